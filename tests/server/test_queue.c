/*
 * test_queue.c - ptserve's render queue (--state-dir) with real processes,
 * real sockets and real files; a raw protocol client plays ptctl.
 *
 *  1. Crash-restart: ptserve (tasks sized by time, the default) is killed
 *     with SIGKILL at least 5 times during a
 *     job (each time after more samples were merged) and restarted on the same
 *     state folder; every restart resumes with at least the samples merged
 *     before the kill, and the final image is bit-identical to an undisturbed
 *     standalone render with exact sample counts; the job's render seconds
 *     (status, final log line, image) never fall below what its image showed
 *     before a kill.
 *  2. The queue: two clients submit at once; priority, then submission order,
 *     decide the order jobs run and finish in; queued jobs survive a kill -9;
 *     cancel during a render frees the workers for the next job; a client's
 *     unfinished-job cap.
 *  3. Damaged state: a queue file or checkpoint that is truncated or has a
 *     flipped byte, and a damaged results log, are refused with an error that
 *     names the file (ptserve exits for the queue; the job fails for its own
 *     files while the server keeps serving); a log cut short at its end (a
 *     crash during a write) is accepted with a warning.
 *  4. Hostile clients during a render: names with '/' or '..', bundles whose
 *     files name '../', absurd sizes, a bundle that lies about its length, one
 *     with the wrong hash, a broken scene, a submit that stops half-way. Each
 *     is refused; the render completes with exact sample counts.
 *  6. Files outside the upload: scenes whose buffer or image names a file of
 *     the server's ("../../..", an absolute path, /dev/zero) are refused
 *     without opening it, and the reply shows neither its bytes, its size nor
 *     a path of the server; the next good submit is served.
 *  7. Uploads held open: four clients with 47 MiB of 48 MiB uploads each
 *     leave the server's resident memory within a few MiB (the uploads are
 *     on disk); a fifth upload of the same client is refused; clients that
 *     leave take their upload files with them.
 */
#include <dirent.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/base/hash.h"
#include "common/render/render.h"
#include "common/scene/bundle.h"
#include "server/api/requests.h"
#include "tests/check.h"
#include "tests/server/farm_util.h"

static const char *SCENE = PT_SOURCE_DIR "/scenes/cornell_box.gltf";
static int g_port;
static pid_t g_srv = -1;

/* ---- a client -------------------------------------------------------------------- */

typedef struct cli {
    int fd;
    uint8_t *buf;
    size_t len, cap, used; /* used: bytes of the frame returned last */
} cli;

/* Next frame (payload valid until the next call) or -1 on close/timeout. */
static int cli_recv(cli *c, proto_frame *f, double timeout)
{
    memmove(c->buf, c->buf + c->used, c->len - c->used);
    c->len -= c->used;
    c->used = 0;
    double end = pt_now_s() + timeout;
    for (;;) {
        size_t used;
        if (c->len &&
            proto_frame_decode(c->buf, c->len, PROTO_MAX_PAYLOAD, f, &used, NULL) == PT_OK) {
            c->used = used;
            return f->type;
        }
        if (pt_now_s() > end)
            return -1;
        if (c->len == c->cap) {
            c->cap *= 2;
            c->buf = realloc(c->buf, c->cap);
        }
        struct pollfd p = {c->fd, POLLIN, 0};
        if (poll(&p, 1, 50) == 1) {
            ssize_t r = recv(c->fd, c->buf + c->len, c->cap - c->len, 0);
            if (r <= 0)
                return -1;
            c->len += (size_t)r;
        }
    }
}

static void cli_close(cli *c)
{
    if (c->fd >= 0)
        close(c->fd);
    free(c->buf);
    c->fd = -1;
    c->buf = NULL;
}

/* Connects and authenticates in role (retrying while the server starts). */
static int cli_open_as(cli *c, int port, uint8_t role)
{
    memset(c, 0, sizeof *c);
    c->cap = 1 << 16;
    c->buf = malloc(c->cap);
    for (int tries = 0; tries < 100; tries++) {
        c->fd = authenticate(port, "", role);
        if (c->fd >= 0) {
            proto_frame f;
            if (cli_recv(c, &f, 5) == PROTO_MSG_WELCOME)
                return 0;
            close(c->fd);
        }
        c->len = c->used = 0;
        sleep_ms(100);
    }
    c->fd = -1;
    return -1;
}

static int cli_open(cli *c, int port)
{
    return cli_open_as(c, port, PROTO_ROLE_CLIENT);
}

static void cli_send(cli *c, uint16_t type, const proto_writer *w)
{
    send_frame(c->fd, type, w);
}

/* As a worker on c, asks for one task; returns its job id, 0 when none came. */
static uint64_t lease_one(cli *c)
{
    proto_writer w;
    proto_writer_init(&w, 64);
    proto_work_request r = {1};
    proto_msg_encode_work_request(&w, &r, NULL);
    cli_send(c, PROTO_MSG_WORK_REQUEST, &w);
    proto_writer_fini(&w);
    proto_frame f;
    proto_task t;
    if (cli_recv(c, &f, 5) != PROTO_MSG_TASK ||
        proto_msg_decode_task(f.payload, f.len, &t, NULL) != PT_OK)
        return 0;
    return t.job_id;
}

static void send_ref(cli *c, uint16_t type, uint64_t id)
{
    proto_writer w;
    proto_writer_init(&w, 64);
    proto_job_ref r = {id};
    proto_msg_encode_job_ref(&w, &r, NULL);
    cli_send(c, type, &w);
    proto_writer_fini(&w);
}

/* Reads the reply; on ERROR copies its text into err_text and returns -2. */
static char err_text[PROTO_MAX_ERROR_TEXT + 1];
static int reply(cli *c, proto_frame *f)
{
    int t = cli_recv(c, f, 30);
    if (t == PROTO_MSG_ERROR) {
        proto_error_msg m;
        proto_msg_decode_error(f->payload, f->len, &m, NULL);
        snprintf(err_text, sizeof err_text, "%s", m.text);
        return -2;
    }
    return t;
}

/* Sends SUBMIT; spp 0 and a reversed frame range (which the encoder
 * refuses) are patched into the bytes. */
static void submit_begin(cli *c, const proto_submit *m)
{
    proto_writer w;
    proto_writer_init(&w, 4096);
    proto_submit fixed = *m;
    fixed.spp = m->spp ? m->spp : 1;
    int reversed = m->frame_step && m->frame_last < m->frame_first;
    if (reversed) {
        fixed.frame_first = m->frame_last;
        fixed.frame_last = m->frame_first;
    }
    CHECK(proto_msg_encode_submit(&w, &fixed, NULL) == PT_OK);
    if (m->spp == 0)
        proto_put_u32(w.buf + 10 + strlen(m->name), 0);
    if (reversed) { /* the range: the last fields but the fps, the animation, the shutter,
                       the clamps */
        uint8_t *range = w.buf + w.len - 1 - 8 - 16 - 2 - strlen(m->animation) - 8 - 12;
        proto_put_u32(range, m->frame_first);
        proto_put_u32(range + 4, m->frame_last);
    }
    cli_send(c, PROTO_MSG_SUBMIT, &w);
    proto_writer_fini(&w);
}

static void upload(cli *c, const uint8_t hash[32], const uint8_t *data, uint64_t total,
                   uint64_t off, uint32_t n)
{
    proto_writer w;
    proto_writer_init(&w, PROTO_MAX_SCENE_CHUNK + 1024);
    proto_scene_chunk ch;
    memcpy(ch.hash, hash, 32);
    ch.offset = off;
    ch.total = total;
    ch.len = n;
    ch.data = data + off;
    proto_msg_encode_scene_chunk(&w, &ch, NULL);
    cli_send(c, PROTO_MSG_UPLOAD, &w);
    proto_writer_fini(&w);
}

static void hash_bytes(const uint8_t *d, size_t n, uint8_t out[32])
{
    char hex[65];
    pt_sha256_hex(d, n, hex);
    for (int i = 0; i < 32; i++) {
        unsigned v;
        sscanf(hex + 2 * i, "%2x", &v);
        out[i] = (uint8_t)v;
    }
}

static proto_submit job_of(const char *name, uint32_t w, uint32_t h, uint32_t spp, int32_t prio)
{
    proto_submit m;
    memset(&m, 0, sizeof m);
    snprintf(m.name, sizeof m.name, "%s", name);
    m.width = w;
    m.height = h;
    m.spp = spp;
    m.seed = 5;
    m.priority = prio;
    return m;
}

/* Submits data (a bundle) as job m; returns the job id, 0 when refused. */
static uint64_t submit_bytes(cli *c, proto_submit m, const uint8_t *data, size_t n)
{
    m.bundle_size = n;
    hash_bytes(data, n, m.bundle_hash);
    submit_begin(c, &m);
    upload(c, m.bundle_hash, data, n, 0, (uint32_t)n);
    proto_frame f;
    if (reply(c, &f) != PROTO_MSG_SUBMITTED)
        return 0;
    proto_job_ref r;
    return proto_msg_decode_job_ref(f.payload, f.len, &r, NULL) == PT_OK ? r.job_id : 0;
}

static pt_bundle *g_bundle;

static uint64_t submit(int port, proto_submit m)
{
    cli c;
    if (cli_open(&c, port) != 0)
        return 0;
    uint64_t id = submit_bytes(&c, m, g_bundle->data, g_bundle->size);
    if (!id)
        fprintf(stderr, "submit refused: %s\n", err_text);
    cli_close(&c);
    return id;
}

static int status(int port, uint64_t id, proto_job_info *out)
{
    cli c;
    if (cli_open(&c, port) != 0)
        return -1;
    send_ref(&c, PROTO_MSG_STATUS, id);
    proto_frame f;
    int t = reply(&c, &f);
    if (t == PROTO_MSG_JOB_INFO && proto_msg_decode_job_info(f.payload, f.len, out, NULL) != PT_OK)
        t = -1;
    cli_close(&c);
    return t;
}

/* Waits until job id is in state (or has ended when state is 0). */
static int wait_state(int port, uint64_t id, int state, double timeout, proto_job_info *out)
{
    double end = pt_now_s() + timeout;
    while (pt_now_s() < end) {
        if (status(port, id, out) == PROTO_MSG_JOB_INFO &&
            (out->state == state || (state == 0 && out->state >= PROTO_JOB_DONE)))
            return 1;
        sleep_ms(50);
    }
    return 0;
}

static int fetch(int port, uint64_t id, const char *name)
{
    cli c;
    if (cli_open(&c, port) != 0)
        return -1;
    send_ref(&c, PROTO_MSG_FETCH, id);
    uint8_t *img = NULL;
    uint64_t got = 0, total = 1;
    uint8_t hash[32];
    int ok = 0;
    while (got < total) {
        proto_frame f;
        if (reply(&c, &f) != PROTO_MSG_IMAGE)
            break;
        proto_scene_chunk ch;
        if (proto_msg_decode_scene_chunk(f.payload, f.len, &ch, NULL) != PT_OK || ch.offset != got)
            break;
        if (!img) {
            total = ch.total;
            img = malloc(total);
            memcpy(hash, ch.hash, 32);
        }
        memcpy(img + got, ch.data, ch.len);
        got += ch.len;
    }
    if (img && got == total) {
        uint8_t h[32];
        hash_bytes(img, total, h);
        FILE *f = fopen(path(name), "wb");
        ok = !memcmp(h, hash, 32) && f && fwrite(img, 1, total, f) == total;
        if (f)
            fclose(f);
    }
    free(img);
    cli_close(&c);
    return ok ? 0 : -1;
}

/* ---- processes --------------------------------------------------------------------- */

/* How ptserve sizes tasks: fixed chunks of 8 unless a test asks otherwise. */
static const char *g_sizing[2] = {"--chunk", "8"};

/* ptserve on state, logging to log; opt and its value (or NULL) are added. */
static void start_server_opt(const char *state, const char *log, const char *opt, const char *value)
{
    char listen[64];
    snprintf(listen, sizeof listen, "127.0.0.1:%d", g_port);
    unlink(path("port"));
    const char *argv[] = {PT_BIN_DIR "/ptserve",
                          "--state-dir",
                          path(state),
                          "--listen",
                          listen,
                          "--port-file",
                          path("port"),
                          "--tile",
                          "16",
                          g_sizing[0],
                          g_sizing[1],
                          "--save-interval",
                          "0.2",
                          "--lease-timeout",
                          "5",
                          opt ? opt : "--quiet",
                          opt ? value : NULL,
                          NULL};
    g_srv = spawn(argv, log);
    int port = read_port();
    CHECK(port > 0);
    if (g_port == 0)
        g_port = port;
}

/* extra: NULL, or an option that takes the value 2. */
static void start_server(const char *state, const char *log, const char *extra)
{
    start_server_opt(state, log, extra, "2");
}

static void kill_server(int sig)
{
    if (g_srv > 0) {
        kill(g_srv, sig);
        int st;
        waitpid(g_srv, &st, 0);
    }
    g_srv = -1;
}

/* A one-thread worker that holds up to 1 + prefetch tasks. */
static pid_t start_worker_prefetch(const char *name, const char *prefetch)
{
    char server[64];
    snprintf(server, sizeof server, "127.0.0.1:%d", g_port);
    const char *argv[] = {
        PT_BIN_DIR "/ptworker", "--server",    server,   "--threads", "1", "--prefetch", prefetch,
        "--cache-dir",          path("cache"), "--name", name,        NULL};
    return spawn(argv, "workers.log");
}

static pid_t start_worker(const char *name)
{
    return start_worker_prefetch(name, "1");
}

static void stop_worker(pid_t w)
{
    kill(w, SIGTERM);
    wait_exit(w, 30);
}

/* Lines of log that contain needle, in order: the job ids of "job N done". */
static int done_order(const char *log, uint64_t *ids, int cap)
{
    FILE *f = fopen(path(log), "r");
    int n = 0;
    char line[4096];
    while (f && fgets(line, sizeof line, f) && n < cap) {
        const char *p = strstr(line, "ptserve: job ");
        unsigned long long id;
        if (p && strstr(p, " done:") && sscanf(p, "ptserve: job %llu done:", &id) == 1)
            ids[n++] = id;
    }
    if (f)
        fclose(f);
    return n;
}

/* The ptfarm.renderSeconds of the image at file; -1 when it cannot be read. */
static double image_seconds_of(const char *file)
{
    pt_image *img = NULL;
    pt_exr_meta meta;
    if (pt_exr_read(file, &img, &meta, NULL) != PT_OK)
        return -1;
    pt_image_free(img);
    return meta.render_seconds;
}

/* The same for a job's image in state1's output folder; 0 before its first save. */
static double image_seconds(const char *output)
{
    char file[1024];
    snprintf(file, sizeof file, "%s/state1/output/%s", tmp, output);
    double s = image_seconds_of(file);
    return s > 0 ? s : 0;
}

/* The seconds of log's last "job id done: N samples in S s" line; -1 if none. */
static double done_seconds(const char *log, uint64_t id)
{
    FILE *f = fopen(path(log), "r");
    double secs = -1;
    char line[4096];
    while (f && fgets(line, sizeof line, f)) {
        const char *p = strstr(line, "ptserve: job ");
        unsigned long long jid, n;
        double v;
        if (p && sscanf(p, "ptserve: job %llu done: %llu samples in %lf s", &jid, &n, &v) == 3 &&
            jid == id)
            secs = v;
    }
    if (f)
        fclose(f);
    return secs;
}

/* ---- 1. crash-restart --------------------------------------------------------------- */

static void crash_restart(void)
{
    /* Long enough for six kills: results merge once their commit returns, which
     * on a busy disk may be seconds behind what the workers returned. */
    const uint32_t spp = CHECK_JOB_SPP(4096);
    char spp_text[16];
    snprintf(spp_text, sizeof spp_text, "%u", spp);
    const char *ref[] = {PT_BIN_DIR "/ptworker",
                         "--scene",
                         SCENE,
                         "--res",
                         "64x48",
                         "--tile",
                         "16",
                         "--chunk",
                         "48",
                         "--seed",
                         "5",
                         "--spp",
                         spp_text,
                         "-o",
                         path("crash_ref.exr"),
                         "-q",
                         NULL};
    CHECK(run(ref, "crash_ref.log", 600) == 0);
    g_port = 0;
    /* Tasks sized by time: the image is still the standalone render's
     * (with exact sums any cut at multiples of 16 samples gives the same
     * bits) after every kill. 250 ms a task, not the default 2 s: on an idle
     * machine the whole job renders in about 3 s, which 2-second tasks cut
     * into so few results that it ended before the kills below. */
    g_sizing[0] = "--task-time";
    g_sizing[1] = "250";
    start_server("state1", "crash.log", NULL);
    pid_t w1 = start_worker("c1"), w2 = start_worker("c2");
    uint64_t id = submit(g_port, job_of("crash", 64, 48, spp, 0));
    CHECK(id > 0);
    const uint64_t total = 64ull * 48 * spp;
    int kills = 0, lost = 0;
    uint64_t last = 0;
    double secs_before = 0; /* the most render seconds an image showed before a kill */
    srand(12345);
    proto_job_info info;
    while (kills < 6) {
        /* Let more samples merge since the restart, then kill at a random
         * moment. Small steps: results are merged once their commit returns,
         * so more than status says may be logged and come back at a restart. */
        uint64_t goal = last + total / 24;
        double end = pt_now_s() + 300;
        while (pt_now_s() < end && status(g_port, id, &info) == PROTO_MSG_JOB_INFO &&
               info.samples_done < goal && info.state != PROTO_JOB_DONE)
            sleep_ms(20);
        if (info.state == PROTO_JOB_DONE)
            break;
        sleep_ms(rand() % 150);
        CHECK(status(g_port, id, &info) == PROTO_MSG_JOB_INFO);
        uint64_t before = info.samples_done;
        if (info.state == PROTO_JOB_DONE)
            break;
        double img_secs = image_seconds(info.output);
        kill_server(SIGKILL);
        kills++;
        start_server("state1", "crash.log", NULL);
        CHECK(status(g_port, id, &info) == PROTO_MSG_JOB_INFO);
        /* The job's time goes on from what its image recorded before the kill. */
        CHECKF(info.seconds >= img_secs, "restart %d: %.3f s after, the image had %.3f s", kills,
               info.seconds, img_secs);
        secs_before = img_secs > secs_before ? img_secs : secs_before;
        if (info.samples_done < before) {
            lost++;
            fprintf(stderr, "restart %d: %llu samples merged before the kill, %llu after\n", kills,
                    (unsigned long long)before, (unsigned long long)info.samples_done);
        }
        last = info.samples_done;
    }
    CHECKF(kills >= 5, "only %d kills before the job ended", kills);
    CHECK(lost == 0);
    CHECK(log_has("crash.log", "resumed"));
    CHECK(wait_state(g_port, id, PROTO_JOB_DONE, 600, &info));
    CHECK(info.samples_done == total);
    CHECK(fetch(g_port, id, "crash.exr") == 0);
    CHECK(same_pixels("crash_ref.exr", "crash.exr"));
    CHECK(all_samples("crash.exr", (float)spp));
    /* The reported time is the job's total over every run, not the last run's. */
    CHECKF(info.seconds >= secs_before, "%.3f s in all, %.3f s before a kill", info.seconds,
           secs_before);
    CHECKF(image_seconds_of(path("crash.exr")) >= secs_before,
           "the image says %.3f s, %.3f s before", image_seconds_of(path("crash.exr")),
           secs_before);
    CHECKF(done_seconds("crash.log", id) + 0.05 >= secs_before, "the log says %.1f s, %.3f before",
           done_seconds("crash.log", id), secs_before);
    /* The image also lies in the output folder, under a sanitised name. */
    char out[300];
    snprintf(out, sizeof out, "state1/output/%s", info.output);
    CHECK(same_pixels("crash_ref.exr", out));
    stop_worker(w1);
    stop_worker(w2);
    kill_server(SIGTERM);
    g_sizing[0] = "--chunk";
    g_sizing[1] = "8";
}

/* ---- 2. the queue ------------------------------------------------------------------- */

static void queue_order(void)
{
    g_port = 0;
    start_server("state2", "queue.log", NULL);
    /* Two clients submit at the same time, interleaved on the wire. */
    cli a, b;
    CHECK(cli_open(&a, g_port) == 0 && cli_open(&b, g_port) == 0);
    proto_submit ma = job_of("a", 32, 32, 16, 0), mb = job_of("b", 32, 32, 16, 0);
    ma.bundle_size = mb.bundle_size = g_bundle->size;
    hash_bytes(g_bundle->data, g_bundle->size, ma.bundle_hash);
    memcpy(mb.bundle_hash, ma.bundle_hash, 32);
    submit_begin(&a, &ma);
    submit_begin(&b, &mb);
    uint32_t half = (uint32_t)(g_bundle->size / 2);
    upload(&a, ma.bundle_hash, g_bundle->data, g_bundle->size, 0, half);
    upload(&b, mb.bundle_hash, g_bundle->data, g_bundle->size, 0, half);
    upload(&b, mb.bundle_hash, g_bundle->data, g_bundle->size, half,
           (uint32_t)(g_bundle->size - half));
    upload(&a, ma.bundle_hash, g_bundle->data, g_bundle->size, half,
           (uint32_t)(g_bundle->size - half));
    proto_frame f;
    proto_job_ref ra = {0}, rb = {0};
    CHECK(reply(&a, &f) == PROTO_MSG_SUBMITTED &&
          proto_msg_decode_job_ref(f.payload, f.len, &ra, NULL) == PT_OK);
    CHECK(reply(&b, &f) == PROTO_MSG_SUBMITTED &&
          proto_msg_decode_job_ref(f.payload, f.len, &rb, NULL) == PT_OK);
    cli_close(&a);
    cli_close(&b);
    CHECK(ra.job_id && rb.job_id && ra.job_id != rb.job_id);
    uint64_t first = ra.job_id < rb.job_id ? ra.job_id : rb.job_id;
    uint64_t second = ra.job_id < rb.job_id ? rb.job_id : ra.job_id;
    uint64_t urgent = submit(g_port, job_of("urgent", 32, 32, 32, 5));
    CHECK(urgent > 0);
    proto_job_info info;
    CHECK(status(g_port, urgent, &info) == PROTO_MSG_JOB_INFO && info.queue_pos == 1);
    CHECK(status(g_port, first, &info) == PROTO_MSG_JOB_INFO && info.queue_pos == 2);
    CHECK(status(g_port, second, &info) == PROTO_MSG_JOB_INFO && info.queue_pos == 3);

    /* Queued jobs survive a kill -9, in the same order. */
    kill_server(SIGKILL);
    start_server("state2", "queue.log", NULL);
    cli l;
    CHECK(cli_open(&l, g_port) == 0);
    cli_send(&l, PROTO_MSG_LIST, NULL);
    proto_job_list list = {0};
    CHECK(reply(&l, &f) == PROTO_MSG_JOB_LIST &&
          proto_msg_decode_job_list(f.payload, f.len, &list, NULL) == PT_OK);
    CHECK(list.count == 3);
    if (list.count == 3) {
        CHECK(list.jobs[0].job_id == urgent && list.jobs[0].queue_pos == 1);
        CHECK(list.jobs[1].job_id == first && list.jobs[1].queue_pos == 2);
        CHECK(list.jobs[2].job_id == second && list.jobs[2].state == PROTO_JOB_QUEUED);
        CHECK(strcmp(list.jobs[0].name, "urgent") == 0 && list.jobs[0].priority == 5);
    }
    pt_free(list.jobs);
    cli_close(&l);

    /* A worker that holds every task of the urgent job (4 tiles x 2 chunks of 16)
     * and asks for more is given the next job's: when the running job cannot
     * use a worker, the next one starts. It never returns a result, so its
     * leases are requeued when it goes. */
    cli fw;
    CHECK(cli_open_as(&fw, g_port, PROTO_ROLE_WORKER) == 0);
    int held = 0;
    uint64_t next_job = 0;
    for (int i = 0; i < 16 && !next_job; i++) {
        uint64_t job = lease_one(&fw);
        if (job == urgent)
            held++;
        else
            next_job = job;
    }
    CHECK(held == 8 && next_job == first);
    CHECK(status(g_port, urgent, &info) == PROTO_MSG_JOB_INFO && info.state == PROTO_JOB_RUNNING);
    CHECK(status(g_port, first, &info) == PROTO_MSG_JOB_INFO && info.state == PROTO_JOB_RUNNING);
    CHECK(status(g_port, second, &info) == PROTO_MSG_JOB_INFO && info.state == PROTO_JOB_QUEUED);
    /* The rest is handed out in the same order: the first job's other 3
     * tasks (4 tiles x 1 chunk), then the second's 4. */
    uint64_t rest[7];
    for (int i = 0; i < 7; i++)
        rest[i] = lease_one(&fw);
    for (int i = 0; i < 7; i++)
        CHECK(rest[i] == (i < 3 ? first : second));
    cli_close(&fw);
    /* Its leases are requeued once the coordinator has seen it go; waited
     * for, not assumed, so that the worker below finds every task queued. */
    int requeued = 0;
    for (double end = pt_now_s() + 30; !requeued && pt_now_s() < end; sleep_ms(20)) {
        proto_job_info iu, i1, i2;
        requeued = status(g_port, urgent, &iu) == PROTO_MSG_JOB_INFO && iu.workers == 0 &&
                   status(g_port, first, &i1) == PROTO_MSG_JOB_INFO && i1.workers == 0 &&
                   status(g_port, second, &i2) == PROTO_MSG_JOB_INFO && i2.workers == 0;
    }
    CHECK(requeued);

    /* One worker runs them all. The order of their ends is not checked: each
     * job's image is written on its own thread, so a later job can finish
     * writing first; the order they are handed out in is checked above. */
    pid_t w = start_worker_prefetch("q1", "8");
    CHECK(wait_state(g_port, urgent, PROTO_JOB_DONE, 120, &info));
    CHECK(wait_state(g_port, first, PROTO_JOB_DONE, 120, &info));
    CHECK(wait_state(g_port, second, PROTO_JOB_DONE, 120, &info));
    uint64_t order[8];
    int n = done_order("queue.log", order, 8), seen = 0;
    for (int i = 0; i < n; i++)
        seen |= (order[i] == urgent) | (order[i] == first) << 1 | (order[i] == second) << 2;
    CHECK(n == 3 && seen == 7);

    /* Cancel during a render: the workers move on to the next job at once.
     * With tasks of 512 samples per pixel the worker is always rendering one
     * and holding the 8 it prefetched when the cancel comes. */
    kill_server(SIGTERM);
    start_server_opt("state2", "queue.log", "--chunk", "512");
    uint64_t big = submit(g_port, job_of("big", 64, 48, 65536, 0));
    CHECK(big > 0);
    double end = pt_now_s() + 60;
    while (pt_now_s() < end && status(g_port, big, &info) == PROTO_MSG_JOB_INFO &&
           info.samples_done == 0)
        sleep_ms(20);
    CHECK(info.state == PROTO_JOB_RUNNING && info.samples_done > 0);
    /* Its latest progressive image can be fetched while it renders. */
    int fetched = -1;
    for (end = pt_now_s() + 30; fetched != 0 && pt_now_s() < end; sleep_ms(50))
        fetched = fetch(g_port, big, "big_progress.exr");
    CHECK(fetched == 0);
    pt_image *progress = load_exr("big_progress.exr");
    CHECK(progress && progress->width == 64 && progress->height == 48);
    pt_image_free(progress);
    uint64_t small = submit(g_port, job_of("after", 32, 32, 16, 0));
    CHECK(status(g_port, small, &info) == PROTO_MSG_JOB_INFO && info.state == PROTO_JOB_QUEUED);
    /* A worker holding a task of the job is told that it ended (JOB_END). */
    CHECK(cli_open_as(&fw, g_port, PROTO_ROLE_WORKER) == 0);
    CHECK(lease_one(&fw) == big);
    CHECK(cli_open(&l, g_port) == 0);
    send_ref(&l, PROTO_MSG_CANCEL, big);
    CHECK(reply(&l, &f) == PROTO_MSG_JOB_INFO &&
          proto_msg_decode_job_info(f.payload, f.len, &info, NULL) == PT_OK &&
          info.state == PROTO_JOB_CANCELLED);
    cli_close(&l);
    proto_job_ref ended = {0};
    CHECK(cli_recv(&fw, &f, 5) == PROTO_MSG_JOB_END &&
          proto_msg_decode_job_ref(f.payload, f.len, &ended, NULL) == PT_OK && ended.job_id == big);
    cli_close(&fw);
    CHECK(wait_state(g_port, small, PROTO_JOB_DONE, 120, &info));
    /* The real worker dropped the tasks of it that it held instead of
     * rendering them, and went on with the next job. */
    char dropped[64];
    snprintf(dropped, sizeof dropped, "job %llu ended: dropped", (unsigned long long)big);
    CHECK(log_has("workers.log", dropped));
    CHECK(status(g_port, big, &info) == PROTO_MSG_JOB_INFO && info.state == PROTO_JOB_CANCELLED);
    CHECK(status(g_port, 999, &info) == -2 && strstr(err_text, "no job"));
    stop_worker(w);
    kill_server(SIGTERM);
}

/* ---- 3. damaged state --------------------------------------------------------------- */

static void copy_file(const char *from, const char *to)
{
    char cmd[1200];
    snprintf(cmd, sizeof cmd, "cp -a '%s' '%s'", path(from), path(to));
    CHECK(system(cmd) == 0);
}

static void flip_byte(const char *name, long at)
{
    FILE *f = fopen(path(name), "r+b");
    CHECK(f != NULL);
    if (!f)
        return;
    fseek(f, 0, SEEK_END);
    long size = ftell(f);
    long off = at < 0 ? size + at : at;
    fseek(f, off, SEEK_SET);
    int c = fgetc(f);
    fseek(f, off, SEEK_SET);
    fputc(c ^ 0x10, f);
    fclose(f);
}

static void cut_file(const char *name, long drop)
{
    struct stat sb;
    CHECK(stat(path(name), &sb) == 0);
    CHECK(truncate(path(name), sb.st_size - drop) == 0);
}

/* Rewrites a state file as format `version`: drops the 8 bytes of the min
 * gain at `at` (none when at < 0), sets the version words at the given
 * offsets and, when `crc`, recomputes the trailing CRC32C. */
static void set_format(const char *name, long at, const long *vers, int nvers, uint32_t version,
                       int crc)
{
    uint8_t *d = NULL;
    size_t n = 0;
    pt_error e = {0};
    CHECK(pt_read_file(path(name), 1 << 30, &d, &n, &e) == PT_OK);
    if (!d)
        return;
    if (at >= 0) {
        CHECK((size_t)at + 8 <= n);
        memmove(d + at, d + at + 8, n - (size_t)at - 8);
        n -= 8;
    }
    for (int i = 0; i < nvers; i++) {
        CHECK((size_t)vers[i] + 4 + (crc ? 4 : 0) <= n);
        proto_put_u32(d + vers[i], version);
    }
    if (crc)
        proto_put_u32(d + n - 4, proto_crc32c(0, d, n - 4));
    CHECK(pt_write_file_atomic(path(name), d, n, &e) == PT_OK);
    pt_free(d);
}

/* ---- format 4 to format 3: what the ptserve before the environment light and
 * the film flags wrote ---- */

/* Reads the state file name into *d (n bytes); 0 when it cannot. */
static int read_state(const char *name, uint8_t **d, size_t *n)
{
    pt_error e = {0};
    *d = NULL;
    CHECK(pt_read_file(path(name), 1 << 30, d, n, &e) == PT_OK);
    return *d != NULL;
}

/* A str field at *at: skips it into w. */
static void copy_str(proto_writer *w, const uint8_t *d, size_t *at)
{
    size_t len = 2 + proto_get_u16(d + *at);
    proto_w_bytes(w, d + *at, len);
    *at += len;
}

/* Writes w as the state file name with version v at the given offsets and,
 * when crc, a fresh trailing CRC32C (w holds the file without it). */
static void write_ver(const char *name, proto_writer *w, const long *vers, int nvers, int crc,
                      uint32_t v)
{
    for (int i = 0; i < nvers; i++)
        proto_put_u32(w->buf + vers[i], v);
    if (crc)
        proto_w_u32(w, proto_crc32c(0, w->buf, w->len));
    pt_error e = {0};
    CHECK(proto_writer_status(w) == PT_OK);
    CHECK(pt_write_file_atomic(path(name), w->buf, w->len, &e) == PT_OK);
    proto_writer_fini(w);
}

/* One step down the state formats: fn writes the older layout of the file's
 * n bytes d (its trailing CRC32C included) into w; convert then sets the
 * version fields at vers to version and appends a fresh CRC32C when crc. */
typedef struct state_converter {
    void (*fn)(const uint8_t *d, size_t n, proto_writer *w);
    long vers[2];
    int nvers, crc;
    uint32_t version;
} state_converter;

/* Rewrites the state file name in c's older format. */
static void convert(const char *name, const state_converter *c)
{
    uint8_t *d;
    size_t n;
    if (!read_state(name, &d, &n))
        return;
    proto_writer w;
    proto_writer_init(&w, 1 << 30);
    c->fn(d, n, &w);
    write_ver(name, &w, c->vers, c->nvers, c->crc, c->version);
    pt_free(d);
}

/* A fixed-point sum (two u64, low half first) at q as format 4's f64. */
static void put_f64_of_fixed(proto_writer *w, const uint8_t *q, int is_signed)
{
    pt_u128 v = ((pt_u128)proto_get_u64(q + 8) << 64) | proto_get_u64(q);
    proto_w_f64(w, is_signed ? pt_fixed_to_double((pt_i128)v) : pt_ufixed_to_double(v));
}

/* A pixel of format 5 (72 bytes) in format 4's layout (f64 sums, n, hits). */
static void pixel_to_v4(proto_writer *w, const uint8_t *q)
{
    for (int c = 0; c < 4; c++)
        put_f64_of_fixed(w, q + 16 * c, c < 3);
    proto_w_bytes(w, q + 64, 8);
}

/* Where the shutter (16 bytes, format 7 on) starts in params at d + at:
 * after the camera, the environment, the film flags and the variant. */
static size_t shutter_at(const uint8_t *d, size_t at)
{
    at += 9 * 4 + 16;
    at += 2 + proto_get_u16(d + at);                  /* camera */
    at += 2 + proto_get_u16(d + at) + 4 + 4 + 1 + 12; /* the environment */
    at += 4;                                          /* film flags */
    at += 2 + proto_get_u16(d + at);                  /* material variant */
    return at;
}

/* The end of a queue record's frame block at d + at (format 6 on). */
static size_t frames_end(const uint8_t *d, size_t at)
{
    at += 4 * 3 + 8;                   /* the frame range and fps */
    at += 2 + proto_get_u16(d + at);   /* the animation */
    at += 4;                           /* frames done */
    return at + 1 + 4 * (size_t)d[at]; /* frames done ahead */
}

/* The queue file of format 9: the same records without format 10's
 * contributions clamped, their last field. */
static void queue_v9(const uint8_t *d, size_t n, proto_writer *w)
{
    size_t at = 8 + 8 + 4, done = 0;
    for (uint32_t i = 0, count = proto_get_u32(d + 16); i < count; i++) {
        at += 8 + 8 + 1 + 4;
        for (int k = 0; k < 4; k++) /* name, owner, scene, output */
            at += 2 + proto_get_u16(d + at);
        at = shutter_at(d, at + 8) + 16 + 8 + 25; /* submitted, params */
        at += 32 + 8 + 8 + 8 + 8;
        at += 2 + proto_get_u16(d + at); /* message */
        at = frames_end(d, at + 8 + 8);  /* paths capped, samples rejected */
        proto_w_bytes(w, d + done, at - done);
        at += 8; /* contributions clamped */
        done = at;
    }
    CHECK(at + 4 == n);
}
static const state_converter QUEUE_V9 = {queue_v9, {4}, 1, 1, 9};

/* A checkpoint of format 9: the same bytes without format 10's
 * contributions clamped after the depth-cap count. */
static void checkpoint_v9(const uint8_t *d, size_t n, proto_writer *w)
{
    /* envelope 8, seconds/rejected/rays 24, magic, version, id, hash, params */
    size_t at = shutter_at(d, 8 + 24 + 4 + 4 + 8 + 32) + 16 + 8 + 25 + 8;
    proto_w_bytes(w, d, at);
    proto_w_bytes(w, d + at + 8, n - 4 - (at + 8));
}
static const state_converter CHECKPOINT_V9 = {checkpoint_v9, {4, 36}, 2, 1, 9};

/* The queue file of format 6: the same records without the shutter, format
 * 9's clamps and format 8's count of rejected samples. */
static void queue_v6(const uint8_t *d, size_t n, proto_writer *w)
{
    size_t at = 8 + 8 + 4, done = 0;
    for (uint32_t i = 0, count = proto_get_u32(d + 16); i < count; i++) {
        at += 8 + 8 + 1 + 4;
        for (int k = 0; k < 4; k++) /* name, owner, scene, output */
            at += 2 + proto_get_u16(d + at);
        at += 8; /* submitted */
        size_t sh = shutter_at(d, at);
        proto_w_bytes(w, d + done, sh - done);
        at = sh + 16 + 8 + 25; /* the shutter, the clamps and guiding */
        done = at;
        at += 32 + 8 + 8 + 8 + 8;
        at += 2 + proto_get_u16(d + at); /* message */
        at += 8;                         /* paths capped */
        proto_w_bytes(w, d + done, at - done);
        at += 8; /* samples rejected */
        done = at;
        at = frames_end(d, at);
    }
    CHECK(at + 4 == n);
    proto_w_bytes(w, d + done, n - 4 - done);
}
static const state_converter QUEUE_V6 = {queue_v6, {4}, 1, 1, 6};

/* A checkpoint of format 6: the same bytes without the shutter and format
 * 9's clamps. */
static void checkpoint_v6(const uint8_t *d, size_t n, proto_writer *w)
{
    /* envelope 8, seconds/rejected/rays 24, magic, version, id, hash, params */
    size_t sh = shutter_at(d, 8 + 24 + 4 + 4 + 8 + 32);
    proto_w_bytes(w, d, sh);
    proto_w_bytes(w, d + sh + 49, n - 4 - (sh + 49)); /* shutter, clamps, guiding */
}
static const state_converter CHECKPOINT_V6 = {checkpoint_v6, {4, 36}, 2, 1, 6};

/* The queue file of format 5: each record without format 6's frame range,
 * pose and frames done, its last fields (read in format 6's layout). */
static void queue_v5(const uint8_t *d, size_t n, proto_writer *w)
{
    size_t at = 8 + 8 + 4;
    proto_w_bytes(w, d, at);
    for (uint32_t i = 0, count = proto_get_u32(d + 16); i < count; i++) {
        size_t start = at;
        at += 8 + 8 + 1 + 4;
        for (int k = 0; k < 4; k++) /* name, owner, scene, output */
            at += 2 + proto_get_u16(d + at);
        at += 8 + 9 * 4 + 16;                             /* submitted, params */
        at += 2 + proto_get_u16(d + at);                  /* camera */
        at += 2 + proto_get_u16(d + at) + 4 + 4 + 1 + 12; /* the environment */
        at += 4;                                          /* film flags */
        at += 2 + proto_get_u16(d + at);                  /* material variant */
        at += 32 + 8 + 8 + 8 + 8;
        at += 2 + proto_get_u16(d + at); /* message */
        at += 8;                         /* paths capped */
        proto_w_bytes(w, d + start, at - start);
        at = frames_end(d, at);
    }
    CHECK(at + 4 == n);
}
static const state_converter QUEUE_V5 = {queue_v5, {4}, 1, 1, 5};

/* The queue file of format 4: the same records as format 5. */
static void queue_v4(const uint8_t *d, size_t n, proto_writer *w)
{
    proto_w_bytes(w, d, n - 4);
}
static const state_converter QUEUE_V4 = {queue_v4, {4}, 1, 1, 4};

/* A checkpoint of format 4: double sums, 40-byte pixels. */
static void checkpoint_v4(const uint8_t *d, size_t n, proto_writer *w)
{
    /* envelope 8, seconds/rejected/rays 24, magic, version, id, hash, params */
    size_t at = 8 + 24 + 4 + 4 + 8 + 32;
    uint32_t wd = proto_get_u32(d + at), ht = proto_get_u32(d + at + 4),
             spp = proto_get_u32(d + at + 8), tile = proto_get_u32(d + at + 12),
             chunk = proto_get_u32(d + at + 16);
    at += 9 * 4 + 16;
    at += 2 + proto_get_u16(d + at);                  /* camera */
    at += 2 + proto_get_u16(d + at) + 4 + 4 + 1 + 12; /* the environment */
    at += 4;                                          /* film flags */
    at += 2 + proto_get_u16(d + at);                  /* material variant */
    at += 8;                                          /* paths capped */
    /* Format 6 counts a tile's samples merged and names a held result by its
     * tile and samples; older ones count chunks and name the task, chunk x
     * tiles + tile (the job's tasks are fixed chunks here). */
    uint32_t ntiles = proto_get_u32(d + at);
    at += 8;
    proto_w_bytes(w, d, at);
    for (uint32_t i = 0; i < ntiles; i++, at += 5) {
        uint32_t m = proto_get_u32(d + at);
        CHECK(m % chunk == 0 || m == spp);
        proto_w_u32(w, (m + chunk - 1) / chunk);
        proto_w_u8(w, d[at + 4]);
    }
    uint32_t nheld = proto_get_u32(d + at);
    proto_w_u32(w, nheld);
    at += 4;
    uint32_t tiles_x = (wd + tile - 1) / tile;
    for (uint32_t i = 0; i < nheld; i++) {
        uint32_t t = proto_get_u32(d + at), s0 = proto_get_u32(d + at + 4);
        uint32_t tx = t % tiles_x, ty = t / tiles_x;
        uint32_t tw = wd - tx * tile < tile ? wd - tx * tile : tile;
        uint32_t th = ht - ty * tile < tile ? ht - ty * tile : tile;
        CHECK(s0 % chunk == 0);
        proto_w_u64(w, (uint64_t)(s0 / chunk) * ntiles + t);
        at += 12;
        for (uint32_t k = 0; k < tw * th; k++, at += 72)
            pixel_to_v4(w, d + at);
    }
    for (uint64_t k = 0; k < (uint64_t)wd * ht; k++, at += 72)
        pixel_to_v4(w, d + at);
    CHECK(at + 4 == n);
}
static const state_converter CHECKPOINT_V4 = {checkpoint_v4, {4, 36}, 2, 1, 4};

/* Whether the frame at `at` of payload length len runs past the log's n
 * bytes: the last record that the kill -9 which made the state folder cut
 * short mid-write. ptserve drops it on reading ("incomplete last record"),
 * so a converted log leaves it out and resumes with the same samples. */
static int torn_tail(size_t at, uint32_t len, size_t n)
{
    return at + PROTO_FRAME_OVERHEAD + (size_t)len > n;
}

/* A RESULT payload of the current layout as protocol 3 wrote it (68 bytes of
 * header, f64 sums) into rec (reset first). */
static void payload_to_p3(const uint8_t *pl, uint32_t len, proto_writer *rec)
{
    proto_result r;
    CHECK(proto_msg_decode_result(pl, len, NULL, 0, &r, NULL) == PT_OK);
    proto_writer_reset(rec);
    proto_w_bytes(rec, pl, 68);
    for (uint32_t k = 0; k < r.npixels; k++) {
        for (int c = 0; c < 3; c++)
            proto_w_f64(rec, pt_acc_sum(&r.pixels[k], c));
        proto_w_f64(rec, pt_acc_sum_sq(&r.pixels[k]));
        proto_w_u32(rec, r.pixels[k].n);
        proto_w_u32(rec, r.pixels[k].hits);
    }
    proto_result_fini(&r);
}

/* A results log of frames ("PTRF") into one of format 4: records ("PTRL")
 * of a RESULT of protocol 3 (68 bytes of header, f64 sums), with their
 * checksum. */
static void log_v4(const uint8_t *d, size_t n, proto_writer *w)
{
    proto_writer rec;
    proto_writer_init(&rec, 1 << 30);
    CHECK(n >= 16 && proto_get_u32(d) == 0x46525450u);
    proto_w_u32(w, 0x4c525450u);
    proto_w_bytes(w, d + 4, 12);
    for (size_t at = 16; at + PROTO_FRAME_OVERHEAD <= n;) {
        uint32_t len = proto_frame_payload_len(d + at);
        if (torn_tail(at, len, n))
            break;
        CHECK(len >= 69);
        payload_to_p3(d + at + PROTO_FRAME_HEADER, len, &rec);
        proto_w_u32(w, (uint32_t)rec.len);
        proto_w_u32(w, proto_crc32c(0, rec.buf, rec.len));
        proto_w_bytes(w, rec.buf, rec.len);
        at += PROTO_FRAME_OVERHEAD + len;
    }
    proto_writer_fini(&rec);
}
static const state_converter LOG_V4 = {log_v4, {4}, 1, 0, 4};

/* A results log of frames with every frame's protocol version set to v (its
 * CRC32C redone): from 4 on the payload is kept (RESULT has not changed
 * since), for 3 it is rewritten in protocol 3's layout (f64 sums). */
static void log_frames_to(const char *name, uint16_t v)
{
    uint8_t *d;
    size_t n;
    if (!read_state(name, &d, &n))
        return;
    proto_writer w, rec;
    proto_writer_init(&w, 1 << 30);
    proto_writer_init(&rec, 1 << 30);
    CHECK(n >= 16 && proto_get_u32(d) == 0x46525450u);
    proto_w_bytes(&w, d, 16);
    for (size_t at = 16; at + PROTO_FRAME_OVERHEAD <= n;) {
        uint32_t len = proto_frame_payload_len(d + at);
        const uint8_t *pl = d + at + PROTO_FRAME_HEADER;
        if (torn_tail(at, len, n))
            break;
        CHECK(len >= 69);
        uint32_t m = len;
        if (v < 4) {
            payload_to_p3(pl, len, &rec);
            pl = rec.buf;
            m = (uint32_t)rec.len;
        }
        size_t h = w.len;
        proto_w_bytes(&w, d + at, 4); /* "PTF1" */
        proto_w_u16(&w, v);
        proto_w_u16(&w, PROTO_MSG_RESULT);
        proto_w_u32(&w, m);
        proto_w_bytes(&w, pl, m);
        proto_w_u32(&w, proto_crc32c(0, w.buf + h, w.len - h));
        at += PROTO_FRAME_OVERHEAD + len;
    }
    proto_writer_fini(&rec);
    pt_error e = {0};
    CHECK(proto_writer_status(&w) == PT_OK);
    CHECK(pt_write_file_atomic(path(name), w.buf, w.len, &e) == PT_OK);
    proto_writer_fini(&w);
    pt_free(d);
}

/* The job params block up to the camera (nine u32, two f64, str), copied; the
 * environment (str, f32 x2, u8, f32 x3) and the film flags after it dropped.
 * Returns the width, height and tile side. */
static void copy_params_v3(proto_writer *w, const uint8_t *d, size_t *at, uint32_t wht[3])
{
    wht[0] = proto_get_u32(d + *at);
    wht[1] = proto_get_u32(d + *at + 4);
    wht[2] = proto_get_u32(d + *at + 12);
    proto_w_bytes(w, d + *at, 9 * 4 + 16);
    *at += 9 * 4 + 16;
    copy_str(w, d, at);
    *at += 2 + proto_get_u16(d + *at) + 4 + 4 + 1 + 12; /* the environment */
    *at += 4;                                           /* film flags */
    *at += 2 + proto_get_u16(d + *at);                  /* material variant */
}

/* The queue file: each record without its environment, film flags, variant
 * and depth-cap count. */
static void queue_v3(const uint8_t *d, size_t n, proto_writer *w)
{
    size_t at = 8 + 8 + 4;
    proto_w_bytes(w, d, at);
    for (uint32_t i = 0, count = proto_get_u32(d + 16); i < count; i++) {
        proto_w_bytes(w, d + at, 8 + 8 + 1 + 4);
        at += 8 + 8 + 1 + 4;
        for (int k = 0; k < 4; k++) /* name, owner, scene, output */
            copy_str(w, d, &at);
        proto_w_bytes(w, d + at, 8); /* submitted */
        at += 8;
        uint32_t wht[3];
        copy_params_v3(w, d, &at, wht);
        proto_w_bytes(w, d + at, 32 + 8 + 8 + 8 + 8);
        at += 32 + 8 + 8 + 8 + 8;
        copy_str(w, d, &at); /* message */
        at += 8;             /* paths capped */
    }
    CHECK(at + 4 == n);
}
static const state_converter QUEUE_V3 = {queue_v3, {4}, 1, 1, 3};

/* A checkpoint: no environment, no film flags, no variant, no depth-cap
 * count, 36-byte pixels. */
static void checkpoint_v3(const uint8_t *d, size_t n, proto_writer *w)
{
    /* envelope 8, seconds/rejected/rays 24, magic, version, id, hash */
    size_t at = 8 + 24 + 4 + 4 + 8 + 32;
    proto_w_bytes(w, d, at);
    uint32_t wht[3];
    copy_params_v3(w, d, &at, wht);
    at += 8; /* paths capped */
    uint32_t ntiles = proto_get_u32(d + at);
    proto_w_bytes(w, d + at, 8 + (size_t)ntiles * 5 + 4);
    at += 8 + (size_t)ntiles * 5;
    uint32_t nheld = proto_get_u32(d + at);
    at += 4;
    uint32_t tiles_x = (wht[0] + wht[2] - 1) / wht[2], tiles_y = (wht[1] + wht[2] - 1) / wht[2];
    CHECK(tiles_x * tiles_y == ntiles);
    for (uint32_t i = 0; i < nheld; i++) {
        uint64_t t = proto_get_u64(d + at) % ntiles;
        uint32_t tx = (uint32_t)(t % tiles_x), ty = (uint32_t)(t / tiles_x);
        uint32_t tw = wht[0] - tx * wht[2] < wht[2] ? wht[0] - tx * wht[2] : wht[2];
        uint32_t th = wht[1] - ty * wht[2] < wht[2] ? wht[1] - ty * wht[2] : wht[2];
        proto_w_bytes(w, d + at, 8);
        at += 8;
        for (uint32_t k = 0; k < tw * th; k++, at += 40)
            proto_w_bytes(w, d + at, 36);
    }
    for (uint64_t k = 0; k < (uint64_t)wht[0] * wht[1]; k++, at += 40)
        proto_w_bytes(w, d + at, 36);
    CHECK(at + 4 == n);
}
static const state_converter CHECKPOINT_V3 = {checkpoint_v3, {4, 36}, 2, 1, 3};

/* A results log: each record a RESULT of protocol 2 (no depth-cap count,
 * 36-byte pixels), with its checksum. */
static void log_v3(const uint8_t *d, size_t n, proto_writer *w)
{
    proto_w_bytes(w, d, 16);
    uint8_t *rec = pt_malloc(n);
    for (size_t at = 16; rec && at + 8 <= n;) {
        uint32_t len = proto_get_u32(d + at);
        const uint8_t *pl = d + at + 8;
        CHECK(at + 8 + len <= n && len >= 68 && (len - 68) % 40 == 0);
        size_t m = 0;
        memcpy(rec, pl, 56);
        memcpy(rec + 56, pl + 64, 4);
        m = 60;
        for (uint32_t k = 0; k < (len - 68) / 40; k++, m += 36)
            memcpy(rec + m, pl + 68 + (size_t)k * 40, 36);
        proto_w_u32(w, (uint32_t)m);
        proto_w_u32(w, proto_crc32c(0, rec, m));
        proto_w_bytes(w, rec, m);
        at += 8 + len;
    }
    pt_free(rec);
}
static const state_converter LOG_V3 = {log_v3, {4}, 1, 0, 3};

/* The format before the min-gain rule (see set_format). */
static void to_format2(const char *name, long at, const long *vers, int nvers, int crc)
{
    set_format(name, at, vers, nvers, 2, crc);
}

/* The offset of the min gain in a queue file of one job: after the header,
 * the next id, the count and the record's fields up to the target error. */
static long queue_min_gain_at(const char *name)
{
    uint8_t *d = NULL;
    size_t n = 0;
    pt_error e = {0};
    CHECK(pt_read_file(path(name), 1 << 20, &d, &n, &e) == PT_OK);
    if (!d)
        return -1;
    CHECK(n > 20 && proto_get_u32(d + 16) == 1);
    size_t at = 8 + 8 + 4 + 8 + 8 + 1 + 4;
    for (int i = 0; i < 4 && at + 2 <= n; i++) /* name, owner, scene, output */
        at += 2 + proto_get_u16(d + at);
    at += 8 + 9 * 4 + 8; /* submitted, nine u32 parameters, target error */
    pt_free(d);
    CHECK(at + 8 < n);
    return (long)at;
}

/* Starts ptserve on a damaged state folder; returns its exit status when it
 * exits within a few seconds, or -1 when it keeps running (then stops it). */
static int start_damaged(const char *log)
{
    unlink(path("port"));
    char listen[64];
    snprintf(listen, sizeof listen, "127.0.0.1:%d", g_port);
    const char *argv[] = {PT_BIN_DIR "/ptserve", "--state-dir", path("state3"), "--listen", listen,
                          "--port-file",         path("port"),  "--quiet",      NULL};
    g_srv = spawn(argv, log);
    for (int i = 0; i < 100; i++) {
        int st;
        if (waitpid(g_srv, &st, WNOHANG) == g_srv) {
            g_srv = -1;
            return WIFEXITED(st) ? WEXITSTATUS(st) : 128;
        }
        if (access(path("port"), F_OK) == 0)
            return -1;
        sleep_ms(50);
    }
    return -1;
}

static void damaged(void)
{
    /* A job with a checkpoint and a results log: run, stop cleanly (checkpoint),
     * run again until more results are logged, kill -9. */
    g_port = 0;
    start_server("state3", "damage.log", NULL);
    pid_t w = start_worker("d1");
    uint64_t id = submit(g_port, job_of("damage", 64, 48, 65536, 0));
    proto_job_info info;
    double end = pt_now_s() + 60;
    while (pt_now_s() < end && status(g_port, id, &info) == PROTO_MSG_JOB_INFO &&
           info.samples_done < 64 * 48 * 16)
        sleep_ms(20);
    kill_server(SIGTERM);
    start_server("state3", "damage.log", NULL);
    /* From what the restart holds: a clean stop merges the results still
     * waiting for their commit, so that may be more than status said. */
    CHECK(status(g_port, id, &info) == PROTO_MSG_JOB_INFO);
    uint64_t base = info.samples_done;
    end = pt_now_s() + 60;
    while (pt_now_s() < end && status(g_port, id, &info) == PROTO_MSG_JOB_INFO &&
           info.samples_done < base + 64 * 48 * 16)
        sleep_ms(20);
    kill_server(SIGKILL);
    stop_worker(w);
    char job[64], ck[96], lg[96];
    snprintf(job, sizeof job, "state3/jobs/%llu", (unsigned long long)id);
    snprintf(ck, sizeof ck, "%s/checkpoint", job);
    snprintf(lg, sizeof lg, "%s/results.log", job);
    struct stat sb;
    CHECK(stat(path(ck), &sb) == 0);
    CHECK(stat(path(lg), &sb) == 0 && sb.st_size > 1000);
    copy_file("state3", "state3.good");

    /* The queue file: a flipped byte, then a truncation. ptserve refuses to start. */
    flip_byte("state3/queue", 30);
    CHECK(start_damaged("damage_q1.log") == 1);
    CHECK(log_has("damage_q1.log", "state3/queue") && log_has("damage_q1.log", "checksum"));
    copy_file("state3.good/queue", "state3/queue");
    cut_file("state3/queue", 7);
    CHECK(start_damaged("damage_q2.log") == 1);
    CHECK(log_has("damage_q2.log", "state3/queue"));
    copy_file("state3.good/queue", "state3/queue");

    /* The checkpoint and the log: the job fails naming the file; the server serves on. */
    struct {
        const char *file;
        long at, cut;
        const char *log, *expect;
    } cases[] = {
        {ck, 100, 0, "damage_c1.log", "checksum"},
        {ck, 0, 1000, "damage_c2.log", "truncated"},
        {lg, 40, 0, "damage_l1.log", "damaged"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        char cmd[1200];
        snprintf(cmd, sizeof cmd, "rm -rf '%s' && cp -a '%s' '%s'", path("state3"),
                 path("state3.good"), path("state3"));
        CHECK(system(cmd) == 0);
        if (cases[i].cut)
            cut_file(cases[i].file, cases[i].cut);
        else
            flip_byte(cases[i].file, cases[i].at);
        CHECK(start_damaged(cases[i].log) == -1);
        CHECK(status(g_port, id, &info) == PROTO_MSG_JOB_INFO);
        CHECKF(info.state == PROTO_JOB_FAILED && strstr(info.message, cases[i].file + 7) &&
                   strstr(info.message, cases[i].expect),
               "case %zu: state %u, message '%s'", i, info.state, info.message);
        kill_server(SIGTERM);
    }

    /* A log cut short at its end is what a crash during a write leaves: accepted. */
    char cmd[1200];
    snprintf(cmd, sizeof cmd, "rm -rf '%s' && cp -a '%s' '%s'", path("state3"), path("state3.good"),
             path("state3"));
    CHECK(system(cmd) == 0);
    cut_file(lg, 100);
    CHECK(start_damaged("damage_torn.log") == -1);
    CHECK(status(g_port, id, &info) == PROTO_MSG_JOB_INFO && info.state == PROTO_JOB_RUNNING);
    CHECK(info.samples_done > 0);
    kill_server(SIGTERM);
    CHECK(log_has("damage_torn.log", "incomplete last record"));

    /* State folders in format 9 (before the clamped count), 5 (before frame ranges), 4 (before
     * fixed-point sums), 3 (before the environment light and the film flags as well) and 2 (before
     * --min-gain as well): the same job resumes with the same samples as from the current format.
     */
    CHECK(system(cmd) == 0); /* state3.good again */
    CHECK(start_damaged("migrate_v5.log") == -1);
    proto_job_info v4;
    CHECK(status(g_port, id, &v4) == PROTO_MSG_JOB_INFO && v4.samples_done > 0);
    kill_server(SIGKILL);
    const long qv[] = {4}, cv[] = {4, 36};
    /* checkpoint: header 8, seconds/rejected/rays 24, magic, version, id, hash,
     * nine u32 parameters, target error; then the min gain */
    const long ck_gain = 8 + 24 + 4 + 4 + 8 + 32 + 36 + 8;
    for (uint32_t format = 9; format >= 2; format = format == 9 ? 6 : format - 1) {
        snprintf(cmd, sizeof cmd, "rm -rf '%s' && cp -a '%s' '%s'", path("state3"),
                 path("state3.good"), path("state3"));
        CHECK(system(cmd) == 0);
        /* Format 9: no contributions clamped in the queue's records and
         * the checkpoint. */
        convert("state3/queue", &QUEUE_V9);
        convert(ck, &CHECKPOINT_V9);
        /* Format 6: no shutter in the queue's records and the checkpoint. */
        if (format <= 6) {
            convert("state3/queue", &QUEUE_V6);
            convert(ck, &CHECKPOINT_V6);
        }
        /* Format 5: no frame ranges in the queue's records; the results
         * log's frames of protocol 4 (RESULT as today's: read as they are). */
        if (format <= 5) {
            convert("state3/queue", &QUEUE_V5);
            log_frames_to(lg, 4);
        }
        /* Format 4: double sums in the checkpoint, protocol 3's RESULT in
         * the results log (converted as read, and rewritten). */
        if (format <= 4) {
            convert("state3/queue", &QUEUE_V4);
            convert(ck, &CHECKPOINT_V4);
            convert(lg, &LOG_V4);
        }
        /* Format 3: no environment, no film flags, and the results log in
         * protocol 2's RESULT layout (read so, and rewritten). */
        if (format <= 3) {
            convert("state3/queue", &QUEUE_V3);
            convert(ck, &CHECKPOINT_V3);
            convert(lg, &LOG_V3);
        }
        if (format == 2) {
            to_format2("state3/queue", queue_min_gain_at("state3/queue"), qv, 1, 1);
            to_format2(ck, ck_gain, cv, 2, 1);
            to_format2(lg, -1, qv, 1, 0); /* the results log: only its header's version */
        }
        char log[32];
        snprintf(log, sizeof log, "migrate_v%u.log", format);
        CHECK(start_damaged(log) == -1);
        CHECKF(status(g_port, id, &info) == PROTO_MSG_JOB_INFO && info.state == PROTO_JOB_RUNNING &&
                   info.samples_done == v4.samples_done,
               "format %u: state %u, %llu samples (format 6: %llu)", format, info.state,
               (unsigned long long)info.samples_done, (unsigned long long)v4.samples_done);
        kill_server(SIGTERM);
    }
    /* A results log of protocol 3 frames (f64 sums) is converted as read and
     * rewritten in today's frames: the same samples. One of protocol 2 frames
     * is refused, naming the file and the protocol: that job fails. */
    for (uint16_t pv = 3; pv >= 2; pv--) {
        snprintf(cmd, sizeof cmd, "rm -rf '%s' && cp -a '%s' '%s'", path("state3"),
                 path("state3.good"), path("state3"));
        CHECK(system(cmd) == 0);
        log_frames_to(lg, pv);
        char log[32];
        snprintf(log, sizeof log, "migrate_p%u.log", pv);
        CHECK(start_damaged(log) == -1);
        if (pv == 3) {
            CHECKF(status(g_port, id, &info) == PROTO_MSG_JOB_INFO &&
                       info.state == PROTO_JOB_RUNNING && info.samples_done == v4.samples_done,
                   "protocol 3 frames: state %u, %llu samples (today's: %llu)", info.state,
                   (unsigned long long)info.samples_done, (unsigned long long)v4.samples_done);
            uint8_t *d = NULL;
            size_t n = 0;
            CHECK(read_state(lg, &d, &n) && n > 16 + PROTO_FRAME_HEADER &&
                  proto_get_u16(d + 16 + 4) == PROTO_VERSION);
            pt_free(d);
        } else {
            CHECK(status(g_port, id, &info) == PROTO_MSG_JOB_INFO &&
                  info.state == PROTO_JOB_FAILED);
            CHECK(log_has(log, "results.log") && log_has(log, "a frame of protocol 2"));
        }
        kill_server(SIGTERM);
    }
    /* A format this ptserve does not know is refused, naming the file. */
    const long fv[] = {4};
    copy_file("state3.good/queue", "state3/queue");
    set_format("state3/queue", -1, fv, 1, 99, 1);
    CHECK(start_damaged("migrate_v99.log") == 1);
    CHECK(log_has("migrate_v99.log", "state3/queue") && log_has("migrate_v99.log", "format 99"));
}

/* ---- 4. hostile clients ------------------------------------------------------------- */

/* A bundle of n files (name, bytes, size; binary data allowed) in the PTB1 layout. */
static uint8_t *make_bundle_n(const char *const *names, const uint8_t *const *datas,
                              const size_t *sizes, int n, size_t *len)
{
    proto_writer w;
    proto_writer_init(&w, 1 << 20);
    proto_w_u32(&w, 0x31425450u); /* "PTB1" */
    proto_w_u32(&w, (uint32_t)n);
    for (int i = 0; i < n; i++) {
        proto_w_u16(&w, (uint16_t)strlen(names[i]));
        proto_w_bytes(&w, names[i], strlen(names[i]));
        proto_w_u64(&w, sizes[i]);
        proto_w_bytes(&w, datas[i], sizes[i]);
    }
    *len = w.len;
    return w.buf;
}

/* The same for text files, their sizes by strlen. */
static uint8_t *make_bundle(const char *const *names, const char *const *datas, int n, size_t *len)
{
    const uint8_t *bytes[8];
    size_t sizes[8];
    if (n > 8)
        return NULL;
    for (int i = 0; i < n; i++) {
        bytes[i] = (const uint8_t *)datas[i];
        sizes[i] = strlen(datas[i]);
    }
    return make_bundle_n(names, bytes, sizes, n, len);
}

static int refused(proto_submit m, const uint8_t *data, size_t n, const char *expect)
{
    cli c;
    if (cli_open(&c, g_port) != 0)
        return 0;
    err_text[0] = '\0';
    uint64_t id = submit_bytes(&c, m, data, n);
    int ok = id == 0 && strstr(err_text, expect) != NULL;
    if (!ok)
        fprintf(stderr, "expected a refusal with '%s', got job %llu / '%s'\n", expect,
                (unsigned long long)id, err_text);
    cli_close(&c);
    return ok;
}

static void hostile_clients(void)
{
    const char *ref[] = {PT_BIN_DIR "/ptworker",
                         "--scene",
                         SCENE,
                         "--res",
                         "64x48",
                         "--tile",
                         "16",
                         "--chunk",
                         "8",
                         "--seed",
                         "5",
                         "--spp",
                         "256",
                         "-o",
                         path("hostile_ref.exr"),
                         "-q",
                         NULL};
    CHECK(run(ref, "hostile_ref.log", 300) == 0);
    g_port = 0;
    start_server("state4", "hostile.log", "--max-queued");
    uint64_t id = submit(g_port, job_of("victim", 64, 48, 256, 0));
    CHECK(id > 0);
    const uint8_t *B = g_bundle->data;
    size_t N = g_bundle->size;

    CHECK(refused(job_of("../../etc/passwd", 64, 48, 16, 0), B, N, "not a plain name"));
    CHECK(refused(job_of("/etc/passwd", 64, 48, 16, 0), B, N, "not a plain name"));
    CHECK(refused(job_of(".hidden", 64, 48, 16, 0), B, N, "not a plain name"));
    CHECK(refused(job_of("wide", 100000, 48, 16, 0), B, N, "resolution"));
    CHECK(refused(job_of("many", 64, 48, 1u << 24, 0), B, N, "samples per pixel"));
    CHECK(refused(job_of("zero", 64, 48, 0, 0), B, N, "SUBMIT"));
    proto_submit both = job_of("both", 64, 48, 16, 0);
    both.target_error = 0.05;
    both.min_gain = 1e-6;
    CHECK(refused(both, B, N, "two adaptive rules"));
    /* Frame ranges: refused at SUBMIT, the server serving on. */
    proto_submit fr = job_of("shot", 64, 48, 16, 0);
    fr.frame_first = 9;
    fr.frame_last = 3;
    fr.frame_step = 1;
    fr.fps = 24.0;
    CHECK(refused(fr, B, N, "bad frame range"));
    fr.frame_first = 0;
    fr.fps = 2e6;
    CHECK(refused(fr, B, N, "frames per second is out of range"));
    /* ptctl refuses a rate this small; a raw SUBMIT with it put its frames
     * at an infinite time, and workers reconnected in a loop. */
    fr.fps = 5e-324;
    CHECK(refused(fr, B, N, "frames per second is out of range"));
    fr.fps = 1e-4;
    CHECK(refused(fr, B, N, "frames per second is out of range"));

    /* Bundles: a file named ../x, a lying inner length, the wrong hash, a broken glTF. */
    const char *n1[] = {"scene.gltf", "../evil.bin"}, *d1[] = {"{}", "x"};
    size_t len;
    uint8_t *evil = make_bundle(n1, d1, 2, &len);
    CHECK(refused(job_of("evil", 0, 0, 16, 0), evil, len, "bad scene bundle"));
    proto_put_u64(evil + 8 + 2 + strlen(n1[0]), 1u << 30); /* entry claims 1 GiB */
    CHECK(refused(job_of("liar", 0, 0, 16, 0), evil, len, "bad scene bundle"));
    free(evil);
    const char *n2[] = {"scene.gltf"},
               *d2[] = {"{\"asset\": {\"version\": \"2.0\"}, \"buffers\": ["};
    uint8_t *broken = make_bundle(n2, d2, 1, &len);
    CHECK(refused(job_of("broken", 0, 0, 16, 0), broken, len, "scene refused"));
    free(broken);
    /* JSON nested 30,000 deep (60 KB) overflowed the upload check's stack in
     * tinygltf's recursive parse and killed the server: now it is refused,
     * and everything below shows the server serving on. */
    enum { DEEP = 30000 };
    char *deep = malloc(2 * DEEP + 64);
    size_t dn = (size_t)sprintf(deep, "{\"asset\": {\"version\": \"2.0\"}, \"extras\": ");
    memset(deep + dn, '[', DEEP);
    memset(deep + dn + DEEP, ']', DEEP);
    strcpy(deep + dn + 2 * DEEP, "}");
    const char *d3[] = {deep};
    uint8_t *deep_bundle = make_bundle(n2, d3, 1, &len);
    CHECK(refused(job_of("deep", 0, 0, 16, 0), deep_bundle, len, "more than 128 deep"));
    free(deep_bundle);
    free(deep);

    cli c;
    proto_frame f;
    /* The announced size is absurd. */
    CHECK(cli_open(&c, g_port) == 0);
    proto_submit m = job_of("huge", 64, 48, 16, 0);
    m.bundle_size = 1ull << 62;
    submit_begin(&c, &m);
    CHECK(reply(&c, &f) == -2 && strstr(err_text, "over this server's limit"));
    cli_close(&c);
    /* A film over --max-film-mb (default 4096 MiB): 4096x4096 is within the
     * pixel cap, but with render passes its film would take 7.5 GiB. */
    CHECK(cli_open(&c, g_port) == 0);
    m = job_of("film", 4096, 4096, 16, 0);
    m.film_flags = proto_film_of_passes(PT_PASS_ALL);
    m.bundle_size = N;
    submit_begin(&c, &m);
    CHECK(reply(&c, &f) == -2 && strstr(err_text, "with render passes takes 7680 MiB") &&
          strstr(err_text, "--max-film-mb"));
    cli_close(&c);
    /* Uploads that do not continue what SUBMIT announced: a wrong total, a gap. */
    for (int k = 0; k < 2; k++) {
        CHECK(cli_open(&c, g_port) == 0);
        m = job_of("gap", 64, 48, 16, 0);
        m.bundle_size = N;
        hash_bytes(B, N, m.bundle_hash);
        submit_begin(&c, &m);
        if (k == 0)
            upload(&c, m.bundle_hash, B, N + 10, 0, (uint32_t)N);
        else
            upload(&c, m.bundle_hash, B, N, 1, (uint32_t)N - 1);
        CHECK(reply(&c, &f) == -2 && strstr(err_text, "does not continue"));
        cli_close(&c);
    }
    /* The bytes do not hash to what SUBMIT announced. */
    CHECK(cli_open(&c, g_port) == 0);
    m = job_of("hash", 64, 48, 16, 0);
    m.bundle_size = N;
    memset(m.bundle_hash, 0xab, 32);
    submit_begin(&c, &m);
    upload(&c, m.bundle_hash, B, N, 0, (uint32_t)N);
    CHECK(reply(&c, &f) == -2 && strstr(err_text, "SHA-256"));
    cli_close(&c);
    /* A submit that stops half-way: the client goes away. */
    CHECK(cli_open(&c, g_port) == 0);
    m = job_of("half", 64, 48, 16, 0);
    m.bundle_size = N;
    hash_bytes(B, N, m.bundle_hash);
    submit_begin(&c, &m);
    upload(&c, m.bundle_hash, B, N, 0, (uint32_t)(N / 2));
    sleep_ms(100);
    cli_close(&c);
    /* A worker's message from a client. */
    CHECK(cli_open(&c, g_port) == 0);
    proto_writer w;
    proto_writer_init(&w, 64);
    proto_work_request wr = {4};
    proto_msg_encode_work_request(&w, &wr, NULL);
    cli_send(&c, PROTO_MSG_WORK_REQUEST, &w);
    proto_writer_fini(&w);
    CHECK(reply(&c, &f) == -2 && strstr(err_text, "from a client"));
    cli_close(&c);

    /* The cap of --max-queued 2: a second unfinished job is taken, a third is not. */
    uint64_t second = submit(g_port, job_of("second", 32, 32, 16, 0));
    CHECK(second > 0);
    CHECK(refused(job_of("third", 64, 48, 16, 0), B, N, "unfinished jobs"));
    CHECK(cli_open(&c, g_port) == 0);
    send_ref(&c, PROTO_MSG_CANCEL, second);
    CHECK(reply(&c, &f) == PROTO_MSG_JOB_INFO);
    cli_close(&c);

    /* Nothing else was queued, and the victim renders to the end, exactly. */
    CHECK(cli_open(&c, g_port) == 0);
    cli_send(&c, PROTO_MSG_LIST, NULL);
    proto_job_list list = {0};
    CHECK(reply(&c, &f) == PROTO_MSG_JOB_LIST &&
          proto_msg_decode_job_list(f.payload, f.len, &list, NULL) == PT_OK && list.count == 2);
    pt_free(list.jobs);
    cli_close(&c);
    pid_t wk = start_worker("h1");
    proto_job_info info;
    CHECK(wait_state(g_port, id, PROTO_JOB_DONE, 300, &info));
    CHECK(fetch(g_port, id, "hostile.exr") == 0);
    CHECK(same_pixels("hostile_ref.exr", "hostile.exr"));
    CHECK(all_samples("hostile.exr", 256.0f));
    CHECK(log_has("hostile.log", "left during an upload"));
    stop_worker(wk);
    kill_server(SIGTERM);
}

/* ---- 5. scenes are checked off the event loop --------------------------------------- */

/* Lines of log that contain needle. */
static int log_count(const char *log, const char *needle)
{
    FILE *f = fopen(path(log), "r");
    int n = 0;
    char line[4096];
    while (f && fgets(line, sizeof line, f))
        n += strstr(line, needle) != NULL;
    if (f)
        fclose(f);
    return n;
}

/* Waits up to 60 s for n lines of log with needle. */
static int wait_log_count(const char *log, const char *needle, int n)
{
    for (double end = pt_now_s() + 60; pt_now_s() < end; sleep_ms(50))
        if (log_count(log, needle) >= n)
            return 1;
    return 0;
}

/* Sends SUBMIT and the whole of bundle b as job name. */
static void send_submission(cli *c, const char *name, const pt_bundle *b)
{
    proto_submit m = job_of(name, 64, 48, 16, 0);
    /* The spheres have no light of their own: a uniform sky lights them. */
    m.env.background = 1;
    m.env.rgb[0] = m.env.rgb[1] = m.env.rgb[2] = 1.0f;
    m.bundle_size = b->size;
    hash_bytes(b->data, b->size, m.bundle_hash);
    submit_begin(c, &m);
    upload(c, m.bundle_hash, b->data, b->size, 0, (uint32_t)b->size);
}

static void checked_off_loop(void)
{
    char big_path[1024];
    snprintf(big_path, sizeof big_path,
             "%s/MetalRoughSpheresNoTextures/MetalRoughSpheresNoTextures.glb", PT_SHARED_SCENES);
    struct stat sb;
    if (stat(big_path, &sb) != 0) {
        const char *ci = getenv("CI");
        CHECKF(!ci || strcmp(ci, "true") != 0, "CI needs %s", big_path);
        CHECK_SKIP("the off-loop check: no %s", big_path);
        return;
    }
    pt_bundle *big = NULL;
    pt_error err = {0};
    CHECK(pt_bundle_pack(big_path, &big, &err) == PT_OK);
    if (!big)
        return;
    g_port = 0;
    start_server("state5", "check.log", NULL);
    proto_frame f;
    /* A million triangles take the server a good part of a second to check;
     * meanwhile another client is answered at once, and the submitter not yet. */
    cli a, b;
    CHECK(cli_open(&a, g_port) == 0 && cli_open(&b, g_port) == 0);
    send_submission(&a, "spheres", big);
    sleep_ms(30); /* the upload has arrived: its check runs */
    cli_send(&b, PROTO_MSG_LIST, NULL);
    CHECK(reply(&b, &f) == PROTO_MSG_JOB_LIST);
    struct pollfd pa = {a.fd, POLLIN, 0};
    CHECK(poll(&pa, 1, 0) == 0 && a.len == a.used);
    proto_job_ref ref = {0};
    CHECK(reply(&a, &f) == PROTO_MSG_SUBMITTED &&
          proto_msg_decode_job_ref(f.payload, f.len, &ref, NULL) == PT_OK && ref.job_id > 0);
    cli_close(&a);
    /* A request before the answer to a SUBMIT is refused; a submitter that
     * leaves during its check queues nothing. */
    CHECK(cli_open(&a, g_port) == 0);
    send_submission(&a, "eager", big);
    cli_send(&a, PROTO_MSG_LIST, NULL);
    CHECK(reply(&a, &f) == -2 && strstr(err_text, "before the answer to its SUBMIT"));
    cli_close(&a);
    const char *left = "left before its scene was checked";
    CHECK(wait_log_count("check.log", left, 1));
    CHECK(cli_open(&a, g_port) == 0);
    send_submission(&a, "gone", big);
    cli_close(&a);
    CHECK(wait_log_count("check.log", left, 2));
    cli_send(&b, PROTO_MSG_LIST, NULL);
    proto_job_list list = {0};
    CHECK(reply(&b, &f) == PROTO_MSG_JOB_LIST &&
          proto_msg_decode_job_list(f.payload, f.len, &list, NULL) == PT_OK && list.count == 1 &&
          list.jobs[0].job_id == ref.job_id);
    pt_free(list.jobs);
    cli_close(&b);
    /* Four uploads (a client's most) complete at once: SRV_MAX_SCENE_CHECKS are checked at a
     * time (each holds a decoded scene), the rest wait their turn, and every
     * one is queued in the end. */
    cli many[SRV_MAX_UPLOADS_PER_CLIENT];
    for (int i = 0; i < (int)SRV_MAX_UPLOADS_PER_CLIENT; i++) {
        char name[16];
        snprintf(name, sizeof name, "many%d", i);
        CHECK(cli_open(&many[i], g_port) == 0);
        send_submission(&many[i], name, big);
    }
    for (int i = 0; i < (int)SRV_MAX_UPLOADS_PER_CLIENT; i++) {
        ref.job_id = 0;
        CHECK(reply(&many[i], &f) == PROTO_MSG_SUBMITTED &&
              proto_msg_decode_job_ref(f.payload, f.len, &ref, NULL) == PT_OK && ref.job_id);
        cli_close(&many[i]);
    }
    CHECK(log_count("check.log", "waits to be checked: 2 checks run at once") >= 1);
    pt_bundle_free(big);
    kill_server(SIGTERM);
}

/* ---- 7. uploads on disk ------------------------------------------------------------- */

/* Files in folder whose names start with prefix (of size bytes, when size
 * is not 0). */
static int count_files_sized(const char *folder, const char *prefix, off_t size)
{
    DIR *d = opendir(folder);
    int n = 0;
    for (struct dirent *e; d && (e = readdir(d));) {
        char p[2048];
        struct stat sb;
        snprintf(p, sizeof p, "%s/%s", folder, e->d_name);
        n += strncmp(e->d_name, prefix, strlen(prefix)) == 0 &&
             (!size || (stat(p, &sb) == 0 && sb.st_size == size));
    }
    if (d)
        closedir(d);
    return n;
}

static int count_files(const char *folder, const char *prefix)
{
    return count_files_sized(folder, prefix, 0);
}

static void uploads_on_disk(void)
{
    enum { MIB = 1 << 20, SIZE = 48 * MIB, SENT = 47, N = SRV_MAX_UPLOADS_PER_CLIENT };
    uint8_t *junk = malloc(SIZE), hash[32];
    for (size_t i = 0; i < SIZE; i++)
        junk[i] = (uint8_t)(i * 2654435761u >> 13);
    hash_bytes(junk, SIZE, hash);
    g_port = 0;
    /* Under AddressSanitizer freed buffers wait in its quarantine (256 MiB),
     * which the upload frames fill: this server runs without one, so its
     * resident memory is what it holds. */
    const char *asan = getenv("ASAN_OPTIONS");
    char *saved = asan ? strdup(asan) : NULL;
    char opts[1024];
    snprintf(opts, sizeof opts, "%s%squarantine_size_mb=0", saved ? saved : "",
             saved && *saved ? ":" : "");
    setenv("ASAN_OPTIONS", opts, 1);
    start_server("state7", "uploads.log", NULL);
    if (saved)
        setenv("ASAN_OPTIONS", saved, 1);
    else
        unsetenv("ASAN_OPTIONS");
    free(saved);
    long base = rss_kib(g_srv);
    static cli c[N + 1];
    for (int i = 0; i <= N; i++) {
        char name[16];
        snprintf(name, sizeof name, "held%d", i);
        CHECK(cli_open(&c[i], g_port) == 0);
        proto_submit m = job_of(name, 64, 48, 16, 0);
        m.bundle_size = SIZE;
        memcpy(m.bundle_hash, hash, 32);
        submit_begin(&c[i], &m);
        if (i == N)
            break;
        /* In halves: send_frame's writer holds a frame of at most 1 MiB. */
        for (int k = 0; k < 2 * SENT; k++)
            upload(&c[i], hash, junk, SIZE, (uint64_t)k * (MIB / 2), MIB / 2);
    }
    /* The fifth of one client is refused; the four others are all in. */
    proto_frame f;
    CHECK(reply(&c[N], &f) == -2 && strstr(err_text, "too many uploads in progress"));
    cli_close(&c[N]);
    char part_dir[1024];
    snprintf(part_dir, sizeof part_dir, "%s/tmp", path("state7"));
    /* Every byte sent is with the server: on disk, in its upload files. */
    for (double end = pt_now_s() + 30; pt_now_s() < end; sleep_ms(50))
        if (count_files_sized(part_dir, "part-", (off_t)SENT * MIB) == N)
            break;
    CHECK(count_files_sized(part_dir, "part-", (off_t)SENT * MIB) == N);
    long held = rss_kib(g_srv);
    CHECKF(base > 0 && held - base < 32 * 1024,
           "%d uploads of %d MiB held open took the server from %ld to %ld KiB", N, SENT, base,
           held);
    fprintf(stderr, "uploads: %d x %d MiB held open: VmRSS %ld -> %ld KiB\n", N, SENT, base, held);
    CHECK(count_files(part_dir, "part-") == N);
    for (int i = 0; i < N; i++)
        cli_close(&c[i]);
    CHECK(wait_log_count("uploads.log", "left during an upload", N));
    CHECK(count_files(part_dir, "part-") == 0);
    free(junk);
    kill_server(SIGTERM);
}

/* ---- 6. files outside the upload ---------------------------------------------------- */

/* One triangle: buffer bin_uri (68 bytes: positions, u16 indices at 36, uvs
 * at 44), its material's base colour image img_uri (or none). */
static void outside_scene(char *json, size_t cap, const char *bin_uri, const char *img_uri)
{
    char img[1024] = "";
    if (img_uri)
        snprintf(img, sizeof img,
                 ",\"textures\":[{\"source\":0}],\"images\":[{\"uri\":\"%s\"}],"
                 "\"materials\":[{\"pbrMetallicRoughness\":{\"baseColorTexture\":{\"index\":0}}}]",
                 img_uri);
    snprintf(json, cap,
             "{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],"
             "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":"
             "{\"POSITION\":0,\"TEXCOORD_0\":2},\"indices\":1%s}]}],"
             "\"buffers\":[{\"uri\":\"%s\",\"byteLength\":68}],\"bufferViews\":["
             "{\"buffer\":0,\"byteOffset\":0,\"byteLength\":36},"
             "{\"buffer\":0,\"byteOffset\":36,\"byteLength\":6},"
             "{\"buffer\":0,\"byteOffset\":44,\"byteLength\":24}],\"accessors\":["
             "{\"bufferView\":0,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\"},"
             "{\"bufferView\":1,\"componentType\":5123,\"count\":3,\"type\":\"SCALAR\"},"
             "{\"bufferView\":2,\"componentType\":5126,\"count\":3,\"type\":\"VEC2\"}]%s}",
             img_uri ? ",\"material\":0" : "", bin_uri, img);
}

/* Submits a bundle of scene.gltf (json) and, when bin is given, tri.bin;
 * expects a refusal containing `expect`, and a reply that shows none of the
 * secrets' bytes, nor `leaks` (a size, an index), nor the server's paths
 * (its state folder, the upload's folder). The URI the client wrote may be
 * quoted: it names nothing the client does not know. */
static void refused_outside(const char *what, const char *json, const uint8_t *bin,
                            const char *expect, const char *leaks)
{
    const char *names[] = {"scene.gltf", "tri.bin"};
    const uint8_t *datas[] = {(const uint8_t *)json, bin};
    size_t sizes[] = {strlen(json), 68}, len;
    uint8_t *b = make_bundle_n(names, datas, sizes, bin ? 2 : 1, &len);
    cli c;
    CHECK(cli_open(&c, g_port) == 0);
    err_text[0] = '\0';
    uint64_t id = submit_bytes(&c, job_of(what, 32, 32, 4, 0), b, len);
    cli_close(&c);
    free(b);
    CHECKF(id == 0 && strstr(err_text, "scene refused") && strstr(err_text, expect),
           "%s: job %llu, '%s'", what, (unsigned long long)id, err_text);
    const char *never[] = {"PTFARM", "root:", "state6", "upload-", leaks};
    for (size_t i = 0; i < sizeof never / sizeof *never; i++)
        CHECKF(!strstr(err_text, never[i]), "%s: the reply shows '%s': %s", what, never[i],
               err_text);
}

/* A client names files of the server's in its scene: "../../x", an absolute
 * path, /dev/zero as an image. The coordinator's check opens none of them
 * (README: "the server never opens a path a client names"), its reply
 * shows neither the file's bytes, nor its size, nor a path of the server,
 * and the next good submit is served. */
static void outside_files(void)
{
    /* Two secrets beside the state folder: 70 bytes (a 68-byte buffer would
     * be told its size), and 68 bytes whose u16 at 36 an index error would
     * print. */
    const char *s70 = "PTFARM-SECRET-0123456789-PTFARM-SECRET-0123456789-PTFARM-SECRET-01234\n";
    const char *s68 = "PTFARM-SECRET-0123456789-PTFARM-SECR"
                      "ZZ"
                      "ZZ-PTFARM-SECRET-0123456789ab\n";
    CHECK(strlen(s70) == 70 && strlen(s68) == 68);
    FILE *f = fopen(path("secret70.txt"), "wb");
    CHECK(f && fwrite(s70, 1, 70, f) == 70 && fclose(f) == 0);
    f = fopen(path("secret68.txt"), "wb");
    CHECK(f && fwrite(s68, 1, 68, f) == 68 && fclose(f) == 0);
    unsigned zz = 'Z' | 'Z' << 8; /* the index the 68-byte secret holds */
    char zz_text[16];
    snprintf(zz_text, sizeof zz_text, "%u", zz);

    g_port = 0;
    start_server("state6", "outside.log", NULL);
    /* From state6/tmp/upload-N, more "../" than needed reach '/', then tmp. */
    char up70[1024], up68[1024], abs70[512];
    snprintf(abs70, sizeof abs70, "%s", path("secret70.txt"));
    snprintf(up70, sizeof up70, "../../../../../../../../../../../../../../../..%s", abs70);
    snprintf(up68, sizeof up68, "../../../../../../../../../../../../../../../..%s",
             path("secret68.txt"));
    char json[4096];
    outside_scene(json, sizeof json, up70, NULL);
    refused_outside("up70", json, NULL, "leads out", " 70");
    outside_scene(json, sizeof json, up68, NULL);
    refused_outside("up68", json, NULL, "leads out", zz_text);
    outside_scene(json, sizeof json, abs70, NULL);
    refused_outside("abs70", json, NULL, "absolute", " 70");

    /* An image on a device: refused before a byte is read. */
    unsigned char bin[68] = {0};
    float pos[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    uint16_t idx[3] = {0, 1, 2};
    memcpy(bin, pos, 36);
    memcpy(bin + 36, idx, 6);
    outside_scene(json, sizeof json, "tri.bin", "/dev/zero");
    refused_outside("zero", json, bin, "absolute", "1073741824");
    outside_scene(json, sizeof json, "tri.bin", "%2e%2e/%2e%2e/%2e%2e/%2e%2e/etc/passwd");
    refused_outside("passwd", json, bin, "leads out", ":0:0:");

    /* The same bundle with the image inside it is taken, and the server serves on. */
    outside_scene(json, sizeof json, "tri.bin", NULL);
    const char *names[] = {"scene.gltf", "tri.bin"};
    const uint8_t *datas[] = {(const uint8_t *)json, bin};
    size_t sizes[] = {strlen(json), 68}, len;
    uint8_t *good = make_bundle_n(names, datas, sizes, 2, &len);
    cli c;
    CHECK(cli_open(&c, g_port) == 0);
    /* Lit by a uniform sky: a scene with no light is refused (test_farm_env). */
    proto_submit inside = job_of("inside", 32, 32, 4, 0);
    inside.env.background = 1;
    inside.env.rgb[0] = inside.env.rgb[1] = inside.env.rgb[2] = 1.0f;
    uint64_t id = submit_bytes(&c, inside, good, len);
    CHECKF(id > 0, "the good scene was refused: %s", err_text);
    cli_close(&c);
    free(good);
    CHECK(submit(g_port, job_of("cornell", 32, 32, 4, 0)) > 0);
    kill_server(SIGTERM);
}

int main(void)
{
    snprintf(tmp, sizeof tmp, "/tmp/pt_test_queue_XXXXXX");
    if (!mkdtemp(tmp))
        return 1;
    signal(SIGPIPE, SIG_IGN);
    pt_error err = {0};
    if (pt_bundle_pack(SCENE, &g_bundle, &err) != PT_OK) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    crash_restart();
    queue_order();
    damaged();
    hostile_clients();
    checked_off_loop();
    outside_files();
    uploads_on_disk();
    pt_bundle_free(g_bundle);
    if (g_srv > 0)
        kill_server(SIGKILL);
    return farm_test_end();
}
