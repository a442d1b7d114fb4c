/*
 * test_manifold.c - manifold next-event estimation through thick smooth
 * glass (manifold.c: the chain's solver and its Jacobian; render.c:
 * mf_connect, mf_nee, mf_bsdf_weight).
 *
 * - Snell, closed form: a point in glass (ior 1.5) under its flat top face;
 *   for directions wl of the sky the solved vertex refracts by Snell's law
 *   (eta sin t_in = sin t_L, in wl's plane) and the Jacobian is the ratio
 *   of the two sides' projected solid angles, |d w / d wl| = cos t_L /
 *   (eta^2 cos t_in) (the etendue eta^2 cos t dw is kept across an
 *   interface), to 1e-8.
 * - A slab, closed form: a point under a flat glass slab: two refractions
 *   give back wl's direction (parallel faces), and the Jacobian is 1 (to
 *   1e-9).
 * - Curved: one triangle whose vertex normals tilt apart (a lens); the
 *   Jacobian from the implicit function theorem equals the one measured by
 *   solving the chain again for wl turned by 1e-4 rad each way, to 1e-3;
 *   likewise for a chain through two such triangles.
 * - A directional light through a glass slab onto a Lambert plane matches
 *   its closed form (directional_slab, below), and is black without
 *   manifold NEE (no sampled path can find a directional light).
 * - Unbiased, rendered: the glass ball with things inside
 *   (scenes/glass_things.gltf) under a sky with a broad bright patch,
 *   rendered with manifold NEE and without it (no_manifold: BSDF sampling
 *   alone finds the sky through the glass, as before) with the same
 *   numbers: the paired differences of every 8 x 8 block's samples (512
 *   a pixel) have mean zero by a z-test (Bonferroni over the blocks), and
 *   chains were connected. The patch is broad (about 40 degrees) and 16
 *   times the rest, so that the old estimator's tail is light enough at
 *   these counts for its sample variance to be valid (with 4 x 4 blocks and
 *   a patch 40 times the rest, seeds put a block at |z| 5 to 7 now here,
 *   now there, always where the new estimate is the larger: the old one's
 *   rare large samples missing, not a bias). With the sampled paths'
 *   weights left at 1 (the chains counted twice) 30 of the 48 block
 *   channels differ, at |z| up to 93.
 * - Both take every light sample (manifold_min_light 0: the skies have no
 *   lamp past the default bound, 16 times the mean; with the default a
 *   uniform sky connects no chain, checked); the glass ball again under a
 *   patch of two halves (1.6 and 4.8) with only the brighter half's
 *   samples taken, where both strategies must draw the same line between
 *   them.
 * - The same for AttenuationTest (absorbing glass, KHR_materials_volume:
 *   the chain's media) under a uniform sky, where the old estimator has no
 *   heavy tail at all (under the patch its tail put 3 of 12 16 x 16 blocks
 *   past |z| 4 at two seeds of six, always new above old; 16,384 old
 *   samples of such a block agree with the new estimate). Leaving out the
 *   media's transmittance moves 20 of 48 block channels (|z| up to 20),
 *   counting the chains twice 34.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/image/envmap.h"
#include "common/render/dielectric.h"
#include "common/render/env.h"
#include "common/render/manifold.h"
#include "common/render/render.h"
#include "common/scene/scene.h"
#include "tests/check.h"
#include "tests/common/render/normal_texel.h"
#include "tests/common/render/ortho.h"
#include "tests/common/render/paired.h"

#define ETA 1.5

static void set3(double a[3], double x, double y, double z)
{
    a[0] = x;
    a[1] = y;
    a[2] = z;
}

static double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static void unit3(double a[3])
{
    double l = sqrt(dot3(a, a));
    a[0] /= l;
    a[1] /= l;
    a[2] /= l;
}

/* A triangle of the test's glass: corners p0, p0 + e1, p0 + e2, vertex
 * normals n0..n2 (unit), geometric normal (the front) ng. */
typedef struct tri {
    double p0[3], e1[3], e2[3], n[3][3], ng[3];
} tri;

static void vert_of(const tri *t, uint32_t index, double b1, double b2, pt_mf_vert *v)
{
    memcpy(v->p0, t->p0, sizeof v->p0);
    memcpy(v->e1, t->e1, sizeof v->e1);
    memcpy(v->e2, t->e2, sizeof v->e2);
    memcpy(v->n0, t->n[0], sizeof v->n0);
    memcpy(v->n1, t->n[1], sizeof v->n1);
    memcpy(v->n2, t->n[2], sizeof v->n2);
    memcpy(v->ng, t->ng, sizeof v->ng);
    v->ior = ETA;
    v->b[0] = b1;
    v->b[1] = b2;
    v->tri = index;
}

/* Where the line from o along d meets t's plane, in t's barycentrics
 * (anywhere on the plane: the test's triangles are large). */
static int plane_hit(const tri *t, const double o[3], const double d[3], double b[2])
{
    double den = dot3(d, t->ng);
    if (fabs(den) < 1e-14)
        return 0;
    double q[3] = {t->p0[0] - o[0], t->p0[1] - o[1], t->p0[2] - o[2]};
    double s = dot3(q, t->ng) / den;
    if (!(s > 0.0))
        return 0;
    double p[3] = {o[0] + s * d[0] - t->p0[0], o[1] + s * d[1] - t->p0[1],
                   o[2] + s * d[2] - t->p0[2]};
    double d11 = dot3(t->e1, t->e1), d12 = dot3(t->e1, t->e2), d22 = dot3(t->e2, t->e2);
    double q1 = dot3(p, t->e1), q2 = dot3(p, t->e2), det = d11 * d22 - d12 * d12;
    b[0] = (d22 * q1 - d12 * q2) / det;
    b[1] = (d11 * q2 - d12 * q1) / det;
    return 1;
}

/* The test's glass: the chain's vertex i lies on tris[i]. */
typedef struct scene2 {
    const tri *tris;
} scene2;

static int project(void *user, const pt_mf_vert *prev, const double from[3], const double q[3],
                   pt_mf_vert *out)
{
    const scene2 *sc = user;
    uint32_t i = prev ? prev->tri + 1 : 0;
    double d[3] = {q[0] - from[0], q[1] - from[1], q[2] - from[2]}, b[2];
    unit3(d);
    if (!plane_hit(&sc->tris[i], from, d, b))
        return 0;
    vert_of(&sc->tris[i], i, b[0], b[1], out);
    return 1;
}

/* The unit direction from x to the chain's first vertex. */
static void first_dir(const double x[3], const pt_mf_chain *c, double w[3])
{
    double y[3];
    pt_mf_point(&c->v[0], c->v[0].b, y);
    for (int j = 0; j < 3; j++)
        w[j] = y[j] - x[j];
    unit3(w);
}

/* Seeds the chain by the straight line from x along wl and solves it. */
static int solve(const scene2 *sc, uint32_t k, const double x[3], const double wl[3],
                 pt_mf_chain *c)
{
    c->k = k;
    c->at = 0;
    double o[3];
    memcpy(o, x, sizeof o);
    for (uint32_t i = 0; i < k; i++) {
        double b[2];
        if (!plane_hit(&sc->tris[i], o, wl, b))
            return 0;
        vert_of(&sc->tris[i], i, b[0], b[1], &c->v[i]);
        pt_mf_point(&c->v[i], c->v[i].b, o);
    }
    return pt_mf_solve(x, c, wl, project, (void *)sc);
}

/* A big flat triangle at height z, normals up. */
static tri flat_at(double z)
{
    tri t;
    set3(t.p0, -50, -50, z);
    set3(t.e1, 100, 0, 0);
    set3(t.e2, 0, 100, 0);
    for (int i = 0; i < 3; i++)
        set3(t.n[i], 0, 0, 1);
    set3(t.ng, 0, 0, 1);
    return t;
}

static void snell(void)
{
    tri top = flat_at(0.0);
    scene2 sc = {&top};
    double x[3] = {0.3, -0.2, -1.0}, worst_s = 0.0, worst_j = 0.0;
    int solved = 0;
    for (int i = 0; i < 40; i++) {
        double th = 0.02 + 1.4 * i / 40.0, ph = 0.7 * i;
        double wl[3] = {sin(th) * cos(ph), sin(th) * sin(ph), cos(th)};
        pt_mf_chain c;
        if (!solve(&sc, 1, x, wl, &c)) {
            CHECKF(0, "no chain at t_L %.3f", th);
            continue;
        }
        solved++;
        double w[3];
        first_dir(x, &c, w);
        /* Snell: the tangential parts, eta w_t = wl_t. */
        worst_s = fmax(worst_s, fabs(ETA * w[0] - wl[0]) + fabs(ETA * w[1] - wl[1]));
        double jac = pt_mf_jacobian(x, &c, wl), want = wl[2] / (ETA * ETA * w[2]);
        worst_j = fmax(worst_j, fabs(jac / want - 1.0));
    }
    printf("snell: %d of 40 solved; Snell off by %.2g, Jacobian by %.2g (relative)\n", solved,
           worst_s, worst_j);
    CHECK(solved == 40);
    CHECKF(worst_s < 1e-8, "Snell's law off by %g", worst_s);
    CHECKF(worst_j < 1e-8, "the Jacobian off by %g of the closed form", worst_j);
}

static void slab(void)
{
    /* The slab's bottom face looks down (its front, air below), its top
     * face up. */
    tri t[2] = {flat_at(0.0), flat_at(0.4)};
    for (int i = 0; i < 3; i++)
        set3(t[0].n[i], 0, 0, -1);
    set3(t[0].ng, 0, 0, -1);
    scene2 sc = {t};
    double x[3] = {0.1, 0.2, -0.5}, worst_d = 0.0, worst_j = 0.0;
    int solved = 0;
    for (int i = 0; i < 30; i++) {
        double th = 0.05 + 1.2 * i / 30.0, ph = 1.3 * i;
        double wl[3] = {sin(th) * cos(ph), sin(th) * sin(ph), cos(th)};
        pt_mf_chain c;
        if (!solve(&sc, 2, x, wl, &c))
            continue;
        solved++;
        double w[3];
        first_dir(x, &c, w);
        worst_d = fmax(worst_d, fabs(w[0] - wl[0]) + fabs(w[1] - wl[1]) + fabs(w[2] - wl[2]));
        worst_j = fmax(worst_j, fabs(pt_mf_jacobian(x, &c, wl) - 1.0));
    }
    printf("slab: %d of 30 solved; direction off by %.2g, Jacobian by %.2g\n", solved, worst_d,
           worst_j);
    CHECK(solved == 30);
    CHECKF(worst_d < 1e-8, "the slab turned the light by %g", worst_d);
    CHECKF(worst_j < 1e-9, "the slab's Jacobian off 1 by %g", worst_j);
}

/* The direction from x to the chain's first vertex, solved again for wl. */
static int dir_for(const scene2 *sc, uint32_t k, const double x[3], const double wl[3],
                   const pt_mf_chain *start, double w[3])
{
    pt_mf_chain c = *start;
    if (!pt_mf_solve(x, &c, wl, project, (void *)sc))
        return 0;
    first_dir(x, &c, w);
    (void)k;
    return 1;
}

/* Orthonormal tangents of unit n. */
static void tangents(const double n[3], double t1[3], double t2[3])
{
    double a[3] = {1, 0, 0};
    if (fabs(n[0]) > 0.9)
        set3(a, 0, 1, 0);
    double d = dot3(a, n);
    for (int j = 0; j < 3; j++)
        t1[j] = a[j] - d * n[j];
    unit3(t1);
    t2[0] = n[1] * t1[2] - n[2] * t1[1];
    t2[1] = n[2] * t1[0] - n[0] * t1[2];
    t2[2] = n[0] * t1[1] - n[1] * t1[0];
}

/* The Jacobian against the one measured by solving again: wl turned by h
 * along each tangent, the directions at x read in w's tangents. */
static double measured_jacobian(const scene2 *sc, uint32_t k, const double x[3], const double wl[3],
                                const pt_mf_chain *c)
{
    const double h = 1e-4;
    double s1[3], s2[3], w0[3];
    tangents(wl, s1, s2);
    if (!dir_for(sc, k, x, wl, c, w0))
        return -1.0;
    double u1[3], u2[3];
    tangents(w0, u1, u2);
    const double *s[2] = {s1, s2};
    double M[2][2];
    for (int col = 0; col < 2; col++) {
        double wp[3], wm[3], dp[3], dm[3];
        for (int j = 0; j < 3; j++) {
            wp[j] = wl[j] + h * s[col][j];
            wm[j] = wl[j] - h * s[col][j];
        }
        unit3(wp);
        unit3(wm);
        if (!dir_for(sc, k, x, wp, c, dp) || !dir_for(sc, k, x, wm, c, dm))
            return -1.0;
        double dd[3] = {(dp[0] - dm[0]) / (2 * h), (dp[1] - dm[1]) / (2 * h),
                        (dp[2] - dm[2]) / (2 * h)};
        M[0][col] = dot3(u1, dd);
        M[1][col] = dot3(u2, dd);
    }
    return fabs(M[0][0] * M[1][1] - M[0][1] * M[1][0]);
}

/* A lens: the triangle's normals tilt away from its centre by `tilt`. */
static tri lens_at(double z, double tilt, int down)
{
    tri t = flat_at(z);
    set3(t.p0, -1.0, -1.0, z);
    set3(t.e1, 3.0, 0, 0);
    set3(t.e2, 0, 3.0, 0);
    const double corner[3][2] = {{-1, -1}, {1, -0.3}, {-0.3, 1}};
    for (int i = 0; i < 3; i++) {
        set3(t.n[i], tilt * corner[i][0], tilt * corner[i][1], down ? -1.0 : 1.0);
        unit3(t.n[i]);
    }
    if (down)
        set3(t.ng, 0, 0, -1);
    return t;
}

/* The chain from x to the point l through sc's k triangles, seeded by the
 * straight line and solved (c->at). */
static int solve_at(const scene2 *sc, uint32_t k, const double x[3], const double l[3],
                    pt_mf_chain *c)
{
    double d[3] = {l[0] - x[0], l[1] - x[1], l[2] - x[2]}, o[3];
    unit3(d);
    c->k = k;
    c->at = 1;
    memcpy(o, x, sizeof o);
    for (uint32_t i = 0; i < k; i++) {
        double b[2];
        if (!plane_hit(&sc->tris[i], o, d, b))
            return 0;
        vert_of(&sc->tris[i], i, b[0], b[1], &c->v[i]);
        pt_mf_point(&c->v[i], c->v[i].b, o);
    }
    return pt_mf_solve(x, c, l, project, (void *)sc);
}

/* |d omega_l / dA_x| measured by solving again: x moved by h along each
 * tangent of its segment's direction, omega_l = (y_k - l) / |y_k - l| read
 * in its own tangents. */
static double measured_point_jacobian(const scene2 *sc, uint32_t k, const double x[3],
                                      const double l[3], const pt_mf_chain *c)
{
    const double h = 1e-5;
    double w[3], s1[3], s2[3], u1[3], u2[3], wl0[3], y[3];
    first_dir(x, c, w);
    tangents(w, s1, s2);
    pt_mf_point(&c->v[k - 1], c->v[k - 1].b, y);
    for (int j = 0; j < 3; j++)
        wl0[j] = y[j] - l[j];
    unit3(wl0);
    tangents(wl0, u1, u2);
    const double *s[2] = {s1, s2};
    double M[2][2];
    for (int col = 0; col < 2; col++) {
        double dl[2][3];
        for (int sg = 0; sg < 2; sg++) {
            double xs[3];
            for (int j = 0; j < 3; j++)
                xs[j] = x[j] + (sg ? -h : h) * s[col][j];
            pt_mf_chain cc = *c;
            if (!pt_mf_solve(xs, &cc, l, project, (void *)sc))
                return -1.0;
            pt_mf_point(&cc.v[k - 1], cc.v[k - 1].b, y);
            for (int j = 0; j < 3; j++)
                dl[sg][j] = y[j] - l[j];
            unit3(dl[sg]);
        }
        double dd[3];
        for (int j = 0; j < 3; j++)
            dd[j] = (dl[0][j] - dl[1][j]) / (2 * h);
        M[0][col] = dot3(u1, dd);
        M[1][col] = dot3(u2, dd);
    }
    return fabs(M[0][0] * M[1][1] - M[0][1] * M[1][0]);
}

/* The Jacobians on two lenses (one refraction, two), against the ones
 * measured by solving again: |d omega / d omega_L| for 20 directions wl,
 * or with `at`, |d omega_l / dA_x| for 20 points l beyond the lenses; to
 * 1e-3. */
static void curved(int at)
{
    tri one = lens_at(0.0, 0.5, 0);
    tri two[2] = {lens_at(0.0, 0.4, 1), lens_at(0.5, -0.3, 0)};
    const scene2 sc1 = {&one}, sc2 = {two};
    const double x1[3] = {0.1, 0.05, -0.8}, x2[3] = {0.05, 0.1, -0.7};
    double worst[2] = {0.0, 0.0};
    int solved[2] = {0, 0};
    for (int i = 0; i < 20; i++) {
        double th = 0.05 + 0.6 * i / 20.0, ph = 2.1 * i, r = 0.8 + 0.1 * (i % 5);
        double wl[3] = {sin(th) * cos(ph), sin(th) * sin(ph), cos(th)};
        double l[3] = {r * wl[0], r * wl[1], 0.5 + r * wl[2]};
        for (uint32_t k = 1; k <= 2; k++) {
            const scene2 *sc = k == 1 ? &sc1 : &sc2;
            const double *x = k == 1 ? x1 : x2;
            pt_mf_chain c;
            if (!(at ? solve_at(sc, k, x, l, &c) : solve(sc, k, x, wl, &c)))
                continue;
            double j = at ? pt_mf_point_jacobian(x, &c, l) : pt_mf_jacobian(x, &c, wl);
            double m =
                at ? measured_point_jacobian(sc, k, x, l, &c) : measured_jacobian(sc, k, x, wl, &c);
            if (!(m > 0.0))
                continue;
            solved[k - 1]++;
            worst[k - 1] = fmax(worst[k - 1], fabs(j / m - 1.0));
        }
    }
    printf("curved%s: one refraction %d of 20 solved, Jacobian off the measured by %.2g; two %d "
           "of 20, %.2g\n",
           at ? ", to a point" : "", solved[0], worst[0], solved[1], worst[1]);
    CHECK(solved[0] >= 18 && solved[1] >= 18);
    CHECKF(worst[0] < 1e-3 && worst[1] < 1e-3, "Jacobians off by %g and %g", worst[0], worst[1]);
}

/* The reflection chain off t from x towards wl (with `at`, to the point
 * wl), seeded towards the light's image in t's plane (the xy-plane: wl
 * mirrored, or the point's image), and solved. */
static int solve_mirror(const tri *t, const double x[3], const double wl[3], int at, pt_mf_chain *c)
{
    const scene2 sc = {t};
    double d[3] = {wl[0], wl[1], -wl[2]}, b[2];
    if (at) {
        set3(d, wl[0] - x[0], wl[1] - x[1], -wl[2] - x[2]);
        unit3(d);
    }
    c->k = 1;
    c->at = (uint32_t)at;
    if (!plane_hit(t, x, d, b))
        return 0;
    vert_of(t, 0, b[0], b[1], &c->v[0]);
    return pt_mf_solve(x, c, wl, project, (void *)&sc);
}

/*
 * Reflection chains (manifold.h's constraint with one index on both sides):
 * off a flat mirror the direction from x is wl mirrored (to 1e-8) and the
 * Jacobian 1 (a mirror keeps solid angle); to a point l, |d omega_l / dA_x|
 * is 1 / |x - l'|^2 (l' its mirror image: a light seen in a mirror is that
 * far). Off a lens-shaped mirror (its normals tilted) both Jacobians match
 * the ones measured by solving again to 1e-3, for 20 directions and points
 * each.
 */
static void mirror(void)
{
    tri flat = flat_at(0.0), lens = lens_at(0.0, 0.5, 0);
    const scene2 sl = {&lens};
    const double x[3] = {0.1, -0.05, 0.7};
    double worst_d = 0.0, worst_f = 0.0, worst_l = 0.0, worst_fa = 0.0, worst_la = 0.0;
    int solved[2] = {0, 0}, solved_at[2] = {0, 0};
    for (int i = 0; i < 20; i++) {
        double th = 0.05 + 1.2 * i / 20.0, ph = 1.7 * i;
        double wl[3] = {sin(th) * cos(ph), sin(th) * sin(ph), cos(th)};
        pt_mf_chain c;
        if (solve_mirror(&flat, x, wl, 0, &c)) {
            solved[0]++;
            double w[3];
            first_dir(x, &c, w);
            worst_d = fmax(worst_d, fabs(w[0] - wl[0]) + fabs(w[1] - wl[1]) + fabs(w[2] + wl[2]));
            worst_f = fmax(worst_f, fabs(pt_mf_jacobian(x, &c, wl) - 1.0));
        }
        if (th < 0.65 && solve_mirror(&lens, x, wl, 0, &c)) {
            double m = measured_jacobian(&sl, 1, x, wl, &c);
            if (m > 0.0) {
                solved[1]++;
                worst_l = fmax(worst_l, fabs(pt_mf_jacobian(x, &c, wl) / m - 1.0));
            }
        }
        double r = 0.6 + 0.1 * (i % 5), l[3] = {r * wl[0], r * wl[1], r * wl[2]};
        if (solve_mirror(&flat, x, l, 1, &c)) {
            solved_at[0]++;
            double dx = x[0] - l[0], dy = x[1] - l[1], dz = x[2] + l[2];
            double want = 1.0 / (dx * dx + dy * dy + dz * dz);
            worst_fa = fmax(worst_fa, fabs(pt_mf_point_jacobian(x, &c, l) / want - 1.0));
        }
        if (th < 0.65 && solve_mirror(&lens, x, l, 1, &c)) {
            double m = measured_point_jacobian(&sl, 1, x, l, &c);
            if (m > 0.0) {
                solved_at[1]++;
                worst_la = fmax(worst_la, fabs(pt_mf_point_jacobian(x, &c, l) / m - 1.0));
            }
        }
    }
    printf("mirror: flat %d of 20 solved, direction off by %.2g, Jacobian off 1 by %.2g; lens %d "
           "solved, Jacobian off the measured by %.2g\n",
           solved[0], worst_d, worst_f, solved[1], worst_l);
    printf("mirror, to a point: flat %d of 20 solved, Jacobian off 1 / |x - l'|^2 by %.2g; lens %d "
           "solved, off the measured by %.2g\n",
           solved_at[0], worst_fa, solved_at[1], worst_la);
    CHECK(solved[0] == 20 && solved[1] >= 9 && solved_at[0] == 20 && solved_at[1] >= 9);
    CHECKF(worst_fa < 1e-8, "the flat mirror's point Jacobian off by %g", worst_fa);
    CHECKF(worst_la < 1e-3, "the lens mirror's point Jacobian off by %g", worst_la);
    CHECKF(worst_d < 1e-8, "the flat mirror turned the light by %g", worst_d);
    CHECKF(worst_f < 1e-8, "the flat mirror's Jacobian off 1 by %g", worst_f);
    CHECKF(worst_l < 1e-3, "the lens mirror's Jacobian off by %g", worst_l);
}

/* A sky of radiance 0.2 with a patch, about 40 by 55 degrees, 28 to 68
 * degrees from the zenith, whose two halves are left and right. */
static pt_env *patch_sky(float left, float right)
{
    const uint32_t w = 64, h = 32;
    pt_envmap map = {w, h, pt_malloc_array(w * h * 3, sizeof(float))};
    if (!map.rgb)
        return NULL;
    for (uint32_t y = 0; y < h; y++)
        for (uint32_t x = 0; x < w; x++) {
            float v = (y >= 5 && y < 12 && x >= 6 && x < 16) ? (x < 11 ? left : right) : 0.2f;
            for (int c = 0; c < 3; c++)
                map.rgb[3 * (y * w + x) + c] = v;
        }
    pt_env *env = NULL;
    pt_error err = {0};
    CHECKF(pt_env_new(&map, 1.0f, 0.0f, &env, &err) == PT_OK, "%s", err.msg);
    pt_free(map.rgb);
    return env;
}

/* The scene rendered with manifold NEE and without it, paired by block;
 * with `no_mirror`, the refraction chains alone. */
static void paired(const char *name, const pt_scene *s, const pt_env *env, uint32_t bs,
                   float min_light, uint32_t no_mirror)
{
    const uint32_t side = 32, spp = 512;
    pt_render_params p;
    pt_render_params_default(&p);
    p.width = p.height = side;
    p.seed = 3;
    p.env = env;
    p.manifold_min_light = min_light;
    p.no_mirror = no_mirror;
    pt_renderer *rn = NULL, *ro = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &rn, &err) == PT_OK, "%s", err.msg);
    p.no_manifold = 1;
    CHECKF(pt_renderer_new(s, &p, &ro, &err) == PT_OK, "%s", err.msg);
    if (rn && ro) {
        paired_result pr = paired_blocks_z(name, rn, ro, side, bs, spp, 0.0);
        printf("%s: %u of %u block channels differ (|z| > %.2f; largest %.2f); image mean %.5f "
               "with manifold NEE, %.5f without; %llu chains\n",
               name, pr.bad, pr.tests, pr.z_bound, pr.z_max, pr.mean_a, pr.mean_b,
               (unsigned long long)pr.sa.chains);
        CHECK(pr.nonfinite == 0);
        CHECKF(pr.sa.rejected == 0 && pr.sb.rejected == 0, "%s: %llu and %llu samples rejected",
               name, (unsigned long long)pr.sa.rejected, (unsigned long long)pr.sb.rejected);
        CHECKF(pr.bad == 0, "%s: %u block channels differ", name, pr.bad);
        CHECKF(pr.sa.chains > 0, "%s: manifold NEE connected no chain", name);
        CHECK(pr.sb.chains == 0);
    }
    pt_renderer_free(rn);
    pt_renderer_free(ro);
}

static pt_scene *chrome_ball_scene(int two, int sun);

/* The chains connected in a side x side render of s, spp samples a pixel,
 * under env with manifold_min_light min_light; -1 when no renderer. Whether
 * its renderer tries chains at all (pt_renderer_chains) into *tries unless
 * NULL. */
static long long chains_of(const pt_scene *s, const pt_env *env, float min_light, uint32_t side,
                           uint32_t spp, int *tries)
{
    pt_render_params p;
    pt_render_params_default(&p);
    p.width = p.height = side;
    p.env = env;
    p.manifold_min_light = min_light;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    if (!r)
        return -1;
    if (tries)
        *tries = pt_renderer_chains(r);
    pt_render_stats st = {0};
    for (uint32_t i = 0; i < side * side * spp; i++)
        pt_render_sample(r, i % side, (i / side) % side, i / (side * side), &st, NULL);
    pt_renderer_free(r);
    return (long long)st.chains;
}

static void unbiased(void)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/scenes/glass_things.gltf", PT_SOURCE_DIR);
    pt_scene_opts o = {0};
    pt_scene *s = NULL;
    pt_error err = {0};
    CHECKF(pt_scene_load(path, &o, &s, &err) == PT_OK, "%s", err.msg);
    pt_env *env = patch_sky(3.2f, 3.2f);
    /* The refraction chains alone: the ball's reflections onto the floor
     * (mirror_sphere's) are so rare a find for BSDF sampling here that at
     * 512 spp most blocks hold none, and their paired differences are the
     * chains' light alone, not a mean a z-test can judge. */
    if (s && env)
        paired("glass ball", s, env, 8, 0.0f, 1);
    pt_env_free(env);
    /* Halves of 1.6 and 4.8 (past the mean, both sampled), manifold NEE
     * taking the brighter only: both strategies must draw the same line
     * between them, or the dimmer half's light through the glass is lost
     * (or counted twice). */
    env = patch_sky(1.6f, 4.8f);
    if (s && env)
        paired("glass ball, the brighter half alone", s, env, 8,
               (float)(3.2 / pt_env_mean_luminance(env)), 1);
    pt_scene_free(s);
    /* Absorbing glass (KHR_materials_volume's attenuation): the chain's
     * media. */
    pt_env_free(env);
    s = load_shared_asset("AttenuationTest/AttenuationTest.glb", "volume");
    env = NULL;
    CHECK(pt_env_uniform(pt_v3(0.8f, 0.8f, 0.8f), &env, &err) == PT_OK);
    if (s && env) {
        paired("AttenuationTest", s, env, 8, 0.0f, 0);
        /* With the default bound a uniform sky has no light sample past
         * it: no chain, BSDF sampling alone (and the image as before). */
        long long n = chains_of(s, env, PT_MANIFOLD_MIN_LIGHT, 16, 64, NULL);
        CHECKF(n == 0, "%lld chains under a uniform sky by default", n);
    }
    pt_scene_free(s);
    pt_env_free(env);
    /* A chrome ball on the plane under the sky's patch, the brighter half
     * chained off it (mr_env_nee), the dimmer half left to the sampled
     * paths: both must draw the same line between them. */
    s = chrome_ball_scene(0, 0);
    env = patch_sky(1.6f, 4.8f);
    if (s && env)
        paired("chrome ball, the brighter half chained", s, env, 8,
               (float)(3.2 / pt_env_mean_luminance(env)), 0);
    pt_scene_free(s);
    /* Two balls in one object: between them a point of the plane sees a
     * lamp or the sun in both, which a chain (one root) would not deliver.
     * Chains take smooth opaque surfaces of objects on their convex hull
     * only (with one ball in the sun: chains); these keep their sampled
     * paths, and their renderer, which no chain could connect in, tries
     * none (pt_renderer_chains). */
    for (int v = 0; v < 3; v++) {
        s = chrome_ball_scene(v != 2, v != 0);
        int tries = -1;
        long long n = s ? chains_of(s, v == 0 ? env : NULL, 0.0f, 8, 16, &tries) : -1;
        CHECKF(n >= 0 && (n > 0) == (v == 2), "%s in one object%s: %lld chains",
               v == 2 ? "one ball" : "two balls", v ? " in the sun" : "", n);
        CHECKF(tries == (v == 2), "%s in one object%s: chains %s",
               v == 2 ? "one ball" : "two balls", v ? " in the sun" : "",
               tries == 1 ? "on" : "off");
        pt_scene_free(s);
    }
    pt_env_free(env);
}

/*
 * A directional light through a glass slab, closed form: a Lambert plane
 * (albedo RHO_D) at z = 0 under a slab of smooth thick glass (ior 1.5, z =
 * 1 to 1.5, far wider than the view), lit by a directional light of
 * irradiance E from t degrees off the vertical, seen orthographically
 * straight down through the slab, at max_depth 5 (the plane at depth 2
 * takes its light through the slab's two faces; nothing past that). The
 * slab keeps the light's direction (J = 1), each face passes 1 - F(cos) of
 * it, and the camera's path through the slab at normal incidence passes
 * (1 - F(1))^2 on average, so each pixel reads
 *   (1 - F(1))^2 RHO_D / pi E cos t (1 - F(cos t))^2,
 * F the exact dielectric Fresnel; within 5 standard errors. Without
 * manifold NEE (no_manifold) no path reaches the light: 0.
 */
#define RHO_D 0.6
#define E_DIR 2.0

/* A builder holding a Lambert plane (albedo RHO_D) at z = 0, 200 wide, and
 * in *mg a smooth thick glass material (ior ETA) of the given thickness;
 * NULL on an error. */
static pt_scene_builder *plane_and_glass(float thickness, uint32_t *mg)
{
    pt_error err = {0};
    pt_scene_builder *b = NULL;
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    if (!b)
        return NULL;
    pt_material lam = pt_material_default();
    lam.metallic = 0.0f;
    lam.specular = 0.0f;
    lam.double_sided = 1;
    lam.base_color[0] = lam.base_color[1] = lam.base_color[2] = (float)RHO_D;
    pt_material gl = pt_material_default();
    gl.metallic = 0.0f;
    gl.roughness = 0.0f;
    gl.transmission = 1.0f;
    gl.thickness = thickness;
    gl.ior = (float)ETA;
    uint32_t ml = 0;
    CHECKF(pt_scene_builder_add_material(b, &lam, &ml, &err) == PT_OK, "%s", err.msg);
    CHECKF(pt_scene_builder_add_material(b, &gl, mg, &err) == PT_OK, "%s", err.msg);
    const float R = 100.0f;
    const float plane[12] = {-R, -R, 0, R, -R, 0, R, R, 0, -R, R, 0};
    const uint32_t quad[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "plane", plane, NULL, NULL, 4, quad, 2, NULL, ml, &err) ==
          PT_OK);
    return b;
}

/* b's scene with light l (at `at`; none when l is NULL), seen through
 * cam. */
static pt_scene *lit_scene(pt_scene_builder *b, const pt_punctual *l, const double at[3],
                           pt_camera cam)
{
    pt_error err = {0};
    if (l)
        CHECKF(pt_scene_builder_add_punctual(b, l, at, &err) == PT_OK, "%s", err.msg);
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene_opts o = {0};
    pt_scene *sc = NULL;
    CHECKF(pt_scene_builder_finish(b, &o, &sc, &err) == PT_OK, "%s", err.msg);
    return sc;
}

static pt_scene *slab_scene(double tilt_deg)
{
    uint32_t mg = 0;
    pt_scene_builder *b = plane_and_glass(0.5f, &mg);
    if (!b)
        return NULL;
    pt_error err = {0};
    const float R = 100.0f, lo = 1.0f, hi = 1.5f;
    const uint32_t quad[6] = {0, 1, 2, 0, 2, 3};
    /* The slab's six faces, each with its own vertices and outward normal
     * (counter-clockwise seen from outside). */
    const float c[8][3] = {{-R, -R, lo}, {R, -R, lo}, {R, R, lo}, {-R, R, lo},
                           {-R, -R, hi}, {R, -R, hi}, {R, R, hi}, {-R, R, hi}};
    const int face[6][4] = {{0, 3, 2, 1}, {4, 5, 6, 7}, {0, 1, 5, 4},
                            {1, 2, 6, 5}, {2, 3, 7, 6}, {3, 0, 4, 7}};
    const float fn[6][3] = {{0, 0, -1}, {0, 0, 1}, {0, -1, 0}, {1, 0, 0}, {0, 1, 0}, {-1, 0, 0}};
    float pos[72], nrm[72];
    uint32_t idx[36];
    for (int f = 0; f < 6; f++) {
        for (int v = 0; v < 4; v++)
            for (int j = 0; j < 3; j++) {
                pos[(4 * f + v) * 3 + j] = c[face[f][v]][j];
                nrm[(4 * f + v) * 3 + j] = fn[f][j];
            }
        for (int k = 0; k < 6; k++)
            idx[6 * f + k] = (uint32_t)(4 * f) + quad[k];
    }
    CHECK(pt_scene_builder_add_mesh(b, "slab", pos, nrm, NULL, 24, idx, 12, NULL, mg, &err) ==
          PT_OK);
    pt_punctual l;
    memset(&l, 0, sizeof l);
    l.type = PT_PUNCTUAL_DIRECTIONAL;
    double t = tilt_deg * 3.14159265358979323846 / 180.0;
    l.direction = pt_v3((float)sin(t), 0.0f, (float)-cos(t));
    l.intensity = pt_v3((float)E_DIR, (float)E_DIR, (float)E_DIR);
    snprintf(l.name, sizeof l.name, "sun");
    const double at[3] = {0.0, 0.0, 10.0};
    return lit_scene(b, &l, at, pt_test_ortho_down(0, 0, 3, 0.5f));
}

/* The mean green of s's w x w image, spp samples a pixel, at max_depth
 * depth (manifold NEE off when `off`), and its standard error in *se; the
 * render's stats in *st. */
static double params_mean(const pt_scene *s, const pt_render_params *params, uint32_t spp,
                          pt_render_stats *st, double *se);

static double plane_mean(const pt_scene *s, uint32_t w, uint32_t depth, uint32_t seed, uint32_t spp,
                         int off, pt_render_stats *st, double *se)
{
    pt_render_params p;
    pt_render_params_default(&p);
    p.width = p.height = w;
    p.max_depth = depth;
    p.seed = seed;
    p.no_manifold = (uint32_t)off;
    return params_mean(s, &p, spp, st, se);
}

/* plane_mean's with the parameters p (its image p->width wide). */
static double params_mean(const pt_scene *s, const pt_render_params *p, uint32_t spp,
                          pt_render_stats *st, double *se)
{
    const uint32_t w = p->width;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, p, &r, &err) == PT_OK, "%s", err.msg);
    if (!r)
        return NAN;
    double sum = 0.0, sq = 0.0, n = (double)w * w * spp;
    for (uint32_t i = 0; i < w * w * spp; i++) {
        pt_vec3 v = pt_render_sample(r, i % w, (i / w) % w, i / (w * w), st, NULL);
        sum += v.y;
        sq += (double)v.y * v.y;
    }
    pt_renderer_free(r);
    double m = sum / n;
    *se = sqrt(fmax(sq / n - m * m, 0.0) / (n - 1.0));
    return m;
}

static void directional_slab(void)
{
    for (int tilt = 0; tilt <= 30; tilt += 30) {
        pt_scene *s = slab_scene(tilt);
        if (!s)
            continue;
        double ct = cos(tilt * 3.14159265358979323846 / 180.0),
               f1 = pt_fresnel_dielectric(1.0f, (float)ETA),
               ft = pt_fresnel_dielectric((float)ct, (float)ETA);
        double want = (1.0 - f1) * (1.0 - f1) * RHO_D / 3.14159265358979323846 * E_DIR * ct *
                      (1.0 - ft) * (1.0 - ft);
        for (int off = 0; off <= 1; off++) {
            pt_render_stats st = {0};
            double se = 0.0, m = plane_mean(s, 8, 5, 4, 1024, off, &st, &se);
            printf("slab, light %d deg off the vertical%s: %.6f +- %.6f, closed form %.6f; %llu "
                   "chains\n",
                   tilt, off ? ", without manifold NEE" : "", m, se, off ? 0.0 : want,
                   (unsigned long long)st.chains);
            if (off)
                CHECKF(m == 0.0 && st.chains == 0, "light through the slab without chains: %g", m);
            else
                CHECKF(fabs(m - want) < 5.0 * se + 1e-6 * want, "%g against %g (+- %g)", m, want,
                       se);
        }
        pt_scene_free(s);
    }
}

/*
 * A point light through a glass sphere, closed form: a point light of
 * intensity I_PT at the centre c of a smooth glass sphere (ior 1.5, radius
 * 0.5; hollow with an inner radius of 0.35, or solid) above a Lambert plane
 * (albedo RHO_D) at z = 0, c at height 1. Every ray from c meets the
 * sphere's faces at normal incidence and leaves unbent, so a point p of the
 * plane at distance d from c, at cos t = 1 / d to the vertical, takes the
 * irradiance I (1 - F(1))^m cos t / d^2 (m = 2 faces hollow, 1 solid: flux
 * along a tube of rays, which leaves the solid sphere's glass with no change
 * of index squared). A camera straight down sees a patch 1e-3 wide around
 * p = (1.2, 0.3, 0), past the sphere's outline, at max_depth 3 (the plane's
 * chains alone: a path back to the plane by the sphere has no depth left
 * for one), so each pixel reads RHO_D / pi times that irradiance; within
 * 0.05 % (measured: 1e-5; the sphere's 64 x 32 facets bend the chain a
 * little, their interpolated normals exact at the vertices only), against
 * 2.25 times that in the solid case with the index's square left in, and 0
 * without manifold NEE (a point light behind glass is found by no other
 * path).
 */
#define I_PT 3.0

/* UV spheres of radius rad around c[0 .. count - 1], one mesh, normals out
 * (in when `in`: the cavity's surface, whose front, where the index is 1,
 * faces c). */
static void spheres_mesh(pt_scene_builder *b, const char *name, const double (*c)[3],
                         uint32_t count, double rad, int in, uint32_t mat)
{
    enum { NU = 64, NV = 32, NVERT = (NV + 1) * (NU + 1) };
    float *pos = malloc(sizeof(float) * 3 * NVERT * count);
    float *nrm = malloc(sizeof(float) * 3 * NVERT * count);
    uint32_t *idx = malloc(sizeof(uint32_t) * 6 * NV * NU * count), n = 0;
    for (uint32_t s = 0; s < count; s++) {
        for (int j = 0; j <= NV; j++)
            for (int i = 0; i <= NU; i++) {
                double th = 3.14159265358979323846 * j / NV,
                       ph = 2.0 * 3.14159265358979323846 * i / NU;
                double d[3] = {sin(th) * cos(ph), sin(th) * sin(ph), cos(th)};
                uint32_t v = s * NVERT + (uint32_t)(j * (NU + 1) + i);
                for (int k = 0; k < 3; k++) {
                    pos[3 * v + k] = (float)(c[s][k] + rad * d[k]);
                    nrm[3 * v + k] = (float)(in ? -d[k] : d[k]);
                }
            }
        for (int j = 0; j < NV; j++)
            for (int i = 0; i < NU; i++) {
                uint32_t a = s * NVERT + (uint32_t)(j * (NU + 1) + i), bb = a + NU + 1;
                /* counter-clockwise seen from outside (from inside when `in`) */
                uint32_t t[6] = {a, bb, bb + 1, a, bb + 1, a + 1};
                for (int k = 0; k < 6; k++)
                    idx[n + (uint32_t)k] = t[in ? 5 - k : k];
                n += 6;
            }
    }
    pt_error err = {0};
    CHECKF(pt_scene_builder_add_mesh(b, name, pos, nrm, NULL, NVERT * count, idx, n / 3, NULL, mat,
                                     &err) == PT_OK,
           "%s", err.msg);
    free(pos);
    free(nrm);
    free(idx);
}

/* One UV sphere (spheres_mesh's). */
static void sphere_mesh(pt_scene_builder *b, const char *name, const double c[3], double rad,
                        int in, uint32_t mat)
{
    spheres_mesh(b, name, (const double(*)[3])c, 1, rad, in, mat);
}

/* Spot variants of the point light: none, aimed at the plane's point seen
 * (cone 0.1 to 0.2 rad: the same light there), or straight up (none
 * there: no light sample is taken, so no chain either; a spot whose cone
 * misses the straight line to x is not chained). */
enum { BULB_POINT, BULB_SPOT_AT, BULB_SPOT_UP };

static pt_scene *point_sphere_scene(int hollow, int kind)
{
    uint32_t mg = 0;
    pt_scene_builder *b = plane_and_glass(0.15f, &mg);
    if (!b)
        return NULL;
    const double c[3] = {0.0, 0.0, 1.0};
    sphere_mesh(b, "outer", c, 0.5, 0, mg);
    if (hollow)
        sphere_mesh(b, "inner", c, 0.35, 1, mg);
    pt_punctual l;
    memset(&l, 0, sizeof l);
    l.type = kind == BULB_POINT ? PT_PUNCTUAL_POINT : PT_PUNCTUAL_SPOT;
    l.direction =
        kind == BULB_SPOT_UP ? pt_v3(0.0f, 0.0f, 1.0f) : pt_v3_norm(pt_v3(1.2f, 0.3f, -1.0f));
    l.cos_inner = cosf(0.1f);
    l.cos_outer = cosf(0.2f);
    l.intensity = pt_v3((float)I_PT, (float)I_PT, (float)I_PT);
    snprintf(l.name, sizeof l.name, "bulb");
    return lit_scene(b, &l, c, pt_test_ortho_down(1.2f, 0.3f, 3.0f, 5e-4f));
}

static void point_sphere(void)
{
    static const char *const what[3] = {"point light", "spot aimed at it", "spot aimed up"};
    for (int v = 0; v < 4; v++) {
        int hollow = v != 1, kind = v < 2 ? BULB_POINT : v - 1;
        pt_scene *s = point_sphere_scene(hollow, kind);
        if (!s)
            continue;
        double d2 = 1.2 * 1.2 + 0.3 * 0.3 + 1.0, d = sqrt(d2),
               f1 = pt_fresnel_dielectric(1.0f, (float)ETA);
        double want = kind == BULB_SPOT_UP ? 0.0
                                           : RHO_D / 3.14159265358979323846 * I_PT *
                                                 pow(1.0 - f1, hollow ? 2 : 1) / d / d2;
        for (int off = 0; off <= 1; off++) {
            pt_render_stats st = {0};
            double se = 0.0, m = plane_mean(s, 4, 3, 5, 64, off, &st, &se);
            printf("%s in a %s glass sphere%s: %.6f, closed form %.6f; %llu chains\n", what[kind],
                   hollow ? "hollow" : "solid", off ? ", without manifold NEE" : "", m,
                   off ? 0.0 : want, (unsigned long long)st.chains);
            if (off)
                CHECKF(m == 0.0 && st.chains == 0, "light through the sphere without chains: %g",
                       m);
            else
                CHECKF(fabs(m - want) <= 5e-4 * want && (st.chains > 0) == (want > 0.0),
                       "%g against %g", m, want);
        }
        pt_scene_free(s);
    }
}

/*
 * An emitter through glass, both strategies: an emissive sphere (radius
 * 0.15, radiance LE_BULB) inside the hollow glass sphere of point_sphere,
 * over the Lambert plane, seen from above (32 x 32, 512 spp). The plane
 * sees the emitter only through the glass: BSDF sampling finds it by
 * chance, manifold NEE by light sampling, and the two are weighed by MIS
 * (mf_emit_weight, mf_area_pdf). Paired per-block z-tests against the
 * renderer without manifold NEE (an unbiased estimator of the same image)
 * find no block that differs; weighing the chains by 1 instead of by MIS
 * counts that light twice.
 */
#define LE_BULB 4.0f

static pt_scene *bulb_scene(void)
{
    uint32_t mg = 0;
    pt_scene_builder *b = plane_and_glass(0.15f, &mg);
    if (!b)
        return NULL;
    pt_error err = {0};
    pt_material em = pt_material_default();
    em.metallic = 0.0f;
    em.base_color[0] = em.base_color[1] = em.base_color[2] = 0.0f;
    em.emissive[0] = em.emissive[1] = em.emissive[2] = LE_BULB;
    uint32_t me = 0;
    CHECKF(pt_scene_builder_add_material(b, &em, &me, &err) == PT_OK, "%s", err.msg);
    const double c[3] = {0.0, 0.0, 1.0};
    sphere_mesh(b, "outer", c, 0.5, 0, mg);
    sphere_mesh(b, "inner", c, 0.35, 1, mg);
    sphere_mesh(b, "bulb", c, 0.15, 0, me);
    pt_camera cam = pt_test_ortho_down(0.4f, 0.2f, 3.0f, 1.2f);
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene_opts o = {0};
    pt_scene *sc = NULL;
    CHECKF(pt_scene_builder_finish(b, &o, &sc, &err) == PT_OK, "%s", err.msg);
    return sc;
}

static void emitter_sphere(void)
{
    pt_scene *s = bulb_scene();
    if (s)
        paired("emitter in a glass sphere", s, NULL, 8, 0.0f, 0);
    pt_scene_free(s);
}

/*
 * A directional light off a glass wall, closed form: a Lambert plane
 * (albedo RHO_D) at z = 0 and a wall of smooth thin glass (ior 1.5) in the
 * plane x = 0, 10 high and 200 wide, lit by a directional light of
 * irradiance E from t = 20 degrees off the vertical on the +x side. The
 * wall mirrors the light onto the plane beside it (out to x = 10 tan t),
 * reflecting F(sin t) of it (the wall's Fresnel at its cosine sin t to the
 * light); a camera straight down sees a patch 1e-3 wide around (1, 0.3, 0),
 * where the light also falls directly, at max_depth 2 (the plane's own
 * light samples alone), so each pixel reads
 *   RHO_D / pi E cos t (1 + F(sin t));
 * within 5 standard errors. Without reflection chains (no_manifold) no
 * path finds the mirrored light, a delta seen in a delta: the direct term
 * alone, exactly. Under a roof of the same thin glass (at z = 12, 2,000
 * wide: the sun through it before the wall mirrors it) both terms pass 1 -
 * F(cos t) of it: the chain's light crosses thin walls as shadow rays do;
 * at max_depth 3, which leaves the mirrored path a vertex for the roof. x
 * then picks the wall or the roof (whose underside mirrors no sun), each
 * with probability 1/2: within 5 standard errors.
 * A wall of smooth metal instead (metallic 1, roughness 0: the GGX lobe at
 * PT_BSDF_MIN_ALPHA, which the chains take as a mirror), base colour green
 * G_METAL: the same with Schlick's F = G + (1 - G)(1 - sin t)^5 for the
 * glass's F. NEE at the wall leaves its lobe's light to the plane's chain
 * there (else both would count it): without the roof every sample reads
 * the closed form, to a standard error under 1e-6 of it (with the wall's
 * NEE it is 7e-4). Without the chains the GGX's light is found by the
 * plane's samples that happen to fall within its lobe (0.3605 +- 0.0007
 * against the direct 0.3589), so only their count (none) is checked. A
 * black wall under a smooth clear coat (car paint without its paint): the
 * coat's F = Fc(sin t) = 0.04 + 0.96 (1 - sin t)^5, the same way; a wall of
 * smooth black plastic (a dielectric base of F0 0.04) the same. So does the
 * coated wall whose base has a normal map (a texel 25 degrees off): the
 * coat keeps the wall's own normal (KHR_materials_clearcoat), and the
 * chains mirror off it alone (pt_closure_coat_mirror); without that the
 * coat's sun is found by chance (no chain, the direct term).
 */
#define G_METAL 0.8
/* The wall's material: wall_builder's kind. */
enum { WALL_GLASS, WALL_METAL, WALL_COAT, WALL_PLASTIC, WALL_COAT_MAPPED };

/* A builder holding plane_and_glass's plane and, of its thin glass (of
 * smooth metal, black under a smooth clear coat, or smooth black plastic,
 * by kind), the wall in
 * the plane x = 0 (or, with `pane`, point_wall's small pane in it) and
 * with `roof` the roof, of thin glass; NULL on an error. */
static pt_scene_builder *wall_builder(int pane, int roof, int kind)
{
    uint32_t mg = 0, mw = 0;
    pt_scene_builder *b = plane_and_glass(0.0f, &mg);
    if (!b)
        return NULL;
    pt_error err = {0};
    mw = mg;
    if (kind != WALL_GLASS) {
        pt_material m = pt_material_default();
        m.double_sided = 1;
        if (kind == WALL_METAL) {
            m.metallic = 1.0f;
            m.roughness = 0.0f;
            m.base_color[0] = 0.9f;
            m.base_color[1] = (float)G_METAL;
            m.base_color[2] = 0.7f;
        } else {
            m.metallic = 0.0f;
            m.roughness = 0.0f;
            m.base_color[0] = m.base_color[1] = m.base_color[2] = 0.0f;
            if (kind == WALL_COAT || kind == WALL_COAT_MAPPED) {
                m.specular = 0.0f;
                m.roughness = 1.0f;
                m.clearcoat = 1.0f;
                m.clearcoat_roughness = 0.0f;
            }
            if (kind == WALL_COAT_MAPPED) {
                uint8_t c[3];
                texel_for(25.0, 1.0, c);
                m.normal_tex = (int32_t)one_texel(b, c);
            }
        }
        CHECKF(pt_scene_builder_add_material(b, &m, &mw, &err) == PT_OK, "%s", err.msg);
    }
    const float R = 100.0f, H = 10.0f;
    const float wall[12] = {0, -R, 0, 0, R, 0, 0, R, H, 0, -R, H};
    const float small[12] = {0, 0, 0.6f, 0, 0.8f, 0.6f, 0, 0.8f, 1.4f, 0, 0, 1.4f};
    const uint32_t quad[6] = {0, 1, 2, 0, 2, 3};
    /* u along +y, v along +z: the tangent +y */
    const float *pos = pane ? small : wall;
    float uv[8], tan[16];
    for (int i = 0; i < 4; i++) {
        uv[2 * i] = 0.5f + pos[3 * i + 1] / (2.0f * R);
        uv[2 * i + 1] = pos[3 * i + 2] / H;
        tan[4 * i] = tan[4 * i + 2] = 0.0f;
        tan[4 * i + 1] = tan[4 * i + 3] = 1.0f;
    }
    pt_mesh_extra ex = {NULL, tan, NULL};
    if (kind == WALL_COAT_MAPPED)
        CHECK(pt_scene_builder_add_mesh_extra(b, "wall", pos, NULL, uv, &ex, 4, quad, 2, NULL, mw,
                                              &err) == PT_OK);
    else
        CHECK(pt_scene_builder_add_mesh(b, "wall", pos, NULL, NULL, 4, quad, 2, NULL, mw, &err) ==
              PT_OK);
    /* wider than the plane, so that no point of it sees the sun past it */
    const float W = 10.0f * R, top[12] = {-W, -W, 12, W, -W, 12, W, W, 12, -W, W, 12};
    if (roof)
        CHECK(pt_scene_builder_add_mesh(b, "roof", top, NULL, NULL, 4, quad, 2, NULL, mg, &err) ==
              PT_OK);
    return b;
}

static pt_scene *wall_scene(int roof, int kind)
{
    pt_scene_builder *b = wall_builder(0, roof, kind);
    if (!b)
        return NULL;
    pt_punctual l;
    memset(&l, 0, sizeof l);
    l.type = PT_PUNCTUAL_DIRECTIONAL;
    double t = 20.0 * 3.14159265358979323846 / 180.0;
    l.direction = pt_v3((float)-sin(t), 0.0f, (float)-cos(t));
    l.intensity = pt_v3((float)E_DIR, (float)E_DIR, (float)E_DIR);
    snprintf(l.name, sizeof l.name, "sun");
    const double at[3] = {0.0, 0.0, 10.0};
    return lit_scene(b, &l, at, pt_test_ortho_down(1.0f, 0.3f, 3.0f, 5e-4f));
}

static void directional_wall(void)
{
    for (int v = 0; v < 10; v++) {
        const int roof = v & 1, kind = v >> 1, metal = kind != WALL_GLASS;
        pt_scene *s = wall_scene(roof, kind);
        if (s && kind == WALL_COAT_MAPPED)
            CHECK((s->features & PT_FEAT_NORMAL_MAP) && s->tangents);
        if (!s)
            continue;
        double t = 20.0 * 3.14159265358979323846 / 180.0;
        double pass = roof ? 1.0 - pt_fresnel_dielectric((float)cos(t), (float)ETA) : 1.0;
        double direct = pass * RHO_D / 3.14159265358979323846 * E_DIR * cos(t);
        double f = kind == WALL_METAL   ? G_METAL + (1.0 - G_METAL) * pow(1.0 - sin(t), 5.0)
                   : kind != WALL_GLASS ? 0.04 + 0.96 * pow(1.0 - sin(t), 5.0)
                                        : pt_fresnel_dielectric((float)sin(t), (float)ETA);
        double want = direct * (1.0 + f);
        for (int off = 0; off <= 1; off++) {
            pt_render_stats st = {0};
            double se = 0.0, m = plane_mean(s, 4, roof ? 3 : 2, 6, 256, off, &st, &se);
            printf("%s wall%s, directional light%s: %.6f +- %.6f, closed form %.6f; %llu chains\n",
                   kind == WALL_METAL         ? "metal"
                   : kind == WALL_COAT        ? "coated"
                   : kind == WALL_PLASTIC     ? "plastic"
                   : kind == WALL_COAT_MAPPED ? "coated normal-mapped"
                                              : "glass",
                   roof ? " under a glass roof" : "", off ? ", without reflection chains" : "", m,
                   se, off ? direct : want, (unsigned long long)st.chains);
            if (off && metal)
                CHECK(st.chains == 0);
            else if (off)
                CHECKF(fabs(m - direct) <= 1e-5 * direct && st.chains == 0,
                       "%g against the direct light's %g", m, direct);
            else
                CHECKF(fabs(m - want) < 5.0 * se + 1e-5 * want && st.chains > 0,
                       "%g against %g (+- %g)", m, want, se);
            /* Without the roof every sample reads the closed form: a
             * metal wall's lobe adds nothing by NEE beside its chain. */
            if (!off && !roof)
                CHECKF(se <= 1e-6 * want, "%g +- %g: samples differ", m, se);
        }
        pt_scene_free(s);
    }
}

/*
 * A point light off the glass wall, closed form: wall_scene's plane and
 * wall, lit by a point light of intensity I_PT at l = (2, 0.5, 3) instead
 * of the sun. The plane's point p = (1, 0.3, 0) takes the light directly,
 * I cos / |p - l|^2, and off the wall as from l's mirror image l' = (-2,
 * 0.5, 3), I F(c) cos' / |p - l'|^2, reflecting F(c) at the wall (c = 3 /
 * |p - l'|, the cosine there; the line from l' meets the wall at y = (0,
 * 0.367, 1)).
 * A spot at l aimed between p and that point of the wall, nearer the
 * wall's, whose cone (5 to 20 degrees) dims both lines by different
 * amounts, scales each term by its own: the intensity is the one towards
 * the chain's vertex, not towards p. (A spot whose cone misses the straight
 * line to p is not chained at all: its light sample is not taken there.)
 * Within 1e-4 (a flat wall: no facets); without reflection chains the
 * direct term alone, exactly. A pane 0.8 wide around that point instead of
 * the wall fills about 0.52 sr of p's view, under MR_OMEGA (pi): p chains
 * off it in about a sixth of its samples, weighed up by as much; the mean
 * within 5 standard errors. The metal wall (directional_wall's) with F
 * Schlick's: the point light and the spot the same, with a standard error
 * under 1e-4 of the mean (the wall's NEE leaves the chain's light alone:
 * with it, 2.6e-4 and 1e-3); a point light with a range is not chained off
 * metal, whose NEE then finds a little of its light by chance (the mean at
 * least the direct term's, no chain).
 */

/* glTF's spot falloff along unit u for a spot along unit a. */
static double spot_falloff(const double a[3], const double u[3], double ci, double co)
{
    double t = (dot3(a, u) - co) / (ci - co);
    t = t < 0.0 ? 0.0 : t > 1.0 ? 1.0 : t;
    return t * t;
}

static void point_wall(void)
{
    const double l[3] = {2.0, 0.5, 3.0}, p[3] = {1.0, 0.3, 0.0};
    const double li[3] = {-2.0, 0.5, 3.0};
    double d2 = 0.0, i2 = 0.0;
    for (int j = 0; j < 3; j++) {
        d2 += (p[j] - l[j]) * (p[j] - l[j]);
        i2 += (p[j] - li[j]) * (p[j] - li[j]);
    }
    const double c = 3.0 / sqrt(i2), fg = pt_fresnel_dielectric((float)c, (float)ETA),
                 fm = G_METAL + (1.0 - G_METAL) * pow(1.0 - c, 5.0);
    /* the unit directions from l to p and to the wall's point y (2/3 of the
     * way from l' to p), and the spot's axis between them */
    double up[3] = {p[0] - l[0], p[1] - l[1], p[2] - l[2]}, uy[3], ax[3];
    for (int j = 0; j < 3; j++)
        uy[j] = li[j] + 2.0 / 3.0 * (p[j] - li[j]) - l[j];
    unit3(up);
    unit3(uy);
    for (int j = 0; j < 3; j++)
        ax[j] = 0.3 * up[j] + 0.7 * uy[j];
    unit3(ax);
    const double ci = cos(5.0 * 3.14159265358979323846 / 180.0),
                 co = cos(20.0 * 3.14159265358979323846 / 180.0);
    for (int v = 0; v < 6; v++) {
        /* the point light, the spot, the point light off a small pane; off
         * the metal wall the point light, the spot, and a point light with
         * a range (not chained) */
        const int spot = v == 1 || v == 4, pane = v == 2, metal = v >= 3, ranged = v == 5;
        double sp = spot ? spot_falloff(ax, up, ci, co) : 1.0,
               sy = spot ? spot_falloff(ax, uy, ci, co) : 1.0;
        const double direct = sp * RHO_D / 3.14159265358979323846 * I_PT * (3.0 / sqrt(d2)) / d2;
        const double mirrored =
            sy * RHO_D / 3.14159265358979323846 * I_PT * (metal ? fm : fg) * (3.0 / sqrt(i2)) / i2;
        pt_scene_builder *b = wall_builder(pane, 0, metal ? WALL_METAL : WALL_GLASS);
        if (!b)
            return;
        pt_punctual pl;
        memset(&pl, 0, sizeof pl);
        pl.type = spot ? PT_PUNCTUAL_SPOT : PT_PUNCTUAL_POINT;
        pl.direction = pt_v3((float)ax[0], (float)ax[1], (float)ax[2]);
        pl.cos_inner = (float)ci;
        pl.cos_outer = (float)co;
        pl.intensity = pt_v3((float)I_PT, (float)I_PT, (float)I_PT);
        /* far past the scene: its window (1 - (d / range)^4) is 1 to 2e-7 */
        pl.range = ranged ? 100.0f : 0.0f;
        snprintf(pl.name, sizeof pl.name, "lamp");
        pt_scene *s = lit_scene(b, &pl, l, pt_test_ortho_down(1.0f, 0.3f, 3.0f, 5e-4f));
        if (!s)
            continue;
        double want = direct + mirrored;
        for (int off = 0; off <= 1; off++) {
            pt_render_stats st = {0};
            double se = 0.0, m = plane_mean(s, 4, 2, 6, pane ? 4096 : 64, off, &st, &se);
            double w = off || ranged ? want - mirrored : want;
            printf("%s%s, %s light%s%s: %.6f +- %.6f, closed form %.6f; %llu chains\n",
                   pane ? "pane" : "wall", metal ? " of metal" : "", spot ? "spot" : "point",
                   ranged ? " with a range" : "", off ? ", without reflection chains" : "", m, se,
                   w, (unsigned long long)st.chains);
            if (spot && !off)
                printf("  the spot's falloff towards the plane's point %.4f, the wall's %.4f\n", sp,
                       sy);
            if (metal && (off || ranged))
                /* the GGX lobe's light found by chance, not chained */
                CHECKF(st.chains == 0 && m >= w * (1.0 - 1e-4), "%g against %g; %llu chains", m, w,
                       (unsigned long long)st.chains);
            else if (pane && !off)
                CHECKF(fabs(m - w) < 5.0 * se + 1e-4 * want && st.chains > 0,
                       "%g against %g (+- %g)", m, w, se);
            else
                CHECKF(fabs(m - w) <= 1e-4 * want && (st.chains > 0) == !off &&
                           (!metal || se <= 1e-4 * want),
                       "%g +- %g against %g", m, se, w);
        }
        pt_scene_free(s);
    }
}

/*
 * The sun's glint on smooth metal, seen in smooth metal: a metal floor (z =
 * 0) under a metal panel (at z = 2, its normal (0.766, 0, -0.643)) that
 * mirrors the light of a sun 10 degrees above the +x horizon straight down,
 * seen orthographically straight down. The camera's path samples the
 * floor's lobe, up to the panel, whose NEE finds the sun in its own lobe:
 * the glint. The floor's reflection chain adds nothing there (its closure
 * is all mirror) and the panel's NEE must keep the whole of its lobe (the
 * path's mirror share 1): the image as without the chains, to rounding,
 * and bright (a mean over 10; without the glint 0).
 */
static void glint_in_mirror(void)
{
    pt_error err = {0};
    pt_scene_builder *b = NULL;
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    if (!b)
        return;
    pt_material chrome = pt_material_default();
    chrome.metallic = 1.0f;
    chrome.roughness = 0.0f;
    chrome.double_sided = 1;
    uint32_t mc = 0;
    CHECKF(pt_scene_builder_add_material(b, &chrome, &mc, &err) == PT_OK, "%s", err.msg);
    const float R = 50.0f, floor[12] = {-R, -R, 0, R, -R, 0, R, R, 0, -R, R, 0};
    const uint32_t quad[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "floor", floor, NULL, NULL, 4, quad, 2, NULL, mc, &err) ==
          PT_OK);
    /* the panel: a 4 x 4 square about (0, 0, 2) in the plane of normal n */
    const double e = 10.0 * 3.14159265358979323846 / 180.0;
    double n[3] = {cos(e), 0.0, sin(e) - 1.0}, u[3], v[3] = {0.0, 1.0, 0.0};
    unit3(n);
    set3(u, -n[2], 0.0, n[0]);
    float panel[12];
    const double cs[4][2] = {{-2, -2}, {2, -2}, {2, 2}, {-2, 2}};
    for (int k = 0; k < 4; k++)
        for (int j = 0; j < 3; j++)
            panel[3 * k + j] = (float)((j == 2 ? 2.0 : 0.0) + cs[k][0] * u[j] + cs[k][1] * v[j]);
    CHECK(pt_scene_builder_add_mesh(b, "panel", panel, NULL, NULL, 4, quad, 2, NULL, mc, &err) ==
          PT_OK);
    pt_punctual l;
    memset(&l, 0, sizeof l);
    l.type = PT_PUNCTUAL_DIRECTIONAL;
    l.direction = pt_v3((float)-cos(e), 0.0f, (float)-sin(e));
    l.intensity = pt_v3((float)E_DIR, (float)E_DIR, (float)E_DIR);
    snprintf(l.name, sizeof l.name, "sun");
    const double at[3] = {10.0, 0.0, 10.0};
    pt_scene *s = lit_scene(b, &l, at, pt_test_ortho_down(0.0f, 0.0f, 1.0f, 0.05f));
    if (!s)
        return;
    double mean[2] = {0, 0}, se[2] = {0, 0};
    for (int off = 0; off <= 1; off++) {
        pt_render_stats st = {0};
        mean[off] = plane_mean(s, 4, 3, 6, 64, off, &st, &se[off]);
        printf("glint in a mirror%s: %.6f +- %.6f\n", off ? ", without reflection chains" : "",
               mean[off], se[off]);
    }
    CHECKF(mean[0] > 10.0 && fabs(mean[0] - mean[1]) <= 1e-6 * mean[1],
           "%g with the chains, %g without", mean[0], mean[1]);
    pt_scene_free(s);
}

/* A chrome ball (radius 0.5, Schlick's F of F0 0.9) on plane_and_glass's
 * plane, seen from above with the plane around it; with `two`, two such
 * balls side by side, one object (not on its convex hull); with `sun`, a
 * directional light. */
static pt_scene *chrome_ball_scene(int two, int sun)
{
    uint32_t mg = 0, mc = 0;
    pt_scene_builder *b = plane_and_glass(0.0f, &mg);
    if (!b)
        return NULL;
    pt_material m = pt_material_default();
    m.metallic = 1.0f;
    m.roughness = 0.0f;
    m.base_color[0] = m.base_color[1] = m.base_color[2] = 0.9f;
    pt_error err = {0};
    CHECKF(pt_scene_builder_add_material(b, &m, &mc, &err) == PT_OK, "%s", err.msg);
    const double c[2][3] = {{0.0, 0.0, 0.5}, {0.0, 1.2, 0.5}};
    spheres_mesh(b, "ball", c, two ? 2 : 1, 0.5, 0, mc);
    pt_punctual l;
    memset(&l, 0, sizeof l);
    l.type = PT_PUNCTUAL_DIRECTIONAL;
    l.direction = pt_v3_norm(pt_v3(0.3f, -0.5f, -1.0f));
    l.intensity = pt_v3((float)E_DIR, (float)E_DIR, (float)E_DIR);
    snprintf(l.name, sizeof l.name, "sun");
    const double at[3] = {0.0, 0.0, 10.0};
    return lit_scene(b, sun ? &l : NULL, at, pt_test_ortho_down(0.6f, 0.2f, 3.0f, 1.4f));
}

/*
 * The environment off a metal wall, closed form: wall_scene's plane and
 * metal wall (Schlick's F, green F0 G_METAL) under a uniform sky of
 * radiance L_SKY and no other light, at max_depth 2, the plane's point p =
 * (1, 0.3, 0) seen. Each direction of p's hemisphere either sees the sky
 * or, through the wall (those that meet it), the sky mirrored with F(c),
 * c the cosine at the wall: E = L (pi - int_wall (1 - F(c)) cos dw), the
 * integral by the midpoint rule (wall_loss), and p reads RHO_D / pi E.
 * Every direction chained (manifold_min_light 0: mr_env_nee), none
 * (no_mirror: the sampled paths alone) and the default (a uniform sky has
 * no lamp: no chain), each within 5 standard errors; the wall's NEE and
 * the sky its sampled paths find leave what the chain took (mshare,
 * ekeep), or the chained image reads E plus the mirrored sky again. The
 * same with the black coated wall whose base is normal-mapped
 * (directional_wall's), F the coat's Fc, Schlick's of F0 0.04: its coat
 * alone is the mirror the chains take and the sampled paths leave.
 */
#define L_SKY 0.5

/* int (1 - F(c)) cos dw over the directions from p that meet the wall
 * (x = 0, |y| < 100, 0 < z < 10), F Schlick's of F0 g. */
static double wall_loss(const double p[3], double g)
{
    const int nt = 1200, np = 2400;
    const double pi = 3.14159265358979323846;
    double sum = 0.0;
    for (int i = 0; i < nt; i++) {
        double th = (i + 0.5) * 0.5 * pi / nt, st = sin(th), ct = cos(th);
        for (int j = 0; j < np; j++) {
            double ph = (j + 0.5) * 2.0 * pi / np, dx = st * cos(ph), dy = st * sin(ph);
            if (!(dx < 0.0))
                continue;
            double t = -p[0] / dx, y = p[1] + t * dy, z = p[2] + t * ct;
            if (fabs(y) >= 100.0 || z >= 10.0)
                continue;
            double c = -dx, f = g + (1.0 - g) * pow(1.0 - c, 5.0);
            sum += (1.0 - f) * ct * st;
        }
    }
    return sum * (0.5 * pi / nt) * (2.0 * pi / np);
}

static void env_wall(int kind)
{
    pt_scene_builder *b = wall_builder(0, 0, kind);
    if (!b)
        return;
    pt_scene *s = lit_scene(b, NULL, NULL, pt_test_ortho_down(1.0f, 0.3f, 3.0f, 5e-4f));
    pt_env *env = NULL;
    pt_error err = {0};
    CHECK(pt_env_uniform(pt_v3((float)L_SKY, (float)L_SKY, (float)L_SKY), &env, &err) == PT_OK);
    const char *name = kind == WALL_METAL ? "metal" : "coated normal-mapped";
    if (s && env) {
        const double p[3] = {1.0, 0.3, 0.0}, pi = 3.14159265358979323846;
        /* the coat's Fc is Schlick's of F0 0.04 */
        double want = RHO_D / pi * L_SKY * (pi - wall_loss(p, kind == WALL_METAL ? G_METAL : 0.04));
        static const char *const what[3] = {"every direction chained", "no chain (no_mirror)",
                                            "the default bound: no lamp, no chain"};
        for (int v = 0; v < 3; v++) {
            pt_render_params q;
            pt_render_params_default(&q);
            q.width = q.height = 4;
            q.max_depth = 2;
            q.seed = 6;
            q.env = env;
            if (v == 0)
                q.manifold_min_light = 0.0f;
            q.no_mirror = v == 1;
            pt_render_stats st = {0};
            double se = 0.0, m = params_mean(s, &q, 1024, &st, &se);
            printf("%s wall under a uniform sky, %s: %.6f +- %.6f, closed form %.6f; %llu "
                   "chains\n",
                   name, what[v], m, se, want, (unsigned long long)st.chains);
            CHECKF(fabs(m - want) < 5.0 * se + 1e-4 * want, "%s wall, %s: %g against %g (+- %g)",
                   name, what[v], m, want, se);
            CHECKF(v == 0 ? st.chains > 0 : st.chains == 0, "%s wall, %s: %llu chains", name,
                   what[v], (unsigned long long)st.chains);
        }
    }
    pt_env_free(env);
    pt_scene_free(s);
}

int main(void)
{
    snell();
    slab();
    curved(0);
    curved(1);
    mirror();
    directional_slab();
    point_sphere();
    emitter_sphere();
    directional_wall();
    point_wall();
    glint_in_mirror();
    env_wall(WALL_METAL);
    env_wall(WALL_COAT_MAPPED);
    unbiased();
    return check_report();
}
