/*
 * test_gltf.c - pt_scene_load on the shared public assets (triangle counts,
 * emissive strengths, cameras, warnings), on hostile files generated at run
 * time in a temporary folder, and under allocation failure.
 */
#include "common/scene/scene.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <stb_image_write.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/base/json.h"
#include "common/scene/bundle.h"
#include "tests/check.h"

static char tmp[256];

typedef struct warnings {
    int count;
    char text[4096];
} warnings;

static void collect(void *user, const char *msg)
{
    warnings *w = user;
    w->count++;
    size_t n = strlen(w->text);
    snprintf(w->text + n, sizeof w->text - n, "%s\n", msg);
}

static void write_file(const char *name, const void *data, size_t len)
{
    char p[512];
    snprintf(p, sizeof p, "%s/%s", tmp, name);
    FILE *f = fopen(p, "wb");
    if (!f) {
        perror(p);
        exit(1);
    }
    if (len)
        fwrite(data, 1, len, f);
    fclose(f);
}

static const char *tpath(const char *name)
{
    static char p[512];
    snprintf(p, sizeof p, "%s/%s", tmp, name);
    return p;
}

/* Loads, expecting failure: code as given (0: any error) and a message that
 * names the file and contains `word`. */
static void expect_fail(const char *name, pt_status code, const char *word)
{
    pt_error err = {0};
    pt_scene *s = NULL;
    pt_scene_opts o = {0};
    warnings w = {0};
    o.warn = collect;
    o.warn_user = &w;
    int64_t live = pt_alloc_live();
    pt_status st = pt_scene_load(tpath(name), &o, &s, &err);
    if (getenv("PT_TEST_VERBOSE"))
        printf("%s -> %s\n", name, err.msg);
    CHECKF(st != PT_OK && s == NULL, "%s loaded", name);
    if (code)
        CHECKF(st == code, "%s: status %d, expected %d (%s)", name, (int)st, (int)code, err.msg);
    CHECKF(strstr(err.msg, name) != NULL, "%s: message does not name the file: %s", name, err.msg);
    CHECKF(strstr(err.msg, word) != NULL, "%s: message lacks '%s': %s", name, word, err.msg);
    CHECKF(pt_alloc_live() == live, "%s: leaked %lld blocks", name,
           (long long)(pt_alloc_live() - live));
    pt_scene_free(s);
}

/* ---- a tiny valid scene and its hostile variants ----------------------------------- */

/* bin: 3 float3 positions (36 bytes), then 3 u16 indices (6 bytes), then 2 pad, then 3
 * float2 uvs (24 bytes): 68 bytes. */
static size_t make_bin(unsigned char *bin, float p0x, uint16_t i2)
{
    float pos[9] = {p0x, 0, 0, 1, 0, 0, 0, 1, 0};
    uint16_t idx[4] = {0, 1, i2, 0};
    float uv[6] = {0, 0, 1, 0, 0, 1};
    memcpy(bin, pos, 36);
    memcpy(bin + 36, idx, 8);
    memcpy(bin + 44, uv, 24);
    return 68;
}

static const char *k_views = "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":0,\"byteLength\":36},"
                             "{\"buffer\":0,\"byteOffset\":36,\"byteLength\":6},"
                             "{\"buffer\":0,\"byteOffset\":44,\"byteLength\":24}]";

/* A .gltf with the given pieces substituted; tail holds the materials and
 * whatever follows them. */
static void make_gltf_tail(const char *name, const char *bin_uri, const char *pos_acc,
                           const char *views, const char *nodes, const char *tail)
{
    char json[8192];
    snprintf(json, sizeof json,
             "{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],"
             "\"nodes\":%s,"
             "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0,\"TEXCOORD_0\":2},"
             "\"indices\":1,\"material\":0}]}],"
             "\"buffers\":[{\"uri\":\"%s\",\"byteLength\":68}],%s,"
             "\"accessors\":[%s,"
             "{\"bufferView\":1,\"componentType\":5123,\"count\":3,\"type\":\"SCALAR\"},"
             "{\"bufferView\":2,\"componentType\":5126,\"count\":3,\"type\":\"VEC2\"}],"
             "%s}",
             nodes, bin_uri, views, pos_acc, tail);
    write_file(name, json, strlen(json));
}

/* A .gltf with the given pieces substituted and one untextured material. */
static void make_gltf(const char *name, const char *bin_uri, const char *pos_acc, const char *views,
                      const char *nodes, const char *extra)
{
    char tail[4096];
    snprintf(tail, sizeof tail,
             "\"materials\":[{\"name\":\"m0\",\"pbrMetallicRoughness\":{\"metallicFactor\":0}}]%s",
             extra);
    make_gltf_tail(name, bin_uri, pos_acc, views, nodes, tail);
}

/* Gives material m0 of a .gltf written by make_gltf texture 0 as its
 * emissive texture, so that the texture is used and its image loaded. */
static void use_texture_as_emission(const char *name)
{
    char json[8192];
    FILE *f = fopen(tpath(name), "rb");
    size_t n = fread(json, 1, sizeof json - 1, f);
    fclose(f);
    json[n] = 0;
    char *m = strstr(json, "\"name\":\"m0\",");
    if (m) {
        char out[8192];
        snprintf(out, sizeof out, "%.*s\"name\":\"m0\",\"emissiveTexture\":{\"index\":0},%s",
                 (int)(m - json), json, m + strlen("\"name\":\"m0\","));
        write_file(name, out, strlen(out));
    }
}

static const char *k_pos_ok =
    "{\"bufferView\":0,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\"}";
static const char *k_nodes_ok = "[{\"mesh\":0,\"translation\":[0,0,1]}]";

static void test_small_valid(void)
{
    unsigned char bin[68];
    make_bin(bin, 0.0f, 2);
    write_file("tri.bin", bin, sizeof bin);
    /* A 2x2 PNG: red, green / blue, white; used as base colour with CLAMP / MIRROR. */
    unsigned char px[16] = {255, 0, 0, 255, 0, 255, 0, 255, 0, 0, 255, 255, 255, 255, 255, 255};
    CHECK(stbi_write_png(tpath("tex.png"), 2, 2, 4, px, 8) != 0);
    make_gltf(
        "tri.gltf", "tri.bin", k_pos_ok, k_views,
        "[{\"mesh\":0,\"translation\":[0,0,1],\"children\":[1]},{\"camera\":0}]",
        ",\"textures\":[{\"source\":0,\"sampler\":0}],\"images\":[{\"uri\":\"tex.png\"}],"
        "\"samplers\":[{\"wrapS\":33071,\"wrapT\":33648}],"
        "\"cameras\":[{\"type\":\"perspective\",\"perspective\":{\"yfov\":0.5,\"znear\":0.1}}]");
    /* Same material, now textured (tri.gltf's material 0 has no texture). */
    char json[8192];
    FILE *f = fopen(tpath("tri.gltf"), "rb");
    size_t n = fread(json, 1, sizeof json - 1, f);
    fclose(f);
    json[n] = 0;
    char *m = strstr(json, "\"metallicFactor\":0}");
    CHECK(m != NULL);
    if (m) {
        char out[8192];
        snprintf(out, sizeof out, "%.*s\"metallicFactor\":0,\"baseColorTexture\":{\"index\":0}}%s",
                 (int)(m - json), json, m + strlen("\"metallicFactor\":0}"));
        write_file("tritex.gltf", out, strlen(out));
    }

    pt_error err = {0};
    pt_scene *s = NULL;
    CHECKF(pt_scene_load(tpath("tritex.gltf"), NULL, &s, &err) == PT_OK, "%s", err.msg);
    if (s) {
        CHECK(s->num_triangles == 1 && s->num_vertices == 3);
        CHECK(fabsf(s->positions[2] - 1.0f) < 1e-6f); /* translated by the node */
        CHECK(fabsf(s->normals[2] - 1.0f) < 1e-6f);   /* computed: +Z */
        CHECK(s->uvs && s->uvs[2] == 1.0f);
        CHECK(s->num_textures == 1);
        if (s->num_textures == 1) {
            CHECK(s->textures[0].width == 2 && s->textures[0].srgb == 1);
            CHECK(s->textures[0].wrap_s == PT_WRAP_CLAMP &&
                  s->textures[0].wrap_t == PT_WRAP_MIRROR);
            CHECK(s->textures[0].rgba[4] == 0 && s->textures[0].rgba[5] == 255);
        }
        CHECK(s->features & PT_FEAT_TEXTURES);
        CHECK(s->features & PT_FEAT_UVS);
        CHECK(s->num_cameras == 1 && strcmp(s->camera.name, "camera 0") == 0);
        CHECK(s->camera.position.z == 1.0f && s->camera.forward.z == -1.0f);
        CHECK(strlen(s->hash) == 64);
    }
    pt_scene *s2 = NULL;
    CHECKF(pt_scene_load(tpath("tri.gltf"), NULL, &s2, &err) == PT_OK, "%s", err.msg);
    if (s2) {
        /* The texture no material uses is neither decoded nor flagged. */
        CHECK(s2->num_textures == 0 && !(s2->features & PT_FEAT_TEXTURES));
        CHECK((s2->features & PT_FEAT_GLOSSY) != 0); /* specular 1 by default: glossy */
        if (s)
            CHECK(strcmp(s->hash, s2->hash) != 0);
    }
    pt_scene_free(s);
    pt_scene_free(s2);

    /* Allocation failure: every failing allocation gives PT_ERR_NOMEM and no leak. */
    int64_t live = pt_alloc_live();
    int ok = 0;
    for (uint64_t i = 1; i < 10000 && !ok; i++) {
        pt_scene *t = NULL;
        pt_error e = {0};
        pt_alloc_fail_at(i);
        pt_status st = pt_scene_load(tpath("tritex.gltf"), NULL, &t, &e);
        pt_alloc_fail_at(0);
        if (st == PT_OK) {
            ok = 1;
            CHECK(t && t->num_triangles == 1);
            pt_scene_free(t);
        } else {
            CHECKF(st == PT_ERR_NOMEM, "fail at %llu: %d %s", (unsigned long long)i, (int)st,
                   e.msg);
            CHECK(t == NULL);
        }
        CHECKF(pt_alloc_live() == live, "fail at %llu leaked %lld", (unsigned long long)i,
               (long long)(pt_alloc_live() - live));
    }
    CHECK(ok);
}

/* A one-triangle .gltf whose material's base colour is image img_uri. */
static void make_textured(const char *name, const char *bin_uri, const char *img_uri)
{
    char tail[1024];
    snprintf(tail, sizeof tail,
             "\"textures\":[{\"source\":0}],\"images\":[{\"uri\":\"%s\"}],"
             "\"materials\":[{\"pbrMetallicRoughness\":{\"baseColorTexture\":{\"index\":0}}}]",
             img_uri);
    make_gltf_tail(name, bin_uri, k_pos_ok, k_views, k_nodes_ok, tail);
}

/* The secret outside the scene's folder: 70 bytes, so a scene that names it
 * as its 68-byte buffer would be told the size if it were opened. */
static const char k_secret[] =
    "PTFARM-SECRET-0123456789-PTFARM-SECRET-0123456789-PTFARM-SECRET-01234\n";

/* Loads confine/<name>, expecting PT_ERR_FORMAT with `word` in the message,
 * and a message that holds neither the secret's bytes nor its size, and no
 * path of this machine beyond the scene's own (which a caller strips). */
static void expect_confined(const char *name, const char *word, int uri_is_path)
{
    char rel[128];
    snprintf(rel, sizeof rel, "confine/%s", name);
    pt_error err = {0};
    pt_scene *s = NULL;
    pt_scene_opts o = {0};
    warnings w = {0};
    o.warn = collect;
    o.warn_user = &w;
    int64_t live = pt_alloc_live();
    pt_status st = pt_scene_load(tpath(rel), &o, &s, &err);
    if (getenv("PT_TEST_VERBOSE"))
        printf("%s -> %s\n", rel, err.msg);
    CHECKF(st == PT_ERR_FORMAT && s == NULL, "%s: status %d (%s)", rel, (int)st, err.msg);
    const char *msg = err.msg;
    if (strncmp(msg, tpath(rel), strlen(tpath(rel))) == 0)
        msg += strlen(tpath(rel));
    CHECKF(strstr(msg, word) != NULL, "%s: message lacks '%s': %s", rel, word, err.msg);
    CHECKF(strstr(msg, "PTFARM") == NULL, "%s: message shows the secret: %s", rel, err.msg);
    CHECKF(strstr(msg, "70") == NULL, "%s: message shows the secret's size: %s", rel, err.msg);
    CHECKF(uri_is_path || strstr(msg, tmp) == NULL, "%s: message shows a path: %s", rel, err.msg);
    CHECKF(strstr(w.text, "PTFARM") == NULL, "%s: warning shows the secret: %s", rel, w.text);
    CHECKF(pt_alloc_live() == live, "%s: leaked", rel);
    pt_scene_free(s);
}

/* Every external file is read from below the scene's folder, or not at all:
 * no "..", no absolute path, no link, nothing but a regular file. */
static void test_confined(void)
{
    char p[512], target[512];
    snprintf(p, sizeof p, "%s/confine/sub", tmp);
    CHECK(pt_mkdirs(p, 0, NULL) == PT_OK);
    write_file("secret.txt", k_secret, strlen(k_secret));
    CHECK(strlen(k_secret) == 70);
    unsigned char bin[68];
    make_bin(bin, 0.0f, 2);
    write_file("confine/tri.bin", bin, sizeof bin);
    unsigned char px[16] = {255, 0, 0, 255, 0, 255, 0, 255, 0, 0, 255, 255, 255, 255, 255, 255};
    CHECK(stbi_write_png(tpath("confine/sub/tex.png"), 2, 2, 4, px, 8) != 0);
    CHECK(symlink("../secret.txt", tpath("confine/link.bin")) == 0);
    snprintf(target, sizeof target, "%s", tmp);
    CHECK(symlink(target, tpath("confine/ldir")) == 0);
    CHECK(symlink("tex.png", tpath("confine/sub/texlink.png")) == 0); /* inside, still a link */
    CHECK(mkfifo(tpath("confine/fifo.png"), 0600) == 0);
    alarm(60); /* a FIFO opened for reading would block here */

    /* Buffers: tinygltf's reads. */
    make_gltf("confine/up.gltf", "../secret.txt", k_pos_ok, k_views, k_nodes_ok, "");
    expect_confined("up.gltf", "'../secret.txt'", 0);
    char abs_uri[512];
    snprintf(abs_uri, sizeof abs_uri, "%s/secret.txt", tmp);
    make_gltf("confine/abs.gltf", abs_uri, k_pos_ok, k_views, k_nodes_ok, "");
    expect_confined("abs.gltf", "absolute", 1);
    make_gltf("confine/deep.gltf", "sub/../../secret.txt", k_pos_ok, k_views, k_nodes_ok, "");
    expect_confined("deep.gltf", "..", 0);
    make_gltf("confine/pct.gltf", "%2e%2e/secret.txt", k_pos_ok, k_views, k_nodes_ok, "");
    expect_confined("pct.gltf", "..", 0);
    make_gltf("confine/bslash.gltf", "..%5csecret.txt", k_pos_ok, k_views, k_nodes_ok, "");
    expect_confined("bslash.gltf", "backslash", 0);
    make_gltf("confine/link.gltf", "link.bin", k_pos_ok, k_views, k_nodes_ok, "");
    expect_confined("link.gltf", "symbolic link", 0);
    make_gltf("confine/ldir.gltf", "ldir/secret.txt", k_pos_ok, k_views, k_nodes_ok, "");
    expect_confined("ldir.gltf", "symbolic link", 0);
    make_gltf("confine/dev.gltf", "/dev/zero", k_pos_ok, k_views, k_nodes_ok, "");
    expect_confined("dev.gltf", "absolute", 1);

    /* Images: the importer's own reads. */
    make_textured("confine/img_up.gltf", "tri.bin", "../secret.txt");
    expect_confined("img_up.gltf", "'../secret.txt'", 0);
    make_textured("confine/img_zero.gltf", "tri.bin", "/dev/zero");
    expect_confined("img_zero.gltf", "absolute", 1);
    make_textured("confine/img_fifo.gltf", "tri.bin", "fifo.png");
    expect_confined("img_fifo.gltf", "not a regular file", 0);
    make_textured("confine/img_link.gltf", "tri.bin", "sub/texlink.png");
    expect_confined("img_link.gltf", "symbolic link", 0);
    make_textured("confine/img_ldir.gltf", "tri.bin", "ldir/secret.txt");
    expect_confined("img_ldir.gltf", "symbolic link", 0);
    make_textured("confine/img_dir.gltf", "tri.bin", "sub");
    expect_confined("img_dir.gltf", "not a regular file", 0);
    alarm(0);

    /* What stays allowed: a nested file, "./", percent-encoding inside. */
    make_textured("confine/ok.gltf", "./tri.bin", "sub/tex%2epng");
    pt_error err = {0};
    pt_scene *s = NULL;
    CHECKF(pt_scene_load(tpath("confine/ok.gltf"), NULL, &s, &err) == PT_OK, "%s", err.msg);
    CHECK(s && s->num_triangles == 1 && s->num_textures == 1);
    pt_scene_free(s);
}

/* Packs a .glb (glTF 2.0 spec 4.4): header, JSON chunk, BIN chunk. */
static size_t make_glb(unsigned char *out, size_t cap)
{
    unsigned char bin[68];
    make_bin(bin, 0.0f, 2);
    char json[2048];
    int jl = snprintf(json, sizeof json,
                      "{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],"
                      "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":"
                      "{\"POSITION\":0},\"indices\":1}]}],\"buffers\":[{\"byteLength\":68}],%s,"
                      "\"accessors\":[%s,{\"bufferView\":1,\"componentType\":5123,\"count\":3,"
                      "\"type\":\"SCALAR\"}]}",
                      k_views, k_pos_ok);
    while (jl % 4)
        json[jl++] = ' ';
    uint32_t total = 12 + 8 + (uint32_t)jl + 8 + 68;
    if (total > cap)
        return 0;
    uint32_t h[3] = {0x46546C67u, 2, total}, jh[2] = {(uint32_t)jl, 0x4E4F534Au},
             bh[2] = {68, 0x004E4942u};
    size_t o = 0;
    memcpy(out + o, h, 12), o += 12;
    memcpy(out + o, jh, 8), o += 8;
    memcpy(out + o, json, (size_t)jl), o += (size_t)jl;
    memcpy(out + o, bh, 8), o += 8;
    memcpy(out + o, bin, 68), o += 68;
    return o;
}

/* A one-triangle scene whose second node holds KHR_lights_punctual light
 * `index` of the one-light array `light` (JSON). */
static void make_lit(const char *name, int index, const char *light)
{
    char nodes[256], extra[1024];
    snprintf(nodes, sizeof nodes,
             "[{\"mesh\":0,\"children\":[1]},{\"rotation\":[-0.7071068,0,0,0.7071068],"
             "\"translation\":[0,2,0],\"extensions\":{\"KHR_lights_punctual\":{\"light\":%d}}}]",
             index);
    snprintf(extra, sizeof extra, ",\"extensions\":{\"KHR_lights_punctual\":{\"lights\":[%s]}}",
             light);
    make_gltf(name, "tri.bin", k_pos_ok, k_views, nodes, extra);
}

/* Punctual lights: one that loads where its node puts it, and what is refused. */
static void test_lights(void)
{
    make_lit("lit.gltf", 0,
             "{\"type\":\"spot\",\"color\":[1,0.5,0.25],\"intensity\":8,\"range\":5,"
             "\"spot\":{\"innerConeAngle\":0.2,\"outerConeAngle\":0.6},\"name\":\"key\"}");
    pt_scene *s = NULL;
    pt_error err = {0};
    CHECKF(pt_scene_load(tpath("lit.gltf"), NULL, &s, &err) == PT_OK, "%s", err.msg);
    if (s) {
        CHECK(s->num_punctual == 1 && (s->features & PT_FEAT_PUNCTUAL));
        const pt_punctual *l = &s->punctual[0];
        CHECK(l->type == PT_PUNCTUAL_SPOT && !strcmp(l->name, "key"));
        CHECK(l->intensity.x == 8.0f && l->intensity.y == 4.0f && l->intensity.z == 2.0f);
        CHECK(l->range == 5.0f);
        CHECK(fabsf(l->cos_inner - cosf(0.2f)) < 1e-6f && fabsf(l->cos_outer - cosf(0.6f)) < 1e-6f);
        /* Rotated -90 deg about x: its -Z shines down -Y, from (0, 2, 0). */
        CHECK(fabsf(l->direction.y + 1.0f) < 1e-6f && fabsf(l->direction.z) < 1e-6f);
        CHECK(fabsf(l->position.y + (float)s->origin[1] - 2.0f) < 1e-6f);
    }
    pt_scene_free(s);
    make_lit("laser.gltf", 0, "{\"type\":\"laser\"}");
    expect_fail("laser.gltf", PT_ERR_FORMAT, "not point, spot or directional");
    make_lit("lightidx.gltf", 3, "{\"type\":\"point\"}");
    expect_fail("lightidx.gltf", PT_ERR_FORMAT, "light 3 out of range");
    make_lit("lightneg.gltf", 0, "{\"type\":\"point\",\"intensity\":-1}");
    expect_fail("lightneg.gltf", PT_ERR_FORMAT, "intensity");
    make_lit("lightcol.gltf", 0, "{\"type\":\"point\",\"color\":[2,0,0]}");
    expect_fail("lightcol.gltf", PT_ERR_FORMAT, "color");
    make_lit("lightcone.gltf", 0,
             "{\"type\":\"spot\",\"spot\":{\"innerConeAngle\":1,\"outerConeAngle\":0.5}}");
    expect_fail("lightcone.gltf", PT_ERR_FORMAT, "cone");
    make_lit("lightbig.gltf", 0, "{\"type\":\"point\",\"intensity\":1e38}");
    expect_fail("lightbig.gltf", PT_ERR_FORMAT, "light");
}

static void test_hostile(void)
{
    unsigned char bin[68];
    char buf[1024];

    make_gltf("nobin.gltf", "missing.bin", k_pos_ok, k_views, k_nodes_ok, "");
    expect_fail("nobin.gltf", PT_ERR_IO, "buffer");
    expect_fail("nobin.gltf", PT_ERR_IO, "missing.bin");

    make_gltf("accrange.gltf", "tri.bin",
              "{\"bufferView\":0,\"componentType\":5126,\"count\":100,\"type\":\"VEC3\"}", k_views,
              k_nodes_ok, "");
    expect_fail("accrange.gltf", PT_ERR_FORMAT, "accessor 0 (POSITION of mesh 0 primitive 0)");

    make_gltf("accoff.gltf", "tri.bin",
              "{\"bufferView\":0,\"byteOffset\":4,\"componentType\":5126,\"count\":3,"
              "\"type\":\"VEC3\"}",
              k_views, k_nodes_ok, "");
    expect_fail("accoff.gltf", PT_ERR_FORMAT, "accessor 0");

    make_gltf("huge.gltf", "tri.bin",
              "{\"bufferView\":0,\"componentType\":5126,\"count\":4000000000,\"type\":\"VEC3\"}",
              k_views, k_nodes_ok, "");
    expect_fail("huge.gltf", PT_ERR_LIMIT, "accessor 0");

    make_gltf("bvrange.gltf", "tri.bin",
              "{\"bufferView\":7,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\"}", k_views,
              k_nodes_ok, "");
    expect_fail("bvrange.gltf", PT_ERR_FORMAT, "bufferView");

    make_gltf("bvpast.gltf", "tri.bin", k_pos_ok,
              "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":40,\"byteLength\":36},"
              "{\"buffer\":0,\"byteOffset\":36,\"byteLength\":6},"
              "{\"buffer\":0,\"byteOffset\":44,\"byteLength\":24}]",
              k_nodes_ok, "");
    expect_fail("bvpast.gltf", PT_ERR_FORMAT, "bufferView 0");

    make_gltf("bvbuf.gltf", "tri.bin", k_pos_ok,
              "\"bufferViews\":[{\"buffer\":3,\"byteOffset\":0,\"byteLength\":36},"
              "{\"buffer\":0,\"byteOffset\":36,\"byteLength\":6},"
              "{\"buffer\":0,\"byteOffset\":44,\"byteLength\":24}]",
              k_nodes_ok, "");
    expect_fail("bvbuf.gltf", 0, "buffer");

    make_bin(bin, 0.0f, 9);
    write_file("badidx.bin", bin, sizeof bin);
    make_gltf("badidx.gltf", "badidx.bin", k_pos_ok, k_views, k_nodes_ok, "");
    expect_fail("badidx.gltf", PT_ERR_FORMAT, "index 9");

    make_bin(bin, NAN, 2);
    write_file("nan.bin", bin, sizeof bin);
    make_gltf("nan.gltf", "nan.bin", k_pos_ok, k_views, k_nodes_ok, "");
    expect_fail("nan.gltf", PT_ERR_FORMAT, "position");

    make_bin(bin, 1e30f, 2);
    write_file("far.bin", bin, sizeof bin);
    make_gltf("far.gltf", "far.bin", k_pos_ok, k_views, k_nodes_ok, "");
    expect_fail("far.gltf", PT_ERR_FORMAT, "position");

    /* A node scale that pushes a sane vertex past the cap. */
    make_gltf("farscale.gltf", "tri.bin", k_pos_ok, k_views, "[{\"mesh\":0,\"scale\":[1e20,1,1]}]",
              "");
    expect_fail("farscale.gltf", PT_ERR_FORMAT, "position");

    make_gltf("notri.gltf", "tri.bin", k_pos_ok, k_views, "[{}]", "");
    expect_fail("notri.gltf", PT_ERR_FORMAT, "no triangles");

    make_gltf("cycle.gltf", "tri.bin", k_pos_ok, k_views,
              "[{\"mesh\":0,\"children\":[1]},{\"children\":[0]}]", "");
    expect_fail("cycle.gltf", PT_ERR_FORMAT, "cycle");

    make_gltf("noderange.gltf", "tri.bin", k_pos_ok, k_views, "[{\"mesh\":0,\"children\":[5]}]",
              "");
    expect_fail("noderange.gltf", 0, "node");

    make_gltf("meshrange.gltf", "tri.bin", k_pos_ok, k_views, "[{\"mesh\":4}]", "");
    expect_fail("meshrange.gltf", 0, "mesh");

    /* A material uses a texture whose image does not exist. */
    snprintf(buf, sizeof buf, ",\"textures\":[{\"source\":3}],\"images\":[]");
    make_gltf("noimg.gltf", "tri.bin", k_pos_ok, k_views, k_nodes_ok, buf);
    use_texture_as_emission("noimg.gltf");
    expect_fail("noimg.gltf", PT_ERR_FORMAT, "image 3");
    /* ... and the material and texture are named. */
    {
        pt_error err = {0};
        pt_scene *s = NULL;
        pt_scene_load(tpath("noimg.gltf"), NULL, &s, &err);
        CHECKF(strstr(err.msg, "material 0 ('m0')") && strstr(err.msg, "texture 0"), "%s", err.msg);
        pt_scene_free(s);
    }

    make_gltf("badimg.gltf", "tri.bin", k_pos_ok, k_views, k_nodes_ok,
              ",\"textures\":[{\"source\":0}],\"images\":[{\"uri\":\"tri.bin\"}]");
    use_texture_as_emission("badimg.gltf");
    expect_fail("badimg.gltf", PT_ERR_FORMAT, "image 0");

    /* An image in a buffer view that lies outside its buffer, used by a material. */
    make_gltf("imgview.gltf", "tri.bin", k_pos_ok,
              "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":0,\"byteLength\":36},"
              "{\"buffer\":0,\"byteOffset\":36,\"byteLength\":6},"
              "{\"buffer\":0,\"byteOffset\":44,\"byteLength\":24},"
              "{\"buffer\":0,\"byteOffset\":60,\"byteLength\":100}]",
              k_nodes_ok,
              ",\"textures\":[{\"source\":0}],"
              "\"images\":[{\"bufferView\":3,\"mimeType\":\"image/png\"}]");
    use_texture_as_emission("imgview.gltf");
    expect_fail("imgview.gltf", PT_ERR_FORMAT, "bufferView 3");

    write_file("empty.gltf", "", 0);
    expect_fail("empty.gltf", PT_ERR_FORMAT, "empty");

    unsigned char garbage[512];
    uint32_t x = 12345;
    for (size_t i = 0; i < sizeof garbage; i++) {
        x = x * 1664525u + 1013904223u;
        garbage[i] = (unsigned char)(x >> 24);
    }
    write_file("garbage.gltf", garbage, sizeof garbage);
    expect_fail("garbage.gltf", PT_ERR_FORMAT, "JSON");
    write_file("garbage.glb", "glTF\x02\0\0\0\xff\xff\xff\xff", 12);
    expect_fail("garbage.glb", PT_ERR_FORMAT, "GLB");

    write_file("json.gltf", "{\"asset\":{\"version\":\"2.0\"},\"scenes\":\"x\"", 39);
    expect_fail("json.gltf", PT_ERR_FORMAT, "json.gltf");
    /* tinygltf says "not found" of missing JSON objects too: that is the
     * content's fault, not a file that cannot be read (found by fuzz_gltf). */
    static const char no_asset[] = "{\"scenes\":[]}";
    write_file("noasset.gltf", no_asset, sizeof no_asset - 1);
    expect_fail("noasset.gltf", PT_ERR_FORMAT, "invalid glTF JSON");
    static const char ortho[] = "{\"asset\":{\"version\":\"2.0\"},\"cameras\":[{\"type\":"
                                "\"orthographic\"}]}";
    write_file("ortho.gltf", ortho, sizeof ortho - 1);
    expect_fail("ortho.gltf", PT_ERR_FORMAT, "invalid glTF JSON");

    expect_fail("does-not-exist.gltf", PT_ERR_IO, "does-not-exist");

    /* A valid GLB, then every interesting truncation of it. */
    unsigned char glb[4096];
    size_t gl = make_glb(glb, sizeof glb);
    CHECK(gl > 0);
    write_file("ok.glb", glb, gl);
    {
        pt_error err = {0};
        pt_scene *s = NULL;
        CHECKF(pt_scene_load(tpath("ok.glb"), NULL, &s, &err) == PT_OK, "%s", err.msg);
        CHECK(s && s->num_triangles == 1 && s->uvs == NULL);
        pt_scene_free(s);
    }
    size_t cuts[] = {3, 11, 12, 19, 20, 40, gl - 80, gl - 68, gl - 30, gl - 1};
    for (size_t i = 0; i < sizeof cuts / sizeof cuts[0]; i++) {
        char name[64];
        snprintf(name, sizeof name, "cut%zu.glb", cuts[i]);
        write_file(name, glb, cuts[i]);
        expect_fail(name, PT_ERR_FORMAT, "GLB");
    }
}

/* TEXCOORD_1, TANGENT, COLOR_0 (normalized bytes), a NEAREST sampler, a
 * normal texture with its scale and a KHR_texture_transform that moves the
 * base colour to TEXCOORD_1, in a file that requires the extension, under a
 * node that mirrors x (so the tangent's x and its w flip). */
static void test_attributes(void)
{
    unsigned char bin[180];
    memset(bin, 0, sizeof bin);
    const float pos[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    const float uv0[6] = {0, 0, 1, 0, 0, 1};
    const float uv1[6] = {0.25f, 0.5f, 0.75f, 0.5f, 0.25f, 1.0f};
    const float tan[12] = {1, 0, 0, 1, 1, 0, 0, 1, 1, 0, 0, 1};
    const uint8_t col[12] = {255, 0, 0, 255, 0, 255, 0, 255, 0, 0, 255, 128};
    memcpy(bin, pos, 36);
    memcpy(bin + 36, uv0, 24);
    memcpy(bin + 60, uv1, 24);
    memcpy(bin + 84, tan, 48);
    memcpy(bin + 132, col, 12);
    /* NORMAL: without it a file's TANGENT is ignored (glTF 2.0, 3.7.2.1). */
    const float nrm[9] = {0, 0, 1, 0, 0, 1, 0, 0, 1};
    memcpy(bin + 144, nrm, 36);
    write_file("attr.bin", bin, sizeof bin);
    unsigned char px[16] = {255, 0, 0, 255, 0, 255, 0, 255, 0, 0, 255, 255, 255, 255, 255, 255};
    CHECK(stbi_write_png(tpath("attr.png"), 2, 2, 4, px, 8) != 0);
    const char *json =
        "{\"asset\":{\"version\":\"2.0\"},"
        "\"extensionsUsed\":[\"KHR_texture_transform\"],"
        "\"extensionsRequired\":[\"KHR_texture_transform\"],"
        "\"buffers\":[{\"uri\":\"attr.bin\",\"byteLength\":180}],"
        "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":0,\"byteLength\":36},"
        "{\"buffer\":0,\"byteOffset\":36,\"byteLength\":24},"
        "{\"buffer\":0,\"byteOffset\":60,\"byteLength\":24},"
        "{\"buffer\":0,\"byteOffset\":84,\"byteLength\":48},"
        "{\"buffer\":0,\"byteOffset\":132,\"byteLength\":12},"
        "{\"buffer\":0,\"byteOffset\":144,\"byteLength\":36}],"
        "\"accessors\":["
        "{\"bufferView\":0,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\","
        "\"min\":[0,0,0],\"max\":[1,1,0]},"
        "{\"bufferView\":1,\"componentType\":5126,\"count\":3,\"type\":\"VEC2\"},"
        "{\"bufferView\":2,\"componentType\":5126,\"count\":3,\"type\":\"VEC2\"},"
        "{\"bufferView\":3,\"componentType\":5126,\"count\":3,\"type\":\"VEC4\"},"
        "{\"bufferView\":4,\"componentType\":5121,\"normalized\":true,\"count\":3,"
        "\"type\":\"VEC4\"},"
        "{\"bufferView\":5,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\"}],"
        "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0,\"TEXCOORD_0\":1,"
        "\"TEXCOORD_1\":2,\"TANGENT\":3,\"COLOR_0\":4,\"NORMAL\":5},\"material\":0}]}],"
        "\"materials\":[{\"pbrMetallicRoughness\":{\"metallicFactor\":0,"
        "\"baseColorTexture\":{\"index\":0,\"extensions\":{\"KHR_texture_transform\":"
        "{\"offset\":[0.5,0],\"texCoord\":1}}}},"
        "\"normalTexture\":{\"index\":1,\"scale\":0.5}}],"
        "\"textures\":[{\"source\":0,\"sampler\":0},{\"source\":0}],"
        "\"images\":[{\"uri\":\"attr.png\"}],"
        "\"samplers\":[{\"magFilter\":9728,\"minFilter\":9728}],"
        "\"nodes\":[{\"mesh\":0,\"scale\":[-1,1,1]}],\"scenes\":[{\"nodes\":[0]}]}";
    write_file("attr.gltf", json, strlen(json));
    warnings w = {0};
    pt_scene_opts o = {0};
    o.warn = collect;
    o.warn_user = &w;
    pt_error err = {0};
    pt_scene *s = NULL;
    CHECKF(pt_scene_load(tpath("attr.gltf"), &o, &s, &err) == PT_OK, "%s", err.msg);
    CHECKF(w.count == 0, "warnings: %s", w.text);
    if (!s)
        return;
    CHECK(s->uvs1 && s->tangents && s->colors);
    CHECK((s->features & PT_FEAT_NORMAL_MAP) && (s->features & PT_FEAT_VERTEX_COLOR));
    if (s->uvs1 && s->tangents && s->colors) {
        /* The mirror flips the winding: find vertex 1 (x = -1) wherever it went. */
        for (uint32_t v = 0; v < 3; v++) {
            float x = s->positions[3 * v] + (float)s->origin[0];
            if (x < -0.5f) {
                CHECK(s->uvs1[2 * v] == 0.75f && s->uvs1[2 * v + 1] == 0.5f);
                CHECK(s->colors[4 * v] == 0.0f && s->colors[4 * v + 1] == 1.0f);
            }
            CHECKF(s->tangents[4 * v] == -1.0f && s->tangents[4 * v + 3] == -1.0f,
                   "tangent %g w %g", (double)s->tangents[4 * v], (double)s->tangents[4 * v + 3]);
        }
        int half = 0;
        for (uint32_t v = 0; v < 3; v++)
            half += fabsf(s->colors[4 * v + 3] - 128.0f / 255.0f) < 1e-6f;
        CHECK(half == 1);
    }
    const pt_material *m = &s->materials[0];
    CHECK(m->normal_tex >= 0 && m->normal_scale == 0.5f);
    CHECK(m->tex_xf[PT_SLOT_BASE].active && m->tex_xf[PT_SLOT_BASE].texcoord == 1 &&
          m->tex_xf[PT_SLOT_BASE].m[2] == 0.5f);
    CHECK(!m->tex_xf[PT_SLOT_NORMAL].active && m->tex_xf[PT_SLOT_NORMAL].texcoord == 0);
    /* The base colour (sRGB) has the NEAREST sampler; the normal texture
     * (linear, no sampler) filters. */
    CHECK(m->base_color_tex >= 0 && s->textures[m->base_color_tex].nearest == 1 &&
          s->textures[m->base_color_tex].srgb == 1);
    CHECK(s->textures[m->normal_tex].nearest == 0 && s->textures[m->normal_tex].srgb == 0);
    pt_scene_free(s);

    /* Allocation failure on the new paths (the optional attributes, the
     * tangents): PT_ERR_NOMEM and no leak, whichever allocation fails. */
    int64_t live = pt_alloc_live();
    int ok = 0;
    for (uint64_t i = 1; i < 10000 && !ok; i++) {
        pt_scene *t = NULL;
        pt_error e = {0};
        pt_alloc_fail_at(i);
        pt_status st = pt_scene_load(tpath("attr.gltf"), &o, &t, &e);
        pt_alloc_fail_at(0);
        if (st == PT_OK) {
            ok = 1;
            pt_scene_free(t);
        } else {
            CHECKF(st == PT_ERR_NOMEM, "fail at %llu: %d %s", (unsigned long long)i, (int)st,
                   e.msg);
        }
    }
    CHECK(ok);
    CHECK(pt_alloc_live() == live);
}

/* ---- the shared public assets ------------------------------------------------------ */

typedef struct asset {
    const char *path;
    uint32_t triangles;
} asset;

static const asset k_assets[] = {
    {"DamagedHelmet/DamagedHelmet.glb", 15452},
    {"EmissiveStrengthTest/EmissiveStrengthTest.glb", 90},
    {"MetalRoughSpheresNoTextures/MetalRoughSpheresNoTextures.glb", 1040409},
    {"ToyCar/ToyCar.gltf", 108936},
    {"LightsPunctualLamp/LightsPunctualLamp.gltf", 6000},
    {"StainedGlassLamp/StainedGlassLamp.gltf", 35132},
    {"TransmissionTest/TransmissionTest.glb", 128775},
    {"CornellBox/cornellBox.gltf", 16732},
    {"Cameras/Cameras.gltf", 2},
    {"SheenChair/SheenChair.gltf", 39936},
    {"TextureTransformTest/TextureTransformTest.gltf", 24},
    {"NormalTangentMirrorTest/NormalTangentMirrorTest.glb", 5240},
};

static pt_scene *load_shared(const char *rel, const char *camera, warnings *w, pt_status *st,
                             pt_error *err)
{
    char p[1024];
    snprintf(p, sizeof p, "%s/%s", PT_SHARED_SCENES, rel);
    pt_scene_opts o = {0};
    o.camera_name = camera;
    o.warn = collect;
    o.warn_user = w;
    pt_scene *s = NULL;
    *st = pt_scene_load(p, &o, &s, err);
    return s;
}

static int cmp_float(const void *a, const void *b)
{
    float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

static void check_asset(const asset *a)
{
    warnings w = {0};
    pt_error err = {0};
    pt_status st;
    pt_scene *s = load_shared(a->path, NULL, &w, &st, &err);
    CHECKF(st == PT_OK && s, "%s: %s", a->path, err.msg);
    if (!s)
        return;
    if (getenv("PT_TEST_VERBOSE"))
        printf("%s: %u triangles, features %#x, camera '%s'\n%s", a->path, s->num_triangles,
               s->features, s->camera.name, w.text);
    CHECKF(s->num_triangles == a->triangles, "%s: %u triangles, expected %u", a->path,
           s->num_triangles, a->triangles);
    CHECK(strlen(s->hash) == 64);
    CHECK(pt_isfinite3(s->bounds_min) && pt_isfinite3(s->bounds_max));
    CHECK(s->camera.yfov > 0.0f && s->camera.yfov < PT_PI);
    /* Every normal is unit length, and no index or material is out of range. */
    int bad = 0;
    for (uint32_t v = 0; v < s->num_vertices; v++) {
        const float *n = s->normals + 3 * (size_t)v;
        float l = sqrtf(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        bad += !(fabsf(l - 1.0f) < 1e-3f);
    }
    for (uint32_t t = 0; t < s->num_triangles; t++) {
        bad += s->tri_material[t] >= s->num_materials;
        for (int k = 0; k < 3; k++)
            bad += s->indices[3 * (size_t)t + k] >= s->num_vertices;
    }
    CHECKF(bad == 0, "%s: %d bad normals/indices", a->path, bad);

    if (strstr(a->path, "EmissiveStrength")) {
        float lum[16];
        int n = 0;
        for (uint32_t i = 0; i < s->num_materials && n < 16; i++) {
            const float *e = s->materials[i].emissive;
            if (e[0] > 0 || e[1] > 0 || e[2] > 0)
                lum[n++] = pt_luminance(pt_v3(e[0], e[1], e[2]));
        }
        CHECKF(n == 5, "%d emissive materials", n);
        qsort(lum, (size_t)n, sizeof lum[0], cmp_float);
        for (int i = 1; i < n; i++)
            CHECKF(fabsf(lum[i] / lum[0] - (float)(1 << i)) < 1e-3f, "ratio %d: %g", i,
                   (double)(lum[i] / lum[0]));
        CHECK(s->features & PT_FEAT_EMITTERS);
    }
    if (strstr(a->path, "Cornell")) {
        CHECKF(fabsf(s->camera.position.x) < 1e-3f && fabsf(s->camera.position.y) < 1e-3f &&
                   fabsf(s->camera.position.z - 19.99f) < 0.01f,
               "camera at %g %g %g", (double)s->camera.position.x, (double)s->camera.position.y,
               (double)s->camera.position.z);
        CHECK(fabsf(s->camera.forward.z + 1.0f) < 1e-4f);
        CHECK(fabsf(s->camera.aspect - 4.0f / 3.0f) < 1e-4f);
        CHECK(s->features & PT_FEAT_EMITTERS);
        CHECK(!(s->features & PT_FEAT_SINGLE_SIDED));
        /* The light panel is HDR: 10, not clamped. */
        int hdr = 0;
        for (uint32_t i = 0; i < s->num_materials; i++)
            hdr |= s->materials[i].emissive[0] == 10.0f;
        CHECK(hdr);
    }
    if (strstr(a->path, "MetalRough")) {
        CHECK(s->uvs == NULL && !(s->features & PT_FEAT_UVS));
        CHECK(s->features & PT_FEAT_GLOSSY);
        CHECK(!(s->features & PT_FEAT_TEXTURES));
        CHECK(s->num_cameras == 0);
    }
    if (strstr(a->path, "DamagedHelmet")) {
        CHECK(s->features & PT_FEAT_TEXTURES);
        CHECK(s->features & PT_FEAT_EMISSIVE_TEX);
        /* base colour, metal-rough, emissive, normal; AO skipped */
        CHECK(s->num_textures == 4);
        CHECK(strstr(w.text, "normal textures") == NULL);
        /* No TANGENT in the file: generated, unit and perpendicular to the normals. */
        CHECK((s->features & PT_FEAT_NORMAL_MAP) && s->tangents != NULL);
        int nbad = 0;
        for (uint32_t v = 0; s->tangents && v < s->num_vertices; v++) {
            const float *t = &s->tangents[4 * v], *n = &s->normals[3 * v];
            float len = sqrtf(t[0] * t[0] + t[1] * t[1] + t[2] * t[2]);
            nbad += fabsf(len - 1.0f) > 1e-4f ||
                    fabsf(t[0] * n[0] + t[1] * n[1] + t[2] * n[2]) > 1e-4f ||
                    !(t[3] == 1.0f || t[3] == -1.0f);
        }
        CHECKF(nbad == 0, "%d bad tangents", nbad);
    }
    if (strstr(a->path, "SheenChair")) {
        /* It requires KHR_texture_transform: loaded, its transforms kept. */
        CHECK(strstr(w.text, "KHR_texture_transform") == NULL);
        CHECK(strstr(w.text, "KHR_materials_sheen") == NULL); /* supported */
        CHECK(s->features & PT_FEAT_SHEEN);
        CHECK(s->features & PT_FEAT_NORMAL_MAP);
        int active = 0;
        for (uint32_t i = 0; i < s->num_materials; i++)
            active += s->materials[i].tex_xf[PT_SLOT_BASE].active;
        CHECK(active >= 2);
    }
    if (strstr(a->path, "TextureTransformTest")) {
        CHECK(w.count == 0);
        int active = 0;
        for (uint32_t i = 0; i < s->num_materials; i++)
            active += s->materials[i].tex_xf[PT_SLOT_BASE].active;
        CHECK(active == 6); /* offsets U, V, UV, rotation, scale, all */
    }
    if (strstr(a->path, "NormalTangentMirror")) {
        CHECK((s->features & PT_FEAT_NORMAL_MAP) && s->tangents != NULL);
        CHECK(strstr(w.text, "normal textures") == NULL);
    }
    if (strstr(a->path, "LightsPunctual")) {
        /* Its five point lights are imported, not ignored. */
        CHECK(strstr(w.text, "KHR_lights_punctual") == NULL);
        CHECK(s->num_punctual == 5 && (s->features & PT_FEAT_PUNCTUAL));
        int found = 0;
        for (uint32_t i = 0; i < s->num_punctual; i++) {
            const pt_punctual *l = &s->punctual[i];
            CHECK(l->type == PT_PUNCTUAL_POINT);
            /* "Point.004": colour (1, 0.628, 0.501) x 180, at its node's origin. */
            if (!strcmp(l->name, "Point.004")) {
                found = 1;
                CHECK(fabsf(l->intensity.x - 180.0f) < 1e-3f);
                CHECK(fabsf(l->intensity.y - 0.6278365f * 180.0f) < 1e-3f);
                CHECK(fabsf(l->position.x + (float)s->origin[0] - 0.29202104f) < 1e-5f);
                CHECK(fabsf(l->position.z + (float)s->origin[2] - 1.558916f) < 1e-5f);
                /* Down the node's -Z: the matrix turns -Z into -Y. */
                CHECK(fabsf(l->direction.y + 1.0f) < 1e-6f);
            }
        }
        CHECK(found);
        /* Its glass shade is imported (KHR_materials_transmission), not ignored;
         * its BLEND material is rendered, not warned about. */
        CHECK(strstr(w.text, "KHR_materials_transmission") == NULL);
        CHECK(s->features & PT_FEAT_TRANSMISSION);
        CHECK(strstr(w.text, "BLEND") == NULL && strstr(w.text, "alphaMode") == NULL);
        CHECK(s->features & PT_FEAT_ALPHA);
    }
    if (strstr(a->path, "ToyCar")) {
        CHECK(s->num_cameras == 8);
        CHECK(strstr(w.text, "KHR_texture_transform") == NULL); /* supported */
        /* Clearcoat and sheen are imported, not ignored. */
        CHECK(strstr(w.text, "uses KHR_materials_clearcoat") == NULL);
        CHECK(strstr(w.text, "uses KHR_materials_sheen") == NULL);
        CHECK((s->features & (PT_FEAT_CLEARCOAT | PT_FEAT_SHEEN)) ==
              (PT_FEAT_CLEARCOAT | PT_FEAT_SHEEN));
    }
    if (strstr(a->path, "Cameras")) {
        /* Its perspective and its orthographic camera (xmag = ymag = 1). */
        CHECK(strstr(w.text, "orthographic") == NULL);
        CHECK(s->num_cameras == 2);
        CHECK(fabsf(s->camera.position.z - 3.0f) < 1e-5f && !s->camera.ortho);
        if (s->num_cameras == 2) {
            const pt_camera *o = &s->cameras[1];
            CHECK(o->ortho && o->xmag == 1.0f && o->ymag == 1.0f && o->aspect == 1.0f);
            CHECK(fabsf(o->forward.z + 1.0f) < 1e-6f);
        }
    }
    /* Each warning once: no line repeats. */
    char *copy = strdup(w.text), *save = NULL;
    int dup = 0;
    for (char *line = strtok_r(copy, "\n", &save); line; line = strtok_r(NULL, "\n", &save)) {
        const char *first = strstr(w.text, line);
        dup += first && strstr(first + strlen(line), line) != NULL;
    }
    free(copy);
    CHECKF(dup == 0, "%s: repeated warnings:\n%s", a->path, w.text);
    pt_scene_free(s);
}

static void test_cameras(void)
{
    warnings w = {0};
    pt_error err = {0};
    pt_status st;
    pt_scene *all = load_shared("ToyCar/ToyCar.gltf", NULL, &w, &st, &err);
    pt_scene *s = load_shared("ToyCar/ToyCar.gltf", "Camera003", &w, &st, &err);
    CHECKF(st == PT_OK && s, "%s", err.msg);
    if (s && all) {
        CHECK(strcmp(s->camera.name, "Camera003") == 0);
        CHECK(s->camera.position.x == all->cameras[2].position.x &&
              s->camera.position.z == all->cameras[2].position.z);
        CHECK(strcmp(all->camera.name, "Camera001") == 0);
        CHECK(s->camera.aspect == 0.0f); /* aspectRatio left out: the image decides */
    }
    pt_scene_free(s);
    pt_scene_free(all);
    s = load_shared("ToyCar/ToyCar.gltf", "NoSuchCamera", &w, &st, &err);
    CHECK(st == PT_ERR_ARG && s == NULL);
    CHECKF(strstr(err.msg, "NoSuchCamera") && strstr(err.msg, "Camera008"), "%s", err.msg);
    pt_scene_free(s);
}

/* ---- decompression and instancing bombs -------------------------------------------- */

typedef struct bitbuf {
    unsigned char *p;
    size_t len, cap;
    uint32_t acc;
    int nacc;
} bitbuf;

static void put_byte(bitbuf *b, unsigned char c)
{
    if (b->len == b->cap) {
        b->cap = b->cap ? 2 * b->cap : 4096;
        b->p = realloc(b->p, b->cap);
        if (!b->p)
            exit(1);
    }
    b->p[b->len++] = c;
}

static void put_be32(bitbuf *b, uint32_t v)
{
    for (int s = 24; s >= 0; s -= 8)
        put_byte(b, (unsigned char)(v >> s));
}

/* Deflate's bit order (RFC 1951, 3.1.1): values LSB first, Huffman codes
 * MSB first. */
static void put_bits(bitbuf *b, uint32_t v, int n)
{
    for (int i = 0; i < n; i++) {
        b->acc |= ((v >> i) & 1u) << b->nacc;
        if (++b->nacc == 8) {
            put_byte(b, (unsigned char)b->acc);
            b->acc = 0;
            b->nacc = 0;
        }
    }
}

static void put_code(bitbuf *b, uint32_t code, int n)
{
    for (int i = n - 1; i >= 0; i--)
        put_bits(b, (code >> i) & 1u, 1);
}

/* A zlib stream of n zero bytes in one fixed-Huffman block (RFC 1950, 1951
 * 3.2.6): a literal 0, then matches of length 258 at distance 1 (13 bits
 * for 258 bytes), then literals, then end of block; Adler-32 of zeros is
 * (n mod 65521) << 16 | 1. */
static void put_zlib_zeros(bitbuf *b, uint64_t n)
{
    put_byte(b, 0x78);
    put_byte(b, 0x01);
    put_bits(b, 1, 1); /* BFINAL */
    put_bits(b, 1, 2); /* BTYPE 01: fixed Huffman */
    uint64_t left = n;
    if (left) {
        put_code(b, 0x30, 8); /* literal 0 */
        left--;
    }
    for (; left >= 258; left -= 258) {
        put_code(b, 0xc5, 8); /* length symbol 285: 258 */
        put_code(b, 0, 5);    /* distance code 0: 1 */
    }
    for (; left > 0; left--)
        put_code(b, 0x30, 8);
    put_code(b, 0, 7); /* end of block */
    if (b->nacc)
        put_bits(b, 0, 8 - b->nacc);
    put_be32(b, (uint32_t)((n % 65521u) << 16 | 1u));
}

static uint32_t crc32_png(const unsigned char *p, size_t n)
{
    uint32_t c = 0xffffffffu;
    for (size_t i = 0; i < n; i++) {
        c ^= p[i];
        for (int k = 0; k < 8; k++)
            c = (c >> 1) ^ (0xedb88320u & (0u - (c & 1u)));
    }
    return ~c;
}

static void put_chunk(bitbuf *b, const char *type, const unsigned char *data, size_t n)
{
    put_be32(b, (uint32_t)n);
    size_t start = b->len;
    for (int i = 0; i < 4; i++)
        put_byte(b, (unsigned char)type[i]);
    for (size_t i = 0; i < n; i++)
        put_byte(b, data[i]);
    put_be32(b, crc32_png(b->p + start, b->len - start));
}

/* The bytes a w x h 8-bit greyscale PNG's stream inflates to: a filter byte
 * and w bytes a row, or with Adam7 (PNG spec 8.2) the same for each row of
 * each of the 7 passes' subimages. */
static uint64_t png_raw(uint32_t w, uint32_t h, int interlace)
{
    if (!interlace)
        return (uint64_t)h * (w + 1u);
    static const uint32_t x0[7] = {0, 4, 0, 2, 0, 1, 0}, y0[7] = {0, 0, 4, 0, 2, 0, 1},
                          dx[7] = {8, 8, 4, 4, 2, 2, 1}, dy[7] = {8, 8, 8, 4, 4, 2, 2};
    uint64_t n = 0;
    for (int p = 0; p < 7; p++) {
        uint32_t pw = w > x0[p] ? (w - x0[p] + dx[p] - 1) / dx[p] : 0;
        uint32_t ph = h > y0[p] ? (h - y0[p] + dy[p] - 1) / dy[p] : 0;
        if (pw && ph)
            n += (uint64_t)ph * (pw + 1u);
    }
    return n;
}

/* Writes a PNG whose IHDR says w x h, 8-bit greyscale, Adam7 or not, and
 * whose IDAT inflates to `raw` zero bytes (png_raw for the whole image; 0
 * for no IDAT at all: a header alone). */
static void write_png_zeros(const char *name, uint32_t w, uint32_t h, int interlace, uint64_t raw)
{
    bitbuf b = {0};
    static const unsigned char sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
    for (int i = 0; i < 8; i++)
        put_byte(&b, sig[i]);
    unsigned char ihdr[13] = {0};
    for (int i = 0; i < 4; i++) {
        ihdr[i] = (unsigned char)(w >> (24 - 8 * i));
        ihdr[4 + i] = (unsigned char)(h >> (24 - 8 * i));
    }
    ihdr[8] = 8; /* bit depth; colour type 0 (grey), deflate, filter 0 */
    ihdr[12] = (unsigned char)interlace;
    put_chunk(&b, "IHDR", ihdr, sizeof ihdr);
    if (raw) {
        bitbuf z = {0};
        put_zlib_zeros(&z, raw);
        put_chunk(&b, "IDAT", z.p, z.len);
        free(z.p);
    }
    put_chunk(&b, "IEND", NULL, 0);
    write_file(name, b.p, b.len);
    free(b.p);
}

/* Loads `name` in a child process and reports its status and how far the
 * child's peak resident memory rose over the load, in KiB. */
static pt_status load_in_child(const char *name, long *rise_kib, char *msg, size_t msg_size)
{
    int fd[2];
    if (pipe(fd) != 0)
        return PT_ERR_IO;
    pid_t pid = fork();
    if (pid == 0) {
        close(fd[0]);
        struct rusage r0, r1;
        getrusage(RUSAGE_SELF, &r0);
        pt_error err = {0};
        pt_scene *s = NULL;
        pt_scene_opts o = {0};
        warnings w = {0};
        o.warn = collect;
        o.warn_user = &w;
        pt_status st = pt_scene_load(tpath(name), &o, &s, &err);
        getrusage(RUSAGE_SELF, &r1);
        char out[sizeof err.msg + 64];
        int n =
            snprintf(out, sizeof out, "%d %ld %s", (int)st, r1.ru_maxrss - r0.ru_maxrss, err.msg);
        if (write(fd[1], out, (size_t)n + 1) != n + 1)
            _exit(2);
        _exit(0);
    }
    close(fd[1]);
    char in[sizeof((pt_error *)0)->msg + 64] = {0};
    size_t got = 0;
    ssize_t r;
    while (got < sizeof in - 1 && (r = read(fd[0], in + got, sizeof in - 1 - got)) > 0)
        got += (size_t)r;
    close(fd[0]);
    int status = 0;
    waitpid(pid, &status, 0);
    int st = -1, off = 0;
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0 ||
        sscanf(in, "%d %ld %n", &st, rise_kib, &off) != 2)
        return (pt_status)-1;
    snprintf(msg, msg_size, "%s", in + off);
    return (pt_status)st;
}

/* A one-triangle .gltf whose materials use images img[0..n) as base colour,
 * one material each. */
static void make_textured_n(const char *name, const char *const *img, int n)
{
    char tail[4096];
    size_t k = 0;
    k += (size_t)snprintf(tail + k, sizeof tail - k, "\"textures\":[");
    for (int i = 0; i < n; i++)
        k += (size_t)snprintf(tail + k, sizeof tail - k, "%s{\"source\":%d}", i ? "," : "", i);
    k += (size_t)snprintf(tail + k, sizeof tail - k, "],\"images\":[");
    for (int i = 0; i < n; i++)
        k +=
            (size_t)snprintf(tail + k, sizeof tail - k, "%s{\"uri\":\"%s\"}", i ? "," : "", img[i]);
    k += (size_t)snprintf(tail + k, sizeof tail - k, "],\"materials\":[");
    for (int i = 0; i < n; i++)
        k += (size_t)snprintf(tail + k, sizeof tail - k,
                              "%s{\"pbrMetallicRoughness\":{\"baseColorTexture\":{\"index\":%d}}}",
                              i ? "," : "", i);
    snprintf(tail + k, sizeof tail - k, "]");
    make_gltf_tail(name, "tri.bin", k_pos_ok, k_views, k_nodes_ok, tail);
}

/* Images are refused from their headers, before anything is decoded: one
 * over PT_SCENE_MAX_IMAGE_TEXELS, or one that takes the scene's textures
 * over PT_SCENE_MAX_TEXELS; at the caps, the decoder is reached. */
static void test_image_caps(void)
{
    /* A whole 16384^2 PNG of zeros (1.7 MB): 256 MiB of grey, 1 GiB once
     * decoded to RGBA. Refused from its IHDR with no pixel allocated. */
    write_png_zeros("bomb16k.png", 16384, 16384, 0, png_raw(16384, 16384, 0));
    const char *one[] = {"bomb16k.png"};
    make_textured_n("bomb16k.gltf", one, 1);
    long rise = -1;
    char msg[512] = "";
    pt_status st = load_in_child("bomb16k.gltf", &rise, msg, sizeof msg);
    if (getenv("PT_TEST_VERBOSE"))
        printf("bomb16k.gltf -> %d, peak +%ld KiB: %s\n", (int)st, rise, msg);
    CHECKF(st == PT_ERR_LIMIT, "bomb16k.gltf: status %d (%s)", (int)st, msg);
    CHECKF(strstr(msg, "'bomb16k.png') is 16384x16384") && strstr(msg, "268435456 texels") &&
               strstr(msg, "at most 67108864 an image"),
           "bomb16k.gltf: %s", msg);
    CHECKF(rise >= 0 && rise < 64 * 1024, "bomb16k.gltf: peak memory rose by %ld KiB", rise);
    expect_fail("bomb16k.gltf", PT_ERR_LIMIT, "16384x16384");

    /* The same claim with no pixel data at all: the header alone decides. */
    write_png_zeros("hdr16k.png", 16384, 16384, 0, 0);
    write_png_zeros("wide.png", 8193, 8192, 0, 0);
    const char *hdr[] = {"hdr16k.png"}, *wide[] = {"wide.png"};
    make_textured_n("hdr16k.gltf", hdr, 1);
    expect_fail("hdr16k.gltf", PT_ERR_LIMIT, "at most 67108864 an image");
    make_textured_n("wide.gltf", wide, 1);
    expect_fail("wide.gltf", PT_ERR_LIMIT, "8193x8192, 67117056 texels");

    /* Five images of 8192^2 (the most one may have): 320 Mi texels, over
     * the scene's 256 Mi, refused before the first is decoded (none can
     * be: they are headers alone). Four are at the cap: the loader then
     * goes on to decode, and it is the missing data that fails. */
    write_png_zeros("h8k.png", 8192, 8192, 0, 0);
    const char *five[] = {"h8k.png", "h8k.png", "h8k.png", "h8k.png", "h8k.png"};
    make_textured_n("five8k.gltf", five, 5);
    expect_fail("five8k.gltf", PT_ERR_LIMIT,
                "makes 335544320 texels in the scene's textures (at most 268435456 a scene)");
    make_textured_n("four8k.gltf", five, 4);
    expect_fail("four8k.gltf", PT_ERR_FORMAT, "cannot be decoded");
    /* One image used as sRGB and as linear data is decoded, and counted,
     * twice: two textures used so make four images, at the cap; a third
     * texture makes five. */
    char tail[1024];
    snprintf(tail, sizeof tail,
             "\"textures\":[{\"source\":0},{\"source\":1}],"
             "\"images\":[{\"uri\":\"h8k.png\"},{\"uri\":\"h8k.png\"}],"
             "\"materials\":[{\"pbrMetallicRoughness\":{\"baseColorTexture\":{\"index\":0},"
             "\"metallicRoughnessTexture\":{\"index\":0}},\"emissiveTexture\":{\"index\":1},"
             "\"normalTexture\":{\"index\":1},\"emissiveFactor\":[1,1,1]}]");
    make_gltf_tail("twice8k.gltf", "tri.bin", k_pos_ok, k_views, k_nodes_ok, tail);
    expect_fail("twice8k.gltf", PT_ERR_FORMAT, "cannot be decoded");
    snprintf(tail, sizeof tail,
             "\"textures\":[{\"source\":0},{\"source\":1},{\"source\":2}],"
             "\"images\":[{\"uri\":\"h8k.png\"},{\"uri\":\"h8k.png\"},{\"uri\":\"h8k.png\"}],"
             "\"materials\":[{\"pbrMetallicRoughness\":{\"baseColorTexture\":{\"index\":0},"
             "\"metallicRoughnessTexture\":{\"index\":0}},\"emissiveTexture\":{\"index\":1},"
             "\"normalTexture\":{\"index\":1},\"emissiveFactor\":[1,1,1]},"
             "{\"pbrMetallicRoughness\":{\"baseColorTexture\":{\"index\":2}}}]");
    make_gltf_tail("thrice8k.gltf", "tri.bin", k_pos_ok, k_views, k_nodes_ok, tail);
    expect_fail("thrice8k.gltf", PT_ERR_LIMIT, "at most 268435456 a scene");

    /* Real images below the caps still load, interlaced or not. */
    for (int il = 0; il < 2; il++) {
        const char *png = il ? "small_il.png" : "small.png";
        const char *gltf = il ? "small_il.gltf" : "small.gltf";
        write_png_zeros(png, 37, 23, il, png_raw(37, 23, il));
        make_textured_n(gltf, &png, 1);
        pt_scene *s = NULL;
        pt_error err = {0};
        st = pt_scene_load(tpath(gltf), NULL, &s, &err);
        CHECKF(st == PT_OK && s->num_textures == 1 && s->textures[0].width == 37 &&
                   s->textures[0].height == 23,
               "%s: %s", gltf, err.msg);
        pt_scene_free(s);
    }
}

/* A PNG whose stream inflates past what its header's size needs is
 * refused before stb_image sees it: stb_image grows its buffer with the
 * stream, to 2 GiB, whatever the header says. */
static void test_png_stream(void)
{
    /* 1x1, with 256 MiB of zeros in its stream (1.6 MB). */
    write_png_zeros("liar.png", 1, 1, 0, 256u << 20);
    const char *liar[] = {"liar.png"};
    make_textured_n("liar.gltf", liar, 1);
    long rise = -1;
    char msg[512] = "";
    pt_status st = load_in_child("liar.gltf", &rise, msg, sizeof msg);
    if (getenv("PT_TEST_VERBOSE"))
        printf("liar.gltf -> %d, peak +%ld KiB: %s\n", (int)st, rise, msg);
    CHECKF(st == PT_ERR_FORMAT && strstr(msg, "('liar.png'): its PNG data does not inflate to "
                                              "the 1x1 its header gives"),
           "liar.gltf: status %d (%s)", (int)st, msg);
    CHECKF(rise >= 0 && rise < 64 * 1024, "liar.gltf: peak memory rose by %ld KiB", rise);
    expect_fail("liar.gltf", PT_ERR_FORMAT, "does not inflate");
    /* A little longer than its size needs, interlaced or not. */
    for (int il = 0; il < 2; il++) {
        const char *png = il ? "long_il.png" : "long.png";
        const char *gltf = il ? "long_il.gltf" : "long.gltf";
        write_png_zeros(png, 37, 23, il, png_raw(37, 23, 0) + 4 * 23 + 17);
        make_textured_n(gltf, &png, 1);
        expect_fail(gltf, PT_ERR_FORMAT, "does not inflate");
    }
}

/* A scene whose mesh 0 is one triangle repeated 1 Mi times (u8 indices:
 * 3 MiB), instanced by `big` nodes, and whose mesh 1, one triangle, is
 * instanced by `small` nodes. */
static void make_instanced(const char *name, int big, int small)
{
    static const float pos[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    const size_t nidx = 3u << 20;
    unsigned char *bin = malloc(36 + nidx);
    if (!bin)
        exit(1);
    memcpy(bin, pos, 36);
    for (size_t i = 0; i < nidx; i++)
        bin[36 + i] = (unsigned char)(i % 3);
    write_file("big.bin", bin, 36 + nidx);
    free(bin);
    char nodes[4096];
    size_t k = (size_t)snprintf(nodes, sizeof nodes, "[{\"children\":[");
    for (int i = 0; i < big + small; i++)
        k += (size_t)snprintf(nodes + k, sizeof nodes - k, "%s%d", i ? "," : "", i + 1);
    k += (size_t)snprintf(nodes + k, sizeof nodes - k, "]}");
    for (int i = 0; i < big + small; i++)
        k += (size_t)snprintf(nodes + k, sizeof nodes - k, ",{\"mesh\":%d}", i < big ? 0 : 1);
    snprintf(nodes + k, sizeof nodes - k, "]");
    char json[8192];
    snprintf(json, sizeof json,
             "{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],"
             "\"nodes\":%s,"
             "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0},\"indices\":1}]},"
             "{\"primitives\":[{\"attributes\":{\"POSITION\":0},\"indices\":2}]}],"
             "\"buffers\":[{\"uri\":\"big.bin\",\"byteLength\":%zu}],"
             "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":0,\"byteLength\":36},"
             "{\"buffer\":0,\"byteOffset\":36,\"byteLength\":%zu}],"
             "\"accessors\":[%s,"
             "{\"bufferView\":1,\"componentType\":5121,\"count\":%zu,\"type\":\"SCALAR\"},"
             "{\"bufferView\":1,\"componentType\":5121,\"count\":3,\"type\":\"SCALAR\"}]}",
             nodes, 36 + nidx, nidx, k_pos_ok, nidx);
    write_file(name, json, strlen(json));
}

/* A scene whose one mesh is one triangle over 64 Ki vertices (768 KiB),
 * instanced by `n` nodes. */
static void make_many_vertices(const char *name, int n)
{
    const uint32_t nv = 65536;
    float *pos = calloc(3u * nv + 1, sizeof *pos);
    if (!pos)
        exit(1);
    pos[3] = pos[7] = 1.0f; /* (0,0,0), (1,0,0), (0,1,0), then zeros */
    unsigned char *bin = (unsigned char *)pos;
    bin[12u * nv] = 0;
    bin[12u * nv + 1] = 1;
    bin[12u * nv + 2] = 2;
    write_file("verts.bin", bin, 12u * nv + 4);
    free(pos);
    size_t cap = 64 + 16 * (size_t)n, k = 0;
    char *nodes = malloc(cap);
    if (!nodes)
        exit(1);
    k += (size_t)snprintf(nodes + k, cap - k, "[{\"children\":[");
    for (int i = 0; i < n; i++)
        k += (size_t)snprintf(nodes + k, cap - k, "%s%d", i ? "," : "", i + 1);
    k += (size_t)snprintf(nodes + k, cap - k, "]}");
    for (int i = 0; i < n; i++)
        k += (size_t)snprintf(nodes + k, cap - k, ",{\"mesh\":0}");
    snprintf(nodes + k, cap - k, "]");
    size_t jcap = k + 2048;
    char *json = malloc(jcap);
    if (!json)
        exit(1);
    snprintf(json, jcap,
             "{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],"
             "\"nodes\":%s,"
             "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0,\"NORMAL\":0},"
             "\"indices\":1}]}],"
             "\"buffers\":[{\"uri\":\"verts.bin\",\"byteLength\":%u}],"
             "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":0,\"byteLength\":%u},"
             "{\"buffer\":0,\"byteOffset\":%u,\"byteLength\":3}],"
             "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":%u,"
             "\"type\":\"VEC3\"},"
             "{\"bufferView\":1,\"componentType\":5121,\"count\":3,\"type\":\"SCALAR\"}]}",
             nodes, 12u * nv + 4, 12u * nv, 12u * nv, nv);
    write_file(name, json, strlen(json));
    free(json);
    free(nodes);
}

/* Triangles are counted with every instance, and refused before any is built. */
static void test_instancing_caps(void)
{
    /* 16 instances of 1 Mi triangles and one of 1: one over the cap. */
    make_instanced("inst_over.gltf", 16, 1);
    expect_fail("inst_over.gltf", PT_ERR_LIMIT,
                "16777217 triangles once every instance of its meshes is counted, over the cap "
                "of 16777216");
    /* 16 Mi exactly: loads. Not in a sanitizer build: the load writes
     * gigabytes of vertices (most of this test's time, three times as long
     * under ASan), and the refusals above and below run the counts'
     * arithmetic there. */
    pt_scene *s = NULL;
    pt_error err = {0};
    pt_status st;
    if (!CHECK_SANITIZED) {
        make_instanced("inst_at.gltf", 16, 0);
        st = pt_scene_load(tpath("inst_at.gltf"), NULL, &s, &err);
        CHECKF(st == PT_OK && s->num_triangles == PT_SCENE_MAX_TRIANGLES, "inst_at.gltf: %s",
               err.msg);
        pt_scene_free(s);
    }

    /* Nodes shared by several parents multiply: 2^40 instances of one
     * triangle from 41 nodes, counted without walking them. */
    char nodes[4096];
    size_t k = (size_t)snprintf(nodes, sizeof nodes, "[");
    for (int i = 0; i < 40; i++)
        k += (size_t)snprintf(nodes + k, sizeof nodes - k, "{\"children\":[%d,%d]},", i + 1, i + 1);
    snprintf(nodes + k, sizeof nodes - k, "{\"mesh\":0}]");
    make_gltf("dag.gltf", "tri.bin", k_pos_ok, k_views, nodes, "");
    expect_fail("dag.gltf", PT_ERR_LIMIT, "1099511627776 triangles once every instance");

    /* Vertices count too, referenced or not: 769 instances of one triangle
     * over 64 Ki vertices are 50397184, over 3 x 16 Mi. (With NORMAL: a
     * primitive without it gets one vertex a corner.) */
    make_many_vertices("vtx_over.gltf", 769);
    expect_fail("vtx_over.gltf", PT_ERR_LIMIT,
                "50397184 vertices once every instance of its meshes is counted, over the cap of "
                "50331648");
    make_many_vertices("vtx_few.gltf", 3);
    s = NULL;
    st = pt_scene_load(tpath("vtx_few.gltf"), NULL, &s, &err);
    CHECKF(st == PT_OK && s->num_vertices == 3u * 65536u, "vtx_few.gltf: %s", err.msg);
    pt_scene_free(s);
}

/* The project's own scenes (scenes/): they must load, emit, and carry a camera or not. */
static void test_project_scenes(void)
{
    const char *names[2] = {"scenes/cornell_box.gltf", "scenes/furnace.gltf"};
    for (int i = 0; i < 2; i++) {
        char p[1024];
        snprintf(p, sizeof p, "%s/%s", PT_SOURCE_DIR, names[i]);
        pt_scene *s = NULL;
        pt_error err = {0};
        CHECKF(pt_scene_load(p, NULL, &s, &err) == PT_OK, "%s", err.msg);
        if (s) {
            CHECK(s->num_triangles > 0 && (s->features & PT_FEAT_EMITTERS));
            CHECK(strlen(s->hash) == 64);
        }
        pt_scene_free(s);
    }
}

/* Environment portals: a node whose extras hold "ptfarm_portal": true
 * gives its mesh's triangles as portals, placed by its node, and no
 * geometry; false (or no such key) leaves it geometry. */
static void test_portals(void)
{
    unsigned char bin[68];
    make_bin(bin, 0.0f, 2);
    write_file("portal.bin", bin, sizeof bin);
    const char *flags[2] = {"true", "false"};
    for (int i = 0; i < 2; i++) {
        char nodes[256], name[32];
        snprintf(nodes, sizeof nodes,
                 "[{\"mesh\":0,\"children\":[1]},{\"mesh\":0,\"translation\":[0,0,3],"
                 "\"name\":\"window\",\"extras\":{\"ptfarm_portal\":%s}}]",
                 flags[i]);
        snprintf(name, sizeof name, "portal_%d.gltf", i);
        make_gltf(name, "portal.bin", k_pos_ok, k_views, nodes, "");
        pt_scene *s = NULL;
        pt_error err = {0};
        CHECKF(pt_scene_load(tpath(name), NULL, &s, &err) == PT_OK, "%s", err.msg);
        if (!s)
            continue;
        if (i == 0) {
            CHECKF(s->num_triangles == 1 && s->num_portals == 1 && (s->features & PT_FEAT_PORTAL),
                   "a portal node: %u triangles, %u portals", s->num_triangles, s->num_portals);
            /* its corners (0,0,0), (1,0,0), (0,1,0) moved to z = 3 */
            const float want[9] = {0, 0, 3, 1, 0, 3, 0, 1, 3};
            for (int k = 0; s->num_portals == 1 && k < 9; k++)
                CHECKF(fabs(s->portals[k] + s->origin[k % 3] - want[k]) < 1e-6,
                       "portal corner %d: %g", k, s->portals[k] + s->origin[k % 3]);
        } else {
            CHECKF(s->num_triangles == 2 && s->num_portals == 0 && !(s->features & PT_FEAT_PORTAL),
                   "\"ptfarm_portal\": false: %u triangles, %u portals", s->num_triangles,
                   s->num_portals);
        }
        pt_scene_free(s);
    }
    /* 65 portal nodes of one triangle each: past the limit, refused with
     * the node's name and nothing leaked; a portal of NaN corners too. */
    char nodes[8192];
    int at = snprintf(nodes, sizeof nodes, "[{\"mesh\":0,\"children\":[");
    for (int i = 1; i <= 65; i++)
        at += snprintf(nodes + at, sizeof nodes - (size_t)at, "%s%d", i > 1 ? "," : "", i);
    at += snprintf(nodes + at, sizeof nodes - (size_t)at, "]}");
    for (int i = 1; i <= 65; i++)
        at += snprintf(nodes + at, sizeof nodes - (size_t)at,
                       ",{\"mesh\":0,\"name\":\"w%d\",\"translation\":[0,0,%d],"
                       "\"extras\":{\"ptfarm_portal\":true}}",
                       i, i);
    snprintf(nodes + at, sizeof nodes - (size_t)at, "]");
    make_gltf("portal_many.gltf", "portal.bin", k_pos_ok, k_views, nodes, "");
    expect_fail("portal_many.gltf", PT_ERR_LIMIT, "more than 64 portal triangles");
    make_gltf("portal_nan.gltf", "portal.bin", k_pos_ok, k_views,
              "[{\"mesh\":0,\"children\":[1]},{\"mesh\":0,\"name\":\"bad\","
              "\"scale\":[1e300,1e300,1e300],\"extras\":{\"ptfarm_portal\":true}}]",
              "");
    expect_fail("portal_nan.gltf", 0, "portal 'bad'");
    /* A node that mirrors makes its front face clockwise (glTF 3.7.4): the
     * triangle (0,0,0), (1,0,0), (0,1,0) faces +z, and under scale
     * (1, 1, -1) its corners stay where they are but it faces -z. */
    const char *scales[2] = {"1,1,1", "1,1,-1"};
    for (int i = 0; i < 2; i++) {
        char mirrored[256];
        snprintf(mirrored, sizeof mirrored,
                 "[{\"mesh\":0,\"children\":[1]},{\"mesh\":0,\"scale\":[%s],"
                 "\"extras\":{\"ptfarm_portal\":true}}]",
                 scales[i]);
        make_gltf("portal_mirror.gltf", "portal.bin", k_pos_ok, k_views, mirrored, "");
        pt_scene *s = NULL;
        pt_error err = {0};
        CHECKF(pt_scene_load(tpath("portal_mirror.gltf"), NULL, &s, &err) == PT_OK, "%s", err.msg);
        if (s && s->num_portals == 1) {
            const float *f = s->portal_fronts;
            float want = i ? -1.0f : 1.0f;
            CHECKF(f[0] == 0.0f && f[1] == 0.0f && f[2] == want,
                   "scale %s: portal front (%g, %g, %g), want (0, 0, %g)", scales[i], f[0], f[1],
                   f[2], want);
        } else {
            CHECKF(0, "scale %s: %u portals", scales[i], s ? s->num_portals : 0);
        }
        pt_scene_free(s);
    }
}

/* alphaMode and alphaCutoff: read into the material (cutoff default 0.5),
 * PT_FEAT_ALPHA only when a material is MASK or BLEND, no warning; an
 * unknown mode or a negative cutoff is refused naming the field. */
static void test_alpha_modes(void)
{
    unsigned char bin[68];
    make_bin(bin, 0.0f, 2);
    write_file("alpha.bin", bin, sizeof bin);
    const struct {
        const char *name, *fields;
        int mode;
        float cutoff;
    } ok[] = {
        {"a_opaque.gltf", "\"alphaMode\":\"OPAQUE\",\"alphaCutoff\":0.9", PT_ALPHA_OPAQUE, 0.9f},
        {"a_mask.gltf", "\"alphaMode\":\"MASK\",\"alphaCutoff\":0.25", PT_ALPHA_MASK, 0.25f},
        {"a_mask_default.gltf", "\"alphaMode\":\"MASK\"", PT_ALPHA_MASK, 0.5f},
        {"a_blend.gltf", "\"alphaMode\":\"BLEND\"", PT_ALPHA_BLEND, 0.5f}};
    char tail[512];
    for (size_t i = 0; i < sizeof ok / sizeof ok[0]; i++) {
        snprintf(tail, sizeof tail, "\"materials\":[{\"name\":\"m0\",%s}]", ok[i].fields);
        make_gltf_tail(ok[i].name, "alpha.bin", k_pos_ok, k_views, k_nodes_ok, tail);
        pt_scene_opts o = {0};
        warnings w = {0};
        o.warn = collect;
        o.warn_user = &w;
        pt_error err = {0};
        pt_scene *s = NULL;
        CHECKF(pt_scene_load(tpath(ok[i].name), &o, &s, &err) == PT_OK, "%s", err.msg);
        if (!s)
            continue;
        CHECK(s->num_materials == 1 && s->materials[0].alpha_mode == ok[i].mode);
        CHECK(s->materials[0].alpha_cutoff == ok[i].cutoff);
        CHECK(!(s->features & PT_FEAT_ALPHA) == (ok[i].mode == PT_ALPHA_OPAQUE));
        CHECKF(strstr(w.text, "alpha") == NULL, "%s: %s", ok[i].name, w.text);
        pt_scene_free(s);
    }
    make_gltf_tail("a_bad_mode.gltf", "alpha.bin", k_pos_ok, k_views, k_nodes_ok,
                   "\"materials\":[{\"name\":\"m0\",\"alphaMode\":\"CLIP\"}]");
    expect_fail("a_bad_mode.gltf", PT_ERR_FORMAT, "alphaMode 'CLIP'");
    make_gltf_tail("a_bad_cutoff.gltf", "alpha.bin", k_pos_ok, k_views, k_nodes_ok,
                   "\"materials\":[{\"name\":\"m0\",\"alphaMode\":\"MASK\","
                   "\"alphaCutoff\":-0.5}]");
    expect_fail("a_bad_cutoff.gltf", PT_ERR_FORMAT, "alphaCutoff");
}

/* tri.gltf (test_small_valid's) with "extras" nested depth deep in front,
 * as .gltf or as a .glb whose JSON chunk it is; then the JSON with a
 * string full of brackets instead. */
static void write_deep(const char *name, unsigned depth, int glb, int in_string)
{
    FILE *f = fopen(tpath("tri.gltf"), "rb");
    char base[8192];
    size_t bn = f ? fread(base, 1, sizeof base, f) : 0;
    if (f)
        fclose(f);
    size_t cap = 2 * (size_t)depth + bn + 64, n = 0;
    char *j = malloc(cap);
    n += (size_t)snprintf(j, cap, "{\"extras\":%s", in_string ? "\"" : "");
    for (unsigned i = 0; i < depth; i++)
        j[n++] = '[';
    for (unsigned i = 0; i < depth; i++)
        j[n++] = in_string ? '{' : ']';
    n += (size_t)snprintf(j + n, cap - n, "%s,", in_string ? "\"" : "");
    memcpy(j + n, base + 1, bn - 1); /* tri.gltf without its opening brace */
    n += bn - 1;
    if (!glb) {
        write_file(name, j, n);
        free(j);
        return;
    }
    while (n % 4)
        j[n++] = ' ';
    size_t total = 20 + n;
    unsigned char *g = malloc(total);
    uint32_t head[5] = {0x46546C67u, 2, (uint32_t)total, (uint32_t)n, 0x4E4F534Au};
    memcpy(g, head, sizeof head); /* little-endian hosts only, as the project */
    memcpy(g + 20, j, n);
    write_file(name, g, total);
    free(g);
    free(j);
}

/* JSON nested deeper than PT_JSON_MAX_DEPTH is refused before tinygltf's
 * recursive conversion sees it (30,000 deep overflowed the stack), in .gltf
 * and .glb, by the loader and by the bundle's dependency scan; up to the
 * bound, and brackets inside strings, load. */
static void test_deep_json(void)
{
    write_deep("deep.gltf", 30000, 0, 0);
    expect_fail("deep.gltf", PT_ERR_LIMIT, "more than 128 deep");
    write_deep("deep.glb", 30000, 1, 0);
    expect_fail("deep.glb", PT_ERR_LIMIT, "JSON chunk nests");
    char **deps = NULL;
    uint32_t ndeps = 0;
    pt_error err = {0};
    CHECK(pt_gltf_dependencies(tpath("deep.gltf"), &deps, &ndeps, &err) == PT_ERR_LIMIT &&
          strstr(err.msg, "128 deep"));
    CHECK(pt_gltf_dependencies(tpath("deep.glb"), &deps, &ndeps, &err) == PT_ERR_LIMIT);

    /* The root object and "extras" take two levels: 126 more is the bound. */
    const char *ok[] = {"edge.gltf", "edge.glb", "strings.gltf"};
    write_deep(ok[0], PT_JSON_MAX_DEPTH - 1, 0, 0);
    write_deep(ok[1], PT_JSON_MAX_DEPTH - 1, 1, 0);
    write_deep(ok[2], 30000, 0, 1);
    for (int i = 0; i < 3; i++) {
        pt_scene *sc = NULL;
        pt_scene_opts o = {0};
        pt_status st = pt_scene_load(tpath(ok[i]), &o, &sc, &err);
        CHECKF(st == PT_OK, "%s: %s", ok[i], err.msg);
        pt_scene_free(sc);
        st = pt_gltf_dependencies(tpath(ok[i]), &deps, &ndeps, &err);
        CHECKF(st == PT_OK && ndeps >= 1, "%s: %s", ok[i], err.msg);
        if (st == PT_OK)
            pt_gltf_dependencies_free(deps, ndeps);
    }
    write_deep("over.gltf", PT_JSON_MAX_DEPTH, 0, 0);
    expect_fail("over.gltf", PT_ERR_LIMIT, "deep");
}

int main(void)
{
    snprintf(tmp, sizeof tmp, "/tmp/pt_test_gltf_XXXXXX");
    if (!mkdtemp(tmp))
        return 1;
    test_small_valid();
    test_attributes();
    test_hostile();
    test_deep_json();
    test_image_caps();
    test_png_stream();
    test_instancing_caps();
    test_lights();
    test_portals();
    test_confined();
    test_alpha_modes();
    test_project_scenes();

    struct stat sb;
    if (stat(PT_SHARED_SCENES, &sb) != 0) {
        if (check_shared_required()) {
            CHECKF(0, "shared scenes missing at %s", PT_SHARED_SCENES);
        } else {
            CHECK_SKIP("shared assets: %s not found", PT_SHARED_SCENES);
        }
    } else {
        for (size_t i = 0; i < sizeof k_assets / sizeof k_assets[0]; i++)
            check_asset(&k_assets[i]);
        test_cameras();
    }
    if (pt_remove_tree(tmp) != 0)
        fprintf(stderr, "could not remove %s\n", tmp);
    return check_report();
}
