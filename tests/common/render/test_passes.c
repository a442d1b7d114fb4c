/*
 * test_passes.c - render passes (common/render/passes.h, render.h's passes
 * variant, film.h's pass sums, exr.h's layers).
 *
 * - The list of names: every name, `all`, and each refusal.
 * - A Lambert plane (specular 0) and an emissive one beside it, seen head on
 *   by an orthographic camera under a uniform sky: every sample's albedo is
 *   the base colour, its normal +Z, its depth the camera's height and its
 *   emission the emissive factor, so the resolved means are those exactly
 *   (the fixed-point sums of equal values divide back to them) and the
 *   variances 0. Without the passes variant these would be 0: the test fails.
 * - A sphere of radius 1 tessellated into a UV sphere: each sample's normal
 *   is the sphere's normal at its hit within the tessellation's bound (the
 *   angle a triangle spans), its depth the closed-form distance to the sphere
 *   within the chord's sagitta, its projection inside its pixel's footprint.
 * - A mirror (metal, smooth) at 45 degrees in front of a Lambert wall: the
 *   albedo is read through it, Schlick's F at 45 degrees times the wall's
 *   colour (through the specular chain, as Cycles' denoising albedo).
 * - The halves: sample 0 alone is all even, sample 1 all odd (the index's
 *   parity); over 64 samples the counts are n/2 each, n_even x halfA + n_odd x halfB is
 *   the beauty's sum, and halfA - halfB over the pixels is noise of the
 *   variance the beauty's variance predicts (4 x variance of the mean): the
 *   mean of z^2 is 1 within 5 of its standard errors (sqrt(2 / pixels)).
 * - Determinism: the passes of [0, spp) in one call equal any split at
 *   blocks added in any order, and the batched tile equals pt_render_sample
 *   one sample at a time; the beauty of the passes variant is the same bits
 *   as the variant without passes (Cornell box).
 * - The EXR: the planes written as layers, read back with
 *   pt_exr_read_layers bit for bit; pt_exr_read leaves them out.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/image/exr.h"
#include "common/render/env.h"
#include "common/render/film.h"
#include "common/render/passes.h"
#include "common/render/render.h"
#include "tests/check.h"
#include "tests/common/render/ortho.h"

#define W 8u
#define SPP 64u

static void parse(void)
{
    uint32_t m = 0;
    pt_error err = {0};
    CHECK(pt_passes_parse("--passes", "albedo", &m, &err) == PT_OK && m == PT_PASS_ALBEDO);
    CHECK(pt_passes_parse("--passes", "normal,depth,normal", &m, &err) == PT_OK &&
          m == (PT_PASS_NORMAL | PT_PASS_DEPTH));
    CHECK(pt_passes_parse("--passes", "albedo,normal,depth,emission,halves,cryptomatte", &m,
                          &err) == PT_OK &&
          m == PT_PASS_ALL);
    CHECK(pt_passes_parse("--passes", "all", &m, &err) == PT_OK && m == PT_PASS_ALL);
    const char *bad[] = {"",       ",", "albedo,", ",albedo",      "albedo,,depth",
                         "Albedo", "z", "alll",    "albedo normal"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        m = 12345;
        CHECKF(pt_passes_parse("--passes", bad[i], &m, &err) == PT_ERR_ARG && m == 12345,
               "'%s' accepted", bad[i]);
        CHECK(strstr(err.msg, "--passes") && strstr(err.msg, "albedo, normal"));
    }
    char t[PT_PASSES_MAX_TEXT];
    pt_passes_text(PT_PASS_ALL, t, sizeof t);
    CHECK(!strcmp(t, "albedo,normal,depth,emission,halves,cryptomatte"));
    CHECK(pt_passes_parse("--passes", t, &m, &err) == PT_OK && m == PT_PASS_ALL);
    pt_passes_text(PT_PASS_DEPTH | PT_PASS_HALVES, t, sizeof t);
    CHECK(!strcmp(t, "depth,halves"));
    pt_passes_text(0, t, sizeof t);
    CHECK(t[0] == '\0');
}

static pt_renderer *renderer(const pt_scene *s, const pt_env *env, uint32_t w, uint32_t passes)
{
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = p.height = w;
    p.seed = 7;
    p.env = env;
    p.passes = passes;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    return r;
}

/* The film of a whole image rendered in one tile, its passes resolved. */
static pt_image *render_image(const pt_renderer *r, uint32_t w, uint32_t spp, uint32_t passes)
{
    pt_error err = {0};
    pt_film *film = NULL;
    pt_image *img = NULL;
    pt_pixel_acc *acc = pt_calloc((size_t)w * w, sizeof *acc);
    pt_pass_acc *pacc = pt_calloc((size_t)w * w, sizeof *pacc);
    CHECK(acc && pacc);
    CHECK(pt_film_new(w, w, &film, &err) == PT_OK);
    CHECK(pt_film_enable_passes(film, passes, &err) == PT_OK);
    CHECK(pt_image_new(w, w, &img, &err) == PT_OK);
    const pt_rect all = {0, 0, w, w};
    pt_render_stats st = {0};
    pt_render_tile_passes(r, all, 0, spp, acc, pacc, &st, NULL);
    CHECK(st.rejected == 0);
    pt_film_add_tile_passes(film, all, acc, pacc);
    pt_film_resolve(film, img);
    pt_film_free(film);
    pt_free(acc);
    pt_free(pacc);
    return img;
}

static float plane_at(const pt_image *img, const char *name, uint32_t i)
{
    const float *p = pt_image_find_plane(img, name);
    CHECKF(p != NULL, "no plane %s", name);
    return p ? p[i] : NAN;
}

/* Two quads in z = 0, x < 0 emissive, x >= 0 Lambert, seen from z = 10. */
static const float BASE[3] = {0.3f, 0.5f, 0.7f}, EBASE[3] = {0.1f, 0.2f, 0.1f},
                   EMIT[3] = {2.0f, 3.0f, 4.0f};
#define HEIGHT 10.0f

static pt_scene *planes_scene(void)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default(), e = pt_material_default();
    memcpy(m.base_color, BASE, sizeof BASE);
    m.metallic = 0.0f;
    m.specular = 0.0f;
    memcpy(e.base_color, EBASE, sizeof EBASE);
    memcpy(e.emissive, EMIT, sizeof EMIT);
    e.metallic = 0.0f;
    e.specular = 0.0f;
    uint32_t mm = 0, me = 0;
    CHECK(pt_scene_builder_add_material(b, &m, &mm, &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &e, &me, &err) == PT_OK);
    const float P = 100.0f;
    float ql[12] = {-P, -P, 0, 0, -P, 0, 0, P, 0, -P, P, 0};
    float qr[12] = {0, -P, 0, P, -P, 0, P, P, 0, 0, P, 0};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "emitter", ql, NULL, NULL, 4, idx, 2, NULL, me, &err) ==
          PT_OK);
    CHECK(pt_scene_builder_add_mesh(b, "plane", qr, NULL, NULL, 4, idx, 2, NULL, mm, &err) ==
          PT_OK);
    pt_camera cam = pt_test_ortho_down(0, 0, HEIGHT, (float)W / 2);
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

static void plane_passes(void)
{
    pt_env *env = NULL;
    pt_error err = {0};
    CHECK(pt_env_uniform(pt_v3(1, 1, 1), &env, &err) == PT_OK);
    pt_scene *s = planes_scene();
    pt_renderer *r = renderer(s, env, W, PT_PASS_ALL);
    if (!s || !r)
        return;
    CHECK(!strcmp(pt_renderer_variant(r), "passes"));
    pt_image *img = render_image(r, W, SPP, PT_PASS_ALL);
    static const char *const rgb[3] = {"R", "G", "B"}, *const xyz[3] = {"X", "Y", "Z"};
    int bad = 0;
    for (uint32_t y = 0; y < W; y++)
        for (uint32_t x = 0; x < W; x++) {
            uint32_t i = y * W + x;
            /* Column x sees world x in [x - W/2, x - W/2 + 1). */
            int emitter = x < W / 2;
            char name[32];
            for (int c = 0; c < 3; c++) {
                snprintf(name, sizeof name, "albedo.%s", rgb[c]);
                bad += plane_at(img, name, i) != (emitter ? EBASE[c] : BASE[c]);
                snprintf(name, sizeof name, "N.%s", xyz[c]);
                bad += plane_at(img, name, i) != (c == 2 ? 1.0f : 0.0f);
                snprintf(name, sizeof name, "emission.%s", rgb[c]);
                bad += plane_at(img, name, i) != (emitter ? EMIT[c] : 0.0f);
            }
            bad += plane_at(img, "depth.Z", i) != HEIGHT;
            const char *vars[] = {"albedo.variance", "N.variance", "depth.variance",
                                  "emission.variance"};
            for (int k = 0; k < 4; k++)
                bad += !(plane_at(img, vars[k], i) <= 1e-12f);
            if (bad && y == 0 && x < 8)
                fprintf(stderr, "pixel %u,%u: albedo %g %g %g N %g %g %g depth %.9g emission %g\n",
                        x, y, plane_at(img, "albedo.R", i), plane_at(img, "albedo.G", i),
                        plane_at(img, "albedo.B", i), plane_at(img, "N.X", i),
                        plane_at(img, "N.Y", i), plane_at(img, "N.Z", i),
                        plane_at(img, "depth.Z", i), plane_at(img, "emission.R", i));
        }
    CHECKF(bad == 0, "%d pass values of the planes differ from the closed form", bad);
    pt_image_free(img);

    /* A renderer without passes writes zeros into the pass sums. */
    pt_renderer *plain = renderer(s, env, W, 0);
    static pt_pixel_acc acc[W * W], acc2[W * W];
    static pt_pass_acc pacc[W * W], zero[W * W];
    memset(pacc, 0xab, sizeof pacc);
    const pt_rect all = {0, 0, W, W};
    pt_render_tile_passes(plain, all, 0, SPP, acc, pacc, NULL, NULL);
    CHECK(memcmp(pacc, zero, sizeof pacc) == 0);
    CHECK(strcmp(pt_renderer_variant(plain), "passes") != 0);
    /* ... and the same beauty as the passes variant. */
    pt_render_tile_passes(r, all, 0, SPP, acc2, pacc, NULL, NULL);
    CHECK(memcmp(acc, acc2, sizeof acc) == 0);
    pt_renderer_free(plain);
    pt_renderer_free(r);
    pt_scene_free(s);
    pt_env_free(env);
}

/* A UV sphere of radius 1 at the origin: NU segments around, NV rings. */
#define NU 128u
#define NV 64u
static pt_scene *sphere_scene(float half_width)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    m.metallic = 0.0f;
    m.specular = 0.0f;
    uint32_t mm = 0;
    CHECK(pt_scene_builder_add_material(b, &m, &mm, &err) == PT_OK);
    uint32_t nv = (NU + 1) * (NV + 1), nt = 2 * NU * NV;
    float *pos = pt_malloc_array(3 * nv, sizeof *pos);
    uint32_t *idx = pt_malloc_array(3 * nt, sizeof *idx);
    CHECK(pos && idx);
    for (uint32_t j = 0; j <= NV; j++)
        for (uint32_t i = 0; i <= NU; i++) {
            double th = PT_PI * j / NV, ph = 2.0 * PT_PI * i / NU;
            float *p = &pos[3 * (j * (NU + 1) + i)];
            p[0] = (float)(sin(th) * cos(ph));
            p[1] = (float)cos(th);
            p[2] = (float)(sin(th) * sin(ph));
        }
    uint32_t t = 0;
    for (uint32_t j = 0; j < NV; j++)
        for (uint32_t i = 0; i < NU; i++) {
            uint32_t a = j * (NU + 1) + i, b2 = a + 1, c = a + NU + 1, d = c + 1;
            uint32_t *q = &idx[3 * t];
            q[0] = a, q[1] = b2, q[2] = d, q[3] = a, q[4] = d, q[5] = c;
            t += 2;
        }
    /* The vertex normals are the positions: the sphere's own. */
    CHECK(pt_scene_builder_add_mesh(b, "sphere", pos, pos, NULL, nv, idx, nt, NULL, mm, &err) ==
          PT_OK);
    pt_free(pos);
    pt_free(idx);
    pt_camera cam = pt_test_ortho_down(0, 0, HEIGHT, half_width);
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

static void sphere_passes(void)
{
    const uint32_t w = 16;
    const float hw = 1.2f, px = 2.0f * hw / (float)w; /* a pixel's side */
    pt_env *env = NULL;
    pt_error err = {0};
    CHECK(pt_env_uniform(pt_v3(1, 1, 1), &env, &err) == PT_OK);
    pt_scene *s = sphere_scene(hw);
    pt_renderer *r = renderer(s, env, w, PT_PASS_ALL);
    if (!s || !r)
        return;
    /* A triangle spans at most dphi = 2 pi / NU around and dth = pi / NV
     * down: its plane lies within R (1 - cos(d)) <= R d^2 / 2 of the sphere
     * (d the diagonal angle), and an interpolated vertex normal within d of
     * the sphere's normal at the hit. */
    double d = hypot(2.0 * PT_PI / NU, PT_PI / NV);
    double sag = d * d / 2.0, ntol = d + 1e-5;
    int checked = 0, bad = 0;
    for (uint32_t y = 0; y < w; y++)
        for (uint32_t x = 0; x < w; x++) {
            /* The footprint: world x in [x0, x0 + px), y (up) in (y0 - px, y0]. */
            double x0 = -hw + x * px, y0 = hw - y * px;
            double far =
                fmax(hypot(x0, y0),
                     fmax(hypot(x0 + px, y0), fmax(hypot(x0, y0 - px), hypot(x0 + px, y0 - px))));
            if (far > 0.9)
                continue; /* keep to the sphere's inside, away from its silhouette */
            for (uint32_t k = 0; k < 8; k++) {
                pt_pass_sample ps;
                int covered = 0;
                pt_render_sample_passes(r, x, y, k, NULL, &covered, &ps);
                checked++;
                pt_vec3 n = ps.normal;
                double len = sqrt((double)n.x * n.x + (double)n.y * n.y + (double)n.z * n.z);
                /* The hit on the sphere from its normal: (x, y) = R n.xy
                 * within the normal's bound, inside the footprint. */
                int ok = covered && fabs(len - 1.0) < 1e-5 && n.z > 0.0f;
                ok = ok && n.x >= x0 - ntol && n.x <= x0 + px + ntol && n.y <= y0 + ntol &&
                     n.y >= y0 - px - ntol;
                /* Depth: the camera's height less the sphere's z at the hit,
                 * sqrt(1 - x^2 - y^2) = n.z, within the normal's and the
                 * chord's bounds. */
                ok = ok && fabs((double)ps.depth - (HEIGHT - n.z)) <= ntol + sag;
                ok = ok && ps.albedo.x == 1.0f && ps.emission.x == 0.0f;
                if (!ok && bad++ < 4)
                    fprintf(stderr, "sphere pixel %u,%u sample %u: N %g %g %g depth %.7g\n", x, y,
                            k, n.x, n.y, n.z, ps.depth);
            }
        }
    CHECK(checked > 100);
    CHECKF(bad == 0, "%d of %d sphere samples off the closed form", bad, checked);
    /* A ray that escapes: zeros. */
    pt_pass_sample ps;
    int covered = 1;
    pt_render_sample_passes(r, 0, 0, 0, NULL, &covered, &ps);
    CHECK(!covered && ps.depth == 0.0f && ps.normal.z == 0.0f && ps.albedo.x == 0.0f);
    pt_renderer_free(r);
    pt_scene_free(s);
    pt_env_free(env);
}

/* A smooth metal mirror tilted 45 degrees about X, under a camera looking
 * down -Z, reflects the view to +Y, onto a Lambert wall at y = 5. */
static void mirror_albedo(void)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material mir = pt_material_default(), wall = pt_material_default();
    const float F0[3] = {0.9f, 0.8f, 0.6f}, WALL[3] = {0.25f, 0.5f, 0.75f};
    memcpy(mir.base_color, F0, sizeof F0);
    mir.metallic = 1.0f;
    mir.roughness = 0.0f;
    memcpy(wall.base_color, WALL, sizeof WALL);
    wall.metallic = 0.0f;
    wall.specular = 0.0f;
    uint32_t mm = 0, mw = 0;
    CHECK(pt_scene_builder_add_material(b, &mir, &mm, &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &wall, &mw, &err) == PT_OK);
    const float P = 50.0f;
    /* The mirror: the plane z = -y (normal (0, 1, 1) / sqrt 2). */
    float qm[12] = {-P, -P, P, P, -P, P, P, P, -P, -P, P, -P};
    float qw[12] = {-P, 5, -P, -P, 5, P, P, 5, P, P, 5, -P};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "mirror", qm, NULL, NULL, 4, idx, 2, NULL, mm, &err) ==
          PT_OK);
    CHECK(pt_scene_builder_add_mesh(b, "wall", qw, NULL, NULL, 4, idx, 2, NULL, mw, &err) == PT_OK);
    pt_camera cam = pt_test_ortho_down(0, 0, HEIGHT, 1.0f);
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    pt_env *env = NULL;
    CHECK(pt_env_uniform(pt_v3(1, 1, 1), &env, &err) == PT_OK);
    pt_renderer *r = renderer(s, env, 4, PT_PASS_ALL);
    if (!s || !r)
        return;
    /* The smooth GGX lobe (alpha PT_BSDF_MIN_ALPHA) reflects with Schlick's
     * F at cos 45 degrees and a masking term within 1e-3 of 1. */
    double c5 = pow(1.0 - sqrt(0.5), 5.0);
    int bad = 0;
    for (uint32_t k = 0; k < 16; k++) {
        pt_pass_sample ps;
        pt_render_sample_passes(r, 1, 2, k, NULL, NULL, &ps);
        const float *a = &ps.albedo.x;
        for (int c = 0; c < 3; c++) {
            double f = F0[c] + (1.0 - F0[c]) * c5;
            bad += fabs(a[c] - f * WALL[c]) > 2e-3 * f * WALL[c];
        }
        /* The wall's normal, facing the ray (-Y), and the depth to the
         * mirror (first hit: z = -y, at the pixel's y near 0: depth about
         * HEIGHT). */
        bad += fabsf(ps.normal.y + 1.0f) > 1e-6f;
        bad += fabsf(ps.depth - HEIGHT) > 1.0f;
        if (bad && k == 0)
            fprintf(stderr, "mirror: albedo %g %g %g, N %g %g %g, depth %g\n", a[0], a[1], a[2],
                    ps.normal.x, ps.normal.y, ps.normal.z, ps.depth);
    }
    CHECKF(bad == 0, "%d values of the albedo through the mirror off", bad);
    pt_renderer_free(r);
    pt_scene_free(s);
    pt_env_free(env);
}

static void halves(void)
{
    const uint32_t w = 32, spp = 64;
    pt_env *env = NULL;
    pt_error err = {0};
    CHECK(pt_env_uniform(pt_v3(1, 1, 1), &env, &err) == PT_OK);
    pt_scene *s = sphere_scene(1.2f);
    pt_renderer *r = renderer(s, env, w, PT_PASS_ALL);
    if (!s || !r)
        return;
    pt_pixel_acc *acc = pt_calloc((size_t)w * w, sizeof *acc);
    pt_pass_acc *pacc = pt_calloc((size_t)w * w, sizeof *pacc);
    pt_pixel_acc *acc2 = pt_calloc((size_t)w * w, sizeof *acc2);
    pt_pass_acc *pacc2 = pt_calloc((size_t)w * w, sizeof *pacc2);
    pt_pixel_acc *part = pt_calloc((size_t)w * w, sizeof *part);
    pt_pass_acc *ppart = pt_calloc((size_t)w * w, sizeof *ppart);
    CHECK(acc && pacc && acc2 && pacc2 && part && ppart);
    const pt_rect all = {0, 0, w, w};
    pt_render_tile_passes(r, all, 0, spp, acc, pacc, NULL, NULL);
    /* The blocks in reverse order, two tiles of the image: the same bits. */
    for (uint32_t b0 = spp; b0 > 0; b0 -= PT_SAMPLE_BLOCK) {
        for (uint32_t h = 0; h < 2; h++) {
            pt_rect t = {0, h * w / 2, w, (h + 1) * w / 2};
            pt_render_tile_passes(r, t, b0 - PT_SAMPLE_BLOCK, b0, part, ppart, NULL, NULL);
            for (uint32_t i = 0; i < w * w / 2; i++) {
                pt_pixel_acc_add(&acc2[h * w * w / 2 + i], &part[i]);
                pt_pass_acc_add(&pacc2[h * w * w / 2 + i], &ppart[i]);
            }
        }
    }
    CHECK(memcmp(acc, acc2, (size_t)w * w * sizeof *acc) == 0);
    CHECK(memcmp(pacc, pacc2, (size_t)w * w * sizeof *pacc) == 0);
    /* The parity of the sample index: sample 0 alone is all even, sample 1
     * alone all odd. */
    int parity = 1;
    for (uint32_t k = 0; k < 2; k++) {
        pt_render_tile_passes(r, all, k, k + 1, part, ppart, NULL, NULL);
        for (uint32_t i = 0; i < w * w; i++)
            for (int c = 0; c < 3; c++)
                parity &= ppart[i].n_even == (k == 0 ? part[i].n : 0) &&
                          ppart[i].s[PT_PS_EVEN + c] == (k == 0 ? part[i].fsum[c] : 0);
    }
    CHECK(parity);
    /* The batched tile against one sample at a time: the same sums. */
    int same = 1;
    for (uint32_t y = 0; y < 4; y++)
        for (uint32_t x = 0; x < w; x += 5) {
            pt_pass_block pb;
            pt_block_acc blk = {{0, 0, 0}, 0, 0, 0};
            pt_pass_acc one;
            memset(&pb, 0, sizeof pb);
            memset(&one, 0, sizeof one);
            for (uint32_t k = 0; k < PT_SAMPLE_BLOCK; k++) {
                pt_pass_sample ps;
                pt_vec3 c = pt_render_sample_passes(r, x, y + w / 2 - 2, k, NULL, NULL, &ps);
                if (pt_block_acc_sample(&blk, c))
                    pt_pass_block_sample(&pb, &ps, c, k);
            }
            pt_pass_acc_add_block(&one, &pb);
            pt_render_tile_passes(r, (pt_rect){x, y + w / 2 - 2, x + 1, y + w / 2 - 1}, 0,
                                  PT_SAMPLE_BLOCK, part, ppart, NULL, NULL);
            same &= memcmp(&one, ppart, sizeof one) == 0;
        }
    CHECK(same);

    pt_film *film = NULL;
    pt_image *img = NULL;
    CHECK(pt_film_new(w, w, &film, &err) == PT_OK);
    CHECK(pt_film_enable_passes(film, PT_PASS_HALVES, &err) == PT_OK);
    CHECK(pt_image_new(w, w, &img, &err) == PT_OK);
    pt_film_add_tile_passes(film, all, acc, pacc);
    pt_film_resolve(film, img);
    /* Only the passes asked for. */
    CHECK(pt_image_find_plane(img, "halfA.R") && !pt_image_find_plane(img, "albedo.R"));
    double z2 = 0.0;
    uint32_t npix = 0;
    int bad = 0;
    for (uint32_t i = 0; i < w * w; i++) {
        bad += pacc[i].n_even != spp / 2 || acc[i].n != spp;
        const float *ha[3] = {pt_image_find_plane(img, "halfA.R"),
                              pt_image_find_plane(img, "halfA.G"),
                              pt_image_find_plane(img, "halfA.B")};
        const float *hb[3] = {pt_image_find_plane(img, "halfB.R"),
                              pt_image_find_plane(img, "halfB.G"),
                              pt_image_find_plane(img, "halfB.B")};
        const float *beauty[3] = {img->r, img->g, img->b};
        float la = 0, lb = 0;
        const float wl[3] = {0.2126f, 0.7152f, 0.0722f};
        for (int c = 0; c < 3; c++) {
            /* Weighted by their counts the halves are the beauty. */
            double m = 0.5 * ((double)ha[c][i] + hb[c][i]);
            bad += fabs(m - beauty[c][i]) > 1e-6 * fabs(beauty[c][i]) + 1e-9;
            la += wl[c] * ha[c][i];
            lb += wl[c] * hb[c][i];
        }
        /* Each half's mean has twice the beauty mean's variance. */
        if (img->variance[i] > 0.0f) {
            z2 += (double)(la - lb) * (la - lb) / (4.0 * img->variance[i]);
            npix++;
        }
    }
    CHECKF(bad == 0, "%d pixels whose halves do not average to the beauty", bad);
    CHECK(npix > w * w / 4);
    double mz2 = z2 / npix, se = sqrt(2.0 / npix);
    CHECKF(fabs(mz2 - 1.0) < 5.0 * se, "halves' difference: mean z^2 %.3f over %u pixels (se %.3f)",
           mz2, npix, se);
    pt_image_free(img);
    pt_film_free(film);
    pt_free(acc);
    pt_free(pacc);
    pt_free(acc2);
    pt_free(pacc2);
    pt_free(part);
    pt_free(ppart);
    pt_renderer_free(r);
    pt_scene_free(s);
    pt_env_free(env);
}

/* The Cornell box of scenes/: the passes variant's beauty is the bits of
 * the Lambert variant's. */
static void cornell_same_beauty(void)
{
    pt_scene *s = NULL;
    pt_error err = {0};
    CHECKF(pt_scene_load(PT_SOURCE_DIR "/scenes/cornell_box.gltf", NULL, &s, &err) == PT_OK, "%s",
           err.msg);
    if (!s)
        return;
    const uint32_t w = 24;
    pt_renderer *a = renderer(s, NULL, w, 0), *b = renderer(s, NULL, w, PT_PASS_ALL);
    if (!a || !b)
        return;
    CHECK(!strcmp(pt_renderer_variant(b), "passes") && strcmp(pt_renderer_variant(a), "passes"));
    pt_pixel_acc *x = pt_calloc((size_t)w * w, sizeof *x), *y = pt_calloc((size_t)w * w, sizeof *y);
    pt_pass_acc *p = pt_calloc((size_t)w * w, sizeof *p);
    const pt_rect all = {0, 0, w, w};
    pt_render_tile(a, all, 0, 32, x, NULL);
    pt_render_tile_passes(b, all, 0, 32, y, p, NULL, NULL);
    CHECK(memcmp(x, y, (size_t)w * w * sizeof *x) == 0);
    /* The box's walls are Lambert: its albedo never exceeds 1 and is
     * mostly positive; every normal has length 1 where something was hit. */
    int bad = 0, lit = 0;
    for (uint32_t i = 0; i < w * w; i++) {
        double n = y[i].n;
        double ar = pt_fixed_to_double(p[i].s[PT_PS_ALBEDO]) / n;
        lit += ar > 0.0;
        bad += !(ar >= 0.0 && ar <= 1.0);
    }
    CHECK(bad == 0 && lit > (int)(w * w / 2));
    pt_free(x);
    pt_free(y);
    pt_free(p);
    pt_renderer_free(a);
    pt_renderer_free(b);
    pt_scene_free(s);
}

static void exr_layers(void)
{
    pt_image *img = NULL, *back = NULL, *plain = NULL;
    pt_error err = {0};
    CHECK(pt_image_new(5, 3, &img, &err) == PT_OK);
    pt_pass_planes pl;
    CHECK(pt_passes_add_planes(img, PT_PASS_ALL, &pl, &err) == PT_OK);
    CHECK(img->n_planes == 20 + 32); /* 32: Cryptomatte's 2 kinds x 4 layers x RGBA */
    for (uint32_t k = 0; k < img->n_planes; k++)
        for (uint32_t i = 0; i < 15; i++)
            img->planes[k].data[i] = (float)(k * 100 + i) * 0.25f - 3.0f;
    for (uint32_t i = 0; i < 15; i++)
        img->r[i] = img->g[i] = img->b[i] = (float)i;
    /* Refusals: a base channel's name, a control byte, too long, empty. */
    CHECK(pt_image_add_plane(img, "R", NULL, &err) == PT_ERR_ARG);
    CHECK(pt_image_add_plane(img, "a\nb", NULL, &err) == PT_ERR_ARG);
    CHECK(pt_image_add_plane(img, "0123456789012345678901234567890123", NULL, &err) == PT_ERR_ARG);
    CHECK(pt_image_add_plane(img, "", NULL, &err) == PT_ERR_ARG);
    char path[64];
    snprintf(path, sizeof path, "/tmp/pt_test_passes_%d.exr", (int)getpid());
    CHECKF(pt_exr_write(path, img, NULL, &err) == PT_OK, "%s", err.msg);
    CHECKF(pt_exr_read_layers(path, &back, NULL, &err) == PT_OK, "%s", err.msg);
    CHECK(pt_exr_read(path, &plain, NULL, &err) == PT_OK);
    if (back) {
        CHECK(back->n_planes == img->n_planes);
        for (uint32_t k = 0; k < img->n_planes; k++) {
            const float *d = pt_image_find_plane(back, img->planes[k].name);
            CHECKF(d && memcmp(d, img->planes[k].data, 15 * sizeof *d) == 0, "plane %s",
                   img->planes[k].name);
        }
        CHECK(memcmp(back->g, img->g, 15 * sizeof(float)) == 0);
    }
    CHECK(plain && plain->n_planes == 0);
    unlink(path);
    pt_image_free(back);
    pt_image_free(plain);
    pt_image_free(img);
}

int main(void)
{
    parse();
    plane_passes();
    sphere_passes();
    mirror_albedo();
    halves();
    cornell_same_beauty();
    exr_layers();
    CHECK(pt_alloc_live() == 0);
    return check_report();
}
