/*
 * test_variants.c - KHR_materials_variants in pt_scene_load: a hand-written
 * file with two variants (the mapped material is used, the default one
 * without a variant, an unknown name is refused listing the file's
 * variants), and SheenChair from the shared assets (each variant gives
 * different materials on its mapped primitives, and no warnings but the
 * occlusion texture's).
 */
#include "common/scene/scene.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "tests/check.h"

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

/* One triangle (data: URI), two primitives of it: the first maps material 1
 * (red) to variant "Red" and 2 (green) to "Green", default 0 (white); the
 * second has no mappings and keeps material 0 whatever the variant. */
static const char k_gltf[] =
    "{\"asset\":{\"version\":\"2.0\"},\"extensionsUsed\":[\"KHR_materials_variants\"],"
    "\"extensions\":{\"KHR_materials_variants\":{\"variants\":[{\"name\":\"Red\"},"
    "{\"name\":\"Green\"}]}},"
    "\"scenes\":[{\"nodes\":[0]}],\"nodes\":[{\"mesh\":0}],"
    "\"meshes\":[{\"primitives\":["
    "{\"attributes\":{\"POSITION\":0},\"material\":0,\"extensions\":{\"KHR_materials_variants\":"
    "{\"mappings\":[{\"material\":1,\"variants\":[0]},{\"material\":2,\"variants\":[1]}]}}},"
    "{\"attributes\":{\"POSITION\":0},\"material\":0}]}],"
    "\"materials\":["
    "{\"pbrMetallicRoughness\":{\"baseColorFactor\":[1,1,1,1],\"metallicFactor\":0}},"
    "{\"pbrMetallicRoughness\":{\"baseColorFactor\":[1,0,0,1],\"metallicFactor\":0}},"
    "{\"pbrMetallicRoughness\":{\"baseColorFactor\":[0,1,0,1],\"metallicFactor\":0}}],"
    "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\","
    "\"min\":[0,0,0],\"max\":[1,1,0]}],"
    "\"bufferViews\":[{\"buffer\":0,\"byteLength\":36}],"
    "\"buffers\":[{\"byteLength\":36,\"uri\":\"data:application/octet-stream;base64,"
    "AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA\"}]}";

static pt_scene *load(const char *path, const char *variant, warnings *w, pt_status *st,
                      pt_error *err)
{
    pt_scene_opts o = {0};
    o.variant = variant;
    o.warn = collect;
    o.warn_user = w;
    pt_scene *s = NULL;
    *st = pt_scene_load(path, &o, &s, err);
    return s;
}

/* Base colour (r, g, b) of triangle t's material. */
static int tri_color(const pt_scene *s, uint32_t t, float r, float g, float b)
{
    const float *c = s->materials[s->tri_material[t]].base_color;
    return c[0] == r && c[1] == g && c[2] == b;
}

static void test_hand_written(const char *dir)
{
    char path[512];
    snprintf(path, sizeof path, "%s/variants.gltf", dir);
    FILE *f = fopen(path, "wb");
    CHECK(f != NULL);
    if (!f)
        return;
    fwrite(k_gltf, 1, sizeof k_gltf - 1, f);
    fclose(f);

    struct {
        const char *variant;
        float r, g, b;
    } cases[] = {{NULL, 1, 1, 1}, {"Red", 1, 0, 0}, {"Green", 0, 1, 0}};
    char hash0[65] = "";
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        warnings w = {0};
        pt_error err = {0};
        pt_status st;
        pt_scene *s = load(path, cases[i].variant, &w, &st, &err);
        const char *v = cases[i].variant ? cases[i].variant : "(none)";
        CHECKF(st == PT_OK && s, "variant %s: %s", v, err.msg);
        if (!s)
            continue;
        CHECKF(w.count == 0, "variant %s: warnings: %s", v, w.text);
        CHECK(s->num_triangles == 2);
        CHECKF(tri_color(s, 0, cases[i].r, cases[i].g, cases[i].b),
               "variant %s: the mapped primitive has the wrong material", v);
        CHECKF(tri_color(s, 1, 1, 1, 1), "variant %s: the unmapped primitive changed material", v);
        /* The hash names the files, so a variant is a render setting, not a new scene. */
        if (i == 0)
            snprintf(hash0, sizeof hash0, "%s", s->hash);
        CHECK(strcmp(hash0, s->hash) == 0);
        pt_scene_free(s);
    }

    /* An unknown name is refused, naming it and listing the file's variants. */
    warnings w = {0};
    pt_error err = {0};
    pt_status st;
    int64_t live = pt_alloc_live();
    pt_scene *s = load(path, "Blue", &w, &st, &err);
    CHECKF(st == PT_ERR_ARG && !s, "unknown variant: status %d", (int)st);
    CHECKF(strstr(err.msg, "'Blue'") && strstr(err.msg, "'Red', 'Green'"), "message: %s", err.msg);
    CHECK(pt_alloc_live() == live);
    pt_scene_free(s);
    unlink(path);
}

static void test_sheen_chair(void)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/SheenChair/SheenChair.gltf", PT_SHARED_SCENES);
    if (access(path, R_OK) != 0) {
        if (check_shared_required()) {
            CHECKF(0, "shared scene missing: %s", path);
        } else {
            CHECK_SKIP("shared assets: %s not found", path);
        }
        return;
    }
    const char *names[2] = {"Mango Velvet", "Peacock Velvet"};
    pt_scene *s[2] = {NULL, NULL};
    for (int i = 0; i < 2; i++) {
        warnings w = {0};
        pt_error err = {0};
        pt_status st;
        s[i] = load(path, names[i], &w, &st, &err);
        CHECKF(st == PT_OK && s[i], "%s: %s", names[i], err.msg);
        /* Occlusion textures are a known omission; nothing else may be reported. */
        int others = 0;
        for (const char *l = w.text; *l;) {
            const char *e = strchr(l, '\n');
            size_t n = e ? (size_t)(e - l) : strlen(l);
            char line[1024];
            snprintf(line, sizeof line, "%.*s", (int)n, l);
            others += strstr(line, "occlusion textures are ignored") == NULL;
            l += n + (e != NULL);
        }
        CHECKF(others == 0, "%s: warnings: %s", names[i], w.text);
    }
    if (s[0] && s[1]) {
        CHECK(s[0]->num_triangles == s[1]->num_triangles);
        /* The fabric and wood primitives change material; metal and label do not. */
        uint32_t changed = 0, same = 0;
        for (uint32_t t = 0; t < s[0]->num_triangles && t < s[1]->num_triangles; t++) {
            const pt_material *a = &s[0]->materials[s[0]->tri_material[t]];
            const pt_material *b = &s[1]->materials[s[1]->tri_material[t]];
            if (strcmp(a->name, b->name) != 0) {
                changed++;
                CHECKF(memcmp(a->base_color, b->base_color, sizeof a->base_color) != 0 ||
                           a->base_color_tex != b->base_color_tex ||
                           memcmp(a->sheen_color, b->sheen_color, sizeof a->sheen_color) != 0,
                       "'%s' and '%s' render alike", a->name, b->name);
            } else {
                same++;
            }
        }
        CHECKF(changed > 0 && same > 0, "%u triangles changed material, %u kept it", changed, same);
    }
    pt_scene_free(s[0]);
    pt_scene_free(s[1]);
}

int main(void)
{
    char dir[] = "/tmp/pt_variants_XXXXXX";
    CHECK(mkdtemp(dir) != NULL);
    test_hand_written(dir);
    rmdir(dir);
    test_sheen_chair();
    return check_report();
}
