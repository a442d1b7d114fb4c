/*
 * bdpt_auto.c - whether --bdpt auto takes bidirectional path tracing (see
 * bdpt_auto.h).
 */
#include "common/render/bdpt_auto.h"

#include <math.h>
#include <stdlib.h>

#include "common/base/alloc.h"
#include "common/math/vec.h"
#include "common/render/light.h"
#include "common/render/render.h"
#include "common/render/sampler.h"
#include "common/scene/accel.h"

/* The sample sequence's seed (any fixed number: the answer must not depend
 * on the job's seed) and its dimensions. */
#define POCKET_SEED 0x62647074u
enum { DIM_PICK = 0, DIM_POINT = 1, DIM_DIR = 3, DIM_SIDE = 5, DIM_PROBE = 6 };

static void tri_corners(const pt_scene *s, uint32_t t, pt_vec3 v[3])
{
    for (int k = 0; k < 3; k++) {
        const float *p = &s->positions[3 * s->indices[3 * t + k]];
        v[k] = pt_v3(p[0], p[1], p[2]);
    }
}

/* The power a triangle emits (its front's radiance at the centroid times
 * its area, both sides when double-sided): an estimate used to choose, as
 * the light sampler's. */
static double tri_power(const pt_scene *s, uint32_t t, pt_vec3 *n)
{
    pt_vec3 v[3];
    tri_corners(s, t, v);
    pt_vec3 c = pt_v3_cross(pt_v3_sub(v[1], v[0]), pt_v3_sub(v[2], v[0]));
    float len = pt_v3_len(c);
    if (!(len > 0.0f) || !isfinite(len))
        return 0.0;
    *n = pt_v3_scale(c, 1.0f / len);
    const pt_material *m = &s->materials[s->tri_material[t]];
    double le = pt_luminance(pt_emitted(s, t, 1.0f / 3.0f, 1.0f / 3.0f, *n));
    double p = le * 0.5 * len * (m->double_sided ? 2.0 : 1.0);
    return isfinite(p) && p > 0.0 ? p : 0.0;
}

/* How open the point p (geometric normal n, on the side the light came
 * from) is: the share of PT_BDPT_AUTO_PROBES cosine directions that travel
 * farther than `near` before they meet a surface. */
static double openness(const pt_accel *a, pt_vec3 p, pt_vec3 n, float near, uint32_t photon)
{
    pt_frame f = pt_frame_from_normal(n);
    pt_vec3 o = pt_accel_offset_ray(a, p, n);
    uint32_t open = 0;
    for (uint32_t k = 0; k < PT_BDPT_AUTO_PROBES; k++) {
        float u[2];
        pt_sample_2d(POCKET_SEED, photon * PT_BDPT_AUTO_PROBES + k, DIM_PROBE, u);
        pt_vec3 d = pt_frame_to_world(&f, pt_sample_cosine_hemisphere(u[0], u[1]));
        open += !pt_accel_occluded(a, o, d, near);
    }
    return (double)open / PT_BDPT_AUTO_PROBES;
}

pt_status pt_bdpt_pocketed(const pt_scene *s, double *share, pt_error *err)
{
    *share = 0.0;
    const uint32_t nt = s->num_flat_triangles;
    double *cdf = pt_malloc_array(nt ? nt : 1u, sizeof *cdf);
    if (!cdf)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    double total = 0.0;
    for (uint32_t t = 0; t < nt; t++) {
        pt_vec3 n;
        cdf[t] = total += tri_power(s, t, &n);
    }
    if (!(total > 0.0)) {
        pt_free(cdf);
        return PT_OK;
    }
    pt_accel *a = NULL;
    pt_status st = pt_accel_new(s, &a, err);
    if (st != PT_OK) {
        pt_free(cdf);
        return st;
    }
    const pt_vec3 ext = pt_v3_sub(s->bounds_max, s->bounds_min);
    const float near = (float)(PT_BDPT_AUTO_NEAR * pt_v3_len(ext));
    double closed = 0.0;
    for (uint32_t i = 0; i < PT_BDPT_AUTO_PHOTONS; i++) {
        /* A triangle by power, a point uniform on it, a cosine direction
         * from a side it emits on. Every photon carries total / N. */
        double x = pt_sample_1d(POCKET_SEED, i, DIM_PICK) * total;
        uint32_t lo = 0, hi = nt - 1u;
        while (lo < hi) {
            uint32_t mid = lo + (hi - lo) / 2u;
            if (cdf[mid] > x)
                hi = mid;
            else
                lo = mid + 1u;
        }
        pt_vec3 v[3], n;
        if (!(tri_power(s, lo, &n) > 0.0))
            continue;
        tri_corners(s, lo, v);
        float u[2], w[2];
        pt_sample_2d(POCKET_SEED, i, DIM_POINT, u);
        float r = sqrtf(u[0]), b1 = r * (1.0f - u[1]), b2 = r * u[1];
        pt_vec3 p = pt_v3_add(v[0], pt_v3_add(pt_v3_scale(pt_v3_sub(v[1], v[0]), b1),
                                              pt_v3_scale(pt_v3_sub(v[2], v[0]), b2)));
        if (s->materials[s->tri_material[lo]].double_sided &&
            pt_sample_1d(POCKET_SEED, i, DIM_SIDE) < 0.5f)
            n = pt_v3_neg(n);
        pt_sample_2d(POCKET_SEED, i, DIM_DIR, w);
        pt_frame f = pt_frame_from_normal(n);
        pt_vec3 d = pt_frame_to_world(&f, pt_sample_cosine_hemisphere(w[0], w[1]));
        pt_hit hit;
        if (!pt_accel_intersect(a, pt_accel_offset_ray(a, p, n), d, INFINITY, &hit))
            continue; /* it leaves the scene: open */
        pt_vec3 y, ng;
        pt_accel_hit_point(s, &hit, &y, &ng);
        if (pt_v3_dot(ng, d) > 0.0f)
            ng = pt_v3_neg(ng);
        closed += 1.0 - openness(a, y, ng, near, i);
    }
    pt_accel_free(a);
    pt_free(cdf);
    *share = closed / PT_BDPT_AUTO_PHOTONS;
    return PT_OK;
}

pt_status pt_bdpt_auto(const pt_scene *s, int has_env, int guiding, int clamped, int *on,
                       double *share, pt_error *err)
{
    *on = 0;
    *share = -1.0;
    pt_error why;
    if (has_env || s->num_punctual > 0 || !(s->features & PT_FEAT_EMITTERS) ||
        pt_render_check_bdpt(s, has_env, guiding, clamped, &why) != PT_OK)
        return PT_OK;
    pt_status st = pt_bdpt_pocketed(s, share, err);
    *on = st == PT_OK && *share >= PT_BDPT_AUTO_SHARE;
    return st;
}
