/*
 * manifold.h - chains of smooth refractions, or one smooth reflection,
 * between a point and a direction or a point (manifold next-event
 * estimation, Hanika, Droske & Fascione 2015, "Manifold Next Event
 * Estimation", with the half-vector constraint of Jakob & Marschner 2012,
 * "Manifold Exploration").
 *
 * Light from the environment that reaches a rough point x only through
 * smooth glass (the floor under a glass ball, a thing inside one) is found
 * by a path that samples its BSDF by chance: a shadow ray towards the light
 * ends at the glass. Given x and a direction wl of the environment, the
 * chain y_1 .. y_k (k <= PT_MF_MAX) on the glass's triangles where light
 * leaving along wl refracts towards x is the root of a constraint: at every
 * vertex the generalised half vector h = eta_a w_a + eta_b w_b (w_a, w_b the
 * unit directions to the neighbours, wl for the last; eta the index on each
 * one's side) is parallel to the shading normal, which is Snell's law (its
 * tangential components cancel); with both neighbours on one side (one
 * index), the law of reflection: the same constraint, solver and Jacobians
 * serve a vertex that mirrors (render.c's reflection chains). Newton's
 * method solves it in the vertices' barycentrics; a step that leaves a
 * vertex's triangle is put back on the glass by a ray from the previous
 * vertex (the caller's project).
 *
 * At the root, the implicit function theorem gives how the direction from x
 * to y_1 turns with wl: |d omega / d omega_L|, the ratio of solid angles by
 * which a density over wl becomes one over the directions at x (the
 * generalised geometry term of Hanika et al., sec. 4.3, for a light at
 * infinity).
 *
 * Doubles throughout: the chain is solved to 1e-9 of the constraint, so
 * that the float path the renderer rebuilds from it refracts where the
 * solver said. The shading normal interpolates the vertex normals as
 * surface_at does (render.c). Thread-safe (no state).
 */
#ifndef PT_COMMON_RENDER_MANIFOLD_H
#define PT_COMMON_RENDER_MANIFOLD_H

#include <stdint.h>

/* Refractions a chain holds at most: one (out of the glass around x) or two
 * (into a glass object and out of it). */
#define PT_MF_MAX 2u

/* A chain vertex: a point of a triangle of smooth glass. */
typedef struct pt_mf_vert {
    double p0[3], e1[3], e2[3]; /* the triangle: p = p0 + b1 e1 + b2 e2 */
    double n0[3], n1[3], n2[3]; /* its vertex normals, interpolated for the shading normal */
    double ng[3];               /* its geometric normal: the front, where the index is 1 */
    double ior;                 /* the index behind the front */
    double b[2];                /* the vertex's barycentrics b1, b2 */
    uint32_t tri;               /* the triangle's index, for the caller */
} pt_mf_vert;

typedef struct pt_mf_chain {
    uint32_t k;  /* vertices, 1 .. PT_MF_MAX */
    uint32_t at; /* 0: light leaves the last vertex along wl (a light at infinity);
                    1: wl is a point the light comes from (a point or spot light) */
    pt_mf_vert v[PT_MF_MAX];
} pt_mf_chain;

/* Puts *out where a ray from `from` (x when prev is NULL, else the chain
 * vertex prev) towards q first meets glass the chain may refract at; 0 when
 * it meets anything else or nothing. */
typedef int (*pt_mf_project_fn)(void *user, const pt_mf_vert *prev, const double from[3],
                                const double q[3], pt_mf_vert *out);

/* The vertex's point and its unit shading normal (0 when the normals
 * cancel there). */
void pt_mf_point(const pt_mf_vert *v, const double b[2], double p[3]);
int pt_mf_normal(const pt_mf_vert *v, const double b[2], double n[3]);

/* Newton's method from c's vertices; 1 when the constraint fell below
 * PT_MF_TOL within PT_MF_ITERS steps (c holds the root), else 0. The
 * steps take the constraint's derivatives analytically (the chain rule
 * through the unit vectors it is made of); a step that leaves the glass's
 * outline is halved. From the renderer's straight seeds on the glass ball
 * with things inside (scenes/glass_things.gltf) most chains that converge
 * take 4 to 6 steps, a tail up to 12 (the seed far from the root, the path
 * bent by the ball); those still far from it after 5 give up (manifold.c,
 * MF_BAIL_ITER). */
#define PT_MF_TOL 1e-9
#define PT_MF_ITERS 12
int pt_mf_solve(const double x[3], pt_mf_chain *c, const double wl[3], pt_mf_project_fn project,
                void *user);

/* |d omega / d omega_L| at a root: the solid angle of directions at x per
 * solid angle of wl; 0 where the chain is singular. */
double pt_mf_jacobian(const double x[3], const pt_mf_chain *c, const double wl[3]);

/* For a chain that ends at the point l (c->at): |d omega_l / dA_x|, the solid
 * angle of the directions leaving l per area at x across the chain's first
 * segment, the implicit function theorem's answer to x moved along the two
 * tangents of that segment. A point light's intensity I along omega_l then
 * gives x the irradiance I |d omega_l / dA_x| times the interfaces'
 * transmittance (flux along a thin tube of rays: no radiance, so no index
 * squared; 1 / d^2 with no glass between). 0 where the chain is singular. */
double pt_mf_point_jacobian(const double x[3], const pt_mf_chain *c, const double l[3]);

#endif
