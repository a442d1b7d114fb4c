/*
 * vec.h - small float vector math for the renderer's hot path.
 *
 * Plain structs passed by value, all functions static inline. World space is
 * glTF's: right-handed, +Y up, metres (but any scale must work). Shading frames
 * are built with the branchless orthonormal basis of Duff et al. 2017,
 * "Building an Orthonormal Basis, Revisited" (JCGT 6(1)).
 *
 * Threads: pure inline functions; any thread.
 */
#ifndef PT_COMMON_MATH_VEC_H
#define PT_COMMON_MATH_VEC_H

#include <math.h>
#include <stdint.h>

#define PT_PI 3.14159265358979323846f
#define PT_INV_PI 0.31830988618379067154f

typedef struct pt_vec3 {
    float x, y, z;
} pt_vec3;

static inline pt_vec3 pt_v3(float x, float y, float z)
{
    return (pt_vec3){x, y, z};
}
static inline pt_vec3 pt_v3_add(pt_vec3 a, pt_vec3 b)
{
    return pt_v3(a.x + b.x, a.y + b.y, a.z + b.z);
}
static inline pt_vec3 pt_v3_sub(pt_vec3 a, pt_vec3 b)
{
    return pt_v3(a.x - b.x, a.y - b.y, a.z - b.z);
}
static inline pt_vec3 pt_v3_mul(pt_vec3 a, pt_vec3 b)
{
    return pt_v3(a.x * b.x, a.y * b.y, a.z * b.z);
}
static inline pt_vec3 pt_v3_scale(pt_vec3 a, float s)
{
    return pt_v3(a.x * s, a.y * s, a.z * s);
}
static inline pt_vec3 pt_v3_neg(pt_vec3 a)
{
    return pt_v3(-a.x, -a.y, -a.z);
}
static inline float pt_v3_dot(pt_vec3 a, pt_vec3 b)
{
    return a.x * b.x + a.y * b.y + a.z * b.z;
}
static inline pt_vec3 pt_v3_cross(pt_vec3 a, pt_vec3 b)
{
    return pt_v3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}
static inline float pt_v3_len(pt_vec3 a)
{
    return sqrtf(pt_v3_dot(a, a));
}
static inline pt_vec3 pt_v3_norm(pt_vec3 a)
{
    float l = pt_v3_len(a);
    return l > 0.0f ? pt_v3_scale(a, 1.0f / l) : a;
}
static inline float pt_v3_max_comp(pt_vec3 a)
{
    return fmaxf(a.x, fmaxf(a.y, a.z));
}
/* Rec.709 / sRGB-primaries luminance. */
static inline float pt_luminance(pt_vec3 c)
{
    return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z;
}
static inline pt_vec3 pt_v3_lerp(pt_vec3 a, pt_vec3 b, float t)
{
    return pt_v3_add(a, pt_v3_scale(pt_v3_sub(b, a), t));
}

/* An orthonormal frame; local z is the normal. */
typedef struct pt_frame {
    pt_vec3 t, b, n;
} pt_frame;

/* Duff et al. 2017, listing 3. n must be unit length. */
static inline pt_frame pt_frame_from_normal(pt_vec3 n)
{
    float sign = copysignf(1.0f, n.z);
    float a = -1.0f / (sign + n.z);
    float b = n.x * n.y * a;
    pt_frame f;
    f.t = pt_v3(1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x);
    f.b = pt_v3(b, sign + n.y * n.y * a, -n.y);
    f.n = n;
    return f;
}
static inline pt_vec3 pt_frame_to_local(const pt_frame *f, pt_vec3 v)
{
    return pt_v3(pt_v3_dot(v, f->t), pt_v3_dot(v, f->b), pt_v3_dot(v, f->n));
}
static inline pt_vec3 pt_frame_to_world(const pt_frame *f, pt_vec3 v)
{
    return pt_v3_add(pt_v3_add(pt_v3_scale(f->t, v.x), pt_v3_scale(f->b, v.y)),
                     pt_v3_scale(f->n, v.z));
}

static inline int pt_isfinite3(pt_vec3 v)
{
    return isfinite(v.x) && isfinite(v.y) && isfinite(v.z);
}

#endif
