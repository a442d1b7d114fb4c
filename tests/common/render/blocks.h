/*
 * blocks.h - two renders of one scene with different light sampling
 * (pt_render_params.light_select), compared per 8 x 8 block of a 32 x 32
 * image at 256 spp (test_light_tree.c, test_sphtri.c).
 *
 * blocks_differing renders with select_a (seed 11) and select_b (seed 12,
 * independent) and counts the blocks x channels whose means differ by more
 * than z_crit(1e-3, blocks x 3) standard errors: the two-sided normal
 * quantile for a family-wise false alarm of 1e-3 (Bonferroni). The standard
 * error is each render's from its pixels' own sample variances, which is
 * conservative under the sampler's stratification. *var_ratio (may be NULL)
 * gets the mean pixel variance of b over that of a. NaN or Inf samples
 * fail a CHECK. Returns the count, or -1 when a renderer could not be made.
 */
#ifndef PT_TESTS_COMMON_RENDER_BLOCKS_H
#define PT_TESTS_COMMON_RENDER_BLOCKS_H

#include <math.h>
#include <stdio.h>

#include "common/render/render.h"
#include "tests/check.h"

static inline double z_crit(double alpha, int m)
{
    double lo = 0.0, hi = 20.0, target = alpha / m;
    for (int i = 0; i < 200; i++) {
        double mid = 0.5 * (lo + hi);
        if (erfc(mid / sqrt(2.0)) > target)
            lo = mid;
        else
            hi = mid;
    }
    return hi;
}

static inline pt_renderer *blocks_renderer(const pt_scene *s, const pt_env *env, uint32_t side,
                                           uint32_t select, uint32_t seed)
{
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = p.height = side;
    p.seed = seed;
    p.env = env;
    p.light_select = select;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    return r;
}

static inline int blocks_differing(const pt_scene *s, const pt_env *env, uint32_t select_a,
                                   uint32_t select_b, const char *what, double *var_ratio)
{
    enum { SIDE = 32, BLOCK = 8, SPP = 256 };
    pt_renderer *r[2] = {blocks_renderer(s, env, SIDE, select_a, 11),
                         blocks_renderer(s, env, SIDE, select_b, 12)};
    int count = -1;
    if (r[0] && r[1]) {
        const int nb = (SIDE / BLOCK) * (SIDE / BLOCK);
        double zc = z_crit(1e-3, nb * 3), zmax = 0.0, pix_var[2] = {0, 0};
        count = 0;
        uint64_t bad = 0;
        for (int b = 0; b < nb; b++) {
            int bx = b % (SIDE / BLOCK), by = b / (SIDE / BLOCK);
            double mean[2][3] = {{0}}, var[2][3] = {{0}};
            for (int k = 0; k < 2; k++)
                for (int y = by * BLOCK; y < (by + 1) * BLOCK; y++)
                    for (int x = bx * BLOCK; x < (bx + 1) * BLOCK; x++) {
                        double sum[3] = {0}, sq[3] = {0};
                        for (uint32_t i = 0; i < SPP; i++) {
                            pt_render_stats st = {0};
                            int cov = 0;
                            pt_vec3 c =
                                pt_render_sample(r[k], (uint32_t)x, (uint32_t)y, i, &st, &cov);
                            const double ca[3] = {c.x, c.y, c.z};
                            for (int ch = 0; ch < 3; ch++) {
                                bad += !isfinite(ca[ch]);
                                sum[ch] += ca[ch];
                                sq[ch] += ca[ch] * ca[ch];
                            }
                        }
                        for (int ch = 0; ch < 3; ch++) {
                            double m = sum[ch] / SPP, v = fmax(sq[ch] / SPP - m * m, 0.0);
                            mean[k][ch] += m / (BLOCK * BLOCK);
                            /* the pixel mean's variance, over the block's count squared */
                            var[k][ch] += v / (SPP - 1.0) / (BLOCK * BLOCK * BLOCK * BLOCK);
                            pix_var[k] += v;
                        }
                    }
            for (int ch = 0; ch < 3; ch++) {
                double se = sqrt(var[0][ch] + var[1][ch]);
                double d = fabs(mean[0][ch] - mean[1][ch]);
                double z = se > 0.0 ? d / se : (d > 0.0 ? INFINITY : 0.0);
                zmax = fmax(zmax, z);
                count += z > zc;
            }
        }
        CHECK(bad == 0);
        if (var_ratio)
            *var_ratio = pix_var[0] > 0.0 ? pix_var[1] / pix_var[0] : INFINITY;
        printf("%s: largest block z %.2f (limit %.2f over %d tests), variance b/a %.3f\n", what,
               zmax, zc, nb * 3, pix_var[0] > 0.0 ? pix_var[1] / pix_var[0] : INFINITY);
    }
    pt_renderer_free(r[0]);
    pt_renderer_free(r[1]);
    return count;
}

#endif
