/*
 * denoise_frame.h - a finished frame denoised in place: the planes a render
 * with the denoiser's passes resolved into (pt_passes_add_planes, the EXR
 * convention of docs/ARCHITECTURE.md) handed to NFOR (common/image/denoise.h),
 * and its output added to the frame as the layer denoised.R, .G, .B.
 *
 * ptworker --denoise runs it on its image before writing it; ptdenoise does
 * the same to a file. The result is a function of the frame's pixels alone,
 * so a frame rendered on the farm or standalone - the same bits - denoises
 * to the same bits, on any number of threads.
 */
#ifndef PT_COMMON_RENDER_DENOISE_FRAME_H
#define PT_COMMON_RENDER_DENOISE_FRAME_H

#include <stdatomic.h>
#include <stdint.h>

#include "common/base/error.h"
#include "common/image/denoise.h"
#include "common/image/image.h"
#include "common/render/tile.h"

/* The passes the denoiser reads: --denoise asks for them. */
#define PT_PASS_DENOISE (PT_PASS_ALBEDO | PT_PASS_NORMAL | PT_PASS_DEPTH | PT_PASS_HALVES)

/* Denoises img (threads as pt_denoise; despeckle 0 or PT_DENOISE_DESPECKLE
 * and up, as pt_denoise_input) and adds denoised.R/G/B to it; *out (may be
 * NULL) points at those planes. PT_ERR_FORMAT naming what is missing when
 * img lacks a plane of PT_PASS_DENOISE, or a pixel holds fewer than 2
 * samples (one of its halves is empty); pt_denoise's refusals; PT_ERR_NOMEM.
 * img is unchanged on failure but for a denoised plane already added. */
pt_status pt_denoise_frame(pt_image *img, unsigned threads, float despeckle, float *out[3],
                           pt_error *err);

/* How pt_denoise_frame_until denoises. */
typedef struct pt_denoise_frame_opts {
    float despeckle; /* as pt_denoise_input's */
    /* The denoiser's working memory at most (0: no limit): a frame that
     * needs more is denoised in the largest regions that fit
     * (pt_denoise_regions: the same bits); PT_ERR_LIMIT when none does. */
    uint64_t max_bytes;
    /* NULL, or a flag another thread may set to stop the work: PT_AGAIN
     * ("cancelled") then, img without a new denoised layer (one already
     * there may be partly overwritten). The coordinator's writer drops a
     * progressive save's denoising so when the finished image arrives. */
    const atomic_int *cancel;
    atomic_uint *progress; /* NULL, or the work done in thousandths (pt_denoise_input's) */
    /* NULL, or who denoises the frame in place of pt_denoise_within (the
     * coordinator, sharing the regions with its workers): called with the
     * frame's input, checked, into out (width x height floats each); it
     * sets *side to the regions' side it cut (0: whole). */
    pt_status (*denoise)(void *ctx, const pt_denoise_input *in, float *const out[3], uint32_t *side,
                         pt_error *err);
    void *ctx;
} pt_denoise_frame_opts;

/* pt_denoise_frame as o says; the regions' side into *side (0: the whole
 * frame) unless side is NULL. */
pt_status pt_denoise_frame_until(pt_image *img, unsigned threads, const pt_denoise_frame_opts *o,
                                 float *out[3], uint32_t *side, pt_error *err);

#endif
