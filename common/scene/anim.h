/*
 * anim.h - glTF animation: a scene's rig, posed at any time without
 * reparsing the file.
 *
 * pt_anim_load loads a scene as pt_scene_load does and keeps its rig: the
 * node hierarchy with each node's local TRS (or matrix), the animations
 * (channels on translation, rotation, scale and morph weights; samplers
 * STEP, LINEAR with spherical linear rotations, CUBICSPLINE), the skins
 * (joints, inverse bind matrices) and, for every mesh instance the scene
 * holds, its rest vertex data in mesh space (POSITION, NORMAL, TANGENT,
 * JOINTS_0/1, WEIGHTS_0/1, morph targets' POSITION, NORMAL and TANGENT
 * deltas, default weights). pt_anim_pose then poses that rig at a time t
 * (seconds) and writes the world-space result in the scene's own layout.
 *
 * What a pose computes (glTF 2.0, 3.11 "Animations", 3.7.3 "Skins", 3.7.2.2
 * "Morph Targets"):
 * - every channel of the chosen animation(s) (pt_scene_opts.animation: NULL
 *   or "" plays the first, "all" every channel of every animation, in the
 *   file's order, so a later channel on the same property wins) sets its
 *   node's property to its
 *   sampler's value at t; a time before a sampler's first key gives the first
 *   value, after its last key the last (no looping);
 * - a node's local matrix is T * R * S; its global matrix parent * local;
 * - a morphed vertex is rest + sum_k weight_k * delta_k (the node's weights,
 *   else the mesh's, as animated);
 * - a skinned vertex is sum_i w_i * jointMatrix_i * v with jointMatrix =
 *   global(joint) * inverseBindMatrix; the skinned mesh node's own transform
 *   is ignored, as the spec says; normals go through the inverse transpose,
 *   tangents through the matrix itself;
 * - other mesh instances go through their node's global matrix;
 * - cameras and KHR_lights_punctual lights follow their nodes' global
 *   matrices (position, axes); the rendered camera (scene->camera) follows
 *   when it is one of the file's cameras (a framed camera stays where the
 *   load framed it; the renderer frames it again from the posed bounds).
 * Only what can move is computed: instances under a node whose TRS a chosen
 * channel animates (or under such an ancestor), skinned and morphed
 * instances, cameras and lights under animated nodes. Everything else keeps
 * the values of the load (a still's), bit for bit.
 * Then opts' scale and translation are applied (in double) and positions are
 * stored relative to scene->origin, which the load fixed: a pose never
 * changes origin. Bounds are recomputed from the stored positions. Normals of
 * primitives without NORMAL are recomputed (area-weighted) from the posed
 * positions; generated tangents are regenerated (tangent.h).
 *
 * Topology never changes between poses: the number of vertices and
 * triangles, the indices (winding included: a transform that turns mirroring
 * during an animation keeps the winding of the load), the materials, the
 * UVs, colours and the set of cameras and lights are those of the load. Only
 * positions, normals, tangents, bounds, camera and light placements move.
 * So an accelerator may be refitted (Embree's rtcCommitScene after updating
 * its vertex buffer) rather than rebuilt, and motion-blur time steps may
 * share one index buffer.
 *
 * A pose is a pure function of (rig, t): pt_anim_pose at t gives bit for
 * bit the scene that pt_scene_load gives with animate 1 and time t (the load
 * is the rest build followed by this very pose), whatever was posed before.
 *
 * Threads: a pt_anim is immutable after load; any number of threads may pose
 * it at once, each into its own output (a pose allocates its own scratch).
 */
#ifndef PT_COMMON_SCENE_ANIM_H
#define PT_COMMON_SCENE_ANIM_H

#include "common/base/error.h"
#include "common/base/frames.h"
#include "common/scene/scene.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct pt_anim pt_anim;

/* Caps on what a file may ask for (PT_ERR_LIMIT past them). */
#define PT_ANIM_MAX_KEYS (1u << 24)    /* keyframes in one sampler */
#define PT_ANIM_MAX_JOINTS (1u << 16)  /* joints in one skin */
#define PT_ANIM_MAX_TARGETS (1u << 10) /* morph targets in one mesh */
/* Morph target deltas the rig keeps, a vertex and a target each, every
 * instance of a mesh counted (the rig holds each instance's rest data, up
 * to 36 bytes a delta): checked before anything is built, as the scene's
 * triangles are. 64 Mi: 100 instances of a 10k-vertex face with 64
 * targets. A 3 MB file of 200 instances of a 999-vertex mesh with 256
 * targets took an animated load from 38 MB to 640 MB. */
#define PT_ANIM_MAX_MORPH_DELTAS (64ull << 20)

/* Loads path as pt_scene_load does with opts (opts->animate is ignored: the
 * scene comes back posed at opts->time, which must be finite and >= 0) and
 * returns its rig in *anim. opts->animation chooses the animation (NULL or
 * "": the first; "all"; a name; or a decimal index); unknown is PT_ERR_ARG listing the
 * file's animations. A malformed animation, skin or morph target is
 * PT_ERR_FORMAT naming the element ("animation 0 ('Walk') sampler 2: input
 * times are not increasing at key 7"). On failure nothing is returned and
 * nothing leaks. A file without animations, skins or morph targets gives an
 * empty rig whose every pose is the still: the load reads nothing more and
 * gives the bits of a still's load, and a pose leaves the scene as it is. */
pt_status pt_anim_load(const char *path, const pt_scene_opts *opts, pt_scene **scene,
                       pt_anim **anim, pt_error *err);

/* Poses scene (which must be the one pt_anim_load returned with anim, or a
 * copy with the same arrays) at time t seconds, in place: positions,
 * normals, tangents, bounds, cameras, scene->camera (see above) and punctual
 * lights. t must be finite and >= 0 (else PT_ERR_ARG). A pose whose
 * positions, cameras or lights are not finite or over PT_SCENE_MAX_COORD at t
 * (a hostile scale) is PT_ERR_FORMAT; on any failure the scene is untouched.
 * A scene a renderer or an accelerator is using must not be posed under it. */
pt_status pt_anim_pose(const pt_anim *anim, double t, pt_scene *scene, pt_error *err);

/* The output of a pose into caller-owned arrays, for holding several times
 * at once (motion-blur time steps): arrays sized as the scene's
 * (positions 3 per vertex, normals 3, tangents 4 or NULL when the scene has
 * none, cameras num_cameras, punctual num_punctual; any output may be NULL
 * to skip it). */
typedef struct pt_anim_pose_out {
    float *positions;
    float *normals;
    float *tangents;
    pt_camera *cameras;
    pt_camera *camera; /* the rendered camera, updated as scene->camera is */
    pt_punctual *punctual;
    pt_vec3 bounds_min, bounds_max; /* written always */
} pt_anim_pose_out;

/* Poses at time t into out, reading scene (built by pt_anim_load with anim)
 * for what a pose keeps (indices, UVs, materials, origin, cameras' and
 * lights' other fields); scene is not written. Same checks as pt_anim_pose. */
pt_status pt_anim_pose_into(const pt_anim *anim, double t, const pt_scene *scene,
                            pt_anim_pose_out *out, pt_error *err);

/* The time range of the chosen animation(s): the first and last key of
 * their samplers (0, 0 when there is no animation). */
void pt_anim_range(const pt_anim *anim, double *start, double *end);

/* Whether a pose can differ from another: some channel, skin or morph target
 * is in play. 0: every pose is the same as the load's. */
int pt_anim_moves(const pt_anim *anim);

/* The view a frame range is rendered from when the scene has no camera of
 * its own (scene->camera.framed): pt_camera_frame of the union of the
 * bounds posed at every frame's time (pt_frames_time(number, fps)), for an
 * image of `aspect`, as placement text (pt_camera_look_text_fit, in the
 * coordinates opts' scale and translation apply to) into out, so that
 * every frame is seen from one place and nothing that moves leaves the
 * frame. out[0] is 0 when the camera is the file's, nothing moves or the
 * range is one frame: each frame's own framing is then that view already. scene and opts are
 * those pt_anim_load took and gave with anim. A pose's error, or
 * PT_ERR_ARG when the text does not fit in cap. */
pt_status pt_anim_range_view(const pt_anim *anim, const pt_scene *scene, const pt_scene_opts *opts,
                             const pt_frames *frames, double fps, float aspect, char *out,
                             size_t cap, pt_error *err);

/* Frees the rig. Accepts NULL. */
void pt_anim_free(pt_anim *anim);

#ifdef __cplusplus
}
#endif

#endif
