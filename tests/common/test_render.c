/*
 * test_render.c - the integrator against analytic answers and against itself.
 *
 * - White furnace (scenes/furnace.gltf): a closed Lambertian sphere of albedo
 *   rho emitting E everywhere; every pixel's exact value is E / (1 - rho).
 *   Each pixel must lie within 5 sigma of it (sigma: the pixel's own standard
 *   error from its samples) and the image mean within 0.5 %, at scales 1, 1e-4
 *   and 1e4.
 * - Direct light by NEE alone and by BSDF sampling alone agree within their
 *   combined standard error.
 * - Determinism: [0,64) equals the in-order sum of four 16-sample chunks bit
 *   for bit, and the same pixels rendered by several threads equal one thread's.
 * - The Cornell box renders with no NaN or Inf and no rejected sample.
 */
#include <math.h>
#include <pthread.h>
#include <string.h>

#include "common/alloc.h"
#include "common/render.h"
#include "common/scene.h"
#include "tests/check.h"

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
    double n = a->n, mean = pt_luminance(pt_v3((float)(a->sum[0] / n), (float)(a->sum[1] / n),
                                              (float)(a->sum[2] / n)));
    double var = (a->sum_sq - n * mean * mean) / (n - 1.0);
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
    pt_render_stats st = {0, 0, 0};
    pt_rect all = {0, 0, W, H};
    pt_render_tile(r, all, 0, SPP, acc, &st);
    int outliers = 0;
    double sum = 0, var_sum = 0;
    for (uint32_t i = 0; i < W * H; i++) {
        double m = acc[i].sum[1] / acc[i].n;
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
        double xa = pt_luminance(pt_v3((float)(pa[i].sum[0] / pa[i].n), (float)(pa[i].sum[1] / pa[i].n),
                                       (float)(pa[i].sum[2] / pa[i].n)));
        double xb = pt_luminance(pt_v3((float)(pb[i].sum[0] / pb[i].n), (float)(pb[i].sum[1] / pb[i].n),
                                       (float)(pb[i].sum[2] / pb[i].n)));
        double sa = pixel_sigma(&pa[i]), sb = pixel_sigma(&pb[i]);
        if (fabs(xa - xb) > 5.0 * sqrt(sa * sa + sb * sb) + 1e-6)
            outliers++;
        ma += pa[i].sum[1];
        mb += pb[i].sum[1];
        mm += pm[i].sum[1];
        va += sa * sa;
        vb += sb * sb;
        vm += pixel_sigma(&pm[i]) * pixel_sigma(&pm[i]);
    }
    ma /= 256.0 * W * H;
    mb /= 4096.0 * W * H;
    mm /= 256.0 * W * H;
    double sab = sqrt(va + vb) / (W * H), sam = sqrt(va + vm) / (W * H);
    printf("direct light, image mean: NEE %.5f, BSDF %.5f, MIS %.5f (sigma %.2e, %.2e)\n", ma,
           mb, mm, sab, sam);
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
        nonzero += whole[i].sum[0] > 0;
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

static void cornell_finite(void)
{
    pt_scene *s = load("scenes/cornell_box.gltf", 1.0f);
    CHECK(s != NULL);
    if (!s)
        return;
    const uint32_t W = 32, H = 32;
    pt_renderer *r = renderer(s, W, H, 16, PT_LIGHT_MIS);
    pt_pixel_acc *acc = pt_malloc_array(W * H, sizeof *acc);
    pt_render_stats st = {0, 0, 0};
    pt_rect all = {0, 0, W, H};
    pt_render_tile(r, all, 0, 16, acc, &st);
    int bad = 0;
    for (uint32_t i = 0; i < W * H; i++)
        for (int c = 0; c < 3; c++)
            bad += !isfinite(acc[i].sum[c]) || acc[i].sum[c] < 0;
    CHECK(bad == 0);
    CHECKF(st.rejected == 0, "%llu rejected samples", (unsigned long long)st.rejected);
    CHECK(st.samples == (uint64_t)W * H * 16);
    pt_free(acc);
    pt_renderer_free(r);
    pt_scene_free(s);
}

int main(void)
{
    furnace(1.0f);
    furnace(1e-4f);
    furnace(1e4f);
    nee_vs_bsdf();
    determinism();
    cornell_finite();
    return check_report();
}
