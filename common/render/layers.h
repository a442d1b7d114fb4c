/*
 * layers.h - clearcoat and sheen layered over the glTF base BSDF
 * (KHR_materials_clearcoat, KHR_materials_sheen).
 *
 * The layering is the extensions' own (their READMEs, "Layering" and
 * "Albedo-scaling"), outermost first:
 *   f = Fc(wo) f_coat + (1 - Fc(wo)) [ f_sheen + S(wo, wi) f_base ],
 *   Fc(wo) = clearcoat x Schlick(F0 = 0.04, wo.z)   (a coat of ior 1.5),
 *   S(wo, wi) = min(1 - max(sheen) E(wo.z), 1 - max(sheen) E(wi.z)),
 * with f_coat a GGX reflection without Fresnel (alpha = clearcoatRoughness^2,
 * Smith height-correlated G2) on the shading normal (clearcoatNormalTexture
 * is not read), and f_sheen = sheenColor D_charlie V_ashikhmin: the "Charlie"
 * distribution of Estevez & Kulla 2017 ("Production Friendly Microfacet
 * Sheen BRDF"), alpha = sheenRoughness^2 (>= PT_LAYERS_MIN_SHEEN_ALPHA), with
 * the visibility 1 / (4 (zi + zo - zi zo)) of Neubelt & Pettineo 2013 (as in
 * Filament). E(mu) is that sheen lobe's directional albedo for white colour,
 * tabulated by numerical quadrature (32 x 32 over mu and roughness, computed
 * once per process, bilinear). That visibility lets a sharp sheen seen at
 * grazing reflect more than it receives (E > 1): there the sheen lobe is
 * divided by E(wo.z) and E is read as min(E, 1). The whole never reflects more than it gets:
 * each term's albedo is at most what the layer above leaves.
 *
 * Sampling picks coat, sheen or base with u[0] by the weights Fc(wo),
 * (1 - Fc) max(sheen) E(wo.z), (1 - Fc)(1 - max(sheen) E(wo.z)); the coat by
 * GGX visible normals, the sheen uniformly over the hemisphere, the base by
 * pt_bsdf_sample with u[0] rescaled. pdf is the one-sample MIS mixture of all
 * three, so NEE weighs with it as with pt_bsdf_pdf. Local frame as bsdf.h.
 */
#ifndef PT_COMMON_RENDER_LAYERS_H
#define PT_COMMON_RENDER_LAYERS_H

#include "common/render/bsdf.h"

typedef struct pt_layers {
    pt_bsdf base;
    float clearcoat;   /* [0, 1] */
    float coat_alpha;  /* >= PT_BSDF_MIN_ALPHA */
    pt_vec3 sheen;     /* colour in [0, 1] */
    float sheen_max;   /* max component of sheen */
    float sheen_rough; /* [0, 1]: the table's coordinate */
    float sheen_alpha; /* >= PT_LAYERS_MIN_SHEEN_ALPHA */
} pt_layers;

/* Charlie's D is degenerate at alpha 0; below this the lobe is this sharp. */
#define PT_LAYERS_MIN_SHEEN_ALPHA 0.0049f /* roughness 0.07 */

/* Fills *l over base. Returns 0 (and the caller should use base alone, the
 * same bits as without the layers) when clearcoat and sheen are both 0. */
int pt_layers_setup(pt_layers *l, const pt_bsdf *base, float clearcoat, float coat_roughness,
                    const float sheen_color[3], float sheen_roughness);

/* As pt_bsdf_eval / pt_bsdf_pdf / pt_bsdf_sample for the layered whole. */
pt_vec3 pt_layers_eval(const pt_layers *l, pt_vec3 wo, pt_vec3 wi, float *pdf);
float pt_layers_pdf(const pt_layers *l, pt_vec3 wo, pt_vec3 wi);
pt_vec3 pt_layers_sample(const pt_layers *l, pt_vec3 wo, const float u[3], pt_vec3 *wi, float *pdf);

/* Pieces for the tests: the white sheen lobe's f x cos, and its albedo. */
float pt_sheen_eval(float alpha, pt_vec3 wo, pt_vec3 wi);
float pt_sheen_albedo(float mu, float roughness);

#endif
