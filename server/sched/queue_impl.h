/*
 * queue_impl.h - the inside of the queue (server/sched/queue.h), shared by
 * the files it is cut into by concern: queue.c (the entries in order, their
 * leases, JOB_INFO, their end, the timers) and results.c (the results
 * pipeline: a result logged, committed and merged, checkpoints, and the
 * pauses of a job whose state folder does not take its writes). No other
 * file includes it.
 *
 * Threads: as queue.h: the event-loop thread only.
 */
#ifndef PT_SERVER_SCHED_QUEUE_IMPL_H
#define PT_SERVER_SCHED_QUEUE_IMPL_H

#include "server/sched/queue.h"

/* A write to a folder that failed (full, over quota) is tried again this
 * often: often enough that a farm resumes soon after space is freed, rarely
 * enough that a full disk costs nothing. */
#define DISK_RETRY_MS 3000

/* each_worker's walk that requeues a job's leases of each worker. */
typedef struct owner_release {
    srv_job *job;
    uint32_t n;
} owner_release;

/* Tries the write that paused j again; resumes j when it succeeds. */
void queue_retry_paused(srv_server *s, srv_entry *j, uint64_t now);

void queue_release_owner(void *ctx, uint64_t owner);

/* Starts j's checkpoint off the loop (server/store/state.h): a snapshot of the job
 * now, its results log rotated, and the records of the results not merged
 * yet logged again in the new log (the snapshot does not hold them), to be
 * merged once that log is durable. */
void queue_checkpoint_start(srv_server *s, srv_entry *j);

/* The state folder cannot take j's writes: no task of j is leased until the
 * failed write succeeds (srv_queue_tick tries it again). Its leases are
 * requeued and the workers told to drop its tasks (JOB_END), since results
 * that cannot be logged could not be merged. Logged once per pause. */
void queue_pause_job(srv_server *s, srv_entry *j, const char *what, const pt_error *err);

/* Drops j's results that wait for a group commit (never merged: their
 * records are gone, or the job is). */
void queue_drop_pending(srv_entry *j);

/* The bytes of r's decoded pixels (a pending result's share of
 * srv_queue_pending_bytes). */
uint64_t queue_pixel_bytes(const proto_result *r);

/* Frees a pending result p of j (its pixels, unless the job took them). */
void queue_pending_fini(srv_entry *j, srv_pending *p);

/* What a client is shown of a failed write: "state folder full (No space
 * left on device)". Never the error's text, which names server paths. */
void queue_disk_reason(const char *folder, const pt_error *err, char *out, size_t cap);

/* Job j ended before it was done: the layers above tell every worker, so
 * each drops the tasks of it that it has not started and its threads go to
 * the next job at once (their results would be dropped anyway). */
void queue_announce_job_end(srv_server *s, const srv_entry *j);

/* The state folder's side of srv_durability_folder (queue.c); the rest of
 * it is results.c's. */
pt_status queue_journal_folder(srv_server *s, pt_error *err);
pt_status queue_restore_folder(srv_server *s, srv_entry *j, pt_error *err);
pt_status queue_load_bundle_folder(srv_server *s, srv_entry *j, pt_error *err);
pt_status queue_load_manifests_folder(srv_server *s, uint64_t id, char **text, pt_error *err);

#endif
