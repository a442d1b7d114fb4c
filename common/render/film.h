/*
 * film.h - the whole image's per-pixel sums (fixed point, tile.h) and counts.
 *
 * Memory O(width x height) (72 bytes a pixel), independent of how many tasks
 * are merged. Tiles are added with pt_film_add_tile; the sums are exact
 * integers, so the pixels are the same bits whatever the order in which the
 * parts of a range of samples are added and however it was split at
 * PT_SAMPLE_BLOCK boundaries. pt_film_resolve turns sums into a pt_image
 * (mean RGB, sample count, variance of the mean). A film may also hold the
 * render passes' sums (pt_film_enable_passes: pass[], 280 bytes a pixel
 * more), added and resolved with the beauty's, pixel by pixel.
 * Threads: pt_film_add_tile and the resolves lock the bands of
 * PT_FILM_BAND_ROWS rows they touch, one at a time, so a thread may resolve
 * while another adds tiles: every pixel is resolved whole (its sums and count
 * from the same moment), each band as it was when it was read. Everything
 * else (px read or written directly, pt_film_free) is the owner's, while no
 * other thread uses the film.
 */
#ifndef PT_COMMON_RENDER_FILM_H
#define PT_COMMON_RENDER_FILM_H

#include <stdint.h>

#include "common/base/error.h"
#include "common/image/image.h"
#include "common/render/render.h"

#define PT_FILM_BAND_ROWS 16

typedef struct pt_film_bands pt_film_bands;

typedef struct pt_film {
    uint32_t width, height;
    pt_pixel_acc *px;     /* width*height, row-major */
    pt_pass_acc *pass;    /* the same for the render passes, or NULL (none asked for) */
    uint32_t passes;      /* PT_PASS_* the film resolves (pass != NULL) */
    pt_film_bands *bands; /* a lock per PT_FILM_BAND_ROWS rows */
} pt_film;

pt_status pt_film_new(uint32_t width, uint32_t height, pt_film **out, pt_error *err);
void pt_film_free(pt_film *film); /* accepts NULL */

/* Gives the film pass sums for the passes of mask (PT_PASS_*, non-zero),
 * zeroed: to be called before any tile is added. PT_ERR_NOMEM. */
pt_status pt_film_enable_passes(pt_film *film, uint32_t mask, pt_error *err);

/* Adds a tile's partial sums (row-major over tile, as pt_render_tile writes
 * them). On a film with passes acc holds the tile's pixel sums followed by
 * its pass sums, in one block (as a decoded RESULT's, proto_result.pass).
 * Returns the samples added (the sum of their n). */
uint64_t pt_film_add_tile(pt_film *film, pt_rect tile, const pt_pixel_acc *acc);
/* The same with the tile's pass sums (pacc, as pt_render_tile_passes writes
 * them; NULL: none, as pt_film_add_tile), added under the same lock. */
uint64_t pt_film_add_tile_passes(pt_film *film, pt_rect tile, const pt_pixel_acc *acc,
                                 const pt_pass_acc *pacc);

/* Writes mean, count, variance of the mean and coverage (hits / n, into
 * img->a; img->has_alpha is the caller's) into img (same size). Pixels with
 * no samples are 0; variance needs n >= 2 (else 0). A film with passes
 * resolves them into img's named planes (passes.h), which it adds when img
 * lacks them (an out-of-memory there leaves them out: the caller that must
 * have them adds them first with pt_passes_add_planes). Returns the samples
 * of the pixels it resolved (their sum of n). */
uint64_t pt_film_resolve(const pt_film *film, pt_image *img);

/* pt_film_resolve that also measures the image for adaptive sampling: into
 * *rel_error, pt_tile_rel_error over every pixel (the same value, infinite
 * while a pixel has fewer than 2 samples), each band's from the sums it
 * resolves, in the same walk and under the same lock. */
uint64_t pt_film_resolve_measured(const pt_film *film, pt_image *img, double *rel_error);

/* Total samples over all pixels. */
uint64_t pt_film_total_samples(const pt_film *film);

#endif
