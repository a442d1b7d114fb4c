/*
 * test_layers.c - clearcoat and sheen layered over the base BSDF
 * (common/render/layers.h): energy, closed forms, sampling, the assets.
 *
 * - White furnace: under a uniform environment of radiance 1 the light a
 *   surface reflects towards wo is the mean of the sampled weight f cos / pdf
 *   (one bounce). Clearcoat 1 over a white base, sheen over a white base and
 *   both, at incidences 0..89 degrees: the mean is at most 1 within 5
 *   standard errors of the estimate (sigma from the samples), and no weight
 *   is negative, NaN or Inf.
 * - Clearcoat over a black base seen along the normal, a smooth coat: the
 *   coat alone reflects clearcoat x F0 = clearcoat x 0.04 (the extension's
 *   Fresnel at cos 1, the smooth GGX lobe's albedo 1).
 * - Clearcoat 0 and sheen colour 0: pt_layers_setup declines (the renderer
 *   keeps the base BSDF, the same bits), and a scene with them has no layer
 *   feature bit.
 * - Chi-square of pt_layers_sample against pt_layers_pdf for four settings
 *   (binning and quadrature as in test_bsdf.c), each sampled pdf equal to
 *   the pdf function's; the fourth has a coat normal tilted 35 degrees from
 *   the base's (pt_layers_coat_normal), so part of the coat's lobe lies
 *   below the base's hemisphere.
 * - ToyCar, SheenChair and ClearCoatTest (../shared/scenes) load without a
 *   warning about either extension, ToyCar's clearcoat texture and sheen
 *   factors are read, ClearCoatTest's clearcoat normal textures are read
 *   (with tangents), and each renders under an environment map with no
 *   NaN/Inf (skipped without ../shared; a failure under CI=true).
 */
#include "common/render/layers.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/env.h"
#include "common/render/render.h"
#include "common/render/sampler.h"
#include "common/scene/scene.h"
#include "tests/check.h"
#include "tests/stats.h"

#define PI_D 3.14159265358979323846

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
#define N_CHI2_TESTS 4

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

/* ---- the layered BSDF ------------------------------------------------------ */

static pt_bsdf white_base(int specular)
{
    return pt_bsdf_setup(pt_v3(1, 1, 1), 0.0f, 0.5f, specular ? 1.0f : 0.0f, pt_v3(1, 1, 1));
}

static pt_layers make(pt_bsdf base, float cc, float ccr, float sheen, float sr)
{
    pt_layers l;
    float sc[3] = {sheen, sheen, sheen};
    CHECK(pt_layers_setup(&l, &base, cc, ccr, sc, sr));
    return l;
}

/* Mean and standard error of the sampled weight's channel 0 at wo. */
static void furnace(const pt_layers *l, pt_vec3 wo, int n, uint64_t seed, double *mean, double *se,
                    int *bad)
{
    pcg32 r = pcg32_make(seed, 7);
    double s = 0.0, s2 = 0.0;
    *bad = 0;
    for (int i = 0; i < n; i++) {
        float u[3] = {pcg32_float(&r), pcg32_float(&r), pcg32_float(&r)};
        pt_vec3 wi;
        float pdf;
        pt_vec3 w = pt_layers_sample(l, wo, u, &wi, &pdf);
        if (!pt_isfinite3(w) || w.x < 0.0f || w.y < 0.0f || w.z < 0.0f || !(pdf >= 0.0f))
            (*bad)++;
        double x = w.x;
        s += x;
        s2 += x * x;
    }
    *mean = s / n;
    *se = sqrt(fmax(s2 / n - *mean * *mean, 0.0) / (n - 1));
}

static void test_furnace(void)
{
    static const float inc[] = {0.0f, 30.0f, 60.0f, 80.0f, 89.0f};
    struct {
        const char *name;
        float cc, ccr, sheen, sr;
        int spec;
    } cfg[] = {
        {"clearcoat smooth / Lambert", 1.0f, 0.0f, 0.0f, 0.0f, 0},
        {"clearcoat 0.3 / Lambert", 1.0f, 0.3f, 0.0f, 0.0f, 0},
        {"clearcoat 1.0 / Lambert+spec", 1.0f, 1.0f, 0.0f, 0.0f, 1},
        {"sheen 0.1 / Lambert", 0.0f, 0.0f, 1.0f, 0.1f, 0},
        {"sheen 0.5 / Lambert", 0.0f, 0.0f, 1.0f, 0.5f, 0},
        {"sheen 1.0 / Lambert+spec", 0.0f, 0.0f, 1.0f, 1.0f, 1},
        {"clearcoat + sheen", 1.0f, 0.2f, 1.0f, 0.4f, 1},
    };
    for (size_t c = 0; c < sizeof cfg / sizeof cfg[0]; c++) {
        pt_layers l = make(white_base(cfg[c].spec), cfg[c].cc, cfg[c].ccr, cfg[c].sheen, cfg[c].sr);
        for (size_t k = 0; k < sizeof inc / sizeof inc[0]; k++) {
            double mean, se;
            int bad;
            furnace(&l, dir_at(inc[k], 0.3f), 200000, 11 + k, &mean, &se, &bad);
            CHECKF(bad == 0, "%s at %g deg: %d negative/NaN/Inf weights", cfg[c].name,
                   (double)inc[k], bad);
            CHECKF(mean <= 1.0 + 5.0 * se + 1e-5, "%s at %g deg: albedo %.5f +- %.5f above 1",
                   cfg[c].name, (double)inc[k], mean, se);
            /* A layer must not swallow the base: a white Lambert base under
             * a clear coat or white sheen still reflects most of the light. */
            CHECKF(inc[k] > 70.0f || mean > 0.8, "%s at %g deg: albedo %.5f", cfg[c].name,
                   (double)inc[k], mean);
            if (getenv("PT_TEST_VERBOSE"))
                printf("%-30s %4.0f deg: %.5f +- %.5f\n", cfg[c].name, (double)inc[k], mean, se);
        }
    }
}

static void test_coat_f0(void)
{
    pt_bsdf black = pt_bsdf_setup(pt_v3(0, 0, 0), 0.0f, 0.5f, 0.0f, pt_v3(1, 1, 1));
    static const float ccs[] = {1.0f, 0.5f};
    for (int k = 0; k < 2; k++) {
        pt_layers l = make(black, ccs[k], 0.0f, 0.0f, 0.0f);
        double mean, se;
        int bad;
        furnace(&l, pt_v3(0, 0, 1), 200000, 3, &mean, &se, &bad);
        double want = 0.04 * ccs[k];
        CHECKF(bad == 0 && fabs(mean - want) < 5.0 * se + 2e-4,
               "clearcoat %g over black at normal incidence: %.6f +- %.6f, want %.6f",
               (double)ccs[k], mean, se, want);
    }
}

static void test_off_is_base(void)
{
    pt_bsdf b = white_base(1);
    pt_layers l;
    float zero[3] = {0, 0, 0}, grey[3] = {0.5f, 0.5f, 0.5f};
    CHECK(!pt_layers_setup(&l, &b, 0.0f, 0.3f, zero, 0.5f));
    CHECK(pt_layers_setup(&l, &b, 0.0f, 0.3f, grey, 0.5f));
    CHECK(pt_layers_setup(&l, &b, 0.5f, 0.3f, zero, 0.5f));

    /* The scene: a clearcoat or sheen of 0 sets no feature bit. */
    for (int with = 0; with < 2; with++) {
        pt_scene_builder *sb = NULL;
        pt_error err = {0};
        CHECK(pt_scene_builder_new(&sb, &err) == PT_OK);
        pt_material m = pt_material_default();
        m.clearcoat_roughness = 0.4f;
        m.sheen_roughness = 0.4f;
        if (with) {
            m.clearcoat = 0.25f;
            m.sheen_color[1] = 0.5f;
        }
        uint32_t mi = 0;
        CHECK(pt_scene_builder_add_material(sb, &m, &mi, &err) == PT_OK);
        float pos[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
        uint32_t idx[3] = {0, 1, 2};
        CHECK(pt_scene_builder_add_mesh(sb, "tri", pos, NULL, NULL, 3, idx, 1, NULL, mi, &err) ==
              PT_OK);
        pt_scene *s = NULL;
        CHECK(pt_scene_builder_finish(sb, NULL, &s, &err) == PT_OK);
        if (!s)
            continue;
        uint32_t want = with ? (uint32_t)(PT_FEAT_CLEARCOAT | PT_FEAT_SHEEN) : 0u;
        CHECKF((s->features & (PT_FEAT_CLEARCOAT | PT_FEAT_SHEEN)) == want, "features %#x",
               s->features);
        pt_scene_free(s);
    }
}

typedef struct lay_ctx {
    pt_layers l;
    pt_vec3 wo;
} lay_ctx;

static float lay_pdf(const void *ctx, pt_vec3 w)
{
    const lay_ctx *c = ctx;
    return pt_layers_pdf(&c->l, c->wo, w);
}

static pt_vec3 lay_sample(const void *ctx, pcg32 *r, float *pdf)
{
    const lay_ctx *c = ctx;
    float u[3] = {pcg32_float(r), pcg32_float(r), pcg32_float(r)};
    pt_vec3 wi;
    pt_layers_sample(&c->l, c->wo, u, &wi, pdf);
    return wi;
}

static void test_chi2(void)
{
    lay_ctx c1;
    c1.l = make(white_base(1), 1.0f, 0.3f, 0.0f, 0.0f);
    c1.wo = dir_at(45.0f, 0.2f);
    lay_ctx c2;
    c2.l = make(white_base(1), 0.0f, 0.0f, 1.0f, 0.5f);
    c2.wo = dir_at(60.0f, 1.0f);
    c2.l.sheen = pt_v3(1.0f, 0.5f, 0.2f);
    lay_ctx c3;
    c3.l = make(white_base(1), 0.7f, 0.5f, 0.6f, 0.8f);
    c3.wo = dir_at(20.0f, 2.0f);
    binning b1 = {pt_frame_from_normal(pt_v3(-c1.wo.x, -c1.wo.y, c1.wo.z)), 2.0, lay_pdf, &c1};
    binning b2 = {pt_frame_from_normal(pt_v3(0, 0, 1)), 1.0, lay_pdf, &c2};
    binning b3 = {pt_frame_from_normal(pt_v3(-c3.wo.x, -c3.wo.y, c3.wo.z)), 1.5, lay_pdf, &c3};
    chi2_run("clearcoat 0.3 over glossy, 45 deg", &b1, lay_sample, &c1, 300000, 21);
    chi2_run("sheen 0.5 over glossy, 60 deg", &b2, lay_sample, &c2, 300000, 22);
    chi2_run("clearcoat + sheen, 20 deg", &b3, lay_sample, &c3, 300000, 23);
    lay_ctx c4;
    c4.l = make(white_base(1), 1.0f, 0.4f, 0.5f, 0.6f);
    pt_vec3 nc = dir_at(35.0f, 0.4f);
    pt_layers_coat_normal(&c4.l, nc);
    c4.wo = dir_at(50.0f, 3.3f);
    pt_vec3 r4 = pt_v3_sub(pt_v3_scale(nc, 2.0f * pt_v3_dot(nc, c4.wo)), c4.wo);
    binning b4 = {pt_frame_from_normal(pt_v3_norm(r4)), 1.5, lay_pdf, &c4};
    chi2_run("clearcoat on its own normal + sheen, 50 deg", &b4, lay_sample, &c4, 300000, 24);
}

/* ---- the shared assets ------------------------------------------------------ */

static int g_layer_warnings;

static void count_layer_warnings(void *user, const char *message)
{
    (void)user;
    /* Any word of either extension (the clearcoat normal texture included). */
    if (strstr(message, "KHR_materials_clearcoat") || strstr(message, "KHR_materials_sheen") ||
        strstr(message, "clearcoatNormal"))
        g_layer_warnings++;
    if (getenv("PT_TEST_VERBOSE"))
        printf("  warning: %s\n", message);
}

static void asset(const char *rel, uint32_t want)
{
    char p[1024];
    snprintf(p, sizeof p, "%s/%s", PT_SHARED_SCENES, rel);
    pt_scene_opts o = {0};
    o.warn = count_layer_warnings;
    g_layer_warnings = 0;
    pt_scene *s = NULL;
    pt_error err = {0};
    CHECKF(pt_scene_load(p, &o, &s, &err) == PT_OK, "%s: %s", rel, err.msg);
    if (!s)
        return;
    CHECKF(g_layer_warnings == 0, "%s: %d clearcoat/sheen warnings", rel, g_layer_warnings);
    CHECKF((s->features & want) == want, "%s: features %#x lack %#x", rel, s->features, want);
    if (strstr(rel, "ToyCar")) {
        /* Its body's clearcoat comes from a texture (R), its fabric's red sheen
         * from the factors. */
        int cc_tex = 0, red = 0;
        for (uint32_t i = 0; i < s->num_materials; i++) {
            const pt_material *m = &s->materials[i];
            cc_tex += m->clearcoat == 1.0f && m->clearcoat_tex >= 0;
            red += m->sheen_color[0] == 1.0f && m->sheen_color[1] == 0.0f &&
                   m->sheen_roughness == 0.5f;
        }
        CHECK(cc_tex == 1 && red == 1);
    }
    if (strstr(rel, "ClearCoatTest")) {
        /* Its "coat normal" row maps the coat's normal only. */
        int coat_normal = 0;
        for (uint32_t i = 0; i < s->num_materials; i++)
            coat_normal +=
                s->materials[i].clearcoat > 0.0f && s->materials[i].clearcoat_normal_tex >= 0;
        CHECKF(coat_normal > 0 && (s->features & PT_FEAT_NORMAL_MAP) && s->tangents,
               "%s: %d materials with a coat normal map, features %#x", rel, coat_normal,
               s->features);
    }
    char path[1024];
    snprintf(path, sizeof path, "%s/../envs/studio_small_03_1k.hdr", PT_SHARED_SCENES);
    pt_env *env = NULL;
    CHECKF(pt_env_load(path, 1.0f, 0.0f, &env, &err) == PT_OK, "%s", err.msg);
    pt_render_params rp = {0};
    pt_render_params_default(&rp);
    rp.width = rp.height = 32;
    rp.seed = 9;
    rp.env = env;
    pt_renderer *rd = NULL;
    CHECKF(pt_renderer_new(s, &rp, &rd, &err) == PT_OK, "%s", err.msg);
    pt_pixel_acc *acc = pt_malloc_array(32u * 32u, sizeof *acc);
    if (rd && acc) {
        pt_render_stats st = {0, 0, 0, 0};
        pt_render_tile(rd, (pt_rect){0, 0, 32, 32}, 0, 8, acc, &st);
        int finite = 1;
        double sum = 0.0;
        for (uint32_t i = 0; i < 32u * 32u; i++)
            for (int c = 0; c < 3; c++) {
                finite &= isfinite(acc[i].sum[c]) && acc[i].sum[c] >= 0.0;
                sum += acc[i].sum[c];
            }
        CHECKF(st.rejected == 0 && finite, "%s: %llu NaN/Inf samples, finite %d", rel,
               (unsigned long long)st.rejected, finite);
        CHECKF(sum > 0.0, "%s: black image", rel);
    }
    pt_free(acc);
    pt_renderer_free(rd);
    pt_env_free(env);
    pt_scene_free(s);
}

int main(void)
{
    test_off_is_base();
    test_coat_f0();
    test_furnace();
    test_chi2();
    char probe[1024];
    snprintf(probe, sizeof probe, "%s/../envs/studio_small_03_1k.hdr", PT_SHARED_SCENES);
    FILE *f = fopen(probe, "rb");
    if (!f) {
        CHECK_SKIP("shared scenes and maps not found; the asset renders");
        CHECK(!check_shared_required());
        return check_report();
    }
    fclose(f);
    asset("ToyCar/ToyCar.gltf", PT_FEAT_CLEARCOAT | PT_FEAT_SHEEN);
    asset("SheenChair/SheenChair.gltf", PT_FEAT_SHEEN);
    asset("ClearCoatTest/ClearCoatTest.glb", PT_FEAT_CLEARCOAT);
    return check_report();
}
