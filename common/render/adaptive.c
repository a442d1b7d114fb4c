/*
 * adaptive.c - adaptive sampling's measures of a tile and its stopping rule.
 */
#include "common/render/adaptive.h"

#include <math.h>
#include <stddef.h>

int pt_rel_error_add(const pt_pixel_acc *px, uint32_t stride, uint32_t width, uint32_t height,
                     double *sum)
{
    for (uint32_t y = 0; y < height; y++) {
        for (uint32_t x = 0; x < width; x++) {
            const pt_pixel_acc *a = &px[(size_t)y * stride + x];
            if (a->n < 2)
                return -1;
            double n = a->n;
            double mean = (0.2126 * pt_acc_sum(a, 0) + 0.7152 * pt_acc_sum(a, 1) +
                           0.0722 * pt_acc_sum(a, 2)) /
                          n;
            double var = (pt_acc_sum_sq(a) - n * mean * mean) / (n - 1.0);
            double sigma = var > 0.0 ? sqrt(var / n) : 0.0;
            double rel = sigma / (fabs(mean) + PT_ADAPTIVE_EPS);
            *sum += rel * rel;
        }
    }
    return 0;
}

double pt_tile_rel_error(const pt_pixel_acc *px, uint32_t stride, uint32_t width, uint32_t height)
{
    double sum = 0.0;
    if (pt_rel_error_add(px, stride, width, height, &sum) != 0)
        return INFINITY;
    return width && height ? sqrt(sum / ((double)width * height)) : 0.0;
}

double pt_tile_gain(const pt_pixel_acc *px, uint32_t stride, const pt_pixel_acc *last,
                    uint32_t last_stride, uint32_t width, uint32_t height)
{
    double sum = 0.0;
    for (uint32_t y = 0; y < height; y++) {
        for (uint32_t x = 0; x < width; x++) {
            const pt_pixel_acc *a = &px[(size_t)y * stride + x];
            const pt_pixel_acc *l = &last[(size_t)y * last_stride + x];
            if (l->n == 0 || a->n < l->n)
                return INFINITY;
            if (a->n == l->n) {
                /* The first chunk: no earlier samples to hold it against. A
                 * pixel whose samples are all exactly 0 (radiance is never
                 * negative, so zero sums and a zero luminance sum of squares
                 * mean that) has no error by any estimate; any other has no
                 * estimate yet. */
                if (a->fsum[0] != 0 || a->fsum[1] != 0 || a->fsum[2] != 0 || a->fsum_sq != 0)
                    return INFINITY;
                continue;
            }
            double nl = l->n, np = (double)(a->n - l->n), n = a->n, d2 = 0.0;
            for (int c = 0; c < 3; c++) {
                double d = pt_acc_sum(l, c) / nl - pt_fixed_to_double(a->fsum[c] - l->fsum[c]) / np;
                d2 += d * d;
            }
            double r = d2 / 3.0 / (1.0 / nl + 1.0 / np);
            sum += r / (n * (n + 1.0));
        }
    }
    return width && height ? sum / ((double)width * height) : 0.0;
}

int pt_tile_stops(const pt_pixel_acc *px, uint32_t stride, const pt_pixel_acc *last,
                  uint32_t last_stride, uint32_t width, uint32_t height, uint64_t samples,
                  const pt_adaptive *a)
{
    if (samples < a->min_spp)
        return 0;
    if (a->target_error > 0.0 && pt_tile_rel_error(px, stride, width, height) <= a->target_error)
        return 1;
    return a->min_gain > 0.0 &&
           pt_tile_gain(px, stride, last, last_stride, width, height) <= a->min_gain;
}
