/*
 * test_portal.c - environment portals (common/render/portal.c and the
 * environment light's mixture in light.c; PT_FEAT_PORTAL).
 *
 * - Chi-square of the portal sampler against its own density (dir_chi2.h):
 *   a quad of two triangles above the receiver, a triangle behind it that
 *   overlaps part of it as seen from there (directions through both: k = 2),
 *   and one below the receiver's tangent plane, which must take no sample
 *   with the normal given and its share without one; a receiver behind
 *   the fronts of portals (outside the room) counts none of them.
 * - Chi-square of the environment light's samples (pt_lights_sample: the
 *   portals mixed with a map that has a bright patch) against
 *   pt_lights_env_pdf, which MIS weighs BSDF-sampled rays by: the two must
 *   be one density.
 * - Irradiance through a window, in closed form: a black closed box whose
 *   ceiling has a rectangular hole, a Lambert floor (albedo rho), a uniform
 *   sky of radiance L. A floor point's radiance is rho L F, F its form
 *   factor to the hole (the parallel-rectangle formula, summed over the
 *   hole's corners); an orthographic view of the floor averages it. With
 *   the hole a portal, MIS and NEE alone both agree with it (z < 5 on the
 *   image's standard error), as does MIS without the portal; and the
 *   portal's standard error is under half that without it (measured: 0.12
 *   of it).
 * - The rule: the portals go unused where the map's sun can shine in
 *   through one (the sun behind a portal's front), and are used where it
 *   cannot, or where the map has no sun.
 * (Their import from glTF is test_gltf.c's; the farm's bits
 * tests/integration/test_portal_farm.sh's.)
 */
#define N_CHI2_TESTS 3
/* The portals' density is an indicator: its cells' integrals need finer
 * quadrature than a lobe's. */
#define CHI2_SIMPSON_EPS_INNER 1e-9
#define CHI2_SIMPSON_EPS_OUTER 1e-8
#define CHI2_SIMPSON_DEPTH 12
#include "common/render/portal.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/env.h"
#include "common/render/film.h"
#include "common/render/light.h"
#include "common/render/render.h"
#include "common/scene/scene.h"
#include "tests/check.h"
#include "tests/common/render/dir_chi2.h"
#include "tests/common/render/env_mean.h"
#include "tests/common/render/ortho.h"

/* ---- the sampler against its density ---------------------------------------------- */

enum { NTRI = 4 };
static const float tris[NTRI * 9] = {
    /* a quad at y = 1, x in [-0.5, 0.5], z in [-0.3, 0.7] */
    -0.5f, 1.0f, -0.3f, 0.5f, 1.0f, -0.3f, 0.5f, 1.0f, 0.7f, -0.5f, 1.0f, -0.3f, 0.5f, 1.0f, 0.7f,
    -0.5f, 1.0f, 0.7f,
    /* behind it from the origin, over its +x half and past it */
    0.0f, 2.0f, 0.0f, 1.6f, 2.0f, 0.0f, 0.4f, 2.0f, 1.2f,
    /* below the plane y = 0 */
    -1.0f, -1.0f, -1.0f, 0.0f, -1.0f, 1.0f, 1.0f, -1.0f, -1.0f};
/* Their fronts (counter-clockwise sides) face the receivers: the quad's and
 * the one behind it's -y, down to the origin; the one below's +y. */

/* A scene of portals (n triangles, 9 doubles each) and one far triangle (a
 * scene needs geometry). */
static pt_scene *portals_scene(const double *v, int n)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    uint32_t mat = 0;
    CHECK(pt_scene_builder_add_material(b, &m, &mat, &err) == PT_OK);
    const float far[9] = {50, 50, 50, 51, 50, 50, 50, 51, 50};
    const uint32_t idx[3] = {0, 1, 2};
    CHECK(pt_scene_builder_add_mesh(b, "far", far, NULL, NULL, 3, idx, 1, NULL, mat, &err) ==
          PT_OK);
    for (int t = 0; t < n; t++)
        CHECKF(pt_scene_builder_add_portal(b, v + 9 * t, "test", &err) == PT_OK, "%s", err.msg);
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

/* The sampler's portals as they are (a scene holds their fronts), and the
 * view of them from p (world space) with normal n. */
static pt_scene *plain_scene(void)
{
    double v[NTRI * 9];
    for (int i = 0; i < NTRI * 9; i++)
        v[i] = tris[i];
    return portals_scene(v, NTRI);
}

static void view_from(const pt_scene *s, pt_vec3 p, pt_vec3 n, pt_portal_view *v)
{
    pt_vec3 q = pt_v3((float)(p.x - s->origin[0]), (float)(p.y - s->origin[1]),
                      (float)(p.z - s->origin[2]));
    pt_portal_view_init(v, s->portals, s->portal_fronts, s->num_portals, q, n);
}

typedef struct portal_ctx {
    pt_vec3 p, n;
    pt_portal_view v;
} portal_ctx;

static float portal_pdf_fn(const void *ctx, pt_vec3 w)
{
    const portal_ctx *c = ctx;
    pt_portal_view v = c->v;
    return (float)pt_portal_pdf(&v, w);
}

static pt_vec3 portal_sample_fn(const void *ctx, pcg32 *r, float *pdf)
{
    const portal_ctx *c = ctx;
    float u0 = pcg32_float(r), u1 = pcg32_float(r), u2 = pcg32_float(r);
    pt_vec3 wi = pt_v3(0, 0, 1);
    double pd = 0.0;
    pt_portal_view v = c->v;
    *pdf = pt_portal_sample(&v, u0, u1, u2, &wi, &pd) ? (float)pd : 0.0f;
    return wi;
}

static void chi2_portals(void)
{
    pt_scene *s = plain_scene();
    if (!s)
        return;
    portal_ctx c = {.p = pt_v3(0.1f, 0.0f, 0.05f), .n = pt_v3(0, 1, 0)};
    view_from(s, c.p, c.n, &c.v);
    pt_portal_measure(&c.v);
    CHECKF(c.v.om[3] == 0.0 && c.v.om[0] > 0.0 && c.v.om[2] > 0.0,
           "the triangle below the plane counts (%g), or one above does not", c.v.om[3]);
    binning bn = {pt_frame_from_normal(pt_v3(0, 1, 0)), 2.0, portal_pdf_fn, &c};
    double total = chi2_run("portals, above the plane", &bn, portal_sample_fn, &c, 300000, 5);
    /* The overlap: the sampler's density integrates to 1 only where the
     * directions through two triangles count twice. */
    CHECKF(fabs(total - 1.0) < 2e-3, "portals: the density integrates to %.5f", total);

    portal_ctx z = {.p = c.p, .n = pt_v3(0, 0, 0)};
    view_from(s, z.p, z.n, &z.v);
    pt_portal_measure(&z.v);
    CHECKF(z.v.om[3] > 0.0, "without a normal the triangle below takes no share");
    /* Behind the fronts of the quad and of the triangle past it (outside
     * the room): those two take no share, the one below still does. */
    pt_portal_view out;
    view_from(s, pt_v3(0.1f, 3.0f, 0.05f), pt_v3(0, 0, 0), &out);
    CHECKF(out.counted == (UINT64_C(1) << 3), "behind the fronts: counted %#llx, want 0x8",
           (unsigned long long)out.counted);
    binning bz = {pt_frame_from_normal(pt_v3(0, 1, 0)), 2.0, portal_pdf_fn, &z};
    chi2_run("portals, no normal", &bz, portal_sample_fn, &z, 300000, 6);
    pt_scene_free(s);
}

/* ---- the environment light's mixture ----------------------------------------------- */

/* The sampler's portals turned to face the horizon (y and z swapped), away
 * from the map's poles, where its density's quadrature and its float pdf
 * lose digits. */
static pt_scene *portal_scene(void)
{
    double v[NTRI * 9];
    for (int i = 0; i < NTRI * 9; i++)
        v[i] = tris[i + (i % 3 == 1 ? 1 : i % 3 == 2 ? -1 : 0)];
    for (int t = 0; t < NTRI; t++) /* the swap mirrors: two corners swapped keep the fronts */
        for (int k = 0; k < 3; k++) {
            double x = v[9 * t + 3 + k];
            v[9 * t + 3 + k] = v[9 * t + 6 + k];
            v[9 * t + 6 + k] = x;
        }
    return portals_scene(v, NTRI);
}

/* A 64 x 32 map: a sky that brightens towards the zenith, black within 4
 * rows of the poles, and a 3 x 3 patch 30 times brighter near the
 * portals' side (smooth enough for the quadrature of its cells). */
static pt_env *patch_sky(void)
{
    enum { W = 64, H = 32 };
    static float px[W * H * 3];
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++)
            for (int c = 0; c < 3; c++)
                px[3 * (y * W + x) + c] = y < 4 || y >= H - 4 ? 0.0f
                                          : abs(x - 58) <= 1 && abs(y - 12) <= 1
                                              ? 30.0f
                                              : 1.0f + 2.0f * (H - y) / H;
    pt_env *env = NULL;
    pt_error err = {0};
    CHECKF(pt_env_new(&(pt_envmap){W, H, px}, 1.0f, 0.0f, &env, &err) == PT_OK, "%s", err.msg);
    return env;
}

typedef struct light_ctx {
    const pt_lights *L;
    const pt_scene *s;
    pt_vec3 p, n;
} light_ctx;

static float light_pdf_fn(const void *ctx, pt_vec3 w)
{
    const light_ctx *c = ctx;
    return pt_lights_env_pdf(c->L, w, c->p, c->n);
}

static pt_vec3 light_sample_fn(const void *ctx, pcg32 *r, float *pdf)
{
    const light_ctx *c = ctx;
    float u[3] = {pcg32_float(r), pcg32_float(r), pcg32_float(r)};
    pt_light_sample ls;
    *pdf = pt_lights_sample(c->L, c->s, c->p, c->n, u, &ls) ? ls.pdf : 0.0f;
    return ls.wi;
}

static void chi2_mixture(void)
{
    pt_scene *s = portal_scene();
    pt_env *env = patch_sky();
    pt_lights *L = NULL;
    pt_error err = {0};
    if (s && env)
        CHECKF(pt_lights_new_env(s, env, PT_ENV_FULL, &L, &err) == PT_OK, "%s", err.msg);
    if (L) {
        CHECK(pt_lights_has_portals(L));
        /* The receiver in scene space (the far triangle moves its origin). */
        pt_vec3 p = pt_v3((float)(0.1 - s->origin[0]), (float)(0.05 - s->origin[1]),
                          (float)(0.0 - s->origin[2]));
        light_ctx c = {L, s, p, pt_v3(0, 0, 1)};
        pt_portal_view v;
        pt_portal_view_init(&v, s->portals, s->portal_fronts, s->num_portals, p, c.n);
        CHECKF(v.counted == 7, "the receiver counts portals %#llx, want 0x7",
               (unsigned long long)v.counted);
        binning bn = {pt_frame_from_normal(pt_v3(0, 0, 1)), 2.0, light_pdf_fn, &c};
        chi2_run("environment through portals", &bn, light_sample_fn, &c, 300000, 7);
    }
    pt_lights_free(L);
    pt_env_free(env);
    pt_scene_free(s);
}

/* ---- a sun that shines in -------------------------------------------------------- */

/* One portal quad in the plane z = 0, its front towards +z (front 1) or
 * -z. */
static pt_scene *quad_scene(int front)
{
    /* counter-clockwise seen from +z: its front faces +z */
    double q[2][9] = {{-1, -1, 0, 1, -1, 0, 1, 1, 0}, {-1, -1, 0, 1, 1, 0, -1, 1, 0}};
    for (int i = 0; i < 2 && !front; i++) /* two corners swapped: the other side */
        for (int k = 0; k < 3; k++) {
            double t = q[i][3 + k];
            q[i][3 + k] = q[i][6 + k];
            q[i][6 + k] = t;
        }
    return portals_scene(&q[0][0], 2);
}

/* The portals are used unless the map's sun can shine in through one:
 * a sun towards -z (the map's centre column, at the horizon) is behind a
 * portal whose front faces +z (into the room), in front of one that faces
 * -z; a map without a sun uses them either way. */
static void sun_rule(void)
{
    enum { W = 64, H = 32 };
    static float px[W * H * 3];
    for (int i = 0; i < W * H; i++)
        for (int c = 0; c < 3; c++)
            px[3 * i + c] = i == (H / 2) * W + W / 2 ? 5e4f : 1.0f;
    pt_env *sun = NULL, *sky = NULL;
    pt_error err = {0};
    CHECKF(pt_env_new(&(pt_envmap){W, H, px}, 1.0f, 0.0f, &sun, &err) == PT_OK, "%s", err.msg);
    CHECK(pt_env_uniform(pt_v3(1, 1, 1), &sky, &err) == PT_OK);
    pt_vec3 axis;
    float sh;
    CHECK(sun && pt_env_sun(sun, &axis, &sh) && axis.z < -0.99f && sh > 0.0f && sh < 0.2f);
    for (int front = 0; front < 2; front++) {
        pt_scene *s = quad_scene(front);
        for (int k = 0; s && sun && sky && k < 2; k++) {
            pt_lights *L = NULL;
            CHECKF(pt_lights_new_env(s, k ? sky : sun, PT_ENV_MIS, &L, &err) == PT_OK, "%s",
                   err.msg);
            int want = k == 1 || front == 0;
            CHECKF(pt_lights_has_portals(L) == want, "front %s, %s: portals %s, want %s",
                   front ? "+z" : "-z", k ? "no sun" : "a sun towards -z",
                   pt_lights_has_portals(L) ? "used" : "unused", want ? "used" : "unused");
            pt_lights_free(L);
        }
        pt_scene_free(s);
    }
    pt_env_free(sun);
    pt_env_free(sky);
}

/* ---- irradiance through a window ---------------------------------------------------- */

/* The box: x and y in [-1, 1], z in [0, 1]; the hole in the ceiling. */
static const double HX0 = -0.2, HX1 = 0.3, HY0 = -0.25, HY1 = 0.25;

static void add_quad(pt_scene_builder *b, const char *what, const float q[12], uint32_t mat)
{
    pt_error err = {0};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECKF(pt_scene_builder_add_mesh(b, what, q, NULL, NULL, 4, idx, 2, NULL, mat, &err) == PT_OK,
           "%s", err.msg);
}

/* The box with its hole: portal 0 none, 1 the hole a portal facing down
 * into the box, 2 the same wound the wrong way (facing up); pane: a glass
 * pane over the hole, outside the box. */
static pt_scene *window_box_ex(float rho, int portal, int pane)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    m.metallic = 0.0f;
    m.specular = 0.0f;
    m.double_sided = 1;
    m.base_color[0] = m.base_color[1] = m.base_color[2] = rho;
    uint32_t floor_mat = 0, black = 0;
    CHECK(pt_scene_builder_add_material(b, &m, &floor_mat, &err) == PT_OK);
    m.base_color[0] = m.base_color[1] = m.base_color[2] = 0.0f;
    CHECK(pt_scene_builder_add_material(b, &m, &black, &err) == PT_OK);
    const float x0 = (float)HX0, x1 = (float)HX1, y0 = (float)HY0, y1 = (float)HY1;
    const float fl[12] = {-1, -1, 0, 1, -1, 0, 1, 1, 0, -1, 1, 0};
    add_quad(b, "floor", fl, floor_mat);
    const float walls[4][12] = {{-1, -1, 0, 1, -1, 0, 1, -1, 1, -1, -1, 1},
                                {-1, 1, 0, 1, 1, 0, 1, 1, 1, -1, 1, 1},
                                {-1, -1, 0, -1, 1, 0, -1, 1, 1, -1, -1, 1},
                                {1, -1, 0, 1, 1, 0, 1, 1, 1, 1, -1, 1}};
    for (int i = 0; i < 4; i++)
        add_quad(b, "wall", walls[i], black);
    /* The ceiling around the hole: four rectangles. */
    const float ceil[4][12] = {{-1, -1, 1, 1, -1, 1, 1, y0, 1, -1, y0, 1},
                               {-1, y1, 1, 1, y1, 1, 1, 1, 1, -1, 1, 1},
                               {-1, y0, 1, x0, y0, 1, x0, y1, 1, -1, y1, 1},
                               {x1, y0, 1, 1, y0, 1, 1, y1, 1, x1, y1, 1}};
    for (int i = 0; i < 4; i++)
        add_quad(b, "ceiling", ceil[i], black);
    if (portal) {
        /* its front down, into the box (portal 1), or up */
        double q[2][9] = {{HX0, HY0, 1, HX1, HY1, 1, HX1, HY0, 1},
                          {HX0, HY0, 1, HX0, HY1, 1, HX1, HY1, 1}};
        for (int i = 0; i < 2 && portal == 2; i++)
            for (int k = 0; k < 3; k++) {
                double t = q[i][3 + k];
                q[i][3 + k] = q[i][6 + k];
                q[i][6 + k] = t;
            }
        for (int i = 0; i < 2; i++)
            CHECKF(pt_scene_builder_add_portal(b, q[i], "hole", &err) == PT_OK, "%s", err.msg);
    }
    if (pane) {
        pt_material g = pt_material_default();
        g.transmission = 1.0f;
        uint32_t glass = 0;
        CHECK(pt_scene_builder_add_material(b, &g, &glass, &err) == PT_OK);
        const float q[12] = {-0.5f, -0.5f, 1.05f, 0.5f,  -0.5f, 1.05f,
                             0.5f,  0.5f,  1.05f, -0.5f, 0.5f,  1.05f};
        add_quad(b, "pane", q, glass);
    }
    pt_camera cam = pt_test_ortho_down(0.0f, 0.0f, 0.9f, 0.8f);
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

static pt_scene *window_box(float rho, int portal)
{
    return window_box_ex(rho, portal, 0);
}

/* ---- which way a portal faces ------------------------------------------------- */

/* The hole's portal facing into the box has the box in front (no probe
 * leaves) and the sky behind (every probe leaves); wound the wrong way,
 * the reverse, and pt_portal_reversed counts both of its triangles. A
 * glass pane over the hole is seen through. */
static void reversed_portals(void)
{
    for (int pane = 0; pane < 2; pane++)
        for (int portal = 1; portal <= 2; portal++) {
            pt_scene *s = window_box_ex(0.5f, portal, pane);
            if (!s)
                continue;
            float open[4] = {-1, -1, -1, -1};
            pt_error err = {0};
            CHECKF(pt_portal_openness(s, open, &err) == PT_OK, "%s", err.msg);
            float in = portal == 1 ? open[0] : open[1], out = portal == 1 ? open[1] : open[0];
            CHECKF(in == 0.0f && out == 1.0f && open[0] == open[2] && open[1] == open[3],
                   "portal %d, pane %d: the box's side %g open, the sky's %g", portal, pane, in,
                   out);
            uint32_t n = 99;
            pt_vec3 f;
            CHECKF(pt_portal_reversed(s, &n, &f, &err) == PT_OK, "%s", err.msg);
            CHECKF(n == (portal == 2 ? 2u : 0u) && f.z == (portal == 2 ? 1.0f : 0.0f),
                   "portal %d, pane %d: %u reversed, front z %g", portal, pane, n, f.z);
            pt_scene_free(s);
        }
    pt_scene *none = window_box(0.5f, 0);
    uint32_t n = 99;
    pt_vec3 f;
    pt_error err = {0};
    CHECK(none && pt_portal_reversed(none, &n, &f, &err) == PT_OK && n == 0);
    pt_scene_free(none);
}

/* A corner's term of the form factor from a floor point to a parallel
 * rectangle at height 1 (signed extents a, b from the point): Howell's
 * catalogue, configuration B-3, odd in a and in b, so the hole's factor is
 * the signed sum over its corners. */
static double corner_term(double a, double b)
{
    double sa = sqrt(1.0 + a * a), sb = sqrt(1.0 + b * b);
    return (a / sa * atan(b / sa) + b / sb * atan(a / sb)) / (2.0 * PI_D);
}

static double hole_factor(double x, double y)
{
    return corner_term(HX1 - x, HY1 - y) - corner_term(HX0 - x, HY1 - y) -
           corner_term(HX1 - x, HY0 - y) + corner_term(HX0 - x, HY0 - y);
}

static void window_irradiance(void)
{
    const float rho = 0.5f, L = 2.0f;
    /* The view: x and y in [-0.8, 0.8]; the factor's mean over it by the
     * midpoint rule on a 400 x 400 grid (smooth: far below the noise). */
    const int G = 400;
    double f = 0.0;
    for (int j = 0; j < G; j++)
        for (int i = 0; i < G; i++)
            f += hole_factor(-0.8 + 1.6 * (i + 0.5) / G, -0.8 + 1.6 * (j + 0.5) / G);
    double want = rho * L * f / ((double)G * G);
    pt_env *env = NULL;
    pt_error err = {0};
    CHECK(pt_env_uniform(pt_v3(L, L, L), &env, &err) == PT_OK);
    pt_scene *with = window_box(rho, 1), *without = window_box(rho, 0);
    if (env && with && without) {
        CHECK((with->features & PT_FEAT_PORTAL) && !(without->features & PT_FEAT_PORTAL));
        double se_m, se_n, se_0;
        double mis = render_mean(with, env, PT_LIGHT_MIS, 32, 64, &se_m);
        double nee = render_mean(with, env, PT_LIGHT_NEE_ONLY, 32, 64, &se_n);
        double none = render_mean(without, env, PT_LIGHT_MIS, 32, 64, &se_0);
        printf("window: want %.5f; portal MIS %.5f (se %.2e), NEE %.5f (se %.2e); "
               "no portal %.5f (se %.2e): se ratio %.3f\n",
               want, mis, se_m, nee, se_n, none, se_0, se_m / se_0);
        CHECKF(fabs(mis - want) < 5.0 * se_m + 1e-4 * want, "portal MIS %.5f, want %.5f", mis,
               want);
        CHECKF(fabs(nee - want) < 5.0 * se_n + 1e-4 * want, "portal NEE %.5f, want %.5f", nee,
               want);
        CHECKF(fabs(none - want) < 5.0 * se_0 + 1e-4 * want, "no portal %.5f, want %.5f", none,
               want);
        CHECKF(se_m < 0.5 * se_0, "the portal's standard error %.2e, without it %.2e", se_m, se_0);
    }
    pt_scene_free(with);
    pt_scene_free(without);
    pt_env_free(env);
}

int main(void)
{
    int64_t live0 = pt_alloc_live();
    chi2_portals();
    chi2_mixture();
    sun_rule();
    reversed_portals();
    window_irradiance();
    CHECK(pt_alloc_live() == live0);
    return check_report();
}
