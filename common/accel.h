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
#ifndef PT_COMMON_ACCEL_H
#define PT_COMMON_ACCEL_H

#include <stdint.h>

#include "common/error.h"
#include "common/scene.h"
#include "common/vec.h"

typedef struct pt_accel pt_accel;

typedef struct pt_hit {
    float t;
    float b1, b2;    /* barycentrics of vertices 1 and 2 (Embree's u, v) */
    uint32_t tri;    /* triangle index, or UINT32_MAX on a miss */
} pt_hit;

pt_status pt_accel_new(const pt_scene *scene, pt_accel **out, pt_error *err);
void pt_accel_free(pt_accel *accel); /* accepts NULL */

/* Closest hit along o + t d for t in (0, tfar]. Returns 1 on a hit. */
int pt_accel_intersect(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar, pt_hit *hit);
/* 1 when anything blocks o + t d for t in (0, tfar). */
int pt_accel_occluded(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar);

/* World-space point and geometric normal (unit, from the winding) of a hit. */
void pt_accel_hit_point(const pt_scene *scene, const pt_hit *hit, pt_vec3 *p, pt_vec3 *ng);

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

#endif
