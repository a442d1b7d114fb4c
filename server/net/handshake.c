#define _GNU_SOURCE /* epoll, accept4, pipe2 */
#include "server/net/loop_impl.h"

#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <unistd.h>

#include <arpa/inet.h>
#include <netinet/in.h>

#include "common/base/alloc.h"
#include "common/base/net.h"
#include "common/base/text.h"
#include "server/net/clients.h"
#include "server/net/io.h"

/* Sends ERROR(code, text) and closes c, without a log line: for refusals
 * that server/net/authlimit.h logs within its own limits. */
static void handshake_refuse(srv_server *s, srv_conn *c, uint16_t code, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
static void handshake_refuse(srv_server *s, srv_conn *c, uint16_t code, const char *fmt, ...)
{
    proto_error_msg m;
    m.code = code;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(m.text, sizeof m.text, fmt, ap);
    va_end(ap);
    size_t mark;
    if (proto_frame_begin(&c->out, PROTO_MSG_ERROR, &mark, NULL) == PT_OK)
        proto_frame_finish(&c->out, mark, proto_msg_encode_error(&c->out, &m, NULL), NULL);
    srv_conn_close_soon(s, c);
}

/* 1 (and c refused) while c's address is blocked for failed
 * authentications; nothing is computed for it. PROTO_E_LIMIT, not _AUTH: a
 * worker with the right token behind the same address retries later. */
static int handshake_blocked(srv_server *s, srv_conn *c)
{
    char addr[SRV_AUTHLIMIT_ADDR];
    srv_authlimit_addr(c->peer, addr);
    uint64_t ms = srv_authlimit_blocked(&s->guard->authlimit, addr, pt_now_ms());
    if (ms == 0)
        return 0;
    handshake_refuse(s, c, PROTO_E_LIMIT,
                     "too many failed authentications from %s, retry in %llu s", addr,
                     (unsigned long long)((ms + 999) / 1000));
    return 1;
}

void loop_on_hello(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_hello h;
    pt_error err = {0};
    if (handshake_blocked(s, c))
        return;
    if (proto_msg_decode_hello(f->payload, f->len, &h, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad HELLO: %s", err.msg);
        return;
    }
    snprintf(c->name, sizeof c->name, "%s", h.name);
    pt_text_shown(c->name, c->shown, sizeof c->shown);
    if (h.version != PROTO_VERSION) {
        srv_conn_send_error(s, c, PROTO_E_VERSION,
                            "protocol version %u is not supported (this "
                            "coordinator speaks %u)",
                            h.version, PROTO_VERSION);
        return;
    }
    if (h.role == PROTO_ROLE_CLIENT && !s->mode->serves_clients) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL,
                            "this coordinator renders one scene and keeps "
                            "no queue (start ptserve with --state-dir for clients)");
        return;
    }
    if (h.role != PROTO_ROLE_WORKER && h.role != PROTO_ROLE_CLIENT) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "role %u is not served by this coordinator",
                            h.role);
        return;
    }
    /* A client's build does not touch the pixels; a worker's does. */
    if (h.role == PROTO_ROLE_WORKER && strcmp(h.build_id, proto_build_id()) != 0) {
        srv_conn_send_error(s, c, PROTO_E_BUILD,
                            "worker renderer build %s differs from the "
                            "coordinator's %s; mixed builds would break bit-identical merging",
                            h.build_id, proto_build_id());
        return;
    }
    c->role = h.role;
    if (loop_session_of(s, c)->refused && loop_session_of(s, c)->refused(s, c))
        return;
    c->threads = h.threads;
    c->caps = h.caps;
    proto_challenge ch;
    if (proto_auth_nonce(ch.nonce, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "cannot make a nonce: %s", err.msg);
        return;
    }
    memcpy(c->nonce, ch.nonce, sizeof c->nonce);
    size_t mark;
    if (proto_frame_begin(&c->out, PROTO_MSG_CHALLENGE, &mark, NULL) == PT_OK)
        proto_frame_finish(&c->out, mark, proto_msg_encode_challenge(&c->out, &ch, NULL), NULL);
    c->state = SRV_C_AUTH;
}

/* Which token a's MAC proves: the shared one (an admin), else a
 * --clients-file entry's (*ident its NAME). 1 with *key, *key_len set (the
 * token for WELCOME's proof), 0 when none. */
static int auth_match(srv_server *s, srv_conn *c, const proto_auth *a, const uint8_t **key,
                      size_t *key_len, const char **ident)
{
    *ident = NULL;
    if (proto_auth_verify(s->token, s->token_len, c->nonce, a->mac, NULL) == PT_OK) {
        *key = s->token;
        *key_len = s->token_len;
        return 1;
    }
    return s->clients && srv_clients_match(s->clients, c->nonce, a->mac, ident, key, key_len) >= 0;
}

void loop_on_auth(srv_server *s, srv_conn *c, const proto_frame *f)
{
    proto_auth a;
    pt_error err = {0};
    if (proto_msg_decode_auth(f->payload, f->len, &a, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_PROTOCOL, "bad AUTH: %s", err.msg);
        return;
    }
    /* Blocked since its HELLO (parallel handshakes from one address). */
    if (handshake_blocked(s, c))
        return;
    const uint8_t *key;
    size_t key_len;
    const char *ident;
    if (!auth_match(s, c, &a, &key, &key_len, &ident)) {
        char addr[SRV_AUTHLIMIT_ADDR];
        srv_authlimit_addr(c->peer, addr);
        srv_authlimit_failed(&s->guard->authlimit, addr, c->shown, pt_now_ms());
        handshake_refuse(s, c, PROTO_E_AUTH, "authentication failed (wrong token)");
        return;
    }
    /* Workers get leases and scenes: only the shared token may join as one. */
    if (ident && c->role == PROTO_ROLE_WORKER) {
        srv_conn_send_error(s, c, PROTO_E_AUTH,
                            "the token of client %s cannot join as a worker; workers "
                            "use the shared token (--token-file)",
                            ident);
        return;
    }
    proto_welcome w;
    w.session_id = c->id;
    snprintf(w.build_id, sizeof w.build_id, "%s", proto_build_id());
    if (proto_auth_server_proof(key, key_len, c->nonce, a.nonce, w.proof, &err) != PT_OK) {
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "cannot prove the token: %s", err.msg);
        return;
    }
    /* The role's session takes the peer from here on, with its own state. */
    const srv_session *ops = loop_session_of(s, c);
    void *session = ops->open ? ops->open(s, c) : NULL;
    if (ops->open && !session) {
        srv_conn_send_error(s, c, PROTO_E_INTERNAL, "out of memory");
        return;
    }
    size_t mark;
    if (proto_frame_begin(&c->out, PROTO_MSG_WELCOME, &mark, NULL) == PT_OK)
        proto_frame_finish(&c->out, mark, proto_msg_encode_welcome(&c->out, &w, NULL), NULL);
    c->state = SRV_C_READY;
    c->ops = ops;
    c->session = session;
    c->admin = ident == NULL;
    if (ident && strcmp(ident, c->name) != 0) {
        char id_shown[PT_TEXT_ESCAPED_SIZE(PROTO_MAX_NAME)];
        pt_text_shown(ident, id_shown, sizeof id_shown);
        if (!s->cfg->quiet)
            srv_log("client %s from %s authenticated as %s", c->shown, c->peer, id_shown);
        snprintf(c->name, sizeof c->name, "%s", ident);
        memcpy(c->shown, id_shown, sizeof c->shown);
    }
    if (c->role == PROTO_ROLE_WORKER) {
        s->nworkers++;
        if (!s->cfg->quiet) {
            srv_log("worker %s joined from %s (%u threads)", c->shown, c->peer, c->threads);
        }
    }
}

void srv_conn_peer_error(srv_server *s, srv_conn *c, const proto_frame *f, const char *who)
{
    proto_error_msg m;
    char text[PT_TEXT_ESCAPED_SIZE(PROTO_MAX_ERROR_TEXT)];
    if (proto_msg_decode_error(f->payload, f->len, &m, NULL) == PT_OK)
        srv_log("%s %s reports: %s", who, c->shown, pt_text_shown(m.text, text, sizeof text));
    srv_conn_close_soon(s, c);
}
