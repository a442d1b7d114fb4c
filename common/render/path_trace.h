/*
 * path_trace.h - a log of one path's events (each bounce's lobe and pdf,
 * each light sample's pdfs and MIS weight, each emitter or environment hit
 * and what it added), for finding the paths that make an image's fireflies
 * (tests/bench/paths.c, ptbench-paths; docs/bench/toycar.md).
 *
 * Compiled in only where PT_PATH_TRACE is defined: ptbench-paths builds its
 * own copy of render.c and closure.c with it and keeps the log (per thread)
 * itself. Everywhere else each macro below is empty, so the renderer that
 * users run has none of it.
 */
#ifndef PT_COMMON_RENDER_PATH_TRACE_H
#define PT_COMMON_RENDER_PATH_TRACE_H

#include <stdint.h>

#include "common/math/vec.h"

enum {
    PT_TRACE_BOUNCE, /* a sampled continuation: a = pdf, b = wo.z, c = wi.z (shading frame) */
    PT_TRACE_NEE,    /* a light sample: a = light pdf, b = BSDF pdf, c = its weight w / pdf */
    PT_TRACE_SHADOW, /* the light sample's contribution, added (unblocked) */
    PT_TRACE_EMIT,   /* an emitter hit: a = BSDF pdf, b = light pdf, c = MIS weight */
    PT_TRACE_ENV,    /* an environment hit: a = BSDF pdf, b = env pdf, c = MIS weight */
    /* A vertex the guided variant offered the guide (before its bounce):
     * a = the chance it drew from the guide (0: its cell is unlearned or
     * its lobes too narrow), b = the guide's pdf at the direction taken (0
     * when a is), c = the BSDF's pdf there; delta: drawn from the guide. */
    PT_TRACE_GUIDE,
};

#ifdef PT_PATH_TRACE
/* mat: the material's index or -1; lobe: PT_LOBE_* (bounce), the light's
 * kind (PT_LIGHT_*, NEE) or -1; delta: a delta lobe was taken; v: the
 * bounce's weight f cos / pdf, else the contribution to L. */
void pt_trace_event(int kind, uint32_t depth, int32_t mat, int32_t lobe, int delta, float a,
                    float b, float c, pt_vec3 v);
/* closure.c: the kind of the lobe pt_closure_sample picked. */
void pt_trace_lobe(uint32_t kind);
#define PT_TRACE_EVENT(...) pt_trace_event(__VA_ARGS__)
#define PT_TRACE_LOBE(kind) pt_trace_lobe(kind)
#else
#define PT_TRACE_EVENT(...) ((void)0)
#define PT_TRACE_LOBE(kind) ((void)0)
#endif

#endif
