// test_gltf_ext.cpp - the importer's glTF extensions and encodings against
// values computed here from the spec's formulas, on files written at run
// time and on the shared sample assets:
// - extensionsRequired naming an extension the importer does not support is
//   refused, naming it; one only in extensionsUsed is warned about once;
// - KHR_mesh_quantization: every 8- and 16-bit type, normalized or not, for
//   POSITION, NORMAL and TEXCOORD_0, dequantized as the spec says;
// - sparse accessors (glTF 2.0, 3.6.2.3) with and without a base view, on
//   SimpleSparseAccessor, and hostile ones (indices out of range or out of
//   order, counts that lie);
// - morph targets at their default weights in a still: MorphPrimitivesTest
//   against base + 0.5 x delta computed from the file.
// - KHR_draco_mesh_compression: MorphPrimitivesTest's Draco variant within
//   its quantization of the uncompressed one; hostile Draco buffers.
// - EXT_mesh_gpu_instancing: instances placed by global(node) * T * R * S,
//   as a still and posed; SimpleInstancing's 1,500 triangles.
// - EXT_texture_webp (lossless WebP texels exactly, preferred over the PNG
//   fallback) and KHR_texture_basisu (the PNG fallback; KTX2 alone refused).
// - EXT_meshopt_compression: lossless positions and indices bit-identical
//   to the plain file, octahedral normals within their quantization.
// - A primitive without NORMAL gets flat normals, as a still and posed.
// - Generated tangents under a non-uniform scale: a pose gives the still's.
// The test reads the shared files with tinygltf itself (its implementation is
// the one compiled into ptcore).
#define TINYGLTF_NO_STB_IMAGE_WRITE
#define TINYGLTF_NO_EXTERNAL_IMAGE
#include <tiny_gltf.h>

#include <meshoptimizer.h>
#include <stb_image_write.h>
#include <webp/encode.h>

#include <cmath>
#include <cstring>
#include <string>
#include <unistd.h>
#include <vector>

extern "C" {
#include "common/base/alloc.h"
#include "common/scene/accel.h"
#include "common/scene/scene.h"
}
#include "tests/check.h"
#include "tests/common/scene/gltf_writer.hpp"

namespace
{

using pt_test::gltf;

std::string shared(const char *rel)
{
    return std::string(PT_SHARED_SCENES) + "/" + rel;
}

bool exists(const std::string &p)
{
    FILE *f = fopen(p.c_str(), "rb");
    if (f)
        fclose(f);
    return f != nullptr;
}

// Whether the shared asset is there; a CHECK failure when it must be.
bool have_shared(const std::string &p)
{
    if (exists(p))
        return true;
    if (check_shared_required())
        CHECKF(0, "%s is missing", p.c_str());
    else
        CHECK_SKIP("%s is missing", p.c_str());
    return false;
}

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

// ---- KHR_mesh_quantization ----------------------------------------------------------

// The spec's dequantization (glTF 2.0, 3.11 "Animations", the table of
// normalized integers, which KHR_mesh_quantization uses): f = max(c / 127,
// -1) for i8, c / 255 for u8, max(c / 32767, -1) for i16, c / 65535 for u16.
double dequant(int ctype, int c, bool normalized)
{
    if (!normalized)
        return double(c);
    switch (ctype) {
    case 5120:
        return std::fmax(c / 127.0, -1.0);
    case 5121:
        return c / 255.0;
    case 5122:
        return std::fmax(c / 32767.0, -1.0);
    default:
        return c / 65535.0;
    }
}

// Three VEC3 elements (padded to 4-byte elements as the spec's alignment
// asks) of component type ctype from raw integers.
std::vector<unsigned char> packed3(int ctype, const int v[9])
{
    int cs = ctype == 5120 || ctype == 5121 ? 1 : 2;
    size_t stride = cs == 1 ? 4 : 8;
    std::vector<unsigned char> out(3 * stride, 0);
    for (int e = 0; e < 3; e++)
        for (int c = 0; c < 3; c++) {
            unsigned char *p = &out[size_t(e) * stride + size_t(c * cs)];
            uint16_t u = uint16_t(v[3 * e + c]);
            p[0] = uint8_t(u & 0xff);
            if (cs == 2)
                p[1] = uint8_t(u >> 8);
        }
    return out;
}

void test_quantization()
{
    const int types[4] = {5120, 5121, 5122, 5123};
    const int big[4] = {-128, 255, -32768, 65535}; // the extremes; i8/i16 clamp to -1
    for (int t = 0; t < 4; t++)
        for (int norm = 0; norm < 2; norm++) {
            int ct = types[t], c = big[t];
            int raw[9] = {0, 0, 0, c, 0, 0, 0, c == -128 || c == -32768 ? 1 : 3, 0};
            gltf g;
            std::vector<unsigned char> pb = packed3(ct, raw);
            int view = g.view(pb.data(), pb.size(), ct == 5120 || ct == 5121 ? 4 : 8);
            char acc[200];
            snprintf(acc, sizeof acc,
                     "{\"bufferView\":%d,\"byteOffset\":0,\"componentType\":%d,\"count\":3,"
                     "\"type\":\"VEC3\"%s}",
                     view, ct, norm ? ",\"normalized\":true" : "");
            int pa = g.accessor(acc);
            // Normals +Z as normalized i8 (127), texcoords as i16.
            int8_t n8[12] = {0, 0, 127, 0, 0, 0, 127, 0, 0, 0, 127, 0};
            int na = g.add(n8, sizeof n8, 5120, "VEC3", 3, true, 4);
            int16_t uv[6] = {0, 0, 2, 0, 0, -3};
            int ua = g.add(uv, sizeof uv, 5122, "VEC2", 3);
            char m[600];
            snprintf(m, sizeof m,
                     "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":{"
                     "\"POSITION\":%d,\"NORMAL\":%d,\"TEXCOORD_0\":%d}}]}],"
                     "\"extensionsUsed\":[\"KHR_mesh_quantization\"],"
                     "\"extensionsRequired\":[\"KHR_mesh_quantization\"]",
                     pa, na, ua);
            std::string text = g.json(m);
            std::string p = write_tmp(text, "quant");
            loaded l;
            load(p, l);
            CHECKF(l.st == PT_OK, "type %d normalized %d: %s", ct, norm, l.err.msg);
            if (!l.s)
                continue;
            CHECK(l.nwarn == 0);
            for (int v = 0; v < 3; v++)
                for (int r = 0; r < 3; r++) {
                    double want = dequant(ct, raw[3 * v + r], norm != 0);
                    CHECKF(std::fabs(l.pos(size_t(v), r) - want) < 1e-6 * (1 + std::fabs(want)),
                           "type %d normalized %d vertex %d axis %d: %g, want %g", ct, norm, v, r,
                           l.pos(size_t(v), r), want);
                }
            CHECK(l.s->normals[2] == 1.0f);
            CHECK(l.s->uvs && l.s->uvs[2] == 2.0f && l.s->uvs[5] == -3.0f);
            unlink(p.c_str());
        }
    // What stays refused: u32 positions, unnormalized integer normals.
    {
        gltf g;
        uint32_t p32[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
        int pa = g.add(p32, sizeof p32, 5125, "VEC3", 3);
        char m[200];
        snprintf(m, sizeof m,
                 "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":{"
                 "\"POSITION\":%d}}]}]",
                 pa);
        expect_fail(g.json(m), "quant_u32", PT_ERR_FORMAT, "component type 5125 is not supported");
    }
    {
        gltf g;
        g.floats(k_tri, "VEC3", 3);
        int8_t n8[12] = {0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0};
        int na = g.add(n8, sizeof n8, 5120, "VEC3", 3, false, 4);
        char m[200];
        snprintf(m, sizeof m,
                 "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":{"
                 "\"POSITION\":0,\"NORMAL\":%d}}]}]",
                 na);
        expect_fail(g.json(m), "quant_nrm", PT_ERR_FORMAT, "component type 5120 is not supported");
    }
}

// ---- sparse accessors -----------------------------------------------------------------

// A triangle whose POSITION (accessor 1) is sparse: `base` false means no
// buffer view (zeros); indices of component type ictype from `idx`, values
// (count of them) from `val`; `count` is the sparse count the file claims.
std::string sparse_file(bool base, int ictype, const std::vector<uint32_t> &idx,
                        const std::vector<float> &val, int count)
{
    gltf g;
    uint16_t tri[3] = {0, 1, 2};
    g.add(tri, sizeof tri, 5123, "SCALAR", 3);
    int bv = g.view(k_tri.data(), k_tri.size() * 4);
    std::vector<unsigned char> ib;
    for (uint32_t i : idx) {
        int is = ictype == 5121 ? 1 : ictype == 5123 ? 2 : 4;
        for (int k = 0; k < is; k++)
            ib.push_back(uint8_t(i >> (8 * k)));
    }
    if (ib.empty())
        ib.push_back(0);
    int iv = g.view(ib.data(), ib.size());
    int vv = g.view(val.data(), val.size() * 4);
    char acc[400];
    snprintf(acc, sizeof acc,
             "{%s\"componentType\":5126,\"count\":3,\"type\":\"VEC3\",\"sparse\":{\"count\":%d,"
             "\"indices\":{\"bufferView\":%d,\"componentType\":%d},\"values\":{\"bufferView\":%"
             "d}}}",
             base ? ("\"bufferView\":" + std::to_string(bv) + ",").c_str() : "", count, iv, ictype,
             vv);
    g.accessor(acc);
    return g.json("\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":{"
                  "\"POSITION\":1},\"indices\":0}]}]");
}

void check_positions(const std::string &text, const char *name, const std::vector<float> &want)
{
    std::string p = write_tmp(text, name);
    loaded l;
    load(p, l);
    CHECKF(l.st == PT_OK, "%s: %s", name, l.err.msg);
    if (l.s && l.s->num_vertices == want.size() / 3)
        for (size_t v = 0; v < want.size() / 3; v++)
            for (int r = 0; r < 3; r++)
                CHECKF(l.pos(v, r) == double(want[3 * v + size_t(r)]),
                       "%s: vertex %zu axis %d: %g, want %g", name, v, r, l.pos(v, r),
                       double(want[3 * v + size_t(r)]));
    else
        CHECKF(0, "%s: not loaded with 3 vertices", name);
    unlink(p.c_str());
}

void test_sparse()
{
    // Over the base: vertex 1 moved to (5, 0, 2).
    check_positions(sparse_file(true, 5123, {1}, {5, 0, 2}, 1), "sparse_base",
                    {0, 0, 0, 5, 0, 2, 0, 1, 0});
    // No base: zeros, then vertices 0 and 2 set (u8 and u32 indices).
    check_positions(sparse_file(false, 5121, {0, 2}, {1, 1, 1, 0, 3, 0}, 2), "sparse_zeros8",
                    {1, 1, 1, 0, 0, 0, 0, 3, 0});
    check_positions(sparse_file(false, 5125, {0, 2}, {1, 1, 1, 0, 3, 0}, 2), "sparse_zeros32",
                    {1, 1, 1, 0, 0, 0, 0, 3, 0});
    // Hostile: an index past the count, indices out of order or repeated, a
    // count over the accessor's, a count the views cannot hold, indices of
    // a float type.
    expect_fail(sparse_file(true, 5123, {3}, {5, 0, 2}, 1), "sparse_range", PT_ERR_FORMAT,
                "sparse index 3 at 0 is out of range (count 3)");
    expect_fail(sparse_file(true, 5123, {2, 1}, {0, 0, 0, 0, 0, 0}, 2), "sparse_order",
                PT_ERR_FORMAT, "sparse indices do not strictly increase (1 after 2)");
    expect_fail(sparse_file(true, 5123, {1, 1}, {0, 0, 0, 0, 0, 0}, 2), "sparse_repeat",
                PT_ERR_FORMAT, "sparse indices do not strictly increase (1 after 1)");
    expect_fail(sparse_file(true, 5123, {0, 1, 2}, {0, 0, 0, 0, 0, 0, 0, 0, 0}, 4), "sparse_over",
                PT_ERR_FORMAT, "sparse count 4 is not in [1, 3]");
    expect_fail(sparse_file(true, 5123, {0}, {0, 0, 0}, 2), "sparse_lie", PT_ERR_FORMAT,
                "run past the end of bufferView");
    expect_fail(sparse_file(true, 5126, {0}, {0, 0, 0}, 1), "sparse_ftype", PT_ERR_FORMAT,
                "is not u8/u16/u32");
    expect_fail(sparse_file(true, 5123, {}, {}, 0), "sparse_zero", PT_ERR_FORMAT,
                "sparse count 0 is not in [1, 3]");

    // SimpleSparseAccessor: its 14 positions computed here from the .bin
    // (indices u16 at byte 0, base view 1 at 72, sparse indices u16 at byte
    // 240, values at 248).
    std::string path = shared("SimpleSparseAccessor/SimpleSparseAccessor.gltf");
    if (!have_shared(path))
        return;
    std::vector<unsigned char> bin(284);
    FILE *f = fopen(shared("SimpleSparseAccessor/SimpleSparseAccessor.bin").c_str(), "rb");
    CHECK(f && fread(bin.data(), 1, bin.size(), f) == bin.size());
    if (f)
        fclose(f);
    std::vector<float> want(42);
    memcpy(want.data(), &bin[72], 168);
    for (int k = 0; k < 3; k++) {
        int at = bin[size_t(240 + 2 * k)] | bin[size_t(241 + 2 * k)] << 8;
        memcpy(&want[size_t(3 * at)], &bin[size_t(248 + 12 * k)], 12);
    }
    loaded l;
    load(path, l);
    CHECKF(l.st == PT_OK && l.nwarn == 0, "%s %s", l.err.msg, l.warnings.c_str());
    if (!l.s)
        return;
    // No NORMAL: flat normals (glTF 2.0, 3.7.2.1), so one vertex a corner
    // of the 12 triangles, corner c at the vertex of index c (u16 at 2 c).
    CHECK(l.s->num_vertices == 36 && l.s->num_triangles == 12);
    int bad = 0;
    for (size_t c = 0; c < 36 && c < l.s->num_vertices; c++) {
        size_t v = size_t(bin[2 * c] | bin[2 * c + 1] << 8);
        for (int r = 0; r < 3; r++)
            bad += v >= 14 || l.pos(c, r) != double(want[3 * v + size_t(r)]);
    }
    CHECKF(bad == 0, "%d coordinates differ from the sparse substitution", bad);
    // The accessor's max (6, 4, 0) holds the displaced vertices.
    CHECKF(l.s->bounds_max.y + l.s->origin[1] == 4.0, "max y %g",
           double(l.s->bounds_max.y + l.s->origin[1]));
}

// ---- morph targets at their default weights ------------------------------------------

// Accessor element i, component c, as a double (float; normalized or not
// 8/16-bit integers).
double acc_get(const tinygltf::Model &m, int ai, size_t i, int c)
{
    const tinygltf::Accessor &a = m.accessors[size_t(ai)];
    const tinygltf::BufferView &v = m.bufferViews[size_t(a.bufferView)];
    int cs = tinygltf::GetComponentSizeInBytes(uint32_t(a.componentType));
    int nc = tinygltf::GetNumComponentsInType(uint32_t(a.type));
    size_t stride = v.byteStride ? v.byteStride : size_t(cs * nc);
    const unsigned char *p = m.buffers[size_t(v.buffer)].data.data() + v.byteOffset + a.byteOffset +
                             i * stride + size_t(c * cs);
    int raw;
    switch (a.componentType) {
    case TINYGLTF_COMPONENT_TYPE_FLOAT: {
        float f;
        memcpy(&f, p, 4);
        return f;
    }
    case 5120:
        raw = int8_t(p[0]);
        break;
    case 5121:
        raw = p[0];
        break;
    case 5122:
        raw = int16_t(uint16_t(p[0] | p[1] << 8));
        break;
    default:
        raw = p[0] | p[1] << 8;
        break;
    }
    return dequant(a.componentType, raw, a.normalized);
}

void test_morph_default_weights()
{
    std::string path = shared("MorphPrimitivesTest/glTF-Binary/MorphPrimitivesTest.glb");
    if (!have_shared(path))
        return;
    tinygltf::Model m;
    tinygltf::TinyGLTF loader;
    std::string terr, twarn;
    CHECK(loader.LoadBinaryFromFile(&m, &terr, &twarn, path));
    loaded l;
    load(path, l);
    CHECKF(l.st == PT_OK, "%s", l.err.msg);
    CHECKF(l.nwarn == 0, "%s", l.warnings.c_str());
    if (!l.s || m.nodes.empty())
        return;
    // A root node over one mesh node with weights [0.5]; no node has a
    // matrix or TRS (checked), so a vertex is base + 0.5 x delta.
    for (const auto &n : m.nodes)
        CHECK(n.matrix.empty() && n.translation.empty() && n.rotation.empty() && n.scale.empty() &&
              n.weights.empty());
    CHECK(m.nodes.size() == 2 && m.nodes[1].mesh == 0 && m.meshes.size() == 1);
    if (m.meshes.size() != 1)
        return;
    const tinygltf::Mesh &mesh = m.meshes[0];
    CHECK(mesh.weights.size() == 1 && mesh.weights[0] == 0.5);
    size_t v0 = 0;
    double worst = 0, moved = 0;
    for (const auto &p : mesh.primitives) {
        int pa = p.attributes.at("POSITION");
        size_t nv = m.accessors[size_t(pa)].count;
        for (size_t v = 0; v < nv && v0 + v < l.s->num_vertices; v++)
            for (int r = 0; r < 3; r++) {
                double want = acc_get(m, pa, v, r);
                for (size_t k = 0; k < p.targets.size(); k++) {
                    auto it = p.targets[k].find("POSITION");
                    if (it != p.targets[k].end()) {
                        double d = mesh.weights[k] * acc_get(m, it->second, v, r);
                        want += d;
                        moved = std::fmax(moved, std::fabs(d));
                    }
                }
                worst = std::fmax(worst, std::fabs(l.pos(v0 + v, r) - want));
            }
        v0 += nv;
    }
    CHECK(v0 == l.s->num_vertices);
    CHECKF(worst < 1e-6, "morphed vertices off by %g", worst);
    CHECKF(moved > 0.1, "the targets move vertices by %g only", moved);
}

// ---- KHR_draco_mesh_compression --------------------------------------------------------

// MorphPrimitivesTest's Draco variant against its uncompressed one: the same
// triangles over the same vertices in the same order (the extension keeps
// the order when a mesh has morph targets), and every vertex within Draco's
// quantization of the uncompressed one. The bound: Draco quantizes a
// position to q bits over its bounding cube of side r, so a coordinate moves
// by at most r / (2^q - 1) / 2 (half a step); the variant's POSITION
// accessors (max 0.5004885 = 0.5 + 1 / 2047 on a side of 1) give q = 11 for
// this file, a step of 1 / 2047. The still adds 0.5 x the (uncompressed)
// morph delta to both alike. Normals are quantized on the octahedron with
// at least 8 bits a coordinate by default: a step of 2 / 255 on each of
// the two octahedral coordinates moves a unit normal by under 0.02.
// Texture coordinates: 10 bits over their range [0, 1], a step of 1 / 1023.
void test_draco()
{
    std::string bin = shared("MorphPrimitivesTest/glTF-Binary/MorphPrimitivesTest.glb");
    std::string dra = shared("MorphPrimitivesTest/glTF-Draco/MorphPrimitivesTest.gltf");
    if (!have_shared(bin) || !have_shared(dra))
        return;
    loaded a, b;
    load(bin, a);
    load(dra, b);
    CHECKF(a.st == PT_OK && b.st == PT_OK, "%s / %s", a.err.msg, b.err.msg);
    CHECKF(b.nwarn == 0, "%s", b.warnings.c_str());
    if (!a.s || !b.s)
        return;
    CHECK(a.s->num_vertices == b.s->num_vertices && a.s->num_triangles == b.s->num_triangles);
    if (a.s->num_vertices != b.s->num_vertices || a.s->num_triangles != b.s->num_triangles)
        return;
    CHECK(memcmp(a.s->indices, b.s->indices, 12 * size_t(a.s->num_triangles)) == 0);
    double dp = 0, dn = 0, du = 0;
    for (size_t v = 0; v < a.s->num_vertices; v++) {
        for (int r = 0; r < 3; r++) {
            dp = std::fmax(dp, std::fabs(a.pos(v, r) - b.pos(v, r)));
            dn = std::fmax(dn, std::fabs(double(a.s->normals[3 * v + size_t(r)]) -
                                         double(b.s->normals[3 * v + size_t(r)])));
        }
        for (int r = 0; r < 2 && a.s->uvs && b.s->uvs; r++)
            du = std::fmax(du, std::fabs(double(a.s->uvs[2 * v + size_t(r)]) -
                                         double(b.s->uvs[2 * v + size_t(r)])));
    }
    if (getenv("PT_TEST_VERBOSE"))
        printf("draco: position %g, normal %g, uv %g\n", dp, dn, du);
    CHECK(a.s->uvs && b.s->uvs);
    CHECKF(dp <= 1.0 / 2047.0 / 2.0 + 1e-6, "positions differ by %g", dp);
    CHECKF(dn < 0.02, "normals differ by %g", dn);
    CHECKF(du <= 1.0 / 1023.0 / 2.0 + 1e-6, "texture coordinates differ by %g", du);
    CHECKF(dp > 0.0, "no quantization at all: the Draco variant was not decoded?");
}

std::string read_text(const std::string &path)
{
    std::string out;
    FILE *f = fopen(path.c_str(), "rb");
    if (!f)
        return out;
    char buf[4096];
    size_t n;
    while ((n = fread(buf, 1, sizeof buf, f)) > 0)
        out.append(buf, n);
    fclose(f);
    return out;
}

// The k-th (0-based) occurrence of from in s replaced by to.
std::string replace_nth(std::string s, const std::string &from, const std::string &to, int k)
{
    size_t at = s.find(from);
    for (int i = 0; i < k && at != std::string::npos; i++)
        at = s.find(from, at + 1);
    if (at != std::string::npos)
        s.replace(at, from.size(), to);
    else
        CHECKF(0, "'%s' not found", from.c_str());
    return s;
}

// Hostile Draco: accessors whose counts disagree with the Draco buffer's, a
// truncated buffer, and every byte of the Draco streams overwritten in turn
// (counts, varints, entropy-coded data): each loads, or fails with a format
// or limit error that names the file, never anything else.
void test_draco_hostile()
{
    std::string dir = shared("MorphPrimitivesTest/glTF-Draco/");
    if (!have_shared(dir + "MorphPrimitivesTest.gltf"))
        return;
    std::string text = read_text(dir + "MorphPrimitivesTest.gltf");
    std::string binb = read_text(dir + "MorphPrimitivesTest.bin");
    std::string jpg = read_text(dir + "uv_texture.jpg");
    CHECK(binb.size() == 880);
    // The file alone: its buffer and image as data: URIs.
    text =
        replace_nth(text, "\"uri\": \"uv_texture.jpg\"",
                    "\"uri\": \"data:image/jpeg;base64," +
                        pt_test::base64(std::vector<unsigned char>(jpg.begin(), jpg.end())) + "\"",
                    0);
    auto with_bin = [&](const std::string &t, const std::string &b) {
        std::vector<unsigned char> v(b.begin(), b.end());
        return replace_nth(t, "\"MorphPrimitivesTest.bin\"",
                           "\"data:application/octet-stream;base64," + pt_test::base64(v) + "\"",
                           0);
    };
    {
        std::string p = write_tmp(with_bin(text, binb), "draco_intact");
        loaded l;
        load(p, l);
        CHECKF(l.st == PT_OK && l.nwarn == 0, "%s %s", l.err.msg, l.warnings.c_str());
        unlink(p.c_str());
    }
    // Accessor 4 (POSITION of primitive 0) says 22: the third "count": 21.
    expect_fail(with_bin(replace_nth(text, "\"count\": 21", "\"count\": 22", 2), binb),
                "draco_count", PT_ERR_FORMAT,
                "accessor 4 (POSITION) says 22 elements, the Draco buffer holds 21 points");
    expect_fail(with_bin(replace_nth(text, "\"count\": 72", "\"count\": 75", 0), binb),
                "draco_indices", PT_ERR_FORMAT,
                "indices accessor 2 says 75 indices, the Draco buffer holds 24 triangles");
    expect_fail(with_bin(replace_nth(text, "\"byteLength\": 310", "\"byteLength\": 200", 0), binb),
                "draco_short", PT_ERR_FORMAT, "KHR_draco_mesh_compression bufferView 2: Draco:");
    int loaded_ok = 0, refused = 0, bad = 0;
    for (size_t at = 360; at < 880; at++) {
        if (at >= 670 && at < 672)
            continue; // padding between the two streams
        // Every byte as 0xff; the headers' (the first 32 of each stream)
        // as 0 and 0x7f too: counts and varints.
        bool head = at < 392 || (at >= 672 && at < 704);
        for (int val : {0xff, 0x00, 0x7f}) {
            if (val != 0xff && !head)
                continue;
            std::string b = binb;
            if ((unsigned char)b[at] == val)
                continue;
            b[at] = char(val);
            std::string p = write_tmp(with_bin(text, b), "draco_byte");
            loaded l;
            load(p, l);
            if (l.st == PT_OK) {
                loaded_ok++;
                CHECK(l.s && l.s->num_triangles > 0);
            } else if ((l.st == PT_ERR_FORMAT || l.st == PT_ERR_LIMIT) &&
                       strstr(l.err.msg, p.c_str()) != nullptr) {
                refused++;
            } else if (bad++ < 5) {
                CHECKF(0, "byte %zu = %d: status %d: %s", at, val, int(l.st), l.err.msg);
            }
            unlink(p.c_str());
        }
    }
    if (getenv("PT_TEST_VERBOSE"))
        printf("draco bytes: %d loaded, %d refused\n", loaded_ok, refused);
    CHECK(refused > 0);
    CHECKF(bad == 0, "%d overwritten bytes gave another error", bad);
}

// ---- EXT_mesh_gpu_instancing -----------------------------------------------------------

// A triangle instanced twice (translations (10, 0, 0) and (0, 10, 0), the
// second also rotated a quarter turn about z and scaled by 2) under node 0,
// which an animation moves from (0, 0, 0) at 0 s to (0, 0, 4) at 1 s. The
// still has both copies where global(node) * T * R * S puts them; posed at
// 0.5 s they follow the node. Then: SimpleInstancing's 125 cubes, and
// instance counts that lie.
void test_instancing()
{
    gltf g;
    g.floats(k_tri, "VEC3", 3);
    int ta = g.floats({10, 0, 0, 0, 10, 0}, "VEC3", 3);
    int ra = g.floats({0, 0, 0, 1, 0, 0, 0.70710678f, 0.70710678f}, "VEC4", 4);
    int sa = g.floats({1, 1, 1, 2, 2, 2}, "VEC3", 3);
    int in = g.floats({0, 1}, "SCALAR", 1), out = g.floats({0, 0, 0, 0, 0, 4}, "VEC3", 3);
    char m[700];
    snprintf(m, sizeof m,
             "\"nodes\":[{\"mesh\":0,\"extensions\":{\"EXT_mesh_gpu_instancing\":{\"attributes\":{"
             "\"TRANSLATION\":%d,\"ROTATION\":%d,\"SCALE\":%d}}}}],\"meshes\":[{\"primitives\":[{"
             "\"attributes\":{\"POSITION\":0}}]}],\"extensionsUsed\":[\"EXT_mesh_gpu_"
             "instancing\"],\"animations\":[{\"channels\":[{\"sampler\":0,\"target\":{\"node\":0,"
             "\"path\":\"translation\"}}],\"samplers\":[{\"input\":%d,\"output\":%d}]}]",
             ta, ra, sa, in, out);
    std::string p = write_tmp(g.json(m), "instancing");
    // Instance 1 maps (x, y, z) to (-2y, 2x, 2z) + (0, 10, 0).
    const double want[6][3] = {{10, 0, 0}, {11, 0, 0}, {10, 1, 0},
                               {0, 10, 0}, {0, 12, 0}, {-2, 10, 0}};
    for (int posed = 0; posed < 2; posed++) {
        pt_scene_opts o{};
        o.animate = posed;
        o.time = 0.5;
        pt_scene *s = nullptr;
        pt_error err{};
        CHECKF(pt_scene_load(p.c_str(), &o, &s, &err) == PT_OK, "%s", err.msg);
        if (!s)
            continue;
        // The still keeps them as instances of the one triangle (its
        // vertices in the mesh's space, each instance's map applied here);
        // posed, every copy is in scene space.
        if (!posed) {
            CHECKF(s->num_instances == 2 && s->num_prototypes == 1 && s->num_triangles == 1 &&
                       s->num_flat_triangles == 0 && (s->features & PT_FEAT_INSTANCES),
                   "%u instances, %u triangles", s->num_instances, s->num_triangles);
        } else {
            CHECK(s->num_triangles == 2 && s->num_vertices == 6 && s->num_instances == 0);
        }
        for (size_t v = 0; v < 6; v++) {
            pt_vec3 q;
            if (!posed && s->num_instances == 2)
                q = pt_instance_point(&s->instances[v / 3], pt_v3(s->positions[3 * (v % 3)],
                                                                  s->positions[3 * (v % 3) + 1],
                                                                  s->positions[3 * (v % 3) + 2]));
            else if (posed && v < s->num_vertices)
                q = pt_v3(s->positions[3 * v], s->positions[3 * v + 1], s->positions[3 * v + 2]);
            else
                continue;
            const float qa[3] = {q.x, q.y, q.z};
            for (int r = 0; r < 3; r++) {
                double got = qa[r] + s->origin[r];
                double w = want[v][r] + (posed && r == 2 ? 2.0 : 0.0);
                CHECKF(std::fabs(got - w) < 1e-5, "posed %d vertex %zu axis %d: %g, want %g", posed,
                       v, r, got, w);
            }
        }
        pt_scene_free(s);
    }
    unlink(p.c_str());

    std::string path = shared("SimpleInstancing/SimpleInstancing.glb");
    if (!have_shared(path))
        return;
    loaded l;
    load(path, l);
    CHECKF(l.st == PT_OK && l.nwarn == 0, "%s %s", l.err.msg, l.warnings.c_str());
    if (l.s)
        CHECKF(l.s->num_triangles == 12 && l.s->num_instances == 125, "%u triangles, %u instances",
               l.s->num_triangles, l.s->num_instances);

    // Attributes that disagree on the count.
    gltf h;
    h.floats(k_tri, "VEC3", 3);
    int t2 = h.floats({1, 0, 0, 2, 0, 0}, "VEC3", 3), s3 = h.floats({1, 1, 1}, "VEC3", 3);
    snprintf(m, sizeof m,
             "\"nodes\":[{\"mesh\":0,\"extensions\":{\"EXT_mesh_gpu_instancing\":{\"attributes\":{"
             "\"TRANSLATION\":%d,\"SCALE\":%d}}}}],\"meshes\":[{\"primitives\":[{"
             "\"attributes\":{\"POSITION\":0}}]}]",
             t2, s3);
    expect_fail(h.json(m), "inst_disagree", PT_ERR_FORMAT,
                "EXT_mesh_gpu_instancing attributes disagree on the count");
}

// N instances of an octahedron with smooth normals (its positions) over
// a floor, written once with EXT_mesh_gpu_instancing (node 1) and once
// as N nodes with each instance's TRS (the same floats): rotations about
// several axes, non-uniform scales and one mirror (SCALE (-1, 1, 1)).
// copies 1: the nodes; bad: "nan" puts a NaN in a TRANSLATION, "huge"
// claims 2^31 instances.
std::string instancing_file(int n, bool copies, const char *bad = "")
{
    gltf g;
    const float r = 1.0f;
    std::vector<float> oct = {r, 0, 0, -r, 0, 0, 0, r, 0, 0, -r, 0, 0, 0, r, 0, 0, -r};
    const std::vector<unsigned short> oi = {0, 2, 4, 2, 1, 4, 1, 3, 4, 3, 0, 4,
                                            2, 0, 5, 1, 2, 5, 3, 1, 5, 0, 3, 5};
    int pa = g.floats(oct, "VEC3", 3), na = g.floats(oct, "VEC3", 3);
    int ia = g.add(oi.data(), oi.size() * 2, 5123, "SCALAR", oi.size());
    std::vector<float> fl = {-20, -20, -3, 20, -20, -3, 20, 20, -3, -20, 20, -3};
    const std::vector<unsigned short> fi = {0, 1, 2, 0, 2, 3};
    int fa = g.floats(fl, "VEC3", 3);
    int fia = g.add(fi.data(), fi.size() * 2, 5123, "SCALAR", fi.size());
    std::vector<float> t, q, sc;
    uint32_t h = 12345;
    auto rnd = [&h]() {
        h = h * 1664525u + 1013904223u;
        return float(h >> 8) / 16777216.0f;
    };
    for (int i = 0; i < n; i++) {
        t.insert(t.end(), {float(i % 6) * 3.0f - 7.5f, float(i / 6) * 3.0f - 7.5f, rnd() - 0.5f});
        float ax[3] = {rnd() - 0.5f, rnd() - 0.5f, rnd() - 0.5f};
        float al = std::sqrt(ax[0] * ax[0] + ax[1] * ax[1] + ax[2] * ax[2]);
        float ang = 6.0f * rnd(), sh = std::sin(ang / 2) / al;
        q.insert(q.end(), {ax[0] * sh, ax[1] * sh, ax[2] * sh, std::cos(ang / 2)});
        if (i == 3)
            sc.insert(sc.end(), {-1.0f, 1.0f, 1.0f});
        else
            sc.insert(sc.end(), {0.5f + rnd(), 0.5f + rnd(), 0.5f + rnd()});
    }
    if (!strcmp(bad, "nan"))
        t[4] = NAN;
    int ta = g.floats(t, "VEC3", 3), ra = g.floats(q, "VEC4", 4), sa = g.floats(sc, "VEC3", 3);
    if (!strcmp(bad, "huge"))
        g.accessors.replace(g.accessors.rfind("\"count\":" + std::to_string(n)),
                            8 + std::to_string(n).size(), "\"count\":2147483648");
    char head[600];
    snprintf(head, sizeof head,
             "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":%d,\"NORMAL\":%d},"
             "\"indices\":%d}]},{\"primitives\":[{\"attributes\":{\"POSITION\":%d},\"indices\":%"
             "d}]}]",
             pa, na, ia, fa, fia);
    std::string nodes;
    if (!copies) {
        char n1[300];
        snprintf(n1, sizeof n1,
                 "{\"children\":[1,2]},{\"mesh\":0,\"extensions\":{\"EXT_mesh_gpu_instancing\":{"
                 "\"attributes\":{\"TRANSLATION\":%d,\"ROTATION\":%d,\"SCALE\":%d}}}},{\"mesh\":1}",
                 ta, ra, sa);
        nodes = n1;
    } else {
        nodes = "{\"children\":[1";
        for (int i = 0; i < n; i++)
            nodes += "," + std::to_string(2 + i);
        nodes += "]},{\"mesh\":1}";
        for (int i = 0; i < n; i++) {
            char ni[300];
            snprintf(ni, sizeof ni,
                     ",{\"mesh\":0,\"translation\":[%.9g,%.9g,%.9g],\"rotation\":[%.9g,%.9g,%.9g,%."
                     "9g],\"scale\":[%.9g,%.9g,%.9g]}",
                     double(t[3 * i]), double(t[3 * i + 1]), double(t[3 * i + 2]), double(q[4 * i]),
                     double(q[4 * i + 1]), double(q[4 * i + 2]), double(q[4 * i + 3]),
                     double(sc[3 * i]), double(sc[3 * i + 1]), double(sc[3 * i + 2]));
            nodes += ni;
        }
    }
    std::string ext = copies ? "" : ",\"extensionsUsed\":[\"EXT_mesh_gpu_instancing\"]";
    return g.json(std::string(head) + ",\"nodes\":[" + nodes + "]" + ext);
}

// The shading normal of a hit, interpolated and normalised, through its
// instance's inverse transpose when it has one.
pt_vec3 shading_normal(const pt_scene *s, const pt_hit &h)
{
    const uint32_t *t = &s->indices[3 * h.tri];
    float b0 = 1.0f - h.b1 - h.b2;
    pt_vec3 n = pt_v3(0, 0, 0);
    const float w[3] = {b0, h.b1, h.b2};
    for (int k = 0; k < 3; k++) {
        pt_vec3 v = pt_v3(s->normals[3 * t[k]], s->normals[3 * t[k] + 1], s->normals[3 * t[k] + 2]);
        if (h.inst) // vertex by vertex, as the builder makes a copy's
            v = pt_instance_normal(&s->instances[h.inst - 1], v, v);
        n = pt_v3_add(n, pt_v3_scale(v, w[k]));
    }
    return pt_v3_norm(n);
}

// The instanced file and its copies, ray by ray: 4,096 rays from above
// hit the same surfaces at the same distance, point, geometric and
// shading normal, up to float rounding (1e-4 of the scene's size: an
// instance's point is its float map of the mesh's float vertices, a
// copy's vertices are mapped in double and rounded); a ray that grazes
// an edge may hit one and miss the other (at most 4). Then the caps and
// a NaN.
void test_instances_vs_copies()
{
    const int n = 36;
    std::string pi = write_tmp(instancing_file(n, false), "inst_n"),
                pc = write_tmp(instancing_file(n, true), "inst_copies");
    loaded li, lc;
    load(pi, li);
    load(pc, lc);
    CHECKF(li.st == PT_OK && lc.st == PT_OK, "%s / %s", li.err.msg, lc.err.msg);
    if (li.s && lc.s) {
        CHECKF(li.s->num_instances == uint32_t(n) && li.s->num_triangles == 8 + 2 &&
                   lc.s->num_instances == 0 && lc.s->num_triangles == 8u * n + 2,
               "%u instances, %u / %u triangles", li.s->num_instances, li.s->num_triangles,
               lc.s->num_triangles);
        CHECK(li.nwarn == 0 && lc.nwarn == 0);
        pt_accel *ai = nullptr, *ac = nullptr;
        pt_error err{};
        CHECKF(pt_accel_new(li.s, &ai, &err) == PT_OK, "%s", err.msg);
        CHECKF(pt_accel_new(lc.s, &ac, &err) == PT_OK, "%s", err.msg);
        int hits = 0, odd = 0, far = 0, through = 0, mirrored = 0;
        for (int k = 0; ai && ac && k < 4096; k++) {
            // World (0, 0, 20) looking down over the grid; origins are 0.
            double o[3] = {0, 0, 20};
            pt_vec3 oi = pt_v3(float(o[0] - li.s->origin[0]), float(o[1] - li.s->origin[1]),
                               float(o[2] - li.s->origin[2]));
            pt_vec3 oc = pt_v3(float(o[0] - lc.s->origin[0]), float(o[1] - lc.s->origin[1]),
                               float(o[2] - lc.s->origin[2]));
            pt_vec3 d = pt_v3_norm(pt_v3((float(k % 64) - 31.5f) / 64.0f * 0.9f,
                                         (float(k / 64) - 31.5f) / 64.0f * 0.9f, -1.0f));
            pt_hit hi{}, hc{};
            int a = pt_accel_intersect(ai, oi, d, INFINITY, &hi);
            int c = pt_accel_intersect(ac, oc, d, INFINITY, &hc);
            if (a != c) {
                odd++;
                continue;
            }
            if (!a)
                continue;
            hits++;
            through += hi.inst != 0;
            if (hi.inst && li.s->instances[hi.inst - 1].tan_sign < 0.0f)
                mirrored++;
            pt_vec3 p1, n1, p2, n2;
            pt_accel_hit_point(li.s, &hi, &p1, &n1);
            pt_accel_hit_point(lc.s, &hc, &p2, &n2);
            pt_vec3 s1 = shading_normal(li.s, hi), s2 = shading_normal(lc.s, hc);
            double dp = 0;
            const float a1[3] = {p1.x, p1.y, p1.z}, a2[3] = {p2.x, p2.y, p2.z};
            for (int r = 0; r < 3; r++)
                dp =
                    std::fmax(dp, std::fabs((a1[r] + li.s->origin[r]) - (a2[r] + lc.s->origin[r])));
            if (std::fabs(hi.t - hc.t) > 1e-4f || dp > 1e-4 || pt_v3_dot(n1, n2) < 1.0f - 1e-5f ||
                pt_v3_dot(s1, s2) < 1.0f - 1e-5f) {
                if (far++ < 3)
                    fprintf(stderr,
                            "ray %d: t %.7g vs %.7g, point off by %g, ng.ng %.7g, ns.ns %.7g\n", k,
                            double(hi.t), double(hc.t), dp, double(pt_v3_dot(n1, n2)),
                            double(pt_v3_dot(s1, s2)));
            }
        }
        CHECKF(hits > 3000 && through > 500 && mirrored > 10,
               "%d hits, %d through instances, %d mirrored", hits, through, mirrored);
        CHECKF(odd <= 4, "%d rays hit one and miss the other", odd);
        CHECKF(far == 0, "%d hits differ", far);
        pt_accel_free(ai);
        pt_accel_free(ac);
    }
    unlink(pi.c_str());
    unlink(pc.c_str());
    expect_fail(instancing_file(n, false, "nan"), "inst_nan", PT_ERR_FORMAT, "not finite");
    // Instances of a mesh of points only: nothing to see, said as a scene
    // without triangles (not an empty accelerator).
    gltf pts;
    pts.floats(k_tri, "VEC3", 3);
    int pt2 = pts.floats({0, 0, 0, 10, 0, 0}, "VEC3", 3);
    char pm[400];
    snprintf(pm, sizeof pm,
             "\"nodes\":[{\"mesh\":0,\"extensions\":{\"EXT_mesh_gpu_instancing\":{"
             "\"attributes\":{\"TRANSLATION\":%d}}}}],\"meshes\":[{\"primitives\":[{"
             "\"attributes\":{\"POSITION\":0},\"mode\":0}]}]",
             pt2);
    expect_fail(pts.json(pm), "inst_points", PT_ERR_FORMAT, "no triangles");
    expect_fail(instancing_file(n, false, "huge"), "inst_huge", PT_ERR_LIMIT,
                "EXT_mesh_gpu_instancing: 2147483648 instances (accessor 7), over the cap of "
                "4194304");
}

// Several material extensions on one material: every combination of the
// base's (iridescence, anisotropy, diffuse transmission) and the layers
// composes, with no warning; metallic-roughness extensions beside
// specular-glossiness are warned once, by name.
void test_combined_materials()
{
    struct {
        const char *ext, *want; // want: the warning's text, or nullptr for none
    } cases[] = {
        {"\"KHR_materials_iridescence\":{\"iridescenceFactor\":1},"
         "\"KHR_materials_anisotropy\":{\"anisotropyStrength\":0.5}",
         nullptr},
        {"\"KHR_materials_iridescence\":{\"iridescenceFactor\":1},"
         "\"KHR_materials_diffuse_transmission\":{\"diffuseTransmissionFactor\":0.5}",
         nullptr},
        {"\"KHR_materials_pbrSpecularGlossiness\":{},\"KHR_materials_clearcoat\":{"
         "\"clearcoatFactor\":1}",
         "KHR_materials_clearcoat beside KHR_materials_pbrSpecularGlossiness is ignored"},
        // Diffuse transmission with anisotropy, and every layer over them
        // with a specular colour.
        {"\"KHR_materials_diffuse_transmission\":{\"diffuseTransmissionFactor\":0.5},"
         "\"KHR_materials_anisotropy\":{\"anisotropyStrength\":0.5},"
         "\"KHR_materials_clearcoat\":{\"clearcoatFactor\":1},"
         "\"KHR_materials_sheen\":{\"sheenColorFactor\":[1,1,1]},"
         "\"KHR_materials_specular\":{\"specularColorFactor\":[1,0.5,0.5]}",
         nullptr},
        {"\"KHR_materials_iridescence\":{\"iridescenceFactor\":1},"
         "\"KHR_materials_transmission\":{\"transmissionFactor\":1},"
         "\"KHR_materials_clearcoat\":{\"clearcoatFactor\":1},"
         "\"KHR_materials_sheen\":{\"sheenColorFactor\":[1,1,1]}",
         nullptr},
    };
    for (const auto &c : cases) {
        std::string p = write_tmp(ext_file("", "", c.ext), "combined");
        loaded l;
        load(p, l);
        CHECKF(l.st == PT_OK, "%s", l.err.msg);
        if (c.want)
            CHECKF(count_of(l.warnings, c.want) == 1, "%s: warnings '%s'", c.want,
                   l.warnings.c_str());
        else
            CHECKF(l.nwarn == 0, "%s: warnings '%s'", c.ext, l.warnings.c_str());
        unlink(p.c_str());
    }
}

// ---- EXT_texture_webp and KHR_texture_basisu ------------------------------------------

std::vector<unsigned char> png_of(const unsigned char *rgba, int w, int h)
{
    std::vector<unsigned char> out;
    stbi_write_png_to_func(
        [](void *ctx, void *data, int size) {
            auto *o = static_cast<std::vector<unsigned char> *>(ctx);
            o->insert(o->end(), (unsigned char *)data, (unsigned char *)data + size);
        },
        &out, w, h, 4, rgba, w * 4);
    return out;
}

std::vector<unsigned char> webp_of(const unsigned char *rgba, int w, int h)
{
    uint8_t *enc = nullptr;
    size_t n = WebPEncodeLosslessRGBA(rgba, w, h, w * 4, &enc);
    std::vector<unsigned char> out(enc, enc + n);
    WebPFree(enc);
    return out;
}

// A triangle whose material's base colour is texture 0, with the given
// texture JSON and images (data: URIs).
std::string textured(const std::string &texture,
                     const std::vector<std::vector<unsigned char>> &imgs, const char *used)
{
    gltf g;
    g.floats(k_tri, "VEC3", 3);
    int uv = g.floats({0, 0, 1, 0, 0, 1}, "VEC2", 2);
    std::string images;
    for (size_t i = 0; i < imgs.size(); i++)
        images += std::string(i ? "," : "") + "{\"uri\":\"data:application/octet-stream;base64," +
                  pt_test::base64(imgs[i]) + "\"}";
    return g.json("\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":{"
                  "\"POSITION\":0,\"TEXCOORD_0\":" +
                  std::to_string(uv) +
                  "},\"material\":0}]}],\"materials\":[{\"pbrMetallicRoughness\":{"
                  "\"baseColorTexture\":{\"index\":0}}}],\"textures\":[" +
                  texture + "],\"images\":[" + images + "],\"extensionsUsed\":[" + used + "]");
}

void test_texture_formats()
{
    // 2x2: a WebP (lossless, so the texels come back exactly) and a PNG of
    // other colours, so the test sees which one was decoded.
    const unsigned char a[16] = {255, 0, 0, 255, 0, 255, 0, 128, 0, 0, 255, 255, 9, 99, 199, 7};
    const unsigned char b[16] = {1, 2, 3, 255, 4, 5, 6, 255, 7, 8, 9, 255, 10, 11, 12, 255};
    std::vector<unsigned char> wa = webp_of(a, 2, 2), pb = png_of(b, 2, 2);
    CHECK(wa.size() > 12 && pb.size() > 8);
    auto texels = [&](const std::string &text, const char *name, const unsigned char *want) {
        std::string p = write_tmp(text, name);
        loaded l;
        load(p, l);
        CHECKF(l.st == PT_OK && l.nwarn == 0, "%s: %s %s", name, l.err.msg, l.warnings.c_str());
        if (l.s) {
            CHECKF(l.s->num_textures == 1, "%s: %u textures", name, l.s->num_textures);
            if (l.s->num_textures == 1)
                CHECKF(l.s->textures[0].width == 2 && l.s->textures[0].height == 2 &&
                           memcmp(l.s->textures[0].rgba, want, 16) == 0,
                       "%s: other texels", name);
        }
        unlink(p.c_str());
    };
    // WebP alone, and WebP preferred over its PNG fallback.
    texels(textured("{\"extensions\":{\"EXT_texture_webp\":{\"source\":0}}}", {wa},
                    "\"EXT_texture_webp\""),
           "webp", a);
    // As a data:image/webp URI (tinygltf alone decodes no such MIME type).
    texels(replace_nth(textured("{\"extensions\":{\"EXT_texture_webp\":{\"source\":0}}}", {wa},
                                "\"EXT_texture_webp\""),
                       "data:application/octet-stream;base64,", "data:image/webp;base64,", 0),
           "webp_mime", a);
    texels(textured("{\"source\":1,\"extensions\":{\"EXT_texture_webp\":{\"source\":0}}}", {wa, pb},
                    "\"EXT_texture_webp\""),
           "webp_fallback", a);
    // KHR_texture_basisu: the PNG fallback is used; without one, refused
    // naming KTX2; a KTX2 file as the core source, the same.
    std::vector<unsigned char> ktx2 = {0xab, 'K',  'T',  'X',  ' ', '2', '0', 0xbb,
                                       '\r', '\n', 0x1a, '\n', 0,   0,   0,   0};
    texels(textured("{\"source\":1,\"extensions\":{\"KHR_texture_basisu\":{\"source\":0}}}",
                    {ktx2, pb}, "\"KHR_texture_basisu\""),
           "basisu_fallback", b);
    expect_fail(textured("{\"extensions\":{\"KHR_texture_basisu\":{\"source\":0}}}", {ktx2},
                         "\"KHR_texture_basisu\""),
                "basisu_only", PT_ERR_FORMAT, "its only image is KTX2 (KHR_texture_basisu)");
    expect_fail(textured("{\"source\":0}", {ktx2}, ""), "ktx2_core", PT_ERR_FORMAT,
                "image 0 is KTX2 (KHR_texture_basisu), which ptfarm cannot decode");
    // Hostile WebP: truncated, and a header that lies about its size.
    std::vector<unsigned char> cut(wa.begin(), wa.begin() + long(wa.size() / 2));
    expect_fail(textured("{\"extensions\":{\"EXT_texture_webp\":{\"source\":0}}}", {cut},
                         "\"EXT_texture_webp\""),
                "webp_cut", PT_ERR_FORMAT, "image 0 cannot be decoded: WebP:");
    std::vector<unsigned char> junk = {
        'R', 'I',  'F',  'F',  30,   0,    0, 0, 'W', 'E', 'B', 'P', 'V', 'P', '8', 'L', 10, 0, 0,
        0,   0x2f, 0xff, 0xff, 0xff, 0xff, 0, 0, 0,   0,   0,   0,   0,   0,   0,   0,   0,  0, 0};
    expect_fail(textured("{\"extensions\":{\"EXT_texture_webp\":{\"source\":0}}}", {junk},
                         "\"EXT_texture_webp\""),
                "webp_liar", PT_ERR_FORMAT, "image 0");
}

// ---- EXT_meshopt_compression ------------------------------------------------------------

// A 4 x 4 grid (16 vertices, 18 triangles) written twice: plainly, and with
// its positions (vertex codec, no filter), indices (index codec) and normals
// (vertex codec, OCTAHEDRAL filter, 8-bit) in EXT_meshopt_compression views
// over a fallback buffer that has no data. Positions are lossless:
// bit-identical; triangles the same, up to a rotation of their corners. Normals: the 8-bit
// octahedral encoding moves a unit vector by at most about 1.5 / 127 (two coordinates each rounded
// by half of 1/127, mapped through the octahedron, whose stretch is at most about 2): the test
// allows 0.02.
void test_meshopt()
{
    std::vector<float> pos, nrm4;
    for (int y = 0; y < 4; y++)
        for (int x = 0; x < 4; x++) {
            float z = 0.1f * float((x * 7 + y * 3) % 5);
            pos.insert(pos.end(), {float(x), float(y), z});
            float n[3] = {0.3f * float(x - 1), 0.2f * float(y - 2), 1.0f};
            float l = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
            nrm4.insert(nrm4.end(), {n[0] / l, n[1] / l, n[2] / l, 0.0f});
        }
    std::vector<uint16_t> idx;
    for (int y = 0; y < 3; y++)
        for (int x = 0; x < 3; x++) {
            uint16_t a = uint16_t(y * 4 + x), b = uint16_t(a + 1), c = uint16_t(a + 4),
                     d = uint16_t(a + 5);
            idx.insert(idx.end(), {a, b, d, a, d, c});
        }
    std::vector<float> nrm3;
    for (size_t i = 0; i < nrm4.size(); i += 4)
        nrm3.insert(nrm3.end(), {nrm4[i], nrm4[i + 1], nrm4[i + 2]});
    // The plain file.
    gltf g;
    int pa = g.floats(pos, "VEC3", 3), na = g.floats(nrm3, "VEC3", 3);
    int ia = g.add(idx.data(), idx.size() * 2, 5123, "SCALAR", idx.size());
    char m[300];
    snprintf(m, sizeof m,
             "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":{"
             "\"POSITION\":%d,\"NORMAL\":%d},\"indices\":%d}]}]",
             pa, na, ia);
    std::string plain = write_tmp(g.json(m), "meshopt_plain");
    // The compressed one.
    std::vector<int8_t> oct(nrm4.size());
    meshopt_encodeFilterOct(oct.data(), 16, 4, 8, nrm4.data());
    std::vector<unsigned char> vb(meshopt_encodeVertexBufferBound(16, 12));
    vb.resize(meshopt_encodeVertexBuffer(vb.data(), vb.size(), pos.data(), 16, 12));
    std::vector<unsigned char> nb(meshopt_encodeVertexBufferBound(16, 4));
    nb.resize(meshopt_encodeVertexBuffer(nb.data(), nb.size(), oct.data(), 16, 4));
    std::vector<unsigned char> ib(meshopt_encodeIndexBufferBound(idx.size(), 16));
    ib.resize(meshopt_encodeIndexBuffer(ib.data(), ib.size(), idx.data(), idx.size()));
    CHECK(vb.size() > 0 && nb.size() > 0 && ib.size() > 0);
    std::vector<unsigned char> packed;
    size_t offs[3];
    for (int k = 0; k < 3; k++) {
        const std::vector<unsigned char> &part = k == 0 ? vb : k == 1 ? nb : ib;
        while (packed.size() % 4)
            packed.push_back(0);
        offs[k] = packed.size();
        packed.insert(packed.end(), part.begin(), part.end());
    }
    auto view = [&](int k, size_t fb_off, size_t len, int stride, size_t count, const char *mode,
                    const char *filter, bool view_stride) {
        char v[400];
        snprintf(v, sizeof v,
                 "{\"buffer\":1,\"byteOffset\":%zu,\"byteLength\":%zu%s,\"extensions\":{"
                 "\"EXT_meshopt_compression\":{\"buffer\":0,\"byteOffset\":%zu,\"byteLength\":%"
                 "zu,\"byteStride\":%d,\"count\":%zu,\"mode\":\"%s\"%s%s%s}}}",
                 fb_off, len,
                 view_stride ? (",\"byteStride\":" + std::to_string(stride)).c_str() : "", offs[k],
                 k == 0   ? vb.size()
                 : k == 1 ? nb.size()
                          : ib.size(),
                 stride, count, mode, filter ? ",\"filter\":\"" : "", filter ? filter : "",
                 filter ? "\"" : "");
        return std::string(v);
    };
    auto compressed = [&](size_t ilen) {
        return "{\"asset\":{\"version\":\"2.0\"},\"scenes\":[{\"nodes\":[0]}],\"nodes\":[{"
               "\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0,"
               "\"NORMAL\":1},\"indices\":2}]}],\"extensionsUsed\":[\"EXT_meshopt_compression\","
               "\"KHR_mesh_quantization\"],\"extensionsRequired\":[\"EXT_meshopt_compression\","
               "\"KHR_mesh_quantization\"],\"buffers\":[{\"byteLength\":" +
               std::to_string(packed.size()) + ",\"uri\":\"data:application/octet-stream;base64," +
               pt_test::base64(packed) +
               "\"},{\"byteLength\":500,\"extensions\":{\"EXT_meshopt_compression\":{"
               "\"fallback\":true}}}],\"bufferViews\":[" +
               view(0, 0, 192, 12, 16, "ATTRIBUTES", nullptr, true) + "," +
               view(1, 192, 64, 4, 16, "ATTRIBUTES", "OCTAHEDRAL", true) + "," +
               view(2, 256, ilen, 2, idx.size(), "TRIANGLES", nullptr, false) +
               "],\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":16,"
               "\"type\":\"VEC3\"},{\"bufferView\":1,\"componentType\":5120,\"normalized\":"
               "true,\"count\":16,\"type\":\"VEC3\"},{\"bufferView\":2,\"componentType\":"
               "5123,\"count\":" +
               std::to_string(idx.size()) + ",\"type\":\"SCALAR\"}]}";
    };
    std::string comp = write_tmp(compressed(idx.size() * 2), "meshopt");
    loaded a, b;
    load(plain, a);
    load(comp, b);
    CHECKF(a.st == PT_OK && b.st == PT_OK, "%s / %s", a.err.msg, b.err.msg);
    CHECKF(b.nwarn == 0, "%s", b.warnings.c_str());
    if (a.s && b.s && a.s->num_vertices == b.s->num_vertices &&
        a.s->num_triangles == b.s->num_triangles) {
        CHECK(memcmp(a.s->positions, b.s->positions, 12 * size_t(a.s->num_vertices)) == 0);
        // The index codec keeps each triangle and its winding, but may
        // rotate its corners (meshoptimizer.h, meshopt_encodeIndexBuffer).
        int moved = 0;
        for (size_t t = 0; t < a.s->num_triangles; t++) {
            const uint32_t *x = a.s->indices + 3 * t, *y = b.s->indices + 3 * t;
            bool same = false;
            for (int r = 0; r < 3; r++)
                same = same || (x[0] == y[r] && x[1] == y[(r + 1) % 3] && x[2] == y[(r + 2) % 3]);
            moved += !same;
        }
        CHECKF(moved == 0, "%d triangles differ beyond a rotation of their corners", moved);
        double dn = 0;
        for (size_t i = 0; i < 3 * size_t(a.s->num_vertices); i++)
            dn = std::fmax(dn, std::fabs(double(a.s->normals[i]) - double(b.s->normals[i])));
        CHECKF(dn < 0.02 && dn > 0.0, "normals differ by %g", dn);
    } else {
        CHECK(0);
    }
    unlink(plain.c_str());
    unlink(comp.c_str());
    // Lies: a view whose byteLength is not count x byteStride; a stream cut
    // short (its byteLength halved).
    std::string bad = compressed(idx.size() * 2 + 2);
    expect_fail(bad, "meshopt_len", PT_ERR_FORMAT,
                "count x byteStride = 108, the view's byteLength 110");
    std::string cut =
        replace_nth(compressed(idx.size() * 2),
                    "\"byteLength\":" + std::to_string(ib.size()) + ",\"byteStride\":2",
                    "\"byteLength\":" + std::to_string(ib.size() / 2) + ",\"byteStride\":2", 0);
    expect_fail(cut, "meshopt_cut", PT_ERR_FORMAT,
                "EXT_meshopt_compression: the stream does not decode");
}

// ---- flat normals without NORMAL ---------------------------------------------------

// glTF 2.0 (3.7.2.1): "When normals are not specified, client
// implementations MUST calculate flat normals and the provided tangents
// (if present) MUST be ignored." Two triangles folded along a shared edge,
// indexed, without NORMAL (a welded mesh, as gltfpack writes the Fox): every
// corner's normal is its own face's, so the shared vertices are split;
// area-weighted vertex normals would blend the two faces there. As a still
// and posed by an animation (the rig, which must split them the same way).
void test_flat_normals()
{
    gltf g;
    int pa = g.floats({0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 1}, "VEC3", 3);
    const uint16_t idx[6] = {0, 1, 2, 1, 3, 2};
    int ia = g.add(idx, sizeof idx, 5123, "SCALAR", 6);
    int ta = g.accessor("{\"bufferView\":" + std::to_string(g.view((const float[2]){0, 1}, 8)) +
                        ",\"componentType\":5126,\"count\":2,\"type\":\"SCALAR\",\"min\":[0],"
                        "\"max\":[1]}");
    int oa = g.floats({0, 0, 0, 0, 0, 0}, "VEC3", 3);
    char m[600];
    snprintf(m, sizeof m,
             "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":{"
             "\"POSITION\":%d},\"indices\":%d}]}],\"animations\":[{\"channels\":[{\"sampler\":0,"
             "\"target\":{\"node\":0,\"path\":\"translation\"}}],\"samplers\":[{\"input\":%d,"
             "\"output\":%d}]}]",
             pa, ia, ta, oa);
    std::string path = write_tmp(g.json(m), "flat");
    const double s3 = 1.0 / std::sqrt(3.0);
    const double face[2][3] = {{0, 0, 1}, {-s3, -s3, s3}};
    for (int posed = 0; posed < 2; posed++) {
        pt_scene_opts o{};
        o.animate = posed;
        o.time = 0.5;
        pt_scene *s = nullptr;
        pt_error err{};
        CHECKF(pt_scene_load(path.c_str(), &o, &s, &err) == PT_OK, "%s", err.msg);
        if (!s)
            continue;
        CHECKF(s->num_vertices == 6 && s->num_triangles == 2, "%s: %u vertices",
               posed ? "posed" : "still", s->num_vertices);
        double worst = 0;
        for (uint32_t t = 0; t < s->num_triangles && s->num_vertices == 6; t++) {
            // Which face: the one whose normal the triangle's winding gives.
            const uint32_t *I = s->indices + 3 * t;
            const float *a = s->positions + 3 * I[0], *b = s->positions + 3 * I[1],
                        *c = s->positions + 3 * I[2];
            double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
            double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
            double x = e1[1] * e2[2] - e1[2] * e2[1];
            const double *f = x < -0.5 ? face[1] : face[0];
            for (int k = 0; k < 3; k++)
                for (int r = 0; r < 3; r++)
                    worst = std::fmax(worst, std::fabs(s->normals[3 * I[k] + r] - f[r]));
        }
        CHECKF(worst < 1e-6, "%s: a corner's normal is %g off its face's",
               posed ? "posed" : "still", worst);
        pt_scene_free(s);
    }
    unlink(path.c_str());
}

// ---- generated tangents, still and posed --------------------------------------------

// A normal-mapped 3 x 3 grid with bumps, NORMAL and TEXCOORD_0 but no
// TANGENT, under a node rotated and scaled (2, 0.5, 1), whose animation
// holds that scale. The still (no rig) generates the tangents in the mesh's
// space and maps them by the node; posed at 0.5 s the rig must give the
// same ones, not tangents generated anew from the posed, non-uniformly
// scaled positions.
void test_generated_tangents_posed()
{
    std::vector<float> pos, nrm, uv;
    for (int y = 0; y < 4; y++)
        for (int x = 0; x < 4; x++) {
            float z = 0.3f * float((x * 5 + y * 3) % 4);
            pos.insert(pos.end(), {float(x), float(y), z});
            float n[3] = {0.2f * float(x - 1), -0.15f * float(y - 2), 1.0f};
            float l = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
            nrm.insert(nrm.end(), {n[0] / l, n[1] / l, n[2] / l});
            uv.insert(uv.end(), {0.3f * float(x) + 0.05f * float(y), 0.25f * float(y)});
        }
    std::vector<uint16_t> idx;
    for (int y = 0; y < 3; y++)
        for (int x = 0; x < 3; x++) {
            uint16_t a = uint16_t(y * 4 + x), b = uint16_t(a + 1), c = uint16_t(a + 4),
                     d = uint16_t(a + 5);
            idx.insert(idx.end(), {a, b, d, a, d, c});
        }
    gltf g;
    int pa = g.floats(pos, "VEC3", 3), na = g.floats(nrm, "VEC3", 3), ua = g.floats(uv, "VEC2", 2);
    int ia = g.add(idx.data(), idx.size() * 2, 5123, "SCALAR", idx.size());
    const float key[2] = {0, 1};
    int ta = g.accessor("{\"bufferView\":" + std::to_string(g.view(key, 8)) +
                        ",\"componentType\":5126,\"count\":2,\"type\":\"SCALAR\",\"min\":[0],"
                        "\"max\":[1]}");
    int oa = g.floats({2, 0.5f, 1, 2, 0.5f, 1}, "VEC3", 3);
    const unsigned char px[16] = {128, 128, 255, 255, 200, 90,  230, 255,
                                  60,  160, 220, 255, 128, 128, 255, 255};
    std::vector<unsigned char> png = png_of(px, 2, 2);
    char m[1200];
    snprintf(m, sizeof m,
             "\"nodes\":[{\"mesh\":0,\"scale\":[2,0.5,1],\"rotation\":[0.2,0.3,0.1,0.927362]}],"
             "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":%d,\"NORMAL\":%d,"
             "\"TEXCOORD_0\":%d},\"indices\":%d,\"material\":0}]}],"
             "\"materials\":[{\"normalTexture\":{\"index\":0}}],\"textures\":[{\"source\":0}],"
             "\"images\":[{\"uri\":\"data:image/png;base64,%s\"}],"
             "\"animations\":[{\"channels\":[{\"sampler\":0,\"target\":{\"node\":0,"
             "\"path\":\"scale\"}}],\"samplers\":[{\"input\":%d,\"output\":%d,"
             "\"interpolation\":\"STEP\"}]}]",
             pa, na, ua, ia, pt_test::base64(png).c_str(), ta, oa);
    std::string path = write_tmp(g.json(m), "tangent_pose");
    pt_scene *s[2] = {nullptr, nullptr};
    for (int posed = 0; posed < 2; posed++) {
        pt_scene_opts o{};
        o.animate = posed;
        o.time = 0.5;
        pt_error err{};
        CHECKF(pt_scene_load(path.c_str(), &o, &s[posed], &err) == PT_OK, "%s", err.msg);
    }
    if (s[0] && s[1] && s[0]->tangents && s[1]->tangents &&
        s[0]->num_vertices == s[1]->num_vertices) {
        double worst = 0;
        int w_differ = 0;
        for (size_t v = 0; v < s[0]->num_vertices; v++) {
            for (int r = 0; r < 3; r++)
                worst = std::fmax(worst, std::fabs(double(s[0]->tangents[4 * v + r]) -
                                                   double(s[1]->tangents[4 * v + r])));
            w_differ += s[0]->tangents[4 * v + 3] != s[1]->tangents[4 * v + 3];
        }
        // Both map the same float tangents through the node's matrix in
        // double; the pose's matrix comes from its TRS keys, the still's
        // from the node's, each rounded: a few float ULPs of a unit vector.
        CHECKF(worst < 1e-6 && w_differ == 0,
               "posed tangents differ from the still's by %g, %d handedness", worst, w_differ);
    } else {
        CHECKF(0, "no tangents to compare");
    }
    pt_scene_free(s[0]);
    pt_scene_free(s[1]);
    unlink(path.c_str());
}

} // namespace

int main(void)
{
    test_extensions();
    test_quantization();
    test_sparse();
    test_morph_default_weights();
    test_draco();
    test_draco_hostile();
    test_instancing();
    test_instances_vs_copies();
    test_combined_materials();
    test_texture_formats();
    test_meshopt();
    test_flat_normals();
    test_generated_tangents_posed();
    return check_report();
}
