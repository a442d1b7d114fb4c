#define _GNU_SOURCE /* pthread_setname_np */
#include "server/net/io.h"

#include <errno.h>
#include <pthread.h>
#include <stdio.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/clock.h"
#include "server/net/peerlimits.h"

#define RATE_MS 100 /* the rate rule is judged this often */

/* A connection a thread reads. */
typedef struct io_conn {
    struct io_conn *next;
    uint64_t id;
    int fd;
    uint32_t cap;
    proto_frame_reader in;
    uint64_t t_frame, t_progress; /* as a loop connection's (server/net/loop.h) */
    int done;                     /* an end, an error or a bad frame was queued: read no more */
    int in_set;                   /* its descriptor is in the thread's epoll set */
    int armed;                    /* ... for one EPOLLIN (EPOLLONESHOT), not yet reported */
    int parked;                   /* its next frame does not fit the input memory yet */
    uint64_t t_parked;
    int waiting; /* not read: the queue was full (until CMD_RESUME) */
    uint64_t t_wait;
} io_conn;

enum { CMD_ATTACH, CMD_CLOSE, CMD_RESUME, CMD_STOP };

typedef struct io_cmd {
    struct io_cmd *next;
    int kind;
    io_conn *conn; /* ATTACH */
    uint64_t id;   /* CLOSE */
    int fd;
} io_cmd;

typedef struct io_thread {
    srv_io *io;
    pthread_t th;
    int started;
    int ep;  /* its connections (EPOLLIN, one-shot) and cmd */
    int cmd; /* eventfd: commands wait */
    pthread_mutex_t mu;
    io_cmd *cmds, **cmds_tail;
    io_conn *conns; /* the thread's own */
    /* Items read this round, queued for the loop at its end. */
    srv_io_item *out, **out_tail;
    uint64_t out_bytes;
} io_thread;

struct srv_io {
    uint32_t n;
    io_thread *t;
    srv_peer_limits lim;
    _Atomic uint64_t *in_held;
    int keep_results;
    int (*check)(const proto_result *r); /* the pixel check (srv_io_new); NULL: none */
    int wake;                            /* eventfd the loop polls */
    pthread_mutex_t mu;
    srv_io_item *head, **tail;
    uint64_t bytes;            /* held by the items waiting */
    int woken;                 /* wake written since the last take */
    int full;                  /* the threads stopped reading on a full queue */
    _Atomic uint64_t received; /* bytes, since the last take */
};

static void eventfd_bump(int fd)
{
    uint64_t one = 1;
    ssize_t r = write(fd, &one, sizeof one);
    (void)r; /* a full counter is still readable: the reader wakes */
}

static void eventfd_drain(int fd)
{
    uint64_t v;
    ssize_t r = read(fd, &v, sizeof v);
    (void)r;
}

static void post_cmd(io_thread *t, io_cmd *c)
{
    pthread_mutex_lock(&t->mu);
    c->next = NULL;
    *t->cmds_tail = c;
    t->cmds_tail = &c->next;
    pthread_mutex_unlock(&t->mu);
    eventfd_bump(t->cmd);
}

static srv_io_item *item_new(io_conn *c, int kind)
{
    srv_io_item *it = pt_calloc(1, sizeof *it);
    if (it) {
        it->conn = c->id;
        it->kind = kind;
    }
    return it;
}

static void out_push(io_thread *t, srv_io_item *it, uint64_t bytes)
{
    *t->out_tail = it;
    t->out_tail = &it->next;
    t->out_bytes += bytes + sizeof *it;
}

/* Queues an error (code, why) or an end of stream for c and reads it no
 * more. */
static void conn_end(io_thread *t, io_conn *c, int kind, uint16_t code, const char *why)
{
    srv_io_item *it = item_new(c, kind);
    if (it) {
        it->code = code;
        snprintf(it->msg, sizeof it->msg, "%s", why ? why : "");
        out_push(t, it, 0);
    }
    /* Without memory the loop still learns of it: the peer's lease
     * deadlines and a closed socket's EPOLLHUP on the loop's side. */
    c->done = 1;
    if (c->in_set) {
        epoll_ctl(t->ep, EPOLL_CTL_DEL, c->fd, NULL);
        c->in_set = c->armed = 0;
    }
}

/* Queues frame f of c: copied whole (a RESULT only when frames are kept),
 * a RESULT decoded. 0 when out of memory (c is then ended). */
static int take_frame(io_thread *t, io_conn *c, const proto_frame *f)
{
    srv_io *io = t->io;
    srv_io_item *it = item_new(c, SRV_IO_FRAME);
    if (!it) {
        conn_end(t, c, SRV_IO_ERROR, PROTO_E_LIMIT, "out of memory for a frame");
        return 0;
    }
    it->f = *f;
    uint64_t bytes = 0;
    if (f->type == PROTO_MSG_RESULT) {
        pt_error err = {0};
        /* A RESULT that does not decode goes to the loop as it came, which
         * decodes it again and answers with the same error. */
        it->decoded = proto_msg_decode_result(f->payload, f->len, NULL, 0, &it->r, &err) == PT_OK;
        if (it->decoded) {
            bytes += (uint64_t)it->r.npixels *
                     (sizeof *it->r.pixels + (it->r.pass ? sizeof *it->r.pass : 0));
            /* Checked here too (a pass over its pixels, the loop's costliest
             * part of validation); one that fails is judged again there. */
            it->checked = io->check && io->check(&it->r);
        }
    }
    it->f.payload = NULL;
    if (f->type != PROTO_MSG_RESULT || io->keep_results || !it->decoded) {
        size_t whole = (size_t)f->len + PROTO_FRAME_OVERHEAD;
        it->frame = pt_malloc(whole);
        if (!it->frame) {
            srv_io_item_free(it);
            conn_end(t, c, SRV_IO_ERROR, PROTO_E_LIMIT, "out of memory for a frame");
            return 0;
        }
        memcpy(it->frame, f->payload - PROTO_FRAME_HEADER, whole);
        it->f.payload = it->frame + PROTO_FRAME_HEADER;
        bytes += whole;
    }
    out_push(t, it, bytes);
    return 1;
}

/* The input bytes c's buffer counts more once grown to its next frame. */
static uint64_t growth(const io_conn *c)
{
    size_t need = proto_frame_reader_need(&c->in);
    return need <= c->in.cap ? 0 : srv_in_counted(need) - srv_in_counted(c->in.cap);
}

/* 1 when c's next frame fits the input memory now (nothing counted). */
static int fits_now(const io_thread *t, const io_conn *c)
{
    uint64_t more = growth(c);
    return !more || atomic_load_explicit(t->io->in_held, memory_order_relaxed) + more <=
                        t->io->lim.max_input_mem;
}

/* 1 when c's buffer may grow to what its next frame needs (counted in
 * in_held as the loop's are); counts the growth when it does. */
static int fits(io_thread *t, io_conn *c)
{
    srv_io *io = t->io;
    uint64_t more = growth(c);
    if (!more)
        return 1;
    uint64_t held = atomic_load_explicit(io->in_held, memory_order_relaxed);
    for (;;) {
        if (held + more > io->lim.max_input_mem)
            return 0;
        if (atomic_compare_exchange_weak_explicit(io->in_held, &held, held + more,
                                                  memory_order_relaxed, memory_order_relaxed))
            return 1;
    }
}

/* Sets in_held from c's capacity going from before to now, past what fits
 * already counted (the reservation of need). */
static void recount(io_thread *t, size_t reserved_for, size_t now)
{
    srv_io *io = t->io;
    uint64_t a = srv_in_counted(reserved_for), b = srv_in_counted(now);
    if (a > b)
        atomic_fetch_sub_explicit(io->in_held, a - b, memory_order_relaxed);
    else if (b > a)
        atomic_fetch_add_explicit(io->in_held, b - a, memory_order_relaxed);
}

/* Reads what c has, queuing its whole frames, until the socket is dry, c
 * ends, or its next frame does not fit the input memory (parked). */
static void conn_read(io_thread *t, io_conn *c)
{
    for (;;) {
        proto_frame f;
        pt_error err = {0};
        pt_status st;
        while ((st = proto_frame_reader_next(&c->in, c->cap, &f, &err)) == PT_OK) {
            c->t_frame = pt_now_ms(); /* the next frame's clock starts as this one ends */
            if (!take_frame(t, c, &f))
                return;
        }
        if (st != PT_AGAIN) {
            conn_end(t, c, SRV_IO_ERROR, PROTO_E_PROTOCOL, err.msg);
            return;
        }
        if (!fits(t, c)) {
            c->parked = 1;
            c->t_parked = pt_now_ms();
            return;
        }
        size_t before = c->in.cap, need = proto_frame_reader_need(&c->in);
        size_t reserved = need > before ? need : before;
        uint8_t *p;
        size_t room;
        st = proto_frame_reader_space(&c->in, &p, &room, NULL);
        recount(t, reserved, c->in.cap);
        if (st != PT_OK) {
            conn_end(t, c, SRV_IO_ERROR, PROTO_E_LIMIT,
                     st == PT_ERR_NOMEM ? "out of memory for a frame"
                                        : "frame larger than the input buffer");
            return;
        }
        ssize_t r = recv(c->fd, p, room, 0);
        if (r == 0 || (r < 0 && errno != EINTR && errno != EAGAIN && errno != EWOULDBLOCK)) {
            conn_end(t, c, SRV_IO_EOF, 0, NULL);
            return;
        }
        if (r < 0) {
            if (errno == EINTR)
                continue;
            size_t cap = c->in.cap;
            proto_frame_reader_shrink(&c->in);
            recount(t, cap, c->in.cap);
            return;
        }
        uint64_t now = pt_now_ms();
        if (proto_frame_reader_pending(&c->in) == 0)
            c->t_frame = now;
        proto_frame_reader_commit(&c->in, (size_t)r);
        atomic_fetch_add_explicit(&t->io->received, (uint64_t)r, memory_order_relaxed);
        c->t_progress = now;
    }
}

/* Puts c back in the epoll set for its next EPOLLIN. */
static void conn_arm(io_thread *t, io_conn *c)
{
    if (c->done || c->armed || c->parked)
        return;
    struct epoll_event e = {.events = EPOLLIN | EPOLLRDHUP | EPOLLONESHOT, .data.ptr = c};
    if (epoll_ctl(t->ep, c->in_set ? EPOLL_CTL_MOD : EPOLL_CTL_ADD, c->fd, &e) != 0) {
        conn_end(t, c, SRV_IO_ERROR, PROTO_E_INTERNAL, "cannot watch the connection");
        return;
    }
    c->in_set = c->armed = 1;
}

static void conn_drop(io_thread *t, io_conn *c)
{
    if (c->in_set)
        epoll_ctl(t->ep, EPOLL_CTL_DEL, c->fd, NULL);
    close(c->fd);
    atomic_fetch_sub_explicit(t->io->in_held, srv_in_counted(c->in.cap), memory_order_relaxed);
    proto_frame_reader_fini(&c->in);
    pt_free(c);
}

/* The rate rule (server/net/loop.h) over the thread's connections. */
static void judge(io_thread *t, uint64_t now)
{
    const srv_peer_limits *l = &t->io->lim;
    for (io_conn *c = t->conns; c; c = c->next) {
        if (c->done || c->parked || c->waiting || proto_frame_reader_pending(&c->in) == 0)
            continue;
        char why[256];
        if (srv_frame_too_slow(l, &c->in, c->t_frame, now, why, sizeof why))
            conn_end(t, c, SRV_IO_ERROR, PROTO_E_LIMIT, why);
        else if (now - c->t_progress > l->frame_grace_ms) {
            snprintf(why, sizeof why, "partial frame stalled for %.1f s",
                     (now - c->t_progress) / 1000.0);
            conn_end(t, c, SRV_IO_ERROR, PROTO_E_PROTOCOL, why);
        }
    }
}

/* Hands the round's items to the loop; 1 when the queue is full (stop
 * reading). */
static int publish(io_thread *t)
{
    srv_io *io = t->io;
    pthread_mutex_lock(&io->mu);
    int wake = 0;
    if (t->out) {
        *io->tail = t->out;
        io->tail = t->out_tail;
        io->bytes += t->out_bytes;
        wake = !io->woken;
        io->woken = 1;
    }
    int full = io->bytes >= SRV_IO_QUEUE_BYTES;
    if (full)
        io->full = 1;
    pthread_mutex_unlock(&io->mu);
    t->out = NULL;
    t->out_tail = &t->out;
    t->out_bytes = 0;
    if (wake)
        eventfd_bump(io->wake);
    return full;
}

/* Runs the commands waiting; 0 on STOP. */
static int run_cmds(io_thread *t)
{
    pthread_mutex_lock(&t->mu);
    io_cmd *list = t->cmds;
    t->cmds = NULL;
    t->cmds_tail = &t->cmds;
    pthread_mutex_unlock(&t->mu);
    int go = 1;
    while (list) {
        io_cmd *c = list;
        list = c->next;
        if (c->kind == CMD_ATTACH) {
            c->conn->next = t->conns;
            t->conns = c->conn;
            /* Frames it sent with its AUTH are already here. */
            conn_read(t, c->conn);
            conn_arm(t, c->conn);
        } else if (c->kind == CMD_CLOSE) {
            for (io_conn **pc = &t->conns; *pc; pc = &(*pc)->next)
                if ((*pc)->id == c->id) {
                    io_conn *dead = *pc;
                    *pc = dead->next;
                    conn_drop(t, dead);
                    break;
                }
        } else if (c->kind == CMD_RESUME) {
            /* The time the queue was full is not held against a frame: the
             * loop was the one not taking (a hold can last seconds). */
            uint64_t now = pt_now_ms();
            for (io_conn *k = t->conns; k; k = k->next) {
                if (k->waiting) {
                    k->waiting = 0;
                    k->t_frame += now - k->t_wait;
                    k->t_progress = now;
                }
                conn_arm(t, k);
            }
        } else {
            go = 0;
        }
        pt_free(c);
    }
    return go;
}

static void *io_main(void *p)
{
    io_thread *t = p;
    pthread_setname_np(pthread_self(), "pt-io");
    uint64_t t_judge = pt_now_ms();
    int go = 1, parked = 0;
    while (go) {
        struct epoll_event evs[64];
        io_conn *read[64];
        int nread = 0, cmds = 0;
        int n = epoll_wait(t->ep, evs, 64, parked ? 10 : RATE_MS);
        for (int i = 0; i < n; i++) {
            if (evs[i].data.ptr == NULL) {
                cmds = 1; /* after the batch: a close frees a connection it may name */
                continue;
            }
            io_conn *c = evs[i].data.ptr;
            c->armed = 0;
            if (!c->done) {
                conn_read(t, c);
                read[nread++] = c;
            }
        }
        uint64_t now = pt_now_ms();
        if (now - t_judge >= RATE_MS) {
            t_judge = now;
            judge(t, now);
        }
        /* Parked connections read again once their frame fits; the time
         * parked is not held against them. */
        if (parked) {
            parked = 0;
            for (io_conn *c = t->conns; c; c = c->next) {
                if (!c->parked || c->done)
                    continue;
                if (fits_now(t, c)) {
                    c->parked = 0;
                    c->t_frame += now - c->t_parked;
                    c->t_progress = now;
                    conn_read(t, c);
                    conn_arm(t, c);
                }
                parked |= c->parked;
            }
        }
        for (int i = 0; i < nread; i++)
            parked |= read[i]->parked;
        /* On a full queue the connections read this round wait for the
         * loop's take (CMD_RESUME) before they are read again. */
        if (!publish(t)) {
            for (int i = 0; i < nread; i++)
                conn_arm(t, read[i]);
        } else {
            for (int i = 0; i < nread; i++)
                if (!read[i]->waiting) {
                    read[i]->waiting = 1;
                    read[i]->t_wait = now;
                }
        }
        if (cmds) {
            eventfd_drain(t->cmd);
            go = run_cmds(t);
            if (t->out) /* an attached connection's first frames */
                publish(t);
            parked = 1; /* an attached one may have parked: look */
        }
    }
    return NULL;
}

pt_status srv_io_new(uint32_t threads, const srv_peer_limits *lim, _Atomic uint64_t *in_held,
                     int keep_results, int (*check)(const proto_result *r), srv_io **out,
                     pt_error *err)
{
    if (threads < 1 || threads > SRV_IO_MAX_THREADS)
        return pt_error_set(err, PT_ERR_ARG, "I/O threads: %u is not 1 to %u", threads,
                            SRV_IO_MAX_THREADS);
    srv_io *io = pt_calloc(1, sizeof *io);
    if (!io)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    io->lim = *lim;
    io->in_held = in_held;
    io->keep_results = keep_results;
    io->check = check;
    io->tail = &io->head;
    pthread_mutex_init(&io->mu, NULL);
    io->wake = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    io->t = pt_calloc(threads, sizeof *io->t);
    if (io->wake < 0 || !io->t) {
        srv_io_free(io);
        return pt_error_errno(err, PT_ERR_IO, "I/O threads");
    }
    for (; io->n < threads; io->n++) {
        io_thread *t = &io->t[io->n];
        t->io = io;
        t->cmds_tail = &t->cmds;
        t->out_tail = &t->out;
        pthread_mutex_init(&t->mu, NULL);
        t->ep = epoll_create1(EPOLL_CLOEXEC);
        t->cmd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
        struct epoll_event e = {.events = EPOLLIN, .data.ptr = NULL};
        if (t->ep < 0 || t->cmd < 0 || epoll_ctl(t->ep, EPOLL_CTL_ADD, t->cmd, &e) != 0 ||
            pthread_create(&t->th, NULL, io_main, t) != 0) {
            io->n++;
            srv_io_free(io);
            return pt_error_errno(err, PT_ERR_IO, "cannot start an I/O thread");
        }
        t->started = 1;
    }
    *out = io;
    return PT_OK;
}

void srv_io_free(srv_io *io)
{
    if (!io)
        return;
    for (uint32_t i = 0; i < io->n; i++) {
        io_thread *t = &io->t[i];
        if (t->started) {
            io_cmd *c = pt_calloc(1, sizeof *c);
            if (c) {
                c->kind = CMD_STOP;
                post_cmd(t, c);
                pthread_join(t->th, NULL);
            } else {
                pthread_cancel(t->th);
                pthread_join(t->th, NULL);
            }
        }
        run_cmds(t); /* closes, attaches: whatever came after the stop */
        while (t->conns) {
            io_conn *c = t->conns;
            t->conns = c->next;
            conn_drop(t, c);
        }
        for (srv_io_item *it = t->out, *nx; it; it = nx) {
            nx = it->next;
            srv_io_item_free(it);
        }
        if (t->ep >= 0)
            close(t->ep);
        if (t->cmd >= 0)
            close(t->cmd);
        pthread_mutex_destroy(&t->mu);
    }
    for (srv_io_item *it = io->head, *nx; it; it = nx) {
        nx = it->next;
        srv_io_item_free(it);
    }
    if (io->wake >= 0)
        close(io->wake);
    pthread_mutex_destroy(&io->mu);
    pt_free(io->t);
    pt_free(io);
}

int srv_io_fd(const srv_io *io)
{
    return io->wake;
}

pt_status srv_io_attach(srv_io *io, uint64_t id, int fd, proto_frame_reader *in, uint32_t cap,
                        pt_error *err)
{
    io_conn *c = pt_calloc(1, sizeof *c);
    io_cmd *cmd = pt_calloc(1, sizeof *cmd);
    if (!c || !cmd) {
        pt_free(c);
        pt_free(cmd);
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory for an I/O connection");
    }
    c->id = id;
    c->fd = fd;
    c->cap = cap;
    c->in = *in;
    proto_frame_reader_init(in, in->initial, in->max);
    c->t_frame = c->t_progress = pt_now_ms();
    cmd->kind = CMD_ATTACH;
    cmd->conn = c;
    post_cmd(&io->t[id % io->n], cmd);
    return PT_OK;
}

void srv_io_close(srv_io *io, uint64_t id, int fd)
{
    /* The thread its attach went to (id % n) has it: the close comes after
     * the attach in that thread's commands. */
    io_cmd *c = pt_calloc(1, sizeof *c);
    if (!c) {
        /* Without memory the descriptor's number stays taken until the
         * threads stop (srv_io_free drops what they hold); the thread stops
         * reading it once the peer hangs up. */
        shutdown(fd, SHUT_RDWR);
        return;
    }
    c->kind = CMD_CLOSE;
    c->id = id;
    c->fd = fd;
    post_cmd(&io->t[id % io->n], c);
}

srv_io_item *srv_io_take(srv_io *io, uint64_t *bytes)
{
    eventfd_drain(io->wake);
    *bytes = atomic_exchange_explicit(&io->received, 0, memory_order_relaxed);
    pthread_mutex_lock(&io->mu);
    srv_io_item *list = io->head;
    io->head = NULL;
    io->tail = &io->head;
    io->bytes = 0;
    io->woken = 0;
    int was_full = io->full;
    io->full = 0;
    pthread_mutex_unlock(&io->mu);
    if (was_full)
        for (uint32_t i = 0; i < io->n; i++) {
            io_cmd *c = pt_calloc(1, sizeof *c);
            if (c) {
                c->kind = CMD_RESUME;
                post_cmd(&io->t[i], c);
            }
        }
    return list;
}

void srv_io_item_free(srv_io_item *it)
{
    if (!it)
        return;
    if (it->decoded)
        proto_result_fini(&it->r);
    pt_free(it->frame);
    pt_free(it);
}
