/*
 * test_env.c - the environment light: its map reader, its sampler and the
 * integrator under it.
 *
 * - Sampling: chi-square goodness of fit of pt_env_sample's directions,
 *   binned by this test's own (u, v) of each direction (so the orientation
 *   is checked too), against the density the map defines - luminance x
 *   sin(theta) per texel, summed here from the map read independently - on
 *   the three shared maps (one with 66 % of its energy in 52 texels), and at
 *   a rotation. The pdf a sample reports equals pt_env_pdf of its direction,
 *   and the pdf integrates to 1 over the sphere (uniform Monte Carlo, within
 *   5 standard errors).
 * - Closed forms: a Lambert plane of albedo rho under a uniform environment
 *   of radiance L (a convex object sees only the sky) has radiance rho L; a
 *   camera ray that leaves the scene sees L itself.
 * - Estimators: on a plane with an occluder under the park map (the hard
 *   sun), NEE alone, BSDF sampling alone and their MIS combination agree
 *   within their combined standard errors.
 * - Bad maps: missing, truncated, not an image, a value over the cap (what
 *   RGBE can say instead of NaN), NaN and 1e38 in an EXR, 0 x 0, not 2:1:
 *   each a clear error.
 * Tolerances are 5 standard errors of the estimate unless a value is exact.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/image/envmap.h"
#include "common/image/exr.h"
#include "common/image/image.h"
#include "common/render/env.h"
#include "common/render/render.h"
#include "common/scene/scene.h"
#include "tests/check.h"
#include "tests/stats.h"

#define PI_D 3.14159265358979323846

static char tmp[256];

/* A deterministic uniform generator (splitmix64) for the test's own draws. */
static uint64_t rng = 0x9e3779b97f4a7c15ull;
static double rnd(void)
{
    uint64_t z = (rng += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    z ^= z >> 31;
    return (double)(z >> 11) * 0x1.0p-53;
}

/* Pearson's chi-square of observed against expected counts in n bins; bins
 * expected below min_exp are pooled into one. Returns the p-value. */
static double chi2_gof(const double *obs, const double *expd, int n, double min_exp, double *stat,
                       int *dof)
{
    double s = 0.0, po = 0.0, pe = 0.0;
    int bins = 0;
    for (int i = 0; i < n; i++) {
        if (expd[i] < min_exp) {
            po += obs[i];
            pe += expd[i];
            continue;
        }
        s += (obs[i] - expd[i]) * (obs[i] - expd[i]) / expd[i];
        bins++;
    }
    if (pe > 0.0) {
        s += (po - pe) * (po - pe) / pe;
        bins++;
    } else if (po > 0.0) {
        s = INFINITY; /* samples where the density is zero */
    }
    *stat = s;
    *dof = bins - 1;
    return stats_chi2_survival(s, *dof);
}

/* This test's (u, v) of a direction: env.h's formula, written again. */
static void uv_of(pt_vec3 d, double rot_deg, double *u, double *v)
{
    double phi = atan2(d.x, -d.z);
    double uu = 0.5 + phi / (2.0 * PI_D) + rot_deg / 360.0;
    uu -= floor(uu);
    *u = uu;
    *v = acos(fmax(-1.0, fmin(1.0, d.y))) / PI_D;
}

/* Chi-square of n samples of env (built from map, rotated) against the
 * map's own density, in BU x BV bins of (u, v). */
static void chi2_env(const char *what, const pt_envmap *map, double rot_deg)
{
    enum { BU = 64, BV = 32 };
    pt_env *env = NULL;
    pt_error err = {0};
    CHECKF(pt_env_new(map, 1.0f, (float)rot_deg, &env, &err) == PT_OK, "%s", err.msg);
    if (!env)
        return;
    static double expd[BU * BV], obs[BU * BV];
    memset(expd, 0, sizeof expd);
    memset(obs, 0, sizeof obs);
    /* The map's density: luminance x sin(theta at the row's centre). */
    double total = 0.0;
    for (uint32_t y = 0; y < map->height; y++) {
        double s = sin(PI_D * (y + 0.5) / map->height);
        for (uint32_t x = 0; x < map->width; x++) {
            const float *c = &map->rgb[3 * ((size_t)y * map->width + x)];
            double w = (0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]) * s;
            /* Texel (x, y) lies in one bin when the bins divide the map. */
            size_t b = (size_t)(y * BV / map->height) * BU + x * BU / map->width;
            expd[b] += w;
            total += w;
        }
    }
    const int N = 400000;
    int pdf_bad = 0;
    for (int i = 0; i < N; i++) {
        float u[2] = {(float)rnd(), (float)rnd()}, pdf;
        pt_vec3 d, rad;
        if (!pt_env_sample(env, u, &d, &rad, &pdf))
            continue;
        double uu, vv;
        uv_of(d, rot_deg, &uu, &vv);
        int bu = (int)(uu * BU), bv = (int)(vv * BV);
        bu = bu < 0 ? 0 : bu >= BU ? BU - 1 : bu;
        bv = bv < 0 ? 0 : bv >= BV ? BV - 1 : bv;
        obs[bv * BU + bu] += 1.0;
        float p2 = pt_env_pdf(env, d);
        if (!(fabsf(p2 - pdf) <= 1e-3f * pdf))
            pdf_bad++;
    }
    for (int b = 0; b < BU * BV; b++)
        expd[b] = expd[b] / total * N;
    double stat, p;
    int dof;
    p = chi2_gof(obs, expd, BU * BV, 5.0, &stat, &dof);
    CHECKF(p > 1e-3, "%s: chi-square %.1f with %d degrees of freedom, p = %.2e", what, stat, dof,
           p);
    /* A direction on a texel's edge may round into its neighbour: rare. */
    CHECKF(pdf_bad < N / 10000, "%s: %d samples' pdf differs from pt_env_pdf", what, pdf_bad);
    printf("%s: chi-square %.1f, %d dof, p = %.3f\n", what, stat, dof, p);

    /* The pdf integrates to 1: E[4 pi pdf(d)] over uniform d. */
    double sum = 0.0, sum2 = 0.0;
    const int M = 200000;
    for (int i = 0; i < M; i++) {
        double z = 1.0 - 2.0 * rnd(), r = sqrt(fmax(0.0, 1.0 - z * z)), a = 2.0 * PI_D * rnd();
        double f =
            4.0 * PI_D * pt_env_pdf(env, pt_v3((float)(r * cos(a)), (float)z, (float)(r * sin(a))));
        sum += f;
        sum2 += f * f;
    }
    double mean = sum / M, se = sqrt(fmax(sum2 / M - mean * mean, 0.0) / M);
    CHECKF(fabs(mean - 1.0) < 5.0 * se + 1e-3, "%s: the pdf integrates to %.4f (se %.4f)", what,
           mean, se);
    pt_env_free(env);
}

static void sampling(void)
{
    const char *maps[] = {"studio_small_03_1k.hdr", "rooitou_park_1k.hdr",
                          "potsdamer_platz_1k.hdr"};
    char path[512];
    struct stat sb;
    snprintf(path, sizeof path, "%s/../envs", PT_SHARED_SCENES);
    if (stat(path, &sb) != 0) {
        CHECK_SKIP("shared environment maps not found; the chi-square tests");
        CHECK(!check_shared_required());
        return;
    }
    for (size_t i = 0; i < sizeof maps / sizeof *maps; i++) {
        snprintf(path, sizeof path, "%s/../envs/%s", PT_SHARED_SCENES, maps[i]);
        pt_envmap m;
        pt_error err = {0};
        CHECKF(pt_envmap_read(path, &m, &err) == PT_OK, "%s", err.msg);
        if (!m.rgb)
            continue;
        CHECK(m.width == 1024 && m.height == 512);
        chi2_env(maps[i], &m, 0.0);
        if (i == 1)
            chi2_env("rooitou_park rotated 37 deg", &m, 37.0);
        pt_envmap_free(&m);
    }
}

/* ---- the integrator ---------------------------------------------------------------- */

/* A Lambert plane of albedo rho (and a box on it when occluder), a camera
 * above looking down with field of view yfov. */
static pt_scene *plane_scene(float rho, int occluder, float yfov)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    m.base_color[0] = m.base_color[1] = m.base_color[2] = rho;
    m.metallic = 0.0f;
    m.specular = 0.0f;
    m.double_sided = 1;
    uint32_t mat = 0;
    CHECK(pt_scene_builder_add_material(b, &m, &mat, &err) == PT_OK);
    const float P = 50.0f;
    float plane[12] = {-P, 0, -P, P, 0, -P, P, 0, P, -P, 0, P};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "plane", plane, NULL, NULL, 4, idx, 2, NULL, mat, &err) ==
          PT_OK);
    if (occluder) {
        /* A tilted panel over part of the view: shadows and interreflection. */
        float q[12] = {-1, 0.5f, -1, 1, 1.5f, -1, 1, 1.5f, 1, -1, 0.5f, 1};
        CHECK(pt_scene_builder_add_mesh(b, "panel", q, NULL, NULL, 4, idx, 2, NULL, mat, &err) ==
              PT_OK);
    }
    pt_camera cam = {0};
    cam.position = pt_v3(0, 10, 0);
    cam.forward = pt_v3(0, -1, 0);
    cam.right = pt_v3(1, 0, 0);
    cam.up = pt_v3(0, 0, -1);
    cam.yfov = yfov;
    cam.aspect = 1.0f;
    snprintf(cam.name, sizeof cam.name, "down");
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

/* The mean of the image's green channel and its standard error. */
static double render_mean(const pt_scene *s, const pt_env *env, uint32_t strategy, uint32_t w,
                          uint32_t spp, double *se)
{
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = p.height = w;
    p.seed = 11;
    p.env = env;
    p.light_strategy = strategy;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    pt_pixel_acc *acc = pt_malloc_array((size_t)w * w, sizeof *acc);
    double sum = 0.0, var = 0.0;
    if (r && acc) {
        pt_render_stats st = {0};
        pt_rect all = {0, 0, w, w};
        pt_render_tile(r, all, 0, spp, acc, &st);
        CHECK(st.rejected == 0);
        for (uint32_t i = 0; i < w * w; i++) {
            double k = acc[i].n;
            double lum = (0.2126 * pt_acc_sum(&acc[i], 0) + 0.7152 * pt_acc_sum(&acc[i], 1) +
                          0.0722 * pt_acc_sum(&acc[i], 2)) /
                         k;
            sum += pt_acc_sum(&acc[i], 1) / k;
            var += fmax((pt_acc_sum_sq(&acc[i]) - k * lum * lum) / (k - 1.0), 0.0) / k;
        }
    }
    pt_free(acc);
    pt_renderer_free(r);
    *se = sqrt(var) / ((double)w * w);
    return sum / ((double)w * w);
}

static void uniform_sky(void)
{
    const float rho = 0.6f, L = 1.5f;
    pt_env *env = NULL;
    pt_error err = {0};
    CHECK(pt_env_uniform(pt_v3(L, L, L), &env, &err) == PT_OK);
    pt_scene *s = plane_scene(rho, 0, 0.5f);
    double se;
    double m = render_mean(s, env, PT_LIGHT_MIS, 16, 256, &se);
    CHECKF(fabs(m - rho * L) < 5.0 * se + 1e-6 && se < 0.003 * rho * L,
           "plane under a uniform sky: %.5f, expected %.5f (se %.2e)", m, (double)(rho * L), se);
    printf("plane under a uniform sky: %.5f (exact %.5f), standard error %.2e\n", m,
           (double)(rho * L), se);
    pt_scene_free(s);
    /* A camera looking away from the plane sees the sky itself, exactly. */
    pt_scene_builder *b = NULL;
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material mt = pt_material_default();
    uint32_t mat;
    CHECK(pt_scene_builder_add_material(b, &mt, &mat, &err) == PT_OK);
    float tri[9] = {0, -5, 0, 1, -5, 0, 0, -5, 1};
    CHECK(pt_scene_builder_add_mesh(b, "below", tri, NULL, NULL, 3, NULL, 1, NULL, mat, &err) ==
          PT_OK);
    pt_camera cam = {0};
    cam.forward = pt_v3(0, 1, 0);
    cam.right = pt_v3(1, 0, 0);
    cam.up = pt_v3(0, 0, 1);
    cam.yfov = 0.5f;
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    CHECK(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK);
    m = render_mean(s, env, PT_LIGHT_MIS, 4, 16, &se);
    CHECKF(fabs(m - L) < 1e-6, "the sky seen directly: %.7f, expected %.7f", m, (double)L);
    pt_scene_free(s);
    pt_env_free(env);
}

static void strategies_agree(void)
{
    char path[512];
    snprintf(path, sizeof path, "%s/../envs/rooitou_park_1k.hdr", PT_SHARED_SCENES);
    pt_envmap m;
    pt_error err = {0};
    if (pt_envmap_read(path, &m, &err) != PT_OK) {
        CHECK_SKIP("shared environment maps not found; the strategies");
        CHECK(!check_shared_required());
        return;
    }
    pt_env *env = NULL;
    CHECK(pt_env_new(&m, 1.0f, 0.0f, &env, &err) == PT_OK);
    pt_envmap_free(&m);
    pt_scene *s = plane_scene(0.5f, 1, 0.6f);
    double se_m, se_n, se_b;
    double mis = render_mean(s, env, PT_LIGHT_MIS, 16, 512, &se_m);
    double nee = render_mean(s, env, PT_LIGHT_NEE_ONLY, 16, 512, &se_n);
    double bsdf = render_mean(s, env, PT_LIGHT_BSDF_ONLY, 16, 2048, &se_b);
    printf("park: MIS %.5f (se %.1e), NEE %.5f (se %.1e), BSDF %.5f (se %.1e)\n", mis, se_m, nee,
           se_n, bsdf, se_b);
    CHECKF(fabs(mis - nee) < 5.0 * sqrt(se_m * se_m + se_n * se_n), "MIS %.5f vs NEE %.5f", mis,
           nee);
    CHECKF(fabs(mis - bsdf) < 5.0 * sqrt(se_m * se_m + se_b * se_b), "MIS %.5f vs BSDF %.5f", mis,
           bsdf);
    CHECKF(fabs(nee - bsdf) < 5.0 * sqrt(se_n * se_n + se_b * se_b), "NEE %.5f vs BSDF %.5f", nee,
           bsdf);
    /* The check means something only if the errors are small against the value. */
    CHECKF(se_m < 0.01 * mis && se_n < 0.01 * nee, "standard errors too large");
    pt_scene_free(s);
    pt_env_free(env);
}

/* ---- bad maps ------------------------------------------------------------------------ */

static void write_bytes(const char *name, const void *d, size_t n)
{
    char p[512];
    snprintf(p, sizeof p, "%s/%s", tmp, name);
    FILE *f = fopen(p, "wb");
    CHECK(f && fwrite(d, 1, n, f) == n);
    if (f)
        fclose(f);
}

static void expect_bad(const char *name, const char *word)
{
    char p[512];
    snprintf(p, sizeof p, "%s/%s", tmp, name);
    pt_envmap m;
    pt_error err = {0};
    int64_t live = pt_alloc_live();
    pt_status st = pt_envmap_read(p, &m, &err);
    CHECKF(st != PT_OK && m.rgb == NULL, "%s: read", name);
    CHECKF(strstr(err.msg, word) != NULL, "%s: message lacks '%s': %s", name, word, err.msg);
    CHECKF(pt_alloc_live() == live, "%s: leaked", name);
}

/* A flat (not run-length) Radiance file of w x h texels, all (r, g, b, e). */
static size_t rgbe_file(uint8_t *buf, size_t cap, int w, int h, const uint8_t px[4])
{
    int n = snprintf((char *)buf, cap, "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n", h, w);
    size_t at = (size_t)n;
    for (int i = 0; i < w * h && at + 4 <= cap; i++, at += 4)
        memcpy(buf + at, px, 4);
    return at;
}

static void bad_maps(void)
{
    static uint8_t buf[1 << 16];
    const uint8_t grey[4] = {128, 128, 128, 129}, huge[4] = {255, 255, 255, 255};
    expect_bad("missing.hdr", "missing.hdr");
    size_t n = rgbe_file(buf, sizeof buf, 8, 4, grey);
    write_bytes("good.hdr", buf, n);
    pt_envmap m;
    pt_error err = {0};
    char p[512];
    snprintf(p, sizeof p, "%s/good.hdr", tmp);
    CHECKF(pt_envmap_read(p, &m, &err) == PT_OK && m.width == 8 && m.height == 4, "%s", err.msg);
    if (m.rgb)
        CHECK(fabsf(m.rgb[0] - 1.0f) < 1e-6f); /* 128/256 * 2^(129-128) */
    pt_envmap_free(&m);
    write_bytes("cut.hdr", buf, n - 40);
    expect_bad("cut.hdr", "cut.hdr");
    write_bytes("text.hdr", "hello, not an image\n", 20);
    expect_bad("text.hdr", "not an environment map");
    n = rgbe_file(buf, sizeof buf, 8, 4, huge);
    write_bytes("huge.hdr", buf, n);
    expect_bad("huge.hdr", "not a radiance in");
    n = rgbe_file(buf, sizeof buf, 0, 0, grey);
    write_bytes("empty.hdr", buf, n);
    expect_bad("empty.hdr", "empty.hdr");
    n = rgbe_file(buf, sizeof buf, 4, 4, grey);
    write_bytes("square.hdr", buf, n);
    expect_bad("square.hdr", "not an equirectangular map");
    /* EXR: NaN and 1e38 through OpenEXRCore. */
    pt_image *img = NULL;
    CHECK(pt_image_new(8, 4, &img, NULL) == PT_OK);
    const float bad[2] = {NAN, 1e38f};
    const char *names[2] = {"nan.exr", "big.exr"};
    for (int k = 0; k < 2 && img; k++) {
        img->g[5] = bad[k];
        snprintf(p, sizeof p, "%s/%s", tmp, names[k]);
        CHECK(pt_exr_write(p, img, NULL, &err) == PT_OK);
        expect_bad(names[k], "pixel (5, 0)");
    }
    pt_image_free(img);
}

int main(void)
{
    snprintf(tmp, sizeof tmp, "/tmp/pt_test_env_XXXXXX");
    if (!mkdtemp(tmp))
        return 1;
    int64_t live0 = pt_alloc_live();
    bad_maps();
    uniform_sky();
    strategies_agree();
    sampling();
    CHECK(pt_alloc_live() == live0);
    if (pt_remove_tree(tmp) != 0)
        return 1;
    return check_report();
}
