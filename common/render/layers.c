/*
 * layers.c - clearcoat and sheen over the base BSDF (layers.h has the model
 * and its references).
 *
 * The sheen albedo table: E(mu, r) = integral over the hemisphere of
 * pt_sheen_eval(alpha(r), wo(mu), wi) d wi, by the midpoint rule in theta
 * (128 steps) and phi (64 steps over [0, pi], doubled: the lobe is symmetric
 * about the plane of wo), in double. It is built once per process
 * (pthread_once) by the same code on every machine of the farm, so each
 * worker reads the same numbers.
 */
#include "common/render/layers.h"

#include <math.h>
#include <pthread.h>

#include "common/render/sampler.h"

#define COAT_F0 0.04f /* ((1.5 - 1) / (1.5 + 1))^2 */
#define TABLE_N 32
#define Q_THETA 128
#define Q_PHI 64

static float sheen_table[TABLE_N][TABLE_N]; /* [roughness][mu] */
static pthread_once_t sheen_once = PTHREAD_ONCE_INIT;

static inline float clamp01(float x)
{
    return x < 0.0f ? 0.0f : (x > 1.0f ? 1.0f : x);
}

static inline float sheen_alpha(float roughness)
{
    float a = roughness * roughness;
    return a > PT_LAYERS_MIN_SHEEN_ALPHA ? a : PT_LAYERS_MIN_SHEEN_ALPHA;
}

float pt_sheen_eval(float alpha, pt_vec3 wo, pt_vec3 wi)
{
    if (!(wo.z > 0.0f) || !(wi.z > 0.0f))
        return 0.0f;
    pt_vec3 h = pt_v3_add(wo, wi);
    float hl = pt_v3_len(h);
    if (!(hl > 0.0f))
        return 0.0f;
    float hz = h.z / hl;
    float sin2 = fmaxf(1.0f - hz * hz, 0.0f);
    float inv_a = 1.0f / alpha;
    /* D_charlie = (2 + 1/a) sin(theta_h)^(1/a) / (2 pi) */
    float d = (2.0f + inv_a) * powf(sin2, 0.5f * inv_a) * (0.5f * PT_INV_PI);
    float v = 1.0f / (4.0f * (wi.z + wo.z - wi.z * wo.z));
    return d * v * wi.z;
}

static void build_sheen_table(void)
{
    const double pi = 3.14159265358979323846;
    for (int j = 0; j < TABLE_N; j++) {
        float alpha = sheen_alpha((float)j / (TABLE_N - 1));
        for (int i = 0; i < TABLE_N; i++) {
            float mu = fmaxf((float)i / (TABLE_N - 1), 1e-3f);
            pt_vec3 wo = pt_v3(sqrtf(1.0f - mu * mu), 0.0f, mu);
            double sum = 0.0;
            for (int t = 0; t < Q_THETA; t++) {
                double th = (t + 0.5) * (0.5 * pi / Q_THETA);
                double st = sin(th), ct = cos(th);
                for (int p = 0; p < Q_PHI; p++) {
                    double ph = (p + 0.5) * (pi / Q_PHI);
                    pt_vec3 wi = pt_v3((float)(st * cos(ph)), (float)(st * sin(ph)), (float)ct);
                    sum += (double)pt_sheen_eval(alpha, wo, wi) * st;
                }
            }
            sheen_table[j][i] = (float)(2.0 * sum * (0.5 * pi / Q_THETA) * (pi / Q_PHI));
        }
    }
}

float pt_sheen_albedo(float mu, float roughness)
{
    pthread_once(&sheen_once, build_sheen_table);
    float x = clamp01(mu) * (TABLE_N - 1), y = clamp01(roughness) * (TABLE_N - 1);
    int i = (int)x, j = (int)y;
    if (i > TABLE_N - 2)
        i = TABLE_N - 2;
    if (j > TABLE_N - 2)
        j = TABLE_N - 2;
    float fx = x - (float)i, fy = y - (float)j;
    float a = sheen_table[j][i] + (sheen_table[j][i + 1] - sheen_table[j][i]) * fx;
    float b = sheen_table[j + 1][i] + (sheen_table[j + 1][i + 1] - sheen_table[j + 1][i]) * fx;
    return a + (b - a) * fy;
}

int pt_layers_setup(pt_layers *l, const pt_bsdf *base, float clearcoat, float coat_roughness,
                    const float sheen_color[3], float sheen_roughness)
{
    l->base = *base;
    l->clearcoat = clamp01(clearcoat == clearcoat ? clearcoat : 0.0f);
    float cr = clamp01(coat_roughness == coat_roughness ? coat_roughness : 0.0f);
    l->coat_alpha = fmaxf(cr * cr, PT_BSDF_MIN_ALPHA);
    l->sheen = pt_v3(clamp01(sheen_color[0] == sheen_color[0] ? sheen_color[0] : 0.0f),
                     clamp01(sheen_color[1] == sheen_color[1] ? sheen_color[1] : 0.0f),
                     clamp01(sheen_color[2] == sheen_color[2] ? sheen_color[2] : 0.0f));
    l->sheen_max = pt_v3_max_comp(l->sheen);
    l->sheen_rough = clamp01(sheen_roughness == sheen_roughness ? sheen_roughness : 0.0f);
    l->sheen_alpha = sheen_alpha(l->sheen_rough);
    l->coat_own = 0;
    return l->clearcoat > 0.0f || l->sheen_max > 0.0f;
}

/* clearcoat x Schlick Fresnel of the coat at cosine c (the extension's
 * fresnel_coat, on N.V). */
static inline float coat_fresnel(const pt_layers *l, float c)
{
    float m = clamp01(1.0f - c);
    float m2 = m * m;
    return l->clearcoat * (COAT_F0 + (1.0f - COAT_F0) * m2 * m2 * m);
}

/* The coat's GGX reflection without Fresnel, times wi.z, and the pdf of
 * sampling it by visible normals. */
static float coat_eval(const pt_layers *l, pt_vec3 wo, pt_vec3 wi, float *pdf)
{
    *pdf = 0.0f;
    pt_vec3 h = pt_v3_add(wo, wi);
    float hl = pt_v3_len(h);
    if (!(hl > 0.0f))
        return 0.0f;
    h = pt_v3_scale(h, 1.0f / hl);
    float oh = pt_v3_dot(wo, h);
    if (!(oh > 0.0f))
        return 0.0f;
    float a = l->coat_alpha;
    float d = pt_ggx_d(h, a);
    float g1o = pt_ggx_g1(wo, a), g1i = pt_ggx_g1(wi, a);
    if (!(g1o > 0.0f) || !(g1i > 0.0f))
        return 0.0f;
    /* height-correlated G2 = 1 / (1 + L(wo) + L(wi)), L = 1/G1 - 1 */
    float g2 = 1.0f / (1.0f / g1o + 1.0f / g1i - 1.0f);
    *pdf = pt_ggx_vndf_pdf(wo, h, a) / (4.0f * oh);
    return d * g2 / (4.0f * wo.z);
}

void pt_layers_coat_normal(pt_layers *l, pt_vec3 n)
{
    l->coat_own = 1;
    l->coat_fr = pt_frame_from_normal(n);
}

/* Lobe probabilities from wo alone (so that pdf needs no sampled state):
 * mu_c = wo's cosine to the coat's normal, mu_o to the base's. */
static inline void lobe_probs(const pt_layers *l, float mu_c, float mu_o, float *pc, float *ps,
                              float *pb, float *fc, float *eo)
{
    *fc = coat_fresnel(l, mu_c);
    *eo = l->sheen_max > 0.0f ? fminf(pt_sheen_albedo(mu_o, l->sheen_rough), 1.0f) : 0.0f;
    float wc = *fc, ws = (1.0f - *fc) * l->sheen_max * *eo;
    float wb = (1.0f - *fc) * (1.0f - l->sheen_max * *eo);
    float sum = wc + ws + wb;
    *pc = wc / sum;
    *ps = ws / sum;
    *pb = wb / sum;
}

static pt_vec3 eval_all(const pt_layers *l, pt_vec3 wo, pt_vec3 wi, float *pdf)
{
    pt_vec3 zero = pt_v3(0.0f, 0.0f, 0.0f);
    *pdf = 0.0f;
    if (!(wo.z > 0.0f) || !(wi.z > 0.0f))
        return zero;
    float pc, ps, pb, fc, eo;
    lobe_probs(l, wo.z, wo.z, &pc, &ps, &pb, &fc, &eo);
    float bpdf = 0.0f, cpdf = 0.0f;
    pt_vec3 fb = pt_bsdf_eval(&l->base, wo, wi, &bpdf);
    float scale = 1.0f;
    pt_vec3 f = zero;
    if (l->sheen_max > 0.0f) {
        /* With Ashikhmin's visibility a sharp sheen seen at grazing
         * reflects more than it receives (E > 1): the lobe is scaled down to
         * albedo 1 there, and the base's scaling reads E clamped to 1. */
        float ei = fminf(pt_sheen_albedo(wi.z, l->sheen_rough), 1.0f);
        float eo_raw = pt_sheen_albedo(wo.z, l->sheen_rough);
        float norm = eo_raw > 1.0f ? 1.0f / eo_raw : 1.0f;
        scale = fminf(1.0f - l->sheen_max * eo, 1.0f - l->sheen_max * ei);
        f = pt_v3_scale(l->sheen, pt_sheen_eval(l->sheen_alpha, wo, wi) * norm);
    }
    f = pt_v3_add(f, pt_v3_scale(fb, scale));
    f = pt_v3_scale(f, 1.0f - fc);
    if (l->clearcoat > 0.0f) {
        float c = coat_eval(l, wo, wi, &cpdf);
        f = pt_v3_add(f, pt_v3(fc * c, fc * c, fc * c));
    }
    *pdf = pc * cpdf + ps * (0.5f * PT_INV_PI) + pb * bpdf;
    return f;
}

/* eval_all with the coat on its own normal (layers.h). */
static pt_vec3 eval_own(const pt_layers *l, pt_vec3 wo, pt_vec3 wi, float *pdf)
{
    pt_vec3 zero = pt_v3(0.0f, 0.0f, 0.0f);
    *pdf = 0.0f;
    pt_vec3 woc = pt_frame_to_local(&l->coat_fr, wo), wic = pt_frame_to_local(&l->coat_fr, wi);
    if (!(wo.z > 0.0f) || !(woc.z > 0.0f))
        return zero;
    float pc, ps, pb, fc, eo;
    lobe_probs(l, woc.z, wo.z, &pc, &ps, &pb, &fc, &eo);
    pt_vec3 f = zero;
    float p = 0.0f;
    if (wi.z > 0.0f) {
        float bpdf = 0.0f, scale = 1.0f;
        pt_vec3 fb = pt_bsdf_eval(&l->base, wo, wi, &bpdf);
        if (l->sheen_max > 0.0f) {
            float ei = fminf(pt_sheen_albedo(wi.z, l->sheen_rough), 1.0f);
            float eo_raw = pt_sheen_albedo(wo.z, l->sheen_rough);
            float norm = eo_raw > 1.0f ? 1.0f / eo_raw : 1.0f;
            scale = fminf(1.0f - l->sheen_max * eo, 1.0f - l->sheen_max * ei);
            f = pt_v3_scale(l->sheen, pt_sheen_eval(l->sheen_alpha, wo, wi) * norm);
        }
        f = pt_v3_scale(pt_v3_add(f, pt_v3_scale(fb, scale)), 1.0f - fc);
        p = ps * (0.5f * PT_INV_PI) + pb * bpdf;
    }
    if (l->clearcoat > 0.0f && wic.z > 0.0f) {
        float cpdf = 0.0f;
        float c = coat_eval(l, woc, wic, &cpdf);
        f = pt_v3_add(f, pt_v3(fc * c, fc * c, fc * c));
        p += pc * cpdf;
    }
    *pdf = p;
    return f;
}

pt_vec3 pt_layers_eval(const pt_layers *l, pt_vec3 wo, pt_vec3 wi, float *pdf)
{
    return l->coat_own ? eval_own(l, wo, wi, pdf) : eval_all(l, wo, wi, pdf);
}

float pt_layers_pdf(const pt_layers *l, pt_vec3 wo, pt_vec3 wi)
{
    float pdf;
    pt_layers_eval(l, wo, wi, &pdf);
    return pdf;
}

/* A direction from the lobes under the coat, for u[0] past the coat's
 * share pc: the sheen (uniform over the hemisphere) for the next ps, else
 * the base, the rest of u[0]'s interval picking the base's own lobe. 0 when
 * the direction is impossible or below the surface. */
static int sample_below_coat(const pt_layers *l, pt_vec3 wo, const float u[3], float pc, float ps,
                             float pb, pt_vec3 *wi)
{
    if (u[0] < pc + ps) {
        float z = u[1], r = sqrtf(fmaxf(0.0f, 1.0f - z * z)), ph = 2.0f * PT_PI * u[2];
        *wi = pt_v3(r * cosf(ph), r * sinf(ph), z);
    } else {
        float ub[3] = {fminf((u[0] - pc - ps) / pb, 0x1.fffffep-1f), u[1], u[2]};
        if (!(ub[0] >= 0.0f))
            ub[0] = 0.0f;
        float bp;
        pt_bsdf_sample(&l->base, wo, ub, wi, &bp);
        if (!(bp > 0.0f))
            return 0;
    }
    return wi->z > 0.0f;
}

/* The sample's weight f / pdf, and *pdf 0 with no weight when impossible. */
static pt_vec3 weight(pt_vec3 f, float *pdf)
{
    if (!(*pdf > 0.0f)) {
        *pdf = 0.0f;
        return pt_v3(0.0f, 0.0f, 0.0f);
    }
    return pt_v3_scale(f, 1.0f / *pdf);
}

/* pt_layers_sample with the coat on its own normal. */
static pt_vec3 sample_own(const pt_layers *l, pt_vec3 wo, const float u[3], pt_vec3 *wi, float *pdf)
{
    pt_vec3 zero = pt_v3(0.0f, 0.0f, 0.0f);
    pt_vec3 woc = pt_frame_to_local(&l->coat_fr, wo);
    if (!(wo.z > 0.0f) || !(woc.z > 0.0f))
        return zero;
    float pc, ps, pb, fc, eo;
    lobe_probs(l, woc.z, wo.z, &pc, &ps, &pb, &fc, &eo);
    if (u[0] < pc) {
        pt_vec3 m = pt_ggx_sample_vndf(woc, l->coat_alpha, u[1], u[2]);
        float om = pt_v3_dot(woc, m);
        pt_vec3 wic = pt_v3_sub(pt_v3_scale(m, 2.0f * om), woc);
        if (!(wic.z > 0.0f))
            return zero;
        *wi = pt_frame_to_world(&l->coat_fr, wic);
    } else if (!sample_below_coat(l, wo, u, pc, ps, pb, wi)) {
        return zero;
    }
    return weight(eval_own(l, wo, *wi, pdf), pdf);
}

pt_vec3 pt_layers_sample(const pt_layers *l, pt_vec3 wo, const float u[3], pt_vec3 *wi, float *pdf)
{
    pt_vec3 zero = pt_v3(0.0f, 0.0f, 0.0f);
    *pdf = 0.0f;
    *wi = pt_v3(0.0f, 0.0f, 1.0f);
    if (l->coat_own)
        return sample_own(l, wo, u, wi, pdf);
    if (!(wo.z > 0.0f))
        return zero;
    float pc, ps, pb, fc, eo;
    lobe_probs(l, wo.z, wo.z, &pc, &ps, &pb, &fc, &eo);
    if (u[0] < pc) {
        pt_vec3 m = pt_ggx_sample_vndf(wo, l->coat_alpha, u[1], u[2]);
        float om = pt_v3_dot(wo, m);
        *wi = pt_v3_sub(pt_v3_scale(m, 2.0f * om), wo);
        if (!(wi->z > 0.0f))
            return zero;
    } else if (!sample_below_coat(l, wo, u, pc, ps, pb, wi)) {
        return zero;
    }
    return weight(eval_all(l, wo, *wi, pdf), pdf);
}
