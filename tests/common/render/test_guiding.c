/*
 * test_guiding.c - path guiding through the integrator (render.h,
 * pt_render_tile_guided; the SD-tree itself is test_guide.c's).
 *
 * A render is guided as ptworker does it: a first pass records into
 * statistics of a uniform guide without sampling it, the guide built from
 * them is sampled by half of a guided vertex's directions in the second.
 *
 * - Unbiased, analytically: the white furnace (scenes/furnace.gltf with flat
 *   normals, albedo 0.5, emission 1; test_render.c) forced onto the guided
 *   variant reads 1 / (1 - 0.5) = 2 within 0.1 % and 5 standard errors, with
 *   the guide sampled at every bounce and weighed by MIS against NEE.
 * - Unbiased against the unguided render: the same sphere made a glossy
 *   dielectric (roughness 0.4) has no closed form; guided and unguided
 *   images agree over the image and pixel by pixel within 5 standard errors
 *   (at most 1 of 256 pixels beyond, as chance allows). The same for the
 *   NVIDIA Cornell box (../shared; mirror spheres, a small bright light)
 *   and scenes/glass_things.gltf under the studio map (a glass ball's
 *   caustic), at most 2 of 256 pixels beyond: a pixel whose rare caustic
 *   paths neither render caught has its variance underestimated.
 * - The guide learns: the second pass's guide has more than one directional
 *   node, and its statistics saw records.
 * - Behind glass: a Lambert floor seen through three thin smooth panes (its
 *   paths' first rough vertex, their fourth bounce) is guided and recorded:
 *   its cell learns the lamp, and its guided render agrees with the
 *   unguided one (images_agree) without being its bits.
 * - Bits: a guided tile equals the same samples traced one path at a time
 *   (pt_render_sample_guided) and summed in order, and the statistics of a
 *   tile equal, exactly, the merged statistics of its halves rendered apart.
 * - A glossy vertex keeps its BSDF: a metal of roughness 0.5 renders guided
 *   the same bits as unguided (its lobe is too narrow for the guide).
 * - The auto rule (pt_guide_auto): off for a Lambert sphere, a rough and a
 *   smooth dielectric one and a metal one; on for glass.
 * - Off costs nothing: a renderer made without params.guiding ignores a
 *   guide it is handed (the same bits as pt_render_tile), and a Lambert scene
 *   with guiding asked keeps its own variant.
 */
#include <math.h>
#include <pthread.h>
#include <string.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/image/envmap.h"
#include "common/render/env.h"
#include "common/render/guide.h"
#include "common/render/render.h"
#include "common/scene/scene.h"
#include "tests/check.h"
#include "tests/common/render/furnace.h"

/* The furnace's sphere with flat normals (furnace.h), emission 1, base
 * colour albedo, and the given metallic, roughness and specular. */
static pt_scene *furnace(float albedo, float metallic, float roughness, float specular)
{
    const float mrs[3] = {metallic, roughness, specular};
    return flat_furnace_of(albedo, 1.0f, mrs);
}

static pt_renderer *renderer_env(const pt_scene *s, uint32_t w, uint32_t h, int guiding,
                                 const pt_env *env)
{
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = w;
    p.height = h;
    p.seed = 5;
    p.guiding = (uint32_t)guiding;
    p.env = env;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    return r;
}

static void quiet(void *user, const char *message)
{
    (void)user;
    (void)message;
}

static pt_renderer *renderer(const pt_scene *s, uint32_t w, uint32_t h, int guiding, uint32_t extra)
{
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = w;
    p.height = h;
    p.seed = 5;
    p.guiding = (uint32_t)guiding;
    p.extra_features = extra;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    return r;
}

typedef struct half_job {
    const pt_renderer *r;
    pt_rect rows;
    uint32_t s0, s1;
    pt_pixel_acc *acc;
    pt_render_guiding gd;
} half_job;

static void *render_half(void *arg)
{
    half_job *j = arg;
    pt_render_tile_guided(j->r, j->rows, j->s0, j->s1, j->acc, NULL, j->gd.guide ? &j->gd : NULL);
    return NULL;
}

/* Samples [s0, s1) of the w x h image on two threads (half the rows each),
 * guided by gd (prob; guide NULL: unguided) with each thread's records into
 * st[0], st[1] (may be NULL); added to acc. */
static void render_pass(const pt_renderer *r, uint32_t w, uint32_t h, uint32_t s0, uint32_t s1,
                        const pt_guide *g, float prob, pt_guide_stats *st[2], pt_pixel_acc *acc)
{
    pt_pixel_acc *part = pt_malloc_array((size_t)w * h, sizeof *part);
    if (!part)
        return;
    half_job jobs[2] = {
        {r, {0, 0, w, h / 2}, s0, s1, part, {g, prob, st ? st[0] : NULL}},
        {r, {0, h / 2, w, h}, s0, s1, part + (size_t)w * (h / 2), {g, prob, st ? st[1] : NULL}},
    };
    pthread_t th;
    int threaded = pthread_create(&th, NULL, render_half, &jobs[1]) == 0;
    render_half(&jobs[0]);
    if (threaded)
        pthread_join(th, NULL);
    else
        render_half(&jobs[1]);
    for (size_t i = 0; i < (size_t)w * h; i++)
        pt_pixel_acc_add(&acc[i], &part[i]);
    pt_free(part);
}

/* A guided render as ptworker's: [0, first) recording, the rest guided.
 * Returns the guide of the second pass (the caller frees it). */
static pt_guide *render_guided(const pt_scene *s, const pt_renderer *r, uint32_t w, uint32_t h,
                               uint32_t first, uint32_t spp, pt_pixel_acc *acc)
{
    pt_error err = {0};
    pt_guide *g = NULL, *g2 = NULL;
    pt_guide_stats *st[2] = {NULL, NULL};
    CHECK(pt_guide_new_uniform(pt_v3_sub(s->bounds_min, pt_v3(0.01f, 0.01f, 0.01f)),
                               pt_v3_add(s->bounds_max, pt_v3(0.01f, 0.01f, 0.01f)), &g,
                               &err) == PT_OK);
    CHECK(g && pt_guide_stats_new(g, &st[0], &err) == PT_OK &&
          pt_guide_stats_new(g, &st[1], &err) == PT_OK);
    if (g && st[0] && st[1]) {
        render_pass(r, w, h, 0, first, g, 0.0f, st, acc);
        CHECK(pt_guide_stats_merge(st[0], st[1], &err) == PT_OK);
        uint64_t recs = 0;
        for (uint32_t i = 0; i < st[0]->nsnode; i++)
            recs += st[0]->count[i];
        CHECKF(recs > 0, "the first pass recorded nothing");
        CHECK(pt_guide_build(g, st[0], 20000, &g2, &err) == PT_OK);
        if (g2) {
            CHECKF(g2->nqnode > 1, "the guide did not learn (%u directional nodes)", g2->nqnode);
            render_pass(r, w, h, first, spp, g2, 0.5f, NULL, acc);
        }
    }
    pt_guide_stats_free(st[0]);
    pt_guide_stats_free(st[1]);
    pt_guide_free(g);
    return g2;
}

static double lum_mean(const pt_pixel_acc *a)
{
    return pt_luminance(
               pt_v3((float)pt_acc_sum(a, 0), (float)pt_acc_sum(a, 1), (float)pt_acc_sum(a, 2))) /
           (double)a->n;
}

static double lum_var_of_mean(const pt_pixel_acc *a)
{
    double n = a->n, m = lum_mean(a);
    return fmax((pt_acc_sum_sq(a) - n * m * m) / (n - 1.0), 0.0) / n;
}

#define ALBEDO 0.5f
static void white_furnace(void)
{
    pt_scene *s = furnace(ALBEDO, 0.0f, 1.0f, 0.0f);
    if (!s)
        return;
    /* A sanitizer build: a quarter of the samples, twice the bound (check.h). */
    enum { W = 32, H = 32, SPP = CHECK_WORK(6144) };
    const double bound = CHECK_LOOSE(0.001);
    /* PT_FEAT_GLOSSY: the guided variant for a Lambert material. */
    pt_renderer *r = renderer(s, W, H, 1, PT_FEAT_GLOSSY);
    CHECK(r && strcmp(pt_renderer_variant(r), "guided") == 0);
    pt_pixel_acc *acc = pt_calloc(W * H, sizeof *acc);
    pt_guide *g2 = NULL;
    if (r && acc)
        g2 = render_guided(s, r, W, H, 256, SPP, acc);
    double sum = 0.0, var = 0.0;
    for (uint32_t i = 0; acc && i < W * H; i++) {
        sum += lum_mean(&acc[i]);
        var += lum_var_of_mean(&acc[i]);
    }
    double mean = sum / (W * H), se = sqrt(var) / (W * H), want = 1.0 / (1.0 - ALBEDO);
    CHECKF(fabs(mean - want) < bound * want && fabs(mean - want) < 5.0 * se,
           "guided furnace: %.5f, want %.5f (se %.5f)", mean, want, se);
    /* The bound is beyond 5 standard errors: a bias that large cannot hide. */
    CHECKF(5.0 * se < bound * want, "guided furnace: standard error %.5f too large", se);
    printf("guided white furnace: %.5f (exact %.5f), standard error %.2e\n", mean, want, se);
    pt_guide_free(g2);
    pt_free(acc);
    pt_renderer_free(r);
    pt_scene_free(s);
}

/* Guided image ag against unguided au (w x h): the image's summed
 * difference within 5 standard errors, and at most max_off pixels beyond
 * 5 standard errors of their own (chance allows one in 1.7 million; a
 * pixel whose rare bright paths neither render caught has its variance
 * underestimated, which max_off leaves room for). */
static void images_agree(const pt_pixel_acc *ag, const pt_pixel_acc *au, uint32_t n, int max_off,
                         const char *what)
{
    double dsum = 0.0, vsum = 0.0;
    int off = 0;
    for (uint32_t i = 0; i < n; i++) {
        double d = lum_mean(&ag[i]) - lum_mean(&au[i]);
        double v = lum_var_of_mean(&ag[i]) + lum_var_of_mean(&au[i]);
        dsum += d;
        vsum += v;
        off += fabs(d) > 5.0 * sqrt(v);
    }
    double z = vsum > 0.0 ? dsum / sqrt(vsum) : 0.0;
    CHECKF(fabs(z) < 5.0, "%s: guided and unguided images differ (z %.2f)", what, z);
    CHECKF(off <= max_off, "%s: %d of %u pixels differ beyond 5 standard errors", what, off, n);
    printf("%s: guided vs unguided z %.2f, %d of %u pixels beyond 5 se\n", what, z, off, n);
}

/* Scene s (freed here) rendered w x h at spp guided (render_guided: the
 * guide learned from samples [0, first)) and unguided: the images agree
 * (images_agree, at most 1 pixel beyond), and same_bits 1: they are the
 * same bits; -1: they are not (the guide drew directions); 0: either. */
static void guided_vs_unguided(pt_scene *s, uint32_t w, uint32_t h, uint32_t first, uint32_t spp,
                               int same_bits, const char *what)
{
    if (!s)
        return;
    pt_renderer *rg = renderer(s, w, h, 1, 0), *ru = renderer(s, w, h, 0, 0);
    pt_pixel_acc *ag = pt_calloc((size_t)w * h, sizeof *ag),
                 *au = pt_calloc((size_t)w * h, sizeof *au);
    pt_guide *g2 = NULL;
    if (rg && ru && ag && au) {
        CHECK(strcmp(pt_renderer_variant(rg), "guided") == 0);
        g2 = render_guided(s, rg, w, h, first, spp, ag);
        render_pass(ru, w, h, 0, spp, NULL, 0.0f, NULL, au);
        images_agree(ag, au, w * h, 1, what);
        int same = memcmp(ag, au, (size_t)w * h * sizeof *ag) == 0;
        CHECKF(same_bits == 0 || same == (same_bits > 0),
               "%s: guided and unguided %s the same bits", what, same ? "are" : "are not");
    }
    pt_guide_free(g2);
    pt_free(ag);
    pt_free(au);
    pt_renderer_free(rg);
    pt_renderer_free(ru);
    pt_scene_free(s);
}

static void glossy_agrees(void)
{
    guided_vs_unguided(furnace(0.8f, 0.0f, 0.4f, 1.0f), 16, 16, 256, 2048, 0, "glossy furnace");
}

static void bits(void)
{
    pt_scene *s = furnace(0.8f, 0.0f, 0.4f, 1.0f);
    if (!s)
        return;
    enum { W = 6, H = 4, S0 = 3, S1 = 37 };
    pt_error err = {0};
    pt_renderer *r = renderer(s, W, H, 1, 0), *off = renderer(s, W, H, 0, 0);
    pt_guide *g = NULL;
    pt_guide_stats *whole = NULL, *a = NULL, *b = NULL, *single = NULL;
    CHECK(pt_guide_new_uniform(pt_v3(-2, -2, -2), pt_v3(2, 2, 2), &g, &err) == PT_OK);
    if (!r || !off || !g)
        goto done;
    /* A guide with something learned, to sample from. */
    pt_guide_stats *st[2] = {NULL, NULL};
    pt_pixel_acc warm[W * H];
    memset(warm, 0, sizeof warm);
    CHECK(pt_guide_stats_new(g, &st[0], &err) == PT_OK &&
          pt_guide_stats_new(g, &st[1], &err) == PT_OK);
    render_pass(r, W, H, 0, 64, g, 0.0f, st, warm);
    pt_guide_stats_merge(st[0], st[1], &err);
    pt_guide *g2 = NULL;
    CHECK(pt_guide_build(g, st[0], 50, &g2, &err) == PT_OK);
    pt_guide_stats_free(st[0]);
    pt_guide_stats_free(st[1]);
    pt_guide_free(g);
    g = g2;
    if (!g)
        goto done;
    CHECK(pt_guide_stats_new(g, &whole, &err) == PT_OK &&
          pt_guide_stats_new(g, &a, &err) == PT_OK && pt_guide_stats_new(g, &b, &err) == PT_OK &&
          pt_guide_stats_new(g, &single, &err) == PT_OK);
    if (!single)
        goto done;
    pt_rect all = {0, 0, W, H};
    pt_pixel_acc tile[W * H], ref[W * H], plain[W * H], ignored[W * H];
    pt_render_guiding gw = {g, 0.5f, whole}, gs = {g, 0.5f, single};
    pt_render_tile_guided(r, all, S0, S1, tile, NULL, &gw);
    memset(ref, 0, sizeof ref);
    for (uint32_t k = 0; k < W * H; k++)
        for (uint32_t b0 = S0; b0 < S1;) {
            uint32_t b1 = (b0 / PT_SAMPLE_BLOCK + 1) * PT_SAMPLE_BLOCK;
            b1 = b1 < S1 ? b1 : S1;
            pt_block_acc blk = {{0, 0, 0}, 0, 0, 0};
            for (uint32_t i = b0; i < b1; i++) {
                int cov = 0;
                if (pt_block_acc_sample(
                        &blk, pt_render_sample_guided(r, k % W, k / W, i, NULL, &cov, &gs)))
                    blk.hits += (uint32_t)cov;
            }
            pt_pixel_acc_add_block(&ref[k], &blk);
            b0 = b1;
        }
    CHECKF(memcmp(tile, ref, sizeof tile) == 0, "a guided tile differs from one path at a time");
    CHECK(memcmp(whole->sum, single->sum, g->nqnode * sizeof *whole->sum) == 0 &&
          memcmp(whole->count, single->count, g->nsnode * sizeof *whole->count) == 0);
    /* The tile's statistics equal its two halves', rendered apart. */
    pt_render_guiding ga = {g, 0.5f, a}, gb = {g, 0.5f, b};
    pt_pixel_acc part[W * H];
    pt_rect top = {0, 0, W, H / 2}, bottom = {0, H / 2, W, H};
    pt_render_tile_guided(r, bottom, S0, S1, part, NULL, &gb);
    pt_render_tile_guided(r, top, S0, S1, part, NULL, &ga);
    CHECK(pt_guide_stats_merge(b, a, &err) == PT_OK);
    CHECKF(memcmp(whole->sum, b->sum, g->nqnode * sizeof *b->sum) == 0 &&
               memcmp(whole->count, b->count, g->nsnode * sizeof *b->count) == 0,
           "a tile's statistics differ from its halves'");
    /* Without params.guiding a guide changes nothing. */
    pt_render_tile(off, all, S0, S1, plain, NULL);
    pt_render_tile_guided(off, all, S0, S1, ignored, NULL, &gw);
    CHECK(memcmp(plain, ignored, sizeof plain) == 0);
    CHECK(strcmp(pt_renderer_variant(off), "guided") != 0);
done:
    pt_guide_stats_free(whole);
    pt_guide_stats_free(a);
    pt_guide_stats_free(b);
    pt_guide_stats_free(single);
    pt_guide_free(g);
    pt_renderer_free(r);
    pt_renderer_free(off);
    pt_scene_free(s);
}

/* b finished with a camera of 0.5 rad at pos looking along forward (unit)
 * with up (unit, normal to it) its up: right is up x -forward. NULL when it
 * fails. */
static pt_scene *finish_looking(pt_scene_builder *b, pt_vec3 pos, pt_vec3 forward, pt_vec3 up)
{
    pt_error err = {0};
    pt_camera cam = {0};
    cam.position = pos;
    cam.forward = forward;
    cam.right = pt_v3_cross(up, pt_v3_neg(forward));
    cam.up = up;
    cam.yfov = 0.5f;
    cam.aspect = 1.0f;
    snprintf(cam.name, sizeof cam.name, "c");
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

/* A floor (z = 0, +z up: a rough metal, or Lambert of albedo 0.8 when
 * lambert is set) and a small emitter facing it from above and to the side;
 * the camera looks down at the floor, through `panes` thin smooth glass
 * panes (z = 2, 2.2, 2.4, ..., wider than the camera's view) when asked. */
static pt_scene *floor_and_lamp(int lambert, uint32_t panes)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    if (!b)
        return NULL;
    pt_material fl = pt_material_default();
    fl.metallic = lambert ? 0.0f : 1.0f;
    fl.roughness = lambert ? 1.0f : 0.7f;
    if (lambert)
        fl.base_color[0] = fl.base_color[1] = fl.base_color[2] = 0.8f;
    pt_material glass = pt_material_default();
    glass.metallic = 0.0f;
    glass.roughness = 0.0f;
    glass.transmission = 1.0f;
    pt_material lamp = pt_material_default();
    lamp.base_color[0] = lamp.base_color[1] = lamp.base_color[2] = 0.0f;
    lamp.emissive[0] = lamp.emissive[1] = lamp.emissive[2] = 50.0f;
    uint32_t mf, ml;
    CHECK(pt_scene_builder_add_material(b, &fl, &mf, &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &lamp, &ml, &err) == PT_OK);
    const float floor_p[12] = {-1, -1, 0, 1, -1, 0, 1, 1, 0, -1, 1, 0};
    /* 0.2 x 0.2 at (1.5, 0, 1.5), wound to face -z. */
    const float lamp_p[12] = {1.4f, -0.1f, 1.5f, 1.4f, 0.1f,  1.5f,
                              1.6f, 0.1f,  1.5f, 1.6f, -0.1f, 1.5f};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "floor", floor_p, NULL, NULL, 4, idx, 2, NULL, mf, &err) ==
          PT_OK);
    CHECK(pt_scene_builder_add_mesh(b, "lamp", lamp_p, NULL, NULL, 4, idx, 2, NULL, ml, &err) ==
          PT_OK);
    uint32_t mg;
    if (panes)
        CHECK(pt_scene_builder_add_material(b, &glass, &mg, &err) == PT_OK);
    for (uint32_t i = 0; i < panes; i++) {
        float z = 2.0f + 0.2f * (float)i;
        const float pane_p[12] = {-3, -3, z, 3, -3, z, 3, 3, z, -3, 3, z};
        CHECK(pt_scene_builder_add_mesh(b, "pane", pane_p, NULL, NULL, 4, idx, 2, NULL, mg, &err) ==
              PT_OK);
    }
    return finish_looking(b, pt_v3(0, 0, 3), pt_v3(0, 0, -1), pt_v3(0, 1, 0));
}

/* The guide that one recording pass of samples [0, spp) of r's w x h image
 * builds over [lo, hi], its spatial leaf left unsplit (NULL when it could
 * not; the caller frees it). */
static pt_guide *learn_one_pass(const pt_renderer *r, uint32_t w, uint32_t h, uint32_t spp,
                                pt_vec3 lo, pt_vec3 hi)
{
    pt_error err = {0};
    pt_guide *g = NULL, *g2 = NULL;
    pt_guide_stats *st[2] = {NULL, NULL};
    CHECK(pt_guide_new_uniform(lo, hi, &g, &err) == PT_OK);
    pt_pixel_acc *acc = pt_calloc((size_t)w * h, sizeof *acc);
    if (r && g && acc && pt_guide_stats_new(g, &st[0], &err) == PT_OK &&
        pt_guide_stats_new(g, &st[1], &err) == PT_OK) {
        render_pass(r, w, h, 0, spp, g, 0.0f, st, acc);
        pt_guide_stats_merge(st[0], st[1], &err);
        CHECK(pt_guide_build(g, st[0], UINT64_MAX, &g2, &err) == PT_OK);
    }
    pt_guide_stats_free(st[0]);
    pt_guide_stats_free(st[1]);
    pt_guide_free(g);
    pt_free(acc);
    return g2;
}

/* The guide learns where light comes from: on the floor under BSDF sampling
 * alone (so a ray that finds the lamp records its whole radiance), the cell
 * of the floor's middle, after one recording pass, has a pdf towards the
 * lamp many times its pdf in the mirrored direction. The floor is seen
 * directly or through panes (floor_and_lamp); max_depth lets the path
 * bounce once off the floor and find the lamp, nothing more. */
static void learns_the_lamp_at(const char *what, int lambert, uint32_t panes, uint32_t max_depth)
{
    pt_scene *s = floor_and_lamp(lambert, panes);
    if (!s)
        return;
    enum { W = 16, H = 16 };
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = W;
    p.height = H;
    p.guiding = 1;
    p.light_strategy = PT_LIGHT_BSDF_ONLY;
    p.max_depth = max_depth;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    /* No split: one cell for the whole floor, whose middle sees the lamp 45
     * degrees up towards +x. */
    pt_guide *g2 =
        learn_one_pass(r, W, H, 1024, pt_v3(-1.1f, -1.1f, -0.1f), pt_v3(1.7f, 1.1f, 1.6f));
    if (g2) {
        uint32_t cell = pt_guide_cell(g2, pt_v3(0, 0, 0), pt_v3(0, 0, 1));
        pt_vec3 to_lamp = pt_v3_norm(pt_v3(1.5f, 0, 1.5f)),
                mirror = pt_v3_norm(pt_v3(-1.5f, 0, 1.5f));
        float pl = pt_guide_pdf(g2, cell, to_lamp), pm = pt_guide_pdf(g2, cell, mirror);
        CHECKF(pl > 10.0f * pm, "%s: pdf towards the lamp %g, mirrored %g", what, pl, pm);
        printf("%s: pdf towards the lamp %.3g, mirrored %.3g\n", what, pl, pm);
    }
    pt_guide_free(g2);
    pt_renderer_free(r);
    pt_scene_free(s);
}

static void learns_the_lamp(void)
{
    learns_the_lamp_at("learned lamp", 0, 0, 1);
}

/* Behind glass: a Lambert floor seen through three thin smooth panes is
 * each camera path's first rough vertex but its fourth bounce (depth 3),
 * and is guided and recorded all the same (render.c counts guidable
 * vertices, GUIDE_MAX_ROUGH, not bounces): its cell learns the lamp. When
 * every bounce counted, the floor was never recorded and its cell stayed
 * uniform (the pdfs equal). */
static void learns_behind_glass(void)
{
    learns_the_lamp_at("learned lamp behind three panes", 1, 3, 4);
}

/* The floor behind the panes, guided (MIS against NEE, the guide learned
 * in a first pass and sampled by half of the floor's directions), renders
 * what the unguided render does (images_agree), and not its bits: the
 * floor's directions were drawn from the guide. */
static void behind_glass_agrees(void)
{
    guided_vs_unguided(floor_and_lamp(1, 3), 16, 16, 64, 2048, -1, "floor behind three panes");
}

/* A Lambert floor (y = 0, |x|, |z| <= 1) beside a vertical mirror (x = 1.2,
 * 0 <= y <= 2, facing -x), seen from above; no emitter: the light is a map
 * (mirror_sun_env). */
static pt_scene *floor_and_mirror(void)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    if (!b)
        return NULL;
    pt_material fl = pt_material_default();
    fl.metallic = 0.0f;
    fl.roughness = 1.0f;
    fl.base_color[0] = fl.base_color[1] = fl.base_color[2] = 0.8f;
    pt_material mirror = pt_material_default();
    mirror.metallic = 1.0f;
    mirror.roughness = 0.0f;
    uint32_t mf, mm;
    CHECK(pt_scene_builder_add_material(b, &fl, &mf, &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &mirror, &mm, &err) == PT_OK);
    const float floor_p[12] = {-1, 0, -1, -1, 0, 1, 1, 0, 1, 1, 0, -1};
    const float mirror_p[12] = {1.2f, 0, -1, 1.2f, 2, -1, 1.2f, 2, 1, 1.2f, 0, 1};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "floor", floor_p, NULL, NULL, 4, idx, 2, NULL, mf, &err) ==
          PT_OK);
    CHECK(pt_scene_builder_add_mesh(b, "mirror", mirror_p, NULL, NULL, 4, idx, 2, NULL, mm, &err) ==
          PT_OK);
    return finish_looking(b, pt_v3(0, 3, 0), pt_v3(0, -1, 0), pt_v3(0, 0, -1));
}

/* A dim sky (0.1) with a sun of radiance sun in the 2n x 2n texels of a
 * 1024 x 512 map around the direction (-1, 1, 0) / sqrt 2 (env.h's map:
 * theta 45 degrees from +y, u = 1/2 + atan2(x, -z) / 2 pi = 1/4). */
static pt_env *mirror_sun_env(uint32_t n, float sun)
{
    enum { MW = 1024, MH = 512 };
    pt_envmap map = {MW, MH, pt_malloc_array((size_t)MW * MH * 3, sizeof(float))};
    pt_env *env = NULL;
    pt_error err = {0};
    if (!map.rgb)
        return NULL;
    for (size_t i = 0; i < (size_t)MW * MH * 3; i++)
        map.rgb[i] = 0.1f;
    for (uint32_t y = MH / 4 - n; y < MH / 4 + n; y++)
        for (uint32_t x = MW / 4 - n; x < MW / 4 + n; x++)
            for (int c = 0; c < 3; c++)
                map.rgb[((size_t)y * MW + x) * 3 + c] = sun;
    CHECKF(pt_env_new(&map, 1.0f, 0.0f, &env, &err) == PT_OK, "%s", err.msg);
    pt_free(map.rgb);
    return env;
}

/* Caustic photons (render.c, photon_trace): the sun reflected by the mirror
 * lights the floor from (1, 1, 0) / sqrt 2, which a camera path finds only
 * when its cosine-sampled direction off the floor meets the mirror and then
 * the sun's few texels (about 5e-5 of them; one path in 16,384 here). After
 * one recording pass of 64 spp, the floor's cell (unsplit) has a pdf towards
 * the mirror's light many times its pdf towards the sky beside it: the
 * photons' records taught it. Without them the two pdfs are alike. */
static void learns_the_caustic(void)
{
    pt_scene *s = floor_and_mirror();
    pt_env *env = mirror_sun_env(1, 1e5f);
    enum { W = 16, H = 16 };
    pt_renderer *r = s && env ? renderer_env(s, W, H, 1, env) : NULL;
    pt_guide *g2 =
        r ? learn_one_pass(r, W, H, 64, pt_v3(-1.1f, -0.1f, -1.1f), pt_v3(1.3f, 2.1f, 1.1f)) : NULL;
    if (g2) {
        uint32_t cell = pt_guide_cell(g2, pt_v3(0, 0, 0), pt_v3(0, 1, 0));
        pt_vec3 caustic = pt_v3_norm(pt_v3(1, 1, 0)), sky = pt_v3_norm(pt_v3(0, 1, 1));
        float pc = pt_guide_pdf(g2, cell, caustic), ps = pt_guide_pdf(g2, cell, sky);
        CHECKF(pc > 10.0f * ps, "caustic: pdf towards the mirror's sun %g, the sky %g", pc, ps);
        printf("caustic: pdf towards the mirror's sun %.3g, the sky %.3g\n", pc, ps);
    }
    pt_guide_free(g2);
    pt_renderer_free(r);
    pt_env_free(env);
    pt_scene_free(s);
}

/* The floor beside the mirror, guided (the guide learned from the photons'
 * records in a first pass) and unguided, agree (images_agree): the photons
 * shape the guide, not the estimate. The sun is 32 x 32 texels here, large
 * enough for the unguided render to find the caustic often and estimate
 * its variance (with learns_the_caustic's, 2,048 samples of a pixel would
 * find it about once in ten pixels). */
static void caustic_agrees(void)
{
    pt_scene *s = floor_and_mirror();
    pt_env *env = mirror_sun_env(16, 100.0f);
    enum { W = 16, H = 16 };
    pt_renderer *rg = s && env ? renderer_env(s, W, H, 1, env) : NULL;
    pt_renderer *ru = s && env ? renderer_env(s, W, H, 0, env) : NULL;
    pt_pixel_acc *ag = pt_calloc(W * H, sizeof *ag), *au = pt_calloc(W * H, sizeof *au);
    if (rg && ru && ag && au) {
        pt_guide_free(render_guided(s, rg, W, H, 64, 2048, ag));
        render_pass(ru, W, H, 0, 2048, NULL, 0.0f, NULL, au);
        images_agree(ag, au, W * H, 2, "floor lit by a mirror");
    }
    pt_free(ag);
    pt_free(au);
    pt_renderer_free(rg);
    pt_renderer_free(ru);
    pt_env_free(env);
    pt_scene_free(s);
}

/* A vertex whose lobes are all narrower than a guide of radiance alone can
 * stand in for (render.c, closure_guide_share: a metal of roughness 0.5,
 * GGX alpha 0.25, which closure_guidable guides) keeps its BSDF sampling:
 * the guided render, its guide learned and offered with probability 0.5,
 * is the unguided render to the bit. */
/* The inside of a cube of half-side 3 about the furnace's camera, Lambert
 * of albedo 0.9 with emission 1, flat normals facing in: a closed furnace
 * whose walls' normals are the axes, so that every quadtree leaf of a
 * face's tree lies on one side of the walls' horizon (the equal-area map
 * splits at z = 0 and at phi = 0, 90, 180, 270 degrees) and a learned
 * guide never draws a direction below a wall. */
static pt_scene *cube_furnace(void)
{
    pt_scene *src = furnace(0.9f, 0.0f, 1.0f, 0.0f);
    if (!src)
        return NULL;
    float pos[6 * 6 * 3], nrm[6 * 6 * 3];
    const float R = 3.0f;
    for (int f = 0; f < 6; f++) {
        int a = f / 2;
        float sgn = (f & 1) ? -1.0f : 1.0f;
        /* The wall at coordinate sgn R of axis a, its normal -sgn along a;
         * corners c0..c3 around it, two triangles wound to face in. */
        float c[4][3];
        const float uv[4][2] = {{-1, -1}, {1, -1}, {1, 1}, {-1, 1}};
        for (int k = 0; k < 4; k++) {
            c[k][a] = sgn * R;
            c[k][(a + 1) % 3] = uv[k][0] * R;
            c[k][(a + 2) % 3] = uv[k][1] * R;
        }
        const int tri[6] = {0, 1, 2, 0, 2, 3};
        pt_vec3 n = pt_v3(0, 0, 0);
        float *np = &n.x;
        np[a] = -sgn;
        pt_vec3 v0 = pt_v3(c[0][0], c[0][1], c[0][2]), v1 = pt_v3(c[1][0], c[1][1], c[1][2]),
                v2 = pt_v3(c[2][0], c[2][1], c[2][2]);
        int flip = pt_v3_dot(pt_v3_cross(pt_v3_sub(v1, v0), pt_v3_sub(v2, v0)), n) < 0.0f;
        for (int k = 0; k < 6; k++) {
            int v = tri[flip ? (k / 3) * 3 + 2 - k % 3 : k];
            memcpy(&pos[18 * f + 3 * k], c[v], 3 * sizeof(float));
            memcpy(&nrm[18 * f + 3 * k], &n, 3 * sizeof(float));
        }
    }
    pt_scene *out = NULL;
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    uint32_t mat;
    if (pt_scene_builder_new(&b, &err) == PT_OK) {
        CHECK(pt_scene_builder_add_material(b, &src->materials[0], &mat, &err) == PT_OK);
        CHECK(pt_scene_builder_add_mesh(b, "cube", pos, nrm, NULL, 36, NULL, 12, NULL, mat, &err) ==
              PT_OK);
        CHECK(pt_scene_builder_add_camera(b, &src->camera, &err) == PT_OK);
        CHECKF(pt_scene_builder_finish(b, NULL, &out, &err) == PT_OK, "%s", err.msg);
    }
    pt_scene_free(src);
    return out;
}

/* Russian roulette at a guided vertex reads the throughput the BSDF alone
 * would have left (render.c), not the mixture's weight, which is small
 * where the guide expects much light and would make roulette undo the
 * guide. In the cube furnace, with BSDF sampling only (no shadow rays) and
 * no escape, that throughput is 0.9^k on every path whatever the guide
 * drew, so guided paths end as unguided ones do: the same samples trace
 * the same number of rays in expectation. The tolerance: a path traces
 * three rays before roulette starts, and its rays past those are bounded
 * by a geometric count of survival 0.95 (second moment 0.95 / 0.05^2 +
 * 19^2 = 741), so the mean over N paths has a standard error at most
 * sqrt(741 / N); 5 of them for the difference of two means. Read by the
 * weight, guided paths here trace 3 % fewer rays (0.30 of 10.3, 1.6 times
 * the tolerance at 4,096 spp, 2.3 times at 8,192). */
static void roulette_ignores_guide(void)
{
    pt_scene *s = cube_furnace();
    if (!s)
        return;
    enum { W = 16, H = 16, FIRST = 64, SPP = FIRST + CHECK_WORK(4096) };
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = W;
    p.height = H;
    p.seed = 5;
    p.guiding = 1;
    p.extra_features = PT_FEAT_GLOSSY;
    p.light_strategy = PT_LIGHT_BSDF_ONLY;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    CHECK(r && strcmp(pt_renderer_variant(r), "guided") == 0);
    pt_pixel_acc *acc = pt_calloc(W * H, sizeof *acc), *out = pt_calloc(W * H, sizeof *out);
    pt_guide *g2 = NULL;
    if (r && acc && out)
        g2 = render_guided(s, r, W, H, FIRST, FIRST + 1, acc);
    if (g2) {
        pt_rect all = {0, 0, W, H};
        pt_render_stats sg = {0}, su = {0};
        pt_render_guiding gg = {g2, 0.5f, NULL}, gu = {g2, 0.0f, NULL};
        pt_render_tile_guided(r, all, FIRST, SPP, out, &sg, &gg);
        pt_render_tile_guided(r, all, FIRST, SPP, out, &su, &gu);
        double n = (double)W * H * (SPP - FIRST);
        double mg = (double)sg.rays / n, mu = (double)su.rays / n;
        double tol = 5.0 * sqrt(2.0 * 741.0 / n);
        CHECKF(fabs(mg - mu) < tol,
               "guided paths trace %.4f rays, unguided %.4f (tolerance %.4f): roulette "
               "reads the guided weight",
               mg, mu, tol);
        printf("cube furnace, roulette: guided paths %.4f rays, unguided %.4f (tolerance %.4f)\n",
               mg, mu, tol);
    }
    pt_guide_free(g2);
    pt_free(acc);
    pt_free(out);
    pt_renderer_free(r);
    pt_scene_free(s);
}

static void glossy_keeps_bsdf(void)
{
    guided_vs_unguided(furnace(0.8f, 1.0f, 0.5f, 1.0f), 8, 8, 32, 128, 1, "glossy metal");
}

static void lambert_keeps_variant(void)
{
    pt_scene *s = furnace_load("scenes/cornell_box.gltf");
    if (!s)
        return;
    pt_renderer *a = renderer(s, 8, 8, 1, 0), *b = renderer(s, 8, 8, 0, 0);
    CHECK(a && b && strcmp(pt_renderer_variant(a), pt_renderer_variant(b)) == 0);
    pt_renderer_free(a);
    pt_renderer_free(b);
    pt_scene_free(s);
}

/* A scene from a file (path under the source tree or ../shared), lit by
 * the map at env_path (NULL: its own emitters): guided and unguided renders
 * of w x h at spp agree (images_agree). Skipped when the file is missing,
 * unless CI requires the shared data. */
static void scene_agrees(const char *path, const char *env_path, uint32_t w, uint32_t h,
                         uint32_t spp, const char *what)
{
    if (access(path, R_OK) != 0 || (env_path && access(env_path, R_OK) != 0)) {
        CHECK_SKIP("shared data not found; guided against unguided");
        CHECK(!check_shared_required());
        return;
    }
    pt_error err = {0};
    pt_scene *s = NULL;
    pt_env *env = NULL;
    pt_scene_opts o = {0};
    o.warn = quiet;
    CHECKF(pt_scene_load(path, &o, &s, &err) == PT_OK, "%s: %s", path, err.msg);
    if (env_path)
        CHECKF(pt_env_load(env_path, 1.0f, 0.0f, &env, &err) == PT_OK, "%s: %s", env_path, err.msg);
    pt_renderer *rg = NULL, *ru = NULL;
    pt_pixel_acc *ag = pt_calloc((size_t)w * h, sizeof *ag),
                 *au = pt_calloc((size_t)w * h, sizeof *au);
    pt_guide *g2 = NULL;
    if (s && (env || !env_path)) {
        rg = renderer_env(s, w, h, 1, env);
        ru = renderer_env(s, w, h, 0, env);
    }
    if (rg && ru && ag && au) {
        CHECK(strcmp(pt_renderer_variant(rg), "guided") == 0);
        g2 = render_guided(s, rg, w, h, 64, spp, ag);
        render_pass(ru, w, h, 0, spp, NULL, 0.0f, NULL, au);
        images_agree(ag, au, w * h, 2, what);
    }
    pt_guide_free(g2);
    pt_free(ag);
    pt_free(au);
    pt_renderer_free(rg);
    pt_renderer_free(ru);
    pt_env_free(env);
    pt_scene_free(s);
}

static void scenes_agree(void)
{
    char path[1024], env[1024];
    snprintf(path, sizeof path, "%s/CornellBox/cornellBox.gltf", PT_SHARED_SCENES);
    scene_agrees(path, NULL, 16, 16, 2048, "NVIDIA Cornell box");
    snprintf(path, sizeof path, "%s/scenes/glass_things.gltf", PT_SOURCE_DIR);
    snprintf(env, sizeof env, "%s/../envs/studio_small_03_1k.hdr", PT_SHARED_SCENES);
    scene_agrees(path, env, 16, 16, 2048, "glass ball's caustic");
}

static void auto_rule(void)
{
    static const struct {
        float metallic, roughness, specular;
        int want;
        const char *what;
    } c[] = {{0.0f, 1.0f, 0.0f, 0, "Lambert"},
             {0.0f, 1.0f, 1.0f, 0, "rough dielectric"},
             {1.0f, 0.5f, 1.0f, 0, "metal"},
             {0.0f, 0.1f, 1.0f, 0, "smooth dielectric"}};
    for (size_t i = 0; i < sizeof c / sizeof c[0]; i++) {
        pt_scene *s = furnace(0.5f, c[i].metallic, c[i].roughness, c[i].specular);
        if (!s)
            continue;
        CHECKF(pt_guide_auto(s) == c[i].want, "auto guiding for a %s sphere: %d", c[i].what,
               pt_guide_auto(s));
        /* Glass: transmission on the rough dielectric. */
        if (i == 1) {
            s->materials[0].transmission = 1.0f;
            s->features |= PT_FEAT_TRANSMISSION;
            CHECKF(pt_guide_auto(s) == 1, "auto guiding off for glass");
        }
        pt_scene_free(s);
    }
}

int main(void)
{
    int64_t live = pt_alloc_live();
    auto_rule();
    bits();
    lambert_keeps_variant();
    learns_the_lamp();
    learns_behind_glass();
    behind_glass_agrees();
    learns_the_caustic();
    caustic_agrees();
    white_furnace();
    glossy_agrees();
    glossy_keeps_bsdf();
    roulette_ignores_guide();
    scenes_agree();
    CHECKF(pt_alloc_live() == live, "%lld allocations left", (long long)(pt_alloc_live() - live));
    return check_report();
}
