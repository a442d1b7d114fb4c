/*
 * render.h - the integrator and the unit of work a worker runs.
 *
 * Unidirectional path tracing: next-event estimation on emissive triangles and
 * BSDF sampling, combined by multiple importance sampling with the power
 * heuristic (Veach 1997, ch. 9); Russian roulette on throughput after
 * rr_depth bounces. Every random number is pt_sample_*(pixel seed, sample
 * index, dimension), so a pixel's samples [a,b) are the same numbers however
 * the range is split. pt_render_tile sums each aligned block of
 * PT_SAMPLE_BLOCK samples in sample order in double (pt_block_acc), rounds the
 * block's sums to fixed point (pt_pixel_acc_add_block, tile.h) and adds the
 * blocks as integers, exactly. So rendering [s0,s1) gives the same bits as
 * rendering any split of it at multiples of PT_SAMPLE_BLOCK (parts of any
 * sizes) and adding the parts with pt_pixel_acc_add in any order: the farm
 * may size every task differently. (A split inside a block is only equal to
 * rounding.)
 * A sample with a NaN or Inf component, or one above PT_MAX_SAMPLE_RADIANCE in
 * magnitude, is not accumulated; it is counted.
 * The renderer is immutable after pt_renderer_new; pt_render_tile is
 * thread-safe and allocates nothing.
 */
#ifndef PT_COMMON_RENDER_RENDER_H
#define PT_COMMON_RENDER_RENDER_H

#include <math.h>
#include <stdint.h>

#include "common/base/error.h"
#include "common/render/tile.h"
#include "common/scene/scene.h"

typedef struct pt_env pt_env; /* common/render/env.h */

/* One block's sums in double, in sample order: the part of the sum that is
 * floating point, kept to at most PT_SAMPLE_BLOCK samples. */
typedef struct pt_block_acc {
    double sum[3];
    double sum_sq;
    uint32_t n, hits;
} pt_block_acc;

/* Adds one sample's radiance to b; a sample with a component not finite or
 * above PT_MAX_SAMPLE_RADIANCE in magnitude is left out and returns 0 (the
 * caller counts it as rejected). */
static inline int pt_block_acc_sample(pt_block_acc *b, pt_vec3 c)
{
    const float cap = (float)PT_MAX_SAMPLE_RADIANCE;
    /* NaN fails every comparison, and Inf is above the cap. */
    if (!(fabsf(c.x) <= cap && fabsf(c.y) <= cap && fabsf(c.z) <= cap))
        return 0;
    double lum = (double)pt_luminance(c);
    b->sum[0] += c.x;
    b->sum[1] += c.y;
    b->sum[2] += c.z;
    b->sum_sq += lum * lum;
    b->n++;
    return 1;
}

/* x (a sum) in fixed point, rounded to nearest (ties to even): a pure function
 * of x. |x| must be below 2^94 (a block's sum is at most 1.6e19 < 2^64). */
static inline pt_i128 pt_fixed_of(double x)
{
    double v = nearbyint(x * PT_FIXED_ONE); /* exact scaling by a power of 2 */
    if (fabs(v) < 0x1p62)
        return (pt_i128)(int64_t)v;
    return (pt_i128)v;
}

/* x >= 0 (a sum of squares) in fixed point (units of 2^-48), rounded to
 * nearest, saturating at PT_U128_MAX; NaN or a negative x gives 0. */
static inline pt_u128 pt_ufixed_of(double x)
{
    double v = nearbyint(x * PT_FIXED_SQ_ONE);
    if (!(v > 0.0))
        return 0;
    if (v < 0x1p63)
        return (pt_u128)(uint64_t)v;
    if (v >= 0x1p128)
        return PT_U128_MAX;
    return (pt_u128)v;
}

/* A pt_pixel_acc of the double sums given, each rounded as a block's sum is
 * (pt_fixed_of; |r|, |g|, |b| below 2^94): for tests and benchmarks. */
static inline pt_pixel_acc pt_pixel_acc_of(double r, double g, double b, double sum_sq, uint32_t n,
                                           uint32_t hits)
{
    pt_pixel_acc a = {
        {pt_fixed_of(r), pt_fixed_of(g), pt_fixed_of(b)}, pt_ufixed_of(sum_sq), n, hits};
    return a;
}

/* a += the block b, its sums rounded to fixed point. */
static inline void pt_pixel_acc_add_block(pt_pixel_acc *a, const pt_block_acc *b)
{
    a->fsum[0] += pt_fixed_of(b->sum[0]);
    a->fsum[1] += pt_fixed_of(b->sum[1]);
    a->fsum[2] += pt_fixed_of(b->sum[2]);
    a->fsum_sq = pt_u128_sat_add(a->fsum_sq, pt_ufixed_of(b->sum_sq));
    a->n += b->n;
    a->hits += b->hits;
}

/* What one sample gives the render passes (PT_PASS_*, tile.h): the albedo
 * of its first non-specular surface (times the specular chain's throughput
 * before it), that surface's shading normal (world space, facing the ray),
 * the camera distance of its first hit and that hit's emission. Zero where
 * the path escapes before reaching them. */
typedef struct pt_pass_sample {
    pt_vec3 albedo, normal, emission;
    float depth;
    uint32_t crypto[PT_CRYPTO_KINDS]; /* the first hit's object and material Cryptomatte ids
                                         (crypto.h; 0: none, as where the ray escapes) */
} pt_pass_sample;

/* One block's pass sums in double, in sample order (pt_block_acc's twin). */
typedef struct pt_pass_block {
    double s[PT_PASS_SUMS];
    double sq[PT_PASS_SQS];
    uint32_t n_even;
    /* Cryptomatte: the block's ids and counts, exact (a block has at most
     * PT_SAMPLE_BLOCK samples), ascending, unused last. */
    uint32_t cid[PT_CRYPTO_KINDS][PT_SAMPLE_BLOCK];
    uint32_t ccnt[PT_CRYPTO_KINDS][PT_SAMPLE_BLOCK];
} pt_pass_block;

/* A pass value that is not finite or is above PT_MAX_SAMPLE_RADIANCE in
 * magnitude counts as 0 (the beauty decides whether a sample is kept). */
static inline double pt_pass_value(float v)
{
    const float cap = (float)PT_MAX_SAMPLE_RADIANCE;
    return fabsf(v) <= cap ? (double)v : 0.0;
}

/* Adds sample `index` (accepted into the beauty's block: c is its radiance)
 * to b. */
static inline void pt_pass_block_sample(pt_pass_block *b, const pt_pass_sample *ps, pt_vec3 c,
                                        uint32_t index)
{
    const pt_vec3 *v3[3] = {&ps->albedo, &ps->normal, &ps->emission};
    for (int k = 0; k < 3; k++) {
        double x = pt_pass_value(v3[k]->x), y = pt_pass_value(v3[k]->y),
               z = pt_pass_value(v3[k]->z);
        b->s[3 * k] += x;
        b->s[3 * k + 1] += y;
        b->s[3 * k + 2] += z;
        b->sq[k] += x * x + y * y + z * z;
    }
    double d = pt_pass_value(ps->depth);
    b->s[PT_PS_DEPTH] += d;
    b->sq[PT_PQ_DEPTH] += d * d;
    for (int k = 0; k < PT_CRYPTO_KINDS; k++) {
        /* Insertion into the ascending list: at most 16 entries. */
        uint32_t id = ps->crypto[k], *ids = b->cid[k], *cnt = b->ccnt[k];
        unsigned j = 0;
        while (j < PT_SAMPLE_BLOCK && cnt[j] && ids[j] < id)
            j++;
        if (j < PT_SAMPLE_BLOCK && cnt[j] && ids[j] == id) {
            cnt[j]++;
        } else if (j < PT_SAMPLE_BLOCK) {
            for (unsigned m = PT_SAMPLE_BLOCK - 1; m > j; m--) {
                ids[m] = ids[m - 1];
                cnt[m] = cnt[m - 1];
            }
            ids[j] = id;
            cnt[j] = 1;
        }
    }
    if (!(index & 1u)) {
        b->s[PT_PS_EVEN] += c.x;
        b->s[PT_PS_EVEN + 1] += c.y;
        b->s[PT_PS_EVEN + 2] += c.z;
        b->n_even++;
    }
}

/* a += the block b, its sums rounded to fixed point (pt_fixed_of and
 * pt_ufixed_of, as the beauty's). */
static inline void pt_pass_acc_add_block(pt_pass_acc *a, const pt_pass_block *b)
{
    for (int i = 0; i < PT_PASS_SUMS; i++)
        a->s[i] += pt_fixed_of(b->s[i]);
    for (int i = 0; i < PT_PASS_SQS; i++)
        a->sq[i] = pt_u128_sat_add(a->sq[i], pt_ufixed_of(b->sq[i]));
    for (int k = 0; k < PT_CRYPTO_KINDS; k++)
        if (b->ccnt[k][0])
            pt_crypto_merge(a->cid[k], a->ccnt[k], b->cid[k], b->ccnt[k], PT_SAMPLE_BLOCK);
    a->n_even += b->n_even;
}

/* How emitters are reached: both strategies weighted by MIS (the default),
 * or one alone (unweighted), which tests use to check each is unbiased. */
enum { PT_LIGHT_MIS = 0, PT_LIGHT_NEE_ONLY = 1, PT_LIGHT_BSDF_ONLY = 2 };

/* The default bound on bounces. Russian roulette (from rr_depth on, survival
 * at most 0.95 a bounce) is what ends paths, without bias; this cap only
 * stops a pathological scene. A path reaches it with probability at most
 * 0.95^(1024 - 3), about 1e-23, so the bias it leaves is below any float's
 * resolution. The old default of 16 biased a white furnace of albedo 0.8 by
 * 0.8^17 = 2.3 % (4.887 for 5). */
#define PT_RENDER_DEFAULT_MAX_DEPTH 1024u

typedef struct pt_render_params {
    uint32_t width, height;
    uint32_t seed;
    uint32_t max_depth;      /* maximum scattering events (bounces) per path;
                                default PT_RENDER_DEFAULT_MAX_DEPTH */
    uint32_t rr_depth;       /* Russian roulette from this many bounces on; default 3 */
    uint32_t light_strategy; /* PT_LIGHT_*; default PT_LIGHT_MIS */
    uint32_t extra_features; /* PT_FEAT_* assumed present besides the scene's own, which
                                picks a less specialised integrator (0xffffffff: the
                                general one); for tests and benchmarks; default 0 */
    const pt_env *env;       /* the environment light (env.h) or NULL; it must outlive the
                                renderer; default NULL */
    uint32_t scalar_shading; /* 1: the Lambert variants shade one path at a time, as
                                they do where SIMD lanes are slow (pt_simd_lanes_fast);
                                the same bits; for tests and benchmarks; default 0 */
    uint32_t guiding;        /* 1: renders may be handed a path-guiding distribution
                                (pt_render_tile_guided); picks the guided variant when the
                                scene has glossy materials; default 0 */
    uint32_t bdpt;           /* 1: bidirectional path tracing (render.c, bd_sample): a
                                light path from the emitters joined to every camera
                                vertex; scenes lit by emissive surfaces alone, without
                                glass (pt_renderer_new refuses others), and without
                                guiding, passes or clamping; default 0 */
    uint32_t transparent;    /* 1: a camera ray that escapes adds nothing (the environment
                                still lights the scene through bounces and NEE), so RGB is
                                premultiplied by the coverage, pt_pixel_acc.hits / n
                                (Cycles' "film transparent"); default 0 */
    /* Sample clamping (biased; 0, the default: off), as Cycles' Clamp Direct
     * and Clamp Indirect: a contribution to a sample whose R + G + B passes
     * the limit is scaled down to it. Direct: light reaching the camera or
     * the first surface the camera sees; indirect: after more bounces.
     * Either non-zero picks the clamped variant (or the guided one). */
    float clamp_direct, clamp_indirect;
    uint32_t passes;       /* PT_PASS_* (tile.h): render passes; non-zero picks the
                              passes variant (the general one that also records them,
                              pt_render_tile_passes); the beauty keeps its bits;
                              default 0 */
    uint32_t light_select; /* PT_LIGHT_SELECT_* (light.h): how NEE chooses among the
                              emissive triangles, with PT_LIGHT_SOLID_ANGLE or'd in to
                              sample large near lights by solid angle (taken only in
                              scenes that are not Lambert-only); for tests and
                              benchmarks; default PT_LIGHT_SELECT_AUTO (0: the light
                              tree from PT_LIGHT_TREE_MIN to _AUTO_MAX lights, area sampling) */
    /* 1: shadow rays stop at thin smooth glass as they did before
     * PT_FEAT_THIN_GLASS (BSDF sampling alone finds light through it); for
     * tests and benchmarks; default 0 */
    uint32_t opaque_thin_glass;
    /* 1: no manifold next-event estimation through or off smooth glass
     * (PT_FEAT_MANIFOLD; BSDF sampling alone finds the light that arrives
     * through it or off it, as before); for tests and benchmarks; default 0 */
    uint32_t no_manifold;
    /* 1: manifold NEE through thick glass only, no reflection chains off
     * smooth glass or smooth opaque surfaces; for tests and benchmarks;
     * default 0 */
    uint32_t no_mirror;
    /* Manifold NEE takes only the environment's light samples brighter
     * than this many times the map's mean luminance (the lamps, whose
     * caustics BSDF sampling finds as fireflies); BSDF sampling alone
     * finds the rest, in both strategies' weights alike, so any value is
     * unbiased. For tests and benchmarks; default PT_MANIFOLD_MIN_LIGHT. */
    float manifold_min_light;
} pt_render_params;

/* pt_render_params.manifold_min_light's default: on the glass ball with
 * things inside (docs/bench/manifold.md) 16 took 7 % less time than 0 for
 * 0.1 to 0.4 % more error at 128 spp; 64 and 256 saved more time (12 %,
 * 16 %) but lost more error (2 to 8 %, 3 to 14 %). */
#define PT_MANIFOLD_MIN_LIGHT 16.0f

/* The most thin smooth walls (PT_FEAT_THIN_GLASS) a shadow ray crosses; one
 * that meets more is blocked (pt_render_stats.dropped), and a path that
 * crosses more by sampling counts what it then finds in full, so the two
 * strategies still sum to the same expectation. */
#define PT_SHADOW_CROSSINGS 8u

typedef struct pt_render_stats {
    uint64_t samples;  /* accepted samples */
    uint64_t rejected; /* NaN/Inf samples dropped */
    uint64_t rays;     /* closest-hit + shadow rays traced */
    uint64_t capped;   /* paths ended by max_depth (a hit they could not scatter from),
                          not by Russian roulette, absorption or escape */
    uint64_t clamped;  /* contributions scaled down by clamp_direct / clamp_indirect */
    /* Thin smooth walls that shadow rays crossed (PT_FEAT_THIN_GLASS), and
     * shadow rays blocked for meeting more than they may cross. */
    uint64_t crossings;
    uint64_t dropped;
    /* Chains of refractions through thick smooth glass that manifold NEE
     * connected to a light: the environment, a punctual light or an emitter
     * (PT_FEAT_MANIFOLD). */
    uint64_t chains;
} pt_render_stats;

typedef struct pt_renderer pt_renderer;

/* Fills defaults (max_depth PT_RENDER_DEFAULT_MAX_DEPTH, rr_depth 3, seed 0, MIS) into p, keeping
 * width/height. */
void pt_render_params_default(pt_render_params *p);

/* Builds the acceleration structure and lights for a scene, and picks the
 * integrator variant specialised to scene->features. The scene must outlive
 * the renderer. */
pt_status pt_renderer_new(const pt_scene *scene, const pt_render_params *params, pt_renderer **out,
                          pt_error *err);
void pt_renderer_free(pt_renderer *r); /* accepts NULL */
const pt_render_params *pt_renderer_params(const pt_renderer *r);

/* The integrator variant chosen for the scene ("general", "lambert", ...).
 * Every variant gives the same bits as the general one; it only skips work. */
const char *pt_renderer_variant(const pt_renderer *r);
/* The camera rays leave from: the scene's, or for a framed one (no camera
 * in the file) pt_camera_frame of the scene's bounds at the image's aspect. */
const pt_camera *pt_renderer_camera(const pt_renderer *r);

/* 1 when the variant shades 8 paths at a time in SIMD lanes (the Lambert
 * variants, on a processor where the lanes are fast). */
int pt_renderer_lanes(const pt_renderer *r);

/* 1 when the renderer tries manifold chains (light through smooth glass,
 * off smooth metal): the scene has a surface and a light a chain can
 * connect, and no option turned them off. */
int pt_renderer_chains(const pt_renderer *r);

/* PT_OK when bidirectional path tracing (pt_render_params.bdpt) can render
 * scene: lit by emissive triangles, point, spot and directional lights,
 * an environment (has_env: a map or a background) or
 * any of them, with opaque materials (no transmission, no unlit), and
 * without guiding or clamping (render passes it records as the other
 * variants do); else
 * PT_ERR_ARG saying what stands in the way, in words for the user (the
 * coordinator refuses such a job when it is submitted; pt_renderer_new
 * refuses the same). Any thread. */
pt_status pt_render_check_bdpt(const pt_scene *scene, int has_env, int guiding, int clamped,
                               pt_error *err);

/* PT_OK when the scene has a light source (an emissive triangle, a punctual
 * light) or has_env (an environment map or uniform background is given);
 * else PT_ERR_ARG with a message naming the scene (name) that says how to
 * light it, since it would render black. Standalone, one-job and queue mode
 * all refuse with this one message. */
pt_status pt_render_check_lit(const pt_scene *scene, int has_env, const char *name, pt_error *err);

/* Path guiding for one pass (common/render/guide.h): the distribution its
 * renders sample, the chance a guided vertex draws from it (0: the guide
 * only defines the statistics' cells: nothing is sampled from it, as in a
 * first pass), and the calling thread's statistics to record into (NULL:
 * none). A vertex is guided where the closure has a diffuse lobe or a rough
 * GGX lobe and no glass interface (render.c, closure_guidable). */
typedef struct pt_guide pt_guide;
typedef struct pt_guide_stats pt_guide_stats;
typedef struct pt_render_guiding {
    const pt_guide *guide;
    float prob;
    pt_guide_stats *stats;
} pt_render_guiding;

/* Renders samples [s0, s1) of every pixel of tile and writes one pt_pixel_acc
 * per pixel (row-major over the tile, (x1-x0)*(y1-y0) entries, overwritten).
 * stats (may be NULL) is added to. */
void pt_render_tile(const pt_renderer *r, pt_rect tile, uint32_t s0, uint32_t s1, pt_pixel_acc *out,
                    pt_render_stats *stats);
/* The same with path guiding (gd may be NULL: as pt_render_tile; a renderer
 * made without params.guiding ignores it). */
void pt_render_tile_guided(const pt_renderer *r, pt_rect tile, uint32_t s0, uint32_t s1,
                           pt_pixel_acc *out, pt_render_stats *stats, const pt_render_guiding *gd);

/* pt_render_tile_guided that also writes each pixel's pass sums into pout
 * (one pt_pass_acc per pixel, like out; NULL: none), over the same samples
 * as out. A renderer made without params.passes writes zeros there. */
void pt_render_tile_passes(const pt_renderer *r, pt_rect tile, uint32_t s0, uint32_t s1,
                           pt_pixel_acc *out, pt_pass_acc *pout, pt_render_stats *stats,
                           const pt_render_guiding *gd);

/* Radiance of one camera sample, traced alone: the reference that
 * pt_render_tile's batched paths match bit for bit (for tests). *covered (when
 * not NULL) gets 1 when its camera ray hit the scene (it counts in hits). */
pt_vec3 pt_render_sample(const pt_renderer *r, uint32_t px, uint32_t py, uint32_t index,
                         pt_render_stats *stats, int *covered);
/* pt_render_sample with path guiding (as pt_render_tile_guided). */
pt_vec3 pt_render_sample_guided(const pt_renderer *r, uint32_t px, uint32_t py, uint32_t index,
                                pt_render_stats *stats, int *covered, const pt_render_guiding *gd);

/* pt_render_sample that also fills *ps (zeros from a renderer made without
 * params.passes): the reference of pt_render_tile_passes. */
pt_vec3 pt_render_sample_passes(const pt_renderer *r, uint32_t px, uint32_t py, uint32_t index,
                                pt_render_stats *stats, int *covered, pt_pass_sample *ps);

/* Receives every ray one sample traces, for benchmarks that replay the same
 * rays through bare Embree (the ray-query ceiling). occlusion: 1 for shadow
 * rays (any hit in (0, tfar)), 0 for closest-hit rays. */
typedef struct pt_ray_sink {
    void (*ray)(void *user, pt_vec3 o, pt_vec3 d, float tfar, int occlusion);
    void *user;
} pt_ray_sink;

/* pt_render_tile through the general variant, reporting each ray to sink in
 * the order pt_render_tile traces them. */
void pt_render_tile_traced(const pt_renderer *r, pt_rect tile, uint32_t s0, uint32_t s1,
                           pt_pixel_acc *out, const pt_ray_sink *sink);

#endif
