/*
 * simd.h - the 8-lane vector types (GCC/Clang vector extensions) of the
 * sampler's, the cosine map's, the light sampler's and the Lambert shading's
 * SIMD loops; the attribute that compiles such a loop for AVX2 and for the
 * x86-64 baseline, the loader picking one per CPU (target_clones); the lanes'
 * select and square root.
 *
 * Threads: types and pure inline functions; any thread.
 */
#ifndef PT_COMMON_MATH_SIMD_H
#define PT_COMMON_MATH_SIMD_H

#include <stdint.h>
#include <string.h>

#if defined(__SSE__)
#include <immintrin.h>
#endif

typedef uint32_t v8u __attribute__((vector_size(32)));
typedef int32_t v8i __attribute__((vector_size(32)));
typedef float v8f __attribute__((vector_size(32)));

/* Stores a 3-vector v (x, y, z members) as slot j of a structure of arrays
 * a[3][N], the layout the lanes load 8 slots of at a time. */
#define PT_LANE_PUT3(a, j, v) ((a)[0][j] = (v).x, (a)[1][j] = (v).y, (a)[2][j] = (v).z)

/* Per lane: m ? a : b (m a v8i mask of all-ones or zero lanes). */
#define V8_SELECT(m, a, b) ((v8f)(((v8i)(a) & (m)) | ((v8i)(b) & ~(m))))

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__linux__)
#define PT_SIMD_CLONES __attribute__((target_clones("avx2", "default")))
#define PT_SIMD_HAVE_CLONES 1
#else
#define PT_SIMD_CLONES
#define PT_SIMD_HAVE_CLONES 0
#endif

/* Whether 8-lane loops run in whole vector registers here. On x86-64 that
 * takes AVX2: the clone the loader picks, or a build for it; the baseline
 * (SSE2) does much of a long loop's lanes one by one. Other processors are
 * taken to have their vector unit (AArch64's NEON is in its baseline). */
static inline int pt_simd_lanes_fast(void)
{
#if defined(__x86_64__) && PT_SIMD_HAVE_CLONES
    return __builtin_cpu_supports("avx2");
#elif defined(__x86_64__)
#if defined(__AVX2__)
    return 1;
#else
    return 0;
#endif
#else
    return 1;
#endif
}

/* *r = sqrtf of each lane of *x: correctly rounded, so the same bits as the
 * scalar code's. Two SSE instructions where there is SSE (the x86-64
 * baseline), as C has no portable vector square root. Vectors go by pointer:
 * passed by value they would have another ABI in the AVX2 clones. */
static inline __attribute__((always_inline)) void pt_v8_sqrt(v8f *r, const v8f *x)
{
#if defined(__SSE__)
    float xs[8], rs[8];
    memcpy(xs, x, sizeof xs);
    _mm_storeu_ps(rs, _mm_sqrt_ps(_mm_loadu_ps(xs)));
    _mm_storeu_ps(rs + 4, _mm_sqrt_ps(_mm_loadu_ps(xs + 4)));
    memcpy(r, rs, sizeof rs);
#else
    for (int l = 0; l < 8; l++)
        (*r)[l] = __builtin_sqrtf((*x)[l]);
#endif
}

#endif
