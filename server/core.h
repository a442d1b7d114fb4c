/*
 * core.h - the coordinator's shared state (its log line is server/log.h).
 *
 * srv_server is what every server module's functions take: the event loop's
 * connections (server/net/loop.h), the queue of jobs (server/sched/queue.h), the upload
 * verifications in flight (server/api/upload.h), the local worker processes
 * (server/app/local.h) and the mode chosen at setup (server/app/mode.h). Each group
 * of fields belongs to the module named beside it; the others only read it,
 * or change it through that module's functions.
 *
 * The mode is data: a srv_mode, chosen once, says how the loop ends, what it
 * does after each round of leases, what a timer tick prints and what happens
 * when the local workers are gone, so no module asks which mode it is in.
 *
 * Threads: srv_server is touched only by the event-loop thread. srv_log
 * (server/log.h) may be called from any thread. Times are pt_now_ms (common/base/clock.h).
 */
#ifndef PT_SERVER_CORE_H
#define PT_SERVER_CORE_H

#include <limits.h>
#include <stddef.h>
#include <stdint.h>

#include "common/base/clock.h"
#include "common/base/error.h"
#include "common/render/film.h"
#include "protocol/auth.h"
#include "protocol/msg.h"
#include "server/config.h"
#include "server/log.h"

typedef struct srv_server srv_server;
typedef struct srv_conn srv_conn;       /* server/net/loop.h */
typedef struct srv_entry srv_entry;     /* server/sched/queue.h */
typedef struct srv_upload srv_upload;   /* server/api/upload.h */
typedef struct srv_clients srv_clients; /* server/net/clients.h */
typedef struct srv_local srv_local;     /* server/app/local.h */
typedef struct srv_state srv_state;     /* server/store/state.h */
typedef struct srv_adder srv_adder;     /* server/sched/adder.h */
/* A scene check's outcome for its client c, still connected (upload.h). */
typedef void (*srv_verified_fn)(srv_server *s, srv_conn *c, srv_upload *k);

/* A worker refused for the coordinator's life (server/api/workers.h). */
#define SRV_MAX_BLOCKED 256
typedef struct srv_blocked {
    char name[PROTO_MAX_NAME + 1];
    char addr[64]; /* "" when its address is not blocked (loopback) */
    char why[96];
} srv_blocked;

/* One way of running the coordinator (server/app/mode.c has the two). */
typedef struct srv_mode {
    const char *name;
    int serves_clients; /* a client (ptctl) may connect */
    int logs_starts;    /* log each job as it starts (the queue's; one job logs its setup) */
    /* A result is logged durably before it is merged (the queue's state
     * folder: srv_queue_log_result, merged once its commit returns); else
     * it is merged as it arrives (one job). */
    int durable;
    /* What the scheduler's jobs keep on disk and how (server/sched/queue.h:
     * the state folder's, or nothing), so that it never asks which mode it
     * is in. */
    const struct srv_durability *durability;
    /* Bytes of results waiting for the disk (srv_loop_hold holds the workers
     * past cfg->max_log_mem); 0 where nothing is logged. */
    uint64_t (*backlog)(const srv_server *s);
    /* Loads or restores the jobs before the loop listens (its descriptors
     * may be added to the loop: srv_loop_add_fd). */
    pt_status (*setup)(srv_server *s, pt_error *err);
    /* 1 when the loop is over (besides a stop signal). */
    int (*over)(const srv_server *s);
    /* After each round's leases: what must reach the disk, jobs that ended. */
    void (*after_leases)(srv_server *s);
    /* Once per loop round after the timers; now in ms (pt_now_ms). */
    void (*tick)(srv_server *s, uint64_t now);
    /* Every local worker has exited: returns 1 to end the loop. */
    int (*local_gone)(srv_server *s);
    /* After the loop: saves what must be saved; returns the exit status. */
    int (*finish)(srv_server *s);
} srv_mode;

/* What the scheduler (server/sched/queue.h) tells the layers above it: they
 * install these at setup (srv_serve), and it never calls them by name.
 * Each may be NULL. Called on the loop thread. */
typedef struct srv_sched_events {
    /* j ended before it was done, or was paused: workers drop its tasks. */
    void (*job_ended)(srv_server *s, const srv_entry *j);
    /* j changed state (queued, started, ended): its watchers are told. */
    void (*job_changed)(srv_server *s, const srv_entry *j);
    /* A result of connection owner was merged: merged samples, at now (ms). */
    void (*result_merged)(srv_server *s, uint64_t owner, uint64_t merged, uint64_t now);
    /* A lease of connection owner passed a deadline at now (ms). */
    void (*owner_missed)(srv_server *s, uint64_t owner, uint64_t now);
    /* Calls fn(ctx, id) for each ready worker connection, in their order. */
    void (*each_worker)(srv_server *s, void (*fn)(void *ctx, uint64_t owner), void *ctx);
    /* Worker connection owner returned a denoised region whose bits differ
     * from the coordinator's (server/sched/dnshare.h): it is blocked. */
    void (*owner_lied)(srv_server *s, uint64_t owner, const char *why);
} srv_sched_events;

/* Totals since the coordinator started, for /metrics (server/api/http.h). */
#define SRV_HIST_BUCKETS 12 /* 10 us .. 42 s, x4 apart (SRV_HIST_FIRST), then +Inf */
#define SRV_HIST_FIRST 1e-5
#define SRV_HIST_FACTOR 4.0
typedef struct srv_histogram {
    uint64_t count, buckets[SRV_HIST_BUCKETS]; /* buckets: observations <= the bound */
    double sum;                                /* seconds */
} srv_histogram;
typedef struct srv_counters {
    uint64_t samples_merged, tasks_leased, tasks_requeued, tasks_expired, results_rejected;
    uint64_t samples_rejected; /* merged as rejected (proto_job_info.rejected) */
    uint64_t state_write_errors;
    uint64_t log_holds;    /* times workers were not read, the results log being behind */
    uint64_t log_unsynced; /* bytes of results not yet durable (srv_loop_hold), last round */
    /* Loop time: a RESULT's merge, a progressive image resolved and handed to
     * its writer, a checkpoint written. */
    srv_histogram merge, save, checkpoint;
} srv_counters;

/* Adds one observation of seconds to h. */
void srv_histogram_add(srv_histogram *h, double seconds);

struct srv_server {
    const srv_config *cfg;
    const srv_mode *mode;
    uint64_t t_start, t_last_print;

    /* the loop (server/net/loop.c) */
    int ep, lfd, sigpipe[2];
    struct srv_loop_reg *reg; /* the descriptors added and the role sessions */
    uint16_t port;
    srv_conn *conns;
    uint32_t nconns, nworkers;
    uint64_t next_conn_id;
    uint8_t token[PROTO_TOKEN_MAX];
    size_t token_len;
    srv_clients *clients;         /* --clients-file (server/net/clients.h); NULL: none */
    uint64_t bytes_in, bytes_out; /* on the wire, all peers */
    struct srv_guard *guard;      /* limits on peers: memory, slots, rates, refusals */
    srv_counters counters;        /* counted where they happen; read by server/api/http.c */
    struct srv_http *http;        /* --http: the dashboard (server/api/http.h); NULL: none */

    /* the queue (server/sched/queue.c) */
    const srv_sched_events *events; /* what it tells the layers above (srv_serve sets it) */
    const struct srv_range_ops
        *ranges;     /* frame ranges' entries (server/sched/frames.h; srv_serve) */
    srv_entry *jobs; /* every job, in queue order */
    uint32_t njobs;
    uint64_t next_job_id;
    srv_entry *single; /* one-job mode: the job */
    srv_state *state;  /* queue mode: the state folder; NULL in one-job mode */
    char out_dir[PATH_MAX - 512];
    uint64_t t_expire;    /* srv_queue_expire's last walk over the leases */
    uint64_t queue_retry; /* when an unsaved queue file is tried again */

    /* upload verification (server/api/upload.c) */
    int verifypipe[2];          /* verifications done: their pointers */
    srv_upload *verifications;  /* in flight */
    srv_upload *checks_waiting; /* complete uploads waiting for a check thread, oldest first */
    uint32_t checks_running;    /* of verifications, those with a thread */
    srv_verified_fn verified;   /* answers a check's client (srv_upload_open) */

    /* client requests (server/api/requests.c) */
    uint64_t t_watch;     /* srv_requests_tick's last walk over the watchers */
    uint8_t *fetch_chunk; /* one IMAGE piece read from a fetched file (PROTO_MAX_SCENE_CHUNK) */

    /* worker messages (server/api/workers.c) */
    pt_pixel_acc *scratch;      /* RESULT decode buffer */
    struct proto_heartbeat *hb; /* HEARTBEAT decode buffer (large) */
    int enforce_due;            /* a worker reached SRV_MAX_MISSES since srv_workers_enforce */
    srv_adder *adder;           /* film adds off the loop (--merge-threads); NULL: none */
    struct srv_io *io; /* workers read off the loop (--io-threads, server/net/io.h); NULL: none */
    int log_held;      /* workers not read: the results log is behind (srv_loop_hold) */
    uint64_t t_held, t_released;
    srv_blocked blocked[SRV_MAX_BLOCKED];
    uint32_t nblocked;
    uint64_t
        verify_seed; /* picks the tasks verified (server/sched/job.h), made at the first lease */

    /* local workers (server/app/local.c) */
    srv_local *local; /* srv_serve's */
    int local_gone_logged;
};

#endif
