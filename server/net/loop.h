/*
 * loop.h - the event loop: non-blocking sockets under one epoll, and the
 * connections (workers and clients) it serves.
 *
 * Owns every srv_conn: its input (a proto_frame_reader of SRV_IN_START bytes,
 * grown only to the frame its header declares once the decoder has checked
 * that length against the cap: PROTO_MAX_PAYLOAD_PREAUTH before
 * authentication, then the role's SRV_WORKER_MAX_PAYLOAD or
 * SRV_CLIENT_MAX_PAYLOAD, and cut back to SRV_IN_START once that frame is
 * consumed), its output (a writer capped at OUT_MAX; a peer whose unsent
 * output passes OUT_HIGH is not read from, which is backpressure), the
 * handshake (HELLO, CHALLENGE, AUTH, WELCOME) and its timeout.
 *
 * Limits on peers (srv_peer_limits, server/serve.h; hostile peers are
 * stopped by these, honest ones only slowed):
 * - memory: input buffers grown past SRV_IN_START hold at most max_input_mem in
 *   all. A peer whose next frame would pass it is parked: not read (no
 *   EPOLLIN, TCP pushes back on it) until a frame ends or a peer goes, and
 *   not judged by the rate rule meanwhile. Total input memory is thus at
 *   most connections x SRV_IN_START + max_input_mem.
 * - slots: the file-descriptor limit (RLIMIT_NOFILE, its soft value raised
 *   to the hard one at srv_loop_open where allowed) less SRV_FD_RESERVE
 *   connections in all, logged at start; of them at most max_handshakes in
 *   the handshake, at most max_handshakes_ip of those from one address and
 *   twice that from one network (an IPv4 /24, an IPv6 /64), the rest
 *   authenticated. A connection past them is accepted and closed at once
 *   (so is one that meets EMFILE, through a spare descriptor), except that
 *   when only the handshake slots are full, the newcomer takes the slot of
 *   the oldest connection still in its handshake, which is closed: a peer
 *   that holds a slot without authenticating is thus pushed out by every
 *   newer one, and an honest handshake, one round trip long, is not. Refusals (and handshakes that
 * fail on a bad frame or time out) are logged one by one up to 5 per reason in 10 s, then as one
 * line with the count of the others.
 * - rate: a frame in progress must be whole within max(frame_grace,
 *   its size / min_rate) of its first byte, an upload within max(grace,
 *   bundle size / min_rate) of its SUBMIT, and nothing may stall for
 *   frame_grace; a peer that fails is sent ERROR and closed, with the
 *   reason logged.
 * The loop is a registry: the descriptors it waits on besides its
 * connections are added by their owners at setup (srv_loop_add_fd: the
 * upload checks' pipe, the results log's commits, the I/O threads), each
 * with the function it calls when it is ready, and a whole frame from a
 * ready peer goes to the session of its role (srv_session: the worker and
 * client handlers, server/api/workers.h and server/api/requests.h, installed by
 * srv_serve at setup), so the loop names none of the layers above it.
 * With I/O threads (server/net/io.h) a
 * worker is read by one of them from its AUTH on ("attached"): its frames
 * arrive as items, served in order as if read here, the limits above
 * applied by its thread, and its descriptor closed by that thread once the
 * loop frees the connection. A protocol error is answered with
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
#include "server/net/peerlimits.h"

#define SRV_OUT_HIGH (16u << 20) /* stop reading a peer whose unsent output passes this */
/* Connection slots: the file-descriptor limit less SRV_FD_RESERVE, of which
 * at most max_handshakes (srv_peer_limits, server/serve.h) are not yet
 * authenticated; the others are kept for authenticated peers, so a flood of
 * handshakes never locks a worker out. The reserve is for the process's
 * own descriptors: standard streams, the listener, epoll and its pipes, the
 * state folder (lock, queue file, a results log per running job,
 * checkpoints), images being written, uploads being verified and the
 * dashboard's connections (at most 64). */
#define SRV_FD_RESERVE 128u

/* The largest payload each role sends once authenticated (the frame cap):
 * a worker's RESULT of a PT_TILE_MAX x PT_TILE_MAX tile, 69 bytes of header
 * and at most 72 per pixel (4,718,661 bytes; HEARTBEAT, WORK_REQUEST, SCENE_GET and
 * ERROR are smaller), and a guided task's statistics, up to 2^18 entries of 12
 * bytes (a pass's distribution is far smaller; RESULT in protocol/msg.h); a
 * client's UPLOAD chunk, 52 bytes of header and PROTO_MAX_SCENE_CHUNK of data
 * (SUBMIT and the rest are smaller). */
#define SRV_WORKER_MAX_PAYLOAD                                                                     \
    (PROTO_RESULT_HEADER_SIZE + PROTO_RESULT_WIDE_PIXEL_SIZE * PROTO_MAX_TILE_PIXELS + 16u +       \
     12u * (1u << 18))
#define SRV_CLIENT_MAX_PAYLOAD (52u + PROTO_MAX_SCENE_CHUNK)

/* Defaults of srv_peer_limits (server/serve.h): a field left 0 takes these. */
#define SRV_DEFAULT_MAX_INPUT_MEM (512ull << 20)
#define SRV_DEFAULT_MAX_HANDSHAKES 64u
#define SRV_DEFAULT_MAX_HANDSHAKES_IP 8u
#define SRV_DEFAULT_FRAME_GRACE_MS 30000u
#define SRV_DEFAULT_MIN_RATE (16u << 10)

enum { SRV_C_HELLO, SRV_C_AUTH, SRV_C_READY };

/* Called on the loop thread when the descriptor it was added with is
 * ready; events: epoll's. */
typedef void (*srv_loop_fn)(srv_server *s, void *ctx, uint32_t events);

/* One descriptor the loop waits on (a connection's, or one srv_loop_add_fd
 * added): what its readiness calls. */
typedef struct srv_loop_source {
    srv_loop_fn fn;
    void *ctx;
    int fd;
    int paused; /* not waited on (srv_loop_pause_fd) */
} srv_loop_source;

/* What a role's peers are served by once they are ready (installed by
 * srv_loop_set_session before srv_loop_open; each may be NULL). The
 * connection takes its role's session at WELCOME (srv_conn.ops), with the
 * session's own state of it (srv_conn.session): the loop knows the
 * transport, the session what the peer asked and was given. */
typedef struct srv_session {
    /* At WELCOME: the session's state of c, kept in c->session until
     * on_gone frees it; NULL when memory is short (c is then refused). */
    void *(*open)(srv_server *s, srv_conn *c);
    /* A whole frame from a ready peer. */
    void (*on_frame)(srv_server *s, srv_conn *c, const proto_frame *f);
    /* A RESULT an I/O thread decoded into r (checked: check_result passed
     * there; own: the frame's buffer, which the callee may take). */
    void (*on_result)(srv_server *s, srv_conn *c, const proto_frame *f, proto_result *r,
                      int checked, uint8_t **own);
    /* Run on the I/O threads over a decoded RESULT: 1 when its pixels are
     * plausible (pure: any thread). */
    int (*check_result)(const proto_result *r);
    /* At HELLO, the name and role set: 1 when c is refused (and was sent why). */
    int (*refused)(srv_server *s, srv_conn *c);
    /* c leaves: it is closing (report 0), or is freed without having closed
     * (report 1: say what it left). */
    void (*on_leave)(srv_server *s, srv_conn *c, int report);
    /* c is being freed (it frees c->session). */
    void (*on_gone)(srv_server *s, srv_conn *c);
} srv_session;

struct srv_conn {
    srv_loop_source src; /* its descriptor in the loop */
    int fd;
    uint64_t id;
    int state; /* SRV_C_* */
    uint8_t role;
    int closing;
    uint64_t close_at;
    proto_frame_reader in;
    proto_writer out;
    size_t out_off;
    /* The last send left output unsent (the socket's buffer was full): only
     * then is EPOLLOUT waited for. Output is otherwise sent by the round's
     * sweep, with no change of epoll interest per message. */
    int out_blocked;
    uint8_t nonce[PROTO_NONCE_SIZE];
    /* The HELLO name until WELCOME; from then on the peer's identity: the
     * NAME of the --clients-file token it proved, else the HELLO name. */
    char name[PROTO_MAX_NAME + 1];
    char shown[PT_TEXT_ESCAPED_SIZE(PROTO_MAX_NAME)]; /* name escaped for logs, set with it */
    char peer[64];
    char host[48];    /* the peer's address alone, for refusals */
    uint8_t addr[16]; /* the same as bytes (IPv4 as ::ffff:a.b.c.d): per-address caps */
    int handshaking;  /* holds one of the max_handshakes slots */
    /* Read by an I/O thread (server/net/io.h) since it authenticated as a
     * worker: in is then empty and unused; its frames arrive as items,
     * which wait in rq while its output is over SRV_OUT_HIGH. */
    int attached;
    struct srv_io_item *rq, **rq_tail;
    uint32_t nrq;
    int active; /* on the loop's list for this round's sweep (loop.c) */
    int parked; /* not read: its next frame waits for input memory */
    uint64_t t_parked;
    uint64_t t_frame;  /* the first byte of the frame in progress arrived */
    uint64_t t_upload; /* its upload (c->uploading) began */
    uint16_t threads;  /* HELLO's */
    uint32_t caps;     /* HELLO's capability bits (PROTO_CAP_*) */
    int admin;         /* proved the shared token (every peer, without --clients-file) */
    uint64_t t_connect, t_progress;
    uint32_t events;
    /* An upload in progress as its client's session declares it, for the
     * rate rule (guard.c): its size, the bytes received so far. */
    int uploading;
    uint64_t up_total;
    size_t up_len;
    /* From WELCOME: its role's session and that session's state of it
     * (server/api/workers.h, server/api/client.h); NULL before. */
    const srv_session *ops;
    void *session;
    srv_conn *next;
};

/* Opens the epoll set and the signal pipe in it, so the owners of other
 * descriptors can add them (srv_loop_add_fd) before the loop listens. */
pt_status srv_loop_init(srv_server *s, pt_error *err);

/* Waits on fd (readable) from now on: fn(s, ctx, events) runs when it is
 * ready. *out (may be NULL) receives its source, for srv_loop_pause_fd.
 * At most SRV_LOOP_SOURCES of them. */
pt_status srv_loop_add_fd(srv_server *s, int fd, srv_loop_fn fn, void *ctx, srv_loop_source **out,
                          pt_error *err);

/* Stops waiting on src's descriptor (paused 1) or waits on it again (0). */
void srv_loop_pause_fd(srv_server *s, srv_loop_source *src, int paused);

/* The session that serves ready peers of role (PROTO_ROLE_*). */
void srv_loop_set_session(srv_server *s, uint8_t role, const srv_session *ops);

/* Listens (cfg->listen, loopback only without a token), adds the listening
 * socket (and the I/O threads, cfg->io_threads, reading for the worker
 * session) to the epoll set, installs the SIGINT and SIGTERM handlers, and
 * writes cfg->port_file. */
pt_status srv_loop_open(srv_server *s, pt_error *err);

/* Frees every connection and closes what srv_loop_open opened. */
void srv_loop_close(srv_server *s);

/* The signal that stopped the loop (SIGINT, SIGTERM), 0 while none has. */
int srv_loop_stopped(void);

/* Waits up to timeout_ms for events and serves them: accepts, reads and
 * dispatches frames, flushes output, completes verifications. */
void srv_loop_poll(srv_server *s, int timeout_ms);

/* Handshake, stall and rate timeouts (judged at most every 50 ms: the walk
 * over every connection is not repeated each round); the refusals not yet
 * logged. */
void srv_loop_timers(srv_server *s, uint64_t now);

/* Backpressure on the results log (queue mode): once more than
 * cfg->max_log_mem of results wait for the disk (backlog: the mode's count
 * of their records and their decoded pixels, srv_mode.backlog: results come
 * faster than the disk takes them), workers are not read (the
 * I/O threads' items are not taken, so the threads stop reading at
 * SRV_IO_QUEUE_BYTES; a worker the loop reads is parked) until the commits
 * bring it under half of that. TCP then holds the workers' frames, and they
 * block on their sends: a farm goes at its disk's pace instead of the
 * coordinator's memory growing without bound. Clients and handshakes are
 * served as before, and leases do not expire meanwhile, nor for a lease
 * timeout after (the workers' heartbeats wait behind the hold). The cap may
 * be passed by what one round takes in. Called once per round. */
void srv_loop_hold(srv_server *s, uint64_t backlog);

/* Sends what the connections touched this round have queued (before a slow
 * disk sync). */
void srv_loop_flush_all(srv_server *s);

/* Flushes, processes input left by backpressure, frees the connections
 * closed since the last sweep, reads again from parked peers whose frame
 * now fits and sets each one's epoll interest. Each round it visits only
 * the connections touched since the last sweep (an event, queued output, a
 * close, a park), and all of them every 50 ms, so a round's cost follows
 * what happened in it, not how many peers are connected. */
void srv_loop_sweep(srv_server *s);

/* Calls fn(s, c, ctx) for the connections a round's hand-out of tasks
 * (server/sched/queue.c) must look at: those touched since the last sweep (a
 * WORK_REQUEST, a RESULT, output drained), or all of them every 50 ms and
 * while some worker waits on a queue that had nothing for it (fn returned 1
 * for it in the last call). Tasks reach waiting workers as before; a
 * busy farm's round looks only at the peers it heard from. */
void srv_loop_each_for_hand_out(srv_server *s, int (*fn)(srv_server *, srv_conn *, void *),
                                void *ctx);

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
