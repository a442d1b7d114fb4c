/*
 * loop_impl.h - the inside of the event loop (server/net/loop.h), shared by
 * the files it is cut into by concern: loop.c (the registry of descriptors,
 * connections, reading, writing, the round's sweep), guard.c (the limits on
 * peers: refusals, slots, memory, rates, accepting) and handshake.c (HELLO,
 * AUTH, WELCOME). No other file includes it.
 *
 * Threads: as loop.h: the event-loop thread only.
 */
#ifndef PT_SERVER_NET_LOOP_IMPL_H
#define PT_SERVER_NET_LOOP_IMPL_H

#include <stdatomic.h>
#include <stdint.h>

#include "server/net/authlimit.h"
#include "server/net/loop.h"

#define ROLE_MAX_PAYLOAD                                                                           \
    (SRV_WORKER_MAX_PAYLOAD > SRV_CLIENT_MAX_PAYLOAD ? SRV_WORKER_MAX_PAYLOAD                      \
                                                     : SRV_CLIENT_MAX_PAYLOAD)
#define IN_MAX (PROTO_FRAME_OVERHEAD + ROLE_MAX_PAYLOAD) /* the largest frame after AUTH */
#define OUT_MAX (256u << 20) /* a peer that lets this much pile up is dropped */
#define CLOSE_GRACE_MS 1000  /* time to flush an ERROR before closing */
#define REFUSAL_LOG_MS 10000 /* the window of refusals logged one by one */
#define REFUSAL_BURST 5      /* lines per reason and window; then one with the count */
#define TIMERS_MS 50         /* srv_loop_timers walks the connections at most this often */
#define RQ_MAX 4096          /* an attached worker's frames waiting on its full output */

_Static_assert(ROLE_MAX_PAYLOAD <= PROTO_MAX_PAYLOAD, "a role's frames fit the protocol's cap");
_Static_assert(SRV_IN_START >= PROTO_FRAME_OVERHEAD + PROTO_MAX_PAYLOAD_PREAUTH,
               "a handshake frame fits the first buffer");

/* Why a connection was refused; one rate-limited log line each. */
enum {
    REFUSE_FULL,
    REFUSE_HANDSHAKES,
    REFUSE_ADDRESS,
    REFUSE_NETWORK,
    REFUSE_EVICTED,
    REFUSE_AUTHED,
    REFUSE_LATE,
    REFUSE_GARBAGE,
    REFUSE_N
};

typedef struct refusal_log {
    uint64_t t_window; /* its window began */
    uint32_t logged;   /* lines in it */
    uint32_t count;    /* refusals in it not logged yet */
    int many;          /* they came from more than one address */
    char host[48];     /* the address of the first of them */
} refusal_log;

/* The loop's limits on peers (loop.h) and what it counts against them. */
struct srv_guard {
    srv_peer_limits lim;      /* the configuration's, defaults filled in */
    srv_authlimit authlimit;  /* failed handshakes per address (server/net/authlimit.h) */
    _Atomic uint64_t in_held; /* srv_in_counted over the input buffers (the I/O
                               * threads count theirs here too) */
    srv_conn **hs;            /* the connections in the handshake: nhs of lim.max_handshakes */
    uint32_t nhs;
    uint32_t max_conns; /* connection slots: RLIMIT_NOFILE less SRV_FD_RESERVE */
    int spare_fd;       /* /dev/null, given up to accept and refuse a peer at EMFILE */
    uint64_t t_timers;  /* srv_loop_timers' last walk (ms) */
    /* The connections touched since the last sweep (conn_touch), in the
     * growable act, and whether one could not be listed (no memory): the
     * next sweep then walks them all. */
    srv_conn **act;
    uint32_t nact, act_cap;
    int act_lost;
    uint64_t t_sweep; /* the last sweep over every connection (ms) */
    uint64_t t_hand;  /* srv_loop_each_for_hand_out's last walk over every one */
    int hand_waiting; /* its last call left a worker waiting on a dry queue */
    /* Every connection by its id: open addressing with linear probing,
     * ids_cap a power of two at least twice ids_n, so srv_conn_find does
     * not walk the connections (it is asked once per result). */
    srv_conn **ids;
    uint32_t ids_n, ids_cap;
    refusal_log refused[REFUSE_N];
};

/* The descriptors added by their owners (srv_loop_add_fd) and the role
 * sessions (srv_loop_set_session). */
#define SRV_LOOP_SOURCES 8
struct srv_loop_reg {
    srv_loop_source src[SRV_LOOP_SOURCES];
    uint32_t n;
    srv_loop_source *io;           /* the I/O threads' items (paused by srv_loop_hold) */
    const srv_session *session[3]; /* by PROTO_ROLE_* */
};

void loop_on_hello(srv_server *s, srv_conn *c, const proto_frame *f);

void loop_on_auth(srv_server *s, srv_conn *c, const proto_frame *f);

/* Cuts c's input buffer back to SRV_IN_START once its big frame is consumed. */
void loop_in_shrink(srv_server *s, srv_conn *c);

/* 1 when c's input buffer may grow to what its next frame needs. */
int loop_in_fits(const srv_server *s, const srv_conn *c);

/* Adds c to the table by id; -1 without memory. */
int loop_id_add(struct srv_guard *g, srv_conn *c);

/* An authenticated worker the loop reads, while srv_loop_hold holds them. */
int loop_held(const srv_server *s, const srv_conn *c);

/* Checks a frame c sends in the handshake before it is dispatched: an AUTH
 * is refused while the authenticated peers fill their slots (so the
 * handshake slots stay free for the next peer). Returns 1 to dispatch. */
int loop_handshake_admits(srv_server *s, srv_conn *c, const proto_frame *f);

/* Fills the defaults of the limits and checks them. */
pt_status loop_guard_open(srv_server *s, pt_error *err);

void loop_guard_close(srv_server *s);

/* Reads c again; the time it was parked is not held against its frame. */
void loop_conn_unpark(srv_conn *c, uint64_t now);

/* Stops reading c until loop_in_fits (backpressure on memory: TCP holds the
 * rest of its frame at the peer). */
void loop_conn_park(srv_server *s, srv_conn *c);

/* A connection's descriptor is ready (its srv_loop_source's function). */
void loop_conn_event(srv_server *s, void *ctx, uint32_t events);

/* The rate rule (loop.h): closes c, logging why, when its frame in
 * progress or its upload is too slow or stalled. A parked peer is not
 * judged: the loop is the one not reading it. */
void loop_conn_check_rate(srv_server *s, srv_conn *c, uint64_t now);

void loop_accept_all(srv_server *s);

/* The session of c's role (an empty one for a role with none). */
const srv_session *loop_session_of(const srv_server *s, const srv_conn *c);

/* Queues ERROR(m) for c and closes it once that is flushed; logs nothing. */
void loop_send_error_msg(srv_server *s, srv_conn *c, const proto_error_msg *m);

/* Logs the refusals of each reason counted and not logged in its window,
 * once the window is over (or at once with all: at exit), and starts a new
 * window for the reasons it logged. */
void loop_refusals_flush(srv_server *s, uint64_t now, int all);

/* Records that c's input buffer went from before bytes to its capacity now. */
void loop_in_account(srv_server *s, const srv_conn *c, size_t before);

/* Takes c out of the table, moving back the entries after it that its slot
 * kept from their own (linear probing's deletion, no tombstones). */
void loop_id_remove(struct srv_guard *g, const srv_conn *c);

/* c gives back its handshake slot (authenticated, or gone). */
void loop_handshake_leave(srv_server *s, srv_conn *c);

/* Refuses a connection already accepted: ERROR(text) to the peer, one
 * rate-limited log line (note_refusal), closed once that is flushed. */
void loop_conn_refuse(srv_server *s, srv_conn *c, uint16_t code, int why, const char *text);

void loop_conn_free(srv_server *s, srv_conn *c);

/* The payload cap of c's next frame: tighter until it has authenticated,
 * then the largest its role sends (loop.h). */
uint32_t loop_conn_cap(const srv_conn *c);

/* Every handshake slot is taken: closes the connection that has been in
 * its handshake longest, so the newcomer gets its slot. An honest peer
 * authenticates in a round trip; one that sits in the handshake is pushed
 * out by every newer connection. 0 when none could be closed. */
int loop_take_oldest_handshake(srv_server *s);

/* Which of accept's checks refuses a new connection from addr, or -1. The
 * per-address and per-network caps come first: a peer they refuse does not
 * push anyone out of a handshake slot (loop_take_oldest_handshake). */
int loop_accept_refusal(const srv_server *s, const uint8_t addr[16]);

/* Counts one refusal for why from host: the first REFUSAL_BURST of a
 * REFUSAL_LOG_MS window are logged one by one, with their detail; the rest
 * only counted, for refusals_flush's one line. A flood of connections thus
 * costs a few lines per reason every REFUSAL_LOG_MS, not a line each. */
void loop_note_refusal(srv_server *s, int why, const char *host, const char *detail);

/* Lists c for the next sweep (once). */
void loop_conn_touch(srv_server *s, srv_conn *c);

void loop_conn_flush(srv_server *s, srv_conn *c);

#endif
