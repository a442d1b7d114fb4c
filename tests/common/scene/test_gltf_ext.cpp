// test_gltf_ext.cpp - the importer's glTF extensions and encodings against
// values computed here from the spec's formulas, on files written at run
// time and on the shared sample assets:
// - extensionsRequired naming an extension the importer does not support is
//   refused, naming it; one only in extensionsUsed is warned about once;
// The test reads the shared files with tinygltf itself (its implementation is
// the one compiled into ptcore).
#define TINYGLTF_NO_STB_IMAGE_WRITE
#define TINYGLTF_NO_EXTERNAL_IMAGE
#include <tiny_gltf.h>

#include <cmath>
#include <cstring>
#include <string>
#include <unistd.h>
#include <vector>

extern "C" {
#include "common/base/alloc.h"
#include "common/scene/scene.h"
}
#include "tests/check.h"
#include "tests/common/scene/gltf_writer.hpp"

namespace
{

using pt_test::gltf;

std::string write_tmp(const std::string &text, const char *name)
{
    std::string p =
        std::string("/tmp/pt_test_gltf_ext_") + std::to_string(getpid()) + "_" + name + ".gltf";
    FILE *f = fopen(p.c_str(), "wb");
    if (f) {
        fwrite(text.data(), 1, text.size(), f);
        fclose(f);
    }
    return p;
}

struct loaded {
    pt_scene *s = nullptr;
    pt_status st = PT_OK;
    pt_error err{};
    std::string warnings;
    int nwarn = 0;
    loaded() = default;
    loaded(const loaded &) = delete;
    loaded &operator=(const loaded &) = delete;
    ~loaded() { pt_scene_free(s); }
    // Vertex v's world position, axis r.
    double pos(size_t v, int r) const { return s->positions[3 * v + size_t(r)] + s->origin[r]; }
};

void collect(void *user, const char *msg)
{
    auto *l = static_cast<loaded *>(user);
    l->warnings += std::string(msg) + "\n";
    l->nwarn++;
}

void load(const std::string &path, loaded &l)
{
    pt_scene_opts o{};
    o.warn = collect;
    o.warn_user = &l;
    int64_t live = pt_alloc_live();
    l.st = pt_scene_load(path.c_str(), &o, &l.s, &l.err);
    if (l.st != PT_OK)
        CHECKF(pt_alloc_live() == live, "%s: leaked %lld blocks", path.c_str(),
               (long long)(pt_alloc_live() - live));
}

// The file fails with `code`, naming itself and containing `want`.
void expect_fail(const std::string &text, const char *name, pt_status code, const char *want)
{
    std::string p = write_tmp(text, name);
    loaded l;
    load(p, l);
    CHECKF(l.st == code && !l.s, "%s: status %d (want %d): %s", name, int(l.st), int(code),
           l.err.msg);
    CHECKF(strstr(l.err.msg, p.c_str()) != nullptr, "%s: message lacks the file: %s", name,
           l.err.msg);
    CHECKF(strstr(l.err.msg, want) != nullptr, "%s: '%s' lacks '%s'", name, l.err.msg, want);
    unlink(p.c_str());
}

const std::vector<float> k_tri = {0, 0, 0, 1, 0, 0, 0, 1, 0};

// One triangle (accessor 0) at node 0, the given extension lists and
// material extensions.
std::string ext_file(const char *used, const char *required, const char *mat_ext)
{
    gltf g;
    g.floats(k_tri, "VEC3", 3);
    std::string m = "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":{"
                    "\"POSITION\":0},\"material\":0},{\"attributes\":{\"POSITION\":0},"
                    "\"material\":1}]}],\"materials\":[{\"extensions\":{" +
                    std::string(mat_ext) + "}},{\"extensions\":{" + mat_ext + "}}]";
    if (*used)
        m += ",\"extensionsUsed\":[" + std::string(used) + "]";
    if (*required)
        m += ",\"extensionsRequired\":[" + std::string(required) + "]";
    return g.json(m);
}

int count_of(const std::string &hay, const char *needle)
{
    int n = 0;
    for (size_t at = hay.find(needle); at != std::string::npos; at = hay.find(needle, at + 1))
        n++;
    return n;
}

void test_extensions()
{
    // Required and not supported: refused before anything is built.
    expect_fail(ext_file("\"EXT_made_up\"", "\"EXT_made_up\"", "\"EXT_made_up\":{}"), "required",
                PT_ERR_FORMAT,
                "requires extension EXT_made_up (extensionsRequired), which ptfarm does not "
                "support");
    // Used, not required: loads, one warning naming it, however many
    // materials use it.
    {
        std::string p = write_tmp(ext_file("\"EXT_made_up\"", "", "\"EXT_made_up\":{}"), "used");
        loaded l;
        load(p, l);
        CHECKF(l.st == PT_OK, "%s", l.err.msg);
        CHECKF(l.nwarn == 1 && count_of(l.warnings, "EXT_made_up") == 1, "warnings: %s",
               l.warnings.c_str());
        CHECK(count_of(l.warnings, "is not supported") == 1);
        unlink(p.c_str());
    }
    // A material's extension the file does not declare: warned once too.
    {
        std::string p = write_tmp(ext_file("", "", "\"EXT_undeclared\":{}"), "undeclared");
        loaded l;
        load(p, l);
        CHECKF(l.st == PT_OK, "%s", l.err.msg);
        CHECKF(l.nwarn == 1 && count_of(l.warnings, "EXT_undeclared") == 1, "warnings: %s",
               l.warnings.c_str());
        unlink(p.c_str());
    }
    // Required and supported: no warning at all.
    {
        std::string p =
            write_tmp(ext_file("\"KHR_texture_transform\",\"KHR_materials_emissive_strength\"",
                               "\"KHR_texture_transform\"",
                               "\"KHR_materials_emissive_strength\":{\"emissiveStrength\":2}"),
                      "supported");
        loaded l;
        load(p, l);
        CHECKF(l.st == PT_OK && l.nwarn == 0, "%s %s", l.err.msg, l.warnings.c_str());
        unlink(p.c_str());
    }
}

} // namespace

int main(void)
{
    test_extensions();
    return check_report();
}
