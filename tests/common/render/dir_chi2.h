/*
 * dir_chi2.h - chi-square goodness of fit of a direction sampler against its
 * pdf, shared by the BSDF tests (test_bsdf.c, test_layers.c): a local PCG32
 * (O'Neill 2014) for i.i.d. numbers, which a chi-square test needs
 * (stratified ones would make it pass too easily), a binning of the sphere
 * around a peak direction, the pdf integrated over each cell by adaptive
 * Simpson quadrature, and the test itself (chi2_run).
 *
 * The including file defines N_CHI2_TESTS, the number of chi-square tests it
 * runs, before including this: the significance 0.01 is split over them.
 * Static functions, one copy per test program.
 */
#ifndef PT_TESTS_COMMON_RENDER_DIR_CHI2_H
#define PT_TESTS_COMMON_RENDER_DIR_CHI2_H

#ifndef N_CHI2_TESTS
#error "define N_CHI2_TESTS before including dir_chi2.h"
#endif

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "common/math/vec.h"
#include "common/render/closure.h"
#include "tests/check.h"
#include "tests/stats.h"

#ifndef PI_D
#define PI_D 3.14159265358979323846
#endif

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

static inline pt_vec3 dir_at(float theta_deg, float phi)
{
    float t = theta_deg * (PT_PI / 180.0f);
    return pt_v3(sinf(t) * cosf(phi), sinf(t) * sinf(phi), cosf(t));
}

static float rel_err(float a, float b)
{
    float m = fmaxf(fabsf(a), fabsf(b));
    return m > 0.0f ? fabsf(a - b) / m : 0.0f;
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
/* The quadrature's tolerances (inner over phi, outer over t) and depth; a
 * pdf with edges (an indicator, as a portal's) takes finer ones. */
#ifndef CHI2_SIMPSON_DEPTH
#define CHI2_SIMPSON_EPS_INNER 1e-7
#define CHI2_SIMPSON_EPS_OUTER 1e-6
#define CHI2_SIMPSON_DEPTH 8
#endif

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
    return simpson(inner_fn, &in, c->p0, c->p1, CHI2_SIMPSON_EPS_INNER, CHI2_SIMPSON_DEPTH);
}

static void cell_probs(const binning *bn, double prob[NCELL])
{
    for (int it = 0; it < NT; it++)
        for (int ip = 0; ip < NP; ip++) {
            simpson_ctx c = {bn, 0.0, 2.0 * PI_D * ip / NP, 2.0 * PI_D * (ip + 1) / NP};
            prob[it * NP + ip] = simpson(outer_fn, &c, (double)it / NT, (double)(it + 1) / NT,
                                         CHI2_SIMPSON_EPS_OUTER, CHI2_SIMPSON_DEPTH);
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

/* A material closure (common/render/closure.h) as a binning's and
 * chi2_run's ctx: its pdf, and a direction from three i.i.d. numbers. */
static inline float closure_pdf_fn(const void *ctx, pt_vec3 w)
{
    return pt_closure_pdf(ctx, w);
}

static inline pt_vec3 closure_sample_fn(const void *ctx, pcg32 *r, float *pdf)
{
    float u[3] = {pcg32_float(r), pcg32_float(r), pcg32_float(r)};
    pt_vec3 wi;
    int delta = 0;
    pt_closure_sample(ctx, u, &wi, pdf, &delta);
    return wi;
}

/* The sampling contract of a closure without a delta lobe: of n samples
 * drawn from rng, the ones with a pdf (counted in *taken) return f / pdf
 * equal to what pt_closure_eval gives at their direction, channel by channel
 * (relative 1e-4). Returns the channels that differ. */
static inline int closure_weights_differ(const pt_closure *c, pcg32 *rng, int n, int *taken)
{
    int bad = 0;
    *taken = 0;
    for (int i = 0; i < n; i++) {
        const float u[3] = {pcg32_float(rng), pcg32_float(rng), pcg32_float(rng)};
        pt_vec3 wi;
        float pdf, ep;
        pt_vec3 w = pt_closure_sample(c, u, &wi, &pdf, NULL);
        if (!(pdf > 0.0f))
            continue;
        (*taken)++;
        pt_vec3 f = pt_closure_eval(c, wi, &ep);
        const float fa[3] = {f.x, f.y, f.z}, wa[3] = {w.x, w.y, w.z};
        for (int k = 0; k < 3; k++)
            bad += !(fabsf(fa[k] / ep - wa[k]) <= 1e-4f * fmaxf(1.0f, wa[k]));
    }
    return bad;
}

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

#endif
