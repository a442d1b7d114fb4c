/*
 * alpha.h - glTF alpha coverage (alphaMode MASK and BLEND) at a point of a
 * triangle, and the stochastic pass-through that the ray queries apply.
 *
 * glTF 2.0 (3.9.2): alpha = baseColorFactor.a x baseColorTexture.a (x the
 * COLOR_0 alpha when the primitive has one). OPAQUE ignores it; MASK draws
 * the surface where alpha >= alphaCutoff and nothing elsewhere; BLEND covers
 * a fraction alpha of what is behind. A path tracer renders BLEND without
 * sorting or a second pass by stochastic transparency: a ray meets the
 * surface with probability alpha and passes through it with 1 - alpha, so
 * the expected radiance is alpha * L_surface + (1 - alpha) * L_behind
 * (Enderton et al. 2010, "Stochastic Transparency"; Cycles and pbrt-v4 do
 * the same for camera rays). Shadow rays take the expectation instead, the
 * product of 1 - alpha along the ray (pt_accel_transmittance_alpha), and
 * path rays in a scene with BLEND materials choose the layer they stop at
 * by one stratified number (pt_accel_intersect_layers); the key below then
 * decides MASK surfaces and BLEND ones past the sixteenth on a ray.
 *
 * The random number of a pass-through comes from the caller as a 32-bit key
 * (from the keyed sampler: pixel, sample index, dimension) and is hashed with
 * the triangle's index, so the several surfaces one ray crosses get
 * independent numbers, and the answer for a (key, triangle) pair is the same
 * however often, and in whatever order, the accelerator asks for it.
 * Pure functions over an immutable scene: any thread may call them.
 */
#ifndef PT_COMMON_SCENE_ALPHA_H
#define PT_COMMON_SCENE_ALPHA_H

#include <stdint.h>

#include "common/base/error.h"
#include "common/scene/scene.h"

/* glTF alpha value at barycentrics (b1, b2) of triangle tri (vertices 1 and
 * 2, as pt_hit gives them), before the mode is applied: the base colour
 * factor's alpha times the base colour texture's alpha at the interpolated
 * TEXCOORD_0. */
float pt_alpha_value(const pt_scene *s, uint32_t tri, float b1, float b2);

/* The fraction of the surface present at that point: 1 for OPAQUE, 0 or 1
 * for MASK (alpha >= alphaCutoff), alpha for BLEND. */
float pt_alpha_coverage(const pt_scene *s, uint32_t tri, float b1, float b2);

/* 1 when a ray with pass-through key `key` meets the surface at that point,
 * 0 when it passes through: always 1 for OPAQUE, the cutoff for MASK, and
 * for BLEND 1 with probability alpha over uniformly distributed keys, from
 * a hash of (key, tri). */
int pt_alpha_hit(const pt_scene *s, uint32_t tri, float b1, float b2, uint32_t key);

/* Most texels that pt_alpha_solid_new reads for one triangle, and for the
 * whole scene: a triangle whose UVs span more, and those after the budget
 * is spent, are left to the lookups (a scene of a million MASK leaves
 * loads in a fraction of a second more, not minutes). */
#define PT_ALPHA_SOLID_TEXELS 16384u
#define PT_ALPHA_SOLID_BUDGET (1u << 26)

/* Per triangle of s (s->num_triangles bytes, pt_free'd by the caller) into
 * *out: 1 where a MASK triangle is whole, its alpha at least its cutoff at
 * every point, so that pt_alpha_coverage is 1 and pt_alpha_hit 1 there
 * without a lookup; else 0 (every other mode, and a triangle whose bound is
 * not known: its UVs over more than PT_ALPHA_SOLID_TEXELS texels, or past
 * PT_ALPHA_SOLID_BUDGET texels read in all). The bound
 * is conservative: alpha factor x the least alpha of the texels that a
 * lookup anywhere in the box of the triangle's (transformed) UVs can read,
 * widened by a texel, x the least COLOR_0 alpha of its corners, with a
 * margin for the lookup's rounding. PT_ERR_NOMEM. */
pt_status pt_alpha_solid_new(const pt_scene *s, uint8_t **out, pt_error *err);

/* 1 when triangle tri's material is MASK or BLEND (quick test before the
 * lookups). */
static inline int pt_alpha_tri(const pt_scene *s, uint32_t tri)
{
    return s->materials[s->tri_material[tri]].alpha_mode != PT_ALPHA_OPAQUE;
}

/* 1 when triangle tri's material is BLEND. */
static inline int pt_alpha_blend_tri(const pt_scene *s, uint32_t tri)
{
    return s->materials[s->tri_material[tri]].alpha_mode == PT_ALPHA_BLEND;
}

/* The key of a pass-through decision from a sample value u in [0, 1) and a
 * salt that tells apart the rays that draw from the same u (a bounce's
 * closest-hit ray, 0, and its shadow ray, 1): a surface crossed by both must
 * not get the same decision twice. Floats in [0, 1) have their top bit clear,
 * so shifting keeps every pair distinct. */
static inline uint32_t pt_alpha_key(float u, uint32_t salt)
{
    union {
        float f;
        uint32_t u;
    } b = {u};
    return (b.u << 1) | (salt & 1u);
}

#endif
