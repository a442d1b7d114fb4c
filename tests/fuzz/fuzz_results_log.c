/*
 * fuzz_results_log.c - libFuzzer target for a job's results log as the
 * coordinator replays it after a restart (server/store/state.c: header, records
 * that are RESULT frames, or in an older log length, CRC32C and payload; the
 * incomplete last record; each record decoded by proto_msg_decode_result and
 * merged by srv_job_replay).
 *
 * Input: a mode byte (fuzz_state.h: which job, sealed or not), then the log
 * file. The harness writes it as jobs/1/results.log of a real state folder,
 * with no checkpoint, and calls srv_state_restore on a fresh job, twice.
 * Invariants: a refusal names its cause; nothing is left allocated; the
 * second restore, of what the first left on disk (an incomplete record cut
 * off), gives the same verdict, the same records replayed, no incomplete
 * record, and a job that saves (srv_job_save) to the same bytes.
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

typedef struct restored {
    pt_status st;
    uint32_t replayed;
    int torn;
    srv_ckpt_extra x;
    uint8_t *saved; /* srv_job_save of the job when st is PT_OK */
    size_t saved_len;
} restored;

static restored restore(const srv_job_params *p)
{
    restored r = {0};
    srv_job *job = fresh(p);
    pt_error err = {0};
    r.st = srv_state_restore(state, job, &r.x, &r.replayed, &r.torn, &err);
    fuzz_note("restore", r.st, &err);
    FUZZ_CHECK(r.st == PT_OK || (r.st == err.code && err.msg[0]));
    if (r.st == PT_OK) {
        FUZZ_CHECK(srv_job_tasks_merged(job) <= srv_job_tasks_total(job));
        r.saved = save(job, &r.saved_len);
    }
    srv_job_free(job);
    return r;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    const srv_job_params *p = write_input(data, size, "results.log", "checkpoint", fuzz_seal_log);

    int64_t live = pt_alloc_live();
    restored a = restore(p);
    restored b = restore(p);
    FUZZ_CHECK(a.st == b.st);
    if (a.st == PT_OK) {
        FUZZ_CHECK(b.torn == 0 && a.replayed == b.replayed);
        FUZZ_CHECK(a.x.rejected == b.x.rejected && a.x.rays == b.x.rays);
        FUZZ_CHECK(a.saved_len == b.saved_len && memcmp(a.saved, b.saved, a.saved_len) == 0);
    }
    free(a.saved);
    free(b.saved);
    FUZZ_CHECK(pt_alloc_live() == live);
    return 0;
}
