#include "common/image/denoise.h"

#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/image/image.h"

/* Tiles: the unit of parallel work and of the fixed summation order. */
#define TILE 32
/* The paper's parameters (NFOR sec. 5 and its reference implementation). */
#define REG_F 3     /* patch radius of the regression's weights */
#define REG_R 9     /* window radius of the regression: 19 x 19 */
#define FEAT_F 3    /* feature prefilter: patch radius */
#define FEAT_R 5    /* ... window radius */
#define FEAT_K 0.5f /* ... and k */
#define MSE_F 1     /* MSE and selection-map smoothing: patch radius */
#define MSE_R 9     /* ... window radius */
#define MAX_F 3     /* the largest patch radius above: scratch sizes */
#define MAX_R 9     /* the largest window radius */
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
/* The centre pixel always keeps some weight, so a window never sums to 0. */
#define NLM_MIN_CENTER 1e-4f

typedef struct rect {
    int x0, y0, x1, y1; /* [x0, x1) x [y0, y1) */
} rect;

/* The parallel runner: threads take tile indices from a counter; what a
 * tile computes depends only on its index, never on the thread. */
typedef int (*tile_fn)(void *ctx, int tile, void *scratch); /* 0, or -1: out of memory */

typedef struct tile_job {
    tile_fn fn;
    void *ctx;
    int ntiles;
    size_t scratch_bytes;
    atomic_int next;
    atomic_int failed;
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
        if (job->fn(job->ctx, t, scratch) != 0)
            atomic_store(&job->failed, 1);
    }
    pt_free(scratch);
    return NULL;
}

static pt_status run_tiles(unsigned threads, int ntiles, size_t scratch_bytes, tile_fn fn,
                           void *ctx, pt_error *err)
{
    tile_job job = {.fn = fn, .ctx = ctx, .ntiles = ntiles, .scratch_bytes = scratch_bytes};
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
    if (atomic_load(&job.failed))
        return pt_error_set(err, PT_ERR_NOMEM, "denoise: out of memory");
    return PT_OK;
}

typedef struct dims {
    int w, h, tx, ty; /* image size; tiles across and down */
} dims;

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

/* What NL-means weights are computed from: nc guide channels and the
 * variance of each (pointers may repeat), scaled by vscale. */
typedef struct guide {
    int nc;
    const float *g[3];
    const float *v[3];
    float vscale, k;
    int f; /* patch radius */
} guide;

/* Scratch of patch_weights. */
typedef struct wscratch {
    float *d;  /* 3 x (TILE + 2 MAX_F)^2 distances */
    float *hs; /* 3 x (TILE + 2 MAX_F) x TILE horizontal sums */
    int *hcount;
} wscratch;

#define PAD (TILE + 2 * MAX_F)
#define WSCRATCH_BYTES                                                                             \
    (3 * PAD * PAD * sizeof(float) + 3 * PAD * TILE * sizeof(float) + TILE * sizeof(int))

static wscratch wscratch_at(void *mem)
{
    wscratch s;
    s.d = mem;
    s.hs = s.d + 3 * PAD * PAD;
    s.hcount = (int *)(void *)(s.hs + 3 * PAD * TILE);
    return s;
}

/* The NL-means weights between each pixel p of tile r and p + (dx, dy):
 * per channel into out[c * tn + i] (per_channel) or, for the regression,
 * the smallest over the channels into out[i] (i: the pixel's index in the
 * tile, tn its pixel count). 0 where p + (dx, dy) is outside the image.
 * The patch distance is the mean of the per-pixel distances over the part
 * of the patch where both patches are inside the image. */
static void patch_weights(const dims *dm, const guide *gd, rect r, int dx, int dy, int per_channel,
                          wscratch *s, float *out)
{
    int w = dm->w, tw = r.x1 - r.x0, th = r.y1 - r.y0, tn = tw * th, f = gd->f;
    memset(out, 0, sizeof(float) * (size_t)tn * (size_t)(per_channel ? gd->nc : 1));
    /* p and p + (dx, dy) both inside the image */
    int vx0 = imax(r.x0, -dx), vx1 = imin(r.x1, w - dx);
    int vy0 = imax(r.y0, -dy), vy1 = imin(r.y1, dm->h - dy);
    if (vx0 >= vx1 || vy0 >= vy1)
        return;
    int px0 = imax(vx0 - f, imax(0, -dx)), px1 = imin(vx1 + f, imin(w, w - dx));
    int py0 = imax(vy0 - f, imax(0, -dy)), py1 = imin(vy1 + f, imin(dm->h, dm->h - dy));
    int pw = px1 - px0, ph = py1 - py0, vw = vx1 - vx0;
    float k2 = gd->k * gd->k;
    for (int c = 0; c < gd->nc; c++) {
        const float *g = gd->g[c], *v = gd->v[c];
        float *d = s->d + (size_t)c * PAD * PAD;
        for (int y = py0; y < py1; y++) {
            const float *gp = g + (size_t)y * w, *gq = g + (size_t)(y + dy) * w + dx;
            const float *vp = v + (size_t)y * w, *vq = v + (size_t)(y + dy) * w + dx;
            float *drow = d + (size_t)(y - py0) * pw - px0;
            for (int x = px0; x < px1; x++) {
                float a = vp[x] * gd->vscale, b = vq[x] * gd->vscale;
                float diff = gp[x] - gq[x];
                float dist = (diff * diff - (a + fminf(a, b))) / (NLM_EPS + k2 * (a + b));
                drow[x] = fminf(dist, NLM_CLAMP);
            }
        }
        float *hs = s->hs + (size_t)c * PAD * TILE;
        for (int j = 0; j < ph; j++) {
            const float *drow = d + (size_t)j * pw;
            for (int x = vx0; x < vx1; x++) {
                int a = imax(x - f, px0) - px0, b = imin(x + f + 1, px1) - px0;
                float sum = 0.0f;
                for (int i = a; i < b; i++)
                    sum += drow[i];
                hs[(size_t)j * vw + (x - vx0)] = sum;
                s->hcount[x - vx0] = b - a;
            }
        }
    }
    for (int y = vy0; y < vy1; y++) {
        int a = imax(y - f, py0) - py0, b = imin(y + f + 1, py1) - py0;
        for (int x = vx0; x < vx1; x++) {
            float n = (float)((b - a) * s->hcount[x - vx0]);
            int i = (y - r.y0) * tw + (x - r.x0);
            float dmax = 0.0f;
            for (int c = 0; c < gd->nc; c++) {
                const float *hs = s->hs + (size_t)c * PAD * TILE + (x - vx0);
                float sum = 0.0f;
                for (int j = a; j < b; j++)
                    sum += hs[(size_t)j * vw];
                float dist = fmaxf(sum / n, 0.0f);
                if (per_channel)
                    out[(size_t)c * tn + i] = expf(-dist);
                else
                    dmax = fmaxf(dmax, dist);
            }
            if (!per_channel)
                out[i] = expf(-dmax);
        }
    }
    if (dx == 0 && dy == 0)
        for (int i = 0; i < tn * (per_channel ? gd->nc : 1); i++)
            out[i] = fmaxf(out[i], NLM_MIN_CENTER);
}

/* ---- NL-means (per-channel weights), for the features, MSE and selection ---- */

typedef struct nlm_ctx {
    dims dm;
    guide gd;
    int r;               /* window radius */
    const float *src[3]; /* gd.nc channels filtered */
    float *dst[3];
} nlm_ctx;

#define NLM_SCRATCH_BYTES (WSCRATCH_BYTES + 3 * TILE * TILE * (sizeof(float) + 2 * sizeof(double)))

static int nlm_tile(void *vctx, int t, void *mem)
{
    nlm_ctx *cx = vctx;
    const dims *dm = &cx->dm;
    rect r = tile_rect(dm, t);
    int tw = r.x1 - r.x0, tn = tw * (r.y1 - r.y0), nc = cx->gd.nc;
    wscratch s = wscratch_at(mem);
    float *wt = (float *)(void *)((char *)mem + WSCRATCH_BYTES);
    double *acc = (double *)(void *)(wt + 3 * TILE * TILE), *wsum = acc + 3 * TILE * TILE;
    memset(acc, 0, sizeof(double) * 3 * TILE * TILE * 2);
    for (int dy = -cx->r; dy <= cx->r; dy++) {
        for (int dx = -cx->r; dx <= cx->r; dx++) {
            patch_weights(dm, &cx->gd, r, dx, dy, 1, &s, wt);
            int vx0 = imax(r.x0, -dx), vx1 = imin(r.x1, dm->w - dx);
            int vy0 = imax(r.y0, -dy), vy1 = imin(r.y1, dm->h - dy);
            for (int c = 0; c < nc; c++) {
                for (int y = vy0; y < vy1; y++) {
                    const float *q = cx->src[c] + (size_t)(y + dy) * dm->w + dx;
                    for (int x = vx0; x < vx1; x++) {
                        int i = (y - r.y0) * tw + (x - r.x0);
                        float wv = wt[(size_t)c * tn + i];
                        acc[c * tn + i] += (double)wv * q[x];
                        wsum[c * tn + i] += wv;
                    }
                }
            }
        }
    }
    for (int c = 0; c < nc; c++)
        for (int y = r.y0; y < r.y1; y++)
            for (int x = r.x0; x < r.x1; x++) {
                int i = (y - r.y0) * tw + (x - r.x0);
                cx->dst[c][(size_t)y * dm->w + x] = (float)(acc[c * tn + i] / wsum[c * tn + i]);
            }
    return 0;
}

static pt_status nlmeans(const dims *dm, unsigned threads, const guide *gd, int radius,
                         const float *const src[], float *const dst[], pt_error *err)
{
    nlm_ctx cx = {.dm = *dm, .gd = *gd, .r = radius};
    for (int c = 0; c < gd->nc; c++) {
        cx.src[c] = src[c];
        cx.dst[c] = dst[c];
    }
    return run_tiles(threads, dm->tx * dm->ty, NLM_SCRATCH_BYTES, nlm_tile, &cx, err);
}

/* ---- first-order regression with collaborative accumulation ---- */

/* Weighted least squares by the normal equations in double, Gaussian
 * elimination with the pivots in column order; a column whose pivot falls
 * to 1e-10 of its own weighted sum of squares (a feature constant over the
 * window, or a combination of the columns before it: grey albedo, a flat
 * depth) is dropped, its coefficient 0, so the fit stays defined. The
 * constant's column has the centre weight at least: never dropped. */
static void solve_wls(double a[DIM][DIM], double b[DIM][3], double beta[DIM][3])
{
    double diag0[DIM];
    int drop[DIM];
    for (int i = 0; i < DIM; i++) {
        for (int j = 0; j < i; j++)
            a[i][j] = a[j][i];
        diag0[i] = a[i][i];
    }
    for (int j = 0; j < DIM; j++) {
        double piv = a[j][j];
        drop[j] = !(diag0[j] > 0.0) || !(piv > 1e-10 * diag0[j]);
        if (drop[j])
            continue;
        for (int i = j + 1; i < DIM; i++) {
            double m = a[i][j] / piv;
            if (m == 0.0)
                continue;
            for (int k = j; k < DIM; k++)
                a[i][k] -= m * a[j][k];
            for (int c = 0; c < 3; c++)
                b[i][c] -= m * b[j][c];
        }
    }
    for (int j = DIM - 1; j >= 0; j--) {
        for (int c = 0; c < 3; c++) {
            if (drop[j]) {
                beta[j][c] = 0.0;
                continue;
            }
            double s = b[j][c];
            for (int k = j + 1; k < DIM; k++)
                s -= a[j][k] * beta[k][c];
            beta[j][c] = s / a[j][j];
        }
    }
}

typedef struct reg_ctx {
    dims dm;
    guide gd;          /* weights: the other half (or the image itself) */
    const float *y[3]; /* the colour fitted */
    const float *feat[PT_DENOISE_FEATURES];
    double **tile_acc; /* per tile: 4 planes (R, G, B, weight) over its grown rect */
} reg_ctx;

/* The tile grown by the window radius, inside the image: where its fits land. */
static rect grown_rect(const dims *dm, rect r)
{
    rect g = {imax(r.x0 - REG_R, 0), imax(r.y0 - REG_R, 0), imin(r.x1 + REG_R, dm->w),
              imin(r.y1 + REG_R, dm->h)};
    return g;
}

#define REG_SCRATCH_BYTES                                                                          \
    (WSCRATCH_BYTES + (size_t)WIN * TILE * TILE * sizeof(float) +                                  \
     (size_t)WIN * (DIM * sizeof(double) + sizeof(float) + sizeof(int)))

static int reg_tile(void *vctx, int t, void *mem)
{
    reg_ctx *cx = vctx;
    const dims *dm = &cx->dm;
    int w = dm->w;
    rect r = tile_rect(dm, t), gr = grown_rect(dm, r);
    int tw = r.x1 - r.x0, tn = tw * (r.y1 - r.y0), gw = gr.x1 - gr.x0;
    size_t gn = (size_t)gw * (size_t)(gr.y1 - gr.y0);
    wscratch s = wscratch_at(mem);
    float *wt = (float *)(void *)((char *)mem + WSCRATCH_BYTES);
    double *xs = (double *)(void *)(wt + (size_t)WIN * TILE * TILE);
    float *ws = (float *)(void *)(xs + (size_t)WIN * DIM);
    int *qs = (int *)(void *)(ws + WIN);
    double *acc = pt_calloc(4 * gn, sizeof(double));
    if (!acc)
        return -1;
    cx->tile_acc[t] = acc;
    const int side = 2 * REG_R + 1;
    for (int dy = -REG_R; dy <= REG_R; dy++)
        for (int dx = -REG_R; dx <= REG_R; dx++)
            patch_weights(dm, &cx->gd, r, dx, dy, 0, &s,
                          wt + (size_t)((dy + REG_R) * side + dx + REG_R) * tn);
    for (int py = r.y0; py < r.y1; py++) {
        for (int px = r.x0; px < r.x1; px++) {
            int i = (py - r.y0) * tw + (px - r.x0);
            size_t p = (size_t)py * w + px;
            double a[DIM][DIM] = {{0}}, b[DIM][3] = {{0}}, beta[DIM][3];
            float fp[PT_DENOISE_FEATURES];
            for (int k = 0; k < PT_DENOISE_FEATURES; k++)
                fp[k] = cx->feat[k][p];
            int n = 0;
            for (int qy = imax(py - REG_R, 0); qy < imin(py + REG_R + 1, dm->h); qy++) {
                for (int qx = imax(px - REG_R, 0); qx < imin(px + REG_R + 1, w); qx++) {
                    int o = (qy - py + REG_R) * side + (qx - px + REG_R);
                    float wv = wt[(size_t)o * tn + i];
                    if (!(wv > 0.0f))
                        continue;
                    size_t q = (size_t)qy * w + qx;
                    double *x = xs + (size_t)n * DIM;
                    x[0] = 1.0;
                    x[1] = qx - px;
                    x[2] = qy - py;
                    for (int k = 0; k < PT_DENOISE_FEATURES; k++)
                        x[3 + k] = (double)cx->feat[k][q] - fp[k];
                    double yq[3] = {cx->y[0][q], cx->y[1][q], cx->y[2][q]};
                    for (int j = 0; j < DIM; j++) {
                        double wx = wv * x[j];
                        for (int k = j; k < DIM; k++)
                            a[j][k] += wx * x[k];
                        for (int c = 0; c < 3; c++)
                            b[j][c] += wx * yq[c];
                    }
                    ws[n] = wv;
                    qs[n] = (qy - gr.y0) * gw + (qx - gr.x0);
                    n++;
                }
            }
            solve_wls(a, b, beta);
            for (int m = 0; m < n; m++) {
                const double *x = xs + (size_t)m * DIM;
                for (int c = 0; c < 3; c++) {
                    double pred = 0.0;
                    for (int j = 0; j < DIM; j++)
                        pred += x[j] * beta[j][c];
                    acc[(size_t)c * gn + qs[m]] += ws[m] * pred;
                }
                acc[3 * gn + qs[m]] += ws[m];
            }
        }
    }
    return 0;
}

/* Filters y (3 channels) by collaborative first-order regression on the
 * features with weights from gd; out may not alias y. */
static pt_status regression(const dims *dm, unsigned threads, const guide *gd,
                            const float *const y[3], const float *const feat[], float *const out[3],
                            pt_error *err)
{
    int ntiles = dm->tx * dm->ty;
    size_t n = (size_t)dm->w * dm->h;
    reg_ctx cx = {.dm = *dm, .gd = *gd};
    for (int c = 0; c < 3; c++)
        cx.y[c] = y[c];
    for (int k = 0; k < PT_DENOISE_FEATURES; k++)
        cx.feat[k] = feat[k];
    cx.tile_acc = pt_calloc((size_t)ntiles, sizeof(double *));
    double *sum = pt_calloc(4 * n, sizeof(double));
    pt_status st = PT_OK;
    if (!cx.tile_acc || !sum) {
        st = pt_error_set(err, PT_ERR_NOMEM, "denoise: out of memory");
        goto done;
    }
    if ((st = run_tiles(threads, ntiles, REG_SCRATCH_BYTES, reg_tile, &cx, err)) != PT_OK)
        goto done;
    /* Tile order: the sums do not depend on which thread made them. */
    for (int t = 0; t < ntiles; t++) {
        rect gr = grown_rect(dm, tile_rect(dm, t));
        int gw = gr.x1 - gr.x0;
        size_t gn = (size_t)gw * (size_t)(gr.y1 - gr.y0);
        const double *acc = cx.tile_acc[t];
        for (int c = 0; c < 4; c++)
            for (int yy = gr.y0; yy < gr.y1; yy++)
                for (int xx = gr.x0; xx < gr.x1; xx++)
                    sum[(size_t)c * n + (size_t)yy * dm->w + xx] +=
                        acc[(size_t)c * gn + (size_t)(yy - gr.y0) * gw + (xx - gr.x0)];
        pt_free(cx.tile_acc[t]);
        cx.tile_acc[t] = NULL;
    }
    for (size_t i = 0; i < n; i++)
        for (int c = 0; c < 3; c++)
            out[c][i] = (float)(sum[c * n + i] / sum[3 * n + i]);
done:
    if (cx.tile_acc)
        for (int t = 0; t < ntiles; t++)
            pt_free(cx.tile_acc[t]);
    pt_free(cx.tile_acc);
    pt_free(sum);
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
    if ((st = check_plane(in, in->variance, "variance", 0.0f, M, err)) != PT_OK ||
        (st = check_plane(in, in->albedo_var, "albedo.variance", 0.0f, M, err)) != PT_OK ||
        (st = check_plane(in, in->normal_var, "N.variance", 0.0f, M, err)) != PT_OK ||
        (st = check_plane(in, in->depth, "depth.Z", 0.0f, M, err)) != PT_OK ||
        (st = check_plane(in, in->depth_var, "depth.variance", 0.0f, M, err)) != PT_OK)
        return st;
    return PT_OK;
}

/* ---- the pipeline ---- */

/* Internal planes, one allocation. */
enum {
    P_FEAT = 0,                          /* 7 prefiltered features */
    P_FA = P_FEAT + PT_DENOISE_FEATURES, /* 2 candidates x 3: half A filtered */
    P_FB = P_FA + 6,                     /* 2 x 3: half B filtered */
    P_MSE = P_FB + 6,                    /* 2 x 3: smoothed MSE estimates */
    P_TMP = P_MSE + 6,                   /* 3: noisy MSE, then the noisy selection */
    P_SEL = P_TMP + 3,                   /* 3: the smoothed selection map */
    P_RA = P_SEL + 3,                    /* 3 + 3: the blended halves */
    P_RB = P_RA + 3,
    P_VAR = P_RB + 3,    /* 3: variance of the blend's mean */
    P_HVAR = P_VAR + 3,  /* 1: a half's variance (2 x the beauty's) */
    P_COMB = P_HVAR + 1, /* 3: the blend's mean */
    P_COUNT = P_COMB + 3
};

pt_status pt_denoise(const pt_denoise_input *in, unsigned threads, float *const out[3],
                     pt_error *err)
{
    pt_status st = pt_denoise_check(in, err);
    if (st != PT_OK)
        return st;
    if (!out || !out[0] || !out[1] || !out[2])
        return pt_error_set(err, PT_ERR_ARG, "denoise: no output planes");
    if (threads == 0)
        threads = 1;
    if (threads > PT_DENOISE_MAX_THREADS)
        return pt_error_set(err, PT_ERR_ARG, "denoise: %u threads, at most %u", threads,
                            PT_DENOISE_MAX_THREADS);
    dims dm = {(int)in->width, (int)in->height, ((int)in->width + TILE - 1) / TILE,
               ((int)in->height + TILE - 1) / TILE};
    size_t n = (size_t)in->width * in->height;
    float *mem = pt_malloc_array(n * P_COUNT, sizeof(float));
    if (!mem)
        return pt_error_set(err, PT_ERR_NOMEM, "denoise: out of memory for %ux%u", in->width,
                            in->height);
    float *pl[P_COUNT];
    for (int i = 0; i < P_COUNT; i++)
        pl[i] = mem + (size_t)i * n;

    /* 1. Features, each through NL-means guided by itself (sec. 5.1). */
    const float *fin[PT_DENOISE_FEATURES] = {in->albedo[0], in->albedo[1], in->albedo[2],
                                             in->normal[0], in->normal[1], in->normal[2],
                                             in->depth};
    const float *fvar[3] = {in->albedo_var, in->normal_var, in->depth_var};
    for (int g = 0; g < 3 && st == PT_OK; g++) {
        int first = 3 * g, nc = g < 2 ? 3 : 1;
        guide gd = {.nc = nc, .vscale = 1.0f, .k = FEAT_K, .f = FEAT_F};
        for (int c = 0; c < nc; c++) {
            gd.g[c] = fin[first + c];
            gd.v[c] = fvar[g];
        }
        st = nlmeans(&dm, threads, &gd, FEAT_R, fin + first, pl + P_FEAT + first, err);
    }
    const float *const *feat = (const float *const *)(pl + P_FEAT);

    /* 2. Two candidates, each half filtered with the other's weights (sec. 5.2). */
    for (size_t i = 0; i < n; i++)
        pl[P_HVAR][i] = 2.0f * in->variance[i];
    static const float cand_k[2] = {0.5f, 1.0f};
    for (int k = 0; k < 2 && st == PT_OK; k++) {
        guide ga = {.nc = 3, .vscale = 1.0f, .k = cand_k[k], .f = REG_F};
        guide gb = ga;
        for (int c = 0; c < 3; c++) {
            ga.g[c] = in->half_b[c]; /* A is filtered with B's weights */
            gb.g[c] = in->half_a[c];
            ga.v[c] = gb.v[c] = pl[P_HVAR];
        }
        st = regression(&dm, threads, &ga, in->half_a, feat, pl + P_FA + 3 * k, err);
        if (st == PT_OK)
            st = regression(&dm, threads, &gb, in->half_b, feat, pl + P_FB + 3 * k, err);
        if (st != PT_OK)
            break;
        /* 3. The candidate's MSE from the halves' cross errors (sec. 5.3). */
        for (int c = 0; c < 3; c++) {
            const float *fa = pl[P_FA + 3 * k + c], *fb = pl[P_FB + 3 * k + c];
            for (size_t i = 0; i < n; i++) {
                float hv = pl[P_HVAR][i];
                float ea = (in->half_b[c][i] - fa[i]) * (in->half_b[c][i] - fa[i]) - hv;
                float eb = (in->half_a[c][i] - fb[i]) * (in->half_a[c][i] - fb[i]) - hv;
                float res = 0.25f * (fb[i] - fa[i]) * (fb[i] - fa[i]);
                pl[P_TMP + c][i] = 0.5f * (ea + eb) - res;
            }
        }
        guide gc = {.nc = 3, .vscale = 1.0f, .k = 1.0f, .f = MSE_F};
        for (int c = 0; c < 3; c++) {
            gc.g[c] = in->color[c];
            gc.v[c] = in->variance;
        }
        st = nlmeans(&dm, threads, &gc, MSE_R, (const float *const *)(pl + P_TMP),
                     pl + P_MSE + 3 * k, err);
    }
    if (st != PT_OK)
        goto done;
    /* The choice map, smoothed like the estimates, blends the candidates. */
    for (int c = 0; c < 3; c++)
        for (size_t i = 0; i < n; i++)
            pl[P_TMP + c][i] = pl[P_MSE + c][i] < pl[P_MSE + 3 + c][i] ? 0.0f : 1.0f;
    guide gc = {.nc = 3, .vscale = 1.0f, .k = 1.0f, .f = MSE_F};
    for (int c = 0; c < 3; c++) {
        gc.g[c] = in->color[c];
        gc.v[c] = in->variance;
    }
    if ((st = nlmeans(&dm, threads, &gc, MSE_R, (const float *const *)(pl + P_TMP), pl + P_SEL,
                      err)) != PT_OK)
        goto done;
    for (int c = 0; c < 3; c++) {
        for (size_t i = 0; i < n; i++) {
            float s = pl[P_SEL + c][i];
            /* a + s (b - a): exactly a where the candidates agree */
            float a0 = pl[P_FA + c][i], a1 = pl[P_FA + 3 + c][i];
            float b0 = pl[P_FB + c][i], b1 = pl[P_FB + 3 + c][i];
            float ra = a0 + s * (a1 - a0), rb = b0 + s * (b1 - b0);
            pl[P_RA + c][i] = ra;
            pl[P_RB + c][i] = rb;
            pl[P_COMB + c][i] = 0.5f * (ra + rb);
            pl[P_VAR + c][i] = 0.25f * (rb - ra) * (rb - ra);
        }
    }
    /* 4. The second pass over the blend's mean (sec. 5.4). */
    guide gf = {.nc = 3, .vscale = 1.0f, .k = 1.0f, .f = REG_F};
    for (int c = 0; c < 3; c++) {
        gf.g[c] = pl[P_COMB + c];
        gf.v[c] = pl[P_VAR + c];
    }
    st = regression(&dm, threads, &gf, (const float *const *)(pl + P_COMB), feat, out, err);
done:
    pt_free(mem);
    return st;
}
