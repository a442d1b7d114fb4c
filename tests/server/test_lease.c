/*
 * test_lease.c - leases that end, backups, refused garbage and caught liars:
 * a real ptserve, real ptworkers and raw protocol peers on loopback.
 *
 *  a. A hoarder that asks for every task and only heartbeats: its leases
 *     pass their hard deadline and are requeued, it is blocked after
 *     repeated misses and refused when it comes back under its name, and the
 *     job completes bit-identical to a clean render.
 *  b. A peer that takes a task and sits on it (leases of ten minutes): the
 *     idle real worker gets a backup copy and the job ends long before.
 *  c. Garbage results (sums of 1e38 and -1e30, counts of 0, counts that are
 *     not the task's samples): each refused with ERROR, counted, nothing
 *     merged: the image is bit-identical to a clean render.
 *  d. A liar that renders nothing and answers plausible sums, with
 *     --verify-fraction 1 beside two real workers: found by a verification
 *     copy and a third render, blocked with the reason logged, refused when
 *     it comes back.
 *  e. --verify-fraction 1 with honest workers only: every task rendered
 *     twice, every copy matches, the image is bit-identical.
 *  f. The liar in queue mode: `ptctl status` of the job, once done, says
 *     how many of the liar's results were merged unverified.
 *  g. A worker that renders nothing and says every sample was rejected, in
 *     queue mode with --verify-fraction 1: alone, its job fails ("every
 *     sample was rejected"), status and JSON count the rejected samples,
 *     and the log says no task was verified (none was compared); beside an
 *     honest worker, three such results in a row (here the verification
 *     copies of the honest worker's tasks, which it is handed first) block
 *     it.
 *  h. Frames in flight: with --max-pixels at twice a frame's pixels, a
 *     worker that asks for 64 tasks of a ten-frame range gets tasks of two
 *     frames, not of SRV_FRAMES_AHEAD (each frame in flight holds a film).
 *
 * With PT_LEASE_MEASURE set it only measures, at the default lease timeout,
 * how long a stalled lease (a peer that holds a task and heartbeats) takes to
 * be requeued once the job has results, three times, and prints the times.
 */
#include <errno.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include "common/base/net.h"
#include "common/render/render.h"
#include "protocol/auth.h"
#include "protocol/frame.h"
#include "protocol/msg.h"
#include "tests/check.h"

#include "tests/server/farm_util.h"

static const char *SCENE = PT_SOURCE_DIR "/scenes/cornell_box.gltf";
static const char *TOKEN = "correct horse battery staple";
#define COMMON "--res", "48x32", "--tile", "16", "--seed", "3"

/* ---- a raw worker: frames kept across reads ---- */

typedef struct peer {
    int fd;
    uint8_t buf[1 << 20];
    size_t len;
    int closed;                           /* the server closed the connection */
    char error[PROTO_MAX_ERROR_TEXT + 1]; /* the ERROR text it sent, if any */
    proto_task tasks[1024];               /* the last 1024 TASKs received (a ring) */
    uint32_t ntasks, next;
} peer;

/* Reads what is there within timeout_ms; TASKs go to p->tasks, an ERROR to
 * p->error. */
static void peer_read(peer *p, int timeout_ms)
{
    double end = pt_now_s() + timeout_ms / 1000.0;
    do {
        struct pollfd pf = {p->fd, POLLIN, 0};
        if (!p->closed && poll(&pf, 1, 20) == 1) {
            ssize_t r = recv(p->fd, p->buf + p->len, sizeof p->buf - p->len, 0);
            if (r == 0 || (r < 0 && errno != EINTR && errno != EAGAIN))
                p->closed = 1;
            else if (r > 0)
                p->len += (size_t)r;
        }
        for (;;) {
            proto_frame f;
            size_t used;
            if (!p->len ||
                proto_frame_decode(p->buf, p->len, PROTO_MAX_PAYLOAD, &f, &used, NULL) != PT_OK)
                break;
            if (f.type == PROTO_MSG_TASK) {
                if (proto_msg_decode_task(f.payload, f.len, &p->tasks[p->next], NULL) == PT_OK) {
                    p->next = (p->next + 1) % 1024;
                    if (p->ntasks < 1024)
                        p->ntasks++;
                }
            } else if (f.type == PROTO_MSG_ERROR) {
                proto_error_msg m;
                if (proto_msg_decode_error(f.payload, f.len, &m, NULL) == PT_OK)
                    snprintf(p->error, sizeof p->error, "%s", m.text);
            }
            memmove(p->buf, p->buf + used, p->len - used);
            p->len -= used;
        }
    } while (pt_now_s() < end && !p->closed);
}

/* Connects and authenticates as worker name of threads render threads;
 * returns 1 once WELCOME came, 0 when the server refused (p->error says
 * why). */
static int peer_open_threads(peer *p, int port, const char *name, uint16_t threads)
{
    memset(p, 0, sizeof *p);
    p->fd = connect_to(port);
    if (p->fd < 0)
        return 0;
    proto_hello h = {0};
    h.version = PROTO_VERSION;
    h.role = PROTO_ROLE_WORKER;
    snprintf(h.name, sizeof h.name, "%s", name);
    h.threads = threads;
    snprintf(h.build_id, sizeof h.build_id, "%s", proto_build_id());
    proto_writer w;
    proto_writer_init(&w, 4096);
    proto_msg_encode_hello(&w, &h, NULL);
    send_frame(p->fd, PROTO_MSG_HELLO, &w);
    proto_writer_fini(&w);
    proto_frame f;
    size_t used;
    double end = pt_now_s() + 10;
    int stage = 0; /* 0: wants CHALLENGE, 1: wants WELCOME */
    while (pt_now_s() < end && !p->closed) {
        struct pollfd pf = {p->fd, POLLIN, 0};
        if (poll(&pf, 1, 50) == 1) {
            ssize_t r = recv(p->fd, p->buf + p->len, sizeof p->buf - p->len, 0);
            if (r <= 0)
                p->closed = 1;
            else
                p->len += (size_t)r;
        }
        while (p->len &&
               proto_frame_decode(p->buf, p->len, PROTO_MAX_PAYLOAD, &f, &used, NULL) == PT_OK) {
            int type = f.type;
            if (type == PROTO_MSG_ERROR) {
                proto_error_msg m;
                if (proto_msg_decode_error(f.payload, f.len, &m, NULL) == PT_OK)
                    snprintf(p->error, sizeof p->error, "%s", m.text);
            } else if (type == PROTO_MSG_CHALLENGE && stage == 0) {
                proto_challenge ch;
                proto_msg_decode_challenge(f.payload, f.len, &ch, NULL);
                proto_auth a;
                proto_auth_response((const uint8_t *)TOKEN, strlen(TOKEN), ch.nonce, a.mac, NULL);
                proto_writer_init(&w, 4096);
                proto_msg_encode_auth(&w, &a, NULL);
                send_frame(p->fd, PROTO_MSG_AUTH, &w);
                proto_writer_fini(&w);
                stage = 1;
            }
            memmove(p->buf, p->buf + used, p->len - used);
            p->len -= used;
            if (type == PROTO_MSG_WELCOME)
                return 1;
        }
    }
    return 0;
}

static int peer_open(peer *p, int port, const char *name)
{
    return peer_open_threads(p, port, name, 1);
}

static void peer_ask(peer *p, uint16_t slots)
{
    proto_work_request r = {slots};
    proto_writer w;
    proto_writer_init(&w, 64);
    proto_msg_encode_work_request(&w, &r, NULL);
    send_frame(p->fd, PROTO_MSG_WORK_REQUEST, &w);
    proto_writer_fini(&w);
}

static void peer_heartbeat(peer *p)
{
    static proto_heartbeat hb;
    hb.count = 0;
    for (uint32_t i = 0; i < p->ntasks && hb.count < PROTO_MAX_HEARTBEAT_TASKS; i++)
        hb.task_ids[hb.count++] = p->tasks[i].task_id;
    proto_writer w;
    proto_writer_init(&w, 1 << 16);
    proto_msg_encode_heartbeat(&w, &hb, NULL);
    send_frame(p->fd, PROTO_MSG_HEARTBEAT, &w);
    proto_writer_fini(&w);
}

/* Sends a result for t whose every pixel is px (n as given). */
static void peer_result(peer *p, const proto_task *t, pt_pixel_acc px, uint64_t rejected)
{
    static pt_pixel_acc pixels[PROTO_MAX_TILE_PIXELS];
    proto_result r;
    memset(&r, 0, sizeof r);
    r.job_id = t->job_id;
    r.task_id = t->task_id;
    r.tile = t->tile;
    r.s0 = t->s0;
    r.s1 = t->s1;
    r.rejected = rejected;
    r.npixels = (t->tile.x1 - t->tile.x0) * (t->tile.y1 - t->tile.y0);
    for (uint32_t i = 0; i < r.npixels; i++)
        pixels[i] = px;
    r.pixels = pixels;
    proto_writer w;
    proto_writer_init(&w, 1 << 20);
    proto_msg_encode_result(&w, &r, NULL);
    send_frame(p->fd, PROTO_MSG_RESULT, &w);
    proto_writer_fini(&w);
}

static void peer_close(peer *p)
{
    if (p->fd >= 0)
        close(p->fd);
    p->fd = -1;
}

/* ---- processes ---- */

static pid_t start_worker(int port, const char *name)
{
    char server[64];
    snprintf(server, sizeof server, "127.0.0.1:%d", port);
    const char *argv[] = {
        PT_BIN_DIR "/ptworker", "--server",    server,        "--threads", "1",  "--token-file",
        path("token"),          "--cache-dir", path("cache"), "--name",    name, NULL};
    return spawn(argv, "workers.log");
}

/* Stops a worker this test started (pid <= 0: none was). */
static void stop(pid_t pid)
{
    if (pid > 0) {
        kill(pid, SIGTERM);
        wait_exit(pid, 10);
    }
}

static void write_token(void)
{
    FILE *f = fopen(path("token"), "w");
    fprintf(f, "%s\n", TOKEN);
    fclose(f);
    chmod(path("token"), 0600);
}

/* The clean render of the scene at these settings (the standalone worker). */
static void reference(const char *spp, const char *chunk, const char *out)
{
    const char *argv[] = {PT_BIN_DIR "/ptworker",
                          "--scene",
                          SCENE,
                          COMMON,
                          "--spp",
                          spp,
                          "--chunk",
                          chunk,
                          "-o",
                          path(out),
                          "-q",
                          NULL};
    CHECK(run(argv, "ref.log", 300) == 0);
}

/* Starts ptserve for one job; extra: more options (NULL-terminated). */
static pid_t start_server(const char *spp, const char *chunk, const char *out, const char *log,
                          const char *const *extra)
{
    unlink(path("port"));
    const char *argv[40] = {PT_BIN_DIR "/ptserve",
                            "--listen",
                            "127.0.0.1:0",
                            "--port-file",
                            path("port"),
                            "--token-file",
                            path("token"),
                            COMMON,
                            "--spp",
                            spp,
                            "--chunk",
                            chunk,
                            "-q",
                            "-o",
                            path(out)};
    int n = 0;
    while (argv[n])
        n++;
    for (int i = 0; extra && extra[i]; i++)
        argv[n++] = extra[i];
    argv[n++] = SCENE;
    argv[n] = NULL;
    return spawn(argv, log);
}

static int wait_log(const char *log, const char *needle, double timeout)
{
    double end = pt_now_s() + timeout;
    while (pt_now_s() < end) {
        if (log_has(log, needle))
            return 1;
        sleep_ms(50);
    }
    return 0;
}

/* Runs a shell command; its stdout (at most size - 1 bytes) in out. */
static int capture(const char *cmd, char *out, size_t size)
{
    FILE *p = popen(cmd, "r");
    size_t n = p ? fread(out, 1, size - 1, p) : 0;
    out[n] = '\0';
    return p ? pclose(p) : -1;
}

/* The dashboard's /api/workers (ptserve --http, its port in hport_file),
 * with the farm's token, in out. */
static void api_workers(const char *hport_file, char *out, size_t size)
{
    int port = 0;
    FILE *f = fopen(hport_file, "r");
    if (f) {
        if (fscanf(f, "%d", &port) != 1)
            port = 0;
        fclose(f);
    }
    char cmd[1024];
    snprintf(cmd, sizeof cmd,
             "curl -s --max-time 10 -H \"Authorization: Bearer $(cat '%s')\" "
             "http://127.0.0.1:%d/api/workers",
             path("token"), port);
    out[0] = '\0';
    if (port > 0)
        capture(cmd, out, size);
}

/* ---- a. the hoarder ---- */

static void hoarder(void)
{
    static peer h;
    /* A short lease timeout: the hoarder's rounds are short next to the time
     * the honest workers need for the tasks it holds (they take over some as
     * backups), so it misses 3 rounds long before the job could end without
     * it. Honest workers deliver results all the time: no misses in a row. */
    static char hport[512];
    snprintf(hport, sizeof hport, "%s", path("hport"));
    unlink(hport);
    const char *extra[] = {"--lease-timeout",
                           "0.3",
                           "--verify-fraction",
                           "0",
                           "--http",
                           "127.0.0.1:0",
                           "--http-port-file",
                           hport,
                           NULL};
    const int n = CHECK_JOB_SPP(8192);
    char spp[16];
    snprintf(spp, sizeof spp, "%d", n);
    pid_t srv = start_server(spp, "64", "hoard.exr", "hoard.log", extra);
    int port = read_port();
    CHECK(port > 0);
    CHECK(peer_open(&h, port, "hoarder"));
    double t_stall = pt_now_s(), t_requeue = 0, end = t_stall + 300;
    peer_ask(&h, PROTO_MAX_SLOTS);
    pid_t w1 = -1, w2 = -1;
    /* It heartbeats every task it holds and keeps asking for more. */
    while (!h.closed && pt_now_s() < end) {
        peer_read(&h, 100);
        peer_heartbeat(&h);
        peer_ask(&h, PROTO_MAX_SLOTS);
        if (w1 < 0) {
            CHECKF(h.ntasks > 100, "the hoarder got %u tasks", h.ntasks);
            w1 = start_worker(port, "good1");
            w2 = start_worker(port, "good2");
        }
        if (!t_requeue && log_has("hoard.log", "leases expired"))
            t_requeue = pt_now_s();
    }
    CHECKF(h.closed, "the hoarder was never closed");
    CHECKF(strstr(h.error, "blocked") != NULL, "the hoarder was told: '%s'", h.error);
    if (t_requeue > 0)
        printf("hoarder: first requeue %.2f s after the stall (lease timeout 0.3 s; before any "
               "result the allowance is 10 x 0.3 s)\n",
               t_requeue - t_stall);
    peer_close(&h);
    CHECK(wait_log("hoard.log", "worker hoarder from 127.0.0.1", 10));
    CHECK(log_has("hoard.log", "blocked: missed lease deadlines 3 times in a row"));
    /* Refused when it comes back under its name. */
    CHECK(!peer_open(&h, port, "hoarder"));
    CHECKF(strstr(h.error, "blocked") != NULL, "the returning hoarder was told: '%s'", h.error);
    peer_close(&h);
    /* The dashboard lists it as blocked with the reason, beside the honest
     * workers and what they rendered. */
    static char workers[16384];
    const char *blocked_row = "\"name\": \"hoarder\", \"address\": \"\", \"state\": \"blocked\"";
    /* The dashboard's snapshot follows the loop within about a second. */
    for (double t_end = pt_now_s() + 10; pt_now_s() < t_end; sleep_ms(100)) {
        api_workers(hport, workers, sizeof workers);
        if (strstr(workers, blocked_row))
            break;
    }
    CHECKF(strstr(workers, "\"name\": \"hoarder\", \"address\": \"\", \"state\": \"blocked\", "
                           "\"reason\": \"missed lease deadlines 3 times in a row") != NULL,
           "/api/workers: %s", workers);
    CHECKF(strstr(workers, "\"name\": \"good1\"") && strstr(workers, "\"tasks_done\": "),
           "/api/workers: %s", workers);
    int st = wait_exit(srv, 300);
    CHECKF(st == 0, "ptserve exit status %d", st);
    stop(w1);
    stop(w2);
    reference(spp, "64", "hoard_ref.exr");
    CHECKF(same_pixels("hoard_ref.exr", "hoard.exr"), "the hoarder changed the image");
    CHECK(all_samples("hoard.exr", (float)n));
}

/* ---- b. backup copies ---- */

static void backup(void)
{
    static peer s;
    const char *extra[] = {"--lease-timeout", "600", "--verify-fraction", "0", NULL};
    pid_t srv = start_server("64", "8", "backup.exr", "backup.log", extra);
    int port = read_port();
    CHECK(port > 0);
    CHECK(peer_open(&s, port, "sitter"));
    peer_ask(&s, 1);
    double end = pt_now_s() + 10;
    while (!s.ntasks && pt_now_s() < end)
        peer_read(&s, 100);
    CHECK(s.ntasks == 1);
    double t0 = pt_now_s();
    pid_t w = start_worker(port, "good");
    /* The sitter holds its task (heartbeats not even needed: ten minutes). */
    int st = wait_exit(srv, 300);
    double took = pt_now_s() - t0;
    CHECKF(st == 0, "ptserve exit status %d", st);
    printf("backup: the job ended %.2f s after the sitter took its task (leases: 600 s)\n", took);
    CHECK(took < 300);
    CHECK(log_has("backup.log", "1 backup copies"));
    peer_close(&s);
    stop(w);
    reference("64", "8", "backup_ref.exr");
    CHECKF(same_pixels("backup_ref.exr", "backup.exr"), "the backup changed the image");
}

/* ---- c. garbage results ---- */

static void garbage(void)
{
    static peer g;
    const char *extra[] = {"--verify-fraction", "0", NULL};
    pid_t srv = start_server("64", "8", "garbage.exr", "garbage.log", extra);
    int port = read_port();
    CHECK(port > 0);
    struct {
        const char *what;
        pt_pixel_acc px; /* n: -1 for the task's samples, -2 for one fewer */
        int n;
    } cases[] = {
        {"sums of 1e38", {{1e38, 1e38, 1e38}, 1e30, 0, 0}, -1},
        {"sums of -1e30", {{-1e30, 1, 1}, 1, 0, 0}, -1},
        {"counts of 0", {{0, 0, 0}, 0, 0, 0}, 0},
        {"counts one short", {{1, 1, 1}, 1, 0, 0}, -2},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        CHECK(peer_open(&g, port, "garbage"));
        peer_ask(&g, 1);
        double end = pt_now_s() + 10;
        while (!g.ntasks && pt_now_s() < end)
            peer_read(&g, 100);
        CHECK(g.ntasks == 1);
        pt_pixel_acc px = cases[i].px;
        uint32_t spp = g.tasks[0].s1 - g.tasks[0].s0;
        px.n = cases[i].n == -1 ? spp : cases[i].n == -2 ? spp - 1 : (uint32_t)cases[i].n;
        peer_result(&g, &g.tasks[0], px, 0);
        peer_read(&g, 5000);
        CHECKF(g.closed && (strstr(g.error, "not a plausible render") != NULL ||
                            strstr(g.error, "rejected") != NULL),
               "%s: told '%s'", cases[i].what, g.error);
        peer_close(&g);
    }
    pid_t w = start_worker(port, "good");
    int st = wait_exit(srv, 300);
    CHECKF(st == 0, "ptserve exit status %d", st);
    CHECK(log_has("garbage.log", "4 results refused"));
    stop(w);
    reference("64", "8", "garbage_ref.exr");
    CHECKF(same_pixels("garbage_ref.exr", "garbage.exr"), "garbage changed the image");
    CHECK(all_samples("garbage.exr", 64.0f));
}

/* ---- d. the liar ---- */

/* The liar's loop: answers every task at once with 0.5 everywhere until it
 * is closed. The honest workers start only once it has lied 8 times, or
 * has lied and then been given nothing for 40 rounds (a lease gate, or
 * tasks sized by its speed, left it fewer than 8), so the verification
 * copies of its first lies are what they render first (those go before
 * new tasks), and a mismatch holds the job until it is decided: the liar
 * is caught however fast the machine renders. */
static uint32_t lie(peer *l, int port, pid_t *w1, pid_t *w2)
{
    double end = pt_now_s() + 300;
    uint32_t lies = 0, idle = 0;
    *w1 = *w2 = -1;
    while (!l->closed && pt_now_s() < end) {
        peer_ask(l, 4);
        l->ntasks = l->next = 0;
        peer_read(l, 50);
        idle = l->ntasks ? 0 : idle + 1;
        for (uint32_t i = 0; i < l->ntasks; i++) {
            pt_pixel_acc px =
                pt_pixel_acc_of(0.5, 0.5, 0.5, 0.25, l->tasks[i].s1 - l->tasks[i].s0, 0);
            peer_result(l, &l->tasks[i], px, 0);
            lies++;
        }
        if (*w1 < 0 && (lies >= 8 || (lies > 0 && idle >= 40))) {
            *w1 = start_worker(port, "good1");
            *w2 = start_worker(port, "good2");
        }
    }
    return lies;
}

static void liar(void)
{
    static peer l;
    const char *extra[] = {"--verify-fraction", "1", NULL};
    pid_t srv = start_server("256", "8", "liar.exr", "liar.log", extra);
    int port = read_port();
    CHECK(port > 0);
    CHECK(peer_open(&l, port, "liar"));
    pid_t w1, w2;
    uint32_t lies = lie(&l, port, &w1, &w2);
    CHECKF(l.closed, "the liar was never closed");
    CHECKF(strstr(l.error, "blocked") != NULL, "the liar was told '%s'", l.error);
    printf("liar: closed after %u false results\n", lies);
    peer_close(&l);
    CHECK(wait_log("liar.log", "worker liar from 127.0.0.1", 10));
    CHECK(log_has("liar.log", "differs from two others"));
    CHECK(!peer_open(&l, port, "liar"));
    CHECKF(strstr(l.error, "blocked") != NULL, "the returning liar was told '%s'", l.error);
    peer_close(&l);
    int st = wait_exit(srv, 300);
    CHECKF(st == 0, "ptserve exit status %d", st);
    stop(w1);
    stop(w2);
}

/* ---- e. verification leaves the image alone ---- */

static void verify_clean(void)
{
    const char *extra[] = {"--verify-fraction", "1", NULL};
    pid_t srv = start_server("64", "8", "verify.exr", "verify.log", extra);
    int port = read_port();
    CHECK(port > 0);
    pid_t w1 = start_worker(port, "good1"), w2 = start_worker(port, "good2");
    int st = wait_exit(srv, 300);
    CHECKF(st == 0, "ptserve exit status %d", st);
    CHECK(log_has("verify.log", "0 mismatched, 0 liars"));
    stop(w1);
    stop(w2);
    reference("64", "8", "verify_ref.exr");
    CHECKF(same_pixels("verify_ref.exr", "verify.exr"), "verification changed the image");
}

/* ptctl ARGS against the server on port, its stdout in out. */
static int ctl(int port, const char *args, char *out, size_t size)
{
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "%s/ptctl --server 127.0.0.1:%d --token-file %s %s", PT_BIN_DIR, port,
             path("token"), args);
    return capture(cmd, out, size);
}

/* A queue-mode ptserve with the farm's token on a fresh state folder,
 * extra options after those (NULL-terminated); its port in *port. */
static pid_t start_queue(const char *state, const char *log, const char *const *extra, int *port)
{
    const char *argv[24] = {PT_BIN_DIR "/ptserve", "--state-dir", path(state),  "--listen",
                            "127.0.0.1:0",         "--port-file", path("port"), "--token-file",
                            path("token")};
    int n = 9;
    while (*extra && n < 23)
        argv[n++] = *extra++;
    argv[n] = NULL;
    unlink(path("port"));
    pid_t srv = spawn(argv, log);
    *port = read_port();
    CHECK(*port > 0);
    return srv;
}

/* ---- f. the liar's note in queue mode ---- */

static void liar_queue(void)
{
    static peer l;
    const char *extra[] = {"--verify-fraction", "1", "-q", NULL};
    int port;
    /* No task from 128 samples on (the job's second half) is leased until
     * the liar is closed (PTSERVE_TEST_LEASE_GATE): the liar cannot answer
     * the whole job before the honest workers join, however long they take
     * to start (they did, under ThreadSanitizer, and the job ended
     * unverified); the checks of its lies are leased through the gate. */
    char gate[600];
    snprintf(gate, sizeof gate, "128:%s", path("liar_go"));
    setenv("PTSERVE_TEST_LEASE_GATE", gate, 1);
    pid_t srv = start_queue("state", "queue.log", extra, &port);
    unsetenv("PTSERVE_TEST_LEASE_GATE");
    CHECK(peer_open(&l, port, "liar"));
    char args[1024], out[8192];
    snprintf(args, sizeof args, "submit %s --res 48x32 --spp 256", SCENE);
    CHECK(ctl(port, args, out, sizeof out) == 0);
    long job = strtol(out, NULL, 10);
    CHECK(job > 0);
    pid_t w1, w2;
    lie(&l, port, &w1, &w2);
    double end = pt_now_s() + 300;
    CHECKF(strstr(l.error, "blocked") != NULL, "the liar was told '%s'", l.error);
    peer_close(&l);
    FILE *go = fopen(path("liar_go"), "w");
    CHECK(go && fclose(go) == 0);
    snprintf(args, sizeof args, "status %ld", job);
    int done = 0;
    while (!done && pt_now_s() < end) {
        ctl(port, args, out, sizeof out);
        done = strstr(out, "done") != NULL;
        if (!done)
            sleep_ms(100);
    }
    CHECKF(done && strstr(out, "merged unverified") != NULL, "ptctl status says:\n%s", out);
    if (srv > 0)
        kill(srv, SIGTERM);
    CHECK(wait_exit(srv, 30) == 0);
    stop(w1);
    stop(w2);
}

/* ---- g. the empty worker ---- */

/* Answers every task it is given with no sample, all of them "rejected",
 * until it is closed or max results are sent; returns how many it sent. */
static uint32_t send_nothing(peer *e, uint32_t max, double seconds)
{
    double end = pt_now_s() + seconds;
    uint32_t sent = 0;
    while (!e->closed && sent < max && pt_now_s() < end) {
        peer_ask(e, 4);
        e->ntasks = e->next = 0;
        peer_read(e, 50);
        for (uint32_t i = 0; i < e->ntasks && sent < max; i++) {
            const proto_task *t = &e->tasks[i];
            uint64_t px = (uint64_t)(t->tile.x1 - t->tile.x0) * (t->tile.y1 - t->tile.y0);
            peer_result(e, t, pt_pixel_acc_of(0, 0, 0, 0, 0, 0), px * (t->s1 - t->s0));
            sent++;
        }
    }
    return sent;
}

static void empty_worker(void)
{
    static peer e;
    const char *extra[] = {"--verify-fraction", "1", "--chunk", "16", NULL};
    int port;
    pid_t srv = start_queue("state_empty", "empty.log", extra, &port);
    char out[8192], args[1024];
    snprintf(args, sizeof args, "submit %s --res 48x32 --spp 32 --name alone", SCENE);
    CHECK(ctl(port, args, out, sizeof out) == 0);
    long job = strtol(out, NULL, 10);
    CHECK(job > 0);

    /* Alone: 2 tiles (of 32 pixels) x 2 chunks, every one empty. The job
     * fails. */
    CHECK(peer_open(&e, port, "empty"));
    uint32_t sent = send_nothing(&e, 4, 60);
    CHECKF(sent == 4 && !e.closed, "sent %u, closed %d (%s)", sent, e.closed, e.error);
    peer_close(&e);
    snprintf(args, sizeof args, "status %ld --json", job);
    double end = pt_now_s() + 60;
    while (pt_now_s() < end && !(ctl(port, args, out, sizeof out) == 0 && strstr(out, "failed")))
        sleep_ms(100);
    CHECKF(strstr(out, "\"state\": \"failed\"") && strstr(out, "every sample was rejected") &&
               strstr(out, "\"samples_rejected\": 49152"),
           "status --json says:\n%s", out);
    snprintf(args, sizeof args, "status %ld", job);
    CHECK(ctl(port, args, out, sizeof out) == 0);
    CHECKF(strstr(out, "rejected   49152 samples"), "status says:\n%s", out);
    /* Picked for verification, never compared: not "verified". */
    CHECK(wait_log("empty.log", "job 1: verified 0 of 4 tasks", 10));

    /* Beside an honest worker whose samples the next job has merged: three
     * empty results in a row block it, and the job counts their samples. */
    snprintf(args, sizeof args, "submit %s --res 48x32 --spp 65536 --name shared", SCENE);
    CHECK(ctl(port, args, out, sizeof out) == 0);
    long job2 = strtol(out, NULL, 10);
    pid_t w = start_worker(port, "honest");
    snprintf(args, sizeof args, "status %ld --json", job2);
    end = pt_now_s() + 60;
    while (pt_now_s() < end && ctl(port, args, out, sizeof out) == 0 &&
           strstr(out, "\"samples_done\": 0,"))
        sleep_ms(50);
    CHECKF(!strstr(out, "\"samples_done\": 0,"), "the honest worker merged nothing:\n%s", out);
    CHECK(peer_open(&e, port, "empty2"));
    sent = send_nothing(&e, 1000, 60);
    CHECKF(e.closed && strstr(e.error, "blocked") && strstr(e.error, "held no sample"),
           "after %u empty results the worker was told '%s'", sent, e.error);
    CHECKF(sent >= 3, "blocked after %u empty results", sent);
    /* Blocked at the next enforcement: after the third, or a few more that
     * arrived with it. */
    CHECK(wait_log("empty.log", "blocked: returned results that held no sample (", 10));
    peer_close(&e);
    snprintf(args, sizeof args, "cancel %ld", job2);
    CHECK(ctl(port, args, out, sizeof out) == 0);
    stop(w);
    kill(srv, SIGTERM);
    CHECK(wait_exit(srv, 30) == 0);
}

/* ---- h. frames in flight ---- */

static void frames_in_flight(void)
{
    static peer g;
    const char *extra[] = {"--max-pixels", "2400", "-q", NULL};
    int port;
    pid_t srv = start_queue("state_frames", "frames.log", extra, &port);
    char out[8192], args[1024];
    snprintf(args, sizeof args, "submit %s --res 40x30 --spp 16 --frames 0-9 --name flight", SCENE);
    CHECK(ctl(port, args, out, sizeof out) == 0);
    long job = strtol(out, NULL, 10);
    CHECK(job > 0);
    CHECK(peer_open_threads(&g, port, "greedy", 64));
    uint64_t jobs[64];
    uint32_t njobs = 0;
    for (int round = 0; round < 20; round++) {
        peer_ask(&g, 64);
        peer_read(&g, 100);
    }
    for (uint32_t i = 0; i < g.ntasks; i++) {
        uint32_t k = 0;
        while (k < njobs && jobs[k] != g.tasks[i].job_id)
            k++;
        if (k == njobs && njobs < 64)
            jobs[njobs++] = g.tasks[i].job_id;
    }
    CHECKF(g.ntasks > 2 && njobs == 2, "%u tasks of %u frames (2400 pixels: two frames of 1200)",
           g.ntasks, njobs);
    peer_close(&g);
    snprintf(args, sizeof args, "cancel %ld", job);
    CHECK(ctl(port, args, out, sizeof out) == 0);
    kill(srv, SIGTERM);
    CHECK(wait_exit(srv, 30) == 0);
}

/* Counts "leases expired" lines in a log. */
static int expiries(const char *log)
{
    FILE *f = fopen(path(log), "r");
    int n = 0;
    char line[4096];
    while (f && fgets(line, sizeof line, f))
        n += strstr(line, "leases expired") != NULL;
    if (f)
        fclose(f);
    return n;
}

static void measure(void)
{
    static peer p;
    const char *extra[] = {NULL};
    pid_t srv = start_server("65536", "16", "measure.exr", "measure.log", extra);
    int port = read_port();
    CHECK(port > 0);
    pid_t w = start_worker(port, "good");
    sleep_ms(3000); /* its first results are in: the deadlines know task times */
    for (int i = 0; i < 3; i++) {
        int before = expiries("measure.log");
        char name[32];
        snprintf(name, sizeof name, "stall%d", i);
        CHECK(peer_open(&p, port, name));
        peer_ask(&p, 1);
        while (!p.ntasks && !p.closed)
            peer_read(&p, 50);
        double t0 = pt_now_s(), last_hb = 0;
        while (expiries("measure.log") == before && pt_now_s() < t0 + 600) {
            if (pt_now_s() - last_hb > 1.0) {
                peer_heartbeat(&p);
                last_hb = pt_now_s();
            }
            peer_read(&p, 20);
        }
        printf("measure: stalled lease requeued after %.2f s\n", pt_now_s() - t0);
        peer_close(&p);
    }
    if (srv > 0)
        kill(srv, SIGTERM);
    wait_exit(srv, 30);
    stop(w);
}

int main(void)
{
    snprintf(tmp, sizeof tmp, "/tmp/pt_lease_XXXXXX");
    if (!mkdtemp(tmp))
        return 1;
    write_token();
    if (getenv("PT_LEASE_MEASURE")) {
        measure();
        return farm_test_end();
    }
    hoarder();
    backup();
    garbage();
    liar();
    verify_clean();
    liar_queue();
    empty_worker();
    frames_in_flight();
    return farm_test_end();
}
