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

#include "common/base/error.h"
#include "common/render/bdpt_auto.h"
#include "common/render/tile.h"
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
    PROTO_MSG_WORK_REQUEST = 16,   /* worker -> server */
    PROTO_MSG_TASK = 17,           /* server -> worker */
    PROTO_MSG_SCENE_GET = 18,      /* worker -> server */
    PROTO_MSG_SCENE_CHUNK = 19,    /* server -> worker */
    PROTO_MSG_RESULT = 20,         /* worker -> server */
    PROTO_MSG_HEARTBEAT = 21,      /* worker -> server */
    PROTO_MSG_JOB_END = 22,        /* server -> worker, JOB_REF layout: drop that job's tasks */
    PROTO_MSG_GUIDE_GET = 23,      /* worker -> server, SCENE_GET layout: a guiding distribution */
    PROTO_MSG_GUIDE_CHUNK = 24,    /* server -> worker, SCENE_CHUNK layout: a piece of one */
    PROTO_MSG_DENOISE_TASK = 25,   /* server -> worker: denoise one region of a frame */
    PROTO_MSG_DENOISE_GET = 26,    /* worker -> server, SCENE_GET layout: a region's input */
    PROTO_MSG_DENOISE_CHUNK = 27,  /* server -> worker, SCENE_CHUNK layout: a piece of one */
    PROTO_MSG_DENOISE_RESULT = 28, /* worker -> server: the region denoised */
    /* client (ptctl) -> server */
    PROTO_MSG_SUBMIT = 32, /* then UPLOAD frames with the scene bundle */
    PROTO_MSG_LIST = 33,
    PROTO_MSG_STATUS = 34,
    PROTO_MSG_WATCH = 35,
    PROTO_MSG_CANCEL = 36,
    PROTO_MSG_FETCH = 37,
    PROTO_MSG_UPLOAD = 38,      /* SCENE_CHUNK layout: a piece of the submitted bundle */
    PROTO_MSG_FETCH_FRAME = 39, /* a frame-range job's image of one frame */
    /* server -> client */
    PROTO_MSG_SUBMITTED = 48, /* JOB_REF layout: the new job's id */
    PROTO_MSG_JOB_LIST = 49,
    PROTO_MSG_JOB_INFO = 50,
    PROTO_MSG_IMAGE = 51 /* SCENE_CHUNK layout: a piece of the job's EXR file */
} proto_msg_type;

/* 1 when type is one of the values above (the frame decoder refuses others). */
int proto_msg_type_known(uint32_t type);
/* 1 for the handshake types, the only ones a peer may send before WELCOME. */
int proto_msg_type_preauth(uint32_t type);
/* Static name ("HELLO"), or "unknown". */
const char *proto_msg_type_name(uint32_t type);

/* Caps (bytes for strings, entries for lists). */
#define PROTO_MAX_NAME 64u
#define PROTO_MAX_PATH 255u /* file names in JOB_INFO and ENV */
#define PROTO_MAX_BUILD_ID 64u
#define PROTO_MAX_ERROR_TEXT 1024u
#define PROTO_MAX_SLOTS 1024u                             /* WORK_REQUEST slots */
#define PROTO_MAX_HEARTBEAT_TASKS 1024u                   /* task ids in one HEARTBEAT */
#define PROTO_MAX_SCENE_CHUNK (1u << 20)                  /* data bytes in one SCENE_CHUNK */
#define PROTO_MAX_TILE_PIXELS (PT_TILE_MAX * PT_TILE_MAX) /* pixels in one TASK / RESULT tile */
#define PROTO_HASH_SIZE 32u                               /* scene content hash (SHA-256) */
#define PROTO_NONCE_SIZE 32u
#define PROTO_MAC_SIZE 32u               /* HMAC-SHA256 */
#define PROTO_RESULT_PIXEL_SIZE 40u      /* bytes per pixel in a narrow RESULT */
#define PROTO_RESULT_WIDE_PIXEL_SIZE 72u /* bytes per pixel in a wide RESULT (the most) */
#define PROTO_RESULT_WIDE_RGB 1u         /* RESULT pixel form: RGB sums in 16 bytes */
#define PROTO_RESULT_WIDE_SQ 2u          /* RESULT pixel form: sum of squares in 16 bytes */
#define PROTO_RESULT_PASSES 4u           /* RESULT pixel form: pass sums follow the pixels */
#define PROTO_RESULT_WIDE_PASSES 8u      /* RESULT pixel form: pass sums in 16 bytes */
#define PROTO_RESULT_GUIDE 16u           /* RESULT pixel form: guiding statistics follow */
#define PROTO_RESULT_CLAMPED 32u    /* RESULT pixel form: a clamped-contribution count follows */
#define PROTO_RESULT_PASS_SIZE 268u /* bytes per pixel of narrow pass sums */
#define PROTO_RESULT_WIDE_PASS_SIZE 404u /* bytes per pixel of wide pass sums (the most) */
#define PROTO_RESULT_HEADER_SIZE 69u     /* bytes of RESULT before its pixels */

/* Film flags (TASK, SUBMIT). Decoders refuse a bit not defined here. */
#define PROTO_FILM_TRANSPARENT 1u /* camera rays that escape add nothing; the EXR gets A */
/* Bits 1 to 5: the render passes (PT_PASS_* of tile.h, shifted): a task
 * renders them and its RESULT carries their sums (PROTO_RESULT_PASSES). */
#define PROTO_FILM_PASS_SHIFT 1u
#define PROTO_FILM_PASSES (PT_PASS_ALL << PROTO_FILM_PASS_SHIFT)
/* Bit 7: the coordinator denoises the finished image (denoise_frame.h) and
 * writes its layer denoised.R/G/B; the passes it reads are among bits 1-6.
 * Workers render as the passes ask and otherwise ignore it. */
#define PROTO_FILM_DENOISE (1u << 7)
/* Bit 8, with bit 7: progressive saves are denoised too (server/sched/writer.h). */
#define PROTO_FILM_DENOISE_PROGRESSIVE (1u << 8)
/* Bit 9: bidirectional path tracing (pt_render_params.bdpt): a worker
 * renders the task with it; the coordinator refused the job at submission
 * where the scene cannot take it (pt_render_check_bdpt). */
#define PROTO_FILM_BDPT (1u << 9)
/* Bit 10, SUBMIT: the user said --bdpt=off. Without it or bit 9 the
 * coordinator decides (--bdpt auto, pt_bdpt_auto) when it admits the job
 * and sets bit 9 where bdpt renders it; workers read bit 9 only. */
#define PROTO_FILM_BDPT_OFF (1u << 10)
#define PROTO_FILM_KNOWN                                                                           \
    (PROTO_FILM_TRANSPARENT | PROTO_FILM_PASSES | PROTO_FILM_DENOISE |                             \
     PROTO_FILM_DENOISE_PROGRESSIVE | PROTO_FILM_BDPT | PROTO_FILM_BDPT_OFF)
/* The film flags of --bdpt's PT_BDPT_* (bdpt_auto.h): auto sets neither,
 * and the coordinator decides. */
static inline uint32_t proto_film_of_bdpt(int mode)
{
    return mode == PT_BDPT_ON ? PROTO_FILM_BDPT : mode == PT_BDPT_OFF ? PROTO_FILM_BDPT_OFF : 0u;
}
/* ... and the PT_BDPT_* of a job's film flags. */
static inline int proto_bdpt_of_film(uint32_t flags)
{
    return (flags & PROTO_FILM_BDPT)       ? PT_BDPT_ON
           : (flags & PROTO_FILM_BDPT_OFF) ? PT_BDPT_OFF
                                           : PT_BDPT_AUTO;
}
/* The PT_PASS_* mask of film flags, and the flags of a mask. */
static inline uint32_t proto_film_passes(uint32_t flags)
{
    return (flags & PROTO_FILM_PASSES) >> PROTO_FILM_PASS_SHIFT;
}
static inline uint32_t proto_film_of_passes(uint32_t passes)
{
    return (passes & PT_PASS_ALL) << PROTO_FILM_PASS_SHIFT;
}

enum { PROTO_ROLE_WORKER = 1, PROTO_ROLE_CLIENT = 2 };

/* ERROR codes. Decoders accept any value, so a newer peer may add codes. */
enum {
    PROTO_E_PROTOCOL = 1,  /* malformed frame or message, or one out of place */
    PROTO_E_VERSION = 2,   /* protocol version not supported */
    PROTO_E_AUTH = 3,      /* authentication failed */
    PROTO_E_BUILD = 4,     /* renderer build id differs from the server's */
    PROTO_E_LIMIT = 5,     /* a cap was exceeded */
    PROTO_E_NOT_FOUND = 6, /* unknown scene hash, job or task */
    PROTO_E_INTERNAL = 7,  /* the sender failed for its own reasons */
    PROTO_E_DENIED = 8     /* not allowed for this peer's identity (another's job) */
};

/* The renderer build id of this binary (pt_build_id, common/base/version.h):
 * workers of another build would break bit-identical merging, so HELLO
 * carries it. */
const char *proto_build_id(void);

/* HELLO capability bits. */
/* The worker denoises regions of frames (DENOISE_TASK); the coordinator
 * leases them only to workers that say so. */
#define PROTO_CAP_DENOISE 1u

/* HELLO
 *   offset   size  type  meaning
 *   0        2     u16   protocol version the peer speaks (PROTO_VERSION)
 *   2        1     u8    role: PROTO_ROLE_WORKER or PROTO_ROLE_CLIENT
 *   3        2+a   str   name of the peer (host, user), a <= PROTO_MAX_NAME
 *   5+a      2     u16   render threads (0 for a client)
 *   7+a      2+b   str   renderer build id, b <= PROTO_MAX_BUILD_ID
 *   9+a+b    4     u32   capability bits (PROTO_CAP_*; unknown bits ignored)
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
 * AUTH (mutual: the peer proves the token, and asks the server to prove it)
 *   0    32   u8[32]  HMAC-SHA256 over the server's nonce (protocol/auth.h)
 *   32   32   u8[32]  the peer's own nonce (random, fresh per connection)
 *   size 64 */
typedef struct proto_challenge {
    uint8_t nonce[PROTO_NONCE_SIZE];
} proto_challenge;
typedef struct proto_auth {
    uint8_t mac[PROTO_MAC_SIZE];
    uint8_t nonce[PROTO_NONCE_SIZE];
} proto_auth;

/* WELCOME
 *   0    8    u64     session id
 *   8    32   u8[32]  the server's proof: HMAC-SHA256 over both nonces under the
 *                     token the peer authenticated with (proto_auth_server_proof);
 *                     the peer checks it before it sends anything else
 *   40   2+a  str     server's renderer build id, a <= PROTO_MAX_BUILD_ID
 *   size 42+a */
typedef struct proto_welcome {
    uint64_t session_id;
    uint8_t proof[PROTO_MAC_SIZE];
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

/* ENV (inside SUBMIT and TASK): the job's environment light, the light that
 * rays leaving the scene see (common/render/env.h)
 *   0    2+e  str  the map's file name in the bundle, relative to the entry
 *                  file's folder, e <= PROTO_MAX_PATH ("": no map); the
 *                  coordinator accepts only PT_BUNDLE_ENV_NAME
 *   2+e  4    f32  strength: the map's factor (finite, >= 0)
 *   6+e  4    f32  rotation about +Y in degrees (finite)
 *   10+e 1    u8   1: a uniform environment of the colour below (then no map), else 0
 *   11+e 12   f32×3 that colour, linear RGB radiance (each finite, >= 0)
 *   size 23+e
 * No map and no colour: no environment (strength and rotation unused). */
typedef struct proto_env {
    char name[PROTO_MAX_PATH + 1]; /* NUL-terminated; "" no map */
    float strength, rotate_deg;
    uint8_t background; /* 1: uniform, of rgb */
    float rgb[3];
} proto_env;

/* The default: no environment, strength 1, no rotation. */
void proto_env_none(proto_env *e);
/* 1 when e lights anything (a map or a uniform colour). */
int proto_env_any(const proto_env *e);
/* 1 when a and b are the same environment, bit for bit. */
int proto_env_same(const proto_env *a, const proto_env *b);

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
 *   92   2+c  str      camera name, c <= PROTO_MAX_NAME ("": the scene's first camera,
 *                      or a view framing the scene when it has none; a name, node
 *                      name or index; or a placement "look:X,Y,Z:X,Y,Z[:fov=D|
 *                      :ortho=W]", pt_camera_look_parse in common/scene/scene.h)
 *   94+c 23+e ENV      the environment light (ENV layout, above)
 *   117+c+e 4 u32      film flags (PROTO_FILM_*; unknown bits refused)
 *   121+c+e 2+v str    KHR_materials_variants name, v <= PROTO_MAX_NAME ("": none)
 *   123+c+e+v 1 u8     animate: 1 the scene is posed at the time below (a frame of
 *                      a frame-range job), 0 the file's still pose (0 or 1)
 *   124+c+e+v 8 f64    time in seconds into the animation (finite, >= 0; 0 when
 *                      animate is 0)
 *   132+c+e+v 2+n str  animation: "" every animation, else a name or decimal
 *                      index (pt_scene_opts.animation), n <= PROTO_MAX_NAME
 *   134+c+e+v+n 16 SHUTTER motion blur's shutter (SHUTTER layout, below)
 *   150+c+e+v+n 8 CLAMP  sample clamping (CLAMP layout, below)
 *   158+c+e+v+n 37 GUIDE path guiding (GUIDE layout, below)
 *   size 195+c+e+v+n
 * A frame-range job's frames are separate jobs on the wire: each has its own
 * job id (srv_frame_job_id, server/sched/frames.h), so a task id, a RESULT and a
 * JOB_END name one frame's tasks. */
typedef struct proto_task {
    uint64_t job_id, task_id;
    pt_rect tile;
    uint32_t s0, s1;
    uint32_t width, height;
    uint32_t seed;
    uint16_t max_depth, rr_depth;
    uint8_t scene_hash[PROTO_HASH_SIZE];
    uint32_t lease_ms;
    char camera[PROTO_MAX_NAME + 1]; /* NUL-terminated; "" the default view */
    proto_env env;
    uint32_t film_flags;                /* PROTO_FILM_* */
    char variant[PROTO_MAX_NAME + 1];   /* material variant; "" each primitive's own */
    uint8_t animate;                    /* 1: posed at time */
    double time;                        /* seconds */
    char animation[PROTO_MAX_NAME + 1]; /* "" every animation */
    double shutter[2];                  /* SHUTTER: open, close; 0, 0 off */
    float clamp[2];                     /* CLAMP: direct, indirect; 0 off */
    uint8_t guided;                     /* GUIDE: PROTO_GUIDE_* of pass guide_pass */
    uint32_t guide_pass;
    uint8_t guide_hash[PROTO_HASH_SIZE]; /* the pass's distribution (proto_guide_encode) */
} proto_task;

/* SHUTTER (in TASK and SUBMIT): motion blur's shutter, in seconds after the
 * frame's time (a still's: 0), so that what the scene's animation moves in
 * [time + open, time + close] blurs (common/scene/motion.h).
 *   0    8    f64      open
 *   8    8    f64      close
 *   size 16
 * Both finite with 0 <= open <= close <= PROTO_MAX_SHUTTER_S; close == open
 * is no motion blur (0, 0 when off). Clients give fractions of a frame and
 * the frame rate (ptctl submit --shutter, --fps) and send their seconds. */
#define PROTO_MAX_SHUTTER_S 3600.0
/* NULL when open and close make a shutter, else what is wrong. */
const char *proto_shutter_problem(const double shutter[2]);

/* CLAMP (in TASK and SUBMIT): sample clamping, biased and off by default
 * (pt_render_params.clamp_direct, clamp_indirect: a contribution whose
 * R + G + B passes the limit is scaled down to it, as Cycles' Clamp Direct
 * and Clamp Indirect).
 *   0    4    f32      direct: light reaching the camera or the first surface it sees
 *   4    4    f32      indirect: light after more bounces
 *   size 8
 * Each finite with 0 <= limit <= PROTO_MAX_CLAMP; 0 is off. The floats are
 * sent as their bits, so a worker clamps exactly as ptworker --clamp-direct
 * of the same value does. */
#define PROTO_MAX_CLAMP 1e30f
/* NULL when both limits are finite and in [0, PROTO_MAX_CLAMP], else what is wrong. */
const char *proto_clamp_problem(const float clamp[2]);

/* GUIDE (in TASK): path guiding (common/render/guide.h), learned by the farm
 * in passes at fixed sample boundaries (pt_guide_pass_end).
 *   0    1    u8       guided: PROTO_GUIDE_NONE (0) not guided;
 *                      PROTO_GUIDE_RECORD (1) samples of guided pass `pass`,
 *                      recording statistics; PROTO_GUIDE_LAST (2) samples of
 *                      guided pass `pass`, the job's last, recording none
 *   1    4    u32      pass (0 when not guided; <= PROTO_MAX_GUIDE_PASS)
 *   5    32   u8[32]   SHA-256 of the pass's distribution as proto_guide_encode
 *                      writes it (zeros when not guided); the worker fetches it
 *                      with GUIDE_GET (SCENE_GET layout) once and keeps it
 *   size 37
 * A guided task renders with the distribution, draws directions from it with
 * probability 0 in pass 0 and PT_GUIDE_PASS_PROB after (as ptworker --guiding
 * on). Of RECORD it returns its statistics in RESULT (PROTO_RESULT_GUIDE); of
 * LAST, whose statistics no distribution would be built from (the last pass
 * runs to the job's spp, pt_guide_pass_end), it records nothing and its
 * RESULT carries none, as the standalone render's last pass records none
 * (pt_guide_run_begin). Recording never changes a sample, so the pixels are
 * the same either way. GUIDE_CHUNK has the SCENE_CHUNK layout, the total at
 * most PROTO_MAX_GUIDE_BYTES; its data is the distribution packed with zlib
 * (proto_guide_pack, protocol/guide.h), which the worker unpacks before it
 * checks the hash. */
enum { PROTO_GUIDE_NONE = 0, PROTO_GUIDE_RECORD = 1, PROTO_GUIDE_LAST = 2 };
#define PROTO_MAX_GUIDE_PASS 31u
#define PROTO_MAX_GUIDE_NODES (1u << 24) /* PT_GUIDE_MAX_NODES */
#define PROTO_MAX_GUIDE_BYTES (256u << 20)

/* SUBMIT's guiding mode, ptctl submit --guiding. */
enum { PROTO_GUIDING_OFF = 0, PROTO_GUIDING_ON = 1, PROTO_GUIDING_AUTO = 2 };

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

/* One entry of RESULT's guiding statistics: a node and its value. */
typedef struct proto_guide_entry {
    uint32_t node;
    uint64_t value;
} proto_guide_entry;

/* RESULT
 *   0    8    u64   job id
 *   8    8    u64   task id
 *   16   16   u32×4 tile x0, y0, x1, y1 (x0 < x1, y0 < y1)
 *   32   4    u32   s0
 *   36   4    u32   s1 (s0 < s1)
 *   40   8    u64   samples rejected (NaN/Inf) over the tile
 *   48   8    u64   rays traced
 *   56   8    u64   paths ended by the depth cap (pt_render_stats.capped)
 *   64   4    u32   N: pixels; must equal (x1-x0)*(y1-y0) and be <= PROTO_MAX_TILE_PIXELS
 *   68   1    u8    pixel form: PROTO_RESULT_WIDE_RGB | PROTO_RESULT_WIDE_SQ |
 *                   PROTO_RESULT_PASSES | PROTO_RESULT_WIDE_PASSES |
 *                   PROTO_RESULT_GUIDE | PROTO_RESULT_CLAMPED, no other bit
 *                   (WIDE_PASSES only with PASSES)
 *   69   PN         pixels, row-major over the tile, P = 40 to 72 bytes, each:
 *                     the sums of pt_pixel_acc (tile.h) in fixed point: R, G, B
 *                     (signed, units of 2^-32), each an i64 (8 bytes) or, with
 *                     WIDE_RGB, two u64 low half first (16 bytes); then the sum
 *                     of squared luminance (unsigned, units of 2^-48), a u64 or,
 *                     with WIDE_SQ, two u64 low half first
 *                     P-8  4  u32  n: samples accumulated, n <= s1 - s0
 *                     P-4  4  u32  hits: of those, samples whose camera ray hit the
 *                                  scene, hits <= n (the coverage is hits / n)
 *   69+PN QN        with PASSES: each pixel's pass sums (pt_pass_acc, tile.h),
 *                   row-major, Q = 140 bytes (narrow) or 276 (WIDE_PASSES):
 *                     13 sums (signed, units of 2^-32: albedo RGB, normal XYZ,
 *                     emission RGB, depth, the beauty's RGB over even sample
 *                     indices), each an i64 or two u64 low half first; 4 sums
 *                     of squares (unsigned, units of 2^-48: albedo, normal,
 *                     emission, depth), each a u64 or two; then a u32: of the
 *                     pixel's n samples, those of even index (<= n); then
 *                     Cryptomatte, objects then materials, PT_CRYPTO_KEEP (8)
 *                     u32 ids then 8 u32 sample counts each, in the merge's
 *                     canonical form (pt_crypto_canonical: ascending ids,
 *                     unused entries 0 last, counts summing to <= n)
 *   ..   with CLAMPED (set exactly when the count is not 0; the task had
 *                   --clamp-direct or --clamp-indirect): a u64, the
 *                   contributions its samples scaled down to the clamp
 *                   (pt_render_stats.clamped), at most 2 (max depth + 2) per
 *                   sample (the server checks)
 *   ..   with GUIDE (the task was PROTO_GUIDE_RECORD): the statistics it recorded
 *                   (pt_guide_stats), sparse, in canonical form:
 *                     +0  4  u32  the guide's spatial nodes (its nsnode)
 *                     +4  4  u32  the guide's directional nodes (its nqnode)
 *                     +8  4  u32  C: record counts listed, C <= nsnode
 *                     +12 4  u32  S: fixed-point sums listed, S <= nqnode
 *                     +16 12C     (u32 spatial node, u64 count), nodes ascending,
 *                                 each < nsnode, counts > 0
 *                     ..  12S     (u32 directional node, u64 sum), likewise < nqnode
 *   size 69+PN[+QN][+8][+16+12(C+S)] (PROTO_RESULT_HEADER_SIZE + P x N; P =
 *   PROTO_RESULT_PIXEL_SIZE narrow, PROTO_RESULT_WIDE_PIXEL_SIZE with both bits)
 * The encoder sets a bit only when some pixel's sum of that kind does not fit
 * 64 bits: RGB sums fit below 2^31 per task, squares below 2^16, so a pixel of
 * ordinary radiance costs 40 bytes on the wire as with double sums. The sums
 * are not checked (plausibility is the server's business). */
typedef struct proto_result {
    uint64_t job_id, task_id;
    pt_rect tile;
    uint32_t s0, s1;
    uint64_t rejected, rays;
    uint64_t capped; /* paths ended by the depth cap */
    uint32_t npixels;
    pt_pixel_acc *pixels; /* npixels entries */
    int owns_pixels;      /* 1 when the decoder allocated pixels */
    pt_pass_acc *pass;    /* NULL, or npixels pass sums; decoded, they lie right after
                             pixels[npixels - 1] in the same allocation (pt_film_add_tile
                             of a film with passes reads them there) */
    /* Guiding statistics (PROTO_RESULT_GUIDE): guide == NULL when none. The
     * decoder allocates guide (gcount + gsum entries, counts first); encoders
     * read it; proto_result_fini frees what the decoder allocated. */
    uint32_t g_nsnode, g_nqnode, gcount, gsum;
    proto_guide_entry *guide;
    int owns_guide;
    uint64_t clamped; /* contributions clamped (PROTO_RESULT_CLAMPED when not 0) */
} proto_result;

/* DENOISE_TASK: one region of a finished frame to denoise (the coordinator
 * cuts a --denoise job's frame as pt_denoise_regions does,
 * common/image/denoise.h, and races its workers for the regions). Sent only
 * to a worker whose HELLO had PROTO_CAP_DENOISE, against a slot it asked for
 * (WORK_REQUEST), as a TASK is.
 *   0    8    u64      job id (a frame's wire id, as TASK's)
 *   8    8    u64      task id: PROTO_DENOISE_TASK_BIT | the region's index
 *   16   4    u32      crop width  \ the crop around the region, cut from the
 *   20   4    u32      crop height /  frame: each <= PROTO_MAX_DENOISE_CROP
 *   24   16   u32×4    region x0, y0, x1, y1 within the crop (x0 < x1 <= crop
 *                      width, y0 < y1 <= crop height, each side <=
 *                      PROTO_MAX_DENOISE_REGION)
 *   40   4    f32      despeckle (0, or finite in [1, PROTO_MAX_DESPECKLE]:
 *                      pt_denoise_input's)
 *   44   4    u32      lease in milliseconds (heartbeat the task id before it runs out)
 *   48   32   u8[32]   SHA-256 of the crop's input (below)
 *   80   8    u64      its size: crop width x height x PROTO_DENOISE_PLANES x 4
 *   size 88
 * The input is fetched with DENOISE_GET (SCENE_GET layout, the hash above)
 * and comes in DENOISE_CHUNK frames (SCENE_CHUNK layout): the 20 planes in
 * pt_denoise_input_set_planes' order, each crop width x height little-endian
 * f32, row-major. The worker checks the hash, denoises the crop as a whole
 * image (pt_denoise: its checks refuse what is not a denoiser's input) and
 * returns the region's pixels. A crop's corner lies on the denoiser's tile
 * grid and its margin covers the denoiser's reach, so they are the bits of
 * the whole frame's denoising there. A DENOISE_GET for a frame the
 * coordinator has finished denoising (it races its workers) gets no answer;
 * JOB_END for the frame follows once its image is written, and the worker
 * drops the task. */
#define PROTO_DENOISE_TASK_BIT (1ull << 63)
#define PROTO_MAX_DENOISE_REGION 1024u
/* The region and PT_DENOISE_MARGIN (96) on both sides; test_msg checks it. */
#define PROTO_MAX_DENOISE_CROP (PROTO_MAX_DENOISE_REGION + 256u)
/* PT_DENOISE_PLANES and PT_DENOISE_DESPECKLE_MAX (common/image/denoise.h),
 * which protocol/ does not include; test_msg checks that they agree. */
#define PROTO_DENOISE_PLANES 20u
#define PROTO_MAX_DESPECKLE 1e6f
typedef struct proto_denoise_task {
    uint64_t job_id, task_id;
    uint32_t crop_w, crop_h;
    pt_rect region; /* within the crop */
    float despeckle;
    uint32_t lease_ms;
    uint8_t hash[PROTO_HASH_SIZE];
    uint64_t size;
} proto_denoise_task;

/* DENOISE_RESULT
 *   0    8    u64      job id
 *   8    8    u64      task id (PROTO_DENOISE_TASK_BIT set)
 *   16   16   u32×4    region x0, y0, x1, y1 within the crop (as the task's)
 *   32   4    u32      N: pixels, (x1 - x0) x (y1 - y0)
 *   36   12N  f32      the denoised R plane, then G, then B: N little-endian
 *                      f32 each, row-major over the region
 *   size 36+12N
 * Decoded, data points into the payload (borrowed, no copy); the values are
 * not checked (the server does: finite, and the same bits as its own when
 * it verifies one). */
typedef struct proto_denoise_result {
    uint64_t job_id, task_id;
    pt_rect region;
    uint32_t npixels;
    const uint8_t *data; /* 12 x npixels bytes */
} proto_denoise_result;

/* HEARTBEAT
 *   0    2    u16     N: task ids, N <= PROTO_MAX_HEARTBEAT_TASKS
 *   2    8N   u64[N]  the tasks the worker holds (leased, queued or running)
 *   size 2+8N */
typedef struct proto_heartbeat {
    uint16_t count;
    uint64_t task_ids[PROTO_MAX_HEARTBEAT_TASKS];
} proto_heartbeat;

/* JOB_END (JOB_REF layout, below): the job was cancelled or failed, or is
 * paused (its state folder cannot be written; its tasks come again later). The worker
 * drops the tasks of it that it holds and has not started, discards the
 * results of those still rendering, and asks for work again, so its threads go
 * to the next job at once. A job it holds nothing of is ignored. */

/* ---- client messages ----
 *
 * A client (HELLO role PROTO_ROLE_CLIENT) authenticates like a worker, then
 * sends requests; the server answers each one (or ERROR and closes):
 *   SUBMIT, UPLOAD...        -> SUBMITTED (once the last UPLOAD byte checked out)
 *   LIST                     -> JOB_LIST
 *   STATUS (JOB_REF)         -> JOB_INFO
 *   WATCH (JOB_REF)          -> JOB_INFO now, then about once a second and when
 *                               the job ends (state DONE, CANCELLED or FAILED)
 *   CANCEL (JOB_REF)         -> JOB_INFO (state CANCELLED, or the state it had
 *                               when it had already ended)
 *   FETCH (JOB_REF)          -> IMAGE frames, offsets 0.. in order, until total
 *   FETCH_FRAME              -> IMAGE frames likewise: that frame's latest EXR
 * LIST has an empty payload (size 0).
 *
 * UPLOAD and IMAGE use the SCENE_CHUNK layout and decoder: hash is the SHA-256
 * of the whole file (the bundle announced by SUBMIT; the EXR sent for FETCH),
 * so the receiver checks what it assembled. */

#define PROTO_MAX_JOBS 4096u      /* entries in one JOB_LIST */
#define PROTO_MAX_FRAMES_SHOWN 8u /* frames rendering listed in one JOB_INFO */

/* JOB_REF (STATUS, WATCH, CANCEL, FETCH, SUBMITTED)
 *   0    8    u64  job id
 *   size 8 */
typedef struct proto_job_ref {
    uint64_t job_id;
} proto_job_ref;

/* FETCH_FRAME
 *   0    8    u64  job id (a frame-range job)
 *   8    4    u32  frame number
 *   size 12 */
typedef struct proto_fetch_frame {
    uint64_t job_id;
    uint32_t frame;
} proto_fetch_frame;

/* SUBMIT
 *   0    2+a  str  job name, a <= PROTO_MAX_NAME (may be empty)
 *   2+a  4    u32  width  \ both 0: the server picks (512 wide, height from
 *   6+a  4    u32  height /  the camera's aspect); else both > 0
 *   10+a 4    u32  samples per pixel (> 0)
 *   14+a 4    u32  seed
 *   18+a 4    i32  priority (higher runs first; ties by submission order)
 *   22+a 2    u16  max depth (bounces; 0: the server's default)
 *   24+a 4    u32  min spp for adaptive sampling (0: one chunk)
 *   28+a 8    f64  target error for adaptive sampling (0: off; finite, >= 0)
 *   36+a 8    u64  bundle size in bytes (> 0), sent next in UPLOAD frames
 *   44+a 32   u8[32] SHA-256 of the bundle
 *   76+a 2+c  str  camera name, c <= PROTO_MAX_NAME ("": the scene's first camera)
 *   78+a+c 8  f64  min gain for adaptive sampling, the lowest-mean-error rule
 *                  (0: off; finite, >= 0; see pt_tile_stops)
 *   86+a+c 23+e ENV the environment light (ENV layout, above); a map named
 *                  here travels in the bundle
 *   109+a+c+e 4 u32 film flags (PROTO_FILM_*; unknown bits refused)
 *   113+a+c+e 2+v str KHR_materials_variants name, v <= PROTO_MAX_NAME ("": none;
 *                  the server refuses a name the scene lacks)
 *   115+a+c+e+v 4 u32 first frame \  a frame range (common/base/frames.h):
 *   119+a+c+e+v 4 u32 last frame   | step 0 (and the others 0): a still;
 *   123+a+c+e+v 4 u32 frame step  /  else pt_frames_check's rules
 *   127+a+c+e+v 8 f64 frames per second (finite, > 0 for a range; 0 for a still)
 *   135+a+c+e+v 2+n str animation: "" every animation, else a name or decimal
 *                  index, n <= PROTO_MAX_NAME ("" for a still)
 *   137+a+c+e+v+n 16 SHUTTER motion blur's shutter (SHUTTER layout, above)
 *   153+a+c+e+v+n 8 CLAMP sample clamping (CLAMP layout, above)
 *   161+a+c+e+v+n 1 u8 guiding: PROTO_GUIDING_OFF, _ON or _AUTO (the server turns
 *                  on or auto into guiding where the scene has glossy surfaces)
 *   size 162+a+c+e+v+n
 * The decoder checks shape only (width and height both 0 or both > 0, spp > 0,
 * size > 0, target error and min gain finite and >= 0); caps, and whether the
 * two rules may be combined, are the server's business. */
typedef struct proto_submit {
    char name[PROTO_MAX_NAME + 1];
    uint32_t width, height, spp, seed;
    int32_t priority;
    uint16_t max_depth;
    uint32_t min_spp;
    double target_error;
    uint64_t bundle_size;
    uint8_t bundle_hash[PROTO_HASH_SIZE];
    char camera[PROTO_MAX_NAME + 1]; /* NUL-terminated; "" the default view */
    double min_gain;
    proto_env env;
    uint32_t film_flags;                          /* PROTO_FILM_* */
    char variant[PROTO_MAX_NAME + 1];             /* material variant; "" each primitive's own */
    uint32_t frame_first, frame_last, frame_step; /* step 0: a still */
    double fps;
    char animation[PROTO_MAX_NAME + 1];
    double shutter[2]; /* SHUTTER: open, close; 0, 0 off */
    float clamp[2];    /* CLAMP: direct, indirect; 0 off */
    uint8_t guiding;   /* PROTO_GUIDING_* */
} proto_submit;

enum {
    PROTO_JOB_QUEUED = 1,
    PROTO_JOB_RUNNING = 2,
    PROTO_JOB_DONE = 3,
    PROTO_JOB_CANCELLED = 4,
    PROTO_JOB_FAILED = 5
};
/* Static name ("queued", ...), or "unknown". */
const char *proto_job_state_name(uint32_t state);

/* JOB_INFO (also each entry of JOB_LIST)
 *   0    8    u64  job id
 *   8    1    u8   state (PROTO_JOB_*; any value decodes, see proto_job_state_name)
 *   9    4    i32  priority
 *   13   2+a  str  job name, a <= PROTO_MAX_NAME
 *   ..   2+b  str  owner (the submitting client's identity: its --clients-file NAME, else its HELLO
 * name), b <= PROTO_MAX_NAME
 *   ..   2+c  str  scene (the bundle's entry file name), c <= PROTO_MAX_PATH
 *   ..   2+d  str  output file name (in the server's output folder), d <= PROTO_MAX_PATH
 *   ..   4    u32  width
 *   ..   4    u32  height
 *   ..   4    u32  samples per pixel asked for
 *   ..   8    u64  samples merged
 *   ..   8    u64  samples total (width x height x spp; adaptive sampling may end sooner)
 *   ..   4    u32  passes merged for every tile
 *   ..   4    u32  passes
 *   ..   4    u32  tiles stopped by adaptive sampling
 *   ..   4    u32  tiles
 *   ..   4    u32  workers holding tasks of this job now
 *   ..   8    f64  render seconds so far (across coordinator restarts)
 *   ..   8    f64  samples per second (recent)
 *   ..   8    f64  estimated relative error of the image (negative: unknown)
 *   ..   8    u64  submitted, Unix seconds
 *   ..   4    u32  position in the queue (1 = next; 0 when not queued)
 *   ..   2+e  str  message (why it failed, ...), e <= PROTO_MAX_ERROR_TEXT
 *   ..   8    u64  paths ended by the depth cap, over the results merged
 *   ..   8    u64  samples rejected: the workers' NaN/Inf samples and those of results
 *                  that held no sample at all, over the results merged
 *   ..   4    u32  first frame \  the frame range (step 0: a still, and the
 *   ..   4    u32  last frame   | frame fields below are 0); for a range,
 *   ..   4    u32  frame step  /  the sample counts above cover every frame
 *   ..   4    u32  frames done
 *   ..   4    u32  frames rendering (started, not done)
 *   ..   1    u8   K: frames listed next, K <= PROTO_MAX_FRAMES_SHOWN
 *   ..   20K       the frames rendering, earliest first, each:
 *                    +0  4  u32  frame number
 *                    +4  8  u64  samples merged
 *                    +12 8  u64  samples total
 *   ..   1    u8   guiding: 1 the job is guided (path guiding learned by the farm), 0 not
 *   ..   4    u32  the guiding pass whose samples are being rendered (0 when not guided
 *                  or not running)
 *   ..   4    u32  the samples per pixel its distribution was learned from (0 in pass 0)
 *   ..   8    u64  contributions clamped (--clamp-direct/--clamp-indirect), over the
 *                  results merged
 *   ..   1    u8   bidirectional: 1 the job renders with bidirectional path tracing
 *                  (PROTO_FILM_BDPT: asked for, or chosen by --bdpt auto), 0 not
 *   size 162+a+b+c+d+e+20K */
typedef struct proto_job_info {
    uint64_t job_id;
    uint8_t state;
    int32_t priority;
    char name[PROTO_MAX_NAME + 1];
    char owner[PROTO_MAX_NAME + 1];
    char scene[PROTO_MAX_PATH + 1];
    char output[PROTO_MAX_PATH + 1];
    uint32_t width, height, spp;
    uint64_t samples_done, samples_total;
    uint32_t passes_done, passes;
    uint32_t tiles_stopped, tiles;
    uint32_t workers;
    double seconds, rate, error;
    uint64_t submitted;
    uint32_t queue_pos;
    char message[PROTO_MAX_ERROR_TEXT + 1];
    uint64_t capped;                              /* paths ended by the depth cap */
    uint64_t clamped;                             /* contributions clamped (--clamp-*) */
    uint64_t rejected;                            /* samples merged as rejected */
    uint32_t frame_first, frame_last, frame_step; /* step 0: a still */
    uint32_t frames_done, frames_rendering;
    uint8_t nshown;
    struct {
        uint32_t frame;
        uint64_t samples_done, samples_total;
    } shown[PROTO_MAX_FRAMES_SHOWN];
    uint8_t guided;      /* 1: path guiding learned by the farm */
    uint32_t guide_pass; /* the pass being rendered (0 when not guided) */
    uint32_t guide_spp;  /* samples per pixel its distribution was learned from */
    uint8_t bdpt;        /* 1: bidirectional path tracing (PROTO_FILM_BDPT) */
} proto_job_info;

/* JOB_LIST
 *   0    4    u32  N: jobs, N <= PROTO_MAX_JOBS
 *   4    ...       N JOB_INFO entries, back to back
 * Decoded, jobs is a pt_malloc'd array of N entries (NULL when N is 0) that
 * the caller frees with pt_free; N is checked against the bytes present (each
 * entry needs at least 162 bytes) before anything is allocated. */
typedef struct proto_job_list {
    uint32_t count;
    proto_job_info *jobs;
} proto_job_list;

pt_status proto_msg_encode_job_ref(proto_writer *w, const proto_job_ref *m, pt_error *err);
pt_status proto_msg_decode_job_ref(const uint8_t *p, size_t len, proto_job_ref *out, pt_error *err);

pt_status proto_msg_encode_fetch_frame(proto_writer *w, const proto_fetch_frame *m, pt_error *err);
pt_status proto_msg_decode_fetch_frame(const uint8_t *p, size_t len, proto_fetch_frame *out,
                                       pt_error *err);

pt_status proto_msg_encode_submit(proto_writer *w, const proto_submit *m, pt_error *err);
pt_status proto_msg_decode_submit(const uint8_t *p, size_t len, proto_submit *out, pt_error *err);

pt_status proto_msg_encode_job_info(proto_writer *w, const proto_job_info *m, pt_error *err);
pt_status proto_msg_decode_job_info(const uint8_t *p, size_t len, proto_job_info *out,
                                    pt_error *err);

/* Encodes count entries of jobs. */
pt_status proto_msg_encode_job_list(proto_writer *w, const proto_job_info *jobs, uint32_t count,
                                    pt_error *err);
/* May allocate (see JOB_LIST); PT_ERR_NOMEM when that fails. */
pt_status proto_msg_decode_job_list(const uint8_t *p, size_t len, proto_job_list *out,
                                    pt_error *err);

/* ---- encoders and decoders ---- */

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
 * allocation fails). A RESULT with pass sums always goes to an allocation of
 * its own, the pixels then the passes (out->pass), whatever buf is; a pass
 * whose even count exceeds its pixel's n, or whose Cryptomatte lists are not
 * canonical, is refused. Release with
 * proto_result_fini either way. */
pt_status proto_msg_decode_result(const uint8_t *p, size_t len, pt_pixel_acc *buf, size_t buf_cap,
                                  proto_result *out, pt_error *err);
/* Frees the pixels when the decoder allocated them, and clears the pointer. Accepts NULL. */
void proto_result_fini(proto_result *r);

pt_status proto_msg_encode_denoise_task(proto_writer *w, const proto_denoise_task *m,
                                        pt_error *err);
pt_status proto_msg_decode_denoise_task(const uint8_t *p, size_t len, proto_denoise_task *out,
                                        pt_error *err);

/* Encodes 12 x m->npixels bytes from m->data (npixels must equal the region's area). */
pt_status proto_msg_encode_denoise_result(proto_writer *w, const proto_denoise_result *m,
                                          pt_error *err);
/* out->data borrows from p: keep the payload alive while it is used. */
pt_status proto_msg_decode_denoise_result(const uint8_t *p, size_t len, proto_denoise_result *out,
                                          pt_error *err);

pt_status proto_msg_encode_heartbeat(proto_writer *w, const proto_heartbeat *m, pt_error *err);
pt_status proto_msg_decode_heartbeat(const uint8_t *p, size_t len, proto_heartbeat *out,
                                     pt_error *err);

#endif
