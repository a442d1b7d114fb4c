#define _GNU_SOURCE /* epoll, accept4, pipe2 */
#include "server/net/loop_impl.h"

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

/* ---- limits on peers: slots, memory, rates (loop.h) ---- */

/* Logs the refusals of each reason counted and not logged in its window,
 * once the window is over (or at once with all: at exit), and starts a new
 * window for the reasons it logged. */
void loop_refusals_flush(srv_server *s, uint64_t now, int all)
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
void loop_note_refusal(srv_server *s, int why, const char *host, const char *detail)
{
    refusal_log *l = &s->guard->refused[why];
    uint64_t now = pt_now_ms();
    if (now - l->t_window >= REFUSAL_LOG_MS) {
        loop_refusals_flush(s, now, 0);
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
 * rate-limited log line (loop_note_refusal), closed once that is flushed. */
void loop_conn_refuse(srv_server *s, srv_conn *c, uint16_t code, int why, const char *text)
{
    proto_error_msg m;
    m.code = code;
    snprintf(m.text, sizeof m.text, "%s", text);
    loop_note_refusal(s, why, c->host, text);
    loop_send_error_msg(s, c, &m);
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
 * push anyone out of a handshake slot (loop_take_oldest_handshake). */
int loop_accept_refusal(const srv_server *s, const uint8_t addr[16])
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
void loop_handshake_leave(srv_server *s, srv_conn *c)
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
int loop_take_oldest_handshake(srv_server *s)
{
    struct srv_guard *g = s->guard;
    srv_conn *old = NULL;
    for (uint32_t i = 0; i < g->nhs; i++)
        if (!old || g->hs[i]->t_connect < old->t_connect)
            old = g->hs[i];
    if (!old)
        return 0;
    loop_handshake_leave(s, old);
    loop_conn_refuse(s, old, PROTO_E_LIMIT, REFUSE_EVICTED,
                     "the handshake took too long while others waited; connect again");
    return 1;
}

/* Checks a frame c sends in the handshake before it is dispatched: an AUTH
 * is refused while the authenticated peers fill their slots (so the
 * handshake slots stay free for the next peer). Returns 1 to dispatch. */
int loop_handshake_admits(srv_server *s, srv_conn *c, const proto_frame *f)
{
    const struct srv_guard *g = s->guard;
    if (c->state != SRV_C_AUTH || f->type != PROTO_MSG_AUTH)
        return 1;
    if (s->nconns - g->nhs < g->max_conns - g->lim.max_handshakes)
        return 1;
    loop_conn_refuse(s, c, PROTO_E_LIMIT, REFUSE_AUTHED,
                     "too many peers connected; try again later");
    return 0;
}

/* Records that c's input buffer went from before bytes to its capacity now. */
void loop_in_account(srv_server *s, const srv_conn *c, size_t before)
{
    struct srv_guard *g = s->guard;
    g->in_held -= srv_in_counted(before);
    g->in_held += srv_in_counted(c->in.cap);
}

/* 1 when c's input buffer may grow to what its next frame needs. */
int loop_in_fits(const srv_server *s, const srv_conn *c)
{
    const struct srv_guard *g = s->guard;
    size_t need = proto_frame_reader_need(&c->in);
    if (need <= c->in.cap)
        return 1;
    uint64_t more = srv_in_counted(need) - srv_in_counted(c->in.cap);
    return g->in_held + more <= g->lim.max_input_mem;
}

/* Cuts c's input buffer back to SRV_IN_START once its big frame is consumed. */
void loop_in_shrink(srv_server *s, srv_conn *c)
{
    size_t before = c->in.cap;
    proto_frame_reader_shrink(&c->in);
    loop_in_account(s, c, before);
}

/* Stops reading c until loop_in_fits (backpressure on memory: TCP holds the
 * rest of its frame at the peer). */
void loop_conn_park(srv_server *s, srv_conn *c)
{
    if (!c->parked) {
        c->parked = 1;
        c->t_parked = pt_now_ms();
    }
    srv_conn_update_events(s, c);
}

/* An authenticated worker the loop reads, while srv_loop_hold holds them. */
int loop_held(const srv_server *s, const srv_conn *c)
{
    return s->log_held && c->state == SRV_C_READY && c->role == PROTO_ROLE_WORKER;
}

/* Reads c again; the time it was parked is not held against its frame. */
void loop_conn_unpark(srv_conn *c, uint64_t now)
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
void loop_conn_check_rate(srv_server *s, srv_conn *c, uint64_t now)
{
    const srv_peer_limits *l = &s->guard->lim;
    if (c->parked)
        return;
    size_t held = proto_frame_reader_pending(&c->in);
    double kib_s = l->min_rate / 1024.0;
    char why[256];
    if (srv_frame_too_slow(l, &c->in, c->t_frame, now, why, sizeof why)) {
        srv_conn_send_error(s, c, PROTO_E_LIMIT, "%s", why);
    } else if (c->uploading && c->t_upload && now - c->t_upload > srv_allowed_ms(l, c->up_total)) {
        srv_conn_send_error(s, c, PROTO_E_LIMIT,
                            "upload of %llu bytes too slow: %zu received in %.1f s (the minimum "
                            "is %.1f KiB/s after %.1f s)",
                            (unsigned long long)c->up_total, c->up_len,
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
pt_status loop_guard_open(srv_server *s, pt_error *err)
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

void loop_guard_close(srv_server *s)
{
    if (s->guard) {
        loop_refusals_flush(s, pt_now_ms(), 1);
        pt_free(s->guard->hs);
        pt_free(s->guard->act);
        pt_free(s->guard->ids);
        if (s->guard->spare_fd >= 0)
            close(s->guard->spare_fd);
    }
    pt_free(s->guard);
    s->guard = NULL;
}
