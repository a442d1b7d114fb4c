/*
 * bsdf.h - the glTF 2.0 metallic-roughness base (with KHR_materials_specular):
 * its parameters and its two lobes, for the material closure (closure.h).
 *
 * Plain data and functions, after the setup/eval/sample triple of the Cycles
 * closures. All directions are in the local shading frame (z = normal), unit
 * length, pointing away from the surface. Lobes:
 *  - diffuse: Lambert, base colour x (1 - metallic), weighted by 1 - max(F_dielectric),
 *    the largest channel of the dielectric's coloured Fresnel, as in
 *    KHR_materials_specular's fresnel_mix;
 *  - specular: GGX / Trowbridge-Reitz microfacets (alpha = roughness^2), Smith
 *    height-correlated masking-shadowing, Schlick Fresnel; F0 = mix(0.04 *
 *    specular_color * specular, base colour, metallic).
 * The closure picks a lobe by pt_bsdf_spec_prob, an estimate of the lobes'
 * albedos at wo, then samples cosine-weighted (diffuse) or the GGX
 * distribution of visible normals (Heitz 2018, "Sampling the GGX Distribution
 * of Visible Normals", JCGT 7(4)). Each lobe's eval gives f cos and its share
 * of the closure's one-sample MIS pdf (the lobe's pick probability times its
 * own density, in that order of operations); an impossible direction gives 0.
 * Thread-safe (no state).
 */
#ifndef PT_COMMON_RENDER_BSDF_H
#define PT_COMMON_RENDER_BSDF_H

#include <stddef.h>

#include "common/math/vec.h"
#include "common/render/sampler.h"

/* fminf and fmaxf by comparisons, with their NaN rule (a NaN argument is
 * ignored): without -ffinite-math-only GCC calls the library for them, on
 * every lobe's eval. Only the sign of a zero result may differ, which no
 * caller can see (none compares a +0 with a -0 argument). */
static inline float pt_fminf(float a, float b)
{
    return (a < b || b != b) ? a : b;
}
static inline float pt_fmaxf(float a, float b)
{
    return (a > b || b != b) ? a : b;
}

typedef struct pt_bsdf {
    pt_vec3 diffuse;   /* Lambert albedo (already x (1 - metallic)), 0 when absent */
    pt_vec3 f0;        /* specular reflectance at normal incidence */
    float spec_weight; /* specular strength (0 = no GGX lobe at all) */
    float alpha;       /* GGX alpha = roughness^2, clamped to >= PT_BSDF_MIN_ALPHA */
    /* The diffuse weight's scalar Schlick: the largest channel of the
     * dielectric's F0, min(0.04 x specular colour, 1) x specular, and its
     * F90, specular (bsdf.c). */
    float dielectric_f0;
    float dielectric_f90;
} pt_bsdf;

/* Below this alpha the lobe is treated as this smooth; avoids a delta lobe
 * and the singular D of alpha -> 0 in float. */
#define PT_BSDF_MIN_ALPHA 1e-3f

/* Builds the base from glTF parameters (linear base colour, metallic,
 * roughness in [0,1], KHR_materials_specular factor and colour). */
pt_bsdf pt_bsdf_setup(pt_vec3 base_color, float metallic, float roughness, float specular,
                      pt_vec3 specular_color);

/* Builds the base from KHR_materials_pbrSpecularGlossiness inputs (linear
 * diffuse colour, specular colour and glossiness in [0,1]): the
 * extension's c_diff = diffuse x (1 - max(specular)) as the Lambert albedo,
 * F0 = specular and F90 = 1 for the GGX lobe, alpha = (1 - glossiness)^2,
 * and the diffuse weighed by the dielectric's (1 - F) as the metallic-
 * roughness base weighs it (bsdf.c). It equals pt_bsdf_setup(c_diff, 0,
 * 1 - glossiness, 1, specular / 0.04): the metallic-roughness material with
 * KHR_materials_specular that the extension converts to. */
pt_bsdf pt_bsdf_setup_spec_gloss(pt_vec3 diffuse, pt_vec3 specular, float glossiness);

/* The Lambert lobe: albedo x (1 - F_d(min(cos wo, cos wi))) / pi, F_d the
 * dielectric layer's scalar Schlick from dielectric_f0 to dielectric_f90
 * (bsdf.c). */
typedef struct pt_diffuse_lobe {
    pt_vec3 albedo;
    float dielectric_f0;
    float dielectric_f90;
} pt_diffuse_lobe;

/* The GGX reflection lobe with Schlick's Fresnel from f0 to f90. */
typedef struct pt_specular_lobe {
    pt_vec3 f0;
    float f90;
    float alpha;
} pt_specular_lobe;

/* The probability of sampling the specular lobe at cos wo, from the lobes'
 * albedo estimates: 0 without a specular lobe, 1 without a diffuse one
 * (diffuse colour 0), else within [0.05, 0.95]. The closure has the specular
 * lobe when it is > 0 and the diffuse one when it is < 1. */
float pt_bsdf_spec_prob(const pt_bsdf *b, float cos_o);

/* Lower-level pieces, exposed for the statistical tests. */
/* GGX visible normal for view wo (Heitz 2018); isotropic alpha. */
pt_vec3 pt_ggx_sample_vndf(pt_vec3 wo, float alpha, float u1, float u2);
/* The same for the anisotropic GGX (alphas ax along x, ay along y), in the
 * frame where they lie on the axes (aniso.h). */
pt_vec3 pt_ggx_sample_vndf_aniso(pt_vec3 wo, float ax, float ay, float u1, float u2);
float pt_ggx_g1(pt_vec3 w, float alpha);
/* pdf of pt_ggx_sample_vndf's normal m: G1(wo) max(0, wo.m) D(m) / wo.z */
float pt_ggx_vndf_pdf(pt_vec3 wo, pt_vec3 m, float alpha);

/* ---- the lobes, inline: the closure's hot path ------------------------- */

#define PT_BSDF_DIELECTRIC_F0 0.04f /* glTF's ((1 - ior) / (1 + ior))^2 for ior 1.5 */

/* (1 - c)^5 for Schlick's approximation. */
static inline float pt_bsdf_schlick_w(float c)
{
    float m = 1.0f - c;
    m = m < 0.0f ? 0.0f : (m > 1.0f ? 1.0f : m);
    float m2 = m * m;
    return m2 * m2 * m;
}

/* Scalar Schlick of the dielectric layer for the diffuse weight: F0 =
 * dielectric_f0, F90 = dielectric_f90 (pt_bsdf). */
static inline float pt_bsdf_diffuse_fresnel(float dielectric_f0, float dielectric_f90, float c)
{
    return dielectric_f0 + (dielectric_f90 - dielectric_f0) * pt_bsdf_schlick_w(c);
}

/* The GGX lobe's Fresnel: F0 = f0, F90 = f90. */
static inline pt_vec3 pt_bsdf_spec_fresnel(pt_vec3 f0, float f90, float c)
{
    float w = pt_bsdf_schlick_w(c);
    return pt_v3(f0.x + (f90 - f0.x) * w, f0.y + (f90 - f0.y) * w, f0.z + (f90 - f0.z) * w);
}

/* GGX D (Walter et al. 2007); 0 below the surface. */
static inline float pt_ggx_d(pt_vec3 m, float alpha)
{
    if (m.z <= 0.0f)
        return 0.0f;
    /* cos^2 (a^2 - 1) + 1 written as sin^2 + a^2 cos^2: no cancellation
     * near the normal when alpha is tiny. */
    float a2 = alpha * alpha;
    float t = (m.x * m.x + m.y * m.y) + a2 * m.z * m.z;
    return t > 0.0f ? a2 / (PT_PI * t * t) : 0.0f;
}

/* s(w) = z * sqrt(1 + a^2 tan^2) = sqrt(z^2 + a^2 (x^2 + y^2)) (bsdf.c). */
static inline float pt_ggx_lambda_root(pt_vec3 w, float alpha)
{
    return sqrtf(w.z * w.z + alpha * alpha * (w.x * w.x + w.y * w.y));
}

static inline pt_diffuse_lobe pt_bsdf_diffuse(const pt_bsdf *b)
{
    pt_diffuse_lobe l = {b->diffuse, b->dielectric_f0, b->dielectric_f90};
    return l;
}

static inline pt_specular_lobe pt_bsdf_specular(const pt_bsdf *b)
{
    pt_specular_lobe l = {b->f0, b->spec_weight, b->alpha};
    return l;
}

/* f cos at wi, and *share = prob x the pdf of the lobe's sampling at wi (0
 * with f 0 where wi or wo is not above the surface). */
static inline pt_vec3 pt_diffuse_eval(const pt_diffuse_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob,
                                      float *share)
{
    if (!(wo.z > 0.0f) || !(wi.z > 0.0f)) {
        *share = 0.0f;
        return pt_v3(0.0f, 0.0f, 0.0f);
    }
    float fd = pt_bsdf_diffuse_fresnel(l->dielectric_f0, l->dielectric_f90, pt_fminf(wo.z, wi.z));
    *share = prob * wi.z * PT_INV_PI;
    return pt_v3_scale(l->albedo, (1.0f - fd) * wi.z * PT_INV_PI);
}

/* The GGX lobe's f cos without its Fresnel, D zi / (2 (zi s_o + zo s_i)),
 * *share as pt_specular_eval's and *cos_h = wo.h (for the Fresnel); 0 (and
 * *share 0) where wi or wo is not above the surface. */
static inline float pt_specular_geom(const pt_specular_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob,
                                     float *share, float *cos_h)
{
    *share = 0.0f;
    *cos_h = 0.0f;
    if (!(wo.z > 0.0f) || !(wi.z > 0.0f))
        return 0.0f;
    pt_vec3 h = pt_v3_add(wo, wi);
    float hl = pt_v3_len(h);
    if (!(hl > 0.0f))
        return 0.0f;
    h = pt_v3_scale(h, 1.0f / hl);
    float d = pt_ggx_d(h, l->alpha);
    float so = pt_ggx_lambda_root(wo, l->alpha), si = pt_ggx_lambda_root(wi, l->alpha);
    /* f cos = F D G2 / (4 zo) = F D zi / (2 (zi s_o + zo s_i)). */
    float den = wi.z * so + wo.z * si;
    if (!(den > 0.0f) || !(d > 0.0f))
        return 0.0f;
    *cos_h = pt_v3_dot(wo, h);
    /* VNDF pdf / (4 wo.h) = D / (2 (zo + s_o)). */
    *share = prob * d / (2.0f * (wo.z + so));
    return d * wi.z / (2.0f * den);
}

static inline pt_vec3 pt_specular_eval(const pt_specular_lobe *l, pt_vec3 wo, pt_vec3 wi,
                                       float prob, float *share)
{
    float c;
    float g = pt_specular_geom(l, wo, wi, prob, share, &c);
    if (g == 0.0f)
        return pt_v3(0.0f, 0.0f, 0.0f);
    return pt_v3_scale(pt_bsdf_spec_fresnel(l->f0, l->f90, c), g);
}

/* KHR_materials_diffuse_transmission's thin-walled Lambertian transmission:
 * the diffuse lobe mirrored to the far side (wi.z < 0), weighted as the
 * diffuse is by 1 - F_d(min(cos wo, |cos wi|)); albedo is the transmitted
 * share, dt x colour x (1 - metallic). */
static inline pt_vec3 pt_diffuse_transmit_eval(const pt_diffuse_lobe *l, pt_vec3 wo, pt_vec3 wi,
                                               float prob, float *share)
{
    if (!(wo.z > 0.0f) || !(wi.z < 0.0f)) {
        *share = 0.0f;
        return pt_v3(0.0f, 0.0f, 0.0f);
    }
    float fd = pt_bsdf_diffuse_fresnel(l->dielectric_f0, l->dielectric_f90, pt_fminf(wo.z, -wi.z));
    *share = prob * -wi.z * PT_INV_PI;
    return pt_v3_scale(l->albedo, (1.0f - fd) * -wi.z * PT_INV_PI);
}

/* A direction on the far side from u[1..2]; 1 when it lies below. */
static inline int pt_diffuse_transmit_sample(const float u[3], pt_vec3 *wi)
{
    *wi = pt_sample_cosine_hemisphere(u[1], u[2]);
    wi->z = -wi->z;
    return wi->z < 0.0f;
}

/* A direction from u[1..2]; 1 when it lies above the surface, else 0. */
static inline int pt_diffuse_sample(const float u[3], pt_vec3 *wi)
{
    *wi = pt_sample_cosine_hemisphere(u[1], u[2]);
    return wi->z > 0.0f;
}

static inline int pt_specular_sample(const pt_specular_lobe *l, pt_vec3 wo, const float u[3],
                                     pt_vec3 *wi)
{
    pt_vec3 m = pt_ggx_sample_vndf(wo, l->alpha, u[1], u[2]);
    *wi = pt_v3_sub(pt_v3_scale(m, 2.0f * pt_v3_dot(wo, m)), wo);
    return wi->z > 0.0f;
}

#endif
