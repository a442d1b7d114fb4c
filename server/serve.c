#define _GNU_SOURCE /* epoll, accept4, pipe2 */
#include "server/serve.h"

#include <errno.h>
#include <math.h>
#include <fcntl.h>
#include <limits.h>
#include <pthread.h>
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

#include "common/base/alloc.h"
#include "common/scene/bundle.h"
#include "common/render/film.h"
#include "common/base/net.h"
#include "common/scene/scene.h"
#include "protocol/frame.h"
#include "protocol/msg.h"
#include "common/base/fsutil.h"
#include "common/base/hash.h"
#include "common/render/adaptive.h"
#include "server/state.h"
#include "server/writer.h"

extern char **environ;

enum { C_HELLO, C_AUTH, C_READY };

#define MAX_CONNS 1024
#define IN_START (64u * 1024u)
#define OUT_HIGH (16u << 20)   /* stop reading a peer whose unsent output passes this */
#define OUT_MAX (256u << 20)   /* a peer that lets this much pile up is dropped */
#define STALL_MS 30000         /* a partial frame or upload with no progress for this long */
#define CLOSE_GRACE_MS 1000    /* time to flush an ERROR before closing */
#define WATCH_MS 1000          /* JOB_INFO to watchers this often */
#define CKPT_MIN_LOG (16u << 20) /* checkpoint once a job's results log passes this */
#define MAX_FINISHED 1000      /* ended jobs kept in the queue's history */
#define MAX_FETCH ((size_t)4 << 30)

/* A job of the queue (or the one job of one-job mode). */
typedef struct srv_entry {
    srv_job_record rec;
    srv_job *job;          /* NULL until it is first scheduled (and after it ends) */
    pt_bundle *bundle;     /* loaded when a worker first asks for it */
    srv_writer *writer;
    char out_path[PATH_MAX];
    double seconds_before; /* render seconds of earlier coordinator runs */
    uint64_t t_started;    /* when this run started rendering it (ms), 0: not yet */
    uint64_t rejected, rays;
    uint32_t saved_passes;
    uint64_t saved_samples, t_last_save;
    uint64_t rate_t, rate_samples;
    double rate;
    struct srv_entry *next;     /* the queue's order: priority (high first), then id */
} srv_entry;

typedef struct conn {
    int fd;
    uint64_t id;
    int state;
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
    uint32_t want;
    uint64_t t_connect, t_progress;
    uint32_t events;
    /* client */
    uint64_t watch, watch_t;      /* job watched, last JOB_INFO sent */
    uint8_t *fetch;               /* the EXR being sent */
    size_t fetch_len, fetch_off;
    uint8_t fetch_hash[32];
    int uploading;
    int verifying; /* its upload is being verified (a srv_upload in flight) */
    proto_submit up;
    uint8_t *up_buf;
    size_t up_len, up_cap;
    struct conn *next;
} conn;

/* A complete upload verified off the event loop, since a big scene takes
 * seconds: its SHA-256, its bundle, one load of the scene (with the camera
 * asked for: a broken scene is refused now, not by every worker), and the
 * bundle stored in the state folder under the job id reserved for it. The
 * thread hands it back through the server's verification pipe. */
typedef struct srv_upload {
    uint64_t conn_id, job_id;
    proto_submit m;
    uint8_t *data; /* the upload (owned), freed once wrapped in bundle */
    size_t len;
    srv_state *state;
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
    struct srv_upload *next;
} srv_upload;

typedef struct server {
    const srv_config *cfg;
    int ep, lfd, sigpipe[2];
    int verifypipe[2]; /* verifications done: their pointers */
    srv_upload *verifications;    /* in flight */
    conn *conns;
    uint32_t nconns, nworkers;
    uint64_t next_id;
    uint8_t token[PROTO_TOKEN_MAX];
    size_t token_len;
    srv_entry *jobs;            /* every job, in queue order */
    uint32_t njobs;
    uint64_t next_job_id;
    srv_entry *single;          /* one-job mode: the job */
    srv_state *state;      /* queue mode */
    char out_dir[PATH_MAX - 512];
    uint64_t t_start, t_last_print;
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

static void release_owner_all(server *s, conn *c, int report)
{
    if (c->state != C_READY || c->role != PROTO_ROLE_WORKER)
        return;
    uint32_t n = 0;
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->job)
            n += srv_job_release_owner(j->job, c->id);
    if (n && report)
        logf_(s, "worker %s left; %u leased tasks requeued", c->name, n);
}

/* Marks c for closing once its output is flushed (or the grace time ends). */
static void conn_close_soon(server *s, conn *c)
{
    if (!c->closing) {
        c->closing = 1;
        c->close_at = now_ms() + CLOSE_GRACE_MS;
        release_owner_all(s, c, 0);
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

static void upload_drop(conn *c)
{
    pt_free(c->up_buf);
    c->up_buf = NULL;
    c->up_len = c->up_cap = 0;
    c->uploading = 0;
}

static void conn_free(server *s, conn *c)
{
    if (!c->closing)
        release_owner_all(s, c, 1);
    if (c->state == C_READY && c->role == PROTO_ROLE_WORKER && s->nworkers > 0)
        s->nworkers--;
    if (c->uploading)
        logf_(s, "client %s left during an upload (%zu of %llu bytes); nothing was queued",
              c->name, c->up_len, (unsigned long long)c->up.bundle_size);
    upload_drop(c);
    pt_free(c->fetch);
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

/* ---- the queue ------------------------------------------------------------------- */

static int job_active(const srv_entry *j)
{
    return j->rec.state == PROTO_JOB_QUEUED || j->rec.state == PROTO_JOB_RUNNING;
}

static srv_entry *find_job(server *s, uint64_t id)
{
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->rec.id == id)
            return j;
    return NULL;
}

/* Queue order: priority (higher first), then submission (lower id first). */
static void insert_job(server *s, srv_entry *j)
{
    srv_entry **p = &s->jobs;
    while (*p && ((*p)->rec.priority > j->rec.priority ||
                  ((*p)->rec.priority == j->rec.priority && (*p)->rec.id < j->rec.id)))
        p = &(*p)->next;
    j->next = *p;
    *p = j;
    s->njobs++;
}

static void free_job_run(srv_entry *j)
{
    srv_writer_free(j->writer);
    j->writer = NULL;
    srv_job_free(j->job);
    j->job = NULL;
    pt_bundle_free(j->bundle);
    j->bundle = NULL;
}

static void free_entry(srv_entry *j)
{
    free_job_run(j);
    pt_free(j);
}

/* Drops the oldest ended jobs beyond MAX_FINISHED from the history. */
static void prune_history(server *s)
{
    uint32_t ended = 0;
    for (srv_entry *j = s->jobs; j; j = j->next)
        ended += !job_active(j);
    while (ended > MAX_FINISHED) {
        srv_entry **oldest = NULL;
        for (srv_entry **p = &s->jobs; *p; p = &(*p)->next)
            if (!job_active(*p) && (!oldest || (*p)->rec.id < (*oldest)->rec.id))
                oldest = p;
        srv_entry *j = *oldest;
        *oldest = j->next;
        free_entry(j);
        s->njobs--;
        ended--;
    }
}

/* Writes the queue file (queue mode). */
static pt_status journal(server *s, pt_error *err)
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

static void journal_or_log(server *s)
{
    pt_error err = {0};
    if (journal(s, &err) != PT_OK)
        logf_(s, "error: cannot write the queue: %s", err.msg);
}

static double job_seconds(const srv_entry *j, uint64_t now)
{
    if (!job_active(j))
        return j->rec.seconds;
    return j->seconds_before + (j->t_started ? (double)(now - j->t_started) / 1000.0 : 0.0);
}

static uint32_t job_workers(const server *s, const srv_entry *j)
{
    uint32_t n = 0;
    if (!j->job)
        return 0;
    for (const conn *c = s->conns; c; c = c->next)
        if (c->state == C_READY && c->role == PROTO_ROLE_WORKER &&
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

static void job_info(const server *s, const srv_entry *j, proto_job_info *m)
{
    uint64_t now = now_ms();
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
    m->seconds = job_seconds(j, now);
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

static void send_job_info(server *s, conn *c, const srv_entry *j)
{
    proto_job_info m;
    job_info(s, j, &m);
    size_t mark;
    if (frame_open(c, PROTO_MSG_JOB_INFO, &mark))
        frame_close(c, mark, proto_msg_encode_job_info(&c->out, &m, NULL));
    c->watch_t = now_ms();
    if (!job_active(j) && c->watch == j->rec.id)
        c->watch = 0;
}

/* Sends the job's state to everyone watching it (its end included). */
static void notify_watchers(server *s, const srv_entry *j)
{
    for (conn *c = s->conns; c; c = c->next)
        if (c->watch == j->rec.id && !c->closing)
            send_job_info(s, c, j);
}

static void save_progress(server *s, srv_entry *j)
{
    pt_image *img = NULL;
    const pt_film *film = srv_job_film(j->job);
    if (pt_image_new(film->width, film->height, &img, NULL) != PT_OK) {
        logf_(s, "out of memory for a progressive image of job %llu; will try again",
              (unsigned long long)j->rec.id);
        return;
    }
    pt_film_resolve(film, img);
    pt_exr_meta meta = {0};
    meta.total_samples = pt_film_total_samples(film);
    meta.render_seconds = job_seconds(j, now_ms());
    pt_hash_hex(j->rec.hash, meta.scene_hash);
    snprintf(meta.job_id, sizeof meta.job_id, "%llu", (unsigned long long)j->rec.id);
    srv_writer_submit(j->writer, img, &meta);
    j->t_last_save = now_ms();
    j->saved_passes = srv_job_passes_done(j->job);
    j->saved_samples = meta.total_samples;
}

static void checkpoint(server *s, srv_entry *j)
{
    if (!s->state || !j->job)
        return;
    srv_ckpt_extra x = {job_seconds(j, now_ms()), j->rejected, j->rays};
    pt_error err = {0};
    if (srv_state_checkpoint(s->state, j->job, &x, &err) != PT_OK)
        logf_(s, "error: job %llu: cannot write its checkpoint: %s (its results log still holds "
              "every merged task)", (unsigned long long)j->rec.id, err.msg);
}

/* Ends a job: DONE (the final image is written first), CANCELLED or FAILED. */
/* Tells every worker that job j ended before it was done, so each drops the
 * tasks of it that it has not started and its threads go to the next job at
 * once (their results would be dropped anyway). */
static void announce_job_end(server *s, const srv_entry *j)
{
    proto_job_ref ref = {j->rec.id};
    for (conn *c = s->conns; c; c = c->next) {
        if (c->role != PROTO_ROLE_WORKER || c->state != C_READY || c->closing)
            continue;
        size_t mark;
        if (frame_open(c, PROTO_MSG_JOB_END, &mark))
            frame_close(c, mark, proto_msg_encode_job_ref(&c->out, &ref, NULL));
        conn_update_events(s, c);
    }
}

static void job_end(server *s, srv_entry *j, uint8_t state, const char *message)
{
    uint64_t now = now_ms();
    pt_error err = {0};
    if (state == PROTO_JOB_DONE && j->job) {
        save_progress(s, j);
        if (srv_writer_flush(j->writer, &err) != PT_OK) {
            state = PROTO_JOB_FAILED;
            char msg[PROTO_MAX_ERROR_TEXT + 1];
            snprintf(msg, sizeof msg, "cannot write the image: %s", err.msg);
            job_end(s, j, state, msg);
            return;
        }
    }
    j->rec.seconds = job_seconds(j, now);
    if (j->job) {
        j->rec.samples_done = srv_job_samples_merged(j->job);
        j->rec.error = job_error(j->job);
    }
    if (state != PROTO_JOB_DONE && j->t_started)
        announce_job_end(s, j);
    j->rec.state = state;
    snprintf(j->rec.message, sizeof j->rec.message, "%s", message ? message : "");
    free_job_run(j);
    pt_status st = journal(s, &err);
    if (st != PT_OK)
        logf_(s, "error: cannot write the queue: %s", err.msg);
    /* A failed job's files stay for the operator to look at; an ended one's
     * go once the queue says it ended. */
    if (s->state && state != PROTO_JOB_FAILED && st == PT_OK)
        srv_state_forget_job(s->state, j->rec.id);
    if (state == PROTO_JOB_DONE)
        logf_(s, "job %llu done: %llu samples in %.1f s; %s", (unsigned long long)j->rec.id,
              (unsigned long long)j->rec.samples_done, j->rec.seconds, j->out_path);
    else
        logf_(s, "job %llu %s%s%s", (unsigned long long)j->rec.id, proto_job_state_name(state),
              j->rec.message[0] ? ": " : "", j->rec.message);
    notify_watchers(s, j);
}

/* Makes a job ready to lease: its task state (restored from its checkpoint
 * and results log in queue mode) and its image writer. Returns 0 when it
 * cannot be (the job is marked FAILED, with the reason). */
static int job_ready(server *s, srv_entry *j)
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
                logf_(s, "job %llu: dropped the incomplete last record of its results log (a "
                      "write cut short by a crash; it was never merged)",
                      (unsigned long long)j->rec.id);
            if (srv_job_tasks_merged(j->job) > 0)
                logf_(s, "job %llu resumed: %llu samples merged (%u from its results log)",
                      (unsigned long long)j->rec.id,
                      (unsigned long long)srv_job_samples_merged(j->job), replayed);
        }
    }
    if (st == PT_OK && !j->writer)
        st = srv_writer_new(j->out_path, &j->writer, &err);
    if (st != PT_OK) {
        char msg[PROTO_MAX_ERROR_TEXT + 1];
        snprintf(msg, sizeof msg, "%s", err.msg);
        job_end(s, j, PROTO_JOB_FAILED, msg);
        return 0;
    }
    j->saved_passes = srv_job_passes_done(j->job);
    j->saved_samples = srv_job_samples_merged(j->job);
    j->t_last_save = now_ms();
    j->rate_t = now_ms();
    j->rate_samples = j->saved_samples;
    return 1;
}

/* Leases the first task the queue has for owner: the first job in queue order
 * with a task to hand out, so when the running job has nothing left for an
 * idle worker (its last pass), the next job starts. */
static int lease_any(server *s, uint64_t owner, uint64_t now, proto_task *t)
{
    for (srv_entry *j = s->jobs; j; j = j->next) {
        if (!job_active(j) || !job_ready(s, j))
            continue;
        if (!srv_job_lease(j->job, owner, now, s->cfg->lease_ms, t))
            continue;
        if (!j->t_started)
            j->t_started = now;
        if (j->rec.state == PROTO_JOB_QUEUED) {
            j->rec.state = PROTO_JOB_RUNNING;
            journal_or_log(s);
            if (s->state)
                logf_(s, "job %llu started (%s, %ux%u, %u spp)", (unsigned long long)j->rec.id,
                      j->rec.scene, j->rec.params.width, j->rec.params.height,
                      j->rec.params.spp);
        }
        return 1;
    }
    return 0;
}

/* Appends IMAGE frames of a fetch in progress while c's output has room. */
static void pump_fetch(server *s, conn *c)
{
    (void)s;
    while (c->fetch && !c->closing && c->out.len - c->out_off < OUT_HIGH) {
        proto_scene_chunk ch;
        memcpy(ch.hash, c->fetch_hash, 32);
        ch.offset = c->fetch_off;
        ch.total = c->fetch_len;
        size_t left = c->fetch_len - c->fetch_off;
        ch.len = (uint32_t)(left < PROTO_MAX_SCENE_CHUNK ? left : PROTO_MAX_SCENE_CHUNK);
        ch.data = c->fetch + c->fetch_off;
        size_t mark;
        if (!frame_open(c, PROTO_MSG_IMAGE, &mark) ||
            !frame_close(c, mark, proto_msg_encode_scene_chunk(&c->out, &ch, NULL))) {
            conn_send_error(s, c, PROTO_E_LIMIT, "output buffer full");
            break;
        }
        c->fetch_off += ch.len;
        if (c->fetch_off == c->fetch_len) {
            pt_free(c->fetch);
            c->fetch = NULL;
        }
    }
}

/* Leases tasks to every ready worker that asked for some, and feeds fetches. */
static void hand_out(server *s)
{
    uint64_t now = now_ms();
    int dry = 0; /* the queue had nothing to lease: skip the other workers */
    for (conn *c = s->conns; c; c = c->next) {
        if (c->state != C_READY || c->closing)
            continue;
        if (c->fetch)
            pump_fetch(s, c);
        while (!dry && c->role == PROTO_ROLE_WORKER && c->want > 0 &&
               c->out.len - c->out_off < OUT_HIGH) {
            proto_task t;
            if (!lease_any(s, c->id, now, &t)) {
                dry = 1;
                break;
            }
            size_t mark;
            if (!frame_open(c, PROTO_MSG_TASK, &mark) ||
                !frame_close(c, mark, proto_msg_encode_task(&c->out, &t, NULL))) {
                conn_send_error(s, c, PROTO_E_LIMIT, "output buffer full");
                break;
            }
            c->want--;
        }
        conn_update_events(s, c);
    }
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
    if (h.role == PROTO_ROLE_CLIENT && !s->state) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "this coordinator renders one scene and keeps "
                        "no queue (start ptserve with --state-dir for clients)");
        return;
    }
    if (h.role != PROTO_ROLE_WORKER && h.role != PROTO_ROLE_CLIENT) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "role %u is not served by this coordinator",
                        h.role);
        return;
    }
    /* A client's build does not touch the pixels; a worker's does. */
    if (h.role == PROTO_ROLE_WORKER && strcmp(h.build_id, proto_build_id()) != 0) {
        conn_send_error(s, c, PROTO_E_BUILD, "worker renderer build %s differs from the "
                        "coordinator's %s; mixed builds would break bit-identical merging",
                        h.build_id, proto_build_id());
        return;
    }
    c->role = h.role;
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
    if (c->role == PROTO_ROLE_WORKER) {
        s->nworkers++;
        if (!s->cfg->quiet)
            logf_(s, "worker %s joined from %s (%u threads)", c->name, c->peer, c->threads);
    }
}

static void on_scene_get(server *s, conn *c, const proto_frame *f)
{
    proto_scene_get g;
    pt_error err = {0};
    if (proto_msg_decode_scene_get(f->payload, f->len, &g, &err) != PT_OK) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "bad SCENE_GET: %s", err.msg);
        return;
    }
    srv_entry *j = s->jobs;
    while (j && !(job_active(j) && memcmp(g.hash, j->rec.hash, 32) == 0))
        j = j->next;
    if (j && !j->bundle && s->state &&
        srv_state_load_bundle(s->state, j->rec.id, j->rec.hash, &j->bundle, &err) != PT_OK) {
        char msg[PROTO_MAX_ERROR_TEXT + 1];
        snprintf(msg, sizeof msg, "%s", err.msg);
        job_end(s, j, PROTO_JOB_FAILED, msg);
        j = NULL;
    }
    if (!j || !j->bundle) {
        conn_send_error(s, c, PROTO_E_NOT_FOUND, "no scene with that hash");
        return;
    }
    const pt_bundle *b = j->bundle;
    if (g.offset > b->size) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "scene offset %llu is past its end (%zu)",
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
    srv_entry *j = find_job(s, r.job_id);
    if (!j || !job_active(j) || !j->job) {
        proto_result_fini(&r); /* a job that ended (cancelled): nothing to do */
        return;
    }
    int lease_index;
    srv_outcome o = srv_job_validate(j->job, c->id, &r, &lease_index, &err);
    /* Durable before merged: the log holds every result the film holds. */
    if (o == SRV_MERGED && s->state &&
        srv_state_log_result(s->state, j->rec.id, f->payload, f->len, &err) != PT_OK) {
        logf_(s, "error: job %llu: %s; result dropped (its task will be rendered again)",
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
    uint64_t now = now_ms();
    /* Task ids are per job; extending only leases this owner holds is safe
     * even when two of its jobs share an id. */
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->job && job_active(j))
            for (uint32_t i = 0; i < hb.count; i++)
                srv_job_heartbeat(j->job, c->id, hb.task_ids[i], now, s->cfg->lease_ms);
}

/* ---- client requests --------------------------------------------------------------- */

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

static uint32_t owner_unfinished(const server *s, const char *owner)
{
    uint32_t n = 0;
    for (const srv_entry *j = s->jobs; j; j = j->next)
        n += job_active(j) && strcmp(j->rec.owner, owner) == 0;
    return n;
}

static void on_submit(server *s, conn *c, const proto_frame *f)
{
    pt_error err = {0};
    proto_submit m;
    if (c->uploading) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "SUBMIT during an upload");
        return;
    }
    if (proto_msg_decode_submit(f->payload, f->len, &m, &err) != PT_OK) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "bad SUBMIT: %s", err.msg);
        return;
    }
    if (strchr(m.name, '/') || strchr(m.name, '\\') || m.name[0] == '.' || strstr(m.name, "..")) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "job name '%s' is not a plain name (no '/', "
                        "'\\', '..' or leading '.')", m.name);
        return;
    }
    for (const char *p = m.name; *p; p++)
        if ((unsigned char)*p < 0x20 || *p == 0x7f) {
            conn_send_error(s, c, PROTO_E_PROTOCOL, "job name has control characters");
            return;
        }
    const srv_caps *cap = &s->cfg->caps;
    if (m.bundle_size > cap->max_scene) {
        conn_send_error(s, c, PROTO_E_LIMIT, "scene of %llu bytes is over this server's limit "
                        "of %llu", (unsigned long long)m.bundle_size,
                        (unsigned long long)cap->max_scene);
        return;
    }
    if (m.spp > cap->max_spp) {
        conn_send_error(s, c, PROTO_E_LIMIT, "%u samples per pixel is over this server's limit "
                        "of %u", m.spp, cap->max_spp);
        return;
    }
    if (m.width > cap->max_side || m.height > cap->max_side ||
        (uint64_t)m.width * m.height > cap->max_pixels) {
        conn_send_error(s, c, PROTO_E_LIMIT, "resolution %ux%u is over this server's limit (%u "
                        "per side, %llu pixels)", m.width, m.height, cap->max_side,
                        (unsigned long long)cap->max_pixels);
        return;
    }
    if (m.max_depth > 1024 || (m.min_spp && m.min_spp < 2) || m.min_spp > m.spp) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "max depth %u or min spp %u is out of range",
                        m.max_depth, m.min_spp);
        return;
    }
    if (m.target_error > 0.0 && m.min_gain > 0.0) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "target error and min gain are two adaptive "
                        "rules; a job takes one");
        return;
    }
    if (owner_unfinished(s, c->name) >= cap->max_queued) {
        conn_send_error(s, c, PROTO_E_LIMIT, "%s already has %u unfinished jobs, this "
                        "server's limit", c->name, cap->max_queued);
        return;
    }
    if (s->njobs >= SRV_MAX_JOBS) {
        conn_send_error(s, c, PROTO_E_LIMIT, "the queue is full (%u jobs)", SRV_MAX_JOBS);
        return;
    }
    c->up = m;
    c->uploading = 1;
    c->up_len = 0;
    c->t_progress = now_ms();
}

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
        verify_refuse(k, PROTO_E_PROTOCOL, "the scene's SHA-256 is %.16s..., not the %.16s... "
                     "SUBMIT announced", hex, want);
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

/* A complete upload: reserves the job id and starts its verification. */
static void finish_submit(server *s, conn *c)
{
    srv_upload *k = pt_calloc(1, sizeof *k);
    if (!k) {
        conn_send_error(s, c, PROTO_E_INTERNAL, "out of memory");
        return;
    }
    k->conn_id = c->id;
    k->job_id = s->next_job_id++;
    k->m = c->up;
    k->data = c->up_buf;
    k->len = c->up_len;
    c->up_buf = NULL;
    upload_drop(c);
    k->state = s->state;
    snprintf(k->tmp, sizeof k->tmp, "%s/tmp/upload-%llu", srv_state_dir(s->state),
             (unsigned long long)k->job_id);
    k->wake_fd = s->verifypipe[1];
    if (pthread_create(&k->thread, NULL, verify_thread, k) != 0) {
        upload_free(k);
        conn_send_error(s, c, PROTO_E_INTERNAL, "cannot start checking the scene");
        return;
    }
    k->next = s->verifications;
    s->verifications = k;
    c->verifying = 1;
}

/* A verification is done: queues the job, or tells the client why not. */
static void complete_submit(server *s, conn *c, srv_upload *k)
{
    pt_error err = {0};
    pt_status st;
    const proto_submit *m = &k->m;
    c->verifying = 0;
    if (!k->ok) {
        conn_send_error(s, c, k->code, "%s", k->msg);
        return;
    }
    pt_bundle *b = k->bundle;
    k->bundle = NULL;
    srv_entry *j = pt_calloc(1, sizeof *j);
    if (!j) {
        pt_bundle_free(b);
        srv_state_forget_job(s->state, k->job_id);
        conn_send_error(s, c, PROTO_E_INTERNAL, "out of memory");
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
        conn_send_error(s, c, PROTO_E_LIMIT, "%s", err.msg);
        return;
    }
    srv_job_free(probe);
    j->bundle = b;
    insert_job(s, j);
    prune_history(s);
    if (journal(s, &err) != PT_OK) {
        /* Not durable, so not accepted. */
        for (srv_entry **q = &s->jobs; *q; q = &(*q)->next)
            if (*q == j) {
                *q = j->next;
                break;
            }
        s->njobs--;
        srv_state_forget_job(s->state, r->id);
        free_entry(j);
        conn_send_error(s, c, PROTO_E_INTERNAL, "cannot write the queue: %s", err.msg);
        return;
    }
    logf_(s, "job %llu queued from %s: %s (%u triangles), %ux%u, %u spp, priority %d",
          (unsigned long long)r->id, c->name, r->scene, ntris, p.width, p.height, p.spp,
          r->priority);
    proto_job_ref ref = {r->id};
    size_t mark;
    if (frame_open(c, PROTO_MSG_SUBMITTED, &mark))
        frame_close(c, mark, proto_msg_encode_job_ref(&c->out, &ref, NULL));
}

static void on_upload(server *s, conn *c, const proto_frame *f)
{
    proto_scene_chunk ch;
    pt_error err = {0};
    if (!c->uploading) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "UPLOAD without a SUBMIT");
        return;
    }
    if (proto_msg_decode_scene_chunk(f->payload, f->len, &ch, &err) != PT_OK) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "bad UPLOAD: %s", err.msg);
        return;
    }
    if (memcmp(ch.hash, c->up.bundle_hash, 32) != 0 || ch.total != c->up.bundle_size ||
        ch.offset != c->up_len || ch.len == 0) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "UPLOAD of %u bytes at %llu of %llu does not "
                        "continue the announced scene (%zu of %llu bytes so far)", ch.len,
                        (unsigned long long)ch.offset, (unsigned long long)ch.total, c->up_len,
                        (unsigned long long)c->up.bundle_size);
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
            conn_send_error(s, c, PROTO_E_INTERNAL, "out of memory for the scene");
            return;
        }
        c->up_buf = n;
        c->up_cap = cap;
    }
    memcpy(c->up_buf + c->up_len, ch.data, ch.len);
    c->up_len += ch.len;
    if (c->up_len == c->up.bundle_size)
        finish_submit(s, c);
}

/* Completes each verification that is done: its client gets the answer or, gone
 * meanwhile, nothing is queued and the stored bundle goes. */
static void verifications_done(server *s)
{
    srv_upload *k;
    while (read(s->verifypipe[0], &k, sizeof k) == (ssize_t)sizeof k) {
        pthread_join(k->thread, NULL);
        for (srv_upload **q = &s->verifications; *q; q = &(*q)->next)
            if (*q == k) {
                *q = k->next;
                break;
            }
        conn *c = s->conns;
        while (c && (c->id != k->conn_id || c->closing))
            c = c->next;
        if (c) {
            complete_submit(s, c, k);
        } else {
            if (k->ok)
                srv_state_forget_job(s->state, k->job_id);
            logf_(s, "a client left before its scene was checked; nothing was queued");
        }
        upload_free(k);
    }
}

/* At exit: waits for the verifications in flight; none of them was queued. */
static void verifications_abandon(server *s)
{
    while (s->verifications) {
        srv_upload *k = s->verifications;
        s->verifications = k->next;
        pthread_join(k->thread, NULL);
        if (k->ok)
            srv_state_forget_job(s->state, k->job_id);
        upload_free(k);
    }
}

static int read_job_ref(server *s, conn *c, const proto_frame *f, srv_entry **out)
{
    proto_job_ref ref;
    pt_error err = {0};
    if (proto_msg_decode_job_ref(f->payload, f->len, &ref, &err) != PT_OK) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "bad %s: %s", proto_msg_type_name(f->type),
                        err.msg);
        return 0;
    }
    *out = find_job(s, ref.job_id);
    if (!*out) {
        conn_send_error(s, c, PROTO_E_NOT_FOUND, "no job %llu", (unsigned long long)ref.job_id);
        return 0;
    }
    return 1;
}

static void on_list(server *s, conn *c, const proto_frame *f)
{
    if (f->len != 0) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "bad LIST: trailing bytes");
        return;
    }
    uint32_t n = s->njobs < PROTO_MAX_JOBS ? s->njobs : PROTO_MAX_JOBS;
    proto_job_info *infos = pt_malloc_array(n ? n : 1, sizeof *infos);
    if (!infos) {
        conn_send_error(s, c, PROTO_E_INTERNAL, "out of memory");
        return;
    }
    uint32_t k = 0;
    for (srv_entry *j = s->jobs; j && k < n; j = j->next)
        job_info(s, j, &infos[k++]);
    size_t mark;
    if (!frame_open(c, PROTO_MSG_JOB_LIST, &mark) ||
        !frame_close(c, mark, proto_msg_encode_job_list(&c->out, infos, k, NULL)))
        conn_send_error(s, c, PROTO_E_LIMIT, "output buffer full");
    pt_free(infos);
}

static void on_fetch(server *s, conn *c, srv_entry *j)
{
    pt_error err = {0};
    if (c->fetch) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "FETCH while a fetch is in progress");
        return;
    }
    uint8_t *data;
    size_t len;
    if (pt_read_file(j->out_path, MAX_FETCH, &data, &len, &err) != PT_OK) {
        if (err.sys_errno == ENOENT)
            conn_send_error(s, c, PROTO_E_NOT_FOUND, "job %llu has no image yet (%s)",
                            (unsigned long long)j->rec.id, proto_job_state_name(j->rec.state));
        else
            conn_send_error(s, c, PROTO_E_INTERNAL, "%s", err.msg);
        return;
    }
    if (len == 0) {
        pt_free(data);
        conn_send_error(s, c, PROTO_E_INTERNAL, "job %llu: its image file is empty",
                        (unsigned long long)j->rec.id);
        return;
    }
    char hex[65];
    pt_sha256_hex(data, len, hex);
    pt_hex_decode(hex, c->fetch_hash, 32);
    c->fetch = data;
    c->fetch_len = len;
    c->fetch_off = 0;
    pump_fetch(s, c);
}

/* An ERROR from the peer (who: "client" or "worker"): logged, then closed. */
static void on_peer_error(server *s, conn *c, const proto_frame *f, const char *who)
{
    proto_error_msg m;
    if (proto_msg_decode_error(f->payload, f->len, &m, NULL) == PT_OK)
        logf_(s, "%s %s reports: %s", who, c->name, m.text);
    conn_close_soon(s, c);
}

static void dispatch_client(server *s, conn *c, const proto_frame *f)
{
    srv_entry *j;
    if (c->verifying) {
        conn_send_error(s, c, PROTO_E_PROTOCOL, "%s before the answer to its SUBMIT",
                        proto_msg_type_name(f->type));
        return;
    }
    switch (f->type) {
    case PROTO_MSG_SUBMIT: on_submit(s, c, f); break;
    case PROTO_MSG_UPLOAD: on_upload(s, c, f); break;
    case PROTO_MSG_LIST: on_list(s, c, f); break;
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
            if (job_active(j)) {
                char msg[PROTO_MAX_ERROR_TEXT + 1];
                snprintf(msg, sizeof msg, "cancelled by %s", c->name);
                job_end(s, j, PROTO_JOB_CANCELLED, msg);
            }
            send_job_info(s, c, j);
        }
        break;
    case PROTO_MSG_FETCH:
        if (read_job_ref(s, c, f, &j))
            on_fetch(s, c, j);
        break;
    case PROTO_MSG_ERROR:
        on_peer_error(s, c, f, "client");
        break;
    default:
        conn_send_error(s, c, PROTO_E_PROTOCOL, "unexpected %s from a client",
                        proto_msg_type_name(f->type));
    }
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
    if (c->role == PROTO_ROLE_CLIENT) {
        dispatch_client(s, c, f);
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
    case PROTO_MSG_ERROR:
        on_peer_error(s, c, f, "worker");
        break;
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

static void timers(server *s)
{
    uint64_t now = now_ms();
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->job && job_active(j) && srv_job_expire(j->job, now, NULL) > 0)
            logf_(s, "job %llu: leases expired; tasks requeued", (unsigned long long)j->rec.id);
    for (conn *c = s->conns; c; c = c->next) {
        if (c->closing)
            continue;
        if (c->state != C_READY && now - c->t_connect > s->cfg->handshake_ms)
            conn_send_error(s, c, PROTO_E_PROTOCOL, "handshake not finished in %.1f s",
                            s->cfg->handshake_ms / 1000.0);
        else if ((c->in_len > 0 || c->uploading) && now - c->t_progress > STALL_MS)
            conn_send_error(s, c, PROTO_E_PROTOCOL, "%s stalled for %d s",
                            c->uploading ? "upload" : "partial frame", STALL_MS / 1000);
    }
    for (srv_entry *j = s->jobs; j; j = j->next) {
        if (!j->job || !job_active(j))
            continue;
        uint64_t merged = srv_job_samples_merged(j->job);
        int pass_done = srv_job_passes_done(j->job) > j->saved_passes;
        if ((pass_done || merged > j->saved_samples) &&
            (double)(now - j->t_last_save) >= s->cfg->save_interval * 1000.0 &&
            !srv_job_complete(j->job))
            save_progress(s, j);
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
                checkpoint(s, j);
        }
    }
    for (conn *c = s->conns; c; c = c->next) {
        if (c->closing || !c->watch || now - c->watch_t < WATCH_MS)
            continue;
        srv_entry *j = find_job(s, c->watch);
        if (j)
            send_job_info(s, c, j);
        else
            c->watch = 0;
    }
    if (s->single && s->single->job && !s->cfg->quiet && now - s->t_last_print >= 1000) {
        s->t_last_print = now;
        print_progress(s, now);
    }
}

/* Ends the queue's jobs whose every task is merged; returns how many. */
static int finish_complete(server *s)
{
    int ended = 0;
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j != s->single && j->job && job_active(j) && srv_job_complete(j->job)) {
            job_end(s, j, PROTO_JOB_DONE, NULL);
            ended++;
        }
    return ended;
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


static pt_status setup_single(server *s, pt_error *err)
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
    insert_job(s, j);
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
    if (!job_ready(s, j))
        return pt_error_set(err, PT_ERR_IO, "%s", j->rec.message);
    if (!cfg->quiet)
        logf_(s, "%s: %u triangles, %ux%u, %u spp in %u passes of %u, tiles of %u",
              cfg->scene_path, ntris, jp.width, jp.height, jp.spp, srv_job_passes(j->job),
              jp.chunk, jp.tile);
    return PT_OK;
}

static pt_status setup_queue(server *s, pt_error *err)
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
        insert_job(s, j);
        counts[j->rec.state]++;
    }
    pt_free(recs);
    if (!cfg->quiet || counts[PROTO_JOB_RUNNING] || counts[PROTO_JOB_QUEUED])
        logf_(s, "state %s: %u jobs queued, %u running, %u ended; images go to %s",
              cfg->state_dir, counts[PROTO_JOB_QUEUED], counts[PROTO_JOB_RUNNING],
              counts[PROTO_JOB_DONE] + counts[PROTO_JOB_CANCELLED] + counts[PROTO_JOB_FAILED],
              s->out_dir);
    /* Resume the running jobs now: their checkpoints are checked at start. */
    for (srv_entry *j = s->jobs; j; j = j->next)
        if (j->rec.state == PROTO_JOB_RUNNING)
            job_ready(s, j);
    return PT_OK;
}

static pt_status setup(server *s, pt_error *err)
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
            logf_(s, "warning: %s is readable by other users", cfg->token_path);
    }
    s->scratch = pt_malloc_array(PROTO_MAX_TILE_PIXELS, sizeof *s->scratch);
    if (!s->scratch)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    if ((st = cfg->scene_path ? setup_single(s, err) : setup_queue(s, err)) != PT_OK)
        return st;

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
        logf_(s, "listening on %s:%u%s", host, s->port,
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
    /* The threads' end blocks (a pointer is never lost); the loop's does not. */
    if (pipe2(s->verifypipe, O_CLOEXEC) != 0 ||
        fcntl(s->verifypipe[0], F_SETFL, fcntl(s->verifypipe[0], F_GETFL) | O_NONBLOCK) != 0)
        return pt_error_errno(err, PT_ERR_IO, "pipe2");
    e.data.ptr = &s->verifypipe;
    epoll_ctl(s->ep, EPOLL_CTL_ADD, s->verifypipe[0], &e);
    g_sigpipe_w = s->sigpipe[1];
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
    s->t_start = s->t_last_print = now_ms();
    if (cfg->local_workers && (st = spawn_workers(s, err)) != PT_OK)
        return st;
    return PT_OK;
}

/* One-job mode's ending: the final image and the summary. Returns the exit status. */
static int finish_single(server *s)
{
    const srv_config *cfg = s->cfg;
    srv_entry *j = s->single;
    pt_error err = {0};
    if (!j->job)
        return 1;
    save_progress(s, j);
    pt_status st = srv_writer_flush(j->writer, &err);
    if (!cfg->quiet)
        print_progress(s, now_ms());
    fputc('\n', stderr);
    double secs = (double)(now_ms() - s->t_start) / 1000.0;
    uint64_t samples = srv_job_samples_merged(j->job);
    const srv_job_params *p = &j->rec.params;
    if (st != PT_OK) {
        fprintf(stderr, "ptserve: cannot write %s: %s\n", cfg->out_path, err.msg);
        return 1;
    }
    if (srv_job_complete(j->job)) {
        uint64_t tasks = srv_job_tasks_total(j->job);
        fprintf(stderr, "ptserve: done in %.2fs: %llu samples (%.4g samples/s), %llu rejected "
                "samples (NaN/Inf); wrote %s\n", secs, (unsigned long long)samples,
                (double)samples / secs, (unsigned long long)j->rejected, cfg->out_path);
        fprintf(stderr, "ptserve: wire: %llu bytes in, %llu out (scene %zu); %.3f bytes per "
                "sample, %.0f per task\n", (unsigned long long)s->bytes_in,
                (unsigned long long)s->bytes_out, j->bundle ? j->bundle->size : 0,
                (double)(s->bytes_in + s->bytes_out) / (double)samples,
                (double)(s->bytes_in + s->bytes_out) / (double)tasks);
        return 0;
    }
    if (g_stop) {
        fprintf(stderr, "ptserve: interrupted after %.2fs; %s holds %llu of %llu samples\n", secs,
                cfg->out_path, (unsigned long long)samples,
                (unsigned long long)p->width * p->height * p->spp);
        return 130;
    }
    return 1;
}

/* Queue mode's ending: every running job checkpointed, its image saved. */
static void finish_queue(server *s)
{
    uint32_t n = 0;
    for (srv_entry *j = s->jobs; j; j = j->next) {
        if (!j->job || !job_active(j))
            continue;
        checkpoint(s, j);
        save_progress(s, j);
        pt_error err = {0};
        if (srv_writer_flush(j->writer, &err) != PT_OK)
            logf_(s, "job %llu: cannot write its image: %s", (unsigned long long)j->rec.id,
                  err.msg);
        n++;
    }
    logf_(s, "stopped; %u running jobs checkpointed", n);
}

int srv_serve(const srv_config *cfg)
{
    server s;
    memset(&s, 0, sizeof s);
    s.cfg = cfg;
    s.lfd = s.ep = s.sigpipe[0] = s.sigpipe[1] = s.verifypipe[0] = s.verifypipe[1] = -1;
    pt_error err = {0};
    int rc = 1, children_reported = 0;
    if (setup(&s, &err) != PT_OK) {
        fprintf(stderr, "ptserve: %s\n", err.msg);
        goto done;
    }
    while (!g_stop) {
        if (s.single && (!s.single->job || srv_job_complete(s.single->job)))
            break;
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
            } else if (p == &s.verifypipe) {
                verifications_done(&s);
            } else {
                conn *c = p;
                if (evs[i].events & (EPOLLIN | EPOLLHUP | EPOLLERR))
                    conn_read(&s, c);
                if (evs[i].events & EPOLLOUT)
                    conn_flush(&s, c);
            }
        }
        hand_out(&s);
        if (s.state) {
            /* Leases need no disk: they leave before the group commit, so
             * workers do not wait on it for their next tasks. Then the
             * results logged in this round reach the disk. */
            for (conn *c = s.conns; c; c = c->next)
                if (c->out.len > c->out_off && !c->closing)
                    conn_flush(&s, c);
            if (srv_state_sync(s.state, &err) != PT_OK)
                logf_(&s, "error: %s", err.msg);
            if (finish_complete(&s))
                hand_out(&s); /* the workers the ended jobs left waiting */
        }
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
            if (s.children_alive == 0 && s.single && !srv_job_complete(s.single->job)) {
                fprintf(stderr, "\nptserve: all %u local workers exited before the image was "
                        "complete\n", s.nchildren);
                break;
            }
            if (s.children_alive == 0 && !s.single && !children_reported) {
                logf_(&s, "all %u local workers exited; waiting for remote ones", s.nchildren);
                children_reported = 1;
            }
        }
    }
    if (s.single) {
        rc = finish_single(&s);
    } else if (s.state) {
        finish_queue(&s);
        rc = 0;
    }
done:
    verifications_abandon(&s);
    for (int i = 0; i < 2; i++)
        if (s.verifypipe[i] >= 0)
            close(s.verifypipe[i]);
    if (s.nchildren)
        stop_children(&s);
    while (s.conns) {
        conn *c = s.conns;
        s.conns = c->next;
        conn_free(&s, c);
    }
    while (s.jobs) {
        srv_entry *j = s.jobs;
        s.jobs = j->next;
        free_entry(j);
    }
    srv_state_close(s.state);
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
