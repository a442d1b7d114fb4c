/*
 * test_stress.c - numerical stability of the whole renderer under extreme
 * scenes. Every render checks that no output pixel is NaN or Inf, prints the
 * count of rejected (NaN/Inf) samples and requires it to be 0; tolerances are
 * derived from the per-pixel standard errors (5 sigma per pixel, 4 sigma for
 * image means), never picked by hand.
 *
 * - Scale and placement: the Cornell box at scale 1e-4, 1e4 and translated by
 *   1e5 equals the unscaled image.
 * - Scale, sample by sample: an emitter's light samples (the Cornell box) and
 *   the light paths that need more than a ray and a light sample (reflection
 *   chains off chrome in the sun, refraction chains through a glass ball,
 *   bidirectional paths on the NVIDIA Cornell box) give the same samples at
 *   scale 1e-3, 1e3 and 1e11 as at 1 with the same random
 *   numbers (paired.h's z-test per block, past float rounding: a sample that
 *   takes another path after a rounding moves its block's mean by one
 *   standard error at most), and --bdpt auto measures the same pocket share.
 * - Degenerate geometry: zero-area and needle (1e-7 wide) triangles, emissive
 *   ones too, leave a closed box's image unchanged; duplicated coplanar
 *   triangles of two materials give an image between the two materials';
 *   a camera inside a closed object sees exact black; a camera in the plane
 *   of a large floor stays below the analytic bound rho * E.
 * - Extreme values: a closed emitting sphere (white furnace) with Lambert
 *   albedo 0, 0.5, 1 (exact answers), metals of roughness 0, 0.5, 1 (bounds),
 *   emission 1e-6 and 1e6; a tiny (1e-6 area) emitter of radiance 1e6 and a
 *   box of every metallic/roughness/base colour extreme.
 * - MetalRoughSpheresNoTextures (1,040,409 triangles, 7 mm): offset rays from
 *   camera-ray hits never hit the triangle they leave, and the hit/miss
 *   statistics agree at scale 1 and 1000.
 * - glTF files with non-finite or out-of-range values are rejected at load:
 *   JSON cannot carry NaN and its parser refuses numbers that overflow to Inf;
 *   factors outside glTF's [0, 1], yfov outside (0, pi) and node transforms
 *   that put vertices beyond PT_SCENE_MAX_COORD are refused by the builder,
 *   with messages naming the material/camera and field.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/render/bdpt_auto.h"
#include "common/render/render.h"
#include "common/scene/accel.h"
#include "common/scene/scene.h"
#include "tests/check.h"
#include "tests/common/render/paired.h"
#include "tests/rng.h"

/* ---- rendering and statistics ---------------------------------------------------------- */

typedef struct image {
    uint32_t w, h, spp;
    pt_pixel_acc *acc;
    pt_render_stats st;
} image;

static double lum_of(const pt_pixel_acc *a)
{
    double n = a->n;
    return pt_luminance(pt_v3((float)(pt_acc_sum(a, 0) / n), (float)(pt_acc_sum(a, 1) / n),
                              (float)(pt_acc_sum(a, 2) / n)));
}

/* Standard error of a pixel mean from its luminance sums. */
static double pixel_sigma(const pt_pixel_acc *a)
{
    double n = a->n, mean = lum_of(a);
    double var = (pt_acc_sum_sq(a) - n * mean * mean) / (n - 1.0);
    return sqrt(fmax(var, 0.0) / n);
}

/* Renders the whole image; checks every output is finite and every sample is
 * accounted for; reports the rejected count, which must be 0. */
static image render(const pt_scene *s, uint32_t w, uint32_t h, uint32_t spp, uint32_t seed,
                    uint32_t max_depth, const char *what)
{
    image im = {w, h, spp, NULL, {0}};
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = w;
    p.height = h;
    p.seed = seed;
    p.max_depth = max_depth;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s: %s", what, err.msg);
    im.acc = pt_malloc_array((size_t)w * h, sizeof *im.acc);
    CHECK(im.acc != NULL);
    if (!r || !im.acc) {
        pt_renderer_free(r);
        return im;
    }
    pt_rect all = {0, 0, w, h};
    pt_render_tile(r, all, 0, spp, im.acc, &im.st);
    int bad = 0;
    uint64_t n = 0;
    for (uint32_t i = 0; i < w * h; i++) {
        for (int c = 0; c < 3; c++)
            bad += !isfinite(pt_acc_sum(&im.acc[i], c)) || pt_acc_sum(&im.acc[i], c) < 0;
        bad += !isfinite(pt_acc_sum_sq(&im.acc[i])) || im.acc[i].n == 0;
        n += im.acc[i].n;
    }
    printf("%-40s %ux%u %4u spp: %llu rejected samples\n", what, w, h, spp,
           (unsigned long long)im.st.rejected);
    CHECKF(bad == 0, "%s: %d non-finite or empty pixels", what, bad);
    CHECKF(im.st.rejected == 0, "%s: %llu rejected samples", what,
           (unsigned long long)im.st.rejected);
    CHECK(n == im.st.samples && n + im.st.rejected == (uint64_t)w * h * spp);
    pt_renderer_free(r);
    return im;
}

static void image_free(image *im)
{
    pt_free(im->acc);
    im->acc = NULL;
}

/* a == k * b in expectation: every pixel within 5 sigma, the image means
 * within 4 sigma of their combined standard error. The 1e-9 relative term
 * only absorbs rounding where both pixels are noise-free. */
static void same_image(const image *a, const image *b, double k, const char *what)
{
    if (!a->acc || !b->acc)
        return;
    int outliers = 0;
    double ma = 0, mb = 0, va = 0, vb = 0, worst = 0;
    uint32_t n = a->w * a->h;
    for (uint32_t i = 0; i < n; i++) {
        double xa = lum_of(&a->acc[i]), xb = k * lum_of(&b->acc[i]);
        double sa = pixel_sigma(&a->acc[i]), sb = k * pixel_sigma(&b->acc[i]);
        double sig = sqrt(sa * sa + sb * sb);
        double d = fabs(xa - xb);
        if (d > 5.0 * sig + 1e-9 * (fabs(xa) + fabs(xb)))
            outliers++;
        if (sig > 0)
            worst = fmax(worst, d / sig);
        ma += xa;
        mb += xb;
        va += sa * sa;
        vb += sb * sb;
    }
    ma /= n;
    mb /= n;
    double sig = sqrt(va + vb) / n;
    printf("  %s: means %.6g vs %.6g (sigma %.2e), worst pixel %.2f sigma\n", what, ma, mb, sig,
           worst);
    CHECKF(outliers == 0, "%s: %d pixels beyond 5 sigma", what, outliers);
    CHECKF(fabs(ma - mb) <= 4.0 * sig + 1e-9 * (fabs(ma) + fabs(mb)),
           "%s: image means %.6g vs %.6g beyond 4 sigma (%.2e)", what, ma, mb, sig);
}

/* Every pixel of `im` and its image mean against an exact value. */
static void equals_value(const image *im, double expected, const char *what)
{
    if (!im->acc)
        return;
    int outliers = 0;
    double m = 0, v = 0;
    uint32_t n = im->w * im->h;
    for (uint32_t i = 0; i < n; i++) {
        double x = lum_of(&im->acc[i]), sg = pixel_sigma(&im->acc[i]);
        outliers += fabs(x - expected) > 5.0 * sg + 1e-6 * expected;
        m += x;
        v += sg * sg;
    }
    m /= n;
    double sig = sqrt(v) / n;
    printf("  %s: mean %.6g, exact %.6g (sigma %.2e)\n", what, m, expected, sig);
    CHECKF(outliers == 0, "%s: %d pixels beyond 5 sigma of %g", what, outliers, expected);
    CHECKF(fabs(m - expected) <= 4.0 * sig + 1e-6 * expected, "%s: mean %.6g, exact %.6g", what, m,
           expected);
}

/* ---- scenes built by code --------------------------------------------------------------- */

static pt_material lambert(float albedo)
{
    pt_material m = pt_material_default();
    m.metallic = 0.0f;
    m.specular = 0.0f;
    m.base_color[0] = m.base_color[1] = m.base_color[2] = albedo;
    return m;
}

static uint32_t add_mat(pt_scene_builder *b, const pt_material *m)
{
    uint32_t i = 0;
    pt_error err = {0};
    CHECKF(pt_scene_builder_add_material(b, m, &i, &err) == PT_OK, "%s", err.msg);
    return i;
}

static void add_tris(pt_scene_builder *b, const char *what, const float *p, uint32_t nt,
                     uint32_t mat)
{
    pt_error err = {0};
    CHECKF(pt_scene_builder_add_mesh(b, what, p, NULL, NULL, 3 * nt, NULL, nt, NULL, mat, &err) ==
               PT_OK,
           "%s: %s", what, err.msg);
}

/* A parallelogram c, c+u, c+u+v, c+v; its front (emitting side) is u x v. */
static void add_quad(pt_scene_builder *b, const char *what, pt_vec3 c, pt_vec3 u, pt_vec3 v,
                     uint32_t mat)
{
    pt_vec3 q[4] = {c, pt_v3_add(c, u), pt_v3_add(pt_v3_add(c, u), v), pt_v3_add(c, v)};
    const int order[6] = {0, 1, 2, 0, 2, 3};
    float p[18];
    for (int i = 0; i < 6; i++) {
        p[3 * i] = q[order[i]].x;
        p[3 * i + 1] = q[order[i]].y;
        p[3 * i + 2] = q[order[i]].z;
    }
    add_tris(b, what, p, 2, mat);
}

/* The six faces of the axis-aligned cube centre +- h. */
static void add_cube(pt_scene_builder *b, pt_vec3 centre, float h, uint32_t mat, uint32_t floor)
{
    float d = 2 * h;
    pt_vec3 lo = pt_v3_sub(centre, pt_v3(h, h, h)), hi = pt_v3_add(centre, pt_v3(h, h, h));
    add_quad(b, "floor", lo, pt_v3(d, 0, 0), pt_v3(0, 0, d), floor);
    add_quad(b, "ceiling", pt_v3(lo.x, hi.y, lo.z), pt_v3(0, 0, d), pt_v3(d, 0, 0), mat);
    add_quad(b, "back", lo, pt_v3(0, d, 0), pt_v3(d, 0, 0), mat);
    add_quad(b, "front", pt_v3(lo.x, lo.y, hi.z), pt_v3(d, 0, 0), pt_v3(0, d, 0), mat);
    add_quad(b, "left", lo, pt_v3(0, 0, d), pt_v3(0, d, 0), mat);
    add_quad(b, "right", pt_v3(hi.x, lo.y, lo.z), pt_v3(0, d, 0), pt_v3(0, 0, d), mat);
}

static void add_cam(pt_scene_builder *b, pt_vec3 pos, pt_vec3 fwd, float yfov)
{
    pt_camera c = {0};
    c.position = pos;
    c.forward = pt_v3_norm(fwd);
    c.right = pt_v3_norm(pt_v3_cross(c.forward, pt_v3(0, 1, 0)));
    c.up = pt_v3_cross(c.right, c.forward);
    c.yfov = yfov;
    snprintf(c.name, sizeof c.name, "cam");
    pt_error err = {0};
    CHECKF(pt_scene_builder_add_camera(b, &c, &err) == PT_OK, "%s", err.msg);
}

static pt_scene *finish(pt_scene_builder *b)
{
    pt_scene *s = NULL;
    pt_error err = {0};
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

/* A closed white box [-1,1]^3 with a square ceiling light (half-size lh,
 * radiance E, facing down) and the camera inside looking at the back wall.
 * Materials: 0 walls, 1 light, 2 red, 3 `extra` (or white). */
static pt_scene_builder *lit_box(float lh, float E, const pt_material *walls, int red_floor)
{
    pt_scene_builder *b = NULL;
    CHECK(pt_scene_builder_new(&b, NULL) == PT_OK);
    pt_material white = lambert(0.7f), red = lambert(0.0f), light = lambert(0.0f);
    red.base_color[0] = 0.7f;
    light.emissive[0] = light.emissive[1] = light.emissive[2] = E;
    add_mat(b, walls ? walls : &white);
    add_mat(b, &light);
    add_mat(b, &red);
    add_cube(b, pt_v3(0, 0, 0), 1.0f, 0, red_floor ? 2 : 0);
    add_quad(b, "light", pt_v3(-lh, 0.999f, -lh), pt_v3(2 * lh, 0, 0), pt_v3(0, 0, 2 * lh), 1);
    add_cam(b, pt_v3(0, 0, 0.95f), pt_v3(0, 0, -1), 1.3f);
    return b;
}

/* A closed UV sphere of radius 1 at the origin. */
static void add_sphere(pt_scene_builder *b, uint32_t mat)
{
    enum { NU = 32, NV = 16 };
    float *p = pt_malloc_array((NV + 1) * (NU + 1) * 3, sizeof(float));
    uint32_t *idx = pt_malloc_array(NU * NV * 6, sizeof(uint32_t)), nt = 0;
    CHECK(p && idx);
    if (!p || !idx) {
        pt_free(p);
        pt_free(idx);
        return;
    }
    for (int j = 0; j <= NV; j++)
        for (int i = 0; i <= NU; i++) {
            /* The seam column repeats the first exactly, so the mesh is closed. */
            double th = PT_PI * j / NV, ph = 2 * PT_PI * (i % NU) / NU;
            float *q = p + 3 * (j * (NU + 1) + i);
            q[0] = (float)(sin(th) * cos(ph));
            q[1] = (float)cos(th);
            q[2] = (float)(sin(th) * sin(ph));
            if (j == 0 || j == NV)
                q[0] = q[2] = 0.0f;
        }
    for (uint32_t j = 0; j < NV; j++)
        for (uint32_t i = 0; i < NU; i++) {
            uint32_t a = j * (NU + 1) + i, c = a + NU + 1;
            const uint32_t t[6] = {a, a + 1, c + 1, a, c + 1, c};
            memcpy(idx + 3 * nt, t, sizeof t);
            nt += 2;
        }
    /* Unshared vertices: the computed normals are then the faces' own, so
     * no interpolated shading normal breaks the furnace's energy balance on
     * this coarse tessellation; equal floats keep the mesh watertight. */
    float *flat = pt_malloc_array((size_t)nt * 9, sizeof(float));
    CHECK(flat != NULL);
    for (uint32_t k = 0; flat && k < 3 * nt; k++)
        memcpy(flat + 3 * k, p + 3 * idx[k], 3 * sizeof(float));
    if (flat)
        add_tris(b, "sphere", flat, nt, mat);
    pt_free(flat);
    pt_free(p);
    pt_free(idx);
}

/* A furnace: a closed double-sided sphere of material m emitting E, the
 * camera at its centre. */
static pt_scene *furnace(pt_material m, float E)
{
    pt_scene_builder *b = NULL;
    CHECK(pt_scene_builder_new(&b, NULL) == PT_OK);
    m.double_sided = 1;
    m.emissive[0] = m.emissive[1] = m.emissive[2] = E;
    add_sphere(b, add_mat(b, &m));
    add_cam(b, pt_v3(0, 0, 0), pt_v3(0.3f, 0.1f, -1), 1.2f);
    return finish(b);
}

/* ---- scale and placement ---------------------------------------------------------------- */

/* The scene at path scaled by `scale`, then moved by tr; NULL where a
 * shared asset is absent (outside CI) or it did not load (a failed CHECK). */
static pt_scene *load_scaled(const char *path, float scale, pt_vec3 tr)
{
    if (!check_shared_file(path))
        return NULL;
    pt_scene_opts o = {0};
    o.scale = scale;
    o.translate = tr;
    pt_scene *s = NULL;
    pt_error err = {0};
    CHECKF(pt_scene_load(path, &o, &s, &err) == PT_OK, "%s: %s", path, err.msg);
    return s;
}

static pt_scene *load_cornell(float scale, pt_vec3 tr)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/scenes/cornell_box.gltf", PT_SOURCE_DIR);
    return load_scaled(path, scale, tr);
}

static void scale_and_placement(void)
{
    const uint32_t W = 24, H = 24, SPP = 128;
    pt_scene *ref = load_cornell(1.0f, pt_v3(0, 0, 0));
    if (!ref)
        return;
    image a = render(ref, W, H, SPP, 1, 8, "cornell scale 1");
    const struct {
        float scale;
        pt_vec3 tr;
        const char *what;
    } v[] = {{1e-4f, {0, 0, 0}, "cornell scale 1e-4"},
             {1e4f, {0, 0, 0}, "cornell scale 1e4"},
             {1.0f, {1e5f, 1e5f, 1e5f}, "cornell translated 1e5"},
             {1.0f, {-3.3e6f, 1.234567e5f, 7.7e5f}, "cornell translated 3e6"}};
    for (size_t i = 0; i < sizeof v / sizeof v[0]; i++) {
        pt_scene *s = load_cornell(v[i].scale, v[i].tr);
        if (!s)
            continue;
        if (v[i].scale == 1.0f)
            CHECKF(fabs(s->origin[0] - v[i].tr.x) < 1.0 && fabsf(s->camera.position.x) < 2.0f,
                   "%s: origin %g, camera at %g", v[i].what, s->origin[0],
                   (double)s->camera.position.x);
        image b = render(s, W, H, SPP, 2 + (uint32_t)i, 8, v[i].what);
        same_image(&b, &a, 1.0, v[i].what);
        image_free(&b);
        pt_scene_free(s);
    }
    image_free(&a);
    pt_scene_free(ref);
}

/* Every length in the renderer's tolerances (ray offsets, the chains' seeds,
 * solver and hull test, bdpt's disk and pocket probes) must scale with the
 * scene: the same samples at 1e-3 and 1e3 as at 1. The glass ball is lit by
 * a map of a dim sky and one lamp 2,000 times brighter, over the chains'
 * threshold (PT_MANIFOLD_MIN_LIGHT times the map's mean), so that its light
 * samples of the lamp chain through the ball. */
static void scale_features(void)
{
    const uint32_t SIDE = 24, BLOCK = 8, SPP = 32, MW = 64, MH = 32;
    pt_error err = {0};
    float *px = pt_malloc_array((size_t)MW * MH * 3, sizeof(float));
    pt_env *lamp = NULL;
    if (px) {
        for (uint32_t i = 0; i < MW * MH * 3; i++)
            px[i] = 0.5f;
        for (uint32_t y = 2; y < 4; y++) /* high above, over the ball */
            for (uint32_t x = 30; x < 32; x++)
                for (int c = 0; c < 3; c++)
                    px[3 * (y * MW + x) + c] = 1000.0f;
        pt_envmap map = {MW, MH, px};
        CHECKF(pt_env_new(&map, 1.0f, 0.0f, &lamp, &err) == PT_OK, "%s", err.msg);
    }
    pt_free(px);
    char cornell[4096], chrome[4096], glass[4096], nvidia[4096];
    snprintf(cornell, sizeof cornell, "%s/scenes/cornell_box.gltf", PT_SOURCE_DIR);
    snprintf(chrome, sizeof chrome, "%s/scenes/chrome_sun.gltf", PT_SOURCE_DIR);
    snprintf(glass, sizeof glass, "%s/scenes/glass_things.gltf", PT_SOURCE_DIR);
    snprintf(nvidia, sizeof nvidia, "%s/CornellBox/cornellBox.gltf", PT_SHARED_SCENES);
    const struct {
        const char *path, *what;
        const pt_env *env;
        int bdpt;   /* bidirectional */
        int chains; /* the chains must run */
    } sc[] = {{cornell, "Cornell box (light samples of an emitter)", NULL, 0, 0},
              {chrome, "chrome in the sun (reflection chains)", NULL, 0, 1},
              {glass, "glass ball (refraction chains)", lamp, 0, 1},
              {nvidia, "NVIDIA Cornell box (bdpt)", NULL, 1, 0}};
    /* 1e11: the lamps' triangles 1e10 wide, whose area's float sum of
     * squares overflows (pt_accel_tri_area) */
    const float scales[] = {1e-3f, 1e3f, 1e11f};
    for (size_t i = 0; i < sizeof sc / sizeof sc[0]; i++) {
        pt_scene *ref = load_scaled(sc[i].path, 1.0f, pt_v3(0, 0, 0));
        if (!ref)
            continue;
        double share0 = 0.0;
        if (sc[i].bdpt)
            CHECKF(pt_bdpt_pocketed(ref, &share0, &err) == PT_OK, "%s", err.msg);
        pt_renderer *a = paired_renderer(ref, sc[i].env, SIDE, sc[i].bdpt);
        for (size_t k = 0; k < sizeof scales / sizeof scales[0] && a; k++) {
            pt_scene *s = load_scaled(sc[i].path, scales[k], pt_v3(0, 0, 0));
            pt_renderer *b = s ? paired_renderer(s, sc[i].env, SIDE, sc[i].bdpt) : NULL;
            if (b) {
                char name[160];
                snprintf(name, sizeof name, "%s at scale %g", sc[i].what, (double)scales[k]);
                /* 1e-4 of a block's mean: float rounding of a scaled scene,
                 * whose lengths and offsets round at other places, moves
                 * every sample a little the same way (chrome_sun: |z| up to
                 * 6 on differences of 1e-7). */
                paired_result pr = paired_blocks_z(name, a, b, SIDE, BLOCK, SPP, 1e-4);
                uint64_t ca = pr.sa.chains, cb = pr.sb.chains;
                printf("  %s: largest |z| %.2f (bound %.2f), chains %llu vs %llu\n", name, pr.z_max,
                       pr.z_bound, (unsigned long long)ca, (unsigned long long)cb);
                CHECKF(pr.bad == 0 && pr.nonfinite == 0,
                       "%s: %u of %u blocks x channels differ, %llu non-finite samples", name,
                       pr.bad, pr.tests, (unsigned long long)pr.nonfinite);
                /* The same rays but where a path took another turn: a light
                 * sample that fails at one scale (an emitter whose area
                 * overflowed) traces no shadow ray, though the paths that
                 * find the light keep the image unbiased. */
                double ra = (double)pr.sa.rays, rb = (double)pr.sb.rays;
                printf("  %s: rays %.0f vs %.0f\n", name, ra, rb);
                CHECKF(fabs(ra - rb) <= 0.01 * ra, "%s: %.0f rays, %.0f at scale 1", name, rb, ra);
                if (sc[i].chains)
                    CHECKF(ca > 0 && cb > 0, "%s: no chains (%llu, %llu)", name,
                           (unsigned long long)ca, (unsigned long long)cb);
                if (sc[i].bdpt) {
                    double share = 0.0;
                    CHECKF(pt_bdpt_pocketed(s, &share, &err) == PT_OK, "%s", err.msg);
                    printf("  %s: pocket share %.4f (at 1: %.4f)\n", name, share, share0);
                    CHECKF(fabs(share - share0) < 0.01, "%s: pocket share %.4f, at 1 %.4f", name,
                           share, share0);
                }
            }
            pt_renderer_free(b);
            pt_scene_free(s);
        }
        pt_renderer_free(a);
        pt_scene_free(ref);
    }
    pt_env_free(lamp);
}

/* ---- degenerate geometry ---------------------------------------------------------------- */

static void degenerate_geometry(void)
{
    const uint32_t W = 16, H = 16, SPP = 128;
    pt_scene *sane = finish(lit_box(0.3f, 4.0f, NULL, 0));
    if (!sane)
        return;
    image ref = render(sane, W, H, SPP, 1, 8, "box");

    /* Zero-area (a point, a collinear triple) and needle triangles, white
     * and emissive: they have (almost) no area, so the image must not move. */
    pt_scene_builder *b = lit_box(0.3f, 4.0f, NULL, 0);
    const float deg[] = {0.1f,  0.2f,          0.3f,  0.1f,  0.2f,  0.3f,  0.1f,  0.2f,
                         0.3f,  -0.5f,         -0.5f, 0.0f,  0.0f,  -0.5f, 0.0f,  0.5f,
                         -0.5f, 0.0f,          -0.5f, -0.6f, -0.5f, 0.5f,  -0.6f, -0.5f,
                         0.5f,  -0.6f + 1e-7f, -0.5f, -0.9f, -0.9f, -0.9f, 0.9f,  0.9f,
                         -0.9f, 0.9f + 1e-7f,  0.9f,  -0.9f};
    add_tris(b, "degenerate white", deg, 4, 0);
    add_tris(b, "degenerate light", deg, 4, 1);
    pt_scene *s = finish(b);
    if (s) {
        image im = render(s, W, H, SPP, 2, 8, "box + zero-area/needle triangles");
        same_image(&im, &ref, 1.0, "zero-area and needle triangles");
        image_free(&im);
        pt_scene_free(s);
    }

    /* Z-fighting: the white floor twice, once red. Every path's value is
     * monotone in each hit's albedo, so each pixel lies between the box with
     * a red floor and the box with a white one. */
    pt_scene *red = finish(lit_box(0.3f, 4.0f, NULL, 1));
    b = lit_box(0.3f, 4.0f, NULL, 0);
    add_quad(b, "red floor", pt_v3(-1, -1, -1), pt_v3(2, 0, 0), pt_v3(0, 0, 2), 2);
    s = finish(b);
    if (s && red) {
        image z = render(s, W, H, SPP, 3, 8, "box, floor z-fighting white/red");
        image r = render(red, W, H, SPP, 4, 8, "box, red floor");
        int out = 0;
        for (uint32_t i = 0; i < W * H && z.acc && r.acc; i++) {
            double sz = pixel_sigma(&z.acc[i]), sr = pixel_sigma(&r.acc[i]),
                   sw = pixel_sigma(&ref.acc[i]);
            double lz = lum_of(&z.acc[i]);
            out += lz < lum_of(&r.acc[i]) - 5.0 * sqrt(sz * sz + sr * sr) ||
                   lz > lum_of(&ref.acc[i]) + 5.0 * sqrt(sz * sz + sw * sw);
        }
        CHECKF(out == 0, "z-fighting: %d pixels outside [red floor, white floor]", out);
        image_free(&z);
        image_free(&r);
    }
    pt_scene_free(s);
    pt_scene_free(red);

    /* The camera inside a closed cube, the light outside it: exactly black
     * (robust Embree is watertight, so no light leaks through edges). */
    b = lit_box(0.3f, 4.0f, NULL, 0);
    add_cube(b, pt_v3(0, 0, 0.95f), 0.04f, 0, 0);
    s = finish(b);
    if (s) {
        image im = render(s, W, H, SPP, 5, 8, "camera inside a closed cube");
        double total = 0;
        for (uint32_t i = 0; i < W * H && im.acc; i++)
            total +=
                pt_acc_sum(&im.acc[i], 0) + pt_acc_sum(&im.acc[i], 1) + pt_acc_sum(&im.acc[i], 2);
        CHECKF(total == 0.0, "inside a closed cube: light leaks (%g)", total);
        image_free(&im);
        pt_scene_free(s);
    }
    image_free(&ref);
    pt_scene_free(sane);

    /* Grazing rays: the camera in the plane of a large floor (albedo rho),
     * then 1e-4 above it, the light above and behind (out of view). Rays
     * above the horizon can reach nothing: exact black. Below it a Lambert
     * floor lit by one emitter of radiance E is at most rho * E (the light
     * covers less than the hemisphere). */
    const float rho = 0.5f, E = 3.0f;
    const float heights[2] = {0.0f, 1e-4f};
    for (int k = 0; k < 2; k++) {
        b = NULL;
        CHECK(pt_scene_builder_new(&b, NULL) == PT_OK);
        pt_material fl = lambert(rho), li = lambert(0.0f);
        li.emissive[0] = li.emissive[1] = li.emissive[2] = E;
        uint32_t mf = add_mat(b, &fl), ml = add_mat(b, &li);
        add_quad(b, "floor", pt_v3(-500, 0, -500), pt_v3(0, 0, 1000), pt_v3(1000, 0, 0), mf);
        add_quad(b, "light", pt_v3(-1, 10, 4), pt_v3(2, 0, 0), pt_v3(0, 0, 2), ml);
        add_cam(b, pt_v3(0, heights[k], 0), pt_v3(0, 0, -1), 0.8f);
        s = finish(b);
        if (!s)
            continue;
        image im = render(s, W, H, SPP, 6, 8,
                          k ? "camera 1e-4 above a floor" : "camera in a floor's plane");
        int lit_sky = 0, over = 0;
        double below = 0;
        for (uint32_t y = 0; y < H && im.acc; y++)
            for (uint32_t x = 0; x < W; x++) {
                const pt_pixel_acc *a = &im.acc[y * W + x];
                if (y < H / 2)
                    lit_sky +=
                        pt_acc_sum(a, 0) != 0 || pt_acc_sum(a, 1) != 0 || pt_acc_sum(a, 2) != 0;
                else
                    below += lum_of(a);
                over += lum_of(a) > rho * E + 5.0 * pixel_sigma(a);
            }
        printf("  grazing, camera at height %g: mean below the horizon %.4g\n", (double)heights[k],
               below / (W * H / 2));
        CHECKF(lit_sky == 0, "grazing: %d pixels above the horizon are not black", lit_sky);
        CHECKF(over == 0, "grazing: %d pixels above rho * E", over);
        if (k == 1)
            CHECK(below > 0);
        image_free(&im);
        pt_scene_free(s);
    }
}

/* ---- extreme values --------------------------------------------------------------------- */

static void extreme_values(void)
{
    const uint32_t W = 16, H = 16, SPP = 64;
    /* Lambert furnaces: albedo rho emitting E gives E / (1 - rho) at any
     * roughness (which Lambert ignores), and emission 1e-6 and 1e6. */
    const struct {
        float rough, E;
    } lam[] = {{0.0f, 0.5f}, {1.0f, 0.5f}, {1.0f, 1e-6f}, {0.5f, 1e6f}};
    for (size_t i = 0; i < sizeof lam / sizeof lam[0]; i++) {
        pt_material m = lambert(0.5f);
        m.roughness = lam[i].rough;
        pt_scene *s = furnace(m, lam[i].E);
        if (!s)
            continue;
        char what[80];
        snprintf(what, sizeof what, "furnace lambert 0.5 rough %g E %g", (double)lam[i].rough,
                 (double)lam[i].E);
        image im = render(s, W, H, SPP, 11, 1000, what);
        equals_value(&im, 2.0 * lam[i].E, what);
        image_free(&im);
        pt_scene_free(s);
    }
    /* Albedo 0: every sample is exactly E. Albedo 1 with max_depth D: each
     * of the D scattering events adds E (conservation, Russian roulette
     * unbiased), so (D + 1) E. */
    {
        pt_scene *s = furnace(lambert(0.0f), 0.5f);
        if (s) {
            image im = render(s, W, H, SPP, 12, 16, "furnace lambert 0");
            int off = 0;
            for (uint32_t i = 0; i < W * H && im.acc; i++)
                off += pt_acc_sum(&im.acc[i], 1) != 0.5 * im.acc[i].n;
            CHECKF(off == 0, "albedo 0: %d pixels are not exactly E", off);
            image_free(&im);
            pt_scene_free(s);
        }
        s = furnace(lambert(1.0f), 0.5f);
        if (s) {
            image im = render(s, W, H, 256, 13, 8, "furnace lambert 1, max_depth 8");
            equals_value(&im, 9 * 0.5, "albedo 1, max_depth 8");
            image_free(&im);
            pt_scene_free(s);
        }
    }
    /* Metals of base colour 0.5 (F0 = 0.5) at roughness 0, 0.5, 1: no exact
     * answer, but the emission is seen directly (>= E) and no BSDF reflects
     * more than it receives, so each of D events adds at most E. */
    const float rough[3] = {0.0f, 0.5f, 1.0f};
    for (int i = 0; i < 3; i++) {
        pt_material m = pt_material_default();
        m.base_color[0] = m.base_color[1] = m.base_color[2] = 0.5f;
        m.roughness = rough[i];
        pt_scene *s = furnace(m, 0.5f);
        if (!s)
            continue;
        char what[80];
        snprintf(what, sizeof what, "furnace metal 0.5 rough %g", (double)rough[i]);
        image im = render(s, W, H, SPP, 14, 8, what);
        int out = 0;
        double mean = 0;
        for (uint32_t k = 0; k < W * H && im.acc; k++) {
            double x = lum_of(&im.acc[k]), sg = pixel_sigma(&im.acc[k]);
            out += x < 0.5 - 5 * sg - 1e-6 || x > 9 * 0.5 + 5 * sg;
            mean += x / (W * H);
        }
        printf("  %s: mean %.4f in [0.5, 4.5]\n", what, mean);
        CHECKF(out == 0, "%s: %d pixels outside [E, 9E]", what, out);
        image_free(&im);
        pt_scene_free(s);
    }

    /* A tiny emitter (1e-3 square, area 1e-6 of the box's side) of radiance
     * 1e6, and an ordinary light of emission 1e-6: light transport is linear
     * in the emission, so each equals its radiance-1 twin times the factor. */
    const struct {
        float lh, k;
        const char *what;
    } lin[] = {{5e-4f, 1e6f, "tiny emitter, radiance 1e6"}, {0.3f, 1e-6f, "emission 1e-6"}};
    for (int i = 0; i < 2; i++) {
        pt_scene *s = finish(lit_box(lin[i].lh, lin[i].k, NULL, 0));
        pt_scene *one = finish(lit_box(lin[i].lh, 1.0f, NULL, 0));
        if (s && one) {
            image a = render(s, W, H, 256, 21, 8, lin[i].what);
            image b = render(one, W, H, 256, 22, 8, "  (its radiance-1 twin)");
            same_image(&a, &b, lin[i].k, lin[i].what);
            image_free(&a);
            image_free(&b);
        }
        pt_scene_free(s);
        pt_scene_free(one);
    }

    /* Every combination of metallic, roughness and base colour at 0 and 1 on
     * the walls of the lit box. Base 0, metallic 0 and no specular lobe is
     * black: each sample is 0 or the light's radiance seen directly. */
    for (int c = 0; c < 8; c++) {
        pt_material m = pt_material_default();
        m.metallic = (float)(c & 1);
        m.roughness = (float)((c >> 1) & 1);
        float base = (float)((c >> 2) & 1);
        m.base_color[0] = m.base_color[1] = m.base_color[2] = base;
        if (base == 0.0f && m.metallic == 0.0f)
            m.specular = 0.0f;
        pt_scene *s = finish(lit_box(0.3f, 4.0f, &m, 0));
        if (!s)
            continue;
        char what[80];
        snprintf(what, sizeof what, "box metallic %g rough %g base %g", (double)m.metallic,
                 (double)m.roughness, (double)base);
        image im = render(s, W, H, SPP, 30 + (uint32_t)c, 8, what);
        if (base == 0.0f && m.metallic == 0.0f) {
            int off = 0;
            for (uint32_t i = 0; i < W * H && im.acc; i++) {
                double k = pt_acc_sum(&im.acc[i], 1) / 4.0;
                off += k != floor(k) || k > im.acc[i].n;
            }
            CHECKF(off == 0, "%s: %d pixels are not whole numbers of light hits", what, off);
        }
        image_free(&im);
        pt_scene_free(s);
    }
}

/* ---- self-intersection on a million tiny triangles -------------------------------------- */

static uint64_t rng_state;

static double rnd(void)
{
    return rng_f53(&rng_state);
}

typedef struct offset_stats {
    uint32_t hits;    /* camera rays that hit a sphere */
    uint32_t same;    /* offset rays that hit the triangle they left */
    uint32_t near;    /* offset rays that hit anything within 1e-4 of the scene's size */
    uint32_t escaped; /* offset rays that hit nothing */
} offset_stats;

static offset_stats offset_rays(const pt_scene *s, uint32_t n, uint64_t seed)
{
    offset_stats o = {0, 0, 0, 0};
    pt_accel *a = NULL;
    pt_error err = {0};
    CHECKF(pt_accel_new(s, &a, &err) == PT_OK, "%s", err.msg);
    if (!a)
        return o;
    rng_state = seed;
    const pt_camera *c = &s->camera;
    float size = pt_v3_len(pt_v3_sub(s->bounds_max, s->bounds_min));
    float th = tanf(0.5f * c->yfov);
    for (uint32_t i = 0; i < n; i++) {
        float x = (float)(2 * rnd() - 1) * th, y = (float)(2 * rnd() - 1) * th;
        pt_vec3 d = pt_v3_norm(
            pt_v3_add(c->forward, pt_v3_add(pt_v3_scale(c->right, x), pt_v3_scale(c->up, y))));
        pt_hit h;
        if (!pt_accel_intersect(a, c->position, d, INFINITY, &h))
            continue;
        o.hits++;
        pt_vec3 p, ng;
        pt_accel_hit_point(s, &h, &p, &ng);
        if (pt_v3_dot(ng, d) > 0)
            ng = pt_v3_neg(ng);
        /* A uniform direction on the hemisphere around ng. */
        pt_vec3 w;
        do {
            w = pt_v3((float)(2 * rnd() - 1), (float)(2 * rnd() - 1), (float)(2 * rnd() - 1));
        } while (!(pt_v3_dot(w, w) <= 1.0f && pt_v3_dot(w, w) > 1e-4f));
        w = pt_v3_norm(w);
        if (pt_v3_dot(w, ng) < 0)
            w = pt_v3_neg(w);
        pt_vec3 org = pt_accel_offset_ray(a, p, ng);
        pt_hit h2;
        if (!pt_accel_intersect(a, org, w, INFINITY, &h2)) {
            o.escaped++;
            continue;
        }
        o.same += h2.tri == h.tri;
        o.near += h2.t < 1e-4f * size;
    }
    pt_accel_free(a);
    return o;
}

static void million_triangles(void)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/MetalRoughSpheresNoTextures/MetalRoughSpheresNoTextures.glb",
             PT_SHARED_SCENES);
    if (access(path, R_OK) != 0) {
        CHECK_SKIP("MetalRoughSpheresNoTextures: not found");
        CHECKF(!check_shared_required(), "%s is required in CI", path);
        return;
    }
    const uint32_t N = 50000;
    offset_stats st[2];
    const float scales[2] = {1.0f, 1000.0f};
    for (int k = 0; k < 2; k++) {
        pt_scene_opts o = {0};
        o.scale = scales[k];
        pt_scene *s = NULL;
        pt_error err = {0};
        CHECKF(pt_scene_load(path, &o, &s, &err) == PT_OK, "%s", err.msg);
        if (!s)
            return;
        CHECK(s->num_triangles == 1040409);
        st[k] = offset_rays(s, N, 1234 + (uint64_t)k);
        printf("MetalRoughSpheres scale %g: %u hits, offset rays: %u same triangle, %u within "
               "1e-4 of the size, %u escaped\n",
               (double)scales[k], st[k].hits, st[k].same, st[k].near, st[k].escaped);
        CHECKF(st[k].same == 0, "scale %g: %u offset rays hit their own triangle",
               (double)scales[k], st[k].same);
        CHECK(st[k].hits > N / 10);
        pt_scene_free(s);
    }
    /* The escaped and near fractions are binomial proportions: at the two
     * scales they must agree within 4 sigma of their difference. */
    const uint32_t *cnt[2][2] = {{&st[0].escaped, &st[1].escaped}, {&st[0].near, &st[1].near}};
    const char *names[2] = {"escaped", "near"};
    for (int q = 0; q < 2; q++) {
        double n0 = st[0].hits, n1 = st[1].hits;
        double p0 = *cnt[q][0] / n0, p1 = *cnt[q][1] / n1;
        double pp = (*cnt[q][0] + *cnt[q][1]) / (n0 + n1);
        double sig = sqrt(pp * (1 - pp) * (1 / n0 + 1 / n1));
        CHECKF(fabs(p0 - p1) <= 4 * sig + 1e-12,
               "%s fraction %.5f at scale 1, %.5f at 1000 "
               "(sigma %.2e)",
               names[q], p0, p1, sig);
    }
}

/* ---- absurd input values in glTF files ------------------------------------------------- */

static void base64(const unsigned char *in, size_t n, char *out)
{
    static const char t[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    size_t o = 0;
    for (size_t i = 0; i < n; i += 3) {
        uint32_t v = (uint32_t)in[i] << 16;
        if (i + 1 < n)
            v |= (uint32_t)in[i + 1] << 8;
        if (i + 2 < n)
            v |= in[i + 2];
        out[o++] = t[(v >> 18) & 63];
        out[o++] = t[(v >> 12) & 63];
        out[o++] = i + 1 < n ? t[(v >> 6) & 63] : '=';
        out[o++] = i + 2 < n ? t[v & 63] : '=';
    }
    out[o] = 0;
}

/* Writes a one-triangle glTF with the given material, node transform and
 * camera yfov (JSON text) and loads it. */
static pt_status load_variant(const char *dir, const char *material, const char *node_xform,
                              const char *yfov, pt_error *err)
{
    const float tri[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    unsigned char bytes[36];
    memcpy(bytes, tri, sizeof bytes); /* glTF buffers are little-endian, as is every target */
    char b64[64];
    base64(bytes, sizeof bytes, b64);
    char path[4200];
    snprintf(path, sizeof path, "%s/variant.gltf", dir);
    FILE *f = fopen(path, "w");
    CHECK(f != NULL);
    if (!f)
        return PT_ERR_IO;
    fprintf(
        f,
        "{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0,1]}],"
        "\"nodes\":[{\"mesh\":0%s},{\"camera\":0,\"translation\":[0,0,3]}],"
        "\"cameras\":[{\"type\":\"perspective\",\"perspective\":{\"yfov\":%s,\"znear\":0.01}}],"
        "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0},\"material\":0}]}],"
        "\"materials\":[{\"name\":\"probe\",%s}],"
        "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\","
        "\"min\":[0,0,0],\"max\":[1,1,0]}],"
        "\"bufferViews\":[{\"buffer\":0,\"byteLength\":36}],"
        "\"buffers\":[{\"byteLength\":36,\"uri\":\"data:application/octet-stream;base64,%s\"}]}",
        node_xform, yfov, material, b64);
    CHECK(fclose(f) == 0);
    pt_scene *s = NULL;
    pt_status st = pt_scene_load(path, NULL, &s, err);
    pt_scene_free(s);
    remove(path);
    return st;
}

static void absurd_inputs(void)
{
    char dir[] = "/tmp/pt_stress_XXXXXX";
    if (!mkdtemp(dir)) {
        CHECK(!"mkdtemp");
        return;
    }
    const char *ok_mat = "\"pbrMetallicRoughness\":{\"roughnessFactor\":0.5}";
    pt_error err = {0};
    CHECKF(load_variant(dir, ok_mat, "", "0.8", &err) == PT_OK, "control: %s", err.msg);
    const struct {
        const char *mat, *xform, *yfov, *want;
    } bad[] = {
        /* JSON has no NaN; 1e400 overflows to Inf in the parser. */
        {"\"emissiveFactor\":[NaN,0,0]", "", "0.8", "parse error"},
        {"\"emissiveFactor\":[1e400,0,0]", "", "0.8", "1e400"},
        {"\"pbrMetallicRoughness\":{\"roughnessFactor\":-0.5}", "", "0.8", "roughnessFactor"},
        {"\"pbrMetallicRoughness\":{\"roughnessFactor\":1.5}", "", "0.8", "roughnessFactor"},
        {"\"pbrMetallicRoughness\":{\"metallicFactor\":-1}", "", "0.8", "metallicFactor"},
        {"\"pbrMetallicRoughness\":{\"metallicFactor\":2}", "", "0.8", "metallicFactor"},
        {"\"pbrMetallicRoughness\":{\"baseColorFactor\":[1,2,1,1]}", "", "0.8", "baseColorFactor"},
        {ok_mat, "", "1e400", "1e400"},
        {ok_mat, "", "0", "yfov"},
        {ok_mat, "", "3.2", "yfov"},
        {ok_mat, ",\"matrix\":[1e30,0,0,0,0,1e30,0,0,0,0,1e30,0,0,0,0,1]", "0.8", "over"},
        {ok_mat, ",\"scale\":[1e30,1e30,1e30]", "0.8", "over"},
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        pt_error e = {0};
        pt_status st = load_variant(dir, bad[i].mat, bad[i].xform, bad[i].yfov, &e);
        printf("  rejected? %-60.60s yfov %-6s -> %d: %s\n", bad[i].mat[0] ? bad[i].mat : "-",
               bad[i].yfov, (int)st, e.msg);
        CHECKF(st != PT_OK, "case %zu (%s %s yfov %s) was accepted", i, bad[i].mat, bad[i].xform,
               bad[i].yfov);
        CHECKF(strstr(e.msg, bad[i].want) != NULL, "case %zu: message '%s' does not name '%s'", i,
               e.msg, bad[i].want);
    }
    rmdir(dir);
}

int main(void)
{
    scale_and_placement();
    scale_features();
    degenerate_geometry();
    extreme_values();
    million_triangles();
    absurd_inputs();
    return check_report();
}
