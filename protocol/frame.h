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
 * table-driven one byte at a time.
 * proto_frame_reader is the one input buffer of every peer (coordinator,
 * worker, ptctl): received bytes go in, whole frames come out; it grows to
 * exactly the frame being received, never past the maximum fixed at init,
 * and proto_frame_reader_shrink gives the memory back once that frame is
 * consumed (a server counts what its peers hold: server/net/loop.h).
 * Thread-safety: the functions are reentrant; a reader belongs to the one
 * thread that reads its connection.
 */
#ifndef PT_PROTOCOL_FRAME_H
#define PT_PROTOCOL_FRAME_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"
#include "protocol/wire.h"

#define PROTO_MAGIC "PTF1"
/* 2: mutual authentication (AUTH and WELCOME, protocol/msg.h); 3: the environment light
 * in SUBMIT and TASK (ENV), film flags in TASK and SUBMIT, coverage and depth-cap counts
 * in RESULT and JOB_INFO; 4: RESULT's sums in fixed point (exact, so a job's image is the
 * same bits however its tasks are sized); 5: frame ranges (the pose in TASK, the range in
 * SUBMIT and JOB_INFO, FETCH_FRAME); 6: motion blur's shutter in TASK and SUBMIT; 7: the
 * samples rejected in JOB_INFO; 8: sample clamping (CLAMP) in TASK and SUBMIT; 9: the
 * contributions clamped in RESULT and JOB_INFO; 10: the integrator in JOB_INFO and
 * --bdpt=off's film flag in SUBMIT */
#define PROTO_VERSION 10u
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

/* CRC32C of n bytes, continuing from crc (start with 0). check("123456789") = 0xE3069283.
 * With the processor's CRC32 instruction (x86-64 SSE4.2) where it has one,
 * else from a byte table: the same values either way. */
uint32_t proto_crc32c(uint32_t crc, const void *data, size_t n);

/* The two ways, for tests and benchmarks: the table, and the instruction
 * (call it only when proto_crc32c_hw_available() says so). */
uint32_t proto_crc32c_table(uint32_t crc, const void *data, size_t n);
uint32_t proto_crc32c_hw(uint32_t crc, const void *data, size_t n);
int proto_crc32c_hw_available(void);

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

/* Ends the frame begun at mark given the status of the encoder that wrote its
 * payload: proto_frame_end when encoded is PT_OK; otherwise proto_frame_cancel
 * and returns encoded (the encoder has filled err). So one message is framed
 * with no macro and no partial frame left on any path:
 *     st = proto_frame_begin(w, PROTO_MSG_HELLO, &mark, err);
 *     if (st == PT_OK)
 *         st = proto_frame_finish(w, mark, proto_msg_encode_hello(w, &h, err), err); */
pt_status proto_frame_finish(proto_writer *w, size_t mark, pt_status encoded, pt_error *err);

/* The payload length L declared by a frame header (offset 8 above), from its
 * first PROTO_FRAME_HEADER bytes; nothing is checked (proto_frame_decode
 * judges it against the cap). The frame's whole size is
 * PROTO_FRAME_OVERHEAD + L. Pure. */
uint32_t proto_frame_payload_len(const uint8_t header[PROTO_FRAME_HEADER]);

/* ---- proto_frame_reader: received bytes in, whole frames out ---------------
 *
 *   proto_frame_reader_init(&r, 64 << 10, PROTO_FRAME_OVERHEAD + PROTO_MAX_PAYLOAD);
 *   for (;;) {
 *       while ((st = proto_frame_reader_next(&r, cap, &f, err)) == PT_OK)
 *           handle(&f);                  // f's payload is borrowed until the next call
 *       if (st != PT_AGAIN) ...;         // a bad frame: PT_ERR_PROTO
 *       if (proto_frame_reader_space(&r, &p, &room, err) != PT_OK) ...;
 *       n = recv(fd, p, room, 0);
 *       proto_frame_reader_commit(&r, n);
 *   }
 */
typedef struct proto_frame_reader {
    uint8_t *buf;   /* owned; NULL until the first proto_frame_reader_space */
    size_t start;   /* bytes [0, start) are consumed frames */
    size_t len;     /* bytes [start, len) wait to be decoded */
    size_t cap;     /* bytes allocated */
    size_t initial; /* the first allocation */
    size_t max;     /* cap never passes this */
} proto_frame_reader;

/* An empty reader that first allocates initial bytes and never holds more
 * than max (at least PROTO_FRAME_OVERHEAD + the largest payload it is to
 * accept, and initial <= max). Allocates nothing. */
void proto_frame_reader_init(proto_frame_reader *r, size_t initial, size_t max);

/* Frees the buffer; r is then empty as after init. Accepts a reader never used. */
void proto_frame_reader_fini(proto_frame_reader *r);

/* Forgets every byte held (a new connection), keeping the buffer. */
void proto_frame_reader_reset(proto_frame_reader *r);

/* Bytes received and not yet decoded. */
static inline size_t proto_frame_reader_pending(const proto_frame_reader *r)
{
    return r->len - r->start;
}

/* The capacity the next proto_frame_reader_space needs: room for the bytes
 * held plus one, and for the whole frame once its header is held (its
 * declared length is not checked here: call proto_frame_reader_next first).
 * At most the bytes held plus 1 plus PROTO_FRAME_OVERHEAD + 2^32 - 1. Pure. */
size_t proto_frame_reader_need(const proto_frame_reader *r);

/* Where to receive the next bytes: *p and the *room bytes free there (> 0).
 * Moves the undecoded bytes to the front, and grows the buffer when
 * proto_frame_reader_need passes its capacity: to exactly that need (the
 * frame's size; no doubling, so what a peer holds is what its frame
 * declares), at least initial, at most max. PT_ERR_NOMEM (nothing lost), or PT_ERR_LIMIT when max
 * bytes are held, which cannot happen while max fits the largest accepted frame. Invalidates the
 * payload of every frame returned so far. */
pt_status proto_frame_reader_space(proto_frame_reader *r, uint8_t **p, size_t *room, pt_error *err);

/* Gives memory back: when the buffer is larger than initial and what it
 * holds, with the frame whose header it holds, fits in initial bytes, the
 * held bytes move to the front and the buffer is cut to initial. Keeps the
 * buffer as it was when the allocator refuses. Invalidates the payload of
 * every frame returned so far. */
void proto_frame_reader_shrink(proto_frame_reader *r);

/* Records that n bytes were written at the *p of the last
 * proto_frame_reader_space (n <= its *room). */
void proto_frame_reader_commit(proto_frame_reader *r, size_t n);

/* Decodes the next frame held (proto_frame_decode with max_payload) and
 * consumes it: PT_OK with *f, its payload borrowed from the reader until the
 * next proto_frame_reader_space, _reset or _fini; PT_AGAIN when no whole
 * frame is held yet; PT_ERR_PROTO as proto_frame_decode (the reader is then
 * unchanged; the connection is to be closed). */
pt_status proto_frame_reader_next(proto_frame_reader *r, uint32_t max_payload, proto_frame *f,
                                  pt_error *err);

#endif
