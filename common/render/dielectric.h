/*
 * dielectric.h - glass: the glTF transmission model (KHR_materials_transmission,
 * KHR_materials_ior, KHR_materials_volume's thin/thick switch): its parameters
 * and the dielectric interface's lobe, which the closure (closure.h) puts
 * beside the opaque share.
 *
 * glTF's dielectric is fresnel_mix(ior, mix(diffuse, specular_btdf, T),
 * specular_brdf), linear in the transmission T, so it splits exactly into
 *   (1 - T) x the opaque dielectric  +  T x fresnel_mix(ior, btdf, brdf).
 * The opaque share (with the metal) is a pt_bsdf (bsdf.h) whose dielectric
 * parts are scaled by 1 - T; the transmissive share, weighted (1 - metallic)
 * T, is a dielectric interface with the exact Fresnel equations for the ior
 * (not Schlick's, so a smooth sphere conserves energy exactly), whose
 * transmitted light is tinted by the base colour as the extension says:
 *  - rough: the microfacet BSDF of Walter, Marschner, Li & Torrance 2007,
 *    "Microfacet Models for Refraction through Rough Surfaces" (EGSR), eqs.
 *    20-21, with GGX D and Smith height-correlated G2, sampled with the
 *    distribution of visible normals (Heitz 2018, JCGT 7(4)); the reflect /
 *    refract choice is by the Fresnel of the sampled normal, as pbrt-v4's
 *    DielectricBxDF does. Transmitted radiance is scaled by 1 / eta^2
 *    (Veach 1997, sec. 5.2: radiance, not importance, is carried).
 *  - smooth (alpha below PT_GLASS_SMOOTH_ALPHA, or eta 1): two delta lobes, mirror
 *    reflection with probability F and refraction with 1 - F, weight 1 each
 *    (1 / eta^2 for the refraction). eval and pdf never see them: the
 *    integrator finds lights through them by sampling only.
 *  - thin-walled (KHR_materials_volume absent or thickness 0): the
 *    transmitted direction is the reflected one mirrored through the surface
 *    plane, so light passes without bending (-wo when smooth); one interface's
 *    Fresnel, no 1 / eta^2. The two walls of a real thin sheet are not
 *    modelled.
 * Local shading frame, z = normal, wo on the upper side (wo.z > 0); eta is
 * n_below / n_above. Reciprocal in the sense of Walter's eq. 21 (transmission
 * with the 1 / eta^2 radiance scaling). Thread-safe (no state).
 */
#ifndef PT_COMMON_RENDER_DIELECTRIC_H
#define PT_COMMON_RENDER_DIELECTRIC_H

#include "common/math/vec.h"
#include "common/render/bsdf.h"

/* Below this GGX alpha (roughness about 0.03) the interface is smooth. */
#define PT_GLASS_SMOOTH_ALPHA 1e-3f

typedef struct pt_glass {
    pt_bsdf base; /* the opaque share: (1 - T) of the dielectric, and the metal */
    pt_vec3 tint; /* base colour: tints transmitted light (glTF specular_btdf) */
    float weight; /* (1 - metallic) T: the dielectric interface's share */
    float pick;   /* probability that sampling picks the interface */
    float eta;    /* n_below / n_above across the surface (wo above) */
    float alpha;  /* GGX alpha, 0 when smooth */
    int thin;     /* thin-walled: transmission does not bend */
    /* KHR_materials_dispersion (pt_glass_disperse): 1, and eta per colour
     * channel in eta3 (eta unused by the interface); 0 from pt_glass_setup. */
    int disp;
    float eta3[3];
    /* KHR_materials_iridescence (pt_glass_film): the film's strength (0:
     * none, from pt_glass_setup), index and thickness (nm), and the F0 of
     * the glass under it. */
    float film[3];
    float film_f0;
} pt_glass;

/* Builds the glass from glTF parameters (as pt_bsdf_setup) plus the
 * transmission factor in [0, 1], the relative ior eta (the caller passes
 * ior or 1 / ior by the side the ray arrives from; 0 reflects everything)
 * and thin. */
pt_glass pt_glass_setup(pt_vec3 base_color, float metallic, float roughness, float specular,
                        pt_vec3 specular_color, float transmission, float eta, int thin);

/* Makes g's interface dispersive (KHR_materials_dispersion): ior_n is the
 * material's ior at each channel's wavelength (pt_dispersion_ior), and the
 * caller's side decides eta as for pt_glass_setup (inverted: 1 / ior). A
 * thin wall or an eta of 0 or 1 stays as it is. */
void pt_glass_disperse(pt_glass *g, const float ior_n[3], int inverted);

/* Puts a thin film (thinfilm.h) over g's interface: its Fresnel becomes
 * mix(F, F_film, strength) per channel for reflection and one minus that
 * for transmission; F0 of the glass under the film is ((ior - 1) / (ior +
 * 1))^2. The caller applies it where the ray arrives from outside; a
 * dispersive interface keeps no film. */
void pt_glass_film(pt_glass *g, float strength, float eta_film, float d_nm, float ior);

/* The ior at the wavelengths that stand for the R, G and B channels (611,
 * 549 and 464 nm: the Rec.709 primaries' dominant wavelengths) from the
 * ior at 587.56 nm (the d line) and the extension's dispersion 20 / V_d:
 * n(lambda) = max(n_d + (n_d - 1) / V_d (523655 / lambda^2 - 1.5168), 1)
 * (KHR_materials_dispersion, a Cauchy fit through the Abbe number). */
void pt_dispersion_ior(float ior, float dispersion, float out[3]);

/* The dielectric interface lobe: glass.weight x fresnel_mix(ior, btdf, brdf).
 * Dispersive (disp): each channel has its own eta (eta3); sampling picks a
 * channel with probability 1/3 (u[0] split in three), and the lobe's value
 * and density are the channels' own, the density their mean, so that a
 * refraction (which takes one channel's direction) carries that channel
 * alone. Light that later meets another dispersive interface keeps only
 * what that interface's pick shares with it. */
typedef struct pt_dielectric_lobe {
    pt_vec3 tint; /* tints transmitted light */
    float weight; /* (1 - metallic) T */
    float eta;    /* n_below / n_above */
    float alpha;  /* GGX alpha, 0 when smooth (two delta lobes) */
    int thin;
    int disp; /* dispersive: eta3 per channel */
    float eta3[3];
    float film[3]; /* strength (0: no film), index, thickness (nm) */
    float film_f0;
} pt_dielectric_lobe;

pt_dielectric_lobe pt_glass_interface(const pt_glass *g);

/* f |cos wi| of the rough interface, wi on either side, and *share = prob x
 * the pdf of its sampling at wi; 0 when smooth (delta lobes are not
 * evaluated). */
pt_vec3 pt_dielectric_eval(const pt_dielectric_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob,
                           float *share);

/* What pt_dielectric_sample made. */
enum { PT_DIELECTRIC_NONE = 0, PT_DIELECTRIC_DIR = 1, PT_DIELECTRIC_DELTA = 2 };

/* Samples wi from u: u[0] in [0,1) (rescaled to this lobe by the caller)
 * picks reflection or refraction, u[1..2] the microfacet normal. Returns
 * PT_DIELECTRIC_DIR for a direction of the rough interface (the caller
 * weighs it by the closure's eval and pdf), PT_DIELECTRIC_DELTA for a smooth
 * interface's delta lobe, with *weight = its f cos / pdf within a closure that
 * picks this lobe with probability prob and *pdf = prob x the lobe's discrete
 * probability (not a density, not for MIS), PT_DIELECTRIC_NONE when impossible. */
int pt_dielectric_sample(const pt_dielectric_lobe *l, pt_vec3 wo, const float u[3], float prob,
                         pt_vec3 *wi, pt_vec3 *weight, float *pdf);

/* The expected weight of a smooth thin wall's straight-through delta lobe
 * (wi = -wo): weight x tint x (1 - F(wo.z)), the filmed Fresnel per channel
 * where the lobe has a film; what pt_dielectric_sample's transmission
 * returns times the probability that it takes it. A shadow ray may cross
 * such a wall with this factor (it is a partial transparency along the
 * ray). Zero when the lobe is rough, not thin, dispersive or wo.z <= 0. */
pt_vec3 pt_dielectric_straight(const pt_dielectric_lobe *l, pt_vec3 wo);

/* A smooth thick interface's delta refraction (manifold.h): the refracted
 * direction *wi and the lobe's expected weight along it, weight x tint x
 * (1 - F(wo.z)) / eta^2 (what pt_dielectric_sample returns when it takes
 * the refraction, times the probability 1 - F that it does, which goes to
 * *take). Zero when the lobe is rough, thin, dispersive or filmed, or
 * under total internal reflection. */
pt_vec3 pt_dielectric_refracted(const pt_dielectric_lobe *l, pt_vec3 wo, pt_vec3 *wi, float *take);

/* A smooth interface's delta reflection, thin or thick (manifold NEE's
 * reflection chains, render.c): the mirrored direction *wi and the lobe's
 * expected weight along it, weight x F(wo.z) (what pt_dielectric_sample
 * returns when it takes the reflection, times the probability F that it
 * does, which goes to *take). Zero when the lobe is rough, dispersive or
 * filmed (a reflectance per channel), or F is 0. */
pt_vec3 pt_dielectric_reflected(const pt_dielectric_lobe *l, pt_vec3 wo, pt_vec3 *wi, float *take);

/* Exact Fresnel reflectance of unpolarised light at a dielectric interface,
 * cos_i >= 0 on the incident side, eta = n_transmitted / n_incident; 1 under
 * total internal reflection. */
float pt_fresnel_dielectric(float cos_i, float eta);

#endif
