/*
 * wire.h - the byte order of the protocol, in one place.
 *
 * Every field on the wire is a fixed-width little-endian integer or an IEEE 754
 * float sent as its bit pattern; encoding uses byte shifts only, so the host's
 * byte order and alignment never matter.
 *
 * proto_writer: a growable output buffer with a maximum size fixed at init
 *   (curl's dynbuf). A write that would take it past the maximum fails with
 *   PT_ERR_LIMIT; an allocation failure with PT_ERR_NOMEM. The first failure is
 *   sticky: later writes do nothing, and the caller checks proto_writer_status()
 *   once at the end. Memory comes from pt_malloc/pt_realloc; the writer owns it.
 * proto_reader: a {p, end} cursor over untrusted bytes. Every read checks that
 *   n <= end - p before touching a byte; a short read records the first failure
 *   ("truncated <field>"), returns zeros, and makes every later read fail too, so a
 *   decoder reads all its fields and checks once (Lua's lundump.c).
 * Thread-safety: none needed; a writer or reader belongs to one caller.
 */
#ifndef PT_PROTOCOL_WIRE_H
#define PT_PROTOCOL_WIRE_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "common/base/error.h"

/* ---- raw little-endian codecs (p must hold the bytes) ---- */

static inline void proto_put_u8(uint8_t *p, uint8_t v)
{
    p[0] = v;
}

static inline void proto_put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
}

static inline void proto_put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
    p[2] = (uint8_t)(v >> 16);
    p[3] = (uint8_t)(v >> 24);
}

static inline void proto_put_u64(uint8_t *p, uint64_t v)
{
    proto_put_u32(p, (uint32_t)v);
    proto_put_u32(p + 4, (uint32_t)(v >> 32));
}

static inline uint8_t proto_get_u8(const uint8_t *p)
{
    return p[0];
}

static inline uint16_t proto_get_u16(const uint8_t *p)
{
    return (uint16_t)(p[0] | (uint16_t)p[1] << 8);
}

static inline uint32_t proto_get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static inline uint64_t proto_get_u64(const uint8_t *p)
{
    return (uint64_t)proto_get_u32(p) | (uint64_t)proto_get_u32(p + 4) << 32;
}

/* Floats travel as their IEEE 754 bit patterns; memcpy is the defined way to
 * reinterpret them (NaN payloads and signed zeros survive). */
static inline uint32_t proto_f32_bits(float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return u;
}

static inline float proto_bits_f32(uint32_t u)
{
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

static inline uint64_t proto_f64_bits(double d)
{
    uint64_t u;
    memcpy(&u, &d, sizeof u);
    return u;
}

static inline double proto_bits_f64(uint64_t u)
{
    double d;
    memcpy(&d, &u, sizeof d);
    return d;
}

static inline void proto_put_f32(uint8_t *p, float v)
{
    proto_put_u32(p, proto_f32_bits(v));
}
static inline void proto_put_f64(uint8_t *p, double v)
{
    proto_put_u64(p, proto_f64_bits(v));
}
static inline float proto_get_f32(const uint8_t *p)
{
    return proto_bits_f32(proto_get_u32(p));
}
static inline double proto_get_f64(const uint8_t *p)
{
    return proto_bits_f64(proto_get_u64(p));
}

/* ---- writer ---- */

typedef struct proto_writer {
    uint8_t *buf;     /* owned; NULL until the first write */
    size_t len;       /* bytes written */
    size_t cap;       /* bytes allocated */
    size_t max;       /* len never passes this */
    pt_status status; /* first failure, PT_OK while none */
} proto_writer;

/* Starts an empty writer that will never hold more than max bytes. Allocates nothing. */
void proto_writer_init(proto_writer *w, size_t max);
/* Frees the buffer; the writer may be initialised again. Accepts NULL. */
void proto_writer_fini(proto_writer *w);
/* Forgets the content and a sticky failure, keeping the memory. */
void proto_writer_reset(proto_writer *w);
/* Cuts the content back to its first len bytes (len <= w->len): undoes what
 * was written since w->len was len. A sticky failure stays. */
void proto_writer_truncate(proto_writer *w, size_t len);
/* PT_OK, or the first failure of any write since init/reset. */
static inline pt_status proto_writer_status(const proto_writer *w)
{
    return w->status;
}

/* Appends n uninitialised bytes and returns where they start, or NULL on
 * failure (PT_ERR_LIMIT past max, PT_ERR_NOMEM; sticky). The pointer is valid
 * until the next write. */
uint8_t *proto_w_reserve(proto_writer *w, size_t n);
/* Appends n bytes (sticky failure as above). */
void proto_w_bytes(proto_writer *w, const void *src, size_t n);
void proto_w_u8(proto_writer *w, uint8_t v);
void proto_w_u16(proto_writer *w, uint16_t v);
void proto_w_u32(proto_writer *w, uint32_t v);
void proto_w_u64(proto_writer *w, uint64_t v);
void proto_w_f32(proto_writer *w, float v);
void proto_w_f64(proto_writer *w, double v);
/* A str field: u16 length, then the bytes without a NUL (the caller checks
 * that s fits its field's cap first). */
void proto_w_str(proto_writer *w, const char *s);

/* ---- reader ---- */

typedef struct proto_reader {
    const uint8_t *p, *end;
    pt_status status;  /* first failure, PT_OK while none */
    const char *field; /* the field that failed (static string) */
    const char *why;   /* "truncated", "too long", ... (static string) */
} proto_reader;

static inline proto_reader proto_reader_make(const uint8_t *buf, size_t len)
{
    /* NULL + 0 is undefined, so an empty NULL buffer keeps end == p == NULL. */
    proto_reader r = {buf, buf ? buf + len : buf, PT_OK, NULL, NULL};
    return r;
}

static inline size_t proto_r_left(const proto_reader *r)
{
    return (size_t)(r->end - r->p);
}

/* Records a failure (the first one wins) and makes every later read fail. */
void proto_r_fail(proto_reader *r, pt_status code, const char *why, const char *field);

/* Each read checks n <= end - p first; on a short read it records
 * "truncated <field>" and returns 0 (or NULL). */
const uint8_t *proto_r_bytes(proto_reader *r, size_t n, const char *field);
uint8_t proto_r_u8(proto_reader *r, const char *field);
uint16_t proto_r_u16(proto_reader *r, const char *field);
uint32_t proto_r_u32(proto_reader *r, const char *field);
uint64_t proto_r_u64(proto_reader *r, const char *field);
/* A str field into dst (max_len + 1 bytes, NUL-terminated); a length over
 * max_len or a NUL byte inside fails the read. */
void proto_r_str(proto_reader *r, char *dst, size_t max_len, const char *field);
float proto_r_f32(proto_reader *r, const char *field);
double proto_r_f64(proto_reader *r, const char *field);

/* Ends a decode: PT_OK when every read succeeded and no byte is left over;
 * else fills err with "<what>: <why> <field>" (or "<what>: trailing bytes")
 * and returns the failure (PT_ERR_PROTO for anything a peer got wrong). */
pt_status proto_r_finish(const proto_reader *r, const char *what, pt_error *err);

#endif
