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

/* The session of c's role (an empty one for a role with none). */
const srv_session *loop_session_of(const srv_server *s, const srv_conn *c)
{
    static const srv_session none;
    if (c->ops)
        return c->ops; /* taken at WELCOME */
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
int loop_id_add(struct srv_guard *g, srv_conn *c)
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
void loop_id_remove(struct srv_guard *g, const srv_conn *c)
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

/* Lists c for the next sweep (once). */
void loop_conn_touch(srv_server *s, srv_conn *c)
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
    int pending = c->out.len > c->out_off;
    if (pending && c->out_blocked)
        ev |= EPOLLOUT;
    if (ev != c->events) {
        struct epoll_event e = {.events = ev, .data.ptr = &c->src};
        epoll_ctl(s->ep, EPOLL_CTL_MOD, c->fd, &e);
        c->events = ev;
    }
    /* Output queued: the sweep sends it this round. */
    if (pending)
        loop_conn_touch(s, c);
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
        loop_conn_touch(s, c);
        c->closing = 1;
        c->close_at = pt_now_ms() + CLOSE_GRACE_MS;
        if (c->state == SRV_C_READY && loop_session_of(s, c)->on_leave)
            loop_session_of(s, c)->on_leave(s, c, 0);
    }
}

/* Queues ERROR(m) for c and closes it once that is flushed; logs nothing. */
void loop_send_error_msg(srv_server *s, srv_conn *c, const proto_error_msg *m)
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
    loop_send_error_msg(s, c, &m);
}

void loop_conn_flush(srv_server *s, srv_conn *c)
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
            } else {
                c->out_blocked = 1; /* EPOLLOUT says when it takes more */
            }
            break;
        }
        c->out_off += (size_t)w;
        s->bytes_out += (uint64_t)w;
    }
    if (c->out_off == c->out.len) {
        c->out_blocked = 0;
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

/* The signal pipe is readable: a signal came (srv_signal_stopped says
 * which), or the dashboard woke the loop. */
static void drain_signals(srv_server *s, void *ctx, uint32_t events)
{
    (void)ctx;
    (void)events;
    char buf[16];
    while (read(s->sigpipe[0], buf, sizeof buf) > 0) {
    }
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

void srv_loop_flush_all(srv_server *s)
{
    /* Queued output is listed (srv_conn_update_events); a list that lost
     * one is not trusted. */
    struct srv_guard *g = s->guard;
    if (g->act_lost) {
        for (srv_conn *c = s->conns; c; c = c->next)
            if (c->out.len > c->out_off && !c->closing)
                loop_conn_flush(s, c);
        return;
    }
    for (uint32_t i = 0; i < g->nact; i++) {
        srv_conn *c = g->act[i];
        if (c->out.len > c->out_off && !c->closing)
            loop_conn_flush(s, c);
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
