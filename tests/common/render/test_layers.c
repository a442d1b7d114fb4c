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
 * - Chi-square of cl_layers_sample against cl_layers_pdf for four settings
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
#include "common/render/sheen_table.h"
#include "common/scene/scene.h"
#include "tests/check.h"
#include "tests/common/render/closure_of.h"
#include "tests/stats.h"

#define PI_D 3.14159265358979323846

#define N_CHI2_TESTS 4
#include "tests/common/render/dir_chi2.h"

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
        pt_vec3 w = cl_layers_sample(l, wo, u, &wi, &pdf);
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
    return cl_layers_pdf(&c->l, c->wo, w);
}

static pt_vec3 lay_sample(const void *ctx, pcg32 *r, float *pdf)
{
    const lay_ctx *c = ctx;
    float u[3] = {pcg32_float(r), pcg32_float(r), pcg32_float(r)};
    pt_vec3 wi;
    cl_layers_sample(&c->l, c->wo, u, &wi, pdf);
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
        pt_render_stats st = {0};
        pt_render_tile(rd, (pt_rect){0, 0, 32, 32}, 0, 8, acc, &st);
        int finite = 1;
        double sum = 0.0;
        for (uint32_t i = 0; i < 32u * 32u; i++)
            for (int c = 0; c < 3; c++) {
                finite &= isfinite(pt_acc_sum(&acc[i], c)) && pt_acc_sum(&acc[i], c) >= 0.0;
                sum += pt_acc_sum(&acc[i], c);
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

/* ---- the sheen albedo table ------------------------------------------------ */

/*
 * The reference for common/render/sheen_table.c: E(mu, r) = integral over
 * the hemisphere of pt_sheen_charlie(alpha(r), wo(mu), wi) d wi, by the
 * midpoint rule in theta (128 steps) and phi (64 steps over [0, pi], doubled:
 * the lobe is symmetric about the plane of wo), in double; r and mu on a
 * 32 x 32 grid over [0, 1] (mu at least 1e-3). `test_layers --sheen-table`
 * prints the table's source from it.
 */
#define Q_THETA 128
#define Q_PHI 64

static void sheen_quadrature(float t[PT_SHEEN_TABLE_N][PT_SHEEN_TABLE_N])
{
    const int n = PT_SHEEN_TABLE_N;
    for (int j = 0; j < n; j++) {
        float r = (float)j / (n - 1);
        float alpha = r * r;
        alpha = alpha > PT_LAYERS_MIN_SHEEN_ALPHA ? alpha : PT_LAYERS_MIN_SHEEN_ALPHA;
        for (int i = 0; i < n; i++) {
            float mu = fmaxf((float)i / (n - 1), 1e-3f);
            pt_vec3 wo = pt_v3(sqrtf(1.0f - mu * mu), 0.0f, mu);
            double sum = 0.0;
            for (int q = 0; q < Q_THETA; q++) {
                double th = (q + 0.5) * (0.5 * PI_D / Q_THETA);
                double st = sin(th), ct = cos(th);
                for (int p = 0; p < Q_PHI; p++) {
                    double ph = (p + 0.5) * (PI_D / Q_PHI);
                    pt_vec3 wi = pt_v3((float)(st * cos(ph)), (float)(st * sin(ph)), (float)ct);
                    sum += (double)pt_sheen_charlie(alpha, wo, wi) * st;
                }
            }
            t[j][i] = (float)(2.0 * sum * (0.5 * PI_D / Q_THETA) * (PI_D / Q_PHI));
        }
    }
}

/* The compiled table against the quadrature: equal where this machine's
 * libm is the one that made it; within 1e-5 (a few float roundings of the
 * sum) elsewhere. And pt_sheen_albedo reads it at the grid's corners. */
static void test_sheen_table(void)
{
    static float t[PT_SHEEN_TABLE_N][PT_SHEEN_TABLE_N];
    sheen_quadrature(t);
    int n = PT_SHEEN_TABLE_N, exact = 0;
    double worst = 0.0;
    for (int j = 0; j < n; j++)
        for (int i = 0; i < n; i++) {
            double a = pt_sheen_table[j][i], b = t[j][i];
            exact += a == b;
            worst = fmax(worst, fabs(a - b) / fmax(fabs(b), 1e-30));
        }
    CHECKF(worst <= 1e-5, "sheen table differs from the quadrature by %.3g (relative)", worst);
    if (exact != n * n)
        fprintf(stderr,
                "note: %d of %d sheen table entries differ from this machine's quadrature "
                "by at most %.3g\n",
                n * n - exact, n * n, worst);
    CHECK(pt_sheen_albedo(0.0f, 0.0f) == pt_sheen_table[0][0]);
    CHECK(fabsf(pt_sheen_albedo(1.0f, 1.0f) - pt_sheen_table[n - 1][n - 1]) <=
          1e-6f * pt_sheen_table[n - 1][n - 1]);
}

/* Prints common/render/sheen_table.c. */
static int print_sheen_table(void)
{
    static float t[PT_SHEEN_TABLE_N][PT_SHEEN_TABLE_N];
    sheen_quadrature(t);
    printf("/*\n"
           " * sheen_table.c - the sheen lobe's directional albedo (sheen_table.h),\n"
           " * generated by `test_layers --sheen-table` from the quadrature in\n"
           " * tests/common/render/test_layers.c, which checks it. Do not edit.\n"
           " */\n"
           "#include \"common/render/sheen_table.h\"\n\n"
           "const float pt_sheen_table[PT_SHEEN_TABLE_N][PT_SHEEN_TABLE_N] = {\n");
    for (int j = 0; j < PT_SHEEN_TABLE_N; j++) {
        printf("    {");
        for (int i = 0; i < PT_SHEEN_TABLE_N; i++)
            printf("%s%af", i ? ", " : "", (double)t[j][i]);
        printf("},\n");
    }
    printf("};\n");
    return 0;
}

int main(int argc, char **argv)
{
    if (argc > 1 && strcmp(argv[1], "--sheen-table") == 0)
        return print_sheen_table();
    test_sheen_table();
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
