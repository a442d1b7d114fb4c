#define _GNU_SOURCE /* O_CLOEXEC, fdatasync */
#include "server/store/state.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <sys/uio.h>
#include <time.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/base/hash.h"
#include "common/render/render.h"
#include "protocol/frame.h"
#include "protocol/wire.h"

#define QUEUE_MAGIC 0x31515450u /* "PTQ1" */
#define CKPT_MAGIC 0x4b435450u  /* "PTCK" */
#define LOG_MAGIC 0x4c525450u   /* "PTRL": records of u32 length, u32 CRC32C, payload */
#define FLOG_MAGIC 0x46525450u  /* "PTRF": records are RESULT frames as received */
#define STATE_VERSION 8u
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

/* Takes p (pt_malloc'd, n > 0 bytes) as the next record; 0, or -1 out of
 * memory (p stays the caller's). */
static int rec_take(rec_buf *r, uint8_t *p, size_t n)
{
    if (r->nseg == r->cap) {
        rec_seg *g = pt_grow_array(r->seg, &r->cap, sizeof *g, 64);
        if (!g)
            return -1;
        r->seg = g;
    }
    r->seg[r->nseg++] = (rec_seg){p, n};
    r->len += n;
    return 0;
}

/* Frees the records; the array stays for the next ones. */
static void rec_clear(rec_buf *r)
{
    for (uint32_t i = 0; i < r->nseg; i++)
        pt_free(r->seg[i].p);
    r->nseg = 0;
    r->len = 0;
}

static void rec_fini(rec_buf *r)
{
    rec_clear(r);
    pt_free(r->seg);
    *r = (rec_buf){0};
}

/* Moves src's records after dst's (src is left empty); 0, or -1 out of
 * memory (both unchanged). */
static int rec_join(rec_buf *dst, rec_buf *src)
{
    if (src->nseg == 0)
        return 0;
    if (src->nseg > UINT32_MAX - dst->nseg)
        return -1;
    uint32_t need = dst->nseg + src->nseg;
    if (need > dst->cap) {
        rec_seg *g = pt_realloc(dst->seg, (size_t)need * sizeof *g);
        if (!g)
            return -1;
        dst->seg = g;
        dst->cap = need;
    }
    memcpy(dst->seg + dst->nseg, src->seg, (size_t)src->nseg * sizeof *src->seg);
    dst->nseg = need;
    dst->len += src->len;
    src->nseg = 0;
    src->len = 0;
    return 0;
}

/* Writes every record to fd, in order; 0, or -1 with errno (some may be
 * written). */
static int rec_write(int fd, const rec_buf *r)
{
    enum { IOV = 256 };
    uint32_t i = 0;
    size_t off = 0; /* into record i */
    while (i < r->nseg) {
        struct iovec iov[IOV];
        int k = 0;
        for (uint32_t j = i; j < r->nseg && k < IOV; j++, k++) {
            size_t skip = j == i ? off : 0;
            iov[k] = (struct iovec){r->seg[j].p + skip, r->seg[j].n - skip};
        }
        ssize_t w = writev(fd, iov, k);
        if (w < 0 && errno == EINTR)
            continue;
        if (w <= 0) {
            if (w == 0)
                errno = EIO;
            return -1;
        }
        for (size_t left = (size_t)w; left > 0;) {
            size_t rest = r->seg[i].n - off;
            if (left < rest) {
                off += left;
                break;
            }
            left -= rest;
            i++;
            off = 0;
        }
    }
    return 0;
}

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
    log_file *logs;
    uint32_t nlogs, logs_cap;
    int queue_unsaved; /* the last queue file write failed */
    committer cm;
    ckpt_work ck;
    sweeper sw;
    uint64_t ckpt_log_bytes; /* test hook: checkpoint past this many bytes of log */
    uint32_t epochs;         /* the last log_file epoch given */
};

const char *srv_state_dir(const srv_state *st)
{
    return st->dir;
}

static void path_of(const srv_state *st, char *buf, size_t cap, const char *rel)
{
    snprintf(buf, cap, "%s/%s", st->dir, rel);
}

static void job_path(const srv_state *st, uint64_t id, const char *file, char *buf, size_t cap)
{
    if (file)
        snprintf(buf, cap, "%s/jobs/%llu/%s", st->dir, (unsigned long long)id, file);
    else
        snprintf(buf, cap, "%s/jobs/%llu", st->dir, (unsigned long long)id);
}

/* The path of a job's file (job_path) once the job's folder exists: it is
 * made, private, on the first file written to it. */
static pt_status job_file(const srv_state *st, uint64_t id, const char *file, char *buf, size_t cap,
                          pt_error *err)
{
    job_path(st, id, NULL, buf, cap);
    pt_status s = pt_mkdirs(buf, 1, err);
    if (s == PT_OK)
        job_path(st, id, file, buf, cap);
    return s;
}

static void *commit_main(void *arg);

/* Removes everything in the trash. The renames that put it there are made
 * durable first (the jobs folder's fsync), so that a crash never brings an
 * ended job's folder back. */
static void sweep(const sweeper *sw)
{
    pt_fsync_dir(sw->jobs);
    DIR *d = opendir(sw->trash);
    if (!d)
        return;
    struct dirent *e;
    while ((e = readdir(d)) != NULL) {
        char p[PATH_MAX + 256];
        if (strcmp(e->d_name, ".") != 0 && strcmp(e->d_name, "..") != 0 &&
            (size_t)snprintf(p, sizeof p, "%s/%s", sw->trash, e->d_name) < sizeof p)
            pt_remove_tree(p);
    }
    closedir(d);
    pt_fsync_dir(sw->trash);
}

static void *sweep_main(void *arg)
{
    sweeper *sw = arg;
    pthread_mutex_lock(&sw->mu);
    for (;;) {
        while (!sw->work && !sw->stop)
            pthread_cond_wait(&sw->cv, &sw->mu);
        if (!sw->work)
            break; /* stopped, with nothing left to remove */
        sw->work = 0;
        pthread_mutex_unlock(&sw->mu);
        sweep(sw);
        pthread_mutex_lock(&sw->mu);
    }
    pthread_mutex_unlock(&sw->mu);
    return NULL;
}

static void sweep_signal(sweeper *sw)
{
    pthread_mutex_lock(&sw->mu);
    sw->work = 1;
    pthread_cond_signal(&sw->cv);
    pthread_mutex_unlock(&sw->mu);
}

/* A thread of the state's own (the commit's, the sweeper's), with its mutex
 * and condition; what names it in an error. */
static pt_status thread_start(pthread_t *th, pthread_mutex_t *mu, pthread_cond_t *cv,
                              void *(*fn)(void *), void *arg, const char *what, pt_error *err)
{
    pthread_mutex_init(mu, NULL);
    pthread_cond_init(cv, NULL);
    if (pthread_create(th, NULL, fn, arg) == 0)
        return PT_OK;
    pthread_mutex_destroy(mu);
    pthread_cond_destroy(cv);
    return pt_error_set(err, PT_ERR_IO, "cannot start the %s thread", what);
}

/* Sets *stop under mu, wakes the thread and joins it. */
static void thread_stop(pthread_t th, pthread_mutex_t *mu, pthread_cond_t *cv, int *stop)
{
    pthread_mutex_lock(mu);
    *stop = 1;
    pthread_cond_signal(cv);
    pthread_mutex_unlock(mu);
    pthread_join(th, NULL);
    pthread_mutex_destroy(mu);
    pthread_cond_destroy(cv);
}

pt_status srv_state_open(const char *dir, srv_state **out, pt_error *err)
{
    if (strlen(dir) >= sizeof((srv_state *)0)->dir)
        return pt_error_set(err, PT_ERR_ARG, "state folder %s: path too long", dir);
    srv_state *st = pt_calloc(1, sizeof *st);
    if (!st)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    snprintf(st->dir, sizeof st->dir, "%s", dir);
    st->lock_fd = -1;
    st->cm.efd = -1;
    st->cm.next = 1;
    /* Test hooks (tests/integration/test_durable.sh): hold each fdatasync of
     * a group commit until a file exists, or fail it while another exists;
     * hold a checkpoint written but not yet renamed into place until a file
     * exists; write checkpoints past a small log. Unset in production. */
    const char *e;
    if ((e = getenv("PTSERVE_TEST_COMMIT_GATE")) != NULL)
        snprintf(st->cm.gate, sizeof st->cm.gate, "%s", e);
    if ((e = getenv("PTSERVE_TEST_COMMIT_FAIL")) != NULL)
        snprintf(st->cm.fail, sizeof st->cm.fail, "%s", e);
    if ((e = getenv("PTSERVE_TEST_CKPT_GATE")) != NULL)
        snprintf(st->ck.gate, sizeof st->ck.gate, "%s", e);
    if ((e = getenv("PTSERVE_TEST_CKPT_LOG_BYTES")) != NULL)
        st->ckpt_log_bytes = strtoull(e, NULL, 10);
    char p[PATH_MAX];
    pt_status s;
    path_of(st, st->sw.jobs, sizeof st->sw.jobs, "jobs");
    path_of(st, st->sw.trash, sizeof st->sw.trash, "trash");
    if ((s = pt_mkdirs(st->sw.jobs, 1, err)) != PT_OK ||
        (s = pt_mkdirs(st->sw.trash, 1, err)) != PT_OK)
        goto fail;
    path_of(st, p, sizeof p, "lock");
    st->lock_fd = open(p, O_RDWR | O_CREAT | O_NOFOLLOW | O_CLOEXEC, 0600);
    if (st->lock_fd < 0) {
        s = pt_error_errno(err, PT_ERR_IO, "state folder %s: cannot open its lock file", dir);
        goto fail;
    }
    if (flock(st->lock_fd, LOCK_EX | LOCK_NB) != 0) {
        s = pt_error_errno(err, PT_ERR_IO, "state folder %s is in use by another ptserve", dir);
        goto fail;
    }
    st->cm.efd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    if (st->cm.efd < 0) {
        s = pt_error_errno(err, PT_ERR_IO, "eventfd");
        goto fail;
    }
    if ((s = thread_start(&st->cm.th, &st->cm.mu, &st->cm.cv, commit_main, &st->cm, "commit",
                          err)) != PT_OK)
        goto fail;
    st->cm.started = 1;
    st->sw.work = 1; /* the sweeper starts with what a crash left in the trash */
    if ((s = thread_start(&st->sw.th, &st->sw.mu, &st->sw.cv, sweep_main, &st->sw, "sweeper",
                          err)) != PT_OK)
        goto fail;
    st->sw.started = 1;
    *out = st;
    return PT_OK;
fail:
    srv_state_close(st);
    return s;
}

static void ckpt_join(srv_state *st);
static int cut_back(log_file *l);

/* Writes the log's records not handed to a commit, on the caller's thread
 * (no commit in flight). Returns 0, or -1 with errno: the file is cut back
 * to the records before them, which stay in memory to be written again. */
static int write_out(log_file *l)
{
    if (l->out.len == 0)
        return 0;
    if (rec_write(l->fd, &l->out) == 0) {
        rec_clear(&l->out);
        return 0;
    }
    int e = errno;
    cut_back(l);
    errno = e;
    return -1;
}

void srv_state_close(srv_state *st)
{
    if (!st)
        return;
    ckpt_join(st);
    if (st->cm.started)
        thread_stop(st->cm.th, &st->cm.mu, &st->cm.cv, &st->cm.stop);
    if (st->sw.started) /* after the checkpoint's: it may have ended a job */
        thread_stop(st->sw.th, &st->sw.mu, &st->sw.cv, &st->sw.stop);
    for (uint32_t i = 0; i < st->cm.cap; i++)
        rec_fini(&st->cm.items[i].in);
    pt_free(st->cm.items);
    if (st->cm.efd >= 0)
        close(st->cm.efd);
    for (uint32_t i = 0; i < st->nlogs; i++) {
        log_file *l = &st->logs[i];
        if (l->fd >= 0) {
            /* Records not merged yet: a restart replays them. */
            if (write_out(l) == 0)
                fdatasync(l->fd);
            close(l->fd);
        }
        rec_fini(&l->out);
    }
    pt_free(st->logs);
    if (st->lock_fd >= 0)
        close(st->lock_fd);
    pt_free(st);
}

/* ---- common: a whole file with magic, version, body, CRC32C ---------------------- */

static void begin_file(proto_writer *w, uint32_t magic)
{
    proto_w_u32(w, magic);
    proto_w_u32(w, STATE_VERSION);
}

static pt_status end_file(proto_writer *w, const char *path, pt_error *err)
{
    if (proto_writer_status(w) != PT_OK)
        return pt_error_set(err, proto_writer_status(w), "%s: cannot serialise", path);
    proto_w_u32(w, proto_crc32c(0, w->buf, w->len));
    if (proto_writer_status(w) != PT_OK)
        return pt_error_set(err, proto_writer_status(w), "%s: cannot serialise", path);
    return pt_write_file_atomic(path, w->buf, w->len, err);
}

static int version_read(uint32_t v)
{
    return v >= STATE_OLDEST_VERSION && v <= STATE_VERSION;
}

/* Reads path and checks magic, version and checksum; *body and *body_len get
 * what lies between, *version (when not NULL) the format version. *missing =
 * 1 (and PT_OK) when the file does not exist. */
static pt_status read_intact(const char *path, uint32_t magic, size_t max, uint8_t **data,
                             const uint8_t **body, size_t *body_len, uint32_t *version,
                             int *missing, pt_error *err)
{
    size_t len;
    *missing = 0;
    *data = NULL;
    pt_status s = pt_read_file(path, max, data, &len, err);
    if (s != PT_OK) {
        if (s == PT_ERR_IO && err && err->sys_errno == ENOENT) {
            *missing = 1;
            return PT_OK;
        }
        return s;
    }
    const char *why = NULL;
    char vwhy[128];
    if (len < 12)
        why = "truncated (shorter than its header and checksum)";
    else if (proto_get_u32(*data) != magic)
        why = "not a ptserve state file of this kind (bad magic)";
    else if (!version_read(proto_get_u32(*data + 4))) {
        snprintf(vwhy, sizeof vwhy,
                 "written by another version of ptserve (format %u; this "
                 "one reads %u to %u)",
                 proto_get_u32(*data + 4), STATE_OLDEST_VERSION, STATE_VERSION);
        why = vwhy;
    } else if (proto_crc32c(0, *data, len - 4) != proto_get_u32(*data + len - 4))
        why = "checksum mismatch: the file is truncated or damaged";
    if (why) {
        pt_free(*data);
        *data = NULL;
        return pt_error_set(err, PT_ERR_FORMAT,
                            "%s: %s; refusing to use it (move it aside to "
                            "start without it)",
                            path, why);
    }
    if (version)
        *version = proto_get_u32(*data + 4);
    *body = *data + 8;
    *body_len = len - 12;
    return PT_OK;
}

/* ---- the queue --------------------------------------------------------------------- */

pt_status srv_state_save_queue(srv_state *st, srv_job_record *const *recs, uint32_t n,
                               uint64_t next_id, pt_error *err)
{
    char path[PATH_MAX];
    path_of(st, path, sizeof path, "queue");
    proto_writer w;
    proto_writer_init(&w, MAX_QUEUE_BYTES);
    begin_file(&w, QUEUE_MAGIC);
    proto_w_u64(&w, next_id);
    proto_w_u32(&w, n);
    for (uint32_t i = 0; i < n; i++) {
        const srv_job_record *j = recs[i];
        proto_w_u64(&w, j->id);
        proto_w_u64(&w, j->seq);
        proto_w_u8(&w, j->state);
        proto_w_u32(&w, (uint32_t)j->priority);
        proto_w_str(&w, j->name);
        proto_w_str(&w, j->owner);
        proto_w_str(&w, j->scene);
        proto_w_str(&w, j->output);
        proto_w_u64(&w, j->submitted);
        srv_job_params_write(&w, &j->params);
        proto_w_bytes(&w, j->hash, 32);
        proto_w_u64(&w, j->bundle_size);
        proto_w_u64(&w, j->samples_done);
        proto_w_f64(&w, j->seconds);
        proto_w_f64(&w, j->error);
        proto_w_str(&w, j->message);
        proto_w_u64(&w, j->capped);
        proto_w_u64(&w, j->rejected);
        proto_w_u32(&w, j->frames.first);
        proto_w_u32(&w, j->frames.last);
        proto_w_u32(&w, j->frames.step);
        proto_w_f64(&w, j->fps);
        proto_w_str(&w, j->animation);
        proto_w_u32(&w, j->frames_done);
        proto_w_u8(&w, (uint8_t)j->ndone_ahead);
        for (uint32_t k = 0; k < j->ndone_ahead; k++)
            proto_w_u32(&w, j->done_ahead[k]);
    }
    pt_status s = end_file(&w, path, err);
    proto_writer_fini(&w);
    st->queue_unsaved = s != PT_OK;
    return s;
}

int srv_state_queue_unsaved(const srv_state *st)
{
    return st->queue_unsaved;
}

/* A record's frame range, pose and frames done; what does not check out
 * fails r. */
static void read_frames(proto_reader *r, srv_job_record *j)
{
    j->frames.first = proto_r_u32(r, "first frame");
    j->frames.last = proto_r_u32(r, "last frame");
    j->frames.step = proto_r_u32(r, "frame step");
    j->fps = proto_r_f64(r, "frames per second");
    proto_r_str(r, j->animation, sizeof j->animation - 1, "animation");
    j->frames_done = proto_r_u32(r, "frames done");
    j->ndone_ahead = proto_r_u8(r, "frames done ahead");
    if (r->status != PT_OK)
        return;
    uint32_t count = pt_frames_count(&j->frames);
    if (pt_frames_check(&j->frames, NULL) != PT_OK || j->frames_done > count ||
        j->ndone_ahead > SRV_FRAMES_AHEAD || (j->frames.step && !(j->fps > 0.0 && j->fps < 1e9))) {
        proto_r_fail(r, PT_ERR_FORMAT, "bad", "frame range or frames done");
        return;
    }
    for (uint32_t k = 0; k < j->ndone_ahead && r->status == PT_OK; k++) {
        j->done_ahead[k] = proto_r_u32(r, "frame done ahead");
        if (r->status == PT_OK && (j->done_ahead[k] <= j->frames_done || j->done_ahead[k] >= count))
            proto_r_fail(r, PT_ERR_FORMAT, "bad", "frame done ahead");
    }
}

pt_status srv_state_load_queue(srv_state *st, srv_job_record **recs, uint32_t *n, uint64_t *next_id,
                               pt_error *err)
{
    char path[PATH_MAX];
    path_of(st, path, sizeof path, "queue");
    uint8_t *data;
    const uint8_t *body;
    size_t len;
    uint32_t version;
    int missing;
    *recs = NULL;
    *n = 0;
    *next_id = 1;
    pt_status s = read_intact(path, QUEUE_MAGIC, MAX_QUEUE_BYTES, &data, &body, &len, &version,
                              &missing, err);
    if (s != PT_OK || missing)
        return s;
    proto_reader r = proto_reader_make(body, len);
    uint64_t nid = proto_r_u64(&r, "next job id");
    uint32_t count = proto_r_u32(&r, "job count");
    srv_job_record *out = NULL;
    if (r.status == PT_OK && (count > SRV_MAX_JOBS || count > proto_r_left(&r) / 64)) {
        pt_free(data);
        return pt_error_set(err, PT_ERR_FORMAT, "%s: %u jobs do not fit its %zu bytes", path, count,
                            len);
    }
    if (count) {
        out = pt_calloc(count, sizeof *out);
        if (!out) {
            pt_free(data);
            return pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory", path);
        }
    }
    for (uint32_t i = 0; i < count && r.status == PT_OK; i++) {
        srv_job_record *j = &out[i];
        j->id = proto_r_u64(&r, "job id");
        j->seq = proto_r_u64(&r, "job seq");
        j->state = proto_r_u8(&r, "job state");
        j->priority = (int32_t)proto_r_u32(&r, "priority");
        proto_r_str(&r, j->name, sizeof j->name - 1, "name");
        proto_r_str(&r, j->owner, sizeof j->owner - 1, "owner");
        proto_r_str(&r, j->scene, sizeof j->scene - 1, "scene");
        proto_r_str(&r, j->output, sizeof j->output - 1, "output");
        j->submitted = proto_r_u64(&r, "submitted");
        srv_job_params_read(&r, &j->params, version >= STATE_MIN_GAIN_VERSION,
                            version >= STATE_ENV_VERSION, version >= STATE_SHUTTER_VERSION);
        const uint8_t *h = proto_r_bytes(&r, 32, "scene hash");
        if (h)
            memcpy(j->hash, h, 32);
        j->bundle_size = proto_r_u64(&r, "bundle size");
        j->samples_done = proto_r_u64(&r, "samples done");
        j->seconds = proto_r_f64(&r, "seconds");
        j->error = proto_r_f64(&r, "error");
        proto_r_str(&r, j->message, sizeof j->message - 1, "message");
        j->capped = version >= STATE_FILM_VERSION ? proto_r_u64(&r, "paths capped") : 0;
        j->rejected = version >= STATE_REJECTED_VERSION ? proto_r_u64(&r, "samples rejected") : 0;
        if (version >= STATE_FRAMES_VERSION)
            read_frames(&r, j);
        if (r.status == PT_OK && (j->id == 0 || j->id >= nid || j->state < PROTO_JOB_QUEUED ||
                                  j->state > PROTO_JOB_FAILED))
            proto_r_fail(&r, PT_ERR_FORMAT, "bad", "job id or state");
    }
    pt_error e2 = {0};
    s = proto_r_finish(&r, "queue", &e2);
    pt_free(data);
    if (s != PT_OK) {
        pt_free(out);
        return pt_error_set(err, PT_ERR_FORMAT, "%s: %s; refusing to use it", path, e2.msg);
    }
    *recs = out;
    *n = count;
    *next_id = nid;
    return PT_OK;
}

/* ---- bundles ----------------------------------------------------------------------- */

pt_status srv_state_save_bundle(const srv_state *st, uint64_t id, const uint8_t *data, size_t n,
                                pt_error *err)
{
    char p[PATH_MAX];
    pt_status s = job_file(st, id, "bundle", p, sizeof p, err);
    if (s != PT_OK)
        return s;
    return pt_write_file_atomic(p, data, n, err);
}

pt_status srv_state_load_bundle(srv_state *st, uint64_t id, const uint8_t hash[32], pt_bundle **out,
                                pt_error *err)
{
    char p[PATH_MAX];
    job_path(st, id, "bundle", p, sizeof p);
    uint8_t *data;
    size_t len;
    pt_status s = pt_read_file(p, PT_BUNDLE_MAX_BYTES, &data, &len, err);
    if (s != PT_OK)
        return s;
    char hex[65], want[65];
    pt_sha256_hex(data, len, hex);
    pt_hash_hex(hash, want);
    if (strcmp(hex, want) != 0) {
        pt_free(data);
        return pt_error_set(err, PT_ERR_FORMAT,
                            "%s: SHA-256 %.16s... differs from the queue's "
                            "%.16s...: the file is damaged",
                            p, hex, want);
    }
    s = pt_bundle_from_bytes(data, len, out, err);
    pt_free(data);
    return s;
}

/* ---- logs -------------------------------------------------------------------------- */

static log_file *find_log(const srv_state *st, uint64_t id)
{
    for (uint32_t i = 0; i < st->nlogs; i++)
        if (st->logs[i].id == id)
            return &st->logs[i];
    return NULL;
}

static void close_log(srv_state *st, uint64_t id)
{
    log_file *l = find_log(st, id);
    if (!l)
        return;
    if (l->fd >= 0)
        close(l->fd);
    rec_fini(&l->out);
    *l = st->logs[--st->nlogs];
}

/* Writes a new log's header (fd empty); its durability is left to the next
 * group commit (the file is then marked fresh). */
static int write_header(int fd, uint64_t id)
{
    uint8_t h[LOG_HEADER];
    proto_put_u32(h, FLOG_MAGIC);
    proto_put_u32(h + 4, STATE_VERSION);
    proto_put_u64(h + 8, id);
    return pt_write_all(fd, h, sizeof h);
}

/* Opens the job's log for appending, writing its header when it is new. */
static pt_status open_log(srv_state *st, uint64_t id, log_file **out, pt_error *err)
{
    log_file *l = find_log(st, id);
    if (l) {
        *out = l;
        return PT_OK;
    }
    if (st->nlogs == st->logs_cap) {
        log_file *n = pt_grow_array(st->logs, &st->logs_cap, sizeof *n, 8);
        if (!n)
            return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
        st->logs = n;
    }
    char p[PATH_MAX];
    /* The folder is made here too: a frame of a frame-range job has no
     * bundle of its own, so its first file may be its log. */
    pt_status ms = job_file(st, id, "results.log", p, sizeof p, err);
    if (ms != PT_OK)
        return ms;
    int fd = open(p, O_RDWR | O_CREAT | O_APPEND | O_NOFOLLOW | O_CLOEXEC, 0600);
    if (fd < 0)
        return pt_error_errno(err, PT_ERR_IO, "%s", p);
    struct stat sb;
    if (fstat(fd, &sb) != 0) {
        close(fd);
        return pt_error_errno(err, PT_ERR_IO, "%s", p);
    }
    uint64_t bytes = (uint64_t)sb.st_size;
    if (bytes > 0 && bytes < LOG_HEADER && ftruncate(fd, 0) == 0)
        bytes = 0; /* a header a full disk cut short: the log held nothing */
    if (bytes > 0 && bytes < LOG_HEADER) {
        pt_status s = pt_error_errno(err, PT_ERR_IO, "%s: cannot cut its partial header", p);
        close(fd);
        return s;
    }
    uint8_t h[4];
    if (bytes >= LOG_HEADER && (pread(fd, h, 4, 0) != 4 || proto_get_u32(h) != FLOG_MAGIC)) {
        /* A log of records (an older ptserve's) is rewritten in frames when
         * it is replayed (srv_state_restore); never appended to. */
        close(fd);
        return pt_error_set(err, PT_ERR_FORMAT, "%s: not a results log of frames", p);
    }
    int fresh = 0;
    if (bytes == 0) {
        if (write_header(fd, id) != 0) {
            pt_status s = pt_error_errno(err, PT_ERR_IO, "%s: cannot write its header", p);
            /* Records must not follow a header cut short: leave the log empty
             * (it holds nothing yet) for the next try. Should that fail too,
             * the next open finds a short file and refuses it (above). */
            int cut = ftruncate(fd, 0);
            (void)cut;
            close(fd);
            return s;
        }
        bytes = LOG_HEADER;
        fresh = 1;
    }
    l = &st->logs[st->nlogs++];
    *l = (log_file){id, fd, bytes, bytes, ++st->epochs, fresh, 0, fresh, {NULL, 0, 0, 0}};
    *out = l;
    return PT_OK;
}

/* Truncates the file to the records written (l->bytes less those still in
 * memory), dropping a partial record; l->cut says whether that is still to
 * do. Returns 0, or -1 with errno kept. */
static int cut_back(log_file *l)
{
    int saved = errno;
    l->cut = 1;
    if (ftruncate(l->fd, (off_t)(l->bytes - l->out.len)) != 0)
        return -1;
    l->cut = 0;
    errno = saved;
    return 0;
}

/* A record the log cannot take: empty, or no memory for it. */
static pt_status record_refused(uint64_t id, size_t len, pt_error *err)
{
    return pt_error_set(err, len ? PT_ERR_NOMEM : PT_ERR_ARG, "results log of job %llu: %s",
                        (unsigned long long)id, len ? "out of memory" : "an empty record");
}

pt_status srv_state_log_result_take(srv_state *st, uint64_t id, uint8_t **frame, size_t len,
                                    pt_error *err)
{
    log_file *l;
    pt_status s = open_log(st, id, &l, err);
    if (s != PT_OK)
        return s;
    /* A write cut short (a full disk, a quota) leaves part of a record at the
     * end; the next record would follow it and the log would read as damaged
     * in its middle. So the log is cut back to its last whole record before
     * anything else is appended, and stays unwritten while that fails. */
    if (l->cut && cut_back(l) != 0)
        return pt_error_errno(
            err, PT_ERR_IO, "results log of job %llu: cannot cut it back to its last whole record",
            (unsigned long long)id);
    /* Kept in memory for the commit thread, which writes it before the
     * fdatasync: a write() of every record on the loop cost more than half
     * its time in queue mode (the copy into the page cache). A kill -9 loses
     * only records not durable, which were never merged. The frame's own
     * CRC32C, checked when it arrived, is the record's checksum. */
    if (len == 0 || rec_take(&l->out, *frame, len) != 0)
        return record_refused(id, len, err);
    *frame = NULL;
    l->bytes += len;
    l->dirty = 1;
    return PT_OK;
}

pt_status srv_state_log_result(srv_state *st, uint64_t id, const uint8_t *frame, size_t len,
                               pt_error *err)
{
    uint8_t *copy = len ? pt_malloc(len) : NULL;
    if (!copy)
        return record_refused(id, len, err);
    memcpy(copy, frame, len);
    pt_status s = srv_state_log_result_take(st, id, &copy, len, err);
    pt_free(copy); /* NULL once taken */
    return s;
}

uint64_t srv_state_unsynced(const srv_state *st)
{
    uint64_t n = 0;
    for (uint32_t i = 0; i < st->nlogs; i++)
        n += st->logs[i].bytes - st->logs[i].durable;
    return n;
}

uint64_t srv_state_log_bytes(const srv_state *st, uint64_t id)
{
    const log_file *l = find_log(st, id);
    return l ? l->bytes : 0;
}

uint64_t srv_state_ckpt_limit(const srv_state *st, uint64_t film_bytes)
{
    if (st->ckpt_log_bytes)
        return st->ckpt_log_bytes;
    uint64_t limit = SRV_CKPT_FILM_MULTIPLE * film_bytes;
    return limit > SRV_CKPT_MIN_LOG ? limit : SRV_CKPT_MIN_LOG;
}

/* ---- the group commit -------------------------------------------------------------- */

static void *commit_main(void *arg)
{
    committer *cm = arg;
    long ps = sysconf(_SC_PAGESIZE);
    uint64_t page = ps > 0 ? (uint64_t)ps : 4096u;
    pthread_mutex_lock(&cm->mu);
    for (;;) {
        while (!cm->has_req && !cm->stop)
            pthread_cond_wait(&cm->cv, &cm->mu);
        if (!cm->has_req)
            break;
        pthread_mutex_unlock(&cm->mu);
        for (uint32_t i = 0; i < cm->n; i++) {
            commit_item *it = &cm->items[i];
            it->err = 0;
            it->step = "write";
            if (rec_write(it->fd, &it->in) != 0)
                it->err = errno ? errno : EIO;
            if (!it->err) {
                pt_wait_for_file(cm->gate);
                it->step = "fdatasync";
                if (cm->fail[0] && access(cm->fail, F_OK) == 0)
                    it->err = EIO;
                else if (fdatasync(it->fd) != 0 || (it->fresh && pt_fsync_dir_of(it->path) != 0))
                    it->err = errno ? errno : EIO;
            }
            if (!it->err) {
                rec_clear(&it->in); /* durable: off the loop's time */
                /* Its pages are read again only by a restart's replay (from
                 * the disk): dropped now, clean, rather than when the log is
                 * cut at a checkpoint or removed with its job, on the loop
                 * (a 500 MB log's pages were 3 % of a 1,024-spp job's loop
                 * time in queue mode). Whole pages only: the next record
                 * goes on in the last one. Advice: a failure changes nothing. */
                off_t whole = (off_t)(it->upto / page * page);
                if (whole > 0)
                    posix_fadvise(it->fd, 0, whole, POSIX_FADV_DONTNEED);
            }
            close(it->fd);
            it->fd = -1;
        }
        pthread_mutex_lock(&cm->mu);
        cm->has_req = 0;
        cm->ready = 1;
        pthread_cond_broadcast(&cm->cv);
        uint64_t one = 1;
        ssize_t w = write(cm->efd, &one, sizeof one);
        (void)w;
    }
    pthread_mutex_unlock(&cm->mu);
    return NULL;
}

int srv_state_commit_fd(const srv_state *st)
{
    return st->cm.efd;
}

uint64_t srv_state_commit_next(const srv_state *st)
{
    return st->cm.next;
}

int srv_state_commit_start(srv_state *st)
{
    committer *cm = &st->cm;
    if (cm->busy)
        return 0;
    uint32_t n = 0;
    for (uint32_t i = 0; i < st->nlogs; i++)
        n += st->logs[i].dirty;
    if (n == 0)
        return 0;
    if (n > cm->cap) {
        commit_item *items = pt_realloc(cm->items, n * sizeof *items);
        if (!items)
            return 0; /* tried again next round */
        memset(items + cm->cap, 0, (n - cm->cap) * sizeof *items);
        cm->items = items;
        cm->cap = n;
    }
    uint32_t k = 0;
    for (uint32_t i = 0; i < st->nlogs; i++) {
        log_file *l = &st->logs[i];
        if (!l->dirty)
            continue;
        commit_item *it = &cm->items[k];
        /* A dup, so that the log may be closed (its job ended) meanwhile. */
        it->fd = fcntl(l->fd, F_DUPFD_CLOEXEC, 0);
        if (it->fd < 0)
            continue; /* stays dirty: tried again next round */
        it->id = l->id;
        it->upto = l->bytes;
        it->epoch = l->epoch;
        it->fresh = l->fresh;
        it->err = 0;
        /* The log's records go to the thread; the item's emptied buffer
         * (from an earlier commit) takes the next ones. */
        rec_buf spare = it->in;
        it->in = l->out;
        l->out = spare;
        if (l->fresh)
            job_path(st, l->id, "results.log", it->path, sizeof it->path);
        l->dirty = 0;
        l->fresh = 0;
        k++;
    }
    if (k == 0)
        return 0;
    cm->n = k;
    cm->gen = cm->next++;
    cm->busy = 1;
    pthread_mutex_lock(&cm->mu);
    cm->has_req = 1;
    pthread_cond_broadcast(&cm->cv);
    pthread_mutex_unlock(&cm->mu);
    return 1;
}

int srv_state_commit_busy(const srv_state *st)
{
    return st->cm.busy;
}

int srv_state_commit_collect(srv_state *st, int wait, uint64_t *done, srv_commit_fn fn, void *ctx)
{
    committer *cm = &st->cm;
    uint64_t v;
    ssize_t r = read(cm->efd, &v, sizeof v); /* the wake-up; the flag below says */
    (void)r;
    if (!cm->busy)
        return 0;
    pthread_mutex_lock(&cm->mu);
    while (wait && !cm->ready)
        pthread_cond_wait(&cm->cv, &cm->mu);
    int ready = cm->ready;
    cm->ready = 0;
    pthread_mutex_unlock(&cm->mu);
    if (!ready)
        return 0;
    cm->busy = 0;
    for (uint32_t i = 0; i < cm->n; i++) {
        commit_item *it = &cm->items[i];
        log_file *l = find_log(st, it->id);
        int current = l && l->epoch == it->epoch;
        if (current && it->err == 0 && it->upto > l->durable)
            l->durable = it->upto;
        pt_status outcome = it->err ? PT_ERR_IO : PT_OK;
        if (current && it->err != 0) {
            /* A write cut short, or a failed fdatasync, which may have dropped
             * any page written since the last good one (and a later one would
             * not say so): the file is cut back to what is known durable. The
             * batch's records go back in front of those logged since, to be
             * written again once srv_state_log_resync says to (not at once: a
             * full disk would make that a busy loop). Only when memory for
             * that is short are they dropped (PT_ERR_NOMEM: never merged). */
            if (rec_join(&it->in, &l->out) == 0) {
                rec_buf failed = it->in;
                it->in = l->out;
                l->out = failed;
            } else {
                l->bytes = l->durable;
                rec_clear(&l->out);
                outcome = PT_ERR_NOMEM;
            }
            cut_back(l);
            l->dirty = 0;
            l->fresh |= it->fresh;
        }
        rec_clear(&it->in);
        if (fn && current) {
            pt_error e = {0};
            if (it->err) {
                errno = it->err;
                pt_error_errno(&e, PT_ERR_IO, "results log of job %llu: %s",
                               (unsigned long long)it->id, it->step);
            }
            fn(ctx, it->id, outcome, &e);
        }
    }
    *done = cm->gen;
    return 1;
}

pt_status srv_state_sync(srv_state *st, pt_error *err)
{
    /* The batch in flight first (its outcome is left for the collect). */
    pthread_mutex_lock(&st->cm.mu);
    while (st->cm.has_req)
        pthread_cond_wait(&st->cm.cv, &st->cm.mu);
    pthread_mutex_unlock(&st->cm.mu);
    pt_status s = PT_OK;
    for (uint32_t i = 0; i < st->nlogs; i++) {
        log_file *l = &st->logs[i];
        if (!l->dirty)
            continue;
        /* A commit that failed and is not collected yet: its log is cut
         * back when it is, and nothing is written after its torn end. */
        int failed = 0;
        for (uint32_t k = 0; st->cm.busy && k < st->cm.n; k++)
            failed |= st->cm.items[k].id == l->id && st->cm.items[k].epoch == l->epoch &&
                      st->cm.items[k].err != 0;
        char p[PATH_MAX];
        job_path(st, l->id, "results.log", p, sizeof p);
        if (failed) {
            if (s == PT_OK)
                s = pt_error_set(err, PT_ERR_IO, "results log of job %llu: its commit failed",
                                 (unsigned long long)l->id);
            continue;
        }
        if (write_out(l) != 0 || fdatasync(l->fd) != 0 || (l->fresh && pt_fsync_dir_of(p) != 0)) {
            if (s == PT_OK)
                s = pt_error_errno(err, PT_ERR_IO, "results log of job %llu: fdatasync",
                                   (unsigned long long)l->id);
            continue;
        }
        l->durable = l->bytes;
        l->dirty = l->fresh = 0;
    }
    return s;
}

pt_status srv_state_log_resync(srv_state *st, uint64_t id, pt_error *err)
{
    log_file *l = find_log(st, id);
    if (!l)
        return PT_OK;
    if (l->cut && cut_back(l) != 0)
        return pt_error_errno(
            err, PT_ERR_IO, "results log of job %llu: cannot cut it back to its last whole record",
            (unsigned long long)id);
    l->dirty = 1;
    return PT_OK;
}

/* Moves the job's folder to the trash, for the sweeper to remove (a rename:
 * the loop does not wait for the unlinks). Where the rename fails, the
 * folder is removed in place. */
static void remove_job(srv_state *st, uint64_t id)
{
    char p[PATH_MAX], t[PATH_MAX + 32];
    job_path(st, id, NULL, p, sizeof p);
    snprintf(t, sizeof t, "%s/%llu", st->sw.trash, (unsigned long long)id);
    if (rename(p, t) == 0) {
        sweep_signal(&st->sw);
    } else if (errno != ENOENT) {
        pt_remove_tree(p);
        pt_fsync_dir_of(p);
    }
}

void srv_state_forget_job(srv_state *st, uint64_t id)
{
    close_log(st, id);
    if (st->ck.running && st->ck.id == id) {
        /* Its checkpoint is being written into the folder: the folder goes
         * when that is done (srv_state_checkpoint_collect), not under it. */
        st->ck.forget = 1;
        return;
    }
    remove_job(st, id);
}

/* ---- checkpoints ------------------------------------------------------------------- */

/* Serialises job into a checkpoint file at path, durably: a temporary file
 * beside it, renamed into place (gate: a test hook, waited for between). */
static pt_status write_ckpt(const char *path, const srv_job *job, const srv_ckpt_extra *x,
                            const char *gate, pt_error *err)
{
    proto_writer w;
    proto_writer_init(&w, MAX_CKPT_BYTES);
    begin_file(&w, CKPT_MAGIC);
    proto_w_f64(&w, x->seconds);
    proto_w_u64(&w, x->rejected);
    proto_w_u64(&w, x->rays);
    pt_status s = srv_job_save(job, &w, err);
    if (s == PT_OK && proto_writer_status(&w) == PT_OK)
        proto_w_u32(&w, proto_crc32c(0, w.buf, w.len));
    if (s == PT_OK && proto_writer_status(&w) != PT_OK)
        s = pt_error_set(err, proto_writer_status(&w), "%s: cannot serialise", path);
    pt_temp t;
    if (s == PT_OK && (s = pt_temp_open(path, 0644, &t, err)) == PT_OK) {
        if (pt_write_all(t.fd, w.buf, w.len) != 0) {
            s = pt_error_errno(err, PT_ERR_IO, "%s: write", path);
            pt_temp_abort(&t);
        } else {
            pt_wait_for_file(gate);
            s = pt_temp_commit(&t, path, err);
        }
    }
    proto_writer_fini(&w);
    return s;
}

/* Cuts the job's open log to its header (everything it held is in a
 * checkpoint now). */
static pt_status log_restart(srv_state *st, uint64_t id, pt_error *err)
{
    log_file *l = find_log(st, id);
    if (!l)
        return PT_OK;
    if (ftruncate(l->fd, LOG_HEADER) != 0 || fdatasync(l->fd) != 0)
        return pt_error_errno(err, PT_ERR_IO, "results log of job %llu: truncate",
                              (unsigned long long)id);
    l->bytes = l->durable = LOG_HEADER;
    rec_clear(&l->out);
    l->epoch = ++st->epochs;
    l->dirty = 0;
    l->cut = 0;
    return PT_OK;
}

pt_status srv_state_checkpoint(srv_state *st, const srv_job *job, const srv_ckpt_extra *x,
                               pt_error *err)
{
    uint64_t id = srv_job_id(job);
    if (st->ck.running)
        ckpt_join(st); /* its older snapshot must not land after this one */
    char p[PATH_MAX], old[PATH_MAX];
    pt_status s = job_file(st, id, "checkpoint", p, sizeof p, err);
    if (s != PT_OK)
        return s;
    pthread_mutex_lock(&st->cm.mu); /* no fdatasync of the log during the truncate */
    while (st->cm.has_req)
        pthread_cond_wait(&st->cm.cv, &st->cm.mu);
    pthread_mutex_unlock(&st->cm.mu);
    if ((s = write_ckpt(p, job, x, "", err)) != PT_OK)
        return s;
    /* Everything the logs held is in the checkpoint now: start afresh. */
    job_path(st, id, "results.old", old, sizeof old);
    if (unlink(old) != 0 && errno != ENOENT)
        return pt_error_errno(err, PT_ERR_IO, "%s", old);
    return log_restart(st, id, err);
}

static void *ckpt_main(void *arg)
{
    ckpt_work *ck = arg;
    ck->status = write_ckpt(ck->path, ck->snap, &ck->x, ck->gate, &ck->err);
    /* The records of the rotated log are in the checkpoint now. Should the
     * unlink not reach the disk, a restart replays them again: harmless. */
    if (ck->status == PT_OK && unlink(ck->old) != 0 && errno != ENOENT)
        ck->status = pt_error_errno(&ck->err, PT_ERR_IO, "%s", ck->old);
    atomic_store(&ck->done, 1);
    return NULL;
}

static void ckpt_join(srv_state *st)
{
    if (!st->ck.running)
        return;
    pthread_join(st->ck.th, NULL);
    st->ck.running = 0;
    srv_job_free(st->ck.snap);
    st->ck.snap = NULL;
    if (st->ck.forget)
        remove_job(st, st->ck.id);
    st->ck.forget = 0;
}

int srv_state_checkpoint_busy(const srv_state *st)
{
    return st->ck.running;
}

pt_status srv_state_checkpoint_start(srv_state *st, srv_job *snap, const srv_ckpt_extra *x,
                                     pt_error *err)
{
    ckpt_work *ck = &st->ck;
    uint64_t id = srv_job_id(snap);
    pt_status s;
    if (ck->running) {
        srv_job_free(snap);
        return pt_error_set(err, PT_AGAIN, "a checkpoint is being written");
    }
    char cur[PATH_MAX];
    if ((s = job_file(st, id, "checkpoint", ck->path, sizeof ck->path, err)) != PT_OK) {
        srv_job_free(snap);
        return s;
    }
    job_path(st, id, "results.old", ck->old, sizeof ck->old);
    job_path(st, id, "results.log", cur, sizeof cur);
    /* An older rotated log still here means the checkpoint that was to
     * replace it failed: its records are not all in a checkpoint yet, so the
     * current log is not rotated over it; this checkpoint, when written,
     * holds both, and both go. */
    struct stat sb;
    int keep_old = lstat(ck->old, &sb) == 0;
    log_file *l = find_log(st, id);
    if (l && !keep_old) {
        /* The current log becomes results.old until the checkpoint that
         * holds its records is durable; records go to a fresh log meanwhile
         * (its header and folder entry are synced by the next group commit,
         * before any of its records is merged). */
        if (rename(cur, ck->old) != 0) {
            srv_job_free(snap);
            return pt_error_errno(err, PT_ERR_IO, "%s: rename", cur);
        }
        close_log(st, id);
        /* Should the new log not open, the next result's write tries again. */
        pt_error e2 = {0};
        (void)open_log(st, id, &l, &e2);
    }
    /* With keep_old, both stay until this checkpoint is durable: the thread
     * then takes results.old away, and the log's records stay (replayed as
     * duplicates at worst). */
    ck->id = id;
    ck->snap = snap;
    ck->x = *x;
    ck->status = PT_OK;
    ck->forget = 0;
    memset(&ck->err, 0, sizeof ck->err);
    atomic_store(&ck->done, 0);
    if (pthread_create(&ck->th, NULL, ckpt_main, ck) != 0) {
        ck->snap = NULL;
        srv_job_free(snap);
        return pt_error_set(err, PT_ERR_IO, "cannot start the checkpoint thread");
    }
    ck->running = 1;
    return PT_OK;
}

int srv_state_checkpoint_collect(srv_state *st, uint64_t *id, pt_status *status, pt_error *err)
{
    ckpt_work *ck = &st->ck;
    if (!ck->running || !atomic_load(&ck->done))
        return 0;
    ckpt_join(st);
    *id = ck->id;
    *status = ck->status;
    if (ck->status != PT_OK && err)
        *err = ck->err;
    return 1;
}

/* A RESULT payload of protocol 2 (a log before STATE_FILM_VERSION: 60 bytes
 * of header, 36 per pixel) in protocol 3's layout (msg.h) into out, which
 * holds the largest RESULT: no paths capped (not counted then), every sample a
 * camera hit (those jobs are not transparent). Returns its length, or 0 when
 * pl is not of that shape (the decoder then names the fault). */
static size_t log_upgrade_record(const uint8_t *pl, size_t n, uint8_t *out)
{
    if (n < 60 || (n - 60) % 36 != 0 || (n - 60) / 36 > PROTO_MAX_TILE_PIXELS)
        return 0;
    size_t npx = (n - 60) / 36;
    memcpy(out, pl, 56);
    proto_put_u64(out + 56, 0);
    memcpy(out + 64, pl + 56, 4);
    for (size_t i = 0; i < npx; i++) {
        uint8_t *q = out + 68 + i * 40;
        memcpy(q, pl + 60 + i * 36, 36);
        memcpy(q + 36, pl + 60 + i * 36 + 32, 4);
    }
    return 68 + npx * 40;
}

/* A RESULT payload of protocol 3 (68 bytes of header, 40 per pixel with
 * double sums) in protocol 4's layout (msg.h), written into w (reset first);
 * px is scratch for PROTO_MAX_TILE_PIXELS pixels. Each double sum becomes
 * fixed point by the rounding a block's sum gets (pt_fixed_of): the same
 * bits on every coordinator, so resuming from an old log loses no work.
 * Returns the length, or 0 when pl is not of that shape or a sum is not one a
 * render gives (not finite, negative, above the cap), and the decoder then
 * names the fault. */
static size_t log_upgrade_fixed(const uint8_t *pl, size_t n, pt_pixel_acc *px, proto_writer *w)
{
    if (n < 68 || (n - 68) % 40 != 0 || (n - 68) / 40 > PROTO_MAX_TILE_PIXELS)
        return 0;
    proto_result m = {0};
    m.job_id = proto_get_u64(pl);
    m.task_id = proto_get_u64(pl + 8);
    m.tile = (pt_rect){proto_get_u32(pl + 16), proto_get_u32(pl + 20), proto_get_u32(pl + 24),
                       proto_get_u32(pl + 28)};
    m.s0 = proto_get_u32(pl + 32);
    m.s1 = proto_get_u32(pl + 36);
    m.rejected = proto_get_u64(pl + 40);
    m.rays = proto_get_u64(pl + 48);
    m.capped = proto_get_u64(pl + 56);
    m.npixels = (uint32_t)((n - 68) / 40);
    m.pixels = px;
    for (uint32_t i = 0; i < m.npixels; i++) {
        const uint8_t *q = pl + 68 + (size_t)i * 40;
        px[i].n = proto_get_u32(q + 32);
        px[i].hits = proto_get_u32(q + 36);
        for (int c = 0; c < 3; c++) {
            double d = proto_get_f64(q + 8 * c);
            if (!(d >= 0.0 && d <= PT_MAX_SAMPLE_RADIANCE * px[i].n))
                return 0;
            px[i].fsum[c] = pt_fixed_of(d);
        }
        double sq = proto_get_f64(q + 24);
        if (!(sq >= 0.0 && sq <= INFINITY))
            return 0;
        px[i].fsum_sq = pt_ufixed_of(sq);
    }
    proto_writer_reset(w);
    pt_error e = {0};
    if (proto_msg_encode_result(w, &m, &e) != PT_OK)
        return 0;
    return w->len;
}

/* Merges one RESULT payload of the log into job. */
static pt_status replay_one(srv_job *job, const uint8_t *pl, size_t n, pt_pixel_acc *buf,
                            srv_ckpt_extra *x, uint32_t *replayed, const char *p, size_t at,
                            pt_error *err)
{
    proto_result r;
    pt_error e2 = {0};
    if (proto_msg_decode_result(pl, n, buf, PROTO_MAX_TILE_PIXELS, &r, &e2) != PT_OK)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "%s: record at byte %zu is damaged (contents: %s); refusing to use it",
                            p, at, e2.msg);
    srv_outcome o = srv_job_replay(job, &r, &e2);
    if (o == SRV_MERGED) {
        x->rejected += r.rejected;
        x->rays += r.rays;
        (*replayed)++;
    }
    proto_result_fini(&r);
    if (o != SRV_MERGED && o != SRV_DUPLICATE)
        return pt_error_set(err, PT_ERR_FORMAT, "%s: record at byte %zu does not fit the job: %s",
                            p, at, e2.msg);
    return PT_OK;
}

/* The oldest protocol whose RESULT frames a log may hold: 3 (double sums,
 * upgraded to fixed point as read); from PROTO_FIXED_RESULT on the RESULT
 * layout is the current one (later versions changed only TASK and SUBMIT). */
#define LOG_OLDEST_PROTO 3u
#define PROTO_FIXED_RESULT 4u

/* Decodes the record at b[0, len) of a frames log: a RESULT frame of any
 * protocol from LOG_OLDEST_PROTO to PROTO_VERSION (proto_frame_decode takes
 * only the current one, and a log outlives a protocol bump). PT_AGAIN when
 * the bytes end inside it. */
static pt_status log_frame_decode(const uint8_t *b, size_t len, proto_frame *f, size_t *used,
                                  pt_error *err)
{
    if (len < PROTO_FRAME_HEADER)
        return PT_AGAIN;
    if (memcmp(b, PROTO_MAGIC, 4) != 0)
        return pt_error_set(err, PT_ERR_FORMAT, "not a frame (bad magic)");
    uint16_t version = proto_get_u16(b + 4), type = proto_get_u16(b + 6);
    uint32_t plen = proto_get_u32(b + 8);
    if (version < LOG_OLDEST_PROTO || version > PROTO_VERSION)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "a frame of protocol %u; this ptserve reads logs of protocols %u to %u",
                            (unsigned)version, LOG_OLDEST_PROTO, PROTO_VERSION);
    if (type != PROTO_MSG_RESULT)
        return pt_error_set(err, PT_ERR_FORMAT, "not a RESULT (type %u)", (unsigned)type);
    if (plen > PROTO_MAX_PAYLOAD)
        return pt_error_set(err, PT_ERR_FORMAT, "payload length %u over the cap", (unsigned)plen);
    size_t total = (size_t)PROTO_FRAME_OVERHEAD + plen;
    if (len < total)
        return PT_AGAIN;
    if (proto_crc32c(0, b, PROTO_FRAME_HEADER + (size_t)plen) !=
        proto_get_u32(b + PROTO_FRAME_HEADER + plen))
        return pt_error_set(err, PT_ERR_FORMAT, "bad CRC");
    f->version = version;
    f->type = type;
    f->len = plen;
    f->payload = b + PROTO_FRAME_HEADER;
    *used = total;
    return PT_OK;
}

/* Replays the log at p (results.old or results.log) into job. A log of
 * records (PTRL, an older ptserve's: u32 length, u32 CRC32C, payload) or a
 * frames log holding protocol 3 frames (double sums) is rewritten as frames
 * of the current protocol once replayed, so that records appended later never
 * follow records of another layout; its older payloads are upgraded on the
 * way (log_upgrade_record, log_upgrade_fixed). A torn last record is cut off
 * (*torn). */
static pt_status replay_log(const char *p, srv_job *job, srv_ckpt_extra *x, uint32_t *replayed,
                            int *torn, pt_error *err)
{
    uint64_t id = srv_job_id(job);
    uint8_t *data;
    size_t len;
    pt_status s = pt_read_file(p, (size_t)64 << 30, &data, &len, err);
    if (s != PT_OK)
        return (s == PT_ERR_IO && err->sys_errno == ENOENT) ? PT_OK : s;
    size_t good = 0;
    uint8_t *upbuf = NULL;
    proto_writer up, rec;
    proto_writer_init(&up, (size_t)64 << 30);
    proto_writer_init(&rec, (size_t)1 << 30);
    int frames = 0, rewrite = 0;
    uint32_t logver = 0;
    if (len < LOG_HEADER) {
        *torn = len > 0; /* the header write itself was cut short */
    } else if ((proto_get_u32(data) != LOG_MAGIC && proto_get_u32(data) != FLOG_MAGIC) ||
               !version_read(proto_get_u32(data + 4)) || proto_get_u64(data + 8) != id) {
        pt_free(data);
        proto_writer_fini(&up);
        proto_writer_fini(&rec);
        return pt_error_set(err, PT_ERR_FORMAT,
                            "%s: not the results log of job %llu (bad "
                            "header); refusing to use it",
                            p, (unsigned long long)id);
    } else {
        good = LOG_HEADER;
        frames = proto_get_u32(data) == FLOG_MAGIC;
        logver = proto_get_u32(data + 4);
        rewrite = !frames;
        upbuf = pt_malloc(PROTO_RESULT_HEADER_SIZE +
                          (size_t)PROTO_RESULT_WIDE_PIXEL_SIZE * PROTO_MAX_TILE_PIXELS);
        proto_w_u32(&up, FLOG_MAGIC);
        proto_w_u32(&up, STATE_VERSION);
        proto_w_u64(&up, id);
        pt_pixel_acc *buf = pt_malloc_array(PROTO_MAX_TILE_PIXELS, sizeof *buf);
        if (!buf || !upbuf) {
            pt_free(buf);
            pt_free(upbuf);
            proto_writer_fini(&up);
            proto_writer_fini(&rec);
            pt_free(data);
            return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
        }
        while (good < len && s == PT_OK) {
            const uint8_t *pl;
            size_t n, next;
            if (frames) {
                proto_frame f = {0};
                size_t used = 0;
                pt_error e2 = {0};
                pt_status fs = log_frame_decode(data + good, len - good, &f, &used, &e2);
                if (fs == PT_AGAIN) {
                    *torn = 1; /* the last write was cut short by the crash */
                    break;
                }
                if (fs != PT_OK && len - good >= PROTO_FRAME_HEADER &&
                    good + PROTO_FRAME_OVERHEAD + (size_t)proto_frame_payload_len(data + good) ==
                        len) {
                    /* The last record, whole in length but not in content:
                     * the file grew before its data reached the disk (a
                     * crash or a full disk during the write). Never merged. */
                    *torn = 1;
                    break;
                }
                if (fs != PT_OK) {
                    s = pt_error_set(err, PT_ERR_FORMAT,
                                     "%s: record at byte %zu is damaged (%s); refusing to use it",
                                     p, good, e2.msg);
                    break;
                }
                pl = f.payload;
                n = f.len;
                next = good + used;
                if (f.version < PROTO_FIXED_RESULT) {
                    /* Double sums: this record and every later one go into a
                     * rewritten log, the records before it as they are. */
                    if (!rewrite) {
                        proto_w_bytes(&up, data + LOG_HEADER, good - LOG_HEADER);
                        rewrite = 1;
                    }
                    size_t k = log_upgrade_fixed(pl, n, buf, &rec);
                    if (k == 0) {
                        s = pt_error_set(err, PT_ERR_FORMAT,
                                         "%s: record at byte %zu is a protocol %u RESULT that "
                                         "cannot be upgraded; refusing to use it",
                                         p, good, (unsigned)f.version);
                        break;
                    }
                    pl = rec.buf;
                    n = k;
                }
                if (rewrite)
                    proto_frame_encode(&up, PROTO_MSG_RESULT, pl, n, NULL);
            } else {
                if (len - good < 8 || len - good - 8 < proto_get_u32(data + good)) {
                    *torn = 1;
                    break;
                }
                n = proto_get_u32(data + good);
                pl = data + good + 8;
                next = good + 8 + n;
                if (proto_crc32c(0, pl, n) != proto_get_u32(data + good + 4)) {
                    if (next == len) {
                        *torn = 1;
                        break;
                    }
                    s = pt_error_set(err, PT_ERR_FORMAT,
                                     "%s: record at byte %zu is damaged (checksum mismatch); "
                                     "refusing to use it",
                                     p, good);
                    break;
                }
                if (logver < STATE_FIXED_VERSION) {
                    size_t k = logver < STATE_FILM_VERSION ? log_upgrade_record(pl, n, upbuf) : 0;
                    if (k) {
                        pl = upbuf;
                        n = k;
                    }
                    if ((k = log_upgrade_fixed(pl, n, buf, &rec)) != 0) {
                        pl = rec.buf;
                        n = k;
                    }
                }
                proto_frame_encode(&up, PROTO_MSG_RESULT, pl, n, NULL);
            }
            s = replay_one(job, pl, n, buf, x, replayed, p, good, err);
            if (s == PT_OK)
                good = next;
        }
        pt_free(buf);
        pt_free(upbuf);
    }
    pt_free(data);
    proto_writer_fini(&rec);
    if (s == PT_OK && rewrite) {
        /* Whole records only: a torn last one is left out. */
        s = proto_writer_status(&up) != PT_OK
                ? pt_error_set(err, proto_writer_status(&up), "%s: cannot upgrade", p)
                : pt_write_file_atomic(p, up.buf, up.len, err);
        proto_writer_fini(&up);
        return s;
    }
    proto_writer_fini(&up);
    if (s == PT_OK && *torn) {
        /* Cut the incomplete record off so new records follow whole ones. */
        if (truncate(p, (off_t)(good >= LOG_HEADER ? good : 0)) != 0)
            s = pt_error_errno(err, PT_ERR_IO, "%s: truncate", p);
    }
    return s;
}

pt_status srv_state_restore(srv_state *st, srv_job *job, srv_ckpt_extra *extra, uint32_t *replayed,
                            int *torn, pt_error *err)
{
    memset(extra, 0, sizeof *extra);
    *replayed = 0;
    *torn = 0;
    char p[PATH_MAX];
    job_path(st, srv_job_id(job), "checkpoint", p, sizeof p);
    uint8_t *data;
    const uint8_t *body;
    size_t len;
    int missing;
    /* The checkpoint body carries its own version (srv_job_restore). */
    pt_status s =
        read_intact(p, CKPT_MAGIC, MAX_CKPT_BYTES, &data, &body, &len, NULL, &missing, err);
    if (s != PT_OK)
        return s;
    if (!missing) {
        if (len < 24) {
            pt_free(data);
            return pt_error_set(err, PT_ERR_FORMAT, "%s: truncated header", p);
        }
        extra->seconds = proto_get_f64(body);
        extra->rejected = proto_get_u64(body + 8);
        extra->rays = proto_get_u64(body + 16);
        pt_error e2 = {0};
        s = srv_job_load(job, body + 24, len - 24, &e2);
        pt_free(data);
        if (s != PT_OK)
            return pt_error_set(err, s, "%s: %s; refusing to use it", p, e2.msg);
        if (!(extra->seconds >= 0) || extra->seconds > 1e12)
            extra->seconds = 0;
    }
    /* A rotated log (results.old) is there when the checkpoint meant to
     * hold it was not written (a crash or a failure): its records come
     * before the current log's. Replay is idempotent, so records the
     * checkpoint already holds change nothing. */
    char old[PATH_MAX], cur[PATH_MAX];
    job_path(st, srv_job_id(job), "results.old", old, sizeof old);
    job_path(st, srv_job_id(job), "results.log", cur, sizeof cur);
    int torn_old = 0;
    if ((s = replay_log(old, job, extra, replayed, &torn_old, err)) != PT_OK ||
        (s = replay_log(cur, job, extra, replayed, torn, err)) != PT_OK)
        return s;
    *torn |= torn_old;
    struct stat sb;
    if (lstat(old, &sb) != 0)
        return PT_OK;
    /* Fold both into a checkpoint now, so that the next rotation finds no
     * results.old in its way. */
    if ((s = job_file(st, srv_job_id(job), "checkpoint", p, sizeof p, err)) != PT_OK ||
        (s = write_ckpt(p, job, extra, "", err)) != PT_OK)
        return s;
    if (unlink(old) != 0)
        return pt_error_errno(err, PT_ERR_IO, "%s", old);
    if (lstat(cur, &sb) == 0 && sb.st_size > LOG_HEADER && truncate(cur, LOG_HEADER) != 0)
        return pt_error_errno(err, PT_ERR_IO, "%s: truncate", cur);
    return PT_OK;
}
