#define _GNU_SOURCE /* epoll, accept4, pipe2 */
#include "server/net/loop.h"

#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <unistd.h>

#include <arpa/inet.h>
#include <netinet/in.h>

#include "common/base/alloc.h"
#include "common/base/net.h"
#include "common/base/text.h"
#include "server/net/io.h"

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
static const char *const refusal_why[REFUSE_N] = {
    "every connection slot is taken",
    "too many unauthenticated connections",
    "too many unauthenticated connections from that address",
    "too many unauthenticated connections from that network",
    "handshake slot taken by a newer connection (all were in use)",
    "too many authenticated peers",
    "handshake not finished in time",
    "bad frame before authentication",
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

static volatile sig_atomic_t g_stop;
static int g_sigpipe_w = -1;

/* The session of c's role (an empty one for a role with none). */
static const srv_session *session_of(const srv_server *s, const srv_conn *c)
{
    static const srv_session none;
    const srv_session *o = c->role < 3 ? s->reg->session[c->role] : NULL;
    return o ? o : &none;
}

int srv_conn_has_room(const srv_conn *c)
{
    return c->out.len - c->out_off < SRV_OUT_HIGH;
}

/* The slot where id is, or the empty one where it would go. */
static uint32_t id_slot(const struct srv_guard *g, uint64_t id)
{
    uint32_t mask = g->ids_cap - 1;
    uint32_t i = (uint32_t)((id * 0x9E3779B97F4A7C15ull) >> 32) & mask;
    while (g->ids[i] && g->ids[i]->id != id)
        i = (i + 1) & mask;
    return i;
}

/* Adds c to the table by id; -1 without memory. */
static int id_add(struct srv_guard *g, srv_conn *c)
{
    if (2 * (g->ids_n + 1) > g->ids_cap) {
        uint32_t cap = g->ids_cap ? 2 * g->ids_cap : 64;
        srv_conn **old = g->ids, **n = pt_calloc(cap, sizeof *n);
        if (!n)
            return -1;
        uint32_t old_cap = g->ids_cap;
        g->ids = n;
        g->ids_cap = cap;
        for (uint32_t i = 0; i < old_cap; i++)
            if (old[i])
                g->ids[id_slot(g, old[i]->id)] = old[i];
        pt_free(old);
    }
    g->ids[id_slot(g, c->id)] = c;
    g->ids_n++;
    return 0;
}

/* Takes c out of the table, moving back the entries after it that its slot
 * kept from their own (linear probing's deletion, no tombstones). */
static void id_remove(struct srv_guard *g, const srv_conn *c)
{
    if (!g->ids_cap)
        return;
    uint32_t mask = g->ids_cap - 1, i = id_slot(g, c->id);
    if (g->ids[i] != c)
        return;
    g->ids[i] = NULL;
    g->ids_n--;
    for (uint32_t j = (i + 1) & mask; g->ids[j]; j = (j + 1) & mask) {
        uint32_t home = (uint32_t)((g->ids[j]->id * 0x9E3779B97F4A7C15ull) >> 32) & mask;
        /* The entry at j stays unless i lies cyclically in [home, j). */
        if (((j - home) & mask) >= ((j - i) & mask)) {
            g->ids[i] = g->ids[j];
            g->ids[j] = NULL;
            i = j;
        }
    }
}

srv_conn *srv_conn_find(srv_server *s, uint64_t id)
{
    const struct srv_guard *g = s->guard;
    if (!g || !g->ids_cap)
        return NULL;
    srv_conn *c = g->ids[id_slot(g, id)];
    return c && !c->closing ? c : NULL;
}

static void on_signal(int sig)
{
    g_stop = sig;
    if (g_sigpipe_w >= 0) {
        int saved = errno;
        char c = 1;
        ssize_t r = write(g_sigpipe_w, &c, 1);
        (void)r;
        errno = saved;
    }
}

/* Lists c for the next sweep (once). */
static void conn_touch(srv_server *s, srv_conn *c)
{
    struct srv_guard *g = s->guard;
    if (c->active)
        return;
    if (g->nact == g->act_cap) {
        srv_conn **n = pt_grow_array(g->act, &g->act_cap, sizeof *n, 64);
        if (!n) {
            g->act_lost = 1;
            return;
        }
        g->act = n;
    }
    g->act[g->nact++] = c;
    c->active = 1;
}

void srv_conn_update_events(srv_server *s, srv_conn *c)
{
    uint32_t ev = 0;
    if (c->attached)
        ev |= EPOLLET; /* its thread reads; a hang-up is reported here once */
    else if (!c->closing && !c->parked && srv_conn_has_room(c))
        ev |= EPOLLIN;
    if (c->out.len > c->out_off)
        ev |= EPOLLOUT;
    if (ev != c->events) {
        struct epoll_event e = {.events = ev, .data.ptr = &c->src};
        epoll_ctl(s->ep, EPOLL_CTL_MOD, c->fd, &e);
        c->events = ev;
    }
    /* Output queued: the sweep sends it this round. */
    if (ev & EPOLLOUT)
        conn_touch(s, c);
}

int srv_conn_queued(srv_server *s, srv_conn *c, pt_status st)
{
    if (st == PT_OK)
        return 1;
    srv_conn_send_error(s, c, PROTO_E_LIMIT, "output buffer full");
    return 0;
}

void srv_conn_close_soon(srv_server *s, srv_conn *c)
{
    if (!c->closing) {
        conn_touch(s, c);
        c->closing = 1;
        c->close_at = pt_now_ms() + CLOSE_GRACE_MS;
        if (c->state == SRV_C_READY && session_of(s, c)->on_leave)
            session_of(s, c)->on_leave(s, c, 0);
    }
}

/* Queues ERROR(m) for c and closes it once that is flushed; logs nothing. */
static void send_error_msg(srv_server *s, srv_conn *c, const proto_error_msg *m)
{
    size_t mark;
    if (proto_frame_begin(&c->out, PROTO_MSG_ERROR, &mark, NULL) == PT_OK)
        proto_frame_finish(&c->out, mark, proto_msg_encode_error(&c->out, m, NULL), NULL);
    srv_conn_close_soon(s, c);
}

void srv_conn_send_error(srv_server *s, srv_conn *c, uint16_t code, const char *fmt, ...)
{
    proto_error_msg m;
    m.code = code;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(m.text, sizeof m.text, fmt, ap);
    va_end(ap);
    char text[PT_TEXT_ESCAPED_SIZE(PROTO_MAX_ERROR_TEXT)];
    srv_log("peer %s%s%s: %s; closing", c->peer, c->name[0] ? " " : "", c->shown,
            pt_text_shown(m.text, text, sizeof text));
    send_error_msg(s, c, &m);
}

/* ---- limits on peers: slots, memory, rates (loop.h) ---- */

/* Logs the refusals of each reason counted and not logged in its window,
 * once the window is over (or at once with all: at exit), and starts a new
 * window for the reasons it logged. */
static void refusals_flush(srv_server *s, uint64_t now, int all)
{
    for (int why = 0; why < REFUSE_N; why++) {
        refusal_log *l = &s->guard->refused[why];
        /* Saturated: a window opened after now (a later clock reading
         * passed in) is 0 s old, never 2^64 ms. */
        uint64_t age = now > l->t_window ? now - l->t_window : 0;
        if (l->count == 0 || (!all && age < REFUSAL_LOG_MS))
            continue;
        srv_log("refused %u more connection%s from %s%s in the last %.0f s: %s", l->count,
                l->count == 1 ? "" : "s", l->host, l->many ? " and other addresses" : "",
                (double)age / 1000.0, refusal_why[why]);
        l->count = 0;
        l->logged = 0;
        l->t_window = now;
    }
}

/* Counts one refusal for why from host: the first REFUSAL_BURST of a
 * REFUSAL_LOG_MS window are logged one by one, with their detail; the rest
 * only counted, for refusals_flush's one line. A flood of connections thus
 * costs a few lines per reason every REFUSAL_LOG_MS, not a line each. */
static void note_refusal(srv_server *s, int why, const char *host, const char *detail)
{
    refusal_log *l = &s->guard->refused[why];
    uint64_t now = pt_now_ms();
    if (now - l->t_window >= REFUSAL_LOG_MS) {
        refusals_flush(s, now, 0);
        l->logged = 0;
        l->t_window = now;
    }
    if (l->logged < REFUSAL_BURST) {
        char text[PT_TEXT_ESCAPED_SIZE(PROTO_MAX_ERROR_TEXT)];
        srv_log("refused a connection from %s: %s%s%s", host, refusal_why[why], detail ? ": " : "",
                detail ? pt_text_shown(detail, text, sizeof text) : "");
        l->logged++;
        return;
    }
    if (l->count == 0) {
        snprintf(l->host, sizeof l->host, "%s", host);
        l->many = 0;
    } else if (strcmp(l->host, host) != 0) {
        l->many = 1;
    }
    l->count++;
}

/* Refuses a connection already accepted: ERROR(text) to the peer, one
 * rate-limited log line (note_refusal), closed once that is flushed. */
static void conn_refuse(srv_server *s, srv_conn *c, uint16_t code, int why, const char *text)
{
    proto_error_msg m;
    m.code = code;
    snprintf(m.text, sizeof m.text, "%s", text);
    note_refusal(s, why, c->host, text);
    send_error_msg(s, c, &m);
}

/* The bytes of an address (IPv4 as ::ffff:a.b.c.d) that name its network:
 * an IPv4 /24, an IPv6 /64. */
static size_t network_bytes(const uint8_t addr[16])
{
    static const uint8_t v4[12] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0xff, 0xff};
    return memcmp(addr, v4, sizeof v4) == 0 ? 15 : 8;
}

/* Which of accept's checks refuses a new connection from addr, or -1. The
 * per-address and per-network caps come first: a peer they refuse does not
 * push anyone out of a handshake slot (take_oldest_handshake). */
static int accept_refusal(const srv_server *s, const uint8_t addr[16])
{
    const struct srv_guard *g = s->guard;
    if (s->nconns >= g->max_conns)
        return REFUSE_FULL;
    uint32_t same = 0, near = 0;
    size_t net = network_bytes(addr);
    for (uint32_t i = 0; i < g->nhs; i++) {
        same += memcmp(g->hs[i]->addr, addr, 16) == 0;
        near += memcmp(g->hs[i]->addr, addr, net) == 0;
    }
    if (same >= g->lim.max_handshakes_ip)
        return REFUSE_ADDRESS;
    if (near >= 2 * g->lim.max_handshakes_ip)
        return REFUSE_NETWORK;
    return g->nhs >= g->lim.max_handshakes ? REFUSE_HANDSHAKES : -1;
}

/* c gives back its handshake slot (authenticated, or gone). */
static void handshake_leave(srv_server *s, srv_conn *c)
{
    struct srv_guard *g = s->guard;
    if (!c->handshaking)
        return;
    c->handshaking = 0;
    for (uint32_t i = 0; i < g->nhs; i++) {
        if (g->hs[i] == c) {
            g->hs[i] = g->hs[--g->nhs];
            break;
        }
    }
}

/* Every handshake slot is taken: closes the connection that has been in
 * its handshake longest, so the newcomer gets its slot. An honest peer
 * authenticates in a round trip; one that sits in the handshake is pushed
 * out by every newer connection. 0 when none could be closed. */
static int take_oldest_handshake(srv_server *s)
{
    struct srv_guard *g = s->guard;
    srv_conn *old = NULL;
    for (uint32_t i = 0; i < g->nhs; i++)
        if (!old || g->hs[i]->t_connect < old->t_connect)
            old = g->hs[i];
    if (!old)
        return 0;
    handshake_leave(s, old);
    conn_refuse(s, old, PROTO_E_LIMIT, REFUSE_EVICTED,
                "the handshake took too long while others waited; connect again");
    return 1;
}

/* Checks a frame c sends in the handshake before it is dispatched: an AUTH
 * is refused while the authenticated peers fill their slots (so the
 * handshake slots stay free for the next peer). Returns 1 to dispatch. */
static int handshake_admits(srv_server *s, srv_conn *c, const proto_frame *f)
{
    const struct srv_guard *g = s->guard;
    if (c->state != SRV_C_AUTH || f->type != PROTO_MSG_AUTH)
        return 1;
    if (s->nconns - g->nhs < g->max_conns - g->lim.max_handshakes)
        return 1;
    conn_refuse(s, c, PROTO_E_LIMIT, REFUSE_AUTHED, "too many peers connected; try again later");
    return 0;
}

/* Records that c's input buffer went from before bytes to its capacity now. */
static void in_account(srv_server *s, const srv_conn *c, size_t before)
{
    struct srv_guard *g = s->guard;
    g->in_held -= srv_in_counted(before);
    g->in_held += srv_in_counted(c->in.cap);
}

/* 1 when c's input buffer may grow to what its next frame needs. */
static int in_fits(const srv_server *s, const srv_conn *c)
{
    const struct srv_guard *g = s->guard;
    size_t need = proto_frame_reader_need(&c->in);
    if (need <= c->in.cap)
        return 1;
    uint64_t more = srv_in_counted(need) - srv_in_counted(c->in.cap);
    return g->in_held + more <= g->lim.max_input_mem;
}

/* Cuts c's input buffer back to SRV_IN_START once its big frame is consumed. */
static void in_shrink(srv_server *s, srv_conn *c)
{
    size_t before = c->in.cap;
    proto_frame_reader_shrink(&c->in);
    in_account(s, c, before);
}

/* Stops reading c until in_fits (backpressure on memory: TCP holds the
 * rest of its frame at the peer). */
static void conn_park(srv_server *s, srv_conn *c)
{
    if (!c->parked) {
        c->parked = 1;
        c->t_parked = pt_now_ms();
    }
    srv_conn_update_events(s, c);
}

/* An authenticated worker the loop reads, while srv_loop_hold holds them. */
static int held(const srv_server *s, const srv_conn *c)
{
    return s->log_held && c->state == SRV_C_READY && c->role == PROTO_ROLE_WORKER;
}

/* Reads c again; the time it was parked is not held against its frame. */
static void conn_unpark(srv_conn *c, uint64_t now)
{
    if (!c->parked)
        return;
    c->parked = 0;
    uint64_t waited = now - c->t_parked;
    c->t_frame += waited;
    if (c->t_upload)
        c->t_upload += waited;
    c->t_progress = now;
}

/* The rate rule (loop.h): closes c, logging why, when its frame in
 * progress or its upload is too slow or stalled. A parked peer is not
 * judged: the loop is the one not reading it. */
static void conn_check_rate(srv_server *s, srv_conn *c, uint64_t now)
{
    const srv_peer_limits *l = &s->guard->lim;
    if (c->parked)
        return;
    size_t held = proto_frame_reader_pending(&c->in);
    double kib_s = l->min_rate / 1024.0;
    char why[256];
    if (srv_frame_too_slow(l, &c->in, c->t_frame, now, why, sizeof why)) {
        srv_conn_send_error(s, c, PROTO_E_LIMIT, "%s", why);
    } else if (c->uploading && c->t_upload &&
               now - c->t_upload > srv_allowed_ms(l, c->up.bundle_size)) {
        srv_conn_send_error(s, c, PROTO_E_LIMIT,
                            "upload of %llu bytes too slow: %zu received in %.1f s (the minimum "
                            "is %.1f KiB/s after %.1f s)",
                            (unsigned long long)c->up.bundle_size, c->up_len,
                            (now - c->t_upload) / 1000.0, kib_s, l->frame_grace_ms / 1000.0);
    } else if ((held > 0 || c->uploading) && now - c->t_progress > l->frame_grace_ms) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "%s stalled for %.1f s",
                            c->uploading ? "upload" : "partial frame",
                            (now - c->t_progress) / 1000.0);
    }
}

/* The connection slots the file-descriptor limit allows: the soft
 * RLIMIT_NOFILE is raised to the hard one first where the kernel lets it
 * (an unlimited hard limit: to fs.nr_open's usual 1,048,576, else kept),
 * then SRV_FD_RESERVE of it is kept for files. Logs the outcome; *cap 0
 * when the limit leaves no room. */
static void conns_from_nofile(const srv_server *s, uint32_t *cap)
{
    struct rlimit rl;
    *cap = 0;
    if (getrlimit(RLIMIT_NOFILE, &rl) != 0)
        return;
    rlim_t was = rl.rlim_cur;
    if (rl.rlim_cur != RLIM_INFINITY &&
        (rl.rlim_max == RLIM_INFINITY || rl.rlim_cur < rl.rlim_max)) {
        struct rlimit up = rl;
        up.rlim_cur = rl.rlim_max == RLIM_INFINITY ? (rlim_t)1 << 20 : rl.rlim_max;
        if (up.rlim_cur > rl.rlim_cur && setrlimit(RLIMIT_NOFILE, &up) == 0)
            rl.rlim_cur = up.rlim_cur;
    }
    uint64_t lim = rl.rlim_cur == RLIM_INFINITY ? UINT32_MAX : (uint64_t)rl.rlim_cur;
    uint64_t n = lim > SRV_FD_RESERVE ? lim - SRV_FD_RESERVE : 0;
    *cap = n > UINT32_MAX - 1 ? UINT32_MAX - 1 : (uint32_t)n;
    if (s->cfg->quiet)
        return;
    char from[64] = "";
    if (rl.rlim_cur != was)
        snprintf(from, sizeof from, ", raised from %llu", (unsigned long long)was);
    srv_log("connections: at most %u (file descriptor limit %llu%s, %u kept for files)", *cap,
            (unsigned long long)lim, from, SRV_FD_RESERVE);
}

/* Fills the defaults of the limits and checks them. */
static pt_status guard_open(srv_server *s, pt_error *err)
{
    struct srv_guard *g = pt_calloc(1, sizeof *g);
    if (!g)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    s->guard = g;
    g->spare_fd = -1;
    g->lim = s->cfg->limits;
    srv_peer_limits *l = &g->lim;
    if (!l->max_input_mem)
        l->max_input_mem = SRV_DEFAULT_MAX_INPUT_MEM;
    if (!l->max_handshakes)
        l->max_handshakes = SRV_DEFAULT_MAX_HANDSHAKES;
    if (!l->max_handshakes_ip)
        l->max_handshakes_ip = SRV_DEFAULT_MAX_HANDSHAKES_IP;
    if (!l->frame_grace_ms)
        l->frame_grace_ms = SRV_DEFAULT_FRAME_GRACE_MS;
    if (!l->min_rate)
        l->min_rate = SRV_DEFAULT_MIN_RATE;
    /* --local's workers all connect from loopback at once. */
    l->max_handshakes += s->cfg->local_workers;
    l->max_handshakes_ip += s->cfg->local_workers;
    /* A peer's largest frame must fit what may be held, or it would wait for ever. */
    if (l->max_input_mem < IN_MAX)
        return pt_error_set(err, PT_ERR_ARG,
                            "input memory limit of %llu bytes under one frame's %u",
                            (unsigned long long)l->max_input_mem, (unsigned)IN_MAX);
    conns_from_nofile(s, &g->max_conns);
    if (l->max_handshakes >= g->max_conns)
        return pt_error_set(err, PT_ERR_ARG,
                            "%u handshakes at once leave no slot of %u for peers (the file "
                            "descriptor limit less %u for files; raise it: ulimit -n)",
                            l->max_handshakes, g->max_conns, SRV_FD_RESERVE);
    g->spare_fd = open("/dev/null", O_RDONLY | O_CLOEXEC);
    g->hs = pt_calloc(l->max_handshakes, sizeof *g->hs);
    if (!g->hs)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    return PT_OK;
}

static void guard_close(srv_server *s)
{
    if (s->guard) {
        refusals_flush(s, pt_now_ms(), 1);
        pt_free(s->guard->hs);
        pt_free(s->guard->act);
        pt_free(s->guard->ids);
        if (s->guard->spare_fd >= 0)
            close(s->guard->spare_fd);
    }
    pt_free(s->guard);
    s->guard = NULL;
}

static void conn_free(srv_server *s, srv_conn *c)
{
    const srv_session *o = session_of(s, c);
    if (!c->closing && c->state == SRV_C_READY && o->on_leave)
        o->on_leave(s, c, 1);
    if (c->state == SRV_C_READY && c->role == PROTO_ROLE_WORKER && s->nworkers > 0)
        s->nworkers--;
    if (o->on_gone)
        o->on_gone(s, c);
    epoll_ctl(s->ep, EPOLL_CTL_DEL, c->fd, NULL);
    if (c->attached)
        srv_io_close(s->io, c->id, c->fd); /* its thread closes it, done reading */
    else
        close(c->fd);
    for (srv_io_item *it = c->rq, *nx; it; it = nx) {
        nx = it->next;
        srv_io_item_free(it);
    }
    handshake_leave(s, c);
    s->guard->in_held -= srv_in_counted(c->in.cap);
    proto_writer_fini(&c->out);
    proto_frame_reader_fini(&c->in);
    id_remove(s->guard, c);
    pt_free(c);
    s->nconns--;
}

static void conn_event(srv_server *s, void *ctx, uint32_t events);
static void io_deliver(srv_server *s);

/* The address of ss as text (host) and as 16 bytes, IPv4 as ::ffff:a.b.c.d;
 * returns the port. */
static uint16_t peer_address(const struct sockaddr_storage *ss, char *host, size_t n,
                             uint8_t addr[16])
{
    memset(addr, 0, 16);
    snprintf(host, n, "?");
    if (ss->ss_family == AF_INET) {
        const struct sockaddr_in *a = (const struct sockaddr_in *)ss;
        inet_ntop(AF_INET, &a->sin_addr, host, (socklen_t)n);
        addr[10] = addr[11] = 0xff;
        memcpy(addr + 12, &a->sin_addr, 4);
        return ntohs(a->sin_port);
    }
    if (ss->ss_family == AF_INET6) {
        const struct sockaddr_in6 *a = (const struct sockaddr_in6 *)ss;
        inet_ntop(AF_INET6, &a->sin6_addr, host, (socklen_t)n);
        memcpy(addr, &a->sin6_addr, 16);
        return ntohs(a->sin6_port);
    }
    return 0;
}

static void accept_all(srv_server *s)
{
    for (;;) {
        struct sockaddr_storage ss;
        socklen_t sl = sizeof ss;
        int fd = accept4(s->lfd, (struct sockaddr *)&ss, &sl, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (fd < 0 && (errno == EMFILE || errno == ENFILE) && s->guard->spare_fd >= 0) {
            /* Out of descriptors (files took more than the reserve): the
             * peer would wait in the backlog and wake epoll every round.
             * The spare descriptor lets it be accepted and closed. */
            close(s->guard->spare_fd);
            fd = accept4(s->lfd, (struct sockaddr *)&ss, &sl, SOCK_CLOEXEC);
            if (fd >= 0) {
                char host[48];
                uint8_t addr[16];
                peer_address(&ss, host, sizeof host, addr);
                close(fd);
                note_refusal(s, REFUSE_FULL, host, "out of file descriptors");
            }
            s->guard->spare_fd = open("/dev/null", O_RDONLY | O_CLOEXEC);
            if (fd >= 0)
                continue;
        }
        if (fd < 0)
            return;
        char host[48];
        uint8_t addr[16];
        uint16_t port = peer_address(&ss, host, sizeof host, addr);
        /* Refused before anything is allocated, and logged by
         * note_refusal's rule, not a line each. */
        int why = accept_refusal(s, addr);
        if (why == REFUSE_HANDSHAKES && take_oldest_handshake(s))
            why = -1;
        if (why >= 0) {
            close(fd);
            note_refusal(s, why, host, NULL);
            continue;
        }
        srv_conn *c = pt_calloc(1, sizeof *c);
        uint8_t *room_at;
        size_t room;
        if (c)
            proto_frame_reader_init(&c->in, SRV_IN_START, IN_MAX);
        /* The input buffer is taken now: a peer it cannot be had for is
         * refused at once rather than told later. */
        if (!c || proto_frame_reader_space(&c->in, &room_at, &room, NULL) != PT_OK) {
            if (c)
                pt_free(c);
            close(fd);
            continue;
        }
        c->fd = fd;
        c->id = ++s->next_conn_id;
        c->t_connect = c->t_progress = pt_now_ms();
        proto_writer_init(&c->out, OUT_MAX);
        snprintf(c->host, sizeof c->host, "%s", host);
        memcpy(c->addr, addr, sizeof c->addr);
        snprintf(c->peer, sizeof c->peer, "%s:%u", host, port);
        c->src = (srv_loop_source){conn_event, c, fd, 0};
        struct epoll_event e = {.events = EPOLLIN, .data.ptr = &c->src};
        if (id_add(s->guard, c) != 0 || epoll_ctl(s->ep, EPOLL_CTL_ADD, fd, &e) != 0) {
            id_remove(s->guard, c);
            proto_writer_fini(&c->out);
            proto_frame_reader_fini(&c->in);
            pt_free(c);
            close(fd);
            continue;
        }
        c->events = EPOLLIN;
        c->next = s->conns;
        s->conns = c;
        s->nconns++;
        c->handshaking = 1;
        s->guard->hs[s->guard->nhs++] = c;
    }
}

/* Sends ERROR(code, text) and closes c, without a log line: for refusals
 * that server/net/authlimit.h logs within its own limits. */
static void handshake_refuse(srv_server *s, srv_conn *c, uint16_t code, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
static void handshake_refuse(srv_server *s, srv_conn *c, uint16_t code, const char *fmt, ...)
{
    proto_error_msg m;
    m.code = code;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(m.text, sizeof m.text, fmt, ap);
    va_end(ap);
    size_t mark;
    if (proto_frame_begin(&c->out, PROTO_MSG_ERROR, &mark, NULL) == PT_OK)
        proto_frame_finish(&c->out, mark, proto_msg_encode_error(&c->out, &m, NULL), NULL);
    srv_conn_close_soon(s, c);
}

/* 1 (and c refused) while c's address is blocked for failed
 * authentications; nothing is computed for it. PROTO_E_LIMIT, not _AUTH: a
 * worker with the right token behind the same address retries later. */
static int handshake_blocked(srv_server *s, srv_conn *c)
{
    char addr[SRV_AUTHLIMIT_ADDR];
    srv_authlimit_addr(c->peer, addr);
    uint64_t ms = srv_authlimit_blocked(&s->authlimit, addr, pt_now_ms());
    if (ms == 0)
        return 0;
    handshake_refuse(s, c, PROTO_E_LIMIT,
                     "too many failed authentications from %s, retry in %llu s", addr,
                     (unsigned long long)((ms + 999) / 1000));
    return 1;
}

static void on_hello(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_hello h;
    pt_error err = {0};
    if (handshake_blocked(s, c))
        return;
    if (proto_msg_decode_hello(f->payload, f->len, &h, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad HELLO: %s", err.msg);
        return;
    }
    snprintf(c->name, sizeof c->name, "%s", h.name);
    pt_text_shown(c->name, c->shown, sizeof c->shown);
    if (h.version != PROTO_VERSION) {
        srv_conn_send_error(s, c, PROTO_E_VERSION,
                            "protocol version %u is not supported (this "
                            "coordinator speaks %u)",
                            h.version, PROTO_VERSION);
        return;
    }
    if (h.role == PROTO_ROLE_CLIENT && !s->mode->serves_clients) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL,
                            "this coordinator renders one scene and keeps "
                            "no queue (start ptserve with --state-dir for clients)");
        return;
    }
    if (h.role != PROTO_ROLE_WORKER && h.role != PROTO_ROLE_CLIENT) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "role %u is not served by this coordinator",
                            h.role);
        return;
    }
    /* A client's build does not touch the pixels; a worker's does. */
    if (h.role == PROTO_ROLE_WORKER && strcmp(h.build_id, proto_build_id()) != 0) {
        srv_conn_send_error(s, c, PROTO_E_BUILD,
                            "worker renderer build %s differs from the "
                            "coordinator's %s; mixed builds would break bit-identical merging",
                            h.build_id, proto_build_id());
        return;
    }
    c->role = h.role;
    if (session_of(s, c)->refused && session_of(s, c)->refused(s, c))
        return;
    c->threads = h.threads;
    proto_challenge ch;
    if (proto_auth_nonce(ch.nonce, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "cannot make a nonce: %s", err.msg);
        return;
    }
    memcpy(c->nonce, ch.nonce, sizeof c->nonce);
    size_t mark;
    if (proto_frame_begin(&c->out, PROTO_MSG_CHALLENGE, &mark, NULL) == PT_OK)
        proto_frame_finish(&c->out, mark, proto_msg_encode_challenge(&c->out, &ch, NULL), NULL);
    c->state = SRV_C_AUTH;
}

/* Which token a's MAC proves: the shared one (an admin), else a
 * --clients-file entry's (*ident its NAME). 1 with *key, *key_len set (the
 * token for WELCOME's proof), 0 when none. */
static int auth_match(srv_server *s, srv_conn *c, const proto_auth *a, const uint8_t **key,
                      size_t *key_len, const char **ident)
{
    *ident = NULL;
    if (proto_auth_verify(s->token, s->token_len, c->nonce, a->mac, NULL) == PT_OK) {
        *key = s->token;
        *key_len = s->token_len;
        return 1;
    }
    return s->clients && srv_clients_match(s->clients, c->nonce, a->mac, ident, key, key_len) >= 0;
}

static void on_auth(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_auth a;
    pt_error err = {0};
    if (proto_msg_decode_auth(f->payload, f->len, &a, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad AUTH: %s", err.msg);
        return;
    }
    /* Blocked since its HELLO (parallel handshakes from one address). */
    if (handshake_blocked(s, c))
        return;
    const uint8_t *key;
    size_t key_len;
    const char *ident;
    if (!auth_match(s, c, &a, &key, &key_len, &ident)) {
        char addr[SRV_AUTHLIMIT_ADDR];
        srv_authlimit_addr(c->peer, addr);
        srv_authlimit_failed(&s->authlimit, addr, c->shown, pt_now_ms());
        handshake_refuse(s, c, PROTO_E_AUTH, "authentication failed (wrong token)");
        return;
    }
    /* Workers get leases and scenes: only the shared token may join as one. */
    if (ident && c->role == PROTO_ROLE_WORKER) {
        srv_conn_send_error(s, c, PROTO_E_AUTH,
                            "the token of client %s cannot join as a worker; workers "
                            "use the shared token (--token-file)",
                            ident);
        return;
    }
    proto_welcome w;
    w.session_id = c->id;
    snprintf(w.build_id, sizeof w.build_id, "%s", proto_build_id());
    if (proto_auth_server_proof(key, key_len, c->nonce, a.nonce, w.proof, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "cannot prove the token: %s", err.msg);
        return;
    }
    size_t mark;
    if (proto_frame_begin(&c->out, PROTO_MSG_WELCOME, &mark, NULL) == PT_OK)
        proto_frame_finish(&c->out, mark, proto_msg_encode_welcome(&c->out, &w, NULL), NULL);
    c->state = SRV_C_READY;
    c->admin = ident == NULL;
    if (ident && strcmp(ident, c->name) != 0) {
        char id_shown[PT_TEXT_ESCAPED_SIZE(PROTO_MAX_NAME)];
        pt_text_shown(ident, id_shown, sizeof id_shown);
        if (!s->cfg->quiet)
            srv_log("client %s from %s authenticated as %s", c->shown, c->peer, id_shown);
        snprintf(c->name, sizeof c->name, "%s", ident);
        memcpy(c->shown, id_shown, sizeof c->shown);
    }
    if (c->role == PROTO_ROLE_WORKER) {
        s->nworkers++;
        if (!s->cfg->quiet) {
            srv_log("worker %s joined from %s (%u threads)", c->shown, c->peer, c->threads);
        }
    }
}

void srv_conn_peer_error(srv_server *s, srv_conn *c, const proto_frame *f, const char *who)
{
    proto_error_msg m;
    char text[PT_TEXT_ESCAPED_SIZE(PROTO_MAX_ERROR_TEXT)];
    if (proto_msg_decode_error(f->payload, f->len, &m, NULL) == PT_OK)
        srv_log("%s %s reports: %s", who, c->shown, pt_text_shown(m.text, text, sizeof text));
    srv_conn_close_soon(s, c);
}

static void dispatch(srv_server *s, srv_conn *c, const proto_frame *f)
{
    if (c->state == SRV_C_HELLO) {
        if (f->type == PROTO_MSG_HELLO)
            on_hello(s, c, f);
        else
            srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "expected HELLO, got %s",
                                proto_msg_type_name(f->type));
        return;
    }
    if (c->state == SRV_C_AUTH) {
        if (f->type == PROTO_MSG_AUTH)
            on_auth(s, c, f);
        else
            srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "expected AUTH, got %s",
                                proto_msg_type_name(f->type));
        return;
    }
    const srv_session *o = session_of(s, c);
    if (o->on_frame)
        o->on_frame(s, c, f);
    else
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "unexpected %s", proto_msg_type_name(f->type));
}

/* The payload cap of c's next frame: tighter until it has authenticated,
 * then the largest its role sends (loop.h). */
static uint32_t conn_cap(const srv_conn *c)
{
    if (c->state != SRV_C_READY)
        return PROTO_MAX_PAYLOAD_PREAUTH;
    return c->role == PROTO_ROLE_WORKER ? SRV_WORKER_MAX_PAYLOAD : SRV_CLIENT_MAX_PAYLOAD;
}

/* Hands a worker that has just authenticated to an I/O thread, with what
 * it has sent since; without memory for that the loop goes on reading it. */
static void conn_attach(srv_server *s, srv_conn *c)
{
    if (srv_io_attach(s->io, c->id, c->fd, &c->in, SRV_WORKER_MAX_PAYLOAD, NULL) != PT_OK)
        return;
    c->attached = 1;
    c->rq_tail = &c->rq;
    srv_conn_update_events(s, c);
}

/* Decodes and dispatches the whole frames buffered in c->in, while the peer's
 * output is under the high-water mark (backpressure). */
static void conn_process(srv_server *s, srv_conn *c)
{
    while (!c->closing && !c->attached && srv_conn_has_room(c)) {
        proto_frame f;
        pt_error err = {0};
        pt_status st = proto_frame_reader_next(&c->in, conn_cap(c), &f, &err);
        if (st == PT_AGAIN)
            break;
        if (st != PT_OK) {
            if (c->state == SRV_C_READY)
                srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "%s", err.msg);
            else
                conn_refuse(s, c, PROTO_E_PROTOCOL, REFUSE_GARBAGE, err.msg);
            break;
        }
        /* The next frame's clock starts as this one ends. */
        uint64_t now = pt_now_ms();
        c->t_frame = now;
        if (c->handshaking && !handshake_admits(s, c, &f))
            break;
        int was_uploading = c->uploading;
        dispatch(s, c, &f);
        if (c->handshaking && c->state == SRV_C_READY) {
            handshake_leave(s, c);
            if (s->io && c->role == PROTO_ROLE_WORKER && !c->closing)
                conn_attach(s, c);
        }
        if (c->uploading && !was_uploading)
            c->t_upload = now;
        else if (!c->uploading)
            c->t_upload = 0;
    }
}

static void conn_read(srv_server *s, srv_conn *c)
{
    for (;;) {
        /* The frames held go first, so the decoder has judged the header of
         * the next one against conn_cap before the reader grows to the
         * length it declares: a length over the cap is refused before
         * anything is waited for or allocated. */
        conn_process(s, c);
        if (c->closing || c->attached || !srv_conn_has_room(c))
            return;
        if (!in_fits(s, c) || held(s, c)) {
            conn_park(s, c);
            return;
        }
        uint8_t *p;
        size_t room;
        size_t before = c->in.cap;
        pt_status st = proto_frame_reader_space(&c->in, &p, &room, NULL);
        in_account(s, c, before);
        if (st == PT_ERR_NOMEM) {
            srv_conn_send_error(s, c, PROTO_E_LIMIT, "out of memory for a frame");
            return;
        }
        if (st != PT_OK) {
            srv_conn_send_error(s, c, PROTO_E_LIMIT, "frame larger than the input buffer");
            return;
        }
        ssize_t r = recv(c->fd, p, room, 0);
        if (r == 0 || (r < 0 && errno != EINTR && errno != EAGAIN && errno != EWOULDBLOCK)) {
            srv_conn_close_soon(s, c);
            c->close_at = 0;
            return;
        }
        if (r < 0) {
            if (errno == EINTR)
                continue;
            in_shrink(s, c);
            return;
        }
        uint64_t now = pt_now_ms();
        if (proto_frame_reader_pending(&c->in) == 0)
            c->t_frame = now;
        proto_frame_reader_commit(&c->in, (size_t)r);
        s->bytes_in += (uint64_t)r;
        c->t_progress = now;
    }
}

static void conn_flush(srv_server *s, srv_conn *c)
{
    while (c->out.len > c->out_off) {
        ssize_t w = send(c->fd, c->out.buf + c->out_off, c->out.len - c->out_off,
                         MSG_NOSIGNAL | MSG_DONTWAIT);
        if (w < 0) {
            if (errno == EINTR)
                continue;
            if (errno != EAGAIN && errno != EWOULDBLOCK) {
                srv_conn_close_soon(s, c);
                c->close_at = 0;
            }
            break;
        }
        c->out_off += (size_t)w;
        s->bytes_out += (uint64_t)w;
    }
    if (c->out_off == c->out.len) {
        proto_writer_reset(&c->out);
        c->out_off = 0;
    } else if (c->out_off > (1u << 20) && c->out_off > c->out.len / 2) {
        memmove(c->out.buf, c->out.buf + c->out_off, c->out.len - c->out_off);
        c->out.len -= c->out_off;
        c->out_off = 0;
    }
    if (c->closing && c->out.len == c->out_off)
        c->close_at = 0;
}

int srv_loop_stopped(void)
{
    return g_stop;
}

/* The signal pipe is readable: a signal came (g_stop says which). */
static void drain_signals(srv_server *s, void *ctx, uint32_t events)
{
    (void)ctx;
    (void)events;
    char buf[16];
    while (read(s->sigpipe[0], buf, sizeof buf) > 0) {
    }
}

/* The listening socket is readable. */
static void on_listener(srv_server *s, void *ctx, uint32_t events)
{
    (void)ctx;
    (void)events;
    accept_all(s);
}

/* The I/O threads have items. */
static void on_io(srv_server *s, void *ctx, uint32_t events)
{
    (void)ctx;
    (void)events;
    io_deliver(s);
}

pt_status srv_loop_init(srv_server *s, pt_error *err)
{
    s->reg = pt_calloc(1, sizeof *s->reg);
    if (!s->reg)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    s->ep = epoll_create1(EPOLL_CLOEXEC);
    if (s->ep < 0)
        return pt_error_errno(err, PT_ERR_IO, "epoll_create1");
    if (pipe2(s->sigpipe, O_NONBLOCK | O_CLOEXEC) != 0)
        return pt_error_errno(err, PT_ERR_IO, "pipe2");
    return srv_loop_add_fd(s, s->sigpipe[0], drain_signals, NULL, NULL, err);
}

pt_status srv_loop_add_fd(srv_server *s, int fd, srv_loop_fn fn, void *ctx, srv_loop_source **out,
                          pt_error *err)
{
    struct srv_loop_reg *r = s->reg;
    if (r->n == SRV_LOOP_SOURCES)
        return pt_error_set(err, PT_ERR_ARG, "the loop waits on at most %d descriptors",
                            SRV_LOOP_SOURCES);
    srv_loop_source *src = &r->src[r->n];
    *src = (srv_loop_source){fn, ctx, fd, 0};
    struct epoll_event e = {.events = EPOLLIN, .data.ptr = src};
    if (epoll_ctl(s->ep, EPOLL_CTL_ADD, fd, &e) != 0)
        return pt_error_errno(err, PT_ERR_IO, "epoll_ctl");
    r->n++;
    if (out)
        *out = src;
    return PT_OK;
}

void srv_loop_pause_fd(srv_server *s, srv_loop_source *src, int paused)
{
    if (!src || src->paused == paused)
        return;
    src->paused = paused;
    if (paused) {
        epoll_ctl(s->ep, EPOLL_CTL_DEL, src->fd, NULL);
    } else {
        struct epoll_event e = {.events = EPOLLIN, .data.ptr = src};
        epoll_ctl(s->ep, EPOLL_CTL_ADD, src->fd, &e);
    }
}

void srv_loop_set_session(srv_server *s, uint8_t role, const srv_session *ops)
{
    if (role < 3)
        s->reg->session[role] = ops;
}

pt_status srv_loop_open(srv_server *s, pt_error *err)
{
    const srv_config *cfg = s->cfg;
    pt_status st;
    char host[256];
    uint16_t port = cfg->local_workers ? 0 : 7878;
    snprintf(host, sizeof host, "127.0.0.1");
    if (cfg->listen && (st = pt_net_split(cfg->listen, host, sizeof host, &port, err)) != PT_OK)
        return st;
    if (!cfg->token_path && !pt_net_host_is_loopback(host)) {
        srv_log("no --token-file: listening on loopback only (127.0.0.1), not '%s'", host);
        snprintf(host, sizeof host, "127.0.0.1");
    }
    if ((st = guard_open(s, err)) != PT_OK)
        return st;
    if ((st = pt_net_listen(host, port, &s->lfd, &s->port, err)) != PT_OK)
        return st;
    if (cfg->port_file) {
        FILE *f = fopen(cfg->port_file, "w");
        if (!f || fprintf(f, "%u\n", s->port) < 0 || fclose(f) != 0)
            return pt_error_errno(err, PT_ERR_IO, "%s", cfg->port_file);
    }
    if (!cfg->quiet)
        srv_log("listening on %s:%u%s", host, s->port, cfg->token_path ? " (token required)" : "");
    if ((st = srv_loop_add_fd(s, s->lfd, on_listener, NULL, NULL, err)) != PT_OK)
        return st;
    if (cfg->io_threads) { /* a durable mode keeps a RESULT's frame for its log */
        const srv_session *w = s->reg->session[PROTO_ROLE_WORKER];
        if ((st = srv_io_new(cfg->io_threads, &s->guard->lim, &s->guard->in_held, s->mode->durable,
                             w ? w->check_result : NULL, &s->io, err)) != PT_OK)
            return st;
        if ((st = srv_loop_add_fd(s, srv_io_fd(s->io), on_io, NULL, &s->reg->io, err)) != PT_OK)
            return st;
    }
    g_sigpipe_w = s->sigpipe[1];
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
    return PT_OK;
}

void srv_loop_close(srv_server *s)
{
    while (s->conns) {
        srv_conn *c = s->conns;
        s->conns = c->next;
        conn_free(s, c);
    }
    srv_io_free(s->io); /* after the conns: it closes the descriptors they gave it */
    s->io = NULL;
    if (s->lfd >= 0)
        close(s->lfd);
    if (s->ep >= 0)
        close(s->ep);
    s->lfd = s->ep = -1;
    g_sigpipe_w = -1;
    if (s->sigpipe[0] >= 0) {
        close(s->sigpipe[0]);
        close(s->sigpipe[1]);
        s->sigpipe[0] = s->sigpipe[1] = -1;
    }
    guard_close(s);
    pt_free(s->reg);
    s->reg = NULL;
}

/* Serves one of an attached worker's items (server/net/io.h); frees it. */
static void item_run(srv_server *s, srv_conn *c, srv_io_item *it)
{
    if (it->kind == SRV_IO_EOF) {
        srv_conn_close_soon(s, c);
        c->close_at = 0;
    } else if (it->kind == SRV_IO_ERROR) {
        srv_conn_send_error(s, c, it->code, "%s", it->msg);
    } else {
        /* No clock: an attached peer's frame times are its thread's. */
        const srv_session *o = session_of(s, c);
        if (it->f.type == PROTO_MSG_RESULT && it->decoded && o->on_result)
            o->on_result(s, c, &it->f, &it->r, it->checked, it->frame ? &it->frame : NULL);
        else
            dispatch(s, c, &it->f);
    }
    srv_io_item_free(it);
}

/* Serves what c's items waiting in rq it has room for. */
static void rq_run(srv_server *s, srv_conn *c)
{
    while (c->rq && !c->closing && srv_conn_has_room(c)) {
        srv_io_item *it = c->rq;
        if (!(c->rq = it->next))
            c->rq_tail = &c->rq;
        c->nrq--;
        item_run(s, c, it);
    }
}

/* Serves the items the I/O threads have read, each connection's in order;
 * those of a peer whose output is full wait in its rq (its thread reads on:
 * a worker that sends on without reading its replies is closed at RQ_MAX). */
static void io_deliver(srv_server *s)
{
    uint64_t received;
    srv_io_item *it = srv_io_take(s->io, &received);
    s->bytes_in += received;
    while (it) {
        srv_io_item *next = it->next;
        it->next = NULL;
        srv_conn *c = srv_conn_find(s, it->conn); /* none: closed or closing */
        if (!c) {
            srv_io_item_free(it);
            it = next;
            continue;
        }
        conn_touch(s, c);
        if (c->rq || !srv_conn_has_room(c)) {
            if (c->nrq >= RQ_MAX) {
                srv_io_item_free(it);
                srv_conn_send_error(s, c, PROTO_E_LIMIT,
                                    "%u frames unanswered while it does not read its replies",
                                    c->nrq);
            } else {
                *c->rq_tail = it;
                c->rq_tail = &it->next;
                c->nrq++;
            }
        } else {
            item_run(s, c, it);
        }
        it = next;
    }
}

/* A connection's descriptor is ready (its srv_loop_source's function). */
static void conn_event(srv_server *s, void *ctx, uint32_t events)
{
    srv_conn *c = ctx;
    conn_touch(s, c);
    /* An attached peer's thread reads it, a hang-up included. A parked peer
     * is not read; one that hung up meanwhile can never finish its frame
     * (and would wake epoll every round). */
    uint32_t in = c->attached ? 0 : events & (EPOLLIN | EPOLLHUP | EPOLLERR);
    if (c->parked && (in & (EPOLLHUP | EPOLLERR)) && !c->closing) {
        srv_conn_close_soon(s, c);
        c->close_at = 0;
    } else if (in) {
        conn_read(s, c);
    }
    if (events & EPOLLOUT)
        conn_flush(s, c);
}

void srv_loop_poll(srv_server *s, int timeout_ms)
{
    struct epoll_event evs[64];
    int n = epoll_wait(s->ep, evs, 64, timeout_ms);
    for (int i = 0; i < n; i++) {
        const srv_loop_source *src = evs[i].data.ptr;
        src->fn(s, src->ctx, evs[i].events);
    }
}

void srv_loop_timers(srv_server *s, uint64_t now)
{
    /* The walk over every connection runs every TIMERS_MS, not every
     * round: its deadlines are seconds long, and a farm's loop turns
     * thousands of rounds a second over thousands of connections. */
    if (now - s->guard->t_timers < TIMERS_MS) {
        refusals_flush(s, now, 0);
        return;
    }
    s->guard->t_timers = now;
    for (srv_conn *c = s->conns; c; c = c->next) {
        if (c->closing)
            continue;
        if (c->state != SRV_C_READY && now - c->t_connect > s->cfg->handshake_ms) {
            char text[64];
            snprintf(text, sizeof text, "handshake not finished in %.1f s",
                     s->cfg->handshake_ms / 1000.0);
            conn_refuse(s, c, PROTO_E_PROTOCOL, REFUSE_LATE, text);
        } else {
            conn_check_rate(s, c, now);
        }
    }
    refusals_flush(s, now, 0);
}

void srv_loop_hold(srv_server *s, uint64_t unsynced)
{
    uint64_t cap = s->cfg->max_log_mem;
    s->counters.log_unsynced = unsynced;
    int hold = s->log_held ? unsynced > cap / 2 : unsynced > cap;
    if (hold == s->log_held)
        return;
    uint64_t now = pt_now_ms();
    s->log_held = hold;
    if (hold) {
        s->t_held = now;
        s->counters.log_holds++;
        srv_loop_pause_fd(s, s->reg->io, 1);
        srv_log("results log: %.1f MiB of results not on disk yet (--max-log-mb %llu); "
                "workers are not read until the disk catches up",
                unsynced / 1048576.0, (unsigned long long)(cap >> 20));
        return;
    }
    s->t_released = now;
    /* Items still waiting wake the loop again at once (the eventfd was
     * left unread); parked workers are read again by the sweep, which looks
     * at every parked peer each round. */
    srv_loop_pause_fd(s, s->reg->io, 0);
    srv_log("results log: the disk caught up after %.1f s; workers are read again",
            (now - s->t_held) / 1000.0);
}

void srv_loop_flush_all(srv_server *s)
{
    /* Queued output is listed (srv_conn_update_events); a list that lost
     * one is not trusted. */
    struct srv_guard *g = s->guard;
    if (g->act_lost) {
        for (srv_conn *c = s->conns; c; c = c->next)
            if (c->out.len > c->out_off && !c->closing)
                conn_flush(s, c);
        return;
    }
    for (uint32_t i = 0; i < g->nact; i++) {
        srv_conn *c = g->act[i];
        if (c->out.len > c->out_off && !c->closing)
            conn_flush(s, c);
    }
}

void srv_loop_each_for_hand_out(srv_server *s, int (*fn)(srv_server *, srv_conn *, void *),
                                void *ctx)
{
    struct srv_guard *g = s->guard;
    uint64_t now = pt_now_ms();
    int waiting = 0;
    if (g->hand_waiting || g->act_lost || now - g->t_hand >= TIMERS_MS) {
        g->t_hand = now;
        for (srv_conn *c = s->conns; c; c = c->next)
            waiting |= fn(s, c, ctx);
    } else {
        /* By index: fn may list more (its own output, other peers'). */
        for (uint32_t i = 0; i < g->nact; i++)
            waiting |= fn(s, g->act[i], ctx);
    }
    g->hand_waiting = waiting;
}

/* The sweep of one connection; 1 when c is to be freed now. */
static int sweep_one(srv_server *s, srv_conn *c, uint64_t now)
{
    if (c->out.len > c->out_off)
        conn_flush(s, c);
    if (c->rq && !c->closing && !held(s, c)) { /* held: the walk every 50 ms resumes it */
        rq_run(s, c);
        conn_touch(s, c); /* what it asked for is handed out next round */
    }
    if (proto_frame_reader_pending(&c->in) > 0 && !c->closing) {
        conn_process(s, c);
        in_shrink(s, c);
        conn_touch(s, c); /* what it asked for is handed out next round */
    }
    if (c->closing && (c->close_at == 0 || now >= c->close_at))
        return 1;
    if (c->parked && in_fits(s, c) && !held(s, c))
        conn_unpark(c, now);
    srv_conn_update_events(s, c);
    return 0;
}

/* Takes c, about to be freed, off the touched list (another peer's frame
 * may have touched it since the list was taken). */
static void conn_unlist(srv_server *s, srv_conn *c)
{
    struct srv_guard *g = s->guard;
    if (!c->active)
        return;
    for (uint32_t k = 0; k < g->nact; k++)
        if (g->act[k] == c) {
            g->act[k] = g->act[--g->nact];
            break;
        }
    c->active = 0;
}

/* Takes the list of touched connections (each one's mark cleared), so that
 * what the sweep touches goes on a new one; the caller frees it. */
static srv_conn **take_touched(srv_server *s, uint32_t *n)
{
    struct srv_guard *g = s->guard;
    srv_conn **list = g->act;
    *n = g->nact;
    for (uint32_t i = 0; i < *n; i++)
        list[i]->active = 0;
    g->act = NULL;
    g->nact = g->act_cap = 0;
    return list;
}

void srv_loop_sweep(srv_server *s)
{
    struct srv_guard *g = s->guard;
    uint64_t now = pt_now_ms();
    uint32_t n;
    srv_conn **list = take_touched(s, &n);
    if (g->act_lost || now - g->t_sweep >= TIMERS_MS) {
        /* Every connection: grace times end, parked peers may fit again,
         * and nothing left unlisted waits longer than this. */
        g->act_lost = 0;
        g->t_sweep = now;
        pt_free(list);
        for (srv_conn **pc = &s->conns; *pc;) {
            srv_conn *c = *pc;
            if (sweep_one(s, c, now)) {
                *pc = c->next;
                conn_unlist(s, c);
                conn_free(s, c);
                continue;
            }
            if (c->closing || c->parked)
                conn_touch(s, c);
            pc = &c->next;
        }
        return;
    }
    for (uint32_t i = 0; i < n; i++) {
        srv_conn *c = list[i];
        if (!sweep_one(s, c, now)) {
            /* Not done: looked at again next round, not only every 50 ms. */
            if (c->closing || c->parked)
                conn_touch(s, c);
            continue;
        }
        /* Frees are rare beside the rounds: the walk to unlink is fine. */
        srv_conn **pc = &s->conns;
        while (*pc != c)
            pc = &(*pc)->next;
        *pc = c->next;
        conn_unlist(s, c);
        conn_free(s, c);
    }
    pt_free(list);
}
