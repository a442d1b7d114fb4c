/*
 * test_film_farm.c - the transparent film and the depth-cap count through the
 * real programs (ptworker, ptserve --local) as processes.
 *
 *  1. `ptworker --transparent` on the Cornell box seen wider than its
 *     opening (camera rays escape at the sides), under a uniform --background:
 *     the EXR has an A channel, 0 with RGB exactly 0 where every camera ray
 *     escaped, 1 where none did, fractions on the box's silhouette; without
 *     the flag, no A channel and the background where the rays escape.
 *  2. `ptserve --local 3 --transparent --background` gives the same R, G, B,
 *     samples and A bits as the standalone render: the flag and the
 *     environment both reach the workers, and an escaping camera ray gives
 *     RGB 0 and A 0 on the farm too.
 *  3. The white furnace (a closed sphere) with --max-depth 2: every path
 *     reaches the cap (Russian roulette starts at 3 bounces), so ptworker and
 *     one-job ptserve both report exactly W x H x spp capped paths.
 */
#include <math.h>

#include "tests/check.h"
#include "tests/server/farm_util.h"

#define VIEW "--res", "64x16", "--tile", "16", "--chunk", "8", "--seed", "5", "--spp", "16"
/* A sky that a camera ray leaving the scene would see without --transparent. */
#define SKY "--background", "0.25,0.5,1"

static const char *CORNELL = PT_SOURCE_DIR "/scenes/cornell_box.gltf";
static const char *FURNACE = PT_SOURCE_DIR "/scenes/furnace.gltf";

static void transparent(void)
{
    const char *solo[] = {PT_BIN_DIR "/ptworker", "--scene", CORNELL,          VIEW, SKY,
                          "--transparent",        "-o",      path("solo.exr"), "-q", NULL};
    CHECK(run(solo, "solo.log", 120) == 0);
    pt_image *img = load_exr("solo.exr");
    CHECK(img && img->has_alpha == 1);
    int empty = 0, full = 0, part = 0, bad = 0;
    for (uint32_t i = 0; img && i < img->width * img->height; i++) {
        float a = img->a[i];
        if (a == 0.0f) {
            empty++;
            bad += img->r[i] != 0.0f || img->g[i] != 0.0f || img->b[i] != 0.0f;
        } else if (a == 1.0f) {
            full++;
        } else {
            part++;
            bad += !(a > 0.0f && a < 1.0f);
        }
        /* 16 samples: a coverage is a multiple of 1/16. */
        bad += a * 16.0f != (float)(int)(a * 16.0f);
    }
    printf("transparent Cornell box: %d pixels empty, %d covered, %d on the silhouette\n", empty,
           full, part);
    CHECK(empty > 0 && full > 0 && part > 0 && bad == 0);

    /* Without the flag the pixels no camera ray covered show the sky. */
    const char *opaque[] = {PT_BIN_DIR "/ptworker", "--scene", CORNELL, VIEW, SKY, "-o",
                            path("opaque.exr"),     "-q",      NULL};
    CHECK(run(opaque, "opaque.log", 120) == 0);
    pt_image *op = load_exr("opaque.exr");
    CHECK(op && op->has_alpha == 0);
    int sky = 0, notsky = 0;
    for (uint32_t i = 0; img && op && i < img->width * img->height; i++) {
        if (img->a[i] != 0.0f)
            continue;
        int is = fabsf(op->r[i] - 0.25f) < 1e-4f && fabsf(op->g[i] - 0.5f) < 1e-4f &&
                 fabsf(op->b[i] - 1.0f) < 1e-4f;
        sky += is;
        notsky += !is;
    }
    CHECKF(sky == empty && notsky == 0, "opaque: %d of %d uncovered pixels show the sky", sky,
           empty);
    pt_image_free(op);
    pt_image_free(img);

    const char *farm[] = {PT_BIN_DIR "/ptserve",
                          "--local",
                          "3",
                          "--worker-threads",
                          "1",
                          VIEW,
                          SKY,
                          "--transparent",
                          "-o",
                          path("farm.exr"),
                          CORNELL,
                          NULL};
    CHECK(run(farm, "farm.log", 120) == 0);
    CHECKF(same_pixels("solo.exr", "farm.exr"), "--transparent: --local 3 differs (RGB)");
    pt_image *a = load_exr("solo.exr"), *b = load_exr("farm.exr");
    CHECK(a && b && b->has_alpha == 1);
    if (a && b)
        CHECKF(memcmp(a->a, b->a, (size_t)a->width * a->height * sizeof(float)) == 0,
               "--transparent: --local 3 differs (A)");
    int farm_empty = 0, farm_bad = 0;
    for (uint32_t i = 0; b && b->has_alpha && i < b->width * b->height; i++) {
        if (b->a[i] != 0.0f)
            continue;
        farm_empty++;
        farm_bad += b->r[i] != 0.0f || b->g[i] != 0.0f || b->b[i] != 0.0f;
    }
    CHECKF(farm_empty == empty && farm_bad == 0,
           "--transparent on the farm: %d pixels empty (%d standalone), %d of them not black",
           farm_empty, empty, farm_bad);
    pt_image_free(a);
    pt_image_free(b);
}

static void depth_cap(void)
{
    const char *solo[] = {PT_BIN_DIR "/ptworker",
                          "--scene",
                          FURNACE,
                          "--res",
                          "8x8",
                          "--spp",
                          "16",
                          "--max-depth",
                          "2",
                          "-o",
                          path("furnace.exr"),
                          "-q",
                          NULL};
    CHECK(run(solo, "furnace.log", 120) == 0);
    CHECKF(log_has("furnace.log", "1024 paths reached the depth cap of 2; raise --max-depth"),
           "ptworker did not report 8 x 8 x 16 capped paths");
    const char *farm[] = {PT_BIN_DIR "/ptserve",
                          "--local",
                          "2",
                          "--worker-threads",
                          "1",
                          "--res",
                          "8x8",
                          "--spp",
                          "16",
                          "--tile",
                          "4",
                          "--chunk",
                          "8",
                          "--max-depth",
                          "2",
                          "-o",
                          path("furnace_farm.exr"),
                          FURNACE,
                          NULL};
    CHECK(run(farm, "furnace_farm.log", 120) == 0);
    CHECKF(log_has("furnace_farm.log", "1024 paths reached the depth cap of 2"),
           "ptserve did not report 8 x 8 x 16 capped paths");
    /* At the default cap none does, and nothing is said. */
    const char *deflt[] = {
        PT_BIN_DIR "/ptworker", "--scene", FURNACE, "--res", "8x8", "--spp", "16", "-o",
        path("furnace_d.exr"),  "-q",      NULL};
    CHECK(run(deflt, "furnace_d.log", 120) == 0);
    CHECK(!log_has("furnace_d.log", "depth cap"));
}

int main(void)
{
    snprintf(tmp, sizeof tmp, "/tmp/pt_test_film_farm_XXXXXX");
    if (!mkdtemp(tmp))
        return 1;
    signal(SIGPIPE, SIG_IGN);
    transparent();
    depth_cap();
    return farm_test_end();
}
