/*
 * sample_mean.h - the mean of a renderer's samples over a square image and
 * its standard error, per channel (test_diffuse_transmission.c,
 * test_iridescence.c): for scenes whose every pixel has the same expected
 * radiance, a closed form to compare with.
 *
 * sample_mean renders spp samples of each of side x side pixels of r (sample
 * index i of every pixel before i + 1) and writes each channel's mean over
 * all of them and the standard error of that mean (the samples' spread over
 * the square root of their count less one).
 */
#ifndef PT_TESTS_COMMON_RENDER_SAMPLE_MEAN_H
#define PT_TESTS_COMMON_RENDER_SAMPLE_MEAN_H

#include <math.h>
#include <stdint.h>

#include "common/render/render.h"

static inline void sample_mean(pt_renderer *r, uint32_t side, uint32_t spp, double mean[3],
                               double se[3])
{
    double sum[3] = {0, 0, 0}, sq[3] = {0, 0, 0};
    const uint32_t pixels = side * side;
    const double n = (double)pixels * spp;
    for (uint32_t i = 0; i < spp; i++)
        for (uint32_t k = 0; k < pixels; k++) {
            pt_render_stats st = {0};
            int cov = 0;
            pt_vec3 v = pt_render_sample(r, k % side, k / side, i, &st, &cov);
            const double va[3] = {v.x, v.y, v.z};
            for (int c = 0; c < 3; c++) {
                sum[c] += va[c];
                sq[c] += va[c] * va[c];
            }
        }
    for (int c = 0; c < 3; c++) {
        mean[c] = sum[c] / n;
        se[c] = sqrt(fmax(sq[c] / n - mean[c] * mean[c], 0.0) / (n - 1.0));
    }
}

#endif
