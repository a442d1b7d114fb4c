/*
 * envmap.h - reading an environment map: an equirectangular image of linear
 * RGB radiance, from a Radiance .hdr (RGBE, through stb_image's reader in
 * Debian's libstb) or an OpenEXR file (R, G, B through OpenEXRCore, exr.h).
 *
 * The format is told by the bytes, not the name: "#?RADIANCE" or "#?RGBE"
 * opens a Radiance file, the EXR magic 76 2f 31 01 an OpenEXR file.
 * Everything read is checked before it is returned, because a map comes
 * from a user or a client: a side of 0 or over PT_ENVMAP_MAX_SIDE, a width
 * that is not twice the height (within one pixel, for odd sizes), and any
 * texel that is negative, not finite or over PT_ENVMAP_MAX_VALUE are
 * refused with the reason and, for a texel, its position.
 *
 * Threads: pure functions of their arguments; any thread.
 */
#ifndef PT_COMMON_IMAGE_ENVMAP_H
#define PT_COMMON_IMAGE_ENVMAP_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"

#define PT_ENVMAP_MAX_SIDE 16384u
#define PT_ENVMAP_MAX_BYTES (1024u << 20)
/* Far above any real sky (the sun in a 1k map is about 1e5), far below
 * where sums of a few thousand texels overflow a float. */
#define PT_ENVMAP_MAX_VALUE 1e20f

typedef struct pt_envmap {
    uint32_t width, height;
    float *rgb; /* width * height * 3, row 0 at the top (straight up) */
} pt_envmap;

/* Decodes the n bytes of a Radiance map (an EXR is read from its file, by
 * pt_envmap_read); name only labels messages. PT_ERR_FORMAT for bytes that
 * are not a map or hold bad values, PT_ERR_LIMIT over the caps,
 * PT_ERR_NOMEM. */
pt_status pt_envmap_decode(const uint8_t *data, size_t n, const char *name, pt_envmap *out,
                           pt_error *err);

/* Reads and decodes the file at path (at most PT_ENVMAP_MAX_BYTES). */
pt_status pt_envmap_read(const char *path, pt_envmap *out, pt_error *err);

void pt_envmap_free(pt_envmap *m); /* frees m->rgb; accepts a zeroed map */

#endif
