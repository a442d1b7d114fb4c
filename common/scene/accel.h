/*
 * accel.h - ray queries through Embree 3 (robust mode).
 *
 * One pt_accel per scene, built once and shared by render threads (queries are
 * thread-safe). Hits return the triangle, barycentrics and distance; the hit
 * point is then rebuilt from the triangle's vertices (pt_accel_hit_point),
 * which is more accurate than o + t*d, and rays leave surfaces through
 * pt_offset_ray (Waechter & Binder, "A Fast and Robust Method for Avoiding
 * Self-Intersection", Ray Tracing Gems ch. 6), which scales the offset with
 * the magnitude of the coordinates instead of a hand-picked epsilon.
 */
#ifndef PT_COMMON_SCENE_ACCEL_H
#define PT_COMMON_SCENE_ACCEL_H

#include <math.h>
#include <stdint.h>
#include <string.h>

#include "common/base/error.h"
#include "common/math/vec.h"
#include "common/scene/scene.h"

typedef struct pt_accel pt_accel;

typedef struct pt_hit {
    float t;
    float b1, b2; /* barycentrics of vertices 1 and 2 (Embree's u, v) */
    uint32_t tri; /* triangle index, or UINT32_MAX on a miss */
    /* 1 + the index in scene->instances of the instance the triangle was
     * hit through (PT_FEAT_INSTANCES; tri is then a prototype's, in its own
     * space), else 0: a zeroed hit is a flat one. */
    uint32_t inst;
} pt_hit;

pt_status pt_accel_new(const pt_scene *scene, pt_accel **out, pt_error *err);
/* An accel over the scene's triangles sel[0 .. n - 1] only (still, not
 * instanced), for queries that look for those alone (manifold NEE's steps
 * onto glass): a hit reports the scene's triangle index, and the offsets
 * are the whole scene's. sel must outlive the accel. */
pt_status pt_accel_new_subset(const pt_scene *scene, const uint32_t *sel, uint32_t n,
                              pt_accel **out, pt_error *err);
void pt_accel_free(pt_accel *accel); /* accepts NULL */

/* Closest hit along o + t d for t in (0, tfar]. Returns 1 on a hit. */
int pt_accel_intersect(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar, pt_hit *hit);
/* 1 when anything blocks o + t d for t in (0, tfar). */
int pt_accel_occluded(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar);
/* Both ignore alpha: every triangle is opaque. */

/* The same with glTF alpha (common/scene/alpha.h): MASK and BLEND surfaces
 * that the ray passes through (pt_alpha_hit with this key) are not hit and
 * do not block. For a scene without PT_FEAT_ALPHA they are the functions
 * above. The scene given to pt_accel_new must outlive the accel when it has
 * alpha materials (its filters read the materials and textures). */
int pt_accel_intersect_alpha(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar, uint32_t key,
                             pt_hit *hit);
int pt_accel_occluded_alpha(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar, uint32_t key);

/* BLEND layers one ray counts or chooses among at most (below). */
#define PT_ACCEL_TRANS_MAX 16u

/* The closest hit as pt_accel_intersect_time with alpha, but the BLEND
 * surfaces along the ray are met or passed by one number u in [0, 1), in
 * the order the ray meets them: the first (alpha a) is hit when u < a,
 * else u becomes (u - a) / (1 - a) for the next. Each is hit with
 * probability alpha given that the ray reached it, as with the key, but
 * the layer a ray stops at is a monotone function of u, so samples whose
 * u are stratified stop at the layers in stratified proportions. Each
 * layer passed costs a query of the rest of the ray; past
 * PT_ACCEL_TRANS_MAX of them the others pass by the key. MASK surfaces
 * pass as with the key. */
int pt_accel_intersect_layers(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar, float time,
                              float u, uint32_t key, pt_hit *hit);

/* The share of light that o + t d, t in (0, tfar), lets through: 0 when an
 * opaque or MASK surface (or a BLEND one of alpha 1) blocks it, else the
 * product of 1 - alpha over the BLEND surfaces it crosses: the expectation
 * of pt_accel_occluded_alpha's pass-through over its key, which a shadow
 * ray can take instead of one draw of it (Enderton et al. 2010's
 * stochastic transparency, averaged along the ray as Cycles' transparent
 * shadows do). Each BLEND triangle is counted once; past
 * PT_ACCEL_TRANS_MAX of them on one ray the others pass or block by the
 * key, as in pt_accel_occluded_alpha. Without alpha materials it is
 * 1 - pt_accel_occluded. */
float pt_accel_transmittance_alpha(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar,
                                   uint32_t key);

/* The same at a time in [0, 1] of the shutter (motion blur,
 * common/scene/motion.h): moving triangles are where they are at that time
 * (between time steps on the straight line, as Embree interpolates); still
 * ones ignore it. alpha: 0 ignores alpha (as pt_accel_intersect), 1 as the
 * _alpha functions with key. Time 0 with alpha 0 is pt_accel_intersect. */
int pt_accel_intersect_time(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar, float time,
                            int alpha, uint32_t key, pt_hit *hit);
int pt_accel_occluded_time(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar, float time,
                           int alpha, uint32_t key);

/* With alpha materials, one byte per triangle: 1 for a whole MASK triangle
 * (pt_alpha_solid_new), which the queries take as opaque without a texture
 * lookup (the answer the lookup would give); NULL without alpha. Owned by
 * the accel. */
const uint8_t *pt_accel_alpha_solid(const pt_accel *accel);

/* The unit normal of a degenerate or overflowing triangle's cross product n
 * (computed in double; (0,0,1) when it has no direction). */
pt_vec3 pt_accel_degenerate_normal(pt_vec3 n);

/* The area of a triangle whose edges' cross product is c, len its float
 * length pt_v3_len(c) (which the callers have for the normal): len / 2
 * where it is finite (every triangle of a scene of sane size), else from c
 * in double: past about 1e9 a side the float sum of squares overflows, and
 * an emitter of infinite area would have no light sample (its pmf over the
 * area 0). */
static inline float pt_accel_tri_area(pt_vec3 c, float len)
{
    if (isfinite(len))
        return 0.5f * len;
    double x = c.x, y = c.y, z = c.z;
    return (float)(0.5 * sqrt(x * x + y * y + z * z));
}

/* The point p of an instance's prototype in scene space. */
static inline pt_vec3 pt_instance_point(const pt_instance *in, pt_vec3 p)
{
    const float *m = in->xf;
    return pt_v3(m[0] * p.x + m[3] * p.y + m[6] * p.z + m[9],
                 m[1] * p.x + m[4] * p.y + m[7] * p.z + m[10],
                 m[2] * p.x + m[5] * p.y + m[8] * p.z + m[11]);
}

/* A direction on the surface (a tangent) of an instance's prototype in
 * scene space, not normalised. */
static inline pt_vec3 pt_instance_vector(const pt_instance *in, pt_vec3 v)
{
    const float *m = in->xf;
    return pt_v3(m[0] * v.x + m[3] * v.y + m[6] * v.z, m[1] * v.x + m[4] * v.y + m[7] * v.z,
                 m[2] * v.x + m[5] * v.y + m[8] * v.z);
}

/* A unit normal of an instance's prototype in scene space (the inverse
 * transpose, normalised; fallback when that has no length). */
static inline pt_vec3 pt_instance_normal(const pt_instance *in, pt_vec3 n, pt_vec3 fallback)
{
    const float *m = in->nm;
    pt_vec3 r = pt_v3(m[0] * n.x + m[3] * n.y + m[6] * n.z, m[1] * n.x + m[4] * n.y + m[7] * n.z,
                      m[2] * n.x + m[5] * n.y + m[8] * n.z);
    float len = pt_v3_len(r);
    return (len > 0.0f && isfinite(len)) ? pt_v3_scale(r, 1.0f / len) : fallback;
}

/* World-space point and geometric normal (unit, from the winding) of a hit;
 * through an instance, its transform applied. Inline: the integrator calls
 * it at every bounce. */
static inline void pt_accel_hit_point(const pt_scene *scene, const pt_hit *hit, pt_vec3 *p,
                                      pt_vec3 *ng)
{
    const uint32_t *t = &scene->indices[3 * hit->tri];
    const float *x = scene->positions;
    pt_vec3 v0 = pt_v3(x[3 * t[0]], x[3 * t[0] + 1], x[3 * t[0] + 2]);
    pt_vec3 v1 = pt_v3(x[3 * t[1]], x[3 * t[1] + 1], x[3 * t[1] + 2]);
    pt_vec3 v2 = pt_v3(x[3 * t[2]], x[3 * t[2] + 1], x[3 * t[2] + 2]);
    float b0 = 1.0f - hit->b1 - hit->b2;
    /* Barycentric interpolation of the vertices: its error is relative to the
     * vertex magnitudes, where o + t d adds the error of t times |d| (Waechter
     * & Binder, RTG ch. 6, sec. 6.2.1). */
    *p = pt_v3_add(pt_v3_add(pt_v3_scale(v0, b0), pt_v3_scale(v1, hit->b1)),
                   pt_v3_scale(v2, hit->b2));
    pt_vec3 n = pt_v3_cross(pt_v3_sub(v1, v0), pt_v3_sub(v2, v0));
    float len = pt_v3_len(n);
    *ng =
        (len > 0.0f && isfinite(len)) ? pt_v3_scale(n, 1.0f / len) : pt_accel_degenerate_normal(n);
    if (hit->inst) {
        const pt_instance *in = &scene->instances[hit->inst - 1];
        *p = pt_instance_point(in, *p);
        *ng = pt_instance_normal(in, *ng, *ng);
    }
}

/* Offsets p along the geometric normal n (towards the side the ray leaves on)
 * so a ray starting there does not hit its own surface (Waechter & Binder),
 * with the paper's constants, which suit scenes of about unit size. */
pt_vec3 pt_offset_ray(pt_vec3 p, pt_vec3 n);

/* The same with the near-origin constants (1/32 and 1/65536 in the paper)
 * scaled by the power of two just above the scene's largest coordinate: near
 * the origin a hit point's error is relative to the scene's coordinates, not
 * absolute, so a fixed 1.5e-5 would be 15 % of a 1e-4 scene. Far from the
 * origin both offset by ULPs and agree. The integrator uses this one. */
pt_vec3 pt_accel_offset_ray(const pt_accel *accel, pt_vec3 p, pt_vec3 n);

/* pt_accel_offset_ray's two constants for a scene, so that the integrator can
 * inline the offset (pt_offset_apply) instead of calling across modules for
 * each of the 2-3 offsets of a bounce; the results are the same bits. */
typedef struct pt_offset {
    float origin; /* below this |coordinate|, offset by float_scale * n */
    float float_scale;
} pt_offset;

pt_offset pt_accel_offset(const pt_accel *accel);

/* Waechter & Binder's integer scale: a unit normal component moves a
 * coordinate by 256 ULPs. */
#define PT_OFFSET_INT_SCALE 256.0f

static inline float pt_offset_coord(float p, float n, float origin, float float_scale)
{
    if (fabsf(p) < origin)
        return p + float_scale * n;
    /* n is unit length; the clamp (NaN goes to 1) only keeps a bad n from an
     * undefined float-to-int conversion. Comparisons, not fminf/fmaxf, which
     * are library calls without -ffinite-math-only. */
    float c = n < 1.0f ? (n > -1.0f ? n : -1.0f) : 1.0f;
    int32_t of = (int32_t)(PT_OFFSET_INT_SCALE * c);
    uint32_t bits;
    memcpy(&bits, &p, sizeof bits);
    /* Sign-magnitude floats: adding to the bits moves away from zero, so a
     * negative coordinate moves along +n by subtracting. Unsigned arithmetic
     * wraps instead of overflowing; finite |p| >= 1/32 stays far from both
     * ends of the bit range. */
    bits += (uint32_t)(p < 0.0f ? -of : of);
    float r;
    memcpy(&r, &bits, sizeof r);
    return r;
}

/* pt_accel_offset_ray(accel, p, n) given off = pt_accel_offset(accel). */
static inline pt_vec3 pt_offset_apply(pt_offset off, pt_vec3 p, pt_vec3 n)
{
    return pt_v3(pt_offset_coord(p.x, n.x, off.origin, off.float_scale),
                 pt_offset_coord(p.y, n.y, off.origin, off.float_scale),
                 pt_offset_coord(p.z, n.z, off.origin, off.float_scale));
}

#endif
