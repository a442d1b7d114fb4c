/*
 * frame.h - the frame that carries every protocol message, and its checksum.
 *
 *   offset  size  type      meaning
 *   0       4     u8[4]     magic "PTF1"
 *   4       2     u16       protocol version (PROTO_VERSION)
 *   6       2     u16       message type (proto_msg_type, protocol/msg.h)
 *   8       4     u32       payload length L (<= the connection's cap)
 *   12      L     bytes     payload (layout per type: protocol/msg.h)
 *   12+L    4     u32       CRC32C of bytes [0, 12+L)
 *
 * All integers little-endian (protocol/wire.h). The decoder is a pure function
 * over a byte buffer: it reports a whole frame, "need more bytes" or an error
 * with a reason, and it checks each header field as soon as its bytes are
 * present, so garbage and oversized frames are refused before anything is
 * waited for (Redis's multibulk length check). Caps: PROTO_MAX_PAYLOAD_PREAUTH
 * until the peer has authenticated, PROTO_MAX_PAYLOAD after.
 * CRC32C is the Castagnoli polynomial (reflected 0x82F63B78, RFC 3720 B.4),
 * table-driven one byte at a time. Thread-safety: reentrant, no state.
 */
#ifndef PT_PROTOCOL_FRAME_H
#define PT_PROTOCOL_FRAME_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"
#include "protocol/wire.h"

#define PROTO_MAGIC "PTF1"
#define PROTO_VERSION 1u
#define PROTO_FRAME_HEADER 12u
#define PROTO_FRAME_TRAILER 4u
#define PROTO_FRAME_OVERHEAD (PROTO_FRAME_HEADER + PROTO_FRAME_TRAILER)
#define PROTO_MAX_PAYLOAD_PREAUTH (4u * 1024u)  /* before AUTH succeeded */
#define PROTO_MAX_PAYLOAD (64u * 1024u * 1024u) /* after; the hard cap */

/* A decoded frame; payload points into the buffer given to the decoder. */
typedef struct proto_frame {
    uint16_t version;
    uint16_t type;
    uint32_t len;
    const uint8_t *payload;
} proto_frame;

/* CRC32C of n bytes, continuing from crc (start with 0). check("123456789") = 0xE3069283. */
uint32_t proto_crc32c(uint32_t crc, const void *data, size_t n);

/* Decodes the frame at the start of buf[0, len).
 *   PT_OK:        *out describes a whole frame (its payload borrowed from buf)
 *                 and *consumed is its size in bytes.
 *   PT_AGAIN:     every byte present is valid so far; more are needed.
 *   PT_ERR_PROTO: bad magic, unsupported version, unknown type, a payload length
 *                 over max_payload (reported as soon as the header is present,
 *                 not after waiting for the payload) or a bad CRC; err says which.
 * max_payload must be <= PROTO_MAX_PAYLOAD. out and consumed are untouched
 * unless PT_OK. */
pt_status proto_frame_decode(const uint8_t *buf, size_t len, uint32_t max_payload, proto_frame *out,
                             size_t *consumed, pt_error *err);

/* Appends one whole frame of type carrying payload[0, len) to w.
 * PT_ERR_ARG for an unknown type or len over PROTO_MAX_PAYLOAD; the writer's
 * failure (PT_ERR_LIMIT, PT_ERR_NOMEM) otherwise. On failure w holds no byte
 * of the frame (a writer failure stays sticky in w). */
pt_status proto_frame_encode(proto_writer *w, uint16_t type, const void *payload, size_t len,
                             pt_error *err);

/* Writing a payload in place, with no copy: proto_frame_begin appends a header
 * and returns its offset in *mark; the caller appends the payload to w
 * (proto_msg_encode_*); proto_frame_end patches the length and appends the CRC.
 * Errors as proto_frame_encode; a writer failure in between is reported by
 * end. A failed begin or end leaves no byte of the frame in w; when the
 * payload cannot be written, proto_frame_cancel(w, mark) removes the header:
 *     if (proto_frame_begin(w, PROTO_MSG_TASK, &mark, err) != PT_OK) ...;
 *     if (proto_msg_encode_task(w, &t, err) != PT_OK) proto_frame_cancel(w, mark);
 *     else if (proto_frame_end(w, mark, err) != PT_OK) ...; */
pt_status proto_frame_begin(proto_writer *w, uint16_t type, size_t *mark, pt_error *err);
pt_status proto_frame_end(proto_writer *w, size_t mark, pt_error *err);
void proto_frame_cancel(proto_writer *w, size_t mark);

#endif
