/*
 * motion_anim.c - motion blur's time steps from a glTF animation rig
 * (common/scene/anim.h): the scene posed at K times over the shutter.
 *
 * How many steps: a node's translation at constant speed is exact with two,
 * but a rotation, a skin or a cubic spline curves between keys, and Embree
 * moves a vertex on the straight line between two steps. The steps start at
 * the shutter's ends and are doubled (each segment split at its middle) while
 * the middle pose of some segment is further from the straight line than
 * PT_MOTION_TOLERANCE of the scene's extent (the bounds' diagonal), for a
 * vertex or the camera's position, or the camera's direction turns more than
 * PT_MOTION_TOLERANCE radians off it: 2, 3, 5, 9, 17 steps at most. A
 * vertex's chord error falls as 1/K^2 (motion.h), so a quarter turn over the
 * shutter needs 9 steps for 1e-3 (a half turn 17); what stays is under a
 * pixel of a 512-pixel view of the whole scene. The doubling also stops
 * before the scene's triangles times the steps would pass the cap
 * (PT_MOTION_MAX_TRIANGLE_STEPS, motion.h): each step costs a pose of every
 * vertex here and a time segment of every moving triangle in Embree.
 */
#include "common/scene/motion.h"

#include <math.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/scene/anim.h"

#define PT_MOTION_TOLERANCE 1e-3
#define AUTO_MAX_STEPS 17u

typedef struct pose {
    double t;
    float *pos, *nrm;
    pt_camera cam;
} pose;

static void pose_free(pose *p)
{
    pt_free(p->pos);
    pt_free(p->nrm);
    p->pos = p->nrm = NULL;
}

static pt_status pose_at(const pt_anim *anim, const pt_scene *s, double t, pose *out, pt_error *err)
{
    size_t n = 3 * (size_t)s->num_vertices;
    out->t = t;
    out->pos = pt_malloc_array(n ? n : 1, sizeof(float));
    out->nrm = pt_malloc_array(n ? n : 1, sizeof(float));
    if (!out->pos || !out->nrm) {
        pose_free(out);
        return pt_error_set(err, PT_ERR_NOMEM, "motion: out of memory for a pose");
    }
    out->cam = s->camera;
    pt_anim_pose_out o;
    memset(&o, 0, sizeof o);
    o.positions = out->pos;
    o.normals = out->nrm;
    o.camera = &out->cam;
    pt_status st = pt_anim_pose_into(anim, t, s, &o, err);
    if (st != PT_OK)
        pose_free(out);
    return st;
}

/* How far the middle pose m is from the straight line between a and b. */
static int off_line(const pose *a, const pose *m, const pose *b, size_t n, double tol)
{
    for (size_t i = 0; i < n; i++) {
        double mid = 0.5 * ((double)a->pos[i] + (double)b->pos[i]);
        if (fabs((double)m->pos[i] - mid) > tol)
            return 1;
    }
    pt_vec3 pa = a->cam.position, pb = b->cam.position, pm = m->cam.position;
    if (fabs(pm.x - 0.5 * ((double)pa.x + pb.x)) > tol ||
        fabs(pm.y - 0.5 * ((double)pa.y + pb.y)) > tol ||
        fabs(pm.z - 0.5 * ((double)pa.z + pb.z)) > tol)
        return 1;
    pt_vec3 f = pt_v3_norm(pt_v3_add(a->cam.forward, b->cam.forward));
    double c = pt_v3_dot(f, m->cam.forward);
    return c < cos(PT_MOTION_TOLERANCE);
}

pt_status pt_motion_from_anim(pt_scene *s, const pt_anim *anim, double t0, double t1, pt_error *err)
{
    return pt_motion_from_anim_cap(s, anim, t0, t1, PT_MOTION_MAX_TRIANGLE_STEPS, err);
}

pt_status pt_motion_from_anim_cap(pt_scene *s, const pt_anim *anim, double t0, double t1,
                                  uint64_t max_triangle_steps, pt_error *err)
{
    if (!(t1 > t0) || !pt_anim_moves(anim))
        return PT_OK;
    pt_status st = pt_anim_pose(anim, t0, s, err); /* the still: step 0 */
    if (st != PT_OK)
        return st;
    pt_vec3 ext = pt_v3_sub(s->bounds_max, s->bounds_min);
    double tol = PT_MOTION_TOLERANCE * fmax((double)pt_v3_len(ext), 1e-30);
    size_t n = 3 * (size_t)s->num_vertices;
    pose p[AUTO_MAX_STEPS], mid[AUTO_MAX_STEPS];
    memset(p, 0, sizeof p);
    memset(mid, 0, sizeof mid);
    uint32_t k = 2;
    if ((st = pose_at(anim, s, t0, &p[0], err)) != PT_OK ||
        (st = pose_at(anim, s, t1, &p[1], err)) != PT_OK)
        goto done;
    while (2 * k - 1 <= AUTO_MAX_STEPS &&
           (uint64_t)s->num_triangles * (2 * k - 1) <= max_triangle_steps) {
        int split = 0;
        for (uint32_t i = 0; i + 1 < k; i++) {
            if ((st = pose_at(anim, s, 0.5 * (p[i].t + p[i + 1].t), &mid[i], err)) != PT_OK)
                goto done;
            split |= off_line(&p[i], &mid[i], &p[i + 1], n, tol);
        }
        if (!split)
            break;
        /* Interleave: p0 m0 p1 m1 ... p(k-1), from the end so nothing is
         * overwritten before it moves. */
        for (uint32_t i = k; i-- > 0;) {
            p[2 * i] = p[i];
            if (i + 1 < k) {
                p[2 * i + 1] = mid[i];
                memset(&mid[i], 0, sizeof mid[i]);
            }
        }
        k = 2 * k - 1;
    }
    const float *pos[AUTO_MAX_STEPS], *nrm[AUTO_MAX_STEPS];
    pt_camera cams[AUTO_MAX_STEPS];
    for (uint32_t i = 0; i < k; i++) {
        pos[i] = p[i].pos;
        nrm[i] = p[i].nrm;
        cams[i] = p[i].cam;
    }
    if ((st = pt_scene_set_motion(s, k, pos, nrm, err)) != PT_OK)
        goto done;
    st = pt_scene_set_camera_motion_scene(s, k, cams, err);
done:
    for (uint32_t i = 0; i < AUTO_MAX_STEPS; i++) {
        pose_free(&p[i]);
        pose_free(&mid[i]);
    }
    return st;
}
