/*
 * test_dnshare.c - a frame's denoising shared with workers
 * (server/sched/dnshare.h), without sockets: a share of a 96 x 64 test
 * image cut into regions of 32 leases regions, serves their crops in
 * pieces of any size, takes results (as a worker computes them, from the
 * crop it was served) and refuses hostile ones; the writer's run then
 * finishes the frame to pt_denoise's bits, having verified each worker's
 * first region, caught the one whose bits differ, taken a region a worker
 * returned while it ran on another thread, and denoised the region of one
 * that stalls once it was out longer than the lease.
 */
#include <math.h>
#include <pthread.h>
#include <string.h>

#include "common/base/hash.h"
#include "protocol/wire.h"
#include "server/sched/dnshare.h"
#include "tests/check.h"
#include "tests/common/image/denoise_scene.h"

#define W 96u
#define H 64u
#define SIDE 32u

/* What a worker does with a task: the crop fetched through
 * srv_dnshare_chunk in pieces of `piece` bytes, its hash checked, denoised
 * whole, the region's pixels as DENOISE_RESULT's data (12 x N bytes). */
static uint8_t *worker_denoise(srv_dnshare *d, const proto_denoise_task *t, size_t piece,
                               proto_denoise_result *r)
{
    uint8_t *in = malloc((size_t)t->size), *buf = malloc(piece);
    CHECK(in && buf);
    uint64_t at = 0;
    while (at < t->size) {
        size_t len;
        uint64_t total, job;
        CHECK(srv_dnshare_chunk(d, t->hash, at, buf, piece, &len, &total, &job));
        CHECK(total == t->size && job == t->job_id && len > 0);
        memcpy(in + at, buf, len);
        at += len;
    }
    uint8_t h[32];
    pt_sha256(in, (size_t)t->size, h);
    CHECK(memcmp(h, t->hash, 32) == 0);
    size_t plane = (size_t)t->crop_w * t->crop_h;
    float *v = malloc(t->size);
    CHECK(v != NULL);
    for (size_t i = 0; i < plane * PT_DENOISE_PLANES; i++)
        v[i] = proto_get_f32(in + 4 * i);
    const float *p[PT_DENOISE_PLANES];
    for (int k = 0; k < PT_DENOISE_PLANES; k++)
        p[k] = v + k * plane;
    pt_denoise_input ci = {.width = t->crop_w, .height = t->crop_h, .despeckle = t->despeckle};
    pt_denoise_input_set_planes(&ci, p);
    float *o = malloc(3 * plane * sizeof(float));
    CHECK(o != NULL);
    float *const op[3] = {o, o + plane, o + 2 * plane};
    pt_error err = {0};
    CHECKF(pt_denoise(&ci, 1, op, &err) == PT_OK, "%s", err.msg);
    pt_rect g = t->region;
    size_t n = (size_t)(g.x1 - g.x0) * (g.y1 - g.y0);
    uint8_t *data = malloc(12 * n), *q = data;
    CHECK(data != NULL);
    for (int c = 0; c < 3; c++)
        for (uint32_t y = g.y0; y < g.y1; y++)
            for (uint32_t x = g.x0; x < g.x1; x++, q += 4)
                proto_put_f32(q, op[c][(size_t)y * t->crop_w + x]);
    *r = (proto_denoise_result){t->job_id, t->task_id, g, (uint32_t)n, data};
    free(in);
    free(buf);
    free(v);
    free(o);
    return data;
}

/* The writer's side on a thread of its own. */
typedef struct run_ctx {
    srv_dnshare *d;
    srv_dnshare_stats stats;
    pt_status st;
    pt_error err;
} run_ctx;

static void *run_writer(void *p)
{
    run_ctx *rc = p;
    rc->st = srv_dnshare_run(rc->d, 2, &rc->stats, &rc->err);
    return NULL;
}

int main(void)
{
    scene s;
    CHECK(scene_alloc(&s, W, H) == 0);
    scene_truth(&s);
    scene_noise(&s, 0.1, 31);
    pt_denoise_input in = scene_input(&s);
    in.despeckle = PT_DENOISE_DESPECKLE;
    pt_error err = {0};
    size_t n = (size_t)W * H;
    float *ref = malloc(3 * n * sizeof(float)), *got = calloc(3 * n, sizeof(float));
    CHECK(ref && got);
    float *const rp[3] = {ref, ref + n, ref + 2 * n}, *const gp[3] = {got, got + n, got + 2 * n};
    CHECKF(pt_denoise(&in, 2, rp, &err) == PT_OK, "%s", err.msg);

    srv_dnshare *d = NULL;
    CHECK(srv_dnshare_new(7, 0.0, &d, &err) == PT_OK);
    proto_denoise_task t;
    CHECK(!srv_dnshare_lease(d, 1, 1000, &t)); /* not open */
    CHECK(srv_dnshare_open(d, &in, SIDE, gp, 42, &err) == PT_OK);

    /* Region 0 to worker 1: its crop [0, 128) x [0, 64), served in pieces of
     * 1000 bytes (floats cut across pieces). */
    CHECK(srv_dnshare_lease(d, 1, 1000, &t));
    CHECK(t.job_id == 42 && t.task_id == (PROTO_DENOISE_TASK_BIT | 0) && t.lease_ms == 1000);
    CHECK(t.crop_w == W && t.crop_h == H && t.region.x0 == 0 && t.region.x1 == SIDE);
    CHECK(t.size == (uint64_t)W * H * PT_DENOISE_PLANES * 4);
    CHECK(srv_dnshare_held(d, 1) == 1 && srv_dnshare_held(d, 2) == 0);
    proto_denoise_result r;
    uint8_t *data = worker_denoise(d, &t, 1000, &r);

    /* Hostile results are refused with a reason; others' are dropped. */
    proto_denoise_result bad = r;
    bad.region.x1 = SIDE - 1;
    CHECK(srv_dnshare_result(d, 1, 1, &bad, &err) == SRV_DNSHARE_INVALID &&
          strstr(err.msg, "another rectangle"));
    bad = r;
    bad.task_id = PROTO_DENOISE_TASK_BIT | 99;
    CHECK(srv_dnshare_result(d, 1, 1, &bad, &err) == SRV_DNSHARE_INVALID &&
          strstr(err.msg, "region 99 of 6"));
    uint8_t keep[4];
    memcpy(keep, data + 40, 4);
    proto_put_f32(data + 40, NAN);
    CHECK(srv_dnshare_result(d, 1, 1, &r, &err) == SRV_DNSHARE_INVALID &&
          strstr(err.msg, "holds nan"));
    proto_put_f32(data + 40, 1e30f);
    CHECK(srv_dnshare_result(d, 1, 1, &r, &err) == SRV_DNSHARE_INVALID);
    memcpy(data + 40, keep, 4);
    CHECK(srv_dnshare_result(d, 2, 1, &r, &err) == SRV_DNSHARE_DROPPED); /* not leased to 2 */
    CHECK(srv_dnshare_held(d, 1) == 1);
    CHECK(srv_dnshare_result(d, 1, 1, &r, &err) == SRV_DNSHARE_TAKEN);
    CHECK(srv_dnshare_held(d, 1) == 0);
    free(data);

    /* Region 1 to worker 2, which lies: one bit of its first value. */
    CHECK(srv_dnshare_lease(d, 2, 1000, &t));
    CHECK(t.task_id == (PROTO_DENOISE_TASK_BIT | 1));
    data = worker_denoise(d, &t, 4096, &r);
    data[0] ^= 1;
    CHECK(srv_dnshare_result(d, 2, 1, &r, &err) == SRV_DNSHARE_TAKEN);
    free(data);
    /* Region 2 to worker 3, which leaves: the region is free again. */
    CHECK(srv_dnshare_lease(d, 3, 1000, &t));
    srv_dnshare_release(d, 3);
    CHECK(srv_dnshare_held(d, 3) == 0);

    /* Region 2 again, to worker 4, which stalls: the writer waits for it, then
     * races it. */
    CHECK(srv_dnshare_lease(d, 4, 300, &t));
    CHECK(t.task_id == (PROTO_DENOISE_TASK_BIT | 2)); /* the one worker 3 left */

    /* Region 3 to worker 5, which fetches and returns it while the writer
     * runs on another thread (as the loop and the writer do). */
    CHECK(srv_dnshare_lease(d, 5, 60000, &t));
    CHECK(t.task_id == (PROTO_DENOISE_TASK_BIT | 3));

    /* The writer does the rest and verifies the workers' first regions. */
    uint64_t owner;
    CHECK(!srv_dnshare_take_liar(d, &owner));
    run_ctx rc = {d, {0}, PT_OK, {0}};
    pthread_t th;
    CHECK(pthread_create(&th, NULL, run_writer, &rc) == 0);
    data = worker_denoise(d, &t, 65536, &r);
    CHECK(srv_dnshare_result(d, 5, 1, &r, &err) == SRV_DNSHARE_TAKEN);
    free(data);
    pthread_join(th, NULL);
    CHECKF(rc.st == PT_OK, "%s", rc.err.msg);
    srv_dnshare_close(d);
    srv_dnshare_stats st = rc.stats;
    printf("dnshare: %u regions, %u from workers, %u verified, %u liars\n", st.regions,
           st.by_workers, st.verified, st.liars);
    CHECK(st.regions == 6 && st.by_workers == 2 && st.verified == 2 && st.liars == 1);
    CHECK(srv_dnshare_take_liar(d, &owner) && owner == 2);
    CHECK(!srv_dnshare_take_liar(d, &owner));
    CHECK(memcmp(got, ref, 3 * n * sizeof(float)) == 0);
    /* After close: nothing leased, a late result dropped. */
    CHECK(!srv_dnshare_lease(d, 1, 1000, &t));
    CHECK(srv_dnshare_result(d, 1, 0, &r, &err) == SRV_DNSHARE_DROPPED);
    srv_dnshare_free(d);
    free(ref);
    free(got);
    scene_free(&s);
    return check_report();
}
