/*
 * test_punctual.c - punctual lights (KHR_lights_punctual) against closed-form
 * answers, through the whole integrator (pt_render_tile at default settings).
 *
 * Each scene is a large Lambert plane of albedo RHO seen by a camera with a
 * field of view so narrow (1e-4 rad) that the pixel sees one point of it; a
 * point, spot or directional light is the only light. With nothing else in
 * the scene, the only light path is camera -> plane -> light, which NEE takes
 * exactly once per sample, so the estimate has no noise beyond the pixel's
 * footprint (1e-8 relative). The answers:
 * - a point light of intensity I at height h above the foot: RHO / pi * I / h^2;
 * - a directional light of irradiance E on a plane tilted by theta:
 *   RHO / pi * E * cos theta;
 * - a spot light: the point light's value inside its inner cone, zero outside
 *   its outer cone, and between them the README's falloff computed here by
 *   hand in double;
 * - a range r: the point light's value times clamp(1 - (h / r)^4, 0, 1);
 * - the same at scene scales 1e-3 and 1e3 (intensity scales by scale^2).
 * Tolerance 1e-4 relative: float arithmetic, far above the footprint term.
 *
 * The choice between classes: an emissive quad beside the point light. The
 * image with both lights must equal (within 5 standard errors of the noisy
 * renders) the sum of an image with the quad alone and one with the point
 * light alone: a pmf that did not match the probability a light is chosen
 * with, or MIS weights that forgot the triangles' share, bias it.
 */
#include <math.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/render.h"
#include "common/scene/scene.h"
#include "tests/check.h"

#define RHO 0.5
#define PI_D 3.14159265358979323846

typedef struct setup {
    int plane_tilt_deg; /* plane normal tilted about x */
    pt_vec3 look_at;    /* the point the camera looks straight down at */
    int quad;           /* 0: none, 1: a black occluder-free quad, 2: it emits */
    int light;          /* 0: no punctual light */
    pt_punctual l;      /* position in l.position */
    float scale;        /* scene scale (0: 1) */
    uint32_t w, h, spp; /* image */
    float yfov;
} setup;

static pt_scene *build(const setup *su)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    m.base_color[0] = m.base_color[1] = m.base_color[2] = (float)RHO;
    m.metallic = 0.0f;
    m.specular = 0.0f;
    m.double_sided = 1;
    uint32_t plane_mat = 0, quad_mat = 0;
    CHECK(pt_scene_builder_add_material(b, &m, &plane_mat, &err) == PT_OK);
    pt_material q = m;
    q.base_color[0] = q.base_color[1] = q.base_color[2] = 0.0f;
    if (su->quad == 2)
        q.emissive[0] = q.emissive[1] = q.emissive[2] = 2.0f;
    CHECK(pt_scene_builder_add_material(b, &q, &quad_mat, &err) == PT_OK);
    /* The plane: 200 x 200 about the origin, tilted about x. */
    double t = su->plane_tilt_deg * PI_D / 180.0, c = cos(t), s = sin(t);
    const float P = 100.0f;
    float plane[12] = {-P, -P, 0, P, -P, 0, P, P, 0, -P, P, 0};
    for (int i = 0; i < 4; i++) {
        float y = plane[3 * i + 1];
        plane[3 * i + 1] = (float)(y * c);
        plane[3 * i + 2] = (float)(y * s);
    }
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECKF(pt_scene_builder_add_mesh(b, "plane", plane, NULL, NULL, 4, idx, 2, NULL, plane_mat,
                                     &err) == PT_OK,
           "%s", err.msg);
    if (su->quad) {
        /* A 1 x 1 quad at height 1.5, facing down, off to the side. */
        float quad[12] = {1, -0.5f, 1.5f, 1, 0.5f, 1.5f, 2, 0.5f, 1.5f, 2, -0.5f, 1.5f};
        CHECK(pt_scene_builder_add_mesh(b, "quad", quad, NULL, NULL, 4, idx, 2, NULL, quad_mat,
                                        &err) == PT_OK);
    }
    if (su->light) {
        const double pos[3] = {su->l.position.x, su->l.position.y, su->l.position.z};
        CHECKF(pt_scene_builder_add_punctual(b, &su->l, pos, &err) == PT_OK, "%s", err.msg);
    }
    pt_camera cam = {0};
    cam.position = pt_v3_add(su->look_at, pt_v3(0, 0, 10));
    cam.forward = pt_v3(0, 0, -1);
    cam.right = pt_v3(1, 0, 0);
    cam.up = pt_v3(0, 1, 0);
    cam.yfov = su->yfov;
    cam.aspect = 1.0f;
    snprintf(cam.name, sizeof cam.name, "down");
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene_opts o = {0};
    o.scale = su->scale;
    pt_scene *sc = NULL;
    CHECKF(pt_scene_builder_finish(b, &o, &sc, &err) == PT_OK, "%s", err.msg);
    return sc;
}

/* Renders su; returns the mean of the image's green channel and its
 * standard error (from the pixels' sums of squared luminance: the scenes
 * are grey). */
static double render_mean(const setup *su, double *se)
{
    pt_scene *s = build(su);
    if (!s)
        return NAN;
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = su->w;
    p.height = su->h;
    p.seed = 3;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    uint32_t n = su->w * su->h;
    pt_pixel_acc *acc = pt_malloc_array(n, sizeof *acc);
    double sum = 0.0, var = 0.0;
    if (r && acc) {
        if (su->light)
            CHECK(strcmp(pt_renderer_variant(r), "general") == 0);
        pt_render_stats st = {0};
        pt_rect all = {0, 0, su->w, su->h};
        pt_render_tile(r, all, 0, su->spp, acc, &st);
        CHECK(st.rejected == 0);
        for (uint32_t i = 0; i < n; i++) {
            double k = acc[i].n, m = pt_acc_sum(&acc[i], 1) / k;
            double lum = (pt_acc_sum(&acc[i], 0) * 0.2126 + pt_acc_sum(&acc[i], 1) * 0.7152 +
                          pt_acc_sum(&acc[i], 2) * 0.0722) /
                         k;
            double v = (pt_acc_sum_sq(&acc[i]) - k * lum * lum) / (k - 1.0);
            sum += m;
            var += fmax(v, 0.0) / k;
        }
    }
    pt_free(acc);
    pt_renderer_free(r);
    pt_scene_free(s);
    if (se)
        *se = sqrt(var) / n;
    return sum / n;
}

static setup point_setup(float h, float intensity)
{
    setup su;
    memset(&su, 0, sizeof su);
    su.light = 1;
    su.l.type = PT_PUNCTUAL_POINT;
    su.l.position = pt_v3(0, 0, h);
    su.l.direction = pt_v3(0, 0, -1);
    su.l.intensity = pt_v3(intensity, intensity, intensity);
    snprintf(su.l.name, sizeof su.l.name, "bulb");
    su.w = su.h = 2;
    su.spp = 16;
    su.yfov = 1e-4f;
    return su;
}

static void expect_close(const char *what, double got, double want)
{
    double tol = want == 0.0 ? 1e-12 : 1e-4 * fabs(want);
    CHECKF(fabs(got - want) <= tol, "%s: %.8g, expected %.8g", what, got, want);
}

static void point_light(void)
{
    const float h = 2.0f, I = 3.0f;
    setup su = point_setup(h, I);
    double want = RHO / PI_D * I / (h * h);
    expect_close("point light at its foot", render_mean(&su, NULL), want);
    /* Off the foot, at horizontal distance x: cos^3 / h^2. */
    su.look_at = pt_v3(1.5f, 0, 0);
    double d2 = 1.5 * 1.5 + h * h, cos_t = h / sqrt(d2);
    expect_close("point light off its foot", render_mean(&su, NULL), RHO / PI_D * I * cos_t / d2);
    /* Scale: the same picture at 1e-3 and 1e3 (the camera and the light
     * scale with the scene; the intensity by scale^2). */
    su.look_at = pt_v3(0, 0, 0);
    su.scale = 1e-3f;
    expect_close("point light at scale 1e-3", render_mean(&su, NULL), want);
    su.scale = 1e3f;
    expect_close("point light at scale 1e3", render_mean(&su, NULL), want);
    /* A range windows it: clamp(1 - (d / r)^4, 0, 1). */
    su.scale = 0.0f;
    su.l.range = 3.0f;
    double x = h / 3.0;
    expect_close("point light with a range", render_mean(&su, NULL), want * (1.0 - pow(x, 4)));
    su.l.range = 1.5f;
    expect_close("point light beyond its range", render_mean(&su, NULL), 0.0);
}

static void directional_light(void)
{
    for (int tilt = 0; tilt <= 60; tilt += 30) {
        setup su = point_setup(1.0f, 0.0f);
        su.l.type = PT_PUNCTUAL_DIRECTIONAL;
        su.l.intensity = pt_v3(2.0f, 2.0f, 2.0f); /* irradiance */
        su.plane_tilt_deg = tilt;
        char what[64];
        snprintf(what, sizeof what, "directional light on a plane tilted %d deg", tilt);
        expect_close(what, render_mean(&su, NULL), RHO / PI_D * 2.0 * cos(tilt * PI_D / 180.0));
    }
}

static void spot_light(void)
{
    const float h = 2.0f, I = 3.0f;
    const double inner = 0.3, outer = 0.5;
    setup su = point_setup(h, I);
    su.l.type = PT_PUNCTUAL_SPOT;
    su.l.cos_inner = (float)cos(inner);
    su.l.cos_outer = (float)cos(outer);
    double at_foot = RHO / PI_D * I / (h * h);
    expect_close("spot light inside its inner cone", render_mean(&su, NULL), at_foot);
    /* Between the cones, at 0.4 rad off its axis. */
    double a = 0.4, x = h * tan(a), d2 = x * x + h * h;
    double f = (cos(a) - cos(outer)) / (cos(inner) - cos(outer));
    su.look_at = pt_v3((float)x, 0, 0);
    expect_close("spot light between its cones", render_mean(&su, NULL),
                 RHO / PI_D * I * f * f * cos(a) / d2);
    /* Outside the outer cone: nothing. */
    su.look_at = pt_v3((float)(h * tan(0.6)), 0, 0);
    expect_close("spot light outside its outer cone", render_mean(&su, NULL), 0.0);
    /* Pointed away: nothing at the foot either. */
    su.look_at = pt_v3(0, 0, 0);
    su.l.direction = pt_v3(0, 0, 1);
    expect_close("spot light pointed away", render_mean(&su, NULL), 0.0);
}

/* Both classes at once: the quad's light and the bulb's add up. */
static void both_classes(void)
{
    setup su = point_setup(2.0f, 3.0f);
    su.w = su.h = 32;
    su.spp = 1024;
    su.yfov = 1.0f; /* a wide view of the plane under both lights */
    su.quad = 2;
    double se_both, se_quad;
    double both = render_mean(&su, &se_both);
    su.light = 0;
    double quad = render_mean(&su, &se_quad);
    su.light = 1;
    su.quad = 1; /* the same geometry, black: the bulb alone (no noise) */
    double bulb = render_mean(&su, NULL);
    double se = sqrt(se_both * se_both + se_quad * se_quad);
    CHECKF(fabs(both - (quad + bulb)) < 5.0 * se,
           "both lights %.6f, quad %.6f + bulb %.6f = %.6f (standard error %.2e)", both, quad, bulb,
           quad + bulb, se);
    CHECKF(se < 0.01 * both, "standard error %.2e too large for the check", se);
    printf("both classes: %.6f vs %.6f + %.6f, standard error %.2e\n", both, quad, bulb, se);
}

/* What the builder refuses. */
static void refused(void)
{
    pt_error err = {0};
    pt_scene_builder *b = NULL;
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    const double at[3] = {0, 0, 1}, nan_at[3] = {NAN, 0, 0};
    pt_punctual l = point_setup(1.0f, 1.0f).l;
    CHECK(pt_scene_builder_add_punctual(b, &l, at, &err) == PT_OK);
    CHECK(pt_scene_builder_add_punctual(b, &l, nan_at, &err) == PT_ERR_FORMAT);
    pt_punctual bad = l;
    bad.intensity.x = -1.0f;
    CHECK(pt_scene_builder_add_punctual(b, &bad, at, &err) == PT_ERR_FORMAT &&
          strstr(err.msg, "bulb"));
    bad = l;
    bad.intensity.y = NAN;
    CHECK(pt_scene_builder_add_punctual(b, &bad, at, &err) == PT_ERR_FORMAT);
    bad = l;
    bad.direction = pt_v3(0, 0, 0);
    CHECK(pt_scene_builder_add_punctual(b, &bad, at, &err) == PT_ERR_FORMAT);
    bad = l;
    bad.range = -1.0f;
    CHECK(pt_scene_builder_add_punctual(b, &bad, at, &err) == PT_ERR_FORMAT);
    bad = l;
    bad.type = PT_PUNCTUAL_SPOT;
    bad.cos_inner = 0.5f;
    bad.cos_outer = 0.9f; /* inner wider than outer */
    CHECK(pt_scene_builder_add_punctual(b, &bad, at, &err) == PT_ERR_FORMAT);
    pt_scene_builder_free(b);
}

int main(void)
{
    int64_t live0 = pt_alloc_live();
    point_light();
    directional_light();
    spot_light();
    both_classes();
    refused();
    CHECK(pt_alloc_live() == live0);
    return check_report();
}
