/*
 * accel.c - ray queries through Embree 3.
 *
 * One RTCDevice and one RTCScene per pt_accel, with one triangle geometry.
 * The vertex and index data are copied into buffers that Embree allocates
 * (rtcSetNewGeometryBuffer): Embree reads vertices with 16-byte loads and so
 * needs the last vertex padded, which the scene's tightly packed arrays are
 * not. The scene is built in robust mode (watertight traversal; no triangle
 * is skipped through an edge or vertex crack) with high build quality: it is
 * built once per scene and then traced billions of times.
 *
 * Queries (rtcIntersect1 / rtcOccluded1 on a committed scene) are thread-safe.
 *
 * Alpha (PT_FEAT_ALPHA): only a scene with MASK or BLEND materials gets
 * Embree filter functions, so every other scene traverses exactly as before.
 * The filter is called for each candidate hit and rejects the ones where the
 * ray passes through the surface (pt_alpha_hit), and Embree goes on to the
 * next candidate. Every query passes an alpha_ctx, an RTCIntersectContext
 * with the scene and the pass-through key after it: the filter recovers it
 * from the context pointer it is given (Embree's documented way of passing
 * data to filters). The decision is a pure function of (key, triangle), so
 * the answer does not depend on the order in which Embree visits candidates
 * or on a triangle split into several BVH leaves being tested more than once.
 *
 * Motion blur (PT_FEAT_MOTION with moving triangles, common/scene/motion.h):
 * two geometries, the still triangles (id 0, one time step) and the moving
 * ones (id 1, the motion's K time steps, a vertex buffer per step), so that
 * still geometry keeps its ordinary BVH nodes. A hit's primID is then an
 * index into its geometry's list of scene triangles (map[geomID]). Queries
 * pass the ray's time in [0, 1] (the shutter's); Embree interpolates the
 * moving vertices linearly between the two steps around it. A scene without
 * moving triangles is built and queried exactly as before.
 *
 * Instancing (PT_FEAT_INSTANCES, EXT_mesh_gpu_instancing): geometry 0 holds
 * the flat triangles, and each prototype is a scene of its own (one
 * triangle geometry over its vertices, copied once) that instance
 * geometries 1 + i place by instance i's 3x4 (rtcNewGeometry
 * RTC_GEOMETRY_TYPE_INSTANCE): a mesh placed a million times is stored
 * once, with about 300 bytes an instance. A hit through instance i has
 * instID[0] = 1 + i (pt_hit.inst) and the prototype's primID; the
 * prototype's geometry carries its first triangle as user data, which the
 * alpha filter reads too. A scene without instances is built as before.
 */
#include "common/scene/accel.h"

#include <math.h>
#include <string.h>

#include <embree3/rtcore.h>

#include "common/base/alloc.h"
#include "common/scene/alpha.h"
#include "common/scene/motion.h"

/* Waechter & Binder's constants (RTG ch. 6), for a scene of about unit size. */
#define OFFSET_ORIGIN (1.0f / 32.0f)
#define OFFSET_FLOAT_SCALE (1.0f / 65536.0f)

struct pt_accel {
    RTCDevice device;
    RTCScene scene;
    float origin, float_scale; /* pt_accel_offset_ray's constants for this scene */
    const pt_scene *alpha;     /* the scene, when it has alpha filters; else NULL */
    uint8_t *solid;            /* with alpha: pt_alpha_solid_new's flags (whole MASK
                                  triangles, which the filter passes without a lookup) */
    int mapped;                /* map[geomID][primID] is the scene triangle: two
                                  geometries (still, moving) or a subset's one */
    const uint32_t *map[2];
    uint32_t nproto; /* instancing: the prototypes' scenes */
    RTCScene *protos;
    const pt_scene *scene_ref; /* instancing: the scene, for the prototypes' first triangles */
};

/* What a query passes to the alpha filter. rtc comes first: Embree hands the
 * filter the address of rtc, which is the address of the whole. */
typedef struct alpha_ctx {
    struct RTCIntersectContext rtc;
    const pt_scene *scene; /* NULL: the query ignores alpha */
    uint32_t key;
    const pt_accel *accel; /* for the triangle maps of a moving scene or a subset */
    /* pt_accel_transmittance_alpha: the product of 1 - alpha over the BLEND
     * triangles met so far (NULL: BLEND by the key, as for every other
     * query), and those triangles (with their instance), each counted once
     * however often Embree offers it (a triangle split into several leaves by
     * the high-quality build is tested once per leaf). */
    float *trans;
    /* pt_accel_intersect_layers: BLEND triangles are hits (the caller
     * chooses among them), but for those in seen, which the ray passed. */
    int layered;
    uint32_t nseen;
    uint32_t seen[PT_ACCEL_TRANS_MAX][2];
} alpha_ctx;

static int seen_before(const alpha_ctx *c, uint32_t tri, uint32_t inst)
{
    for (uint32_t k = 0; k < c->nseen; k++)
        if (c->seen[k][0] == tri && c->seen[k][1] == inst)
            return 1;
    return 0;
}

/* Field i of an RTCHitN of N hits: Embree's RTCHitN_u/v/primID, which its
 * header defines for C++ only. The layout is a structure of arrays of N
 * entries each: Ng.x, Ng.y, Ng.z, u, v, primID, ... (rtcore_ray.h). */
static inline float hitn_float(const struct RTCHitN *hit, unsigned n, unsigned field, unsigned i)
{
    float f;
    memcpy(&f, (const char *)hit + 4 * ((size_t)field * n + i), sizeof f);
    return f;
}

static inline uint32_t hitn_prim(const struct RTCHitN *hit, unsigned n, unsigned i)
{
    uint32_t v;
    memcpy(&v, (const char *)hit + 4 * ((size_t)5 * n + i), sizeof v);
    return v;
}

/* instID[0] of hit i (field 7), RTC_INVALID_GEOMETRY_ID outside an instance. */
static inline uint32_t hitn_inst(const struct RTCHitN *hit, unsigned n, unsigned i)
{
    uint32_t v;
    memcpy(&v, (const char *)hit + 4 * ((size_t)7 * n + i), sizeof v);
    return v;
}

/* A transmittance query's BLEND triangle tri (through instance inst) at
 * (b1, b2): 1 when the ray goes on past it, its 1 - alpha multiplied into
 * *c->trans once. 0 for a triangle that is not BLEND, one of alpha 1 (it
 * blocks), and a new one when PT_ACCEL_TRANS_MAX are counted already: the
 * caller decides those by the key (unbiased either way: each triangle is
 * either weighed by its transmittance or passed with that probability). */
static int blend_through(alpha_ctx *c, uint32_t tri, uint32_t inst, float b1, float b2)
{
    const pt_scene *s = c->scene;
    if (!pt_alpha_blend_tri(s, tri))
        return 0;
    float t = 1.0f - pt_alpha_coverage(s, tri, b1, b2);
    if (!(t > 0.0f) || c->nseen == PT_ACCEL_TRANS_MAX)
        return 0;
    c->seen[c->nseen][0] = tri;
    c->seen[c->nseen][1] = inst;
    c->nseen++;
    *c->trans *= t;
    return 1;
}

/* The intersection and occlusion filter of a scene with alpha materials:
 * drops the candidate hits that the ray passes through. */
static void alpha_filter(const struct RTCFilterFunctionNArguments *args)
{
    alpha_ctx *c = (alpha_ctx *)args->context;
    if (!c->scene)
        return;
    for (unsigned i = 0; i < args->N; i++) {
        if (args->valid[i] == 0)
            continue;
        uint32_t tri = hitn_prim(args->hit, args->N, i);
        if (args->geometryUserPtr) { /* a prototype's: its first triangle */
            tri += ((const pt_prototype *)args->geometryUserPtr)->first_tri;
        } else if (c->accel->mapped) {
            uint32_t gid;
            memcpy(&gid, (const char *)args->hit + 4 * ((size_t)6 * args->N + i), sizeof gid);
            tri = c->accel->map[gid][tri];
        }
        if (!pt_alpha_tri(c->scene, tri) || c->accel->solid[tri])
            continue;
        float b1 = hitn_float(args->hit, args->N, 3, i), b2 = hitn_float(args->hit, args->N, 4, i);
        uint32_t inst = hitn_inst(args->hit, args->N, i);
        if (c->nseen && seen_before(c, tri, inst)) {
            args->valid[i] = 0; /* counted, or passed, once already */
            continue;
        }
        if (c->trans && blend_through(c, tri, inst, b1, b2)) {
            args->valid[i] = 0;
            continue;
        }
        if (c->layered && pt_alpha_blend_tri(c->scene, tri))
            continue;
        if (!pt_alpha_hit(c->scene, tri, b1, b2, c->key))
            args->valid[i] = 0;
    }
}

/* Static text for an Embree error, and the status it maps to. */
static pt_status rtc_status(enum RTCError e, const char **msg)
{
    switch (e) {
    case RTC_ERROR_NONE:
        *msg = "no error";
        return PT_OK;
    case RTC_ERROR_OUT_OF_MEMORY:
        *msg = "out of memory";
        return PT_ERR_NOMEM;
    case RTC_ERROR_INVALID_ARGUMENT:
        *msg = "invalid argument";
        return PT_ERR_ARG;
    case RTC_ERROR_INVALID_OPERATION:
        *msg = "invalid operation";
        return PT_ERR_ARG;
    case RTC_ERROR_UNSUPPORTED_CPU:
        *msg = "unsupported CPU";
        return PT_ERR_LIMIT;
    case RTC_ERROR_CANCELLED:
        *msg = "build cancelled";
        return PT_ERR_LIMIT;
    case RTC_ERROR_UNKNOWN:
    default:
        *msg = "unknown error";
        return PT_ERR_LIMIT;
    }
}

/* Reports the device's pending error (if any) as a pt_error naming `step`. */
static pt_status check_device(RTCDevice device, const char *step, pt_error *err)
{
    const char *msg;
    enum RTCError e = rtcGetDeviceError(device);
    pt_status st = rtc_status(e, &msg);
    if (st != PT_OK)
        return pt_error_set(err, st, "embree: %s: %s", step, msg);
    return PT_OK;
}

/* Attaches a triangle geometry of nt triangles: triangle i is the scene's
 * sel[i] (sel NULL: i), its vertices indices[3 sel[i] ..] into nv vertices
 * of `steps` time steps, step k at pos + k * step_stride (floats). With
 * alpha materials it gets the filters. Its id is `id`. */
static pt_status add_geometry_to(pt_accel *a, RTCScene into, const pt_prototype *proto,
                                 const pt_scene *scene, unsigned id, uint32_t steps, uint32_t nv,
                                 const float *pos, size_t step_stride, uint32_t nt,
                                 const uint32_t *sel, const uint32_t *indices, pt_error *err);

static pt_status add_geometry(pt_accel *a, const pt_scene *scene, unsigned id, uint32_t steps,
                              uint32_t nv, const float *pos, size_t step_stride, uint32_t nt,
                              const uint32_t *sel, const uint32_t *indices, pt_error *err)
{
    return add_geometry_to(a, a->scene, NULL, scene, id, steps, nv, pos, step_stride, nt, sel,
                           indices, err);
}

/* add_geometry into the scene `into`; proto: the geometry is that
 * prototype's (its vertices from proto->first_vertex, its indices rebased,
 * proto its user data), else NULL. */
static pt_status add_geometry_to(pt_accel *a, RTCScene into, const pt_prototype *proto,
                                 const pt_scene *scene, unsigned id, uint32_t steps, uint32_t nv,
                                 const float *pos, size_t step_stride, uint32_t nt,
                                 const uint32_t *sel, const uint32_t *indices, pt_error *err)
{
    pt_status st;
    RTCGeometry g = rtcNewGeometry(a->device, RTC_GEOMETRY_TYPE_TRIANGLE);
    if ((st = check_device(a->device, "rtcNewGeometry", err)) != PT_OK)
        return st;
    rtcSetGeometryBuildQuality(g, RTC_BUILD_QUALITY_HIGH);
    if (steps > 1)
        rtcSetGeometryTimeStepCount(g, steps);
    uint32_t *ib = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                           3 * sizeof(uint32_t), nt);
    if (!ib && nt > 0)
        goto nomem;
    for (uint32_t k = 0; k < steps; k++) {
        float *vb = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, k, RTC_FORMAT_FLOAT3,
                                            3 * sizeof(float), nv);
        if (!vb && nv > 0)
            goto nomem;
        if (nv > 0)
            memcpy(vb, pos + step_stride * k, (size_t)nv * 3 * sizeof(float));
    }
    if (sel) {
        for (uint32_t i = 0; i < nt; i++)
            memcpy(ib + 3 * (size_t)i, indices + 3 * (size_t)sel[i], 3 * sizeof(uint32_t));
    } else if (proto) {
        for (size_t i = 0; i < 3 * (size_t)nt; i++)
            ib[i] = indices[i] - proto->first_vertex;
        rtcSetGeometryUserData(g, (void *)proto);
    } else if (nt > 0) {
        memcpy(ib, indices, (size_t)nt * 3 * sizeof(uint32_t));
    }
    if (scene->features & PT_FEAT_ALPHA) {
        if (!rtcGetDeviceProperty(a->device, RTC_DEVICE_PROPERTY_FILTER_FUNCTION_SUPPORTED)) {
            rtcReleaseGeometry(g);
            return pt_error_set(err, PT_ERR_LIMIT,
                                "embree: this build has no filter functions, which alpha "
                                "MASK and BLEND materials need");
        }
        rtcSetGeometryIntersectFilterFunction(g, alpha_filter);
        rtcSetGeometryOccludedFilterFunction(g, alpha_filter);
        a->alpha = scene;
    }
    rtcCommitGeometry(g);
    rtcAttachGeometryByID(into, g, id);
    rtcReleaseGeometry(g);
    return check_device(a->device, "geometry", err);
nomem:
    rtcReleaseGeometry(g);
    if ((st = check_device(a->device, "vertex/index buffers", err)) == PT_OK)
        st = pt_error_set(err, PT_ERR_NOMEM, "embree: vertex/index buffers: out of memory");
    return st;
}

/* The prototypes' scenes, and an instance geometry (id 1 + i) for each
 * instance i, in the top scene. */
static pt_status add_instances(pt_accel *a, const pt_scene *scene, pt_error *err)
{
    pt_status st;
    a->protos = pt_calloc(scene->num_prototypes, sizeof *a->protos);
    if (!a->protos)
        return pt_error_set(err, PT_ERR_NOMEM, "embree: out of memory for prototypes");
    a->nproto = scene->num_prototypes;
    a->scene_ref = scene;
    for (uint32_t i = 0; i < scene->num_prototypes; i++) {
        const pt_prototype *p = &scene->prototypes[i];
        a->protos[i] = rtcNewScene(a->device);
        if ((st = check_device(a->device, "rtcNewScene", err)) != PT_OK)
            return st;
        rtcSetSceneFlags(a->protos[i], RTC_SCENE_FLAG_ROBUST);
        rtcSetSceneBuildQuality(a->protos[i], RTC_BUILD_QUALITY_HIGH);
        if (p->num_tris > 0 &&
            (st = add_geometry_to(a, a->protos[i], p, scene, 0, 1, p->num_vertices,
                                  scene->positions + 3 * (size_t)p->first_vertex, 0, p->num_tris,
                                  NULL, scene->indices + 3 * (size_t)p->first_tri, err)) != PT_OK)
            return st;
        rtcCommitScene(a->protos[i]);
        if ((st = check_device(a->device, "rtcCommitScene (prototype)", err)) != PT_OK)
            return st;
    }
    for (uint32_t i = 0; i < scene->num_instances; i++) {
        const pt_instance *in = &scene->instances[i];
        RTCGeometry g = rtcNewGeometry(a->device, RTC_GEOMETRY_TYPE_INSTANCE);
        if ((st = check_device(a->device, "rtcNewGeometry (instance)", err)) != PT_OK)
            return st;
        rtcSetGeometryInstancedScene(g, a->protos[in->proto]);
        rtcSetGeometryTransform(g, 0, RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR, in->xf);
        rtcCommitGeometry(g);
        rtcAttachGeometryByID(a->scene, g, 1 + i);
        rtcReleaseGeometry(g);
        if ((st = check_device(a->device, "instance", err)) != PT_OK)
            return st;
    }
    return PT_OK;
}

static pt_status accel_begin(pt_accel **out, pt_error *err);
static pt_status accel_commit(pt_accel *a, const pt_scene *scene, pt_error *err);
static pt_status accel_done(pt_accel *a, const pt_scene *scene, pt_accel **out, pt_error *err);

pt_status pt_accel_new(const pt_scene *scene, pt_accel **out, pt_error *err)
{
    pt_status st;
    if (!scene || !out)
        return pt_error_set(err, PT_ERR_ARG, "pt_accel_new: NULL argument");
    if (scene->num_triangles > 0 && (!scene->positions || !scene->indices))
        return pt_error_set(err, PT_ERR_ARG, "pt_accel_new: scene has triangles but no arrays");

    pt_accel *a = NULL;
    if ((st = accel_begin(&a, err)) != PT_OK)
        goto fail;
    if (scene->motion && scene->motion->num_triangles > 0) {
        const pt_motion *m = scene->motion;
        a->mapped = 1;
        a->map[0] = m->static_tri;
        a->map[1] = m->tri;
        if (m->num_static > 0 &&
            (st = add_geometry(a, scene, 0, 1, scene->num_vertices, scene->positions, 0,
                               m->num_static, m->static_tri, scene->indices, err)) != PT_OK)
            goto fail;
        if ((st = add_geometry(a, scene, 1, m->steps, m->num_vertices, m->positions,
                               (size_t)m->num_vertices * 3, m->num_triangles, NULL, m->indices,
                               err)) != PT_OK)
            goto fail;
    } else if (scene->num_instances > 0) {
        if (scene->num_flat_triangles > 0 &&
            (st = add_geometry(a, scene, 0, 1, scene->num_flat_vertices, scene->positions, 0,
                               scene->num_flat_triangles, NULL, scene->indices, err)) != PT_OK)
            goto fail;
        if ((st = add_instances(a, scene, err)) != PT_OK)
            goto fail;
    } else if (scene->num_triangles > 0) {
        if ((st = add_geometry(a, scene, 0, 1, scene->num_vertices, scene->positions, 0,
                               scene->num_triangles, NULL, scene->indices, err)) != PT_OK)
            goto fail;
    }
    return accel_done(a, scene, out, err);

fail:
    pt_accel_free(a);
    return st;
}

pt_status pt_accel_new_subset(const pt_scene *scene, const uint32_t *sel, uint32_t n,
                              pt_accel **out, pt_error *err)
{
    pt_status st;
    if (!scene || !out || (n > 0 && !sel))
        return pt_error_set(err, PT_ERR_ARG, "pt_accel_new_subset: NULL argument");
    for (uint32_t i = 0; i < n; i++)
        if (sel[i] >= scene->num_triangles ||
            (scene->num_instances > 0 && sel[i] >= scene->num_flat_triangles) ||
            (scene->motion && scene->motion->num_triangles > 0))
            return pt_error_set(err, PT_ERR_ARG,
                                "pt_accel_new_subset: triangle %u is not a still flat one", sel[i]);
    pt_accel *a = NULL;
    if ((st = accel_begin(&a, err)) != PT_OK)
        goto fail;
    a->mapped = 1;
    a->map[0] = sel;
    uint32_t nv = scene->num_instances > 0 ? scene->num_flat_vertices : scene->num_vertices;
    if (n > 0 && (st = add_geometry(a, scene, 0, 1, nv, scene->positions, 0, n, sel, scene->indices,
                                    err)) != PT_OK)
        goto fail;
    return accel_done(a, scene, out, err);

fail:
    pt_accel_free(a);
    return st;
}

/* A new accel's device and empty scene, in *out (freed by the caller on an
 * error). */
static pt_status accel_begin(pt_accel **out, pt_error *err)
{
    pt_status st;
    pt_accel *a = *out = pt_calloc(1, sizeof *a);
    if (!a)
        return pt_error_set(err, PT_ERR_NOMEM, "pt_accel_new: out of memory");
    a->device = rtcNewDevice("");
    if (!a->device) {
        st = check_device(NULL, "rtcNewDevice", err);
        return st == PT_OK ? pt_error_set(err, PT_ERR_LIMIT, "embree: rtcNewDevice failed") : st;
    }
    a->scene = rtcNewScene(a->device);
    if ((st = check_device(a->device, "rtcNewScene", err)) != PT_OK)
        return st;
    rtcSetSceneFlags(a->scene, RTC_SCENE_FLAG_ROBUST);
    rtcSetSceneBuildQuality(a->scene, RTC_BUILD_QUALITY_HIGH);
    return PT_OK;
}

/* accel_commit, then a in *out, or freed on an error. */
static pt_status accel_done(pt_accel *a, const pt_scene *scene, pt_accel **out, pt_error *err)
{
    pt_status st = accel_commit(a, scene, err);
    if (st == PT_OK)
        *out = a;
    else
        pt_accel_free(a);
    return st;
}

/* Builds a's BVH over what was attached, and the offsets of scene's size. */
static pt_status accel_commit(pt_accel *a, const pt_scene *scene, pt_error *err)
{
    pt_status st;
    rtcCommitScene(a->scene);
    if (a->alpha && (st = pt_alpha_solid_new(a->alpha, &a->solid, err)) != PT_OK)
        return st;
    {
        /* The scene's coordinate magnitude, rounded up to a power of two so the
         * scaled constants are exact. */
        float m = fmaxf(pt_v3_max_comp(pt_v3(fabsf(scene->bounds_min.x), fabsf(scene->bounds_min.y),
                                             fabsf(scene->bounds_min.z))),
                        pt_v3_max_comp(pt_v3(fabsf(scene->bounds_max.x), fabsf(scene->bounds_max.y),
                                             fabsf(scene->bounds_max.z))));
        int e = 0;
        if (m > 0.0f && isfinite(m))
            frexpf(m, &e);
        a->origin = ldexpf(OFFSET_ORIGIN, e);
        a->float_scale = ldexpf(OFFSET_FLOAT_SCALE, e);
    }
    return check_device(a->device, "rtcCommitScene", err);
}

void pt_accel_free(pt_accel *accel)
{
    if (!accel)
        return;
    if (accel->scene)
        rtcReleaseScene(accel->scene);
    for (uint32_t i = 0; i < accel->nproto; i++)
        if (accel->protos[i])
            rtcReleaseScene(accel->protos[i]);
    pt_free(accel->protos);
    pt_free(accel->solid);
    if (accel->device)
        rtcReleaseDevice(accel->device);
    pt_free(accel);
}

static void init_ray(struct RTCRay *r, pt_vec3 o, pt_vec3 d, float tnear, float tfar, float time)
{
    r->org_x = o.x;
    r->org_y = o.y;
    r->org_z = o.z;
    r->tnear = tnear;
    r->dir_x = d.x;
    r->dir_y = d.y;
    r->dir_z = d.z;
    r->time = time;
    r->tfar = tfar;
    r->mask = 0xffffffffu;
    r->id = 0;
    r->flags = 0;
}

/* The closest hit in [tnear, tfar] under ctx (initialised). */
static inline int intersect_ctx(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tnear,
                                float tfar, float time, alpha_ctx *ctx, pt_hit *hit)
{
    hit->tri = UINT32_MAX;
    if (!(tfar > 0.0f))
        return 0;
    struct RTCRayHit rh;
    init_ray(&rh.ray, o, d, tnear, tfar, time);
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(accel->scene, &ctx->rtc, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID)
        return 0;
    hit->t = rh.ray.tfar;
    hit->b1 = rh.hit.u;
    hit->b2 = rh.hit.v;
    hit->inst = 0;
    if (rh.hit.instID[0] != RTC_INVALID_GEOMETRY_ID) {
        /* Through instance instID - 1 (add_instances): its prototype's
         * triangle. */
        const pt_scene *s = accel->scene_ref;
        hit->inst = rh.hit.instID[0];
        hit->tri = s->prototypes[s->instances[hit->inst - 1].proto].first_tri + rh.hit.primID;
        return 1;
    }
    hit->tri = accel->mapped ? accel->map[rh.hit.geomID][rh.hit.primID] : rh.hit.primID;
    return 1;
}

static void ctx_init(alpha_ctx *ctx, const pt_accel *accel, const pt_scene *scene, uint32_t key)
{
    rtcInitIntersectContext(&ctx->rtc);
    ctx->scene = scene;
    ctx->key = key;
    ctx->accel = accel;
    ctx->trans = NULL;
    ctx->layered = 0;
    ctx->nseen = 0;
}

/* The closest hit; scene NULL ignores alpha. Embree accepts hits with
 * tnear <= t <= tfar. tnear = 0: a hit at exactly t = 0 is a measure-zero
 * event once origins are offset (pt_offset_ray). */
static inline int intersect(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar, float time,
                            const pt_scene *scene, uint32_t key, pt_hit *hit)
{
    alpha_ctx ctx;
    ctx_init(&ctx, accel, scene, key);
    return intersect_ctx(accel, o, d, 0.0f, tfar, time, &ctx, hit);
}

int pt_accel_intersect_layers(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar, float time,
                              float u, uint32_t key, pt_hit *hit)
{
    const pt_scene *s = accel->alpha;
    alpha_ctx ctx;
    ctx_init(&ctx, accel, s, key);
    ctx.layered = s != NULL;
    float tnear = 0.0f;
    for (;;) {
        if (!intersect_ctx(accel, o, d, tnear, tfar, time, &ctx, hit))
            return 0;
        if (!ctx.layered || !pt_alpha_blend_tri(s, hit->tri))
            return 1;
        /* The layers in the order the ray meets them, each hit with
         * probability alpha given the ray came to it: u < alpha hits this
         * one, else (u - alpha) / (1 - alpha) is uniform again and chooses
         * among the rest (the inverse of the discrete distribution of the
         * layer the ray stops at, one layer at a time). */
        float a = pt_alpha_coverage(s, hit->tri, hit->b1, hit->b2);
        if (u < a)
            return 1;
        u = (u - a) / (1.0f - a);
        if (!(u < 1.0f))
            u = 0x1.fffffep-1f;
        ctx.seen[ctx.nseen][0] = hit->tri;
        ctx.seen[ctx.nseen][1] = hit->inst ? hit->inst : RTC_INVALID_GEOMETRY_ID;
        /* Past PT_ACCEL_TRANS_MAX layers the rest pass by the key. */
        if (++ctx.nseen == PT_ACCEL_TRANS_MAX)
            ctx.layered = 0;
        tnear = hit->t;
    }
}

int pt_accel_intersect(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar, pt_hit *hit)
{
    return intersect(accel, o, d, tfar, 0.0f, NULL, 0, hit);
}

int pt_accel_intersect_alpha(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar, uint32_t key,
                             pt_hit *hit)
{
    return intersect(accel, o, d, tfar, 0.0f, accel->alpha, key, hit);
}

/* nextafterf(t, 0) for t > 0 (finite or not), without the library call: a
 * positive float's successor towards zero is its bit pattern minus one. */
static inline float below(float t)
{
    uint32_t bits;
    memcpy(&bits, &t, sizeof bits);
    bits--;
    memcpy(&t, &bits, sizeof t);
    return t;
}

static inline int occluded(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar, float time,
                           const pt_scene *scene, uint32_t key, float *trans)
{
    if (!(tfar > 0.0f))
        return 0;
    alpha_ctx ctx;
    ctx_init(&ctx, accel, scene, key);
    ctx.trans = trans;
    struct RTCRay r;
    /* The contract is the half-open [0, tfar): the end point itself (a light
     * point the caller offset towards the shading point) must not occlude.
     * Embree's test is closed, so pass the next float below tfar: exactly the
     * open interval, not a hand-picked shortening. */
    init_ray(&r, o, d, 0.0f, below(tfar), time);
    rtcOccluded1(accel->scene, &ctx.rtc, &r);
    return r.tfar == -INFINITY;
}

int pt_accel_occluded(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar)
{
    return occluded(accel, o, d, tfar, 0.0f, NULL, 0, NULL);
}

int pt_accel_occluded_alpha(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar, uint32_t key)
{
    return occluded(accel, o, d, tfar, 0.0f, accel->alpha, key, NULL);
}

int pt_accel_intersect_time(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar, float time,
                            int alpha, uint32_t key, pt_hit *hit)
{
    return intersect(accel, o, d, tfar, time, alpha ? accel->alpha : NULL, key, hit);
}

int pt_accel_occluded_time(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar, float time,
                           int alpha, uint32_t key)
{
    return occluded(accel, o, d, tfar, time, alpha ? accel->alpha : NULL, key, NULL);
}

float pt_accel_transmittance_alpha(const pt_accel *accel, pt_vec3 o, pt_vec3 d, float tfar,
                                   uint32_t key)
{
    float t = 1.0f;
    if (occluded(accel, o, d, tfar, 0.0f, accel->alpha, key, &t))
        return 0.0f;
    return t;
}

const uint8_t *pt_accel_alpha_solid(const pt_accel *accel)
{
    return accel->solid;
}

pt_vec3 pt_accel_degenerate_normal(pt_vec3 n)
{
    /* In double: a cross product that overflowed in float still has a
     * direction; any unit vector beats a NaN when there is none. */
    double lx = n.x, ly = n.y, lz = n.z;
    double l = sqrt(lx * lx + ly * ly + lz * lz);
    if (l > 0.0 && isfinite(l))
        return pt_v3((float)(lx / l), (float)(ly / l), (float)(lz / l));
    return pt_v3(0.0f, 0.0f, 1.0f);
}

/* Waechter & Binder, "A Fast and Robust Method for Avoiding Self-Intersection",
 * Ray Tracing Gems (2019) ch. 6. Far from the origin each coordinate is moved
 * by an integer number of ULPs proportional to the normal's component
 * (int_scale ULPs for a unit component), so the offset grows with the
 * coordinate's own rounding error; near the origin, where ULPs get arbitrarily
 * small, a fixed absolute offset float_scale * n is used instead. The code is
 * pt_offset_coord in accel.h, inlined into the integrator. */

pt_vec3 pt_offset_ray(pt_vec3 p, pt_vec3 n)
{
    pt_offset off = {OFFSET_ORIGIN, OFFSET_FLOAT_SCALE};
    return pt_offset_apply(off, p, n);
}

pt_offset pt_accel_offset(const pt_accel *a)
{
    pt_offset off = {a->origin, a->float_scale};
    return off;
}

pt_vec3 pt_accel_offset_ray(const pt_accel *a, pt_vec3 p, pt_vec3 n)
{
    return pt_offset_apply(pt_accel_offset(a), p, n);
}
