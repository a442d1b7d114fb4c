/*
 * fuzz_queue.c - libFuzzer target for the state folder's queue file as
 * ptserve reads it at start (srv_state_load_queue, server/store/state.c: magic,
 * version, CRC32C, every job's record).
 *
 * Input: a mode byte (fuzz_state.h: bit 1 seals the checksum; bit 0 unused),
 * then the queue file. The harness writes it as DIR/queue of a real state
 * folder and loads it. Invariants: a refusal names its cause; nothing is left
 * allocated; every record loaded has an id below the next id, a known state
 * and NUL-terminated texts; what loads saves (srv_state_save_queue) to a file
 * that loads to records saving to the very same bytes.
 */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "server/store/state.h"
#include "tests/fuzz/fuzz_state.h"
#include "tests/fuzz/fuzz_util.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static srv_state *state;
static char state_dir[600];

static void close_state(void)
{
    srv_state_close(state);
}

static void open_state(void)
{
    if (state)
        return;
    snprintf(state_dir, sizeof state_dir, "%s/state", fuzz_dir());
    pt_error err = {0};
    FUZZ_CHECK(srv_state_open(state_dir, NULL, &state, &err) == PT_OK);
    atexit(close_state);
}

/* Saves recs, then reads the queue file back into a new buffer. */
static uint8_t *save(srv_job_record *recs, uint32_t n, uint64_t next_id, size_t *len)
{
    srv_job_record **ptrs = malloc((n ? n : 1) * sizeof *ptrs);
    FUZZ_CHECK(ptrs != NULL);
    for (uint32_t i = 0; i < n; i++)
        ptrs[i] = &recs[i];
    pt_error err = {0};
    FUZZ_CHECK(srv_state_save_queue(state, ptrs, n, next_id, &err) == PT_OK);
    free(ptrs);
    char path[700];
    snprintf(path, sizeof path, "%s/queue", state_dir);
    uint8_t *buf = NULL;
    FUZZ_CHECK(pt_read_file(path, (size_t)1 << 30, &buf, len, &err) == PT_OK);
    return buf;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    open_state();
    size_t n = size - 1;
    uint8_t *file = malloc(n ? n : 1);
    FUZZ_CHECK(file != NULL);
    memcpy(file, data + 1, n);
    if (data[0] & FUZZ_MODE_SEAL)
        fuzz_seal_file(file, n);
    fuzz_write(state_dir, "queue", file, n);
    free(file);

    int64_t live = pt_alloc_live();
    srv_job_record *recs = NULL;
    uint32_t count = 0;
    uint64_t next_id = 0;
    pt_error err = {0};
    pt_status st = srv_state_load_queue(state, &recs, &count, &next_id, &err);
    fuzz_note("load", st, &err);
    FUZZ_CHECK(st == PT_OK || (st == err.code && err.msg[0]));
    if (st == PT_OK) {
        FUZZ_CHECK(count <= SRV_MAX_JOBS && (count == 0 || recs != NULL));
        for (uint32_t i = 0; i < count; i++) {
            const srv_job_record *j = &recs[i];
            FUZZ_CHECK(j->id > 0 && j->id < next_id);
            FUZZ_CHECK(j->state >= PROTO_JOB_QUEUED && j->state <= PROTO_JOB_FAILED);
            FUZZ_CHECK(memchr(j->name, 0, sizeof j->name) && memchr(j->owner, 0, sizeof j->owner));
            FUZZ_CHECK(memchr(j->scene, 0, sizeof j->scene) &&
                       memchr(j->output, 0, sizeof j->output));
            FUZZ_CHECK(memchr(j->message, 0, sizeof j->message) &&
                       memchr(j->params.camera, 0, sizeof j->params.camera));
        }
        /* Round trip: load(save(recs)) saves to the same bytes. */
        size_t la, lb;
        uint8_t *a = save(recs, count, next_id, &la);
        srv_job_record *recs2 = NULL;
        uint32_t count2 = 0;
        uint64_t next2 = 0;
        FUZZ_CHECK(srv_state_load_queue(state, &recs2, &count2, &next2, &err) == PT_OK);
        FUZZ_CHECK(count2 == count && next2 == next_id);
        uint8_t *b = save(recs2, count2, next2, &lb);
        FUZZ_CHECK(la == lb && memcmp(a, b, la) == 0);
        pt_free(a);
        pt_free(b);
        pt_free(recs2);
    }
    pt_free(recs);
    FUZZ_CHECK(pt_alloc_live() == live);
    return 0;
}
