/*
 * config.h - the coordinator's configuration: what ptserve's options set,
 * read by every part of server/ and written by none once srv_serve starts.
 *
 * The bottom of server/'s headers: it includes nothing of server/ but
 * params.h's plain parameter types, so the parts (core.h, io.h, local.h, ...)
 * take their settings from here, not from serve.h, the entry point above
 * them. Plain data: any thread may read it.
 */
#ifndef PT_SERVER_CONFIG_H
#define PT_SERVER_CONFIG_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/frames.h"
#include "common/image/view.h"
#include "protocol/auth.h"
#include "server/params.h"

typedef struct srv_caps {
    uint32_t max_side;   /* longest image side a client may ask for */
    uint64_t max_pixels; /* width x height */
    uint64_t max_film;   /* bytes of one job's film on the coordinator (srv_film_bytes) */
    uint32_t max_spp;
    uint64_t max_scene;  /* bundle bytes */
    uint32_t max_queued; /* unfinished jobs per client identity */
} srv_caps;

/* What the loop lets peers hold (server/net/loop.h); 0 in a field: its default. */
typedef struct srv_peer_limits {
    uint64_t max_input_mem;     /* input buffer bytes grown past the first, all peers */
    uint32_t max_handshakes;    /* connections not yet authenticated */
    uint32_t max_handshakes_ip; /* of those, from one address */
    uint32_t frame_grace_ms;    /* a frame or upload may take this long whatever its size */
    uint32_t min_rate;          /* bytes/s a frame or upload must average past the grace */
} srv_peer_limits;

#define SRV_DEFAULT_MAX_LOG_MEM (512ull << 20) /* ptserve --max-log-mb */

typedef struct srv_config {
    const char *scene_path; /* one-job mode: render this and exit; NULL: queue mode */
    const char *out_path;   /* one-job mode: the EXR */
    const char *state_dir;  /* queue mode: the queue, bundles, checkpoints (server/store/state.h) */
    const char *output_dir; /* queue mode: finished images; NULL: STATE_DIR/output */
    const char *listen;     /* HOST:PORT; NULL: 127.0.0.1:7878, or port 0 with --local */
    const char *token_path; /* NULL: no token (loopback only) */
    const char *clients_path;   /* per-client tokens (server/net/clients.h); needs token_path */
    const char *port_file;      /* write the bound port here (tests, scripts) */
    const char *http;           /* the dashboard's HOST:PORT (server/api/http.h); NULL: none */
    const char *http_port_file; /* write its bound port here */
    const char *http_hosts;     /* host names the dashboard answers to besides IP literals and
                                   localhost (comma-separated; NULL: none) */
    const char *worker_bin;     /* NULL: ptworker beside this program */
    double save_interval;       /* seconds between progressive saves, at most this often */
    uint32_t lease_ms;
    uint32_t task_ms;        /* time-sized tasks of about this long; 0: fixed chunks (job.h) */
    double verify_fraction;  /* share of tasks rendered twice and compared (server/sched/job.h) */
    uint32_t handshake_ms;   /* a peer must authenticate within this time */
    uint32_t local_workers;  /* spawn this many ptworker processes */
    uint32_t worker_threads; /* threads per local worker; 0: cores / local_workers */
    uint32_t local_stop_ms;  /* a local worker still running this long after SIGTERM is
                                killed (server/app/local.h); 0: SRV_DEFAULT_LOCAL_STOP_MS */
    uint32_t
        merge_threads;     /* threads adding results to films (server/sched/adder.h); 0: the loop */
    uint32_t io_threads;   /* threads reading workers (server/net/io.h); 0: the loop */
    uint64_t max_log_mem;  /* queue mode: bytes of results not yet durable past which
                            * workers are not read (srv_loop_hold, server/net/loop.h) */
    uint64_t max_denoise;  /* bytes a frame's denoising may take (--max-denoise-mb;
                            * server/sched/writer.h); 0: what it needs */
    int denoise_share;     /* --denoise-on-workers (server/sched/dnshare.h) */
    uint32_t denoise_side; /* --denoise-region: its regions' side */
    srv_job_params job;    /* one-job mode: the job; queue mode: defaults (tile,
                            * chunk, max depth, rr depth) for submitted jobs.
                            * width/height 0: from the camera, 512 wide */
    srv_caps caps;         /* queue mode: what a client may ask for */
    srv_peer_limits limits; /* memory, connections and rates of peers */
    int quiet;
    const char *env_path; /* one-job mode: the environment map packed with the scene
                           * (job.env then names it PT_BUNDLE_ENV_NAME); NULL: none */
    pt_frames frames;     /* one-job mode: a frame range (server/sched/frames.h); step 0: a still */
    double fps;           /* its frames per second */
    const char *animation; /* its animation; NULL: every one */
    pt_view view;          /* every PNG preview's exposure and view transform */
    uint32_t guiding;      /* one-job mode: --guiding (PT_GUIDING_*), resolved against the
                            * scene into job.guiding when the job is set up */
} srv_config;

#endif
