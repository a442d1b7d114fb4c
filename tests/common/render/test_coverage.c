/*
 * test_coverage.c - the camera-ray coverage a pixel accumulates (hits), the
 * transparent film (render.h, film.h, exr.h) and the count of paths ended by
 * the depth cap (pt_render_stats.capped).
 *
 * - A Lambert half-plane seen by an orthographic camera under a uniform sky,
 *   its edge across one column of pixels: with a transparent film the
 *   background's RGB is exactly 0 and its coverage 0, a covered pixel's
 *   coverage exactly 1 and its radiance rho L (the sky still lights it), the
 *   edge pixel's coverage the covered fraction of its area within 5 standard
 *   deviations of a binomial proportion over its samples.
 * - The film resolves hits / n into A; the EXR has an A channel only then.
 * - A closed box with max depth 2 and Russian roulette from 3 bounces: every
 *   path reaches the cap, so the count is exactly the samples; at the default
 *   depth none does.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/image/exr.h"
#include "common/render/env.h"
#include "common/render/film.h"
#include "common/render/render.h"
#include "tests/check.h"
#include "tests/common/render/ortho.h"

#define W 8u
#define SPP 256u
/* The half-plane covers x >= EDGE; pixel px sees x in [px - W/2, px - W/2 + 1). */
#define EDGE 0.3f

/* An orthographic camera looking down -Z at a Lambert half-plane of albedo rho. */
static pt_scene *half_plane(float rho)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    m.base_color[0] = m.base_color[1] = m.base_color[2] = rho;
    m.metallic = 0.0f;
    m.specular = 0.0f;
    uint32_t mat = 0;
    CHECK(pt_scene_builder_add_material(b, &m, &mat, &err) == PT_OK);
    const float P = 100.0f;
    float q[12] = {EDGE, -P, 0, P, -P, 0, P, P, 0, EDGE, P, 0};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "half", q, NULL, NULL, 4, idx, 2, NULL, mat, &err) == PT_OK);
    pt_camera cam = pt_test_ortho_down(0, 0, 10, (float)W / 2);
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

static pt_renderer *renderer(const pt_scene *s, const pt_env *env, uint32_t transparent,
                             uint32_t max_depth, uint32_t scalar)
{
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = p.height = W;
    p.seed = 3;
    p.env = env;
    p.transparent = transparent;
    p.max_depth = max_depth;
    p.scalar_shading = scalar;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    return r;
}

static void transparent_film(void)
{
    const float rho = 0.5f, L = 2.0f;
    pt_env *env = NULL;
    pt_error err = {0};
    CHECK(pt_env_uniform(pt_v3(L, L, L), &env, &err) == PT_OK);
    pt_scene *s = half_plane(rho);
    static pt_pixel_acc acc[W * W], opaque[W * W];
    const pt_rect all = {0, 0, W, W};
    pt_renderer *r = renderer(s, env, 1, PT_RENDER_DEFAULT_MAX_DEPTH, 0);
    pt_renderer *o = renderer(s, env, 0, PT_RENDER_DEFAULT_MAX_DEPTH, 0);
    if (!r || !o)
        return;
    pt_render_stats st = {0};
    pt_render_tile(r, all, 0, SPP, acc, &st);
    pt_render_tile(o, all, 0, SPP, opaque, NULL);
    CHECK(st.rejected == 0 && st.capped == 0);
    const uint32_t edge_px = W / 2; /* x in [0, 1): covered from EDGE on */
    const double frac = 1.0 - EDGE;
    int bad_bg = 0, bad_full = 0;
    double full_sum = 0.0, full_var = 0.0;
    for (uint32_t y = 0; y < W; y++) {
        for (uint32_t x = 0; x < W; x++) {
            const pt_pixel_acc *a = &acc[y * W + x], *b = &opaque[y * W + x];
            CHECK(a->n == SPP && a->hits <= a->n);
            /* The same paths either way: only the escaped camera rays differ. */
            CHECK(a->hits == b->hits);
            if (x < edge_px) {
                bad_bg += a->hits != 0 || pt_acc_sum(a, 0) != 0.0 || pt_acc_sum(a, 1) != 0.0 ||
                          pt_acc_sum(a, 2) != 0.0 || pt_acc_sum_sq(a) != 0.0;
                /* Opaque: the sky itself, exactly. */
                bad_bg += pt_acc_sum(b, 1) != (double)L * SPP;
            } else if (x > edge_px) {
                bad_full += a->hits != a->n;
                bad_full += memcmp(a->fsum, b->fsum, sizeof a->fsum) != 0;
                double n = a->n, mean = pt_acc_sum(a, 1) / n;
                full_sum += mean;
                full_var += fmax((pt_acc_sum_sq(a) - n * mean * mean) / (n - 1.0), 0.0) / n;
            } else {
                /* A binomial proportion over SPP samples (stratified samples
                 * only do better). */
                double cov = (double)a->hits / a->n;
                double sd = sqrt(frac * (1.0 - frac) / a->n);
                CHECKF(fabs(cov - frac) < 5.0 * sd, "edge pixel row %u: coverage %.4f, area %.4f",
                       y, cov, frac);
                CHECK(a->hits > 0 && a->hits < a->n);
            }
        }
    }
    CHECKF(bad_bg == 0, "%d background pixels not exactly 0 (transparent) or the sky (opaque)",
           bad_bg);
    CHECKF(bad_full == 0, "%d covered pixels not of coverage 1 or differing from opaque", bad_full);
    /* The sky lights the plane through NEE and bounces: rho L. */
    uint32_t nfull = W * (W - edge_px - 1);
    double mean = full_sum / nfull, se = sqrt(full_var) / nfull;
    CHECKF(fabs(mean - rho * L) < 5.0 * se + 1e-6, "covered pixels %.5f, expected %.5f (se %.2e)",
           mean, (double)(rho * L), se);

    /* Split at block boundaries and merged in order: the same bits, hits too. */
    static pt_pixel_acc part[W * W], sum[W * W];
    memset(sum, 0, sizeof sum);
    for (uint32_t s0 = 0; s0 < SPP; s0 += PT_SAMPLE_BLOCK) {
        pt_render_tile(r, all, s0, s0 + PT_SAMPLE_BLOCK, part, NULL);
        for (uint32_t i = 0; i < W * W; i++)
            pt_pixel_acc_add(&sum[i], &part[i]);
    }
    CHECK(memcmp(sum, acc, sizeof acc) == 0);

    /* The film: A = hits / n; the EXR gets A only on a transparent film. */
    pt_film *film = NULL;
    pt_image *img = NULL, *back = NULL;
    CHECK(pt_film_new(W, W, &film, &err) == PT_OK && pt_image_new(W, W, &img, &err) == PT_OK);
    if (film && img) {
        pt_film_add_tile(film, all, acc);
        pt_film_resolve(film, img);
        int bad_a = 0;
        for (uint32_t i = 0; i < W * W; i++)
            bad_a += img->a[i] != (float)((double)acc[i].hits / acc[i].n);
        CHECK(bad_a == 0 && img->a[0] == 0.0f && img->a[W - 1] == 1.0f);
        char path[] = "/tmp/pt_test_coverage_XXXXXX";
        int fd = mkstemp(path);
        CHECK(fd >= 0);
        if (fd >= 0)
            close(fd);
        img->has_alpha = 1;
        CHECK(pt_exr_write(path, img, NULL, &err) == PT_OK);
        CHECK(pt_exr_read(path, &back, NULL, &err) == PT_OK);
        if (back) {
            CHECK(back->has_alpha == 1 && memcmp(back->a, img->a, W * W * sizeof(float)) == 0);
            CHECK(memcmp(back->r, img->r, W * W * sizeof(float)) == 0);
            pt_image_free(back);
            back = NULL;
        }
        img->has_alpha = 0;
        CHECK(pt_exr_write(path, img, NULL, &err) == PT_OK);
        CHECK(pt_exr_read(path, &back, NULL, &err) == PT_OK);
        if (back) {
            CHECK(back->has_alpha == 0 && back->a[W - 1] == 0.0f);
            pt_image_free(back);
        }
        unlink(path);
    }
    pt_image_free(img);
    pt_film_free(film);
    pt_renderer_free(r);
    pt_renderer_free(o);
    pt_scene_free(s);
    pt_env_free(env);
}

/* A closed cube of Lambert faces around the camera (flat faces: the shading
 * normal is the geometric one, so a cosine sample never points below). */
static pt_scene *closed_box(float rho)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    m.base_color[0] = m.base_color[1] = m.base_color[2] = rho;
    m.metallic = 0.0f;
    m.specular = 0.0f;
    m.emissive[0] = m.emissive[1] = m.emissive[2] = 1.0f;
    uint32_t mat = 0;
    CHECK(pt_scene_builder_add_material(b, &m, &mat, &err) == PT_OK);
    const float v[24] = {-1, -1, -1, 1, -1, -1, 1, 1, -1, -1, 1, -1,
                         -1, -1, 1,  1, -1, 1,  1, 1, 1,  -1, 1, 1};
    /* The corners of each face, wound to face inwards. A mesh per face, so
     * that no vertex normal is averaged over two faces. */
    const uint32_t face[6][4] = {{0, 1, 2, 3}, {4, 7, 6, 5}, {0, 4, 5, 1},
                                 {3, 2, 6, 7}, {0, 3, 7, 4}, {1, 5, 6, 2}};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    for (int f = 0; f < 6; f++) {
        float q[12];
        for (int k = 0; k < 4; k++)
            memcpy(&q[3 * k], &v[3 * face[f][k]], 3 * sizeof(float));
        CHECK(pt_scene_builder_add_mesh(b, "face", q, NULL, NULL, 4, idx, 2, NULL, mat, &err) ==
              PT_OK);
    }
    pt_camera cam = {0};
    cam.forward = pt_v3(0, 0, -1);
    cam.right = pt_v3(1, 0, 0);
    cam.up = pt_v3(0, 1, 0);
    cam.yfov = 1.2f;
    cam.aspect = 1.0f;
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

static void depth_cap(void)
{
    pt_scene *s = closed_box(0.5f);
    static pt_pixel_acc acc[W * W];
    const pt_rect all = {0, 0, W, W};
    /* Roulette from 3 bounces, the cap at 2: no path ends before the cap
     * (every ray hits, every bounce scatters), so every path is capped. Both
     * shadings (lanes and per path) and the one-path reference agree. */
    for (uint32_t scalar = 0; scalar < 2; scalar++) {
        pt_renderer *r = renderer(s, NULL, 0, 2, scalar);
        if (!r)
            continue;
        pt_render_stats st = {0};
        pt_render_tile(r, all, 0, 48, acc, &st);
        CHECKF(st.samples == W * W * 48 && st.capped == st.samples,
               "%s: %llu paths capped of %llu samples", scalar ? "per path" : "lanes",
               (unsigned long long)st.capped, (unsigned long long)st.samples);
        pt_render_stats one = {0};
        for (uint32_t i = 0; i < 16; i++)
            pt_render_sample(r, 3, 4, i, &one, NULL);
        CHECK(one.capped == 16);
        pt_renderer_free(r);
    }
    /* At the default cap Russian roulette ends every path first. */
    pt_renderer *r = renderer(s, NULL, 0, PT_RENDER_DEFAULT_MAX_DEPTH, 0);
    if (r) {
        pt_render_stats st = {0};
        pt_render_tile(r, all, 0, 48, acc, &st);
        CHECK(st.samples == W * W * 48 && st.capped == 0);
        int all_hit = 1;
        for (uint32_t i = 0; i < W * W; i++)
            all_hit &= acc[i].hits == acc[i].n;
        CHECK(all_hit);
        pt_renderer_free(r);
    }
    pt_scene_free(s);
}

int main(void)
{
    transparent_film();
    depth_cap();
    return check_report();
}
