/*
 * light.c - emissive triangles as lights: power-proportional choice through an
 * alias table, uniform area sampling, conversion to solid angle.
 *
 * Power of a light triangle (only the ratios matter):
 *     area x luminance(emissive factor (x) mean of the emissive texture
 *                      over the triangle's UV footprint)
 *          x (2 if double-sided) x pi
 * The footprint's mean (footprint_mean) reads the texels the triangle covers,
 * once at load, so a triangle over the black part of an emissive texture is
 * no light and a bright one is chosen for its own brightness; it is an
 * estimate (texel centres, or a grid over large footprints), which costs
 * variance, never bias (the pdf is the one used to choose). Triangles with
 * zero or non-finite power (black emission, zero area) are left out: NEE
 * never chooses them, and BSDF sampling finds them with MIS weight 1.
 *
 * Choice: Vose 1991, "A Linear Algorithm for Generating Random Numbers with a
 * Given Distribution" (IEEE TSE 17(9)): Walker's alias method built in O(n).
 * Point: Heitz 2019, "A Low-Distortion Map Between Triangle and Square"
 * (HAL hal-02073696), which keeps the stratification of the sampler's points;
 * with PT_LIGHT_SOLID_ANGLE, a triangle seen under SA_MIN sr or more is
 * sampled by solid angle instead (Arvo 1995, sphtri.h). Many lights: the
 * light tree (light_tree.h) from PT_LIGHT_TREE_MIN to PT_LIGHT_TREE_AUTO_MAX of them.
 *
 * Punctual lights (scene.h) are chosen among themselves by a cumulative
 * table, and against the triangles by the two classes' total power, on the
 * triangles' scale (flux): a point light of intensity I emits 4 pi I; a spot
 * light about 2 pi (1 - (cos inner + cos outer) / 2) I, the solid angle of the
 * cone halfway through its falloff; a directional light of irradiance E
 * lights at most the scene's bounding sphere's cross-section, pi R^2 E. These
 * are estimates: a poor one costs variance, never bias, since the sample is
 * divided by the probability it was chosen with. Falloffs follow the
 * extension's README: a spot's angular attenuation is
 * saturate(cos * scale + offset)^2, scale = 1 / max(0.001, cos inner - cos
 * outer), offset = -cos outer * scale; a range r windows 1 / d^2 by
 * clamp(1 - (d / r)^4, 0, 1).
 */
#include "common/render/light.h"

#include <math.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/bsdf.h"
#include "common/render/env.h"
#include "common/render/light_lanes.h"
#include "common/render/light_tree.h"
#include "common/render/portal.h"
#include "common/render/sampler.h"
#include "common/render/sphtri.h"
#include "common/scene/accel.h"
#include "common/scene/motion.h"

/* One column of the alias table: 16 bytes, so that the random read of a
 * column touches one cache line and four columns share it. */
typedef struct alias_slot {
    double prob;    /* keep the column's own light when the residual of u[0] is below */
    uint32_t alias; /* light taken otherwise */
    uint32_t pad;
} alias_slot;

/* What sampling needs of a light triangle, copied once so that a sample reads
 * one 64-byte, line-aligned entry instead of the index, three vertices and a
 * recomputed normal (tri_geom's results, the same bits). With many emissive
 * triangles these reads are cache misses; the entry keeps them to one line. */
typedef struct light_entry {
    pt_vec3 v[3];      /* vertices */
    pt_vec3 normal;    /* unit geometric normal (tri_geom) */
    float pmf_area;    /* probability of choosing the light / its area (without a tree) */
    uint32_t tri;      /* triangle in the scene */
    uint32_t material; /* its material */
    float area;        /* its area */
} light_entry;
_Static_assert(sizeof(light_entry) == 64, "a light entry is one cache line");

struct pt_lights {
    uint32_t count;
    uint32_t num_triangles;
    light_entry *lights; /* count entries, 64-byte aligned inside lights_mem */
    void *lights_mem;
    /* 6 floats a light: its vertices' (u, v) in the coordinate set of its
     * material's emissive slot, where that material has an emissive texture
     * (emission_at), so that a sample reads neither the index nor the
     * vertices' coordinates; NULL when no light's material has one. */
    float *tex_uv;
    alias_slot *alias;   /* count columns */
    pt_light_tree *tree; /* where it chooses the triangle (light_tree.h); NULL: the alias table */
    int solid_angle;     /* PT_LIGHT_SOLID_ANGLE: large near triangles by solid angle */
    uint32_t *tri_to_light; /* num_triangles entries, UINT32_MAX: not a light; NULL if count 0 */
    /* punctual lights */
    uint32_t npunct;          /* the punctual class's lights (0: no class) */
    uint32_t npunct_all;      /* punctual lights NEE can choose, by class or tree */
    uint32_t *tree_punct;     /* tree light count + i: the scene's punctual light */
    uint32_t ntree_punct;     /* ... for i below this */
    const pt_punctual *punct; /* the scene's */
    double *punct_cdf;        /* npunct + 1: cumulative power among them, 0 to 1 */
    float *punct_pmf;         /* the probability of choosing each, class included */
    double p_tri;             /* the probability of choosing the triangles' class */
    const pt_env *env;        /* NULL: none (or black) */
    double c_env;             /* u0 >= c_env chooses the environment (1: never) */
    float p_env;              /* the probability of choosing it */
    int env_dist;             /* its distribution (env.h, PT_ENV_*) */
    const pt_scene *portals;  /* the scene, whose portals (portal.h) are used; NULL:
                                 none, no env, or a sun that shines in through one */
};

static pt_vec3 vertex(const pt_scene *s, uint32_t i)
{
    return pt_v3(s->positions[3 * i], s->positions[3 * i + 1], s->positions[3 * i + 2]);
}

/* Vertices, unit geometric normal (from the winding) and area of triangle
 * tri. The normal is computed exactly as pt_accel_hit_point does, so a hit's
 * ng and a sample's normal agree to the bit. The area is pt_accel_tri_area's:
 * a lamp 1e10 wide still has one. */
static void tri_geom(const pt_scene *s, uint32_t tri, pt_vec3 v[3], pt_vec3 *n, float *area)
{
    const uint32_t *t = &s->indices[3 * tri];
    v[0] = vertex(s, t[0]);
    v[1] = vertex(s, t[1]);
    v[2] = vertex(s, t[2]);
    pt_vec3 c = pt_v3_cross(pt_v3_sub(v[1], v[0]), pt_v3_sub(v[2], v[0]));
    float len = pt_v3_len(c);
    *area = pt_accel_tri_area(c, len);
    *n = (len > 0.0f && isfinite(len)) ? pt_v3_scale(c, 1.0f / len) : pt_accel_degenerate_normal(c);
}

static int emits(const pt_material *m)
{
    return m->emissive[0] > 0.0f || m->emissive[1] > 0.0f || m->emissive[2] > 0.0f;
}

/* Emission of tri at barycentrics (b1, b2), ignoring the side. */
static pt_vec3 emission(const pt_scene *s, const pt_material *m, uint32_t tri, float b1, float b2)
{
    pt_vec3 e = pt_v3(m->emissive[0], m->emissive[1], m->emissive[2]);
    if (m->emissive_tex >= 0 && (uint32_t)m->emissive_tex < s->num_textures && s->uvs) {
        /* Its coordinate set and KHR_texture_transform (an identity on
         * TEXCOORD_0 gives the plain interpolation's bits). */
        float uv[2], c[4];
        pt_scene_slot_uv(s, m, PT_SLOT_EMISSIVE, tri, b1, b2, uv);
        pt_texture_sample(&s->textures[m->emissive_tex], uv[0], uv[1], c);
        e = pt_v3_mul(e, pt_v3(c[0], c[1], c[2]));
    }
    return e;
}

/* Whether a light's emission reads its texture (emission's condition). */
static inline int textured(const pt_scene *s, const pt_material *m)
{
    return m->emissive_tex >= 0 && (uint32_t)m->emissive_tex < s->num_textures && s->uvs;
}

/* The emissive slot's UV of light k at (b1, b2), from the copy in tex_uv:
 * pt_scene_slot_uv's arithmetic on the same numbers, so the same bits. */
static inline void light_uv(const pt_lights *L, const pt_scene *s, const pt_material *m, uint32_t k,
                            float b1, float b2, float out[2])
{
    const pt_tex_xform *x = &m->tex_xf[PT_SLOT_EMISSIVE];
    float t[2] = {0.0f, 0.0f};
    if (x->texcoord ? s->uvs1 : s->uvs) {
        const float *uv = &L->tex_uv[6 * (size_t)k];
        float b0 = 1.0f - b1 - b2;
        t[0] = b0 * uv[0] + b1 * uv[2] + b2 * uv[4];
        t[1] = b0 * uv[1] + b1 * uv[3] + b2 * uv[5];
    }
    pt_tex_xform_apply(x, t, out);
}

/* emission() of light entry le: the same bits, its texture coordinates read
 * from the lights' own copy. */
static inline pt_vec3 emission_at(const pt_lights *L, const pt_scene *s, const light_entry *le,
                                  float b1, float b2)
{
    const pt_material *m = &s->materials[le->material];
    pt_vec3 e = pt_v3(m->emissive[0], m->emissive[1], m->emissive[2]);
    if (textured(s, m)) {
        float uv[2], c[4];
        light_uv(L, s, m, (uint32_t)(le - L->lights), b1, b2, uv);
        pt_texture_sample(&s->textures[m->emissive_tex], uv[0], uv[1], c);
        e = pt_v3_mul(e, pt_v3(c[0], c[1], c[2]));
    }
    return e;
}

pt_vec3 pt_emitted(const pt_scene *scene, uint32_t tri, float b1, float b2, pt_vec3 w_out)
{
    const pt_material *m = &scene->materials[scene->tri_material[tri]];
    if (!emits(m))
        return pt_v3(0.0f, 0.0f, 0.0f);
    if (!m->double_sided) {
        pt_vec3 v[3], n;
        float area;
        tri_geom(scene, tri, v, &n, &area);
        if (!(pt_v3_dot(n, w_out) > 0.0f))
            return pt_v3(0.0f, 0.0f, 0.0f);
    }
    return emission(scene, m, tri, b1, b2);
}

pt_status pt_emitters_init(pt_emitters *e, const pt_scene *s, pt_error *err)
{
    uint32_t n = 0;
    for (uint32_t t = 0; t < s->num_triangles; t++)
        n += emits(&s->materials[s->tri_material[t]]);
    e->n = 0;
    e->tri = pt_malloc_array(n ? n : 1, sizeof *e->tri);
    e->cdf = pt_malloc_array(n ? n : 1, sizeof *e->cdf);
    if (!e->tri || !e->cdf) {
        pt_emitters_fini(e);
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory for the emitters' table");
    }
    double sum = 0.0;
    for (uint32_t t = 0; t < s->num_triangles; t++) {
        const pt_material *m = &s->materials[s->tri_material[t]];
        if (!emits(m))
            continue;
        /* Power by the emission at the centroid: a light path's start
         * density is any positive one; where it is 0 the other strategies
         * take the light. */
        pt_vec3 v[3], ng;
        float area;
        tri_geom(s, t, v, &ng, &area);
        pt_vec3 le = pt_emitted(s, t, 1.0f / 3.0f, 1.0f / 3.0f, ng);
        double w = (double)area * pt_luminance(le) * (m->double_sided ? 2.0 : 1.0);
        if (!(w > 0.0) || !isfinite(w))
            continue;
        sum += w;
        e->tri[e->n] = t;
        e->cdf[e->n++] = sum;
    }
    return PT_OK;
}

void pt_emitters_fini(pt_emitters *e)
{
    pt_free(e->tri);
    pt_free(e->cdf);
    e->tri = NULL;
    e->cdf = NULL;
    e->n = 0;
}

uint32_t pt_emitters_pick(const pt_emitters *e, double x)
{
    uint32_t lo = 0, hi = e->n - 1;
    while (lo < hi) {
        uint32_t mid = lo + (hi - lo) / 2;
        if (e->cdf[mid] > x)
            hi = mid;
        else
            lo = mid + 1;
    }
    return lo;
}

pt_vec3 pt_emitter_start(pt_vec3 ng, int double_sided, const float u[4], float *b1, float *b2,
                         pt_vec3 *side)
{
    float su = sqrtf(u[0]);
    *b1 = 1.0f - su;
    *b2 = u[1] * su;
    pt_vec3 n = ng;
    float ud = u[2];
    if (double_sided) {
        if (ud < 0.5f) {
            n = pt_v3_neg(n);
            ud *= 2.0f;
        } else {
            ud = 2.0f * ud - 1.0f;
        }
        ud = pt_fminf(ud, 0x1.fffffep-1f);
    }
    *side = n;
    pt_frame f = pt_frame_from_normal(n);
    return pt_frame_to_world(&f, pt_sample_cosine_hemisphere(ud, u[3]));
}

/* The texels per triangle footprint_mean reads one by one; a larger
 * footprint is read at FOOTPRINT_GRID^2 points spread evenly over the
 * triangle. */
#define FOOTPRINT_TEXELS 4096u
#define FOOTPRINT_GRID 32u

/* Mean linear RGB of material m's emissive texture over triangle tri: the
 * texels whose centres its UV triangle covers, read through the renderer's
 * lookup (at a centre, that texel), or at its centroid and corners when it
 * covers none; a footprint of more than FOOTPRINT_TEXELS texels (by its
 * bounding box) is read at points uniform in area (Heitz 2019's map over a
 * grid). The UV map is affine over a triangle (pt_scene_slot_uv:
 * barycentric interpolation, then KHR_texture_transform), so the footprint
 * is the triangle of its corners' UVs. It is an estimate of power, used
 * only to choose: a poor one costs variance, never bias. */
static pt_vec3 footprint_mean(const pt_scene *s, const pt_material *m, uint32_t tri)
{
    const pt_texture *tex = &s->textures[m->emissive_tex];
    const float w = (float)tex->width, h = (float)tex->height;
    float uv[3][2];
    pt_scene_slot_uv(s, m, PT_SLOT_EMISSIVE, tri, 0.0f, 0.0f, uv[0]);
    pt_scene_slot_uv(s, m, PT_SLOT_EMISSIVE, tri, 1.0f, 0.0f, uv[1]);
    pt_scene_slot_uv(s, m, PT_SLOT_EMISSIVE, tri, 0.0f, 1.0f, uv[2]);
    /* In texel units, texel (x, y)'s centre at the integers. */
    double x[3], y[3];
    for (int i = 0; i < 3; i++) {
        x[i] = (double)uv[i][0] * w - 0.5;
        y[i] = (double)uv[i][1] * h - 0.5;
    }
    double x0 = fmin(fmin(x[0], x[1]), x[2]), x1 = fmax(fmax(x[0], x[1]), x[2]);
    double y0 = fmin(fmin(y[0], y[1]), y[2]), y1 = fmax(fmax(y[0], y[1]), y[2]);
    double sum[3] = {0, 0, 0};
    uint64_t n = 0;
    float c[4];
    double bx = ceil(x1) - floor(x0) + 1.0, by = ceil(y1) - floor(y0) + 1.0;
    if (isfinite(bx) && isfinite(by) && bx * by <= (double)FOOTPRINT_TEXELS) {
        /* Edge functions of the UV triangle, either winding. */
        double area2 = (x[1] - x[0]) * (y[2] - y[0]) - (x[2] - x[0]) * (y[1] - y[0]);
        for (double ty = ceil(y0); ty <= y1 && area2 != 0.0; ty += 1.0) {
            for (double tx = ceil(x0); tx <= x1; tx += 1.0) {
                double e0 = ((x[1] - tx) * (y[2] - ty) - (x[2] - tx) * (y[1] - ty)) / area2;
                double e1 = ((x[2] - tx) * (y[0] - ty) - (x[0] - tx) * (y[2] - ty)) / area2;
                double e2 = 1.0 - e0 - e1;
                if (e0 < 0.0 || e1 < 0.0 || e2 < 0.0)
                    continue;
                pt_texture_sample(tex, (float)((tx + 0.5) / w), (float)((ty + 0.5) / h), c);
                sum[0] += c[0];
                sum[1] += c[1];
                sum[2] += c[2];
                n++;
            }
        }
        if (n == 0) { /* smaller than a texel: its centroid and corners */
            const float b[4][2] = {{1.0f / 3.0f, 1.0f / 3.0f}, {0, 0}, {1, 0}, {0, 1}};
            for (int i = 0; i < 4; i++) {
                float t[2];
                pt_scene_slot_uv(s, m, PT_SLOT_EMISSIVE, tri, b[i][0], b[i][1], t);
                pt_texture_sample(tex, t[0], t[1], c);
                sum[0] += c[0];
                sum[1] += c[1];
                sum[2] += c[2];
                n++;
            }
        }
    } else {
        for (uint32_t j = 0; j < FOOTPRINT_GRID * FOOTPRINT_GRID; j++) {
            /* Heitz 2019 (pick_point's map) at the grid cell's centre */
            float u1 = ((float)(j % FOOTPRINT_GRID) + 0.5f) / (float)FOOTPRINT_GRID;
            float u2 = ((float)(j / FOOTPRINT_GRID) + 0.5f) / (float)FOOTPRINT_GRID;
            int upper = u2 > u1;
            float b1 = upper ? 0.5f * u1 : u1 - 0.5f * u2;
            float b2 = upper ? u2 - 0.5f * u1 : 0.5f * u2;
            float t[2];
            pt_scene_slot_uv(s, m, PT_SLOT_EMISSIVE, tri, b1, b2, t);
            pt_texture_sample(tex, t[0], t[1], c);
            sum[0] += c[0];
            sum[1] += c[1];
            sum[2] += c[2];
            n++;
        }
    }
    return pt_v3((float)(sum[0] / (double)n), (float)(sum[1] / (double)n),
                 (float)(sum[2] / (double)n));
}

/* Whether triangle tri can be a light: its material emits and it does not
 * move. A moving emitter is no light to sample (its area and place depend on
 * the path's time): BSDF sampling alone finds it, with MIS weight 1. */
static int candidate(const pt_scene *s, uint32_t tri)
{
    return emits(&s->materials[s->tri_material[tri]]) &&
           !(s->motion && s->motion->moving[tri] != UINT32_MAX);
}

/* Power of candidate triangle tri (see the top of the file); 0 when it is
 * not a light (no area, or black over its whole footprint). */
static double tri_power(const pt_scene *s, uint32_t tri)
{
    const pt_material *m = &s->materials[s->tri_material[tri]];
    pt_vec3 v[3], n;
    float area;
    tri_geom(s, tri, v, &n, &area);
    pt_vec3 e = pt_v3(m->emissive[0], m->emissive[1], m->emissive[2]);
    if (textured(s, m))
        e = pt_v3_mul(e, footprint_mean(s, m, tri));
    double p = (double)area * (double)pt_luminance(e) * (m->double_sided ? 2.0 : 1.0) *
               3.14159265358979323846;
    return p > 0.0 && isfinite(p) ? p : 0.0;
}

/* The estimated flux of a punctual light (the top of the file); 0 when it
 * could never light anything. radius: of the scene's bounding sphere. */
static double punctual_power(const pt_punctual *l, double radius)
{
    const double pi = 3.14159265358979323846;
    double lum = pt_luminance(l->intensity), p;
    if (l->type == PT_PUNCTUAL_DIRECTIONAL)
        p = pi * radius * radius * lum;
    else if (l->type == PT_PUNCTUAL_SPOT)
        p = 2.0 * pi * (1.0 - 0.5 * ((double)l->cos_inner + (double)l->cos_outer)) * lum;
    else
        p = 4.0 * pi * lum;
    return p > 0.0 && isfinite(p) ? p : 0.0;
}

/* Vose's alias table over lights[0..n) from power[] (total > 0).
 * scratch: n uint32. The small list grows up from the front of scratch, the
 * large list down from the back; Vose's update q_g = (q_g + q_l) - 1 keeps
 * the rounding error from accumulating. */
static void build_alias(alias_slot *lights, double *q, uint32_t *scratch, uint32_t n, double total)
{
    uint32_t ns = 0, nl = 0;
    for (uint32_t i = 0; i < n; i++) {
        q[i] = q[i] * (double)n / total;
        if (q[i] < 1.0)
            scratch[ns++] = i;
        else
            scratch[n - 1 - nl++] = i;
    }
    while (ns > 0 && nl > 0) {
        uint32_t l = scratch[--ns];
        uint32_t g = scratch[n - nl];
        lights[l].prob = q[l];
        lights[l].alias = g;
        q[g] = (q[g] + q[l]) - 1.0;
        if (q[g] < 1.0) { /* g moves from the top of the large list to the small one */
            nl--;
            scratch[ns++] = g;
        }
    }
    /* What is left is 1 up to rounding. */
    while (nl > 0) {
        uint32_t g = scratch[n - nl--];
        lights[g].prob = 1.0;
        lights[g].alias = g;
    }
    while (ns > 0) {
        uint32_t l = scratch[--ns];
        lights[l].prob = 1.0;
        lights[l].alias = l;
    }
}

/* The light tree over the n triangle lights of L (entries filled) with
 * their powers, then the m point and spot lights of the scene with a power
 * (punct_power) in their order. A triangle's cone is its normal alone
 * (theta_o = 0); a point light's is every direction, a spot light's its
 * outer cone (the tree's bound adds pi/2 to it: loose, never too tight). */
static pt_status build_tree(const pt_scene *scene, pt_lights *L, const double *power, uint32_t n,
                            const double *punct_power, uint32_t m, pt_error *err)
{
    pt_light_tree_item *items = pt_malloc_array((size_t)n + m, sizeof *items);
    if (!items || (m > 0 && !(L->tree_punct = pt_malloc_array(m, sizeof *L->tree_punct)))) {
        pt_free(items);
        return pt_error_set(err, PT_ERR_NOMEM, "pt_lights_new: out of memory for the light tree");
    }
    for (uint32_t i = 0; i < n; i++) {
        const light_entry *le = &L->lights[i];
        const pt_vec3 *v = le->v;
        pt_light_tree_item *it = &items[i];
        it->lo = pt_v3(fminf(fminf(v[0].x, v[1].x), v[2].x), fminf(fminf(v[0].y, v[1].y), v[2].y),
                       fminf(fminf(v[0].z, v[1].z), v[2].z));
        it->hi = pt_v3(fmaxf(fmaxf(v[0].x, v[1].x), v[2].x), fmaxf(fmaxf(v[0].y, v[1].y), v[2].y),
                       fmaxf(fmaxf(v[0].z, v[1].z), v[2].z));
        it->axis = le->normal;
        it->cos_o = 1.0f;
        it->power = (float)power[i];
        it->two_sided = scene->materials[le->material].double_sided;
    }
    for (uint32_t i = 0, j = 0; j < m; i++) {
        const pt_punctual *l = &scene->punctual[i];
        if (l->type == PT_PUNCTUAL_DIRECTIONAL || !(punct_power[i] > 0.0))
            continue;
        pt_light_tree_item *it = &items[n + j];
        it->lo = it->hi = l->position;
        int spot = l->type == PT_PUNCTUAL_SPOT;
        it->axis = spot ? l->direction : pt_v3(0.0f, 0.0f, 1.0f);
        it->cos_o = spot ? l->cos_outer : -1.0f;
        it->power = (float)punct_power[i];
        it->two_sided = 0;
        L->tree_punct[j++] = i;
    }
    L->ntree_punct = m;
    pt_status st = pt_light_tree_new(items, n + m, &L->tree, err);
    pt_free(items);
    return st;
}

/* Grows the box [lo, hi] to hold point x. */
static inline void grow_box(double lo[3], double hi[3], pt_vec3 x)
{
    const float c[3] = {x.x, x.y, x.z};
    for (int a = 0; a < 3; a++) {
        lo[a] = fmin(lo[a], (double)c[a]);
        hi[a] = fmax(hi[a], (double)c[a]);
    }
}

/* The diagonal of the box around the tree's lights (the n triangle lights'
 * vertices, the point and spot lights' positions) over that of the box
 * around the scene and them: PT_LIGHT_TREE_MIN_SPREAD says why. 1 for a
 * scene of no extent. */
static double lights_spread(const pt_scene *scene, const pt_lights *L, uint32_t n,
                            const double *punct_power)
{
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (uint32_t i = 0; i < n; i++)
        for (int c = 0; c < 3; c++)
            grow_box(lo, hi, L->lights[i].v[c]);
    for (uint32_t i = 0; L->punct && i < scene->num_punctual; i++) {
        const pt_punctual *l = &scene->punctual[i];
        if (l->type != PT_PUNCTUAL_DIRECTIONAL && punct_power[i] > 0.0)
            grow_box(lo, hi, l->position);
    }
    const float smin[3] = {scene->bounds_min.x, scene->bounds_min.y, scene->bounds_min.z};
    const float smax[3] = {scene->bounds_max.x, scene->bounds_max.y, scene->bounds_max.z};
    double dl = 0.0, ds = 0.0;
    for (int a = 0; a < 3; a++) {
        double e = hi[a] > lo[a] ? hi[a] - lo[a] : 0.0;
        double f = fmax(hi[a], (double)smax[a]) - fmin(lo[a], (double)smin[a]);
        dl += e * e;
        ds += isfinite(f) && f > 0.0 ? f * f : 0.0;
    }
    return ds > 0.0 ? sqrt(dl / ds) : 1.0;
}

pt_status pt_lights_new(const pt_scene *scene, pt_lights **out, pt_error *err)
{
    return pt_lights_new_env(scene, NULL, PT_ENV_FULL, out, err);
}

pt_status pt_lights_new_env(const pt_scene *scene, const pt_env *env, int env_dist, pt_lights **out,
                            pt_error *err)
{
    return pt_lights_new_select(scene, env, env_dist, PT_LIGHT_SELECT_AUTO, out, err);
}

/* With portals (portal.h) a light sample of the environment takes a
 * direction through them with probability PORTAL_SHARE, else one of the
 * map's distribution, and its pdf is the mixture's (Veach's one-sample
 * model): the portals give the sky in a window the samples that the map
 * would spend on walls, and the map's part still finds what they miss. A
 * receiver that sees no portal (none has a corner above its tangent
 * plane) samples the map alone. Where the map has a sun (pt_env_sun) that
 * can shine in through a portal, the portals are not used at all: the sun
 * through the window is then most of the room's light, the map's own
 * samples find it, and a share of uniform directions through the window
 * takes samples from it. A portal's front (its counter-clockwise side,
 * the glTF front face) faces into the room, so the sun can shine in
 * through it when the sun's cone reaches behind it. Measured on the window
 * room (docs/bench/portals.md): under the overcast map a share of 0.8 has
 * 1.14 times the error of 0.95, 0.5 1.65 times; with the park's map turned
 * so that its sun is behind the room, 0.8 has 0.74 times the error of 0.5;
 * under the park's sun, which shines in, a share of 0.05 has 0.83 of the
 * error for 1.19 times the CPU (1.00 times the time to the same error) and
 * larger shares lose. */
#define PORTAL_SHARE 0.8

/* Whether env has a sun whose cone reaches behind some portal of scene's
 * (the side its front does not face). */
static int sun_enters(const pt_env *env, const pt_scene *scene)
{
    pt_vec3 axis;
    float sin_half;
    if (!pt_env_sun(env, &axis, &sin_half))
        return 0;
    for (uint32_t i = 0; i < scene->num_portals; i++) {
        const float *f = scene->portal_fronts + 3 * (size_t)i;
        if (pt_v3_dot(axis, pt_v3(f[0], f[1], f[2])) < sin_half)
            return 1;
    }
    return 0;
}

pt_status pt_lights_new_select(const pt_scene *scene, const pt_env *env, int env_dist,
                               uint32_t select, pt_lights **out, pt_error *err)
{
    pt_status st = PT_OK;
    double *cand_power = NULL;  /* per candidate triangle, in order */
    double *punct_power = NULL; /* per punctual light */
    double *power = NULL;
    uint32_t *scratch = NULL;
    if (!scene || !out)
        return pt_error_set(err, PT_ERR_ARG, "pt_lights_new: NULL argument");

    pt_lights *L = pt_calloc(1, sizeof *L);
    if (!L)
        return pt_error_set(err, PT_ERR_NOMEM, "pt_lights_new: out of memory");
    L->num_triangles = scene->num_triangles;
    L->env_dist = env_dist;
    L->solid_angle = (select & PT_LIGHT_SOLID_ANGLE) != 0;
    select &= ~(uint32_t)PT_LIGHT_SOLID_ANGLE;

    /* Check what we will index. */
    int any_tex = 0;
    for (uint32_t i = 0; i < scene->num_materials; i++) {
        const pt_material *m = &scene->materials[i];
        if (!emits(m) || m->emissive_tex < 0)
            continue;
        if ((uint32_t)m->emissive_tex >= scene->num_textures) {
            st = pt_error_set(err, PT_ERR_FORMAT, "material %u (%s): emissive texture %d of %u", i,
                              m->name, (int)m->emissive_tex, scene->num_textures);
            goto fail;
        }
        const pt_texture *t = &scene->textures[m->emissive_tex];
        if (t->width == 0 || t->height == 0 || !t->rgba) {
            st = pt_error_set(err, PT_ERR_FORMAT, "texture %d: empty", (int)m->emissive_tex);
            goto fail;
        }
        any_tex = 1;
    }
    /* Punctual lights and the environment: their power, and the triangles'
     * share. */
    double punct_total = 0.0, env_power = 0.0;
    pt_vec3 ext = pt_v3_sub(scene->bounds_max, scene->bounds_min);
    double radius = 0.5 * (double)pt_v3_len(ext);
    if (env) {
        env_power = 4.0 * 3.14159265358979323846 * 3.14159265358979323846 * radius * radius *
                    pt_env_mean_luminance(env);
        if (env_power > 0.0 && isfinite(env_power))
            L->env = env;
        else
            env_power = 0.0;
    }
    if (scene->num_punctual > 0) {
        L->punct_cdf = pt_malloc_array((size_t)scene->num_punctual + 1, sizeof *L->punct_cdf);
        L->punct_pmf = pt_malloc_array(scene->num_punctual, sizeof *L->punct_pmf);
        punct_power = pt_malloc_array(scene->num_punctual, sizeof *punct_power);
        if (!L->punct_cdf || !L->punct_pmf || !punct_power)
            goto nomem;
        for (uint32_t i = 0; i < scene->num_punctual; i++) {
            punct_power[i] = punctual_power(&scene->punctual[i], radius);
            punct_total += punct_power[i];
        }
        if (punct_total > 0.0)
            L->punct = scene->punctual;
    }

    uint32_t n = 0, nc = 0;
    double total = 0.0; /* the triangles' power */
    for (uint32_t i = 0; i < scene->num_triangles; i++) {
        if (scene->tri_material[i] >= scene->num_materials) {
            st = pt_error_set(err, PT_ERR_FORMAT, "triangle %u: material %u of %u", i,
                              scene->tri_material[i], scene->num_materials);
            goto fail;
        }
        nc += (uint32_t)candidate(scene, i);
    }
    /* Each candidate's power once: a textured one reads its footprint. */
    if (nc > 0 && !(cand_power = pt_malloc_array(nc, sizeof *cand_power)))
        goto nomem;
    for (uint32_t i = 0, c = 0; i < scene->num_triangles; i++) {
        if (!candidate(scene, i))
            continue;
        cand_power[c] = tri_power(scene, i);
        n += cand_power[c++] > 0.0;
    }
    if (n == 0) {
        L->p_tri = 0.0;
        goto others;
    }

    /* One spare entry's room to align the array to a cache line. */
    L->lights_mem = pt_malloc_array((size_t)n + 1, sizeof *L->lights);
    if (L->lights_mem)
        L->lights = (light_entry *)(((uintptr_t)L->lights_mem + 63) & ~(uintptr_t)63);
    L->alias = pt_malloc_array(n, sizeof *L->alias);
    L->tri_to_light = pt_malloc_array(scene->num_triangles, sizeof *L->tri_to_light);
    power = pt_malloc_array(n, sizeof *power);
    scratch = pt_malloc_array(n, sizeof *scratch);
    if (!L->lights_mem || !L->alias || !L->tri_to_light || !power || !scratch)
        goto nomem;
    if (any_tex && scene->uvs && !(L->tex_uv = pt_malloc_array(n, 6 * sizeof *L->tex_uv)))
        goto nomem;

    uint32_t k = 0;
    for (uint32_t i = 0, ci = 0; i < scene->num_triangles; i++) {
        L->tri_to_light[i] = UINT32_MAX;
        if (!candidate(scene, i))
            continue;
        double p = cand_power[ci++];
        if (!(p > 0.0))
            continue;
        L->tri_to_light[i] = k;
        light_entry *le = &L->lights[k];
        le->tri = i;
        le->material = scene->tri_material[i];
        tri_geom(scene, i, le->v, &le->normal, &le->area);
        const pt_material *m = &scene->materials[le->material];
        if (L->tex_uv && textured(scene, m)) {
            const float *set = m->tex_xf[PT_SLOT_EMISSIVE].texcoord ? scene->uvs1 : scene->uvs;
            const uint32_t *t = &scene->indices[3 * (size_t)i];
            for (int c = 0; c < 6; c++)
                L->tex_uv[6 * (size_t)k + c] = set ? set[2 * t[c >> 1] + (c & 1)] : 0.0f;
        }
        power[k] = p;
        total += p;
        k++;
    }
    L->count = n;

others : {
    /* The tree takes the point and spot lights too (a directional light has
     * no place to bound): then the first class is the tree's, and the
     * punctual class keeps the directional lights. */
    uint32_t m = 0; /* point and spot lights that can be chosen */
    double tree_punct = 0.0;
    for (uint32_t i = 0; L->punct && i < scene->num_punctual; i++)
        if (scene->punctual[i].type != PT_PUNCTUAL_DIRECTIONAL && punct_power[i] > 0.0) {
            m++;
            tree_punct += punct_power[i];
        }
    int use_tree = select == PT_LIGHT_SELECT_TREE ? n + m >= 2
                   : select == PT_LIGHT_SELECT_AUTO
                       ? n + m >= PT_LIGHT_TREE_MIN && n + m <= PT_LIGHT_TREE_AUTO_MAX &&
                             lights_spread(scene, L, n, punct_power) >= PT_LIGHT_TREE_MIN_SPREAD
                       : 0;
    double first = use_tree ? total + tree_punct : total; /* the first class's power */
    double class_punct = use_tree ? punct_total - tree_punct : punct_total;
    if (!(class_punct > 0.0))
        class_punct = 0.0;
    double all = first + class_punct + env_power;
    /* Without other lights p_tri is 1 and the pmfs are the bits they were
     * before there were any. */
    int others = class_punct > 0.0 || L->env;
    L->p_tri = others ? first / all : 1.0;
    for (uint32_t i = 0; i < n; i++) {
        float pmf = (float)(others ? power[i] / total * L->p_tri : power[i] / total);
        L->lights[i].pmf_area = pmf / L->lights[i].area;
    }
    if (use_tree && (st = build_tree(scene, L, power, n, punct_power, m, err)) != PT_OK)
        goto fail;
    if (n > 0) /* last: it scales power[] in place */
        build_alias(L->alias, power, scratch, n, total);
    double p_punct = class_punct > 0.0 ? class_punct / all : 0.0;
    if (class_punct > 0.0) {
        L->npunct = scene->num_punctual;
        L->punct_cdf[0] = 0.0;
        for (uint32_t i = 0; i < L->npunct; i++) {
            /* the tree's lights take no room in the class */
            int in_tree = use_tree && scene->punctual[i].type != PT_PUNCTUAL_DIRECTIONAL;
            L->punct_cdf[i + 1] = L->punct_cdf[i] + (in_tree ? 0.0 : punct_power[i]);
        }
        for (uint32_t i = 0; i < L->npunct; i++) {
            L->punct_cdf[i + 1] /= class_punct;
            L->punct_pmf[i] = (float)(p_punct * (L->punct_cdf[i + 1] - L->punct_cdf[i]));
        }
        L->punct_cdf[L->npunct] = 1.0;
    }
    L->npunct_all = (class_punct > 0.0 || (use_tree && m > 0)) ? scene->num_punctual : 0;
    L->c_env = L->env ? L->p_tri + p_punct : 1.0;
    L->p_env = L->env ? (float)(env_power / all) : 0.0f;
    if (L->env && !(L->p_env > 0.0f)) {
        L->env = NULL; /* too faint to choose in float: as if none */
        L->c_env = 1.0;
    }
    if (L->env && scene->num_portals > 0 && !sun_enters(L->env, scene))
        L->portals = scene;
}

    pt_free(scratch);
    pt_free(power);
    pt_free(cand_power);
    pt_free(punct_power);
    *out = L;
    return PT_OK;

nomem:
    st = pt_error_set(err, PT_ERR_NOMEM, "pt_lights_new: out of memory");
fail:
    pt_free(scratch);
    pt_free(power);
    pt_free(cand_power);
    pt_free(punct_power);
    pt_lights_free(L);
    return st;
}

void pt_lights_free(pt_lights *lights)
{
    if (!lights)
        return;
    pt_free(lights->lights_mem);
    pt_free(lights->tex_uv);
    pt_free(lights->alias);
    pt_light_tree_free(lights->tree);
    pt_free(lights->tri_to_light);
    pt_free(lights->punct_cdf);
    pt_free(lights->punct_pmf);
    pt_free(lights->tree_punct);
    pt_free(lights);
}

uint32_t pt_lights_count(const pt_lights *lights)
{
    return lights ? lights->count : 0;
}

uint32_t pt_lights_punctual_count(const pt_lights *lights)
{
    return lights ? lights->npunct_all : 0;
}

int pt_lights_has_tree(const pt_lights *lights)
{
    return lights && lights->tree;
}

int pt_lights_has_env(const pt_lights *lights)
{
    return lights && lights->env;
}

int pt_lights_has_portals(const pt_lights *lights)
{
    return lights && lights->portals;
}

/* The portals' view from a receiver at p with normal n. */
static inline void portal_view(const pt_lights *lights, pt_vec3 p, pt_vec3 n, pt_portal_view *v)
{
    const pt_scene *s = lights->portals;
    pt_portal_view_init(v, s->portals, s->portal_fronts, s->num_portals, p, n);
}

/* The share of a receiver whose view is v: PORTAL_SHARE where a portal
 * counts, else 0 (the map alone). */
static inline double portal_share(const pt_portal_view *v)
{
    return v->counted ? PORTAL_SHARE : 0.0;
}

/* The mixture's density for a share, the portals' density and the map's. */
static inline double portal_mix(double share, double portal_pdf, double map_pdf)
{
    return share * portal_pdf + (1.0 - share) * map_pdf;
}

float pt_lights_env_pdf(const pt_lights *lights, pt_vec3 dir, pt_vec3 p, pt_vec3 n)
{
    if (!lights || !lights->env)
        return 0.0f;
    float map = pt_env_pdf(lights->env, dir, lights->env_dist, n);
    if (lights->portals) {
        pt_portal_view v;
        portal_view(lights, p, n, &v);
        double share = portal_share(&v);
        if (share > 0.0)
            return lights->p_env * (float)portal_mix(share, pt_portal_pdf(&v, dir), map);
    }
    return lights->p_env * map;
}

/* A sample of the environment through the portals or from the map (u0 in
 * [0,1) chooses, above) for a receiver at p with normal n: a direction,
 * its radiance and the mixture's pdf. */
static int sample_env_portals(const pt_lights *lights, pt_vec3 p, pt_vec3 n, double u0,
                              const float u[3], pt_light_sample *s)
{
    pt_portal_view v;
    portal_view(lights, p, n, &v);
    float map;
    double pp, share = portal_share(&v);
    if (u0 < share) {
        if (!pt_portal_sample(&v, (float)(u0 / share), u[1], u[2], &s->wi, &pp))
            return 0;
        s->radiance = pt_env_eval(lights->env, s->wi);
        map = pt_env_pdf(lights->env, s->wi, lights->env_dist, n);
    } else {
        if (!pt_env_sample(lights->env, &u[1], lights->env_dist, n, &s->wi, &s->radiance, &map))
            return 0;
        pp = share > 0.0 ? pt_portal_pdf(&v, s->wi) : 0.0;
    }
    double pdf = portal_mix(share, pp, map);
    s->pdf = lights->p_env * (float)pdf;
    return s->pdf > 0.0f && isfinite(s->pdf);
}

/* A sample of the environment from u[1..2] for a receiver at p with normal
 * n (env.h: the sun's share by n): a direction and the radiance from it,
 * not a delta (MIS weighs it against BSDF sampling). u[0] (>= c_env) chose
 * it; with portals what is left of it chooses how it is sampled. */
static int sample_env(const pt_lights *lights, pt_vec3 p, pt_vec3 n, const float u[3],
                      pt_light_sample *s)
{
    s->delta = PT_LIGHT_ENV;
    s->tri = UINT32_MAX;
    s->dist = INFINITY;
    if (lights->portals) {
        double v = ((double)u[0] - lights->c_env) / (1.0 - lights->c_env);
        return sample_env_portals(lights, p, n, v < 0.0 ? 0.0 : v, u, s);
    }
    float pdf;
    if (!pt_env_sample(lights->env, &u[1], lights->env_dist, n, &s->wi, &s->radiance, &pdf))
        return 0;
    s->pdf = lights->p_env * pdf;
    return s->pdf > 0.0f && isfinite(s->pdf);
}

static int eval_punctual(const pt_punctual *l, pt_vec3 p, float pmf, pt_light_sample *s);

/* A sample of the punctual light that v (in [0,1)) picks, seen from p. */
static int sample_punctual(const pt_lights *lights, pt_vec3 p, double v, pt_light_sample *s)
{
    uint32_t lo = 0, hi = lights->npunct - 1; /* the first i with v < cdf[i + 1] */
    while (lo < hi) {
        uint32_t mid = lo + (hi - lo) / 2;
        if (v < lights->punct_cdf[mid + 1])
            hi = mid;
        else
            lo = mid + 1;
    }
    return eval_punctual(&lights->punct[lo], p, lights->punct_pmf[lo], s);
}

/* atten times a point or spot light's falloff towards a point at distance
 * dist along -wi (wi: the unit direction from that point to the light): the
 * range's window and the spot's cone (the top of the file). */
float pt_punctual_range_window(const pt_punctual *l, float dist)
{
    if (!(l->range > 0.0f))
        return 1.0f;
    float x = dist / l->range, x4 = (x * x) * (x * x);
    return x4 < 1.0f ? 1.0f - x4 : 0.0f;
}

static inline float punctual_falloff(const pt_punctual *l, pt_vec3 wi, float dist, float atten)
{
    if (l->range > 0.0f)
        atten *= pt_punctual_range_window(l, dist);
    if (l->type == PT_PUNCTUAL_SPOT) {
        float scale = 1.0f / fmaxf(0.001f, l->cos_inner - l->cos_outer);
        float a = -pt_v3_dot(l->direction, wi) * scale - l->cos_outer * scale;
        a = a < 0.0f ? 0.0f : a > 1.0f ? 1.0f : a;
        atten *= a * a;
    }
    return atten;
}

/* A sample of punctual light l seen from p, chosen with probability pmf. */
static int eval_punctual(const pt_punctual *l, pt_vec3 p, float pmf, pt_light_sample *s)
{
    s->pdf = pmf;
    if (!(s->pdf > 0.0f))
        return 0;
    if (l->type == PT_PUNCTUAL_DIRECTIONAL) {
        s->delta = PT_LIGHT_FAR;
        s->punct = l;
        s->wi = pt_v3_neg(l->direction);
        s->dist = INFINITY;
        s->radiance = l->intensity;
        return 1;
    }
    s->delta = PT_LIGHT_AT;
    s->position = l->position;
    pt_vec3 d = pt_v3_sub(l->position, p);
    float d2 = pt_v3_dot(d, d);
    s->dist = sqrtf(d2);
    if (!(s->dist > 0.0f) || !isfinite(s->dist))
        return 0;
    s->wi = pt_v3_scale(d, 1.0f / s->dist);
    s->punct = l;
    float atten = punctual_falloff(l, s->wi, s->dist, 1.0f / d2);
    s->radiance = pt_v3_scale(l->intensity, atten);
    return isfinite(atten) && atten > 0.0f;
}

pt_vec3 pt_punctual_intensity(const pt_punctual *l, pt_vec3 wi, float dist)
{
    float atten = punctual_falloff(l, wi, dist, 1.0f);
    return isfinite(atten) && atten > 0.0f ? pt_v3_scale(l->intensity, atten) : pt_v3(0, 0, 0);
}

/* pdf_w = pmf / area * d^2 / |cos theta_light| (area to solid angle: dA =
 * d^2 / |cos| dw). 0 on the back of a single-sided light, at a grazing angle,
 * at distance 0, or where the division overflows. */
static inline float solid_angle_pdf_d(float pmf_area, int double_sided, pt_vec3 d, float d2,
                                      float dist, pt_vec3 n)
{
    if (!(d2 > 0.0f) || !isfinite(d2))
        return 0.0f;
    float cos_l = -pt_v3_dot(n, d) / dist; /* > 0: p sees the front */
    if (!double_sided && !(cos_l > 0.0f))
        return 0.0f;
    float ac = fabsf(cos_l);
    if (!(ac > 0.0f))
        return 0.0f;
    float pdf = pmf_area * d2 / ac; /* pmf / area * d2 / ac, the same bits */
    return isfinite(pdf) ? pdf : 0.0f;
}

/* The same from p and the light point x; d = x - p, dist = |d|. */
static float solid_angle_pdf(float pmf_area, int double_sided, pt_vec3 p, pt_vec3 x, pt_vec3 n)
{
    pt_vec3 d = pt_v3_sub(x, p);
    float d2 = pt_v3_dot(d, d);
    return solid_angle_pdf_d(pmf_area, double_sided, d, d2, sqrtf(d2), n);
}

/* The light and the point on it that u picks (pt_lights_sample's first
 * step), with the point's barycentrics of vertices 1 and 2. */
/* The alias table's column for u0 and its residual. */
static inline uint32_t pick_column(const pt_lights *lights, float u0, double *residual)
{
    /* One number picks a column and, with its residual, the column's own
     * light or its alias. In double: u[0] * n is exact for n < 2^29. */
    uint32_t n = lights->count;
    double x = (double)u0 * (double)n;
    uint32_t col = x < (double)n ? (uint32_t)x : n - 1;
    *residual = x - (double)col;
    return col;
}

/* The light that u0 picks. */
static inline uint32_t pick_index(const pt_lights *lights, float u0)
{
    double r;
    uint32_t col = pick_column(lights, u0, &r);
    /* A select, not a branch: the choice is random, so a branch would be
     * mispredicted half of the time. */
    const alias_slot *c = &lights->alias[col];
    return r < c->prob ? col : c->alias;
}

/* The point of light le that (u1, u2) picks, and its barycentrics. */
static inline const light_entry *point_on(const light_entry *le, float u1, float u2, pt_vec3 *pos,
                                          float *b1_out, float *b2_out)
{
    const float u[3] = {0.0f, u1, u2};
    /* Heitz 2019, sec. 3: the square is cut along its diagonal and each half
     * sheared onto the triangle; the Jacobian is constant, so the density is
     * uniform in area. */
    int upper = u[2] > u[1]; /* random: selects, not branches */
    float h1 = 0.5f * u[1], h2 = 0.5f * u[2];
    float b1 = upper ? h1 : u[1] - h2;
    float b2 = upper ? u[2] - h1 : h2;
    float b0 = 1.0f - b1 - b2;
    const pt_vec3 *v = le->v;
    *pos =
        pt_v3_add(pt_v3_add(pt_v3_scale(v[0], b0), pt_v3_scale(v[1], b1)), pt_v3_scale(v[2], b2));
    *b1_out = b1;
    *b2_out = b2;
    return le;
}

static inline const light_entry *pick_point(const pt_lights *lights, const float u[3], pt_vec3 *pos,
                                            float *b1_out, float *b2_out)
{
    return point_on(&lights->lights[pick_index(lights, u[0])], u[1], u[2], pos, b1_out, b2_out);
}

/* pmf / area of light le chosen by the tree with probability q within the
 * triangles' class. */
static inline float tree_pmf_area(const pt_lights *lights, const light_entry *le, double q)
{
    return (float)(q * lights->p_tri) / le->area;
}

/* The light and point u picks through the alias table; *pmf_area its
 * probability / area. */
static inline const light_entry *choose(const pt_lights *lights, const float u[3], pt_vec3 *pos,
                                        float *b1, float *b2, float *pmf_area)
{
    const light_entry *le = pick_point(lights, u, pos, b1, b2);
    *pmf_area = le->pmf_area;
    return le;
}

/* The solid angle of light le seen from p when it is sampled by solid
 * angle there (PT_LIGHT_SOLID_ANGLE and at least SA_MIN sr), else 0. The
 * solid angle is at most area / h^2, h the distance to the light's plane
 * (it is the integral of h / r^3 over the triangle, r >= h), which skips
 * its computation for every light seen smaller. Sampling and
 * pt_lights_pdf decide by this one function, so their pdfs agree. */
#define SA_MIN 1.5
static inline double sa_omega(const pt_lights *lights, const light_entry *le, pt_vec3 p)
{
    if (!lights->solid_angle)
        return 0.0;
    double h = fabs((double)pt_v3_dot(le->normal, pt_v3_sub(p, le->v[0])));
    if (!((double)le->area > SA_MIN * h * h))
        return 0.0;
    /* and at most area / d^2, d the distance to the triangle, at least the
     * distance to its centroid less its farthest vertex's */
    pt_vec3 c = pt_v3_scale(pt_v3_add(pt_v3_add(le->v[0], le->v[1]), le->v[2]), 1.0f / 3.0f);
    double r2 = 0.0;
    for (int i = 0; i < 3; i++) {
        pt_vec3 e = pt_v3_sub(le->v[i], c);
        r2 = fmax(r2, (double)pt_v3_dot(e, e));
    }
    pt_vec3 dc = pt_v3_sub(p, c);
    double d = sqrt((double)pt_v3_dot(dc, dc)) - sqrt(r2);
    if (d > 0.0 && !((double)le->area > SA_MIN * d * d))
        return 0.0;
    double om = pt_sphtri_solid_angle(p, le->v[0], le->v[1], le->v[2]);
    return om >= SA_MIN ? om : 0.0;
}

/* The pdf of a direction to light le sampled by solid angle: its pmf over
 * the solid angle. */
static inline float sa_pdf(const light_entry *le, float pmf_area, double omega)
{
    return (float)((double)(pmf_area * le->area) / omega);
}

/* pt_lights_sample's light point for le by solid angle (Arvo 1995,
 * sphtri.h): the direction from u1, u2, the point where it meets the
 * light's plane, its barycentrics for the emission. */
static int sample_solid_angle(const pt_lights *lights, const pt_scene *scene, const light_entry *le,
                              pt_vec3 p, float pmf_area, double omega, float u1, float u2,
                              pt_light_sample *s)
{
    double arvo_omega; /* from the inner angles: omega up to rounding */
    pt_vec3 wi;
    if (!pt_sphtri_sample(p, le->v[0], le->v[1], le->v[2], u1, u2, &wi, &arvo_omega))
        return 0;
    const pt_material *m = &scene->materials[le->material];
    float dn = pt_v3_dot(wi, le->normal);
    if (!m->double_sided && !(dn < 0.0f)) /* the back of a single-sided light */
        return 0;
    float t = pt_v3_dot(pt_v3_sub(le->v[0], p), le->normal) / dn;
    if (!(t > 0.0f) || !isfinite(t))
        return 0;
    s->position = pt_v3_add(p, pt_v3_scale(wi, t));
    s->wi = wi;
    s->dist = t;
    s->normal = le->normal;
    s->tri = le->tri;
    s->pdf = sa_pdf(le, pmf_area, omega);
    if (!(s->pdf > 0.0f) || !isfinite(s->pdf))
        return 0;
    /* barycentrics of the point, clamped into the triangle */
    pt_vec3 e1 = pt_v3_sub(le->v[1], le->v[0]), e2 = pt_v3_sub(le->v[2], le->v[0]);
    pt_vec3 x = pt_v3_sub(s->position, le->v[0]);
    pt_vec3 c = pt_v3_cross(e1, e2);
    float cc = pt_v3_dot(c, c);
    float b1 = cc > 0.0f ? pt_v3_dot(pt_v3_cross(x, e2), c) / cc : 0.0f;
    float b2 = cc > 0.0f ? pt_v3_dot(pt_v3_cross(e1, x), c) / cc : 0.0f;
    b1 = b1 < 0.0f ? 0.0f : b1 > 1.0f ? 1.0f : b1;
    b2 = b2 < 0.0f ? 0.0f : b2 > 1.0f - b1 ? 1.0f - b1 : b2;
    s->radiance = emission_at(lights, scene, le, b1, b2);
    return 1;
}

/* pt_lights_sample's point on triangle light le, chosen with probability
 * pmf_area x its area, from u[1], u[2]. */
static int sample_on(const pt_lights *lights, const pt_scene *scene, const light_entry *le,
                     pt_vec3 p, float pmf_area, const float u[3], pt_light_sample *s)
{
    if (!(pmf_area > 0.0f))
        return 0;
    double omega = sa_omega(lights, le, p);
    if (omega > 0.0)
        return sample_solid_angle(lights, scene, le, p, pmf_area, omega, u[1], u[2], s);
    float b1, b2;
    point_on(le, u[1], u[2], &s->position, &b1, &b2);
    s->tri = le->tri;
    s->normal = le->normal;
    pt_vec3 d = pt_v3_sub(s->position, p);
    float d2 = pt_v3_dot(d, d);
    s->dist = sqrtf(d2);
    if (!(s->dist > 0.0f) || !isfinite(s->dist))
        return 0;
    s->wi = pt_v3_scale(d, 1.0f / s->dist);
    const pt_material *m = &scene->materials[le->material];
    s->pdf = solid_angle_pdf_d(pmf_area, m->double_sided, d, d2, s->dist, le->normal);
    if (!(s->pdf > 0.0f))
        return 0;
    s->radiance = emission_at(lights, scene, le, b1, b2);
    return 1;
}

/* pt_lights_sample's sample once the tree has chosen light k (UINT32_MAX:
 * none) with probability q within the first class. */
static int sample_tree_light(const pt_lights *lights, const pt_scene *scene, pt_vec3 p,
                             const float u[3], uint32_t k, double q, pt_light_sample *s)
{
    if (k == UINT32_MAX)
        return 0;
    if (k >= lights->count) /* a point or spot light */
        return eval_punctual(&lights->punct[lights->tree_punct[k - lights->count]], p,
                             (float)(q * lights->p_tri), s);
    const light_entry *le = &lights->lights[k];
    return sample_on(lights, scene, le, p, tree_pmf_area(lights, le, q), u, s);
}

int pt_lights_sample(const pt_lights *lights, const pt_scene *scene, pt_vec3 p, pt_vec3 n,
                     const float u[3], pt_light_sample *s)
{
    memset(s, 0, sizeof *s);
    s->tri = UINT32_MAX;
    if (!lights || (lights->count == 0 && lights->npunct == 0 && !lights->env && !lights->tree))
        return 0;
    float ut[3];
    if (lights->npunct > 0 || lights->env) {
        /* The class first, then the light within it, from one number. */
        double u0 = u[0];
        if (!(u0 < lights->c_env))
            return sample_env(lights, p, n, u, s);
        if (!(u0 < lights->p_tri)) {
            s->tri = UINT32_MAX;
            return sample_punctual(lights, p,
                                   (u0 - lights->p_tri) / (lights->c_env - lights->p_tri), s);
        }
        ut[0] = (float)(u0 / lights->p_tri);
        ut[1] = u[1];
        ut[2] = u[2];
        u = ut;
    }

    if (lights->tree) {
        double q;
        uint32_t k = pt_light_tree_sample(lights->tree, p, n, (double)u[0], &q);
        return sample_tree_light(lights, scene, p, u, k, q, s);
    }
    const light_entry *le = &lights->lights[pick_index(lights, u[0])];
    return sample_on(lights, scene, le, p, le->pmf_area, u, s);
}

/* Slot j of out: light le's point pos at barycentrics (b1, b2), chosen with
 * pmf_area. The emission of every pick, also of those that the checks will
 * reject: without a branch on the checks, which the lanes make. */
static inline void put_pick(const pt_lights *lights, const pt_scene *scene, pt_light_picks *out,
                            uint32_t j, const light_entry *le, pt_vec3 pos, float b1, float b2,
                            float pmf_area)
{
    const pt_material *m = &scene->materials[le->material];
    pt_vec3 e = emission_at(lights, scene, le, b1, b2);
    PT_LANE_PUT3(out->pos, j, pos);
    PT_LANE_PUT3(out->normal, j, le->normal);
    out->pmf_area[j] = pmf_area;
    out->two_sided[j] = m->double_sided ? -1 : 0;
    PT_LANE_PUT3(out->radiance, j, e);
}

void pt_lights_pick_n(const pt_lights *lights, const pt_scene *scene, uint32_t n, const float *pick,
                      const float *point, size_t stride, const float *const p[3],
                      const float *const nrm[3], pt_light_picks *out)
{
    if (n == 0)
        return;
    if (!lights->tree) {
        for (uint32_t j = 0; j < n; j++) {
            const float u[3] = {pick[j * stride], point[j * stride], point[j * stride + 1]};
            pt_vec3 pos;
            float b1, b2, pmf_area;
            const light_entry *le = choose(lights, u, &pos, &b1, &b2, &pmf_area);
            put_pick(lights, scene, out, j, le, pos, b1, b2, pmf_area);
        }
        return;
    }
    /* Through the tree, the n points walk it together (pt_light_tree_sample_n:
     * their cache misses overlap), then each takes its light as
     * pt_lights_sample does: the same bits as one at a time. */
    pt_vec3 pp[PT_LIGHT_PICKS], nn[PT_LIGHT_PICKS];
    double u0[PT_LIGHT_PICKS], q[PT_LIGHT_PICKS];
    uint32_t k[PT_LIGHT_PICKS];
    for (uint32_t j = 0; j < n; j++) {
        pp[j] = pt_v3(p[0][j], p[1][j], p[2][j]);
        nn[j] = pt_v3(nrm[0][j], nrm[1][j], nrm[2][j]);
        u0[j] = (double)pick[j * stride];
    }
    pt_light_tree_sample_n(lights->tree, n, pp, nn, u0, k, q);
    for (uint32_t j = 0; j < n; j++) {
        pt_vec3 pos;
        float b1, b2, pmf_area = 0.0f;
        const light_entry *le;
        if (k[j] >= lights->count) { /* none, or a punctual light: not in the lanes */
            le = point_on(&lights->lights[0], point[j * stride], point[j * stride + 1], &pos, &b1,
                          &b2);
        } else {
            le = point_on(&lights->lights[k[j]], point[j * stride], point[j * stride + 1], &pos,
                          &b1, &b2);
            pmf_area = tree_pmf_area(lights, le, q[j]);
        }
        put_pick(lights, scene, out, j, le, pos, b1, b2, pmf_area);
    }
}

/*
 * pt_lights_sample for many points, in three steps over 8 at a time: the
 * light picks and points, then the distances, directions and pdfs in 8 lanes
 * (pt_light_lanes_pdf), then the emission per point. The picks' reads of the
 * alias table and the light entries, and the emission textures' reads, come
 * close together for 8 points, so that with many lights their cache misses
 * overlap. A lane whose point the scalar code rejects before a division
 * computes it anyway, harmlessly (a NaN or an infinity, no traps), and its
 * result is not used.
 */
/* The light count past which pt_lights_sample_n prefetches its picks'
 * reads: 512 entries are 32 KB. */
#define PREFETCH_LIGHTS 512u

/* pt_lights_sample_n through the tree: the points whose number picks the
 * tree's class walk it together (pt_light_tree_sample_n, their cache misses
 * overlapping), then the chosen lights' entries and texels are asked for
 * before any is read, then each sample is finished as pt_lights_sample
 * finishes it: the same bits. */
#define TREE_BATCH 64u
static void sample_n_tree(const pt_lights *lights, const pt_scene *scene, uint32_t n,
                          const pt_vec3 *p, const pt_vec3 *nrm, const float (*u)[3],
                          pt_light_sample *s, int *ok)
{
    for (uint32_t i0 = 0; i0 < n; i0 += TREE_BATCH) {
        uint32_t m = 0, idx[TREE_BATCH], k[TREE_BATCH];
        float ut[TREE_BATCH][3];
        pt_vec3 pt[TREE_BATCH], nt[TREE_BATCH];
        double u0[TREE_BATCH], q[TREE_BATCH];
        for (uint32_t i = i0; i < n && i < i0 + TREE_BATCH; i++) {
            /* pt_lights_sample's choice of the class, from one number */
            ut[m][0] = u[i][0];
            ut[m][1] = u[i][1];
            ut[m][2] = u[i][2];
            if (lights->npunct > 0 || lights->env) {
                double v = u[i][0];
                if (!(v < lights->p_tri)) { /* the environment or a punctual light */
                    ok[i] = pt_lights_sample(lights, scene, p[i], nrm[i], u[i], &s[i]);
                    continue;
                }
                ut[m][0] = (float)(v / lights->p_tri);
            }
            u0[m] = (double)ut[m][0];
            pt[m] = p[i];
            nt[m] = nrm[i];
            idx[m++] = i;
        }
        pt_light_tree_sample_n(lights->tree, m, pt, nt, u0, k, q);
        for (uint32_t j = 0; j < m; j++) {
            if (k[j] >= lights->count)
                continue;
            const light_entry *le = &lights->lights[k[j]];
            __builtin_prefetch(le);
            if (lights->tex_uv)
                __builtin_prefetch(&lights->tex_uv[6 * (size_t)k[j]]);
        }
        for (uint32_t j = 0; j < m && lights->tex_uv; j++) {
            if (k[j] >= lights->count)
                continue;
            const light_entry *le = &lights->lights[k[j]];
            const pt_material *lm = &scene->materials[le->material];
            if (!textured(scene, lm))
                continue;
            pt_vec3 pos;
            float b1, b2, tuv[2];
            point_on(le, ut[j][1], ut[j][2], &pos, &b1, &b2);
            light_uv(lights, scene, lm, k[j], b1, b2, tuv);
            pt_texture_prefetch(&scene->textures[lm->emissive_tex], tuv[0], tuv[1]);
        }
        for (uint32_t j = 0; j < m; j++) {
            pt_light_sample *si = &s[idx[j]];
            memset(si, 0, sizeof *si);
            si->tri = UINT32_MAX;
            ok[idx[j]] = sample_tree_light(lights, scene, pt[j], ut[j], k[j], q[j], si);
        }
    }
}

PT_SIMD_CLONES
void pt_lights_sample_n(const pt_lights *lights, const pt_scene *scene, uint32_t n,
                        const pt_vec3 *p, const pt_vec3 *nrm, const float (*u)[3],
                        pt_light_sample *s, int *ok)
{
    if (lights && lights->tree) {
        sample_n_tree(lights, scene, n, p, nrm, u, s, ok);
        return;
    }
    if (!lights || lights->count == 0 || lights->solid_angle) {
        for (uint32_t i = 0; i < n; i++)
            ok[i] = pt_lights_sample(lights, scene, p[i], nrm[i], u[i], &s[i]);
        return;
    }
    /* The reads of the picks, asked for in two passes before the first
     * pick is made: the alias table's columns (their addresses need only
     * the numbers), then the entries they name and their texture
     * coordinates, so that these misses overlap across all n points. Only
     * where there are lights enough for the reads to miss: a few hundred
     * entries stay in the nearer caches. */
    for (uint32_t i = 0; i < n && lights->count > PREFETCH_LIGHTS; i++) {
        double r;
        __builtin_prefetch(&lights->alias[pick_column(lights, u[i][0], &r)]);
    }
    for (uint32_t i = 0; i < n && lights->count > PREFETCH_LIGHTS; i++) {
        uint32_t k = pick_index(lights, u[i][0]);
        __builtin_prefetch(&lights->lights[k]);
        if (lights->tex_uv)
            __builtin_prefetch(&lights->tex_uv[6 * (size_t)k]);
    }
    for (uint32_t k0 = 0; k0 < n; k0 += 8) {
        uint32_t m = n - k0 < 8 ? n - k0 : 8;
        const light_entry *les[8];
        float b1s[8], b2s[8];
        pt_vec3 ds[8];
        float d2[8], ndot[8], pmf_area[8];
        int32_t two_sided[8];
        for (uint32_t l = 0; l < 8; l++) {
            /* Lanes past n repeat the last point. */
            uint32_t i = k0 + (l < m ? l : m - 1);
            pt_light_sample *si = &s[k0 + l < n ? k0 + l : i];
            pt_vec3 pos;
            float b1, b2;
            const light_entry *le = pick_point(lights, u[i], &pos, &b1, &b2);
            pt_vec3 d = pt_v3_sub(pos, p[i]);
            if (l < m) {
                memset(si, 0, sizeof *si);
                si->tri = le->tri;
                si->position = pos;
                si->normal = le->normal;
            }
            les[l] = le;
            b1s[l] = b1;
            b2s[l] = b2;
            /* The emission's texels, asked for now so that the 8 lanes'
             * misses overlap while the pdfs are computed. */
            const pt_material *lm = &scene->materials[le->material];
            if (lights->tex_uv && lights->count > PREFETCH_LIGHTS && textured(scene, lm)) {
                float tuv[2];
                light_uv(lights, scene, lm, (uint32_t)(le - lights->lights), b1, b2, tuv);
                pt_texture_prefetch(&scene->textures[lm->emissive_tex], tuv[0], tuv[1]);
            }
            ds[l] = d;
            d2[l] = pt_v3_dot(d, d);
            ndot[l] = pt_v3_dot(le->normal, d);
            pmf_area[l] = le->pmf_area;
            two_sided[l] = scene->materials[le->material].double_sided ? -1 : 0;
        }
        v8f vd2, vndot, vpa, dist, inv, pdf;
        v8i vts, vok;
        memcpy(&vd2, d2, sizeof vd2);
        memcpy(&vndot, ndot, sizeof vndot);
        memcpy(&vpa, pmf_area, sizeof vpa);
        memcpy(&vts, two_sided, sizeof vts);
        pt_light_lanes_pdf(&vd2, &vndot, &vpa, &vts, &dist, &inv, &pdf, &vok);
        for (uint32_t l = 0; l < m; l++) {
            pt_light_sample *si = &s[k0 + l];
            const light_entry *le = les[l];
            ok[k0 + l] = 0;
            si->dist = dist[l];
            if (!(si->dist > 0.0f) || !isfinite(si->dist))
                continue;
            si->wi = pt_v3_scale(ds[l], inv[l]);
            si->pdf = pdf[l];
            if (!vok[l])
                continue;
            si->radiance = emission_at(lights, scene, le, b1s[l], b2s[l]);
            ok[k0 + l] = 1;
        }
    }
}

float pt_lights_punctual_pmf(const pt_lights *lights, uint32_t i, pt_vec3 p, pt_vec3 n)
{
    if (!lights || !lights->punct)
        return 0.0f;
    if (lights->tree)
        for (uint32_t j = 0; j < lights->ntree_punct; j++)
            if (lights->tree_punct[j] == i)
                return (float)(pt_light_tree_pmf(lights->tree, p, n, lights->count + j) *
                               lights->p_tri);
    return i < lights->npunct ? lights->punct_pmf[i] : 0.0f;
}

float pt_lights_pdf(const pt_lights *lights, const pt_scene *scene, uint32_t tri, pt_vec3 p,
                    pt_vec3 n, pt_vec3 hit, pt_vec3 n_light)
{
    if (!lights || lights->count == 0 || tri >= lights->num_triangles)
        return 0.0f;
    uint32_t k = lights->tri_to_light[tri];
    if (k == UINT32_MAX)
        return 0.0f;
    const light_entry *le = &lights->lights[k];
    const pt_material *m = &scene->materials[le->material];
    float pmf_area = le->pmf_area;
    if (lights->tree)
        pmf_area = tree_pmf_area(lights, le, pt_light_tree_pmf(lights->tree, p, n, k));
    double omega = sa_omega(lights, le, p);
    if (omega > 0.0) {
        /* sample_solid_angle's pdf, on the side it samples */
        if (!m->double_sided && !(pt_v3_dot(n_light, pt_v3_sub(hit, p)) < 0.0f))
            return 0.0f;
        float pdf = sa_pdf(le, pmf_area, omega);
        return pdf > 0.0f && isfinite(pdf) ? pdf : 0.0f;
    }
    return solid_angle_pdf(pmf_area, m->double_sided, p, hit, n_light);
}
