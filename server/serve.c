#define _GNU_SOURCE /* epoll, accept4, pipe2 */
#include "server/serve.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <arpa/inet.h>
#include <netinet/in.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/base/hash.h"
#include "common/base/net.h"
#include "common/render/adaptive.h"
#include "common/render/film.h"
#include "common/scene/bundle.h"
#include "common/scene/scene.h"
#include "protocol/frame.h"
#include "protocol/msg.h"
#include "server/core.h"
#include "server/job.h"
#include "server/local.h"
#include "server/state.h"
#include "server/writer.h"

/* ---- loop.h -------------------------------------------------------------- */

/*
 * loop.h - the event loop: non-blocking sockets under one epoll, and the
 * connections (workers and clients) it serves.
 *
 * Owns every srv_conn: its input buffer (IN_START bytes, grown only to the
 * frame its header declares, which the decoder has checked against the cap:
 * PROTO_MAX_PAYLOAD_PREAUTH before authentication, PROTO_MAX_PAYLOAD after),
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

#define SRV_OUT_HIGH (16u << 20) /* stop reading a peer whose unsent output passes this */

enum { SRV_C_HELLO, SRV_C_AUTH, SRV_C_READY };

struct srv_conn {
    int fd;
    uint64_t id;
    int state; /* SRV_C_* */
    uint8_t role;
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
    uint32_t want; /* worker: free slots it asked tasks for */
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

/* Frames one message into c's output: srv_conn_frame_open, the encoder's
 * status, srv_conn_frame_close. A failed encoder leaves no partial frame.
 * Each returns 1 on success. */
int srv_conn_frame_open(srv_conn *c, uint16_t type, size_t *mark);
int srv_conn_frame_close(srv_conn *c, size_t mark, pt_status encoded);

/* 1 while c's unsent output is under SRV_OUT_HIGH. */
int srv_conn_has_room(const srv_conn *c);

/* Sets c's epoll interest from its output and closing state. */
void srv_conn_update_events(srv_server *s, srv_conn *c);

/* Logs, sends ERROR(code, text) and closes c once that is flushed. */
void srv_conn_send_error(srv_server *s, srv_conn *c, uint16_t code, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));

/* Closes c once its output is flushed (or the grace time ends). */
void srv_conn_close_soon(srv_server *s, srv_conn *c);

/* An ERROR from the peer (who: "client" or "worker"): logged, then closed. */
void srv_conn_peer_error(srv_server *s, srv_conn *c, const proto_frame *f, const char *who);

/* The open connection with this id, NULL when there is none. */
srv_conn *srv_conn_find(srv_server *s, uint64_t id);

/* ---- queue.h ------------------------------------------------------------- */

/*
 * queue.h - the jobs a coordinator serves, in order, and their scheduling.
 *
 * Owns every srv_entry: a job as the coordinator serves it (its durable
 * record, its srv_job once it is first scheduled, its bundle, its image
 * writer, its timings). The list is in queue order: priority (higher first),
 * then submission (lower id first). A worker's free slot gets the first task
 * of the first job in that order that has one to hand out, so a higher
 * priority job takes the farm from its next task on, and idle workers start
 * on the next job during the running one's last pass. Leases expire; a job
 * ends DONE (its final image written first), CANCELLED or FAILED, and
 * workers are told at once of one that ended early (JOB_END). Progressive
 * images are saved at most every cfg->save_interval seconds, checkpoints
 * when a results log grows past max(16 MiB, the film's size).
 *
 * Durable steps (the queue file, results logs, checkpoints, bundles) use the
 * state folder (server/state.h); with none (one-job mode) they are skipped.
 *
 * Threads: called only from the event-loop thread.
 */

/* A job of the queue (or the one job of one-job mode). */
struct srv_entry {
    srv_job_record rec;
    srv_job *job;      /* NULL until it is first scheduled (and after it ends) */
    pt_bundle *bundle; /* loaded when a worker first asks for it */
    srv_writer *writer;
    char out_path[PATH_MAX];
    double seconds_before; /* render seconds of earlier coordinator runs */
    uint64_t t_started;    /* when this run started rendering it (ms), 0: not yet */
    uint64_t rejected, rays;
    uint32_t saved_passes;
    uint64_t saved_samples, t_last_save;
    uint64_t rate_t, rate_samples;
    double rate;
    srv_entry *next; /* the queue's order */
};

/* 1 while j is QUEUED or RUNNING. */
int srv_entry_active(const srv_entry *j);

/* Render seconds of j, over every coordinator run, at now (ms). */
double srv_entry_seconds(const srv_entry *j, uint64_t now);

/* Frees j and what it holds; accepts NULL. */
void srv_entry_free(srv_entry *j);

/* Makes j ready to lease: its srv_job (restored from its checkpoint and
 * results log when there is a state folder) and its image writer. Returns 0
 * when it cannot be (j is then ended FAILED, with the reason). */
int srv_entry_ready(srv_server *s, srv_entry *j);

/* Hands j's film, resolved, to its writer (a progressive or final image). */
void srv_entry_save_image(srv_entry *j);

/* Writes j's checkpoint when there is a state folder (errors are logged). */
void srv_entry_checkpoint(srv_server *s, srv_entry *j);

/* The job with id, NULL when there is none. */
srv_entry *srv_queue_find(srv_server *s, uint64_t id);

/* The active job whose scene has this SHA-256, its bundle loaded (a bundle
 * that does not load fails the job); NULL when there is none. */
srv_entry *srv_queue_find_scene(srv_server *s, const uint8_t hash[32]);

/* Puts j in its place in the queue order / takes it out again. */
void srv_queue_insert(srv_server *s, srv_entry *j);
void srv_queue_unlink(srv_server *s, srv_entry *j);

/* Drops the oldest ended jobs beyond the history's cap. */
void srv_queue_prune(srv_server *s);

/* Writes the queue file (every job's record); PT_OK with no state folder. */
pt_status srv_queue_journal(srv_server *s, pt_error *err);

/* Logs an accepted RESULT payload of j durably before it is merged; PT_OK
 * with no state folder. */
pt_status srv_queue_log_result(srv_server *s, const srv_entry *j, const uint8_t *payload,
                               size_t len, pt_error *err);

/* JOB_INFO of j as a client sees it now. */
void srv_queue_info(const srv_server *s, const srv_entry *j, proto_job_info *m);

/* Ends j: DONE (the final image is written first; FAILED when it cannot
 * be), CANCELLED or FAILED with message (may be NULL). Journals it, tells
 * the workers when it ended early and its watchers always. */
void srv_queue_end_job(srv_server *s, srv_entry *j, uint8_t state, const char *message);

/* Ends the jobs whose every task is merged; returns how many. */
int srv_queue_end_complete(srv_server *s);

/* Leases tasks to every ready worker that asked for some (and feeds the
 * clients' fetches, server/requests.h, while going over the connections). */
void srv_queue_hand_out(srv_server *s);

/* Requeues every task leased to c (a worker that is leaving); report: log
 * how many. Nothing for a peer that is not a ready worker. */
void srv_queue_release_owner(srv_server *s, const srv_conn *c, int report);

/* Lease expiry; then, per running job, the progressive save, the rate and
 * the checkpoint trigger. now in ms (srv_now_ms). */
void srv_queue_expire(srv_server *s, uint64_t now);
void srv_queue_tick(srv_server *s, uint64_t now);

/* Frees every job and closes the state folder. */
void srv_queue_free(srv_server *s);

/* ---- upload.h ------------------------------------------------------------ */

/*
 * upload.h - upload verification: a submitted scene checked off the loop.
 *
 * A complete upload is verified on a thread of its own, since a big scene
 * takes seconds: its SHA-256 against the one SUBMIT announced, its bundle,
 * one load of the scene in a temporary folder (with the camera asked for, so
 * a broken scene is refused now, not by every worker), and the bundle stored
 * in the state folder under the job id reserved for it. The thread writes
 * the srv_upload's pointer to the verification pipe; the loop then hands the
 * outcome to server/requests.h, which queues the job or refuses it. The
 * server never opens a path a client names.
 *
 * Threads: every function here is called from the event-loop thread. The
 * verification thread touches only its srv_upload and, through
 * srv_state_save_bundle, the state folder (server/state.h says it may).
 */

struct srv_upload {
    uint64_t conn_id, job_id;
    proto_submit m;
    uint8_t *data; /* the upload (owned), freed once wrapped in bundle */
    size_t len;
    const srv_state *state;
    char tmp[PATH_MAX];
    int wake_fd;
    pthread_t thread;
    /* the outcome */
    int ok;
    uint16_t code; /* PROTO_E_* of the refusal */
    char msg[PROTO_MAX_ERROR_TEXT + 1];
    pt_bundle *bundle;
    char scene[256]; /* the entry file's name */
    uint32_t ntris;
    float aspect;
    srv_upload *next;
};

/* Makes the verification pipe (s->verifypipe; its read end non-blocking). */
pt_status srv_upload_open(srv_server *s, pt_error *err);

/* c's upload is complete: reserves the job id and starts its verification
 * (c is answered now only when it cannot start). */
void srv_upload_start(srv_server *s, srv_conn *c);

/* Completes each verification that is done (server/requests.h answers the
 * client); a client gone meanwhile gets nothing queued, its bundle removed. */
void srv_upload_collect(srv_server *s);

/* At exit: waits for the verifications in flight (none of them is queued)
 * and closes the pipe. */
void srv_upload_close(srv_server *s);

/* ---- workers.h ----------------------------------------------------------- */

/*
 * workers.h - what a connected, authenticated worker asks and sends.
 *
 * WORK_REQUEST adds free slots (capped at PROTO_MAX_SLOTS) that the queue
 * fills with tasks (server/queue.h); SCENE_GET is answered with a chunk of
 * the bundle of the active job with that hash; HEARTBEAT extends the
 * worker's leases; RESULT is decoded into s->scratch, validated against the
 * job's lease (srv_job_validate), logged durably (when there is a state
 * folder) and only then merged, so the results log holds every result the
 * film holds. A result that is malformed or inconsistent with its task is
 * the worker's fault (ERROR, closed); a late or duplicate one is dropped.
 *
 * Threads: called only from the event-loop thread.
 */

/* Serves one whole frame from a ready worker. */
void srv_workers_dispatch(srv_server *s, srv_conn *c, const proto_frame *f);

/* ---- requests.h ---------------------------------------------------------- */

/*
 * requests.h - what a connected, authenticated client (ptctl) asks.
 *
 * SUBMIT is checked against the caps (resolution, spp, scene size, the
 * unfinished jobs of one client name, the queue's size) and the job name
 * must be a plain name; UPLOAD chunks must continue the announced scene
 * exactly, and the buffer grows with what arrives, not with what was
 * announced. A complete upload goes to verification (server/upload.h); its
 * outcome comes back to srv_requests_verified, which queues the job (durable
 * before it is acknowledged with SUBMITTED) or refuses it. A client sends
 * nothing else until that answer. LIST, STATUS, WATCH (JOB_INFO now, then
 * every second and at the job's end), CANCEL and FETCH (the image file in
 * IMAGE chunks while the client's output has room) are served here. Images
 * are written only as ID-NAME.exr, NAME reduced to [A-Za-z0-9._-].
 *
 * Threads: called only from the event-loop thread.
 */

/* Serves one whole frame from a ready client. */
void srv_requests_dispatch(srv_server *s, srv_conn *c, const proto_frame *f);

/* Queues the job of a verified upload of c's, or sends c the refusal. */
void srv_requests_verified(srv_server *s, srv_conn *c, srv_upload *k);

/* Sends j's JOB_INFO to every client watching it (its end included). */
void srv_requests_notify_watchers(srv_server *s, const srv_entry *j);

/* Appends IMAGE frames of c's fetch in progress while c's output has room. */
void srv_requests_pump_fetch(srv_server *s, srv_conn *c);

/* JOB_INFO to each watcher whose last one is a second old; now in ms. */
void srv_requests_tick(srv_server *s, uint64_t now);

/* Frees c's upload buffer and ends its upload. */
void srv_requests_drop_upload(srv_conn *c);

/* c is being freed: logs an upload it left unfinished, frees its upload and
 * its fetch. */
void srv_requests_conn_gone(srv_conn *c);

/* ---- mode.h -------------------------------------------------------------- */

/*
 * mode.h - the coordinator's two modes, as data (srv_mode, server/core.h).
 *
 * One job (cfg->scene_path set): the scene is loaded once to refuse a broken
 * one before any worker starts, packed into a bundle and rendered to
 * cfg->out_path; no clients, no state folder; a progress line each second;
 * the loop ends when the image is complete, on a signal, or when every local
 * worker has exited first; the exit status is 0 (complete), 130
 * (interrupted) or 1.
 *
 * Queue (cfg->state_dir set): the queue is loaded from the state folder and
 * its running jobs resumed from their checkpoints and results logs; clients
 * fill it; each round's results are fdatasync'd after the leases are sent
 * (group commit) and complete jobs end at once; on a signal every running
 * job is checkpointed and its image saved, and the exit status is 0.
 *
 * Threads: called only from the event-loop thread.
 */

extern const srv_mode srv_mode_one_job;
extern const srv_mode srv_mode_queue;

/* The mode cfg asks for. */
const srv_mode *srv_mode_for(const srv_config *cfg);

/* ---- loop ---------------------------------------------------------------- */

#define MAX_CONNS 1024
#define IN_START (64u * 1024u)
#define OUT_MAX (256u << 20) /* a peer that lets this much pile up is dropped */
#define STALL_MS 30000       /* a partial frame or upload with no progress for this long */
#define CLOSE_GRACE_MS 1000  /* time to flush an ERROR before closing */

static volatile sig_atomic_t g_stop;
static int g_sigpipe_w = -1;

/* The payload length a frame header declares, read field by field in the
 * order of protocol/frame.h's table (frame.h has no accessor for it). The
 * decoder has already refused a header whose length is over the cap. */
static uint32_t frame_declared_len(const uint8_t *header)
{
    proto_reader r = proto_reader_make(header, PROTO_FRAME_HEADER);
    proto_r_bytes(&r, 4, "magic");
    proto_r_u16(&r, "version");
    proto_r_u16(&r, "type");
    return proto_r_u32(&r, "length");
}

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

int srv_conn_frame_open(srv_conn *c, uint16_t type, size_t *mark)
{
    return proto_frame_begin(&c->out, type, mark, NULL) == PT_OK;
}

int srv_conn_frame_close(srv_conn *c, size_t mark, pt_status encoded)
{
    if (encoded != PT_OK) {
        proto_frame_cancel(&c->out, mark);
        return 0;
    }
    return proto_frame_end(&c->out, mark, NULL) == PT_OK;
}

void srv_conn_close_soon(srv_server *s, srv_conn *c)
{
    if (!c->closing) {
        c->closing = 1;
        c->close_at = srv_now_ms() + CLOSE_GRACE_MS;
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
    srv_log("peer %s%s%s: %s; closing", c->peer, c->name[0] ? " " : "", c->name, m.text);
    size_t mark;
    if (srv_conn_frame_open(c, PROTO_MSG_ERROR, &mark))
        srv_conn_frame_close(c, mark, proto_msg_encode_error(&c->out, &m, NULL));
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
    pt_free(c->in);
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
        if (c)
            c->in = pt_malloc(IN_START);
        if (!c || !c->in) {
            if (c)
                pt_free(c);
            close(fd);
            continue;
        }
        c->fd = fd;
        c->id = ++s->next_conn_id;
        c->in_cap = IN_START;
        c->t_connect = c->t_progress = srv_now_ms();
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

static void on_hello(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_hello h;
    pt_error err = {0};
    if (proto_msg_decode_hello(f->payload, f->len, &h, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad HELLO: %s", err.msg);
        return;
    }
    snprintf(c->name, sizeof c->name, "%s", h.name);
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
    c->threads = h.threads;
    proto_challenge ch;
    if (proto_auth_nonce(ch.nonce, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "cannot make a nonce: %s", err.msg);
        return;
    }
    memcpy(c->nonce, ch.nonce, sizeof c->nonce);
    size_t mark;
    if (srv_conn_frame_open(c, PROTO_MSG_CHALLENGE, &mark))
        srv_conn_frame_close(c, mark, proto_msg_encode_challenge(&c->out, &ch, NULL));
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
    if (srv_conn_frame_open(c, PROTO_MSG_WELCOME, &mark))
        srv_conn_frame_close(c, mark, proto_msg_encode_welcome(&c->out, &w, NULL));
    c->state = SRV_C_READY;
    if (c->role == PROTO_ROLE_WORKER) {
        s->nworkers++;
        if (!s->cfg->quiet)
            srv_log("worker %s joined from %s (%u threads)", c->name, c->peer, c->threads);
    }
}

void srv_conn_peer_error(srv_server *s, srv_conn *c, const proto_frame *f, const char *who)
{
    proto_error_msg m;
    if (proto_msg_decode_error(f->payload, f->len, &m, NULL) == PT_OK)
        srv_log("%s %s reports: %s", who, c->name, m.text);
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

/* Decodes and dispatches the whole frames buffered in c->in, while the peer's
 * output is under the high-water mark (backpressure). */
static void conn_process(srv_server *s, srv_conn *c)
{
    size_t off = 0;
    while (!c->closing && srv_conn_has_room(c)) {
        proto_frame f;
        size_t used;
        pt_error err = {0};
        uint32_t cap = c->state == SRV_C_READY ? PROTO_MAX_PAYLOAD : PROTO_MAX_PAYLOAD_PREAUTH;
        pt_status st = proto_frame_decode(c->in + off, c->in_len - off, cap, &f, &used, &err);
        if (st == PT_AGAIN)
            break;
        if (st != PT_OK) {
            srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "%s", err.msg);
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

static void conn_read(srv_server *s, srv_conn *c)
{
    while (!c->closing && srv_conn_has_room(c)) {
        uint32_t cap = c->state == SRV_C_READY ? PROTO_MAX_PAYLOAD : PROTO_MAX_PAYLOAD_PREAUTH;
        /* Grow the input buffer to the declared frame (the decoder has already
         * refused a length over the cap once the header was present). */
        if (c->in_len >= PROTO_FRAME_HEADER) {
            size_t need = PROTO_FRAME_OVERHEAD + (size_t)frame_declared_len(c->in);
            if (need > c->in_cap && need <= PROTO_FRAME_OVERHEAD + (size_t)cap) {
                uint8_t *n = pt_realloc(c->in, need);
                if (!n) {
                    srv_conn_send_error(s, c, PROTO_E_LIMIT, "out of memory for a frame");
                    return;
                }
                c->in = n;
                c->in_cap = need;
            }
        }
        if (c->in_len == c->in_cap) {
            srv_conn_send_error(s, c, PROTO_E_LIMIT, "frame larger than the input buffer");
            return;
        }
        ssize_t r = recv(c->fd, c->in + c->in_len, c->in_cap - c->in_len, 0);
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
        c->in_len += (size_t)r;
        s->bytes_in += (uint64_t)r;
        c->t_progress = srv_now_ms();
        conn_process(s, c);
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
        else if ((c->in_len > 0 || c->uploading) && now - c->t_progress > STALL_MS)
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
    uint64_t now = srv_now_ms();
    for (srv_conn **pc = &s->conns; *pc;) {
        srv_conn *c = *pc;
        if (c->out.len > c->out_off)
            conn_flush(s, c);
        if (c->in_len > 0 && !c->closing)
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

/* ---- queue --------------------------------------------------------------- */

#define CKPT_MIN_LOG (16u << 20) /* checkpoint once a job's results log passes this */
#define MAX_FINISHED 1000        /* ended jobs kept in the queue's history */

int srv_entry_active(const srv_entry *j)
{
    return j->rec.state == PROTO_JOB_QUEUED || j->rec.state == PROTO_JOB_RUNNING;
}

srv_entry *srv_queue_find(srv_server *s, uint64_t id)
{
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->rec.id == id)
            return j;
    return NULL;
}

void srv_queue_insert(srv_server *s, srv_entry *j)
{
    srv_entry **p = &s->jobs;
    while (*p && ((*p)->rec.priority > j->rec.priority ||
                  ((*p)->rec.priority == j->rec.priority && (*p)->rec.id < j->rec.id)))
        p = &(*p)->next;
    j->next = *p;
    *p = j;
    s->njobs++;
}

static void free_run(srv_entry *j)
{
    srv_writer_free(j->writer);
    j->writer = NULL;
    srv_job_free(j->job);
    j->job = NULL;
    pt_bundle_free(j->bundle);
    j->bundle = NULL;
}

void srv_entry_free(srv_entry *j)
{
    if (!j)
        return;
    free_run(j);
    pt_free(j);
}

void srv_queue_prune(srv_server *s)
{
    uint32_t ended = 0;
    for (srv_entry *j = s->jobs; j; j = j->next)
        ended += !srv_entry_active(j);
    while (ended > MAX_FINISHED) {
        srv_entry **oldest = NULL;
        for (srv_entry **p = &s->jobs; *p; p = &(*p)->next)
            if (!srv_entry_active(*p) && (!oldest || (*p)->rec.id < (*oldest)->rec.id))
                oldest = p;
        srv_entry *j = *oldest;
        *oldest = j->next;
        srv_entry_free(j);
        s->njobs--;
        ended--;
    }
}

pt_status srv_queue_journal(srv_server *s, pt_error *err)
{
    if (!s->state)
        return PT_OK;
    srv_job_record **recs = pt_malloc_array(s->njobs ? s->njobs : 1, sizeof *recs);
    if (!recs)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    uint32_t n = 0;
    for (srv_entry *j = s->jobs; j; j = j->next)
        recs[n++] = &j->rec;
    pt_status st = srv_state_save_queue(s->state, recs, n, s->next_job_id, err);
    pt_free(recs);
    return st;
}

static void journal_or_log(srv_server *s)
{
    pt_error err = {0};
    if (srv_queue_journal(s, &err) != PT_OK)
        srv_log("error: cannot write the queue: %s", err.msg);
}

double srv_entry_seconds(const srv_entry *j, uint64_t now)
{
    if (!srv_entry_active(j))
        return j->rec.seconds;
    return j->seconds_before + (j->t_started ? (double)(now - j->t_started) / 1000.0 : 0.0);
}

static uint32_t job_workers(const srv_server *s, const srv_entry *j)
{
    uint32_t n = 0;
    if (!j->job)
        return 0;
    for (const srv_conn *c = s->conns; c; c = c->next)
        if (c->state == SRV_C_READY && c->role == PROTO_ROLE_WORKER &&
            srv_job_owner_active(j->job, c->id))
            n++;
    return n;
}

/* The estimated relative error of the job's image so far; -1 when unknown. */
static double job_error(const srv_job *job)
{
    const pt_film *f = srv_job_film(job);
    double e = pt_tile_rel_error(f->px, f->width, f->width, f->height);
    return isfinite(e) ? e : -1.0;
}

void srv_queue_info(const srv_server *s, const srv_entry *j, proto_job_info *m)
{
    uint64_t now = srv_now_ms();
    const srv_job_record *r = &j->rec;
    memset(m, 0, sizeof *m);
    m->job_id = r->id;
    m->state = r->state;
    m->priority = r->priority;
    snprintf(m->name, sizeof m->name, "%s", r->name);
    snprintf(m->owner, sizeof m->owner, "%s", r->owner);
    snprintf(m->scene, sizeof m->scene, "%s", r->scene);
    snprintf(m->output, sizeof m->output, "%s", r->output);
    m->width = r->params.width;
    m->height = r->params.height;
    m->spp = r->params.spp;
    m->samples_total = (uint64_t)r->params.width * r->params.height * r->params.spp;
    m->tiles = srv_job_params_tiles(&r->params);
    m->passes = srv_job_params_passes(&r->params);
    m->error = -1.0;
    if (j->job) {
        m->samples_done = srv_job_samples_merged(j->job);
        m->passes_done = srv_job_passes_done(j->job);
        m->tiles_stopped = srv_job_tiles_stopped(j->job);
        m->workers = job_workers(s, j);
        m->error = job_error(j->job);
    } else if (r->state == PROTO_JOB_DONE) {
        m->samples_done = r->samples_done;
        m->passes_done = m->passes;
        m->error = r->error;
    } else {
        m->samples_done = r->samples_done;
        m->error = r->samples_done ? r->error : -1.0;
    }
    m->seconds = srv_entry_seconds(j, now);
    m->rate = j->rate;
    m->submitted = r->submitted;
    if (r->state == PROTO_JOB_QUEUED) {
        uint32_t pos = 0;
        for (const srv_entry *q = s->jobs; q; q = q->next) {
            if (q->rec.state == PROTO_JOB_QUEUED)
                pos++;
            if (q == j)
                break;
        }
        m->queue_pos = pos;
    }
    snprintf(m->message, sizeof m->message, "%s", r->message);
}

void srv_entry_save_image(srv_entry *j)
{
    pt_image *img = NULL;
    const pt_film *film = srv_job_film(j->job);
    if (pt_image_new(film->width, film->height, &img, NULL) != PT_OK) {
        srv_log("out of memory for a progressive image of job %llu; will try again",
                (unsigned long long)j->rec.id);
        return;
    }
    pt_film_resolve(film, img);
    pt_exr_meta meta = {0};
    meta.total_samples = pt_film_total_samples(film);
    meta.render_seconds = srv_entry_seconds(j, srv_now_ms());
    pt_hash_hex(j->rec.hash, meta.scene_hash);
    snprintf(meta.job_id, sizeof meta.job_id, "%llu", (unsigned long long)j->rec.id);
    srv_writer_submit(j->writer, img, &meta);
    j->t_last_save = srv_now_ms();
    j->saved_passes = srv_job_passes_done(j->job);
    j->saved_samples = meta.total_samples;
}

void srv_entry_checkpoint(srv_server *s, srv_entry *j)
{
    if (!s->state || !j->job)
        return;
    srv_ckpt_extra x = {srv_entry_seconds(j, srv_now_ms()), j->rejected, j->rays};
    pt_error err = {0};
    if (srv_state_checkpoint(s->state, j->job, &x, &err) != PT_OK)
        srv_log("error: job %llu: cannot write its checkpoint: %s (its results log still holds "
                "every merged task)",
                (unsigned long long)j->rec.id, err.msg);
}

/* Tells every worker that job j ended before it was done, so each drops the
 * tasks of it that it has not started and its threads go to the next job at
 * once (their results would be dropped anyway). */
static void announce_job_end(srv_server *s, const srv_entry *j)
{
    proto_job_ref ref = {j->rec.id};
    for (srv_conn *c = s->conns; c; c = c->next) {
        if (c->role != PROTO_ROLE_WORKER || c->state != SRV_C_READY || c->closing)
            continue;
        size_t mark;
        if (srv_conn_frame_open(c, PROTO_MSG_JOB_END, &mark))
            srv_conn_frame_close(c, mark, proto_msg_encode_job_ref(&c->out, &ref, NULL));
        srv_conn_update_events(s, c);
    }
}

void srv_queue_end_job(srv_server *s, srv_entry *j, uint8_t state, const char *message)
{
    uint64_t now = srv_now_ms();
    pt_error err = {0};
    if (state == PROTO_JOB_DONE && j->job) {
        srv_entry_save_image(j);
        if (srv_writer_flush(j->writer, &err) != PT_OK) {
            state = PROTO_JOB_FAILED;
            char msg[PROTO_MAX_ERROR_TEXT + 1];
            snprintf(msg, sizeof msg, "cannot write the image: %s", err.msg);
            srv_queue_end_job(s, j, state, msg);
            return;
        }
    }
    j->rec.seconds = srv_entry_seconds(j, now);
    if (j->job) {
        j->rec.samples_done = srv_job_samples_merged(j->job);
        j->rec.error = job_error(j->job);
    }
    if (state != PROTO_JOB_DONE && j->t_started)
        announce_job_end(s, j);
    j->rec.state = state;
    snprintf(j->rec.message, sizeof j->rec.message, "%s", message ? message : "");
    free_run(j);
    pt_status st = srv_queue_journal(s, &err);
    if (st != PT_OK)
        srv_log("error: cannot write the queue: %s", err.msg);
    /* A failed job's files stay for the operator to look at; an ended one's
     * go once the queue says it ended. */
    if (s->state && state != PROTO_JOB_FAILED && st == PT_OK)
        srv_state_forget_job(s->state, j->rec.id);
    if (state == PROTO_JOB_DONE)
        srv_log("job %llu done: %llu samples in %.1f s; %s", (unsigned long long)j->rec.id,
                (unsigned long long)j->rec.samples_done, j->rec.seconds, j->out_path);
    else
        srv_log("job %llu %s%s%s", (unsigned long long)j->rec.id, proto_job_state_name(state),
                j->rec.message[0] ? ": " : "", j->rec.message);
    srv_requests_notify_watchers(s, j);
}

int srv_entry_ready(srv_server *s, srv_entry *j)
{
    if (j->job)
        return 1;
    pt_error err = {0};
    pt_status st = srv_job_new(j->rec.id, &j->rec.params, j->rec.hash, &j->job, &err);
    if (st == PT_OK && s->state) {
        srv_ckpt_extra x;
        uint32_t replayed;
        int torn;
        st = srv_state_restore(s->state, j->job, &x, &replayed, &torn, &err);
        if (st == PT_OK) {
            j->seconds_before = x.seconds;
            j->rejected = x.rejected;
            j->rays = x.rays;
            if (torn)
                srv_log("job %llu: dropped the incomplete last record of its results log (a "
                        "write cut short by a crash; it was never merged)",
                        (unsigned long long)j->rec.id);
            if (srv_job_tasks_merged(j->job) > 0)
                srv_log("job %llu resumed: %llu samples merged (%u from its results log)",
                        (unsigned long long)j->rec.id,
                        (unsigned long long)srv_job_samples_merged(j->job), replayed);
        }
    }
    if (st == PT_OK && !j->writer)
        st = srv_writer_new(j->out_path, &j->writer, &err);
    if (st != PT_OK) {
        char msg[PROTO_MAX_ERROR_TEXT + 1];
        snprintf(msg, sizeof msg, "%s", err.msg);
        srv_queue_end_job(s, j, PROTO_JOB_FAILED, msg);
        return 0;
    }
    j->saved_passes = srv_job_passes_done(j->job);
    j->saved_samples = srv_job_samples_merged(j->job);
    j->t_last_save = srv_now_ms();
    j->rate_t = srv_now_ms();
    j->rate_samples = j->saved_samples;
    return 1;
}

/* Leases the first task the queue has for owner: the first job in queue order
 * with a task to hand out, so when the running job has nothing left for an
 * idle worker (its last pass), the next job starts. */
static int lease_any(srv_server *s, uint64_t owner, uint64_t now, proto_task *t)
{
    for (srv_entry *j = s->jobs; j; j = j->next) {
        if (!srv_entry_active(j) || !srv_entry_ready(s, j))
            continue;
        if (!srv_job_lease(j->job, owner, now, s->cfg->lease_ms, t))
            continue;
        if (!j->t_started)
            j->t_started = now;
        if (j->rec.state == PROTO_JOB_QUEUED) {
            j->rec.state = PROTO_JOB_RUNNING;
            journal_or_log(s);
            if (s->mode->logs_starts)
                srv_log("job %llu started (%s, %ux%u, %u spp)", (unsigned long long)j->rec.id,
                        j->rec.scene, j->rec.params.width, j->rec.params.height, j->rec.params.spp);
        }
        return 1;
    }
    return 0;
}

void srv_queue_hand_out(srv_server *s)
{
    uint64_t now = srv_now_ms();
    int dry = 0; /* the queue had nothing to lease: skip the other workers */
    for (srv_conn *c = s->conns; c; c = c->next) {
        if (c->state != SRV_C_READY || c->closing)
            continue;
        if (c->fetch)
            srv_requests_pump_fetch(s, c);
        while (!dry && c->role == PROTO_ROLE_WORKER && c->want > 0 && srv_conn_has_room(c)) {
            proto_task t;
            if (!lease_any(s, c->id, now, &t)) {
                dry = 1;
                break;
            }
            size_t mark;
            if (!srv_conn_frame_open(c, PROTO_MSG_TASK, &mark) ||
                !srv_conn_frame_close(c, mark, proto_msg_encode_task(&c->out, &t, NULL))) {
                srv_conn_send_error(s, c, PROTO_E_LIMIT, "output buffer full");
                break;
            }
            c->want--;
        }
        srv_conn_update_events(s, c);
    }
}

void srv_queue_release_owner(srv_server *s, const srv_conn *c, int report)
{
    if (c->state != SRV_C_READY || c->role != PROTO_ROLE_WORKER)
        return;
    uint32_t n = 0;
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->job)
            n += srv_job_release_owner(j->job, c->id);
    if (n && report)
        srv_log("worker %s left; %u leased tasks requeued", c->name, n);
}

int srv_queue_end_complete(srv_server *s)
{
    int ended = 0;
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->job && srv_entry_active(j) && srv_job_complete(j->job)) {
            srv_queue_end_job(s, j, PROTO_JOB_DONE, NULL);
            ended++;
        }
    return ended;
}

void srv_queue_unlink(srv_server *s, srv_entry *j)
{
    for (srv_entry **q = &s->jobs; *q; q = &(*q)->next)
        if (*q == j) {
            *q = j->next;
            s->njobs--;
            return;
        }
}

srv_entry *srv_queue_find_scene(srv_server *s, const uint8_t hash[32])
{
    pt_error err = {0};
    srv_entry *j = s->jobs;
    while (j && !(srv_entry_active(j) && memcmp(hash, j->rec.hash, 32) == 0))
        j = j->next;
    if (j && !j->bundle && s->state &&
        srv_state_load_bundle(s->state, j->rec.id, j->rec.hash, &j->bundle, &err) != PT_OK) {
        char msg[PROTO_MAX_ERROR_TEXT + 1];
        snprintf(msg, sizeof msg, "%s", err.msg);
        srv_queue_end_job(s, j, PROTO_JOB_FAILED, msg);
        j = NULL;
    }
    return j && j->bundle ? j : NULL;
}

pt_status srv_queue_log_result(srv_server *s, const srv_entry *j, const uint8_t *payload,
                               size_t len, pt_error *err)
{
    if (!s->state)
        return PT_OK;
    return srv_state_log_result(s->state, j->rec.id, payload, len, err);
}

void srv_queue_expire(srv_server *s, uint64_t now)
{
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->job && srv_entry_active(j) && srv_job_expire(j->job, now, NULL) > 0)
            srv_log("job %llu: leases expired; tasks requeued", (unsigned long long)j->rec.id);
}

void srv_queue_tick(srv_server *s, uint64_t now)
{
    for (srv_entry *j = s->jobs; j; j = j->next) {
        if (!j->job || !srv_entry_active(j))
            continue;
        uint64_t merged = srv_job_samples_merged(j->job);
        int pass_done = srv_job_passes_done(j->job) > j->saved_passes;
        if ((pass_done || merged > j->saved_samples) &&
            (double)(now - j->t_last_save) >= s->cfg->save_interval * 1000.0 &&
            !srv_job_complete(j->job))
            srv_entry_save_image(j);
        if (now - j->rate_t >= 1000) {
            j->rate = (double)(merged - j->rate_samples) * 1000.0 / (double)(now - j->rate_t);
            j->rate_t = now;
            j->rate_samples = merged;
        }
        /* Checkpoint cost stays proportional to what the log has taken in. */
        if (s->state) {
            const pt_film *f = srv_job_film(j->job);
            uint64_t film_bytes = (uint64_t)f->width * f->height * PROTO_RESULT_PIXEL_SIZE;
            uint64_t limit = film_bytes > CKPT_MIN_LOG ? film_bytes : CKPT_MIN_LOG;
            if (srv_state_log_bytes(s->state, j->rec.id) >= limit)
                srv_entry_checkpoint(s, j);
        }
    }
}

void srv_queue_free(srv_server *s)
{
    while (s->jobs) {
        srv_entry *j = s->jobs;
        s->jobs = j->next;
        srv_entry_free(j);
    }
    s->njobs = 0;
    s->single = NULL;
    srv_state_close(s->state);
    s->state = NULL;
}

/* ---- upload -------------------------------------------------------------- */

static void verify_refuse(srv_upload *k, uint16_t code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
static void verify_refuse(srv_upload *k, uint16_t code, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(k->msg, sizeof k->msg, fmt, ap);
    va_end(ap);
    k->code = code;
    k->ok = 0;
}

/* The verification itself, on its own thread: touches nothing of the server's. */
static void verify_upload(srv_upload *k)
{
    pt_error err = {0};
    char hex[65], want[65];
    pt_sha256_hex(k->data, k->len, hex);
    pt_hash_hex(k->m.bundle_hash, want);
    if (strcmp(hex, want) != 0) {
        verify_refuse(k, PROTO_E_PROTOCOL,
                      "the scene's SHA-256 is %.16s..., not the %.16s... "
                      "SUBMIT announced",
                      hex, want);
        return;
    }
    pt_status st = pt_bundle_from_bytes(k->data, k->len, &k->bundle, &err);
    pt_free(k->data);
    k->data = NULL;
    if (st != PT_OK) {
        verify_refuse(k, PROTO_E_PROTOCOL, "bad scene bundle: %s", err.msg);
        return;
    }
    char entry[PATH_MAX];
    pt_remove_tree(k->tmp);
    pt_scene *scene = NULL;
    st = pt_bundle_unpack(k->bundle, k->tmp, entry, sizeof entry, &err);
    if (st == PT_OK) {
        pt_scene_opts so = {0};
        so.camera_name = k->m.camera[0] ? k->m.camera : NULL;
        st = pt_scene_load(entry, &so, &scene, &err);
    }
    pt_remove_tree(k->tmp);
    if (st != PT_OK) {
        /* The path is our temp folder's: name the file inside the bundle instead. */
        const char *msg = err.msg;
        size_t tl = strlen(k->tmp);
        if (strncmp(msg, k->tmp, tl) == 0 && msg[tl] == '/')
            msg += tl + 1;
        verify_refuse(k, st == PT_ERR_NOMEM ? PROTO_E_INTERNAL : PROTO_E_PROTOCOL,
                      "scene refused: %s", msg);
        return;
    }
    const char *base = strrchr(entry, '/');
    snprintf(k->scene, sizeof k->scene, "%.255s", base ? base + 1 : entry);
    k->ntris = scene->num_triangles;
    k->aspect = scene->camera.aspect;
    pt_scene_free(scene);
    st = srv_state_save_bundle(k->state, k->job_id, k->bundle->data, k->bundle->size, &err);
    if (st != PT_OK) {
        verify_refuse(k, PROTO_E_INTERNAL, "cannot store the scene: %s", err.msg);
        return;
    }
    k->ok = 1;
}

static void *verify_thread(void *arg)
{
    srv_upload *k = arg;
    verify_upload(k);
    /* A blocking write of a pointer: atomic (under PIPE_BUF), never lost. */
    ssize_t r = write(k->wake_fd, &k, sizeof k);
    (void)r;
    return NULL;
}

static void upload_free(srv_upload *k)
{
    pt_free(k->data);
    pt_bundle_free(k->bundle);
    pt_free(k);
}

void srv_upload_start(srv_server *s, srv_conn *c)
{
    srv_upload *k = pt_calloc(1, sizeof *k);
    if (!k) {
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "out of memory");
        return;
    }
    k->conn_id = c->id;
    k->job_id = s->next_job_id++;
    k->m = c->up;
    k->data = c->up_buf;
    k->len = c->up_len;
    c->up_buf = NULL;
    srv_requests_drop_upload(c);
    k->state = s->state;
    snprintf(k->tmp, sizeof k->tmp, "%s/tmp/upload-%llu", srv_state_dir(s->state),
             (unsigned long long)k->job_id);
    k->wake_fd = s->verifypipe[1];
    if (pthread_create(&k->thread, NULL, verify_thread, k) != 0) {
        upload_free(k);
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "cannot start checking the scene");
        return;
    }
    k->next = s->verifications;
    s->verifications = k;
    c->verifying = 1;
}

void srv_upload_collect(srv_server *s)
{
    srv_upload *k;
    while (read(s->verifypipe[0], &k, sizeof k) == (ssize_t)sizeof k) {
        pthread_join(k->thread, NULL);
        for (srv_upload **q = &s->verifications; *q; q = &(*q)->next)
            if (*q == k) {
                *q = k->next;
                break;
            }
        srv_conn *c = srv_conn_find(s, k->conn_id);
        if (c) {
            srv_requests_verified(s, c, k);
        } else {
            if (k->ok)
                srv_state_forget_job(s->state, k->job_id);
            srv_log("a client left before its scene was checked; nothing was queued");
        }
        upload_free(k);
    }
}

void srv_upload_close(srv_server *s)
{
    while (s->verifications) {
        srv_upload *k = s->verifications;
        s->verifications = k->next;
        pthread_join(k->thread, NULL);
        if (k->ok)
            srv_state_forget_job(s->state, k->job_id);
        upload_free(k);
    }
    for (int i = 0; i < 2; i++)
        if (s->verifypipe[i] >= 0)
            close(s->verifypipe[i]);
    s->verifypipe[0] = s->verifypipe[1] = -1;
}

pt_status srv_upload_open(srv_server *s, pt_error *err)
{
    /* The threads' end blocks (a pointer is never lost); the loop's does not. */
    if (pipe2(s->verifypipe, O_CLOEXEC) != 0 ||
        fcntl(s->verifypipe[0], F_SETFL, fcntl(s->verifypipe[0], F_GETFL) | O_NONBLOCK) != 0)
        return pt_error_errno(err, PT_ERR_IO, "pipe2");
    return PT_OK;
}

/* ---- workers ------------------------------------------------------------- */

static void on_scene_get(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_scene_get g;
    pt_error err = {0};
    if (proto_msg_decode_scene_get(f->payload, f->len, &g, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad SCENE_GET: %s", err.msg);
        return;
    }
    srv_entry *j = srv_queue_find_scene(s, g.hash);
    if (!j) {
        srv_conn_send_error(s, c, PROTO_E_NOT_FOUND, "no scene with that hash");
        return;
    }
    const pt_bundle *b = j->bundle;
    if (g.offset > b->size) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "scene offset %llu is past its end (%zu)",
                            (unsigned long long)g.offset, b->size);
        return;
    }
    proto_scene_chunk ch;
    memcpy(ch.hash, j->rec.hash, 32);
    ch.offset = g.offset;
    ch.total = b->size;
    size_t left = b->size - (size_t)g.offset;
    ch.len = (uint32_t)(left < PROTO_MAX_SCENE_CHUNK ? left : PROTO_MAX_SCENE_CHUNK);
    ch.data = b->data + g.offset;
    size_t mark;
    if (!srv_conn_frame_open(c, PROTO_MSG_SCENE_CHUNK, &mark) ||
        !srv_conn_frame_close(c, mark, proto_msg_encode_scene_chunk(&c->out, &ch, NULL)))
        srv_conn_send_error(s, c, PROTO_E_LIMIT, "output buffer full");
}

static void on_result(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_result r;
    pt_error err = {0};
    if (proto_msg_decode_result(f->payload, f->len, s->scratch, PROTO_MAX_TILE_PIXELS, &r, &err) !=
        PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad RESULT: %s", err.msg);
        return;
    }
    srv_entry *j = srv_queue_find(s, r.job_id);
    if (!j || !srv_entry_active(j) || !j->job) {
        proto_result_fini(&r); /* a job that ended (cancelled): nothing to do */
        return;
    }
    int lease_index;
    srv_outcome o = srv_job_validate(j->job, c->id, &r, &lease_index, &err);
    /* Durable before merged: the log holds every result the film holds. */
    if (o == SRV_MERGED && srv_queue_log_result(s, j, f->payload, f->len, &err) != PT_OK) {
        srv_log("error: job %llu: %s; result dropped (its task will be rendered again)",
                (unsigned long long)j->rec.id, err.msg);
        proto_result_fini(&r);
        return;
    }
    if (o == SRV_MERGED)
        o = srv_job_result_validated(j->job, lease_index, &r, &err);
    switch (o) {
    case SRV_MERGED:
        j->rejected += r.rejected;
        j->rays += r.rays;
        break;
    case SRV_DUPLICATE:
        break;
    case SRV_NOT_LEASED:
        srv_log("worker %s: %s; dropped", c->name, err.msg);
        break;
    case SRV_INVALID:
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "%s", err.msg);
        break;
    }
    proto_result_fini(&r);
}

static void on_heartbeat(srv_server *s, srv_conn *c, const proto_frame *f)
{
    static proto_heartbeat hb; /* large; the loop is single-threaded */
    pt_error err = {0};
    if (proto_msg_decode_heartbeat(f->payload, f->len, &hb, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad HEARTBEAT: %s", err.msg);
        return;
    }
    uint64_t now = srv_now_ms();
    /* Task ids are per job; extending only leases this owner holds is safe
     * even when two of its jobs share an id. */
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->job && srv_entry_active(j))
            for (uint32_t i = 0; i < hb.count; i++)
                srv_job_heartbeat(j->job, c->id, hb.task_ids[i], now, s->cfg->lease_ms);
}

void srv_workers_dispatch(srv_server *s, srv_conn *c, const proto_frame *f)
{
    switch (f->type) {
    case PROTO_MSG_WORK_REQUEST: {
        proto_work_request w;
        pt_error err = {0};
        if (proto_msg_decode_work_request(f->payload, f->len, &w, &err) != PT_OK) {
            srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad WORK_REQUEST: %s", err.msg);
            return;
        }
        c->want += w.slots;
        if (c->want > PROTO_MAX_SLOTS)
            c->want = PROTO_MAX_SLOTS;
        break;
    }
    case PROTO_MSG_SCENE_GET:
        on_scene_get(s, c, f);
        break;
    case PROTO_MSG_RESULT:
        on_result(s, c, f);
        break;
    case PROTO_MSG_HEARTBEAT:
        on_heartbeat(s, c, f);
        break;
    case PROTO_MSG_ERROR:
        srv_conn_peer_error(s, c, f, "worker");
        break;
    default:
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "unexpected %s from a worker",
                            proto_msg_type_name(f->type));
    }
}

/* ---- requests ------------------------------------------------------------ */

#define WATCH_MS 1000 /* JOB_INFO to watchers this often */
#define MAX_FETCH ((size_t)4 << 30)

static void send_job_info(srv_server *s, srv_conn *c, const srv_entry *j)
{
    proto_job_info m;
    srv_queue_info(s, j, &m);
    size_t mark;
    if (srv_conn_frame_open(c, PROTO_MSG_JOB_INFO, &mark))
        srv_conn_frame_close(c, mark, proto_msg_encode_job_info(&c->out, &m, NULL));
    c->watch_t = srv_now_ms();
    if (!srv_entry_active(j) && c->watch == j->rec.id)
        c->watch = 0;
}

void srv_requests_notify_watchers(srv_server *s, const srv_entry *j)
{
    for (srv_conn *c = s->conns; c; c = c->next)
        if (c->watch == j->rec.id && !c->closing)
            send_job_info(s, c, j);
}

void srv_requests_pump_fetch(srv_server *s, srv_conn *c)
{
    while (c->fetch && !c->closing && srv_conn_has_room(c)) {
        proto_scene_chunk ch;
        memcpy(ch.hash, c->fetch_hash, 32);
        ch.offset = c->fetch_off;
        ch.total = c->fetch_len;
        size_t left = c->fetch_len - c->fetch_off;
        ch.len = (uint32_t)(left < PROTO_MAX_SCENE_CHUNK ? left : PROTO_MAX_SCENE_CHUNK);
        ch.data = c->fetch + c->fetch_off;
        size_t mark;
        if (!srv_conn_frame_open(c, PROTO_MSG_IMAGE, &mark) ||
            !srv_conn_frame_close(c, mark, proto_msg_encode_scene_chunk(&c->out, &ch, NULL))) {
            srv_conn_send_error(s, c, PROTO_E_LIMIT, "output buffer full");
            break;
        }
        c->fetch_off += ch.len;
        if (c->fetch_off == c->fetch_len) {
            pt_free(c->fetch);
            c->fetch = NULL;
        }
    }
}

/* A file name from untrusted text: [A-Za-z0-9._-] kept, the rest '_', no
 * leading dot, at most 64 characters; "job" when nothing is left. */
static void sanitise(const char *in, char *out, size_t cap)
{
    size_t n = 0;
    for (const char *p = in; *p && n + 1 < cap && n < 64; p++) {
        char ch = *p;
        int ok = (ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9') ||
                 ch == '-' || ch == '_' || (ch == '.' && n > 0);
        out[n++] = ok ? ch : '_';
    }
    out[n] = '\0';
    if (n == 0)
        snprintf(out, cap, "job");
}

static uint32_t owner_unfinished(const srv_server *s, const char *owner)
{
    uint32_t n = 0;
    for (const srv_entry *j = s->jobs; j; j = j->next)
        n += srv_entry_active(j) && strcmp(j->rec.owner, owner) == 0;
    return n;
}

static void on_submit(srv_server *s, srv_conn *c, const proto_frame *f)
{
    pt_error err = {0};
    proto_submit m;
    if (c->uploading) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "SUBMIT during an upload");
        return;
    }
    if (proto_msg_decode_submit(f->payload, f->len, &m, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad SUBMIT: %s", err.msg);
        return;
    }
    if (strchr(m.name, '/') || strchr(m.name, '\\') || m.name[0] == '.' || strstr(m.name, "..")) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL,
                            "job name '%s' is not a plain name (no '/', "
                            "'\\', '..' or leading '.')",
                            m.name);
        return;
    }
    for (const char *p = m.name; *p; p++)
        if ((unsigned char)*p < 0x20 || *p == 0x7f) {
            srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "job name has control characters");
            return;
        }
    const srv_caps *cap = &s->cfg->caps;
    if (m.bundle_size > cap->max_scene) {
        srv_conn_send_error(s, c, PROTO_E_LIMIT,
                            "scene of %llu bytes is over this server's limit "
                            "of %llu",
                            (unsigned long long)m.bundle_size, (unsigned long long)cap->max_scene);
        return;
    }
    if (m.spp > cap->max_spp) {
        srv_conn_send_error(s, c, PROTO_E_LIMIT,
                            "%u samples per pixel is over this server's limit "
                            "of %u",
                            m.spp, cap->max_spp);
        return;
    }
    if (m.width > cap->max_side || m.height > cap->max_side ||
        (uint64_t)m.width * m.height > cap->max_pixels) {
        srv_conn_send_error(s, c, PROTO_E_LIMIT,
                            "resolution %ux%u is over this server's limit (%u "
                            "per side, %llu pixels)",
                            m.width, m.height, cap->max_side, (unsigned long long)cap->max_pixels);
        return;
    }
    if (m.max_depth > 1024 || (m.min_spp && m.min_spp < 2) || m.min_spp > m.spp) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "max depth %u or min spp %u is out of range",
                            m.max_depth, m.min_spp);
        return;
    }
    if (m.target_error > 0.0 && m.min_gain > 0.0) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL,
                            "target error and min gain are two adaptive "
                            "rules; a job takes one");
        return;
    }
    if (owner_unfinished(s, c->name) >= cap->max_queued) {
        srv_conn_send_error(s, c, PROTO_E_LIMIT,
                            "%s already has %u unfinished jobs, this "
                            "server's limit",
                            c->name, cap->max_queued);
        return;
    }
    if (s->njobs >= SRV_MAX_JOBS) {
        srv_conn_send_error(s, c, PROTO_E_LIMIT, "the queue is full (%u jobs)", SRV_MAX_JOBS);
        return;
    }
    c->up = m;
    c->uploading = 1;
    c->up_len = 0;
    c->t_progress = srv_now_ms();
}

void srv_requests_drop_upload(srv_conn *c)
{
    pt_free(c->up_buf);
    c->up_buf = NULL;
    c->up_len = c->up_cap = 0;
    c->uploading = 0;
}

void srv_requests_verified(srv_server *s, srv_conn *c, srv_upload *k)
{
    pt_error err = {0};
    pt_status st;
    const proto_submit *m = &k->m;
    c->verifying = 0;
    if (!k->ok) {
        srv_conn_send_error(s, c, k->code, "%s", k->msg);
        return;
    }
    pt_bundle *b = k->bundle;
    k->bundle = NULL;
    srv_entry *j = pt_calloc(1, sizeof *j);
    if (!j) {
        pt_bundle_free(b);
        srv_state_forget_job(s->state, k->job_id);
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "out of memory");
        return;
    }
    srv_job_record *r = &j->rec;
    r->id = r->seq = k->job_id;
    r->state = PROTO_JOB_QUEUED;
    r->error = -1.0;
    r->priority = m->priority;
    snprintf(r->name, sizeof r->name, "%s", m->name);
    snprintf(r->owner, sizeof r->owner, "%s", c->name);
    snprintf(r->scene, sizeof r->scene, "%s", k->scene);
    r->submitted = (uint64_t)time(NULL);
    srv_job_params p = s->cfg->job;
    p.spp = m->spp;
    p.seed = m->seed;
    if (m->max_depth)
        p.max_depth = m->max_depth;
    p.target_error = m->target_error;
    p.min_gain = m->min_gain;
    p.min_spp = m->min_spp ? m->min_spp : (p.chunk > 1 ? p.chunk : 2);
    p.width = m->width;
    p.height = m->height;
    snprintf(p.camera, sizeof p.camera, "%s", m->camera);
    if (p.width == 0) {
        float aspect = k->aspect > 0 ? k->aspect : 1.0f;
        p.width = 512;
        p.height = (uint32_t)(512.0f / aspect + 0.5f);
        if (p.height == 0)
            p.height = 1;
        if (p.height > s->cfg->caps.max_side)
            p.height = s->cfg->caps.max_side;
    }
    uint32_t ntris = k->ntris;
    r->params = p;
    memcpy(r->hash, m->bundle_hash, 32);
    r->bundle_size = b->size;
    char stem[PROTO_MAX_PATH + 1], safe[80];
    snprintf(stem, sizeof stem, "%s", r->name[0] ? r->name : r->scene);
    char *dot = strrchr(stem, '.');
    if (!r->name[0] && dot && dot != stem)
        *dot = '\0';
    sanitise(stem, safe, sizeof safe);
    snprintf(r->output, sizeof r->output, "%llu-%s.exr", (unsigned long long)r->id, safe);
    snprintf(j->out_path, sizeof j->out_path, "%s/%s", s->out_dir, r->output);
    srv_job *probe = NULL;
    if ((st = srv_job_new(r->id, &p, r->hash, &probe, &err)) != PT_OK) {
        pt_free(j);
        pt_bundle_free(b);
        srv_state_forget_job(s->state, k->job_id);
        srv_conn_send_error(s, c, PROTO_E_LIMIT, "%s", err.msg);
        return;
    }
    srv_job_free(probe);
    j->bundle = b;
    srv_queue_insert(s, j);
    srv_queue_prune(s);
    if (srv_queue_journal(s, &err) != PT_OK) {
        /* Not durable, so not accepted. */
        srv_queue_unlink(s, j);
        srv_state_forget_job(s->state, r->id);
        srv_entry_free(j);
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "cannot write the queue: %s", err.msg);
        return;
    }
    srv_log("job %llu queued from %s: %s (%u triangles), %ux%u, %u spp, priority %d",
            (unsigned long long)r->id, c->name, r->scene, ntris, p.width, p.height, p.spp,
            r->priority);
    proto_job_ref ref = {r->id};
    size_t mark;
    if (srv_conn_frame_open(c, PROTO_MSG_SUBMITTED, &mark))
        srv_conn_frame_close(c, mark, proto_msg_encode_job_ref(&c->out, &ref, NULL));
}

static void on_upload(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_scene_chunk ch;
    pt_error err = {0};
    if (!c->uploading) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "UPLOAD without a SUBMIT");
        return;
    }
    if (proto_msg_decode_scene_chunk(f->payload, f->len, &ch, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad UPLOAD: %s", err.msg);
        return;
    }
    if (memcmp(ch.hash, c->up.bundle_hash, 32) != 0 || ch.total != c->up.bundle_size ||
        ch.offset != c->up_len || ch.len == 0) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL,
                            "UPLOAD of %u bytes at %llu of %llu does not "
                            "continue the announced scene (%zu of %llu bytes so far)",
                            ch.len, (unsigned long long)ch.offset, (unsigned long long)ch.total,
                            c->up_len, (unsigned long long)c->up.bundle_size);
        return;
    }
    /* Grow with what arrives, not with what was announced. */
    if (c->up_len + ch.len > c->up_cap) {
        size_t cap = c->up_cap ? c->up_cap : (1u << 20);
        while (cap < c->up_len + ch.len)
            cap *= 2;
        if (cap > c->up.bundle_size)
            cap = (size_t)c->up.bundle_size;
        uint8_t *n = pt_realloc(c->up_buf, cap);
        if (!n) {
            srv_conn_send_error(s, c, PROTO_E_INTERNAL, "out of memory for the scene");
            return;
        }
        c->up_buf = n;
        c->up_cap = cap;
    }
    memcpy(c->up_buf + c->up_len, ch.data, ch.len);
    c->up_len += ch.len;
    if (c->up_len == c->up.bundle_size)
        srv_upload_start(s, c);
}

static int read_job_ref(srv_server *s, srv_conn *c, const proto_frame *f, srv_entry **out)
{
    proto_job_ref ref;
    pt_error err = {0};
    if (proto_msg_decode_job_ref(f->payload, f->len, &ref, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad %s: %s", proto_msg_type_name(f->type),
                            err.msg);
        return 0;
    }
    *out = srv_queue_find(s, ref.job_id);
    if (!*out) {
        srv_conn_send_error(s, c, PROTO_E_NOT_FOUND, "no job %llu", (unsigned long long)ref.job_id);
        return 0;
    }
    return 1;
}

static void on_list(srv_server *s, srv_conn *c, const proto_frame *f)
{
    if (f->len != 0) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad LIST: trailing bytes");
        return;
    }
    uint32_t n = s->njobs < PROTO_MAX_JOBS ? s->njobs : PROTO_MAX_JOBS;
    proto_job_info *infos = pt_malloc_array(n ? n : 1, sizeof *infos);
    if (!infos) {
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "out of memory");
        return;
    }
    uint32_t k = 0;
    for (srv_entry *j = s->jobs; j && k < n; j = j->next)
        srv_queue_info(s, j, &infos[k++]);
    size_t mark;
    if (!srv_conn_frame_open(c, PROTO_MSG_JOB_LIST, &mark) ||
        !srv_conn_frame_close(c, mark, proto_msg_encode_job_list(&c->out, infos, k, NULL)))
        srv_conn_send_error(s, c, PROTO_E_LIMIT, "output buffer full");
    pt_free(infos);
}

static void on_fetch(srv_server *s, srv_conn *c, srv_entry *j)
{
    pt_error err = {0};
    if (c->fetch) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "FETCH while a fetch is in progress");
        return;
    }
    uint8_t *data;
    size_t len;
    if (pt_read_file(j->out_path, MAX_FETCH, &data, &len, &err) != PT_OK) {
        if (err.sys_errno == ENOENT)
            srv_conn_send_error(s, c, PROTO_E_NOT_FOUND, "job %llu has no image yet (%s)",
                                (unsigned long long)j->rec.id, proto_job_state_name(j->rec.state));
        else
            srv_conn_send_error(s, c, PROTO_E_INTERNAL, "%s", err.msg);
        return;
    }
    if (len == 0) {
        pt_free(data);
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "job %llu: its image file is empty",
                            (unsigned long long)j->rec.id);
        return;
    }
    char hex[65];
    pt_sha256_hex(data, len, hex);
    pt_hex_decode(hex, c->fetch_hash, 32);
    c->fetch = data;
    c->fetch_len = len;
    c->fetch_off = 0;
    srv_requests_pump_fetch(s, c);
}

void srv_requests_dispatch(srv_server *s, srv_conn *c, const proto_frame *f)
{
    srv_entry *j;
    if (c->verifying) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "%s before the answer to its SUBMIT",
                            proto_msg_type_name(f->type));
        return;
    }
    switch (f->type) {
    case PROTO_MSG_SUBMIT:
        on_submit(s, c, f);
        break;
    case PROTO_MSG_UPLOAD:
        on_upload(s, c, f);
        break;
    case PROTO_MSG_LIST:
        on_list(s, c, f);
        break;
    case PROTO_MSG_STATUS:
        if (read_job_ref(s, c, f, &j))
            send_job_info(s, c, j);
        break;
    case PROTO_MSG_WATCH:
        if (read_job_ref(s, c, f, &j)) {
            c->watch = j->rec.id;
            send_job_info(s, c, j);
        }
        break;
    case PROTO_MSG_CANCEL:
        if (read_job_ref(s, c, f, &j)) {
            if (srv_entry_active(j)) {
                char msg[PROTO_MAX_ERROR_TEXT + 1];
                snprintf(msg, sizeof msg, "cancelled by %s", c->name);
                srv_queue_end_job(s, j, PROTO_JOB_CANCELLED, msg);
            }
            send_job_info(s, c, j);
        }
        break;
    case PROTO_MSG_FETCH:
        if (read_job_ref(s, c, f, &j))
            on_fetch(s, c, j);
        break;
    case PROTO_MSG_ERROR:
        srv_conn_peer_error(s, c, f, "client");
        break;
    default:
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "unexpected %s from a client",
                            proto_msg_type_name(f->type));
    }
}

void srv_requests_tick(srv_server *s, uint64_t now)
{
    for (srv_conn *c = s->conns; c; c = c->next) {
        if (c->closing || !c->watch || now - c->watch_t < WATCH_MS)
            continue;
        srv_entry *j = srv_queue_find(s, c->watch);
        if (j)
            send_job_info(s, c, j);
        else
            c->watch = 0;
    }
}

void srv_requests_conn_gone(srv_conn *c)
{
    if (c->uploading)
        srv_log("client %s left during an upload (%zu of %llu bytes); nothing was queued", c->name,
                c->up_len, (unsigned long long)c->up.bundle_size);
    srv_requests_drop_upload(c);
    pt_free(c->fetch);
    c->fetch = NULL;
}

/* ---- mode ---------------------------------------------------------------- */

/* ---- one job ----------------------------------------------------------------------- */

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

static void print_progress(srv_server *s, uint64_t now)
{
    const srv_entry *j = s->single;
    const srv_job_params *p = &j->rec.params;
    double el = (double)(now - s->t_start) / 1000.0;
    uint64_t done = srv_job_samples_merged(j->job);
    double total = (double)p->width * p->height * p->spp;
    double rate = el > 0 ? (double)done / el : 0;
    char eta[32];
    format_eta(rate > 0 ? (total - (double)done) / rate : -1, eta, sizeof eta);
    fprintf(stderr, "\rptserve: pass %u/%u  %.1f/%u spp  %.3g samples/s  %u workers  ETA %s\033[K",
            srv_job_passes_done(j->job), srv_job_passes(j->job),
            (double)done / ((double)p->width * p->height), p->spp, rate, s->nworkers, eta);
}

static pt_status setup_single(srv_server *s, pt_error *err)
{
    const srv_config *cfg = s->cfg;
    pt_status st;
    /* Load once here so a broken scene fails before any worker starts. */
    pt_scene_opts so = {0};
    so.camera_name = cfg->job.camera[0] ? cfg->job.camera : NULL;
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
    srv_entry *j = pt_calloc(1, sizeof *j);
    if (!j)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    srv_queue_insert(s, j);
    s->single = j;
    if ((st = pt_bundle_pack(cfg->scene_path, &j->bundle, err)) != PT_OK)
        return st;
    j->rec.id = j->rec.seq = 1;
    j->rec.state = PROTO_JOB_QUEUED;
    j->rec.error = -1.0;
    j->rec.params = jp;
    pt_hex_decode(j->bundle->hash, j->rec.hash, 32);
    const char *base = strrchr(cfg->scene_path, '/');
    snprintf(j->rec.scene, sizeof j->rec.scene, "%s", base ? base + 1 : cfg->scene_path);
    snprintf(j->out_path, sizeof j->out_path, "%s", cfg->out_path);
    if (!srv_entry_ready(s, j))
        return pt_error_set(err, PT_ERR_IO, "%s", j->rec.message);
    if (!cfg->quiet)
        srv_log("%s: %u triangles, %ux%u, %u spp in %u passes of %u, tiles of %u", cfg->scene_path,
                ntris, jp.width, jp.height, jp.spp, srv_job_passes(j->job), jp.chunk, jp.tile);
    return PT_OK;
}

/* The final image and the summary. Returns the exit status. */
static int finish_single(srv_server *s)
{
    const srv_config *cfg = s->cfg;
    srv_entry *j = s->single;
    pt_error err = {0};
    if (!j->job)
        return 1;
    srv_entry_save_image(j);
    pt_status st = srv_writer_flush(j->writer, &err);
    if (!cfg->quiet)
        print_progress(s, srv_now_ms());
    fputc('\n', stderr);
    double secs = (double)(srv_now_ms() - s->t_start) / 1000.0;
    uint64_t samples = srv_job_samples_merged(j->job);
    const srv_job_params *p = &j->rec.params;
    if (st != PT_OK) {
        fprintf(stderr, "ptserve: cannot write %s: %s\n", cfg->out_path, err.msg);
        return 1;
    }
    if (srv_job_complete(j->job)) {
        uint64_t tasks = srv_job_tasks_total(j->job);
        fprintf(stderr,
                "ptserve: done in %.2fs: %llu samples (%.4g samples/s), %llu rejected "
                "samples (NaN/Inf); wrote %s\n",
                secs, (unsigned long long)samples, (double)samples / secs,
                (unsigned long long)j->rejected, cfg->out_path);
        fprintf(stderr,
                "ptserve: wire: %llu bytes in, %llu out (scene %zu); %.3f bytes per "
                "sample, %.0f per task\n",
                (unsigned long long)s->bytes_in, (unsigned long long)s->bytes_out,
                j->bundle ? j->bundle->size : 0,
                (double)(s->bytes_in + s->bytes_out) / (double)samples,
                (double)(s->bytes_in + s->bytes_out) / (double)tasks);
        return 0;
    }
    if (srv_loop_stopped()) {
        fprintf(stderr, "ptserve: interrupted after %.2fs; %s holds %llu of %llu samples\n", secs,
                cfg->out_path, (unsigned long long)samples,
                (unsigned long long)p->width * p->height * p->spp);
        return 130;
    }
    return 1;
}

static int single_over(const srv_server *s)
{
    return !s->single->job || srv_job_complete(s->single->job);
}

static void single_after_leases(srv_server *s)
{
    (void)s; /* nothing is durable, and the loop ends with the job */
}

static void single_tick(srv_server *s, uint64_t now)
{
    if (s->single->job && !s->cfg->quiet && now - s->t_last_print >= 1000) {
        s->t_last_print = now;
        print_progress(s, now);
    }
}

static int single_local_gone(srv_server *s)
{
    if (srv_job_complete(s->single->job))
        return 0;
    fprintf(stderr, "\nptserve: all %u local workers exited before the image was complete\n",
            s->local.nchildren);
    return 1;
}

const srv_mode srv_mode_one_job = {
    .name = "one job",
    .serves_clients = 0,
    .logs_starts = 0,
    .setup = setup_single,
    .over = single_over,
    .after_leases = single_after_leases,
    .tick = single_tick,
    .local_gone = single_local_gone,
    .finish = finish_single,
};

/* ---- the queue --------------------------------------------------------------------- */

static pt_status setup_queue(srv_server *s, pt_error *err)
{
    const srv_config *cfg = s->cfg;
    pt_status st;
    if ((st = srv_state_open(cfg->state_dir, &s->state, err)) != PT_OK)
        return st;
    if (cfg->output_dir)
        snprintf(s->out_dir, sizeof s->out_dir, "%s", cfg->output_dir);
    else
        snprintf(s->out_dir, sizeof s->out_dir, "%s/output", cfg->state_dir);
    char tmp[PATH_MAX];
    snprintf(tmp, sizeof tmp, "%s/tmp", cfg->state_dir);
    pt_remove_tree(tmp); /* uploads a crash left half-verified */
    if ((st = pt_mkdirs(s->out_dir, 0, err)) != PT_OK || (st = pt_mkdirs(tmp, 1, err)) != PT_OK)
        return st;
    srv_job_record *recs;
    uint32_t n;
    if ((st = srv_state_load_queue(s->state, &recs, &n, &s->next_job_id, err)) != PT_OK)
        return st;
    uint32_t counts[6] = {0};
    for (uint32_t i = 0; i < n; i++) {
        srv_entry *j = pt_calloc(1, sizeof *j);
        if (!j) {
            pt_free(recs);
            return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
        }
        j->rec = recs[i];
        snprintf(j->out_path, sizeof j->out_path, "%s/%s", s->out_dir, j->rec.output);
        srv_queue_insert(s, j);
        counts[j->rec.state]++;
    }
    pt_free(recs);
    if (!cfg->quiet || counts[PROTO_JOB_RUNNING] || counts[PROTO_JOB_QUEUED])
        srv_log("state %s: %u jobs queued, %u running, %u ended; images go to %s", cfg->state_dir,
                counts[PROTO_JOB_QUEUED], counts[PROTO_JOB_RUNNING],
                counts[PROTO_JOB_DONE] + counts[PROTO_JOB_CANCELLED] + counts[PROTO_JOB_FAILED],
                s->out_dir);
    /* Resume the running jobs now: their checkpoints are checked at start. */
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->rec.state == PROTO_JOB_RUNNING)
            srv_entry_ready(s, j);
    return PT_OK;
}

/* Every running job checkpointed, its image saved. */
static int finish_queue(srv_server *s)
{
    uint32_t n = 0;
    for (srv_entry *j = s->jobs; j; j = j->next) {
        if (!j->job || !srv_entry_active(j))
            continue;
        srv_entry_checkpoint(s, j);
        srv_entry_save_image(j);
        pt_error err = {0};
        if (srv_writer_flush(j->writer, &err) != PT_OK)
            srv_log("job %llu: cannot write its image: %s", (unsigned long long)j->rec.id, err.msg);
        n++;
    }
    srv_log("stopped; %u running jobs checkpointed", n);
    return 0;
}

static int queue_over(const srv_server *s)
{
    (void)s; /* until a signal */
    return 0;
}

static void queue_after_leases(srv_server *s)
{
    pt_error err = {0};
    /* Leases need no disk: they leave before the group commit, so workers do
     * not wait on it for their next tasks. Then the results logged in this
     * round reach the disk. */
    srv_loop_flush_all(s);
    if (srv_state_sync(s->state, &err) != PT_OK)
        srv_log("error: %s", err.msg);
    if (srv_queue_end_complete(s))
        srv_queue_hand_out(s); /* the workers the ended jobs left waiting */
}

static void queue_tick(srv_server *s, uint64_t now)
{
    (void)s;
    (void)now;
}

static int queue_local_gone(srv_server *s)
{
    if (!s->local_gone_logged) {
        srv_log("all %u local workers exited; waiting for remote ones", s->local.nchildren);
        s->local_gone_logged = 1;
    }
    return 0;
}

const srv_mode srv_mode_queue = {
    .name = "queue",
    .serves_clients = 1,
    .logs_starts = 1,
    .setup = setup_queue,
    .over = queue_over,
    .after_leases = queue_after_leases,
    .tick = queue_tick,
    .local_gone = queue_local_gone,
    .finish = finish_queue,
};

const srv_mode *srv_mode_for(const srv_config *cfg)
{
    return cfg->scene_path ? &srv_mode_one_job : &srv_mode_queue;
}

/* Everything before the loop: the token, the decode buffer, the mode's jobs,
 * the listening socket and the local workers, in that order (a broken scene
 * or state folder fails before anything listens or starts). */
static pt_status setup(srv_server *s, pt_error *err)
{
    const srv_config *cfg = s->cfg;
    pt_status st;
    s->next_job_id = 1;
    if (cfg->token_path) {
        int loose = 0;
        if ((st = proto_token_load(cfg->token_path, s->token, sizeof s->token, &s->token_len,
                                   &loose, err)) != PT_OK)
            return st;
        if (loose)
            srv_log("warning: %s is readable by other users", cfg->token_path);
    }
    s->scratch = pt_malloc_array(PROTO_MAX_TILE_PIXELS, sizeof *s->scratch);
    if (!s->scratch)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    if ((st = s->mode->setup(s, err)) != PT_OK)
        return st;
    if ((st = srv_loop_open(s, err)) != PT_OK)
        return st;
    s->t_start = s->t_last_print = srv_now_ms();
    if (cfg->local_workers && (st = srv_local_start(&s->local, cfg, s->port, err)) != PT_OK)
        return st;
    return PT_OK;
}

/* The timers, once per round: leases, connections, jobs, watchers, then
 * what the mode shows. */
static void timers(srv_server *s)
{
    uint64_t now = srv_now_ms();
    srv_queue_expire(s, now);
    srv_loop_timers(s, now);
    srv_queue_tick(s, now);
    srv_requests_tick(s, now);
    s->mode->tick(s, now);
}

int srv_serve(const srv_config *cfg)
{
    srv_server s;
    memset(&s, 0, sizeof s);
    s.cfg = cfg;
    s.mode = srv_mode_for(cfg);
    s.lfd = s.ep = s.sigpipe[0] = s.sigpipe[1] = s.verifypipe[0] = s.verifypipe[1] = -1;
    pt_error err = {0};
    int rc = 1;
    if (setup(&s, &err) != PT_OK) {
        fprintf(stderr, "ptserve: %s\n", err.msg);
        goto done;
    }
    while (!srv_loop_stopped() && !s.mode->over(&s)) {
        srv_loop_poll(&s, 100);
        srv_queue_hand_out(&s);
        s.mode->after_leases(&s);
        timers(&s);
        /* Flush, then free closed connections outside their callbacks. */
        srv_loop_sweep(&s);
        if (s.local.nchildren) {
            srv_local_reap(&s.local, 0);
            if (s.local.alive == 0 && s.mode->local_gone(&s))
                break;
        }
    }
    rc = s.mode->finish(&s);
done:
    srv_upload_close(&s);
    srv_local_stop(&s.local);
    srv_loop_close(&s);
    srv_queue_free(&s);
    pt_free(s.scratch);
    return rc;
}
