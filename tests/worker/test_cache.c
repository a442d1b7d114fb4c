/*
 * test_cache.c - the worker's scene caches.
 *
 * On disk: store, lookup, re-unpacking a missing folder, refusing bytes that
 * do not match their hash, detecting and removing a corrupt or truncated
 * bundle, and removing the temporaries of a dead process but not a live one.
 * In memory: two threads asking for the same (scene, params) at once build it
 * once and share it; failures reach every waiter; unused entries are evicted
 * down to the limit; nothing leaks. A bundle whose scene names a file outside
 * it is refused when the scene is built.
 */
#include <dirent.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/base/hash.h"
#include "common/render/render.h"
#include "common/scene/bundle.h"
#include "tests/check.h"
#include "worker/cache.h"

static char tmp[256];
static char cache_dir[512];
static const char *SCENE = PT_SOURCE_DIR "/scenes/cornell_box.gltf";

static int exists(const char *path)
{
    struct stat sb;
    return stat(path, &sb) == 0;
}

static void hex_to_hash(const char *hex, uint8_t hash[32])
{
    for (int i = 0; i < 32; i++) {
        unsigned v;
        sscanf(hex + 2 * i, "%2x", &v);
        hash[i] = (uint8_t)v;
    }
}

static int count_temps(void)
{
    DIR *d = opendir(cache_dir);
    int n = 0;
    struct dirent *e;
    while (d && (e = readdir(d)) != NULL)
        n += strncmp(e->d_name, ".tmp-", 5) == 0;
    if (d)
        closedir(d);
    return n;
}

static void flip_byte(const char *path, long at)
{
    FILE *f = fopen(path, "r+b");
    fseek(f, at, SEEK_SET);
    int c = fgetc(f);
    fseek(f, at, SEEK_SET);
    fputc(c ^ 0x5a, f);
    fclose(f);
}

static void test_disk(const pt_bundle *b, const uint8_t hash[32])
{
    pt_error err = {0};
    wrk_cache *c = NULL;
    char entry[4096], entry2[4096], bundle_path[1024], scene_dir[1024];
    snprintf(bundle_path, sizeof bundle_path, "%s/%s.bundle", cache_dir, b->hash);
    snprintf(scene_dir, sizeof scene_dir, "%s/%s", cache_dir, b->hash);

    CHECK(wrk_cache_open(cache_dir, &c, &err) == PT_OK);
    if (!c)
        return;
    CHECK(exists(cache_dir));
    CHECK(wrk_cache_lookup(c, hash, entry, sizeof entry, &err) == PT_AGAIN);

    /* Bytes that do not hash to the name are refused, nothing written. */
    uint8_t wrong[32];
    memcpy(wrong, hash, 32);
    wrong[0] ^= 1;
    CHECK(wrk_cache_store(c, wrong, b->data, b->size, entry, sizeof entry, &err) == PT_ERR_FORMAT);
    CHECK(wrk_cache_lookup(c, wrong, entry, sizeof entry, &err) == PT_AGAIN);
    /* Garbage whose hash matches is refused by the layout check. */
    const char garbage[] = "not a bundle at all";
    char ghex[65];
    uint8_t ghash[32];
    pt_sha256_hex((const uint8_t *)garbage, sizeof garbage, ghex);
    hex_to_hash(ghex, ghash);
    CHECK(wrk_cache_store(c, ghash, (const uint8_t *)garbage, sizeof garbage, entry, sizeof entry,
                          &err) == PT_ERR_FORMAT);
    CHECK(count_temps() == 0);

    /* Store, then find it again. */
    CHECK(wrk_cache_store(c, hash, b->data, b->size, entry, sizeof entry, &err) == PT_OK);
    CHECK(exists(bundle_path) && exists(scene_dir) && exists(entry));
    CHECK(strncmp(entry, scene_dir, strlen(scene_dir)) == 0);
    CHECK(strstr(entry, "cornell_box.gltf") != NULL);
    CHECK(count_temps() == 0);
    CHECK(wrk_cache_lookup(c, hash, entry2, sizeof entry2, &err) == PT_OK);
    CHECK(strcmp(entry, entry2) == 0);
    /* Storing again (a second fetch racing the first) is harmless. */
    CHECK(wrk_cache_store(c, hash, b->data, b->size, entry2, sizeof entry2, &err) == PT_OK);
    CHECK(strcmp(entry, entry2) == 0 && count_temps() == 0);
    /* A small entry buffer is refused, not overrun. */
    char small[8];
    CHECK(wrk_cache_lookup(c, hash, small, sizeof small, &err) == PT_ERR_LIMIT);

    /* The folder gone (or emptied): unpacked again from the bundle. */
    CHECK(pt_remove_tree(scene_dir) == 0 && !exists(scene_dir));
    CHECK(wrk_cache_lookup(c, hash, entry2, sizeof entry2, &err) == PT_OK);
    CHECK(exists(entry2) && strcmp(entry, entry2) == 0);
    CHECK(unlink(entry2) == 0);
    CHECK(wrk_cache_lookup(c, hash, entry2, sizeof entry2, &err) == PT_OK && exists(entry2));

    /* A corrupt bundle is detected, removed with its folder, and then missing. */
    flip_byte(bundle_path, (long)b->size / 2);
    CHECK(wrk_cache_lookup(c, hash, entry2, sizeof entry2, &err) == PT_ERR_FORMAT);
    CHECKF(strstr(err.msg, b->hash) != NULL, "message names the file: %s", err.msg);
    CHECK(!exists(bundle_path) && !exists(scene_dir));
    CHECK(wrk_cache_lookup(c, hash, entry2, sizeof entry2, &err) == PT_AGAIN);

    /* A truncated one too. */
    CHECK(wrk_cache_store(c, hash, b->data, b->size, entry, sizeof entry, &err) == PT_OK);
    CHECK(truncate(bundle_path, (off_t)b->size - 1) == 0);
    CHECK(wrk_cache_lookup(c, hash, entry2, sizeof entry2, &err) == PT_ERR_FORMAT);
    CHECK(!exists(bundle_path) && !exists(scene_dir));
    /* A folder without its bundle cannot be trusted: removed. */
    CHECK(wrk_cache_store(c, hash, b->data, b->size, entry, sizeof entry, &err) == PT_OK);
    CHECK(unlink(bundle_path) == 0);
    CHECK(wrk_cache_lookup(c, hash, entry2, sizeof entry2, &err) == PT_AGAIN);
    CHECK(!exists(scene_dir));
    CHECK(wrk_cache_store(c, hash, b->data, b->size, entry, sizeof entry, &err) == PT_OK);
    wrk_cache_close(c);

    /* Temporaries: a dead process's are removed on open, a live one's kept. */
    pid_t dead = fork();
    if (dead == 0)
        _exit(0);
    waitpid(dead, NULL, 0);
    char dead_tmp[1024], live_tmp[1024];
    snprintf(dead_tmp, sizeof dead_tmp, "%s/.tmp-%s-%ld-7.d", cache_dir, b->hash, (long)dead);
    snprintf(live_tmp, sizeof live_tmp, "%s/.tmp-%s-%ld-7.bundle", cache_dir, b->hash,
             (long)getppid());
    CHECK(mkdir(dead_tmp, 0755) == 0);
    char half[1200];
    snprintf(half, sizeof half, "%s/half.bin", dead_tmp);
    FILE *f = fopen(half, "w");
    if (f)
        fclose(f);
    f = fopen(live_tmp, "w");
    if (f)
        fclose(f);
    CHECK(wrk_cache_open(cache_dir, &c, &err) == PT_OK);
    CHECK(!exists(dead_tmp));
    CHECK(exists(live_tmp));
    unlink(live_tmp);
    /* The stored scene survived the reopen. */
    CHECK(wrk_cache_lookup(c, hash, entry2, sizeof entry2, &err) == PT_OK);
    wrk_cache_close(c);

    /* A cache folder that is a file is refused. */
    char file_dir[600];
    snprintf(file_dir, sizeof file_dir, "%s/plainfile", tmp);
    f = fopen(file_dir, "w");
    if (f)
        fclose(f);
    c = NULL;
    CHECK(wrk_cache_open(file_dir, &c, &err) != PT_OK && c == NULL);
}

/* ---- in memory ---------------------------------------------------------------------- */

typedef struct racer {
    wrk_scenes *s;
    const uint8_t *hash;
    const char *entry;
    pt_render_params params;
    pthread_barrier_t *barrier;
    wrk_scene_ref *ref;
    pt_status st;
    pt_error err;
} racer;

static void *race(void *p)
{
    racer *r = p;
    pthread_barrier_wait(r->barrier);
    r->st = wrk_scenes_acquire(r->s, r->hash, &r->params, NULL, r->entry, &r->ref, &r->err);
    return NULL;
}

/* Two threads ask for the same key at the same moment. */
static void race2(wrk_scenes *s, const uint8_t *hash, const char *entry,
                  const pt_render_params *params, racer out[2])
{
    pthread_barrier_t barrier;
    pthread_barrier_init(&barrier, NULL, 2);
    pthread_t t[2];
    for (int i = 0; i < 2; i++) {
        memset(&out[i], 0, sizeof out[i]);
        out[i].s = s;
        out[i].hash = hash;
        out[i].entry = entry;
        out[i].params = *params;
        out[i].barrier = &barrier;
        pthread_create(&t[i], NULL, race, &out[i]);
    }
    for (int i = 0; i < 2; i++)
        pthread_join(t[i], NULL);
    pthread_barrier_destroy(&barrier);
}

static void test_memory(const uint8_t hash[32], const char *entry)
{
    pt_error err = {0};
    wrk_scenes *s = NULL;
    CHECK(wrk_scenes_new(2, &s, &err) == PT_OK);
    if (!s)
        return;
    pt_render_params p;
    memset(&p, 0, sizeof p);
    p.width = 16;
    p.height = 12;
    pt_render_params_default(&p);
    p.seed = 1;

    racer r[2];
    race2(s, hash, entry, &p, r);
    CHECK(r[0].st == PT_OK && r[1].st == PT_OK);
    CHECKF(wrk_scenes_builds(s) == 1, "built %llu times", (unsigned long long)wrk_scenes_builds(s));
    CHECK(r[0].ref && r[0].ref == r[1].ref);
    if (r[0].st == PT_OK) {
        const pt_renderer *ren = wrk_scene_renderer(r[0].ref);
        CHECK(ren != NULL && pt_renderer_params(ren)->seed == 1);
        CHECK(pt_renderer_params(ren)->width == 16 && pt_renderer_params(ren)->height == 12);
        pt_pixel_acc px[4];
        pt_rect tile = {4, 4, 6, 6};
        pt_render_stats st = {0};
        pt_render_tile(ren, tile, 0, 4, px, &st);
        CHECK(st.samples + st.rejected == 16);
    }
    wrk_scenes_release(s, r[0].ref);
    wrk_scenes_release(s, r[1].ref);
    CHECK(wrk_scenes_count(s) == 1);

    /* Same key again: cached, no build. */
    wrk_scene_ref *a = NULL, *b = NULL, *c = NULL;
    uint64_t before0;
    CHECK(wrk_scenes_acquire(s, hash, &p, NULL, entry, &a, &err) == PT_OK);
    CHECK(wrk_scenes_builds(s) == 1);
    /* Other params are another entry. */
    pt_render_params p2 = p, p3 = p;
    p2.seed = 2;
    p3.max_depth = 5;
    CHECK(wrk_scenes_acquire(s, hash, &p2, NULL, entry, &b, &err) == PT_OK);
    CHECK(wrk_scenes_builds(s) == 2 && b != a);
    /* A third while both are held: over the limit until released. */
    CHECK(wrk_scenes_acquire(s, hash, &p3, NULL, entry, &c, &err) == PT_OK);
    CHECK(wrk_scenes_builds(s) == 3 && wrk_scenes_count(s) == 3);
    wrk_scenes_release(s, b); /* b is the least recently used now */
    CHECK(wrk_scenes_count(s) == 2);
    wrk_scenes_release(s, a);
    wrk_scenes_release(s, c);
    CHECK(wrk_scenes_count(s) == 2);
    /* a (p) was kept, b (p2) was evicted. */
    CHECK(wrk_scenes_acquire(s, hash, &p, NULL, entry, &a, &err) == PT_OK);
    CHECK(wrk_scenes_builds(s) == 3);
    wrk_scenes_release(s, a);
    CHECK(wrk_scenes_acquire(s, hash, &p2, NULL, entry, &b, &err) == PT_OK);
    CHECK(wrk_scenes_builds(s) == 4);
    wrk_scenes_release(s, b);

    /* The environment is part of the key: no environment (however its unused
     * fields are set) is one entry, a uniform one another, built once; a map
     * under any name but the bundle's own is refused without a file opened. */
    before0 = wrk_scenes_builds(s);
    proto_env none, zeroed, sky, stray;
    proto_env_none(&none);
    memset(&zeroed, 0, sizeof zeroed);
    sky = none;
    sky.background = 1;
    sky.rgb[0] = sky.rgb[1] = sky.rgb[2] = 0.5f;
    stray = none;
    snprintf(stray.name, sizeof stray.name, "../../etc/passwd");
    CHECK(wrk_scenes_acquire(s, hash, &p, &(wrk_scene_look){.env = &none}, entry, &a, &err) ==
          PT_OK);
    CHECK(pt_renderer_params(wrk_scene_renderer(a))->env == NULL);
    CHECK(wrk_scenes_acquire(s, hash, &p, &(wrk_scene_look){.env = &zeroed}, entry, &b, &err) ==
          PT_OK);
    CHECK(a == b && wrk_scenes_builds(s) == before0);
    wrk_scenes_release(s, b);
    CHECK(wrk_scenes_acquire(s, hash, &p, &(wrk_scene_look){.env = &sky}, entry, &b, &err) ==
          PT_OK);
    CHECK(wrk_scenes_acquire(s, hash, &p, &(wrk_scene_look){.env = &sky}, entry, &c, &err) ==
          PT_OK);
    CHECK(b == c && b != a && wrk_scenes_builds(s) == before0 + 1);
    CHECK(pt_renderer_params(wrk_scene_renderer(b))->env != NULL);
    wrk_scenes_release(s, a);
    wrk_scenes_release(s, b);
    wrk_scenes_release(s, c);
    CHECK(wrk_scenes_acquire(s, hash, &p, &(wrk_scene_look){.env = &stray}, entry, &a, &err) ==
          PT_ERR_ARG);
    CHECK(strstr(err.msg, "not the bundle's") != NULL);
    /* The material variant is in the key: the cached default entry does not
     * serve a variant, whose build fails here (the scene has none). */
    before0 = wrk_scenes_builds(s);
    CHECK(wrk_scenes_acquire(s, hash, &p, &(wrk_scene_look){.variant = "", .env = &none}, entry, &a,
                             &err) == PT_OK);
    CHECK(wrk_scenes_builds(s) == before0);
    wrk_scenes_release(s, a);
    CHECK(wrk_scenes_acquire(s, hash, &p, &(wrk_scene_look){.variant = "Velvet", .env = &none},
                             entry, &a, &err) == PT_ERR_ARG);
    CHECKF(strstr(err.msg, "no variant named 'Velvet'") && wrk_scenes_builds(s) == before0 + 1,
           "%s", err.msg);

    /* A build that fails: both racers get the error, nothing is kept, and a
     * later acquire tries again. */
    uint8_t other[32];
    memset(other, 0xab, sizeof other);
    char missing[600];
    snprintf(missing, sizeof missing, "%s/missing.gltf", tmp);
    uint64_t before = wrk_scenes_builds(s);
    uint32_t count = wrk_scenes_count(s);
    race2(s, other, missing, &p, r);
    CHECK(r[0].st != PT_OK && r[1].st != PT_OK);
    CHECK(strstr(r[0].err.msg, "missing.gltf") != NULL);
    CHECK(strstr(r[1].err.msg, "missing.gltf") != NULL);
    CHECK(wrk_scenes_builds(s) - before >= 1 && wrk_scenes_builds(s) - before <= 2);
    CHECK(wrk_scenes_count(s) == count);
    before = wrk_scenes_builds(s);
    CHECK(wrk_scenes_acquire(s, other, &p, NULL, missing, &a, &err) == PT_ERR_IO);
    CHECK(wrk_scenes_builds(s) == before + 1);
    wrk_scenes_free(s);
}

/* A one-file bundle (PTB1, bundle.h) of scene.gltf holding json. */
static uint8_t *one_file_bundle(const char *json, size_t *len)
{
    const char *name = "scene.gltf";
    size_t nl = strlen(name), jl = strlen(json), n = 8 + 2 + nl + 8 + jl;
    uint8_t *b = malloc(n);
    if (!b)
        return NULL;
    memcpy(b, "PTB1", 4);
    b[4] = 1, b[5] = b[6] = b[7] = 0;
    b[8] = (uint8_t)nl, b[9] = 0;
    memcpy(b + 10, name, nl);
    for (int i = 0; i < 8; i++)
        b[10 + nl + i] = (uint8_t)((uint64_t)jl >> (8 * i));
    memcpy(b + 18 + nl, json, jl);
    *len = n;
    return b;
}

/* A bundle from the coordinator whose scene names a file outside it: the
 * worker's load refuses it, without reading the file. The file outside is a
 * valid triangle buffer, so a load that opened it would succeed. */
static void test_outside(void)
{
    float pos[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    uint16_t idx[3] = {0, 1, 2};
    uint8_t bin[44] = {0};
    memcpy(bin, pos, 36);
    memcpy(bin + 36, idx, 6);
    char secret[600];
    snprintf(secret, sizeof secret, "%s/outside.bin", tmp);
    CHECK(pt_write_file_atomic(secret, bin, sizeof bin, NULL) == PT_OK);
    const char *ups = "../../../../../../../../../../../../../../../..";
    for (int k = 0; k < 2; k++) {
        char uri[1200], json[4096];
        snprintf(uri, sizeof uri, "%s%s", k == 0 ? ups : "", secret);
        snprintf(json, sizeof json,
                 "{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],"
                 "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":"
                 "{\"POSITION\":0},\"indices\":1}]}],"
                 "\"buffers\":[{\"uri\":\"%s\",\"byteLength\":44}],\"bufferViews\":["
                 "{\"buffer\":0,\"byteOffset\":0,\"byteLength\":36},"
                 "{\"buffer\":0,\"byteOffset\":36,\"byteLength\":6}],\"accessors\":["
                 "{\"bufferView\":0,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\"},"
                 "{\"bufferView\":1,\"componentType\":5123,\"count\":3,\"type\":\"SCALAR\"}]}",
                 uri);
        size_t len = 0;
        uint8_t *data = one_file_bundle(json, &len);
        CHECK(data != NULL);
        if (!data)
            return;
        char hex[65], entry[4096];
        uint8_t hash[32];
        pt_sha256_hex(data, len, hex);
        hex_to_hash(hex, hash);
        wrk_cache *c = NULL;
        pt_error err = {0};
        CHECK(wrk_cache_open(cache_dir, &c, &err) == PT_OK);
        CHECKF(c && wrk_cache_store(c, hash, data, len, entry, sizeof entry, &err) == PT_OK, "%s",
               err.msg);
        wrk_cache_close(c);
        free(data);
        wrk_scenes *s = NULL;
        CHECK(wrk_scenes_new(2, &s, &err) == PT_OK);
        pt_render_params p;
        memset(&p, 0, sizeof p);
        p.width = 16;
        p.height = 12;
        pt_render_params_default(&p);
        wrk_scene_ref *r = NULL;
        pt_status st = s ? wrk_scenes_acquire(s, hash, &p, NULL, entry, &r, &err) : PT_ERR_ARG;
        CHECKF(st == PT_ERR_FORMAT && r == NULL, "%s: status %d (%s)", uri, (int)st, err.msg);
        CHECKF(strstr(err.msg, k == 0 ? "leads out" : "absolute"), "%s", err.msg);
        wrk_scenes_release(s, r);
        wrk_scenes_free(s);
    }
}

int main(void)
{
    const char *t = getenv("TMPDIR");
    snprintf(tmp, sizeof tmp, "%s/test_cache-XXXXXX", t && *t ? t : "/tmp");
    if (!mkdtemp(tmp)) {
        perror("mkdtemp");
        return 1;
    }
    snprintf(cache_dir, sizeof cache_dir, "%s/cache/scenes", tmp);
    int64_t live = pt_alloc_live();

    pt_error err = {0};
    pt_bundle *b = NULL;
    CHECK(pt_bundle_pack(SCENE, &b, &err) == PT_OK);
    if (b) {
        uint8_t hash[32];
        hex_to_hash(b->hash, hash);
        test_disk(b, hash);
        char entry[4096];
        wrk_cache *c = NULL;
        CHECK(wrk_cache_open(cache_dir, &c, &err) == PT_OK);
        CHECK(c && wrk_cache_lookup(c, hash, entry, sizeof entry, &err) == PT_OK);
        wrk_cache_close(c);
        test_memory(hash, entry);
        test_outside();
    } else {
        fprintf(stderr, "%s\n", err.msg);
    }
    pt_bundle_free(b);
    CHECKF(pt_alloc_live() == live, "%lld blocks leaked", (long long)(pt_alloc_live() - live));

    if (pt_remove_tree(tmp) != 0)
        fprintf(stderr, "could not remove %s\n", tmp);
    return check_report();
}
