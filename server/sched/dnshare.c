#include "server/sched/dnshare.h"

#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/clock.h"
#include "common/base/hash.h"
#include "protocol/wire.h"
#include "server/log.h"
#include "server/sched/job.h"

enum { R_FREE, R_LEASED, R_DONE };

typedef struct region {
    uint32_t rect[4], crop[4]; /* x0, y0, x1, y1 in the frame */
    uint8_t hash[32];          /* of the crop's input as DENOISE_CHUNK sends it */
    int state;                 /* R_* */
    uint64_t owner;            /* R_LEASED: the leaseholder; R_DONE: whose bits (0: the writer's) */
    int verify;                /* R_DONE by a worker: the writer denoises it again */
    int mine;                  /* the writer denoises it now: not leased */
    uint64_t t_leased;         /* R_LEASED: since when (ms), */
    uint32_t lease_ms;         /* ... and its lease's timeout */
} region;

#define MAX_LIARS 16u
/* A leased region is raced (the writer denoises it too) once it has been
 * out this many times as long as the writer takes for a crop of its size,
 * and at least the lease timeout: a worker a little slower than the
 * coordinator is waited for, a stalled one is not. */
#define STALL_FACTOR 4.0

struct srv_dnshare {
    pthread_mutex_t mu;
    pthread_cond_t cv; /* a result taken, a lease released: the writer looks again */
    int open;
    pt_denoise_input in; /* the frame's planes: the writer's */
    uint32_t side, n;
    float *out[3];
    uint64_t job_id;
    region *r;
    uint32_t cap;
    uint64_t seed;
    double fraction;
    double ms_per_px;          /* the writer's last region: ms per crop pixel; 0 none yet */
    uint64_t liars[MAX_LIARS]; /* named in this share, each once */
    uint32_t nliars, ntaken;   /* ... and those the loop has taken */
    srv_dnshare_stats st;
};

pt_status srv_dnshare_new(uint64_t verify_seed, double verify_fraction, srv_dnshare **out,
                          pt_error *err)
{
    srv_dnshare *d = pt_calloc(1, sizeof *d);
    if (!d)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    pthread_mutex_init(&d->mu, NULL);
    pthread_cond_init(&d->cv, NULL);
    d->seed = verify_seed;
    d->fraction = verify_fraction;
    *out = d;
    return PT_OK;
}

void srv_dnshare_free(srv_dnshare *d)
{
    if (!d)
        return;
    pthread_mutex_destroy(&d->mu);
    pthread_cond_destroy(&d->cv);
    pt_free(d->r);
    pt_free(d);
}

static uint32_t rect_w(const uint32_t r[4])
{
    return r[2] - r[0];
}

static uint32_t rect_h(const uint32_t r[4])
{
    return r[3] - r[1];
}

static uint64_t crop_bytes(const region *g)
{
    return (uint64_t)rect_w(g->crop) * rect_h(g->crop) * PT_DENOISE_PLANES * sizeof(float);
}

/* Bytes [offset, offset + len) of g's crop input (planes, rows, columns as
 * DENOISE_TASK says: little-endian f32) from the frame's planes into buf. */
static void crop_read(const srv_dnshare *d, const region *g, uint64_t offset, uint8_t *buf,
                      size_t len)
{
    const float *src[PT_DENOISE_PLANES];
    pt_denoise_input_planes(&d->in, src);
    uint64_t cw = rect_w(g->crop), plane = cw * rect_h(g->crop);
    while (len > 0) {
        uint64_t v = offset / 4, k = v / plane, y = v % plane / cw, x = v % cw;
        uint8_t le[4];
        proto_put_f32(le, src[k][(size_t)(y + g->crop[1]) * d->in.width + g->crop[0] + x]);
        size_t at = (size_t)(offset % 4), n = 4 - at < len ? 4 - at : len;
        memcpy(buf, le + at, n);
        buf += n;
        len -= n;
        offset += n;
    }
}

pt_status srv_dnshare_open(srv_dnshare *d, const pt_denoise_input *in, uint32_t side,
                           float *const out[3], uint64_t job_id, pt_error *err)
{
    uint32_t n = pt_denoise_region_count(in->width, in->height, side);
    region *r = d->r;
    if (n > d->cap) {
        r = pt_malloc_array(n, sizeof *r);
        if (!r)
            return pt_error_set(err, PT_ERR_NOMEM, "out of memory for %u regions", n);
    }
    /* The crops' hashes, before the loop can see any of them. */
    uint64_t most = 0;
    for (uint32_t i = 0; i < n; i++) {
        memset(&r[i], 0, sizeof r[i]);
        pt_denoise_region_at(in->width, in->height, side, i, r[i].rect, r[i].crop);
        most = crop_bytes(&r[i]) > most ? crop_bytes(&r[i]) : most;
    }
    uint8_t *tmp = pt_malloc((size_t)most);
    if (!tmp) {
        if (r != d->r)
            pt_free(r);
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory for a region's crop");
    }
    pthread_mutex_lock(&d->mu);
    d->in = *in;
    for (uint32_t i = 0; i < n; i++) {
        crop_read(d, &r[i], 0, tmp, (size_t)crop_bytes(&r[i]));
        pt_sha256(tmp, (size_t)crop_bytes(&r[i]), r[i].hash);
    }
    if (r != d->r) {
        pt_free(d->r);
        d->r = r;
        d->cap = n;
    }
    d->n = n;
    d->side = side;
    d->job_id = job_id;
    for (int c = 0; c < 3; c++)
        d->out[c] = out[c];
    d->nliars = d->ntaken = 0;
    d->ms_per_px = 0.0;
    memset(&d->st, 0, sizeof d->st);
    d->st.regions = n;
    d->open = 1;
    pthread_mutex_unlock(&d->mu);
    pt_free(tmp);
    return PT_OK;
}

void srv_dnshare_close(srv_dnshare *d)
{
    pthread_mutex_lock(&d->mu);
    d->open = 0;
    pthread_mutex_unlock(&d->mu);
}

/* Pixels of rect equal in a and b (frame planes). */
static int same_pixels(const srv_dnshare *d, const region *g, float *const a[3], float *const b[3])
{
    size_t w = d->in.width, rw = rect_w(g->rect) * sizeof(float);
    for (int c = 0; c < 3; c++)
        for (uint32_t y = g->rect[1]; y < g->rect[3]; y++)
            if (memcmp(a[c] + y * w + g->rect[0], b[c] + y * w + g->rect[0], rw) != 0)
                return 0;
    return 1;
}

static void copy_pixels(const srv_dnshare *d, const region *g, float *const to[3],
                        float *const from[3])
{
    size_t w = d->in.width, rw = rect_w(g->rect) * sizeof(float);
    for (int c = 0; c < 3; c++)
        for (uint32_t y = g->rect[1]; y < g->rect[3]; y++)
            memcpy(to[c] + y * w + g->rect[0], from[c] + y * w + g->rect[0], rw);
}

/* owner's bits differed from the writer's: named once, and every region it
 * returned is denoised again. Under the mutex. */
static void liar(srv_dnshare *d, uint64_t owner, uint32_t at)
{
    int named = 0;
    for (uint32_t i = 0; i < d->nliars; i++)
        named |= d->liars[i] == owner;
    if (!named) {
        srv_log("job %llu: a worker's denoised region %u differs from the coordinator's; its "
                "regions are denoised again",
                (unsigned long long)d->job_id, at);
        d->st.liars++;
        if (d->nliars < MAX_LIARS)
            d->liars[d->nliars++] = owner;
    }
    for (uint32_t i = 0; i < d->n; i++)
        if (d->r[i].state == R_DONE && d->r[i].owner == owner)
            d->r[i].verify = 1;
}

/* in->progress: the pixels of the regions done, in thousandths. Under the
 * mutex. */
static void progress_set(const srv_dnshare *d)
{
    if (!d->in.progress)
        return;
    uint64_t done = 0;
    for (uint32_t k = 0; k < d->n; k++)
        if (d->r[k].state == R_DONE)
            done += (uint64_t)rect_w(d->r[k].rect) * rect_h(d->r[k].rect);
    atomic_store(d->in.progress, (unsigned)(done * 1000 / ((uint64_t)d->in.width * d->in.height)));
}

/* The next region for the writer, or n: free ones, then workers' results
 * to verify, then leased ones out past their stall time. With n, *wait_ms
 * is how long until a leased one stalls (0: every region is done and
 * verified). Under the mutex. */
static uint32_t writer_pick(const srv_dnshare *d, uint64_t now, uint64_t *wait_ms)
{
    *wait_ms = 0;
    for (uint32_t i = 0; i < d->n; i++)
        if (d->r[i].state == R_FREE)
            return i;
    for (uint32_t i = 0; i < d->n; i++)
        if (d->r[i].state == R_DONE && d->r[i].verify)
            return i;
    uint64_t soonest = UINT64_MAX;
    for (uint32_t i = 0; i < d->n; i++) {
        const region *g = &d->r[i];
        if (g->state != R_LEASED)
            continue;
        double own = STALL_FACTOR * d->ms_per_px * rect_w(g->crop) * rect_h(g->crop);
        uint64_t stall = own > g->lease_ms ? (uint64_t)own : g->lease_ms;
        if (now - g->t_leased >= stall)
            return i;
        soonest = stall - (now - g->t_leased) < soonest ? stall - (now - g->t_leased) : soonest;
    }
    if (soonest != UINT64_MAX)
        *wait_ms = soonest;
    return d->n;
}

/* Waits on d's condition for at most ms (the mutex held). */
static void wait_for(srv_dnshare *d, uint64_t ms)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    ts.tv_sec += (time_t)(ms / 1000);
    ts.tv_nsec += (long)(ms % 1000) * 1000000L;
    if (ts.tv_nsec >= 1000000000L) {
        ts.tv_sec++;
        ts.tv_nsec -= 1000000000L;
    }
    pthread_cond_timedwait(&d->cv, &d->mu, &ts);
}

pt_status srv_dnshare_run(srv_dnshare *d, unsigned threads, srv_dnshare_stats *st, pt_error *err)
{
    size_t np = (size_t)d->in.width * d->in.height;
    float *mem = pt_malloc_array(3 * np, sizeof(float));
    if (!mem)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory for the denoised frame");
    float *const mine[3] = {mem, mem + np, mem + 2 * np};
    pt_status s = PT_OK;
    pthread_mutex_lock(&d->mu);
    for (;;) {
        uint64_t wait_ms;
        uint32_t i = writer_pick(d, pt_now_ms(), &wait_ms);
        if (i == d->n && wait_ms == 0)
            break;
        if (i == d->n) {
            if (d->in.cancel && atomic_load(d->in.cancel)) {
                s = pt_error_set(err, PT_AGAIN, "denoise: cancelled");
                break;
            }
            wait_for(d, wait_ms < 100 ? wait_ms : 100);
            continue;
        }
        region *g = &d->r[i];
        g->mine = 1;
        pthread_mutex_unlock(&d->mu);
        uint64_t t0 = pt_now_ms();
        s = pt_denoise_region(&d->in, threads, d->side, i, mine, err);
        uint64_t took = pt_now_ms() - t0;
        pthread_mutex_lock(&d->mu);
        g->mine = 0;
        if (s != PT_OK)
            break;
        d->ms_per_px = (double)took / ((double)rect_w(g->crop) * rect_h(g->crop));
        if (g->state != R_DONE) {
            copy_pixels(d, g, d->out, mine);
            g->state = R_DONE;
            g->owner = 0;
        } else if (g->owner != 0) {
            /* A worker's bits arrived first, or were picked to verify. */
            if (same_pixels(d, g, d->out, mine)) {
                d->st.verified++;
            } else {
                copy_pixels(d, g, d->out, mine);
                liar(d, g->owner, i);
                d->st.by_workers--;
                g->owner = 0;
            }
            g->verify = 0;
        }
        progress_set(d);
    }
    if (st)
        *st = d->st;
    pthread_mutex_unlock(&d->mu);
    pt_free(mem);
    return s;
}

int srv_dnshare_lease(srv_dnshare *d, uint64_t owner, uint32_t lease_ms, proto_denoise_task *t)
{
    pthread_mutex_lock(&d->mu);
    uint32_t i = 0;
    while (d->open && i < d->n && (d->r[i].state != R_FREE || d->r[i].mine))
        i++;
    int got = d->open && i < d->n;
    if (got) {
        region *g = &d->r[i];
        g->state = R_LEASED;
        g->owner = owner;
        g->t_leased = pt_now_ms();
        g->lease_ms = lease_ms;
        memset(t, 0, sizeof *t);
        t->job_id = d->job_id;
        t->task_id = PROTO_DENOISE_TASK_BIT | i;
        t->crop_w = rect_w(g->crop);
        t->crop_h = rect_h(g->crop);
        t->region = (pt_rect){g->rect[0] - g->crop[0], g->rect[1] - g->crop[1],
                              g->rect[2] - g->crop[0], g->rect[3] - g->crop[1]};
        t->despeckle = d->in.despeckle;
        t->lease_ms = lease_ms;
        memcpy(t->hash, g->hash, 32);
        t->size = crop_bytes(g);
    }
    pthread_mutex_unlock(&d->mu);
    return got;
}

int srv_dnshare_chunk(srv_dnshare *d, const uint8_t hash[32], uint64_t offset, uint8_t *buf,
                      size_t cap, size_t *len, uint64_t *total, uint64_t *job_id)
{
    pthread_mutex_lock(&d->mu);
    *job_id = d->job_id;
    int found = 0;
    for (uint32_t i = 0; d->open && i < d->n && !found; i++) {
        const region *g = &d->r[i];
        if (memcmp(g->hash, hash, 32) != 0)
            continue;
        found = 1;
        *total = crop_bytes(g);
        *len = offset < *total ? (size_t)(*total - offset < cap ? *total - offset : cap) : 0;
        crop_read(d, g, offset, buf, *len);
    }
    pthread_mutex_unlock(&d->mu);
    return found;
}

int srv_dnshare_result(srv_dnshare *d, uint64_t owner, int first, const proto_denoise_result *r,
                       pt_error *err)
{
    pthread_mutex_lock(&d->mu);
    int ok = SRV_DNSHARE_DROPPED;
    uint64_t i = r->task_id & ~PROTO_DENOISE_TASK_BIT;
    if (!d->open || r->job_id != d->job_id)
        goto out; /* late: the writer finished the frame */
    if (i >= d->n) {
        ok = SRV_DNSHARE_INVALID;
        pt_error_set(err, PT_ERR_FORMAT, "DENOISE_RESULT for region %llu of %u",
                     (unsigned long long)i, d->n);
        goto out;
    }
    region *g = &d->r[i];
    if (r->region.x0 != g->rect[0] - g->crop[0] || r->region.y0 != g->rect[1] - g->crop[1] ||
        r->region.x1 != g->rect[2] - g->crop[0] || r->region.y1 != g->rect[3] - g->crop[1]) {
        ok = SRV_DNSHARE_INVALID;
        pt_error_set(err, PT_ERR_FORMAT, "DENOISE_RESULT for region %llu has another rectangle",
                     (unsigned long long)i);
        goto out;
    }
    if (!(g->owner == owner && (g->state == R_LEASED || g->state == R_DONE)) &&
        !(g->state == R_DONE && g->owner == 0))
        goto out; /* not leased to it: dropped */
    /* The pixels, checked before they touch the frame. */
    float *const *out = d->out;
    size_t w = d->in.width, rw = rect_w(g->rect), rh = rect_h(g->rect), np = rw * rh;
    for (size_t k = 0; k < 3 * np; k++) {
        float v = proto_get_f32(r->data + 4 * k);
        if (!isfinite(v) || fabsf(v) > PT_DENOISE_MAX_VALUE) {
            ok = SRV_DNSHARE_INVALID;
            pt_error_set(err, PT_ERR_FORMAT, "DENOISE_RESULT for region %llu holds %g",
                         (unsigned long long)i, (double)v);
            goto out;
        }
    }
    if (g->state == R_DONE) {
        /* The writer's bits are there: a free verification. */
        int same = 1;
        for (int c = 0; c < 3 && same; c++)
            for (size_t y = 0; y < rh && same; y++)
                for (size_t x = 0; x < rw && same; x++) {
                    float v = proto_get_f32(r->data + 4 * (c * np + y * rw + x));
                    same = memcmp(&out[c][(y + g->rect[1]) * w + g->rect[0] + x], &v, 4) == 0;
                }
        if (g->owner == 0 && !same)
            liar(d, owner, (uint32_t)i);
        goto out;
    }
    for (int c = 0; c < 3; c++)
        for (size_t y = 0; y < rh; y++)
            for (size_t x = 0; x < rw; x++)
                out[c][(y + g->rect[1]) * w + g->rect[0] + x] =
                    proto_get_f32(r->data + 4 * (c * np + y * rw + x));
    g->state = R_DONE;
    g->verify = first || srv_verify_picked(d->seed, d->job_id, (uint32_t)i, d->fraction);
    d->st.by_workers++;
    progress_set(d);
    pthread_cond_signal(&d->cv);
    ok = SRV_DNSHARE_TAKEN;
out:
    pthread_mutex_unlock(&d->mu);
    return ok;
}

void srv_dnshare_release(srv_dnshare *d, uint64_t owner)
{
    pthread_mutex_lock(&d->mu);
    for (uint32_t i = 0; i < d->n; i++)
        if (d->r[i].state == R_LEASED && d->r[i].owner == owner) {
            d->r[i].state = R_FREE;
            d->r[i].owner = 0;
        }
    pthread_cond_signal(&d->cv);
    pthread_mutex_unlock(&d->mu);
}

uint32_t srv_dnshare_held(srv_dnshare *d, uint64_t owner)
{
    pthread_mutex_lock(&d->mu);
    uint32_t n = 0;
    for (uint32_t i = 0; d->open && i < d->n; i++)
        n += d->r[i].state == R_LEASED && d->r[i].owner == owner;
    pthread_mutex_unlock(&d->mu);
    return n;
}

int srv_dnshare_take_liar(srv_dnshare *d, uint64_t *owner)
{
    pthread_mutex_lock(&d->mu);
    int got = d->ntaken < d->nliars;
    if (got)
        *owner = d->liars[d->ntaken++];
    pthread_mutex_unlock(&d->mu);
    return got;
}
