/*
 * aniso.c - the anisotropic GGX lobe of KHR_materials_anisotropy (aniso.h).
 *
 * In the lobe's frame (x along the direction): D(m) = 1 / (pi ax ay
 * (mx^2 / ax^2 + my^2 / ay^2 + mz^2)^2) (Heitz 2014, eq. 85), and Smith's
 * Lambda through s(w) = sqrt(z^2 + ax^2 x^2 + ay^2 y^2), so that, as for the
 * isotropic lobe (bsdf.c), G1 = 2z / (z + s), G2 = 2 zo zi / (zi s_o +
 * zo s_i), f cos = F D zi / (2 (zi s_o + zo s_i)) and the visible-normal
 * pdf of wi is D / (2 (zo + s_o)).
 */
#include "common/render/aniso.h"

#include <math.h>

pt_aniso_lobe pt_aniso_setup(const pt_bsdf *b, float strength, float c, float s)
{
    pt_aniso_lobe l;
    strength = strength > 0.0f ? (strength < 1.0f ? strength : 1.0f) : 0.0f;
    float len = sqrtf(c * c + s * s);
    if (len > 0.0f && isfinite(len)) {
        l.c = c / len;
        l.s = s / len;
    } else {
        l.c = 1.0f;
        l.s = 0.0f;
    }
    l.f0 = b->f0;
    l.f90 = b->spec_weight;
    l.ay = b->alpha;
    l.ax = b->alpha + (1.0f - b->alpha) * strength * strength;
    return l;
}

/* w in the lobe's frame: turned by minus the direction's angle. */
static inline pt_vec3 to_lobe(const pt_aniso_lobe *l, pt_vec3 w)
{
    return pt_v3(l->c * w.x + l->s * w.y, -l->s * w.x + l->c * w.y, w.z);
}

static inline pt_vec3 from_lobe(const pt_aniso_lobe *l, pt_vec3 w)
{
    return pt_v3(l->c * w.x - l->s * w.y, l->s * w.x + l->c * w.y, w.z);
}

float pt_aniso_d(pt_vec3 m, float ax, float ay)
{
    if (m.z <= 0.0f)
        return 0.0f;
    float x = m.x / ax, y = m.y / ay;
    float t = x * x + y * y + m.z * m.z;
    return t > 0.0f ? 1.0f / (PT_PI * ax * ay * t * t) : 0.0f;
}

static inline float lambda_root(pt_vec3 w, float ax, float ay)
{
    return sqrtf(w.z * w.z + ax * ax * w.x * w.x + ay * ay * w.y * w.y);
}

float pt_aniso_geom(const pt_aniso_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob, float *share,
                    float *c)
{
    *share = 0.0f;
    *c = 0.0f;
    if (!(wo.z > 0.0f) || !(wi.z > 0.0f))
        return 0.0f;
    pt_vec3 o = to_lobe(l, wo), i = to_lobe(l, wi);
    pt_vec3 h = pt_v3_add(o, i);
    float hl = pt_v3_len(h);
    if (!(hl > 0.0f))
        return 0.0f;
    h = pt_v3_scale(h, 1.0f / hl);
    float d = pt_aniso_d(h, l->ax, l->ay);
    float so = lambda_root(o, l->ax, l->ay), si = lambda_root(i, l->ax, l->ay);
    float den = i.z * so + o.z * si;
    if (!(den > 0.0f) || !(d > 0.0f))
        return 0.0f;
    *share = prob * d / (2.0f * (o.z + so));
    *c = pt_v3_dot(o, h);
    return d * i.z / (2.0f * den);
}

pt_vec3 pt_aniso_eval(const pt_aniso_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob, float *share)
{
    float c;
    float g = pt_aniso_geom(l, wo, wi, prob, share, &c);
    if (g == 0.0f)
        return pt_v3(0.0f, 0.0f, 0.0f);
    return pt_v3_scale(pt_bsdf_spec_fresnel(l->f0, l->f90, c), g);
}

int pt_aniso_sample(const pt_aniso_lobe *l, pt_vec3 wo, const float u[3], pt_vec3 *wi)
{
    pt_vec3 o = to_lobe(l, wo);
    pt_vec3 m = pt_ggx_sample_vndf_aniso(o, l->ax, l->ay, u[1], u[2]);
    pt_vec3 i = pt_v3_sub(pt_v3_scale(m, 2.0f * pt_v3_dot(o, m)), o);
    *wi = from_lobe(l, i);
    return wi->z > 0.0f;
}
