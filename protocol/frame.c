#include "protocol/frame.h"

#include <assert.h>
#include <string.h>

#include "common/base/alloc.h"
#include "protocol/msg.h"

/* The byte-wise table is built by the preprocessor, so it is constant data
 * with no run-time initialisation to race on. One step of the reflected CRC:
 * shift right and fold in the polynomial when the low bit was set (the mask
 * form keeps each expansion to two copies of its argument). */
#define CRC_STEP(c) (((c) >> 1) ^ (0x82F63B78u & (0u - ((c)&1u))))
#define CRC_ENTRY(n)                                                                               \
    CRC_STEP(CRC_STEP(CRC_STEP(CRC_STEP(CRC_STEP(CRC_STEP(CRC_STEP(CRC_STEP((uint32_t)(n)))))))))
#define CRC_4(n) CRC_ENTRY(n), CRC_ENTRY((n) + 1), CRC_ENTRY((n) + 2), CRC_ENTRY((n) + 3)
#define CRC_16(n) CRC_4(n), CRC_4((n) + 4), CRC_4((n) + 8), CRC_4((n) + 12)
#define CRC_64(n) CRC_16(n), CRC_16((n) + 16), CRC_16((n) + 32), CRC_16((n) + 48)

static const uint32_t crc_table[256] = {CRC_64(0), CRC_64(64), CRC_64(128), CRC_64(192)};

uint32_t proto_crc32c_table(uint32_t crc, const void *data, size_t n)
{
    const uint8_t *p = data;
    crc = ~crc;
    while (n--)
        crc = (crc >> 8) ^ crc_table[(crc ^ *p++) & 0xffu];
    return ~crc;
}

#if defined(__x86_64__) && defined(__GNUC__)
/* SSE4.2's CRC32 instruction computes this very polynomial (Castagnoli,
 * reflected), 8 bytes a step: about 20 times the table's speed, which the
 * coordinator's loop spends most of its time on per result (issue 16). The
 * instruction takes the CRC register as it is, so the ~ at each end is the
 * same as the table's. */
__attribute__((target("sse4.2"))) uint32_t proto_crc32c_hw(uint32_t crc, const void *data, size_t n)
{
    const uint8_t *p = data;
    uint64_t c = ~crc;
    for (; n && ((uintptr_t)p & 7u); n--)
        c = __builtin_ia32_crc32qi((uint32_t)c, *p++);
    for (; n >= 8; n -= 8, p += 8) {
        uint64_t v;
        memcpy(&v, p, 8);
        c = __builtin_ia32_crc32di(c, v);
    }
    for (; n; n--)
        c = __builtin_ia32_crc32qi((uint32_t)c, *p++);
    return ~(uint32_t)c;
}

int proto_crc32c_hw_available(void)
{
    /* The runtime's CPU model is filled by a constructor before main; reading
     * it is a load and a test, cheaper than a cached pointer's first-use race. */
    return __builtin_cpu_supports("sse4.2");
}
#else
uint32_t proto_crc32c_hw(uint32_t crc, const void *data, size_t n)
{
    return proto_crc32c_table(crc, data, n);
}

int proto_crc32c_hw_available(void)
{
    return 0;
}
#endif

uint32_t proto_crc32c(uint32_t crc, const void *data, size_t n)
{
    return proto_crc32c_hw_available() ? proto_crc32c_hw(crc, data, n)
                                       : proto_crc32c_table(crc, data, n);
}

pt_status proto_frame_decode(const uint8_t *buf, size_t len, uint32_t max_payload, proto_frame *out,
                             size_t *consumed, pt_error *err)
{
    assert(max_payload <= PROTO_MAX_PAYLOAD);
    /* Each header field is judged as soon as its bytes have arrived, so a peer
     * speaking another protocol is refused at its first wrong byte. */
    size_t m = len < 4 ? len : 4;
    if (m && memcmp(buf, PROTO_MAGIC, m) != 0)
        return pt_error_set(err, PT_ERR_PROTO, "frame: bad magic");
    if (len < 6)
        return PT_AGAIN;
    uint16_t version = proto_get_u16(buf + 4);
    if (version != PROTO_VERSION)
        return pt_error_set(err, PT_ERR_PROTO, "frame: unsupported version %u (want %u)",
                            (unsigned)version, PROTO_VERSION);
    if (len < 8)
        return PT_AGAIN;
    uint16_t type = proto_get_u16(buf + 6);
    if (!proto_msg_type_known(type))
        return pt_error_set(err, PT_ERR_PROTO, "frame: unknown type %u", (unsigned)type);
    if (len < PROTO_FRAME_HEADER)
        return PT_AGAIN;
    uint32_t plen = proto_get_u32(buf + 8);
    if (plen > max_payload)
        return pt_error_set(err, PT_ERR_PROTO, "frame: payload length %u over the cap of %u",
                            (unsigned)plen, (unsigned)max_payload);
    /* plen <= 64 MiB, so the sum cannot wrap even with a 32-bit size_t. */
    size_t total = (size_t)PROTO_FRAME_HEADER + plen + PROTO_FRAME_TRAILER;
    if (len < total)
        return PT_AGAIN;
    uint32_t want = proto_get_u32(buf + PROTO_FRAME_HEADER + plen);
    uint32_t got = proto_crc32c(0, buf, PROTO_FRAME_HEADER + (size_t)plen);
    if (want != got)
        return pt_error_set(err, PT_ERR_PROTO, "frame: bad CRC (type %u, length %u)",
                            (unsigned)type, (unsigned)plen);
    out->version = version;
    out->type = type;
    out->len = plen;
    out->payload = buf + PROTO_FRAME_HEADER;
    *consumed = total;
    return PT_OK;
}

pt_status proto_frame_begin(proto_writer *w, uint16_t type, size_t *mark, pt_error *err)
{
    if (!proto_msg_type_known(type))
        return pt_error_set(err, PT_ERR_ARG, "frame: unknown type %u", (unsigned)type);
    size_t at = w->len;
    uint8_t *h = proto_w_reserve(w, PROTO_FRAME_HEADER);
    if (!h)
        return pt_error_set(err, proto_writer_status(w), "frame header: %s",
                            pt_status_str(proto_writer_status(w)));
    memcpy(h, PROTO_MAGIC, 4);
    proto_put_u16(h + 4, PROTO_VERSION);
    proto_put_u16(h + 6, type);
    proto_put_u32(h + 8, 0);
    *mark = at;
    return PT_OK;
}

void proto_frame_cancel(proto_writer *w, size_t mark)
{
    assert(mark + PROTO_FRAME_HEADER <= w->len);
    proto_writer_truncate(w, mark);
}

pt_status proto_frame_end(proto_writer *w, size_t mark, pt_error *err)
{
    assert(mark + PROTO_FRAME_HEADER <= w->len);
    pt_status st = proto_writer_status(w);
    if (st != PT_OK) {
        proto_writer_truncate(w, mark);
        return pt_error_set(err, st, "frame payload: %s", pt_status_str(st));
    }
    size_t plen = w->len - mark - PROTO_FRAME_HEADER;
    if (plen > PROTO_MAX_PAYLOAD) {
        proto_writer_truncate(w, mark);
        return pt_error_set(err, PT_ERR_ARG, "frame: payload of %zu bytes over the cap of %u", plen,
                            PROTO_MAX_PAYLOAD);
    }
    proto_put_u32(w->buf + mark + 8, (uint32_t)plen);
    uint32_t crc = proto_crc32c(0, w->buf + mark, PROTO_FRAME_HEADER + plen);
    proto_w_u32(w, crc);
    st = proto_writer_status(w);
    if (st != PT_OK) {
        proto_writer_truncate(w, mark);
        return pt_error_set(err, st, "frame trailer: %s", pt_status_str(st));
    }
    return PT_OK;
}

pt_status proto_frame_encode(proto_writer *w, uint16_t type, const void *payload, size_t len,
                             pt_error *err)
{
    if (len > PROTO_MAX_PAYLOAD)
        return pt_error_set(err, PT_ERR_ARG, "frame: payload of %zu bytes over the cap of %u", len,
                            PROTO_MAX_PAYLOAD);
    size_t mark = 0;
    pt_status st = proto_frame_begin(w, type, &mark, err);
    if (st != PT_OK)
        return st;
    proto_w_bytes(w, payload, len);
    return proto_frame_end(w, mark, err);
}

pt_status proto_frame_finish(proto_writer *w, size_t mark, pt_status encoded, pt_error *err)
{
    if (encoded != PT_OK) {
        proto_frame_cancel(w, mark);
        return encoded;
    }
    return proto_frame_end(w, mark, err);
}

uint32_t proto_frame_payload_len(const uint8_t header[PROTO_FRAME_HEADER])
{
    return proto_get_u32(header + 8);
}

/* ---- proto_frame_reader ---- */

void proto_frame_reader_init(proto_frame_reader *r, size_t initial, size_t max)
{
    assert(initial > 0 && initial <= max);
    memset(r, 0, sizeof *r);
    r->initial = initial;
    r->max = max;
}

void proto_frame_reader_fini(proto_frame_reader *r)
{
    pt_free(r->buf);
    r->buf = NULL;
    r->start = r->len = r->cap = 0;
}

void proto_frame_reader_reset(proto_frame_reader *r)
{
    r->start = r->len = 0;
}

size_t proto_frame_reader_need(const proto_frame_reader *r)
{
    size_t held = r->len - r->start;
    size_t need = held + 1;
    if (held >= PROTO_FRAME_HEADER) {
        size_t frame = PROTO_FRAME_OVERHEAD + (size_t)proto_frame_payload_len(r->buf + r->start);
        if (frame > need)
            need = frame;
    }
    return need;
}

/* Moves the undecoded bytes to the front of the buffer. */
static void compact(proto_frame_reader *r)
{
    if (r->start > 0) {
        memmove(r->buf, r->buf + r->start, r->len - r->start);
        r->len -= r->start;
        r->start = 0;
    }
}

pt_status proto_frame_reader_space(proto_frame_reader *r, uint8_t **p, size_t *room, pt_error *err)
{
    compact(r);
    /* Room for one more byte at least, and for the whole frame once its
     * header is here: the decoder has judged the declared length against the
     * cap by then, so this never waits on a length it would refuse. */
    size_t need = proto_frame_reader_need(r);
    if (need > r->cap) {
        if (need > r->max)
            return pt_error_set(err, PT_ERR_LIMIT, "frame of %zu bytes over the input buffer's %zu",
                                need, r->max);
        size_t ncap = need > r->initial ? need : r->initial;
        /* Whole frames not yet decoded fill the buffer: it grows by half
         * again, not by the one byte more it needs, or a peer that sends
         * faster than the frames are taken out costs a copy of the buffer
         * per byte. A frame whose length is known gets just its size. */
        if (need == r->len + 1 && ncap < r->cap + r->cap / 2)
            ncap = r->cap + r->cap / 2 < r->max ? r->cap + r->cap / 2 : r->max;
        uint8_t *nb = pt_realloc(r->buf, ncap);
        if (!nb)
            return pt_error_set(err, PT_ERR_NOMEM, "input buffer of %zu bytes", ncap);
        r->buf = nb;
        r->cap = ncap;
    }
    *p = r->buf + r->len;
    *room = r->cap - r->len;
    return PT_OK;
}

void proto_frame_reader_shrink(proto_frame_reader *r)
{
    if (r->cap <= r->initial || proto_frame_reader_need(r) > r->initial)
        return;
    compact(r);
    uint8_t *nb = pt_realloc(r->buf, r->initial);
    if (nb) {
        r->buf = nb;
        r->cap = r->initial;
    }
}

void proto_frame_reader_commit(proto_frame_reader *r, size_t n)
{
    assert(n <= r->cap - r->len);
    r->len += n;
}

pt_status proto_frame_reader_next(proto_frame_reader *r, uint32_t max_payload, proto_frame *f,
                                  pt_error *err)
{
    if (r->start == r->len)
        return PT_AGAIN;
    size_t used = 0;
    pt_status st =
        proto_frame_decode(r->buf + r->start, r->len - r->start, max_payload, f, &used, err);
    if (st == PT_OK)
        r->start += used;
    return st;
}
