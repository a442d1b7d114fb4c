/*
 * light.h - the lights of next-event estimation: emissive triangles and
 * punctual lights (scene.h, pt_punctual), and the environment (env.h).
 *
 * Every triangle whose material emits (emissive factor > 0 and, with an
 * emissive texture, some non-black texel under its UV footprint) becomes a
 * light. Lights are chosen in proportion to power (area x luminance of the
 * emission, with the emissive texture's mean over the triangle's footprint)
 * through an alias table (Walker 1977 / Vose 1991), or, from
 * PT_LIGHT_TREE_MIN to PT_LIGHT_TREE_AUTO_MAX lights (triangles, point and
 * spot lights together) spread over PT_LIGHT_TREE_MIN_SPREAD of the scene, by
 * a light tree (light_tree.h) in proportion to an estimate of what each gives
 * the shading point (power, distance and orientation bounds, and the side of
 * the receiver's tangent plane it lies on); then a point is
 * sampled uniformly by area and the pdf converted to solid angle:
 * pdf_w = pdf_A * d^2 / |cos theta_light|. pt_lights_pdf gives the same
 * number for a BSDF ray that hits the light (the tree's pmf recomputed for it).
 * With fewer lights the tree is not built and every sample keeps the bits of
 * the alias table.
 * Single-sided emitters emit on the side of their geometric normal (counter-
 * clockwise winding); double-sided ones on both sides.
 *
 * Punctual lights and the environment join the same choice: one number picks
 * the class (triangles, punctual lights, environment) by the classes' total
 * power, then the light within it by its own power (the environment: a
 * direction by its map's distribution, env.h), so each light is chosen in
 * proportion to its estimated power (light.c says how it is estimated).
 * With a tree, the first class is the tree's (triangles, point and spot
 * lights) and the punctual class keeps the directional lights. A
 * punctual sample is a delta: its pdf is the probability of choosing it, and
 * BSDF sampling never finds it, so it takes no MIS weight; an environment
 * sample is weighed by MIS like a triangle's. A scene with triangles alone
 * does not draw the class: its samples are the bits they were before.
 * Immutable after pt_lights_new; thread-safe for reading.
 */
#ifndef PT_COMMON_RENDER_LIGHT_H
#define PT_COMMON_RENDER_LIGHT_H

#include <stdint.h>

#include "common/base/error.h"
#include "common/math/vec.h"
#include "common/scene/scene.h"

typedef struct pt_lights pt_lights;

enum { PT_LIGHT_AREA = 0, PT_LIGHT_AT = 1, PT_LIGHT_FAR = 2, PT_LIGHT_ENV = 3 };

typedef struct pt_env pt_env; /* common/render/env.h */

/* How the triangles' class chooses a triangle: PT_LIGHT_SELECT_AUTO, the
 * light tree from PT_LIGHT_TREE_MIN to PT_LIGHT_TREE_AUTO_MAX lights spread
 * over PT_LIGHT_TREE_MIN_SPREAD of the scene or more (otherwise it costs
 * more than it saves; the samples then keep the bits of the alias table);
 * _POWER, the alias table by power always; _TREE, the tree from 2 on. */
enum { PT_LIGHT_SELECT_AUTO = 0, PT_LIGHT_SELECT_POWER = 1, PT_LIGHT_SELECT_TREE = 2 };
#define PT_LIGHT_TREE_MIN 16u
/* ... and up to PT_LIGHT_TREE_AUTO_MAX: past it _AUTO chooses by power.
 * Measured (tests/bench/light_tree.sh, time to equal relMSE, power/tree,
 * CPU, with the receiver's normal in the tree): EmissiveStrengthTest's 60
 * lights 3.31x faster with the tree, but DamagedHelmet's 370 textured ones
 * 0.78x, ToyCar's 2,720 0.86x and StainedGlassLamp's 16,704 0.87x: there
 * the walk costs more than the better choice saves. */
#define PT_LIGHT_TREE_AUTO_MAX 256u
/* ... and only when the lights spread over at least this share of the scene
 * (the diagonal of the box around them over the scene's): lights gathered
 * in one small place (a panel cut into many triangles) look alike from
 * every shading point, and the walk costs more than its choice saves.
 * Measured (tests/bench/light_tree.sh, CPU): a Cornell box whose ceiling
 * light is 128 triangles, spread 0.17, 0.77x with the tree against power;
 * EmissiveStrengthTest's five cubes, spread 0.68, 3.31x. */
#define PT_LIGHT_TREE_MIN_SPREAD (1.0 / 3.0)
/* Or'd into select: a triangle seen under at least 1.5 sr is sampled by solid
 * angle (Arvo 1995, sphtri.h) instead of area, where that pays (a large
 * light close to the shading point); pt_lights_pdf follows. Not for the
 * SIMD lanes of light_lanes.h, which compute area sampling's pdf. Off by
 * default: on the NVIDIA CornellBox its tests cost 5 % for 2 % less
 * relMSE. */
#define PT_LIGHT_SOLID_ANGLE 0x100u

typedef struct pt_light_sample {
    pt_vec3 position; /* on the light */
    pt_vec3 normal;   /* geometric normal of the light triangle */
    pt_vec3 wi;       /* unit direction from the shading point to position */
    float dist;       /* distance to position */
    pt_vec3 radiance; /* emitted radiance towards the shading point (0 if back side) */
    float pdf;        /* solid-angle pdf (including the choice of triangle); 0 = impossible;
                         for a punctual light the probability of choosing it */
    uint32_t tri;     /* triangle index in the scene; UINT32_MAX for a punctual light */
    int delta;        /* PT_LIGHT_AREA; a punctual light: PT_LIGHT_AT (at position,
                         radiance is the irradiance it gives facing it) or PT_LIGHT_FAR
                         (directional: dist infinite, radiance is its irradiance); or
                         PT_LIGHT_ENV (the environment along wi: dist infinite, radiance
                         and a solid-angle pdf, weighed by MIS) */
    /* PT_LIGHT_AT and PT_LIGHT_FAR: the light (else not set) */
    const pt_punctual *punct;
} pt_light_sample;

/* The intensity (W/sr, per colour) point or spot light l sends towards a
 * point at distance dist along -wi (wi: the unit direction from there to
 * the light), with its range's window and its spot's cone, as a light
 * sample weighs it (without the 1 / dist^2). */
pt_vec3 pt_punctual_intensity(const pt_punctual *l, pt_vec3 wi, float dist);

/* The window of l's range at distance dist: 1 - (dist / range)^4 within
 * it, 0 past it, 1 without a range; the factor pt_punctual_intensity and
 * a light sample take for it. */
float pt_punctual_range_window(const pt_punctual *l, float dist);

/* Builds the light list. A scene without emitters gives a valid, empty set. */
pt_status pt_lights_new(const pt_scene *scene, pt_lights **out, pt_error *err);
/* The same with an environment (may be NULL) as a third class, sampled by
 * its distribution env_dist (env.h: PT_ENV_MIS when NEE is weighed against
 * BSDF sampling, PT_ENV_FULL when it runs alone); it must outlive the set. */
pt_status pt_lights_new_env(const pt_scene *scene, const pt_env *env, int env_dist, pt_lights **out,
                            pt_error *err);
/* The same choosing among triangles as select (PT_LIGHT_SELECT_*) says. */
pt_status pt_lights_new_select(const pt_scene *scene, const pt_env *env, int env_dist,
                               uint32_t select, pt_lights **out, pt_error *err);
void pt_lights_free(pt_lights *lights); /* accepts NULL */
/* 1 when a light tree chooses the triangle. */
int pt_lights_has_tree(const pt_lights *lights);

/* Emissive triangles that can be chosen / punctual lights. */
uint32_t pt_lights_count(const pt_lights *lights);
uint32_t pt_lights_punctual_count(const pt_lights *lights);
/* 1 when the environment can be chosen. */
int pt_lights_has_env(const pt_lights *lights);
/* The solid-angle pdf with which pt_lights_sample gives direction dir of the
 * environment to a receiver at p with normal n (pt_lights_sample's; the
 * environment's split bounds by n too, env.h, and the scene's portals by
 * both, portal.h), its class's share included; 0 without one. */
float pt_lights_env_pdf(const pt_lights *lights, pt_vec3 dir, pt_vec3 p, pt_vec3 n);
/* 1 when the environment is sampled through the scene's portals as well. */
int pt_lights_has_portals(const pt_lights *lights);

/* Samples a light point seen from p. n: the receiver's unit normal on the
 * side it reflects light to, or a zero vector for a receiver that scatters
 * to both sides; a light tree gives no probability to lights wholly below
 * that side's tangent plane (the alias table ignores n). u: 3 numbers in
 * [0,1) (u[0] picks the triangle, u[1..2] the point). Returns 0 when there
 * are no lights or the sample is impossible (then s->pdf is 0). */
int pt_lights_sample(const pt_lights *lights, const pt_scene *scene, pt_vec3 p, pt_vec3 n,
                     const float u[3], pt_light_sample *s);

/* pt_lights_sample(lights, scene, p[i], nrm[i], u[i], &s[i]) into ok[i] for
 * i < n, the same bits, computed a few points at a time in SIMD lanes.
 * Triangles only: not for a set with punctual lights. */
void pt_lights_sample_n(const pt_lights *lights, const pt_scene *scene, uint32_t n,
                        const pt_vec3 *p, const pt_vec3 *nrm, const float (*u)[3],
                        pt_light_sample *s, int *ok);

/* The probability with which pt_lights_sample chooses the scene's punctual
 * light i for a receiver at p with normal n (as pt_lights_sample takes
 * them: by the light tree where it holds the light); 0 when it never does. */
float pt_lights_punctual_pmf(const pt_lights *lights, uint32_t i, pt_vec3 p, pt_vec3 n);

/* Solid-angle pdf that pt_lights_sample would give for reaching point `hit` on
 * triangle `tri` (normal n_light) from p with receiver normal n (the same n
 * NEE was given there: MIS needs the same function); 0 when tri is not a
 * light. */
float pt_lights_pdf(const pt_lights *lights, const pt_scene *scene, uint32_t tri, pt_vec3 p,
                    pt_vec3 n, pt_vec3 hit, pt_vec3 n_light);

/* Emitted radiance of triangle tri at barycentrics (b1, b2) towards direction
 * w_out (unit, away from the light); 0 on the back of a single-sided emitter. */
pt_vec3 pt_emitted(const pt_scene *scene, uint32_t tri, float b1, float b2, pt_vec3 w_out);

/* The emissive triangles by power, where light paths start (bidirectional
 * path tracing, render.c; --bdpt auto's photons, bdpt_auto.c): each one's
 * area times the luminance of its emission at the centroid, twice that
 * when double-sided; those of no power left out. */
typedef struct pt_emitters {
    uint32_t n;    /* triangles of positive power */
    uint32_t *tri; /* their indices in the scene, ascending */
    double *cdf;   /* the running sum of their power */
} pt_emitters;

pt_status pt_emitters_init(pt_emitters *e, const pt_scene *scene, pt_error *err);
void pt_emitters_fini(pt_emitters *e); /* accepts a zeroed table */

/* Their power together. */
static inline double pt_emitters_total(const pt_emitters *e)
{
    return e->n ? e->cdf[e->n - 1] : 0.0;
}

/* The entry (an index into e->tri) whose share of the running sum holds x,
 * for x in [0, total): a triangle by power. e->n must be at least 1. */
uint32_t pt_emitters_pick(const pt_emitters *e, double x);

/* Where a light path leaves an emissive triangle (geometric normal ng,
 * double_sided as its material): barycentrics uniform in area by u[0..1]
 * into *b1, *b2, and a direction by the cosine about the side it leaves
 * from, by u[2..3] (of a double-sided one, the side by u[2]'s half, which is
 * then rescaled); that side's normal into *side. Returns the direction. */
pt_vec3 pt_emitter_start(pt_vec3 ng, int double_sided, const float u[4], float *b1, float *b2,
                         pt_vec3 *side);

#endif
