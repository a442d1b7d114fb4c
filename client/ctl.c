#include "client/ctl.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <math.h>
#include <poll.h>
#include <pwd.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/time.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/base/hash.h"
#include "common/base/net.h"
#include "common/base/text.h"
#include "protocol/auth.h"
#include "protocol/frame.h"
#include "protocol/jobjson.h"

#define IN_START ((size_t)64 << 10)
#define IN_MAX ((size_t)PROTO_MAX_PAYLOAD + PROTO_FRAME_OVERHEAD)

struct ctl_conn {
    int fd;
    char addr[300]; /* "host:port", for messages */
    int timeout_ms;
    uint32_t cap; /* payload cap: pre-authentication until WELCOME */
    proto_frame_reader in;
    proto_writer out;
    uint16_t server_code;
    char server_text[PROTO_MAX_ERROR_TEXT + 1];
    char server_build[PROTO_MAX_BUILD_ID + 1];
};

uint16_t ctl_server_code(const ctl_conn *c)
{
    return c ? c->server_code : 0;
}

const char *ctl_server_text(const ctl_conn *c)
{
    return c ? c->server_text : "";
}

const char *ctl_server_build(const ctl_conn *c)
{
    return c ? c->server_build : "";
}

void ctl_close(ctl_conn *c)
{
    if (!c)
        return;
    if (c->fd >= 0)
        close(c->fd);
    proto_frame_reader_fini(&c->in);
    proto_writer_fini(&c->out);
    pt_free(c);
}

/* ---- frames ---- */

/* Sends everything in c->out, then empties it. */
static pt_status flush_out(ctl_conn *c, pt_error *err)
{
    const uint8_t *p = c->out.buf;
    size_t n = c->out.len;
    while (n > 0) {
        ssize_t k = send(c->fd, p, n, MSG_NOSIGNAL);
        if (k < 0 && errno == EINTR)
            continue;
        if (k < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
            proto_writer_reset(&c->out);
            return pt_error_set(err, PT_ERR_IO, "%s accepted no data for %g s", c->addr,
                                c->timeout_ms / 1000.0);
        }
        if (k <= 0) {
            proto_writer_reset(&c->out);
            return pt_error_errno(err, PT_ERR_IO, "cannot send to %s", c->addr);
        }
        p += k;
        n -= (size_t)k;
    }
    proto_writer_reset(&c->out);
    return PT_OK;
}

/* Ends the frame begun at mark with the encoder's status (proto_frame_finish)
 * and sends it. */
static pt_status send_frame(ctl_conn *c, size_t mark, pt_status encoded, pt_error *err)
{
    pt_status st = proto_frame_finish(&c->out, mark, encoded, err);
    return st == PT_OK ? flush_out(c, err) : st;
}

/* Reads more bytes into c->in, which grows to the frame being received. */
static pt_status read_more(ctl_conn *c, pt_error *err)
{
    uint8_t *p;
    size_t room;
    pt_error e = {0};
    pt_status st = proto_frame_reader_space(&c->in, &p, &room, &e);
    if (st != PT_OK)
        return pt_error_set(err, st, "%s: %s", c->addr, e.msg);
    for (;;) {
        ssize_t n = recv(c->fd, p, room, 0);
        if (n > 0) {
            proto_frame_reader_commit(&c->in, (size_t)n);
            return PT_OK;
        }
        if (n == 0)
            return pt_error_set(err, PT_ERR_IO, "%s closed the connection", c->addr);
        if (errno == EINTR)
            continue;
        if (errno == EAGAIN || errno == EWOULDBLOCK)
            return pt_error_set(err, PT_ERR_IO, "no reply from %s within %g s", c->addr,
                                c->timeout_ms / 1000.0);
        return pt_error_errno(err, PT_ERR_IO, "cannot read from %s", c->addr);
    }
}

/* Receives the next frame; its payload is borrowed until the next call. An
 * ERROR frame is recorded (code, text) and returned as PT_ERR_PROTO. */
static pt_status recv_frame(ctl_conn *c, proto_frame *f, pt_error *err)
{
    for (;;) {
        pt_error e = {0};
        pt_status st = proto_frame_reader_next(&c->in, c->cap, f, &e);
        if (st == PT_OK)
            break;
        if (st != PT_AGAIN)
            return pt_error_set(err, PT_ERR_PROTO, "%s sent a bad frame: %s", c->addr, e.msg);
        st = read_more(c, err);
        if (st != PT_OK)
            return st;
    }
    if (f->type != PROTO_MSG_ERROR)
        return PT_OK;
    proto_error_msg m;
    pt_error e = {0};
    if (proto_msg_decode_error(f->payload, f->len, &m, &e) != PT_OK)
        return pt_error_set(err, PT_ERR_PROTO, "%s sent a bad ERROR: %s", c->addr, e.msg);
    c->server_code = m.code ? m.code : PROTO_E_INTERNAL;
    snprintf(c->server_text, sizeof c->server_text, "%s", m.text[0] ? m.text : "(no reason)");
    char text[sizeof err->msg - 16];
    return pt_error_set(err, PT_ERR_PROTO, "server: %s",
                        pt_text_shown(c->server_text, text, sizeof text));
}

static pt_status unexpected(ctl_conn *c, const proto_frame *f, const char *waiting, pt_error *err)
{
    return pt_error_set(err, PT_ERR_PROTO, "%s sent %s while %s was awaited", c->addr,
                        proto_msg_type_name(f->type), waiting);
}

/* Receives a frame that must be of type want. */
static pt_status recv_type(ctl_conn *c, uint16_t want, proto_frame *f, pt_error *err)
{
    pt_status st = recv_frame(c, f, err);
    if (st != PT_OK)
        return st;
    if (f->type != want)
        return unexpected(c, f, proto_msg_type_name(want), err);
    return PT_OK;
}

static pt_status bad_reply(ctl_conn *c, const char *what, const pt_error *e, pt_error *err)
{
    return pt_error_set(err, PT_ERR_PROTO, "%s sent a bad %s: %s", c->addr, what, e->msg);
}

/* ---- connecting ---- */

static pt_status set_timeouts(int fd, int timeout_ms, pt_error *err)
{
    struct timeval tv;
    tv.tv_sec = timeout_ms / 1000;
    tv.tv_usec = (timeout_ms % 1000) * 1000;
    if (setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv) != 0 ||
        setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv) != 0)
        return pt_error_errno(err, PT_ERR_IO, "socket timeouts");
    return PT_OK;
}

static pt_status handshake(ctl_conn *c, const ctl_opts *o, pt_error *err)
{
    proto_hello h;
    memset(&h, 0, sizeof h);
    h.version = PROTO_VERSION;
    h.role = PROTO_ROLE_CLIENT;
    snprintf(h.name, sizeof h.name, "%s", o->name ? o->name : "");
    h.threads = 0;
    snprintf(h.build_id, sizeof h.build_id, "%s", proto_build_id());
    h.caps = 0;
    size_t mark;
    pt_status st = proto_frame_begin(&c->out, PROTO_MSG_HELLO, &mark, err);
    if (st == PT_OK)
        st = send_frame(c, mark, proto_msg_encode_hello(&c->out, &h, err), err);
    if (st != PT_OK)
        return st;

    proto_frame f;
    pt_error e = {0};
    st = recv_type(c, PROTO_MSG_CHALLENGE, &f, err);
    if (st != PT_OK)
        return st;
    proto_challenge ch;
    if (proto_msg_decode_challenge(f.payload, f.len, &ch, &e) != PT_OK)
        return bad_reply(c, "CHALLENGE", &e, err);
    proto_auth a;
    st = proto_auth_response(o->token, o->token_len, ch.nonce, a.mac, err);
    if (st == PT_OK)
        st = proto_auth_nonce(a.nonce, err);
    if (st != PT_OK)
        return st;
    st = proto_frame_begin(&c->out, PROTO_MSG_AUTH, &mark, err);
    if (st == PT_OK)
        st = send_frame(c, mark, proto_msg_encode_auth(&c->out, &a, err), err);
    if (st != PT_OK)
        return st;

    st = recv_type(c, PROTO_MSG_WELCOME, &f, err);
    if (st != PT_OK)
        return st;
    proto_welcome w;
    if (proto_msg_decode_welcome(f.payload, f.len, &w, &e) != PT_OK)
        return bad_reply(c, "WELCOME", &e, err);
    /* Nothing is sent to a listener that cannot prove it holds the token:
     * a scene submitted to it would leak, a cancel would be lost. */
    if (proto_auth_check_server(o->token, o->token_len, ch.nonce, a.nonce, w.proof, &e) != PT_OK)
        return pt_error_set(err, PT_ERR_AUTH,
                            "%s: the coordinator does not know the token (its WELCOME proof is "
                            "wrong); nothing was sent to it",
                            c->addr);
    snprintf(c->server_build, sizeof c->server_build, "%s", w.build_id);
    c->cap = PROTO_MAX_PAYLOAD;
    return PT_OK;
}

pt_status ctl_attach(int fd, const char *addr, const ctl_opts *o, ctl_conn **out, pt_error *err)
{
    *out = NULL;
    ctl_conn *c = pt_calloc(1, sizeof *c);
    if (!c) {
        close(fd);
        return pt_error_set(err, PT_ERR_NOMEM, "connection state");
    }
    c->fd = fd;
    snprintf(c->addr, sizeof c->addr, "%s", addr);
    c->timeout_ms = o->timeout_ms > 0 ? o->timeout_ms : CTL_DEFAULT_TIMEOUT_MS;
    c->cap = PROTO_MAX_PAYLOAD_PREAUTH;
    proto_frame_reader_init(&c->in, IN_START, IN_MAX);
    /* One UPLOAD frame at most is queued at a time. */
    proto_writer_init(&c->out, (size_t)PROTO_MAX_SCENE_CHUNK + 4096);
    pt_status st = set_timeouts(fd, c->timeout_ms, err);
    if (st == PT_OK)
        st = handshake(c, o, err);
    if (st != PT_OK && !c->server_code) {
        ctl_close(c);
        return st;
    }
    *out = c;
    return st;
}

pt_status ctl_connect(const ctl_opts *o, ctl_conn **out, pt_error *err)
{
    *out = NULL;
    char host[256];
    uint16_t port = 0;
    pt_status st = pt_net_split(o->server, host, sizeof host, &port, err);
    if (st != PT_OK)
        return st;
    if (!host[0])
        snprintf(host, sizeof host, "127.0.0.1");
    int timeout_ms = o->timeout_ms > 0 ? o->timeout_ms : CTL_DEFAULT_TIMEOUT_MS;
    int fd = -1;
    st = pt_net_connect(host, port, timeout_ms, &fd, err);
    if (st != PT_OK)
        return st;
    char addr[300];
    snprintf(addr, sizeof addr, strchr(host, ':') ? "[%s]:%u" : "%s:%u", host, (unsigned)port);
    return ctl_attach(fd, addr, o, out, err);
}

/* ---- requests ---- */

static pt_status send_job_ref(ctl_conn *c, uint16_t type, uint64_t job_id, pt_error *err)
{
    proto_job_ref r = {job_id};
    size_t mark;
    pt_status st = proto_frame_begin(&c->out, type, &mark, err);
    if (st == PT_OK)
        st = send_frame(c, mark, proto_msg_encode_job_ref(&c->out, &r, err), err);
    return st;
}

static pt_status recv_job_info(ctl_conn *c, proto_job_info *out, pt_error *err)
{
    proto_frame f;
    pt_status st = recv_type(c, PROTO_MSG_JOB_INFO, &f, err);
    if (st != PT_OK)
        return st;
    pt_error e = {0};
    if (proto_msg_decode_job_info(f.payload, f.len, out, &e) != PT_OK)
        return bad_reply(c, "JOB_INFO", &e, err);
    return PT_OK;
}

pt_status ctl_status(ctl_conn *c, uint64_t job_id, proto_job_info *out, pt_error *err)
{
    pt_status st = send_job_ref(c, PROTO_MSG_STATUS, job_id, err);
    return st != PT_OK ? st : recv_job_info(c, out, err);
}

pt_status ctl_cancel(ctl_conn *c, uint64_t job_id, proto_job_info *out, pt_error *err)
{
    pt_status st = send_job_ref(c, PROTO_MSG_CANCEL, job_id, err);
    return st != PT_OK ? st : recv_job_info(c, out, err);
}

pt_status ctl_watch_begin(ctl_conn *c, uint64_t job_id, pt_error *err)
{
    return send_job_ref(c, PROTO_MSG_WATCH, job_id, err);
}

pt_status ctl_watch_next(ctl_conn *c, proto_job_info *out, pt_error *err)
{
    return recv_job_info(c, out, err);
}

pt_status ctl_list(ctl_conn *c, proto_job_list *out, pt_error *err)
{
    pt_status st = proto_frame_encode(&c->out, PROTO_MSG_LIST, NULL, 0, err);
    if (st == PT_OK)
        st = flush_out(c, err);
    if (st != PT_OK)
        return st;
    proto_frame f;
    st = recv_type(c, PROTO_MSG_JOB_LIST, &f, err);
    if (st != PT_OK)
        return st;
    pt_error e = {0};
    st = proto_msg_decode_job_list(f.payload, f.len, out, &e);
    if (st == PT_ERR_NOMEM)
        return pt_error_set(err, st, "%s", e.msg);
    if (st != PT_OK)
        return bad_reply(c, "JOB_LIST", &e, err);
    return PT_OK;
}

/* While uploading, the server only speaks to refuse: a frame waiting is read
 * (an ERROR ends the upload with its reason). */
static pt_status check_refusal(ctl_conn *c, pt_error *err)
{
    struct pollfd p = {c->fd, POLLIN, 0};
    if (poll(&p, 1, 0) <= 0)
        return PT_OK;
    proto_frame f;
    pt_status st = recv_frame(c, &f, err);
    if (st != PT_OK)
        return st;
    return unexpected(c, &f, "the upload", err);
}

pt_status ctl_submit(ctl_conn *c, const proto_submit *m, const pt_bundle *b,
                     ctl_progress_fn progress, void *arg, uint64_t *job_id, pt_error *err)
{
    if (m->bundle_size != b->size)
        return pt_error_set(err, PT_ERR_ARG, "SUBMIT: bundle size differs from the bundle's");
    size_t mark;
    pt_status st = proto_frame_begin(&c->out, PROTO_MSG_SUBMIT, &mark, err);
    if (st == PT_OK)
        st = send_frame(c, mark, proto_msg_encode_submit(&c->out, m, err), err);
    if (st != PT_OK)
        return st;
    proto_scene_chunk ch;
    memcpy(ch.hash, m->bundle_hash, PROTO_HASH_SIZE);
    ch.total = b->size;
    for (size_t off = 0; off < b->size;) {
        size_t n = b->size - off;
        if (n > PROTO_MAX_SCENE_CHUNK)
            n = PROTO_MAX_SCENE_CHUNK;
        ch.offset = off;
        ch.len = (uint32_t)n;
        ch.data = b->data + off;
        st = check_refusal(c, err);
        if (st != PT_OK)
            return st;
        st = proto_frame_begin(&c->out, PROTO_MSG_UPLOAD, &mark, err);
        if (st == PT_OK)
            st = send_frame(c, mark, proto_msg_encode_scene_chunk(&c->out, &ch, err), err);
        if (st != PT_OK) {
            /* A server that refused mid-upload has said why before closing. */
            pt_error e2 = {0};
            proto_frame f;
            if (st == PT_ERR_IO && recv_frame(c, &f, &e2) == PT_ERR_PROTO && c->server_code)
                return pt_error_set(err, PT_ERR_PROTO, "%s", e2.msg);
            return st;
        }
        off += n;
        if (progress)
            progress(off, b->size, arg);
    }
    proto_frame f;
    st = recv_type(c, PROTO_MSG_SUBMITTED, &f, err);
    if (st != PT_OK)
        return st;
    proto_job_ref r;
    pt_error e = {0};
    if (proto_msg_decode_job_ref(f.payload, f.len, &r, &e) != PT_OK)
        return bad_reply(c, "SUBMITTED", &e, err);
    *job_id = r.job_id;
    return PT_OK;
}

static pt_status recv_image(ctl_conn *c, ctl_progress_fn progress, void *arg, uint8_t **data,
                            size_t *size, pt_error *err);

pt_status ctl_fetch(ctl_conn *c, uint64_t job_id, ctl_progress_fn progress, void *arg,
                    uint8_t **data, size_t *size, pt_error *err)
{
    pt_status st = send_job_ref(c, PROTO_MSG_FETCH, job_id, err);
    if (st != PT_OK)
        return st;
    return recv_image(c, progress, arg, data, size, err);
}

pt_status ctl_fetch_frame(ctl_conn *c, uint64_t job_id, uint32_t frame, ctl_progress_fn progress,
                          void *arg, uint8_t **data, size_t *size, pt_error *err)
{
    proto_fetch_frame m = {job_id, frame};
    size_t mark;
    pt_status st = proto_frame_begin(&c->out, PROTO_MSG_FETCH_FRAME, &mark, err);
    if (st == PT_OK)
        st = send_frame(c, mark, proto_msg_encode_fetch_frame(&c->out, &m, err), err);
    if (st != PT_OK)
        return st;
    return recv_image(c, progress, arg, data, size, err);
}

/* The IMAGE frames answering a FETCH or FETCH_FRAME (ctl_fetch). */
static pt_status recv_image(ctl_conn *c, ctl_progress_fn progress, void *arg, uint8_t **data,
                            size_t *size, pt_error *err)
{
    pt_status st;
    uint8_t *buf = NULL;
    size_t have = 0, cap = 0;
    uint64_t total = 0;
    uint8_t hash[PROTO_HASH_SIZE];
    do {
        proto_frame f;
        st = recv_type(c, PROTO_MSG_IMAGE, &f, err);
        if (st != PT_OK)
            goto fail;
        proto_scene_chunk ch;
        pt_error e = {0};
        if (proto_msg_decode_scene_chunk(f.payload, f.len, &ch, &e) != PT_OK) {
            st = bad_reply(c, "IMAGE", &e, err);
            goto fail;
        }
        if (have == 0 && total == 0) {
            if (ch.total == 0 || ch.total > CTL_MAX_IMAGE) {
                st = pt_error_set(err, PT_ERR_PROTO, "%s: IMAGE of %llu bytes (at most %llu)",
                                  c->addr, (unsigned long long)ch.total,
                                  (unsigned long long)CTL_MAX_IMAGE);
                goto fail;
            }
            total = ch.total;
            memcpy(hash, ch.hash, PROTO_HASH_SIZE);
        }
        const char *why = NULL;
        if (ch.total != total)
            why = "the total size changed";
        else if (memcmp(ch.hash, hash, PROTO_HASH_SIZE) != 0)
            why = "the hash changed";
        else if (ch.offset != have)
            why = "a chunk out of order";
        else if (ch.len == 0)
            why = "an empty chunk";
        if (why) {
            st = pt_error_set(err, PT_ERR_PROTO, "%s: IMAGE at offset %llu: %s", c->addr,
                              (unsigned long long)ch.offset, why);
            goto fail;
        }
        /* Grow with what arrives, not with what the header promises. */
        if (have + ch.len > cap) {
            size_t ncap = cap ? cap * 2 : (size_t)PROTO_MAX_SCENE_CHUNK;
            if (ncap < have + ch.len)
                ncap = have + ch.len;
            if (ncap > total)
                ncap = (size_t)total;
            uint8_t *nb = pt_realloc(buf, ncap);
            if (!nb) {
                st = pt_error_set(err, PT_ERR_NOMEM, "image buffer of %zu bytes", ncap);
                goto fail;
            }
            buf = nb;
            cap = ncap;
        }
        memcpy(buf + have, ch.data, ch.len);
        have += ch.len;
        if (progress)
            progress(have, total, arg);
    } while (have < total);
    char want[65], got[65];
    pt_hash_hex(hash, want);
    pt_sha256_hex(buf, have, got);
    if (strcmp(want, got) != 0) {
        st = pt_error_set(err, PT_ERR_PROTO,
                          "%s: the image's SHA-256 is %s, the server announced %s", c->addr, got,
                          want);
        goto fail;
    }
    *data = buf;
    *size = have;
    return PT_OK;
fail:
    pt_free(buf);
    return st;
}

/* ---- helpers ---- */

pt_status ctl_write_atomic(const char *path, const uint8_t *data, size_t size, pt_error *err)
{
    /* An image is as readable as any new file of the user's would be. */
    return pt_write_file_atomic_mode(path, data, size, 0666, err);
}

int ctl_hex_to_hash(const char *hex, uint8_t out[PROTO_HASH_SIZE])
{
    return pt_hex_decode(hex, out, PROTO_HASH_SIZE);
}

void ctl_default_name(char out[PROTO_MAX_NAME + 1])
{
    const char *user = getlogin();
    if (!user || !*user) {
        struct passwd *pw = getpwuid(geteuid());
        user = pw && pw->pw_name && *pw->pw_name ? pw->pw_name : "user";
    }
    char host[256];
    if (gethostname(host, sizeof host) != 0 || !host[0])
        snprintf(host, sizeof host, "localhost");
    host[sizeof host - 1] = '\0';
    /* Cut to the cap: the user to 40 bytes, the host to what is left. */
    size_t nu = strnlen(user, 40), nh = strlen(host);
    if (nh > PROTO_MAX_NAME - 1 - nu)
        nh = PROTO_MAX_NAME - 1 - nu;
    memcpy(out, user, nu);
    out[nu] = '@';
    memcpy(out + nu + 1, host, nh);
    out[nu + 1 + nh] = '\0';
}

int ctl_job_ended(uint8_t state)
{
    return state == PROTO_JOB_DONE || state == PROTO_JOB_CANCELLED || state == PROTO_JOB_FAILED;
}

double ctl_job_fraction(const proto_job_info *j)
{
    return proto_job_fraction(j);
}

void ctl_json_string(FILE *f, const char *s)
{
    proto_json_string(f, s);
}

void ctl_json_job(FILE *f, const proto_job_info *j)
{
    proto_json_job(f, j);
}

void ctl_printable(const char *s, char *out, size_t cap)
{
    if (cap == 0)
        return;
    size_t i = 0;
    for (; s[i] && i + 1 < cap; i++) {
        unsigned char c = (unsigned char)s[i];
        out[i] = c < 0x20 || c == 0x7F ? '?' : (char)c;
    }
    out[i] = '\0';
}

void ctl_format_duration(double s, char *out, size_t cap)
{
    if (!(s >= 0.0) || !isfinite(s) || s > 1e12) {
        snprintf(out, cap, "-");
        return;
    }
    unsigned long long t = (unsigned long long)(s + 0.5);
    if (t < 60)
        snprintf(out, cap, "%llus", t);
    else if (t < 3600)
        snprintf(out, cap, "%llum%02llus", t / 60, t % 60);
    else if (t < 86400)
        snprintf(out, cap, "%lluh%02llum", t / 3600, t / 60 % 60);
    else
        snprintf(out, cap, "%llud%02lluh", t / 86400, t / 3600 % 24);
}

/* Appends to out[*len, cap) like snprintf, never past the end. */
static void append(char *out, size_t cap, size_t *len, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));

static void append(char *out, size_t cap, size_t *len, const char *fmt, ...)
{
    if (*len + 1 >= cap)
        return;
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(out + *len, cap - *len, fmt, ap);
    va_end(ap);
    if (n > 0)
        *len += (size_t)n < cap - *len ? (size_t)n : cap - *len - 1;
}

static void format_rate(double r, char *out, size_t cap)
{
    if (!(r > 0.0) || !isfinite(r))
        snprintf(out, cap, "- samples/s");
    else if (r >= 1e9)
        snprintf(out, cap, "%.2f G samples/s", r / 1e9);
    else if (r >= 1e6)
        snprintf(out, cap, "%.2f M samples/s", r / 1e6);
    else if (r >= 1e3)
        snprintf(out, cap, "%.2f k samples/s", r / 1e3);
    else
        snprintf(out, cap, "%.0f samples/s", r);
}

void ctl_progress_line(const proto_job_info *j, char *out, size_t cap)
{
    size_t len = 0;
    if (cap == 0)
        return;
    out[0] = '\0';
    if (j->state == PROTO_JOB_QUEUED) {
        if (j->queue_pos > 0)
            append(out, cap, &len, "job %llu queued, position %lu", (unsigned long long)j->job_id,
                   (unsigned long)j->queue_pos);
        else
            append(out, cap, &len, "job %llu queued", (unsigned long long)j->job_id);
        return;
    }
    double frac = ctl_job_fraction(j);
    enum { BAR = 24 };
    int fill = (int)(frac * BAR + 1e-9);
    char bar[BAR + 1];
    for (int i = 0; i < BAR; i++)
        bar[i] = i < fill ? '#' : '-';
    bar[BAR] = '\0';
    uint64_t pixels = (uint64_t)j->width * j->height;
    double spp_done = pixels ? (double)j->samples_done / (double)pixels : 0.0;
    if (j->frame_step) {
        /* A frame range: frames done, then the earliest frame rendering. */
        uint32_t count = (j->frame_last - j->frame_first) / j->frame_step + 1;
        append(out, cap, &len, "[%s] frames %lu/%lu done %5.1f%%", bar,
               (unsigned long)j->frames_done, (unsigned long)count, 100.0 * frac);
        if (j->nshown > 0 && j->shown[0].samples_total > 0)
            append(out, cap, &len, "  frame %lu %.0f%%", (unsigned long)j->shown[0].frame,
                   100.0 * (double)j->shown[0].samples_done / (double)j->shown[0].samples_total);
    } else {
        append(out, cap, &len, "[%s] %.1f/%lu spp %5.1f%%", bar, spp_done, (unsigned long)j->spp,
               100.0 * frac);
    }
    if (ctl_job_ended(j->state)) {
        char d[32];
        ctl_format_duration(j->seconds, d, sizeof d);
        append(out, cap, &len, "  %s in %s", proto_job_state_name(j->state), d);
        return;
    }
    char r[32], eta[32];
    format_rate(j->rate, r, sizeof r);
    double left = -1.0; /* unknown until there is a rate */
    if (j->rate > 0.0 && isfinite(j->rate))
        left = j->samples_total > j->samples_done
                   ? (double)(j->samples_total - j->samples_done) / j->rate
                   : 0.0;
    ctl_format_duration(left, eta, sizeof eta);
    append(out, cap, &len, "  %s  %lu worker%s  ETA %s", r, (unsigned long)j->workers,
           j->workers == 1 ? "" : "s", eta);
    if (j->error >= 0.0 && isfinite(j->error))
        append(out, cap, &len, "  err %.2f%%", 100.0 * j->error);
}
