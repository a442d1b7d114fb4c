/*
 * view.h - view transforms: linear scene radiance to 8-bit display values.
 *
 * Every preview ptfarm makes (ptworker's and ptserve's PNGs, the dashboard's
 * image, ptcontact-sheet) goes through one pt_view: an exposure in stops
 * (the radiance is multiplied by 2^EV first) and one of three transforms.
 * The EXR is never touched by it: it stays linear scene radiance.
 *
 *   standard  clamp to [0, 1], then the sRGB encoding (IEC 61966-2-1); at
 *             0 EV, bit for bit the preview of earlier releases
 *   filmic    John Hable's filmic curve (the "Uncharted 2" operator: Hable,
 *             "Filmic Tonemapping Operators", 2010, and "Uncharted 2: HDR
 *             Lighting", GDC 2010), exposure bias 2 and linear white 11.2
 *             as published, then the sRGB encoding: a toe and a soft
 *             shoulder, so 5.6 x the exposed radiance is white
 *   agx       Troy Sobotka's AgX as Blender 4 ships it: the inset matrix, a
 *             log2 encoding over [-12.47393, 4.026069] stops, the base
 *             contrast sigmoid, the inverse inset matrix. The sigmoid is the
 *             6th-order polynomial fitted to Blender's AgX base LUT by
 *             Benjamin Wrensch ("Minimal AgX Implementation", 2023), an
 *             approximation; its output is the display value itself
 *
 * Each is monotonic in every channel and maps 0 to 0. Pure functions: any
 * thread may call them.
 */
#ifndef PT_COMMON_IMAGE_VIEW_H
#define PT_COMMON_IMAGE_VIEW_H

#include <stdint.h>

#include "common/base/error.h"

typedef enum pt_view_kind { PT_VIEW_STANDARD = 0, PT_VIEW_FILMIC, PT_VIEW_AGX } pt_view_kind;

typedef struct pt_view {
    pt_view_kind kind;
    float exposure; /* stops: radiance x 2^exposure before the transform */
} pt_view;

/* The exposure a view accepts, in stops either way. */
#define PT_VIEW_MAX_EV 20.0

/* The names, "standard|filmic|agx", for usage lines and messages. */
#define PT_VIEW_NAMES "standard|filmic|agx"

/* name ("standard", "filmic", "agx") into *out. PT_ERR_ARG otherwise:
 * "OPT: 'NAME' is not a view (standard, filmic or agx)". */
pt_status pt_view_parse(const char *opt, const char *name, pt_view_kind *out, pt_error *err);

/* The name of kind ("standard" for an unknown one). */
const char *pt_view_name(pt_view_kind kind);

/* One pixel's linear Rec.709 radiance rgb through v (NULL: standard, 0 EV)
 * into display values 0..255 (sRGB-encoded). NaN and negatives go to 0. */
void pt_view_pixel(const pt_view *v, const float rgb[3], uint8_t out[3]);

/* sRGB transfer functions (IEC 61966-2-1). */
float pt_srgb_to_linear(float c);
float pt_linear_to_srgb(float c);

/* The transform alone on one channel value x (already exposed), as a display
 * value in [0, 1] before rounding: the tests' window into the curves. For
 * agx the channel is taken as a grey (r = g = b = x). */
float pt_view_curve(pt_view_kind kind, float x);

#endif
