/*
 * motion.h - what moves while the shutter is open: time steps of the moving
 * meshes' vertices and of the camera, for motion blur.
 *
 * Time is the shutter's: 0 when it opens, 1 when it closes. A moving mesh
 * has K >= 2 poses (time steps) evenly spaced over [0, 1], the same K for
 * every moving mesh of a scene (Embree's multi-segment motion blur,
 * rtcSetGeometryTimeStepCount); between two steps a vertex moves on the
 * straight line, as Embree intersects it. K = 2 is exact for a translation;
 * a rotation or a deformation needs more steps (their chord error shrinks as
 * 1/K^2: a rotation by angle a over the shutter is off its arc by at most
 * r (1 - cos(a / (2 (K - 1)))) with K - 1 segments).
 *
 * Only moving triangles (any of whose vertices differs between steps) have
 * steps; every other triangle stays single-step, so a scene pays for what
 * moves. A scene with nothing moving has no pt_motion (scene->motion is
 * NULL) and no PT_FEAT_MOTION: it renders as it did, bit for bit.
 *
 * The scene's own arrays (positions, normals) hold step 0 for the moving
 * vertices too; the renderer reads the steps for moving triangles only.
 * Positions are in scene space (world - scene->origin), as the scene's are.
 *
 * Immutable after the scene is built; any thread may read it.
 */
#ifndef PT_COMMON_SCENE_MOTION_H
#define PT_COMMON_SCENE_MOTION_H

#include <stdint.h>

#include "common/base/error.h"
#include "common/math/vec.h"
#include "common/scene/scene.h"

/* The most time steps a scene may have (a skinned mesh posed at a fine step
 * over a long shutter stays far under it). */
#define PT_MOTION_MAX_STEPS 64u

struct pt_motion {
    uint32_t steps;         /* K >= 2 for the moving meshes; 0 when only the camera moves */
    uint32_t num_vertices;  /* moving vertices (those of moving triangles) */
    uint32_t num_triangles; /* moving triangles */
    float *positions;       /* steps x num_vertices x 3 (step-major), scene space */
    float *normals;         /* steps x num_vertices x 3, unit length */
    uint32_t *tri;          /* per moving triangle: its index in the scene */
    uint32_t *indices;      /* 3 per moving triangle: indices into the moving vertices */
    uint32_t *moving;       /* per scene triangle: its index among the moving ones, or
                               UINT32_MAX for a still triangle */
    uint32_t num_static;    /* the scene's still triangles */
    uint32_t *static_tri;   /* their scene indices, increasing */
    uint32_t camera_steps;  /* 0: the camera is still; else >= 2 poses of scene->camera */
    pt_camera *cameras;     /* camera_steps poses, scene space, evenly spaced over [0, 1] */
};

/* The segment of time t in [0, 1] among n >= 2 evenly spaced steps: the
 * step before it in *i and the fraction past that step in *f, as Embree
 * splits a ray's time (t (n - 1), its integer part clamped to n - 2). */
static inline void pt_motion_segment(uint32_t n, float t, uint32_t *i, float *f)
{
    float x = t * (float)(n - 1);
    uint32_t k = x > 0.0f ? (uint32_t)x : 0u;
    if (k > n - 2)
        k = n - 2;
    *i = k;
    *f = x - (float)k;
}

/* Moving vertex v (an index into the moving vertices) at step i + f. */
static inline pt_vec3 pt_motion_position(const pt_motion *m, uint32_t v, uint32_t i, float f)
{
    const float *a = m->positions + 3 * ((size_t)i * m->num_vertices + v);
    const float *b = a + 3 * (size_t)m->num_vertices;
    return pt_v3((1.0f - f) * a[0] + f * b[0], (1.0f - f) * a[1] + f * b[1],
                 (1.0f - f) * a[2] + f * b[2]);
}

/* Its normal at step i + f, interpolated and not normalised. */
static inline pt_vec3 pt_motion_normal(const pt_motion *m, uint32_t v, uint32_t i, float f)
{
    const float *a = m->normals + 3 * ((size_t)i * m->num_vertices + v);
    const float *b = a + 3 * (size_t)m->num_vertices;
    return pt_v3((1.0f - f) * a[0] + f * b[0], (1.0f - f) * a[1] + f * b[1],
                 (1.0f - f) * a[2] + f * b[2]);
}

/* The camera at time t (m->camera_steps >= 2): the position on the straight
 * line between the two poses around t, the axes interpolated the same way
 * and made orthonormal again (forward, then right orthogonal to it, then up
 * = right x forward, which is how every pt_camera's axes relate). The
 * other fields are pose 0's: the field of view does not change within the
 * shutter. */
pt_camera pt_motion_camera(const pt_motion *m, float t);

typedef struct pt_anim pt_anim; /* common/scene/anim.h */

/* The most triangle-steps (the scene's triangles x its time steps) that
 * pt_motion_from_anim poses. Each step holds a pose of every vertex while
 * the steps are chosen and Embree a time segment of every moving triangle:
 * 8 M instanced triangles at 17 steps took ptworker from 1.3 GB (the still)
 * to 16.9 GB, about 115 bytes a triangle-step. Past the cap the steps stop
 * doubling and the blur follows a curved path by fewer, longer chords; two
 * steps (linear motion) stay within it for any scene under
 * PT_SCENE_MAX_TRIANGLES. */
#define PT_MOTION_MAX_TRIANGLE_STEPS (2ull * PT_SCENE_MAX_TRIANGLES)

/* Gives scene s (loaded by pt_anim_load with anim) motion blur over the
 * shutter [t0, t1] (seconds of animation): s is posed at t0 (its still),
 * then at time steps over the interval, as many as the motion's curvature
 * needs (motion_anim.c: 2 to 17) while the scene's triangles times the
 * steps stay within PT_MOTION_MAX_TRIANGLE_STEPS, and pt_scene_set_motion
 * and the camera's poses make of them what moves. Nothing when t1 <= t0 or
 * the rig cannot move. Errors as pt_anim_pose's and pt_scene_set_motion's.
 * pt_scene_load calls it for pt_scene_opts.shutter_open and _close. */
pt_status pt_motion_from_anim(pt_scene *s, const pt_anim *anim, double t0, double t1,
                              pt_error *err);
/* The same with max_triangle_steps for PT_MOTION_MAX_TRIANGLE_STEPS (tests
 * give a small cap to a small scene). */
pt_status pt_motion_from_anim_cap(pt_scene *s, const pt_anim *anim, double t0, double t1,
                                  uint64_t max_triangle_steps, pt_error *err);

/* Frees m and all it owns. Accepts NULL. */
void pt_motion_free(pt_motion *m);

/* ---- building (common/scene/scene.c calls these) -------------------------------------- */

typedef struct pt_motion_build pt_motion_build;

/* Records a mesh the builder has just added as vertices [v0, v0 + nv) and
 * triangles [t0, t0 + nt) (its indices: 3 * nt, into its own vertices, or
 * NULL for non-indexed), posed at `steps` times: positions[k] (3 * nv
 * floats, world space) for k < steps, normals[k] likewise or normals NULL
 * (each step's area-weighted, as the builder computes them). Checks steps in
 * [2, PT_MOTION_MAX_STEPS] and equal to earlier moving meshes' (PT_ERR_ARG),
 * and every value finite and under PT_SCENE_MAX_COORD (PT_ERR_FORMAT).
 * *bp is created on first use. */
pt_status pt_motion_build_add(pt_motion_build **bp, const char *what, uint32_t v0, uint32_t nv,
                              uint32_t t0, uint32_t nt, const uint32_t *indices, uint32_t steps,
                              const float *const *positions, const float *const *normals,
                              pt_error *err);

/* Finishes the scene's motion: each recorded mesh's steps scaled by sc,
 * translated by tr and moved to scene space (s->origin), as the builder
 * moves step 0; meshes whose steps are all equal are dropped (they do not
 * move). Where something moves, s->motion is set, s->bounds grown to hold
 * every step and PT_FEAT_MOTION set. Accepts b NULL (nothing moves). */
pt_status pt_motion_build_finish(pt_motion_build *b, pt_scene *s, double sc, const double tr[3],
                                 pt_error *err);
void pt_motion_build_free(pt_motion_build *b); /* accepts NULL */

/* Feeds the motion's data into a scene hash (an EVP_MD_CTX *), so that a
 * moving scene and its still are told apart. */
void pt_motion_hash(const pt_motion *m, void *evp_md_ctx);

/* Gives scene s motion from whole-scene poses: positions[k] and normals[k]
 * (3 per vertex each, scene space, in the scene's vertex order, as a
 * re-posing of the scene writes them) for k < steps, evenly spaced over the
 * shutter; the scene's own arrays must hold step 0. Vertices that differ
 * between steps (bit for bit) make their triangles move; all vertices of a
 * moving triangle get steps. Sets s->motion, grows the bounds and sets
 * PT_FEAT_MOTION when something moves; else leaves s as it was. Rejects
 * (PT_ERR_ARG) steps outside [2, PT_MOTION_MAX_STEPS], PT_ERR_FORMAT a
 * position that is not finite. Call before the renderer is made. */
pt_status pt_scene_set_motion(pt_scene *s, uint32_t steps, const float *const *positions,
                              const float *const *normals, pt_error *err);

/* Gives scene s's camera `steps` poses over the shutter (world space;
 * positions are moved to scene space). s->camera becomes pose 0 and the
 * camera moves when the poses differ: s->motion is created when needed and
 * PT_FEAT_MOTION set. Rejects (PT_ERR_ARG) steps outside [2,
 * PT_MOTION_MAX_STEPS], non-finite or non-unit axes. Call before the
 * renderer is made. */
pt_status pt_scene_set_camera_motion(pt_scene *s, uint32_t steps, const pt_camera *poses,
                                     pt_error *err);
/* The same with the poses in scene space (as a re-posing writes them). */
pt_status pt_scene_set_camera_motion_scene(pt_scene *s, uint32_t steps, const pt_camera *poses,
                                           pt_error *err);

#endif
