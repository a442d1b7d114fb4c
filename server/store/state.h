/*
 * state.h - the coordinator's state folder: the queue and each job's files.
 *
 *   DIR/lock                 held (flock) by the one ptserve using DIR
 *   DIR/queue                every job's record; rewritten whole on each
 *                            change (temp, fsync, rename), CRC32C at the end
 *   DIR/jobs/ID/bundle       the scene bundle as submitted (SHA-256 checked on load)
 *   DIR/jobs/ID/cryptomatte  a job with Cryptomatte: its two manifests (objects,
 *                            materials), one JSON object a line, from the scene
 *                            the upload check loaded
 *   DIR/jobs/ID/checkpoint   the job's merged state (the codec's save) with render
 *                            seconds and counters; written whole, CRC32C at the end
 *   DIR/jobs/ID/results.log  every result accepted since that checkpoint, appended
 *                            before it is merged: a 16-byte header ("PTRF",
 *                            version, job id), then each RESULT frame as it
 *                            was received (protocol/frame.h: header, payload,
 *                            CRC32C), so the frame's own checksum, checked on
 *                            arrival, is the record's and none is computed
 *   DIR/jobs/ID/results.old  the log a checkpoint being written will hold: it
 *                            is renamed from results.log when that checkpoint
 *                            starts, and removed once the checkpoint is durable
 *   DIR/trash/ID             an ended job's folder, moved here from jobs/ (a
 *                            rename) and removed by the state's sweeper thread;
 *                            what a crash left here is removed after the next
 *                            start
 *
 * A merged result is therefore always on disk: in the checkpoint, or in a log.
 * A record is written before its result is merged, and the result is merged
 * only once a group commit (fdatasync of every log written since the last, on
 * the commit thread, srv_state_commit_start) has returned: so neither a kill
 * -9 of the coordinator nor a power loss loses a merged result. After a
 * restart the job is rebuilt from the checkpoint, then results.old and
 * results.log are replayed; replay is idempotent, so a crash between writing a
 * checkpoint and removing the log it holds is harmless. Checkpoints are
 * written from a snapshot of the job (its owner's copy) by their own thread
 * (srv_state_checkpoint_start), to a temporary file renamed into place, so a
 * crash during one leaves the previous checkpoint and both logs, which hold
 * everything. A write cut short (a full disk) is cut back at once to the last
 * whole record, so later records never follow a partial one; a failed
 * fdatasync cuts the log back to what the last good one covered (the kernel
 * may have dropped the pages since, and a later fdatasync would not say so).
 * An incomplete or unchecked last record (cut short by a crash, or by a full
 * disk when the cut back also failed) is dropped at the next start with a
 * warning: it was never merged. Anything else that does not check out (a bad
 * magic, checksum, length, or contents before the last record) is refused
 * with an error that names the file; it is never used silently. A log of an
 * older ptserve ("PTRL": u32 length, u32 CRC32C of the payload, the payload)
 * is read and rewritten in frames at its first replay.
 *
 * The folder knows a job only as a handle and what the codec its opener
 * hands it (srv_job_codec) does with one: it never calls the scheduler,
 * whose job it keeps; replay yields each record's decoded RESULT to the
 * codec, which merges it.
 *
 * Threads: called only from the event-loop thread, except srv_state_dir and
 * srv_state_save_bundle, which any thread may call between open and close.
 * The state owns three threads of its own: the group commit's and the
 * sweeper's (started at open) and the checkpoint writer's (one checkpoint at
 * a time); they touch only what they were handed.
 */
#ifndef PT_SERVER_STATE_H
#define PT_SERVER_STATE_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"
#include "common/base/frames.h"
#include "common/scene/bundle.h"
#include "protocol/msg.h"
#include "protocol/wire.h"
#include "server/params.h"

/* Frames of one frame-range job rendering at once (server/sched/frames.h). */
#define SRV_FRAMES_AHEAD 8u

/* One job's durable record: its entry in the queue file. */
typedef struct srv_job_record {
    uint64_t id, seq; /* seq: submission order */
    uint8_t state;    /* PROTO_JOB_* */
    int32_t priority;
    char name[PROTO_MAX_NAME + 1];
    char owner[PROTO_MAX_NAME + 1];
    char scene[PROTO_MAX_PATH + 1];  /* the bundle's entry file name */
    char output[PROTO_MAX_PATH + 1]; /* the EXR's name in the output folder */
    uint64_t submitted;              /* Unix seconds */
    srv_job_params params;
    uint8_t hash[32]; /* SHA-256 of the bundle */
    uint64_t bundle_size;
    uint64_t samples_done; /* set when the job ends */
    double seconds;        /* render seconds, set when the job ends */
    double error;          /* estimated relative error when it ended; < 0 unknown */
    char message[PROTO_MAX_ERROR_TEXT + 1];
    uint64_t capped;  /* paths ended by the depth cap, set when the job ends */
    uint64_t clamped; /* contributions clamped (--clamp-*), likewise */
    /* Samples merged as rejected (proto_job_info.rejected), set when the job
     * ends (format 8; 0 from older ones). */
    uint64_t rejected;
    /* A frame-range job (server/sched/frames.h; format 5, none from older ones):
     * its range (step 0: a still, and the rest unused), the pose's frame rate
     * and animation, and the frames done: every index below frames_done, and
     * the ndone_ahead indices in done_ahead (frames past the first one not
     * done that finished first; never more than SRV_FRAMES_AHEAD, as no
     * frame further on is started). Written before a done frame's files go,
     * so a frame is never rendered again after a restart. */
    pt_frames frames;
    double fps;
    char animation[PROTO_MAX_NAME + 1];
    uint32_t frames_done;
    uint32_t ndone_ahead;
    uint32_t done_ahead[SRV_FRAMES_AHEAD];
} srv_job_record;

#define SRV_MAX_JOBS 100000u /* records in one queue file */

typedef struct srv_state srv_state;

/* A job as the scheduler keeps it (server/sched/job.h): a handle here, reached
 * only through the codec. */
typedef struct srv_job srv_job;

/* What the folder asks of a job, handed to it at open by the layer that owns
 * the jobs. The checkpoint thread calls save on a snapshot (and free once it
 * is written), so save must touch nothing but the job it is given. */
typedef struct srv_job_codec {
    uint64_t (*id)(const srv_job *job);
    /* Appends the job's merged state to w (a checkpoint's body). */
    pt_status (*save)(const srv_job *job, proto_writer *w, pt_error *err);
    /* Restores a checkpoint's body into a fresh job; err says what does not fit. */
    pt_status (*load)(srv_job *job, const uint8_t *data, size_t len, pt_error *err);
    /* Merges one record of a results log (the job may take r's pixels):
     * PT_OK with *merged 1, or 0 for a result the job holds already; any
     * other status when it does not fit the job (err says why). */
    pt_status (*replay)(srv_job *job, proto_result *r, int *merged, pt_error *err);
    void (*free)(srv_job *job); /* a snapshot handed to srv_state_checkpoint_start */
} srv_job_codec;

/* Opens (creating) DIR and DIR/jobs and takes DIR/lock: PT_ERR_IO naming DIR
 * when another ptserve holds it. codec (kept; NULL when the folder's jobs
 * are never checkpointed or restored, only its queue file and bundles used)
 * is what checkpoints and replays call. */
pt_status srv_state_open(const char *dir, const srv_job_codec *codec, srv_state **out,
                         pt_error *err);
void srv_state_close(srv_state *st); /* accepts NULL */
const char *srv_state_dir(const srv_state *st);

/* The queue. A missing file is an empty queue (*n = 0, ids from 1). */
pt_status srv_state_load_queue(srv_state *st, srv_job_record **recs, uint32_t *n, uint64_t *next_id,
                               pt_error *err);
pt_status srv_state_save_queue(srv_state *st, srv_job_record *const *recs, uint32_t n,
                               uint64_t next_id, pt_error *err);
/* 1 when the last srv_state_save_queue failed (the file on disk is older than
 * the queue): the caller tries again until it succeeds. */
int srv_state_queue_unsaved(const srv_state *st);

/* The bundle of job id: saved durably; loaded with its SHA-256 checked.
 * srv_state_save_bundle reads only the folder's name, fixed at open, and
 * writes only job id's folder, so the upload verification thread may call it
 * (as may srv_state_dir) while the loop uses st. */
pt_status srv_state_save_bundle(const srv_state *st, uint64_t id, const uint8_t *data, size_t n,
                                pt_error *err);
pt_status srv_state_load_bundle(srv_state *st, uint64_t id, const uint8_t hash[32], pt_bundle **out,
                                pt_error *err);

/* The Cryptomatte manifests of job id (text of at most
 * SRV_STATE_MAX_MANIFESTS bytes): saved durably by the upload check (as a
 * bundle is, from its thread), loaded when the job's writer is made.
 * *out is pt_malloc'd and NUL-terminated. */
#define SRV_STATE_MAX_MANIFESTS (4u << 20)
pt_status srv_state_save_manifests(const srv_state *st, uint64_t id, const char *text,
                                   pt_error *err);
pt_status srv_state_load_manifests(srv_state *st, uint64_t id, char **out, pt_error *err);

/* Counters a checkpoint carries beside the job's merged state. */
typedef struct srv_ckpt_extra {
    double seconds;    /* render time so far */
    uint64_t rejected; /* NaN/Inf samples the workers dropped */
    uint64_t rays;
} srv_ckpt_extra;

/* Checkpoints go when a job's log passes SRV_CKPT_FILM_MULTIPLE times the
 * film's size (its pixels at PROTO_RESULT_PIXEL_SIZE bytes), and at least
 * SRV_CKPT_MIN_LOG: a checkpoint costs about a film's size of writing, so this
 * bounds its share of the disk and the loop's time per result, and a
 * restart's replay to that many bytes of log (docs/ARCHITECTURE.md has the
 * measurements behind the multiple). */
#define SRV_CKPT_FILM_MULTIPLE 4u
#define SRV_CKPT_MIN_LOG ((uint64_t)16 << 20)
uint64_t srv_state_ckpt_limit(const srv_state *st, uint64_t film_bytes);

/* Writes the checkpoint of job (durably) on the caller's thread, then
 * empties its results logs (for a clean stop, and the retry of a paused
 * job). Waits for the checkpoint thread and the group commit in flight
 * first. Every record of the job's log is dropped: the caller drops the
 * results it holds unmerged. */
pt_status srv_state_checkpoint(srv_state *st, const srv_job *job, const srv_ckpt_extra *x,
                               pt_error *err);

/* Starts the checkpoint of a job off the loop: snap (a copy of it that the
 * codec's save reads and free frees, owned by the state from here on) is serialised and written
 * durably by the checkpoint thread. The job's results.log is renamed results.old at once and a
 * fresh one opened: records logged from now on go there, and a record of results.old whose result
 * is not merged yet must be logged again (its result is not in snap). PT_AGAIN while another
 * checkpoint is being written; PT_ERR_IO when the log cannot be rotated. */
pt_status srv_state_checkpoint_start(srv_state *st, srv_job *snap, const srv_ckpt_extra *x,
                                     pt_error *err);
int srv_state_checkpoint_busy(const srv_state *st);
/* 1 when the checkpoint started last has finished: *id its job, *status how
 * (err: why not); 0 while it runs or when there is none. */
int srv_state_checkpoint_collect(srv_state *st, uint64_t *id, pt_status *status, pt_error *err);

/* Rebuilds a fresh job (made with its record's settings) from its
 * checkpoint, when there is one, and its results logs, through the codec. *extra receives the
 * checkpoint's counters plus the replayed results'; *replayed the number of
 * log records merged; *torn 1 when an incomplete last record was dropped.
 * A results.old found is folded into a new checkpoint at once. */
pt_status srv_state_restore(srv_state *st, srv_job *job, srv_ckpt_extra *extra, uint32_t *replayed,
                            int *torn, pt_error *err);

/* Appends one accepted RESULT frame (its whole bytes as received: header,
 * payload, CRC32C) to the job's log (opened on first use). The record is kept
 * in memory: the group commit's thread writes it and makes it durable (so the
 * loop does no disk work per result), or srv_state_sync on the caller's
 * thread; the result may be merged once the commit srv_state_commit_next said
 * before this call has returned. A write that fails (err->sys_errno ENOSPC,
 * EDQUOT, EIO...) fails that commit or sync: the file is cut back to its last
 * whole record and the records since stay in memory, written again later
 * (srv_state_commit_collect, srv_state_log_resync). Fails itself
 * (PT_ERR_IO, PT_ERR_NOMEM) only when the log cannot be opened or cut back,
 * or memory is short; the result must not be merged then. */
pt_status srv_state_log_result(srv_state *st, uint64_t id, const uint8_t *frame, size_t len,
                               pt_error *err);
/* srv_state_log_result without a copy: takes *frame (a pt_malloc'd buffer of
 * len bytes holding the frame) and sets it to NULL; on failure it stays the
 * caller's. */
pt_status srv_state_log_result_take(srv_state *st, uint64_t id, uint8_t **frame, size_t len,
                                    pt_error *err);
/* Bytes of every log's records not known durable yet: those in memory, and
 * those of the commit in flight or of a failed one. */
uint64_t srv_state_unsynced(const srv_state *st);
/* Bytes in the job's log now (0 when it has none). */
uint64_t srv_state_log_bytes(const srv_state *st, uint64_t id);

/* The group commit. srv_state_commit_next: the number of the commit a record
 * logged now will be in. srv_state_commit_start (once per loop round) hands
 * every log written since the last commit to the commit thread, which writes
 * their records and fdatasyncs them; it does nothing while one is in flight
 * (returns 0) or when nothing was written. The thread makes
 * srv_state_commit_fd (an eventfd, for the loop's epoll set) readable when it
 * is done; srv_state_commit_collect then returns 1 with *done the commit's
 * number, having called fn for each job's log in it: PT_OK (every record
 * logged before it began is durable); PT_ERR_IO (the write or fdatasync
 * failed: the file is cut back to what the last good commit covered, every
 * record since is kept in memory, and the log is left out of commits until
 * srv_state_log_resync; the next commit that succeeds says it takes writes
 * again); PT_ERR_NOMEM (the same, but memory to keep the records was short:
 * they are gone, never merged). wait: block until the commit in flight is
 * done. Returns 0 when none was collected. */
typedef void (*srv_commit_fn)(void *ctx, uint64_t job_id, pt_status st, const pt_error *err);
int srv_state_commit_fd(const srv_state *st);
uint64_t srv_state_commit_next(const srv_state *st);
int srv_state_commit_start(srv_state *st);
int srv_state_commit_busy(const srv_state *st);
int srv_state_commit_collect(srv_state *st, int wait, uint64_t *done, srv_commit_fn fn, void *ctx);
/* Marks the job's log for the next commit (after a failed one). */
pt_status srv_state_log_resync(srv_state *st, uint64_t id, pt_error *err);
/* Writes and fdatasyncs every log written to since the last commit, on the
 * caller's thread, after the commit in flight (whose outcome is left to
 * collect; a log whose commit failed is left for it). */
pt_status srv_state_sync(srv_state *st, pt_error *err);

/* Closes the job's log and deletes its folder (the job ended): moved to
 * the trash at once, its files removed by the sweeper, so the caller does
 * not wait for the unlinks (tens of ms for a large job). When its checkpoint
 * is being written, that is done first (srv_state_checkpoint_collect). */
void srv_state_forget_job(srv_state *st, uint64_t id);

#endif
