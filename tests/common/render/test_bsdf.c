/*
 * test_bsdf.c - the glTF metallic-roughness BSDF: chi-square goodness of fit of
 * every sampling routine (after pbrt-v4's bsdfs_test), eval/pdf/sample
 * consistency, pdf normalisation, albedo and energy bounds, reciprocity, the
 * exact Lambert limit, and no NaN at the edges.
 *
 * Tolerances come from the estimators: chi-square p-values against a
 * significance of 0.01 split over the number of chi-square tests; Monte Carlo
 * means within 3 or 4 of their standard errors. Randomness is a local PCG32
 * (O'Neill 2014) with fixed seeds: i.i.d. numbers, which a chi-square test
 * needs (stratified ones would make it pass too easily).
 */
#include "common/render/bsdf.h"
#include "common/render/sampler.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "tests/check.h"
#include "tests/common/render/closure_of.h"
#include "tests/stats.h"

#define PI_D 3.14159265358979323846

#define N_CHI2_TESTS 19
#include "tests/common/render/dir_chi2.h"

static pt_vec3 uniform_sphere(pcg32 *r)
{
    float z = 1.0f - 2.0f * pcg32_float(r), phi = 2.0f * PT_PI * pcg32_float(r);
    float s = sqrtf(fmaxf(0.0f, 1.0f - z * z));
    return pt_v3(s * cosf(phi), s * sinf(phi), z);
}

/* ---- chi-square survival function (tests/stats.h) ----------------------- */

static void test_chi2_survival(void)
{
    /* Known values: dof 2 is exp(-x/2); dof 1 at 3.841 is 0.05; dof 10 at
     * 18.307 is 0.05; dof 100 at 135.807 is 0.01. */
    CHECK(fabs(stats_chi2_survival(3.0, 2) - exp(-1.5)) < 1e-12);
    CHECK(fabs(stats_chi2_survival(3.841459, 1) - 0.05) < 1e-6);
    CHECK(fabs(stats_chi2_survival(18.307038, 10) - 0.05) < 1e-6);
    CHECK(fabs(stats_chi2_survival(135.806723, 100) - 0.01) < 1e-6);
}

/* ---- sample / pdf adapters ------------------------------------------------- */

static float cos_pdf(const void *ctx, pt_vec3 w)
{
    (void)ctx;
    return w.z > 0.0f ? w.z * PT_INV_PI : 0.0f;
}

static pt_vec3 cos_sample(const void *ctx, pcg32 *r, float *pdf)
{
    (void)ctx;
    float u1 = pcg32_float(r), u2 = pcg32_float(r);
    pt_vec3 w = pt_sample_cosine_hemisphere(u1, u2);
    *pdf = cos_pdf(NULL, w);
    return w;
}

typedef struct bsdf_ctx {
    pt_bsdf b;
    pt_vec3 wo;
} bsdf_ctx;

static float bsdf_pdf(const void *ctx, pt_vec3 w)
{
    const bsdf_ctx *c = ctx;
    return cl_bsdf_pdf(&c->b, c->wo, w);
}

static pt_vec3 bsdf_sample(const void *ctx, pcg32 *r, float *pdf)
{
    const bsdf_ctx *c = ctx;
    float u[3] = {pcg32_float(r), pcg32_float(r), pcg32_float(r)};
    pt_vec3 wi;
    cl_bsdf_sample(&c->b, c->wo, u, &wi, pdf);
    return wi;
}

static pt_vec3 mirror(pt_vec3 wo)
{
    return pt_v3(-wo.x, -wo.y, wo.z);
}

/* p such that the lobe's angular scale alpha lands near t = 0.3. */
static double warp_for(float alpha)
{
    double a2 = (double)alpha * alpha;
    return fmax(1.0, log(a2) / log(0.3));
}

static int g_chi2_samples = 500000;

static void test_chi2(void)
{
    int n = g_chi2_samples;
    binning bn = {pt_frame_from_normal(pt_v3(0, 0, 1)), 1.0, cos_pdf, NULL};
    chi2_run("cosine hemisphere", &bn, cos_sample, NULL, n, 1);

    static const float rough[] = {0.05f, 0.3f, 0.7f, 1.0f};
    static const float view[] = {0.0f, 45.0f, 80.0f};
    char name[128];
    uint64_t seed = 100;
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 3; j++) {
            bsdf_ctx c;
            c.b = pt_bsdf_setup(pt_v3(0.9f, 0.6f, 0.3f), 1.0f, rough[i], 1.0f, pt_v3(1, 1, 1));
            c.wo = dir_at(view[j], 0.7f);
            binning b2 = {pt_frame_from_normal(mirror(c.wo)), warp_for(c.b.alpha), bsdf_pdf, &c};
            snprintf(name, sizeof name, "GGX metal roughness %.2f view %.0f", rough[i], view[j]);
            chi2_run(name, &b2, bsdf_sample, &c, n, seed++);
        }
    static const float mix_rough[] = {0.3f, 0.7f};
    for (int i = 0; i < 2; i++)
        for (int j = 0; j < 3; j++) {
            bsdf_ctx c;
            c.b = pt_bsdf_setup(pt_v3(0.8f, 0.5f, 0.2f), 0.5f, mix_rough[i], 1.0f, pt_v3(1, 1, 1));
            c.wo = dir_at(view[j], -1.2f);
            binning b2 = {pt_frame_from_normal(mirror(c.wo)), warp_for(c.b.alpha), bsdf_pdf, &c};
            snprintf(name, sizeof name, "mixture metallic 0.5 roughness %.2f view %.0f",
                     mix_rough[i], view[j]);
            chi2_run(name, &b2, bsdf_sample, &c, n, seed++);
        }
}

/* ---- the rest ------------------------------------------------------------- */

static pt_bsdf random_material(pcg32 *r)
{
    pt_vec3 base = pt_v3(pcg32_float(r), pcg32_float(r), pcg32_float(r));
    float metallic = pcg32_float(r) < 0.3f ? (pcg32_float(r) < 0.5f ? 0.0f : 1.0f) : pcg32_float(r);
    float rough = pcg32_float(r) < 0.2f ? 0.0f : pcg32_float(r);
    float spec = pcg32_float(r) < 0.2f ? 0.0f : pcg32_float(r);
    pt_vec3 sc = pt_v3(pcg32_float(r) * 2.0f, pcg32_float(r), pcg32_float(r));
    return pt_bsdf_setup(base, metallic, rough, spec, sc);
}

static void test_consistency(void)
{
    pcg32 r = pcg32_make(7, 1);
    int bad_w = 0, bad_pdf = 0, bad_eval_pdf = 0, nonfinite = 0, n = 0;
    for (int m = 0; m < 2000; m++) {
        pt_bsdf b = random_material(&r);
        pt_vec3 wo = uniform_sphere(&r);
        wo.z = fabsf(wo.z);
        for (int k = 0; k < 50; k++) {
            float u[3] = {pcg32_float(&r), pcg32_float(&r), pcg32_float(&r)};
            pt_vec3 wi;
            float pdf;
            pt_vec3 w = cl_bsdf_sample(&b, wo, u, &wi, &pdf);
            nonfinite += !pt_isfinite3(w) || !isfinite(pdf);
            if (!(pdf > 0.0f))
                continue;
            n++;
            float epdf;
            pt_vec3 f = cl_bsdf_eval(&b, wo, wi, &epdf);
            bad_pdf += rel_err(pdf, cl_bsdf_pdf(&b, wo, wi)) > 1e-5f;
            bad_eval_pdf += rel_err(pdf, epdf) > 1e-5f;
            pt_vec3 ratio = pt_v3_scale(f, 1.0f / epdf);
            bad_w += rel_err(w.x, ratio.x) > 1e-3f || rel_err(w.y, ratio.y) > 1e-3f ||
                     rel_err(w.z, ratio.z) > 1e-3f;
        }
    }
    CHECKF(n > 50000, "only %d possible samples", n);
    CHECKF(nonfinite == 0, "%d non-finite samples", nonfinite);
    CHECKF(bad_w == 0, "%d weights differ from eval / pdf", bad_w);
    CHECKF(bad_pdf == 0, "%d sampled pdfs differ from cl_bsdf_pdf", bad_pdf);
    CHECKF(bad_eval_pdf == 0, "%d eval pdfs differ from cl_bsdf_pdf", bad_eval_pdf);
}

/* The GGX pieces are normalised: int D(m) cos(m) dm = 1 and the visible
 * normal pdf integrates to 1 (Heitz 2014, eqs. 4 and 16), by quadrature. */
typedef struct ggx_ctx {
    pt_vec3 wo;
    float alpha;
} ggx_ctx;

static float d_cos(const void *ctx, pt_vec3 m)
{
    const ggx_ctx *c = ctx;
    return pt_ggx_d(m, c->alpha) * fmaxf(m.z, 0.0f);
}

static float vndf(const void *ctx, pt_vec3 m)
{
    const ggx_ctx *c = ctx;
    return pt_ggx_vndf_pdf(c->wo, m, c->alpha);
}

static void test_ggx_normalisation(void)
{
    static const float alphas[] = {1e-3f, 0.01f, 0.1f, 0.5f, 1.0f};
    static double prob[NCELL];
    for (int i = 0; i < 5; i++)
        for (int j = 0; j < 3; j++) {
            ggx_ctx c = {dir_at(j * 40.0f, 0.2f), alphas[i]};
            binning bn = {pt_frame_from_normal(pt_v3(0, 0, 1)), warp_for(alphas[i] * 0.5f), d_cos,
                          &c};
            double s = 0.0;
            cell_probs(&bn, prob);
            for (int k = 0; k < NCELL; k++)
                s += prob[k];
            CHECKF(fabs(s - 1.0) < 2e-3, "alpha %g: int D cos = %.6f", alphas[i], s);
            bn.pdf = vndf;
            s = 0.0;
            cell_probs(&bn, prob);
            for (int k = 0; k < NCELL; k++)
                s += prob[k];
            CHECKF(fabs(s - 1.0) < 2e-3, "alpha %g view %d: int vndf = %.6f", alphas[i], j * 40, s);
        }
}

/* MC integral of cl_bsdf_pdf over the sphere with uniform directions, against
 * the fraction of possible samples; both with their standard errors. */
static void test_pdf_integral_mc(void)
{
    static const float rough[] = {0.3f, 0.6f, 1.0f};
    static const float view[] = {0.0f, 60.0f, 85.0f};
    pcg32 r = pcg32_make(3, 3);
    const int n = 200000;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            pt_bsdf b =
                pt_bsdf_setup(pt_v3(0.5f, 0.5f, 0.5f), 0.7f, rough[i], 1.0f, pt_v3(1, 1, 1));
            pt_vec3 wo = dir_at(view[j], 2.0f);
            double s = 0.0, s2 = 0.0;
            for (int k = 0; k < n; k++) {
                double v = cl_bsdf_pdf(&b, wo, uniform_sphere(&r)) * 4.0 * PI_D;
                s += v, s2 += v * v;
            }
            double mean = s / n, sd = sqrt(fmax(0.0, s2 / n - mean * mean) / n);
            int possible = 0;
            for (int k = 0; k < n; k++) {
                float u[3] = {pcg32_float(&r), pcg32_float(&r), pcg32_float(&r)};
                pt_vec3 wi;
                float pdf;
                cl_bsdf_sample(&b, wo, u, &wi, &pdf);
                possible += pdf > 0.0f;
            }
            double q = (double)possible / n, qsd = sqrt(fmax(q * (1.0 - q), 1.0 / n) / n);
            CHECKF(mean <= 1.0 + 4.0 * sd, "rough %.1f view %.0f: int pdf %.5f +- %.5f", rough[i],
                   view[j], mean, sd);
            CHECKF(fabs(mean - q) < 4.0 * sqrt(sd * sd + qsd * qsd),
                   "rough %.1f view %.0f: int pdf %.5f +- %.5f, possible %.5f", rough[i], view[j],
                   mean, sd, q);
            if (view[j] == 0.0f && rough[i] <= 0.3f)
                CHECKF(fabs(mean - 1.0) < 4.0 * sd + 1e-3, "int pdf %.5f at normal view", mean);
        }
}

typedef struct estimate {
    double mean, sd;
} estimate;

/* Directional albedo int f cos dwi by BSDF sampling (weights), per channel 0. */
static estimate albedo_sampled(const pt_bsdf *b, pt_vec3 wo, int n, pcg32 *r)
{
    double s = 0.0, s2 = 0.0;
    for (int k = 0; k < n; k++) {
        float u[3] = {pcg32_float(r), pcg32_float(r), pcg32_float(r)};
        pt_vec3 wi;
        float pdf;
        double v = cl_bsdf_sample(b, wo, u, &wi, &pdf).x;
        s += v, s2 += v * v;
    }
    double mean = s / n;
    return (estimate){mean, sqrt(fmax(0.0, s2 / n - mean * mean) / n)};
}

/* The same integral with cosine-distributed directions and cl_bsdf_eval: an
 * estimator independent of the sampling code. */
static estimate albedo_cosine(const pt_bsdf *b, pt_vec3 wo, int n, pcg32 *r)
{
    double s = 0.0, s2 = 0.0;
    for (int k = 0; k < n; k++) {
        pt_vec3 wi = pt_sample_cosine_hemisphere(pcg32_float(r), pcg32_float(r));
        float pdf;
        double v = wi.z > 0.0f ? cl_bsdf_eval(b, wo, wi, &pdf).x / (wi.z * PT_INV_PI) : 0.0;
        s += v, s2 += v * v;
    }
    double mean = s / n;
    return (estimate){mean, sqrt(fmax(0.0, s2 / n - mean * mean) / n)};
}

static void test_albedo(void)
{
    static const float rough[] = {0.0f, 0.05f, 0.2f, 0.4f, 0.6f, 0.8f, 1.0f};
    static const float view[] = {0.0f, 30.0f, 60.0f, 75.0f, 85.0f, 89.0f};
    pcg32 r = pcg32_make(11, 5);
    const int n = 20000;
    for (int i = 0; i < 7; i++)
        for (int j = 0; j < 6; j++) {
            pt_vec3 wo = dir_at(view[j], 0.4f);
            /* White metal: F = 1, only the GGX lobe. */
            pt_bsdf metal = pt_bsdf_setup(pt_v3(1, 1, 1), 1.0f, rough[i], 1.0f, pt_v3(1, 1, 1));
            estimate a = albedo_sampled(&metal, wo, n, &r);
            CHECKF(a.mean <= 1.0 + 3.0 * a.sd, "metal r %.2f view %.0f: albedo %.4f +- %.4f",
                   rough[i], view[j], a.mean, a.sd);
            if (rough[i] >= 0.4f) {
                estimate c = albedo_cosine(&metal, wo, n, &r);
                CHECKF(fabs(a.mean - c.mean) < 4.0 * sqrt(a.sd * a.sd + c.sd * c.sd),
                       "metal r %.2f view %.0f: sampled %.4f +- %.4f, cosine %.4f +- %.4f",
                       rough[i], view[j], a.mean, a.sd, c.mean, c.sd);
            }
            /* White dielectric and half metal: never above 1. */
            for (int k = 0; k < 2; k++) {
                pt_bsdf d = pt_bsdf_setup(pt_v3(1, 1, 1), k * 0.5f, rough[i], 1.0f, pt_v3(1, 1, 1));
                estimate e = albedo_sampled(&d, wo, n, &r);
                CHECKF(e.mean <= 1.0 + 3.0 * e.sd,
                       "dielectric m %.1f r %.2f view %.0f: albedo %.4f +- %.4f", k * 0.5, rough[i],
                       view[j], e.mean, e.sd);
            }
            /* White Lambert (specular 0): every weight is 1. */
            pt_bsdf l = pt_bsdf_setup(pt_v3(1, 1, 1), 0.0f, rough[i], 0.0f, pt_v3(1, 1, 1));
            estimate e = albedo_sampled(&l, wo, n, &r);
            CHECKF(fabs(e.mean - 1.0) < 1e-5 && e.sd < 1e-6, "lambert albedo %.7f +- %.2g", e.mean,
                   e.sd);
        }
}

static void test_lambert_limit(void)
{
    pt_vec3 base = pt_v3(0.8f, 0.5f, 0.2f);
    pt_bsdf b = pt_bsdf_setup(base, 0.0f, 0.5f, 0.0f, pt_v3(1, 1, 1));
    CHECK(b.spec_weight == 0.0f);
    CHECK(b.f0.x == 0.0f && b.f0.y == 0.0f && b.f0.z == 0.0f);
    CHECK(b.dielectric_f0 == 0.0f);
    pcg32 r = pcg32_make(5, 9);
    int bad = 0;
    for (int k = 0; k < 10000; k++) {
        pt_vec3 wo = uniform_sphere(&r), wi = uniform_sphere(&r);
        wo.z = fabsf(wo.z), wi.z = fabsf(wi.z);
        float pdf;
        pt_vec3 f = cl_bsdf_eval(&b, wo, wi, &pdf);
        pt_vec3 want = pt_v3_scale(base, wi.z * PT_INV_PI);
        bad += rel_err(f.x, want.x) > 1e-6f || rel_err(f.y, want.y) > 1e-6f ||
               rel_err(f.z, want.z) > 1e-6f || rel_err(pdf, wi.z * PT_INV_PI) > 1e-6f;
    }
    CHECKF(bad == 0, "%d evaluations differ from base / pi cos", bad);
    /* glTF defaults (specular 1): F0 0.04 dielectric; metal F0 = base. */
    pt_bsdf d = pt_bsdf_setup(base, 0.0f, 0.5f, 1.0f, pt_v3(1, 1, 1));
    CHECK(fabsf(d.f0.x - 0.04f) < 1e-7f && d.spec_weight == 1.0f);
    CHECK(fabsf(d.dielectric_f0 - 0.04f) < 1e-7f);
    CHECK(fabsf(d.alpha - 0.25f) < 1e-7f);
    pt_bsdf m = pt_bsdf_setup(base, 1.0f, 0.0f, 0.3f, pt_v3(1, 1, 1));
    CHECK(m.f0.x == base.x && m.diffuse.x == 0.0f && m.spec_weight == 1.0f);
    CHECK(m.alpha == PT_BSDF_MIN_ALPHA);
}

/*
 * KHR_materials_specular, section "Implementation": a white dielectric
 * (base 1, metallic 0) with specular s and specular colour C has
 *   F_i(x) = f0_i + (s - f0_i)(1 - x)^5,  f0_i = min(0.04 C_i, 1) s,
 *   f cos = F_i(wo.h) D G2 / (4 cos_o) + (1 - max_j F_j(c)) cos_i / pi,
 * c = min(cos_o, cos_i) (bsdf.c: the project's reciprocal stand-in for v.h).
 * The model is written again here in double and its directional albedo per
 * channel is integrated by the midpoint rule over (cos_i, phi_i) at two
 * resolutions; their difference bounds the quadrature's error. The
 * closure's sampling (and eval under cosine sampling) must meet that within
 * 4 standard errors plus that bound, per channel: a diffuse weighed by the
 * white 0.04 s (as before the colour counted) is off by tens of them.
 */
static double spec_ref_fresnel(double f0, double s, double x)
{
    double m = 1.0 - x;
    m = m < 0.0 ? 0.0 : m;
    return f0 + (s - f0) * m * m * m * m * m;
}

static double spec_ref_lambda(double z, double xy2, double alpha)
{
    /* (sqrt(1 + a^2 tan^2) - 1) / 2, Heitz 2014 eq. 86 for GGX. */
    return 0.5 * (sqrt(1.0 + alpha * alpha * xy2 / (z * z)) - 1.0);
}

/* Directional albedo per channel at wo by the midpoint rule, n x 2n cells. */
static void spec_ref_albedo(const double f0[3], double s, double alpha, const double wo[3], int n,
                            double out[3])
{
    double acc[3] = {0.0, 0.0, 0.0};
    double a2 = alpha * alpha, du = 1.0 / n, dp = PI_D / n;
    double lo = spec_ref_lambda(wo[2], wo[0] * wo[0] + wo[1] * wo[1], alpha);
    for (int i = 0; i < n; i++) {
        double zi = (i + 0.5) * du, ri = sqrt(1.0 - zi * zi);
        double c = fmin(wo[2], zi), fmax_c = 0.0;
        for (int k = 0; k < 3; k++)
            fmax_c = fmax(fmax_c, spec_ref_fresnel(f0[k], s, c));
        double diffuse = (1.0 - fmax_c) * zi / PI_D;
        for (int j = 0; j < 2 * n; j++) {
            double ph = (j + 0.5) * dp;
            double wi[3] = {ri * cos(ph), ri * sin(ph), zi};
            double h[3] = {wo[0] + wi[0], wo[1] + wi[1], wo[2] + wi[2]};
            double hl = sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2]);
            for (int k = 0; k < 3; k++)
                h[k] /= hl;
            double t = (h[0] * h[0] + h[1] * h[1]) + a2 * h[2] * h[2];
            double d = a2 / (PI_D * t * t);
            double g2 = 1.0 / (1.0 + lo + spec_ref_lambda(zi, ri * ri, alpha));
            double voh = wo[0] * h[0] + wo[1] * h[1] + wo[2] * h[2];
            double spec = d * g2 / (4.0 * wo[2]);
            for (int k = 0; k < 3; k++)
                acc[k] += spec_ref_fresnel(f0[k], s, voh) * spec + diffuse;
        }
    }
    for (int k = 0; k < 3; k++)
        out[k] = acc[k] * du * dp;
}

static void test_specular_colour_furnace(void)
{
    static const float cols[][3] = {{6.0f, 1.0f, 0.25f}, {30.0f, 2.0f, 0.0f}, {1, 1, 1}};
    static const float specs[] = {0.8f, 1.0f, 0.5f};
    static const float rough[] = {0.5f, 0.8f};
    static const float view[] = {0.0f, 45.0f, 75.0f};
    pcg32 r = pcg32_make(17, 3);
    const int n = 100000;
    for (int ci = 0; ci < 3; ci++)
        for (int ri = 0; ri < 2; ri++)
            for (int vi = 0; vi < 3; vi++) {
                pt_vec3 col = pt_v3(cols[ci][0], cols[ci][1], cols[ci][2]);
                float s = specs[ci];
                pt_bsdf b = pt_bsdf_setup(pt_v3(1, 1, 1), 0.0f, rough[ri], s, col);
                pt_vec3 wo = dir_at(view[vi], 0.3f);
                double f0[3], wod[3] = {wo.x, wo.y, wo.z}, q1[3], q2[3];
                for (int k = 0; k < 3; k++)
                    f0[k] = fmin(0.04 * cols[ci][k], 1.0) * s;
                spec_ref_albedo(f0, s, (double)b.alpha, wod, 300, q1);
                spec_ref_albedo(f0, s, (double)b.alpha, wod, 600, q2);
                double ss[3] = {0, 0, 0}, ss2[3] = {0, 0, 0}, cs[3] = {0, 0, 0}, cs2[3] = {0, 0, 0};
                for (int k = 0; k < n; k++) {
                    float u[3] = {pcg32_float(&r), pcg32_float(&r), pcg32_float(&r)};
                    pt_vec3 wi;
                    float pdf;
                    pt_vec3 w = cl_bsdf_sample(&b, wo, u, &wi, &pdf);
                    pt_vec3 wc = pt_sample_cosine_hemisphere(pcg32_float(&r), pcg32_float(&r));
                    pt_vec3 e = cl_bsdf_eval(&b, wo, wc, &pdf);
                    e = wc.z > 0.0f ? pt_v3_scale(e, 1.0f / (wc.z * PT_INV_PI)) : pt_v3(0, 0, 0);
                    const float wv[3] = {w.x, w.y, w.z}, ev[3] = {e.x, e.y, e.z};
                    for (int c = 0; c < 3; c++) {
                        ss[c] += wv[c], ss2[c] += (double)wv[c] * wv[c];
                        cs[c] += ev[c], cs2[c] += (double)ev[c] * ev[c];
                    }
                }
                for (int c = 0; c < 3; c++) {
                    double quad_err = fabs(q2[c] - q1[c]) + 1e-6;
                    double m1 = ss[c] / n, sd1 = sqrt(fmax(0.0, ss2[c] / n - m1 * m1) / n);
                    double m2 = cs[c] / n, sd2 = sqrt(fmax(0.0, cs2[c] / n - m2 * m2) / n);
                    CHECKF(fabs(m1 - q2[c]) < 4.0 * sd1 + quad_err,
                           "colour %d rough %.1f view %.0f ch %d: sampled %.5f +- %.5f, "
                           "quadrature %.5f (+- %.1g)",
                           ci, rough[ri], view[vi], c, m1, sd1, q2[c], quad_err);
                    CHECKF(fabs(m2 - q2[c]) < 4.0 * sd2 + quad_err,
                           "colour %d rough %.1f view %.0f ch %d: eval %.5f +- %.5f, "
                           "quadrature %.5f (+- %.1g)",
                           ci, rough[ri], view[vi], c, m2, sd2, q2[c], quad_err);
                    CHECKF(q2[c] <= 1.0 + quad_err, "albedo %.5f above 1", q2[c]);
                }
            }
    /* A white colour keeps the plain glTF dielectric's numbers, bit for bit:
     * F0 0.04 s for the diffuse weight and F90 s. */
    for (int i = 0; i <= 4; i++) {
        float s = 0.25f * (float)i;
        pt_bsdf w = pt_bsdf_setup(pt_v3(0.5f, 0.5f, 0.5f), 0.0f, 0.5f, s, pt_v3(1, 1, 1));
        CHECK(w.dielectric_f0 == PT_BSDF_DIELECTRIC_F0 * s && w.dielectric_f90 == s);
    }
}

/* f(wo, wi) = f(wi, wo): eval returns f cos(wi), so compare eval / cos. */
static void test_reciprocity(void)
{
    pcg32 r = pcg32_make(13, 2);
    int bad = 0, n = 0;
    for (int m = 0; m < 200; m++) {
        pt_bsdf b = random_material(&r);
        for (int k = 0; k < 100; k++) {
            pt_vec3 wo = uniform_sphere(&r), wi = uniform_sphere(&r);
            wo.z = fabsf(wo.z), wi.z = fabsf(wi.z);
            if (wo.z < 1e-3f || wi.z < 1e-3f)
                continue;
            float p1, p2;
            pt_vec3 a = pt_v3_scale(cl_bsdf_eval(&b, wo, wi, &p1), 1.0f / wi.z);
            pt_vec3 c = pt_v3_scale(cl_bsdf_eval(&b, wi, wo, &p2), 1.0f / wo.z);
            bad +=
                rel_err(a.x, c.x) > 1e-4f || rel_err(a.y, c.y) > 1e-4f || rel_err(a.z, c.z) > 1e-4f;
            n++;
        }
    }
    CHECKF(bad == 0, "%d of %d pairs not reciprocal", bad, n);
}

/* Below the horizon nothing; grazing and tiny alpha give finite numbers. */
static void test_edges(void)
{
    pt_bsdf b = pt_bsdf_setup(pt_v3(0.7f, 0.7f, 0.7f), 0.3f, 0.0f, 1.0f, pt_v3(1, 1, 1));
    float pdf = 1.0f;
    pt_vec3 f = cl_bsdf_eval(&b, pt_v3(0, 0, 1), pt_v3(0.6f, 0, -0.8f), &pdf);
    CHECK(pdf == 0.0f && f.x == 0.0f && f.y == 0.0f && f.z == 0.0f);
    f = cl_bsdf_eval(&b, pt_v3(0.6f, 0, -0.8f), pt_v3(0, 0, 1), &pdf);
    CHECK(pdf == 0.0f && f.x == 0.0f);
    CHECK(cl_bsdf_pdf(&b, pt_v3(0, 0, -1), pt_v3(0, 0, 1)) == 0.0f);
    pt_vec3 wi;
    float u[3] = {0.5f, 0.5f, 0.5f};
    f = cl_bsdf_sample(&b, pt_v3(0, 0, -1), u, &wi, &pdf);
    CHECK(pdf == 0.0f && f.x == 0.0f);

    static const float zs[] = {0.0f, 1e-30f, 1e-12f, 1e-7f, 1e-4f, 0.01f, 1.0f};
    static const float us[] = {0.0f, 1e-7f, 0.25f, 0.5f, 0.99999994f};
    static const float rough[] = {0.0f, 1e-3f, 0.03f, 1.0f};
    int bad = 0;
    for (int ri = 0; ri < 4; ri++) {
        pt_bsdf m = pt_bsdf_setup(pt_v3(0.9f, 0.9f, 0.9f), 0.5f, rough[ri], 1.0f, pt_v3(1, 1, 1));
        for (int a = 0; a < 7; a++)
            for (int c = 0; c < 7; c++) {
                pt_vec3 wo = pt_v3_norm(pt_v3(sqrtf(1.0f - zs[a] * zs[a]), 0.0f, zs[a]));
                pt_vec3 wv = pt_v3_norm(pt_v3(-sqrtf(1.0f - zs[c] * zs[c]) * 0.6f,
                                              sqrtf(1.0f - zs[c] * zs[c]) * 0.8f, zs[c]));
                float p;
                pt_vec3 e = cl_bsdf_eval(&m, wo, wv, &p);
                bad += !pt_isfinite3(e) || !isfinite(p) || p < 0.0f;
                bad += !isfinite(pt_ggx_g1(wo, m.alpha)) || !isfinite(pt_ggx_d(wv, m.alpha));
                for (int i = 0; i < 5; i++)
                    for (int j = 0; j < 5; j++) {
                        float uu[3] = {us[(i + j) % 5], us[i], us[j]};
                        pt_vec3 w = cl_bsdf_sample(&m, wo, uu, &wi, &p);
                        bad += !pt_isfinite3(w) || !isfinite(p) || !pt_isfinite3(wi);
                        pt_vec3 h = pt_ggx_sample_vndf(wo, m.alpha, us[i], us[j]);
                        bad += !pt_isfinite3(h) || h.z < 0.0f;
                        pt_vec3 cw = pt_sample_cosine_hemisphere(us[i], us[j]);
                        bad +=
                            !pt_isfinite3(cw) || cw.z < 0.0f || fabsf(pt_v3_len(cw) - 1.0f) > 1e-5f;
                    }
            }
    }
    CHECKF(bad == 0, "%d non-finite or invalid results at the edges", bad);
}

/* The SIMD cosine-hemisphere sampler gives the scalar one's bits, for every
 * count (full and partial lanes), on a grid that includes the square's
 * centre (the disk's origin), its edges and both wedges of the concentric
 * map, and on random points. */
static void test_cosine_n(void)
{
    enum { N = 700, STRIDE = 3 };
    static float u[N * STRIDE];
    static float out[3][N]; /* x, y, z */
    uint64_t rng = 12345;
    for (uint32_t k = 0; k < N; k++) {
        float a, b;
        if (k < 17 * 17) {
            a = (float)(k % 17) / 16.0f;
            b = (float)(k / 17) / 16.0f;
            a = a < 1.0f ? a : 0x1.fffffep-1f;
            b = b < 1.0f ? b : 0x1.fffffep-1f;
        } else {
            rng = rng * 6364136223846793005ull + 1442695040888963407ull;
            a = (float)(rng >> 40) * 0x1p-24f;
            b = (float)((rng >> 16) & 0xffffff) * 0x1p-24f;
        }
        u[k * STRIDE] = a;
        u[k * STRIDE + 1] = b;
        u[k * STRIDE + 2] = -1.0f; /* not read */
    }
    int bad = 0;
    for (uint32_t n = 0; n <= 20; n++) {
        memset(out, 0xff, sizeof out);
        pt_sample_cosine_hemisphere_n(u, STRIDE, n, out[0], out[1], out[2]);
        for (uint32_t k = 0; k < n; k++) {
            pt_vec3 w = pt_sample_cosine_hemisphere(u[k * STRIDE], u[k * STRIDE + 1]);
            pt_vec3 o = pt_v3(out[0][k], out[1][k], out[2][k]);
            bad += memcmp(&w, &o, sizeof w) != 0;
        }
        uint32_t first_bad = 0xffffffffu; /* nothing past n is written */
        for (int c = 0; c < 3; c++)
            bad += memcmp(&out[c][n], &first_bad, sizeof first_bad) != 0;
    }
    pt_sample_cosine_hemisphere_n(u, STRIDE, N, out[0], out[1], out[2]);
    for (uint32_t k = 0; k < N; k++) {
        pt_vec3 w = pt_sample_cosine_hemisphere(u[k * STRIDE], u[k * STRIDE + 1]);
        pt_vec3 o = pt_v3(out[0][k], out[1][k], out[2][k]);
        bad += memcmp(&w, &o, sizeof w) != 0;
    }
    CHECKF(bad == 0, "%d SIMD cosine samples differ from the scalar ones", bad);
}

int main(int argc, char **argv)
{
    /* PT_QUICK=1 (or an argument) for a fast run with 10x fewer chi-square
     * samples. */
    const char *quick = getenv("PT_QUICK");
    if (argc > 1 || (quick && quick[0] == '1'))
        g_chi2_samples /= 10;
    (void)argv;
    test_cosine_n();
    test_chi2_survival();
    test_lambert_limit();
    test_edges();
    test_reciprocity();
    test_consistency();
    test_ggx_normalisation();
    test_pdf_integral_mc();
    test_albedo();
    test_specular_colour_furnace();
    test_chi2();
    return check_report();
}
