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
#include "tests/stats.h"

#define PI_D 3.14159265358979323846

/* ---- randomness ---------------------------------------------------------- */

typedef struct pcg32 {
    uint64_t state, inc;
} pcg32;

static uint32_t pcg32_next(pcg32 *r)
{
    uint64_t old = r->state;
    r->state = old * 6364136223846793005ull + r->inc;
    uint32_t xs = (uint32_t)(((old >> 18) ^ old) >> 27);
    uint32_t rot = (uint32_t)(old >> 59);
    return (xs >> rot) | (xs << ((32 - rot) & 31));
}

static pcg32 pcg32_make(uint64_t seed, uint64_t stream)
{
    pcg32 r = {0, (stream << 1) | 1u};
    pcg32_next(&r);
    r.state += seed;
    pcg32_next(&r);
    return r;
}

static float pcg32_float(pcg32 *r)
{
    return (float)(pcg32_next(r) >> 8) * 0x1p-24f;
}

static pt_vec3 dir_at(float theta_deg, float phi)
{
    float t = theta_deg * (PT_PI / 180.0f);
    return pt_v3(sinf(t) * cosf(phi), sinf(t) * sinf(phi), cosf(t));
}

static pt_vec3 uniform_sphere(pcg32 *r)
{
    float z = 1.0f - 2.0f * pcg32_float(r), phi = 2.0f * PT_PI * pcg32_float(r);
    float s = sqrtf(fmaxf(0.0f, 1.0f - z * z));
    return pt_v3(s * cosf(phi), s * sinf(phi), z);
}

static float rel_err(float a, float b)
{
    float m = fmaxf(fabsf(a), fabsf(b));
    return m > 0.0f ? fabsf(a - b) / m : 0.0f;
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

/* ---- the binning and the pdf integration ---------------------------------- */

/*
 * The sphere is binned around a peak direction r (the normal, or the mirror
 * direction of wo): polar coordinate t = ((1 - cos theta') / 2)^(1/p), azimuth
 * phi', uniform cells in both. With p > 1 the cells shrink towards r, so even a
 * very narrow GGX lobe spans many of them; dw = d(cos theta') d(phi') =
 * 2 p t^(p-1) dt dphi'. Expected counts are the pdf integrated over each cell
 * by nested adaptive Simpson quadrature.
 */
#define NT 10
#define NP 20
#define NCELL (NT * NP)
#define N_CHI2_TESTS 19

typedef float (*pdf_fn)(const void *ctx, pt_vec3 wi);

typedef struct binning {
    pt_frame fr;
    double p;
    pdf_fn pdf;
    const void *ctx;
} binning;

static pt_vec3 bin_dir(const binning *bn, double t, double phi)
{
    double x = pow(t, bn->p);
    double c = 1.0 - 2.0 * x, s = 2.0 * sqrt(fmax(0.0, x * (1.0 - x)));
    pt_vec3 l = pt_v3((float)(s * cos(phi)), (float)(s * sin(phi)), (float)c);
    return pt_frame_to_world(&bn->fr, l);
}

static int bin_of(const binning *bn, pt_vec3 w)
{
    pt_vec3 l = pt_frame_to_local(&bn->fr, w);
    /* (1 - cos) / 2 from the lateral components near the pole, where cos
     * itself has lost the digits of a narrow lobe. */
    double lat = (double)l.x * l.x + (double)l.y * l.y, z = fmin(1.0, fmax(-1.0, (double)l.z));
    double x = z > 0.0 ? lat / (2.0 * (1.0 + z)) : 0.5 * (1.0 - z);
    double t = pow(x, 1.0 / bn->p);
    double phi = atan2((double)l.y, (double)l.x);
    if (phi < 0.0)
        phi += 2.0 * PI_D;
    int it = (int)(t * NT), ip = (int)(phi / (2.0 * PI_D) * NP);
    it = it < 0 ? 0 : (it >= NT ? NT - 1 : it);
    ip = ip < 0 ? 0 : (ip >= NP ? NP - 1 : ip);
    return it * NP + ip;
}

typedef struct simpson_ctx {
    const binning *bn;
    double t;      /* fixed t for the inner integral */
    double p0, p1; /* phi range for the inner integral */
} simpson_ctx;

static double integrand(const binning *bn, double t, double phi)
{
    if (t <= 0.0)
        return 0.0;
    double jac = 2.0 * bn->p * pow(t, bn->p - 1.0);
    return bn->pdf(bn->ctx, bin_dir(bn, t, phi)) * jac;
}

typedef double (*fn1)(simpson_ctx *c, double x);

static double simpson_rec(fn1 f, simpson_ctx *c, double a, double b, double fa, double fm,
                          double fb, double whole, double eps, int depth)
{
    double m = 0.5 * (a + b), lm = 0.5 * (a + m), rm = 0.5 * (m + b);
    double flm = f(c, lm), frm = f(c, rm);
    double left = (m - a) / 6.0 * (fa + 4.0 * flm + fm);
    double right = (b - m) / 6.0 * (fm + 4.0 * frm + fb);
    double delta = left + right - whole;
    if (depth <= 0 || fabs(delta) <= 15.0 * eps)
        return left + right + delta / 15.0;
    return simpson_rec(f, c, a, m, fa, flm, fm, left, 0.5 * eps, depth - 1) +
           simpson_rec(f, c, m, b, fm, frm, fb, right, 0.5 * eps, depth - 1);
}

/* Adaptive Simpson over [a, b], started from 4 panels so that a feature in
 * the middle of the interval is not missed by the first estimate. */
static double simpson(fn1 f, simpson_ctx *c, double a, double b, double eps, int depth)
{
    double s = 0.0, h = (b - a) / 4.0;
    for (int i = 0; i < 4; i++) {
        double x0 = a + i * h, x1 = x0 + h, xm = 0.5 * (x0 + x1);
        double f0 = f(c, x0), fm = f(c, xm), f1 = f(c, x1);
        s += simpson_rec(f, c, x0, x1, f0, fm, f1, h / 6.0 * (f0 + 4.0 * fm + f1), 0.25 * eps,
                         depth);
    }
    return s;
}

static double inner_fn(simpson_ctx *c, double phi)
{
    return integrand(c->bn, c->t, phi);
}

static double outer_fn(simpson_ctx *c, double t)
{
    simpson_ctx in = *c;
    in.t = t;
    return simpson(inner_fn, &in, c->p0, c->p1, 1e-7, 8);
}

static void cell_probs(const binning *bn, double prob[NCELL])
{
    for (int it = 0; it < NT; it++)
        for (int ip = 0; ip < NP; ip++) {
            simpson_ctx c = {bn, 0.0, 2.0 * PI_D * ip / NP, 2.0 * PI_D * (ip + 1) / NP};
            prob[it * NP + ip] =
                simpson(outer_fn, &c, (double)it / NT, (double)(it + 1) / NT, 1e-6, 8);
        }
}

typedef struct cell {
    double expected, observed;
} cell;

static int cmp_cell(const void *a, const void *b)
{
    double x = ((const cell *)a)->expected, y = ((const cell *)b)->expected;
    return x < y ? -1 : (x > y ? 1 : 0);
}

/* Pearson's chi-square with cells of expected count < 5 pooled; returns the
 * p-value. */
static double chi2_pvalue(cell *cells, int n, int *dof_out)
{
    qsort(cells, (size_t)n, sizeof *cells, cmp_cell);
    double pe = 0.0, po = 0.0, chi2 = 0.0;
    int k = 0, used = 0;
    /* Pool the smallest cells until the pool holds at least 5 expected. */
    for (; k < n && !(cells[k].expected >= 5.0 && pe >= 5.0); k++) {
        pe += cells[k].expected;
        po += cells[k].observed;
    }
    if (pe > 0.0 || po > 0.0) {
        if (pe <= 0.0)
            return 0.0; /* samples where the pdf says none can be */
        chi2 += (po - pe) * (po - pe) / pe;
        used++;
    }
    for (; k < n; k++) {
        double d = cells[k].observed - cells[k].expected;
        chi2 += d * d / cells[k].expected;
        used++;
    }
    *dof_out = used - 1;
    return used > 1 ? stats_chi2_survival(chi2, used - 1) : 1.0;
}

typedef pt_vec3 (*sample_fn)(const void *ctx, pcg32 *r, float *pdf);

/*
 * Draws n samples, bins them, integrates the pdf over the cells; the
 * impossible samples (pdf 0) form one more cell whose probability is 1 minus
 * the integral of the pdf. Checks the p-value and returns the integral.
 */
static double chi2_run(const char *name, const binning *bn, sample_fn sample, const void *ctx,
                       int n, uint64_t seed)
{
    static double prob[NCELL];
    static cell cells[NCELL + 1];
    memset(cells, 0, sizeof cells);
    pcg32 r = pcg32_make(seed, 54);
    int lost = 0, bad_pdf = 0;
    for (int i = 0; i < n; i++) {
        float pdf;
        pt_vec3 w = sample(ctx, &r, &pdf);
        if (!(pdf > 0.0f)) {
            lost++;
            continue;
        }
        bad_pdf += rel_err(pdf, bn->pdf(bn->ctx, w)) > 1e-4f;
        cells[bin_of(bn, w)].observed += 1.0;
    }
    cell_probs(bn, prob);
    double total = 0.0;
    for (int c = 0; c < NCELL; c++) {
        cells[c].expected = prob[c] * n;
        total += prob[c];
    }
    cells[NCELL].expected = fmax(0.0, 1.0 - total) * n;
    cells[NCELL].observed = lost;
    int dof = 0;
    double pval = chi2_pvalue(cells, NCELL + 1, &dof);
    double sig = 0.01 / N_CHI2_TESTS;
    CHECKF(pval > sig, "%s: chi-square p-value %.3g (dof %d) below %.3g", name, pval, dof, sig);
    CHECKF(bad_pdf == 0, "%s: %d sampled pdfs differ from the pdf function", name, bad_pdf);
    /* The integral of the pdf is the probability of a possible sample; the
     * fraction of possible samples estimates it with binomial error. */
    double q = 1.0 - (double)lost / n;
    double sd = sqrt(fmax(q * (1.0 - q), 1.0 / n) / n);
    CHECKF(total <= 1.0 + 1e-3, "%s: pdf integrates to %.6f > 1", name, total);
    CHECKF(fabs(total - q) < 4.0 * sd + 1e-3,
           "%s: pdf integral %.6f, possible-sample fraction %.6f", name, total, q);
    return total;
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
    return pt_bsdf_pdf(&c->b, c->wo, w);
}

static pt_vec3 bsdf_sample(const void *ctx, pcg32 *r, float *pdf)
{
    const bsdf_ctx *c = ctx;
    float u[3] = {pcg32_float(r), pcg32_float(r), pcg32_float(r)};
    pt_vec3 wi;
    pt_bsdf_sample(&c->b, c->wo, u, &wi, pdf);
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
            pt_vec3 w = pt_bsdf_sample(&b, wo, u, &wi, &pdf);
            nonfinite += !pt_isfinite3(w) || !isfinite(pdf);
            if (!(pdf > 0.0f))
                continue;
            n++;
            float epdf;
            pt_vec3 f = pt_bsdf_eval(&b, wo, wi, &epdf);
            bad_pdf += rel_err(pdf, pt_bsdf_pdf(&b, wo, wi)) > 1e-5f;
            bad_eval_pdf += rel_err(pdf, epdf) > 1e-5f;
            pt_vec3 ratio = pt_v3_scale(f, 1.0f / epdf);
            bad_w += rel_err(w.x, ratio.x) > 1e-3f || rel_err(w.y, ratio.y) > 1e-3f ||
                     rel_err(w.z, ratio.z) > 1e-3f;
        }
    }
    CHECKF(n > 50000, "only %d possible samples", n);
    CHECKF(nonfinite == 0, "%d non-finite samples", nonfinite);
    CHECKF(bad_w == 0, "%d weights differ from eval / pdf", bad_w);
    CHECKF(bad_pdf == 0, "%d sampled pdfs differ from pt_bsdf_pdf", bad_pdf);
    CHECKF(bad_eval_pdf == 0, "%d eval pdfs differ from pt_bsdf_pdf", bad_eval_pdf);
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

/* MC integral of pt_bsdf_pdf over the sphere with uniform directions, against
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
                double v = pt_bsdf_pdf(&b, wo, uniform_sphere(&r)) * 4.0 * PI_D;
                s += v, s2 += v * v;
            }
            double mean = s / n, sd = sqrt(fmax(0.0, s2 / n - mean * mean) / n);
            int possible = 0;
            for (int k = 0; k < n; k++) {
                float u[3] = {pcg32_float(&r), pcg32_float(&r), pcg32_float(&r)};
                pt_vec3 wi;
                float pdf;
                pt_bsdf_sample(&b, wo, u, &wi, &pdf);
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
        double v = pt_bsdf_sample(b, wo, u, &wi, &pdf).x;
        s += v, s2 += v * v;
    }
    double mean = s / n;
    return (estimate){mean, sqrt(fmax(0.0, s2 / n - mean * mean) / n)};
}

/* The same integral with cosine-distributed directions and pt_bsdf_eval: an
 * estimator independent of the sampling code. */
static estimate albedo_cosine(const pt_bsdf *b, pt_vec3 wo, int n, pcg32 *r)
{
    double s = 0.0, s2 = 0.0;
    for (int k = 0; k < n; k++) {
        pt_vec3 wi = pt_sample_cosine_hemisphere(pcg32_float(r), pcg32_float(r));
        float pdf;
        double v = wi.z > 0.0f ? pt_bsdf_eval(b, wo, wi, &pdf).x / (wi.z * PT_INV_PI) : 0.0;
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
        pt_vec3 f = pt_bsdf_eval(&b, wo, wi, &pdf);
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
            pt_vec3 a = pt_v3_scale(pt_bsdf_eval(&b, wo, wi, &p1), 1.0f / wi.z);
            pt_vec3 c = pt_v3_scale(pt_bsdf_eval(&b, wi, wo, &p2), 1.0f / wo.z);
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
    pt_vec3 f = pt_bsdf_eval(&b, pt_v3(0, 0, 1), pt_v3(0.6f, 0, -0.8f), &pdf);
    CHECK(pdf == 0.0f && f.x == 0.0f && f.y == 0.0f && f.z == 0.0f);
    f = pt_bsdf_eval(&b, pt_v3(0.6f, 0, -0.8f), pt_v3(0, 0, 1), &pdf);
    CHECK(pdf == 0.0f && f.x == 0.0f);
    CHECK(pt_bsdf_pdf(&b, pt_v3(0, 0, -1), pt_v3(0, 0, 1)) == 0.0f);
    pt_vec3 wi;
    float u[3] = {0.5f, 0.5f, 0.5f};
    f = pt_bsdf_sample(&b, pt_v3(0, 0, -1), u, &wi, &pdf);
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
                pt_vec3 e = pt_bsdf_eval(&m, wo, wv, &p);
                bad += !pt_isfinite3(e) || !isfinite(p) || p < 0.0f;
                bad += !isfinite(pt_ggx_g1(wo, m.alpha)) || !isfinite(pt_ggx_d(wv, m.alpha));
                for (int i = 0; i < 5; i++)
                    for (int j = 0; j < 5; j++) {
                        float uu[3] = {us[(i + j) % 5], us[i], us[j]};
                        pt_vec3 w = pt_bsdf_sample(&m, wo, uu, &wi, &p);
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
    test_chi2();
    return check_report();
}
