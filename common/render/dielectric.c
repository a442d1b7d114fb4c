/*
 * dielectric.c - glass (dielectric.h): its parameters, and the rough or
 * smooth dielectric interface's lobe.
 *
 * The rough interface follows Walter et al. 2007 in the form of pbrt-v4's
 * DielectricBxDF (Pharr, Jakob & Humphreys, "Physically Based Rendering",
 * 4th ed., sec. 9.7): with wo above and eta = n_below / n_above,
 *  reflection (wi.z > 0): wm = normalize(wo + wi),
 *    f cos_i = F D G2 / (4 cos_o),  pdf = Dv(wm) / (4 wo.wm) F;
 *  transmission (wi.z < 0): wm = normalize(wo + eta wi), turned up,
 *    f cos_i = (1 - F) D G2 |wi.wm wo.wm| / (cos_o (wi.wm + wo.wm / eta)^2) / eta^2,
 *    pdf = Dv(wm) |wi.wm| / (wi.wm + wo.wm / eta)^2 (1 - F),
 * F = F(wo.wm), Dv the visible-normal density (bsdf.h: pt_ggx_vndf_pdf), and
 * microfacets that face away from wo or wi contribute nothing. G2 is Smith's
 * height-correlated masking-shadowing (Heitz 2014, eq. 99) with |cos|.
 */
#include "common/render/dielectric.h"

#include <math.h>

#include "common/render/thinfilm.h"

static inline float clamp01(float x)
{
    return x < 0.0f ? 0.0f : (x > 1.0f ? 1.0f : x);
}

float pt_fresnel_dielectric(float cos_i, float eta)
{
    cos_i = clamp01(cos_i);
    float s2 = (1.0f - cos_i * cos_i) / (eta * eta);
    if (!(s2 < 1.0f))
        return 1.0f; /* total internal reflection (or a bad eta) */
    float ct = sqrtf(1.0f - s2);
    float rs = (cos_i - eta * ct) / (cos_i + eta * ct);
    float rp = (eta * cos_i - ct) / (eta * cos_i + ct);
    return 0.5f * (rs * rs + rp * rp);
}

pt_glass pt_glass_setup(pt_vec3 base_color, float metallic, float roughness, float specular,
                        pt_vec3 specular_color, float transmission, float eta, int thin)
{
    pt_glass g;
    g.base = pt_bsdf_setup(base_color, metallic, roughness, specular, specular_color);
    /* pt_bsdf_setup's clamps, repeated for the shares. */
    metallic = clamp01(metallic == metallic ? metallic : 0.0f);
    roughness = clamp01(roughness == roughness ? roughness : 1.0f);
    specular = clamp01(specular == specular ? specular : 1.0f);
    transmission = clamp01(transmission == transmission ? transmission : 0.0f);
    pt_vec3 base = pt_v3(clamp01(base_color.x), clamp01(base_color.y), clamp01(base_color.z));
    /* Scale the opaque dielectric by 1 - T: its diffuse, and its share of
     * the GGX lobe's F0 and F90 (bsdf.c: F0 = mix(s f0_d, base, m), F90 =
     * (1 - m) s + m). The diffuse's own Fresnel weight is a ratio and stays. */
    float keep = 1.0f - transmission;
    float dm = (1.0f - metallic) * keep;
    g.base.diffuse = pt_v3_scale(g.base.diffuse, keep);
    pt_vec3 f0d = pt_v3(fminf(fmaxf(specular_color.x * 0.04f, 0.0f), 1.0f) * specular,
                        fminf(fmaxf(specular_color.y * 0.04f, 0.0f), 1.0f) * specular,
                        fminf(fmaxf(specular_color.z * 0.04f, 0.0f), 1.0f) * specular);
    g.base.f0 = pt_v3_add(pt_v3_scale(f0d, dm), pt_v3_scale(base, metallic));
    g.base.spec_weight = dm * specular + metallic;
    g.tint = base;
    g.weight = (1.0f - metallic) * transmission;
    g.eta = eta >= 0.0f && isfinite(eta) ? eta : 1.5f; /* 0: F = 1 */
    float a = roughness * roughness;
    /* At eta 1 the interface does nothing (F = 0, no bending) whatever its
     * roughness, and Walter's half vector wo + eta wi is 0 for the one
     * direction light takes: treat it as smooth, as pbrt-v4 does. */
    g.alpha = a < PT_GLASS_SMOOTH_ALPHA || g.eta == 1.0f ? 0.0f : a;
    g.thin = thin != 0;
    g.disp = 0;
    g.eta3[0] = g.eta3[1] = g.eta3[2] = g.eta;
    g.film[0] = g.film[1] = g.film[2] = 0.0f;
    g.film_f0 = 0.0f;
    int opaque = pt_v3_max_comp(g.base.diffuse) > 0.0f || g.base.spec_weight > 0.0f;
    if (!(g.weight > 0.0f))
        g.pick = 0.0f;
    else if (!opaque)
        g.pick = 1.0f;
    else
        g.pick = fminf(fmaxf(g.weight, 0.1f), 0.9f);
    return g;
}

/* s(w) = |z| sqrt(1 + a^2 tan^2) (bsdf.c), for G2 with |cos|. */
static inline float lambda_root(pt_vec3 w, float alpha)
{
    return sqrtf(w.z * w.z + alpha * alpha * (w.x * w.x + w.y * w.y));
}

/* G2(wo, wi) = 2 |zo| |zi| / (|zi| s_o + |zo| s_i). */
static inline float g2(pt_vec3 wo, pt_vec3 wi, float alpha)
{
    float zo = fabsf(wo.z), zi = fabsf(wi.z);
    float den = zi * lambda_root(wo, alpha) + zo * lambda_root(wi, alpha);
    return den > 0.0f ? 2.0f * zo * zi / den : 0.0f;
}

static inline pt_vec3 reflect(pt_vec3 w, pt_vec3 m)
{
    return pt_v3_sub(pt_v3_scale(m, 2.0f * pt_v3_dot(w, m)), w);
}

/* Refraction of w (on m's side) through a surface of normal m, eta =
 * n_other / n_this. Returns 0 under total internal reflection. */
static inline int refract(pt_vec3 w, pt_vec3 m, float eta, pt_vec3 *out)
{
    float ci = pt_v3_dot(w, m);
    float s2 = (1.0f - ci * ci) / (eta * eta);
    if (!(s2 < 1.0f))
        return 0;
    float ct = sqrtf(1.0f - s2);
    *out = pt_v3_add(pt_v3_scale(w, -1.0f / eta), pt_v3_scale(m, ci / eta - ct));
    return 1;
}

/* The rough interface at (wo, wi), wo.z > 0: f |cos wi| without the tint,
 * its pdf (within the interface), and whether wi is transmission. */
static float rough_eval(const pt_dielectric_lobe *g, pt_vec3 wo, pt_vec3 wi, float *pdf, int *trans)
{
    *pdf = 0.0f;
    *trans = wi.z < 0.0f;
    if (!(wo.z > 0.0f) || wi.z == 0.0f || !(wi.z == wi.z))
        return 0.0f;
    /* The thin wall's transmission is the reflection mirrored below. */
    pt_vec3 wr = (*trans && g->thin) ? pt_v3(wi.x, wi.y, -wi.z) : wi;
    int refr = *trans && !g->thin;
    pt_vec3 wm = refr ? pt_v3_add(wo, pt_v3_scale(wi, g->eta)) : pt_v3_add(wo, wr);
    float len = pt_v3_len(wm);
    if (!(len > 0.0f))
        return 0.0f;
    wm = pt_v3_scale(wm, 1.0f / len);
    if (wm.z < 0.0f)
        wm = pt_v3_neg(wm);
    float dwo = pt_v3_dot(wo, wm), dwi = pt_v3_dot(wr, wm);
    /* Microfacets seen from their back side by wo or wi. */
    if (!(dwo > 0.0f) || dwi * wr.z < 0.0f)
        return 0.0f;
    float d = pt_ggx_d(wm, g->alpha);
    float vpdf = pt_ggx_vndf_pdf(wo, wm, g->alpha);
    float F = pt_fresnel_dielectric(dwo, g->eta);
    float G = g2(wo, wr, g->alpha);
    if (!refr) {
        float p = *trans ? 1.0f - F : F;
        *pdf = vpdf / (4.0f * dwo) * p;
        return p * d * G / (4.0f * wo.z);
    }
    float t = dwi + dwo / g->eta;
    float den = t * t;
    if (!(den > 0.0f))
        return 0.0f;
    *pdf = vpdf * fabsf(dwi) / den * (1.0f - F);
    return (1.0f - F) * d * G * fabsf(dwi * dwo) / (wo.z * den) / (g->eta * g->eta);
}

void pt_dispersion_ior(float ior, float dispersion, float out[3])
{
    static const float lambda[3] = {611.0f, 549.0f, 464.0f};
    for (int c = 0; c < 3; c++) {
        float n = ior + (ior - 1.0f) * (dispersion / 20.0f) *
                            (523655.0f / (lambda[c] * lambda[c]) - 1.5168f);
        out[c] = n > 1.0f ? n : 1.0f;
    }
}

void pt_glass_disperse(pt_glass *g, const float ior_n[3], int inverted)
{
    if (g->thin || g->eta == 0.0f || g->eta == 1.0f)
        return;
    for (int c = 0; c < 3; c++) {
        float n = ior_n[c] >= 1.0f && isfinite(ior_n[c]) ? ior_n[c] : g->eta;
        g->eta3[c] = inverted ? 1.0f / n : n;
    }
    g->disp = 1;
}

pt_dielectric_lobe pt_glass_interface(const pt_glass *g)
{
    pt_dielectric_lobe l = {g->tint,
                            g->weight,
                            g->eta,
                            g->alpha,
                            g->thin,
                            g->disp,
                            {g->eta3[0], g->eta3[1], g->eta3[2]},
                            {g->film[0], g->film[1], g->film[2]},
                            g->film_f0};
    return l;
}

void pt_glass_film(pt_glass *g, float strength, float eta_film, float d_nm, float ior)
{
    if (g->disp || !(strength > 0.0f) || g->eta == 0.0f)
        return;
    float r = (ior - 1.0f) / (ior + 1.0f);
    g->film[0] = strength < 1.0f ? strength : 1.0f;
    g->film[1] = eta_film;
    g->film[2] = d_nm;
    g->film_f0 = r * r;
}

/* The filmed interface's reflectance per channel at cos c, from the bare
 * interface's F there. */
static pt_vec3 film_fresnel(const pt_dielectric_lobe *l, float c, float F)
{
    float f0 = l->film_f0;
    pt_vec3 ff = pt_thinfilm_fresnel(1.0f, l->film[1], c, l->film[2], pt_v3(f0, f0, f0));
    return pt_v3_lerp(pt_v3(F, F, F), ff, l->film[0]);
}

static inline float mean3(pt_vec3 v)
{
    return (v.x + v.y + v.z) * (1.0f / 3.0f);
}

/* rough_eval under a film: f |cos wi| per channel (without the tint) with
 * the filmed Fresnel, the pdf with its mean, as sampling picks by it. */
static pt_vec3 rough_eval_film(const pt_dielectric_lobe *g, pt_vec3 wo, pt_vec3 wi, float *pdf,
                               int *trans)
{
    pt_vec3 zero = pt_v3(0.0f, 0.0f, 0.0f);
    *pdf = 0.0f;
    *trans = wi.z < 0.0f;
    if (!(wo.z > 0.0f) || wi.z == 0.0f || !(wi.z == wi.z))
        return zero;
    pt_vec3 wr = (*trans && g->thin) ? pt_v3(wi.x, wi.y, -wi.z) : wi;
    int refr = *trans && !g->thin;
    pt_vec3 wm = refr ? pt_v3_add(wo, pt_v3_scale(wi, g->eta)) : pt_v3_add(wo, wr);
    float len = pt_v3_len(wm);
    if (!(len > 0.0f))
        return zero;
    wm = pt_v3_scale(wm, 1.0f / len);
    if (wm.z < 0.0f)
        wm = pt_v3_neg(wm);
    float dwo = pt_v3_dot(wo, wm), dwi = pt_v3_dot(wr, wm);
    if (!(dwo > 0.0f) || dwi * wr.z < 0.0f)
        return zero;
    float d = pt_ggx_d(wm, g->alpha);
    float vpdf = pt_ggx_vndf_pdf(wo, wm, g->alpha);
    pt_vec3 F = film_fresnel(g, dwo, pt_fresnel_dielectric(dwo, g->eta));
    float G = g2(wo, wr, g->alpha);
    pt_vec3 p = *trans ? pt_v3_sub(pt_v3(1.0f, 1.0f, 1.0f), F) : F;
    float pm = mean3(p);
    if (!refr) {
        *pdf = vpdf / (4.0f * dwo) * pm;
        return pt_v3_scale(p, d * G / (4.0f * wo.z));
    }
    float t = dwi + dwo / g->eta;
    float den = t * t;
    if (!(den > 0.0f))
        return zero;
    *pdf = vpdf * fabsf(dwi) / den * pm;
    return pt_v3_scale(p, d * G * fabsf(dwi * dwo) / (wo.z * den) / (g->eta * g->eta));
}

/* The dispersive rough interface: each channel's own lobe (its eta), the
 * density the channels' mean. */
static pt_vec3 disp_eval(const pt_dielectric_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob,
                         float *share)
{
    float f[3], pd = 0.0f;
    int trans = 0;
    for (int c = 0; c < 3; c++) {
        pt_dielectric_lobe one = *l;
        one.eta = l->eta3[c];
        float p;
        f[c] = rough_eval(&one, wo, wi, &p, &trans) * l->weight;
        pd += p;
    }
    *share = prob * (pd * (1.0f / 3.0f));
    pt_vec3 v = pt_v3(f[0], f[1], f[2]);
    return trans ? pt_v3_mul(l->tint, v) : v;
}

pt_vec3 pt_dielectric_eval(const pt_dielectric_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob,
                           float *share)
{
    *share = 0.0f;
    if (!(l->alpha > 0.0f))
        return pt_v3(0.0f, 0.0f, 0.0f);
    if (l->disp)
        return disp_eval(l, wo, wi, prob, share);
    if (l->film[0] > 0.0f) {
        float pd;
        int trans;
        pt_vec3 f = pt_v3_scale(rough_eval_film(l, wo, wi, &pd, &trans), l->weight);
        *share = prob * pd;
        return trans ? pt_v3_mul(l->tint, f) : f;
    }
    float pd;
    int trans;
    float fd = rough_eval(l, wo, wi, &pd, &trans) * l->weight;
    *share = prob * pd;
    return trans ? pt_v3_scale(l->tint, fd) : pt_v3(fd, fd, fd);
}

/* The dispersive smooth interface: channel c picked with probability 1/3,
 * then reflection with its F_c. Reflection is one direction for every
 * channel, taken with probability mean(F): weight F_ch / mean(F).
 * Refraction is channel c's own direction, taken with probability
 * (1 - F_c) / 3: weight 3 tint_c / eta_c^2 on channel c alone. */
static pt_vec3 disp_smooth_sample(const pt_dielectric_lobe *g, pt_vec3 wo, float uc, pt_vec3 *wi,
                                  float *prob)
{
    float x = uc * 3.0f;
    int c = x < 1.0f ? 0 : (x < 2.0f ? 1 : 2);
    float u = x - (float)c;
    float F[3];
    for (int k = 0; k < 3; k++)
        F[k] = pt_fresnel_dielectric(wo.z, g->eta3[k]);
    if (u < F[c]) {
        float mean = (F[0] + F[1] + F[2]) * (1.0f / 3.0f);
        *wi = pt_v3(-wo.x, -wo.y, wo.z);
        *prob = mean;
        return pt_v3_scale(pt_v3(F[0], F[1], F[2]), 1.0f / mean);
    }
    *prob = (1.0f - F[c]) * (1.0f / 3.0f);
    if (!refract(wo, pt_v3(0.0f, 0.0f, 1.0f), g->eta3[c], wi)) {
        *prob = 0.0f;
        return pt_v3(0.0f, 0.0f, 0.0f);
    }
    const float tint[3] = {g->tint.x, g->tint.y, g->tint.z};
    float v[3] = {0.0f, 0.0f, 0.0f};
    v[c] = 3.0f * tint[c] / (g->eta3[c] * g->eta3[c]);
    return pt_v3(v[0], v[1], v[2]);
}

/* The smooth interface under a film: reflection with probability mean(F)
 * (weight F / mean), transmission otherwise (weight (1 - F) / (1 - mean),
 * tinted, / eta^2 when it bends). */
static pt_vec3 film_smooth_sample(const pt_dielectric_lobe *g, pt_vec3 wo, float uc, pt_vec3 *wi,
                                  float *prob)
{
    pt_vec3 F = film_fresnel(g, wo.z, pt_fresnel_dielectric(wo.z, g->eta));
    float m = mean3(F);
    if (uc < m) {
        *wi = pt_v3(-wo.x, -wo.y, wo.z);
        *prob = m;
        return pt_v3_scale(F, 1.0f / m);
    }
    *prob = 1.0f - m;
    pt_vec3 t =
        pt_v3_scale(pt_v3_mul(g->tint, pt_v3_sub(pt_v3(1.0f, 1.0f, 1.0f), F)), 1.0f / (1.0f - m));
    if (g->thin) {
        *wi = pt_v3_neg(wo);
        return t;
    }
    if (!refract(wo, pt_v3(0.0f, 0.0f, 1.0f), g->eta, wi)) {
        *prob = 0.0f;
        return pt_v3(0.0f, 0.0f, 0.0f);
    }
    return pt_v3_scale(t, 1.0f / (g->eta * g->eta));
}

/* The smooth interface's delta lobes. */
static pt_vec3 smooth_sample(const pt_dielectric_lobe *g, pt_vec3 wo, float uc, pt_vec3 *wi,
                             float *prob)
{
    float F = pt_fresnel_dielectric(wo.z, g->eta);
    if (uc < F) {
        *wi = pt_v3(-wo.x, -wo.y, wo.z);
        *prob = F;
        return pt_v3(1.0f, 1.0f, 1.0f);
    }
    *prob = 1.0f - F;
    if (g->thin) {
        *wi = pt_v3_neg(wo);
        return g->tint;
    }
    if (!refract(wo, pt_v3(0.0f, 0.0f, 1.0f), g->eta, wi)) {
        *prob = 0.0f; /* F was 1: not reached */
        return pt_v3(0.0f, 0.0f, 0.0f);
    }
    return pt_v3_scale(g->tint, 1.0f / (g->eta * g->eta));
}

pt_vec3 pt_dielectric_straight(const pt_dielectric_lobe *l, pt_vec3 wo)
{
    if (!l->thin || l->alpha != 0.0f || l->disp || !(wo.z > 0.0f))
        return pt_v3(0.0f, 0.0f, 0.0f);
    /* smooth_sample / film_smooth_sample: the transmission is taken with
     * probability 1 - mean(F) and weighs tint (1 - F) / (1 - mean(F)). */
    float F = pt_fresnel_dielectric(wo.z, l->eta);
    pt_vec3 keep = pt_v3(1.0f - F, 1.0f - F, 1.0f - F);
    if (l->film[0] > 0.0f)
        keep = pt_v3_sub(pt_v3(1.0f, 1.0f, 1.0f), film_fresnel(l, wo.z, F));
    return pt_v3_scale(pt_v3_mul(l->tint, keep), l->weight);
}

pt_vec3 pt_dielectric_refracted(const pt_dielectric_lobe *l, pt_vec3 wo, pt_vec3 *wi, float *take)
{
    pt_vec3 zero = pt_v3(0.0f, 0.0f, 0.0f);
    *take = 0.0f;
    if (l->thin || l->alpha != 0.0f || l->disp || l->film[0] > 0.0f || !(wo.z > 0.0f))
        return zero;
    /* smooth_sample's refraction. */
    float F = pt_fresnel_dielectric(wo.z, l->eta);
    if (!(F < 1.0f) || !refract(wo, pt_v3(0.0f, 0.0f, 1.0f), l->eta, wi))
        return zero;
    *take = 1.0f - F;
    return pt_v3_scale(l->tint, l->weight * (1.0f - F) / (l->eta * l->eta));
}

pt_vec3 pt_dielectric_reflected(const pt_dielectric_lobe *l, pt_vec3 wo, pt_vec3 *wi, float *take)
{
    pt_vec3 zero = pt_v3(0.0f, 0.0f, 0.0f);
    *take = 0.0f;
    if (l->alpha != 0.0f || l->disp || l->film[0] > 0.0f || !(wo.z > 0.0f))
        return zero;
    /* smooth_sample's reflection: taken with probability F, weight 1. */
    float F = pt_fresnel_dielectric(wo.z, l->eta);
    if (!(F > 0.0f))
        return zero;
    *wi = pt_v3(-wo.x, -wo.y, wo.z);
    *take = F;
    return pt_v3(l->weight * F, l->weight * F, l->weight * F);
}

int pt_dielectric_sample(const pt_dielectric_lobe *l, pt_vec3 wo, const float u[3], float prob,
                         pt_vec3 *wi, pt_vec3 *weight, float *pdf)
{
    float uc = u[0];
    float eta = l->eta;
    if (l->disp) {
        /* The channel, and u[0] rescaled to what is left of it. */
        float x = uc * 3.0f;
        int c = x < 1.0f ? 0 : (x < 2.0f ? 1 : 2);
        if (l->alpha > 0.0f) {
            uc = x - (float)c;
            eta = l->eta3[c];
        }
    }
    if (l->alpha == 0.0f) {
        float p;
        pt_vec3 w = l->disp             ? disp_smooth_sample(l, wo, uc, wi, &p)
                    : l->film[0] > 0.0f ? film_smooth_sample(l, wo, uc, wi, &p)
                                        : smooth_sample(l, wo, uc, wi, &p);
        if (!(p > 0.0f))
            return PT_DIELECTRIC_NONE;
        *pdf = prob * p;
        *weight = pt_v3_scale(w, l->weight / prob);
        return PT_DIELECTRIC_DELTA;
    }
    pt_vec3 wm = pt_ggx_sample_vndf(wo, l->alpha, u[1], u[2]);
    float dwo = pt_v3_dot(wo, wm);
    float F = pt_fresnel_dielectric(dwo, eta);
    if (l->film[0] > 0.0f)
        F = mean3(film_fresnel(l, dwo, F));
    if (uc < F) {
        *wi = reflect(wo, wm);
        return wi->z > 0.0f ? PT_DIELECTRIC_DIR : PT_DIELECTRIC_NONE;
    }
    if (l->thin) {
        pt_vec3 r = reflect(wo, wm);
        if (!(r.z > 0.0f))
            return PT_DIELECTRIC_NONE;
        *wi = pt_v3(r.x, r.y, -r.z);
        return PT_DIELECTRIC_DIR;
    }
    if (!refract(wo, wm, eta, wi) || !(wi->z < 0.0f))
        return PT_DIELECTRIC_NONE;
    return PT_DIELECTRIC_DIR;
}
