/*
 * http_impl.h - the inside of the dashboard (server/api/http.h), shared by
 * the files it is cut into by concern: http.c (the snapshot the loop
 * publishes, its actions, the request handler, start and stop), http_auth.c
 * (who asks: tokens, sessions, the accept policy, hosts and origins) and
 * http_views.c (JSON, images, event streams, /metrics). No other file
 * includes it.
 *
 * Threads: as http.h: the loop's functions on the loop thread, the rest on
 * libmicrohttpd's, under srv_http's mutex where it says so.
 */
#ifndef PT_SERVER_API_HTTP_IMPL_H
#define PT_SERVER_API_HTTP_IMPL_H

#include <limits.h>
#include <microhttpd.h>
#include <pthread.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <time.h>

#include "protocol/auth.h"
#include "server/api/http.h"
#include "server/net/authlimit.h"
#include "server/net/loop.h"

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

/* Connections that have waited SRV_HTTP_HEADER_S for a request's headers
 * are shut down, so their thread reads the end and libmicrohttpd closes
 * them: a client that sends its headers a byte at a time holds a
 * connection that long, no longer. Under mu, which NOTIFY_CLOSED takes
 * before libmicrohttpd closes a descriptor, so the one shut down is the
 * connection's own. */
void http_sweep_headers(srv_http *h, uint64_t now);

/* A new session for w: its cookie value (64 hex digits) in out. */
int http_session_new(srv_http *h, const who *w, char out[65]);

enum MHD_Result http_serve_api(srv_http *h, struct MHD_Connection *conn, const who *w,
                               const char *method, const char *url, req *r);

/* Queues r with status, its type and no-store, and lets it go. */
enum MHD_Result http_send_response(struct MHD_Connection *conn, unsigned status,
                                   struct MHD_Response *r, const char *type);

/* 0 when a state-changing request comes from another origin as a browser
 * says (Sec-Fetch-Site, Origin), or, authenticated by the session cookie,
 * does not say where it comes from: cross-site request forgery. */
int http_same_origin(struct MHD_Connection *conn, const who *w);

/* 429 with Retry-After: addr is blocked for ms more. */
enum MHD_Result http_respond_blocked(struct MHD_Connection *conn, uint64_t ms);

enum MHD_Result http_post_field(void *cls, enum MHD_ValueKind kind, const char *key,
                                const char *filename, const char *type, const char *enc,
                                const char *data, uint64_t off, size_t size);

/* Tracks a connection from its start to its close. */
void http_on_connection(void *cls, struct MHD_Connection *conn, void **socket_context,
                        enum MHD_ConnectionNotificationCode code);

void http_metrics_text(FILE *f, const snap *p);

/* A request of conn began to be answered (busy 1: its headers are in) or
 * was answered (0: the connection waits for the next one's headers). */
void http_mark_busy(srv_http *h, struct MHD_Connection *conn, int busy);

/* 1 when host (a Host header, or an Origin's host part: NAME[:PORT]) names
 * this server as only its operator would: an IP literal, localhost, or a
 * --http-host name. A DNS name an attacker points at this address (DNS
 * rebinding) is none of those. */
int http_host_allowed(const srv_http *h, const char *host);

/* Hands an action to the loop and waits for its outcome. */
enum MHD_Result http_do_action(srv_http *h, struct MHD_Connection *conn, const who *w, int kind,
                               uint64_t id, int32_t priority);

/* The client's address as text (the failed-authentication table's key). */
void http_client_addr(struct MHD_Connection *conn, char out[SRV_AUTHLIMIT_ADDR]);

who http_authenticate(srv_http *h, struct MHD_Connection *conn);

void http_auth_failed(srv_http *h, const char *addr);

/* Milliseconds addr stays blocked for failed authentications (0: none). */
uint64_t http_auth_blocked(srv_http *h, const char *addr);

/* libmicrohttpd's accept policy: a connection from a network that holds
 * SRV_HTTP_PER_NETWORK already is refused before a thread is started, so
 * slow clients need that many networks to hold every connection. */
enum MHD_Result http_accept_policy(void *cls, const struct sockaddr *sa, socklen_t len);

/* Who a bearer token is: the shared token's admin or a --clients-file
 * client. Both sides go through HMAC over the random label, so every
 * comparison is CRYPTO_memcmp over MACs and takes the same time whatever
 * the token. */
void http_who_token(const srv_http *h, const uint8_t *tok, size_t len, who *w);

void http_snap_put(srv_http *h, snap *p);

snap *http_snap_get(srv_http *h);

const snap_job *http_snap_find(const snap *p, uint64_t id);

enum MHD_Result http_serve_login(srv_http *h, struct MHD_Connection *conn, req *r,
                                 const char *addr);

enum MHD_Result http_respond(struct MHD_Connection *conn, unsigned status, const char *type,
                             void *data, size_t len, enum MHD_ResponseMemoryMode mode);

/* Closes f, an open_memstream over *buf and *len (both set only then), and
 * sends what it holds. */
enum MHD_Result http_respond_stream(struct MHD_Connection *conn, FILE *f, char **buf, size_t *len,
                                    const char *type);

/* {"error": TEXT} with status. */
enum MHD_Result http_respond_error(struct MHD_Connection *conn, unsigned status, const char *text);

#define COOKIE "ptfarm_session" /* the session cookie's name */

enum MHD_Result http_respond_text(struct MHD_Connection *conn, unsigned status, const char *type,
                                  const char *text);

/* What a viewer would see change at once: jobs and their states and
 * priorities, peers. Progress alone waits for the next second, since each
 * snapshot computes every running job's error estimate over its film. */
uint64_t http_loop_signature(const srv_server *s);

void http_snap_unref_locked(snap *p);

#endif
