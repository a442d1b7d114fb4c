/*
 * test_framing.c - the automatic camera of a scene without one, as the
 * renderer uses it: it looks at the scene as posed at the time asked for
 * (BoxAnimated at t = 1 keeps its lid in the frame) and fits the bounds'
 * projection to the image's aspect (a flat board fills the frame, where the
 * bounding sphere left it about half of it). A file's camera is used as it
 * is. Needs ../shared for BoxAnimated (skipped without it, a failure under
 * CI=true).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "common/render/render.h"
#include "common/scene/scene.h"
#include "tests/check.h"

/* The largest of |x| / (z tan(xfov/2)) and |y| / (z tan(yfov/2)) over the
 * box's 8 corners seen by c at aspect a: <= 1 when all are in the view, and
 * the share of the frame the box fills along its fuller axis. -1 when a
 * corner is behind the camera. */
static float fill(const pt_camera *c, pt_vec3 lo, pt_vec3 hi, float a)
{
    float t = tanf(0.5f * c->yfov), worst = 0.0f;
    for (int i = 0; i < 8; i++) {
        pt_vec3 p = pt_v3(i & 1 ? hi.x : lo.x, i & 2 ? hi.y : lo.y, i & 4 ? hi.z : lo.z);
        pt_vec3 d = pt_v3_sub(p, c->position);
        float z = pt_v3_dot(d, c->forward);
        if (!(z > 0.0f))
            return -1.0f;
        float x = fabsf(pt_v3_dot(d, c->right)) / (z * t * a);
        float y = fabsf(pt_v3_dot(d, c->up)) / (z * t);
        worst = fmaxf(worst, fmaxf(x, y));
    }
    return worst;
}

static pt_renderer *renderer(const pt_scene *s, uint32_t w, uint32_t h)
{
    pt_render_params p;
    pt_render_params_default(&p);
    p.width = w;
    p.height = h;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    return r;
}

/* A 4 x 2 board in the XY plane, lit by its own emission. */
static void test_board_fills(void)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    m.emissive[0] = m.emissive[1] = m.emissive[2] = 1.0f;
    uint32_t mi = 0;
    CHECK(pt_scene_builder_add_material(b, &m, &mi, &err) == PT_OK);
    const float pos[12] = {-2, -1, 0, 2, -1, 0, 2, 1, 0, -2, 1, 0};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "board", pos, NULL, NULL, 4, idx, 2, NULL, 0, &err) ==
          PT_OK);
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    if (!s)
        return;
    CHECK(s->camera.framed);
    const uint32_t sizes[][2] = {{200, 100}, {100, 100}, {60, 120}};
    for (int k = 0; k < 3; k++) {
        pt_renderer *r = renderer(s, sizes[k][0], sizes[k][1]);
        if (!r)
            continue;
        const pt_camera *c = pt_renderer_camera(r);
        float a = (float)sizes[k][0] / (float)sizes[k][1];
        float f = fill(c, s->bounds_min, s->bounds_max, a);
        /* Within the view, filling it to the 5 % margin (1 / 1.05 = 0.952). */
        CHECKF(f > 0.93f && f <= 1.0f, "%ux%u: the board fills %.3f of the frame", sizes[k][0],
               sizes[k][1], f);
        CHECK(c->framed && c->forward.z < -0.5f);
        pt_renderer_free(r);
    }
    /* A file's camera is the renderer's, bit for bit. */
    pt_camera fc = s->camera;
    fc.framed = 0;
    fc.position = pt_v3(0.5f, 0.25f, 9.0f);
    s->camera = fc;
    pt_renderer *r = renderer(s, 64, 32);
    if (r) {
        CHECK(memcmp(pt_renderer_camera(r), &fc, sizeof fc) == 0);
        pt_renderer_free(r);
    }
    pt_scene_free(s);
}

static void test_box_animated(void)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/BoxAnimated/BoxAnimated.glb", PT_SHARED_SCENES);
    if (access(path, R_OK) != 0) {
        CHECK_SKIP("%s is missing", path);
        CHECK(!check_shared_required());
        return;
    }
    pt_error err = {0};
    pt_scene_opts so = {0};
    pt_scene *rest = NULL, *posed = NULL;
    CHECKF(pt_scene_load(path, &so, &rest, &err) == PT_OK, "%s", err.msg);
    so.animate = 1;
    so.time = 1.0;
    CHECKF(pt_scene_load(path, &so, &posed, &err) == PT_OK, "%s", err.msg);
    if (!rest || !posed) {
        pt_scene_free(rest);
        pt_scene_free(posed);
        return;
    }
    /* The lid rises at t = 1: the posed bounds are taller than the rest's. */
    CHECKF(posed->bounds_max.y > rest->bounds_max.y + 0.1f, "rest top %g, posed top %g",
           (double)rest->bounds_max.y, (double)posed->bounds_max.y);
    CHECK(posed->camera.framed);
    pt_renderer *r = renderer(posed, 64, 48);
    if (r) {
        const pt_camera *c = pt_renderer_camera(r);
        float f = fill(c, posed->bounds_min, posed->bounds_max, 64.0f / 48.0f);
        CHECKF(f > 0.9f && f <= 1.0f, "posed box fills %.3f of the frame (<= 1: lid inside)", f);
        /* The rest pose's view would cut the lid off. */
        float g = fill(&rest->camera, posed->bounds_min, posed->bounds_max, 64.0f / 48.0f);
        CHECKF(g > 1.0f || g < 0.0f, "the rest view already held the lid (%.3f)", g);
        pt_renderer_free(r);
    }
    pt_scene_free(rest);
    pt_scene_free(posed);
}

int main(void)
{
    test_board_fills();
    test_box_animated();
    return check_report();
}
