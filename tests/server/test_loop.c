/*
 * test_loop.c - the coordinator's connection loop logs what peers chose
 * safely, with real processes and sockets: a ptworker whose --name holds a
 * newline, a forged log line and an ANSI escape, and a raw peer sending the
 * same name with a HELLO the server refuses. The log must hold the name as
 * \xNN escapes on the server's own lines, no forged line and no escape
 * sequence from the peer; an honest worker still joins afterwards.
 */
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "protocol/msg.h"
#include "tests/check.h"

#include "tests/server/farm_util.h"

#define EVIL "evil\nptserve: job 1 done: forged\x1b[31m"
#define EVIL_SHOWN "evil\\x0aptserve: job 1 done: forged\\x1b[31m"

/* The log's text (NUL-terminated; a NUL inside ends it early), or NULL. */
static char *read_log(const char *name)
{
    static char buf[1 << 16];
    FILE *f = fopen(path(name), "r");
    if (!f)
        return NULL;
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    buf[n] = '\0';
    return buf;
}

static int wait_log(const char *log, const char *needle)
{
    for (int i = 0; i < 500; i++) {
        if (log_has(log, needle))
            return 1;
        sleep_ms(20);
    }
    return 0;
}

static pid_t start_worker(int port, const char *name)
{
    char server[64];
    snprintf(server, sizeof server, "127.0.0.1:%d", port);
    const char *argv[] = {PT_BIN_DIR "/ptworker", "--server",    server,   "--threads", "1",
                          "--cache-dir",          path("cache"), "--name", name,        NULL};
    return spawn(argv, "workers.log");
}

/* A raw peer: a HELLO named EVIL with a build the server refuses. */
static void refused_peer(int port)
{
    int fd = connect_to(port);
    CHECK(fd >= 0);
    if (fd < 0)
        return;
    proto_hello h = {0};
    h.version = PROTO_VERSION;
    h.role = PROTO_ROLE_WORKER;
    h.threads = 1;
    snprintf(h.name, sizeof h.name, "%s", EVIL);
    snprintf(h.build_id, sizeof h.build_id, "0000000000000000");
    proto_writer p;
    proto_writer_init(&p, 4096);
    proto_msg_encode_hello(&p, &h, NULL);
    send_frame(fd, PROTO_MSG_HELLO, &p);
    proto_writer_fini(&p);
    CHECK(closed_by_server(fd, 3000));
    close(fd);
}

static void peer_names_escaped(void)
{
    unlink(path("port"));
    const char *serve[] = {PT_BIN_DIR "/ptserve", "--state-dir", path("state"), "--listen",
                           "127.0.0.1:0",         "--port-file", path("port"),  NULL};
    pid_t srv = spawn(serve, "serve.log");
    int port = read_port();
    CHECK(port > 0);
    if (port <= 0) {
        kill(srv, SIGKILL);
        wait_exit(srv, 10);
        return;
    }
    pid_t evil = start_worker(port, EVIL);
    CHECKF(wait_log("serve.log", "joined"), "the worker named EVIL never joined");
    refused_peer(port);
    pid_t good = start_worker(port, "good");
    CHECKF(wait_log("serve.log", "worker good joined"), "the next worker was not served");

    kill(evil, SIGTERM);
    kill(good, SIGTERM);
    wait_exit(evil, 10);
    wait_exit(good, 10);
    kill(srv, SIGTERM);
    CHECK(wait_exit(srv, 30) == 0);

    const char *log = read_log("serve.log");
    CHECK(log != NULL);
    if (!log)
        return;
    CHECKF(strstr(log, "worker " EVIL_SHOWN " joined") != NULL, "no escaped name in the join line");
    CHECKF(strstr(log, EVIL_SHOWN ": worker renderer build 0000000000000000") != NULL,
           "no escaped name in the refusal");
    CHECKF(strstr(log, "\nptserve: job 1 done") == NULL, "a peer forged a log line");
    CHECKF(strstr(log, "\x1b[31m") == NULL, "a peer's escape sequence reached the log");
    CHECKF(strstr(log, "evil\n") == NULL, "a raw newline from a peer reached the log");
}

int main(void)
{
    snprintf(tmp, sizeof tmp, "/tmp/pt_test_loop_XXXXXX");
    if (!mkdtemp(tmp))
        return 1;
    signal(SIGPIPE, SIG_IGN);
    peer_names_escaped();
    return farm_test_end();
}
