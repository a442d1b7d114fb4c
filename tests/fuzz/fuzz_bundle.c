/*
 * fuzz_bundle.c - libFuzzer target for a scene bundle as the coordinator
 * verifies an upload and a worker unpacks a fetched scene
 * (common/scene/bundle.c: layout and names; then the scene inside it).
 *
 * Input: the bundle's bytes. The harness checks them (pt_bundle_check),
 * wraps them (pt_bundle_from_bytes), unpacks them into a fresh folder of its
 * scratch folder and, as server/api/upload.c does, scans the entry file's
 * dependencies and loads it as a scene. Invariants: check and wrap agree; a
 * refusal names its cause; the wrapped copy holds the input and its SHA-256;
 * a checked bundle unpacks (or fails on the file system, PT_ERR_IO, as two
 * files named "a" and "a/b" must) with its entry file inside the folder;
 * nothing is left allocated.
 */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/base/hash.h"
#include "common/scene/bundle.h"
#include "common/scene/scene.h"
#include "common/scene/uri.h"
#include "tests/fuzz/fuzz_util.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void quiet(void *user, const char *message)
{
    (void)user;
    (void)message;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char dir[600];
    snprintf(dir, sizeof dir, "%s/unpack", fuzz_dir());
    int64_t live = pt_alloc_live();
    pt_error e1 = {0}, e2 = {0};
    pt_status checked = pt_bundle_check(data, size, &e1);
    fuzz_note("check", checked, &e1);
    FUZZ_CHECK(checked == PT_OK || (checked == e1.code && e1.msg[0]));
    pt_bundle *b = NULL;
    pt_status st = pt_bundle_from_bytes(data, size, &b, &e2);
    FUZZ_CHECK(st == checked && (st != PT_OK) == (b == NULL));
    if (st != PT_OK) {
        FUZZ_CHECK(strcmp(e1.msg, e2.msg) == 0);
        FUZZ_CHECK(pt_alloc_live() == live);
        return 0;
    }
    FUZZ_CHECK(b->size == size && memcmp(b->data, data, size) == 0);
    char hex[65];
    pt_sha256_hex(data, size, hex);
    FUZZ_CHECK(strcmp(hex, b->hash) == 0);

    pt_remove_tree(dir);
    char entry[4096];
    pt_error err = {0};
    st = pt_bundle_unpack(b, dir, entry, sizeof entry, &err);
    fuzz_note("unpack", st, &err);
    FUZZ_CHECK(st == PT_OK || st == PT_ERR_IO || st == PT_ERR_LIMIT);
    FUZZ_CHECK(st == PT_OK || (st == err.code && err.msg[0]));
    if (st == PT_OK) {
        size_t dl = strlen(dir);
        FUZZ_CHECK(strncmp(entry, dir, dl) == 0 && entry[dl] == '/' && !strstr(entry, "/../"));
        char **names = NULL;
        uint32_t n = 0;
        pt_status ds = pt_gltf_dependencies(entry, &names, &n, &err);
        fuzz_note("dependencies", ds, &err);
        FUZZ_CHECK(ds == PT_OK || (ds == err.code && err.msg[0]));
        if (ds == PT_OK) {
            for (uint32_t i = 0; i < n; i++)
                FUZZ_CHECK(!pt_uri_path_refusal(names[i], strlen(names[i])));
            pt_gltf_dependencies_free(names, n);
        }
        pt_scene_opts opts = {0};
        opts.warn = quiet;
        opts.max_triangles = PT_SCENE_MAX_TRIANGLES / 64; /* as fuzz_gltf: fast loads */
        pt_scene *scene = NULL;
        pt_status ls = pt_scene_load(entry, &opts, &scene, &err);
        fuzz_note("load", ls, &err);
        FUZZ_CHECK(ls == PT_OK || (ls == err.code && err.msg[0]));
        FUZZ_CHECK((ls == PT_OK) == (scene != NULL));
        pt_scene_free(scene);
    }
    pt_remove_tree(dir);
    pt_bundle_free(b);
    FUZZ_CHECK(pt_alloc_live() == live);
    return 0;
}
