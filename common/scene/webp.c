/* webp.c - pt_webp_*: EXT_texture_webp images through libwebp's simple
 * decoding API (webp/decode.h). See webp.h. */
#include "common/scene/webp.h"

#include <string.h>

#include <webp/decode.h>

static const char *status_name(VP8StatusCode st)
{
    switch (st) {
    case VP8_STATUS_OUT_OF_MEMORY:
        return "out of memory";
    case VP8_STATUS_INVALID_PARAM:
        return "invalid parameter";
    case VP8_STATUS_BITSTREAM_ERROR:
        return "bitstream error";
    case VP8_STATUS_UNSUPPORTED_FEATURE:
        return "unsupported feature";
    case VP8_STATUS_NOT_ENOUGH_DATA:
        return "truncated";
    default:
        return "cannot be decoded";
    }
}

int pt_webp_is(const uint8_t *data, size_t len)
{
    return len >= 12 && memcmp(data, "RIFF", 4) == 0 && memcmp(data + 8, "WEBP", 4) == 0;
}

pt_status pt_webp_size(const uint8_t *data, size_t len, uint32_t *w, uint32_t *h, pt_error *err)
{
    WebPBitstreamFeatures f;
    VP8StatusCode st = WebPGetFeatures(data, len, &f);
    if (st != VP8_STATUS_OK)
        return pt_error_set(err, PT_ERR_FORMAT, "WebP: %s", status_name(st));
    if (f.has_animation)
        return pt_error_set(err, PT_ERR_FORMAT, "WebP: an animation, not one image");
    if (f.width <= 0 || f.height <= 0)
        return pt_error_set(err, PT_ERR_FORMAT, "WebP: %dx%d", f.width, f.height);
    *w = (uint32_t)f.width;
    *h = (uint32_t)f.height;
    return PT_OK;
}

pt_status pt_webp_decode(const uint8_t *data, size_t len, uint32_t w, uint32_t h, uint8_t *rgba,
                         pt_error *err)
{
    uint32_t fw = 0, fh = 0;
    pt_status st = pt_webp_size(data, len, &fw, &fh, err);
    if (st != PT_OK)
        return st;
    if (fw != w || fh != h || (uint64_t)w * 4 > INT32_MAX)
        return pt_error_set(err, PT_ERR_FORMAT, "WebP: %ux%u, not the %ux%u asked for", fw, fh, w,
                            h);
    size_t n = (size_t)w * h * 4;
    if (!WebPDecodeRGBAInto(data, len, rgba, n, (int)(w * 4)))
        return pt_error_set(err, PT_ERR_FORMAT, "WebP: the bitstream does not decode");
    return PT_OK;
}
