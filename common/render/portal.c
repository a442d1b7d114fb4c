#include "common/render/portal.h"

#include <math.h>
#include <stdio.h>

#include "common/base/alloc.h"
#include "common/render/sampler.h"
#include "common/render/sphtri.h"
#include "common/scene/accel.h"
#include "common/scene/motion.h"
#include "common/scene/scene.h"

static inline pt_vec3 corner(const float *t, int k)
{
    return pt_v3(t[3 * k], t[3 * k + 1], t[3 * k + 2]);
}

/* Whether triangle t, its front towards `front`, counts for a receiver at
 * p with normal nrm (portal.h): p on its front side (the room's), and some
 * corner above p's plane. */
static inline int counts(const float *t, const float *front, pt_vec3 p, pt_vec3 nrm)
{
    if (!(pt_v3_dot(pt_v3_sub(p, corner(t, 0)), pt_v3(front[0], front[1], front[2])) > 0.0f))
        return 0;
    if (nrm.x == 0.0f && nrm.y == 0.0f && nrm.z == 0.0f)
        return 1;
    for (int k = 0; k < 3; k++)
        if (!(pt_v3_dot(pt_v3_sub(corner(t, k), p), nrm) <= 0.0f))
            return 1;
    return 0; /* every corner on or below the plane */
}

void pt_portal_view_init(pt_portal_view *v, const float *tris, const float *fronts, uint32_t n,
                         pt_vec3 p, pt_vec3 nrm)
{
    v->tris = tris;
    v->fronts = fronts;
    v->n = n < PT_SCENE_MAX_PORTALS ? n : PT_SCENE_MAX_PORTALS;
    v->p = p;
    v->counted = 0;
    v->measured = 0;
    for (uint32_t i = 0; i < v->n; i++)
        if (counts(tris + 9 * (size_t)i, fronts + 3 * (size_t)i, p, nrm))
            v->counted |= UINT64_C(1) << i;
}

void pt_portal_measure(pt_portal_view *v)
{
    if (v->measured)
        return;
    v->measured = 1;
    v->sum = 0.0;
    for (uint32_t i = 0; i < v->n; i++) {
        const float *t = v->tris + 9 * (size_t)i;
        v->om[i] = (v->counted >> i & 1u)
                       ? pt_sphtri_solid_angle(v->p, corner(t, 0), corner(t, 1), corner(t, 2))
                       : 0.0;
        v->sum += v->om[i];
    }
}

/* Whether the ray from p along d crosses triangle t (either side). With
 * a, b, c the corners less p, d = (alpha a + beta b + gamma c) / t for the
 * point where the ray meets the plane when alpha, beta and gamma, each
 * det(...) / det(a, b, c) by Cramer's rule, are all >= 0: three triple
 * products of the same sign as det(a, b, c), no division. */
static int crosses(const float *t, pt_vec3 p, pt_vec3 d)
{
    pt_vec3 a = pt_v3_sub(corner(t, 0), p), b = pt_v3_sub(corner(t, 1), p),
            c = pt_v3_sub(corner(t, 2), p);
    pt_vec3 bc = pt_v3_cross(b, c);
    float det = pt_v3_dot(a, bc);
    float al = pt_v3_dot(d, bc), be = pt_v3_dot(a, pt_v3_cross(d, c)),
          ga = pt_v3_dot(a, pt_v3_cross(b, d));
    if (det < 0.0f) {
        det = -det;
        al = -al;
        be = -be;
        ga = -ga;
    }
    return det > 0.0f && al >= 0.0f && be >= 0.0f && ga >= 0.0f && al + be + ga > 0.0f;
}

/* How many counted triangles other than `skip` the ray crosses. */
static uint32_t crossings(const pt_portal_view *v, pt_vec3 d, uint32_t skip)
{
    uint32_t k = 0;
    for (uint32_t i = 0; i < v->n; i++)
        k += i != skip && (v->counted >> i & 1u) && crosses(v->tris + 9 * (size_t)i, v->p, d);
    return k;
}

int pt_portal_sample(pt_portal_view *v, float u0, float u1, float u2, pt_vec3 *wi, double *pdf)
{
    if (!v->counted)
        return 0;
    pt_portal_measure(v);
    if (!(v->sum > 0.0) || !isfinite(v->sum))
        return 0;
    /* The triangle whose share of the sum holds u0; the last counted one
     * past the rounding of the running sum. */
    double x = (double)u0 * v->sum, run = 0.0;
    uint32_t pick = UINT32_MAX;
    for (uint32_t i = 0; i < v->n; i++) {
        if (!(v->om[i] > 0.0))
            continue;
        pick = i;
        run += v->om[i];
        if (x < run)
            break;
    }
    const float *t = v->tris + 9 * (size_t)pick;
    if (!pt_sphtri_sample_omega(v->p, corner(t, 0), corner(t, 1), corner(t, 2), v->om[pick], u1, u2,
                                wi))
        return 0;
    *pdf = (double)(1u + crossings(v, *wi, pick)) / v->sum;
    return 1;
}

double pt_portal_pdf(pt_portal_view *v, pt_vec3 dir)
{
    uint32_t k = v->counted ? crossings(v, dir, UINT32_MAX) : 0u;
    if (k == 0)
        return 0.0;
    pt_portal_measure(v);
    return v->sum > 0.0 ? (double)k / v->sum : 0.0;
}

/* ---- which way a portal faces ------------------------------------------------ */

#define PROBE_SEED 0x706f7274u /* "port" */

pt_status pt_portal_openness(const pt_scene *s, float *open, pt_error *err)
{
    if (s->num_portals == 0)
        return PT_OK;
    /* Every triangle but glass's (an accel over a subset is of still flat
     * triangles only, so a scene of instances or of moving triangles keeps
     * them all). */
    uint32_t *sel = NULL, nsel = 0;
    pt_accel *a = NULL;
    pt_status st;
    if ((s->features & PT_FEAT_INSTANCES) || (s->motion && s->motion->num_triangles > 0)) {
        st = pt_accel_new(s, &a, err);
    } else {
        if (!(sel = pt_malloc_array(s->num_triangles ? s->num_triangles : 1, sizeof *sel)))
            return pt_error_set(err, PT_ERR_NOMEM, "portal check: out of memory");
        for (uint32_t t = 0; t < s->num_triangles; t++)
            if (!(s->materials[s->tri_material[t]].transmission > 0.0f))
                sel[nsel++] = t;
        st = pt_accel_new_subset(s, sel, nsel, &a, err);
    }
    for (uint32_t i = 0; st == PT_OK && i < s->num_portals; i++) {
        const float *t = s->portals + 9 * (size_t)i, *f = s->portal_fronts + 3 * (size_t)i;
        pt_vec3 c = pt_v3_scale(pt_v3_add(pt_v3_add(corner(t, 0), corner(t, 1)), corner(t, 2)),
                                1.0f / 3.0f);
        for (int side = 0; side < 2; side++) {
            pt_vec3 n = pt_v3(f[0], f[1], f[2]);
            if (side)
                n = pt_v3_neg(n);
            pt_frame fr = pt_frame_from_normal(n);
            pt_vec3 o = pt_accel_offset_ray(a, c, n);
            uint32_t out = 0;
            for (uint32_t k = 0; k < PT_PORTAL_PROBES; k++) {
                float u[2];
                pt_sample_2d(PROBE_SEED, k, 0, u);
                pt_vec3 d = pt_frame_to_world(&fr, pt_sample_cosine_hemisphere(u[0], u[1]));
                out += !pt_accel_occluded(a, o, d, INFINITY);
            }
            open[2 * (size_t)i + (size_t)side] = (float)out / (float)PT_PORTAL_PROBES;
        }
    }
    pt_accel_free(a);
    pt_free(sel);
    return st;
}

pt_status pt_portal_reversed(const pt_scene *s, uint32_t *n, pt_vec3 *front, pt_error *err)
{
    *n = 0;
    *front = pt_v3(0.0f, 0.0f, 0.0f);
    if (s->num_portals == 0)
        return PT_OK;
    float *open = pt_malloc_array(2 * (size_t)s->num_portals, sizeof *open);
    if (!open)
        return pt_error_set(err, PT_ERR_NOMEM, "portal check: out of memory");
    pt_status st = pt_portal_openness(s, open, err);
    for (uint32_t i = 0; st == PT_OK && i < s->num_portals; i++)
        if (open[2 * i] >= open[2 * i + 1] + PT_PORTAL_REVERSED_GAP) {
            if ((*n)++ == 0) {
                const float *f = s->portal_fronts + 3 * (size_t)i;
                *front = pt_v3(f[0], f[1], f[2]);
            }
        }
    pt_free(open);
    return st;
}

int pt_portal_check_text(const pt_scene *s, char *out, size_t cap)
{
    uint32_t n = 0;
    pt_vec3 f;
    pt_error err = {0};
    out[0] = '\0';
    if (pt_portal_reversed(s, &n, &f, &err) != PT_OK) {
        snprintf(out, cap, "the portals' directions were not checked: %s", err.msg);
        return -1;
    }
    if (n == 0)
        return 0;
    snprintf(out, cap,
             "warning: %u of %u portal triangles look wound the wrong way: their front sees the "
             "outdoors and their back a room (the first faces (%.3g, %.3g, %.3g)); a portal's "
             "front (its counter-clockwise side) must face into the room, or the map is not "
             "sampled through it",
             n, s->num_portals, (double)f.x, (double)f.y, (double)f.z);
    return 1;
}
