/*
 * paired.h - two scenes rendered with the same random numbers, compared
 * sample by sample (test_specgloss.c, test_anisotropy.c).
 *
 * paired_differing renders a and b (side x side, spp samples, seed 7, under
 * env) and counts the pixel channels where they differ: the mean of the
 * paired differences of the samples is more than 5 of its standard errors
 * from 0 (a paired t-test, the error from the differences' own spread) and
 * more than float rounding of the inputs, 1e-5 of the pixel's value
 * (+ 1e-8). A sample that takes another path in one render (a decision on
 * a rounded number) is one large difference among spp: it moves the mean by
 * about one standard error, never five. NaN or Inf samples fail a CHECK.
 * Returns the count, or -1 when a renderer could not be made.
 *
 * load_shared_asset loads a sample asset of ../shared/scenes (rel under
 * PT_SHARED_SCENES) and CHECKs that no loader warning names `word` (the
 * extension it is there for). A missing file fails under CI=true and is
 * skipped elsewhere; either way, and when it does not load, NULL.
 *
 * paired_blocks_z renders side x side pixels of spp samples with renderers a
 * and b (the same scene, parameters and seed but for the estimator under
 * test), sample by sample, and counts the blocks (bs x bs pixels) x
 * channels where the paired differences' mean is more than z_crit(1e-3,
 * blocks x 3) standard errors from 0 (blocks.h: Bonferroni), the error
 * from the differences' own spread, and more than rel_tol of the block's
 * mean in a (0 for any difference: float rounding that moves every sample
 * the same way, as a scene's scale does, is a difference of rel_tol); it
 * prints the blocks that differ under name, and fills the largest |z|, the
 * images' mean green, the samples that were not finite and each renderer's
 * stats.
 *
 * render_smoke renders a loaded sample asset at 32 x 32, 8 spp, under a
 * uniform grey sky, and CHECKs that every sample was accepted (no NaN or
 * Inf): the asset's new material through the whole integrator.
 */
#ifndef PT_TESTS_COMMON_RENDER_PAIRED_H
#define PT_TESTS_COMMON_RENDER_PAIRED_H

#include <math.h>

#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/env.h"
#include "common/render/render.h"
#include "tests/check.h"
#include "tests/common/render/blocks.h"

typedef struct asset_warn {
    const char *word;
    int hit;
} asset_warn;

static inline void asset_note(void *user, const char *message)
{
    asset_warn *w = user;
    if (strstr(message, w->word))
        w->hit = 1;
}

static inline pt_scene *load_shared_asset(const char *rel, const char *word)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/%s", PT_SHARED_SCENES, rel);
    if (!check_shared_file(path))
        return NULL;
    asset_warn w = {word, 0};
    pt_scene_opts o = {0};
    o.warn = asset_note;
    o.warn_user = &w;
    pt_scene *s = NULL;
    pt_error err = {0};
    CHECKF(pt_scene_load(path, &o, &s, &err) == PT_OK, "%s: %s", path, err.msg);
    CHECKF(!w.hit, "%s: a warning about %s", path, word);
    return s;
}

static inline void render_smoke(const pt_scene *s)
{
    pt_error err = {0};
    pt_env *env = NULL;
    CHECK(pt_env_uniform(pt_v3(0.5f, 0.5f, 0.5f), &env, &err) == PT_OK);
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = p.height = 32;
    p.env = env;
    pt_renderer *r = NULL;
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    pt_pixel_acc *acc = pt_malloc_array(32 * 32, sizeof *acc);
    if (r && acc) {
        memset(acc, 0, 32 * 32 * sizeof *acc);
        pt_render_stats st = {0};
        pt_render_tile(r, (pt_rect){0, 0, 32, 32}, 0, 8, acc, &st);
        CHECK(st.rejected == 0 && st.samples == 32 * 32 * 8);
    }
    pt_free(acc);
    pt_renderer_free(r);
    pt_env_free(env);
}

/* A renderer of side x side pixels, seed 7, under env, bidirectional when
 * bdpt: paired_differing's, and test_stress's scale check's. */
static inline pt_renderer *paired_renderer(const pt_scene *s, const pt_env *env, uint32_t side,
                                           int bdpt)
{
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = p.height = side;
    p.seed = 7;
    p.env = env;
    p.bdpt = bdpt != 0;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    return r;
}

static inline int paired_differing(const pt_scene *a, const pt_scene *b, const pt_env *env,
                                   uint32_t side, uint32_t spp)
{
    pt_renderer *ra = paired_renderer(a, env, side, 0), *rb = paired_renderer(b, env, side, 0);
    int count = -1;
    uint64_t bad = 0;
    if (ra && rb) {
        count = 0;
        for (uint32_t i = 0; i < side * side; i++) {
            double sum[3] = {0, 0, 0}, sq[3] = {0, 0, 0}, va[3] = {0, 0, 0};
            for (uint32_t k = 0; k < spp; k++) {
                pt_render_stats st = {0};
                int cov = 0;
                pt_vec3 x = pt_render_sample(ra, i % side, i / side, k, &st, &cov);
                pt_vec3 y = pt_render_sample(rb, i % side, i / side, k, &st, &cov);
                const double xa[3] = {x.x, x.y, x.z}, ya[3] = {y.x, y.y, y.z};
                for (int c = 0; c < 3; c++) {
                    bad += !isfinite(xa[c]) || !isfinite(ya[c]);
                    double d = xa[c] - ya[c];
                    sum[c] += d;
                    sq[c] += d * d;
                    va[c] += xa[c];
                }
            }
            for (int c = 0; c < 3; c++) {
                double m = sum[c] / spp;
                double se = sqrt(fmax(sq[c] / spp - m * m, 0.0) / (spp - 1.0));
                if (fabs(m) > 5.0 * se && fabs(m) > 1e-5 * fabs(va[c] / spp) + 1e-8)
                    count++;
            }
        }
    }
    CHECK(bad == 0);
    pt_renderer_free(ra);
    pt_renderer_free(rb);
    return count;
}

typedef struct paired_result {
    uint32_t bad, tests;   /* block channels past the bound, of */
    double z_bound, z_max; /* the bound, the largest |z| */
    double mean_a, mean_b; /* green, over the image */
    uint64_t nonfinite;
    pt_render_stats sa, sb;
} paired_result;

static inline paired_result paired_blocks_z(const char *name, pt_renderer *a, pt_renderer *b,
                                            uint32_t side, uint32_t bs, uint32_t spp,
                                            double rel_tol)
{
    paired_result pr;
    memset(&pr, 0, sizeof pr);
    const uint32_t nb = side / bs;
    pr.tests = 3 * nb * nb;
    pr.z_bound = z_crit(0.001, (int)pr.tests);
    for (uint32_t by = 0; by < nb; by++)
        for (uint32_t bx = 0; bx < nb; bx++) {
            double sum[3] = {0, 0, 0}, sq[3] = {0, 0, 0}, av[3] = {0, 0, 0};
            uint64_t n = 0;
            for (uint32_t y = by * bs; y < (by + 1) * bs; y++)
                for (uint32_t x = bx * bs; x < (bx + 1) * bs; x++)
                    for (uint32_t i = 0; i < spp; i++) {
                        pt_vec3 va = pt_render_sample(a, x, y, i, &pr.sa, NULL);
                        pt_vec3 vb = pt_render_sample(b, x, y, i, &pr.sb, NULL);
                        if (!pt_isfinite3(va) || !pt_isfinite3(vb)) {
                            pr.nonfinite++;
                            continue;
                        }
                        const double d[3] = {va.x - vb.x, va.y - vb.y, va.z - vb.z};
                        const double xa[3] = {va.x, va.y, va.z};
                        for (int c = 0; c < 3; c++) {
                            sum[c] += d[c];
                            sq[c] += d[c] * d[c];
                            av[c] += xa[c];
                        }
                        pr.mean_a += va.y;
                        pr.mean_b += vb.y;
                        n++;
                    }
            for (int c = 0; c < 3; c++) {
                double m = sum[c] / (double)n;
                double se = sqrt(fmax(sq[c] / (double)n - m * m, 0.0) / ((double)n - 1.0));
                if (!(se > 0.0))
                    continue; /* no difference at all */
                double z = fabs(m) / se;
                pr.z_max = fmax(pr.z_max, z);
                if (z > pr.z_bound && fabs(m) > rel_tol * fabs(av[c] / (double)n)) {
                    pr.bad++;
                    printf("%s: block %u,%u channel %d differs by %.5f +- %.5f\n", name, bx, by, c,
                           m, se);
                }
            }
        }
    pr.mean_a /= (double)side * side * spp;
    pr.mean_b /= (double)side * side * spp;
    return pr;
}

#endif
