#define _GNU_SOURCE /* O_CLOEXEC, fdatasync */
#include "server/state.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/base/hash.h"
#include "common/render/render.h"
#include "protocol/frame.h"
#include "protocol/wire.h"

#define QUEUE_MAGIC 0x31515450u /* "PTQ1" */
#define CKPT_MAGIC 0x4b435450u  /* "PTCK" */
#define LOG_MAGIC 0x4c525450u   /* "PTRL" */
#define STATE_VERSION 7u
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
#define LOG_HEADER 16u
#define MAX_QUEUE_BYTES (256u << 20)
#define MAX_CKPT_BYTES ((size_t)8 << 30)

typedef struct log_file {
    uint64_t id;
    int fd;
    uint64_t bytes; /* the log's length: its whole records end here */
    int dirty;
    int cut; /* a write was cut short and the cut back to bytes failed */
} log_file;

struct srv_state {
    char dir[PATH_MAX - 64];
    int lock_fd;
    log_file *logs;
    uint32_t nlogs, logs_cap;
    int queue_unsaved; /* the last queue file write failed */
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

pt_status srv_state_open(const char *dir, srv_state **out, pt_error *err)
{
    if (strlen(dir) >= sizeof((srv_state *)0)->dir)
        return pt_error_set(err, PT_ERR_ARG, "state folder %s: path too long", dir);
    srv_state *st = pt_calloc(1, sizeof *st);
    if (!st)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    snprintf(st->dir, sizeof st->dir, "%s", dir);
    st->lock_fd = -1;
    char p[PATH_MAX];
    pt_status s;
    path_of(st, p, sizeof p, "jobs");
    if ((s = pt_mkdirs(p, 1, err)) != PT_OK)
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
    *out = st;
    return PT_OK;
fail:
    srv_state_close(st);
    return s;
}

void srv_state_close(srv_state *st)
{
    if (!st)
        return;
    for (uint32_t i = 0; i < st->nlogs; i++)
        if (st->logs[i].fd >= 0) {
            fdatasync(st->logs[i].fd);
            close(st->logs[i].fd);
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
    *l = st->logs[--st->nlogs];
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
        uint32_t cap = st->logs_cap ? 2 * st->logs_cap : 8;
        log_file *n = pt_realloc(st->logs, cap * sizeof *n);
        if (!n)
            return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
        st->logs = n;
        st->logs_cap = cap;
    }
    char p[PATH_MAX];
    /* The folder is made here too: a frame of a frame-range job has no
     * bundle of its own, so its first file may be its log. */
    pt_status ms = job_file(st, id, "results.log", p, sizeof p, err);
    if (ms != PT_OK)
        return ms;
    int fd = open(p, O_WRONLY | O_CREAT | O_APPEND | O_NOFOLLOW | O_CLOEXEC, 0600);
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
    if (bytes == 0) {
        uint8_t h[LOG_HEADER];
        proto_put_u32(h, LOG_MAGIC);
        proto_put_u32(h + 4, STATE_VERSION);
        proto_put_u64(h + 8, id);
        if (pt_write_all(fd, h, sizeof h) != 0 || fdatasync(fd) != 0 || pt_fsync_dir_of(p) != 0) {
            pt_status s = pt_error_errno(err, PT_ERR_IO, "%s: cannot write its header", p);
            /* Records must not follow a header cut short: leave the log empty
             * (it holds nothing yet) for the next try. Should that fail too,
             * the next open finds a short file and refuses it (below). */
            int cut = ftruncate(fd, 0);
            (void)cut;
            close(fd);
            return s;
        }
        bytes = LOG_HEADER;
    }
    l = &st->logs[st->nlogs++];
    *l = (log_file){id, fd, bytes, 0, 0};
    *out = l;
    return PT_OK;
}

/* Truncates the log to its known length (l->bytes), dropping a partial
 * record; clears l->cut on success. Returns 0, or -1 with errno kept. */
static int cut_back(log_file *l)
{
    int saved = errno;
    if (ftruncate(l->fd, (off_t)l->bytes) != 0)
        return -1;
    l->cut = 0;
    errno = saved;
    return 0;
}

pt_status srv_state_log_result(srv_state *st, uint64_t id, const uint8_t *payload, size_t len,
                               pt_error *err)
{
    log_file *l;
    pt_status s = open_log(st, id, &l, err);
    if (s != PT_OK)
        return s;
    uint8_t h[8];
    proto_put_u32(h, (uint32_t)len);
    proto_put_u32(h + 4, proto_crc32c(0, payload, len));
    /* One buffer so the record goes out in a single write(): a kill -9 leaves
     * it whole or cut short at the end, never interleaved. */
    uint8_t *rec = pt_malloc(len + 8);
    if (!rec)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory for a log record");
    memcpy(rec, h, 8);
    memcpy(rec + 8, payload, len);
    /* A write cut short (a full disk, a quota) leaves part of a record at the
     * end; the next record would follow it and the log would read as damaged
     * in its middle. So the log is cut back to its last whole record before
     * anything else is appended, and stays unwritten while that fails. */
    if (l->cut && cut_back(l) != 0) {
        s = pt_error_errno(err, PT_ERR_IO,
                           "results log of job %llu: cannot cut it back to its last whole record",
                           (unsigned long long)id);
        pt_free(rec);
        return s;
    }
    if (pt_write_all(l->fd, rec, len + 8) != 0) {
        s = pt_error_errno(err, PT_ERR_IO, "results log of job %llu", (unsigned long long)id);
        pt_free(rec);
        l->cut = 1;
        cut_back(l);
        return s;
    }
    pt_free(rec);
    l->bytes += len + 8;
    l->dirty = 1;
    return PT_OK;
}

uint64_t srv_state_log_bytes(const srv_state *st, uint64_t id)
{
    const log_file *l = find_log(st, id);
    return l ? l->bytes : 0;
}

pt_status srv_state_sync(srv_state *st, pt_error *err)
{
    pt_status s = PT_OK;
    for (uint32_t i = 0; i < st->nlogs; i++) {
        if (!st->logs[i].dirty)
            continue;
        if (fdatasync(st->logs[i].fd) != 0 && s == PT_OK)
            s = pt_error_errno(err, PT_ERR_IO, "results log of job %llu: fdatasync",
                               (unsigned long long)st->logs[i].id);
        st->logs[i].dirty = 0;
    }
    return s;
}

void srv_state_forget_job(srv_state *st, uint64_t id)
{
    close_log(st, id);
    char p[PATH_MAX];
    job_path(st, id, NULL, p, sizeof p);
    pt_remove_tree(p);
    pt_fsync_dir_of(p);
}

/* ---- checkpoints ------------------------------------------------------------------- */

pt_status srv_state_checkpoint(srv_state *st, const srv_job *job, const srv_ckpt_extra *x,
                               pt_error *err)
{
    uint64_t id = srv_job_id(job);
    char p[PATH_MAX];
    pt_status s = job_file(st, id, "checkpoint", p, sizeof p, err);
    if (s != PT_OK)
        return s;
    proto_writer w;
    proto_writer_init(&w, MAX_CKPT_BYTES);
    begin_file(&w, CKPT_MAGIC);
    proto_w_f64(&w, x->seconds);
    proto_w_u64(&w, x->rejected);
    proto_w_u64(&w, x->rays);
    if ((s = srv_job_save(job, &w, err)) == PT_OK)
        s = end_file(&w, p, err);
    proto_writer_fini(&w);
    if (s != PT_OK)
        return s;
    /* Everything the log held is in the checkpoint now: start it afresh. */
    log_file *l = find_log(st, id);
    if (l) {
        if (ftruncate(l->fd, LOG_HEADER) != 0 || fdatasync(l->fd) != 0)
            return pt_error_errno(err, PT_ERR_IO, "results log of job %llu: truncate",
                                  (unsigned long long)id);
        l->bytes = LOG_HEADER;
        l->dirty = 0;
        l->cut = 0;
    }
    return PT_OK;
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

static pt_status replay_log(srv_state *st, srv_job *job, srv_ckpt_extra *x, uint32_t *replayed,
                            int *torn, pt_error *err)
{
    uint64_t id = srv_job_id(job);
    char p[PATH_MAX];
    job_path(st, id, "results.log", p, sizeof p);
    uint8_t *data;
    size_t len;
    pt_status s = pt_read_file(p, (size_t)64 << 30, &data, &len, err);
    if (s != PT_OK)
        return (s == PT_ERR_IO && err->sys_errno == ENOENT) ? PT_OK : s;
    size_t good = 0;
    /* An older log's records are upgraded as they are read, and the whole log
     * is rewritten in this layout once replayed, so that records appended
     * later never follow records of another layout. */
    uint8_t *upbuf = NULL;
    proto_writer up, rec;
    proto_writer_init(&up, (size_t)64 << 30);
    proto_writer_init(&rec, (size_t)1 << 30);
    int old = 0;
    uint32_t logver = 0;
    if (len < LOG_HEADER) {
        *torn = len > 0; /* the header write itself was cut short */
    } else if (proto_get_u32(data) != LOG_MAGIC || !version_read(proto_get_u32(data + 4)) ||
               proto_get_u64(data + 8) != id) {
        pt_free(data);
        return pt_error_set(err, PT_ERR_FORMAT,
                            "%s: not the results log of job %llu (bad "
                            "header); refusing to use it",
                            p, (unsigned long long)id);
    } else {
        good = LOG_HEADER;
        logver = proto_get_u32(data + 4);
        old = logver < STATE_FIXED_VERSION;
        if (old) {
            upbuf = pt_malloc(PROTO_RESULT_HEADER_SIZE +
                              (size_t)PROTO_RESULT_PIXEL_SIZE * PROTO_MAX_TILE_PIXELS);
            proto_w_u32(&up, LOG_MAGIC);
            proto_w_u32(&up, STATE_VERSION);
            proto_w_u64(&up, id);
        }
        pt_pixel_acc *buf = pt_malloc_array(PROTO_MAX_TILE_PIXELS, sizeof *buf);
        if (!buf || (old && !upbuf)) {
            pt_free(buf);
            pt_free(upbuf);
            proto_writer_fini(&up);
            proto_writer_fini(&rec);
            pt_free(data);
            return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
        }
        while (good < len) {
            if (len - good < 8 || len - good - 8 < proto_get_u32(data + good)) {
                *torn = 1; /* the last write was cut short by the crash */
                break;
            }
            uint32_t n = proto_get_u32(data + good);
            const uint8_t *pl = data + good + 8;
            proto_result r;
            pt_error e2 = {0};
            int crc_ok = proto_crc32c(0, pl, n) == proto_get_u32(data + good + 4);
            if (!crc_ok && good + 8 + (size_t)n == len) {
                /* The last record, whole in length but not in content: the
                 * file grew before its data reached the disk (a crash or a
                 * full disk during the write). It was never merged. */
                *torn = 1;
                break;
            }
            size_t rn = n;
            if (crc_ok && old) {
                size_t k = logver < STATE_FILM_VERSION ? log_upgrade_record(pl, n, upbuf) : 0;
                if (k) {
                    pl = upbuf;
                    rn = k;
                }
                if ((k = log_upgrade_fixed(pl, rn, buf, &rec)) != 0) {
                    pl = rec.buf;
                    rn = k;
                }
                proto_w_u32(&up, (uint32_t)rn);
                proto_w_u32(&up, proto_crc32c(0, pl, rn));
                proto_w_bytes(&up, pl, rn);
            }
            if (!crc_ok ||
                proto_msg_decode_result(pl, rn, buf, PROTO_MAX_TILE_PIXELS, &r, &e2) != PT_OK) {
                s = pt_error_set(err, PT_ERR_FORMAT,
                                 "%s: record at byte %zu is damaged "
                                 "(checksum or contents: %s); refusing to use it",
                                 p, good, e2.msg[0] ? e2.msg : "checksum mismatch");
                break;
            }
            srv_outcome o = srv_job_replay(job, &r, &e2);
            if (o == SRV_MERGED) {
                x->rejected += r.rejected;
                x->rays += r.rays;
                (*replayed)++;
            } else if (o != SRV_DUPLICATE) {
                s = pt_error_set(err, PT_ERR_FORMAT,
                                 "%s: record at byte %zu does not fit the "
                                 "job: %s",
                                 p, good, e2.msg);
                break;
            }
            good += 8 + (size_t)n;
        }
        pt_free(buf);
        pt_free(upbuf);
    }
    pt_free(data);
    proto_writer_fini(&rec);
    if (s == PT_OK && old) {
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
    return replay_log(st, job, extra, replayed, torn, err);
}
