/*
 * state_impl.h - the inside of the state folder (server/store/state.h),
 * shared by the files it is cut into by concern: state.c (the folder, its
 * threads, whole files, the queue file, bundles), state_log.c (results
 * logs and the group commit) and state_ckpt.c (checkpoints, replay and the
 * logs' format upgrades). No other file includes it.
 *
 * Threads: as state.h.
 */
#ifndef PT_SERVER_STORE_STATE_IMPL_H
#define PT_SERVER_STORE_STATE_IMPL_H

#include <limits.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#include "server/store/state.h"

#define QUEUE_MAGIC 0x31515450u /* "PTQ1" */
#define CKPT_MAGIC 0x4b435450u  /* "PTCK" */
#define LOG_MAGIC 0x4c525450u   /* "PTRL": records of u32 length, u32 CRC32C, payload */
#define FLOG_MAGIC 0x46525450u  /* "PTRF": records are RESULT frames as received */
#define STATE_VERSION 10u
/* The oldest format still read: version 2 has no min gain (read as 0, the
 * rule off), versions 2 and 3 no environment and no film flags (read as
 * none) and protocol 2's RESULT in the log, so a state folder survives the
 * upgrades that brought them. */
#define STATE_OLDEST_VERSION 2u
#define STATE_MIN_GAIN_VERSION 3u /* the first with the min gain */
/* The first with the environment and the film flags in the queue file's job
 * params, and with protocol 3's RESULT (the depth-cap count, each pixel's
 * camera hits) in the log; an older log is read through log_upgrade_record and
 * rewritten. One format version brought both. */
#define STATE_ENV_VERSION 4u
#define STATE_FILM_VERSION STATE_ENV_VERSION
/* The first with protocol 4's RESULT (fixed-point sums) in the log; an older
 * log's double sums are converted as it is read (log_upgrade_fixed). */
#define STATE_FIXED_VERSION 5u
/* The first with a frame-range job's range, pose and frames done in its
 * queue record (older records are stills). */
#define STATE_FRAMES_VERSION 6u
/* The first with motion blur's shutter in the job params (older: none). */
#define STATE_SHUTTER_VERSION 7u
/* The first with a job's rejected samples in its queue record (older: 0). */
#define STATE_REJECTED_VERSION 8u
/* The first with sample clamping in the job params (older: none). */
#define STATE_CLAMP_VERSION 9u
/* The first with a job's contributions clamped in its queue record (older: 0). */
#define STATE_CLAMPED_VERSION 10u
#define LOG_HEADER 16u
#define MAX_QUEUE_BYTES (256u << 20)
#define MAX_CKPT_BYTES ((size_t)8 << 30)

/* Records waiting to be written: the loop appends, the commit thread writes
 * them with writev. Each record is a buffer of its own: a RESULT frame as an
 * I/O thread received it, taken without a copy (a copy of 37 kB per result
 * was 12 % of the loop's time in queue mode) or a copy. The buffers are
 * freed once written and durable, by the commit thread. */
typedef struct rec_seg {
    uint8_t *p;
    size_t n; /* > 0 */
} rec_seg;

typedef struct rec_buf {
    rec_seg *seg;
    uint32_t nseg, cap;
    size_t len; /* the bytes of all its records */
} rec_buf;

typedef struct log_file {
    uint64_t id;
    int fd;
    uint64_t bytes;   /* the log's length once written: its whole records end here */
    uint64_t durable; /* what the last successful commit covered (<= bytes) */
    uint32_t epoch;   /* bumped when the file is cut to its header or replaced */
    int dirty;        /* written (or to be synced) since its last commit began */
    int cut;          /* a write was cut short and the cut back failed */
    int fresh;        /* made since its last commit: its folder entry is synced too */
    rec_buf out;      /* records logged, not yet handed to a commit (bytes - out.len:
                       * what the file holds or a commit in flight writes) */
} log_file;

/* One log of a group commit: what the commit thread syncs. */
typedef struct commit_item {
    uint64_t id, upto;
    uint32_t epoch;
    int fd;           /* a dup of the log's, closed by the commit thread */
    int fresh;        /* also fsync its folder */
    rec_buf in;       /* the records the thread appends before the fdatasync */
    const char *step; /* what failed: "write" or "fdatasync" */
    int err;          /* errno of the step that failed; 0: durable up to upto */
    char path[PATH_MAX];
} commit_item;

/* The group commit: the loop hands a batch to the thread (busy), the thread
 * syncs it and says so through efd (ready), the loop collects it. The mutex
 * guards has_req, ready and stop; the items belong to the thread between the
 * hand-over and ready, to the loop otherwise. */
typedef struct committer {
    pthread_t th;
    int started;
    pthread_mutex_t mu;
    pthread_cond_t cv;
    int efd;
    int has_req, ready, stop, busy;
    uint64_t gen;  /* the batch in flight (or last collected) */
    uint64_t next; /* the batch a record written now joins */
    commit_item *items;
    uint32_t n, cap;
    char gate[PATH_MAX]; /* test hook: wait for this file before each fdatasync */
    char fail[PATH_MAX]; /* test hook: while this file exists, each fdatasync fails */
} committer;

/* The sweeper: removes the folders of ended jobs (DIR/trash), whose files
 * (a results log of hundreds of MB, a checkpoint as large as the film) take
 * tens of milliseconds to unlink. */
typedef struct sweeper {
    pthread_t th;
    pthread_mutex_t mu;
    pthread_cond_t cv;
    int started, work, stop;
    char jobs[PATH_MAX], trash[PATH_MAX];
} sweeper;

/* The checkpoint in flight: a snapshot of the job written by its own thread. */
typedef struct ckpt_work {
    pthread_t th;
    int running; /* started and not joined */
    atomic_int done;
    uint64_t id;
    const srv_job_codec *codec; /* the state's, read by the thread */
    srv_job *snap;
    srv_ckpt_extra x;
    char path[PATH_MAX], old[PATH_MAX];
    char gate[PATH_MAX]; /* test hook: wait for this file before the rename */
    pt_status status;
    pt_error err;
    int forget; /* the job ended meanwhile: its folder goes once this is done */
} ckpt_work;

struct srv_state {
    char dir[PATH_MAX - 64];
    int lock_fd;
    const srv_job_codec *codec; /* NULL: no checkpoint or restore */
    log_file *logs;
    uint32_t nlogs, logs_cap;
    int queue_unsaved; /* the last queue file write failed */
    committer cm;
    ckpt_work ck;
    sweeper sw;
    uint64_t ckpt_log_bytes; /* test hook: checkpoint past this many bytes of log */
    uint32_t epochs;         /* the last log_file epoch given */
};

void st_ckpt_join(srv_state *st);

void st_sweep_signal(sweeper *sw);

/* Frees the records; the array stays for the next ones. */
void st_rec_clear(rec_buf *r);

void st_job_path(const srv_state *st, uint64_t id, const char *file, char *buf, size_t cap);

/* The path of a job's file (job_path) once the job's folder exists: it is
 * made, private, on the first file written to it. */
pt_status st_job_file(const srv_state *st, uint64_t id, const char *file, char *buf, size_t cap,
                      pt_error *err);

void *st_commit_main(void *arg);

/* Writes the log's records not handed to a commit, on the caller's thread
 * (no commit in flight). Returns 0, or -1 with errno: the file is cut back
 * to the records before them, which stay in memory to be written again. */
int st_write_out(log_file *l);

int st_version_read(uint32_t v);

/* Moves the job's folder to the trash, for the sweeper to remove (a rename:
 * the loop does not wait for the unlinks). Where the rename fails, the
 * folder is removed in place. */
void st_remove_job(srv_state *st, uint64_t id);

/* Writes every record to fd, in order; 0, or -1 with errno (some may be
 * written). */
int st_rec_write(int fd, const rec_buf *r);

void st_rec_fini(rec_buf *r);

/* Reads path and checks magic, version and checksum; *body and *body_len get
 * what lies between, *version (when not NULL) the format version. *missing =
 * 1 (and PT_OK) when the file does not exist. */
pt_status st_read_intact(const char *path, uint32_t magic, size_t max, uint8_t **data,
                         const uint8_t **body, size_t *body_len, uint32_t *version, int *missing,
                         pt_error *err);

/* Opens the job's log for appending, writing its header when it is new. */
pt_status st_open_log(srv_state *st, uint64_t id, log_file **out, pt_error *err);

log_file *st_find_log(const srv_state *st, uint64_t id);

/* Truncates the file to the records written (l->bytes less those still in
 * memory), dropping a partial record; l->cut says whether that is still to
 * do. Returns 0, or -1 with errno kept. */
int st_cut_back(log_file *l);

void st_close_log(srv_state *st, uint64_t id);

void st_begin_file(proto_writer *w, uint32_t magic);

pt_status st_end_file(proto_writer *w, const char *path, pt_error *err);

/* Sets *stop under mu, wakes the thread and joins it. */
void st_thread_stop(pthread_t th, pthread_mutex_t *mu, pthread_cond_t *cv, int *stop);

/* A thread of the state's own (the commit's, the sweeper's), with its mutex
 * and condition; what names it in an error. */
pt_status st_thread_start(pthread_t *th, pthread_mutex_t *mu, pthread_cond_t *cv,
                          void *(*fn)(void *), void *arg, const char *what, pt_error *err);

void *st_sweep_main(void *arg);

void st_path_of(const srv_state *st, char *buf, size_t cap, const char *rel);

#endif
