/*
 * ctl.h - the client side of the render queue: what ptctl does on the wire,
 * and how it shows what comes back.
 *
 * A ctl_conn is one blocking TCP connection to a ptserve in queue mode,
 * authenticated like a worker (HELLO with role PROTO_ROLE_CLIENT, CHALLENGE,
 * AUTH, WELCOME; protocol/msg.h, protocol/auth.h), mutually: a WELCOME whose
 * proof does not show that the server holds the token ends the connection
 * with PT_ERR_AUTH ("the coordinator does not know the token") before any
 * request is sent. Each request waits for its
 * reply; a reply that does not come within the connection's timeout is an
 * error (SO_RCVTIMEO / SO_SNDTIMEO on the socket). Frames received are capped
 * like the worker's: PROTO_MAX_PAYLOAD_PREAUTH until WELCOME, PROTO_MAX_PAYLOAD
 * after; the input buffer grows only as far as the frame being read.
 *
 * An ERROR from the server ends the request with PT_ERR_PROTO; its code and
 * text stay readable through ctl_server_code / ctl_server_text, so the caller
 * can tell "no such job" (PROTO_E_NOT_FOUND) from other refusals. Every other
 * failure names the server's address or the field at fault in err.
 *
 * The formatting half (JSON, progress lines, tables) is pure and writes to a
 * FILE or a caller's buffer. Strings from the server are never trusted: JSON
 * output escapes them and replaces bytes that are not UTF-8; human output
 * replaces control characters so a job name cannot drive the terminal.
 * Thread-safety: a ctl_conn belongs to one thread; the rest is reentrant.
 */
#ifndef PT_CLIENT_CTL_H
#define PT_CLIENT_CTL_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "common/base/error.h"
#include "common/scene/bundle.h"
#include "protocol/msg.h"

#define CTL_DEFAULT_SERVER "127.0.0.1:7878"
#define CTL_DEFAULT_TIMEOUT_MS 30000
/* The largest image FETCH accepts: the file is assembled in memory. */
#define CTL_MAX_IMAGE ((uint64_t)4 << 30)

typedef struct ctl_conn ctl_conn;

typedef struct ctl_opts {
    const char *server;   /* "HOST:PORT" (pt_net_split forms) */
    const uint8_t *token; /* the shared or a per-client token; may be empty (token_len 0) */
    size_t token_len;
    int timeout_ms;   /* connect, and each reply (> 0) */
    const char *name; /* HELLO name, at most PROTO_MAX_NAME bytes ("user@host") */
} ctl_opts;

/* Called with bytes done and the total, as an upload or download goes on. */
typedef void (*ctl_progress_fn)(uint64_t done, uint64_t total, void *arg);

/* Connects to o->server and authenticates. On success *out is a new
 * connection (ctl_close). PT_ERR_ARG for a malformed address, PT_ERR_IO for
 * the network (err names the address), PT_ERR_PROTO for a refusal or a
 * server that breaks the protocol, PT_ERR_AUTH for a server that cannot
 * prove the token in WELCOME. On a refusal *out is still set (NULL
 * otherwise) so that the caller can read the server's code; close it too. */
pt_status ctl_connect(const ctl_opts *o, ctl_conn **out, pt_error *err);
/* The same over a socket that is already connected (taken over: ctl_close
 * closes it, also after a failure); addr names the peer in messages. */
pt_status ctl_attach(int fd, const char *addr, const ctl_opts *o, ctl_conn **out, pt_error *err);
/* Closes the socket and frees. Accepts NULL. */
void ctl_close(ctl_conn *c);

/* The code of the ERROR the server sent (PROTO_E_*), 0 while none came. */
uint16_t ctl_server_code(const ctl_conn *c);
/* Its text ("" while none came). Accepts NULL. */
const char *ctl_server_text(const ctl_conn *c);
/* The server's renderer build id from WELCOME. */
const char *ctl_server_build(const ctl_conn *c);

/* SUBMIT m (whose bundle_size and bundle_hash must describe b; the caller
 * fills the rest), then b's bytes in UPLOAD frames of at most
 * PROTO_MAX_SCENE_CHUNK bytes, then waits for SUBMITTED: *job_id. An ERROR
 * the server sends during the upload ends it at once. */
pt_status ctl_submit(ctl_conn *c, const proto_submit *m, const pt_bundle *b,
                     ctl_progress_fn progress, void *arg, uint64_t *job_id, pt_error *err);

/* STATUS / CANCEL: one JOB_INFO in *out. */
pt_status ctl_status(ctl_conn *c, uint64_t job_id, proto_job_info *out, pt_error *err);
pt_status ctl_cancel(ctl_conn *c, uint64_t job_id, proto_job_info *out, pt_error *err);

/* LIST: *out as decoded (free out->jobs with pt_free). */
pt_status ctl_list(ctl_conn *c, proto_job_list *out, pt_error *err);

/* WATCH: sends the request; then each ctl_watch_next waits for the next
 * JOB_INFO (within the timeout). The caller stops at a terminal state. */
pt_status ctl_watch_begin(ctl_conn *c, uint64_t job_id, pt_error *err);
pt_status ctl_watch_next(ctl_conn *c, proto_job_info *out, pt_error *err);

/* FETCH: receives the job's image in IMAGE frames (offsets in order from 0,
 * the same total and hash in every frame, total in 1..CTL_MAX_IMAGE, no
 * empty frame) and checks the SHA-256 of the whole against the frames'
 * hash. On success *data is a pt_malloc'd buffer of *size bytes (pt_free). */
pt_status ctl_fetch(ctl_conn *c, uint64_t job_id, ctl_progress_fn progress, void *arg,
                    uint8_t **data, size_t *size, pt_error *err);
/* FETCH_FRAME: as ctl_fetch, the image of one frame of a frame-range job. */
pt_status ctl_fetch_frame(ctl_conn *c, uint64_t job_id, uint32_t frame, ctl_progress_fn progress,
                          void *arg, uint8_t **data, size_t *size, pt_error *err);

/* ---- helpers ---- */

/* Writes data to path atomically and durably (pt_write_file_atomic_mode),
 * mode 0666 before umask. Readers see the old file or the whole new one; a
 * failure, the folder's fsync included, leaves no temporary file behind. */
pt_status ctl_write_atomic(const char *path, const uint8_t *data, size_t size, pt_error *err);

/* 64 hex digits (either case) to 32 bytes: pt_hex_decode for a scene hash.
 * 0 on success, -1 if malformed (out untouched). */
int ctl_hex_to_hash(const char *hex, uint8_t out[PROTO_HASH_SIZE]);

/* "user@host" of this process, cut to PROTO_MAX_NAME bytes. */
void ctl_default_name(char out[PROTO_MAX_NAME + 1]);

/* 1 for PROTO_JOB_DONE, _CANCELLED and _FAILED. */
int ctl_job_ended(uint8_t state);

/* Fraction of the job done, 0..1 (1 once DONE; adaptive jobs end early). */
double ctl_job_fraction(const proto_job_info *j);

/* s as a JSON string, quotes included: '"', '\\' and control characters
 * escaped, bytes that are not well-formed UTF-8 replaced by U+FFFD. */
void ctl_json_string(FILE *f, const char *s);
/* One job as a JSON object (no trailing newline). */
void ctl_json_job(FILE *f, const proto_job_info *j);

/* Copies s to out (cap bytes, terminated) with control characters as '?'. */
void ctl_printable(const char *s, char *out, size_t cap);

/* A duration as "45s", "12m03s", "3h07m", "2d05h"; "-" when not finite or < 0. */
void ctl_format_duration(double seconds, char *out, size_t cap);

/* The live progress line of watch, without a newline, at most cap - 1 bytes:
 * bar, spp done/asked, percent, samples/s, workers, ETA, estimated error;
 * or the queue position while queued; or the final state. */
void ctl_progress_line(const proto_job_info *j, char *out, size_t cap);

#endif
