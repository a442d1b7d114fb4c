/*
 * test_bdpt_auto.c - --bdpt auto's choice (common/render/bdpt_auto.h).
 *
 * - A lamp shut in a small box inside a large room: every photon lands in
 *   the box, and every probe from there meets a wall within the box, far
 *   nearer than PT_BDPT_AUTO_NEAR of the room's diagonal: the share is 1
 *   exactly, and auto takes bdpt.
 * - The same lamp on the room's ceiling, shining down: its photons land on
 *   the floor and the walls, open to the room: the share is under 0.05,
 *   and auto stays unidirectional. (The box was the only change: the share
 *   measures where the light lands, not that there is a lamp.)
 * - What bdpt cannot take, or was not measured to pay on, keeps auto off
 *   without measuring (share -1): a map or background, a punctual light,
 *   guiding, clamping; a scene without emitters has a share of 0.
 * - The answer is a function of the scene: the same share, bit for bit,
 *   from a second call.
 * - With ../shared: the NVIDIA Cornell box, whose lamp lights the gap under
 *   the ceiling (docs/bench/bdpt.md), is on; the repository's box is off.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>

#include "common/base/alloc.h"
#include "common/render/bdpt_auto.h"
#include "tests/check.h"

/* A quad p0, p0 + a, p0 + a + b, p0 + b (its front along a x b). */
static void quad(pt_scene_builder *b, const float p0[3], const float a[3], const float c[3],
                 uint32_t mat)
{
    float v[12];
    for (int k = 0; k < 3; k++) {
        v[k] = p0[k];
        v[3 + k] = p0[k] + a[k];
        v[6 + k] = p0[k] + a[k] + c[k];
        v[9 + k] = p0[k] + c[k];
    }
    static const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    pt_error err;
    CHECK(pt_scene_builder_add_mesh(b, "quad", v, NULL, NULL, 4, idx, 2, NULL, mat, &err) == PT_OK);
}

/* An axis-aligned box [lo, hi], its six faces facing in. */
static void box(pt_scene_builder *b, const float lo[3], const float hi[3], uint32_t mat)
{
    const float dx = hi[0] - lo[0], dy = hi[1] - lo[1], dz = hi[2] - lo[2];
    const float X[3] = {dx, 0, 0}, Y[3] = {0, dy, 0}, Z[3] = {0, 0, dz};
    const float mX[3] = {-dx, 0, 0}, mY[3] = {0, -dy, 0};
    quad(b, lo, Z, X, mat);                                /* floor, facing +y */
    quad(b, (float[3]){hi[0], hi[1], hi[2]}, mX, mY, mat); /* front; the rest any side */
    quad(b, (float[3]){lo[0], hi[1], lo[2]}, X, Z, mat);   /* ceiling */
    quad(b, lo, X, Y, mat);                                /* back */
    quad(b, lo, Y, Z, mat);                                /* left */
    quad(b, (float[3]){hi[0], lo[1], lo[2]}, Z, Y, mat);   /* right */
}

enum { LAMP_SHUT, LAMP_CEILING, NO_LAMP, LAMP_AND_POINT };

/* A 20 x 10 x 20 room; a 0.4-wide lamp facing up on the floor of a
 * 0.6-wide closed box (LAMP_SHUT), or facing down under the ceiling. */
static pt_scene *room(int kind)
{
    pt_error err;
    pt_scene_builder *b = NULL;
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material wall = pt_material_default(), lamp = pt_material_default();
    wall.metallic = 0.0f;
    lamp.metallic = 0.0f;
    lamp.emissive[0] = lamp.emissive[1] = lamp.emissive[2] = 10.0f;
    uint32_t mw = 0, ml = 0;
    CHECK(pt_scene_builder_add_material(b, &wall, &mw, &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &lamp, &ml, &err) == PT_OK);
    box(b, (float[3]){-10, 0, -10}, (float[3]){10, 10, 10}, mw);
    const float A[3] = {0.4f, 0, 0}, Zf[3] = {0, 0, 0.4f};
    if (kind == LAMP_SHUT) {
        box(b, (float[3]){-0.3f, 0, -0.3f}, (float[3]){0.3f, 0.6f, 0.3f}, mw);
        quad(b, (float[3]){-0.2f, 0.05f, -0.2f}, Zf, A, ml); /* faces +y */
    } else if (kind != NO_LAMP) {
        quad(b, (float[3]){-0.2f, 9.9f, -0.2f}, A, Zf, ml); /* faces -y */
    }
    if (kind == LAMP_AND_POINT || kind == NO_LAMP) {
        pt_punctual p = {0};
        p.type = PT_PUNCTUAL_POINT;
        p.direction = pt_v3(0.0f, -1.0f, 0.0f);
        p.intensity = pt_v3(1.0f, 1.0f, 1.0f);
        snprintf(p.name, sizeof p.name, "bulb");
        CHECK(pt_scene_builder_add_punctual(b, &p, (double[3]){0.0, 5.0, 0.0}, &err) == PT_OK);
    }
    pt_scene *s = NULL;
    CHECK(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK); /* consumes b */
    return s;
}

static void synthetic(void)
{
    pt_error err;
    int on = -1;
    double share = -2.0, again = -2.0;

    pt_scene *shut = room(LAMP_SHUT);
    CHECK(pt_bdpt_auto(shut, 0, 0, 0, &on, &share, &err) == PT_OK);
    CHECKF(on == 1 && share == 1.0, "lamp in a closed box: on %d, share %.4f", on, share);
    CHECK(pt_bdpt_pocketed(shut, &again, &err) == PT_OK);
    CHECK(memcmp(&share, &again, sizeof share) == 0);
    /* What auto does not measure. */
    const struct {
        int env, guiding, clamped;
    } no[] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    for (size_t i = 0; i < sizeof no / sizeof no[0]; i++) {
        CHECK(pt_bdpt_auto(shut, no[i].env, no[i].guiding, no[i].clamped, &on, &share, &err) ==
              PT_OK);
        CHECKF(on == 0 && share == -1.0, "case %zu: on %d, share %g", i, on, share);
    }
    pt_scene_free(shut);

    pt_scene *open = room(LAMP_CEILING);
    CHECK(pt_bdpt_auto(open, 0, 0, 0, &on, &share, &err) == PT_OK);
    CHECKF(on == 0 && share >= 0.0 && share < 0.05, "lamp on the ceiling: on %d, share %.4f", on,
           share);
    pt_scene_free(open);

    pt_scene *punct = room(LAMP_AND_POINT);
    CHECK(pt_bdpt_auto(punct, 0, 0, 0, &on, &share, &err) == PT_OK);
    CHECKF(on == 0 && share == -1.0, "with a point light: on %d, share %g", on, share);
    pt_scene_free(punct);

    pt_scene *dark = room(NO_LAMP);
    CHECK(pt_bdpt_pocketed(dark, &share, &err) == PT_OK);
    CHECK(share == 0.0);
    pt_scene_free(dark);
}

static void shared_scenes(void)
{
    const char *nv = PT_SHARED_SCENES "/CornellBox/cornellBox.gltf";
    struct stat sb;
    if (stat(nv, &sb) != 0) {
        CHECK_SKIP("shared scenes not found (%s)", nv);
        return;
    }
    const struct {
        const char *path;
        int on;
    } cases[] = {{nv, 1}, {PT_SOURCE_DIR "/scenes/cornell_box.gltf", 0}};
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        pt_error err;
        pt_scene *s = NULL;
        pt_scene_opts so = {0};
        so.warn = NULL;
        CHECK(pt_scene_load(cases[i].path, &so, &s, &err) == PT_OK);
        if (!s)
            continue;
        int on = -1;
        double share = -2.0;
        CHECK(pt_bdpt_auto(s, 0, 0, 0, &on, &share, &err) == PT_OK);
        CHECKF(on == cases[i].on, "%s: on %d, share %.4f", cases[i].path, on, share);
        printf("%s: share %.4f\n", cases[i].path, share);
        pt_scene_free(s);
    }
}

int main(void)
{
    int64_t live0 = pt_alloc_live();
    synthetic();
    shared_scenes();
    CHECK(pt_alloc_live() == live0);
    return check_report();
}
