#include "common/render.h"

#include <math.h>
#include <string.h>

#include "common/accel.h"
#include "common/alloc.h"
#include "common/bsdf.h"
#include "common/light.h"
#include "common/sampler.h"

/*
 * Sample dimensions. Pixel jitter uses dims 0-1; bounce k uses the 8 dims
 * starting at DIM_BOUNCE0 + 8k. 2D values start at even dimensions, so each
 * is one stratified pair of the sampler (sampler.h).
 */
enum {
    DIM_PIXEL = 0,
    DIM_BOUNCE0 = 4,
    DIM_PER_BOUNCE = 8,
    OFF_LIGHT_POINT = 0, /* 2D */
    OFF_BSDF_DIR = 2,    /* 2D */
    OFF_LIGHT_PICK = 4,  /* 2D with the lobe pick */
    OFF_RR = 6,
};

/* Bounces whose sampler seeds a pixel keeps; deeper ones hash theirs per use. */
#define SEED_CACHE 32u

/* One pixel's sampler state, shared by all of its samples: the seeds of the
 * pixel jitter's dimensions and, filled as paths first reach each depth, of
 * every bounce's 8 dimensions (sampler.h: pt_sample_group). Only seeds: the
 * values stay a pure function of (seed, pixel, index, dimension). */
typedef struct pixel_ctx {
    uint32_t px, py;
    uint32_t seed;
    uint32_t ngroups; /* bounce[0..ngroups) are filled */
    pt_sample_group jitter;
    pt_sample_group bounce[SEED_CACHE];
} pixel_ctx;

static void pixel_ctx_init(pixel_ctx *pc, const pt_renderer *r, uint32_t px, uint32_t py);

/* The integrator variants: a feature mask fixed at compile time, so that code
 * for features a scene lacks is folded away (see pick_variant). */
typedef pt_vec3 (*li_fn)(const pt_renderer *r, pixel_ctx *pc, uint32_t index,
                         pt_render_stats *stats);

struct pt_renderer {
    const pt_scene *scene;
    pt_accel *accel;
    pt_offset offset; /* pt_accel_offset(accel) */
    pt_lights *lights;
    pt_bsdf *mat_bsdf; /* per material: its BSDF when it has no texture */
    pt_render_params params;
    li_fn li;
    const char *variant;
    float tan_half_fov;
};

void pt_render_params_default(pt_render_params *p)
{
    p->seed = 0;
    p->max_depth = 16;
    p->rr_depth = 3;
    p->light_strategy = PT_LIGHT_MIS;
    p->extra_features = 0;
}

const pt_render_params *pt_renderer_params(const pt_renderer *r)
{
    return &r->params;
}
const char *pt_renderer_variant(const pt_renderer *r)
{
    return r->variant;
}

/* Power heuristic with beta = 2 (Veach 1997, eq. 9.13). */
static inline float power_heuristic(float pa, float pb)
{
    float a = pa * pa, b = pb * pb;
    return a + b > 0.0f ? a / (a + b) : 0.0f;
}

static inline pt_vec3 vert(const float *arr, uint32_t i)
{
    return pt_v3(arr[3 * i], arr[3 * i + 1], arr[3 * i + 2]);
}

/* Everything the integrator needs to know about a surface point. */
typedef struct surface {
    pt_vec3 p;  /* world position */
    pt_vec3 ng; /* geometric normal from the winding (unflipped) */
    pt_vec3 ns; /* shading normal */
    float uv[2];
    const pt_material *mat;
} surface;

static inline void surface_at(const pt_scene *s, const pt_hit *hit, surface *sf,
                              const uint32_t features)
{
    pt_accel_hit_point(s, hit, &sf->p, &sf->ng);
    const uint32_t *tri = &s->indices[3 * hit->tri];
    float b0 = 1.0f - hit->b1 - hit->b2;
    pt_vec3 n = pt_v3_add(pt_v3_add(pt_v3_scale(vert(s->normals, tri[0]), b0),
                                    pt_v3_scale(vert(s->normals, tri[1]), hit->b1)),
                          pt_v3_scale(vert(s->normals, tri[2]), hit->b2));
    float len = pt_v3_len(n);
    sf->ns = (len > 0.0f && isfinite(len)) ? pt_v3_scale(n, 1.0f / len) : sf->ng;
    sf->uv[0] = sf->uv[1] = 0.0f;
    if ((features & PT_FEAT_TEXTURES) && s->uvs) {
        const float *t = s->uvs;
        sf->uv[0] = b0 * t[2 * tri[0]] + hit->b1 * t[2 * tri[1]] + hit->b2 * t[2 * tri[2]];
        sf->uv[1] =
            b0 * t[2 * tri[0] + 1] + hit->b1 * t[2 * tri[1] + 1] + hit->b2 * t[2 * tri[2] + 1];
    }
    sf->mat = &s->materials[s->tri_material[hit->tri]];
}

/* max(a, b) as fmaxf gives it (a NaN argument is ignored), by comparisons:
 * fmaxf is a library call without -ffinite-math-only. Only the sign of a
 * zero result may differ, which no caller can see. */
static inline float max2(float a, float b)
{
    return (a > b || b != b) ? a : b;
}

/* pt_v3_max_comp(v) > 0, exactly (fmaxf ignores NaNs; so does this). */
static inline int any_positive(pt_vec3 v)
{
    return v.x > 0.0f || v.y > 0.0f || v.z > 0.0f;
}

/* The BSDF of a material without textures: the work of material_bsdf below,
 * done once per material (pt_renderer_new) instead of at every hit. */
static pt_bsdf material_bsdf_untextured(const pt_material *m)
{
    return pt_bsdf_setup(pt_v3(m->base_color[0], m->base_color[1], m->base_color[2]), m->metallic,
                         m->roughness, m->specular,
                         pt_v3(m->specular_color[0], m->specular_color[1], m->specular_color[2]));
}

static inline pt_bsdf material_bsdf(const pt_renderer *r, const surface *sf,
                                    const uint32_t features)
{
    const pt_scene *s = r->scene;
    const pt_material *m = sf->mat;
    if (!(features & PT_FEAT_TEXTURES) || (m->base_color_tex < 0 && m->metal_rough_tex < 0)) {
        /* pt_bsdf_setup's result for the material's own factors; without
         * PT_FEAT_GLOSSY only its diffuse (the clamped base colour times
         * 1 - 0) is read, the same bits as the branch below. */
        return r->mat_bsdf[m - s->materials];
    }
    pt_vec3 base = pt_v3(m->base_color[0], m->base_color[1], m->base_color[2]);
    float metallic = m->metallic, roughness = m->roughness;
    if (features & PT_FEAT_TEXTURES) {
        float t[4];
        if (m->base_color_tex >= 0) {
            pt_texture_sample(&s->textures[m->base_color_tex], sf->uv[0], sf->uv[1], t);
            base = pt_v3_mul(base, pt_v3(t[0], t[1], t[2]));
        }
        if (m->metal_rough_tex >= 0) {
            pt_texture_sample(&s->textures[m->metal_rough_tex], sf->uv[0], sf->uv[1], t);
            roughness *= t[1];
            metallic *= t[2];
        }
    }
    if (!(features & PT_FEAT_GLOSSY)) {
        /* pt_bsdf_setup's diffuse for metallic 0: the clamped base times 1. */
        pt_bsdf b;
        memset(&b, 0, sizeof b);
        b.diffuse = pt_v3(fminf(fmaxf(base.x, 0.0f), 1.0f), fminf(fmaxf(base.y, 0.0f), 1.0f),
                          fminf(fmaxf(base.z, 0.0f), 1.0f));
        return b;
    }
    return pt_bsdf_setup(base, metallic, roughness, m->specular,
                         pt_v3(m->specular_color[0], m->specular_color[1], m->specular_color[2]));
}

/*
 * Lambert-only scenes (no PT_FEAT_GLOSSY: every material has metallic 0 and
 * specularFactor 0): the glTF BSDF is diffuse / pi with a Fresnel weight of
 * exactly 1 and the diffuse lobe always chosen. These repeat pt_bsdf_eval and
 * pt_bsdf_sample's arithmetic for that case operation for operation
 * ((1 - 0) * cos = cos exactly), so the pixels are bit-identical to the
 * general integrator's; they skip the lobe choice, Fresnel and GGX terms.
 */
static inline pt_vec3 bsdf_eval(const pt_bsdf *b, pt_vec3 wo, pt_vec3 wi, float *pdf,
                                const uint32_t features)
{
    if (features & PT_FEAT_GLOSSY)
        return pt_bsdf_eval(b, wo, wi, pdf);
    if (!(wo.z > 0.0f) || !(wi.z > 0.0f)) {
        *pdf = 0.0f;
        return pt_v3(0.0f, 0.0f, 0.0f);
    }
    float c = wi.z * PT_INV_PI;
    *pdf = c;
    return pt_v3_scale(b->diffuse, c);
}

static inline pt_vec3 bsdf_sample(const pt_bsdf *b, pt_vec3 wo, const float u[3], pt_vec3 *wi,
                                  float *pdf, const uint32_t features)
{
    if (features & PT_FEAT_GLOSSY)
        return pt_bsdf_sample(b, wo, u, wi, pdf);
    pt_vec3 zero = pt_v3(0.0f, 0.0f, 0.0f);
    *pdf = 0.0f;
    *wi = pt_v3(0.0f, 0.0f, 1.0f);
    if (!(wo.z > 0.0f))
        return zero;
    *wi = pt_sample_cosine_hemisphere(u[1], u[2]);
    if (!(wi->z > 0.0f))
        return zero;
    pt_vec3 f = bsdf_eval(b, wo, *wi, pdf, features);
    if (!(*pdf > 0.0f)) {
        *pdf = 0.0f;
        return zero;
    }
    return pt_v3_scale(f, 1.0f / *pdf);
}

static inline int emits(const pt_material *m)
{
    return m->emissive[0] > 0.0f || m->emissive[1] > 0.0f || m->emissive[2] > 0.0f;
}

static inline void camera_ray(const pt_renderer *r, uint32_t px, uint32_t py, const float u[2],
                              pt_vec3 *o, pt_vec3 *d)
{
    const pt_camera *c = &r->scene->camera;
    float w = (float)r->params.width, h = (float)r->params.height;
    /* Box filter: a uniform point in the pixel; y grows downwards in the image. */
    float sx = (2.0f * ((float)px + u[0]) / w - 1.0f) * r->tan_half_fov * (w / h);
    float sy = (1.0f - 2.0f * ((float)py + u[1]) / h) * r->tan_half_fov;
    *o = c->position;
    *d = pt_v3_norm(
        pt_v3_add(c->forward, pt_v3_add(pt_v3_scale(c->right, sx), pt_v3_scale(c->up, sy))));
}

/*
 * One path. NEE samples an emissive triangle at every vertex; the BSDF-sampled
 * continuation that hits an emitter adds its emission weighted by the power
 * heuristic against the light pdf, so each light path is counted once
 * (Veach 1997, sec. 9.2). Russian roulette after rr_depth bounces keeps
 * throughput-weighted survival (survival probability max(beta), at most 0.95).
 */
static inline __attribute__((always_inline)) pt_vec3 li_impl(const pt_renderer *r, pixel_ctx *pc,
                                                             uint32_t index, pt_render_stats *stats,
                                                             const uint32_t features,
                                                             const pt_ray_sink *sink)
{
    const pt_scene *s = r->scene;
    float u2[2];
    pt_sample_group_eval2(&pc->jitter, index, u2);
    pt_vec3 o, d;
    camera_ray(r, pc->px, pc->py, u2, &o, &d);

    pt_vec3 L = pt_v3(0, 0, 0), beta = pt_v3(1, 1, 1);
    pt_vec3 prev_p = o;
    float prev_pdf = 0.0f; /* 0: the previous vertex was the camera (no MIS) */
    uint64_t rays = 0;
    const uint32_t strategy = r->params.light_strategy;
    const int has_lights = (features & PT_FEAT_EMITTERS) && pt_lights_count(r->lights) > 0 &&
                           strategy != PT_LIGHT_BSDF_ONLY;

    for (uint32_t depth = 0;; depth++) {
        /* All 8 numbers of the bounce at once (the light pick and the lobe
         * pick are one pair: one index shuffle), drawn before the ray is
         * traced: they do not depend on the hit, and the scrambles' long
         * dependency chain then overlaps the ray query instead of following
         * it. (A missed ray wastes them; a miss ends the path anyway.) */
        float u[DIM_PER_BOUNCE];
        {
            pt_sample_group deep;
            const pt_sample_group *g = &deep;
            if (depth < SEED_CACHE) {
                while (pc->ngroups <= depth) {
                    pt_sample_group_init(&pc->bounce[pc->ngroups], pc->seed,
                                         DIM_BOUNCE0 + DIM_PER_BOUNCE * pc->ngroups);
                    pc->ngroups++;
                }
                g = &pc->bounce[depth];
            } else {
                pt_sample_group_init(&deep, pc->seed, DIM_BOUNCE0 + DIM_PER_BOUNCE * depth);
            }
            pt_sample_group_eval(g, index, u);
        }

        pt_hit hit;
        rays++;
        if (sink)
            sink->ray(sink->user, o, d, INFINITY, 0);
        if (!pt_accel_intersect(r->accel, o, d, INFINITY, &hit))
            break;
        surface sf;
        surface_at(s, &hit, &sf, features);
        pt_vec3 wo = pt_v3_neg(d);

        if ((features & PT_FEAT_EMITTERS) && emits(sf.mat)) {
            pt_vec3 le = pt_emitted(s, hit.tri, hit.b1, hit.b2, wo);
            if (prev_pdf > 0.0f && strategy == PT_LIGHT_MIS) {
                float lp = pt_lights_pdf(r->lights, s, hit.tri, prev_p, sf.p, sf.ng);
                le = pt_v3_scale(le, power_heuristic(prev_pdf, lp));
            }
            if (prev_pdf == 0.0f || strategy != PT_LIGHT_NEE_ONLY)
                L = pt_v3_add(L, pt_v3_mul(beta, le));
        }
        if (depth >= r->params.max_depth)
            break;

        /* Shade on the side the ray arrived from; single-sided surfaces are
         * treated as two-sided for scattering (only emission is one-sided). */
        pt_vec3 ng = sf.ng;
        if (pt_v3_dot(ng, wo) < 0.0f)
            ng = pt_v3_neg(ng);
        pt_vec3 ns = sf.ns;
        if (pt_v3_dot(ns, ng) < 0.0f)
            ns = pt_v3_neg(ns);
        if (pt_v3_dot(ns, wo) <= 0.0f)
            ns = ng; /* interpolated normal faces away from the viewer */
        pt_frame fr = pt_frame_from_normal(ns);
        pt_vec3 wo_l = pt_frame_to_local(&fr, wo);
        pt_bsdf bsdf = material_bsdf(r, &sf, features);
        if (has_lights) {
            float u3[3];
            u3[0] = u[OFF_LIGHT_PICK];
            u3[1] = u[OFF_LIGHT_POINT];
            u3[2] = u[OFF_LIGHT_POINT + 1];
            pt_light_sample ls;
            if (pt_lights_sample(r->lights, s, sf.p, u3, &ls) && ls.pdf > 0.0f &&
                any_positive(ls.radiance) && pt_v3_dot(ls.wi, ng) > 0.0f) {
                float bpdf;
                pt_vec3 f = bsdf_eval(&bsdf, wo_l, pt_frame_to_local(&fr, ls.wi), &bpdf, features);
                if (any_positive(f)) {
                    pt_vec3 from = pt_offset_apply(r->offset, sf.p, ng);
                    pt_vec3 nl = ls.normal;
                    if (pt_v3_dot(nl, ls.wi) > 0.0f)
                        nl = pt_v3_neg(nl);
                    pt_vec3 to = pt_offset_apply(r->offset, ls.position, nl);
                    pt_vec3 sd = pt_v3_sub(to, from);
                    float dist = pt_v3_len(sd);
                    rays++;
                    pt_vec3 sdir = pt_v3_scale(sd, dist > 0.0f ? 1.0f / dist : 0.0f);
                    if (sink && dist > 0.0f)
                        sink->ray(sink->user, from, sdir, dist, 1);
                    if (dist > 0.0f && !pt_accel_occluded(r->accel, from, sdir, dist)) {
                        float w =
                            (strategy == PT_LIGHT_MIS ? power_heuristic(ls.pdf, bpdf) : 1.0f) /
                            ls.pdf;
                        L = pt_v3_add(L,
                                      pt_v3_mul(beta, pt_v3_scale(pt_v3_mul(f, ls.radiance), w)));
                    }
                }
            }
        }

        float u3[3];
        u3[0] = u[OFF_LIGHT_PICK + 1];
        u3[1] = u[OFF_BSDF_DIR];
        u3[2] = u[OFF_BSDF_DIR + 1];
        pt_vec3 wi_l;
        float pdf;
        pt_vec3 weight = bsdf_sample(&bsdf, wo_l, u3, &wi_l, &pdf, features);
        if (!(pdf > 0.0f) || !any_positive(weight))
            break;
        pt_vec3 wi = pt_frame_to_world(&fr, wi_l);
        if (pt_v3_dot(wi, ng) <= 0.0f)
            break; /* below the geometric surface: reflection only */
        beta = pt_v3_mul(beta, weight);

        if (depth + 1 >= r->params.rr_depth) {
            /* fminf(pt_v3_max_comp(beta), 0.95f) by comparisons (a NaN max
             * gives 0.95 as fminf does). */
            float m = max2(beta.x, max2(beta.y, beta.z));
            float survive = m < 0.95f ? m : 0.95f;
            if (!(u[OFF_RR] < survive))
                break;
            beta = pt_v3_scale(beta, 1.0f / survive);
        }
        prev_p = sf.p;
        prev_pdf = pdf;
        o = pt_offset_apply(r->offset, sf.p, ng);
        d = wi;
    }
    if (stats)
        stats->rays += rays;
    return L;
}

#define ALL_FEATURES 0xffffffffu
#define VARIANT(name, feat)                                                                        \
    static pt_vec3 name(const pt_renderer *r, pixel_ctx *pc, uint32_t index,                       \
                        pt_render_stats *stats)                                                    \
    {                                                                                              \
        return li_impl(r, pc, index, stats, (feat), NULL);                                         \
    }
#define NO_TEX (uint32_t)(PT_FEAT_TEXTURES | PT_FEAT_EMISSIVE_TEX)
VARIANT(li_general, ALL_FEATURES)
VARIANT(li_untextured, ALL_FEATURES & ~NO_TEX)
VARIANT(li_lambert, ALL_FEATURES & ~(uint32_t)PT_FEAT_GLOSSY)
VARIANT(li_lambert_untextured, ALL_FEATURES & ~NO_TEX & ~(uint32_t)PT_FEAT_GLOSSY)
#undef VARIANT

/* The most specialised variant whose assumptions the scene meets. */
static void pick_variant(pt_renderer *r, uint32_t features)
{
    int tex = (features & NO_TEX) != 0, glossy = (features & PT_FEAT_GLOSSY) != 0;
    if (glossy) {
        r->li = tex ? li_general : li_untextured;
        r->variant = tex ? "general" : "untextured";
    } else {
        r->li = tex ? li_lambert : li_lambert_untextured;
        r->variant = tex ? "lambert" : "lambert-untextured";
    }
}

pt_status pt_renderer_new(const pt_scene *scene, const pt_render_params *params, pt_renderer **out,
                          pt_error *err)
{
    if (params->width == 0 || params->height == 0)
        return pt_error_set(err, PT_ERR_ARG, "image size %ux%u is empty", params->width,
                            params->height);
    if (!(scene->camera.yfov > 0.0f && scene->camera.yfov < PT_PI))
        return pt_error_set(err, PT_ERR_ARG, "camera field of view %g rad is not in (0, pi)",
                            (double)scene->camera.yfov);
    pt_renderer *r = pt_calloc(1, sizeof *r);
    if (!r)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory for the renderer");
    pt_status st;
    r->scene = scene;
    r->params = *params;
    r->tan_half_fov = tanf(0.5f * scene->camera.yfov);
    if ((st = pt_accel_new(scene, &r->accel, err)) != PT_OK)
        goto fail;
    if ((st = pt_lights_new(scene, &r->lights, err)) != PT_OK)
        goto fail;
    r->offset = pt_accel_offset(r->accel);
    if (scene->num_materials > 0) {
        r->mat_bsdf = pt_malloc_array(scene->num_materials, sizeof *r->mat_bsdf);
        if (!r->mat_bsdf) {
            st = pt_error_set(err, PT_ERR_NOMEM, "out of memory for the renderer");
            goto fail;
        }
        for (uint32_t i = 0; i < scene->num_materials; i++)
            r->mat_bsdf[i] = material_bsdf_untextured(&scene->materials[i]);
    }
    pick_variant(r, scene->features | params->extra_features);
    *out = r;
    return PT_OK;
fail:
    pt_renderer_free(r);
    return st;
}

void pt_renderer_free(pt_renderer *r)
{
    if (!r)
        return;
    pt_free(r->mat_bsdf);
    pt_lights_free(r->lights);
    pt_accel_free(r->accel);
    pt_free(r);
}

static void pixel_ctx_init(pixel_ctx *pc, const pt_renderer *r, uint32_t px, uint32_t py)
{
    pc->px = px;
    pc->py = py;
    pc->seed = pt_pixel_seed(r->params.seed, px, py);
    pc->ngroups = 0;
    pt_sample_group_init(&pc->jitter, pc->seed, DIM_PIXEL);
}

pt_vec3 pt_render_sample(const pt_renderer *r, uint32_t px, uint32_t py, uint32_t index,
                         pt_render_stats *stats)
{
    pixel_ctx pc;
    pixel_ctx_init(&pc, r, px, py);
    return r->li(r, &pc, index, stats);
}

pt_vec3 pt_render_sample_traced(const pt_renderer *r, uint32_t px, uint32_t py, uint32_t index,
                                const pt_ray_sink *sink)
{
    pixel_ctx pc;
    pixel_ctx_init(&pc, r, px, py);
    return li_impl(r, &pc, index, NULL, ALL_FEATURES, sink);
}

void pt_render_tile(const pt_renderer *r, pt_rect tile, uint32_t s0, uint32_t s1, pt_pixel_acc *out,
                    pt_render_stats *stats)
{
    pt_render_stats local = {0, 0, 0};
    uint32_t tw = tile.x1 - tile.x0;
    for (uint32_t y = tile.y0; y < tile.y1; y++) {
        for (uint32_t x = tile.x0; x < tile.x1; x++) {
            pt_pixel_acc *a = &out[(size_t)(y - tile.y0) * tw + (x - tile.x0)];
            memset(a, 0, sizeof *a);
            pixel_ctx pc;
            pixel_ctx_init(&pc, r, x, y);
            /* Sum each aligned block of PT_SAMPLE_BLOCK samples on its own, then
             * add the block sums in order: the result for [s0,s1) is then the
             * same bits as adding the results of any split at block boundaries. */
            for (uint32_t b0 = s0; b0 < s1;) {
                uint32_t b1 = (b0 / PT_SAMPLE_BLOCK + 1) * PT_SAMPLE_BLOCK;
                if (b1 > s1 || b1 < b0)
                    b1 = s1;
                pt_pixel_acc blk = {{0, 0, 0}, 0, 0, 0};
                for (uint32_t i = b0; i < b1; i++) {
                    pt_vec3 c = r->li(r, &pc, i, &local);
                    if (!pt_isfinite3(c)) {
                        local.rejected++;
                        continue;
                    }
                    double lum = (double)pt_luminance(c);
                    blk.sum[0] += c.x;
                    blk.sum[1] += c.y;
                    blk.sum[2] += c.z;
                    blk.sum_sq += lum * lum;
                    blk.n++;
                }
                pt_pixel_acc_add(a, &blk);
                local.samples += blk.n;
                b0 = b1;
            }
        }
    }
    if (stats) {
        stats->samples += local.samples;
        stats->rejected += local.rejected;
        stats->rays += local.rays;
    }
}
