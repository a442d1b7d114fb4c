/*
 * denoise_scene.h - a synthetic render with every denoiser input known, for
 * test_denoise and ptpasses-exr: a sphere with a checkered albedo in front of
 * a striped floor under a directional light, sky elsewhere; the truth, its
 * exact features, and half buffers = truth + independent Gaussian noise.
 */
#ifndef PT_TESTS_COMMON_IMAGE_DENOISE_SCENE_H
#define PT_TESTS_COMMON_IMAGE_DENOISE_SCENE_H

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "common/image/denoise.h"
#include "tests/rng.h"

/* The buffers of one test image: truth and everything pt_denoise reads. */
typedef struct scene {
    uint32_t w, h;
    float *truth[3], *a[3], *b[3], *color[3], *var;
    float *albedo[3], *albedo_var, *normal[3], *normal_var, *depth, *depth_var;
    float *out[3];
    float *mem;
} scene;

enum { PLANES = 3 + 3 + 3 + 3 + 1 + 3 + 1 + 3 + 1 + 1 + 1 + 3 };

static uint64_t rng_state;

static inline uint64_t splitmix64(void)
{
    return rng_u64(&rng_state);
}

/* A standard normal number (Box-Muller). */
static inline double gauss(void)
{
    double u1 = ((double)(splitmix64() >> 11) + 0.5) / 9007199254740992.0;
    double u2 = (double)(splitmix64() >> 11) / 9007199254740992.0;
    return sqrt(-2.0 * log(u1)) * cos(6.283185307179586 * u2);
}

static inline int scene_alloc(scene *s, uint32_t w, uint32_t h)
{
    memset(s, 0, sizeof *s);
    s->w = w;
    s->h = h;
    size_t n = (size_t)w * h;
    s->mem = calloc(n * PLANES, sizeof(float));
    if (!s->mem)
        return -1;
    float *p = s->mem;
    for (int c = 0; c < 3; c++) {
        s->truth[c] = p, p += n;
        s->a[c] = p, p += n;
        s->b[c] = p, p += n;
        s->color[c] = p, p += n;
        s->albedo[c] = p, p += n;
        s->normal[c] = p, p += n;
        s->out[c] = p, p += n;
    }
    s->var = p, p += n;
    s->albedo_var = p, p += n;
    s->normal_var = p, p += n;
    s->depth = p, p += n;
    s->depth_var = p, p += n;
    return 0;
}

static inline void scene_free(scene *s)
{
    free(s->mem);
}

static inline pt_denoise_input scene_input(const scene *s)
{
    pt_denoise_input in = {.width = s->w, .height = s->h};
    for (int c = 0; c < 3; c++) {
        in.half_a[c] = s->a[c];
        in.half_b[c] = s->b[c];
        in.color[c] = s->color[c];
        in.albedo[c] = s->albedo[c];
        in.normal[c] = s->normal[c];
    }
    in.variance = s->var;
    in.albedo_var = s->albedo_var;
    in.normal_var = s->normal_var;
    in.depth = s->depth;
    in.depth_var = s->depth_var;
    return in;
}

/* The noise-free features and truth: a sphere with a checkered albedo in
 * front of a floor with stripes, lit by a directional light and an ambient
 * term; sky where neither is hit (albedo, normal and depth 0 there). */
static inline void scene_truth(scene *s)
{
    const double l[3] = {0.48, 0.64, 0.6}; /* unit light direction */
    for (uint32_t y = 0; y < s->h; y++) {
        for (uint32_t x = 0; x < s->w; x++) {
            size_t i = (size_t)y * s->w + x;
            double u = (x + 0.5) / s->w * 2.0 - 1.0, v = 1.0 - (y + 0.5) / s->h * 2.0;
            double cx = u + 0.1, cy = v - 0.15, r2 = cx * cx + cy * cy, rad = 0.6;
            double n[3] = {0, 0, 0}, alb[3] = {0, 0, 0}, depth = 0.0, rgb[3];
            if (r2 < rad * rad) {
                double nz = sqrt(rad * rad - r2);
                n[0] = cx / rad, n[1] = cy / rad, n[2] = nz / rad;
                depth = 4.0 - nz;
                int check = ((int)floor((cx + 1) * 3) + (int)floor((cy + 1) * 3)) & 1;
                alb[0] = check ? 0.8 : 0.2, alb[1] = check ? 0.3 : 0.6, alb[2] = 0.4;
            } else if (v < -0.3) {
                n[1] = 1.0;
                depth = 2.0 / (-v);
                int stripe = (int)floor(u * depth * 3.0 + 100.0) & 1;
                alb[0] = stripe ? 0.7 : 0.35, alb[1] = alb[0], alb[2] = stripe ? 0.5 : 0.3;
            }
            double ndl = n[0] * l[0] + n[1] * l[1] + n[2] * l[2];
            double shade = 0.15 + 0.85 * (ndl > 0 ? ndl : 0);
            for (int c = 0; c < 3; c++) {
                rgb[c] = depth > 0 ? alb[c] * shade : 0.25 + 0.2 * v + 0.1 * c;
                s->truth[c][i] = (float)rgb[c];
                s->albedo[c][i] = (float)alb[c];
                s->normal[c][i] = (float)n[c];
            }
            s->depth[i] = (float)depth;
        }
    }
}

/* Halves = truth + independent N(0, sigma_half^2) per channel; the beauty is
 * their mean, whose variance is sigma_half^2 / 2. */
static inline void scene_noise(scene *s, double sigma_half, uint64_t seed)
{
    rng_state = seed;
    size_t n = (size_t)s->w * s->h;
    for (size_t i = 0; i < n; i++) {
        for (int c = 0; c < 3; c++) {
            s->a[c][i] = (float)(s->truth[c][i] + sigma_half * gauss());
            s->b[c][i] = (float)(s->truth[c][i] + sigma_half * gauss());
            s->color[c][i] = 0.5f * (s->a[c][i] + s->b[c][i]);
        }
        s->var[i] = (float)(sigma_half * sigma_half / 2.0);
    }
}

#endif
