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
#include "server/net/authlimit.h"
#include "server/net/clients.h"
#include "server/net/loop.h"
#include "server/sched/frames.h"
#include "server/sched/queue.h"

/* Who a bearer token is: the shared token's admin or a --clients-file
 * client. Both sides go through HMAC over the random label, so every
 * comparison is CRYPTO_memcmp over MACs and takes the same time whatever
 * the token. */
void http_who_token(const srv_http *h, const uint8_t *tok, size_t len, who *w)
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

who http_authenticate(srv_http *h, struct MHD_Connection *conn)
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
            http_who_token(h, (const uint8_t *)auth + 7, strlen(auth + 7), &w);
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
void http_client_addr(struct MHD_Connection *conn, char out[SRV_AUTHLIMIT_ADDR])
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
enum MHD_Result http_accept_policy(void *cls, const struct sockaddr *sa, socklen_t len)
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
void http_mark_busy(srv_http *h, struct MHD_Connection *conn, int busy)
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
void http_sweep_headers(srv_http *h, uint64_t now)
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
void http_on_connection(void *cls, struct MHD_Connection *conn, void **socket_context,
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
uint64_t http_auth_blocked(srv_http *h, const char *addr)
{
    pthread_mutex_lock(&h->mu);
    uint64_t ms = srv_authlimit_blocked(&h->fails, addr, pt_now_ms());
    pthread_mutex_unlock(&h->mu);
    return ms;
}

void http_auth_failed(srv_http *h, const char *addr)
{
    pthread_mutex_lock(&h->mu);
    srv_authlimit_failed(&h->fails, addr, "dashboard", pt_now_ms());
    pthread_mutex_unlock(&h->mu);
}

/* 429 with Retry-After: addr is blocked for ms more. */
enum MHD_Result http_respond_blocked(struct MHD_Connection *conn, uint64_t ms)
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
    return http_send_response(conn, 429, r, "application/json");
}

/* 1 when host (a Host header, or an Origin's host part: NAME[:PORT]) names
 * this server as only its operator would: an IP literal, localhost, or a
 * --http-host name. A DNS name an attacker points at this address (DNS
 * rebinding) is none of those. */
int http_host_allowed(const srv_http *h, const char *host)
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
int http_same_origin(struct MHD_Connection *conn, const who *w)
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
int http_session_new(srv_http *h, const who *w, char out[65])
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
