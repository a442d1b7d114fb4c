/*
 * tile.h - the unit of work's plain data: a rectangle of pixels and the
 * per-pixel partial sums a task returns.
 *
 * Shared vocabulary of the renderer (pt_render_tile writes these), the film
 * (which adds them), the adaptive-sampling rule, the wire format (protocol/
 * encodes them) and the coordinator. Plain structs and one inline function,
 * no dependency beyond <stdint.h>, so protocol/ can use them without knowing
 * the scene model. Any thread may use them.
 */
#ifndef PT_COMMON_RENDER_TILE_H
#define PT_COMMON_RENDER_TILE_H

#include <stdint.h>

/* 128-bit integers (gcc and clang). Aligned to 8 so that a pt_pixel_acc is
 * 72 bytes, not 80: a film is the coordinator's largest allocation, and x86
 * loads them unaligned at no cost. */
__extension__ typedef __int128 pt_i128 __attribute__((aligned(8)));
__extension__ typedef unsigned __int128 pt_u128 __attribute__((aligned(8)));

/* Sums are fixed point: the integer v of an RGB sum stands for v x
 * 2^-PT_FIXED_BITS, that of a sum of squared luminance for v x
 * 2^-PT_FIXED_SQ_BITS. The squares get the finer unit so that a dim pixel
 * (luminance 1e-6, a square of 1e-12) keeps its variance estimate; they
 * saturate rather than overflow, so they need no headroom. */
#define PT_FIXED_BITS 32
#define PT_FIXED_ONE 0x1p32
#define PT_FIXED_ULP 0x1p-32
#define PT_FIXED_SQ_BITS 48
#define PT_FIXED_SQ_ONE 0x1p48
#define PT_FIXED_SQ_ULP 0x1p-48

/* A sample with a colour component above this (or below its negative, or not
 * finite) is rejected, as NaN and Inf are (render.h): it is counted, not
 * accumulated. The cap is what makes the fixed-point sums unable to overflow:
 * a pixel never holds more than 2^32 - 1 samples (n is a u32; spp is a u32),
 * and each 16-sample block's sum rounds to at most 16 x 1e18 x 2^32 + 1/2 in
 * magnitude, so |sum| <= 2^32 x 1e18 x 2^32 x (1 + 2^-40) ~ 1.9e37 < 2^127 ~
 * 1.7e38. (The coordinator checks the same bound per result, job.c.) */
#define PT_MAX_SAMPLE_RADIANCE 1e18
#define PT_U128_MAX (~(pt_u128)0)

/* Per-pixel partial sums of a range of samples, as exact integers. Each
 * aligned block of PT_SAMPLE_BLOCK samples is summed in double in sample
 * order and then rounded to nearest to fixed point (pt_fixed_of): a pure
 * function of the block's samples. Blocks are then added as integers, which
 * is exact and associative, so the sums of a range are the same bits however
 * the range was split at block boundaries and in whatever grouping the parts
 * were added. Read them as doubles with pt_acc_sum / pt_acc_sum_sq. */
typedef struct pt_pixel_acc {
    pt_i128 fsum[3]; /* sum of the RGB samples, units of 2^-32 */
    pt_u128 fsum_sq; /* sum of squared luminance of the samples (error estimate),
                        units of 2^-48; saturates at PT_U128_MAX (adding
                        non-negative values with saturation is associative,
                        so it stays exact and split-invariant; a saturated
                        pixel only reads as a very noisy one) */
    uint32_t n;      /* samples accumulated (rejected ones excluded) */
    uint32_t hits;   /* of those n, the samples whose camera ray hit the scene
                        (hits <= n); hits / n is the pixel's coverage, the alpha
                        of a transparent film. An integer, so it merges exactly. */
} pt_pixel_acc;

/* a + b, saturating at PT_U128_MAX. */
static inline pt_u128 pt_u128_sat_add(pt_u128 a, pt_u128 b)
{
    pt_u128 s = a + b;
    return s < a ? PT_U128_MAX : s;
}

/* a += b: exact, so the order of calls does not matter. */
static inline void pt_pixel_acc_add(pt_pixel_acc *a, const pt_pixel_acc *b)
{
    a->fsum[0] += b->fsum[0];
    a->fsum[1] += b->fsum[1];
    a->fsum[2] += b->fsum[2];
    a->fsum_sq = pt_u128_sat_add(a->fsum_sq, b->fsum_sq);
    a->n += b->n;
    a->hits += b->hits;
}

/*
 * Render passes (AOVs), asked for with a mask of PT_PASS_* bits (passes.h has
 * their names and the EXR layers they become). A pass's per-pixel sums are
 * fixed point like the beauty's, over the same accepted samples (their count
 * is the pixel's pt_pixel_acc.n), so they merge exactly in any order too:
 * s[] in units of 2^-32 (pt_fixed_of), sq[] (the sum over a pass's channels
 * of the squared values, for its variance) in units of 2^-48, saturating.
 * The half buffers are the beauty's sums over the even sample indices (and
 * their count); the odd half is the total minus them.
 */
enum {
    PT_PASS_ALBEDO = 1u << 0,      /* albedo of the first non-specular surface */
    PT_PASS_NORMAL = 1u << 1,      /* its shading normal, world space */
    PT_PASS_DEPTH = 1u << 2,       /* camera distance of the first hit (0: escaped) */
    PT_PASS_EMISSION = 1u << 3,    /* emission of the first hit */
    PT_PASS_HALVES = 1u << 4,      /* the beauty over even and odd sample indices */
    PT_PASS_CRYPTOMATTE = 1u << 5, /* Cryptomatte ids of objects and materials (crypto.h) */
};
#define PT_PASS_ALL 0x3fu

/* Cryptomatte: each pixel keeps, per kind (objects, materials), the exact
 * sample counts of at most PT_CRYPTO_KEEP ids, in ascending order of id,
 * unused entries (count 0, id 0) last. Merging keeps the PT_CRYPTO_KEEP
 * smallest ids of the union, with their counts summed: that rule is
 * associative and commutative (an id among the smallest of all the ids a
 * pixel saw is never dropped, since whatever dropped it would have kept as
 * many smaller ones), so the kept ids and their counts are the same however
 * the samples were split and merged. A pixel that sees more ids than that
 * loses the largest ids' samples: its coverages then sum to less than its
 * share of covered samples. */
#define PT_CRYPTO_KEEP 8
enum { PT_CRYPTO_OBJECT = 0, PT_CRYPTO_MATERIAL = 1, PT_CRYPTO_KINDS = 2 };

/* Indices into pt_pass_acc.s (a pass's first channel) and .sq. */
enum {
    PT_PS_ALBEDO = 0,
    PT_PS_NORMAL = 3,
    PT_PS_EMISSION = 6,
    PT_PS_DEPTH = 9,
    PT_PS_EVEN = 10, /* the beauty's RGB over even sample indices */
    PT_PASS_SUMS = 13
};
enum { PT_PQ_ALBEDO = 0, PT_PQ_NORMAL, PT_PQ_EMISSION, PT_PQ_DEPTH, PT_PASS_SQS };

typedef struct pt_pass_acc {
    pt_i128 s[PT_PASS_SUMS]; /* sums, units of 2^-32 */
    pt_u128 sq[PT_PASS_SQS]; /* sums of squares over a pass's channels, units of 2^-48 */
    uint32_t cid[PT_CRYPTO_KINDS][PT_CRYPTO_KEEP];  /* Cryptomatte ids (MurmurHash3_32) */
    uint32_t ccnt[PT_CRYPTO_KINDS][PT_CRYPTO_KEEP]; /* their sample counts; 0: unused */
    uint32_t n_even;                                /* of the pixel's n samples, those of
                                                       even index */
    uint32_t pad;                                   /* 0 */
} pt_pass_acc;

/* Merges the list (bid, bcnt) of nb entries (ascending ids, unused last)
 * into (id, cnt) of PT_CRYPTO_KEEP: the union, counts of equal ids summed,
 * its PT_CRYPTO_KEEP smallest ids kept. */
static inline void pt_crypto_merge(uint32_t *id, uint32_t *cnt, const uint32_t *bid,
                                   const uint32_t *bcnt, int nb)
{
    uint32_t oid[PT_CRYPTO_KEEP], oc[PT_CRYPTO_KEEP];
    int i = 0, j = 0, n = 0;
    while (n < PT_CRYPTO_KEEP) {
        int ha = i < PT_CRYPTO_KEEP && cnt[i], hb = j < nb && bcnt[j];
        if (!ha && !hb)
            break;
        if (ha && (!hb || id[i] < bid[j])) {
            oid[n] = id[i];
            oc[n++] = cnt[i++];
        } else if (!ha || bid[j] < id[i]) {
            oid[n] = bid[j];
            oc[n++] = bcnt[j++];
        } else {
            oid[n] = id[i];
            oc[n++] = cnt[i++] + bcnt[j++];
        }
    }
    for (int k = 0; k < PT_CRYPTO_KEEP; k++) {
        id[k] = k < n ? oid[k] : 0;
        cnt[k] = k < n ? oc[k] : 0;
    }
}

/* 1 when (id, cnt) is a list as the merge leaves it (ascending ids, counts
 * positive, then unused entries all 0) whose counts sum to at most n. */
static inline int pt_crypto_canonical(const uint32_t *id, const uint32_t *cnt, uint32_t n)
{
    uint64_t sum = 0;
    int used = 1;
    for (int k = 0; k < PT_CRYPTO_KEEP; k++) {
        if (!cnt[k]) {
            used = 0;
            if (id[k])
                return 0;
            continue;
        }
        if (!used || (k > 0 && id[k] <= id[k - 1]))
            return 0;
        sum += cnt[k];
    }
    return sum <= n;
}

/* a += b: exact, so the order of calls does not matter. */
static inline void pt_pass_acc_add(pt_pass_acc *a, const pt_pass_acc *b)
{
    for (int i = 0; i < PT_PASS_SUMS; i++)
        a->s[i] += b->s[i];
    for (int i = 0; i < PT_PASS_SQS; i++)
        a->sq[i] = pt_u128_sat_add(a->sq[i], b->sq[i]);
    for (int k = 0; k < PT_CRYPTO_KINDS; k++)
        if (b->ccnt[k][0])
            pt_crypto_merge(a->cid[k], a->ccnt[k], b->cid[k], b->ccnt[k], PT_CRYPTO_KEEP);
    a->n_even += b->n_even;
}

/* A fixed-point value as a double (rounded to nearest). */
static inline double pt_fixed_to_double(pt_i128 v)
{
    int64_t s = (int64_t)v;
    if ((pt_i128)s == v) /* the common case, without the 128-bit conversion */
        return (double)s * PT_FIXED_ULP;
    return (double)v * PT_FIXED_ULP;
}

/* A fixed-point sum of squares (units of 2^-48) as a double. */
static inline double pt_ufixed_to_double(pt_u128 v)
{
    if (v <= UINT64_MAX)
        return (double)(uint64_t)v * PT_FIXED_SQ_ULP;
    return (double)v * PT_FIXED_SQ_ULP;
}

/* Sum of colour channel c (0..2) and of squared luminance, as doubles. */
static inline double pt_acc_sum(const pt_pixel_acc *a, int c)
{
    return pt_fixed_to_double(a->fsum[c]);
}

static inline double pt_acc_sum_sq(const pt_pixel_acc *a)
{
    return pt_ufixed_to_double(a->fsum_sq);
}

/* A range of samples is summed in aligned blocks of this many, each in sample
 * order in double, rounded to fixed point, then added exactly (render.h): any
 * split at multiples of it gives the same bits. */
#define PT_SAMPLE_BLOCK 16u

/* A --chunk rounded up to whole blocks: a chunk that ends inside a block
 * rounds that block's two parts to fixed point apart, which changes the
 * last bits of the image. ptworker and ptserve round it and say so. */
static inline uint32_t pt_chunk_whole_blocks(uint32_t chunk)
{
    return (chunk + PT_SAMPLE_BLOCK - 1) / PT_SAMPLE_BLOCK * PT_SAMPLE_BLOCK;
}

/* The largest tile side in pixels that any program accepts (ptserve and
 * ptworker --tile, ptbench): its square is the wire's cap on the pixels of a
 * TASK or RESULT (PROTO_MAX_TILE_PIXELS), so a farm tile always fits. */
#define PT_TILE_MAX 256u

/* The longest image side the programs render by default and accept for
 * --res: ptworker, one-job ptserve, and the default of ptserve --max-res. */
#define PT_RENDER_MAX_SIDE 16384u

/* The highest --max-depth any program (ptworker, ptserve, ptctl) or a
 * SUBMIT accepts: one limit, checked where it is typed (it is also the
 * default, render.h's PT_RENDER_DEFAULT_MAX_DEPTH). */
#define PT_RENDER_MAX_DEPTH 1024u

typedef struct pt_rect {
    uint32_t x0, y0, x1, y1; /* pixels [x0,x1) x [y0,y1), y down from the top row */
} pt_rect;

#endif
