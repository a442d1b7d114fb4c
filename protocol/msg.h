/*
 * msg.h - the messages of the ptfarm protocol: types, layouts, encoders, decoders.
 *
 * Each message is the payload of one frame (protocol/frame.h) and is laid out
 * below as a table (offset, size, type, meaning); all integers little-endian,
 * floats as IEEE 754 bit patterns (protocol/wire.h). A "str" is a u16 byte
 * length a followed by a bytes, no terminator; a is capped per field and the
 * bytes must contain no NUL (they are not otherwise checked: text for logs and
 * comparisons, never interpreted). A payload must be exactly as long as its
 * layout says: trailing bytes are an error.
 *
 * Decoders are pure functions over (payload, len): every read is bounds-checked
 * (protocol/wire.h), every count and length is checked against its cap before
 * it is used, and they return PT_OK or PT_ERR_PROTO with the field at fault in
 * err (proto_msg_decode_result also PT_ERR_LIMIT and PT_ERR_NOMEM, see there);
 * *out is untouched on failure. Only proto_msg_decode_result may allocate.
 * Decoders check the shape of a message (caps, rect order, sizes that must
 * agree), not its meaning for the session (whether a task id is leased, whether
 * values are finite): that is the server's and worker's business.
 * Encoders append the payload to a proto_writer (wrap them between
 * proto_frame_begin and proto_frame_end, and call proto_frame_cancel when one
 * fails), refuse a message their decoder would refuse (PT_ERR_ARG, before
 * writing anything), and report the writer's failure (PT_ERR_LIMIT,
 * PT_ERR_NOMEM). A failed encoder leaves no byte of its message in the writer.
 * Thread-safety: reentrant, no state.
 */
#ifndef PT_PROTOCOL_MSG_H
#define PT_PROTOCOL_MSG_H

#include <stddef.h>
#include <stdint.h>

#include "common/error.h"
#include "common/render.h"
#include "protocol/wire.h"

/* Frame types. Gaps are room for growth within each group. */
typedef enum proto_msg_type {
    /* handshake (allowed before authentication) */
    PROTO_MSG_HELLO = 1,     /* peer -> server */
    PROTO_MSG_CHALLENGE = 2, /* server -> peer */
    PROTO_MSG_AUTH = 3,      /* peer -> server */
    PROTO_MSG_WELCOME = 4,   /* server -> peer */
    PROTO_MSG_ERROR = 5,     /* either way; the sender closes after it */
    /* worker */
    PROTO_MSG_WORK_REQUEST = 16, /* worker -> server */
    PROTO_MSG_TASK = 17,         /* server -> worker */
    PROTO_MSG_SCENE_GET = 18,    /* worker -> server */
    PROTO_MSG_SCENE_CHUNK = 19,  /* server -> worker */
    PROTO_MSG_RESULT = 20,       /* worker -> server */
    PROTO_MSG_HEARTBEAT = 21,    /* worker -> server */
    /* client (ptctl): numbers reserved, layouts not defined yet; replies will
     * take numbers from 48 on */
    PROTO_MSG_SUBMIT = 32,
    PROTO_MSG_LIST = 33,
    PROTO_MSG_STATUS = 34,
    PROTO_MSG_WATCH = 35,
    PROTO_MSG_CANCEL = 36,
    PROTO_MSG_FETCH = 37
} proto_msg_type;

/* 1 when type is one of the values above (the frame decoder refuses others). */
int proto_msg_type_known(uint32_t type);
/* 1 for the handshake types, the only ones a peer may send before WELCOME. */
int proto_msg_type_preauth(uint32_t type);
/* Static name ("HELLO"), or "unknown". */
const char *proto_msg_type_name(uint32_t type);

/* Caps (bytes for strings, entries for lists). */
#define PROTO_MAX_NAME 64u
#define PROTO_MAX_BUILD_ID 64u
#define PROTO_MAX_ERROR_TEXT 1024u
#define PROTO_MAX_SLOTS 1024u               /* WORK_REQUEST slots */
#define PROTO_MAX_HEARTBEAT_TASKS 1024u     /* task ids in one HEARTBEAT */
#define PROTO_MAX_SCENE_CHUNK (1u << 20)    /* data bytes in one SCENE_CHUNK */
#define PROTO_MAX_TILE_PIXELS (256u * 256u) /* pixels in one TASK / RESULT tile */
#define PROTO_HASH_SIZE 32u                 /* scene content hash (SHA-256) */
#define PROTO_NONCE_SIZE 32u
#define PROTO_MAC_SIZE 32u          /* HMAC-SHA256 */
#define PROTO_RESULT_PIXEL_SIZE 36u /* bytes per pixel in RESULT */

enum { PROTO_ROLE_WORKER = 1, PROTO_ROLE_CLIENT = 2 };

/* ERROR codes. Decoders accept any value, so a newer peer may add codes. */
enum {
    PROTO_E_PROTOCOL = 1,  /* malformed frame or message, or one out of place */
    PROTO_E_VERSION = 2,   /* protocol version not supported */
    PROTO_E_AUTH = 3,      /* authentication failed */
    PROTO_E_BUILD = 4,     /* renderer build id differs from the server's */
    PROTO_E_LIMIT = 5,     /* a cap was exceeded */
    PROTO_E_NOT_FOUND = 6, /* unknown scene hash, job or task */
    PROTO_E_INTERNAL = 7   /* the sender failed for its own reasons */
};

/* The renderer build id of this binary (PT_BUILD_ID of ptcore): workers of
 * another build would break bit-identical merging, so HELLO carries it. */
const char *proto_build_id(void);

/* HELLO
 *   offset   size  type  meaning
 *   0        2     u16   protocol version the peer speaks (PROTO_VERSION)
 *   2        1     u8    role: PROTO_ROLE_WORKER or PROTO_ROLE_CLIENT
 *   3        2+a   str   name of the peer (host, user), a <= PROTO_MAX_NAME
 *   5+a      2     u16   render threads (0 for a client)
 *   7+a      2+b   str   renderer build id, b <= PROTO_MAX_BUILD_ID
 *   9+a+b    4     u32   capability bits (none defined yet; unknown bits ignored)
 *   size 13+a+b */
typedef struct proto_hello {
    uint16_t version;
    uint8_t role;
    char name[PROTO_MAX_NAME + 1]; /* NUL-terminated */
    uint16_t threads;
    char build_id[PROTO_MAX_BUILD_ID + 1];
    uint32_t caps;
} proto_hello;

/* CHALLENGE: 0 32 u8[32] nonce (random, fresh per connection). size 32
 * AUTH:      0 32 u8[32] HMAC-SHA256 over the nonce (protocol/auth.h). size 32 */
typedef struct proto_challenge {
    uint8_t nonce[PROTO_NONCE_SIZE];
} proto_challenge;
typedef struct proto_auth {
    uint8_t mac[PROTO_MAC_SIZE];
} proto_auth;

/* WELCOME
 *   0    8    u64  session id
 *   8    2+a  str  server's renderer build id, a <= PROTO_MAX_BUILD_ID
 *   size 10+a */
typedef struct proto_welcome {
    uint64_t session_id;
    char build_id[PROTO_MAX_BUILD_ID + 1];
} proto_welcome;

/* ERROR
 *   0    2    u16  code (PROTO_E_*)
 *   2    2+a  str  message for a human, a <= PROTO_MAX_ERROR_TEXT
 *   size 4+a */
typedef struct proto_error_msg {
    uint16_t code;
    char text[PROTO_MAX_ERROR_TEXT + 1];
} proto_error_msg;

/* WORK_REQUEST
 *   0    2    u16  slots: how many more tasks the worker wants, <= PROTO_MAX_SLOTS
 *   size 2 */
typedef struct proto_work_request {
    uint16_t slots;
} proto_work_request;

/* TASK
 *   0    8    u64      job id
 *   8    8    u64      task id (unique within the job)
 *   16   4    u32      tile x0  \  pixels [x0,x1) x [y0,y1): x0 < x1 <= width,
 *   20   4    u32      tile y0   | y0 < y1 <= height, area <= PROTO_MAX_TILE_PIXELS
 *   24   4    u32      tile x1   |
 *   28   4    u32      tile y1  /
 *   32   4    u32      s0: first sample index
 *   36   4    u32      s1: one past the last (s0 < s1)
 *   40   4    u32      image width
 *   44   4    u32      image height
 *   48   4    u32      job seed
 *   52   2    u16      max depth (bounces)
 *   54   2    u16      Russian roulette depth
 *   56   32   u8[32]   scene content hash
 *   88   4    u32      lease in milliseconds (heartbeat before it runs out)
 *   size 92 */
typedef struct proto_task {
    uint64_t job_id, task_id;
    pt_rect tile;
    uint32_t s0, s1;
    uint32_t width, height;
    uint32_t seed;
    uint16_t max_depth, rr_depth;
    uint8_t scene_hash[PROTO_HASH_SIZE];
    uint32_t lease_ms;
} proto_task;

/* SCENE_GET
 *   0    32   u8[32]  scene content hash
 *   32   8    u64     byte offset wanted (the server answers one SCENE_CHUNK from there)
 *   size 40 */
typedef struct proto_scene_get {
    uint8_t hash[PROTO_HASH_SIZE];
    uint64_t offset;
} proto_scene_get;

/* SCENE_CHUNK
 *   0    32   u8[32]  scene content hash
 *   32   8    u64     offset of this chunk in the scene file
 *   40   8    u64     total size of the scene file
 *   48   4    u32     n: data bytes, n <= PROTO_MAX_SCENE_CHUNK, offset + n <= total
 *   52   n    bytes   data
 *   size 52+n
 * Decoded, data points into the payload (borrowed, no copy). */
typedef struct proto_scene_chunk {
    uint8_t hash[PROTO_HASH_SIZE];
    uint64_t offset, total;
    uint32_t len;
    const uint8_t *data;
} proto_scene_chunk;

/* RESULT
 *   0    8    u64   job id
 *   8    8    u64   task id
 *   16   16   u32×4 tile x0, y0, x1, y1 (x0 < x1, y0 < y1)
 *   32   4    u32   s0
 *   36   4    u32   s1 (s0 < s1)
 *   40   8    u64   samples rejected (NaN/Inf) over the tile
 *   48   8    u64   rays traced
 *   56   4    u32   N: pixels; must equal (x1-x0)*(y1-y0) and be <= PROTO_MAX_TILE_PIXELS
 *   60   36N        pixels, row-major over the tile, each:
 *                     +0   8  f64  sum R
 *                     +8   8  f64  sum G
 *                     +16  8  f64  sum B
 *                     +24  8  f64  sum of squared luminance
 *                     +32  4  u32  n: samples accumulated, n <= s1 - s0
 *   size 60+36N
 * The floats are not checked (finiteness is the server's business). */
typedef struct proto_result {
    uint64_t job_id, task_id;
    pt_rect tile;
    uint32_t s0, s1;
    uint64_t rejected, rays;
    uint32_t npixels;
    pt_pixel_acc *pixels; /* npixels entries */
    int owns_pixels;      /* 1 when the decoder allocated pixels */
} proto_result;

/* HEARTBEAT
 *   0    2    u16     N: task ids, N <= PROTO_MAX_HEARTBEAT_TASKS
 *   2    8N   u64[N]  the tasks the worker holds (leased, queued or running)
 *   size 2+8N */
typedef struct proto_heartbeat {
    uint16_t count;
    uint64_t task_ids[PROTO_MAX_HEARTBEAT_TASKS];
} proto_heartbeat;

pt_status proto_msg_encode_hello(proto_writer *w, const proto_hello *m, pt_error *err);
pt_status proto_msg_decode_hello(const uint8_t *p, size_t len, proto_hello *out, pt_error *err);

pt_status proto_msg_encode_challenge(proto_writer *w, const proto_challenge *m, pt_error *err);
pt_status proto_msg_decode_challenge(const uint8_t *p, size_t len, proto_challenge *out,
                                     pt_error *err);

pt_status proto_msg_encode_auth(proto_writer *w, const proto_auth *m, pt_error *err);
pt_status proto_msg_decode_auth(const uint8_t *p, size_t len, proto_auth *out, pt_error *err);

pt_status proto_msg_encode_welcome(proto_writer *w, const proto_welcome *m, pt_error *err);
pt_status proto_msg_decode_welcome(const uint8_t *p, size_t len, proto_welcome *out, pt_error *err);

pt_status proto_msg_encode_error(proto_writer *w, const proto_error_msg *m, pt_error *err);
pt_status proto_msg_decode_error(const uint8_t *p, size_t len, proto_error_msg *out, pt_error *err);

pt_status proto_msg_encode_work_request(proto_writer *w, const proto_work_request *m,
                                        pt_error *err);
pt_status proto_msg_decode_work_request(const uint8_t *p, size_t len, proto_work_request *out,
                                        pt_error *err);

pt_status proto_msg_encode_task(proto_writer *w, const proto_task *m, pt_error *err);
pt_status proto_msg_decode_task(const uint8_t *p, size_t len, proto_task *out, pt_error *err);

pt_status proto_msg_encode_scene_get(proto_writer *w, const proto_scene_get *m, pt_error *err);
pt_status proto_msg_decode_scene_get(const uint8_t *p, size_t len, proto_scene_get *out,
                                     pt_error *err);

/* out->data borrows from p: keep the payload alive while it is used. */
pt_status proto_msg_encode_scene_chunk(proto_writer *w, const proto_scene_chunk *m, pt_error *err);
pt_status proto_msg_decode_scene_chunk(const uint8_t *p, size_t len, proto_scene_chunk *out,
                                       pt_error *err);

/* Encodes m->npixels entries of m->pixels (npixels must equal the tile's area). */
pt_status proto_msg_encode_result(proto_writer *w, const proto_result *m, pt_error *err);
/* Decodes a RESULT. The pixel count is checked against the tile's area, the cap
 * and the bytes present before anything is allocated. Pixels go to buf when buf
 * is not NULL (PT_ERR_LIMIT when N > buf_cap; out->owns_pixels = 0), else to a
 * pt_malloc'd array that out owns (out->owns_pixels = 1; PT_ERR_NOMEM when the
 * allocation fails). Release with proto_result_fini either way. */
pt_status proto_msg_decode_result(const uint8_t *p, size_t len, pt_pixel_acc *buf, size_t buf_cap,
                                  proto_result *out, pt_error *err);
/* Frees the pixels when the decoder allocated them, and clears the pointer. Accepts NULL. */
void proto_result_fini(proto_result *r);

pt_status proto_msg_encode_heartbeat(proto_writer *w, const proto_heartbeat *m, pt_error *err);
pt_status proto_msg_decode_heartbeat(const uint8_t *p, size_t len, proto_heartbeat *out,
                                     pt_error *err);

#endif
