#include "server/job.h"

#include <math.h>
#include <string.h>

#include "common/alloc.h"

enum { T_PENDING = 0, T_LEASED = 1, T_HELD = 2, T_MERGED = 3, T_SKIPPED = 4 };

typedef struct lease {
    uint64_t task, owner, deadline;
} lease;

typedef struct held {
    uint64_t task;
    pt_pixel_acc *px;
} held;

struct srv_job {
    uint64_t id;
    srv_job_params p;
    uint8_t hash[32];
    uint32_t tiles_x, tiles_y, ntiles, nchunks;
    uint64_t ntasks;
    uint8_t *state;        /* T_* per task */
    uint32_t *next_chunk;  /* per tile: the chunk to merge next */
    uint32_t *merged_in_pass; /* per chunk: tiles merged */
    uint32_t passes_done;
    uint64_t cursor;       /* every id below it has been handed out at least once */
    uint64_t *requeue;     /* FIFO ring of task ids */
    uint64_t rq_head, rq_len, rq_cap;
    lease *leases;
    uint32_t nleases, leases_cap;
    held *held;
    uint32_t nheld, held_cap;
    uint64_t merged, samples;
    uint32_t stopped;
    pt_film *film;
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

pt_status srv_job_new(uint64_t id, const srv_job_params *p, const uint8_t scene_hash[32],
                      srv_job **out, pt_error *err)
{
    if (!p->width || !p->height || !p->spp || !p->tile || !p->chunk || p->width > 65536 ||
        p->height > 65536 || (uint64_t)p->tile * p->tile > PROTO_MAX_TILE_PIXELS ||
        !(p->target_error >= 0.0) || !isfinite(p->target_error))
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
    j->ntiles = j->tiles_x * j->tiles_y;
    j->nchunks = (p->spp + p->chunk - 1) / p->chunk;
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
    pt_free(j->leases);
    pt_free(j->requeue);
    pt_free(j->state);
    pt_free(j->next_chunk);
    pt_free(j->merged_in_pass);
    pt_film_free(j->film);
    pt_free(j);
}

uint64_t srv_job_id(const srv_job *j) { return j->id; }
const srv_job_params *srv_job_params_of(const srv_job *j) { return &j->p; }
uint32_t srv_job_passes(const srv_job *j) { return j->nchunks; }
uint32_t srv_job_passes_done(const srv_job *j) { return j->passes_done; }
uint64_t srv_job_tasks_total(const srv_job *j) { return j->ntasks; }
uint64_t srv_job_tasks_merged(const srv_job *j) { return j->merged; }
uint64_t srv_job_samples_merged(const srv_job *j) { return j->samples; }
uint32_t srv_job_leases(const srv_job *j) { return j->nleases; }
uint32_t srv_job_tiles_stopped(const srv_job *j) { return j->stopped; }
int srv_job_complete(const srv_job *j) { return j->merged == j->ntasks; }
const pt_film *srv_job_film(const srv_job *j) { return j->film; }

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

/* Drops lease i and makes its task pending again. If the requeue list cannot
 * grow, the cursor is moved back instead, which also finds the task again. */
static void requeue_lease(srv_job *j, uint32_t i)
{
    uint64_t t = j->leases[i].task;
    j->leases[i] = j->leases[--j->nleases];
    if (j->state[t] != T_LEASED)
        return;
    j->state[t] = T_PENDING;
    if (requeue_push(j, t) != 0 && t < j->cursor)
        j->cursor = t;
}

int srv_job_lease(srv_job *j, uint64_t owner, uint64_t now_ms, uint32_t lease_ms,
                  proto_task *task)
{
    uint64_t t = UINT64_MAX;
    while (j->rq_len > 0) {
        uint64_t c = j->requeue[j->rq_head];
        j->rq_head = (j->rq_head + 1) % j->rq_cap;
        j->rq_len--;
        if (j->state[c] == T_PENDING) {
            t = c;
            break;
        }
    }
    if (t == UINT64_MAX) {
        while (j->cursor < j->ntasks && j->state[j->cursor] != T_PENDING)
            j->cursor++;
        if (j->cursor == j->ntasks)
            return 0;
        t = j->cursor++;
    }
    if (j->nleases == j->leases_cap) {
        uint32_t cap = j->leases_cap ? 2 * j->leases_cap : 64;
        lease *n = pt_realloc(j->leases, (size_t)cap * sizeof *n);
        if (!n) {
            j->state[t] = T_PENDING;
            if (requeue_push(j, t) != 0 && t < j->cursor)
                j->cursor = t;
            return 0;
        }
        j->leases = n;
        j->leases_cap = cap;
    }
    j->state[t] = T_LEASED;
    j->leases[j->nleases++] = (lease){t, owner, now_ms + lease_ms};

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

uint32_t srv_job_expire(srv_job *j, uint64_t now_ms, uint64_t *next_deadline)
{
    uint32_t n = 0;
    uint64_t next = UINT64_MAX;
    for (uint32_t i = 0; i < j->nleases;) {
        if (j->leases[i].deadline <= now_ms) {
            requeue_lease(j, i);
            n++;
        } else {
            if (j->leases[i].deadline < next)
                next = j->leases[i].deadline;
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
            for (uint32_t i = 0; i < j->nleases; i++)
                if (j->leases[i].task == t) {
                    j->leases[i] = j->leases[--j->nleases];
                    break;
                }
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
    if (j->p.target_error > 0.0 && chunk + 1 < j->nchunks &&
        (uint64_t)(chunk + 1) * j->p.chunk >= j->p.min_spp) {
        const pt_pixel_acc *fp = &j->film->px[(size_t)r.y0 * j->p.width + r.x0];
        if (pt_tile_rel_error(fp, j->p.width, r.x1 - r.x0, r.y1 - r.y0) <= j->p.target_error)
            stop_tile(j, tile, chunk + 1);
    }
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

srv_outcome srv_job_result(srv_job *j, uint64_t owner, const proto_result *r, pt_error *err)
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
    if (j->state[t] == T_MERGED || j->state[t] == T_HELD || j->state[t] == T_SKIPPED)
        return SRV_DUPLICATE;
    int li = find_lease(j, t, owner);
    if (li < 0) {
        pt_error_set(err, PT_ERR_PROTO, "result for task %llu, which this peer does not hold",
                     (unsigned long long)t);
        return SRV_NOT_LEASED;
    }
    pt_rect rc = task_rect(j, t);
    uint32_t s0, s1;
    task_samples(j, t, &s0, &s1);
    if (memcmp(&rc, &r->tile, sizeof rc) != 0 || r->s0 != s0 || r->s1 != s1 ||
        r->npixels != (rc.x1 - rc.x0) * (rc.y1 - rc.y0)) {
        pt_error_set(err, PT_ERR_PROTO, "result for task %llu does not match the task's tile or samples",
                     (unsigned long long)t);
        return SRV_INVALID;
    }
    for (uint32_t i = 0; i < r->npixels; i++) {
        const pt_pixel_acc *a = &r->pixels[i];
        if (!isfinite(a->sum[0]) || !isfinite(a->sum[1]) || !isfinite(a->sum[2]) ||
            !isfinite(a->sum_sq) || a->sum_sq < 0 || a->n > s1 - s0) {
            pt_error_set(err, PT_ERR_PROTO, "result for task %llu: pixel %u is not finite or has "
                         "%u samples of %u", (unsigned long long)t, i, a->n, s1 - s0);
            return SRV_INVALID;
        }
    }
    uint32_t tile = (uint32_t)(t % j->ntiles), chunk = (uint32_t)(t / j->ntiles);
    if (chunk == j->next_chunk[tile]) {
        j->leases[li] = j->leases[--j->nleases];
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
    j->held[j->nheld++] = (held){t, copy};
    j->leases[li] = j->leases[--j->nleases];
    j->state[t] = T_HELD;
    return SRV_MERGED;
nomem:
    /* Keep the lease: the task is requeued when it expires, nothing is lost. */
    pt_error_set(err, PT_ERR_NOMEM, "out of memory holding task %llu", (unsigned long long)t);
    return SRV_NOT_LEASED;
}
