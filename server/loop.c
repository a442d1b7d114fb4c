#define _GNU_SOURCE /* epoll, accept4, pipe2 */
#include "server/loop.h"

#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <arpa/inet.h>
#include <netinet/in.h>

#include "common/base/alloc.h"
#include "common/base/net.h"
#include "common/base/text.h"
#include "server/queue.h"
#include "server/requests.h"
#include "server/upload.h"
#include "server/workers.h"

#define MAX_CONNS 1024
#define IN_START (64u * 1024u)
#define IN_MAX (PROTO_FRAME_OVERHEAD + PROTO_MAX_PAYLOAD) /* the largest frame after AUTH */
#define OUT_MAX (256u << 20) /* a peer that lets this much pile up is dropped */
#define STALL_MS 30000       /* a partial frame or upload with no progress for this long */
#define CLOSE_GRACE_MS 1000  /* time to flush an ERROR before closing */

static volatile sig_atomic_t g_stop;
static int g_sigpipe_w = -1;

int srv_conn_has_room(const srv_conn *c)
{
    return c->out.len - c->out_off < SRV_OUT_HIGH;
}

srv_conn *srv_conn_find(srv_server *s, uint64_t id)
{
    srv_conn *c = s->conns;
    while (c && (c->id != id || c->closing))
        c = c->next;
    return c;
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

void srv_conn_update_events(srv_server *s, srv_conn *c)
{
    uint32_t ev = 0;
    if (!c->closing && srv_conn_has_room(c))
        ev |= EPOLLIN;
    if (c->out.len > c->out_off)
        ev |= EPOLLOUT;
    if (ev != c->events) {
        struct epoll_event e = {.events = ev, .data.ptr = c};
        epoll_ctl(s->ep, EPOLL_CTL_MOD, c->fd, &e);
        c->events = ev;
    }
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
        c->closing = 1;
        c->close_at = pt_now_ms() + CLOSE_GRACE_MS;
        srv_queue_release_owner(s, c, 0);
    }
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
    size_t mark;
    if (proto_frame_begin(&c->out, PROTO_MSG_ERROR, &mark, NULL) == PT_OK)
        proto_frame_finish(&c->out, mark, proto_msg_encode_error(&c->out, &m, NULL), NULL);
    srv_conn_close_soon(s, c);
}

static void conn_free(srv_server *s, srv_conn *c)
{
    if (!c->closing)
        srv_queue_release_owner(s, c, 1);
    if (c->state == SRV_C_READY && c->role == PROTO_ROLE_WORKER && s->nworkers > 0)
        s->nworkers--;
    srv_requests_conn_gone(c);
    epoll_ctl(s->ep, EPOLL_CTL_DEL, c->fd, NULL);
    close(c->fd);
    proto_writer_fini(&c->out);
    proto_frame_reader_fini(&c->in);
    pt_free(c);
    s->nconns--;
}

static void accept_all(srv_server *s)
{
    for (;;) {
        struct sockaddr_storage ss;
        socklen_t sl = sizeof ss;
        int fd = accept4(s->lfd, (struct sockaddr *)&ss, &sl, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (fd < 0)
            return;
        if (s->nconns >= MAX_CONNS) {
            close(fd);
            srv_log("refused a connection: %u peers already", s->nconns);
            continue;
        }
        srv_conn *c = pt_calloc(1, sizeof *c);
        uint8_t *room_at;
        size_t room;
        if (c)
            proto_frame_reader_init(&c->in, IN_START, IN_MAX);
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
        char host[INET6_ADDRSTRLEN] = "?";
        uint16_t port = 0;
        if (ss.ss_family == AF_INET) {
            inet_ntop(AF_INET, &((struct sockaddr_in *)&ss)->sin_addr, host, sizeof host);
            port = ntohs(((struct sockaddr_in *)&ss)->sin_port);
        } else if (ss.ss_family == AF_INET6) {
            inet_ntop(AF_INET6, &((struct sockaddr_in6 *)&ss)->sin6_addr, host, sizeof host);
            port = ntohs(((struct sockaddr_in6 *)&ss)->sin6_port);
        }
        snprintf(c->peer, sizeof c->peer, "%s:%u", host, port);
        struct epoll_event e = {.events = EPOLLIN, .data.ptr = c};
        if (epoll_ctl(s->ep, EPOLL_CTL_ADD, fd, &e) != 0) {
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
    }
}

static void on_hello(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_hello h;
    pt_error err = {0};
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
    if (h.role == PROTO_ROLE_WORKER && srv_workers_refused(s, c))
        return;
    c->role = h.role;
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

static void on_auth(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_auth a;
    pt_error err = {0};
    if (proto_msg_decode_auth(f->payload, f->len, &a, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad AUTH: %s", err.msg);
        return;
    }
    if (proto_auth_verify(s->token, s->token_len, c->nonce, a.mac, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_AUTH, "authentication failed (wrong token)");
        return;
    }
    proto_welcome w;
    w.session_id = c->id;
    snprintf(w.build_id, sizeof w.build_id, "%s", proto_build_id());
    size_t mark;
    if (proto_frame_begin(&c->out, PROTO_MSG_WELCOME, &mark, NULL) == PT_OK)
        proto_frame_finish(&c->out, mark, proto_msg_encode_welcome(&c->out, &w, NULL), NULL);
    c->state = SRV_C_READY;
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
    if (c->role == PROTO_ROLE_CLIENT)
        srv_requests_dispatch(s, c, f);
    else
        srv_workers_dispatch(s, c, f);
}

/* The payload cap of c's next frame: tighter until it has authenticated. */
static uint32_t conn_cap(const srv_conn *c)
{
    return c->state == SRV_C_READY ? PROTO_MAX_PAYLOAD : PROTO_MAX_PAYLOAD_PREAUTH;
}

/* Decodes and dispatches the whole frames buffered in c->in, while the peer's
 * output is under the high-water mark (backpressure). */
static void conn_process(srv_server *s, srv_conn *c)
{
    while (!c->closing && srv_conn_has_room(c)) {
        proto_frame f;
        pt_error err = {0};
        pt_status st = proto_frame_reader_next(&c->in, conn_cap(c), &f, &err);
        if (st == PT_AGAIN)
            break;
        if (st != PT_OK) {
            srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "%s", err.msg);
            break;
        }
        dispatch(s, c, &f);
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
        if (c->closing || !srv_conn_has_room(c))
            return;
        uint8_t *p;
        size_t room;
        pt_status st = proto_frame_reader_space(&c->in, &p, &room, NULL);
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
            return;
        }
        proto_frame_reader_commit(&c->in, (size_t)r);
        s->bytes_in += (uint64_t)r;
        c->t_progress = pt_now_ms();
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
    if ((st = pt_net_listen(host, port, &s->lfd, &s->port, err)) != PT_OK)
        return st;
    if (cfg->port_file) {
        FILE *f = fopen(cfg->port_file, "w");
        if (!f || fprintf(f, "%u\n", s->port) < 0 || fclose(f) != 0)
            return pt_error_errno(err, PT_ERR_IO, "%s", cfg->port_file);
    }
    if (!cfg->quiet)
        srv_log("listening on %s:%u%s", host, s->port, cfg->token_path ? " (token required)" : "");

    s->ep = epoll_create1(EPOLL_CLOEXEC);
    if (s->ep < 0)
        return pt_error_errno(err, PT_ERR_IO, "epoll_create1");
    struct epoll_event e = {.events = EPOLLIN, .data.ptr = NULL};
    epoll_ctl(s->ep, EPOLL_CTL_ADD, s->lfd, &e);
    if (pipe2(s->sigpipe, O_NONBLOCK | O_CLOEXEC) != 0)
        return pt_error_errno(err, PT_ERR_IO, "pipe2");
    e.data.ptr = &s->sigpipe;
    epoll_ctl(s->ep, EPOLL_CTL_ADD, s->sigpipe[0], &e);
    if ((st = srv_upload_open(s, err)) != PT_OK)
        return st;
    e.data.ptr = &s->verifypipe;
    epoll_ctl(s->ep, EPOLL_CTL_ADD, s->verifypipe[0], &e);
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
}

void srv_loop_poll(srv_server *s, int timeout_ms)
{
    struct epoll_event evs[64];
    int n = epoll_wait(s->ep, evs, 64, timeout_ms);
    for (int i = 0; i < n; i++) {
        void *p = evs[i].data.ptr;
        if (p == NULL) {
            accept_all(s);
        } else if (p == &s->sigpipe) {
            char buf[16];
            while (read(s->sigpipe[0], buf, sizeof buf) > 0) {
            }
        } else if (p == &s->verifypipe) {
            srv_upload_collect(s);
        } else {
            srv_conn *c = p;
            if (evs[i].events & (EPOLLIN | EPOLLHUP | EPOLLERR))
                conn_read(s, c);
            if (evs[i].events & EPOLLOUT)
                conn_flush(s, c);
        }
    }
}

void srv_loop_timers(srv_server *s, uint64_t now)
{
    for (srv_conn *c = s->conns; c; c = c->next) {
        if (c->closing)
            continue;
        if (c->state != SRV_C_READY && now - c->t_connect > s->cfg->handshake_ms)
            srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "handshake not finished in %.1f s",
                                s->cfg->handshake_ms / 1000.0);
        else if ((proto_frame_reader_pending(&c->in) > 0 || c->uploading) &&
                 now - c->t_progress > STALL_MS)
            srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "%s stalled for %d s",
                                c->uploading ? "upload" : "partial frame", STALL_MS / 1000);
    }
}

void srv_loop_flush_all(srv_server *s)
{
    for (srv_conn *c = s->conns; c; c = c->next)
        if (c->out.len > c->out_off && !c->closing)
            conn_flush(s, c);
}

void srv_loop_sweep(srv_server *s)
{
    uint64_t now = pt_now_ms();
    for (srv_conn **pc = &s->conns; *pc;) {
        srv_conn *c = *pc;
        if (c->out.len > c->out_off)
            conn_flush(s, c);
        if (proto_frame_reader_pending(&c->in) > 0 && !c->closing)
            conn_process(s, c);
        if (c->closing && (c->close_at == 0 || now >= c->close_at)) {
            *pc = c->next;
            conn_free(s, c);
            continue;
        }
        srv_conn_update_events(s, c);
        pc = &c->next;
    }
}
