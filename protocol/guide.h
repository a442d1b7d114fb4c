/*
 * guide.h - path guiding's data on the wire: a learned distribution
 * (pt_guide, common/render/guide.h) as the bytes the coordinator hashes,
 * keeps in checkpoints and hands workers in GUIDE_CHUNK frames (packed with
 * zlib, below), and a pass's statistics (pt_guide_stats) as RESULT's sparse
 * entries (protocol/msg.h, PROTO_RESULT_GUIDE).
 *
 * GUIDE (the distribution), little-endian:
 *   offset   size     type     meaning
 *   0        4        u32      magic "PTGD"
 *   4        4        u32      format version (PROTO_GUIDE_VERSION)
 *   8        24       f32x6    bounds lo x, y, z, hi x, y, z
 *   32       4        u32      S: spatial nodes, 1 <= S <= PROTO_MAX_GUIDE_NODES
 *   36       4        u32      Q: directional nodes, 6 <= Q <= PROTO_MAX_GUIDE_NODES
 *   40       12S               each: u32 child, u32 axis, u32 tree (pt_guide_snode)
 *   40+12S   8Q                each: u32 child, f32 energy (pt_guide_qnode)
 *   size 40+12S+8Q
 * One encoding per distribution (the fields in order, floats as their bits),
 * so equal distributions have equal bytes and equal hashes, and a hash names
 * one distribution. The decoder checks the shape (magic, version, counts
 * against the bytes present); the tree itself (children in range, energies
 * finite) is pt_guide_check's, which a receiver runs before it samples.
 *
 * Statistics: a pass's counts and fixed-point sums are integers and add
 * exactly, saturating, in any order (pt_guide_stats_merge), so a pass's
 * statistics do not depend on how it was cut into tasks.
 *
 * Pure functions; any thread.
 */
#ifndef PT_PROTOCOL_GUIDE_H
#define PT_PROTOCOL_GUIDE_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"
#include "common/render/guide.h"
#include "protocol/msg.h"
#include "protocol/wire.h"

#define PROTO_GUIDE_MAGIC 0x44475450u /* "PTGD" */
#define PROTO_GUIDE_VERSION 1u
#define PROTO_GUIDE_HEADER 40u

/* Appends g's bytes (GUIDE above). PT_ERR_ARG for a guide of counts over the
 * caps; the writer's failure (PT_ERR_LIMIT, PT_ERR_NOMEM) else. */
pt_status proto_guide_encode(proto_writer *w, const pt_guide *g, pt_error *err);
/* A new guide from p[0, len): PT_ERR_FORMAT naming the fault (the shape
 * only; run pt_guide_check before sampling it), PT_ERR_NOMEM. */
pt_status proto_guide_decode(const uint8_t *p, size_t len, pt_guide **out, pt_error *err);

/* GUIDE_CHUNK's bytes: a distribution's GUIDE bytes compressed losslessly
 * with zlib (deflate, RFC 1950/1951), so a 1080p job's 59 MB distribution
 * crosses the network as a fraction of that. Little-endian:
 *   0    4    u32  magic "PTGZ"
 *   4    8    u64  n: the GUIDE bytes' length, PROTO_GUIDE_HEADER <= n <= PROTO_MAX_GUIDE_BYTES
 *   12   ..        one zlib stream of exactly those n bytes, nothing after it
 * TASK names a distribution by the SHA-256 of its GUIDE bytes, never of
 * these: a receiver unpacks, then checks the hash, so it samples exactly the
 * bytes the coordinator built whatever the compressor did. */
#define PROTO_GUIDE_PACK_MAGIC 0x5a475450u /* "PTGZ" */
#define PROTO_GUIDE_PACK_HEADER 12u
/* The most one byte of deflate data expands to (a 258-byte match coded in
 * two 1-bit codes: 1032 to 1, zlib's technical notes), which bounds n by the
 * stream's length before anything is allocated. */
#define PROTO_GUIDE_PACK_RATIO 1032u

/* *out (pt_malloc'd, the caller's) = raw[0, n) packed as above. PT_ERR_ARG
 * for n out of range, PT_ERR_NOMEM (zlib's failures too). */
pt_status proto_guide_pack(const uint8_t *raw, size_t n, uint8_t **out, size_t *out_len,
                           pt_error *err);
/* *out (pt_malloc'd, the caller's) = the GUIDE bytes that p[0, len) packs.
 * The declared length is checked against PROTO_MAX_GUIDE_BYTES and against
 * what the stream's length can expand to before the output is allocated,
 * and inflating stops at it: PT_ERR_FORMAT naming the fault (a bad magic, a
 * length out of range, a corrupt, short, long or trailed stream) with
 * nothing allocated, PT_ERR_NOMEM. The bytes are not decoded or hashed. */
pt_status proto_guide_unpack(const uint8_t *p, size_t len, uint8_t **out, size_t *out_len,
                             pt_error *err);

/* r's guiding statistics (g_nsnode ... guide, owns_guide) from s: its
 * non-zero counts and sums, ascending. PT_ERR_NOMEM. */
pt_status proto_guide_stats_to_result(const pt_guide_stats *s, proto_result *r, pt_error *err);
/* into += r's statistics (saturating, as pt_guide_stats_merge). PT_ERR_FORMAT
 * when r carries none or they were made for a guide of other sizes than
 * into's; into is untouched then. */
pt_status proto_guide_stats_add(pt_guide_stats *into, const proto_result *r, pt_error *err);

#endif
