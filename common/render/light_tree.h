/*
 * light_tree.h - a bounding hierarchy over lights for choosing one in
 * proportion to its estimated contribution at a shading point (next-event
 * estimation with many emitters).
 *
 * Conty Estevez & Kulla 2018, "Importance Sampling of Many Lights with
 * Adaptive Tree Splitting" (Proc. ACM CGIT 1(2)), as in pbrt-v4's BVH light
 * sampler (Pharr, Jakob & Humphreys, 4th ed., sec. 12.6.3): every node bounds
 * its lights' positions (a box), their emitting normals (a cone of half-angle
 * theta_o around an axis; the emission spreads pi/2 further, Lambertian) and
 * their power. Seen from p with normal n, a node's importance is
 *     power x cos(theta') x cos(theta_i') / d^2   (outside its sphere)
 *     power / r^2                                  (p inside it),
 * d the distance to the box's centre, r its half-diagonal, theta' the
 * smallest angle any emitting normal in the cone can make with the direction
 * to p once the box's angular size theta_b = asin(r / d) is allowed for (0
 * when no light in the node can face p: theta' >= pi/2), and theta_i' =
 * max(0, theta_i - theta_b), theta_i the angle between n and the direction
 * from p to the centre (Conty & Kulla eq. 3): 0 when the node lies wholly
 * below p's tangent plane. n is the receiver's normal on the side it
 * reflects to; a zero n (a receiver that scatters to both sides) sets no
 * such bound. A light is chosen by walking down from the root
 * two levels a step: among a node's four grandchildren (a child that is a
 * leaf stands for itself), each with probability importance / (sum of the
 * four), the four importances in one set of SIMD lanes - the 4-wide tree
 * whose nodes are the binary tree's even levels. Its probability is the
 * product along the way, which pt_light_tree_pmf recomputes for any light
 * from the branch bits stored with it, with the same float operations, so
 * NEE and the MIS weight of a BSDF hit see the same number. Nodes are 32
 * bytes (the cone's axis and cosine in 16 bits, rounded outwards), a pair
 * of children one cache line; pt_light_tree_sample_n interleaves the walks
 * of many points so that their cache misses overlap.
 *
 * Build: binned surface-area-orientation heuristic (SAOH, Conty & Kulla eq. 2)
 * over 12 buckets per axis; one light per leaf. It is a pure function of the
 * items (no threads, no hashing of addresses, stable partitions), so every
 * worker builds the same tree and a farm's image is bit-identical.
 *
 * Immutable after pt_light_tree_new; thread-safe for reading.
 */
#ifndef PT_COMMON_RENDER_LIGHT_TREE_H
#define PT_COMMON_RENDER_LIGHT_TREE_H

#include <stdint.h>

#include "common/base/error.h"
#include "common/math/vec.h"

typedef struct pt_light_tree pt_light_tree;

/* What the tree needs of one light (world space). */
typedef struct pt_light_tree_item {
    pt_vec3 lo, hi; /* bounds of its emitting surface (a point for a point light) */
    pt_vec3 axis;   /* unit axis of the cone of its emitting normals */
    float cos_o;    /* cosine of the cone's half-angle: 1 for a triangle, -1 all around */
    float power;    /* estimated flux, > 0 and finite */
    int two_sided;  /* emits on both sides of its normals */
} pt_light_tree_item;

/* The most lights a tree holds (its branch bits fit 64 levels). */
#define PT_LIGHT_TREE_MAX ((uint32_t)1 << 26)

/* Builds the tree over items[0..n), 2 <= n <= PT_LIGHT_TREE_MAX; item i is
 * light i. PT_ERR_ARG for a bad count or an item with a non-positive or
 * non-finite power or bounds, PT_ERR_NOMEM. */
pt_status pt_light_tree_new(const pt_light_tree_item *items, uint32_t n, pt_light_tree **out,
                            pt_error *err);
void pt_light_tree_free(pt_light_tree *tree); /* accepts NULL */

/* The light u (in [0,1)) chooses seen from p with unit normal n (or a zero
 * n: no bound by the receiver's side), and its probability in *pmf;
 * UINT32_MAX with *pmf 0 when no light can light p. */
uint32_t pt_light_tree_sample(const pt_light_tree *tree, pt_vec3 p, pt_vec3 n, double u,
                              double *pmf);

/* pt_light_tree_sample(tree, p[i], nrm[i], u[i], &pmf[i]) into light[i] for
 * i < n, the same bits, with the walks of up to 16 points interleaved so
 * that their cache misses overlap. */
void pt_light_tree_sample_n(const pt_light_tree *tree, uint32_t n, const pt_vec3 *p,
                            const pt_vec3 *nrm, const double *u, uint32_t *light, double *pmf);

/* The probability that pt_light_tree_sample chooses light from p with
 * normal n, the same bits; 0 for a light it cannot choose there. */
double pt_light_tree_pmf(const pt_light_tree *tree, pt_vec3 p, pt_vec3 n, uint32_t light);

/* Nodes, and the deepest leaf's depth (the root's is 0). */
uint32_t pt_light_tree_nodes(const pt_light_tree *tree);
uint32_t pt_light_tree_depth(const pt_light_tree *tree);

#endif
