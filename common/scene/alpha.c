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

/* The attribute `attr` (n floats a vertex) of triangle tri interpolated at
 * (b1, b2), as surface_at interpolates it (render.c). */
static void interp(const pt_scene *s, const float *attr, int n, uint32_t tri, float b1, float b2,
                   float *out)
{
    const uint32_t *t = &s->indices[3 * tri];
    float b0 = 1.0f - b1 - b2;
    for (int k = 0; k < n; k++)
        out[k] = b0 * attr[n * t[0] + k] + b1 * attr[n * t[1] + k] + b2 * attr[n * t[2] + k];
}

float pt_alpha_value(const pt_scene *s, uint32_t tri, float b1, float b2)
{
    const pt_material *m = &s->materials[s->tri_material[tri]];
    float a = m->base_color[3];
    if (m->base_color_tex >= 0) {
        /* Read at the texel the base colour is: the slot's coordinate set
         * and transform (KHR_texture_transform). */
        const pt_tex_xform *x = &m->tex_xf[PT_SLOT_BASE];
        const float *set = x->texcoord ? s->uvs1 : s->uvs;
        float uv[2] = {0.0f, 0.0f}, st[2];
        if (set)
            interp(s, set, 2, tri, b1, b2, uv);
        pt_tex_xform_apply(x, uv, st);
        float texel[4];
        pt_texture_sample(&s->textures[m->base_color_tex], st[0], st[1], texel);
        a *= texel[3];
    }
    /* COLOR_0: the base colour is factor x texture x COLOR_0, alpha included
     * (glTF 2.0, 3.9.2). */
    if (s->colors) {
        float c[4];
        interp(s, s->colors, 4, tri, b1, b2, c);
        a *= c[3];
    }
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
