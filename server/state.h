/*
 * state.h - the coordinator's state folder: the queue and each job's files.
 *
 *   DIR/lock                 held (flock) by the one ptserve using DIR
 *   DIR/queue                every job's record; rewritten whole on each
 *                            change (temp, fsync, rename), CRC32C at the end
 *   DIR/jobs/ID/bundle       the scene bundle as submitted (SHA-256 checked on load)
 *   DIR/jobs/ID/checkpoint   the job's merged state (srv_job_save) with render
 *                            seconds and counters; written whole, CRC32C at the end
 *   DIR/jobs/ID/results.log  every result accepted since that checkpoint, appended
 *                            before it is merged: record = u32 length, u32 CRC32C
 *                            of the payload, the RESULT payload as received
 *
 * A merged result is therefore always on disk: in the checkpoint, or in the log
 * (written before the merge, so a kill -9 of the coordinator loses nothing
 * merged; the log is fdatasync'd in groups for power loss). After a restart the
 * job is rebuilt from the checkpoint, then the log is replayed; replay is
 * idempotent, so a crash between writing a checkpoint and emptying the log is
 * harmless. A write cut short (a full disk) is cut back at once to the last
 * whole record, so later records never follow a partial one. An incomplete or
 * unchecked last record (cut short by a crash, or by a full disk when the cut
 * back also failed) is dropped at the next start with a warning: it was never
 * merged. Anything else that does not check out (a bad magic, checksum,
 * length, or contents before the last record) is refused with an error that
 * names the file; it is never used silently.
 *
 * Threads: called only from the event-loop thread, except srv_state_dir and
 * srv_state_save_bundle, which any thread may call between open and close.
 */
#ifndef PT_SERVER_STATE_H
#define PT_SERVER_STATE_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"
#include "common/base/frames.h"
#include "common/scene/bundle.h"
#include "protocol/msg.h"
#include "server/job.h"

/* Frames of one frame-range job rendering at once (server/frames.h). */
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
    uint64_t capped; /* paths ended by the depth cap, set when the job ends */
    /* A frame-range job (server/frames.h; format 5, none from older ones):
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

/* Opens (creating) DIR and DIR/jobs and takes DIR/lock: PT_ERR_IO naming DIR
 * when another ptserve holds it. */
pt_status srv_state_open(const char *dir, srv_state **out, pt_error *err);
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

/* Counters a checkpoint carries beside the job's merged state. */
typedef struct srv_ckpt_extra {
    double seconds;    /* render time so far */
    uint64_t rejected; /* NaN/Inf samples the workers dropped */
    uint64_t rays;
} srv_ckpt_extra;

/* Writes the checkpoint of job (durably), then empties its results log. */
pt_status srv_state_checkpoint(srv_state *st, const srv_job *job, const srv_ckpt_extra *x,
                               pt_error *err);

/* Rebuilds a fresh job (srv_job_new with its record's settings) from its
 * checkpoint, when there is one, and its results log. *extra receives the
 * checkpoint's counters plus the replayed results'; *replayed the number of
 * log records merged; *torn 1 when an incomplete last record was dropped. */
pt_status srv_state_restore(srv_state *st, srv_job *job, srv_ckpt_extra *extra, uint32_t *replayed,
                            int *torn, pt_error *err);

/* Appends one accepted RESULT payload to the job's log (opened on first use).
 * Written before the result is merged; srv_state_sync makes it durable. On
 * failure (PT_ERR_IO, err->sys_errno ENOSPC, EDQUOT, EIO...) the log is left
 * as it was, ending with its last whole record (a partial write is cut
 * back), and the result must not be merged. */
pt_status srv_state_log_result(srv_state *st, uint64_t id, const uint8_t *payload, size_t len,
                               pt_error *err);
/* Bytes in the job's log now (0 when it has none). */
uint64_t srv_state_log_bytes(const srv_state *st, uint64_t id);
/* fdatasync of every log written to since the last call. */
pt_status srv_state_sync(srv_state *st, pt_error *err);

/* Closes the job's log and deletes its folder (the job ended). */
void srv_state_forget_job(srv_state *st, uint64_t id);

#endif
