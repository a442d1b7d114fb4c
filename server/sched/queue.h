/*
 * queue.h - the jobs a coordinator serves, in order, and their scheduling.
 *
 * Owns every srv_entry: a job as the coordinator serves it (its durable
 * record, its srv_job once it is first scheduled, its bundle, its image
 * writer, its timings). The list is in queue order: priority (higher first),
 * then submission (lower id first). A worker's free slot gets the first task
 * of the first job in that order that has one to hand out, so a higher
 * priority job takes the farm from its next task on, and idle workers start
 * on the next job during the running one's last pass, after the backup
 * copies of its stragglers. Each job leases under one policy (server/sched/job.h:
 * hard deadlines from cfg->lease_ms and the job's observed task times,
 * backups, cfg->verify_fraction with a seed drawn once per run); a lease
 * past a deadline is requeued and counts a miss for its worker
 * (server/api/workers.h blocks repeat offenders). A job ends DONE (its final
 * image written first), CANCELLED or FAILED, and workers are told at once of
 * one that ended early (JOB_END). Progressive images are saved at most every
 * cfg->save_interval seconds, checkpoints (written off the loop,
 * server/store/state.h) when a results log grows past srv_state_ckpt_limit.
 *
 * Durable steps (the queue file, results logs, checkpoints, bundles) use the
 * state folder (server/store/state.h); with none (one-job mode) they are skipped.
 *
 * Threads: called only from the event-loop thread.
 */
#ifndef PT_SERVER_QUEUE_H
#define PT_SERVER_QUEUE_H

#include <limits.h>
#include <stddef.h>
#include <stdint.h>

#include "common/scene/bundle.h"
#include "protocol/msg.h"
#include "server/core.h"
#include "server/sched/job.h"
#include "server/sched/writer.h"
#include "server/store/state.h"

/* What the queue keeps on disk, a strategy its mode names (srv_mode.durability):
 * srv_durability_folder, the state folder's (a queue file, each job's
 * bundle, checkpoint and results log), or srv_durability_none (one job:
 * nothing is kept; the scene is in memory). Called on the loop thread. */
typedef struct srv_durability {
    /* Writes the queue file (every job's record). */
    pt_status (*journal)(srv_server *s, pt_error *err);
    /* 1 while the last journal failed (the file on disk is older). */
    int (*unsaved)(const srv_server *s);
    /* The files of job id go (it ended). */
    void (*forget)(srv_server *s, uint64_t id);
    /* Rebuilds j's fresh job from what was kept of it. */
    pt_status (*restore)(srv_server *s, srv_entry *j, pt_error *err);
    /* Loads the bundle of j, which has none in memory. */
    pt_status (*load_bundle)(srv_server *s, srv_entry *j, pt_error *err);
    /* The Cryptomatte manifests kept for job id (*text: NULL when this
     * durability keeps none: the job has them in memory from setup). */
    pt_status (*load_manifests)(srv_server *s, uint64_t id, char **text, pt_error *err);
    /* Once per round (srv_queue_tick): for each running job, then once. */
    void (*tick_job)(srv_server *s, srv_entry *j, uint64_t now);
    void (*tick)(srv_server *s, uint64_t now);
} srv_durability;

extern const srv_durability srv_durability_folder;
extern const srv_durability srv_durability_none;

/* A result logged and waiting for the group commit that makes its record
 * durable; merged only then (srv_queue_committed). */
typedef struct srv_pending {
    proto_result r;   /* the result as logged, decoded; it owns its pixels */
    uint64_t owner;   /* the connection that sent it */
    uint64_t commit;  /* the group commit that holds its record */
    uint64_t arrived; /* ms */
    uint64_t ticket;  /* its lease's (srv_job_answered); 0: none (merged as a replay) */
    uint64_t bytes;   /* its pixels' bytes when kept, counted in pend_bytes */
} srv_pending;

/* A job of the queue (or the one job of one-job mode). */
struct srv_entry {
    srv_job_record rec;
    srv_job *job;      /* NULL until it is first scheduled (and after it ends) */
    pt_bundle *bundle; /* loaded when a worker first asks for it */
    srv_writer *writer;
    /* Cryptomatte's header attributes (its manifests), known where the
     * coordinator loaded the scene itself (one-job mode), else NULL: a
     * queued job's EXR has the layers and no manifest. A frame uses its
     * range's. Owned. */
    struct pt_crypto_meta *crypto;
    char out_path[PATH_MAX];
    double seconds_before; /* render seconds of earlier coordinator runs */
    uint64_t t_started;    /* when this run started rendering it (ms), 0: not yet */
    uint64_t rejected, rays;
    uint32_t saved_passes;
    uint64_t saved_samples, t_last_save;
    uint64_t rate_t, rate_samples;
    double rate;
    /* A folder that cannot be written (full, over quota, failing): while
     * paused, none of the job's tasks is leased, and every few seconds the
     * write that failed is tried again (pending_rec: the result its results
     * log could not take, merged once it is logged; pending_ckpt: its
     * checkpoint); the job resumes by itself when it succeeds. */
    int paused;
    char pause_reason[160]; /* shown by ptctl status: "state folder full (...)" */
    uint8_t *pending_rec;
    size_t pending_len;
    int pending_ckpt;
    int pending_sync;  /* a group commit of its log failed: synced again first */
    srv_pending *pend; /* logged, not merged yet: in commit order */
    uint32_t npend, pend_cap;
    uint64_t pend_bytes;             /* their pixels' bytes (srv_queue_pending_bytes) */
    uint64_t committed;              /* the last group commit its log was in, and durable */
    uint64_t t_paused, t_retry;      /* ms */
    int final_writing;               /* complete, its final image with the writer */
    int final_pending;               /* complete, but its final image could not be written */
    char out_reason[160];            /* why the last image write failed ("" when none) */
    unsigned long save_fails_logged; /* progressive saves failed in a row, logged once */
    /* A frame-range job (server/sched/frames.h): the range holds its frames
     * rendering (frames); each frame is an entry of this list too, a still
     * of its own with parent set and its frame number. Frame entries are
     * not journaled, listed or found by id (srv_queue_find_any finds them). */
    struct srv_frames *frames;
    srv_entry *parent;
    uint32_t frame;
    srv_entry *next; /* the queue's order */
};

/* What a frame range does as an entry of the queue where it differs from a
 * still: server/sched/frames.h provides it (srv_frames_ops) and srv_serve installs
 * it (s->ranges), so the queue, below the ranges made of its stills, never
 * calls them by name. Each as the srv_frames_* function of its name. */
typedef struct srv_range_ops {
    int (*ready)(srv_server *s, srv_entry *p);
    srv_entry *(*at)(const srv_entry *p, uint32_t i);
    void (*pose)(const srv_entry *f, proto_task *t);
    void (*note_done)(srv_entry *f);
    void (*end)(srv_server *s, srv_entry *p, uint8_t state, const char *message);
    int (*round)(srv_server *s);
    void (*info)(const srv_server *s, const srv_entry *p, proto_job_info *m);
} srv_range_ops;

/* 1 while j is QUEUED or RUNNING. */
int srv_entry_active(const srv_entry *j);

/* Render seconds of j, over every coordinator run, at now (ms). */
double srv_entry_seconds(const srv_entry *j, uint64_t now);

/* Frees j and what it holds; accepts NULL. */
void srv_entry_free(srv_entry *j);

/* Makes j ready to lease: its srv_job (restored from its checkpoint and
 * results log when there is a state folder) and its image writer. Returns 0
 * when it cannot be (j is then ended FAILED, with the reason). */
int srv_entry_ready(srv_server *s, srv_entry *j);

/* Hands j's film, resolved, to its writer: a progressive image, or with
 * final the finished one (denoised when the job asks, srv_writer.h). */
void srv_entry_save_image(srv_entry *j, int final);

/* Writes j's checkpoint when there is a state folder; an error is logged
 * and returned. */
pt_status srv_entry_checkpoint(srv_server *s, srv_entry *j, pt_error *err);

/* The job with id, NULL when there is none (a frame of a frame-range job
 * is not a job of the queue: NULL for its id). */
srv_entry *srv_queue_find(srv_server *s, uint64_t id);

/* The entry whose tasks carry job id, a frame's included (RESULT). */
srv_entry *srv_queue_find_any(srv_server *s, uint64_t id);

/* The active job whose scene has this SHA-256, its bundle loaded (a bundle
 * that does not load fails the job); NULL when there is none. */
srv_entry *srv_queue_find_scene(srv_server *s, const uint8_t hash[32]);

/* The packed bytes (proto_guide_pack) of a guiding distribution some
 * active job holds under this SHA-256 of its unpacked bytes (GUIDE_GET;
 * borrowed until the loop's next merge); 0 when none. */
int srv_queue_find_guide(srv_server *s, const uint8_t hash[32], const uint8_t **data, size_t *len);

/* Puts j in its place in the queue order / takes it out again. */
void srv_queue_insert(srv_server *s, srv_entry *j);
void srv_queue_unlink(srv_server *s, srv_entry *j);

/* Drops the oldest ended jobs beyond the history's cap. */
void srv_queue_prune(srv_server *s);

/* Writes the queue file (every job's record); PT_OK with no state folder. */
pt_status srv_queue_journal(srv_server *s, pt_error *err);

/* Logs an accepted RESULT of j (frame: its whole frame as received, len
 * bytes; r: that frame decoded into pixels of its own) from owner, which
 * srv_job_validate judged the answer to lease_index; the result is merged
 * once its record is durable (srv_queue_committed), through that lease when
 * it is still live (it is not judged again), and the caller must not merge
 * it. The lease is marked answered meanwhile (srv_job_answered). Takes r's pixels (r->pixels is
 * then NULL, r->owns_pixels 0): they wait with the record, decoded once. own: NULL, or the
 * pt_malloc'd buffer frame lies at the start of, which the log takes instead of a copy
 * (*own is then NULL). When the log cannot take it, j is paused (its leases
 * requeued, the workers told to drop its tasks, the reason logged once) and
 * the frame kept to be logged by a later srv_queue_tick. Also fails, quietly,
 * while j is paused. Needs a state folder. */
pt_status srv_queue_log_result(srv_server *s, srv_entry *j, uint64_t owner, int lease_index,
                               proto_result *r, const uint8_t *frame, size_t len, uint8_t **own,
                               uint64_t arrived, pt_error *err);

/* The bytes of the pixels of every job's results waiting for their commit
 * (decoded: twice their log records' size); srv_loop_hold counts them with
 * the records. */
uint64_t srv_queue_pending_bytes(const srv_server *s);

/* The group commit's completions (its eventfd is readable): merges the
 * results whose records are now durable, pauses a job whose log's fdatasync
 * failed (its unmerged results dropped; their tasks are leased again). wait:
 * first wait for the commit in flight. */
void srv_queue_committed(srv_server *s, int wait);

/* Commits and merges everything logged (a clean stop). */
void srv_queue_commit_all(srv_server *s);

/* JOB_INFO of j as a client sees it now. */
void srv_queue_info(const srv_server *s, const srv_entry *j, proto_job_info *m);

/* Ends j: DONE (the final image is written first, by j's writer thread:
 * j stays RUNNING, "writing", with final_writing set while the loop goes on,
 * and srv_queue_tick ends it once the image is on disk; when it cannot be
 * written, final_pending is set, the reason shown, and srv_queue_tick tries
 * again every few seconds), CANCELLED or FAILED with message (may be NULL).
 * Journals it, tells the workers when it ended early and its watchers
 * always. */
void srv_queue_end_job(srv_server *s, srv_entry *j, uint8_t state, const char *message);

/* 1 when who (admin: it proved the shared token) may change j: cancel it
 * or set its priority. Every client may, without --clients-file. */
int srv_queue_may_change(const srv_entry *j, const char *who, int admin);

/* Cancels j, "cancelled by <by>", when it is still active (ptctl's CANCEL
 * and the dashboard's). */
void srv_queue_cancel(srv_server *s, srv_entry *j, const char *by);

/* Sets active j's priority, moves it to its place in the queue order and
 * journals it (a failure logged); by: who set it, for the log. 0 when
 * nothing changed (j ended, or the priority is the same). */
int srv_queue_set_priority(srv_server *s, srv_entry *j, int32_t priority, const char *by);

/* Ends the jobs whose every task is merged; returns how many. */
int srv_queue_end_complete(srv_server *s);

/* Leases owner (a worker connection's id) a task into *t: of the first job
 * in queue order that has one to hand out (a frame range's earliest frame
 * that has one), starting a queued job. 0 when no job has one. */
int srv_queue_lease(srv_server *s, uint64_t owner, uint64_t now, proto_task *t);

/* Requeues every task leased to owner (a worker that is leaving); returns
 * how many. */
uint32_t srv_queue_release_owner(srv_server *s, uint64_t owner);

/* Merges r, a result of j from owner that srv_job_validate accepted
 * (lease_index: what it gave, the job unchanged since; -1: no lease, merged
 * as a replay), and counts it: the merge's time, j's rejected samples and
 * rays, srv_sched_events.result_merged, the verification summary once j is
 * complete. May take r's pixels (srv_job_result_validated). */
srv_outcome srv_queue_merge(srv_server *s, srv_entry *j, uint64_t owner, int lease_index,
                            proto_result *r, uint64_t arrived, pt_error *err);

/* Logs what verification cost and found in j (complete). */
void srv_queue_verify_summary(const srv_entry *j);

/* Lease expiry, at most every 50 ms (each miss told as
 * srv_sched_events.owner_missed): returns 1 when it walked the leases;
 * then, per running
 * job, the progressive save (a failure logged once per streak), the rate, the
 * checkpoint trigger, and the retries of a paused job's writes, of a final
 * image and of the queue file. now in ms (pt_now_ms). */
int srv_queue_expire(srv_server *s, uint64_t now);
void srv_queue_tick(srv_server *s, uint64_t now);

/* Frees every job and closes the state folder. */
void srv_queue_free(srv_server *s);

#endif
