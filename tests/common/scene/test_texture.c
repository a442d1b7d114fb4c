/*
 * test_texture.c - texture lookups (wrap modes per axis, NEAREST and LINEAR
 * filters), KHR_texture_transform and texture coordinate sets, and the
 * tangents generated for normal maps (common/scene/tangent.c).
 *
 * Lookups are compared with texel values computed here by hand: a linear
 * (non-sRGB) 4 x 2 texture whose red channel holds a distinct byte per
 * texel, read at chosen UVs whose texel and weights follow from the
 * convention (texel i covers [i/w, (i+1)/w), its centre at (i + 0.5)/w; v = 0
 * is the top row). Tolerance 1e-6: one float rounding of a weighted sum.
 *
 * Shared blocks (scene.h, pt_texture): the textures a material reads at the
 * same coordinates, put side by side by the builder, must sit at the bytes
 * the layout gives and read back, texel by texel and through every lookup,
 * the bits of the same texels in rows.
 *
 * Tangents: on planes and on a latitude-longitude sphere the generated
 * tangent must be dP/du made orthogonal to the normal (analytic), with the
 * handedness that a mirrored UV layout implies; on the shared asset
 * NormalTangentMirrorTest, which supplies TANGENT, regenerating must agree
 * with the file within 0.25 degrees at every vertex and in every w, and on
 * LightsPunctualLamp (also with TANGENT) within 0.1 degrees at the median
 * and at the 90th percentile, with every w equal (MikkTSpace splits some
 * seam vertices that the per-vertex mean cannot: tangent.h).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "common/base/alloc.h"
#include "common/scene/scene.h"
#include "common/scene/tangent.h"
#include "tests/check.h"

#define PI_D 3.14159265358979323846

/* Red bytes of the 4 x 2 texture, row 0 (top) first. */
static const uint8_t k_red[2][4] = {{10, 50, 90, 130}, {170, 210, 250, 30}};

static pt_texture make_tex(int ws, int wt, int nearest)
{
    pt_texture t;
    memset(&t, 0, sizeof t);
    t.width = 4;
    t.height = 2;
    t.rgba = pt_malloc(32);
    for (int y = 0; y < 2; y++)
        for (int x = 0; x < 4; x++) {
            uint8_t *p = t.rgba + 4 * (y * 4 + x);
            p[0] = k_red[y][x];
            p[1] = (uint8_t)(x * 60);
            p[2] = 0;
            p[3] = 255;
        }
    t.wrap_s = ws;
    t.wrap_t = wt;
    t.nearest = nearest;
    return t;
}

static double texel(int x, int y)
{
    return k_red[y][x] / 255.0;
}

static float red_at(const pt_texture *t, float u, float v)
{
    float o[4];
    pt_texture_sample(t, u, v, o);
    return o[0];
}

static void expect(const char *what, double got, double want)
{
    CHECKF(fabs(got - want) <= 1e-6, "%s: %.8g, expected %.8g", what, got, want);
}

static void test_nearest(void)
{
    pt_texture t = make_tex(PT_WRAP_REPEAT, PT_WRAP_REPEAT, 1);
    /* Anywhere inside a texel's square gives that texel, unfiltered (a
     * LINEAR lookup there would blend with the neighbour). */
    expect("nearest (0.3/4, top)", red_at(&t, 0.3f / 4, 0.2f), texel(0, 0));
    expect("nearest (1.9/4, top)", red_at(&t, 1.9f / 4, 0.4f), texel(1, 0));
    expect("nearest (2.1/4, bottom)", red_at(&t, 2.1f / 4, 0.6f), texel(2, 1));
    /* REPEAT: u = -0.1 is texel floor(-0.4) = -1 -> 3; v = 1.2 is row 0. */
    expect("nearest repeat u<0", red_at(&t, -0.1f, 0.25f), texel(3, 0));
    expect("nearest repeat v>1", red_at(&t, 0.1f, 1.2f), texel(0, 0));
    /* CLAMP_TO_EDGE: beyond the edge, the edge texel. */
    t.wrap_s = t.wrap_t = PT_WRAP_CLAMP;
    expect("nearest clamp u>1", red_at(&t, 1.7f, 0.75f), texel(3, 1));
    expect("nearest clamp u<0 v<0", red_at(&t, -3.0f, -0.5f), texel(0, 0));
    /* MIRRORED_REPEAT: u = 1.1 reads 0.9 (texel 3), 1.3 reads 0.7 (texel
     * 2), -0.1 reads 0.1 (texel 0), 2.1 reads 0.1 again. */
    t.wrap_s = t.wrap_t = PT_WRAP_MIRROR;
    expect("nearest mirror 1.1", red_at(&t, 1.1f, 0.25f), texel(3, 0));
    expect("nearest mirror 1.3", red_at(&t, 1.3f, 0.25f), texel(2, 0));
    expect("nearest mirror -0.1", red_at(&t, -0.1f, 0.25f), texel(0, 0));
    expect("nearest mirror 2.1", red_at(&t, 2.1f, 0.25f), texel(0, 0));
    expect("nearest mirror v 1.2", red_at(&t, 0.1f, 1.2f), texel(0, 1));
    /* Per axis: u repeats while v clamps. */
    t.wrap_s = PT_WRAP_REPEAT;
    t.wrap_t = PT_WRAP_CLAMP;
    expect("nearest repeat s, clamp t", red_at(&t, 1.1f, 5.0f), texel(0, 1));
    /* sRGB: the byte decoded by the sRGB curve, exactly one texel. */
    t.srgb = 1;
    float o[4];
    pt_texture_sample(&t, 0.3f / 4, 0.2f, o);
    double c = 10 / 255.0;
    expect("nearest sRGB", o[0], c / 12.92);
    pt_free(t.rgba);
}

static void test_linear(void)
{
    pt_texture t = make_tex(PT_WRAP_REPEAT, PT_WRAP_CLAMP, 0);
    float vc = 0.25f; /* the top row's centre: no vertical blend */
    /* A quarter of the way from texel 1's centre to texel 2's. */
    expect("linear 1.75/4", red_at(&t, 1.75f / 4, vc), 0.75 * texel(1, 0) + 0.25 * texel(2, 0));
    /* u = 0 sits between texel 3 (wrapped) and texel 0 under REPEAT. */
    expect("linear repeat at u=0", red_at(&t, 0.0f, vc), 0.5 * texel(3, 0) + 0.5 * texel(0, 0));
    /* v = 0.5 is midway between the rows' centres. */
    expect("linear between rows", red_at(&t, 0.5f / 4, 0.5f),
           0.5 * texel(0, 0) + 0.5 * texel(0, 1));
    /* CLAMP in t: v = 0 (top edge) blends the top row with itself. */
    expect("linear clamp v=0", red_at(&t, 0.5f / 4, 0.0f), texel(0, 0));
    t.wrap_s = PT_WRAP_CLAMP;
    expect("linear clamp u=0", red_at(&t, 0.0f, vc), texel(0, 0));
    expect("linear clamp u=1", red_at(&t, 1.0f, vc), texel(3, 0));
    /* MIRROR: at u = 1 the texel beyond the edge is texel 3 itself; at
     * u = 0 likewise texel 0. */
    t.wrap_s = PT_WRAP_MIRROR;
    expect("linear mirror u=1", red_at(&t, 1.0f, vc), texel(3, 0));
    expect("linear mirror u=0", red_at(&t, 0.0f, vc), texel(0, 0));
    /* u = 1 + 0.125: mirrored to 0.875 = texel 3's centre (3.5/4). */
    expect("linear mirror u=1.125", red_at(&t, 1.125f, vc), texel(3, 0));
    pt_free(t.rgba);
}

/* Every byte decodes to the bits of its formula: unorm as (float)b *
 * (1.0f / 255.0f), sRGB as IEC 61966-2-1's curve in double rounded to float
 * (scene.c keeps both as compiled-in tables); alpha is unorm either way. */
static void test_decode_tables(void)
{
    int bad = 0;
    for (int srgb = 0; srgb < 2; srgb++)
        for (int b = 0; b < 256; b++) {
            uint8_t px[4] = {(uint8_t)b, (uint8_t)b, (uint8_t)b, (uint8_t)b};
            pt_texture t;
            memset(&t, 0, sizeof t);
            t.width = t.height = 1;
            t.rgba = px;
            t.srgb = srgb;
            t.nearest = 1;
            float o[4];
            pt_texture_sample(&t, 0.5f, 0.5f, o);
            double c = b / 255.0;
            float want = srgb ? (float)(c <= 0.04045 ? c / 12.92 : pow((c + 0.055) / 1.055, 2.4))
                              : (float)b * (1.0f / 255.0f);
            float alpha = (float)b * (1.0f / 255.0f);
            bad += memcmp(&o[0], &want, sizeof want) != 0 ||
                   memcmp(&o[2], &want, sizeof want) != 0 ||
                   memcmp(&o[3], &alpha, sizeof alpha) != 0;
        }
    CHECKF(bad == 0, "%d texel bytes decode to other bits than their formula", bad);
}

/* The lookup as it was written before its fast paths (integer modulo for
 * every wrap, a decode per channel, sums from 0): pt_texture_sample must give
 * its bits for every wrap mode, filter and size, at coordinates in range,
 * far out of it, at the edges a float rounds to, and not finite. */
static int ref_wrap(int i, int n, int mode)
{
    if (mode == PT_WRAP_CLAMP)
        return i < 0 ? 0 : (i >= n ? n - 1 : i);
    if (mode == PT_WRAP_MIRROR) {
        int p = i % (2 * n);
        if (p < 0)
            p += 2 * n;
        return p < n ? p : 2 * n - 1 - p;
    }
    int p = i % n;
    return p < 0 ? p + n : p;
}

static float ref_reduce(float u, int mode)
{
    if (!isfinite(u))
        return 0.0f;
    if (mode == PT_WRAP_CLAMP)
        return fminf(fmaxf(u, -1.0f), 2.0f);
    if (mode == PT_WRAP_MIRROR)
        return u - 2.0f * floorf(0.5f * u);
    return u - floorf(u);
}

static float ref_decode(int srgb, uint8_t b)
{
    double c = b / 255.0;
    return srgb ? (float)(c <= 0.04045 ? c / 12.92 : pow((c + 0.055) / 1.055, 2.4))
                : (float)b * (1.0f / 255.0f);
}

static void ref_sample(const pt_texture *tex, float u, float v, float out[4])
{
    int w = (int)tex->width, h = (int)tex->height;
    if (tex->nearest) {
        int xi = ref_wrap((int)floorf(ref_reduce(u, tex->wrap_s) * (float)w), w, tex->wrap_s);
        int yi = ref_wrap((int)floorf(ref_reduce(v, tex->wrap_t) * (float)h), h, tex->wrap_t);
        const uint8_t *px = tex->rgba + 4 * ((size_t)yi * (size_t)w + (size_t)xi);
        for (int c = 0; c < 3; c++)
            out[c] = ref_decode(tex->srgb, px[c]);
        out[3] = (float)px[3] * (1.0f / 255.0f);
        return;
    }
    float x = ref_reduce(u, tex->wrap_s) * (float)w - 0.5f;
    float y = ref_reduce(v, tex->wrap_t) * (float)h - 0.5f;
    float fx0 = floorf(x), fy0 = floorf(y);
    float fx = x - fx0, fy = y - fy0;
    int x0 = (int)fx0, y0 = (int)fy0;
    int xs[2] = {ref_wrap(x0, w, tex->wrap_s), ref_wrap(x0 + 1, w, tex->wrap_s)};
    int ys[2] = {ref_wrap(y0, h, tex->wrap_t), ref_wrap(y0 + 1, h, tex->wrap_t)};
    float wt[4] = {(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy};
    out[0] = out[1] = out[2] = out[3] = 0.0f;
    for (int k = 0; k < 4; k++) {
        const uint8_t *px = tex->rgba + 4 * ((size_t)ys[k >> 1] * (size_t)w + (size_t)xs[k & 1]);
        for (int c = 0; c < 3; c++)
            out[c] += wt[k] * ref_decode(tex->srgb, px[c]);
        out[3] += wt[k] * (float)px[3] * (1.0f / 255.0f);
    }
}

static void test_against_reference(void)
{
    static const uint32_t sizes[][2] = {{1, 1}, {1, 7}, {5, 1}, {2, 3}, {16, 16}, {33, 17}};
    static const float special[] = {0.0f,           -0.0f,     1.0f,       -1.0f,     0.5f,
                                    0x1.fffffep-1f, -0x1p-30f, 1.0000001f, 2.0f,      -2.0f,
                                    3.99999f,       1e7f,      -1e7f,      3e38f,     -3e38f,
                                    INFINITY,       -INFINITY, NAN,        0x1p-149f, -0.75f};
    const int nspecial = (int)(sizeof special / sizeof special[0]);
    uint64_t rng = 0x9e3779b97f4a7c15ull;
    int bad = 0, n = 0;
    for (int si = 0; si < 6; si++) {
        pt_texture t;
        memset(&t, 0, sizeof t);
        t.width = sizes[si][0];
        t.height = sizes[si][1];
        size_t len = (size_t)t.width * t.height * 4;
        t.rgba = pt_malloc(len);
        for (size_t i = 0; i < len; i++) {
            rng = rng * 6364136223846793005ull + 1442695040888963407ull;
            t.rgba[i] = (uint8_t)(rng >> 56);
        }
        for (int mode = 0; mode < 18; mode++) {
            t.wrap_s = mode % 3;
            t.wrap_t = (mode / 3) % 3;
            t.nearest = mode / 9;
            for (t.srgb = 0; t.srgb < 2; t.srgb++)
                for (int k = 0; k < 3000; k++) {
                    float uv[2];
                    for (int a = 0; a < 2; a++) {
                        rng = rng * 6364136223846793005ull + 1442695040888963407ull;
                        uint32_t r = (uint32_t)(rng >> 32);
                        if (k < nspecial * nspecial)
                            uv[a] = special[a ? k / nspecial : k % nspecial];
                        else if (r % 4 == 0) /* on a texel edge */
                            uv[a] = (float)(int)(r % 97 - 40) / (float)(a ? t.height : t.width);
                        else
                            uv[a] = ((float)(r >> 8) * 0x1p-24f) * 6.0f - 3.0f;
                    }
                    float got[4], want[4];
                    pt_texture_sample(&t, uv[0], uv[1], got);
                    ref_sample(&t, uv[0], uv[1], want);
                    bad += memcmp(got, want, sizeof got) != 0;
                    n++;
                }
        }
        pt_free(t.rgba);
    }
    CHECKF(bad == 0, "%d of %d lookups differ from the reference's bits", bad, n);
}

static void apply(const pt_tex_xform *x, float u, float v, float out[2])
{
    const float uv[2] = {u, v};
    pt_tex_xform_apply(x, uv, out);
}

static void test_transform(void)
{
    float o[2];
    /* The identity is not applied: the same bits, even for -0 and NaN. */
    pt_tex_xform id = pt_tex_xform_identity();
    CHECK(!id.active && id.texcoord == 0);
    apply(&id, -0.0f, NAN, o);
    CHECK(signbit(o[0]) && isnan(o[1]));
    pt_tex_xform zero;
    memset(&zero, 0, sizeof zero); /* a zeroed transform is the identity too */
    apply(&zero, 0.3f, 0.7f, o);
    CHECK(o[0] == 0.3f && o[1] == 0.7f);

    /* The check: an offset of 0.5 swaps the halves of a two-tone
     * (black | white) texture. */
    pt_texture two;
    memset(&two, 0, sizeof two);
    two.width = 2;
    two.height = 1;
    two.nearest = 1;
    uint8_t px[8] = {0, 0, 0, 255, 255, 255, 255, 255};
    two.rgba = px;
    const float off[2] = {0.5f, 0.0f}, one[2] = {1.0f, 1.0f};
    pt_tex_xform x = pt_tex_xform_make(off, 0.0f, one, 0);
    CHECK(x.active);
    for (int i = 0; i < 8; i++) {
        float u = (i + 0.5f) / 8.0f;
        apply(&x, u, 0.5f, o);
        float c[4];
        pt_texture_sample(&two, o[0], o[1], c);
        CHECKF(c[0] == (u < 0.5f ? 1.0f : 0.0f), "offset 0.5 at u=%g reads %g", (double)u,
               (double)c[0]);
    }
    /* Scale then rotation then offset (T * R * S): rotation pi/2 sends
     * (u, v) to (v, -u) (the sense TextureTransformTest's markers show). */
    const float sc[2] = {2.0f, 3.0f}, of2[2] = {0.25f, -0.5f};
    x = pt_tex_xform_make(of2, (float)(PI_D / 2), sc, 1);
    CHECK(x.active && x.texcoord == 1);
    apply(&x, 0.1f, 0.2f, o);
    /* S: (0.2, 0.6); R: (0.6, -0.2); T: (0.85, -0.7). */
    CHECKF(fabsf(o[0] - 0.85f) < 1e-6f && fabsf(o[1] + 0.7f) < 1e-6f, "TRS gives %g %g",
           (double)o[0], (double)o[1]);
    /* A general angle against the matrix written out. */
    double a = 0.3;
    x = pt_tex_xform_make(of2, (float)a, sc, 0);
    apply(&x, 0.4f, -0.3f, o);
    double wu = cos(a) * 2 * 0.4 + sin(a) * 3 * -0.3 + 0.25;
    double wv = -sin(a) * 2 * 0.4 + cos(a) * 3 * -0.3 - 0.5;
    CHECK(fabs(o[0] - wu) < 1e-6 && fabs(o[1] - wv) < 1e-6);
}

/* A quad's triangle with TEXCOORD_0 and TEXCOORD_1; the slot reads the set
 * its texCoord names, transformed. */
static void test_slot_uv(void)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m = pt_material_default();
    const float of[2] = {0.5f, 0.0f}, one[2] = {1.0f, 1.0f};
    m.tex_xf[PT_SLOT_BASE] = pt_tex_xform_make(of, 0.0f, one, 1);
    m.tex_xf[PT_SLOT_EMISSIVE].texcoord = 1; /* set 1, no transform */
    uint32_t mi;
    CHECK(pt_scene_builder_add_material(b, &m, &mi, &err) == PT_OK);
    const float pos[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    const float uv0[6] = {0, 0, 1, 0, 0, 1};
    const float uv1[6] = {0.1f, 0.2f, 0.3f, 0.2f, 0.1f, 0.6f};
    pt_mesh_extra ex = {uv1, NULL, NULL};
    CHECKF(pt_scene_builder_add_mesh_extra(b, "tri", pos, NULL, uv0, &ex, 3, NULL, 1, NULL, mi,
                                           &err) == PT_OK,
           "%s", err.msg);
    /* A second mesh without TEXCOORD_1 gets zeros there. */
    const float pos2[9] = {0, 0, 1, 1, 0, 1, 0, 1, 1};
    CHECK(pt_scene_builder_add_mesh(b, "tri2", pos2, NULL, uv0, 3, NULL, 1, NULL, mi, &err) ==
          PT_OK);
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    if (!s)
        return;
    CHECK(s->uvs1 != NULL && s->tangents == NULL && s->colors == NULL);
    CHECK(!(s->features & (PT_FEAT_NORMAL_MAP | PT_FEAT_VERTEX_COLOR)));
    float o[2];
    /* b1 = 0.5, b2 = 0.25: uv1 = 0.25 * (0.1, 0.2) + 0.5 * (0.3, 0.2) + 0.25 * (0.1, 0.6). */
    pt_scene_slot_uv(s, &s->materials[0], PT_SLOT_BASE, 0, 0.5f, 0.25f, o);
    CHECKF(fabsf(o[0] - (0.2f + 0.5f)) < 1e-6f && fabsf(o[1] - 0.3f) < 1e-6f, "slot uv %g %g",
           (double)o[0], (double)o[1]);
    pt_scene_slot_uv(s, &s->materials[0], PT_SLOT_EMISSIVE, 0, 0.5f, 0.25f, o);
    CHECK(fabsf(o[0] - 0.2f) < 1e-6f && fabsf(o[1] - 0.3f) < 1e-6f);
    pt_scene_slot_uv(s, &s->materials[0], PT_SLOT_METAL_ROUGH, 0, 0.5f, 0.25f, o);
    CHECK(fabsf(o[0] - 0.5f) < 1e-6f && fabsf(o[1] - 0.25f) < 1e-6f); /* set 0 */
    pt_scene_slot_uv(s, &s->materials[0], PT_SLOT_EMISSIVE, 1, 0.5f, 0.25f, o);
    CHECK(o[0] == 0.0f && o[1] == 0.0f);
    pt_scene_free(s);

    /* Rejects: a texCoord other than 0 and 1, a non-finite transform, a
     * tangent whose w is not +-1, a non-finite colour. */
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    m = pt_material_default();
    m.tex_xf[PT_SLOT_NORMAL].texcoord = 2;
    CHECK(pt_scene_builder_add_material(b, &m, &mi, &err) == PT_ERR_FORMAT);
    m = pt_material_default();
    m.tex_xf[PT_SLOT_BASE].m[2] = INFINITY;
    CHECK(pt_scene_builder_add_material(b, &m, &mi, &err) == PT_ERR_FORMAT);
    m = pt_material_default();
    m.normal_tex = 0; /* no texture yet */
    CHECK(pt_scene_builder_add_material(b, &m, &mi, &err) == PT_ERR_ARG);
    m = pt_material_default();
    CHECK(pt_scene_builder_add_material(b, &m, &mi, &err) == PT_OK);
    const float tan_bad[12] = {1, 0, 0, 0.5f, 1, 0, 0, 1, 1, 0, 0, 1};
    pt_mesh_extra e2 = {NULL, tan_bad, NULL};
    CHECK(pt_scene_builder_add_mesh_extra(b, "t", pos, NULL, uv0, &e2, 3, NULL, 1, NULL, mi,
                                          &err) == PT_ERR_FORMAT);
    CHECK(strstr(err.msg, "TANGENT") != NULL);
    const float col_bad[12] = {1, 1, 1, 1, NAN, 1, 1, 1, 1, 1, 1, 1};
    pt_mesh_extra e3 = {NULL, NULL, col_bad};
    CHECK(pt_scene_builder_add_mesh_extra(b, "c", pos, NULL, uv0, &e3, 3, NULL, 1, NULL, mi,
                                          &err) == PT_ERR_FORMAT);
    CHECK(strstr(err.msg, "COLOR_0") != NULL);
    pt_scene_builder_free(b);
}

static double angle_deg(const float *a, const float *b)
{
    double d = (double)a[0] * b[0] + (double)a[1] * b[1] + (double)a[2] * b[2];
    return acos(d > 1.0 ? 1.0 : (d < -1.0 ? -1.0 : d)) * 180.0 / PI_D;
}

/* A 2 x 2 plane at z = 0 (normal +z) with u = su x, v = -y (v points down
 * in the image, so +y is the image's up): the tangent is sign(su) x and the
 * bitangent +y, so w = +1 for su > 0 and -1 for a mirrored layout. */
static void test_plane_tangents(void)
{
    for (int mirror = 0; mirror < 2; mirror++) {
        float su = mirror ? -1.0f : 1.0f;
        const float pos[12] = {-1, -1, 0, 1, -1, 0, 1, 1, 0, -1, 1, 0};
        const float nrm[12] = {0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 0, 1};
        float uv[8];
        for (int i = 0; i < 4; i++) {
            uv[2 * i] = su * pos[3 * i];
            uv[2 * i + 1] = -pos[3 * i + 1];
        }
        const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
        float tan[16] = {0};
        pt_error err = {0};
        CHECK(pt_tangents_generate(pos, nrm, uv, idx, 2, NULL, 4, tan, &err) == PT_OK);
        for (int v = 0; v < 4; v++) {
            const float want[3] = {su, 0, 0};
            CHECKF(angle_deg(&tan[4 * v], want) < 1e-4 && tan[4 * v + 3] == su,
                   "mirror %d vertex %d: tangent %g %g %g w %g", mirror, v, (double)tan[4 * v],
                   (double)tan[4 * v + 1], (double)tan[4 * v + 2], (double)tan[4 * v + 3]);
        }
    }
    /* Degenerate UVs (all zero): a unit tangent perpendicular to the normal. */
    const float pos[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0}, nrm[9] = {0, 0, 1, 0, 0, 1, 0, 0, 1};
    const float uv[6] = {0};
    const uint32_t idx[3] = {0, 1, 2};
    float tan[12] = {0};
    pt_error err = {0};
    CHECK(pt_tangents_generate(pos, nrm, uv, idx, 1, NULL, 3, tan, &err) == PT_OK);
    CHECK(fabsf(tan[2]) < 1e-6f && fabsf(tan[0] * tan[0] + tan[1] * tan[1] - 1.0f) < 1e-6f &&
          tan[3] == 1.0f);
    /* A given tangent is kept; a triangle not in use[] leaves its vertices. */
    float keep[12] = {0, 1, 0, -1};
    uint8_t use0 = 0;
    CHECK(pt_tangents_generate(pos, nrm, uv, idx, 1, &use0, 3, keep, &err) == PT_OK);
    CHECK(keep[1] == 1.0f && keep[3] == -1.0f && keep[4] == 0.0f && keep[7] == 0.0f);
}

/* A latitude-longitude sphere (u = phi / 2 pi, v = theta / pi from the
 * north pole): away from the poles the tangent is dP/du, the direction of
 * increasing phi, (-sin phi, cos phi, 0); the bitangent points north
 * (decreasing v), and cross(n, t) is north too, so w = +1. */
static void test_sphere_tangents(void)
{
    enum { NU = 48, NV = 24 };
    uint32_t nv = (NU + 1) * (NV + 1), nt = 2 * NU * NV;
    float *pos = pt_malloc_array(nv, 3 * sizeof(float));
    float *nrm = pt_malloc_array(nv, 3 * sizeof(float));
    float *uv = pt_malloc_array(nv, 2 * sizeof(float));
    float *tan = pt_calloc(nv, 4 * sizeof(float));
    uint32_t *idx = pt_malloc_array(nt, 3 * sizeof(uint32_t));
    for (uint32_t j = 0; j <= NV; j++)
        for (uint32_t i = 0; i <= NU; i++) {
            uint32_t k = j * (NU + 1) + i;
            double phi = 2 * PI_D * i / NU, th = PI_D * j / NV;
            nrm[3 * k] = pos[3 * k] = (float)(sin(th) * cos(phi));
            nrm[3 * k + 1] = pos[3 * k + 1] = (float)(sin(th) * sin(phi));
            nrm[3 * k + 2] = pos[3 * k + 2] = (float)cos(th);
            uv[2 * k] = (float)i / NU;
            uv[2 * k + 1] = (float)j / NV;
        }
    uint32_t t = 0;
    for (uint32_t j = 0; j < NV; j++)
        for (uint32_t i = 0; i < NU; i++) {
            uint32_t a = j * (NU + 1) + i, b = a + 1, c = a + NU + 1, d = c + 1;
            /* Outward winding: a, c, d and a, d, b. */
            uint32_t q[6] = {a, c, d, a, d, b};
            memcpy(&idx[3 * t], q, sizeof q);
            t += 2;
        }
    pt_error err = {0};
    CHECK(pt_tangents_generate(pos, nrm, uv, idx, nt, NULL, nv, tan, &err) == PT_OK);
    double worst = 0.0, worst_seam = 0.0;
    int wbad = 0;
    for (uint32_t j = 1; j < NV; j++)
        for (uint32_t i = 0; i <= NU; i++) {
            uint32_t k = j * (NU + 1) + i;
            double phi = 2 * PI_D * i / NU;
            const float want[3] = {(float)-sin(phi), (float)cos(phi), 0.0f};
            double a = angle_deg(&tan[4 * k], want);
            if (i == 0 || i == NU)
                worst_seam = fmax(worst_seam, a);
            else
                worst = fmax(worst, a);
            wbad += tan[4 * k + 3] != 1.0f;
        }
    /* Each triangle's dP/du is a chord, turned by half the grid step (3.75
     * degrees) from the tangent at its ends: inside, the two neighbours'
     * chords cancel to within 0.05 degrees (the diagonal split is not
     * symmetric); on the UV seam a vertex has only
     * one side's (as MikkTSpace, which does not weld across seams). */
    CHECKF(worst < 0.05 && worst_seam < 3.76 && wbad == 0,
           "sphere tangents: worst %g deg (seam %g), %d bad w", worst, worst_seam, wbad);
    pt_free(pos);
    pt_free(nrm);
    pt_free(uv);
    pt_free(tan);
    pt_free(idx);
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Regenerates the tangents of a shared asset that supplies TANGENT and
 * compares: angle quantiles (degrees) and the number of w that differ. */
static void compare_asset(const char *rel, double max_median, double max_p90, double max_all)
{
    char p[1024];
    snprintf(p, sizeof p, "%s/%s", PT_SHARED_SCENES, rel);
    pt_scene *s = NULL;
    pt_error err = {0};
    pt_scene_opts o = {0};
    o.warn = NULL;
    CHECKF(pt_scene_load(p, &o, &s, &err) == PT_OK, "%s: %s", rel, err.msg);
    if (!s)
        return;
    CHECK(s->tangents != NULL && s->uvs != NULL);
    if (!s->tangents || !s->uvs) {
        pt_scene_free(s);
        return;
    }
    uint32_t nv = s->num_vertices;
    float *g = pt_calloc(nv, 4 * sizeof(float));
    double *ang = pt_malloc_array(nv, sizeof(double));
    CHECK(pt_tangents_generate(s->positions, s->normals, s->uvs, s->indices, s->num_triangles, NULL,
                               nv, g, &err) == PT_OK);
    uint32_t n = 0, wbad = 0;
    for (uint32_t v = 0; v < nv; v++) {
        if (g[4 * v + 3] == 0.0f)
            continue; /* no triangle uses it */
        ang[n++] = angle_deg(&s->tangents[4 * v], &g[4 * v]);
        wbad += s->tangents[4 * v + 3] != g[4 * v + 3];
    }
    qsort(ang, n, sizeof(double), cmp_double);
    double med = ang[n / 2], p90 = ang[(size_t)n * 9 / 10], mx = ang[n - 1];
    printf("%s: %u vertices, generated vs TANGENT: median %.4f, p90 %.4f, p99 %.4f, max %.4f "
           "deg; %u w differ\n",
           rel, n, med, p90, ang[(size_t)n * 99 / 100], mx, wbad);
    CHECKF(n > 0 && med <= max_median && p90 <= max_p90 && mx <= max_all && wbad == 0,
           "%s: median %g p90 %g max %g, %u w differ", rel, med, p90, mx, wbad);
    pt_free(g);
    pt_free(ang);
    pt_scene_free(s);
}

static void test_shared_tangents(void)
{
    struct stat sb;
    if (stat(PT_SHARED_SCENES, &sb) != 0) {
        if (check_shared_required())
            CHECKF(0, "shared scenes missing at %s", PT_SHARED_SCENES);
        else
            CHECK_SKIP("shared assets: %s not found", PT_SHARED_SCENES);
        return;
    }
    compare_asset("NormalTangentMirrorTest/NormalTangentMirrorTest.glb", 0.25, 0.25, 0.25);
    compare_asset("LightsPunctualLamp/LightsPunctualLamp.gltf", 0.1, 0.1, 90.0);
}

/* A texture in rows holding `bytes` (w x h RGBA8), for the reference. */
static pt_texture rows_of(const uint8_t *bytes, uint32_t w, uint32_t h)
{
    pt_texture t;
    memset(&t, 0, sizeof t);
    t.width = w;
    t.height = h;
    t.rgba = (uint8_t *)bytes;
    return t;
}

/* Textures that a material reads at the same coordinates share a block,
 * texel by texel (scene.h, pt_texture): a material with base colour,
 * metal-rough, normal and emissive textures of 9 x 5 on TEXCOORD_0 and a
 * clearcoat texture of another size, and a second material whose base
 * colour texture is read through a transform and whose normal texture is
 * the first material's. The first four must end in one block of 16 bytes a
 * texel, in slot order, the others alone; the bytes at the places the
 * layout gives, every texel through pt_texture_texel, and lookups at
 * random and special coordinates under every wrap mode and filter must be
 * those of the same bytes in rows, bit for bit. */
enum { SB_W = 9, SB_H = 5, SB_NT = 6 };
static const uint32_t sb_dims[SB_NT][2] = {{SB_W, SB_H}, {SB_W, SB_H}, {SB_W, SB_H},
                                           {SB_W, SB_H}, {4, 4},       {SB_W, SB_H}};

/* The scene of test_shared_blocks, its texels from src (filled here when
 * fill); PT_OK and *out, or a failure with nothing leaked. */
static pt_status shared_scene(uint8_t *src[SB_NT], int fill, pt_scene **out, pt_error *err)
{
    uint64_t rng = 0x2545f4914f6cdd1dull;
    pt_scene_builder *b = NULL;
    pt_status st = pt_scene_builder_new(&b, err);
    if (st != PT_OK)
        return st;
    uint32_t ti[SB_NT];
    for (int k = 0; k < SB_NT; k++) {
        size_t len = (size_t)sb_dims[k][0] * sb_dims[k][1] * 4;
        pt_texture t;
        memset(&t, 0, sizeof t);
        t.width = sb_dims[k][0];
        t.height = sb_dims[k][1];
        t.rgba = pt_malloc(len);
        t.srgb = k == 0 || k == 3;
        if (!t.rgba) {
            pt_scene_builder_free(b);
            return PT_ERR_NOMEM;
        }
        for (size_t i = 0; i < len; i++) {
            rng = rng * 6364136223846793005ull + 1442695040888963407ull;
            if (fill)
                src[k][i] = (uint8_t)(rng >> 56);
            t.rgba[i] = src[k][i];
        }
        if ((st = pt_scene_builder_add_texture(b, &t, &ti[k], err)) != PT_OK) {
            pt_scene_builder_free(b);
            return st;
        }
    }
    pt_material m = pt_material_default();
    m.base_color_tex = (int32_t)ti[0];
    m.metal_rough_tex = (int32_t)ti[1];
    m.normal_tex = (int32_t)ti[2];
    m.emissive_tex = (int32_t)ti[3];
    m.emissive[0] = m.emissive[1] = m.emissive[2] = 1.0f;
    m.clearcoat = 1.0f;
    m.clearcoat_tex = (int32_t)ti[4];
    pt_material m2 = pt_material_default();
    m2.normal_tex = (int32_t)ti[2];
    m2.base_color_tex = (int32_t)ti[5];
    const float of[2] = {0.25f, 0.0f}, one[2] = {1.0f, 1.0f};
    m2.tex_xf[PT_SLOT_BASE] = pt_tex_xform_make(of, 0.0f, one, 0);
    const float pos[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0}, pos2[9] = {0, 0, 1, 1, 0, 1, 0, 1, 1};
    const float uv0[6] = {0, 0, 1, 0, 0, 1};
    uint32_t mi, mi2;
    if ((st = pt_scene_builder_add_material(b, &m, &mi, err)) != PT_OK ||
        (st = pt_scene_builder_add_material(b, &m2, &mi2, err)) != PT_OK ||
        (st = pt_scene_builder_add_mesh(b, "a", pos, NULL, uv0, 3, NULL, 1, NULL, mi, err)) !=
            PT_OK ||
        (st = pt_scene_builder_add_mesh(b, "b", pos2, NULL, uv0, 3, NULL, 1, NULL, mi2, err)) !=
            PT_OK) {
        pt_scene_builder_free(b);
        return st;
    }
    return pt_scene_builder_finish(b, NULL, out, err); /* frees b */
}

/* Every texel of the scene's textures read back as src holds it. */
static int shared_texels_bad(const pt_scene *s, uint8_t *src[SB_NT])
{
    int bad = 0;
    for (int k = 0; k < SB_NT; k++)
        for (uint32_t y = 0; y < sb_dims[k][1]; y++)
            for (uint32_t x = 0; x < sb_dims[k][0]; x++) {
                uint8_t got[4];
                pt_texture_texel(&s->textures[k], x, y, got);
                bad += memcmp(got, src[k] + 4 * ((size_t)y * sb_dims[k][0] + x), 4) != 0;
            }
    return bad;
}

static void test_shared_blocks(void)
{
    enum { W = SB_W, H = SB_H, NT = SB_NT };
    uint8_t *src[NT];
    for (int k = 0; k < NT; k++)
        src[k] = malloc((size_t)sb_dims[k][0] * sb_dims[k][1] * 4);
    uint64_t rng = 0x9e3779b97f4a7c15ull;
    pt_error err = {0};
    pt_scene *s = NULL;
    CHECKF(shared_scene(src, 1, &s, &err) == PT_OK, "%s", err.msg);
    if (s && s->num_textures == NT) {
        const pt_texture *t = s->textures;
        /* Base, metal-rough, normal, emissive: one block, in slot order
         * (core slots: base, metal-rough, normal, emissive). */
        for (uint32_t j = 0; j < 4; j++)
            CHECKF(t[j].step == 16 && t[j].member == j && t[j].rgba == t[0].rgba + 4 * j,
                   "texture %u: step %u, member %u", j, t[j].step, t[j].member);
        for (uint32_t j = 4; j < NT; j++) /* another size; another transform */
            CHECKF((t[j].step == 0 || t[j].step == 4) && t[j].member == 0,
                   "texture %u: step %u, member %u", j, t[j].step, t[j].member);
        int bad_layout = 0, bad_texel = 0, bad_sample = 0, n = 0;
        for (size_t i = 0; i < (size_t)W * H; i++)
            for (uint32_t j = 0; j < 4; j++)
                bad_layout += memcmp(t[0].rgba + 16 * i + 4 * j, src[j] + 4 * i, 4) != 0;
        bad_texel = shared_texels_bad(s, src);
        for (int k = 0; k < NT; k++) {
            pt_texture ref = rows_of(src[k], sb_dims[k][0], sb_dims[k][1]);
            pt_texture tk = t[k];
            ref.srgb = tk.srgb;
            for (int mode = 0; mode < 18; mode++) {
                tk.wrap_s = ref.wrap_s = mode % 3;
                tk.wrap_t = ref.wrap_t = (mode / 3) % 3;
                tk.nearest = ref.nearest = mode / 9;
                for (int q = 0; q < 400; q++) {
                    float uv[2];
                    for (int a = 0; a < 2; a++) {
                        rng = rng * 6364136223846793005ull + 1442695040888963407ull;
                        uint32_t r = (uint32_t)(rng >> 32);
                        uv[a] = r % 5 == 0 ? (float)(int)(r % 31 - 10) / (float)(a ? H : W)
                                           : ((float)(r >> 8) * 0x1p-24f) * 4.0f - 2.0f;
                    }
                    float got[4], want[4];
                    pt_texture_sample(&tk, uv[0], uv[1], got);
                    ref_sample(&ref, uv[0], uv[1], want);
                    bad_sample += memcmp(got, want, sizeof got) != 0;
                    n++;
                }
            }
        }
        CHECKF(bad_layout == 0, "%d texels not where the shared layout puts them", bad_layout);
        CHECKF(bad_texel == 0, "%d texels read back wrong", bad_texel);
        CHECKF(bad_sample == 0, "%d of %d lookups differ from the rows' bits", bad_sample, n);
        /* A hint on shared blocks: it must not fault. */
        const uint32_t tris[2] = {0, 1};
        const float b1[2] = {0.3f, 0.1f}, b2[2] = {0.3f, 0.8f};
        pt_scene_prefetch_hits(s, 2, tris, b1, b2);
    } else {
        CHECK(!"the scene has its six textures");
    }
    pt_scene_free(s);
    for (int k = 0; k < NT; k++)
        free(src[k]);
}

/* Allocation failure at every step of building that scene: a failure with
 * nothing leaked, or a scene whose texels all read back right, its blocks
 * shared or, where the block's allocation failed, left as they were. */
static void test_shared_blocks_nomem(void)
{
    uint8_t *src[SB_NT];
    for (int k = 0; k < SB_NT; k++)
        src[k] = malloc((size_t)sb_dims[k][0] * sb_dims[k][1] * 4);
    pt_error err = {0};
    pt_scene *s = NULL;
    CHECK(shared_scene(src, 1, &s, &err) == PT_OK);
    pt_scene_free(s);
    int64_t live = pt_alloc_live();
    int failed = 0, apart = 0, shared = 0, bad = 0;
    for (uint64_t n = 1; n < 2000; n++) {
        pt_alloc_fail_at(n);
        s = NULL;
        pt_status st = shared_scene(src, 0, &s, &err);
        pt_alloc_fail_at(0);
        if (st != PT_OK) {
            failed++;
            CHECKF(st == PT_ERR_NOMEM && !s, "allocation %llu: status %d", (unsigned long long)n,
                   (int)st);
        } else {
            bad += shared_texels_bad(s, src);
            if (s->textures[0].step == 16)
                shared++;
            else
                apart++;
            pt_scene_free(s);
        }
        CHECKF(pt_alloc_live() == live, "allocation %llu: %lld blocks leaked",
               (unsigned long long)n, (long long)(pt_alloc_live() - live));
        if (st == PT_OK && shared)
            break; /* past the last allocation */
    }
    CHECKF(bad == 0, "%d texels read back wrong", bad);
    CHECKF(failed > 0 && apart >= 1 && shared == 1, "%d failed, %d apart, %d shared", failed, apart,
           shared);
    printf("shared blocks under failing allocations: %d failed, %d built apart, %d shared\n",
           failed, apart, shared);
    for (int k = 0; k < SB_NT; k++)
        free(src[k]);
}

int main(void)
{
    test_decode_tables();
    test_against_reference();
    test_shared_blocks();
    test_shared_blocks_nomem();
    test_nearest();
    test_linear();
    test_transform();
    test_slot_uv();
    test_plane_tangents();
    test_sphere_tangents();
    test_shared_tangents();
    return check_report();
}
