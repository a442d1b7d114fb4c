/*
 * job.h - one render job on the coordinator: tasks, leases, the merge.
 *
 * The image is cut into tiles (tile x tile pixels) and the samples into chunks
 * (chunk samples each). A task is (tile, chunk); its id is chunk * ntiles +
 * tile, so handing out ids in increasing order hands out pass 0 (chunk 0 of
 * every tile), then pass 1, and the progressive image improves evenly.
 *
 * Tasks are leased to an owner (a connection) until a deadline that
 * heartbeats extend; an expired lease or a lost owner puts the task back in a
 * requeue list that is served first. A result is accepted only from the owner
 * of a live lease for exactly that task (tile, sample range, pixel count,
 * finite sums, n <= samples), so merging is idempotent: a duplicate or late
 * result changes nothing.
 *
 * Chunks of a tile are added to the film in chunk order (early arrivals are
 * held), in double, so the final pixels are bit-identical however many
 * workers rendered them and in whatever order results arrived.
 *
 * Adaptive sampling: when a tile's chunk c is merged and the tile has at least
 * min_spp samples, pt_tile_stops decides from the film's sums and chunk c's
 * whether it stops (pt_tile_rel_error at most target_error, or pt_tile_gain
 * at most min_gain): its later chunks are then skipped (dropped if already
 * leased or held). The decision depends only on the tile's sums after chunk c
 * and on chunk c, which do not depend on how the work was split, so adaptive
 * images are bit-identical across worker counts and a resumed job too.
 * Pure code: no sockets, no clock (callers pass now_ms). Threads: a job is
 * used by one thread at a time (the event loop's); the params functions below
 * are pure and may be called from any thread.
 */
#ifndef PT_SERVER_JOB_H
#define PT_SERVER_JOB_H

#include <stdint.h>

#include "common/base/error.h"
#include "common/render/film.h"
#include "common/render/render.h"
#include "protocol/msg.h"

typedef struct srv_job_params {
    uint32_t width, height;
    uint32_t spp;
    uint32_t tile, chunk;
    uint32_t seed;
    uint32_t max_depth, rr_depth;
    double target_error;             /* adaptive sampling: 0 = off, else pt_tile_rel_error target */
    uint32_t min_spp;                /* adaptive sampling: no tile stops before this many samples */
    double min_gain;                 /* adaptive sampling: 0 = off, else pt_tile_gain threshold */
    char camera[PROTO_MAX_NAME + 1]; /* the camera's name; "" the scene's default view */
} srv_job_params;

#define SRV_MAX_TASKS (64u * 1024u * 1024u)

typedef enum srv_outcome {
    SRV_MERGED = 0, /* accepted (merged now or held until its turn) */
    SRV_DUPLICATE,  /* already accepted: dropped, harmless */
    SRV_NOT_LEASED, /* no live lease of this owner for the task: dropped */
    SRV_INVALID     /* malformed or inconsistent with the task: the peer is at fault */
} srv_outcome;

typedef struct srv_job srv_job;

/* scene_hash: 32 raw bytes. PT_ERR_ARG for sizes that make no sense,
 * PT_ERR_LIMIT over SRV_MAX_TASKS. */
pt_status srv_job_new(uint64_t id, const srv_job_params *p, const uint8_t scene_hash[32],
                      srv_job **out, pt_error *err);
void srv_job_free(srv_job *job); /* accepts NULL */

uint64_t srv_job_id(const srv_job *job);
const srv_job_params *srv_job_params_of(const srv_job *job);

/* Leases the next task to owner until now_ms + lease_ms and describes it in
 * *task. Returns 0 when nothing is left to hand out right now. */
int srv_job_lease(srv_job *job, uint64_t owner, uint64_t now_ms, uint32_t lease_ms,
                  proto_task *task);

/* Extends owner's lease of task_id (ignored when it holds none). */
void srv_job_heartbeat(srv_job *job, uint64_t owner, uint64_t task_id, uint64_t now_ms,
                       uint32_t lease_ms);

/* Requeues every task leased to owner (it disconnected). Returns how many. */
uint32_t srv_job_release_owner(srv_job *job, uint64_t owner);

/* Requeues leases whose deadline passed. Returns how many; *next_deadline
 * (may be NULL) receives the earliest remaining deadline or UINT64_MAX. */
uint32_t srv_job_expire(srv_job *job, uint64_t now_ms, uint64_t *next_deadline);

/* Accepts a result (see the file comment); err explains SRV_INVALID. */
srv_outcome srv_job_result(srv_job *job, uint64_t owner, const proto_result *r, pt_error *err);

/* Result validation: judges a result as srv_job_result would, changing
 * nothing: SRV_MERGED when it would be accepted, with *lease_index the lease it
 * answers (an index valid while the job is unchanged). Lets the caller log it
 * durably before merging. */
srv_outcome srv_job_validate(const srv_job *job, uint64_t owner, const proto_result *r,
                             int *lease_index, pt_error *err);

/* srv_job_result for a result that srv_job_validate accepted (lease_index: what
 * it gave), the job unchanged since: merges or holds it without looking up its
 * lease or validating its task and pixels again. */
srv_outcome srv_job_result_validated(srv_job *job, int lease_index, const proto_result *r,
                                     pt_error *err);

/* Accepts a result from the durable log after a restart: like srv_job_result
 * but without a lease (there are none yet). Duplicates are dropped, so a log
 * that overlaps the checkpoint is harmless. */
srv_outcome srv_job_replay(srv_job *job, const proto_result *r, pt_error *err);

/* 1 when owner holds a lease of this job. */
int srv_job_owner_active(const srv_job *job, uint64_t owner);

/* The params block as the checkpoint and the state folder's queue file both
 * store it: nine u32 (width, height, spp, tile, chunk, seed, max depth, rr
 * depth, min spp), f64 target error, f64 min gain (in the formats that have
 * it; read as 0 from older ones), str camera. srv_job_params_read reads a
 * block with or without the min gain, as its file's format version says; a
 * failure is left in r's status. */
void srv_job_params_write(proto_writer *w, const srv_job_params *p);
void srv_job_params_read(proto_reader *r, srv_job_params *p, int has_min_gain);

/* Checkpoints. srv_job_save appends the merged state (per tile the chunks
 * merged and whether adaptive sampling stopped it, the held early results, the
 * film's double sums and counts) to w; leases are not saved (their tasks are
 * pending again after a load). srv_job_load restores that state into a fresh
 * job made with the same id, params and scene hash: PT_ERR_FORMAT naming what
 * does not fit when the bytes are of another job or inconsistent. The result
 * merges bit-identically to the job that was saved. */
pt_status srv_job_save(const srv_job *job, proto_writer *w, pt_error *err);
pt_status srv_job_load(srv_job *job, const uint8_t *data, size_t len, pt_error *err);

/* Tiles and passes (chunks per tile) of a job with params p, before or
 * without a srv_job: what srv_job_tiles and srv_job_passes of one would say. */
uint32_t srv_job_params_tiles(const srv_job_params *p);
uint32_t srv_job_params_passes(const srv_job_params *p);

/* Progress. */
uint32_t srv_job_tiles(const srv_job *job);
uint32_t srv_job_passes(const srv_job *job);      /* chunks per tile */
uint32_t srv_job_passes_done(const srv_job *job); /* passes merged for every tile */
uint64_t srv_job_tasks_total(const srv_job *job);
uint64_t srv_job_tasks_merged(const srv_job *job);
uint64_t srv_job_samples_merged(const srv_job *job);
uint32_t srv_job_tiles_stopped(const srv_job *job); /* tiles adaptive sampling stopped early */
uint32_t srv_job_leases(const srv_job *job);
int srv_job_complete(const srv_job *job);
const pt_film *srv_job_film(const srv_job *job);

#endif
