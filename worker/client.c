#include "worker/client.h"

#include <assert.h>
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/clock.h"
#include "common/base/hash.h"
#include "common/base/net.h"
#include "common/base/text.h"
#include "common/image/denoise.h"
#include "common/render/guide.h"
#include "common/render/guide_sched.h"
#include "common/render/render.h"
#include "common/scene/bundle.h"
#include "protocol/auth.h"
#include "protocol/frame.h"
#include "protocol/guide.h"
#include "protocol/msg.h"
#include "worker/cache.h"

#define BACKOFF_MIN_MS 200
#define BACKOFF_MAX_MS 10000
#define CONNECT_TIMEOUT_MS 5000
#define HANDSHAKE_TIMEOUT_MS 15000
#define HEARTBEAT_MIN_MS 200
#define IN_START ((size_t)64 << 10)
#define IN_MAX ((size_t)PROTO_MAX_PAYLOAD + PROTO_FRAME_OVERHEAD)
#define OUT_MAX ((size_t)32 << 20)
/* Finished results wait in the done list while this much output is unsent:
 * a coordinator that stops reading gets backpressure, not an unbounded buffer. */
#define OUT_HIGH_WATER ((size_t)8 << 20)
/* Renderers kept while unused: a frame-range job's frames are separate
 * scenes (each posed at its time), and a worker holds tasks of two or three
 * frames at once where one frame's last tasks meet the next's first. */
#define SCENES_IN_MEMORY 4u
/* Denoise inputs whose fetch JOB_END cut short that are remembered (below). */
#define DN_ABANDONED 8u

/* ---- shared between the I/O thread and the render threads ---------------------------- */

/* A guiding distribution (GUIDE in protocol/msg.h), fetched by hash once.
 * The I/O thread owns the list; render threads read a fetched guide. */
typedef struct guide_rec {
    uint8_t hash[PROTO_HASH_SIZE];
    pt_guide *guide; /* NULL until fetched and checked */
    int fetching;    /* a GUIDE_GET is outstanding on this connection */
    uint8_t *buf;
    size_t len, cap;
    uint64_t total;
    uint64_t t_fetch; /* when its first GUIDE_GET went (ms) */
    struct guide_rec *next;
} guide_rec;

/* Distributions kept besides the newest: a job's passes are fetched one
 * after another, each once; older ones are freed only while no task is
 * queued or rendering (no render thread can be reading one). */
#define GUIDES_KEPT 2u

/* A task held: a render task, or a denoise task (DENOISE_TASK in
 * protocol/msg.h), which then also fills t's job id, task id and lease, so
 * that the render queue, HEARTBEAT and JOB_END treat both kinds alike. */
typedef struct task_item {
    proto_task t;
    guide_rec *guide; /* a guided task's distribution, once fetched */
    char *entry;      /* the scene's entry file (pt_strdup) once known */
    uint64_t epoch;   /* connection it belongs to */
    int denoise;      /* 1: a denoise task, dt */
    proto_denoise_task dt;
    /* Its input, dt.size bytes (the 20 planes, little-endian as fetched;
     * denoise_one reads them as floats in place): NULL until its fetch
     * starts, complete and checked against dt.hash once input_len is
     * dt.size. */
    float *input;
    size_t input_len;
    struct task_item *next;
} task_item;

typedef struct done_item {
    proto_task t;
    proto_result gres; /* a guided task's statistics (guide, owns_guide), else zeros */
    uint64_t epoch;
    pt_status st; /* PT_OK: pixels hold the result */
    pt_error err; /* why not */
    pt_render_stats stats;
    pt_pixel_acc *pixels;
    pt_pass_acc *pass; /* the render passes' sums, when the task asks for them */
    int denoise;       /* 1: a denoise task's, dt and rgb (t holds its ids) */
    proto_denoise_task dt;
    uint8_t *rgb; /* DENOISE_RESULT's data: the region's R, G, B planes, little-endian */
    struct done_item *next;
} done_item;

typedef struct running_slot {
    int active;
    int dropped; /* its job ended (JOB_END): the result is discarded */
    int denoise; /* a denoise task */
    uint64_t job_id, task_id;
    uint32_t lease_ms;
    uint64_t epoch;
} running_slot;

typedef struct worker worker;

typedef struct render_arg {
    worker *w;
    uint32_t index;
} render_arg;

/* I/O-thread state for one scene hash: known on disk, or being fetched. */
typedef struct scene_rec {
    uint8_t hash[PROTO_HASH_SIZE];
    char *entry;  /* entry file path, NULL until cached */
    int fetching; /* a SCENE_GET is outstanding on this connection */
    uint8_t *buf; /* bytes received so far */
    size_t len, cap;
    uint64_t total; /* from the first chunk */
    struct scene_rec *next;
} scene_rec;

enum { S_HELLO, S_AUTH, S_READY };
/* How a session ended. */
enum { END_RETRY, END_STOP, END_FATAL };

struct worker {
    const wrk_client_opts *o;
    char host[256];
    uint16_t port;
    char name[PROTO_MAX_NAME + 1];
    uint8_t token[PROTO_TOKEN_MAX];
    size_t token_len;
    uint8_t server_nonce[PROTO_NONCE_SIZE]; /* this session's CHALLENGE */
    uint8_t own_nonce[PROTO_NONCE_SIZE];    /* sent in AUTH; WELCOME's proof covers it */
    uint32_t slots_max;                     /* threads + prefetch */
    uint32_t link_timeout_ms;
    int link_warned; /* the kernel refused the link-timeout options once; said so */

    wrk_cache *cache;
    wrk_scenes *scenes;

    /* Shared, under mu. */
    pthread_mutex_t mu;
    pthread_cond_t cv;      /* queue got a task, or stop */
    pthread_cond_t exit_cv; /* a render thread ended */
    task_item *q_head, *q_tail;
    uint32_t nqueued;
    done_item *d_head, *d_tail;
    running_slot *running;
    uint32_t threads_alive;
    uint64_t epoch;
    int stop;
    int wake_w; /* render threads write a byte here */

    /* I/O thread only. */
    int wake_r;
    int fd;
    int state;
    proto_frame_reader in;
    proto_writer out;
    size_t out_sent;
    uint32_t requested; /* slots asked for, TASKs not yet received */
    task_item *pending; /* tasks waiting for their scene or distribution */
    uint32_t npending;
    /* Denoise tasks not yet in the render queue, in arrival order: waiting,
     * their input being fetched (one at a time), or fetched. One runs at a
     * time (pt_denoise starts a thread per render thread itself and needs
     * about 0.4 KiB a pixel, so a second one at once would only share the
     * cores and double the memory), and the next one's input is fetched
     * while it runs. */
    task_item *dn_head, *dn_tail;
    uint32_t ndn;
    int dn_get_out; /* a DENOISE_GET is outstanding, for this: */
    uint8_t dn_get_hash[PROTO_HASH_SIZE];
    uint64_t dn_get_offset, dn_get_total;
    /* The inputs of DENOISE_GETs that JOB_END left unanswered: the
     * coordinator may answer them still, or never (a frame it finished
     * itself first), so the fetch goes on with the next task and a
     * DENOISE_CHUNK of one of these is dropped. The last DN_ABANDONED are
     * kept: it leases a worker one region at a time and answers in order,
     * so a late answer comes within a round trip of its JOB_END. */
    uint8_t dn_abandoned[DN_ABANDONED][PROTO_HASH_SIZE];
    uint32_t ndn_abandoned; /* ever, this session */
    /* Test hook, unset in production: with PTWORKER_TEST_DENOISE_LIE in the
     * environment (any value) the worker flips the lowest mantissa bit of
     * the first value of every DENOISE_RESULT it sends, so that a
     * coordinator test can see a lying worker caught. */
    int test_denoise_lie;
    scene_rec *scenes_known;
    guide_rec *guides; /* the I/O thread's */
    uint64_t t_connect, t_heartbeat;
    char reason[1600]; /* why the session ended */

    /* Totals for the summary. */
    uint64_t tasks_done, samples, failed, denoised;
    uint64_t t_start;
};

static volatile sig_atomic_t g_stop;
static int g_sig_w = -1;

static void on_signal(int sig)
{
    (void)sig;
    int e = errno;
    g_stop = 1;
    if (g_sig_w >= 0) {
        char b = 1;
        ssize_t r = write(g_sig_w, &b, 1);
        (void)r;
    }
    errno = e;
}

static int make_pipe(int fds[2])
{
    if (pipe(fds) != 0)
        return -1;
    for (int i = 0; i < 2; i++) {
        fcntl(fds[i], F_SETFL, fcntl(fds[i], F_GETFL) | O_NONBLOCK);
        fcntl(fds[i], F_SETFD, FD_CLOEXEC);
    }
    return 0;
}

static void drain(int fd)
{
    char buf[256];
    while (read(fd, buf, sizeof buf) > 0) {
    }
}

void wrk_client_default_cache_dir(char *buf, size_t cap)
{
    const char *x = getenv("XDG_CACHE_HOME"), *home = getenv("HOME");
    if (x && x[0] == '/')
        snprintf(buf, cap, "%s/ptfarm", x);
    else if (home && home[0] == '/')
        snprintf(buf, cap, "%s/.cache/ptfarm", home);
    else
        snprintf(buf, cap, "/tmp/ptfarm-cache-%ld", (long)getuid());
}

static void task_free(task_item *t)
{
    if (t) {
        pt_free(t->entry);
        pt_free(t->input);
        pt_free(t);
    }
}

static void done_free(done_item *d)
{
    if (d) {
        proto_result_fini(&d->gres);
        pt_free(d->pixels);
        pt_free(d->pass);
        pt_free(d->rgb);
        pt_free(d);
    }
}

/* ---- render threads ------------------------------------------------------------------ */

static void render_one(worker *w, const task_item *t, done_item *d)
{
    const proto_task *k = &t->t;
    pt_render_params p;
    memset(&p, 0, sizeof p);
    pt_render_params_default(&p);
    p.width = k->width;
    p.height = k->height;
    p.seed = k->seed;
    p.max_depth = k->max_depth;
    p.rr_depth = k->rr_depth;
    p.light_strategy = PT_LIGHT_MIS;
    p.transparent = (k->film_flags & PROTO_FILM_TRANSPARENT) ? 1u : 0u;
    p.bdpt = (k->film_flags & PROTO_FILM_BDPT) ? 1u : 0u;
    p.passes = proto_film_passes(k->film_flags);
    p.clamp_direct = k->clamp[0];
    p.clamp_indirect = k->clamp[1];
    size_t npx = (size_t)(k->tile.x1 - k->tile.x0) * (k->tile.y1 - k->tile.y0);
    d->pixels = pt_malloc_array(npx, sizeof *d->pixels);
    if (p.passes)
        d->pass = pt_malloc_array(npx, sizeof *d->pass);
    if (!d->pixels || (p.passes && !d->pass)) {
        d->st = pt_error_set(&d->err, PT_ERR_NOMEM, "out of memory for %zu pixels", npx);
        return;
    }
    /* A guided task: the pass's distribution, and unless the pass is the
     * job's last (nothing is built from its statistics) statistics of its
     * own (they add exactly at the coordinator, whatever the tasks). */
    p.guiding = k->guided != PROTO_GUIDE_NONE;
    pt_guide_stats *gs = NULL;
    pt_render_guiding gd = {0}, *gdp = NULL;
    if (p.guiding) {
        if (k->guided == PROTO_GUIDE_RECORD) {
            d->st = pt_guide_stats_new(t->guide->guide, &gs, &d->err);
            if (d->st != PT_OK)
                return;
        }
        gd = (pt_render_guiding){t->guide->guide, pt_guide_pass_prob(k->guide_pass), gs};
        gdp = &gd;
    }
    wrk_scene_ref *ref = NULL;
    wrk_pose pose = {k->animate, k->time, k->animation};
    wrk_scene_look look = {k->camera, k->variant, &k->env, &pose, k->shutter};
    d->st = wrk_scenes_acquire(w->scenes, k->scene_hash, &p, &look, t->entry, &ref, &d->err);
    if (d->st != PT_OK) {
        pt_guide_stats_free(gs);
        return;
    }
    pt_render_tile_passes(wrk_scene_renderer(ref), k->tile, k->s0, k->s1, d->pixels, d->pass,
                          &d->stats, gdp);
    wrk_scenes_release(w->scenes, ref);
    if (gs)
        d->st = proto_guide_stats_to_result(gs, &d->gres, &d->err);
    pt_guide_stats_free(gs);
}

/* A denoise task: its crop denoised as a whole image (pt_denoise, on as
 * many threads as the worker renders with), and its region's pixels kept as
 * DENOISE_RESULT carries them. pt_denoise's refusal of the input is d->st. */
static void denoise_one(worker *w, const task_item *t, done_item *d)
{
    const proto_denoise_task *k = &t->dt;
    d->denoise = 1;
    d->dt = *k;
    size_t plane = (size_t)k->crop_w * k->crop_h;
    /* The decoder held the size to the crop's, and the region within it. */
    assert(k->size == plane * PT_DENOISE_PLANES * 4 && t->input_len == k->size);
    assert(k->region.x1 <= k->crop_w && k->region.y1 <= k->crop_h);
    /* The planes came little-endian: read in place as floats, so that the
     * byte order stays wire.h's business (pt_malloc'd, the buffer is
     * aligned for them). */
    float *v = t->input;
    const uint8_t *b = (const uint8_t *)t->input;
    for (size_t i = 0; i < plane * PT_DENOISE_PLANES; i++)
        v[i] = proto_get_f32(b + 4 * i);
    const float *p[PT_DENOISE_PLANES];
    for (size_t i = 0; i < PT_DENOISE_PLANES; i++)
        p[i] = v + i * plane;
    pt_denoise_input in;
    memset(&in, 0, sizeof in); /* no cancel flag, no progress */
    in.width = k->crop_w;
    in.height = k->crop_h;
    pt_denoise_input_set_planes(&in, p);
    in.despeckle = k->despeckle;
    size_t n = (size_t)(k->region.x1 - k->region.x0) * (k->region.y1 - k->region.y0);
    float *out = pt_malloc_array(plane, 3 * sizeof *out);
    d->rgb = pt_malloc_array(n, 12);
    if (!out || !d->rgb) {
        pt_free(out);
        d->st = pt_error_set(&d->err, PT_ERR_NOMEM, "out of memory for a %ux%u crop", k->crop_w,
                             k->crop_h);
        return;
    }
    float *o[3] = {out, out + plane, out + 2 * plane};
    unsigned threads =
        w->o->threads < PT_DENOISE_MAX_THREADS ? w->o->threads : PT_DENOISE_MAX_THREADS;
    d->st = pt_denoise(&in, threads, o, &d->err);
    if (d->st == PT_OK) {
        uint8_t *q = d->rgb;
        for (int c = 0; c < 3; c++)
            for (uint32_t y = k->region.y0; y < k->region.y1; y++)
                for (uint32_t x = k->region.x0; x < k->region.x1; x++, q += 4)
                    proto_put_f32(q, o[c][(size_t)y * k->crop_w + x]);
    }
    pt_free(out);
}

static void wake_io(worker *w)
{
    char b = 1;
    ssize_t r = write(w->wake_w, &b, 1); /* EAGAIN: a wake-up is pending anyway */
    (void)r;
}

static void *render_thread(void *p)
{
    render_arg *a = p;
    worker *w = a->w;
    running_slot *slot = &w->running[a->index];
    pthread_mutex_lock(&w->mu);
    for (;;) {
        while (!w->stop && !w->q_head)
            pthread_cond_wait(&w->cv, &w->mu);
        if (w->stop)
            break;
        task_item *t = w->q_head;
        w->q_head = t->next;
        if (!w->q_head)
            w->q_tail = NULL;
        w->nqueued--;
        slot->active = 1;
        slot->dropped = 0;
        slot->denoise = t->denoise;
        slot->job_id = t->t.job_id;
        slot->task_id = t->t.task_id;
        slot->lease_ms = t->t.lease_ms;
        slot->epoch = t->epoch;
        pthread_mutex_unlock(&w->mu);

        done_item *d = pt_calloc(1, sizeof *d);
        if (d) {
            d->t = t->t;
            d->epoch = t->epoch;
            if (t->denoise)
                denoise_one(w, t, d);
            else
                render_one(w, t, d);
        }
        task_free(t);

        pthread_mutex_lock(&w->mu);
        slot->active = 0;
        if (d && d->epoch == w->epoch && !w->stop && !slot->dropped) {
            if (w->d_tail)
                w->d_tail->next = d;
            else
                w->d_head = d;
            w->d_tail = d;
        } else {
            done_free(d); /* its connection is gone (the task was requeued) or its job ended */
        }
        wake_io(w); /* also when d is NULL: a slot is free */
    }
    w->threads_alive--;
    pthread_cond_broadcast(&w->exit_cv);
    pthread_mutex_unlock(&w->mu);
    return NULL;
}

/* ---- the link ------------------------------------------------------------------------ */

/*
 * Makes a dead link fail the connection within about link_timeout_ms, even
 * when no FIN or RST ever arrives (a cable pulled, a host gone, packets
 * dropped): without this, Linux retransmits for ~15 minutes and an idle
 * connection lives forever, so a worker cut off would hold a connection the
 * coordinator has long given up on and never rejoin.
 *
 * TCP_USER_TIMEOUT (RFC 5482; tcp(7)) bounds how long sent data may stay
 * unacknowledged; heartbeats and results are sent while tasks are held, so a
 * busy worker notices through it. An idle worker (no tasks: nothing to send)
 * sends keepalive probes after link/2 of silence, every link/6; with a user
 * timeout set the kernel aborts once the link has been silent for link_ms
 * with a probe unanswered, so both cases fail after about link_ms. The peer's
 * kernel acknowledges data and answers probes even while ptserve is busy, so
 * a slow coordinator is not mistaken for a dead link.
 */
static int set_link_timeout(int fd, uint32_t link_ms)
{
    int one = 1;
    unsigned int user_ms = link_ms;
    int idle = (int)(link_ms / 2000u), intvl = (int)(link_ms / 6000u), cnt = 3;
    if (idle < 1)
        idle = 1;
    if (intvl < 1)
        intvl = 1;
    if (setsockopt(fd, SOL_SOCKET, SO_KEEPALIVE, &one, sizeof one) != 0 ||
        setsockopt(fd, IPPROTO_TCP, TCP_KEEPIDLE, &idle, sizeof idle) != 0 ||
        setsockopt(fd, IPPROTO_TCP, TCP_KEEPINTVL, &intvl, sizeof intvl) != 0 ||
        setsockopt(fd, IPPROTO_TCP, TCP_KEEPCNT, &cnt, sizeof cnt) != 0 ||
        setsockopt(fd, IPPROTO_TCP, TCP_USER_TIMEOUT, &user_ms, sizeof user_ms) != 0)
        return -1;
    return 0;
}

/* w->reason for a failed send or recv; ETIMEDOUT is the link timeout firing, or
 * the route's error when this end of the link went down. */
static void socket_failed(worker *w, const char *call, int e)
{
    if (e == ETIMEDOUT)
        snprintf(w->reason, sizeof w->reason,
                 "no answer from the server for %.1f s (--link-timeout): link or host down",
                 w->link_timeout_ms / 1000.0);
    else if (e == ENETUNREACH || e == EHOSTUNREACH)
        snprintf(w->reason, sizeof w->reason, "%s: %s (the link to the server is down)", call,
                 strerror(e));
    else
        snprintf(w->reason, sizeof w->reason, "%s: %s", call, strerror(e));
}

/* ---- output -------------------------------------------------------------------------- */

/* Sends what the socket takes now. 0, or -1 with w->reason set. */
static int flush_out(worker *w)
{
    while (w->out_sent < w->out.len) {
        ssize_t n = send(w->fd, w->out.buf + w->out_sent, w->out.len - w->out_sent,
                         MSG_NOSIGNAL | MSG_DONTWAIT);
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK))
            break;
        if (n <= 0) {
            socket_failed(w, "send", n < 0 ? errno : EPIPE);
            return -1;
        }
        w->out_sent += (size_t)n;
    }
    if (w->out_sent == w->out.len) {
        proto_writer_reset(&w->out);
        w->out_sent = 0;
    } else if (w->out_sent >= ((size_t)1 << 20)) {
        /* Move the unsent tail to the front so the buffer does not creep. */
        size_t left = w->out.len - w->out_sent;
        memmove(w->out.buf, w->out.buf + w->out_sent, left);
        proto_writer_truncate(&w->out, left);
        w->out_sent = 0;
    }
    return 0;
}

static size_t out_pending(const worker *w)
{
    return w->out.len - w->out_sent;
}

/* The end of framing one message into w->out (proto_frame_begin, then
 * proto_frame_finish with the encoder's status): 0, or -1 with the reason. */
static int queued(worker *w, uint16_t type, pt_status st, const pt_error *e)
{
    if (st == PT_OK)
        return 0;
    snprintf(w->reason, sizeof w->reason, "cannot queue %s: %s", proto_msg_type_name(type),
             e->msg[0] ? e->msg : pt_status_str(st));
    return -1;
}

static int send_hello(worker *w)
{
    proto_hello h;
    memset(&h, 0, sizeof h);
    h.version = PROTO_VERSION;
    h.role = PROTO_ROLE_WORKER;
    snprintf(h.name, sizeof h.name, "%s", w->name);
    h.threads = (uint16_t)w->o->threads;
    snprintf(h.build_id, sizeof h.build_id, "%s", proto_build_id());
    h.caps = PROTO_CAP_DENOISE;
    size_t mark;
    pt_error e = {0};
    pt_status st = proto_frame_begin(&w->out, PROTO_MSG_HELLO, &mark, &e);
    if (st == PT_OK)
        st = proto_frame_finish(&w->out, mark, proto_msg_encode_hello(&w->out, &h, &e), &e);
    return queued(w, PROTO_MSG_HELLO, st, &e);
}

static int send_scene_get(worker *w, const uint8_t *hash, uint64_t offset)
{
    proto_scene_get g;
    memcpy(g.hash, hash, PROTO_HASH_SIZE);
    g.offset = offset;
    size_t mark;
    pt_error e = {0};
    pt_status st = proto_frame_begin(&w->out, PROTO_MSG_SCENE_GET, &mark, &e);
    if (st == PT_OK)
        st = proto_frame_finish(&w->out, mark, proto_msg_encode_scene_get(&w->out, &g, &e), &e);
    return queued(w, PROTO_MSG_SCENE_GET, st, &e);
}

/* Tells the coordinator why we hang up (best effort; it closes after ERROR too). */
static void send_error(worker *w, uint16_t code, const char *text)
{
    proto_error_msg m;
    m.code = code;
    snprintf(m.text, sizeof m.text, "%s", text);
    size_t mark;
    if (proto_frame_begin(&w->out, PROTO_MSG_ERROR, &mark, NULL) == PT_OK &&
        proto_frame_finish(&w->out, mark, proto_msg_encode_error(&w->out, &m, NULL), NULL) == PT_OK)
        flush_out(w);
}

/* The server broke the protocol: say why (to it and in w->reason); -1. */
static int fail_proto(worker *w, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static int fail_proto(worker *w, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(w->reason, sizeof w->reason, fmt, ap);
    va_end(ap);
    send_error(w, PROTO_E_PROTOCOL, w->reason);
    return -1;
}

/* ---- the task pipeline --------------------------------------------------------------- */

/* Slots taken: tasks waiting for a scene or a denoise input, queued, and
 * render threads busy (also with a task of a dropped connection: the thread
 * is not free yet). */
static uint32_t slots_taken(worker *w)
{
    pthread_mutex_lock(&w->mu);
    uint32_t n = w->nqueued;
    for (uint32_t i = 0; i < w->o->threads; i++)
        n += w->running[i].active != 0;
    pthread_mutex_unlock(&w->mu);
    return n + w->npending + w->ndn + w->requested;
}

static int request_work(worker *w)
{
    uint32_t busy = slots_taken(w);
    if (busy >= w->slots_max)
        return 0;
    uint32_t slots = w->slots_max - busy;
    if (slots > PROTO_MAX_SLOTS)
        slots = PROTO_MAX_SLOTS;
    proto_work_request r = {(uint16_t)slots};
    size_t mark;
    pt_error e = {0};
    pt_status st = proto_frame_begin(&w->out, PROTO_MSG_WORK_REQUEST, &mark, &e);
    if (st == PT_OK)
        st = proto_frame_finish(&w->out, mark, proto_msg_encode_work_request(&w->out, &r, &e), &e);
    if (queued(w, PROTO_MSG_WORK_REQUEST, st, &e) != 0)
        return -1;
    w->requested += slots;
    return 0;
}

/* Lists the tasks of list in hb, and lowers *min_lease to their leases. */
static void heartbeat_list(proto_heartbeat *hb, uint32_t *min_lease, const task_item *list)
{
    for (const task_item *t = list; t; t = t->next) {
        if (hb->count < PROTO_MAX_HEARTBEAT_TASKS)
            hb->task_ids[hb->count++] = t->t.task_id;
        if (t->t.lease_ms < *min_lease)
            *min_lease = t->t.lease_ms;
    }
}

static int send_heartbeat(worker *w, uint64_t now)
{
    static proto_heartbeat hb; /* large; only the I/O thread uses it */
    uint32_t min_lease = UINT32_MAX;
    hb.count = 0;
    heartbeat_list(&hb, &min_lease, w->pending);
    heartbeat_list(&hb, &min_lease, w->dn_head);
    pthread_mutex_lock(&w->mu);
    heartbeat_list(&hb, &min_lease, w->q_head);
    for (uint32_t i = 0; i < w->o->threads; i++) {
        const running_slot *s = &w->running[i];
        if (!s->active || s->dropped || s->epoch != w->epoch)
            continue;
        if (hb.count < PROTO_MAX_HEARTBEAT_TASKS)
            hb.task_ids[hb.count++] = s->task_id;
        if (s->lease_ms < min_lease)
            min_lease = s->lease_ms;
    }
    for (done_item *d = w->d_head; d; d = d->next)
        if (hb.count < PROTO_MAX_HEARTBEAT_TASKS)
            hb.task_ids[hb.count++] = d->t.task_id;
    pthread_mutex_unlock(&w->mu);
    uint32_t interval = min_lease == UINT32_MAX ? 1000u : min_lease / 3;
    if (interval < HEARTBEAT_MIN_MS)
        interval = HEARTBEAT_MIN_MS;
    w->t_heartbeat = now + interval;
    if (hb.count == 0)
        return 0; /* nothing to keep alive */
    size_t mark;
    pt_error e = {0};
    pt_status st = proto_frame_begin(&w->out, PROTO_MSG_HEARTBEAT, &mark, &e);
    if (st == PT_OK)
        st = proto_frame_finish(&w->out, mark, proto_msg_encode_heartbeat(&w->out, &hb, &e), &e);
    return queued(w, PROTO_MSG_HEARTBEAT, st, &e);
}

static void enqueue(worker *w, task_item *t)
{
    pthread_mutex_lock(&w->mu);
    t->next = NULL;
    if (w->q_tail)
        w->q_tail->next = t;
    else
        w->q_head = t;
    w->q_tail = t;
    w->nqueued++;
    pthread_cond_signal(&w->cv);
    pthread_mutex_unlock(&w->mu);
}

static scene_rec *scene_find(worker *w, const uint8_t *hash, int create)
{
    for (scene_rec *s = w->scenes_known; s; s = s->next)
        if (memcmp(s->hash, hash, PROTO_HASH_SIZE) == 0)
            return s;
    if (!create)
        return NULL;
    scene_rec *s = pt_calloc(1, sizeof *s);
    if (!s)
        return NULL;
    memcpy(s->hash, hash, PROTO_HASH_SIZE);
    s->next = w->scenes_known;
    w->scenes_known = s;
    return s;
}

static void fetch_reset(scene_rec *s)
{
    pt_free(s->buf);
    s->buf = NULL;
    s->len = s->cap = 0;
    s->total = 0;
    s->fetching = 0;
}

static guide_rec *guide_find(worker *w, const uint8_t *hash, int create)
{
    for (guide_rec *g = w->guides; g; g = g->next)
        if (memcmp(g->hash, hash, PROTO_HASH_SIZE) == 0)
            return g;
    if (!create)
        return NULL;
    guide_rec *g = pt_calloc(1, sizeof *g);
    if (!g)
        return NULL;
    memcpy(g->hash, hash, PROTO_HASH_SIZE);
    g->next = w->guides;
    w->guides = g;
    return g;
}

static void guide_fetch_reset(guide_rec *g)
{
    pt_free(g->buf);
    g->buf = NULL;
    g->len = g->cap = 0;
    g->total = 0;
    g->fetching = 0;
}

static int send_guide_get(worker *w, const uint8_t *hash, uint64_t offset)
{
    proto_scene_get g;
    memcpy(g.hash, hash, PROTO_HASH_SIZE);
    g.offset = offset;
    size_t mark;
    pt_error e = {0};
    pt_status st = proto_frame_begin(&w->out, PROTO_MSG_GUIDE_GET, &mark, &e);
    if (st == PT_OK)
        st = proto_frame_finish(&w->out, mark, proto_msg_encode_scene_get(&w->out, &g, &e), &e);
    return queued(w, PROTO_MSG_GUIDE_GET, st, &e);
}

/* Frees fetched distributions past the newest GUIDES_KEPT + 1 while no task
 * is queued or rendering (then no render thread reads one). */
static void guides_trim(worker *w)
{
    pthread_mutex_lock(&w->mu);
    int idle = w->nqueued == 0;
    for (uint32_t i = 0; idle && i < w->threads_alive; i++)
        idle = !w->running[i].active;
    pthread_mutex_unlock(&w->mu);
    if (!idle)
        return;
    uint32_t kept = 0;
    for (guide_rec **pp = &w->guides; *pp;) {
        guide_rec *g = *pp;
        if (g->guide && !g->fetching && kept++ > GUIDES_KEPT) {
            *pp = g->next;
            pt_guide_free(g->guide);
            guide_fetch_reset(g);
            pt_free(g);
            continue;
        }
        pp = &g->next;
    }
}

/* t goes to the render queue once its scene is on disk and (guided) its
 * distribution is here; else it waits in pending. -1 without memory. */
static int enqueue_when_ready(worker *w, task_item *t, const scene_rec *s)
{
    if (t->t.guided && !t->guide) {
        guide_rec *g = guide_find(w, t->t.guide_hash, 0);
        if (g && g->guide)
            t->guide = g;
    }
    if (s && s->entry && !t->entry && !(t->entry = pt_strdup(s->entry))) {
        snprintf(w->reason, sizeof w->reason, "out of memory");
        task_free(t);
        return -1;
    }
    if (t->entry && (!t->t.guided || t->guide)) {
        enqueue(w, t);
    } else {
        t->next = w->pending;
        w->pending = t;
        w->npending++;
    }
    return 0;
}

/* A scene is on disk or a distribution arrived: the tasks waiting on it
 * that have all they need go to the render queue. */
static int pending_ready(worker *w)
{
    task_item *list = w->pending;
    w->pending = NULL;
    w->npending = 0;
    int rc = 0;
    while (list) {
        task_item *t = list;
        list = t->next;
        t->next = NULL;
        if (rc == 0)
            rc = enqueue_when_ready(w, t, scene_find(w, t->t.scene_hash, 0));
        else
            task_free(t);
    }
    return rc;
}

/* The scene is on disk: its waiting tasks go to the render queue. */
static int scene_ready(worker *w, scene_rec *s)
{
    (void)s;
    return pending_ready(w);
}

/* A shorter lease than those held so far brings the next heartbeat closer. */
static void lease_seen(worker *w, uint32_t lease_ms)
{
    uint32_t interval = lease_ms / 3 > HEARTBEAT_MIN_MS ? lease_ms / 3 : HEARTBEAT_MIN_MS;
    if (pt_now_ms() + interval < w->t_heartbeat)
        w->t_heartbeat = pt_now_ms() + interval;
}

static int on_task(worker *w, const proto_frame *f)
{
    pt_error err = {0};
    task_item *t = pt_calloc(1, sizeof *t);
    if (!t) {
        snprintf(w->reason, sizeof w->reason, "out of memory");
        return -1;
    }
    if (proto_msg_decode_task(f->payload, f->len, &t->t, &err) != PT_OK) {
        pt_free(t);
        return fail_proto(w, "bad TASK: %s", err.msg);
    }
    if (w->requested == 0) {
        unsigned long long id = t->t.task_id;
        pt_free(t);
        return fail_proto(w, "TASK %llu was not asked for", id);
    }
    w->requested--;
    lease_seen(w, t->t.lease_ms);
    pthread_mutex_lock(&w->mu);
    t->epoch = w->epoch;
    pthread_mutex_unlock(&w->mu);

    scene_rec *s = scene_find(w, t->t.scene_hash, 1);
    if (!s) {
        snprintf(w->reason, sizeof w->reason, "out of memory");
        pt_free(t);
        return -1;
    }
    if (!s->entry && !s->fetching) {
        char entry[4096], hex[65];
        pt_status st = wrk_cache_lookup(w->cache, s->hash, entry, sizeof entry, &err);
        if (st == PT_OK) {
            s->entry = pt_strdup(entry);
            if (!s->entry) {
                snprintf(w->reason, sizeof w->reason, "out of memory");
                pt_free(t);
                return -1;
            }
        } else {
            if (st != PT_AGAIN)
                fprintf(stderr, "ptworker: %s; fetching it again\n", err.msg);
            pt_hash_hex(s->hash, hex);
            fprintf(stderr, "ptworker: fetching scene %.16s\n", hex);
            if (send_scene_get(w, s->hash, 0) != 0) {
                pt_free(t);
                return -1;
            }
            s->fetching = 1;
        }
    }
    if (t->t.guided) {
        guide_rec *g = guide_find(w, t->t.guide_hash, 1);
        if (!g) {
            snprintf(w->reason, sizeof w->reason, "out of memory");
            pt_free(t);
            return -1;
        }
        if (!g->guide && !g->fetching) {
            if (send_guide_get(w, g->hash, 0) != 0) {
                pt_free(t);
                return -1;
            }
            g->fetching = 1;
            g->t_fetch = pt_now_ms();
        }
    }
    return enqueue_when_ready(w, t, s);
}

static int on_guide_chunk(worker *w, const proto_frame *f)
{
    pt_error err = {0};
    proto_scene_chunk c;
    if (proto_msg_decode_scene_chunk(f->payload, f->len, &c, &err) != PT_OK)
        return fail_proto(w, "bad GUIDE_CHUNK: %s", err.msg);
    char hex[65];
    pt_hash_hex(c.hash, hex);
    guide_rec *g = guide_find(w, c.hash, 0);
    if (!g || !g->fetching)
        return fail_proto(w, "GUIDE_CHUNK for distribution %.16s, not asked for", hex);
    if (c.offset != g->len || (g->len > 0 && c.total != g->total) || c.total == 0 ||
        c.total > PROTO_MAX_GUIDE_BYTES || (c.len == 0 && c.offset < c.total))
        return fail_proto(w, "GUIDE_CHUNK for %.16s at %llu of %llu, expected %zu of %llu", hex,
                          (unsigned long long)c.offset, (unsigned long long)c.total, g->len,
                          (unsigned long long)g->total);
    g->total = c.total;
    if (g->len + c.len > g->cap) {
        size_t cap = (size_t)g->total;
        uint8_t *nb = pt_realloc(g->buf, cap);
        if (!nb) {
            snprintf(w->reason, sizeof w->reason, "out of memory for distribution %.16s", hex);
            return -1;
        }
        g->buf = nb;
        g->cap = cap;
    }
    memcpy(g->buf + g->len, c.data, c.len);
    g->len += c.len;
    if (g->len < g->total)
        return send_guide_get(w, g->hash, g->len);
    /* Unpacked (the size bounded before anything is allocated), its bytes
     * must be the ones TASK named, and a tree that samples safely. */
    uint64_t t_unpack = pt_now_ms();
    uint8_t *raw = NULL;
    size_t rawlen = 0;
    pt_status st = proto_guide_unpack(g->buf, g->len, &raw, &rawlen, &err);
    uint64_t unpack_ms = pt_now_ms() - t_unpack;
    pt_guide *gd = NULL;
    if (st == PT_OK) {
        uint8_t h[32];
        pt_sha256(raw, rawlen, h);
        st = memcmp(h, g->hash, 32) == 0
                 ? proto_guide_decode(raw, rawlen, &gd, &err)
                 : pt_error_set(&err, PT_ERR_FORMAT, "its bytes do not hash to its name");
    }
    pt_free(raw);
    if (st == PT_OK && (st = pt_guide_check(gd, &err)) != PT_OK) {
        pt_guide_free(gd);
        gd = NULL;
    }
    guide_fetch_reset(g);
    if (st != PT_OK)
        return fail_proto(w, "distribution %.16s: %s", hex, err.msg);
    g->guide = gd;
    fprintf(stderr,
            "ptworker: guiding distribution %.16s (%llu bytes, %zu unpacked) fetched in %llu ms "
            "(unpacked in %llu ms)\n",
            hex, (unsigned long long)c.total, rawlen,
            (unsigned long long)(pt_now_ms() - g->t_fetch), (unsigned long long)unpack_ms);
    guides_trim(w);
    return pending_ready(w);
}

static int on_scene_chunk(worker *w, const proto_frame *f)
{
    pt_error err = {0};
    proto_scene_chunk c;
    if (proto_msg_decode_scene_chunk(f->payload, f->len, &c, &err) != PT_OK)
        return fail_proto(w, "bad SCENE_CHUNK: %s", err.msg);
    char hex[65];
    pt_hash_hex(c.hash, hex);
    scene_rec *s = scene_find(w, c.hash, 0);
    if (!s || !s->fetching)
        return fail_proto(w, "SCENE_CHUNK for scene %.16s, not asked for", hex);
    if (c.offset != s->len || (s->len > 0 && c.total != s->total))
        return fail_proto(w, "SCENE_CHUNK for %.16s at %llu of %llu, expected %zu of %llu", hex,
                          (unsigned long long)c.offset, (unsigned long long)c.total, s->len,
                          (unsigned long long)s->total);
    if (c.total == 0 || c.total > PT_BUNDLE_MAX_BYTES)
        return fail_proto(w, "scene %.16s of %llu bytes (cap %llu)", hex,
                          (unsigned long long)c.total, (unsigned long long)PT_BUNDLE_MAX_BYTES);
    if (c.len == 0 && c.offset < c.total)
        return fail_proto(w, "empty SCENE_CHUNK for %.16s at %llu", hex,
                          (unsigned long long)c.offset);
    s->total = c.total;
    if (s->len + c.len > s->cap) {
        /* Grow by doubling, never past the declared total. */
        size_t cap = s->cap ? s->cap * 2 : ((size_t)1 << 20);
        if (cap < s->len + c.len)
            cap = s->len + c.len;
        if (cap > s->total)
            cap = (size_t)s->total;
        uint8_t *nb = pt_realloc(s->buf, cap);
        if (!nb) {
            snprintf(w->reason, sizeof w->reason, "out of memory for scene %.16s (%zu bytes)", hex,
                     cap);
            return -1;
        }
        s->buf = nb;
        s->cap = cap;
    }
    memcpy(s->buf + s->len, c.data, c.len);
    s->len += c.len;
    if (s->len < s->total)
        return send_scene_get(w, s->hash, s->len);

    char entry[4096];
    pt_status st = wrk_cache_store(w->cache, s->hash, s->buf, s->len, entry, sizeof entry, &err);
    fetch_reset(s);
    if (st == PT_ERR_FORMAT)
        return fail_proto(w, "scene %.16s: %s", hex, err.msg);
    if (st != PT_OK) {
        snprintf(w->reason, sizeof w->reason, "scene %.16s: %s", hex, err.msg);
        return -1;
    }
    s->entry = pt_strdup(entry);
    if (!s->entry) {
        snprintf(w->reason, sizeof w->reason, "out of memory");
        return -1;
    }
    fprintf(stderr, "ptworker: scene %.16s cached (%llu bytes)\n", hex,
            (unsigned long long)c.total);
    return scene_ready(w, s);
}

/* ---- denoise tasks ------------------------------------------------------------------- */

/* Asks for a denoise input from offset on, and remembers what was asked. */
static int send_denoise_get(worker *w, const proto_denoise_task *k, uint64_t offset)
{
    proto_scene_get g;
    memcpy(g.hash, k->hash, PROTO_HASH_SIZE);
    g.offset = offset;
    size_t mark;
    pt_error e = {0};
    pt_status st = proto_frame_begin(&w->out, PROTO_MSG_DENOISE_GET, &mark, &e);
    if (st == PT_OK)
        st = proto_frame_finish(&w->out, mark, proto_msg_encode_scene_get(&w->out, &g, &e), &e);
    if (queued(w, PROTO_MSG_DENOISE_GET, st, &e) != 0)
        return -1;
    w->dn_get_out = 1;
    memcpy(w->dn_get_hash, k->hash, PROTO_HASH_SIZE);
    w->dn_get_offset = offset;
    w->dn_get_total = k->size;
    return 0;
}

/* The denoise task whose input is being fetched (fetched 0) or is complete
 * (fetched 1), or NULL. */
static task_item *denoise_find(worker *w, int fetched)
{
    for (task_item *t = w->dn_head; t; t = t->next)
        if (t->input && (t->input_len == t->dt.size) == fetched)
            return t;
    return NULL;
}

/* 1 while a denoise task is queued for a render thread or running on one
 * (of any connection: its memory is still taken). */
static int denoiser_busy(worker *w)
{
    int busy = 0;
    pthread_mutex_lock(&w->mu);
    for (const task_item *t = w->q_head; t && !busy; t = t->next)
        busy = t->denoise;
    for (uint32_t i = 0; i < w->o->threads && !busy; i++)
        busy = w->running[i].active && w->running[i].denoise;
    pthread_mutex_unlock(&w->mu);
    return busy;
}

/* Takes t out of the list *head .. *tail (t is in it). */
static void unlink_task(task_item **head, task_item **tail, task_item *t)
{
    task_item *last = NULL;
    while (*head != t) {
        last = *head;
        head = &last->next;
    }
    *head = t->next;
    if (*tail == t)
        *tail = last;
    t->next = NULL;
}

/* Moves the denoise tasks along: a fetched one to the render queue once no
 * other is queued or running, and the next one's input fetched once none is
 * being fetched or waits fetched. 0, or -1 with the reason. */
static int denoise_advance(worker *w)
{
    task_item *ready = denoise_find(w, 1);
    if (ready && !denoiser_busy(w)) {
        unlink_task(&w->dn_head, &w->dn_tail, ready);
        w->ndn--;
        enqueue(w, ready);
        ready = NULL;
    }
    if (ready || w->dn_get_out || denoise_find(w, 0))
        return 0;
    for (task_item *t = w->dn_head, *next; t; t = next) {
        next = t->next;
        if (t->input)
            continue;
        t->input = pt_malloc((size_t)t->dt.size);
        if (t->input)
            return send_denoise_get(w, &t->dt, 0);
        /* As when pt_denoise runs out of memory: dropped, its lease runs out
         * and the coordinator denoises the region itself. */
        fprintf(stderr,
                "ptworker: denoise region %llu of job %llu: out of memory for its input (%llu "
                "bytes); dropped\n",
                (unsigned long long)(t->dt.task_id & ~PROTO_DENOISE_TASK_BIT),
                (unsigned long long)t->dt.job_id, (unsigned long long)t->dt.size);
        w->failed++;
        unlink_task(&w->dn_head, &w->dn_tail, t);
        w->ndn--;
        task_free(t);
    }
    return 0;
}

static int on_denoise_task(worker *w, const proto_frame *f)
{
    pt_error err = {0};
    task_item *t = pt_calloc(1, sizeof *t);
    if (!t) {
        snprintf(w->reason, sizeof w->reason, "out of memory");
        return -1;
    }
    if (proto_msg_decode_denoise_task(f->payload, f->len, &t->dt, &err) != PT_OK) {
        pt_free(t);
        return fail_proto(w, "bad DENOISE_TASK: %s", err.msg);
    }
    if (w->requested == 0) {
        unsigned long long id = t->dt.task_id & ~PROTO_DENOISE_TASK_BIT;
        pt_free(t);
        return fail_proto(w, "DENOISE_TASK for region %llu was not asked for", id);
    }
    w->requested--;
    lease_seen(w, t->dt.lease_ms);
    t->denoise = 1;
    t->t.job_id = t->dt.job_id;
    t->t.task_id = t->dt.task_id;
    t->t.lease_ms = t->dt.lease_ms;
    pthread_mutex_lock(&w->mu);
    t->epoch = w->epoch;
    pthread_mutex_unlock(&w->mu);
    if (w->dn_tail)
        w->dn_tail->next = t;
    else
        w->dn_head = t;
    w->dn_tail = t;
    w->ndn++;
    return denoise_advance(w);
}

static int on_denoise_chunk(worker *w, const proto_frame *f)
{
    pt_error err = {0};
    proto_scene_chunk c;
    if (proto_msg_decode_scene_chunk(f->payload, f->len, &c, &err) != PT_OK)
        return fail_proto(w, "bad DENOISE_CHUNK: %s", err.msg);
    char hex[65];
    pt_hash_hex(c.hash, hex);
    int asked = w->dn_get_out && memcmp(c.hash, w->dn_get_hash, PROTO_HASH_SIZE) == 0;
    if (!asked || c.offset != w->dn_get_offset || c.total != w->dn_get_total ||
        (c.len == 0 && c.offset < c.total)) {
        for (uint32_t i = 0; i < w->ndn_abandoned && i < DN_ABANDONED; i++)
            if (memcmp(c.hash, w->dn_abandoned[i], PROTO_HASH_SIZE) == 0)
                return 0; /* a late answer for a task whose job has ended */
        if (!asked)
            return fail_proto(w, "DENOISE_CHUNK for input %.16s, not asked for", hex);
        return fail_proto(w, "DENOISE_CHUNK for %.16s at %llu of %llu, expected %llu of %llu", hex,
                          (unsigned long long)c.offset, (unsigned long long)c.total,
                          (unsigned long long)w->dn_get_offset,
                          (unsigned long long)w->dn_get_total);
    }
    w->dn_get_out = 0;
    task_item *t = denoise_find(w, 0);
    assert(t); /* a GET is out only for the task being fetched */
    /* The decoder held offset + len to the total, which is the buffer's size. */
    memcpy((uint8_t *)t->input + t->input_len, c.data, c.len);
    t->input_len += c.len;
    if (t->input_len < t->dt.size)
        return send_denoise_get(w, &t->dt, t->input_len);
    uint8_t h[PROTO_HASH_SIZE];
    pt_sha256((const uint8_t *)t->input, t->input_len, h);
    if (memcmp(h, t->dt.hash, PROTO_HASH_SIZE) != 0)
        return fail_proto(w, "denoise input %.16s: its bytes do not hash to its name", hex);
    return denoise_advance(w);
}

/* A finished denoise task: its DENOISE_RESULT. An input pt_denoise refused
 * came from the coordinator, so that ends the session as a protocol error;
 * one it had no memory for is dropped (its lease runs out and the
 * coordinator denoises the region itself). Frees d. 0, or -1 with the
 * reason. */
static int send_denoise_result(worker *w, done_item *d)
{
    unsigned long long job = d->dt.job_id, region = d->dt.task_id & ~PROTO_DENOISE_TASK_BIT;
    if (d->st == PT_ERR_FORMAT || d->st == PT_ERR_ARG) {
        int rc = fail_proto(w, "denoise region %llu of job %llu: not a denoiser's input: %s",
                            region, job, d->err.msg);
        done_free(d);
        return rc;
    }
    if (d->st != PT_OK) {
        fprintf(stderr, "ptworker: denoise region %llu of job %llu failed: %s; dropped\n", region,
                job, d->err.msg);
        w->failed++;
        done_free(d);
        return 0;
    }
    proto_denoise_result r;
    r.job_id = d->dt.job_id;
    r.task_id = d->dt.task_id;
    r.region = d->dt.region;
    r.npixels = (r.region.x1 - r.region.x0) * (r.region.y1 - r.region.y0);
    r.data = d->rgb;
    if (w->test_denoise_lie)
        proto_put_u32(d->rgb, proto_get_u32(d->rgb) ^ 1u);
    size_t mark;
    pt_error e = {0};
    pt_status st = proto_frame_begin(&w->out, PROTO_MSG_DENOISE_RESULT, &mark, &e);
    if (st == PT_OK)
        st =
            proto_frame_finish(&w->out, mark, proto_msg_encode_denoise_result(&w->out, &r, &e), &e);
    done_free(d);
    if (queued(w, PROTO_MSG_DENOISE_RESULT, st, &e) != 0)
        return -1;
    w->denoised++;
    return 0;
}

/* Moves finished results into the output, while it is not too full. */
static int collect_results(worker *w)
{
    for (;;) {
        if (out_pending(w) >= OUT_HIGH_WATER)
            return 0;
        pthread_mutex_lock(&w->mu);
        done_item *d = w->d_head;
        if (d) {
            w->d_head = d->next;
            if (!w->d_head)
                w->d_tail = NULL;
        }
        pthread_mutex_unlock(&w->mu);
        if (!d)
            return 0;
        if (d->denoise) {
            if (send_denoise_result(w, d) != 0)
                return -1;
            continue;
        }
        if (d->st != PT_OK) {
            /* Dropped: the lease runs out and the coordinator hands it to another. */
            fprintf(stderr, "ptworker: task %llu of job %llu failed: %s\n",
                    (unsigned long long)d->t.task_id, (unsigned long long)d->t.job_id, d->err.msg);
            w->failed++;
            /* Look the scene up (and check it) again for its next task, in
             * case its files changed under us. */
            scene_rec *s = scene_find(w, d->t.scene_hash, 0);
            if (s && s->entry) {
                pt_free(s->entry);
                s->entry = NULL;
            }
            done_free(d);
            continue;
        }
        proto_result r;
        memset(&r, 0, sizeof r);
        r.job_id = d->t.job_id;
        r.task_id = d->t.task_id;
        r.tile = d->t.tile;
        r.s0 = d->t.s0;
        r.s1 = d->t.s1;
        r.rejected = d->stats.rejected;
        r.rays = d->stats.rays;
        r.capped = d->stats.capped;
        r.clamped = d->stats.clamped;
        r.npixels = (d->t.tile.x1 - d->t.tile.x0) * (d->t.tile.y1 - d->t.tile.y0);
        r.pixels = d->pixels;
        r.pass = d->pass;
        r.owns_pixels = 0;
        r.g_nsnode = d->gres.g_nsnode;
        r.g_nqnode = d->gres.g_nqnode;
        r.gcount = d->gres.gcount;
        r.gsum = d->gres.gsum;
        r.guide = d->gres.guide; /* d's, freed with it */
        uint64_t samples = d->stats.samples;
        size_t mark;
        pt_error e = {0};
        pt_status st = proto_frame_begin(&w->out, PROTO_MSG_RESULT, &mark, &e);
        if (st == PT_OK)
            st = proto_frame_finish(&w->out, mark, proto_msg_encode_result(&w->out, &r, &e), &e);
        done_free(d);
        if (queued(w, PROTO_MSG_RESULT, st, &e) != 0)
            return -1;
        w->tasks_done++;
        w->samples += samples;
    }
}

/* ---- input --------------------------------------------------------------------------- */

static int fatal_code(uint16_t code)
{
    return code == PROTO_E_AUTH || code == PROTO_E_BUILD || code == PROTO_E_VERSION;
}

static int on_challenge(worker *w, const proto_frame *f)
{
    pt_error err = {0};
    proto_challenge ch;
    if (proto_msg_decode_challenge(f->payload, f->len, &ch, &err) != PT_OK)
        return fail_proto(w, "bad CHALLENGE: %s", err.msg);
    proto_auth a;
    /* Without --token-file the token is empty: a loopback-only coordinator's. */
    pt_status st = proto_auth_response(w->token, w->token_len, ch.nonce, a.mac, &err);
    if (st == PT_OK)
        st = proto_auth_nonce(a.nonce, &err);
    if (st != PT_OK) {
        snprintf(w->reason, sizeof w->reason, "cannot answer the challenge: %s", err.msg);
        return -1;
    }
    size_t mark;
    st = proto_frame_begin(&w->out, PROTO_MSG_AUTH, &mark, &err);
    if (st == PT_OK)
        st = proto_frame_finish(&w->out, mark, proto_msg_encode_auth(&w->out, &a, &err), &err);
    if (queued(w, PROTO_MSG_AUTH, st, &err) != 0)
        return -1;
    memcpy(w->server_nonce, ch.nonce, PROTO_NONCE_SIZE);
    memcpy(w->own_nonce, a.nonce, PROTO_NONCE_SIZE);
    w->state = S_AUTH;
    return 0;
}

/* WELCOME: the coordinator must prove that it holds the token too, before
 * this worker asks it for work (a listener that does not know the token
 * could hand out scenes to render or swallow results). 0, or -1 with *end
 * set. */
static int on_welcome(worker *w, const proto_frame *f, int *end)
{
    pt_error err = {0};
    proto_welcome wm;
    if (proto_msg_decode_welcome(f->payload, f->len, &wm, &err) != PT_OK)
        return fail_proto(w, "bad WELCOME: %s", err.msg);
    if (proto_auth_check_server(w->token, w->token_len, w->server_nonce, w->own_nonce, wm.proof,
                                &err) != PT_OK) {
        fprintf(stderr,
                "ptworker: %s:%u: the coordinator does not know the token (its WELCOME "
                "proof is wrong); sending it nothing\n",
                w->host, w->port);
        *end = END_FATAL;
        return -1;
    }
    w->state = S_READY;
    w->t_heartbeat = pt_now_ms() + HEARTBEAT_MIN_MS;
    fprintf(stderr, "ptworker: connected to %s:%u as %s (%u threads)\n", w->host, w->port, w->name,
            w->o->threads);
    return 0;
}

/* Handles one frame. 0, or -1 (reason set; *end says how to go on). */
/* Drops every task of job id from list *pp; returns how many. */
static uint32_t drop_job_tasks(task_item **pp, task_item **tail, uint64_t id)
{
    uint32_t n = 0;
    task_item *last = NULL;
    while (*pp) {
        task_item *t = *pp;
        if (t->t.job_id == id) {
            *pp = t->next;
            task_free(t);
            n++;
        } else {
            last = t;
            pp = &t->next;
        }
    }
    if (tail)
        *tail = last;
    return n;
}

/* JOB_END: the job was cancelled or failed. Its tasks waiting for a scene, a
 * denoise input or a thread go, those rendering or denoising are marked so
 * that their results are dropped, finished results not yet sent go too; the
 * freed slots are asked for again. */
static int on_job_end(worker *w, const proto_frame *f)
{
    proto_job_ref ref;
    pt_error err = {0};
    if (proto_msg_decode_job_ref(f->payload, f->len, &ref, &err) != PT_OK)
        return fail_proto(w, "bad JOB_END: %s", err.msg);
    uint32_t pending = drop_job_tasks(&w->pending, NULL, ref.job_id);
    w->npending -= pending;
    /* A denoise input being fetched goes too, and its DENOISE_GET with it
     * (a late answer is dropped). */
    task_item *fetching = denoise_find(w, 0);
    if (fetching && fetching->t.job_id == ref.job_id) {
        memcpy(w->dn_abandoned[w->ndn_abandoned++ % DN_ABANDONED], w->dn_get_hash, PROTO_HASH_SIZE);
        w->dn_get_out = 0;
    }
    uint32_t denoise = drop_job_tasks(&w->dn_head, &w->dn_tail, ref.job_id);
    w->ndn -= denoise;
    pending += denoise;
    pthread_mutex_lock(&w->mu);
    uint32_t queued = drop_job_tasks(&w->q_head, &w->q_tail, ref.job_id);
    w->nqueued -= queued;
    uint32_t running = 0;
    for (uint32_t i = 0; i < w->o->threads; i++) {
        running_slot *r = &w->running[i];
        if (r->active && !r->dropped && r->epoch == w->epoch && r->job_id == ref.job_id) {
            r->dropped = 1;
            running++;
        }
    }
    uint32_t finished = 0;
    done_item **dp = &w->d_head, *last = NULL;
    while (*dp) {
        done_item *d = *dp;
        if (d->t.job_id == ref.job_id) {
            *dp = d->next;
            done_free(d);
            finished++;
        } else {
            last = d;
            dp = &d->next;
        }
    }
    w->d_tail = last;
    pthread_mutex_unlock(&w->mu);
    if (pending + queued + running + finished > 0)
        fprintf(stderr,
                "ptworker: job %llu ended: dropped %u tasks not started, %u rendering, %u "
                "results not sent\n",
                (unsigned long long)ref.job_id, pending + queued, running, finished);
    return request_work(w);
}

static int dispatch(worker *w, const proto_frame *f, int *end)
{
    pt_error err = {0};
    if (f->type == PROTO_MSG_ERROR) {
        proto_error_msg m;
        if (proto_msg_decode_error(f->payload, f->len, &m, &err) != PT_OK) {
            return fail_proto(w, "bad ERROR: %s", err.msg);
        }
        char text[1024]; /* the server's words, escaped; a long reason is cut */
        pt_text_shown(m.text, text, sizeof text);
        if (fatal_code(m.code)) {
            fprintf(stderr, "ptworker: refused by %s:%u: %s\n", w->host, w->port, text);
            *end = END_FATAL;
        } else {
            snprintf(w->reason, sizeof w->reason, "server said: %s (code %u)", text, m.code);
        }
        return -1;
    }
    switch (w->state) {
    case S_HELLO:
        if (f->type == PROTO_MSG_CHALLENGE)
            return on_challenge(w, f);
        break;
    case S_AUTH:
        if (f->type == PROTO_MSG_WELCOME)
            return on_welcome(w, f, end);
        break;
    case S_READY:
        if (f->type == PROTO_MSG_TASK)
            return on_task(w, f);
        if (f->type == PROTO_MSG_SCENE_CHUNK)
            return on_scene_chunk(w, f);
        if (f->type == PROTO_MSG_GUIDE_CHUNK)
            return on_guide_chunk(w, f);
        if (f->type == PROTO_MSG_DENOISE_TASK)
            return on_denoise_task(w, f);
        if (f->type == PROTO_MSG_DENOISE_CHUNK)
            return on_denoise_chunk(w, f);
        if (f->type == PROTO_MSG_JOB_END)
            return on_job_end(w, f);
        break;
    }
    return fail_proto(w, "protocol error: unexpected %s from the server",
                      proto_msg_type_name(f->type));
}

/* Reads what is there and handles every whole frame. 0, or -1. */
static int read_in(worker *w, int *end)
{
    uint8_t *p;
    size_t room;
    pt_error err = {0};
    if (proto_frame_reader_space(&w->in, &p, &room, &err) != PT_OK) {
        snprintf(w->reason, sizeof w->reason, "input: %s", err.msg);
        return -1;
    }
    ssize_t n = recv(w->fd, p, room, MSG_DONTWAIT);
    if (n < 0 && (errno == EINTR || errno == EAGAIN || errno == EWOULDBLOCK))
        return 0;
    if (n < 0) {
        socket_failed(w, "recv", errno);
        return -1;
    }
    if (n == 0) {
        snprintf(w->reason, sizeof w->reason, "the server closed the connection");
        return -1;
    }
    proto_frame_reader_commit(&w->in, (size_t)n);
    for (;;) {
        proto_frame f;
        uint32_t cap = w->state == S_READY ? PROTO_MAX_PAYLOAD : PROTO_MAX_PAYLOAD_PREAUTH;
        pt_status st = proto_frame_reader_next(&w->in, cap, &f, &err);
        if (st == PT_AGAIN)
            break;
        if (st != PT_OK)
            return fail_proto(w, "malformed frame from the server: %s", err.msg);
        if (dispatch(w, &f, end) != 0)
            return -1;
    }
    return 0;
}

/* ---- sessions ------------------------------------------------------------------------ */

/* Forgets everything the connection held: the coordinator requeues it. */
static void drop_session(worker *w)
{
    if (w->fd >= 0)
        close(w->fd);
    w->fd = -1;
    pthread_mutex_lock(&w->mu);
    w->epoch++;
    task_item *q = w->q_head;
    w->q_head = w->q_tail = NULL;
    w->nqueued = 0;
    done_item *d = w->d_head;
    w->d_head = w->d_tail = NULL;
    pthread_mutex_unlock(&w->mu);
    while (q) {
        task_item *next = q->next;
        task_free(q);
        q = next;
    }
    while (d) {
        done_item *next = d->next;
        done_free(d);
        d = next;
    }
    while (w->pending) {
        task_item *next = w->pending->next;
        task_free(w->pending);
        w->pending = next;
    }
    w->npending = 0;
    while (w->dn_head) {
        task_item *next = w->dn_head->next;
        task_free(w->dn_head);
        w->dn_head = next;
    }
    w->dn_tail = NULL;
    w->ndn = 0;
    w->dn_get_out = 0;
    w->ndn_abandoned = 0;
    for (scene_rec *s = w->scenes_known; s; s = s->next)
        fetch_reset(s);
    for (guide_rec *g = w->guides; g; g = g->next)
        guide_fetch_reset(g);
    w->requested = 0;
    proto_frame_reader_reset(&w->in);
    proto_writer_reset(&w->out);
    w->out_sent = 0;
}

/* One connection, from connect to its end. Returns END_*. *connected is set
 * when TCP connected, *welcomed when the handshake completed. */
static int session(worker *w, int sig_r, int *connected, int *welcomed)
{
    pt_error err = {0};
    *connected = *welcomed = 0;
    w->reason[0] = '\0';
    if (pt_net_connect(w->host, w->port, CONNECT_TIMEOUT_MS, &w->fd, &err) != PT_OK) {
        w->fd = -1;
        snprintf(w->reason, sizeof w->reason, "%s", err.msg);
        return g_stop ? END_STOP : END_RETRY;
    }
    *connected = 1;
    if (set_link_timeout(w->fd, w->link_timeout_ms) != 0 && !w->link_warned) {
        /* Not fatal: a dead link is then noticed only when TCP gives up. */
        fprintf(stderr, "ptworker: warning: cannot set the link timeout on the socket: %s\n",
                strerror(errno));
        w->link_warned = 1;
    }
    if (pt_net_set_nonblock(w->fd, &err) != PT_OK) {
        snprintf(w->reason, sizeof w->reason, "%s", err.msg);
        drop_session(w);
        return END_RETRY;
    }
    w->state = S_HELLO;
    w->t_connect = pt_now_ms();
    int end = END_RETRY;
    if (send_hello(w) != 0 || flush_out(w) != 0)
        goto out;
    for (;;) {
        if (g_stop) {
            end = END_STOP;
            goto out;
        }
        uint64_t now = pt_now_ms();
        if (w->state == S_READY) {
            *welcomed = 1;
            if (collect_results(w) != 0 || denoise_advance(w) != 0 || request_work(w) != 0)
                goto out;
            if (now >= w->t_heartbeat && send_heartbeat(w, now) != 0)
                goto out;
            if (flush_out(w) != 0)
                goto out;
        } else if (now - w->t_connect > HANDSHAKE_TIMEOUT_MS) {
            snprintf(w->reason, sizeof w->reason, "no WELCOME within %d s",
                     HANDSHAKE_TIMEOUT_MS / 1000);
            goto out;
        }
        int timeout;
        if (w->state == S_READY)
            timeout = w->t_heartbeat > now ? (int)(w->t_heartbeat - now) : 0;
        else
            timeout = (int)(w->t_connect + HANDSHAKE_TIMEOUT_MS - now) + 1;
        if (timeout > 1000)
            timeout = 1000;
        struct pollfd p[3] = {
            {w->fd, POLLIN | (out_pending(w) ? POLLOUT : 0), 0},
            {w->wake_r, POLLIN, 0},
            {sig_r, POLLIN, 0},
        };
        int n = poll(p, 3, timeout);
        if (n < 0 && errno != EINTR) {
            snprintf(w->reason, sizeof w->reason, "poll: %s", strerror(errno));
            goto out;
        }
        if (n <= 0)
            continue;
        if (p[2].revents)
            drain(sig_r);
        if (p[1].revents)
            drain(w->wake_r);
        if (p[0].revents & POLLOUT && flush_out(w) != 0)
            goto out;
        if (p[0].revents & (POLLIN | POLLHUP | POLLERR)) {
            if (read_in(w, &end) != 0)
                goto out;
        }
    }
out:
    if (w->state == S_READY)
        *welcomed = 1;
    drop_session(w);
    return end;
}

/* Sleeps ms, or less when a signal arrives. */
static void backoff_sleep(int sig_r, uint32_t ms)
{
    uint64_t until = pt_now_ms() + ms;
    while (!g_stop) {
        uint64_t now = pt_now_ms();
        if (now >= until)
            break;
        struct pollfd p = {sig_r, POLLIN, 0};
        if (poll(&p, 1, (int)(until - now)) > 0)
            drain(sig_r);
    }
}

/* ---- setup and teardown -------------------------------------------------------------- */

static int setup(worker *w, const wrk_client_opts *o)
{
    pt_error err = {0};
    w->o = o;
    w->fd = -1;
    w->wake_r = w->wake_w = -1;
    w->slots_max = o->threads + o->prefetch;
    w->test_denoise_lie = getenv("PTWORKER_TEST_DENOISE_LIE") != NULL;
    w->link_timeout_ms = o->link_timeout_ms ? o->link_timeout_ms : WRK_LINK_TIMEOUT_MS;
    if (w->link_timeout_ms < WRK_LINK_TIMEOUT_MIN_MS)
        w->link_timeout_ms = WRK_LINK_TIMEOUT_MIN_MS;
    if (w->link_timeout_ms > WRK_LINK_TIMEOUT_MAX_MS)
        w->link_timeout_ms = WRK_LINK_TIMEOUT_MAX_MS;
    if (pt_net_split(o->server, w->host, sizeof w->host, &w->port, &err) != PT_OK) {
        fprintf(stderr, "ptworker: --server: %s\n", err.msg);
        return 2;
    }
    if (!w->host[0])
        snprintf(w->host, sizeof w->host, "127.0.0.1");
    if (o->name) {
        snprintf(w->name, sizeof w->name, "%s", o->name);
    } else {
        char host[256];
        if (gethostname(host, sizeof host) != 0)
            snprintf(host, sizeof host, "worker");
        host[sizeof host - 1] = '\0';
        char pid[24];
        snprintf(pid, sizeof pid, ":%ld", (long)getpid());
        /* Keep the pid when the host name is long. */
        size_t room = sizeof w->name - 1 - strlen(pid);
        snprintf(w->name, sizeof w->name, "%.*s%s", (int)room, host, pid);
    }
    if (o->token_file &&
        proto_token_load(o->token_file, w->token, sizeof w->token, &w->token_len, &err) != PT_OK) {
        fprintf(stderr, "ptworker: %s\n", err.msg);
        return 1;
    }
    char dir[2048];
    if (o->cache_dir)
        snprintf(dir, sizeof dir, "%s", o->cache_dir);
    else
        wrk_client_default_cache_dir(dir, sizeof dir);
    if (wrk_cache_open(dir, &w->cache, &err) != PT_OK ||
        wrk_scenes_new(SCENES_IN_MEMORY, &w->scenes, &err) != PT_OK) {
        fprintf(stderr, "ptworker: %s\n", err.msg);
        return 1;
    }
    proto_frame_reader_init(&w->in, IN_START, IN_MAX);
    w->running = pt_calloc(o->threads, sizeof *w->running);
    if (!w->running) {
        fprintf(stderr, "ptworker: out of memory\n");
        return 1;
    }
    proto_writer_init(&w->out, OUT_MAX);
    int fds[2];
    if (make_pipe(fds) != 0) {
        fprintf(stderr, "ptworker: pipe: %s\n", strerror(errno));
        return 1;
    }
    w->wake_r = fds[0];
    w->wake_w = fds[1];
    pthread_mutex_init(&w->mu, NULL);
    pthread_cond_init(&w->cv, NULL);
    pthread_cond_init(&w->exit_cv, NULL);
    return 0;
}

/* Waits up to ms for the render threads to end (each finishes its tile). */
static int wait_threads(worker *w, uint32_t ms)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    ts.tv_sec += ms / 1000;
    ts.tv_nsec += (long)(ms % 1000) * 1000000L;
    if (ts.tv_nsec >= 1000000000L) {
        ts.tv_sec++;
        ts.tv_nsec -= 1000000000L;
    }
    pthread_mutex_lock(&w->mu);
    w->stop = 1;
    pthread_cond_broadcast(&w->cv);
    while (w->threads_alive > 0)
        if (pthread_cond_timedwait(&w->exit_cv, &w->mu, &ts) != 0)
            break;
    int all = w->threads_alive == 0;
    pthread_mutex_unlock(&w->mu);
    return all;
}

int wrk_client_run(const wrk_client_opts *o)
{
    static worker wk; /* one per process: the signal handler is global anyway */
    worker *w = &wk;
    memset(w, 0, sizeof *w);
    int rc = setup(w, o);
    if (rc != 0)
        return rc;

    int sigp[2];
    if (make_pipe(sigp) != 0) {
        fprintf(stderr, "ptworker: pipe: %s\n", strerror(errno));
        return 1;
    }
    g_sig_w = sigp[1];
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);

    /* Render threads never see SIGTERM/SIGINT: the I/O thread handles them. */
    sigset_t block, old;
    sigemptyset(&block);
    sigaddset(&block, SIGTERM);
    sigaddset(&block, SIGINT);
    pthread_sigmask(SIG_BLOCK, &block, &old);
    pthread_t *threads = pt_calloc(o->threads, sizeof *threads);
    render_arg *args = pt_calloc(o->threads, sizeof *args);
    uint32_t started = 0;
    if (threads && args)
        for (; started < o->threads; started++) {
            args[started] = (render_arg){w, started};
            pthread_mutex_lock(&w->mu);
            w->threads_alive++;
            pthread_mutex_unlock(&w->mu);
            if (pthread_create(&threads[started], NULL, render_thread, &args[started]) != 0) {
                pthread_mutex_lock(&w->mu);
                w->threads_alive--;
                pthread_mutex_unlock(&w->mu);
                break;
            }
        }
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    if (started < o->threads) {
        fprintf(stderr, "ptworker: cannot start %u render threads\n", o->threads);
        rc = 1;
        g_stop = 1;
    }

    if (!g_stop)
        fprintf(stderr,
                "ptworker: farm worker %s: %u threads, prefetch %u, cache %s, server %s:%u%s, "
                "link timeout %.1f s\n",
                w->name, o->threads, o->prefetch, wrk_cache_dir(w->cache), w->host, w->port,
                w->token_len ? " (token)" : "", w->link_timeout_ms / 1000.0);
    w->t_start = pt_now_ms();
    uint32_t delay = BACKOFF_MIN_MS;
    while (!g_stop) {
        int welcomed = 0, connected = 0;
        int end = session(w, sigp[0], &connected, &welcomed);
        if (end == END_FATAL) {
            rc = 1;
            break;
        }
        if (end == END_STOP || g_stop)
            break;
        if (welcomed)
            delay = BACKOFF_MIN_MS;
        if (welcomed)
            fprintf(stderr, "ptworker: lost %s:%u: %s; reconnecting in %.1f s\n", w->host, w->port,
                    w->reason, delay / 1000.0);
        else if (connected)
            fprintf(stderr, "ptworker: %s:%u: %s; retrying in %.1f s\n", w->host, w->port,
                    w->reason, delay / 1000.0);
        else /* pt_net_connect's message names the address */
            fprintf(stderr, "ptworker: %s; retrying in %.1f s\n", w->reason, delay / 1000.0);
        backoff_sleep(sigp[0], delay);
        delay = delay * 2 > BACKOFF_MAX_MS ? BACKOFF_MAX_MS : delay * 2;
    }

    double secs = (double)(pt_now_ms() - w->t_start) / 1000.0;
    fprintf(stderr, "ptworker: %s: %llu tasks done, %llu samples, %.4g samples/s over %.1f s",
            rc == 0 ? "stopped" : "giving up", (unsigned long long)w->tasks_done,
            (unsigned long long)w->samples, secs > 0 ? (double)w->samples / secs : 0.0, secs);
    if (w->denoised)
        fprintf(stderr, ", %llu regions denoised", (unsigned long long)w->denoised);
    if (w->failed)
        fprintf(stderr, ", %llu failed", (unsigned long long)w->failed);
    /* The set-up cost beside the render time (each frame of a range is a
     * build of its own). */
    uint64_t builds = wrk_scenes_builds(w->scenes);
    if (builds)
        fprintf(stderr, "; %llu scene builds, %.3f s each", (unsigned long long)builds,
                wrk_scenes_build_seconds(w->scenes) / (double)builds);
    fputc('\n', stderr);

    /* Finish nothing: threads end after the tile they are in. A tile of a
     * huge scene may take long; then the process ends without freeing, its
     * threads detached: one that ends between the wait and the exit is let
     * go, not left unjoined (ThreadSanitizer reported that as a leak when a
     * worker stopped while building a scene, 9 s under it). */
    if (!wait_threads(w, 2000)) {
        for (uint32_t i = 0; i < started; i++)
            pthread_detach(threads[i]);
        fflush(stdout);
        fflush(stderr);
        _exit(rc);
    }
    for (uint32_t i = 0; i < started; i++)
        pthread_join(threads[i], NULL);
    drop_session(w);
    while (w->scenes_known) {
        scene_rec *next = w->scenes_known->next;
        fetch_reset(w->scenes_known);
        pt_free(w->scenes_known->entry);
        pt_free(w->scenes_known);
        w->scenes_known = next;
    }
    while (w->guides) {
        guide_rec *next = w->guides->next;
        guide_fetch_reset(w->guides);
        pt_guide_free(w->guides->guide);
        pt_free(w->guides);
        w->guides = next;
    }
    pt_free(threads);
    pt_free(args);
    wrk_scenes_free(w->scenes);
    wrk_cache_close(w->cache);
    proto_writer_fini(&w->out);
    proto_frame_reader_fini(&w->in);
    pt_free(w->running);
    close(w->wake_r);
    close(w->wake_w);
    g_sig_w = -1;
    close(sigp[0]);
    close(sigp[1]);
    pthread_cond_destroy(&w->exit_cv);
    pthread_cond_destroy(&w->cv);
    pthread_mutex_destroy(&w->mu);
    return rc;
}
