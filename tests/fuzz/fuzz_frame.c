/*
 * fuzz_frame.c - libFuzzer target for the frame decoder of protocol/frame.c,
 * and through it the message decoders.
 *
 * Input: a byte stream as a peer would send it. Byte 0 picks the cap (odd:
 * before authentication) and how the stream arrives: whole, or in pieces of
 * 1..16 bytes through a reassembly buffer. Both ways must yield the same
 * frames, and every frame's payload goes to its message decoder. Invariants:
 * a frame lies inside the input, consumed = 16 + payload length, the payload
 * respects the cap, PT_AGAIN only for a valid prefix (checked by the two
 * arrival orders agreeing).
 */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "protocol/frame.h"
#include "tests/fuzz/fuzz_msg.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* Decodes every whole frame at the start of buf; returns bytes consumed and
 * the status that stopped it; records frame ends in ends[]. */
static size_t drain(const uint8_t *buf, size_t len, uint32_t cap, pt_status *stop, size_t *ends,
                    size_t *nends, size_t base, int decode_payloads)
{
    size_t off = 0;
    for (;;) {
        proto_frame f;
        size_t used = 0;
        pt_error err = {0};
        pt_status st = proto_frame_decode(buf + off, len - off, cap, &f, &used, &err);
        if (st != PT_OK) {
            FUZZ_CHECK(st == PT_AGAIN || (st == PT_ERR_PROTO && err.code == st && err.msg[0]));
            *stop = st;
            return off;
        }
        FUZZ_CHECK(used == PROTO_FRAME_OVERHEAD + (size_t)f.len && used <= len - off);
        FUZZ_CHECK(f.len <= cap && f.payload == buf + off + PROTO_FRAME_HEADER);
        FUZZ_CHECK(proto_msg_type_known(f.type) && f.version == PROTO_VERSION);
        if (decode_payloads)
            fuzz_decode(f.type, f.payload, f.len, (int)(f.len & 1));
        off += used;
        if (*nends < 4096)
            ends[(*nends)++] = base + off;
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    uint8_t mode = data[0];
    const uint8_t *s = data + 1;
    size_t n = size - 1;
    uint32_t cap = (mode & 1) ? PROTO_MAX_PAYLOAD_PREAUTH : PROTO_MAX_PAYLOAD;

    /* Whole. */
    static size_t ends_a[4096], ends_b[4096];
    size_t na = 0, nb = 0;
    pt_status stop_a = PT_OK, stop_b = PT_AGAIN;
    drain(s, n, cap, &stop_a, ends_a, &na, 0, 1);

    /* In pieces, the way a socket delivers them. */
    size_t piece = 1 + ((mode >> 1) & 15);
    uint8_t *buf = malloc(n ? n : 1);
    if (!buf)
        return 0;
    size_t have = 0, base = 0;
    for (size_t at = 0; at < n && stop_b == PT_AGAIN;) {
        size_t k = n - at < piece ? n - at : piece;
        memcpy(buf + have, s + at, k);
        have += k;
        at += k;
        size_t used = drain(buf, have, cap, &stop_b, ends_b, &nb, base, 0);
        memmove(buf, buf + used, have - used);
        have -= used;
        base += used;
    }
    free(buf);
    /* Same frames at the same places, and the same final verdict. */
    FUZZ_CHECK(na == nb && memcmp(ends_a, ends_b, na * sizeof ends_a[0]) == 0);
    if (n > 0)
        FUZZ_CHECK(stop_a == stop_b);
    return 0;
}
