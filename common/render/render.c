#include "common/render/render.h"

#include <math.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/math/simd.h"
#include "common/render/bsdf.h"
#include "common/render/closure.h"
#include "common/render/crypto.h"
#include "common/render/dielectric.h"
#include "common/render/env.h"
#include "common/render/guide.h"
#include "common/render/layers.h"
#include "common/render/light.h"
#include "common/render/light_lanes.h"
#include "common/render/manifold.h"
#include "common/render/path_trace.h"
#include "common/render/sampler.h"
#include "common/scene/accel.h"
#include "common/scene/alpha.h"
#include "common/scene/motion.h"

/*
 * Sample dimensions. Pixel jitter uses dims 0-1; bounce k uses the 8 dims
 * starting at DIM_BOUNCE0 + 8k. 2D values start at even dimensions, so each
 * is one stratified pair of the sampler (sampler.h). A camera sample's time
 * in the shutter (motion blur) is dim 2, the first of a pair of its own: it
 * is stratified over a pixel's samples independently of the jitter, and no
 * other dimension moves, so a scene without motion keeps its numbers.
 */
enum {
    DIM_PIXEL = 0,
    DIM_TIME = 2,
    DIM_BOUNCE0 = 4,
    DIM_PER_BOUNCE = 8,
    OFF_LIGHT_POINT = 0, /* 2D */
    OFF_BSDF_DIR = 2,    /* 2D */
    OFF_LIGHT_PICK = 4,  /* 2D with the lobe pick */
    OFF_RR = 6,
    OFF_ALPHA = 7, /* the pass-through of MASK/BLEND surfaces (alpha.h), for the
                      bounce's closest-hit ray and its shadow ray */
};

/* pt_alpha_key salts: the closest-hit ray of a bounce and its shadow ray
 * draw from the same number, and a surface that both cross must get two
 * independent decisions (a shadow ray back through the BLEND surface that
 * the camera ray passed must pass with 1 - alpha, not surely). */
enum { ALPHA_SALT_RAY = 0, ALPHA_SALT_SHADOW = 1 };

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
                         pt_render_stats *stats, int *covered, const pt_render_guiding *gd,
                         pt_pass_sample *ps);
typedef void (*tile_fn)(const pt_renderer *r, pt_rect tile, uint32_t s0, uint32_t s1,
                        pt_pixel_acc *out, pt_pass_acc *pout, pt_render_stats *stats,
                        const pt_render_guiding *gd);

/* Path guiding (guide.h): a renderer feature like the environment, set when
 * the parameters ask for it; only the guided variant has its code. */
#define FEAT_GUIDE (1u << 31)
/* Render passes (params.passes): likewise, only the passes variants record
 * them (pass_rec), so a render without passes runs the code it always did. */
#define FEAT_PASSES (1u << 30)
/* Sample clamping (clamp_sample): set when the parameters ask for it; only
 * the clamped, guided and passes variants have its code. */
#define FEAT_CLAMP (1u << 29)
/* Bidirectional path tracing (params.bdpt, bd_sample): only its variant
 * has the code. */
#define FEAT_BDPT (1u << 28)
/* The renderer's own features, set by the parameters: the variants without
 * them are what a render that does not ask for them runs. */
#define PARAM_FEATURES (FEAT_GUIDE | FEAT_CLAMP | FEAT_PASSES)

/* Caustic photons' source (photon_trace): the environment's light aimed at
 * a sphere (c, radius) around the scene's smooth triangles, from reach beyond
 * it along the light's direction (outside the whole scene); plane: the
 * camera's image plane area at unit distance (an orthographic view's area). */
typedef struct photon_src {
    int on;
    pt_vec3 c;
    float radius, reach, plane;
    uint8_t *smooth; /* per flat triangle: 1 when it may be smooth (photon_tri_smooth) */
} photon_src;

struct pt_renderer {
    const pt_scene *scene;
    pt_accel *accel;
    pt_offset offset; /* pt_accel_offset(accel) */
    pt_lights *lights;
    pt_bsdf *mat_bsdf;    /* per material: its BSDF when it has no texture */
    struct tri_rec *tris; /* per triangle (surface_at), in tris_mem */
    void *tris_mem;
    pt_render_params params;
    li_fn li;     /* one path at a time: pt_render_sample */
    tile_fn tile; /* batched: pt_render_tile */
    int nee;      /* next-event estimation runs: lights exist, the strategy uses them */
    int nee_n;    /* nee, with lights enough to sample them for a stage at once */
    int alpha;    /* the scene has MASK/BLEND materials: rays pass through them */
    const uint8_t *alpha_solid; /* with alpha: the whole MASK triangles (a light sample on
                                   one has coverage 1 without a lookup) */
    int blend; /* ... BLEND ones: shadow rays take their transmittance (trace_shadow),
                  path rays choose their layer by one number (closest_hit) */
    /* PT_FEAT_THIN_GLASS: shadow rays cross thin smooth glass */
    int thin_glass;
    /* PT_FEAT_MANIFOLD: manifold NEE, through thick smooth glass (refract) or
     * off smooth glass (mirror) */
    int manifold;
    int refract;
    float mf_min_light; /* the luminance a light sample must pass for it (manifold_min_light) */
    pt_accel *mf_accel; /* the chain glass's triangles alone (mf_project's rays) */
    uint32_t *mf_tris;  /* their indices, mf_accel's map */
    /* PT_FEAT_MANIFOLD: reflection chains off smooth glass (mr_glass), of a
     * directional, point or spot light, and off smooth opaque surfaces
     * (mr_smooth: metal, polished dielectrics, clear coats), of the lights
     * mr_smooth_light takes and of the environment's lamps */
    int mirror;
    int mirror_smooth;      /* a reflector is smooth and opaque (mr_smooth) */
    int smooth_at;          /* point and spot lights chain off it too (mr_smooth_light) */
    int mirror_env;         /* the environment's lamps chain off it too (mr_env_nee) */
    pt_accel *mr_accel;     /* the reflectors' triangles alone */
    uint32_t *mr_tris;      /* their indices, mr_accel's map */
    struct mr_object *mr;   /* the reflecting objects' bounding spheres */
    uint32_t mr_n;          /* how many (at most MR_MAX) */
    uint32_t *mr_of_object; /* the scene's object -> its index in mr, or MR_NONE */
    int8_t *mr_side;        /* mirror_smooth: per triangle of an MR_HULL object, its hull's outward
                               side (mr_front): 1 along ng, -1 against it, 0 either (flat) */
    /* a light tree chooses: light_normal computes the receiver's normal */
    int light_tree;
    /* a light tree, or an environment split into a sun and the rest
     * (env.h): the receiver's normal bounds the light sampling */
    int recv_normal;
    const char *variant;
    int lanes; /* the Lambert variants shade in lanes (shade_lanes) */
    float tan_half_fov;
    pt_camera camera; /* the scene's, or a framed one fitted to the image (pt_renderer_new) */
    const pt_motion *motion; /* the scene's (PT_FEAT_MOTION), or NULL: nothing moves */
    /* Cryptomatte (PT_PASS_CRYPTOMATTE): each object's and material's id, or NULL. */
    uint32_t *crypto_obj, *crypto_mat;
    photon_src photon; /* FEAT_GUIDE: where caustic photons come from (photon_trace) */
    /* FEAT_BDPT: the emissive triangles light paths start on, by power */
    struct {
        pt_emitters em;
        uint32_t np;    /* point and spot lights light paths start at: the scene's */
        uint32_t *pidx; /* punctual light pidx[i], with the running sum of their */
        double *pcdf;   /* power in cdf's units, after the triangles' */
        double env_w;   /* the environment's power in cdf's units (bd_setup), 0: none */
        double total;   /* the triangles', punctual lights' and environment's together */
        pt_vec3 c;      /* the scene's bounding sphere, whose disks the environment's */
        float rad;      /* light paths start on */
    } bd;
};

void pt_render_params_default(pt_render_params *p)
{
    p->seed = 0;
    p->max_depth = PT_RENDER_DEFAULT_MAX_DEPTH;
    p->rr_depth = 3;
    p->light_strategy = PT_LIGHT_MIS;
    p->extra_features = 0;
    p->scalar_shading = 0;
    p->env = NULL;
    p->transparent = 0;
    p->guiding = 0;
    p->bdpt = 0;
    p->passes = 0;
    p->clamp_direct = 0.0f;
    p->clamp_indirect = 0.0f;
    p->light_select = PT_LIGHT_SELECT_AUTO;
    p->opaque_thin_glass = 0;
    p->no_manifold = 0;
    p->no_mirror = 0;
    p->manifold_min_light = PT_MANIFOLD_MIN_LIGHT;
}

const pt_render_params *pt_renderer_params(const pt_renderer *r)
{
    return &r->params;
}
const pt_camera *pt_renderer_camera(const pt_renderer *r)
{
    return &r->camera;
}

const char *pt_renderer_variant(const pt_renderer *r)
{
    return r->variant;
}

int pt_renderer_lanes(const pt_renderer *r)
{
    return r->lanes;
}

int pt_renderer_chains(const pt_renderer *r)
{
    return r->manifold;
}

/* Features with lights that next-event estimation samples. */
#define NEE_LIGHTS (uint32_t)(PT_FEAT_EMITTERS | PT_FEAT_PUNCTUAL | PT_FEAT_ENV)

/* Russian roulette's largest survival probability. A path survives a bounce
 * with probability max(beta) and carries beta / that, so a path whose
 * throughput stays near 1 (white walls, chrome: bounce weights above this cap)
 * is ended anyway and the survivors' beta grows by weight / cap a bounce. Below
 * 1 so that a closed white scene still ends its paths (in about 100 bounces,
 * not max_depth); 0.99 rather than 0.95 because the second moment of a path
 * through surfaces of albedo a grows by a^2 / cap a bounce: with 0.95 it
 * diverges for a above 0.975, which is the light trapped between the NVIDIA
 * Cornell box's white ceiling and its light (docs/bench/toycar.md; the
 * closed forms in test_roulette). */
#define RR_MAX_SURVIVE 0.99f

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

/* xyz of a 4-float-per-vertex array (tangents). */
static inline pt_vec3 vert4(const float *arr, uint32_t i)
{
    return pt_v3(arr[4 * i], arr[4 * i + 1], arr[4 * i + 2]);
}

/* Where a clear coat's own normal comes from (surface.coat_mapped). */
enum {
    COAT_SHARED = 0,  /* none: the coat shares the base's normal */
    COAT_TEXTURE = 1, /* its clearcoatNormalTexture */
    COAT_SURFACE = 2, /* the interpolated normal under a normal-mapped base: the
                         chains' mirror (pt_closure_coat_mirror) */
};

/* Everything the integrator needs to know about a surface point. */
typedef struct surface {
    pt_vec3 p;  /* world position */
    pt_vec3 ng; /* geometric normal from the winding (unflipped) */
    pt_vec3 ns; /* shading normal (normal-mapped when mapped) */
    float uv[2];
    float uv1[2];  /* TEXCOORD_1 (PT_FEAT_TEXTURES; 0 without the set) */
    pt_vec3 color; /* COLOR_0 (PT_FEAT_VERTEX_COLOR) */
    int mapped;    /* ns comes from a normal map (PT_FEAT_NORMAL_MAP) */
    /* The clear coat's own normal, where coat_mapped (COAT_*; PT_FEAT_CLEARCOAT
     * and PT_FEAT_NORMAL_MAP). */
    pt_vec3 nc;
    int coat_mapped;
    /* The interpolated tangent and its handedness, where aniso: an
     * anisotropic material (PT_FEAT_ANISOTROPY) on a mesh with tangents. */
    pt_vec3 tan;
    float tan_w;
    int aniso;
    const pt_material *mat;
    /* The instance the hit came through (PT_FEAT_INSTANCES), else NULL:
     * the tangents, in its prototype's space, go through its transform. */
    const pt_instance *inst;
} surface;

/* The UV that slot x reads: its coordinate set, transformed. */
static inline void slot_uv(const surface *sf, const pt_tex_xform *x, float out[2])
{
    pt_tex_xform_apply(x, x->texcoord ? sf->uv1 : sf->uv, out);
}

/* Through an instance, vertex attributes are taken to scene space vertex
 * by vertex, then interpolated, as the builder makes a copy's (a tangent
 * by the 3x3 and normalised, a normal by the inverse transpose and
 * normalised): under a non-uniform scale, transforming the interpolated
 * value would weight the vertices otherwise. */
static __attribute__((noinline)) pt_vec3 instance_tangent(const pt_instance *in, const float *T,
                                                          const uint32_t *tri, const pt_hit *hit)
{
    const float w[3] = {1.0f - hit->b1 - hit->b2, hit->b1, hit->b2};
    pt_vec3 t = pt_v3(0.0f, 0.0f, 0.0f);
    for (int k = 0; k < 3; k++) {
        pt_vec3 v = pt_instance_vector(in, vert4(T, tri[k]));
        float len = pt_v3_len(v);
        if (len > 0.0f && isfinite(len))
            t = pt_v3_add(t, pt_v3_scale(v, w[k] / len));
    }
    return t;
}

/*
 * Tangent-space normal mapping (glTF 2.0, 3.9.3): the interpolated tangent,
 * made orthogonal to the interpolated normal n = sf->ns (Gram-Schmidt), the
 * bitangent w cross(n, t) with the handedness w, and the texel of texture
 * tex (read through slot's transform) normalize((2 c - 1) * (scale, scale, 1))
 * in that frame, into *out. The result may face away from the viewer or the
 * geometric normal; shade() bends it back (valid_reflection). Returns 0 and
 * leaves *out alone for a degenerate frame. The base's normalTexture and the
 * clear coat's clearcoatNormalTexture both go through here, in the same frame.
 */
static int tangent_normal(const pt_scene *s, const pt_hit *hit, const surface *sf, int32_t tex,
                          float scale, int slot, pt_vec3 *out, const uint32_t features)
{
    const pt_material *m = sf->mat;
    const pt_instance *inst = (features & PT_FEAT_INSTANCES) ? sf->inst : NULL;
    const uint32_t *tri = &s->indices[3 * hit->tri];
    const float *T = s->tangents;
    float b0 = 1.0f - hit->b1 - hit->b2;
    pt_vec3 t = inst ? instance_tangent(inst, T, tri, hit)
                     : pt_v3_add(pt_v3_add(pt_v3_scale(vert4(T, tri[0]), b0),
                                           pt_v3_scale(vert4(T, tri[1]), hit->b1)),
                                 pt_v3_scale(vert4(T, tri[2]), hit->b2));
    float w = b0 * T[4 * tri[0] + 3] + hit->b1 * T[4 * tri[1] + 3] + hit->b2 * T[4 * tri[2] + 3];
    if (inst)
        w *= inst->tan_sign;
    pt_vec3 n = sf->ns;
    t = pt_v3_sub(t, pt_v3_scale(n, pt_v3_dot(n, t)));
    float len = pt_v3_len(t);
    if (!(len > 1e-12f) || !isfinite(len))
        return 0;
    t = pt_v3_scale(t, 1.0f / len);
    pt_vec3 bt = pt_v3_scale(pt_v3_cross(n, t), w < 0.0f ? -1.0f : 1.0f);
    float uv[2], c[4];
    slot_uv(sf, &m->tex_xf[slot], uv);
    pt_texture_sample(&s->textures[tex], uv[0], uv[1], c);
    float x = (2.0f * c[0] - 1.0f) * scale, y = (2.0f * c[1] - 1.0f) * scale,
          z = 2.0f * c[2] - 1.0f;
    pt_vec3 nm = pt_v3_add(pt_v3_add(pt_v3_scale(t, x), pt_v3_scale(bt, y)), pt_v3_scale(n, z));
    len = pt_v3_len(nm);
    if (!(len > 1e-12f) || !isfinite(len))
        return 0;
    /* Kept on the side of the winding's normal where the interpolated normal
     * is, so that shade()'s flip towards the viewer (by ng) puts it where the
     * interpolated normal would go, even when a file's normals disagree
     * with its winding. */
    if (pt_v3_dot(n, sf->ng) < 0.0f)
        len = -len;
    *out = pt_v3_scale(nm, 1.0f / len);
    return 1;
}

/* The base's normal map: sf->ns mapped (unchanged for a degenerate frame). */
static void normal_map(const pt_scene *s, const pt_hit *hit, surface *sf, const uint32_t features)
{
    const pt_material *m = sf->mat;
    if (tangent_normal(s, hit, sf, m->normal_tex, m->normal_scale, PT_SLOT_NORMAL, &sf->ns,
                       features))
        sf->mapped = 1;
}

/* The clear coat's normal map, from the interpolated normal (so before
 * normal_map replaces it): sf->nc, and sf->coat_mapped where it took. */
static void coat_normal_map(const pt_scene *s, const pt_hit *hit, surface *sf,
                            const uint32_t features)
{
    const pt_material *m = sf->mat;
    sf->coat_mapped = tangent_normal(s, hit, sf, m->clearcoat_normal_tex, m->clearcoat_normal_scale,
                                     PT_SLOT_CLEARCOAT_NORMAL, &sf->nc, features)
                          ? COAT_TEXTURE
                          : COAT_SHARED;
}

/*
 * The shading normal n bent towards the geometric normal ng (both on wo's
 * side) just enough that the mirror reflection of wo about it stays above the
 * geometric surface by t = min(0.9 ng.wo, 0.01) in cosine: Cycles'
 * ensure_valid_reflection (Blender 2.90 and later, kernel/geom; the
 * derivation is in its comments). A normal map may tilt n so far that wo
 * lies below n's hemisphere or its reflection below the surface: the BSDF
 * would then return black (the "black spots" of normal maps) or send light
 * through the surface. Bent, the normal keeps n's azimuth about ng and takes
 * the elevation at which wo's reflection grazes the surface at t, so the
 * map's detail survives and wo.ns > 0. Rays are still kept on the lobe's side
 * of the geometric surface by shade() (reflection only: wi.ng > 0 for NEE and
 * the continuation), so nothing leaks.
 *
 * In the frame z = ng, x = n's part orthogonal to ng, with wo = (ix, ., iz),
 * the unit n' = (sqrt(1 - y), 0, sqrt(y)) whose reflection has z = t solves
 * 4 a y^2 - 4 c y + (t + iz)^2 = 0 with a = ix^2 + iz^2, c = a + iz t: the
 * roots y = (c +- b) / (2 a), b = sqrt(ix^2 (a - t^2)). Squaring admits a
 * false root: keep those in (0, 1] whose reflection is really above the
 * surface, the shallower of two (the nearer to n).
 */
static pt_vec3 valid_reflection(pt_vec3 ng, pt_vec3 wo, pt_vec3 n)
{
    float ndi = pt_v3_dot(n, wo);
    pt_vec3 refl = pt_v3_sub(pt_v3_scale(n, 2.0f * ndi), wo);
    float iz = pt_v3_dot(ng, wo);
    float t = fminf(0.9f * iz, 0.01f);
    if (pt_v3_dot(ng, refl) >= t)
        return n;
    pt_vec3 xv = pt_v3_sub(n, pt_v3_scale(ng, pt_v3_dot(n, ng)));
    float xl = pt_v3_len(xv);
    if (!(xl > 1e-12f) || !isfinite(xl))
        return ng;
    xv = pt_v3_scale(xv, 1.0f / xl);
    float ix = pt_v3_dot(wo, xv);
    float ix2 = ix * ix, a = ix2 + iz * iz;
    float b = sqrtf(fmaxf(ix2 * (a - t * t), 0.0f));
    float c = a + iz * t;
    float y1 = 0.5f * (c + b) / a, y2 = 0.5f * (c - b) / a;
    int ok1 = y1 > 1e-5f && y1 <= 1.0f + 1e-5f, ok2 = y2 > 1e-5f && y2 <= 1.0f + 1e-5f;
    float nx, nz;
    if (ok1 && ok2) {
        float x1 = sqrtf(fmaxf(1.0f - y1, 0.0f)), z1 = sqrtf(y1);
        float x2 = sqrtf(fmaxf(1.0f - y2, 0.0f)), z2 = sqrtf(y2);
        float r1 = 2.0f * (x1 * ix + z1 * iz) * z1 - iz, r2 = 2.0f * (x2 * ix + z2 * iz) * z2 - iz;
        int v1 = r1 >= 1e-5f, v2 = r2 >= 1e-5f;
        int pick1 = (v1 && v2) ? r1 < r2 : r1 > r2;
        nx = pick1 ? x1 : x2;
        nz = pick1 ? z1 : z2;
    } else if (ok1 || ok2) {
        float y = ok1 ? y1 : y2;
        nx = sqrtf(fmaxf(1.0f - y, 0.0f));
        nz = sqrtf(fminf(y, 1.0f));
    } else {
        return ng;
    }
    pt_vec3 r = pt_v3_add(pt_v3_scale(xv, nx), pt_v3_scale(ng, nz));
    return isfinite(r.x) && isfinite(r.y) && isfinite(r.z) ? r : ng;
}

/*
 * What the integrator reads of a hit triangle, in one 64-byte, cache-line-
 * aligned record indexed by Embree's primID, built once per renderer: the
 * vertices (so the hit point is pt_accel_hit_point's, the same bits), the
 * unit geometric normal that pt_accel_hit_point would compute at every hit
 * (computed once by the same code: the same bits), and the material. A flat
 * triangle - three bit-identical vertex normals, as in every flat-shaded
 * mesh - also stores that normal, normalised: interpolating three equal unit
 * normals and normalising gives it back, up to a rounding of the sum, so the
 * shading normal costs neither the interpolation nor a square root.
 */
typedef struct tri_rec {
    pt_vec3 v0, v1, v2;
    pt_vec3 ng;
    pt_vec3 ns;   /* when mat & TRI_FLAT */
    uint32_t mat; /* material index, and TRI_FLAT */
} tri_rec;
#define TRI_FLAT 0x80000000u
_Static_assert(sizeof(tri_rec) == 64, "tri_rec is one cache line");

/* A hit's point as surface_at computes it (pt_accel_hit_point's expression)
 * and its triangle's unit winding normal, in its prototype's space for a hit
 * through an instance. */
static pt_vec3 tri_point(const pt_renderer *r, const pt_hit *hit, pt_vec3 *ng)
{
    const tri_rec *t = &r->tris[hit->tri];
    float b0 = 1.0f - hit->b1 - hit->b2;
    *ng = t->ng;
    return pt_v3_add(pt_v3_add(pt_v3_scale(t->v0, b0), pt_v3_scale(t->v1, hit->b1)),
                     pt_v3_scale(t->v2, hit->b2));
}

/* A moving triangle's hit point, winding normal and interpolated shading
 * normal at the path's time (common/scene/motion.h), in place of the
 * triangle record's (which hold its step 0). */
static __attribute__((noinline)) void surface_moving(const pt_motion *m, uint32_t k,
                                                     const pt_hit *hit, float time, surface *sf)
{
    const uint32_t *vi = &m->indices[3 * (size_t)k];
    uint32_t i;
    float f;
    pt_motion_segment(m->steps, time, &i, &f);
    pt_vec3 v0 = pt_motion_position(m, vi[0], i, f), v1 = pt_motion_position(m, vi[1], i, f),
            v2 = pt_motion_position(m, vi[2], i, f);
    float b0 = 1.0f - hit->b1 - hit->b2;
    sf->p = pt_v3_add(pt_v3_add(pt_v3_scale(v0, b0), pt_v3_scale(v1, hit->b1)),
                      pt_v3_scale(v2, hit->b2));
    pt_vec3 n = pt_v3_cross(pt_v3_sub(v1, v0), pt_v3_sub(v2, v0));
    float len = pt_v3_len(n);
    sf->ng =
        (len > 0.0f && isfinite(len)) ? pt_v3_scale(n, 1.0f / len) : pt_accel_degenerate_normal(n);
    n = pt_v3_add(pt_v3_add(pt_v3_scale(pt_motion_normal(m, vi[0], i, f), b0),
                            pt_v3_scale(pt_motion_normal(m, vi[1], i, f), hit->b1)),
                  pt_v3_scale(pt_motion_normal(m, vi[2], i, f), hit->b2));
    len = pt_v3_len(n);
    sf->ns = (len > 0.0f && isfinite(len)) ? pt_v3_scale(n, 1.0f / len) : sf->ng;
}

/* A hit through an instance (PT_FEAT_INSTANCES): the point and normals,
 * computed in its prototype's space, taken to scene space (a point by the
 * 3x4, normals by the inverse transpose, as the builder takes a copy's:
 * the same up to float rounding). */
static __attribute__((noinline)) void surface_instance(const pt_scene *s, const pt_instance *in,
                                                       const pt_hit *hit, int flat, surface *sf)
{
    sf->inst = in;
    sf->p = pt_instance_point(in, sf->p);
    sf->ng = pt_instance_normal(in, sf->ng, sf->ng);
    if (flat) { /* three equal normals: the record's, transformed */
        sf->ns = pt_instance_normal(in, sf->ns, sf->ng);
        return;
    }
    const uint32_t *tri = &s->indices[3 * hit->tri];
    const float w[3] = {1.0f - hit->b1 - hit->b2, hit->b1, hit->b2};
    pt_vec3 n = pt_v3(0.0f, 0.0f, 0.0f);
    for (int k = 0; k < 3; k++)
        n = pt_v3_add(n,
                      pt_v3_scale(pt_instance_normal(in, vert(s->normals, tri[k]), sf->ng), w[k]));
    float len = pt_v3_len(n);
    sf->ns = (len > 0.0f && isfinite(len)) ? pt_v3_scale(n, 1.0f / len) : sf->ng;
}

static inline void surface_at(const pt_renderer *r, const pt_hit *hit, float time, surface *sf,
                              const uint32_t features)
{
    const pt_scene *s = r->scene;
    const tri_rec *t = &r->tris[hit->tri];
    float b0 = 1.0f - hit->b1 - hit->b2;
    /* pt_accel_hit_point's expression. */
    sf->p = pt_v3_add(pt_v3_add(pt_v3_scale(t->v0, b0), pt_v3_scale(t->v1, hit->b1)),
                      pt_v3_scale(t->v2, hit->b2));
    sf->ng = t->ng;
    const uint32_t *tri = &s->indices[3 * hit->tri];
    if (t->mat & TRI_FLAT) {
        sf->ns = t->ns;
    } else {
        pt_vec3 n = pt_v3_add(pt_v3_add(pt_v3_scale(vert(s->normals, tri[0]), b0),
                                        pt_v3_scale(vert(s->normals, tri[1]), hit->b1)),
                              pt_v3_scale(vert(s->normals, tri[2]), hit->b2));
        float len = pt_v3_len(n);
        sf->ns = (len > 0.0f && isfinite(len)) ? pt_v3_scale(n, 1.0f / len) : sf->ng;
    }
    if ((features & PT_FEAT_MOTION) && r->motion && r->motion->num_triangles > 0) {
        uint32_t k = r->motion->moving[hit->tri];
        if (k != UINT32_MAX)
            surface_moving(r->motion, k, hit, time, sf);
    }
    if (features & PT_FEAT_INSTANCES) {
        sf->inst = NULL;
        if (hit->inst)
            surface_instance(s, &s->instances[hit->inst - 1], hit, (t->mat & TRI_FLAT) != 0, sf);
    }
    sf->uv[0] = sf->uv[1] = 0.0f;
    if ((features & PT_FEAT_TEXTURES) && s->uvs) {
        const float *uv = s->uvs;
        sf->uv[0] = b0 * uv[2 * tri[0]] + hit->b1 * uv[2 * tri[1]] + hit->b2 * uv[2 * tri[2]];
        sf->uv[1] =
            b0 * uv[2 * tri[0] + 1] + hit->b1 * uv[2 * tri[1] + 1] + hit->b2 * uv[2 * tri[2] + 1];
    }
    sf->mat = &s->materials[t->mat & ~TRI_FLAT];
    if (features & PT_FEAT_TEXTURES) {
        sf->uv1[0] = sf->uv1[1] = 0.0f;
        if (s->uvs1) {
            const float *uv = s->uvs1;
            sf->uv1[0] = b0 * uv[2 * tri[0]] + hit->b1 * uv[2 * tri[1]] + hit->b2 * uv[2 * tri[2]];
            sf->uv1[1] = b0 * uv[2 * tri[0] + 1] + hit->b1 * uv[2 * tri[1] + 1] +
                         hit->b2 * uv[2 * tri[2] + 1];
        }
    }
    if ((features & PT_FEAT_VERTEX_COLOR) && s->colors) {
        const float *c = s->colors;
        sf->color = pt_v3(
            b0 * c[4 * tri[0]] + hit->b1 * c[4 * tri[1]] + hit->b2 * c[4 * tri[2]],
            b0 * c[4 * tri[0] + 1] + hit->b1 * c[4 * tri[1] + 1] + hit->b2 * c[4 * tri[2] + 1],
            b0 * c[4 * tri[0] + 2] + hit->b1 * c[4 * tri[1] + 2] + hit->b2 * c[4 * tri[2] + 2]);
    }
    if (features & PT_FEAT_NORMAL_MAP) {
        sf->mapped = 0;
        const pt_material *m = sf->mat;
        const int coat = (features & PT_FEAT_CLEARCOAT) && m->clearcoat > 0.0f &&
                         m->clearcoat_normal_tex >= 0 && s->tangents;
        if (features & PT_FEAT_CLEARCOAT)
            sf->coat_mapped = COAT_SHARED;
        if ((m->normal_tex >= 0 && s->tangents) || coat) {
            if (!(features & PT_FEAT_TEXTURES) || !s->uvs) {
                /* normal_map reads the UVs; set them even where no other
                 * texture needs them. */
                const float *uv = s->uvs;
                sf->uv[0] = sf->uv[1] = 0.0f;
                if (uv) {
                    sf->uv[0] =
                        b0 * uv[2 * tri[0]] + hit->b1 * uv[2 * tri[1]] + hit->b2 * uv[2 * tri[2]];
                    sf->uv[1] = b0 * uv[2 * tri[0] + 1] + hit->b1 * uv[2 * tri[1] + 1] +
                                hit->b2 * uv[2 * tri[2] + 1];
                }
            }
            if (coat)
                coat_normal_map(s, hit, sf, features);
            if (m->normal_tex >= 0) {
                /* KHR_materials_clearcoat: a coat without a
                 * clearcoatNormalTexture is not normal-mapped, even where
                 * the base is; it keeps the interpolated normal. */
                if ((features & PT_FEAT_CLEARCOAT) && m->clearcoat > 0.0f &&
                    sf->coat_mapped == COAT_SHARED) {
                    sf->nc = sf->ns;
                    sf->coat_mapped = COAT_SURFACE;
                }
                normal_map(s, hit, sf, features);
            }
        }
    }
    if (features & PT_FEAT_ANISOTROPY) {
        sf->aniso = (sf->mat->ext & PT_MATX_ANISOTROPY) && s->tangents;
        if (sf->aniso) {
            const float *T = s->tangents;
            sf->tan = pt_v3_add(pt_v3_add(pt_v3_scale(vert4(T, tri[0]), b0),
                                          pt_v3_scale(vert4(T, tri[1]), hit->b1)),
                                pt_v3_scale(vert4(T, tri[2]), hit->b2));
            sf->tan_w =
                b0 * T[4 * tri[0] + 3] + hit->b1 * T[4 * tri[1] + 3] + hit->b2 * T[4 * tri[2] + 3];
            if ((features & PT_FEAT_INSTANCES) && sf->inst) {
                sf->tan = instance_tangent(sf->inst, T, tri, hit);
                sf->tan_w *= sf->inst->tan_sign;
            }
        }
    }
}

/* The records of a scene's triangles, in a block whose start is aligned to
 * 64 bytes (*base is what to free). */
static tri_rec *tri_recs_new(const pt_scene *s, void **base)
{
    *base = NULL;
    if (s->num_triangles == 0)
        return NULL;
    size_t n = s->num_triangles;
    if (n > (SIZE_MAX - 63) / sizeof(tri_rec))
        return NULL;
    char *mem = pt_malloc(n * sizeof(tri_rec) + 63);
    if (!mem)
        return NULL;
    tri_rec *recs = (tri_rec *)(mem + ((64 - (uintptr_t)mem % 64) % 64));
    for (size_t i = 0; i < n; i++) {
        const uint32_t *tri = &s->indices[3 * i];
        tri_rec *t = &recs[i];
        pt_hit hit = {0.0f, 0.0f, 0.0f, (uint32_t)i, 0};
        pt_vec3 p;
        pt_accel_hit_point(s, &hit, &p, &t->ng);
        t->v0 = vert(s->positions, tri[0]);
        t->v1 = vert(s->positions, tri[1]);
        t->v2 = vert(s->positions, tri[2]);
        t->mat = s->tri_material[i] & ~TRI_FLAT;
        t->ns = t->ng;
        pt_vec3 n0 = vert(s->normals, tri[0]), n1 = vert(s->normals, tri[1]),
                n2 = vert(s->normals, tri[2]);
        float len = pt_v3_len(n0);
        if (memcmp(&n0, &n1, sizeof n0) == 0 && memcmp(&n0, &n2, sizeof n0) == 0 && len > 0.0f &&
            isfinite(len)) {
            t->ns = pt_v3_scale(n0, 1.0f / len);
            t->mat |= TRI_FLAT;
        }
    }
    *base = mem;
    return recs;
}

/* max(a, b) as fmaxf gives it (a NaN argument is ignored), by comparisons:
 * fmaxf is a library call without -ffinite-math-only. Only the sign of a
 * zero result may differ, which no caller can see. */
static inline float max2(float a, float b)
{
    return (a > b || b != b) ? a : b;
}

/* Clearcoat and sheen (common/render/layers.h). */
#define LAYERS (uint32_t)(PT_FEAT_CLEARCOAT | PT_FEAT_SHEEN)
static inline int has_layers(const pt_material *m)
{
    return m->clearcoat > 0.0f || m->sheen_color[0] > 0.0f || m->sheen_color[1] > 0.0f ||
           m->sheen_color[2] > 0.0f;
}

/* The layers of sf's material over base: the factors times their textures
 * (KHR_materials_clearcoat: R and G; KHR_materials_sheen: RGB and A). */
static int layers_setup(const pt_renderer *r, const surface *sf, const pt_bsdf *base,
                        pt_layers *lay, const uint32_t features)
{
    const pt_material *m = sf->mat;
    float cc = m->clearcoat, ccr = m->clearcoat_roughness, sr = m->sheen_roughness;
    float sc[3] = {m->sheen_color[0], m->sheen_color[1], m->sheen_color[2]};
    if (features & PT_FEAT_TEXTURES) {
        const pt_texture *tx = r->scene->textures;
        float t[4], uv[2];
        if (m->clearcoat_tex >= 0) {
            slot_uv(sf, &m->tex_xf[PT_SLOT_CLEARCOAT], uv);
            pt_texture_sample(&tx[m->clearcoat_tex], uv[0], uv[1], t);
            cc *= t[0];
        }
        if (m->clearcoat_rough_tex >= 0) {
            slot_uv(sf, &m->tex_xf[PT_SLOT_CLEARCOAT_ROUGH], uv);
            pt_texture_sample(&tx[m->clearcoat_rough_tex], uv[0], uv[1], t);
            ccr *= t[1];
        }
        if (m->sheen_color_tex >= 0) {
            slot_uv(sf, &m->tex_xf[PT_SLOT_SHEEN_COLOR], uv);
            pt_texture_sample(&tx[m->sheen_color_tex], uv[0], uv[1], t);
            sc[0] *= t[0];
            sc[1] *= t[1];
            sc[2] *= t[2];
        }
        if (m->sheen_rough_tex >= 0) {
            slot_uv(sf, &m->tex_xf[PT_SLOT_SHEEN_ROUGH], uv);
            pt_texture_sample(&tx[m->sheen_rough_tex], uv[0], uv[1], t);
            sr *= t[3];
        }
    }
    return pt_layers_setup(lay, base, cc, ccr, sc, sr);
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

/* The metallic-roughness inputs at sf: the material's factors times its
 * base-colour and metal-rough textures (each read through its slot's
 * coordinate set and transform), the base colour times COLOR_0 (glTF 2.0,
 * 3.9.2). Shared by the opaque BSDF and the glass. */
static inline __attribute__((always_inline)) void base_inputs(const pt_scene *s, const surface *sf,
                                                              const uint32_t features,
                                                              pt_vec3 *base, float *metallic,
                                                              float *roughness)
{
    const pt_material *m = sf->mat;
    *base = pt_v3(m->base_color[0], m->base_color[1], m->base_color[2]);
    *metallic = m->metallic;
    *roughness = m->roughness;
    if (features & PT_FEAT_TEXTURES) {
        float t[4];
        float uv[2];
        if (m->base_color_tex >= 0) {
            slot_uv(sf, &m->tex_xf[PT_SLOT_BASE], uv);
            pt_texture_sample(&s->textures[m->base_color_tex], uv[0], uv[1], t);
            *base = pt_v3_mul(*base, pt_v3(t[0], t[1], t[2]));
        }
        if (m->metal_rough_tex >= 0) {
            slot_uv(sf, &m->tex_xf[PT_SLOT_METAL_ROUGH], uv);
            pt_texture_sample(&s->textures[m->metal_rough_tex], uv[0], uv[1], t);
            *roughness *= t[1];
            *metallic *= t[2];
        }
    }
    if ((features & PT_FEAT_VERTEX_COLOR) && s->colors)
        *base = pt_v3_mul(*base, sf->color);
}

/* KHR_materials_specular's factors at sf, times their textures
 * (PT_FEAT_SPECULAR_TEX: specularTexture's A, specularColorTexture's RGB). */
static inline void specular_inputs(const pt_scene *s, const surface *sf, const uint32_t features,
                                   float *spec, pt_vec3 *col)
{
    const pt_material *m = sf->mat;
    *spec = m->specular;
    *col = pt_v3(m->specular_color[0], m->specular_color[1], m->specular_color[2]);
    if (!((features & PT_FEAT_SPECULAR_TEX) && (m->ext & PT_MATX_SPECULAR_TEX)))
        return;
    float t[4], uv[2];
    if (m->specular_tex >= 0) {
        slot_uv(sf, &m->tex_xf[PT_SLOT_SPECULAR], uv);
        pt_texture_sample(&s->textures[m->specular_tex], uv[0], uv[1], t);
        *spec *= t[3];
    }
    if (m->specular_color_tex >= 0) {
        slot_uv(sf, &m->tex_xf[PT_SLOT_SPECULAR_COLOR], uv);
        pt_texture_sample(&s->textures[m->specular_color_tex], uv[0], uv[1], t);
        *col = pt_v3_mul(*col, pt_v3(t[0], t[1], t[2]));
    }
}

/* The material extensions that change the opaque base's inputs. */
#define BSDF_EXTS (uint32_t)(PT_FEAT_SPEC_GLOSS | PT_FEAT_SPECULAR_TEX)

/* The base of a material with pt_material.ext set: specular-glossiness
 * (its factors times specularGlossinessTexture: RGB specular, A
 * glossiness), or metallic-roughness with KHR_materials_specular textures. */
static pt_bsdf material_bsdf_ext(const pt_renderer *r, const surface *sf, const uint32_t features)
{
    const pt_scene *s = r->scene;
    const pt_material *m = sf->mat;
    pt_vec3 base;
    float metallic, roughness;
    base_inputs(s, sf, features, &base, &metallic, &roughness);
    if ((features & PT_FEAT_SPEC_GLOSS) && (m->ext & PT_MATX_SPEC_GLOSS)) {
        pt_vec3 spec = pt_v3(m->sg_specular[0], m->sg_specular[1], m->sg_specular[2]);
        float gloss = m->sg_glossiness;
        if ((features & PT_FEAT_TEXTURES) && m->sg_tex >= 0) {
            float t[4], uv[2];
            slot_uv(sf, &m->tex_xf[PT_SLOT_SPEC_GLOSS], uv);
            pt_texture_sample(&s->textures[m->sg_tex], uv[0], uv[1], t);
            spec = pt_v3_mul(spec, pt_v3(t[0], t[1], t[2]));
            gloss *= t[3];
        }
        return pt_bsdf_setup_spec_gloss(base, spec, gloss);
    }
    float spec;
    pt_vec3 col;
    specular_inputs(s, sf, features, &spec, &col);
    return pt_bsdf_setup(base, metallic, roughness, spec, col);
}

static inline pt_bsdf material_bsdf(const pt_renderer *r, const surface *sf,
                                    const uint32_t features)
{
    const pt_scene *s = r->scene;
    const pt_material *m = sf->mat;
    if ((features & BSDF_EXTS) && (m->ext & (PT_MATX_SPEC_GLOSS | PT_MATX_SPECULAR_TEX)))
        return material_bsdf_ext(r, sf, features);
    const int vcol = (features & PT_FEAT_VERTEX_COLOR) && s->colors;
    if ((!(features & PT_FEAT_TEXTURES) || (m->base_color_tex < 0 && m->metal_rough_tex < 0)) &&
        !vcol) {
        /* pt_bsdf_setup's result for the material's own factors; without
         * PT_FEAT_GLOSSY only its diffuse (the clamped base colour times
         * 1 - 0) is read, the same bits as the branch below. */
        return r->mat_bsdf[m - s->materials];
    }
    pt_vec3 base;
    float metallic, roughness;
    base_inputs(s, sf, features, &base, &metallic, &roughness);
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
 * specularFactor 0): the closure is one diffuse lobe with a Fresnel weight
 * of exactly 1, always picked. These repeat pt_closure_eval and
 * pt_closure_sample's arithmetic for that case operation for operation
 * ((1 - 0) * cos = cos exactly), so the pixels are bit-identical to the
 * general integrator's; they skip building the closure, the lobe choice,
 * Fresnel and GGX terms.
 */
static inline pt_vec3 lambert_eval(const pt_bsdf *b, pt_vec3 wo, pt_vec3 wi, float *pdf)
{
    if (!(wo.z > 0.0f) || !(wi.z > 0.0f)) {
        *pdf = 0.0f;
        return pt_v3(0.0f, 0.0f, 0.0f);
    }
    float c = wi.z * PT_INV_PI;
    *pdf = c;
    return pt_v3_scale(b->diffuse, c);
}

/* cos_wi, when not NULL, is pt_sample_cosine_hemisphere(u[1], u[2]),
 * computed ahead for many paths in lanes. */
static inline pt_vec3 lambert_sample(const pt_bsdf *b, pt_vec3 wo, const float u[3], pt_vec3 *wi,
                                     float *pdf, const pt_vec3 *cos_wi)
{
    pt_vec3 zero = pt_v3(0.0f, 0.0f, 0.0f);
    *pdf = 0.0f;
    *wi = pt_v3(0.0f, 0.0f, 1.0f);
    if (!(wo.z > 0.0f))
        return zero;
    *wi = cos_wi ? *cos_wi : pt_sample_cosine_hemisphere(u[1], u[2]);
    if (!(wi->z > 0.0f))
        return zero;
    pt_vec3 f = lambert_eval(b, wo, *wi, pdf);
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

static inline void camera_ray(const pt_renderer *r, const pt_camera *c, uint32_t px, uint32_t py,
                              const float u[2], pt_vec3 *o, pt_vec3 *d)
{
    float w = (float)r->params.width, h = (float)r->params.height;
    if (c->ortho) {
        /* Parallel rays from the camera's plane: ymag is half the image's
         * height, and the width follows the image's aspect, as a
         * perspective camera's yfov does. */
        float ox = (2.0f * ((float)px + u[0]) / w - 1.0f) * c->ymag * (w / h);
        float oy = (1.0f - 2.0f * ((float)py + u[1]) / h) * c->ymag;
        *o = pt_v3_add(c->position, pt_v3_add(pt_v3_scale(c->right, ox), pt_v3_scale(c->up, oy)));
        *d = c->forward;
        return;
    }
    /* Box filter: a uniform point in the pixel; y grows downwards in the image. */
    float sx = (2.0f * ((float)px + u[0]) / w - 1.0f) * r->tan_half_fov * (w / h);
    float sy = (1.0f - 2.0f * ((float)py + u[1]) / h) * r->tan_half_fov;
    *o = c->position;
    *d = pt_v3_norm(
        pt_v3_add(c->forward, pt_v3_add(pt_v3_scale(c->right, sx), pt_v3_scale(c->up, sy))));
}

/* The sampler seeds of bounce `depth` of pc's pixel: kept in pc for the
 * first SEED_CACHE bounces, hashed into *deep beyond. */
static inline const pt_sample_group *bounce_group(pixel_ctx *pc, uint32_t depth,
                                                  pt_sample_group *deep)
{
    if (depth >= SEED_CACHE) {
        pt_sample_group_init(deep, pc->seed, DIM_BOUNCE0 + DIM_PER_BOUNCE * depth);
        return deep;
    }
    while (pc->ngroups <= depth) {
        pt_sample_group_init(&pc->bounce[pc->ngroups], pc->seed,
                             DIM_BOUNCE0 + DIM_PER_BOUNCE * pc->ngroups);
        pc->ngroups++;
    }
    return &pc->bounce[depth];
}

/* The 8 numbers of bounce `depth` of sample `index` (the light pick and the
 * lobe pick are one pair: one index shuffle). */
static inline void draw_bounce(pixel_ctx *pc, uint32_t depth, uint32_t index,
                               float u[DIM_PER_BOUNCE])
{
    pt_sample_group deep;
    pt_sample_group_eval(bounce_group(pc, depth, &deep), index, u);
}

/* The closest hit of a path's ray, through the MASK/BLEND surfaces it
 * passes (their emission and BSDF are then not applied: the ray never meets
 * them) when the scene has any; u_alpha is the bounce's OFF_ALPHA number.
 * With BLEND surfaces u_alpha itself chooses the layer the ray stops at
 * (pt_accel_intersect_layers), so a pixel's samples, whose numbers are
 * stratified, see a BLEND surface and what is behind it in stratified
 * proportions rather than by independent draws. */
static inline __attribute__((always_inline)) int closest_hit(const pt_renderer *r, pt_vec3 o,
                                                             pt_vec3 d, float time, float u_alpha,
                                                             pt_hit *hit, const uint32_t features)
{
    if ((features & PT_FEAT_ALPHA) && r->blend)
        return pt_accel_intersect_layers(r->accel, o, d, INFINITY,
                                         (features & PT_FEAT_MOTION) && r->motion ? time : 0.0f,
                                         u_alpha, pt_alpha_key(u_alpha, ALPHA_SALT_RAY), hit);
    if ((features & PT_FEAT_MOTION) && r->motion) {
        int alpha = (features & PT_FEAT_ALPHA) && r->alpha;
        return pt_accel_intersect_time(r->accel, o, d, INFINITY, time, alpha,
                                       alpha ? pt_alpha_key(u_alpha, ALPHA_SALT_RAY) : 0, hit);
    }
    if ((features & PT_FEAT_ALPHA) && r->alpha)
        return pt_accel_intersect_alpha(r->accel, o, d, INFINITY,
                                        pt_alpha_key(u_alpha, ALPHA_SALT_RAY), hit);
    return pt_accel_intersect(r->accel, o, d, INFINITY, hit);
}

/* The share of an emissive MASK/BLEND triangle present at a light sample
 * (alpha.h: 0 or 1 for MASK, alpha for BLEND). A ray that samples the BSDF
 * meets the surface, and so its emission, with that probability; NEE weighs
 * the sample by it, so the two strategies estimate the same emission
 * (alpha * Le) and their MIS weights, which assume the same integrand, stay
 * right. The sample's barycentrics, which the light sample does not keep,
 * are solved from its position (they pick a texel only). */
static float light_coverage(const pt_renderer *r, const pt_light_sample *ls)
{
    const tri_rec *t = &r->tris[ls->tri];
    pt_vec3 e1 = pt_v3_sub(t->v1, t->v0), e2 = pt_v3_sub(t->v2, t->v0);
    pt_vec3 q = pt_v3_sub(ls->position, t->v0);
    float d11 = pt_v3_dot(e1, e1), d12 = pt_v3_dot(e1, e2), d22 = pt_v3_dot(e2, e2);
    float q1 = pt_v3_dot(q, e1), q2 = pt_v3_dot(q, e2);
    float den = d11 * d22 - d12 * d12;
    float b1 = 0.0f, b2 = 0.0f;
    if (den > 0.0f) {
        b1 = (d22 * q1 - d12 * q2) / den;
        b2 = (d11 * q2 - d12 * q1) / den;
    }
    return pt_alpha_coverage(r->scene, ls->tri, b1, b2);
}

/* One path between bounces: the ray it traces next and what it carries. */
typedef struct path {
    pt_vec3 o, d; /* the next closest-hit ray */
    pt_vec3 L, beta;
    pt_vec3 prev_p;
    pt_vec3 prev_n; /* light_normal at prev_p: its NEE's receiver normal, for the MIS pdf */
    float prev_pdf; /* 0: the previous vertex was the camera or a delta lobe (no MIS) */
    int32_t medium; /* the absorbing material whose volume the path is in, or -1 */
    /* PT_FEAT_VOLUME: the previous vertex, a thin wall crossed straight
     * through included (prev_p stays at the last real one), where the
     * segment in a medium starts (medium_length). */
    pt_vec3 seg_p;
    uint32_t depth;
    uint32_t index;   /* the sample index */
    uint32_t escaped; /* 1: the camera ray left the scene (the sample does not cover the pixel) */
    float time;       /* in the shutter, [0, 1) (PT_FEAT_MOTION; else 0) */
    uint32_t clamped; /* FEAT_CLAMP: contributions clamp_sample scaled down */
    /* PT_FEAT_THIN_GLASS: thin smooth walls crossed straight through since
     * the last real vertex (whose prev_p and prev_pdf the path keeps), and
     * for the stats the walls shadow rays crossed and the shadow rays that
     * met more than they may cross. */
    uint32_t cross, crossings, dropped;
    pixel_ctx *pc;
    struct guide_path *gp; /* FEAT_GUIDE: its guided vertices; else NULL */
    struct pass_rec *pr;   /* FEAT_PASSES: what the passes record; else NULL */
    struct mf_path *mf;    /* PT_FEAT_MANIFOLD: its chain since a rough vertex; else NULL */
} path;

/* A path's smooth refractions since its last rough vertex x (manifold
 * next-event estimation, mf_connect): the BSDF's strategy for light that
 * manifold NEE at x also finds, whose MIS weight shade_miss reads. */
#define MF_OFF 0xffffffffu
#define MR_NONE 0xffffffffu
typedef struct mf_path {
    uint32_t k;        /* refractions since x, or MF_OFF: no chain from a rough vertex */
    pt_vec3 x, ng, ln; /* x, its geometric normal on the path's side, its light_normal */
    float pdf;         /* the BSDF's pdf at x for the direction the path took */
    float take;        /* the product of the refractions' pick probabilities */
    int32_t medium;    /* the medium at x */
    uint32_t depth;    /* x's */
    uint32_t chains;   /* chains manifold NEE connected on this path (the stats') */
    /* r->mirror_smooth: the share of the throughput that the last vertex's
     * mirror lobes carried (per channel; 1 where no reflection chain from
     * it delivers what they find), which NEE at the next vertex's mirror
     * lobes takes (mr_smooth_at) */
    pt_vec3 mshare;
    /* r->mirror_env: the share of the environment's light that the path
     * keeps when its last vertex's sampled direction leaves the scene (per
     * channel; less than 1 where the vertex is a mirror whose lobes mirror
     * the environment's lamps to the vertex before, which mr_env_nee
     * chained) */
    pt_vec3 ekeep;
    pt_vec3 y[PT_MF_MAX];
} mf_path;

/* A path's render passes (FEAT_PASSES): found is set once the albedo and
 * normal were read at its first non-specular vertex. */
typedef struct pass_rec {
    pt_pass_sample v;
    uint32_t found;
} pass_rec;

/* The vertices of a path where it sampled its next direction from the
 * guide's mixture, for the statistics: each one's cell, direction, the
 * quadtree leaf the direction falls in when the guide's pdf lookup found it
 * (else GUIDE_NO_QLEAF: the record looks it up), mixture pdf, throughput
 * after it (luminance) and the path's radiance (luminance) before anything
 * it found along that direction was added. */
#define GUIDE_VERTS 8u
#define GUIDE_NO_QLEAF 0xffffffffu
typedef struct guide_vert {
    pt_vec3 dir;
    uint32_t leaf, qleaf;
    float pdf, beta, snap;
} guide_vert;
typedef struct guide_path {
    const pt_render_guiding *gd;
    /* The product, over the path's guided vertices, of the mixture's pdf
     * over the BSDF's: the throughput times it is the throughput sampling
     * the BSDF alone would have left, which Russian roulette reads. */
    float rr;
    uint32_t n;       /* vertices in v */
    uint32_t rough;   /* guidable vertices met so far (GUIDE_MAX_ROUGH) */
    uint32_t pending; /* the last vertex's snap is taken at the path's next event */
    guide_vert v[GUIDE_VERTS];
} guide_path;

/* The path's next event (an emitter or the environment found along the last
 * guided direction, or nothing) begins: the radiance so far is the last
 * guided vertex's baseline. */
static inline __attribute__((always_inline)) void guide_snap(path *pa, const uint32_t features)
{
    if ((features & FEAT_GUIDE) && pa->gp && pa->gp->pending) {
        pa->gp->v[pa->gp->n - 1].snap = pt_luminance(pa->L);
        pa->gp->pending = 0;
    }
}

/* At the path's end: each guided vertex's incident radiance estimate,
 * (L - snap) / beta, over its pdf, into the pass's statistics. */
static void guide_record(const path *pa)
{
    const guide_path *gp = pa->gp;
    if (!gp || !gp->gd || !gp->gd->stats)
        return;
    float l = pt_luminance(pa->L);
    for (uint32_t i = 0; i < gp->n; i++) {
        const guide_vert *v = &gp->v[i];
        float li = v->beta > 0.0f ? (l - v->snap) / v->beta : 0.0f;
        float value = li > 0.0f ? li / v->pdf : 0.0f;
        if (v->qleaf != GUIDE_NO_QLEAF)
            pt_guide_stats_add(gp->gd->stats, v->leaf, v->qleaf, value);
        else
            pt_guide_stats_record(gp->gd->stats, gp->gd->guide, v->leaf, v->dir, value);
    }
}

/* A shadow ray that shade() asks for, and what the path gains when the ray is
 * unoccluded. Nothing is traced when dist is not positive (it still counts as
 * a ray, as it always has). */
typedef struct shadow_ray {
    pt_vec3 from, dir;
    float dist;
    pt_vec3 contrib;    /* beta * (f * Le * w), beta before this bounce's weight */
    uint32_t alpha_key; /* pass-through key (PT_FEAT_ALPHA) */
    uint32_t cross_max; /* thin smooth walls it may cross (PT_FEAT_THIN_GLASS) */
} shadow_ray;

enum { SHADE_SHADOW = 1u, SHADE_CONTINUE = 2u }; /* bits 0 and 1: the batch counts with them */

/* The camera ray of sample `index` of pc's pixel, at the sample's time in
 * the shutter when something moves (a moving camera at its pose then). */
static inline __attribute__((always_inline)) void
path_start(const pt_renderer *r, pixel_ctx *pc, uint32_t index, path *pa, const uint32_t features)
{
    float u2[2];
    pt_sample_group_eval2(&pc->jitter, index, u2);
    pa->time = 0.0f;
    if ((features & PT_FEAT_MOTION) && r->motion) {
        pa->time = pt_sample_1d(pc->seed, index, DIM_TIME);
        if (r->motion->camera_steps > 0) {
            pt_camera c = pt_motion_camera(r->motion, pa->time);
            camera_ray(r, &c, pc->px, pc->py, u2, &pa->o, &pa->d);
        } else {
            camera_ray(r, &r->camera, pc->px, pc->py, u2, &pa->o, &pa->d);
        }
    } else {
        camera_ray(r, &r->camera, pc->px, pc->py, u2, &pa->o, &pa->d);
    }
    pa->L = pt_v3(0, 0, 0);
    pa->beta = pt_v3(1, 1, 1);
    pa->prev_p = pa->o;
    pa->prev_n = pt_v3(0.0f, 0.0f, 0.0f);
    pa->prev_pdf = 0.0f;
    pa->seg_p = pa->o;
    pa->medium = -1;
    pa->depth = 0;
    pa->index = index;
    pa->escaped = 0;
    pa->clamped = 0;
    pa->cross = pa->crossings = pa->dropped = 0;
    pa->pc = pc;
    pa->gp = NULL;
    pa->pr = NULL;
    pa->mf = NULL;
}

/* Sample clamping (FEAT_CLAMP; pt_render_params.clamp_direct and
 * clamp_indirect), as Cycles clamps samples: contribution c, whose light
 * arrives directly (at the camera or at the first surface it sees) or
 * after more bounces, scaled down to the limit when |R| + |G| + |B| passes
 * it. Biased, so only where asked for; each one counted. A NaN passes
 * unchanged, to be rejected with its sample. */
static inline __attribute__((always_inline)) pt_vec3
clamp_sample(const pt_renderer *r, path *pa, pt_vec3 c, int direct, const uint32_t features)
{
    if (!(features & FEAT_CLAMP))
        return c;
    float lim = direct ? r->params.clamp_direct : r->params.clamp_indirect;
    float sum = fabsf(c.x) + fabsf(c.y) + fabsf(c.z);
    if (!(lim > 0.0f && sum > lim))
        return c;
    pa->clamped++;
    return pt_v3_scale(c, lim / sum);
}

static inline int transmits(const pt_material *m);

/* The receiver normal by which a light tree bounds its choice at sf seen
 * along -wo (pt_lights_sample's n): the geometric normal on wo's side, the
 * plane below which shade() takes no light sample (wi.ng > 0), so that the
 * lights the tree gives no probability there would have added nothing, with
 * NEE alone too; zero (no bound) where the surface scatters to both sides
 * (shade()'s `through`). NEE at sf and the MIS weight of the hit the path
 * finds next (pa->prev_n) both take it from here; an environment split
 * into a sun and the rest (env.h) bounds by it too. Without either nothing
 * reads it: zero, for nothing. */
static inline __attribute__((always_inline)) pt_vec3
light_normal(const pt_renderer *r, const surface *sf, pt_vec3 wo, const uint32_t features)
{
    if (!r->recv_normal || ((features & PT_FEAT_TRANSMISSION) && transmits(sf->mat)) ||
        ((features & PT_FEAT_DIFFUSE_TRANSMISSION) &&
         (sf->mat->ext & PT_MATX_DIFFUSE_TRANSMISSION)))
        return pt_v3(0.0f, 0.0f, 0.0f);
    return pt_v3_dot(sf->ng, wo) < 0.0f ? pt_v3_neg(sf->ng) : sf->ng;
}

/* The light sample of a bounce at sf, reached by path pa, when NEE runs.
 * Like the hit's surface (surface_at) it is a pure function of the hit and
 * the bounce's numbers, so the batched loop computes both for all paths,
 * stage by stage, before shading any: short loops of independent
 * iterations, which the processor overlaps. */
static inline __attribute__((always_inline)) int
bounce_light(const pt_renderer *r, const surface *sf, const path *pa, const float u[DIM_PER_BOUNCE],
             pt_light_sample *ls, const uint32_t features)
{
    if (!((features & NEE_LIGHTS) && r->nee))
        return 0;
    float u3[3];
    u3[0] = u[OFF_LIGHT_PICK];
    u3[1] = u[OFF_LIGHT_POINT];
    u3[2] = u[OFF_LIGHT_POINT + 1];
    pt_vec3 n = light_normal(r, sf, pt_v3_neg(pa->d), features);
    return pt_lights_sample(r->lights, r->scene, sf->p, n, u3, ls);
}

/* shade()'s first step: the hit's emission into pa->L, weighted by the
 * power heuristic against the light pdf when the path got here by sampling
 * its BSDF (Veach 1997, sec. 9.2). */
static float mf_emit_weight(const pt_renderer *r, const path *pa, const pt_hit *hit,
                            const surface *sf, const uint32_t features);

static inline __attribute__((always_inline)) void shade_emission(const pt_renderer *r, path *pa,
                                                                 const pt_hit *hit,
                                                                 const surface *sf,
                                                                 const uint32_t features)
{
    const pt_scene *s = r->scene;
    const uint32_t strategy = r->params.light_strategy;
    guide_snap(pa, features);
    if (!((features & PT_FEAT_EMITTERS) && emits(sf->mat)))
        return;
    pt_vec3 wo = pt_v3_neg(pa->d);
    if ((features & PT_FEAT_MOTION) && r->motion && r->motion->num_triangles > 0 &&
        r->motion->moving[hit->tri] != UINT32_MAX) {
        /* pt_emitted tells the front by the still triangle; a moving one
         * has turned: its side at the path's time (sf->ng) decides, and
         * pt_emitted is handed the still normal on that side. */
        pt_vec3 n0 = r->tris[hit->tri].ng;
        wo = pt_v3_dot(sf->ng, wo) > 0.0f ? n0 : pt_v3_neg(n0);
    }
    pt_vec3 le = pt_emitted(s, hit->tri, hit->b1, hit->b2, wo);
    if ((features & FEAT_PASSES) && pa->pr && pa->depth == 0)
        pa->pr->v.emission = le;
    float lp = 0.0f, mis = 1.0f; /* the light's pdf and the MIS weight (the path log's too) */
    if (pa->prev_pdf > 0.0f && strategy == PT_LIGHT_MIS) {
        lp = pt_lights_pdf(r->lights, s, hit->tri, pa->prev_p, pa->prev_n, sf->p, sf->ng);
        mis = power_heuristic(pa->prev_pdf, lp);
        le = pt_v3_scale(le, mis);
    }
    if ((features & PT_FEAT_MANIFOLD) && pa->mf && pa->mf->k != MF_OFF && pa->mf->k > 0 &&
        any_positive(le))
        le = pt_v3_scale(le, mf_emit_weight(r, pa, hit, sf, features));
    PT_TRACE_EVENT(PT_TRACE_EMIT, pa->depth, (int32_t)(sf->mat - s->materials), -1, 0, pa->prev_pdf,
                   lp, mis, pt_v3_mul(pa->beta, le));
    /* Found at depth d, the light arrives at vertex d - 1: direct up to 1. */
    if (pa->prev_pdf == 0.0f || strategy != PT_LIGHT_NEE_ONLY)
        pa->L = pt_v3_add(pa->L,
                          clamp_sample(r, pa, pt_v3_mul(pa->beta, le), pa->depth <= 1, features));
}

static float mf_bsdf_weight(const pt_renderer *r, const path *pa, pt_vec3 le,
                            const uint32_t features);

/* 1 when the environment's radiance le along a direction is a lamp that
 * mr_env_nee chains off smooth opaque surfaces (brighter than
 * r->mf_min_light, as manifold NEE's); the dimmer rest is left to the
 * sampled paths, which find it often. */
static inline int mr_env_lamp(const pt_renderer *r, pt_vec3 le)
{
    return pt_luminance(le) > r->mf_min_light;
}

/* A ray of the path that left the scene: the environment's radiance along
 * it, weighed by the power heuristic against the environment's NEE pdf when
 * the path got here by sampling its BSDF (as shade_emission weighs an
 * emitter). A camera ray sees the environment as it is, or nothing on a
 * transparent film. Only a camera ray misses at depth 0 (a path traces again
 * only after a bounce), so depth 0 marks the sample as not covering. */
static inline __attribute__((always_inline)) void shade_miss(const pt_renderer *r, path *pa,
                                                             const uint32_t features)
{
    guide_snap(pa, features);
    if (pa->depth == 0) {
        pa->escaped = 1;
        if (r->params.transparent)
            return;
    }
    if (!(features & PT_FEAT_ENV) || !r->params.env)
        return;
    const uint32_t strategy = r->params.light_strategy;
    pt_vec3 le = pt_env_eval(r->params.env, pa->d);
    if ((features & PT_FEAT_MANIFOLD) && pa->mf && r->mirror_env && mr_env_lamp(r, le))
        le = pt_v3_mul(le, pa->mf->ekeep); /* a lamp off a mirror, chained (mr_env_nee) */
    float lp = 0.0f, mis = 1.0f; /* the map's pdf and the MIS weight (the path log's too) */
    if (pa->prev_pdf > 0.0f && strategy == PT_LIGHT_MIS) {
        lp = pt_lights_env_pdf(r->lights, pa->d, pa->prev_p, pa->prev_n);
        mis = power_heuristic(pa->prev_pdf, lp);
        le = pt_v3_scale(le, mis);
    }
    if ((features & PT_FEAT_MANIFOLD) && pa->mf && pa->mf->k != MF_OFF && pa->mf->k > 0)
        le = pt_v3_scale(le, mf_bsdf_weight(r, pa, le, features));
    PT_TRACE_EVENT(PT_TRACE_ENV, pa->depth, -1, -1, 0, pa->prev_pdf, lp, mis,
                   pt_v3_mul(pa->beta, le));
    if (pa->prev_pdf == 0.0f || strategy != PT_LIGHT_NEE_ONLY)
        pa->L = pt_v3_add(pa->L,
                          clamp_sample(r, pa, pt_v3_mul(pa->beta, le), pa->depth <= 1, features));
}

/* KHR_materials_unlit (PT_FEAT_UNLIT; general variant only): the ray sees
 * the base colour (factor x texture x COLOR_0) as radiance, whatever the
 * lighting, and the path ends. No light sampling can find the surface, so
 * the colour counts in full at any depth and under any light strategy. */
static inline __attribute__((always_inline)) void
shade_unlit(const pt_renderer *r, path *pa, const surface *sf, const uint32_t features)
{
    pt_vec3 base;
    float metallic, roughness;
    base_inputs(r->scene, sf, features, &base, &metallic, &roughness);
    pa->L =
        pt_v3_add(pa->L, clamp_sample(r, pa, pt_v3_mul(pa->beta, base), pa->depth <= 1, features));
}

/*
 * Glass and media (PT_FEAT_TRANSMISSION, PT_FEAT_VOLUME; general variant
 * only). A path knows one medium: the absorbing material whose closed mesh
 * it is inside (path.medium), set when it refracts in through the side the
 * winding's normal points away from (the front: closed meshes are wound
 * outwards) and cleared when it refracts out through a back face. Media do
 * not nest: glass inside glass, or a mesh that is not closed, gives wrong
 * absorption but never NaN. Inside, every segment of length t scales beta by
 * Beer-Lambert's c^(t / d) per channel (KHR_materials_volume:
 * sigma = -ln(c) / d). The outside is air (n = 1).
 */
static inline pt_vec3 medium_transmittance(const pt_scene *s, int32_t medium, float t)
{
    pt_vec3 tr = pt_v3(1.0f, 1.0f, 1.0f);
    if (medium < 0)
        return tr;
    const pt_material *m = &s->materials[medium];
    float x = t / m->attenuation_distance; /* t may be +inf: c^inf = 0 for c < 1 */
    float *out[3] = {&tr.x, &tr.y, &tr.z};
    for (int c = 0; c < 3; c++) {
        float col = m->attenuation_color[c];
        if (col < 1.0f)
            *out[c] = col > 0.0f ? expf(logf(col) * x) : 0.0f;
    }
    return tr;
}

/*
 * The length of the path's segment in a medium, from its previous vertex to
 * the hit: the true points, not the ray's origin, which the self-intersection
 * offset moved into the medium (by 256 ULPs of the coordinates far from the
 * origin: 0.25 at 12,288), so that measured from it each crossing was short
 * by the offset over the cosine. Along the direction to the plane of the
 * face hit, which is exact for a plane at any incidence; the chord between
 * the points where the face is seen near edge-on or moves (motion blur).
 */
static __attribute__((noinline)) float medium_length(const pt_renderer *r, const path *pa,
                                                     const pt_hit *hit, const uint32_t features)
{
    pt_vec3 n;
    pt_vec3 h = tri_point(r, hit, &n);
    if ((features & PT_FEAT_MOTION) && r->motion && r->motion->num_triangles > 0 &&
        r->motion->moving[hit->tri] != UINT32_MAX) {
        h = pt_v3_add(pa->o, pt_v3_scale(pa->d, hit->t));
        n = pt_v3(0.0f, 0.0f, 0.0f);
    } else if ((features & PT_FEAT_INSTANCES) && hit->inst) {
        const pt_instance *in = &r->scene->instances[hit->inst - 1];
        h = pt_instance_point(in, h);
        n = pt_instance_normal(in, n, n);
    }
    pt_vec3 e = pt_v3_sub(h, pa->seg_p);
    float dn = pt_v3_dot(pa->d, n);
    if (fabsf(dn) > 0.05f) {
        float l = pt_v3_dot(e, n) / dn;
        if (l >= 0.0f && isfinite(l))
            return l;
    }
    return pt_v3_len(e);
}

/* The path's segment ended at hit (NULL: a miss, an infinite segment). */
static inline __attribute__((always_inline)) void
medium_segment(const pt_renderer *r, path *pa, const pt_hit *hit, const uint32_t features)
{
    if ((features & PT_FEAT_VOLUME) && pa->medium >= 0) {
        float t = hit ? medium_length(r, pa, hit, features) : INFINITY;
        pa->beta = pt_v3_mul(pa->beta, medium_transmittance(r->scene, pa->medium, t));
    }
}

static inline int transmits(const pt_material *m)
{
    return m->transmission > 0.0f;
}

/* The medium on the far side of a transmissive surface of material index mi
 * hit from the front (or not): entering an absorbing closed mesh, or leaving
 * it; a thin wall changes nothing. */
static inline int32_t medium_across(const pt_scene *s, int32_t current, uint32_t mi, int front,
                                    int thin)
{
    if (thin)
        return current;
    if (!front)
        return -1;
    return pt_material_absorbs(&s->materials[mi]) ? (int32_t)mi : -1;
}

static int film_at(const pt_renderer *r, const surface *sf, const uint32_t features, pt_irid *film);

/* The glass BSDF at sf for a ray arriving from the front or the back. */
static pt_glass glass_at(const pt_renderer *r, const surface *sf, int front,
                         const uint32_t features)
{
    const pt_scene *s = r->scene;
    const pt_material *m = sf->mat;
    pt_vec3 base;
    float metallic, roughness, trans = m->transmission;
    base_inputs(s, sf, features, &base, &metallic, &roughness);
    if ((features & PT_FEAT_TEXTURES) && m->transmission_tex >= 0) {
        float t[4], uv[2];
        slot_uv(sf, &m->tex_xf[PT_SLOT_TRANSMISSION], uv);
        pt_texture_sample(&s->textures[m->transmission_tex], uv[0], uv[1], t);
        trans *= t[0];
    }
    int thin = !(m->thickness > 0.0f);
    /* Seen from the back of a closed mesh the ray is inside: n_far / n_near
     * is 1 / ior. A thin wall has air on both sides. */
    float eta = m->ior == 0.0f ? 0.0f : (thin || front ? m->ior : 1.0f / m->ior);
    float spec;
    pt_vec3 col;
    specular_inputs(s, sf, features, &spec, &col);
    pt_glass g = pt_glass_setup(base, metallic, roughness, spec, col, trans, eta, thin);
    if ((features & PT_FEAT_DISPERSION) && m->dispersion > 0.0f && !thin) {
        /* KHR_materials_dispersion: eta per channel, on the same side. */
        float n3[3];
        pt_dispersion_ior(m->ior, m->dispersion, n3);
        pt_glass_disperse(&g, n3, !front);
    }
    pt_irid film;
    if ((features & PT_FEAT_IRIDESCENCE) && (m->ext & PT_MATX_IRIDESCENCE) && (front || thin) &&
        film_at(r, sf, features, &film))
        pt_glass_film(&g, film.strength, film.eta, film.d_nm, m->ior);
    return g;
}

/* The iridescent film at sf (KHR_materials_iridescence): the factor times
 * its texture's R, the thickness between its minimum and maximum by its
 * texture's G (the maximum without one). 0 where the strength is 0. */
static int film_at(const pt_renderer *r, const surface *sf, const uint32_t features, pt_irid *film)
{
    const pt_material *m = sf->mat;
    film->strength = m->iridescence;
    film->eta = m->iridescence_ior;
    film->d_nm = m->irid_thickness_max;
    if (features & PT_FEAT_TEXTURES) {
        const pt_texture *tx = r->scene->textures;
        float t[4], uv[2];
        if (m->iridescence_tex >= 0) {
            slot_uv(sf, &m->tex_xf[PT_SLOT_IRIDESCENCE], uv);
            pt_texture_sample(&tx[m->iridescence_tex], uv[0], uv[1], t);
            film->strength *= t[0];
        }
        if (m->irid_thickness_tex >= 0) {
            slot_uv(sf, &m->tex_xf[PT_SLOT_IRID_THICKNESS], uv);
            pt_texture_sample(&tx[m->irid_thickness_tex], uv[0], uv[1], t);
            film->d_nm =
                m->irid_thickness_min + (m->irid_thickness_max - m->irid_thickness_min) * t[1];
        }
    }
    return film->strength > 0.0f;
}

/* The diffuse transmission at sf (KHR_materials_diffuse_transmission): the
 * factor times its texture's A into *dt, and the transmitted albedo, dt x
 * the colour (times its texture's RGB) x (1 - metallic), into *through. 0
 * where dt is 0. */
static int dt_at(const pt_renderer *r, const surface *sf, const uint32_t features, float *dt,
                 pt_vec3 *through)
{
    const pt_scene *s = r->scene;
    const pt_material *m = sf->mat;
    pt_vec3 base, col = pt_v3(m->diffuse_transmission_color[0], m->diffuse_transmission_color[1],
                              m->diffuse_transmission_color[2]);
    float metallic, roughness, t = m->diffuse_transmission;
    base_inputs(s, sf, features, &base, &metallic, &roughness);
    if (features & PT_FEAT_TEXTURES) {
        float x[4], uv[2];
        if (m->diffuse_transmission_tex >= 0) {
            slot_uv(sf, &m->tex_xf[PT_SLOT_DIFFUSE_TRANSMISSION], uv);
            pt_texture_sample(&s->textures[m->diffuse_transmission_tex], uv[0], uv[1], x);
            t *= x[3];
        }
        if (m->diffuse_transmission_color_tex >= 0) {
            slot_uv(sf, &m->tex_xf[PT_SLOT_DIFFUSE_TRANSMISSION_COLOR], uv);
            pt_texture_sample(&s->textures[m->diffuse_transmission_color_tex], uv[0], uv[1], x);
            col = pt_v3_mul(col, pt_v3(x[0], x[1], x[2]));
        }
    }
    metallic = metallic > 0.0f ? (metallic < 1.0f ? metallic : 1.0f) : 0.0f;
    t = t > 0.0f ? (t < 1.0f ? t : 1.0f) : 0.0f;
    *dt = t;
    *through = pt_v3_scale(col, t * (1.0f - metallic));
    return t > 0.0f;
}

/* The anisotropy at sf (KHR_materials_anisotropy) in the shading frame fr:
 * the strength times the texture's B, the direction (cos, sin) of the
 * rotation, or the texture's RG in [-1, 1] turned by it, in the tangent
 * frame (the tangent made orthogonal to fr's normal, the bitangent by its
 * handedness), into (*c, *s) in fr. 0 where the strength is 0 or the frame
 * is degenerate. */
static int aniso_at(const pt_renderer *r, const surface *sf, const pt_frame *fr,
                    const uint32_t features, float *strength, float *c, float *s)
{
    const pt_material *m = sf->mat;
    float st = m->anisotropy;
    float cr = cosf(m->anisotropy_rotation), sr = sinf(m->anisotropy_rotation);
    float dx = cr, dy = sr;
    if ((features & PT_FEAT_TEXTURES) && m->anisotropy_tex >= 0) {
        float t[4], uv[2];
        slot_uv(sf, &m->tex_xf[PT_SLOT_ANISOTROPY], uv);
        pt_texture_sample(&r->scene->textures[m->anisotropy_tex], uv[0], uv[1], t);
        float x = 2.0f * t[0] - 1.0f, y = 2.0f * t[1] - 1.0f;
        dx = x * cr - y * sr;
        dy = x * sr + y * cr;
        st *= t[2];
    }
    pt_vec3 n = fr->n;
    pt_vec3 t = pt_v3_sub(sf->tan, pt_v3_scale(n, pt_v3_dot(n, sf->tan)));
    float len = pt_v3_len(t);
    if (!(st > 0.0f) || !(len > 1e-12f) || !isfinite(len))
        return 0;
    t = pt_v3_scale(t, 1.0f / len);
    pt_vec3 b = pt_v3_scale(pt_v3_cross(n, t), sf->tan_w < 0.0f ? -1.0f : 1.0f);
    pt_vec3 d = pt_frame_to_local(fr, pt_v3_add(pt_v3_scale(t, dx), pt_v3_scale(b, dy)));
    *strength = st;
    *c = d.x;
    *s = d.y;
    return d.x * d.x + d.y * d.y > 0.0f;
}

/* The extensions that change the base's lobes, and their material bits. */
#define BASE_EXTS                                                                                  \
    (uint32_t)(PT_FEAT_DIFFUSE_TRANSMISSION | PT_FEAT_ANISOTROPY | PT_FEAT_IRIDESCENCE)
#define BASE_MATX (PT_MATX_DIFFUSE_TRANSMISSION | PT_MATX_ANISOTROPY | PT_MATX_IRIDESCENCE)

/* The base's lobes of a material with one of BASE_MATX, into cl: diffuse
 * transmission (its specular lobe anisotropic, and every lobe under the
 * film, when the material has those too), else anisotropy (under the film
 * when the material is iridescent too), else iridescence: every
 * combination composes. Out of line, so that the core path stays as small
 * as it was. */
static __attribute__((noinline)) void add_base_ext(const pt_renderer *r, const surface *sf,
                                                   const pt_frame *fr, const pt_bsdf *bsdf,
                                                   pt_closure *cl, const uint32_t features)
{
    pt_irid film;
    float as = 0.0f, ac = 1.0f, an = 0.0f, dt;
    pt_vec3 dtc;
    if ((features & PT_FEAT_DIFFUSE_TRANSMISSION) &&
        (sf->mat->ext & PT_MATX_DIFFUSE_TRANSMISSION) && dt_at(r, sf, features, &dt, &dtc)) {
        /* With anisotropy, iridescence or both too: they compose. */
        int aniso = (features & PT_FEAT_ANISOTROPY) && sf->aniso &&
                    aniso_at(r, sf, fr, features, &as, &ac, &an);
        if ((features & PT_FEAT_IRIDESCENCE) && (sf->mat->ext & PT_MATX_IRIDESCENCE) &&
            film_at(r, sf, features, &film))
            pt_closure_add_base_dt_irid(cl, bsdf, dt, dtc, &film, aniso, as, ac, an);
        else if (aniso)
            pt_closure_add_base_dt_aniso(cl, bsdf, dt, dtc, as, ac, an);
        else
            pt_closure_add_base_dt(cl, bsdf, dt, dtc);
    } else if ((features & PT_FEAT_ANISOTROPY) && sf->aniso &&
               aniso_at(r, sf, fr, features, &as, &ac, &an)) {
        /* With iridescence too: the film over the anisotropic lobe. */
        if ((features & PT_FEAT_IRIDESCENCE) && (sf->mat->ext & PT_MATX_IRIDESCENCE) &&
            film_at(r, sf, features, &film))
            pt_closure_add_base_irid_aniso(cl, bsdf, &film, as, ac, an);
        else
            pt_closure_add_base_aniso(cl, bsdf, as, ac, an);
    } else if ((features & PT_FEAT_IRIDESCENCE) && (sf->mat->ext & PT_MATX_IRIDESCENCE) &&
               film_at(r, sf, features, &film))
        pt_closure_add_base_irid(cl, bsdf, &film);
    else
        pt_closure_add_base(cl, bsdf);
}

/*
 * The closure at sf (closure.h): the builder. wo_l is wo in the shading frame
 * fr. Glass (PT_FEAT_TRANSMISSION; front: the ray arrives on the side the
 * geometric normal points to) is its opaque share beside the interface;
 * other materials are the glTF base. Clearcoat and sheen go over either
 * where the material has them (PT_FEAT_CLEARCOAT, PT_FEAT_SHEEN), as the
 * extensions layer them over the whole material, transmission included.
 */
static inline __attribute__((always_inline)) void
material_closure(const pt_renderer *r, const surface *sf, int glass, int front, const pt_frame *fr,
                 pt_vec3 wo, pt_vec3 wo_l, pt_vec3 ng, pt_closure *cl, const uint32_t features)
{
    pt_closure_init(cl, wo_l);
    pt_bsdf bsdf;
    if ((features & PT_FEAT_TRANSMISSION) && glass) {
        pt_glass g = glass_at(r, sf, front, features);
        pt_closure_add_glass(cl, &g);
        bsdf = g.base;
    } else {
        bsdf = material_bsdf(r, sf, features);
        if ((features & BASE_EXTS) && (sf->mat->ext & BASE_MATX))
            add_base_ext(r, sf, fr, &bsdf, cl, features);
        else
            pt_closure_add_base(cl, &bsdf);
    }
    pt_layers lay;
    if (!((features & LAYERS) && has_layers(sf->mat) && layers_setup(r, sf, &bsdf, &lay, features)))
        return;
    if ((features & PT_FEAT_CLEARCOAT) && (features & PT_FEAT_NORMAL_MAP) && sf->coat_mapped) {
        /* The coat's own normal, turned and bent as the base's mapped one
         * is (shading_normals), in the base's local frame; the surface's
         * interpolated one (COAT_SURFACE) as an unmapped base's is, turned
         * to ng's side and never bent, so that the chains, which solve for
         * that normal, mirror where the coat does, and mirror off it alone. */
        pt_vec3 nc = sf->nc;
        if (sf->coat_mapped == COAT_SURFACE) {
            if (pt_v3_dot(nc, ng) < 0.0f)
                nc = pt_v3_neg(nc);
            pt_closure_coat_mirror(cl);
        } else {
            if (pt_v3_dot(sf->ng, wo) < 0.0f)
                nc = pt_v3_neg(nc);
            nc = valid_reflection(ng, wo, nc);
        }
        if (pt_v3_dot(nc, wo) <= 0.0f)
            nc = ng;
        pt_layers_coat_normal(&lay, pt_frame_to_local(fr, nc));
    }
    pt_closure_add_layers(cl, &lay);
}

/* A closure path guiding samples at: one with a diffuse lobe or a GGX lobe
 * rough enough (alpha >= GUIDE_MIN_ALPHA) for light to arrive over a spread
 * of directions, and nothing that transmits (a glass's delta or narrow
 * lobes, a thin wall's diffuse transmission: a face's tree learns one side
 * of a surface); the BSDF alone samples those. */
#define GUIDE_MIN_ALPHA 0.1f
/* A path samples the guide's mixture (and records) at its first
 * GUIDE_MAX_ROUGH guidable vertices, however many smooth bounces (glass,
 * mirrors, chrome) lie before or between them: the backdrop seen through two
 * glass interfaces, or a car's cabin behind its windshield, is the path's
 * first rough vertex and is guided as a wall seen directly is. Counting every
 * bounce instead left those vertices unguided and unrecorded. Guiding more
 * rough vertices than this compounds the throughput's variance (the Cornell
 * box's long diffuse paths, docs/bench/guiding.md). */
#define GUIDE_MAX_ROUGH 3u
static inline int closure_guidable(const pt_closure *cl)
{
    int any = 0;
    for (uint32_t i = 0; i < cl->n_lobes; i++) {
        const pt_lobe *l = &cl->lobe[i];
        if (l->kind == PT_LOBE_DIELECTRIC || l->kind == PT_LOBE_DIFFUSE_TRANSMIT ||
            l->kind == PT_LOBE_DIFFUSE_TRANSMIT_IRID)
            return 0;
        any |= l->kind == PT_LOBE_DIFFUSE ||
               (l->kind == PT_LOBE_SPECULAR && l->p.specular.alpha >= GUIDE_MIN_ALPHA);
    }
    return any;
}

/* The share of cl's sampling probability held by lobes that a guide of
 * incident radiance alone can stand in for: diffuse ones and GGX lobes of
 * alpha >= GUIDE_BROAD_ALPHA, broad enough that the light's shape matters
 * more than the lobe's. A narrower lobe's directions drawn from the guide
 * mostly land where it reflects nothing; the guide's share of a vertex's
 * directions is scaled by this, so a glossy vertex keeps its BSDF sampling
 * (the selection probability is a function of the vertex: one-sample MIS
 * stays unbiased, Mueller et al. 2017 sec. 5; Mueller 2019 learns it). */
#define GUIDE_BROAD_ALPHA 0.5f
static inline float closure_guide_share(const pt_closure *cl)
{
    float reach = 1.0f, share = 0.0f;
    for (uint32_t g = cl->n_groups; g-- > 0;) {
        const pt_closure_group *gr = &cl->group[g];
        for (uint32_t i = 0; i < gr->n; i++) {
            const pt_lobe *l = &cl->lobe[gr->first + i];
            if (l->kind == PT_LOBE_DIFFUSE ||
                (l->kind == PT_LOBE_SPECULAR && l->p.specular.alpha >= GUIDE_BROAD_ALPHA))
                share += reach * l->prob;
        }
        reach *= gr->below;
    }
    return share < 1.0f ? share : 1.0f;
}

/* The passes of the camera ray's hit: its distance (the ray's direction is
 * a unit vector) and Cryptomatte ids. */
static inline __attribute__((always_inline)) void pass_first_hit(const pt_renderer *r, pass_rec *pr,
                                                                 const pt_hit *hit,
                                                                 const surface *sf,
                                                                 const uint32_t features)
{
    const pt_scene *s = r->scene;
    pr->v.depth = hit->t;
    if (r->crypto_obj) {
        /* Through an instance, its node's object (a prototype's triangles
         * are shared by every node instancing the mesh). */
        uint32_t obj = (features & PT_FEAT_INSTANCES) && hit->inst
                           ? s->instances[hit->inst - 1].object
                           : s->tri_object[hit->tri];
        pr->v.crypto[PT_CRYPTO_OBJECT] = r->crypto_obj[obj];
        pr->v.crypto[PT_CRYPTO_MATERIAL] = r->crypto_mat[sf->mat - s->materials];
    }
}

/* The passes at an unlit surface (PT_FEAT_UNLIT), where the path ends: its
 * colour is the albedo, its interpolated normal turned to the ray the
 * normal. */
static inline __attribute__((always_inline)) void
pass_unlit(const pt_renderer *r, path *pa, const surface *sf, pt_vec3 wo, const uint32_t features)
{
    pt_vec3 base;
    float metallic, roughness;
    base_inputs(r->scene, sf, features, &base, &metallic, &roughness);
    pa->pr->found = 1;
    pa->pr->v.albedo = pt_v3_mul(pa->beta, base);
    pa->pr->v.normal = pt_v3_dot(sf->ns, wo) < 0.0f ? pt_v3_neg(sf->ns) : sf->ns;
}

/* The normals a ray arriving along -wo shades sf with: the geometric one on
 * the side it arrives from (*ng; glass: a ray that grazes the geometric
 * surface counts as arriving from the back, *front 0) and the shading one
 * turned to it (*ns). */
static inline __attribute__((always_inline)) void shading_normals(const surface *sf, pt_vec3 wo,
                                                                  int through, int *front,
                                                                  pt_vec3 *ng_out, pt_vec3 *ns_out,
                                                                  const uint32_t features)
{
    float wng = pt_v3_dot(sf->ng, wo);
    *front = wng > 0.0f;
    pt_vec3 ng = (through ? !*front : wng < 0.0f) ? pt_v3_neg(sf->ng) : sf->ng;
    pt_vec3 ns = sf->ns;
    if ((features & PT_FEAT_NORMAL_MAP) && sf->mapped && !through) {
        /* A mapped normal may lie anywhere: turn it with the side the ray
         * sees (as ng was), then bend it until wo's reflection is valid. */
        if (wng < 0.0f)
            ns = pt_v3_neg(ns);
        ns = valid_reflection(ng, wo, ns);
        if (pt_v3_dot(ns, wo) <= 0.0f)
            ns = ng;
    } else {
        if (pt_v3_dot(ns, ng) < 0.0f)
            ns = pt_v3_neg(ns);
        if (pt_v3_dot(ns, wo) <= 0.0f)
            ns = ng; /* interpolated normal faces away from the viewer */
    }
    *ng_out = ng;
    *ns_out = ns;
}

static inline int thin_wall(const pt_material *m);

/*
 * Manifold next-event estimation (PT_FEAT_MANIFOLD): the environment's
 * light through thick smooth glass (Hanika, Droske & Fascione 2015,
 * "Manifold Next Event Estimation"; the chain's solver is manifold.h).
 *
 * At a rough vertex x whose light sample is the environment along wl, a ray
 * from x along wl seeds the chain: if it meets one or two surfaces of smooth
 * glass (mf_caster) and then nothing, Newton's method moves those points
 * until light leaving along wl refracts through them to x. The chain is
 * then checked as the renderer sees it: each segment's ray meets the next
 * vertex first, the last one escapes, and each vertex's closure refracts
 * the light from x's side exactly along the chain (pt_closure_refracted,
 * the same float arithmetic as sampling). Its estimate is
 *   f(w) T L(wl) J / p(wl),
 * w the direction from x to y_1, T the refractions' expected weights (with
 * the media's absorption), J = |d w / d wl| (pt_mf_jacobian), p the light
 * sample's pdf: a density p / J over the directions at x.
 *
 * A path that samples its BSDF at x (not a delta lobe) and reaches the
 * environment after exactly these refractions is the same light found by
 * the other strategy, whose density is the BSDF's pdf at x times the
 * refractions' pick probabilities. Both are weighed by the power heuristic
 * (Veach 1997, sec. 9.2): shade_miss solves the chain from x for the
 * direction the path left along (the deterministic seed makes that the
 * chain manifold NEE would have found, when it finds it at all) and weighs
 * the path by it; a path whose chain the solver does not give back is the
 * only strategy for its light and keeps weight 1. Any such pair of weights
 * is unbiased, whatever the solver fails to find.
 *
 * While seeding, the ray along wl answers the light sample's own shadow
 * ray: nothing met, the environment is seen; glass or anything but a thin
 * wall met, it is blocked. The scene has no alpha and nothing moves
 * (pt_renderer_new), so that closest hit and occlusion agree.
 */
/* Things inside the glass (not glass) the seed ray passes, at most, on its
 * way to the glass's far side: the refracted chain may go round them. */
#define MF_SEED_PASS 4u
/* What the seed ray along wl met. */
enum { MF_SEED_MISS, MF_SEED_BLOCKED, MF_SEED_THIN, MF_SEED_CHAIN };

/* A material whose surfaces a reflection chain may reflect at: smooth
 * glass, thin or thick, reflecting (ior not 1), with nothing that could
 * make it rough, bend its normal, split its lobe or colour its Fresnel. A
 * metallic texture may leave it glass in places (a metallic factor of 1
 * too): mr_connect finds the chain's closure and takes it only where it
 * reflects smoothly. */
static int mr_glass(const pt_material *m)
{
    return m->transmission > 0.0f && m->roughness == 0.0f && m->normal_tex < 0 &&
           (m->metallic < 1.0f || m->metal_rough_tex >= 0) && m->ior > 0.0f && m->ior != 1.0f &&
           !(m->dispersion > 0.0f) && !has_layers(m) && m->alpha_mode == PT_ALPHA_OPAQUE &&
           !(m->ext & ~(uint32_t)PT_MATX_SPECULAR_TEX);
}

/* ... or an opaque surface with a GGX lobe at PT_BSDF_MIN_ALPHA (roughness
 * up to sqrt(PT_BSDF_MIN_ALPHA), about 0.03) on the surface's interpolated
 * normal, which the chains take as a mirror (pt_closure_mirrored): smooth
 * metal, a smooth dielectric (a polished floor, plastic: F0 0.04 times its
 * specular), or a smooth clear coat without a normal of its own (car
 * paint). A normal map bends the base's lobes off that normal: then only
 * such a coat, which keeps it (pt_closure_coat_mirror). A texture may make
 * either lobe rough in places, where the closure says so. */
static int mr_smooth(const pt_material *m)
{
    const int base = (m->metallic > 0.0f || m->specular > 0.0f) &&
                     (m->metal_rough_tex >= 0 || m->roughness * m->roughness <= PT_BSDF_MIN_ALPHA);
    const int coat = m->clearcoat > 0.0f && m->clearcoat_normal_tex < 0 &&
                     (m->clearcoat_rough_tex >= 0 ||
                      m->clearcoat_roughness * m->clearcoat_roughness <= PT_BSDF_MIN_ALPHA);
    return !(m->transmission > 0.0f) && (m->normal_tex < 0 ? base || coat : coat) &&
           m->alpha_mode == PT_ALPHA_OPAQUE && !(m->ext & ~(uint32_t)PT_MATX_SPECULAR_TEX);
}

static int mr_caster(const pt_material *m)
{
    return mr_glass(m) || mr_smooth(m);
}

/* A material whose surfaces a chain may refract at: smooth thick glass,
 * refracting (ior not 1), with no texture or layer that could make it
 * rough, bend its normal or split its lobe. */
static int mf_caster(const pt_material *m)
{
    return m->thickness > 0.0f && m->metal_rough_tex < 0 && m->metallic < 1.0f && mr_glass(m);
}

/* A chain vertex at hit; 0 where the chain may not refract (reflect when
 * `mirror`). */
static int chain_vert(const pt_renderer *r, const pt_hit *hit, int mirror, pt_mf_vert *v)
{
    const pt_scene *s = r->scene;
    const tri_rec *t = &r->tris[hit->tri];
    const pt_material *m = &s->materials[t->mat & ~TRI_FLAT];
    if (hit->inst || !(mirror ? mr_caster(m) : mf_caster(m)))
        return 0;
    const uint32_t *tri = &s->indices[3 * hit->tri];
    pt_vec3 n[3] = {t->ns, t->ns, t->ns};
    if (!(t->mat & TRI_FLAT))
        for (int k = 0; k < 3; k++)
            n[k] = vert(s->normals, tri[k]);
    const pt_vec3 e1 = pt_v3_sub(t->v1, t->v0), e2 = pt_v3_sub(t->v2, t->v0);
    const pt_vec3 *src[6] = {&t->v0, &e1, &e2, &n[0], &n[1], &n[2]};
    double *dst[6] = {v->p0, v->e1, v->e2, v->n0, v->n1, v->n2};
    for (int k = 0; k < 6; k++) {
        dst[k][0] = src[k]->x;
        dst[k][1] = src[k]->y;
        dst[k][2] = src[k]->z;
    }
    v->ng[0] = t->ng.x;
    v->ng[1] = t->ng.y;
    v->ng[2] = t->ng.z;
    v->ior = m->ior;
    v->b[0] = hit->b1;
    v->b[1] = hit->b2;
    v->tri = hit->tri;
    return 1;
}

static inline pt_vec3 mf_f3(const double a[3])
{
    return pt_v3((float)a[0], (float)a[1], (float)a[2]);
}

/* A point off a surface of geometric normal n, on the side of d. */
static inline pt_vec3 mf_off(const pt_renderer *r, pt_vec3 p, pt_vec3 n, pt_vec3 d)
{
    return pt_offset_apply(r->offset, p, pt_v3_dot(n, d) < 0.0f ? pt_v3_neg(n) : n);
}

typedef struct mf_ctx {
    const pt_renderer *r;
    pt_vec3 ng; /* x's geometric normal */
    int mirror; /* a reflection chain's: its reflectors, not the chain glass */
} mf_ctx;

/* pt_mf_project_fn: the first surface along the ray, if a chain's. */
static __attribute__((noinline)) int mf_project(void *user, const pt_mf_vert *prev,
                                                const double from[3], const double q[3],
                                                pt_mf_vert *out)
{
    const mf_ctx *c = user;
    double d[3] = {q[0] - from[0], q[1] - from[1], q[2] - from[2]};
    pt_vec3 dir = pt_v3_norm(mf_f3(d));
    pt_vec3 o = mf_off(c->r, mf_f3(from), prev ? mf_f3(prev->ng) : c->ng, dir);
    /* The glass alone: a step's guess may pass behind a thing inside the
     * glass; the chain found is checked for that at the end. */
    pt_hit hit;
    return pt_accel_intersect(c->mirror ? c->r->mr_accel : c->r->mf_accel, o, dir, INFINITY,
                              &hit) &&
           chain_vert(c->r, &hit, c->mirror, out);
}

/* The second seed of a chain through two interfaces (c's first vertex
 * kept): the ray along wl refracted into the glass there, to where it
 * leaves. */
static int mf_seed_bent(const mf_ctx *ctx, pt_vec3 wl, pt_mf_chain *c)
{
    double p[3], n[3], d[3] = {wl.x, wl.y, wl.z};
    pt_mf_point(&c->v[0], c->v[0].b, p);
    if (!pt_mf_normal(&c->v[0], c->v[0].b, n))
        return 0;
    /* Into the glass: the ray meets the front (against ng) from air. */
    double ng_d = c->v[0].ng[0] * d[0] + c->v[0].ng[1] * d[1] + c->v[0].ng[2] * d[2];
    double eta = ng_d < 0.0 ? 1.0 / c->v[0].ior : c->v[0].ior;
    double ci = -(n[0] * d[0] + n[1] * d[1] + n[2] * d[2]);
    if (ci < 0.0) {
        for (int j = 0; j < 3; j++)
            n[j] = -n[j];
        ci = -ci;
    }
    double k = 1.0 - eta * eta * (1.0 - ci * ci);
    if (!(k > 0.0))
        return 0;
    double q[3];
    for (int j = 0; j < 3; j++)
        q[j] = p[j] + eta * d[j] + (eta * ci - sqrt(k)) * n[j];
    return mf_project((void *)ctx, &c->v[0], p, q, &c->v[1]);
}

/* The index of refraction on q's side of chain vertex v's surface: 1 in
 * front of it (its geometric normal's side), its glass's behind. */
static double mf_side_index(const pt_mf_vert *v, const double q[3])
{
    double p[3], side = 0.0;
    pt_mf_point(v, v->b, p);
    for (int j = 0; j < 3; j++)
        side += (q[j] - p[j]) * v->ng[j];
    return side > 0.0 ? 1.0 : v->ior;
}

/* A chain from x to the environment, found and checked. */
typedef struct mf_link {
    uint32_t k;
    pt_vec3 y[PT_MF_MAX];
    pt_vec3 T;    /* the refractions' expected weights and the media's transmittance */
    int opaque;   /* a reflection off an opaque mirror (mr_smooth), not glass (mr_connect) */
    float take;   /* the product of the refractions' pick probabilities */
    float jac;    /* |d w / d wl|; to a point: |d omega_l / dA_x| */
    float flux;   /* to a point: (index at the light / index at x)^2, which turns the
                     refractions' radiance weights T into the flux's; else 1 */
    uint32_t tri; /* a reflection chain's: its vertex's triangle (mr_connect) */
} mf_link;

/* What a chain's vertex v is as the renderer sees it from `from` (geometric
 * normal fng) along unit d: 0 unless that ray meets v's triangle first;
 * else its surface in *sf (its side in *front), its geometric normal on
 * d's side in *ngs, and its closure's smooth refraction (its reflection
 * when `reflect`), shaded as shade would shade the ray: the expected weight
 * (0 when there is none) and its pick probability in *T and *take, the
 * direction in *wi and, in the shading frame, *wi_l. An opaque surface's
 * reflection is its mirror lobes' (pt_closure_mirrored). */
static int chain_event(const pt_renderer *r, pt_vec3 from, pt_vec3 fng, pt_vec3 d,
                       const pt_mf_vert *v, int reflect, surface *sf, int *front, pt_vec3 *ngs,
                       pt_vec3 *T, float *take, pt_vec3 *wi, pt_vec3 *wi_l, const uint32_t features)
{
    pt_hit hit;
    if (!pt_accel_intersect(r->accel, mf_off(r, from, fng, d), d, INFINITY, &hit) ||
        hit.tri != v->tri || hit.inst)
        return 0;
    hit.b1 = (float)v->b[0];
    hit.b2 = (float)v->b[1];
    surface_at(r, &hit, 0.0f, sf, features);
    pt_vec3 wo = pt_v3_neg(d), ns;
    /* as shade: glass scatters to both sides, an opaque surface to its front */
    const int glass = transmits(sf->mat);
    shading_normals(sf, wo, glass, front, ngs, &ns, features);
    pt_frame fr = pt_frame_from_normal(ns);
    pt_vec3 wo_l = pt_frame_to_local(&fr, wo);
    pt_closure cl;
    material_closure(r, sf, glass, *front, &fr, wo, wo_l, *ngs, &cl, features);
    *T = !reflect ? pt_closure_refracted(&cl, wi_l, take)
         : glass  ? pt_closure_reflected(&cl, wi_l, take)
                  : pt_closure_mirrored(&cl, wi_l, take);
    *wi = pt_frame_to_world(&fr, *wi_l);
    return 1;
}

/* The chain from x (geometric normal ng on the side wl leaves, medium
 * `medium` there) to the environment along wl, or with `at` to the point
 * *at of a point light or an emitter (wl the unit direction to it), in
 * *lk: MF_SEED_CHAIN when one was found and checked, else what the seed ray
 * met (a seed that met glass but gave no chain is MF_SEED_BLOCKED). Rays
 * towards a point stop short of it by MF_AT_SHORT of their length (an
 * emitter's own triangle lies there). */
#define MF_AT_SHORT 1e-4f
static __attribute__((noinline)) int mf_connect(const pt_renderer *r, pt_vec3 x, pt_vec3 ng,
                                                int32_t medium, pt_vec3 wl, const pt_vec3 *at,
                                                uint32_t depth, mf_link *lk,
                                                const uint32_t features)
{
    const pt_scene *s = r->scene;
    if (!(pt_v3_dot(wl, ng) > 0.0f))
        return MF_SEED_BLOCKED;
    pt_mf_chain c;
    c.k = 0;
    c.at = at != NULL;
    uint32_t passed = 0;
    pt_vec3 o = pt_offset_apply(r->offset, x, ng);
    for (;;) {
        pt_hit hit;
        /* Up to the light's point; beyond it nothing matters. */
        float tfar = at ? (1.0f - MF_AT_SHORT) * pt_v3_dot(pt_v3_sub(*at, o), wl) : INFINITY;
        if (!pt_accel_intersect(r->accel, o, wl, tfar, &hit))
            break;
        const pt_material *m = &s->materials[s->tri_material[hit.tri] & ~TRI_FLAT];
        if (c.k == 0 && (features & PT_FEAT_THIN_GLASS) && r->thin_glass && thin_wall(m))
            return MF_SEED_THIN;
        if (c.k < PT_MF_MAX && chain_vert(r, &hit, 0, &c.v[c.k]))
            c.k++;
        else if (c.k == 0 || mf_caster(m) || ++passed > MF_SEED_PASS)
            return MF_SEED_BLOCKED;
        const tri_rec *t = &r->tris[hit.tri];
        pt_vec3 p = pt_v3_add(o, pt_v3_scale(wl, hit.t));
        o = mf_off(r, p, t->ng, wl);
    }
    if (c.k == 0)
        return MF_SEED_MISS;
    /* The path through the chain's last vertex must be one that scatters
     * (shade: depth below max_depth), as a sampled path's would. */
    if (depth + c.k >= r->params.max_depth)
        return MF_SEED_BLOCKED;
    mf_ctx ctx = {r, ng, 0};
    pt_vec3 end = at ? *at : wl;
    double xd[3] = {x.x, x.y, x.z}, wd[3] = {end.x, end.y, end.z};
    pt_mf_chain seed = c;
    if (!pt_mf_solve(xd, &c, wd, mf_project, &ctx)) {
        c = seed;
        if (c.k != 2 || !mf_seed_bent(&ctx, wl, &c) || !pt_mf_solve(xd, &c, wd, mf_project, &ctx))
            return MF_SEED_BLOCKED;
    }
    /* The chain as the renderer sees it. */
    pt_vec3 from = x, fng = ng, T = pt_v3(1.0f, 1.0f, 1.0f);
    float take = 1.0f;
    int32_t med = medium;
    for (uint32_t i = 0; i < c.k; i++) {
        double pd[3];
        pt_mf_point(&c.v[i], c.v[i].b, pd);
        pt_vec3 y = mf_f3(pd);
        pt_vec3 d = pt_v3_norm(pt_v3_sub(y, from));
        surface sf;
        int front;
        pt_vec3 ngs, w, wi, wi_l;
        float tk;
        if (!chain_event(r, from, fng, d, &c.v[i], 0, &sf, &front, &ngs, &w, &tk, &wi, &wi_l,
                         features) ||
            !(tk > 0.0f) || !any_positive(w))
            return MF_SEED_BLOCKED;
        pt_vec3 next = at ? pt_v3_norm(pt_v3_sub(*at, sf.p)) : wl;
        if (i + 1 < c.k) {
            double qd[3];
            pt_mf_point(&c.v[i + 1], c.v[i + 1].b, qd);
            next = pt_v3_norm(pt_v3_sub(mf_f3(qd), sf.p));
        }
        float side = pt_v3_dot(wi, ngs);
        /* shade's test for a direction through glass, and the solver's
         * chain within the float refraction's rounding */
        if (side == 0.0f || (side > 0.0f) != (wi_l.z > 0.0f) || !(pt_v3_dot(wi, next) > 0.9999f))
            return MF_SEED_BLOCKED;
        if ((features & PT_FEAT_VOLUME) && med >= 0)
            T = pt_v3_mul(T, medium_transmittance(s, med, pt_v3_len(pt_v3_sub(sf.p, from))));
        med = medium_across(s, med, (uint32_t)(sf.mat - s->materials), front, 0);
        T = pt_v3_mul(T, w);
        take *= tk;
        lk->y[i] = sf.p;
        from = sf.p;
        fng = sf.ng;
    }
    float jac;
    if (at) {
        /* The last segment reaches the light, through the medium it is in;
         * the flux along the chain's tube of rays leaves the light in
         * that medium's index and reaches x in x's: pt_closure_refracted's
         * weights carry the radiance's change of (index at x / index at the
         * light)^2, which the flux has not (manifold.h). */
        pt_vec3 d = pt_v3_sub(*at, from);
        float dist = pt_v3_len(d);
        if (!(dist > 0.0f))
            return MF_SEED_BLOCKED;
        /* aimed from the offset origin, so that an emitter is met at l */
        pt_vec3 lo = mf_off(r, from, fng, d), ld = pt_v3_sub(*at, lo);
        float ll = pt_v3_len(ld);
        if (!(ll > 0.0f) ||
            pt_accel_occluded(r->accel, lo, pt_v3_scale(ld, 1.0f / ll), (1.0f - MF_AT_SHORT) * ll))
            return MF_SEED_BLOCKED;
        if ((features & PT_FEAT_VOLUME) && med >= 0)
            T = pt_v3_mul(T, medium_transmittance(s, med, dist));
        double n_x = mf_side_index(&c.v[0], xd), n_l = mf_side_index(&c.v[c.k - 1], wd);
        lk->flux = (float)((n_l / n_x) * (n_l / n_x));
        jac = (float)pt_mf_point_jacobian(xd, &c, wd);
    } else {
        if (med >= 0) /* out into the environment through an absorbing volume: nothing */
            return MF_SEED_BLOCKED;
        pt_hit hit;
        if (pt_accel_intersect(r->accel, mf_off(r, from, fng, wl), wl, INFINITY, &hit))
            return MF_SEED_BLOCKED;
        jac = (float)pt_mf_jacobian(xd, &c, wd);
        lk->flux = 1.0f;
    }
    if (!(jac > 0.0f) || !isfinite(jac) || !any_positive(T))
        return MF_SEED_BLOCKED;
    lk->k = c.k;
    lk->T = T;
    lk->take = take;
    lk->jac = jac;
    return MF_SEED_CHAIN;
}

/* 1 when manifold NEE's chain lk is the sampled path's m: as many
 * vertices, each within tol of its distance from x. */
static int mf_same_chain(const mf_path *m, const mf_link *lk, float tol)
{
    if (lk->k != m->k)
        return 0;
    for (uint32_t i = 0; i < lk->k; i++) {
        float dist = pt_v3_len(pt_v3_sub(m->y[i], m->x));
        if (!(pt_v3_len(pt_v3_sub(lk->y[i], m->y[i])) <= tol * dist))
            return 0;
    }
    return 1;
}

/* The power heuristic's weight of a sampled path that reached the
 * environment (radiance le, shade_miss's lookup: after a delta lobe no MIS
 * has scaled it) after pa->mf's refractions from a rough vertex x, against
 * manifold NEE at x (see above); 1 when manifold NEE would not find it. */
static __attribute__((noinline)) float mf_bsdf_weight(const pt_renderer *r, const path *pa,
                                                      pt_vec3 le, const uint32_t features)
{
    const mf_path *m = pa->mf;
    /* Where light sampling never picks the direction (the dim part of a
     * map whose sampling is MIS-compensated), or manifold NEE does not
     * take it (mf_min_light), no chain is solved. */
    float lp = pt_lights_env_pdf(r->lights, pa->d, m->x, m->ln);
    if (!(lp > 0.0f) || !(pt_luminance(le) > r->mf_min_light))
        return 1.0f;
    mf_link lk;
    if (mf_connect(r, m->x, m->ng, m->medium, pa->d, NULL, m->depth, &lk, features) !=
            MF_SEED_CHAIN ||
        !mf_same_chain(m, &lk, 1e-3f))
        return 1.0f;
    return power_heuristic(m->pdf * m->take, lp / lk.jac);
}

/* The density over the directions at x of manifold NEE's chain lk from x
 * to point l of an emitter (geometric normal n) that light sampling picked
 * with solid-angle pdf lp along the straight line: its area density lp
 * |cos_s| / d^2 over |d omega_x / dA_l| = |cos_c| flux |d omega_l / dA_x|
 * (the etendue n^2 dA dw is kept along the tube), cos_s and cos_c the
 * cosines at l of the straight line and of the chain's last segment. 0 when
 * the two leave different sides of the emitter (not taken). */
static float mf_area_pdf(float lp, pt_vec3 n, pt_vec3 x, pt_vec3 l, const mf_link *lk)
{
    pt_vec3 s = pt_v3_sub(x, l), c = pt_v3_sub(lk->y[lk->k - 1], l);
    float ds = pt_v3_len(s), dc = pt_v3_len(c);
    float cos_s = pt_v3_dot(n, s) / ds, cos_c = pt_v3_dot(n, c) / dc;
    if (!(cos_s * cos_c > 0.0f))
        return 0.0f;
    float pd = lp * fabsf(cos_s) / (ds * ds) / (fabsf(cos_c) * lk->flux * lk->jac);
    return isfinite(pd) ? pd : 0.0f;
}

/* The power heuristic's weight of a sampled path that reached point sf->p
 * of emitter hit->tri after pa->mf's refractions from a rough vertex x,
 * against manifold NEE at x of that point (mf_nee); 1 when manifold NEE
 * would not find it. */
static __attribute__((noinline)) float mf_emit_weight(const pt_renderer *r, const path *pa,
                                                      const pt_hit *hit, const surface *sf,
                                                      const uint32_t features)
{
    const mf_path *m = pa->mf;
    pt_vec3 d = pt_v3_sub(sf->p, m->x);
    float dist = pt_v3_len(d);
    float lp = pt_lights_pdf(r->lights, r->scene, hit->tri, m->x, m->ln, sf->p, sf->ng);
    if (!(lp > 0.0f) || !(dist > 0.0f))
        return 1.0f;
    mf_link lk;
    /* The same chain within 1e-2: on the glass sphere of test_manifold's
     * emitter_sphere the solver's vertices lie up to 1e-3 of their distance
     * from the sampled path's (both refract within float rounding of each
     * other there: the chain's end on the emitter moves little as they
     * move), so 1e-3, the environment's tolerance, took a third of the same
     * chains for others and counted their light twice. */
    if (mf_connect(r, m->x, m->ng, m->medium, pt_v3_scale(d, 1.0f / dist), &sf->p, m->depth, &lk,
                   features) != MF_SEED_CHAIN ||
        !mf_same_chain(m, &lk, 1e-2f))
        return 1.0f;
    float pd = mf_area_pdf(lp, r->tris[hit->tri].ng, m->x, sf->p, &lk);
    return pd > 0.0f ? power_heuristic(m->pdf * m->take, pd) : 1.0f;
}

/* Manifold NEE at rough vertex sf (closure cl, frame fr, geometric normal
 * ng on wo's side) for its light sample ls of the environment or of a
 * directional light, which the
 * seed ray along it also answers: the shadow ray shade asked for (ret's
 * SHADE_SHADOW) is settled here unless a thin wall needs crossing. Returns
 * ret without SHADE_SHADOW when it was settled. */
static uint32_t mf_nee(const pt_renderer *r, path *pa, const surface *sf, const pt_light_sample *ls,
                       pt_vec3 ng, const pt_frame *fr, const pt_closure *cl, const shadow_ray *sr,
                       uint32_t ret, const uint32_t features)
{
    mf_link lk;
    const int at = ls->delta == PT_LIGHT_AT, area = ls->delta == PT_LIGHT_AREA;
    /* An emitter's point whose front the straight line does not see is not
     * taken (mf_emit_weight's rule too). */
    if (area && !any_positive(ls->radiance))
        return ret;
    int got = mf_connect(r, sf->p, ng, pa->medium, ls->wi, at || area ? &ls->position : NULL,
                         pa->depth, &lk, features);
    /* A point light's or an emitter's shadow ray is shade's, as before: the
     * seed ray ran from another point towards it. */
    if (got == MF_SEED_THIN || ((at || area) && got != MF_SEED_CHAIN))
        return ret;
    if ((ret & SHADE_SHADOW) && !at && !area) {
        /* The shadow ray's contribution, added where trace_shadow would
         * have: after this bounce's emission, before anything else. */
        if (got == MF_SEED_MISS) {
            pa->L = pt_v3_add(pa->L, sr->contrib);
            PT_TRACE_EVENT(PT_TRACE_SHADOW, pa->depth, -1, -1, 0, 0.0f, 0.0f, 0.0f, sr->contrib);
        }
        ret &= ~(uint32_t)SHADE_SHADOW;
    }
    if (got != MF_SEED_CHAIN)
        return ret;
    if (pa->mf)
        pa->mf->chains++;
    pt_vec3 w = pt_v3_norm(pt_v3_sub(lk.y[0], sf->p));
    if (!(pt_v3_dot(w, ng) > 0.0f))
        return ret;
    float bpdf = 0.0f;
    pt_vec3 f = pt_closure_eval(cl, pt_frame_to_local(fr, w), &bpdf);
    if (!any_positive(f))
        return ret;
    /* A directional light is a delta in wl: no sampled path finds it, and
     * ls->radiance is its irradiance (J carries it to the directions at
     * x); the environment is weighed against the sampled paths. A point
     * or spot light is a delta too: its intensity towards the chain's last
     * vertex (its range's window over the chain's length) times
     * |d omega_l / dA_x| (lk.jac) is the irradiance. */
    pt_vec3 le = ls->radiance;
    if (at) {
        pt_vec3 prev = sf->p;
        float len = 0.0f;
        for (uint32_t i = 0; i < lk.k; i++) {
            len += pt_v3_len(pt_v3_sub(lk.y[i], prev));
            prev = lk.y[i];
        }
        pt_vec3 d = pt_v3_sub(ls->position, prev);
        float dl = pt_v3_len(d);
        le = pt_punctual_intensity(ls->punct, pt_v3_scale(d, 1.0f / dl), len + dl);
    }
    float mis =
        ls->delta == PT_LIGHT_FAR || at ? 1.0f : power_heuristic(ls->pdf / lk.jac, bpdf * lk.take);
    float scale = mis * lk.jac / ls->pdf;
    if (at) {
        scale *= lk.flux;
    } else if (area) {
        /* An emitter's point l: the chain's density over the directions at x
         * (mf_area_pdf), weighed against the sampled paths that reach l
         * through the same chain (mf_emit_weight). */
        float pd = mf_area_pdf(ls->pdf, ls->normal, sf->p, ls->position, &lk);
        if (!(pd > 0.0f))
            return ret;
        mis = power_heuristic(pd, bpdf * lk.take);
        scale = mis / pd;
    }
    pt_vec3 c = pt_v3_mul(pt_v3_mul(pa->beta, pt_v3_mul(f, lk.T)), pt_v3_scale(le, scale));
    /* The light arrives at sf after smooth bounces: indirect, as the
     * sampled path that finds it counts it. */
    c = clamp_sample(r, pa, c, 0, features);
    PT_TRACE_EVENT(PT_TRACE_SHADOW, pa->depth, -1, ls->delta, (int32_t)lk.k, ls->pdf, bpdf, mis, c);
    pa->L = pt_v3_add(pa->L, c);
    return ret;
}

/*
 * Reflection chains (PT_FEAT_MANIFOLD, r->mirror): the light of a
 * directional, point or spot light that reaches a rough vertex x off one
 * smooth reflecting surface (glass's Fresnel reflection, thin or thick:
 * mr_glass; and smooth opaque surfaces, mr_smooth, for the lights
 * mr_smooth_light takes): a sun mirrored by a window onto the floor, a lamp
 * in a glass cabinet's door, a chrome ball in the sun. No path finds it
 * otherwise: the light is a delta, the reflection is a delta, and a shadow
 * ray towards the light ends at the glass (or crosses a thin wall, but never
 * turns), so the renderer left it out. The chain is one vertex y whose half
 * vector of the directions to x and to the light is the shading normal
 * there: manifold.h's constraint with the same index on both sides, solved
 * by the same Newton steps.
 *
 * No ray towards the light seeds it (that ray passes the reflector by), so
 * x picks one reflecting object k, with probability P_k(x) by the solid
 * angle its bounding sphere subtends at x (mr_pick; the bounce's roulette
 * number, independent of the light's pick), and seeds on it (mr_seed). The
 * estimate is, for a directional light of irradiance E along wl,
 *   f(w) T E J / (p P_k),  J = |d w / d wl| (pt_mf_jacobian),
 * and for a point or spot light at l of intensity I towards y,
 *   f(w) T I |d omega_l / dA_x| / (p P_k)  (pt_mf_point_jacobian),
 * w the direction from x to y, T the reflection's expected weight
 * (pt_closure_reflected), p the light's pick probability. No MIS: no other
 * strategy finds these paths.
 *
 * Smooth metal, a smooth dielectric (a polished floor) or a smooth clear
 * coat (mr_smooth: a GGX lobe at PT_BSDF_MIN_ALPHA, glTF roughness up to
 * about 0.03) is a mirror to the chains (T its Fresnel at y under the lobes
 * around it, pt_closure_mirrored). Its lobe is not a delta, so a sampled
 * path does find that light, by NEE at y, where x's direction fell within
 * the lobe's tenth of a degree (rare spikes: the light was all but missing).
 * That NEE leaves the light of y's mirror lobes to x's chain: the chain
 * evaluates x's closure without its own mirror lobes, the path keeps what
 * those sampled (mf_path's mshare, 1 after the camera or a delta bounce,
 * which no chain covers), and the sun's glint on chrome, seen directly or in
 * a mirror, keeps its NEE. The chain must cover every x the NEE gives way
 * to, so only lights whose choice at x cannot be denied are chained off
 * these surfaces (mr_smooth_light): directional ones, and point and spot
 * lights without a range in a scene without a light tree, for an x inside
 * the spot's cone; the others keep their NEE there.
 *
 * The environment's lamps off smooth opaque surfaces are chained the same
 * way (mr_env_nee: a direction of the map taken as a sun), and the sampled
 * path gives way to the chain as for a sun, its NEE at y and the map its
 * sampled direction from y finds (mf_path's ekeep). The environment's
 * light off glass, which BSDF sampling finds at a delta reflection, is not
 * chained: weighed against it by MIS (a sampled path's reflection solved
 * again from x, as for the refractions) it was unbiased but did not pay
 * (docs/bench/manifold.md, "Reflections"). Nor is an emitter's, which
 * would take the same weighing (not measured).
 */
/* Reflecting objects the chains know at most (the first ones met in the
 * scene's triangle order; the others reflect no chain). */
#define MR_MAX 64u
/* Rounds of the seed's fixed point on an object's bounding sphere
 * (mr_seed): with TransmissionTest's spheres chained to its map's lamps, 3
 * took 14 % off the render's time against 1, 6 no more. */
#define MR_SEED_ROUNDS 3
/* The solid angle of reflectors below which x chains only sometimes
 * (mr_pick). On the glass ball under a sun (64 spp, four seeds), pi took
 * the render's CPU from 2.83 s to 2.10 s (the build without chains: 1.46
 * s) for a relMSE 0.01 % higher, 2 pi to 2.02 s and 0.05 %, 4 pi to 1.85 s
 * and 0.1 %; a flat reflector's mirrored light does not fade with its solid
 * angle, so the smallest of the three (docs/bench/manifold.md). */
#define MR_OMEGA PT_PI

/* What a reflecting object has (mr_object.kinds; mr_pick's filter). */
enum {
    MR_GLASS = 1u,  /* smooth glass (mr_glass), which every chained light reflects off */
    MR_SMOOTH = 2u, /* smooth opaque surfaces (mr_smooth) */
    MR_HULL = 4u,   /* ... that lie on their convex hull (mr_hulls): the chains take
                       smooth opaque surfaces on such objects only */
};
/* The most smooth triangles of an object whose hull mr_hulls checks; a
 * larger object is not MR_HULL. */
#define MR_HULL_TRIS (1u << 20)

typedef struct mr_object {
    pt_vec3 c;       /* its reflecting triangles' bounding sphere: centre */
    float rad;       /* and radius */
    uint32_t object; /* the scene's object */
    uint32_t kinds;  /* MR_GLASS | MR_SMOOTH: what its reflecting triangles are */
} mr_object;

/* The solid angle of o's bounding sphere seen from x; 0 when it lies wholly
 * behind x's geometric normal ng (unless `both`: x transmits). */
static float mr_solid_angle(const mr_object *o, pt_vec3 x, pt_vec3 ng, int both)
{
    pt_vec3 d = pt_v3_sub(o->c, x);
    if (!both && pt_v3_dot(d, ng) < -o->rad)
        return 0.0f;
    float d2 = pt_v3_dot(d, d), r2 = o->rad * o->rad;
    if (!(d2 > r2))
        return 2.0f * PT_PI;
    /* 2 pi (1 - cos t), cos t = sqrt(1 - r^2 / d^2), without cancellation */
    float s2 = r2 / d2;
    return 2.0f * PT_PI * s2 / (1.0f + sqrtf(1.0f - s2));
}

/* Picks a reflecting object for x by u (its index, MR_NONE for none), its
 * probability in *P: its solid angle over their sum, or over MR_OMEGA when
 * they fill less of x's view, so that x far from small reflectors chains
 * rarely (their light there is faint) and weighs what it chains up. Of the
 * objects that have one of `kinds` (MR_GLASS, MR_SMOOTH). */
static uint32_t mr_pick(const pt_renderer *r, pt_vec3 x, pt_vec3 ng, int both, uint32_t kinds,
                        float u, float *P)
{
    float w[MR_MAX], sum = 0.0f;
    for (uint32_t i = 0; i < r->mr_n; i++)
        sum += w[i] = r->mr[i].kinds & kinds ? mr_solid_angle(&r->mr[i], x, ng, both) : 0.0f;
    *P = 0.0f;
    float total = fmaxf(sum, MR_OMEGA), t = u * total;
    if (!(sum > 0.0f) || !(t < sum))
        return MR_NONE;
    uint32_t last = MR_NONE;
    for (uint32_t i = 0; i < r->mr_n; i++) {
        if (!(w[i] > 0.0f))
            continue;
        last = i;
        if (t < w[i])
            break;
        t -= w[i];
    }
    *P = w[last] / total;
    return last;
}

/* The scene's object of triangle tri (0 in a scene without objects). */
static inline uint32_t mr_object_of(const pt_renderer *r, uint32_t tri)
{
    return r->scene->tri_object ? r->scene->tri_object[tri] : 0u;
}

/* 1 when pa's vertex (`through`: it scatters to both sides, `thin`: a thin
 * wall) offers reflection chains: not thick glass, in air, and with a
 * vertex at y that scatters, as a sampled path's would (mr_nee; mf_path's
 * mshare). */
static inline int mr_chains_at(const pt_renderer *r, const path *pa, int through, int thin)
{
    return (!through || thin) && pa->medium < 0 && pa->depth + 1 < r->params.max_depth;
}

/* 1 when light l (a point or spot light when `at`, else directional) chains
 * off smooth opaque surfaces (mr_smooth) for a receiver at x: a directional light always, its
 * choice the same at every x (the light tree holds point and spot lights
 * only); a point or spot light without a range, where no light tree may
 * deny x its choice (r->smooth_at) and x is inside its cone, as x's light
 * sample of it is taken (a range would window the chain's length and NEE's
 * distance apart). */
static inline int mr_smooth_light(const pt_renderer *r, const pt_punctual *l, int at, pt_vec3 x)
{
    if (!at)
        return 1;
    if (!r->smooth_at || l->range > 0.0f)
        return 0;
    pt_vec3 d = pt_v3_sub(l->position, x);
    float dist = pt_v3_len(d);
    return dist > 0.0f && any_positive(pt_punctual_intensity(l, pt_v3_scale(d, 1.0f / dist), dist));
}

/* 1 when NEE at hit (surface sf) of a light mr_smooth_light takes leaves the
 * mirror lobes of its closure to the reflection chain of the path's previous
 * vertex, as far as mf_path's mshare says: a still triangle of a smooth
 * opaque surface (mr_smooth) on one of the reflectors, as chain_vert takes
 * it. A sun mirrored by such a lobe onto a rough vertex x is the chain's
 * from x; NEE there found it only where x's sampled direction fell within
 * the lobe's tenth of a degree. Seen from the camera, or after a smooth
 * bounce, the lobe keeps its NEE (the sun's glint on chrome). */
static inline int mr_smooth_at(const pt_renderer *r, const pt_hit *hit, const surface *sf)
{
    return !hit->inst && mr_smooth(sf->mat) &&
           r->mr_of_object[mr_object_of(r, hit->tri)] != MR_NONE;
}

/* 1 when x lies on the outward side of triangle tri's plane (r->mr_side),
 * at its point y: x sees that MR_HULL object from outside its hull, where
 * one point of it at most mirrors a direction to x (the Gauss map of a
 * convex surface is one to one), the chain's root. */
static inline int mr_front(const pt_renderer *r, uint32_t tri, pt_vec3 x, pt_vec3 y)
{
    const int8_t side = r->mr_side[tri];
    return side == 0 || (float)side * pt_v3_dot(pt_v3_sub(x, y), r->tris[tri].ng) > 0.0f;
}

/* 1 when the light that point p of triangle tri (of a reflecting object)
 * mirrors to x may be x's chain's (mr_nee, mr_env_nee): p is on an MR_HULL
 * object, seen from outside its hull. Inside a bowl, where several points
 * mirror one light to x, a chain would deliver one: the sampled paths
 * keep them all. */
static inline int mr_hull_at(const pt_renderer *r, uint32_t tri, pt_vec3 x, pt_vec3 p)
{
    return (r->mr[r->mr_of_object[mr_object_of(r, tri)]].kinds & MR_HULL) && mr_front(r, tri, x, p);
}

/* The unit direction from p towards the light: wl, or towards the point
 * *at. */
static inline pt_vec3 mr_towards(pt_vec3 p, pt_vec3 wl, const pt_vec3 *at)
{
    return at ? pt_v3_norm(pt_v3_sub(*at, p)) : wl;
}

/* A seed on reflecting object o for the chain from x towards the light (wl,
 * or the point *at), into *v; 0 when its ray does not meet o first among
 * the reflectors. Seed 0: where the normal of o's bounding sphere halves
 * the directions to x and to the light (a few rounds of that fixed point
 * from the sphere's centre: the root on a sphere, near it on a convex
 * object); seed 1, for flat and concave ones: towards the light's mirror
 * image in the plane of the point that the ray from x towards o's centre
 * meets (the root on a plane). Unless `both` (x transmits), a seed below
 * x's surface is none: x on a convex mirror sees none of it. */
static int mr_seed(const pt_renderer *r, pt_vec3 x, pt_vec3 ng, int both, pt_vec3 wl,
                   const pt_vec3 *at, const mr_object *o, int seed, pt_mf_vert *v)
{
    pt_vec3 d;
    pt_hit hit;
    if (seed == 0) {
        pt_vec3 y = o->c;
        for (int i = 0; i < MR_SEED_ROUNDS; i++) {
            pt_vec3 a = pt_v3_sub(x, y);
            float la = pt_v3_len(a);
            if (!(la > 0.0f))
                return 0;
            pt_vec3 h = pt_v3_add(pt_v3_scale(a, 1.0f / la), mr_towards(y, wl, at));
            float lh = pt_v3_len(h);
            if (!(lh > 1e-6f))
                return 0;
            y = pt_v3_add(o->c, pt_v3_scale(h, o->rad / lh));
        }
        d = pt_v3_sub(y, x);
    } else {
        pt_vec3 dc = pt_v3_norm(pt_v3_sub(o->c, x));
        double nd[3];
        if (!pt_accel_intersect(r->mr_accel, mf_off(r, x, ng, dc), dc, INFINITY, &hit) ||
            !chain_vert(r, &hit, 1, v) || mr_object_of(r, hit.tri) != o->object ||
            !pt_mf_normal(v, v->b, nd))
            return 0;
        pt_vec3 n = mf_f3(nd);
        if (at) {
            /* x towards the image of *at in the plane through the hit */
            pt_vec3 p = pt_v3_add(x, pt_v3_scale(dc, hit.t));
            pt_vec3 img = pt_v3_sub(*at, pt_v3_scale(n, 2.0f * pt_v3_dot(pt_v3_sub(*at, p), n)));
            d = pt_v3_sub(img, x);
        } else {
            d = pt_v3_sub(wl, pt_v3_scale(n, 2.0f * pt_v3_dot(wl, n)));
        }
    }
    float ld = pt_v3_len(d);
    if (!(ld > 0.0f) || (!both && !(pt_v3_dot(d, ng) > 0.0f)))
        return 0;
    d = pt_v3_scale(d, 1.0f / ld);
    return pt_accel_intersect(r->mr_accel, mf_off(r, x, ng, d), d, INFINITY, &hit) &&
           chain_vert(r, &hit, 1, v) && mr_object_of(r, hit.tri) == o->object;
}

static int shadow_through(const pt_renderer *r, path *pa, const shadow_ray *sr,
                          const pt_ray_sink *sink, pt_vec3 *tr, const uint32_t features);

/* 1 when the light is seen from o along unit d over dist (INFINITY: a light
 * at infinity), through the smooth thin walls a shadow ray crosses
 * (shadow_through: their transmittance into *tr, at most as many as a path
 * whose vertex o is at `depth` could cross, alpha passed by alpha_key), or
 * past nothing at all without them. */
static int mr_light_seen(const pt_renderer *r, path *pa, pt_vec3 o, pt_vec3 d, float dist,
                         uint32_t depth, uint32_t alpha_key, pt_vec3 *tr, const uint32_t features)
{
    *tr = pt_v3(1.0f, 1.0f, 1.0f);
    if ((features & PT_FEAT_THIN_GLASS) && r->thin_glass) {
        uint32_t left = r->params.max_depth - 1u - depth;
        shadow_ray sr;
        sr.from = o;
        sr.dir = d;
        sr.dist = dist;
        sr.alpha_key = alpha_key;
        sr.cross_max = left < PT_SHADOW_CROSSINGS ? left : PT_SHADOW_CROSSINGS;
        return shadow_through(r, pa, &sr, NULL, tr, features);
    }
    pt_hit hit;
    return isfinite(dist) ? !pt_accel_occluded(r->accel, o, d, dist)
                          : !pt_accel_intersect(r->accel, o, d, INFINITY, &hit);
}

/* The reflection chain from x, pa's vertex (geometric normal ng on the side
 * of its path; `both`: it transmits), off reflecting object k towards the light along wl, or to
 * the point *at, in *lk: MF_SEED_CHAIN when one was found and checked as
 * the renderer sees it (x sees y, y's closure reflects the light from x
 * towards the light, which y sees, past thin walls with their
 * transmittance in lk->T; alpha_key passes MASK and BLEND surfaces there). */
static __attribute__((noinline)) int mr_connect(const pt_renderer *r, path *pa, pt_vec3 x,
                                                pt_vec3 ng, int both, pt_vec3 wl, const pt_vec3 *at,
                                                int opaque, uint32_t k, uint32_t alpha_key,
                                                mf_link *lk, const uint32_t features)
{
    const uint32_t depth = pa->depth;
    const mr_object *o = &r->mr[k];
    pt_mf_chain c;
    c.k = 1;
    c.at = at != NULL;
    mf_ctx ctx = {r, ng, 1};
    pt_vec3 end = at ? *at : wl;
    double xd[3] = {x.x, x.y, x.z}, wd[3] = {end.x, end.y, end.z}, pd[3];
    int got = MF_SEED_MISS;
    for (int seed = 0; seed < 2 && got != MF_SEED_CHAIN; seed++) {
        if (!mr_seed(r, x, ng, both, wl, at, o, seed, &c.v[0]))
            continue;
        got = pt_mf_solve(xd, &c, wd, mf_project, &ctx) && mr_object_of(r, c.v[0].tri) == o->object
                  ? MF_SEED_CHAIN
                  : MF_SEED_BLOCKED;
    }
    if (got != MF_SEED_CHAIN)
        return got;
    pt_mf_point(&c.v[0], c.v[0].b, pd);
    pt_vec3 w = pt_v3_norm(pt_v3_sub(mf_f3(pd), x));
    if (!both && !(pt_v3_dot(w, ng) > 0.0f))
        return MF_SEED_BLOCKED;
    surface sf;
    int front;
    pt_vec3 ngs, T, wi, wi_l;
    float tk;
    /* Smooth opaque surfaces mirror only the lights mr_smooth_light takes. */
    if (!chain_event(r, x, ng, w, &c.v[0], 1, &sf, &front, &ngs, &T, &tk, &wi, &wi_l, features) ||
        (!opaque && !transmits(sf.mat)) || !(tk > 0.0f) || !any_positive(T))
        return MF_SEED_BLOCKED;
    pt_vec3 next = mr_towards(sf.p, wl, at);
    /* shade's test for a reflected direction, and the solver's chain
     * within the float reflection's rounding. (A weight means wo.z > 0, so
     * a reflection about the shading normal is above it; a coat mirroring
     * on its own normal over a mapped base, COAT_SURFACE, may reflect
     * below the map's normal, as its sampled directions may.) */
    if (!(pt_v3_dot(wi, ngs) > 0.0f) || !(pt_v3_dot(wi, next) > 0.9999f))
        return MF_SEED_BLOCKED;
    /* y sees the light (past thin walls, as shade's shadow rays); aimed from
     * the offset origin, so that nothing at a light's point is met */
    pt_vec3 lo = mf_off(r, sf.p, sf.ng, next), ld = next, tr;
    float ll = INFINITY;
    if (at) {
        ld = pt_v3_sub(*at, lo);
        ll = pt_v3_len(ld);
        if (!(ll > 0.0f))
            return MF_SEED_BLOCKED;
        ld = pt_v3_scale(ld, 1.0f / ll);
        ll *= 1.0f - MF_AT_SHORT;
    }
    if (!mr_light_seen(r, pa, lo, ld, ll, depth + 1u, alpha_key, &tr, features))
        return MF_SEED_BLOCKED;
    float jac = (float)(at ? pt_mf_point_jacobian(xd, &c, wd) : pt_mf_jacobian(xd, &c, wd));
    if (!(jac > 0.0f) || !isfinite(jac))
        return MF_SEED_BLOCKED;
    lk->k = 1;
    lk->tri = c.v[0].tri;
    lk->y[0] = sf.p;
    lk->T = pt_v3_mul(T, tr);
    lk->opaque = !transmits(sf.mat);
    lk->take = tk;
    lk->jac = jac;
    lk->flux = 1.0f;
    return MF_SEED_CHAIN;
}

/* What x's closure cl (frame fr, geometric normal ng on wo's side; `both`:
 * it transmits) sends along the chain lk, its pdf in *bpdf: 0 when y is
 * below x's surface. Off an opaque mirror, without x's own mirror lobes:
 * what they send towards y is its sampled paths' (the next vertex's NEE
 * and the environment they find, mf_path's mshare and ekeep). Counts the
 * chain in the path's stats. */
static pt_vec3 mr_eval(path *pa, pt_vec3 x, pt_vec3 ng, const pt_frame *fr, const pt_closure *cl,
                       int both, const mf_link *lk, float *bpdf)
{
    if (pa->mf)
        pa->mf->chains++;
    pt_vec3 w = pt_v3_norm(pt_v3_sub(lk->y[0], x));
    if (!both && !(pt_v3_dot(w, ng) > 0.0f))
        return pt_v3(0.0f, 0.0f, 0.0f);
    pt_vec3 w_l = pt_frame_to_local(fr, w);
    pt_vec3 f = pt_closure_eval(cl, w_l, bpdf);
    if (lk->opaque && any_positive(f)) {
        pt_vec3 fm = pt_closure_eval_mirror(cl, w_l, NULL);
        f = pt_v3(fmaxf(f.x - fm.x, 0.0f), fmaxf(f.y - fm.y, 0.0f), fmaxf(f.z - fm.z, 0.0f));
    }
    return f;
}

/* The share of closure cl's f cos at wi (local) that its mirror lobes
 * give, per channel in [0, 1] (0 where f is 0): of a sampled direction,
 * the part of the throughput they carried (mf_path's mshare, ekeep). */
static pt_vec3 mirror_share(const pt_closure *cl, pt_vec3 wi)
{
    pt_vec3 fa, fm = pt_closure_eval_mirror(cl, wi, &fa);
    return pt_v3(fa.x > 0.0f ? fminf(fm.x / fa.x, 1.0f) : 0.0f,
                 fa.y > 0.0f ? fminf(fm.y / fa.y, 1.0f) : 0.0f,
                 fa.z > 0.0f ? fminf(fm.z / fa.z, 1.0f) : 0.0f);
}

/* The reflection chain at rough vertex sf (closure cl, frame fr, geometric
 * normal ng on wo's side; `both`: it transmits) for its light sample ls of
 * a directional, point or spot light, off the object u picks. Adds to
 * pa->L; the light sample's own shadow ray is shade's. */
static __attribute__((noinline)) void mr_nee(const pt_renderer *r, path *pa, const surface *sf,
                                             const pt_light_sample *ls, pt_vec3 ng,
                                             const pt_frame *fr, const pt_closure *cl, int both,
                                             float u, uint32_t alpha_key, const uint32_t features)
{
    float P;
    const int at = ls->delta == PT_LIGHT_AT;
    /* A closure of mirror lobes alone leaves opaque mirrors to its sampled
     * paths (mf_path's mshare 1): it chains off glass only. */
    const int opaque = r->mirror_smooth && mr_smooth_light(r, ls->punct, at, sf->p);
    const int glass_only = !opaque || pt_closure_has_mirror(cl) == 2;
    uint32_t k = mr_pick(r, sf->p, ng, both, glass_only ? MR_GLASS : MR_GLASS | MR_HULL, u, &P);
    mf_link lk;
    if (k == MR_NONE ||
        mr_connect(r, pa, sf->p, ng, both, ls->wi, at ? &ls->position : NULL, opaque, k, alpha_key,
                   &lk, features) != MF_SEED_CHAIN ||
        (lk.opaque && !mr_hull_at(r, lk.tri, sf->p, lk.y[0])))
        return;
    float bpdf = 0.0f;
    pt_vec3 f = mr_eval(pa, sf->p, ng, fr, cl, both, &lk, &bpdf);
    if (!any_positive(f))
        return;
    /* A directional light's ls->radiance is its irradiance; a point or spot
     * light's intensity is the one towards y, over the chain's length. */
    pt_vec3 le = ls->radiance;
    if (at) {
        pt_vec3 d = pt_v3_sub(ls->position, lk.y[0]);
        float dl = pt_v3_len(d);
        le = pt_punctual_intensity(ls->punct, pt_v3_scale(d, 1.0f / dl),
                                   pt_v3_len(pt_v3_sub(lk.y[0], sf->p)) + dl);
    }
    pt_vec3 c =
        pt_v3_mul(pt_v3_mul(pa->beta, pt_v3_mul(f, lk.T)), pt_v3_scale(le, lk.jac / (ls->pdf * P)));
    /* The light arrives at sf off a smooth bounce: indirect. */
    c = clamp_sample(r, pa, c, 0, features);
    PT_TRACE_EVENT(PT_TRACE_SHADOW, pa->depth, -1, ls->delta, 1, ls->pdf, bpdf, 1.0f, c);
    pa->L = pt_v3_add(pa->L, c);
}

/* The environment's light that reaches rough vertex sf (as mr_nee) off one
 * smooth opaque surface (r->mirror_env): a studio's lamps mirrored by
 * chrome onto the floor. A sampled path finds it where x's direction falls
 * within the mirror lobe's tenth of a degree of the lamp: caustic
 * fireflies. The chain takes a direction wl from the whole map's
 * distribution (numbers ud, the light sample's own: no new dimension) and
 * treats it as a sun of irradiance L(wl) / p(wl): f(w) T L J / (p P_k).
 * Only the lamps (mr_env_lamp): the path keeps the rest, and what the
 * mirror lobes at the next vertex y send of a lamp is taken out of its NEE
 * and of the map its sampled direction finds (mshare, ekeep), so that the
 * chain's directions cover all it gives way to: the whole map's
 * distribution is positive wherever the lookup is. */
static __attribute__((noinline)) void mr_env_nee(const pt_renderer *r, path *pa, const surface *sf,
                                                 pt_vec3 ng, const pt_frame *fr,
                                                 const pt_closure *cl, int both, float u,
                                                 const float ud[2], uint32_t alpha_key,
                                                 const uint32_t features)
{
    /* All of x's light off mirrors is then its sampled paths' (mshare 1). */
    if (pt_closure_has_mirror(cl) == 2)
        return;
    pt_vec3 wl, le;
    float lpdf, P;
    if (!pt_env_sample(r->params.env, ud, PT_ENV_FULL, pt_v3(0.0f, 0.0f, 0.0f), &wl, &le, &lpdf) ||
        !mr_env_lamp(r, le))
        return;
    uint32_t k = mr_pick(r, sf->p, ng, both, MR_HULL, u, &P);
    mf_link lk;
    if (k == MR_NONE ||
        mr_connect(r, pa, sf->p, ng, both, wl, NULL, 1, k, alpha_key, &lk, features) !=
            MF_SEED_CHAIN ||
        !lk.opaque || !mr_hull_at(r, lk.tri, sf->p, lk.y[0]))
        return;
    float bpdf = 0.0f;
    pt_vec3 f = mr_eval(pa, sf->p, ng, fr, cl, both, &lk, &bpdf);
    if (!any_positive(f))
        return;
    pt_vec3 c =
        pt_v3_mul(pt_v3_mul(pa->beta, pt_v3_mul(f, lk.T)), pt_v3_scale(le, lk.jac / (lpdf * P)));
    c = clamp_sample(r, pa, c, 0, features);
    PT_TRACE_EVENT(PT_TRACE_SHADOW, pa->depth, -1, PT_LIGHT_ENV, 1, lpdf, bpdf, 1.0f, c);
    pa->L = pt_v3_add(pa->L, c);
}

/*
 * One bounce of a path whose ray hit `hit`, with the bounce's numbers u. NEE
 * samples an emissive triangle at every vertex; the BSDF-sampled continuation
 * that hits an emitter adds its emission weighted by the power heuristic
 * against the light pdf, so each light path is counted once (Veach 1997,
 * sec. 9.2). Russian roulette after rr_depth bounces keeps throughput-weighted
 * survival (survival probability max(beta), at most RR_MAX_SURVIVE).
 *
 * Opaque surfaces reflect only: single-sided surfaces are treated as
 * two-sided for scattering (only emission is one-sided), a direction below
 * the geometric surface is dropped. Glass (PT_FEAT_TRANSMISSION, PT_FEAT_VOLUME;
 * general variant only) scatters to both sides: a shadow ray or the next ray
 * leaves from the side it goes to, offset along that side's normal; a
 * direction is kept only when the shading frame and the geometric normal put
 * it on the same side (no light leaks through interpolated normals); after a
 * smooth interface's delta lobe prev_pdf is 0, so the emitter or the
 * environment that the path then finds counts in full (Veach 1997, sec. 9.2:
 * a delta lobe has no light-sampling rival). A shadow ray from glass inside
 * an absorbing medium carries its transmittance. As before the closure
 * interface, glass reads its shading normal unbent by a normal map.
 *
 * Adds the hit's emission to pa->L; fills *sr and returns SHADE_SHADOW when
 * the light sample needs a shadow ray, whose contribution the caller adds
 * after this bounce's emission and before the next one's (trace_shadow), so
 * that L sums the same terms in the same order however the rays of many paths
 * are interleaved. Returns SHADE_CONTINUE with pa's next ray when the path
 * goes on.
 */
static inline __attribute__((always_inline)) uint32_t
shade(const pt_renderer *r, path *pa, const pt_hit *hit, const float u[DIM_PER_BOUNCE],
      const surface *sf, const pt_light_sample *ls, int ls_ok, const pt_vec3 *cos_wi,
      shadow_ray *sr, const uint32_t features)
{
    const pt_scene *s = r->scene;
    const int glass = (features & PT_FEAT_TRANSMISSION) && transmits(sf->mat);
    /* Scatters to both sides: glass, or a diffuse transmitter (thin). */
    const int through = glass || ((features & PT_FEAT_DIFFUSE_TRANSMISSION) &&
                                  (sf->mat->ext & PT_MATX_DIFFUSE_TRANSMISSION));
    const uint32_t strategy = r->params.light_strategy;
    uint32_t ret = 0;
    pt_vec3 wo = pt_v3_neg(pa->d);

    shade_emission(r, pa, hit, sf, features);
    if ((features & FEAT_PASSES) && pa->pr && pa->depth == 0)
        pass_first_hit(r, pa->pr, hit, sf, features);
    if ((features & PT_FEAT_UNLIT) && (sf->mat->ext & PT_MATX_UNLIT)) {
        if ((features & FEAT_PASSES) && pa->pr && !pa->pr->found)
            pass_unlit(r, pa, sf, wo, features);
        shade_unlit(r, pa, sf, features);
        return ret;
    }
    if (pa->depth >= r->params.max_depth)
        return ret;

    int front;
    pt_vec3 ng, ns;
    shading_normals(sf, wo, through, &front, &ng, &ns, features);
    pt_frame fr = pt_frame_from_normal(ns);
    pt_vec3 wo_l = pt_frame_to_local(&fr, wo);
    /* The Lambert variants skip the closure (lambert_eval). */
    pt_bsdf lambert;
    pt_closure cl;
    if (features & PT_FEAT_GLOSSY)
        material_closure(r, sf, glass, front, &fr, wo, wo_l, ng, &cl, features);
    else
        lambert = material_bsdf(r, sf, features);
    uint32_t mi = (uint32_t)(sf->mat - s->materials);
    /* Glass, or a diffuse transmitter, with a volume (KHR_materials_volume)
     * crosses into it or out of it (medium_across); a thin one does not. */
    int thin = through && !(sf->mat->thickness > 0.0f);
    if ((features & FEAT_PASSES) && pa->pr && !pa->pr->found) {
        /* The passes' vertex: the first non-specular one. Through a specular
         * one the path goes on, and beta carries the chain's throughput to
         * the albedo found behind it. */
        pt_vec3 alb = pt_v3(0.0f, 0.0f, 0.0f);
        int rough = 1;
        if (features & PT_FEAT_GLOSSY)
            rough = pt_closure_albedo(&cl, &alb);
        else
            alb = lambert.diffuse;
        if (rough) {
            pa->pr->found = 1;
            pa->pr->v.albedo = pt_v3_mul(pa->beta, alb);
            pa->pr->v.normal = ns;
        }
    }
    /* Path guiding (FEAT_GUIDE): at a guidable closure the continuation is
     * drawn from the mixture gprob x guide + (1 - gprob) x closure (one-sample
     * MIS, Mueller et al. 2017, sec. 5). MIS against light sampling weighs
     * the closure's own pdf, not the mixture's: light sampling and the
     * emission a continuation finds weigh the same pdf, so their weights
     * still sum to 1 (Veach 1997, sec. 9.2: any such weights are unbiased),
     * and a light sample costs no lookup of the guide's pdf. */
    const pt_guide *guide = NULL;
    uint32_t gleaf = 0;
    float gprob = 0.0f;
    if ((features & FEAT_GUIDE) && pa->gp && pa->gp->gd && pa->gp->gd->guide && !glass &&
        pa->gp->rough < GUIDE_MAX_ROUGH && (features & PT_FEAT_GLOSSY) && closure_guidable(&cl)) {
        pa->gp->rough++;
        guide = pa->gp->gd->guide;
        gprob = pa->gp->gd->prob * closure_guide_share(&cl);
        gleaf = pt_guide_cell(guide, sf->p, ns);
        /* Whether it was learned is read after light sampling, which
         * hides the fetch of its tree. */
        pt_guide_prefetch(guide, gleaf);
    }

    if ((features & NEE_LIGHTS) && r->nee) {
        pt_vec3 lrad = ls_ok ? ls->radiance : pt_v3(0.0f, 0.0f, 0.0f);
        if ((features & PT_FEAT_ALPHA) && r->alpha && ls_ok && ls->delta == PT_LIGHT_AREA &&
            pt_alpha_tri(r->scene, ls->tri) && !(r->alpha_solid && r->alpha_solid[ls->tri]))
            lrad = pt_v3_scale(lrad, light_coverage(r, ls));
        if (features & PT_FEAT_ALPHA)
            sr->alpha_key = pt_alpha_key(u[OFF_ALPHA], ALPHA_SALT_SHADOW);
        float side = ls_ok ? pt_v3_dot(ls->wi, ng) : 0.0f;
        if (ls_ok && ls->pdf > 0.0f && any_positive(lrad) && (side > 0.0f || through)) {
            float bpdf = 0.0f;
            pt_vec3 wi_ll = pt_frame_to_local(&fr, ls->wi);
            pt_vec3 f = pt_v3(0.0f, 0.0f, 0.0f);
            if (!(features & PT_FEAT_GLOSSY))
                f = lambert_eval(&lambert, wo_l, wi_ll, &bpdf);
            else if (!through || (side != 0.0f && (side > 0.0f) == (wi_ll.z > 0.0f)))
                f = pt_closure_eval(&cl, wi_ll, &bpdf);
            if ((features & PT_FEAT_MANIFOLD) && r->mirror_smooth && (features & PT_FEAT_GLOSSY) &&
                pa->mf && mr_smooth_at(r, hit, sf) && any_positive(f) &&
                (((ls->delta == PT_LIGHT_FAR || ls->delta == PT_LIGHT_AT) &&
                  mr_smooth_light(r, ls->punct, ls->delta == PT_LIGHT_AT, pa->mf->x)) ||
                 ((features & PT_FEAT_ENV) && ls->delta == PT_LIGHT_ENV && r->mirror_env &&
                  mr_env_lamp(r, ls->radiance))) &&
                mr_hull_at(r, hit->tri, pa->mf->x, sf->p)) {
                /* The share of the mirror lobes' light that the previous
                 * vertex's chain delivers is not taken again. */
                pt_vec3 fm = pt_closure_eval_mirror(&cl, wi_ll, NULL);
                pt_vec3 ms = pa->mf->mshare;
                f = pt_v3(fmaxf(f.x - fm.x * (1.0f - ms.x), 0.0f),
                          fmaxf(f.y - fm.y * (1.0f - ms.y), 0.0f),
                          fmaxf(f.z - fm.z * (1.0f - ms.z), 0.0f));
            }
            if (any_positive(f)) {
                pt_vec3 from = pt_offset_apply(r->offset, sf->p, side > 0.0f ? ng : pt_v3_neg(ng));
                float w;
                sr->from = from;
                if ((features & PT_FEAT_THIN_GLASS) && r->thin_glass) {
                    /* A path that samples its way through k walls shades
                     * them at depths depth + 1 .. depth + k, which must be
                     * below max_depth for it to reach the light: NEE crosses
                     * as many, so both strategies see the same light. */
                    uint32_t left = r->params.max_depth - 1u - pa->depth;
                    sr->cross_max = left < PT_SHADOW_CROSSINGS ? left : PT_SHADOW_CROSSINGS;
                }
                if (!(features & (PT_FEAT_PUNCTUAL | PT_FEAT_ENV)) || ls->delta == PT_LIGHT_AREA) {
                    pt_vec3 nl = ls->normal;
                    if (pt_v3_dot(nl, ls->wi) > 0.0f)
                        nl = pt_v3_neg(nl);
                    pt_vec3 to = pt_offset_apply(r->offset, ls->position, nl);
                    pt_vec3 sd = pt_v3_sub(to, from);
                    float dist = pt_v3_len(sd);
                    sr->dist = dist;
                    sr->dir = pt_v3_scale(sd, dist > 0.0f ? 1.0f / dist : 0.0f);
                    w = (strategy == PT_LIGHT_MIS ? power_heuristic(ls->pdf, bpdf) : 1.0f) /
                        ls->pdf;
                } else if (ls->delta == PT_LIGHT_AT) {
                    /* A punctual light: BSDF sampling cannot find it, so no
                     * MIS; ls->radiance is the irradiance it gives, f holds
                     * the cosine. */
                    pt_vec3 sd = pt_v3_sub(ls->position, from);
                    float dist = pt_v3_len(sd);
                    sr->dist = dist;
                    sr->dir = pt_v3_scale(sd, dist > 0.0f ? 1.0f / dist : 0.0f);
                    w = 1.0f / ls->pdf;
                } else {
                    /* A directional light, or the environment: weighed
                     * against BSDF sampling like an emitter. Both at infinity. */
                    sr->dir = ls->wi;
                    sr->dist = INFINITY;
                    w = 1.0f / ls->pdf;
                    if ((features & PT_FEAT_ENV) && ls->delta == PT_LIGHT_ENV &&
                        strategy == PT_LIGHT_MIS)
                        w = power_heuristic(ls->pdf, bpdf) / ls->pdf;
                }
                pt_vec3 c = pt_v3_mul(pa->beta, pt_v3_scale(pt_v3_mul(f, lrad), w));
                if ((features & PT_FEAT_VOLUME) && through) {
                    /* From the hit point to the light's (medium_length),
                     * not between the offset ends of the shadow ray. */
                    int32_t med =
                        side > 0.0f ? pa->medium : medium_across(s, pa->medium, mi, front, thin);
                    float md =
                        isfinite(sr->dist) ? pt_v3_len(pt_v3_sub(ls->position, sf->p)) : INFINITY;
                    c = pt_v3_mul(c, medium_transmittance(s, med, md));
                }
                /* Light sampled at depth d arrives at vertex d: direct at 0. */
                sr->contrib = clamp_sample(r, pa, c, pa->depth == 0, features);
                PT_TRACE_EVENT(PT_TRACE_NEE, pa->depth, (int32_t)mi, ls->delta, 0, ls->pdf, bpdf,
                               w * ls->pdf, c);
                ret = SHADE_SHADOW;
            }
        }
    }

    if ((features & PT_FEAT_MANIFOLD) && r->refract && (features & PT_FEAT_GLOSSY) && ls_ok &&
        !through && ls->pdf > 0.0f &&
        ((ls->delta == PT_LIGHT_ENV && pt_luminance(ls->radiance) > r->mf_min_light) ||
         ((features & PT_FEAT_PUNCTUAL) &&
          (ls->delta == PT_LIGHT_FAR || ls->delta == PT_LIGHT_AT)) ||
         ((features & PT_FEAT_EMITTERS) && ls->delta == PT_LIGHT_AREA)))
        ret = mf_nee(r, pa, sf, ls, ng, &fr, &cl, sr, ret, features);
    if ((features & PT_FEAT_MANIFOLD) && (features & PT_FEAT_PUNCTUAL) && r->mirror &&
        (features & PT_FEAT_GLOSSY) && ls_ok && ls->pdf > 0.0f &&
        (ls->delta == PT_LIGHT_FAR || ls->delta == PT_LIGHT_AT) &&
        mr_chains_at(r, pa, through, thin))
        mr_nee(r, pa, sf, ls, ng, &fr, &cl, through, u[OFF_RR],
               pt_alpha_key(u[OFF_ALPHA], ALPHA_SALT_SHADOW), features);
    if ((features & PT_FEAT_MANIFOLD) && (features & PT_FEAT_ENV) && r->mirror_env &&
        (features & PT_FEAT_GLOSSY) && pa->mf && mr_chains_at(r, pa, through, thin))
        mr_env_nee(r, pa, sf, ng, &fr, &cl, through, u[OFF_RR], &u[OFF_LIGHT_POINT],
                   pt_alpha_key(u[OFF_ALPHA], ALPHA_SALT_SHADOW), features);

    float u3[3];
    u3[0] = u[OFF_LIGHT_PICK + 1];
    u3[1] = u[OFF_BSDF_DIR];
    u3[2] = u[OFF_BSDF_DIR + 1];
    pt_vec3 wi_l;
    float pdf;
    int delta = 0;
    pt_vec3 weight;
    float rr_scale = 1.0f;           /* FEAT_GUIDE: the mixture's pdf over the BSDF's */
    float bp_mis = 0.0f;             /* FEAT_GUIDE: the BSDF's pdf, which MIS weighs */
    uint32_t qleaf = GUIDE_NO_QLEAF; /* FEAT_GUIDE: the guide's leaf of wi, when looked up */
    int from_guide = 0;              /* FEAT_GUIDE: wi was drawn from the guide */
    /* A cell no record reached is uniform: recorded into, not sampled. */
    if ((features & FEAT_GUIDE) && guide && !pt_guide_learned(guide, gleaf))
        gprob = 0.0f;
    if ((features & FEAT_GUIDE) && guide && gprob > 0.0f) {
        /* u3[0] picks the guide or the closure, rescaled for the closure's
         * own lobe pick; the weight is f / the mixture's pdf. */
        float gpdf = 0.0f, bp = 0.0f;
        pt_vec3 f = pt_v3(0.0f, 0.0f, 0.0f);
        if (u3[0] < gprob) {
            from_guide = 1;
            pt_vec3 wg = pt_guide_sample(guide, gleaf, &u3[1], &gpdf);
            wi_l = pt_frame_to_local(&fr, wg);
            f = pt_closure_eval(&cl, wi_l, &bp);
        } else {
            float uc[3] = {fminf((u3[0] - gprob) / (1.0f - gprob), 0x1.fffffep-1f), u3[1], u3[2]};
            pt_vec3 w = pt_closure_sample(&cl, uc, &wi_l, &bp, &delta);
            if (bp > 0.0f) {
                f = pt_v3_scale(w, bp);
                /* The leaf of the direction recorded (wi below, the same
                 * bits), kept for the record. */
                gpdf = pt_guide_pdf_leaf(guide, gleaf, pt_frame_to_world(&fr, wi_l), &qleaf);
            }
        }
        pdf = gprob * gpdf + (1.0f - gprob) * bp;
        PT_TRACE_EVENT(PT_TRACE_GUIDE, pa->depth, (int32_t)mi, -1, u3[0] < gprob, gprob, gpdf, bp,
                       pt_v3(0.0f, 0.0f, 0.0f));
        weight = pdf > 0.0f ? pt_v3_scale(f, 1.0f / pdf) : pt_v3(0.0f, 0.0f, 0.0f);
        if (bp > 0.0f && pdf > 0.0f)
            rr_scale = pdf / bp;
        bp_mis = bp > 0.0f ? bp : 0x1p-126f;
    } else {
        weight = (features & PT_FEAT_GLOSSY)
                     ? pt_closure_sample(&cl, u3, &wi_l, &pdf, &delta)
                     : lambert_sample(&lambert, wo_l, u3, &wi_l, &pdf, cos_wi);
    }
    if ((features & FEAT_GUIDE) && guide && !(gprob > 0.0f))
        PT_TRACE_EVENT(PT_TRACE_GUIDE, pa->depth, (int32_t)mi, -1, 0, 0.0f, 0.0f, pdf,
                       pt_v3(0.0f, 0.0f, 0.0f));
    if (!(pdf > 0.0f) || !any_positive(weight))
        return ret;
    PT_TRACE_EVENT(PT_TRACE_BOUNCE, pa->depth, (int32_t)mi, -1, delta, pdf, wo_l.z, wi_l.z, weight);
    pt_vec3 wi = pt_frame_to_world(&fr, wi_l);
    float side = pt_v3_dot(wi, ng);
    if (through ? side == 0.0f || (side > 0.0f) != (wi_l.z > 0.0f) : side <= 0.0f)
        return ret; /* opaque: below the geometric surface, reflection only */
    pt_vec3 beta = pt_v3_mul(pa->beta, weight);
    if ((features & FEAT_GUIDE) && guide)
        pa->gp->rr *= rr_scale;

    if (pa->depth + 1 >= r->params.rr_depth) {
        /* fminf(pt_v3_max_comp(beta), RR_MAX_SURVIVE) by comparisons (a
         * NaN max gives RR_MAX_SURVIVE as fminf does). */
        float m = max2(beta.x, max2(beta.y, beta.z));
        /* Guided: the throughput the BSDF alone would have left. A
         * direction the guide chose for its light has a small weight (its
         * pdf is large) and a large radiance to come; roulette by the
         * weight alone would kill it as often as the guide made it likely,
         * and undo the guide (Vorba & Krivanek 2016, "Adjoint-Driven
         * Russian Roulette and Splitting in Light Transport Simulation":
         * roulette by the expected contribution; the guide's pdf over the
         * BSDF's stands in for the radiance to come over its mean). Any
         * survival probability in (0, 1] keeps the estimate unbiased. */
        if ((features & FEAT_GUIDE) && pa->gp)
            m *= pa->gp->rr;
        float survive = m < RR_MAX_SURVIVE ? m : RR_MAX_SURVIVE;
        if (!(u[OFF_RR] < survive))
            return ret;
        beta = pt_v3_scale(beta, 1.0f / survive);
    }
    if ((features & PT_FEAT_MANIFOLD) && r->mirror_smooth && (features & PT_FEAT_GLOSSY) &&
        pa->mf) {
        /* At a vertex whose reflection chains (mr_nee; mr_connect's tests)
         * take a sun off opaque mirrors, the path keeps only the share its
         * own mirror lobes sampled: the chains evaluate the rest of its
         * closure towards the mirror. */
        pt_vec3 ms = pt_v3(1.0f, 1.0f, 1.0f);
        /* the share of f at wi that the closure's mirror lobes give, per
         * channel (both uses below read it; computed once) */
        pt_vec3 share = pt_v3(0.0f, 0.0f, 0.0f);
        int shared = 0;
        if ((features & PT_FEAT_ENV) && r->mirror_env &&
            !((features & PT_FEAT_THIN_GLASS) && r->thin_glass && delta && thin && wi_l.z < 0.0f &&
              pa->cross < PT_SHADOW_CROSSINGS)) {
            /* A lamp this vertex's mirror lobes send back along the path is
             * the previous vertex's chain's (mr_env_nee) as far as its
             * mshare says; straight through a thin wall (below) the last
             * real vertex's share stands, as the chain's light crosses it. */
            pt_vec3 ek = pt_v3(1.0f, 1.0f, 1.0f), pm = pa->mf->mshare;
            if (!delta && mr_smooth_at(r, hit, sf) && (pm.x < 1.0f || pm.y < 1.0f || pm.z < 1.0f) &&
                mr_hull_at(r, hit->tri, pa->mf->x, sf->p)) {
                share = mirror_share(&cl, wi_l);
                shared = 1;
                ek = pt_v3(1.0f - share.x * (1.0f - pm.x), 1.0f - share.y * (1.0f - pm.y),
                           1.0f - share.z * (1.0f - pm.z));
            }
            pa->mf->ekeep = ek;
        }
        if (!delta && mr_chains_at(r, pa, through, thin)) {
            ms = pt_v3(0.0f, 0.0f, 0.0f);
            if (shared)
                ms = share;
            else if (pt_closure_has_mirror(&cl))
                ms = mirror_share(&cl, wi_l);
        }
        pa->mf->mshare = ms;
    }
    if ((features & PT_FEAT_VOLUME) && through && side < 0.0f)
        pa->medium = medium_across(s, pa->medium, mi, front, thin);
    pa->beta = beta;
    if ((features & PT_FEAT_THIN_GLASS) && r->thin_glass && delta && thin && wi_l.z < 0.0f &&
        pa->cross < PT_SHADOW_CROSSINGS) {
        /* Straight through a smooth thin wall (its delta transmission is
         * -wo), which shadow rays cross too (trace_shadow): the light found
         * behind it is weighed against NEE from the last real vertex, as if
         * the wall were not there, so prev_p and prev_pdf stay. Past
         * PT_SHADOW_CROSSINGS walls NEE is blocked, and what the path finds
         * counts in full (prev_pdf 0), as after any delta lobe. */
        pa->cross++;
    } else {
        pa->prev_p = sf->p;
        pa->prev_n = light_normal(r, sf, wo, features);
        pa->prev_pdf =
            delta ? 0.0f : ((features & FEAT_GUIDE) && guide && gprob > 0.0f ? bp_mis : pdf);
        if ((features & PT_FEAT_THIN_GLASS) && r->thin_glass)
            pa->cross = 0;
    }
    if ((features & PT_FEAT_MANIFOLD) && pa->mf) {
        /* The chain manifold NEE at a rough vertex would weigh this path
         * against (mf_bsdf_weight): it starts at a rough direction from an
         * opaque vertex and grows by smooth refractions at chain glass. */
        mf_path *m = pa->mf;
        if (!delta) {
            /* (without r->refract only reflection chains, which no sampled
             * path finds: nothing to weigh) */
            m->k = through || !r->refract ? MF_OFF : 0u;
            m->x = sf->p;
            m->ng = ng;
            m->ln = pa->prev_n;
            m->pdf = pa->prev_pdf;
            m->take = 1.0f;
            m->medium = pa->medium;
            m->depth = pa->depth;
        } else if (m->k < PT_MF_MAX && glass && wi_l.z < 0.0f && mf_caster(sf->mat)) {
            m->y[m->k++] = sf->p;
            m->take *= pdf;
        } else {
            m->k = MF_OFF;
        }
    }
    if (features & PT_FEAT_VOLUME)
        pa->seg_p = sf->p;
    pa->o = pt_offset_apply(r->offset, sf->p, side > 0.0f ? ng : pt_v3_neg(ng));
    pa->d = wi;
    pa->depth++;
    if ((features & FEAT_GUIDE) && guide && pa->gp->n < GUIDE_VERTS) {
        guide_vert *gv = &pa->gp->v[pa->gp->n++];
        gv->dir = wi;
        gv->leaf = gleaf;
        /* A direction the guide drew: its record's leaf is found now,
         * while the lines its sampling walked are in the cache, not at
         * the path's end (the same leaf: the same walk of wi). */
        if (from_guide && pa->gp->gd->stats)
            qleaf = pt_guide_qleaf(guide, gleaf, wi, NULL);
        gv->qleaf = qleaf;
        gv->pdf = pdf;
        gv->beta = pt_luminance(beta);
        gv->snap = 0.0f;
        pa->gp->pending = 1;
    }
    return ret | SHADE_CONTINUE;
}

/*
 * Caustic photons (FEAT_GUIDE, in a pass that records). Light that reaches a
 * rough surface only through smooth ones (glass, mirrors, chrome) is what a
 * camera path finds by chance, so the guide its records build seldom knows
 * that light's direction (docs/bench/guiding.md, "Light through glass": most
 * of the glass scenes' error leaves a guided vertex whose guide gives the
 * caustic less than half the BSDF's pdf). Each camera sample of a recording
 * pass also traces one photon from the environment at the sphere around the
 * scene's smooth surfaces (photon_src), through them, and records at the
 * first rough surface it reaches the direction it came from: the caustic
 * photons of Jensen 1996 ("Global Illumination using Photon Maps"), used as
 * the guide's training records as in Vorba et al. 2014 ("On-line Learning of
 * Parametric Mixture Models for Light Transport Simulation"). A photon that
 * meets a rough surface first is dropped: that light is direct, and NEE
 * finds it.
 *
 * Its record is in the camera records' units. A camera record is L / p, so a
 * leaf's sum in a direction cell is about (camera records in the leaf) x the
 * mean over its surface of the integral of L over the cell; those records
 * number spp x A / a per area A, a = d^2 w / cos_c the area a pixel of solid
 * angle w sees at distance d and angle c. A photon of flux F arriving at
 * angle t adds F / cos t to A x that integral in expectation; with N = npix x
 * spp photons a pass of the environment's flux through the sphere's disk,
 * F = (L / p) pi R^2 / N, its record is (L / p) pi R^2 cos_c /
 * (cos t d^2 npix w), in which npix x w is the image plane's area at unit
 * distance over cos^3 of the angle off the camera's axis (perspective; an
 * orthographic view's area, without d^2, otherwise). The records are
 * approximate (the pixel area of the point seen directly, deeper camera
 * records not counted); they only shape the guide, the pdf of a one-sample
 * mixture with the BSDF, so the estimate stays unbiased whatever they say.
 * Keyed by (pixel, sample) like the camera's numbers, the statistics stay
 * sums of integers, the same however the pass was split.
 */
#define PHOTON_SALT 0x70686f74u /* the photons' numbers: their own scramble */
/* One camera sample in PHOTON_EVERY traces a photon (its record counts for
 * that many): at 1 the photons cost the glass ball 37 % more CPU than the
 * guided render without them, at 4 about 15 %, and kept most of the error's
 * fall at 256 spp (docs/bench/guiding.md, "Caustic photons"). */
#define PHOTON_EVERY 4u
/* The caustic's records weigh this many times the units above: the camera's
 * records hold the light NEE already samples well (the lamps seen directly),
 * which a guide in proportion to all incident light spends most of its
 * directions on. Measured on the glass ball at 256 spp (three seeds, mean
 * relMSE): 0.1 1.75, 1 1.78, 10 1.16, 100 1.07, 1,000 1.07; without photons
 * 2.09. */
#define PHOTON_WEIGHT 100.0f
#define PHOTON_MAX_BOUNCES 8u    /* smooth bounces a photon follows at most */
#define PHOTON_MIN_COS 0.05f     /* a grazing arrival's cosine is taken as this */
#define PHOTON_MIN_CAM_COS 0.25f /* and a point's cosine off the camera's axis */

/* A metal smooth enough for a path not to be guided at it
 * (closure_guidable), by its metallic and roughness. */
static inline int smooth_metal(float metallic, float roughness)
{
    return metallic >= 0.5f && roughness * roughness < GUIDE_MIN_ALPHA;
}

/* A material whose surfaces may pass light on without spreading it, so that
 * photon_trace aims at them: glass, or a metal that may be smooth. The
 * factors multiply the metallic-roughness texture's values (at most 1): with
 * one, any point of a metallic factor of 0.5 or more may be such a metal
 * (ToyCar's chrome is a texel of its one material). */
static int photon_smooth(const pt_material *m)
{
    return transmits(m) || smooth_metal(m->metallic, m->metal_rough_tex >= 0 ? 0.0f : m->roughness);
}

static void photon_trace(const pt_renderer *r, uint32_t pixel_seed, uint32_t index,
                         const pt_render_guiding *gd, const uint32_t features)
{
    const photon_src *src = &r->photon;
    if (index % PHOTON_EVERY)
        return;
    uint32_t seed = pt_hash_combine(pixel_seed, PHOTON_SALT);
    float u[2];
    pt_sample_2d(seed, index, 0, u);
    pt_vec3 dir, rad;
    float pdf;
    if (!pt_env_sample(r->params.env, u, PT_ENV_FULL, pt_v3(0.0f, 0.0f, 0.0f), &dir, &rad, &pdf) ||
        !(pdf > 0.0f))
        return;
    /* (L / p) pi R^2: the flux of N photons, times N. */
    float flux = pt_luminance(rad) / pdf * PT_PI * src->radius * src->radius;
    pt_sample_2d(seed, index, 2, u);
    float rr = src->radius * sqrtf(u[0]), phi = 2.0f * PT_PI * u[1];
    pt_frame df = pt_frame_from_normal(dir);
    pt_vec3 o = pt_v3_add(
        src->c, pt_v3_add(pt_v3_scale(df.t, rr * cosf(phi)), pt_v3_scale(df.b, rr * sinf(phi))));
    o = pt_v3_add(o, pt_v3_scale(dir, src->reach)); /* outside the scene */
    pt_vec3 d = pt_v3_neg(dir);
    for (uint32_t b = 0; b < PHOTON_MAX_BOUNCES; b++) {
        float uc[4];
        pt_sample_2d(seed, index, 4 + 4 * b, uc);
        pt_sample_2d(seed, index, 6 + 4 * b, uc + 2);
        pt_hit hit;
        if (!closest_hit(r, o, d, 0.0f, uc[3], &hit, features))
            return;
        surface sf;
        surface_at(r, &hit, 0.0f, &sf, features);
        /* A first hit that cannot be smooth is direct light: dropped
         * before its closure is built. */
        if (((features & PT_FEAT_UNLIT) && (sf.mat->ext & PT_MATX_UNLIT)) ||
            (b == 0 && ((features & PT_FEAT_INSTANCES) && hit.inst ? !photon_smooth(sf.mat)
                                                                   : !src->smooth[hit.tri])))
            return;
        const int glass = (features & PT_FEAT_TRANSMISSION) && transmits(sf.mat);
        const int through = glass || ((features & PT_FEAT_DIFFUSE_TRANSMISSION) &&
                                      (sf.mat->ext & PT_MATX_DIFFUSE_TRANSMISSION));
        pt_vec3 wo = pt_v3_neg(d);
        int front;
        pt_vec3 ng, ns;
        shading_normals(&sf, wo, through, &front, &ng, &ns, features);
        pt_frame fr = pt_frame_from_normal(ns);
        pt_vec3 wo_l = pt_frame_to_local(&fr, wo);
        pt_closure cl;
        material_closure(r, &sf, glass, front, &fr, wo, wo_l, ng, &cl, features);
        if (!glass && closure_guidable(&cl)) {
            if (b == 0 || through)
                return; /* direct light, or a diffuse transmitter's */
            const pt_camera *cam = &r->camera;
            float cos_t = pt_fmaxf(pt_v3_dot(ns, wo), PHOTON_MIN_COS);
            float scale;
            if (cam->ortho) {
                scale = fabsf(pt_v3_dot(ns, cam->forward)) / src->plane;
            } else {
                pt_vec3 to_cam = pt_v3_sub(cam->position, sf.p);
                float d2 = pt_v3_dot(to_cam, to_cam);
                float dist = sqrtf(d2);
                if (!(dist > 0.0f))
                    return;
                float cos_c = fabsf(pt_v3_dot(ns, to_cam)) / dist;
                float cos_a = pt_fmaxf(-pt_v3_dot(cam->forward, to_cam) / dist, PHOTON_MIN_CAM_COS);
                scale = cos_c / (d2 * src->plane / (cos_a * cos_a * cos_a));
            }
            pt_guide_stats_record(gd->stats, gd->guide, pt_guide_cell(gd->guide, sf.p, ns), wo,
                                  flux * scale / cos_t * (PHOTON_WEIGHT * PHOTON_EVERY));
            return;
        }
        pt_vec3 wi_l;
        float p;
        int delta = 0;
        pt_vec3 w = pt_closure_sample(&cl, uc, &wi_l, &p, &delta);
        if (!(p > 0.0f))
            return;
        pt_vec3 wi = pt_frame_to_world(&fr, wi_l);
        float side = pt_v3_dot(wi, ng);
        if (through ? side == 0.0f || (side > 0.0f) != (wi_l.z > 0.0f) : side <= 0.0f)
            return;
        flux *= pt_luminance(w);
        if (!(flux > 0.0f))
            return;
        o = pt_offset_apply(r->offset, sf.p, side > 0.0f ? ng : pt_v3_neg(ng));
        d = wi;
    }
}

/* A thin-walled transmitter (glass_at's thin: no KHR_materials_volume
 * thickness), which shadow rays may cross where it is smooth. */
static inline int thin_wall(const pt_material *m)
{
    return transmits(m) && !(m->thickness > 0.0f);
}

/* What a shadow ray along d keeps crossing the thin wall it hit at sf: the
 * closure's expected straight-through weight (pt_closure_straight), built
 * as shade() builds it for a path arriving along d (wo = -d; a wall turns
 * its normals to the side the ray comes from and reads no normal map), so
 * the textures at the hit and every layer over the glass count. Zero where
 * the interface is rough (not a delta: it blocks) or the ray grazes it
 * (shade() lets no path cross there either). */
static pt_vec3 wall_transmittance(const pt_renderer *r, const surface *sf, pt_vec3 d,
                                  const uint32_t features)
{
    pt_vec3 wo = pt_v3_neg(d);
    float wng = pt_v3_dot(sf->ng, wo);
    if (wng == 0.0f || !(features & PT_FEAT_GLOSSY))
        return pt_v3(0.0f, 0.0f, 0.0f);
    int front = wng > 0.0f;
    pt_vec3 ng = front ? sf->ng : pt_v3_neg(sf->ng);
    pt_vec3 ns = sf->ns;
    if (pt_v3_dot(ns, ng) < 0.0f)
        ns = pt_v3_neg(ns);
    if (pt_v3_dot(ns, wo) <= 0.0f)
        ns = ng;
    pt_frame fr = pt_frame_from_normal(ns);
    pt_closure cl;
    material_closure(r, sf, 1, front, &fr, wo, pt_frame_to_local(&fr, wo), ng, &cl, features);
    return pt_closure_straight(&cl, NULL);
}

/* The closest hit of a shadow ray's segment, through the MASK/BLEND
 * surfaces it passes with its key (as the occlusion queries below). */
static inline __attribute__((always_inline)) int shadow_hit(const pt_renderer *r, pt_vec3 o,
                                                            pt_vec3 d, float tfar, float time,
                                                            uint32_t key, pt_hit *hit,
                                                            const uint32_t features)
{
    int alpha = (features & PT_FEAT_ALPHA) && r->alpha;
    if ((features & PT_FEAT_MOTION) && r->motion)
        return pt_accel_intersect_time(r->accel, o, d, tfar, time, alpha, alpha ? key : 0, hit);
    if (alpha)
        return pt_accel_intersect_alpha(r->accel, o, d, tfar, key, hit);
    return pt_accel_intersect(r->accel, o, d, tfar, hit);
}

/* A shadow ray in a scene with thin smooth glass (PT_FEAT_THIN_GLASS): the
 * closest hit, segment by segment; a smooth thin wall is a partial
 * transparency along the ray (its straight-through delta lobe), so the ray
 * goes on past it with the wall's transmittance multiplied into *tr, which
 * keeps NEE unbiased: a path that samples the BSDF crosses it with that
 * expected weight. Anything else blocks, and so does a wall past
 * sr->cross_max. Returns 1 when the ray reaches its end. */
static int shadow_through(const pt_renderer *r, path *pa, const shadow_ray *sr,
                          const pt_ray_sink *sink, pt_vec3 *tr, const uint32_t features)
{
    const pt_scene *s = r->scene;
    pt_vec3 o = sr->from, t = pt_v3(1.0f, 1.0f, 1.0f);
    float left = sr->dist;
    for (uint32_t k = 0;; k++) {
        pt_hit hit;
        /* Occlusion excludes the far end, intersection includes it: the
         * end point is offset off the light, so nothing sits there. */
        if (!shadow_hit(r, o, sr->dir, left, pa->time, sr->alpha_key, &hit, features)) {
            *tr = t;
            return 1;
        }
        if (!(hit.t < left)) {
            *tr = t;
            return 1;
        }
        if (!thin_wall(&s->materials[s->tri_material[hit.tri]]))
            return 0;
        if (k >= sr->cross_max) {
            pa->dropped++;
            return 0;
        }
        surface sf;
        surface_at(r, &hit, pa->time, &sf, features);
        t = pt_v3_mul(t, wall_transmittance(r, &sf, sr->dir, features));
        if (!any_positive(t))
            return 0;
        pa->crossings++;
        /* On past the wall, from its far side; the rest of the segment. */
        float wng = pt_v3_dot(sf.ng, sr->dir);
        pt_vec3 np = pt_offset_apply(r->offset, sf.p, wng > 0.0f ? sf.ng : pt_v3_neg(sf.ng));
        if (isfinite(left))
            left = sr->dist - pt_v3_dot(pt_v3_sub(np, sr->from), sr->dir);
        if (!(left > 0.0f)) {
            *tr = t;
            return 1;
        }
        o = np;
        if (sink)
            sink->ray(sink->user, o, sr->dir, left, 0);
    }
}

/* Traces the shadow ray shade() asked for and adds its contribution. MASK
 * and BLEND surfaces on the way block it only where the ray meets them, as
 * a BSDF-sampled ray towards the same light would pass them: BLEND ones by
 * their transmittance 1 - alpha (pt_accel_transmittance_alpha: the
 * expectation of the stochastic pass-through that BSDF-sampled rays take,
 * so MIS weighs the same integrand, with none of its variance), or with
 * motion blur or thin glass stochastically, passing with 1 - alpha. Smooth
 * thin walls (PT_FEAT_THIN_GLASS, shadow_through) pass it with their
 * transmittance. */
static inline __attribute__((always_inline)) void trace_shadow(const pt_renderer *r, path *pa,
                                                               const shadow_ray *sr,
                                                               const pt_ray_sink *sink,
                                                               const uint32_t features)
{
    if (!(sr->dist > 0.0f))
        return;
    if (sink)
        sink->ray(sink->user, sr->from, sr->dir, sr->dist,
                  !((features & PT_FEAT_THIN_GLASS) && r->thin_glass));
    if ((features & PT_FEAT_THIN_GLASS) && r->thin_glass) {
        pt_vec3 tr;
        if (shadow_through(r, pa, sr, sink, &tr, features)) {
            pa->L = pt_v3_add(pa->L, pt_v3_mul(sr->contrib, tr));
            PT_TRACE_EVENT(PT_TRACE_SHADOW, pa->depth, -1, -1, 0, 0.0f, 0.0f, 0.0f,
                           pt_v3_mul(sr->contrib, tr));
        }
        return;
    }
    if ((features & PT_FEAT_ALPHA) && r->blend && !((features & PT_FEAT_MOTION) && r->motion)) {
        float t =
            pt_accel_transmittance_alpha(r->accel, sr->from, sr->dir, sr->dist, sr->alpha_key);
        if (t > 0.0f) {
            pt_vec3 c = pt_v3_scale(sr->contrib, t);
            pa->L = pt_v3_add(pa->L, c);
            PT_TRACE_EVENT(PT_TRACE_SHADOW, pa->depth, -1, -1, 0, 0.0f, 0.0f, 0.0f, c);
        }
        return;
    }
    int blocked;
    if ((features & PT_FEAT_MOTION) && r->motion) {
        int alpha = (features & PT_FEAT_ALPHA) && r->alpha;
        blocked = pt_accel_occluded_time(r->accel, sr->from, sr->dir, sr->dist, pa->time, alpha,
                                         alpha ? sr->alpha_key : 0);
    } else {
        blocked =
            (features & PT_FEAT_ALPHA) && r->alpha
                ? pt_accel_occluded_alpha(r->accel, sr->from, sr->dir, sr->dist, sr->alpha_key)
                : pt_accel_occluded(r->accel, sr->from, sr->dir, sr->dist);
    }
    if (!blocked) {
        pa->L = pt_v3_add(pa->L, sr->contrib);
        PT_TRACE_EVENT(PT_TRACE_SHADOW, pa->depth, -1, -1, 0, 0.0f, 0.0f, 0.0f, sr->contrib);
    }
}

/* Paths in flight in the tile loop, and the most pixels they come from. */
#define BATCH 64u
#define BATCH_PIXELS 16u
_Static_assert(BATCH <= PT_LIGHT_PICKS && BATCH % 8 == 0, "a stage's light picks fit");

/*
 * The Lambert variants' shading (no PT_FEAT_GLOSSY), 8 paths per step in SIMD
 * lanes: everything shade() does after the hit's emission - the light
 * sample's distance, direction and pdf (pt_lights_sample's arithmetic,
 * pt_light_lanes_pdf), the normal flips, the frame (Duff et al. 2017), the
 * Lambert eval, the power heuristic, the shadow ray with its offsets
 * (Waechter & Binder) and contribution, the cosine-sampled continuation,
 * Russian roulette and the next ray - with shade()'s float operations in its
 * order (IEEE arithmetic, no contraction; the square roots and divisions are
 * correctly rounded either way) and its branches as masks: every path gets
 * the same bits as li_impl gives it. A lane that the scalar code would reject
 * early computes on harmlessly (NaNs or infinities, no traps) and is masked.
 *
 * The inputs are a stage's structure of arrays, by position in live[],
 * filled where they are computed (surface_at, the light picks, the cosine
 * sampler), so that only the paths' own state is gathered per lane. Moving
 * one stage alone into lanes measured no faster: the copies into and out of
 * lanes cost what the lanes saved (docs/bench/throughput.md).
 */
typedef struct stage_lanes {
    float p[3][BATCH];       /* hit point */
    float ng[3][BATCH];      /* geometric normal, unflipped */
    float ns[3][BATCH];      /* shading normal */
    float diffuse[3][BATCH]; /* Lambert albedo (material_bsdf) */
    float cos_wi[3][BATCH];  /* pt_sample_cosine_hemisphere of the bounce's numbers */
    float ln[3][BATCH];      /* light_normal: the light picks' receiver normal */
    pt_light_picks lights;   /* when NEE runs */
} stage_lanes;

/* Lanes j0..j0+7 of an array (of floats, or with V8I_LOAD of int32s). */
#define V8_LANES(arr, j0)                                                                          \
    {                                                                                              \
        (arr)[j0], (arr)[(j0) + 1], (arr)[(j0) + 2], (arr)[(j0) + 3], (arr)[(j0) + 4],             \
            (arr)[(j0) + 5], (arr)[(j0) + 6], (arr)[(j0) + 7]                                      \
    }
#define V8_LOAD(arr, j0) ((v8f)V8_LANES(arr, j0))
#define V8I_LOAD(arr, j0) ((v8i)V8_LANES(arr, j0))
#define V8_SPLAT(x) ((v8f){0} + (x))
#define V8_NEG_IF(m, x) ((v8f)((v8i)(x) ^ ((m) & (int32_t)0x80000000)))
#define V8_DOT(ax, ay, az, bx, by, bz) ((ax) * (bx) + (ay) * (by) + (az) * (bz))
/* any_positive, per lane */
#define V8_ANY_POS(x, y, z) (((x) > 0.0f) | ((y) > 0.0f) | ((z) > 0.0f))

/* pt_offset_coord in lanes. */
static inline __attribute__((always_inline)) void offset8(pt_offset off, const v8f *p, const v8f *n,
                                                          v8f *out)
{
    v8f c = V8_SELECT(*n < 1.0f, V8_SELECT(*n > -1.0f, *n, V8_SPLAT(-1.0f)), V8_SPLAT(1.0f));
    v8i of = __builtin_convertvector(PT_OFFSET_INT_SCALE * c, v8i);
    v8u bits = (v8u)*p + (v8u)((-of & (*p < 0.0f)) | (of & ~(*p < 0.0f)));
    v8f near = *p + off.float_scale * *n;
    v8f ap = (v8f)((v8i)*p & 0x7fffffff);
    *out = V8_SELECT(ap < off.origin, near, (v8f)bits);
}

/* Lanes j0..j0+7 of a stage (m < 8: lanes past m repeat the last path and
 * are not written): each path's shadow ray into sr[k] and its next ray, for
 * k = live[j0 + l]; flags[l] gets shade()'s SHADE_ bits. nee: NEE runs
 * (r->nee, and the scene has emitters). Compiled for AVX2 and the baseline. */
PT_SIMD_CLONES
static void shade_lanes(const pt_renderer *r, path *paths, const uint8_t *live, uint32_t j0,
                        uint32_t m, const stage_lanes *sl, const float (*u)[DIM_PER_BOUNCE],
                        int nee, shadow_ray *sr, uint8_t *flags)
{
    path *pp[8];
    const float *ul[8];
    for (uint32_t l = 0; l < 8; l++) {
        uint32_t j = j0 + (l < m ? l : m - 1);
        pp[l] = &paths[live[j]];
        ul[l] = u[j];
    }
#define GATHER(f) {pp[0]->f, pp[1]->f, pp[2]->f, pp[3]->f, pp[4]->f, pp[5]->f, pp[6]->f, pp[7]->f}
    v8f wox = -(v8f)GATHER(d.x), woy = -(v8f)GATHER(d.y), woz = -(v8f)GATHER(d.z);
    v8f btx = GATHER(beta.x), bty = GATHER(beta.y), btz = GATHER(beta.z);
    v8u depth = GATHER(depth);
#undef GATHER
    v8f urr = {ul[0][OFF_RR], ul[1][OFF_RR], ul[2][OFF_RR], ul[3][OFF_RR],
               ul[4][OFF_RR], ul[5][OFF_RR], ul[6][OFF_RR], ul[7][OFF_RR]};
    v8f px = V8_LOAD(sl->p[0], j0), py = V8_LOAD(sl->p[1], j0), pz = V8_LOAD(sl->p[2], j0);
    v8f ngx = V8_LOAD(sl->ng[0], j0), ngy = V8_LOAD(sl->ng[1], j0), ngz = V8_LOAD(sl->ng[2], j0);
    v8f nsx = V8_LOAD(sl->ns[0], j0), nsy = V8_LOAD(sl->ns[1], j0), nsz = V8_LOAD(sl->ns[2], j0);
    v8f dfx = V8_LOAD(sl->diffuse[0], j0), dfy = V8_LOAD(sl->diffuse[1], j0),
        dfz = V8_LOAD(sl->diffuse[2], j0);
    v8i go = (v8i)(depth < (v8u){0} + r->params.max_depth);

    /* shade()'s normal flips: ng towards wo, ns into ng's side, ng when ns
     * faces away from the viewer. */
    v8i flip = V8_DOT(ngx, ngy, ngz, wox, woy, woz) < 0.0f;
    ngx = V8_NEG_IF(flip, ngx);
    ngy = V8_NEG_IF(flip, ngy);
    ngz = V8_NEG_IF(flip, ngz);
    flip = V8_DOT(nsx, nsy, nsz, ngx, ngy, ngz) < 0.0f;
    nsx = V8_NEG_IF(flip, nsx);
    nsy = V8_NEG_IF(flip, nsy);
    nsz = V8_NEG_IF(flip, nsz);
    v8i away = V8_DOT(nsx, nsy, nsz, wox, woy, woz) <= 0.0f;
    nsx = V8_SELECT(away, ngx, nsx);
    nsy = V8_SELECT(away, ngy, nsy);
    nsz = V8_SELECT(away, ngz, nsz);
    /* pt_frame_from_normal(ns) */
    v8f sign = (v8f)(((v8i)nsz & (int32_t)0x80000000) | 0x3f800000); /* copysignf(1, z) */
    v8f fa = -1.0f / (sign + nsz);
    v8f fb = nsx * nsy * fa;
    v8f tx = 1.0f + sign * nsx * nsx * fa, ty = sign * fb, tz = -sign * nsx;
    v8f bx = fb, by = sign + nsy * nsy * fa, bz = -nsy;
    v8f wolz = V8_DOT(wox, woy, woz, nsx, nsy, nsz);
    v8f ox, oy, oz; /* the shadow ray's and the next ray's origin */
    offset8(r->offset, &px, &ngx, &ox);
    offset8(r->offset, &py, &ngy, &oy);
    offset8(r->offset, &pz, &ngz, &oz);

    v8i shadow = {0};
    v8f sdx = {0}, sdy = {0}, sdz = {0}, sdist = {0}, cx = {0}, cy = {0}, cz = {0};
    if (nee) {
        const pt_light_picks *lp = &sl->lights;
        v8f lpx = V8_LOAD(lp->pos[0], j0), lpy = V8_LOAD(lp->pos[1], j0),
            lpz = V8_LOAD(lp->pos[2], j0);
        v8f lnx = V8_LOAD(lp->normal[0], j0), lny = V8_LOAD(lp->normal[1], j0),
            lnz = V8_LOAD(lp->normal[2], j0);
        v8f lrx = V8_LOAD(lp->radiance[0], j0), lry = V8_LOAD(lp->radiance[1], j0),
            lrz = V8_LOAD(lp->radiance[2], j0);
        v8f pmf_area = V8_LOAD(lp->pmf_area, j0);
        v8i two_sided = V8I_LOAD(lp->two_sided, j0);
        /* pt_lights_sample: d = x - p. */
        v8f dx = lpx - px, dy = lpy - py, dz = lpz - pz;
        v8f d2 = V8_DOT(dx, dy, dz, dx, dy, dz), ndot = V8_DOT(lnx, lny, lnz, dx, dy, dz);
        v8f ldist, inv, lpdf;
        v8i lok;
        pt_light_lanes_pdf(&d2, &ndot, &pmf_area, &two_sided, &ldist, &inv, &lpdf, &lok);
        v8f wix = dx * inv, wiy = dy * inv, wiz = dz * inv;
        shadow =
            go & lok & V8_ANY_POS(lrx, lry, lrz) & (V8_DOT(wix, wiy, wiz, ngx, ngy, ngz) > 0.0f);
        /* lambert_eval at the light's direction in the frame. */
        v8f wilz = V8_DOT(wix, wiy, wiz, nsx, nsy, nsz);
        v8f ce = wilz * PT_INV_PI;
        v8f fx = dfx * ce, fy = dfy * ce, fz = dfz * ce;
        shadow &= (wolz > 0.0f) & (wilz > 0.0f) & V8_ANY_POS(fx, fy, fz);
        v8i back = V8_DOT(lnx, lny, lnz, wix, wiy, wiz) > 0.0f;
        lnx = V8_NEG_IF(back, lnx);
        lny = V8_NEG_IF(back, lny);
        lnz = V8_NEG_IF(back, lnz);
        v8f tox, toy, toz;
        offset8(r->offset, &lpx, &lnx, &tox);
        offset8(r->offset, &lpy, &lny, &toy);
        offset8(r->offset, &lpz, &lnz, &toz);
        sdx = tox - ox;
        sdy = toy - oy;
        sdz = toz - oz;
        v8f sd2 = V8_DOT(sdx, sdy, sdz, sdx, sdy, sdz);
        pt_v8_sqrt(&sdist, &sd2);
        v8f sinv = (v8f)((v8i)(1.0f / sdist) & (sdist > 0.0f));
        sdx = sdx * sinv;
        sdy = sdy * sinv;
        sdz = sdz * sinv;
        v8f w = V8_SPLAT(1.0f);
        if (r->params.light_strategy == PT_LIGHT_MIS) {
            /* power_heuristic(lpdf, ce) */
            v8f ha = lpdf * lpdf, hb = ce * ce;
            w = (v8f)((v8i)(ha / (ha + hb)) & (ha + hb > 0.0f));
        }
        w = w / lpdf;
        cx = btx * ((fx * lrx) * w);
        cy = bty * ((fy * lry) * w);
        cz = btz * ((fz * lrz) * w);
    }

    /* lambert_sample with the cosine direction, and the checks after it. */
    v8f cwx = V8_LOAD(sl->cos_wi[0], j0), cwy = V8_LOAD(sl->cos_wi[1], j0),
        cwz = V8_LOAD(sl->cos_wi[2], j0);
    v8f pdf = cwz * PT_INV_PI;
    v8f ipdf = 1.0f / pdf;
    v8f wx = dfx * pdf * ipdf, wy = dfy * pdf * ipdf, wz = dfz * pdf * ipdf;
    v8i cont = go & (wolz > 0.0f) & (cwz > 0.0f) & (pdf > 0.0f) & V8_ANY_POS(wx, wy, wz);
    v8f dx = tx * cwx + bx * cwy + nsx * cwz, dy = ty * cwx + by * cwy + nsy * cwz,
        dz = tz * cwx + bz * cwy + nsz * cwz; /* pt_frame_to_world */
    cont &= V8_DOT(dx, dy, dz, ngx, ngy, ngz) > 0.0f;
    btx = btx * wx;
    bty = bty * wy;
    btz = btz * wz;
    /* Russian roulette: max2(x, max2(y, z)), capped at RR_MAX_SURVIVE. */
    v8f mx = V8_SELECT((bty > btz) | (btz != btz), bty, btz);
    mx = V8_SELECT((btx > mx) | (mx != mx), btx, mx);
    v8f survive = V8_SELECT(mx < RR_MAX_SURVIVE, mx, V8_SPLAT(RR_MAX_SURVIVE));
    v8i roulette = (v8i)(depth + 1u >= (v8u){0} + r->params.rr_depth);
    cont &= ~roulette | (urr < survive);
    v8f isurv = 1.0f / survive;
    btx = V8_SELECT(roulette, btx * isurv, btx);
    bty = V8_SELECT(roulette, bty * isurv, bty);
    btz = V8_SELECT(roulette, btz * isurv, btz);

    /* Written whatever the masks, without branches on them (they are
     * random): a shadow ray is read only under SHADE_SHADOW, and a path that
     * ends is read no more except for its L, which is not written here. */
    for (uint32_t l = 0; l < m; l++) {
        path *pa = pp[l];
        shadow_ray *s = &sr[live[j0 + l]];
        s->from = pt_v3(ox[l], oy[l], oz[l]);
        s->dir = pt_v3(sdx[l], sdy[l], sdz[l]);
        s->dist = sdist[l];
        s->contrib = pt_v3(cx[l], cy[l], cz[l]);
        pa->beta = pt_v3(btx[l], bty[l], btz[l]);
        pa->prev_p = pt_v3(px[l], py[l], pz[l]);
        if (r->recv_normal) /* else nothing reads it */
            pa->prev_n = pt_v3(sl->ln[0][j0 + l], sl->ln[1][j0 + l], sl->ln[2][j0 + l]);
        pa->prev_pdf = pdf[l];
        pa->o = pt_v3(ox[l], oy[l], oz[l]);
        pa->d = pt_v3(dx[l], dy[l], dz[l]);
        pa->depth++;
        flags[l] = (uint8_t)((shadow[l] & SHADE_SHADOW) | (cont[l] & SHADE_CONTINUE));
    }
}

/* One path, start to end: the reference that the batched tile loop below
 * must match bit for bit (tested through pt_render_sample). */
static uint64_t bd_block(const pt_renderer *r, path *paths, uint32_t n, const uint32_t features);

static inline __attribute__((always_inline)) pt_vec3
li_impl(const pt_renderer *r, pixel_ctx *pc, uint32_t index, pt_render_stats *stats, int *covered,
        const pt_render_guiding *gd, pt_pass_sample *ps, const uint32_t features)
{
    path pa;
    path_start(r, pc, index, &pa, features);
    pass_rec pr;
    if ((features & FEAT_PASSES) && ps) {
        memset(&pr, 0, sizeof pr);
        pa.pr = &pr;
    }
    if (features & FEAT_BDPT) {
        uint64_t rays = bd_block(r, &pa, 1, features);
        if (stats)
            stats->rays += rays;
        if (covered)
            *covered = !pa.escaped;
        if ((features & FEAT_PASSES) && ps)
            *ps = pr.v;
        return pa.L;
    }
    guide_path gp;
    if ((features & FEAT_GUIDE) && gd) {
        gp.gd = gd;
        gp.n = gp.rough = gp.pending = 0;
        gp.rr = 1.0f;
        pa.gp = &gp;
    }
    mf_path mf;
    if ((features & PT_FEAT_MANIFOLD) && r->manifold) {
        mf.k = MF_OFF;
        mf.chains = 0;
        mf.mshare = mf.ekeep = pt_v3(1.0f, 1.0f, 1.0f);
        pa.mf = &mf;
    }
    uint64_t rays = 0, capped = 0;
    for (;;) {
        /* The bounce's numbers are drawn before the ray is traced: they do
         * not depend on the hit, and the scrambles' dependency chain then
         * overlaps the ray query. (A missed ray wastes them.) */
        float u[DIM_PER_BOUNCE];
        draw_bounce(pc, pa.depth, index, u);
        pt_hit hit;
        rays++;
        if (!closest_hit(r, pa.o, pa.d, pa.time, u[OFF_ALPHA], &hit, features)) {
            medium_segment(r, &pa, NULL, features);
            shade_miss(r, &pa, features);
            break;
        }
        medium_segment(r, &pa, &hit, features);
        capped += pa.depth >= r->params.max_depth; /* shade() ends it: it may not scatter */
        shadow_ray sr = {{0, 0, 0}, {0, 0, 0}, 0.0f, {0, 0, 0}, 0, 0}; /* set when SHADE_SHADOW */
        surface sf;
        surface_at(r, &hit, pa.time, &sf, features);
        pt_light_sample ls;
        int ls_ok = bounce_light(r, &sf, &pa, u, &ls, features);
        uint32_t st = shade(r, &pa, &hit, u, &sf, &ls, ls_ok, NULL, &sr, features);
        if (st & SHADE_SHADOW) {
            rays++;
            trace_shadow(r, &pa, &sr, NULL, features);
        }
        if (!(st & SHADE_CONTINUE))
            break;
    }
    if (stats) {
        stats->rays += rays + pa.crossings; /* a shadow segment past each wall */
        stats->capped += capped;
        stats->clamped += pa.clamped;
        stats->crossings += pa.crossings;
        stats->dropped += pa.dropped;
        if ((features & PT_FEAT_MANIFOLD) && pa.mf)
            stats->chains += pa.mf->chains;
    }
    if (covered)
        *covered = !pa.escaped;
    if ((features & FEAT_GUIDE) && gd) {
        guide_record(&pa);
        if (gd->stats && gd->guide && r->photon.on)
            photon_trace(r, pc->seed, index, gd, features);
    }
    if ((features & FEAT_PASSES) && ps)
        *ps = pr.v;
    return pa.L;
}

/* The fewest lights for which trace_batch samples a stage's lights in one
 * call (pt_lights_sample_n): about where their entries and alias columns
 * (80 bytes a light) outgrow a 32 KiB level-1 data cache. */
#define LIGHTS_N_MIN 512u

/* bounce_light for the n surfaces of a stage (NEE runs), in one call to
 * pt_lights_sample_n: the same bits. The random reads of many lights' entries
 * and emission textures are then issued close together, and their cache
 * misses overlap. With few lights they hit the cache anyway and trace_batch
 * calls bounce_light per point, which is faster there (the copies and staging
 * cost more than they save). Not inlined, so that it leaves those variants'
 * loop as it was. */
static __attribute__((noinline)) void
lights_stage(const pt_renderer *r, uint32_t n, const surface *sfs, const path *paths,
             const uint8_t *live, const float (*u)[DIM_PER_BOUNCE], pt_light_sample *lss,
             int *ls_ok, const uint32_t features)
{
    pt_vec3 p[BATCH], nrm[BATCH];
    float lu[BATCH][3];
    for (uint32_t j = 0; j < n; j++) {
        p[j] = sfs[j].p;
        nrm[j] = light_normal(r, &sfs[j], pt_v3_neg(paths[live[j]].d), features);
        lu[j][0] = u[j][OFF_LIGHT_PICK];
        lu[j][1] = u[j][OFF_LIGHT_POINT];
        lu[j][2] = u[j][OFF_LIGHT_POINT + 1];
    }
    pt_lights_sample_n(r->lights, r->scene, n, p, nrm, (const float(*)[3])lu, lss, ls_ok);
}

/* What the stage's hits will read (their triangle records, vertices and
 * texels), asked for before any of them is shaded (pt_scene_prefetch_hits),
 * so that their cache misses overlap instead of each stalling its own path;
 * no value changes. */
static inline __attribute__((always_inline)) void prefetch_stage(const pt_renderer *r,
                                                                 const pt_hit *hits,
                                                                 const uint8_t *live, uint32_t nh,
                                                                 const uint32_t features)
{
    if (!(features & PT_FEAT_TEXTURES))
        return;
    uint32_t tri[BATCH];
    float b1[BATCH], b2[BATCH];
    for (uint32_t j = 0; j < nh; j++) {
        const pt_hit *h = &hits[live[j]];
        __builtin_prefetch(&r->tris[h->tri]);
        tri[j] = h->tri;
        b1[j] = h->b1;
        b2[j] = h->b2;
    }
    pt_scene_prefetch_hits(r->scene, nh, tri, b1, b2);
}

/*
 * Traces n paths (all started) to their ends, stage by stage over all live
 * paths: the closest hits, the bounce's numbers (one sampler call, SIMD), the
 * surfaces, the light samples, the shading, the shadow rays. The Lambert
 * variants shade in SIMD lanes, 8 paths a step (shade_lanes), from the cosine
 * directions, surfaces and light picks of the stage written straight into
 * lanes. Each path does exactly what li_impl does, in
 * the same order, so its L is the same bits; but the loops' iterations are
 * independent paths, so the processor overlaps one path's long dependency
 * chains (the square roots and divisions) with its neighbours' instead of
 * waiting on each in turn, and the ray queries run back to back. This is a
 * small wavefront (Laine, Karras & Aila 2013, "Megakernels Considered
 * Harmful") kept on the stack: about 70 KB with tile_impl's, most of it the
 * pixels' sampler seeds. sl holds the Lambert variants' lanes (NULL in the
 * others). Adds to *capped the paths that hit a surface at max_depth (which
 * shade() and shade_lanes end there).
 */
static inline __attribute__((always_inline)) uint64_t
trace_batch(const pt_renderer *r, path *paths, uint32_t n, stage_lanes *sl, const uint32_t features,
            const pt_ray_sink *sink, uint64_t *capped)
{
    uint8_t live[BATCH], shadowed[BATCH];
    float u[BATCH][DIM_PER_BOUNCE]; /* by position in live[] */
    const pt_sample_group *groups[BATCH];
    pt_sample_group deep[BATCH];
    uint32_t index[BATCH];
    uint8_t flags[BATCH];
    surface sfs[BATCH];
    pt_light_sample lss[BATCH];
    int ls_ok[BATCH];
    pt_hit hits[BATCH];
    shadow_ray sr[BATCH];
    uint64_t rays = 0, ncapped = 0;
    for (uint32_t k = 0; k < n; k++)
        live[k] = (uint8_t)k;
    /* With MASK/BLEND surfaces the query needs the bounce's OFF_ALPHA
     * number, so the numbers are drawn before it, for every live path. */
    const int alpha = (features & PT_FEAT_ALPHA) && r->alpha;
    while (n > 0) {
        rays += n;
        uint32_t nh = 0;
        if (alpha) {
            for (uint32_t j = 0; j < n; j++) {
                path *pa = &paths[live[j]];
                groups[j] = bounce_group(pa->pc, pa->depth, &deep[j]);
                index[j] = pa->index;
            }
            pt_sample_group_eval_n(groups, index, n, u);
        }
        for (uint32_t j = 0; j < n; j++) {
            uint32_t k = live[j];
            if (sink)
                sink->ray(sink->user, paths[k].o, paths[k].d, INFINITY, 0);
            if (closest_hit(r, paths[k].o, paths[k].d, paths[k].time,
                            alpha ? u[j][OFF_ALPHA] : 0.0f, &hits[k], features)) {
                medium_segment(r, &paths[k], &hits[k], features);
                if (alpha && nh != j) /* u follows live[]'s compaction */
                    memcpy(u[nh], u[j], sizeof u[nh]);
                live[nh++] = (uint8_t)k;
                ncapped += paths[k].depth >= r->params.max_depth;
            } else {
                medium_segment(r, &paths[k], NULL, features);
                shade_miss(r, &paths[k], features);
            }
        }
        /* The bounce's numbers, for the paths that hit something: a pure
         * function of (pixel, index, depth), so drawing them after the
         * query, and in one call for all, changes no value. */
        if (!alpha) {
            for (uint32_t j = 0; j < nh; j++) {
                path *pa = &paths[live[j]];
                groups[j] = bounce_group(pa->pc, pa->depth, &deep[j]);
                index[j] = pa->index;
            }
            pt_sample_group_eval_n(groups, index, nh, u);
        }
        uint32_t ns = 0, nc = 0;
        if (!(features & PT_FEAT_GLOSSY) && sl) {
            /* Lambert: every bounce that samples its BSDF samples the cosine
             * hemisphere with these numbers, all at once in lanes; the
             * surfaces and light picks go into lanes too, then the shading
             * (shade_lanes). Only the hits' emission stays per path. */
            pt_sample_cosine_hemisphere_n(&u[0][OFF_BSDF_DIR], DIM_PER_BOUNCE, nh, sl->cos_wi[0],
                                          sl->cos_wi[1], sl->cos_wi[2]);
            prefetch_stage(r, hits, live, nh, features);
            for (uint32_t j = 0; j < nh; j++) {
                uint32_t k = live[j];
                surface sf;
                surface_at(r, &hits[k], paths[k].time, &sf, features);
                shade_emission(r, &paths[k], &hits[k], &sf, features);
                pt_bsdf b = material_bsdf(r, &sf, features);
                PT_LANE_PUT3(sl->p, j, sf.p);
                PT_LANE_PUT3(sl->ng, j, sf.ng);
                PT_LANE_PUT3(sl->ns, j, sf.ns);
                PT_LANE_PUT3(sl->diffuse, j, b.diffuse);
                if (r->recv_normal)
                    PT_LANE_PUT3(sl->ln, j, light_normal(r, &sf, pt_v3_neg(paths[k].d), features));
            }
            int nee = (features & PT_FEAT_EMITTERS) && r->nee;
            if (nee) {
                const float *const sp[3] = {sl->p[0], sl->p[1], sl->p[2]};
                const float *const sn[3] = {sl->ln[0], sl->ln[1], sl->ln[2]};
                pt_lights_pick_n(r->lights, r->scene, nh, &u[0][OFF_LIGHT_PICK],
                                 &u[0][OFF_LIGHT_POINT], DIM_PER_BOUNCE, sp, sn, &sl->lights);
            }
            for (uint32_t j0 = 0; j0 < nh; j0 += 8)
                shade_lanes(r, paths, live, j0, nh - j0 < 8 ? nh - j0 : 8, sl,
                            (const float(*)[DIM_PER_BOUNCE])u, nee, sr, &flags[j0]);
            /* Without branches on the flags, which are random: each path is
             * written to both lists and counted where its flag is set. */
            for (uint32_t j = 0; j < nh; j++) {
                uint8_t k = live[j];
                shadowed[ns] = k;
                ns += flags[j] & SHADE_SHADOW;
                live[nc] = k; /* nc <= j: compaction in place */
                nc += (flags[j] & SHADE_CONTINUE) >> 1;
            }
        } else {
            /* Lambert shaded per path (where lanes are slow): the cosine
             * directions still all at once. */
            float cw[3][BATCH];
            if (!(features & PT_FEAT_GLOSSY))
                pt_sample_cosine_hemisphere_n(&u[0][OFF_BSDF_DIR], DIM_PER_BOUNCE, nh, cw[0], cw[1],
                                              cw[2]);
            prefetch_stage(r, hits, live, nh, features);
            for (uint32_t j = 0; j < nh; j++)
                surface_at(r, &hits[live[j]], paths[live[j]].time, &sfs[j], features);
            if ((features & PT_FEAT_EMITTERS) && r->nee_n) {
                lights_stage(r, nh, sfs, paths, live, u, lss, ls_ok, features);
            } else {
                for (uint32_t j = 0; j < nh; j++)
                    ls_ok[j] = bounce_light(r, &sfs[j], &paths[live[j]], u[j], &lss[j], features);
            }
            for (uint32_t j = 0; j < nh; j++) {
                uint32_t k = live[j];
                pt_vec3 c, *cp = NULL;
                if (!(features & PT_FEAT_GLOSSY)) {
                    c = pt_v3(cw[0][j], cw[1][j], cw[2][j]);
                    cp = &c;
                }
                uint32_t st = shade(r, &paths[k], &hits[k], u[j], &sfs[j], &lss[j], ls_ok[j], cp,
                                    &sr[k], features);
                if (st & SHADE_SHADOW)
                    shadowed[ns++] = (uint8_t)k;
                if (st & SHADE_CONTINUE)
                    live[nc++] = (uint8_t)k; /* nc <= j: compaction in place */
            }
        }
        rays += ns;
        for (uint32_t j = 0; j < ns; j++)
            trace_shadow(r, &paths[shadowed[j]], &sr[shadowed[j]], sink, features);
        n = nc;
    }
    *capped += ncapped;
    return rays;
}

/*
 * Bidirectional path tracing (params.bdpt; FEAT_BDPT; Veach 1997, ch. 10;
 * the weights' bookkeeping as in pbrt-v3's BDPT, Pharr et al. 2016, sec.
 * 16.3). Each sample traces a camera path z_1 z_2 ... as the unidirectional
 * variants do (the same numbers) and a light path y_0 y_1 ... from an
 * emissive triangle, a point or spot light or the environment picked by
 * power (r->bd), numbers of dimensions of its own, and joins them at every pair of their vertices.
 * A path z_1 .. z_k (z_k on a light) is then sampled by strategies s = 0 (the camera path finds the
 * light), s = 1 (a light sample, as NEE), and s >= 2 (camera vertex z_{t-1} joined to light vertex
 * z_t, t = k + 1 - s), each weighed by the power heuristic over all of them. Strategies t < 2
 * (light paths joined to the camera itself, "light tracing") are not taken: their light lands on
 * any pixel, and a task renders its own tile's pixels only, so a sample keeps every contribution in
 * its own pixel and the image stays a pure function of (seed, pixel, sample index), whatever the
 * split.
 *
 * What the light path reaches is light that the camera path finds only by
 * chance: the NVIDIA Cornell box's light, trapped in the gap above its
 * lamp and leaving through a slit, or a room lit by a lamp turned to the
 * ceiling, or a room lit by the sky through its opening. Opaque surfaces,
 * emissive triangles, point, spot and directional lights and the
 * environment only (pt_render_check_bdpt): glass keeps the unidirectional
 * variants.
 */
#define BD_VERTS 48u             /* vertices a camera or a light path keeps */
#define DIM_BD_LIGHT 0x40000000u /* the light path's numbers: 8 a vertex from here */

/* A vertex of either path: its surface and closure (built for wo, the
 * direction to the vertex before it on its own path), its throughput up to
 * it (beta), and the area densities of sampling it from its own path's
 * side (pf) and from the other (pr). delta: its closure's sampled lobe was
 * a delta. */
typedef struct bd_vert {
    pt_vec3 p, ng, ngs, wo, beta;
    surface sf;
    pt_frame fr;
    pt_closure cl;
    double pf, pr;
    int delta;
    int inf;    /* the environment at infinity (y_0 or z_k only): p holds the direction to it */
    int dlight; /* a point or spot light (y_0 or z_k only; tri: its index): no strategy
                   finds it by a direction, and its delta marks that for bd_weight */
    uint32_t tri;
    float b1, b2;
} bd_vert;

/* The triangle's area (the renderer's copy of its corners). */
static float bd_tri_area(const pt_renderer *r, uint32_t t)
{
    const tri_rec *tr = &r->tris[t];
    pt_vec3 c = pt_v3_cross(pt_v3_sub(tr->v1, tr->v0), pt_v3_sub(tr->v2, tr->v0));
    return pt_accel_tri_area(c, pt_v3_len(c));
}

/* The emitters' power in r->bd.em.cdf's units: the triangles' and the
 * environment's. */
static inline double bd_tris(const pt_renderer *r)
{
    return pt_emitters_total(&r->bd.em);
}

static inline double bd_total(const pt_renderer *r)
{
    return r->bd.total;
}

/* The probability that a light path starts at punctual entry k of r->bd. */
static inline double bd_punct_share(const pt_renderer *r, uint32_t k)
{
    return (r->bd.pcdf[k] - (k ? r->bd.pcdf[k - 1] : 0.0)) / bd_total(r);
}

/* The probability that a light path starts at the scene's punctual light i. */
static double bd_punct_pick(const pt_renderer *r, uint32_t i)
{
    for (uint32_t k = 0; k < r->bd.np; k++)
        if (r->bd.pidx[k] == i)
            return bd_punct_share(r, k);
    return 0.0;
}

/* The solid-angle density of a light path's first direction d from point or
 * spot light l: uniform over the sphere, or over the spot's outer cone. */
static double bd_punct_dir_pdf(const pt_punctual *l, pt_vec3 d)
{
    if (l->type != PT_PUNCTUAL_SPOT)
        return 1.0 / (4.0 * PT_PI);
    double c = 1.0 - (double)l->cos_outer;
    return c > 0.0 && pt_v3_dot(d, l->direction) >= l->cos_outer ? 1.0 / (2.0 * PT_PI * c) : 0.0;
}

/* The area density with which a light path starts at a point of emitter
 * tri: its pick probability (r->bd.em) over its area; 0 when the light
 * paths never start there. */
static double bd_start_pdf(const pt_renderer *r, uint32_t tri)
{
    const pt_emitters *em = &r->bd.em;
    const uint32_t *t = em->tri;
    uint32_t lo = 0, hi = em->n;
    while (lo < hi) {
        uint32_t mid = lo + (hi - lo) / 2;
        if (t[mid] < tri)
            lo = mid + 1;
        else
            hi = mid;
    }
    if (lo >= em->n || t[lo] != tri)
        return 0.0;
    double w = em->cdf[lo] - (lo ? em->cdf[lo - 1] : 0.0);
    return w / bd_total(r) / bd_tri_area(r, tri);
}

/* The solid-angle density with which a light path starts from the
 * environment in direction w (towards it): its pick probability times the
 * map's whole distribution. */
static double bd_env_start_pdf(const pt_renderer *r, pt_vec3 w)
{
    if (!(r->bd.env_w > 0.0))
        return 0.0;
    return r->bd.env_w / bd_total(r) *
           pt_env_pdf(r->params.env, w, PT_ENV_FULL, pt_v3(0.0f, 0.0f, 0.0f));
}

/* The solid-angle density of the light path's first direction d from
 * emitter tri: cosine-weighted about its normal, on one side or, for a
 * double-sided emitter, either side at one half. */
static double bd_emit_pdf(const pt_renderer *r, uint32_t tri, pt_vec3 d)
{
    const pt_material *m = &r->scene->materials[r->scene->tri_material[tri]];
    float c = pt_v3_dot(r->tris[tri].ng, d);
    if (m->double_sided)
        return 0.5 * fabsf(c) / PT_PI;
    return c > 0.0f ? c / PT_PI : 0.0;
}

/* Solid-angle density pw at `from` as an area density at v; at infinity
 * (the environment) a density stays one of solid angle, as the light
 * sample's and the light path's start there are. */
static inline double bd_area(double pw, pt_vec3 from, const bd_vert *v)
{
    if (v->inf)
        return pw;
    pt_vec3 d = pt_v3_sub(v->p, from);
    double d2 = pt_v3_dot(d, d);
    if (!(d2 > 0.0))
        return 0.0;
    return pw * fabs(pt_v3_dot(v->ng, d)) / (d2 * sqrt(d2));
}

static inline pt_vec3 bd_dir(pt_vec3 from, pt_vec3 to)
{
    return pt_v3_norm(pt_v3_sub(to, from));
}

/* The unit direction from `from` to vertex v, on a surface or at infinity. */
static inline pt_vec3 bd_to(pt_vec3 from, const bd_vert *v)
{
    return v->inf ? v->p : bd_dir(from, v->p);
}

/* The area density at v of a light path from the environment along -w:
 * its start uniform on the disk of radius rad facing w (pbrt-v3's
 * infinite lights, Pharr et al. 2016, sec. 16.1.5), whose parallel rays
 * meet v's surface at |w.ng|. */
static inline double bd_env_area(const pt_renderer *r, const bd_vert *v, pt_vec3 w)
{
    return fabs(pt_v3_dot(v->ng, w)) / (PT_PI * (double)r->bd.rad * (double)r->bd.rad);
}

/* The vertex a ray along d found at hit, its closure built for wo = -d.
 * 0 where bd_supported leaves nothing to build (a transmitter). */
static int bd_vertex(const pt_renderer *r, const pt_hit *hit, pt_vec3 d, float time, bd_vert *v,
                     const uint32_t features)
{
    surface_at(r, hit, time, &v->sf, features);
    if ((features & PT_FEAT_TRANSMISSION) && transmits(v->sf.mat))
        return 0;
    int front;
    pt_vec3 ns;
    v->wo = pt_v3_neg(d);
    shading_normals(&v->sf, v->wo, 0, &front, &v->ngs, &ns, features);
    v->fr = pt_frame_from_normal(ns);
    material_closure(r, &v->sf, 0, front, &v->fr, v->wo, pt_frame_to_local(&v->fr, v->wo), v->ngs,
                     &v->cl, features);
    v->p = v->sf.p;
    v->ng = v->sf.ng;
    v->tri = hit->tri;
    v->b1 = hit->b1;
    v->b2 = hit->b2;
    v->delta = v->inf = v->dlight = 0;
    v->pf = v->pr = 0.0;
    return 1;
}

/* f cos towards d at v (its closure, built for v->wo) and the solid-angle
 * density of sampling d there; 0 below v's surface on wo's side. */
static pt_vec3 bd_fcos(const bd_vert *v, pt_vec3 d, float *pdf)
{
    *pdf = 0.0f;
    if (!(pt_v3_dot(d, v->ngs) > 0.0f))
        return pt_v3(0.0f, 0.0f, 0.0f);
    return pt_closure_eval(&v->cl, pt_frame_to_local(&v->fr, d), pdf);
}

/* The solid-angle density of sampling wout at v when the path came from
 * win (its closure built for win). */
static float bd_pdf(const pt_renderer *r, const bd_vert *v, pt_vec3 win, pt_vec3 wout,
                    const uint32_t features)
{
    int front;
    pt_vec3 ngs, ns;
    shading_normals(&v->sf, win, 0, &front, &ngs, &ns, features);
    if (!(pt_v3_dot(wout, ngs) > 0.0f))
        return 0.0f;
    pt_frame fr = pt_frame_from_normal(ns);
    pt_closure cl;
    material_closure(r, &v->sf, 0, front, &fr, win, pt_frame_to_local(&fr, win), ngs, &cl,
                     features);
    float pdf;
    pt_closure_eval(&cl, pt_frame_to_local(&fr, wout), &pdf);
    return pdf;
}

/* The light path's factor for a shading normal (Veach 1997, sec. 5.3):
 * light carried from wo to wi at v scatters by the adjoint BSDF, which
 * differs from the BSDF by |wo.ns| |wi.ng| / (|wo.ng| |wi.ns|). */
static inline float bd_adjoint(const bd_vert *v, pt_vec3 wo, pt_vec3 wi)
{
    pt_vec3 ns = pt_frame_to_world(&v->fr, pt_v3(0.0f, 0.0f, 1.0f));
    float den = fabsf(pt_v3_dot(wo, v->ng)) * fabsf(pt_v3_dot(wi, ns));
    return den > 0.0f ? fabsf(pt_v3_dot(wo, ns)) * fabsf(pt_v3_dot(wi, v->ng)) / den : 0.0f;
}

static inline double bd_ratio(double a, double b)
{
    return b > 0.0 ? a / b : 1.0; /* a delta's density, 0 on both sides, cancels */
}

/*
 * The power-heuristic weight of strategy s for the path z_1 .. z_k. pc[i]:
 * the area density of z_i sampled from the camera's side (i >= 2); pl[i]:
 * from the light's, pl[k] a light path's start there; pn: a light sample's
 * (s = 1) of z_k from z_{k-1}; delta[i]: z_i scatters by a delta lobe (no
 * strategy joins there), delta[k]: z_k is a point or spot light (no camera
 * path finds it: s = 0 is not a strategy). Strategy s' takes the camera vertices z_0 ..
 * z_{t'-1}, t' = k + 1 - s', and the light's z_{t'} .. z_k; only t' >= 2
 * and what BD_VERTS keeps count. The densities of strategies s' over s's
 * are built one vertex at a time outwards from s (pbrt-v3's MISWeight)
 * along s' = 0, 2, 3, ...; s' = 1 is a branch off 0 or 2, never a step
 * between them: a light sample's density may be 0 where the others' are
 * not (the environment's compensated distribution, env.h, leaves out the
 * directions darker than its mean), and a step through it would lose
 * every strategy past it.
 */
static double bd_weight(uint32_t k, uint32_t s, const double *pc, const double *pl, double pn,
                        const int *delta)
{
#define BD_TAKEN(sp)                                                                               \
    ((sp) <= BD_VERTS && k + 1 - (sp) <= BD_VERTS + 1 &&                                           \
     ((sp) == 0   ? !delta[k]                                                                      \
      : (sp) == 1 ? !delta[k - 1]                                                                  \
                  : !delta[k - (sp)] && !delta[k + 1 - (sp)]))
    double sum = 1.0, q = 1.0, q1;
    /* z_k and z_{k-1} change sides between s' = 0 and 2 */
    const double up2 = bd_ratio(pl[k], pc[k]) * bd_ratio(pl[k - 1], pc[k - 1]);
    const double down2 = bd_ratio(pc[k], pl[k]) * bd_ratio(pc[k - 1], pl[k - 1]);
    uint32_t from = s;
    if (s == 1) { /* onto the chain: 0, then 2 */
        q = bd_ratio(pc[k], pn);
        if (BD_TAKEN(0))
            sum += q * q;
        q1 = bd_ratio(pl[k], pn) * bd_ratio(pl[k - 1], pc[k - 1]);
        if (k + 1 - 2 >= 2 && BD_TAKEN(2))
            sum += q1 * q1;
        q = q1;
        from = 2;
    } else if (s == 0 && k >= 2) {
        q1 = bd_ratio(pn, pc[k]);
        if (BD_TAKEN(1))
            sum += q1 * q1;
    }
    for (uint32_t sp = from + 1; k + 1 - sp >= 2; sp++) { /* z_{t'} moves to the light's side */
        if (sp == 1)
            continue;
        q *= sp == 2 ? up2 : bd_ratio(pl[k + 1 - sp], pc[k + 1 - sp]);
        if (BD_TAKEN(sp))
            sum += q * q;
    }
    q = 1.0;
    for (uint32_t sp = s == 1 ? 0 : s; sp-- > 0;) { /* z_{t'-1} moves to the camera's side */
        if (sp == 1) {
            q1 = q * bd_ratio(pc[k - 1], pl[k - 1]) * bd_ratio(pn, pl[k]);
            if (BD_TAKEN(1))
                sum += q1 * q1;
            continue;
        }
        q *= sp == 0 ? down2 : bd_ratio(pc[k - sp], pl[k - sp]);
        if (BD_TAKEN(sp))
            sum += q * q;
    }
#undef BD_TAKEN
    return 1.0 / sum;
}

/* The area density of a sampled from b when the path came to b from c
 * (a, b, c consecutive on one path): a's pr once c is known. 0 after a
 * delta at b. */
static double bd_back(const pt_renderer *r, const bd_vert *a, const bd_vert *b, const bd_vert *c,
                      const uint32_t features)
{
    if (b->delta || a->dlight)
        return 0.0;
    return bd_area(bd_pdf(r, b, bd_to(b->p, c), bd_to(b->p, a), features), b->p, a);
}

/* Russian roulette with survival min(m, RR_MAX_SURVIVE) by number u: 0
 * when the path ends, else *beta scaled up by the survival. */
static inline int bd_roulette(pt_vec3 *beta, float m, float u)
{
    float survive = m < RR_MAX_SURVIVE ? m : RR_MAX_SURVIVE;
    if (!(u < survive))
        return 0;
    *beta = pt_v3_scale(*beta, 1.0f / survive);
    return 1;
}

/* The next direction at v by its closure (numbers u, as a bounce's), its
 * weight f cos / p and density, and whether its lobe is a delta; 0 when the
 * path ends there (no lobe, or a direction below v's surface). */
static int bd_scatter(const bd_vert *v, const float u[DIM_PER_BOUNCE], pt_vec3 *wi, pt_vec3 *w,
                      float *p, int *delta)
{
    const float uc[3] = {u[OFF_LIGHT_PICK + 1], u[OFF_BSDF_DIR], u[OFF_BSDF_DIR + 1]};
    pt_vec3 wi_l;
    *delta = 0;
    *w = pt_closure_sample(&v->cl, uc, &wi_l, p, delta);
    if (!(*p > 0.0f) || !any_positive(*w))
        return 0;
    *wi = pt_frame_to_world(&v->fr, wi_l);
    return pt_v3_dot(*wi, v->ngs) > 0.0f;
}

/* A sample's two paths and the densities of the path being weighed. */
typedef struct bd_scratch {
    bd_vert cam[BD_VERTS + 1]; /* cam[1 ..]: z_1 ..; cam[0] holds the camera's point */
    bd_vert lig[BD_VERTS];     /* lig[0]: y_0, on the light */
    double pc[2 * BD_VERTS + 3], pl[2 * BD_VERTS + 3];
    int delta[2 * BD_VERTS + 3];
    double pn_far; /* bd_light_pdf towards y_2 (a light path of 3 vertices or more) */
} bd_scratch;

/* A light sample's area density of the light path's start y_0 from y_1,
 * y_1 receiving towards `next` (the vertex after it on the whole path): the
 * density of strategy s = 1 for every path that ends y_1 y_0. */
static double bd_light_pdf(const pt_renderer *r, const bd_scratch *bs, pt_vec3 next,
                           const uint32_t features)
{
    const bd_vert *y0 = &bs->lig[0], *y1 = &bs->lig[1];
    pt_vec3 n = light_normal(r, &y1->sf, bd_dir(y1->p, next), features);
    if (y0->dlight) /* a point, spot or directional light */
        return pt_lights_punctual_pmf(r->lights, y0->tri, y1->p, n);
    if (y0->inf)
        return pt_lights_env_pdf(r->lights, y0->p, y1->p, n);
    return bd_area(pt_lights_pdf(r->lights, r->scene, y0->tri, y1->p, n, y0->p, y0->ng), y1->p, y0);
}

/* A light path's start y0 on an emitter triangle picked by x (in [0, the
 * triangles' power)): a point uniform on it (Turk 1990) by u[1..2], a
 * direction by the cosine about the side it emits to by u[3..4]. Its ray
 * (*o, *dir), throughput and the direction's solid-angle density *pw; 0
 * when it carries nothing. */
static int bd_start_tri(const pt_renderer *r, const float u[DIM_PER_BOUNCE], double x, bd_vert *y0,
                        pt_vec3 *o, pt_vec3 *dir, pt_vec3 *beta, double *pw,
                        const uint32_t features)
{
    const pt_scene *s = r->scene;
    uint32_t tri = r->bd.em.tri[pt_emitters_pick(&r->bd.em, x)];
    const tri_rec *tr = &r->tris[tri];
    float b1, b2;
    pt_vec3 n;
    *dir = pt_emitter_start(tr->ng, s->materials[s->tri_material[tri]].double_sided, &u[1], &b1,
                            &b2, &n);
    y0->p = pt_v3_add(pt_v3_add(pt_v3_scale(tr->v0, 1.0f - b1 - b2), pt_v3_scale(tr->v1, b1)),
                      pt_v3_scale(tr->v2, b2));
    y0->ng = tr->ng;
    y0->tri = tri;
    y0->b1 = b1;
    y0->b2 = b2;
    y0->pf = bd_start_pdf(r, tri);
    *pw = bd_emit_pdf(r, tri, *dir);
    pt_vec3 le = pt_emitted(s, tri, b1, b2, *dir);
    if ((features & PT_FEAT_ALPHA) && r->alpha && pt_alpha_tri(s, tri))
        le = pt_v3_scale(le, pt_alpha_coverage(s, tri, b1, b2));
    if (!(*pw > 0.0) || !(y0->pf > 0.0) || !any_positive(le))
        return 0;
    *beta = pt_v3_scale(le, (float)(fabsf(pt_v3_dot(tr->ng, *dir)) / (y0->pf * *pw)));
    *o = pt_offset_apply(r->offset, y0->p, n);
    return 1;
}

/* A point uniform on the disk of the scene's bounding sphere that faces
 * direction w (towards the light), by the cosine sample's disk coordinates
 * of (u3, u4): where a light path from the environment or a directional
 * light starts, along -w (pbrt-v3's infinite lights, Pharr et al. 2016,
 * sec. 16.1.5). */
static pt_vec3 bd_disk_origin(const pt_renderer *r, pt_vec3 w, float u3, float u4)
{
    const float R = r->bd.rad;
    pt_vec3 dk = pt_sample_cosine_hemisphere(u3, u4);
    pt_frame f = pt_frame_from_normal(w);
    return pt_v3_add(pt_v3_add(r->bd.c, pt_v3_scale(w, R)),
                     pt_v3_add(pt_v3_scale(f.t, dk.x * R), pt_v3_scale(f.b, dk.y * R)));
}

/* A light path's start y0 at the scene's point or spot light i (picked with
 * probability pick): a direction uniform over the sphere or the spot's
 * outer cone by u[3..4], its density in *pw. As bd_start_tri. A
 * directional light: its direction, from a point uniform on the disk of
 * the scene's bounding sphere that faces the light (as bd_start_env); y0
 * lies at infinity towards the light, and the next vertex's density is
 * the disk's (bd_env_area). */
static int bd_start_punct(const pt_renderer *r, const float u[DIM_PER_BOUNCE], uint32_t i,
                          double pick, bd_vert *y0, pt_vec3 *o, pt_vec3 *dir, pt_vec3 *beta,
                          double *pw)
{
    const pt_punctual *l = &r->scene->punctual[i];
    if (l->type == PT_PUNCTUAL_DIRECTIONAL) {
        if (!(pick > 0.0) || !any_positive(l->intensity))
            return 0;
        const float R = r->bd.rad;
        pt_vec3 w = pt_v3_neg(l->direction);
        *o = bd_disk_origin(r, w, u[3], u[4]);
        *dir = l->direction;
        *pw = 1.0; /* not read: the next vertex's density is the disk's */
        y0->p = w;
        y0->ng = *dir;
        y0->inf = y0->dlight = y0->delta = 1;
        y0->tri = i;
        y0->b1 = y0->b2 = 0.0f;
        y0->pf = pick;
        *beta = pt_v3_scale(l->intensity, (float)(PT_PI * (double)R * (double)R / pick));
        return 1;
    }
    const float cmin = l->type == PT_PUNCTUAL_SPOT ? l->cos_outer : -1.0f;
    float z = 1.0f - u[3] * (1.0f - cmin), sz = sqrtf(fmaxf(0.0f, 1.0f - z * z));
    float phi = 2.0f * (float)PT_PI * u[4];
    pt_frame f =
        pt_frame_from_normal(l->type == PT_PUNCTUAL_SPOT ? l->direction : pt_v3(0.0f, 0.0f, 1.0f));
    *dir = pt_frame_to_world(&f, pt_v3(sz * cosf(phi), sz * sinf(phi), z));
    *pw = bd_punct_dir_pdf(l, *dir);
    /* at distance 0: the range's window, 1 there, is taken at the first
     * vertex (bd_light_path) */
    pt_vec3 in = pt_punctual_intensity(l, pt_v3_neg(*dir), 0.0f);
    if (!(*pw > 0.0) || !(pick > 0.0) || !any_positive(in))
        return 0;
    y0->p = l->position;
    y0->ng = *dir;
    y0->tri = i;
    y0->dlight = y0->delta = 1;
    y0->b1 = y0->b2 = 0.0f;
    y0->pf = pick;
    *beta = pt_v3_scale(in, (float)(1.0 / (pick * *pw)));
    *o = l->position;
    return 1;
}

/* A light path's start y0 on the environment: a direction w of the map by
 * its whole distribution (u[1..2]), a point uniform on the disk of the
 * scene's bounding sphere that faces w (u[3..4], by the cosine sample's
 * disk coordinates), the ray from there along -w. As bd_start_tri. */
static int bd_start_env(const pt_renderer *r, const float u[DIM_PER_BOUNCE], bd_vert *y0,
                        pt_vec3 *o, pt_vec3 *dir, pt_vec3 *beta)
{
    pt_vec3 w, le;
    float pd;
    const float uw[2] = {u[1], u[2]};
    if (!pt_env_sample(r->params.env, uw, PT_ENV_FULL, pt_v3(0.0f, 0.0f, 0.0f), &w, &le, &pd) ||
        !(pd > 0.0f) || !any_positive(le))
        return 0;
    const float R = r->bd.rad;
    *o = bd_disk_origin(r, w, u[3], u[4]);
    *dir = pt_v3_neg(w);
    y0->p = w;
    y0->ng = *dir;
    y0->inf = 1;
    y0->tri = UINT32_MAX;
    y0->b1 = y0->b2 = 0.0f;
    y0->pf = r->bd.env_w / bd_total(r) * pd;
    *beta = pt_v3_scale(le, (float)(PT_PI * (double)R * (double)R / y0->pf));
    return 1;
}

/* The light path of pa's sample into bs->lig; returns its vertex count
 * (0: none) and adds its rays to *rays. Its start: an emitter triangle or
 * the environment, by their power (r->bd). */
static uint32_t bd_light_path(const pt_renderer *r, const path *pa, bd_scratch *bs, uint64_t *rays,
                              const uint32_t features)
{
    const pixel_ctx *pc = pa->pc;
    float u[DIM_PER_BOUNCE];
    pt_sample_group g;
    pt_sample_group_init(&g, pc->seed, DIM_BD_LIGHT);
    pt_sample_group_eval(&g, pa->index, u);
    bd_vert *y0 = &bs->lig[0];
    y0->delta = y0->inf = y0->dlight = 0;
    y0->pr = 0.0;
    pt_vec3 o, dir, beta;
    double pw = 0.0;
    const double total = bd_total(r), x = u[0] * total, tris = bd_tris(r);
    if (r->bd.np && x >= tris && (x - tris < r->bd.pcdf[r->bd.np - 1] || !(r->bd.env_w > 0.0))) {
        uint32_t k = 0;
        while (k + 1 < r->bd.np && !(r->bd.pcdf[k] > x - tris))
            k++;
        if (!bd_start_punct(r, u, r->bd.pidx[k], bd_punct_share(r, k), y0, &o, &dir, &beta, &pw))
            return 0;
    } else if (r->bd.env_w > 0.0 && !(x < tris)) {
        if (!bd_start_env(r, u, y0, &o, &dir, &beta))
            return 0;
    } else if (!bd_start_tri(r, u, x, y0, &o, &dir, &beta, &pw, features)) {
        return 0;
    }
    float ua = u[5];
    int prev_delta = 0;
    uint32_t nl = 1;
    while (nl < BD_VERTS) {
        pt_hit hit;
        (*rays)++;
        if (!closest_hit(r, o, dir, pa->time, ua, &hit, features))
            break;
        bd_vert *y = &bs->lig[nl];
        if (!bd_vertex(r, &hit, dir, pa->time, y, features))
            break;
        if (nl == 1 && y0->dlight && !y0->inf) {
            /* a point or spot light's range: its window at the distance
             * the light travelled (the ray starts at the light) */
            const float win = pt_punctual_range_window(&r->scene->punctual[y0->tri], hit.t);
            if (!(win > 0.0f))
                break;
            beta = pt_v3_scale(beta, win);
        }
        y->beta = beta;
        y->pf = prev_delta           ? 0.0
                : y0->inf && nl == 1 ? bd_env_area(r, y, y0->p)
                                     : bd_area(pw, bs->lig[nl - 1].p, y);
        nl++;
        if (nl >= 3) /* y_{nl-3} from y_{nl-2}, the path coming from y_{nl-1} */
            bs->lig[nl - 3].pr = bd_back(r, &bs->lig[nl - 3], &bs->lig[nl - 2], y, features);
        if (nl >= BD_VERTS || nl > r->params.max_depth)
            break;
        pt_sample_group_init(&g, pc->seed, DIM_BD_LIGHT + DIM_PER_BOUNCE * nl);
        pt_sample_group_eval(&g, pa->index, u);
        pt_vec3 wi, w;
        float p;
        int delta;
        if (!bd_scatter(y, u, &wi, &w, &p, &delta))
            break;
        y->delta = delta;
        beta = pt_v3_scale(pt_v3_mul(beta, w), bd_adjoint(y, y->wo, wi));
        /* Roulette by the throughput over the first vertex's. */
        if (nl >= r->params.rr_depth &&
            !bd_roulette(&beta,
                         pt_luminance(beta) / pt_fmaxf(pt_luminance(bs->lig[1].beta), 1e-30f),
                         u[OFF_RR]))
            break;
        pw = delta ? 0.0 : p;
        prev_delta = delta;
        ua = u[OFF_ALPHA];
        o = pt_offset_apply(r->offset, y->p, y->ngs);
        dir = wi;
    }
    return nl;
}

/* What the shadow ray from camera vertex x to point `to` (offset off the
 * far surface by nto; far 2: a point light's, no surface there), or along
 * direction `to` to the environment (far 1),
 * lets through: 0 blocked, 1 clear, between for BLEND surfaces (as
 * trace_shadow weighs them). Counts its ray in *rays. Traced before a
 * join's densities are worked out, so that a blocked one costs none. */
static float bd_visible(const pt_renderer *r, const path *pa, const bd_vert *x, pt_vec3 to,
                        pt_vec3 nto, int far, uint32_t alpha_key, uint64_t *rays,
                        const uint32_t features)
{
    pt_vec3 from = pt_offset_apply(r->offset, x->p, x->ngs), dir;
    float dist;
    if (far == 1) {
        dir = to;
        dist = INFINITY;
    } else {
        pt_vec3 sd = pt_v3_sub(far == 2 ? to : pt_offset_apply(r->offset, to, nto), from);
        dist = pt_v3_len(sd);
        if (!(dist > 0.0f))
            return 0.0f;
        dir = pt_v3_scale(sd, 1.0f / dist);
    }
    (*rays)++;
    if ((features & PT_FEAT_ALPHA) && r->blend && !((features & PT_FEAT_MOTION) && r->motion))
        return pt_accel_transmittance_alpha(r->accel, from, dir, dist, alpha_key);
    int blocked;
    if ((features & PT_FEAT_MOTION) && r->motion) {
        int alpha = (features & PT_FEAT_ALPHA) && r->alpha;
        blocked = pt_accel_occluded_time(r->accel, from, dir, dist, pa->time, alpha,
                                         alpha ? alpha_key : 0);
    } else {
        blocked = (features & PT_FEAT_ALPHA) && r->alpha
                      ? pt_accel_occluded_alpha(r->accel, from, dir, dist, alpha_key)
                      : pt_accel_occluded(r->accel, from, dir, dist);
    }
    return blocked ? 0.0f : 1.0f;
}

/* The camera densities of z_1 .. z_t1 into pc/pl/delta (the ones every
 * strategy's path with this camera prefix shares). */
static void bd_camera_part(bd_scratch *bs, uint32_t t1)
{
    for (uint32_t i = 1; i <= t1; i++) {
        bs->pc[i] = bs->cam[i].pf;
        bs->pl[i] = bs->cam[i].pr;
        bs->delta[i] = bs->cam[i].delta;
    }
    bs->delta[t1] = 0;
}

/* s = 1 at camera vertex x = z_t1 (throughput beta, its bounce's numbers
 * u): a light sample, as the unidirectional variants take it (an emitter
 * triangle's point, or a direction of the map), weighed against the other
 * strategies, into pa->L. */
static void bd_nee(const pt_renderer *r, path *pa, bd_scratch *bs, const bd_vert *x, uint32_t t1,
                   pt_vec3 beta, const float u[DIM_PER_BOUNCE], uint64_t *rays,
                   const uint32_t features)
{
    const pt_scene *s = r->scene;
    const float u3[3] = {u[OFF_LIGHT_PICK], u[OFF_LIGHT_POINT], u[OFF_LIGHT_POINT + 1]};
    pt_light_sample ls;
    float bp;
    pt_vec3 f;
    if (pt_lights_sample(r->lights, s, x->p, light_normal(r, &x->sf, x->wo, features), u3, &ls) &&
        ls.pdf > 0.0f &&
        (ls.delta == PT_LIGHT_AREA || ((features & PT_FEAT_ENV) && ls.delta == PT_LIGHT_ENV) ||
         ((features & PT_FEAT_PUNCTUAL) &&
          (ls.delta == PT_LIGHT_AT || ls.delta == PT_LIGHT_FAR))) &&
        any_positive(ls.radiance) && any_positive(f = bd_fcos(x, ls.wi, &bp))) {
        const uint32_t k = t1 + 1;
        /* far: at infinity (the map, a directional light); at: a delta light */
        const int dirl = ls.delta == PT_LIGHT_FAR;
        const int far = ls.delta == PT_LIGHT_ENV || dirl, at = ls.delta == PT_LIGHT_AT || dirl;
        pt_vec3 lrad = ls.radiance;
        if (ls.delta == PT_LIGHT_AREA && (features & PT_FEAT_ALPHA) && r->alpha &&
            pt_alpha_tri(s, ls.tri) && !(r->alpha_solid && r->alpha_solid[ls.tri]))
            lrad = pt_v3_scale(lrad, light_coverage(r, &ls));
        bd_vert yl;
        yl.inf = far;
        yl.dlight = at;
        yl.p = far ? ls.wi : ls.position;
        yl.ng = far || at ? pt_v3_neg(ls.wi) : ls.normal;
        pt_vec3 nto = pt_v3_dot(yl.ng, ls.wi) > 0.0f ? pt_v3_neg(yl.ng) : yl.ng;
        const float vis = bd_visible(
            r, pa, x, yl.p, nto,
            far  ? 1
            : at ? 2
                 : 0,
            (features & PT_FEAT_ALPHA) ? pt_alpha_key(u[OFF_ALPHA], ALPHA_SALT_SHADOW) : 0u, rays,
            features);
        if (!(vis > 0.0f))
            return;
        bs->delta[k] = at;
        bs->pc[k] = at ? 0.0 : bd_area(bp, x->p, &yl);
        if (at) {
            uint32_t i = (uint32_t)(ls.punct - s->punctual);
            bs->pl[k] = bd_punct_pick(r, i);
            bs->pl[k - 1] = dirl ? bd_env_area(r, x, ls.wi)
                                 : bd_area(bd_punct_dir_pdf(ls.punct, pt_v3_neg(ls.wi)), yl.p, x);
        } else if (far) {
            bs->pl[k] = bd_env_start_pdf(r, ls.wi);
            bs->pl[k - 1] = bd_env_area(r, x, ls.wi);
        } else {
            bs->pl[k] = bd_start_pdf(r, ls.tri);
            bs->pl[k - 1] = bd_area(bd_emit_pdf(r, ls.tri, pt_v3_neg(ls.wi)), yl.p, x);
        }
        if (t1 >= 2)
            bs->pl[t1 - 1] = bd_area(bd_pdf(r, x, ls.wi, bd_dir(x->p, bs->cam[t1 - 1].p), features),
                                     x->p, &bs->cam[t1 - 1]);
        double w =
            bd_weight(k, 1, bs->pc, bs->pl, at ? ls.pdf : bd_area(ls.pdf, x->p, &yl), bs->delta);
        pt_vec3 c = pt_v3_scale(pt_v3_mul(beta, pt_v3_mul(f, lrad)), (float)(w / ls.pdf));
        pa->L = pt_v3_add(pa->L, pt_v3_scale(c, vis));
    }
}

/* s = 0 for a camera path z_1 .. z_{t1-1} whose ray pa->d (sampled at
 * z_{t1-1} with solid-angle density pw, 0 after a delta) left the scene:
 * the environment's light along it, weighed against the strategies that
 * take the path z_1 .. z_{t1-1} z_t1 with z_t1 at infinity. */
static void bd_escape(const pt_renderer *r, path *pa, bd_scratch *bs, uint32_t t1, pt_vec3 beta,
                      double pw, const uint32_t features)
{
    pt_vec3 le = pt_env_eval(r->params.env, pa->d);
    if (!any_positive(le))
        return;
    double w = 1.0;
    if (t1 >= 2) {
        const uint32_t k = t1;
        bd_vert *xp = &bs->cam[k - 1];
        bd_vert e;
        e.inf = 1;
        e.dlight = 0;
        e.p = pa->d;
        if (k >= 3) /* z_{k-2} from z_{k-1}, the path coming from the environment */
            bs->cam[k - 2].pr = bd_back(r, &bs->cam[k - 2], xp, &e, features);
        bd_camera_part(bs, k - 1);
        bs->delta[k - 1] = xp->delta;
        bs->delta[k] = 0;
        bs->pc[k] = pw;
        bs->pl[k] = bd_env_start_pdf(r, pa->d);
        bs->pl[k - 1] = bd_env_area(r, xp, pa->d);
        float lp =
            pt_lights_env_pdf(r->lights, pa->d, xp->p, light_normal(r, &xp->sf, xp->wo, features));
        w = bd_weight(k, 0, bs->pc, bs->pl, lp, bs->delta);
    }
    pa->L = pt_v3_add(pa->L, pt_v3_scale(pt_v3_mul(beta, le), (float)w));
}

/* The render passes at the camera path's vertex x = z_t1 (FEAT_PASSES), as
 * shade() records them: the camera ray's hit, and the first vertex whose
 * closure is not all specular (the albedo through the specular ones before
 * it, beta their throughput), short of the last bounce. */
static void bd_passes(const pt_renderer *r, pass_rec *pr, const pt_hit *hit, const bd_vert *x,
                      uint32_t t1, pt_vec3 beta, const uint32_t features)
{
    if (t1 == 1)
        pass_first_hit(r, pr, hit, &x->sf, features);
    pt_vec3 alb = pt_v3(0.0f, 0.0f, 0.0f);
    if (!pr->found && t1 <= r->params.max_depth && pt_closure_albedo(&x->cl, &alb)) {
        pr->found = 1;
        pr->v.albedo = pt_v3_mul(beta, alb);
        pr->v.normal = x->fr.n;
    }
}

/* The sample of pa (started by path_start) by bidirectional path tracing,
 * into pa->L; adds its rays to *rays. */
static void bd_sample(const pt_renderer *r, path *pa, bd_scratch *bs, uint64_t *rays,
                      const uint32_t features)
{
    const pt_scene *s = r->scene;
    const uint32_t max_k = r->params.max_depth + 1u; /* z_1 .. z_k: k - 1 bounces */
    uint32_t nl =
        r->bd.em.n || r->bd.np || r->bd.env_w > 0.0 ? bd_light_path(r, pa, bs, rays, features) : 0;
    if (nl >= 3)
        bs->pn_far = bd_light_pdf(r, bs, bs->lig[2].p, features);
    pt_vec3 beta = pt_v3(1.0f, 1.0f, 1.0f);
    double pw = 0.0;
    int prev_delta = 0;
    bs->cam[0].p = pa->o;
    for (uint32_t t1 = 1; t1 <= BD_VERTS; t1++) {
        float u[DIM_PER_BOUNCE];
        draw_bounce(pa->pc, t1 - 1, pa->index, u);
        pt_hit hit;
        (*rays)++;
        if (!closest_hit(r, pa->o, pa->d, pa->time, u[OFF_ALPHA], &hit, features)) {
            if (t1 == 1)
                pa->escaped = 1;
            if ((features & PT_FEAT_ENV) && r->params.env && !(t1 == 1 && r->params.transparent))
                bd_escape(r, pa, bs, t1, beta, pw, features);
            break;
        }
        bd_vert *x = &bs->cam[t1];
        if (!bd_vertex(r, &hit, pa->d, pa->time, x, features))
            break;
        if ((features & FEAT_PASSES) && pa->pr)
            bd_passes(r, pa->pr, &hit, x, t1, beta, features);
        x->beta = beta;
        x->pf = t1 >= 2 && !prev_delta ? bd_area(pw, bs->cam[t1 - 1].p, x) : 0.0;
        if (t1 >= 3)
            bs->cam[t1 - 2].pr = bd_back(r, &bs->cam[t1 - 2], &bs->cam[t1 - 1], x, features);
        /* The densities of z_1 .. z_t1 that every strategy below shares
         * (z_{t1-2}'s from the light's side is its pr, just set); each
         * strategy writes those of its own join (pl[t1 - 1], pl[t1], ...). */
        bd_camera_part(bs, t1);
        /* s = 0: the camera path found a light. */
        if ((features & PT_FEAT_EMITTERS) && emits(x->sf.mat) && t1 <= max_k) {
            pt_vec3 le = pt_emitted(s, x->tri, x->b1, x->b2, x->wo);
            if ((features & FEAT_PASSES) && pa->pr && t1 == 1)
                pa->pr->v.emission = le;
            if (any_positive(le)) {
                double w = 1.0;
                if (t1 >= 2) {
                    const uint32_t k = t1;
                    const bd_vert *xp = &bs->cam[k - 1];
                    bs->pl[k] = bd_start_pdf(r, x->tri);
                    bs->pl[k - 1] = bd_area(bd_emit_pdf(r, x->tri, bd_dir(x->p, xp->p)), x->p, xp);
                    float lp =
                        pt_lights_pdf(r->lights, s, x->tri, xp->p,
                                      light_normal(r, &xp->sf, xp->wo, features), x->p, x->ng);
                    w = bd_weight(k, 0, bs->pc, bs->pl, bd_area(lp, xp->p, x), bs->delta);
                }
                pa->L = pt_v3_add(pa->L, pt_v3_scale(pt_v3_mul(beta, le), (float)w));
            }
        }
        if (t1 >= max_k)
            break;
        /* s = 1: a light sample (NEE). */
        if (r->nee)
            bd_nee(r, pa, bs, x, t1, beta, u, rays, features);
        /* s >= 2: x joined to each light vertex y_j past the light. */
        for (uint32_t j = 1; j < nl && t1 + j + 1 <= max_k; j++) {
            const bd_vert *y = &bs->lig[j];
            pt_vec3 d = pt_v3_sub(y->p, x->p);
            float d2 = pt_v3_dot(d, d);
            if (!(d2 > 0.0f))
                continue;
            pt_vec3 dn = pt_v3_scale(d, 1.0f / sqrtf(d2));
            float px, py;
            pt_vec3 fx = bd_fcos(x, dn, &px), fy;
            if (!any_positive(fx) || !any_positive(fy = bd_fcos(y, pt_v3_neg(dn), &py)))
                continue;
            uint32_t key = (features & PT_FEAT_ALPHA) ? pt_alpha_key(u[OFF_ALPHA], 2u + j) : 0u;
            const float vis = bd_visible(r, pa, x, y->p, y->ngs, 0, key, rays, features);
            if (!(vis > 0.0f))
                continue;
            /* the path z_1 .. z_t1 (camera), z_{t1+1} = y_j .. z_k = y_0 */
            const uint32_t k = t1 + j + 1;
            for (uint32_t jj = 0; jj <= j; jj++) {
                bs->pl[k - jj] = bs->lig[jj].pf;
                bs->pc[k - jj] = bs->lig[jj].pr;
                bs->delta[k - jj] = bs->lig[jj].delta;
            }
            bs->delta[t1 + 1] = 0;
            bs->pc[t1 + 1] = bd_area(px, x->p, y);
            bs->pl[t1] = bd_area(py, y->p, x);
            bs->pc[t1 + 2] =
                bs->lig[j - 1].dlight
                    ? 0.0
                    : bd_area(bd_pdf(r, y, pt_v3_neg(dn), bd_to(y->p, &bs->lig[j - 1]), features),
                              y->p, &bs->lig[j - 1]);
            if (t1 >= 2)
                bs->pl[t1 - 1] =
                    bd_area(bd_pdf(r, x, dn, bd_dir(x->p, bs->cam[t1 - 1].p), features), x->p,
                            &bs->cam[t1 - 1]);
            double w =
                bd_weight(k, j + 1, bs->pc, bs->pl,
                          j >= 2 ? bs->pn_far : bd_light_pdf(r, bs, x->p, features), bs->delta);
            pt_vec3 c = pt_v3_mul(pt_v3_mul(beta, fx), pt_v3_mul(fy, y->beta));
            c = pt_v3_scale(c, (float)(w / d2) * bd_adjoint(y, y->wo, pt_v3_neg(dn)));
            pa->L = pt_v3_add(pa->L, pt_v3_scale(c, vis));
        }
        /* On: the BSDF's direction, roulette as the unidirectional variants. */
        pt_vec3 wi, w;
        float p;
        int delta;
        if (!bd_scatter(x, u, &wi, &w, &p, &delta))
            break;
        x->delta = delta;
        beta = pt_v3_mul(beta, w);
        if (t1 >= r->params.rr_depth &&
            !bd_roulette(&beta, max2(beta.x, max2(beta.y, beta.z)), u[OFF_RR]))
            break;
        pw = delta ? 0.0 : p;
        prev_delta = delta;
        pa->o = pt_offset_apply(r->offset, x->p, x->ngs);
        pa->d = wi;
        pa->depth = t1;
    }
}

/* bd_sample for paths[0 .. n) (started by path_start), one by one, on a
 * scratch of its own; returns their rays. */
static __attribute__((noinline)) uint64_t bd_block(const pt_renderer *r, path *paths, uint32_t n,
                                                   const uint32_t features)
{
    bd_scratch bs;
    uint64_t rays = 0;
    for (uint32_t k = 0; k < n; k++)
        bd_sample(r, &paths[k], &bs, &rays, features);
    return rays;
}

/*
 * Samples [s0, s1) of a tile's pixels. Pixels are taken in row-major groups
 * and, per aligned block of PT_SAMPLE_BLOCK samples, the block's samples of
 * the whole group are traced together (trace_batch); then each pixel sums its
 * block's results in sample order and adds the block sum (in fixed point):
 * the same additions as one pixel and one sample at a time.
 */
static inline __attribute__((always_inline)) void
tile_impl(const pt_renderer *r, pt_rect tile, uint32_t s0, uint32_t s1, pt_pixel_acc *out,
          pt_pass_acc *pout, pt_render_stats *stats, stage_lanes *sl, const uint32_t features,
          const pt_ray_sink *sink, const pt_render_guiding *gd)
{
    guide_path gps[BATCH]; /* FEAT_GUIDE only: folded away in the other variants */
    pass_rec prs[BATCH];   /* FEAT_PASSES only */
    mf_path mfs[BATCH];    /* PT_FEAT_MANIFOLD only */
    pt_render_stats local = {0};
    uint32_t tw = tile.x1 - tile.x0, npix = tw * (tile.y1 - tile.y0);
    uint32_t span = s1 > s0 ? s1 - s0 : 1;
    uint32_t group = BATCH / (span < PT_SAMPLE_BLOCK ? span : PT_SAMPLE_BLOCK);
    if (group > BATCH_PIXELS)
        group = BATCH_PIXELS;
    pixel_ctx pcs[BATCH_PIXELS];
    path paths[BATCH];
    for (uint32_t p0 = 0; p0 < npix; p0 += group) {
        uint32_t np = npix - p0 < group ? npix - p0 : group;
        for (uint32_t g = 0; g < np; g++) {
            memset(&out[p0 + g], 0, sizeof out[p0 + g]);
            if ((features & FEAT_PASSES) && pout)
                memset(&pout[p0 + g], 0, sizeof pout[p0 + g]);
            pixel_ctx_init(&pcs[g], r, tile.x0 + (p0 + g) % tw, tile.y0 + (p0 + g) / tw);
        }
        /* Sum each aligned block of PT_SAMPLE_BLOCK samples on its own in
         * double, round it to fixed point and add it exactly: the result for
         * [s0,s1) is then the same bits as adding the results of any split at
         * block boundaries, whatever the parts' sizes. */
        for (uint32_t b0 = s0; b0 < s1;) {
            uint32_t b1 = (b0 / PT_SAMPLE_BLOCK + 1) * PT_SAMPLE_BLOCK;
            if (b1 > s1 || b1 < b0)
                b1 = s1;
            uint32_t nb = b1 - b0;
            for (uint32_t g = 0; g < np; g++)
                for (uint32_t i = 0; i < nb; i++) {
                    path *pa = &paths[g * nb + i];
                    path_start(r, &pcs[g], b0 + i, pa, features);
                    if ((features & FEAT_GUIDE) && gd) {
                        guide_path *gp = &gps[g * nb + i];
                        gp->gd = gd;
                        gp->n = gp->rough = gp->pending = 0;
                        gp->rr = 1.0f;
                        pa->gp = gp;
                    }
                    if ((features & FEAT_PASSES) && pout) {
                        memset(&prs[g * nb + i], 0, sizeof prs[0]);
                        pa->pr = &prs[g * nb + i];
                    }
                    if ((features & PT_FEAT_MANIFOLD) && r->manifold) {
                        mfs[g * nb + i].k = MF_OFF;
                        mfs[g * nb + i].chains = 0;
                        mfs[g * nb + i].mshare = mfs[g * nb + i].ekeep = pt_v3(1.0f, 1.0f, 1.0f);
                        pa->mf = &mfs[g * nb + i];
                    }
                }
            if (features & FEAT_BDPT)
                local.rays += bd_block(r, paths, np * nb, features);
            else
                local.rays += trace_batch(r, paths, np * nb, sl, features, sink, &local.capped);
            if ((features & FEAT_GUIDE) && gd) {
                for (uint32_t k = 0; k < np * nb; k++)
                    guide_record(&paths[k]);
                if (gd->stats && gd->guide && r->photon.on)
                    for (uint32_t k = 0; k < np * nb; k++)
                        photon_trace(r, pcs[k / nb].seed, b0 + k % nb, gd, features);
            }
            for (uint32_t g = 0; g < np; g++) {
                pt_block_acc blk = {{0, 0, 0}, 0, 0, 0};
                pt_pass_block pb;
                if ((features & FEAT_PASSES) && pout)
                    memset(&pb, 0, sizeof pb);
                for (uint32_t i = 0; i < nb; i++) {
                    const path *pa = &paths[g * nb + i];
                    if (!pt_block_acc_sample(&blk, pa->L)) {
                        local.rejected++;
                    } else {
                        blk.hits += !pa->escaped;
                        if ((features & FEAT_PASSES) && pout)
                            pt_pass_block_sample(&pb, &prs[g * nb + i].v, pa->L, pa->index);
                    }
                    if (features & FEAT_CLAMP)
                        local.clamped += pa->clamped;
                    if (features & PT_FEAT_THIN_GLASS) {
                        local.rays += pa->crossings; /* a segment past each wall */
                        local.crossings += pa->crossings;
                        local.dropped += pa->dropped;
                    }
                    if ((features & PT_FEAT_MANIFOLD) && pa->mf)
                        local.chains += pa->mf->chains;
                }
                pt_pixel_acc_add_block(&out[p0 + g], &blk);
                if ((features & FEAT_PASSES) && pout)
                    pt_pass_acc_add_block(&pout[p0 + g], &pb);
                local.samples += blk.n;
            }
            b0 = b1;
        }
    }
    if (stats) {
        stats->samples += local.samples;
        stats->rejected += local.rejected;
        stats->rays += local.rays;
        stats->capped += local.capped;
        stats->clamped += local.clamped;
        stats->crossings += local.crossings;
        stats->dropped += local.dropped;
        stats->chains += local.chains;
    }
}

#define ALL_FEATURES (0xffffffffu & ~FEAT_BDPT)
#define VARIANT(li_name, tile_name, feat)                                                          \
    static pt_vec3 li_name(const pt_renderer *r, pixel_ctx *pc, uint32_t index,                    \
                           pt_render_stats *stats, int *covered, const pt_render_guiding *gd,      \
                           pt_pass_sample *ps)                                                     \
    {                                                                                              \
        return li_impl(r, pc, index, stats, covered, gd, ps, (feat));                              \
    }                                                                                              \
    static void tile_name(const pt_renderer *r, pt_rect tile, uint32_t s0, uint32_t s1,            \
                          pt_pixel_acc *out, pt_pass_acc *pout, pt_render_stats *stats,            \
                          const pt_render_guiding *gd)                                             \
    {                                                                                              \
        if (((feat)&PT_FEAT_GLOSSY) || !r->lanes) {                                                \
            tile_impl(r, tile, s0, s1, out, pout, stats, NULL, (feat), NULL, gd);                  \
        } else {                                                                                   \
            /* Lanes past a stage's paths compute on zeros or an earlier                           \
             * stage's values, not on what the stack held (which could be                          \
             * slow denormals). */                                                                 \
            stage_lanes sl;                                                                        \
            memset(&sl, 0, sizeof sl);                                                             \
            tile_impl(r, tile, s0, s1, out, pout, stats, &sl, (feat), NULL, gd);                   \
        }                                                                                          \
    }
#define NO_TEX (uint32_t)(PT_FEAT_TEXTURES | PT_FEAT_EMISSIVE_TEX)
/* Lights besides emissive triangles: only the general variant has their code. */
#define OTHER_LIGHTS (uint32_t)(PT_FEAT_PUNCTUAL | PT_FEAT_ENV)
/* Glass and media: likewise only in the general variant. */
#define GLASS                                                                                      \
    (uint32_t)(PT_FEAT_TRANSMISSION | PT_FEAT_VOLUME | PT_FEAT_THIN_GLASS | PT_FEAT_MANIFOLD)
/* The material features beyond the core's (normal maps, vertex colours). */
#define SURFACE_EXTRAS (uint32_t)(PT_FEAT_NORMAL_MAP | PT_FEAT_VERTEX_COLOR)
/* The glTF material extensions past the core's: unlit, specular-glossiness,
 * specular textures, iridescence, anisotropy, diffuse transmission,
 * dispersion. */
#define MATERIAL_EXTS                                                                              \
    (uint32_t)(PT_FEAT_UNLIT | BSDF_EXTS | PT_FEAT_IRIDESCENCE | PT_FEAT_ANISOTROPY |              \
               PT_FEAT_DIFFUSE_TRANSMISSION | PT_FEAT_DISPERSION)
/* Features that only the general variant has code for. */
/* Motion blur (PT_FEAT_MOTION) too: a path's time reaches every ray query. */
/* Instancing (PT_FEAT_INSTANCES) too: a hit's instance transform. */
#define GENERAL_ONLY                                                                               \
    (uint32_t)(OTHER_LIGHTS | PT_FEAT_ALPHA | GLASS | SURFACE_EXTRAS | LAYERS | PT_FEAT_MOTION |   \
               MATERIAL_EXTS | PT_FEAT_INSTANCES)
VARIANT(li_bdpt, tile_bdpt, (ALL_FEATURES & ~PARAM_FEATURES) | FEAT_BDPT)
VARIANT(li_bdpt_passes, tile_bdpt_passes, (ALL_FEATURES & ~FEAT_GUIDE & ~FEAT_CLAMP) | FEAT_BDPT)
VARIANT(li_guided_passes, tile_guided_passes, ALL_FEATURES)
VARIANT(li_passes, tile_passes, ALL_FEATURES & ~FEAT_GUIDE)
VARIANT(li_guided, tile_guided, ALL_FEATURES & ~FEAT_PASSES)
VARIANT(li_clamped, tile_clamped, ALL_FEATURES & ~FEAT_GUIDE & ~FEAT_PASSES)
VARIANT(li_general, tile_general, ALL_FEATURES & ~PARAM_FEATURES)
VARIANT(li_untextured, tile_untextured, ALL_FEATURES & ~NO_TEX & ~GENERAL_ONLY & ~PARAM_FEATURES)
VARIANT(li_lambert, tile_lambert,
        ALL_FEATURES & ~(uint32_t)PT_FEAT_GLOSSY & ~GENERAL_ONLY & ~PARAM_FEATURES)
VARIANT(li_lambert_untextured, tile_lambert_untextured,
        ALL_FEATURES & ~NO_TEX & ~(uint32_t)PT_FEAT_GLOSSY & ~GENERAL_ONLY & ~PARAM_FEATURES)
#undef VARIANT

/* The most specialised variant whose assumptions the scene meets. */
static void pick_variant(pt_renderer *r, uint32_t features)
{
    int tex = (features & NO_TEX) != 0, glossy = (features & PT_FEAT_GLOSSY) != 0;
    if ((features & FEAT_BDPT) && (features & FEAT_PASSES)) {
        /* bdpt that also records the passes: its beauty is li_bdpt's bits */
        r->li = li_bdpt_passes;
        r->tile = tile_bdpt_passes;
        r->variant = "bdpt-passes";
    } else if (features & FEAT_BDPT) {
        r->li = li_bdpt;
        r->tile = tile_bdpt;
        r->variant = "bdpt";
    } else if ((features & FEAT_PASSES) && (features & FEAT_GUIDE)) {
        r->li = li_guided_passes;
        r->tile = tile_guided_passes;
        r->variant = "guided-passes";
    } else if (features & FEAT_PASSES) {
        /* The general variant that also records the passes: its beauty is
         * the same bits as any variant's. */
        r->li = li_passes;
        r->tile = tile_passes;
        r->variant = "passes";
    } else if (features & FEAT_GUIDE) {
        r->li = li_guided;
        r->tile = tile_guided;
        r->variant = "guided";
    } else if (features & FEAT_CLAMP) {
        r->li = li_clamped;
        r->tile = tile_clamped;
        r->variant = "clamped";
    } else if (features & GENERAL_ONLY) {
        r->li = li_general;
        r->tile = tile_general;
        r->variant = "general";
    } else if (glossy) {
        r->li = tex ? li_general : li_untextured;
        r->tile = tex ? tile_general : tile_untextured;
        r->variant = tex ? "general" : "untextured";
    } else {
        r->li = tex ? li_lambert : li_lambert_untextured;
        r->tile = tex ? tile_lambert : tile_lambert_untextured;
        r->variant = tex ? "lambert" : "lambert-untextured";
    }
}

/* 1 when flat triangle i may pass light on without spreading it: its
 * material may (photon_smooth), and where a metallic-roughness texture
 * decides, the texel at its centre says a smooth metal (ToyCar's chrome is
 * a few triangles of a material whose other texels are paint and rubber). */
static int photon_tri_smooth(const pt_renderer *r, uint32_t i, const uint32_t features)
{
    const pt_material *m = &r->scene->materials[r->tris[i].mat & ~TRI_FLAT];
    if (!photon_smooth(m))
        return 0;
    if (transmits(m) || m->metal_rough_tex < 0 || !(features & PT_FEAT_TEXTURES))
        return 1;
    pt_hit hit = {0.0f, 1.0f / 3.0f, 1.0f / 3.0f, i, 0};
    surface sf;
    surface_at(r, &hit, 0.0f, &sf, features);
    pt_vec3 base;
    float metallic, roughness;
    base_inputs(r->scene, &sf, features, &base, &metallic, &roughness);
    return smooth_metal(metallic, roughness);
}

/* r->photon for a guided render lit by an environment: on when the scene's
 * own (not instanced) triangles include smooth ones, the sphere around
 * them, the scene's reach beyond it and the camera's image plane. */
static void photon_setup(pt_renderer *r, const uint32_t features)
{
    const pt_scene *s = r->scene;
    uint32_t flat = s->num_prototypes ? s->prototypes[0].first_tri : s->num_triangles;
    photon_src *src = &r->photon;
    src->smooth = pt_malloc_array(flat ? flat : 1, sizeof *src->smooth);
    if (!src->smooth)
        return; /* no photons: the guide learns from the camera alone */
    pt_vec3 lo = pt_v3(INFINITY, INFINITY, INFINITY), hi = pt_v3(-INFINITY, -INFINITY, -INFINITY);
    for (uint32_t i = 0; i < flat; i++) {
        const tri_rec *t = &r->tris[i];
        src->smooth[i] = (uint8_t)photon_tri_smooth(r, i, features);
        if (!src->smooth[i])
            continue;
        const pt_vec3 v[3] = {t->v0, t->v1, t->v2};
        for (int k = 0; k < 3; k++) {
            lo = pt_v3(fminf(lo.x, v[k].x), fminf(lo.y, v[k].y), fminf(lo.z, v[k].z));
            hi = pt_v3(fmaxf(hi.x, v[k].x), fmaxf(hi.y, v[k].y), fmaxf(hi.z, v[k].z));
        }
    }
    if (!(lo.x <= hi.x))
        return;
    src->c = pt_v3_scale(pt_v3_add(lo, hi), 0.5f);
    src->radius = 0.5f * pt_v3_len(pt_v3_sub(hi, lo)) * 1.001f + 1e-6f;
    pt_vec3 sc = pt_v3_scale(pt_v3_add(s->bounds_min, s->bounds_max), 0.5f);
    src->reach = pt_v3_len(pt_v3_sub(src->c, sc)) +
                 0.5f * pt_v3_len(pt_v3_sub(s->bounds_max, s->bounds_min)) + src->radius;
    const pt_camera *cam = &r->camera;
    float aspect = (float)r->params.width / (float)r->params.height;
    src->plane = cam->ortho ? 4.0f * cam->xmag * cam->ymag
                            : 4.0f * r->tan_half_fov * r->tan_half_fov * aspect;
    src->on = isfinite(src->radius) && isfinite(src->reach) && src->plane > 0.0f;
}

/* 1 when some material is a thin wall (thin_wall) that may be smooth where
 * shading reads it (a roughness factor below glass_at's smooth threshold, a
 * metallic-roughness texture that may lower it, specular-glossiness, or an
 * ior of 1, which pt_glass_setup treats as smooth): PT_FEAT_THIN_GLASS. */
static int scene_thin_glass(const pt_scene *s)
{
    for (uint32_t i = 0; i < s->num_materials; i++) {
        const pt_material *m = &s->materials[i];
        if (thin_wall(m) &&
            (m->roughness * m->roughness < PT_GLASS_SMOOTH_ALPHA || m->metal_rough_tex >= 0 ||
             (m->ext & PT_MATX_SPEC_GLOSS) || m->ior == 1.0f))
            return 1;
    }
    return 0;
}

/* 1 when the scene has a punctual light (directional, point or spot),
 * which manifold NEE connects through thick glass as it does the
 * environment. */
static int scene_punctual(const pt_scene *s)
{
    return s->num_punctual > 0;
}

/* 1 when some material is glass a manifold chain may refract at
 * (mf_caster): PT_FEAT_MANIFOLD. */
static int scene_manifold(const pt_scene *s)
{
    for (uint32_t i = 0; i < s->num_materials; i++)
        if (mf_caster(&s->materials[i]))
            return 1;
    return 0;
}

/* 1 when some material is smooth and opaque (mr_smooth): the
 * environment's lamps chain off it (mr_env_nee). */
static int scene_smooth(const pt_scene *s)
{
    for (uint32_t i = 0; i < s->num_materials; i++)
        if (mr_smooth(&s->materials[i]))
            return 1;
    return 0;
}

/* 1 when some material is one a reflection chain may reflect at
 * (mr_caster). */
static int scene_mirror(const pt_scene *s)
{
    for (uint32_t i = 0; i < s->num_materials; i++)
        if (mr_caster(&s->materials[i]))
            return 1;
    return 0;
}

/* mr_hulls' tree of an object's corners p[0 .. n): node i holds the box
 * (lo xyz, hi xyz) of p[a .. b), its children 2i + 1 and 2i + 2 the halves
 * at (a + b) / 2 after a selection along its longest side. */
#define HULL_LEAF 8u
typedef struct hull_tree {
    pt_vec3 *p;
    float (*box)[6];
} hull_tree;

static inline float v3_at(pt_vec3 v, int k)
{
    return k == 0 ? v.x : k == 1 ? v.y : v.z;
}

/* Reorders p[0 .. n) so that p[m] is the one of rank m by component k,
 * none after it smaller and none before it larger (Hoare's selection). */
static void hull_select(pt_vec3 *p, int64_t n, int64_t m, int k)
{
    int64_t lo = 0, hi = n - 1;
    while (lo < hi) {
        float piv = v3_at(p[(lo + hi) / 2], k);
        int64_t i = lo, j = hi;
        while (i <= j) {
            while (v3_at(p[i], k) < piv)
                i++;
            while (v3_at(p[j], k) > piv)
                j--;
            if (i <= j) {
                pt_vec3 t = p[i];
                p[i++] = p[j];
                p[j--] = t;
            }
        }
        if (m <= j)
            hi = j;
        else if (m >= i)
            lo = i;
        else
            return;
    }
}

/* qsort's order of points: by x, then y, then z. */
static int v3_order(const void *pa, const void *pb)
{
    const pt_vec3 *a = pa, *b = pb;
    for (int k = 0; k < 3; k++) {
        float x = v3_at(*a, k), y = v3_at(*b, k);
        if (x != y)
            return x < y ? -1 : 1;
    }
    return 0;
}

static void hull_build(hull_tree *t, uint32_t node, uint32_t a, uint32_t b)
{
    float *bx = t->box[node];
    bx[0] = bx[1] = bx[2] = INFINITY;
    bx[3] = bx[4] = bx[5] = -INFINITY;
    for (uint32_t i = a; i < b; i++)
        for (int k = 0; k < 3; k++) {
            bx[k] = fminf(bx[k], v3_at(t->p[i], k));
            bx[3 + k] = fmaxf(bx[3 + k], v3_at(t->p[i], k));
        }
    if (b - a <= HULL_LEAF)
        return;
    int k = 0;
    for (int j = 1; j < 3; j++)
        if (bx[3 + j] - bx[j] > bx[3 + k] - bx[k])
            k = j;
    uint32_t mid = a + (b - a) / 2;
    hull_select(t->p + a, b - a, mid - a, k);
    hull_build(t, 2 * node + 1, a, mid);
    hull_build(t, 2 * node + 2, mid, b);
}

/* 1 when a corner p of node's p[a .. b) has n . p > thr. */
static int hull_beyond(const hull_tree *t, uint32_t node, uint32_t a, uint32_t b, pt_vec3 n,
                       float thr)
{
    const float *bx = t->box[node];
    float m = fmaxf(n.x * bx[0], n.x * bx[3]) + fmaxf(n.y * bx[1], n.y * bx[4]) +
              fmaxf(n.z * bx[2], n.z * bx[5]);
    if (!(m > thr))
        return 0;
    if (b - a <= HULL_LEAF) {
        for (uint32_t i = a; i < b; i++)
            if (pt_v3_dot(n, t->p[i]) > thr)
                return 1;
        return 0;
    }
    uint32_t mid = a + (b - a) / 2;
    return hull_beyond(t, 2 * node + 1, a, mid, n, thr) ||
           hull_beyond(t, 2 * node + 2, mid, b, n, thr);
}

/* The objects whose n smooth reflecting triangles (r->mr_tris) lie on
 * their convex hull: each one's plane has every corner of the others on
 * one side, within 1e-4 of the object's radius (on neither: a flat
 * mirror; a degenerate triangle, which no ray meets, has no side), a
 * tree of the corners' boxes sparing the corners far behind the plane;
 * MR_HULL, and the outward side in r->mr_side. */
static pt_status mr_hulls(pt_renderer *r, uint32_t n)
{
    const pt_scene *s = r->scene;
    uint32_t nt = s->num_instances > 0 ? s->num_flat_triangles : s->num_triangles;
    uint32_t *start = pt_calloc(r->mr_n + 1u, sizeof *start);
    uint32_t *at = pt_calloc(r->mr_n, sizeof *at);
    uint32_t *tri = pt_malloc_array(n ? n : 1, sizeof *tri);
    r->mr_side = pt_calloc(nt ? nt : 1, sizeof *r->mr_side);
    if (!start || !at || !tri || !r->mr_side) {
        pt_free(start);
        pt_free(at);
        pt_free(tri);
        return PT_ERR_NOMEM;
    }
    /* each object's smooth triangles, by a counting sort */
    for (uint32_t i = 0; i < n; i++)
        if (!mr_glass(&s->materials[s->tri_material[r->mr_tris[i]] & ~TRI_FLAT]))
            start[r->mr_of_object[mr_object_of(r, r->mr_tris[i])] + 1u]++;
    for (uint32_t k = 0; k < r->mr_n; k++)
        start[k + 1] += start[k];
    for (uint32_t i = 0; i < n; i++) {
        uint32_t t = r->mr_tris[i];
        if (mr_glass(&s->materials[s->tri_material[t] & ~TRI_FLAT]))
            continue;
        uint32_t k = r->mr_of_object[mr_object_of(r, t)];
        tri[start[k] + at[k]++] = t;
    }
    pt_free(at);
    pt_status st = PT_OK;
    for (uint32_t k = 0; k < r->mr_n && st == PT_OK; k++) {
        uint32_t a = start[k], b = start[k + 1], nc = 3u * (b - a);
        if (b == a || b - a > MR_HULL_TRIS)
            continue;
        hull_tree ht = {pt_malloc_array(nc, sizeof *ht.p),
                        pt_malloc_array(4u * (nc / HULL_LEAF + 1u), sizeof *ht.box)};
        if (!ht.p || !ht.box) {
            st = PT_ERR_NOMEM;
        } else {
            for (uint32_t i = a; i < b; i++) {
                const tri_rec *t = &r->tris[tri[i]];
                ht.p[3 * (i - a)] = t->v0;
                ht.p[3 * (i - a) + 1] = t->v1;
                ht.p[3 * (i - a) + 2] = t->v2;
            }
            /* each corner once: a closed mesh shares one among six triangles */
            qsort(ht.p, nc, sizeof *ht.p, v3_order);
            uint32_t u = 0;
            for (uint32_t i = 0; i < nc; i++)
                if (u == 0 || v3_order(&ht.p[u - 1], &ht.p[i]) != 0)
                    ht.p[u++] = ht.p[i];
            nc = u;
            hull_build(&ht, 0, 0, nc);
            const float eps = 2e-2f * r->mr[k].rad;
            int hull = 1;
            for (uint32_t i = a; i < b && hull; i++) {
                const tri_rec *t = &r->tris[tri[i]];
                /* a degenerate triangle (a UV sphere's pole) has no plane */
                pt_vec3 cr = pt_v3_cross(pt_v3_sub(t->v1, t->v0), pt_v3_sub(t->v2, t->v0));
                if (!(pt_v3_len(cr) > eps * eps))
                    continue;
                float d0 = pt_v3_dot(t->ng, t->v0);
                int pos = hull_beyond(&ht, 0, 0, nc, t->ng, d0 + eps);
                int neg = hull_beyond(&ht, 0, 0, nc, pt_v3_neg(t->ng), eps - d0);
                hull = !(pos && neg);
                r->mr_side[tri[i]] = (int8_t)(neg - pos);
            }
            if (hull)
                r->mr[k].kinds |= MR_HULL;
        }
        pt_free(ht.p);
        pt_free(ht.box);
    }
    pt_free(start);
    pt_free(tri);
    return st;
}

/* The reflection chains' objects (r->mr: each one's still, flat reflecting
 * triangles, their bounding sphere) and their triangles' BVH (r->mr_accel);
 * r->mirror when one of them can chain a light (below). */
static pt_status mr_new(pt_renderer *r, pt_error *err)
{
    const pt_scene *s = r->scene;
    /* Smooth opaque surfaces mirror the lights mr_smooth_light takes, in a scene
     * without MASK or BLEND surfaces: a path passes their cutouts, a
     * chain's ray does not, so their NEE would give way where no
     * chain was offered. */
    int smooth_lights = 0;
    for (uint32_t i = 0; i < s->num_punctual && !r->alpha; i++) {
        const pt_punctual *l = &s->punctual[i];
        if (l->type == PT_PUNCTUAL_DIRECTIONAL)
            smooth_lights = 1;
        else if (!r->light_tree && !(l->range > 0.0f))
            smooth_lights = r->smooth_at = 1;
    }
    /* ... and the environment's lamps (mr_env_nee) */
    const int smooth_env = !r->alpha && r->params.env && pt_lights_has_env(r->lights);
    smooth_lights |= smooth_env;
    uint32_t nt = s->num_instances > 0 ? s->num_flat_triangles : s->num_triangles, n = 0;
    uint32_t nobj = s->tri_object && s->num_objects > 0 ? s->num_objects : 1u;
    r->mr_tris = pt_malloc_array(nt ? nt : 1, sizeof *r->mr_tris);
    r->mr = pt_calloc(MR_MAX, sizeof *r->mr);
    r->mr_of_object = pt_malloc_array(nobj, sizeof *r->mr_of_object);
    float(*box)[6] = pt_malloc_array(MR_MAX, sizeof *box);
    if (!r->mr_tris || !r->mr || !r->mr_of_object || !box) {
        pt_free(box);
        return pt_error_set(err, PT_ERR_NOMEM, "manifold NEE: out of memory");
    }
    for (uint32_t i = 0; i < nobj; i++)
        r->mr_of_object[i] = MR_NONE;
    for (uint32_t i = 0; i < nt; i++) {
        const pt_material *m = &s->materials[s->tri_material[i] & ~TRI_FLAT];
        const int glass = mr_glass(m);
        if (!glass && !(smooth_lights && mr_smooth(m)))
            continue;
        uint32_t obj = mr_object_of(r, i);
        uint32_t k = r->mr_of_object[obj];
        if (k == MR_NONE) {
            if (r->mr_n == MR_MAX)
                continue;
            k = r->mr_of_object[obj] = r->mr_n++;
            r->mr[k].object = obj;
            for (int j = 0; j < 3; j++) {
                box[k][j] = INFINITY;
                box[k][3 + j] = -INFINITY;
            }
        }
        r->mr[k].kinds |= glass ? MR_GLASS : MR_SMOOTH;
        r->mirror_smooth |= !glass;
        r->mirror_env |= !glass && smooth_env;
        r->mr_tris[n++] = i;
        const tri_rec *t = &r->tris[i];
        const pt_vec3 *v[3] = {&t->v0, &t->v1, &t->v2};
        for (int c = 0; c < 3; c++)
            for (int j = 0; j < 3; j++) {
                float x = j == 0 ? v[c]->x : j == 1 ? v[c]->y : v[c]->z;
                box[k][j] = fminf(box[k][j], x);
                box[k][3 + j] = fmaxf(box[k][3 + j], x);
            }
    }
    for (uint32_t k = 0; k < r->mr_n; k++)
        r->mr[k].c = pt_v3(0.5f * (box[k][0] + box[k][3]), 0.5f * (box[k][1] + box[k][4]),
                           0.5f * (box[k][2] + box[k][5]));
    /* The radius: the farthest vertex from the centre. */
    for (uint32_t i = 0; i < n; i++) {
        const tri_rec *t = &r->tris[r->mr_tris[i]];
        mr_object *o = &r->mr[r->mr_of_object[mr_object_of(r, r->mr_tris[i])]];
        o->rad = fmaxf(o->rad, fmaxf(pt_v3_len(pt_v3_sub(t->v0, o->c)),
                                     fmaxf(pt_v3_len(pt_v3_sub(t->v1, o->c)),
                                           pt_v3_len(pt_v3_sub(t->v2, o->c)))));
    }
    pt_free(box);
    if (r->mirror_smooth && mr_hulls(r, n) != PT_OK)
        return pt_error_set(err, PT_ERR_NOMEM, "manifold NEE: out of memory");
    /* A smooth object's chains start only where it is MR_HULL (mr_pick),
     * glass's only from a punctual light (mr_nee): without either, no chain
     * can connect, and trying one at every rough vertex (an environment
     * sample drawn for mr_env_nee, then no object to take) costs a scene
     * with non-convex smooth metal under a map about a quarter of its time
     * for the same image. */
    uint32_t kinds = 0;
    for (uint32_t k = 0; k < r->mr_n; k++)
        kinds |= r->mr[k].kinds;
    if (!(kinds & MR_HULL))
        r->mirror_smooth = r->mirror_env = 0;
    r->mirror = (kinds & MR_HULL) || ((kinds & MR_GLASS) && scene_punctual(s));
    if (!r->mirror)
        return PT_OK;
    return pt_accel_new_subset(s, r->mr_tris, n, &r->mr_accel, err);
}

/* r->mf_accel: the still, flat triangles a chain may refract at (chain_vert
 * takes no others), so that a solver's step finds the glass behind the
 * things inside it with one ray. */
static pt_status mf_accel_new(pt_renderer *r, pt_error *err)
{
    const pt_scene *s = r->scene;
    uint32_t nt = s->num_instances > 0 ? s->num_flat_triangles : s->num_triangles, n = 0;
    r->mf_tris = pt_malloc_array(nt ? nt : 1, sizeof *r->mf_tris);
    if (!r->mf_tris)
        return pt_error_set(err, PT_ERR_NOMEM, "manifold NEE: out of memory");
    for (uint32_t i = 0; i < nt; i++)
        if (mf_caster(&s->materials[s->tri_material[i] & ~TRI_FLAT]))
            r->mf_tris[n++] = i;
    return pt_accel_new_subset(s, r->mf_tris, n, &r->mf_accel, err);
}

/* What in this render bidirectional path tracing cannot take, in words for
 * the user; NULL: nothing (pt_render_check_bdpt). */
static const char *bd_why(const pt_scene *scene, int has_env, int guiding, int clamped)
{
    const uint32_t f = scene->features;
    if (f & (PT_FEAT_TRANSMISSION | PT_FEAT_VOLUME | PT_FEAT_THIN_GLASS |
             PT_FEAT_DIFFUSE_TRANSMISSION | PT_FEAT_DISPERSION))
        return "transmissive materials (glass, KHR_materials_transmission, "
               "KHR_materials_diffuse_transmission)";
    if (f & PT_FEAT_UNLIT)
        return "unlit materials (KHR_materials_unlit)";
    if (!(f & (PT_FEAT_EMITTERS | PT_FEAT_PUNCTUAL)) && !has_env)
        return "no emissive surface, point or spot light or environment to start light paths on";
    if (guiding)
        return "path guiding";
    if (clamped)
        return "sample clamping";
    return NULL;
}

pt_status pt_render_check_bdpt(const pt_scene *scene, int has_env, int guiding, int clamped,
                               pt_error *err)
{
    const char *why = bd_why(scene, has_env, guiding, clamped);
    if (!why)
        return PT_OK;
    return pt_error_set(err, PT_ERR_ARG,
                        "bidirectional path tracing (--bdpt) renders scenes lit by emissive "
                        "surfaces, point and spot lights and environments with opaque materials "
                        "only; this render has %s",
                        why);
}

/* r->bd: the emissive triangles, point and spot lights and environment by
 * power, as light paths pick them. */
static pt_status bd_setup(pt_renderer *r, pt_error *err)
{
    const pt_scene *s = r->scene;
    pt_status st = pt_emitters_init(&r->bd.em, s, err);
    if (st != PT_OK)
        return st;
    /* The scene's bounding sphere: a light path from the environment or a
     * directional light starts on its disk that faces the light. */
    pt_vec3 lo = s->bounds_min, hi = s->bounds_max;
    r->bd.c = pt_v3_scale(pt_v3_add(lo, hi), 0.5f);
    r->bd.rad = 0.5f * pt_v3_len(pt_v3_sub(hi, lo)) * 1.001f + 1e-6f;
    const double rad2 = (double)r->bd.rad * (double)r->bd.rad;
    /* Point, spot and directional lights: their flux over pi, 4 I,
     * 2 (1 - cos outer) I, or E R^2 (the irradiance E through the disk). */
    r->bd.np = 0;
    r->bd.pidx = pt_malloc_array(s->num_punctual ? s->num_punctual : 1, sizeof *r->bd.pidx);
    r->bd.pcdf = pt_malloc_array(s->num_punctual ? s->num_punctual : 1, sizeof *r->bd.pcdf);
    if (!r->bd.pidx || !r->bd.pcdf)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory for the light paths' lights");
    double psum = 0.0;
    for (uint32_t i = 0; i < s->num_punctual; i++) {
        const pt_punctual *l = &s->punctual[i];
        double w = pt_luminance(l->intensity) * (l->type == PT_PUNCTUAL_SPOT
                                                     ? 2.0 * (1.0 - (double)l->cos_outer)
                                                 : l->type == PT_PUNCTUAL_DIRECTIONAL ? rad2
                                                                                      : 4.0);
        if (!(w > 0.0) || !isfinite(w))
            continue;
        psum += w;
        r->bd.pidx[r->bd.np] = i;
        r->bd.pcdf[r->bd.np++] = psum;
    }
    /* The environment: the flux its parallel rays carry through the disk
     * of the scene's bounding sphere, pi R^2 4 pi mean, over pi as the
     * triangles' area x luminance is. */
    const pt_env *env = r->params.env;
    r->bd.env_w = 0.0;
    if (env) {
        double w = 4.0 * PT_PI * rad2 * pt_env_mean_luminance(env);
        if (w > 0.0 && isfinite(w))
            r->bd.env_w = w;
    }
    /* Once, for every light path's pick and start density. */
    r->bd.total = bd_tris(r) + (r->bd.np ? r->bd.pcdf[r->bd.np - 1] : 0.0) + r->bd.env_w;
    return PT_OK;
}

pt_status pt_renderer_new(const pt_scene *scene, const pt_render_params *params, pt_renderer **out,
                          pt_error *err)
{
    if (params->width == 0 || params->height == 0)
        return pt_error_set(err, PT_ERR_ARG, "image size %ux%u is empty", params->width,
                            params->height);
    if (!scene->camera.ortho && !(scene->camera.yfov > 0.0f && scene->camera.yfov < PT_PI))
        return pt_error_set(err, PT_ERR_ARG, "camera field of view %g rad is not in (0, pi)",
                            (double)scene->camera.yfov);
    if (params->bdpt) {
        pt_status bs =
            pt_render_check_bdpt(scene, params->env != NULL, params->guiding != 0,
                                 params->clamp_direct > 0.0f || params->clamp_indirect > 0.0f, err);
        if (bs != PT_OK)
            return bs;
        if (params->light_strategy != PT_LIGHT_MIS)
            return pt_error_set(err, PT_ERR_ARG,
                                "bidirectional path tracing weighs every strategy by MIS: "
                                "light_strategy must be PT_LIGHT_MIS");
    }
    pt_renderer *r = pt_calloc(1, sizeof *r);
    if (!r)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory for the renderer");
    pt_status st;
    r->scene = scene;
    r->params = *params;
    r->camera = scene->camera;
    /* A framed camera looks at the bounds as they are (posed at the time
     * asked for) and fits them to this image's aspect. */
    if (scene->camera.framed)
        pt_camera_frame(scene->bounds_min, scene->bounds_max,
                        (float)params->width / (float)params->height, &r->camera);
    /* An orthographic view given by its width alone (ymag 0): the height
     * follows the image. */
    if (r->camera.ortho && !(r->camera.ymag > 0.0f))
        r->camera.ymag = r->camera.xmag * (float)params->height / (float)params->width;
    r->tan_half_fov = tanf(0.5f * r->camera.yfov);
    if ((st = pt_accel_new(scene, &r->accel, err)) != PT_OK)
        goto fail;
    r->alpha_solid = pt_accel_alpha_solid(r->accel);
    /* Solid-angle sampling of large near lights (light.h), when asked for,
     * where the scene runs a variant that samples lights one path at a
     * time: the Lambert variants' lanes compute area sampling's pdf, so a
     * Lambert-only scene keeps area sampling in all its variants and their
     * bits. */
    uint32_t scene_feats = scene->features | (params->env ? (uint32_t)PT_FEAT_ENV : 0u);
    uint32_t select = params->light_select;
    if (!(scene_feats & (PT_FEAT_GLOSSY | GENERAL_ONLY)))
        select &= ~(uint32_t)PT_LIGHT_SOLID_ANGLE;
    if ((st = pt_lights_new_select(
             scene, params->env, params->light_strategy == PT_LIGHT_MIS ? PT_ENV_MIS : PT_ENV_FULL,
             select, &r->lights, err)) != PT_OK)
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
    if (scene->num_triangles > 0 && !(r->tris = tri_recs_new(scene, &r->tris_mem))) {
        st = pt_error_set(err, PT_ERR_NOMEM, "out of memory for the renderer");
        goto fail;
    }
    uint32_t others = pt_lights_punctual_count(r->lights) + (uint32_t)pt_lights_has_env(r->lights);
    r->nee =
        pt_lights_count(r->lights) + others > 0 && params->light_strategy != PT_LIGHT_BSDF_ONLY;
    /* The stage-wide light sampling and the lanes know only triangles; with
     * a light tree it takes any class and pays at any count (the walks of a
     * stage's points interleave: EmissiveStrengthTest's 60 lights, see
     * docs/bench/light_tree.md). */
    r->nee_n = r->nee && ((pt_lights_count(r->lights) >= LIGHTS_N_MIN && others == 0) ||
                          pt_lights_has_tree(r->lights));
    r->light_tree = pt_lights_has_tree(r->lights);
    r->recv_normal =
        r->light_tree || pt_lights_has_portals(r->lights) ||
        (params->env && pt_lights_has_env(r->lights) &&
         pt_env_splits(params->env,
                       params->light_strategy == PT_LIGHT_MIS ? PT_ENV_MIS : PT_ENV_FULL));
    uint32_t features = scene->features | (params->extra_features & ~(PARAM_FEATURES | FEAT_BDPT));
    r->alpha = (scene->features & PT_FEAT_ALPHA) != 0;
    for (uint32_t i = 0; r->alpha && i < scene->num_materials; i++)
        r->blend |= scene->materials[i].alpha_mode == PT_ALPHA_BLEND;
    r->motion = (scene->features & PT_FEAT_MOTION) ? scene->motion : NULL;
    if (params->env)
        features |= PT_FEAT_ENV;
    /* Variants are compiled for feature masks; the general one has this
     * code, which r->thin_glass turns on. */
    features &= ~(uint32_t)PT_FEAT_THIN_GLASS;
    r->thin_glass = !params->opaque_thin_glass && r->nee && scene_thin_glass(scene);
    if (r->thin_glass)
        features |= PT_FEAT_THIN_GLASS;
    features &= ~(uint32_t)PT_FEAT_MANIFOLD;
    /* A reflection chain's rays meet any triangle, MASK and BLEND ones too
     * (pt_accel_intersect): it connects only where no surface lies between
     * (light off glass through a cutout stays out, as it was); a refraction
     * chain's seed ray answers a shadow ray, which alpha would make
     * stochastic. */
    const int chains = !params->no_manifold && !params->bdpt && r->nee &&
                       params->light_strategy == PT_LIGHT_MIS && (features & PT_FEAT_GLOSSY) &&
                       !(features & PT_FEAT_MOTION);
    r->refract = chains && !(features & PT_FEAT_ALPHA) &&
                 (params->env || scene_punctual(scene) || (features & PT_FEAT_EMITTERS)) &&
                 scene_manifold(scene);
    const int mirror = chains && !params->no_mirror &&
                       ((scene_punctual(scene) && scene_mirror(scene)) ||
                        (params->env && pt_lights_has_env(r->lights) &&
                         !(features & PT_FEAT_ALPHA) && scene_smooth(scene)));
    r->manifold = r->refract || mirror;
    if (r->manifold) {
        features |= PT_FEAT_MANIFOLD;
        r->mf_min_light =
            params->env ? (float)(params->manifold_min_light * pt_env_mean_luminance(params->env))
                        : 0.0f;
        if (r->refract && (st = mf_accel_new(r, err)) != PT_OK)
            goto fail;
        if (mirror && (st = mr_new(r, err)) != PT_OK)
            goto fail;
        r->manifold = r->refract || r->mirror;
        if (!r->manifold)
            features &= ~(uint32_t)PT_FEAT_MANIFOLD;
    }
    if (params->bdpt) {
        if ((st = bd_setup(r, err)) != PT_OK)
            goto fail;
        features |= FEAT_BDPT;
    }
    /* Guiding samples glossy closures only (closure_guidable): a
     * Lambert-only scene keeps its variant. */
    if (params->guiding && (features & PT_FEAT_GLOSSY))
        features |= FEAT_GUIDE;
    if (params->clamp_direct > 0.0f || params->clamp_indirect > 0.0f)
        features |= FEAT_CLAMP;
    if (params->passes & PT_PASS_ALL)
        features |= FEAT_PASSES;
    if ((params->passes & PT_PASS_CRYPTOMATTE) && scene->tri_object) {
        /* The names' ids, hashed once (crypto.h). */
        r->crypto_obj =
            pt_malloc_array(scene->num_objects ? scene->num_objects : 1, sizeof *r->crypto_obj);
        r->crypto_mat =
            pt_malloc_array(scene->num_materials ? scene->num_materials : 1, sizeof *r->crypto_mat);
        if (!r->crypto_obj || !r->crypto_mat) {
            st = pt_error_set(err, PT_ERR_NOMEM, "out of memory for the renderer");
            goto fail;
        }
        for (uint32_t i = 0; i < scene->num_objects; i++)
            r->crypto_obj[i] = pt_crypto_id(scene->object_names[i].s);
        for (uint32_t i = 0; i < scene->num_materials; i++)
            r->crypto_mat[i] = pt_crypto_id(scene->materials[i].name);
    }
    if ((features & FEAT_GUIDE) && params->env && r->tris)
        photon_setup(r, features);
    pick_variant(r, features);
    /* Without fast lanes (an x86-64 processor without AVX2 runs shade_lanes'
     * baseline clone, which does the lanes one by one) the per-path shading
     * is faster: docs/bench/throughput.md, "Fourth round". */
    r->lanes = !(features & (PT_FEAT_GLOSSY | GENERAL_ONLY | PARAM_FEATURES | FEAT_BDPT)) &&
               !params->scalar_shading && pt_simd_lanes_fast();
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
    pt_free(r->crypto_obj);
    pt_free(r->crypto_mat);
    pt_free(r->photon.smooth);
    pt_free(r->tris_mem);
    pt_lights_free(r->lights);
    pt_accel_free(r->mf_accel);
    pt_free(r->mf_tris);
    pt_accel_free(r->mr_accel);
    pt_free(r->mr_tris);
    pt_free(r->mr);
    pt_free(r->mr_of_object);
    pt_free(r->mr_side);
    pt_emitters_fini(&r->bd.em);
    pt_free(r->bd.pidx);
    pt_free(r->bd.pcdf);
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
                         pt_render_stats *stats, int *covered)
{
    pixel_ctx pc;
    pixel_ctx_init(&pc, r, px, py);
    return r->li(r, &pc, index, stats, covered, NULL, NULL);
}

pt_vec3 pt_render_sample_guided(const pt_renderer *r, uint32_t px, uint32_t py, uint32_t index,
                                pt_render_stats *stats, int *covered, const pt_render_guiding *gd)
{
    pixel_ctx pc;
    pixel_ctx_init(&pc, r, px, py);
    return r->li(r, &pc, index, stats, covered, gd, NULL);
}

pt_vec3 pt_render_sample_passes(const pt_renderer *r, uint32_t px, uint32_t py, uint32_t index,
                                pt_render_stats *stats, int *covered, pt_pass_sample *ps)
{
    pixel_ctx pc;
    pixel_ctx_init(&pc, r, px, py);
    memset(ps, 0, sizeof *ps);
    return r->li(r, &pc, index, stats, covered, NULL, ps);
}

void pt_render_tile(const pt_renderer *r, pt_rect tile, uint32_t s0, uint32_t s1, pt_pixel_acc *out,
                    pt_render_stats *stats)
{
    r->tile(r, tile, s0, s1, out, NULL, stats, NULL);
}

void pt_render_tile_guided(const pt_renderer *r, pt_rect tile, uint32_t s0, uint32_t s1,
                           pt_pixel_acc *out, pt_render_stats *stats, const pt_render_guiding *gd)
{
    r->tile(r, tile, s0, s1, out, NULL, stats, gd);
}

void pt_render_tile_passes(const pt_renderer *r, pt_rect tile, uint32_t s0, uint32_t s1,
                           pt_pixel_acc *out, pt_pass_acc *pout, pt_render_stats *stats,
                           const pt_render_guiding *gd)
{
    if (pout && !(r->params.passes & PT_PASS_ALL))
        memset(pout, 0, (size_t)(tile.x1 - tile.x0) * (tile.y1 - tile.y0) * sizeof *pout);
    r->tile(r, tile, s0, s1, out, pout, stats, gd);
}

void pt_render_tile_traced(const pt_renderer *r, pt_rect tile, uint32_t s0, uint32_t s1,
                           pt_pixel_acc *out, const pt_ray_sink *sink)
{
    tile_impl(r, tile, s0, s1, out, NULL, NULL, NULL, ALL_FEATURES & ~PARAM_FEATURES, sink, NULL);
}

pt_status pt_render_check_lit(const pt_scene *scene, int has_env, const char *name, pt_error *err)
{
    if ((scene->features & (PT_FEAT_EMITTERS | PT_FEAT_PUNCTUAL)) || has_env)
        return PT_OK;
    return pt_error_set(err, PT_ERR_ARG,
                        "%s has no light: no emissive material and no KHR_lights_punctual "
                        "light; light it with --env MAP.hdr (an environment map) or --background "
                        "R,G,B (a uniform sky)",
                        name);
}
