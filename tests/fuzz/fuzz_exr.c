/*
 * fuzz_exr.c - libFuzzer target for the OpenEXR reader (pt_exr_read,
 * common/image/exr.c over OpenEXRCore): the header and layout checks, the
 * ptfarm attributes, and the pixels. The coordinator reads the header of a
 * job's last image when it resumes the job; the environment-map readers will
 * read EXRs a client sends.
 *
 * Input: a mode byte (bit 0: the header alone, as a resume reads it; bit
 * 1: pt_exr_read_layers, every other channel into named planes), then
 * the file, written to the scratch folder as image.exr. Invariants: a
 * refusal names its cause; nothing is left allocated; an image read has a
 * size within PT_IMAGE_MAX_SIDE and every plane; the metadata's texts are
 * NUL-terminated; named planes have names of 1 to 31 bytes, none twice, and
 * data. Seeds (corpus/fuzz_exr/) are files pt_exr_write made (one with
 * render passes' layers),
 * committed as they are: their compressed bytes depend on the zlib version,
 * so gen_corpus does not make them.
 */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/image/exr.h"
#include "common/image/image.h"
#include "tests/fuzz/fuzz_util.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    const char *dir = fuzz_dir();
    fuzz_write(dir, "image.exr", data + 1, size - 1);
    char path[700];
    snprintf(path, sizeof path, "%s/image.exr", dir);

    int64_t live = pt_alloc_live();
    pt_image *img = NULL;
    pt_exr_meta meta;
    memset(&meta, 0x55, sizeof meta);
    pt_error err = {0};
    pt_status st = (data[0] & 2)
                       ? pt_exr_read_layers(path, (data[0] & 1) ? NULL : &img, &meta, &err)
                       : pt_exr_read(path, (data[0] & 1) ? NULL : &img, &meta, &err);
    fuzz_note("read", st, &err);
    FUZZ_CHECK(st == PT_OK || (st == err.code && err.msg[0]));
    if (st == PT_OK) {
        FUZZ_CHECK(memchr(meta.scene_hash, 0, sizeof meta.scene_hash) &&
                   memchr(meta.job_id, 0, sizeof meta.job_id) &&
                   memchr(meta.software, 0, sizeof meta.software));
        if (!(data[0] & 1)) {
            FUZZ_CHECK(img && img->width > 0 && img->height > 0);
            FUZZ_CHECK(img->width <= PT_IMAGE_MAX_SIDE && img->height <= PT_IMAGE_MAX_SIDE);
            FUZZ_CHECK(img->r && img->g && img->b && img->samples && img->variance);
            FUZZ_CHECK(img->n_planes <= PT_IMAGE_MAX_PLANES && ((data[0] & 2) || !img->n_planes));
            for (uint32_t i = 0; i < img->n_planes; i++) {
                size_t len = strlen(img->planes[i].name);
                FUZZ_CHECK(len > 0 && len < PT_IMAGE_PLANE_NAME && img->planes[i].data);
                FUZZ_CHECK(pt_image_find_plane(img, img->planes[i].name) == img->planes[i].data);
            }
        }
    } else {
        FUZZ_CHECK(img == NULL);
    }
    pt_image_free(img);
    FUZZ_CHECK(pt_alloc_live() == live);
    return 0;
}
