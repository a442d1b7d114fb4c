/*
 * film.h - the whole image's per-pixel double sums and counts.
 *
 * Memory O(width x height), independent of how many tasks are merged. Tiles
 * are added with pt_film_add_tile; adding the same partial sums in the same
 * order gives bit-identical pixels. pt_film_resolve turns sums into a pt_image
 * (mean RGB, sample count, variance of the mean). Not thread-safe: one owner.
 */
#ifndef PT_COMMON_FILM_H
#define PT_COMMON_FILM_H

#include <stdint.h>

#include "common/error.h"
#include "common/image.h"
#include "common/render.h"

typedef struct pt_film {
    uint32_t width, height;
    pt_pixel_acc *px; /* width*height, row-major */
} pt_film;

pt_status pt_film_new(uint32_t width, uint32_t height, pt_film **out, pt_error *err);
void pt_film_free(pt_film *film); /* accepts NULL */

/* Adds a tile's partial sums (row-major over tile, as pt_render_tile writes them). */
void pt_film_add_tile(pt_film *film, pt_rect tile, const pt_pixel_acc *acc);

/* Writes mean, count and variance of the mean into img (same size). Pixels
 * with no samples are 0; variance needs n >= 2 (else 0). */
void pt_film_resolve(const pt_film *film, pt_image *img);

/* Total samples over all pixels. */
uint64_t pt_film_total_samples(const pt_film *film);

/* Adaptive sampling's measure of a tile: the root mean square over its pixels
 * of the relative error of each pixel mean, sigma_mean / (mean + eps), in
 * luminance, with eps = PT_ADAPTIVE_EPS (so black background converges at
 * once and near-black pixels are judged on an absolute scale). px holds the
 * tile's accumulators row by row with the given stride (in pixels). A pixel
 * with fewer than 2 samples has infinite error. Pure and deterministic: the
 * same sums give the same decision wherever it is made. */
#define PT_ADAPTIVE_EPS 1e-2
double pt_tile_rel_error(const pt_pixel_acc *px, uint32_t stride, uint32_t width, uint32_t height);

/* Adaptive sampling's decision, shared by ptserve, ptworker and ptbench: a
 * tile whose sums (as for pt_tile_rel_error) hold its first `samples` samples
 * per pixel stops when samples >= min_spp and its error is at most target.
 * target <= 0 never stops. Callers do not ask after the last chunk. */
int pt_tile_stops(const pt_pixel_acc *px, uint32_t stride, uint32_t width, uint32_t height,
                  uint64_t samples, uint32_t min_spp, double target);

#endif
