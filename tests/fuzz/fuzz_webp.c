/*
 * fuzz_webp.c - libFuzzer target for EXT_texture_webp's image decoder
 * (pt_webp_size, pt_webp_decode: common/scene/webp.c over Debian's libwebp).
 *
 * Input: a WebP file's bytes. Invariants: the size read from the headers is
 * what the decode checks against (a bitstream that decodes to another size
 * is refused), a refusal names its cause, and an image under the harness's
 * cap (1024 x 1024) decodes into a buffer of exactly w x h x 4 bytes or is
 * refused. Seeds (corpus/fuzz_webp/): an 8x6 image encoded lossless and
 * lossy with alpha, and a 4x4 lossy one, by libwebp's encoder.
 */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>

#include "common/scene/webp.h"
#include "tests/fuzz/fuzz_util.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    uint32_t w = 0, h = 0;
    pt_error err = {0};
    if (pt_webp_size(data, size, &w, &h, &err) != PT_OK) {
        FUZZ_CHECK(err.msg[0] != 0);
        return 0;
    }
    FUZZ_CHECK(w > 0 && h > 0);
    if (w > 1024 || h > 1024)
        return 0;
    uint8_t *rgba = malloc((size_t)w * h * 4);
    FUZZ_CHECK(rgba != NULL);
    pt_error e = {0};
    if (pt_webp_decode(data, size, w, h, rgba, &e) != PT_OK)
        FUZZ_CHECK(e.msg[0] != 0);
    /* A size that is not the file's is refused. */
    pt_error e2 = {0};
    FUZZ_CHECK(pt_webp_decode(data, size, w + 1, h, rgba, &e2) != PT_OK);
    free(rgba);
    return 0;
}
