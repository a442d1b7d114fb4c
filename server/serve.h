/*
 * serve.h - the coordinator: one event loop that serves workers for a job.
 *
 * Loads and packs the scene, listens, authenticates workers (HELLO,
 * CHALLENGE, AUTH, WELCOME), leases tasks in pass order, merges results
 * (server/job.h), serves the scene bundle in chunks, expires leases, and
 * writes progressive EXRs off the loop (server/writer.h). With local_workers
 * it also spawns that many ptworker processes on loopback and reaps them.
 * Runs until the image is complete (exit status 0), interrupted (SIGINT or
 * SIGTERM: the last progressive EXR is left valid; status 130), or it cannot
 * go on (status 1, with the reason on stderr).
 */
#ifndef PT_SERVER_SERVE_H
#define PT_SERVER_SERVE_H

#include <stddef.h>
#include <stdint.h>

#include "protocol/auth.h"
#include "server/job.h"

typedef struct srv_config {
    const char *scene_path;
    const char *out_path;
    const char *listen;        /* HOST:PORT; NULL: 127.0.0.1:7878, or port 0 with --local */
    const char *token_path;    /* NULL: no token (loopback only) */
    const char *port_file;     /* write the bound port here (tests, scripts) */
    const char *worker_bin;    /* NULL: ptworker beside this program */
    double save_interval;      /* seconds between progressive saves, at most this often */
    uint32_t lease_ms;
    uint32_t handshake_ms;     /* a peer must authenticate within this time */
    uint32_t local_workers;    /* spawn this many ptworker processes */
    uint32_t worker_threads;   /* threads per local worker; 0: cores / local_workers */
    srv_job_params job;        /* width/height 0: from the camera, 512 wide */
    int quiet;
} srv_config;

int srv_serve(const srv_config *cfg);

#endif
