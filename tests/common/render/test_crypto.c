/*
 * test_crypto.c - Cryptomatte (common/render/crypto.h, the pass sums'
 * id lists in tile.h).
 *
 * - MurmurHash3_x86_32 against published reference values: the Cryptomatte
 *   specification's manifest example ("bunny" 13851a76, "default" 42c9679f,
 *   "bunny_porcelain_mat" b24b26d4), and the hash's usual test vectors
 *   (empty input under three seeds, "test", the quick brown fox); the
 *   metadata key is 7 hex digits of the type name's id.
 * - uint32_to_float32: the exponent clamped to [1, 254], sign and mantissa
 *   kept, so no id is a NaN, an infinity or a denormal.
 * - The manifest: names with quotes and backslashes escaped, each found
 *   again by its id; malformed text refused; through an EXR header and back.
 * - The merge that keeps PT_CRYPTO_KEEP ids: any order and grouping of the
 *   same lists gives the same list (it is associative), with exact counts
 *   for the ids it keeps, even when there are more ids than it keeps.
 * - A render: two objects meeting inside a pixel, half the pixel each, and a
 *   pixel half over the background: each pixel's coverages sum to exactly 1
 *   (whole sample counts over n), each is its area's share within 5 binomial
 *   standard deviations, and the ids are the hashes of the objects' and
 *   materials' names.
 * - Instancing: a glTF whose nodes instance one mesh (EXT_mesh_gpu_instancing)
 *   gives, kept as instances, the object layers and manifest of its copies:
 *   each instance its own node's name (instanced_names).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/image/exr.h"
#include "common/render/crypto.h"
#include "common/render/env.h"
#include "common/render/film.h"
#include "common/render/passes.h"
#include "common/render/render.h"
#include "tests/check.h"
#include "tests/common/render/ortho.h"

static uint32_t bits_of(float f)
{
    uint32_t b;
    memcpy(&b, &f, sizeof b);
    return b;
}

static void hash_vectors(void)
{
    CHECK(pt_murmur3_32("", 0, 0) == 0);
    CHECK(pt_murmur3_32("", 0, 1) == 0x514e28b7u);
    CHECK(pt_murmur3_32("", 0, 0xffffffffu) == 0x81f16f39u);
    CHECK(pt_murmur3_32("test", 4, 0) == 0xba6bd213u);
    const char *fox = "The quick brown fox jumps over the lazy dog";
    CHECK(pt_murmur3_32(fox, strlen(fox), 0) == 0x2e4ff723u);
    /* The specification's manifest example: 8 hex digits of the float. */
    CHECK(bits_of(pt_crypto_float(pt_crypto_id("bunny"))) == 0x13851a76u);
    CHECK(bits_of(pt_crypto_float(pt_crypto_id("default"))) == 0x42c9679fu);
    CHECK(bits_of(pt_crypto_float(pt_crypto_id("bunny_porcelain_mat"))) == 0xb24b26d4u);
    /* The metadata key: 7 hex digits of the type name's id (the
     * specification's suggestion; its example keys are arbitrary). */
    char key[8], okey[8], hex[9];
    pt_crypto_key(PT_CRYPTO_OBJECT, okey);
    snprintf(hex, sizeof hex, "%08x", (unsigned)pt_murmur3_32("CryptoObject", 12, 0));
    CHECK(strlen(okey) == 7 && !strncmp(okey, hex, 7));
    pt_crypto_key(PT_CRYPTO_MATERIAL, key);
    CHECK(strlen(key) == 7 && strcmp(key, okey) != 0);
    /* Every tail length (1 to 3 bytes) hashes differently from its prefix. */
    CHECK(pt_murmur3_32("abc", 1, 0) != pt_murmur3_32("abc", 2, 0) &&
          pt_murmur3_32("abc", 2, 0) != pt_murmur3_32("abc", 3, 0));
}

static void float_conversion(void)
{
    /* Exponent 0 (a denormal) and 255 (Inf/NaN) clamped; others kept. */
    CHECK(bits_of(pt_crypto_float(0x00000000u)) == 0x00800000u);
    CHECK(bits_of(pt_crypto_float(0x807fffffu)) == 0x80ffffffu);
    CHECK(bits_of(pt_crypto_float(0x7f800000u)) == 0x7f000000u);
    CHECK(bits_of(pt_crypto_float(0xffc00001u)) == 0xff400001u);
    CHECK(bits_of(pt_crypto_float(0x3f800000u)) == 0x3f800000u);
    int bad = 0;
    for (uint32_t i = 0; i < 100000; i++) {
        float f = pt_crypto_float(i * 2654435761u);
        bad += !isnormal(f);
    }
    CHECK(bad == 0);
}

static void manifest(void)
{
    const char *names[] = {"bunny", "de\"fault", "back\\slash", "bunny", "tab\there"};
    char *m = NULL;
    pt_error err = {0};
    CHECK(pt_crypto_manifest(names, 5, &m, &err) == PT_OK);
    if (!m)
        return;
    CHECK(strstr(m, "\"bunny\":\"13851a76\"") != NULL);
    CHECK(strstr(m, "\"de\\\"fault\"") && strstr(m, "\"back\\\\slash\"") && strstr(m, "\\u0009"));
    /* Each name found again by its id; the duplicate written once. */
    char name[64];
    for (int i = 0; i < 5; i++)
        CHECKF(pt_crypto_manifest_find(m, pt_crypto_id(names[i]), name, sizeof name) == 1 &&
                   !strcmp(name, names[i]),
               "%s not found in %s", names[i], m);
    const char *first = strstr(m, "\"bunny\"");
    CHECK(first && !strstr(first + 1, "\"bunny\""));
    CHECK(pt_crypto_manifest_find(m, 12345, name, sizeof name) == 0);
    const char *bad[] = {
        "", "[]", "{\"a\":1}", "{\"a\":\"123\"}", "{\"a\":\"13851a76\"", "{\"a\" \"13851a76\"}"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++)
        CHECKF(pt_crypto_manifest_find(bad[i], 1, name, sizeof name) == -1, "'%s'", bad[i]);
    CHECK(pt_crypto_manifest_find("{ }", 1, name, sizeof name) == 0);

    /* Through an EXR header and back, with the other attributes. */
    pt_image *img = NULL;
    CHECK(pt_image_new(2, 2, &img, &err) == PT_OK);
    pt_exr_attr attrs[2] = {{"cryptomatte/d593dd7/manifest", m},
                            {"cryptomatte/d593dd7/name", "CryptoObject"}};
    pt_exr_meta meta = {0};
    meta.attrs = attrs;
    meta.nattrs = 2;
    char path[64];
    snprintf(path, sizeof path, "/tmp/pt_test_crypto_%d.exr", (int)getpid());
    CHECKF(pt_exr_write(path, img, &meta, &err) == PT_OK, "%s", err.msg);
    char *back = NULL;
    CHECK(pt_exr_read_attr(path, "cryptomatte/d593dd7/manifest", &back, &err) == PT_OK);
    CHECK(back && !strcmp(back, m));
    pt_free(back);
    back = NULL;
    CHECK(pt_exr_read_attr(path, "cryptomatte/d593dd7/hash", &back, &err) == PT_ERR_FORMAT &&
          !back);
    unlink(path);
    pt_image_free(img);
    pt_free(m);
}

/* A list of nid random ids (of 24 distinct) with counts, as a pixel's. */
static void random_list(uint32_t *id, uint32_t *cnt, unsigned *seed)
{
    memset(id, 0, PT_CRYPTO_KEEP * sizeof *id);
    memset(cnt, 0, PT_CRYPTO_KEEP * sizeof *cnt);
    for (int k = 0; k < 5; k++) {
        uint32_t one_id = (uint32_t)(rand_r(seed) % 24) * 0x9e3779b9u, one = 1 + rand_r(seed) % 9;
        pt_crypto_merge(id, cnt, &one_id, &one, 1);
    }
}

static void merge_associative(void)
{
    unsigned seed = 11;
    int bad = 0, truncated = 0;
    for (int trial = 0; trial < 200; trial++) {
        enum { N = 6 };
        uint32_t id[N][PT_CRYPTO_KEEP], cnt[N][PT_CRYPTO_KEEP];
        for (int i = 0; i < N; i++)
            random_list(id[i], cnt[i], &seed);
        /* In order, one by one. */
        uint32_t a_id[PT_CRYPTO_KEEP] = {0}, a_cnt[PT_CRYPTO_KEEP] = {0};
        for (int i = 0; i < N; i++)
            pt_crypto_merge(a_id, a_cnt, id[i], cnt[i], PT_CRYPTO_KEEP);
        /* Reversed, in pairs: (5+4) + ((3+2) + (1+0)). */
        uint32_t p_id[3][PT_CRYPTO_KEEP], p_cnt[3][PT_CRYPTO_KEEP];
        for (int p = 0; p < 3; p++) {
            memcpy(p_id[p], id[2 * p + 1], sizeof p_id[p]);
            memcpy(p_cnt[p], cnt[2 * p + 1], sizeof p_cnt[p]);
            pt_crypto_merge(p_id[p], p_cnt[p], id[2 * p], cnt[2 * p], PT_CRYPTO_KEEP);
        }
        pt_crypto_merge(p_id[1], p_cnt[1], p_id[0], p_cnt[0], PT_CRYPTO_KEEP);
        pt_crypto_merge(p_id[2], p_cnt[2], p_id[1], p_cnt[1], PT_CRYPTO_KEEP);
        bad += memcmp(a_id, p_id[2], sizeof a_id) != 0 || memcmp(a_cnt, p_cnt[2], sizeof a_cnt);
        bad += !pt_crypto_canonical(a_id, a_cnt, UINT32_MAX);
        /* The kept ids' counts are exact: each id's total over the lists. */
        uint32_t total_ids = 0;
        uint32_t seen[64];
        for (int i = 0; i < N; i++)
            for (int k = 0; k < PT_CRYPTO_KEEP && cnt[i][k]; k++) {
                int dup = 0;
                for (uint32_t s = 0; s < total_ids; s++)
                    dup |= seen[s] == id[i][k];
                if (!dup && total_ids < 64)
                    seen[total_ids++] = id[i][k];
            }
        truncated += total_ids > PT_CRYPTO_KEEP;
        for (int k = 0; k < PT_CRYPTO_KEEP && a_cnt[k]; k++) {
            uint32_t want = 0;
            for (int i = 0; i < N; i++)
                for (int j = 0; j < PT_CRYPTO_KEEP; j++)
                    want += cnt[i][j] && id[i][j] == a_id[k] ? cnt[i][j] : 0;
            bad += want != a_cnt[k];
        }
    }
    CHECKF(bad == 0, "%d merges depend on the order or lose counts", bad);
    CHECK(truncated > 20); /* the rule was exercised past what it keeps */
}

/* Two Lambert quads in z = 0 under an orthographic camera: "left" for x <
 * EDGE, "right" from EDGE to 2 (its own material), nothing past x = 2. */
#define W 8u
#define EDGE 0.3f
static void render_coverage(void)
{
    pt_scene_builder *b = NULL;
    pt_error err = {0};
    CHECK(pt_scene_builder_new(&b, &err) == PT_OK);
    pt_material m1 = pt_material_default(), m2 = pt_material_default();
    snprintf(m1.name, sizeof m1.name, "chalk");
    snprintf(m2.name, sizeof m2.name, "slate");
    uint32_t i1 = 0, i2 = 0;
    CHECK(pt_scene_builder_add_material(b, &m1, &i1, &err) == PT_OK);
    CHECK(pt_scene_builder_add_material(b, &m2, &i2, &err) == PT_OK);
    const float P = 100.0f, X2 = 2.5f;
    float ql[12] = {-P, -P, 0, EDGE, -P, 0, EDGE, P, 0, -P, P, 0};
    float qr[12] = {EDGE, -P, 0, X2, -P, 0, X2, P, 0, EDGE, P, 0};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pt_scene_builder_add_mesh(b, "left", ql, NULL, NULL, 4, idx, 2, NULL, i1, &err) == PT_OK);
    CHECK(pt_scene_builder_set_object(b, "right", &err) == PT_OK);
    CHECK(pt_scene_builder_add_mesh(b, "r", qr, NULL, NULL, 4, idx, 2, NULL, i2, &err) == PT_OK);
    pt_camera cam = pt_test_ortho_down(0, 0, 10, (float)W / 2);
    CHECK(pt_scene_builder_add_camera(b, &cam, &err) == PT_OK);
    pt_scene *s = NULL;
    CHECKF(pt_scene_builder_finish(b, NULL, &s, &err) == PT_OK, "%s", err.msg);
    if (!s)
        return;
    CHECK(s->num_objects == 2 && !strcmp(s->object_names[0].s, "left") &&
          !strcmp(s->object_names[1].s, "right"));
    /* The header's attributes of the scene, and through the text the state
     * folder keeps: the same attributes. */
    pt_crypto_meta cm, back;
    char *text = NULL;
    CHECK(pt_crypto_meta_init(&cm, s, &err) == PT_OK && cm.nattrs == 8);
    CHECK(pt_crypto_meta_text(&cm, &text, &err) == PT_OK);
    CHECK(text && pt_crypto_meta_from_text(&back, text, &err) == PT_OK && back.nattrs == 8);
    for (uint32_t a = 0; a < cm.nattrs && a < back.nattrs; a++)
        CHECK(!strcmp(cm.attrs[a].name, back.attrs[a].name) &&
              !strcmp(cm.attrs[a].value, back.attrs[a].value));
    char found[32];
    CHECK(pt_crypto_manifest_find(cm.manifest[PT_CRYPTO_OBJECT], pt_crypto_id("right"), found,
                                  sizeof found) == 1 &&
          !strcmp(found, "right"));
    CHECK(pt_crypto_manifest_find(cm.manifest[PT_CRYPTO_MATERIAL], pt_crypto_id("slate"), found,
                                  sizeof found) == 1);
    CHECK(!strcmp(cm.attrs[0].value, "CryptoObject") &&
          !strcmp(cm.attrs[1].value, "MurmurHash3_32") &&
          !strcmp(cm.attrs[2].value, "uint32_to_float32"));
    pt_crypto_meta_fini(&back);
    CHECK(pt_crypto_meta_from_text(&back, "{}", &err) == PT_ERR_FORMAT);
    CHECK(pt_crypto_meta_from_text(&back, "{}\n{\"a\":1}", &err) == PT_ERR_FORMAT);
    pt_free(text);
    pt_crypto_meta_fini(&cm);
    pt_env *env = NULL;
    CHECK(pt_env_uniform(pt_v3(1, 1, 1), &env, &err) == PT_OK);
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = p.height = W;
    p.seed = 5;
    p.env = env;
    p.passes = PT_PASS_CRYPTOMATTE;
    pt_renderer *r = NULL;
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    enum { SPP = 512 };
    static pt_pixel_acc acc[W * W];
    static pt_pass_acc pacc[W * W];
    const pt_rect all = {0, 0, W, W};
    pt_render_tile_passes(r, all, 0, SPP, acc, pacc, NULL, NULL);
    pt_film *film = NULL;
    pt_image *img = NULL;
    CHECK(pt_film_new(W, W, &film, &err) == PT_OK);
    CHECK(pt_film_enable_passes(film, PT_PASS_CRYPTOMATTE, &err) == PT_OK);
    CHECK(pt_image_new(W, W, &img, &err) == PT_OK);
    pt_film_add_tile_passes(film, all, acc, pacc);
    pt_film_resolve(film, img);
    const float *r0 = pt_image_find_plane(img, "CryptoObject00.R"),
                *g0 = pt_image_find_plane(img, "CryptoObject00.G"),
                *b0 = pt_image_find_plane(img, "CryptoObject00.B"),
                *a0 = pt_image_find_plane(img, "CryptoObject00.A"),
                *mr = pt_image_find_plane(img, "CryptoMaterial00.R"),
                *r1 = pt_image_find_plane(img, "CryptoObject01.R");
    CHECK(r0 && g0 && b0 && a0 && mr && r1 && pt_image_find_plane(img, "CryptoMaterial03.A"));
    if (!r0 || !g0 || !b0 || !a0 || !mr || !r1)
        return;
    float left = pt_crypto_float(pt_crypto_id("left")),
          right = pt_crypto_float(pt_crypto_id("right")),
          chalk = pt_crypto_float(pt_crypto_id("chalk")), none = pt_crypto_float(0);
    /* Column x sees world x in [x - 4, x - 3): column 4 holds EDGE (0.3 of
     * it left, 0.7 right), column 6 holds X2 = 2.5 (half right, half none). */
    const struct {
        uint32_t x;
        float first, second, frac;
    } cases[] = {{4, right, left, 0.7f}, {6, none, right, 0.5f}};
    for (int c = 0; c < 2; c++)
        for (uint32_t y = 0; y < W; y++) {
            uint32_t i = y * W + cases[c].x;
            double cov0 = g0[i], cov1 = a0[i];
            /* Whole counts over n: exactly 1 in all (float rounding of k / n). */
            CHECKF(fabs(cov0 + cov1 - 1.0) < 1e-6, "pixel %u,%u: %g + %g", cases[c].x, y, cov0,
                   cov1);
            CHECK(r1[i] == 0.0f); /* no third id */
            /* Ranked by coverage: the larger first (equal halves: the smaller id). */
            int swapped = cov0 < cov1 || (cov0 == cov1 && bits_of(r0[i]) > bits_of(b0[i]));
            CHECK(!swapped);
            float want_first = cases[c].first, want_second = cases[c].second;
            if (cov0 >= cov1 && r0[i] != want_first) {
                float t = want_first;
                want_first = want_second;
                want_second = t;
            }
            CHECKF(r0[i] == want_first && b0[i] == want_second, "pixel %u,%u ids %08x %08x",
                   cases[c].x, y, bits_of(r0[i]), bits_of(b0[i]));
            double share = r0[i] == cases[c].first ? cov0 : cov1;
            double sd = sqrt(cases[c].frac * (1.0 - cases[c].frac) / SPP);
            CHECKF(fabs(share - cases[c].frac) < 5.0 * sd, "pixel %u,%u: %.4f of %.2f", cases[c].x,
                   y, share, (double)cases[c].frac);
        }
    /* A pixel wholly on "left": one id, coverage 1, material chalk. */
    CHECK(r0[1] == left && g0[1] == 1.0f && b0[1] == 0.0f && a0[1] == 0.0f && mr[1] == chalk);
    pt_image_free(img);
    pt_film_free(film);
    pt_renderer_free(r);
    pt_env_free(env);
    pt_scene_free(s);
}

/*
 * Cryptomatte through EXT_mesh_gpu_instancing: nodes "left" and "right"
 * instance one quad mesh twice each, side by side; a third, unnamed node
 * (node 2) instances it once. Loaded as a still the mesh is one prototype
 * under five instances; loaded for animation (the camera's node has one,
 * which keeps its place) it is five copies.
 * Every pixel's object ids and coverages are the same in both, each quad
 * carries its own node's name (the prototype's first node would name all
 * five otherwise), and the object manifests are equal.
 */
static pt_scene *load_quads(const char *path, int copies)
{
    pt_scene_opts o = {0};
    o.animate = copies;
    pt_scene *s = NULL;
    pt_error err = {0};
    CHECKF(pt_scene_load(path, &o, &s, &err) == PT_OK, "%s", err.msg);
    return s;
}

enum { QW = 40, QSPP = 32 };

/* The scene's CryptoObject00 and 01 planes (R, G, B, A each) into ids. */
static void object_planes(const pt_scene *s, float *ids)
{
    pt_render_params p = {0};
    pt_render_params_default(&p);
    p.width = p.height = QW;
    p.seed = 3;
    p.passes = PT_PASS_CRYPTOMATTE;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    static pt_pixel_acc acc[QW * QW];
    static pt_pass_acc pacc[QW * QW];
    const pt_rect all = {0, 0, QW, QW};
    pt_film *film = NULL;
    pt_image *img = NULL;
    CHECK(pt_film_new(QW, QW, &film, &err) == PT_OK);
    CHECK(pt_film_enable_passes(film, PT_PASS_CRYPTOMATTE, &err) == PT_OK);
    CHECK(pt_image_new(QW, QW, &img, &err) == PT_OK);
    if (r && film && img) {
        memset(acc, 0, sizeof acc);
        memset(pacc, 0, sizeof pacc);
        pt_render_tile_passes(r, all, 0, QSPP, acc, pacc, NULL, NULL);
        pt_film_add_tile_passes(film, all, acc, pacc);
        pt_film_resolve(film, img);
        const char *names[8] = {"CryptoObject00.R", "CryptoObject00.G", "CryptoObject00.B",
                                "CryptoObject00.A", "CryptoObject01.R", "CryptoObject01.G",
                                "CryptoObject01.B", "CryptoObject01.A"};
        for (int k = 0; k < 8; k++) {
            const float *pl = pt_image_find_plane(img, names[k]);
            CHECK(pl != NULL);
            if (pl)
                memcpy(ids + (size_t)k * QW * QW, pl, sizeof(float) * QW * QW);
        }
    }
    pt_image_free(img);
    pt_film_free(film);
    pt_renderer_free(r);
}

static void instanced_names(void)
{
    char dir[] = "/tmp/ptcrypto.XXXXXX";
    if (!mkdtemp(dir)) {
        CHECK(0);
        return;
    }
    /* 4 positions, 6 indices, then 2 + 2 + 1 instance translations. */
    struct {
        float pos[12];
        uint16_t idx[6];
        float tr[15];
        float key[2], cam[6]; /* the camera's (still) animation */
    } bin = {{0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0},
             {0, 1, 2, 0, 2, 3},
             {-4.0f, 0, 0, -2.5f, 0, 0, -1.0f, 0, 0, 0.5f, 0, 0, 2.0f, 0, 0},
             {0, 1},
             {-0.5f, 0.5f, 5, -0.5f, 0.5f, 5}};
    _Static_assert(sizeof bin == 48 + 12 + 60 + 32, "packed");
    static const char json[] =
        "{\"asset\":{\"version\":\"2.0\"},\"extensionsUsed\":[\"EXT_mesh_gpu_instancing\"],"
        "\"buffers\":[{\"uri\":\"q.bin\",\"byteLength\":152}],"
        "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":0,\"byteLength\":48},"
        "{\"buffer\":0,\"byteOffset\":48,\"byteLength\":12},"
        "{\"buffer\":0,\"byteOffset\":60,\"byteLength\":60},"
        "{\"buffer\":0,\"byteOffset\":120,\"byteLength\":32}],"
        "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":4,\"type\":\"VEC3\","
        "\"min\":[0,0,0],\"max\":[1,1,0]},"
        "{\"bufferView\":1,\"componentType\":5123,\"count\":6,\"type\":\"SCALAR\"},"
        "{\"bufferView\":2,\"componentType\":5126,\"count\":2,\"type\":\"VEC3\"},"
        "{\"bufferView\":2,\"byteOffset\":24,\"componentType\":5126,\"count\":2,"
        "\"type\":\"VEC3\"},"
        "{\"bufferView\":2,\"byteOffset\":48,\"componentType\":5126,\"count\":1,"
        "\"type\":\"VEC3\"},"
        "{\"bufferView\":3,\"componentType\":5126,\"count\":2,\"type\":\"SCALAR\","
        "\"min\":[0],\"max\":[1]},"
        "{\"bufferView\":3,\"byteOffset\":8,\"componentType\":5126,\"count\":2,"
        "\"type\":\"VEC3\"}],"
        "\"animations\":[{\"channels\":[{\"sampler\":0,\"target\":{\"node\":3,"
        "\"path\":\"translation\"}}],\"samplers\":[{\"input\":5,\"output\":6}]}],"
        "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0},\"indices\":1}]}],"
        "\"cameras\":[{\"type\":\"orthographic\",\"orthographic\":{\"xmag\":3.5,"
        "\"ymag\":3.5,\"znear\":0.1,\"zfar\":100}}],"
        "\"nodes\":[{\"name\":\"left\",\"mesh\":0,\"extensions\":{\"EXT_mesh_gpu_instancing\":"
        "{\"attributes\":{\"TRANSLATION\":2}}}},"
        "{\"name\":\"right\",\"mesh\":0,\"extensions\":{\"EXT_mesh_gpu_instancing\":"
        "{\"attributes\":{\"TRANSLATION\":3}}}},"
        "{\"mesh\":0,\"extensions\":{\"EXT_mesh_gpu_instancing\":"
        "{\"attributes\":{\"TRANSLATION\":4}}}},"
        "{\"camera\":0,\"translation\":[-0.5,0.5,5]}],"
        "\"scenes\":[{\"nodes\":[0,1,2,3]}],\"scene\":0}";
    char gltf[300], qbin[300];
    snprintf(gltf, sizeof gltf, "%s/quads.gltf", dir);
    snprintf(qbin, sizeof qbin, "%s/q.bin", dir);
    FILE *f = fopen(qbin, "wb");
    CHECK(f && fwrite(&bin, sizeof bin, 1, f) == 1);
    if (f)
        fclose(f);
    f = fopen(gltf, "wb");
    CHECK(f && fwrite(json, strlen(json), 1, f) == 1);
    if (f)
        fclose(f);
    pt_scene *si = load_quads(gltf, 0), *sc = load_quads(gltf, 1);
    if (si && sc) {
        CHECK(si->num_instances == 5 && (si->features & PT_FEAT_INSTANCES));
        CHECKF(sc->num_instances == 0 && sc->num_triangles == 10, "%u instances, %u triangles",
               sc->num_instances, sc->num_triangles);
        pt_error err = {0};
        pt_crypto_meta mi, mc;
        CHECK(pt_crypto_meta_init(&mi, si, &err) == PT_OK);
        CHECK(pt_crypto_meta_init(&mc, sc, &err) == PT_OK);
        CHECKF(!strcmp(mi.manifest[PT_CRYPTO_OBJECT], mc.manifest[PT_CRYPTO_OBJECT]),
               "manifests %s and %s", mi.manifest[PT_CRYPTO_OBJECT], mc.manifest[PT_CRYPTO_OBJECT]);
        char found[32];
        CHECK(pt_crypto_manifest_find(mi.manifest[PT_CRYPTO_OBJECT], pt_crypto_id("node 2"), found,
                                      sizeof found) == 1);
        pt_crypto_meta_fini(&mi);
        pt_crypto_meta_fini(&mc);
        static float a[8 * QW * QW], b[8 * QW * QW];
        object_planes(si, a);
        object_planes(sc, b);
        int differ = 0;
        for (size_t i = 0; i < 8 * QW * QW; i++)
            differ += bits_of(a[i]) != bits_of(b[i]);
        CHECKF(differ == 0, "%d values of the object layers differ between instances and copies",
               differ);
        /* Each quad's middle (quad q spans x in [x_q, x_q + 1], y in [0, 1];
         * the view is x in [-4, 3], y in [-3, 4]): its node's name, wholly. */
        const struct {
            float x;
            const char *name;
        } quads[5] = {
            {-4.0f, "left"}, {-2.5f, "left"}, {-1.0f, "right"}, {0.5f, "right"}, {2.0f, "node 2"}};
        for (int q = 0; q < 5; q++) {
            uint32_t px = (uint32_t)((quads[q].x + 0.5f + 4.0f) / 7.0f * QW);
            uint32_t py = (uint32_t)((4.0f - 0.5f) / 7.0f * QW);
            size_t i = (size_t)py * QW + px;
            CHECKF(a[i] == pt_crypto_float(pt_crypto_id(quads[q].name)) && a[QW * QW + i] == 1.0f,
                   "quad %d: id %08x, coverage %g, want %s", q, bits_of(a[i]),
                   (double)a[QW * QW + i], quads[q].name);
        }
    }
    pt_scene_free(si);
    pt_scene_free(sc);
    unlink(gltf);
    unlink(qbin);
    rmdir(dir);
}

int main(void)
{
    hash_vectors();
    float_conversion();
    manifest();
    merge_associative();
    render_coverage();
    instanced_names();
    CHECK(pt_alloc_live() == 0);
    return check_report();
}
