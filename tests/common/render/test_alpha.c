/*
 * test_alpha.c - glTF alphaMode MASK and BLEND (common/scene/alpha.c, the
 * accel's filters, the integrator) against closed-form answers.
 *
 * The camera has a field of view so narrow (1e-4 rad) that each pixel sees
 * one point, and every surface but the Lambert floor is black, so each
 * sample is one of a few known values and the estimators' variances are
 * known in closed form:
 * - camera rays: a black BLEND plane of alpha a that emits Ls, in front of
 *   an emitter (or a uniform environment) of radiance Lb. A sample reads Ls
 *   with probability a, Lb otherwise: mean a Ls + (1 - a) Lb, variance
 *   a (1 - a) (Ls - Lb)^2 per sample; checked within 5 standard errors.
 *   Two BLEND planes over an emitter: the layer a ray stops at is chosen by
 *   one stratified number, so each pixel's mean is within 2/n of the
 *   layers' spread of the expectation (independent draws: 15 times that).
 * - MASK, by texture alpha and by factor, above and below the cutoff: every
 *   sample reads the same value, exactly Ls (opaque) or Lb (invisible).
 * - shadow rays: a black BLEND occluder between a point light and a Lambert
 *   floor of albedo RHO: the shadow ray takes the occluder's transmittance,
 *   so every sample reads (1 - a) V, V = RHO/pi I cos/d^2 (a draw would read
 *   V with probability 1 - a: variance a (1 - a) V^2); and
 *   pt_accel_transmittance_alpha through stacked BLEND sheets, a wall and
 *   MASK sheets gives the product of 1 - alpha, 0 or 1 on every ray.
 * - an area light behind a BLEND occluder, and a BLEND area light: NEE
 *   alone, BSDF sampling alone and MIS each read (1 - a) (or a) RHO/pi E,
 *   E from Lambert's polygon formula, within 5 standard errors estimated
 *   from the samples; NEE and BSDF sampling must also agree with each other.
 * - determinism: a tile rendered in one sample range equals the sum of two
 *   (bit for bit), and the batched tile loop equals one path at a time.
 * - OPAQUE ignores alpha, and BLEND of alpha 1 renders the same bits as
 *   OPAQUE (the pass-through path changes nothing where nothing passes).
 * - the AlphaBlendModeTest asset (../shared/scenes): rays through its MASK
 *   quads pass where the texture's alpha is under the cutoff, its BLEND quad
 *   is hit at the rate alpha, and it renders without NaN or Inf.
 */
#include <math.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/env.h"
#include "common/render/render.h"
#include "common/scene/accel.h"
#include "common/scene/alpha.h"
#include "common/scene/scene.h"
#include "tests/check.h"

#define RHO 0.5
#define PI_D 3.14159265358979323846
#define KSIGMA 5.0

static const uint32_t QUAD_IDX[6] = {0, 1, 2, 0, 2, 3};

/* A black, non-reflecting material (metallic 0, specular 0) emitting e. */
static pt_material black(float e)
{
    pt_material m = pt_material_default();
    m.base_color[0] = m.base_color[1] = m.base_color[2] = 0.0f;
    m.metallic = 0.0f;
    m.specular = 0.0f;
    m.emissive[0] = m.emissive[1] = m.emissive[2] = e;
    m.double_sided = 1;
    return m;
}

/* An axis-aligned quad at height z over [x0,x1] x [y0,y1], wound so that it
 * faces +z (up) or -z (down), with uvs (x0,y0) -> (0,0), (x1,y1) -> (1,1). */
static void add_quad_z(pt_scene_builder *b, float x0, float x1, float y0, float y1, float z, int up,
                       uint32_t mat)
{
    float p[12] = {x0, y0, z, x1, y0, z, x1, y1, z, x0, y1, z};
    float uv[8] = {0, 0, 1, 0, 1, 1, 0, 1};
    const uint32_t down_idx[6] = {0, 2, 1, 0, 3, 2};
    pt_error err = {0};
    CHECKF(pt_scene_builder_add_mesh(b, "quad", p, NULL, uv, 4, up ? QUAD_IDX : down_idx, 2, NULL,
                                     mat, &err) == PT_OK,
           "%s", err.msg);
}

/* A camera at pos looking straight down (-z), and the scene finished. */
static pt_scene *finish_down(pt_scene_builder *b, pt_vec3 pos)
{
    pt_camera cam = {0};
    cam.position = pos;
    cam.forward = pt_v3(0, 0, -1);
    cam.right = pt_v3(1, 0, 0);
    cam.up = pt_v3(0, 1, 0);
    cam.yfov = 1e-4f;
    cam.aspect = 1.0f;
    snprintf(cam.name, sizeof cam.name, "down");
    pt_error err = {0};
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

/* A W x H RGBA texture, white, whose alpha is `left` for u < 0.5 and `right`
 * beyond (linear; bytes). */
static uint32_t add_alpha_texture(pt_scene_builder *b, uint8_t left, uint8_t right)
{
    const uint32_t W = 8, H = 8;
    pt_texture t = {0};
    t.width = W;
    t.height = H;
    t.rgba = pt_malloc(W * H * 4);
    CHECK(t.rgba != NULL);
    for (uint32_t i = 0; t.rgba && i < W * H; i++) {
        t.rgba[4 * i] = t.rgba[4 * i + 1] = t.rgba[4 * i + 2] = 255;
        t.rgba[4 * i + 3] = (i % W) < W / 2 ? left : right;
    }
    t.wrap_s = t.wrap_t = PT_WRAP_CLAMP;
    uint32_t idx = 0;
    pt_error err = {0};
    CHECK(pt_scene_builder_add_texture(b, &t, &idx, &err) == PT_OK);
    return idx;
}

typedef struct stats {
    double mean; /* of the green channel over pixels and samples */
    double se;   /* its standard error, from the samples' luminance */
    uint32_t n;  /* samples */
} stats;

static stats render_stats(const pt_scene *s, const pt_env *env, uint32_t strategy, uint32_t spp,
                          const char **variant)
{
    stats out = {NAN, NAN, 0};
    const uint32_t W = 2, H = 2;
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = W;
    p.height = H;
    p.seed = 7;
    p.light_strategy = strategy;
    p.env = env;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    if (!r)
        return out;
    if (variant)
        *variant = pt_renderer_variant(r);
    pt_pixel_acc acc[4];
    pt_render_stats st = {0};
    pt_rect all = {0, 0, W, H};
    pt_render_tile(r, all, 0, spp, acc, &st);
    CHECK(st.rejected == 0);
    double sum = 0.0, sq = 0.0, n = 0.0;
    for (uint32_t i = 0; i < W * H; i++) {
        sum += pt_acc_sum(&acc[i], 1);
        sq += pt_acc_sum_sq(&acc[i]);
        n += acc[i].n;
    }
    out.mean = sum / n;
    out.se = sqrt(fmax(sq / n - out.mean * out.mean, 0.0) / (n - 1.0));
    out.n = (uint32_t)n;
    pt_renderer_free(r);
    return out;
}

/* Within KSIGMA of the analytic standard error of a Bernoulli mixture of
 * two values a (probability p) and b over n samples. */
static void expect_bernoulli(const char *what, stats got, double p, double a, double b)
{
    double want = p * a + (1.0 - p) * b;
    double sigma = sqrt(p * (1.0 - p)) * fabs(a - b) / sqrt((double)got.n);
    double tol = KSIGMA * sigma + 1e-5 * fabs(want);
    CHECKF(fabs(got.mean - want) <= tol, "%s: %.6g, expected %.6g (+- %.3g)", what, got.mean, want,
           tol);
}

/* ---- camera rays ---------------------------------------------------------------------- */

/* A black BLEND plane of alpha a emitting LS at z = 1 in front of an
 * emitter LB at z = 0 (or nothing, for the environment), both facing up. */
static pt_scene *blend_plane_scene(float a, int emitter_behind)
{
    const float LS = 1.0f, LB = 4.0f;
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material front = black(LS), back = black(LB);
    front.alpha_mode = PT_ALPHA_BLEND;
    front.base_color[3] = a;
    uint32_t mf = 0, mb = 0;
    CHECK(pt_scene_builder_add_material(b, &front, &mf, &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &back, &mb, &err) == PT_OK);
    add_quad_z(b, -10, 10, -10, 10, 1.0f, 1, mf);
    if (emitter_behind)
        add_quad_z(b, -10, 10, -10, 10, 0.0f, 1, mb);
    return finish_down(b, pt_v3(0.3f, 0.2f, 5.0f));
}

static void blend_camera(void)
{
    const float alphas[] = {0.0f, 0.25f, 0.5f, 0.75f, 1.0f};
    for (size_t i = 0; i < sizeof alphas / sizeof alphas[0]; i++) {
        float a = alphas[i];
        char what[96];
        pt_scene *s = blend_plane_scene(a, 1);
        if (!s)
            return;
        CHECK(s->features & PT_FEAT_ALPHA);
        const char *variant = NULL;
        stats st = render_stats(s, NULL, PT_LIGHT_MIS, 1024, &variant);
        CHECK(variant && strcmp(variant, "general") == 0);
        snprintf(what, sizeof what, "BLEND a=%.2f over an emitter", (double)a);
        expect_bernoulli(what, st, a, 1.0, 4.0);
        pt_scene_free(s);

        /* The same in front of a uniform environment of radiance 3. */
        s = blend_plane_scene(a, 0);
        pt_env *env = NULL;
        CHECK(pt_env_uniform(pt_v3(3, 3, 3), &env, NULL) == PT_OK);
        if (s && env) {
            st = render_stats(s, env, PT_LIGHT_MIS, 1024, NULL);
            snprintf(what, sizeof what, "BLEND a=%.2f over the environment", (double)a);
            expect_bernoulli(what, st, a, 1.0, 3.0);
        }
        pt_env_free(env);
        pt_scene_free(s);
    }
}

/* Two black BLEND planes, alpha A2 emitting 2 at z = 2 and A1 emitting 1 at
 * z = 1, over an emitter of 4: a camera ray stops at the upper plane with
 * probability A2, at the lower with (1 - A2) A1, else at the emitter. The
 * layer is chosen by the bounce's one stratified number
 * (pt_accel_intersect_layers), so over 1024 samples (a power of 2: each of
 * [k/1024, (k+1)/1024) holds one number) each pixel's share of each layer
 * is within 2/1024 of its probability, and its mean within 2/1024 x 3 of
 * the expectation; independent draws per sample would miss by about
 * sqrt(p (1 - p) / 1024) x 3 = 0.045 (a pixel lands within the bound with
 * probability about 0.1). */
static void blend_layers_stratified(void)
{
    const float A1 = 0.4f, A2 = 0.3f;
    const uint32_t SPP = 1024, W = 2, H = 2;
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material p1 = black(1.0f), p2 = black(2.0f), back = black(4.0f);
    p1.alpha_mode = p2.alpha_mode = PT_ALPHA_BLEND;
    p1.base_color[3] = A1;
    p2.base_color[3] = A2;
    uint32_t m1 = 0, m2 = 0, mb = 0;
    CHECK(pt_scene_builder_add_material(b, &p1, &m1, &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &p2, &m2, &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &back, &mb, &err) == PT_OK);
    add_quad_z(b, -10, 10, -10, 10, 2.0f, 1, m2);
    add_quad_z(b, -10, 10, -10, 10, 1.0f, 1, m1);
    add_quad_z(b, -10, 10, -10, 10, 0.0f, 1, mb);
    pt_scene *s = finish_down(b, pt_v3(0.3f, 0.2f, 5.0f));
    if (!s)
        return;
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = W;
    p.height = H;
    p.seed = 11;
    pt_renderer *r = NULL;
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    if (r) {
        pt_pixel_acc acc[4];
        pt_render_stats st = {0};
        pt_rect all = {0, 0, W, H};
        pt_render_tile(r, all, 0, SPP, acc, &st);
        double want = A2 * 2.0 + (1.0 - A2) * (A1 * 1.0 + (1.0 - A1) * 4.0);
        double tol = 2.0 / SPP * 3.0 + 1e-5 * want;
        for (uint32_t i = 0; i < W * H; i++) {
            double mean = pt_acc_sum(&acc[i], 1) / acc[i].n;
            CHECKF(fabs(mean - want) <= tol,
                   "two BLEND layers, pixel %u: %.6g, expected %.6g (+- %.3g, stratified)", i, mean,
                   want, tol);
        }
    }
    pt_renderer_free(r);
    pt_scene_free(s);
}

/* A black MASK (or OPAQUE) plane emitting 1 in front of an emitter of 4;
 * tex: an alpha texture 0.2 | 0.8 across u (the camera sees u = 0.25 or
 * 0.75 by look_x = -0.5 or 0.5), else alpha is the factor. */
static double mask_read(int mode, float factor, float cutoff, int tex, float look_x)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material front = black(1.0f), back = black(4.0f);
    front.alpha_mode = mode;
    front.alpha_cutoff = cutoff;
    front.base_color[3] = factor;
    if (tex)
        front.base_color_tex = (int32_t)add_alpha_texture(b, 51, 204);
    uint32_t mf = 0, mb = 0;
    CHECK(pt_scene_builder_add_material(b, &front, &mf, &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &back, &mb, &err) == PT_OK);
    add_quad_z(b, -1, 1, -1, 1, 1.0f, 1, mf);
    add_quad_z(b, -10, 10, -10, 10, 0.0f, 1, mb);
    pt_scene *s = finish_down(b, pt_v3(look_x, 0.0f, 5.0f));
    if (!s)
        return NAN;
    CHECK(!(s->features & PT_FEAT_ALPHA) == (mode == PT_ALPHA_OPAQUE));
    stats st = render_stats(s, NULL, PT_LIGHT_MIS, 64, NULL);
    pt_scene_free(s);
    return st.mean;
}

static void expect_exact(const char *what, double got, double want)
{
    CHECKF(fabs(got - want) <= 1e-6 * want, "%s: %.8g, expected %.8g", what, got, want);
}

static void mask_camera(void)
{
    /* Texture alpha 0.2 (left) and 0.8 (right), default cutoff 0.5. */
    expect_exact("MASK, texture alpha 0.2 < 0.5", mask_read(PT_ALPHA_MASK, 1, 0.5f, 1, -0.5f), 4.0);
    expect_exact("MASK, texture alpha 0.8 >= 0.5", mask_read(PT_ALPHA_MASK, 1, 0.5f, 1, 0.5f), 1.0);
    expect_exact("MASK, texture 0.8 x factor 0.5 < 0.5",
                 mask_read(PT_ALPHA_MASK, 0.5f, 0.5f, 1, 0.5f), 4.0);
    expect_exact("MASK, texture 0.2, cutoff 0.1", mask_read(PT_ALPHA_MASK, 1, 0.1f, 1, -0.5f), 1.0);
    /* Factor alone, around the cutoff; alpha == cutoff is opaque. */
    expect_exact("MASK, factor 0.3 < 0.4", mask_read(PT_ALPHA_MASK, 0.3f, 0.4f, 0, 0), 4.0);
    expect_exact("MASK, factor 0.5 >= 0.4", mask_read(PT_ALPHA_MASK, 0.5f, 0.4f, 0, 0), 1.0);
    expect_exact("MASK, factor 0.5 == cutoff 0.5", mask_read(PT_ALPHA_MASK, 0.5f, 0.5f, 0, 0), 1.0);
    /* OPAQUE ignores alpha (glTF 3.9.4), the factor's and the texture's. */
    expect_exact("OPAQUE, factor 0.1", mask_read(PT_ALPHA_OPAQUE, 0.1f, 0.5f, 0, 0), 1.0);
    expect_exact("OPAQUE, texture alpha 0.2", mask_read(PT_ALPHA_OPAQUE, 1, 0.5f, 1, -0.5f), 1.0);
}

/* ---- shadow rays ---------------------------------------------------------------------- */

/* A Lambert floor (RHO) at z = 0 seen at the origin, lit by a point light
 * of intensity I at (2, 0, 2); a black BLEND quad of alpha a in the plane
 * x = 1 crosses the segment between them but not the camera's ray. */
static void blend_shadow_point(void)
{
    const float I = 5.0f;
    const float alphas[] = {0.0f, 0.3f, 0.7f, 1.0f};
    for (size_t i = 0; i < sizeof alphas / sizeof alphas[0]; i++) {
        float a = alphas[i];
        pt_scene_builder *b = NULL;
        pt_error err = {0};
        CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
        pt_material floor = black(0.0f), occ = black(0.0f);
        floor.base_color[0] = floor.base_color[1] = floor.base_color[2] = (float)RHO;
        occ.alpha_mode = PT_ALPHA_BLEND;
        occ.base_color[3] = a;
        uint32_t mfl = 0, mo = 0;
        CHECK(pt_scene_builder_add_material(b, &floor, &mfl, &err) == PT_OK);
        CHECK(pt_scene_builder_add_material(b, &occ, &mo, &err) == PT_OK);
        add_quad_z(b, -10, 10, -10, 10, 0.0f, 1, mfl);
        float q[12] = {1, -0.5f, 0.5f, 1, 0.5f, 0.5f, 1, 0.5f, 1.5f, 1, -0.5f, 1.5f};
        CHECK(pt_scene_builder_add_mesh(b, "occluder", q, NULL, NULL, 4, QUAD_IDX, 2, NULL, mo,
                                        &err) == PT_OK);
        pt_punctual l = {0};
        l.type = PT_PUNCTUAL_POINT;
        l.direction = pt_v3(0, 0, -1);
        l.intensity = pt_v3(I, I, I);
        snprintf(l.name, sizeof l.name, "bulb");
        const double pos[3] = {2, 0, 2};
        CHECKF(pt_scene_builder_add_punctual(b, &l, pos, &err) == PT_OK, "%s", err.msg);
        pt_scene *s = finish_down(b, pt_v3(0, 0, 5));
        if (!s)
            return;
        stats st = render_stats(s, NULL, PT_LIGHT_MIS, 1024, NULL);
        double d2 = 8.0, cos_t = 2.0 / sqrt(d2);
        double v = RHO / PI_D * I * cos_t / d2;
        char what[96];
        snprintf(what, sizeof what, "point light through BLEND a=%.2f", (double)a);
        expect_bernoulli(what, st, 1.0 - a, v, 0.0);
        /* The shadow ray takes the sheet's transmittance, not a draw of it:
         * every sample reads (1 - a) V, where a draw would give a standard
         * error of sqrt(a (1 - a) / n) V (5e-4 at a = 0.3). Allowed: 5 % of
         * that, for the rounding of the accumulated squares (5e-6 here). */
        double draw_se = sqrt(a * (1.0 - a) / (double)st.n) * v;
        CHECKF(a == 0.0f || a == 1.0f || st.se <= 0.05 * draw_se,
               "%s: standard error %.3g, a draw's %.3g (transmittance)", what, st.se, draw_se);
        pt_scene_free(s);
    }
}

/* A black BLEND plane of alpha a at z = 1 between the camera and the floor,
 * and a point light above it: the camera ray and the shadow ray both cross
 * the plane's same triangle, each passing with 1 - a on its own. A sample
 * reads V with probability (1 - a)^2; reusing the camera ray's decision for
 * the shadow ray would give (1 - a). */
static void blend_shadow_twice(void)
{
    const float I = 5.0f, a = 0.5f;
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material floor = black(0.0f), occ = black(0.0f);
    floor.base_color[0] = floor.base_color[1] = floor.base_color[2] = (float)RHO;
    occ.alpha_mode = PT_ALPHA_BLEND;
    occ.base_color[3] = a;
    uint32_t mfl = 0, mo = 0;
    CHECK(pt_scene_builder_add_material(b, &floor, &mfl, &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &occ, &mo, &err) == PT_OK);
    add_quad_z(b, -10, 10, -10, 10, 0.0f, 1, mfl);
    add_quad_z(b, -3, 3, -3, 3, 1.0f, 1, mo);
    pt_punctual l = {0};
    l.type = PT_PUNCTUAL_POINT;
    l.direction = pt_v3(0, 0, -1);
    l.intensity = pt_v3(I, I, I);
    snprintf(l.name, sizeof l.name, "bulb");
    const double pos[3] = {0.5, 0.3, 2};
    CHECKF(pt_scene_builder_add_punctual(b, &l, pos, &err) == PT_OK, "%s", err.msg);
    pt_scene *s = finish_down(b, pt_v3(0.4f, 0.2f, 5));
    if (!s)
        return;
    stats st = render_stats(s, NULL, PT_LIGHT_MIS, 1024, NULL);
    double dx = 0.1, dy = 0.1, d2 = dx * dx + dy * dy + 4.0, cos_t = 2.0 / sqrt(d2);
    double v = RHO / PI_D * I * cos_t / d2;
    expect_bernoulli("camera and shadow ray through one BLEND triangle", st, (1.0 - a) * (1.0 - a),
                     v, 0.0);
    pt_scene_free(s);
}

/* Irradiance at the origin (normal +z) from a polygon of uniform radiance
 * L (Lambert's formula: E = L/2 sum_i angle_i n . unit(r_i x r_i+1)). */
static double polygon_irradiance(const double (*v)[3], int n, double L)
{
    double e = 0.0;
    for (int i = 0; i < n; i++) {
        const double *a = v[i], *c = v[(i + 1) % n];
        double la = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
        double lc = sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
        double cosg = (a[0] * c[0] + a[1] * c[1] + a[2] * c[2]) / (la * lc);
        double g = acos(fmin(fmax(cosg, -1.0), 1.0));
        double x[3] = {a[1] * c[2] - a[2] * c[1], a[2] * c[0] - a[0] * c[2],
                       a[0] * c[1] - a[1] * c[0]};
        double lx = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
        e += g * x[2] / lx;
    }
    return fabs(0.5 * L * e);
}

/* The floor at the origin lit by an emissive quad of radiance LE facing
 * down over [1.5,2.5] x [-0.5,0.5] at z = 2. occluder: a black BLEND quad of
 * alpha a over [0.5,1.5] x [-1,1] at z = 1 (every ray from the origin to the
 * light crosses it; the camera's ray does not). Else the light itself is
 * BLEND of alpha a. Each strategy must read frac RHO/pi E. */
static void blend_area(int occluder)
{
    const float LE = 6.0f, a = 0.4f;
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material floor = black(0.0f), light = black(LE), occ = black(0.0f);
    floor.base_color[0] = floor.base_color[1] = floor.base_color[2] = (float)RHO;
    occ.alpha_mode = PT_ALPHA_BLEND;
    occ.base_color[3] = a;
    light.double_sided = 0;
    if (!occluder) {
        light.alpha_mode = PT_ALPHA_BLEND;
        light.base_color[3] = a;
    }
    uint32_t mfl = 0, ml = 0, mo = 0;
    CHECK(pt_scene_builder_add_material(b, &floor, &mfl, &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &light, &ml, &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &occ, &mo, &err) == PT_OK);
    add_quad_z(b, -10, 10, -10, 10, 0.0f, 1, mfl);
    add_quad_z(b, 1.5f, 2.5f, -0.5f, 0.5f, 2.0f, 0, ml);
    if (occluder)
        add_quad_z(b, 0.5f, 1.5f, -1.0f, 1.0f, 1.0f, 1, mo);
    pt_scene *s = finish_down(b, pt_v3(0, 0, 5));
    if (!s)
        return;
    const double v[4][3] = {{1.5, -0.5, 2}, {2.5, -0.5, 2}, {2.5, 0.5, 2}, {1.5, 0.5, 2}};
    double frac = occluder ? 1.0 - a : a;
    double want = frac * RHO / PI_D * polygon_irradiance(v, 4, LE);
    const char *names[3] = {"MIS", "NEE only", "BSDF only"};
    stats st[3];
    for (uint32_t k = 0; k < 3; k++) {
        st[k] = render_stats(s, NULL, k, k == 2 ? 16384 : 4096, NULL);
        double tol = KSIGMA * st[k].se;
        CHECKF(fabs(st[k].mean - want) <= tol, "%s, %s: %.6g, expected %.6g (+- %.3g)",
               occluder ? "area light behind BLEND" : "BLEND area light", names[k], st[k].mean,
               want, tol);
    }
    /* NEE and BSDF sampling estimate the same integral. */
    double tol = KSIGMA * sqrt(st[1].se * st[1].se + st[2].se * st[2].se);
    CHECKF(fabs(st[1].mean - st[2].mean) <= tol, "%s: NEE %.6g vs BSDF %.6g (+- %.3g)",
           occluder ? "area light behind BLEND" : "BLEND area light", st[1].mean, st[2].mean, tol);
    pt_scene_free(s);
}

/* ---- determinism ---------------------------------------------------------------------- */

/* A lit scene with a textured BLEND quad, a MASK quad and a BLEND emitter,
 * seen through a wide camera, so paths cross several alpha surfaces. */
static pt_scene *mixed_scene(int blend_alpha_one)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material floor = black(0.0f), light = black(5.0f), bl = black(0.0f), mk = black(0.0f);
    floor.base_color[0] = floor.base_color[1] = floor.base_color[2] = 0.7f;
    bl.base_color[1] = 0.6f;
    mk.base_color[0] = 0.6f;
    uint32_t tex = add_alpha_texture(b, 60, 190);
    if (blend_alpha_one) {
        bl.alpha_mode = PT_ALPHA_BLEND; /* alpha 1: nothing passes */
    } else {
        bl.alpha_mode = PT_ALPHA_BLEND;
        bl.base_color_tex = (int32_t)tex;
        bl.base_color[3] = 0.9f;
        mk.alpha_mode = PT_ALPHA_MASK;
        mk.base_color_tex = (int32_t)tex;
        light.alpha_mode = PT_ALPHA_BLEND;
        light.base_color[3] = 0.5f;
    }
    uint32_t m[4];
    CHECK(pt_scene_builder_add_material(b, &floor, &m[0], &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &light, &m[1], &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &bl, &m[2], &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &mk, &m[3], &err) == PT_OK);
    add_quad_z(b, -4, 4, -4, 4, 0.0f, 1, m[0]);
    add_quad_z(b, -1, 1, -1, 1, 3.0f, 0, m[1]);
    add_quad_z(b, -2, 0.5f, -2, 0.5f, 1.0f, 1, m[2]);
    add_quad_z(b, -0.5f, 2, -0.5f, 2, 1.5f, 1, m[3]);
    pt_camera cam = {0};
    cam.position = pt_v3(0, -6, 4);
    cam.forward = pt_v3_norm(pt_v3(0, 6, -3.5f));
    cam.right = pt_v3(1, 0, 0);
    cam.up = pt_v3_cross(cam.right, cam.forward);
    cam.yfov = 1.0f;
    snprintf(cam.name, sizeof cam.name, "wide");
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

static pt_renderer *renderer_for(const pt_scene *s, uint32_t w, uint32_t h, uint32_t strategy,
                                 uint32_t extra)
{
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = w;
    p.height = h;
    p.seed = 11;
    p.light_strategy = strategy;
    p.extra_features = extra;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    return r;
}

static void determinism(void)
{
    pt_scene *s = mixed_scene(0);
    if (!s)
        return;
    enum { W = 12, H = 10, N = W * H };
    for (uint32_t strategy = 0; strategy < 3; strategy++) {
        pt_renderer *r = renderer_for(s, W, H, strategy, 0);
        if (!r)
            break;
        CHECK(pt_renderer_lanes(r) == 0);
        pt_pixel_acc whole[N], a[N], b[N], ref[N];
        pt_rect all = {0, 0, W, H};
        pt_render_tile(r, all, 0, 48, whole, NULL);
        /* In chunks of one sample block, added in order, as the
         * coordinator merges them. */
        memset(a, 0, sizeof a);
        for (uint32_t c = 0; c < 3; c++) {
            pt_render_tile(r, all, 16 * c, 16 * (c + 1), b, NULL);
            for (uint32_t i = 0; i < N; i++)
                pt_pixel_acc_add(&a[i], &b[i]);
        }
        CHECKF(memcmp(whole, a, sizeof whole) == 0,
               "strategy %u: [0,48) differs from its three 16-sample chunks", strategy);
        /* The tile split in two row bands. */
        pt_rect top = {0, 0, W, H / 2}, bottom = {0, H / 2, W, H};
        pt_render_tile(r, top, 0, 48, b, NULL);
        pt_render_tile(r, bottom, 0, 48, b + N / 2, NULL);
        CHECKF(memcmp(whole, b, sizeof whole) == 0, "strategy %u: two bands differ from the tile",
               strategy);
        /* One path at a time (li_impl) must give the batched loop's bits. */
        memset(ref, 0, sizeof ref);
        for (uint32_t k = 0; k < N; k++)
            for (uint32_t b0 = 0; b0 < 48; b0 += PT_SAMPLE_BLOCK) {
                pt_block_acc blk = {{0, 0, 0}, 0, 0, 0};
                for (uint32_t i = b0; i < b0 + PT_SAMPLE_BLOCK; i++) {
                    int cov = 0; /* a cut-out the camera ray passes may leave the pixel */
                    if (pt_block_acc_sample(&blk, pt_render_sample(r, k % W, k / W, i, NULL, &cov)))
                        blk.hits += (uint32_t)cov;
                }
                pt_pixel_acc_add_block(&ref[k], &blk);
            }
        CHECKF(memcmp(whole, ref, sizeof whole) == 0,
               "strategy %u: the tile differs from one path at a time", strategy);
        double lit = 0.0;
        for (uint32_t i = 0; i < N; i++)
            lit += pt_acc_sum(&whole[i], 1);
        CHECK(lit > 0.0);
        pt_renderer_free(r);
    }
    pt_scene_free(s);
}

/* BLEND of alpha 1 with no texture passes nothing: the same bits as the
 * scene with the material OPAQUE (in the general variant, which the alpha
 * scene runs). */
/* Alpha is read where the base colour is: through the base slot's texture
 * transform (an offset of 0.5 swaps the texture's transparent and opaque
 * halves), and times COLOR_0's alpha (glTF 2.0, 3.9.2). Read at triangle 0's
 * point (b1, b2) = (0.2, 0.1), whose u is 0.3 (the texture's left half). */
static void alpha_inputs(void)
{
    for (int variant = 0; variant < 3; variant++) {
        pt_scene_builder *b = NULL;
        pt_error err = {0};
        CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
        pt_material m = black(0.0f);
        m.alpha_mode = PT_ALPHA_BLEND;
        m.base_color_tex = (int32_t)add_alpha_texture(b, 0, 255);
        if (variant == 1) {
            const float off[2] = {0.5f, 0.0f}, scale[2] = {1.0f, 1.0f};
            m.tex_xf[PT_SLOT_BASE] = pt_tex_xform_make(off, 0.0f, scale, 0);
        }
        uint32_t mi = 0;
        CHECK(pt_scene_builder_add_material(b, &m, &mi, &err) == PT_OK);
        float p[12] = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
        float uv[8] = {0, 0, 1, 0, 1, 1, 0, 1};
        float rgba[16];
        for (int i = 0; i < 16; i++)
            rgba[i] = (i % 4 == 3) ? 0.25f : 1.0f;
        pt_mesh_extra extra = {NULL, NULL, variant == 2 ? rgba : NULL};
        CHECKF(pt_scene_builder_add_mesh_extra(b, "quad", p, NULL, uv, &extra, 4, QUAD_IDX, 2, NULL,
                                               mi, &err) == PT_OK,
               "%s", err.msg);
        pt_scene *s = finish_down(b, pt_v3(0.5f, 0.5f, 5.0f));
        if (!s)
            continue;
        if (variant == 2) { /* the opaque half, times COLOR_0's 0.25 */
            s->materials[0].tex_xf[PT_SLOT_BASE] =
                pt_tex_xform_make((const float[2]){0.5f, 0.0f}, 0.0f, (const float[2]){1, 1}, 0);
        }
        float a = pt_alpha_value(s, 0, 0.2f, 0.1f);
        const float want[3] = {0.0f, 1.0f, 0.25f};
        CHECKF(fabsf(a - want[variant]) < 1e-6f, "alpha inputs %d: %g, want %g", variant, (double)a,
               (double)want[variant]);
        pt_scene_free(s);
    }
}

static void alpha_one_is_opaque(void)
{
    pt_scene *s = mixed_scene(1);
    if (!s)
        return;
    enum { W = 12, H = 10, N = W * H };
    pt_pixel_acc with[N], without[N];
    pt_rect all = {0, 0, W, H};
    pt_renderer *r = renderer_for(s, W, H, PT_LIGHT_MIS, 0);
    if (r)
        pt_render_tile(r, all, 0, 32, with, NULL);
    pt_renderer_free(r);
    for (uint32_t i = 0; i < s->num_materials; i++)
        s->materials[i].alpha_mode = PT_ALPHA_OPAQUE;
    s->features &= ~(uint32_t)PT_FEAT_ALPHA;
    r = renderer_for(s, W, H, PT_LIGHT_MIS, 0xffffffffu);
    if (r)
        pt_render_tile(r, all, 0, 32, without, NULL);
    pt_renderer_free(r);
    CHECK(memcmp(with, without, sizeof with) == 0);
    pt_scene_free(s);
}

/* ---- the shared asset ----------------------------------------------------------------- */

static void count_alpha_warnings(void *user, const char *message)
{
    if (strstr(message, "alphaMode"))
        (*(int *)user)++;
}

static void asset(void)
{
    char path[512];
    snprintf(path, sizeof path, "%s/AlphaBlendModeTest/AlphaBlendModeTest.glb", PT_SHARED_SCENES);
    if (!check_shared_file(path))
        return;
    int warned = 0;
    pt_scene_opts o = {0};
    o.warn = count_alpha_warnings;
    o.warn_user = &warned;
    pt_scene *s = NULL;
    pt_error err = {0};
    CHECKF(pt_scene_load(path, &o, &s, &err) == PT_OK, "%s", err.msg);
    if (!s)
        return;
    CHECKF(warned == 0, "%d warnings about alpha", warned);
    CHECK(s->features & PT_FEAT_ALPHA);
    pt_accel *acc = NULL;
    CHECK(pt_accel_new(s, &acc, &err) == PT_OK);
    uint32_t masks = 0, blends = 0, passed = 0, met = 0;
    for (uint32_t i = 0; acc && i < s->num_materials; i++) {
        const pt_material *m = &s->materials[i];
        if (m->alpha_mode == PT_ALPHA_MASK)
            masks++;
        if (m->alpha_mode == PT_ALPHA_BLEND)
            blends++;
    }
    CHECK(masks == 3 && blends == 1);
    /* At points over every MASK and BLEND triangle, a ray straight at the
     * point along the normal: a MASK point under its cutoff is passed (the
     * ray does not stop at that triangle), over it is met; a BLEND point is
     * met by a fraction alpha of 256 keys (within 5 binomial sigmas). */
    uint32_t checked_mask = 0, checked_blend = 0;
    for (uint32_t t = 0; acc && t < s->num_triangles; t++) {
        if (!pt_alpha_tri(s, t))
            continue;
        const pt_material *m = &s->materials[s->tri_material[t]];
        pt_hit h0 = {0.0f, 0.0f, 0.0f, t, 0};
        for (int k = 0; k < 9; k++) {
            float b1 = 0.1f + 0.1f * (float)(k % 3), b2 = 0.1f + 0.1f * (float)(k / 3);
            h0.b1 = b1;
            h0.b2 = b2;
            pt_vec3 p, ng;
            pt_accel_hit_point(s, &h0, &p, &ng);
            pt_vec3 o2 = pt_v3_add(p, pt_v3_scale(ng, 1e-3f));
            pt_vec3 d = pt_v3_neg(ng);
            float a = pt_alpha_value(s, t, b1, b2);
            uint32_t hits = 0, n = m->alpha_mode == PT_ALPHA_MASK ? 1 : 256;
            for (uint32_t key = 0; key < n; key++) {
                pt_hit h;
                int got = pt_accel_intersect_alpha(acc, o2, d, 2e-3f, key * 2654435761u, &h);
                hits += got && h.tri == t;
            }
            if (m->alpha_mode == PT_ALPHA_MASK) {
                if (fabsf(a - m->alpha_cutoff) < 0.02f)
                    continue; /* on the edge: the bilinear lookup decides */
                CHECKF((hits == 1) == (a >= m->alpha_cutoff),
                       "MASK '%s' tri %u: alpha %.3f, cutoff %.2f, met %u", m->name, t, (double)a,
                       (double)m->alpha_cutoff, hits);
                checked_mask++;
                passed += hits == 0;
                met += hits == 1;
            } else {
                double sd = sqrt(n * (double)a * (1.0 - a));
                CHECKF(fabs(hits - n * (double)a) <= KSIGMA * sd + 0.5,
                       "BLEND tri %u: alpha %.3f, met %u of %u", t, (double)a, hits, n);
                checked_blend++;
            }
        }
    }
    CHECK(checked_mask > 0 && checked_blend > 0 && passed > 0 && met > 0);
    pt_accel_free(acc);

    /* It renders, without NaN or Inf, and not as the same scene does with
     * alpha ignored. */
    pt_env *env = NULL;
    CHECK(pt_env_uniform(pt_v3(1, 1, 1), &env, NULL) == PT_OK);
    enum { W = 24, H = 16, N = W * H };
    pt_pixel_acc with[N], without[N];
    pt_rect all = {0, 0, W, H};
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = W;
    p.height = H;
    p.env = env;
    pt_render_stats st = {0};
    pt_renderer *r = NULL;
    CHECK(pt_renderer_new(s, &p, &r, NULL) == PT_OK);
    if (r)
        pt_render_tile(r, all, 0, 16, with, &st);
    pt_renderer_free(r);
    CHECK(st.rejected == 0 && st.samples == (uint64_t)N * 16);
    for (uint32_t i = 0; i < s->num_materials; i++)
        s->materials[i].alpha_mode = PT_ALPHA_OPAQUE;
    s->features &= ~(uint32_t)PT_FEAT_ALPHA;
    r = NULL;
    CHECK(pt_renderer_new(s, &p, &r, NULL) == PT_OK);
    if (r)
        pt_render_tile(r, all, 0, 16, without, NULL);
    pt_renderer_free(r);
    uint32_t differ = 0;
    for (uint32_t i = 0; i < N; i++)
        differ += pt_acc_sum(&with[i], 0) != pt_acc_sum(&without[i], 0);
    CHECKF(differ > N / 50, "only %u of %u pixels change with alpha", differ, N);
    pt_env_free(env);
    pt_scene_free(s);
}

/* pt_accel_transmittance_alpha through n parallel BLEND sheets of alpha a
 * (x = 1 .. n, one triangle pair each) and, with opaque, an opaque wall
 * behind them: prod (1 - a) = (1 - a)^n for every key while n is at most
 * PT_ACCEL_TRANS_MAX / 2 (two triangles could be offered per sheet; the ray
 * crosses one), 0 with the wall; past that the sheets beyond the count pass
 * by the key, and the mean over keys is still (1 - a)^n, within KSIGMA
 * standard errors of the draws. A MASK sheet under its cutoff passes (1),
 * over it blocks (0). */
static void transmittance_query(uint32_t n, int opaque, int mask)
{
    const float a = 0.25f;
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material sheet = black(0.0f), wall = black(0.0f);
    sheet.alpha_mode = mask ? PT_ALPHA_MASK : PT_ALPHA_BLEND;
    sheet.base_color[3] = mask == 2 ? 0.9f : a; /* cutoff 0.5: 2 blocks, 1 passes */
    uint32_t ms = 0, mw = 0;
    CHECK(pt_scene_builder_add_material(b, &sheet, &ms, &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &wall, &mw, &err) == PT_OK);
    for (uint32_t k = 0; k < n + (opaque != 0); k++) {
        float x = 1.0f + (float)k;
        float q[12] = {x, -1, -1, x, 1, -1, x, 1, 1, x, -1, 1};
        CHECK(pt_scene_builder_add_mesh(b, "sheet", q, NULL, NULL, 4, QUAD_IDX, 2, NULL,
                                        k < n ? ms : mw, &err) == PT_OK);
    }
    pt_scene *s = finish_down(b, pt_v3(0, 0, 5));
    if (!s)
        return;
    pt_accel *acc = NULL;
    CHECK(pt_accel_new(s, &acc, &err) == PT_OK);
    double want = opaque || mask == 2 ? 0.0 : mask ? 1.0 : pow(1.0 - a, (double)n);
    double sum = 0.0, sq = 0.0;
    const uint32_t keys = 4096;
    int exact = 1;
    for (uint32_t key = 0; acc && key < keys; key++) {
        /* Off the sheets' diagonal, where either triangle could be offered. */
        pt_vec3 o = pt_v3(0.0f, 0.1f + 0.3f * (float)key / keys, -0.2f);
        double t = pt_accel_transmittance_alpha(acc, o, pt_v3(1, 0, 0), (float)n + 2.0f,
                                                key * 2654435761u);
        exact &= fabs(t - want) <= 1e-6;
        sum += t;
        sq += t * t;
    }
    double mean = sum / keys, se = sqrt(fmax(sq / keys - mean * mean, 0.0) / (keys - 1.0));
    /* The closest hit by layers (pt_accel_intersect_layers) with u on a
     * grid: the share of rays stopping at sheet j (x = 1 + j) is within
     * 2 / keys of a (1 - a)^j while the layers are chosen by u; past
     * PT_ACCEL_TRANS_MAX (n = 20) the rest pass by the key, and the share
     * that passes all is (1 - a)^n within KSIGMA standard errors. */
    if (!opaque && !mask && acc) {
        uint32_t stop[24] = {0}, through = 0;
        for (uint32_t key = 0; key < keys; key++) {
            pt_vec3 o = pt_v3(0.0f, 0.1f + 0.3f * (float)key / keys, -0.2f);
            pt_hit h;
            float u = ((float)key + 0.5f) / (float)keys;
            if (!pt_accel_intersect_layers(acc, o, pt_v3(1, 0, 0), (float)n + 2.0f, 0.0f, u,
                                           key * 2654435761u, &h))
                through++;
            else if (h.t >= 0.5f && h.t < 23.5f)
                stop[(uint32_t)(h.t - 0.5f)]++;
        }
        for (uint32_t j = 0; j < n && j < PT_ACCEL_TRANS_MAX; j++) {
            double pj = a * pow(1.0 - a, (double)j);
            CHECKF(fabs((double)stop[j] / keys - pj) <= 2.0 / keys,
                   "%u sheets by layers: %.5f stop at sheet %u, expected %.5f", n,
                   (double)stop[j] / keys, j, pj);
        }
        double pt_ = pow(1.0 - a, (double)n);
        double sd = sqrt(pt_ * (1.0 - pt_) / keys);
        CHECKF(fabs((double)through / keys - pt_) <= KSIGMA * sd + 2.0 / keys,
               "%u sheets by layers: %.5f pass all, expected %.5f", n, (double)through / keys, pt_);
    }
    if (n <= PT_ACCEL_TRANS_MAX / 2 || opaque || mask)
        CHECKF(exact, "%u sheets%s%s: transmittance not %.6g on every ray (mean %.6g)", n,
               opaque ? " and a wall" : "", mask ? " (MASK)" : "", want, mean);
    else
        CHECKF(fabs(mean - want) <= KSIGMA * se + 1e-6,
               "%u sheets: mean %.6g, expected %.6g (+- %.3g)", n, mean, want, KSIGMA * se);
    pt_accel_free(acc);
    pt_scene_free(s);
}

/* pt_alpha_solid_new: a MASK quad whose UVs lie in the texture's opaque
 * half (alpha 0.8 over a cutoff of 0.5) is whole, one in its clear half or
 * across both is not; by factor alone 0.8 is whole and 0.3 not; OPAQUE and
 * BLEND triangles are never flagged. */
static void solid_flags(void)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    uint32_t tex = add_alpha_texture(b, 51, 204);
    pt_material mt = black(0.0f), m8 = black(0.0f), m3 = black(0.0f), op = black(0.0f),
                bl = black(0.0f);
    mt.alpha_mode = m8.alpha_mode = m3.alpha_mode = PT_ALPHA_MASK;
    mt.base_color_tex = (int32_t)tex;
    m8.base_color[3] = 0.8f;
    m3.base_color[3] = 0.3f;
    bl.alpha_mode = PT_ALPHA_BLEND;
    uint32_t m[5] = {0};
    const pt_material *ms[5] = {&mt, &m8, &m3, &op, &bl};
    for (int k = 0; k < 5; k++)
        CHECK(pt_scene_builder_add_material(b, ms[k], &m[k], &err) == PT_OK);
    /* Quads 0-2 textured: u in [0.6, 0.9] (texels 4..7: alpha 0.8), [0.1,
     * 0.4] (0.2), [0.3, 0.7] (both); 3-6: the other materials. */
    const float u0[3] = {0.6f, 0.1f, 0.3f}, u1[3] = {0.9f, 0.4f, 0.7f};
    const uint32_t mat[7] = {m[0], m[0], m[0], m[1], m[2], m[3], m[4]};
    for (int k = 0; k < 7; k++) {
        float z = (float)k;
        float q[12] = {0, 0, z, 1, 0, z, 1, 1, z, 0, 1, z};
        float a = k < 3 ? u0[k] : 0.0f, c = k < 3 ? u1[k] : 1.0f;
        float uv[8] = {a, 0.3f, c, 0.3f, c, 0.6f, a, 0.6f};
        CHECK(pt_scene_builder_add_mesh(b, "quad", q, NULL, uv, 4, QUAD_IDX, 2, NULL, mat[k],
                                        &err) == PT_OK);
    }
    pt_scene *s = finish_down(b, pt_v3(0, 0, 10));
    if (!s)
        return;
    uint8_t *f = NULL;
    CHECK(pt_alpha_solid_new(s, &f, &err) == PT_OK);
    const uint8_t want[7] = {1, 0, 0, 1, 0, 0, 0};
    for (uint32_t t = 0; f && t < 14 && t < s->num_triangles; t++)
        CHECKF(f[t] == want[t / 2], "triangle %u (quad %u): whole %d, expected %d", t, t / 2, f[t],
               want[t / 2]);
    pt_free(f);
    pt_scene_free(s);
}

/* StainedGlassLamp's MASK triangles: the flags hold (each flagged
 * triangle's coverage is 1 at 64 random points of it) and most of the
 * stained glass is whole (0.8 % of its texture is clear). */
static void solid_lamp(void)
{
    char path[512];
    snprintf(path, sizeof path, "%s/StainedGlassLamp/StainedGlassLamp.gltf", PT_SHARED_SCENES);
    if (!check_shared_file(path))
        return;
    pt_scene_opts o = {0};
    pt_scene *s = NULL;
    pt_error err = {0};
    CHECKF(pt_scene_load(path, &o, &s, &err) == PT_OK, "%s", err.msg);
    if (!s)
        return;
    uint8_t *f = NULL;
    CHECK(pt_alpha_solid_new(s, &f, &err) == PT_OK);
    uint32_t masks = 0, whole = 0, wrong = 0, rng = 12345;
    for (uint32_t t = 0; f && t < s->num_triangles; t++) {
        if (s->materials[s->tri_material[t]].alpha_mode != PT_ALPHA_MASK)
            continue;
        masks++;
        if (!f[t])
            continue;
        whole++;
        for (int k = 0; k < 64; k++) {
            rng = rng * 1664525u + 1013904223u;
            float b1 = (float)(rng >> 8) * 0x1p-24f;
            rng = rng * 1664525u + 1013904223u;
            float b2 = (float)(rng >> 8) * 0x1p-24f;
            if (b1 + b2 > 1.0f) {
                b1 = 1.0f - b1;
                b2 = 1.0f - b2;
            }
            wrong += pt_alpha_coverage(s, t, b1, b2) != 1.0f;
        }
    }
    CHECKF(wrong == 0, "%u points of whole triangles are not covered", wrong);
    CHECKF(whole >= masks / 2, "%u of %u MASK triangles whole, expected most", whole, masks);
    pt_free(f);
    pt_scene_free(s);
}

int main(void)
{
    solid_flags();
    solid_lamp();
    transmittance_query(1, 0, 0);
    transmittance_query(3, 0, 0);
    transmittance_query(3, 1, 0);
    transmittance_query(1, 0, 1);
    transmittance_query(1, 0, 2);
    transmittance_query(20, 0, 0);
    blend_camera();
    blend_layers_stratified();
    mask_camera();
    blend_shadow_point();
    blend_shadow_twice();
    blend_area(1);
    blend_area(0);
    determinism();
    alpha_one_is_opaque();
    alpha_inputs();
    asset();
    return check_report();
}
