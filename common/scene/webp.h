/*
 * webp.h - EXT_texture_webp's image decoder (Debian's libwebp), for the glTF
 * importer: a still WebP image (lossy or lossless, with or without alpha) to
 * RGBA8.
 *
 * The size is read from the bitstream's headers first (pt_webp_size), so the
 * caller checks it against its caps before anything of that size is
 * allocated; pt_webp_decode then decodes into the caller's buffer of exactly
 * that size and refuses a bitstream that decodes to another. An animated
 * WebP is refused (a texture is one image). Errors are PT_ERR_FORMAT with
 * libwebp's reason.
 *
 * Threads: any; no state.
 */
#ifndef PT_COMMON_SCENE_WEBP_H
#define PT_COMMON_SCENE_WEBP_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Whether data starts as a WebP file does ("RIFF", 4 bytes, "WEBP"). */
int pt_webp_is(const uint8_t *data, size_t len);

pt_status pt_webp_size(const uint8_t *data, size_t len, uint32_t *w, uint32_t *h, pt_error *err);

/* Decodes into rgba, w x h x 4 bytes (w and h from pt_webp_size). */
pt_status pt_webp_decode(const uint8_t *data, size_t len, uint32_t w, uint32_t h, uint8_t *rgba,
                         pt_error *err);

#ifdef __cplusplus
}
#endif

#endif
