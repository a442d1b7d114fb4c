/*
 * thinfilm.h - KHR_materials_iridescence: the Fresnel reflectance of a thin
 * dielectric film over a base, after Belcour & Barla 2017 ("A Practical
 * Extension to Microfacet Theory for the Modeling of Varying Iridescence",
 * ACM TOG 36(4)), in the approximation the extension gives (its section
 * "Iridescence Fresnel"), and the iridescent specular and diffuse lobes of
 * the glTF base for the material closure (closure.h).
 *
 * The film (index eta_film, thickness d in nanometres) lies between the
 * outside (index eta_out, 1 for air) and a base of normal-incidence
 * reflectance f0 (per channel, its index taken as (1 + sqrt f0) / (1 -
 * sqrt f0), no extinction). Light reflected at the film's top and after
 * k >= 1 trips through it sums to Airy's series, whose reflectance is
 * R(delta) = C0 + sum_m 2 C_m cos(m delta + m phi) in the phase delta = 2 pi
 * OPD / lambda (OPD = 2 eta_film d cos theta_2); Belcour & Barla integrate
 * each term against the CIE matching functions analytically (Gaussian fits
 * in wavenumber, their Fourier transforms evaluated at m OPD) and keep
 * m <= 2. The extension maps the constant C0 to grey and the harmonics
 * through XYZ to linear Rec.709.
 *
 * Lobes: the GGX specular lobe with F = mix(Schlick(f0, f90), F_film(f0),
 * strength) at wo.h, and the Lambert lobe weighted by 1 - mix(F_d, max
 * F_film, strength) at min(cos wo, cos wi) (F_d the dielectric's scalar
 * Schlick, bsdf.h): the extension's rgb_mix, reciprocal as the base is.
 * Sampling as the base's lobes. Thread-safe (no state).
 */
#ifndef PT_COMMON_RENDER_THINFILM_H
#define PT_COMMON_RENDER_THINFILM_H

#include "common/math/vec.h"
#include "common/render/aniso.h"
#include "common/render/bsdf.h"

/* The film's reflectance (linear Rec.709, each >= 0) at cos theta_1 =
 * cos1 in (0, 1] on the outside; (1, 1, 1) past total internal reflection
 * into the film. */
pt_vec3 pt_thinfilm_fresnel(float eta_out, float eta_film, float cos1, float d_nm, pt_vec3 f0);

/* The same before the colour step, for a grey base (f0.x used): the CIE
 * XYZ of the film's reflectance spectrum under the extension's matching
 * functions (C0 x (1, 1, 1) plus the harmonics m = 1, 2), and C0 in *dc. */
pt_vec3 pt_thinfilm_xyz(float eta_out, float eta_film, float cos1, float d_nm, float f0, float *dc);

/* The film of one shading point. */
typedef struct pt_irid {
    float strength; /* iridescenceFactor x texture, in [0, 1] */
    float eta;      /* the film's index, iridescenceIor */
    float d_nm;     /* thickness, nanometres, >= 0 */
} pt_irid;

typedef struct pt_irid_specular_lobe {
    pt_specular_lobe s;
    pt_irid film;
} pt_irid_specular_lobe;

/* The anisotropic GGX lobe (aniso.h, KHR_materials_anisotropy) under the
 * film: its D and G2, the film's Fresnel as the isotropic lobe's. */
typedef struct pt_irid_aniso_lobe {
    pt_aniso_lobe a;
    pt_irid film;
} pt_irid_aniso_lobe;

typedef struct pt_irid_diffuse_lobe {
    pt_diffuse_lobe d;
    pt_vec3 f0; /* the base's F0, under the film */
    pt_irid film;
} pt_irid_diffuse_lobe;

/* f cos at wi and *share = prob x the lobe's sampling pdf at wi, as
 * pt_specular_eval and pt_diffuse_eval (bsdf.h) with the film's Fresnel. */
pt_vec3 pt_irid_specular_eval(const pt_irid_specular_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob,
                              float *share);
pt_vec3 pt_irid_diffuse_eval(const pt_irid_diffuse_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob,
                             float *share);
/* pt_irid_diffuse_eval on the far side (pt_diffuse_transmit_eval's
 * geometry: wi below, the cosine min(wo.z, -wi.z)); sampled by
 * pt_diffuse_transmit_sample. */
pt_vec3 pt_irid_transmit_eval(const pt_irid_diffuse_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob,
                              float *share);
/* The same for the anisotropic lobe (pt_aniso_eval with the film's
 * Fresnel); sampled by pt_aniso_sample. */
pt_vec3 pt_irid_aniso_eval(const pt_irid_aniso_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob,
                           float *share);

#endif
