/*
 * fuzz_exr.c - libFuzzer target for the OpenEXR reader (pt_exr_read,
 * common/image/exr.c over OpenEXRCore): the header and layout checks, the
 * ptfarm attributes, and the pixels. The coordinator reads the header of a
 * job's last image when it resumes the job; the environment-map readers will
 * read EXRs a client sends.
 *
 * Input: a mode byte (bit 0: the header alone, as a resume reads it; bit
 * 1: pt_exr_read_layers, every other channel into named planes; bit 2:
 * named channels instead, as ptdenoise reads a render's passes with
 * pt_exr_read_channels, then a copy with a channel added by
 * pt_exr_write_with_channels, read back), then the file, written to the
 * scratch folder as image.exr. Invariants: a
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

/* Named channels: what is read has the file's size; a copy with a channel
 * added reads back with that channel's values and the first one's. */
static void named_channels(const char *dir, const char *path)
{
    static const char *const names[5] = {"R", "halfA.R", "albedo.variance", "N.X", "no.such"};
    float *pl[5] = {0};
    uint32_t w = 0, h = 0;
    pt_error err = {0};
    pt_status st = pt_exr_read_channels(path, 5, names, pl, &w, &h, &err);
    fuzz_note("read channels", st, &err);
    FUZZ_CHECK(st == PT_OK || (st == err.code && err.msg[0]));
    if (st != PT_OK) {
        for (int i = 0; i < 5; i++)
            FUZZ_CHECK(pl[i] == NULL);
        return;
    }
    FUZZ_CHECK(w > 0 && h > 0 && (uint64_t)w * h <= PT_IMAGE_MAX_PIXELS);
    char out[760];
    snprintf(out, sizeof out, "%s/copy.exr", dir);
    const char *add[1] = {"denoised.R"};
    float *mark = pt_malloc_array((size_t)w * h, sizeof(float));
    if (mark) {
        for (size_t i = 0; i < (size_t)w * h; i++)
            mark[i] = (float)i;
        const float *ap[1] = {mark};
        st = pt_exr_write_with_channels(path, out, 1, add, ap, &err);
        fuzz_note("copy", st, &err);
        FUZZ_CHECK(st == PT_OK || (st == err.code && err.msg[0]));
        if (st == PT_OK) {
            const char *back[2] = {"denoised.R", names[0]};
            float *bp[2] = {0};
            uint32_t bw = 0, bh = 0;
            FUZZ_CHECK(pt_exr_read_channels(out, 2, back, bp, &bw, &bh, &err) == PT_OK);
            FUZZ_CHECK(bw == w && bh == h && bp[0] &&
                       !memcmp(bp[0], mark, (size_t)w * h * sizeof(float)));
            FUZZ_CHECK((bp[1] == NULL) == (pl[0] == NULL));
            FUZZ_CHECK(!bp[1] || !memcmp(bp[1], pl[0], (size_t)w * h * sizeof(float)));
            pt_free(bp[0]);
            pt_free(bp[1]);
        }
        pt_free(mark);
    }
    for (int i = 0; i < 5; i++)
        pt_free(pl[i]);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    const char *dir = fuzz_dir();
    fuzz_write(dir, "image.exr", data + 1, size - 1);
    char path[700];
    snprintf(path, sizeof path, "%s/image.exr", dir);

    int64_t live = pt_alloc_live();
    if (data[0] & 4) {
        named_channels(dir, path);
        FUZZ_CHECK(pt_alloc_live() == live);
        return 0;
    }
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
