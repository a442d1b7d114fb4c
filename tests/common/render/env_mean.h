/*
 * env_mean.h - a render's mean and its standard error under an environment
 * (test_env.c, test_portal.c): a w x w image of spp samples a pixel, seed
 * 11, with light strategy `strategy` (PT_LIGHT_*), for comparing with a
 * closed form. The standard error is the image mean's, from each pixel's
 * own sample variance (of the luminance), so a picture whose pixels differ
 * in their expected value (a floor lit through a hole) is not counted as
 * noise.
 */
#ifndef PT_TESTS_COMMON_RENDER_ENV_MEAN_H
#define PT_TESTS_COMMON_RENDER_ENV_MEAN_H

#include <math.h>
#include <stdint.h>

#include "common/base/alloc.h"
#include "common/render/env.h"
#include "common/render/film.h"
#include "common/render/render.h"
#include "tests/check.h"

/* The mean of the image's green channel and its standard error. */
static inline double render_mean(const pt_scene *s, const pt_env *env, uint32_t strategy,
                                 uint32_t w, uint32_t spp, double *se)
{
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = p.height = w;
    p.seed = 11;
    p.env = env;
    p.light_strategy = strategy;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    pt_pixel_acc *acc = pt_malloc_array((size_t)w * w, sizeof *acc);
    double sum = 0.0, var = 0.0;
    if (r && acc) {
        pt_render_stats st = {0};
        pt_rect all = {0, 0, w, w};
        pt_render_tile(r, all, 0, spp, acc, &st);
        CHECK(st.rejected == 0);
        for (uint32_t i = 0; i < w * w; i++) {
            double k = acc[i].n;
            double lum = (0.2126 * pt_acc_sum(&acc[i], 0) + 0.7152 * pt_acc_sum(&acc[i], 1) +
                          0.0722 * pt_acc_sum(&acc[i], 2)) /
                         k;
            sum += pt_acc_sum(&acc[i], 1) / k;
            var += fmax((pt_acc_sum_sq(&acc[i]) - k * lum * lum) / (k - 1.0), 0.0) / k;
        }
    }
    pt_free(acc);
    pt_renderer_free(r);
    *se = sqrt(var) / ((double)w * w);
    return sum / ((double)w * w);
}

#endif
