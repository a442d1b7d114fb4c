/*
 * fuzz_job_state.h - what fuzz_checkpoint and fuzz_results_log share: the
 * real state folder (in fuzz_dir()) each writes its input into, as
 * jobs/FUZZ_JOB_ID/, opened once per process and closed at exit, and a
 * job's srv_job_save into a buffer for their round-trip checks. Include it
 * once, in a target's .c file: it defines the folder's static state.
 */
#ifndef PT_TESTS_FUZZ_JOB_STATE_H
#define PT_TESTS_FUZZ_JOB_STATE_H

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/fsutil.h"
#include "server/state.h"
#include "tests/fuzz/fuzz_state.h"
#include "tests/fuzz/fuzz_util.h"

static srv_state *state;
static char job_dir[700];

static void close_state(void)
{
    srv_state_close(state);
}

static void open_state(void)
{
    if (state)
        return;
    char dir[600];
    snprintf(dir, sizeof dir, "%s/state", fuzz_dir());
    pt_error err = {0};
    FUZZ_CHECK(srv_state_open(dir, &state, &err) == PT_OK);
    snprintf(job_dir, sizeof job_dir, "%s/jobs/%u", dir, FUZZ_JOB_ID);
    FUZZ_CHECK(pt_mkdirs(job_dir, 1, &err) == PT_OK);
    atexit(close_state);
}

/* srv_job_save of job into a new buffer (free it with free). */
static uint8_t *save(const srv_job *job, size_t *len)
{
    proto_writer w;
    proto_writer_init(&w, (size_t)1 << 30);
    FUZZ_CHECK(srv_job_save(job, &w, NULL) == PT_OK && proto_writer_status(&w) == PT_OK);
    uint8_t *out = malloc(w.len ? w.len : 1);
    FUZZ_CHECK(out != NULL);
    memcpy(out, w.buf, w.len);
    *len = w.len;
    proto_writer_fini(&w);
    return out;
}

#endif
