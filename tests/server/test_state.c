/*
 * test_state.c - the state folder's results log when writes fail or are cut
 * short: a short write (a full disk, here RLIMIT_FSIZE), by a sync or by the
 * group commit's thread, is cut back to the last whole record so later
 * records follow whole ones; a torn last record
 * (incomplete, or whole in length with a bad checksum) is dropped at restore
 * and cut off; damage before the last record is still refused; records
 * taken without a copy, more than one writev's, keep their order through a
 * failed commit; a queue file
 * that cannot be written is reported as unsaved until one is; an ended
 * job's folder is swept from the trash, with what a crash left there.
 */
#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/render/render.h"
#include "protocol/frame.h"
#include "protocol/wire.h"
#include "server/sched/job.h"
#include "server/store/state.h"
#include "tests/check.h"

static const uint8_t HASH[32] = {7, 7, 7};
static const srv_job_params PARAMS = {
    64, 32, 32,     32,     16, 5,  8, 3, 0.0, 0, 0.0, "", {"", 1.0f, 0.0f, 0, {0, 0, 0}},
    0,  "", {0, 0}, {0, 0}, 0,  {0}};
#define JOB_ID 4u

/* The RESULT frame of task t of a PARAMS job, with synthetic pixels: a log
 * record. */
static void payload_of(srv_job *job, uint64_t t, proto_writer *w)
{
    static pt_pixel_acc px[32 * 32];
    proto_task task;
    /* Lease every task up to t so that the description is the job's own. */
    do {
        CHECK(srv_job_lease(job, 1, 0, 1000000, &task) == 1);
    } while (task.task_id != t);
    uint32_t n = (task.tile.x1 - task.tile.x0) * (task.tile.y1 - task.tile.y0);
    for (uint32_t i = 0; i < n; i++)
        px[i] = pt_pixel_acc_of(0.25 * (double)(t + 1), 0.5, 0.125 * i, 1.0, task.s1 - task.s0, 0);
    proto_result r = {JOB_ID, t,    task.tile, task.s0, task.s1, 0, 0,    0, n, px,
                      0,      NULL, 0,         0,       0,       0, NULL, 0, 0};
    proto_writer_init(w, (size_t)1 << 20);
    size_t mark;
    CHECK(proto_frame_begin(w, PROTO_MSG_RESULT, &mark, NULL) == PT_OK);
    CHECK(proto_frame_finish(w, mark, proto_msg_encode_result(w, &r, NULL), NULL) == PT_OK);
}

/* Opens the state folder dir with job JOB_ID's folder made (as its bundle's
 * save would). */
static srv_state *open_state(const char *dir)
{
    srv_state *st = NULL;
    pt_error err = {0};
    CHECKF(srv_state_open(dir, &srv_job_state_codec, &st, &err) == PT_OK, "%s", err.msg);
    char p[512];
    snprintf(p, sizeof p, "%s/jobs/%u", dir, JOB_ID);
    CHECK(pt_mkdirs(p, 1, &err) == PT_OK);
    return st;
}

static srv_job *fresh_job(void)
{
    srv_job *job = NULL;
    pt_error err = {0};
    CHECKF(srv_job_new(JOB_ID, &PARAMS, HASH, &job, &err) == PT_OK, "%s", err.msg);
    return job;
}

/* Logs tasks [0, n) of a fresh job; returns the log's size after each in sizes. */
static void log_tasks(srv_state *st, uint32_t n, uint64_t *sizes)
{
    srv_job *src = fresh_job();
    pt_error err = {0};
    for (uint32_t t = 0; t < n; t++) {
        proto_writer w;
        payload_of(src, t, &w);
        CHECKF(srv_state_log_result(st, JOB_ID, w.buf, w.len, &err) == PT_OK, "%s", err.msg);
        proto_writer_fini(&w);
        sizes[t] = srv_state_log_bytes(st, JOB_ID);
    }
    CHECK(srv_state_sync(st, &err) == PT_OK);
    srv_job_free(src);
}

/* Restores the job from dir; returns the status, with the counts. */
static pt_status restore(const char *dir, uint32_t *replayed, int *torn, pt_error *err)
{
    srv_state *st = NULL;
    CHECK(srv_state_open(dir, &srv_job_state_codec, &st, err) == PT_OK);
    srv_job *job = fresh_job();
    srv_ckpt_extra x;
    pt_status s = srv_state_restore(st, job, &x, replayed, torn, err);
    srv_job_free(job);
    srv_state_close(st);
    return s;
}

static off_t size_of(const char *path)
{
    struct stat sb;
    return stat(path, &sb) == 0 ? sb.st_size : -1;
}

typedef struct commit_seen {
    unsigned calls;
    pt_status last;
} commit_seen;

static void on_commit_seen(void *ctx, uint64_t job_id, pt_status st, const pt_error *err)
{
    commit_seen *c = ctx;
    (void)err;
    CHECK(job_id == JOB_ID);
    c->calls++;
    c->last = st;
}

static void test_short_write_cut_back(const char *dir)
{
    char log[512];
    snprintf(log, sizeof log, "%s/jobs/%u/results.log", dir, JOB_ID);
    pt_error err = {0};
    srv_state *st = open_state(dir);
    uint64_t sizes[3];
    log_tasks(st, 2, sizes);
    CHECK(size_of(log) == (off_t)sizes[1]);

    /* The file may grow by half a record only: the write is cut short. */
    srv_job *src = fresh_job();
    proto_writer w;
    for (uint64_t t = 0; t < 2; t++) { /* lease past tasks 0 and 1 */
        proto_task task;
        CHECK(srv_job_lease(src, 1, 0, 1000000, &task) == 1);
    }
    payload_of(src, 2, &w);
    struct rlimit old, lim;
    CHECK(getrlimit(RLIMIT_FSIZE, &old) == 0);
    lim = old;
    lim.rlim_cur = (rlim_t)(sizes[1] + w.len / 2);
    signal(SIGXFSZ, SIG_IGN);
    /* The record is kept in memory; the write comes with the sync. */
    CHECKF(srv_state_log_result(st, JOB_ID, w.buf, w.len, &err) == PT_OK, "%s", err.msg);
    CHECK(setrlimit(RLIMIT_FSIZE, &lim) == 0);
    pt_status s = srv_state_sync(st, &err);
    CHECK(setrlimit(RLIMIT_FSIZE, &old) == 0);
    CHECKF(s == PT_ERR_IO, "a cut-short write reported %d", s);
    CHECKF(size_of(log) == (off_t)sizes[1], "the log holds %lld bytes, not %llu",
           (long long)size_of(log), (unsigned long long)sizes[1]);
    /* The record is kept; with space again it goes after the last whole one. */
    CHECK(srv_state_log_bytes(st, JOB_ID) == sizes[1] + w.len);
    CHECK(srv_state_sync(st, &err) == PT_OK);
    uint64_t whole = srv_state_log_bytes(st, JOB_ID);
    CHECK(size_of(log) == (off_t)whole);

    /* The same through the group commit, whose thread writes the records. */
    proto_writer_fini(&w);
    payload_of(src, 3, &w);
    lim.rlim_cur = (rlim_t)(whole + w.len / 2);
    CHECKF(srv_state_log_result(st, JOB_ID, w.buf, w.len, &err) == PT_OK, "%s", err.msg);
    CHECK(setrlimit(RLIMIT_FSIZE, &lim) == 0);
    commit_seen seen = {0};
    uint64_t done = 0;
    CHECK(srv_state_commit_start(st) == 1);
    CHECK(srv_state_commit_collect(st, 1, &done, on_commit_seen, &seen) == 1);
    CHECK(setrlimit(RLIMIT_FSIZE, &old) == 0);
    CHECKF(seen.calls == 1 && seen.last == PT_ERR_IO, "%u calls, status %d", seen.calls, seen.last);
    CHECKF(size_of(log) == (off_t)whole, "the log holds %lld bytes after a failed commit, not %llu",
           (long long)size_of(log), (unsigned long long)whole);
    /* Kept, and not tried again until the resync says so. */
    CHECK(srv_state_log_bytes(st, JOB_ID) == whole + w.len);
    CHECK(srv_state_commit_start(st) == 0);
    CHECK(srv_state_log_resync(st, JOB_ID, &err) == PT_OK);
    CHECK(srv_state_commit_start(st) == 1);
    CHECK(srv_state_commit_collect(st, 1, &done, on_commit_seen, &seen) == 1);
    CHECK(seen.calls == 2 && seen.last == PT_OK);
    CHECK(size_of(log) == (off_t)srv_state_log_bytes(st, JOB_ID));
    proto_writer_fini(&w);
    srv_job_free(src);
    srv_state_close(st);

    uint32_t replayed = 0;
    int torn = 0;
    CHECKF(restore(dir, &replayed, &torn, &err) == PT_OK, "%s", err.msg);
    CHECKF(replayed == 4 && torn == 0, "%u replayed, torn %d", replayed, torn);
    pt_remove_tree(dir);
}

/* Records taken without a copy (srv_state_log_result_take) and more of them
 * than one writev takes: a group commit writes them in order; one cut short
 * keeps its records in front of those logged since, and the next commit
 * writes them all, in order, once. */
static void test_commit_many_taken(const char *dir)
{
    enum { FIRST = 300, LATER = 300 }; /* each more than the writev batch of 256 */
    char log[512];
    snprintf(log, sizeof log, "%s/jobs/%u/results.log", dir, JOB_ID);
    pt_error err = {0};
    srv_state *st = open_state(dir);
    srv_job *src = fresh_job();
    proto_writer w[4];
    for (uint64_t t = 0; t < 4; t++)
        payload_of(src, t, &w[t]);
    size_t total = 0;
    uint8_t *want = pt_malloc((size_t)(FIRST + LATER) * w[0].len * 2);
    CHECK(want != NULL);
    uint64_t start = 0;
    struct rlimit old, lim;
    CHECK(getrlimit(RLIMIT_FSIZE, &old) == 0);
    commit_seen seen = {0};
    uint64_t done = 0;
    for (int i = 0; i < FIRST + LATER; i++) {
        const proto_writer *r = &w[i % 4];
        uint8_t *frame = pt_malloc(r->len);
        CHECK(frame != NULL);
        memcpy(frame, r->buf, r->len);
        memcpy(want + total, r->buf, r->len);
        total += r->len;
        CHECKF(srv_state_log_result_take(st, JOB_ID, &frame, r->len, &err) == PT_OK, "%s", err.msg);
        CHECK(frame == NULL); /* the log's now */
        if (i == 0)
            start = srv_state_log_bytes(st, JOB_ID) - r->len; /* the header */
        if (i == FIRST - 1) {
            /* The first batch's commit is cut short past its 200th record. */
            lim = old;
            lim.rlim_cur = (rlim_t)(start + total * 2 / 3);
            CHECK(setrlimit(RLIMIT_FSIZE, &lim) == 0);
            CHECK(srv_state_commit_start(st) == 1);
            CHECK(srv_state_commit_collect(st, 1, &done, on_commit_seen, &seen) == 1);
            CHECK(setrlimit(RLIMIT_FSIZE, &old) == 0);
            CHECKF(seen.calls == 1 && seen.last == PT_ERR_IO, "%u calls, status %d", seen.calls,
                   seen.last);
            CHECK(size_of(log) == (off_t)start);
        }
    }
    CHECK(srv_state_log_bytes(st, JOB_ID) == start + total);
    CHECK(srv_state_log_resync(st, JOB_ID, &err) == PT_OK);
    CHECK(srv_state_commit_start(st) == 1);
    CHECK(srv_state_commit_collect(st, 1, &done, on_commit_seen, &seen) == 1);
    CHECK(seen.calls == 2 && seen.last == PT_OK);
    uint8_t *data = NULL;
    size_t len = 0;
    CHECK(pt_read_file(log, 1 << 30, &data, &len, &err) == PT_OK);
    CHECKF(len == start + total && memcmp(data + start, want, total) == 0,
           "the log holds %zu bytes, %zu written in order wanted", len, (size_t)(start + total));
    pt_free(data);
    pt_free(want);
    for (int t = 0; t < 4; t++)
        proto_writer_fini(&w[t]);
    srv_job_free(src);
    srv_state_close(st);
    pt_remove_tree(dir);
}

/* Appends bytes to path. */
static void append(const char *path, const void *data, size_t n)
{
    int fd = open(path, O_WRONLY | O_APPEND);
    CHECK(fd >= 0 && pt_write_all(fd, data, n) == 0);
    close(fd);
}

static void test_torn_tail(const char *dir)
{
    char log[512];
    snprintf(log, sizeof log, "%s/jobs/%u/results.log", dir, JOB_ID);
    pt_error err = {0};
    uint64_t sizes[3];

    /* An incomplete last record: dropped, cut off, the job restored. */
    srv_state *st = open_state(dir);
    log_tasks(st, 3, sizes);
    srv_state_close(st);
    CHECK(truncate(log, (off_t)(sizes[2] - 10)) == 0);
    uint32_t replayed = 0;
    int torn = 0;
    CHECKF(restore(dir, &replayed, &torn, &err) == PT_OK, "%s", err.msg);
    CHECK(replayed == 2 && torn == 1);
    CHECK(size_of(log) == (off_t)sizes[1]);

    /* A last record whole in length but not in content (the file grew
     * before the data reached the disk): dropped too. */
    uint8_t *data;
    size_t len;
    CHECK(pt_read_file(log, 1 << 24, &data, &len, &err) == PT_OK);
    uint32_t rec = (uint32_t)(sizes[1] - sizes[0]); /* one record's size */
    uint8_t *zeros = pt_calloc(1, rec);
    memcpy(zeros, data + sizes[0], PROTO_FRAME_HEADER); /* its header, no data */
    append(log, zeros, rec);
    pt_free(zeros);
    CHECKF(restore(dir, &replayed, &torn, &err) == PT_OK, "%s", err.msg);
    CHECK(replayed == 2 && torn == 1);
    CHECK(size_of(log) == (off_t)sizes[1]);

    /* Damage before the last record is refused, naming the file. */
    data[16 + 20] ^= 0x5a; /* inside the first of two records */
    CHECK(pt_write_file_atomic(log, data, len, &err) == PT_OK);
    pt_status s = restore(dir, &replayed, &torn, &err);
    CHECKF(s == PT_ERR_FORMAT && strstr(err.msg, "results.log") && strstr(err.msg, "damaged"),
           "%d %s", s, err.msg);
    pt_free(data);
    pt_remove_tree(dir);
}

static void test_queue_unsaved(const char *dir)
{
    srv_state *st = NULL;
    pt_error err = {0};
    CHECK(srv_state_open(dir, &srv_job_state_codec, &st, &err) == PT_OK);
    srv_job_record rec = {0};
    rec.id = 1;
    rec.state = PROTO_JOB_QUEUED;
    rec.params = PARAMS;
    srv_job_record *recs[1] = {&rec};
    CHECK(srv_state_save_queue(st, recs, 1, 2, &err) == PT_OK && !srv_state_queue_unsaved(st));
    /* A queue file that cannot be written (here: no room for one byte). */
    struct rlimit old, lim;
    CHECK(getrlimit(RLIMIT_FSIZE, &old) == 0);
    lim = old;
    lim.rlim_cur = 16;
    CHECK(setrlimit(RLIMIT_FSIZE, &lim) == 0);
    CHECK(srv_state_save_queue(st, recs, 1, 2, &err) == PT_ERR_IO);
    CHECK(setrlimit(RLIMIT_FSIZE, &old) == 0);
    CHECK(srv_state_queue_unsaved(st));
    CHECK(srv_state_save_queue(st, recs, 1, 2, &err) == PT_OK && !srv_state_queue_unsaved(st));
    srv_state_close(st);
    pt_remove_tree(dir);
}

/* The queue file keeps a job's environment (version 4), and a version 3
 * file, from before it, still loads: its jobs have none. */
static void test_queue_env_versions(const char *dir)
{
    srv_state *st = NULL;
    pt_error err = {0};
    CHECK(srv_state_open(dir, &srv_job_state_codec, &st, &err) == PT_OK);
    srv_job_record rec = {0}, *recs[1] = {&rec}, *got = NULL;
    rec.id = 1;
    rec.state = PROTO_JOB_QUEUED;
    snprintf(rec.name, sizeof rec.name, "sky");
    rec.params = PARAMS;
    snprintf(rec.params.env.name, sizeof rec.params.env.name, ".ptfarm/environment");
    rec.params.env.strength = 2.0f;
    rec.params.env.rotate_deg = -30.0f;
    uint32_t n = 0;
    uint64_t next = 0;
    CHECK(srv_state_save_queue(st, recs, 1, 2, &err) == PT_OK);
    CHECK(srv_state_load_queue(st, &got, &n, &next, &err) == PT_OK && n == 1);
    CHECK(got && proto_env_same(&got->params.env, &rec.params.env));
    pt_free(got);
    got = NULL;
    rec.params.env = PARAMS.env;
    rec.params.env.background = 1;
    rec.params.env.rgb[1] = 0.5f;
    CHECK(srv_state_save_queue(st, recs, 1, 2, &err) == PT_OK);
    CHECK(srv_state_load_queue(st, &got, &n, &next, &err) == PT_OK && n == 1);
    CHECK(got && proto_env_same(&got->params.env, &rec.params.env));
    pt_free(got);
    got = NULL;

    /* Version 3: the same record without the ENV block (23 bytes with no map
     * name), the film flags (4), the variant (2, empty), the shutter (16) and
     * the clamps and guiding (8 + 25), which sit after the camera, and without the depth-cap count
     * (8), version 8's rejected count (8), version 6's frame block (27 with no animation and no
     * frame done ahead) and version 10's clamped count (8), its last fields. */
    rec.params.env = PARAMS.env;
    CHECK(srv_state_save_queue(st, recs, 1, 2, &err) == PT_OK);
    char qp[512];
    snprintf(qp, sizeof qp, "%s/queue", dir);
    uint8_t *f = NULL;
    size_t len = 0;
    CHECK(pt_read_file(qp, 1 << 20, &f, &len, &err) == PT_OK);
    size_t at = 8 + 8 + 4 + 8 + 8 + 1 + 4 + (2 + strlen(rec.name)) + 2 + 2 + 2 + 8 + 9 * 4 + 2 * 8 +
                2 + strlen(rec.params.camera);
    if (f && len > at + 78 + 12 + 43) {
        memmove(f + at, f + at + 78, len - at - 78);
        len -= 78;
        /* the capped and rejected counts, frames and clamped count before the CRC */
        memmove(f + len - 55, f + len - 4, 4);
        len -= 51;
        proto_put_u32(f + 4, 3);
        proto_put_u32(f + len - 4, proto_crc32c(0, f, len - 4));
        CHECK(pt_write_file_atomic(qp, f, len, &err) == PT_OK);
        CHECKF(srv_state_load_queue(st, &got, &n, &next, &err) == PT_OK && n == 1, "%s", err.msg);
        proto_env none;
        proto_env_none(&none);
        CHECK(got && proto_env_same(&got->params.env, &none) && strcmp(got->name, "sky") == 0 &&
              got->params.spp == PARAMS.spp);
        pt_free(got);
    }
    pt_free(f);
    srv_state_close(st);
    pt_remove_tree(dir);
}

/* A frame range's record (version 5): its range, pose and frames done
 * round-trip; a record whose frames done do not fit its range is refused
 * naming the file. */
static void test_queue_frames(const char *dir)
{
    srv_state *st = NULL;
    pt_error err = {0};
    CHECK(srv_state_open(dir, &srv_job_state_codec, &st, &err) == PT_OK);
    srv_job_record rec = {0}, *recs[1] = {&rec}, *got = NULL;
    rec.id = 4;
    rec.state = PROTO_JOB_RUNNING;
    rec.params = PARAMS;
    rec.frames = (pt_frames){1001, 1100, 1};
    rec.fps = 23.976;
    snprintf(rec.animation, sizeof rec.animation, "Walk");
    rec.frames_done = 7;
    rec.ndone_ahead = 2;
    rec.done_ahead[0] = 9;
    rec.done_ahead[1] = 12;
    uint32_t n = 0;
    uint64_t next = 0;
    CHECK(srv_state_save_queue(st, recs, 1, 5, &err) == PT_OK);
    CHECK(srv_state_load_queue(st, &got, &n, &next, &err) == PT_OK && n == 1);
    CHECK(got && got->frames.first == 1001 && got->frames.last == 1100 && got->frames.step == 1 &&
          got->fps == 23.976 && strcmp(got->animation, "Walk") == 0 && got->frames_done == 7 &&
          got->ndone_ahead == 2 && got->done_ahead[0] == 9 && got->done_ahead[1] == 12);
    pt_free(got);
    got = NULL;
    /* Each inconsistency, written as a queue file would be, is refused. */
    for (int k = 0; k < 4; k++) {
        srv_job_record bad = rec, *brecs[1] = {&bad};
        if (k == 0)
            bad.frames_done = 101; /* more than its 100 frames */
        else if (k == 1)
            bad.done_ahead[1] = 7; /* "ahead" but within the done prefix */
        else if (k == 2)
            bad.frames.last = 1000; /* reversed */
        else
            bad.fps = 0.0;
        CHECK(srv_state_save_queue(st, brecs, 1, 5, &err) == PT_OK);
        CHECKF(srv_state_load_queue(st, &got, &n, &next, &err) == PT_ERR_FORMAT &&
                   strstr(err.msg, "queue") && strstr(err.msg, "frame"),
               "case %d: %s", k, err.msg);
        pt_free(got);
        got = NULL;
    }
    srv_state_close(st);
    pt_remove_tree(dir);
}

/* An ended job's folder leaves jobs/ at once, moved to the trash, and the
 * state's sweeper removes it (by close at the latest), together with what a
 * crash left in the trash before the open. */
static void test_forget_swept(const char *dir)
{
    char p[512], left[512];
    pt_error err = {0};
    snprintf(left, sizeof left, "%s/trash/99", dir);
    CHECK(pt_mkdirs(left, 1, &err) == PT_OK);
    snprintf(p, sizeof p, "%s/trash/99/results.log", dir);
    CHECK(pt_write_file_atomic(p, "x", 1, &err) == PT_OK);
    srv_state *st = open_state(dir);
    uint64_t sizes[3];
    log_tasks(st, 3, sizes);
    snprintf(p, sizeof p, "%s/jobs/%u/results.log", dir, JOB_ID);
    CHECK(size_of(p) == (off_t)sizes[2]);
    srv_state_forget_job(st, JOB_ID);
    snprintf(p, sizeof p, "%s/jobs/%u", dir, JOB_ID);
    CHECK(access(p, F_OK) != 0);
    srv_state_close(st);
    snprintf(p, sizeof p, "%s/trash/%u", dir, JOB_ID);
    CHECK(access(p, F_OK) != 0);
    CHECK(access(left, F_OK) != 0);
    snprintf(p, sizeof p, "%s/trash", dir);
    CHECK(access(p, F_OK) == 0);
}

int main(void)
{
    umask(022);
    signal(SIGXFSZ, SIG_IGN);
    char dir[] = "/tmp/test_state_XXXXXX";
    if (!mkdtemp(dir)) {
        perror("mkdtemp");
        return 1;
    }
    test_short_write_cut_back(dir);
    test_torn_tail(dir);
    test_commit_many_taken(dir);
    test_queue_unsaved(dir);
    test_queue_env_versions(dir);
    test_queue_frames(dir);
    test_forget_swept(dir);
    pt_remove_tree(dir);
    return check_report();
}
