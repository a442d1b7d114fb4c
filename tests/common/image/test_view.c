/* Tests for common/image/view.c and the PNG preview through it: standard at
 * 0 EV is the preview of earlier releases bit for bit; +1 EV is the radiance
 * doubled before the transform; every view is monotonic and maps 0 to 0;
 * filmic and agx have the values of their published definitions at a few
 * inputs, computed here from the formulas; a transparent image's PNG has a
 * straight alpha channel. */
#include "common/image/view.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <stb/stb_image.h>

#include "common/image/image.h"
#include "tests/check.h"

static const pt_view_kind kinds[] = {PT_VIEW_STANDARD, PT_VIEW_FILMIC, PT_VIEW_AGX};

/* The preview's encoding before view transforms existed (image.c's former
 * to_byte): clamp to [0, 1], NaN to 0, sRGB, round to nearest. */
static unsigned char old_preview_byte(float linear)
{
    if (!(linear > 0.0f))
        return 0;
    if (linear >= 1.0f)
        return 255;
    float s = pt_linear_to_srgb(linear) * 255.0f + 0.5f;
    return s >= 255.0f ? 255 : (unsigned char)s;
}

/* Inputs that cover the curves: 0, negatives, NaN, Inf, tiny, and a log
 * sweep from 2^-20 to 2^12 in 1/64 stops. */
static size_t inputs(float *x, size_t cap)
{
    size_t n = 0;
    const float special[] = {0.0f,   -0.0f, -1.0f,      NAN,  INFINITY,  -INFINITY,
                             1e-30f, 1.0f,  0.0031308f, 0.5f, 0.999999f, 1.000001f};
    for (size_t i = 0; i < sizeof special / sizeof special[0] && n < cap; i++)
        x[n++] = special[i];
    for (int k = -20 * 64; k <= 12 * 64 && n < cap; k++)
        x[n++] = exp2f((float)k / 64.0f);
    return n;
}

static void test_standard_is_the_old_preview(void)
{
    static float x[4096];
    size_t n = inputs(x, 4096);
    pt_view v0 = {PT_VIEW_STANDARD, 0.0f};
    size_t bad = 0;
    for (size_t i = 0; i < n; i++) {
        const float c[3] = {x[i], x[i] * 0.5f, x[i] * 0.25f};
        uint8_t a[3], b[3];
        pt_view_pixel(&v0, c, a);
        pt_view_pixel(NULL, c, b);
        for (int k = 0; k < 3; k++)
            bad += a[k] != old_preview_byte(c[k]) || b[k] != a[k];
    }
    CHECKF(bad == 0, "%zu values differ from the old preview", bad);
    /* Every 8-bit sRGB step, through its linear value and either side. */
    for (int d = 0; d < 256; d++) {
        float l = pt_srgb_to_linear((float)d / 255.0f);
        const float c[3] = {l, nextafterf(l, 0.0f), nextafterf(l, 2.0f)};
        uint8_t o[3];
        pt_view_pixel(&v0, c, o);
        for (int k = 0; k < 3; k++)
            CHECKF(o[k] == old_preview_byte(c[k]), "%g: %d, want %d", c[k], o[k],
                   old_preview_byte(c[k]));
    }
}

static void test_exposure_doubles(void)
{
    static float x[4096];
    size_t n = inputs(x, 4096);
    for (int t = 0; t < 3; t++) {
        pt_view v1 = {kinds[t], 1.0f}, v0 = {kinds[t], 0.0f}, vm = {kinds[t], -2.0f};
        size_t bad = 0;
        for (size_t i = 0; i < n; i++) {
            const float c[3] = {x[i], x[i] * 0.3f, x[i] * 0.01f};
            const float c2[3] = {2.0f * c[0], 2.0f * c[1], 2.0f * c[2]};
            const float c4[3] = {0.25f * c[0], 0.25f * c[1], 0.25f * c[2]};
            uint8_t a[3], b[3], m[3], q[3];
            pt_view_pixel(&v1, c, a);
            pt_view_pixel(&v0, c2, b);
            pt_view_pixel(&vm, c, m);
            pt_view_pixel(&v0, c4, q);
            bad += memcmp(a, b, 3) != 0 || memcmp(m, q, 3) != 0;
        }
        CHECKF(bad == 0, "%s: +1 EV is not 2x radiance at %zu inputs", pt_view_name(kinds[t]), bad);
        /* And it does change the image: 0.3 at +1 EV is brighter. */
        const float c[3] = {0.3f, 0.3f, 0.3f};
        uint8_t a[3], b[3];
        pt_view_pixel(&v1, c, a);
        pt_view_pixel(&v0, c, b);
        CHECKF(a[0] > b[0], "%s: +1 EV %d, 0 EV %d", pt_view_name(kinds[t]), a[0], b[0]);
    }
}

static void test_monotonic_and_zero(void)
{
    for (int t = 0; t < 3; t++) {
        const char *name = pt_view_name(kinds[t]);
        CHECKF(pt_view_curve(kinds[t], 0.0f) == 0.0f, "%s(0) = %g", name,
               pt_view_curve(kinds[t], 0.0f));
        CHECK(pt_view_curve(kinds[t], -3.0f) == 0.0f && pt_view_curve(kinds[t], NAN) == 0.0f);
        const float z[3] = {0.0f, 0.0f, 0.0f};
        uint8_t o[3];
        pt_view v = {kinds[t], 3.0f};
        pt_view_pixel(&v, z, o);
        CHECK(o[0] == 0 && o[1] == 0 && o[2] == 0);
        float prev = 0.0f;
        size_t bad = 0;
        for (int k = -24 * 256; k <= 16 * 256; k++) {
            float y = pt_view_curve(kinds[t], exp2f((float)k / 256.0f));
            bad += !(y >= prev) || y > 1.0f;
            prev = y;
        }
        CHECKF(bad == 0, "%s: %zu steps go down or past 1", name, bad);
        /* The top is white: AgX's fitted curve ends at 0.99858, a byte of 255. */
        const float hi[3] = {1e6f, INFINITY, 1e30f};
        pt_view v0 = {kinds[t], 0.0f};
        pt_view_pixel(&v0, hi, o);
        CHECKF(o[0] == 255 && o[1] == 255 && o[2] == 255, "%s: %d %d %d at the top", name, o[0],
               o[1], o[2]);
        CHECKF(pt_view_curve(kinds[t], 1e6f) >= 0.998f, "%s: %g at 1e6", name,
               pt_view_curve(kinds[t], 1e6f));
        /* Per channel too: raising red alone never lowers any byte of it. */
        uint8_t last = 0;
        for (int k = -12 * 16; k <= 8 * 16; k++) {
            const float c[3] = {exp2f((float)k / 16.0f), 0.2f, 0.05f};
            pt_view_pixel(&v0, c, o);
            CHECKF(o[0] >= last, "%s: red %g gives %d after %d", name, c[0], o[0], last);
            last = o[0];
        }
    }
}

/* Hable's F (filmicworlds.com, "Filmic Tonemapping Operators", 2010) with
 * the published constants, written out again here. */
static double hable_f(double x)
{
    return (x * (0.15 * x + 0.10 * 0.50) + 0.20 * 0.02) / (x * (0.15 * x + 0.50) + 0.20 * 0.30) -
           0.02 / 0.30;
}

static double srgb(double l)
{
    return l <= 0.0031308 ? 12.92 * l : 1.055 * pow(l, 1.0 / 2.4) - 0.055;
}

static void test_filmic_values(void)
{
    const double xs[] = {0.01, 0.18, 0.5, 1.0, 2.0, 4.0};
    for (size_t i = 0; i < sizeof xs / sizeof xs[0]; i++) {
        double want = srgb(hable_f(2.0 * xs[i]) / hable_f(11.2));
        float got = pt_view_curve(PT_VIEW_FILMIC, (float)xs[i]);
        CHECKF(fabs(got - want) < 2e-6, "filmic(%g) = %.7f, want %.7f", xs[i], got, want);
    }
    /* The linear white, 11.2 after the exposure bias of 2, is white; and
     * the toe keeps middle grey well below the standard view's 0.46. */
    CHECK(pt_view_curve(PT_VIEW_FILMIC, 5.6f) == 1.0f);
    CHECK(pt_view_curve(PT_VIEW_FILMIC, 5.5f) < 1.0f);
    CHECKF(pt_view_curve(PT_VIEW_FILMIC, 0.18f) < pt_view_curve(PT_VIEW_STANDARD, 0.18f), "%g",
           pt_view_curve(PT_VIEW_FILMIC, 0.18f));
}

/* Wrensch's fit of the AgX base contrast, written out again here. */
static double agx_poly(double x)
{
    return 15.5 * pow(x, 6) - 40.14 * pow(x, 5) + 31.96 * pow(x, 4) - 6.868 * pow(x, 3) +
           0.4298 * x * x + 0.1191 * x - 0.00232;
}

static void test_agx_values(void)
{
    /* Blender's AgX window: log2 from -12.47393 to 4.026069, 16.5 stops;
     * middle grey 0.18 sits 10 stops above its bottom. The inset matrix's
     * rows sum to 1 within 1.4e-4, so a grey stays a grey and comes out as
     * the curve's value at its place in the window (to 1e-3). */
    const double xs[] = {0.18, 0.01, 1.0, 4.0, 0.001};
    for (size_t i = 0; i < sizeof xs / sizeof xs[0]; i++) {
        double w = (log2(xs[i]) + 12.47393) / (4.026069 + 12.47393);
        double want = agx_poly(w);
        float got = pt_view_curve(PT_VIEW_AGX, (float)xs[i]);
        CHECKF(fabs(got - want) < 1e-3, "agx(%g) = %.5f, want %.5f", xs[i], got, want);
    }
    CHECKF(fabs(pt_view_curve(PT_VIEW_AGX, 0.18f) - 0.4967) < 2e-3, "agx(0.18) = %g",
           pt_view_curve(PT_VIEW_AGX, 0.18f));
    /* Past the window's top (2^4.026 = 16.3) the curve is flat at the
     * fit's end, poly(1) = 0.99858. */
    CHECKF(fabs(pt_view_curve(PT_VIEW_AGX, 17.0f) - agx_poly(1.0)) < 1e-3, "%g",
           pt_view_curve(PT_VIEW_AGX, 17.0f));
    CHECK(pt_view_curve(PT_VIEW_AGX, 17.0f) == pt_view_curve(PT_VIEW_AGX, 1000.0f));
    /* A saturated bright red desaturates toward white (AgX's point), where
     * the standard view keeps it pure red. */
    const float red[3] = {8.0f, 0.0f, 0.0f};
    pt_view va = {PT_VIEW_AGX, 0.0f}, vs = {PT_VIEW_STANDARD, 0.0f};
    uint8_t a[3], s[3];
    pt_view_pixel(&va, red, a);
    pt_view_pixel(&vs, red, s);
    CHECKF(s[0] == 255 && s[1] == 0 && a[0] > 200 && a[1] > 20 && a[2] > 20, "agx red %d %d %d",
           a[0], a[1], a[2]);
}

static void test_parse(void)
{
    pt_view_kind k = PT_VIEW_STANDARD;
    pt_error err = {0};
    CHECK(pt_view_parse("--view", "agx", &k, &err) == PT_OK && k == PT_VIEW_AGX);
    CHECK(pt_view_parse("--view", "filmic", &k, &err) == PT_OK && k == PT_VIEW_FILMIC);
    CHECK(pt_view_parse("--view", "standard", &k, &err) == PT_OK && k == PT_VIEW_STANDARD);
    CHECK(pt_view_parse("--view", "aces", &k, &err) == PT_ERR_ARG && k == PT_VIEW_STANDARD);
    CHECKF(!strcmp(err.msg, "--view: 'aces' is not a view (standard, filmic or agx)"), "%s",
           err.msg);
    CHECK(!strcmp(pt_view_name(PT_VIEW_AGX), "agx"));
}

/* A transparent image's PNG: RGBA, straight alpha = coverage; an opaque
 * one stays RGB. */
static void test_png_alpha(void)
{
    char path[] = "/tmp/pt_test_view_XXXXXX";
    int fd = mkstemp(path);
    CHECK(fd >= 0);
    close(fd);
    pt_image *img = NULL;
    pt_error err = {0};
    if (pt_image_new(4, 1, &img, &err) != PT_OK) {
        CHECK(0);
        return;
    }
    /* Coverage 1, 0.5, 0 and 0.25; RGB premultiplied by it. */
    const float cov[4] = {1.0f, 0.5f, 0.0f, 0.25f};
    for (int i = 0; i < 4; i++) {
        img->a[i] = cov[i];
        img->r[i] = 0.5f * cov[i];
        img->g[i] = 0.2f * cov[i];
        img->b[i] = 0.0f;
    }
    img->has_alpha = 1;
    CHECK(pt_png_write_preview(path, img, NULL, &err) == PT_OK);
    int w = 0, h = 0, comp = 0;
    unsigned char *px = stbi_load(path, &w, &h, &comp, 0);
    CHECKF(px && w == 4 && h == 1 && comp == 4, "comp %d", comp);
    if (px && comp == 4) {
        for (int i = 0; i < 4; i++) {
            int want_a = (int)(cov[i] * 255.0f + 0.5f);
            CHECKF(px[4 * i + 3] == want_a, "alpha %d, want %d", px[4 * i + 3], want_a);
            if (cov[i] > 0.0f) {
                CHECKF(px[4 * i] == old_preview_byte(0.5f) &&
                           px[4 * i + 1] == old_preview_byte(0.2f),
                       "pixel %d: %d %d, straight colour %d %d", i, px[4 * i], px[4 * i + 1],
                       old_preview_byte(0.5f), old_preview_byte(0.2f));
            } else {
                CHECK(px[4 * i] == 0 && px[4 * i + 1] == 0 && px[4 * i + 2] == 0);
            }
        }
    }
    stbi_image_free(px);
    img->has_alpha = 0;
    CHECK(pt_png_write_preview(path, img, NULL, &err) == PT_OK);
    px = stbi_load(path, &w, &h, &comp, 0);
    CHECK(px && comp == 3);
    stbi_image_free(px);
    /* The view reaches the file: filmic darkens middle grey. */
    for (int i = 0; i < 4; i++)
        img->r[i] = img->g[i] = img->b[i] = 0.18f;
    pt_view f = {PT_VIEW_FILMIC, 0.0f};
    CHECK(pt_png_write_preview(path, img, &f, &err) == PT_OK);
    px = stbi_load(path, &w, &h, &comp, 0);
    CHECK(px && px[0] < old_preview_byte(0.18f));
    stbi_image_free(px);
    pt_image_free(img);
    unlink(path);
}

int main(void)
{
    test_standard_is_the_old_preview();
    test_exposure_doubles();
    test_monotonic_and_zero();
    test_filmic_values();
    test_agx_values();
    test_parse();
    test_png_alpha();
    return check_report();
}
