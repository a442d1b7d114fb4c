/*
 * closure.h - the material closure: the BSDF at one shading point as a small
 * list of weighted lobes, after pbrt-v4's BSDF/BxDF split and Cycles' closure
 * lists. The integrator builds one per shading point, for its wo, and asks it
 * for eval, pdf and sample; it never sees a lobe.
 *
 * Lobes (each a file with its setup, eval and sample): diffuse and specular
 * (bsdf.h, the glTF metallic-roughness base), the dielectric interface
 * (dielectric.h, glass), sheen and clearcoat (layers.h), the base's lobes
 * under an iridescent film (thinfilm.h), the anisotropic GGX lobe (aniso.h).
 * Adding a lobe is its
 * file, a kind below with its case in closure.c's lobe_eval and sample
 * switch, and its entry in the builder (pt_closure_add_*).
 *
 * Structure. The lobes sit in groups, innermost first: the base's lobes
 * (specular, diffuse), then the interface beside the base, then the layers
 * over both (coat, sheen). Sampling walks the groups from the outermost: u[0]
 * picks a lobe of the group by its probability, or the group inside with the
 * group's `below` probability, u[0] rescaled to what it picked (one number
 * picks at every level, as a one-sample MIS mixture should). The pdf of a
 * group is its lobes' shares (each lobe's probability times its density) plus
 * below x the inner group's pdf; lobes on a normal of their own (a coat with
 * clearcoatNormalTexture) are added last. The value is a fold from the
 * innermost lobe outwards, f = f_lobe + below_lobe(wo, wi) x f_inside: 1 for
 * lobes side by side, 1 - Fc(wo) under a coat, the sheen's albedo scaling
 * under a sheen (layers.h). The probabilities and every term that depends on
 * wo alone are computed once, when the closure is built.
 *
 * pt_closure_sample returns the whole closure's f cos / pdf at the sampled
 * direction, not the picked lobe's, so NEE and BSDF sampling weigh one
 * estimator (Veach 1997, ch. 9). A sample fails (pdf 0) where the picked
 * lobe's direction is impossible or the pdf of its group or of any group
 * around it is 0. A delta lobe (a smooth interface) is sampled only, never
 * evaluated; the groups around it scale its weight by their lobes' below
 * factors at the sampled direction and its probability by their below
 * probabilities.
 *
 * Directions in the local shading frame (z = the normal), unit length,
 * pointing away from the surface; wo.z > 0 or the closure is empty (eval and
 * sample give 0). Plain data on the stack; thread-safe (no state).
 */
#ifndef PT_COMMON_RENDER_CLOSURE_H
#define PT_COMMON_RENDER_CLOSURE_H

#include <stdint.h>

#include "common/math/vec.h"
#include "common/render/aniso.h"
#include "common/render/bsdf.h"
#include "common/render/dielectric.h"
#include "common/render/layers.h"
#include "common/render/thinfilm.h"

#define PT_CLOSURE_MAX_LOBES 6
#define PT_CLOSURE_MAX_GROUPS 3

enum {
    PT_LOBE_DIFFUSE,
    PT_LOBE_SPECULAR,
    PT_LOBE_DIELECTRIC,
    PT_LOBE_SHEEN,
    PT_LOBE_COAT,
    PT_LOBE_SPECULAR_IRID, /* thinfilm.h: the base's lobes under an iridescent film */
    PT_LOBE_DIFFUSE_IRID,
    PT_LOBE_SPECULAR_ANISO,        /* aniso.h: the base's GGX lobe, anisotropic */
    PT_LOBE_DIFFUSE_TRANSMIT,      /* bsdf.h: Lambertian transmission to the far side */
    PT_LOBE_SPECULAR_ANISO_IRID,   /* thinfilm.h: the anisotropic lobe under the film */
    PT_LOBE_DIFFUSE_TRANSMIT_IRID, /* thinfilm.h: the transmitted diffuse under the film */
};

typedef struct pt_lobe {
    uint32_t kind; /* PT_LOBE_* */
    uint32_t own;  /* on a normal of its own: its pdf share is added after the group's */
    float prob;    /* probability that sampling picks it within its group, at wo */
    union {
        pt_diffuse_lobe diffuse;
        pt_specular_lobe specular;
        pt_dielectric_lobe dielectric;
        pt_sheen_lobe sheen;
        pt_coat_lobe coat;
        pt_irid_specular_lobe irid_specular;
        pt_irid_diffuse_lobe irid_diffuse;
        pt_aniso_lobe aniso;
        pt_irid_aniso_lobe irid_aniso;
    } p;
} pt_lobe;

typedef struct pt_closure_group {
    uint32_t first, n; /* lobes [first, first + n), outermost first */
    float below;       /* probability of sampling the group inside; 0 for the innermost */
} pt_closure_group;

typedef struct pt_closure {
    pt_vec3 wo;
    uint32_t n_lobes, n_groups; /* no groups: nothing scatters */
    int dead;                   /* wo is below a lobe's normal: stays empty */
    /* The base is normal-mapped and the coat lies on the surface's own
     * (interpolated) normal (pt_closure_coat_mirror): the coat alone is a
     * mirror to the reflection chains, which solve for that normal. */
    int coat_mirror;
    pt_closure_group group[PT_CLOSURE_MAX_GROUPS]; /* [0] the innermost */
    pt_lobe lobe[PT_CLOSURE_MAX_LOBES];
} pt_closure;

/* Starts an empty closure for wo. */
void pt_closure_init(pt_closure *c, pt_vec3 wo);

/* The builder: each adds a group around what is there. */
/* The glTF base's lobes (bsdf.h): specular, diffuse; innermost. */
void pt_closure_add_base(pt_closure *c, const pt_bsdf *b);
/* The same under a thin film (thinfilm.h, KHR_materials_iridescence;
 * film->strength > 0). */
void pt_closure_add_base_irid(pt_closure *c, const pt_bsdf *b, const pt_irid *film);
/* The base with its GGX lobe anisotropic (aniso.h, KHR_materials_anisotropy):
 * strength in [0, 1], the direction (c, s) in the shading frame. */
void pt_closure_add_base_aniso(pt_closure *c, const pt_bsdf *b, float strength, float dc, float ds);
/* Both: the film over the anisotropic GGX lobe and over the diffuse one
 * (KHR_materials_iridescence with KHR_materials_anisotropy). */
void pt_closure_add_base_irid_aniso(pt_closure *c, const pt_bsdf *b, const pt_irid *film,
                                    float strength, float dc, float ds);
/* The base with a share of its diffuse transmitted (bsdf.h,
 * KHR_materials_diffuse_transmission): reflected albedo b's diffuse x
 * (1 - dt), transmitted albedo `through` (dt x colour x (1 - metallic)). */
void pt_closure_add_base_dt(pt_closure *c, const pt_bsdf *b, float dt, pt_vec3 through);
/* Both: the diffuse shares of pt_closure_add_base_dt beside the
 * anisotropic GGX lobe of pt_closure_add_base_aniso (a material with
 * KHR_materials_diffuse_transmission and KHR_materials_anisotropy). */
void pt_closure_add_base_dt_aniso(pt_closure *c, const pt_bsdf *b, float dt, pt_vec3 through,
                                  float strength, float dc, float ds);
/* Either under a film too (KHR_materials_iridescence): every lobe of the
 * base takes the film's Fresnel, the transmitted diffuse as the reflected
 * one (pt_irid_transmit_eval). aniso 0: the GGX lobe isotropic (strength,
 * dc, ds unread). */
void pt_closure_add_base_dt_irid(pt_closure *c, const pt_bsdf *b, float dt, pt_vec3 through,
                                 const pt_irid *film, int aniso, float strength, float dc,
                                 float ds);
/* Glass (dielectric.h): its opaque share as the base, then the interface
 * beside it; in place of pt_closure_add_base. */
void pt_closure_add_glass(pt_closure *c, const pt_glass *g);
/* Clearcoat and sheen (layers.h) over what is there. */
void pt_closure_add_layers(pt_closure *c, const pt_layers *l);
/* Marks the closure's coat (pt_closure_add_layers, before or after), given
 * its own normal (pt_layers_coat_normal), as lying on the surface's
 * interpolated normal over a normal-mapped base
 * (KHR_materials_clearcoat without a clearcoatNormalTexture): the chains'
 * mirror is then that coat's lobe, reflected about its normal, and the
 * base's lobes, on the map's normal, are none (pt_closure_mirrored). */
void pt_closure_coat_mirror(pt_closure *c);

/* f(wo, wi) |cos wi| and the pdf pt_closure_sample gives wi (solid angle;
 * delta lobes excluded). */
pt_vec3 pt_closure_eval(const pt_closure *c, pt_vec3 wi, float *pdf);
float pt_closure_pdf(const pt_closure *c, pt_vec3 wi);

/* Samples wi from u (3 numbers in [0,1): u[0] picks the lobe, u[1..2] the
 * direction). Returns f cos / pdf and sets *wi, *pdf; *delta (may be NULL
 * when the closure has no delta lobe) is 1 when a delta lobe was taken, and
 * then *pdf is its discrete probability. An impossible sample returns zero
 * with *pdf 0. */
pt_vec3 pt_closure_sample(const pt_closure *c, const float u[3], pt_vec3 *wi, float *pdf,
                          int *delta);

/* The expected weight of the closure's straight-through delta transmission
 * (wi = -wo): what pt_closure_sample returns when it takes that lobe, times
 * the probability that it does - a smooth thin-walled interface's
 * pt_dielectric_straight, times below(wo, -wo) of every lobe in the groups
 * around it. *smooth (may be NULL) is 1 when the closure has such a lobe.
 * Zero without one (opaque, rough or thick glass). */
pt_vec3 pt_closure_straight(const pt_closure *c, int *smooth);

/* The expected weight of the closure's delta refraction through a smooth
 * thick interface (manifold next-event estimation, render.c): what
 * pt_closure_sample returns when it takes the refraction, times the
 * probability that it does, which goes to *take; the refracted direction
 * in *wi. Only for a closure of one group (no coat or sheen around the
 * glass): zero otherwise, and without such a lobe. */
pt_vec3 pt_closure_refracted(const pt_closure *c, pt_vec3 *wi, float *take);

/* The same for the closure's delta reflection off a smooth interface, thin
 * or thick (pt_dielectric_reflected), for the reflection chains. */
pt_vec3 pt_closure_reflected(const pt_closure *c, pt_vec3 *wi, float *take);

/* Its GGX lobes at PT_BSDF_MIN_ALPHA (glTF roughness up to about 0.03: the
 * base's, and a coat's on the base's normal; under pt_closure_coat_mirror
 * the coat's alone, on its own normal), taken as the mirror they
 * stand for: render.c's reflection chains, which deliver the light such a
 * lobe reflects onto a rough vertex. The expected weight of that delta
 * reflection (each lobe's Fresnel at wo.z, its f cos integrated over wi as
 * alpha goes to 0, times the below factors of the lobes around it at the
 * mirrored direction), the probability that sampling picks them in *take,
 * the mirrored direction (about the mirror lobes' normal) in *wi. Zero
 * without one. */
pt_vec3 pt_closure_mirrored(const pt_closure *c, pt_vec3 *wi, float *take);

/* The share of pt_closure_eval's f cos at wi that those mirror lobes give
 * (under the same below factors), and the whole into *f (may be NULL). */
pt_vec3 pt_closure_eval_mirror(const pt_closure *c, pt_vec3 wi, pt_vec3 *f);

/* 1 when the closure has such a lobe, 2 when it has no other. */
int pt_closure_has_mirror(const pt_closure *c);

/* The closure's albedo for the render passes (the albedo pass, a guide for
 * the denoiser, not an energy: Cycles' denoising albedo) into *albedo: the
 * sum of its lobes' colours (a diffuse lobe's albedo, a GGX lobe's F0, the
 * interface's tint x weight, the sheen's colour; the colourless coat adds
 * none). Returns 1 when the closure is non-specular, so the pass is read
 * here: the lobes that are diffuse or rough (GGX alpha above
 * PT_CLOSURE_ROUGH_ALPHA) hold over a quarter of the probability of being
 * sampled (Cycles, film_write_denoising_features_surface: roughness^2 above
 * 0.075^2, non-specular weight above a quarter); else 0, and a path looks
 * through it (a mirror, smooth glass) to the next surface. */
#define PT_CLOSURE_ROUGH_ALPHA 0.075f
int pt_closure_albedo(const pt_closure *c, pt_vec3 *albedo);

#endif
