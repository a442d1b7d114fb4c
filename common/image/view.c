#include "common/image/view.h"

#include <math.h>
#include <string.h>

static const char *const names[] = {"standard", "filmic", "agx"};

/* IEC 61966-2-1:1999, section 5.2 (encoding) and its inverse. */
float pt_srgb_to_linear(float c)
{
    if (c <= 0.04045f)
        return c / 12.92f;
    return powf((c + 0.055f) / 1.055f, 2.4f);
}

float pt_linear_to_srgb(float c)
{
    if (c <= 0.0031308f)
        return c * 12.92f;
    return 1.055f * powf(c, 1.0f / 2.4f) - 0.055f;
}

pt_status pt_view_parse(const char *opt, const char *name, pt_view_kind *out, pt_error *err)
{
    for (int k = 0; k < 3; k++)
        if (strcmp(name, names[k]) == 0) {
            *out = (pt_view_kind)k;
            return PT_OK;
        }
    return pt_error_set(err, PT_ERR_ARG, "%s: '%s' is not a view (standard, filmic or agx)", opt,
                        name);
}

const char *pt_view_name(pt_view_kind kind)
{
    return (unsigned)kind < 3 ? names[kind] : names[0];
}

/* A display value in [0, 1] (NaN to 0) to 0..255, rounded to nearest. */
static uint8_t quantize(float d)
{
    if (!(d > 0.0f))
        return 0;
    if (d >= 1.0f)
        return 255;
    float s = d * 255.0f + 0.5f;
    return s >= 255.0f ? 255 : (uint8_t)s;
}

/* The preview of earlier releases: clamp, then the sRGB encoding. */
static float standard(float x)
{
    if (!(x > 0.0f))
        return 0.0f;
    if (x >= 1.0f)
        return 1.0f;
    return pt_linear_to_srgb(x);
}

/* Hable's filmic curve, "Filmic Tonemapping Operators" (filmicworlds.com,
 * 2010): F(x) = (x(Ax + CB) + DE) / (x(Ax + B) + DF) - E/F with shoulder A,
 * linear strength B, linear angle C, toe strength D, toe numerator E and
 * denominator F as published; the colour is F(2x) / F(W), W = 11.2 the
 * linear white, 2 the published exposure bias. F(0) = 0 and F rises. */
static double hable(double x)
{
    const double A = 0.15, B = 0.50, C = 0.10, D = 0.20, E = 0.02, F = 0.30;
    return (x * (A * x + C * B) + D * E) / (x * (A * x + B) + D * F) - E / F;
}

static float filmic(float x)
{
    if (!(x > 0.0f))
        return 0.0f;
    if (isinf(x))
        return 1.0f;
    double w = hable(11.2);
    double y = hable(2.0 * (double)x) / w;
    return y >= 1.0 ? 1.0f : standard((float)y);
}

/* AgX (Troy Sobotka), in the form Benjamin Wrensch published for Rec.709
 * input ("Minimal AgX Implementation", iolite engine, 2023): the inset
 * matrix (rows), the log2 window of Blender 4's AgX config and the
 * polynomial fit of its base contrast curve; then the inset's inverse. */
static const double agx_inset[3][3] = {
    {0.842479062253094, 0.0784335999999992, 0.0792237451477643},
    {0.0423282422610123, 0.878468636469772, 0.0791661274605434},
    {0.0423756549057051, 0.0784336, 0.879142973793104},
};
static const double agx_outset[3][3] = {
    {1.19687900512017, -0.0980208811401368, -0.0990297440797205},
    {-0.0528968517574562, 1.15190312990417, -0.0989611768448433},
    {-0.0529716355144438, -0.0980434501171241, 1.15107367264116},
};
#define AGX_MIN_EV (-12.47393)
#define AGX_MAX_EV 4.026069

/* Wrensch's 6th-order fit of the AgX base contrast on [0, 1]. */
static double agx_contrast(double x)
{
    double x2 = x * x, x4 = x2 * x2;
    return 15.5 * x4 * x2 - 40.14 * x4 * x + 31.96 * x4 - 6.868 * x2 * x + 0.4298 * x2 +
           0.1191 * x - 0.00232;
}

static double agx_log(double v)
{
    double l = v > 0.0 ? log2(v) : AGX_MIN_EV;
    if (!(l > AGX_MIN_EV)) /* NaN too */
        l = AGX_MIN_EV;
    if (l > AGX_MAX_EV)
        l = AGX_MAX_EV;
    return (l - AGX_MIN_EV) / (AGX_MAX_EV - AGX_MIN_EV);
}

static void agx(const double in[3], float out[3])
{
    double s[3];
    for (int i = 0; i < 3; i++)
        s[i] = agx_contrast(
            agx_log(agx_inset[i][0] * in[0] + agx_inset[i][1] * in[1] + agx_inset[i][2] * in[2]));
    for (int i = 0; i < 3; i++) {
        double d = agx_outset[i][0] * s[0] + agx_outset[i][1] * s[1] + agx_outset[i][2] * s[2];
        out[i] = d > 0.0 ? (d < 1.0 ? (float)d : 1.0f) : 0.0f;
    }
}

float pt_view_curve(pt_view_kind kind, float x)
{
    if (kind == PT_VIEW_FILMIC)
        return filmic(x);
    if (kind == PT_VIEW_AGX) {
        double g = x > 0.0f ? (double)x : 0.0;
        double in[3] = {g, g, g};
        float out[3];
        agx(in, out);
        return out[1];
    }
    return standard(x);
}

void pt_view_pixel(const pt_view *v, const float rgb[3], uint8_t out[3])
{
    pt_view_kind kind = v ? v->kind : PT_VIEW_STANDARD;
    /* 2^0 is exactly 1: at 0 EV the radiance is used as it is. */
    float scale = v && v->exposure != 0.0f ? exp2f(v->exposure) : 1.0f;
    if (kind == PT_VIEW_AGX) {
        double in[3];
        float d[3];
        for (int k = 0; k < 3; k++)
            in[k] = rgb[k] * scale > 0.0f ? (double)(rgb[k] * scale) : 0.0;
        agx(in, d);
        for (int k = 0; k < 3; k++)
            out[k] = quantize(d[k]);
        return;
    }
    for (int k = 0; k < 3; k++)
        out[k] =
            quantize(kind == PT_VIEW_FILMIC ? filmic(rgb[k] * scale) : standard(rgb[k] * scale));
}
