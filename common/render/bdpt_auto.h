/*
 * bdpt_auto.h - whether bidirectional path tracing should render a scene
 * whose user did not say (--bdpt auto, the default).
 *
 * Unidirectional path tracing with NEE finds the light an emitter sends
 * straight onto what the camera sees; it finds light that first lands in a
 * pocket (the gap between a lamp and the ceiling, the inside of a fitting)
 * and leaves it through a slit only by the directions that happen to aim
 * into the slit, as rare bright samples. A light path starts in the pocket
 * and is joined to every camera vertex it can see, which is what pays on
 * the NVIDIA Cornell box (docs/bench/bdpt.md): 2.04 times less CPU to the
 * same error, while on the repository's Cornell box, lit straight down, it
 * costs 2.2 times more, on a room lit through a window by a map 2.2 times
 * more, and off chrome in the sun it has no chains.
 *
 * So `auto` takes bdpt only where the scene can take it
 * (pt_render_check_bdpt), is lit by its emissive triangles alone (no map,
 * no background, no punctual light: the cases measured to lose or not
 * measured), and where at least PT_BDPT_AUTO_SHARE of the emitters' power
 * first lands in a pocket. A pocket point is one most of whose
 * cosine-distributed directions meet a surface within PT_BDPT_AUTO_NEAR of
 * the scene's bounding-box diagonal (every triangle counts as opaque here,
 * MASK and BLEND ones too: an estimate used to choose, never to weigh). The
 * share is estimated from a fixed set of photons (Sobol numbers of a fixed
 * seed: the same scene gives the same answer on every machine that traces
 * it alike), and it is a function of the
 * scene alone, not of the camera, the resolution or the split, so the
 * coordinator decides once for a job and a standalone render decides the
 * same.
 */
#ifndef PT_COMMON_RENDER_BDPT_AUTO_H
#define PT_COMMON_RENDER_BDPT_AUTO_H

#include "common/base/error.h"
#include "common/scene/scene.h"

/* --bdpt: auto (the default: pt_bdpt_auto decides), on, off. */
enum { PT_BDPT_AUTO = 0, PT_BDPT_ON = 1, PT_BDPT_OFF = 2 };

#define PT_BDPT_AUTO_PHOTONS 2048u /* photons the share is estimated from */
#define PT_BDPT_AUTO_PROBES 16u    /* directions that measure how open a landing point is */
#define PT_BDPT_AUTO_NEAR 0.05     /* "near": this fraction of the bounds' diagonal */
#define PT_BDPT_AUTO_SHARE 0.25    /* the pocketed share of power that turns bdpt on */

/* What every program says when auto turns bdpt on (a printf format of the
 * share in per cent). */
#define PT_BDPT_AUTO_ON                                                                            \
    "--bdpt auto: on (%.0f %% of the emitters' light first lands in a pocket; --bdpt=off to "      \
    "render without)"

/* The share in [0, 1] of the power of scene's emissive triangles whose
 * first landing is in a pocket (above); 0 for a scene without emitters.
 * PT_OK, or an error building the ray queries. */
pt_status pt_bdpt_pocketed(const pt_scene *scene, double *share, pt_error *err);

/* *on = 1 when `auto` renders scene with bdpt: it is lit by emitters only
 * (has_env 0, no punctual light), pt_render_check_bdpt takes it (guiding,
 * clamped: as the job has them) and pt_bdpt_pocketed reaches
 * PT_BDPT_AUTO_SHARE. *share gets the share measured (-1 when the other
 * conditions already said no). PT_OK, or pt_bdpt_pocketed's error. */
pt_status pt_bdpt_auto(const pt_scene *scene, int has_env, int guiding, int clamped, int *on,
                       double *share, pt_error *err);

/* What a render does with --bdpt's mode (PT_BDPT_*), decided where the
 * coordinator admits a job: on: *on = 1 when pt_render_check_bdpt takes
 * the scene, else its error; off: *on = 0; auto: pt_bdpt_auto's answer.
 * *share as pt_bdpt_auto gives it (-1 unless auto measured it). */
pt_status pt_bdpt_resolve(const pt_scene *scene, int mode, int has_env, int guiding, int clamped,
                          int *on, double *share, pt_error *err);

#endif
