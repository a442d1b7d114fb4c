/*
 * rng.h - the tests' own random numbers: splitmix64 (Steele, Lea & Flood
 * 2014, "Fast splittable pseudorandom number generators"), a fixed and
 * portable stream, so a statistical test draws the same numbers on every
 * machine and a failure can be replayed.
 *
 * Each test keeps its own state (a uint64_t seed) and passes its address:
 *   rng_u64(&s)  the next 64 bits
 *   rng_f24(&s)  a float in [0, 1) from the top 24 bits
 *   rng_f53(&s)  a double in [0, 1) from the top 53 bits
 */
#ifndef PT_TESTS_RNG_H
#define PT_TESTS_RNG_H

#include <stdint.h>

static inline uint64_t rng_u64(uint64_t *state)
{
    uint64_t z = (*state += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

static inline float rng_f24(uint64_t *state)
{
    return (float)(rng_u64(state) >> 40) * 0x1p-24f;
}

static inline double rng_f53(uint64_t *state)
{
    return (double)(rng_u64(state) >> 11) * 0x1p-53;
}

#endif
