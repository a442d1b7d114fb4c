/*
 * sampler.h - deterministic sample values: Owen-scrambled Sobol keyed by
 * (seed, pixel, sample index, dimension).
 *
 * Burley 2020, "Practical Hash-based Owen Scrambling" (JCGT 9(4)): the sample
 * index is shuffled by a nested uniform scramble (Owen scramble of the
 * bit-reversed index), each 4-dimensional group of Sobol dimensions gets its own
 * shuffle seed ("padding"), and each dimension its own Owen scramble seed, all
 * derived by hashing. Every value is a pure function of its key, with no state:
 * samples [a,b) of a pixel give the same numbers wherever and in however many
 * pieces they are computed. Thread-safe.
 */
#ifndef PT_COMMON_SAMPLER_H
#define PT_COMMON_SAMPLER_H

#include <stdint.h>

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

/* Two dimensions (dim, dim+1) of one sample, in [0,1)^2; dim should be even
 * so a pair stays within one Sobol group and keeps its 2D stratification. */
void pt_sample_2d(uint32_t pixel_seed, uint32_t index, uint32_t dim, float out[2]);

/* Unscrambled Sobol value (bits) of dimension d in 0..3, for tests. */
uint32_t pt_sobol_bits(uint32_t index, uint32_t d);

#endif
