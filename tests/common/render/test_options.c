/* Tests for common/render/options.c: the table names every option once, a
 * mask gives getopt exactly its options, values land where they should
 * with the limits every program shares, and the pairs that exclude each
 * other are refused (a placement becomes the camera). */
#include "common/render/options.h"

#include <string.h>

#include "common/render/render.h"
#include "tests/check.h"

static pt_status set(pt_render_opts *o, pt_ropt_id id, const char *text, pt_error *err)
{
    return pt_render_opt_set(o, PT_ROPT_BASE + (int)id, text, err);
}

static void test_table(void)
{
    struct option all[PT_ROPT_COUNT];
    size_t n = pt_render_longopts(PT_ROPT_ALL, all, PT_ROPT_COUNT);
    CHECK(n == PT_ROPT_COUNT);
    for (size_t i = 0; i < n; i++) {
        CHECKF(all[i].name && all[i].name[0] && all[i].val == PT_ROPT_BASE + (int)i, "entry %zu",
               i);
        CHECK(pt_render_opt_is(all[i].val));
        for (size_t j = 0; j < i; j++)
            CHECKF(strcmp(all[i].name, all[j].name) != 0, "--%s twice", all[i].name);
    }
    CHECK(!pt_render_opt_is(PT_ROPT_BASE - 1) && !pt_render_opt_is(PT_ROPT_BASE + PT_ROPT_COUNT));
    struct option two[4];
    CHECK(pt_render_longopts(PT_ROPT(PT_ROPT_SPP) | PT_ROPT(PT_ROPT_VIEW), two, 4) == 2);
    CHECK(!strcmp(two[0].name, "spp") && !strcmp(two[1].name, "view"));
    CHECK(pt_render_longopts(PT_ROPT_ALL, two, 1) == 1); /* never past cap */
}

static void test_values(void)
{
    pt_render_opts o;
    pt_render_opts_init(&o);
    pt_error err = {0};
    CHECK(o.spp == 64 && o.tile == 32 && o.chunk == 16 && o.env_strength == 1.0 && o.fps == 24.0 &&
          o.max_depth == PT_RENDER_DEFAULT_MAX_DEPTH && o.given == 0 && !o.camera);
    CHECK(set(&o, PT_ROPT_SPP, "256", &err) == PT_OK && o.spp == 256);
    CHECK(set(&o, PT_ROPT_SPP, "16777217", &err) == PT_ERR_ARG && o.spp == 256);
    CHECKF(!strcmp(err.msg, "--spp: '16777217' is not a whole number in [1, 16777216]"), "%s",
           err.msg);
    CHECK(set(&o, PT_ROPT_RES, "64x32", &err) == PT_OK && o.width == 64 && o.height == 32);
    CHECK(set(&o, PT_ROPT_MIN_SPP, "1", &err) == PT_ERR_ARG);
    CHECK(set(&o, PT_ROPT_TARGET_ERROR, "0", &err) == PT_ERR_ARG);
    CHECK(set(&o, PT_ROPT_VIEW, "agx", &err) == PT_OK && o.view.kind == PT_VIEW_AGX);
    CHECK(set(&o, PT_ROPT_EXPOSURE, "-1.5", &err) == PT_OK && o.view.exposure == -1.5f);
    CHECK(set(&o, PT_ROPT_TRANSPARENT, NULL, &err) == PT_OK);
    CHECK(set(&o, PT_ROPT_BACKGROUND, "1,0.5,0", &err) == PT_OK && o.background[1] == 0.5);
    /* The clamps: 0 (off) to 1e30, kept as the float the farm sends;
     * negative, NaN, infinite and over the cap refused naming the option. */
    CHECK(set(&o, PT_ROPT_CLAMP_DIRECT, "0.1", &err) == PT_OK && o.clamp_direct == 0.1f);
    CHECK(set(&o, PT_ROPT_CLAMP_INDIRECT, "1e30", &err) == PT_OK && o.clamp_indirect == 1e30f);
    CHECK(set(&o, PT_ROPT_CLAMP_INDIRECT, "0", &err) == PT_OK && o.clamp_indirect == 0.0f);
    const char *bad_clamps[] = {"-1", "nan", "inf", "1e31", "x", ""};
    for (size_t k = 0; k < sizeof bad_clamps / sizeof *bad_clamps; k++) {
        CHECKF(set(&o, PT_ROPT_CLAMP_DIRECT, bad_clamps[k], &err) == PT_ERR_ARG &&
                   strstr(err.msg, "--clamp-direct") && o.clamp_direct == 0.1f,
               "'%s'", bad_clamps[k]);
        CHECKF(set(&o, PT_ROPT_CLAMP_INDIRECT, bad_clamps[k], &err) == PT_ERR_ARG &&
                   strstr(err.msg, "--clamp-indirect") && o.clamp_indirect == 0.0f,
               "'%s'", bad_clamps[k]);
    }
    char long_name[80];
    memset(long_name, 'c', 65);
    long_name[65] = '\0';
    CHECK(set(&o, PT_ROPT_CAMERA, long_name, &err) == PT_ERR_ARG && !o.camera);
    CHECK(set(&o, PT_ROPT_CAMERA, "", &err) == PT_ERR_ARG);
    uint32_t want = PT_ROPT(PT_ROPT_SPP) | PT_ROPT(PT_ROPT_RES) | PT_ROPT(PT_ROPT_VIEW) |
                    PT_ROPT(PT_ROPT_EXPOSURE) | PT_ROPT(PT_ROPT_TRANSPARENT) |
                    PT_ROPT(PT_ROPT_BACKGROUND) | PT_ROPT(PT_ROPT_CLAMP_DIRECT) |
                    PT_ROPT(PT_ROPT_CLAMP_INDIRECT);
    CHECKF(o.given == want, "given %#x, want %#x", o.given, want);
    CHECK(pt_render_opts_finish(&o, &err) == PT_OK);
}

static void test_pairs(void)
{
    pt_error err = {0};
    pt_render_opts o;
    pt_render_opts_init(&o);
    CHECK(set(&o, PT_ROPT_ENV, "a.hdr", &err) == PT_OK);
    CHECK(set(&o, PT_ROPT_BACKGROUND, "1,1,1", &err) == PT_OK);
    CHECK(pt_render_opts_finish(&o, &err) == PT_ERR_ARG && strstr(err.msg, "two environments"));
    pt_render_opts_init(&o);
    CHECK(set(&o, PT_ROPT_TARGET_ERROR, "0.01", &err) == PT_OK);
    CHECK(set(&o, PT_ROPT_MIN_GAIN, "1e-6", &err) == PT_OK);
    CHECK(pt_render_opts_finish(&o, &err) == PT_ERR_ARG && strstr(err.msg, "adaptive rules"));
    /* A placement becomes the camera, as text a job carries. */
    pt_render_opts_init(&o);
    CHECK(set(&o, PT_ROPT_CAMERA_FROM, "0,1,5", &err) == PT_OK);
    CHECK(set(&o, PT_ROPT_CAMERA_AT, "0,1,0", &err) == PT_OK);
    CHECK(set(&o, PT_ROPT_FOV, "30", &err) == PT_OK);
    CHECK(pt_render_opts_finish(&o, &err) == PT_OK);
    CHECKF(o.camera && !strcmp(o.camera, "look:0,1,5:0,1,0:fov=30"), "%s",
           o.camera ? o.camera : "(none)");
    pt_camera c;
    CHECK(pt_camera_look_parse(o.camera, &c, &err) == PT_OK && c.forward.z < -0.99f &&
          c.position.z == 5.0f);
    pt_render_opts_init(&o);
    CHECK(set(&o, PT_ROPT_CAMERA_AT, "0,1,0", &err) == PT_OK);
    CHECK(pt_render_opts_finish(&o, &err) == PT_ERR_ARG && strstr(err.msg, "together"));
}

int main(void)
{
    test_table();
    test_values();
    test_pairs();
    return check_report();
}
