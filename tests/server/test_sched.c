/*
 * test_sched.c - the scheduler built without sockets: an srv_server with no
 * loop, no listener and no connection, its queue driven by calls and its
 * events (srv_sched_events) recorded in process.
 *
 *  a. Leases in queue order: a queued job starts at its first lease, a
 *     leaving worker's leases come back (srv_queue_release_owner) and are
 *     leased again, JOB_INFO counts the workers holding leases through the
 *     each_worker event, and every merged result raises result_merged with
 *     its owner and samples.
 *  b. Expiry: a lease past its heartbeat deadline is requeued by
 *     srv_queue_expire, which says it walked the leases and raises
 *     owner_missed for the owner; within EXPIRE_MS it does not walk again.
 *  c. Verification: with verify_fraction 1 every task is picked, and the
 *     copies that the other owner renders are judged (srv_job_check): all
 *     match, and no owner is called a liar.
 *  d. A frame range: its frames are leased earliest first, one frame in
 *     flight (max_pixels 0), each written under its own name, and the range
 *     ends DONE once its last frame is, with job_changed raised.
 *  e. A job ended early (cancelled) raises job_ended (workers drop its
 *     tasks) and job_changed; a queued one never started raises no
 *     job_ended.
 *  f. Frames in flight hold no more pixels than --max-pixels and no more
 *     film than --max-film-mb: render passes (480 bytes a pixel against 72)
 *     leave fewer frames in flight.
 */
#define _DEFAULT_SOURCE /* usleep, mkdtemp */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/clock.h"
#include "server/app/mode.h"
#include "server/sched/frames.h"
#include "server/sched/job.h"
#include "server/sched/queue.h"
#include "tests/check.h"

/* ---- the events, recorded ---- */

static struct {
    uint32_t ended, changed, merged, missed;
    uint64_t last_owner, last_merged, missed_owner, changed_id, ended_id;
    uint8_t changed_state;
    uint64_t owners[4]; /* the "ready workers" each_worker walks */
    uint32_t nowners;
} ev;

static void on_ended(srv_server *s, const srv_entry *j)
{
    (void)s;
    ev.ended++;
    ev.ended_id = j->rec.id;
}

static void on_changed(srv_server *s, const srv_entry *j)
{
    (void)s;
    ev.changed++;
    ev.changed_id = j->rec.id;
    ev.changed_state = j->rec.state;
}

static void on_merged(srv_server *s, uint64_t owner, uint64_t merged, uint64_t now)
{
    (void)s;
    (void)now;
    ev.merged++;
    ev.last_owner = owner;
    ev.last_merged = merged;
}

static void on_missed(srv_server *s, uint64_t owner, uint64_t now)
{
    (void)s;
    (void)now;
    ev.missed++;
    ev.missed_owner = owner;
}

static void each_worker(srv_server *s, void (*fn)(void *ctx, uint64_t owner), void *ctx)
{
    (void)s;
    for (uint32_t i = 0; i < ev.nowners; i++)
        fn(ctx, ev.owners[i]);
}

static const srv_sched_events EVENTS = {on_ended,  on_changed,  on_merged,
                                        on_missed, each_worker, NULL};

/* ---- a server without sockets ---- */

static char dir[] = "/tmp/test_sched.XXXXXX";

static void server_init(srv_server *s, srv_config *cfg, double verify)
{
    memset(cfg, 0, sizeof *cfg);
    cfg->scene_path = "in-process"; /* one-job mode: nothing durable */
    cfg->lease_ms = 200;
    cfg->verify_fraction = verify;
    cfg->save_interval = 1e9;
    cfg->quiet = 1;
    memset(s, 0, sizeof *s);
    s->cfg = cfg;
    s->mode = srv_mode_for(cfg);
    s->events = &EVENTS;
    s->ranges = &srv_frames_ops;
    s->next_job_id = 1;
    memset(&ev, 0, sizeof ev);
}

/* A job of w x h pixels, spp samples in chunks of chunk, tiles of 16,
 * writing name in the test's folder; queued. */
static srv_entry *add_job(srv_server *s, uint64_t id, uint32_t w, uint32_t h, uint32_t spp,
                          uint32_t chunk, const char *name)
{
    srv_entry *j = pt_calloc(1, sizeof *j);
    CHECK(j != NULL);
    j->rec.id = j->rec.seq = id;
    j->rec.state = PROTO_JOB_QUEUED;
    j->rec.error = -1.0;
    srv_job_params p = {
        w, h,  spp,    16,     chunk, 5,  16, 3, 0.0, 0, 0.0, "", {"", 1.0f, 0.0f, 0, {0, 0, 0}},
        0, "", {0, 0}, {0, 0}, 0,     {0}};
    j->rec.params = p;
    j->rec.hash[0] = (uint8_t)id;
    snprintf(j->rec.scene, sizeof j->rec.scene, "scene.gltf");
    snprintf(j->out_path, sizeof j->out_path, "%s/%s", dir, name);
    srv_queue_insert(s, j);
    return j;
}

/* Deterministic pixels for a task (the same task, the same bits; salt
 * changes them). */
static void fake_result(const proto_task *t, uint64_t salt, pt_pixel_acc *px, proto_result *r)
{
    uint32_t n = (t->tile.x1 - t->tile.x0) * (t->tile.y1 - t->tile.y0);
    uint64_t h = t->task_id * 0x9E3779B97F4A7C15ull + 1 + salt + t->job_id;
    for (uint32_t i = 0; i < n; i++) {
        h ^= h >> 33;
        h *= 0xff51afd7ed558ccdull;
        double v = (double)(h >> 11) / 9007199254740992.0;
        px[i] = pt_pixel_acc_of(v, v * 0.5, v * 0.25, v * v, t->s1 - t->s0, 0);
    }
    memset(r, 0, sizeof *r);
    r->job_id = t->job_id;
    r->task_id = t->task_id;
    r->tile = t->tile;
    r->s0 = t->s0;
    r->s1 = t->s1;
    r->npixels = n;
    r->pixels = px;
}

static pt_pixel_acc px[16 * 16];

/* Answers task t of owner as a worker would: validated, then merged
 * (srv_queue_merge) or judged as a verification copy. Returns the outcome. */
static srv_outcome answer(srv_server *s, uint64_t owner, const proto_task *t, uint64_t salt)
{
    srv_entry *j = srv_queue_find_any(s, t->job_id);
    CHECK(j != NULL && j->job != NULL);
    if (!j || !j->job)
        return SRV_INVALID;
    proto_result r;
    fake_result(t, salt, px, &r);
    int li;
    pt_error err = {0};
    srv_outcome o = srv_job_validate(j->job, owner, &r, &li, &err);
    if (o == SRV_CHECK) {
        srv_verdict v;
        srv_job_check(j->job, li, &r, &v);
        CHECKF(v.kind == SRV_V_MATCH, "task %llu: verdict %d", (unsigned long long)t->task_id,
               v.kind);
        return o;
    }
    CHECKF(o == SRV_MERGED, "task %llu: %s", (unsigned long long)t->task_id, err.msg);
    return o == SRV_MERGED ? srv_queue_merge(s, j, owner, li, &r, pt_now_ms(), &err) : o;
}

/* Runs the queue's rounds until no job is active (ends, final images). */
static void settle(srv_server *s)
{
    for (int i = 0; i < 2000; i++) {
        srv_queue_end_complete(s);
        srv_queue_tick(s, pt_now_ms());
        int active = 0;
        for (srv_entry *j = s->jobs; j; j = j->next)
            active |= srv_entry_active(j);
        if (!active)
            return;
        usleep(2000);
    }
}

static int exists(const char *name)
{
    char path[512];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    return access(path, F_OK) == 0;
}

static void leases(void)
{
    srv_config cfg;
    srv_server s;
    server_init(&s, &cfg, 0.0);
    srv_entry *j = add_job(&s, 1, 32, 32, 8, 8, "a.exr"); /* 4 tiles, one pass */
    uint64_t now = pt_now_ms();
    proto_task t1, t2;
    CHECK(srv_queue_lease(&s, 1, now, &t1) == 1);
    CHECK(j->rec.state == PROTO_JOB_RUNNING && t1.job_id == 1 && t1.task_id == 0);
    CHECK(srv_queue_lease(&s, 2, now, &t2) == 1 && t2.task_id == 1);
    /* JOB_INFO's workers: the owners the events name that hold a lease. */
    ev.owners[0] = 1;
    ev.owners[1] = 2;
    ev.owners[2] = 7; /* holds none */
    ev.nowners = 3;
    proto_job_info m;
    srv_queue_info(&s, j, &m);
    CHECK(m.workers == 2);
    /* Owner 2 leaves: its task is requeued and leased again, to owner 1. */
    CHECK(srv_queue_release_owner(&s, 2) == 1);
    CHECK(s.counters.tasks_requeued == 1);
    ev.nowners = 1;
    srv_queue_info(&s, j, &m);
    CHECK(m.workers == 1);
    proto_task t3;
    CHECK(srv_queue_lease(&s, 1, now, &t3) == 1 && t3.task_id == 1);
    CHECK(answer(&s, 1, &t1, 0) == SRV_MERGED);
    CHECK(ev.merged == 1 && ev.last_owner == 1 && ev.last_merged == 16u * 16u * 8u);
    CHECK(s.counters.samples_merged == 16u * 16u * 8u);
    /* The result of a task the owner no longer holds is not merged. */
    proto_result r;
    fake_result(&t2, 0, px, &r);
    int li;
    CHECK(srv_job_validate(j->job, 2, &r, &li, NULL) == SRV_NOT_LEASED);
    CHECK(answer(&s, 1, &t3, 0) == SRV_MERGED);
    proto_task t;
    while (srv_queue_lease(&s, 1, now, &t))
        CHECK(answer(&s, 1, &t, 0) == SRV_MERGED);
    CHECK(ev.merged == 4 && srv_job_complete(j->job));
    settle(&s);
    CHECK(j->rec.state == PROTO_JOB_DONE && j->rec.samples_done == 32u * 32u * 8u);
    CHECK(ev.changed_id == 1 && ev.changed_state == PROTO_JOB_DONE);
    CHECK(ev.ended == 0); /* done, not ended early */
    CHECK(exists("a.exr"));
    srv_queue_free(&s);
}

static void expiry(void)
{
    srv_config cfg;
    srv_server s;
    server_init(&s, &cfg, 0.0);
    add_job(&s, 1, 32, 16, 4, 4, "b.exr");
    uint64_t now = pt_now_ms();
    proto_task t;
    CHECK(srv_queue_lease(&s, 3, now, &t) == 1 && t.task_id == 0);
    /* Within its heartbeat deadline: nothing expires. */
    CHECK(srv_queue_expire(&s, now + 1) == 1);
    CHECK(ev.missed == 0 && s.counters.tasks_expired == 0);
    /* Walked at most every 50 ms. */
    CHECK(srv_queue_expire(&s, now + 2) == 0);
    /* Past it (no heartbeat): requeued, and its owner told of the miss. */
    uint64_t later = now + 100u * cfg.lease_ms;
    CHECK(srv_queue_expire(&s, later) == 1);
    CHECK(s.counters.tasks_expired == 1);
    CHECK(ev.missed == 1 && ev.missed_owner == 3);
    proto_task again;
    CHECK(srv_queue_lease(&s, 4, later, &again) == 1 && again.task_id == 0);
    srv_queue_free(&s);
}

static void verification(void)
{
    srv_config cfg;
    srv_server s;
    server_init(&s, &cfg, 1.0);
    srv_entry *j = add_job(&s, 1, 32, 32, 8, 8, "c.exr");
    uint64_t now = pt_now_ms();
    uint32_t checks = 0, merges = 0;
    for (int round = 0; round < 64 && !(j->job && srv_job_complete(j->job)); round++) {
        proto_task a, b;
        int la = srv_queue_lease(&s, 1, now, &a), lb = srv_queue_lease(&s, 2, now, &b);
        if (la) {
            srv_outcome o = answer(&s, 1, &a, 0);
            checks += o == SRV_CHECK;
            merges += o == SRV_MERGED;
        }
        if (lb) {
            srv_outcome o = answer(&s, 2, &b, 0);
            checks += o == SRV_CHECK;
            merges += o == SRV_MERGED;
        }
    }
    CHECK(j->job && srv_job_complete(j->job));
    srv_verify_stats v = srv_job_verify_stats(j->job);
    /* Every task picked; those whose copy another owner rendered compared
     * (a copy is never its own owner's), all matching. */
    CHECKF(checks >= 2 && merges == 4, "%u checks, %u merges", checks, merges);
    CHECK(v.picked == 4 && v.matched == checks && v.mismatched == 0 && v.liars == 0);
    settle(&s);
    CHECK(j->rec.state == PROTO_JOB_DONE);
    srv_queue_free(&s);
}

static void frame_range(void)
{
    srv_config cfg;
    srv_server s;
    server_init(&s, &cfg, 0.0);
    srv_entry *p = add_job(&s, 5, 32, 16, 4, 4, "f_####.exr");
    p->rec.frames = (pt_frames){1, 3, 1};
    p->rec.fps = 24.0;
    uint64_t now = pt_now_ms();
    uint32_t last = 0, tasks = 0;
    int ordered = 1;
    /* Rounds until the range ends (each frame's writer is a thread: on a
     * loaded machine a frame's image may take a while), at most 60 s. */
    for (uint64_t end = now + 60000; srv_entry_active(p) && pt_now_ms() < end;) {
        proto_task t;
        while (srv_queue_lease(&s, 1, now, &t)) {
            uint32_t frame = (uint32_t)(t.job_id - srv_frame_job_id(5, 0));
            ordered &= frame >= last && frame >= 1 && frame <= 3;
            last = frame;
            tasks++;
            CHECK(answer(&s, 1, &t, 0) == SRV_MERGED);
        }
        srv_queue_end_complete(&s);
        srv_queue_tick(&s, pt_now_ms());
        usleep(2000);
    }
    settle(&s);
    CHECK(ordered && last == 3);
    CHECK(tasks == 3 * 2); /* two tiles a frame, one pass */
    CHECK(p->rec.state == PROTO_JOB_DONE && p->rec.frames_done == 3);
    CHECK(exists("f_0001.exr") && exists("f_0002.exr") && exists("f_0003.exr"));
    CHECK(ev.changed_id == 5 && ev.changed_state == PROTO_JOB_DONE);
    srv_queue_free(&s);
}

static void ended_early(void)
{
    srv_config cfg;
    srv_server s;
    server_init(&s, &cfg, 0.0);
    srv_entry *a = add_job(&s, 1, 32, 16, 4, 4, "d.exr");
    srv_entry *b = add_job(&s, 2, 32, 16, 4, 4, "e.exr");
    proto_task t;
    CHECK(srv_queue_lease(&s, 1, pt_now_ms(), &t) == 1 && t.job_id == 1);
    srv_queue_end_job(&s, b, PROTO_JOB_CANCELLED, "cancelled"); /* never started */
    CHECK(ev.ended == 0 && ev.changed == 1 && ev.changed_id == 2);
    srv_queue_end_job(&s, a, PROTO_JOB_CANCELLED, "cancelled");
    CHECK(ev.ended == 1 && ev.ended_id == 1);
    CHECK(ev.changed == 2 && ev.changed_state == PROTO_JOB_CANCELLED);
    CHECK(srv_queue_lease(&s, 1, pt_now_ms(), &t) == 0);
    srv_queue_free(&s);
}

static void frames_in_flight(void)
{
    srv_caps caps = {.max_pixels = 16777216, .max_film = 4096ull << 20};
    uint32_t all = proto_film_of_passes(PT_PASS_ALL);
    CHECK(srv_film_bytes(1920, 1080, 0) == 1920ull * 1080 * 72);
    CHECK(srv_film_bytes(1920, 1080, all) == 1920ull * 1080 * 480);
    /* 1080p: 8 frames' pixels fit, and 8 beauty films (1.2 GB); with passes
     * a film is 995 MB, so 4 fit in 4 GiB. */
    CHECK(srv_frames_in_flight(&caps, 1920, 1080, 0) == SRV_FRAMES_AHEAD);
    CHECK(srv_frames_in_flight(&caps, 1920, 1080, all) == 4);
    /* 4K with passes: one film (3.98 GB) at a time; larger: still one. */
    CHECK(srv_frames_in_flight(&caps, 3840, 2160, all) == 1);
    CHECK(srv_frames_in_flight(&caps, 4096, 4096, all) == 1);
    /* No film cap (0): pixels alone, as before. */
    caps.max_film = 0;
    CHECK(srv_frames_in_flight(&caps, 1920, 1080, all) == SRV_FRAMES_AHEAD);
    CHECK(srv_frames_in_flight(&caps, 4096, 2048, all) == 2);
}

int main(void)
{
    if (!mkdtemp(dir)) {
        perror("mkdtemp");
        return 1;
    }
    leases();
    expiry();
    verification();
    frame_range();
    ended_early();
    frames_in_flight();
    char cmd[128];
    snprintf(cmd, sizeof cmd, "rm -rf %s", dir);
    if (system(cmd) != 0)
        fprintf(stderr, "cannot remove %s\n", dir);
    return check_report();
}
