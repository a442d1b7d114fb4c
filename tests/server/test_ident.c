/*
 * test_ident.c - tokens and identities, with a real ptserve, ptworker and
 * ptctl over real sockets on loopback.
 *
 *  1. Token rules: a short token (ptserve, ptworker and ptctl exit 1 and say
 *     how to make a good one) and a token or clients file that group or
 *     others may access (refused with its mode and the chmod that fixes it).
 *  2. Backoff: 50 wrong answers from 127.0.0.1 in a burst; after the first
 *     few, the address is refused with "too many failed authentications,
 *     retry in N s" (without computing a MAC), while a peer with the right
 *     token from 127.0.0.2 is welcomed, with a WELCOME that proves the token;
 *     the log stays within a bounded number of lines.
 *  3. A fake coordinator that answers the handshake without knowing the
 *     token: ptworker and ptctl exit 1 with "does not know the token" and
 *     send it nothing after AUTH.
 *  4. --clients-file: a client's identity is the NAME of the token it
 *     proves, not the name its HELLO declares (alice declaring "bob" owns her
 *     job, and --max-queued counts her as alice); alice cannot cancel bob's
 *     job (refused, the job still queued), the admin (shared token) can; a
 *     client token cannot join as a worker (raw peer, and a real ptworker).
 */
#include <arpa/inet.h>
#include <netinet/in.h>

#include "common/base/hash.h"
#include "common/scene/bundle.h"
#include "tests/check.h"
#include "tests/server/farm_util.h"

static const char *SCENE = PT_SOURCE_DIR "/scenes/cornell_box.gltf";
static const char *ADMIN_TOKEN = "YWRtaW4tdG9rZW4tZm9yLXRoZS10ZXN0LWZhcm0K";
static const char *ALICE_TOKEN = "YWxpY2UtdG9rZW4tZm9yLXRoZS10ZXN0LWZhcm0K";
static const char *BOB_TOKEN = "Ym9iLXRva2VuLWZvci10aGUtdGVzdC1mYXJtLWZhcm0K";

static void write_secret(const char *name, const char *text, mode_t mode)
{
    unlink(path(name));
    FILE *f = fopen(path(name), "w");
    if (!f)
        return;
    fputs(text, f);
    fclose(f);
    chmod(path(name), mode);
}

/* Runs argv with stdout to out_name and stderr to log_name (both in tmp). */
static int run_out(const char *const *argv, const char *out_name, const char *log_name,
                   double timeout)
{
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 1, path(out_name), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_addopen(&fa, 2, path(log_name), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    pid_t pid = -1;
    if (posix_spawn(&pid, argv[0], &fa, NULL, (char *const *)argv, environ) != 0)
        pid = -1;
    posix_spawn_file_actions_destroy(&fa);
    return pid > 0 ? wait_exit(pid, timeout) : -1;
}

static unsigned long long read_id(const char *out_name)
{
    unsigned long long id = 0;
    FILE *f = fopen(path(out_name), "r");
    if (f) {
        if (fscanf(f, "%llu", &id) != 1)
            id = 0;
        fclose(f);
    }
    return id;
}

/* Lines of a log that contain needle. */
static int log_count(const char *log, const char *needle)
{
    FILE *f = fopen(path(log), "r");
    if (!f)
        return 0;
    char line[4096];
    int n = 0;
    while (fgets(line, sizeof line, f))
        n += needle == NULL || strstr(line, needle) != NULL;
    fclose(f);
    return n;
}

static pid_t g_srv = -1;

static void stop_server(void)
{
    if (g_srv > 0) {
        kill(g_srv, SIGTERM);
        wait_exit(g_srv, 30);
    }
    g_srv = -1;
}

/* Starts ptserve in queue mode on a free loopback port with extra options
 * (NULL-terminated); returns the port or -1. */
static int start_server(const char *state, const char *log, const char *const *extra)
{
    const char *argv[32] = {PT_BIN_DIR "/ptserve", "--state-dir", path(state), "--listen",
                            "127.0.0.1:0",         "--port-file", path("port")};
    int n = 7;
    for (int i = 0; extra[i] && n < 31; i++)
        argv[n++] = extra[i];
    argv[n] = NULL;
    unlink(path("port"));
    g_srv = spawn(argv, log);
    int port = read_port();
    CHECKF(port > 0, "ptserve did not start (see %s)", log);
    return port;
}

/* ---- a raw peer that speaks the new handshake ---- */

typedef struct peer {
    int fd;
    uint8_t buf[1 << 16];
    size_t len, used;
    char error[PROTO_MAX_ERROR_TEXT + 1]; /* the last ERROR's text */
    uint16_t code;
} peer;

static int peer_recv(peer *p, proto_frame *f, double timeout)
{
    memmove(p->buf, p->buf + p->used, p->len - p->used);
    p->len -= p->used;
    p->used = 0;
    double end = pt_now_s() + timeout;
    for (;;) {
        size_t used;
        if (p->len &&
            proto_frame_decode(p->buf, p->len, PROTO_MAX_PAYLOAD, f, &used, NULL) == PT_OK) {
            p->used = used;
            if (f->type == PROTO_MSG_ERROR) {
                proto_error_msg m;
                if (proto_msg_decode_error(f->payload, f->len, &m, NULL) == PT_OK) {
                    snprintf(p->error, sizeof p->error, "%s", m.text);
                    p->code = m.code;
                }
            }
            return f->type;
        }
        if (pt_now_s() > end || p->len == sizeof p->buf)
            return -1;
        struct pollfd q = {p->fd, POLLIN, 0};
        if (poll(&q, 1, 50) == 1) {
            ssize_t r = recv(p->fd, p->buf + p->len, sizeof p->buf - p->len, 0);
            if (r <= 0)
                return -1;
            p->len += (size_t)r;
        }
    }
}

static void peer_send(peer *p, uint16_t type, const proto_writer *w)
{
    send_frame(p->fd, type, w);
}

/* Connects from source address src (NULL: any) to 127.0.0.1:port. */
static int connect_from(const char *src, int port)
{
    int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0)
        return -1;
    struct sockaddr_in a;
    memset(&a, 0, sizeof a);
    a.sin_family = AF_INET;
    if (src) {
        inet_pton(AF_INET, src, &a.sin_addr);
        if (bind(fd, (struct sockaddr *)&a, sizeof a) != 0) {
            close(fd);
            return -1;
        }
    }
    inet_pton(AF_INET, "127.0.0.1", &a.sin_addr);
    a.sin_port = htons((uint16_t)port);
    if (connect(fd, (struct sockaddr *)&a, sizeof a) != 0) {
        close(fd);
        return -1;
    }
    return fd;
}

/* The whole handshake as name in role with token, from src. Returns the
 * type of the answer to AUTH (or to HELLO when that was refused): WELCOME
 * only when its proof shows the server holds token; p->error holds an
 * ERROR's text. p->fd stays open (the caller closes it). */
static int handshake(peer *p, const char *src, int port, const char *token, const char *name,
                     uint8_t role)
{
    memset(p, 0, sizeof *p);
    p->fd = connect_from(src, port);
    if (p->fd < 0)
        return -1;
    proto_hello h = {0};
    h.version = PROTO_VERSION;
    h.role = role;
    snprintf(h.name, sizeof h.name, "%s", name);
    h.threads = role == PROTO_ROLE_WORKER ? 1 : 0;
    snprintf(h.build_id, sizeof h.build_id, "%s", proto_build_id());
    proto_writer w;
    proto_writer_init(&w, 4096);
    proto_msg_encode_hello(&w, &h, NULL);
    peer_send(p, PROTO_MSG_HELLO, &w);
    proto_frame f;
    int t = peer_recv(p, &f, 10);
    if (t != PROTO_MSG_CHALLENGE) {
        proto_writer_fini(&w);
        return t;
    }
    proto_challenge ch;
    proto_msg_decode_challenge(f.payload, f.len, &ch, NULL);
    proto_auth a;
    proto_auth_response((const uint8_t *)token, strlen(token), ch.nonce, a.mac, NULL);
    proto_auth_nonce(a.nonce, NULL);
    proto_writer_reset(&w);
    proto_msg_encode_auth(&w, &a, NULL);
    peer_send(p, PROTO_MSG_AUTH, &w);
    proto_writer_fini(&w);
    t = peer_recv(p, &f, 10);
    if (t == PROTO_MSG_WELCOME) {
        proto_welcome wm;
        if (proto_msg_decode_welcome(f.payload, f.len, &wm, NULL) != PT_OK ||
            proto_auth_check_server((const uint8_t *)token, strlen(token), ch.nonce, a.nonce,
                                    wm.proof, NULL) != PT_OK)
            return -2;
    }
    return t;
}

/* ---- 1. token rules ---------------------------------------------------------------- */

static void token_rules(void)
{
    write_secret("short", "x\n", 0600);
    write_secret("loose", "bG9vc2UtYnV0LWxvbmctZW5vdWdoLXRva2VuCg\n", 0644);
    write_secret("tok", ADMIN_TOKEN, 0600);

    const char *srv_short[] = {PT_BIN_DIR "/ptserve", "--state-dir", path("st1"),
                               "--token-file",        path("short"), NULL};
    CHECK(run(srv_short, "short_srv.log", 30) == 1);
    CHECKF(log_has("short_srv.log", "too short") &&
               log_has("short_srv.log", "head -c 32 /dev/urandom | base64"),
           "ptserve did not refuse the 1-byte token with the way to make one");
    const char *wrk_short[] = {PT_BIN_DIR "/ptworker", "--server",    "127.0.0.1:1", "--token-file",
                               path("short"),          "--cache-dir", path("cache"), NULL};
    CHECK(run(wrk_short, "short_wrk.log", 30) == 1);
    CHECK(log_has("short_wrk.log", "too short"));
    const char *ctl_short[] = {PT_BIN_DIR "/ptctl", "--server", "127.0.0.1:1", "--token-file",
                               path("short"),       "list",     NULL};
    CHECK(run(ctl_short, "short_ctl.log", 30) == 1);
    CHECK(log_has("short_ctl.log", "too short"));

    const char *srv_loose[] = {PT_BIN_DIR "/ptserve", "--state-dir", path("st1"),
                               "--token-file",        path("loose"), NULL};
    CHECK(run(srv_loose, "loose_srv.log", 30) == 1);
    CHECKF(log_has("loose_srv.log", "0644") && log_has("loose_srv.log", "chmod 600"),
           "ptserve did not refuse the world-readable token file with its mode and the fix");
    const char *wrk_loose[] = {PT_BIN_DIR "/ptworker", "--server",    "127.0.0.1:1", "--token-file",
                               path("loose"),          "--cache-dir", path("cache"), NULL};
    CHECK(run(wrk_loose, "loose_wrk.log", 30) == 1);
    CHECK(log_has("loose_wrk.log", "chmod 600"));
    const char *ctl_loose[] = {PT_BIN_DIR "/ptctl", "--server", "127.0.0.1:1", "--token-file",
                               path("loose"),       "list",     NULL};
    CHECK(run(ctl_loose, "loose_ctl.log", 30) == 1);
    CHECK(log_has("loose_ctl.log", "chmod 600"));

    /* A clients file that the group may read, and one with a short token. */
    char text[512];
    snprintf(text, sizeof text, "alice %s\n", ALICE_TOKEN);
    write_secret("clients_loose", text, 0640);
    const char *cl_loose[] = {PT_BIN_DIR "/ptserve", "--state-dir", path("st1"),
                              "--token-file",        path("tok"),   "--clients-file",
                              path("clients_loose"), NULL};
    CHECK(run(cl_loose, "clients_loose.log", 30) == 1);
    CHECK(log_has("clients_loose.log", "0640") && log_has("clients_loose.log", "chmod 600"));
    write_secret("clients_short", "# a comment\n\nalice short\n", 0600);
    const char *cl_short[] = {PT_BIN_DIR "/ptserve", "--state-dir", path("st1"),
                              "--token-file",        path("tok"),   "--clients-file",
                              path("clients_short"), NULL};
    CHECK(run(cl_short, "clients_short.log", 30) == 1);
    CHECK(log_has("clients_short.log", "line 3") && log_has("clients_short.log", "too short"));
}

/* ---- 2. backoff -------------------------------------------------------------------- */

static void backoff(void)
{
    const char *extra[] = {"--token-file", path("tok"), NULL};
    int port = start_server("st2", "backoff.log", extra);
    if (port <= 0)
        return;
    /* A right token works from 127.0.0.1 before the attack. */
    peer *p = calloc(1, sizeof *p);
    CHECK(handshake(p, "127.0.0.1", port, ADMIN_TOKEN, "before", PROTO_ROLE_CLIENT) ==
          PROTO_MSG_WELCOME);
    close(p->fd);

    int failed = 0, blocked = 0, other = 0;
    double t0 = pt_now_s();
    for (int i = 0; i < 50; i++) {
        int t = handshake(p, "127.0.0.1", port, "a-wrong-guess-of-the-token", "guesser",
                          PROTO_ROLE_CLIENT);
        if (t == PROTO_MSG_ERROR && strstr(p->error, "authentication failed"))
            failed++;
        else if (t == PROTO_MSG_ERROR &&
                 strstr(p->error, "too many failed authentications from 127.0.0.1, retry in"))
            blocked++;
        else
            other++;
        close(p->fd);
    }
    fprintf(stderr, "backoff: 50 wrong answers in %.3f s: %d checked and failed, %d refused\n",
            pt_now_s() - t0, failed, blocked);
    /* 5 free failures, then one more per block that ran out during the
     * burst (1, 2, 4... s): however slow the machine, a burst under a
     * minute leaves at most 5 + 6. */
    CHECKF(failed >= 5 && failed <= 11 && blocked >= 39 && other == 0,
           "%d failed, %d refused by the backoff, %d other", failed, blocked, other);
    /* The right token from the blocked address is refused too (the backoff
     * judges the address, before any MAC)... */
    int t = handshake(p, "127.0.0.1", port, ADMIN_TOKEN, "honest", PROTO_ROLE_CLIENT);
    CHECKF(t == PROTO_MSG_ERROR && strstr(p->error, "retry in"), "type %d: %s", t, p->error);
    close(p->fd);
    /* ...while another address is served at once. */
    t = handshake(p, "127.0.0.2", port, ADMIN_TOKEN, "neighbour", PROTO_ROLE_CLIENT);
    CHECKF(t == PROTO_MSG_WELCOME, "the peer from 127.0.0.2 got type %d: %s", t, p->error);
    close(p->fd);
    /* And from there a wrong token is still told so, not blocked. */
    t = handshake(p, "127.0.0.2", port, "a-wrong-guess-of-the-token", "x", PROTO_ROLE_CLIENT);
    CHECK(t == PROTO_MSG_ERROR && strstr(p->error, "authentication failed"));
    close(p->fd);
    free(p);
    stop_server();
    /* Bounded log: a line per free failure and per block, not per attempt. */
    int lines = log_count("backoff.log", "authentication");
    CHECKF(lines >= 5 && lines <= 14, "%d log lines about authentication", lines);
    CHECK(log_has("backoff.log", "failed authentications in a row; refusing 127.0.0.1"));
}

/* ---- 3. a coordinator that does not know the token --------------------------------- */

/* Accepts one connection on lfd and plays the coordinator's side without
 * knowing the token: CHALLENGE, then a WELCOME proved under a guess.
 * Returns 1 when the peer sent nothing after AUTH and closed. */
static int impostor(int lfd, uint8_t role)
{
    struct pollfd q = {lfd, POLLIN, 0};
    if (poll(&q, 1, 20000) != 1)
        return 0;
    peer *p = calloc(1, sizeof *p);
    p->fd = accept(lfd, NULL, NULL);
    int ok = 0;
    proto_frame f;
    proto_hello h;
    if (p->fd < 0 || peer_recv(p, &f, 10) != PROTO_MSG_HELLO ||
        proto_msg_decode_hello(f.payload, f.len, &h, NULL) != PT_OK || h.role != role)
        goto done;
    proto_challenge ch;
    proto_auth_nonce(ch.nonce, NULL);
    proto_writer w;
    proto_writer_init(&w, 4096);
    proto_msg_encode_challenge(&w, &ch, NULL);
    peer_send(p, PROTO_MSG_CHALLENGE, &w);
    proto_auth a;
    if (peer_recv(p, &f, 10) != PROTO_MSG_AUTH ||
        proto_msg_decode_auth(f.payload, f.len, &a, NULL) != PT_OK) {
        proto_writer_fini(&w);
        goto done;
    }
    proto_welcome wm;
    memset(&wm, 0, sizeof wm);
    wm.session_id = 1;
    snprintf(wm.build_id, sizeof wm.build_id, "%s", proto_build_id());
    static const char guess[] = "the-impostor-guesses-a-token";
    proto_auth_server_proof((const uint8_t *)guess, sizeof guess - 1, ch.nonce, a.nonce, wm.proof,
                            NULL);
    proto_writer_reset(&w);
    proto_msg_encode_welcome(&w, &wm, NULL);
    peer_send(p, PROTO_MSG_WELCOME, &w);
    proto_writer_fini(&w);
    /* Nothing more may come: no WORK_REQUEST, no LIST; just the close. */
    ok = peer_recv(p, &f, 20) == -1 && p->len == p->used;
done:
    if (p->fd >= 0)
        close(p->fd);
    free(p);
    return ok;
}

static void fake_coordinator(void)
{
    int lfd = -1;
    uint16_t port = 0;
    pt_error err = {0};
    if (pt_net_listen("127.0.0.1", 0, &lfd, &port, &err) != PT_OK) {
        CHECKF(0, "%s", err.msg);
        return;
    }
    char server[64];
    snprintf(server, sizeof server, "127.0.0.1:%u", port);
    const char *wrk[] = {PT_BIN_DIR "/ptworker",
                         "--server",
                         server,
                         "--token-file",
                         path("tok"),
                         "--cache-dir",
                         path("cache"),
                         "--threads",
                         "1",
                         NULL};
    pid_t pid = spawn(wrk, "impostor_wrk.log");
    CHECKF(impostor(lfd, PROTO_ROLE_WORKER), "ptworker talked on after a wrong WELCOME proof");
    CHECK(wait_exit(pid, 30) == 1);
    CHECK(log_has("impostor_wrk.log", "the coordinator does not know the token"));

    const char *ctl[] = {PT_BIN_DIR "/ptctl", "--server", server, "--token-file",
                         path("tok"),         "list",     NULL};
    pid = spawn(ctl, "impostor_ctl.log");
    CHECKF(impostor(lfd, PROTO_ROLE_CLIENT), "ptctl talked on after a wrong WELCOME proof");
    CHECK(wait_exit(pid, 30) == 1);
    CHECK(log_has("impostor_ctl.log", "the coordinator does not know the token"));
    close(lfd);
}

/* ---- 4. per-client identities ------------------------------------------------------ */

static pt_bundle *g_bundle;

/* SUBMIT + UPLOAD of the test scene on an authenticated peer; the job id,
 * 0 when refused (p->error says why). */
static uint64_t raw_submit(peer *p, const char *job)
{
    proto_submit m;
    memset(&m, 0, sizeof m);
    snprintf(m.name, sizeof m.name, "%s", job);
    m.width = m.height = 16;
    m.spp = 4;
    m.bundle_size = g_bundle->size;
    pt_sha256(g_bundle->data, g_bundle->size, m.bundle_hash);
    proto_writer w;
    proto_writer_init(&w, PROTO_MAX_SCENE_CHUNK + 4096);
    proto_msg_encode_submit(&w, &m, NULL);
    peer_send(p, PROTO_MSG_SUBMIT, &w);
    for (uint64_t off = 0; off < g_bundle->size; off += PROTO_MAX_SCENE_CHUNK) {
        uint64_t n = g_bundle->size - off;
        proto_scene_chunk ch;
        memcpy(ch.hash, m.bundle_hash, 32);
        ch.offset = off;
        ch.total = g_bundle->size;
        ch.len = (uint32_t)(n < PROTO_MAX_SCENE_CHUNK ? n : PROTO_MAX_SCENE_CHUNK);
        ch.data = g_bundle->data + off;
        proto_writer_reset(&w);
        proto_msg_encode_scene_chunk(&w, &ch, NULL);
        peer_send(p, PROTO_MSG_UPLOAD, &w);
    }
    proto_writer_fini(&w);
    proto_frame f;
    proto_job_ref r;
    if (peer_recv(p, &f, 60) != PROTO_MSG_SUBMITTED ||
        proto_msg_decode_job_ref(f.payload, f.len, &r, NULL) != PT_OK)
        return 0;
    return r.job_id;
}

/* The job's JOB_INFO through an admin connection; 1 when it came. */
static int job_info(int port, uint64_t id, proto_job_info *out)
{
    peer *p = calloc(1, sizeof *p);
    int ok = 0;
    if (handshake(p, NULL, port, ADMIN_TOKEN, "admin", PROTO_ROLE_CLIENT) == PROTO_MSG_WELCOME) {
        proto_writer w;
        proto_writer_init(&w, 64);
        proto_job_ref r = {id};
        proto_msg_encode_job_ref(&w, &r, NULL);
        peer_send(p, PROTO_MSG_STATUS, &w);
        proto_writer_fini(&w);
        proto_frame f;
        ok = peer_recv(p, &f, 10) == PROTO_MSG_JOB_INFO &&
             proto_msg_decode_job_info(f.payload, f.len, out, NULL) == PT_OK;
    }
    close(p->fd);
    free(p);
    return ok;
}

static void identities(void)
{
    char text[1024];
    snprintf(text, sizeof text,
             "# the test farm's clients\n"
             "alice %s\n"
             "\t  # bob's, indented\n"
             "bob\t%s  \n",
             ALICE_TOKEN, BOB_TOKEN);
    write_secret("clients", text, 0600);
    write_secret("alice.tok", ALICE_TOKEN, 0600);
    write_secret("bob.tok", BOB_TOKEN, 0600);
    const char *extra[] = {
        "--token-file", path("tok"), "--clients-file", path("clients"), "--max-queued", "1", NULL};
    int port = start_server("st4", "ident.log", extra);
    if (port <= 0)
        return;
    char server[64];
    snprintf(server, sizeof server, "127.0.0.1:%d", port);

    /* alice declares the name "bob": she is alice all the same. */
    peer *p = calloc(1, sizeof *p);
    CHECK(handshake(p, NULL, port, ALICE_TOKEN, "bob", PROTO_ROLE_CLIENT) == PROTO_MSG_WELCOME);
    uint64_t a1 = raw_submit(p, "alice-1");
    CHECKF(a1 > 0, "alice's submit was refused: %s", p->error);
    close(p->fd);
    proto_job_info info;
    CHECK(job_info(port, a1, &info) && strcmp(info.owner, "alice") == 0);
    /* Her cap (1) counts her as alice, whatever name she declares. */
    CHECK(handshake(p, NULL, port, ALICE_TOKEN, "carol", PROTO_ROLE_CLIENT) == PROTO_MSG_WELCOME);
    CHECK(raw_submit(p, "alice-2") == 0);
    CHECKF(strstr(p->error, "alice already has 1 unfinished"), "%s", p->error);
    close(p->fd);

    /* bob, through ptctl with his own token: not counted against alice's
     * declared "bob". */
    const char *bob_submit[] = {PT_BIN_DIR "/ptctl",
                                "--server",
                                server,
                                "--token-file",
                                path("bob.tok"),
                                "submit",
                                SCENE,
                                "--res",
                                "16x16",
                                "--spp",
                                "4",
                                NULL};
    CHECK(run_out(bob_submit, "bob_submit.out", "bob_submit.log", 60) == 0);
    unsigned long long b1 = read_id("bob_submit.out");
    CHECK(b1 > 0 && job_info(port, b1, &info) && strcmp(info.owner, "bob") == 0);

    /* alice cannot cancel bob's job: a clear refusal, the job untouched. */
    char id[32];
    snprintf(id, sizeof id, "%llu", b1);
    const char *alice_cancel[] = {PT_BIN_DIR "/ptctl", "--server", server, "--token-file",
                                  path("alice.tok"),   "cancel",   id,     NULL};
    CHECK(run_out(alice_cancel, "alice_cancel.out", "alice_cancel.log", 30) == 1);
    CHECKF(log_has("alice_cancel.log", "belongs to bob") &&
               log_has("alice_cancel.log", "you are alice"),
           "no clear refusal in alice_cancel.log");
    CHECK(job_info(port, b1, &info) && info.state == PROTO_JOB_QUEUED);
    /* The same through the raw protocol, declaring bob's name. */
    CHECK(handshake(p, NULL, port, ALICE_TOKEN, "bob", PROTO_ROLE_CLIENT) == PROTO_MSG_WELCOME);
    proto_writer w;
    proto_writer_init(&w, 64);
    proto_job_ref r = {b1};
    proto_msg_encode_job_ref(&w, &r, NULL);
    peer_send(p, PROTO_MSG_CANCEL, &w);
    proto_writer_fini(&w);
    proto_frame f;
    CHECK(peer_recv(p, &f, 10) == PROTO_MSG_ERROR && p->code == PROTO_E_DENIED);
    close(p->fd);
    CHECK(job_info(port, b1, &info) && info.state == PROTO_JOB_QUEUED);

    /* She may cancel her own. */
    snprintf(id, sizeof id, "%llu", (unsigned long long)a1);
    CHECK(run_out(alice_cancel, "alice_own.out", "alice_own.log", 30) == 0);
    CHECK(job_info(port, a1, &info) && info.state == PROTO_JOB_CANCELLED);

    /* The admin may cancel anyone's. */
    snprintf(id, sizeof id, "%llu", b1);
    const char *admin_cancel[] = {PT_BIN_DIR "/ptctl", "--server", server, "--token-file",
                                  path("tok"),         "cancel",   id,     NULL};
    CHECK(run_out(admin_cancel, "admin_cancel.out", "admin_cancel.log", 30) == 0);
    CHECK(job_info(port, b1, &info) && info.state == PROTO_JOB_CANCELLED);

    /* A client token cannot join as a worker: a raw peer, and a real ptworker. */
    int t = handshake(p, NULL, port, ALICE_TOKEN, "sneaky", PROTO_ROLE_WORKER);
    CHECKF(t == PROTO_MSG_ERROR && p->code == PROTO_E_AUTH &&
               strstr(p->error, "cannot join as a worker"),
           "type %d: %s", t, p->error);
    close(p->fd);
    const char *wrk[] = {PT_BIN_DIR "/ptworker", "--server",  server,      "--token-file",
                         path("alice.tok"),      "--threads", "1",         "--cache-dir",
                         path("cache"),          "--name",    "alice-wrk", NULL};
    CHECK(run(wrk, "alice_wrk.log", 30) == 1);
    CHECK(log_has("alice_wrk.log", "cannot join as a worker"));
    /* The shared token still joins as one. */
    t = handshake(p, NULL, port, ADMIN_TOKEN, "real-worker", PROTO_ROLE_WORKER);
    CHECK(t == PROTO_MSG_WELCOME);
    close(p->fd);
    free(p);
    stop_server();
    CHECK(!log_has("ident.log", "worker alice-wrk joined") &&
          !log_has("ident.log", "worker sneaky joined"));
    CHECK(log_has("ident.log", "authenticated as alice"));
}

int main(void)
{
    snprintf(tmp, sizeof tmp, "/tmp/pt_test_ident_XXXXXX");
    if (!mkdtemp(tmp))
        return 1;
    signal(SIGPIPE, SIG_IGN);
    pt_error err = {0};
    if (pt_bundle_pack(SCENE, &g_bundle, &err) != PT_OK) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    token_rules();
    backoff();
    fake_coordinator();
    identities();
    pt_bundle_free(g_bundle);
    stop_server();
    return farm_test_end();
}
