/*
 * gen_corpus.c - writes or checks the seed corpus of the fuzz targets.
 *
 *   gen_corpus write DIR   writes the files of DIR/<target> for every target
 *   gen_corpus check DIR   fails unless every generated file is in DIR with
 *                          the same bytes (other files, such as crash inputs
 *                          added by hand, are allowed)
 *
 * The seeds are the sample messages of tests/protocol/samples.h: for
 * fuzz_msg a selector byte (see fuzz_msg.c) and a payload; for fuzz_frame a
 * mode byte (see fuzz_frame.c) and frames, alone, in one stream, and a few
 * broken ones, a client's session and a denoised region's exchange. For
 * the decoders of files: small glTF scenes (a data: URI
 * buffer, an external buffer and image, a .glb, a name leading out of the
 * folder, JSON nested too deep and just deep enough, a PNG whose header
 * claims 16384^2, one whose data inflates past its header's 1x1, meshes
 * instanced past the triangle cap and morph targets past the delta cap,
 * animated ones with skins and morph targets, and hostile animated ones)
 * for fuzz_gltf; bundles packed from such scenes, and hostile ones, for
 * fuzz_bundle; and for the state folder's targets (fuzz_state.h) real
 * queue files, checkpoints and results logs written by server/store/state.c in
 * a scratch folder: fresh, with held early results, finished, cut short,
 * unsealed. ctest runs "check", so a change to the wire format that
 * forgets the corpus fails the suite; rerun "write" to refresh it.
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/render/guide.h"
#include "common/scene/bundle.h"
#include "protocol/frame.h"
#include "protocol/guide.h"
#include "protocol/msg.h"
#include "protocol/wire.h"
#include "server/sched/job.h"
#include "server/store/state.h"
#include "tests/fuzz/fuzz_state.h"
#include "tests/protocol/samples.h"

static int write_mode;
static int failures;
static const char *const file_targets[] = {"fuzz_gltf",      "fuzz_bundle",      "fuzz_checkpoint",
                                           "fuzz_queue",     "fuzz_results_log", "fuzz_guide",
                                           "fuzz_guide_pack"};

static void emit(const char *dir, const char *target, const char *name, const uint8_t *data,
                 size_t len)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/%s/%s", dir, target, name);
    if (write_mode) {
        FILE *f = fopen(path, "wb");
        if (!f || fwrite(data, 1, len, f) != len || fclose(f) != 0) {
            fprintf(stderr, "cannot write %s\n", path);
            failures++;
        }
        return;
    }
    FILE *f = fopen(path, "rb");
    if (!f) {
        fprintf(stderr, "missing %s (run gen_corpus write)\n", path);
        failures++;
        return;
    }
    uint8_t *have = malloc(len + 1);
    size_t got = have ? fread(have, 1, len + 1, f) : 0;
    fclose(f);
    if (!have || got != len || memcmp(have, data, len) != 0) {
        fprintf(stderr, "stale %s (run gen_corpus write)\n", path);
        failures++;
    }
    free(have);
}

/* Appends a mode byte then frames to w. */
static void frames(proto_writer *w, uint8_t mode, int variant_mask)
{
    proto_w_u8(w, mode);
    for (int v = 0; v < 2; v++)
        if (variant_mask & (1 << v))
            for (int s = 0; s < SAMPLE_COUNT; s++)
                if (!sample_frame(s, v, w))
                    failures++;
}

/* ---- the files: glTF scenes, bundles, the state folder ----------------------------- */

/* Appends to a growing byte string (aborting the generator when out of memory). */
typedef struct bytes {
    uint8_t *p;
    size_t len, cap;
} bytes;

static void put(bytes *b, const void *data, size_t n)
{
    if (b->len + n > b->cap) {
        size_t cap = b->cap ? b->cap : 256;
        while (cap < b->len + n)
            cap *= 2;
        uint8_t *np = realloc(b->p, cap);
        if (!np)
            abort();
        b->p = np;
        b->cap = cap;
    }
    memcpy(b->p + b->len, data, n);
    b->len += n;
}

static void puts_(bytes *b, const char *s)
{
    put(b, s, strlen(s));
}

/* A 2x2 RGBA PNG (red, green / blue, white), made once with zlib: fixed
 * bytes, so the corpus does not depend on the system's PNG encoder. */
static const uint8_t k_png[75] = {
    0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44,
    0x52, 0x00, 0x00, 0x00, 0x02, 0x00, 0x00, 0x00, 0x02, 0x08, 0x06, 0x00, 0x00, 0x00, 0x72,
    0xb6, 0x0d, 0x24, 0x00, 0x00, 0x00, 0x12, 0x49, 0x44, 0x41, 0x54, 0x78, 0xda, 0x63, 0xf8,
    0xcf, 0xc0, 0xf0, 0x1f, 0x0c, 0x81, 0x34, 0x18, 0x00, 0x00, 0x49, 0xc8, 0x09, 0xf7, 0x03,
    0xd9, 0x64, 0xf1, 0x00, 0x00, 0x00, 0x00, 0x49, 0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82};

/* A PNG whose IHDR claims 16384x16384 RGBA (1 GiB decoded) and whose IDAT
 * holds one row of zeros (zlib, level 9): the decompression bomb's header,
 * refused before anything is decoded (PT_SCENE_MAX_IMAGE_TEXELS). */
static const uint8_t k_png_bomb[142] = {
    0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44, 0x52,
    0x00, 0x00, 0x40, 0x00, 0x00, 0x00, 0x40, 0x00, 0x08, 0x06, 0x00, 0x00, 0x00, 0xa9, 0xc8, 0x10,
    0x84, 0x00, 0x00, 0x00, 0x55, 0x49, 0x44, 0x41, 0x54, 0x78, 0xda, 0xed, 0xc1, 0x01, 0x01, 0x00,
    0x00, 0x00, 0x82, 0x20, 0xff, 0xaf, 0xae, 0x21, 0x40, 0x01, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0xc0, 0x0d, 0x00, 0x10, 0x00, 0x01, 0xd2, 0x25,
    0x94, 0x11, 0x00, 0x00, 0x00, 0x00, 0x49, 0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82};

/* A PNG whose IHDR says 1x1 greyscale and whose IDAT inflates to 1 MiB of
 * zeros (zlib, level 9): refused before stb_image, which would grow its
 * buffer with the stream. */
static const uint8_t k_png_liar[1096] = {
    0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44, 0x52,
    0x00, 0x00, 0x00, 0x01, 0x00, 0x00, 0x00, 0x01, 0x08, 0x00, 0x00, 0x00, 0x00, 0x3a, 0x7e, 0x9b,
    0x55, 0x00, 0x00, 0x04, 0x0f, 0x49, 0x44, 0x41, 0x54, 0x78, 0xda, 0xed, 0xc1, 0x31, 0x01, 0x00,
    0x00, 0x00, 0xc2, 0xa0, 0xf5, 0x4f, 0x6d, 0x08, 0x5f, 0xa0, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x3e, 0x03, 0x00, 0xf0, 0x00, 0x01, 0x9d, 0x5d, 0xf5, 0xbd, 0x00, 0x00, 0x00, 0x00,
    0x49, 0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82};

/* A 2x1 binary PPM: the other image format stb_image reads without zlib. */
static const char k_ppm[] = "P6\n2 1\n255\n\xff\x80\x00\x00\x80\xff";

/* The triangle's buffer: 3 float3 positions (36 bytes), 3 u16 indices and 2
 * bytes of padding (8), 3 float2 uvs (24): 68 bytes, little-endian. */
#define TRI_BIN 68
static void tri_bin(uint8_t *out)
{
    static const float pos[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    static const float uv[6] = {0, 0, 1, 0, 0, 1};
    static const uint16_t idx[4] = {0, 1, 2, 0};
    for (int i = 0; i < 9; i++)
        proto_put_f32(out + 4 * i, pos[i]);
    for (int i = 0; i < 4; i++)
        proto_put_u16(out + 36 + 2 * i, idx[i]);
    for (int i = 0; i < 6; i++)
        proto_put_f32(out + 44 + 4 * i, uv[i]);
}

static void base64(bytes *b, const uint8_t *p, size_t n)
{
    static const char tab[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    for (size_t i = 0; i < n; i += 3) {
        uint32_t v = (uint32_t)p[i] << 16 | (i + 1 < n ? (uint32_t)p[i + 1] << 8 : 0) |
                     (i + 2 < n ? p[i + 2] : 0);
        char q[4] = {tab[v >> 18 & 63], tab[v >> 12 & 63], i + 1 < n ? tab[v >> 6 & 63] : '=',
                     i + 2 < n ? tab[v & 63] : '='};
        put(b, q, 4);
    }
}

/* The JSON of a one-triangle scene; buffer_uri NULL for a GLB's own chunk,
 * image: an "images" entry or NULL for an untextured material. */
static void tri_json(bytes *b, const char *buffer_uri, uint32_t buffer_len, const char *views,
                     const char *image, const char *nodes_and_cameras)
{
    puts_(b, "{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],");
    puts_(b, nodes_and_cameras);
    puts_(b, ",\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0,\"TEXCOORD_0\":2},"
             "\"indices\":1,\"material\":0}]}],\"buffers\":[{");
    if (buffer_uri) {
        puts_(b, "\"uri\":\"");
        puts_(b, buffer_uri);
        puts_(b, "\",");
    }
    char num[64];
    snprintf(num, sizeof num, "\"byteLength\":%u}],", buffer_len);
    puts_(b, num);
    puts_(b, views);
    puts_(b, ",\"accessors\":["
             "{\"bufferView\":0,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\","
             "\"min\":[0,0,0],\"max\":[1,1,0]},"
             "{\"bufferView\":1,\"componentType\":5123,\"count\":3,\"type\":\"SCALAR\"},"
             "{\"bufferView\":2,\"componentType\":5126,\"count\":3,\"type\":\"VEC2\"}],");
    if (image) {
        puts_(b, "\"images\":[");
        puts_(b, image);
        puts_(b, "],\"samplers\":[{\"wrapS\":33071,\"wrapT\":33648,\"magFilter\":9729}],"
                 "\"textures\":[{\"source\":0,\"sampler\":0}],"
                 "\"materials\":[{\"name\":\"m0\",\"pbrMetallicRoughness\":{"
                 "\"baseColorTexture\":{\"index\":0,\"extensions\":{\"KHR_texture_transform\":"
                 "{\"scale\":[2,2]}}},\"metallicRoughnessTexture\":{\"index\":0},"
                 "\"metallicFactor\":0.5,\"roughnessFactor\":0.25},"
                 "\"emissiveTexture\":{\"index\":0},\"emissiveFactor\":[1,1,1],"
                 "\"doubleSided\":true}]}");
    } else {
        puts_(b, "\"materials\":[{\"name\":\"lamp\",\"pbrMetallicRoughness\":{"
                 "\"baseColorFactor\":[0.8,0.5,0.2,1],\"metallicFactor\":0},"
                 "\"emissiveFactor\":[1,0.5,0.25],\"extensions\":{"
                 "\"KHR_materials_emissive_strength\":{\"emissiveStrength\":4},"
                 "\"KHR_materials_specular\":{\"specularFactor\":0.5,"
                 "\"specularColorFactor\":[1,0.9,0.8]}}}]}");
    }
}

static const char k_views[] = "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":0,\"byteLength\":36},"
                              "{\"buffer\":0,\"byteOffset\":36,\"byteLength\":6},"
                              "{\"buffer\":0,\"byteOffset\":44,\"byteLength\":24,"
                              "\"byteStride\":8}]";
static const char k_nodes[] = "\"nodes\":[{\"mesh\":0,\"translation\":[0,0,1],"
                              "\"rotation\":[0,0,0.3826834,0.9238795],\"children\":[1,2]},"
                              "{\"camera\":0,\"translation\":[0.5,0.5,3]},"
                              "{\"camera\":1,\"matrix\":[1,0,0,0,0,1,0,0,0,0,1,0,0,0,5,1]}],"
                              "\"cameras\":[{\"name\":\"cam\",\"type\":\"perspective\","
                              "\"perspective\":{\"yfov\":0.6,\"znear\":0.1,\"aspectRatio\":1.5}},"
                              "{\"name\":\"ortho\",\"type\":\"orthographic\",\"orthographic\":"
                              "{\"xmag\":1,\"ymag\":1,\"znear\":0.1,\"zfar\":10}}]";
#define GLTF_SEP "\n#ptfuzz#\n" /* fuzz_gltf.c's part separator */

static void gen_gltf(const char *dir)
{
    uint8_t bin[TRI_BIN];
    tri_bin(bin);
    bytes b = {0};

    /* The buffer inline as a data: URI; emissive strength and specular. */
    bytes uri = {0};
    puts_(&uri, "data:application/octet-stream;base64,");
    base64(&uri, bin, sizeof bin);
    put(&uri, "", 1);
    tri_json(&b, (const char *)uri.p, TRI_BIN, k_views, NULL, k_nodes);
    emit(dir, "fuzz_gltf", "tri_datauri.gltf", b.p, b.len);
    free(uri.p);

    /* The same with "extras" nested 30,000 deep in front (refused before the
     * recursive parser sees it: common/base/json.h), and 126 deep, the most
     * that loads (the root object and "extras" are two more levels). */
    static const unsigned depths[] = {30000, 126};
    static const char *const deep_names[] = {"deep_extras.gltf", "deep_edge.gltf"};
    for (int k = 0; k < 2; k++) {
        bytes d = {0};
        puts_(&d, "{\"extras\":");
        for (unsigned i = 0; i < depths[k]; i++)
            put(&d, "[", 1);
        for (unsigned i = 0; i < depths[k]; i++)
            put(&d, "]", 1);
        put(&d, ",", 1);
        put(&d, b.p + 1, b.len - 1);
        emit(dir, "fuzz_gltf", deep_names[k], d.p, d.len);
        free(d.p);
    }

    /* External buffer and PNG texture; then the same asking for a camera,
     * with a PPM image, with a name that leads out of the folder, for the
     * orthographic camera (its yfov is 0), and for placements of a camera
     * (pt_camera_look_parse: an orthographic one has ymag 0). */
    static const struct {
        const char *name, *buffer, *image, *camera;
        const uint8_t *img;
        size_t img_len;
    } ext[] = {
        {"tri_bin_png", "b.bin", "{\"uri\":\"i.png\"}", NULL, k_png, sizeof k_png},
        {"tri_bin_ppm_cam", "./b%2ebin", "{\"uri\":\"i.png\",\"mimeType\":\"image/png\"}", "cam",
         (const uint8_t *)k_ppm, sizeof k_ppm - 1},
        {"tri_escape", "../b.bin", "{\"uri\":\"/etc/passwd\"}", "ortho", k_png, sizeof k_png},
        {"tri_bin_ortho", "b.bin", "{\"uri\":\"i.png\"}", "ortho", k_png, sizeof k_png},
        {"tri_look_ortho", "b.bin", "{\"uri\":\"i.png\"}", "look:0,1,5:0,1,0:ortho=2", k_png,
         sizeof k_png},
        {"tri_look_fov", "b.bin", "{\"uri\":\"i.png\"}", "look:3,3,3:0,0,0:fov=25", k_png,
         sizeof k_png},
        {"png_bomb", "b.bin", "{\"uri\":\"i.png\"}", NULL, k_png_bomb, sizeof k_png_bomb},
        {"png_liar", "b.bin", "{\"uri\":\"i.png\"}", NULL, k_png_liar, sizeof k_png_liar},
    };
    for (size_t i = 0; i < sizeof ext / sizeof ext[0]; i++) {
        b.len = 0;
        tri_json(&b, ext[i].buffer, TRI_BIN, k_views, ext[i].image, k_nodes);
        puts_(&b, GLTF_SEP);
        put(&b, bin, sizeof bin);
        puts_(&b, GLTF_SEP);
        put(&b, ext[i].img, ext[i].img_len);
        if (ext[i].camera) {
            puts_(&b, GLTF_SEP);
            puts_(&b, ext[i].camera);
        }
        emit(dir, "fuzz_gltf", ext[i].name, b.p, b.len);
    }

    /* Instancing bombs: a mesh of 1,024 triangles (u8 indices) under nodes
     * shared by two parents, 15 deep: 2^15 instances, 33.5 M triangles,
     * twice PT_SCENE_MAX_TRIANGLES; then 40 deep over one triangle: 2^40. */
    uint8_t ibin[36 + 3072];
    memcpy(ibin, bin, 36);
    for (size_t i = 0; i < 3072; i++)
        ibin[36 + i] = (uint8_t)(i % 3);
    for (int k = 0; k < 2; k++) {
        const int levels = k == 0 ? 15 : 40;
        b.len = 0;
        puts_(&b, "{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],"
                  "\"nodes\":[");
        char node[64];
        for (int i = 0; i < levels; i++) {
            snprintf(node, sizeof node, "{\"children\":[%d,%d]},", i + 1, i + 1);
            puts_(&b, node);
        }
        puts_(&b, "{\"mesh\":0}],"
                  "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0},\"indices\":1}]}],"
                  "\"buffers\":[{\"uri\":\"b.bin\",\"byteLength\":3108}],"
                  "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":0,\"byteLength\":36},"
                  "{\"buffer\":0,\"byteOffset\":36,\"byteLength\":3072}],"
                  "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":3,"
                  "\"type\":\"VEC3\",\"min\":[0,0,0],\"max\":[1,1,0]},"
                  "{\"bufferView\":1,\"componentType\":5121,\"type\":\"SCALAR\",\"count\":");
        puts_(&b, k == 0 ? "3072}]}" : "3}]}");
        puts_(&b, GLTF_SEP);
        put(&b, ibin, sizeof ibin);
        emit(dir, "fuzz_gltf", k == 0 ? "inst_bomb.gltf" : "inst_dag.gltf", b.p, b.len);
    }
    /* A morph bomb for the animated load: one triangle with 256 targets
     * (one accessor for all) under 17 levels of shared nodes, 2^17 x 3 x 256
     * deltas, past PT_ANIM_MAX_MORPH_DELTAS; as a still it loads. */
    b.len = 0;
    puts_(&b, "{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],"
              "\"nodes\":[");
    for (int i = 0; i < 17; i++) {
        char node[64];
        snprintf(node, sizeof node, "{\"children\":[%d,%d]},", i + 1, i + 1);
        puts_(&b, node);
    }
    puts_(&b, "{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0},"
              "\"indices\":1,\"targets\":[");
    for (int t = 0; t < 256; t++)
        puts_(&b, t ? ",{\"POSITION\":0}" : "{\"POSITION\":0}");
    puts_(&b, "]}]}],\"buffers\":[{\"uri\":\"b.bin\",\"byteLength\":3108}],"
              "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":0,\"byteLength\":36},"
              "{\"buffer\":0,\"byteOffset\":36,\"byteLength\":3072}],"
              "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":3,"
              "\"type\":\"VEC3\",\"min\":[0,0,0],\"max\":[1,1,0]},"
              "{\"bufferView\":1,\"componentType\":5121,\"type\":\"SCALAR\",\"count\":3}]}");
    puts_(&b, GLTF_SEP);
    put(&b, ibin, sizeof ibin);
    emit(dir, "fuzz_gltf", "morph_bomb.gltf", b.p, b.len);

    /* A .glb (glTF 2.0 spec 4.4): header, JSON chunk, BIN chunk holding the
     * triangle and the PNG, which a bufferView names as the texture. */
    bytes json = {0};
    char views[512];
    snprintf(views, sizeof views,
             "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":0,\"byteLength\":36},"
             "{\"buffer\":0,\"byteOffset\":36,\"byteLength\":6},"
             "{\"buffer\":0,\"byteOffset\":44,\"byteLength\":24},"
             "{\"buffer\":0,\"byteOffset\":%u,\"byteLength\":%zu}]",
             TRI_BIN, sizeof k_png);
    uint32_t binlen = (uint32_t)(TRI_BIN + sizeof k_png + 3) & ~3u;
    tri_json(&json, NULL, binlen, views, "{\"bufferView\":3,\"mimeType\":\"image/png\"}",
             "\"nodes\":[{\"mesh\":0,\"scale\":[2,2,2]}]");
    while (json.len % 4)
        puts_(&json, " ");
    uint8_t h[12];
    b.len = 0;
    proto_put_u32(h, 0x46546C67u); /* "glTF" */
    proto_put_u32(h + 4, 2);
    proto_put_u32(h + 8, (uint32_t)(12 + 8 + json.len + 8 + binlen));
    put(&b, h, 12);
    proto_put_u32(h, (uint32_t)json.len);
    proto_put_u32(h + 4, 0x4E4F534Au); /* "JSON" */
    put(&b, h, 8);
    put(&b, json.p, json.len);
    proto_put_u32(h, binlen);
    proto_put_u32(h + 4, 0x004E4942u); /* "BIN\0" */
    put(&b, h, 8);
    put(&b, bin, sizeof bin);
    put(&b, k_png, sizeof k_png);
    static const uint8_t zero[4] = {0};
    put(&b, zero, binlen - TRI_BIN - sizeof k_png);
    emit(dir, "fuzz_gltf", "tri.glb", b.p, b.len);
    free(json.p);
    free(b.p);
}

/* Animated scenes (common/scene/anim.h), the buffer inline: a triangle
 * whose node is moved by LINEAR translation, STEP rotation and CUBICSPLINE
 * scale, with two morph targets whose weights are animated, and a camera
 * under it; and the triangle skinned to two joints, one of them turning. */
/* Seeds of the extensions (gen_gltf_ext): streams encoded once by libdraco's,
 * libmeshoptimizer's and libwebp's encoders (tests/fuzz/corpus/fuzz_draco,
 * fuzz_meshopt, fuzz_webp hold the same), kept as bytes so the corpus does
 * not change with an encoder's version. */
static const uint8_t k_draco_seq[158] = {
    0x44, 0x52, 0x41, 0x43, 0x4f, 0x02, 0x02, 0x01, 0x00, 0x00, 0x00, 0x04, 0x09, 0x01, 0x00, 0x01,
    0x02, 0x03, 0x04, 0x02, 0x00, 0x05, 0x06, 0x00, 0x07, 0x08, 0x01, 0x03, 0x00, 0x09, 0x03, 0x00,
    0x00, 0x01, 0x09, 0x03, 0x00, 0x01, 0x03, 0x09, 0x02, 0x00, 0x02, 0x02, 0x03, 0x02, 0x00, 0x01,
    0x01, 0x00, 0x03, 0x03, 0x71, 0x1c, 0x91, 0x23, 0x04, 0x20, 0x34, 0x40, 0x80, 0x88, 0x91, 0x48,
    0xc0, 0x10, 0x02, 0x00, 0x00, 0x00, 0x00, 0xff, 0x07, 0x00, 0x00, 0x00, 0x03, 0x01, 0x01, 0x01,
    0x80, 0x01, 0x71, 0x3c, 0xff, 0xf7, 0x91, 0x03, 0x03, 0xa0, 0xcc, 0x8a, 0xff, 0x00, 0x00, 0x00,
    0x7f, 0x00, 0x00, 0x00, 0x00, 0x01, 0x01, 0x00, 0x03, 0x03, 0x71, 0x1c, 0x91, 0x23, 0x04, 0x48,
    0x94, 0x40, 0x80, 0x64, 0x18, 0x96, 0x06, 0x00, 0x00, 0x00, 0x00, 0xff, 0x03, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x80, 0x3f, 0x0b,
    0x08, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x80, 0x3f, 0x0a,
};
static const uint8_t k_meshopt_pos[136] = {
    0xa0, 0x00, 0x00, 0x03, 0x00, 0xff, 0xff, 0x80, 0x7f, 0xff, 0xff, 0x80, 0x7f, 0xff, 0xff, 0x80,
    0x7f, 0xff, 0xff, 0x80, 0x01, 0x38, 0xf8, 0xf8, 0xf8, 0x7e, 0x7f, 0x7e, 0x7f, 0x7e, 0x7f, 0x7e,
    0x00, 0x00, 0x01, 0x00, 0xc0, 0xc0, 0xc0, 0xff, 0xff, 0x80, 0x01, 0x00, 0xc0, 0x80, 0x00, 0x7e,
    0x01, 0x30, 0xfc, 0x3f, 0x0f, 0x65, 0x65, 0xcc, 0x65, 0x65, 0xcc, 0x65, 0x65, 0xcc, 0x01, 0x30,
    0xfc, 0x3f, 0x0f, 0x67, 0x65, 0xce, 0x67, 0x65, 0xce, 0x67, 0x65, 0xce, 0x03, 0x00, 0x98, 0xff,
    0x00, 0x65, 0xce, 0x98, 0xff, 0x00, 0x65, 0xce, 0x98, 0xff, 0x00, 0x65, 0xce, 0x01, 0x31, 0xbc,
    0x6f, 0x1b, 0x7c, 0x7b, 0x7c, 0x7b, 0x7c, 0x7b, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
};
static const uint8_t k_meshopt_tri[50] = {
    0xe0, 0xfe, 0x0f, 0xfe, 0x13, 0xfe, 0x12, 0xbf, 0x0f, 0xaf, 0x02, 0x9f, 0x01,
    0x9f, 0x0f, 0x9f, 0x02, 0x9f, 0x01, 0x0f, 0x0a, 0x01, 0xf3, 0x04, 0xf2, 0x02,
    0x04, 0x01, 0x04, 0x02, 0x04, 0x01, 0x04, 0x02, 0x00, 0x76, 0x87, 0x56, 0x67,
    0x78, 0xa9, 0x86, 0x65, 0x89, 0x68, 0x98, 0x01, 0x69, 0x00, 0x00,
};
static const uint8_t k_webp_8x6[112] = {
    0x52, 0x49, 0x46, 0x46, 0x68, 0x00, 0x00, 0x00, 0x57, 0x45, 0x42, 0x50, 0x56, 0x50, 0x38, 0x4c,
    0x5c, 0x00, 0x00, 0x00, 0x2f, 0x07, 0x40, 0x01, 0x10, 0x99, 0x32, 0x44, 0xf4, 0x3f, 0x36, 0x51,
    0xf0, 0xe8, 0x7f, 0x48, 0xcc, 0xb4, 0x6d, 0x13, 0xfe, 0x48, 0x47, 0xa2, 0x1a, 0x8f, 0x9c, 0xb9,
    0xc4, 0x82, 0x29, 0xde, 0x93, 0x4b, 0x8a, 0x22, 0x49, 0x6a, 0xee, 0x95, 0x8f, 0x28, 0x87, 0x3f,
    0x5e, 0x56, 0x0e, 0x96, 0x70, 0x73, 0x32, 0x04, 0x24, 0x49, 0xcf, 0xa5, 0xe7, 0xf1, 0xe8, 0xc5,
    0x96, 0xb6, 0xfc, 0x95, 0x56, 0x6f, 0xcd, 0xd7, 0x76, 0x03, 0xe6, 0x98, 0xb2, 0xbc, 0xab, 0x2c,
    0xc3, 0x76, 0xe3, 0x12, 0x4b, 0xe2, 0xbb, 0x8b, 0x65, 0x79, 0xa3, 0xc4, 0x81, 0x47, 0x5c, 0x01,
};

/* A .gltf whose one buffer is data: uri of bin; json_head then the buffer's
 * URI, then json_tail. */
static void emit_with_buffer(const char *dir, const char *name, const char *json_head,
                             const uint8_t *bin, size_t n, const char *json_tail)
{
    bytes b = {0};
    puts_(&b, json_head);
    puts_(&b, "data:application/octet-stream;base64,");
    base64(&b, bin, n);
    puts_(&b, json_tail);
    emit(dir, "fuzz_gltf", name, b.p, b.len);
    free(b.p);
}

/* Seeds of the geometry and image extensions: a sparse accessor, quantized
 * positions with GPU instancing (normalized i16 rotations), a Draco mesh, a
 * meshopt-compressed grid over a fallback buffer without data, and a WebP
 * texture given as a data:image/webp URI. */
static void gen_gltf_ext(const char *dir)
{
    static const char head[] = "{\"asset\":{\"version\":\"2.0\"},\"scenes\":[{\"nodes\":[0]}],";
    uint8_t bin[256];
    memset(bin, 0, sizeof bin);
    static const float pos[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    for (int i = 0; i < 9; i++)
        proto_put_f32(bin + 4 * i, pos[i]);
    proto_put_u16(bin + 36, 1);
    proto_put_f32(bin + 40, 2.0f);
    proto_put_f32(bin + 48, 0.5f);
    bytes j = {0};
    puts_(&j, head);
    puts_(&j, "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":{"
              "\"POSITION\":0}}]}],\"bufferViews\":[{\"buffer\":0,\"byteLength\":36},{\"buffer\":0,"
              "\"byteOffset\":36,\"byteLength\":2},{\"buffer\":0,\"byteOffset\":40,\"byteLength\":"
              "12}],\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":3,\"type\":"
              "\"VEC3\",\"sparse\":{\"count\":1,\"indices\":{\"bufferView\":1,\"componentType\":"
              "5123},\"values\":{\"bufferView\":2}}}],\"buffers\":[{\"byteLength\":52,\"uri\":\"");
    put(&j, "", 1);
    emit_with_buffer(dir, "ext_sparse.gltf", (const char *)j.p, bin, 52, "\"}]}");
    free(j.p);

    /* i16 positions (stride 8), 2 translations, 2 rotations (i16, stride 8). */
    memset(bin, 0, sizeof bin);
    proto_put_u16(bin + 8, 32767);
    proto_put_u16(bin + 18, 32767);
    proto_put_f32(bin + 24 + 12, 2.0f);
    proto_put_u16(bin + 48 + 6, 32767);
    proto_put_u16(bin + 56 + 4, 23170);
    proto_put_u16(bin + 56 + 6, 23170);
    j = (bytes){0};
    puts_(&j, head);
    puts_(&j, "\"nodes\":[{\"mesh\":0,\"extensions\":{\"EXT_mesh_gpu_instancing\":{\"attributes\":"
              "{\"TRANSLATION\":1,\"ROTATION\":2}}}}],\"meshes\":[{\"primitives\":[{\"attributes\":"
              "{\"POSITION\":0}}]}],\"extensionsUsed\":[\"KHR_mesh_quantization\","
              "\"EXT_mesh_gpu_instancing\"],\"extensionsRequired\":[\"KHR_mesh_quantization\"],"
              "\"bufferViews\":[{\"buffer\":0,\"byteLength\":24,\"byteStride\":8},{\"buffer\":0,"
              "\"byteOffset\":24,\"byteLength\":24},{\"buffer\":0,\"byteOffset\":48,\"byteLength\":"
              "16,\"byteStride\":8}],\"accessors\":[{\"bufferView\":0,\"componentType\":5122,"
              "\"normalized\":true,\"count\":3,\"type\":\"VEC3\"},{\"bufferView\":1,"
              "\"componentType\":5126,\"count\":2,\"type\":\"VEC3\"},{\"bufferView\":2,"
              "\"componentType\":5122,\"normalized\":true,\"count\":2,\"type\":\"VEC4\"}],"
              "\"buffers\":[{\"byteLength\":64,\"uri\":\"");
    put(&j, "", 1);
    emit_with_buffer(dir, "ext_quant_instancing.gltf", (const char *)j.p, bin, 64, "\"}]}");
    free(j.p);

    /* Draco: 9 points, 4 triangles; POSITION, NORMAL, TEXCOORD_0 (ids 0-2). */
    j = (bytes){0};
    puts_(&j, head);
    puts_(&j, "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":{"
              "\"POSITION\":1,\"NORMAL\":2,\"TEXCOORD_0\":3},\"indices\":0,\"extensions\":{"
              "\"KHR_draco_mesh_compression\":{\"bufferView\":0,\"attributes\":{\"POSITION\":0,"
              "\"NORMAL\":1,\"TEXCOORD_0\":2}}}}]}],\"extensionsUsed\":["
              "\"KHR_draco_mesh_compression\"],\"extensionsRequired\":["
              "\"KHR_draco_mesh_compression\"],\"bufferViews\":[{\"buffer\":0,\"byteLength\":158}],"
              "\"accessors\":[{\"componentType\":5123,\"count\":12,\"type\":\"SCALAR\"},"
              "{\"componentType\":5126,\"count\":9,\"type\":\"VEC3\"},{\"componentType\":5126,"
              "\"count\":9,\"type\":\"VEC3\"},{\"componentType\":5126,\"count\":9,\"type\":"
              "\"VEC2\"}],\"buffers\":[{\"byteLength\":158,\"uri\":\"");
    put(&j, "", 1);
    emit_with_buffer(dir, "ext_draco.gltf", (const char *)j.p, k_draco_seq, sizeof k_draco_seq,
                     "\"}]}");
    free(j.p);

    /* meshopt: a 4 x 4 grid's positions (vertex codec) and 18 triangles
     * (index codec, read as u16). */
    size_t np = sizeof k_meshopt_pos, at = (np + 3) & ~(size_t)3, nt = sizeof k_meshopt_tri;
    uint8_t mo[512];
    memset(mo, 0, sizeof mo);
    memcpy(mo, k_meshopt_pos, np);
    memcpy(mo + at, k_meshopt_tri, nt);
    char views[900];
    snprintf(views, sizeof views,
             "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":{"
             "\"POSITION\":0},\"indices\":1}]}],\"extensionsUsed\":[\"EXT_meshopt_compression\"],"
             "\"extensionsRequired\":[\"EXT_meshopt_compression\"],\"bufferViews\":[{\"buffer\":0,"
             "\"byteLength\":192,\"byteStride\":12,\"extensions\":{\"EXT_meshopt_compression\":{"
             "\"buffer\":1,\"byteLength\":%zu,\"byteStride\":12,\"count\":16,\"mode\":"
             "\"ATTRIBUTES\"}}},{\"buffer\":0,\"byteOffset\":192,\"byteLength\":108,"
             "\"extensions\":{\"EXT_meshopt_compression\":{\"buffer\":1,\"byteOffset\":%zu,"
             "\"byteLength\":%zu,\"byteStride\":2,\"count\":54,\"mode\":\"TRIANGLES\"}}}],"
             "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":16,\"type\":"
             "\"VEC3\"},{\"bufferView\":1,\"componentType\":5123,\"count\":54,\"type\":"
             "\"SCALAR\"}],\"buffers\":[{\"byteLength\":300,\"extensions\":{"
             "\"EXT_meshopt_compression\":{\"fallback\":true}}},{\"byteLength\":%zu,\"uri\":\"",
             np, at, nt, at + nt);
    j = (bytes){0};
    puts_(&j, head);
    puts_(&j, views);
    put(&j, "", 1);
    emit_with_buffer(dir, "ext_meshopt.gltf", (const char *)j.p, mo, at + nt, "\"}]}");
    free(j.p);

    /* The triangle textured by a WebP, as a data:image/webp URI. */
    uint8_t tri[TRI_BIN];
    tri_bin(tri);
    bytes img = {0};
    puts_(&img, "{\"uri\":\"data:image/webp;base64,");
    base64(&img, k_webp_8x6, sizeof k_webp_8x6);
    puts_(&img, "\"}");
    put(&img, "", 1);
    bytes w = {0};
    bytes uri = {0};
    puts_(&uri, "data:application/octet-stream;base64,");
    base64(&uri, tri, sizeof tri);
    put(&uri, "", 1);
    tri_json(&w, (const char *)uri.p, TRI_BIN, k_views, (const char *)img.p, k_nodes);
    /* tri_json's texture points at the image itself; EXT_texture_webp is
     * what a WebP texture should name: both are read. */
    emit(dir, "fuzz_gltf", "ext_webp.gltf", w.p, w.len);
    free(w.p);
    free(uri.p);
    free(img.p);
}

static void gen_gltf_anim(const char *dir)
{
    /* clang-format off */
    static const float f[] = {
        0, 0, 0, 1, 0, 0, 0, 1, 0,                        /* 0: positions */
        0, 0.5f, 1,                                       /* 36: times */
        0, 0, 0, 1, 0, 0, 1, 1, 0,                        /* 48: translations */
        0, 0, 0, 1, 0, 0, 0.7071068f, 0.7071068f,         /* 84: rotations */
        0, 0, 1, 0,
        0, 0, 0, 1, 1, 1, 0, 0, 0,                        /* 132: scales, */
        0, 0, 0, 0, 0, 0, 2, 2, 2,                        /* (in, value, out) */
        0, 0, 0, 1, 1, 1, 0, 0, 0,
        1, 0, 0, 0, 0.5f, 0.5f, 0, 0, 1, 0, 0, 0,         /* 240: weights */
        1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1,   /* 288: inverse binds */
        1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, -1, 0, 0, 1,
        0, 0, 1, 0, 0, 1, 0, 0, 1,                        /* 416: target 0 */
        0, 1, 0, 0, 1, 0, 0, 1, 0,                        /* 452: target 1 */
        0, 0, 1, 0, 0.5f, 0.5f,                           /* 488: morph weights */
    };
    /* clang-format on */
    static const uint16_t joints[12] = {0, 1, 0, 0, 0, 1, 0, 0, 1, 0, 0, 0};
    uint8_t bin[sizeof f + sizeof joints];
    for (size_t i = 0; i < sizeof f / sizeof f[0]; i++)
        proto_put_f32(bin + 4 * i, f[i]);
    for (size_t i = 0; i < 12; i++)
        proto_put_u16(bin + sizeof f + 2 * i, joints[i]);
    bytes b = {0};
    static const char k_anim_views[] =
        "\"bufferViews\":[{\"buffer\":0,\"byteLength\":36},"
        "{\"buffer\":0,\"byteOffset\":36,\"byteLength\":12},"
        "{\"buffer\":0,\"byteOffset\":48,\"byteLength\":36},"
        "{\"buffer\":0,\"byteOffset\":84,\"byteLength\":48},"
        "{\"buffer\":0,\"byteOffset\":132,\"byteLength\":108},"
        "{\"buffer\":0,\"byteOffset\":240,\"byteLength\":48},"
        "{\"buffer\":0,\"byteOffset\":288,\"byteLength\":128},"
        "{\"buffer\":0,\"byteOffset\":416,\"byteLength\":36},"
        "{\"buffer\":0,\"byteOffset\":452,\"byteLength\":36},"
        "{\"buffer\":0,\"byteOffset\":488,\"byteLength\":24},"
        "{\"buffer\":0,\"byteOffset\":512,\"byteLength\":24}],"
        "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\"},"
        "{\"bufferView\":1,\"componentType\":5126,\"count\":3,\"type\":\"SCALAR\"},"
        "{\"bufferView\":2,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\"},"
        "{\"bufferView\":3,\"componentType\":5126,\"count\":3,\"type\":\"VEC4\"},"
        "{\"bufferView\":4,\"componentType\":5126,\"count\":9,\"type\":\"VEC3\"},"
        "{\"bufferView\":5,\"componentType\":5126,\"count\":3,\"type\":\"VEC4\"},"
        "{\"bufferView\":6,\"componentType\":5126,\"count\":2,\"type\":\"MAT4\"},"
        "{\"bufferView\":7,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\"},"
        "{\"bufferView\":8,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\"},"
        "{\"bufferView\":9,\"componentType\":5126,\"count\":6,\"type\":\"SCALAR\"},"
        "{\"bufferView\":10,\"componentType\":5123,\"count\":3,\"type\":\"VEC4\"}],";
    /* The last three are hostile: a skin whose joints form a cycle out of the
     * scene, a joint index past the skin's joints, a CUBICSPLINE sampler with
     * one value a key. */
    static const char k_skin_mesh[] =
        "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0,\"JOINTS_0\":10,"
        "\"WEIGHTS_0\":5}}]}],";
    static const char *const scenes[5][3] = {
        {"anim_trs_morph.gltf", "\"scenes\":[{\"nodes\":[0]}],",
         "\"nodes\":[{\"mesh\":0,\"weights\":[0.5,0],\"children\":[1]},"
         "{\"camera\":0,\"translation\":[0,0,3]}],"
         "\"cameras\":[{\"name\":\"cam\",\"type\":\"perspective\",\"perspective\":{\"yfov\":0.6,"
         "\"znear\":0.1}}],"
         "\"meshes\":[{\"weights\":[0,0],\"primitives\":[{\"attributes\":{\"POSITION\":0},"
         "\"targets\":[{\"POSITION\":7},{\"POSITION\":8}]}]}],"
         "\"animations\":[{\"name\":\"all\",\"channels\":["
         "{\"sampler\":0,\"target\":{\"node\":0,\"path\":\"translation\"}},"
         "{\"sampler\":1,\"target\":{\"node\":0,\"path\":\"rotation\"}},"
         "{\"sampler\":2,\"target\":{\"node\":0,\"path\":\"scale\"}},"
         "{\"sampler\":3,\"target\":{\"node\":0,\"path\":\"weights\"}}],\"samplers\":["
         "{\"input\":1,\"output\":2},{\"input\":1,\"output\":3,\"interpolation\":\"STEP\"},"
         "{\"input\":1,\"output\":4,\"interpolation\":\"CUBICSPLINE\"},"
         "{\"input\":1,\"output\":9}]}],"},
        {"anim_skin.gltf", "",
         "\"nodes\":[{\"mesh\":0,\"skin\":0},{\"children\":[2]},{\"translation\":[1,0,0]}],"
         "\"scenes\":[{\"nodes\":[0,1]}],"
         "\"skins\":[{\"joints\":[1,2],\"inverseBindMatrices\":6,\"skeleton\":1}],"
         "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0,\"JOINTS_0\":10,"
         "\"WEIGHTS_0\":5}}]}],"
         "\"animations\":[{\"name\":\"bend\",\"channels\":["
         "{\"sampler\":0,\"target\":{\"node\":2,\"path\":\"rotation\"}}],\"samplers\":["
         "{\"input\":1,\"output\":3}]}],"},
        {"anim_skin_cycle.gltf", k_skin_mesh,
         "\"nodes\":[{\"mesh\":0,\"skin\":0},{\"children\":[2]},"
         "{\"translation\":[1,0,0],\"children\":[1]}],\"scenes\":[{\"nodes\":[0]}],"
         "\"skins\":[{\"joints\":[1,2],\"inverseBindMatrices\":6}],"},
        {"anim_bad_joint.gltf", k_skin_mesh,
         "\"nodes\":[{\"mesh\":0,\"skin\":0,\"children\":[1]},{}],\"scenes\":[{\"nodes\":[0]}],"
         "\"skins\":[{\"joints\":[1]}],"},
        {"anim_bad_count.gltf", "",
         "\"nodes\":[{\"mesh\":0}],\"scenes\":[{\"nodes\":[0]}],"
         "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0}}]}],"
         "\"animations\":[{\"channels\":[{\"sampler\":0,\"target\":{\"node\":0,\"path\":"
         "\"translation\"}}],\"samplers\":[{\"input\":1,\"output\":2,"
         "\"interpolation\":\"CUBICSPLINE\"}]}],"},
    };
    for (int i = 0; i < 5; i++) {
        b.len = 0;
        puts_(&b, "{\"asset\":{\"version\":\"2.0\"},");
        puts_(&b, scenes[i][1]);
        puts_(&b, scenes[i][2]);
        puts_(&b, k_anim_views);
        char len[64];
        snprintf(len, sizeof len, "\"buffers\":[{\"byteLength\":%zu,", sizeof bin);
        puts_(&b, len);
        puts_(&b, "\"uri\":\"data:application/octet-stream;base64,");
        base64(&b, bin, sizeof bin);
        puts_(&b, "\"}]}");
        emit(dir, "fuzz_gltf", scenes[i][0], b.p, b.len);
    }
    free(b.p);
}

/* Writes tmp/name with data (the generator's own scratch files). */
static void scratch(const char *tmp, const char *name, const void *data, size_t len)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", tmp, name);
    pt_error err = {0};
    if (pt_write_file_atomic(path, data, len, &err) != PT_OK) {
        fprintf(stderr, "%s\n", err.msg);
        failures++;
    }
}

static void gen_bundle(const char *dir, const char *tmp)
{
    uint8_t bin[TRI_BIN];
    tri_bin(bin);
    bytes b = {0};
    pt_error err = {0};
    char path[4096];
    snprintf(path, sizeof path, "%s/sub/tex", tmp);
    pt_mkdirs(path, 0, &err);
    scratch(tmp, "sub/b.bin", bin, sizeof bin);
    scratch(tmp, "sub/tex/i x.png", k_png, sizeof k_png);
    tri_json(&b, "sub/b.bin", TRI_BIN, k_views, "{\"uri\":\"sub/tex/i%20x.png\"}", k_nodes);
    scratch(tmp, "nested.gltf", b.p, b.len);
    b.len = 0;
    tri_json(&b, "b.bin", TRI_BIN, k_views, NULL, k_nodes);
    scratch(tmp, "b.bin", bin, sizeof bin);
    scratch(tmp, "flat.gltf", b.p, b.len);
    free(b.p);

    static const char *const packed[] = {"nested.gltf", "flat.gltf"};
    for (size_t i = 0; i < 2; i++) {
        snprintf(path, sizeof path, "%s/%s", tmp, packed[i]);
        pt_bundle *bun = NULL;
        if (pt_bundle_pack(path, &bun, &err) != PT_OK) {
            fprintf(stderr, "%s\n", err.msg);
            failures++;
            continue;
        }
        emit(dir, "fuzz_bundle", packed[i], bun->data, bun->size);
        pt_bundle_free(bun);
    }
    /* Names that must be refused, and files where folders must go. */
    static const char *const hostile[][2] = {
        {"../up.gltf", "{}"},
        {"a/./b", "{}"},
        {"a", "{}"},
    };
    for (size_t i = 0; i < sizeof hostile / sizeof hostile[0]; i++) {
        proto_writer w;
        proto_writer_init(&w, 1 << 20);
        proto_w_bytes(&w, "PTB1", 4);
        proto_w_u32(&w, i == 2 ? 2 : 1);
        for (int k = 0; k < (i == 2 ? 2 : 1); k++) {
            const char *name = k ? "a/b.bin" : hostile[i][0];
            proto_w_u16(&w, (uint16_t)strlen(name));
            proto_w_bytes(&w, name, strlen(name));
            proto_w_u64(&w, strlen(hostile[i][1]));
            proto_w_bytes(&w, hostile[i][1], strlen(hostile[i][1]));
        }
        static const char *const names[] = {"escape", "dot", "file_then_folder"};
        emit(dir, "fuzz_bundle", names[i], w.buf, w.len);
        proto_writer_fini(&w);
    }
}

/* Reads tmp/rel whole and emits it behind a mode byte, with cut bytes off
 * the end and, when flip is not 0, one bit of byte flip changed. */
static void emit_state_file(const char *dir, const char *target, const char *name, const char *tmp,
                            const char *rel, uint8_t mode, size_t cut, size_t flip)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", tmp, rel);
    uint8_t *data = NULL;
    size_t len = 0;
    pt_error err = {0};
    if (pt_read_file(path, (size_t)1 << 30, &data, &len, &err) != PT_OK || len < cut ||
        len <= flip) {
        fprintf(stderr, "%s\n", err.msg);
        failures++;
        pt_free(data);
        return;
    }
    uint8_t *out = malloc(len + 1);
    if (!out)
        abort();
    out[0] = mode;
    memcpy(out + 1, data, len);
    if (flip)
        out[1 + flip] ^= 0x20;
    emit(dir, target, name, out, len + 1 - cut);
    free(out);
    pt_free(data);
}

/* Deterministic pixels for a task; varied, so that adaptive sampling has
 * some tiles to stop and some to go on with. */
static void fake_result(const proto_task *t, pt_pixel_acc *px, pt_pass_acc *pa, proto_result *r)
{
    uint32_t n = (t->tile.x1 - t->tile.x0) * (t->tile.y1 - t->tile.y0);
    uint32_t ns = t->s1 - t->s0;
    for (uint32_t i = 0; i < n; i++) {
        double v = (t->tile.x0 == 0 ? 0.5 : (double)((i * 37 + t->task_id * 11) % 17) / 8.0);
        /* An odd task's first pixel lost one sample (NaN/Inf), as its
         * rejected count says: the coordinator checks the two agree. */
        uint32_t k = i == 0 && (t->task_id & 1) ? ns - 1 : ns;
        px[i] = (pt_pixel_acc){
            {pt_fixed_of(v * k), pt_fixed_of(v * 0.5 * k), pt_fixed_of(v * 0.25 * k)},
            pt_ufixed_of(v * v * k * 1.1),
            k,
            0};
    }
    memset(r, 0, sizeof *r);
    r->job_id = t->job_id;
    r->task_id = t->task_id;
    r->tile = t->tile;
    r->s0 = t->s0;
    r->s1 = t->s1;
    r->rejected = t->task_id & 1;
    r->rays = 1000 + t->task_id;
    r->npixels = n;
    r->pixels = px;
    if (proto_film_passes(t->film_flags)) {
        /* The passes' sums: some of each, and two Cryptomatte ids. */
        memset(pa, 0, (size_t)n * sizeof *pa);
        for (uint32_t i = 0; i < n; i++) {
            for (int k = 0; k < PT_PASS_SUMS; k++)
                pa[i].s[k] = pt_fixed_of(0.125 * (k + 1) * px[i].n);
            for (int k = 0; k < PT_PASS_SQS; k++)
                pa[i].sq[k] = pt_ufixed_of(0.5 * px[i].n);
            pa[i].n_even = px[i].n / 2;
            for (int k = 0; k < PT_CRYPTO_KINDS; k++) {
                pa[i].cid[k][0] = 7u + (uint32_t)k;
                pa[i].cid[k][1] = 0xdeadbeefu;
                pa[i].ccnt[k][0] = 1;
                pa[i].ccnt[k][1] = px[i].n - 1;
            }
        }
        r->pass = pa;
    }
}

/* Validates, logs (its frame), then merges a task's result, as the
 * coordinator does once the record is durable; a
 * task of a tile that adaptive sampling stopped is dropped unlogged. */
static void log_and_merge(srv_state *st, srv_job *job, const proto_task *t)
{
    static pt_pixel_acc px[64];
    static pt_pass_acc pa[64];
    proto_result r;
    fake_result(t, px, pa, &r);
    pt_error err = {0};
    int lease = -1;
    srv_outcome o = srv_job_validate(job, 1, &r, &lease, &err);
    if (o == SRV_NOT_LEASED || o == SRV_DUPLICATE)
        return;
    proto_writer w;
    proto_writer_init(&w, PROTO_MAX_PAYLOAD + PROTO_FRAME_OVERHEAD);
    size_t mark;
    if (o != SRV_MERGED || proto_frame_begin(&w, PROTO_MSG_RESULT, &mark, &err) != PT_OK ||
        proto_frame_finish(&w, mark, proto_msg_encode_result(&w, &r, &err), &err) != PT_OK ||
        srv_state_log_result(st, FUZZ_JOB_ID, w.buf, w.len, &err) != PT_OK ||
        srv_job_result_validated(job, lease, &r, 0, &err) != SRV_MERGED) {
        fprintf(stderr, "task %llu: %s\n", (unsigned long long)t->task_id, err.msg);
        failures++;
    }
    proto_writer_fini(&w);
}

static void gen_state(const char *dir, const char *tmp)
{
    pt_error err = {0};
    char sdir[4096];
    snprintf(sdir, sizeof sdir, "%s/state", tmp);
    srv_state *st = NULL;
    if (srv_state_open(sdir, &srv_job_state_codec, &st, &err) != PT_OK) {
        fprintf(stderr, "%s\n", err.msg);
        failures++;
        return;
    }
    /* The queue: empty, then three jobs in every kind of state. */
    if (srv_state_save_queue(st, NULL, 0, 1, &err) != PT_OK)
        failures++;
    emit_state_file(dir, "fuzz_queue", "queue_empty", sdir, "queue", FUZZ_MODE_SEAL, 0, 0);
    srv_job_record recs[3];
    memset(recs, 0, sizeof recs);
    for (int i = 0; i < 3; i++) {
        srv_job_record *j = &recs[i];
        j->id = (uint64_t)(2 * i + 1);
        j->seq = (uint64_t)i;
        j->state = (uint8_t)(PROTO_JOB_QUEUED + 2 * i);
        j->priority = i - 1;
        snprintf(j->name, sizeof j->name, "job %d", i);
        snprintf(j->owner, sizeof j->owner, "client\x1b[%d", i);
        snprintf(j->scene, sizeof j->scene, "scene.gltf");
        snprintf(j->output, sizeof j->output, "%d-job.exr", i);
        j->submitted = 1700000000u + (uint64_t)i;
        j->params = FUZZ_JOB_PARAMS[i & 1];
        memcpy(j->hash, FUZZ_JOB_HASH, 32);
        j->bundle_size = 1234;
        j->samples_done = (uint64_t)i * 1000;
        j->seconds = 1.5 * i;
        j->error = i == 2 ? -1 : 0.01 * i;
        if (i == 2)
            snprintf(j->message, sizeof j->message, "scene refused: accessor 3");
    }
    srv_job_record *ptrs[3] = {&recs[0], &recs[1], &recs[2]};
    if (srv_state_save_queue(st, ptrs, 3, 9, &err) != PT_OK)
        failures++;
    emit_state_file(dir, "fuzz_queue", "queue_3jobs", sdir, "queue", FUZZ_MODE_SEAL, 0, 0);
    emit_state_file(dir, "fuzz_queue", "queue_3jobs_damaged", sdir, "queue", 0, 0, 100);
    emit_state_file(dir, "fuzz_queue", "queue_3jobs_cut", sdir, "queue", 0, 7, 0);
    emit_state_file(dir, "fuzz_queue", "queue_3jobs_cut_sealed", sdir, "queue", FUZZ_MODE_SEAL, 7,
                    0);

    /* Each job: a fresh checkpoint; a log with early arrivals held; the
     * checkpoint after them; the finished job's checkpoint. */
    for (uint8_t p = 0; p < 2; p++) {
        srv_job *job = NULL;
        if (srv_job_new(FUZZ_JOB_ID, &FUZZ_JOB_PARAMS[p], FUZZ_JOB_HASH, &job, &err) != PT_OK) {
            failures++;
            continue;
        }
        srv_ckpt_extra x = {12.5, 3, 100000};
        char name[64], rel[64];
        snprintf(rel, sizeof rel, "jobs/%u/checkpoint", FUZZ_JOB_ID);
        uint8_t sealed = (uint8_t)(FUZZ_MODE_SEAL | p);
        if (srv_state_checkpoint(st, job, &x, &err) != PT_OK)
            failures++;
        snprintf(name, sizeof name, "ckpt%u_fresh", p);
        emit_state_file(dir, "fuzz_checkpoint", name, sdir, rel, sealed, 0, 0);

        proto_task tasks[32];
        uint32_t nt = 0;
        while (nt < 32 && srv_job_lease(job, 1, 0, 1000, &tasks[nt]))
            nt++;
        uint32_t tiles = srv_job_tiles(job);
        /* Chunk 1 of tile 0 before chunk 0 (held), every chunk 0, chunk 2 of
         * tile 1 (held). */
        log_and_merge(st, job, &tasks[tiles]);
        for (uint32_t t = 0; t < tiles; t++)
            log_and_merge(st, job, &tasks[t]);
        log_and_merge(st, job, &tasks[2 * tiles + 1]);
        if (srv_state_sync(st, &err) != PT_OK) /* the records are written by a commit */
            failures++;
        snprintf(rel, sizeof rel, "jobs/%u/results.log", FUZZ_JOB_ID);
        snprintf(name, sizeof name, "log%u", p);
        emit_state_file(dir, "fuzz_results_log", name, sdir, rel, sealed, 0, 0);
        snprintf(name, sizeof name, "log%u_torn", p);
        emit_state_file(dir, "fuzz_results_log", name, sdir, rel, sealed, 9, 0);
        snprintf(name, sizeof name, "log%u_damaged", p);
        emit_state_file(dir, "fuzz_results_log", name, sdir, rel, p, 0, 100);

        x.seconds = 30.25;
        if (srv_state_checkpoint(st, job, &x, &err) != PT_OK)
            failures++;
        snprintf(rel, sizeof rel, "jobs/%u/checkpoint", FUZZ_JOB_ID);
        snprintf(name, sizeof name, "ckpt%u_held", p);
        emit_state_file(dir, "fuzz_checkpoint", name, sdir, rel, sealed, 0, 0);
        snprintf(name, sizeof name, "ckpt%u_damaged", p);
        emit_state_file(dir, "fuzz_checkpoint", name, sdir, rel, p, 0, 100);
        snprintf(name, sizeof name, "ckpt%u_cut_sealed", p);
        emit_state_file(dir, "fuzz_checkpoint", name, sdir, rel, sealed, 50, 0);
        snprintf(rel, sizeof rel, "jobs/%u/results.log", FUZZ_JOB_ID);
        snprintf(name, sizeof name, "log%u_header", p);
        emit_state_file(dir, "fuzz_results_log", name, sdir, rel, sealed, 0, 0);

        for (uint32_t k = tiles; k < nt; k++)
            if (k != tiles && k != 2 * tiles + 1)
                log_and_merge(st, job, &tasks[k]);
        if (!srv_job_complete(job) || srv_job_tiles_stopped(job) != (p ? 2u : 0u)) {
            fprintf(stderr, "job %u: not complete, or %u tiles stopped\n", p,
                    srv_job_tiles_stopped(job));
            failures++;
        }
        if (srv_state_checkpoint(st, job, &x, &err) != PT_OK)
            failures++;
        snprintf(rel, sizeof rel, "jobs/%u/checkpoint", FUZZ_JOB_ID);
        snprintf(name, sizeof name, "ckpt%u_done", p);
        emit_state_file(dir, "fuzz_checkpoint", name, sdir, rel, sealed, 0, 0);
        srv_job_free(job);
        srv_state_forget_job(st, FUZZ_JOB_ID);
    }
    srv_state_close(st);
}

/* fuzz_guide_pack: guide bytes packed as GUIDE_CHUNK carries them and, with
 * hostile, refused ones made from them: cut, a declared length one short,
 * trailing bytes, and a bomb. */
static void gen_guide_pack(const char *dir, const char *name, const uint8_t *raw, size_t n,
                           int hostile)
{
    uint8_t *pk = NULL;
    size_t len = 0;
    if (proto_guide_pack(raw, n, &pk, &len, NULL) != PT_OK) {
        failures++;
        return;
    }
    emit(dir, "fuzz_guide_pack", name, pk, len);
    if (hostile) {
        emit(dir, "fuzz_guide_pack", "cut", pk, len - 7);
        proto_put_u64(pk + 4, n - 1);
        emit(dir, "fuzz_guide_pack", "one_short", pk, len);
        proto_put_u64(pk + 4, n);
        uint8_t *more = pt_malloc(len + 3);
        if (more) {
            memcpy(more, pk, len);
            memset(more + len, 0xab, 3);
            emit(dir, "fuzz_guide_pack", "trailing", more, len + 3);
        }
        pt_free(more);
        /* 256 MiB declared, a few bytes of stream: refused before allocating. */
        uint8_t bomb[PROTO_GUIDE_PACK_HEADER + 8] = {0};
        proto_put_u32(bomb, PROTO_GUIDE_PACK_MAGIC);
        bomb[PROTO_GUIDE_PACK_HEADER] = 0x78; /* a zlib header */
        bomb[PROTO_GUIDE_PACK_HEADER + 1] = 0x01;
        proto_put_u64(bomb + 4, PROTO_MAX_GUIDE_BYTES);
        emit(dir, "fuzz_guide_pack", "bomb", bomb, sizeof bomb);
    }
    pt_free(pk);
}

/* fuzz_guide: a first pass's uniform guide, one built from statistics of
 * records in two directions, and three refused: cut, a bad magic, a tree
 * whose node shares a child (pt_guide_check's). */
static void gen_guide(const char *dir)
{
    pt_guide *g = NULL, *b = NULL;
    pt_guide_stats *st = NULL;
    proto_writer w;
    proto_writer_init(&w, PROTO_MAX_GUIDE_BYTES);
    if (pt_guide_new_uniform(pt_v3(-1, -1, -1), pt_v3(1, 1, 1), &g, NULL) != PT_OK ||
        pt_guide_stats_new(g, &st, NULL) != PT_OK) {
        failures++;
        goto done;
    }
    for (int k = 0; k < 4000; k++) {
        pt_vec3 p = pt_v3((float)(k % 7) / 7.0f - 0.5f, (float)(k % 5) / 5.0f - 0.5f, 0.1f);
        uint32_t cell = pt_guide_cell(g, p, pt_v3(0, 0, 1));
        pt_guide_stats_record(st, g, cell, pt_v3_norm(pt_v3(0.1f, 0.2f, 1.0f)), 5.0f);
        pt_guide_stats_record(st, g, cell, pt_v3_norm(pt_v3(-1.0f, 0.0f, 0.3f)), 0.5f);
    }
    if (pt_guide_build(g, st, 500, &b, NULL) != PT_OK) {
        failures++;
        goto done;
    }
    /* The smallest guide, under the fuzzers' input cap: one spatial leaf
     * whose six trees are single leaves. */
    {
        pt_guide_snode sn = {0, 0, 0};
        pt_guide_qnode qn[PT_GUIDE_FACES] = {{0, 0.0f}, {0, 1.0f}, {0, 0.0f},
                                             {0, 1.0f}, {0, 0.0f}, {0, 1.0f}};
        pt_guide small = {pt_v3(-1, -1, -1), pt_v3(1, 1, 1), 1, PT_GUIDE_FACES, &sn, qn};
        proto_writer_reset(&w);
        if (proto_guide_encode(&w, &small, NULL) != PT_OK)
            failures++;
        else {
            emit(dir, "fuzz_guide", "smallest", w.buf, w.len);
            gen_guide_pack(dir, "smallest", w.buf, w.len, 0);
        }
    }
    const pt_guide *gs[2] = {g, b};
    const char *names[2] = {"uniform", "built"};
    for (int k = 0; k < 2; k++) {
        proto_writer_reset(&w);
        if (proto_guide_encode(&w, gs[k], NULL) != PT_OK) {
            failures++;
            goto done;
        }
        emit(dir, "fuzz_guide", names[k], w.buf, w.len);
        gen_guide_pack(dir, names[k], w.buf, w.len, k == 0);
        if (k == 0) {
            emit(dir, "fuzz_guide", "cut", w.buf, w.len - 5);
            w.buf[0] ^= 1;
            emit(dir, "fuzz_guide", "bad_magic", w.buf, w.len);
            w.buf[0] ^= 1;
            /* qnode 1's child (a leaf of face 1's tree) pointed at face 0's first children */
            size_t at = PROTO_GUIDE_HEADER + 12 * (size_t)g->nsnode + 8 * 1;
            proto_put_u32(w.buf + at, g->qnode[0].child);
            emit(dir, "fuzz_guide", "shared_child", w.buf, w.len);
        }
    }
done:
    proto_writer_fini(&w);
    pt_guide_stats_free(st);
    pt_guide_free(g);
    pt_guide_free(b);
}

static void gen_files(const char *dir)
{
    char tmp[] = "/tmp/ptfuzz-gen.XXXXXX";
    if (!mkdtemp(tmp)) {
        perror(tmp);
        failures++;
        return;
    }
    gen_gltf(dir);
    gen_gltf_ext(dir);
    gen_gltf_anim(dir);
    gen_bundle(dir, tmp);
    gen_state(dir, tmp);
    gen_guide(dir);
    pt_remove_tree(tmp);
}

int main(int argc, char **argv)
{
    if (argc != 3 || (strcmp(argv[1], "write") && strcmp(argv[1], "check"))) {
        fprintf(stderr, "usage: %s write|check DIR\n", argv[0]);
        return 2;
    }
    write_mode = strcmp(argv[1], "write") == 0;
    const char *dir = argv[2];
    if (write_mode) {
        char path[4096];
        mkdir(dir, 0755);
        snprintf(path, sizeof path, "%s/fuzz_frame", dir);
        mkdir(path, 0755);
        snprintf(path, sizeof path, "%s/fuzz_msg", dir);
        mkdir(path, 0755);
        for (size_t i = 0; i < sizeof file_targets / sizeof file_targets[0]; i++) {
            snprintf(path, sizeof path, "%s/%s", dir, file_targets[i]);
            mkdir(path, 0755);
        }
    }
    proto_writer w;
    proto_writer_init(&w, PROTO_MAX_PAYLOAD);
    char name[64];

    for (int s = 0; s < SAMPLE_COUNT; s++) {
        for (int v = 0; v < 2; v++) {
            /* fuzz_msg: selector then payload; RESULT also through the caller's buffer. */
            for (int path = 0; path < (s == 9 ? 2 : 1); path++) {
                proto_writer_reset(&w);
                proto_w_u8(&w, (uint8_t)(s + path * SAMPLE_COUNT));
                uint16_t type = sample_payload(s, v, &w);
                if (!type || proto_writer_status(&w) != PT_OK) {
                    failures++;
                    continue;
                }
                snprintf(name, sizeof name, "%s_%d%s", proto_msg_type_name(type), v,
                         path ? "_buf" : "");
                emit(dir, "fuzz_msg", name, w.buf, w.len);
            }
            if (s == 9) {
                /* A RESULT with render passes' sums, through both paths. */
                for (int path = 0; path < 2; path++) {
                    proto_writer_reset(&w);
                    proto_w_u8(&w, (uint8_t)(s + path * SAMPLE_COUNT));
                    proto_result m = sample_result_passes(v);
                    if (proto_msg_encode_result(&w, &m, NULL) != PT_OK) {
                        failures++;
                        continue;
                    }
                    snprintf(name, sizeof name, "RESULT_passes_%d%s", v, path ? "_buf" : "");
                    emit(dir, "fuzz_msg", name, w.buf, w.len);
                }
            }
            /* fuzz_frame: one frame, whole and byte by byte. */
            proto_writer_reset(&w);
            proto_w_u8(&w, (uint8_t)(v ? 0x01 : 0x00));
            uint16_t type = sample_frame(s, v, &w);
            if (!type) {
                failures++;
                continue;
            }
            snprintf(name, sizeof name, "%s_%d", proto_msg_type_name(type), v);
            emit(dir, "fuzz_frame", name, w.buf, w.len);
        }
    }

    /* Streams: every sample in pieces of 4 (pre-auth cap) and of 16. */
    proto_writer_reset(&w);
    frames(&w, 0x07, 3);
    emit(dir, "fuzz_frame", "stream_all_preauth", w.buf, w.len);
    proto_writer_reset(&w);
    frames(&w, 0x1E, 1);
    emit(dir, "fuzz_frame", "stream_v0", w.buf, w.len);
    /* A stream that turns to garbage, and one cut short. */
    proto_writer_reset(&w);
    frames(&w, 0x02, 2);
    proto_w_bytes(&w, "GET / HTTP/1.1\r\n", 16);
    emit(dir, "fuzz_frame", "stream_then_garbage", w.buf, w.len);
    proto_writer_reset(&w);
    frames(&w, 0x04, 2);
    w.len -= 5;
    emit(dir, "fuzz_frame", "stream_cut", w.buf, w.len);
    /* Empty frames of the client types (LIST is empty by design; the
     * others' decoders refuse them). */
    proto_writer_reset(&w);
    proto_w_u8(&w, 0);
    for (uint16_t t = PROTO_MSG_SUBMIT; t <= PROTO_MSG_IMAGE; t++)
        if (proto_msg_type_known(t) && proto_frame_encode(&w, t, NULL, 0, NULL) != PT_OK)
            failures++;
    emit(dir, "fuzz_frame", "client_empty", w.buf, w.len);
    /* A client session: SUBMIT, UPLOAD (SCENE_CHUNK layout), the JOB_REF
     * requests, then the server's answers (IMAGE in the SCENE_CHUNK layout). */
    {
        static const uint16_t session[][2] = {
            {12, PROTO_MSG_SUBMIT},   {8, PROTO_MSG_UPLOAD},    {11, PROTO_MSG_SUBMITTED},
            {11, PROTO_MSG_STATUS},   {11, PROTO_MSG_CANCEL},   {11, PROTO_MSG_FETCH},
            {13, PROTO_MSG_JOB_INFO}, {14, PROTO_MSG_JOB_LIST}, {8, PROTO_MSG_IMAGE},
        };
        proto_writer pw;
        proto_writer_init(&pw, PROTO_MAX_PAYLOAD);
        proto_writer_reset(&w);
        proto_w_u8(&w, 0x0C);
        for (size_t i = 0; i < sizeof session / sizeof session[0]; i++) {
            proto_writer_reset(&pw);
            if (!sample_payload(session[i][0], 1, &pw) ||
                proto_frame_encode(&w, session[i][1], pw.buf, pw.len, NULL) != PT_OK)
                failures++;
        }
        proto_frame_encode(&w, PROTO_MSG_LIST, NULL, 0, NULL);
        proto_writer_fini(&pw);
        emit(dir, "fuzz_frame", "client_session", w.buf, w.len);
    }
    /* A denoised region: DENOISE_TASK, DENOISE_GET (SCENE_GET layout), the
     * input in DENOISE_CHUNK (SCENE_CHUNK layout), DENOISE_RESULT. */
    {
        static const uint16_t region[][2] = {
            {15, PROTO_MSG_DENOISE_TASK},
            {7, PROTO_MSG_DENOISE_GET},
            {8, PROTO_MSG_DENOISE_CHUNK},
            {16, PROTO_MSG_DENOISE_RESULT},
        };
        proto_writer pw;
        proto_writer_init(&pw, PROTO_MAX_PAYLOAD);
        proto_writer_reset(&w);
        proto_w_u8(&w, 0x0A);
        for (size_t i = 0; i < sizeof region / sizeof region[0]; i++) {
            proto_writer_reset(&pw);
            if (!sample_payload(region[i][0], 0, &pw) ||
                proto_frame_encode(&w, region[i][1], pw.buf, pw.len, NULL) != PT_OK)
                failures++;
        }
        proto_writer_fini(&pw);
        emit(dir, "fuzz_frame", "denoise_region", w.buf, w.len);
    }
    /* A header declaring a payload over the pre-auth cap. */
    uint8_t h[13] = {1, 'P', 'T', 'F', '1'};
    proto_put_u16(h + 5, PROTO_VERSION);
    proto_put_u16(h + 7, PROTO_MSG_HELLO);
    proto_put_u32(h + 9, PROTO_MAX_PAYLOAD_PREAUTH + 1);
    emit(dir, "fuzz_frame", "over_cap_preauth", h, sizeof h);
    /* A bad CRC. */
    proto_writer_reset(&w);
    proto_w_u8(&w, 0);
    sample_frame(5, 0, &w);
    w.buf[w.len - 1] ^= 0x80;
    emit(dir, "fuzz_frame", "bad_crc", w.buf, w.len);

    proto_writer_fini(&w);
    gen_files(dir);
    if (failures)
        fprintf(stderr, "%d corpus problems\n", failures);
    else
        printf("corpus %s: ok\n", write_mode ? "written" : "current");
    return failures ? 1 : 0;
}
