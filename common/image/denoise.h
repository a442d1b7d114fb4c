/*
 * denoise.h - a feature-guided denoiser of a finished render: NFOR.
 *
 * Bitterli, Rousselle, Moon, Iglesias-Guitian, Adler, Mitchell, Jarosz and
 * Novak, "Nonlinearly Weighted First-order Regression for Denoising Monte
 * Carlo Renderings", Computer Graphics Forum 35(4), 2016 (EGSR). Its steps,
 * with the paper's parameters:
 *
 *   1. feature prefiltering (sec. 5.1): each feature channel (albedo R, G, B,
 *      normal X, Y, Z, depth) through NL-means guided by itself and its
 *      variance (patch radius 3, window radius 5, k = 0.5). The paper
 *      cross-filters feature halves; ptfarm's passes carry the mean and its
 *      variance, not halves, so each feature is filtered by itself.
 *   2. first-order regression (sec. 5.2): at each pixel a weighted least
 *      squares fit of the colour over a 19 x 19 window, on a constant, the
 *      screen offset and the seven features, weights from NL-means patch
 *      distances (Rousselle, Knaus and Zwicker 2012) on the OTHER half buffer
 *      (cross-filtering: half A is filtered with weights from half B and the
 *      reverse, so a half's noise does not select its own neighbours); every
 *      fit predicts its whole window and the predictions are averaged with
 *      their weights (collaborative filtering). Two candidates, k = 0.5 and 1;
 *      not in the paper, the k = 0.5 one compares 3 x 3 patches instead of
 *      7 x 7, so that a pixel beside an edge no feature explains (a shadow's
 *      border, a corner) finds the neighbours along it (the Cornell box at
 *      64 spp: relMSE 8.84e-5 -> 7.79e-5).
 *      Not in the paper: a pixel's variance in these patch distances is at
 *      least 3e-5 (u^2 + 0.01), so that a noisy pixel beside noise-free
 *      texture (an environment seen directly) is not shut out of every
 *      patch by differences of its noise-free neighbours that no one could
 *      see (SheenChair in the studio at 64 spp: relMSE 4.69e-4 -> 3.52e-4).
 *   3. selection (sec. 5.3): each candidate's per-pixel MSE estimated from the
 *      halves' cross errors, (B - F_A)^2 - var B, averaged over A and B, less
 *      the residual variance (F_B - F_A)^2 / 4; the estimates and then the
 *      binary choice map are smoothed by NL-means on the colour, and the
 *      candidates blended by the map.
 *   4. a second pass (sec. 5.4): the blended halves' mean filtered once more
 *      with the variance of their difference, k = 1.
 *
 * Before them, outliers (not in the paper; measured on DamagedHelmet in the
 * studio at 64 spp: relMSE 1.39e-2 -> 4.7e-3 at a despeckle of 3, the mean
 * 0.5 % lower; 4.2e-3 at the default 2): a
 * pixel of one half brighter than `despeckle` x the brightest of the other
 * half's 3 x 3 neighbourhood (luminance) is scaled down to that, and its
 * variance with it (a spike only one half has is one rare sample; what
 * the picture holds, both halves see); then a variance over 16 x the
 * median of its 3 x 3 neighbourhood's is capped to that (one rare sample
 * inflated it, and it made the pixel "similar" to everything). The light
 * the clamp took is splatted back, after NFOR, over the pixels of the same
 * surface (normal, depth) within 24 pixels, so the image's sum is kept
 * (ToyCar in the park: 4.2 % of its mean lost without it, 0.2 % with).
 *
 * The halves are the means over even and odd sample indices (the EXR
 * convention: halfA, halfB); their variance is twice the beauty's variance
 * of the mean. That one is luminance's (`variance`); a channel's is taken
 * as luminance's x (channel / luminance)^2, which is exact for noise that
 * scales the pixel's colour (a path's random factor times its throughput).
 *
 * Deterministic: every pixel's arithmetic is fixed by the image alone. The
 * work is cut into 32 x 32 tiles in a fixed order; threads take tiles, and
 * each tile's partial sums are added into the image in tile order, so the
 * result is the same bits for any thread count.
 *
 * Threads: pt_denoise starts and joins its own threads; any thread may call
 * it on its own buffers.
 */
#ifndef PT_COMMON_IMAGE_DENOISE_H
#define PT_COMMON_IMAGE_DENOISE_H

#include <stdatomic.h>
#include <stdint.h>

#include "common/base/error.h"

/* Seven feature channels: albedo R, G, B, normal X, Y, Z, depth. */
#define PT_DENOISE_FEATURES 7

/* The largest magnitude a value may have: ptfarm's merger refuses sums over
 * 1e18 a sample, and nothing a renderer writes comes near it. */
#define PT_DENOISE_MAX_VALUE 1e18f

/* The most threads pt_denoise starts. */
#define PT_DENOISE_MAX_THREADS 256u

/* The processors online, within [1, PT_DENOISE_MAX_THREADS]: the threads a
 * program denoises with when not told (the result is the same bits). */
unsigned pt_denoise_default_threads(void);

/* The image to denoise: planar float arrays of width x height, row 0 at the
 * top, every one required (borrowed; not modified). */
typedef struct pt_denoise_input {
    uint32_t width, height;
    const float *half_a[3], *half_b[3]; /* means over even, odd sample indices */
    const float *color[3];              /* the beauty: mean over all samples */
    const float *variance;              /* of the beauty's mean (luminance) */
    const float *albedo[3], *albedo_var;
    const float *normal[3], *normal_var;
    const float *depth, *depth_var; /* camera distance; 0 where the ray escaped */
    /* Fireflies: a half's pixel over despeckle x the other half's 3 x 3
     * maximum is scaled down to it; 0 turns it off, PT_DENOISE_DESPECKLE is
     * the default of the programs; at least 1 otherwise. */
    float despeckle;
    /* NULL, or a flag another thread may set to stop the work early:
     * pt_denoise then returns PT_AGAIN ("cancelled") with out partly
     * written. Read between tiles. */
    const atomic_int *cancel;
    /* NULL, or where the work done so far is kept, in thousandths (0 to
     * 1000; the caller sets it to 0 first): it only rises, 1000 once the
     * output is written, and any thread may read it while pt_denoise runs
     * (a status line, the coordinator's job status). */
    atomic_uint *progress;
} pt_denoise_input;

/* The input's planes in one order, the one ptdenoise reads its EXR's
 * channels in: half_a R, G, B, half_b R, G, B, color R, G, B, variance,
 * albedo R, G, B, albedo_var, normal X, Y, Z, normal_var, depth, depth_var. */
#define PT_DENOISE_PLANES 20
void pt_denoise_input_set_planes(pt_denoise_input *in, const float *const p[PT_DENOISE_PLANES]);
void pt_denoise_input_planes(const pt_denoise_input *in, const float *p[PT_DENOISE_PLANES]);

/* 2, not the 3 it was: since the light the clamp takes is splatted back,
 * a lower threshold no longer costs the mean (DamagedHelmet in the park had
 * lost 1.3 % at 2 without the splat). Measured, 64 spp against 16,384-spp
 * references (docs/bench/denoise.md): DamagedHelmet in the studio 5.06e-3
 * -> 4.18e-3 relMSE, ToyCar in the park 1.250e-3 -> 1.226e-3, SheenChair
 * 3.05e-4 -> 3.03e-4, the Cornell box and the park helmet within 0.3 %,
 * every mean within 0.14 %; 1.5 took the studio helmet to 3.99e-3 but the
 * park helmet up 1.4 %. */
#define PT_DENOISE_DESPECKLE 2.0f
#define PT_DENOISE_DESPECKLE_MAX 1e6f

/* PT_OK when in can be denoised: a size within PT_IMAGE_MAX_SIDE and
 * PT_IMAGE_MAX_PIXELS, every plane present, every value finite and at most
 * PT_DENOISE_MAX_VALUE in magnitude, variances, depth and albedo not
 * negative, normal components within [-1.001, 1.001] (a mean of unit
 * vectors), despeckle 0 or in [1, PT_DENOISE_DESPECKLE_MAX]. Else PT_ERR_ARG
 * (size, a missing plane, despeckle) or PT_ERR_FORMAT, the
 * message naming the pass and the first bad pixel ("albedo.G at (3, 7) is
 * nan"). Pure. */
pt_status pt_denoise_check(const pt_denoise_input *in, pt_error *err);

/* Denoises in into out[0..2] (R, G, B; width x height floats each, caller's;
 * may not alias the input) with `threads` threads (0: 1; at most
 * PT_DENOISE_MAX_THREADS). Runs pt_denoise_check first and returns its
 * refusal; PT_ERR_NOMEM when memory runs out, PT_AGAIN when in->cancel was
 * set (out then partly written). The
 * output is the same bits for any thread count. Memory: pt_denoise_bytes
 * besides the input (about 0.42 KiB a pixel: 849 MiB for 1920 x 1080). */
pt_status pt_denoise(const pt_denoise_input *in, unsigned threads, float *const out[3],
                     pt_error *err);

/* The work's unit: 32 x 32 tiles from the image's corner, whose partial
 * sums are added in tile order. */
#define PT_DENOISE_TILE 32u
/* How far from a pixel the inputs that decide its output lie, at most, in
 * pixels (the sum of the steps' reaches): the fits' weights 21 (a fit
 * centred 9 away from the pixel, its window 9 more, its patch 3), the
 * features' prefilter 8, the outliers' rules 2; the MSE estimates'
 * smoothing 10 and the choice map's 10 after the first regression, the
 * second regression 21 after those (67 in all), and the splat of the
 * outliers' light 24 from its source, whose weights read 24 around it
 * (94). A pixel farther than this from every edge of a crop of the image
 * comes out of the crop's pt_denoise with the bits the whole image's
 * gives it, when the crop's corner is a multiple of PT_DENOISE_TILE from
 * the image's (the tiles then hold the same pixels). */
#define PT_DENOISE_REACH 94u
/* The margin a region is cut with: the reach in whole tiles. */
#define PT_DENOISE_MARGIN                                                                          \
    ((PT_DENOISE_REACH + PT_DENOISE_TILE - 1) / PT_DENOISE_TILE * PT_DENOISE_TILE)

/* The bytes pt_denoise allocates for a width x height image (its planes,
 * the regressions' sums and tiles; not the input or output). */
uint64_t pt_denoise_bytes(uint32_t width, uint32_t height);
/* The bytes pt_denoise_regions allocates for regions of side x side
 * pixels (0: the whole image, pt_denoise's) of a width x height image:
 * the largest crop's copy of the input and output, and pt_denoise's for it. */
uint64_t pt_denoise_region_bytes(uint32_t width, uint32_t height, uint32_t side);

/* The side of the largest regions (a multiple of PT_DENOISE_TILE) whose
 * pt_denoise_regions allocates at most max_bytes for a width x height
 * image: 0 when the whole image fits (pt_denoise), UINT32_MAX when no
 * region does. */
uint32_t pt_denoise_region_side(uint32_t width, uint32_t height, uint64_t max_bytes);

/* pt_denoise within max_bytes of working memory (0: no limit): the whole
 * image when it fits, else pt_denoise_regions with the largest regions
 * that do (pt_denoise_region_side), their side into *side (0: whole)
 * unless side is NULL; PT_ERR_LIMIT naming the memory the smallest
 * regions need when none fit. */
pt_status pt_denoise_within(const pt_denoise_input *in, unsigned threads, uint64_t max_bytes,
                            float *const out[3], uint32_t *side, pt_error *err);

/* pt_denoise, the image cut into regions of side x side pixels (a multiple
 * of PT_DENOISE_TILE; 0, or at least the image: pt_denoise itself), each
 * denoised from a crop PT_DENOISE_MARGIN larger on every side (within the
 * image): the same bits as pt_denoise, in the memory of one crop
 * (pt_denoise_region_bytes) rather than of the image, for more work (a
 * region of 1024 pixels denoises a crop of 1216). The regions run one after
 * another, each on `threads` threads. PT_ERR_ARG for a side that is not a
 * multiple of the tile; else as pt_denoise. */
pt_status pt_denoise_regions(const pt_denoise_input *in, unsigned threads, uint32_t side,
                             float *const out[3], pt_error *err);

/* The regions pt_denoise_regions cuts a width x height image into for a
 * side (a multiple of PT_DENOISE_TILE, > 0): how many, in row-major order. */
uint32_t pt_denoise_region_count(uint32_t width, uint32_t height, uint32_t side);
/* Region `index` (< the count) as x0, y0, x1, y1 in the image: its pixels
 * into region, and the crop it is denoised from into crop (PT_DENOISE_MARGIN
 * wider on every side, within the image; its corner on the tile grid). */
void pt_denoise_region_at(uint32_t width, uint32_t height, uint32_t side, uint32_t index,
                          uint32_t region[4], uint32_t crop[4]);
/* One region of pt_denoise_regions: its pixels of out (the whole image's
 * planes) written, no other; the same bits as pt_denoise gives them. The
 * crop is copied into a buffer of its own (pt_denoise_region_bytes).
 * in->progress is not moved. Errors as pt_denoise_regions, PT_ERR_ARG for
 * an index past the count. Regions of one image may run on several
 * threads at once: they write disjoint pixels. */
pt_status pt_denoise_region(const pt_denoise_input *in, unsigned threads, uint32_t side,
                            uint32_t index, float *const out[3], pt_error *err);

#endif
