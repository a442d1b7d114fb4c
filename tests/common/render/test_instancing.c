/*
 * test_instancing.c - EXT_mesh_gpu_instancing kept as instances
 * (PT_FEAT_INSTANCES) through the whole integrator, and what they cost.
 *
 * Equal to copies: a UV sphere with given tangents, a noisy normal map
 * and an anisotropic glossy material, placed 8 times (rotations about
 * several axes, non-uniform scales, one mirror) over a floor, as
 * instances of one prototype and as 8 meshes transformed by the builder.
 * Rendered with the same random numbers (paired.h) under a sun (no sky:
 * its noise would hide a moved instance), no pixel channel differs by a paired t-test: an
 * instance's hit point, normals (vertex by vertex through the inverse transpose) and tangents
 * (through the 3x3, the mirror's handedness flipped) are the copy's up to float rounding, which
 * moves a sample's value by rounding or, rarely, sends one sample down another path (one difference
 * among spp, about one standard error). A scene whose one instance is turned 1 to the side differs:
 * the test sees a misplaced instance.
 *
 * Memory: one mesh of 1,024 triangles under N instances (1e5; PT_TEST_
 * INSTANCES sets another N) costs what the instances' records and
 * Embree's instance geometries and top-level BVH take, not N meshes: the
 * peak resident memory (VmHWM) that building the scene and its
 * accelerator adds is under 1 KB an instance, and under a tenth of what
 * the same N copies would take at the 170 bytes a triangle that
 * OPERATIONS.md measures for flat meshes. The instanced scene then
 * renders (a few samples, none rejected).
 *
 * Generated tangents: the same spheres without TANGENT, so the builder
 * generates them. They are made in the mesh's own space and then taken
 * through the node's matrix, as a given TANGENT is (glTF 3.7.2.1 asks for
 * MikkTSpace over the mesh's vertex positions), for a copy as for the
 * prototype: under the non-uniform scales above, tangents generated from
 * the copies' world-space positions differ from the prototype's, mapped,
 * and the paired test sees it.
 *
 * Alpha through instances: see test_alpha below.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/env.h"
#include "common/render/render.h"
#include "common/scene/accel.h"
#include "common/scene/scene.h"
#include "tests/check.h"

/* The most peak memory an instance may add: about 513 bytes here (Embree's
 * instance and top-level BVH, and our record). AddressSanitizer's allocator
 * pads and quarantines every block, so under it the bound is looser; the
 * bound against copies below holds either way. */
#if defined(__SANITIZE_ADDRESS__)
#define PER_INSTANCE_MAX 4000.0
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define PER_INSTANCE_MAX 4000.0
#endif
#endif
#ifndef PER_INSTANCE_MAX
#define PER_INSTANCE_MAX 1000.0
#endif
#include "tests/common/render/paired.h"

#define PI_D 3.14159265358979323846
#define SEG_U 32
#define SEG_V 16

typedef struct sphere {
    float pos[3 * (SEG_U + 1) * (SEG_V + 1)];
    float nrm[3 * (SEG_U + 1) * (SEG_V + 1)];
    float uv[2 * (SEG_U + 1) * (SEG_V + 1)];
    float tan[4 * (SEG_U + 1) * (SEG_V + 1)];
    uint32_t idx[6 * SEG_U * SEG_V];
    uint32_t nv, nt;
} sphere;

/* A unit UV sphere: u along the longitude (its tangent), v down from the
 * pole; 2 SEG_U SEG_V triangles (some at the poles degenerate). */
static void make_sphere(sphere *s)
{
    uint32_t v = 0;
    for (int j = 0; j <= SEG_V; j++) {
        double th = PI_D * j / SEG_V;
        for (int i = 0; i <= SEG_U; i++, v++) {
            double ph = 2.0 * PI_D * i / SEG_U;
            double p[3] = {sin(th) * cos(ph), sin(th) * sin(ph), cos(th)};
            for (int r = 0; r < 3; r++)
                s->pos[3 * v + r] = s->nrm[3 * v + r] = (float)p[r];
            s->uv[2 * v] = (float)i / SEG_U;
            s->uv[2 * v + 1] = (float)j / SEG_V;
            s->tan[4 * v] = (float)-sin(ph);
            s->tan[4 * v + 1] = (float)cos(ph);
            s->tan[4 * v + 2] = 0.0f;
            s->tan[4 * v + 3] = 1.0f;
        }
    }
    s->nv = v;
    uint32_t t = 0;
    for (uint32_t j = 0; j < SEG_V; j++)
        for (uint32_t i = 0; i < SEG_U; i++) {
            uint32_t a = j * (SEG_U + 1) + i, b = a + 1, c = a + SEG_U + 1, d = c + 1;
            const uint32_t q[6] = {a, c, b, b, c, d};
            memcpy(&s->idx[3 * t], q, sizeof q);
            t += 2;
        }
    s->nt = t;
}

/* Instance k's column-major world matrix: a rotation about a fixed axis
 * of its own, a non-uniform scale (instance 5: the mirror (-1, 1, 1)), a
 * place on a 4 x 2 grid. turn: a shift along x of instance 2. */
static void instance_matrix(int k, double turn, double m[16])
{
    double ax[3] = {sin(1.3 * k + 0.2), cos(0.7 * k + 0.5), 0.6 + 0.1 * k};
    double al = sqrt(ax[0] * ax[0] + ax[1] * ax[1] + ax[2] * ax[2]);
    for (int r = 0; r < 3; r++)
        ax[r] /= al;
    double a = 0.9 * k + 0.3, c = cos(a), s = sin(a), C = 1.0 - c;
    double x = ax[0], y = ax[1], z = ax[2];
    double R[3][3] = {{c + x * x * C, x * y * C - z * s, x * z * C + y * s},
                      {y * x * C + z * s, c + y * y * C, y * z * C - x * s},
                      {z * x * C - y * s, z * y * C + x * s, c + z * z * C}};
    double S[3] = {0.6 + 0.1 * k, 0.9 - 0.05 * k, 0.7 + 0.07 * k};
    if (k == 5) {
        S[0] = -1.0;
        S[1] = S[2] = 1.0;
    }
    memset(m, 0, 16 * sizeof(double));
    for (int col = 0; col < 3; col++)
        for (int r = 0; r < 3; r++)
            m[4 * col + r] = R[r][col] * S[col];
    m[12] = 2.5 * (k % 4) - 3.75 + (k == 2 ? turn : 0.0);
    m[13] = 2.5 * (k / 4) - 1.25;
    m[14] = 0.2 * k;
    m[15] = 1.0;
}

/* The scene: the floor, then 8 spheres as copies or as instances, with
 * the sphere's tangents (gen 0) or none, so that the builder generates
 * them (gen 1). */
static pt_scene *build(const sphere *sp, int instanced, double turn, int gen)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_texture t;
    memset(&t, 0, sizeof t);
    t.width = t.height = 16;
    t.rgba = pt_malloc(16 * 16 * 4);
    uint32_t h = 99;
    for (int i = 0; i < 16 * 16; i++) {
        h = h * 1664525u + 1013904223u;
        t.rgba[4 * i] = (uint8_t)(64 + (h >> 24) % 128);
        t.rgba[4 * i + 1] = (uint8_t)(64 + (h >> 16) % 128);
        t.rgba[4 * i + 2] = 230;
        t.rgba[4 * i + 3] = 255;
    }
    uint32_t ti = 0;
    CHECK(pt_scene_builder_add_texture(b, &t, &ti, &err) == PT_OK);
    pt_material m = pt_material_default();
    m.base_color[0] = 0.7f;
    m.base_color[1] = 0.6f;
    m.base_color[2] = 0.5f;
    m.metallic = 0.3f;
    m.roughness = 0.35f;
    m.normal_tex = (int32_t)ti;
    m.normal_scale = 1.0f;
    m.anisotropy = 0.6f;
    m.anisotropy_rotation = 0.3f;
    snprintf(m.name, sizeof m.name, "bumpy");
    pt_material f = pt_material_default();
    f.metallic = 0.0f;
    f.base_color[0] = f.base_color[1] = f.base_color[2] = 0.5f;
    snprintf(f.name, sizeof f.name, "floor");
    uint32_t mi, fi;
    CHECKF(pt_scene_builder_add_material(b, &m, &mi, &err) == PT_OK, "%s", err.msg);
    CHECKF(pt_scene_builder_add_material(b, &f, &fi, &err) == PT_OK, "%s", err.msg);
    const float fl[12] = {-20, -20, -2, 20, -20, -2, 20, 20, -2, -20, 20, -2};
    const uint32_t fidx[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "floor", fl, NULL, NULL, 4, fidx, 2, NULL, fi, &err) ==
          PT_OK);
    pt_mesh_extra ex = {NULL, gen ? NULL : sp->tan, NULL};
    uint32_t proto = 0;
    if (instanced) {
        CHECK(pt_scene_builder_begin_prototype(b, &proto, &err) == PT_OK);
        CHECKF(pt_scene_builder_add_mesh_extra(b, "sphere", sp->pos, sp->nrm, sp->uv, &ex, sp->nv,
                                               sp->idx, sp->nt, NULL, mi, &err) == PT_OK,
               "%s", err.msg);
        CHECK(pt_scene_builder_end_prototype(b, &err) == PT_OK);
    }
    for (int k = 0; k < 8; k++) {
        double x[16];
        instance_matrix(k, turn, x);
        if (instanced)
            CHECKF(pt_scene_builder_add_instance(b, proto, x, &err) == PT_OK, "%s", err.msg);
        else
            CHECKF(pt_scene_builder_add_mesh_extra(b, "sphere", sp->pos, sp->nrm, sp->uv, &ex,
                                                   sp->nv, sp->idx, sp->nt, x, mi, &err) == PT_OK,
                   "%s", err.msg);
    }
    pt_punctual l;
    memset(&l, 0, sizeof l);
    l.type = PT_PUNCTUAL_DIRECTIONAL;
    l.direction = pt_v3_norm(pt_v3(0.3f, 0.5f, -1.0f));
    l.intensity = pt_v3(2.0f, 2.0f, 2.0f);
    snprintf(l.name, sizeof l.name, "sun");
    const double lp[3] = {0, 0, 0};
    CHECK(pt_scene_builder_add_punctual(b, &l, lp, &err) == PT_OK);
    pt_camera cam = {0};
    cam.position = pt_v3(0.0f, -9.0f, 9.0f);
    cam.forward = pt_v3_norm(pt_v3(0.0f, 9.0f, -9.0f));
    cam.right = pt_v3(1, 0, 0);
    cam.up = pt_v3_cross(cam.right, cam.forward);
    cam.yfov = 0.9f;
    snprintf(cam.name, sizeof cam.name, "view");
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

static void test_equal_to_copies(int gen)
{
    static sphere sp;
    make_sphere(&sp);
    pt_scene *inst = build(&sp, 1, 0.0, gen), *copies = build(&sp, 0, 0.0, gen),
             *turned = build(&sp, 1, 1.0, gen);
    if (inst && copies && turned) {
        CHECK(inst->num_instances == 8 && (inst->features & PT_FEAT_INSTANCES) &&
              !(copies->features & PT_FEAT_INSTANCES));
        CHECK(inst->num_triangles == 2 + sp.nt && copies->num_triangles == 2 + 8 * sp.nt);
        /* The same bounds, bit for bit (so is a framed camera). */
        CHECKF(memcmp(&inst->bounds_min, &copies->bounds_min, sizeof(pt_vec3)) == 0 &&
                   memcmp(&inst->bounds_max, &copies->bounds_max, sizeof(pt_vec3)) == 0,
               "x from %.7g (copies %.7g), z to %.7g (copies %.7g)", (double)inst->bounds_min.x,
               (double)copies->bounds_min.x, (double)inst->bounds_max.z,
               (double)copies->bounds_max.z);
        int d = paired_differing(inst, copies, NULL, 48, 32);
        CHECKF(d == 0, "%s tangents: %d pixel channels differ between instances and copies",
               gen ? "generated" : "given", d);
        int t = paired_differing(inst, turned, NULL, 48, 32);
        CHECKF(t > 20, "only %d pixel channels differ with one instance moved", t);
        if (getenv("PT_TEST_VERBOSE"))
            printf("%s tangents, instances vs copies: %d channels differ; one moved: %d\n",
                   gen ? "generated" : "given", d, t);
    }
    pt_scene_free(inst);
    pt_scene_free(copies);
    pt_scene_free(turned);
}

/* VmHWM of this process, in bytes (0 when /proc cannot say). */
static uint64_t peak_rss(void)
{
    FILE *f = fopen("/proc/self/status", "r");
    if (!f)
        return 0;
    char line[256];
    unsigned long long kb = 0;
    while (fgets(line, sizeof line, f))
        if (sscanf(line, "VmHWM: %llu kB", &kb) == 1)
            break;
    fclose(f);
    return (uint64_t)kb * 1024u;
}

static void test_memory(void)
{
    const char *e = getenv("PT_TEST_INSTANCES");
    uint32_t n = e ? (uint32_t)strtoul(e, NULL, 10) : 100000u;
    if (n == 0)
        n = 100000u;
    static sphere sp;
    make_sphere(&sp);
    uint64_t before = peak_rss();
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    uint32_t mi, proto;
    CHECK(pt_scene_builder_add_material(b, &m, &mi, &err) == PT_OK);
    CHECK(pt_scene_builder_begin_prototype(b, &proto, &err) == PT_OK);
    CHECK(pt_scene_builder_add_mesh(b, "sphere", sp.pos, sp.nrm, sp.uv, sp.nv, sp.idx, sp.nt, NULL,
                                    mi, &err) == PT_OK);
    CHECK(pt_scene_builder_end_prototype(b, &err) == PT_OK);
    uint32_t side = (uint32_t)ceil(sqrt((double)n));
    for (uint32_t i = 0; i < n; i++) {
        double x[16] = {0.4, 0, 0, 0, 0, 0.4, 0, 0, 0, 0, 0.4, 0, 0, 0, 0, 1};
        x[12] = (double)(i % side);
        x[13] = (double)(i / side);
        if (pt_scene_builder_add_instance(b, proto, x, &err) != PT_OK) {
            CHECKF(0, "instance %u: %s", i, err.msg);
            break;
        }
    }
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    pt_accel *a = NULL;
    if (s)
        CHECKF(pt_accel_new(s, &a, &err) == PT_OK, "%s", err.msg);
    uint64_t after = peak_rss();
    if (s && a && before && after) {
        double per = (double)(after - before) / n;
        double copies = 170.0 * sp.nt * (double)n;
        if (getenv("PT_TEST_VERBOSE"))
            printf("%u instances of %u triangles: peak RSS +%.1f MB (%.0f bytes an instance); "
                   "copies would take about %.0f MB\n",
                   n, sp.nt, (after - before) / 1e6, per, copies / 1e6);
        CHECKF(per < PER_INSTANCE_MAX, "%.0f bytes an instance", per);
        CHECKF((double)(after - before) < copies / 10.0, "%.1f MB for %u instances",
               (after - before) / 1e6, n);
        /* It renders: a few samples through the instances, none rejected. */
        pt_render_params p;
        pt_render_params_default(&p);
        p.width = p.height = 16;
        pt_renderer *r = NULL;
        CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
        if (r) {
            pt_pixel_acc acc[16 * 16];
            memset(acc, 0, sizeof acc);
            pt_render_stats st = {0};
            pt_render_tile(r, (pt_rect){0, 0, 16, 16}, 0, 2, acc, &st);
            CHECK(st.rejected == 0 && st.samples == 16 * 16 * 2);
        }
        pt_renderer_free(r);
    }
    pt_accel_free(a);
    pt_scene_free(s);
}

/* Alpha (PT_FEAT_ALPHA) through instances: the filter finds the
 * prototype's triangle from its geometry's first triangle. A floor (flat,
 * opaque) comes first, so a filter that took the prototype's primID as a
 * scene triangle would read the floor's opaque material. A quad with a
 * 2 x 2 checker alpha (MASK, nearest) under 6 instances and as 6 copies:
 * 4,096 rays down hit and miss the same, at the same distance. */
static pt_scene *alpha_scene(int instanced)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_texture t;
    memset(&t, 0, sizeof t);
    t.width = t.height = 2;
    t.nearest = 1;
    t.rgba = pt_malloc(16);
    const uint8_t px[16] = {255, 255, 255, 255, 255, 255, 255, 0,
                            255, 255, 255, 0,   255, 255, 255, 255};
    memcpy(t.rgba, px, 16);
    uint32_t ti = 0, mi = 0, fi = 0;
    CHECK(pt_scene_builder_add_texture(b, &t, &ti, &err) == PT_OK);
    pt_material m = pt_material_default();
    m.base_color_tex = (int32_t)ti;
    m.alpha_mode = PT_ALPHA_MASK;
    m.alpha_cutoff = 0.5f;
    m.double_sided = 1;
    pt_material f = pt_material_default();
    CHECK(pt_scene_builder_add_material(b, &m, &mi, &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &f, &fi, &err) == PT_OK);
    const float fl[12] = {-20, -20, -5, 20, -20, -5, 20, 20, -5, -20, 20, -5};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "floor", fl, NULL, NULL, 4, idx, 2, NULL, fi, &err) ==
          PT_OK);
    const float q[12] = {-1, -1, 0, 1, -1, 0, 1, 1, 0, -1, 1, 0};
    const float uv[8] = {0, 1, 1, 1, 1, 0, 0, 0};
    uint32_t proto = 0;
    if (instanced) {
        CHECK(pt_scene_builder_begin_prototype(b, &proto, &err) == PT_OK);
        CHECK(pt_scene_builder_add_mesh(b, "quad", q, NULL, uv, 4, idx, 2, NULL, mi, &err) ==
              PT_OK);
        CHECK(pt_scene_builder_end_prototype(b, &err) == PT_OK);
    }
    for (int k = 0; k < 6; k++) {
        double x[16] = {0};
        double a = 0.4 * k, c = cos(a), s = sin(a);
        x[0] = 1.5 * c;
        x[1] = 1.5 * s;
        x[4] = -s;
        x[5] = c;
        x[10] = 1.0;
        x[12] = 4.0 * (k % 3) - 4.0;
        x[13] = 4.0 * (k / 3) - 2.0;
        x[14] = 0.3 * k;
        x[15] = 1.0;
        if (instanced)
            CHECK(pt_scene_builder_add_instance(b, proto, x, &err) == PT_OK);
        else
            CHECK(pt_scene_builder_add_mesh_dxform(b, "quad", q, NULL, uv, 4, idx, 2, x, mi,
                                                   &err) == PT_OK);
    }
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

static void test_alpha(void)
{
    pt_scene *si = alpha_scene(1), *sc = alpha_scene(0);
    pt_accel *ai = NULL, *ac = NULL;
    pt_error err = {0};
    if (si && sc) {
        CHECK((si->features & PT_FEAT_ALPHA) && si->num_instances == 6);
        CHECK(pt_accel_new(si, &ai, &err) == PT_OK && pt_accel_new(sc, &ac, &err) == PT_OK);
    }
    int differ = 0, quads = 0, floor = 0;
    for (int k = 0; ai && ac && k < 4096; k++) {
        pt_vec3 o = pt_v3((float)(k % 64) / 64.0f * 14.0f - 7.0f,
                          (float)(k / 64) / 64.0f * 10.0f - 5.0f, 10.0f);
        pt_hit a, c;
        int ha = pt_accel_intersect_alpha(ai, o, pt_v3(0, 0, -1), INFINITY, 1, &a);
        int hc = pt_accel_intersect_alpha(ac, o, pt_v3(0, 0, -1), INFINITY, 1, &c);
        if (ha != hc || (ha && fabsf(a.t - c.t) > 1e-4f))
            differ++;
        quads += ha && a.inst != 0;
        floor += ha && a.inst == 0;
    }
    CHECKF(differ <= 4, "%d of 4096 rays differ", differ);
    CHECKF(quads > 500 && floor > 500, "%d through quads, %d on the floor", quads, floor);
    pt_accel_free(ai);
    pt_accel_free(ac);
    pt_scene_free(si);
    pt_scene_free(sc);
}

int main(void)
{
    test_memory(); /* first: the peak it measures is then its own */
    test_alpha();
    test_equal_to_copies(0);
    test_equal_to_copies(1);
    return check_report();
}
