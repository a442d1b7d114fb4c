#define _GNU_SOURCE /* open_memstream */
#include "server/api/http.h"

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
#include "common/image/view.h"
#include "protocol/auth.h"
#include "protocol/jobjson.h"
#include "server/api/http_assets.h"
#include "server/net/authlimit.h"
#include "server/net/loop.h"
#include "server/sched/frames.h"
#include "server/sched/queue.h"

/* ---- the snapshot: built by the loop, read by the request threads ---- */

typedef struct snap_job {
    proto_job_info info;
    char exr[PATH_MAX]; /* its image file ("" when none yet) */
    unsigned long images;
} snap_job;

typedef struct snap_worker {
    uint64_t id;
    char name[PROTO_MAX_NAME + 1];
    char peer[64];
    uint32_t threads, want, misses;
    double connected_s;
    uint64_t tasks_done, samples_done;
    double last_result_s; /* seconds since its last merged result; < 0: none yet */
} snap_worker;

typedef struct snap {
    int refs; /* under srv_http.mu */
    uint64_t version;
    double uptime_s;
    uint32_t njobs, nworkers, nclients;
    snap_job *jobs;
    snap_worker *workers;
    uint32_t nblocked;
    srv_blocked *blocked; /* workers refused for the coordinator's life (workers.h) */
    srv_counters counters;
    uint64_t bytes_in, bytes_out;
} snap;

enum { ACT_FREE, ACT_PENDING, ACT_RUNNING, ACT_DONE, ACT_ABANDONED };
enum { ACT_CANCEL = 1, ACT_PRIORITY };

/* One action in its slot: filled by a request thread, run by the loop. */
typedef struct action {
    int state, kind;
    uint64_t job;
    int32_t priority;
    char who[PROTO_MAX_NAME + 1];
    int admin;
    unsigned status; /* HTTP status of the outcome */
    char text[256];  /* its reason when not 200 */
} action;

typedef struct session {
    uint8_t hash[32]; /* SHA-256 of the cookie's value; all zero: free */
    char who[PROTO_MAX_NAME + 1];
    int admin;
    time_t expires;
} session;

struct srv_http {
    struct MHD_Daemon *d;
    int wake_fd; /* the loop's wake pipe (write end) */
    /* Identity: read-only once started. */
    uint8_t token[PROTO_TOKEN_MAX];
    size_t token_len;
    const srv_clients *clients;
    uint8_t label[PROTO_NONCE_SIZE]; /* random: the fixed nonce of bearer checks */
    pthread_mutex_t mu;
    pthread_cond_t cv; /* a new snapshot or an action answered */
    snap *cur;
    action acts[SRV_HTTP_ACTIONS];
    session sessions[SRV_HTTP_SESSIONS];
    srv_authlimit fails; /* under mu: failed authentications per address */
    /* under mu: the open connections: each one's network (an IPv4 /24, an
     * IPv6 /64, as the first bytes of the v6 or v4-mapped address), for the
     * accept policy (at most SRV_HTTP_PER_NETWORK from one), and for the
     * header deadline its descriptor and since when it waits for a
     * request's headers (busy: a request of it is being answered) */
    struct {
        struct MHD_Connection *c; /* NULL: a free slot */
        uint8_t net[16];
        int fd, busy;
        uint64_t since;
    } open[SRV_HTTP_MAX_CONNS];
    char hosts[512]; /* --http-host's names, comma-separated ("" for none) */
    /* the loop's own */
    uint64_t t_pub, version, sig;
    int stopping;  /* under mu: event streams end */
    int rendering; /* under mu: PNGs being made (at most SRV_HTTP_RENDERS) */
};

static void sweep_headers(srv_http *h, uint64_t now);

static void snap_unref_locked(snap *p)
{
    if (p && --p->refs == 0) {
        pt_free(p->jobs);
        pt_free(p->workers);
        pt_free(p->blocked);
        pt_free(p);
    }
}

static snap *snap_get(srv_http *h)
{
    pthread_mutex_lock(&h->mu);
    snap *p = h->cur;
    if (p)
        p->refs++;
    pthread_mutex_unlock(&h->mu);
    return p;
}

static void snap_put(srv_http *h, snap *p)
{
    pthread_mutex_lock(&h->mu);
    snap_unref_locked(p);
    pthread_mutex_unlock(&h->mu);
}

static const snap_job *snap_find(const snap *p, uint64_t id)
{
    for (uint32_t i = 0; p && i < p->njobs; i++)
        if (p->jobs[i].info.job_id == id)
            return &p->jobs[i];
    return NULL;
}

/* ---- the loop's side ---- */

/* What a viewer would see change at once: jobs and their states and
 * priorities, peers. Progress alone waits for the next second, since each
 * snapshot computes every running job's error estimate over its film. */
static uint64_t loop_signature(const srv_server *s)
{
    uint64_t sig = (uint64_t)s->nconns * 1000003u + s->njobs + (uint64_t)s->nblocked * 7919u;
    for (const srv_entry *j = s->jobs; j; j = j->next)
        sig = sig * 1099511628211ull + j->rec.id * 31u + j->rec.state * 17u +
              (uint64_t)(uint32_t)j->rec.priority;
    return sig;
}

void srv_http_publish(srv_server *s, srv_http *h, int force)
{
    if (!h)
        return;
    uint64_t now = pt_now_ms();
    /* Called every loop round: the signature walks the queue, so it is
     * taken only once a republish is possible (250 ms after the last). */
    if (!force && now - h->t_pub < 250)
        return;
    sweep_headers(h, now);
    uint64_t sig = loop_signature(s);
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
        if (p->nworkers >= s->nconns)
            break;
        snap_worker *w = &p->workers[p->nworkers++];
        w->id = c->id;
        snprintf(w->name, sizeof w->name, "%s", c->name);
        snprintf(w->peer, sizeof w->peer, "%s", c->peer);
        w->threads = c->threads;
        w->want = c->want;
        w->misses = c->misses;
        w->connected_s = (double)(now - c->t_connect) / 1000.0;
        w->tasks_done = c->tasks_done;
        w->samples_done = c->samples_done;
        w->last_result_s = c->t_result ? (double)(now - c->t_result) / 1000.0 : -1.0;
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
    snap_unref_locked(old);
    pthread_cond_broadcast(&h->cv);
    pthread_mutex_unlock(&h->mu);
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
    if (!a->admin && strcmp(j->rec.owner, a->who) != 0) {
        a->status = 403;
        snprintf(a->text, sizeof a->text,
                 "job %llu belongs to another client: only its owner or an admin may change it",
                 (unsigned long long)a->job);
        return;
    }
    a->status = 200;
    if (a->kind == ACT_CANCEL) {
        if (srv_entry_active(j)) {
            char msg[PROTO_MAX_ERROR_TEXT + 1];
            snprintf(msg, sizeof msg, "cancelled by %s (web)", a->who);
            srv_queue_end_job(s, j, PROTO_JOB_CANCELLED, msg);
        }
        return;
    }
    if (!srv_entry_active(j) || j->rec.priority == a->priority)
        return;
    j->rec.priority = a->priority;
    srv_queue_unlink(s, j);
    srv_queue_insert(s, j);
    pt_error err = {0};
    if (srv_queue_journal(s, &err) != PT_OK)
        srv_log("job %llu: priority %d not saved: %s", (unsigned long long)a->job, a->priority,
                err.msg);
    srv_log("job %llu: priority %d, set by %s (web)", (unsigned long long)a->job, a->priority,
            a->who);
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

/* ---- requests ---- */

typedef struct who {
    int ok, admin;
    int tried;  /* the request presented a token or a session cookie */
    int cookie; /* authenticated by the session cookie (a browser's) */
    char name[PROTO_MAX_NAME + 1];
} who;

/* The state of one request across the handler's calls. */
typedef struct req {
    struct MHD_PostProcessor *pp;
    char token[PROTO_TOKEN_MAX + 1]; /* the login form's field */
    size_t token_len;
    char priority[24];
    size_t body; /* bytes of body so far (at most SRV_HTTP_BODY) */
    int too_big;
} req;

/* Queues r with status, its type and no-store, and lets it go. */
static enum MHD_Result send_response(struct MHD_Connection *conn, unsigned status,
                                     struct MHD_Response *r, const char *type)
{
    MHD_add_response_header(r, "Content-Type", type);
    MHD_add_response_header(r, "Cache-Control", "no-store");
    enum MHD_Result ret = MHD_queue_response(conn, status, r);
    MHD_destroy_response(r);
    return ret;
}

static enum MHD_Result respond(struct MHD_Connection *conn, unsigned status, const char *type,
                               void *data, size_t len, enum MHD_ResponseMemoryMode mode)
{
    struct MHD_Response *r = MHD_create_response_from_buffer(len, data, mode);
    if (!r) {
        if (mode == MHD_RESPMEM_MUST_FREE)
            free(data);
        return MHD_NO;
    }
    MHD_add_response_header(r, "X-Content-Type-Options", "nosniff");
    MHD_add_response_header(r, "X-Frame-Options", "DENY");
    MHD_add_response_header(r, "Content-Security-Policy",
                            "default-src 'self'; img-src 'self' blob:; frame-ancestors 'none'");
    return send_response(conn, status, r, type);
}

static enum MHD_Result respond_text(struct MHD_Connection *conn, unsigned status, const char *type,
                                    const char *text)
{
    return respond(conn, status, type, (void *)text, strlen(text), MHD_RESPMEM_MUST_COPY);
}

/* {"error": TEXT} with status. */
static enum MHD_Result respond_error(struct MHD_Connection *conn, unsigned status, const char *text)
{
    char *buf = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&buf, &len);
    if (!f)
        return MHD_NO;
    fputs("{\"error\": ", f);
    proto_json_string(f, text);
    fputs("}\n", f);
    fclose(f);
    return respond(conn, status, "application/json", buf, len, MHD_RESPMEM_MUST_FREE);
}

/* Closes f, an open_memstream over *buf and *len (both set only then), and
 * sends what it holds. */
static enum MHD_Result respond_stream(struct MHD_Connection *conn, FILE *f, char **buf, size_t *len,
                                      const char *type)
{
    if (fclose(f) != 0) {
        free(*buf);
        return respond_error(conn, 500, "out of memory");
    }
    return respond(conn, 200, type, *buf, *len, MHD_RESPMEM_MUST_FREE);
}

/* Who a bearer token is: the shared token's admin or a --clients-file
 * client. Both sides go through HMAC over the random label, so every
 * comparison is CRYPTO_memcmp over MACs and takes the same time whatever
 * the token. */
static void who_token(const srv_http *h, const uint8_t *tok, size_t len, who *w)
{
    uint8_t mac[PROTO_MAC_SIZE];
    if (len == 0 || len > PROTO_TOKEN_MAX ||
        proto_auth_response(tok, len, h->label, mac, NULL) != PT_OK)
        return;
    if (proto_auth_verify(h->token, h->token_len, h->label, mac, NULL) == PT_OK) {
        w->ok = w->admin = 1;
        snprintf(w->name, sizeof w->name, "admin");
        return;
    }
    const char *name;
    const uint8_t *key;
    size_t key_len;
    if (h->clients && srv_clients_match(h->clients, h->label, mac, &name, &key, &key_len) >= 0) {
        w->ok = 1;
        snprintf(w->name, sizeof w->name, "%s", name);
    }
}

#define COOKIE "ptfarm_session"

static void who_cookie(srv_http *h, const char *value, who *w)
{
    uint8_t hash[32];
    pt_sha256((const uint8_t *)value, strlen(value), hash);
    time_t now = time(NULL);
    int found = -1;
    pthread_mutex_lock(&h->mu);
    for (unsigned i = 0; i < SRV_HTTP_SESSIONS; i++)
        if (CRYPTO_memcmp(h->sessions[i].hash, hash, 32) == 0 && h->sessions[i].expires > now)
            found = (int)i;
    if (found >= 0) {
        w->ok = 1;
        w->admin = h->sessions[found].admin;
        snprintf(w->name, sizeof w->name, "%s", h->sessions[found].who);
    }
    pthread_mutex_unlock(&h->mu);
}

static who authenticate(srv_http *h, struct MHD_Connection *conn)
{
    who w = {0};
    if (h->token_len == 0) { /* loopback only, like the worker port */
        w.ok = w.admin = 1;
        snprintf(w.name, sizeof w.name, "admin");
        return w;
    }
    const char *auth = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "Authorization");
    if (auth) {
        w.tried = 1;
        if (strncmp(auth, "Bearer ", 7) == 0)
            who_token(h, (const uint8_t *)auth + 7, strlen(auth + 7), &w);
        return w;
    }
    const char *cookie = MHD_lookup_connection_value(conn, MHD_COOKIE_KIND, COOKIE);
    if (cookie) {
        w.tried = w.cookie = 1;
        if (strlen(cookie) == 64)
            who_cookie(h, cookie, &w);
    }
    return w;
}

/* The client's address as text (the failed-authentication table's key). */
static void client_addr(struct MHD_Connection *conn, char out[SRV_AUTHLIMIT_ADDR])
{
    const union MHD_ConnectionInfo *ci =
        MHD_get_connection_info(conn, MHD_CONNECTION_INFO_CLIENT_ADDRESS);
    out[0] = '\0';
    if (!ci || !ci->client_addr)
        return;
    const struct sockaddr *sa = ci->client_addr;
    if (sa->sa_family == AF_INET)
        inet_ntop(AF_INET, &((const struct sockaddr_in *)(const void *)sa)->sin_addr, out,
                  SRV_AUTHLIMIT_ADDR);
    else if (sa->sa_family == AF_INET6)
        inet_ntop(AF_INET6, &((const struct sockaddr_in6 *)(const void *)sa)->sin6_addr, out,
                  SRV_AUTHLIMIT_ADDR);
}

/* The network of a socket address: its first bytes as IPv6 (IPv4 mapped to
 * ::ffff:a.b.c.d), an IPv4 /24 or an IPv6 /64; 0 for another family. */
static int net_of(const struct sockaddr *sa, uint8_t net[16])
{
    memset(net, 0, 16);
    if (sa->sa_family == AF_INET) {
        const struct sockaddr_in *a = (const struct sockaddr_in *)(const void *)sa;
        net[10] = net[11] = 0xff;
        memcpy(net + 12, &a->sin_addr, 3);
        return 1;
    }
    if (sa->sa_family == AF_INET6) {
        const struct sockaddr_in6 *a = (const struct sockaddr_in6 *)(const void *)sa;
        memcpy(net, &a->sin6_addr, 8);
        if (memcmp(net, "\0\0\0\0\0\0\0\0", 8) == 0) /* v4-mapped: its /24 */
            memcpy(net + 8, (const uint8_t *)&a->sin6_addr + 8, 7);
        return 1;
    }
    return 0;
}

/* libmicrohttpd's accept policy: a connection from a network that holds
 * SRV_HTTP_PER_NETWORK already is refused before a thread is started, so
 * slow clients need that many networks to hold every connection. */
static enum MHD_Result accept_policy(void *cls, const struct sockaddr *sa, socklen_t len)
{
    (void)len;
    srv_http *h = cls;
    uint8_t net[16];
    if (!net_of(sa, net))
        return MHD_YES;
    unsigned n = 0;
    pthread_mutex_lock(&h->mu);
    for (unsigned i = 0; i < SRV_HTTP_MAX_CONNS; i++)
        n += h->open[i].c && memcmp(h->open[i].net, net, 16) == 0;
    pthread_mutex_unlock(&h->mu);
    return n >= SRV_HTTP_PER_NETWORK ? MHD_NO : MHD_YES;
}

/* Under mu: conn's slot in h->open, or -1. */
static int open_slot(const srv_http *h, const struct MHD_Connection *conn)
{
    for (unsigned i = 0; i < SRV_HTTP_MAX_CONNS; i++)
        if (h->open[i].c == conn)
            return (int)i;
    return -1;
}

/* Under mu: conn, of network net, opened (started 1) or is about to be
 * closed (0). */
static void track_open(srv_http *h, struct MHD_Connection *conn, const uint8_t net[16], int started)
{
    int i = started ? open_slot(h, NULL) : open_slot(h, conn);
    if (i < 0)
        return;
    if (!started) {
        h->open[i].c = NULL;
        return;
    }
    const union MHD_ConnectionInfo *fi =
        MHD_get_connection_info(conn, MHD_CONNECTION_INFO_CONNECTION_FD);
    h->open[i].c = conn;
    memcpy(h->open[i].net, net, 16);
    h->open[i].fd = fi ? (int)fi->connect_fd : -1;
    h->open[i].busy = 0;
    h->open[i].since = pt_now_ms();
}

/* A request of conn began to be answered (busy 1: its headers are in) or
 * was answered (0: the connection waits for the next one's headers). */
static void mark_busy(srv_http *h, struct MHD_Connection *conn, int busy)
{
    pthread_mutex_lock(&h->mu);
    int i = open_slot(h, conn);
    if (i >= 0) {
        h->open[i].busy = busy;
        h->open[i].since = pt_now_ms();
    }
    pthread_mutex_unlock(&h->mu);
}

/* Connections that have waited SRV_HTTP_HEADER_S for a request's headers
 * are shut down, so their thread reads the end and libmicrohttpd closes
 * them: a client that sends its headers a byte at a time holds a
 * connection that long, no longer. Under mu, which NOTIFY_CLOSED takes
 * before libmicrohttpd closes a descriptor, so the one shut down is the
 * connection's own. */
static void sweep_headers(srv_http *h, uint64_t now)
{
    pthread_mutex_lock(&h->mu);
    for (unsigned i = 0; i < SRV_HTTP_MAX_CONNS; i++)
        if (h->open[i].c && !h->open[i].busy && h->open[i].fd >= 0 &&
            now - h->open[i].since > SRV_HTTP_HEADER_S * 1000u) {
            shutdown(h->open[i].fd, SHUT_RDWR);
            h->open[i].fd = -1; /* once */
        }
    pthread_mutex_unlock(&h->mu);
}

/* Tracks a connection from its start to its close. */
static void on_connection(void *cls, struct MHD_Connection *conn, void **socket_context,
                          enum MHD_ConnectionNotificationCode code)
{
    (void)socket_context;
    srv_http *h = cls;
    const union MHD_ConnectionInfo *ci =
        MHD_get_connection_info(conn, MHD_CONNECTION_INFO_CLIENT_ADDRESS);
    uint8_t net[16];
    if (!ci || !ci->client_addr || !net_of(ci->client_addr, net))
        return;
    pthread_mutex_lock(&h->mu);
    track_open(h, conn, net, code == MHD_CONNECTION_NOTIFY_STARTED);
    pthread_mutex_unlock(&h->mu);
}

/* Milliseconds addr stays blocked for failed authentications (0: none). */
static uint64_t auth_blocked(srv_http *h, const char *addr)
{
    pthread_mutex_lock(&h->mu);
    uint64_t ms = srv_authlimit_blocked(&h->fails, addr, pt_now_ms());
    pthread_mutex_unlock(&h->mu);
    return ms;
}

static void auth_failed(srv_http *h, const char *addr)
{
    pthread_mutex_lock(&h->mu);
    srv_authlimit_failed(&h->fails, addr, "dashboard", pt_now_ms());
    pthread_mutex_unlock(&h->mu);
}

/* 429 with Retry-After: addr is blocked for ms more. */
static enum MHD_Result respond_blocked(struct MHD_Connection *conn, uint64_t ms)
{
    char text[160], after[24];
    unsigned s = (unsigned)((ms + 999) / 1000);
    snprintf(text, sizeof text,
             "{\"error\": \"too many failed authentications from this address; retry in %u s\"}",
             s);
    snprintf(after, sizeof after, "%u", s);
    struct MHD_Response *r =
        MHD_create_response_from_buffer(strlen(text), text, MHD_RESPMEM_MUST_COPY);
    if (!r)
        return MHD_NO;
    MHD_add_response_header(r, "Retry-After", after);
    return send_response(conn, 429, r, "application/json");
}

/* 1 when host (a Host header, or an Origin's host part: NAME[:PORT]) names
 * this server as only its operator would: an IP literal, localhost, or a
 * --http-host name. A DNS name an attacker points at this address (DNS
 * rebinding) is none of those. */
static int host_allowed(const srv_http *h, const char *host)
{
    char name[256];
    size_t n = strlen(host);
    if (n == 0 || n >= sizeof name)
        return 0;
    if (host[0] == '[') { /* [v6]:port */
        const char *end = strchr(host, ']');
        if (!end || (end[1] && end[1] != ':'))
            return 0;
        snprintf(name, sizeof name, "%.*s", (int)(end - host - 1), host + 1);
        struct in6_addr a6;
        return inet_pton(AF_INET6, name, &a6) == 1;
    }
    const char *colon = strchr(host, ':');
    snprintf(name, sizeof name, "%.*s", (int)(colon ? (size_t)(colon - host) : n), host);
    struct in_addr a4;
    if (inet_pton(AF_INET, name, &a4) == 1 || strcasecmp(name, "localhost") == 0)
        return 1;
    for (const char *p = h->hosts; *p;) {
        const char *comma = strchr(p, ',');
        size_t len = comma ? (size_t)(comma - p) : strlen(p);
        if (len == strlen(name) && strncasecmp(p, name, len) == 0)
            return 1;
        p += len + (comma != NULL);
    }
    return 0;
}

/* 0 when a state-changing request comes from another origin as a browser
 * says (Sec-Fetch-Site, Origin), or, authenticated by the session cookie,
 * does not say where it comes from: cross-site request forgery. */
static int same_origin(struct MHD_Connection *conn, const who *w)
{
    const char *site = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "Sec-Fetch-Site");
    const char *origin = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "Origin");
    const char *host = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "Host");
    if (site && strcmp(site, "same-origin") != 0 && strcmp(site, "none") != 0)
        return 0;
    if (origin) {
        const char *o = strncmp(origin, "http://", 7) == 0    ? origin + 7
                        : strncmp(origin, "https://", 8) == 0 ? origin + 8
                                                              : NULL;
        return o && host && strcasecmp(o, host) == 0;
    }
    return site != NULL || !w->cookie;
}

/* A new session for w: its cookie value (64 hex digits) in out. */
static int session_new(srv_http *h, const who *w, char out[65])
{
    uint8_t raw[PROTO_NONCE_SIZE]; /* 32 bytes from the CSPRNG */
    if (proto_auth_nonce(raw, NULL) != PT_OK)
        return 0;
    pt_hash_hex(raw, out);
    session n = {0};
    pt_sha256((const uint8_t *)out, 64, n.hash);
    snprintf(n.who, sizeof n.who, "%s", w->name);
    n.admin = w->admin;
    time_t now = time(NULL);
    n.expires = now + SRV_HTTP_SESSION_S;
    pthread_mutex_lock(&h->mu);
    /* The identity's oldest login once it holds SRV_HTTP_SESSIONS_PER_WHO
     * live ones (so no client's logins push out another's), else a free or
     * expired slot, else the oldest. */
    unsigned pick = 0, mine = 0, my_oldest = 0;
    for (unsigned i = 0; i < SRV_HTTP_SESSIONS; i++) {
        const session *e = &h->sessions[i];
        if (e->expires < h->sessions[pick].expires)
            pick = i;
        if (e->expires > now && strcmp(e->who, n.who) == 0 &&
            (mine++ == 0 || e->expires < h->sessions[my_oldest].expires))
            my_oldest = i;
    }
    if (mine >= SRV_HTTP_SESSIONS_PER_WHO)
        pick = my_oldest;
    h->sessions[pick] = n;
    pthread_mutex_unlock(&h->mu);
    OPENSSL_cleanse(raw, sizeof raw);
    return 1;
}

/* Hands an action to the loop and waits for its outcome. */
static enum MHD_Result do_action(srv_http *h, struct MHD_Connection *conn, const who *w, int kind,
                                 uint64_t id, int32_t priority)
{
    pthread_mutex_lock(&h->mu);
    action *a = NULL;
    for (unsigned i = 0; i < SRV_HTTP_ACTIONS && !a; i++)
        if (h->acts[i].state == ACT_FREE)
            a = &h->acts[i];
    if (!a) {
        pthread_mutex_unlock(&h->mu);
        return respond_error(conn, 503, "too many actions waiting; try again");
    }
    memset(a, 0, sizeof *a);
    a->state = ACT_PENDING;
    a->kind = kind;
    a->job = id;
    a->priority = priority;
    a->admin = w->admin;
    snprintf(a->who, sizeof a->who, "%s", w->name);
    char one = 1;
    if (write(h->wake_fd, &one, 1) < 0) {
        /* A full pipe already wakes the loop. */
    }
    struct timespec until;
    clock_gettime(CLOCK_REALTIME, &until);
    until.tv_sec += SRV_HTTP_ACTION_WAIT_MS / 1000;
    while (a->state != ACT_DONE && !h->stopping)
        if (pthread_cond_timedwait(&h->cv, &h->mu, &until) == ETIMEDOUT)
            break;
    if (a->state != ACT_DONE) {
        if (a->state == ACT_PENDING)
            a->state = ACT_FREE;
        else
            a->state = ACT_ABANDONED;
        pthread_mutex_unlock(&h->mu);
        return respond_error(conn, 503, "the coordinator did not answer in time");
    }
    unsigned status = a->status;
    char text[sizeof a->text];
    snprintf(text, sizeof text, "%s", a->text);
    a->state = ACT_FREE;
    pthread_mutex_unlock(&h->mu);
    if (status != 200)
        return respond_error(conn, status, text);
    snap *p = snap_get(h);
    const snap_job *j = snap_find(p, id);
    char *buf = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&buf, &len);
    if (!f) {
        snap_put(h, p);
        return MHD_NO;
    }
    if (j)
        proto_json_job(f, &j->info);
    else
        fputs("null", f);
    fputc('\n', f);
    snap_put(h, p);
    return respond_stream(conn, f, &buf, &len, "application/json");
}

static void json_jobs(FILE *f, const snap *p)
{
    fputc('[', f);
    for (uint32_t i = 0; p && i < p->njobs; i++) {
        fputs(i ? ",\n " : "", f);
        proto_json_job(f, &p->jobs[i].info);
    }
    fputs("]\n", f);
}

static void json_workers(FILE *f, const snap *p)
{
    fputc('[', f);
    for (uint32_t i = 0; p && i < p->nworkers; i++) {
        const snap_worker *w = &p->workers[i];
        fprintf(f, "%s{\"id\": %llu, \"name\": ", i ? ",\n " : "", (unsigned long long)w->id);
        proto_json_string(f, w->name);
        fputs(", \"address\": ", f);
        proto_json_string(f, w->peer);
        fprintf(f, ", \"threads\": %u, \"slots_wanted\": %u, \"deadline_misses\": %u, ", w->threads,
                w->want, w->misses);
        fputs("\"connected_seconds\": ", f);
        proto_json_double(f, w->connected_s);
        fprintf(f, ", \"tasks_done\": %llu, \"samples_done\": %llu, \"samples_per_second\": ",
                (unsigned long long)w->tasks_done, (unsigned long long)w->samples_done);
        proto_json_double(f, w->connected_s > 0.0 ? (double)w->samples_done / w->connected_s : 0.0);
        fputs(", \"last_result_seconds_ago\": ", f);
        if (w->last_result_s >= 0.0)
            proto_json_double(f, w->last_result_s);
        else
            fputs("null", f);
        fputs(", \"state\": \"connected\", \"reason\": \"\"}", f);
    }
    /* Blocked workers are closed and refused at HELLO: listed by name, with
     * the address refused with them ("" for loopback) and why. */
    for (uint32_t i = 0; p && i < p->nblocked; i++) {
        const srv_blocked *b = &p->blocked[i];
        fprintf(f, "%s{\"id\": null, \"name\": ", (i || p->nworkers) ? ",\n " : "");
        proto_json_string(f, b->name);
        fputs(", \"address\": ", f);
        proto_json_string(f, b->addr);
        fputs(", \"state\": \"blocked\", \"reason\": ", f);
        proto_json_string(f, b->why);
        fputc('}', f);
    }
    fputs("]\n", f);
}

/* "/api/jobs/123/rest": 123 and "/rest" ("" when none); 0 when not a job id. */
static uint64_t parse_job_path(const char *p, const char **rest)
{
    uint64_t id = 0;
    int digits = 0;
    while (*p >= '0' && *p <= '9' && digits < 19) {
        id = id * 10 + (uint64_t)(*p++ - '0');
        digits++;
    }
    if (!digits || (*p && *p != '/'))
        return 0;
    *rest = p;
    return id;
}

static enum MHD_Result post_field(void *cls, enum MHD_ValueKind kind, const char *key,
                                  const char *filename, const char *type, const char *enc,
                                  const char *data, uint64_t off, size_t size)
{
    (void)kind, (void)filename, (void)type, (void)enc;
    req *r = cls;
    char *dst = NULL;
    size_t cap = 0, *have = NULL, pr_len = strlen(r->priority);
    if (strcmp(key, "token") == 0) {
        dst = r->token;
        cap = sizeof r->token - 1;
        have = &r->token_len;
    } else if (strcmp(key, "priority") == 0) {
        dst = r->priority;
        cap = sizeof r->priority - 1;
        have = &pr_len;
    } else {
        return MHD_YES;
    }
    if (off != *have || size > cap - *have) {
        r->too_big = 1;
        return MHD_NO;
    }
    memcpy(dst + *have, data, size);
    *have += size;
    dst[*have] = '\0';
    return MHD_YES;
}

static int parse_priority(const char *v, int32_t *out)
{
    if (!v || !*v)
        return 0;
    char *end;
    errno = 0;
    long x = strtol(v, &end, 10);
    if (*end || errno || x < -1000000 || x > 1000000)
        return 0;
    *out = (int32_t)x;
    return 1;
}

static double arg_double(struct MHD_Connection *conn, const char *key, double def, double lo,
                         double hi)
{
    const char *v = MHD_lookup_connection_value(conn, MHD_GET_ARGUMENT_KIND, key);
    if (!v)
        return def;
    char *end;
    double x = strtod(v, &end);
    if (*end || !(x >= lo && x <= hi))
        return def;
    return x;
}

/* A colour ramp for heat maps: black, blue, red, yellow, white over 0..1. */
static void heat(double t, uint8_t *px)
{
    static const double stops[5][3] = {
        {0, 0, 0}, {0.1, 0.1, 0.7}, {0.85, 0.1, 0.1}, {1, 0.85, 0}, {1, 1, 1}};
    if (!(t > 0.0))
        t = 0.0;
    if (t > 1.0)
        t = 1.0;
    double x = t * 4.0;
    int i = x >= 4.0 ? 3 : (int)x;
    double u = x - i;
    for (int c = 0; c < 3; c++)
        px[c] = (uint8_t)(255.0 * (stops[i][c] * (1 - u) + stops[i + 1][c] * u) + 0.5);
}

/* The job's current image as a PNG: view "rgb" or "standard", "filmic" or
 * "agx" (the previews' view transforms, common/image/view.h, after exposure
 * in stops), "samples" (samples per pixel over the most any pixel has) or
 * "error" (the relative standard error of each pixel, 0 to 20 %). */
static enum MHD_Result make_png(struct MHD_Connection *conn, const snap_job *j)
{
    const char *view = MHD_lookup_connection_value(conn, MHD_GET_ARGUMENT_KIND, "view");
    if (!view)
        view = "rgb";
    pt_view tv = {PT_VIEW_STANDARD, 0.0f};
    int image = !strcmp(view, "rgb") || pt_view_parse("view", view, &tv.kind, NULL) == PT_OK;
    if (!image && strcmp(view, "samples") && strcmp(view, "error"))
        return respond_error(conn, 400, "view: rgb, standard, filmic, agx, samples or error");
    tv.exposure = (float)arg_double(conn, "exposure", 0.0, -PT_VIEW_MAX_EV, PT_VIEW_MAX_EV);
    pt_image *img = NULL;
    pt_error err = {0};
    if (!j->exr[0] || pt_exr_read_nofollow(j->exr, &img, NULL, &err) != PT_OK)
        return respond_error(conn, 404, "no image yet");
    size_t n = (size_t)img->width * img->height;
    uint8_t *rgb = pt_malloc_array(n, 3);
    if (!rgb) {
        pt_image_free(img);
        return respond_error(conn, 500, "out of memory");
    }
    float smax = 0.0f;
    for (size_t i = 0; i < n; i++)
        smax = img->samples[i] > smax ? img->samples[i] : smax;
    for (size_t i = 0; i < n; i++) {
        uint8_t *px = rgb + 3 * i;
        if (image) {
            const float c[3] = {img->r[i], img->g[i], img->b[i]};
            pt_view_pixel(&tv, c, px);
        } else if (view[0] == 's') {
            heat(smax > 0.0f ? img->samples[i] / smax : 0.0, px);
        } else {
            double lum = 0.2126 * img->r[i] + 0.7152 * img->g[i] + 0.0722 * img->b[i];
            double e = img->samples[i] > 0.0f && lum > 1e-6 ? sqrt(img->variance[i]) / lum
                                                            : (img->samples[i] > 0 ? 0.0 : 1.0);
            heat(e / 0.2, px);
        }
    }
    uint8_t *png = NULL;
    size_t len = 0;
    pt_status st = pt_png_encode_rgb8(rgb, img->width, img->height, &png, &len, &err);
    pt_image_free(img);
    pt_free(rgb);
    if (st != PT_OK)
        return respond_error(conn, 500, err.msg);
    /* MHD frees with free(); the buffer is pt_malloc'd, so copy it. */
    enum MHD_Result ret = respond(conn, 200, "image/png", png, len, MHD_RESPMEM_MUST_COPY);
    pt_free(png);
    return ret;
}

/* make_png holds a whole float image: only SRV_HTTP_RENDERS at a time. */
static enum MHD_Result serve_png(srv_http *h, struct MHD_Connection *conn, const snap_job *j)
{
    pthread_mutex_lock(&h->mu);
    int ok = h->rendering < (int)SRV_HTTP_RENDERS;
    h->rendering += ok;
    pthread_mutex_unlock(&h->mu);
    if (!ok)
        return respond_error(conn, 503, "busy making other images; try again");
    enum MHD_Result ret = make_png(conn, j);
    pthread_mutex_lock(&h->mu);
    h->rendering--;
    pthread_mutex_unlock(&h->mu);
    return ret;
}

static enum MHD_Result serve_exr(struct MHD_Connection *conn, const snap_job *j)
{
    /* Sent from the open file: a rename by the writer meanwhile leaves this
     * copy whole, and no image is held in memory. Opened as FETCH opens it:
     * a link or a FIFO planted at the image's name is refused, not followed
     * or waited on. */
    int fd = -1;
    struct stat st;
    if (!j->exr[0] || pt_open_regular(j->exr, 0, &fd, NULL) != PT_OK)
        return respond_error(conn, 404, "no image yet");
    if (fstat(fd, &st) != 0) {
        close(fd);
        return respond_error(conn, 404, "no image yet");
    }
    struct MHD_Response *r = MHD_create_response_from_fd((uint64_t)st.st_size, fd);
    if (!r) {
        close(fd);
        return MHD_NO;
    }
    char disp[128];
    snprintf(disp, sizeof disp, "attachment; filename=\"job%llu.exr\"",
             (unsigned long long)j->info.job_id);
    MHD_add_response_header(r, "Content-Disposition", disp);
    return send_response(conn, 200, r, "image/x-exr");
}

/* Server-Sent Events of one job: its JSON each time a snapshot changes it,
 * a comment every 15 s otherwise; the stream ends when the job does. */
typedef struct sse {
    srv_http *h;
    uint64_t job, seen;
    char last[4096];
    int ended;
} sse;

static ssize_t sse_read(void *cls, uint64_t pos, char *out, size_t max)
{
    (void)pos;
    sse *e = cls;
    srv_http *h = e->h;
    if (e->ended)
        return MHD_CONTENT_READER_END_OF_STREAM;
    pthread_mutex_lock(&h->mu);
    struct timespec until;
    clock_gettime(CLOCK_REALTIME, &until);
    until.tv_sec += 15;
    while (h->version == e->seen && !h->stopping)
        if (pthread_cond_timedwait(&h->cv, &h->mu, &until) == ETIMEDOUT)
            break;
    int fresh = h->version != e->seen;
    if (h->stopping) {
        pthread_mutex_unlock(&h->mu);
        return MHD_CONTENT_READER_END_OF_STREAM;
    }
    e->seen = h->version;
    pthread_mutex_unlock(&h->mu);
    if (!fresh)
        return snprintf(out, max, ": ping\n\n");
    snap *p = snap_get(h);
    const snap_job *j = snap_find(p, e->job);
    char *buf = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&buf, &len);
    if (!f) {
        snap_put(h, p);
        return MHD_CONTENT_READER_END_WITH_ERROR;
    }
    if (j) {
        fputs("{\"job\": ", f);
        proto_json_job(f, &j->info);
        fprintf(f, ", \"images\": %lu}", j->images);
    } else {
        fputs("null", f);
    }
    fclose(f);
    if (!j || (j->info.state != PROTO_JOB_QUEUED && j->info.state != PROTO_JOB_RUNNING))
        e->ended = 1;
    snap_put(h, p);
    ssize_t n = 0;
    if (len + 16 <= max && strcmp(buf, e->last) != 0) {
        n = snprintf(out, max, "data: %s\n\n", buf);
        snprintf(e->last, sizeof e->last, "%s", buf);
    } else {
        n = snprintf(out, max, ": same\n\n");
    }
    free(buf);
    return n;
}

static enum MHD_Result serve_events(srv_http *h, struct MHD_Connection *conn, uint64_t id)
{
    sse *e = calloc(1, sizeof *e);
    if (!e)
        return MHD_NO;
    e->h = h;
    e->job = id;
    struct MHD_Response *r =
        MHD_create_response_from_callback(MHD_SIZE_UNKNOWN, 8192, sse_read, e, free);
    if (!r) {
        free(e);
        return MHD_NO;
    }
    return send_response(conn, 200, r, "text/event-stream");
}

static enum MHD_Result serve_api(srv_http *h, struct MHD_Connection *conn, const who *w,
                                 const char *method, const char *url, req *r)
{
    int get = strcmp(method, "GET") == 0 || strcmp(method, "HEAD") == 0;
    int post = strcmp(method, "POST") == 0;
    char *buf = NULL;
    size_t len = 0;
    if (strcmp(url, "/api/jobs") == 0 || strcmp(url, "/api/workers") == 0) {
        if (!get)
            return respond_error(conn, 405, "GET only");
        snap *p = snap_get(h);
        FILE *f = open_memstream(&buf, &len);
        if (!f) {
            snap_put(h, p);
            return MHD_NO;
        }
        if (url[5] == 'j')
            json_jobs(f, p);
        else
            json_workers(f, p);
        snap_put(h, p);
        return respond_stream(conn, f, &buf, &len, "application/json");
    }
    if (strncmp(url, "/api/jobs/", 10) != 0)
        return respond_error(conn, 404, "no such API");
    const char *rest = "";
    uint64_t id = parse_job_path(url + 10, &rest);
    if (id == 0)
        return respond_error(conn, 404, "not a job id");
    if (strcmp(rest, "/cancel") == 0 || strcmp(rest, "/priority") == 0) {
        if (!post)
            return respond_error(conn, 405, "POST only");
        int32_t prio = 0;
        if (rest[1] == 'p') {
            const char *v =
                r->priority[0]
                    ? r->priority
                    : MHD_lookup_connection_value(conn, MHD_GET_ARGUMENT_KIND, "priority");
            if (!parse_priority(v, &prio))
                return respond_error(conn, 400, "priority: an integer, -1000000..1000000");
        }
        return do_action(h, conn, w, rest[1] == 'c' ? ACT_CANCEL : ACT_PRIORITY, id, prio);
    }
    if (!get)
        return respond_error(conn, 405, "GET only");
    if (strcmp(rest, "/events") == 0)
        return serve_events(h, conn, id);
    snap *p = snap_get(h);
    const snap_job *j = snap_find(p, id);
    enum MHD_Result ret;
    if (!j) {
        char text[64];
        snprintf(text, sizeof text, "no job %llu", (unsigned long long)id);
        ret = respond_error(conn, 404, text);
    } else if (rest[0] == '\0') {
        FILE *f = open_memstream(&buf, &len);
        if (!f) {
            ret = MHD_NO;
        } else {
            proto_json_job(f, &j->info);
            fputc('\n', f);
            ret = respond_stream(conn, f, &buf, &len, "application/json");
        }
    } else if (strcmp(rest, "/image.png") == 0) {
        ret = serve_png(h, conn, j);
    } else if (strcmp(rest, "/image.exr") == 0) {
        ret = serve_exr(conn, j);
    } else {
        ret = respond_error(conn, 404, "no such API");
    }
    snap_put(h, p);
    return ret;
}

/* ---- /metrics: the Prometheus text format (version 0.0.4) ---- */

static void metric_head(FILE *f, const char *name, const char *type, const char *help)
{
    fprintf(f, "# HELP %s %s\n# TYPE %s %s\n", name, help, name, type);
}

static void metric_counter(FILE *f, const char *name, const char *help, uint64_t v)
{
    metric_head(f, name, "counter", help);
    fprintf(f, "%s %llu\n", name, (unsigned long long)v);
}

static void metric_gauge(FILE *f, const char *name, const char *help, double v)
{
    metric_head(f, name, "gauge", help);
    fprintf(f, "%s %.17g\n", name, v);
}

static void metric_histogram(FILE *f, const char *name, const char *help, const srv_histogram *h)
{
    metric_head(f, name, "histogram", help);
    double bound = SRV_HIST_FIRST;
    for (int i = 0; i < SRV_HIST_BUCKETS; i++, bound *= SRV_HIST_FACTOR)
        fprintf(f, "%s_bucket{le=\"%g\"} %llu\n", name, bound, (unsigned long long)h->buckets[i]);
    fprintf(f, "%s_bucket{le=\"+Inf\"} %llu\n%s_sum %.17g\n%s_count %llu\n", name,
            (unsigned long long)h->count, name, h->sum, name, (unsigned long long)h->count);
}

static void metrics_text(FILE *f, const snap *p)
{
    static const srv_counters none;
    const srv_counters *c = p ? &p->counters : &none;
    uint32_t by_state[6] = {0}, threads = 0;
    for (uint32_t i = 0; p && i < p->njobs; i++)
        if (p->jobs[i].info.state < 6)
            by_state[p->jobs[i].info.state]++;
    for (uint32_t i = 0; p && i < p->nworkers; i++)
        threads += p->workers[i].threads;
    metric_head(f, "ptfarm_jobs", "gauge", "Jobs the coordinator knows, by state.");
    for (uint32_t st = PROTO_JOB_QUEUED; st <= PROTO_JOB_FAILED; st++)
        fprintf(f, "ptfarm_jobs{state=\"%s\"} %u\n", proto_job_state_name(st), by_state[st]);
    metric_counter(f, "ptfarm_samples_merged_total", "Samples merged into job images.",
                   c->samples_merged);
    metric_counter(f, "ptfarm_tasks_leased_total", "Tasks leased to workers.", c->tasks_leased);
    metric_counter(f, "ptfarm_tasks_requeued_total",
                   "Leased tasks put back because their worker left or their job paused.",
                   c->tasks_requeued);
    metric_counter(f, "ptfarm_tasks_expired_total", "Leases past their deadline, requeued.",
                   c->tasks_expired);
    metric_counter(f, "ptfarm_results_rejected_total",
                   "Results refused as invalid or not leased to their sender.",
                   c->results_rejected);
    metric_counter(f, "ptfarm_samples_rejected_total",
                   "Samples merged as rejected: NaN or Inf, or results that held no sample.",
                   c->samples_rejected);
    metric_counter(f, "ptfarm_state_write_errors_total",
                   "Failed writes to the state folder (queue file, results logs, checkpoints).",
                   c->state_write_errors);
    metric_counter(f, "ptfarm_results_log_holds_total",
                   "Times workers were not read because the results log was over --max-log-mb "
                   "waiting for the disk.",
                   c->log_holds);
    metric_gauge(f, "ptfarm_results_log_unsynced_bytes",
                 "Bytes of results not yet durable: their log records and decoded pixels.",
                 (double)c->log_unsynced);
    metric_gauge(f, "ptfarm_workers_connected", "Authenticated workers connected.",
                 p ? p->nworkers : 0);
    metric_gauge(f, "ptfarm_worker_threads", "Render threads of the connected workers.", threads);
    metric_gauge(f, "ptfarm_clients_connected", "Authenticated clients (ptctl) connected.",
                 p ? p->nclients : 0);
    metric_counter(f, "ptfarm_received_bytes_total", "Bytes received from workers and clients.",
                   p ? p->bytes_in : 0);
    metric_counter(f, "ptfarm_sent_bytes_total", "Bytes sent to workers and clients.",
                   p ? p->bytes_out : 0);
    metric_histogram(f, "ptfarm_merge_seconds", "Event-loop time merging one result.", &c->merge);
    metric_histogram(f, "ptfarm_image_save_seconds",
                     "Event-loop time resolving a progressive image for its writer.", &c->save);
    metric_histogram(f, "ptfarm_checkpoint_seconds", "Time writing one job checkpoint.",
                     &c->checkpoint);
    metric_gauge(f, "ptfarm_uptime_seconds", "Seconds since the coordinator started.",
                 p ? p->uptime_s : 0.0);
}

static enum MHD_Result serve_login(srv_http *h, struct MHD_Connection *conn, req *r,
                                   const char *addr)
{
    who w = {0};
    if (r->token_len && !r->too_big)
        who_token(h, (const uint8_t *)r->token, r->token_len, &w);
    OPENSSL_cleanse(r->token, sizeof r->token);
    if (!w.ok) {
        auth_failed(h, addr);
        return respond_text(conn, 401, "text/html; charset=utf-8", srv_http_login_page(1));
    }
    char value[65], cookie[160];
    if (!session_new(h, &w, value))
        return respond_error(conn, 500, "no random bytes for a session");
    snprintf(cookie, sizeof cookie, COOKIE "=%s; Path=/; HttpOnly; SameSite=Strict; Max-Age=%u",
             value, SRV_HTTP_SESSION_S);
    struct MHD_Response *resp =
        MHD_create_response_from_buffer(0, (void *)"", MHD_RESPMEM_PERSISTENT);
    if (!resp)
        return MHD_NO;
    MHD_add_response_header(resp, "Set-Cookie", cookie);
    MHD_add_response_header(resp, "Location", "/");
    return send_response(conn, 303, resp, "text/plain");
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
        mark_busy(h, conn, 1);
        if (strcmp(method, "POST") == 0)
            r->pp = MHD_create_post_processor(conn, 4096, post_field, r);
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
        return respond_error(
            conn, 413,
            "request body: form fields (application/x-www-form-urlencoded) of at most 16 KiB");
    /* DNS rebinding: a page of the attacker's name must not read the API. */
    const char *host = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "Host");
    if (host && !host_allowed(h, host))
        return respond_error(conn, 421,
                             "this dashboard does not answer to that host name (ptserve "
                             "--http-host names the ones it does)");
    int changes = strcmp(method, "GET") != 0 && strcmp(method, "HEAD") != 0;
    char addr[SRV_AUTHLIMIT_ADDR];
    client_addr(conn, addr);
    if (strcmp(url, "/login") == 0) {
        if (!changes)
            return respond_text(conn, 200, "text/html; charset=utf-8", srv_http_login_page(0));
        who none = {0};
        if (!same_origin(conn, &none))
            return respond_error(conn, 403, "a login from another site is refused");
        uint64_t ms = auth_blocked(h, addr);
        if (ms)
            return respond_blocked(conn, ms);
        return serve_login(h, conn, r, addr);
    }
    const srv_http_asset *a = srv_http_asset_find(url);
    if (a && a->is_public)
        return respond(conn, 200, a->type, (void *)a->data, *a->len, MHD_RESPMEM_PERSISTENT);
    uint64_t ms = h->token_len ? auth_blocked(h, addr) : 0;
    if (ms)
        return respond_blocked(conn, ms);
    who w = authenticate(h, conn);
    if (!w.ok && w.tried)
        auth_failed(h, addr);
    if (w.ok && changes && !same_origin(conn, &w))
        return respond_error(conn, 403,
                             "a request from another site is refused (cross-site request "
                             "forgery)");
    if (!w.ok) {
        if (strncmp(url, "/api/", 5) == 0 || strcmp(url, "/metrics") == 0)
            return respond_error(conn, 401, "a token is needed: Authorization: Bearer TOKEN");
        return respond_text(conn, 401, "text/html; charset=utf-8", srv_http_login_page(0));
    }
    if (strncmp(url, "/api/", 5) == 0)
        return serve_api(h, conn, &w, method, url, r);
    if (strcmp(url, "/metrics") == 0) {
        char *buf = NULL;
        size_t len = 0;
        FILE *f = open_memstream(&buf, &len);
        if (!f)
            return MHD_NO;
        snap *p = snap_get(h);
        metrics_text(f, p);
        snap_put(h, p);
        return respond_stream(conn, f, &buf, &len, "text/plain; version=0.0.4; charset=utf-8");
    }
    if (strcmp(method, "GET") && strcmp(method, "HEAD"))
        return respond_error(conn, 405, "GET only");
    if (a)
        return respond(conn, 200, a->type, (void *)a->data, *a->len, MHD_RESPMEM_PERSISTENT);
    return respond_text(conn, 404, "text/plain; charset=utf-8", "not found\n");
}

static void on_done(void *cls, struct MHD_Connection *conn, void **con_cls,
                    enum MHD_RequestTerminationCode toe)
{
    (void)toe;
    req *r = *con_cls;
    if (!r)
        return;
    mark_busy(cls, conn, 0);
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
                            0, accept_policy, h, on_request, h, MHD_OPTION_LISTEN_SOCKET,
                            (MHD_socket)fd, MHD_OPTION_NOTIFY_CONNECTION, on_connection, h,
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
    snap_unref_locked(h->cur);
    OPENSSL_cleanse(h->token, sizeof h->token);
    OPENSSL_cleanse(h->sessions, sizeof h->sessions);
    pthread_cond_destroy(&h->cv);
    pthread_mutex_destroy(&h->mu);
    pt_free(h);
}
