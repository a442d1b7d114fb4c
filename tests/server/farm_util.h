/*
 * farm_util.h - what the farm tests share: spawning and waiting for real
 * processes, files in the test's temp folder, EXR comparisons, and a raw
 * protocol peer (connect, frames, handshake) for hostile and client tests.
 * Header-only (static functions); each test defines tmp's contents in main.
 */
#ifndef PT_TESTS_SERVER_FARM_UTIL_H
#define PT_TESTS_SERVER_FARM_UTIL_H

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

#include "common/base/clock.h"
#include "common/base/fsutil.h"
#include "common/base/net.h"
#include "common/image/exr.h"
#include "protocol/auth.h"
#include "protocol/frame.h"
#include "protocol/msg.h"

extern char **environ;

static char tmp[256];

static inline void sleep_ms(long ms)
{
    struct timespec ts = {ms / 1000, (ms % 1000) * 1000000L};
    nanosleep(&ts, NULL);
}

static inline pid_t spawn(const char *const *argv, const char *log_name)
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
static inline int wait_exit(pid_t pid, double timeout)
{
    double end = pt_now_s() + timeout;
    int st;
    while (pt_now_s() < end) {
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

static inline int run(const char *const *argv, const char *log, double timeout)
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

static inline int log_has(const char *log, const char *needle)
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

static inline int same_pixels(const char *a_name, const char *b_name)
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

static inline int all_samples(const char *name, float spp)
{
    pt_image *a = load_exr(name);
    int ok = a != NULL;
    for (uint32_t i = 0; a && i < a->width * a->height; i++)
        ok &= a->samples[i] == spp;
    pt_image_free(a);
    return ok;
}

static inline int read_port(void)
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

/* Number of logs in tmp that hold a sanitizer report (AddressSanitizer,
 * LeakSanitizer, UndefinedBehaviorSanitizer's "runtime error:"), named on
 * stderr: the processes a test spawns report there, not to the test. */
static inline int sanitizer_reports(void)
{
    char cmd[512];
    snprintf(cmd, sizeof cmd, "grep -l -E 'Sanitizer|runtime error:' %s/*.log 2>/dev/null", tmp);
    FILE *p = popen(cmd, "r");
    int n = 0;
    char line[1024];
    while (p && fgets(line, sizeof line, p)) {
        fprintf(stderr, "sanitizer report in %s", line);
        n++;
    }
    if (p)
        pclose(p);
    return n;
}

/* The end of a farm test's main: no sanitizer report in any log, then tmp
 * removed when every check passed (kept, and named, otherwise or with
 * PT_KEEP_TMP set); returns the exit status. */
static inline int farm_test_end(void)
{
    CHECK(sanitizer_reports() == 0);
    if (check_failed_ == 0 && !getenv("PT_KEEP_TMP")) {
        if (pt_remove_tree(tmp) != 0)
            return 1;
    } else {
        fprintf(stderr, "logs kept in %s\n", tmp);
    }
    return check_report();
}

/* The resident memory of process pid in KiB (VmRSS), -1 when unknown. */
static inline long rss_kib(pid_t pid)
{
    char name[64], line[256];
    snprintf(name, sizeof name, "/proc/%d/status", (int)pid);
    FILE *f = fopen(name, "r");
    long kib = -1;
    while (f && fgets(line, sizeof line, f))
        if (sscanf(line, "VmRSS: %ld kB", &kib) == 1)
            break;
    if (f)
        fclose(f);
    return kib;
}

/* ---- a raw protocol peer ---- */

static inline int connect_to(int port)
{
    int fd = -1;
    pt_error err = {0};
    if (pt_net_connect("127.0.0.1", (uint16_t)port, 2000, &fd, &err) != PT_OK)
        fprintf(stderr, "%s\n", err.msg);
    return fd;
}

/* Reads until the server closes (1) or the timeout passes (0). */
static inline int closed_by_server(int fd, int timeout_ms)
{
    char buf[4096];
    double end = pt_now_s() + timeout_ms / 1000.0;
    while (pt_now_s() < end) {
        struct pollfd p = {fd, POLLIN, 0};
        if (poll(&p, 1, 50) == 1) {
            ssize_t r = recv(fd, buf, sizeof buf, 0);
            if (r == 0 || (r < 0 && errno != EINTR && errno != EAGAIN))
                return 1;
        }
    }
    return 0;
}

static inline void send_frame(int fd, uint16_t type, const proto_writer *payload)
{
    proto_writer w;
    proto_writer_init(&w, 1 << 20);
    proto_frame_encode(&w, type, payload ? payload->buf : NULL, payload ? payload->len : 0, NULL);
    pt_net_write_all(fd, w.buf, w.len, NULL);
    proto_writer_fini(&w);
}

static inline void send_hello(int fd, uint16_t version, const char *build, uint8_t role)
{
    proto_hello h = {0};
    h.version = version;
    h.role = role;
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
static inline int read_frame(int fd, uint8_t *buf, size_t cap, proto_frame *f)
{
    size_t len = 0;
    double end = pt_now_s() + 5;
    while (pt_now_s() < end) {
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
static inline int authenticate(int port, const char *token, uint8_t role)
{
    int fd = connect_to(port);
    send_hello(fd, PROTO_VERSION, proto_build_id(), role);
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
    proto_auth_nonce(a.nonce, NULL);
    proto_writer p;
    proto_writer_init(&p, 4096);
    proto_msg_encode_auth(&p, &a, NULL);
    send_frame(fd, PROTO_MSG_AUTH, &p);
    proto_writer_fini(&p);
    return fd;
}

#endif
