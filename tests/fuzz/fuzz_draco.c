/*
 * fuzz_draco.c - libFuzzer target for the KHR_draco_mesh_compression mesh
 * decoder (pt_draco_decode and its accessors, common/scene/draco.cpp over
 * Debian's libdraco).
 *
 * Input: a Draco buffer, as a glTF buffer view would hold it. Invariants: a
 * refusal names its cause and returns no mesh; a mesh decoded is within the
 * caps given, every face names points below the point count, and attributes
 * 0-7 either convert to every glTF component type with 1-4 components or are
 * refused with a message; nothing is left allocated through pt_malloc.
 * Seeds (corpus/fuzz_draco/): a 4-triangle mesh with POSITION, NORMAL and
 * TEXCOORD encoded by libdraco's Encoder with edgebreaker and with
 * sequential connectivity (quantized to 11, 8 and 10 bits), sequential
 * without quantization, and a 2-point cloud (refused: not a mesh).
 */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/scene/draco.h"
#include "tests/fuzz/fuzz_util.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    /* Caps small enough that the harness never allocates much itself. */
    const uint64_t max_points = 1u << 16, max_faces = 1u << 16;
    int64_t live = pt_alloc_live();
    pt_draco_mesh *m = NULL;
    pt_error err = {0};
    pt_status st = pt_draco_decode(data, size, max_points, max_faces, &m, &err);
    if (st != PT_OK) {
        FUZZ_CHECK(m == NULL && err.msg[0] != 0);
        FUZZ_CHECK(pt_alloc_live() == live);
        return 0;
    }
    uint32_t np = pt_draco_points(m), nf = pt_draco_faces(m);
    FUZZ_CHECK(np <= max_points && nf <= max_faces);
    uint32_t *idx = malloc(3 * (size_t)nf * sizeof *idx + 1);
    FUZZ_CHECK(idx != NULL);
    pt_draco_indices(m, idx);
    for (size_t i = 0; i < 3 * (size_t)nf; i++)
        FUZZ_CHECK(idx[i] < np);
    free(idx);
    static const int ctypes[6] = {5120, 5121, 5122, 5123, 5125, 5126};
    uint8_t *out = malloc((size_t)np * 16 + 1);
    FUZZ_CHECK(out != NULL);
    for (uint32_t id = 0; id < 8; id++)
        for (int c = 0; c < 6; c++)
            for (int n = 1; n <= 4; n++) {
                pt_error e = {0};
                if (pt_draco_attribute(m, id, ctypes[c], n, out, &e) != PT_OK)
                    FUZZ_CHECK(e.msg[0] != 0);
            }
    free(out);
    pt_draco_free(m);
    FUZZ_CHECK(pt_alloc_live() == live);
    return 0;
}
