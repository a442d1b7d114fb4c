/*
 * fuzz_envmap.c - libFuzzer target for the environment-map reader's
 * Radiance decoder (pt_envmap_decode, common/image/envmap.c) and the
 * sampling distribution built from what it returns (pt_env_new,
 * common/render/env.c).
 *
 * Input: the file's bytes. Invariants: a refusal names its cause and leaves
 * no map; a map read is within PT_ENVMAP_MAX_SIDE, about 2:1, and every
 * texel is a finite radiance in [0, PT_ENVMAP_MAX_VALUE]; its environment
 * builds, and a few samples have unit directions and a finite positive pdf
 * that pt_env_pdf agrees with, with and without a receiver's normal (or
 * the map is black); nothing is left
 * allocated. Seeds (corpus/fuzz_envmap/): a flat map, a run-length one and
 * one cut short, committed as written. stb_image, which the decoder
 * replaced, loops forever on the last one.
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/image/envmap.h"
#include "common/render/env.h"
#include "tests/fuzz/fuzz_util.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    int64_t live = pt_alloc_live();
    pt_envmap m;
    pt_error err = {0};
    pt_status st = pt_envmap_decode(data, size, "map.hdr", &m, &err);
    fuzz_note("decode", st, &err);
    FUZZ_CHECK(st == PT_OK || (st == err.code && err.msg[0] && m.rgb == NULL));
    if (st == PT_OK) {
        FUZZ_CHECK(m.width > 0 && m.height > 0 && m.width <= PT_ENVMAP_MAX_SIDE &&
                   m.height <= PT_ENVMAP_MAX_SIDE);
        FUZZ_CHECK(m.width + 1 >= 2 * m.height && m.width <= 2 * m.height + 1);
        for (size_t i = 0; i < (size_t)m.width * m.height * 3; i++)
            FUZZ_CHECK(m.rgb[i] >= 0.0f && m.rgb[i] <= PT_ENVMAP_MAX_VALUE);
        pt_env *env = NULL;
        FUZZ_CHECK(pt_env_new(&m, 1.0f, 33.0f, &env, &err) == PT_OK);
        for (int k = 0; env && k < 32; k++) {
            int which = k & 1 ? PT_ENV_MIS : PT_ENV_FULL;
            float u[2] = {(float)(k / 2) / 16.0f, (float)((k / 2 * 7) % 16) / 16.0f + 0.03f}, pdf;
            pt_vec3 d, rad;
            /* Half the samples for a receiver facing down (env.h's
             * split by the normal, where the map has a sun). */
            pt_vec3 n = k % 4 < 2 ? pt_v3(0.0f, 0.0f, 0.0f) : pt_v3(0.0f, -1.0f, 0.0f);
            if (!pt_env_sample(env, u, which, n, &d, &rad, &pdf))
                continue;
            FUZZ_CHECK(fabsf(pt_v3_len(d) - 1.0f) < 1e-3f && isfinite(pdf) && pdf > 0.0f);
            FUZZ_CHECK(pt_isfinite3(rad) && rad.x >= 0.0f && rad.y >= 0.0f && rad.z >= 0.0f);
            float p2 = pt_env_pdf(env, d, which, n);
            FUZZ_CHECK(isfinite(p2) && p2 >= 0.0f);
        }
        pt_env_free(env);
        pt_envmap_free(&m);
    }
    FUZZ_CHECK(pt_alloc_live() == live);
    return 0;
}
