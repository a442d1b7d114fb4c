/*
 * fuzz_gltf.c - libFuzzer target for the glTF loader (pt_scene_load:
 * common/scene/gltf_import.cpp through tinygltf, the scene builder, the image
 * decoder) and the dependency scan that packs a scene (pt_gltf_dependencies).
 *
 * Input: up to four parts separated by FUZZ_GLTF_SEP: the entry file, written
 * as scene.glb when it starts with the GLB magic "glTF" and as scene.gltf
 * otherwise; the buffer b.bin; the image i.png; a camera name to ask for. A
 * part that is absent is not written, so a plain .gltf or .glb file is an
 * input as it is (ctest also replays the scenes/ folder). The harness writes
 * the files into its scratch folder and loads the entry with the real loader,
 * then frees the scene; no render.
 * The entry is loaded twice: as a still, and animated (pt_anim_load, then
 * posed after its last key).
 * Invariants: a refusal names its cause; nothing is left allocated; a loaded
 * scene has triangles whose indices and materials are in range, finite
 * positions inside its bounds, unit normals, textures within the size cap,
 * and a camera with a finite position and an orthonormal basis.
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/scene/anim.h"
#include "common/scene/bundle.h"
#include "common/scene/scene.h"
#include "common/scene/uri.h"
#include "tests/fuzz/fuzz_util.h"

#define FUZZ_GLTF_SEP "\n#ptfuzz#\n"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void quiet(void *user, const char *message)
{
    (void)user;
    (void)message;
}

/* The first FUZZ_GLTF_SEP in p[0, n), or NULL. */
static const uint8_t *find_sep(const uint8_t *p, size_t n)
{
    size_t k = sizeof FUZZ_GLTF_SEP - 1;
    for (size_t i = 0; n >= k && i <= n - k; i++)
        if (p[i] == '\n' && memcmp(p + i, FUZZ_GLTF_SEP, k) == 0)
            return p + i;
    return NULL;
}

static int near1(float x)
{
    return fabsf(x - 1.0f) < 1e-3f;
}

static void check_scene(const pt_scene *s)
{
    FUZZ_CHECK(s->num_triangles > 0 && s->num_vertices > 0);
    for (uint32_t i = 0; i < 3 * s->num_triangles; i++)
        FUZZ_CHECK(s->indices[i] < s->num_vertices);
    for (uint32_t i = 0; i < s->num_triangles; i++)
        FUZZ_CHECK(s->tri_material[i] < s->num_materials);
    for (uint32_t v = 0; v < s->num_vertices; v++) {
        const float *p = s->positions + 3 * v, *nn = s->normals + 3 * v;
        FUZZ_CHECK(isfinite(p[0]) && isfinite(p[1]) && isfinite(p[2]));
        FUZZ_CHECK(p[0] >= s->bounds_min.x && p[0] <= s->bounds_max.x);
        FUZZ_CHECK(p[1] >= s->bounds_min.y && p[1] <= s->bounds_max.y);
        FUZZ_CHECK(p[2] >= s->bounds_min.z && p[2] <= s->bounds_max.z);
        FUZZ_CHECK(near1(nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2]));
    }
    for (uint32_t t = 0; t < s->num_textures; t++) {
        const pt_texture *x = &s->textures[t];
        FUZZ_CHECK(x->width > 0 && x->height > 0 && x->rgba);
        FUZZ_CHECK(x->width <= PT_SCENE_MAX_TEXTURE_DIM && x->height <= PT_SCENE_MAX_TEXTURE_DIM);
    }
    for (uint32_t m = 0; m < s->num_materials; m++) {
        const pt_material *mt = &s->materials[m];
        FUZZ_CHECK(mt->base_color_tex < (int32_t)s->num_textures);
        FUZZ_CHECK(mt->metal_rough_tex < (int32_t)s->num_textures);
        FUZZ_CHECK(mt->emissive_tex < (int32_t)s->num_textures);
    }
    const pt_camera *c = &s->camera;
    FUZZ_CHECK(isfinite(c->position.x) && isfinite(c->position.y) && isfinite(c->position.z));
    FUZZ_CHECK(near1(pt_v3_dot(c->forward, c->forward)) && near1(pt_v3_dot(c->right, c->right)) &&
               near1(pt_v3_dot(c->up, c->up)));
    /* A placement's orthographic view (a camera name "look:...:ortho=W") has
     * ymag 0: the image's aspect gives its height (pt_renderer_new). */
    int placed = strncmp(c->name, PT_CAMERA_LOOK_PREFIX, strlen(PT_CAMERA_LOOK_PREFIX)) == 0;
    if (c->ortho)
        FUZZ_CHECK(c->yfov == 0 && c->xmag > 0 && c->xmag <= PT_SCENE_MAX_COORD &&
                   (c->ymag > 0 || (placed && c->ymag == 0)) && c->ymag <= PT_SCENE_MAX_COORD);
    else
        FUZZ_CHECK(c->yfov > 0 && c->yfov < 3.1416f);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static const char *const names[3] = {NULL, "b.bin", "i.png"};
    const char *dir = fuzz_dir();
    const uint8_t *part = data, *end = data + size;
    char camera[64] = "";
    int glb = size >= 4 && memcmp(data, "glTF", 4) == 0;
    fuzz_unlink(dir, "scene.gltf");
    fuzz_unlink(dir, "scene.glb");
    for (int i = 0; i < 4; i++) {
        const uint8_t *sep = part ? find_sep(part, (size_t)(end - part)) : NULL;
        size_t n = part ? (size_t)((sep ? sep : end) - part) : 0;
        if (i == 0)
            fuzz_write(dir, glb ? "scene.glb" : "scene.gltf", part, n);
        else if (i < 3 && part)
            fuzz_write(dir, names[i], part, n);
        else if (i < 3)
            fuzz_unlink(dir, names[i]);
        else if (part)
            snprintf(camera, sizeof camera, "%.*s", (int)(n < 63 ? n : 63), (const char *)part);
        part = sep ? sep + sizeof FUZZ_GLTF_SEP - 1 : NULL;
    }
    char entry[700];
    snprintf(entry, sizeof entry, "%s/%s", dir, glb ? "scene.glb" : "scene.gltf");

    int64_t live = pt_alloc_live();
    pt_error err = {0};
    pt_scene_opts opts = {0};
    opts.warn = quiet;
    /* The caps' checks are fuzzed as well at a sixty-fourth of their size:
     * an input that instances its way to the full 16 Mi triangles would be
     * correct and take the fuzzer's whole time budget. */
    opts.max_triangles = PT_SCENE_MAX_TRIANGLES / 64;
    opts.camera_name = camera[0] ? camera : NULL;
    pt_scene *scene = NULL;
    pt_status st = pt_scene_load(entry, &opts, &scene, &err);
    fuzz_note("load", st, &err);
    FUZZ_CHECK(st == PT_OK || (st == err.code && err.msg[0]));
    FUZZ_CHECK((st == PT_OK) == (scene != NULL));
    if (scene)
        check_scene(scene);
    pt_scene_free(scene);

    /* The same file animated (anim.h): posed at load, then after every key;
     * each pose keeps the invariants, or the load names what it refuses. */
    pt_anim *anim = NULL;
    scene = NULL;
    opts.animate = 1;
    opts.time = 0.75;
    st = pt_anim_load(entry, &opts, &scene, &anim, &err);
    fuzz_note("animate", st, &err);
    FUZZ_CHECK(st == PT_OK || (st == err.code && err.msg[0]));
    FUZZ_CHECK((st == PT_OK) == (scene != NULL) && (st == PT_OK) == (anim != NULL));
    if (scene) {
        check_scene(scene);
        st = pt_anim_pose(anim, 1e3, scene, &err);
        FUZZ_CHECK(st == PT_OK || (st == err.code && err.msg[0]));
        check_scene(scene);
    }
    pt_anim_free(anim);
    pt_scene_free(scene);

    /* What a client packs: the same files refused as the loader refuses. */
    char **deps = NULL;
    uint32_t ndeps = 0;
    st = pt_gltf_dependencies(entry, &deps, &ndeps, &err);
    fuzz_note("dependencies", st, &err);
    FUZZ_CHECK(st == PT_OK || (st == err.code && err.msg[0]));
    if (st == PT_OK) {
        for (uint32_t i = 0; i < ndeps; i++)
            FUZZ_CHECK(!pt_uri_path_refusal(deps[i], strlen(deps[i])));
        pt_gltf_dependencies_free(deps, ndeps);
    }
    FUZZ_CHECK(pt_alloc_live() == live);
    return 0;
}
