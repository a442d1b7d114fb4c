/*
 * test_sphtri.c - solid-angle sampling of triangles (common/render/sphtri.c).
 *
 * - The solid angle: an octant's triangle from the origin is pi/2, and random
 *   triangles match Van Oosterom & Strackee 1983's closed form computed here
 *   in double (to 1e-9 relative); the sampler's own solid angle, from the
 *   inner angles, agrees with it (1e-6).
 * - Chi-square goodness of fit against the pdf 1 / Omega: the triangle is cut
 *   into 64 sub-triangles by midpoint subdivision, each sample's direction is
 *   traced back to the triangle and counted in its sub-triangle, and the
 *   expected count is n Omega_sub / Omega from the closed form (200,000
 *   samples, p > 1e-3), at several points, near and far, above and below.
 * - What it pays: irradiance from a large triangle at points on a wall it
 *   nearly touches, estimated by area sampling (cos_p cos_l A / d^2) and by
 *   solid-angle sampling (cos_p Omega). Both means agree (z < 5 on their
 *   combined standard error) and the printed variance ratio is the gain; at
 *   the nearest point solid-angle sampling has the lower variance.
 * - In the renderer: a glossy floor with a large light standing on it,
 *   rendered with solid-angle sampling (PT_LIGHT_SOLID_ANGLE) and with area
 *   sampling only, agrees per 8 x 8 block (blocks.h), and the
 *   pixels' variance is lower with it.
 */
#include "common/render/sphtri.h"

#include <math.h>
#include <stdio.h>

#include "common/render/light.h"
#include "tests/check.h"
#include "tests/common/render/blocks.h"
#include "tests/rng.h"
#include "tests/stats.h"

#define PI_D 3.14159265358979323846

static uint64_t rng_state;

static double rnd(void)
{
    return rng_f24(&rng_state);
}

static void sub3(const double a[3], const double b[3], double o[3])
{
    for (int i = 0; i < 3; i++)
        o[i] = a[i] - b[i];
}

static double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static void cross3(const double a[3], const double b[3], double o[3])
{
    o[0] = a[1] * b[2] - a[2] * b[1];
    o[1] = a[2] * b[0] - a[0] * b[2];
    o[2] = a[0] * b[1] - a[1] * b[0];
}

/* Van Oosterom & Strackee 1983, in double, from p to (a, b, c). */
static double vos(const double p[3], const double a[3], const double b[3], const double c[3])
{
    double A[3], B[3], C[3], x[3];
    sub3(a, p, A);
    sub3(b, p, B);
    sub3(c, p, C);
    double la = sqrt(dot3(A, A)), lb = sqrt(dot3(B, B)), lc = sqrt(dot3(C, C));
    cross3(B, C, x);
    double num = fabs(dot3(A, x));
    double den = la * lb * lc + dot3(A, B) * lc + dot3(B, C) * la + dot3(C, A) * lb;
    double o = 2.0 * atan2(num, den);
    return o < 0.0 ? o + 2.0 * PI_D : o;
}

static pt_vec3 v3(const double a[3])
{
    return pt_v3((float)a[0], (float)a[1], (float)a[2]);
}

static void test_solid_angle(void)
{
    const double o[3] = {0, 0, 0}, x[3] = {1, 0, 0}, y[3] = {0, 1, 0}, z[3] = {0, 0, 1};
    double w = pt_sphtri_solid_angle(v3(o), v3(x), v3(y), v3(z));
    CHECKF(fabs(w - PI_D / 2.0) < 1e-9, "octant: %.12f", w);
    rng_state = 1;
    int bad = 0;
    for (int k = 0; k < 1000; k++) {
        double p[3], t[3][3];
        for (int i = 0; i < 3; i++) {
            p[i] = (double)(float)(4.0 * rnd() - 2.0);
            for (int j = 0; j < 3; j++)
                t[j][i] = (double)(float)(4.0 * rnd() - 2.0);
        }
        double a = pt_sphtri_solid_angle(v3(p), v3(t[0]), v3(t[1]), v3(t[2]));
        double e = vos(p, t[0], t[1], t[2]);
        bad += !(fabs(a - e) <= 1e-9 * e + 1e-12);
    }
    CHECKF(bad == 0, "%d of 1000 solid angles differ from the closed form", bad);
    CHECK(pt_sphtri_solid_angle(v3(o), v3(x), v3(x), v3(z)) == 0.0);
    CHECK(pt_sphtri_solid_angle(v3(x), v3(x), v3(y), v3(z)) == 0.0);
}

/* The sub-triangle (of 4^levels, midpoint subdivision) holding barycentrics
 * l; its corners into out[3][3] from the triangle t. */
static int sub_index(double l[3], int levels)
{
    int idx = 0;
    for (int k = 0; k < levels; k++) {
        int child;
        if (l[0] >= 0.5) {
            child = 0;
            l[0] = 2.0 * l[0] - 1.0, l[1] *= 2.0, l[2] *= 2.0;
        } else if (l[1] >= 0.5) {
            child = 1;
            l[1] = 2.0 * l[1] - 1.0, l[0] *= 2.0, l[2] *= 2.0;
        } else if (l[2] >= 0.5) {
            child = 2;
            l[2] = 2.0 * l[2] - 1.0, l[0] *= 2.0, l[1] *= 2.0;
        } else { /* the middle one: corners at the edges' midpoints */
            child = 3;
            double m0 = 1.0 - 2.0 * l[0], m1 = 1.0 - 2.0 * l[1], m2 = 1.0 - 2.0 * l[2];
            l[0] = m0, l[1] = m1, l[2] = m2;
        }
        idx = 4 * idx + child;
    }
    return idx;
}

/* The corners of sub-triangle idx (sub_index's numbering). */
static void sub_corners(const double t[3][3], int idx, int levels, double out[3][3])
{
    double c[3][3];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            c[i][j] = t[i][j];
    for (int k = levels - 1; k >= 0; k--) {
        int child = (idx >> (2 * k)) & 3;
        double m[3][3]; /* m[i]: midpoint of the edge opposite corner i */
        for (int j = 0; j < 3; j++) {
            m[0][j] = 0.5 * (c[1][j] + c[2][j]);
            m[1][j] = 0.5 * (c[0][j] + c[2][j]);
            m[2][j] = 0.5 * (c[0][j] + c[1][j]);
        }
        double n[3][3];
        for (int j = 0; j < 3; j++) {
            for (int i = 0; i < 3; i++)
                n[i][j] = (child == 3) ? m[i][j] : (i == child ? c[i][j] : m[3 - child - i][j]);
        }
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                c[i][j] = n[i][j];
    }
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            out[i][j] = c[i][j];
}

/* Barycentrics of where the ray p + s d meets the plane of t; 0 if parallel. */
static int hit_bary(const double p[3], const double d[3], const double t[3][3], double l[3])
{
    double e1[3], e2[3], n[3], q[3];
    sub3(t[1], t[0], e1);
    sub3(t[2], t[0], e2);
    cross3(e1, e2, n);
    double dn = dot3(d, n);
    if (dn == 0.0)
        return 0;
    sub3(t[0], p, q);
    double s = dot3(q, n) / dn;
    double x[3] = {p[0] + s * d[0] - t[0][0], p[1] + s * d[1] - t[0][1], p[2] + s * d[2] - t[0][2]};
    double nn = dot3(n, n), c1[3], c2[3];
    cross3(x, e2, c1);
    cross3(e1, x, c2);
    l[1] = dot3(c1, n) / nn;
    l[2] = dot3(c2, n) / nn;
    l[0] = 1.0 - l[1] - l[2];
    return s > 0.0;
}

static void test_chi2(void)
{
    enum { LEVELS = 3, BINS = 64 };
    const double t[3][3] = {{-1, -0.5, 1}, {1.2, -0.3, 1.1}, {0.1, 1.0, 0.9}};
    const double pts[][3] = {{0, 0, 0}, {0.2, 0.1, 0.95}, {3, -2, 5}, {0.5, 0.5, -0.5}};
    rng_state = 2;
    for (int k = 0; k < 4; k++) {
        const double *p = pts[k];
        double total = vos(p, t[0], t[1], t[2]);
        double obs[BINS] = {0}, expd[BINS];
        const int n = 200000;
        for (int b = 0; b < BINS; b++) {
            double c[3][3];
            sub_corners(t, b, LEVELS, c);
            expd[b] = n * vos(p, c[0], c[1], c[2]) / total;
        }
        int lost = 0, bad_omega = 0;
        for (int i = 0; i < n; i++) {
            pt_vec3 wi;
            double omega;
            if (!pt_sphtri_sample(v3(p), v3(t[0]), v3(t[1]), v3(t[2]), (float)rnd(), (float)rnd(),
                                  &wi, &omega)) {
                lost++;
                continue;
            }
            bad_omega += fabs(omega - total) > 1e-6 * total;
            const double d[3] = {wi.x, wi.y, wi.z};
            double l[3];
            if (!hit_bary(p, d, t, l) || l[0] < -1e-4 || l[1] < -1e-4 || l[2] < -1e-4) {
                lost++;
                continue;
            }
            for (int j = 0; j < 3; j++)
                l[j] = l[j] < 0.0 ? 0.0 : l[j];
            obs[sub_index(l, LEVELS)] += 1;
        }
        double chi;
        int dof;
        double pv = stats_chi2_gof(obs, expd, BINS, 5.0, &chi, &dof);
        CHECKF(pv > 1e-3 && lost == 0 && bad_omega == 0,
               "point %d: chi2 %.1f dof %d p %.3g, %d lost, %d bad solid angles", k, chi, dof, pv,
               lost, bad_omega);
        printf("point %d (solid angle %.4f): chi2 %.1f dof %d p %.3f\n", k, total, chi, dof, pv);
    }
}

/* Irradiance at q (normal +z) from the triangle t (radiance 1), n samples:
 * mean and variance of area sampling's and solid-angle sampling's
 * estimates. */
static void irradiance(const double q[3], const double t[3][3], int n, double m[2], double var[2])
{
    double e1[3], e2[3], nl[3];
    sub3(t[1], t[0], e1);
    sub3(t[2], t[0], e2);
    cross3(e1, e2, nl);
    double area = 0.5 * sqrt(dot3(nl, nl));
    double s[2] = {0, 0}, s2[2] = {0, 0};
    for (int i = 0; i < n; i++) {
        double u1 = rnd(), u2 = rnd();
        /* area: uniform point by the square root map (Shirley) */
        double su = sqrt(u1), b1 = su * (1.0 - u2), b2 = su * u2;
        double x[3], d[3];
        for (int j = 0; j < 3; j++)
            x[j] = t[0][j] + b1 * e1[j] + b2 * e2[j];
        sub3(x, q, d);
        double d2 = dot3(d, d), dl = sqrt(d2);
        double cos_p = d[2] / dl, cos_l = fabs(dot3(d, nl)) / (dl * 2.0 * area);
        double fa = cos_p > 0.0 ? cos_p * cos_l * area / d2 : 0.0;
        pt_vec3 wi;
        double omega;
        double fs = 0.0;
        if (pt_sphtri_sample(v3(q), v3(t[0]), v3(t[1]), v3(t[2]), (float)u1, (float)u2, &wi,
                             &omega))
            fs = wi.z > 0.0f ? (double)wi.z * omega : 0.0;
        s[0] += fa;
        s2[0] += fa * fa;
        s[1] += fs;
        s2[1] += fs * fs;
    }
    for (int k = 0; k < 2; k++) {
        m[k] = s[k] / n;
        var[k] = s2[k] / n - m[k] * m[k];
    }
}

static void test_variance(void)
{
    /* a 2 x 2 triangle standing at x = 0.05 over a wall z = 0 */
    const double t[3][3] = {{0.05, -1, 0.02}, {0.05, 1, 0.02}, {0.05, 0, 2}};
    const double xs[] = {0.1, 0.3, 0.5, 1.0, 3.0};
    rng_state = 3;
    double ratio_near = 0.0;
    for (int k = 0; k < 5; k++) {
        const double q[3] = {xs[k], 0.0, 0.0};
        const int n = 400000;
        double m[2], var[2];
        irradiance(q, t, n, m, var);
        double se = sqrt((var[0] + var[1]) / n);
        CHECKF(fabs(m[0] - m[1]) < 5.0 * se, "x = %.2f: area %.6f, solid angle %.6f (se %.2g)",
               xs[k], m[0], m[1], se);
        double ratio = var[1] > 0.0 ? var[0] / var[1] : INFINITY;
        if (k == 0)
            ratio_near = ratio;
        printf("wall at %.2f from the light: irradiance %.5f, variance area %.4g, solid angle "
               "%.4g: %.1fx less\n",
               xs[k], m[1], var[0], var[1], ratio);
    }
    CHECKF(ratio_near > 1.0, "nearest point: solid-angle sampling's variance is %.2fx lower",
           ratio_near);
}

/* A glossy floor [-2, 2]^2 at z = 0 and a 2 x 1.5 light standing on it at
 * x = 0.02, facing -x, seen from above the floor beside it. */
static pt_scene *wall_scene(void)
{
    pt_scene_builder *b = NULL;
    pt_scene *s = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    if (!b)
        return NULL;
    pt_material m = pt_material_default();
    m.base_color[0] = m.base_color[1] = m.base_color[2] = 0.7f;
    m.metallic = 0.0f;
    m.roughness = 0.5f;
    m.double_sided = 1;
    uint32_t floor_mat, light_mat;
    const float fl[12] = {-2, -2, 0, 2, -2, 0, 2, 2, 0, -2, 2, 0};
    const uint32_t fi[6] = {0, 1, 2, 0, 2, 3};
    int ok = pt_scene_builder_add_material(b, &m, &floor_mat, &err) == PT_OK;
    m.emissive[0] = m.emissive[1] = m.emissive[2] = 2.0f;
    m.double_sided = 0;
    ok = ok && pt_scene_builder_add_material(b, &m, &light_mat, &err) == PT_OK;
    /* wound to face -x */
    const float lv[12] = {0.02f, -1, 0.01f, 0.02f, -1, 1.5f, 0.02f, 1, 1.5f, 0.02f, 1, 0.01f};
    ok = ok && pt_scene_builder_add_mesh(b, "floor", fl, NULL, NULL, 4, fi, 2, NULL, floor_mat,
                                         &err) == PT_OK;
    ok = ok && pt_scene_builder_add_mesh(b, "light", lv, NULL, NULL, 4, fi, 2, NULL, light_mat,
                                         &err) == PT_OK;
    pt_camera cam = {0};
    cam.yfov = 0.8f;
    cam.znear = 0.01f;
    cam.position = pt_v3(-1.0f, 0, 2.0f);
    cam.forward = pt_v3_norm(pt_v3(0.6f, 0, -1.0f));
    cam.right = pt_v3_norm(pt_v3_cross(cam.forward, pt_v3(0, 0, 1)));
    cam.up = pt_v3_cross(cam.right, cam.forward);
    ok = ok && pt_scene_builder_add_camera(b, &cam, &err) == PT_OK;
    pt_scene_opts o = {0};
    o.scale = 1.0f;
    if (ok)
        ok = pt_scene_builder_finish(b, &o, &s, &err) == PT_OK;
    else
        pt_scene_builder_free(b);
    CHECKF(ok, "wall scene: %s", err.msg);
    return s;
}

static void test_render(void)
{
    pt_scene *s = wall_scene();
    if (!s)
        return;
    double ratio = 0.0;
    int d = blocks_differing(s, NULL, PT_LIGHT_SELECT_POWER | PT_LIGHT_SOLID_ANGLE,
                             PT_LIGHT_SELECT_POWER,
                             "light on a glossy floor, solid angle (a) vs area (b)", &ratio);
    CHECKF(d == 0, "%d blocks differ", d);
    CHECKF(ratio > 1.0, "area sampling's pixel variance is %.3fx solid angle's", ratio);
    pt_scene_free(s);
}

int main(void)
{
    test_solid_angle();
    test_chi2();
    test_variance();
    test_render();
    return check_report();
}
