/*
 * tile.h - the unit of work's plain data: a rectangle of pixels and the
 * per-pixel partial sums a task returns.
 *
 * Shared vocabulary of the renderer (pt_render_tile writes these), the film
 * (which adds them), the adaptive-sampling rule, the wire format (protocol/
 * encodes them) and the coordinator. Plain structs and one inline function,
 * no dependency beyond <stdint.h>, so protocol/ can use them without knowing
 * the scene model. Any thread may use them.
 */
#ifndef PT_COMMON_RENDER_TILE_H
#define PT_COMMON_RENDER_TILE_H

#include <stdint.h>

/* Per-pixel partial sums of a range of samples. */
typedef struct pt_pixel_acc {
    double sum[3]; /* sum of the RGB samples */
    double sum_sq; /* sum of squared luminance of the samples (error estimate) */
    uint32_t n;    /* samples accumulated (rejected ones excluded) */
    uint32_t hits; /* of those n, the samples whose camera ray hit the scene
                      (hits <= n); hits / n is the pixel's coverage, the alpha
                      of a transparent film. An integer, so it merges exactly. */
} pt_pixel_acc;

/* a += b (the order of calls fixes the floating-point result). */
static inline void pt_pixel_acc_add(pt_pixel_acc *a, const pt_pixel_acc *b)
{
    a->sum[0] += b->sum[0];
    a->sum[1] += b->sum[1];
    a->sum[2] += b->sum[2];
    a->sum_sq += b->sum_sq;
    a->n += b->n;
    a->hits += b->hits;
}

/* A range of samples is summed in aligned blocks of this many, each in sample
 * order, then block by block (render.h): the unit that keeps splits exact. */
#define PT_SAMPLE_BLOCK 16u

/* The largest tile side in pixels that any program accepts (ptserve and
 * ptworker --tile, ptbench): its square is the wire's cap on the pixels of a
 * TASK or RESULT (PROTO_MAX_TILE_PIXELS), so a farm tile always fits. */
#define PT_TILE_MAX 256u

/* The longest image side the programs render by default and accept for
 * --res: ptworker, one-job ptserve, and the default of ptserve --max-res. */
#define PT_RENDER_MAX_SIDE 16384u

typedef struct pt_rect {
    uint32_t x0, y0, x1, y1; /* pixels [x0,x1) x [y0,y1), y down from the top row */
} pt_rect;

#endif
