#define _GNU_SOURCE /* epoll, accept4, pipe2 */
#include "server/serve.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <signal.h>
#include <spawn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <netinet/in.h>
#include <arpa/inet.h>

#include "common/alloc.h"
#include "common/bundle.h"
#include "common/film.h"
#include "common/net.h"
#include "common/scene.h"
#include "protocol/frame.h"
#include "protocol/msg.h"
#include "server/writer.h"

extern char **environ;

enum { C_HELLO, C_AUTH, C_READY };

#define MAX_CONNS 1024
#define IN_START (64u * 1024u)
#define OUT_HIGH (16u << 20)   /* stop reading a peer whose unsent output passes this */
#define OUT_MAX (256u << 20)   /* a peer that lets this much pile up is dropped */
#define STALL_MS 30000         /* a partial frame with no progress for this long */
#define CLOSE_GRACE_MS 1000    /* time to flush an ERROR before closing */

typedef struct conn {
    int fd;
    uint64_t id;
    int state;
    int closing;
    uint64_t close_at;
    uint8_t *in;
    size_t in_len, in_cap;
    proto_writer out;
    size_t out_off;
    uint8_t nonce[PROTO_NONCE_SIZE];
    char name[PROTO_MAX_NAME + 1];
    char peer[64];
    uint16_t threads;
    uint32_t want;
    uint64_t t_connect, t_progress;
    uint32_t events;
    struct conn *next;
} conn;

typedef struct server {
    const srv_config *cfg;
    int ep, lfd, sigpipe[2];
    conn *conns;
    uint32_t nconns, nworkers;
    uint64_t next_id;
    uint8_t token[PROTO_TOKEN_MAX];
    size_t token_len;
    pt_bundle *bundle;
    uint8_t hash[32];
    srv_job *job;
    srv_writer *writer;
    char scene_hash_hex[65];
    uint64_t t_start, t_last_save, t_last_print;
    uint32_t saved_passes;
    uint64_t saved_samples;
    uint64_t rejected, rays;
    uint64_t bytes_in, bytes_out; /* on the wire, all peers */
    pid_t *children;
    uint32_t nchildren, children_alive;
    char cache_dir[256];
    pt_pixel_acc *scratch; /* RESULT decode buffer */
    uint16_t port;
} server;

static volatile sig_atomic_t g_stop;
static int g_sigpipe_w = -1;

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

static uint64_t now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000u + (uint64_t)ts.tv_nsec / 1000000u;
}

static void logf_(const server *s, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void logf_(const server *s, const char *fmt, ...)
{
    (void)s;
    va_list ap;
    va_start(ap, fmt);
    fputs("\rptserve: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputs("\033[K\n", stderr);
    va_end(ap);
}

/* ---- connections ------------------------------------------------------------------- */

static void conn_update_events(server *s, conn *c)
{
    uint32_t ev = 0;
    if (!c->closing && c->out.len - c->out_off < OUT_HIGH)
        ev |= EPOLLIN;
    if (c->out.len > c->out_off)
        ev |= EPOLLOUT;
    if (ev != c->events) {
        struct epoll_event e = {.events = ev, .data.ptr = c};
        epoll_ctl(s->ep, EPOLL_CTL_MOD, c->fd, &e);
        c->events = ev;
    }
}

/* Frames one message into c's output: begin, the encoder's status, end. A
 * failed encoder leaves no partial frame behind. Returns 1 when queued. */
static int frame_open(conn *c, uint16_t type, size_t *mark)
{
    return proto_frame_begin(&c->out, type, mark, NULL) == PT_OK;
}

static int frame_close(conn *c, size_t mark, pt_status encoded)
{
    if (encoded != PT_OK) {
        proto_frame_cancel(&c->out, mark);
        return 0;
    }
    return proto_frame_end(&c->out, mark, NULL) == PT_OK;
}

/* Marks c for closing once its output is flushed (or the grace time ends). */
static void conn_close_soon(server *s, conn *c)
{
    if (!c->closing) {
        c->closing = 1;
        c->close_at = now_ms() + CLOSE_GRACE_MS;
        if (s->job && c->state == C_READY)
            srv_job_release_owner(s->job, c->id);
    }
}

static void conn_send_error(server *s, conn *c, uint16_t code, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
static void conn_send_error(server *s, conn *c, uint16_t code, const char *fmt, ...)
{
    proto_error_msg m;
    m.code = code;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(m.text, sizeof m.text, fmt, ap);
    va_end(ap);
    logf_(s, "peer %s%s%s: %s; closing", c->peer, c->name[0] ? " " : "", c->name, m.text);
    size_t mark;
    if (frame_open(c, PROTO_MSG_ERROR, &mark))
        frame_close(c, mark, proto_msg_encode_error(&c->out, &m, NULL));
    conn_close_soon(s, c);
}

static void conn_free(server *s, conn *c)
{
    if (s->job && c->state == C_READY && !c->closing) {
        uint32_t n = srv_job_release_owner(s->job, c->id);
        if (n)
            logf_(s, "worker %s left; %u leased tasks requeued", c->name, n);
    }
    if (c->state == C_READY && s->nworkers > 0)
        s->nworkers--;
    epoll_ctl(s->ep, EPOLL_CTL_DEL, c->fd, NULL);
    close(c->fd);
    proto_writer_fini(&c->out);
    pt_free(c->in);
    pt_free(c);
    s->nconns--;
}

static void accept_all(server *s)
{
    for (;;) {
        struct sockaddr_storage ss;
        socklen_t sl = sizeof ss;
        int fd = accept4(s->lfd, (struct sockaddr *)&ss, &sl, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (fd < 0)
            return;
        if (s->nconns >= MAX_CONNS) {
            close(fd);
            logf_(s, "refused a connection: %u peers already", s->nconns);
            continue;
        }
        conn *c = pt_calloc(1, sizeof *c);
        if (c)
            c->in = pt_malloc(IN_START);
        if (!c || !c->in) {
            if (c)
                pt_free(c);
            close(fd);
            continue;
        }
        c->fd = fd;
        c->id = ++s->next_id;
        c->in_cap = IN_START;
        c->t_connect = c->t_progress = now_ms();
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
            pt_free(c->in);
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

/* Leases tasks to every ready worker that asked for some. */
static void hand_out(server *s)
{
    if (!s->job)
        return;
    uint64_t now = now_ms();
    for (conn *c = s->conns; c; c = c->next) {
        if (c->state != C_READY || c->closing)
            continue;
        while (c->want > 0 && c->out.len - c->out_off < OUT_HIGH) {
            proto_task t;
            if (!srv_job_lease(s->job, c->id, now, s->cfg->lease_ms, &t))
                return;
            size_t mark;
            if (!frame_open(c, PROTO_MSG_TASK, &mark) ||
                !frame_close(c, mark, proto_msg_encode_task(&c->out, &t, NULL))) {
                srv_job_release_owner(s->job, c->id);
                conn_send_error(s, c, PROTO_E_LIMIT, "output buffer full");
                break;
            }
            c->want--;
        }
        conn_update_events(s, c);
    }
}

static void save_progress(server *s, int final)
{
    pt_image *img = NULL;
    const pt_film *film = srv_job_film(s->job);
    if (pt_image_new(film->width, film->height, &img, NULL) != PT_OK) {
        logf_(s, "out of memory for a progressive image; will try again");
        return;
    }
    pt_film_resolve(film, img);
    pt_exr_meta meta = {0};
    meta.total_samples = pt_film_total_samples(film);
    meta.render_seconds = (double)(now_ms() - s->t_start) / 1000.0;
    snprintf(meta.scene_hash, sizeof meta.scene_hash, "%s", s->scene_hash_hex);
    snprintf(meta.job_id, sizeof meta.job_id, "%llu", (unsigned long long)srv_job_id(s->job));
    srv_writer_submit(s->writer, img, &meta);
    s->t_last_save = now_ms();
    s->saved_passes = srv_job_passes_done(s->job);
    s->saved_samples = meta.total_samples;
    (void)final;
}

/* ---- messages ---------------------------------------------------------------------- */

static void on_hello(server *s, conn *c, const proto_frame *f)
{
    proto_hello h;
    pt_error err = {0};
    if (proto_msg_decode_hello(f->payload, f->len, &h, &err) != PT_OK) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "bad HELLO: %s", err.msg);
        return;
    }
    snprintf(c->name, sizeof c->name, "%s", h.name);
    if (h.version != PROTO_VERSION) {
        conn_send_error(s, c, PROTO_E_VERSION, "protocol version %u is not supported (this "
                        "coordinator speaks %u)", h.version, PROTO_VERSION);
        return;
    }
    if (h.role != PROTO_ROLE_WORKER) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "role %u is not served by this coordinator",
                        h.role);
        return;
    }
    if (strcmp(h.build_id, proto_build_id()) != 0) {
        conn_send_error(s, c, PROTO_E_BUILD, "worker renderer build %s differs from the "
                        "coordinator's %s; mixed builds would break bit-identical merging",
                        h.build_id, proto_build_id());
        return;
    }
    c->threads = h.threads;
    proto_challenge ch;
    if (proto_auth_nonce(ch.nonce, &err) != PT_OK) {
        conn_send_error(s, c, PROTO_E_INTERNAL, "cannot make a nonce: %s", err.msg);
        return;
    }
    memcpy(c->nonce, ch.nonce, sizeof c->nonce);
    size_t mark;
    if (frame_open(c, PROTO_MSG_CHALLENGE, &mark))
        frame_close(c, mark, proto_msg_encode_challenge(&c->out, &ch, NULL));
    c->state = C_AUTH;
}

static void on_auth(server *s, conn *c, const proto_frame *f)
{
    proto_auth a;
    pt_error err = {0};
    if (proto_msg_decode_auth(f->payload, f->len, &a, &err) != PT_OK) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "bad AUTH: %s", err.msg);
        return;
    }
    if (proto_auth_verify(s->token, s->token_len, c->nonce, a.mac, &err) != PT_OK) {
        conn_send_error(s, c, PROTO_E_AUTH, "authentication failed (wrong token)");
        return;
    }
    proto_welcome w;
    w.session_id = c->id;
    snprintf(w.build_id, sizeof w.build_id, "%s", proto_build_id());
    size_t mark;
    if (frame_open(c, PROTO_MSG_WELCOME, &mark))
        frame_close(c, mark, proto_msg_encode_welcome(&c->out, &w, NULL));
    c->state = C_READY;
    s->nworkers++;
    if (!s->cfg->quiet)
        logf_(s, "worker %s joined from %s (%u threads)", c->name, c->peer, c->threads);
}

static void on_scene_get(server *s, conn *c, const proto_frame *f)
{
    proto_scene_get g;
    pt_error err = {0};
    if (proto_msg_decode_scene_get(f->payload, f->len, &g, &err) != PT_OK) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "bad SCENE_GET: %s", err.msg);
        return;
    }
    if (!s->bundle || memcmp(g.hash, s->hash, 32) != 0) {
        conn_send_error(s, c, PROTO_E_NOT_FOUND, "no scene with that hash");
        return;
    }
    if (g.offset > s->bundle->size) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "scene offset %llu is past its end (%zu)",
                        (unsigned long long)g.offset, s->bundle->size);
        return;
    }
    proto_scene_chunk ch;
    memcpy(ch.hash, s->hash, 32);
    ch.offset = g.offset;
    ch.total = s->bundle->size;
    size_t left = s->bundle->size - (size_t)g.offset;
    ch.len = (uint32_t)(left < PROTO_MAX_SCENE_CHUNK ? left : PROTO_MAX_SCENE_CHUNK);
    ch.data = s->bundle->data + g.offset;
    size_t mark;
    if (!frame_open(c, PROTO_MSG_SCENE_CHUNK, &mark) ||
        !frame_close(c, mark, proto_msg_encode_scene_chunk(&c->out, &ch, NULL)))
        conn_send_error(s, c, PROTO_E_LIMIT, "output buffer full");
}

static void on_result(server *s, conn *c, const proto_frame *f)
{
    proto_result r;
    pt_error err = {0};
    if (proto_msg_decode_result(f->payload, f->len, s->scratch, PROTO_MAX_TILE_PIXELS, &r, &err) !=
        PT_OK) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "bad RESULT: %s", err.msg);
        return;
    }
    if (!s->job) {
        proto_result_fini(&r);
        return;
    }
    srv_outcome o = srv_job_result(s->job, c->id, &r, &err);
    switch (o) {
    case SRV_MERGED:
        s->rejected += r.rejected;
        s->rays += r.rays;
        break;
    case SRV_DUPLICATE:
        break;
    case SRV_NOT_LEASED:
        logf_(s, "worker %s: %s; dropped", c->name, err.msg);
        break;
    case SRV_INVALID:
        conn_send_error(s, c, PROTO_E_PROTOCOL, "%s", err.msg);
        break;
    }
    proto_result_fini(&r);
}

static void on_heartbeat(server *s, conn *c, const proto_frame *f)
{
    static proto_heartbeat hb; /* large; the loop is single-threaded */
    pt_error err = {0};
    if (proto_msg_decode_heartbeat(f->payload, f->len, &hb, &err) != PT_OK) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "bad HEARTBEAT: %s", err.msg);
        return;
    }
    if (!s->job)
        return;
    uint64_t now = now_ms();
    for (uint32_t i = 0; i < hb.count; i++)
        srv_job_heartbeat(s->job, c->id, hb.task_ids[i], now, s->cfg->lease_ms);
}

static void dispatch(server *s, conn *c, const proto_frame *f)
{
    if (c->state == C_HELLO) {
        if (f->type == PROTO_MSG_HELLO)
            on_hello(s, c, f);
        else
            conn_send_error(s, c, PROTO_E_PROTOCOL, "expected HELLO, got %s",
                            proto_msg_type_name(f->type));
        return;
    }
    if (c->state == C_AUTH) {
        if (f->type == PROTO_MSG_AUTH)
            on_auth(s, c, f);
        else
            conn_send_error(s, c, PROTO_E_PROTOCOL, "expected AUTH, got %s",
                            proto_msg_type_name(f->type));
        return;
    }
    switch (f->type) {
    case PROTO_MSG_WORK_REQUEST: {
        proto_work_request w;
        pt_error err = {0};
        if (proto_msg_decode_work_request(f->payload, f->len, &w, &err) != PT_OK) {
            conn_send_error(s, c, PROTO_E_PROTOCOL, "bad WORK_REQUEST: %s", err.msg);
            return;
        }
        c->want += w.slots;
        if (c->want > PROTO_MAX_SLOTS)
            c->want = PROTO_MAX_SLOTS;
        break;
    }
    case PROTO_MSG_SCENE_GET: on_scene_get(s, c, f); break;
    case PROTO_MSG_RESULT: on_result(s, c, f); break;
    case PROTO_MSG_HEARTBEAT: on_heartbeat(s, c, f); break;
    case PROTO_MSG_ERROR: {
        proto_error_msg m;
        if (proto_msg_decode_error(f->payload, f->len, &m, NULL) == PT_OK)
            logf_(s, "worker %s reports: %s", c->name, m.text);
        conn_close_soon(s, c);
        break;
    }
    default:
        conn_send_error(s, c, PROTO_E_PROTOCOL, "unexpected %s from a worker",
                        proto_msg_type_name(f->type));
    }
}

/* Decodes and dispatches the whole frames buffered in c->in, while the peer's
 * output is under the high-water mark (backpressure). */
static void conn_process(server *s, conn *c)
{
    size_t off = 0;
    while (!c->closing && c->out.len - c->out_off < OUT_HIGH) {
        proto_frame f;
        size_t used;
        pt_error err = {0};
        uint32_t cap = c->state == C_READY ? PROTO_MAX_PAYLOAD : PROTO_MAX_PAYLOAD_PREAUTH;
        pt_status st = proto_frame_decode(c->in + off, c->in_len - off, cap, &f, &used, &err);
        if (st == PT_AGAIN)
            break;
        if (st != PT_OK) {
            conn_send_error(s, c, PROTO_E_PROTOCOL, "%s", err.msg);
            break;
        }
        dispatch(s, c, &f);
        off += used;
    }
    if (off > 0) {
        memmove(c->in, c->in + off, c->in_len - off);
        c->in_len -= off;
    }
}

static void conn_read(server *s, conn *c)
{
    while (!c->closing && c->out.len - c->out_off < OUT_HIGH) {
        uint32_t cap = c->state == C_READY ? PROTO_MAX_PAYLOAD : PROTO_MAX_PAYLOAD_PREAUTH;
        /* Grow the input buffer to the declared frame (the decoder has already
         * refused a length over the cap once the header was present). */
        if (c->in_len >= PROTO_FRAME_HEADER) {
            size_t need = PROTO_FRAME_OVERHEAD + (size_t)proto_get_u32(c->in + 8);
            if (need > c->in_cap && need <= PROTO_FRAME_OVERHEAD + (size_t)cap) {
                uint8_t *n = pt_realloc(c->in, need);
                if (!n) {
                    conn_send_error(s, c, PROTO_E_LIMIT, "out of memory for a frame");
                    return;
                }
                c->in = n;
                c->in_cap = need;
            }
        }
        if (c->in_len == c->in_cap) {
            conn_send_error(s, c, PROTO_E_LIMIT, "frame larger than the input buffer");
            return;
        }
        ssize_t r = recv(c->fd, c->in + c->in_len, c->in_cap - c->in_len, 0);
        if (r == 0 || (r < 0 && errno != EINTR && errno != EAGAIN && errno != EWOULDBLOCK)) {
            conn_close_soon(s, c);
            c->close_at = 0;
            return;
        }
        if (r < 0) {
            if (errno == EINTR)
                continue;
            return;
        }
        c->in_len += (size_t)r;
        s->bytes_in += (uint64_t)r;
        c->t_progress = now_ms();
        conn_process(s, c);
    }
}

static void conn_flush(server *s, conn *c)
{
    while (c->out.len > c->out_off) {
        ssize_t w = send(c->fd, c->out.buf + c->out_off, c->out.len - c->out_off,
                         MSG_NOSIGNAL | MSG_DONTWAIT);
        if (w < 0) {
            if (errno == EINTR)
                continue;
            if (errno != EAGAIN && errno != EWOULDBLOCK) {
                conn_close_soon(s, c);
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

/* ---- timers ------------------------------------------------------------------------ */

static void format_eta(double sec, char *buf, size_t n)
{
    if (!(sec >= 0) || sec > 360000)
        snprintf(buf, n, "--");
    else if (sec >= 3600)
        snprintf(buf, n, "%dh%02dm", (int)(sec / 3600), (int)(sec / 60) % 60);
    else if (sec >= 60)
        snprintf(buf, n, "%dm%02ds", (int)(sec / 60), (int)sec % 60);
    else
        snprintf(buf, n, "%.0fs", sec);
}

static void print_progress(server *s, uint64_t now)
{
    const srv_job_params *p = srv_job_params_of(s->job);
    double el = (double)(now - s->t_start) / 1000.0;
    uint64_t done = srv_job_samples_merged(s->job);
    double total = (double)p->width * p->height * p->spp;
    double rate = el > 0 ? (double)done / el : 0;
    char eta[32];
    format_eta(rate > 0 ? (total - (double)done) / rate : -1, eta, sizeof eta);
    fprintf(stderr, "\rptserve: pass %u/%u  %.1f/%u spp  %.3g samples/s  %u workers  ETA %s\033[K",
            srv_job_passes_done(s->job), srv_job_passes(s->job),
            (double)done / ((double)p->width * p->height), p->spp, rate, s->nworkers, eta);
}

static void timers(server *s)
{
    uint64_t now = now_ms();
    if (s->job && srv_job_expire(s->job, now, NULL) > 0)
        logf_(s, "leases expired; tasks requeued");
    for (conn *c = s->conns; c; c = c->next) {
        if (c->closing)
            continue;
        if (c->state != C_READY && now - c->t_connect > s->cfg->handshake_ms)
            conn_send_error(s, c, PROTO_E_PROTOCOL, "handshake not finished in %.1f s",
                            s->cfg->handshake_ms / 1000.0);
        else if (c->in_len > 0 && now - c->t_progress > STALL_MS)
            conn_send_error(s, c, PROTO_E_PROTOCOL, "partial frame stalled for %d s",
                            STALL_MS / 1000);
    }
    if (s->job) {
        uint64_t merged = srv_job_samples_merged(s->job);
        int pass_done = srv_job_passes_done(s->job) > s->saved_passes;
        if ((pass_done || merged > s->saved_samples) &&
            (double)(now - s->t_last_save) >= s->cfg->save_interval * 1000.0 &&
            !srv_job_complete(s->job))
            save_progress(s, 0);
        if (!s->cfg->quiet && now - s->t_last_print >= 1000) {
            s->t_last_print = now;
            print_progress(s, now);
        }
    }
}

/* ---- local workers ----------------------------------------------------------------- */

static pt_status spawn_workers(server *s, pt_error *err)
{
    const srv_config *cfg = s->cfg;
    char bin[PATH_MAX];
    if (cfg->worker_bin) {
        snprintf(bin, sizeof bin, "%s", cfg->worker_bin);
    } else {
        ssize_t n = readlink("/proc/self/exe", bin, sizeof bin - 16);
        if (n <= 0)
            return pt_error_errno(err, PT_ERR_IO, "cannot find this program's folder");
        bin[n] = '\0';
        char *slash = strrchr(bin, '/');
        snprintf(slash + 1, sizeof bin - (size_t)(slash + 1 - bin), "ptworker");
    }
    if (access(bin, X_OK) != 0)
        return pt_error_errno(err, PT_ERR_IO, "%s", bin);
    const char *tmp = getenv("TMPDIR");
    snprintf(s->cache_dir, sizeof s->cache_dir, "%s/ptserve-cache-XXXXXX", tmp && *tmp ? tmp : "/tmp");
    if (!mkdtemp(s->cache_dir))
        return pt_error_errno(err, PT_ERR_IO, "%s", s->cache_dir);
    uint32_t threads = cfg->worker_threads;
    if (threads == 0) {
        long cores = sysconf(_SC_NPROCESSORS_ONLN);
        threads = cores > 0 ? (uint32_t)cores / cfg->local_workers : 1;
        if (threads == 0)
            threads = 1;
    }
    s->children = pt_calloc(cfg->local_workers, sizeof *s->children);
    if (!s->children)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    char server_arg[64], threads_arg[16], name_arg[32];
    snprintf(server_arg, sizeof server_arg, "127.0.0.1:%u", s->port);
    snprintf(threads_arg, sizeof threads_arg, "%u", threads);
    for (uint32_t i = 0; i < cfg->local_workers; i++) {
        snprintf(name_arg, sizeof name_arg, "local-%u", i + 1);
        const char *argv[16];
        int a = 0;
        argv[a++] = bin;
        argv[a++] = "--server";
        argv[a++] = server_arg;
        argv[a++] = "--threads";
        argv[a++] = threads_arg;
        argv[a++] = "--cache-dir";
        argv[a++] = s->cache_dir;
        argv[a++] = "--name";
        argv[a++] = name_arg;
        if (cfg->token_path) {
            argv[a++] = "--token-file";
            argv[a++] = cfg->token_path;
        }
        argv[a] = NULL;
        posix_spawn_file_actions_t fa;
        posix_spawn_file_actions_init(&fa);
        posix_spawn_file_actions_addopen(&fa, 1, "/dev/null", O_WRONLY, 0);
        pid_t pid;
        int rc = posix_spawn(&pid, bin, &fa, NULL, (char *const *)argv, environ);
        posix_spawn_file_actions_destroy(&fa);
        if (rc != 0) {
            errno = rc;
            return pt_error_errno(err, PT_ERR_IO, "cannot start %s", bin);
        }
        s->children[s->nchildren++] = pid;
        s->children_alive++;
    }
    if (!cfg->quiet)
        logf_(s, "started %u local workers with %u threads each", cfg->local_workers, threads);
    return PT_OK;
}

static void reap_children(server *s, int wait_all)
{
    for (uint32_t i = 0; i < s->nchildren; i++) {
        if (s->children[i] <= 0)
            continue;
        int st;
        pid_t r = waitpid(s->children[i], &st, wait_all ? 0 : WNOHANG);
        if (r == s->children[i]) {
            if (!wait_all) {
                if (WIFEXITED(st))
                    logf_(s, "local worker %u exited with status %d", i + 1, WEXITSTATUS(st));
                else if (WIFSIGNALED(st))
                    logf_(s, "local worker %u killed by signal %d", i + 1, WTERMSIG(st));
            }
            s->children[i] = 0;
            s->children_alive--;
        }
    }
}

static void stop_children(server *s)
{
    for (uint32_t i = 0; i < s->nchildren; i++)
        if (s->children[i] > 0)
            kill(s->children[i], SIGTERM);
    reap_children(s, 1);
    if (s->cache_dir[0]) {
        /* The cache holds only what the workers unpacked from our bundle. */
        char cmd[512];
        snprintf(cmd, sizeof cmd, "rm -rf '%s'", s->cache_dir);
        if (system(cmd) != 0)
            logf_(s, "could not remove %s", s->cache_dir);
    }
}

/* ---- setup and the loop ------------------------------------------------------------ */

static int hex_to_bytes(const char *hex, uint8_t *out, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        unsigned v;
        if (sscanf(hex + 2 * i, "%2x", &v) != 1)
            return -1;
        out[i] = (uint8_t)v;
    }
    return 0;
}

static pt_status setup(server *s, pt_error *err)
{
    const srv_config *cfg = s->cfg;
    pt_status st;
    if (cfg->token_path) {
        int loose = 0;
        if ((st = proto_token_load(cfg->token_path, s->token, sizeof s->token, &s->token_len,
                                   &loose, err)) != PT_OK)
            return st;
        if (loose)
            logf_(s, "warning: %s is readable by other users", cfg->token_path);
    }
    /* Load once here so a broken scene fails before any worker starts. */
    pt_scene_opts so = {0};
    /* Workers render the scene's first camera: TASK names no camera. */
    pt_scene *scene = NULL;
    if ((st = pt_scene_load(cfg->scene_path, &so, &scene, err)) != PT_OK)
        return st;
    srv_job_params jp = cfg->job;
    if (jp.width == 0) {
        float aspect = scene->camera.aspect > 0 ? scene->camera.aspect : 1.0f;
        jp.width = 512;
        jp.height = (uint32_t)(512.0f / aspect + 0.5f);
        if (jp.height == 0)
            jp.height = 1;
    }
    uint32_t ntris = scene->num_triangles;
    pt_scene_free(scene);
    if ((st = pt_bundle_pack(cfg->scene_path, &s->bundle, err)) != PT_OK)
        return st;
    snprintf(s->scene_hash_hex, sizeof s->scene_hash_hex, "%s", s->bundle->hash);
    hex_to_bytes(s->bundle->hash, s->hash, 32);
    if ((st = srv_job_new(1, &jp, s->hash, &s->job, err)) != PT_OK)
        return st;
    if ((st = srv_writer_new(cfg->out_path, &s->writer, err)) != PT_OK)
        return st;
    s->scratch = pt_malloc_array(PROTO_MAX_TILE_PIXELS, sizeof *s->scratch);
    if (!s->scratch)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");

    char host[256];
    uint16_t port = cfg->local_workers ? 0 : 7878;
    snprintf(host, sizeof host, "127.0.0.1");
    if (cfg->listen && (st = pt_net_split(cfg->listen, host, sizeof host, &port, err)) != PT_OK)
        return st;
    if (!cfg->token_path && !pt_net_host_is_loopback(host)) {
        logf_(s, "no --token-file: listening on loopback only (127.0.0.1), not '%s'", host);
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
        logf_(s, "%s: %u triangles, %ux%u, %u spp in %u passes of %u, tiles of %u; listening on "
              "%s:%u%s", cfg->scene_path, ntris, jp.width, jp.height, jp.spp,
              srv_job_passes(s->job), jp.chunk, jp.tile, host, s->port,
              cfg->token_path ? " (token required)" : "");

    s->ep = epoll_create1(EPOLL_CLOEXEC);
    if (s->ep < 0)
        return pt_error_errno(err, PT_ERR_IO, "epoll_create1");
    struct epoll_event e = {.events = EPOLLIN, .data.ptr = NULL};
    epoll_ctl(s->ep, EPOLL_CTL_ADD, s->lfd, &e);
    if (pipe2(s->sigpipe, O_NONBLOCK | O_CLOEXEC) != 0)
        return pt_error_errno(err, PT_ERR_IO, "pipe2");
    e.data.ptr = &s->sigpipe;
    epoll_ctl(s->ep, EPOLL_CTL_ADD, s->sigpipe[0], &e);
    g_sigpipe_w = s->sigpipe[1];
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
    s->t_start = s->t_last_save = s->t_last_print = now_ms();
    if (cfg->local_workers && (st = spawn_workers(s, err)) != PT_OK)
        return st;
    return PT_OK;
}

int srv_serve(const srv_config *cfg)
{
    server s;
    memset(&s, 0, sizeof s);
    s.cfg = cfg;
    s.lfd = s.ep = s.sigpipe[0] = s.sigpipe[1] = -1;
    pt_error err = {0};
    int rc = 1;
    if (setup(&s, &err) != PT_OK) {
        fprintf(stderr, "ptserve: %s\n", err.msg);
        goto done;
    }
    while (!g_stop && !srv_job_complete(s.job)) {
        struct epoll_event evs[64];
        int n = epoll_wait(s.ep, evs, 64, 100);
        for (int i = 0; i < n; i++) {
            void *p = evs[i].data.ptr;
            if (p == NULL) {
                accept_all(&s);
            } else if (p == &s.sigpipe) {
                char buf[16];
                while (read(s.sigpipe[0], buf, sizeof buf) > 0) {
                }
            } else {
                conn *c = p;
                if (evs[i].events & (EPOLLIN | EPOLLHUP | EPOLLERR))
                    conn_read(&s, c);
                if (evs[i].events & EPOLLOUT)
                    conn_flush(&s, c);
            }
        }
        hand_out(&s);
        timers(&s);
        /* Flush, then free closed connections outside their callbacks. */
        uint64_t now = now_ms();
        for (conn **pc = &s.conns; *pc;) {
            conn *c = *pc;
            if (c->out.len > c->out_off)
                conn_flush(&s, c);
            if (c->in_len > 0 && !c->closing)
                conn_process(&s, c);
            if (c->closing && (c->close_at == 0 || now >= c->close_at)) {
                *pc = c->next;
                conn_free(&s, c);
                continue;
            }
            conn_update_events(&s, c);
            pc = &c->next;
        }
        if (s.nchildren) {
            reap_children(&s, 0);
            if (s.children_alive == 0 && !srv_job_complete(s.job)) {
                fprintf(stderr, "\nptserve: all %u local workers exited before the image was "
                        "complete\n", s.nchildren);
                break;
            }
        }
    }
    if (s.job) {
        save_progress(&s, 1);
        pt_status st = srv_writer_flush(s.writer, &err);
        if (!cfg->quiet)
            print_progress(&s, now_ms());
        fputc('\n', stderr);
        double secs = (double)(now_ms() - s.t_start) / 1000.0;
        if (st != PT_OK) {
            fprintf(stderr, "ptserve: cannot write %s: %s\n", cfg->out_path, err.msg);
        } else if (srv_job_complete(s.job)) {
            fprintf(stderr, "ptserve: done in %.2fs: %llu samples (%.4g samples/s), %llu rejected "
                    "samples (NaN/Inf); wrote %s\n", secs,
                    (unsigned long long)srv_job_samples_merged(s.job),
                    (double)srv_job_samples_merged(s.job) / secs, (unsigned long long)s.rejected,
                    cfg->out_path);
            uint64_t samples = srv_job_samples_merged(s.job), tasks = srv_job_tasks_total(s.job);
            fprintf(stderr, "ptserve: wire: %llu bytes in, %llu out (scene %zu); %.3f bytes per "
                    "sample, %.0f per task\n", (unsigned long long)s.bytes_in,
                    (unsigned long long)s.bytes_out, s.bundle->size,
                    (double)(s.bytes_in + s.bytes_out) / (double)samples,
                    (double)(s.bytes_in + s.bytes_out) / (double)tasks);
            rc = 0;
        } else if (g_stop) {
            fprintf(stderr, "ptserve: interrupted after %.2fs; %s holds %llu of %llu samples\n",
                    secs, cfg->out_path, (unsigned long long)srv_job_samples_merged(s.job),
                    (unsigned long long)srv_job_params_of(s.job)->width *
                        srv_job_params_of(s.job)->height * srv_job_params_of(s.job)->spp);
            rc = 130;
        }
    }
done:
    if (s.nchildren)
        stop_children(&s);
    while (s.conns) {
        conn *c = s.conns;
        s.conns = c->next;
        conn_free(&s, c);
    }
    srv_writer_free(s.writer);
    srv_job_free(s.job);
    pt_bundle_free(s.bundle);
    pt_free(s.scratch);
    pt_free(s.children);
    if (s.lfd >= 0)
        close(s.lfd);
    if (s.ep >= 0)
        close(s.ep);
    g_sigpipe_w = -1;
    if (s.sigpipe[0] >= 0) {
        close(s.sigpipe[0]);
        close(s.sigpipe[1]);
    }
    return rc;
}
