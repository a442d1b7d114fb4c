/*
 * layers.c - clearcoat and sheen over the base: their lobes (layers.h has
 * the model and its references).
 *
 * The sheen albedo E(mu, r) is read bilinearly from the table compiled in
 * (sheen_table.h: generated once by the quadrature in test_layers.c), so a
 * worker neither spends time on it nor depends on its libm for it.
 */
#include "common/render/layers.h"

#include <math.h>

#include "common/render/sampler.h"
#include "common/render/sheen_table.h"

#define COAT_F0 0.04f /* ((1.5 - 1) / (1.5 + 1))^2 */
#define TABLE_N PT_SHEEN_TABLE_N

static inline float clamp01(float x)
{
    return x < 0.0f ? 0.0f : (x > 1.0f ? 1.0f : x);
}

static inline float sheen_alpha(float roughness)
{
    float a = roughness * roughness;
    return a > PT_LAYERS_MIN_SHEEN_ALPHA ? a : PT_LAYERS_MIN_SHEEN_ALPHA;
}

float pt_sheen_charlie(float alpha, pt_vec3 wo, pt_vec3 wi)
{
    if (!(wo.z > 0.0f) || !(wi.z > 0.0f))
        return 0.0f;
    pt_vec3 h = pt_v3_add(wo, wi);
    float hl = pt_v3_len(h);
    if (!(hl > 0.0f))
        return 0.0f;
    float hz = h.z / hl;
    float sin2 = pt_fmaxf(1.0f - hz * hz, 0.0f);
    float inv_a = 1.0f / alpha;
    /* D_charlie = (2 + 1/a) sin(theta_h)^(1/a) / (2 pi) */
    float d = (2.0f + inv_a) * powf(sin2, 0.5f * inv_a) * (0.5f * PT_INV_PI);
    float v = 1.0f / (4.0f * (wi.z + wo.z - wi.z * wo.z));
    return d * v * wi.z;
}

float pt_sheen_albedo(float mu, float roughness)
{
    float x = clamp01(mu) * (TABLE_N - 1), y = clamp01(roughness) * (TABLE_N - 1);
    int i = (int)x, j = (int)y;
    if (i > TABLE_N - 2)
        i = TABLE_N - 2;
    if (j > TABLE_N - 2)
        j = TABLE_N - 2;
    float fx = x - (float)i, fy = y - (float)j;
    float a = pt_sheen_table[j][i] + (pt_sheen_table[j][i + 1] - pt_sheen_table[j][i]) * fx;
    float b =
        pt_sheen_table[j + 1][i] + (pt_sheen_table[j + 1][i + 1] - pt_sheen_table[j + 1][i]) * fx;
    return a + (b - a) * fy;
}

int pt_layers_setup(pt_layers *l, const pt_bsdf *base, float clearcoat, float coat_roughness,
                    const float sheen_color[3], float sheen_roughness)
{
    l->base = *base;
    l->clearcoat = clamp01(clearcoat == clearcoat ? clearcoat : 0.0f);
    float cr = clamp01(coat_roughness == coat_roughness ? coat_roughness : 0.0f);
    l->coat_alpha = pt_fmaxf(cr * cr, PT_BSDF_MIN_ALPHA);
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
static float coat_ggx(float a, pt_vec3 wo, pt_vec3 wi, float *pdf)
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

int pt_layers_lobes(const pt_layers *l, pt_vec3 wo, pt_coat_lobe *coat, pt_sheen_lobe *sheen,
                    float *pc, float *ps, float *pb)
{
    /* mu_c = wo's cosine to the coat's normal, mu_o to the base's. */
    float mu_o = wo.z, mu_c = wo.z;
    coat->own = l->coat_own;
    if (l->coat_own) {
        coat->fr = l->coat_fr;
        coat->wo = pt_frame_to_local(&l->coat_fr, wo);
        mu_c = coat->wo.z;
    }
    if (!(mu_o > 0.0f) || !(mu_c > 0.0f))
        return 0;
    float fc = coat_fresnel(l, mu_c);
    /* E(mu_o) once: the lobes' weights read it clamped, the sheen's
     * normalisation raw. */
    float eo_raw = l->sheen_max > 0.0f ? pt_sheen_albedo(mu_o, l->sheen_rough) : 0.0f;
    float eo = l->sheen_max > 0.0f ? pt_fminf(eo_raw, 1.0f) : 0.0f;
    float wc = fc, ws = (1.0f - fc) * l->sheen_max * eo;
    float wb = (1.0f - fc) * (1.0f - l->sheen_max * eo);
    float sum = wc + ws + wb;
    *pc = wc / sum;
    *ps = ws / sum;
    *pb = wb / sum;
    coat->fc = fc;
    coat->alpha = l->coat_alpha;
    sheen->color = l->sheen;
    sheen->color_max = l->sheen_max;
    sheen->rough = l->sheen_rough;
    sheen->alpha = l->sheen_alpha;
    sheen->keep_o = 1.0f - l->sheen_max * eo;
    sheen->norm = 1.0f;
    if (l->sheen_max > 0.0f) {
        /* With Ashikhmin's visibility a sharp sheen seen at grazing
         * reflects more than it receives (E > 1): the lobe is scaled down to
         * albedo 1 there, and the base's scaling reads E clamped to 1. */
        sheen->norm = eo_raw > 1.0f ? 1.0f / eo_raw : 1.0f;
    }
    return 1;
}

pt_vec3 pt_coat_eval(const pt_coat_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob, float *share,
                     float *below)
{
    float pdf = 0.0f, c = 0.0f;
    *below = 1.0f - l->fc;
    if (l->own) {
        pt_vec3 wic = pt_frame_to_local(&l->fr, wi);
        if (wic.z > 0.0f)
            c = coat_ggx(l->alpha, l->wo, wic, &pdf);
    } else {
        c = coat_ggx(l->alpha, wo, wi, &pdf);
    }
    *share = prob * pdf;
    return pt_v3(l->fc * c, l->fc * c, l->fc * c);
}

pt_vec3 pt_sheen_eval(const pt_sheen_lobe *l, pt_vec3 wo, pt_vec3 wi, float prob, float *share,
                      float *below)
{
    if (!(wo.z > 0.0f) || !(wi.z > 0.0f)) {
        /* Light that the base transmits from below crosses the sheen once,
         * along wo: only S's wo half. (An opaque base gives 0 there.) */
        *share = 0.0f;
        *below = l->keep_o;
        return pt_v3(0.0f, 0.0f, 0.0f);
    }
    float ei = pt_fminf(pt_sheen_albedo(wi.z, l->rough), 1.0f);
    *below = pt_fminf(l->keep_o, 1.0f - l->color_max * ei);
    *share = prob * (0.5f * PT_INV_PI);
    return pt_v3_scale(l->color, pt_sheen_charlie(l->alpha, wo, wi) * l->norm);
}

int pt_coat_sample(const pt_coat_lobe *l, pt_vec3 wo, const float u[3], pt_vec3 *wi)
{
    pt_vec3 v = l->own ? l->wo : wo;
    pt_vec3 m = pt_ggx_sample_vndf(v, l->alpha, u[1], u[2]);
    float om = pt_v3_dot(v, m);
    pt_vec3 r = pt_v3_sub(pt_v3_scale(m, 2.0f * om), v);
    if (!(r.z > 0.0f))
        return 0;
    *wi = l->own ? pt_frame_to_world(&l->fr, r) : r;
    return 1;
}

int pt_sheen_sample(const float u[3], pt_vec3 *wi)
{
    /* Uniform over the hemisphere: z = cos theta is uniform. */
    float z = u[1], r = sqrtf(pt_fmaxf(0.0f, 1.0f - z * z)), ph = 2.0f * PT_PI * u[2];
    *wi = pt_v3(r * cosf(ph), r * sinf(ph), z);
    return wi->z > 0.0f;
}
