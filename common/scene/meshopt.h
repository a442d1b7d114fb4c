/*
 * meshopt.h - EXT_meshopt_compression's buffer view decoder (Debian's
 * libmeshoptimizer 0.18), for the glTF importer.
 *
 * A compressed buffer view is count elements of stride bytes, coded in one
 * of three modes (the extension's "mode"): ATTRIBUTES (meshoptimizer's vertex
 * codec; stride a multiple of 4, at most 256), TRIANGLES (its index codec,
 * count a multiple of 3) or INDICES (its index sequence codec), both with
 * stride 2 or 4; ATTRIBUTES may then be filtered ("filter": OCTAHEDRAL unit
 * vectors, stride 4 or 8; QUATERNION, stride 8; EXPONENTIAL, stride a
 * multiple of 4). The decoder is safe on untrusted bytes and may produce
 * garbage, which the importer's accessor checks then meet; a bad parameter
 * or a stream that does not decode is PT_ERR_FORMAT with the reason.
 *
 * Threads: any; no state.
 */
#ifndef PT_COMMON_SCENE_MESHOPT_H
#define PT_COMMON_SCENE_MESHOPT_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"

#ifdef __cplusplus
extern "C" {
#endif

enum { PT_MESHOPT_ATTRIBUTES, PT_MESHOPT_TRIANGLES, PT_MESHOPT_INDICES };
enum { PT_MESHOPT_NONE, PT_MESHOPT_OCTAHEDRAL, PT_MESHOPT_QUATERNION, PT_MESHOPT_EXPONENTIAL };

/* Decodes src[0, len) into out, count x stride bytes. */
pt_status pt_meshopt_decode(const uint8_t *src, size_t len, uint64_t count, uint32_t stride,
                            int mode, int filter, uint8_t *out, pt_error *err);

#ifdef __cplusplus
}
#endif

#endif
