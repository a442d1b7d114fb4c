/*
 * test_dielectric.c - glass (common/render/dielectric.c) and its place in the
 * integrator (render.c: shade on glass, media).
 *
 * - Fresnel: ((n - 1) / (n + 1))^2 at normal incidence, 1 past the critical
 *   angle, and F(cos_i, eta) = F(cos_t, 1 / eta) (reciprocity).
 * - Sampling: chi-square goodness of fit of cl_glass_sample's directions over
 *   the whole sphere against cl_glass_eval's pdf (integrated per cell by
 *   adaptive Simpson), for roughness 0.3, 0.6 and 0.9, incidences 20, 60 and
 *   80 degrees, entering (eta 1.5) and leaving (1 / 1.5), thick and thin, and
 *   one mixture with the opaque share; each sample's pdf equals the pdf
 *   function's. Significance 0.01 split over the tests.
 * - Energy: the interface's albedo, R + T without the 1 / eta^2 radiance
 *   scaling (which a path undoes when it leaves), is <= 1 within 5 standard
 *   errors at every incidence, from both sides; exactly 1 when smooth. At
 *   ior 1 any roughness passes light straight on with weight 1.
 * - Furnace: a closed smooth glass sphere (flat facets, ior 1.5, no
 *   absorption) under a uniform environment E is invisible: with Russian
 *   roulette off every sample reads E up to rounding; with it on, the mean
 *   is E within 5 standard errors; so is a thin-walled one. A rough one
 *   (roughness 0.5) loses what single-scattering microfacets lose: its mean
 *   lies in [E A^3, E] (5 standard errors), A the smallest albedo of the
 *   interface over incidences from both sides, measured here; a camera ray
 *   that meets the sphere crosses at least two interfaces, and the third
 *   power leaves room for one internal reflection (a band, not an identity).
 * - Slabs at normal incidence (orthographic camera): over a black floor
 *   under E a smooth slab reflects E 2F / (1 + F), F = ((n - 1) / (n + 1))^2
 *   (both faces and their multiple reflections); over an emitter Le, a slab
 *   of thickness d with attenuation colour c at distance D transmits
 *   Le (1 - F)^2 tau / (1 - F^2 tau^2), tau = c^(d / D) per channel.
 * - Media measured exactly: through a slab of ior 1 at large coordinates
 *   (offsets of 0.25; also as an instance) and at the origin (also with a
 *   thin smooth pane inside, which paths cross straight through), at 0, 60
 *   and 80 degrees, every sample is E c^(L / (D cos theta)) to float
 *   precision (media_exact);
 *   a point light inside a rough absorbing box renders the same with ray
 *   offsets of 0.002 and of 0.25 (media_nee).
 * - Estimators: a rough thin pane before an emitter reads the same with MIS,
 *   NEE only and BSDF sampling only (NEE through a rough BTDF works); so it
 *   does before a BLEND emitter of alpha 0.5 (NEE from glass weighs the
 *   emitter's coverage, as BSDF sampling meets it half the time).
 * - Determinism: with glass and media the batched tile loop gives the same
 *   bits as one path at a time, and chunks added in order as one range; so
 *   it does with glass beside a BLEND surface (a glass vertex's shadow ray
 *   draws its own pass-through key).
 * - Shared assets: TransmissionTest, TransmissionRoughnessTest and
 *   AttenuationTest load without warnings about what is now supported,
 *   with the extensions' values (an ior of 2.42, absorbing blocks) and the
 *   feature bits, and render with no NaN/Inf samples.
 * - The builder refuses out-of-range transmission, ior, thickness,
 *   attenuation colour and texture index.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "common/base/alloc.h"
#include "common/render/dielectric.h"
#include "common/render/env.h"
#include "common/render/render.h"
#include "common/scene/scene.h"
#include "tests/check.h"
#include "tests/common/render/closure_of.h"
#include "tests/common/render/paired.h"
#include "tests/rng.h"
#include "tests/stats.h"

#define PI_D 3.14159265358979323846

/* A deterministic uniform generator (splitmix64) for the test's own draws. */
static uint64_t rng = 0x9e3779b97f4a7c15ull;
static float rndf(void)
{
    return rng_f24(&rng);
}

static pt_vec3 incidence(float deg)
{
    float t = deg * (float)PI_D / 180.0f;
    return pt_v3(sinf(t), 0.0f, cosf(t));
}

static pt_glass glass(float roughness, float eta, int thin)
{
    return pt_glass_setup(pt_v3(1, 1, 1), 0.0f, roughness, 1.0f, pt_v3(1, 1, 1), 1.0f, eta, thin);
}

/* ---- Fresnel ------------------------------------------------------------ */

static void fresnel(void)
{
    for (float n = 1.2f; n < 2.6f; n += 0.4f) {
        float want = (n - 1.0f) * (n - 1.0f) / ((n + 1.0f) * (n + 1.0f));
        CHECKF(fabsf(pt_fresnel_dielectric(1.0f, n) - want) < 1e-6f, "n %g", (double)n);
        CHECKF(fabsf(pt_fresnel_dielectric(1.0f, 1.0f / n) - want) < 1e-6f, "n %g", (double)n);
        /* Past the critical angle, asin(1 / n), from inside. */
        float crit = asinf(1.0f / n);
        CHECK(pt_fresnel_dielectric(cosf(crit + 0.01f), 1.0f / n) == 1.0f);
        CHECK(pt_fresnel_dielectric(cosf(crit - 0.01f), 1.0f / n) < 1.0f);
        for (float ci = 0.05f; ci < 1.0f; ci += 0.1f) {
            float st = sqrtf(1.0f - ci * ci) / n, ct = sqrtf(1.0f - st * st);
            CHECK(fabsf(pt_fresnel_dielectric(ci, n) - pt_fresnel_dielectric(ct, 1.0f / n)) <
                  1e-5f);
        }
    }
    CHECK(pt_fresnel_dielectric(0.0f, 1.5f) == 1.0f);
    CHECK(pt_fresnel_dielectric(0.7f, 0.0f) == 1.0f); /* ior 0: a mirror */
}

/* Generalised reciprocity of the radiance BTDF (Veach 1997, eq. 5.16):
 * seen from the other side (frame mirrored, 1 / eta), f(wo, wi) / |cos wi|
 * changes by eta^2 exactly; a reflection is symmetric. Within 1e-4, except
 * where F > 0.5 (near total internal reflection), which is not compared. */
static void reciprocity(void)
{
    for (float rough = 0.3f; rough < 1.0f; rough += 0.3f)
        for (float eta = 1.3f; eta < 2.5f; eta += 0.5f) {
            pt_glass a = glass(rough, eta, 0), b = glass(rough, 1.0f / eta, 0);
            for (int k = 0; k < 50; k++) {
                pt_vec3 wo = incidence(85.0f * rndf()), wi = incidence(85.0f * rndf());
                float ph = 6.2831853f * rndf();
                wi = pt_v3(wi.x * cosf(ph), wi.x * sinf(ph), -wi.z);
                float p;
                pt_vec3 f1 = cl_glass_eval(&a, wo, wi, &p);
                pt_vec3 f2 =
                    cl_glass_eval(&b, pt_v3(wi.x, wi.y, -wi.z), pt_v3(wo.x, wo.y, -wo.z), &p);
                double x = f1.y / fabs(wi.z) * eta * eta, y = f2.y / fabs(wo.z);
                /* Near total internal reflection 1 - F is ill-conditioned in
                 * float (F's slope is unbounded at the critical angle). */
                pt_vec3 h = pt_v3_norm(pt_v3_add(wo, pt_v3_scale(wi, eta)));
                if (pt_fresnel_dielectric(fabsf(pt_v3_dot(wo, h)), eta) > 0.5f)
                    x = y;
                CHECKF(fabs(x - y) <= 1e-4 * fmax(x, y) + 1e-12,
                       "transmission eta %g roughness %g: %g vs %g", (double)eta, (double)rough, x,
                       y);
                pt_vec3 wr = pt_v3(wi.x, wi.y, -wi.z);
                f1 = cl_glass_eval(&a, wo, wr, &p);
                f2 = cl_glass_eval(&a, wr, wo, &p);
                x = f1.y / wr.z, y = f2.y / wo.z;
                CHECKF(fabs(x - y) <= 1e-4 * fmax(x, y) + 1e-12,
                       "reflection eta %g roughness %g: %g vs %g", (double)eta, (double)rough, x,
                       y);
            }
        }
}

/* ---- chi-square over the sphere ----------------------------------------- */

/* Cells uniform in z = cos theta and phi, so every cell has the same solid
 * angle; the lobes of roughness >= 0.3 span several of them. */
#define NZ 24
#define NPHI 24
#define NCELL (NZ * NPHI)
#define N_CHI2 (3 * 3 * 2 * 2 + 1)

typedef struct glass_ctx {
    pt_glass g;
    pt_vec3 wo;
} glass_ctx;

static double pdf_at(const glass_ctx *c, double z, double phi)
{
    double s = sqrt(fmax(0.0, 1.0 - z * z));
    pt_vec3 w = pt_v3((float)(s * cos(phi)), (float)(s * sin(phi)), (float)z);
    float pdf;
    cl_glass_eval(&c->g, c->wo, w, &pdf);
    return pdf;
}

typedef struct simp {
    const glass_ctx *c;
    double z;
    int inner;
    double p0, p1;
} simp;

static double simpson(simp *s, double a, double b, double eps, int depth);

/* The inner integrand is the pdf along phi at fixed z; the outer one is the
 * inner integral, both by adaptive Simpson (a narrow lobe at grazing angles
 * is narrow in phi too). */
static double simp_f(simp *s, double x)
{
    if (s->inner)
        return pdf_at(s->c, s->z, x);
    simp in = *s;
    in.inner = 1;
    in.z = x;
    return simpson(&in, s->p0, s->p1, 1e-7, 12);
}

static double simpson_rec(simp *s, double a, double b, double fa, double fm, double fb,
                          double whole, double eps, int depth)
{
    double m = 0.5 * (a + b), lm = 0.5 * (a + m), rm = 0.5 * (m + b);
    double flm = simp_f(s, lm), frm = simp_f(s, rm);
    double left = (m - a) / 6.0 * (fa + 4.0 * flm + fm);
    double right = (b - m) / 6.0 * (fm + 4.0 * frm + fb);
    double delta = left + right - whole;
    if (depth <= 0 || fabs(delta) <= 15.0 * eps)
        return left + right + delta / 15.0;
    return simpson_rec(s, a, m, fa, flm, fm, left, 0.5 * eps, depth - 1) +
           simpson_rec(s, m, b, fm, frm, fb, right, 0.5 * eps, depth - 1);
}

/* Adaptive Simpson over [a, b], from 4 panels so that a peak inside the
 * interval is not missed by the first estimate. */
static double simpson(simp *s, double a, double b, double eps, int depth)
{
    double sum = 0.0, h = (b - a) / 4.0;
    for (int i = 0; i < 4; i++) {
        double x0 = a + i * h, x1 = x0 + h, xm = 0.5 * (x0 + x1);
        double f0 = simp_f(s, x0), fm = simp_f(s, xm), f1 = simp_f(s, x1);
        sum +=
            simpson_rec(s, x0, x1, f0, fm, f1, h / 6.0 * (f0 + 4.0 * fm + f1), 0.25 * eps, depth);
    }
    return sum;
}

static int cell_of(pt_vec3 w)
{
    double z = fmin(1.0, fmax(-1.0, (double)w.z));
    double phi = atan2((double)w.y, (double)w.x);
    if (phi < 0.0)
        phi += 2.0 * PI_D;
    int iz = (int)((z + 1.0) * 0.5 * NZ), ip = (int)(phi / (2.0 * PI_D) * NPHI);
    iz = iz < 0 ? 0 : (iz >= NZ ? NZ - 1 : iz);
    ip = ip < 0 ? 0 : (ip >= NPHI ? NPHI - 1 : ip);
    return iz * NPHI + ip;
}

static int cmp_d(const void *a, const void *b)
{
    const double *x = a, *y = b;
    return x[0] < y[0] ? -1 : (x[0] > y[0] ? 1 : 0);
}

static void chi2_glass(const char *name, const glass_ctx *c, int n)
{
    static double cells[NCELL + 1][2]; /* expected, observed */
    memset(cells, 0, sizeof cells);
    int lost = 0, bad = 0;
    for (int i = 0; i < n; i++) {
        float u[3] = {rndf(), rndf(), rndf()}, pdf;
        int delta;
        pt_vec3 wi;
        pt_vec3 wt = cl_glass_sample(&c->g, c->wo, u, &wi, &pdf, &delta);
        bad += delta;
        if (!(pdf > 0.0f)) {
            lost++;
            continue;
        }
        float p2;
        pt_vec3 f = cl_glass_eval(&c->g, c->wo, wi, &p2);
        bad += fabsf(pdf - p2) > 1e-4f * p2 || fabsf(wt.y * pdf - f.y) > 1e-4f * f.y + 1e-7f;
        cells[cell_of(wi)][1] += 1.0;
    }
    double total = 0.0;
    for (int iz = 0; iz < NZ; iz++)
        for (int ip = 0; ip < NPHI; ip++) {
            simp s = {c, 0.0, 0, 2.0 * PI_D * ip / NPHI, 2.0 * PI_D * (ip + 1) / NPHI};
            double p = simpson(&s, -1.0 + 2.0 * iz / NZ, -1.0 + 2.0 * (iz + 1) / NZ, 1e-6, 12);
            cells[iz * NPHI + ip][0] = p * n;
            total += p;
        }
    cells[NCELL][0] = fmax(0.0, 1.0 - total) * n;
    cells[NCELL][1] = lost;
    qsort(cells, NCELL + 1, sizeof cells[0], cmp_d);
    double pe = 0.0, po = 0.0, chi2 = 0.0;
    int k = 0, used = 0;
    for (; k < NCELL + 1 && !(cells[k][0] >= 5.0 && pe >= 5.0); k++) {
        pe += cells[k][0];
        po += cells[k][1];
    }
    if (pe > 0.0) {
        chi2 += (po - pe) * (po - pe) / pe;
        used++;
    } else if (po > 0.0) {
        chi2 = INFINITY;
    }
    for (; k < NCELL + 1; k++) {
        double d = cells[k][1] - cells[k][0];
        chi2 += d * d / cells[k][0];
        used++;
    }
    double pval = stats_chi2_survival(chi2, used - 1);
    CHECKF(pval > 0.01 / N_CHI2, "%s: chi-square p-value %.3g (dof %d, pdf integral %.4f)", name,
           pval, used - 1, total);
    CHECKF(bad == 0, "%s: %d samples whose pdf or weight differ from eval's", name, bad);
    CHECKF(total <= 1.0 + 2e-3, "%s: pdf integrates to %.5f", name, total);
}

static void sampling(void)
{
    const float rough[3] = {0.3f, 0.6f, 0.9f}, deg[3] = {20.0f, 60.0f, 80.0f};
    const float etas[2] = {1.5f, 1.0f / 1.5f};
    char name[128];
    for (int t = 0; t < 2; t++)
        for (int e = 0; e < 2; e++)
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) {
                    glass_ctx c = {glass(rough[i], etas[e], t), incidence(deg[j])};
                    snprintf(name, sizeof name, "%s eta %.3f roughness %.1f at %.0f deg",
                             t ? "thin" : "thick", (double)etas[e], (double)rough[i],
                             (double)deg[j]);
                    chi2_glass(name, &c, 200000);
                }
    /* The whole: transmission 0.5 over a metallic 0.3 coloured base. */
    glass_ctx c = {
        pt_glass_setup(pt_v3(0.8f, 0.5f, 0.3f), 0.3f, 0.5f, 1.0f, pt_v3(1, 1, 1), 0.5f, 1.5f, 0),
        incidence(40.0f)};
    CHECK(c.g.pick > 0.0f && c.g.pick < 1.0f);
    chi2_glass("mixture", &c, 200000);
}

/* ---- energy ------------------------------------------------------------- */

/* The interface's albedo at wo and its standard error, R + T with the
 * radiance scaling of the transmission undone. */
static double albedo(const pt_glass *g, pt_vec3 wo, int n, double *se)
{
    double s = 0.0, s2 = 0.0;
    for (int i = 0; i < n; i++) {
        float u[3] = {rndf(), rndf(), rndf()}, pdf;
        int delta;
        pt_vec3 wi;
        pt_vec3 w = cl_glass_sample(g, wo, u, &wi, &pdf, &delta);
        double v = w.y;
        if (wi.z < 0.0f && !g->thin)
            v *= (double)g->eta * g->eta;
        s += v;
        s2 += v * v;
    }
    double m = s / n;
    *se = sqrt(fmax(s2 / n - m * m, 0.0) / n);
    return m;
}

static double min_albedo_rough05 = 1.0;

static void energy(void)
{
    const float rough[4] = {0.0f, 0.3f, 0.5f, 0.9f};
    const float etas[3] = {1.5f, 1.0f / 1.5f, 2.4f};
    for (int i = 0; i < 4; i++)
        for (int e = 0; e < 3; e++)
            for (int t = 0; t < 2; t++)
                for (float deg = 0.0f; deg < 90.0f; deg += 7.5f) {
                    pt_glass g = glass(rough[i], etas[e], t);
                    double se, a = albedo(&g, incidence(deg), 20000, &se);
                    if (rough[i] == 0.0f)
                        CHECKF(fabs(a - 1.0) < 1e-5, "smooth eta %g at %g deg: albedo %.7f",
                               (double)etas[e], (double)deg, a);
                    CHECKF(a <= 1.0 + 5.0 * se + 1e-6,
                           "%s eta %g roughness %g at %g deg: albedo %.5f +- %.5f",
                           t ? "thin" : "thick", (double)etas[e], (double)rough[i], (double)deg, a,
                           se);
                    if (rough[i] == 0.5f && etas[e] < 2.0f && !t &&
                        a - 5.0 * se < min_albedo_rough05)
                        min_albedo_rough05 = a - 5.0 * se;
                }
    printf("rough 0.5 glass: smallest albedo %.4f\n", min_albedo_rough05);
    /* ior 1 (air in TransmissionRoughnessTest): invisible whatever the
     * roughness, light passes straight on with weight 1. */
    for (int t = 0; t < 2; t++) {
        pt_glass g = glass(0.7f, 1.0f, t);
        pt_vec3 wo = incidence(35.0f), wi;
        float u[3] = {0.3f, 0.6f, 0.2f}, pdf;
        int delta;
        pt_vec3 w = cl_glass_sample(&g, wo, u, &wi, &pdf, &delta);
        CHECK(delta && pdf == 1.0f && w.x == 1.0f && w.y == 1.0f);
        CHECK(fabsf(wi.x + wo.x) < 1e-6f && fabsf(wi.y + wo.y) < 1e-6f &&
              fabsf(wi.z + wo.z) < 1e-6f);
    }
}

/* ---- scenes ------------------------------------------------------------- */

static pt_material glass_mat(float roughness, float thickness)
{
    pt_material m = pt_material_default();
    m.metallic = 0.0f;
    m.roughness = roughness;
    m.transmission = 1.0f;
    m.thickness = thickness;
    m.double_sided = 1;
    snprintf(m.name, sizeof m.name, "glass");
    return m;
}

/* A closed polyhedral sphere, flat facets wound outwards. */
static void add_sphere(pt_scene_builder *b, pt_vec3 c, float rad, uint32_t mat)
{
    enum { NLAT = 24, NLON = 48 };
    static float pos[NLAT * NLON * 2 * 9], nrm[NLAT * NLON * 2 * 9];
    uint32_t nt = 0;
    for (int i = 0; i < NLAT; i++)
        for (int j = 0; j < NLON; j++) {
            pt_vec3 q[4];
            for (int k = 0; k < 4; k++) {
                double th = PI_D * (i + (k >> 1)) / NLAT, ph = 2.0 * PI_D * (j + (k & 1)) / NLON;
                q[k] = pt_v3_add(c, pt_v3_scale(pt_v3((float)(sin(th) * cos(ph)),
                                                      (float)(sin(th) * sin(ph)), (float)cos(th)),
                                                rad));
            }
            const int tri[2][3] = {{0, 2, 3}, {0, 3, 1}};
            for (int t = 0; t < 2; t++) {
                pt_vec3 a = q[tri[t][0]], bb = q[tri[t][1]], cc = q[tri[t][2]];
                pt_vec3 n = pt_v3_cross(pt_v3_sub(bb, a), pt_v3_sub(cc, a));
                if (pt_v3_len(n) < 1e-9f)
                    continue; /* the poles' degenerate halves */
                if (pt_v3_dot(n, pt_v3_sub(a, c)) < 0.0f) {
                    pt_vec3 tmp = bb;
                    bb = cc;
                    cc = tmp;
                    n = pt_v3_neg(n);
                }
                n = pt_v3_norm(n);
                pt_vec3 v[3] = {a, bb, cc};
                for (int k = 0; k < 3; k++) {
                    float *p = &pos[9 * nt + 3 * k], *nn = &nrm[9 * nt + 3 * k];
                    p[0] = v[k].x, p[1] = v[k].y, p[2] = v[k].z;
                    nn[0] = n.x, nn[1] = n.y, nn[2] = n.z;
                }
                nt++;
            }
        }
    pt_error err = {0};
    CHECKF(pt_scene_builder_add_mesh(b, "sphere", pos, nrm, NULL, 3 * nt, NULL, nt, NULL, mat,
                                     &err) == PT_OK,
           "%s", err.msg);
}

/* An axis-aligned box, wound outwards. */
static void add_box(pt_scene_builder *b, pt_vec3 lo, pt_vec3 hi, uint32_t mat)
{
    float pos[8 * 3];
    for (int k = 0; k < 8; k++) {
        pos[3 * k] = (k & 1) ? hi.x : lo.x;
        pos[3 * k + 1] = (k & 2) ? hi.y : lo.y;
        pos[3 * k + 2] = (k & 4) ? hi.z : lo.z;
    }
    /* Counter-clockwise seen from outside. */
    const uint32_t idx[36] = {0, 2, 3, 0, 3, 1, 4, 5, 7, 4, 7, 6, 0, 1, 5, 0, 5, 4,
                              2, 6, 7, 2, 7, 3, 0, 4, 6, 0, 6, 2, 1, 3, 7, 1, 7, 5};
    /* Flat normals: separate vertices per face. */
    float p[36 * 3], n[36 * 3];
    pt_vec3 mid = pt_v3_scale(pt_v3_add(lo, hi), 0.5f);
    for (int t = 0; t < 12; t++) {
        pt_vec3 v[3];
        for (int k = 0; k < 3; k++)
            v[k] = pt_v3(pos[3 * idx[3 * t + k]], pos[3 * idx[3 * t + k] + 1],
                         pos[3 * idx[3 * t + k] + 2]);
        pt_vec3 nn = pt_v3_norm(pt_v3_cross(pt_v3_sub(v[1], v[0]), pt_v3_sub(v[2], v[0])));
        if (pt_v3_dot(nn, pt_v3_sub(v[0], mid)) < 0.0f) {
            pt_vec3 tmp = v[1];
            v[1] = v[2];
            v[2] = tmp;
            nn = pt_v3_neg(nn);
        }
        for (int k = 0; k < 3; k++) {
            p[9 * t + 3 * k] = v[k].x, p[9 * t + 3 * k + 1] = v[k].y, p[9 * t + 3 * k + 2] = v[k].z;
            n[9 * t + 3 * k] = nn.x, n[9 * t + 3 * k + 1] = nn.y, n[9 * t + 3 * k + 2] = nn.z;
        }
    }
    pt_error err = {0};
    CHECKF(pt_scene_builder_add_mesh(b, "box", p, n, NULL, 36, NULL, 12, NULL, mat, &err) == PT_OK,
           "%s", err.msg);
}

static uint32_t add_mat(pt_scene_builder *b, const pt_material *m)
{
    uint32_t i = 0;
    pt_error err = {0};
    CHECKF(pt_scene_builder_add_material(b, m, &i, &err) == PT_OK, "%s", err.msg);
    return i;
}

/* A camera on +z looking down -z: orthographic (half-height 1) or a
 * perspective of field yfov. */
static pt_scene *finish(pt_scene_builder *b, float z, int ortho, float yfov)
{
    pt_camera cam = {0};
    cam.position = pt_v3(0, 0, z);
    cam.forward = pt_v3(0, 0, -1);
    cam.right = pt_v3(1, 0, 0);
    cam.up = pt_v3(0, 1, 0);
    cam.yfov = ortho ? 0.0f : yfov;
    cam.ortho = ortho;
    cam.xmag = cam.ymag = 1.0f;
    cam.aspect = 1.0f;
    snprintf(cam.name, sizeof cam.name, "cam");
    pt_error err = {0};
    CHECKF(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK, "%s", err.msg);
    pt_scene_opts o = {0};
    pt_scene *sc = NULL;
    CHECKF(pt_scene_builder_finish(b, &o, &sc, &err) == PT_OK, "%s", err.msg);
    return sc;
}

typedef struct image_stats {
    double mean[3]; /* over all samples of all pixels */
    double se[3];   /* its standard error */
    double max_dev; /* the largest |sample - want| / want seen (when want > 0) */
    uint64_t rejected;
} image_stats;

/* Renders w x w pixels at spp samples one path at a time (pt_render_sample)
 * and gathers per-channel statistics of the samples. */
static image_stats render_stats(const pt_scene *s, const pt_env *env, uint32_t w, uint32_t spp,
                                uint32_t rr_depth, uint32_t strategy, double want)
{
    image_stats is;
    memset(&is, 0, sizeof is);
    pt_render_params p;
    pt_render_params_default(&p);
    p.width = p.height = w;
    p.seed = 7;
    p.env = env;
    /* The default depth cap (1024): a faceted sphere traps some rays by
     * total internal reflection for more than 64 bounces. */
    p.rr_depth = rr_depth;
    p.light_strategy = strategy;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    if (!r)
        return is;
    CHECK(strcmp(pt_renderer_variant(r), "general") == 0);
    double sum[3] = {0, 0, 0}, sq[3] = {0, 0, 0};
    uint64_t n = 0;
    pt_render_stats st = {0};
    for (uint32_t y = 0; y < w; y++)
        for (uint32_t x = 0; x < w; x++)
            for (uint32_t i = 0; i < spp; i++) {
                pt_vec3 c = pt_render_sample(r, x, y, i, &st, NULL);
                if (!pt_isfinite3(c)) {
                    is.rejected++;
                    continue;
                }
                double v[3] = {c.x, c.y, c.z};
                for (int k = 0; k < 3; k++) {
                    sum[k] += v[k];
                    sq[k] += v[k] * v[k];
                }
                if (want > 0.0) {
                    is.max_dev = fmax(is.max_dev, fabs(v[1] - want) / want);
                }
                n++;
            }
    for (int k = 0; k < 3; k++) {
        is.mean[k] = sum[k] / (double)n;
        is.se[k] = sqrt(fmax(sq[k] / (double)n - is.mean[k] * is.mean[k], 0.0) / (double)n);
    }
    pt_renderer_free(r);
    return is;
}

static void furnace(void)
{
    const float E = 0.75f;
    pt_env *env = NULL;
    pt_error err = {0};
    CHECKF(pt_env_uniform(pt_v3(E, E, E), &env, &err) == PT_OK, "%s", err.msg);
    const struct {
        const char *what;
        float roughness, thickness;
    } cases[] = {{"smooth", 0.0f, 1.0f}, {"smooth thin", 0.0f, 0.0f}, {"rough", 0.5f, 1.0f}};
    for (size_t c = 0; c < 3; c++) {
        pt_scene_builder *b = NULL;
        CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
        pt_material m = glass_mat(cases[c].roughness, cases[c].thickness);
        add_sphere(b, pt_v3(0, 0, 0), 1.0f, add_mat(b, &m));
        pt_scene *s = finish(b, 4.0f, 0, 0.55f); /* the sphere fills most of the view */
        if (!s)
            continue;
        CHECK(s->features & PT_FEAT_TRANSMISSION);
        CHECK(!(s->features & PT_FEAT_VOLUME));
        if (cases[c].roughness == 0.0f) {
            /* No roulette: each path reflects or refracts with weight 1 and
             * 1 / eta^2, undone on the way out, so every sample is E. */
            image_stats is = render_stats(s, env, 16, 16, 1000, PT_LIGHT_MIS, E);
            CHECKF(is.max_dev < 1e-4, "%s sphere: a sample is off E by %.3g", cases[c].what,
                   is.max_dev);
            CHECK(is.rejected == 0);
            is = render_stats(s, env, 16, 64, 3, PT_LIGHT_MIS, 0.0);
            CHECKF(fabs(is.mean[1] - E) <= 5.0 * is.se[1] + 1e-6,
                   "%s sphere with roulette: %.5f +- %.5f, want %g", cases[c].what, is.mean[1],
                   is.se[1], (double)E);
        } else {
            image_stats is = render_stats(s, env, 24, 64, 1000, PT_LIGHT_MIS, 0.0);
            double a = min_albedo_rough05, lo = E * a * a * a;
            printf("rough sphere: %.5f +- %.5f in [%.5f, %.5f]\n", is.mean[1], is.se[1], lo,
                   (double)E);
            CHECKF(is.mean[1] <= E + 5.0 * is.se[1], "rough sphere gains energy: %.5f +- %.5f",
                   is.mean[1], is.se[1]);
            CHECKF(is.mean[1] >= lo - 5.0 * is.se[1], "rough sphere: %.5f +- %.5f below %.5f",
                   is.mean[1], is.se[1], lo);
            CHECK(is.rejected == 0);
        }
        pt_scene_free(s);
    }
    pt_env_free(env);
}

/* A glass slab z in [-d, 0] over a floor quad at z = -d - 1 (black, or an
 * emitter of radiance le), seen at normal incidence. */
static pt_scene *slab_scene(float ior, float d, const float att[3], float att_dist, float le)
{
    pt_error err = {0};
    pt_scene_builder *b = NULL;
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material g = glass_mat(0.0f, d);
    g.ior = ior;
    for (int k = 0; k < 3; k++)
        g.attenuation_color[k] = att[k];
    g.attenuation_distance = att_dist;
    add_box(b, pt_v3(-20, -20, -d), pt_v3(20, 20, 0), add_mat(b, &g));
    pt_material f = pt_material_default();
    f.metallic = 0.0f;
    f.specular = 0.0f;
    f.double_sided = 1;
    for (int k = 0; k < 3; k++) {
        f.base_color[k] = 0.0f;
        f.emissive[k] = le;
    }
    snprintf(f.name, sizeof f.name, "floor");
    uint32_t fm = add_mat(b, &f);
    float z = -d - 1.0f;
    const float quad[12] = {-50, -50, z, 50, -50, z, 50, 50, z, -50, 50, z};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECKF(pt_scene_builder_add_mesh(b, "floor", quad, NULL, NULL, 4, idx, 2, NULL, fm, &err) ==
               PT_OK,
           "%s", err.msg);
    return finish(b, 2.0f, 1, 0.0f);
}

static void slabs(void)
{
    const float one[3] = {1, 1, 1};
    pt_env *env = NULL;
    pt_error err = {0};
    const float E = 2.0f;
    CHECKF(pt_env_uniform(pt_v3(E, E, E), &env, &err) == PT_OK, "%s", err.msg);
    for (float n = 1.5f; n < 2.6f; n += 0.9f) {
        pt_scene *s = slab_scene(n, 0.5f, one, 0.0f, 0.0f);
        if (!s)
            continue;
        double F = (n - 1.0) * (n - 1.0) / ((n + 1.0) * (n + 1.0));
        double want = E * 2.0 * F / (1.0 + F);
        image_stats is = render_stats(s, env, 8, 256, 1000, PT_LIGHT_MIS, 0.0);
        printf("slab ior %.1f reflects %.5f +- %.5f, want %.5f\n", (double)n, is.mean[1], is.se[1],
               want);
        CHECKF(fabs(is.mean[1] - want) <= 5.0 * is.se[1], "slab ior %g: %.5f +- %.5f, want %.5f",
               (double)n, is.mean[1], is.se[1], want);
        pt_scene_free(s);
    }
    pt_env_free(env);

    /* Beer-Lambert through a slab d = 0.5 of colour c at distance 0.25:
     * tau = c^2, over an emitter of 3. */
    const float c[3] = {0.5f, 0.25f, 0.8f}, d = 0.5f, dist = 0.25f, le = 3.0f;
    pt_scene *s = slab_scene(1.5f, d, c, dist, le);
    if (!s)
        return;
    CHECK(s->features & PT_FEAT_VOLUME);
    double F = 0.04;
    image_stats is = render_stats(s, NULL, 8, 256, 1000, PT_LIGHT_MIS, 0.0);
    for (int k = 0; k < 3; k++) {
        double tau = pow(c[k], d / dist);
        double want = le * (1.0 - F) * (1.0 - F) * tau / (1.0 - F * F * tau * tau);
        printf("slab transmits %.5f +- %.5f in channel %d, want %.5f\n", is.mean[k], is.se[k], k,
               want);
        CHECKF(fabs(is.mean[k] - want) <= 5.0 * is.se[k] + 1e-6,
               "Beer-Lambert channel %d: %.5f +- %.5f, want %.5f", k, is.mean[k], is.se[k], want);
    }
    pt_scene_free(s);
}

/*
 * The distance a path travels in a medium is the true one: a smooth slab of
 * ior 1 (light goes straight through, weight 1), thickness L and
 * attenuation c^(x / D), under a uniform sky E, seen by an orthographic
 * camera at incidence theta, gives every sample E c^(L / (D cos theta)).
 * The slab's top is at z0: 0, or 12288 in a scene 24,576 across, where a
 * ray's origin is offset from a hit by 256 ULPs of 12288 (0.25, Waechter
 * & Binder); measured from the offset origins instead of the hit points,
 * each crossing would be shortened by about the offset over cos theta.
 * Tolerance, from float precision: the two hit points' z are each within
 * 2 ULPs of their faces', so the length is within 4 ULP(z0) / cos theta,
 * which moves the transmittance by sigma times that, sigma = ln(1 / c) / D;
 * plus 1e-5 for expf and logf.
 */
static void media_exact(void)
{
    const float E = 1.5f, L = 1.0f, D = 0.8f, c = 0.5f;
    pt_env *env = NULL;
    pt_error err = {0};
    CHECKF(pt_env_uniform(pt_v3(E, E, E), &env, &err) == PT_OK, "%s", err.msg);
    /* z0, and whether the slab is an instance of a prototype at the origin
     * (EXT_mesh_gpu_instancing: medium_length takes the hit through it), or
     * holds a thin smooth pane of ior 1 half way down, which paths cross
     * straight through (PT_FEAT_THIN_GLASS: their MIS keeps the slab's top
     * as the last vertex, the medium must not). */
    const float z0s[4] = {0.0f, 12288.0f, 12288.0f, 0.0f}, degs[3] = {0.0f, 60.0f, 80.0f};
    for (int zi = 0; zi < 4; zi++)
        for (int di = 0; di < 3; di++) {
            float z0 = z0s[zi];
            int inst = zi == 2, pane = zi == 3;
            double th = degs[di] * PI_D / 180.0;
            pt_scene_builder *b = NULL;
            CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
            pt_material g = glass_mat(0.0f, L);
            g.ior = 1.0f;
            for (int k = 0; k < 3; k++)
                g.attenuation_color[k] = c;
            g.attenuation_distance = D;
            uint32_t gm = add_mat(b, &g);
            if (!inst)
                add_box(b, pt_v3(-100, -100, z0 - L), pt_v3(100, 100, z0), gm);
            if (pane) {
                pt_material t = glass_mat(0.0f, 0.0f);
                t.ior = 1.0f;
                uint32_t tm = add_mat(b, &t);
                const float h = -0.5f * L;
                const float quad[18] = {-99, -99, h, 99, -99, h, 99,  99, h,
                                        -99, -99, h, 99, 99,  h, -99, 99, h};
                CHECKF(pt_scene_builder_add_mesh(b, "pane", quad, NULL, NULL, 6, NULL, 2, NULL, tm,
                                                 &err) == PT_OK,
                       "%s", err.msg);
            }
            if (z0 > 0.0f) {
                /* Far below, out of every ray's way: the scene spans
                 * 2 z0, so its origin stays at 0. */
                pt_material f = pt_material_default();
                uint32_t fm = add_mat(b, &f);
                const float tri[9] = {-z0, -z0, -z0, 1 - z0, -z0, -z0, -z0, 1 - z0, -z0};
                CHECKF(pt_scene_builder_add_mesh(b, "far", tri, NULL, NULL, 3, NULL, 1, NULL, fm,
                                                 &err) == PT_OK,
                       "%s", err.msg);
            }
            if (inst) {
                uint32_t proto = 0;
                const double xf[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, z0, 1};
                CHECK(pt_scene_builder_begin_prototype(b, &proto, &err) == PT_OK);
                add_box(b, pt_v3(-100, -100, -L), pt_v3(100, 100, 0), gm);
                CHECK(pt_scene_builder_end_prototype(b, &err) == PT_OK);
                CHECKF(pt_scene_builder_add_instance(b, proto, xf, &err) == PT_OK, "%s", err.msg);
            }
            pt_camera cam = {0};
            cam.forward = pt_v3((float)sin(th), 0.0f, (float)-cos(th));
            cam.position = pt_v3_sub(pt_v3(0, 0, z0), pt_v3_scale(cam.forward, 4.0f));
            cam.right = pt_v3(0, 1, 0);
            cam.up = pt_v3_cross(cam.right, cam.forward);
            cam.ortho = 1; /* 0.5 wide: every origin above the slab */
            cam.xmag = cam.ymag = 0.25f;
            cam.aspect = 1.0f;
            snprintf(cam.name, sizeof cam.name, "cam");
            CHECKF(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK, "%s", err.msg);
            pt_scene_opts o = {0};
            pt_scene *s = NULL;
            CHECKF(pt_scene_builder_finish(b, &o, &s, &err) == PT_OK, "%s", err.msg);
            if (!s)
                continue;
            CHECK(s->features & PT_FEAT_VOLUME);
            CHECK(s->origin[2] == 0.0);
            CHECK(!inst || s->num_instances == 1);
            /* The camera's direction as the renderer takes it (float). */
            double cz = fabs((double)pt_v3_norm(cam.forward).z);
            double sigma = log(1.0 / c) / D, len = L / cz;
            double want = E * exp(-sigma * len);
            double ulp = z0 > 0.0f ? ldexp(1.0, ilogb(z0) - 23) : ldexp(1.0, -23);
            double tol = sigma * 4.0 * ulp / cz + 1e-5;
            image_stats is = render_stats(s, env, 8, 4, 1000, PT_LIGHT_MIS, want);
            printf("medium at z %g%s, %g degrees: a sample off E exp(-sigma %.4f) = %.6f by %.3g "
                   "(tolerance %.3g)\n",
                   (double)z0,
                   inst   ? " (instance)"
                   : pane ? " (a pane inside)"
                          : "",
                   (double)degs[di], len, want, is.max_dev, tol);
            CHECKF(is.max_dev <= tol,
                   "slab at z %g, %g degrees: a sample is off %.6f by %.3g of it, over %.3g",
                   (double)z0, (double)degs[di], want, is.max_dev, tol);
            CHECK(is.rejected == 0);
            pt_scene_free(s);
        }
    pt_env_free(env);
}

/*
 * Light sampled from inside a medium crosses it the true distance too: a
 * point light inside a rough absorbing glass box, seen from above, renders
 * the same, paired sample by sample (paired.h), whether the scene is alone
 * (ray offsets of 0.002) or has a triangle 12,288 away (offsets of 0.25,
 * scaled to the scene): every shadow ray from a face of the box measures
 * its medium from the face's hit point to the light, not from the offset
 * origin, which would brighten the far-anchored scene by exp(sigma 0.25).
 */
static void media_nee(void)
{
    pt_scene *sc[2] = {NULL, NULL};
    for (int far = 0; far < 2; far++) {
        pt_error err = {0};
        pt_scene_builder *b = NULL;
        CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
        pt_material g = glass_mat(0.4f, 1.0f);
        for (int k = 0; k < 3; k++)
            g.attenuation_color[k] = 0.5f;
        g.attenuation_distance = 0.8f;
        add_box(b, pt_v3(-2, -2, -1), pt_v3(2, 2, 0), add_mat(b, &g));
        if (far) {
            pt_material f = pt_material_default();
            uint32_t fm = add_mat(b, &f);
            const float tri[9] = {-12288, -12288, -12288, -12287, -12288,
                                  -12288, -12288, -12287, -12288};
            CHECKF(pt_scene_builder_add_mesh(b, "far", tri, NULL, NULL, 3, NULL, 1, NULL, fm,
                                             &err) == PT_OK,
                   "%s", err.msg);
        }
        pt_punctual l;
        memset(&l, 0, sizeof l);
        l.type = PT_PUNCTUAL_POINT;
        l.intensity = pt_v3(1.0f, 1.0f, 1.0f);
        l.direction = pt_v3(0.0f, 0.0f, -1.0f);
        snprintf(l.name, sizeof l.name, "inside");
        const double lp[3] = {0.1, 0.2, -0.5};
        CHECKF(pt_scene_builder_add_punctual(b, &l, lp, &err) == PT_OK, "%s", err.msg);
        sc[far] = finish(b, 2.0f, 1, 0.0f);
    }
    if (sc[0] && sc[1]) {
        int d = paired_differing(sc[0], sc[1], NULL, 8, 64);
        printf("a light inside a medium, offsets of 0.002 and 0.25: %d channels differ\n", d);
        CHECKF(d == 0, "%d pixel channels differ with larger ray offsets", d);
    }
    pt_scene_free(sc[0]);
    pt_scene_free(sc[1]);
}

/* A thin rough pane at z = 0 before an emitter quad at z = -1, both 1.2
 * wide; the three strategies agree. blend: the emitter is a BLEND surface of
 * alpha 0.5, which a BSDF-sampled ray meets half the time, so NEE from the
 * pane must weigh it by its coverage too. */
static void strategies(int blend)
{
    pt_error err = {0};
    pt_scene_builder *b = NULL;
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material g = glass_mat(0.4f, 0.0f);
    g.base_color[1] = 0.7f;
    uint32_t gm = add_mat(b, &g);
    pt_material e = pt_material_default();
    e.metallic = 0.0f;
    e.specular = 0.0f;
    e.double_sided = 1;
    for (int k = 0; k < 3; k++) {
        e.base_color[k] = 0.0f;
        e.emissive[k] = 4.0f;
    }
    if (blend) {
        e.alpha_mode = PT_ALPHA_BLEND;
        e.base_color[3] = 0.5f;
    }
    uint32_t em = add_mat(b, &e);
    const float pane[12] = {-3, -3, 0, 3, -3, 0, 3, 3, 0, -3, 3, 0};
    const float light[12] = {-0.6f, -0.6f, -1, 0.6f, -0.6f, -1, 0.6f, 0.6f, -1, -0.6f, 0.6f, -1};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "pane", pane, NULL, NULL, 4, idx, 2, NULL, gm, &err) ==
          PT_OK);
    CHECK(pt_scene_builder_add_mesh(b, "light", light, NULL, NULL, 4, idx, 2, NULL, em, &err) ==
          PT_OK);
    pt_scene *s = finish(b, 2.0f, 1, 0.0f);
    if (!s)
        return;
    const uint32_t strat[3] = {PT_LIGHT_MIS, PT_LIGHT_NEE_ONLY, PT_LIGHT_BSDF_ONLY};
    image_stats is[3];
    for (int k = 0; k < 3; k++)
        is[k] = render_stats(s, NULL, 8, 512, 3, strat[k], 0.0);
    for (int k = 1; k < 3; k++) {
        double tol = 5.0 * sqrt(is[0].se[1] * is[0].se[1] + is[k].se[1] * is[k].se[1]);
        printf("pane%s: MIS %.5f +- %.5f, strategy %d %.5f +- %.5f\n",
               blend ? " (BLEND light)" : "", is[0].mean[1], is[0].se[1], k, is[k].mean[1],
               is[k].se[1]);
        CHECKF(fabs(is[0].mean[1] - is[k].mean[1]) <= tol,
               "pane%s: MIS %.5f, strategy %d %.5f (tolerance %.5f)", blend ? " (BLEND light)" : "",
               is[0].mean[1], k, is[k].mean[1], tol);
    }
    /* MIS is the one with the least variance here, or near it. */
    CHECK(is[0].mean[1] > 0.1);
    pt_scene_free(s);
}

/* The batched tile loop gives glass and media the same bits as one path at
 * a time (pt_render_sample), and a range split at block boundaries the same
 * bits as one call: images do not depend on how the work is split. */
static void determinism(void)
{
    pt_error err = {0};
    pt_scene_builder *b = NULL;
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material g = glass_mat(0.4f, 1.0f);
    g.attenuation_color[0] = 0.3f;
    g.attenuation_distance = 0.5f;
    add_sphere(b, pt_v3(0.3f, 0, 0), 0.8f, add_mat(b, &g));
    pt_material g2 = glass_mat(0.0f, 1.0f);
    g2.ior = 1.8f;
    g2.attenuation_color[2] = 0.5f;
    g2.attenuation_distance = 1.0f;
    add_box(b, pt_v3(-1.5f, -1.5f, -1.0f), pt_v3(-0.2f, 0.2f, 0.5f), add_mat(b, &g2));
    pt_scene *s = finish(b, 4.0f, 0, 0.8f);
    pt_env *env = NULL;
    CHECK(pt_env_uniform(pt_v3(0.5f, 0.7f, 1.0f), &env, &err) == PT_OK);
    if (!s || !env)
        return;
    CHECK(s->features & PT_FEAT_VOLUME);
    pt_render_params p;
    pt_render_params_default(&p);
    p.width = p.height = 8;
    p.env = env;
    pt_renderer *r = NULL;
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    if (r) {
        static pt_pixel_acc whole[64], part[64], one[64];
        pt_rect all = {0, 0, 8, 8};
        pt_render_tile(r, all, 0, 16, whole, NULL);
        int same = 1;
        for (uint32_t k = 0; k < 64; k++) {
            pt_block_acc blk;
            pt_pixel_acc a;
            memset(&blk, 0, sizeof blk);
            memset(&a, 0, sizeof a);
            for (uint32_t i = 0; i < 16; i++)
                pt_block_acc_sample(&blk, pt_render_sample(r, k % 8, k / 8, i, NULL, NULL));
            pt_pixel_acc_add_block(&a, &blk);
            same &= memcmp(a.fsum, whole[k].fsum, sizeof a.fsum) == 0 && a.n == whole[k].n;
        }
        CHECKF(same, "the batched tile differs from one path at a time");
        pt_render_tile(r, all, 0, 48, whole, NULL);
        memset(part, 0, sizeof part);
        for (uint32_t c = 0; c < 3; c++) {
            pt_render_tile(r, all, 16 * c, 16 * c + 16, one, NULL);
            for (uint32_t k = 0; k < 64; k++)
                pt_pixel_acc_add(&part[k], &one[k]);
        }
        same = 1;
        for (uint32_t k = 0; k < 64; k++)
            same &= memcmp(part[k].fsum, whole[k].fsum, sizeof part[k].fsum) == 0;
        CHECKF(same, "[0,48) differs from three chunks of 16");
    }
    pt_renderer_free(r);
    pt_env_free(env);
    pt_scene_free(s);
}

/* Glass beside a BLEND surface (PT_FEAT_ALPHA): a shadow ray from the glass
 * passes the surface by its own key, so the batched tile loop gives the same
 * bits as one path at a time. */
static void determinism_alpha(void)
{
    pt_error err = {0};
    pt_scene_builder *b = NULL;
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material g = glass_mat(0.4f, 1.0f);
    add_sphere(b, pt_v3(0, 0, 0), 0.8f, add_mat(b, &g));
    pt_material veil = pt_material_default();
    veil.base_color[3] = 0.5f;
    veil.alpha_mode = PT_ALPHA_BLEND;
    veil.double_sided = 1;
    snprintf(veil.name, sizeof veil.name, "veil");
    add_box(b, pt_v3(-3.0f, -3.0f, 1.4f), pt_v3(3.0f, 3.0f, 1.5f), add_mat(b, &veil));
    pt_scene *s = finish(b, 4.0f, 0, 0.8f);
    pt_env *env = NULL;
    CHECK(pt_env_uniform(pt_v3(0.5f, 0.7f, 1.0f), &env, &err) == PT_OK);
    if (!s || !env)
        return;
    CHECK((s->features & PT_FEAT_ALPHA) && (s->features & PT_FEAT_TRANSMISSION));
    pt_render_params p;
    pt_render_params_default(&p);
    p.width = p.height = 8;
    p.env = env;
    pt_renderer *r = NULL;
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    if (r) {
        static pt_pixel_acc whole[64];
        pt_rect all = {0, 0, 8, 8};
        pt_render_tile(r, all, 0, 32, whole, NULL);
        int same = 1;
        for (uint32_t k = 0; k < 64; k++) {
            pt_pixel_acc a;
            memset(&a, 0, sizeof a);
            for (uint32_t i0 = 0; i0 < 32; i0 += 16) {
                pt_block_acc blk;
                memset(&blk, 0, sizeof blk);
                for (uint32_t i = i0; i < i0 + 16; i++)
                    pt_block_acc_sample(&blk, pt_render_sample(r, k % 8, k / 8, i, NULL, NULL));
                pt_pixel_acc_add_block(&a, &blk);
            }
            same &= memcmp(a.fsum, whole[k].fsum, sizeof a.fsum) == 0 && a.n == whole[k].n;
        }
        CHECKF(same, "glass beside a BLEND surface: the batched tile differs from one path at a "
                     "time");
    }
    pt_renderer_free(r);
    pt_env_free(env);
    pt_scene_free(s);
}

/* ---- shared assets ------------------------------------------------------ */

typedef struct warnings {
    char text[8192];
} warnings;

static void collect(void *user, const char *msg)
{
    warnings *w = user;
    size_t len = strlen(w->text);
    snprintf(w->text + len, sizeof w->text - len, "%s\n", msg);
}

static void shared_assets(void)
{
    const char *names[] = {"TransmissionTest", "TransmissionRoughnessTest", "AttenuationTest"};
    for (size_t i = 0; i < 3; i++) {
        char path[512];
        snprintf(path, sizeof path, "%s/%s/%s.glb", PT_SHARED_SCENES, names[i], names[i]);
        struct stat sb;
        if (stat(path, &sb) != 0) {
            CHECK_SKIP("%s not found", names[i]);
            CHECK(!check_shared_required());
            continue;
        }
        warnings w;
        w.text[0] = 0;
        pt_scene_opts o = {0};
        o.warn = collect;
        o.warn_user = &w;
        pt_scene *s = NULL;
        pt_error err = {0};
        CHECKF(pt_scene_load(path, &o, &s, &err) == PT_OK, "%s: %s", names[i], err.msg);
        if (!s)
            continue;
        CHECKF(!strstr(w.text, "transmission") && !strstr(w.text, "_ior") &&
                   !strstr(w.text, "_volume,"),
               "%s warns: %s", names[i], w.text);
        CHECK(s->features & PT_FEAT_TRANSMISSION);
        /* The extensions' values arrive: TransmissionRoughnessTest's diamond
         * row (ior 2.42, thicknessFactor 0.005), AttenuationTest's absorbing
         * blocks. */
        int diamond = 0, absorbs = 0;
        for (uint32_t k = 0; k < s->num_materials; k++) {
            const pt_material *m = &s->materials[k];
            diamond |= m->transmission == 1.0f && fabsf(m->ior - 2.42f) < 1e-6f &&
                       fabsf(m->thickness - 0.005f) < 1e-7f;
            absorbs |= pt_material_absorbs(m);
        }
        if (i == 1)
            CHECK(diamond);
        if (i == 2)
            CHECK(absorbs && (s->features & PT_FEAT_VOLUME));
        pt_env *env = NULL;
        CHECK(pt_env_uniform(pt_v3(1, 1, 1), &env, &err) == PT_OK);
        pt_render_params p;
        pt_render_params_default(&p);
        p.width = p.height = 24;
        p.env = env;
        pt_renderer *r = NULL;
        CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
        if (r) {
            pt_pixel_acc acc[24 * 24];
            pt_render_stats st = {0};
            pt_rect all = {0, 0, 24, 24};
            pt_render_tile(r, all, 0, 8, acc, &st);
            CHECKF(st.rejected == 0, "%s: %llu NaN/Inf samples", names[i],
                   (unsigned long long)st.rejected);
            CHECK(st.samples == 24 * 24 * 8);
        }
        pt_renderer_free(r);
        pt_env_free(env);
        pt_scene_free(s);
    }
}

/* ---- the builder's checks ----------------------------------------------- */

static void refused(void)
{
    pt_error err = {0};
    pt_scene_builder *b = NULL;
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    uint32_t i;
    pt_material m = glass_mat(0.0f, 1.0f);
    CHECK(pt_scene_builder_add_material(b, &m, &i, &err) == PT_OK);
    m.transmission = 1.5f;
    CHECK(pt_scene_builder_add_material(b, &m, &i, &err) == PT_ERR_FORMAT &&
          strstr(err.msg, "transmissionFactor"));
    m = glass_mat(0.0f, 1.0f);
    m.ior = 0.5f;
    CHECK(pt_scene_builder_add_material(b, &m, &i, &err) == PT_ERR_FORMAT &&
          strstr(err.msg, "ior"));
    m.ior = 0.0f; /* the extension's special value */
    CHECK(pt_scene_builder_add_material(b, &m, &i, &err) == PT_OK);
    m = glass_mat(0.0f, -1.0f);
    CHECK(pt_scene_builder_add_material(b, &m, &i, &err) == PT_ERR_FORMAT);
    m = glass_mat(0.0f, 1.0f);
    m.attenuation_color[1] = 2.0f;
    CHECK(pt_scene_builder_add_material(b, &m, &i, &err) == PT_ERR_FORMAT &&
          strstr(err.msg, "attenuationColor"));
    m = glass_mat(0.0f, 1.0f);
    m.transmission_tex = 3;
    CHECK(pt_scene_builder_add_material(b, &m, &i, &err) == PT_ERR_ARG);
    pt_scene_builder_free(b);
}

int main(void)
{
    fresnel();
    reciprocity();
    sampling();
    energy();
    furnace();
    slabs();
    media_exact();
    media_nee();
    strategies(0);
    strategies(1);
    determinism();
    determinism_alpha();
    shared_assets();
    refused();
    return check_report();
}
