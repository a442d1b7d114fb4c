/*
 * fuzz_checkpoint.c - libFuzzer target for a job's checkpoint as the
 * coordinator reads it after a restart: the state folder's envelope (magic,
 * version, CRC32C, render seconds and counters; server/store/state.c) and the
 * merged state inside it (srv_job_load, server/sched/job.c).
 *
 * Input: a mode byte (fuzz_state.h: which job, sealed or not), then the
 * checkpoint file. The harness writes it as jobs/1/checkpoint of a real state
 * folder, with no results log, and calls srv_state_restore on a fresh job.
 * Invariants: a refusal names its cause; nothing is left allocated; an
 * accepted checkpoint leaves a job whose own checkpoint (srv_job_save) loads
 * into another fresh job and saves to the same bytes, whose merged tasks do
 * not exceed its total, and whose every remaining task can be leased once.
 */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "server/store/state.h"
#include "tests/fuzz/fuzz_job_state.h"
#include "tests/fuzz/fuzz_state.h"
#include "tests/fuzz/fuzz_util.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    const srv_job_params *p = write_input(data, size, "checkpoint", "results.log", fuzz_seal_file);

    int64_t live = pt_alloc_live();
    srv_job *job = fresh(p);
    srv_ckpt_extra x;
    uint32_t replayed = 0;
    int torn = 0;
    pt_error err = {0};
    pt_status st = srv_state_restore(state, job, &x, &replayed, &torn, &err);
    fuzz_note("restore", st, &err);
    FUZZ_CHECK(st == PT_OK || (st == err.code && err.msg[0]));
    if (st == PT_OK) {
        FUZZ_CHECK(replayed == 0 && torn == 0 && x.seconds >= 0);
        uint64_t total = srv_job_tasks_total(job), merged = srv_job_tasks_merged(job);
        FUZZ_CHECK(merged <= total);
        FUZZ_CHECK(srv_job_complete(job) == (merged == total));
        /* The loaded state saves, loads and saves again to the same bytes. */
        size_t la, lb;
        uint8_t *a = save(job, &la);
        srv_job *again = fresh(p);
        pt_error e2 = {0};
        FUZZ_CHECK(srv_job_load(again, a, la, &e2) == PT_OK);
        uint8_t *b = save(again, &lb);
        FUZZ_CHECK(la == lb && memcmp(a, b, la) == 0);
        FUZZ_CHECK(srv_job_tasks_merged(again) == merged);
        free(a);
        free(b);
        srv_job_free(again);
        /* What is left can be handed out, each task once. */
        proto_task t;
        uint64_t leased = 0;
        while (leased <= total && srv_job_lease(job, 1, 0, 1000, &t))
            leased++;
        FUZZ_CHECK(leased <= total - merged);
    }
    srv_job_free(job);
    FUZZ_CHECK(pt_alloc_live() == live);
    return 0;
}
