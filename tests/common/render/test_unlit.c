/*
 * test_unlit.c - KHR_materials_unlit: a surface shows its base colour
 * whatever the lighting (common/render/render.c, shade_unlit).
 *
 * - A quad of an unlit material fills the view; rendered with no light, an
 *   emitter above the camera, a uniform environment of radiance 5, a point
 *   light, and all of them at once, every pixel's mean is the base colour
 *   (each sample is that colour exactly: the tolerance is the fixed-point
 *   rounding of the sums, far below 1e-6). With a base-colour texture and
 *   COLOR_0 the colour is factor x texel x vertex colour, the texel read
 *   with pt_texture_sample. Without the extension the same quad under no
 *   light is black and under the lights is not its base colour.
 * - Indirect: a Lambert floor of albedo rho under a 2000 x 2000 unlit
 *   ceiling of colour c at height 1 (it fills all but ~1e-6 of the floor's
 *   cosine-weighted hemisphere) and no light reflects rho x c: each sample's
 *   weight is rho and its bounce sees c, so every pixel is rho x c.
 * - A builder material that is unlit and emissive loses its emission (the
 *   extension ignores it): the scene has no emitter.
 * - UnlitTest (../shared/scenes): both materials load unlit with no warning,
 *   the scene has PT_FEAT_UNLIT, and on a transparent film the image under
 *   a uniform environment of 0.2 and of 7 is the same bits, its fully
 *   covered pixels the orange or the blue base colour (skipped without
 *   ../shared; a failure under CI=true).
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/env.h"
#include "common/render/render.h"
#include "common/scene/scene.h"
#include "tests/check.h"
#include "tests/common/render/paired.h"

#define SIDE 16u
#define SPP 16u

enum { LIGHT_EMITTER = 1, LIGHT_ENV = 2, LIGHT_POINT = 4 };

typedef struct quad_setup {
    int unlit;
    int textured; /* a 1 x 1 sRGB base-colour texture and COLOR_0 */
    int lights;   /* LIGHT_* */
} quad_setup;

static const float BASE[3] = {0.3f, 0.6f, 0.9f};
static const uint8_t TEXEL[4] = {128, 200, 64, 255};
static const float VCOL[3] = {0.5f, 0.25f, 1.0f};

static void add_camera(pt_scene_builder *b, float z, float yfov)
{
    pt_error err = {0};
    pt_camera cam = {0};
    cam.position = pt_v3(0, 0, z);
    cam.forward = pt_v3(0, 0, -1);
    cam.right = pt_v3(1, 0, 0);
    cam.up = pt_v3(0, 1, 0);
    cam.yfov = yfov;
    cam.aspect = 1.0f;
    snprintf(cam.name, sizeof cam.name, "down");
    CHECKF(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK, "%s", err.msg);
}

static pt_scene *build_quad(const quad_setup *su)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    memcpy(m.base_color, BASE, sizeof BASE);
    m.metallic = 0.0f;
    m.roughness = 0.5f;
    m.double_sided = 1;
    m.unlit = su->unlit;
    if (su->textured) {
        pt_texture t = {0};
        t.width = t.height = 1;
        t.rgba = pt_malloc(4);
        if (t.rgba)
            memcpy(t.rgba, TEXEL, 4);
        t.srgb = 1;
        uint32_t ti = 0;
        CHECK(pt_scene_builder_add_texture(b, &t, &ti, &err) == PT_OK);
        m.base_color_tex = (int32_t)ti;
    }
    uint32_t mi = 0, li = 0;
    CHECK(pt_scene_builder_add_material(b, &m, &mi, &err) == PT_OK);
    pt_material lm = pt_material_default();
    lm.base_color[0] = lm.base_color[1] = lm.base_color[2] = 0.0f;
    lm.emissive[0] = lm.emissive[1] = lm.emissive[2] = 4.0f;
    lm.metallic = lm.specular = 0.0f;
    lm.double_sided = 1;
    CHECK(pt_scene_builder_add_material(b, &lm, &li, &err) == PT_OK);
    const float Q = 10.0f;
    const float quad[12] = {-Q, -Q, 0, Q, -Q, 0, Q, Q, 0, -Q, Q, 0};
    const float uv[8] = {0, 0, 1, 0, 1, 1, 0, 1};
    float col[16];
    for (int i = 0; i < 4; i++) {
        memcpy(&col[4 * i], VCOL, sizeof VCOL);
        col[4 * i + 3] = 1.0f;
    }
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    pt_mesh_extra ex = {NULL, NULL, su->textured ? col : NULL};
    CHECKF(pt_scene_builder_add_mesh_extra(b, "quad", quad, NULL, su->textured ? uv : NULL, &ex, 4,
                                           idx, 2, NULL, mi, &err) == PT_OK,
           "%s", err.msg);
    if (su->lights & LIGHT_EMITTER) {
        /* Above the camera, facing down: lights the quad, out of view. */
        const float e[12] = {-2, -2, 20, 2, -2, 20, 2, 2, 20, -2, 2, 20};
        CHECK(pt_scene_builder_add_mesh(b, "lamp", e, NULL, NULL, 4, idx, 2, NULL, li, &err) ==
              PT_OK);
    }
    if (su->lights & LIGHT_POINT) {
        pt_punctual p = {0};
        p.type = PT_PUNCTUAL_POINT;
        p.direction = pt_v3(0, 0, -1);
        p.intensity = pt_v3(50, 50, 50);
        const double pos[3] = {1, 1, 3};
        CHECKF(pt_scene_builder_add_punctual(b, &p, pos, &err) == PT_OK, "%s", err.msg);
    }
    add_camera(b, 5.0f, 0.5f);
    pt_scene_opts o = {0};
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, &o, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

/* Renders s (side x side, spp) into acc (caller's); 0 when it could not. */
static int render(const pt_scene *s, const pt_env *env, int transparent, uint32_t side,
                  pt_pixel_acc *acc)
{
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = p.height = side;
    p.seed = 11;
    p.env = env;
    p.transparent = (uint32_t)transparent;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    if (!r)
        return 0;
    memset(acc, 0, (size_t)side * side * sizeof *acc);
    pt_render_stats st = {0};
    pt_render_tile(r, (pt_rect){0, 0, side, side}, 0, SPP, acc, &st);
    CHECK(st.rejected == 0);
    pt_renderer_free(r);
    return 1;
}

/* The largest |pixel mean - want| over the image, per channel. */
static double worst_error(const pt_pixel_acc *acc, uint32_t n, const double want[3])
{
    double worst = 0.0;
    for (uint32_t i = 0; i < n; i++)
        for (int c = 0; c < 3; c++)
            worst = fmax(worst, fabs(pt_acc_sum(&acc[i], c) / acc[i].n - want[c]));
    return worst;
}

static void quad_under(int unlit, int textured, int lights, pt_pixel_acc *acc, double *worst)
{
    quad_setup su = {unlit, textured, lights};
    pt_scene *s = build_quad(&su);
    pt_env *env = NULL;
    pt_error err = {0};
    if (lights & LIGHT_ENV)
        CHECK(pt_env_uniform(pt_v3(5, 5, 5), &env, &err) == PT_OK);
    double want[3] = {BASE[0], BASE[1], BASE[2]};
    if (textured) {
        float t[4];
        pt_texture_sample(&s->textures[0], 0.5f, 0.5f, t);
        for (int c = 0; c < 3; c++)
            want[c] = (double)(BASE[c] * t[c] * VCOL[c]);
    }
    *worst = INFINITY;
    if (s && render(s, env, 0, SIDE, acc))
        *worst = worst_error(acc, SIDE * SIDE, want);
    if (s && unlit)
        CHECK((s->features & PT_FEAT_UNLIT) && !(s->features & PT_FEAT_GLOSSY));
    pt_env_free(env);
    pt_scene_free(s);
}

static void base_colour_whatever_the_light(void)
{
    pt_pixel_acc *acc = pt_malloc_array(SIDE * SIDE, sizeof *acc);
    if (!acc)
        return;
    const int sets[] = {0, LIGHT_EMITTER, LIGHT_ENV, LIGHT_POINT,
                        LIGHT_EMITTER | LIGHT_ENV | LIGHT_POINT};
    for (int textured = 0; textured < 2; textured++) {
        for (size_t k = 0; k < sizeof sets / sizeof sets[0]; k++) {
            double worst;
            quad_under(1, textured, sets[k], acc, &worst);
            CHECKF(worst < 1e-6, "textured %d lights %d: off the base colour by %g", textured,
                   sets[k], worst);
            /* The control: the same quad lit (or not) as a lit material. */
            quad_under(0, textured, sets[k], acc, &worst);
            CHECKF(worst > 1e-2, "textured %d lights %d: the lit quad shows the base colour too",
                   textured, sets[k]);
        }
    }
    pt_free(acc);
}

/* A Lambert floor under an unlit ceiling: every pixel is rho x c. */
static void lights_by_bounce(void)
{
    const float rho = 0.5f, c[3] = {0.8f, 0.4f, 0.2f};
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material fm = pt_material_default();
    fm.base_color[0] = fm.base_color[1] = fm.base_color[2] = rho;
    fm.metallic = 0.0f;
    fm.specular = 0.0f;
    fm.double_sided = 1;
    pt_material cm = pt_material_default();
    memcpy(cm.base_color, c, sizeof c);
    cm.unlit = 1;
    cm.double_sided = 1;
    uint32_t fi = 0, ci = 0;
    CHECK(pt_scene_builder_add_material(b, &fm, &fi, &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &cm, &ci, &err) == PT_OK);
    const float F = 1000.0f;
    const float floor_[12] = {-F, -F, 0, F, -F, 0, F, F, 0, -F, F, 0};
    const float ceil_[12] = {-F, -F, 1, F, -F, 1, F, F, 1, -F, F, 1};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "floor", floor_, NULL, NULL, 4, idx, 2, NULL, fi, &err) ==
          PT_OK);
    CHECK(pt_scene_builder_add_mesh(b, "ceiling", ceil_, NULL, NULL, 4, idx, 2, NULL, ci, &err) ==
          PT_OK);
    add_camera(b, 0.5f, 0.5f);
    pt_scene_opts o = {0};
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, &o, &s, &err) == PT_OK, "%s", err.msg);
    pt_pixel_acc *acc = pt_malloc_array(SIDE * SIDE, sizeof *acc);
    if (s && acc && render(s, NULL, 0, SIDE, acc)) {
        /* The cosine-weighted share of the hemisphere the ceiling misses
         * at the floor's centre is about (1 / 1000)^2. */
        const double want[3] = {rho * c[0], rho * c[1], rho * c[2]};
        double worst = worst_error(acc, SIDE * SIDE, want);
        CHECKF(worst < 1e-5, "floor off rho x c by %g", worst);
    }
    pt_free(acc);
    pt_scene_free(s);
}

static void emission_ignored(void)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    m.unlit = 1;
    m.emissive[0] = 3.0f;
    uint32_t mi = 0;
    CHECK(pt_scene_builder_add_material(b, &m, &mi, &err) == PT_OK);
    const float quad[12] = {-1, -1, 0, 1, -1, 0, 1, 1, 0, -1, 1, 0};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "quad", quad, NULL, NULL, 4, idx, 2, NULL, mi, &err) ==
          PT_OK);
    pt_scene_opts o = {0};
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, &o, &s, &err) == PT_OK, "%s", err.msg);
    if (s) {
        CHECK(!(s->features & PT_FEAT_EMITTERS));
        CHECK(s->materials[0].emissive[0] == 0.0f && s->materials[0].unlit == 1);
    }
    pt_scene_free(s);
}

static void unlit_test_asset(void)
{
    pt_scene *s = load_shared_asset("UnlitTest/UnlitTest.glb", "unlit");
    if (!s)
        return;
    pt_error err = {0};
    CHECK(s->features & PT_FEAT_UNLIT);
    CHECK(s->num_materials == 2);
    for (uint32_t i = 0; i < s->num_materials; i++)
        CHECK(s->materials[i].unlit == 1);
    const uint32_t side = 32;
    pt_pixel_acc *a = pt_malloc_array(side * side, sizeof *a);
    pt_pixel_acc *bb = pt_malloc_array(side * side, sizeof *bb);
    pt_env *dim = NULL, *bright = NULL;
    CHECK(pt_env_uniform(pt_v3(0.2f, 0.2f, 0.2f), &dim, &err) == PT_OK);
    CHECK(pt_env_uniform(pt_v3(7, 7, 7), &bright, &err) == PT_OK);
    if (a && bb && dim && bright && render(s, dim, 1, side, a) && render(s, bright, 1, side, bb)) {
        CHECK(memcmp(a, bb, side * side * sizeof *a) == 0);
    }
    /* Sample by sample: each that meets the model is one of the colours. */
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = p.height = side;
    p.env = bright;
    pt_renderer *r = NULL;
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    uint32_t covered = 0, matched = 0;
    for (uint32_t i = 0; r && i < side * side; i++) {
        for (uint32_t k = 0; k < 4; k++) {
            pt_render_stats st = {0};
            int cov = 0;
            pt_vec3 v = pt_render_sample(r, i % side, i / side, k, &st, &cov);
            if (!cov)
                continue; /* the camera ray left the scene */
            covered++;
            for (uint32_t m = 0; m < s->num_materials; m++) {
                const float *bc = s->materials[m].base_color;
                if (v.x == bc[0] && v.y == bc[1] && v.z == bc[2]) {
                    matched++;
                    break;
                }
            }
        }
    }
    CHECKF(covered > side && matched == covered, "%u samples meet the model, %u see a base colour",
           covered, matched);
    pt_renderer_free(r);
    pt_env_free(dim);
    pt_env_free(bright);
    pt_free(a);
    pt_free(bb);
    pt_scene_free(s);
}

int main(void)
{
    base_colour_whatever_the_light();
    lights_by_bounce();
    emission_ignored();
    unlit_test_asset();
    return check_report();
}
