#include "common/image/denoise.h"

#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/image/image.h"
#include "common/math/simd.h"

/* Tiles: the unit of parallel work and of the fixed summation order. */
#define TILE 32
_Static_assert(TILE == PT_DENOISE_TILE, "denoise.h's tile is this one");
/* The paper's parameters (NFOR sec. 5 and its reference implementation). */
#define REG_F 3        /* patch radius of the regression's weights */
#define REG_F_STRICT 1 /* ... of the k = 0.5 candidate's (not the paper's; pt_denoise) */
#define REG_R 9        /* window radius of the regression: 19 x 19 */
#define FEAT_F 3       /* feature prefilter: patch radius */
#define FEAT_R 5       /* ... window radius */
#define FEAT_K 0.5f    /* ... and k */
#define MSE_F 1        /* MSE and selection-map smoothing: patch radius */
#define MSE_R 9        /* ... window radius */
#define MAX_F 3        /* the largest patch radius above: scratch sizes */
#define MAX_R 9        /* the largest window radius */
#define WIN ((2 * MAX_R + 1) * (2 * MAX_R + 1))
/* Regression unknowns: a constant, the screen offset (x, y), the features. */
#define DIM (3 + PT_DENOISE_FEATURES)

/* NL-means patch distance (Rousselle, Knaus and Zwicker 2012, eq. 8):
 * d^2 = ((u_p - u_q)^2 - (var_p + min(var_p, var_q))) / (eps + k^2 (var_p + var_q)),
 * averaged over the patch; weight exp(-max(0, d^2)). eps keeps a noise-free
 * image's weights defined (identical patches weigh 1, others ~0); distances
 * are clamped so that the exponential never sees an overflowing argument. */
#define NLM_EPS 1e-10f
#define NLM_CLAMP 10000.0f
/* The regression's weights take each pixel's variance as at least
 * NLM_TOL2 (u^2 + 0.01): a difference under 0.55 % of sqrt(u^2 + 0.01),
 * the scale relMSE measures errors on (common/image/metrics.h's epsilon), is
 * treated as noise. Without it, a noisy pixel beside a noise-free textured
 * one (an object's silhouette against an environment map seen directly, of
 * variance 0) finds no neighbour: the noise-free half of every patch differs
 * by thousands of times a variance of ~0 and the patch distance shuts every
 * offset out, whatever the pixel's own noise. Measured, 64 spp against
 * 4,096-spp references (docs/bench/denoise.md): SheenChair in the studio
 * 4.69e-4 -> 3.52e-4, the Cornell box 1.12e-4 -> 1.10e-4, ToyCar in the park
 * 1.56e-3 -> 1.55e-3 (its mean 0.998 -> 0.997 of the raw image's), both
 * DamagedHelmets as before; 1e-4 took SheenChair to 3.45e-4 but ToyCar's
 * mean to 0.9925, 1e-5 SheenChair only to 3.80e-4. The bias a noise-free
 * neighbour can add is of the same 0.55 %. */
#define NLM_TOL2 3e-5f
/* The distance of a pixel pair that does not exist: weight 0 at any k. */
#define NLM_FAR 1e30f
/* The centre pixel always keeps some weight, so a window never sums to 0. */
#define NLM_MIN_CENTER 1e-4f
/* The largest factor a channel's variance gets over luminance's: pure blue's
 * (1 / 0.0722)^2 is 192. */
#define VAR_RATIO_MAX 200.0f
/* A variance over this many times its 3 x 3 neighbourhood's median is an
 * outlier (variance_cap). */
#define VAR_CAP 16.0f

typedef struct rect {
    int x0, y0, x1, y1; /* [x0, x1) x [y0, y1) */
} rect;

/* Progress (pt_denoise_input.progress): the work done, in weights, of its
 * total, mapped to the caller's thousandths [base, base + span]. Each
 * stage's tiles weigh what a tile of it costs (measured on a 512 x 512
 * image, 1 thread: a features' NL-means 0.4 s, a first regression 8.2 s,
 * the MSE estimates' smoothing 1.8 s, the choice map's 1.8 s, the second
 * regression 3.8 s). */
typedef struct progress {
    atomic_uint *out; /* NULL: nobody reads it */
    uint64_t total;
    atomic_uint_fast64_t done;
    uint32_t base, span;
} progress;
enum { W_FEAT = 2, W_REG = 41, W_MSE = 9, W_SEL = 9, W_FINAL = 19 };
#define W_TILE (3 * W_FEAT + 2 * W_REG + W_MSE + W_SEL + W_FINAL)

/* Raises *pg->out to what done + w makes it (never lowers it: threads
 * finish tiles in any order). */
static void progress_add(progress *pg, uint64_t w)
{
    if (!pg || !pg->out || !pg->total)
        return;
    uint64_t d = atomic_fetch_add(&pg->done, w) + w;
    if (d > pg->total)
        d = pg->total;
    unsigned v = pg->base + (unsigned)(d * pg->span / pg->total);
    unsigned cur = atomic_load(pg->out);
    while (cur < v && !atomic_compare_exchange_weak(pg->out, &cur, v))
        ;
}

typedef struct dims {
    int w, h, tx, ty;         /* image size; tiles across and down */
    const atomic_int *cancel; /* pt_denoise_input's */
    progress *pg;             /* NULL: no progress kept */
} dims;

/* The parallel runner: threads take tile indices from a counter; what a
 * tile computes depends only on its index, never on the thread. */
typedef int (*tile_fn)(void *ctx, int tile, void *scratch); /* 0, or -1: out of memory */

typedef struct tile_job {
    tile_fn fn;
    void *ctx;
    int ntiles;
    size_t scratch_bytes;
    const atomic_int *cancel; /* NULL, or set from outside: stop */
    progress *pg;             /* each tile done adds weight */
    uint32_t weight;
    atomic_int next;
    atomic_int failed; /* 1: out of memory; 2: cancelled */
} tile_job;

static void *tile_worker(void *arg)
{
    tile_job *job = arg;
    void *scratch = pt_malloc(job->scratch_bytes);
    if (!scratch) {
        atomic_store(&job->failed, 1);
        return NULL;
    }
    for (;;) {
        int t = atomic_fetch_add(&job->next, 1);
        if (t >= job->ntiles || atomic_load(&job->failed))
            break;
        if (job->cancel && atomic_load(job->cancel)) {
            atomic_store(&job->failed, 2);
            break;
        }
        if (job->fn(job->ctx, t, scratch) != 0)
            atomic_store(&job->failed, 1);
        else
            progress_add(job->pg, job->weight);
    }
    pt_free(scratch);
    return NULL;
}

static pt_status run_tiles(unsigned threads, const dims *dm, uint32_t weight, size_t scratch_bytes,
                           tile_fn fn, void *ctx, pt_error *err)
{
    tile_job job = {.fn = fn,
                    .ctx = ctx,
                    .ntiles = dm->tx * dm->ty,
                    .scratch_bytes = scratch_bytes,
                    .cancel = dm->cancel,
                    .pg = dm->pg,
                    .weight = weight};
    int ntiles = job.ntiles;
    atomic_init(&job.next, 0);
    atomic_init(&job.failed, 0);
    pthread_t tid[PT_DENOISE_MAX_THREADS];
    unsigned started = 0;
    unsigned want = threads < (unsigned)ntiles ? threads : (unsigned)ntiles;
    /* A thread that cannot be started leaves its tiles to the others: the
     * result does not depend on how many run. */
    while (started + 1 < want && pthread_create(&tid[started], NULL, tile_worker, &job) == 0)
        started++;
    tile_worker(&job);
    for (unsigned i = 0; i < started; i++)
        pthread_join(tid[i], NULL);
    if (atomic_load(&job.failed) == 2)
        return pt_error_set(err, PT_AGAIN, "denoise: cancelled");
    if (atomic_load(&job.failed))
        return pt_error_set(err, PT_ERR_NOMEM, "denoise: out of memory");
    return PT_OK;
}

static rect tile_rect(const dims *d, int t)
{
    int tx = t % d->tx, ty = t / d->tx;
    rect r = {tx * TILE, ty * TILE, tx * TILE + TILE, ty * TILE + TILE};
    if (r.x1 > d->w)
        r.x1 = d->w;
    if (r.y1 > d->h)
        r.y1 = d->h;
    return r;
}

static int imax(int a, int b)
{
    return a > b ? a : b;
}
static int imin(int a, int b)
{
    return a < b ? a : b;
}
/* Not fminf/fmaxf: those are calls where NaN rules differ; no NaN reaches here. */
static float fmin2(float a, float b)
{
    return a < b ? a : b;
}
static float fmax2(float a, float b)
{
    return a > b ? a : b;
}

/* e^-d for d >= 0; 0 from d = 80 on (under 2e-35: nothing next to the
 * centre's weight). Written out rather than expf so that every machine
 * computes the same bits (libm's expf picks code by processor) and loops
 * over it vectorise: 2^-t with t = d log2(e) split into its integer part n
 * and fraction, e^-u for u = fraction x ln 2 in [0, ln 2) by Taylor's
 * series to degree 9 (truncation under 1e-7 relative), times 2^-n built in
 * the exponent bits. */
static inline float exp_neg(float d)
{
    float dc = d < 80.0f ? d : 80.0f;
    float t = dc * 1.44269504f;
    int n = (int)t;
    float u = (t - (float)n) * 0.693147181f;
    float p =
        1.0f +
        u * (-1.0f +
             u * (0.5f +
                  u * (-1.0f / 6.0f +
                       u * (1.0f / 24.0f +
                            u * (-1.0f / 120.0f +
                                 u * (1.0f / 720.0f +
                                      u * (-1.0f / 5040.0f +
                                           u * (1.0f / 40320.0f + u * (-1.0f / 362880.0f)))))))));
    uint32_t bits = (uint32_t)(127 - n) << 23;
    float scale;
    memcpy(&scale, &bits, sizeof scale);
    return d < 80.0f ? p * scale : 0.0f;
}

/* exp_neg of 8 lanes in place, the same operations lane by lane: the same
 * bits. Vectors go by pointer (as in simd.h): no AVX argument ABI. */
static inline void exp_neg8(v8f *x)
{
    v8f d = *x;
    const v8f lim = {80, 80, 80, 80, 80, 80, 80, 80}, zero = {0};
    v8i below = d < lim;
    v8f dc = V8_SELECT(below, d, lim);
    v8f t = dc * 1.44269504f;
    v8i n = __builtin_convertvector(t, v8i);
    v8f u = (t - __builtin_convertvector(n, v8f)) * 0.693147181f;
    v8f p =
        1.0f +
        u * (-1.0f +
             u * (0.5f +
                  u * (-1.0f / 6.0f +
                       u * (1.0f / 24.0f +
                            u * (-1.0f / 120.0f +
                                 u * (1.0f / 720.0f +
                                      u * (-1.0f / 5040.0f +
                                           u * (1.0f / 40320.0f + u * (-1.0f / 362880.0f)))))))));
    v8i bits = (127 - n) << 23;
    *x = V8_SELECT(below, p * (v8f)bits, zero);
}

/* What NL-means weights are computed from: nc guide channels and the
 * variance of each (pointers may repeat), scaled by vscale, plus tol2 (g^2 +
 * 0.01) (0, or NLM_TOL2 for the regression's weights). guide_terms turns
 * v into that sum, pixel by pixel, before patch_dist reads it. */
typedef struct guide {
    int nc;
    const float *g[3];
    const float *v[3];
    float vscale;
    int f; /* patch radius */
    float tol2;
} guide;

/* Each pixel's term of the patch distances, v vscale + tol2 (g^2 + 0.01),
 * computed once per pixel instead of once per pixel and offset (the same
 * operations: the same bits): gd->v[c] then points to it. Returns the
 * planes to free, or NULL (out of memory). */
static float *guide_terms(const dims *dm, guide *gd)
{
    size_t n = (size_t)dm->w * dm->h;
    float *t = pt_malloc_array((size_t)gd->nc * n, sizeof(float));
    if (!t)
        return NULL;
    for (int c = 0; c < gd->nc; c++) {
        const float *g = gd->g[c], *v = gd->v[c];
        float *o = t + (size_t)c * n;
        for (size_t i = 0; i < n; i++)
            o[i] = v[i] * gd->vscale + gd->tol2 * (g[i] * g[i] + 0.01f);
        gd->v[c] = o;
    }
    return t;
}

/* Scratch of patch_weights. */
typedef struct wscratch {
    float *d;  /* 3 x PAD^2: per-pixel distances of each channel */
    float *hs; /* 2 x PAD: a row's column sums, then its patch sums */
    float *hc; /* PAD: each output's patch width */
} wscratch;

#define PAD (TILE + 2 * MAX_F)
#define WSCRATCH_BYTES ((3 * PAD * PAD + 3 * PAD + 2) * sizeof(float))

static wscratch wscratch_at(void *mem)
{
    wscratch s;
    s.d = mem;
    s.hs = s.d + 3 * PAD * PAD;
    s.hc = s.hs + 2 * PAD;
    return s;
}

/* The NL-means patch distances at k = 1 between each pixel p of tile r and
 * p + (dx, dy), for each patch radius fs[k] (at most MAX_F; nf of them)
 * into its own outs[k]: per channel into out[c * TILE * TILE + i]
 * (per_channel) or, for the regression, the largest over the channels into
 * out[i], where i = (y - r.y0) * TILE + (x - r.x0); NLM_FAR where
 * p + (dx, dy) is outside the image and past the tile's edge. A distance
 * at k is this one / k^2 (eps scales with it), so candidates of several k
 * share it; radii share the per-pixel terms. The patch distance is the
 * mean of the per-pixel distances over the part of the patch where both
 * patches are inside the image: column sums, then row sums, each loop
 * running along x so that it vectorises (every element's sum keeps its
 * order; a radius's sums are the bits it would have alone). */
PT_SIMD_CLONES
static void patch_dist(const dims *dm, const guide *gd, rect r, int dx, int dy, int per_channel,
                       wscratch *s, int nf, const int *fs, float *const *outs)
{
    int w = dm->w, f = 0;
    const int tn = TILE * TILE;
    for (int k = 0; k < nf; k++) {
        f = imax(f, fs[k]);
        for (int i = 0; i < tn * (per_channel ? gd->nc : 1); i++)
            outs[k][i] = NLM_FAR;
    }
    /* p and p + (dx, dy) both inside the image */
    int vx0 = imax(r.x0, -dx), vx1 = imin(r.x1, w - dx);
    int vy0 = imax(r.y0, -dy), vy1 = imin(r.y1, dm->h - dy);
    if (vx0 >= vx1 || vy0 >= vy1)
        return;
    int px0 = imax(vx0 - f, imax(0, -dx)), px1 = imin(vx1 + f, imin(w, w - dx));
    int py0 = imax(vy0 - f, imax(0, -dy)), py1 = imin(vy1 + f, imin(dm->h, dm->h - dy));
    int pw = px1 - px0;
    for (int c = 0; c < gd->nc; c++) {
        const float *g = gd->g[c], *v = gd->v[c];
        float *d = s->d + (size_t)c * PAD * PAD;
        for (int y = py0; y < py1; y++) {
            const float *gp = g + (size_t)y * w + px0, *gq = g + (size_t)(y + dy) * w + px0 + dx;
            const float *vp = v + (size_t)y * w + px0, *vq = v + (size_t)(y + dy) * w + px0 + dx;
            float *drow = d + (size_t)(y - py0) * pw;
            for (int x = 0; x < pw; x++) {
                float a = vp[x], b = vq[x];
                float diff = gp[x] - gq[x];
                float dist = (diff * diff - (a + fmin2(a, b))) / (NLM_EPS + a + b);
                drow[x] = fmin2(dist, NLM_CLAMP);
            }
        }
        /* Each radius's sums from the same terms. [px0, px1) x [py0, py1)
         * is the largest radius's reach; for a smaller one, clipping its
         * patch to it clips it to the image alone, as its own reach would. */
        for (int k = 0; k < nf; k++) {
            f = fs[k];
            float *col = s->hs;
            float *o = outs[k] + (per_channel ? (size_t)c * tn : 0);
            int nx = vx1 - vx0;
            /* pixels in each output's patch row: the columns inside [px0, px1) */
            for (int x = vx0; x < vx1; x++)
                s->hc[x - vx0] = (float)(imin(x + f + 1, px1) - imax(x - f, px0));
            /* outputs whose whole patch row is inside [px0, px1) */
            int xa = imin(nx, imax(0, px0 - vx0 + f)), xb = imax(xa, imin(nx, px1 - vx0 - f));
            for (int y = vy0; y < vy1; y++) {
                int i0 = imax(y - f, py0), i1 = imin(y + f + 1, py1);
                /* Each sum in registers, 8 columns at a time, its terms in row
                 * order from 0: the bits of adding row by row into memory,
                 * without a store and a reload per term. */
                int xi = 0;
                for (; xi + 8 <= pw; xi += 8) {
                    v8f acc = {0};
                    for (int i = i0; i < i1; i++) {
                        v8f dv;
                        memcpy(&dv, d + (size_t)(i - py0) * pw + xi, sizeof dv);
                        acc += dv;
                    }
                    memcpy(col + xi, &acc, sizeof acc);
                }
                for (; xi < pw; xi++) {
                    float acc = 0.0f;
                    for (int i = i0; i < i1; i++)
                        acc += d[(size_t)(i - py0) * pw + xi];
                    col[xi] = acc;
                }
                float *orow = o + (y - r.y0) * TILE + (vx0 - r.x0);
                float *sum = s->hs + PAD;
                /* the patch row's columns in order from 0, those inside [px0, px1) */
                const float *cs = col + (vx0 - px0);
                for (xi = 0; xi < xa; xi++) {
                    float acc = 0.0f;
                    for (int t = -f; t <= f; t++)
                        if (xi + t + vx0 >= px0 && xi + t + vx0 < px1)
                            acc += cs[xi + t];
                    sum[xi] = acc;
                }
                for (; xi + 8 <= xb; xi += 8) {
                    v8f acc = {0};
                    for (int t = -f; t <= f; t++) {
                        v8f cv;
                        memcpy(&cv, cs + xi + t, sizeof cv);
                        acc += cv;
                    }
                    memcpy(sum + xi, &acc, sizeof acc);
                }
                for (; xi < nx; xi++) {
                    float acc = 0.0f;
                    for (int t = -f; t <= f; t++)
                        if (xi + t + vx0 >= px0 && xi + t + vx0 < px1)
                            acc += cs[xi + t];
                    sum[xi] = acc;
                }
                float rows = (float)(i1 - i0);
                for (int x = 0; x < nx; x++)
                    sum[x] = fmax2(sum[x] / (rows * s->hc[x]), 0.0f);
                if (per_channel || c == 0)
                    memcpy(orow, sum, sizeof(float) * (size_t)nx);
                else
                    for (int x = 0; x < nx; x++)
                        orow[x] = fmax2(orow[x], sum[x]);
            }
        }
    }
}

/* Weights of n distances at 1 / k^2 = inv_k2: exp(-d / k^2); the tile's
 * own pixels keep NLM_MIN_CENTER at least when this is the centre offset. */
PT_SIMD_CLONES
static void dist_weights(const float *dist, float inv_k2, rect r, int center, float *wt, int n)
{
    int i = 0;
    for (; i + 8 <= n; i += 8) {
        v8f v;
        memcpy(&v, dist + i, sizeof v);
        v *= inv_k2;
        exp_neg8(&v);
        memcpy(wt + i, &v, sizeof v);
    }
    for (; i < n; i++)
        wt[i] = exp_neg(dist[i] * inv_k2);
    if (center)
        for (int c = 0; c < n / (TILE * TILE); c++)
            for (int y = r.y0; y < r.y1; y++)
                for (int x = r.x0; x < r.x1; x++) {
                    float *o = wt + (size_t)c * TILE * TILE + (y - r.y0) * TILE + (x - r.x0);
                    *o = fmax2(*o, NLM_MIN_CENTER);
                }
}

/* ---- NL-means (per-channel weights), for the features, MSE and selection ---- */

typedef struct nlm_ctx {
    dims dm;
    guide gd;
    float inv_k2; /* 1 / k^2 */
    int r;        /* window radius */
    int ns;       /* channels filtered: channel j with the guide's j % nc weights */
    const float *src[6];
    float *dst[6];
} nlm_ctx;

#define NLM_SCRATCH_BYTES (WSCRATCH_BYTES + 6 * TILE * TILE * (sizeof(float) + 2 * sizeof(double)))

static int nlm_tile(void *vctx, int t, void *mem)
{
    nlm_ctx *cx = vctx;
    const dims *dm = &cx->dm;
    rect r = tile_rect(dm, t);
    const int tn = TILE * TILE;
    int nc = cx->gd.nc, ns = cx->ns;
    wscratch s = wscratch_at(mem);
    float *dist = (float *)(void *)((char *)mem + WSCRATCH_BYTES), *wt = dist + 3 * tn;
    double *acc = (double *)(void *)(wt + 3 * tn), *wsum = acc + 6 * tn;
    memset(acc, 0, sizeof(double) * 12 * tn);
    for (int dy = -cx->r; dy <= cx->r; dy++) {
        for (int dx = -cx->r; dx <= cx->r; dx++) {
            patch_dist(dm, &cx->gd, r, dx, dy, 1, &s, 1, &cx->gd.f, &dist);
            dist_weights(dist, cx->inv_k2, r, dx == 0 && dy == 0, wt, nc * tn);
            int vx0 = imax(r.x0, -dx), vx1 = imin(r.x1, dm->w - dx);
            int vy0 = imax(r.y0, -dy), vy1 = imin(r.y1, dm->h - dy);
            for (int c = 0; c < ns; c++) {
                const float *wc = wt + (size_t)(c % nc) * tn;
                for (int y = vy0; y < vy1; y++) {
                    const float *q = cx->src[c] + (size_t)(y + dy) * dm->w + dx;
                    for (int x = vx0; x < vx1; x++) {
                        int i = (y - r.y0) * TILE + (x - r.x0);
                        acc[c * tn + i] += (double)wc[i] * q[x];
                        wsum[c * tn + i] += wc[i];
                    }
                }
            }
        }
    }
    for (int c = 0; c < ns; c++)
        for (int y = r.y0; y < r.y1; y++)
            for (int x = r.x0; x < r.x1; x++) {
                int i = (y - r.y0) * TILE + (x - r.x0);
                cx->dst[c][(size_t)y * dm->w + x] = (float)(acc[c * tn + i] / wsum[c * tn + i]);
            }
    return 0;
}

/* NL-means of ns channels (at most 6, a multiple of gd->nc) with the
 * weights of gd at k: channel j with the guide channel j % nc's. */
static pt_status nlmeans(const dims *dm, unsigned threads, uint32_t weight, const guide *gd,
                         float k, int radius, int ns, const float *const src[], float *const dst[],
                         pt_error *err)
{
    nlm_ctx cx = {.dm = *dm, .gd = *gd, .inv_k2 = 1.0f / (k * k), .r = radius, .ns = ns};
    for (int c = 0; c < ns; c++) {
        cx.src[c] = src[c];
        cx.dst[c] = dst[c];
    }
    float *terms = guide_terms(dm, &cx.gd);
    if (!terms)
        return pt_error_set(err, PT_ERR_NOMEM, "denoise: out of memory");
    pt_status st = run_tiles(threads, dm, weight, NLM_SCRATCH_BYTES, nlm_tile, &cx, err);
    pt_free(terms);
    return st;
}

/* ---- first-order regression with collaborative accumulation ---- */

/* Candidates one regression computes: the same fits at several k. */
#define MAX_CAND 2

typedef struct reg_ctx {
    dims dm;
    guide gd;  /* weights: the other half (or the image itself) */
    int ncand; /* candidates: one per k */
    float inv_k2[MAX_CAND];
    int nf, f[MAX_CAND]; /* the patch radii, each once */
    int fi[MAX_CAND];    /* each candidate's: f[fi[m]] */
    const float *y[3];   /* the colour fitted */
    const float *feat[PT_DENOISE_FEATURES];
    double **tile_acc; /* per tile and candidate: 4 planes (R, G, B, weight) of RPAD x RPAD */
} reg_ctx;

/* A tile's neighbourhood: the tile (always TILE wide here) and the window's
 * reach around it, from (x0 - REG_R, y0 - REG_R); what lies outside the
 * image is 0 and has weight 0. */
#define RPAD (TILE + 2 * REG_R)
/* Unknowns' products: the upper triangle of the normal matrix. */
#define NTRI (DIM * (DIM + 1) / 2)
/* Four pixels of a row fitted at once, one per lane; each lane's sums are
 * taken in the order the scalar code would take them. */
#define LANES 4
typedef double v4d __attribute__((vector_size(LANES * sizeof(double))));

#define REG_SCRATCH_BYTES                                                                          \
    (WSCRATCH_BYTES + (size_t)(MAX_CAND * WIN + MAX_CAND) * TILE * TILE * sizeof(float) +          \
     (size_t)(PT_DENOISE_FEATURES + 3) * RPAD * RPAD * sizeof(float))

#define load4(p) ((v4d){(p)[0], (p)[1], (p)[2], (p)[3]})

/* Weighted least squares by the normal equations in double, Gaussian
 * elimination with the pivots in column order; a column whose pivot falls
 * to 1e-10 of its own weighted sum of squares (a feature constant over the
 * window, or a combination of the columns before it: grey albedo, a flat
 * depth) is dropped, its coefficient 0, so the fit stays defined. The
 * constant's column has the centre weight at least: never dropped. The
 * four lanes' systems at once (tri: the upper triangle by rows), each lane
 * with the operations one system alone would take: a dropped column's
 * multipliers are 0 in its lane, and subtracting 0 x a finite value
 * leaves every element's bits as skipping it did. */
typedef long long v4l __attribute__((vector_size(LANES * sizeof(long long))));
static inline __attribute__((always_inline)) void
solve_wls4(const v4d tri[NTRI], const v4d rhs[DIM][3], v4d beta[DIM][3])
{
    v4d a[DIM][DIM], b[DIM][3], diag0[DIM];
    v4l keep[DIM];
    const v4d zero = {0.0, 0.0, 0.0, 0.0};
    int m = 0;
    for (int j = 0; j < DIM; j++) {
        for (int k = j; k < DIM; k++)
            a[j][k] = a[k][j] = tri[m++];
        for (int c = 0; c < 3; c++)
            b[j][c] = rhs[j][c];
        diag0[j] = a[j][j];
    }
    for (int j = 0; j < DIM; j++) {
        v4d piv = a[j][j];
        keep[j] = (diag0[j] > zero) & (piv > 1e-10 * diag0[j]);
        for (int i = j + 1; i < DIM; i++) {
            v4d mj = a[i][j] / piv;
            mj = (v4d)((v4l)mj & keep[j]);
            for (int k = j; k < DIM; k++)
                a[i][k] -= mj * a[j][k];
            for (int c = 0; c < 3; c++)
                b[i][c] -= mj * b[j][c];
        }
    }
    for (int j = DIM - 1; j >= 0; j--) {
        for (int c = 0; c < 3; c++) {
            v4d sum = b[j][c];
            for (int k = j + 1; k < DIM; k++)
                sum -= a[j][k] * beta[k][c];
            beta[j][c] = (v4d)((v4l)(sum / a[j][j]) & keep[j]);
        }
    }
}

/* Every fit of one row group of a tile: 4 pixels from (lx0, ly) (tile
 * coordinates); pixels past the tile's width have no weight and no fit. */
PT_SIMD_CLONES
static void fit_lanes(const float *wt, const float *loc, int lx0, int ly, int tw, double *acc)
{
    const int side = 2 * REG_R + 1, rn = RPAD * RPAD;
    const int pc = (ly + REG_R) * RPAD + lx0 + REG_R;
    const float *feat = loc, *col = loc + (size_t)PT_DENOISE_FEATURES * rn;
    v4d a[NTRI], b[DIM][3], fp[PT_DENOISE_FEATURES], x[DIM];
    memset(a, 0, sizeof a);
    memset(b, 0, sizeof b);
    memset(x, 0, sizeof x);
    for (int k = 0; k < PT_DENOISE_FEATURES; k++)
        fp[k] = load4(feat + (size_t)k * rn + pc);
    for (int dy = -REG_R; dy <= REG_R; dy++) {
        for (int dx = -REG_R; dx <= REG_R; dx++) {
            const float *wp =
                wt + (size_t)((dy + REG_R) * side + dx + REG_R) * TILE * TILE + ly * TILE + lx0;
            if (wp[0] == 0.0f && wp[1] == 0.0f && wp[2] == 0.0f && wp[3] == 0.0f)
                continue;
            v4d wv = load4(wp);
            int qc = pc + dy * RPAD + dx;
            x[0] = (v4d){1.0, 1.0, 1.0, 1.0};
            x[1] = (v4d){dx, dx, dx, dx};
            x[2] = (v4d){dy, dy, dy, dy};
            for (int k = 0; k < PT_DENOISE_FEATURES; k++)
                x[3 + k] = load4(feat + (size_t)k * rn + qc) - fp[k];
            v4d y[3] = {load4(col + qc), load4(col + rn + qc), load4(col + 2 * rn + qc)};
            int m = 0;
#pragma GCC unroll 16
            for (int j = 0; j < DIM; j++) {
                v4d wx = wv * x[j];
#pragma GCC unroll 16
                for (int k = j; k < DIM; k++)
                    a[m++] += wx * x[k];
#pragma GCC unroll 4
                for (int c = 0; c < 3; c++)
                    b[j][c] += wx * y[c];
            }
        }
    }
    v4d beta[DIM][3];
    solve_wls4(a, b, beta);
    /* lanes past the tile's width: no fit */
    for (int l = tw - lx0; l < LANES; l++)
        for (int j = 0; j < DIM; j++)
            for (int c = 0; c < 3; c++)
                beta[j][c][l] = 0.0;
    /* Each fit predicts its window; the predictions land with their weights. */
    for (int dy = -REG_R; dy <= REG_R; dy++) {
        for (int dx = -REG_R; dx <= REG_R; dx++) {
            const float *wp =
                wt + (size_t)((dy + REG_R) * side + dx + REG_R) * TILE * TILE + ly * TILE + lx0;
            if (wp[0] == 0.0f && wp[1] == 0.0f && wp[2] == 0.0f && wp[3] == 0.0f)
                continue;
            v4d wv = load4(wp);
            int qc = pc + dy * RPAD + dx;
            x[0] = (v4d){1.0, 1.0, 1.0, 1.0};
            x[1] = (v4d){dx, dx, dx, dx};
            x[2] = (v4d){dy, dy, dy, dy};
            for (int k = 0; k < PT_DENOISE_FEATURES; k++)
                x[3 + k] = load4(feat + (size_t)k * rn + qc) - fp[k];
#pragma GCC unroll 4
            for (int c = 0; c < 4; c++) {
                v4d add = wv;
                if (c < 3) {
                    v4d pred = x[0] * beta[0][c];
#pragma GCC unroll 16
                    for (int j = 1; j < DIM; j++)
                        pred += x[j] * beta[j][c];
                    add = wv * pred;
                }
                v4d cur;
                memcpy(&cur, acc + (size_t)c * rn + qc, sizeof cur);
                cur += add;
                memcpy(acc + (size_t)c * rn + qc, &cur, sizeof cur);
            }
        }
    }
}

static int reg_tile(void *vctx, int t, void *mem)
{
    reg_ctx *cx = vctx;
    const dims *dm = &cx->dm;
    const int rn = RPAD * RPAD, tn = TILE * TILE;
    rect r = tile_rect(dm, t);
    int tw = r.x1 - r.x0;
    wscratch s = wscratch_at(mem);
    float *wt = (float *)(void *)((char *)mem + WSCRATCH_BYTES);
    float *dist = wt + (size_t)MAX_CAND * WIN * tn;
    float *dists[MAX_CAND] = {dist, dist + tn};
    float *loc = dist + (size_t)MAX_CAND * tn;
    for (int m = 0; m < cx->ncand; m++) {
        double *acc = pt_calloc(4 * (size_t)rn, sizeof(double));
        if (!acc)
            return -1;
        cx->tile_acc[t * cx->ncand + m] = acc;
    }
    /* The features and the colour around the tile, 0 outside the image. */
    for (int k = 0; k < PT_DENOISE_FEATURES + 3; k++) {
        const float *src = k < PT_DENOISE_FEATURES ? cx->feat[k] : cx->y[k - PT_DENOISE_FEATURES];
        float *dst = loc + (size_t)k * rn;
        for (int ly = 0; ly < RPAD; ly++) {
            int gy = r.y0 - REG_R + ly;
            for (int lx = 0; lx < RPAD; lx++) {
                int gx = r.x0 - REG_R + lx;
                int in = gx >= 0 && gx < dm->w && gy >= 0 && gy < dm->h;
                dst[ly * RPAD + lx] = in ? src[(size_t)gy * dm->w + gx] : 0.0f;
            }
        }
    }
    /* One distance per offset and patch radius, a weight per candidate:
     * candidates of the same radius share the distance. */
    const int side = 2 * REG_R + 1;
    for (int dy = -REG_R; dy <= REG_R; dy++)
        for (int dx = -REG_R; dx <= REG_R; dx++) {
            int o = (dy + REG_R) * side + dx + REG_R;
            patch_dist(dm, &cx->gd, r, dx, dy, 0, &s, cx->nf, cx->f, dists);
            for (int m = 0; m < cx->ncand; m++)
                dist_weights(dists[cx->fi[m]], cx->inv_k2[m], r, dx == 0 && dy == 0,
                             wt + ((size_t)m * WIN + o) * tn, tn);
        }
    for (int m = 0; m < cx->ncand; m++)
        for (int ly = 0; ly < r.y1 - r.y0; ly++)
            for (int lx0 = 0; lx0 < tw; lx0 += LANES)
                fit_lanes(wt + (size_t)m * WIN * tn, loc, lx0, ly, tw,
                          cx->tile_acc[t * cx->ncand + m]);
    return 0;
}

/* Filters y (3 channels) by collaborative first-order regression on the
 * features with weights from gd, once per k in ks[0..ncand-1] with the
 * patch radius fs[m] (at most MAX_F) into out[m][0..2] (which may not alias
 * y). */
static pt_status regression(const dims *dm, unsigned threads, uint32_t weight, const guide *gd,
                            int ncand, const float *ks, const int *fs, const float *const y[3],
                            const float *const feat[], float *const *const out[], pt_error *err)
{
    int ntiles = dm->tx * dm->ty;
    size_t n = (size_t)dm->w * dm->h;
    reg_ctx cx = {.dm = *dm, .gd = *gd, .ncand = ncand};
    for (int m = 0; m < ncand; m++) {
        cx.inv_k2[m] = 1.0f / (ks[m] * ks[m]);
        int j = 0;
        while (j < cx.nf && cx.f[j] != fs[m])
            j++;
        if (j == cx.nf)
            cx.f[cx.nf++] = fs[m];
        cx.fi[m] = j;
    }
    for (int c = 0; c < 3; c++)
        cx.y[c] = y[c];
    for (int k = 0; k < PT_DENOISE_FEATURES; k++)
        cx.feat[k] = feat[k];
    cx.tile_acc = pt_calloc((size_t)ntiles * (size_t)ncand, sizeof(double *));
    double *sum = pt_malloc_array(4 * n, sizeof(double));
    float *terms = guide_terms(dm, &cx.gd);
    pt_status st = PT_OK;
    if (!cx.tile_acc || !sum || !terms) {
        st = pt_error_set(err, PT_ERR_NOMEM, "denoise: out of memory");
        goto done;
    }
    if ((st = run_tiles(threads, dm, weight, REG_SCRATCH_BYTES, reg_tile, &cx, err)) != PT_OK)
        goto done;
    for (int m = 0; m < ncand; m++) {
        memset(sum, 0, 4 * n * sizeof(double));
        /* Tile order: the sums do not depend on which thread made them. */
        for (int t = 0; t < ntiles; t++) {
            rect r = tile_rect(dm, t);
            int ox = r.x0 - REG_R, oy = r.y0 - REG_R;
            double *acc = cx.tile_acc[t * ncand + m];
            for (int c = 0; c < 4; c++)
                for (int yy = imax(oy, 0); yy < imin(oy + RPAD, dm->h); yy++)
                    for (int xx = imax(ox, 0); xx < imin(ox + RPAD, dm->w); xx++)
                        sum[(size_t)c * n + (size_t)yy * dm->w + xx] +=
                            acc[(size_t)c * RPAD * RPAD + (size_t)(yy - oy) * RPAD + (xx - ox)];
            pt_free(acc);
            cx.tile_acc[t * ncand + m] = NULL;
        }
        for (size_t i = 0; i < n; i++)
            for (int c = 0; c < 3; c++)
                out[m][c][i] = (float)(sum[c * n + i] / sum[3 * n + i]);
    }
done:
    if (cx.tile_acc)
        for (int t = 0; t < ntiles * ncand; t++)
            pt_free(cx.tile_acc[t]);
    pt_free(cx.tile_acc);
    pt_free(sum);
    pt_free(terms);
    return st;
}

/* ---- input checks ---- */

static pt_status check_plane(const pt_denoise_input *in, const float *p, const char *name, float lo,
                             float hi, pt_error *err)
{
    if (!p)
        return pt_error_set(err, PT_ERR_ARG, "denoise: no %s plane", name);
    size_t n = (size_t)in->width * in->height;
    for (size_t i = 0; i < n; i++) {
        float v = p[i];
        if (isfinite(v) && v >= lo && v <= hi)
            continue;
        return pt_error_set(err, PT_ERR_FORMAT, "denoise: %s at (%zu, %zu) is %g, not in [%g, %g]",
                            name, i % in->width, i / in->width, (double)v, (double)lo, (double)hi);
    }
    return PT_OK;
}

pt_status pt_denoise_check(const pt_denoise_input *in, pt_error *err)
{
    if (!in)
        return pt_error_set(err, PT_ERR_ARG, "denoise: no input");
    pt_status st = pt_image_check_size("denoise input", in->width, in->height, err);
    if (st != PT_OK)
        return st;
    static const char *const rgb[3] = {"R", "G", "B"}, *const xyz[3] = {"X", "Y", "Z"};
    const float M = PT_DENOISE_MAX_VALUE;
    char name[32];
    for (int c = 0; c < 3; c++) {
        snprintf(name, sizeof name, "halfA.%s", rgb[c]);
        if ((st = check_plane(in, in->half_a[c], name, -M, M, err)) != PT_OK)
            return st;
        snprintf(name, sizeof name, "halfB.%s", rgb[c]);
        if ((st = check_plane(in, in->half_b[c], name, -M, M, err)) != PT_OK)
            return st;
        if ((st = check_plane(in, in->color[c], rgb[c], -M, M, err)) != PT_OK)
            return st;
        snprintf(name, sizeof name, "albedo.%s", rgb[c]);
        if ((st = check_plane(in, in->albedo[c], name, 0.0f, M, err)) != PT_OK)
            return st;
        snprintf(name, sizeof name, "N.%s", xyz[c]);
        if ((st = check_plane(in, in->normal[c], name, -1.001f, 1.001f, err)) != PT_OK)
            return st;
    }
    if (!(in->despeckle == 0.0f ||
          (in->despeckle >= 1.0f && in->despeckle <= PT_DENOISE_DESPECKLE_MAX)))
        return pt_error_set(err, PT_ERR_ARG, "denoise: despeckle %g is not 0 or in [1, %g]",
                            (double)in->despeckle, (double)PT_DENOISE_DESPECKLE_MAX);
    if ((st = check_plane(in, in->variance, "variance", 0.0f, M, err)) != PT_OK ||
        (st = check_plane(in, in->albedo_var, "albedo.variance", 0.0f, M, err)) != PT_OK ||
        (st = check_plane(in, in->normal_var, "N.variance", 0.0f, M, err)) != PT_OK ||
        (st = check_plane(in, in->depth, "depth.Z", 0.0f, M, err)) != PT_OK ||
        (st = check_plane(in, in->depth_var, "depth.variance", 0.0f, M, err)) != PT_OK)
        return st;
    return PT_OK;
}

/* ---- the pipeline ---- */

static float lum3(const float *const p[3], size_t i)
{
    return 0.2126f * p[0][i] + 0.7152f * p[1][i] + 0.0722f * p[2][i];
}

/* Fireflies, before NFOR (which has no rule for them: a spike's huge
 * variance makes it "similar" to every neighbour, and its fit spreads it):
 * one half's pixel whose luminance is over factor x the largest luminance
 * of the other half's 3 x 3 neighbourhood is scaled down to that. A spike
 * that one half's samples have and the other half's do not, around it
 * either, is one rare sample; a feature of the picture, even one pixel
 * wide, is seen by both halves' samples and stays. The pixel's variance
 * is scaled by the square of the factor applied (*vscale, 1 elsewhere),
 * as the spike made it. factor 0: nothing changes. */
static void despeckle(const pt_denoise_input *in, float factor, float *const da[3],
                      float *const db[3], float *vscale)
{
    for (size_t i = 0; i < (size_t)in->width * in->height; i++)
        vscale[i] = 1.0f;
    int w = (int)in->width, h = (int)in->height;
    for (int k = 0; k < 2; k++) {
        const float *const *src = k ? in->half_b : in->half_a, *const *oth =
                                                                   k ? in->half_a : in->half_b;
        float *const *dst = k ? db : da;
        for (int y = 0; y < h; y++)
            for (int x = 0; x < w; x++) {
                size_t i = (size_t)y * w + x;
                float scale = 1.0f;
                if (factor > 0.0f) {
                    float m = 0.0f;
                    for (int yy = imax(y - 1, 0); yy <= imin(y + 1, h - 1); yy++)
                        for (int xx = imax(x - 1, 0); xx <= imin(x + 1, w - 1); xx++)
                            m = fmax2(m, lum3(oth, (size_t)yy * w + xx));
                    float l = lum3(src, i), cap = factor * m;
                    if (l > cap && l > 0.0f)
                        scale = cap / l;
                }
                for (int c = 0; c < 3; c++)
                    dst[c][i] = src[c][i] * scale;
                vscale[i] = fmin2(vscale[i], scale * scale);
            }
    }
}

/* Light the despeckling took, put back: the clamp alone lost 4.2 % of
 * ToyCar's mean in the park, whose glass and sunlit roof make fireflies that
 * hold that much of the picture's light. What a pixel's halves lost,
 * rem = ((A - A') + (B - B')) / 2 per channel, is splatted over the pixels
 * of the same surface around it, the pixel itself left out (a firefly
 * splatted onto itself comes back): weights
 *   w_ij = exp(-|p_i - p_j|^2 / (2 SPLAT_SIGMA^2) - |n_i - n_j|^2 / SPLAT_NORMAL^2
 *              - ((z_i - z_j) / z_j)^2 / SPLAT_DEPTH^2) (L_i^2 + SPLAT_FLOOR)
 * on the prefiltered normal and depth over a (2 SPLAT_R + 1)^2 window, L_i
 * the luminance of the filtered blend (bright), normalised for each source
 * j, so every source hands out exactly what it lost: the image's sum is
 * kept. The expectation a firefly stands for is spread over its
 * neighbourhood (which pixels, no estimator of 64 samples can tell): spread
 * wide, and in proportion to L^2, each pixel's relative squared error, what
 * relMSE counts, stays small (a glint's light lands on the glints around
 * it, not as a glow on the dark surface between them). A pixel takes back
 * at most SPLAT_GAIN x its own filtered luminance over all sources (recv
 * counts what it got): a firefly far brighter than everything around it
 * (ToyCar at 256 spp: one path through the glass worth 0.8 % of the
 * image) would otherwise double a whole patch; what finds no room is
 * dropped, the only light the rules lose. This is the energy-conserving side of
 * firefly splatting (Zirr, Hanika and Dachsbacher 2018, "Re-weighting firefly samples for improved
 * finite-sample Monte Carlo estimates", Computer Graphics Forum 37(6): a
 * clamped sample's excess is redistributed, not dropped). Measured, 64 spp
 * against a 4096-spp reference: on 9 x 9 windows, or weighted by albedo
 * too (a textured surface has few pixels alike), the light came back to
 * the firefly's few neighbours and DamagedHelmet in the studio rose from
 * 4.7e-3 to 8.5e-3 relMSE; without the normal and depth, ToyCar's sunlit
 * roof lit the grass behind it (4.1e-2); without L^2, DamagedHelmet in the
 * park at 16 spp went from 1.3e-3 raw to 7.6e-2, a sun glint of 450 spread
 * as a blob of 1.9 over a surface of 0.1 (1.7e-3 with it; the studio
 * helmet 5.5e-3 -> 5.1e-3 at 64 spp). Sources in pixel order, one
 * thread: the same bits always; sources are few. */
#define SPLAT_R 24
#define SPLAT_SIGMA 12.0f
#define SPLAT_NORMAL 0.5f
#define SPLAT_DEPTH 0.1f
#define SPLAT_FLOOR 1e-4f
#define SPLAT_GAIN 1.0f

static void splat_removed(const dims *dm, const float *const rem[3], const float *const feat[],
                          const float *const bright[3], float *recv, float *const out[3])
{
    int w = dm->w, h = dm->h;
    const int side = 2 * SPLAT_R + 1;
    float wt[(2 * SPLAT_R + 1) * (2 * SPLAT_R + 1)];
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            size_t j = (size_t)y * w + x;
            if (rem[0][j] == 0.0f && rem[1][j] == 0.0f && rem[2][j] == 0.0f)
                continue;
            float zj = feat[6][j];
            double sum = 0.0;
            for (int dy = -SPLAT_R; dy <= SPLAT_R; dy++)
                for (int dx = -SPLAT_R; dx <= SPLAT_R; dx++) {
                    int xx = x + dx, yy = y + dy, o = (dy + SPLAT_R) * side + dx + SPLAT_R;
                    wt[o] = 0.0f;
                    if (xx < 0 || xx >= w || yy < 0 || yy >= h || (dx == 0 && dy == 0))
                        continue;
                    size_t i = (size_t)yy * w + xx;
                    float dn = 0.0f;
                    for (int c = 0; c < 3; c++) {
                        float nv = feat[3 + c][i] - feat[3 + c][j];
                        dn += nv * nv;
                    }
                    /* an escaped ray's depth is 0: the same "surface" only as another */
                    float dz = zj > 0.0f ? (feat[6][i] - zj) / zj : feat[6][i] > 0.0f ? 1.0f : 0.0f;
                    float d = (float)(dx * dx + dy * dy) / (2.0f * SPLAT_SIGMA * SPLAT_SIGMA) +
                              dn / (SPLAT_NORMAL * SPLAT_NORMAL) +
                              dz * dz / (SPLAT_DEPTH * SPLAT_DEPTH);
                    float l = fmax2(lum3(bright, i), 0.0f);
                    wt[o] = exp_neg(d) * (l * l + SPLAT_FLOOR);
                    sum += wt[o];
                }
            if (!(sum > 0.0)) {
                /* nothing alike around (a 1 x 1 image): the light stays */
                wt[SPLAT_R * side + SPLAT_R] = 1.0f;
                sum = 1.0;
            }
            for (int dy = -SPLAT_R; dy <= SPLAT_R; dy++)
                for (int dx = -SPLAT_R; dx <= SPLAT_R; dx++) {
                    float wv = wt[(dy + SPLAT_R) * side + dx + SPLAT_R];
                    if (wv == 0.0f)
                        continue;
                    size_t i = (size_t)(y + dy) * w + (x + dx);
                    float add[3];
                    for (int c = 0; c < 3; c++)
                        add[c] = (float)((double)rem[c][j] * wv / sum);
                    float la = 0.2126f * add[0] + 0.7152f * add[1] + 0.0722f * add[2];
                    float room = SPLAT_GAIN * fmax2(lum3(bright, i), 0.0f) - recv[i];
                    float f = la > room ? (room > 0.0f ? room / la : 0.0f) : 1.0f;
                    for (int c = 0; c < 3; c++)
                        out[c][i] += f * add[c];
                    recv[i] += f * la;
                }
        }
}

/* A variance estimate that one rare sample inflated makes its pixel
 * "similar" to every neighbour in the patch distances, and the fits
 * centred there reach far: a pixel's variance over VAR_CAP x the median of
 * its 3 x 3 neighbourhood's is capped to that (*vscale multiplied by the
 * factor; tmp: width x height floats of scratch). On DamagedHelmet in the
 * studio at 64 spp (4096-spp reference): relMSE 6.71e-3 -> 4.20e-3; the
 * Cornell box 1.07e-4 -> 1.11e-4. */
static void variance_cap(const pt_denoise_input *in, float *vscale, float *tmp)
{
    int w = (int)in->width, h = (int)in->height;
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            float v9[9];
            int m = 0;
            for (int yy = imax(y - 1, 0); yy <= imin(y + 1, h - 1); yy++)
                for (int xx = imax(x - 1, 0); xx <= imin(x + 1, w - 1); xx++) {
                    size_t j = (size_t)yy * w + xx;
                    float v = in->variance[j] * vscale[j];
                    int k = m++;
                    /* insertion: v9[0..m) sorted */
                    while (k > 0 && v9[k - 1] > v) {
                        v9[k] = v9[k - 1];
                        k--;
                    }
                    v9[k] = v;
                }
            size_t i = (size_t)y * w + x;
            float cap = VAR_CAP * v9[m / 2], v = in->variance[i] * vscale[i];
            tmp[i] = v > cap ? cap / v : 1.0f;
        }
    for (size_t i = 0; i < (size_t)w * h; i++)
        vscale[i] *= tmp[i];
}

/* Internal planes, one allocation. */
enum {
    P_FEAT = 0,                          /* 7 prefiltered features */
    P_FA = P_FEAT + PT_DENOISE_FEATURES, /* 2 candidates x 3: half A filtered */
    P_FB = P_FA + 6,                     /* 2 x 3: half B filtered */
    P_MSE = P_FB + 6,                    /* 2 x 3: smoothed MSE estimates */
    P_TMP = P_MSE + 6,                   /* 6: noisy MSE, then the noisy selection */
    P_SEL = P_TMP + 6,                   /* 3: the smoothed selection map */
    P_VAR = P_SEL + 3,                   /* 3: variance of the blend's mean */
    P_CVAR = P_VAR + 3,                  /* 3: the beauty's variance per channel */
    P_HVAR = P_CVAR + 3,                 /* 3: a half's variance per channel (2 x) */
    P_COMB = P_HVAR + 3,                 /* 3: the blend's mean */
    P_HA = P_COMB + 3,                   /* 3 + 3: the halves, spikes clamped */
    P_HB = P_HA + 3,
    P_VS = P_HB + 3,    /* 1: the variance's factor after despeckling */
    P_REM = P_VS + 1,   /* 3: the light despeckling took */
    P_RECV = P_REM + 3, /* 1: the light a pixel received back */
    P_COUNT = P_RECV + 1
};

/* pt_denoise of an input pt_denoise_check passed (the caller ran it: the
 * whole image's check covers its crops), its progress mapped to
 * [base, base + span] thousandths. */
static pt_status denoise_run(const pt_denoise_input *in, unsigned threads, float *const out[3],
                             uint32_t base, uint32_t span, pt_error *err)
{
    pt_status st = PT_OK;
    if (!out || !out[0] || !out[1] || !out[2])
        return pt_error_set(err, PT_ERR_ARG, "denoise: no output planes");
    if (threads == 0)
        threads = 1;
    if (threads > PT_DENOISE_MAX_THREADS)
        return pt_error_set(err, PT_ERR_ARG, "denoise: %u threads, at most %u", threads,
                            PT_DENOISE_MAX_THREADS);
    progress pg = {.out = in->progress, .base = base, .span = span};
    atomic_init(&pg.done, 0);
    dims dm = {(int)in->width,
               (int)in->height,
               ((int)in->width + TILE - 1) / TILE,
               ((int)in->height + TILE - 1) / TILE,
               in->cancel,
               &pg};
    pg.total = (uint64_t)dm.tx * dm.ty * W_TILE;
    size_t n = (size_t)in->width * in->height;
    float *mem = pt_malloc_array(n * P_COUNT, sizeof(float));
    if (!mem)
        return pt_error_set(err, PT_ERR_NOMEM, "denoise: out of memory for %ux%u", in->width,
                            in->height);
    float *pl[P_COUNT];
    for (int i = 0; i < P_COUNT; i++)
        pl[i] = mem + (size_t)i * n;

    const float *ha[3], *hb[3];
    despeckle(in, in->despeckle, pl + P_HA, pl + P_HB, pl[P_VS]);
    if (in->despeckle > 0.0f)
        variance_cap(in, pl[P_VS], pl[P_COMB]);
    for (int c = 0; c < 3; c++) {
        ha[c] = pl[P_HA + c];
        hb[c] = pl[P_HB + c];
    }

    /* 1. Features, each through NL-means guided by itself (sec. 5.1). */
    const float *fin[PT_DENOISE_FEATURES] = {in->albedo[0], in->albedo[1], in->albedo[2],
                                             in->normal[0], in->normal[1], in->normal[2],
                                             in->depth};
    const float *fvar[3] = {in->albedo_var, in->normal_var, in->depth_var};
    for (int g = 0; g < 3 && st == PT_OK; g++) {
        int first = 3 * g, nc = g < 2 ? 3 : 1;
        guide gd = {.nc = nc, .vscale = 1.0f, .f = FEAT_F};
        for (int c = 0; c < nc; c++) {
            gd.g[c] = fin[first + c];
            gd.v[c] = fvar[g];
        }
        st = nlmeans(&dm, threads, W_FEAT, &gd, FEAT_K, FEAT_R, nc, fin + first,
                     pl + P_FEAT + first, err);
    }
    if (st != PT_OK)
        goto done;
    const float *const *feat = (const float *const *)(pl + P_FEAT);

    /* 2. Two candidates (k = 0.5, 1), each half filtered with the other's
     * weights (sec. 5.2). Not the paper's: the strict candidate (k = 0.5)
     * compares 3 x 3 patches, the loose one (k = 1) the paper's 7 x 7. A
     * small patch tells neighbours apart by the pixels next to them only,
     * so a pixel beside an edge, a corner or a shadow's border (what the
     * features do not explain) still finds the neighbours along it,
     * strictly; the large one averages the noise of more pixels for the
     * smooth parts; the selection (step 3) takes each where its estimated
     * error is lower. Measured, 64 spp against 16,384-spp references
     * (docs/bench/denoise.md): the Cornell box 8.84e-5 -> 7.79e-5 relMSE,
     * DamagedHelmet in the studio 4.96e-3 -> 4.91e-3, ToyCar in the park
     * 2.35e-3 -> 2.32e-3 (its mean as before), DamagedHelmet in the park
     * and SheenChair as before; 3 x 3 for the loose candidate too took the
     * Cornell box to 7.26e-5 but the studio helmet to 5.80e-3 and ToyCar's
     * mean to 0.961 of the raw image's. */
    /* The beauty's variance is luminance's; a channel's is taken as
     * luminance's x (channel / luminance)^2, exact for noise that scales
     * the pixel's colour (a path's throughput times a random factor): a
     * red wall's R varies more than its luminance. A half has half the
     * samples: twice the variance. */
    for (size_t i = 0; i < n; i++) {
        float lum =
            0.2126f * in->color[0][i] + 0.7152f * in->color[1][i] + 0.0722f * in->color[2][i];
        for (int c = 0; c < 3; c++) {
            float ratio = lum > 0.0f && in->color[c][i] > 0.0f ? in->color[c][i] / lum : 1.0f;
            float v = in->variance[i] * pl[P_VS][i] * fmin2(ratio * ratio, VAR_RATIO_MAX);
            pl[P_CVAR + c][i] = v;
            pl[P_HVAR + c][i] = 2.0f * v;
        }
    }
    static const float cand_k[2] = {0.5f, 1.0f};
    static const int cand_f[2] = {REG_F_STRICT, REG_F};
    guide ga = {.nc = 3, .vscale = 1.0f, .f = REG_F, .tol2 = NLM_TOL2};
    guide gb = ga;
    for (int c = 0; c < 3; c++) {
        ga.g[c] = hb[c]; /* A is filtered with B's weights */
        gb.g[c] = ha[c];
        ga.v[c] = gb.v[c] = pl[P_HVAR + c];
    }
    float *const fa[2][3] = {{pl[P_FA], pl[P_FA + 1], pl[P_FA + 2]},
                             {pl[P_FA + 3], pl[P_FA + 4], pl[P_FA + 5]}};
    float *const fb[2][3] = {{pl[P_FB], pl[P_FB + 1], pl[P_FB + 2]},
                             {pl[P_FB + 3], pl[P_FB + 4], pl[P_FB + 5]}};
    float *const *const outa[2] = {fa[0], fa[1]}, *const *const outb[2] = {fb[0], fb[1]};
    if ((st = regression(&dm, threads, W_REG, &ga, 2, cand_k, cand_f, ha, feat, outa, err)) !=
            PT_OK ||
        (st = regression(&dm, threads, W_REG, &gb, 2, cand_k, cand_f, hb, feat, outb, err)) !=
            PT_OK)
        goto done;
    /* 3. Each candidate's MSE from the halves' cross errors (sec. 5.3). */
    for (int k = 0; k < 2; k++) {
        for (int c = 0; c < 3; c++) {
            const float *fak = pl[P_FA + 3 * k + c], *fbk = pl[P_FB + 3 * k + c];
            float *noisy = pl[P_TMP + 3 * k + c];
            for (size_t i = 0; i < n; i++) {
                float hv = pl[P_HVAR + c][i];
                float ea = (hb[c][i] - fak[i]) * (hb[c][i] - fak[i]) - hv;
                float eb = (ha[c][i] - fbk[i]) * (ha[c][i] - fbk[i]) - hv;
                float res = 0.25f * (fbk[i] - fak[i]) * (fbk[i] - fak[i]);
                noisy[i] = 0.5f * (ea + eb) - res;
            }
        }
    }
    /* Both estimates smoothed with one set of weights, from the colour,
     * with the regression's variance floor: a pixel's estimate is the
     * noisy (B - F_A)^2 - var B, whose sign between the candidates is a
     * coin toss pixel by pixel; only their sums over neighbours choose.
     * Without the floor an edge pixel beside a noise-free textured
     * background (SheenChair against the studio's curtain) found no
     * neighbour in the smoothing and kept its own toss: the edge column of
     * test_selection_edge keeps 0.44 to 0.47 of its raw MSE, 0.25 to 0.28
     * with the floor; SheenChair 3.42e-4 -> 3.14e-4 relMSE at 64 spp
     * (16,384-spp reference), the other four scenes within 0.04 %
     * (docs/bench/denoise.md). */
    guide gc = {.nc = 3, .vscale = 1.0f, .f = MSE_F, .tol2 = NLM_TOL2};
    for (int c = 0; c < 3; c++) {
        gc.g[c] = in->color[c];
        gc.v[c] = pl[P_CVAR + c];
    }
    if ((st = nlmeans(&dm, threads, W_MSE, &gc, 1.0f, MSE_R, 6, (const float *const *)(pl + P_TMP),
                      pl + P_MSE, err)) != PT_OK)
        goto done;
    /* The choice map, smoothed like the estimates, blends the candidates. */
    for (int c = 0; c < 3; c++)
        for (size_t i = 0; i < n; i++)
            pl[P_TMP + c][i] = pl[P_MSE + c][i] < pl[P_MSE + 3 + c][i] ? 0.0f : 1.0f;
    if ((st = nlmeans(&dm, threads, W_SEL, &gc, 1.0f, MSE_R, 3, (const float *const *)(pl + P_TMP),
                      pl + P_SEL, err)) != PT_OK)
        goto done;
    for (int c = 0; c < 3; c++) {
        for (size_t i = 0; i < n; i++) {
            float sel = pl[P_SEL + c][i];
            /* a + s (b - a): exactly a where the candidates agree */
            float a0 = pl[P_FA + c][i], a1 = pl[P_FA + 3 + c][i];
            float b0 = pl[P_FB + c][i], b1 = pl[P_FB + 3 + c][i];
            float ra = a0 + sel * (a1 - a0), rb = b0 + sel * (b1 - b0);
            pl[P_COMB + c][i] = 0.5f * (ra + rb);
            pl[P_VAR + c][i] = 0.25f * (rb - ra) * (rb - ra);
        }
    }
    /* 4. The second pass over the blend's mean (sec. 5.4). */
    guide gf = {.nc = 3, .vscale = 1.0f, .f = REG_F};
    for (int c = 0; c < 3; c++) {
        gf.g[c] = pl[P_COMB + c];
        gf.v[c] = pl[P_VAR + c];
    }
    static const float final_k[1] = {1.0f};
    static const int final_f[1] = {REG_F};
    float *const *const outf[1] = {out};
    st = regression(&dm, threads, W_FINAL, &gf, 1, final_k, final_f,
                    (const float *const *)(pl + P_COMB), feat, outf, err);
    if (st == PT_OK && in->despeckle > 0.0f) {
        for (int c = 0; c < 3; c++)
            for (size_t i = 0; i < n; i++)
                pl[P_REM + c][i] =
                    0.5f * ((in->half_a[c][i] - ha[c][i]) + (in->half_b[c][i] - hb[c][i]));
        memset(pl[P_RECV], 0, n * sizeof(float));
        splat_removed(&dm, (const float *const *)(pl + P_REM), feat,
                      (const float *const *)(pl + P_COMB), pl[P_RECV], out);
    }
    if (st == PT_OK)
        progress_add(&pg, pg.total); /* the whole span, whatever rounding left */
done:
    pt_free(mem);
    return st;
}

pt_status pt_denoise(const pt_denoise_input *in, unsigned threads, float *const out[3],
                     pt_error *err)
{
    pt_status st = pt_denoise_check(in, err);
    return st != PT_OK ? st : denoise_run(in, threads, out, 0, 1000, err);
}

uint64_t pt_denoise_bytes(uint32_t width, uint32_t height)
{
    uint64_t n = (uint64_t)width * height;
    uint64_t ntiles = (uint64_t)((width + TILE - 1) / TILE) * ((height + TILE - 1) / TILE);
    /* the planes; a regression's tiles (two candidates, four planes of
     * RPAD x RPAD doubles each), its image sums (4 doubles) and patch terms
     * (3 floats) a pixel */
    return n * P_COUNT * sizeof(float) +
           ntiles * MAX_CAND * 4 * (uint64_t)RPAD * RPAD * sizeof(double) +
           n * (4 * sizeof(double) + 3 * sizeof(float));
}

void pt_denoise_input_set_planes(pt_denoise_input *in, const float *const p[PT_DENOISE_PLANES])
{
    for (int k = 0; k < 3; k++) {
        in->half_a[k] = p[k];
        in->half_b[k] = p[3 + k];
        in->color[k] = p[6 + k];
        in->albedo[k] = p[10 + k];
        in->normal[k] = p[14 + k];
    }
    in->variance = p[9];
    in->albedo_var = p[13];
    in->normal_var = p[17];
    in->depth = p[18];
    in->depth_var = p[19];
}

void pt_denoise_input_planes(const pt_denoise_input *in, const float *p[PT_DENOISE_PLANES])
{
    for (int k = 0; k < 3; k++) {
        p[k] = in->half_a[k];
        p[3 + k] = in->half_b[k];
        p[6 + k] = in->color[k];
        p[10 + k] = in->albedo[k];
        p[14 + k] = in->normal[k];
    }
    p[9] = in->variance;
    p[13] = in->albedo_var;
    p[17] = in->normal_var;
    p[18] = in->depth;
    p[19] = in->depth_var;
}

/* The planes a crop copies: the input's and the output's 3. */
#define CROP_PLANES (PT_DENOISE_PLANES + 3)

/* The crop of the region from (x0, y0) of a side (clipped to the image):
 * PT_DENOISE_MARGIN wider on each side, within the image. */
static rect crop_of(uint32_t w, uint32_t h, uint32_t x0, uint32_t y0, uint32_t side)
{
    const uint32_t m = PT_DENOISE_MARGIN;
    rect c = {(int)(x0 > m ? x0 - m : 0), (int)(y0 > m ? y0 - m : 0),
              (int)((uint64_t)x0 + side + m < w ? x0 + side + m : w),
              (int)((uint64_t)y0 + side + m < h ? y0 + side + m : h)};
    return c;
}

uint64_t pt_denoise_region_bytes(uint32_t width, uint32_t height, uint32_t side)
{
    if (side == 0 || (side >= width && side >= height))
        return pt_denoise_bytes(width, height);
    uint32_t cw = side + 2 * PT_DENOISE_MARGIN, ch = cw;
    cw = cw < width ? cw : width;
    ch = ch < height ? ch : height;
    return (uint64_t)cw * ch * CROP_PLANES * sizeof(float) + pt_denoise_bytes(cw, ch);
}

uint32_t pt_denoise_region_side(uint32_t width, uint32_t height, uint64_t max_bytes)
{
    if (pt_denoise_bytes(width, height) <= max_bytes)
        return 0;
    uint32_t big = width > height ? width : height;
    for (uint32_t side = big / TILE * TILE; side >= TILE; side -= TILE)
        if (pt_denoise_region_bytes(width, height, side) <= max_bytes)
            return side;
    return UINT32_MAX;
}

uint32_t pt_denoise_region_count(uint32_t width, uint32_t height, uint32_t side)
{
    return side ? ((width + side - 1) / side) * ((height + side - 1) / side) : 0;
}

void pt_denoise_region_at(uint32_t width, uint32_t height, uint32_t side, uint32_t index,
                          uint32_t region[4], uint32_t crop[4])
{
    uint32_t across = (width + side - 1) / side;
    uint32_t x0 = index % across * side, y0 = index / across * side;
    region[0] = x0;
    region[1] = y0;
    region[2] = x0 + side < width ? x0 + side : width;
    region[3] = y0 + side < height ? y0 + side : height;
    rect c = crop_of(width, height, x0, y0, side);
    crop[0] = (uint32_t)c.x0;
    crop[1] = (uint32_t)c.y0;
    crop[2] = (uint32_t)c.x1;
    crop[3] = (uint32_t)c.y1;
}

/* The planes of one crop: its input's, then its output's 3. */
#define CROP_OUT PT_DENOISE_PLANES

/* Region index of in into out, through the crop planes pl (room for the
 * largest crop); base and span: its share of in->progress (0, 0: none). */
static pt_status region_run(const pt_denoise_input *in, unsigned threads, uint32_t side,
                            uint32_t index, float *const pl[CROP_PLANES], float *const out[3],
                            uint32_t base, uint32_t span, pt_error *err)
{
    uint32_t w = in->width, r[4], c[4];
    pt_denoise_region_at(w, in->height, side, index, r, c);
    uint32_t ow = c[2] - c[0], oh = c[3] - c[1];
    const float *src[PT_DENOISE_PLANES];
    pt_denoise_input_planes(in, src);
    for (int k = 0; k < PT_DENOISE_PLANES; k++)
        for (uint32_t y = 0; y < oh; y++)
            memcpy(pl[k] + (size_t)y * ow, src[k] + (size_t)(y + c[1]) * w + c[0],
                   ow * sizeof(float));
    pt_denoise_input ci = {.width = ow,
                           .height = oh,
                           .despeckle = in->despeckle,
                           .cancel = in->cancel,
                           .progress = span ? in->progress : NULL};
    pt_denoise_input_set_planes(&ci, (const float *const *)pl);
    float *const co[3] = {pl[CROP_OUT], pl[CROP_OUT + 1], pl[CROP_OUT + 2]};
    pt_status st = denoise_run(&ci, threads, co, base, span, err);
    if (st != PT_OK)
        return st;
    uint32_t rw = r[2] - r[0];
    for (int k = 0; k < 3; k++)
        for (uint32_t y = r[1]; y < r[3]; y++)
            memcpy(out[k] + (size_t)y * w + r[0], co[k] + (size_t)(y - c[1]) * ow + (r[0] - c[0]),
                   rw * sizeof(float));
    return PT_OK;
}

/* A buffer for crops of side (within the image) cut from in: CROP_PLANES
 * planes of the largest crop, their pointers into pl; NULL when out of
 * memory. */
static float *crop_buffer(const pt_denoise_input *in, uint32_t side, float *pl[CROP_PLANES],
                          pt_error *err)
{
    uint32_t cw =
        side + 2 * PT_DENOISE_MARGIN < in->width ? side + 2 * PT_DENOISE_MARGIN : in->width;
    uint32_t chh =
        side + 2 * PT_DENOISE_MARGIN < in->height ? side + 2 * PT_DENOISE_MARGIN : in->height;
    size_t cn = (size_t)cw * chh;
    float *mem = pt_malloc_array(cn * CROP_PLANES, sizeof(float));
    if (!mem) {
        pt_error_set(err, PT_ERR_NOMEM, "denoise: out of memory for a crop of %ux%u", cw, chh);
        return NULL;
    }
    for (int k = 0; k < CROP_PLANES; k++)
        pl[k] = mem + (size_t)k * cn;
    return mem;
}

pt_status pt_denoise_regions(const pt_denoise_input *in, unsigned threads, uint32_t side,
                             float *const out[3], pt_error *err)
{
    if (side % TILE != 0)
        return pt_error_set(err, PT_ERR_ARG, "denoise: regions of %u pixels, not a multiple of %d",
                            side, TILE);
    if (side == 0 || (side >= in->width && side >= in->height))
        return pt_denoise(in, threads, out, err);
    pt_status st = pt_denoise_check(in, err);
    if (st != PT_OK)
        return st;
    if (!out || !out[0] || !out[1] || !out[2])
        return pt_error_set(err, PT_ERR_ARG, "denoise: no output planes");
    uint32_t w = in->width, h = in->height, n = pt_denoise_region_count(w, h, side);
    float *pl[CROP_PLANES];
    float *mem = crop_buffer(in, side, pl, err);
    if (!mem)
        return PT_ERR_NOMEM;
    /* Each crop's share of the progress: its tiles over all crops'. */
    uint64_t all = 0, before = 0;
    uint32_t r[4], c[4];
    for (uint32_t i = 0; i < n; i++) {
        pt_denoise_region_at(w, h, side, i, r, c);
        all += (uint64_t)((c[2] - c[0] + TILE - 1) / TILE) * ((c[3] - c[1] + TILE - 1) / TILE);
    }
    for (uint32_t i = 0; i < n && st == PT_OK; i++) {
        pt_denoise_region_at(w, h, side, i, r, c);
        uint32_t base = (uint32_t)(before * 1000 / all);
        before += (uint64_t)((c[2] - c[0] + TILE - 1) / TILE) * ((c[3] - c[1] + TILE - 1) / TILE);
        st = region_run(in, threads, side, i, pl, out, base, (uint32_t)(before * 1000 / all) - base,
                        err);
    }
    pt_free(mem);
    return st;
}

pt_status pt_denoise_region(const pt_denoise_input *in, unsigned threads, uint32_t side,
                            uint32_t index, float *const out[3], pt_error *err)
{
    if (side == 0 || side % TILE != 0)
        return pt_error_set(err, PT_ERR_ARG, "denoise: regions of %u pixels, not a multiple of %d",
                            side, TILE);
    if (index >= pt_denoise_region_count(in->width, in->height, side))
        return pt_error_set(err, PT_ERR_ARG, "denoise: no region %u in %ux%u by %u", index,
                            in->width, in->height, side);
    if (!out || !out[0] || !out[1] || !out[2])
        return pt_error_set(err, PT_ERR_ARG, "denoise: no output planes");
    pt_status st = pt_denoise_check(in, err);
    if (st != PT_OK)
        return st;
    float *pl[CROP_PLANES];
    float *mem = crop_buffer(in, side, pl, err);
    if (!mem)
        return PT_ERR_NOMEM;
    st = region_run(in, threads, side, index, pl, out, 0, 0, err);
    pt_free(mem);
    return st;
}

pt_status pt_denoise_within(const pt_denoise_input *in, unsigned threads, uint64_t max_bytes,
                            float *const out[3], uint32_t *side, pt_error *err)
{
    uint32_t cut = max_bytes ? pt_denoise_region_side(in->width, in->height, max_bytes) : 0;
    if (cut == UINT32_MAX) {
        uint64_t least = pt_denoise_region_bytes(in->width, in->height, TILE);
        return pt_error_set(err, PT_ERR_LIMIT,
                            "denoising %ux%u in %llu MiB is too little: regions of %d pixels "
                            "need %llu MiB",
                            in->width, in->height, (unsigned long long)(max_bytes >> 20), TILE,
                            (unsigned long long)((least + (1u << 20) - 1) >> 20));
    }
    if (side)
        *side = cut;
    return pt_denoise_regions(in, threads, cut, out, err);
}

unsigned pt_denoise_default_threads(void)
{
    long n = sysconf(_SC_NPROCESSORS_ONLN);
    return n < 1 ? 1u : n > (long)PT_DENOISE_MAX_THREADS ? PT_DENOISE_MAX_THREADS : (unsigned)n;
}
