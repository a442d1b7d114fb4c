/*
 * ptbench-durable - the event loop's time per result for queue mode's
 * durable steps, with the state folder's own code (server/store/state.h) on a real
 * folder: receiving a result (frame and RESULT decode, validation), logging
 * it, the group commit, checkpoints and the merge.
 *
 * Builds a job (default 2048x2048, tiles 32, chunks 16, 8 passes), leases
 * each pass's tasks, encodes a synthetic RESULT frame for each (not timed),
 * then feeds them in rounds of R results (R results per loop round, as from
 * R busy workers) through what the loop does with them, timing each step on
 * this thread: wall time (what the loop cannot spend on anything else, a
 * blocking fdatasync included) and this thread's CPU time. Work done by the
 * state's own threads (the commit's fdatasync, a checkpoint's writing) is
 * not counted: the loop does not wait on it.
 *
 * The same file builds against the state API before group commits moved off
 * the loop (no SRV_CKPT_FILM_MULTIPLE): each record is logged with its own
 * CRC32C, merged at once, the round ends with srv_state_sync, and a
 * checkpoint is written on the loop when the log passes max(16 MiB, film).
 * That is how the "before" figures of docs/ARCHITECTURE.md were taken.
 *
 *   ptbench-durable [--res WxH] [--tile N] [--chunk N] [--passes P]
 *                   [--round R] [--dir DIR]
 */
#define _GNU_SOURCE
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "common/base/alloc.h"
#include "common/base/clock.h"
#include "common/base/fsutil.h"
#include "common/base/opt.h"
#include "protocol/frame.h"
#include "protocol/msg.h"
#include "server/sched/job.h"
#include "server/store/state.h"

enum { RECEIVE, LOG, COMMIT, CHECKPOINT, MERGE, NSTEPS };
static const char *const STEP[NSTEPS] = {"receive", "log append", "commit", "checkpoint", "merge"};
static double wall[NSTEPS], cpu[NSTEPS];
static double t_wall, t_cpu;
static double nest_wall, nest_cpu; /* timed as another step inside this one */

static double cpu_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

static void start(void)
{
    nest_wall = nest_cpu = 0;
    t_wall = pt_now_s();
    t_cpu = cpu_now();
}

static void stop(int step)
{
    wall[step] += pt_now_s() - t_wall - nest_wall;
    cpu[step] += cpu_now() - t_cpu - nest_cpu;
}

static void die(const char *what, const pt_error *err)
{
    fprintf(stderr, "ptbench-durable: %s: %s\n", what, err ? err->msg : "failed");
    exit(1);
}

static pt_pixel_acc *scratch;

#ifdef SRV_CKPT_FILM_MULTIPLE
/* Validates and merges the result in frame (as the loop does once it may). */
static void merge(srv_job *job, const uint8_t *frame, size_t len)
{
    proto_result r;
    int li;
    pt_error err = {0};
    if (proto_msg_decode_result(frame + PROTO_FRAME_HEADER, len - PROTO_FRAME_OVERHEAD, scratch,
                                PROTO_MAX_TILE_PIXELS, &r, &err) != PT_OK)
        die("decode", &err);
    if (srv_job_validate(job, 1, &r, &li, &err) != SRV_MERGED ||
        srv_job_result_validated(job, li, &r, 0, &err) != SRV_MERGED)
        die("merge", &err);
    proto_result_fini(&r);
}

/* Results logged and not merged yet: their frames and commits. */
typedef struct pend {
    uint8_t *frame;
    size_t len;
    uint64_t commit;
} pend;
static pend *pends;
static uint32_t npend;
static srv_job *g_job;
static int g_failed;

static void on_commit(void *ctx, uint64_t id, pt_status st, const pt_error *err)
{
    (void)ctx;
    (void)id;
    if (st != PT_OK)
        die("commit", err);
    g_failed = 0;
}

static void collect(srv_state *st, int wait)
{
    uint64_t done;
    while (srv_state_commit_collect(st, wait, &done, on_commit, NULL)) {
        wait = 0;
        uint32_t k = 0, i = 0;
        for (; i < npend && pends[i].commit <= done; i++) {
            double w0 = pt_now_s(), c0 = cpu_now();
            merge(g_job, pends[i].frame, pends[i].len);
            double dw = pt_now_s() - w0, dc = cpu_now() - c0;
            wall[MERGE] += dw;
            cpu[MERGE] += dc;
            nest_wall += dw;
            nest_cpu += dc;
            pt_free(pends[i].frame);
        }
        for (; i < npend; i++)
            pends[k++] = pends[i];
        npend = k;
    }
}
#endif

int main(int argc, char **argv)
{
    uint32_t w = 2048, h = 2048, tile = 32, chunk = 16, passes = 8, round = 16;
    const char *dir = "/tmp";
    pt_status opt = PT_OK;
    pt_error err = {0};
    for (int i = 1; i < argc && opt == PT_OK; i++) {
        if (!strcmp(argv[i], "--res") && i + 1 < argc)
            opt = pt_opt_res("--res", argv[++i], 16384, &w, &h, &err);
        else if (!strcmp(argv[i], "--tile") && i + 1 < argc)
            opt = pt_opt_u32("--tile", argv[++i], 1, PT_TILE_MAX, &tile, &err);
        else if (!strcmp(argv[i], "--chunk") && i + 1 < argc)
            opt = pt_opt_u32("--chunk", argv[++i], 1, 1u << 20, &chunk, &err);
        else if (!strcmp(argv[i], "--passes") && i + 1 < argc)
            opt = pt_opt_u32("--passes", argv[++i], 1, 4096, &passes, &err);
        else if (!strcmp(argv[i], "--round") && i + 1 < argc)
            opt = pt_opt_u32("--round", argv[++i], 1, 1u << 20, &round, &err);
        else if (!strcmp(argv[i], "--dir") && i + 1 < argc)
            dir = argv[++i];
        else {
            printf("usage: ptbench-durable [--res WxH] [--tile N] [--chunk N] [--passes P] "
                   "[--round R] [--dir DIR]\n");
            return strcmp(argv[i], "--help") && strcmp(argv[i], "-h") ? 2 : 0;
        }
    }
    if (opt != PT_OK)
        die("options", &err);
    char sdir[4096], jdir[4200];
    snprintf(sdir, sizeof sdir, "%s/ptbench-durable-XXXXXX", dir);
    if (!mkdtemp(sdir))
        die("mkdtemp", NULL);
    snprintf(jdir, sizeof jdir, "%s/jobs/1", sdir);
    srv_state *st = NULL;
    if (srv_state_open(sdir, &srv_job_state_codec, &st, &err) != PT_OK ||
        pt_mkdirs(jdir, 1, &err) != PT_OK)
        die(sdir, &err);
    srv_job_params p = {0};
    p.width = w;
    p.height = h;
    p.spp = chunk * passes;
    p.tile = tile;
    p.chunk = chunk;
    p.seed = 1;
    p.max_depth = 16;
    p.rr_depth = 3;
    p.env.strength = 1.0f;
    uint8_t hash[32] = {0};
    srv_job *job = NULL;
    if (srv_job_new(1, &p, hash, &job, &err) != PT_OK)
        die("job", &err);
    uint32_t ntiles = srv_job_tiles(job);
    uint64_t film_bytes = (uint64_t)w * h * sizeof(pt_pixel_acc); /* as srv_queue_tick counts */
#ifdef SRV_CKPT_FILM_MULTIPLE
    g_job = job;
    pends = pt_malloc_array((size_t)ntiles * passes, sizeof *pends);
    uint64_t limit = srv_state_ckpt_limit(st, film_bytes);
#else
    uint64_t limit = film_bytes > (16u << 20) ? film_bytes : (16u << 20);
#endif
    scratch = pt_malloc_array(PROTO_MAX_TILE_PIXELS, sizeof *scratch);
    pt_pixel_acc *px = pt_malloc_array((size_t)tile * tile, sizeof *px);
    size_t *offs = pt_malloc_array(ntiles + 1, sizeof *offs);
    proto_writer wr;
    proto_writer_init(&wr, (size_t)8 << 30);
    uint64_t results = 0, ckpts = 0, bytes = 0;
    for (uint32_t pass = 0; pass < passes; pass++) {
        proto_writer_reset(&wr);
        proto_task t;
        uint32_t n = 0;
        while (n < ntiles && srv_job_lease(job, 1, 0, 600000, &t)) {
            uint32_t np = (t.tile.x1 - t.tile.x0) * (t.tile.y1 - t.tile.y0);
            for (uint32_t i = 0; i < np; i++)
                px[i] = (pt_pixel_acc){{(pt_i128)i + 1, 1, 1}, 1, t.s1 - t.s0, 0};
            proto_result res = {t.job_id, t.task_id, t.tile, t.s0, t.s1, 0, 1000, 0, np, px,
                                0,        NULL,      0,      0,    0,    0, NULL, 0, 0};
            size_t mark;
            offs[n++] = wr.len;
            if (proto_frame_begin(&wr, PROTO_MSG_RESULT, &mark, NULL) != PT_OK ||
                proto_msg_encode_result(&wr, &res, NULL) != PT_OK ||
                proto_frame_end(&wr, mark, NULL) != PT_OK)
                die("encode", NULL);
        }
        offs[n] = wr.len;
        bytes += wr.len;
        for (uint32_t i = 0; i < n; i++) {
            const uint8_t *frame = wr.buf + offs[i];
            size_t len = offs[i + 1] - offs[i];
            start();
            proto_frame f;
            size_t used;
            proto_result r;
            int li;
            if (proto_frame_decode(frame, len, PROTO_MAX_PAYLOAD, &f, &used, &err) != PT_OK ||
                proto_msg_decode_result(f.payload, f.len, scratch, PROTO_MAX_TILE_PIXELS, &r,
                                        &err) != PT_OK ||
                srv_job_validate(job, 1, &r, &li, &err) != SRV_MERGED)
                die("receive", &err);
            stop(RECEIVE);
#ifdef SRV_CKPT_FILM_MULTIPLE
            start();
            pends[npend].commit = srv_state_commit_next(st);
            if (srv_state_log_result(st, 1, frame, len, &err) != PT_OK)
                die("log", &err);
            pends[npend].frame = pt_malloc(len);
            memcpy(pends[npend].frame, frame, len);
            pends[npend++].len = len;
            stop(LOG);
            proto_result_fini(&r);
#else
            start();
            if (srv_state_log_result(st, 1, f.payload, f.len, &err) != PT_OK)
                die("log", &err);
            stop(LOG);
            start();
            if (srv_job_result_validated(job, li, &r, 0, &err) != SRV_MERGED)
                die("merge", &err);
            proto_result_fini(&r);
            stop(MERGE);
#endif
            results++;
            if ((i + 1) % round != 0 && i + 1 != n)
                continue;
                /* The end of a loop round. */
#ifdef SRV_CKPT_FILM_MULTIPLE
            start();
            collect(st, 0);
            srv_state_commit_start(st);
            stop(COMMIT);
            start();
            uint64_t id;
            pt_status cst;
            if (srv_state_checkpoint_collect(st, &id, &cst, &err) && cst != PT_OK)
                die("checkpoint", &err);
            if (!srv_state_checkpoint_busy(st) && srv_state_log_bytes(st, 1) >= limit) {
                srv_ckpt_extra x = {0, 0, 0};
                double s0 = pt_now_s();
                srv_job *snap = srv_job_snapshot(job);
                double s1 = pt_now_s();
                if (srv_state_checkpoint_start(st, snap, &x, &err) != PT_OK)
                    die("checkpoint", &err);
                if (getenv("PTBENCH_VERBOSE"))
                    fprintf(stderr, "checkpoint: snapshot %.2f ms, rotation %.2f ms\n",
                            (s1 - s0) * 1e3, (pt_now_s() - s1) * 1e3);
                for (uint32_t k = 0; k < npend; k++) {
                    pends[k].commit = srv_state_commit_next(st);
                    if (srv_state_log_result(st, 1, pends[k].frame, pends[k].len, &err) != PT_OK)
                        die("log", &err);
                }
                ckpts++;
            }
            stop(CHECKPOINT);
#else
            start();
            if (srv_state_sync(st, &err) != PT_OK)
                die("sync", &err);
            stop(COMMIT);
            start();
            if (srv_state_log_bytes(st, 1) >= limit) {
                srv_ckpt_extra x = {0, 0, 0};
                if (srv_state_checkpoint(st, job, &x, &err) != PT_OK)
                    die("checkpoint", &err);
                ckpts++;
            }
            stop(CHECKPOINT);
#endif
        }
    }
#ifdef SRV_CKPT_FILM_MULTIPLE
    /* What is still in flight: the loop would merge it in a later round. */
    while (npend) {
        srv_state_commit_start(st);
        uint64_t done;
        (void)done;
        collect(st, 1);
    }
    (void)g_failed;
#endif
    if (!srv_job_complete(job))
        die("the job is not complete", NULL);
    double tw = 0, tc = 0;
    printf("job              %ux%u, tiles %u, chunks of %u, %u passes: %llu results, %.1f MB, "
           "rounds of %u, %llu checkpoints (film %.1f MB, log limit %.1f MB)\n",
           w, h, tile, chunk, passes, (unsigned long long)results, (double)bytes / 1e6, round,
           (unsigned long long)ckpts, (double)film_bytes / 1e6, (double)limit / 1e6);
    printf("%-16s %10s %10s   (us per result of the loop thread)\n", "step", "wall", "cpu");
    for (int s = 0; s < NSTEPS; s++) {
        printf("%-16s %10.2f %10.2f\n", STEP[s], wall[s] * 1e6 / (double)results,
               cpu[s] * 1e6 / (double)results);
        tw += wall[s];
        tc += cpu[s];
    }
    printf("%-16s %10.2f %10.2f\n", "total", tw * 1e6 / (double)results,
           tc * 1e6 / (double)results);
    proto_writer_fini(&wr);
    pt_free(offs);
    pt_free(px);
    pt_free(scratch);
    srv_job_free(job);
    srv_state_close(st);
    pt_remove_tree(sdir);
    return 0;
}
