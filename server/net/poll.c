#define _GNU_SOURCE /* epoll, accept4, pipe2 */
#include "server/net/loop_impl.h"

#include <errno.h>
#include <fcntl.h>
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
#include "server/net/signal.h"

static void io_deliver(srv_server *s);
static void conn_attach(srv_server *s, srv_conn *c);

int srv_loop_stopped(void)
{
    return srv_signal_stopped();
}

void loop_conn_free(srv_server *s, srv_conn *c)
{
    const srv_session *o = loop_session_of(s, c);
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
    loop_handshake_leave(s, c);
    s->guard->in_held -= srv_in_counted(c->in.cap);
    proto_writer_fini(&c->out);
    proto_frame_reader_fini(&c->in);
    loop_id_remove(s->guard, c);
    pt_free(c);
    s->nconns--;
}

static void dispatch(srv_server *s, srv_conn *c, const proto_frame *f)
{
    if (c->state == SRV_C_HELLO) {
        if (f->type == PROTO_MSG_HELLO)
            loop_on_hello(s, c, f);
        else
            srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "expected HELLO, got %s",
                                proto_msg_type_name(f->type));
        return;
    }
    if (c->state == SRV_C_AUTH) {
        if (f->type == PROTO_MSG_AUTH)
            loop_on_auth(s, c, f);
        else
            srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "expected AUTH, got %s",
                                proto_msg_type_name(f->type));
        return;
    }
    const srv_session *o = loop_session_of(s, c);
    if (o->on_frame)
        o->on_frame(s, c, f);
    else
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "unexpected %s", proto_msg_type_name(f->type));
}

/* The payload cap of c's next frame: tighter until it has authenticated,
 * then the largest its role sends (loop.h). */
uint32_t loop_conn_cap(const srv_conn *c)
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
        pt_status st = proto_frame_reader_next(&c->in, loop_conn_cap(c), &f, &err);
        if (st == PT_AGAIN)
            break;
        if (st != PT_OK) {
            if (c->state == SRV_C_READY)
                srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "%s", err.msg);
            else
                loop_conn_refuse(s, c, PROTO_E_PROTOCOL, REFUSE_GARBAGE, err.msg);
            break;
        }
        /* The next frame's clock starts as this one ends. */
        uint64_t now = pt_now_ms();
        c->t_frame = now;
        if (c->handshaking && !loop_handshake_admits(s, c, &f))
            break;
        int was_uploading = c->uploading;
        dispatch(s, c, &f);
        if (c->handshaking && c->state == SRV_C_READY) {
            loop_handshake_leave(s, c);
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
        if (!loop_in_fits(s, c) || loop_held(s, c)) {
            loop_conn_park(s, c);
            return;
        }
        uint8_t *p;
        size_t room;
        size_t before = c->in.cap;
        pt_status st = proto_frame_reader_space(&c->in, &p, &room, NULL);
        loop_in_account(s, c, before);
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
            loop_in_shrink(s, c);
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

/* The listening socket is readable. */
static void on_listener(srv_server *s, void *ctx, uint32_t events)
{
    (void)ctx;
    (void)events;
    loop_accept_all(s);
}

/* The I/O threads have items. */
static void on_io(srv_server *s, void *ctx, uint32_t events)
{
    (void)ctx;
    (void)events;
    io_deliver(s);
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
    if ((st = loop_guard_open(s, err)) != PT_OK)
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
    srv_signal_attach(s->sigpipe[1]);
    return PT_OK;
}

void srv_loop_close(srv_server *s)
{
    while (s->conns) {
        srv_conn *c = s->conns;
        s->conns = c->next;
        loop_conn_free(s, c);
    }
    srv_io_free(s->io); /* after the conns: it closes the descriptors they gave it */
    s->io = NULL;
    if (s->lfd >= 0)
        close(s->lfd);
    if (s->ep >= 0)
        close(s->ep);
    s->lfd = s->ep = -1;
    srv_signal_withdraw();
    if (s->sigpipe[0] >= 0) {
        close(s->sigpipe[0]);
        close(s->sigpipe[1]);
        s->sigpipe[0] = s->sigpipe[1] = -1;
    }
    loop_guard_close(s);
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
        const srv_session *o = loop_session_of(s, c);
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
        loop_conn_touch(s, c);
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
void loop_conn_event(srv_server *s, void *ctx, uint32_t events)
{
    srv_conn *c = ctx;
    loop_conn_touch(s, c);
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
        loop_conn_flush(s, c);
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
        loop_refusals_flush(s, now, 0);
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
            loop_conn_refuse(s, c, PROTO_E_PROTOCOL, REFUSE_LATE, text);
        } else {
            loop_conn_check_rate(s, c, now);
        }
    }
    loop_refusals_flush(s, now, 0);
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

/* The sweep of one connection; 1 when c is to be freed now. */
static int sweep_one(srv_server *s, srv_conn *c, uint64_t now)
{
    if (c->out.len > c->out_off)
        loop_conn_flush(s, c);
    if (c->rq && !c->closing && !loop_held(s, c)) { /* held: the walk every 50 ms resumes it */
        rq_run(s, c);
        loop_conn_touch(s, c); /* what it asked for is handed out next round */
    }
    if (proto_frame_reader_pending(&c->in) > 0 && !c->closing) {
        conn_process(s, c);
        loop_in_shrink(s, c);
        loop_conn_touch(s, c); /* what it asked for is handed out next round */
    }
    if (c->closing && (c->close_at == 0 || now >= c->close_at))
        return 1;
    if (c->parked && loop_in_fits(s, c) && !loop_held(s, c))
        loop_conn_unpark(c, now);
    /* What the frames served above queued goes now, not after the next
     * wait: EPOLLOUT is waited for only when the socket is full. */
    if (c->out.len > c->out_off && !c->out_blocked)
        loop_conn_flush(s, c);
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
                loop_conn_free(s, c);
                continue;
            }
            if (c->closing || c->parked)
                loop_conn_touch(s, c);
            pc = &c->next;
        }
        return;
    }
    for (uint32_t i = 0; i < n; i++) {
        srv_conn *c = list[i];
        if (!sweep_one(s, c, now)) {
            /* Not done: looked at again next round, not only every 50 ms. */
            if (c->closing || c->parked)
                loop_conn_touch(s, c);
            continue;
        }
        /* Frees are rare beside the rounds: the walk to unlink is fine. */
        srv_conn **pc = &s->conns;
        while (*pc != c)
            pc = &(*pc)->next;
        *pc = c->next;
        conn_unlist(s, c);
        loop_conn_free(s, c);
    }
    pt_free(list);
}

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

void loop_accept_all(srv_server *s)
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
                loop_note_refusal(s, REFUSE_FULL, host, "out of file descriptors");
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
        int why = loop_accept_refusal(s, addr);
        if (why == REFUSE_HANDSHAKES && loop_take_oldest_handshake(s))
            why = -1;
        if (why >= 0) {
            close(fd);
            loop_note_refusal(s, why, host, NULL);
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
        c->src = (srv_loop_source){loop_conn_event, c, fd, 0};
        struct epoll_event e = {.events = EPOLLIN, .data.ptr = &c->src};
        if (loop_id_add(s->guard, c) != 0 || epoll_ctl(s->ep, EPOLL_CTL_ADD, fd, &e) != 0) {
            loop_id_remove(s->guard, c);
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
