/*
 * test_motion.c - motion blur (common/scene/motion.h) through the whole
 * integrator, against the analytic box-filtered coverage.
 *
 * The scene: an emissive square (radiance E, black base colour, so no light
 * is reflected) of side S moving along +x in front of an orthographic camera
 * looking down -z, on nothing (no environment: black). A camera ray sees E
 * where it meets the square at its time, else 0, so a pixel's value is E
 * times the share of (x in the pixel, time in the shutter) where the square
 * covers x: for a square at x0(t) .. x0(t) + S,
 *     L(pixel) = E / dx * integral_0^1 |[x_a, x_b] n [x0(t), x0(t) + S]| dt,
 * which for constant speed is the trapezoid (the box of the square's extent
 * convolved with the box of its travel) averaged over the pixel. The test
 * integrates it over t in double (midpoint rule, 2e5 steps: the integrand is
 * piecewise linear in t, so the error is far below the noise) and compares
 * each pixel of a row inside the square with k = 5 standard errors, the
 * standard error estimated from the pixel's own samples (each is 0 or E: a
 * Bernoulli, whose sample variance over-estimates the error of the
 * stratified estimate). A pixel the square covers always or never has no
 * variance and must match exactly.
 *
 * Also: more than two time steps (a square that moves, then stops), a moving
 * camera in front of a still square (the same trapezoid), steps that do not
 * differ (no PT_FEAT_MOTION, the still image's bits), bit-identical renders
 * however the samples and tiles are split, and the builder's refusals.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/render.h"
#include "common/scene/motion.h"
#include "common/scene/scene.h"
#include "tests/check.h"

#define W 64u
#define H 16u
#define SPP 256u
#define S 1.0f    /* the square's side */
#define E 1.0f    /* its radiance */
#define YMAG 1.0f /* the view is 2 high, 8 wide: a pixel is 0.125 */
#define ROW 7u    /* a row inside the square (y in [-0.5, 0.5]) */

/* The square's left edge at step k of K, and where the test says it is at
 * time t (piecewise linear through the steps). */
typedef struct path_def {
    uint32_t steps;
    float x[8];
} path_def;

static double left_at(const path_def *p, double t)
{
    double x = t * (p->steps - 1);
    uint32_t i = (uint32_t)x;
    if (i > p->steps - 2)
        i = p->steps - 2;
    double f = x - i;
    return (1.0 - f) * p->x[i] + f * p->x[i + 1];
}

/* The world x range of pixel column px. */
static void pixel_x(uint32_t px, double *a, double *b)
{
    double width = 2.0 * YMAG * (double)W / (double)H;
    *a = -0.5 * width + width * px / W;
    *b = -0.5 * width + width * (px + 1) / W;
}

static double expected(const path_def *p, uint32_t px)
{
    double a, b;
    pixel_x(px, &a, &b);
    const int n = 200000;
    double sum = 0.0;
    for (int i = 0; i < n; i++) {
        double x0 = left_at(p, (i + 0.5) / n);
        double lo = fmax(a, x0), hi = fmin(b, x0 + S);
        if (hi > lo)
            sum += hi - lo;
    }
    return E * sum / n / (b - a);
}

static void add_camera(pt_scene_builder *b)
{
    pt_error err = {0};
    pt_camera c;
    memset(&c, 0, sizeof c);
    c.ortho = 1;
    c.xmag = YMAG * (float)W / (float)H;
    c.ymag = YMAG;
    c.position = pt_v3(0, 0, 5);
    c.right = pt_v3(1, 0, 0);
    c.up = pt_v3(0, 1, 0);
    c.forward = pt_v3(0, 0, -1);
    snprintf(c.name, sizeof c.name, "ortho");
    CHECKF(pt_scene_builder_add_camera(b, &c, &err) == PT_OK, "%s", err.msg);
}

/* The square at the left edges of p (moving: 1 through the motion API, 0
 * as an ordinary mesh at p->x[0]). */
static pt_scene *square_scene(const path_def *p, int moving)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    m.base_color[0] = m.base_color[1] = m.base_color[2] = 0.0f;
    m.metallic = 0.0f;
    m.specular = 0.0f;
    m.double_sided = 1;
    m.emissive[0] = m.emissive[1] = m.emissive[2] = E;
    uint32_t mat;
    CHECK(pt_scene_builder_add_material(b, &m, &mat, &err) == PT_OK);
    float pos[8][12];
    const float *pp[8];
    for (uint32_t k = 0; k < p->steps; k++) {
        float x0 = p->x[k], x1 = x0 + S, y0 = -0.5f * S, y1 = 0.5f * S;
        float q[12] = {x0, y0, 0, x1, y0, 0, x1, y1, 0, x0, y1, 0};
        memcpy(pos[k], q, sizeof q);
        pp[k] = pos[k];
    }
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    if (moving)
        CHECKF(pt_scene_builder_add_mesh_motion(b, "square", p->steps, pp, NULL, NULL, 4, idx, 2,
                                                mat, &err) == PT_OK,
               "%s", err.msg);
    else
        CHECKF(pt_scene_builder_add_mesh(b, "square", pos[0], NULL, NULL, 4, idx, 2, NULL, mat,
                                         &err) == PT_OK,
               "%s", err.msg);
    add_camera(b);
    pt_scene *s = NULL;
    pt_scene_opts o;
    memset(&o, 0, sizeof o);
    o.camera_name = "ortho";
    CHECKF(pt_scene_builder_finish(b, &o, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

static pt_renderer *renderer(const pt_scene *s)
{
    pt_render_params rp;
    pt_render_params_default(&rp);
    rp.width = W;
    rp.height = H;
    rp.seed = 7;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &rp, &r, &err) == PT_OK, "%s", err.msg);
    return r;
}

/* Renders the whole image, SPP samples, in one tile and one call. */
static pt_pixel_acc *render_all(const pt_renderer *r)
{
    pt_pixel_acc *acc = pt_calloc(W * H, sizeof *acc);
    CHECK(acc != NULL);
    pt_rect t = {0, 0, W, H};
    pt_render_tile(r, t, 0, SPP, acc, NULL);
    return acc;
}

/* Row ROW against p's analytic profile; returns how many pixels are
 * partly covered (the ones with noise). */
static int check_row(const pt_pixel_acc *acc, const path_def *p, const char *what)
{
    int partial = 0;
    for (uint32_t px = 0; px < W; px++) {
        const pt_pixel_acc *a = &acc[ROW * W + px];
        double n = (double)a->n;
        double mean = pt_acc_sum(a, 0) / n;
        double var = pt_acc_sum_sq(a) / n - mean * mean; /* luminance = red here */
        double se = sqrt(fmax(var, 0.0) / n);
        double want = expected(p, px);
        if (want > 1e-9 && want < E - 1e-9)
            partial++;
        double tol = 5.0 * se + 1e-6;
        CHECKF(fabs(mean - want) <= tol, "%s: pixel %u: %.5f, want %.5f (+- %.5f)", what, px, mean,
               want, tol);
    }
    return partial;
}

/* Constant speed over two steps: the trapezoid. */
static void test_linear(void)
{
    path_def p = {2, {-2.0f, 0.5f}};
    pt_scene *s = square_scene(&p, 1);
    CHECK(s->features & PT_FEAT_MOTION);
    CHECK(s->motion && s->motion->steps == 2 && s->motion->num_triangles == 2);
    /* The bounds hold every step. */
    CHECK(s->bounds_min.x == -2.0f && s->bounds_max.x == 1.5f);
    pt_renderer *r = renderer(s);
    CHECK(strcmp(pt_renderer_variant(r), "general") == 0);
    pt_pixel_acc *acc = render_all(r);
    /* The square (1) is shorter than its travel (2.5): the profile rises over
     * 1, stays at 1 / 2.5 and falls over 1, 3.5 in all, 28 columns. */
    int partial = check_row(acc, &p, "linear");
    CHECKF(partial == 28, "%d partly covered pixels", partial);
    pt_free(acc);
    pt_renderer_free(r);
    pt_scene_free(s);
}

/* Three steps: across, then standing still for the second half. */
static void test_steps(void)
{
    path_def p = {3, {-3.0f, -0.5f, -0.5f}};
    pt_scene *s = square_scene(&p, 1);
    CHECK(s->motion && s->motion->steps == 3);
    pt_renderer *r = renderer(s);
    pt_pixel_acc *acc = render_all(r);
    check_row(acc, &p, "steps");
    pt_free(acc);
    pt_renderer_free(r);
    pt_scene_free(s);
}

/* A camera moving along -x past a still square sees it move along +x. */
static void test_camera(void)
{
    path_def still = {2, {-0.5f, -0.5f}};
    pt_scene *s = square_scene(&still, 0);
    CHECK(!(s->features & PT_FEAT_MOTION));
    pt_camera poses[2] = {s->camera, s->camera};
    poses[0].position.x = 1.0f;
    poses[1].position.x = -1.0f;
    pt_error err = {0};
    CHECKF(pt_scene_set_camera_motion(s, 2, poses, &err) == PT_OK, "%s", err.msg);
    CHECK(s->features & PT_FEAT_MOTION);
    pt_renderer *r = renderer(s);
    pt_pixel_acc *acc = render_all(r);
    path_def seen = {2, {-1.5f, 0.5f}}; /* the square relative to the camera */
    check_row(acc, &seen, "camera");
    pt_free(acc);
    pt_renderer_free(r);
    /* Poses that do not differ move nothing. */
    pt_scene *s2 = square_scene(&still, 0);
    pt_camera same[2] = {s2->camera, s2->camera};
    CHECK(pt_scene_set_camera_motion(s2, 2, same, &err) == PT_OK);
    CHECK(!(s2->features & PT_FEAT_MOTION) && !s2->motion);
    /* Refusals. */
    CHECK(pt_scene_set_camera_motion(s2, 1, same, &err) == PT_ERR_ARG);
    same[1].forward = pt_v3(0, 0, -2);
    CHECK(pt_scene_set_camera_motion(s2, 2, same, &err) == PT_ERR_ARG);
    pt_scene_free(s2);
    pt_scene_free(s);
}

/* Steps that are all equal: no motion, and the still mesh's image bit for
 * bit (and its hash). */
static void test_still(void)
{
    path_def p = {2, {-0.5f, -0.5f}};
    pt_scene *a = square_scene(&p, 0), *b = square_scene(&p, 1);
    CHECK(!(b->features & PT_FEAT_MOTION) && b->motion == NULL);
    CHECK(a->features == b->features);
    CHECK(strcmp(a->hash, b->hash) == 0);
    pt_renderer *ra = renderer(a), *rb = renderer(b);
    CHECK(strcmp(pt_renderer_variant(ra), pt_renderer_variant(rb)) == 0);
    pt_pixel_acc *x = render_all(ra), *y = render_all(rb);
    CHECK(memcmp(x, y, W * H * sizeof *x) == 0);
    pt_free(x);
    pt_free(y);
    pt_renderer_free(ra);
    pt_renderer_free(rb);
    /* A moving scene is told apart from its still by the hash. */
    path_def m = {2, {-0.5f, 0.0f}};
    pt_scene *c = square_scene(&m, 1);
    CHECK(strcmp(a->hash, c->hash) != 0);
    pt_scene_free(c);
    pt_scene_free(a);
    pt_scene_free(b);
}

/* The same bits however the work is split: one call, 16-sample chunks
 * added in order, 8x8 tiles; and one path at a time (pt_render_sample). */
static void test_split(void)
{
    path_def p = {2, {-2.0f, 0.5f}};
    pt_scene *s = square_scene(&p, 1);
    pt_renderer *r = renderer(s);
    const uint32_t spp = 64;
    pt_pixel_acc *whole = pt_calloc(W * H, sizeof *whole);
    pt_pixel_acc *split = pt_calloc(W * H, sizeof *split);
    pt_pixel_acc tile[8 * 8];
    CHECK(whole && split);
    pt_rect all = {0, 0, W, H};
    pt_render_tile(r, all, 0, spp, whole, NULL);
    for (uint32_t ty = 0; ty < H; ty += 8)
        for (uint32_t tx = 0; tx < W; tx += 8) {
            pt_rect t = {tx, ty, tx + 8, ty + 8};
            for (uint32_t s0 = 0; s0 < spp; s0 += 16) {
                pt_render_tile(r, t, s0, s0 + 16, tile, NULL);
                for (uint32_t i = 0; i < 64; i++)
                    pt_pixel_acc_add(&split[(ty + i / 8) * W + tx + i % 8], &tile[i]);
            }
        }
    CHECK(memcmp(whole, split, W * H * sizeof *whole) == 0);
    /* Batched paths equal paths traced alone. */
    for (uint32_t px = 20; px < 44; px++) {
        pt_block_acc one = {{0, 0, 0}, 0, 0, 0};
        pt_rect t = {px, ROW, px + 1, ROW + 1};
        pt_pixel_acc got, want = {{0, 0, 0}, 0, 0, 0};
        pt_render_tile(r, t, 0, 16, &got, NULL);
        for (uint32_t i = 0; i < 16; i++)
            pt_block_acc_sample(&one, pt_render_sample(r, px, ROW, i, NULL, NULL));
        pt_pixel_acc_add_block(&want, &one);
        CHECK(memcmp(want.fsum, got.fsum, sizeof want.fsum) == 0);
    }
    pt_free(whole);
    pt_free(split);
    pt_renderer_free(r);
    pt_scene_free(s);
}

/* A moving occluder in front of a still emitter: shadow and camera rays
 * at the path's time. The emitter is seen through where the occluder is
 * not: 1 - the occluder's coverage. */
static void test_occluder(void)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    m.base_color[0] = m.base_color[1] = m.base_color[2] = 0.0f;
    m.metallic = 0.0f;
    m.specular = 0.0f;
    m.double_sided = 1;
    uint32_t black, light;
    CHECK(pt_scene_builder_add_material(b, &m, &black, &err) == PT_OK);
    m.emissive[0] = m.emissive[1] = m.emissive[2] = E;
    CHECK(pt_scene_builder_add_material(b, &m, &light, &err) == PT_OK);
    const float wall[12] = {-10, -10, -1, 10, -10, -1, 10, 10, -1, -10, 10, -1};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "wall", wall, NULL, NULL, 4, idx, 2, NULL, light, &err) ==
          PT_OK);
    path_def p = {2, {-2.0f, 0.5f}};
    float pos[2][12];
    const float *pp[2] = {pos[0], pos[1]};
    for (uint32_t k = 0; k < 2; k++) {
        float x0 = p.x[k], x1 = x0 + S, y0 = -0.5f * S, y1 = 0.5f * S;
        float q[12] = {x0, y0, 0, x1, y0, 0, x1, y1, 0, x0, y1, 0};
        memcpy(pos[k], q, sizeof q);
    }
    CHECK(pt_scene_builder_add_mesh_motion(b, "occluder", 2, pp, NULL, NULL, 4, idx, 2, black,
                                           &err) == PT_OK);
    add_camera(b);
    pt_scene_opts o;
    memset(&o, 0, sizeof o);
    o.camera_name = "ortho";
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, &o, &s, &err) == PT_OK, "%s", err.msg);
    CHECK(s->motion->num_static == 2 && s->motion->static_tri[0] == 0);
    pt_renderer *r = renderer(s);
    pt_pixel_acc *acc = render_all(r);
    for (uint32_t px = 0; px < W; px++) {
        const pt_pixel_acc *a = &acc[ROW * W + px];
        double n = (double)a->n, mean = pt_acc_sum(a, 0) / n;
        double se = sqrt(fmax(pt_acc_sum_sq(a) / n - mean * mean, 0.0) / n);
        double want = E - expected(&p, px);
        CHECKF(fabs(mean - want) <= 5.0 * se + 1e-6, "occluder: pixel %u: %.5f, want %.5f", px,
               mean, want);
    }
    pt_free(acc);
    pt_renderer_free(r);
    pt_scene_free(s);
}

/* Motion from whole-scene poses (as a re-posing of an animated file gives
 * them): the square's four vertices move, the wall's stay; the same
 * trapezoid, and only the square's triangles get steps. */
static void test_set_motion(void)
{
    path_def p = {2, {-2.0f, 0.5f}};
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    m.base_color[0] = m.base_color[1] = m.base_color[2] = 0.0f;
    m.metallic = 0.0f;
    m.specular = 0.0f;
    m.double_sided = 1;
    uint32_t black, light;
    CHECK(pt_scene_builder_add_material(b, &m, &black, &err) == PT_OK);
    m.emissive[0] = m.emissive[1] = m.emissive[2] = E;
    CHECK(pt_scene_builder_add_material(b, &m, &light, &err) == PT_OK);
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    const float wall[12] = {-10, -10, -1, 10, -10, -1, 10, 10, -1, -10, 10, -1};
    CHECK(pt_scene_builder_add_mesh(b, "wall", wall, NULL, NULL, 4, idx, 2, NULL, black, &err) ==
          PT_OK);
    float sq[12] = {p.x[0], -0.5f, 0, p.x[0] + S, -0.5f, 0, p.x[0] + S, 0.5f, 0, p.x[0], 0.5f, 0};
    CHECK(pt_scene_builder_add_mesh(b, "square", sq, NULL, NULL, 4, idx, 2, NULL, light, &err) ==
          PT_OK);
    add_camera(b);
    pt_scene_opts o;
    memset(&o, 0, sizeof o);
    o.camera_name = "ortho";
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, &o, &s, &err) == PT_OK, "%s", err.msg);
    size_t n = 3 * (size_t)s->num_vertices;
    float *pos1 = pt_malloc_array(n, sizeof(float));
    CHECK(pos1 != NULL);
    memcpy(pos1, s->positions, n * sizeof(float));
    for (uint32_t v = 4; v < 8; v++)
        pos1[3 * v] += p.x[1] - p.x[0];
    const float *pp[2] = {s->positions, s->positions}, *nn[2] = {s->normals, s->normals};
    /* Equal poses: nothing moves. */
    CHECK(pt_scene_set_motion(s, 2, pp, nn, &err) == PT_OK && !s->motion &&
          !(s->features & PT_FEAT_MOTION));
    CHECK(pt_scene_set_motion(s, 1, pp, nn, &err) == PT_ERR_ARG);
    pp[1] = pos1;
    CHECKF(pt_scene_set_motion(s, 2, pp, nn, &err) == PT_OK, "%s", err.msg);
    CHECK(s->motion && s->motion->num_triangles == 2 && s->motion->num_vertices == 4 &&
          s->motion->num_static == 2 && s->motion->tri[0] == 2 &&
          s->motion->moving[0] == UINT32_MAX);
    CHECK((s->features & PT_FEAT_MOTION) && s->bounds_max.z >= 0.0f);
    /* A second call replaces the steps (nothing leaks: the ASan build). */
    CHECKF(pt_scene_set_motion(s, 2, pp, nn, &err) == PT_OK, "%s", err.msg);
    CHECK(s->motion->num_triangles == 2 && s->motion->steps == 2);
    pt_renderer *r = renderer(s);
    pt_pixel_acc *acc = render_all(r);
    check_row(acc, &p, "set_motion");
    pt_free(acc);
    pt_renderer_free(r);
    pt_free(pos1);
    pt_scene_free(s);
}

static void test_refusals(void)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    uint32_t mat;
    CHECK(pt_scene_builder_add_material(b, &m, &mat, &err) == PT_OK);
    float a[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0}, c[9] = {0, 0, 1, 1, 0, 1, 0, 1, 1};
    float bad[9] = {0, 0, 0, 1, 0, 0, 0, NAN, 0};
    const float *two[2] = {a, c}, *three[3] = {a, c, a}, *nan[2] = {a, bad};
    CHECK(pt_scene_builder_add_mesh_motion(b, "one", 1, two, NULL, NULL, 3, NULL, 1, mat, &err) ==
          PT_ERR_ARG);
    CHECK(pt_scene_builder_add_mesh_motion(b, "many", PT_MOTION_MAX_STEPS + 1, two, NULL, NULL, 3,
                                           NULL, 1, mat, &err) == PT_ERR_ARG);
    CHECK(pt_scene_builder_add_mesh_motion(b, "nan", 2, nan, NULL, NULL, 3, NULL, 1, mat, &err) ==
          PT_ERR_FORMAT);
    CHECK(strstr(err.msg, "nan") != NULL);
    CHECK(pt_scene_builder_add_mesh_motion(b, "ok", 2, two, NULL, NULL, 3, NULL, 1, mat, &err) ==
          PT_OK);
    CHECK(pt_scene_builder_add_mesh_motion(b, "three", 3, three, NULL, NULL, 3, NULL, 1, mat,
                                           &err) == PT_ERR_ARG);
    CHECK(strstr(err.msg, "time steps") != NULL);
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    /* The refused meshes left nothing behind. */
    CHECK(s->num_triangles == 1 && s->num_vertices == 3);
    CHECK(s->motion && s->motion->num_triangles == 1 && s->motion->num_static == 0);
    pt_scene_free(s);
}

int main(void)
{
    test_linear();
    test_steps();
    test_camera();
    test_still();
    test_split();
    test_occluder();
    test_set_motion();
    test_refusals();
    return check_report();
}
