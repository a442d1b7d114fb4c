#include "server/job.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/adaptive.h"

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
    return j->merged == j->ntasks;
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

int srv_job_lease(srv_job *j, uint64_t owner, uint64_t now_ms, uint32_t lease_ms, proto_task *task)
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
    snprintf(task->camera, sizeof task->camera, "%s", j->p.camera);
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
           isfinite(a->sum_sq) && a->sum_sq >= 0 && a->n <= max_n;
}

/* Checks r against the task it names; need_lease: the owner must hold it.
 * On SRV_MERGED *lease_index receives the lease (-1 when none was needed). */
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
    if (j->state[t] == T_MERGED || j->state[t] == T_HELD || j->state[t] == T_SKIPPED)
        return SRV_DUPLICATE;
    int li = find_lease(j, t, owner);
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
    for (uint32_t i = 0; i < r->npixels; i++) {
        const pt_pixel_acc *a = &r->pixels[i];
        if (!acc_sane(a, s1 - s0)) {
            pt_error_set(err, PT_ERR_PROTO,
                         "result for task %llu: pixel %u is not finite or has "
                         "%u samples of %u",
                         (unsigned long long)t, i, a->n, s1 - s0);
            return SRV_INVALID;
        }
    }
    *lease_index = li;
    return SRV_MERGED;
}

srv_outcome srv_job_validate(const srv_job *j, uint64_t owner, const proto_result *r,
                             int *lease_index, pt_error *err)
{
    return validate_result(j, owner, r, 1, lease_index, err);
}

static void drop_lease(srv_job *j, int li)
{
    if (li >= 0)
        j->leases[li] = j->leases[--j->nleases];
}

/* Merges or holds r, which validate_result accepted; li: its lease or -1. */
static srv_outcome merge_validated(srv_job *j, int li, const proto_result *r, pt_error *err)
{
    uint64_t t = r->task_id;
    uint32_t tile = (uint32_t)(t % j->ntiles), chunk = (uint32_t)(t / j->ntiles);
    if (chunk == j->next_chunk[tile]) {
        drop_lease(j, li);
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
    drop_lease(j, li);
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
    return o == SRV_MERGED ? merge_validated(j, li, r, err) : o;
}

srv_outcome srv_job_result(srv_job *j, uint64_t owner, const proto_result *r, pt_error *err)
{
    return accept_result(j, owner, r, 1, err);
}

srv_outcome srv_job_result_validated(srv_job *j, int lease_index, const proto_result *r,
                                     pt_error *err)
{
    return merge_validated(j, lease_index, r, err);
}

srv_outcome srv_job_replay(srv_job *j, const proto_result *r, pt_error *err)
{
    return accept_result(j, 0, r, 0, err);
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
#define CKPT_VERSION 3u
#define CKPT_OLDEST_VERSION 2u   /* no min gain: read as 0 */
#define CKPT_MIN_GAIN_VERSION 3u /* the first with the min gain */

static void put_acc(proto_writer *w, const pt_pixel_acc *a)
{
    proto_w_f64(w, a->sum[0]);
    proto_w_f64(w, a->sum[1]);
    proto_w_f64(w, a->sum[2]);
    proto_w_f64(w, a->sum_sq);
    proto_w_u32(w, a->n);
}

static void get_acc(proto_reader *r, pt_pixel_acc *a)
{
    a->sum[0] = proto_r_f64(r, "pixel sum");
    a->sum[1] = proto_r_f64(r, "pixel sum");
    a->sum[2] = proto_r_f64(r, "pixel sum");
    a->sum_sq = proto_r_f64(r, "pixel sum of squares");
    a->n = proto_r_u32(r, "pixel samples");
    a->pad = 0;
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
}

void srv_job_params_read(proto_reader *r, srv_job_params *p, int has_min_gain)
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
    srv_job_params_read(&r, &p, version >= CKPT_MIN_GAIN_VERSION);
    uint32_t ntiles = proto_r_u32(&r, "tiles"), nchunks = proto_r_u32(&r, "chunks");
    if (r.status != PT_OK)
        return proto_r_finish(&r, "checkpoint", err);
    if (id != j->id || memcmp(hash, j->hash, 32) != 0 || p.width != j->p.width ||
        p.height != j->p.height || p.spp != j->p.spp || p.tile != j->p.tile ||
        p.chunk != j->p.chunk || p.seed != j->p.seed || p.max_depth != j->p.max_depth ||
        p.rr_depth != j->p.rr_depth || p.min_spp != j->p.min_spp ||
        memcmp(&p.target_error, &j->p.target_error, sizeof p.target_error) != 0 ||
        memcmp(&p.min_gain, &j->p.min_gain, sizeof p.min_gain) != 0 ||
        strcmp(p.camera, j->p.camera) != 0 || ntiles != j->ntiles || nchunks != j->nchunks)
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
        if (proto_r_left(&r) < (size_t)npx * PROTO_RESULT_PIXEL_SIZE)
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
            get_acc(&r, &px[k]);
        j->held[j->nheld++] = (held){t, px};
        j->state[t] = T_HELD;
        for (uint32_t k = 0; k < npx; k++)
            if (!acc_sane(&px[k], j->p.chunk))
                return pt_error_set(err, PT_ERR_FORMAT,
                                    "checkpoint: held task %llu pixel %u "
                                    "is not finite or has too many samples",
                                    (unsigned long long)t, k);
    }
    size_t npx = (size_t)j->p.width * j->p.height;
    if (r.status == PT_OK && proto_r_left(&r) != npx * PROTO_RESULT_PIXEL_SIZE)
        return pt_error_set(err, PT_ERR_FORMAT, "checkpoint: %zu bytes of film, expected %zu",
                            proto_r_left(&r), npx * PROTO_RESULT_PIXEL_SIZE);
    for (size_t k = 0; k < npx && r.status == PT_OK; k++) {
        get_acc(&r, &j->film->px[k]);
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
    while (j->passes_done < j->nchunks && j->merged_in_pass[j->passes_done] == j->ntiles)
        j->passes_done++;
    return PT_OK;
}
