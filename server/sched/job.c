#include "server/sched/job_impl.h"

#include <assert.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/hash.h"
#include "common/render/adaptive.h"
#include "common/render/render.h"

/* Waits for the job's adds in flight: the film's pixels are then the
 * merged tasks' sums (every read of them on the loop comes after this). */
void job_settle(const srv_job *j)
{
    if (j->adder)
        srv_adder_settle(j->adder, &j->adds);
}

uint64_t srv_film_bytes(uint32_t width, uint32_t height, uint32_t film_flags)
{
    return (uint64_t)width * height *
           (sizeof(pt_pixel_acc) + (proto_film_passes(film_flags) ? sizeof(pt_pass_acc) : 0));
}

size_t job_px_bytes(const srv_job *j, size_t npx)
{
    return npx * (sizeof(pt_pixel_acc) + (j->film->pass ? sizeof(pt_pass_acc) : 0));
}

uint32_t job_tile_pixels(const srv_job *j, uint32_t tile)
{
    uint32_t tx = tile % j->tiles_x, ty = tile / j->tiles_x;
    uint32_t w = j->p.width - tx * j->p.tile, h = j->p.height - ty * j->p.tile;
    return (w < j->p.tile ? w : j->p.tile) * (h < j->p.tile ? h : j->p.tile);
}

pt_rect job_tile_rect(const srv_job *j, uint32_t tile)
{
    uint32_t tx = tile % j->tiles_x, ty = tile / j->tiles_x;
    pt_rect r;
    r.x0 = tx * j->p.tile;
    r.y0 = ty * j->p.tile;
    r.x1 = r.x0 + j->p.tile < j->p.width ? r.x0 + j->p.tile : j->p.width;
    r.y1 = r.y0 + j->p.tile < j->p.height ? r.y0 + j->p.tile : j->p.height;
    return r;
}

/* Pixel-samples of task t: what its time is measured against. */
double job_task_work(const srv_job *j, uint32_t t)
{
    const task *k = &j->tasks[t];
    return (double)job_tile_pixels(j, k->tile) * (k->s1 - k->s0);
}

uint32_t srv_job_params_tiles(const srv_job_params *p)
{
    return ((p->width + p->tile - 1) / p->tile) * ((p->height + p->tile - 1) / p->tile);
}

uint32_t srv_job_params_passes(const srv_job_params *p)
{
    return (p->spp + p->chunk - 1) / p->chunk;
}

/* ---- where tasks may end ---- */

/* 1 when adaptive sampling decides after sample count s (s a multiple of the
 * chunk, at least min spp, short of spp). */
int job_decision_point(const srv_job *j, uint32_t s)
{
    return j->adaptive && s >= j->first_stop && s < j->p.spp && s % j->p.chunk == 0;
}

/* The furthest a task starting at s0 may end: spp, and for an adaptive job
 * never past a decision point. With the min-gain rule, which judges the
 * chunk before the point against the samples before it (pt_tile_gain), only
 * a task of exactly that chunk may end at one; the error rule reads the sums
 * alone. */
uint32_t job_max_end(const srv_job *j, uint32_t s0)
{
    /* A guided job's passes (job_guide.c) are never crossed either: its
     * tasks render with one pass's distribution. It is never adaptive. */
    uint32_t e = job_guide_end(j, s0);
    if (!j->adaptive)
        return e;
    uint64_t c = j->p.chunk;
    uint64_t d = ((uint64_t)s0 / c + 1) * c;
    if (d < j->first_stop)
        d = j->first_stop;
    if (d >= e)
        return e;
    if (j->p.min_gain > 0.0 && s0 < d - c)
        return (uint32_t)(d - c);
    return (uint32_t)d;
}

/* With the min gain, a task that starts a decision point's chunk must end at
 * the point: the end it must have, or 0 when it is free. */
uint32_t job_forced_end(const srv_job *j, uint32_t s0)
{
    if (!j->adaptive || j->p.min_gain <= 0.0 || s0 % j->p.chunk != 0)
        return 0;
    uint64_t d = (uint64_t)s0 + j->p.chunk;
    return job_decision_point(j, (uint32_t)(d < UINT32_MAX ? d : UINT32_MAX)) ? (uint32_t)d : 0;
}

/* 1 when time-sized tasks are cut for this job: a task time is set, and an
 * adaptive job's chunk is a whole number of sample blocks. */
static int time_sized(const srv_job *j)
{
    return j->pol.task_ms > 0 && (!j->adaptive || j->p.chunk % PT_SAMPLE_BLOCK == 0);
}

/* ms per pixel-sample expected of owner o's next task: its own average, else
 * the job's median, 0 when nothing was measured. */
double job_expected_ms_ps(const srv_job *j, const owner_stat *o)
{
    if (o && o->ms_ps > 0.0)
        return o->ms_ps;
    return j->t_mid;
}

/* Samples a time-sized task of a tile with px pixels should have for owner
 * o: the task time at o's speed, less near the end (TAIL_SHARE), a multiple
 * of PT_SAMPLE_BLOCK, at least one block (j->least). */
static uint32_t sized_samples(const srv_job *j, const owner_stat *o, uint32_t px)
{
    double v = job_expected_ms_ps(j, o);
    if (!(v > 0.0))
        return j->least;
    double ms = j->pol.task_ms;
    double farm = j->farm_rate + 1.0 / v; /* this lease included */
    double tail = (double)j->uncut / (farm * TAIL_SHARE);
    if (tail < ms)
        ms = tail;
    double n = ms / v / px;
    if (!(n < 1e9))
        n = 1e9;
    uint32_t b = (uint32_t)(n / PT_SAMPLE_BLOCK) * PT_SAMPLE_BLOCK;
    return b > j->least ? b : j->least;
}

/* The end of the next task of tile that starts at s0 (its frontier) for
 * owner o. Fixed chunks: the next multiple of chunk. Time-sized: s0 +
 * sized_samples, but at most (GROWTH - 1) x s0 past 16 (the first pass is
 * one block, so the progressive image comes as soon as with fixed chunks,
 * and each later one at most takes the tile to GROWTH times its samples),
 * ending on a block boundary. */
static uint32_t next_end(const srv_job *j, uint32_t tile, uint32_t s0, const owner_stat *o)
{
    uint32_t e = job_max_end(j, s0);
    if (job_forced_end(j, s0))
        return job_forced_end(j, s0);
    if (!time_sized(j)) {
        uint64_t c = ((uint64_t)s0 / j->p.chunk + 1) * j->p.chunk;
        return c < e ? (uint32_t)c : e;
    }
    uint32_t n = sized_samples(j, o, job_tile_pixels(j, tile));
    uint64_t grow = s0 == 0 ? j->least : (uint64_t)(s0 > j->least ? s0 : j->least) * (GROWTH - 1);
    if (n > grow)
        n = (uint32_t)grow;
    uint64_t s1 = (uint64_t)s0 + n;
    if (s1 >= e)
        return e;
    s1 -= s1 % PT_SAMPLE_BLOCK; /* s0 off a block boundary (an older chunk size) */
    if (s1 <= s0)
        s1 = (uint64_t)s0 + PT_SAMPLE_BLOCK - s0 % PT_SAMPLE_BLOCK;
    return s1 < e ? (uint32_t)s1 : e;
}

/* ---- tiles in order of samples cut ---- */

static int heap_less(const srv_job *j, uint32_t a, uint32_t b)
{
    uint32_t fa = j->tiles[a].frontier, fb = j->tiles[b].frontier;
    return fa < fb || (fa == fb && a < b);
}

static void heap_down(srv_job *j, uint32_t i)
{
    for (;;) {
        uint32_t l = 2 * i + 1, m = i;
        if (l < j->nheap && heap_less(j, j->heap[l], j->heap[m]))
            m = l;
        if (l + 1 < j->nheap && heap_less(j, j->heap[l + 1], j->heap[m]))
            m = l + 1;
        if (m == i)
            return;
        uint32_t t = j->heap[i];
        j->heap[i] = j->heap[m];
        j->heap[m] = t;
        i = m;
    }
}

static void heap_rebuild(srv_job *j)
{
    j->nheap = 0;
    for (uint32_t t = 0; t < j->ntiles; t++)
        if (!j->tiles[t].stopped && j->tiles[t].frontier < j->p.spp)
            j->heap[j->nheap++] = t;
    for (uint32_t i = j->nheap / 2; i-- > 0;)
        heap_down(j, i);
    j->heap_dirty = 0;
}

/* ---- the job ---- */

pt_status srv_job_new(uint64_t id, const srv_job_params *p, const uint8_t scene_hash[32],
                      srv_job **out, pt_error *err)
{
    if (!p->width || !p->height || !p->spp || !p->tile || !p->chunk || p->width > 65536 ||
        p->height > 65536 || (uint64_t)p->tile * p->tile > PROTO_MAX_TILE_PIXELS ||
        !(p->target_error >= 0.0) || !isfinite(p->target_error) || !(p->min_gain >= 0.0) ||
        !isfinite(p->min_gain))
        return pt_error_set(err, PT_ERR_ARG,
                            "job: size %ux%u, %u spp, tile %u, chunk %u is not a valid job",
                            p->width, p->height, p->spp, p->tile, p->chunk);
    uint64_t ntiles = srv_job_params_tiles(p);
    uint64_t most = ntiles * srv_job_params_passes(p);
    if (most > SRV_MAX_TASKS)
        return pt_error_set(err, PT_ERR_LIMIT, "job: %llu tasks is over the cap of %u",
                            (unsigned long long)most, SRV_MAX_TASKS);
    srv_job *j = pt_calloc(1, sizeof *j);
    if (!j)
        return pt_error_set(err, PT_ERR_NOMEM, "job: out of memory");
    pt_status st;
    j->id = id;
    j->p = *p;
    memcpy(j->hash, scene_hash, 32);
    j->tiles_x = (p->width + p->tile - 1) / p->tile;
    j->tiles_y = (p->height + p->tile - 1) / p->tile;
    j->ntiles = (uint32_t)ntiles;
    j->npasses = srv_job_params_passes(p);
    j->adaptive = p->target_error > 0.0 || p->min_gain > 0.0;
    uint32_t c = p->chunk, m = p->min_spp > c ? p->min_spp : c;
    j->first_stop =
        (uint32_t)(((uint64_t)m + c - 1) / c * c > UINT32_MAX ? UINT32_MAX
                                                              : ((uint64_t)m + c - 1) / c * c);
    j->least = PT_SAMPLE_BLOCK;
    while (j->least < p->spp && ntiles * ((p->spp + j->least - 1) / j->least) > SRV_MAX_TASKS / 2)
        j->least *= 2;
    j->lease_free = NONE;
    j->tiles = pt_calloc(j->ntiles, sizeof *j->tiles);
    j->heap = pt_malloc_array(j->ntiles, sizeof *j->heap);
    if (!j->tiles || !j->heap) {
        st = pt_error_set(err, PT_ERR_NOMEM, "job: out of memory for %u tiles", j->ntiles);
        goto fail;
    }
    for (uint32_t t = 0; t < j->ntiles; t++) {
        j->tiles[t].head = j->tiles[t].tail = NONE;
        j->uncut += (uint64_t)job_tile_pixels(j, t) * p->spp;
    }
    heap_rebuild(j);
    if ((st = pt_film_new(p->width, p->height, &j->film, err)) != PT_OK)
        goto fail;
    /* Render passes: their sums beside the film's, merged with them. */
    if (proto_film_passes(p->film_flags) &&
        (st = pt_film_enable_passes(j->film, proto_film_passes(p->film_flags), err)) != PT_OK)
        goto fail;
    if ((st = job_guide_init(j, err)) != PT_OK)
        goto fail;
    *out = j;
    return PT_OK;
fail:
    srv_job_free(j);
    return st;
}

void srv_job_free(srv_job *j)
{
    if (!j)
        return;
    job_settle(j);
    for (uint32_t i = 0; i < j->nheld; i++)
        pt_free(j->held[i].px);
    pt_free(j->held);
    pt_free(j->checks);
    pt_free(j->owners);
    pt_free(j->owner_map);
    pt_free(j->leases);
    pt_free(j->requeue);
    pt_free(j->tasks);
    pt_free(j->tiles);
    pt_free(j->heap);
    pt_film_free(j->film);
    job_guide_free(j);
    pt_free(j);
}

void srv_job_set_adder(srv_job *j, srv_adder *a)
{
    job_settle(j);
    j->adder = a;
}

void srv_job_settle(const srv_job *j)
{
    job_settle(j);
}

uint64_t srv_job_id(const srv_job *j)
{
    return j->id;
}
const srv_job_params *srv_job_params_of(const srv_job *j)
{
    return &j->p;
}
uint32_t srv_job_passes(const srv_job *j)
{
    return j->npasses;
}
uint32_t srv_job_passes_done(const srv_job *j)
{
    return j->passes_done;
}
uint64_t srv_job_tasks_total(const srv_job *j)
{
    /* Merged or skipped, plus cut and open, plus what fixed chunks would cut
     * of the rest (a chunk boundary ends a task; time-sized ones may cut it
     * otherwise): when nothing is open or uncut, the merged count. */
    uint64_t n = j->merged;
    for (uint32_t t = 0; t < j->ntiles; t++) {
        const tile_state *ts = &j->tiles[t];
        for (uint32_t k = ts->head; k != NONE; k = j->tasks[k].next)
            n++;
        if (!ts->stopped && ts->frontier < j->p.spp)
            n += j->npasses - ts->frontier / j->p.chunk;
    }
    return n;
}
uint64_t srv_job_tasks_merged(const srv_job *j)
{
    return j->merged;
}
uint64_t srv_job_samples_merged(const srv_job *j)
{
    return j->samples;
}
uint64_t srv_job_paths_capped(const srv_job *j)
{
    return j->capped;
}
uint64_t srv_job_clamped(const srv_job *j)
{
    return j->clamped;
}
uint32_t srv_job_leases(const srv_job *j)
{
    return j->nleases;
}
uint32_t srv_job_tiles_stopped(const srv_job *j)
{
    return j->stopped;
}
int srv_job_complete(const srv_job *j)
{
    if (j->tiles_done != j->ntiles)
        return 0;
    /* A mismatch means one of two merged results may be false: the job is
     * not done until a third render says whose (and blocks that worker). */
    for (uint32_t i = 0; i < j->nchecks; i++)
        if (j->checks[i].stage >= C_WANT_C)
            return 0;
    return 1;
}
const pt_film *srv_job_film(const srv_job *j)
{
    job_settle(j);
    return j->film;
}
uint32_t srv_job_tiles(const srv_job *j)
{
    return j->ntiles;
}

/* A new pending task [s0, s1) of tile, linked after `after` in the tile's
 * list (NONE: at its tail). NONE without memory. The requeue ring grows with
 * the table, so a task can always be put back (each is in it at most once). */
uint32_t job_task_add(srv_job *j, uint32_t tile, uint32_t s0, uint32_t s1, uint32_t after)
{
    if (j->ntasks == j->tasks_cap) {
        if (j->tasks_cap >= SRV_MAX_TASKS)
            return NONE;
        uint32_t cap = j->tasks_cap ? 2 * j->tasks_cap : 256;
        if (cap > SRV_MAX_TASKS)
            cap = SRV_MAX_TASKS;
        task *n = pt_realloc(j->tasks, (size_t)cap * sizeof *n);
        if (!n)
            return NONE;
        j->tasks = n;
        uint32_t *q = pt_malloc_array(cap, sizeof *q);
        if (!q)
            return NONE;
        for (uint32_t i = 0; i < j->rq_len; i++)
            q[i] = j->requeue[(j->rq_head + i) % j->tasks_cap];
        pt_free(j->requeue);
        j->requeue = q;
        j->rq_head = 0;
        j->tasks_cap = cap;
    }
    uint32_t t = j->ntasks++;
    j->tasks[t] = (task){tile, s0, s1, NONE, NONE, 0, T_PENDING};
    tile_state *ts = &j->tiles[tile];
    if (after == NONE) {
        if (ts->tail == NONE)
            ts->head = t;
        else
            j->tasks[ts->tail].next = t;
        ts->tail = t;
    } else {
        j->tasks[t].next = j->tasks[after].next;
        j->tasks[after].next = t;
        if (ts->tail == after)
            ts->tail = t;
    }
    return t;
}

void job_requeue_push(srv_job *j, uint32_t t)
{
    j->requeue[(j->rq_head + j->rq_len) % j->tasks_cap] = t;
    j->rq_len++;
}

/* Cuts the next task from the tile with the fewest samples cut, for owner o
 * (its speed sizes it). NONE when every tile is cut to its end. */
uint32_t job_cut_next(srv_job *j, const owner_stat *o)
{
    if (j->heap_dirty)
        heap_rebuild(j);
    while (j->nheap > 0) {
        uint32_t tile = j->heap[0];
        tile_state *ts = &j->tiles[tile];
        if (ts->stopped || ts->frontier >= j->p.spp) {
            j->heap[0] = j->heap[--j->nheap];
            heap_down(j, 0);
            continue;
        }
        /* The test hook's hold (srv_lease_policy.hold_spp): the tile with
         * the fewest samples cut is at it, so every tile is; once the gate
         * file exists the hold is gone for good. */
        if (j->pol.hold_spp && ts->frontier >= j->pol.hold_spp) {
            if (access(j->pol.hold_gate, F_OK) != 0)
                return NONE;
            j->pol.hold_spp = 0;
        }
        /* The tile with the fewest samples cut is at the guided pass's end:
         * every tile is, and the next pass waits for its distribution. */
        if (job_guide_gated(j, ts->frontier)) {
            job_guide_advance(j);
            if (job_guide_gated(j, ts->frontier))
                return NONE;
        }
        uint32_t s0 = ts->frontier, s1 = next_end(j, tile, s0, o);
        uint32_t t = job_task_add(j, tile, s0, s1, NONE);
        if (t == NONE)
            return NONE;
        ts->frontier = s1;
        j->uncut -= (uint64_t)job_tile_pixels(j, tile) * (s1 - s0);
        if (s1 >= j->p.spp) {
            j->heap[0] = j->heap[--j->nheap];
            if (j->nheap)
                heap_down(j, 0);
        } else {
            heap_down(j, 0);
        }
        return t;
    }
    return NONE;
}

/* ---- owners ---- */

static uint32_t owner_slot(uint64_t owner, uint32_t cap)
{
    uint64_t z = owner * 0x9E3779B97F4A7C15ull;
    return (uint32_t)(z >> 32) & (cap - 1);
}

owner_stat *job_owner_find(const srv_job *j, uint64_t owner)
{
    if (!j->owner_map_cap)
        return NULL;
    for (uint32_t i = owner_slot(owner, j->owner_map_cap);; i = (i + 1) & (j->owner_map_cap - 1)) {
        uint32_t v = j->owner_map[i];
        if (!v)
            return NULL;
        if (j->owners[v - 1].owner == owner)
            return &j->owners[v - 1];
    }
}

/* Owner's entry of the per-owner table (made when missing); NULL without memory. */
owner_stat *job_owner_entry(srv_job *j, uint64_t owner)
{
    owner_stat *o = job_owner_find(j, owner);
    if (o)
        return o;
    if (j->nowners == j->owners_cap) {
        owner_stat *n = pt_grow_array(j->owners, &j->owners_cap, sizeof *n, 16);
        if (!n)
            return NULL;
        j->owners = n;
    }
    if (2 * (j->nowners + 1) > j->owner_map_cap) {
        uint32_t cap = j->owner_map_cap ? 2 * j->owner_map_cap : 32;
        uint32_t *m = pt_calloc(cap, sizeof *m);
        if (!m)
            return NULL;
        for (uint32_t k = 0; k < j->nowners; k++) {
            uint32_t i = owner_slot(j->owners[k].owner, cap);
            while (m[i])
                i = (i + 1) & (cap - 1);
            m[i] = k + 1;
        }
        pt_free(j->owner_map);
        j->owner_map = m;
        j->owner_map_cap = cap;
    }
    uint32_t i = owner_slot(owner, j->owner_map_cap);
    while (j->owner_map[i])
        i = (i + 1) & (j->owner_map_cap - 1);
    j->owner_map[i] = j->nowners + 1;
    o = &j->owners[j->nowners++];
    memset(o, 0, sizeof *o);
    o->owner = owner;
    o->leases = NONE;
    return o;
}
