/*
 * bdpt_auto.c - whether --bdpt auto takes bidirectional path tracing (see
 * bdpt_auto.h).
 */
#include "common/render/bdpt_auto.h"

#include <math.h>

#include "common/math/vec.h"
#include "common/render/light.h"
#include "common/render/render.h"
#include "common/render/sampler.h"
#include "common/scene/accel.h"

/* The sample sequence's seed (any fixed number: the answer must not depend
 * on the job's seed) and its dimensions: a photon's emitter, its start
 * (pt_emitter_start's four numbers), its probes. */
#define POCKET_SEED 0x62647074u
enum { DIM_PICK = 0, DIM_START = 1, DIM_PROBE = 5 };

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
    /* The photons start as bidirectional path tracing's light paths do. */
    pt_emitters em;
    pt_status st = pt_emitters_init(&em, s, err);
    if (st != PT_OK || em.n == 0) {
        pt_emitters_fini(&em);
        return st;
    }
    pt_accel *a = NULL;
    if ((st = pt_accel_new(s, &a, err)) != PT_OK) {
        pt_emitters_fini(&em);
        return st;
    }
    const double total = pt_emitters_total(&em);
    const pt_vec3 ext = pt_v3_sub(s->bounds_max, s->bounds_min);
    const float near = (float)(PT_BDPT_AUTO_NEAR * pt_v3_len(ext));
    double closed = 0.0;
    for (uint32_t i = 0; i < PT_BDPT_AUTO_PHOTONS; i++) {
        /* Every photon carries total / N. */
        uint32_t tri =
            em.tri[pt_emitters_pick(&em, pt_sample_1d(POCKET_SEED, i, DIM_PICK) * total)];
        float u[4];
        pt_sample_2d(POCKET_SEED, i, DIM_START, u);
        pt_sample_2d(POCKET_SEED, i, DIM_START + 2, u + 2);
        pt_hit h = {0.0f, 0.0f, 0.0f, tri, 0};
        pt_vec3 p, ng, side;
        pt_accel_hit_point(s, &h, &p, &ng);
        pt_vec3 d = pt_emitter_start(ng, s->materials[s->tri_material[tri]].double_sided, u, &h.b1,
                                     &h.b2, &side);
        pt_accel_hit_point(s, &h, &p, &ng);
        pt_hit hit;
        if (!pt_accel_intersect(a, pt_accel_offset_ray(a, p, side), d, INFINITY, &hit))
            continue; /* it leaves the scene: open */
        pt_vec3 y;
        pt_accel_hit_point(s, &hit, &y, &ng);
        if (pt_v3_dot(ng, d) > 0.0f)
            ng = pt_v3_neg(ng);
        closed += 1.0 - openness(a, y, ng, near, i);
    }
    pt_accel_free(a);
    pt_emitters_fini(&em);
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

pt_status pt_bdpt_resolve(const pt_scene *s, int mode, int has_env, int guiding, int clamped,
                          int *on, double *share, pt_error *err)
{
    *on = 0;
    *share = -1.0;
    if (mode == PT_BDPT_AUTO)
        return pt_bdpt_auto(s, has_env, guiding, clamped, on, share, err);
    if (mode != PT_BDPT_ON)
        return PT_OK;
    pt_status st = pt_render_check_bdpt(s, has_env, guiding, clamped, err);
    *on = st == PT_OK;
    return st;
}
