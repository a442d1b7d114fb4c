/*
 * bsdf.c - the glTF 2.0 metallic-roughness base with KHR_materials_specular:
 * its parameters and its diffuse and specular lobes (closure.h combines them).
 *
 * The glTF model (spec appendix B, and KHR_materials_specular) is
 *   f = (1-m) [ (1 - s F_d) base/pi + s F(f0_d) f_ggx ] + m F(base) f_ggx,
 * F(f0) = f0 + (1 - f0) (1 - c)^5 (Schlick 1994), f0_d = 0.04 x specular colour.
 * Collecting the two GGX terms gives one Schlick Fresnel with
 *   F0 = mix(s f0_d, base, m)  and  F90 = (1-m) s + m = spec_weight,
 * so F = F0 + (spec_weight - F0)(1 - c)^5 and specular = 0, metallic = 0 gives
 * F = 0: no GGX lobe at all, only Lambert.
 *
 * The diffuse attenuation follows KHR_materials_specular's section
 * "Implementation": the dielectric's Fresnel is the RGB
 *   dielectric_fresnel = mix(dielectric_f0, dielectric_f90, (1 - c)^5),
 *   dielectric_f0 = min(0.04 x specularColor, 1) x specular, dielectric_f90 = specular,
 * and the diffuse is weighed by 1 - max_value(dielectric_fresnel) (its
 * dielectric_brdf; the max keeps a coloured F0 from tinting the diffuse with
 * its complement). For c in [0, 1] each channel is f0_i (1 - w) + f90 w with
 * 1 - w >= 0, so the largest channel is the one with the largest f0: the
 * weight is one scalar Schlick from F0 = max_i dielectric_f0_i to F90 =
 * specular, which is what pt_bsdf keeps (a white colour gives 0.04 s, the
 * plain glTF dielectric). It is evaluated at c = min(cos wo, cos wi)
 * instead of glTF's v.h: that keeps the BSDF reciprocal and its energy
 * below 1 (with v.h a smooth dielectric seen at grazing reflects F ~ 1
 * specularly while the diffuse keeps ~96%).
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
    return pt_v3(pt_fminf(pt_fmaxf(c.x, 0.0f), hi), pt_fminf(pt_fmaxf(c.y, 0.0f), hi),
                 pt_fminf(pt_fmaxf(c.z, 0.0f), hi));
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
        pt_v3_scale(clamp3(pt_v3_scale(specular_color, PT_BSDF_DIELECTRIC_F0), 1.0f), specular);
    pt_bsdf b;
    b.diffuse = pt_v3_scale(base_color, 1.0f - metallic);
    b.f0 = pt_v3_lerp(f0_dielectric, base_color, metallic);
    b.spec_weight = (1.0f - metallic) * specular + metallic;
    b.alpha = maxf(roughness * roughness, PT_BSDF_MIN_ALPHA);
    b.dielectric_f0 = pt_v3_max_comp(f0_dielectric);
    b.dielectric_f90 = specular;
    return b;
}

/*
 * KHR_materials_pbrSpecularGlossiness (archived extension, "Specular -
 * Glossiness"): c_diff = diffuse (1 - max(specular)), F0 = specular,
 * alpha = (1 - glossiness)^2, with the BRDF of glTF 2.0's appendix B, whose
 * Fresnel goes to 1 at grazing. That is the metallic-roughness base above
 * with metallic 0, specular 1 (F90 = 1) and F0 given directly, the diffuse
 * weighed by 1 - the largest channel of that Fresnel (dielectric_f0 =
 * max(specular)), so the two workflows share one BSDF; built here without
 * the division by 0.04 that pt_bsdf_setup would need, so F0 keeps its bits.
 */
pt_bsdf pt_bsdf_setup_spec_gloss(pt_vec3 diffuse, pt_vec3 specular, float glossiness)
{
    specular = clamp3(specular, 1.0f);
    glossiness = clamp01(glossiness == glossiness ? glossiness : 0.0f);
    float r = 1.0f - glossiness;
    pt_bsdf b;
    b.diffuse = pt_v3_scale(clamp3(diffuse, 1.0f), 1.0f - pt_v3_max_comp(specular));
    b.f0 = specular;
    b.spec_weight = 1.0f;
    b.alpha = maxf(r * r, PT_BSDF_MIN_ALPHA);
    b.dielectric_f0 = pt_v3_max_comp(specular);
    b.dielectric_f90 = 1.0f;
    return b;
}

float pt_ggx_g1(pt_vec3 w, float alpha)
{
    if (w.z <= 0.0f)
        return 0.0f;
    float s = pt_ggx_lambda_root(w, alpha);
    return 2.0f * w.z / (w.z + s);
}

float pt_ggx_vndf_pdf(pt_vec3 wo, pt_vec3 m, float alpha)
{
    /* G1(wo) / wo.z = 2 / (wo.z + s(wo)). */
    float wm = pt_v3_dot(wo, m);
    if (wo.z <= 0.0f || wm <= 0.0f)
        return 0.0f;
    return 2.0f * wm * pt_ggx_d(m, alpha) / (wo.z + pt_ggx_lambda_root(wo, alpha));
}

pt_vec3 pt_ggx_sample_vndf(pt_vec3 wo, float alpha, float u1, float u2)
{
    return pt_ggx_sample_vndf_aniso(wo, alpha, alpha, u1, u2);
}

pt_vec3 pt_ggx_sample_vndf_aniso(pt_vec3 wo, float ax, float ay, float u1, float u2)
{
    /* Heitz 2018, "Sampling the GGX Distribution of Visible Normals", JCGT
     * 7(4), listing 1: stretch the view to the hemisphere configuration (by
     * both alphas), sample the projected area of the unit hemisphere as a
     * disk whose lower half is squashed by (1 + v.z) / 2, lift to the
     * hemisphere, unstretch. */
    pt_vec3 v = pt_v3_norm(pt_v3(ax * wo.x, ay * wo.y, wo.z));
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
    return pt_v3_norm(pt_v3(ax * nh.x, ay * nh.y, maxf(0.0f, nh.z)));
}

/*
 * Probability of picking the GGX lobe, from albedo estimates at cos wo: the
 * lobe's Fresnel for the specular, the attenuated diffuse albedo for the
 * diffuse. Depends on wo only, so the closure computes it once per shading
 * point. A present lobe keeps at least MIN_LOBE_PROB so that neither is
 * starved where the estimate is off.
 */
float pt_bsdf_spec_prob(const pt_bsdf *b, float cos_o)
{
    if (!(b->spec_weight > 0.0f))
        return 0.0f;
    if (!(pt_v3_max_comp(b->diffuse) > 0.0f))
        return 1.0f;
    float ed = pt_luminance(b->diffuse) *
               (1.0f - pt_bsdf_diffuse_fresnel(b->dielectric_f0, b->dielectric_f90, cos_o));
    float es = pt_luminance(pt_bsdf_spec_fresnel(b->f0, b->spec_weight, cos_o));
    float p = es + ed > 0.0f ? es / (es + ed) : 0.5f;
    return pt_fminf(pt_fmaxf(p, MIN_LOBE_PROB), 1.0f - MIN_LOBE_PROB);
}
