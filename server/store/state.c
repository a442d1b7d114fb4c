#define _GNU_SOURCE /* O_CLOEXEC, fdatasync */
#include "server/store/state_impl.h"

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

const char *srv_state_dir(const srv_state *st)
{
    return st->dir;
}

void st_path_of(const srv_state *st, char *buf, size_t cap, const char *rel)
{
    snprintf(buf, cap, "%s/%s", st->dir, rel);
}

void st_job_path(const srv_state *st, uint64_t id, const char *file, char *buf, size_t cap)
{
    if (file)
        snprintf(buf, cap, "%s/jobs/%llu/%s", st->dir, (unsigned long long)id, file);
    else
        snprintf(buf, cap, "%s/jobs/%llu", st->dir, (unsigned long long)id);
}

/* The path of a job's file (job_path) once the job's folder exists: it is
 * made, private, on the first file written to it. */
pt_status st_job_file(const srv_state *st, uint64_t id, const char *file, char *buf, size_t cap,
                      pt_error *err)
{
    st_job_path(st, id, NULL, buf, cap);
    pt_status s = pt_mkdirs(buf, 1, err);
    if (s == PT_OK)
        st_job_path(st, id, file, buf, cap);
    return s;
}

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

void *st_sweep_main(void *arg)
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

void st_sweep_signal(sweeper *sw)
{
    pthread_mutex_lock(&sw->mu);
    sw->work = 1;
    pthread_cond_signal(&sw->cv);
    pthread_mutex_unlock(&sw->mu);
}

/* A thread of the state's own (the commit's, the sweeper's), with its mutex
 * and condition; what names it in an error. */
pt_status st_thread_start(pthread_t *th, pthread_mutex_t *mu, pthread_cond_t *cv,
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
void st_thread_stop(pthread_t th, pthread_mutex_t *mu, pthread_cond_t *cv, int *stop)
{
    pthread_mutex_lock(mu);
    *stop = 1;
    pthread_cond_signal(cv);
    pthread_mutex_unlock(mu);
    pthread_join(th, NULL);
    pthread_mutex_destroy(mu);
    pthread_cond_destroy(cv);
}

/* ---- common: a whole file with magic, version, body, CRC32C ---------------------- */

void st_begin_file(proto_writer *w, uint32_t magic)
{
    proto_w_u32(w, magic);
    proto_w_u32(w, STATE_VERSION);
}

pt_status st_end_file(proto_writer *w, const char *path, pt_error *err)
{
    if (proto_writer_status(w) != PT_OK)
        return pt_error_set(err, proto_writer_status(w), "%s: cannot serialise", path);
    proto_w_u32(w, proto_crc32c(0, w->buf, w->len));
    if (proto_writer_status(w) != PT_OK)
        return pt_error_set(err, proto_writer_status(w), "%s: cannot serialise", path);
    return pt_write_file_atomic(path, w->buf, w->len, err);
}

int st_version_read(uint32_t v)
{
    return v >= STATE_OLDEST_VERSION && v <= STATE_VERSION;
}

/* Reads path and checks magic, version and checksum; *body and *body_len get
 * what lies between, *version (when not NULL) the format version. *missing =
 * 1 (and PT_OK) when the file does not exist. */
pt_status st_read_intact(const char *path, uint32_t magic, size_t max, uint8_t **data,
                         const uint8_t **body, size_t *body_len, uint32_t *version, int *missing,
                         pt_error *err)
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
    else if (!st_version_read(proto_get_u32(*data + 4))) {
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
    st_path_of(st, path, sizeof path, "queue");
    proto_writer w;
    proto_writer_init(&w, MAX_QUEUE_BYTES);
    st_begin_file(&w, QUEUE_MAGIC);
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
        proto_w_u64(&w, j->clamped);
    }
    pt_status s = st_end_file(&w, path, err);
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
    st_path_of(st, path, sizeof path, "queue");
    uint8_t *data;
    const uint8_t *body;
    size_t len;
    uint32_t version;
    int missing;
    *recs = NULL;
    *n = 0;
    *next_id = 1;
    pt_status s = st_read_intact(path, QUEUE_MAGIC, MAX_QUEUE_BYTES, &data, &body, &len, &version,
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
                            version >= STATE_ENV_VERSION, version >= STATE_SHUTTER_VERSION,
                            version >= STATE_CLAMP_VERSION);
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
        j->clamped =
            version >= STATE_CLAMPED_VERSION ? proto_r_u64(&r, "contributions clamped") : 0;
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
    pt_status s = st_job_file(st, id, "bundle", p, sizeof p, err);
    if (s != PT_OK)
        return s;
    return pt_write_file_atomic(p, data, n, err);
}

pt_status srv_state_save_manifests(const srv_state *st, uint64_t id, const char *text,
                                   pt_error *err)
{
    char p[PATH_MAX];
    size_t n = strlen(text);
    if (n > SRV_STATE_MAX_MANIFESTS)
        return pt_error_set(err, PT_ERR_LIMIT, "Cryptomatte manifests of %zu bytes, over %u", n,
                            SRV_STATE_MAX_MANIFESTS);
    pt_status s = st_job_file(st, id, "cryptomatte", p, sizeof p, err);
    if (s != PT_OK)
        return s;
    return pt_write_file_atomic(p, (const uint8_t *)text, n, err);
}

pt_status srv_state_load_manifests(srv_state *st, uint64_t id, char **out, pt_error *err)
{
    char p[PATH_MAX];
    st_job_path(st, id, "cryptomatte", p, sizeof p);
    uint8_t *data;
    size_t len;
    pt_status s = pt_read_file(p, SRV_STATE_MAX_MANIFESTS, &data, &len, err);
    if (s != PT_OK)
        return s;
    char *text = pt_malloc(len + 1);
    if (!text) {
        pt_free(data);
        return pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory", p);
    }
    memcpy(text, data, len);
    text[len] = '\0';
    pt_free(data);
    *out = text;
    return PT_OK;
}

pt_status srv_state_load_bundle(srv_state *st, uint64_t id, const uint8_t hash[32], pt_bundle **out,
                                pt_error *err)
{
    char p[PATH_MAX];
    st_job_path(st, id, "bundle", p, sizeof p);
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
