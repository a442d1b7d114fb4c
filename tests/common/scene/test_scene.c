/*
 * test_scene.c - the scene builder (transforms, normals, winding, checks,
 * feature mask, hash), texture lookup (wrap modes, sRGB, bilinear) and the
 * camera choice and framing; rebasing of scenes far from the origin (stored
 * positions equal the local ones, origin the translation).
 */
#include "common/scene/scene.h"

#include <math.h>
#include <string.h>

#include "common/base/alloc.h"
#include "tests/check.h"

static const float k_tri[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
static const uint32_t k_idx[3] = {0, 1, 2};

static int near(float a, float b, float tol)
{
    return fabsf(a - b) <= tol;
}

static pt_scene_builder *builder_with(const pt_material *m)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    uint32_t mi = 99;
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material d = pt_material_default();
    CHECK(pt_scene_builder_add_material(b, m ? m : &d, &mi, &err) == PT_OK && mi == 0);
    return b;
}

static pt_scene *finish(pt_scene_builder *b, const pt_scene_opts *o)
{
    pt_scene *s = NULL;
    pt_error err = {0};
    CHECKF(pt_scene_builder_finish(b, o, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

static void test_defaults(void)
{
    pt_material m = pt_material_default();
    CHECK(m.base_color[0] == 1 && m.base_color[3] == 1 && m.metallic == 1 && m.roughness == 1);
    CHECK(m.base_color_tex == -1 && m.metal_rough_tex == -1 && m.emissive_tex == -1);
    CHECK(m.emissive[0] == 0 && m.specular == 1 && m.specular_color[2] == 1 && !m.double_sided);
}

static void test_transform(void)
{
    pt_error err = {0};
    /* Translate by (1,2,3) and scale x by 2: column-major. */
    float xf[16] = {2, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 1, 2, 3, 1};
    float nrm[9] = {0, 0, 1, 0, 0, 1, 1, 0, 1}; /* the third is tilted towards +x */
    pt_scene_builder *b = builder_with(NULL);
    CHECK(pt_scene_builder_add_mesh(b, "t", k_tri, nrm, NULL, 3, k_idx, 1, xf, 0, &err) == PT_OK);
    pt_scene *s = finish(b, NULL);
    if (!s)
        return;
    CHECK(s->positions[3] == 3 && s->positions[4] == 2 && s->positions[5] == 3);
    CHECK(near(s->normals[2], 1, 1e-6f));
    /* Inverse transpose: (1,0,1) under x-scale 2 becomes (0.5,0,1), normalised. */
    float l = sqrtf(0.25f + 1.0f);
    CHECK(near(s->normals[6], 0.5f / l, 1e-6f) && near(s->normals[8], 1.0f / l, 1e-6f));
    CHECK(s->bounds_min.x == 1 && s->bounds_max.x == 3 && s->bounds_max.y == 3);
    CHECK(s->uvs == NULL && !(s->features & PT_FEAT_UVS));
    CHECK(strlen(s->hash) == 64);
    pt_scene_free(s);
}

static void test_computed_normals(void)
{
    pt_error err = {0};
    /* Two faces sharing vertex 0: a big one in z=0 (normal +z) and a small one
     * in x=0 (normal +x). Area weighting tilts the shared normal towards +z. */
    float p[12] = {0, 0, 0, 4, 0, 0, 0, 4, 0, 0, 0, 1};
    uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    pt_scene_builder *b = builder_with(NULL);
    CHECK(pt_scene_builder_add_mesh(b, "n", p, NULL, NULL, 4, idx, 2, NULL, 0, &err) == PT_OK);
    /* A degenerate triangle: kept, with a finite unit normal. */
    float d[9] = {5, 5, 5, 5, 5, 5, 5, 5, 5};
    CHECK(pt_scene_builder_add_mesh(b, "d", d, NULL, NULL, 3, NULL, 1, NULL, 0, &err) == PT_OK);
    pt_scene *s = finish(b, NULL);
    if (!s)
        return;
    CHECK(s->num_triangles == 3 && s->num_vertices == 7);
    const float *n0 = s->normals;
    /* face areas 8 (+z) and 2 (+x): (2, 0, 8) normalised */
    float l = sqrtf(4 + 64);
    CHECKF(near(n0[0], 2 / l, 1e-5f) && near(n0[2], 8 / l, 1e-5f), "%g %g %g", (double)n0[0],
           (double)n0[1], (double)n0[2]);
    CHECK(near(s->normals[5], 1, 1e-6f)); /* vertex 1: only the +z face */
    CHECK(near(s->normals[9], 1, 1e-6f)); /* vertex 3: only the +x face */
    for (int v = 4; v < 7; v++) {
        const float *n = s->normals + 3 * v;
        CHECK(isfinite(n[0]) && near(n[0] * n[0] + n[1] * n[1] + n[2] * n[2], 1, 1e-5f));
    }
    pt_scene_free(s);
}

static void test_negative_determinant(void)
{
    pt_error err = {0};
    /* Mirror in x: the triangle's geometric normal (from the winding) must still
     * agree with the transformed shading normal. */
    float xf[16] = {-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    float nrm[9] = {0, 0, 1, 0, 0, 1, 0, 0, 1};
    pt_scene_builder *b = builder_with(NULL);
    CHECK(pt_scene_builder_add_mesh(b, "m", k_tri, nrm, NULL, 3, k_idx, 1, xf, 0, &err) == PT_OK);
    CHECK(pt_scene_builder_add_mesh(b, "c", k_tri, NULL, NULL, 3, k_idx, 1, xf, 0, &err) == PT_OK);
    pt_scene *s = finish(b, NULL);
    if (!s)
        return;
    for (uint32_t t = 0; t < 2; t++) {
        const uint32_t *I = s->indices + 3 * t;
        pt_vec3 p[3];
        for (int k = 0; k < 3; k++)
            p[k] = pt_v3(s->positions[3 * I[k]], s->positions[3 * I[k] + 1],
                         s->positions[3 * I[k] + 2]);
        pt_vec3 g = pt_v3_cross(pt_v3_sub(p[1], p[0]), pt_v3_sub(p[2], p[0]));
        pt_vec3 n = pt_v3(s->normals[3 * I[0]], s->normals[3 * I[0] + 1], s->normals[3 * I[0] + 2]);
        CHECKF(pt_v3_dot(g, n) > 0, "triangle %u: geometric and shading normals disagree", t);
        CHECK(near(n.z, 1, 1e-6f));
    }
    pt_scene_free(s);
}

static void test_rejects(void)
{
    pt_error err = {0};
    pt_scene_builder *b = builder_with(NULL);
    uint32_t bad[3] = {0, 1, 3};
    CHECK(pt_scene_builder_add_mesh(b, "wheel", k_tri, NULL, NULL, 3, bad, 1, NULL, 0, &err) ==
          PT_ERR_FORMAT);
    CHECKF(strstr(err.msg, "wheel") && strstr(err.msg, "index 3"), "%s", err.msg);
    float nan_p[9] = {0, 0, 0, NAN, 0, 0, 0, 1, 0};
    CHECK(pt_scene_builder_add_mesh(b, "nan", nan_p, NULL, NULL, 3, k_idx, 1, NULL, 0, &err) ==
          PT_ERR_FORMAT);
    CHECK(strstr(err.msg, "nan") != NULL);
    float inf_p[9] = {0, 0, 0, 1, 0, 0, 0, INFINITY, 0};
    CHECK(pt_scene_builder_add_mesh(b, "inf", inf_p, NULL, NULL, 3, k_idx, 1, NULL, 0, &err) ==
          PT_ERR_FORMAT);
    float far_p[9] = {0, 0, 0, 2e15f, 0, 0, 0, 1, 0};
    CHECK(pt_scene_builder_add_mesh(b, "far", far_p, NULL, NULL, 3, k_idx, 1, NULL, 0, &err) ==
          PT_ERR_FORMAT);
    float nan_n[9] = {0, 0, 1, 0, 0, 1, 0, NAN, 1};
    CHECK(pt_scene_builder_add_mesh(b, "nn", k_tri, nan_n, NULL, 3, k_idx, 1, NULL, 0, &err) ==
          PT_ERR_FORMAT);
    float nan_uv[6] = {0, 0, 1, 0, NAN, 1};
    CHECK(pt_scene_builder_add_mesh(b, "uv", k_tri, NULL, nan_uv, 3, k_idx, 1, NULL, 0, &err) ==
          PT_ERR_FORMAT);
    CHECK(pt_scene_builder_add_mesh(b, "mat", k_tri, NULL, NULL, 3, k_idx, 1, NULL, 7, &err) ==
          PT_ERR_ARG);
    CHECK(pt_scene_builder_add_mesh(b, "ni", k_tri, NULL, NULL, 3, NULL, 2, NULL, 0, &err) ==
          PT_ERR_FORMAT);
    CHECK(pt_scene_builder_add_mesh(b, "cap", k_tri, NULL, NULL, 3, k_idx,
                                    PT_SCENE_MAX_TRIANGLES + 1, NULL, 0, &err) == PT_ERR_LIMIT);
    CHECK(strstr(err.msg, "16777217 triangles in the scene, over the cap of 16777216") != NULL);
    /* A material naming a texture that does not exist. */
    pt_material m = pt_material_default();
    m.base_color_tex = 0;
    uint32_t mi;
    CHECK(pt_scene_builder_add_material(b, &m, &mi, &err) == PT_ERR_ARG);
    /* Nothing got in: zero triangles. */
    pt_scene *s = NULL;
    CHECK(pt_scene_builder_finish(b, NULL, &s, &err) == PT_ERR_FORMAT && s == NULL);
    CHECK(strstr(err.msg, "no triangles") != NULL);

    /* A texture the builder refuses is still freed (ownership passes). */
    int64_t live = pt_alloc_live();
    b = builder_with(NULL);
    pt_texture t = {0};
    t.width = PT_SCENE_MAX_TEXTURE_DIM + 1;
    t.height = 1;
    t.rgba = pt_malloc(4);
    uint32_t ti;
    CHECK(pt_scene_builder_add_texture(b, &t, &ti, &err) == PT_ERR_LIMIT);
    pt_scene_builder_free(b);
    CHECK(pt_alloc_live() == live);

    /* Texels: one image over PT_SCENE_MAX_IMAGE_TEXELS, or one that takes
     * the scene over PT_SCENE_MAX_TEXELS, is refused (and freed). No pixel
     * is read before finish, so 4-byte stand-ins do. */
    b = builder_with(NULL);
    t.width = 8193;
    t.height = 8192;
    t.rgba = pt_malloc(4);
    CHECK(pt_scene_builder_add_texture(b, &t, &ti, &err) == PT_ERR_LIMIT &&
          strstr(err.msg, "at most 67108864 an image") != NULL);
    for (int i = 0; i < 4; i++) {
        t.width = t.height = 8192;
        t.rgba = pt_malloc(4);
        CHECK(pt_scene_builder_add_texture(b, &t, &ti, &err) == PT_OK);
    }
    t.width = t.height = 1;
    t.rgba = pt_malloc(4);
    CHECK(pt_scene_builder_add_texture(b, &t, &ti, &err) == PT_ERR_LIMIT &&
          strstr(err.msg, "268435457 texels in the scene") != NULL &&
          strstr(err.msg, "268435456 a scene") != NULL);
    pt_scene_builder_free(b);
    CHECK(pt_alloc_live() == live);
}

static uint32_t features_of(const pt_material *m, int with_tex, int with_uv)
{
    pt_error err = {0};
    pt_scene_builder *b = NULL;
    pt_scene_builder_new(&b, &err);
    if (with_tex) {
        pt_texture t = {0};
        t.width = t.height = 1;
        t.rgba = pt_calloc(4, 1);
        uint32_t ti;
        CHECK(pt_scene_builder_add_texture(b, &t, &ti, &err) == PT_OK);
    }
    uint32_t mi;
    CHECK(pt_scene_builder_add_material(b, m, &mi, &err) == PT_OK);
    /* An unused glossy, emissive, textured material changes nothing. */
    pt_material unused = pt_material_default();
    unused.emissive[0] = 5;
    unused.base_color_tex = with_tex ? 0 : -1;
    CHECK(pt_scene_builder_add_material(b, &unused, &mi, &err) == PT_OK);
    float uv[6] = {0, 0, 1, 0, 0, 1};
    CHECK(pt_scene_builder_add_mesh(b, "f", k_tri, NULL, with_uv ? uv : NULL, 3, k_idx, 1, NULL, 0,
                                    &err) == PT_OK);
    pt_scene *s = finish(b, NULL);
    uint32_t f = s ? s->features : 0xffffffffu;
    pt_scene_free(s);
    return f;
}

static void test_features(void)
{
    pt_material lambert = pt_material_default();
    lambert.metallic = 0;
    lambert.specular = 0;
    lambert.double_sided = 1;
    CHECK(features_of(&lambert, 0, 0) == 0);
    CHECK(features_of(&lambert, 0, 1) == PT_FEAT_UVS);

    pt_material glossy = lambert;
    glossy.specular = 0.5f; /* a dielectric with a specular lobe */
    CHECK(features_of(&glossy, 0, 0) == PT_FEAT_GLOSSY);
    pt_material metal = lambert;
    metal.metallic = 1;
    CHECK(features_of(&metal, 0, 0) == PT_FEAT_GLOSSY);
    pt_material mr = lambert;
    mr.metal_rough_tex = 0;
    CHECK(features_of(&mr, 1, 1) == (PT_FEAT_GLOSSY | PT_FEAT_TEXTURES | PT_FEAT_UVS));

    pt_material emit = lambert;
    emit.emissive[1] = 2;
    CHECK(features_of(&emit, 0, 0) == PT_FEAT_EMITTERS);
    emit.emissive_tex = 0;
    CHECK(features_of(&emit, 1, 1) == (PT_FEAT_EMITTERS | PT_FEAT_EMISSIVE_TEX | PT_FEAT_UVS));

    pt_material tex = lambert;
    tex.base_color_tex = 0;
    tex.double_sided = 0;
    CHECK(features_of(&tex, 1, 1) == (PT_FEAT_TEXTURES | PT_FEAT_UVS | PT_FEAT_SINGLE_SIDED));
}

static void test_texture(void)
{
    /* 2x1: left texel black, right texel white (sRGB 255 -> 1, 128 -> 0.2158). */
    uint8_t px[8] = {0, 0, 0, 255, 255, 128, 255, 0};
    pt_texture t = {0};
    t.width = 2;
    t.height = 1;
    t.rgba = px;
    t.srgb = 0;
    float o[4];
    /* Texel centres at u = 0.25 and 0.75. */
    pt_texture_sample(&t, 0.25f, 0.5f, o);
    CHECK(o[0] == 0 && o[3] == 1);
    pt_texture_sample(&t, 0.75f, 0.5f, o);
    CHECK(o[0] == 1 && near(o[1], 128 / 255.0f, 1e-6f) && o[3] == 0);
    pt_texture_sample(&t, 0.5f, 0.5f, o); /* half way: bilinear */
    CHECK(near(o[0], 0.5f, 1e-6f) && near(o[3], 0.5f, 1e-6f));
    /* REPEAT: u = 0 lies between the right texel (wrapped) and the left one. */
    pt_texture_sample(&t, 0.0f, 0.5f, o);
    CHECK(near(o[0], 0.5f, 1e-6f));
    pt_texture_sample(&t, 1.75f, 0.5f, o);
    CHECK(near(o[0], 1, 1e-6f));
    pt_texture_sample(&t, -0.25f, 0.5f, o);
    CHECK(near(o[0], 1, 1e-6f));
    /* CLAMP: u = 0 is the left texel alone. */
    t.wrap_s = PT_WRAP_CLAMP;
    pt_texture_sample(&t, 0.0f, 0.5f, o);
    CHECK(o[0] == 0);
    pt_texture_sample(&t, 5.0f, 0.5f, o);
    CHECK(o[0] == 1);
    /* MIRROR: u in [1, 2) runs backwards: 1.25 is the right texel. */
    t.wrap_s = PT_WRAP_MIRROR;
    pt_texture_sample(&t, 1.25f, 0.5f, o);
    CHECK(near(o[0], 1, 1e-6f));
    pt_texture_sample(&t, 1.75f, 0.5f, o);
    CHECK(near(o[0], 0, 1e-6f));
    pt_texture_sample(&t, 0.0f, 0.5f, o); /* the mirror edge repeats the left texel */
    CHECK(near(o[0], 0, 1e-6f));
    /* Hostile coordinates do not crash and give finite colours. */
    float hostile[4] = {NAN, INFINITY, -1e30f, 3e9f};
    for (int i = 0; i < 4; i++)
        for (int m = 0; m < 3; m++) {
            t.wrap_s = t.wrap_t = m;
            pt_texture_sample(&t, hostile[i], hostile[3 - i], o);
            CHECK(isfinite(o[0]) && o[0] >= 0 && o[0] <= 1);
        }
    /* sRGB decode (IEC 61966-2-1): alpha stays linear. */
    t.srgb = 1;
    t.wrap_s = t.wrap_t = PT_WRAP_REPEAT;
    pt_texture_sample(&t, 0.75f, 0.5f, o);
    CHECK(near(o[0], 1, 1e-6f) && near(o[1], 0.2158605f, 1e-5f));
    uint8_t g[4] = {10, 10, 10, 10};
    pt_texture t1 = {1, 1, g, 1, 0, 0, 0, 0, 0};
    pt_texture_sample(&t1, 0.3f, 0.3f, o);
    CHECK(near(o[0], 10 / 255.0f / 12.92f, 1e-6f) && near(o[3], 10 / 255.0f, 1e-6f));
    /* v = 0 is the top row. */
    uint8_t col[8] = {255, 0, 0, 255, 0, 0, 255, 255};
    pt_texture tv = {1, 2, col, 0, PT_WRAP_CLAMP, PT_WRAP_CLAMP, 0, 0, 0};
    pt_texture_sample(&tv, 0.5f, 0.0f, o);
    CHECK(o[0] == 1 && o[2] == 0);
    pt_texture_sample(&tv, 0.5f, 1.0f, o);
    CHECK(o[0] == 0 && o[2] == 1);
}

static void test_cameras(void)
{
    pt_error err = {0};
    pt_camera c = {0};
    c.position = pt_v3(0, 0, 10);
    c.forward = pt_v3(0, 0, -1);
    c.up = pt_v3(0, 1, 0);
    c.right = pt_v3(1, 0, 0);
    c.yfov = 0.5f;
    c.aspect = 1.5f;
    snprintf(c.name, sizeof c.name, "front");

    /* Named, scaled and translated. */
    pt_scene_builder *b = builder_with(NULL);
    CHECK(pt_scene_builder_add_mesh(b, "t", k_tri, NULL, NULL, 3, k_idx, 1, NULL, 0, &err) ==
          PT_OK);
    CHECK(pt_scene_builder_add_camera(b, &c, &err) == PT_OK);
    snprintf(c.name, sizeof c.name, "side");
    c.position = pt_v3(10, 0, 0);
    CHECK(pt_scene_builder_add_camera(b, &c, &err) == PT_OK);
    pt_scene_opts o = {0};
    o.camera_name = "side";
    o.scale = 2;
    o.translate = pt_v3(0, 1, 0);
    pt_scene *s = finish(b, &o);
    if (s) {
        CHECK(strcmp(s->camera.name, "side") == 0);
        CHECK(s->camera.position.x == 20 && s->camera.position.y == 1);
        CHECK(s->positions[3] == 2 && s->positions[4] == 1);
        CHECK(s->bounds_max.x == 2 && s->bounds_min.y == 1);
    }
    pt_scene_free(s);

    /* A camera by its node's name or by its index, as --list numbers them;
     * a camera's own name wins over an index that reads the same. */
    const char *picks[][2] = {{"RigNode", "side"}, {"0", "front"}, {"1", "side"}, {"2", "2"}};
    for (int k = 0; k < 4; k++) {
        b = builder_with(NULL);
        CHECK(pt_scene_builder_add_mesh(b, "t", k_tri, NULL, NULL, 3, k_idx, 1, NULL, 0, &err) ==
              PT_OK);
        snprintf(c.name, sizeof c.name, "front");
        snprintf(c.node, sizeof c.node, "FrontNode");
        CHECK(pt_scene_builder_add_camera(b, &c, &err) == PT_OK);
        snprintf(c.name, sizeof c.name, "side");
        snprintf(c.node, sizeof c.node, "RigNode");
        CHECK(pt_scene_builder_add_camera(b, &c, &err) == PT_OK);
        snprintf(c.name, sizeof c.name, "2");
        c.node[0] = '\0';
        CHECK(pt_scene_builder_add_camera(b, &c, &err) == PT_OK);
        o = (pt_scene_opts){0};
        o.camera_name = picks[k][0];
        s = finish(b, &o);
        CHECKF(s && strcmp(s->camera.name, picks[k][1]) == 0, "--camera %s: '%s', want '%s'",
               picks[k][0], s ? s->camera.name : "", picks[k][1]);
        CHECK(!s || pt_scene_find_camera(s, "3") == -1);
        CHECK(!s || pt_scene_find_camera(s, "+1") == -1);
        pt_scene_free(s);
    }
    snprintf(c.name, sizeof c.name, "side");
    c.node[0] = '\0';

    /* Unknown name: PT_ERR_ARG listing the names. */
    b = builder_with(NULL);
    CHECK(pt_scene_builder_add_mesh(b, "t", k_tri, NULL, NULL, 3, k_idx, 1, NULL, 0, &err) ==
          PT_OK);
    CHECK(pt_scene_builder_add_camera(b, &c, &err) == PT_OK);
    o.camera_name = "nope";
    s = NULL;
    CHECK(pt_scene_builder_finish(b, &o, &s, &err) == PT_ERR_ARG && s == NULL);
    CHECKF(strstr(err.msg, "nope") && strstr(err.msg, "side"), "%s", err.msg);

    /* A bad camera is refused. */
    b = builder_with(NULL);
    c.yfov = 0;
    CHECK(pt_scene_builder_add_camera(b, &c, &err) == PT_ERR_FORMAT);
    pt_scene_builder_free(b);

    /* No camera: framed. Every corner of the bounds is inside the view. */
    b = builder_with(NULL);
    float box[9] = {-3, -1, -2, 5, 2, 1, 0, 4, 3};
    CHECK(pt_scene_builder_add_mesh(b, "t", box, NULL, NULL, 3, k_idx, 1, NULL, 0, &err) == PT_OK);
    s = finish(b, NULL);
    if (!s)
        return;
    float aspects[3] = {0.0f, 0.5f, 2.0f};
    for (int a = 0; a < 3; a++) {
        pt_scene_frame_camera(s, aspects[a]);
        const pt_camera *k = &s->camera;
        CHECK(k->aspect == aspects[a]);
        CHECK(k->yfov > 0.6f && k->yfov < 0.8f);
        CHECK(near(pt_v3_dot(k->forward, k->up), 0, 1e-5f) &&
              near(pt_v3_dot(k->forward, k->right), 0, 1e-5f));
        CHECK(k->forward.z < -0.5f); /* looks from +Z */
        float ar = aspects[a] > 0 ? aspects[a] : 1.0f, t = tanf(0.5f * k->yfov);
        for (int i = 0; i < 8; i++) {
            pt_vec3 p = pt_v3(i & 1 ? s->bounds_max.x : s->bounds_min.x,
                              i & 2 ? s->bounds_max.y : s->bounds_min.y,
                              i & 4 ? s->bounds_max.z : s->bounds_min.z);
            pt_vec3 d = pt_v3_sub(p, k->position);
            float z = pt_v3_dot(d, k->forward);
            CHECK(z > k->znear);
            CHECKF(fabsf(pt_v3_dot(d, k->up)) / z <= t &&
                       fabsf(pt_v3_dot(d, k->right)) / z <= t * ar,
                   "aspect %g corner %d outside the view", (double)aspects[a], i);
        }
    }
    pt_scene_free(s);
}

static void test_hash_and_nomem(void)
{
    pt_error err = {0};
    char h[2][65];
    for (int i = 0; i < 2; i++) {
        pt_scene_builder *b = builder_with(NULL);
        float p[9] = {0, 0, 0, 1, 0, 0, 0, 1, (float)i};
        CHECK(pt_scene_builder_add_mesh(b, "t", p, NULL, NULL, 3, k_idx, 1, NULL, 0, &err) ==
              PT_OK);
        pt_scene *s = finish(b, NULL);
        snprintf(h[i], sizeof h[i], "%s", s ? s->hash : "");
        pt_scene_free(s);
    }
    CHECK(strlen(h[0]) == 64 && strcmp(h[0], h[1]) != 0);

    /* Allocation failure at every step of building: NOMEM, no leak. */
    int64_t live = pt_alloc_live();
    int ok = 0;
    for (uint64_t n = 1; n < 1000 && !ok; n++) {
        pt_alloc_fail_at(n);
        pt_status st = PT_OK;
        pt_scene_builder *b = NULL;
        pt_scene *s = NULL;
        uint32_t mi, ti;
        pt_material m = pt_material_default();
        if ((st = pt_scene_builder_new(&b, &err)) != PT_OK)
            goto done;
        pt_texture t = {1, 1, pt_malloc(4), 0, 0, 0, 0, 0, 0};
        if (!t.rgba) {
            st = PT_ERR_NOMEM;
            pt_scene_builder_free(b);
            goto done;
        }
        memset(t.rgba, 0, 4);
        if ((st = pt_scene_builder_add_texture(b, &t, &ti, &err)) != PT_OK ||
            (st = pt_scene_builder_add_material(b, &m, &mi, &err)) != PT_OK ||
            (st = pt_scene_builder_add_mesh(b, "t", k_tri, NULL, NULL, 3, k_idx, 1, NULL, 0,
                                            &err)) != PT_OK ||
            (st = pt_scene_builder_add_camera(
                 b,
                 &(pt_camera){
                     .forward = {0, 0, -1}, .up = {0, 1, 0}, .right = {1, 0, 0}, .yfov = 1},
                 &err)) != PT_OK) {
            pt_scene_builder_free(b);
            goto done;
        }
        st = pt_scene_builder_finish(b, NULL, &s, &err);
    done:
        pt_alloc_fail_at(0);
        if (st == PT_OK)
            ok = 1;
        else
            CHECKF(st == PT_ERR_NOMEM, "n=%llu: %s", (unsigned long long)n, err.msg);
        pt_scene_free(s);
        CHECKF(pt_alloc_live() == live, "n=%llu: leaked", (unsigned long long)n);
    }
    CHECK(ok);
}

/* An irregular mesh centred on the origin (bounds -1..1 on every axis, so its
 * centre is exactly 0) with details far below a float's ULP at 1e5 (8 mm),
 * each of which + 1e5 still fits a double's 53 bits exactly. */
static const float k_far_pos[] = {-1,      -1,         -1,    1,        1,    1,
                                  0.7123f, -0.000123f, 0.25f, -0.3333f, 0.5f, 0.002f,
                                  0.001f,  0.0012f,    -0.9f, 1,        -1,   1};
static const uint32_t k_far_idx[] = {0, 1, 2, 1, 3, 4, 2, 4, 5, 0, 5, 3};

static pt_scene *far_scene(const float *xf, const double *xd, const pt_scene_opts *o,
                           const double cam_pos[3])
{
    pt_error err = {0};
    pt_scene_builder *b = builder_with(NULL);
    if (xd)
        CHECK(pt_scene_builder_add_mesh_dxform(b, "far", k_far_pos, NULL, NULL, 6, k_far_idx, 4, xd,
                                               0, &err) == PT_OK);
    else
        CHECK(pt_scene_builder_add_mesh(b, "far", k_far_pos, NULL, NULL, 6, k_far_idx, 4, xf, 0,
                                        &err) == PT_OK);
    pt_camera c = {0};
    c.forward = pt_v3(0, 0, -1);
    c.up = pt_v3(0, 1, 0);
    c.right = pt_v3(1, 0, 0);
    c.yfov = 0.5f;
    snprintf(c.name, sizeof c.name, "cam");
    CHECKF(pt_scene_builder_add_camera_at(b, &c, cam_pos, &err) == PT_OK, "%s", err.msg);
    return finish(b, o);
}

/* The distance between two adjacent floats around x. */
static double ulpf(float x)
{
    float a = fabsf(x);
    return (double)(nextafterf(a, INFINITY) - a);
}

static void test_rebase(void)
{
    const double cam0[3] = {0, 0.25, 5};
    pt_scene *s0 = far_scene(NULL, NULL, NULL, cam0);
    if (!s0)
        return;
    CHECK(s0->origin[0] == 0 && s0->origin[1] == 0 && s0->origin[2] == 0);
    /* 1e5 is 3125 x 32: mesh + 1e5 is exact in double, so rebasing must give
     * back the local coordinates bit for bit, by a float xform, a double
     * xform, and opts.translate. */
    const float T = 1e5f;
    const float xf[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, T, -T, T, 1};
    double xd[16];
    for (int i = 0; i < 16; i++)
        xd[i] = xf[i];
    const double camT[3] = {cam0[0] + T, cam0[1] - T, cam0[2] + T};
    pt_scene_opts o = {0};
    o.translate = pt_v3(T, -T, T);
    pt_scene *v[3] = {far_scene(xf, NULL, NULL, camT), far_scene(NULL, xd, NULL, camT),
                      far_scene(NULL, NULL, &o, cam0)};
    for (int k = 0; k < 3; k++) {
        pt_scene *s = v[k];
        if (!s)
            continue;
        CHECKF(s->origin[0] == T && s->origin[1] == -T && s->origin[2] == T,
               "variant %d: origin %.17g %.17g %.17g", k, s->origin[0], s->origin[1], s->origin[2]);
        CHECKF(memcmp(s->positions, s0->positions, 18 * sizeof(float)) == 0,
               "variant %d: stored positions differ from the local ones", k);
        CHECKF(memcmp(s->normals, s0->normals, 18 * sizeof(float)) == 0,
               "variant %d: computed normals differ from the untranslated mesh's", k);
        CHECK(memcmp(&s->bounds_min, &s0->bounds_min, sizeof s->bounds_min) == 0 &&
              memcmp(&s->bounds_max, &s0->bounds_max, sizeof s->bounds_max) == 0);
        CHECK(memcmp(&s->camera.position, &s0->camera.position, sizeof(pt_vec3)) == 0);
        CHECK(strcmp(s->hash, s0->hash) != 0); /* the origin is part of the built data */
        pt_scene_free(s);
    }

    /* A translation that is no multiple of a large power of two: world =
     * stored + origin within one float ULP of the stored (local) coordinate,
     * and the origin within the bounds' rounding granule of the translation. */
    const double U[3] = {123456.789, -98765.4321, 31415.9265};
    double xu[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, U[0], U[1], U[2], 1};
    const double camU[3] = {cam0[0] + U[0], cam0[1] + U[1], cam0[2] + U[2]};
    pt_scene *s = far_scene(NULL, xu, NULL, camU);
    if (s) {
        int bad = 0;
        for (int i = 0; i < 18; i++) {
            double world = (double)k_far_pos[i] + U[i % 3];
            double err = fabs((double)s->positions[i] + s->origin[i % 3] - world);
            bad += !(err <= ulpf(s->positions[i]));
        }
        CHECKF(bad == 0, "%d coordinates beyond one float ULP of world - origin", bad);
        for (int r = 0; r < 3; r++) {
            /* extent 2: origin is a multiple of 16 nearest the centre. */
            CHECKF(fabs(s->origin[r] - U[r]) <= 8.0 && fmod(s->origin[r], 16.0) == 0.0,
                   "origin[%d] %.17g for translation %.17g", r, s->origin[r], U[r]);
            float c = (&s->camera.position.x)[r];
            CHECK(fabs((double)c + s->origin[r] - camU[r]) <= ulpf(c));
        }
        /* Stored coordinates stay within 4.5 extents (9) of zero, so their ULP
         * is at most 1e-6, where world-space floats had 8 mm. */
        for (int i = 0; i < 18; i++)
            CHECK(fabsf(s->positions[i]) <= 9.0f);
        pt_scene_free(s);
    }

    /* opts' scale applies in double before the translation; a scale that
     * overflows float after rebasing is rejected, not stored as Inf. */
    pt_scene_opts big = {0};
    big.scale = 1e30f;
    pt_scene_builder *b = builder_with(NULL);
    pt_error err = {0};
    CHECK(pt_scene_builder_add_mesh(b, "far", k_far_pos, NULL, NULL, 6, k_far_idx, 4, NULL, 0,
                                    &err) == PT_OK);
    pt_scene *bad = NULL;
    CHECK(pt_scene_builder_finish(b, &big, &bad, &err) == PT_ERR_ARG && bad == NULL);
    pt_scene_free(s0);
}

/* The default image height from a camera's aspect: rounding, the square
 * fallback and the clamp that keeps an extreme aspect from overflowing. */
static void test_camera_height(void)
{
    CHECK(pt_camera_height(16.0f / 9.0f, 512, 16384) == 288);
    CHECK(pt_camera_height(1.5f, 512, 16384) == 341);  /* 341.33 */
    CHECK(pt_camera_height(0.75f, 512, 16384) == 683); /* 682.67 */
    CHECK(pt_camera_height(2.0f, 3, 16384) == 2);      /* 1.5 rounds up */
    CHECK(pt_camera_height(0.0f, 512, 16384) == 512);
    CHECK(pt_camera_height(-1.0f, 128, 16384) == 128);
    CHECK(pt_camera_height(NAN, 128, 16384) == 128);
    CHECK(pt_camera_height(1e6f, 512, 16384) == 1); /* 0.0005 rounds to 0: at least 1 */
    CHECK(pt_camera_height(INFINITY, 512, 16384) == 1);
    CHECK(pt_camera_height(0.01f, 512, 16384) == 16384);
    CHECK(pt_camera_height(1e-30f, 512, UINT32_MAX) == UINT32_MAX);
    CHECK(pt_camera_height(1e-30f, 512, 1000) == 1000);
    CHECK(pt_camera_height(1.0f, 0, 100) == 1);
    /* Bit for bit the expression the programs used. */
    for (float a = 0.1f; a < 10.0f; a *= 1.37f)
        CHECK(pt_camera_height(a, 512, UINT32_MAX) == (uint32_t)(512.0f / a + 0.5f));
}

int main(void)
{
    test_camera_height();
    test_defaults();
    test_transform();
    test_computed_normals();
    test_negative_determinant();
    test_rejects();
    test_features();
    test_texture();
    test_cameras();
    test_hash_and_nomem();
    test_rebase();
    return check_report();
}
