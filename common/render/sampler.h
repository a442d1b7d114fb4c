/*
 * sampler.h - deterministic sample values: Owen-scrambled Sobol keyed by
 * (seed, pixel, sample index, dimension).
 *
 * Burley 2020, "Practical Hash-based Owen Scrambling" (JCGT 9(4)): each pair
 * of dimensions (2p, 2p+1) is Sobol dimensions (0,1) - the only pair of Sobol
 * dimensions that is a (0,2)-sequence - with the sample index shuffled by a
 * nested uniform scramble seeded per pair ("padding"), and each dimension
 * Owen-scrambled with its own hashed seed. Every value is a pure function of
 * its key, with no state:
 * samples [a,b) of a pixel give the same numbers wherever and in however many
 * pieces they are computed. Thread-safe.
 */
#ifndef PT_COMMON_RENDER_SAMPLER_H
#define PT_COMMON_RENDER_SAMPLER_H

#include <stddef.h>
#include <stdint.h>

#include "common/math/vec.h"

/* A 32-bit hash with good avalanche (used to derive seeds). */
uint32_t pt_hash_u32(uint32_t x);
uint32_t pt_hash_combine(uint32_t seed, uint32_t v);

/* The seed of one pixel for a job seed. */
static inline uint32_t pt_pixel_seed(uint32_t job_seed, uint32_t px, uint32_t py)
{
    return pt_hash_combine(pt_hash_combine(pt_hash_u32(job_seed), px), py);
}

/* Sample `index` of dimension `dim` for a pixel seed, in [0, 1). */
float pt_sample_1d(uint32_t pixel_seed, uint32_t index, uint32_t dim);

/* Two dimensions (dim, dim+1) of one sample, in [0,1)^2; with dim even the
 * pair keeps its 2D stratification. */
void pt_sample_2d(uint32_t pixel_seed, uint32_t index, uint32_t dim, float out[2]);

/*
 * The hot path. Everything in a value but the sample index - the index-shuffle
 * seed of each pair and the Owen seed of each dimension - depends only on
 * (pixel seed, dimension), so a group of 8 consecutive dimensions (4 pairs)
 * has its 12 seeds hashed once per pixel and reused for every sample of that
 * pixel; a sample then costs the scrambles alone, evaluated for the 8
 * dimensions at once in SIMD lanes. The values are those
 * of pt_sample_1d bit for bit (tested), so the sequence is the same.
 */
typedef struct pt_sample_group {
    uint32_t shuffle[8]; /* lane k: index-shuffle seed of pair dim0 / 2 + k / 2 */
    uint32_t owen[8];    /* lane k: Owen-scramble seed of dimension dim0 + k */
} pt_sample_group;

/* Seeds of dimensions [dim0, dim0 + 8) for a pixel seed; dim0 even. */
void pt_sample_group_init(pt_sample_group *g, uint32_t pixel_seed, uint32_t dim0);

/* out[k] = pt_sample_1d(pixel_seed, index, dim0 + k) for k in 0..7. */
void pt_sample_group_eval(const pt_sample_group *g, uint32_t index, float out[8]);

/* out[j][k] = pt_sample_1d(seed of g[j], index[j], dim0 of g[j] + k) for
 * j < n, k in 0..7: pt_sample_group_eval for many samples in one call, two at
 * a time in SIMD lanes, with GFNI's bit reversal where the processor has it
 * (the same bits). */
void pt_sample_group_eval_n(const pt_sample_group *const *g, const uint32_t *index, uint32_t n,
                            float (*out)[8]);
/* The same without the GFNI bit reversal that pt_sample_group_eval_n uses
 * where the processor has it (for tests: both must give the same bits). */
void pt_sample_group_eval_n_portable(const pt_sample_group *const *g, const uint32_t *index,
                                     uint32_t n, float (*out)[8]);

/* out[k] = pt_sample_1d(pixel_seed, index, dim0 + k) for k in 0..1: the first
 * pair of the group alone. */
void pt_sample_group_eval2(const pt_sample_group *g, uint32_t index, float out[2]);

/* Unscrambled Sobol value (bits) of dimension d in 0..3, for tests. */
uint32_t pt_sobol_bits(uint32_t index, uint32_t d);

/* Cosine-weighted directions on the hemisphere around +z, for the Lambert
 * lobe: Malley's method over the concentric disk map. */
pt_vec3 pt_sample_cosine_hemisphere(float u1, float u2); /* pdf = cos/pi */
/* (x[k], y[k], z[k]) = pt_sample_cosine_hemisphere(u[k * stride],
 * u[k * stride + 1]) for k < n, in SIMD lanes (the same bits); nothing past
 * n is written. Coordinates in three arrays, as the shading lanes read them. */
void pt_sample_cosine_hemisphere_n(const float *u, size_t stride, uint32_t n, float *x, float *y,
                                   float *z);

#endif
