/*
 * test_assets.c - the shared glTF assets a new user brings, under the lights
 * they are made for (issue 14's acceptance list), through the whole
 * integrator at default settings.
 *
 * - DamagedHelmet and ToyCar under each of the three shared environment
 *   maps (the studio, the park with its hard low sun, the overcast square):
 *   no sample is rejected as NaN or Inf, every pixel mean is finite and
 *   non-negative, and the image is lit (a mean luminance above 1e-3 of the
 *   map's own mean, far below what any of them reads).
 * - LightsPunctualLamp is lit by its five KHR_lights_punctual lights: the
 *   image with them is brighter, by more than 5 standard errors of the
 *   difference (64 samples: its glass shade makes caustics), than the same scene with its lights
 * taken out (what the renderer made of it before it read the extension), and has no NaN/Inf. The
 * images are small (48 x 48, 8 samples): enough to exercise every material and light path, short
 * enough for the suite. Needs ../shared (skipped without it, a failure under CI=true).
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/env.h"
#include "common/render/render.h"
#include "common/scene/scene.h"
#include "tests/check.h"

#define SIDE 48u
#define SPP 8u
/* The lamp's glass shade makes caustics (found only by BSDF sampling):
 * rare bright samples that more samples tame. */
#define LAMP_SPP 64u

typedef struct image_stats {
    double mean;    /* mean luminance over the pixels */
    double se;      /* its standard error, from the per-pixel sample variance */
    int finite;     /* every pixel mean finite and >= 0 */
    uint64_t bad;   /* samples rejected as NaN / Inf */
    uint64_t count; /* samples taken */
} image_stats;

/* What the importer skips is the materials issue's business, not this test's. */
static void quiet(void *user, const char *message)
{
    (void)user;
    (void)message;
}

static pt_scene *load(const char *rel)
{
    char p[1024];
    snprintf(p, sizeof p, "%s/%s", PT_SHARED_SCENES, rel);
    pt_scene_opts o = {0};
    o.warn = quiet;
    pt_scene *s = NULL;
    pt_error err = {0};
    CHECKF(pt_scene_load(p, &o, &s, &err) == PT_OK, "%s: %s", rel, err.msg);
    return s;
}

static image_stats render(const pt_scene *s, const pt_env *env, uint32_t spp)
{
    image_stats r = {0.0, 0.0, 1, 0, 0};
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = p.height = SIDE;
    p.seed = 5;
    p.env = env;
    pt_renderer *rd = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &rd, &err) == PT_OK, "%s", err.msg);
    pt_pixel_acc *acc = pt_malloc_array((size_t)SIDE * SIDE, sizeof *acc);
    if (!rd || !acc) {
        pt_free(acc);
        pt_renderer_free(rd);
        r.finite = 0;
        return r;
    }
    pt_render_stats st = {0};
    pt_render_tile(rd, (pt_rect){0, 0, SIDE, SIDE}, 0, spp, acc, &st);
    double sum = 0.0, var = 0.0;
    for (uint32_t i = 0; i < SIDE * SIDE; i++) {
        double k = acc[i].n;
        if (k < 2.0) {
            r.finite = 0;
            continue;
        }
        double lum = (0.2126 * pt_acc_sum(&acc[i], 0) + 0.7152 * pt_acc_sum(&acc[i], 1) +
                      0.0722 * pt_acc_sum(&acc[i], 2)) /
                     k;
        for (int c = 0; c < 3; c++)
            r.finite &= isfinite(pt_acc_sum(&acc[i], c)) && pt_acc_sum(&acc[i], c) >= 0.0;
        sum += lum;
        var += fmax((pt_acc_sum_sq(&acc[i]) - k * lum * lum) / (k - 1.0), 0.0) / k;
    }
    r.mean = sum / (SIDE * SIDE);
    r.se = sqrt(var) / (SIDE * SIDE);
    r.bad = st.rejected;
    r.count = st.samples;
    pt_free(acc);
    pt_renderer_free(rd);
    return r;
}

static void under_maps(const char *rel)
{
    static const char *maps[] = {"studio_small_03_1k.hdr", "rooitou_park_1k.hdr",
                                 "potsdamer_platz_1k.hdr"};
    pt_scene *s = load(rel);
    if (!s)
        return;
    for (size_t m = 0; m < sizeof maps / sizeof maps[0]; m++) {
        char path[1024];
        snprintf(path, sizeof path, "%s/../envs/%s", PT_SHARED_SCENES, maps[m]);
        pt_env *env = NULL;
        pt_error err = {0};
        CHECKF(pt_env_load(path, 1.0f, 0.0f, &env, &err) == PT_OK, "%s: %s", maps[m], err.msg);
        if (!env)
            continue;
        image_stats r = render(s, env, SPP);
        double sky = pt_env_mean_luminance(env);
        CHECKF(r.bad == 0 && r.finite, "%s under %s: %llu of %llu samples NaN/Inf, finite %d", rel,
               maps[m], (unsigned long long)r.bad, (unsigned long long)r.count, r.finite);
        CHECKF(r.count == (uint64_t)SIDE * SIDE * SPP, "%s: %llu samples", rel,
               (unsigned long long)r.count);
        CHECKF(r.mean > 1e-3 * sky, "%s under %s: mean luminance %g, the sky's %g", rel, maps[m],
               r.mean, sky);
        if (getenv("PT_TEST_VERBOSE"))
            printf("%s under %s: mean %g +- %g (sky %g)\n", rel, maps[m], r.mean, r.se, sky);
        pt_env_free(env);
    }
    pt_scene_free(s);
}

static void lamp_lit_by_its_lights(void)
{
    pt_scene *s = load("LightsPunctualLamp/LightsPunctualLamp.gltf");
    if (!s)
        return;
    CHECKF(s->num_punctual == 5 && (s->features & PT_FEAT_PUNCTUAL), "%u punctual lights",
           s->num_punctual);
    image_stats lit = render(s, NULL, LAMP_SPP);
    /* The same scene as a reader that ignores the extension sees it. */
    uint32_t n = s->num_punctual, features = s->features;
    s->num_punctual = 0;
    s->features &= ~(uint32_t)PT_FEAT_PUNCTUAL;
    image_stats dark = render(s, NULL, LAMP_SPP);
    s->num_punctual = n;
    s->features = features;
    CHECKF(lit.bad == 0 && lit.finite, "lamp: %llu NaN/Inf samples", (unsigned long long)lit.bad);
    double se = sqrt(lit.se * lit.se + dark.se * dark.se);
    CHECKF(lit.mean - dark.mean > 5.0 * se && lit.mean > 2.0 * dark.mean,
           "lamp: mean %g with its lights, %g without (se %g)", lit.mean, dark.mean, se);
    if (getenv("PT_TEST_VERBOSE"))
        printf("lamp: %g with its lights, %g without\n", lit.mean, dark.mean);
    pt_scene_free(s);
}

int main(void)
{
    char probe[1024];
    snprintf(probe, sizeof probe, "%s/../envs/rooitou_park_1k.hdr", PT_SHARED_SCENES);
    FILE *f = fopen(probe, "rb");
    if (!f) {
        CHECK_SKIP("shared scenes and maps not found; the asset renders");
        CHECK(!check_shared_required());
        return check_report();
    }
    fclose(f);
    under_maps("DamagedHelmet/DamagedHelmet.glb");
    under_maps("ToyCar/ToyCar.gltf");
    lamp_lit_by_its_lights();
    return check_report();
}
