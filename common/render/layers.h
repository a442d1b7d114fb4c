/*
 * layers.h - clearcoat and sheen layered over the glTF base or glass
 * (KHR_materials_clearcoat, KHR_materials_sheen): their parameters and
 * their two lobes, which the closure (closure.h) puts over the rest of the
 * material (f_base below: the base, or glass with its transmission).
 *
 * The layering is the extensions' own (their READMEs, "Layering" and
 * "Albedo-scaling"), outermost first:
 *   f = Fc(wo) f_coat + (1 - Fc(wo)) [ f_sheen + S(wo, wi) f_base ],
 *   Fc(wo) = clearcoat x Schlick(F0 = 0.04, wo.z)   (a coat of ior 1.5),
 *   S(wo, wi) = min(1 - max(sheen) E(wo.z), 1 - max(sheen) E(wi.z)),
 *   S(wo, wi) = 1 - max(sheen) E(wo.z) for wi below the base (light the
 *   base transmits crosses the sheen once, along wo),
 * with f_coat a GGX reflection without Fresnel (alpha = clearcoatRoughness^2,
 * Smith height-correlated G2) on the shading normal, or on the coat's own
 * normal (clearcoatNormalTexture) where pt_layers_coat_normal gave one, and
 * f_sheen = sheenColor D_charlie V_ashikhmin: the "Charlie" distribution of
 * Estevez & Kulla 2017 ("Production Friendly Microfacet Sheen BRDF"),
 * alpha = sheenRoughness^2 (>= PT_LAYERS_MIN_SHEEN_ALPHA), with the
 * visibility 1 / (4 (zi + zo - zi zo)) of Neubelt & Pettineo 2013 (as in
 * Filament). E(mu) is that sheen lobe's directional albedo for white colour,
 * tabulated by numerical quadrature (32 x 32 over mu and roughness,
 * compiled in: sheen_table.h; read bilinearly). That visibility lets a sharp
 * sheen seen at grazing reflect more than it receives (E > 1): there the
 * sheen lobe is divided by E(wo.z) and E is read as min(E, 1). The whole never reflects
 * more than it gets: each term's albedo is at most what the layer above
 * leaves.
 *
 * Sampling picks coat, sheen or base with u[0] by the weights Fc(wo),
 * (1 - Fc) max(sheen) E(wo.z), (1 - Fc)(1 - max(sheen) E(wo.z)); the coat by
 * GGX visible normals, the sheen uniformly over the hemisphere, the base by
 * its own lobes with u[0] rescaled (closure.h). Each lobe's eval gives its
 * f cos, its share of the one-sample MIS pdf, and the factor it puts on the
 * lobes under it (1 - Fc(wo) for the coat, S(wo, wi) for the sheen). Local
 * frame as bsdf.h.
 *
 * With a coat normal nc (in that local frame, z = the base's normal): Fc and
 * the coat lobe read wo and wi in nc's frame (Fc(wo) = clearcoat x
 * Schlick(wo.nc)); the sheen and base terms keep the base normal. Each term
 * is zero where wi is below its own normal's hemisphere, so a direction may
 * be valid for the coat alone (wi.z <= 0 < wi.nc); the caller keeps it above
 * the geometric surface. A sampled lobe's direction below its own normal's
 * hemisphere is a failed sample, so the mixture pdf stays the true density.
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
    int coat_own;      /* the coat has its own normal: coat_fr.n */
    pt_frame coat_fr;
} pt_layers;

/* Charlie's D is degenerate at alpha 0; below this the lobe is this sharp. */
#define PT_LAYERS_MIN_SHEEN_ALPHA 0.0049f /* roughness 0.07 */

/* Fills *l over base. Returns 0 (and the caller should use base alone, the
 * same bits as without the layers) when clearcoat and sheen are both 0. */
int pt_layers_setup(pt_layers *l, const pt_bsdf *base, float clearcoat, float coat_roughness,
                    const float sheen_color[3], float sheen_roughness);

/* Gives the coat its own unit normal n, in the local frame of wo and wi
 * (the base's); n.wo > 0 is the caller's (render.c bends it as the base's
 * mapped normal). Without this call the coat shares the base's normal. */
void pt_layers_coat_normal(pt_layers *l, pt_vec3 n);

/* The coat lobe at one wo: clearcoat x GGX reflection without Fresnel. */
typedef struct pt_coat_lobe {
    float fc;    /* Fc(wo): the coat's weight; the lobes under it get 1 - fc */
    float alpha; /* >= PT_BSDF_MIN_ALPHA */
    int own;     /* on its own normal fr.n, with wo in that frame */
    pt_frame fr;
    pt_vec3 wo;
} pt_coat_lobe;

/* The sheen lobe at one wo. */
typedef struct pt_sheen_lobe {
    pt_vec3 color;
    float color_max;
    float rough;  /* the albedo table's coordinate */
    float alpha;  /* >= PT_LAYERS_MIN_SHEEN_ALPHA */
    float keep_o; /* 1 - max(colour) E(wo.z): S's wo half */
    float norm;   /* 1 / E(wo.z) where E(wo.z) > 1, else 1 */
} pt_sheen_lobe;

/* The lobes of l at wo and the probabilities of sampling the coat, the sheen
 * and what lies under them (*pc + *ps + *pb = 1 up to rounding; a lobe l
 * lacks has probability 0). Returns 0 when wo is not above the base's
 * normal or the coat's: then nothing scatters. */
int pt_layers_lobes(const pt_layers *l, pt_vec3 wo, pt_coat_lobe *coat, pt_sheen_lobe *sheen,
                    float *pc, float *ps, float *pb);

/* f cos at wi, *share = prob x the lobe's sampling pdf at wi, and *below the
 * factor on the lobes under it at (wo, wi). wo is the one the lobe was made
 * for. */
pt_vec3 pt_coat_eval(const pt_coat_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob, float *share,
                     float *below);
pt_vec3 pt_sheen_eval(const pt_sheen_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob, float *share,
                      float *below);
/* A direction from u[1..2]; 1 when it lies above the lobe's own normal. */
int pt_coat_sample(const pt_coat_lobe *l, pt_vec3 wo, const float u[3], pt_vec3 *wi);
int pt_sheen_sample(const float u[3], pt_vec3 *wi);

/* Pieces for the tests: the white sheen lobe's f x cos, and its albedo. */
float pt_sheen_charlie(float alpha, pt_vec3 wo, pt_vec3 wi);
float pt_sheen_albedo(float mu, float roughness);

#endif
