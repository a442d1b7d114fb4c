/*
 * furnace.h - the white furnace's sphere (scenes/furnace.gltf) with flat
 * normals, for test_render.c and test_guiding.c.
 *
 * Its triangles, unshared, each with its geometric normal. Interpolated
 * normals lose a little energy by design (a cosine sample around the shading
 * normal that falls below the triangle ends the path: about 3e-4 of bounces
 * on this sphere), which would read as a bias of 0.12 % at albedo 0.8; these
 * tests are about the estimator, so the surface has none. The material is
 * the file's with base colour albedo and emission `emission`; mrs (may be
 * NULL: the file's) sets metallic, roughness and specular.
 */
#ifndef PT_TESTS_COMMON_RENDER_FURNACE_H
#define PT_TESTS_COMMON_RENDER_FURNACE_H

#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/scene/scene.h"
#include "tests/check.h"

static inline pt_scene *furnace_load(const char *rel)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", PT_SOURCE_DIR, rel);
    pt_scene_opts o = {0};
    o.scale = 1.0f;
    pt_scene *s = NULL;
    pt_error err = {0};
    if (pt_scene_load(path, &o, &s, &err) != PT_OK) {
        fprintf(stderr, "cannot load %s: %s\n", path, err.msg);
        return NULL;
    }
    return s;
}

static inline pt_scene *flat_furnace_of(float albedo, float emission, const float mrs[3])
{
    pt_scene *src = furnace_load("scenes/furnace.gltf");
    if (!src)
        return NULL;
    uint32_t nt = src->num_triangles;
    float *pos = pt_malloc_array((size_t)nt * 9, sizeof *pos);
    float *nrm = pt_malloc_array((size_t)nt * 9, sizeof *nrm);
    pt_scene *out = NULL;
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    if (pos && nrm && pt_scene_builder_new(&b, &err) == PT_OK) {
        for (uint32_t t = 0; t < nt; t++) {
            pt_vec3 v[3];
            for (int k = 0; k < 3; k++) {
                uint32_t i = src->indices[3 * t + k];
                v[k] = pt_v3(src->positions[3 * i], src->positions[3 * i + 1],
                             src->positions[3 * i + 2]);
                memcpy(&pos[9 * t + 3 * k], &v[k], 3 * sizeof(float));
            }
            pt_vec3 n = pt_v3_norm(pt_v3_cross(pt_v3_sub(v[1], v[0]), pt_v3_sub(v[2], v[0])));
            for (int k = 0; k < 3; k++)
                memcpy(&nrm[9 * t + 3 * k], &n, 3 * sizeof(float));
        }
        pt_material m = src->materials[0];
        for (int c = 0; c < 3; c++) {
            m.base_color[c] = albedo;
            m.emissive[c] = emission;
        }
        if (mrs) {
            m.metallic = mrs[0];
            m.roughness = mrs[1];
            m.specular = mrs[2];
        }
        uint32_t mat;
        CHECK(pt_scene_builder_add_material(b, &m, &mat, &err) == PT_OK);
        CHECK(pt_scene_builder_add_mesh(b, "sphere", pos, nrm, NULL, nt * 3, NULL, nt, NULL, mat,
                                        &err) == PT_OK);
        CHECK(pt_scene_builder_add_camera(b, &src->camera, &err) == PT_OK);
        CHECKF(pt_scene_builder_finish(b, NULL, &out, &err) == PT_OK, "%s", err.msg);
    }
    pt_free(pos);
    pt_free(nrm);
    pt_scene_free(src);
    return out;
}

#endif
