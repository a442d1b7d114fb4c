/*
 * bsdf.c - the glTF 2.0 metallic-roughness BSDF with KHR_materials_specular.
 *
 * The glTF model (spec appendix B, and KHR_materials_specular) is
 *   f = (1-m) [ (1 - s F_d) base/pi + s F(f0_d) f_ggx ] + m F(base) f_ggx,
 * F(f0) = f0 + (1 - f0) (1 - c)^5 (Schlick 1994), f0_d = 0.04 x specular colour.
 * Collecting the two GGX terms gives one Schlick Fresnel with
 *   F0 = mix(s f0_d, base, m)  and  F90 = (1-m) s + m = spec_weight,
 * so F = F0 + (spec_weight - F0)(1 - c)^5 and specular = 0, metallic = 0 gives
 * F = 0: no GGX lobe at all, only Lambert.
 *
 * The diffuse attenuation (1 - s F_d) uses the scalar Schlick of the dielectric
 * layer with F0 = dielectric_f0 = 0.04 s and F90 = s (= dielectric_f0 / 0.04),
 * evaluated at c = min(cos wo, cos wi) instead of glTF's v.h: that keeps the
 * BSDF reciprocal and its energy below 1 (with v.h a smooth dielectric seen at
 * grazing reflects F ~ 1 specularly while the diffuse keeps ~96%).
 *
 * Specular: GGX / Trowbridge-Reitz D (Walter et al. 2007), Smith
 * height-correlated masking-shadowing G2 = 1 / (1 + L(wo) + L(wi)) with
 * L(w) = (sqrt(1 + a^2 tan^2) - 1) / 2 (Heitz 2014, "Understanding the
 * Masking-Shadowing Function in Microfacet-Based BRDFs", JCGT 3(2), eq. 99).
 * L is rewritten with s(w) = sqrt(z^2 + a^2 (x^2 + y^2)) so that no formula
 * divides by a cosine: G1 = 2z / (z + s), G2 = 2 zo zi / (zi s_o + zo s_i).
 */
#include "common/render/bsdf.h"

#include <string.h>

#include "common/render/sampler.h"

#define DIELECTRIC_F0 0.04f /* glTF's ((1 - ior) / (1 + ior))^2 for ior 1.5 */
#define MIN_LOBE_PROB 0.05f

static inline float clamp01(float x)
{
    return x < 0.0f ? 0.0f : (x > 1.0f ? 1.0f : x);
}
static inline float maxf(float a, float b)
{
    return a > b ? a : b;
}

static inline pt_vec3 clamp3(pt_vec3 c, float hi)
{
    return pt_v3(fminf(fmaxf(c.x, 0.0f), hi), fminf(fmaxf(c.y, 0.0f), hi),
                 fminf(fmaxf(c.z, 0.0f), hi));
}

/* (1 - c)^5 for Schlick's approximation. */
static inline float schlick_w(float c)
{
    float m = clamp01(1.0f - c);
    float m2 = m * m;
    return m2 * m2 * m;
}

/* Scalar Schlick of the dielectric layer for the diffuse weight: F0 =
 * dielectric_f0 = 0.04 s, F90 = s. */
static inline float diffuse_fresnel(const pt_bsdf *b, float c)
{
    float f90 = b->dielectric_f0 * (1.0f / DIELECTRIC_F0);
    return b->dielectric_f0 + (f90 - b->dielectric_f0) * schlick_w(c);
}

/* The GGX lobe's Fresnel: F0 = b->f0, F90 = spec_weight. */
static inline pt_vec3 spec_fresnel(const pt_bsdf *b, float c)
{
    float w = schlick_w(c);
    return pt_v3(b->f0.x + (b->spec_weight - b->f0.x) * w, b->f0.y + (b->spec_weight - b->f0.y) * w,
                 b->f0.z + (b->spec_weight - b->f0.z) * w);
}

pt_bsdf pt_bsdf_setup(pt_vec3 base_color, float metallic, float roughness, float specular,
                      pt_vec3 specular_color)
{
    /* x == x is false for NaN only: a NaN parameter falls back to metallic 0,
     * roughness 1, specular 1. */
    metallic = clamp01(metallic == metallic ? metallic : 0.0f);
    roughness = clamp01(roughness == roughness ? roughness : 1.0f);
    specular = clamp01(specular == specular ? specular : 1.0f);
    base_color = clamp3(base_color, 1.0f);
    pt_vec3 f0_dielectric =
        pt_v3_scale(clamp3(pt_v3_scale(specular_color, DIELECTRIC_F0), 1.0f), specular);
    pt_bsdf b;
    b.diffuse = pt_v3_scale(base_color, 1.0f - metallic);
    b.f0 = pt_v3_lerp(f0_dielectric, base_color, metallic);
    b.spec_weight = (1.0f - metallic) * specular + metallic;
    b.alpha = maxf(roughness * roughness, PT_BSDF_MIN_ALPHA);
    b.dielectric_f0 = DIELECTRIC_F0 * specular;
    return b;
}

float pt_ggx_d(pt_vec3 m, float alpha)
{
    if (m.z <= 0.0f)
        return 0.0f;
    /* cos^2 (a^2 - 1) + 1 written as sin^2 + a^2 cos^2: no cancellation
     * near the normal when alpha is tiny. */
    float a2 = alpha * alpha;
    float t = (m.x * m.x + m.y * m.y) + a2 * m.z * m.z;
    return t > 0.0f ? a2 / (PT_PI * t * t) : 0.0f;
}

/* s(w) = z * sqrt(1 + a^2 tan^2) = sqrt(z^2 + a^2 (x^2 + y^2)). */
static inline float lambda_root(pt_vec3 w, float alpha)
{
    return sqrtf(w.z * w.z + alpha * alpha * (w.x * w.x + w.y * w.y));
}

float pt_ggx_g1(pt_vec3 w, float alpha)
{
    if (w.z <= 0.0f)
        return 0.0f;
    float s = lambda_root(w, alpha);
    return 2.0f * w.z / (w.z + s);
}

float pt_ggx_vndf_pdf(pt_vec3 wo, pt_vec3 m, float alpha)
{
    /* G1(wo) / wo.z = 2 / (wo.z + s(wo)). */
    float wm = pt_v3_dot(wo, m);
    if (wo.z <= 0.0f || wm <= 0.0f)
        return 0.0f;
    return 2.0f * wm * pt_ggx_d(m, alpha) / (wo.z + lambda_root(wo, alpha));
}

pt_vec3 pt_ggx_sample_vndf(pt_vec3 wo, float alpha, float u1, float u2)
{
    /* Heitz 2018, "Sampling the GGX Distribution of Visible Normals", JCGT
     * 7(4), listing 1: stretch the view to the hemisphere configuration, sample
     * the projected area of the unit hemisphere as a disk whose lower half is
     * squashed by (1 + v.z) / 2, lift to the hemisphere, unstretch. */
    pt_vec3 v = pt_v3_norm(pt_v3(alpha * wo.x, alpha * wo.y, wo.z));
    float len2 = v.x * v.x + v.y * v.y;
    pt_vec3 t1 = len2 > 0.0f ? pt_v3_scale(pt_v3(-v.y, v.x, 0.0f), 1.0f / sqrtf(len2))
                             : pt_v3(1.0f, 0.0f, 0.0f);
    pt_vec3 t2 = pt_v3_cross(v, t1);
    float r = sqrtf(u1), phi = 2.0f * PT_PI * u2;
    float p1 = r * cosf(phi), p2 = r * sinf(phi);
    float s = 0.5f * (1.0f + v.z);
    p2 = (1.0f - s) * sqrtf(maxf(0.0f, 1.0f - p1 * p1)) + s * p2;
    float pz = sqrtf(maxf(0.0f, 1.0f - p1 * p1 - p2 * p2));
    pt_vec3 nh = pt_v3_add(pt_v3_add(pt_v3_scale(t1, p1), pt_v3_scale(t2, p2)), pt_v3_scale(v, pz));
    return pt_v3_norm(pt_v3(alpha * nh.x, alpha * nh.y, maxf(0.0f, nh.z)));
}

static inline pt_vec3 reflect(pt_vec3 w, pt_vec3 m)
{
    return pt_v3_sub(pt_v3_scale(m, 2.0f * pt_v3_dot(w, m)), w);
}

/*
 * Probability of picking the GGX lobe, from albedo estimates at cos wo: the
 * lobe's Fresnel for the specular, the attenuated diffuse albedo for the
 * diffuse. Depends on wo only, so pdf and sample agree. A present lobe keeps
 * at least MIN_LOBE_PROB so that neither is starved where the estimate is off.
 */
static float spec_prob(const pt_bsdf *b, float cos_o)
{
    if (!(b->spec_weight > 0.0f))
        return 0.0f;
    if (!(pt_v3_max_comp(b->diffuse) > 0.0f))
        return 1.0f;
    float ed = pt_luminance(b->diffuse) * (1.0f - diffuse_fresnel(b, cos_o));
    float es = pt_luminance(spec_fresnel(b, cos_o));
    float p = es + ed > 0.0f ? es / (es + ed) : 0.5f;
    return fminf(fmaxf(p, MIN_LOBE_PROB), 1.0f - MIN_LOBE_PROB);
}

/* Both lobes at (wo, wi), both above the surface, with ps = spec_prob(wo):
 * f * cos(wi) and the mixture pdf. */
static pt_vec3 eval_both(const pt_bsdf *b, pt_vec3 wo, pt_vec3 wi, float ps, float *pdf)
{
    pt_vec3 f = pt_v3(0.0f, 0.0f, 0.0f);
    float p = 0.0f;
    if (ps < 1.0f) {
        float fd = diffuse_fresnel(b, fminf(wo.z, wi.z));
        f = pt_v3_scale(b->diffuse, (1.0f - fd) * wi.z * PT_INV_PI);
        p = (1.0f - ps) * wi.z * PT_INV_PI;
    }
    if (ps > 0.0f) {
        pt_vec3 h = pt_v3_add(wo, wi);
        float hl = pt_v3_len(h);
        if (hl > 0.0f) {
            h = pt_v3_scale(h, 1.0f / hl);
            float d = pt_ggx_d(h, b->alpha);
            float so = lambda_root(wo, b->alpha), si = lambda_root(wi, b->alpha);
            /* f cos = F D G2 / (4 zo) = F D zi / (2 (zi s_o + zo s_i)). */
            float den = wi.z * so + wo.z * si;
            pt_vec3 F = spec_fresnel(b, pt_v3_dot(wo, h));
            if (den > 0.0f && d > 0.0f) {
                f = pt_v3_add(f, pt_v3_scale(F, d * wi.z / (2.0f * den)));
                /* VNDF pdf / (4 wo.h) = D / (2 (zo + s_o)). */
                p += ps * d / (2.0f * (wo.z + so));
            }
        }
    }
    *pdf = p;
    return f;
}

pt_vec3 pt_bsdf_eval(const pt_bsdf *b, pt_vec3 wo, pt_vec3 wi, float *pdf)
{
    if (!(wo.z > 0.0f) || !(wi.z > 0.0f)) {
        *pdf = 0.0f;
        return pt_v3(0.0f, 0.0f, 0.0f);
    }
    return eval_both(b, wo, wi, spec_prob(b, wo.z), pdf);
}

float pt_bsdf_pdf(const pt_bsdf *b, pt_vec3 wo, pt_vec3 wi)
{
    float pdf;
    pt_bsdf_eval(b, wo, wi, &pdf);
    return pdf;
}

pt_vec3 pt_bsdf_sample(const pt_bsdf *b, pt_vec3 wo, const float u[3], pt_vec3 *wi, float *pdf)
{
    pt_vec3 zero = pt_v3(0.0f, 0.0f, 0.0f);
    *pdf = 0.0f;
    *wi = pt_v3(0.0f, 0.0f, 1.0f);
    if (!(wo.z > 0.0f))
        return zero;
    float ps = spec_prob(b, wo.z);
    if (u[0] < ps) {
        pt_vec3 m = pt_ggx_sample_vndf(wo, b->alpha, u[1], u[2]);
        *wi = reflect(wo, m);
    } else {
        *wi = pt_sample_cosine_hemisphere(u[1], u[2]);
    }
    if (!(wi->z > 0.0f))
        return zero;
    /* The weight is the mixture's f cos / pdf, not the chosen lobe's, so it
     * agrees with pt_bsdf_eval / pt_bsdf_pdf and MIS sees one estimator. */
    pt_vec3 f = eval_both(b, wo, *wi, ps, pdf);
    if (!(*pdf > 0.0f)) {
        *pdf = 0.0f;
        return zero;
    }
    return pt_v3_scale(f, 1.0f / *pdf);
}
