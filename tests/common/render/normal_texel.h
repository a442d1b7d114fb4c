/*
 * normal_texel.h - a tangent-space normal map's texels and the normals they
 * encode (glTF 2.0, material.normalTexture: n = normalize((2 c / 255 - 1)
 * x (scale, scale, 1)) from linear bytes c), and a texture of one such
 * texel, for test_normalmap.c, test_coatnormal.c and test_manifold.c.
 */
#ifndef PT_TESTS_COMMON_RENDER_NORMAL_TEXEL_H
#define PT_TESTS_COMMON_RENDER_NORMAL_TEXEL_H

#include <math.h>
#include <stdint.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/scene/scene.h"
#include "tests/check.h"

/* The mapped normal of texel c at scale s, in (tangent, bitangent, n). */
static inline void mapped(const uint8_t c[3], double s, double n[3])
{
    double x = (2.0 * c[0] / 255.0 - 1.0) * s, y = (2.0 * c[1] / 255.0 - 1.0) * s,
           z = 2.0 * c[2] / 255.0 - 1.0;
    double l = sqrt(x * x + y * y + z * z);
    n[0] = x / l;
    n[1] = y / l;
    n[2] = z / l;
}

/* The texel that encodes a tilt of deg degrees towards azimuth az (radians
 * from the tangent). */
static inline void texel_for(double deg, double az, uint8_t c[3])
{
    double t = deg * 3.14159265358979323846 / 180.0;
    double v[3] = {sin(t) * cos(az), sin(t) * sin(az), cos(t)};
    for (int k = 0; k < 3; k++)
        c[k] = (uint8_t)lrint((v[k] + 1.0) * 0.5 * 255.0);
}

/* A 1 x 1 texture of linear bytes c (alpha 255) added to b: its index. */
static inline uint32_t one_texel(pt_scene_builder *b, const uint8_t c[3])
{
    pt_texture t;
    memset(&t, 0, sizeof t);
    t.width = t.height = 1;
    t.rgba = pt_malloc(4);
    if (t.rgba) {
        memcpy(t.rgba, c, 3);
        t.rgba[3] = 255;
    }
    uint32_t ti = 0;
    pt_error err = {0};
    CHECK(pt_scene_builder_add_texture(b, &t, &ti, &err) == PT_OK);
    return ti;
}

#endif
