/*
 * thinfilm.c - the thin-film Fresnel of KHR_materials_iridescence and its
 * lobes (thinfilm.h).
 *
 * The film's terms, from the extension's "Iridescence Fresnel" section
 * (Belcour & Barla 2017, sec. 4, with Schlick's approximation at both
 * interfaces and the phase shifts 0 or pi of a reflection off a denser or a
 * lighter medium): R12 = Schlick(((eta2 - eta1) / (eta2 + eta1))^2, cos1),
 * T121 = 1 - R12, R23 = Schlick(((n3 - eta2) / (n3 + eta2))^2, cos2) with
 * cos2 from Snell's law; R123 = R12 R23 (at most 0.9999; the extension's
 * lower clamp at 1e-5 is left out: where the film vanishes, R12 = 0, it
 * would add a harmonic of 2 sqrt(1e-5) to the bare base's Fresnel),
 * Rs = T121^2 R23 / (1 - R123); Airy's series is
 *   R(delta) = C0 + sum_{m>=1} 2 C_m cos(m (delta + phi)),
 *   C0 = R12 + Rs, C_m = (Rs - T121) sqrt(R123)^m, phi = phi21 + phi23,
 * and the harmonics' colour is the Fourier transform of the matching
 * functions (Gaussian fits: val, pos, var below, X with a second lobe) at
 * m OPD, shifted by m phi. The film's index fades to eta1 over its first
 * 0.03 nm (smoothstep), so a film of thickness 0 is no film.
 */
#include "common/render/thinfilm.h"

#include <math.h>

#define PI_F 3.14159265358979f

static inline float sq(float x)
{
    return x * x;
}

static inline float clampf(float x, float lo, float hi)
{
    return x < lo ? lo : (x > hi ? hi : x);
}

static inline float schlick(float f0, float c)
{
    return f0 + (1.0f - f0) * pt_bsdf_schlick_w(c);
}

/* 2 x the XYZ matching functions' transform at optical path difference opd
 * (nm), each component shifted by shift[j] (the extension's
 * evalSensitivity, normalised so that Y's integral is 1). */
static void sensitivity(float opd, const float shift[3], float xyz[3])
{
    static const float val[3] = {5.4856e-13f, 4.4201e-13f, 5.2481e-13f};
    static const float pos[3] = {1.6810e+06f, 1.7953e+06f, 2.2084e+06f};
    static const float var[3] = {4.3278e+09f, 9.3046e+09f, 6.6121e+09f};
    const float phase = 2.0f * PI_F * opd * 1.0e-9f, p2 = phase * phase;
    for (int j = 0; j < 3; j++)
        xyz[j] = val[j] * sqrtf(2.0f * PI_F * var[j]) * cosf(pos[j] * phase + shift[j]) *
                 expf(-p2 * var[j]);
    xyz[0] += 9.7470e-14f * sqrtf(2.0f * PI_F * 4.5282e+09f) *
              cosf(2.2399e+06f * phase + shift[0]) * expf(-4.5282e+09f * p2);
    for (int j = 0; j < 3; j++)
        xyz[j] *= 2.0f / 1.0685e-7f;
}

/* The film's C0 and C_1, C_2 per channel of f0, and the harmonics'
 * transforms h[m - 1] (XYZ); 0 past total internal reflection. */
static int film_terms(float eta1, float eta2, float cos1, float d, const float f0[3], float c0[3],
                      float cm[2][3], float h[2][3])
{
    float t = clampf(d / 0.03f, 0.0f, 1.0f);
    eta2 = eta1 + (eta2 - eta1) * (t * t * (3.0f - 2.0f * t));
    float cos2sq = 1.0f - sq(eta1 / eta2) * (1.0f - sq(cos1));
    if (!(cos2sq >= 0.0f))
        return 0;
    float cos2 = sqrtf(cos2sq);
    float r12 = schlick(sq((eta2 - eta1) / (eta2 + eta1)), cos1), t121 = 1.0f - r12;
    float phi21 = eta2 < eta1 ? 0.0f : PI_F;
    float opd = 2.0f * eta2 * d * cos2;
    float phi[3];
    for (int c = 0; c < 3; c++) {
        float sf = sqrtf(clampf(f0[c], 0.0f, 0.9999f));
        float n3 = (1.0f + sf) / (1.0f - sf);
        float r23 = schlick(sq((n3 - eta2) / (n3 + eta2)), cos2);
        phi[c] = phi21 + (n3 < eta2 ? PI_F : 0.0f);
        float r123 = clampf(r12 * r23, 0.0f, 0.9999f);
        float rs = sq(t121) * r23 / (1.0f - r123);
        c0[c] = r12 + rs;
        cm[0][c] = (rs - t121) * sqrtf(r123);
        cm[1][c] = cm[0][c] * sqrtf(r123);
    }
    for (int m = 0; m < 2; m++) {
        float s[3] = {(float)(m + 1) * phi[0], (float)(m + 1) * phi[1], (float)(m + 1) * phi[2]};
        sensitivity((float)(m + 1) * opd, s, h[m]);
    }
    return 1;
}

/* CIE XYZ to linear Rec.709 (the extension's XYZ_TO_REC709, rows). */
static const float XYZ_TO_RGB[3][3] = {{3.2404542f, -1.5371385f, -0.4985314f},
                                       {-0.9692660f, 1.8760108f, 0.0415560f},
                                       {0.0556434f, -0.2040259f, 1.0572252f}};

pt_vec3 pt_thinfilm_fresnel(float eta_out, float eta_film, float cos1, float d_nm, pt_vec3 f0)
{
    const float f[3] = {f0.x, f0.y, f0.z};
    float c0[3], cm[2][3], h[2][3], out[3];
    if (!film_terms(eta_out, eta_film, cos1, d_nm, f, c0, cm, h))
        return pt_v3(1.0f, 1.0f, 1.0f);
    for (int c = 0; c < 3; c++) {
        float v = c0[c];
        for (int m = 0; m < 2; m++)
            v += cm[m][c] * (XYZ_TO_RGB[c][0] * h[m][0] + XYZ_TO_RGB[c][1] * h[m][1] +
                             XYZ_TO_RGB[c][2] * h[m][2]);
        out[c] = v > 0.0f ? v : 0.0f;
    }
    return pt_v3(out[0], out[1], out[2]);
}

pt_vec3 pt_thinfilm_xyz(float eta_out, float eta_film, float cos1, float d_nm, float f0, float *dc)
{
    const float f[3] = {f0, f0, f0};
    float c0[3], cm[2][3], h[2][3];
    if (!film_terms(eta_out, eta_film, cos1, d_nm, f, c0, cm, h)) {
        *dc = 1.0f;
        return pt_v3(1.0f, 1.0f, 1.0f);
    }
    *dc = c0[0];
    float x[3];
    for (int j = 0; j < 3; j++)
        x[j] = c0[0] + cm[0][0] * h[0][j] + cm[1][0] * h[1][j];
    return pt_v3(x[0], x[1], x[2]);
}

/* A microfacet lobe's value under the film: its geometric factor g (0: none)
 * times its Fresnel (f0, f90) blended with the film's at cos c. */
static pt_vec3 filmed(const pt_irid *film, pt_vec3 f0, float f90, float g, float c)
{
    if (g == 0.0f)
        return pt_v3(0.0f, 0.0f, 0.0f);
    pt_vec3 F = pt_bsdf_spec_fresnel(f0, f90, c);
    pt_vec3 Ff = pt_thinfilm_fresnel(1.0f, film->eta, c, film->d_nm, f0);
    return pt_v3_scale(pt_v3_lerp(F, Ff, film->strength), g);
}

pt_vec3 pt_irid_specular_eval(const pt_irid_specular_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob,
                              float *share)
{
    float c = 0.0f;
    float g = pt_specular_geom(&l->s, wo, wi, prob, share, &c);
    return filmed(&l->film, l->s.f0, l->s.f90, g, c);
}

pt_vec3 pt_irid_transmit_eval(const pt_irid_diffuse_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob,
                              float *share)
{
    if (!(wo.z > 0.0f) || !(wi.z < 0.0f)) {
        *share = 0.0f;
        return pt_v3(0.0f, 0.0f, 0.0f);
    }
    float c = pt_fminf(wo.z, -wi.z);
    float fd = pt_bsdf_diffuse_fresnel(l->d.dielectric_f0, l->d.dielectric_f90, c);
    float ff = pt_v3_max_comp(pt_thinfilm_fresnel(1.0f, l->film.eta, c, l->film.d_nm, l->f0));
    float w = 1.0f - (fd + (ff - fd) * l->film.strength);
    *share = prob * -wi.z * PT_INV_PI;
    return pt_v3_scale(l->d.albedo, (w > 0.0f ? w : 0.0f) * -wi.z * PT_INV_PI);
}

pt_vec3 pt_irid_aniso_eval(const pt_irid_aniso_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob,
                           float *share)
{
    float c = 0.0f;
    float g = pt_aniso_geom(&l->a, wo, wi, prob, share, &c);
    return filmed(&l->film, l->a.f0, l->a.f90, g, c);
}

pt_vec3 pt_irid_diffuse_eval(const pt_irid_diffuse_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob,
                             float *share)
{
    if (!(wo.z > 0.0f) || !(wi.z > 0.0f)) {
        *share = 0.0f;
        return pt_v3(0.0f, 0.0f, 0.0f);
    }
    float c = fminf(wo.z, wi.z);
    float fd = pt_bsdf_diffuse_fresnel(l->d.dielectric_f0, l->d.dielectric_f90, c);
    float ff = pt_v3_max_comp(pt_thinfilm_fresnel(1.0f, l->film.eta, c, l->film.d_nm, l->f0));
    float w = 1.0f - (fd + (ff - fd) * l->film.strength);
    *share = prob * wi.z * PT_INV_PI;
    return pt_v3_scale(l->d.albedo, (w > 0.0f ? w : 0.0f) * wi.z * PT_INV_PI);
}
