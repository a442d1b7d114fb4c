#include "server/net/clients.h"

#include <stdio.h>
#include <string.h>

#include <openssl/crypto.h>

#include "common/base/alloc.h"
#include "protocol/auth.h"

typedef struct client_entry {
    char name[PROTO_MAX_NAME + 1];
    const uint8_t *token; /* into data */
    size_t token_len;
    uint32_t line;
} client_entry;

struct srv_clients {
    uint8_t *data; /* the file's bytes, NUL-terminated; tokens point into it */
    size_t len;
    client_entry *e;
    uint32_t n;
};

void srv_clients_free(srv_clients *cl)
{
    if (!cl)
        return;
    proto_secret_free(cl->data, cl->len + 1);
    pt_free(cl->e);
    pt_free(cl);
}

uint32_t srv_clients_count(const srv_clients *cl)
{
    return cl ? cl->n : 0;
}

static int blank(uint8_t b)
{
    return b == ' ' || b == '\t' || b == '\r';
}

/* Parses one line [p, end) into e; NULL when fine, else why not. */
static const char *parse_line(uint8_t *p, uint8_t *end, client_entry *e, int *skip)
{
    *skip = 0;
    while (p < end && blank(*p))
        p++;
    if (p == end || *p == '#') {
        *skip = 1;
        return NULL;
    }
    uint8_t *name = p;
    while (p < end && !blank(*p))
        p++;
    size_t name_len = (size_t)(p - name);
    while (p < end && blank(*p))
        p++;
    uint8_t *tok = p;
    while (p < end && !blank(*p))
        p++;
    size_t tok_len = (size_t)(p - tok);
    while (p < end && blank(*p))
        p++;
    if (tok_len == 0)
        return "expected NAME TOKEN";
    if (p != end)
        return "more than NAME TOKEN on the line";
    if (name_len > PROTO_MAX_NAME)
        return "NAME is too long";
    for (size_t i = 0; i < name_len; i++)
        if (name[i] < 0x21 || name[i] > 0x7e)
            return "NAME has a byte that is not printable ASCII";
    memcpy(e->name, name, name_len);
    e->name[name_len] = '\0';
    e->token = tok;
    e->token_len = tok_len;
    return NULL;
}

static int same_token(const uint8_t *a, size_t alen, const uint8_t *b, size_t blen)
{
    return alen == blen && CRYPTO_memcmp(a, b, alen) == 0;
}

pt_status srv_clients_load(const char *path, const uint8_t *admin, size_t admin_len,
                           srv_clients **out, pt_error *err)
{
    pt_status st;
    srv_clients *cl = pt_calloc(1, sizeof *cl);
    if (!cl)
        return pt_error_set(err, PT_ERR_NOMEM, "clients file %s: out of memory", path);
    if ((st = proto_secret_read(path, "clients file", SRV_CLIENTS_MAX_BYTES, &cl->data, &cl->len,
                                err)) != PT_OK)
        goto fail;
    cl->e = pt_calloc(SRV_CLIENTS_MAX, sizeof *cl->e);
    if (!cl->e) {
        st = pt_error_set(err, PT_ERR_NOMEM, "clients file %s: out of memory", path);
        goto fail;
    }
    uint8_t *p = cl->data, *end = cl->data + cl->len;
    for (uint32_t line = 1; p < end; line++) {
        uint8_t *nl = memchr(p, '\n', (size_t)(end - p));
        uint8_t *eol = nl ? nl : end;
        client_entry e;
        memset(&e, 0, sizeof e);
        int skip;
        const char *why = parse_line(p, eol, &e, &skip);
        p = nl ? nl + 1 : end;
        if (skip)
            continue;
        if (why) {
            st = pt_error_set(err, PT_ERR_FORMAT, "clients file %s, line %u: %s", path, line, why);
            goto fail;
        }
        char what[600];
        snprintf(what, sizeof what, "clients file %s, line %u", path, line);
        if ((st = proto_token_check(e.token, e.token_len, what, err)) != PT_OK)
            goto fail;
        if (same_token(e.token, e.token_len, admin, admin_len)) {
            st = pt_error_set(err, PT_ERR_FORMAT,
                              "%s: the token is the shared (admin) token of --token-file", what);
            goto fail;
        }
        for (uint32_t i = 0; i < cl->n; i++)
            if (same_token(e.token, e.token_len, cl->e[i].token, cl->e[i].token_len)) {
                st = pt_error_set(err, PT_ERR_FORMAT, "%s: the same token as line %u", what,
                                  cl->e[i].line);
                goto fail;
            }
        if (cl->n == SRV_CLIENTS_MAX) {
            st = pt_error_set(err, PT_ERR_LIMIT, "clients file %s: over %u entries", path,
                              SRV_CLIENTS_MAX);
            goto fail;
        }
        e.line = line;
        cl->e[cl->n++] = e;
    }
    *out = cl;
    return PT_OK;
fail:
    srv_clients_free(cl);
    return st;
}

int srv_clients_match(const srv_clients *cl, const uint8_t nonce[PROTO_NONCE_SIZE],
                      const uint8_t mac[PROTO_MAC_SIZE], const char **name, const uint8_t **token,
                      size_t *token_len)
{
    int found = -1;
    for (uint32_t i = 0; cl && i < cl->n; i++) {
        /* Every entry is tried, so the time does not tell which one matched. */
        if (proto_auth_verify(cl->e[i].token, cl->e[i].token_len, nonce, mac, NULL) == PT_OK &&
            found < 0)
            found = (int)i;
    }
    if (found < 0)
        return -1;
    *name = cl->e[found].name;
    *token = cl->e[found].token;
    *token_len = cl->e[found].token_len;
    return found;
}
