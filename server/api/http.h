/*
 * http.h - the coordinator's web dashboard and HTTP API (ptserve --http).
 *
 * libmicrohttpd serves it from its own threads (one per connection, at most
 * SRV_HTTP_MAX_CONNS, each request's buffers within SRV_HTTP_MEMORY bytes and
 * its body (form fields only) within SRV_HTTP_BODY, an idle connection
 * closed after SRV_HTTP_TIMEOUT_S). Those threads never touch the loop's structures:
 * - the loop publishes a snapshot (srv_http_publish: every job's JOB_INFO,
 *   its image path and how many images were written, the workers, the
 *   counters) under the module's mutex about once a second and soon after a
 *   change; requests read the newest snapshot, reference-counted, so a
 *   slow reader never holds the lock or the loop;
 * - actions (cancel, priority) wait in a fixed table of SRV_HTTP_ACTIONS
 *   slots; the request writes a byte to the loop's wake pipe and waits for
 *   the loop to run it (srv_http_drain) and post the outcome, at most
 *   SRV_HTTP_ACTION_WAIT_MS (then 503; the loop still runs it).
 *
 * Who may ask: without a token (ptserve has no --token-file) it listens on
 * loopback only and every request is the admin's, like the worker port.
 * With one, every page and API call needs `Authorization: Bearer TOKEN`
 * (the shared token: admin; a --clients-file token: that client), or the
 * session cookie that POST /login sets (HttpOnly, SameSite=Strict) for a
 * token typed into the login form. Tokens are compared in constant time
 * (through HMAC over a fixed label, like the worker handshake: no early
 * exit). A request without is answered 401 (a page: the login form); an
 * action on a job of another identity, 403. Failed authentications (a wrong
 * bearer token, session cookie or login) are counted per address with the
 * worker port's backoff (server/net/authlimit.h): a blocked address is answered
 * 429 with Retry-After, and each block is logged. An identity holds at most
 * SRV_HTTP_SESSIONS_PER_WHO logins, so no client's logins push out
 * another's.
 *
 * Browsers: a request whose Host is not an IP address, localhost or a
 * --http-host name is refused (421), so a name an attacker points at this
 * address (DNS rebinding) reads nothing. A state-changing request (POST)
 * that a browser sent from another origin (its Origin or Sec-Fetch-Site
 * says so) is refused (403), and one authenticated by the session cookie
 * must say where it came from (Origin or Sec-Fetch-Site): cross-site
 * request forgery is refused with or without a token. At most
 * SRV_HTTP_PER_ADDRESS connections come from one address and
 * SRV_HTTP_PER_NETWORK from one network (IPv4 /24, IPv6 /64), refused at
 * accept before a thread is started; a connection that has not sent a
 * request's headers within SRV_HTTP_HEADER_S of opening (or of its last
 * answer) is closed, however slowly it keeps sending.
 *
 * No part of a URL reaches the file system: pages and scripts are a fixed
 * table compiled in (server/api/http_assets.c); a job's image is read from the
 * path the loop published for that job id.
 *
 * Threads: srv_http_start, srv_http_publish, srv_http_drain and
 * srv_http_stop on the event-loop thread only; the rest is internal.
 */
#ifndef PT_SERVER_HTTP_H
#define PT_SERVER_HTTP_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"
#include "server/core.h"

#define SRV_HTTP_MAX_CONNS 64u
#define SRV_HTTP_MEMORY (64u << 10)
#define SRV_HTTP_BODY (16u << 10) /* a request body: form fields only; then 413 */
#define SRV_HTTP_TIMEOUT_S 30u
#define SRV_HTTP_ACTIONS 32u
#define SRV_HTTP_ACTION_WAIT_MS 5000u
#define SRV_HTTP_RENDERS 2u /* PNGs made at once (each reads the whole EXR); then 503 */
#define SRV_HTTP_SESSIONS 256u
#define SRV_HTTP_SESSIONS_PER_WHO 8u     /* an identity's logins: its 9th replaces its oldest */
#define SRV_HTTP_PER_ADDRESS 8u          /* connections from one address */
#define SRV_HTTP_PER_NETWORK 16u         /* from one IPv4 /24 or IPv6 /64 */
#define SRV_HTTP_HEADER_S 10u            /* a request's headers must be in within this */
#define SRV_HTTP_SESSION_S (12u * 3600u) /* a login lasts this long */

typedef struct srv_http srv_http;

/* Starts serving s->cfg->http (HOST:PORT; loopback only without a token,
 * as srv_loop_open does for the worker port) and writes the bound port to
 * s->cfg->http_port_file. Needs the loop open (its wake pipe). *out is new
 * (srv_http_stop). */
pt_status srv_http_start(srv_server *s, srv_http **out, pt_error *err);

/* Publishes a new snapshot when one is due (a second since the last, or a
 * quarter of a second after a job, its state or priority, or a peer came or
 * went); force: now. */
void srv_http_publish(srv_server *s, srv_http *h, int force);

/* Runs the actions waiting and answers them. */
void srv_http_drain(srv_server *s, srv_http *h);

/* Stops the daemon (waits for its threads) and frees. Accepts NULL. */
void srv_http_stop(srv_http *h);

#endif
