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
#include "server/store/state.h"
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
    FUZZ_CHECK(srv_state_open(dir, &srv_job_state_codec, &state, &err) == PT_OK);
    snprintf(job_dir, sizeof job_dir, "%s/jobs/%u", dir, FUZZ_JOB_ID);
    FUZZ_CHECK(pt_mkdirs(job_dir, 1, &err) == PT_OK);
    atexit(close_state);
}

/* A fresh job of the fuzzed id with params p. */
static srv_job *fresh(const srv_job_params *p)
{
    srv_job *job = NULL;
    FUZZ_CHECK(srv_job_new(FUZZ_JOB_ID, p, FUZZ_JOB_HASH, &job, NULL) == PT_OK);
    return job;
}

/* Writes an input (a mode byte, then the file) as `name` in the job's
 * folder, its checksums rewritten by seal when the mode asks, and removes
 * the job's `other` file so that a restore reads this one alone. Returns
 * the params of the job the mode picks. size >= 1. */
static const srv_job_params *write_input(const uint8_t *data, size_t size, const char *name,
                                         const char *other, void (*seal)(uint8_t *, size_t))
{
    open_state();
    uint8_t mode = data[0];
    size_t n = size - 1;
    uint8_t *file = malloc(n ? n : 1);
    FUZZ_CHECK(file != NULL);
    memcpy(file, data + 1, n);
    if (mode & FUZZ_MODE_SEAL)
        seal(file, n);
    fuzz_write(job_dir, name, file, n);
    free(file);
    fuzz_unlink(job_dir, other);
    return &FUZZ_JOB_PARAMS[mode & FUZZ_MODE_ADAPTIVE];
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
