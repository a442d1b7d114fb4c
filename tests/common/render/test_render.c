/*
 * test_render.c - the integrator against analytic answers and against itself.
 *
 * - White furnace (scenes/furnace.gltf): a closed Lambertian sphere of albedo
 *   rho emitting E everywhere; every pixel's exact value is E / (1 - rho).
 *   Each pixel must lie within 5 sigma of it (sigma: the pixel's own standard
 *   error from its samples) and the image mean within 0.5 %, at scales 1, 1e-4
 *   and 1e4.
 * - The same furnace at albedo 0.8, emission 1, with the default parameters:
 *   Russian roulette, not the bounce cap, ends paths, so the mean is
 *   1 / (1 - 0.8) = 5 within 0.2 %, beyond 5 standard errors (a cap of 16
 *   bounces read 4.887).
 * - An orthographic camera: an emitting square of side 1 seen by a camera of
 *   ymag 1 covers exactly a quarter of a 64 x 64 image (its edges on pixel
 *   edges), whatever its distance, as parallel projection must.
 * - Direct light by NEE alone and by BSDF sampling alone agree within their
 *   combined standard error.
 * - Determinism: [0,64) equals the in-order sum of four 16-sample chunks bit
 *   for bit, and the same pixels rendered by several threads equal one thread's;
 *   [0,N) equals any split at multiples of 16 into parts of any sizes, merged
 *   in any order (sums and resolved image), N a multiple of 16 or not.
 * - The Cornell box renders with no NaN or Inf and no rejected sample.
 * - Every specialised integrator variant gives the general one's bits.
 * - pt_render_tile, which traces many paths interleaved, gives the bits of
 *   one path at a time (pt_render_sample) summed in the same order, for every
 *   variant, light strategy and a range of sample counts.
 */
#include <math.h>
#include <pthread.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/math/simd.h"
#include "common/render/film.h"
#include "common/render/light.h"
#include "common/render/render.h"
#include "common/scene/scene.h"
#include "tests/check.h"
#include "tests/common/render/furnace.h"
#include "tests/common/render/tile_ref.h"

static pt_scene *load(const char *rel, float scale)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", PT_SOURCE_DIR, rel);
    pt_scene_opts o = {0};
    o.scale = scale;
    pt_scene *s = NULL;
    pt_error err = {0};
    if (pt_scene_load(path, &o, &s, &err) != PT_OK) {
        fprintf(stderr, "cannot load %s: %s\n", path, err.msg);
        return NULL;
    }
    return s;
}

static pt_renderer *renderer(const pt_scene *s, uint32_t w, uint32_t h, uint32_t max_depth,
                             uint32_t strategy)
{
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = w;
    p.height = h;
    p.max_depth = max_depth;
    p.light_strategy = strategy;
    p.seed = 7;
    pt_renderer *r = NULL;
    pt_error err = {0};
    if (pt_renderer_new(s, &p, &r, &err) != PT_OK)
        fprintf(stderr, "renderer: %s\n", err.msg);
    return r;
}

/* Standard error of a pixel mean from its luminance sums. */
static double pixel_sigma(const pt_pixel_acc *a)
{
    double n = a->n,
           mean = pt_luminance(pt_v3((float)(pt_acc_sum(a, 0) / n), (float)(pt_acc_sum(a, 1) / n),
                                     (float)(pt_acc_sum(a, 2) / n)));
    double var = (pt_acc_sum_sq(a) - n * mean * mean) / (n - 1.0);
    return sqrt(fmax(var, 0.0) / n);
}

static void furnace(float scale)
{
    pt_scene *s = load("scenes/furnace.gltf", scale);
    CHECK(s != NULL);
    if (!s)
        return;
    const uint32_t W = 32, H = 32, SPP = 128;
    const double expected = 0.5 / (1.0 - 0.5);
    pt_renderer *r = renderer(s, W, H, 1000, PT_LIGHT_MIS);
    CHECK(r != NULL);
    pt_pixel_acc *acc = pt_malloc_array(W * H, sizeof *acc);
    pt_render_stats st = {0};
    pt_rect all = {0, 0, W, H};
    pt_render_tile(r, all, 0, SPP, acc, &st);
    int outliers = 0;
    double sum = 0, var_sum = 0;
    for (uint32_t i = 0; i < W * H; i++) {
        double m = pt_acc_sum(&acc[i], 1) / acc[i].n;
        double sig = pixel_sigma(&acc[i]);
        sum += m;
        var_sum += sig * sig;
        if (fabs(m - expected) > 5.0 * sig + 1e-6)
            outliers++;
        CHECK(acc[i].n == SPP);
    }
    double mean = sum / (W * H);
    CHECKF(outliers == 0, "scale %g: %d pixels beyond 5 sigma", (double)scale, outliers);
    CHECKF(fabs(mean - expected) < 0.005 * expected, "scale %g: image mean %.5f, expected %.5f",
           (double)scale, mean, expected);
    /* The 0.5 % bound must also be well outside the estimator's own noise. */
    CHECKF(sqrt(var_sum) / (W * H) < 0.001, "image mean standard error %.5f too large",
           sqrt(var_sum) / (W * H));
    CHECK(st.rejected == 0);
    printf("furnace scale %g: mean %.5f (exact %.5f), standard error %.2e\n", (double)scale, mean,
           expected, sqrt(var_sum) / (W * H));
    pt_free(acc);
    pt_renderer_free(r);
    pt_scene_free(s);
}

/* The furnace's sphere with flat normals (furnace.h). */
static pt_scene *flat_furnace(float albedo, float emission)
{
    return flat_furnace_of(albedo, emission, NULL);
}

typedef struct furnace_job {
    const pt_renderer *r;
    pt_rect rows;
    uint32_t spp;
    pt_pixel_acc *acc;
} furnace_job;

static void *furnace_rows(void *arg)
{
    furnace_job *j = arg;
    pt_render_tile(j->r, j->rows, 0, j->spp, j->acc, NULL);
    return NULL;
}

/* The default parameters are unbiased: at albedo 0.8 a path survives 16
 * bounces with probability 0.8^17 = 2.3 %, which a bounce cap would lose. */
static void furnace_defaults(void)
{
    pt_scene *s = flat_furnace(0.8f, 1.0f);
    CHECK(s != NULL);
    if (!s)
        return;
    /* About 4.2 M samples: a standard error of 0.036 %, so that 0.2 % is
     * 5.5 of them, a tenth of the bias a bounce cap makes; two threads,
     * half the rows each. A sanitizer build: a quarter of them, 0.07 % and
     * 0.4 % (check.h). (15 M samples and 0.1 % were half the CPU time of
     * the whole suite's render tests.) */
    const uint32_t W = 64, H = 64, SPP = CHECK_WORK(1024);
    const double bound = CHECK_LOOSE(0.002);
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = W;
    p.height = H;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    pt_pixel_acc *acc = pt_malloc_array(W * H, sizeof *acc);
    if (r && acc) {
        furnace_job jobs[2] = {{r, {0, 0, W, H / 2}, SPP, acc},
                               {r, {0, H / 2, W, H}, SPP, acc + W * H / 2}};
        pthread_t th;
        int threaded = pthread_create(&th, NULL, furnace_rows, &jobs[1]) == 0;
        furnace_rows(&jobs[0]);
        if (threaded)
            pthread_join(th, NULL);
        else
            furnace_rows(&jobs[1]);
    }
    double sum = 0, var_sum = 0;
    for (uint32_t i = 0; r && acc && i < W * H; i++) {
        double sig = pixel_sigma(&acc[i]);
        sum += pt_acc_sum(&acc[i], 1) / acc[i].n;
        var_sum += sig * sig;
    }
    const double expected = 1.0 / (1.0 - 0.8);
    double mean = sum / (W * H), se = sqrt(var_sum) / (W * H);
    CHECKF(fabs(mean - expected) < bound * expected && fabs(mean - expected) < 5.0 * se,
           "defaults: image mean %.5f, expected %.5f (se %.5f)", mean, expected, se);
    /* The bound is beyond 5 standard errors, so a 2.3 % bias cannot hide in noise. */
    CHECKF(5.0 * se < bound * expected, "defaults: standard error %.5f too large", se);
    printf("furnace albedo 0.8, default parameters: mean %.5f (exact %.5f), standard error %.2e\n",
           mean, expected, se);
    pt_free(acc);
    pt_renderer_free(r);
    pt_scene_free(s);
}

/* An orthographic view: the square's pixels, counted, at two distances. */
static void orthographic(void)
{
    for (int k = 0; k < 2; k++) {
        float hs = k ? 3.0f : 0.5f;
        pt_scene_builder *b = NULL;
        pt_error err = {0};
        CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
        pt_material m = pt_material_default();
        m.base_color[0] = m.base_color[1] = m.base_color[2] = 0.5f;
        m.metallic = m.specular = 0.0f;
        m.double_sided = 1;
        pt_material e = m;
        e.base_color[0] = e.base_color[1] = e.base_color[2] = 0.0f;
        e.emissive[0] = e.emissive[1] = e.emissive[2] = 2.0f;
        uint32_t mp, me;
        CHECK(pt_scene_builder_add_material(b, &m, &mp, &err) == PT_OK);
        CHECK(pt_scene_builder_add_material(b, &e, &me, &err) == PT_OK);
        const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
        float plane[12] = {-9, 0, -9, 9, 0, -9, 9, 0, 9, -9, 0, 9};
        float sq[12] = {-0.5f, hs, -0.5f, 0.5f, hs, -0.5f, 0.5f, hs, 0.5f, -0.5f, hs, 0.5f};
        CHECK(pt_scene_builder_add_mesh(b, "plane", plane, NULL, NULL, 4, idx, 2, NULL, mp, &err) ==
              PT_OK);
        CHECK(pt_scene_builder_add_mesh(b, "square", sq, NULL, NULL, 4, idx, 2, NULL, me, &err) ==
              PT_OK);
        pt_camera cam = {0};
        cam.position = pt_v3(0, 10, 0);
        cam.forward = pt_v3(0, -1, 0);
        cam.right = pt_v3(1, 0, 0);
        cam.up = pt_v3(0, 0, -1);
        cam.ortho = 1;
        cam.xmag = cam.ymag = 1.0f;
        cam.aspect = 1.0f;
        CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
        pt_scene *s = NULL;
        CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
        if (!s)
            return;
        const uint32_t W = 64;
        pt_renderer *r = renderer(s, W, W, PT_RENDER_DEFAULT_MAX_DEPTH, PT_LIGHT_MIS);
        pt_pixel_acc *acc = pt_malloc_array(W * W, sizeof *acc);
        pt_render_stats st = {0};
        pt_rect all = {0, 0, W, W};
        int on = 0, wrong = 0;
        if (r && acc) {
            pt_render_tile(r, all, 0, 16, acc, &st);
            for (uint32_t y = 0; y < W; y++)
                for (uint32_t x = 0; x < W; x++) {
                    int inside = x >= 16 && x < 48 && y >= 16 && y < 48;
                    int lit = fabs(pt_acc_sum(&acc[y * W + x], 1) / acc[y * W + x].n - 2.0) < 1e-6;
                    on += lit;
                    wrong += lit != inside;
                }
        }
        CHECKF(on == 1024 && wrong == 0, "square at height %g: %d pixels see it, %d wrongly",
               (double)hs, on, wrong);
        pt_free(acc);
        pt_renderer_free(r);
        pt_scene_free(s);
    }
}

/* Direct light (one bounce) by NEE alone vs BSDF sampling alone. */
static void nee_vs_bsdf(void)
{
    pt_scene *s = load("scenes/cornell_box.gltf", 1.0f);
    CHECK(s != NULL);
    if (!s)
        return;
    const uint32_t W = 8, H = 8;
    pt_renderer *a = renderer(s, W, H, 1, PT_LIGHT_NEE_ONLY);
    pt_renderer *b = renderer(s, W, H, 1, PT_LIGHT_BSDF_ONLY);
    pt_renderer *m = renderer(s, W, H, 1, PT_LIGHT_MIS);
    pt_pixel_acc *pa = pt_malloc_array(W * H, sizeof *pa);
    pt_pixel_acc *pb = pt_malloc_array(W * H, sizeof *pb);
    pt_pixel_acc *pm = pt_malloc_array(W * H, sizeof *pm);
    pt_rect all = {0, 0, W, H};
    pt_render_tile(a, all, 0, 256, pa, NULL);
    pt_render_tile(b, all, 0, 4096, pb, NULL);
    pt_render_tile(m, all, 0, 256, pm, NULL);
    double ma = 0, mb = 0, mm = 0, va = 0, vb = 0, vm = 0;
    int outliers = 0;
    for (uint32_t i = 0; i < W * H; i++) {
        double xa = pt_luminance(pt_v3((float)(pt_acc_sum(&pa[i], 0) / pa[i].n),
                                       (float)(pt_acc_sum(&pa[i], 1) / pa[i].n),
                                       (float)(pt_acc_sum(&pa[i], 2) / pa[i].n)));
        double xb = pt_luminance(pt_v3((float)(pt_acc_sum(&pb[i], 0) / pb[i].n),
                                       (float)(pt_acc_sum(&pb[i], 1) / pb[i].n),
                                       (float)(pt_acc_sum(&pb[i], 2) / pb[i].n)));
        double sa = pixel_sigma(&pa[i]), sb = pixel_sigma(&pb[i]);
        if (fabs(xa - xb) > 5.0 * sqrt(sa * sa + sb * sb) + 1e-6)
            outliers++;
        ma += pt_acc_sum(&pa[i], 1);
        mb += pt_acc_sum(&pb[i], 1);
        mm += pt_acc_sum(&pm[i], 1);
        va += sa * sa;
        vb += sb * sb;
        vm += pixel_sigma(&pm[i]) * pixel_sigma(&pm[i]);
    }
    ma /= 256.0 * W * H;
    mb /= 4096.0 * W * H;
    mm /= 256.0 * W * H;
    double sab = sqrt(va + vb) / (W * H), sam = sqrt(va + vm) / (W * H);
    printf("direct light, image mean: NEE %.5f, BSDF %.5f, MIS %.5f (sigma %.2e, %.2e)\n", ma, mb,
           mm, sab, sam);
    CHECKF(outliers == 0, "%d pixels where NEE and BSDF sampling differ beyond 5 sigma", outliers);
    CHECKF(fabs(ma - mb) < 4.0 * sab, "NEE %.5f vs BSDF %.5f beyond 4 sigma (%.2e)", ma, mb, sab);
    CHECKF(fabs(ma - mm) < 4.0 * sam, "NEE %.5f vs MIS %.5f beyond 4 sigma (%.2e)", ma, mm, sam);
    CHECK(ma > 0.01);
    pt_free(pa);
    pt_free(pb);
    pt_free(pm);
    pt_renderer_free(a);
    pt_renderer_free(b);
    pt_renderer_free(m);
    pt_scene_free(s);
}

typedef struct part {
    const pt_renderer *r;
    pt_rect rect;
    pt_pixel_acc *out;
} part;

static void *render_part(void *p)
{
    part *t = p;
    pt_render_tile(t->r, t->rect, 0, 32, t->out, NULL);
    return NULL;
}

static void determinism(void)
{
    pt_scene *s = load("scenes/cornell_box.gltf", 1.0f);
    CHECK(s != NULL);
    if (!s)
        return;
    const uint32_t W = 16, H = 16;
    pt_renderer *r = renderer(s, W, H, 16, PT_LIGHT_MIS);
    pt_rect tile = {4, 4, 12, 12};
    const uint32_t n = 64;
    pt_pixel_acc whole[64], sum[64], part_acc[64];
    pt_render_tile(r, tile, 0, 64, whole, NULL);
    memset(sum, 0, sizeof sum);
    for (uint32_t c = 0; c < 4; c++) {
        pt_render_tile(r, tile, 16 * c, 16 * (c + 1), part_acc, NULL);
        for (uint32_t i = 0; i < n; i++)
            pt_pixel_acc_add(&sum[i], &part_acc[i]);
    }
    CHECKF(memcmp(whole, sum, sizeof whole) == 0, "[0,64) differs from the sum of 16-chunks");
    int nonzero = 0;
    for (uint32_t i = 0; i < n; i++)
        nonzero += pt_acc_sum(&whole[i], 0) > 0;
    CHECK(nonzero > 0);

    /* Rows of the tile on four threads vs the whole tile on this one. */
    pt_pixel_acc one[64], four[64];
    pt_render_tile(r, tile, 0, 32, one, NULL);
    pthread_t th[4];
    part parts[4];
    for (uint32_t t = 0; t < 4; t++) {
        parts[t] = (part){r, {4, 4 + 2 * t, 12, 6 + 2 * t}, &four[16 * t]};
        pthread_create(&th[t], NULL, render_part, &parts[t]);
    }
    for (uint32_t t = 0; t < 4; t++)
        pthread_join(th[t], NULL);
    CHECKF(memcmp(one, four, sizeof one) == 0, "four threads differ from one");
    pt_renderer_free(r);
    pt_scene_free(s);
}

/* Renders tile's samples [0, n) in parts split at cuts (16-aligned, parts of
 * different sizes), adding the parts in order into acc (zeroed first). */
static void render_split(const pt_renderer *r, pt_rect tile, const uint32_t *cuts, size_t ncuts,
                         uint32_t n, pt_pixel_acc *acc, pt_pixel_acc *part_acc, uint32_t npx)
{
    memset(acc, 0, npx * sizeof *acc);
    for (size_t c = 0; c <= ncuts; c++) {
        uint32_t a = c ? cuts[c - 1] : 0, b = c < ncuts ? cuts[c] : n;
        pt_render_tile(r, tile, a, b, part_acc, NULL);
        for (uint32_t i = 0; i < npx; i++)
            pt_pixel_acc_add(&acc[i], &part_acc[i]);
    }
}

/* Resolves a tile's sums into a film of the tile's size. */
static pt_image *resolve_tile(const pt_pixel_acc *acc, uint32_t w, uint32_t h)
{
    pt_film *f = NULL;
    pt_image *img = NULL;
    if (pt_film_new(w, h, &f, NULL) != PT_OK || pt_image_new(w, h, &img, NULL) != PT_OK) {
        pt_film_free(f);
        return NULL;
    }
    pt_film_add_tile(f, (pt_rect){0, 0, w, h}, acc);
    pt_film_resolve(f, img);
    pt_film_free(f);
    return img;
}

static int image_same(const pt_image *a, const pt_image *b)
{
    if (!a || !b)
        return 0;
    size_t n = (size_t)a->width * a->height * sizeof(float);
    return memcmp(a->r, b->r, n) == 0 && memcmp(a->g, b->g, n) == 0 && memcmp(a->b, b->b, n) == 0 &&
           memcmp(a->variance, b->variance, n) == 0 && memcmp(a->samples, b->samples, n) == 0;
}

/* [0,N) in one call equals, bit for bit, any split at multiples of 16 into
 * parts of different sizes merged in order (the sums and the resolved image),
 * for a total that is a multiple of 16 and one that is not: what lets the
 * coordinator size every task differently. */
static void split_any_sizes(void)
{
    pt_scene *s = load("scenes/cornell_box.gltf", 1.0f);
    CHECK(s != NULL);
    if (!s)
        return;
    const uint32_t W = 16, H = 16;
    pt_renderer *r = renderer(s, W, H, 16, PT_LIGHT_MIS);
    pt_rect tile = {3, 5, 11, 13};
    enum { NPX = 64 };
    static const uint32_t cuts_a[] = {16, 48, 112}, cuts_b[] = {64}, cuts_c[] = {32, 80, 96, 144};
    static const uint32_t totals[] = {160, 203};
    for (size_t t = 0; t < 2; t++) {
        uint32_t n = totals[t];
        pt_pixel_acc whole[NPX], split[NPX], part_acc[NPX];
        pt_render_tile(r, tile, 0, n, whole, NULL);
        const uint32_t *cuts[] = {cuts_a, cuts_b, cuts_c};
        const size_t ncuts[] = {3, 1, 4};
        pt_image *wi = resolve_tile(whole, 8, 8);
        for (size_t k = 0; k < 3; k++) {
            render_split(r, tile, cuts[k], ncuts[k], n, split, part_acc, NPX);
            CHECKF(memcmp(whole, split, sizeof whole) == 0,
                   "[0,%u) differs from split %zu merged in order", n, k);
            pt_image *si = resolve_tile(split, 8, 8);
            CHECKF(image_same(wi, si), "[0,%u): the image of split %zu differs", n, k);
            pt_image_free(si);
        }
        /* The same parts merged in another order: the same bits too. */
        memset(split, 0, sizeof split);
        static const uint32_t rev[][2] = {{112, 0}, {48, 112}, {0, 16}, {16, 48}};
        for (size_t c = 0; c < 4; c++) {
            uint32_t a = rev[c][0], b = rev[c][1] ? rev[c][1] : n;
            pt_render_tile(r, tile, a, b, part_acc, NULL);
            for (uint32_t i = 0; i < NPX; i++)
                pt_pixel_acc_add(&split[i], &part_acc[i]);
        }
        CHECKF(memcmp(whole, split, sizeof whole) == 0, "[0,%u) differs merged out of order", n);
        pt_image_free(wi);
    }
    pt_renderer_free(r);
    pt_scene_free(s);
}

static void cornell_finite(void)
{
    pt_scene *s = load("scenes/cornell_box.gltf", 1.0f);
    CHECK(s != NULL);
    if (!s)
        return;
    const uint32_t W = 32, H = 32;
    pt_renderer *r = renderer(s, W, H, 16, PT_LIGHT_MIS);
    pt_pixel_acc *acc = pt_malloc_array(W * H, sizeof *acc);
    pt_render_stats st = {0};
    pt_rect all = {0, 0, W, H};
    pt_render_tile(r, all, 0, 16, acc, &st);
    int bad = 0;
    for (uint32_t i = 0; i < W * H; i++)
        for (int c = 0; c < 3; c++)
            bad += !isfinite(pt_acc_sum(&acc[i], c)) || pt_acc_sum(&acc[i], c) < 0;
    CHECK(bad == 0);
    CHECKF(st.rejected == 0, "%llu rejected samples", (unsigned long long)st.rejected);
    CHECK(st.samples == (uint64_t)W * H * 16);
    pt_free(acc);
    pt_renderer_free(r);
    pt_scene_free(s);
}

/* pt_render_tile's pixels against pt_render_sample's, summed as
 * pt_render_tile documents: per aligned block of PT_SAMPLE_BLOCK in sample
 * order, then block sums in order. */
static void batched_as_single(const pt_scene *s, uint32_t extra, uint32_t scalar, uint32_t strategy,
                              uint32_t s0, uint32_t s1, uint32_t max_depth)
{
    enum { W = 9, H = 7 };
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = W;
    p.height = H;
    p.seed = 11;
    p.light_strategy = strategy;
    p.extra_features = extra;
    p.scalar_shading = scalar;
    if (max_depth)
        p.max_depth = max_depth;
    pt_renderer *r = NULL;
    CHECK(pt_renderer_new(s, &p, &r, NULL) == PT_OK);
    if (!r)
        return;
    int lambert = strncmp(pt_renderer_variant(r), "lambert", 7) == 0;
    CHECK(pt_renderer_lanes(r) == (lambert && !scalar && pt_simd_lanes_fast()));
    pt_pixel_acc tile[W * H], ref[W * H];
    pt_render_stats ts = {0}, rs = {0};
    pt_rect rect = {1, 2, W, H}; /* not at the origin, rows shorter than the image */
    pt_render_tile(r, rect, s0, s1, tile, &ts);
    uint32_t n = (rect.x1 - rect.x0) * (rect.y1 - rect.y0);
    tile_ref(r, rect, s0, s1, ref, &rs);
    CHECKF(memcmp(tile, ref, n * sizeof *tile) == 0,
           "variant %s (%s), strategy %u, samples [%u,%u): tile differs from one path at a time",
           pt_renderer_variant(r), pt_renderer_lanes(r) ? "lanes" : "per path", strategy, s0, s1);
    CHECK(ts.samples == rs.samples && ts.rejected == rs.rejected && ts.rays == rs.rays &&
          ts.capped == rs.capped);
    pt_renderer_free(r);
}

/* max_depth 0: the default. */
static void batched(const pt_scene *s, uint32_t max_depth)
{
    const uint32_t ranges[][2] = {{0, 1}, {0, 3}, {5, 21}, {0, 40}, {16, 32}};
    for (uint32_t k = 0; k < sizeof ranges / sizeof ranges[0]; k++)
        for (uint32_t strategy = 0; strategy < 3; strategy++) {
            /* The scene's variant, in lanes where they are fast and per path
             * (as where they are not), and the general one. */
            batched_as_single(s, 0, 0, strategy, ranges[k][0], ranges[k][1], max_depth);
            batched_as_single(s, 0, 1, strategy, ranges[k][0], ranges[k][1], max_depth);
            batched_as_single(s, 0xffffffffu, 0, strategy, ranges[k][0], ranges[k][1], max_depth);
        }
}

/* Renders a tile with the scene's own variant and with the general one. */
static void same_as_general(pt_scene *s, const char *want_variant)
{
    const uint32_t W = 12, H = 10;
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = W;
    p.height = H;
    p.seed = 3;
    pt_renderer *a = NULL, *g = NULL;
    CHECK(pt_renderer_new(s, &p, &a, NULL) == PT_OK);
    p.extra_features = 0xffffffffu;
    CHECK(pt_renderer_new(s, &p, &g, NULL) == PT_OK);
    if (a && g) {
        CHECKF(strcmp(pt_renderer_variant(a), want_variant) == 0, "variant %s, expected %s",
               pt_renderer_variant(a), want_variant);
        CHECK(strcmp(pt_renderer_variant(g), "general") == 0);
        pt_pixel_acc pa[120], pg[120];
        pt_rect all = {0, 0, W, H};
        pt_render_tile(a, all, 0, 16, pa, NULL);
        pt_render_tile(g, all, 0, 16, pg, NULL);
        CHECKF(memcmp(pa, pg, sizeof pa) == 0, "variant %s differs from the general integrator",
               want_variant);
        double lit = 0;
        for (int i = 0; i < 120; i++)
            lit += pt_acc_sum(&pa[i], 1);
        CHECK(lit > 0);
    }
    pt_renderer_free(a);
    pt_renderer_free(g);
}

/* Adds a camera "cam" (up completes the right-handed frame) and finishes b. */
static pt_scene *finish_with_camera(pt_scene_builder *b, pt_vec3 position, pt_vec3 forward,
                                    pt_vec3 right, float yfov)
{
    pt_camera cam = {0};
    cam.position = position;
    cam.forward = forward;
    cam.right = right;
    cam.up = pt_v3_cross(right, forward);
    cam.yfov = yfov;
    snprintf(cam.name, sizeof cam.name, "cam");
    CHECK(pt_scene_builder_add_camera(b, &cam, NULL) == PT_OK);
    pt_scene *s = NULL;
    pt_error err = {0};
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

/* A textured Lambertian floor lit by an emissive quad, built by code. With
 * grid > 1 the quad is grid x grid cells of two triangles, textured in its
 * emission too: from 16 triangles a light tree chooses, and with 512 or
 * more the renderer samples a stage's lights in one call
 * (pt_lights_sample_n). */
static pt_scene *textured_lambert_scene(uint32_t grid)
{
    pt_scene_builder *b = NULL;
    CHECK(pt_scene_builder_new(&b, NULL) == PT_OK);
    pt_material floor = pt_material_default();
    floor.metallic = 0.0f;
    floor.specular = 0.0f;
    floor.double_sided = 1;
    pt_texture tex = {2, 2, pt_malloc(16), 1, PT_WRAP_REPEAT, PT_WRAP_REPEAT, 0, 0, 0};
    const uint8_t texels[16] = {255, 40, 40,  255, 40,  255, 40,  255,
                                40,  40, 255, 255, 200, 200, 200, 255};
    memcpy(tex.rgba, texels, 16);
    uint32_t ti = 0, mf = 0, ml = 0;
    CHECK(pt_scene_builder_add_texture(b, &tex, &ti, NULL) == PT_OK);
    floor.base_color_tex = (int32_t)ti;
    pt_material light = pt_material_default();
    light.metallic = 0.0f;
    light.specular = 0.0f;
    light.emissive[0] = light.emissive[1] = light.emissive[2] = 5.0f;
    if (grid > 1)
        light.emissive_tex = (int32_t)ti;
    CHECK(pt_scene_builder_add_material(b, &floor, &mf, NULL) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &light, &ml, NULL) == PT_OK);
    const float fp[] = {-1, 0, -1, 1, 0, -1, 1, 0, 1, -1, 0, 1};
    const float uv[] = {0, 0, 2, 0, 2, 2, 0, 2};
    const uint32_t idx[] = {0, 2, 1, 0, 3, 2};
    CHECK(pt_scene_builder_add_mesh(b, "floor", fp, NULL, uv, 4, idx, 2, NULL, mf, NULL) == PT_OK);
    if (grid <= 1) {
        const float lp[] = {-0.3f, 1, -0.3f, 0.3f, 1, -0.3f, 0.3f, 1, 0.3f, -0.3f, 1, 0.3f};
        const uint32_t lidx[] = {0, 1, 2, 0, 2, 3};
        CHECK(pt_scene_builder_add_mesh(b, "light", lp, NULL, NULL, 4, lidx, 2, NULL, ml, NULL) ==
              PT_OK);
    } else {
        uint32_t nv = (grid + 1) * (grid + 1);
        /* 0.6 wide; with a light tree (grid 4: 32 lights), 1.8, so that the
         * lights spread over enough of the scene for the default to take it
         * (PT_LIGHT_TREE_MIN_SPREAD) */
        float half = grid == 4 ? 0.9f : 0.3f;
        float *gp = pt_malloc_array(nv, 3 * sizeof(float));
        float *guv = pt_malloc_array(nv, 2 * sizeof(float));
        uint32_t *gidx = pt_malloc_array(grid * grid, 6 * sizeof(uint32_t));
        CHECK(gp && guv && gidx);
        if (gp && guv && gidx) {
            for (uint32_t j = 0; j <= grid; j++)
                for (uint32_t i = 0; i <= grid; i++) {
                    uint32_t v = j * (grid + 1) + i;
                    gp[3 * v] = -half + 2.0f * half * (float)i / (float)grid;
                    gp[3 * v + 1] = 1.0f;
                    gp[3 * v + 2] = -half + 2.0f * half * (float)j / (float)grid;
                    guv[2 * v] = (float)i / (float)grid;
                    guv[2 * v + 1] = (float)j / (float)grid;
                }
            for (uint32_t j = 0; j < grid; j++)
                for (uint32_t i = 0; i < grid; i++) {
                    uint32_t v00 = j * (grid + 1) + i, v10 = v00 + 1, v01 = v00 + grid + 1,
                             v11 = v01 + 1, *t = &gidx[6 * (j * grid + i)];
                    t[0] = v00, t[1] = v10, t[2] = v11, t[3] = v00, t[4] = v11, t[5] = v01;
                }
            CHECK(pt_scene_builder_add_mesh(b, "light", gp, NULL, guv, nv, gidx, 2 * grid * grid,
                                            NULL, ml, NULL) == PT_OK);
        }
        pt_free(gp);
        pt_free(guv);
        pt_free(gidx);
    }
    return finish_with_camera(b, pt_v3(0, 0.6f, 2.0f), pt_v3_norm(pt_v3(0, -0.4f, -1)),
                              pt_v3(1, 0, 0), 0.9f);
}

/*
 * Lambert surfaces that reach the shading lanes' rarer masks: a floor and a
 * back wall whose vertex normals lean far from the geometric ones (the
 * shading normal flipped, or replaced when it faces away from the viewer),
 * lit by a vertical single-sided light that half of the floor sees from
 * behind (light samples rejected) and by a horizontal double-sided light
 * that the floor sees from behind (accepted).
 */
static pt_scene *lanes_edge_scene(void)
{
    pt_scene_builder *b = NULL;
    CHECK(pt_scene_builder_new(&b, NULL) == PT_OK);
    pt_material grey = pt_material_default();
    grey.metallic = 0.0f;
    grey.specular = 0.0f;
    pt_material one = grey, two = grey;
    one.emissive[0] = 4.0f, one.emissive[1] = 3.0f, one.emissive[2] = 2.0f;
    two.emissive[0] = two.emissive[1] = two.emissive[2] = 2.0f;
    two.double_sided = 1;
    uint32_t mg = 0, m1 = 0, m2 = 0;
    CHECK(pt_scene_builder_add_material(b, &grey, &mg, NULL) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &one, &m1, NULL) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &two, &m2, NULL) == PT_OK);
    const float fp[] = {-1, 0, -1, 1, 0, -1, 1, 0, 1, -1, 0, 1};
    const float fn[] = {0.9f, 0.3f, 0, -0.9f, 0.3f, 0, 0, 0.2f, 0.95f, 0, -0.3f, -0.9f};
    const uint32_t quad[] = {0, 2, 1, 0, 3, 2};
    CHECK(pt_scene_builder_add_mesh(b, "floor", fp, fn, NULL, 4, quad, 2, NULL, mg, NULL) == PT_OK);
    const float wp[] = {-1, 0, -1, 1, 0, -1, 1, 1.5f, -1, -1, 1.5f, -1};
    const float wn[] = {0.7f, 0, 0.7f, -0.7f, 0, -0.7f, 0, 0.95f, 0.3f, 0, -0.6f, 0.8f};
    const uint32_t wquad[] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "wall", wp, wn, NULL, 4, wquad, 2, NULL, mg, NULL) == PT_OK);
    /* Facing +x (cross of its edges). */
    const float lp[] = {0, 0.2f, -0.4f, 0, 0.8f, -0.4f, 0, 0.8f, 0.4f, 0, 0.2f, 0.4f};
    const uint32_t lq[] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "light", lp, NULL, NULL, 4, lq, 2, NULL, m1, NULL) == PT_OK);
    const float tp[] = {0.3f, 1.2f, -0.3f, 0.8f, 1.2f, -0.3f, 0.8f, 1.2f, 0.2f, 0.3f, 1.2f, 0.2f};
    CHECK(pt_scene_builder_add_mesh(b, "top", tp, NULL, NULL, 4, lq, 2, NULL, m2, NULL) == PT_OK);
    pt_vec3 fwd = pt_v3_norm(pt_v3(-0.1f, -0.3f, -1));
    return finish_with_camera(b, pt_v3(0.3f, 0.7f, 2.2f), fwd,
                              pt_v3_norm(pt_v3_cross(fwd, pt_v3(0, 1, 0))), 1.0f);
}

static void variants(void)
{
    pt_scene *s = load("scenes/cornell_box.gltf", 1.0f);
    if (s) {
        same_as_general(s, "lambert-untextured");
        batched(s, 0);
    }
    pt_scene_free(s);
    s = lanes_edge_scene();
    if (s) {
        same_as_general(s, "lambert-untextured");
        batched(s, 0);
        batched(s, 2); /* paths that end at max_depth */
    }
    pt_scene_free(s);
    s = textured_lambert_scene(1);
    if (s) {
        same_as_general(s, "lambert");
        batched(s, 0);
    }
    pt_scene_free(s);
    s = textured_lambert_scene(16); /* 512 lights */
    if (s) {
        same_as_general(s, "lambert");
        batched(s, 0);
    }
    pt_scene_free(s);
    /* 32 lights: a light tree chooses, with the receiver's normal (the
     * lanes' picks and the MIS pdf of the next hit, prev_n) */
    s = textured_lambert_scene(4);
    if (s) {
        pt_lights *L = NULL;
        CHECK(pt_lights_new(s, &L, NULL) == PT_OK && pt_lights_has_tree(L));
        pt_lights_free(L);
        same_as_general(s, "lambert");
        batched(s, 0);
    }
    pt_scene_free(s);
    /* The shared Cornell box has metals (glTF's default metallic 1): glossy.
     * Its sphere is BLEND (alpha 0.05), which only the general variant
     * renders: first as it is, then with alpha ignored for the untextured
     * variant. */
    char path[4096];
    snprintf(path, sizeof path, "%s/CornellBox/cornellBox.gltf", PT_SHARED_SCENES);
    if (pt_scene_load(path, NULL, &s, NULL) == PT_OK) {
        CHECK(s->features & PT_FEAT_ALPHA);
        same_as_general(s, "general");
        batched(s, 0);
        for (uint32_t i = 0; i < s->num_materials; i++)
            s->materials[i].alpha_mode = PT_ALPHA_OPAQUE;
        s->features &= ~(uint32_t)PT_FEAT_ALPHA;
        same_as_general(s, "untextured");
        batched(s, 0);
        pt_scene_free(s);
    } else {
        CHECK_SKIP("the shared Cornell box: %s not found", path);
        CHECK(!check_shared_required());
    }
}

int main(void)
{
    furnace(1.0f);
    furnace(1e-4f);
    furnace(1e4f);
    furnace_defaults();
    orthographic();
    nee_vs_bsdf();
    determinism();
    split_any_sizes();
    cornell_finite();
    variants();
    return check_report();
}
