/*
 * job.h - one render job on the coordinator: tasks, leases, the merge.
 *
 * The image is cut into tiles (tile x tile pixels). A task is samples
 * [s0, s1) of one tile; its id is its index in the job's task table (ids are
 * given in the order tasks are cut, from 0). Tasks are cut from a tile's
 * uncut samples when an owner asks, always from the tile with the fewest
 * samples cut so far (ties: the lowest tile), so the progressive image
 * improves evenly. How many samples (srv_lease_policy.task_ms):
 *   - 0: fixed chunks: up to the next multiple of chunk (pass by pass, ids
 *     chunk x tiles + tile as before this scheme);
 *   - else time-sized: samples for about task_ms at the asking owner's speed
 *     (its moving average of ms per pixel-sample from lease to result, or the
 *     job's median before it has one; one block before anything is known),
 *     as a multiple of PT_SAMPLE_BLOCK, but never more than the tile already
 *     has cut past the first block times GROWTH - 1 (job.c): the first pass
 *     is 16 samples, each later one takes a tile to at most 8 times its
 *     samples (16, 128, 1024), so the first image comes as soon as with
 *     fixed chunks of 16 and a long job is few results per tile. Near the end, when the uncut work
 * is less than the farm (the sum of its live leases' speeds) renders in TAIL_SHARE (2) task times,
 * a task takes at most half the time the farm needs for that rest, so the last tasks end
 * close together. A task keeps its range: an expired lease's task goes back whole to the requeue
 * list, served first. Tile results merge in sample order (early ones held), so with exact sums the
 * image is the same however it was cut.
 *
 * Tasks are leased to an owner (a connection). A lease has two deadlines: a
 * heartbeat deadline (lease_ms after it was handed out or last heartbeat),
 * which says the owner is alive, and a hard deadline that heartbeats do not
 * move: start + max(floor, factor x the job's observed time per pixel-sample
 * (a high quantile of its recent results) x the task's pixel-samples), or
 * start + first_ms while no result of the job has been seen (see
 * srv_lease_policy). An expired lease or a lost owner puts the task back in a
 * requeue list that is served first. When nothing is left to hand out, an
 * idle owner gets a backup copy of the oldest straggler (a lease older than
 * backup_factor x the median for its size): the first result wins and the
 * other copy's lease is dropped. A result is accepted only from the owner of
 * a live lease for exactly that task (tile, sample range, pixel count, and
 * plausible pixels: non-negative sums under PT_MAX_SAMPLE_RADIANCE (tile.h)
 * per sample, each pixel's count the task's samples less the samples the
 * result reports rejected), so merging is idempotent: a duplicate or late
 * result changes nothing.
 *
 * Verification: a merged result is, with probability verify_fraction (a hash
 * of the task id and a per-run seed, so the pick is deterministic and unknown
 * to workers), leased again to another owner as a verification copy, whose
 * result is compared bit for bit (SHA-256 of the pixels) with the first and
 * never merged. On a mismatch a third owner renders it; the one of the first
 * two that differs from the third is the liar (srv_job_check).
 *
 * A tile's tasks are added to the film in sample order (early arrivals are
 * held), so the final pixels are bit-identical however many workers rendered
 * them and in whatever order results arrived.
 *
 * Adaptive sampling: decisions are taken only at decision points, the
 * multiples of chunk from min_spp on (short of spp), whatever the task
 * sizes: a task never crosses one, and one that ends at one is exactly the
 * chunk before it. When that task is merged, pt_tile_stops decides from the
 * film's sums and that chunk's whether the tile stops (pt_tile_rel_error at
 * most target_error, or pt_tile_gain at most min_gain): its later tasks are
 * then skipped (dropped if already leased or held) and nothing more of it is
 * cut. The decision depends only on the tile's sums after the point and on
 * the chunk before it, which do not depend on how the work was split, so
 * adaptive images are bit-identical across worker counts, task sizes and a
 * resumed job too. Time-sized tasks of an adaptive job are therefore at most
 * one chunk from the chunk before the first decision point on (and fixed
 * chunks when chunk is not a multiple of PT_SAMPLE_BLOCK).
 *
 * Lookups: a task id indexes the task table; a task lists its live leases
 * (a few copies) and an owner its own (pool slots), owners are hashed, so a
 * result, a heartbeat (per task id it names) or a lost owner costs no scan
 * of the job's leases. srv_job_expire and a backup pick (only once nothing
 * else is left) look at every live lease.
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
#include "server/params.h"
#include "server/sched/adder.h"
#include "server/store/state.h"

/* Tasks of one job: a job whose fixed chunks would pass this is refused;
 * time-sized tasks are at least one block, or as many more (a power of two)
 * as keeps a job's smallest tasks under half of it, so their table never
 * fills (requeues keep their task; only a restart's gaps add a few). */
#define SRV_MAX_TASKS (64u * 1024u * 1024u)

/* The default task time (ptserve --task-time). A result costs the event
 * loop about 11 us + 3 ns per byte, and carries 40 bytes per pixel whatever
 * its samples: ~135 us for a 32 x 32 tile, so one loop core takes ~7,400
 * results/s. One core renders ~1.35 M samples/s on the Cornell box, so at
 * 2 s a task is ~2.7 M pixel-samples (a 32 x 32 tile's 2,600 samples: jobs
 * under that spp get tasks of a whole pass) and 10,000 cores send 5,000
 * results/s, two thirds of a loop core; shorter tasks would not feed 10,000
 * cores, longer ones only lengthen the tail and the loss of a lease. */
#define SRV_DEFAULT_TASK_MS 2000u

typedef enum srv_outcome {
    SRV_MERGED = 0, /* accepted (merged now or held until its turn) */
    SRV_DUPLICATE,  /* already accepted: dropped, harmless */
    SRV_NOT_LEASED, /* no live lease of this owner for the task: dropped */
    SRV_INVALID,    /* malformed or inconsistent with the task: the peer is at fault */
    SRV_CHECK       /* the answer to a verification copy: srv_job_check, never merged */
} srv_outcome;

typedef struct srv_job srv_job;

/* How leases end and which tasks are rendered twice. All zero (a new job's):
 * no hard deadline, no backups, no verification. */
typedef struct srv_lease_policy {
    uint32_t floor_ms;      /* no hard deadline sooner than this after the start; 0: none */
    uint32_t first_ms;      /* the allowance while no result of the job was observed */
    double factor;          /* hard deadline: factor x the observed quantile x the task's size */
    double backup_factor;   /* backup copy of a lease older than this x the median; 0: none */
    double verify_fraction; /* [0, 1]: the share of merged tasks rendered again */
    uint64_t verify_seed;   /* picks them with the task id */
    uint32_t task_ms;       /* time-sized tasks of about this long; 0: fixed chunks */
    /* Test hook (PTSERVE_TEST_LEASE_GATE, server/sched/queue.c): while the
     * file hold_gate does not exist, no task starting at hold_spp samples or
     * later is cut, so the job waits there, mid-render, until a test opens
     * the gate. hold_spp 0 (production): none. */
    uint32_t hold_spp;
    const char *hold_gate; /* not copied: the environment's string */
} srv_lease_policy;

#define SRV_DEADLINE_QUANTILE 0.9 /* of the observed times per pixel-sample */

/* Whether item (a task id, a denoise region's index) of job is picked for
 * verification: splitmix64 (Steele et al. 2014) of the seed, job and item as
 * a uniform number in [0, 1), under fraction; never when fraction is not
 * above 0. Deterministic, so the coordinator alone knows the pick. Pure. */
static inline int srv_verify_picked(uint64_t seed, uint64_t job, uint64_t item, double fraction)
{
    if (!(fraction > 0.0))
        return 0;
    uint64_t z = seed ^ (job * 0xD1B54A32D192ED03ull) ^ item;
    z += 0x9E3779B97F4A7C15ull;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    z ^= z >> 31;
    return (double)(z >> 11) * 0x1.0p-53 < fraction;
}

/* What a verification copy's result said (srv_job_check). */
typedef enum srv_verdict_kind {
    SRV_V_MATCH = 0, /* same bits as the first result: both verified */
    SRV_V_MISMATCH,  /* differs: a third copy is leased to decide */
    SRV_V_LIAR,      /* the third agreed with one: liar differs, honest agrees */
    SRV_V_UNRESOLVED /* three different results: nobody can be told apart */
} srv_verdict_kind;

typedef struct srv_verdict {
    srv_verdict_kind kind;
    uint64_t task, liar, honest;
} srv_verdict;

/* Verification's cost and findings so far. */
typedef struct srv_verify_stats {
    uint64_t picked; /* merged tasks picked for a verification copy */
    uint64_t matched, mismatched, liars;
    uint64_t samples;        /* pixel-samples rendered for verification copies */
    uint64_t backups;        /* backup copies handed out */
    uint64_t backup_samples; /* pixel-samples of backup copies that lost */
    uint64_t expired;        /* leases that passed a deadline */
    uint64_t refused;        /* results refused as invalid (srv_job_refused) */
} srv_verify_stats;

/* Callback of srv_job_expire for each lease that passed a deadline. */
typedef void (*srv_miss_fn)(void *ctx, uint64_t owner, uint64_t task);

/* scene_hash: 32 raw bytes. PT_ERR_ARG for sizes that make no sense,
 * PT_ERR_LIMIT when its fixed chunks would pass SRV_MAX_TASKS. */
pt_status srv_job_new(uint64_t id, const srv_job_params *p, const uint8_t scene_hash[32],
                      srv_job **out, pt_error *err);
void srv_job_free(srv_job *job); /* accepts NULL; settles first */

/* The bytes of a width x height film with film_flags' passes on the
 * coordinator: every pixel's exact sums, and its pass sums when it has any
 * (72 and 408 bytes). */
uint64_t srv_film_bytes(uint32_t width, uint32_t height, uint32_t film_flags);

/* Film adds through a (server/sched/adder.h; NULL: made at once, the default):
 * a merged task's add is posted when the job may free its pixels (a result
 * that owns them, a held one) and the task ends at no adaptive decision
 * point (that decision reads the tile's sums). The film's pixels are then
 * behind the merge until settled: srv_job_film, srv_job_save,
 * srv_job_snapshot, srv_job_free and the decisions settle first, and so must
 * any other reader. The sample counts (srv_job_samples_merged) never lag.
 * a must outlive the job. */
void srv_job_set_adder(srv_job *job, srv_adder *a);
/* Waits until every add of the job's merged tasks is in its film. */
void srv_job_settle(const srv_job *job);

uint64_t srv_job_id(const srv_job *job);
const srv_job_params *srv_job_params_of(const srv_job *job);

/* Sets the deadline, backup and verification policy (any time; deadlines of
 * live leases follow the new one). */
void srv_job_set_policy(srv_job *job, const srv_lease_policy *pol);

/* Leases the next task to owner (heartbeat deadline now_ms + lease_ms) and
 * describes it in *task: a requeued task first, then a verification copy
 * owner may render (not of its own result), then a new task cut for owner
 * (see the file comment), then a backup copy of a straggler. Returns 0 when
 * nothing is left for owner. */
int srv_job_lease(srv_job *job, uint64_t owner, uint64_t now_ms, uint32_t lease_ms,
                  proto_task *task);

/* Moves owner's heartbeat deadline for task_id (ignored when it holds none);
 * never its hard deadline. */
void srv_job_heartbeat(srv_job *job, uint64_t owner, uint64_t task_id, uint64_t now_ms,
                       uint32_t lease_ms);

/* Requeues every task leased to owner (it disconnected). Returns how many. */
uint32_t srv_job_release_owner(srv_job *job, uint64_t owner);

/* Requeues leases whose heartbeat or hard deadline passed (a verification
 * copy's goes back to its check), calling missed (may be NULL) for each that
 * missed its heartbeat deadline or a hard deadline derived from observed
 * times (not the allowance before the job's first result).
 * Returns how many; *next_deadline (may be NULL) receives the earliest
 * remaining deadline or UINT64_MAX. */
uint32_t srv_job_expire(srv_job *job, uint64_t now_ms, uint64_t *next_deadline, srv_miss_fn missed,
                        void *ctx);

/* Judges the answer to a verification copy that srv_job_validate called
 * SRV_CHECK (lease_index: what it gave), the job unchanged since; drops that
 * lease and fills *v. */
void srv_job_check(srv_job *job, int lease_index, const proto_result *r, srv_verdict *v);

/* A worker found lying or blocked: drops every lease of owner (requeued),
 * its held results (their tasks are pending again: never merged) and the
 * checks of its results or that wait on it. *merged / *samples (may be NULL)
 * receive how many of its results were merged and not verified, and their
 * pixel-samples: those stay in the film. */
void srv_job_forget_owner(srv_job *job, uint64_t owner, uint64_t *merged, uint64_t *samples);

/* Verification's cost and findings so far. */
srv_verify_stats srv_job_verify_stats(const srv_job *job);

/* Counts a result the caller refused (SRV_INVALID) in the stats. */
void srv_job_refused(srv_job *job);

/* Accepts a result (see the file comment); err explains SRV_INVALID. The
 * answer to a verification copy is judged (srv_job_check) and SRV_CHECK
 * returned; the verdict is not passed on (tests). */
srv_outcome srv_job_result(srv_job *job, uint64_t owner, const proto_result *r, pt_error *err);

/* Result validation: judges a result as srv_job_result would, changing
 * nothing: SRV_MERGED when it would be accepted, with *lease_index the lease it
 * answers (an index valid while the job is unchanged); SRV_CHECK, likewise,
 * for a valid answer to a verification copy (for srv_job_check). Lets the
 * caller log it durably before merging. */
srv_outcome srv_job_validate(const srv_job *job, uint64_t owner, const proto_result *r,
                             int *lease_index, pt_error *err);
/* The same for a result whose pixels srv_job_pixels_plausible accepted:
 * the pixel check, the costliest part, is not made again. */
srv_outcome srv_job_validate_checked(const srv_job *job, uint64_t owner, const proto_result *r,
                                     int *lease_index, pt_error *err);
/* The pixel check of validation (see above: counts, rejections, sums) for
 * r's own sample range; pure, so any thread may make it. 1 when plausible;
 * err says why not. */
int srv_job_pixels_plausible(const proto_result *r, pt_error *err);

/* srv_job_result for a result that srv_job_validate accepted (lease_index: what
 * it gave), the job unchanged since: merges or holds it without looking up its
 * lease or validating its task and pixels again. now_ms: when it arrived, so
 * that the task's time is learnt for the deadlines (0: learn nothing). When r
 * owns its pixels (r->owns_pixels) the job may take them: r->pixels is then
 * NULL and r->owns_pixels 0. */
srv_outcome srv_job_result_validated(srv_job *job, int lease_index, proto_result *r,
                                     uint64_t now_ms, pt_error *err);

/* Marks the lease a result srv_job_validate accepted answers (lease_index:
 * what it gave, the job unchanged since) while that result waits to be
 * merged (its log record is being made durable): no backup copy of it is
 * handed out meanwhile. Nothing else changes; deadlines still apply.
 * Returns a ticket for srv_job_ticket_lease (0 when lease_index names no
 * live lease). */
uint64_t srv_job_answered(srv_job *job, int lease_index);

/* The lease a ticket of srv_job_answered names, while it is still that live
 * lease: what srv_job_validate_checked would give again for the same
 * result and owner, without judging it again (O(1)). -1 once the lease has
 * gone (expired, released, dropped because its task was merged or its tile
 * stopped) or for ticket 0: the result must then be judged anew. */
int srv_job_ticket_lease(const srv_job *job, uint64_t ticket);

/* Accepts a result from the durable log after a restart: like srv_job_result
 * but without a lease, found by its tile and samples rather than its id (ids
 * are per run): the task cut so, else cut to fit from a pending task or the
 * tile's uncut samples (what it leaves pending is requeued); SRV_INVALID
 * when the range overlaps tasks cut otherwise. Duplicates are dropped, so a
 * log that overlaps the checkpoint is harmless. Takes r's pixels as
 * srv_job_result_validated may. */
srv_outcome srv_job_replay(srv_job *job, proto_result *r, pt_error *err);

/* 1 when owner holds a lease of this job. */
int srv_job_owner_active(const srv_job *job, uint64_t owner);

/* Checkpoints (format 6). srv_job_save appends the merged state (per tile
 * the samples merged and whether adaptive sampling stopped it, the held early
 * results with their tile and samples, the film's fixed-point sums and counts)
 * to w; formats 2 to 5 (chunks merged per tile, held task ids of fixed
 * chunks; double sums before 5) are read too; leases are not saved (their tasks are
 * pending again after a load). srv_job_load restores that state into a fresh
 * job made with the same id, params and scene hash: PT_ERR_FORMAT naming what
 * does not fit when the bytes are of another job or inconsistent. The result
 * merges bit-identically to the job that was saved. */
pt_status srv_job_save(const srv_job *job, proto_writer *w, pt_error *err);
/* A copy of what srv_job_save reads (a checkpoint written off the loop from
 * it, while the job goes on); not a job to lease from. NULL when out of
 * memory. Free with srv_job_free. */
srv_job *srv_job_snapshot(const srv_job *job);
pt_status srv_job_load(srv_job *job, const uint8_t *data, size_t len, pt_error *err);
/* The job as the state folder checkpoints and replays it (srv_job_id,
 * srv_job_save, srv_job_load, srv_job_replay and srv_job_free): what the
 * folder is handed at srv_state_open (server/store/state.h). */
extern const srv_job_codec srv_job_state_codec;

/* Tiles and passes (chunks per tile) of a job with params p, before or
 * without a srv_job: what srv_job_tiles and srv_job_passes of one would say. */
uint32_t srv_job_params_tiles(const srv_job_params *p);
uint32_t srv_job_params_passes(const srv_job_params *p);

/* Progress. */
uint32_t srv_job_tiles(const srv_job *job);
/* Passes count chunks whatever the task sizes: pass k is done when every
 * tile has min((k + 1) x chunk, spp) samples merged (or stopped). */
uint32_t srv_job_passes(const srv_job *job);      /* ceil(spp / chunk) */
uint32_t srv_job_passes_done(const srv_job *job); /* passes merged for every tile */
/* Tasks merged (or skipped), cut and open, and those fixed chunks would cut
 * of the samples not cut yet (time-sized tasks may be fewer): equal to
 * srv_job_tasks_merged once every tile is done. O(tiles). */
uint64_t srv_job_tasks_total(const srv_job *job);
uint64_t srv_job_tasks_merged(const srv_job *job);
uint64_t srv_job_samples_merged(const srv_job *job);
/* Paths that the results accepted so far report ended by the depth cap. */
uint64_t srv_job_paths_capped(const srv_job *job);
/* Contributions that the results accepted so far report clamped (--clamp-*). */
uint64_t srv_job_clamped(const srv_job *job);
uint32_t srv_job_tiles_stopped(const srv_job *job); /* tiles adaptive sampling stopped early */
uint32_t srv_job_leases(const srv_job *job);
/* 1 when every tile has all its samples merged (or stopped) and no verification mismatch
 * waits for its third render; checks that have not found a mismatch are
 * dropped with the job. */
int srv_job_complete(const srv_job *job);
/* The job's film, settled (srv_job_set_adder). */
const pt_film *srv_job_film(const srv_job *job);

/* The guiding distribution j holds under hash (a guided job's, job_guide.c)
 * as GUIDE_CHUNK carries it: its bytes packed (proto_guide_pack; hash is
 * the SHA-256 of the unpacked bytes), borrowed until j's next merge or
 * free; 0 when it holds none. */
int srv_job_guide_bytes(const srv_job *j, const uint8_t hash[32], const uint8_t **data,
                        size_t *len);
/* A guided job's pass being learned (its tasks are leased), 0 when not guided. */
uint32_t srv_job_guide_pass(const srv_job *j);

#endif
