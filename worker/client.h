/*
 * client.h - `ptworker --server HOST:PORT`: the farm worker.
 *
 * One I/O thread (the caller of wrk_client_run) speaks the protocol with the
 * coordinator over one non-blocking socket; T render threads take tasks from
 * a bounded local queue and render each with pt_render_tile, start to end.
 *
 * Session: HELLO -> CHALLENGE -> AUTH (HMAC of the nonce under the token,
 * and a nonce of the worker's, protocol/auth.h) -> WELCOME, whose proof over
 * both nonces must show that the coordinator knows the token too (else the
 * process ends with status 1 and sends it nothing), then WORK_REQUEST for free slots
 * (T + prefetch - tasks waiting for a scene, queued, running and requested),
 * TASKs in, scenes fetched by content hash with SCENE_GET/SCENE_CHUNK into the
 * on-disk cache (worker/cache.h), RESULTs out as render threads finish (they
 * wake the I/O thread through a pipe), and a HEARTBEAT listing every task held
 * every max(200 ms, smallest lease / 3).
 * HELLO offers PROTO_CAP_DENOISE: a DENOISE_TASK takes a slot as a TASK does;
 * its input is fetched whole with DENOISE_GET/DENOISE_CHUNK (one at a time,
 * checked against its SHA-256), denoised on a render thread (pt_denoise on as
 * many threads as the worker renders with; one denoise task at a time, the
 * next one's input fetched meanwhile) and its region sent in DENOISE_RESULT.
 * An input pt_denoise refuses is a protocol error; one it has no memory for
 * is dropped (the coordinator denoises the region itself).
 * A dead link is noticed even when nothing closes the connection (a cable
 * pulled, a host powered off, a firewall dropping packets): data the
 * coordinator has not acknowledged for link_timeout_ms fails the connection
 * (TCP_USER_TIMEOUT), and an idle connection is probed with TCP keepalive so
 * that it fails within about the same time.
 * A JOB_END (the job was cancelled or failed) drops that job's tasks not yet
 * started (render or denoise) and the results of those running, and asks for
 * work again.
 * A dropped connection, a malformed frame or a message out of place discards
 * every task held (the coordinator requeues them; results of tasks still
 * rendering are dropped when they finish) and reconnects with exponential
 * backoff (0.2 s doubling to 10 s, reset by a WELCOME). An ERROR refusing
 * authentication, the build or the protocol version ends the process with
 * status 1: retrying cannot help. SIGTERM or SIGINT stops it with status 0
 * without finishing anything.
 */
#ifndef PT_WORKER_CLIENT_H
#define PT_WORKER_CLIENT_H

#include <stddef.h>
#include <stdint.h>

typedef struct wrk_client_opts {
    const char *server; /* "HOST:PORT" */
    uint32_t threads;   /* render threads, 1..PROTO_MAX_SLOTS */
    uint32_t prefetch;  /* tasks asked for beyond threads; threads + prefetch <= PROTO_MAX_SLOTS */
    const char *token_file;   /* NULL: empty token */
    const char *cache_dir;    /* NULL: wrk_client_default_cache_dir() */
    const char *name;         /* NULL: "hostname:pid"; at most PROTO_MAX_NAME bytes */
    uint32_t link_timeout_ms; /* a silent link fails after this long; 0: WRK_LINK_TIMEOUT_MS */
} wrk_client_opts;

/* The default link timeout: ptserve's default lease timeout, so a worker cut
 * off drops its tasks about when the coordinator requeues them. */
#define WRK_LINK_TIMEOUT_MS 20000u
/* Bounds of link_timeout_ms (keepalive works in whole seconds). */
#define WRK_LINK_TIMEOUT_MIN_MS 1000u
#define WRK_LINK_TIMEOUT_MAX_MS 3600000u

/* Runs the worker until a signal or a fatal refusal. Returns the process exit
 * status: 0 stopped by SIGTERM/SIGINT, 1 refused by the coordinator or a
 * local failure (token file, cache folder, threads). */
int wrk_client_run(const wrk_client_opts *o);

/* The cache folder used when none is given: $XDG_CACHE_HOME/ptfarm, else
 * $HOME/.cache/ptfarm, else /tmp/ptfarm-cache-UID. */
void wrk_client_default_cache_dir(char *buf, size_t cap);

#endif
