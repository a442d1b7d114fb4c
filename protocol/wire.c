#include "protocol/wire.h"

#include <assert.h>

#include "common/base/alloc.h"

void proto_writer_init(proto_writer *w, size_t max)
{
    w->buf = NULL;
    w->len = 0;
    w->cap = 0;
    w->max = max;
    w->status = PT_OK;
}

void proto_writer_fini(proto_writer *w)
{
    if (!w)
        return;
    pt_free(w->buf);
    w->buf = NULL;
    w->len = 0;
    w->cap = 0;
    w->status = PT_OK;
}

void proto_writer_reset(proto_writer *w)
{
    w->len = 0;
    w->status = PT_OK;
}

void proto_writer_truncate(proto_writer *w, size_t len)
{
    assert(len <= w->len);
    w->len = len;
}

uint8_t *proto_w_reserve(proto_writer *w, size_t n)
{
    if (w->status != PT_OK)
        return NULL;
    /* len <= max always holds, so max - len cannot wrap. */
    if (n > w->max - w->len) {
        w->status = PT_ERR_LIMIT;
        return NULL;
    }
    size_t need = w->len + n;
    /* Allocating even for n == 0 keeps the returned pointer non-NULL (and
     * spares pointer arithmetic on NULL). */
    if (need > w->cap || !w->buf) {
        /* Grow geometrically but never past max, so a writer capped at 4 KiB
         * never holds 8. */
        size_t cap = w->cap ? w->cap : 256;
        while (cap < need)
            cap = cap > w->max / 2 ? w->max : cap * 2;
        if (cap > w->max)
            cap = w->max;
        if (cap < need)
            cap = need;
        uint8_t *nb = pt_realloc(w->buf, cap);
        if (!nb) {
            w->status = PT_ERR_NOMEM;
            return NULL;
        }
        w->buf = nb;
        w->cap = cap;
    }
    uint8_t *p = w->buf + w->len;
    w->len = need;
    return p;
}

void proto_w_bytes(proto_writer *w, const void *src, size_t n)
{
    uint8_t *p = proto_w_reserve(w, n);
    if (p && n)
        memcpy(p, src, n);
}

void proto_w_u8(proto_writer *w, uint8_t v)
{
    uint8_t *p = proto_w_reserve(w, 1);
    if (p)
        proto_put_u8(p, v);
}

void proto_w_u16(proto_writer *w, uint16_t v)
{
    uint8_t *p = proto_w_reserve(w, 2);
    if (p)
        proto_put_u16(p, v);
}

void proto_w_u32(proto_writer *w, uint32_t v)
{
    uint8_t *p = proto_w_reserve(w, 4);
    if (p)
        proto_put_u32(p, v);
}

void proto_w_u64(proto_writer *w, uint64_t v)
{
    uint8_t *p = proto_w_reserve(w, 8);
    if (p)
        proto_put_u64(p, v);
}

void proto_w_f32(proto_writer *w, float v)
{
    proto_w_u32(w, proto_f32_bits(v));
}

void proto_w_f64(proto_writer *w, double v)
{
    proto_w_u64(w, proto_f64_bits(v));
}

void proto_r_fail(proto_reader *r, pt_status code, const char *why, const char *field)
{
    if (r->status == PT_OK) {
        r->status = code;
        r->why = why;
        r->field = field;
    }
    /* Later reads see no bytes left, so they fail without reading. */
    r->p = r->end;
}

void proto_w_str(proto_writer *w, const char *s)
{
    size_t n = strlen(s);
    proto_w_u16(w, (uint16_t)n);
    proto_w_bytes(w, s, n);
}

void proto_r_str(proto_reader *r, char *dst, size_t max_len, const char *field)
{
    uint16_t n = proto_r_u16(r, field);
    if (r->status != PT_OK)
        return;
    if (n > max_len) {
        proto_r_fail(r, PT_ERR_PROTO, "over the length cap:", field);
        return;
    }
    const uint8_t *s = proto_r_bytes(r, n, field);
    if (!s)
        return;
    if (memchr(s, 0, n)) {
        proto_r_fail(r, PT_ERR_PROTO, "NUL byte in", field);
        return;
    }
    memcpy(dst, s, n);
    dst[n] = '\0';
}

const uint8_t *proto_r_bytes(proto_reader *r, size_t n, const char *field)
{
    if (r->status != PT_OK)
        return NULL;
    if (n > (size_t)(r->end - r->p)) {
        proto_r_fail(r, PT_ERR_PROTO, "truncated", field);
        return NULL;
    }
    const uint8_t *p = r->p;
    r->p += n;
    return p;
}

uint8_t proto_r_u8(proto_reader *r, const char *field)
{
    const uint8_t *p = proto_r_bytes(r, 1, field);
    return p ? proto_get_u8(p) : 0;
}

uint16_t proto_r_u16(proto_reader *r, const char *field)
{
    const uint8_t *p = proto_r_bytes(r, 2, field);
    return p ? proto_get_u16(p) : 0;
}

uint32_t proto_r_u32(proto_reader *r, const char *field)
{
    const uint8_t *p = proto_r_bytes(r, 4, field);
    return p ? proto_get_u32(p) : 0;
}

uint64_t proto_r_u64(proto_reader *r, const char *field)
{
    const uint8_t *p = proto_r_bytes(r, 8, field);
    return p ? proto_get_u64(p) : 0;
}

float proto_r_f32(proto_reader *r, const char *field)
{
    return proto_bits_f32(proto_r_u32(r, field));
}

double proto_r_f64(proto_reader *r, const char *field)
{
    return proto_bits_f64(proto_r_u64(r, field));
}

pt_status proto_r_finish(const proto_reader *r, const char *what, pt_error *err)
{
    if (r->status != PT_OK)
        return pt_error_set(err, r->status, "%s: %s %s", what, r->why ? r->why : "bad",
                            r->field ? r->field : "field");
    if (r->p != r->end)
        return pt_error_set(err, PT_ERR_PROTO, "%s: %zu trailing bytes", what,
                            (size_t)(r->end - r->p));
    return PT_OK;
}
