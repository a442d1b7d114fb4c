/*
 * light_lanes.h - private to common/: the pieces of pt_lights_sample that the
 * SIMD loops of light.c (pt_lights_sample_n) and render.c (the Lambert
 * variants' shading in lanes) share, so that both do its arithmetic once.
 *
 * A pick (pt_lights_pick_n) is pt_lights_sample's first step - the light and
 * the point on it - written into slot j of a structure of arrays; the
 * distances, directions and pdfs then run 8 lanes at a time
 * (pt_light_lanes_pdf) with pt_lights_sample's float operations in its order:
 * the same bits (IEEE arithmetic without contraction; square roots and
 * divisions are correctly rounded either way). Not part of the public API.
 *
 * Threads: pure functions over caller-owned arrays; any render thread.
 */
#ifndef PT_COMMON_RENDER_LIGHT_LANES_H
#define PT_COMMON_RENDER_LIGHT_LANES_H

#include <stddef.h>
#include <stdint.h>

#include "common/math/simd.h"
#include "common/render/light.h"

/* The most picks one pt_light_picks holds. */
#define PT_LIGHT_PICKS 64u

/* Light picks by slot: the point, the light's unit normal, its pmf / area,
 * all-ones when the light is double-sided, and its emitted radiance at the
 * point (side not checked). Arrays of 32-byte multiples: slots 8k..8k+7 load
 * as one v8f. */
typedef struct pt_light_picks {
    float pos[3][PT_LIGHT_PICKS];
    float normal[3][PT_LIGHT_PICKS];
    float pmf_area[PT_LIGHT_PICKS];
    int32_t two_sided[PT_LIGHT_PICKS];
    float radiance[3][PT_LIGHT_PICKS];
} pt_light_picks;

/* pt_lights_sample's lights and points for n <= PT_LIGHT_PICKS points (lights
 * must not be empty), into slots 0..n-1 of out: point k's numbers u[0..2] are
 * pick[k * stride], point[k * stride] and point[k * stride + 1], its shading
 * point (p[0][k], p[1][k], p[2][k]) and receiver normal (nrm[0][k], ...)
 * (read where a light tree chooses). A pick the tree cannot make has
 * pmf_area 0. */
void pt_lights_pick_n(const pt_lights *lights, const pt_scene *scene, uint32_t n, const float *pick,
                      const float *point, size_t stride, const float *const p[3],
                      const float *const nrm[3], pt_light_picks *out);

/* Lanes whose float is finite (isfinite): the magnitude's bits below
 * infinity's. A macro: vectors passed by value would change the ABI. */
#define PT_V8_FINITE(x) (((v8i)(x)&0x7fffffff) < 0x7f800000)

/*
 * pt_lights_sample from d = point - p (d2 = d.d, ndot = normal.d): the
 * distance, its reciprocal, and the solid-angle pdf with
 * solid_angle_pdf_d's checks as a mask (0 where the scalar code gives pdf 0);
 * *ok is where pt_lights_sample returns 1 (a finite positive distance and a
 * positive pdf; the radiance is not part of it). The direction is d * *inv.
 */
static inline __attribute__((always_inline)) void
pt_light_lanes_pdf(const v8f *d2p, const v8f *ndot, const v8f *pmf_area, const v8i *two_sided,
                   v8f *dist, v8f *inv, v8f *pdf, v8i *ok)
{
    v8f d2 = *d2p, r;
    pt_v8_sqrt(&r, &d2);
    v8f cos_l = -*ndot / r; /* > 0: p sees the front */
    v8f ac = (v8f)((v8i)cos_l & 0x7fffffff);
    v8f q = *pmf_area * d2 / ac; /* pmf / area * d2 / ac, the same bits */
    v8i q_ok = (d2 > 0.0f) & PT_V8_FINITE(d2) & (*two_sided | (cos_l > 0.0f)) & (ac > 0.0f) &
               PT_V8_FINITE(q);
    q = (v8f)((v8i)q & q_ok);
    *dist = r;
    *inv = 1.0f / r;
    *pdf = q;
    *ok = (r > 0.0f) & PT_V8_FINITE(r) & (q > 0.0f);
}

#endif
