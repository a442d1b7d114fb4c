/*
 * passes.h - render passes (AOVs): their names, the EXR layers they become
 * and the per-pixel resolve of their sums.
 *
 * A pass is asked for by name in a comma-separated list (`--passes
 * albedo,normal,depth,emission,halves`), which becomes a mask of PT_PASS_*
 * bits (tile.h). The renderer records what each sample gives them
 * (pt_pass_sample, render.h), sums them per pixel in fixed point over the
 * beauty's accepted samples (pt_pass_acc, tile.h), and the film resolves
 * them into named planes of the image, written as layers of the same EXR:
 *
 *   albedo     albedo.R albedo.G albedo.B   albedo.variance
 *   normal     N.X N.Y N.Z                  N.variance
 *   depth      depth.Z                      depth.variance
 *   emission   emission.R emission.G emission.B   emission.variance
 *   halves     halfA.R halfA.G halfA.B  halfB.R halfB.G halfB.B
 *   cryptomatte  CryptoObject00..03.R/G/B/A, CryptoMaterial00..03.R/G/B/A
 *              (crypto.h: 8 ranks of id and coverage a kind)
 *
 * Each channel is the pass's mean over the pixel's samples. A pass's
 * variance is the variance of that mean (sample variance / n, the mean over
 * the pass's channels, n >= 2, else 0), as the beauty's `variance` is for
 * luminance. halfA is the beauty's mean over the pixel's even sample
 * indices, halfB over the odd ones (0 where a half has no sample): the
 * parity of the index, so the halves are the same however the samples were
 * split into tasks. Compositors read `layer.channel` names as layers
 * (Nuke, Blender); N and depth.Z follow the names they expect for normals
 * and depth. Units: albedo is a reflectance, the normal a world-space unit
 * vector (facing the camera ray), depth a distance in scene units, emission
 * a radiance.
 *
 * Pure functions; any thread may call them on its own data.
 */
#ifndef PT_COMMON_RENDER_PASSES_H
#define PT_COMMON_RENDER_PASSES_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"
#include "common/image/image.h"
#include "common/render/crypto.h"
#include "common/render/tile.h"

/* The longest --passes text any program takes. */
#define PT_PASSES_MAX_TEXT 128u

/* "albedo,normal" into a PT_PASS_* mask. Names: albedo, normal, depth,
 * emission, halves, cryptomatte, and `all` for every one; repeats are allowed; an empty
 * list or another name is PT_ERR_ARG naming the valid ones (opt is the
 * option's name for the message). */
pt_status pt_passes_parse(const char *opt, const char *text, uint32_t *mask, pt_error *err);

/* The canonical text of mask ("albedo,normal,depth"; "" for 0) into out (n
 * bytes, cut to fit). */
void pt_passes_text(uint32_t mask, char *out, size_t n);

/* The image's planes of the passes of mask, resolved into by
 * pt_passes_resolve. */
typedef struct pt_pass_planes {
    float *albedo[3], *albedo_var;
    float *normal[3], *normal_var;
    float *depth, *depth_var;
    float *emission[3], *emission_var;
    float *half_a[3], *half_b[3];
    int crypto; /* the Cryptomatte layers below are there */
    pt_crypto_planes cm;
} pt_pass_planes;

/* Adds the named planes of mask's passes to img (zeroed) and points *pl at
 * them (the others NULL). Errors of pt_image_add_plane. */
pt_status pt_passes_add_planes(pt_image *img, uint32_t mask, pt_pass_planes *pl, pt_error *err);

/* Pixel i's passes from its sums (a: the beauty's, for n and the halves;
 * p: the passes') into the planes of pl that are not NULL. */
void pt_passes_resolve(const pt_pixel_acc *a, const pt_pass_acc *p, const pt_pass_planes *pl,
                       size_t i);

#endif
