/*
 * test_ctl.c - the client side of the render queue (client/ctl.c) against a
 * scripted fake server in a child process, over a socketpair.
 *
 * - Handshake: HELLO says client, no threads, this build; AUTH is the right
 *   MAC over the nonce (checked by the fake with proto_auth_verify); a wrong
 *   token ends in the server's ERROR with its code readable.
 * - SUBMIT + UPLOAD: chunks at most PROTO_MAX_SCENE_CHUNK, offsets in order,
 *   the bundle hash and size in each, the bytes reassembled equal; SUBMITTED
 *   gives the id. A refusal mid-upload reports the server's reason.
 * - FETCH: a good image in pieces; refused: a bad SHA-256, a chunk out of
 *   order, a total that changes, a total over CTL_MAX_IMAGE, an empty chunk,
 *   a reply of the wrong type.
 * - STATUS answered by ERROR NOT_FOUND: PT_ERR_PROTO with that code.
 * - Helpers: JSON escaping (control characters, quotes, malformed UTF-8),
 *   progress lines, durations, hex, the atomic write.
 */
#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include "client/ctl.h"
#include "common/base/alloc.h"
#include "common/base/hash.h"
#include "common/scene/bundle.h"
#include "protocol/auth.h"
#include "protocol/frame.h"
#include "protocol/msg.h"
#include "tests/check.h"

static const uint8_t TOKEN[] = "s3cret-token-of-the-farm";
#define TOKEN_LEN (sizeof TOKEN - 1)

/* ---- the fake server (runs in the child; exits non-zero on a broken expectation) ---- */

typedef struct fake {
    int fd;
    uint8_t *in;
    size_t len, cap, start;
} fake;

#define FAKE_EXPECT(cond)                                                                          \
    do {                                                                                           \
        if (!(cond)) {                                                                             \
            fprintf(stderr, "fake server: %s:%d: %s\n", __FILE__, __LINE__, #cond);                \
            _exit(3);                                                                              \
        }                                                                                          \
    } while (0)

static int fake_recv(fake *s, proto_frame *f)
{
    if (s->start) {
        memmove(s->in, s->in + s->start, s->len - s->start);
        s->len -= s->start;
        s->start = 0;
    }
    for (;;) {
        size_t used;
        pt_status st = proto_frame_decode(s->in, s->len, PROTO_MAX_PAYLOAD, f, &used, NULL);
        if (st == PT_OK) {
            s->start = used;
            return 0;
        }
        FAKE_EXPECT(st == PT_AGAIN);
        if (s->len == s->cap) {
            s->cap = s->cap ? s->cap * 2 : 1 << 16;
            s->in = realloc(s->in, s->cap);
            FAKE_EXPECT(s->in);
        }
        ssize_t n = read(s->fd, s->in + s->len, s->cap - s->len);
        if (n <= 0)
            return -1;
        s->len += (size_t)n;
    }
}

static void fake_send_raw(fake *s, uint16_t type, const uint8_t *p, size_t n)
{
    proto_writer w;
    proto_writer_init(&w, PROTO_MAX_PAYLOAD + 64);
    FAKE_EXPECT(proto_frame_encode(&w, type, p, n, NULL) == PT_OK);
    for (size_t off = 0; off < w.len;) {
        ssize_t k = send(s->fd, w.buf + off, w.len - off, MSG_NOSIGNAL);
        if (k <= 0)
            break; /* the client hung up: what it does then is under test */
        off += (size_t)k;
    }
    proto_writer_fini(&w);
}

#define FAKE_SEND(s, type, enc, msgp)                                                              \
    do {                                                                                           \
        proto_writer pw_;                                                                          \
        proto_writer_init(&pw_, PROTO_MAX_PAYLOAD);                                                \
        FAKE_EXPECT(enc(&pw_, (msgp), NULL) == PT_OK);                                             \
        fake_send_raw((s), (type), pw_.buf, pw_.len);                                              \
        proto_writer_fini(&pw_);                                                                   \
    } while (0)

static void fake_error(fake *s, uint16_t code, const char *text)
{
    proto_error_msg m;
    m.code = code;
    snprintf(m.text, sizeof m.text, "%s", text);
    FAKE_SEND(s, PROTO_MSG_ERROR, proto_msg_encode_error, &m);
}

/* The server side of the handshake; 0 when the client proved the token.
 * With impostor set, the fake does not know the token and answers AUTH with
 * a WELCOME whose proof is made under another one. */
static int fake_handshake(fake *s, int impostor)
{
    proto_frame f;
    FAKE_EXPECT(fake_recv(s, &f) == 0 && f.type == PROTO_MSG_HELLO);
    proto_hello h;
    FAKE_EXPECT(proto_msg_decode_hello(f.payload, f.len, &h, NULL) == PT_OK);
    FAKE_EXPECT(h.role == PROTO_ROLE_CLIENT && h.threads == 0 && h.version == PROTO_VERSION);
    FAKE_EXPECT(strcmp(h.build_id, proto_build_id()) == 0 && strcmp(h.name, "tester@here") == 0);
    proto_challenge ch;
    FAKE_EXPECT(proto_auth_nonce(ch.nonce, NULL) == PT_OK);
    FAKE_SEND(s, PROTO_MSG_CHALLENGE, proto_msg_encode_challenge, &ch);
    FAKE_EXPECT(fake_recv(s, &f) == 0 && f.type == PROTO_MSG_AUTH);
    proto_auth a;
    FAKE_EXPECT(proto_msg_decode_auth(f.payload, f.len, &a, NULL) == PT_OK);
    if (!impostor && proto_auth_verify(TOKEN, TOKEN_LEN, ch.nonce, a.mac, NULL) != PT_OK) {
        fake_error(s, PROTO_E_AUTH, "authentication failed (wrong token)");
        return -1;
    }
    proto_welcome w;
    w.session_id = 9;
    static const uint8_t guess[] = "a-guess-at-the-farm-token";
    FAKE_EXPECT(proto_auth_server_proof(impostor ? guess : TOKEN,
                                        impostor ? sizeof guess - 1 : TOKEN_LEN, ch.nonce, a.nonce,
                                        w.proof, NULL) == PT_OK);
    snprintf(w.build_id, sizeof w.build_id, "%s", proto_build_id());
    FAKE_SEND(s, PROTO_MSG_WELCOME, proto_msg_encode_welcome, &w);
    return 0;
}

/* Scenarios the fake plays after the handshake. */
enum {
    SC_NONE,
    SC_SUBMIT,
    SC_SUBMIT_REFUSED,
    SC_FETCH_GOOD,
    SC_FETCH_BAD_HASH,
    SC_FETCH_ORDER,
    SC_FETCH_TOTAL,
    SC_FETCH_HUGE,
    SC_FETCH_EMPTY,
    SC_FETCH_WRONG_TYPE,
    SC_NOT_FOUND,
    SC_IMPOSTOR /* does not know the token: a wrong WELCOME proof */
};

#define BUNDLE_SIZE ((size_t)(5u << 19) + 123) /* 2.5 MiB and a bit: three chunks */
#define IMAGE_SIZE ((size_t)(3u << 19) + 7)

static uint8_t *pattern(size_t n, unsigned salt)
{
    uint8_t *p = malloc(n);
    for (size_t i = 0; i < n; i++)
        p[i] = (uint8_t)(i * 31u + salt + (i >> 11));
    return p;
}

static void send_image_chunk(fake *s, uint16_t type, const uint8_t *hash, uint64_t off,
                             uint64_t total, const uint8_t *data, uint32_t n)
{
    proto_scene_chunk ch;
    memcpy(ch.hash, hash, PROTO_HASH_SIZE);
    ch.offset = off;
    ch.total = total;
    ch.len = n;
    ch.data = data;
    FAKE_SEND(s, type, proto_msg_encode_scene_chunk, &ch);
}

static void fake_fetch(fake *s, int sc)
{
    proto_frame f;
    FAKE_EXPECT(fake_recv(s, &f) == 0 && f.type == PROTO_MSG_FETCH);
    proto_job_ref r;
    FAKE_EXPECT(proto_msg_decode_job_ref(f.payload, f.len, &r, NULL) == PT_OK && r.job_id == 5);
    uint8_t *img = pattern(IMAGE_SIZE, 7);
    char hex[65];
    uint8_t hash[PROTO_HASH_SIZE];
    pt_sha256_hex(img, IMAGE_SIZE, hex);
    FAKE_EXPECT(ctl_hex_to_hash(hex, hash) == 0);
    if (sc == SC_FETCH_BAD_HASH)
        hash[5] ^= 1;
    uint64_t total = IMAGE_SIZE;
    if (sc == SC_FETCH_HUGE)
        total = CTL_MAX_IMAGE + 1;
    if (sc == SC_FETCH_WRONG_TYPE) {
        send_image_chunk(s, PROTO_MSG_SCENE_CHUNK, hash, 0, total, img, 1000);
        free(img);
        return;
    }
    /* Pieces of 1 MiB, 1000 bytes, the rest. */
    size_t cuts[4] = {0, PROTO_MAX_SCENE_CHUNK, PROTO_MAX_SCENE_CHUNK + 1000, IMAGE_SIZE};
    for (int i = 0; i < 3; i++) {
        uint64_t off = cuts[i];
        uint32_t n = (uint32_t)(cuts[i + 1] - cuts[i]);
        if (sc == SC_FETCH_ORDER && i == 1)
            off += 1;
        if (sc == SC_FETCH_TOTAL && i == 2)
            total += 1;
        if (sc == SC_FETCH_EMPTY && i == 1) {
            send_image_chunk(s, PROTO_MSG_IMAGE, hash, off, total, img + off, 0);
            continue;
        }
        send_image_chunk(s, PROTO_MSG_IMAGE, hash, off, total, img + off, n);
    }
    free(img);
}

static void fake_submit(fake *s, int refuse)
{
    proto_frame f;
    FAKE_EXPECT(fake_recv(s, &f) == 0 && f.type == PROTO_MSG_SUBMIT);
    proto_submit m;
    FAKE_EXPECT(proto_msg_decode_submit(f.payload, f.len, &m, NULL) == PT_OK);
    FAKE_EXPECT(strcmp(m.name, "box") == 0 && m.spp == 32 && m.priority == -2);
    FAKE_EXPECT(m.bundle_size == BUNDLE_SIZE);
    if (refuse) {
        fake_error(s, PROTO_E_LIMIT, "scene of 2.5 MiB over the 1 MiB cap");
        return; /* and close, with the upload unread */
    }
    uint8_t *got = malloc(BUNDLE_SIZE);
    uint64_t have = 0;
    while (have < BUNDLE_SIZE) {
        FAKE_EXPECT(fake_recv(s, &f) == 0 && f.type == PROTO_MSG_UPLOAD);
        proto_scene_chunk ch;
        FAKE_EXPECT(proto_msg_decode_scene_chunk(f.payload, f.len, &ch, NULL) == PT_OK);
        FAKE_EXPECT(ch.offset == have && ch.total == BUNDLE_SIZE && ch.len > 0);
        FAKE_EXPECT(memcmp(ch.hash, m.bundle_hash, PROTO_HASH_SIZE) == 0);
        memcpy(got + have, ch.data, ch.len);
        have += ch.len;
    }
    char hex[65];
    uint8_t hash[PROTO_HASH_SIZE];
    pt_sha256_hex(got, BUNDLE_SIZE, hex);
    FAKE_EXPECT(ctl_hex_to_hash(hex, hash) == 0 && memcmp(hash, m.bundle_hash, 32) == 0);
    uint8_t *want = pattern(BUNDLE_SIZE, 3);
    FAKE_EXPECT(memcmp(got, want, BUNDLE_SIZE) == 0);
    free(want);
    free(got);
    proto_job_ref r = {77};
    FAKE_SEND(s, PROTO_MSG_SUBMITTED, proto_msg_encode_job_ref, &r);
}

static void fake_run(int fd, int sc)
{
    fake s = {fd, NULL, 0, 0, 0};
    if (fake_handshake(&s, sc == SC_IMPOSTOR) != 0)
        _exit(0);
    if (sc == SC_IMPOSTOR) {
        /* The client must send nothing more: the next read sees its close. */
        proto_frame f;
        FAKE_EXPECT(fake_recv(&s, &f) != 0);
        _exit(0);
    }
    proto_frame f;
    switch (sc) {
    case SC_SUBMIT:
    case SC_SUBMIT_REFUSED:
        fake_submit(&s, sc == SC_SUBMIT_REFUSED);
        break;
    case SC_NOT_FOUND:
        FAKE_EXPECT(fake_recv(&s, &f) == 0 && f.type == PROTO_MSG_STATUS);
        fake_error(&s, PROTO_E_NOT_FOUND, "no job 5");
        break;
    case SC_NONE:
        break;
    default:
        fake_fetch(&s, sc);
    }
    /* Wait for the client to hang up, so that nothing it sent is cut short. */
    while (fake_recv(&s, &f) == 0)
        ;
    _exit(0);
}

/* Starts the fake playing sc; *fd is the client's end. */
static pid_t start_fake(int sc, int *fd)
{
    int sv[2];
    if (socketpair(AF_UNIX, SOCK_STREAM, 0, sv) != 0)
        return -1;
    pid_t pid = fork();
    if (pid == 0) {
        close(sv[0]);
        fake_run(sv[1], sc);
    }
    close(sv[1]);
    *fd = sv[0];
    return pid;
}

static int fake_exit(pid_t pid)
{
    int status = 0;
    if (waitpid(pid, &status, 0) != pid)
        return -1;
    return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
}

static ctl_opts opts_with(const uint8_t *token, size_t len)
{
    ctl_opts o = {"fake:0", token, len, 5000, "tester@here"};
    return o;
}

/* ---- tests ---- */

static void test_handshake(void)
{
    int fd = -1;
    pt_error err = {0};
    ctl_conn *c = NULL;
    ctl_opts o = opts_with(TOKEN, TOKEN_LEN);
    pid_t pid = start_fake(SC_NONE, &fd);
    CHECK(ctl_attach(fd, "fake", &o, &c, &err) == PT_OK && c != NULL);
    CHECKF(err.code == PT_OK, "%s", err.msg);
    CHECK(ctl_server_code(c) == 0 && strcmp(ctl_server_build(c), proto_build_id()) == 0);
    ctl_close(c);
    CHECK(fake_exit(pid) == 0);

    /* A wrong token: refused, the code and text kept. */
    static const uint8_t wrong[] = "not-the-token";
    o = opts_with(wrong, sizeof wrong - 1);
    pid = start_fake(SC_NONE, &fd);
    c = NULL;
    CHECK(ctl_attach(fd, "fake", &o, &c, &err) == PT_ERR_PROTO);
    CHECK(c != NULL && ctl_server_code(c) == PROTO_E_AUTH);
    CHECK(strstr(ctl_server_text(c), "wrong token") != NULL);
    CHECK(strstr(err.msg, "server: authentication failed") != NULL);
    ctl_close(c);
    CHECK(fake_exit(pid) == 0);

    /* A server that cannot prove the token: refused by the client, which
     * sends it nothing after AUTH. */
    o = opts_with(TOKEN, TOKEN_LEN);
    pid = start_fake(SC_IMPOSTOR, &fd);
    c = NULL;
    CHECK(ctl_attach(fd, "fake", &o, &c, &err) == PT_ERR_AUTH && c == NULL);
    CHECKF(strstr(err.msg, "does not know the token") != NULL, "%s", err.msg);
    CHECK(fake_exit(pid) == 0);

    /* An empty token is what a coordinator without one expects. */
    o = opts_with(NULL, 0);
    pid = start_fake(SC_NONE, &fd);
    CHECK(ctl_attach(fd, "fake", &o, &c, &err) == PT_ERR_PROTO);
    ctl_close(c);
    CHECK(fake_exit(pid) == 0);
}

static void test_submit(void)
{
    for (int refuse = 0; refuse < 2; refuse++) {
        int fd = -1;
        pt_error err = {0};
        ctl_conn *c = NULL;
        ctl_opts o = opts_with(TOKEN, TOKEN_LEN);
        pid_t pid = start_fake(refuse ? SC_SUBMIT_REFUSED : SC_SUBMIT, &fd);
        CHECK(ctl_attach(fd, "fake", &o, &c, &err) == PT_OK);
        pt_bundle b;
        b.data = pattern(BUNDLE_SIZE, 3);
        b.size = BUNDLE_SIZE;
        pt_sha256_hex(b.data, b.size, b.hash);
        proto_submit m;
        memset(&m, 0, sizeof m);
        strcpy(m.name, "box");
        m.spp = 32;
        m.priority = -2;
        m.bundle_size = b.size;
        CHECK(ctl_hex_to_hash(b.hash, m.bundle_hash) == 0);
        uint64_t id = 0;
        pt_status st = ctl_submit(c, &m, &b, NULL, NULL, &id, &err);
        if (!refuse) {
            CHECKF(st == PT_OK && id == 77, "%s", err.msg);
        } else {
            CHECK(st == PT_ERR_PROTO && ctl_server_code(c) == PROTO_E_LIMIT);
            CHECKF(strstr(err.msg, "over the 1 MiB cap") != NULL, "%s", err.msg);
        }
        free(b.data);
        ctl_close(c);
        CHECK(fake_exit(pid) == 0);
    }
}

static void test_fetch(void)
{
    static const struct {
        int sc;
        const char *want; /* NULL: success */
    } cases[] = {
        {SC_FETCH_GOOD, NULL},
        {SC_FETCH_BAD_HASH, "SHA-256"},
        {SC_FETCH_ORDER, "out of order"},
        {SC_FETCH_TOTAL, "total size changed"},
        {SC_FETCH_HUGE, "at most"},
        {SC_FETCH_EMPTY, "empty chunk"},
        {SC_FETCH_WRONG_TYPE, "SCENE_CHUNK"},
    };
    int64_t live = pt_alloc_live();
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        int fd = -1;
        pt_error err = {0};
        ctl_conn *c = NULL;
        ctl_opts o = opts_with(TOKEN, TOKEN_LEN);
        pid_t pid = start_fake(cases[i].sc, &fd);
        CHECK(ctl_attach(fd, "fake", &o, &c, &err) == PT_OK);
        uint8_t *data = (uint8_t *)&err; /* must stay untouched on failure */
        size_t size = 12345;
        pt_status st = ctl_fetch(c, 5, NULL, NULL, &data, &size, &err);
        if (!cases[i].want) {
            CHECKF(st == PT_OK, "%s", err.msg);
            uint8_t *want = pattern(IMAGE_SIZE, 7);
            CHECK(st == PT_OK && size == IMAGE_SIZE && memcmp(data, want, size) == 0);
            free(want);
            if (st == PT_OK)
                pt_free(data);
        } else {
            CHECKF(st == PT_ERR_PROTO && strstr(err.msg, cases[i].want), "case %zu: %s", i,
                   err.msg);
            CHECK(data == (uint8_t *)&err && size == 12345);
        }
        ctl_close(c);
        CHECK(fake_exit(pid) == 0);
        CHECKF(pt_alloc_live() == live, "case %zu leaks", i);
    }
}

static void test_not_found(void)
{
    int fd = -1;
    pt_error err = {0};
    ctl_conn *c = NULL;
    ctl_opts o = opts_with(TOKEN, TOKEN_LEN);
    pid_t pid = start_fake(SC_NOT_FOUND, &fd);
    CHECK(ctl_attach(fd, "fake", &o, &c, &err) == PT_OK);
    static proto_job_info j;
    CHECK(ctl_status(c, 5, &j, &err) == PT_ERR_PROTO);
    CHECK(ctl_server_code(c) == PROTO_E_NOT_FOUND && strcmp(ctl_server_text(c), "no job 5") == 0);
    ctl_close(c);
    CHECK(fake_exit(pid) == 0);
}

/* ---- helpers ---- */

static char *json_of(const char *s)
{
    static char out[4096];
    FILE *f = fmemopen(out, sizeof out, "w");
    ctl_json_string(f, s);
    fclose(f);
    return out;
}

static void test_json(void)
{
    CHECK(strcmp(json_of("plain"), "\"plain\"") == 0);
    CHECK(strcmp(json_of("a\"b\\c"), "\"a\\\"b\\\\c\"") == 0);
    CHECK(strcmp(json_of("t\tn\nr\r\x01\x1f"), "\"t\\tn\\nr\\r\\u0001\\u001f\"") == 0);
    /* Well-formed UTF-8 passes: é, €, U+10FFFF. */
    CHECK(strcmp(json_of("\xc3\xa9\xe2\x82\xac\xf4\x8f\xbf\xbf"),
                 "\"\xc3\xa9\xe2\x82\xac\xf4\x8f\xbf\xbf\"") == 0);
    /* Malformed: a lone continuation byte, an overlong '/', a surrogate, past
     * U+10FFFF, a sequence cut short by the end. */
    CHECK(strcmp(json_of("a\x80z"), "\"a\\ufffdz\"") == 0);
    CHECK(strcmp(json_of("\xc0\xaf"), "\"\\ufffd\\ufffd\"") == 0);
    CHECK(strcmp(json_of("\xed\xa0\x80"), "\"\\ufffd\\ufffd\\ufffd\"") == 0);
    CHECK(strcmp(json_of("\xf4\x90\x80\x80"), "\"\\ufffd\\ufffd\\ufffd\\ufffd\"") == 0);
    CHECK(strcmp(json_of("x\xe2\x82"), "\"x\\ufffd\\ufffd\"") == 0);

    static proto_job_info j;
    memset(&j, 0, sizeof j);
    j.job_id = 12;
    j.state = PROTO_JOB_FAILED;
    j.priority = -4;
    strcpy(j.name, "n\"q");
    strcpy(j.message, "line1\nline2");
    j.error = -1.0;
    j.rate = 0.1;
    char out[4096];
    FILE *f = fmemopen(out, sizeof out, "w");
    ctl_json_job(f, &j);
    fclose(f);
    CHECK(strstr(out, "\"id\": 12,") && strstr(out, "\"state\": \"failed\""));
    CHECK(strstr(out, "\"priority\": -4,") && strstr(out, "\"name\": \"n\\\"q\""));
    CHECK(strstr(out, "\"error\": null") && strstr(out, "\"message\": \"line1\\nline2\"}"));
    CHECK(strstr(out, "\"samples_per_second\": 0.1,") != NULL);
}

static void test_format(void)
{
    char b[256];
    ctl_format_duration(0, b, sizeof b);
    CHECK(strcmp(b, "0s") == 0);
    ctl_format_duration(59.4, b, sizeof b);
    CHECK(strcmp(b, "59s") == 0);
    ctl_format_duration(723, b, sizeof b);
    CHECK(strcmp(b, "12m03s") == 0);
    ctl_format_duration(3 * 3600 + 7 * 60 + 5, b, sizeof b);
    CHECK(strcmp(b, "3h07m") == 0);
    ctl_format_duration(2 * 86400 + 5 * 3600, b, sizeof b);
    CHECK(strcmp(b, "2d05h") == 0);
    ctl_format_duration(-1, b, sizeof b);
    CHECK(strcmp(b, "-") == 0);
    ctl_format_duration(INFINITY, b, sizeof b);
    CHECK(strcmp(b, "-") == 0);

    static proto_job_info j;
    memset(&j, 0, sizeof j);
    j.job_id = 3;
    j.state = PROTO_JOB_QUEUED;
    j.queue_pos = 2;
    ctl_progress_line(&j, b, sizeof b);
    CHECK(strcmp(b, "job 3 queued, position 2") == 0);
    j.state = PROTO_JOB_RUNNING;
    j.width = 10;
    j.height = 10;
    j.spp = 100;
    j.samples_total = 10000;
    j.samples_done = 2500;
    j.rate = 1500.0;
    j.workers = 3;
    j.error = 0.0125;
    ctl_progress_line(&j, b, sizeof b);
    CHECKF(strstr(b, "[######------------------] 25.0/100 spp  25.0%") == b, "%s", b);
    CHECKF(strstr(b, "1.50 k samples/s  3 workers  ETA 5s  err 1.25%") != NULL, "%s", b);
    j.rate = 0.0;
    j.error = -1.0;
    ctl_progress_line(&j, b, sizeof b);
    CHECKF(strstr(b, "- samples/s") && strstr(b, "ETA -") && !strstr(b, "err"), "%s", b);
    j.state = PROTO_JOB_DONE;
    j.seconds = 75;
    ctl_progress_line(&j, b, sizeof b);
    CHECKF(strstr(b, "100.0%  done in 1m15s") != NULL, "%s", b);
    /* A small buffer is filled, never overrun. */
    char small[16];
    memset(small, 'Z', sizeof small);
    ctl_progress_line(&j, small, 10);
    CHECK(strlen(small) == 9 && small[10] == 'Z');

    char p[16];
    ctl_printable("a\x1b[2Jb\x7f", p, sizeof p);
    CHECK(strcmp(p, "a?[2Jb?") == 0);
    ctl_printable("abcdef", p, 4);
    CHECK(strcmp(p, "abc") == 0);

    uint8_t h[32];
    CHECK(ctl_hex_to_hash("00ff10AB00000000000000000000000000000000000000000000000000000001", h) ==
          0);
    CHECK(h[1] == 0xff && h[3] == 0xab && h[31] == 1);
    CHECK(ctl_hex_to_hash("00ff", h) == -1);
    CHECK(ctl_hex_to_hash("g0ff10AB00000000000000000000000000000000000000000000000000000001", h) ==
          -1);

    char name[PROTO_MAX_NAME + 1];
    ctl_default_name(name);
    CHECK(strchr(name, '@') != NULL && strlen(name) <= PROTO_MAX_NAME);
}

static int count_entries(const char *dir)
{
    DIR *d = opendir(dir);
    int n = 0;
    if (!d)
        return -1;
    for (struct dirent *e; (e = readdir(d));)
        n += strcmp(e->d_name, ".") != 0 && strcmp(e->d_name, "..") != 0;
    closedir(d);
    return n;
}

static void test_write_atomic(void)
{
    umask(022);
    char dir[] = "/tmp/test_ctl_XXXXXX";
    CHECK(mkdtemp(dir) != NULL);
    char path[128], bad[160];
    snprintf(path, sizeof path, "%s/out.exr", dir);
    pt_error err = {0};
    CHECK(ctl_write_atomic(path, (const uint8_t *)"first", 5, &err) == PT_OK);
    CHECK(ctl_write_atomic(path, (const uint8_t *)"second!", 7, &err) == PT_OK);
    char buf[16] = {0};
    FILE *f = fopen(path, "rb");
    CHECK(f && fread(buf, 1, sizeof buf, f) == 7 && memcmp(buf, "second!", 7) == 0);
    if (f)
        fclose(f);
    CHECK(count_entries(dir) == 1); /* no temporary left */
    struct stat st;
    CHECK(stat(path, &st) == 0 && (st.st_mode & 0444) != 0400);
    snprintf(bad, sizeof bad, "%s/missing/out.exr", dir);
    CHECK(ctl_write_atomic(bad, (const uint8_t *)"x", 1, &err) == PT_ERR_IO);
    CHECK(strstr(err.msg, "missing") != NULL);
    /* The target is a folder: the rename fails, the temporary is removed. */
    snprintf(bad, sizeof bad, "%s/sub", dir);
    CHECK(mkdir(bad, 0755) == 0);
    CHECK(ctl_write_atomic(bad, (const uint8_t *)"x", 1, &err) == PT_ERR_IO);
    CHECK(count_entries(dir) == 2);
    CHECK(ctl_write_atomic("", (const uint8_t *)"x", 1, &err) == PT_ERR_ARG);
    rmdir(bad);
    unlink(path);
    rmdir(dir);
}

int main(void)
{
    test_handshake();
    test_submit();
    test_fetch();
    test_not_found();
    test_json();
    test_format();
    test_write_atomic();
    return check_report();
}
