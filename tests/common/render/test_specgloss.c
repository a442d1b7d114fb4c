/*
 * test_specgloss.c - KHR_materials_pbrSpecularGlossiness and the textures of
 * KHR_materials_specular, through glTF files written here, the importer and
 * the whole integrator.
 *
 * - pt_bsdf_setup_spec_gloss equals the metallic-roughness base it converts
 *   to (bsdf.h): a metal (diffuse 0, specular S) is base S, metallic 1; a
 *   dielectric (specular 0.04) is base 0.96 x diffuse, metallic 0; any
 *   other is base c_diff, metallic 0, specular 1, specular colour S / 0.04.
 *   Every field within 1e-6 (the diffuse weight's Fresnel where there is a
 *   diffuse: 1 - the largest channel of the Fresnel from F0 = S, as
 *   KHR_materials_specular weighs the conversion's diffuse).
 * - Pairs of files, one a specular-glossiness sphere and one the
 *   metallic-roughness sphere it converts to (the conversions above: a
 *   gold metal, a red dielectric, and one whose diffuse, specular and
 *   glossiness come from textures, converted with their decoded texels),
 *   rendered with the same seed under a uniform environment and a
 *   directional light, sample by sample: no pixel channel's paired
 *   difference is 5 standard errors (and float rounding) from 0
 *   (paired.h), while more than 1 % of them differ from what the
 *   metallic-roughness fallback of the file renders.
 * - The same for KHR_materials_specular: specularTexture (A) and
 *   specularColorTexture (RGB, sRGB) times their factors against the
 *   factors alone set to their product.
 * - KHR_materials_ior on an opaque dielectric (ior 2) renders as the
 *   specular colour scaled by its F0 over 0.04, with no warning, and not as
 *   ior 1.5 does.
 * - A glossinessFactor or specularFactor outside [0, 1] is refused with an
 *   error that names it.
 * - SpecularTest (../shared/scenes) loads without a warning about specular
 *   textures, reads both textures, and renders with no NaN/Inf (skipped
 *   without ../shared; a failure under CI=true).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <stb_image_write.h>

#include "common/base/alloc.h"
#include "common/render/bsdf.h"
#include "common/render/env.h"
#include "common/render/render.h"
#include "common/scene/scene.h"
#include "tests/check.h"
#include "tests/common/render/paired.h"

#define SIDE 32u
#define SPP 32u
#define LAT 24
#define LON 48
#define PI_D 3.14159265358979323846

static char tmp[256];

static const char *tpath(const char *name)
{
    static char p[512];
    snprintf(p, sizeof p, "%s/%s", tmp, name);
    return p;
}

/* ---- the BSDF conversion ----------------------------------------------- */

/* Every field within 1e-6; the diffuse weight's dielectric_f0 and f90 only
 * where there is a diffuse to weigh (a metal's have no effect). */
static int bsdf_close(pt_bsdf a, pt_bsdf b)
{
    const float x[10] = {a.diffuse.x,     a.diffuse.y,     a.diffuse.z,   a.f0.x,
                         a.f0.y,          a.f0.z,          a.spec_weight, a.alpha,
                         a.dielectric_f0, a.dielectric_f90};
    const float y[10] = {b.diffuse.x,     b.diffuse.y,     b.diffuse.z,   b.f0.x,
                         b.f0.y,          b.f0.z,          b.spec_weight, b.alpha,
                         b.dielectric_f0, b.dielectric_f90};
    int n = pt_v3_max_comp(a.diffuse) > 0.0f || pt_v3_max_comp(b.diffuse) > 0.0f ? 10 : 8;
    for (int i = 0; i < n; i++)
        if (!(fabsf(x[i] - y[i]) <= 1e-6f))
            return 0;
    return 1;
}

static void conversion(void)
{
    pt_vec3 gold = pt_v3(1.0f, 0.766f, 0.336f), red = pt_v3(0.8f, 0.3f, 0.2f);
    pt_vec3 f004 = pt_v3(0.04f, 0.04f, 0.04f), s = pt_v3(0.2f, 0.1f, 0.05f);
    for (float g = 0.0f; g <= 1.0f; g += 0.25f) {
        CHECK(bsdf_close(pt_bsdf_setup_spec_gloss(pt_v3(0, 0, 0), gold, g),
                         pt_bsdf_setup(gold, 1.0f, 1.0f - g, 1.0f, pt_v3(1, 1, 1))));
        CHECK(bsdf_close(
            pt_bsdf_setup_spec_gloss(red, f004, g),
            pt_bsdf_setup(pt_v3_scale(red, 0.96f), 0.0f, 1.0f - g, 1.0f, pt_v3(1, 1, 1))));
        CHECK(bsdf_close(pt_bsdf_setup_spec_gloss(red, s, g),
                         pt_bsdf_setup(pt_v3_scale(red, 0.8f), 0.0f, 1.0f - g, 1.0f,
                                       pt_v3_scale(s, 1.0f / 0.04f))));
        /* And not the metallic-roughness reading of the same numbers. */
        CHECK(!bsdf_close(pt_bsdf_setup_spec_gloss(red, s, g),
                          pt_bsdf_setup(red, 0.0f, 1.0f - g, 1.0f, pt_v3(1, 1, 1))));
    }
}

/* ---- the files --------------------------------------------------------- */

/* A unit UV sphere with normals and UVs, as sphere.bin; its byte length. */
static size_t write_sphere(void)
{
    const int nv = (LAT + 1) * (LON + 1), nt = 2 * LAT * LON;
    size_t len = (size_t)nv * 32 + (size_t)nt * 12;
    unsigned char *bin = calloc(1, len);
    if (!bin)
        return 0;
    float *pos = (float *)bin, *nrm = pos + 3 * nv, *uv = nrm + 3 * nv;
    uint32_t *idx = (uint32_t *)(uv + 2 * nv);
    for (int i = 0; i <= LAT; i++) {
        for (int j = 0; j <= LON; j++) {
            double th = PI_D * i / LAT, ph = 2.0 * PI_D * j / LON;
            int k = i * (LON + 1) + j;
            float p[3] = {(float)(sin(th) * cos(ph)), (float)cos(th), (float)(sin(th) * sin(ph))};
            memcpy(&pos[3 * k], p, sizeof p);
            memcpy(&nrm[3 * k], p, sizeof p);
            uv[2 * k] = (float)j / LON;
            uv[2 * k + 1] = (float)i / LAT;
        }
    }
    int t = 0;
    for (int i = 0; i < LAT; i++) {
        for (int j = 0; j < LON; j++) {
            uint32_t a = (uint32_t)(i * (LON + 1) + j), b = a + 1, c = a + LON + 1, d = c + 1;
            /* Wound outwards. */
            const uint32_t q[6] = {a, b, c, b, d, c};
            memcpy(&idx[6 * t++], q, sizeof q);
        }
    }
    FILE *f = fopen(tpath("sphere.bin"), "wb");
    size_t ok = f && fwrite(bin, 1, len, f) == len;
    if (f)
        fclose(f);
    free(bin);
    return ok ? len : 0;
}

/* A 2 x 2 PNG of one RGBA colour. */
static void write_png(const char *name, const uint8_t rgba[4])
{
    uint8_t px[16];
    for (int i = 0; i < 4; i++)
        memcpy(px + 4 * i, rgba, 4);
    CHECK(stbi_write_png(tpath(name), 2, 2, 4, px, 8) != 0);
}

/* The sphere with `material` (JSON) and `images` (a JSON list of URIs, one
 * texture each, or NULL), a camera at z = 3 and a directional light. */
static void write_gltf(const char *name, size_t bin_len, const char *material, const char *images)
{
    const int nv = (LAT + 1) * (LON + 1), nt = 2 * LAT * LON;
    char tex[1024] = "";
    if (images) {
        int n = 1;
        for (const char *c = images; *c; c++)
            n += *c == ',';
        int k = snprintf(tex, sizeof tex, "\"images\":%s,\"textures\":[", images);
        for (int i = 0; i < n; i++)
            k += snprintf(tex + k, sizeof tex - (size_t)k, "%s{\"source\":%d}", i ? "," : "", i);
        snprintf(tex + k, sizeof tex - (size_t)k, "],");
    }
    FILE *f = fopen(tpath(name), "w");
    if (!f)
        return;
    fprintf(f,
            "{\"asset\":{\"version\":\"2.0\"},\"extensionsUsed\":[\"KHR_lights_punctual\","
            "\"KHR_materials_pbrSpecularGlossiness\",\"KHR_materials_specular\"],"
            "\"extensions\":{\"KHR_lights_punctual\":{\"lights\":[{\"type\":\"directional\","
            "\"intensity\":3}]}},"
            "\"scene\":0,\"scenes\":[{\"nodes\":[0,1,2]}],"
            "\"nodes\":[{\"mesh\":0},{\"camera\":0,\"translation\":[0,0,3]},"
            "{\"rotation\":[-0.2,0.3,0,0.932738],\"extensions\":{\"KHR_lights_punctual\":"
            "{\"light\":0}}}],"
            "\"cameras\":[{\"type\":\"perspective\",\"perspective\":{\"yfov\":0.8,"
            "\"znear\":0.1,\"aspectRatio\":1}}],"
            "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0,\"NORMAL\":1,"
            "\"TEXCOORD_0\":2},\"indices\":3,\"material\":0}]}],"
            "\"materials\":[%s],%s"
            "\"buffers\":[{\"uri\":\"sphere.bin\",\"byteLength\":%zu}],"
            "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":0,\"byteLength\":%d},"
            "{\"buffer\":0,\"byteOffset\":%d,\"byteLength\":%d},"
            "{\"buffer\":0,\"byteOffset\":%d,\"byteLength\":%d},"
            "{\"buffer\":0,\"byteOffset\":%d,\"byteLength\":%d}],"
            "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":%d,\"type\":"
            "\"VEC3\",\"min\":[-1,-1,-1],\"max\":[1,1,1]},"
            "{\"bufferView\":1,\"componentType\":5126,\"count\":%d,\"type\":\"VEC3\"},"
            "{\"bufferView\":2,\"componentType\":5126,\"count\":%d,\"type\":\"VEC2\"},"
            "{\"bufferView\":3,\"componentType\":5125,\"count\":%d,\"type\":\"SCALAR\"}]}\n",
            material, tex, bin_len, 12 * nv, 12 * nv, 12 * nv, 24 * nv, 8 * nv, 32 * nv, 12 * nt,
            nv, nv, nv, 3 * nt);
    fclose(f);
}

static int warned_about; /* a warning named the word in warn_word */
static const char *warn_word;
static void note_warning(void *user, const char *message)
{
    (void)user;
    if (warn_word && strstr(message, warn_word))
        warned_about = 1;
}

static pt_scene *load(const char *path, const char *word)
{
    pt_scene_opts o = {0};
    o.warn = note_warning;
    warn_word = word;
    warned_about = 0;
    pt_scene *s = NULL;
    pt_error err = {0};
    CHECKF(pt_scene_load(path, &o, &s, &err) == PT_OK, "%s: %s", path, err.msg);
    CHECKF(!warned_about, "%s: a warning about %s", path, word);
    return s;
}

/* paired_differing (paired.h) under a uniform environment of 0.5 and the
 * files' directional light. */
static int differing(const pt_scene *a, const pt_scene *b)
{
    pt_env *env = NULL;
    pt_error err = {0};
    CHECK(pt_env_uniform(pt_v3(0.5f, 0.5f, 0.5f), &env, &err) == PT_OK);
    int n = env ? paired_differing(a, b, env, SIDE, SPP) : -1;
    pt_env_free(env);
    return n;
}

/* Files a (the extension's), b (its conversion) and the core fallback of
 * a: a and b agree at every pixel, a and the fallback differ at more than
 * 1 % of the pixel channels. */
static void expect_pair(const char *what, const char *a, const char *b, const char *fallback,
                        const char *word)
{
    pt_scene *sa = load(tpath(a), word), *sb = load(tpath(b), word),
             *sf = load(tpath(fallback), "");
    if (sa && sb && sf) {
        int n = differing(sa, sb), nf = differing(sa, sf);
        printf("%s: %d pixel channels differ from the conversion, %d from the fallback\n", what, n,
               nf);
        CHECKF(n == 0, "%s: %d pixel channels differ", what, n);
        CHECKF(nf > (int)(3 * SIDE * SIDE / 100), "%s: only %d differ from the fallback", what, nf);
    }
    pt_scene_free(sa);
    pt_scene_free(sb);
    pt_scene_free(sf);
}

static float srgb(uint8_t v)
{
    double c = v / 255.0;
    return (float)(c <= 0.04045 ? c / 12.92 : pow((c + 0.055) / 1.055, 2.4));
}

static void spec_gloss_pairs(size_t bin)
{
    char m[1024];
    /* Gold: the extension's own example. */
    write_gltf("gold_sg.gltf", bin,
               "{\"extensions\":{\"KHR_materials_pbrSpecularGlossiness\":{\"diffuseFactor\":"
               "[0,0,0,1],\"specularFactor\":[1,0.766,0.336],\"glossinessFactor\":0.8}}}",
               NULL);
    write_gltf("gold_mr.gltf", bin,
               "{\"pbrMetallicRoughness\":{\"baseColorFactor\":[1,0.766,0.336,1],"
               "\"metallicFactor\":1,\"roughnessFactor\":0.2}}",
               NULL);
    /* What a viewer without the extension shows: the core's fallback. */
    write_gltf("gold_fb.gltf", bin,
               "{\"pbrMetallicRoughness\":{\"baseColorFactor\":[1,1,1,1],"
               "\"metallicFactor\":1,\"roughnessFactor\":1}}",
               NULL);
    expect_pair("gold", "gold_sg.gltf", "gold_mr.gltf", "gold_fb.gltf", "SpecularGlossiness");

    write_gltf("red_sg.gltf", bin,
               "{\"extensions\":{\"KHR_materials_pbrSpecularGlossiness\":{\"diffuseFactor\":"
               "[0.8,0.3,0.2,1],\"specularFactor\":[0.04,0.04,0.04],\"glossinessFactor\":0.5}}}",
               NULL);
    snprintf(m, sizeof m,
             "{\"pbrMetallicRoughness\":{\"baseColorFactor\":[%.9g,%.9g,%.9g,1],"
             "\"metallicFactor\":0,\"roughnessFactor\":0.5}}",
             0.8f * 0.96f, 0.3f * 0.96f, 0.2f * 0.96f);
    write_gltf("red_mr.gltf", bin, m, NULL);
    expect_pair("red", "red_sg.gltf", "red_mr.gltf", "gold_fb.gltf", "SpecularGlossiness");

    /* Textures: diffuse (sRGB) and specular (sRGB) with glossiness (A). */
    const uint8_t d8[4] = {180, 120, 60, 255}, s8[4] = {90, 60, 30, 200};
    write_png("diffuse.png", d8);
    write_png("specgloss.png", s8);
    write_gltf("tex_sg.gltf", bin,
               "{\"extensions\":{\"KHR_materials_pbrSpecularGlossiness\":{\"diffuseTexture\":"
               "{\"index\":0},\"specularGlossinessTexture\":{\"index\":1}}}}",
               "[{\"uri\":\"diffuse.png\"},{\"uri\":\"specgloss.png\"}]");
    float sp[3] = {srgb(s8[0]), srgb(s8[1]), srgb(s8[2])};
    float smax = fmaxf(sp[0], fmaxf(sp[1], sp[2]));
    snprintf(m, sizeof m,
             "{\"pbrMetallicRoughness\":{\"baseColorFactor\":[%.9g,%.9g,%.9g,1],"
             "\"metallicFactor\":0,\"roughnessFactor\":%.9g},\"extensions\":{"
             "\"KHR_materials_specular\":{\"specularColorFactor\":[%.9g,%.9g,%.9g]}}}",
             srgb(d8[0]) * (1.0f - smax), srgb(d8[1]) * (1.0f - smax), srgb(d8[2]) * (1.0f - smax),
             1.0 - s8[3] / 255.0, sp[0] / 0.04, sp[1] / 0.04, sp[2] / 0.04);
    write_gltf("tex_mr.gltf", bin, m, NULL);
    expect_pair("textured", "tex_sg.gltf", "tex_mr.gltf", "gold_fb.gltf", "SpecularGlossiness");
}

/* Factors outside the extension's [0, 1] are refused, naming the field. */
static void refused(size_t bin)
{
    write_gltf("bad_sg.gltf", bin,
               "{\"extensions\":{\"KHR_materials_pbrSpecularGlossiness\":{"
               "\"glossinessFactor\":2}}}",
               NULL);
    write_gltf("bad_sp.gltf", bin,
               "{\"extensions\":{\"KHR_materials_pbrSpecularGlossiness\":{"
               "\"specularFactor\":[0.5,-1,0.5]}}}",
               NULL);
    const char *files[2] = {"bad_sg.gltf", "bad_sp.gltf"};
    const char *words[2] = {"glossinessFactor 2", "specularFactor -1"};
    for (int i = 0; i < 2; i++) {
        pt_scene_opts o = {0};
        o.warn = note_warning;
        pt_scene *s = NULL;
        pt_error err = {0};
        pt_status st = pt_scene_load(tpath(files[i]), &o, &s, &err);
        CHECKF(st == PT_ERR_FORMAT && strstr(err.msg, words[i]), "%s: %d %s", files[i], (int)st,
               err.msg);
        pt_scene_free(s);
    }
}

static void specular_texture_pair(size_t bin)
{
    /* specularTexture reads A, specularColorTexture RGB (sRGB): RGB of the
     * first and A of the second are set to mislead a reader of the wrong
     * channels. */
    const uint8_t st[4] = {10, 10, 10, 128}, sc[4] = {200, 100, 50, 20};
    write_png("spec.png", st);
    write_png("speccol.png", sc);
    const char *base = "\"pbrMetallicRoughness\":{\"baseColorFactor\":[0.1,0.1,0.1,1],"
                       "\"metallicFactor\":0,\"roughnessFactor\":0.3}";
    char m[1024];
    snprintf(m, sizeof m,
             "{%s,\"extensions\":{\"KHR_materials_specular\":{\"specularFactor\":1,"
             "\"specularTexture\":{\"index\":0},\"specularColorFactor\":[2,2,2],"
             "\"specularColorTexture\":{\"index\":1}}}}",
             base);
    write_gltf("spec_tex.gltf", bin, m, "[{\"uri\":\"spec.png\"},{\"uri\":\"speccol.png\"}]");
    snprintf(m, sizeof m,
             "{%s,\"extensions\":{\"KHR_materials_specular\":{\"specularFactor\":%.9g,"
             "\"specularColorFactor\":[%.9g,%.9g,%.9g]}}}",
             base, st[3] / 255.0, 2.0f * srgb(sc[0]), 2.0f * srgb(sc[1]), 2.0f * srgb(sc[2]));
    write_gltf("spec_fac.gltf", bin, m, NULL);
    /* Without the textures: the factors alone. */
    snprintf(m, sizeof m,
             "{%s,\"extensions\":{\"KHR_materials_specular\":{\"specularFactor\":1,"
             "\"specularColorFactor\":[2,2,2]}}}",
             base);
    write_gltf("spec_fb.gltf", bin, m, NULL);
    expect_pair("specular textures", "spec_tex.gltf", "spec_fac.gltf", "spec_fb.gltf", "specular");
}

/* KHR_materials_ior on an opaque dielectric: F0 = ((ior - 1) / (ior + 1))^2
 * x the specular colour, the same as the specular colour scaled by that
 * over 0.04 (ior 2: 1/9 / 0.04). */
static void opaque_ior_pair(size_t bin)
{
    const char *base = "\"pbrMetallicRoughness\":{\"baseColorFactor\":[0.2,0.3,0.4,1],"
                       "\"metallicFactor\":0,\"roughnessFactor\":0.25}";
    char m[1024];
    snprintf(m, sizeof m, "{%s,\"extensions\":{\"KHR_materials_ior\":{\"ior\":2}}}", base);
    write_gltf("ior2.gltf", bin, m, NULL);
    const double k = (1.0 / 9.0) / 0.04;
    snprintf(m, sizeof m,
             "{%s,\"extensions\":{\"KHR_materials_specular\":{\"specularColorFactor\":"
             "[%.9g,%.9g,%.9g]}}}",
             base, k, k, k);
    write_gltf("ior2_spec.gltf", bin, m, NULL);
    snprintf(m, sizeof m, "{%s}", base);
    write_gltf("ior15.gltf", bin, m, NULL);
    expect_pair("opaque ior 2", "ior2.gltf", "ior2_spec.gltf", "ior15.gltf", "ior");
}

static void specular_test_asset(void)
{
    pt_scene *s = load_shared_asset("SpecularTest/SpecularTest.glb", "specular");
    if (!s)
        return;
    CHECK(s->features & PT_FEAT_SPECULAR_TEX);
    int spec = 0, col = 0;
    for (uint32_t i = 0; i < s->num_materials; i++) {
        spec += s->materials[i].specular_tex >= 0;
        col += s->materials[i].specular_color_tex >= 0;
    }
    CHECK(spec == 1 && col == 2);
    /* Rendered (against itself): no NaN or Inf, and nothing differs. */
    CHECK(differing(s, s) == 0);
    pt_scene_free(s);
}

int main(void)
{
    snprintf(tmp, sizeof tmp, "/tmp/pt_specgloss_XXXXXX");
    if (!mkdtemp(tmp)) {
        perror("mkdtemp");
        return 1;
    }
    conversion();
    size_t bin = write_sphere();
    CHECK(bin > 0);
    spec_gloss_pairs(bin);
    specular_texture_pair(bin);
    refused(bin);
    opaque_ior_pair(bin);
    specular_test_asset();
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", tmp);
    if (system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", tmp);
    return check_report();
}
