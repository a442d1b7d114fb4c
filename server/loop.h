/*
 * loop.h - the event loop: non-blocking sockets under one epoll, and the
 * connections (workers and clients) it serves.
 *
 * Owns every srv_conn: its input (a proto_frame_reader of IN_START bytes,
 * grown only to the frame its header declares once the decoder has checked
 * that length against the cap: PROTO_MAX_PAYLOAD_PREAUTH before
 * authentication, PROTO_MAX_PAYLOAD after),
 * its output (a writer capped at OUT_MAX; a peer whose unsent output passes
 * OUT_HIGH is not read from, which is backpressure), the handshake (HELLO,
 * CHALLENGE, AUTH, WELCOME) and its timeout, and the stalled-frame timeout.
 * A whole frame from a ready peer goes to server/workers.h or
 * server/requests.h by the peer's role. A protocol error is answered with
 * ERROR, then the peer is closed once that is flushed (or after a grace
 * time); a connection is freed only by srv_loop_sweep, never inside its own
 * callback, so a handler may close the peer it is serving.
 *
 * Threads: called only from the event-loop thread; the signal handler only
 * sets a flag and writes to a pipe.
 */
#ifndef PT_SERVER_LOOP_H
#define PT_SERVER_LOOP_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/text.h"
#include "protocol/frame.h"
#include "protocol/msg.h"
#include "server/core.h"

#define SRV_OUT_HIGH (16u << 20) /* stop reading a peer whose unsent output passes this */

enum { SRV_C_HELLO, SRV_C_AUTH, SRV_C_READY };

struct srv_conn {
    int fd;
    uint64_t id;
    int state; /* SRV_C_* */
    uint8_t role;
    int closing;
    uint64_t close_at;
    proto_frame_reader in;
    proto_writer out;
    size_t out_off;
    uint8_t nonce[PROTO_NONCE_SIZE];
    char name[PROTO_MAX_NAME + 1];
    char shown[PT_TEXT_ESCAPED_SIZE(PROTO_MAX_NAME)]; /* name escaped for logs, set with it */
    char peer[64];
    uint16_t threads;
    uint32_t want;      /* worker: free slots it asked tasks for */
    uint32_t misses;    /* worker: deadline misses since its last result (workers.h) */
    uint64_t missed_at; /* when the last one was counted */
    uint64_t t_connect, t_progress;
    uint32_t events;
    /* client (server/requests.c) */
    uint64_t watch, watch_t; /* job watched, last JOB_INFO sent */
    uint8_t *fetch;          /* the EXR being sent */
    size_t fetch_len, fetch_off;
    uint8_t fetch_hash[32];
    int uploading;
    int verifying; /* its upload is being verified (a srv_upload in flight) */
    proto_submit up;
    uint8_t *up_buf;
    size_t up_len, up_cap;
    srv_conn *next;
};

/* Listens (cfg->listen, loopback only without a token), opens the epoll
 * set with the listening socket, the signal pipe and the verification pipe
 * (server/upload.h makes it first), installs the SIGINT and SIGTERM
 * handlers, and writes cfg->port_file. */
pt_status srv_loop_open(srv_server *s, pt_error *err);

/* Frees every connection and closes what srv_loop_open opened. */
void srv_loop_close(srv_server *s);

/* The signal that stopped the loop (SIGINT, SIGTERM), 0 while none has. */
int srv_loop_stopped(void);

/* Waits up to timeout_ms for events and serves them: accepts, reads and
 * dispatches frames, flushes output, completes verifications. */
void srv_loop_poll(srv_server *s, int timeout_ms);

/* Handshake and stalled-frame timeouts. */
void srv_loop_timers(srv_server *s, uint64_t now);

/* Sends what each open connection has queued (before a slow disk sync). */
void srv_loop_flush_all(srv_server *s);

/* Flushes, processes input left by backpressure, frees the connections
 * closed since the last sweep and sets each one's epoll interest. */
void srv_loop_sweep(srv_server *s);

/* 1 while c's unsent output is under SRV_OUT_HIGH. */
int srv_conn_has_room(const srv_conn *c);

/* Sets c's epoll interest from its output and closing state. */
void srv_conn_update_events(srv_server *s, srv_conn *c);

/* Logs, sends ERROR(code, text) and closes c once that is flushed. */
void srv_conn_send_error(srv_server *s, srv_conn *c, uint16_t code, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));

/* The end of sending one message that a peer must get (a task, a chunk, a
 * list): st is proto_frame_begin's status, then proto_frame_finish's. Returns
 * 1 when the message is queued in c's output; otherwise c is sent ERROR
 * "output buffer full" and closed (srv_conn_send_error), and it returns 0. */
int srv_conn_queued(srv_server *s, srv_conn *c, pt_status st);

/* Closes c once its output is flushed (or the grace time ends). */
void srv_conn_close_soon(srv_server *s, srv_conn *c);

/* An ERROR from the peer (who: "client" or "worker"): logged, then closed. */
void srv_conn_peer_error(srv_server *s, srv_conn *c, const proto_frame *f, const char *who);

/* The open connection with this id, NULL when there is none. */
srv_conn *srv_conn_find(srv_server *s, uint64_t id);

#endif
