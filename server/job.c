#include "server/job.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/hash.h"
#include "common/render/adaptive.h"

enum { T_PENDING = 0, T_LEASED = 1, T_HELD = 2, T_MERGED = 3, T_SKIPPED = 4 };

/* A lease's kind: the task's first copy, a backup copy of a straggler, or a
 * verification copy of a task already merged. */
enum { L_TASK = 0, L_BACKUP = 1, L_VERIFY = 2 };

typedef struct lease {
    uint64_t task, owner;
    uint64_t start;    /* when it was handed out (ms) */
    uint64_t deadline; /* heartbeat deadline: start or last heartbeat + lease_ms */
    uint32_t check;    /* L_VERIFY: its check's index */
    uint8_t kind;      /* L_* */
    uint8_t answered;  /* its result arrived and waits for its log record to be
                          durable before it is merged: not a straggler */
} lease;

typedef struct held {
    uint64_t task, owner;
    pt_pixel_acc *px;
} held;

/* A verification in progress: the task's first result (owner[0], hash[0]),
 * a second worker's (stage 1 on), a third's when those two differ. */
enum { C_WANT_B = 0, C_LEASED_B, C_WANT_C, C_LEASED_C };

typedef struct check {
    uint64_t task;
    uint64_t owner[2];
    uint8_t hash[2][32];
    uint8_t stage; /* C_* */
} check;

/* Per worker connection (owner), what it delivered to this job. */
typedef struct owner_stat {
    uint64_t owner, merged, verified, samples;
} owner_stat;

#define TIMES 256 /* observed task times kept (a ring) for the deadline quantile */
#define CHECK_SCAN 64

struct srv_job {
    uint64_t id;
    srv_job_params p;
    uint8_t hash[32];
    uint32_t tiles_x, tiles_y, ntiles, nchunks;
    uint64_t ntasks;
    uint8_t *state;           /* T_* per task */
    uint32_t *next_chunk;     /* per tile: the chunk to merge next */
    uint32_t *merged_in_pass; /* per chunk: tiles merged */
    uint32_t passes_done;
    uint64_t cursor;   /* every id below it has been handed out at least once */
    uint64_t *requeue; /* FIFO ring of task ids */
    uint64_t rq_head, rq_len, rq_cap;
    lease *leases;
    uint32_t nleases, leases_cap;
    held *held;
    uint32_t nheld, held_cap;
    uint64_t merged, samples;
    uint64_t capped; /* paths ended by the depth cap, over the results accepted */
    uint32_t stopped;
    pt_film *film;
    /* deadlines, backups and verification (srv_job_set_policy) */
    srv_lease_policy pol;
    double times[TIMES];  /* ms per pixel-sample of merged results, in arrival order */
    double sorted[TIMES]; /* the same ntimes values, ascending */
    uint32_t ntimes, times_at;
    double t_high, t_mid; /* the quantile and the median of times, 0 before any */
    check *checks;
    uint32_t nchecks, checks_cap;
    owner_stat *owners;
    uint32_t nowners, owners_cap;
    srv_verify_stats vs;
};

static pt_rect task_rect(const srv_job *j, uint64_t id)
{
    uint32_t tile = (uint32_t)(id % j->ntiles);
    uint32_t tx = tile % j->tiles_x, ty = tile / j->tiles_x;
    pt_rect r;
    r.x0 = tx * j->p.tile;
    r.y0 = ty * j->p.tile;
    r.x1 = r.x0 + j->p.tile < j->p.width ? r.x0 + j->p.tile : j->p.width;
    r.y1 = r.y0 + j->p.tile < j->p.height ? r.y0 + j->p.tile : j->p.height;
    return r;
}

static void task_samples(const srv_job *j, uint64_t id, uint32_t *s0, uint32_t *s1)
{
    uint32_t c = (uint32_t)(id / j->ntiles);
    *s0 = c * j->p.chunk;
    *s1 = *s0 + j->p.chunk < j->p.spp ? *s0 + j->p.chunk : j->p.spp;
}

uint32_t srv_job_params_tiles(const srv_job_params *p)
{
    return ((p->width + p->tile - 1) / p->tile) * ((p->height + p->tile - 1) / p->tile);
}

uint32_t srv_job_params_passes(const srv_job_params *p)
{
    return (p->spp + p->chunk - 1) / p->chunk;
}

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
    srv_job *j = pt_calloc(1, sizeof *j);
    if (!j)
        return pt_error_set(err, PT_ERR_NOMEM, "job: out of memory");
    pt_status st;
    j->id = id;
    j->p = *p;
    memcpy(j->hash, scene_hash, 32);
    j->tiles_x = (p->width + p->tile - 1) / p->tile;
    j->tiles_y = (p->height + p->tile - 1) / p->tile;
    j->ntiles = srv_job_params_tiles(p);
    j->nchunks = srv_job_params_passes(p);
    j->ntasks = (uint64_t)j->ntiles * j->nchunks;
    if (j->ntasks > SRV_MAX_TASKS) {
        st = pt_error_set(err, PT_ERR_LIMIT, "job: %llu tasks is over the cap of %u",
                          (unsigned long long)j->ntasks, SRV_MAX_TASKS);
        goto fail;
    }
    j->state = pt_calloc(j->ntasks, 1);
    j->next_chunk = pt_calloc(j->ntiles, sizeof *j->next_chunk);
    j->merged_in_pass = pt_calloc(j->nchunks, sizeof *j->merged_in_pass);
    if (!j->state || !j->next_chunk || !j->merged_in_pass) {
        st = pt_error_set(err, PT_ERR_NOMEM, "job: out of memory for %llu tasks",
                          (unsigned long long)j->ntasks);
        goto fail;
    }
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
    for (uint32_t i = 0; i < j->nheld; i++)
        pt_free(j->held[i].px);
    pt_free(j->held);
    pt_free(j->checks);
    pt_free(j->owners);
    pt_free(j->leases);
    pt_free(j->requeue);
    pt_free(j->state);
    pt_free(j->next_chunk);
    pt_free(j->merged_in_pass);
    pt_film_free(j->film);
    pt_free(j);
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
    return j->nchunks;
}
uint32_t srv_job_passes_done(const srv_job *j)
{
    return j->passes_done;
}
uint64_t srv_job_tasks_total(const srv_job *j)
{
    return j->ntasks;
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
    if (j->merged != j->ntasks)
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
    return j->film;
}

static int requeue_push(srv_job *j, uint64_t task)
{
    if (j->rq_len == j->rq_cap) {
        uint64_t cap = j->rq_cap ? 2 * j->rq_cap : 64;
        uint64_t *n = pt_malloc_array(cap, sizeof *n);
        if (!n)
            return -1;
        for (uint64_t i = 0; i < j->rq_len; i++)
            n[i] = j->requeue[(j->rq_head + i) % j->rq_cap];
        pt_free(j->requeue);
        j->requeue = n;
        j->rq_cap = cap;
        j->rq_head = 0;
    }
    j->requeue[(j->rq_head + j->rq_len) % j->rq_cap] = task;
    j->rq_len++;
    return 0;
}

/* Pixel-samples of task t: what its time is measured against. */
static double task_work(const srv_job *j, uint64_t t)
{
    pt_rect r = task_rect(j, t);
    uint32_t s0, s1;
    task_samples(j, t, &s0, &s1);
    return (double)(r.x1 - r.x0) * (r.y1 - r.y0) * (s1 - s0);
}

/* Live first or backup copies of task t (verification copies aside). */
static uint32_t task_copies(const srv_job *j, uint64_t t)
{
    uint32_t n = 0;
    for (uint32_t i = 0; i < j->nleases; i++)
        n += j->leases[i].task == t && j->leases[i].kind != L_VERIFY;
    return n;
}

/* Removes lease i (the last one takes its place). */
static void remove_lease(srv_job *j, uint32_t i)
{
    j->leases[i] = j->leases[--j->nleases];
}

/* Drops lease i. A task's copy makes the task pending again when it was its
 * last copy; a verification copy gives its check back to the waiting ones.
 * If the requeue list cannot grow, the cursor is moved back instead, which
 * also finds the task again. */
static void requeue_lease(srv_job *j, uint32_t i)
{
    lease l = j->leases[i];
    remove_lease(j, i);
    if (l.kind == L_VERIFY) {
        check *c = &j->checks[l.check];
        if (c->stage == C_LEASED_B || c->stage == C_LEASED_C)
            c->stage--;
        return;
    }
    if (j->state[l.task] != T_LEASED || task_copies(j, l.task) > 0)
        return;
    j->state[l.task] = T_PENDING;
    if (requeue_push(j, l.task) != 0 && l.task < j->cursor)
        j->cursor = l.task;
}

/* Drops every first or backup copy of task t (its result was accepted, or
 * adaptive sampling skipped it). */
static void drop_copies(srv_job *j, uint64_t t)
{
    for (uint32_t i = 0; i < j->nleases;)
        if (j->leases[i].task == t && j->leases[i].kind != L_VERIFY)
            remove_lease(j, i);
        else
            i++;
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

/* Owner's entry of the per-owner table (made when missing); NULL without memory. */
static owner_stat *owner_entry(srv_job *j, uint64_t owner)
{
    for (uint32_t i = 0; i < j->nowners; i++)
        if (j->owners[i].owner == owner)
            return &j->owners[i];
    if (j->nowners == j->owners_cap) {
        uint32_t cap = j->owners_cap ? 2 * j->owners_cap : 16;
        owner_stat *n = pt_realloc(j->owners, (size_t)cap * sizeof *n);
        if (!n)
            return NULL;
        j->owners = n;
        j->owners_cap = cap;
    }
    owner_stat *o = &j->owners[j->nowners++];
    memset(o, 0, sizeof *o);
    o->owner = owner;
    return o;
}

static int grow_leases(srv_job *j)
{
    if (j->nleases < j->leases_cap)
        return 0;
    uint32_t cap = j->leases_cap ? 2 * j->leases_cap : 64;
    lease *n = pt_realloc(j->leases, (size_t)cap * sizeof *n);
    if (!n)
        return -1;
    j->leases = n;
    j->leases_cap = cap;
    return 0;
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
 * that has no backup yet. UINT64_MAX when none (or nothing was observed). */
static uint64_t backup_pick(const srv_job *j, uint64_t owner, uint64_t now_ms)
{
    if (j->pol.backup_factor <= 0.0 || j->t_mid <= 0.0)
        return UINT64_MAX;
    uint64_t best = UINT64_MAX, best_start = UINT64_MAX;
    for (uint32_t i = 0; i < j->nleases; i++) {
        const lease *l = &j->leases[i];
        if (l->kind != L_TASK || l->answered || l->owner == owner || l->start >= best_start)
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

int srv_job_lease(srv_job *j, uint64_t owner, uint64_t now_ms, uint32_t lease_ms, proto_task *task)
{
    uint64_t t = UINT64_MAX;
    uint8_t kind = L_TASK;
    int ci = -1;
    if (grow_leases(j) != 0)
        return 0;
    while (j->rq_len > 0) {
        uint64_t c = j->requeue[j->rq_head];
        j->rq_head = (j->rq_head + 1) % j->rq_cap;
        j->rq_len--;
        if (j->state[c] == T_PENDING) {
            t = c;
            break;
        }
    }
    if (t == UINT64_MAX && (ci = verify_pick(j, owner)) >= 0) {
        t = j->checks[ci].task;
        kind = L_VERIFY;
        j->checks[ci].stage++;
    }
    if (t == UINT64_MAX) {
        while (j->cursor < j->ntasks && j->state[j->cursor] != T_PENDING)
            j->cursor++;
        if (j->cursor < j->ntasks)
            t = j->cursor++;
    }
    if (t == UINT64_MAX) {
        if ((t = backup_pick(j, owner, now_ms)) == UINT64_MAX)
            return 0;
        kind = L_BACKUP;
        j->vs.backups++;
    }
    if (kind != L_VERIFY)
        j->state[t] = T_LEASED;
    j->leases[j->nleases++] = (lease){t, owner, now_ms, now_ms + lease_ms, (uint32_t)ci, kind, 0};

    memset(task, 0, sizeof *task);
    task->job_id = j->id;
    task->task_id = t;
    task->tile = task_rect(j, t);
    task_samples(j, t, &task->s0, &task->s1);
    task->width = j->p.width;
    task->height = j->p.height;
    task->seed = j->p.seed;
    task->max_depth = (uint16_t)j->p.max_depth;
    task->rr_depth = (uint16_t)j->p.rr_depth;
    memcpy(task->scene_hash, j->hash, 32);
    task->lease_ms = lease_ms;
    snprintf(task->camera, sizeof task->camera, "%s", j->p.camera);
    task->env = j->p.env;
    task->film_flags = j->p.film_flags;
    snprintf(task->variant, sizeof task->variant, "%s", j->p.variant);
    return 1;
}

static int find_lease(const srv_job *j, uint64_t task, uint64_t owner)
{
    for (uint32_t i = 0; i < j->nleases; i++)
        if (j->leases[i].task == task && j->leases[i].owner == owner)
            return (int)i;
    return -1;
}

void srv_job_heartbeat(srv_job *j, uint64_t owner, uint64_t task_id, uint64_t now_ms,
                       uint32_t lease_ms)
{
    int i = find_lease(j, task_id, owner);
    if (i >= 0)
        j->leases[i].deadline = now_ms + lease_ms;
}

uint32_t srv_job_release_owner(srv_job *j, uint64_t owner)
{
    uint32_t n = 0;
    for (uint32_t i = 0; i < j->nleases;) {
        if (j->leases[i].owner == owner) {
            requeue_lease(j, i);
            n++;
        } else {
            i++;
        }
    }
    return n;
}

uint32_t srv_job_expire(srv_job *j, uint64_t now_ms, uint64_t *next_deadline, srv_miss_fn missed,
                        void *ctx)
{
    uint32_t n = 0;
    uint64_t next = UINT64_MAX;
    for (uint32_t i = 0; i < j->nleases;) {
        lease *l = &j->leases[i];
        uint64_t a = allowance(j, l);
        uint64_t hard = a > UINT64_MAX - l->start ? UINT64_MAX : l->start + a;
        uint64_t d = l->deadline < hard ? l->deadline : hard;
        if (d <= now_ms) {
            uint64_t owner = l->owner, task = l->task;
            /* Before the job's first result a slow start (a big scene to
             * fetch and load) cannot be told from hoarding: no miss then,
             * unless the owner stopped heartbeating. */
            int miss = l->deadline <= now_ms || j->t_high > 0.0;
            requeue_lease(j, i);
            n++;
            j->vs.expired++;
            if (missed && miss)
                missed(ctx, owner, task);
        } else {
            if (d < next)
                next = d;
            i++;
        }
    }
    if (next_deadline)
        *next_deadline = next;
    return n;
}

/* Adaptive sampling stopped a tile before chunk `from`: its later tasks are
 * done without work; leased ones lose their lease, held ones their pixels. */
static void stop_tile(srv_job *j, uint32_t tile, uint32_t from)
{
    for (uint32_t c = from; c < j->nchunks; c++) {
        uint64_t t = (uint64_t)c * j->ntiles + tile;
        if (j->state[t] == T_LEASED) {
            drop_copies(j, t);
        } else if (j->state[t] == T_HELD) {
            for (uint32_t i = 0; i < j->nheld; i++)
                if (j->held[i].task == t) {
                    pt_free(j->held[i].px);
                    j->held[i] = j->held[--j->nheld];
                    break;
                }
        }
        j->state[t] = T_SKIPPED;
        j->merged++;
        j->merged_in_pass[c]++;
    }
    j->next_chunk[tile] = j->nchunks;
    j->stopped++;
}

static void merge_now(srv_job *j, uint64_t t, const pt_pixel_acc *px)
{
    uint32_t tile = (uint32_t)(t % j->ntiles), chunk = (uint32_t)(t / j->ntiles);
    pt_rect r = task_rect(j, t);
    pt_film_add_tile(j->film, r, px);
    uint32_t npx = (r.x1 - r.x0) * (r.y1 - r.y0);
    for (uint32_t i = 0; i < npx; i++)
        j->samples += px[i].n;
    j->state[t] = T_MERGED;
    j->merged++;
    j->next_chunk[tile] = chunk + 1;
    j->merged_in_pass[chunk]++;
    pt_adaptive rule = {j->p.target_error, j->p.min_gain, j->p.min_spp};
    uint32_t tw = r.x1 - r.x0;
    if (chunk + 1 < j->nchunks &&
        pt_tile_stops(&j->film->px[(size_t)r.y0 * j->p.width + r.x0], j->p.width, px, tw, tw,
                      r.y1 - r.y0, (uint64_t)(chunk + 1) * j->p.chunk, &rule))
        stop_tile(j, tile, chunk + 1);
    while (j->passes_done < j->nchunks && j->merged_in_pass[j->passes_done] == j->ntiles)
        j->passes_done++;
}

/* Merges the held chunks of a tile that have become next in line. */
static void merge_held(srv_job *j, uint32_t tile)
{
    for (;;) {
        uint32_t c = j->next_chunk[tile];
        if (c >= j->nchunks)
            return;
        uint64_t t = (uint64_t)c * j->ntiles + tile;
        if (j->state[t] != T_HELD)
            return;
        for (uint32_t i = 0; i < j->nheld; i++) {
            if (j->held[i].task == t) {
                pt_pixel_acc *px = j->held[i].px;
                j->held[i] = j->held[--j->nheld];
                merge_now(j, t, px);
                pt_free(px);
                break;
            }
        }
        if (j->state[t] != T_MERGED)
            return; /* cannot happen: a held state always has its pixels */
    }
}

static int acc_sane(const pt_pixel_acc *a, uint32_t max_n)
{
    return isfinite(a->sum[0]) && isfinite(a->sum[1]) && isfinite(a->sum[2]) &&
           isfinite(a->sum_sq) && a->sum_sq >= 0 && a->n <= max_n && a->hits <= a->n;
}

/* Each pixel's count must be the task's samples less those rejected (a NaN
 * or Inf sample is not counted, render.h), the rejections must add up to
 * what the result reports, and the sums must be finite, non-negative and at
 * most n x SRV_MAX_SAMPLE_RADIANCE (sum_sq: the luminance squared, which is
 * at most the largest channel squared). A pixel with no samples then has
 * zero sums. */
static int pixels_plausible(const proto_result *r, uint32_t samples, pt_error *err)
{
    uint64_t missing = 0;
    for (uint32_t i = 0; i < r->npixels; i++) {
        const pt_pixel_acc *a = &r->pixels[i];
        double cap = SRV_MAX_SAMPLE_RADIANCE * a->n;
        if (a->n > samples || !(a->sum[0] >= 0.0 && a->sum[0] <= cap) ||
            !(a->sum[1] >= 0.0 && a->sum[1] <= cap) || !(a->sum[2] >= 0.0 && a->sum[2] <= cap) ||
            !(a->sum_sq >= 0.0 && a->sum_sq <= cap * SRV_MAX_SAMPLE_RADIANCE)) {
            pt_error_set(err, PT_ERR_PROTO,
                         "result for task %llu: pixel %u (%u samples of %u, sums %.3g %.3g %.3g) "
                         "is not a plausible render",
                         (unsigned long long)r->task_id, i, a->n, samples, a->sum[0], a->sum[1],
                         a->sum[2]);
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
static srv_outcome validate_result(const srv_job *j, uint64_t owner, const proto_result *r,
                                   int need_lease, int *lease_index, pt_error *err)
{
    if (r->job_id != j->id) {
        pt_error_set(err, PT_ERR_PROTO, "result for job %llu, not the running job %llu",
                     (unsigned long long)r->job_id, (unsigned long long)j->id);
        return SRV_NOT_LEASED;
    }
    if (r->task_id >= j->ntasks) {
        pt_error_set(err, PT_ERR_PROTO, "result for task %llu, which does not exist",
                     (unsigned long long)r->task_id);
        return SRV_INVALID;
    }
    uint64_t t = r->task_id;
    int li = find_lease(j, t, owner);
    int verify = li >= 0 && j->leases[li].kind == L_VERIFY;
    if (!verify && (j->state[t] == T_MERGED || j->state[t] == T_HELD || j->state[t] == T_SKIPPED))
        return SRV_DUPLICATE;
    if (li < 0 && need_lease) {
        pt_error_set(err, PT_ERR_PROTO, "result for task %llu, which this peer does not hold",
                     (unsigned long long)t);
        return SRV_NOT_LEASED;
    }
    pt_rect rc = task_rect(j, t);
    uint32_t s0, s1;
    task_samples(j, t, &s0, &s1);
    if (memcmp(&rc, &r->tile, sizeof rc) != 0 || r->s0 != s0 || r->s1 != s1 ||
        r->npixels != (rc.x1 - rc.x0) * (rc.y1 - rc.y0)) {
        pt_error_set(err, PT_ERR_PROTO,
                     "result for task %llu does not match the task's tile or samples",
                     (unsigned long long)t);
        return SRV_INVALID;
    }
    if (!pixels_plausible(r, s1 - s0, err))
        return SRV_INVALID;
    *lease_index = li;
    return verify ? SRV_CHECK : SRV_MERGED;
}

srv_outcome srv_job_validate(const srv_job *j, uint64_t owner, const proto_result *r,
                             int *lease_index, pt_error *err)
{
    return validate_result(j, owner, r, 1, lease_index, err);
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

static void add_check(srv_job *j, uint64_t t, uint64_t owner, const proto_result *r)
{
    if (j->nchecks == j->checks_cap) {
        uint32_t cap = j->checks_cap ? 2 * j->checks_cap : 32;
        check *n = pt_realloc(j->checks, (size_t)cap * sizeof *n);
        if (!n)
            return; /* this task goes unverified; nothing else is lost */
        j->checks = n;
        j->checks_cap = cap;
    }
    check *c = &j->checks[j->nchecks++];
    memset(c, 0, sizeof *c);
    c->task = t;
    c->owner[0] = owner;
    pixels_hash(r, c->hash[0]);
    c->stage = C_WANT_B;
    j->vs.picked++;
}

/* Ends check i: its leases go, the last check takes its place. */
static void free_check(srv_job *j, uint32_t i)
{
    for (uint32_t k = 0; k < j->nleases;)
        if (j->leases[k].kind == L_VERIFY && j->leases[k].check == i)
            remove_lease(j, k);
        else
            k++;
    uint32_t last = --j->nchecks;
    if (i == last)
        return;
    j->checks[i] = j->checks[last];
    for (uint32_t k = 0; k < j->nleases; k++)
        if (j->leases[k].kind == L_VERIFY && j->leases[k].check == last)
            j->leases[k].check = i;
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
static void accepted(srv_job *j, int li, const proto_result *r, uint64_t now_ms)
{
    uint64_t t = r->task_id;
    if (li < 0)
        return;
    lease l = j->leases[li];
    uint32_t copies = task_copies(j, t);
    if (copies > 1)
        j->vs.backup_samples += (uint64_t)task_work(j, t) * (copies - 1);
    drop_copies(j, t);
    if (now_ms >= l.start && now_ms > 0)
        observe(j, (double)(now_ms - l.start) / task_work(j, t));
    owner_stat *o = owner_entry(j, l.owner);
    if (o) {
        o->merged++;
        for (uint32_t i = 0; i < r->npixels; i++)
            o->samples += r->pixels[i].n;
    }
    if (verify_picked(j, t))
        add_check(j, t, l.owner, r);
}

/* Merges or holds r, which validate_result accepted; li: its lease or -1. */
static srv_outcome merge_validated(srv_job *j, int li, const proto_result *r, uint64_t now_ms,
                                   pt_error *err)
{
    uint64_t t = r->task_id;
    uint32_t tile = (uint32_t)(t % j->ntiles), chunk = (uint32_t)(t / j->ntiles);
    if (chunk == j->next_chunk[tile]) {
        accepted(j, li, r, now_ms);
        j->capped += r->capped;
        merge_now(j, t, r->pixels);
        merge_held(j, tile);
        return SRV_MERGED;
    }
    /* Early: hold a copy until the tile's earlier chunks are merged. */
    if (j->nheld == j->held_cap) {
        uint32_t cap = j->held_cap ? 2 * j->held_cap : 32;
        held *n = pt_realloc(j->held, (size_t)cap * sizeof *n);
        if (!n)
            goto nomem;
        j->held = n;
        j->held_cap = cap;
    }
    pt_pixel_acc *copy = pt_malloc_array(r->npixels, sizeof *copy);
    if (!copy)
        goto nomem;
    memcpy(copy, r->pixels, (size_t)r->npixels * sizeof *copy);
    j->held[j->nheld++] = (held){t, li >= 0 ? j->leases[li].owner : 0, copy};
    accepted(j, li, r, now_ms);
    j->capped += r->capped;
    j->state[t] = T_HELD;
    return SRV_MERGED;
nomem:
    /* Keep the lease: the task is requeued when it expires, nothing is lost. */
    pt_error_set(err, PT_ERR_NOMEM, "out of memory holding task %llu", (unsigned long long)t);
    return SRV_NOT_LEASED;
}

static srv_outcome accept_result(srv_job *j, uint64_t owner, const proto_result *r, int need_lease,
                                 pt_error *err)
{
    int li;
    srv_outcome o = validate_result(j, owner, r, need_lease, &li, err);
    if (o == SRV_CHECK) {
        srv_verdict v;
        srv_job_check(j, li, r, &v);
        return SRV_CHECK;
    }
    return o == SRV_MERGED ? merge_validated(j, li, r, 0, err) : o;
}

srv_outcome srv_job_result(srv_job *j, uint64_t owner, const proto_result *r, pt_error *err)
{
    return accept_result(j, owner, r, 1, err);
}

srv_outcome srv_job_result_validated(srv_job *j, int lease_index, const proto_result *r,
                                     uint64_t now_ms, pt_error *err)
{
    return merge_validated(j, lease_index, r, now_ms, err);
}

void srv_job_answered(srv_job *j, int lease_index)
{
    if (lease_index >= 0 && (uint32_t)lease_index < j->nleases)
        j->leases[lease_index].answered = 1;
}

srv_outcome srv_job_replay(srv_job *j, const proto_result *r, pt_error *err)
{
    return accept_result(j, 0, r, 0, err);
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
        uint64_t t = j->held[i].task;
        pt_free(j->held[i].px);
        j->held[i] = j->held[--j->nheld];
        j->state[t] = T_PENDING;
        if (requeue_push(j, t) != 0 && t < j->cursor)
            j->cursor = t;
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
    for (uint32_t i = 0; i < j->nleases; i++)
        if (j->leases[i].owner == owner)
            return 1;
    return 0;
}

uint32_t srv_job_tiles(const srv_job *j)
{
    return j->ntiles;
}

/* ---- checkpoints ---- */

#define CKPT_MAGIC 0x434a5450u /* "PTJC" */
#define CKPT_VERSION 4u
#define CKPT_OLDEST_VERSION 2u   /* no min gain: read as 0 */
#define CKPT_MIN_GAIN_VERSION 3u /* the first with the min gain */
/* The first with the environment (older: none), and the first with the film
 * flags, the depth-cap count and each pixel's camera hits; older pixels read
 * as fully covered (their jobs are never transparent, so the count is not
 * shown). One format version brought both: srv_job_params_read takes one flag. */
#define CKPT_ENV_VERSION 4u
#define CKPT_FILM_VERSION CKPT_ENV_VERSION

/* A pixel as the checkpoint stores it: RESULT's pixel layout (msg.h). */
static void put_acc(proto_writer *w, const pt_pixel_acc *a)
{
    proto_w_f64(w, a->sum[0]);
    proto_w_f64(w, a->sum[1]);
    proto_w_f64(w, a->sum[2]);
    proto_w_f64(w, a->sum_sq);
    proto_w_u32(w, a->n);
    proto_w_u32(w, a->hits);
}

static void get_acc(proto_reader *r, pt_pixel_acc *a, int has_hits)
{
    a->sum[0] = proto_r_f64(r, "pixel sum");
    a->sum[1] = proto_r_f64(r, "pixel sum");
    a->sum[2] = proto_r_f64(r, "pixel sum");
    a->sum_sq = proto_r_f64(r, "pixel sum of squares");
    a->n = proto_r_u32(r, "pixel samples");
    a->hits = has_hits ? proto_r_u32(r, "pixel camera hits") : a->n;
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
}

void srv_job_params_read(proto_reader *r, srv_job_params *p, int has_min_gain, int has_env_film)
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
}

static uint32_t tile_merged(const srv_job *j, uint32_t tile)
{
    uint32_t m = 0;
    while (m < j->nchunks && j->state[(uint64_t)m * j->ntiles + tile] == T_MERGED)
        m++;
    return m;
}

pt_status srv_job_save(const srv_job *j, proto_writer *w, pt_error *err)
{
    proto_w_u32(w, CKPT_MAGIC);
    proto_w_u32(w, CKPT_VERSION);
    proto_w_u64(w, j->id);
    proto_w_bytes(w, j->hash, 32);
    srv_job_params_write(w, &j->p);
    proto_w_u64(w, j->capped);
    proto_w_u32(w, j->ntiles);
    proto_w_u32(w, j->nchunks);
    for (uint32_t t = 0; t < j->ntiles; t++) {
        uint32_t m = tile_merged(j, t);
        proto_w_u32(w, m);
        proto_w_u8(w, m < j->nchunks && j->state[(uint64_t)m * j->ntiles + t] == T_SKIPPED);
    }
    proto_w_u32(w, j->nheld);
    for (uint32_t i = 0; i < j->nheld; i++) {
        pt_rect r = task_rect(j, j->held[i].task);
        uint32_t npx = (r.x1 - r.x0) * (r.y1 - r.y0);
        proto_w_u64(w, j->held[i].task);
        for (uint32_t k = 0; k < npx; k++)
            put_acc(w, &j->held[i].px[k]);
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
    if (j->merged || j->nleases || j->nheld)
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
    int film = version >= CKPT_FILM_VERSION;
    size_t acc_size = film ? PROTO_RESULT_PIXEL_SIZE : PROTO_RESULT_PIXEL_SIZE - 4;
    srv_job_params_read(&r, &p, version >= CKPT_MIN_GAIN_VERSION, version >= CKPT_ENV_VERSION);
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
        ntiles != j->ntiles || nchunks != j->nchunks)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "checkpoint is of another job or other settings "
                            "(job %llu, %ux%u, %u spp)",
                            (unsigned long long)id, p.width, p.height, p.spp);
    for (uint32_t t = 0; t < ntiles; t++) {
        uint32_t m = proto_r_u32(&r, "tile chunks merged");
        uint8_t stopped = proto_r_u8(&r, "tile stopped");
        if (r.status != PT_OK)
            return proto_r_finish(&r, "checkpoint", err);
        if (m > nchunks || stopped > 1 || (stopped && m == nchunks))
            return pt_error_set(err, PT_ERR_FORMAT,
                                "checkpoint: tile %u has %u chunks merged "
                                "of %u (stopped %u)",
                                t, m, nchunks, stopped);
        for (uint32_t c = 0; c < m; c++) {
            j->state[(uint64_t)c * ntiles + t] = T_MERGED;
            j->merged_in_pass[c]++;
        }
        j->merged += m;
        j->next_chunk[t] = m;
        if (stopped) {
            for (uint32_t c = m; c < nchunks; c++) {
                j->state[(uint64_t)c * ntiles + t] = T_SKIPPED;
                j->merged_in_pass[c]++;
            }
            j->merged += nchunks - m;
            j->next_chunk[t] = nchunks;
            j->stopped++;
        }
    }
    uint32_t nheld = proto_r_u32(&r, "held results");
    if (r.status == PT_OK && nheld > j->ntasks)
        return pt_error_set(err, PT_ERR_FORMAT, "checkpoint: %u held results", nheld);
    for (uint32_t i = 0; i < nheld && r.status == PT_OK; i++) {
        uint64_t t = proto_r_u64(&r, "held task");
        if (r.status != PT_OK)
            break;
        if (t >= j->ntasks || j->state[t] != T_PENDING ||
            (uint32_t)(t / j->ntiles) <= j->next_chunk[t % j->ntiles])
            return pt_error_set(err, PT_ERR_FORMAT,
                                "checkpoint: held task %llu is not one that "
                                "can be held",
                                (unsigned long long)t);
        pt_rect rc = task_rect(j, t);
        uint32_t npx = (rc.x1 - rc.x0) * (rc.y1 - rc.y0);
        if (proto_r_left(&r) < (size_t)npx * acc_size)
            return pt_error_set(err, PT_ERR_FORMAT, "checkpoint: truncated held task %llu",
                                (unsigned long long)t);
        if (j->nheld == j->held_cap) {
            uint32_t cap = j->held_cap ? 2 * j->held_cap : 32;
            held *n = pt_realloc(j->held, (size_t)cap * sizeof *n);
            if (!n)
                return pt_error_set(err, PT_ERR_NOMEM, "checkpoint: out of memory");
            j->held = n;
            j->held_cap = cap;
        }
        pt_pixel_acc *px = pt_malloc_array(npx, sizeof *px);
        if (!px)
            return pt_error_set(err, PT_ERR_NOMEM, "checkpoint: out of memory");
        for (uint32_t k = 0; k < npx; k++)
            get_acc(&r, &px[k], film);
        j->held[j->nheld++] = (held){t, 0, px};
        j->state[t] = T_HELD;
        for (uint32_t k = 0; k < npx; k++)
            if (!acc_sane(&px[k], j->p.chunk))
                return pt_error_set(err, PT_ERR_FORMAT,
                                    "checkpoint: held task %llu pixel %u "
                                    "is not finite or has too many samples",
                                    (unsigned long long)t, k);
    }
    size_t npx = (size_t)j->p.width * j->p.height;
    if (r.status == PT_OK && proto_r_left(&r) != npx * acc_size)
        return pt_error_set(err, PT_ERR_FORMAT, "checkpoint: %zu bytes of film, expected %zu",
                            proto_r_left(&r), npx * acc_size);
    for (size_t k = 0; k < npx && r.status == PT_OK; k++) {
        get_acc(&r, &j->film->px[k], film);
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
    while (j->passes_done < j->nchunks && j->merged_in_pass[j->passes_done] == j->ntiles)
        j->passes_done++;
    return PT_OK;
}

srv_job *srv_job_snapshot(const srv_job *j)
{
    /* What srv_job_save reads, and nothing else: the sizes, the task states,
     * the held results and the film. */
    srv_job *c = pt_calloc(1, sizeof *c);
    if (!c)
        return NULL;
    c->id = j->id;
    c->p = j->p;
    memcpy(c->hash, j->hash, sizeof c->hash);
    c->tiles_x = j->tiles_x;
    c->tiles_y = j->tiles_y;
    c->ntiles = j->ntiles;
    c->nchunks = j->nchunks;
    c->ntasks = j->ntasks;
    c->capped = j->capped;
    c->state = pt_malloc(j->ntasks ? j->ntasks : 1);
    c->held = pt_malloc_array(j->nheld ? j->nheld : 1, sizeof *c->held);
    if (!c->state || !c->held ||
        pt_film_new(j->film->width, j->film->height, &c->film, NULL) != PT_OK) {
        srv_job_free(c);
        return NULL;
    }
    memcpy(c->state, j->state, j->ntasks);
    memcpy(c->film->px, j->film->px,
           (size_t)j->film->width * j->film->height * sizeof *c->film->px);
    for (uint32_t i = 0; i < j->nheld; i++) {
        pt_rect r = task_rect(j, j->held[i].task);
        size_t npx = (size_t)(r.x1 - r.x0) * (r.y1 - r.y0);
        pt_pixel_acc *px = pt_malloc_array(npx, sizeof *px);
        if (!px) {
            srv_job_free(c);
            return NULL;
        }
        memcpy(px, j->held[i].px, npx * sizeof *px);
        c->held[c->nheld++] = (held){j->held[i].task, j->held[i].owner, px};
    }
    return c;
}
