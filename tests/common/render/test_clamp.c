/*
 * test_clamp.c - sample clamping (pt_render_params.clamp_direct and
 * clamp_indirect; Cycles' Clamp Direct and Clamp Indirect).
 *
 * - Exact: inside a black furnace sphere emitting 2 in every channel, each
 *   camera ray sees R + G + B = 6 at once (direct light): clamp_direct 3
 *   makes every pixel 1 exactly, and every sample counts one clamped
 *   contribution; clamp_indirect alone leaves the pixels at 2.
 * - The split: in a furnace of albedo a and emission E, the light reaching
 *   the camera directly and the first surface directly sums to E (1 + a),
 *   the rest to E a^2 / (1 - a). With clamp_indirect 1e-30 the image reads
 *   E (1 + a) within 5 standard errors; unclamped, E / (1 - a).
 * - A bound: with both limits set, no sample of the Cornell box (8 bounces
 *   at most) exceeds 3 clamp_direct + 2 max_depth clamp_indirect in
 *   R + G + B (at most three direct contributions, two per deeper bounce),
 *   where unclamped samples do (1 spp: a pixel is a sample).
 * - Nothing clamped, nothing changed: limits no sample reaches give the
 *   general variant's bits, from the clamped variant.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/film.h"
#include "common/render/render.h"
#include "tests/check.h"
#include "tests/common/render/furnace.h"

/* max_depth 0: the default. */
static pt_renderer *clamped_renderer(const pt_scene *s, uint32_t w, uint32_t h, float direct,
                                     float indirect, uint32_t max_depth)
{
    pt_render_params p = {0};
    pt_render_params_default(&p);
    if (max_depth)
        p.max_depth = max_depth;
    p.width = w;
    p.height = h;
    p.seed = 11;
    p.clamp_direct = direct;
    p.clamp_indirect = indirect;
    pt_renderer *r = NULL;
    pt_error err = {0};
    if (pt_renderer_new(s, &p, &r, &err) != PT_OK)
        fprintf(stderr, "renderer: %s\n", err.msg);
    return r;
}

static void exact_direct(void)
{
    pt_scene *s = flat_furnace_of(0.0f, 2.0f, NULL);
    CHECK(s != NULL);
    if (!s)
        return;
    const uint32_t W = 8, H = 8, SPP = 4;
    pt_pixel_acc acc[64];
    pt_rect all = {0, 0, W, H};
    for (int k = 0; k < 2; k++) {
        /* k 0: direct clamped to 3 (each channel 1); k 1: indirect only. */
        pt_renderer *r = clamped_renderer(s, W, H, k == 0 ? 3.0f : 0.0f, k == 0 ? 0.0f : 1e-3f, 0);
        CHECK(r != NULL);
        if (!r)
            continue;
        CHECK(strcmp(pt_renderer_variant(r), "clamped") == 0);
        pt_render_stats st = {0};
        pt_render_tile(r, all, 0, SPP, acc, &st);
        double want = k == 0 ? 1.0 : 2.0;
        for (uint32_t i = 0; i < W * H; i++)
            for (int c = 0; c < 3; c++) {
                double v = pt_acc_sum(&acc[i], c) / acc[i].n;
                CHECKF(fabs(v - want) < 1e-6, "limits %d: pixel %u channel %d is %.9g, not %g", k,
                       i, c, v, want);
            }
        CHECKF(st.clamped == (k == 0 ? (uint64_t)W * H * SPP : 0u), "limits %d: %llu clamped", k,
               (unsigned long long)st.clamped);
        pt_renderer_free(r);
    }
    pt_scene_free(s);
}

static void direct_split(void)
{
    const float a = 0.5f, E = 1.0f;
    pt_scene *s = flat_furnace_of(a, E, NULL);
    CHECK(s != NULL);
    if (!s)
        return;
    const uint32_t W = 16, H = 16, SPP = 64;
    pt_pixel_acc *acc = pt_malloc_array(W * H, sizeof *acc);
    pt_rect all = {0, 0, W, H};
    for (int k = 0; k < 2; k++) {
        pt_renderer *r = clamped_renderer(s, W, H, 0.0f, k == 0 ? 1e-30f : 0.0f, 0);
        CHECK(r != NULL && acc != NULL);
        if (!r || !acc) {
            pt_renderer_free(r);
            continue;
        }
        pt_render_stats st = {0};
        pt_render_tile(r, all, 0, SPP, acc, &st);
        /* The image mean and its standard error from the pixels' spread
         * (each pixel an independent estimate of the same value). */
        double sum = 0.0, sq = 0.0;
        for (uint32_t i = 0; i < W * H; i++) {
            double v = pt_acc_sum(&acc[i], 1) / acc[i].n;
            sum += v;
            sq += v * v;
        }
        double n = (double)W * H, mean = sum / n;
        double se = sqrt(fmax(sq / n - mean * mean, 0.0) / (n - 1.0));
        double want = k == 0 ? (double)E * (1.0 + a) : (double)E / (1.0 - a);
        CHECKF(fabs(mean - want) <= 5.0 * se + 1e-6,
               "clamp_indirect %s: mean %.5f, expected %.5f (standard error %.2e)",
               k == 0 ? "1e-30" : "off", mean, want, se);
        CHECKF(se < 0.01, "standard error %.3g: too noisy to tell %.3g from %.3g", se,
               (double)E * (1.0 + a), (double)E / (1.0 - a));
        CHECK(k == 0 ? st.clamped > 0 : st.clamped == 0);
        printf("furnace a %.2f: clamp_indirect %s reads %.5f (expected %.5f, se %.1e)\n", (double)a,
               k == 0 ? "1e-30" : "off", mean, want, se);
        pt_renderer_free(r);
    }
    pt_free(acc);
    pt_scene_free(s);
}

static void bound_and_identity(void)
{
    pt_scene *s = furnace_load("scenes/cornell_box.gltf");
    CHECK(s != NULL);
    if (!s)
        return;
    const uint32_t W = 32, H = 32;
    const float D = 0.2f, I = 0.05f;
    pt_pixel_acc a[32 * 32], b[32 * 32];
    pt_rect all = {0, 0, W, H};
    pt_renderer *plain = clamped_renderer(s, W, H, 0.0f, 0.0f, 8);
    pt_renderer *cl = clamped_renderer(s, W, H, D, I, 8);
    pt_renderer *loose = clamped_renderer(s, W, H, 1e30f, 1e30f, 8);
    CHECK(plain && cl && loose);
    if (plain && cl && loose) {
        const pt_render_params *pp = pt_renderer_params(cl);
        double bound = 3.0 * D + 2.0 * pp->max_depth * I;
        pt_render_tile(plain, all, 0, 1, a, NULL);
        pt_render_tile(cl, all, 0, 1, b, NULL);
        double worst_plain = 0.0, worst = 0.0;
        for (uint32_t i = 0; i < W * H; i++) {
            double sa = 0.0, sb = 0.0;
            for (int c = 0; c < 3; c++) {
                sa += fabs(pt_acc_sum(&a[i], c));
                sb += fabs(pt_acc_sum(&b[i], c));
            }
            worst_plain = fmax(worst_plain, sa);
            worst = fmax(worst, sb);
        }
        CHECKF(worst <= bound * (1.0 + 1e-5), "a clamped sample reaches %.6g, over %.6g", worst,
               bound);
        CHECKF(worst_plain > bound, "no unclamped sample passes %.4g (%.4g): no test", bound,
               worst_plain);
        /* Limits no sample reaches: the general variant's bits. */
        CHECK(strcmp(pt_renderer_variant(loose), "clamped") == 0);
        pt_render_stats st = {0};
        pt_render_tile(plain, all, 0, 8, a, NULL);
        pt_render_tile(loose, all, 0, 8, b, &st);
        CHECK(memcmp(a, b, sizeof a) == 0);
        CHECK(st.clamped == 0);
    }
    pt_renderer_free(plain);
    pt_renderer_free(cl);
    pt_renderer_free(loose);
    pt_scene_free(s);
}

int main(void)
{
    exact_direct();
    direct_split();
    bound_and_identity();
    return check_report();
}
