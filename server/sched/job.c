#include "server/sched/job.h"

#include <assert.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/hash.h"
#include "common/render/adaptive.h"
#include "common/render/render.h"

enum { T_PENDING = 0, T_LEASED = 1, T_HELD = 2, T_MERGED = 3, T_SKIPPED = 4 };

/* A lease's kind: the task's first copy, a backup copy of a straggler, or a
 * verification copy of a task already merged. */
enum { L_TASK = 0, L_BACKUP = 1, L_VERIFY = 2 };

#define NONE UINT32_MAX

/* A task: samples [s0, s1) of one tile. Its id is its index in the job's
 * task table; records are never removed (a check names a merged task). */
typedef struct task {
    uint32_t tile, s0, s1;
    uint32_t next;   /* the tile's next unmerged task in sample order, NONE at the end */
    uint32_t leases; /* its live leases: the first one's slot, NONE when none */
    uint32_t held;   /* T_HELD: its index in held[] */
    uint8_t state;   /* T_* */
} task;

/* A lease lives in a slot of a pool; slots are stable while it lives, so
 * tasks and owners keep lists of them (by slot) and nothing is looked up by
 * scanning. */
typedef struct lease {
    uint64_t owner;
    uint64_t start;    /* when it was handed out (ms) */
    uint64_t deadline; /* heartbeat deadline: start or last heartbeat + lease_ms */
    double rate;       /* what it adds to the farm's rate (pixel-samples per ms) */
    uint32_t task;
    uint32_t check;        /* L_VERIFY: its check's index */
    uint32_t tnext;        /* the task's next lease; in a free slot, the next free slot */
    uint32_t oprev, onext; /* the owner's lease list */
    uint32_t owner_ix;     /* the owner's index in owners[] */
    uint8_t kind;          /* L_* */
    uint8_t live;
    uint8_t answered; /* its result arrived and waits for its log record to be
                         durable before it is merged: not a straggler */
} lease;

typedef struct held {
    uint32_t task;
    uint64_t owner;
    pt_pixel_acc *px;
    uint64_t samples; /* the sum of px's n */
} held;

/* A verification in progress: the task's first result (owner[0], hash[0]),
 * a second worker's (stage 1 on), a third's when those two differ. */
enum { C_WANT_B = 0, C_LEASED_B, C_WANT_C, C_LEASED_C };

typedef struct check {
    uint32_t task;
    uint32_t lease; /* C_LEASED_*: the copy's slot */
    uint64_t owner[2];
    uint8_t hash[2][32];
    uint8_t stage; /* C_* */
} check;

/* Per worker connection (owner), what it delivered to this job, its leases
 * and its measured speed. */
typedef struct owner_stat {
    uint64_t owner, merged, verified, samples;
    double ms_ps;    /* ms per pixel-sample of one of its tasks (moving average); 0 unknown */
    uint32_t leases; /* its first lease's slot, NONE when none */
    uint32_t nleases;
} owner_stat;

/* Per tile: samples [0, merged) are in the film, [merged, frontier) are cut
 * into tasks (the list head..tail in sample order), [frontier, spp) are not
 * cut yet. */
typedef struct tile_state {
    uint32_t merged, frontier;
    uint32_t head, tail;
    uint8_t stopped; /* adaptive sampling stopped it: nothing more is rendered */
} tile_state;

#define TIMES 256 /* observed task times kept (a ring) for the deadline quantile */
#define CHECK_SCAN 64
/* Near the end a task takes at most the time the farm needs for the work not
 * yet cut, divided by this: the last tasks end within a fraction of one
 * another, and no core idles long on the tail. */
#define TAIL_SHARE 2.0
/* After the first pass a task takes a tile to at most this many times the
 * samples it had cut: 16, 128, 1024... so a 1,024-spp tile is three results
 * (doubling made it seven, and the coordinator's cost is per result), while
 * a task is still bounded by the task time and the image still improves
 * pass by pass, fewest samples first. */
#define GROWTH 8
/* Weight of a new measurement in an owner's moving average of its speed. */
#define SPEED_WEIGHT 0.5

struct srv_job {
    uint64_t id;
    srv_job_params p;
    uint8_t hash[32];
    uint32_t tiles_x, tiles_y, ntiles, npasses;
    int adaptive;        /* adaptive sampling is on: decisions at multiples of chunk */
    uint32_t first_stop; /* the first decision point (a multiple of chunk >= min_spp) */
    uint32_t least;      /* the fewest samples of a time-sized task: a block, or more
                          * where a job's blocks would pass half of SRV_MAX_TASKS */
    tile_state *tiles;
    uint32_t *heap; /* tiles not fully cut, by (frontier, tile) */
    uint32_t nheap;
    int heap_dirty; /* a frontier moved in the heap (a replay): rebuild it */
    task *tasks;
    uint32_t ntasks, tasks_cap;
    uint32_t *requeue; /* FIFO ring of task ids, as large as the task table */
    uint32_t rq_head, rq_len;
    lease *leases;
    uint32_t nleases, lease_slots, lease_free;
    held *held;
    uint32_t nheld, held_cap;
    uint64_t merged; /* tasks merged or skipped */
    uint64_t samples;
    uint64_t capped; /* paths ended by the depth cap, over the results accepted */
    uint32_t stopped, tiles_done;
    uint32_t passes_done, at_level; /* tiles with merged >= the next pass's samples */
    uint64_t uncut;                 /* pixel-samples of every tile's [frontier, spp) */
    double farm_rate;               /* sum of the live leases' rates */
    pt_film *film;
    srv_adder *adder; /* srv_job_set_adder: film adds go to its threads */
    srv_adds adds;    /* those in flight */
    /* deadlines, backups, verification and sizing (srv_job_set_policy) */
    srv_lease_policy pol;
    double times[TIMES];  /* ms per pixel-sample of merged results, in arrival order */
    double sorted[TIMES]; /* the same ntimes values, ascending */
    uint32_t ntimes, times_at;
    double t_high, t_mid; /* the quantile and the median of times, 0 before any */
    check *checks;
    uint32_t nchecks, checks_cap;
    owner_stat *owners;
    uint32_t nowners, owners_cap;
    uint32_t *owner_map; /* open addressing: owner index + 1, 0 empty */
    uint32_t owner_map_cap;
    srv_verify_stats vs;
};

/* Waits for the job's adds in flight: the film's pixels are then the
 * merged tasks' sums (every read of them on the loop comes after this). */
static void settle(const srv_job *j)
{
    if (j->adder)
        srv_adder_settle(j->adder, &j->adds);
}

static uint32_t tile_pixels(const srv_job *j, uint32_t tile)
{
    uint32_t tx = tile % j->tiles_x, ty = tile / j->tiles_x;
    uint32_t w = j->p.width - tx * j->p.tile, h = j->p.height - ty * j->p.tile;
    return (w < j->p.tile ? w : j->p.tile) * (h < j->p.tile ? h : j->p.tile);
}

static pt_rect tile_rect(const srv_job *j, uint32_t tile)
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
static double task_work(const srv_job *j, uint32_t t)
{
    const task *k = &j->tasks[t];
    return (double)tile_pixels(j, k->tile) * (k->s1 - k->s0);
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
static int decision_point(const srv_job *j, uint32_t s)
{
    return j->adaptive && s >= j->first_stop && s < j->p.spp && s % j->p.chunk == 0;
}

/* The furthest a task starting at s0 may end: spp, and for an adaptive job
 * never past a decision point. With the min-gain rule, which judges the
 * chunk before the point against the samples before it (pt_tile_gain), only
 * a task of exactly that chunk may end at one; the error rule reads the sums
 * alone. */
static uint32_t max_end(const srv_job *j, uint32_t s0)
{
    uint32_t e = j->p.spp;
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
static uint32_t forced_end(const srv_job *j, uint32_t s0)
{
    if (!j->adaptive || j->p.min_gain <= 0.0 || s0 % j->p.chunk != 0)
        return 0;
    uint64_t d = (uint64_t)s0 + j->p.chunk;
    return decision_point(j, (uint32_t)(d < UINT32_MAX ? d : UINT32_MAX)) ? (uint32_t)d : 0;
}

/* 1 when time-sized tasks are cut for this job: a task time is set, and an
 * adaptive job's chunk is a whole number of sample blocks. */
static int time_sized(const srv_job *j)
{
    return j->pol.task_ms > 0 && (!j->adaptive || j->p.chunk % PT_SAMPLE_BLOCK == 0);
}

/* ms per pixel-sample expected of owner o's next task: its own average, else
 * the job's median, 0 when nothing was measured. */
static double expected_ms_ps(const srv_job *j, const owner_stat *o)
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
    double v = expected_ms_ps(j, o);
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
    uint32_t e = max_end(j, s0);
    if (forced_end(j, s0))
        return forced_end(j, s0);
    if (!time_sized(j)) {
        uint64_t c = ((uint64_t)s0 / j->p.chunk + 1) * j->p.chunk;
        return c < e ? (uint32_t)c : e;
    }
    uint32_t n = sized_samples(j, o, tile_pixels(j, tile));
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
        j->uncut += (uint64_t)tile_pixels(j, t) * p->spp;
    }
    heap_rebuild(j);
    if ((st = pt_film_new(p->width, p->height, &j->film, err)) != PT_OK)
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
    settle(j);
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
    pt_free(j);
}

void srv_job_set_adder(srv_job *j, srv_adder *a)
{
    settle(j);
    j->adder = a;
}

void srv_job_settle(const srv_job *j)
{
    settle(j);
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
    settle(j);
    return j->film;
}
uint32_t srv_job_tiles(const srv_job *j)
{
    return j->ntiles;
}

/* A new pending task [s0, s1) of tile, linked after `after` in the tile's
 * list (NONE: at its tail). NONE without memory. The requeue ring grows with
 * the table, so a task can always be put back (each is in it at most once). */
static uint32_t task_add(srv_job *j, uint32_t tile, uint32_t s0, uint32_t s1, uint32_t after)
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

static void requeue_push(srv_job *j, uint32_t t)
{
    j->requeue[(j->rq_head + j->rq_len) % j->tasks_cap] = t;
    j->rq_len++;
}

/* Cuts the next task from the tile with the fewest samples cut, for owner o
 * (its speed sizes it). NONE when every tile is cut to its end. */
static uint32_t cut_next(srv_job *j, const owner_stat *o)
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
        uint32_t s0 = ts->frontier, s1 = next_end(j, tile, s0, o);
        uint32_t t = task_add(j, tile, s0, s1, NONE);
        if (t == NONE)
            return NONE;
        ts->frontier = s1;
        j->uncut -= (uint64_t)tile_pixels(j, tile) * (s1 - s0);
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

static owner_stat *owner_find(const srv_job *j, uint64_t owner)
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
static owner_stat *owner_entry(srv_job *j, uint64_t owner)
{
    owner_stat *o = owner_find(j, owner);
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

/* ---- leases ---- */

static int grow_leases(srv_job *j)
{
    if (j->lease_free != NONE)
        return 0;
    uint32_t cap = j->lease_slots ? 2 * j->lease_slots : 64;
    lease *n = pt_realloc(j->leases, (size_t)cap * sizeof *n);
    if (!n)
        return -1;
    j->leases = n;
    for (uint32_t i = cap; i-- > j->lease_slots;) {
        n[i].live = 0;
        n[i].tnext = j->lease_free;
        j->lease_free = i;
    }
    j->lease_slots = cap;
    return 0;
}

/* Live first or backup copies of task t (verification copies aside). */
static uint32_t task_copies(const srv_job *j, uint32_t t)
{
    uint32_t n = 0;
    for (uint32_t i = j->tasks[t].leases; i != NONE; i = j->leases[i].tnext)
        n += j->leases[i].kind != L_VERIFY;
    return n;
}

/* Owner's lease of task t: its slot, or -1. Walks the task's few copies. */
static int find_lease(const srv_job *j, uint32_t t, uint64_t owner)
{
    for (uint32_t i = j->tasks[t].leases; i != NONE; i = j->leases[i].tnext)
        if (j->leases[i].owner == owner)
            return (int)i;
    return -1;
}

/* Adds a lease (a slot is free: grow_leases). */
static uint32_t add_lease(srv_job *j, owner_stat *o, uint32_t t, uint8_t kind, uint32_t ci,
                          uint64_t now_ms, uint32_t lease_ms)
{
    uint32_t s = j->lease_free;
    lease *l = &j->leases[s];
    j->lease_free = l->tnext;
    double v = expected_ms_ps(j, o);
    *l = (lease){.owner = o->owner,
                 .start = now_ms,
                 .deadline = now_ms + lease_ms,
                 .rate = v > 0.0 ? 1.0 / v : 0.0,
                 .task = t,
                 .check = ci,
                 .tnext = j->tasks[t].leases,
                 .oprev = NONE,
                 .onext = o->leases,
                 .owner_ix = (uint32_t)(o - j->owners),
                 .kind = kind,
                 .live = 1};
    j->tasks[t].leases = s;
    if (o->leases != NONE)
        j->leases[o->leases].oprev = s;
    o->leases = s;
    o->nleases++;
    j->nleases++;
    j->farm_rate += l->rate;
    return s;
}

/* Removes the lease in slot s from its task's and owner's lists. */
static void remove_lease(srv_job *j, uint32_t s)
{
    lease *l = &j->leases[s];
    uint32_t *p = &j->tasks[l->task].leases;
    while (*p != s)
        p = &j->leases[*p].tnext;
    *p = l->tnext;
    owner_stat *o = &j->owners[l->owner_ix];
    if (l->oprev != NONE)
        j->leases[l->oprev].onext = l->onext;
    else
        o->leases = l->onext;
    if (l->onext != NONE)
        j->leases[l->onext].oprev = l->oprev;
    o->nleases--;
    j->nleases--;
    j->farm_rate -= l->rate;
    if (j->nleases == 0 || j->farm_rate < 0.0)
        j->farm_rate = 0.0; /* no drift left over from the sums */
    l->live = 0;
    l->tnext = j->lease_free;
    j->lease_free = s;
}

/* Drops the lease in slot s. A task's copy makes the task pending again
 * (requeued) when it was its last copy; a verification copy gives its check
 * back to the waiting ones. */
static void requeue_lease(srv_job *j, uint32_t s)
{
    lease l = j->leases[s];
    remove_lease(j, s);
    if (l.kind == L_VERIFY) {
        check *c = &j->checks[l.check];
        if (c->stage == C_LEASED_B || c->stage == C_LEASED_C)
            c->stage--;
        return;
    }
    if (j->tasks[l.task].state != T_LEASED || task_copies(j, l.task) > 0)
        return;
    j->tasks[l.task].state = T_PENDING;
    requeue_push(j, l.task);
}

/* Drops every first or backup copy of task t (its result was accepted, or
 * adaptive sampling skipped it). */
static void drop_copies(srv_job *j, uint32_t t)
{
    for (uint32_t i = j->tasks[t].leases; i != NONE;) {
        uint32_t next = j->leases[i].tnext;
        if (j->leases[i].kind != L_VERIFY)
            remove_lease(j, i);
        i = next;
    }
}

void srv_job_set_policy(srv_job *j, const srv_lease_policy *pol)
{
    j->pol = *pol;
}

/* How long after its start lease l may run, in ms; UINT64_MAX for no limit. */
static uint64_t allowance(const srv_job *j, const lease *l)
{
    if (!j->pol.floor_ms)
        return UINT64_MAX;
    if (j->t_high <= 0.0)
        return j->pol.first_ms > j->pol.floor_ms ? j->pol.first_ms : j->pol.floor_ms;
    double a = j->pol.factor * j->t_high * task_work(j, l->task);
    if (!(a < 1e15))
        a = 1e15;
    return a > (double)j->pol.floor_ms ? (uint64_t)a : j->pol.floor_ms;
}

/* A check owner may answer: the first waiting one whose results so far are
 * not owner's (only the first CHECK_SCAN are looked at, so a long list of
 * checks that only one worker could take costs little). -1 when none. */
static int verify_pick(const srv_job *j, uint64_t owner)
{
    uint32_t seen = 0;
    for (uint32_t i = 0; i < j->nchecks && seen < CHECK_SCAN; i++) {
        const check *c = &j->checks[i];
        if (c->stage != C_WANT_B && c->stage != C_WANT_C)
            continue;
        seen++;
        if (c->owner[0] == owner || (c->stage == C_WANT_C && c->owner[1] == owner))
            continue;
        return (int)i;
    }
    return -1;
}

/* The straggler owner should get a backup copy of: the oldest first copy,
 * not owner's, older than backup_factor x the median time for its size,
 * that has no backup yet. NONE when none (or nothing was observed). Scans
 * the leases, but only once nothing else is left to hand out. */
static uint32_t backup_pick(const srv_job *j, uint64_t owner, uint64_t now_ms)
{
    if (j->pol.backup_factor <= 0.0 || j->t_mid <= 0.0)
        return NONE;
    uint32_t best = NONE;
    uint64_t best_start = UINT64_MAX;
    for (uint32_t i = 0; i < j->lease_slots; i++) {
        const lease *l = &j->leases[i];
        if (!l->live || l->kind != L_TASK || l->answered || l->owner == owner ||
            l->start >= best_start)
            continue;
        double age = (double)(now_ms - l->start);
        if (now_ms < l->start || age < j->pol.backup_factor * j->t_mid * task_work(j, l->task))
            continue;
        if (task_copies(j, l->task) != 1)
            continue;
        best = l->task;
        best_start = l->start;
    }
    return best;
}

int srv_job_lease(srv_job *j, uint64_t owner, uint64_t now_ms, uint32_t lease_ms,
                  proto_task *task_out)
{
    uint32_t t = NONE, check_ix = 0;
    uint8_t kind = L_TASK;
    owner_stat *o = owner_entry(j, owner);
    if (!o || grow_leases(j) != 0)
        return 0;
    while (j->rq_len > 0) {
        uint32_t c = j->requeue[j->rq_head];
        j->rq_head = (j->rq_head + 1) % j->tasks_cap;
        j->rq_len--;
        if (j->tasks[c].state == T_PENDING) {
            t = c;
            break;
        }
    }
    int ci;
    if (t == NONE && (ci = verify_pick(j, owner)) >= 0) {
        t = j->checks[ci].task;
        kind = L_VERIFY;
        check_ix = (uint32_t)ci;
        j->checks[ci].stage++;
    }
    if (t == NONE)
        t = cut_next(j, o);
    if (t == NONE) {
        if ((t = backup_pick(j, owner, now_ms)) == NONE)
            return 0;
        kind = L_BACKUP;
        j->vs.backups++;
    }
    if (kind != L_VERIFY)
        j->tasks[t].state = T_LEASED;
    uint32_t s = add_lease(j, o, t, kind, check_ix, now_ms, lease_ms);
    if (kind == L_VERIFY)
        j->checks[check_ix].lease = s;

    const task *k = &j->tasks[t];
    memset(task_out, 0, sizeof *task_out);
    task_out->job_id = j->id;
    task_out->task_id = t;
    task_out->tile = tile_rect(j, k->tile);
    task_out->s0 = k->s0;
    task_out->s1 = k->s1;
    task_out->width = j->p.width;
    task_out->height = j->p.height;
    task_out->seed = j->p.seed;
    task_out->max_depth = (uint16_t)j->p.max_depth;
    task_out->rr_depth = (uint16_t)j->p.rr_depth;
    memcpy(task_out->scene_hash, j->hash, 32);
    task_out->lease_ms = lease_ms;
    snprintf(task_out->camera, sizeof task_out->camera, "%s", j->p.camera);
    task_out->env = j->p.env;
    task_out->film_flags = j->p.film_flags;
    snprintf(task_out->variant, sizeof task_out->variant, "%s", j->p.variant);
    task_out->shutter[0] = j->p.shutter[0];
    task_out->shutter[1] = j->p.shutter[1];
    return 1;
}

void srv_job_heartbeat(srv_job *j, uint64_t owner, uint64_t task_id, uint64_t now_ms,
                       uint32_t lease_ms)
{
    if (task_id >= j->ntasks)
        return;
    int i = find_lease(j, (uint32_t)task_id, owner);
    if (i >= 0)
        j->leases[i].deadline = now_ms + lease_ms;
}

uint32_t srv_job_release_owner(srv_job *j, uint64_t owner)
{
    owner_stat *o = owner_find(j, owner);
    uint32_t n = 0;
    while (o && o->leases != NONE) {
        requeue_lease(j, o->leases);
        n++;
    }
    return n;
}

uint32_t srv_job_expire(srv_job *j, uint64_t now_ms, uint64_t *next_deadline, srv_miss_fn missed,
                        void *ctx)
{
    uint32_t n = 0;
    uint64_t next = UINT64_MAX;
    for (uint32_t i = 0; i < j->lease_slots; i++) {
        lease *l = &j->leases[i];
        if (!l->live)
            continue;
        uint64_t a = allowance(j, l);
        uint64_t hard = a > UINT64_MAX - l->start ? UINT64_MAX : l->start + a;
        uint64_t d = l->deadline < hard ? l->deadline : hard;
        if (d <= now_ms) {
            uint64_t owner = l->owner, t = l->task;
            /* Before the job's first result a slow start (a big scene to
             * fetch and load) cannot be told from hoarding: no miss then,
             * unless the owner stopped heartbeating. */
            int miss = l->deadline <= now_ms || j->t_high > 0.0;
            requeue_lease(j, i);
            n++;
            j->vs.expired++;
            if (missed && miss)
                missed(ctx, owner, t);
        } else if (d < next) {
            next = d;
        }
    }
    if (next_deadline)
        *next_deadline = next;
    return n;
}

/* ---- merging ---- */

/* A tile's samples as the passes count them: spp once stopped. */
static uint32_t tile_done_samples(const srv_job *j, uint32_t tile)
{
    return j->tiles[tile].stopped ? j->p.spp : j->tiles[tile].merged;
}

/* The samples every tile needs for the next pass to be done. */
static uint32_t next_level(const srv_job *j)
{
    uint64_t l = (uint64_t)(j->passes_done + 1) * j->p.chunk;
    return l < j->p.spp ? (uint32_t)l : j->p.spp;
}

/* Counts passes done from scratch, from the tiles' samples (one pass of the
 * tiles per pass done, so a few per job). */
static void passes_recount(srv_job *j)
{
    while (j->passes_done < j->npasses) {
        uint32_t l = next_level(j);
        j->at_level = 0;
        for (uint32_t t = 0; t < j->ntiles; t++)
            j->at_level += tile_done_samples(j, t) >= l;
        if (j->at_level < j->ntiles)
            return;
        j->passes_done++;
    }
}

/* A tile went from `from` to `to` samples (as tile_done_samples counts). */
static void tile_moved(srv_job *j, uint32_t from, uint32_t to)
{
    if (j->passes_done >= j->npasses)
        return;
    uint32_t l = next_level(j);
    if (from < l && to >= l && ++j->at_level == j->ntiles) {
        j->passes_done++;
        passes_recount(j);
    }
}

static void held_remove(srv_job *j, uint32_t i)
{
    j->held[i] = j->held[--j->nheld];
    if (i < j->nheld)
        j->tasks[j->held[i].task].held = i;
}

/* Adaptive sampling stopped tile: its later tasks are done without work;
 * leased ones lose their lease, held ones their pixels, and nothing more of
 * it is cut. */
static void stop_tile(srv_job *j, uint32_t tile)
{
    tile_state *ts = &j->tiles[tile];
    for (uint32_t t = ts->head; t != NONE;) {
        task *k = &j->tasks[t];
        uint32_t next = k->next;
        if (k->state == T_LEASED) {
            drop_copies(j, t);
        } else if (k->state == T_HELD) {
            pt_free(j->held[k->held].px);
            held_remove(j, k->held);
        }
        k->state = T_SKIPPED;
        j->merged++;
        t = next;
    }
    ts->head = ts->tail = NONE;
    j->uncut -= (uint64_t)tile_pixels(j, tile) * (j->p.spp - ts->frontier);
    ts->frontier = j->p.spp;
    ts->stopped = 1;
    j->stopped++;
    j->tiles_done++;
    tile_moved(j, ts->merged, j->p.spp);
}

/* Adds task t, the first unmerged of its tile, to the film: px holds its
 * sums, samples in all (the sum of their n). owned: px is the job's to
 * free (pt_malloc), so the add may go to the adder's threads. */
static void merge_now(srv_job *j, uint32_t t, pt_pixel_acc *px, uint64_t samples, int owned)
{
    task *k = &j->tasks[t];
    tile_state *ts = &j->tiles[k->tile];
    pt_rect r = tile_rect(j, k->tile);
    /* Only at a decision point, which no task crosses (max_end): the
     * decision sees the same sums however the samples before were split
     * (with the min gain, the task is the chunk before the point). It reads
     * the tile's sums, so the adds in flight land first. */
    int decide = decision_point(j, k->s1) && (j->p.min_gain <= 0.0 || k->s1 - k->s0 == j->p.chunk);
    if (j->adder && owned && !decide) {
        srv_adder_post(j->adder, &j->adds, j->film, r, px);
        owned = 0;
    } else {
        if (decide)
            settle(j);
        uint64_t added = pt_film_add_tile(j->film, r, px);
        assert(added == samples); /* validated: n sums to the samples less rejections */
        (void)added;
    }
    j->samples += samples;
    k->state = T_MERGED;
    j->merged++;
    uint32_t from = ts->merged;
    ts->merged = k->s1;
    ts->head = k->next;
    if (ts->head == NONE)
        ts->tail = NONE;
    if (ts->merged == j->p.spp)
        j->tiles_done++;
    tile_moved(j, from, ts->merged);
    pt_adaptive rule = {j->p.target_error, j->p.min_gain, j->p.min_spp};
    uint32_t tw = r.x1 - r.x0;
    if (decide && pt_tile_stops(&j->film->px[(size_t)r.y0 * j->p.width + r.x0], j->p.width, px, tw,
                                tw, r.y1 - r.y0, k->s1, &rule))
        stop_tile(j, k->tile);
    if (owned)
        pt_free(px);
}

/* Merges the held tasks of a tile that have become next in line. */
static void merge_held(srv_job *j, uint32_t tile)
{
    for (;;) {
        uint32_t t = j->tiles[tile].head;
        if (t == NONE || j->tasks[t].state != T_HELD)
            return;
        held h = j->held[j->tasks[t].held];
        held_remove(j, j->tasks[t].held);
        merge_now(j, t, h.px, h.samples, 1);
    }
}

/* The largest sum n samples can give, in fixed point: n x the cap per sample,
 * with room for each block's rounding (a double sum of 16 samples is within
 * 2^-48 of its exact value, and rounding to fixed point adds at most half a
 * unit). At most 2^32 x 4.3e27 x (1 + 2^-40) + 2^32, below 2^127 (tile.h). */
static pt_i128 acc_cap(uint32_t n)
{
    pt_i128 per = (pt_i128)(PT_MAX_SAMPLE_RADIANCE * PT_FIXED_ONE * (1.0 + 0x1p-40)) + 1;
    return per * n;
}

/* Sums non-negative and within the cap for n samples (radiance is never
 * negative: emission, base colour and textures are bounded and non-negative,
 * see common/scene/scene.c), a pixel with no samples all zero, counts
 * consistent. The sum of squares is unsigned and saturates (tile.h): any
 * value is possible but 0 is the only one for no samples. */
static int acc_sane(const pt_pixel_acc *a, uint32_t max_n)
{
    pt_i128 cap = acc_cap(a->n);
    for (int c = 0; c < 3; c++)
        if (!(a->fsum[c] >= 0 && a->fsum[c] <= cap))
            return 0;
    return (a->n > 0 || a->fsum_sq == 0) && a->n <= max_n && a->hits <= a->n;
}

/* Each pixel's count must be the task's samples less those rejected (a NaN,
 * Inf or over-the-cap sample is not counted, render.h), the rejections must
 * add up to what the result reports, and the sums must be non-negative and at
 * most n x PT_MAX_SAMPLE_RADIANCE (acc_sane). A pixel with no samples then has
 * zero sums. */
static int pixels_plausible(const proto_result *r, uint32_t samples, pt_error *err)
{
    uint64_t missing = 0;
    for (uint32_t i = 0; i < r->npixels; i++) {
        const pt_pixel_acc *a = &r->pixels[i];
        if (a->n > samples || !acc_sane(a, samples)) {
            pt_error_set(err, PT_ERR_PROTO,
                         "result for task %llu: pixel %u (%u samples of %u, sums %.3g %.3g %.3g) "
                         "is not a plausible render",
                         (unsigned long long)r->task_id, i, a->n, samples, pt_acc_sum(a, 0),
                         pt_acc_sum(a, 1), pt_acc_sum(a, 2));
            return 0;
        }
        missing += samples - a->n;
    }
    if (missing != r->rejected) {
        pt_error_set(err, PT_ERR_PROTO,
                     "result for task %llu: its pixels lack %llu samples in all (of %u each), but "
                     "it reports %llu rejected",
                     (unsigned long long)r->task_id, (unsigned long long)missing, samples,
                     (unsigned long long)r->rejected);
        return 0;
    }
    if (r->capped > (uint64_t)r->npixels * samples) {
        pt_error_set(err, PT_ERR_PROTO,
                     "result for task %llu: %llu paths at the depth cap, more than its samples",
                     (unsigned long long)r->task_id, (unsigned long long)r->capped);
        return 0;
    }
    return 1;
}

/* Checks r against the task it names; need_lease: the owner must hold it.
 * On SRV_MERGED or SRV_CHECK *lease_index receives the lease (-1 when none
 * was needed). */

/* Checks a leased result r against its task: on SRV_MERGED or SRV_CHECK
 * *lease_index receives owner's lease. */
static srv_outcome validate_result(const srv_job *j, uint64_t owner, const proto_result *r,
                                   int pixels_checked, int *lease_index, pt_error *err)
{
    if (r->job_id != j->id) {
        pt_error_set(err, PT_ERR_PROTO, "result for job %llu, not the running job %llu",
                     (unsigned long long)r->job_id, (unsigned long long)j->id);
        return SRV_NOT_LEASED;
    }
    /* Past the most tasks the job can have: the peer made it up. Short of
     * it, perhaps a task not cut yet: never leased to it, but no proof of
     * malice. */
    if (r->task_id >= (uint64_t)j->ntiles * j->npasses && r->task_id >= j->ntasks) {
        pt_error_set(err, PT_ERR_PROTO, "result for task %llu, which does not exist",
                     (unsigned long long)r->task_id);
        return SRV_INVALID;
    }
    if (r->task_id >= j->ntasks) {
        pt_error_set(err, PT_ERR_PROTO, "result for task %llu, which this peer does not hold",
                     (unsigned long long)r->task_id);
        return SRV_NOT_LEASED;
    }
    uint32_t t = (uint32_t)r->task_id;
    const task *k = &j->tasks[t];
    int li = find_lease(j, t, owner);
    int verify = li >= 0 && j->leases[li].kind == L_VERIFY;
    if (!verify && (k->state == T_MERGED || k->state == T_HELD || k->state == T_SKIPPED))
        return SRV_DUPLICATE;
    if (li < 0) {
        pt_error_set(err, PT_ERR_PROTO, "result for task %llu, which this peer does not hold",
                     (unsigned long long)t);
        return SRV_NOT_LEASED;
    }
    pt_rect rc = tile_rect(j, k->tile);
    if (memcmp(&rc, &r->tile, sizeof rc) != 0 || r->s0 != k->s0 || r->s1 != k->s1 ||
        r->npixels != (rc.x1 - rc.x0) * (rc.y1 - rc.y0)) {
        pt_error_set(err, PT_ERR_PROTO,
                     "result for task %llu does not match the task's tile or samples",
                     (unsigned long long)t);
        return SRV_INVALID;
    }
    /* Checked for its own range, which is the task's (just above). */
    if (!pixels_checked && !pixels_plausible(r, k->s1 - k->s0, err))
        return SRV_INVALID;
    *lease_index = li;
    return verify ? SRV_CHECK : SRV_MERGED;
}

srv_outcome srv_job_validate(const srv_job *j, uint64_t owner, const proto_result *r,
                             int *lease_index, pt_error *err)
{
    return validate_result(j, owner, r, 0, lease_index, err);
}

srv_outcome srv_job_validate_checked(const srv_job *j, uint64_t owner, const proto_result *r,
                                     int *lease_index, pt_error *err)
{
    return validate_result(j, owner, r, 1, lease_index, err);
}

int srv_job_pixels_plausible(const proto_result *r, pt_error *err)
{
    return r->s1 > r->s0 && pixels_plausible(r, r->s1 - r->s0, err);
}

/* The deterministic pick of verification copies: splitmix64 (Steele et al.
 * 2014) of the seed, job and task, as a uniform number in [0, 1). */
static int verify_picked(const srv_job *j, uint64_t t)
{
    if (!(j->pol.verify_fraction > 0.0))
        return 0;
    uint64_t z = j->pol.verify_seed ^ (j->id * 0xD1B54A32D192ED03ull) ^ t;
    z += 0x9E3779B97F4A7C15ull;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    z ^= z >> 31;
    return (double)(z >> 11) * 0x1.0p-53 < j->pol.verify_fraction;
}

static void pixels_hash(const proto_result *r, uint8_t out[32])
{
    /* pt_pixel_acc has no implicit padding, so the bytes are the result's
     * values (camera hits included) and nothing else. */
    pt_sha256((const uint8_t *)r->pixels, (size_t)r->npixels * sizeof *r->pixels, out);
}

static void add_check(srv_job *j, uint32_t t, uint64_t owner, const proto_result *r)
{
    if (j->nchecks == j->checks_cap) {
        check *n = pt_grow_array(j->checks, &j->checks_cap, sizeof *n, 32);
        if (!n)
            return; /* this task goes unverified; nothing else is lost */
        j->checks = n;
    }
    check *c = &j->checks[j->nchecks++];
    memset(c, 0, sizeof *c);
    c->task = t;
    c->lease = NONE;
    c->owner[0] = owner;
    pixels_hash(r, c->hash[0]);
    c->stage = C_WANT_B;
    j->vs.picked++;
}

/* Check i's live copy, or NONE. */
static uint32_t check_lease(const srv_job *j, uint32_t i)
{
    const check *c = &j->checks[i];
    if (c->stage != C_LEASED_B && c->stage != C_LEASED_C)
        return NONE;
    const lease *l = &j->leases[c->lease];
    return l->live && l->kind == L_VERIFY && l->check == i ? c->lease : NONE;
}

/* Ends check i: its lease goes, the last check takes its place. */
static void free_check(srv_job *j, uint32_t i)
{
    uint32_t s = check_lease(j, i);
    if (s != NONE)
        remove_lease(j, s);
    uint32_t last = --j->nchecks;
    if (i == last)
        return;
    j->checks[i] = j->checks[last];
    const check *c = &j->checks[i];
    if (c->stage == C_LEASED_B || c->stage == C_LEASED_C) {
        lease *l = &j->leases[c->lease];
        if (l->live && l->kind == L_VERIFY && l->check == last)
            l->check = i;
    }
}

/* Learns how long a task took (ms per pixel-sample) and the quantiles the
 * deadlines and backups use. */
/* The first index of sorted[0, n) whose value is not below x. */
static uint32_t lower_bound(const double *sorted, uint32_t n, double x)
{
    uint32_t lo = 0, hi = n;
    while (lo < hi) {
        uint32_t mid = lo + (hi - lo) / 2;
        if (sorted[mid] < x)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

static void observe(srv_job *j, double ms_per_sample)
{
    /* The window stays sorted as it slides: the value leaving the ring is
     * taken out and the new one put in, two moves of at most 2 KiB, where
     * sorting the window again cost tens of microseconds of the event loop
     * per result. */
    uint32_t n = j->ntimes;
    if (n == TIMES) {
        uint32_t k = lower_bound(j->sorted, n, j->times[j->times_at]);
        memmove(&j->sorted[k], &j->sorted[k + 1], (n - k - 1) * sizeof *j->sorted);
        n--;
    }
    uint32_t k = lower_bound(j->sorted, n, ms_per_sample);
    memmove(&j->sorted[k + 1], &j->sorted[k], (n - k) * sizeof *j->sorted);
    j->sorted[k] = ms_per_sample;
    j->ntimes = ++n;
    j->times[j->times_at] = ms_per_sample;
    j->times_at = (j->times_at + 1) % TIMES;
    const double *v = j->sorted;
    j->t_high = v[(uint32_t)(SRV_DEADLINE_QUANTILE * (n - 1) + 0.5)];
    j->t_mid = v[(n - 1) / 2];
    /* A zero time (a task done within the clock's millisecond) still says
     * that something was observed. */
    if (j->t_high <= 0.0)
        j->t_high = 1e-12;
    if (j->t_mid <= 0.0)
        j->t_mid = 1e-12;
}

/* What an accepted result of lease li (or -1: a replay) teaches: the task's
 * time, who delivered it, and whether it is picked for verification. Then
 * every copy's lease goes: the first result wins. */

/* What an accepted result of lease li (or -1: a replay) of task t teaches:
 * the task's time (the job's quantiles and its owner's speed), who delivered
 * it, and whether it is picked for verification. Then every copy's lease
 * goes: the first result wins. */
static void accepted(srv_job *j, uint32_t t, int li, const proto_result *r, uint64_t now_ms)
{
    if (li < 0) {
        drop_copies(j, t); /* a replay while leased (a paused job's last result) */
        return;
    }
    lease l = j->leases[li];
    uint32_t copies = task_copies(j, t);
    if (copies > 1)
        j->vs.backup_samples += (uint64_t)task_work(j, t) * (copies - 1);
    drop_copies(j, t);
    owner_stat *o = &j->owners[l.owner_ix];
    if (now_ms >= l.start && now_ms > 0) {
        /* A task done within the clock's millisecond counts as half of one. */
        double ms = now_ms > l.start ? (double)(now_ms - l.start) : 0.5;
        double v = ms / task_work(j, t);
        observe(j, (double)(now_ms - l.start) / task_work(j, t));
        o->ms_ps = o->ms_ps > 0.0 ? (1.0 - SPEED_WEIGHT) * o->ms_ps + SPEED_WEIGHT * v : v;
    }
    o->merged++;
    /* What its pixels hold, without a walk: validated, they lack exactly the
     * samples the result reports rejected (pixels_plausible). */
    o->samples += (uint64_t)r->npixels * (r->s1 - r->s0) - r->rejected;
    /* Each owner's first result in a job is checked too: at a fraction of
     * 0.02 a job of 64 tasks had a 27 % chance of no check at all, and a
     * worker that lied from its first result could go unchecked. */
    if (verify_picked(j, t) || (j->pol.verify_fraction > 0.0 && o->merged == 1))
        add_check(j, t, l.owner, r);
}

/* Merges or holds r, the result of task t (validated); li: its lease or -1.
 * take: r's pixels are pt_malloc'ed and the caller gives them up; the job
 * has them once this returns SRV_MERGED. */
static srv_outcome merge_task(srv_job *j, uint32_t t, int li, const proto_result *r, int take,
                              uint64_t now_ms, pt_error *err)
{
    uint32_t tile = j->tasks[t].tile;
    /* Validated: each pixel lacks exactly the samples reported rejected. */
    uint64_t samples = (uint64_t)r->npixels * (r->s1 - r->s0) - r->rejected;
    if (j->tiles[tile].head == t) {
        accepted(j, t, li, r, now_ms);
        j->capped += r->capped;
        merge_now(j, t, r->pixels, samples, take);
        merge_held(j, tile);
        return SRV_MERGED;
    }
    /* Early: hold a copy until the tile's earlier samples are merged. */
    if (j->nheld == j->held_cap) {
        held *n = pt_grow_array(j->held, &j->held_cap, sizeof *n, 32);
        if (!n)
            goto nomem;
        j->held = n;
    }
    pt_pixel_acc *copy = r->pixels;
    if (!take) {
        if (!(copy = pt_malloc_array(r->npixels, sizeof *copy)))
            goto nomem;
        memcpy(copy, r->pixels, (size_t)r->npixels * sizeof *copy);
    }
    j->held[j->nheld] = (held){t, li >= 0 ? j->leases[li].owner : 0, copy, samples};
    j->tasks[t].held = j->nheld++;
    accepted(j, t, li, r, now_ms);
    j->capped += r->capped;
    j->tasks[t].state = T_HELD;
    return SRV_MERGED;
nomem:
    /* Keep the lease: the task is requeued when it expires, nothing is lost. */
    pt_error_set(err, PT_ERR_NOMEM, "out of memory holding task %llu", (unsigned long long)t);
    return SRV_NOT_LEASED;
}

srv_outcome srv_job_result(srv_job *j, uint64_t owner, const proto_result *r, pt_error *err)
{
    int li;
    srv_outcome o = validate_result(j, owner, r, 0, &li, err);
    if (o == SRV_CHECK) {
        srv_verdict v;
        srv_job_check(j, li, r, &v);
        return SRV_CHECK;
    }
    return o == SRV_MERGED ? merge_task(j, j->leases[li].task, li, r, 0, 0, err) : o;
}

/* merge_task, taking r's pixels when r owns them. */
static srv_outcome merge_taking(srv_job *j, uint32_t t, int li, proto_result *r, uint64_t now_ms,
                                pt_error *err)
{
    srv_outcome o = merge_task(j, t, li, r, r->owns_pixels, now_ms, err);
    if (r->owns_pixels && o == SRV_MERGED) {
        r->pixels = NULL;
        r->owns_pixels = 0;
    }
    return o;
}

srv_outcome srv_job_result_validated(srv_job *j, int lease_index, proto_result *r, uint64_t now_ms,
                                     pt_error *err)
{
    return merge_taking(j, j->leases[lease_index].task, lease_index, r, now_ms, err);
}

/* 1 when [s0, s1) may be one task: within spp, crossing no decision point,
 * and (min gain) ending at one only as the chunk before it. */
static int cut_ok(const srv_job *j, uint32_t s0, uint32_t s1)
{
    return s0 < s1 && s1 <= max_end(j, s0) &&
           (!decision_point(j, s1) || j->p.min_gain <= 0.0 || s1 - s0 == j->p.chunk) &&
           (!forced_end(j, s0) || s1 == forced_end(j, s0));
}

/* Cuts [from, to) of tile into pending tasks (requeued), linked after
 * `after` (NONE: at the tail). -1 without memory or when the range cannot be
 * cut at valid points. */
static int cut_pending(srv_job *j, uint32_t tile, uint32_t from, uint32_t to, uint32_t after)
{
    while (from < to) {
        uint32_t e = max_end(j, from);
        if (e > to)
            e = to;
        if (!cut_ok(j, from, e))
            return -1;
        uint32_t t = task_add(j, tile, from, e, after);
        if (t == NONE)
            return -1;
        requeue_push(j, t);
        after = after == NONE ? NONE : t;
        from = e;
    }
    return 0;
}

/* The task of tile that samples [s0, s1) are, for a result without a lease
 * (a replay, a checkpoint's held result): the task cut so, else one made by
 * cutting a pending task or the tile's uncut samples (the rest pending).
 * SRV_MERGED with *out, or SRV_DUPLICATE (merged already), or SRV_INVALID
 * (the range does not fit what is cut; err says why). */
static srv_outcome locate(srv_job *j, uint32_t tile, uint32_t s0, uint32_t s1, uint32_t *out,
                          pt_error *err)
{
    tile_state *ts = &j->tiles[tile];
    if (s0 < s1 && s1 <= j->p.spp && (ts->stopped || s1 <= ts->merged))
        return SRV_DUPLICATE;
    if (s0 >= s1 || s1 > j->p.spp || s0 < ts->merged || !cut_ok(j, s0, s1))
        goto misfit;
    for (uint32_t t = ts->head; t != NONE; t = j->tasks[t].next) {
        task k = j->tasks[t];
        if (k.s0 == s0 && k.s1 == s1) {
            *out = t;
            return SRV_MERGED;
        }
        if (k.s1 <= s0)
            continue;
        if (k.s0 > s0 || s1 > k.s1 || k.state != T_PENDING || (k.s0 < s0 && !cut_ok(j, k.s0, s0)) ||
            (s1 < k.s1 && !cut_ok(j, s1, k.s1)))
            goto misfit;
        /* Split the pending task: it keeps its start, the rest is pending. */
        uint32_t n = t;
        if (k.s0 < s0) {
            j->tasks[t].s1 = s0;
            if ((n = task_add(j, tile, s0, s1, t)) == NONE)
                goto nomem;
        } else {
            j->tasks[t].s1 = s1;
        }
        if (s1 < k.s1) {
            uint32_t r = task_add(j, tile, s1, k.s1, n);
            if (r == NONE)
                goto nomem;
            requeue_push(j, r);
        }
        *out = n;
        return SRV_MERGED;
    }
    if (s0 < ts->frontier)
        goto misfit;
    if (cut_pending(j, tile, ts->frontier, s0, NONE) != 0)
        goto misfit;
    uint32_t t = task_add(j, tile, s0, s1, NONE);
    if (t == NONE)
        goto nomem;
    j->uncut -= (uint64_t)tile_pixels(j, tile) * (s1 - ts->frontier);
    ts->frontier = s1;
    j->heap_dirty = 1;
    *out = t;
    return SRV_MERGED;
misfit:
    pt_error_set(err, PT_ERR_PROTO, "samples %u to %u of tile %u do not fit the job's tasks", s0,
                 s1, tile);
    return SRV_INVALID;
nomem:
    pt_error_set(err, PT_ERR_NOMEM, "out of memory for the tasks of tile %u", tile);
    return SRV_INVALID;
}

/* The tile whose rectangle r is, or NONE. */
static uint32_t tile_of(const srv_job *j, pt_rect r)
{
    if (r.x0 % j->p.tile || r.y0 % j->p.tile || r.x0 >= j->p.width || r.y0 >= j->p.height)
        return NONE;
    uint32_t t = (r.y0 / j->p.tile) * j->tiles_x + r.x0 / j->p.tile;
    pt_rect e = tile_rect(j, t);
    return memcmp(&e, &r, sizeof e) == 0 ? t : NONE;
}

void srv_job_answered(srv_job *j, int lease_index)
{
    if (lease_index >= 0 && (uint32_t)lease_index < j->lease_slots && j->leases[lease_index].live)
        j->leases[lease_index].answered = 1;
}

srv_outcome srv_job_replay(srv_job *j, proto_result *r, pt_error *err)
{
    if (r->job_id != j->id) {
        pt_error_set(err, PT_ERR_PROTO, "result for job %llu, not the running job %llu",
                     (unsigned long long)r->job_id, (unsigned long long)j->id);
        return SRV_NOT_LEASED;
    }
    uint32_t tile = tile_of(j, r->tile), t;
    if (tile == NONE || r->npixels != tile_pixels(j, tile)) {
        pt_error_set(err, PT_ERR_PROTO, "result for task %llu: its tile is not one of the job's",
                     (unsigned long long)r->task_id);
        return SRV_INVALID;
    }
    srv_outcome o = locate(j, tile, r->s0, r->s1, &t, err);
    if (o != SRV_MERGED)
        return o;
    uint8_t st = j->tasks[t].state;
    if (st == T_MERGED || st == T_HELD || st == T_SKIPPED)
        return SRV_DUPLICATE;
    if (!pixels_plausible(r, r->s1 - r->s0, err))
        return SRV_INVALID;
    return merge_taking(j, t, -1, r, 0, err);
}

void srv_job_check(srv_job *j, int li, const proto_result *r, srv_verdict *v)
{
    lease l = j->leases[li];
    remove_lease(j, (uint32_t)li);
    memset(v, 0, sizeof *v);
    v->task = l.task;
    v->kind = SRV_V_UNRESOLVED;
    j->vs.samples += (uint64_t)task_work(j, l.task);
    check *c = &j->checks[l.check];
    uint8_t h[32];
    pixels_hash(r, h);
    if (c->stage == C_LEASED_B) {
        if (memcmp(h, c->hash[0], 32) == 0) {
            owner_stat *o = owner_entry(j, c->owner[0]);
            if (o)
                o->verified++;
            v->kind = SRV_V_MATCH;
            v->honest = c->owner[0];
            j->vs.matched++;
            free_check(j, l.check);
        } else {
            c->owner[1] = l.owner;
            memcpy(c->hash[1], h, 32);
            c->stage = C_WANT_C;
            v->kind = SRV_V_MISMATCH;
            j->vs.mismatched++;
        }
        return;
    }
    if (memcmp(h, c->hash[0], 32) == 0) {
        v->kind = SRV_V_LIAR;
        v->liar = c->owner[1];
        v->honest = c->owner[0];
    } else if (memcmp(h, c->hash[1], 32) == 0) {
        v->kind = SRV_V_LIAR;
        v->liar = c->owner[0];
        v->honest = c->owner[1];
    }
    j->vs.liars += v->kind == SRV_V_LIAR;
    free_check(j, l.check);
}

void srv_job_forget_owner(srv_job *j, uint64_t owner, uint64_t *merged, uint64_t *samples)
{
    srv_job_release_owner(j, owner);
    for (uint32_t i = 0; i < j->nheld;) {
        if (j->held[i].owner != owner) {
            i++;
            continue;
        }
        uint32_t t = j->held[i].task;
        pt_free(j->held[i].px);
        held_remove(j, i);
        j->tasks[t].state = T_PENDING;
        requeue_push(j, t);
    }
    for (uint32_t i = 0; i < j->nchecks;) {
        check *c = &j->checks[i];
        if (c->owner[0] == owner) {
            free_check(j, i);
            continue;
        }
        /* Its answer as the second render counts for nothing: ask again. */
        if ((c->stage == C_WANT_C || c->stage == C_LEASED_C) && c->owner[1] == owner)
            c->stage -= 2;
        i++;
    }
    owner_stat *o = owner_entry(j, owner);
    if (merged)
        *merged = o ? o->merged - o->verified : 0;
    if (samples)
        *samples = o ? o->samples : 0;
}

srv_verify_stats srv_job_verify_stats(const srv_job *j)
{
    return j->vs;
}

void srv_job_refused(srv_job *j)
{
    j->vs.refused++;
}

int srv_job_owner_active(const srv_job *j, uint64_t owner)
{
    const owner_stat *o = owner_find(j, owner);
    return o && o->nleases > 0;
}

/* ---- checkpoints ---- */

#define CKPT_MAGIC 0x434a5450u /* "PTJC" */
#define CKPT_VERSION 7u
#define CKPT_OLDEST_VERSION 2u   /* no min gain: read as 0 */
#define CKPT_MIN_GAIN_VERSION 3u /* the first with the min gain */
/* The first with the environment (older: none), and the first with the film
 * flags, the depth-cap count and each pixel's camera hits; older pixels read
 * as fully covered (their jobs are never transparent, so the count is not
 * shown). One format version brought both: srv_job_params_read takes one flag. */
#define CKPT_ENV_VERSION 4u
#define CKPT_FILM_VERSION CKPT_ENV_VERSION
/* The first with fixed-point sums (tile.h); older double sums are converted
 * as they are read (get_acc). */
#define CKPT_FIXED_VERSION 5u
/* The first with motion blur's shutter in the params (older: none). */
#define CKPT_SHUTTER_VERSION 7u

/* A pixel as the checkpoint stores it: each sum as two u64, low half first
 * (RESULT's wide layout, msg.h), then n and hits. */
static void put_acc(proto_writer *w, const pt_pixel_acc *a)
{
    for (int c = 0; c < 3; c++) {
        proto_w_u64(w, (uint64_t)a->fsum[c]);
        proto_w_u64(w, (uint64_t)(a->fsum[c] >> 64));
    }
    proto_w_u64(w, (uint64_t)a->fsum_sq);
    proto_w_u64(w, (uint64_t)(a->fsum_sq >> 64));
    proto_w_u32(w, a->n);
    proto_w_u32(w, a->hits);
}

/* A double sum of a checkpoint before CKPT_FIXED_VERSION in fixed point, by
 * the same rounding as a block's (pt_fixed_of): deterministic, so a job
 * resumed from an older checkpoint loses no work and every coordinator that
 * loads it gets the same bits. A value that is not finite or not within the
 * cap for n samples (which no render gives) becomes -1, for acc_sane to
 * refuse. */
static pt_i128 fixed_of_old(double d, uint32_t n)
{
    if (!(d >= 0.0 && d <= PT_MAX_SAMPLE_RADIANCE * n))
        return -1;
    return pt_fixed_of(d);
}

static void get_acc(proto_reader *r, pt_pixel_acc *a, uint32_t version)
{
    if (version >= CKPT_FIXED_VERSION) {
        for (int c = 0; c < 3; c++) {
            uint64_t lo = proto_r_u64(r, "pixel sum");
            a->fsum[c] = (pt_i128)(((pt_u128)proto_r_u64(r, "pixel sum") << 64) | lo);
        }
        uint64_t lo = proto_r_u64(r, "pixel sum of squares");
        a->fsum_sq = ((pt_u128)proto_r_u64(r, "pixel sum of squares") << 64) | lo;
        a->n = proto_r_u32(r, "pixel samples");
        a->hits = proto_r_u32(r, "pixel camera hits");
        return;
    }
    double sum[3], sum_sq;
    for (int c = 0; c < 3; c++)
        sum[c] = proto_r_f64(r, "pixel sum");
    sum_sq = proto_r_f64(r, "pixel sum of squares");
    a->n = proto_r_u32(r, "pixel samples");
    a->hits = version >= CKPT_FILM_VERSION ? proto_r_u32(r, "pixel camera hits") : a->n;
    for (int c = 0; c < 3; c++)
        a->fsum[c] = fixed_of_old(sum[c], a->n);
    a->fsum_sq = isfinite(sum_sq) ? pt_ufixed_of(sum_sq) : 0;
    if (!isfinite(sum_sq) || sum_sq < 0.0)
        a->fsum[0] = -1;
}

void srv_job_params_write(proto_writer *w, const srv_job_params *p)
{
    proto_w_u32(w, p->width);
    proto_w_u32(w, p->height);
    proto_w_u32(w, p->spp);
    proto_w_u32(w, p->tile);
    proto_w_u32(w, p->chunk);
    proto_w_u32(w, p->seed);
    proto_w_u32(w, p->max_depth);
    proto_w_u32(w, p->rr_depth);
    proto_w_u32(w, p->min_spp);
    proto_w_f64(w, p->target_error);
    proto_w_f64(w, p->min_gain);
    proto_w_str(w, p->camera);
    proto_w_str(w, p->env.name);
    proto_w_f32(w, p->env.strength);
    proto_w_f32(w, p->env.rotate_deg);
    proto_w_u8(w, p->env.background);
    for (int k = 0; k < 3; k++)
        proto_w_f32(w, p->env.rgb[k]);
    proto_w_u32(w, p->film_flags);
    proto_w_str(w, p->variant);
    proto_w_f64(w, p->shutter[0]);
    proto_w_f64(w, p->shutter[1]);
}

void srv_job_params_read(proto_reader *r, srv_job_params *p, int has_min_gain, int has_env_film,
                         int has_shutter)
{
    p->width = proto_r_u32(r, "width");
    p->height = proto_r_u32(r, "height");
    p->spp = proto_r_u32(r, "spp");
    p->tile = proto_r_u32(r, "tile");
    p->chunk = proto_r_u32(r, "chunk");
    p->seed = proto_r_u32(r, "seed");
    p->max_depth = proto_r_u32(r, "max depth");
    p->rr_depth = proto_r_u32(r, "rr depth");
    p->min_spp = proto_r_u32(r, "min spp");
    p->target_error = proto_r_f64(r, "target error");
    p->min_gain = has_min_gain ? proto_r_f64(r, "min gain") : 0.0;
    p->camera[0] = '\0';
    proto_r_str(r, p->camera, PROTO_MAX_NAME, "camera");
    proto_env_none(&p->env);
    p->film_flags = 0;
    p->variant[0] = '\0';
    p->shutter[0] = p->shutter[1] = 0.0;
    if (!has_env_film)
        return;
    proto_r_str(r, p->env.name, PROTO_MAX_PATH, "environment map name");
    p->env.strength = proto_r_f32(r, "environment strength");
    p->env.rotate_deg = proto_r_f32(r, "environment rotation");
    p->env.background = proto_r_u8(r, "environment background flag");
    for (int k = 0; k < 3; k++)
        p->env.rgb[k] = proto_r_f32(r, "background colour");
    p->film_flags = proto_r_u32(r, "film flags");
    if (r->status == PT_OK && (p->film_flags & ~PROTO_FILM_KNOWN))
        proto_r_fail(r, PT_ERR_FORMAT, "unknown", "film flags");
    proto_r_str(r, p->variant, PROTO_MAX_NAME, "variant");
    if (!has_shutter)
        return;
    p->shutter[0] = proto_r_f64(r, "shutter open");
    p->shutter[1] = proto_r_f64(r, "shutter close");
    if (r->status == PT_OK && proto_shutter_problem(p->shutter))
        proto_r_fail(r, PT_ERR_FORMAT, "bad", "shutter");
}

/* The first that records each tile's merged samples and each held result's
 * range (older: chunks merged per tile and held task ids, chunk x tiles +
 * tile, of fixed chunks). */
#define CKPT_RANGE_VERSION 6u

pt_status srv_job_save(const srv_job *j, proto_writer *w, pt_error *err)
{
    settle(j);
    proto_w_u32(w, CKPT_MAGIC);
    proto_w_u32(w, CKPT_VERSION);
    proto_w_u64(w, j->id);
    proto_w_bytes(w, j->hash, 32);
    srv_job_params_write(w, &j->p);
    proto_w_u64(w, j->capped);
    proto_w_u32(w, j->ntiles);
    proto_w_u32(w, j->npasses);
    for (uint32_t t = 0; t < j->ntiles; t++) {
        proto_w_u32(w, j->tiles[t].merged);
        proto_w_u8(w, j->tiles[t].stopped);
    }
    proto_w_u32(w, j->nheld);
    for (uint32_t i = 0; i < j->nheld; i++) {
        const task *k = &j->tasks[j->held[i].task];
        proto_w_u32(w, k->tile);
        proto_w_u32(w, k->s0);
        proto_w_u32(w, k->s1);
        uint32_t npx = tile_pixels(j, k->tile);
        for (uint32_t p = 0; p < npx; p++)
            put_acc(w, &j->held[i].px[p]);
    }
    size_t npx = (size_t)j->p.width * j->p.height;
    for (size_t k = 0; k < npx; k++)
        put_acc(w, &j->film->px[k]);
    if (proto_writer_status(w) != PT_OK)
        return pt_error_set(err, proto_writer_status(w),
                            "checkpoint of job %llu: cannot "
                            "serialise (%zu pixels)",
                            (unsigned long long)j->id, npx);
    return PT_OK;
}

pt_status srv_job_load(srv_job *j, const uint8_t *data, size_t len, pt_error *err)
{
    if (j->merged || j->nleases || j->nheld || j->ntasks)
        return pt_error_set(err, PT_ERR_ARG, "checkpoint: job %llu is not fresh",
                            (unsigned long long)j->id);
    proto_reader r = proto_reader_make(data, len);
    uint32_t magic = proto_r_u32(&r, "magic"), version = proto_r_u32(&r, "version");
    if (magic != CKPT_MAGIC || version < CKPT_OLDEST_VERSION || version > CKPT_VERSION)
        return pt_error_set(err, PT_ERR_FORMAT, "not a version %u to %u job checkpoint",
                            CKPT_OLDEST_VERSION, CKPT_VERSION);
    uint64_t id = proto_r_u64(&r, "job id");
    const uint8_t *hash = proto_r_bytes(&r, 32, "scene hash");
    srv_job_params p;
    int film = version >= CKPT_FILM_VERSION, ranges = version >= CKPT_RANGE_VERSION;
    /* Per pixel: 4 sums of 16 bytes (fixed point) or 8 (double, before
     * CKPT_FIXED_VERSION), n, and hits (from CKPT_FILM_VERSION on). */
    size_t acc_size = version >= CKPT_FIXED_VERSION ? 72 : film ? 40 : 36;
    srv_job_params_read(&r, &p, version >= CKPT_MIN_GAIN_VERSION, version >= CKPT_ENV_VERSION,
                        version >= CKPT_SHUTTER_VERSION);
    uint64_t capped = film ? proto_r_u64(&r, "paths capped") : 0;
    uint32_t ntiles = proto_r_u32(&r, "tiles"), nchunks = proto_r_u32(&r, "chunks");
    if (r.status != PT_OK)
        return proto_r_finish(&r, "checkpoint", err);
    if (id != j->id || memcmp(hash, j->hash, 32) != 0 || p.width != j->p.width ||
        p.height != j->p.height || p.spp != j->p.spp || p.tile != j->p.tile ||
        p.chunk != j->p.chunk || p.seed != j->p.seed || p.max_depth != j->p.max_depth ||
        p.rr_depth != j->p.rr_depth || p.min_spp != j->p.min_spp ||
        memcmp(&p.target_error, &j->p.target_error, sizeof p.target_error) != 0 ||
        memcmp(&p.min_gain, &j->p.min_gain, sizeof p.min_gain) != 0 ||
        strcmp(p.camera, j->p.camera) != 0 || !proto_env_same(&p.env, &j->p.env) ||
        p.film_flags != j->p.film_flags || strcmp(p.variant, j->p.variant) != 0 ||
        memcmp(p.shutter, j->p.shutter, sizeof p.shutter) != 0 || ntiles != j->ntiles ||
        nchunks != j->npasses)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "checkpoint is of another job or other settings "
                            "(job %llu, %ux%u, %u spp)",
                            (unsigned long long)id, p.width, p.height, p.spp);
    for (uint32_t t = 0; t < ntiles; t++) {
        uint32_t m = proto_r_u32(&r, ranges ? "tile samples merged" : "tile chunks merged");
        uint8_t stopped = proto_r_u8(&r, "tile stopped");
        if (r.status != PT_OK)
            return proto_r_finish(&r, "checkpoint", err);
        uint32_t most = ranges ? j->p.spp : nchunks;
        if (m > most || stopped > 1 || (stopped && m == most))
            return pt_error_set(err, PT_ERR_FORMAT,
                                "checkpoint: tile %u has %u %s merged of %u (stopped %u)", t, m,
                                ranges ? "samples" : "chunks", most, stopped);
        if (!ranges) {
            uint64_t s = (uint64_t)m * j->p.chunk;
            j->merged += m;
            m = s < j->p.spp ? (uint32_t)s : j->p.spp;
        } else {
            j->merged += (m + j->p.chunk - 1) / j->p.chunk; /* as many fixed chunks */
        }
        tile_state *ts = &j->tiles[t];
        ts->merged = ts->frontier = m;
        j->uncut -= (uint64_t)tile_pixels(j, t) * m;
        if (m == j->p.spp)
            j->tiles_done++;
        if (stopped) {
            j->uncut -= (uint64_t)tile_pixels(j, t) * (j->p.spp - m);
            ts->frontier = j->p.spp;
            ts->stopped = 1;
            j->stopped++;
            j->tiles_done++;
        }
    }
    j->heap_dirty = 1;
    uint32_t nheld = proto_r_u32(&r, "held results");
    if (r.status == PT_OK && nheld > (uint64_t)ntiles * nchunks)
        return pt_error_set(err, PT_ERR_FORMAT, "checkpoint: %u held results", nheld);
    for (uint32_t i = 0; i < nheld && r.status == PT_OK; i++) {
        uint32_t tile, s0, s1;
        if (ranges) {
            tile = proto_r_u32(&r, "held tile");
            s0 = proto_r_u32(&r, "held samples start");
            s1 = proto_r_u32(&r, "held samples end");
        } else {
            uint64_t t = proto_r_u64(&r, "held task");
            tile = (uint32_t)(t % ntiles);
            uint64_t c = t / ntiles, e = (c + 1) * j->p.chunk;
            s0 = c < nchunks ? (uint32_t)(c * j->p.chunk) : j->p.spp;
            s1 = e < j->p.spp ? (uint32_t)e : j->p.spp;
        }
        if (r.status != PT_OK)
            break;
        uint32_t t;
        pt_error e2 = {0};
        if (tile >= ntiles || locate(j, tile, s0, s1, &t, &e2) != SRV_MERGED ||
            j->tasks[t].state != T_PENDING)
            return pt_error_set(err, PT_ERR_FORMAT,
                                "checkpoint: held samples %u to %u of tile %u are not ones that "
                                "can be held",
                                s0, s1, tile);
        uint32_t npx = tile_pixels(j, tile);
        if (proto_r_left(&r) < (size_t)npx * acc_size)
            return pt_error_set(err, PT_ERR_FORMAT,
                                "checkpoint: truncated held samples %u to %u of tile %u", s0, s1,
                                tile);
        if (j->nheld == j->held_cap) {
            held *n = pt_grow_array(j->held, &j->held_cap, sizeof *n, 32);
            if (!n)
                return pt_error_set(err, PT_ERR_NOMEM, "checkpoint: out of memory");
            j->held = n;
        }
        pt_pixel_acc *px = pt_malloc_array(npx, sizeof *px);
        if (!px)
            return pt_error_set(err, PT_ERR_NOMEM, "checkpoint: out of memory");
        uint64_t samples = 0;
        for (uint32_t k = 0; k < npx; k++) {
            get_acc(&r, &px[k], version);
            samples += px[k].n;
        }
        j->held[j->nheld] = (held){t, 0, px, samples};
        j->tasks[t].held = j->nheld++;
        j->tasks[t].state = T_HELD;
        for (uint32_t k = 0; k < npx; k++)
            if (!acc_sane(&px[k], s1 - s0))
                return pt_error_set(err, PT_ERR_FORMAT,
                                    "checkpoint: held samples %u to %u of tile %u, pixel %u, "
                                    "are not finite or have too many samples",
                                    s0, s1, tile, k);
    }
    size_t npx = (size_t)j->p.width * j->p.height;
    if (r.status == PT_OK && proto_r_left(&r) != npx * acc_size)
        return pt_error_set(err, PT_ERR_FORMAT, "checkpoint: %zu bytes of film, expected %zu",
                            proto_r_left(&r), npx * acc_size);
    for (size_t k = 0; k < npx && r.status == PT_OK; k++) {
        get_acc(&r, &j->film->px[k], version);
        if (r.status == PT_OK && !acc_sane(&j->film->px[k], j->p.spp))
            return pt_error_set(err, PT_ERR_FORMAT,
                                "checkpoint: pixel %zu is not finite or has "
                                "too many samples",
                                k);
    }
    pt_status st = proto_r_finish(&r, "checkpoint", err);
    if (st != PT_OK)
        return st;
    j->samples = pt_film_total_samples(j->film);
    j->capped = capped;
    passes_recount(j);
    return PT_OK;
}

srv_job *srv_job_snapshot(const srv_job *j)
{
    settle(j);
    /* What srv_job_save reads, and nothing else: the sizes, the tiles' merged
     * samples, the held results (each with a copy of its task, numbered as
     * its place in held[], for its tile and range) and the film. */
    srv_job *c = pt_calloc(1, sizeof *c);
    if (!c)
        return NULL;
    c->id = j->id;
    c->p = j->p;
    memcpy(c->hash, j->hash, sizeof c->hash);
    c->tiles_x = j->tiles_x;
    c->tiles_y = j->tiles_y;
    c->ntiles = j->ntiles;
    c->npasses = j->npasses;
    c->capped = j->capped;
    c->tiles = pt_malloc_array(j->ntiles ? j->ntiles : 1, sizeof *c->tiles);
    c->tasks = pt_malloc_array(j->nheld ? j->nheld : 1, sizeof *c->tasks);
    c->held = pt_malloc_array(j->nheld ? j->nheld : 1, sizeof *c->held);
    if (!c->tiles || !c->tasks || !c->held ||
        pt_film_new(j->film->width, j->film->height, &c->film, NULL) != PT_OK) {
        srv_job_free(c);
        return NULL;
    }
    memcpy(c->tiles, j->tiles, (size_t)j->ntiles * sizeof *c->tiles);
    memcpy(c->film->px, j->film->px,
           (size_t)j->film->width * j->film->height * sizeof *c->film->px);
    for (uint32_t i = 0; i < j->nheld; i++) {
        const task *k = &j->tasks[j->held[i].task];
        size_t npx = tile_pixels(j, k->tile);
        pt_pixel_acc *px = pt_malloc_array(npx, sizeof *px);
        if (!px) {
            srv_job_free(c);
            return NULL;
        }
        memcpy(px, j->held[i].px, npx * sizeof *px);
        c->tasks[i] = (task){k->tile, k->s0, k->s1, NONE, NONE, i, T_HELD};
        c->ntasks = c->tasks_cap = i + 1;
        c->held[c->nheld++] = (held){i, j->held[i].owner, px, j->held[i].samples};
    }
    return c;
}
