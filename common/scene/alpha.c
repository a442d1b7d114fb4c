/*
 * alpha.c - glTF alpha coverage and the stochastic pass-through (alpha.h).
 */
#include "common/scene/alpha.h"

/* A 32-bit integer hash with full avalanche ("lowbias32", C. Wellons 2018,
 * "Prospecting for Hash Functions"): its output bits are near-independent
 * of each other for inputs that differ in one bit, which the pass-through
 * needs for keys that differ in a sample's low bits. */
static inline uint32_t mix32(uint32_t x)
{
    x ^= x >> 16;
    x *= 0x7feb352du;
    x ^= x >> 15;
    x *= 0x846ca68bu;
    x ^= x >> 16;
    return x;
}

float pt_alpha_value(const pt_scene *s, uint32_t tri, float b1, float b2)
{
    const pt_material *m = &s->materials[s->tri_material[tri]];
    float a = m->base_color[3];
    if (m->base_color_tex >= 0) {
        /* surface_at's interpolation (render.c), so alpha is read at the
         * texel the base colour is. */
        float u = 0.0f, v = 0.0f;
        if (s->uvs) {
            const uint32_t *t = &s->indices[3 * tri];
            const float *uv = s->uvs;
            float b0 = 1.0f - b1 - b2;
            u = b0 * uv[2 * t[0]] + b1 * uv[2 * t[1]] + b2 * uv[2 * t[2]];
            v = b0 * uv[2 * t[0] + 1] + b1 * uv[2 * t[1] + 1] + b2 * uv[2 * t[2] + 1];
        }
        float texel[4];
        pt_texture_sample(&s->textures[m->base_color_tex], u, v, texel);
        a *= texel[3];
    }
    /* COLOR_0: when vertex colours are imported, multiply here by their
     * alpha interpolated at (b1, b2) (glTF 3.9.2: the base colour is
     * factor x texture x COLOR_0, alpha included). */
    return a;
}

float pt_alpha_coverage(const pt_scene *s, uint32_t tri, float b1, float b2)
{
    const pt_material *m = &s->materials[s->tri_material[tri]];
    if (m->alpha_mode == PT_ALPHA_OPAQUE)
        return 1.0f;
    float a = pt_alpha_value(s, tri, b1, b2);
    if (m->alpha_mode == PT_ALPHA_MASK)
        return a >= m->alpha_cutoff ? 1.0f : 0.0f;
    return a < 0.0f ? 0.0f : (a > 1.0f ? 1.0f : a);
}

int pt_alpha_hit(const pt_scene *s, uint32_t tri, float b1, float b2, uint32_t key)
{
    const pt_material *m = &s->materials[s->tri_material[tri]];
    if (m->alpha_mode == PT_ALPHA_OPAQUE)
        return 1;
    float a = pt_alpha_value(s, tri, b1, b2);
    if (m->alpha_mode == PT_ALPHA_MASK)
        return a >= m->alpha_cutoff;
    /* A uniform number in [0, 1) on a 2^-24 grid from the key and the
     * triangle: the triangle's index goes through its own hash first, so
     * that (key, tri) and (key', tri') collide only by chance. alpha 1 is
     * always hit, alpha 0 never. */
    uint32_t h = mix32(key ^ mix32(tri + 0x9e3779b9u));
    return (float)(h >> 8) * 0x1p-24f < a;
}
