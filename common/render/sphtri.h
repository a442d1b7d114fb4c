/*
 * sphtri.h - uniform sampling of the solid angle a triangle subtends.
 *
 * Arvo 1995, "Stratified Sampling of Spherical Triangles" (SIGGRAPH '95):
 * the directions from p to the triangle (a, b, c) form a spherical triangle
 * of area Omega = alpha + beta + gamma - pi (its inner angles); u1 chooses
 * the sub-triangle of area u1 Omega with one vertex moved along the arc
 * opposite a, u2 the point along the arc from b to that vertex, so the
 * density is 1 / Omega over the directions, and the (u1, u2) square maps
 * continuously (stratification is kept). Against area sampling, whose
 * density in solid angle is d^2 / (A cos theta_light), it removes the
 * variance of the distance and light cosine: what counts for a large
 * triangle close to the shading point.
 *
 * pt_sphtri_solid_angle gives Omega by Van Oosterom & Strackee's closed
 * form (one atan2; the sampler's inner angles agree with it to rounding):
 * a caller divides by this one number both when it samples and when it
 * weighs a BSDF hit, so the two pdfs have the same bits.
 * Pure functions; any thread. Single precision in, double inside: the
 * inner angles of a small spherical triangle lose their digits in float.
 */
#ifndef PT_COMMON_RENDER_SPHTRI_H
#define PT_COMMON_RENDER_SPHTRI_H

#include "common/math/vec.h"

/* The solid angle of triangle (a, b, c) seen from p (steradians, in [0,
 * 2 pi)); 0 when p is on its plane or the triangle is degenerate. */
double pt_sphtri_solid_angle(pt_vec3 p, pt_vec3 a, pt_vec3 b, pt_vec3 c);

/* A direction from p towards triangle (a, b, c) for u1, u2 in [0,1), into
 * *wi (unit), with *omega its solid angle (pdf 1 / *omega). Returns 0 when
 * the solid angle is 0 or not finite. */
int pt_sphtri_sample(pt_vec3 p, pt_vec3 a, pt_vec3 b, pt_vec3 c, float u1, float u2, pt_vec3 *wi,
                     double *omega);

/* The same direction for a triangle whose solid angle omega (> 0) the
 * caller has already (pt_sphtri_solid_angle's): one inner angle is
 * computed instead of three. Returns 0 when the triangle is degenerate
 * from p. */
int pt_sphtri_sample_omega(pt_vec3 p, pt_vec3 a, pt_vec3 b, pt_vec3 c, double omega, float u1,
                           float u2, pt_vec3 *wi);

#endif
