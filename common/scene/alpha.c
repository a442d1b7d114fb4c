/*
 * alpha.c - glTF alpha coverage and the stochastic pass-through (alpha.h).
 */
#include "common/scene/alpha.h"

#include <math.h>

#include "common/base/alloc.h"

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

/* The texel index range [*i0, *i1] along one axis of n texels that lookups
 * at coordinates in [lo, hi] can read (bilinear: the two texel centres
 * around x = u n - 0.5; nearest: floor(u n), within those), widened by a
 * hundredth of a texel and 1e-4 of the span for barycentrics a rounding
 * outside the triangle; the whole axis when the range is not inside
 * [0, 1) (a wrap mode then maps it) or not inside the image. */
static void axis_range(float lo, float hi, uint32_t n, uint32_t *i0, uint32_t *i1)
{
    double x0 = (double)lo * n - 0.5, x1 = (double)hi * n - 0.5;
    double slack = 0.01 + 1e-4 * (x1 - x0);
    double a = floor(x0 - slack), b = floor(x1 + slack) + 1.0;
    if (!(lo >= 0.0f && hi < 1.0f && a >= 0.0 && b <= (double)n - 1.0)) {
        *i0 = 0;
        *i1 = n - 1;
        return;
    }
    *i0 = (uint32_t)a;
    *i1 = (uint32_t)b;
}

/* The least alpha that pt_alpha_value can give on triangle tri (MASK),
 * or -1 when it is not bounded cheaply (see pt_alpha_solid_new). */
static float alpha_floor(const pt_scene *s, uint32_t tri, uint64_t *budget)
{
    const pt_material *m = &s->materials[s->tri_material[tri]];
    const uint32_t *t = &s->indices[3 * tri];
    float a = m->base_color[3];
    if (!(a >= 0.0f))
        return -1.0f;
    if (s->colors) {
        float c = INFINITY;
        for (int k = 0; k < 3; k++)
            c = fminf(c, s->colors[4 * t[k] + 3]);
        if (!(c >= 0.0f))
            return -1.0f;
        a *= c;
    }
    if (m->base_color_tex < 0)
        return a;
    const pt_texture *tex = &s->textures[m->base_color_tex];
    if (tex->width == 0 || tex->height == 0)
        return -1.0f;
    const pt_tex_xform *x = &m->tex_xf[PT_SLOT_BASE];
    const float *set = x->texcoord ? s->uvs1 : s->uvs;
    float lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
    for (int k = 0; k < 3; k++) {
        float uv[2] = {0.0f, 0.0f}, st[2];
        if (set) {
            uv[0] = set[2 * t[k]];
            uv[1] = set[2 * t[k] + 1];
        }
        /* The transform is affine: the box of the corners' images bounds
         * the image of every point between them. */
        pt_tex_xform_apply(x, uv, st);
        for (int c = 0; c < 2; c++) {
            if (!isfinite(st[c]))
                return -1.0f;
            lo[c] = fminf(lo[c], st[c]);
            hi[c] = fmaxf(hi[c], st[c]);
        }
    }
    uint32_t x0, x1, y0, y1;
    axis_range(lo[0], hi[0], tex->width, &x0, &x1);
    axis_range(lo[1], hi[1], tex->height, &y0, &y1);
    uint64_t n = (uint64_t)(x1 - x0 + 1) * (y1 - y0 + 1);
    if (n > PT_ALPHA_SOLID_TEXELS || n > *budget)
        return -1.0f;
    *budget -= n;
    uint8_t least = 255;
    for (uint32_t y = y0; y <= y1 && least > 0; y++)
        for (uint32_t xx = x0; xx <= x1; xx++) {
            uint8_t px[4];
            pt_texture_texel(tex, xx, y, px);
            least = px[3] < least ? px[3] : least;
        }
    return a * ((float)least / 255.0f);
}

pt_status pt_alpha_solid_new(const pt_scene *s, uint8_t **out, pt_error *err)
{
    uint8_t *f = pt_calloc(s->num_triangles ? s->num_triangles : 1, 1);
    if (!f)
        return pt_error_set(err, PT_ERR_NOMEM, "alpha: out of memory for %u triangles' flags",
                            s->num_triangles);
    uint64_t budget = PT_ALPHA_SOLID_BUDGET;
    for (uint32_t tri = 0; tri < s->num_triangles; tri++) {
        const pt_material *m = &s->materials[s->tri_material[tri]];
        if (m->alpha_mode != PT_ALPHA_MASK)
            continue;
        /* The lookup's sums of weights x bytes may round a little under the
         * least texel: a relative margin far above float's. */
        float a = alpha_floor(s, tri, &budget);
        f[tri] = a >= 0.0f && a * (1.0f - 1e-5f) >= m->alpha_cutoff;
    }
    *out = f;
    return PT_OK;
}
