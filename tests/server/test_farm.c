/*
 * test_farm.c - ptserve and ptworker as real processes over real sockets.
 *
 *  1. Bit identity: the standalone `ptworker --scene`, `ptserve --local 1`
 *     and `ptserve --local 3` give the same R, G, B and samples bits.
 *  2. Chaos: workers are killed with SIGKILL at random moments (at least ten
 *     times, each replaced); the job completes bit-identical with exact sample
 *     counts, while a reader polling the output EXR always finds a valid file
 *     whose sample counts never decrease.
 *  3. Hostile peers during a render: garbage, a huge declared length, a bad
 *     CRC, a wrong token, another protocol version, another build id, a result
 *     for a task never leased, a slow-loris peer. Each is refused with a
 *     logged reason; the render completes bit-identical.
 *  4. SIGINT stops ptserve (and its local workers) with status 130 and
 *     leaves a valid progressive EXR.
 */
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "common/exr.h"
#include "common/net.h"
#include "protocol/auth.h"
#include "protocol/frame.h"
#include "protocol/msg.h"
#include "tests/check.h"

extern char **environ;

static char tmp[256];
static const char *SCENE = PT_SOURCE_DIR "/scenes/cornell_box.gltf";
#define COMMON "--res", "48x32", "--tile", "16", "--chunk", "8", "--seed", "3"

static void sleep_ms(long ms)
{
    struct timespec ts = {ms / 1000, (ms % 1000) * 1000000L};
    nanosleep(&ts, NULL);
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static pid_t spawn(const char *const *argv, const char *log_name)
{
    char log[512];
    snprintf(log, sizeof log, "%s/%s", tmp, log_name);
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 1, "/dev/null", O_WRONLY, 0);
    posix_spawn_file_actions_addopen(&fa, 2, log, O_WRONLY | O_CREAT | O_APPEND, 0644);
    pid_t pid = -1;
    if (posix_spawn(&pid, argv[0], &fa, NULL, (char *const *)argv, environ) != 0)
        pid = -1;
    posix_spawn_file_actions_destroy(&fa);
    return pid;
}

/* Waits up to timeout seconds; returns the exit status or -1 (then kills it). */
static int wait_exit(pid_t pid, double timeout)
{
    double end = now_s() + timeout;
    int st;
    while (now_s() < end) {
        pid_t r = waitpid(pid, &st, WNOHANG);
        if (r == pid)
            return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
        sleep_ms(20);
    }
    kill(pid, SIGKILL);
    waitpid(pid, &st, 0);
    fprintf(stderr, "process %d timed out\n", (int)pid);
    return -1;
}

static int run(const char *const *argv, const char *log, double timeout)
{
    pid_t pid = spawn(argv, log);
    return pid > 0 ? wait_exit(pid, timeout) : -1;
}

static char *path(const char *name)
{
    static char bufs[8][512];
    static int k;
    char *b = bufs[k++ % 8];
    snprintf(b, 512, "%s/%s", tmp, name);
    return b;
}

static int log_has(const char *log, const char *needle)
{
    FILE *f = fopen(path(log), "r");
    if (!f)
        return 0;
    static char buf[1 << 20];
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    buf[n] = '\0';
    return strstr(buf, needle) != NULL;
}

static pt_image *load_exr(const char *name)
{
    pt_image *img = NULL;
    pt_error err = {0};
    if (pt_exr_read(path(name), &img, NULL, &err) != PT_OK)
        fprintf(stderr, "%s\n", err.msg);
    return img;
}

static int same_pixels(const char *a_name, const char *b_name)
{
    pt_image *a = load_exr(a_name), *b = load_exr(b_name);
    int same = 0;
    if (a && b && a->width == b->width && a->height == b->height) {
        size_t n = (size_t)a->width * a->height * sizeof(float);
        same = !memcmp(a->r, b->r, n) && !memcmp(a->g, b->g, n) && !memcmp(a->b, b->b, n) &&
               !memcmp(a->samples, b->samples, n);
    }
    pt_image_free(a);
    pt_image_free(b);
    return same;
}

static int all_samples(const char *name, float spp)
{
    pt_image *a = load_exr(name);
    int ok = a != NULL;
    for (uint32_t i = 0; a && i < a->width * a->height; i++)
        ok &= a->samples[i] == spp;
    pt_image_free(a);
    return ok;
}

static int read_port(void)
{
    for (int i = 0; i < 500; i++) {
        FILE *f = fopen(path("port"), "r");
        int port = 0;
        if (f) {
            if (fscanf(f, "%d", &port) != 1)
                port = 0;
            fclose(f);
        }
        if (port > 0)
            return port;
        sleep_ms(20);
    }
    return -1;
}

/* ---- 1. bit identity ---------------------------------------------------------------- */

static void bit_identity(void)
{
    const char *standalone[] = {PT_BIN_DIR "/ptworker", "--scene", SCENE, COMMON, "--spp", "32",
                                "-o", path("ref.exr"), "-q", NULL};
    CHECK(run(standalone, "ref.log", 120) == 0);
    const char *local1[] = {PT_BIN_DIR "/ptserve", "--local", "1", COMMON, "--spp", "32", "-o",
                            path("l1.exr"), SCENE, NULL};
    CHECK(run(local1, "l1.log", 120) == 0);
    const char *local3[] = {PT_BIN_DIR "/ptserve", "--local", "3", "--worker-threads", "1", COMMON,
                            "--spp", "32", "-o", path("l3.exr"), SCENE, NULL};
    CHECK(run(local3, "l3.log", 120) == 0);
    CHECKF(same_pixels("ref.exr", "l1.exr"), "--local 1 differs from the standalone render");
    CHECKF(same_pixels("ref.exr", "l3.exr"), "--local 3 differs from the standalone render");
    CHECK(all_samples("l3.exr", 32.0f));

    /* Adaptive sampling decides from the same sums in both: still identical. */
    const char *ad_solo[] = {PT_BIN_DIR "/ptworker", "--scene", SCENE, COMMON, "--spp", "256",
                             "--target-error", "0.05", "-o", path("ad_ref.exr"), "-q", NULL};
    CHECK(run(ad_solo, "ad_ref.log", 120) == 0);
    const char *ad_farm[] = {PT_BIN_DIR "/ptserve", "--local", "3", "--worker-threads", "1", COMMON,
                             "--spp", "256", "--target-error", "0.05", "-o", path("ad3.exr"),
                             SCENE, NULL};
    CHECK(run(ad_farm, "ad3.log", 120) == 0);
    CHECKF(same_pixels("ad_ref.exr", "ad3.exr"), "adaptive --local 3 differs from standalone");
    pt_image *ad = load_exr("ad3.exr");
    int fewer = 0, full = 0;
    for (uint32_t i = 0; ad && i < ad->width * ad->height; i++) {
        fewer += ad->samples[i] < 256.0f;
        full += ad->samples[i] == 256.0f;
    }
    printf("adaptive: %d pixels stopped early, %d at the full count\n", fewer, full);
    CHECK(fewer > 0);
    pt_image_free(ad);
}

/* ---- 2. chaos ----------------------------------------------------------------------- */

static pid_t start_worker(int port, const char *token, const char *name)
{
    char server[64];
    snprintf(server, sizeof server, "127.0.0.1:%d", port);
    const char *argv[] = {PT_BIN_DIR "/ptworker", "--server", server, "--threads", "1",
                          "--token-file", token, "--cache-dir", path("cache"), "--name", name, NULL};
    return spawn(argv, "workers.log");
}

static void write_token(void)
{
    FILE *f = fopen(path("token"), "w");
    fputs("correct horse battery staple\n", f);
    fclose(f);
    chmod(path("token"), 0600);
}

static void chaos(void)
{
    const char *ref[] = {PT_BIN_DIR "/ptworker", "--scene", SCENE, COMMON, "--spp", "2048", "-o",
                         path("chaos_ref.exr"), "-q", NULL};
    CHECK(run(ref, "chaos_ref.log", 300) == 0);
    unlink(path("port"));
    const char *serve[] = {PT_BIN_DIR "/ptserve", "--listen", "127.0.0.1:0", "--port-file",
                           path("port"), "--token-file", path("token"), COMMON, "--spp", "2048",
                           "--save-interval", "0.1", "--lease-timeout", "5", "-o",
                           path("chaos.exr"), SCENE, NULL};
    pid_t srv = spawn(serve, "chaos.log");
    int port = read_port();
    CHECK(port > 0);
    pid_t w[3];
    int started = 0;
    char name[32];
    for (int i = 0; i < 3; i++) {
        snprintf(name, sizeof name, "w%d", started++);
        w[i] = start_worker(port, path("token"), name);
    }
    srand(12345);
    int kills = 0, polls = 0, bad_reads = 0, decreases = 0, status = -1;
    float *last = NULL;
    double end = now_s() + 600;
    while (now_s() < end) {
        int st;
        if (waitpid(srv, &st, WNOHANG) == srv) {
            status = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
            break;
        }
        /* Poll the progressive image: valid, and counts never go down. */
        struct stat sb;
        if (stat(path("chaos.exr"), &sb) == 0) {
            pt_image *img = load_exr("chaos.exr");
            polls++;
            if (!img) {
                bad_reads++;
            } else {
                size_t n = (size_t)img->width * img->height;
                if (last)
                    for (size_t i = 0; i < n; i++)
                        decreases += img->samples[i] < last[i];
                free(last);
                last = malloc(n * sizeof *last);
                memcpy(last, img->samples, n * sizeof *last);
                pt_image_free(img);
            }
        }
        sleep_ms(30 + rand() % 120);
        if (kills < 12) {
            int k = rand() % 3;
            kill(w[k], SIGKILL);
            waitpid(w[k], NULL, 0);
            kills++;
            snprintf(name, sizeof name, "w%d", started++);
            w[k] = start_worker(port, path("token"), name);
        }
    }
    for (int i = 0; i < 3; i++) {
        kill(w[i], SIGTERM);
        wait_exit(w[i], 10);
    }
    free(last);
    printf("chaos: %d kills, %d polls of the progressive EXR\n", kills, polls);
    CHECKF(status == 0, "ptserve exit status %d", status);
    CHECKF(kills >= 10, "only %d kills before the job ended", kills);
    CHECK(polls > 0 && bad_reads == 0 && decreases == 0);
    CHECKF(same_pixels("chaos_ref.exr", "chaos.exr"), "chaos changed the image");
    CHECK(all_samples("chaos.exr", 2048.0f));
}

/* ---- 3. hostile peers --------------------------------------------------------------- */

static int connect_to(int port)
{
    int fd = -1;
    pt_error err = {0};
    if (pt_net_connect("127.0.0.1", (uint16_t)port, 2000, &fd, &err) != PT_OK)
        fprintf(stderr, "%s\n", err.msg);
    return fd;
}

/* Reads until the server closes (1) or the timeout passes (0). */
static int closed_by_server(int fd, int timeout_ms)
{
    char buf[4096];
    double end = now_s() + timeout_ms / 1000.0;
    while (now_s() < end) {
        struct pollfd p = {fd, POLLIN, 0};
        if (poll(&p, 1, 50) == 1) {
            ssize_t r = recv(fd, buf, sizeof buf, 0);
            if (r == 0 || (r < 0 && errno != EINTR && errno != EAGAIN))
                return 1;
        }
    }
    return 0;
}

static void send_frame(int fd, uint16_t type, const proto_writer *payload)
{
    proto_writer w;
    proto_writer_init(&w, 1 << 20);
    proto_frame_encode(&w, type, payload ? payload->buf : NULL, payload ? payload->len : 0, NULL);
    pt_net_write_all(fd, w.buf, w.len, NULL);
    proto_writer_fini(&w);
}

static void send_hello(int fd, uint16_t version, const char *build)
{
    proto_hello h = {0};
    h.version = version;
    h.role = PROTO_ROLE_WORKER;
    snprintf(h.name, sizeof h.name, "hostile");
    h.threads = 1;
    snprintf(h.build_id, sizeof h.build_id, "%s", build);
    proto_writer p;
    proto_writer_init(&p, 4096);
    proto_msg_encode_hello(&p, &h, NULL);
    send_frame(fd, PROTO_MSG_HELLO, &p);
    proto_writer_fini(&p);
}

/* Reads one frame (blocking with a timeout) into buf; returns its type or -1. */
static int read_frame(int fd, uint8_t *buf, size_t cap, proto_frame *f)
{
    size_t len = 0;
    double end = now_s() + 5;
    while (now_s() < end) {
        size_t used;
        if (len && proto_frame_decode(buf, len, PROTO_MAX_PAYLOAD, f, &used, NULL) == PT_OK)
            return f->type;
        struct pollfd p = {fd, POLLIN, 0};
        if (poll(&p, 1, 50) == 1) {
            ssize_t r = recv(fd, buf + len, cap - len, 0);
            if (r <= 0)
                return -1;
            len += (size_t)r;
        }
    }
    return -1;
}

/* Authenticates with the given token; returns the fd or -1. */
static int authenticate(int port, const char *token)
{
    int fd = connect_to(port);
    send_hello(fd, PROTO_VERSION, proto_build_id());
    static uint8_t buf[1 << 16];
    proto_frame f;
    if (read_frame(fd, buf, sizeof buf, &f) != PROTO_MSG_CHALLENGE) {
        close(fd);
        return -1;
    }
    proto_challenge ch;
    proto_msg_decode_challenge(f.payload, f.len, &ch, NULL);
    proto_auth a;
    proto_auth_response((const uint8_t *)token, strlen(token), ch.nonce, a.mac, NULL);
    proto_writer p;
    proto_writer_init(&p, 4096);
    proto_msg_encode_auth(&p, &a, NULL);
    send_frame(fd, PROTO_MSG_AUTH, &p);
    proto_writer_fini(&p);
    return fd;
}

static void hostile(void)
{
    unlink(path("port"));
    const char *serve[] = {PT_BIN_DIR "/ptserve", "--listen", "127.0.0.1:0", "--port-file",
                           path("port"), "--token-file", path("token"), "--handshake-timeout",
                           "1", COMMON, "--spp", "1024", "-o", path("hostile.exr"), SCENE, NULL};
    pid_t srv = spawn(serve, "hostile.log");
    int port = read_port();
    CHECK(port > 0);

    /* Slow loris: a valid HELLO frame dripped a byte at a time, too slowly
     * to finish the handshake in time. */
    {
        proto_hello h = {0};
        h.version = PROTO_VERSION;
        h.role = PROTO_ROLE_WORKER;
        snprintf(h.name, sizeof h.name, "slow");
        snprintf(h.build_id, sizeof h.build_id, "%s", proto_build_id());
        proto_writer p, w;
        proto_writer_init(&p, 4096);
        proto_writer_init(&w, 4096);
        proto_msg_encode_hello(&p, &h, NULL);
        proto_frame_encode(&w, PROTO_MSG_HELLO, p.buf, p.len, NULL);
        int fd = connect_to(port);
        int closed = 0;
        for (size_t i = 0; i + 1 < w.len && !closed; i++)
            closed = pt_net_write_all(fd, w.buf + i, 1, NULL) != PT_OK || closed_by_server(fd, 150);
        CHECK(closed);
        close(fd);
        proto_writer_fini(&p);
        proto_writer_fini(&w);
    }

    /* An honest worker renders while the hostile peers keep coming. */
    pid_t w1 = start_worker(port, path("token"), "good1");

    int fd = connect_to(port);
    CHECK(pt_net_write_all(fd, "GET / HTTP/1.1\r\nHost: x\r\n\r\n", 27, NULL) == PT_OK);
    CHECK(closed_by_server(fd, 3000));
    close(fd);

    uint8_t hdr[12] = {'P', 'T', 'F', '1', 1, 0, PROTO_MSG_HELLO, 0, 0xff, 0xff, 0xff, 0xff};
    fd = connect_to(port);
    pt_net_write_all(fd, hdr, sizeof hdr, NULL);
    CHECK(closed_by_server(fd, 3000));
    close(fd);

    /* A valid HELLO frame with one bit of its CRC flipped. */
    {
        proto_hello h = {0};
        h.version = PROTO_VERSION;
        h.role = PROTO_ROLE_WORKER;
        snprintf(h.build_id, sizeof h.build_id, "%s", proto_build_id());
        proto_writer p, w;
        proto_writer_init(&p, 4096);
        proto_writer_init(&w, 4096);
        proto_msg_encode_hello(&p, &h, NULL);
        proto_frame_encode(&w, PROTO_MSG_HELLO, p.buf, p.len, NULL);
        w.buf[w.len - 1] ^= 0x10;
        fd = connect_to(port);
        pt_net_write_all(fd, w.buf, w.len, NULL);
        CHECK(closed_by_server(fd, 3000));
        close(fd);
        proto_writer_fini(&p);
        proto_writer_fini(&w);
    }

    fd = authenticate(port, "not the token");
    CHECK(fd >= 0 && closed_by_server(fd, 3000));
    close(fd);

    fd = connect_to(port);
    send_hello(fd, 99, proto_build_id());
    CHECK(closed_by_server(fd, 3000));
    close(fd);

    fd = connect_to(port);
    send_hello(fd, PROTO_VERSION, "0000000000000000");
    CHECK(closed_by_server(fd, 3000));
    close(fd);

    /* Authenticated, then a result for a task it was never leased. */
    fd = authenticate(port, "correct horse battery staple");
    CHECK(fd >= 0);
    if (fd >= 0) {
        static pt_pixel_acc px[256];
        memset(px, 0, sizeof px);
        for (int i = 0; i < 256; i++) {
            px[i].sum[0] = 1e6;
            px[i].n = 8;
        }
        proto_result r = {0};
        r.job_id = 1;
        r.task_id = 0;
        r.tile = (pt_rect){0, 0, 16, 16};
        r.s0 = 0;
        r.s1 = 8;
        r.npixels = 256;
        r.pixels = px;
        proto_writer p;
        proto_writer_init(&p, 1 << 20);
        proto_msg_encode_result(&p, &r, NULL);
        send_frame(fd, PROTO_MSG_RESULT, &p);
        proto_writer_fini(&p);
        sleep_ms(300);
        close(fd);
    }

    pid_t w2 = start_worker(port, path("token"), "good2");
    int status = wait_exit(srv, 300);
    kill(w1, SIGTERM);
    kill(w2, SIGTERM);
    wait_exit(w1, 10);
    wait_exit(w2, 10);
    CHECKF(status == 0, "ptserve exit status %d", status);
    const char *ref[] = {PT_BIN_DIR "/ptworker", "--scene", SCENE, COMMON, "--spp", "1024", "-o",
                         path("hostile_ref.exr"), "-q", NULL};
    CHECK(run(ref, "hostile_ref.log", 120) == 0);
    CHECKF(same_pixels("hostile_ref.exr", "hostile.exr"), "hostile peers changed the image");
    const char *reasons[] = {"bad magic", "over", "CRC", "authentication failed",
                             "protocol version 99", "build 0000000000000000", "does not hold",
                             "handshake not finished"};
    for (size_t i = 0; i < sizeof reasons / sizeof *reasons; i++)
        CHECKF(log_has("hostile.log", reasons[i]), "no logged reason containing '%s'",
               reasons[i]);
}

/* ---- 4. Ctrl-C --------------------------------------------------------------------- */

static void interrupt(void)
{
    const char *serve[] = {PT_BIN_DIR "/ptserve", "--local", "2", "--worker-threads", "1", COMMON,
                           "--spp", "100000", "--save-interval", "0.1", "-o", path("int.exr"),
                           SCENE, NULL};
    pid_t srv = spawn(serve, "int.log");
    struct stat sb;
    for (int i = 0; i < 1000 && stat(path("int.exr"), &sb) != 0; i++)
        sleep_ms(20);
    sleep_ms(200);
    kill(srv, SIGINT);
    int status = wait_exit(srv, 30);
    CHECKF(status == 130, "interrupted ptserve exit status %d", status);
    CHECK(log_has("int.log", "interrupted"));
    pt_image *img = load_exr("int.exr");
    CHECK(img != NULL);
    if (img) {
        double n = 0;
        for (uint32_t i = 0; i < img->width * img->height; i++)
            n += img->samples[i];
        CHECK(n > 0 && n < 48.0 * 32.0 * 100000.0);
    }
    pt_image_free(img);
    /* The local workers are gone: no process is left holding the loopback port. */
    CHECK(log_has("int.log", "holds"));
}

int main(void)
{
    snprintf(tmp, sizeof tmp, "/tmp/pt_test_farm_XXXXXX");
    if (!mkdtemp(tmp))
        return 1;
    signal(SIGPIPE, SIG_IGN);
    write_token();
    bit_identity();
    chaos();
    hostile();
    interrupt();
    if (check_failed_ == 0) {
        char cmd[512];
        snprintf(cmd, sizeof cmd, "rm -rf %s", tmp);
        if (system(cmd) != 0)
            return 1;
    } else {
        fprintf(stderr, "logs kept in %s\n", tmp);
    }
    return check_report();
}
