/*
 * ptbench-merge - how many results one coordinator can merge per second.
 *
 * Builds a job (default 1024x1024, tiles 32, chunks 16), leases every task,
 * encodes a synthetic RESULT frame for each, then times what the event loop
 * does per result: frame decode (with its CRC), RESULT decode and the merge
 * into the film (srv_job_result). Reports the median of R repetitions as
 * results/s and MB/s, and the worker cores one coordinator could feed at a
 * given per-core sample rate (--core-rate, samples/s).
 *
 *   ptbench-merge [--res WxH] [--tile N] [--chunk N] [--reps R] [--core-rate S]
 */
#include <float.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/clock.h"
#include "common/base/opt.h"
#include "common/base/version.h"
#include "protocol/frame.h"
#include "protocol/msg.h"
#include "server/sched/job.h"

static int cmp(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

int main(int argc, char **argv)
{
    uint32_t w = 1024, h = 1024, tile = 32, chunk = 16, reps = 5;
    double core_rate = 7e5;
    pt_status opt = PT_OK;
    pt_error opt_err = {0};
    for (int i = 1; i < argc && opt == PT_OK; i++) {
        if (!strcmp(argv[i], "--res") && i + 1 < argc)
            opt = pt_opt_res("--res", argv[++i], 16384, &w, &h, &opt_err);
        else if (!strcmp(argv[i], "--tile") && i + 1 < argc)
            opt = pt_opt_u32("--tile", argv[++i], 1, PT_TILE_MAX, &tile, &opt_err);
        else if (!strcmp(argv[i], "--chunk") && i + 1 < argc)
            opt = pt_opt_u32("--chunk", argv[++i], 1, 1u << 24, &chunk, &opt_err);
        else if (!strcmp(argv[i], "--reps") && i + 1 < argc)
            opt = pt_opt_u32("--reps", argv[++i], 1, 99, &reps, &opt_err);
        else if (!strcmp(argv[i], "--core-rate") && i + 1 < argc)
            opt = pt_opt_positive("--core-rate", argv[++i], DBL_MAX, &core_rate, &opt_err);
        else if (!strcmp(argv[i], "--version"))
            return pt_version_print("ptbench-merge");
        else {
            printf("usage: ptbench-merge [--res WxH] [--tile N] [--chunk N] [--reps R] "
                   "[--core-rate SAMPLES_PER_S] [--version]\n");
            return strcmp(argv[i], "--help") && strcmp(argv[i], "-h") ? 2 : 0;
        }
    }
    if (opt != PT_OK) {
        fprintf(stderr, "ptbench-merge: %s\n", opt_err.msg);
        return 2;
    }
    srv_job_params p = {
        w, h,  2 * chunk, tile,   chunk, 1,  16, 3, 0.0, 0, 0.0, "", {"", 1.0f, 0.0f, 0, {0, 0, 0}},
        0, "", {0, 0},    {0, 0}, 0,     {0}};
    uint8_t hash[32] = {0};
    double rates[99], mbs[99];
    size_t total_bytes = 0;
    uint64_t ntasks = 0;
    for (uint32_t r = 0; r < reps; r++) {
        srv_job *job = NULL;
        pt_error err = {0};
        if (srv_job_new(1, &p, hash, &job, &err) != PT_OK) {
            fprintf(stderr, "ptbench-merge: %s\n", err.msg);
            return 1;
        }
        ntasks = srv_job_tasks_total(job);
        proto_writer wr;
        proto_writer_init(&wr, (size_t)8 << 30);
        pt_pixel_acc *px = pt_malloc_array((size_t)tile * tile, sizeof *px);
        proto_task t;
        while (srv_job_lease(job, 1, 0, 60000, &t)) {
            uint32_t n = (t.tile.x1 - t.tile.x0) * (t.tile.y1 - t.tile.y0);
            for (uint32_t i = 0; i < n; i++)
                px[i] =
                    (pt_pixel_acc){{pt_fixed_of(0.5 + i), pt_fixed_of(0.25), pt_fixed_of(0.125)},
                                   pt_ufixed_of(0.3),
                                   t.s1 - t.s0,
                                   0};
            proto_result res = {t.job_id, t.task_id, t.tile, t.s0, t.s1, 0, 1000, 0, n, px,
                                0,        NULL,      0,      0,    0,    0, NULL, 0, 0};
            size_t mark;
            if (proto_frame_begin(&wr, PROTO_MSG_RESULT, &mark, NULL) != PT_OK ||
                proto_msg_encode_result(&wr, &res, NULL) != PT_OK ||
                proto_frame_end(&wr, mark, NULL) != PT_OK) {
                fprintf(stderr, "ptbench-merge: encoding failed\n");
                return 1;
            }
        }
        total_bytes = wr.len;
        pt_pixel_acc *scratch = pt_malloc_array(PROTO_MAX_TILE_PIXELS, sizeof *scratch);
        double t0 = pt_now_s();
        size_t off = 0;
        uint64_t merged = 0;
        while (off < wr.len) {
            proto_frame f;
            size_t used;
            proto_result res;
            if (proto_frame_decode(wr.buf + off, wr.len - off, PROTO_MAX_PAYLOAD, &f, &used,
                                   NULL) != PT_OK ||
                proto_msg_decode_result(f.payload, f.len, scratch, PROTO_MAX_TILE_PIXELS, &res,
                                        NULL) != PT_OK)
                break;
            merged += srv_job_result(job, 1, &res, NULL) == SRV_MERGED;
            proto_result_fini(&res);
            off += used;
        }
        double dt = pt_now_s() - t0;
        if (merged != ntasks || !srv_job_complete(job)) {
            fprintf(stderr, "ptbench-merge: merged %llu of %llu\n", (unsigned long long)merged,
                    (unsigned long long)ntasks);
            return 1;
        }
        rates[r] = (double)ntasks / dt;
        mbs[r] = (double)total_bytes / dt / 1e6;
        pt_free(scratch);
        pt_free(px);
        proto_writer_fini(&wr);
        srv_job_free(job);
    }
    qsort(rates, reps, sizeof *rates, cmp);
    qsort(mbs, reps, sizeof *mbs, cmp);
    double rate = rates[reps / 2], mb = mbs[reps / 2];
    double samples_per_result = (double)tile * tile * chunk;
    printf("job              %ux%u, tiles %u, chunks of %u: %llu results, %.1f MB\n", w, h, tile,
           chunk, (unsigned long long)ntasks, total_bytes / 1e6);
    printf("merge            %.4g results/s, %.4g MB/s (median of %u)\n", rate, mb, reps);
    printf("feeds            %.4g samples/s = %.0f worker cores at %.3g samples/s each\n",
           rate * samples_per_result, rate * samples_per_result / core_rate, core_rate);
    return 0;
}
