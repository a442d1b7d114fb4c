/*
 * env.h - the environment light: radiance from every direction that leaves
 * the scene, from an equirectangular map (common/image/envmap.h) or one
 * uniform colour, with importance sampling for next-event estimation.
 *
 * Orientation (glTF is +Y up and defines none for maps): row 0 of the map is
 * straight up (+Y), the last row straight down; the map's centre column is
 * the -Z direction, the one a glTF camera looks along by default, and u grows
 * towards +X, so a view down -Z shows the map's middle the right way round.
 * rotate_deg turns the environment about +Y (positive: counter-clockwise
 * seen from above, as a glTF node's rotation about Y would). In terms of the
 * polar angle theta from +Y and phi = atan2(x, -z):
 *     u = 1/2 + (phi - rotate) / (2 pi)  (wrapped to [0, 1)),  v = theta / pi.
 *
 * Radiance is the map's bilinear lookup under the direction (texel centres
 * at ((x + 0.5) / w, (y + 0.5) / h), u wrapping, v clamped at the poles)
 * times strength; NEE and a BSDF-sampled ray that leaves the scene read the
 * same lookup. Sampling is a 2-D distribution over (u, v), a marginal over
 * rows and a conditional per row (Pharr, Jakob & Humphreys, "Physically
 * Based Rendering", 3rd ed., 13.6.7 and 14.2.4), over the cells between
 * four texel centres (the lookup's own cells; half-height ones at the
 * poles): in each, the density is the bilinear interpolant of a value per
 * texel times sin(theta) at the cell's centre row, sampled exactly within
 * the cell (a linear marginal, then a linear conditional). Its solid-angle
 * pdf is pdf(u, v) / (2 pi^2 sin theta). With the texel's luminance as that
 * value (PT_ENV_FULL) the density is the lookup's luminance itself, but for
 * sin(theta) across a cell's height, so a light sample's luminance over its
 * pdf is nearly constant: a tiny hot sun (66 % of a map's energy in 52
 * texels, its bilinear spread over their neighbours' cells) is found by NEE
 * with its share of the samples, each weighed alike. PT_ENV_MIS takes the
 * texel's luminance less the sphere's mean luminance, 0 where that is
 * negative (MIS compensation, Karlik et al. 2019): for NEE combined with
 * BSDF sampling by MIS, which finds the dim rest.
 *
 * The receiver's side: a map with a sun (texels brighter than 16 times the
 * sphere's mean luminance, within a cone of half-angle under 29 degrees
 * once their bilinear support is allowed for, holding 20 % or more of the
 * full distribution's weight) is split at load into the sun and the rest.
 * A receiver whose tangent plane (normal n) has the whole cone below it
 * samples, and weighs by MIS, the rest alone (the rest's distributions:
 * the map with the sun's texels at 0, and its MIS compensation by the
 * rest's own mean), where the sun's samples would have added nothing; any
 * other receiver, or a zero n (one that transmits, or no bound), samples
 * the whole map as without the split: each part's selection probability
 * is its power on the receiver's side bounded by the cone (0 or all), so
 * the mixture is the unsplit distribution itself. The compensated
 * distribution splits only when half or more of the compensated rest's
 * weight lies on the far side of the sky from the sun (where a receiver
 * that hides the sun can see it; not so in the park map, whose
 * compensated rest is its sunlit haze and ground). A map without such a
 * sun has no split and samples the same whatever n.
 *
 * A uniform colour (--background) is a 64 x 32 map of that colour, whose
 * density, luminance x sin(theta), is close to uniform over the sphere.
 *
 * Immutable after creation; any number of render threads may read it.
 */
#ifndef PT_COMMON_RENDER_ENV_H
#define PT_COMMON_RENDER_ENV_H

#include <stdint.h>

#include "common/base/error.h"
#include "common/image/envmap.h"
#include "common/math/vec.h"

typedef struct pt_env pt_env;

/* Builds the environment from a map (copied; the caller keeps map).
 * strength: a finite factor >= 0; rotate_deg: finite. */
pt_status pt_env_new(const pt_envmap *map, float strength, float rotate_deg, pt_env **out,
                     pt_error *err);
/* Reads the map at path (pt_envmap_read) and builds the environment from
 * it, as pt_env_new does; the map itself is not kept. */
pt_status pt_env_load(const char *path, float strength, float rotate_deg, pt_env **out,
                      pt_error *err);
/* A uniform environment of radiance color (each component finite, >= 0). */
pt_status pt_env_uniform(pt_vec3 color, pt_env **out, pt_error *err);
void pt_env_free(pt_env *env); /* accepts NULL */

/* Radiance arriving from direction dir (unit), i.e. seen looking along dir. */
pt_vec3 pt_env_eval(const pt_env *env, pt_vec3 dir);

/* The sampling distributions (above). */
enum { PT_ENV_FULL = 0, PT_ENV_MIS = 1 };

/* Samples a direction by distribution `which` (PT_ENV_*) from u (2 numbers
 * in [0,1)) for a receiver with normal n (unit, on the side it takes light
 * from; zero: no bound): *dir, the radiance from it (pt_env_eval's) and the
 * solid-angle pdf. Returns 0 when the distribution is black or the sample
 * is impossible (pdf 0). NEE at a receiver samples by it, and the MIS weight
 * of a BSDF-sampled ray from there that leaves the scene takes pt_env_pdf
 * with the same n. */
int pt_env_sample(const pt_env *env, const float u[2], int which, pt_vec3 n, pt_vec3 *dir,
                  pt_vec3 *radiance, float *pdf);

/* The solid-angle pdf pt_env_sample with `which` and n gives dir. */
float pt_env_pdf(const pt_env *env, pt_vec3 dir, int which, pt_vec3 n);

/* 1 when distribution `which` is split into a sun and the rest (above):
 * the receiver's normal changes its sampling. */
int pt_env_splits(const pt_env *env, int which);

/* 1 when the map has a sun by the split's rule (above): its cone's axis
 * (unit, towards the sun) into *axis and the sine of its half-angle (its
 * texels' bilinear support included) into *sin_half; 0 without one. */
int pt_env_sun(const pt_env *env, pt_vec3 *axis, float *sin_half);

/* The mean radiance over the sphere (luminance, weighted by solid angle):
 * the flux it sends into a sphere of radius R is 4 pi^2 R^2 times this. */
double pt_env_mean_luminance(const pt_env *env);

#endif
