/*
 * fuzz_meshopt.c - libFuzzer target for EXT_meshopt_compression's buffer
 * view decoder (pt_meshopt_decode: common/scene/meshopt.c over Debian's
 * libmeshoptimizer).
 *
 * Input: a 5-byte header, then the compressed stream. Header: byte 0 the
 * mode (mod 3: ATTRIBUTES, TRIANGLES, INDICES), byte 1 the filter (mod 4:
 * NONE, OCTAHEDRAL, QUATERNION, EXPONENTIAL), byte 2 the stride minus 1
 * (1-256), bytes 3-4 the count (little-endian, up to 65535). Invariants: a refusal names
 * its cause; a decode writes only the count x stride bytes it is given
 * (ASan guards the buffer's end) and decoded indices of a count that the
 * codec accepts are plain numbers the importer then bounds-checks. Seeds
 * (corpus/fuzz_meshopt/): a grid's positions (vertex codec), its normals
 * (vertex codec after the 8-bit octahedral filter) and its triangles (index
 * codec), encoded by libmeshoptimizer.
 */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>

#include "common/scene/meshopt.h"
#include "tests/fuzz/fuzz_util.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 5)
        return 0;
    int mode = data[0] % 3, filter = data[1] % 4;
    uint32_t stride = (uint32_t)data[2] + 1;
    uint64_t count = (uint64_t)data[3] | (uint64_t)data[4] << 8;
    uint8_t *out = malloc((size_t)(count * stride) + 1);
    FUZZ_CHECK(out != NULL);
    pt_error err = {0};
    if (pt_meshopt_decode(data + 5, size - 5, count, stride, mode, filter, out, &err) != PT_OK)
        FUZZ_CHECK(err.msg[0] != 0);
    free(out);
    return 0;
}
