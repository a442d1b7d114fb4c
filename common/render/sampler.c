/*
 * sampler.c - Owen-scrambled Sobol after Burley 2020, "Practical Hash-based
 * Owen Scrambling" (JCGT 9(4)).
 *
 * A value is Owen(Sobol_j(Shuffle(index))): the index is shuffled by a nested
 * uniform scramble (an Owen scramble of the index read most significant bit
 * first), which maps the first 2^k indices onto an aligned block of 2^k Sobol
 * indices, itself a (t,k,s)-net; then the Sobol value is Owen-scrambled. Both
 * scrambles use the Laine-Karras construction (Laine & Karras 2011,
 * "Stratified sampling for stochastic transparency"): on the bit-reversed
 * value, a chain of operations in which every output bit depends only on the
 * input bits below it (an add, and x ^= x * even), which is a nested uniform
 * scramble when the seed is random.
 *
 * Padding. A 2D pair of dimensions (2p, 2p+1) is Sobol dimensions (0, 1) under
 * its own hashed index shuffle, and every dimension has its own hashed Owen
 * seed. Burley pads 4D groups (Sobol dimensions 0-3 sharing one shuffle); we pad
 * pairs instead because the renderer draws 2D pairs and needs each one to be a
 * (0,2)-sequence, and no two Sobol dimensions other than (0, 1) form one: row 0
 * of every Sobol generator matrix after the first is all ones, so the pair's
 * 2x2 elementary intervals cannot all be hit by 4 points. Sobol dimensions 2
 * and 3 (Joe & Kuo 2008, new-joe-kuo-6.21201, polynomials x^2+x+1 and x^3+x+1,
 * initial m = {1,3} and {1,3,1}) are kept in pt_sobol_bits for a later 4D
 * sample call and for the tests.
 */
#include "common/render/sampler.h"

#include <math.h>
#include <string.h>

#include "common/math/simd.h"

/*
 * Direction vectors, bit-reversed: bit i of kRevDir[d - 2][k] is row i (most
 * significant output bit first) of column k of Sobol dimension d's generator
 * matrix, so XOR-ing the columns of the set index bits yields the Sobol value
 * already reversed, the form the Laine-Karras scramble works on. Dimension 0
 * (van der Corput) is the identity and dimension 1 (polynomial x + 1) is
 * Pascal's triangle mod 2, both computed without a table in sobol_rev.
 * Dimensions 2-3 follow from the Joe & Kuo constants above by the Sobol
 * recurrence m_k = 2 a_1 m_{k-1} ^ ... ^ 2^s m_{k-s} ^ m_{k-s};
 * tests/common/render/test_sampler.c recomputes all four.
 */
static const uint32_t kRevDir[2][32] = {
    {
        0x00000001u, 0x00000003u, 0x00000006u, 0x00000009u, 0x00000017u, 0x0000003au, 0x00000071u,
        0x000000a3u, 0x00000116u, 0x00000339u, 0x00000677u, 0x000009aau, 0x00001601u, 0x00003903u,
        0x00007706u, 0x0000aa09u, 0x00010117u, 0x0003033au, 0x00060671u, 0x000909a3u, 0x00171616u,
        0x003a3939u, 0x00717777u, 0x00a3aaaau, 0x01170001u, 0x033a0003u, 0x06710006u, 0x09a30009u,
        0x16160017u, 0x3939003au, 0x77770071u, 0xaaaa00a3u,
    },
    {
        0x00000001u, 0x00000003u, 0x00000004u, 0x0000000au, 0x0000001fu, 0x0000002eu, 0x00000045u,
        0x000000c9u, 0x0000011bu, 0x000002a4u, 0x0000079au, 0x00000b67u, 0x0000101eu, 0x0000302du,
        0x00004041u, 0x0000a0c3u, 0x0001f104u, 0x0002e28au, 0x000457dfu, 0x000c9baeu, 0x0011a105u,
        0x002a7289u, 0x0079e7dbu, 0x00b6dba4u, 0x0100011au, 0x030002a7u, 0x0400079eu, 0x0a000b6du,
        0x1f001001u, 0x2e003003u, 0x45004004u, 0xc900a00au,
    },
};

/* Domain tag that keeps index-shuffle seeds apart from per-dimension seeds. */
#define SHUFFLE_TAG 0xa511e9b3u

/* The finaliser of MurmurHash3 (Appleby), a full-avalanche 32-bit bijection. */
uint32_t pt_hash_u32(uint32_t x)
{
    x ^= x >> 16;
    x *= 0x85ebca6bu;
    x ^= x >> 13;
    x *= 0xc2b2ae35u;
    x ^= x >> 16;
    return x;
}

/* Boost's hash_combine mixing step, then a full avalanche so that nearby
 * (seed, v) pairs (neighbouring pixels, dimensions) give unrelated seeds. */
uint32_t pt_hash_combine(uint32_t seed, uint32_t v)
{
    return pt_hash_u32(seed ^ (pt_hash_u32(v) + 0x9e3779b9u + (seed << 6) + (seed >> 2)));
}

/* In-place steps on a uint32_t, v8u or v16u variable, so that the scalar
 * functions below and the SIMD lanes further on do the same operations;
 * macros, not functions, because passing a 32-byte vector by value changes
 * the ABI between the two clones. */
#define REVERSE_BITS(x)                                                                            \
    do {                                                                                           \
        x = ((x >> 1) & 0x55555555u) | ((x & 0x55555555u) << 1);                                   \
        x = ((x >> 2) & 0x33333333u) | ((x & 0x33333333u) << 2);                                   \
        x = ((x >> 4) & 0x0f0f0f0fu) | ((x & 0x0f0f0f0fu) << 4);                                   \
        x = ((x >> 8) & 0x00ff00ffu) | ((x & 0x00ff00ffu) << 8);                                   \
        x = (x >> 16) | (x << 16);                                                                 \
    } while (0)
#define LK_PERMUTE(x, seed)                                                                        \
    do {                                                                                           \
        x += seed;                                                                                 \
        x ^= x * 0x6c50b47cu;                                                                      \
        x ^= x * 0xb82f1e52u;                                                                      \
        x ^= x * 0xc7afe638u;                                                                      \
        x ^= x * 0x8d22f6e6u;                                                                      \
    } while (0)
#define PASCAL_REV(y)                                                                              \
    do {                                                                                           \
        y ^= (y >> 1) & 0x55555555u;                                                               \
        y ^= (y >> 2) & 0x33333333u;                                                               \
        y ^= (y >> 4) & 0x0f0f0f0fu;                                                               \
        y ^= (y >> 8) & 0x00ff00ffu;                                                               \
        y ^= (y >> 16) & 0x0000ffffu;                                                              \
    } while (0)

static inline uint32_t reverse_bits(uint32_t x)
{
    REVERSE_BITS(x);
    return x;
}

/*
 * Laine-Karras permutation of a bit-reversed value: each step changes bit k
 * as a function of bits <= k only (a carry moves upwards; x * even has bit k
 * built from bits < k), so in the unreversed value each bit is flipped as a
 * function of the bits above it: an Owen scramble. Constants from Burley 2020,
 * section 3 (the improved hash).
 */
static inline uint32_t lk_permute(uint32_t x, uint32_t seed)
{
    LK_PERMUTE(x, seed);
    return x;
}

/* Sobol dimension 1, bit-reversed. Pascal's triangle mod 2: by Lucas' theorem
 * column k has row i set iff the bits of i are a subset of those of k, so
 * reversed output bit i is the parity of the index bits k that contain i: a
 * superset sum over the 5-bit positions, one butterfly per position bit. */
static inline uint32_t pascal_rev(uint32_t y)
{
    PASCAL_REV(y);
    return y;
}

/* Sobol value of dimension d (0..3), bit-reversed. */
static inline uint32_t sobol_rev(uint32_t index, uint32_t d)
{
    if (d == 0)
        return index;
    if (d == 1)
        return pascal_rev(index);
    const uint32_t *dir = kRevDir[d - 2];
    uint32_t x = 0;
    for (uint32_t k = 0; index; index >>= 1, k++)
        if (index & 1u)
            x ^= dir[k];
    return x;
}

uint32_t pt_sobol_bits(uint32_t index, uint32_t d)
{
    return d < 4 ? reverse_bits(sobol_rev(index, d)) : 0;
}

/* The shuffled Sobol index of sample `index` for the pair holding dim. */
static inline uint32_t shuffled_index(uint32_t pixel_seed, uint32_t index, uint32_t dim)
{
    uint32_t pair_seed = pt_hash_combine(pixel_seed ^ SHUFFLE_TAG, dim >> 1);
    return reverse_bits(lk_permute(reverse_bits(index), pair_seed));
}

/* 24 bits to a float in [0, 1): exact, and never rounds up to 1. (Through a
 * signed int, which the 24 bits fit: SSE2 converts signed ints only.) */
static inline float to_unit(uint32_t bits)
{
    return (float)(int32_t)(bits >> 8) * 0x1p-24f;
}

static inline float owen_sample(uint32_t pixel_seed, uint32_t sobol_index, uint32_t dim)
{
    uint32_t x = sobol_rev(sobol_index, dim & 1u);
    return to_unit(reverse_bits(lk_permute(x, pt_hash_combine(pixel_seed, dim))));
}

float pt_sample_1d(uint32_t pixel_seed, uint32_t index, uint32_t dim)
{
    return owen_sample(pixel_seed, shuffled_index(pixel_seed, index, dim), dim);
}

void pt_sample_2d(uint32_t pixel_seed, uint32_t index, uint32_t dim, float out[2])
{
    if (dim & 1u) {
        /* Straddles two pairs: two independently padded values. */
        out[0] = pt_sample_1d(pixel_seed, index, dim);
        out[1] = pt_sample_1d(pixel_seed, index, dim + 1);
        return;
    }
    uint32_t s = shuffled_index(pixel_seed, index, dim);
    out[0] = owen_sample(pixel_seed, s, dim);
    out[1] = owen_sample(pixel_seed, s, dim + 1);
}

/* The seeds that shuffled_index and owen_sample hash per call, hashed once;
 * each pair's shuffle seed is stored twice, once per lane of its dimensions. */
void pt_sample_group_init(pt_sample_group *g, uint32_t pixel_seed, uint32_t dim0)
{
    for (uint32_t k = 0; k < 4; k++)
        g->shuffle[2 * k] = g->shuffle[2 * k + 1] =
            pt_hash_combine(pixel_seed ^ SHUFFLE_TAG, (dim0 >> 1) + k);
    for (uint32_t k = 0; k < 8; k++)
        g->owen[k] = pt_hash_combine(pixel_seed, dim0 + k);
}

/*
 * owen_sample(shuffled_index(...)) for 8 dimensions in 8 lanes of GCC/Clang
 * vector types: the same integer operations lane by lane, so the results are
 * the same bits on any instruction set. Lane k shuffles the index with its
 * pair's seed (the even and odd lane of a pair compute the same shuffle; in
 * SIMD that is free), takes the Sobol value - the shuffled index itself on
 * even lanes (Sobol dimension 0), Pascal's matrix on odd lanes (dimension 1) -
 * and Owen-scrambles it with the lane's seed. Compiled twice (target_clones):
 * for AVX2, whose 32-bit vector multiply makes each step one instruction,
 * and for the x86-64 baseline (SSE2, where the compiler splits the lanes in
 * two halves and emulates the multiply); the loader picks one per CPU.
 */
PT_SIMD_CLONES
void pt_sample_group_eval(const pt_sample_group *g, uint32_t index, float out[8])
{
    v8u shuffle, owen;
    memcpy(&shuffle, g->shuffle, sizeof shuffle);
    memcpy(&owen, g->owen, sizeof owen);
    const v8u odd = {0, ~0u, 0, ~0u, 0, ~0u, 0, ~0u};
    /* The shuffled index s, in every lane. */
    v8u s = (v8u){0} + reverse_bits(index);
    LK_PERMUTE(s, shuffle);
    REVERSE_BITS(s);
    /* The Sobol value, bit-reversed: s itself, or Pascal's matrix times s. */
    v8u p = s;
    PASCAL_REV(p);
    v8u x = (s & ~odd) | (p & odd);
    LK_PERMUTE(x, owen);
    REVERSE_BITS(x);
    x >>= 8; /* 24 bits, exactly representable: to_unit */
    v8f f = __builtin_convertvector((v8i)x, v8f) * 0x1p-24f;
    memcpy(out, &f, sizeof f);
}

/*
 * pt_sample_group_eval for n (group, index) pairs, two per step in 16 lanes:
 * the same integer operations lane by lane as above, so the same bits. With
 * AVX-512 a step is one instruction for two samples, with AVX2 two, and the
 * calls of a batch of paths become one. Compiled three times, like the above
 * (eval_n_generic), and once more with GFNI's bit reversal (eval_n_gfni),
 * which pt_sample_group_eval_n picks where the processor has it: the two bit
 * reversals were half of the instructions.
 */
typedef uint32_t v16u __attribute__((vector_size(64)));
typedef int32_t v16i __attribute__((vector_size(64)));
typedef float v16f __attribute__((vector_size(64)));

/* One step of eval_n: lanes 0-7 for (g0, i0), lanes 8-15 for (g1, i1). The
 * bit reversal is a parameter (a macro taking a v16u variable), so the GFNI
 * version below shares the rest. */
#define EVAL_N_BODY(REVERSE)                                                                       \
    do {                                                                                           \
        uint32_t k2 = k + 1 < n ? k + 1 : k; /* an odd n repeats its last pair */                  \
        v8u sh0, sh1, ow0, ow1;                                                                    \
        memcpy(&sh0, g[k]->shuffle, 32);                                                           \
        memcpy(&sh1, g[k2]->shuffle, 32);                                                          \
        memcpy(&ow0, g[k]->owen, 32);                                                              \
        memcpy(&ow1, g[k2]->owen, 32);                                                             \
        /* Joined in registers: two 32-byte stores read back as one 64-byte                        \
         * load would stall store forwarding. */                                                   \
        v16u shuffle = __builtin_shufflevector(sh0, sh1, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, \
                                               13, 14, 15);                                        \
        v16u owen = __builtin_shufflevector(ow0, ow1, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12,    \
                                            13, 14, 15);                                           \
        uint32_t r0 = reverse_bits(index[k]), r1 = reverse_bits(index[k2]);                        \
        v16u s = {r0, r0, r0, r0, r0, r0, r0, r0, r1, r1, r1, r1, r1, r1, r1, r1};                 \
        LK_PERMUTE(s, shuffle);                                                                    \
        REVERSE(s);                                                                                \
        v16u p = s;                                                                                \
        PASCAL_REV(p);                                                                             \
        v16u x = (s & ~odd) | (p & odd);                                                           \
        LK_PERMUTE(x, owen);                                                                       \
        REVERSE(x);                                                                                \
        x >>= 8;                                                                                   \
        v16f f = __builtin_convertvector((v16i)x, v16f) * 0x1p-24f;                                \
        v8f lo = __builtin_shufflevector(f, f, 0, 1, 2, 3, 4, 5, 6, 7);                            \
        v8f hi = __builtin_shufflevector(f, f, 8, 9, 10, 11, 12, 13, 14, 15);                      \
        memcpy(out[k], &lo, 32);                                                                   \
        if (k2 != k)                                                                               \
            memcpy(out[k2], &hi, 32);                                                              \
    } while (0)

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__linux__)
#define PT_SIMD_CLONES_WIDE __attribute__((target_clones("avx512f", "avx2", "default")))
#define PT_GFNI 1
#else
#define PT_SIMD_CLONES_WIDE
#define PT_GFNI 0
#endif

PT_SIMD_CLONES_WIDE
static void eval_n_generic(const pt_sample_group *const *g, const uint32_t *index, uint32_t n,
                           float (*out)[8])
{
    const v16u odd = {0, ~0u, 0, ~0u, 0, ~0u, 0, ~0u, 0, ~0u, 0, ~0u, 0, ~0u, 0, ~0u};
    for (uint32_t k = 0; k < n; k += 2)
        EVAL_N_BODY(REVERSE_BITS);
}

#if PT_GFNI
#include <immintrin.h>

/* A 32-bit bit reversal in two instructions: GF2P8AFFINEQB with the matrix
 * 0x8040201008040201 (the anti-diagonal) reverses the bits of every byte,
 * then a byte shuffle reverses the bytes of every 32-bit lane. The same
 * result as REVERSE_BITS, so the same values. */
#define V16_REVERSE_BITS_GFNI(x)                                                                   \
    do {                                                                                           \
        x = (v16u)_mm512_shuffle_epi8(_mm512_gf2p8affine_epi64_epi8((__m512i)x, bitrev8, 0),       \
                                      byterev32);                                                  \
    } while (0)

__attribute__((target("avx512f,avx512bw,gfni"))) static void
eval_n_gfni(const pt_sample_group *const *g, const uint32_t *index, uint32_t n, float (*out)[8])
{
    const v16u odd = {0, ~0u, 0, ~0u, 0, ~0u, 0, ~0u, 0, ~0u, 0, ~0u, 0, ~0u, 0, ~0u};
    const __m512i bitrev8 = _mm512_set1_epi64((long long)0x8040201008040201ull);
    const __m512i byterev32 =
        _mm512_broadcast_i32x4(_mm_set_epi8(12, 13, 14, 15, 8, 9, 10, 11, 4, 5, 6, 7, 0, 1, 2, 3));
    for (uint32_t k = 0; k < n; k += 2)
        EVAL_N_BODY(V16_REVERSE_BITS_GFNI);
}
#endif

void pt_sample_group_eval_n_portable(const pt_sample_group *const *g, const uint32_t *index,
                                     uint32_t n, float (*out)[8])
{
    eval_n_generic(g, index, n, out);
}

void pt_sample_group_eval_n(const pt_sample_group *const *g, const uint32_t *index, uint32_t n,
                            float (*out)[8])
{
#if PT_GFNI
    if (__builtin_cpu_supports("gfni") && __builtin_cpu_supports("avx512bw")) {
        eval_n_gfni(g, index, n, out);
        return;
    }
#endif
    eval_n_generic(g, index, n, out);
}

void pt_sample_group_eval2(const pt_sample_group *g, uint32_t index, float out[2])
{
    uint32_t s = reverse_bits(lk_permute(reverse_bits(index), g->shuffle[0]));
    out[0] = to_unit(reverse_bits(lk_permute(s, g->owen[0])));
    out[1] = to_unit(reverse_bits(lk_permute(pascal_rev(s), g->owen[1])));
}

static inline float maxf(float a, float b)
{
    return a > b ? a : b;
}

/* sin and cos of t in [-pi/4, pi/4] by their Taylor polynomials (to t^9 and
 * t^8; the first omitted terms are below 2e-9 and 3e-8 there, under half an
 * ulp of the results), evaluated in Horner form: a few ulps like sinf/cosf,
 * without the library call and its range reduction. A macro, so that the
 * scalar code (t a float) and the lanes below (t a v8f) evaluate the same
 * polynomials: the same bits. */
#define SINCOS_QUARTER(t, s, c)                                                                    \
    do {                                                                                           \
        __typeof__(t) t2_ = (t) * (t);                                                             \
        s = (t) * (1.0f + t2_ * (-1.0f / 6.0f +                                                    \
                                 t2_ * (1.0f / 120.0f +                                            \
                                        t2_ * (-1.0f / 5040.0f + t2_ * (1.0f / 362880.0f)))));     \
        c = 1.0f + t2_ * (-0.5f + t2_ * (1.0f / 24.0f +                                            \
                                         t2_ * (-1.0f / 720.0f + t2_ * (1.0f / 40320.0f))));       \
    } while (0)

pt_vec3 pt_sample_cosine_hemisphere(float u1, float u2)
{
    /* Malley's method: a uniform point of the unit disk projected up. The
     * disk point comes from the concentric map of Shirley & Chiu 1997, "A
     * Low Distortion Map Between Disk and Square", which keeps strata. */
    float a = 2.0f * u1 - 1.0f, b = 2.0f * u2 - 1.0f;
    if (a == 0.0f && b == 0.0f)
        return pt_v3(0.0f, 0.0f, 1.0f);
    /* phi = t (|a| > |b|) or pi/2 - t, with t = pi/4 times a ratio in [-1, 1],
     * so cos and sin of phi are cos and sin of t, swapped in the second case. */
    int wide = fabsf(a) > fabsf(b);
    float r = wide ? a : b;
    float num = wide ? b : a, den = wide ? a : b; /* selects: wide is random */
    float t = (PT_PI / 4.0f) * (num / den);
    float c, sn;
    SINCOS_QUARTER(t, sn, c);
    float x = r * (wide ? c : sn), y = r * (wide ? sn : c);
    return pt_v3(x, y, sqrtf(maxf(0.0f, 1.0f - x * x - y * y)));
}

/*
 * pt_sample_cosine_hemisphere for n pairs in 8 SIMD lanes, in GCC/Clang vector
 * types: the same float operations lane by lane (IEEE arithmetic, no
 * contraction: the same bits), the branches of the scalar code as selects.
 * The square root is correctly rounded either way (pt_v8_sqrt). Compiled
 * for AVX2 and the x86-64 baseline (target_clones), like the sampler.
 */
PT_SIMD_CLONES
void pt_sample_cosine_hemisphere_n(const float *u, size_t stride, uint32_t n, float *xs, float *ys,
                                   float *zs)
{
    for (uint32_t k0 = 0; k0 < n; k0 += 8) {
        uint32_t m = n - k0 < 8 ? n - k0 : 8;
        /* Lanes past n repeat the last pair. Built by an initialiser, not
         * lane by lane through memory, whose 4-byte stores a 32-byte load
         * could not forward. */
        const float *p[8];
        for (uint32_t l = 0; l < 8; l++)
            p[l] = &u[(size_t)(k0 + (l < m ? l : m - 1)) * stride];
        v8f u1 = {p[0][0], p[1][0], p[2][0], p[3][0], p[4][0], p[5][0], p[6][0], p[7][0]};
        v8f u2 = {p[0][1], p[1][1], p[2][1], p[3][1], p[4][1], p[5][1], p[6][1], p[7][1]};
        v8f a = 2.0f * u1 - 1.0f, b = 2.0f * u2 - 1.0f;
        v8i origin = (a == 0.0f) & (b == 0.0f);
        v8f fa = (v8f)((v8i)a & 0x7fffffff), fb = (v8f)((v8i)b & 0x7fffffff);
        v8i wide = fa > fb;
        v8f r = V8_SELECT(wide, a, b);
        v8f num = V8_SELECT(wide, b, a), den = V8_SELECT(wide, a, b);
        /* At the origin den is 0 and t NaN; the lane's result is replaced. */
        v8f t = (PT_PI / 4.0f) * (num / den);
        v8f sn, c;
        SINCOS_QUARTER(t, sn, c);
        v8f x = r * V8_SELECT(wide, c, sn), y = r * V8_SELECT(wide, sn, c);
        v8f w = 1.0f - x * x - y * y;
        w = V8_SELECT(0.0f > w, (v8f){0}, w); /* maxf(0, w): a NaN w stays */
        v8f z;
        pt_v8_sqrt(&z, &w);
        x = (v8f)((v8i)x & ~origin);
        y = (v8f)((v8i)y & ~origin);
        z = V8_SELECT(origin, (v8f){0} + 1.0f, z);
        if (m == 8) {
            memcpy(&xs[k0], &x, sizeof x);
            memcpy(&ys[k0], &y, sizeof y);
            memcpy(&zs[k0], &z, sizeof z);
        } else {
            for (uint32_t l = 0; l < m; l++) {
                xs[k0 + l] = x[l];
                ys[k0 + l] = y[l];
                zs[k0 + l] = z[l];
            }
        }
    }
}
