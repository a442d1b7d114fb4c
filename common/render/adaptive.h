/*
 * adaptive.h - adaptive sampling: when a tile has enough samples.
 *
 * The policy the coordinator (ptserve), the standalone render (ptworker
 * --scene) and the benchmarks (ptbench) share: two measures of a tile's
 * remaining error, computed from its per-pixel sums (pt_pixel_acc), and the
 * rule that stops it. Pure functions of the sums: the same sums give the same
 * decision wherever it is made, so the image stays the same however the work
 * was split. Any thread may call them. Figures that back the choices made
 * here are in docs/bench/adaptive.md.
 */
#ifndef PT_COMMON_RENDER_ADAPTIVE_H
#define PT_COMMON_RENDER_ADAPTIVE_H

#include <stdint.h>

#include "common/render/tile.h"

/* Adaptive sampling's measure of a tile: the root mean square over its pixels
 * of the relative error of each pixel mean, sigma_mean / (mean + eps), in
 * luminance, with eps = PT_ADAPTIVE_EPS (so black background converges at
 * once and near-black pixels are judged on an absolute scale). px holds the
 * tile's accumulators row by row with the given stride (in pixels). A pixel
 * with fewer than 2 samples has infinite error. Pure and deterministic: the
 * same sums give the same decision wherever it is made. */
#define PT_ADAPTIVE_EPS 1e-2
double pt_tile_rel_error(const pt_pixel_acc *px, uint32_t stride, uint32_t width, uint32_t height);
/* pt_tile_rel_error's sum: adds the squared relative error of each pixel of
 * the region to *sum, in the same order, so that a sum carried from region to
 * region of a row-major whole is that whole's. 0, or -1 at a pixel with fewer
 * than 2 samples (*sum is then partial). */
int pt_rel_error_add(const pt_pixel_acc *px, uint32_t stride, uint32_t width, uint32_t height,
                     double *sum);

/* The minimum-mean-error rule's measure of a tile: what one more sample per
 * pixel would take off the mean squared error of its pixel means (R, G and B,
 * absolute): the mean over its pixels of R_p / (n (n + 1)), with n the
 * pixel's samples and R_p its error per sample, the mean squared error of its
 * mean times n.
 *
 * R_p is estimated from the pixel's last chunk against the chunks before it:
 * with m the last chunk's mean (n_l samples) and m' the mean of the samples
 * before it (n' samples), E[(m - m')^2] = R_p (1/n_l + 1/n') when chunks err
 * independently, so R_p = mean over R, G, B of (m - m')^2 / (1/n_l + 1/n').
 * Not from the sum of squares: that gives the variance of one sample, the
 * error of independent samples, while the samples of a pixel are a scrambled
 * Sobol sequence whose mean errs less, and by how much depends on the content
 * (docs/bench/adaptive.md measures by how much). Chunks of 2^k samples are nets of that
 * sequence, so their spread measures the error the sampler makes; it is
 * extrapolated as 1/n, which overstates the error where the sequence keeps
 * converging faster.
 *
 * px holds the tile's sums with its last chunk (stride in pixels), last that
 * chunk's sums alone (last_stride). A pixel whose last chunk is empty makes
 * the measure infinite, and so does one without earlier samples unless its
 * samples are all exactly 0: such a pixel (the black background, where camera
 * rays leave the scene) counts 0 from its first chunk on, so a tile of them
 * can stop after one chunk. Pure and deterministic. */
double pt_tile_gain(const pt_pixel_acc *px, uint32_t stride, const pt_pixel_acc *last,
                    uint32_t last_stride, uint32_t width, uint32_t height);

/* Adaptive sampling's settings: the two rules (0 = off) and the minimum. */
typedef struct pt_adaptive {
    double target_error; /* the equal-error rule (--target-error) */
    double min_gain;     /* the minimum-mean-error rule (--min-gain) */
    uint32_t min_spp;    /* no tile stops with fewer samples per pixel */
} pt_adaptive;

/* Adaptive sampling's decision, shared by ptserve, ptworker and ptbench: a
 * tile whose sums px (as for pt_tile_gain, with last its last chunk) hold its
 * first `samples` samples per pixel may stop once samples >= a->min_spp, and
 * then stops
 *   - with target_error > 0 (the equal-error rule): when its
 *     pt_tile_rel_error is at most target_error. Every tile ends near the same
 *     relative error, so no region is left noisier than the target;
 *   - with min_gain > 0 (the minimum-mean-error rule): when one more sample
 *     per pixel would take at most min_gain off its mean squared error, its
 *     pt_tile_gain. One sample per pixel more or less then changes the
 *     squared error of every tile by about the same amount, the condition for
 *     the lowest mean squared error of the image for its samples (Lagrange):
 *     a tile gets n ~ sqrt(R / min_gain) samples, in proportion to its noise,
 *     as in Neyman's allocation to strata (Neyman 1934; Cochran, Sampling
 *     Techniques, 3rd ed., 1977, sec. 5.5), where the equal-error rule gives
 *     n ~ R. It decides from the second chunk on, and from the first for a
 *     tile whose samples are all exactly 0 (pt_tile_gain). The cost of a
 *     sample is not weighed: rays per sample, the deterministic proxy for it,
 *     made the renders slower, and the best allocation by measured cost would
 *     win little over this rule (docs/bench/adaptive.md).
 * With both set, the tile stops when either rule says so; with neither, never.
 * Callers do not ask after the last chunk. */
int pt_tile_stops(const pt_pixel_acc *px, uint32_t stride, const pt_pixel_acc *last,
                  uint32_t last_stride, uint32_t width, uint32_t height, uint64_t samples,
                  const pt_adaptive *a);

#endif
