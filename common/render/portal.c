#include "common/render/portal.h"

#include <math.h>

#include "common/render/sphtri.h"
#include "common/scene/scene.h"

static inline pt_vec3 corner(const float *t, int k)
{
    return pt_v3(t[3 * k], t[3 * k + 1], t[3 * k + 2]);
}

/* Whether triangle t counts for a receiver at p with normal nrm (portal.h). */
static inline int counts(const float *t, pt_vec3 p, pt_vec3 nrm)
{
    if (nrm.x == 0.0f && nrm.y == 0.0f && nrm.z == 0.0f)
        return 1;
    for (int k = 0; k < 3; k++)
        if (!(pt_v3_dot(pt_v3_sub(corner(t, k), p), nrm) <= 0.0f))
            return 1;
    return 0; /* every corner on or below the plane */
}

void pt_portal_view_init(pt_portal_view *v, const float *tris, uint32_t n, pt_vec3 p, pt_vec3 nrm)
{
    v->sum = 0.0;
    for (uint32_t i = 0; i < n && i < PT_SCENE_MAX_PORTALS; i++) {
        const float *t = tris + 9 * (size_t)i;
        v->om[i] = counts(t, p, nrm)
                       ? pt_sphtri_solid_angle(p, corner(t, 0), corner(t, 1), corner(t, 2))
                       : 0.0;
        v->sum += v->om[i];
    }
}

/* Whether the ray from p along d crosses triangle t (either side; Moller
 * and Trumbore 1997, in double). */
static int crosses(const float *t, pt_vec3 p, pt_vec3 d)
{
    double a[3], e1[3], e2[3], o[3], dd[3] = {d.x, d.y, d.z}, pp[3] = {p.x, p.y, p.z};
    for (int r = 0; r < 3; r++) {
        a[r] = t[r];
        e1[r] = (double)t[3 + r] - a[r];
        e2[r] = (double)t[6 + r] - a[r];
        o[r] = pp[r] - a[r];
    }
    double q[3] = {dd[1] * e2[2] - dd[2] * e2[1], dd[2] * e2[0] - dd[0] * e2[2],
                   dd[0] * e2[1] - dd[1] * e2[0]};
    double det = e1[0] * q[0] + e1[1] * q[1] + e1[2] * q[2];
    if (det == 0.0 || !isfinite(det))
        return 0;
    double inv = 1.0 / det;
    double u = (o[0] * q[0] + o[1] * q[1] + o[2] * q[2]) * inv;
    if (!(u >= 0.0 && u <= 1.0))
        return 0;
    double s[3] = {o[1] * e1[2] - o[2] * e1[1], o[2] * e1[0] - o[0] * e1[2],
                   o[0] * e1[1] - o[1] * e1[0]};
    double v = (dd[0] * s[0] + dd[1] * s[1] + dd[2] * s[2]) * inv;
    if (!(v >= 0.0 && u + v <= 1.0))
        return 0;
    double dist = (e2[0] * s[0] + e2[1] * s[1] + e2[2] * s[2]) * inv;
    return dist > 0.0;
}

/* How many counted triangles other than `skip` the ray crosses. */
static uint32_t crossings(const pt_portal_view *v, const float *tris, uint32_t n, pt_vec3 p,
                          pt_vec3 d, uint32_t skip)
{
    uint32_t k = 0;
    for (uint32_t i = 0; i < n && i < PT_SCENE_MAX_PORTALS; i++)
        k += i != skip && v->om[i] > 0.0 && crosses(tris + 9 * (size_t)i, p, d);
    return k;
}

int pt_portal_sample(const pt_portal_view *v, const float *tris, uint32_t n, pt_vec3 p, float u0,
                     float u1, float u2, pt_vec3 *wi, double *pdf)
{
    if (!(v->sum > 0.0) || !isfinite(v->sum))
        return 0;
    /* The triangle whose share of the sum holds u0; the last counted one
     * past the rounding of the running sum. */
    double x = (double)u0 * v->sum, run = 0.0;
    uint32_t pick = UINT32_MAX;
    for (uint32_t i = 0; i < n && i < PT_SCENE_MAX_PORTALS; i++) {
        if (!(v->om[i] > 0.0))
            continue;
        pick = i;
        run += v->om[i];
        if (x < run)
            break;
    }
    const float *t = tris + 9 * (size_t)pick;
    double omega;
    if (!pt_sphtri_sample(p, corner(t, 0), corner(t, 1), corner(t, 2), u1, u2, wi, &omega))
        return 0;
    *pdf = (double)(1u + crossings(v, tris, n, p, *wi, pick)) / v->sum;
    return 1;
}

uint32_t pt_portal_crossings(const pt_portal_view *v, const float *tris, uint32_t n, pt_vec3 p,
                             pt_vec3 dir)
{
    return crossings(v, tris, n, p, dir, UINT32_MAX);
}

double pt_portal_pdf(const pt_portal_view *v, const float *tris, uint32_t n, pt_vec3 p, pt_vec3 dir)
{
    if (!(v->sum > 0.0))
        return 0.0;
    return (double)crossings(v, tris, n, p, dir, UINT32_MAX) / v->sum;
}
