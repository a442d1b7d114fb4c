#include "server/serve.h"

#include <stdio.h>
#include <string.h>

#include "common/base/alloc.h"
#include "server/api/http.h"
#include "server/api/requests.h"
#include "server/api/upload.h"
#include "server/api/workers.h"
#include "server/app/local.h"
#include "server/app/mode.h"
#include "server/core.h"
#include "server/net/clients.h"
#include "server/net/loop.h"
#include "server/sched/frames.h"
#include "server/sched/queue.h"

/* What the scheduler tells the layers above it (server/sched/queue.h raises
 * these; the worker and client handlers hear them). */
static const srv_sched_events sched_events = {
    .job_ended = srv_workers_job_ended,
    .job_changed = srv_requests_notify_watchers,
    .result_merged = srv_workers_merged,
    .owner_missed = srv_workers_missed,
    .owner_lied = srv_workers_lied,
    .each_worker = srv_workers_each,
};

/* Everything before the loop: the token, the decode buffer, the mode's jobs,
 * the listening socket and the local workers, in that order (a broken scene
 * or state folder fails before anything listens or starts). */
static pt_status setup(srv_server *s, pt_error *err)
{
    const srv_config *cfg = s->cfg;
    pt_status st;
    s->next_job_id = 1;
    s->events = &sched_events;
    s->ranges = &srv_frames_ops;
    /* The loop first, so each part adds its descriptors as it starts; the
     * sessions that serve each role's peers. */
    if ((st = srv_loop_init(s, err)) != PT_OK)
        return st;
    srv_loop_set_session(s, PROTO_ROLE_WORKER, &srv_workers_session);
    srv_loop_set_session(s, PROTO_ROLE_CLIENT, &srv_requests_session);
    if (cfg->token_path && (st = proto_token_load(cfg->token_path, s->token, sizeof s->token,
                                                  &s->token_len, err)) != PT_OK)
        return st;
    if (cfg->clients_path) {
        if ((st = srv_clients_load(cfg->clients_path, s->token, s->token_len, &s->clients, err)) !=
            PT_OK)
            return st;
        if (!cfg->quiet)
            srv_log("%u client tokens from %s: clients cancel only their own jobs",
                    srv_clients_count(s->clients), cfg->clients_path);
    }
    s->scratch = pt_malloc_array(PROTO_MAX_TILE_PIXELS, sizeof *s->scratch);
    s->hb = pt_malloc(sizeof *s->hb);
    s->fetch_chunk = pt_malloc(PROTO_MAX_SCENE_CHUNK);
    if (!s->scratch || !s->hb || !s->fetch_chunk)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    if (cfg->merge_threads && (st = srv_adder_new(cfg->merge_threads, &s->adder, err)) != PT_OK)
        return st;
    if ((st = s->mode->setup(s, err)) != PT_OK)
        return st;
    if ((st = srv_loop_open(s, err)) != PT_OK ||
        (st = srv_upload_open(s, srv_requests_verified, err)) != PT_OK)
        return st;
    s->t_start = s->t_last_print = pt_now_ms();
    if (cfg->http && (st = srv_http_start(s, &s->http, err)) != PT_OK)
        return st;
    if (cfg->local_workers && (st = srv_local_start(s->local, cfg, s->port, err)) != PT_OK)
        return st;
    return PT_OK;
}

/* The timers, once per round: leases, connections, jobs, watchers, then
 * what the mode shows. */
static void timers(srv_server *s)
{
    uint64_t now = pt_now_ms();
    /* Blocking requeues leases of every job: only once none is being walked. */
    if (srv_queue_expire(s, now))
        srv_workers_enforce(s);
    srv_loop_timers(s, now);
    srv_queue_tick(s, now);
    srv_requests_tick(s, now);
    s->mode->tick(s, now);
}

int srv_serve(const srv_config *cfg)
{
    srv_server s;
    srv_local local;
    memset(&s, 0, sizeof s);
    memset(&local, 0, sizeof local);
    s.local = &local;
    s.cfg = cfg;
    s.mode = srv_mode_for(cfg);
    s.lfd = s.ep = s.sigpipe[0] = s.sigpipe[1] = s.verifypipe[0] = s.verifypipe[1] = -1;
    pt_error err = {0};
    int rc = 1;
    if (setup(&s, &err) != PT_OK) {
        fprintf(stderr, "ptserve: %s\n", err.msg);
        goto done;
    }
    while (!srv_loop_stopped() && !s.mode->over(&s)) {
        srv_loop_poll(&s, 100);
        srv_loop_hold(&s, s.mode->backlog(&s));
        srv_workers_hand_out(&s);
        s.mode->after_leases(&s);
        timers(&s);
        srv_http_drain(&s, s.http); /* the dashboard's actions, then its snapshot */
        srv_http_publish(&s, s.http, 0);
        /* Flush, then free closed connections outside their callbacks. */
        srv_loop_sweep(&s);
        if (s.local->nchildren) {
            srv_local_reap(s.local, 0);
            if (s.local->alive == 0 && s.mode->local_gone(&s))
                break;
        }
    }
    rc = s.mode->finish(&s);
done:
    srv_http_stop(s.http);
    srv_upload_close(&s);
    srv_local_stop(s.local);
    srv_loop_close(&s);
    srv_queue_free(&s);
    srv_adder_free(s.adder); /* after the jobs: each settled as it was freed */
    srv_clients_free(s.clients);
    pt_free(s.scratch);
    pt_free(s.hb);
    pt_free(s.fetch_chunk);
    return rc;
}
