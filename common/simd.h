/*
 * simd.h - the 8-lane vector types (GCC/Clang vector extensions) of the
 * sampler's, the cosine map's and the light sampler's SIMD loops, and the
 * attribute that compiles such a loop for AVX2 and for the x86-64 baseline,
 * the loader picking one per CPU (target_clones).
 */
#ifndef PT_COMMON_SIMD_H
#define PT_COMMON_SIMD_H

#include <stdint.h>

typedef uint32_t v8u __attribute__((vector_size(32)));
typedef int32_t v8i __attribute__((vector_size(32)));
typedef float v8f __attribute__((vector_size(32)));

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__linux__)
#define PT_SIMD_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define PT_SIMD_CLONES
#endif

#endif
