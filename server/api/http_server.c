#define _GNU_SOURCE /* open_memstream */
#include "server/api/http_impl.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <microhttpd.h>
#include <openssl/crypto.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include <arpa/inet.h>
#include <netinet/in.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/base/hash.h"
#include "common/base/net.h"
#include "common/image/exr.h"
#include "common/image/image.h"
#include "protocol/auth.h"
#include "protocol/jobjson.h"
#include "server/api/http_assets.h"
#include "server/api/workers.h"
#include "server/net/authlimit.h"
#include "server/net/loop.h"
#include "server/sched/frames.h"
#include "server/sched/queue.h"

void srv_http_publish(srv_server *s, srv_http *h, int force)
{
    if (!h)
        return;
    uint64_t now = pt_now_ms();
    /* Called every loop round: the signature walks the queue, so it is
     * taken only once a republish is possible (250 ms after the last). */
    if (!force && now - h->t_pub < 250)
        return;
    http_sweep_headers(h, now);
    uint64_t sig = http_loop_signature(s);
    if (!force && now - h->t_pub < 1000 && sig == h->sig)
        return;
    h->t_pub = now;
    h->sig = sig;
    snap *p = pt_calloc(1, sizeof *p);
    if (!p)
        return;
    p->jobs = pt_malloc_array(s->njobs ? s->njobs : 1, sizeof *p->jobs);
    p->workers = pt_malloc_array(s->nconns ? s->nconns : 1, sizeof *p->workers);
    if (!p->jobs || !p->workers) {
        pt_free(p->jobs);
        pt_free(p->workers);
        pt_free(p->blocked);
        pt_free(p);
        return;
    }
    for (const srv_entry *j = s->jobs; j && p->njobs < s->njobs; j = j->next) {
        if (j->parent)
            continue; /* a frame: its range shows it */
        snap_job *o = &p->jobs[p->njobs++];
        srv_queue_info(s, j, &o->info);
        snprintf(o->exr, sizeof o->exr, "%s", j->out_path);
        o->images = j->writer ? srv_writer_count(j->writer) : 0;
        if (j->rec.frames.step) {
            /* The frame a viewer wants: the earliest rendering, or the last done. */
            srv_frames_latest(j, o->exr, sizeof o->exr);
            const srv_entry *f = srv_frames_at(j, 0);
            o->images = f && f->writer ? srv_writer_count(f->writer) : o->exr[0] != '\0';
        }
    }
    for (const srv_conn *c = s->conns; c; c = c->next) {
        if (c->closing || c->state != SRV_C_READY)
            continue;
        if (c->role != PROTO_ROLE_WORKER) {
            p->nclients++;
            continue;
        }
        const srv_worker_conn *k = srv_worker_of(c);
        if (!k)
            continue;
        if (p->nworkers >= s->nconns)
            break;
        snap_worker *w = &p->workers[p->nworkers++];
        w->id = c->id;
        snprintf(w->name, sizeof w->name, "%s", c->name);
        snprintf(w->peer, sizeof w->peer, "%s", c->peer);
        w->threads = c->threads;
        w->want = k->want;
        w->misses = k->misses;
        w->connected_s = (double)(now - c->t_connect) / 1000.0;
        w->tasks_done = k->tasks_done;
        w->samples_done = k->samples_done;
        w->last_result_s = k->t_result ? (double)(now - k->t_result) / 1000.0 : -1.0;
    }
    if (s->nblocked && (p->blocked = pt_malloc_array(s->nblocked, sizeof *p->blocked)) != NULL) {
        memcpy(p->blocked, s->blocked, s->nblocked * sizeof *p->blocked);
        p->nblocked = s->nblocked;
    }
    p->counters = s->counters;
    p->bytes_in = s->bytes_in;
    p->bytes_out = s->bytes_out;
    p->uptime_s = (double)(now - s->t_start) / 1000.0;
    p->refs = 1;
    pthread_mutex_lock(&h->mu);
    p->version = ++h->version;
    snap *old = h->cur;
    h->cur = p;
    http_snap_unref_locked(old);
    pthread_cond_broadcast(&h->cv);
    pthread_mutex_unlock(&h->mu);
}

enum MHD_Result http_serve_login(srv_http *h, struct MHD_Connection *conn, req *r, const char *addr)
{
    who w = {0};
    if (r->token_len && !r->too_big)
        http_who_token(h, (const uint8_t *)r->token, r->token_len, &w);
    OPENSSL_cleanse(r->token, sizeof r->token);
    if (!w.ok) {
        http_auth_failed(h, addr);
        return http_respond_text(conn, 401, "text/html; charset=utf-8", srv_http_login_page(1));
    }
    char value[65], cookie[160];
    if (!http_session_new(h, &w, value))
        return http_respond_error(conn, 500, "no random bytes for a session");
    snprintf(cookie, sizeof cookie, COOKIE "=%s; Path=/; HttpOnly; SameSite=Strict; Max-Age=%u",
             value, SRV_HTTP_SESSION_S);
    struct MHD_Response *resp =
        MHD_create_response_from_buffer(0, (void *)"", MHD_RESPMEM_PERSISTENT);
    if (!resp)
        return MHD_NO;
    MHD_add_response_header(resp, "Set-Cookie", cookie);
    MHD_add_response_header(resp, "Location", "/");
    return http_send_response(conn, 303, resp, "text/plain");
}

static enum MHD_Result on_request(void *cls, struct MHD_Connection *conn, const char *url,
                                  const char *method, const char *version, const char *data,
                                  size_t *data_len, void **con_cls)
{
    (void)version;
    srv_http *h = cls;
    req *r = *con_cls;
    if (!r) {
        r = calloc(1, sizeof *r);
        if (!r)
            return MHD_NO;
        *con_cls = r;
        http_mark_busy(h, conn, 1);
        if (strcmp(method, "POST") == 0)
            r->pp = MHD_create_post_processor(conn, 4096, http_post_field, r);
        return MHD_YES;
    }
    if (*data_len) {
        r->body += *data_len;
        if (r->too_big || r->body > SRV_HTTP_BODY || !r->pp ||
            MHD_post_process(r->pp, data, *data_len) != MHD_YES)
            r->too_big = 1;
        *data_len = 0;
        return MHD_YES;
    }
    if (r->too_big)
        return http_respond_error(
            conn, 413,
            "request body: form fields (application/x-www-form-urlencoded) of at most 16 KiB");
    /* DNS rebinding: a page of the attacker's name must not read the API. */
    const char *host = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "Host");
    if (host && !http_host_allowed(h, host))
        return http_respond_error(conn, 421,
                                  "this dashboard does not answer to that host name (ptserve "
                                  "--http-host names the ones it does)");
    int changes = strcmp(method, "GET") != 0 && strcmp(method, "HEAD") != 0;
    char addr[SRV_AUTHLIMIT_ADDR];
    http_client_addr(conn, addr);
    if (strcmp(url, "/login") == 0) {
        if (!changes)
            return http_respond_text(conn, 200, "text/html; charset=utf-8", srv_http_login_page(0));
        who none = {0};
        if (!http_same_origin(conn, &none))
            return http_respond_error(conn, 403, "a login from another site is refused");
        uint64_t ms = http_auth_blocked(h, addr);
        if (ms)
            return http_respond_blocked(conn, ms);
        return http_serve_login(h, conn, r, addr);
    }
    const srv_http_asset *a = srv_http_asset_find(url);
    if (a && a->is_public)
        return http_respond(conn, 200, a->type, (void *)a->data, *a->len, MHD_RESPMEM_PERSISTENT);
    uint64_t ms = h->token_len ? http_auth_blocked(h, addr) : 0;
    if (ms)
        return http_respond_blocked(conn, ms);
    who w = http_authenticate(h, conn);
    if (!w.ok && w.tried)
        http_auth_failed(h, addr);
    if (w.ok && changes && !http_same_origin(conn, &w))
        return http_respond_error(conn, 403,
                                  "a request from another site is refused (cross-site request "
                                  "forgery)");
    if (!w.ok) {
        if (strncmp(url, "/api/", 5) == 0 || strcmp(url, "/metrics") == 0)
            return http_respond_error(conn, 401, "a token is needed: Authorization: Bearer TOKEN");
        return http_respond_text(conn, 401, "text/html; charset=utf-8", srv_http_login_page(0));
    }
    if (strncmp(url, "/api/", 5) == 0)
        return http_serve_api(h, conn, &w, method, url, r);
    if (strcmp(url, "/metrics") == 0) {
        char *buf = NULL;
        size_t len = 0;
        FILE *f = open_memstream(&buf, &len);
        if (!f)
            return MHD_NO;
        snap *p = http_snap_get(h);
        http_metrics_text(f, p);
        http_snap_put(h, p);
        return http_respond_stream(conn, f, &buf, &len, "text/plain; version=0.0.4; charset=utf-8");
    }
    if (strcmp(method, "GET") && strcmp(method, "HEAD"))
        return http_respond_error(conn, 405, "GET only");
    if (a)
        return http_respond(conn, 200, a->type, (void *)a->data, *a->len, MHD_RESPMEM_PERSISTENT);
    return http_respond_text(conn, 404, "text/plain; charset=utf-8", "not found\n");
}

static void on_done(void *cls, struct MHD_Connection *conn, void **con_cls,
                    enum MHD_RequestTerminationCode toe)
{
    (void)toe;
    req *r = *con_cls;
    if (!r)
        return;
    http_mark_busy(cls, conn, 0);
    if (r->pp)
        MHD_destroy_post_processor(r->pp);
    OPENSSL_cleanse(r->token, sizeof r->token);
    free(r);
    *con_cls = NULL;
}

pt_status srv_http_start(srv_server *s, srv_http **out, pt_error *err)
{
    const srv_config *cfg = s->cfg;
    char host[256];
    uint16_t port = 0;
    pt_status st;
    if ((st = pt_net_split(cfg->http, host, sizeof host, &port, err)) != PT_OK)
        return st;
    if (!cfg->token_path && !pt_net_host_is_loopback(host)) {
        srv_log("no --token-file: the dashboard listens on loopback only (127.0.0.1), not '%s'",
                host);
        snprintf(host, sizeof host, "127.0.0.1");
    }
    srv_http *h = pt_calloc(1, sizeof *h);
    if (!h)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    pthread_mutex_init(&h->mu, NULL);
    pthread_cond_init(&h->cv, NULL);
    h->wake_fd = s->sigpipe[1];
    memcpy(h->token, s->token, s->token_len);
    h->token_len = s->token_len;
    h->clients = s->clients;
    snprintf(h->hosts, sizeof h->hosts, "%s", cfg->http_hosts ? cfg->http_hosts : "");
    int fd = -1;
    uint16_t bound = 0;
    if ((st = proto_auth_nonce(h->label, err)) != PT_OK ||
        (st = pt_net_listen(host, port, &fd, &bound, err)) != PT_OK)
        goto fail;
    h->d = MHD_start_daemon(MHD_USE_THREAD_PER_CONNECTION | MHD_USE_INTERNAL_POLLING_THREAD |
                                MHD_USE_POLL | MHD_USE_ERROR_LOG,
                            0, http_accept_policy, h, on_request, h, MHD_OPTION_LISTEN_SOCKET,
                            (MHD_socket)fd, MHD_OPTION_NOTIFY_CONNECTION, http_on_connection, h,
                            MHD_OPTION_CONNECTION_LIMIT, (unsigned)SRV_HTTP_MAX_CONNS,
                            MHD_OPTION_CONNECTION_MEMORY_LIMIT, (size_t)SRV_HTTP_MEMORY,
                            MHD_OPTION_CONNECTION_TIMEOUT, (unsigned)SRV_HTTP_TIMEOUT_S,
                            MHD_OPTION_PER_IP_CONNECTION_LIMIT, (unsigned)SRV_HTTP_PER_ADDRESS,
                            MHD_OPTION_NOTIFY_COMPLETED, on_done, h, MHD_OPTION_END);
    if (!h->d) {
        close(fd);
        st = pt_error_set(err, PT_ERR_IO, "--http %s: cannot start the HTTP server", cfg->http);
        goto fail;
    }
    if (cfg->http_port_file) {
        FILE *f = fopen(cfg->http_port_file, "w");
        if (!f || fprintf(f, "%u\n", bound) < 0 || fclose(f) != 0) {
            st = pt_error_errno(err, PT_ERR_IO, "%s", cfg->http_port_file);
            srv_http_stop(h);
            return st;
        }
    }
    if (!cfg->quiet)
        srv_log("dashboard on http://%s:%u/%s", host, bound,
                h->token_len ? " (token required)" : "");
    srv_http_publish(s, h, 1);
    *out = h;
    return PT_OK;
fail:
    pthread_cond_destroy(&h->cv);
    pthread_mutex_destroy(&h->mu);
    pt_free(h);
    return st;
}

void srv_http_stop(srv_http *h)
{
    if (!h)
        return;
    if (h->d) {
        /* Wake the event streams so their threads end at once. */
        pthread_mutex_lock(&h->mu);
        h->stopping = 1;
        pthread_cond_broadcast(&h->cv);
        pthread_mutex_unlock(&h->mu);
        MHD_stop_daemon(h->d);
    }
    http_snap_unref_locked(h->cur);
    OPENSSL_cleanse(h->token, sizeof h->token);
    OPENSSL_cleanse(h->sessions, sizeof h->sessions);
    pthread_cond_destroy(&h->cv);
    pthread_mutex_destroy(&h->mu);
    pt_free(h);
}

/* Runs one action on the loop; the outcome in a->status and a->text. */
static void run_action(srv_server *s, action *a)
{
    srv_entry *j = srv_queue_find(s, a->job);
    if (!j) {
        a->status = 404;
        snprintf(a->text, sizeof a->text, "no job %llu", (unsigned long long)a->job);
        return;
    }
    if (!srv_queue_may_change(j, a->who, a->admin)) {
        a->status = 403;
        snprintf(a->text, sizeof a->text,
                 "job %llu belongs to another client: only its owner or an admin may change it",
                 (unsigned long long)a->job);
        return;
    }
    a->status = 200;
    /* The same scheduler calls as ptctl's, by a name that says where from. */
    char by[PROTO_MAX_NAME + 8];
    snprintf(by, sizeof by, "%s (web)", a->who);
    if (a->kind == ACT_CANCEL)
        srv_queue_cancel(s, j, by);
    else
        srv_queue_set_priority(s, j, a->priority, by);
}

void srv_http_drain(srv_server *s, srv_http *h)
{
    if (!h)
        return;
    int todo[SRV_HTTP_ACTIONS], n = 0;
    pthread_mutex_lock(&h->mu);
    for (unsigned i = 0; i < SRV_HTTP_ACTIONS; i++)
        if (h->acts[i].state == ACT_PENDING) {
            h->acts[i].state = ACT_RUNNING;
            todo[n++] = (int)i;
        }
    pthread_mutex_unlock(&h->mu);
    if (n == 0)
        return;
    /* The slots marked RUNNING are the loop's until it answers. */
    for (int i = 0; i < n; i++)
        run_action(s, &h->acts[todo[i]]);
    srv_http_publish(s, h, 1);
    pthread_mutex_lock(&h->mu);
    for (int i = 0; i < n; i++) {
        action *a = &h->acts[todo[i]];
        a->state = a->state == ACT_ABANDONED ? ACT_FREE : ACT_DONE;
    }
    pthread_cond_broadcast(&h->cv);
    pthread_mutex_unlock(&h->mu);
}
