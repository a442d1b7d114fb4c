/*
 * test_closure.c - the material closure (common/render/closure.h): its
 * builder, its composition rule and its sampling contract. The lobes' own
 * statistics (chi-square, furnace, closed forms) are in test_bsdf.c,
 * test_layers.c and test_dielectric.c, which reach them through closures.
 *
 * - The builder: the glTF base gives a specular lobe where pt_bsdf_spec_prob
 *   > 0 and a diffuse one where it is < 1; glass gives its opaque share and
 *   the interface beside it (none of the share when sampling never picks
 *   it); layers give a coat and a sheen over the base, each only when the
 *   material has it. Each group's probabilities add up to 1 (to rounding).
 * - The rule: eval of clearcoat + sheen over the base equals, to float
 *   rounding, the extensions' layering written out from the lobes' own
 *   functions, f = Fc c + (1 - Fc)(f_sheen + S (f_spec + f_diffuse)), and
 *   its pdf the nested mixture pc p_c + ps p_s + pb (q p_spec + (1 - q)
 *   p_diffuse); glass likewise as pick p_t + (1 - pick) p_base.
 * - Sampling: over random materials (base, layers with and without a coat
 *   normal, rough glass) and random wo, a sample with pdf > 0 has pdf equal to
 *   pt_closure_pdf at its direction and weight equal to eval / pdf; a failed
 *   one has pdf 0 and weight 0.
 * - Empty closures: wo below the surface, or below the coat's own normal,
 *   scatter nothing (eval 0, pdf 0, sample pdf 0).
 * - Delta lobes: a smooth interface's sample is flagged delta, with the
 *   discrete probability pick x F or pick x (1 - F), and is not in eval.
 * - Layers over glass (KHR_materials_clearcoat and _sheen over
 *   _transmission): a smooth glass (ior 1.5) under a smooth coat, seen along
 *   the normal, transmits (1 - Fc)(1 - F) / eta^2 and reflects
 *   (1 - Fc) F + Fc A_c with Fc = F = 0.04 (the coat's and the glass's
 *   Fresnel at normal incidence) and A_c in [0.95, 1] the smooth coat lobe's
 *   albedo, each within 5 standard errors of the sampled means; a thin rough
 *   glass under coat and sheen reflects and transmits at most what it gets
 *   (furnace, 5 standard errors, every incidence 0..85 degrees); chi-square
 *   of its sampling against its pdf over the whole sphere.
 */
#include "common/render/closure.h"

#include <math.h>
#include <stdint.h>

#include "tests/check.h"
#include "tests/rng.h"
#include "tests/stats.h"

#define N_CHI2_TESTS 2
#include "tests/common/render/closure_of.h"
#include "tests/common/render/dir_chi2.h"

/* splitmix64: the test's own numbers. */
static uint64_t rng = 0x2545f4914f6cdd1dull;
static float rndf(void)
{
    return rng_f24(&rng);
}

static pt_vec3 random_upper(void)
{
    return dir_at(89.0f * rndf(), 2.0f * PT_PI * rndf());
}

static int close_rel(float a, float b, float tol)
{
    float m = fmaxf(fabsf(a), fabsf(b));
    return m == 0.0f || fabsf(a - b) <= tol * m;
}

static int close3(pt_vec3 a, pt_vec3 b, float tol)
{
    return close_rel(a.x, b.x, tol) && close_rel(a.y, b.y, tol) && close_rel(a.z, b.z, tol);
}

static pt_bsdf gloss_base(void)
{
    return pt_bsdf_setup(pt_v3(0.8f, 0.5f, 0.3f), 0.2f, 0.4f, 1.0f, pt_v3(1, 1, 1));
}

static pt_layers layers(float cc, float sheen)
{
    pt_bsdf b = gloss_base();
    pt_layers l;
    float sc[3] = {sheen, 0.7f * sheen, 0.5f * sheen};
    pt_layers_setup(&l, &b, cc, 0.3f, sc, 0.5f);
    return l;
}

static float group_sum(const pt_closure *c, uint32_t g)
{
    const pt_closure_group *gr = &c->group[g];
    float s = gr->below;
    for (uint32_t i = 0; i < gr->n; i++)
        s += c->lobe[gr->first + i].prob;
    return s;
}

static void test_builder(void)
{
    pt_vec3 wo = dir_at(40.0f, 0.3f);
    pt_closure c;

    /* A Lambert base: one diffuse lobe. */
    pt_bsdf lam = pt_bsdf_setup(pt_v3(0.5f, 0.5f, 0.5f), 0.0f, 1.0f, 0.0f, pt_v3(1, 1, 1));
    pt_closure_init(&c, wo);
    pt_closure_add_base(&c, &lam);
    CHECK(c.n_groups == 1 && c.n_lobes == 1 && c.lobe[0].kind == PT_LOBE_DIFFUSE);
    CHECK(c.lobe[0].prob == 1.0f);

    /* A metal: one specular lobe. */
    pt_bsdf metal = pt_bsdf_setup(pt_v3(0.9f, 0.6f, 0.2f), 1.0f, 0.3f, 1.0f, pt_v3(1, 1, 1));
    pt_closure_init(&c, wo);
    pt_closure_add_base(&c, &metal);
    CHECK(c.n_groups == 1 && c.n_lobes == 1 && c.lobe[0].kind == PT_LOBE_SPECULAR);

    /* A dielectric: specular then diffuse, probabilities adding to 1. */
    pt_bsdf gb = gloss_base();
    pt_closure_init(&c, wo);
    pt_closure_add_base(&c, &gb);
    CHECK(c.n_groups == 1 && c.n_lobes == 2);
    CHECK(c.lobe[0].kind == PT_LOBE_SPECULAR && c.lobe[1].kind == PT_LOBE_DIFFUSE);
    CHECK(c.lobe[0].prob == pt_bsdf_spec_prob(&gb, wo.z));
    CHECK(fabsf(group_sum(&c, 0) - 1.0f) < 1e-6f);

    /* Layers: coat and sheen over the base, each only when present. */
    pt_layers both = layers(0.7f, 0.6f), coat = layers(0.7f, 0.0f), sheen = layers(0.0f, 0.6f);
    pt_closure_init(&c, wo);
    pt_closure_add_base(&c, &both.base);
    pt_closure_add_layers(&c, &both);
    CHECK(c.n_groups == 2 && c.n_lobes == 4);
    CHECK(c.lobe[2].kind == PT_LOBE_COAT && c.lobe[3].kind == PT_LOBE_SHEEN);
    CHECK(c.group[1].below > 0.0f);
    CHECK(fabsf(group_sum(&c, 1) - 1.0f) < 1e-6f);
    pt_closure_init(&c, wo);
    pt_closure_add_base(&c, &coat.base);
    pt_closure_add_layers(&c, &coat);
    CHECK(c.n_groups == 2 && c.n_lobes == 3 && c.lobe[2].kind == PT_LOBE_COAT);
    pt_closure_init(&c, wo);
    pt_closure_add_base(&c, &sheen.base);
    pt_closure_add_layers(&c, &sheen);
    CHECK(c.n_groups == 2 && c.n_lobes == 3 && c.lobe[2].kind == PT_LOBE_SHEEN);

    /* Glass: the opaque share (when it can be picked), then the interface. */
    pt_glass g = pt_glass_setup(pt_v3(1, 1, 1), 0.0f, 0.3f, 1.0f, pt_v3(1, 1, 1), 0.6f, 1.5f, 0);
    pt_closure_init(&c, wo);
    pt_closure_add_glass(&c, &g);
    CHECK(c.n_groups == 2 && c.lobe[c.n_lobes - 1].kind == PT_LOBE_DIELECTRIC);
    CHECK(c.lobe[c.n_lobes - 1].prob == g.pick && c.group[1].below == 1.0f - g.pick);
    pt_glass clear =
        pt_glass_setup(pt_v3(1, 1, 1), 0.0f, 0.3f, 0.0f, pt_v3(1, 1, 1), 1.0f, 1.5f, 0);
    pt_closure_init(&c, wo);
    pt_closure_add_glass(&c, &clear);
    CHECK(clear.pick == 1.0f && c.n_groups == 1 && c.n_lobes == 1);
    CHECK(c.lobe[0].kind == PT_LOBE_DIELECTRIC);
}

/* The layered closure against the layering written out from its lobes. */
static void test_rule(void)
{
    int bad_f = 0, bad_p = 0, n = 0;
    for (int k = 0; k < 2000; k++) {
        pt_layers l = layers(rndf(), rndf());
        pt_vec3 wo = random_upper(), wi = random_upper();
        pt_closure c;
        pt_closure_init(&c, wo);
        pt_closure_add_base(&c, &l.base);
        pt_closure_add_layers(&c, &l);
        float pdf;
        pt_vec3 f = pt_closure_eval(&c, wi, &pdf);

        /* By hand: the base's lobes, then sheen, then coat. */
        pt_coat_lobe cl;
        pt_sheen_lobe sl;
        float pc, ps, pb, sc, ss, sb, ssp = 0.0f, sd = 0.0f, bc, bs;
        CHECK(pt_layers_lobes(&l, wo, &cl, &sl, &pc, &ps, &pb));
        float q = pt_bsdf_spec_prob(&l.base, wo.z);
        pt_diffuse_lobe dl = pt_bsdf_diffuse(&l.base);
        pt_specular_lobe spl = pt_bsdf_specular(&l.base);
        pt_vec3 fb = pt_v3(0, 0, 0);
        if (q > 0.0f)
            fb = pt_v3_add(fb, pt_specular_eval(&spl, wo, wi, q, &ssp));
        if (q < 1.0f)
            fb = pt_v3_add(fb, pt_diffuse_eval(&dl, wo, wi, 1.0f - q, &sd));
        pt_vec3 fc = pt_coat_eval(&cl, wo, wi, pc, &sc, &bc);
        pt_vec3 fs = pt_sheen_eval(&sl, wo, wi, ps, &ss, &bs);
        sb = ssp + sd;
        pt_vec3 want = l.sheen_max > 0.0f ? pt_v3_add(fs, pt_v3_scale(fb, bs)) : fb;
        if (l.clearcoat > 0.0f)
            want = pt_v3_add(fc, pt_v3_scale(want, bc));
        float want_p =
            (l.clearcoat > 0.0f ? sc : 0.0f) + (l.sheen_max > 0.0f ? ss : 0.0f) + pb * sb;
        /* Fc and S as the extensions state them. */
        CHECK(close_rel(bc, 1.0f - cl.fc, 1e-6f));
        bad_f += !close3(f, want, 2e-6f);
        bad_p += !close_rel(pdf, want_p, 2e-6f);
        n++;
    }
    CHECKF(bad_f == 0, "%d of %d layered values differ from the written-out layering", bad_f, n);
    CHECKF(bad_p == 0, "%d of %d layered pdfs differ from the nested mixture", bad_p, n);

    /* Glass: pick p_t + (1 - pick) p_base, f_t + f_base. */
    bad_f = bad_p = 0;
    for (int k = 0; k < 2000; k++) {
        pt_glass g = pt_glass_setup(pt_v3(0.9f, 0.8f, 0.7f), 0.0f, 0.2f + 0.7f * rndf(), 1.0f,
                                    pt_v3(1, 1, 1), rndf(), rndf() < 0.5f ? 1.5f : 1.0f / 1.5f,
                                    rndf() < 0.3f);
        pt_vec3 wo = random_upper(), wi = random_upper();
        if (rndf() < 0.5f)
            wi.z = -wi.z;
        pt_closure c;
        pt_closure_init(&c, wo);
        pt_closure_add_glass(&c, &g);
        float pdf;
        pt_vec3 f = pt_closure_eval(&c, wi, &pdf);
        pt_closure base;
        pt_closure_init(&base, wo);
        pt_closure_add_base(&base, &g.base);
        float pb;
        pt_vec3 fb = g.pick < 1.0f ? pt_closure_eval(&base, wi, &pb) : pt_v3(0, 0, 0);
        if (!(g.pick < 1.0f))
            pb = 0.0f;
        pt_dielectric_lobe dl = pt_glass_interface(&g);
        float st = 0.0f;
        pt_vec3 ft = g.pick > 0.0f ? pt_dielectric_eval(&dl, wo, wi, g.pick, &st) : pt_v3(0, 0, 0);
        bad_f += !close3(f, pt_v3_add(ft, fb), 2e-6f);
        bad_p += !close_rel(pdf, st + (1.0f - g.pick) * pb, 2e-6f);
    }
    CHECKF(bad_f == 0, "%d glass values differ from interface + opaque share", bad_f);
    CHECKF(bad_p == 0, "%d glass pdfs differ from the mixture", bad_p);
}

/* A random closure of one of four kinds. */
static pt_closure random_closure(pt_vec3 wo, int kind)
{
    pt_closure c;
    pt_closure_init(&c, wo);
    if (kind == 0) {
        pt_bsdf b =
            pt_bsdf_setup(pt_v3(rndf(), rndf(), rndf()), rndf(), rndf(), rndf(), pt_v3(1, 1, 1));
        pt_closure_add_base(&c, &b);
    } else if (kind <= 2) {
        pt_layers l = layers(rndf(), rndf());
        if (kind == 2)
            pt_layers_coat_normal(&l,
                                  pt_v3_norm(pt_v3_add(wo, dir_at(30.0f * rndf(), 6.0f * rndf()))));
        pt_closure_add_base(&c, &l.base);
        pt_closure_add_layers(&c, &l);
    } else {
        pt_glass g = pt_glass_setup(pt_v3(rndf(), rndf(), rndf()), 0.3f * rndf(),
                                    0.1f + 0.8f * rndf(), 1.0f, pt_v3(1, 1, 1), rndf(),
                                    rndf() < 0.5f ? 1.5f : 1.0f / 1.5f, rndf() < 0.3f);
        pt_closure_add_glass(&c, &g);
        if (kind >= 4) {
            pt_layers l = layers(rndf(), rndf());
            if (kind == 5)
                pt_layers_coat_normal(
                    &l, pt_v3_norm(pt_v3_add(wo, dir_at(30.0f * rndf(), 6.0f * rndf()))));
            pt_closure_add_layers(&c, &l);
        }
    }
    return c;
}

static void test_sampling_contract(void)
{
    int bad_pdf = 0, bad_w = 0, bad_fail = 0, ok = 0;
    for (int k = 0; k < 6000; k++) {
        pt_vec3 wo = random_upper();
        pt_closure c = random_closure(wo, k % 6);
        for (int j = 0; j < 8; j++) {
            float u[3] = {rndf(), rndf(), rndf()}, pdf;
            pt_vec3 wi;
            int delta;
            pt_vec3 w = pt_closure_sample(&c, u, &wi, &pdf, &delta);
            if (!(pdf > 0.0f)) {
                bad_fail += pdf != 0.0f || w.x != 0.0f || w.y != 0.0f || w.z != 0.0f;
                continue;
            }
            CHECK(!delta);
            float p2;
            pt_vec3 f = pt_closure_eval(&c, wi, &p2);
            bad_pdf += p2 != pdf || pt_closure_pdf(&c, wi) != pdf;
            bad_w += !close3(w, pt_v3_scale(f, 1.0f / p2), 1e-6f);
            ok++;
        }
    }
    CHECKF(bad_pdf == 0, "%d of %d samples' pdfs differ from pt_closure_pdf", bad_pdf, ok);
    CHECKF(bad_w == 0, "%d of %d sample weights differ from eval / pdf", bad_w, ok);
    CHECKF(bad_fail == 0, "%d failed samples have a pdf or a weight", bad_fail);
    CHECK(ok > 30000);
}

static void test_empty(void)
{
    pt_bsdf b = gloss_base();
    float u[3] = {0.3f, 0.4f, 0.5f}, pdf = 1.0f;
    pt_vec3 wi;
    pt_closure c;
    pt_closure_init(&c, pt_v3(0.6f, 0.0f, -0.8f));
    pt_closure_add_base(&c, &b);
    CHECK(c.n_groups == 0);
    pt_vec3 f = pt_closure_eval(&c, pt_v3(0, 0, 1), &pdf);
    CHECK(pdf == 0.0f && f.x == 0.0f && f.y == 0.0f && f.z == 0.0f);
    pt_vec3 w = pt_closure_sample(&c, u, &wi, &pdf, NULL);
    CHECK(pdf == 0.0f && w.x == 0.0f);

    /* wo above the base but below the coat's own normal. */
    pt_layers l = layers(1.0f, 0.5f);
    pt_vec3 wo = dir_at(80.0f, 0.0f);
    pt_layers_coat_normal(&l, dir_at(40.0f, PT_PI));
    pt_closure_init(&c, wo);
    pt_closure_add_base(&c, &l.base);
    pt_closure_add_layers(&c, &l);
    CHECK(c.n_groups == 0);
    f = pt_closure_eval(&c, pt_v3(0, 0, 1), &pdf);
    CHECK(pdf == 0.0f && f.x == 0.0f);
    /* A dead closure stays dead. */
    pt_closure_add_base(&c, &b);
    CHECK(c.n_groups == 0);
}

static void test_delta(void)
{
    pt_glass g = pt_glass_setup(pt_v3(1, 1, 1), 0.0f, 0.0f, 1.0f, pt_v3(1, 1, 1), 0.8f, 1.5f, 0);
    CHECK(g.alpha == 0.0f && g.pick > 0.0f && g.pick < 1.0f);
    pt_vec3 wo = dir_at(30.0f, 1.0f);
    pt_closure c;
    pt_closure_init(&c, wo);
    pt_closure_add_glass(&c, &g);
    float F = pt_fresnel_dielectric(wo.z, 1.5f);
    int nd = 0, bad = 0;
    for (int k = 0; k < 1000; k++) {
        float u[3] = {rndf(), rndf(), rndf()}, pdf;
        pt_vec3 wi;
        int delta;
        pt_closure_sample(&c, u, &wi, &pdf, &delta);
        if (!delta)
            continue;
        nd++;
        float want = wi.z > 0.0f ? g.pick * F : g.pick * (1.0f - F);
        bad += !close_rel(pdf, want, 1e-6f);
    }
    CHECKF(bad == 0, "%d delta samples with a wrong discrete probability", bad);
    CHECK(nd > 600 && nd < 1000);
    /* The mirror direction gets only the opaque share's density. */
    pt_closure base;
    pt_closure_init(&base, wo);
    pt_closure_add_base(&base, &g.base);
    pt_vec3 mir = pt_v3(-wo.x, -wo.y, wo.z);
    CHECK(close_rel(pt_closure_pdf(&c, mir), (1.0f - g.pick) * pt_closure_pdf(&base, mir), 1e-6f));
}

/* A GGX lobe at PT_BSDF_MIN_ALPHA taken as a mirror (pt_closure_mirrored,
 * pt_closure_eval_mirror): a metal, a half-metal (diffuse and specular
 * lobes), that smooth metal under a rough coat, and a Lambert base under a
 * smooth coat, at 0, 40 and 75 degrees. The mirror's weight equals the
 * closure's sampled mass within 2 degrees of the mirror direction, its
 * take the frequency with which sampling lands there, each within 5
 * standard errors and the GGX's tail past 2 degrees (alpha^2 / (alpha^2 +
 * tan^2 1 deg) of the half vectors, 0.33 %: 0.5 % of take allowed, 2 % of
 * the weight, whose other lobes' share within 2 degrees is under 1 %).
 * The mirror lobes' share of eval is, without layers, the specular lobe's
 * own eval, and at most eval; eval_mirror's whole is eval. A rough lobe
 * has no mirror. */
static void test_mirror(void)
{
    const int n = 200000;
    const float ang[3] = {0.0f, 40.0f, 75.0f};
    const char *name[4] = {"metal", "half-metal", "metal under a rough coat",
                           "Lambert under a smooth coat"};
    for (int ci = 0; ci < 4; ci++)
        for (int ai = 0; ai < 3; ai++) {
            pt_bsdf b =
                ci == 3 ? pt_bsdf_setup(pt_v3(0.5f, 0.4f, 0.3f), 0.0f, 1.0f, 0.0f, pt_v3(1, 1, 1))
                        : pt_bsdf_setup(pt_v3(0.9f, 0.6f, 0.3f), ci == 1 ? 0.5f : 1.0f, 0.0f, 1.0f,
                                        pt_v3(1, 1, 1));
            pt_vec3 wo = dir_at(ang[ai], 0.7f);
            pt_closure c;
            if (ci >= 2) {
                pt_layers l;
                float sc[3] = {0, 0, 0};
                CHECK(pt_layers_setup(&l, &b, 1.0f, ci == 2 ? 0.8f : 0.0f, sc, 0.5f));
                c = cl_of_layers(&l, wo);
            } else {
                c = cl_of_bsdf(&b, wo);
                CHECK(pt_closure_has_mirror(&c) == (ci == 0 ? 2 : 1));
            }
            CHECK(pt_closure_has_mirror(&c) > 0);
            pt_vec3 wm;
            float take;
            pt_vec3 T = pt_closure_mirrored(&c, &wm, &take);
            CHECK(close3(wm, pt_v3(-wo.x, -wo.y, wo.z), 1e-6f));
            double sw[3] = {0, 0, 0}, sw2[3] = {0, 0, 0}, hits = 0.0;
            for (int k = 0; k < n; k++) {
                float u[3] = {rndf(), rndf(), rndf()}, pdf;
                pt_vec3 wi;
                pt_vec3 w = pt_closure_sample(&c, u, &wi, &pdf, NULL);
                if (!(pdf > 0.0f) || pt_v3_dot(wi, wm) < cosf(2.0f * PT_PI / 180.0f))
                    continue;
                hits += 1.0;
                const float wc[3] = {w.x, w.y, w.z};
                for (int j = 0; j < 3; j++) {
                    sw[j] += wc[j];
                    sw2[j] += (double)wc[j] * wc[j];
                }
            }
            const float tc[3] = {T.x, T.y, T.z};
            for (int j = 0; j < 3; j++) {
                double m = sw[j] / n, se = sqrt(fmax(sw2[j] / n - m * m, 0.0) / n);
                CHECKF(fabs(m - tc[j]) <= 5.0 * se + 0.02 * tc[j],
                       "%s at %.0f deg: the mirror's weight %g, sampled %g +- %g", name[ci],
                       ang[ai], tc[j], m, se);
            }
            double f = hits / n, fse = sqrt(f * (1.0 - f) / n);
            CHECKF(fabs(f - take) <= 5.0 * fse + 0.005 * take, "%s: take %g, sampled %g +- %g",
                   name[ci], take, f, fse);
            for (int k = 0; k < 64; k++) {
                pt_vec3 wi = k ? random_upper() : wm, fa;
                float pdf, sh;
                pt_vec3 fm = pt_closure_eval_mirror(&c, wi, &fa);
                pt_vec3 fe = pt_closure_eval(&c, wi, &pdf);
                CHECK(close3(fa, fe, 1e-6f) && fm.x <= fa.x * 1.000001f &&
                      fm.y <= fa.y * 1.000001f && fm.z <= fa.z * 1.000001f);
                if (ci < 2) {
                    pt_specular_lobe sl = pt_bsdf_specular(&b);
                    CHECK(close3(fm, pt_specular_eval(&sl, wo, wi, 1.0f, &sh), 1e-5f));
                }
            }
        }
    pt_bsdf rough = pt_bsdf_setup(pt_v3(0.9f, 0.6f, 0.3f), 1.0f, 0.2f, 1.0f, pt_v3(1, 1, 1));
    pt_closure cr = cl_of_bsdf(&rough, dir_at(30.0f, 0.0f));
    pt_vec3 wm;
    float take;
    pt_vec3 tr = pt_closure_mirrored(&cr, &wm, &take);
    CHECK(!pt_closure_has_mirror(&cr) && tr.x == 0.0f && take == 0.0f);
}

/* Clearcoat (and sheen) over glass. */
static pt_closure coated_glass(pt_vec3 wo, float rough, int thin, float cc, float ccr, float sheen)
{
    pt_glass g =
        pt_glass_setup(pt_v3(1, 1, 1), 0.0f, rough, 1.0f, pt_v3(1, 1, 1), 1.0f, 1.5f, thin);
    pt_bsdf b = g.base;
    pt_layers l;
    float sc[3] = {sheen, sheen, sheen};
    pt_layers_setup(&l, &b, cc, ccr, sc, 0.5f);
    pt_closure c;
    pt_closure_init(&c, wo);
    pt_closure_add_glass(&c, &g);
    pt_closure_add_layers(&c, &l);
    return c;
}

static void test_coated_glass_normal(void)
{
    pt_vec3 wo = pt_v3(0, 0, 1);
    pt_closure c = coated_glass(wo, 0.0f, 0, 1.0f, 0.0f, 0.0f);
    CHECK(c.n_groups == 2 && c.n_lobes == 2);
    const double fc = 0.04, F = 0.04, eta2 = 1.5 * 1.5;
    const int n = 400000;
    double st = 0, st2 = 0, sr = 0, sr2 = 0;
    int bad = 0;
    pcg32 r = pcg32_make(91, 3);
    for (int k = 0; k < n; k++) {
        float u[3] = {pcg32_float(&r), pcg32_float(&r), pcg32_float(&r)}, pdf;
        pt_vec3 wi;
        int delta;
        pt_vec3 w = pt_closure_sample(&c, u, &wi, &pdf, &delta);
        if (!pt_isfinite3(w) || w.x < 0.0f || w.y != w.x || w.z != w.x)
            bad++;
        if (!(pdf > 0.0f))
            continue;
        double x = w.x;
        if (wi.z < 0.0f) {
            bad += !delta;
            st += x;
            st2 += x * x;
        } else {
            sr += x;
            sr2 += x * x;
        }
    }
    CHECKF(bad == 0, "%d bad samples of the coated glass", bad);
    double mt = st / n, set = sqrt(fmax(st2 / n - mt * mt, 0.0) / n);
    double mr = sr / n, ser = sqrt(fmax(sr2 / n - mr * mr, 0.0) / n);
    double want_t = (1.0 - fc) * (1.0 - F) / eta2;
    CHECKF(fabs(mt - want_t) <= 5.0 * set + 1e-6,
           "coated glass transmits %.6f, want %.6f (se %.2g)", mt, want_t, set);
    double lo = (1.0 - fc) * F + fc * 0.95, hi = (1.0 - fc) * F + fc;
    CHECKF(mr >= lo - 5.0 * ser && mr <= hi + 5.0 * ser,
           "coated glass reflects %.6f, want [%.6f, %.6f] (se %.2g)", mr, lo, hi, ser);
}

static void test_coated_glass_furnace(void)
{
    int bad = 0;
    for (int deg = 0; deg <= 85; deg += 17) {
        pt_vec3 wo = dir_at((float)deg, 0.7f);
        pt_closure c = coated_glass(wo, 0.4f, 1, 0.8f, 0.3f, 0.7f);
        const int n = 100000;
        double s = 0, s2 = 0;
        pcg32 r = pcg32_make(200 + (uint64_t)deg, 5);
        for (int k = 0; k < n; k++) {
            float u[3] = {pcg32_float(&r), pcg32_float(&r), pcg32_float(&r)}, pdf;
            pt_vec3 wi;
            pt_vec3 w = pt_closure_sample(&c, u, &wi, &pdf, NULL);
            if (!pt_isfinite3(w) || w.x < 0.0f)
                bad++;
            double x = w.x;
            s += x;
            s2 += x * x;
        }
        double m = s / n, se = sqrt(fmax(s2 / n - m * m, 0.0) / n);
        CHECKF(m <= 1.0 + 5.0 * se, "coated thin glass at %d deg: albedo %.5f (se %.2g)", deg, m,
               se);
        CHECKF(m > 0.5, "coated thin glass at %d deg: albedo %.5f", deg, m);
    }
    CHECKF(bad == 0, "%d bad weights from coated thin glass", bad);
}

static void test_coated_glass_chi2(void)
{
    static pt_closure a, b;
    pt_vec3 wo = dir_at(40.0f, 1.1f);
    a = coated_glass(wo, 0.5f, 0, 0.6f, 0.3f, 0.5f);
    binning ba = {pt_frame_from_normal(pt_v3(0, 0, 1)), 1.0, closure_pdf_fn, &a};
    chi2_run("clearcoat + sheen over rough glass, 40 deg", &ba, closure_sample_fn, &a, 300000, 31);
    wo = dir_at(65.0f, 2.0f);
    b = coated_glass(wo, 0.3f, 1, 1.0f, 0.4f, 0.0f);
    binning bb = {pt_frame_from_normal(pt_v3(-wo.x, -wo.y, wo.z)), 1.5, closure_pdf_fn, &b};
    chi2_run("clearcoat over thin rough glass, 65 deg", &bb, closure_sample_fn, &b, 300000, 32);
}

int main(void)
{
    test_builder();
    test_rule();
    test_sampling_contract();
    test_empty();
    test_delta();
    test_mirror();
    test_coated_glass_normal();
    test_coated_glass_furnace();
    test_coated_glass_chi2();
    return check_report();
}
