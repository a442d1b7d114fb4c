/*
 * aniso.h - KHR_materials_anisotropy: the glTF base's GGX lobe stretched
 * along a direction of the surface, for the material closure (closure.h).
 *
 * The extension (its "Anisotropy" section): alpha = roughness^2 across the
 * direction and alpha_t = mix(alpha, 1, strength^2) along it; the direction
 * is the tangent frame's (cos rho, sin rho) for the rotation rho, or the
 * texture's RG in [-1, 1] rotated by rho, its strength times the texture's
 * B. The distribution is the anisotropic GGX / Trowbridge-Reitz D with the
 * height-correlated Smith masking (Heitz 2014, "Understanding the
 * Masking-Shadowing Function in Microfacet-Based BRDFs", JCGT 3(2), eqs. 85
 * and 99), sampled by its visible normals (Heitz 2018, "Sampling the GGX
 * Distribution of Visible Normals", JCGT 7(4), which stretches by both
 * alphas). Schlick's Fresnel from f0 to f90 as the isotropic lobe.
 *
 * Directions in the shading frame (z = normal); the lobe holds the
 * direction there as (c, s, 0) and works in the frame turned by it, where
 * x runs along the direction. With alpha_x = alpha_y it is the isotropic
 * lobe (bsdf.h). Thread-safe (no state).
 */
#ifndef PT_COMMON_RENDER_ANISO_H
#define PT_COMMON_RENDER_ANISO_H

#include "common/math/vec.h"
#include "common/render/bsdf.h"

typedef struct pt_aniso_lobe {
    pt_vec3 f0;
    float f90;
    float ax, ay; /* GGX alphas along the direction and across it, >= PT_BSDF_MIN_ALPHA */
    float c, s;   /* the direction in the shading frame: (c, s, 0), unit */
} pt_aniso_lobe;

/* The base's GGX lobe made anisotropic: strength in [0, 1], the direction
 * (c, s) in the shading frame (normalised here; (1, 0) when it is 0). */
pt_aniso_lobe pt_aniso_setup(const pt_bsdf *b, float strength, float c, float s);

/* Anisotropic GGX D of the microfacet normal m given in the lobe's frame
 * (x along the direction); 0 below the surface. */
float pt_aniso_d(pt_vec3 m, float ax, float ay);

/* f cos at wi and *share = prob x the sampling pdf at wi; 0 where wo or wi
 * is not above the surface. */
pt_vec3 pt_aniso_eval(const pt_aniso_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob, float *share);

/* pt_aniso_eval without its Fresnel: the scalar F multiplies (D G2 wi.z /
 * (4 wo.z), 0 where eval gives 0), with *c the cosine of wo to the half
 * vector that the Fresnel reads (a thin film's too: thinfilm.h). */
float pt_aniso_geom(const pt_aniso_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob, float *share,
                    float *c);

/* A direction from u[1..2]: the reflection of wo about a visible normal;
 * 1 when it lies above the surface, else 0. */
int pt_aniso_sample(const pt_aniso_lobe *l, pt_vec3 wo, const float u[3], pt_vec3 *wi);

#endif
