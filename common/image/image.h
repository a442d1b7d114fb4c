/*
 * image.h - a finished (or progressive) image: planar float channels.
 *
 * r, g, b: mean linear Rec.709 radiance per pixel; samples: the pixel's sample
 * count; variance: the variance of the pixel mean (luminance), i.e. the sample
 * variance divided by the count; a: the pixel's coverage (the fraction of its
 * camera samples whose camera ray hit the scene), meaningful and written as
 * the EXR's A channel only when has_alpha is 1 (a transparent film, whose RGB
 * is then premultiplied by it). Row 0 is the top row.
 * Besides these, an image may hold named planes (render passes, a denoised
 * layer): float channels written into the EXR under their names
 * ("albedo.R", "N.X", ...; common/render/passes.h names the passes).
 * Also writes an 8-bit PNG preview through a view transform (stb_image_write).
 *
 * Threads: an image belongs to one thread at a time; the functions keep no
 * state of their own.
 */
#ifndef PT_COMMON_IMAGE_IMAGE_H
#define PT_COMMON_IMAGE_IMAGE_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"
#include "common/image/view.h"

/* A named plane: an EXR channel name of 1 to PT_IMAGE_PLANE_NAME - 1
 * printable ASCII bytes, and width x height floats (pt_malloc'd). */
#define PT_IMAGE_PLANE_NAME 32
#define PT_IMAGE_MAX_PLANES 64
typedef struct pt_image_plane {
    char name[PT_IMAGE_PLANE_NAME];
    float *data;
} pt_image_plane;

typedef struct pt_image {
    uint32_t width, height;
    float *r, *g, *b;
    float *samples;
    float *variance;
    float *a;           /* always allocated; see has_alpha */
    uint32_t has_alpha; /* 1: a holds the coverage and the EXR has an A channel */
    uint32_t n_planes;  /* named planes in planes[], in the order they were added */
    pt_image_plane planes[PT_IMAGE_MAX_PLANES];
} pt_image;

/* The largest image any module makes, reads or writes (an image, the film
 * that resolves into it, an EXR): pixels per side, and pixels in all. */
#define PT_IMAGE_MAX_SIDE 65536u
#define PT_IMAGE_MAX_PIXELS (1u << 28)

/* PT_OK when width x height is a possible image: PT_ERR_ARG when a side is
 * 0, PT_ERR_LIMIT over the caps above; err names it as `what` ("image",
 * "film") with the size. Pure: any thread may call it. */
pt_status pt_image_check_size(const char *what, uint32_t width, uint32_t height, pt_error *err);

/* Allocates a zeroed image with all six planes (has_alpha 0). */
pt_status pt_image_new(uint32_t width, uint32_t height, pt_image **out, pt_error *err);
void pt_image_free(pt_image *img); /* accepts NULL; frees the named planes too */

/* The named plane `name` of img, added zeroed when it is not there: *out
 * (may be NULL) is its data. PT_ERR_ARG for a name that is not 1 to 31
 * printable ASCII bytes or is one of the six planes above (R, G, B, A,
 * samples, variance); PT_ERR_LIMIT past PT_IMAGE_MAX_PLANES; PT_ERR_NOMEM. */
pt_status pt_image_add_plane(pt_image *img, const char *name, float **out, pt_error *err);

/* The data of the named plane `name`, or NULL when img has none. */
float *pt_image_find_plane(const pt_image *img, const char *name);

/* An output's format, by its name's ending in any case: ".exr" (OpenEXR,
 * linear, with a PNG preview beside it) or ".png" (the 8-bit PNG alone). */
typedef enum pt_image_format {
    PT_IMAGE_FORMAT_NONE = 0,
    PT_IMAGE_FORMAT_EXR,
    PT_IMAGE_FORMAT_PNG
} pt_image_format;
pt_image_format pt_image_format_of(const char *path);

/* The refusal of any other name, for "prog: -o NAME: " PT_IMAGE_FORMATS. */
#define PT_IMAGE_FORMATS                                                                           \
    "the output's format follows its name: .exr (OpenEXR, with a .png preview beside it) or "      \
    ".png (8-bit sRGB)"

/* The name of the PNG preview written beside the EXR exr_path, into out (n
 * bytes, cut to fit): "out.exr" -> "out.png"; any other name gets ".png"
 * appended. Every program names its preview so. */
void pt_png_preview_path(const char *exr_path, char *out, size_t n);

/* Writes a PNG of r,g,b through view (common/image/view.h; NULL: standard
 * at 0 EV, the clamped sRGB of earlier releases), atomically (temp +
 * rename). An image with has_alpha gets an RGBA PNG: straight alpha, the
 * coverage, with the RGB divided by it before the view. */
pt_status pt_png_write_preview(const char *path, const pt_image *img, const pt_view *view,
                               pt_error *err);

/* PNG bytes of width x height 8-bit RGB pixels (rows top first), in memory:
 * *out is pt_malloc'd (pt_free), *len its size; both untouched on failure. */
pt_status pt_png_encode_rgb8(const uint8_t *rgb, uint32_t width, uint32_t height, uint8_t **out,
                             size_t *len, pt_error *err);

#endif
