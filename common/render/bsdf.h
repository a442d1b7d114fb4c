/*
 * bsdf.h - the glTF 2.0 metallic-roughness BSDF (with KHR_materials_specular).
 *
 * Plain data and functions, after the setup/eval/sample triple of the Cycles
 * closures. All directions are in the local shading frame (z = normal), unit
 * length, pointing away from the surface. Lobes:
 *  - diffuse: Lambert, base colour x (1 - metallic), weighted by (1 - F_dielectric)
 *    as in the glTF spec's fresnel_mix;
 *  - specular: GGX / Trowbridge-Reitz microfacets (alpha = roughness^2), Smith
 *    height-correlated masking-shadowing, Schlick Fresnel; F0 = mix(0.04 *
 *    specular_color * specular, base colour, metallic).
 * Sampling picks a lobe by an estimate of its albedo, then cosine-weighted
 * hemisphere sampling (diffuse) or the GGX distribution of visible normals
 * (Heitz 2018, "Sampling the GGX Distribution of Visible Normals", JCGT 7(4)).
 * pt_bsdf_pdf returns the full one-sample MIS pdf of pt_bsdf_sample so NEE
 * can weight with the power heuristic. An impossible sample has pdf 0.
 * Thread-safe (no state).
 */
#ifndef PT_COMMON_RENDER_BSDF_H
#define PT_COMMON_RENDER_BSDF_H

#include <stddef.h>

#include "common/math/vec.h"

typedef struct pt_bsdf {
    pt_vec3 diffuse;     /* Lambert albedo (already x (1 - metallic)), 0 when absent */
    pt_vec3 f0;          /* specular reflectance at normal incidence */
    float spec_weight;   /* specular strength (0 = no GGX lobe at all) */
    float alpha;         /* GGX alpha = roughness^2, clamped to >= PT_BSDF_MIN_ALPHA */
    float dielectric_f0; /* scalar F0 of the dielectric layer (0.04 * specular), for the diffuse
                            weight */
} pt_bsdf;

/* Below this alpha the lobe is treated as this smooth; avoids a delta lobe
 * and the singular D of alpha -> 0 in float. */
#define PT_BSDF_MIN_ALPHA 1e-3f

/* Builds the BSDF from glTF parameters (linear base colour, metallic,
 * roughness in [0,1], KHR_materials_specular factor and colour). */
pt_bsdf pt_bsdf_setup(pt_vec3 base_color, float metallic, float roughness, float specular,
                      pt_vec3 specular_color);

/* f(wo, wi) * |cos(wi)|, and the pdf pt_bsdf_sample would give wi (solid angle). */
pt_vec3 pt_bsdf_eval(const pt_bsdf *b, pt_vec3 wo, pt_vec3 wi, float *pdf);
float pt_bsdf_pdf(const pt_bsdf *b, pt_vec3 wo, pt_vec3 wi);

/* Samples wi from u (3 numbers in [0,1): u[0] picks the lobe, u[1..2] the
 * direction). Returns weight = f * cos / pdf and sets *wi, *pdf; pdf 0 (and a
 * zero weight) when the sample is impossible (below the surface). */
pt_vec3 pt_bsdf_sample(const pt_bsdf *b, pt_vec3 wo, const float u[3], pt_vec3 *wi, float *pdf);

/* Lower-level pieces, exposed for the statistical tests. */
/* GGX visible normal for view wo (Heitz 2018); isotropic alpha. */
pt_vec3 pt_ggx_sample_vndf(pt_vec3 wo, float alpha, float u1, float u2);
float pt_ggx_d(pt_vec3 m, float alpha);
float pt_ggx_g1(pt_vec3 w, float alpha);
/* pdf of pt_ggx_sample_vndf's normal m: G1(wo) max(0, wo.m) D(m) / wo.z */
float pt_ggx_vndf_pdf(pt_vec3 wo, pt_vec3 m, float alpha);

#endif
