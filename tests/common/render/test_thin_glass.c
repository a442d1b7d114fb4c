/*
 * test_thin_glass.c - light through thin smooth glass by next-event
 * estimation (render.c: trace_shadow's shadow_through, the straight-through
 * MIS bookkeeping in shade; closure.c: pt_closure_straight).
 *
 * - Closure: pt_closure_straight equals the mean of pt_closure_sample's
 *   weights over the samples that take the straight-through delta (wi =
 *   -wo), within 5 standard errors, for a plain thin pane, a tinted one
 *   with half transmission and an opaque share, one under a clearcoat and
 *   one under an iridescent film; zero for a rough or a thick interface.
 * - Closed form: a Lambert plane (albedo rho) under a large thin smooth
 *   sheet (ior 1.5, tint c), lit by one small emissive triangle above it,
 *   seen orthographically straight down through the sheet, at max_depth 3
 *   (the plane's direct light only). Each pixel reads
 *     c (1 - F(1)) rho / pi  int_light Le T(theta) cos_p cos_l / d^2 dA,
 *   T = c (1 - F(cos theta)) with the exact Fresnel the glass uses: the
 *   unoccluded closed form times the wall's transmittance. MIS, NEE alone
 *   and BSDF sampling alone each agree with it within 5 standard errors of
 *   their own samples (plus 1e-4 of the value for the quadrature), and the
 *   shadow rays did cross the sheet.
 * - The same two closed forms hold with the sheet an instance (turned a
 *   quarter and lifted into place: the hit's transform) and with the sheet
 *   moving along x over the shutter (the hit at the path's time).
 * - Fireflies: on the same scene every MIS sample is below the bound
 *   derived from the strategies' weights: NEE gives at most
 *   c (1 - F0) rho c Le A / (pi H^2) (cosines <= 1, d >= H) and the BSDF
 *   strategy's power-heuristic weight is at most p_b / (2 p_l) (p_b <= 1 /
 *   pi, p_l >= H^2 / A), half that again; with shadow rays stopped at the
 *   sheet as before (opaque_thin_glass), a sample that finds the light by
 *   the BSDF alone is c (1 - F0) rho T Le, hundreds of times the bound: the
 *   same check fails there.
 * - Environment: the sheet over the plane under a uniform sky L at the
 *   default depth reads F(1) L + c (1 - F(1)) L_p, L_p = rho c (1 - r) L /
 *   (1 - rho r), r = 2 int_0^1 F(mu) mu dmu the sheet's hemispherical
 *   reflectance (light bouncing between the plane and the sheet's
 *   underside), for all three strategies.
 * - A BLEND sheet of alpha 0.5 (shadow rays pass it by their key or cross
 *   the glass) agrees with the old estimator under a uniform sky by the
 *   paired z-test below.
 * - More walls than a shadow ray may cross (PT_SHADOW_CROSSINGS + 2 clear
 *   sheets over the plane, a uniform sky): NEE is blocked there and
 *   counted (pt_render_stats.dropped), BSDF sampling counts what it finds
 *   past them in full, and MIS, NEE alone and BSDF alone agree within 5
 *   standard errors.
 * - Unbiased on assets: TransmissionTest and ToyCar (their own cameras,
 *   under a grey sky) rendered with the new shadow rays and without them
 *   (opaque_thin_glass: the old estimator) agree by a paired z-test per 4 x
 *   4 block of pixels; the new one crosses walls there (both have thin
 *   smooth glass). Not in the studio map: there the old estimator finds
 *   the map's small bright lights through the glass by BSDF sampling alone,
 *   a heavy tail that a few hundred samples seldom reach, so its sample
 *   mean sits low and its sample variance understates the true one, and a
 *   z-test against it is not valid (the plane under the sheet in that map
 *   measured 0.1554 +- 0.0002 new, 0.168 +- 0.028 old, one sample of 1988).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/render/closure.h"
#include "common/render/dielectric.h"
#include "common/render/env.h"
#include "common/render/layers.h"
#include "common/render/render.h"
#include "common/scene/scene.h"
#include "tests/check.h"
#include "tests/common/render/ortho.h"
#include "tests/common/render/paired.h"
#include "tests/rng.h"

#define PI_D 3.14159265358979323846

static uint64_t rng = 0x2545f4914f6cdd1dull;
static float rndf(void)
{
    return rng_f24(&rng);
}

/* ---- pt_closure_straight against sampling ---- */

/* The mean weight of the samples that go straight through, per channel,
 * with its standard error, over n samples. */
static void straight_by_sampling(const pt_closure *c, int n, double mean[3], double se[3])
{
    double sum[3] = {0, 0, 0}, sq[3] = {0, 0, 0};
    for (int i = 0; i < n; i++) {
        float u[3] = {rndf(), rndf(), rndf()}, pdf = 0.0f;
        int delta = 0;
        pt_vec3 wi;
        pt_vec3 w = pt_closure_sample(c, u, &wi, &pdf, &delta);
        double v[3] = {0, 0, 0};
        if (delta && pdf > 0.0f && wi.z < 0.0f) {
            CHECK(fabsf(wi.x + c->wo.x) < 1e-6f && fabsf(wi.y + c->wo.y) < 1e-6f);
            v[0] = w.x, v[1] = w.y, v[2] = w.z;
        }
        for (int k = 0; k < 3; k++) {
            sum[k] += v[k];
            sq[k] += v[k] * v[k];
        }
    }
    for (int k = 0; k < 3; k++) {
        mean[k] = sum[k] / n;
        se[k] = sqrt(fmax(sq[k] / n - mean[k] * mean[k], 0.0) / (n - 1.0));
    }
}

static void check_straight(const char *name, const pt_closure *c)
{
    double m[3], se[3];
    straight_by_sampling(c, 200000, m, se);
    int smooth = 0;
    pt_vec3 t = pt_closure_straight(c, &smooth);
    const double tv[3] = {t.x, t.y, t.z};
    CHECKF(smooth, "%s: a smooth thin interface", name);
    for (int k = 0; k < 3; k++)
        CHECKF(fabs(tv[k] - m[k]) <= 5.0 * se[k] + 1e-6,
               "%s: channel %d %.6f, sampled %.6f +- %.6f", name, k, tv[k], m[k], se[k]);
    printf("%s: straight %.5f %.5f %.5f, sampled %.5f %.5f %.5f\n", name, tv[0], tv[1], tv[2], m[0],
           m[1], m[2]);
}

static void closure_straight(void)
{
    const pt_vec3 white = pt_v3(1, 1, 1);
    const float deg[3] = {0.0f, 50.0f, 80.0f};
    for (int a = 0; a < 3; a++) {
        float th = deg[a] * (float)PI_D / 180.0f;
        pt_vec3 wo = pt_v3(sinf(th), 0.0f, cosf(th));
        char name[96];
        /* A clear pane: (1 - F) exactly, and no opaque share. */
        pt_glass g = pt_glass_setup(white, 0.0f, 0.0f, 1.0f, white, 1.0f, 1.5f, 1);
        pt_closure c;
        pt_closure_init(&c, wo);
        pt_closure_add_glass(&c, &g);
        snprintf(name, sizeof name, "clear pane at %g deg", (double)deg[a]);
        check_straight(name, &c);
        pt_vec3 t = pt_closure_straight(&c, NULL);
        float F = pt_fresnel_dielectric(wo.z, 1.5f);
        CHECKF(fabsf(t.y - (1.0f - F)) < 1e-6f, "%s: 1 - F = %g, got %g", name, (double)(1.0f - F),
               (double)t.y);
        /* Tinted, half transmissive, with the opaque share beside it. */
        g = pt_glass_setup(pt_v3(0.9f, 0.5f, 0.2f), 0.2f, 0.0f, 1.0f, white, 0.5f, 1.5f, 1);
        pt_closure_init(&c, wo);
        pt_closure_add_glass(&c, &g);
        snprintf(name, sizeof name, "tinted half pane at %g deg", (double)deg[a]);
        check_straight(name, &c);
        /* Under a clearcoat: its below factor at (wo, -wo). */
        pt_bsdf base = g.base;
        pt_layers lay;
        memset(&lay, 0, sizeof lay);
        const float no_sheen[3] = {0.0f, 0.0f, 0.0f};
        CHECK(pt_layers_setup(&lay, &base, 0.8f, 0.1f, no_sheen, 0.0f));
        pt_closure_init(&c, wo);
        pt_closure_add_glass(&c, &g);
        pt_closure_add_layers(&c, &lay);
        snprintf(name, sizeof name, "coated pane at %g deg", (double)deg[a]);
        check_straight(name, &c);
        /* Under an iridescent film: its Fresnel per channel. */
        g = pt_glass_setup(white, 0.0f, 0.0f, 1.0f, white, 1.0f, 1.5f, 1);
        pt_glass_film(&g, 1.0f, 1.3f, 400.0f, 1.5f);
        pt_closure_init(&c, wo);
        pt_closure_add_glass(&c, &g);
        snprintf(name, sizeof name, "filmed pane at %g deg", (double)deg[a]);
        check_straight(name, &c);
    }
    /* Rough, or thick: no straight-through delta, nothing passes. */
    pt_vec3 wo = pt_v3(0.3f, 0.0f, 0.9539392f);
    pt_glass g = pt_glass_setup(white, 0.0f, 0.5f, 1.0f, white, 1.0f, 1.5f, 1);
    pt_closure c;
    pt_closure_init(&c, wo);
    pt_closure_add_glass(&c, &g);
    int smooth = 1;
    pt_vec3 t = pt_closure_straight(&c, &smooth);
    CHECK(!smooth && t.x == 0.0f && t.y == 0.0f && t.z == 0.0f);
    g = pt_glass_setup(white, 0.0f, 0.0f, 1.0f, white, 1.0f, 1.5f, 0);
    pt_closure_init(&c, wo);
    pt_closure_add_glass(&c, &g);
    t = pt_closure_straight(&c, &smooth);
    CHECK(!smooth && t.x == 0.0f && t.y == 0.0f && t.z == 0.0f);
}

/* ---- the plane under a sheet ---- */

#define SHEET_H 0.5f  /* the sheet's height over the plane (z = 0) */
#define LIGHT_H 2.0f  /* the light's height over the plane: H */
#define LIGHT_X 1.5f  /* its centre's x: off the reflection of the view */
#define LIGHT_S 0.15f /* its legs */
#define LE 50.0f      /* its radiance */
#define RHO 0.6f      /* the plane's albedo */
#define TINT 0.8f     /* the sheet's base colour (green; 1 in red and blue) */
#define IOR 1.5f

static const float light_tri[9] = {LIGHT_X - LIGHT_S, -LIGHT_S, LIGHT_H,
                                   LIGHT_X + LIGHT_S, -LIGHT_S, LIGHT_H,
                                   LIGHT_X,           LIGHT_S,  LIGHT_H};

static uint32_t add_mat(pt_scene_builder *b, const pt_material *m)
{
    uint32_t i = 0;
    pt_error err = {0};
    CHECKF(pt_scene_builder_add_material(b, m, &i, &err) == PT_OK, "%s", err.msg);
    return i;
}

/* How the sheet is made: a mesh, an instance of a prototype (turned a
 * quarter about z and lifted into place), a mesh moving along x over the
 * shutter, or a mesh of alphaMode BLEND with alpha 0.5. */
enum { SHEET_MESH, SHEET_INSTANCE, SHEET_MOVING, SHEET_BLEND };

/* The plane, the sheet and (with_light) the light, seen orthographically
 * from z = 3 over [-half, half]^2. */
static pt_scene *sheet_scene(int with_light, float half, int mode)
{
    pt_error err = {0};
    pt_scene_builder *b = NULL;
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    if (!b)
        return NULL;
    pt_material lam = pt_material_default();
    lam.metallic = 0.0f;
    lam.specular = 0.0f;
    lam.double_sided = 1;
    lam.base_color[0] = lam.base_color[1] = lam.base_color[2] = RHO;
    pt_material gl = pt_material_default();
    gl.metallic = 0.0f;
    gl.roughness = 0.0f;
    gl.transmission = 1.0f;
    gl.thickness = 0.0f;
    gl.ior = IOR;
    gl.double_sided = 1;
    gl.base_color[1] = TINT;
    if (mode == SHEET_BLEND) {
        gl.alpha_mode = PT_ALPHA_BLEND;
        gl.base_color[3] = 0.5f;
    }
    pt_material em = pt_material_default();
    em.metallic = 0.0f;
    em.specular = 0.0f;
    em.double_sided = 0;
    em.base_color[0] = em.base_color[1] = em.base_color[2] = 0.0f;
    em.emissive[0] = em.emissive[1] = em.emissive[2] = LE;
    uint32_t ml = add_mat(b, &lam), mg = add_mat(b, &gl), me = add_mat(b, &em);
    const float R = 200.0f;
    const float plane[12] = {-R, -R, 0, R, -R, 0, R, R, 0, -R, R, 0};
    const float sheet[12] = {-R, -R, SHEET_H, R, -R, SHEET_H, R, R, SHEET_H, -R, R, SHEET_H};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "plane", plane, NULL, NULL, 4, idx, 2, NULL, ml, &err) ==
          PT_OK);
    if (with_light) {
        /* Wound to face down (-z), its emitting side. */
        const uint32_t down[3] = {0, 2, 1};
        CHECK(pt_scene_builder_add_mesh(b, "light", light_tri, NULL, NULL, 3, down, 1, NULL, me,
                                        &err) == PT_OK);
    }
    if (mode == SHEET_INSTANCE) {
        const float flat[12] = {-R, -R, 0, R, -R, 0, R, R, 0, -R, R, 0};
        uint32_t proto = 0;
        CHECK(pt_scene_builder_begin_prototype(b, &proto, &err) == PT_OK);
        CHECK(pt_scene_builder_add_mesh(b, "sheet", flat, NULL, NULL, 4, idx, 2, NULL, mg, &err) ==
              PT_OK);
        CHECK(pt_scene_builder_end_prototype(b, &err) == PT_OK);
        const double x[16] = {0, 1, 0, 0, -1, 0, 0, 0, 0, 0, 1, 0, 0, 0, SHEET_H, 1};
        CHECKF(pt_scene_builder_add_instance(b, proto, x, &err) == PT_OK, "%s", err.msg);
    } else if (mode == SHEET_MOVING) {
        float pos[2][12];
        const float *pp[2] = {pos[0], pos[1]};
        for (int k = 0; k < 2; k++)
            for (int v = 0; v < 4; v++) {
                pos[k][3 * v] = sheet[3 * v] + (k ? 1.0f : -1.0f);
                pos[k][3 * v + 1] = sheet[3 * v + 1];
                pos[k][3 * v + 2] = sheet[3 * v + 2];
            }
        CHECK(pt_scene_builder_add_mesh_motion(b, "sheet", 2, pp, NULL, NULL, 4, idx, 2, mg,
                                               &err) == PT_OK);
    } else {
        CHECK(pt_scene_builder_add_mesh(b, "sheet", sheet, NULL, NULL, 4, idx, 2, NULL, mg, &err) ==
              PT_OK);
    }
    pt_camera cam = pt_test_ortho_down(0, 0, 3, half);
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene_opts o = {0};
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, &o, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

/* The direct light at plane point (x, y) through the sheet, by quadrature
 * over the light triangle (m x m sub-triangles' midpoints):
 * rho / pi  int Le T(theta) cos_p cos_l / d^2 dA, in green. */
static double direct_at(double x, double y)
{
    const int m = 48;
    const double *v = NULL;
    double tri[9];
    for (int k = 0; k < 9; k++)
        tri[k] = light_tri[k];
    v = tri;
    double e1[3] = {v[3] - v[0], v[4] - v[1], v[5] - v[2]};
    double e2[3] = {v[6] - v[0], v[7] - v[1], v[8] - v[2]};
    double cx = e1[1] * e2[2] - e1[2] * e2[1], cy = e1[2] * e2[0] - e1[0] * e2[2],
           cz = e1[0] * e2[1] - e1[1] * e2[0];
    double area = 0.5 * sqrt(cx * cx + cy * cy + cz * cz);
    double sum = 0.0;
    int n = 0;
    for (int i = 0; i < m; i++)
        for (int j = 0; j < m - i; j++)
            for (int up = 0; up < 2; up++) {
                if (up && j == m - i - 1)
                    continue;
                /* The midpoint of the small triangle, in barycentrics. */
                double a = up ? (i + 2.0 / 3.0) / m : (i + 1.0 / 3.0) / m;
                double bb = up ? (j + 2.0 / 3.0) / m : (j + 1.0 / 3.0) / m;
                double px = v[0] + a * e1[0] + bb * e2[0];
                double py = v[1] + a * e1[1] + bb * e2[1];
                double pz = v[2] + a * e1[2] + bb * e2[2];
                double dx = px - x, dy = py - y, dz = pz;
                double d2 = dx * dx + dy * dy + dz * dz, d = sqrt(d2);
                double cp = dz / d; /* the plane's cosine, and the light's */
                double T = TINT * (1.0 - pt_fresnel_dielectric((float)cp, IOR));
                sum += LE * T * cp * cp / d2;
                n++;
            }
    return RHO / PI_D * sum * area / n;
}

typedef struct sample_stats {
    double mean, se, max; /* green, over all samples */
    uint64_t crossings, rejected;
} sample_stats;

static sample_stats render_samples(const pt_scene *s, const pt_env *env, uint32_t side,
                                   uint32_t spp, uint32_t max_depth, uint32_t strategy, int opaque)
{
    sample_stats ss;
    memset(&ss, 0, sizeof ss);
    pt_render_params p;
    pt_render_params_default(&p);
    p.width = p.height = side;
    p.seed = 11;
    p.env = env;
    p.max_depth = max_depth;
    p.light_strategy = strategy;
    p.opaque_thin_glass = (uint32_t)opaque;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    if (!r)
        return ss;
    double sum = 0.0, sq = 0.0;
    uint64_t n = 0;
    pt_render_stats st = {0};
    for (uint32_t y = 0; y < side; y++)
        for (uint32_t x = 0; x < side; x++)
            for (uint32_t i = 0; i < spp; i++) {
                pt_vec3 c = pt_render_sample(r, x, y, i, &st, NULL);
                if (!pt_isfinite3(c)) {
                    ss.rejected++;
                    continue;
                }
                sum += c.y;
                sq += (double)c.y * c.y;
                ss.max = fmax(ss.max, c.y);
                n++;
            }
    ss.mean = sum / (double)n;
    ss.se = sqrt(fmax(sq / (double)n - ss.mean * ss.mean, 0.0) / ((double)n - 1.0));
    ss.crossings = st.crossings;
    pt_renderer_free(r);
    return ss;
}

static const char *const strat_name[3] = {"MIS", "NEE only", "BSDF only"};
static const uint32_t strat[3] = {PT_LIGHT_MIS, PT_LIGHT_NEE_ONLY, PT_LIGHT_BSDF_ONLY};

static const char *const mode_name[4] = {"mesh", "instance", "moving", "BLEND"};

static void closed_form_light(int mode)
{
    const float half = 0.25f;
    const uint32_t side = 8;
    pt_scene *s = sheet_scene(1, half, mode);
    if (!s)
        return;
    CHECK(s->features & PT_FEAT_TRANSMISSION);
    if (mode == SHEET_INSTANCE)
        CHECK(s->features & PT_FEAT_INSTANCES);
    if (mode == SHEET_MOVING)
        CHECK(s->features & PT_FEAT_MOTION);
    /* The expected image mean: the closed form over each pixel (4 x 4
     * points each), through the sheet at normal incidence. */
    double want = 0.0;
    const int sub = 4;
    for (uint32_t py = 0; py < side; py++)
        for (uint32_t px = 0; px < side; px++)
            for (int i = 0; i < sub; i++)
                for (int j = 0; j < sub; j++) {
                    double x = -half + 2.0 * half * (px + (i + 0.5) / sub) / side;
                    double y = -half + 2.0 * half * (py + (j + 0.5) / sub) / side;
                    want += direct_at(x, y);
                }
    want /= (double)(side * side * sub * sub);
    want *= TINT * (1.0 - pt_fresnel_dielectric(1.0f, IOR));
    for (int k = 0; k < 3; k++) {
        /* BSDF sampling finds a light this small rarely: more samples. */
        uint32_t spp = k == 2 ? 8192 : 512;
        sample_stats ss = render_samples(s, NULL, side, spp, 3, strat[k], 0);
        double tol = 5.0 * ss.se + 1e-4 * want;
        printf("plane under glass (%s), small light, %s: %.6f +- %.6f, closed form %.6f, "
               "max %.4f\n",
               mode_name[mode], strat_name[k], ss.mean, ss.se, want, ss.max);
        CHECK(ss.rejected == 0);
        CHECKF(fabs(ss.mean - want) <= tol, "%s: %.6f, closed form %.6f (tolerance %.6f)",
               strat_name[k], ss.mean, want, tol);
        if (strat[k] != PT_LIGHT_BSDF_ONLY)
            CHECKF(ss.crossings > 0, "%s: no shadow ray crossed the sheet", strat_name[k]);
    }
    pt_scene_free(s);
}

static void fireflies(int mode)
{
    const float half = 0.25f;
    pt_scene *s = sheet_scene(1, half, mode);
    if (!s)
        return;
    /* Light area A and the bound derived in the header comment. */
    double A = 0.5 * (2.0 * LIGHT_S) * (2.0 * LIGHT_S);
    double cam = TINT * (1.0 - pt_fresnel_dielectric(1.0f, IOR));
    double bound = 1.5 * cam * RHO * TINT * LE * A / (PI_D * LIGHT_H * LIGHT_H);
    sample_stats nw = render_samples(s, NULL, 8, 1024, 3, PT_LIGHT_MIS, 0);
    sample_stats old = render_samples(s, NULL, 8, 1024, 3, PT_LIGHT_MIS, 1);
    printf("largest sample: %.4f with NEE through the sheet, %.4f without; bound %.4f\n", nw.max,
           old.max, bound);
    CHECKF(nw.max <= bound, "largest sample %.4f over the bound %.4f", nw.max, bound);
    /* The check can fail: without the shadow rays through the sheet the
     * light is found by the BSDF alone. */
    CHECKF(old.max > bound, "without NEE through glass the largest sample %.4f is under %.4f",
           old.max, bound);
    CHECK(old.crossings == 0);
    /* And the estimate is better for it: same mean, a smaller error. */
    CHECKF(nw.se < 0.5 * old.se, "standard error %.6f with, %.6f without", nw.se, old.se);
    pt_scene_free(s);
}

static void closed_form_env(int mode)
{
    const float L = 0.7f;
    pt_env *env = NULL;
    pt_error err = {0};
    CHECK(pt_env_uniform(pt_v3(L, L, L), &env, &err) == PT_OK);
    pt_scene *s = sheet_scene(0, 0.25f, mode);
    if (!s || !env) {
        pt_env_free(env);
        pt_scene_free(s);
        return;
    }
    /* r = 2 int_0^1 F(mu) mu dmu by Simpson's rule (F is smooth). */
    const int n = 20000;
    double r = 0.0;
    for (int i = 0; i <= n; i++) {
        double mu = (double)i / n;
        double w = (i == 0 || i == n) ? 1.0 : (i % 2 ? 4.0 : 2.0);
        r += w * pt_fresnel_dielectric((float)mu, IOR) * mu;
    }
    r = 2.0 * r / (3.0 * n);
    double lp = RHO * TINT * (1.0 - r) * L / (1.0 - RHO * r);
    double f0 = pt_fresnel_dielectric(1.0f, IOR);
    double want = f0 * L + TINT * (1.0 - f0) * lp;
    for (int k = 0; k < 3; k++) {
        sample_stats ss = render_samples(s, env, 8, 256, PT_RENDER_DEFAULT_MAX_DEPTH, strat[k], 0);
        /* The sheet is finite (200 around a view 0.5 above): light from
         * below 0.15 degrees of the horizon is missing, under 1e-5. */
        double tol = 5.0 * ss.se + 1e-4 * want;
        printf("plane under glass (%s), uniform sky, %s: %.6f +- %.6f, closed form %.6f\n",
               mode_name[mode], strat_name[k], ss.mean, ss.se, want);
        CHECK(ss.rejected == 0);
        CHECKF(fabs(ss.mean - want) <= tol, "%s: %.6f, closed form %.6f (tolerance %.6f)",
               strat_name[k], ss.mean, want, tol);
    }
    pt_scene_free(s);
    pt_env_free(env);
}

/* ---- more walls than a shadow ray crosses ---- */

/* A Lambert plane under n clear sheets (0.05 apart from 0.5 up), seen
 * orthographically from between them and the plane, under a uniform sky. */
static pt_scene *stack_scene(int n)
{
    pt_error err = {0};
    pt_scene_builder *b = NULL;
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    if (!b)
        return NULL;
    pt_material lam = pt_material_default();
    lam.metallic = 0.0f;
    lam.specular = 0.0f;
    lam.double_sided = 1;
    lam.base_color[0] = lam.base_color[1] = lam.base_color[2] = RHO;
    pt_material gl = pt_material_default();
    gl.metallic = 0.0f;
    gl.roughness = 0.0f;
    gl.transmission = 1.0f;
    gl.ior = IOR;
    gl.double_sided = 1;
    uint32_t ml = add_mat(b, &lam), mg = add_mat(b, &gl);
    const float R = 200.0f;
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    const float plane[12] = {-R, -R, 0, R, -R, 0, R, R, 0, -R, R, 0};
    CHECK(pt_scene_builder_add_mesh(b, "plane", plane, NULL, NULL, 4, idx, 2, NULL, ml, &err) ==
          PT_OK);
    for (int k = 0; k < n; k++) {
        float z = 0.5f + 0.05f * (float)k;
        const float sh[12] = {-R, -R, z, R, -R, z, R, R, z, -R, R, z};
        CHECK(pt_scene_builder_add_mesh(b, "sheet", sh, NULL, NULL, 4, idx, 2, NULL, mg, &err) ==
              PT_OK);
    }
    pt_camera cam = pt_test_ortho_down(0, 0, 0.3f, 0.25f);
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene_opts o = {0};
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, &o, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

/* Past PT_SHADOW_CROSSINGS walls NEE is blocked (and counted) while BSDF
 * sampling counts what it finds in full: the strategies still agree. */
static void crossing_cap(void)
{
    pt_error err = {0};
    pt_env *env = NULL;
    CHECK(pt_env_uniform(pt_v3(0.7f, 0.7f, 0.7f), &env, &err) == PT_OK);
    pt_scene *s = stack_scene((int)PT_SHADOW_CROSSINGS + 2);
    if (!s || !env) {
        pt_scene_free(s);
        pt_env_free(env);
        return;
    }
    sample_stats ss[3];
    pt_render_params p;
    pt_render_params_default(&p);
    p.width = p.height = 8;
    p.seed = 3;
    p.env = env;
    for (int k = 0; k < 3; k++)
        ss[k] = render_samples(s, env, 8, 1024, PT_RENDER_DEFAULT_MAX_DEPTH, strat[k], 0);
    /* The dropped count, from a render of its own. */
    pt_renderer *r = NULL;
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    pt_render_stats st = {0};
    for (uint32_t i = 0; r && i < 256; i++)
        pt_render_sample(r, i % 8, (i / 8) % 8, i, &st, NULL);
    pt_renderer_free(r);
    printf("%u sheets: MIS %.6f +- %.6f, NEE only %.6f +- %.6f, BSDF only %.6f +- %.6f; "
           "%llu shadow rays blocked by the cap\n",
           PT_SHADOW_CROSSINGS + 2, ss[0].mean, ss[0].se, ss[1].mean, ss[1].se, ss[2].mean,
           ss[2].se, (unsigned long long)st.dropped);
    CHECK(st.dropped > 0 && st.crossings > 0);
    for (int k = 0; k < 2; k++) {
        double tol = 5.0 * sqrt(ss[k].se * ss[k].se + ss[2].se * ss[2].se);
        CHECKF(fabs(ss[k].mean - ss[2].mean) <= tol, "%s %.6f, BSDF only %.6f (tolerance %.6f)",
               strat_name[k], ss[k].mean, ss[2].mean, tol);
    }
    pt_scene_free(s);
    pt_env_free(env);
}

/* ---- the assets: new against old, paired per block ---- */

/* Renders side x side at spp with and without the shadow rays through thin
 * glass (the same random numbers) and counts the 4 x 4 blocks whose mean
 * paired difference in any channel is more than z_max standard errors from
 * 0; z_max is the two-sided 0.001 quantile Bonferroni-split over the
 * blocks' channels. */
static void paired_blocks(const char *name, const pt_scene *s, const pt_env *env, uint32_t side,
                          uint32_t spp)
{
    pt_render_params p;
    pt_render_params_default(&p);
    p.width = p.height = side;
    p.seed = 5;
    p.env = env;
    pt_renderer *rn = NULL, *ro = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &rn, &err) == PT_OK, "%s", err.msg);
    p.opaque_thin_glass = 1;
    CHECKF(pt_renderer_new(s, &p, &ro, &err) == PT_OK, "%s", err.msg);
    if (!rn || !ro) {
        pt_renderer_free(rn);
        pt_renderer_free(ro);
        return;
    }
    paired_result pr = paired_blocks_z(name, rn, ro, side, 4, spp, 0.0);
    printf("%s: %u of %u block channels differ (|z| > %.2f; largest %.2f); %llu walls "
           "crossed\n",
           name, pr.bad, pr.tests, pr.z_bound, pr.z_max, (unsigned long long)pr.sa.crossings);
    CHECK(pr.nonfinite == 0);
    CHECKF(pr.bad == 0, "%s: %u block channels differ", name, pr.bad);
    CHECKF(pr.sa.crossings > 0, "%s: no shadow ray crossed thin glass", name);
    CHECK(pr.sb.crossings == 0);
    pt_renderer_free(rn);
    pt_renderer_free(ro);
}

/* A BLEND sheet of alpha 0.5: shadow rays pass it where their key says
 * (as the old ones did) and cross the glass elsewhere; paired against the
 * old estimator under a uniform sky (where it has no heavy tail). */
static void blend_sheet(void)
{
    pt_error err = {0};
    pt_env *env = NULL;
    CHECK(pt_env_uniform(pt_v3(0.7f, 0.7f, 0.7f), &env, &err) == PT_OK);
    pt_scene *s = sheet_scene(0, 0.25f, SHEET_BLEND);
    if (s && env) {
        CHECK(s->features & PT_FEAT_ALPHA);
        paired_blocks("BLEND sheet", s, env, 16, 512);
    }
    pt_scene_free(s);
    pt_env_free(env);
}

static void assets(void)
{
    pt_error err = {0};
    pt_env *env = NULL;
    CHECK(pt_env_uniform(pt_v3(0.5f, 0.5f, 0.5f), &env, &err) == PT_OK);
    pt_scene *s = load_shared_asset("TransmissionTest/TransmissionTest.glb", "transmission");
    if (s) {
        paired_blocks("TransmissionTest", s, env, 32, 256);
        pt_scene_free(s);
    }
    s = load_shared_asset("ToyCar/ToyCar.gltf", "transmission");
    if (s) {
        paired_blocks("ToyCar", s, env, 32, 1024);
        pt_scene_free(s);
    }
    pt_env_free(env);
}

int main(void)
{
    closure_straight();
    closed_form_light(SHEET_MESH);
    fireflies(SHEET_MESH);
    closed_form_env(SHEET_MESH);
    /* Through an instance's transform, and a sheet that moves in its own
     * plane (the same closed forms: it covers the view all the time). */
    for (int mode = SHEET_INSTANCE; mode <= SHEET_MOVING; mode++) {
        closed_form_light(mode);
        closed_form_env(mode);
    }
    blend_sheet();
    crossing_cap();
    assets();
    return check_report();
}
