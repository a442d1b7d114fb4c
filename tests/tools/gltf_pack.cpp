// ptgltf-pack MODE IN.(gltf|glb) OUT.glb [--sequence] [--filter] [--corrupt]
//     [--scale-error F]
//
// Writes a compressed or quantized variant of a sample asset, as gltfpack
// would, so that tests can render it against the original (gltfpack is not
// packaged in Debian). Every accessor of a mesh primitive (attributes,
// morph targets and indices) gets a buffer view of its own; the other views (images,
// animations, skins) are copied as they are; the output is one GLB.
//
// MODE meshopt (EXT_meshopt_compression, lossless, no filter): each
// attribute view coded with meshopt_encodeVertexBuffer (mode ATTRIBUTES,
// byteStride the element size rounded up to 4), each 16- or 32-bit
// triangle-list index view with meshopt_encodeIndexBuffer (mode TRIANGLES),
// or with meshopt_encodeIndexSequence (mode INDICES) under --sequence. The
// codec of TRIANGLES keeps every triangle and its winding but may rotate its
// corners (meshoptimizer.h); INDICES keeps the order. The views point into
// a fallback buffer without data ("fallback": true), the compressed bytes
// are in the GLB's buffer, the extension is in extensionsUsed and
// extensionsRequired (the extension's README). --corrupt flips one bit in
// the middle of the first attribute stream.
//
// MODE quantize (KHR_mesh_quantization; the types its README allows):
// - POSITION: SHORT (not normalized), per mesh (meshes that share a POSITION
//   accessor: per group) q = round((p - c) / s) with c the centre of the
//   bounds and s = half the largest extent / 32767,
//   so |q| <= 32767; the dequantization c + s q is the matrix of a new child
//   node that carries the mesh (uniform scale: normals stay normals);
//   --scale-error F writes s F there instead, a deliberately wrong decoder;
// - NORMAL: BYTE normalized (round(127 n)), TANGENT: BYTE normalized xyzw;
// - TEXCOORD_n: UNSIGNED_SHORT normalized; when the file's coordinates leave
//   [0, 1], q = round(65535 (uv - lo) / (hi - lo)) over the file's bounds
//   and every texture reference gets KHR_texture_transform offset lo,
//   scale hi - lo (composed with its own transform, which must not rotate);
// - other attributes and indices as they are. Skins, morph targets and
//   instanced nodes are refused (exit 2).
// Both modes refuse sparse accessors and Draco primitives.
//
// MODE quantize+meshopt: both, as gltfpack writes by default (-c): the
// quantized views then coded as in meshopt; with --filter the normals go
// through meshoptimizer's OCTAHEDRAL filter (8 bits, as gltfpack -cc)
// instead of being rounded to BYTE.
//
// Exit 0 when written, 2 with a message otherwise. A test tool: it trusts
// the sample assets' structure (checked, not hardened like the importer).
#include <meshoptimizer.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

namespace
{

using json = nlohmann::json;
using bytes = std::vector<unsigned char>;

[[noreturn]] void die(const std::string &msg)
{
    throw std::runtime_error(msg);
}

bytes read_file(const std::string &path)
{
    FILE *f = fopen(path.c_str(), "rb");
    if (!f)
        die(path + ": cannot open");
    bytes b;
    unsigned char chunk[65536];
    size_t n;
    while ((n = fread(chunk, 1, sizeof chunk, f)) > 0)
        b.insert(b.end(), chunk, chunk + n);
    fclose(f);
    return b;
}

uint32_t le32(const bytes &b, size_t at)
{
    if (at + 4 > b.size())
        die("truncated GLB");
    return uint32_t(b[at]) | uint32_t(b[at + 1]) << 8 | uint32_t(b[at + 2]) << 16 |
           uint32_t(b[at + 3]) << 24;
}

void put32(bytes &b, uint32_t v)
{
    for (int k = 0; k < 4; k++)
        b.push_back(uint8_t(v >> (8 * k)));
}

// The document and its buffers' bytes (a GLB's BIN chunk, or the files a
// .gltf names beside it).
void load(const std::string &path, json &doc, std::vector<bytes> &bufs)
{
    bytes raw = read_file(path);
    if (raw.size() >= 12 && le32(raw, 0) == 0x46546C67) {
        uint32_t jl = le32(raw, 12);
        if (20 + size_t(jl) > raw.size())
            die(path + ": truncated JSON chunk");
        doc = json::parse(raw.begin() + 20, raw.begin() + 20 + jl);
        size_t at = 20 + size_t(jl);
        if (at + 8 <= raw.size()) {
            uint32_t bl = le32(raw, at);
            if (at + 8 + bl > raw.size())
                die(path + ": truncated BIN chunk");
            bufs.emplace_back(raw.begin() + long(at) + 8, raw.begin() + long(at) + 8 + bl);
        }
        return;
    }
    doc = json::parse(raw.begin(), raw.end());
    std::string dir = path.substr(0, path.find_last_of('/') + 1);
    for (auto &b : doc["buffers"]) {
        std::string uri = b.value("uri", "");
        if (uri.empty() || uri.rfind("data:", 0) == 0 || uri.find("..") != std::string::npos)
            die(path + ": buffer uri '" + uri + "' is not a file beside it");
        bufs.push_back(read_file(dir + uri));
    }
}

int comp_size(int ctype)
{
    switch (ctype) {
    case 5120:
    case 5121:
        return 1;
    case 5122:
    case 5123:
        return 2;
    case 5125:
    case 5126:
        return 4;
    }
    die("component type " + std::to_string(ctype));
}

int type_count(const std::string &t)
{
    static const std::map<std::string, int> n = {{"SCALAR", 1}, {"VEC2", 2}, {"VEC3", 3},
                                                 {"VEC4", 4},   {"MAT2", 4}, {"MAT3", 9},
                                                 {"MAT4", 16}};
    auto it = n.find(t);
    if (it == n.end())
        die("accessor type " + t);
    return it->second;
}

struct packer {
    json doc;
    std::vector<bytes> in;
    bytes out;           // the GLB's buffer
    size_t fallback = 0; // bytes of the meshopt fallback buffer
    json views = json::array();
    bool meshopt = false, quantize = false, sequence = false, corrupt = false, corrupted = false;
    bool octahedral = false;           // --filter: normals through the OCTAHEDRAL filter
    const char *next_filter = nullptr; // the filter of the view being written
    double scale_error = 1.0;

    size_t append(const void *p, size_t n)
    {
        while (out.size() % 4)
            out.push_back(0);
        size_t at = out.size();
        out.insert(out.end(), (const unsigned char *)p, (const unsigned char *)p + n);
        return at;
    }

    // An accessor's elements, tightly packed (elem bytes each).
    bytes elements(const json &a, size_t &elem)
    {
        if (a.contains("sparse") || !a.contains("bufferView"))
            die("sparse accessors and accessors without a view are not handled");
        const json &v = doc["bufferViews"][a["bufferView"].get<size_t>()];
        elem = size_t(comp_size(a["componentType"])) * size_t(type_count(a["type"]));
        size_t count = a["count"], stride = v.value("byteStride", elem);
        size_t off = v.value("byteOffset", size_t(0)) + a.value("byteOffset", size_t(0));
        const bytes &b = in.at(v["buffer"].get<size_t>());
        if (count && off + (count - 1) * stride + elem > b.size())
            die("accessor out of its buffer");
        bytes e(count * elem);
        for (size_t i = 0; i < count; i++)
            memcpy(&e[i * elem], &b[off + i * stride], elem);
        return e;
    }

    // A new view over data (count elements of stride bytes); vertex data
    // gets byteStride. Compressed with meshopt when asked.
    int view(const bytes &data, size_t count, size_t stride, bool vertex, bool triangles)
    {
        json v;
        if (!meshopt || (!vertex && stride != 2 && stride != 4)) {
            v = {{"buffer", 0},
                 {"byteOffset", append(data.data(), data.size())},
                 {"byteLength", data.size()}};
        } else {
            bytes enc;
            std::string mode = "ATTRIBUTES";
            if (vertex) {
                enc.resize(meshopt_encodeVertexBufferBound(count, stride));
                enc.resize(
                    meshopt_encodeVertexBuffer(enc.data(), enc.size(), data.data(), count, stride));
                if (corrupt && !corrupted) {
                    enc[enc.size() / 2] ^= 0x10;
                    corrupted = true;
                }
            } else {
                std::vector<uint32_t> idx(count);
                for (size_t i = 0; i < count; i++)
                    idx[i] = stride == 2 ? uint32_t(data[2 * i] | data[2 * i + 1] << 8)
                                         : uint32_t(data[4 * i]) | uint32_t(data[4 * i + 1]) << 8 |
                                               uint32_t(data[4 * i + 2]) << 16 |
                                               uint32_t(data[4 * i + 3]) << 24;
                uint32_t hi = 0;
                for (uint32_t x : idx)
                    hi = x > hi ? x : hi;
                if (triangles && !sequence) {
                    mode = "TRIANGLES";
                    enc.resize(meshopt_encodeIndexBufferBound(count, size_t(hi) + 1));
                    enc.resize(
                        meshopt_encodeIndexBuffer(enc.data(), enc.size(), idx.data(), count));
                } else {
                    mode = "INDICES";
                    enc.resize(meshopt_encodeIndexSequenceBound(count, size_t(hi) + 1));
                    enc.resize(
                        meshopt_encodeIndexSequence(enc.data(), enc.size(), idx.data(), count));
                }
            }
            if (enc.empty())
                die("meshoptimizer could not encode a view");
            while (fallback % 4)
                fallback++;
            v = {{"buffer", 1},
                 {"byteOffset", fallback},
                 {"byteLength", data.size()},
                 {"extensions",
                  {{"EXT_meshopt_compression",
                    {{"buffer", 0},
                     {"byteOffset", append(enc.data(), enc.size())},
                     {"byteLength", enc.size()},
                     {"byteStride", stride},
                     {"count", count},
                     {"mode", mode}}}}}};
            if (next_filter)
                v["extensions"]["EXT_meshopt_compression"]["filter"] = next_filter;
            fallback += data.size();
        }
        if (vertex)
            v["byteStride"] = stride;
        views.push_back(v);
        return int(views.size() - 1);
    }

    // An attribute as it is, each element padded to 4 bytes.
    void copy_attribute(json &a)
    {
        size_t elem;
        bytes e = elements(a, elem);
        size_t count = a["count"], stride = (elem + 3) / 4 * 4;
        bytes p(count * stride);
        for (size_t i = 0; i < count; i++)
            memcpy(&p[i * stride], &e[i * elem], elem);
        a["bufferView"] = view(p, count, stride, true, false);
        a.erase("byteOffset");
    }

    std::vector<float> floats(const json &a, int n)
    {
        if (a["componentType"] != 5126 || type_count(a["type"]) != n)
            die("expected float attributes");
        size_t elem;
        bytes e = elements(a, elem);
        std::vector<float> f(e.size() / 4);
        memcpy(f.data(), e.data(), e.size());
        return f;
    }

    // Normalized signed bytes, 4 per element (the 4th 0 for VEC3).
    void quantize_unit(json &a, int n)
    {
        std::vector<float> f = floats(a, n);
        size_t count = a["count"];
        bytes p(count * 4, 0);
        for (size_t i = 0; i < count; i++)
            for (int k = 0; k < n; k++) {
                double q = std::round(127.0 * std::fmax(-1.0, std::fmin(1.0, f[i * n + k])));
                p[i * 4 + k] = uint8_t(int8_t(q));
            }
        if (octahedral && meshopt && n == 3) {
            // The filter's input: unit vectors as 4 floats (meshoptimizer.h,
            // meshopt_encodeFilterOct); its output decodes to 8-bit snorm.
            std::vector<float> f4(count * 4, 0.0f);
            for (size_t i = 0; i < count; i++)
                for (int k = 0; k < 3; k++)
                    f4[i * 4 + size_t(k)] = f[i * 3 + size_t(k)];
            meshopt_encodeFilterOct(p.data(), count, 4, 8, f4.data());
            next_filter = "OCTAHEDRAL";
        }
        a["componentType"] = 5120;
        a["normalized"] = true;
        a.erase("min");
        a.erase("max");
        a["bufferView"] = view(p, count, 4, true, false);
        next_filter = nullptr;
        a.erase("byteOffset");
    }

    void quantize_position(json &a, const double c[3], double s)
    {
        std::vector<float> f = floats(a, 3);
        size_t count = a["count"];
        bytes p(count * 8, 0);
        int lo[3] = {32767, 32767, 32767}, hi[3] = {-32767, -32767, -32767};
        for (size_t i = 0; i < count; i++)
            for (int k = 0; k < 3; k++) {
                double q = std::round((double(f[i * 3 + k]) - c[k]) / s);
                int qi = int(std::fmax(-32767.0, std::fmin(32767.0, q)));
                lo[k] = qi < lo[k] ? qi : lo[k];
                hi[k] = qi > hi[k] ? qi : hi[k];
                uint16_t u = uint16_t(int16_t(qi));
                p[i * 8 + 2 * k] = uint8_t(u);
                p[i * 8 + 2 * k + 1] = uint8_t(u >> 8);
            }
        a["componentType"] = 5122;
        a["min"] = {lo[0], lo[1], lo[2]};
        a["max"] = {hi[0], hi[1], hi[2]};
        a["bufferView"] = view(p, count, 8, true, false);
        a.erase("byteOffset");
    }

    void quantize_uv(json &a, const double lo[2], const double span[2])
    {
        std::vector<float> f = floats(a, 2);
        size_t count = a["count"];
        bytes p(count * 4, 0);
        for (size_t i = 0; i < count; i++)
            for (int k = 0; k < 2; k++) {
                double t = (double(f[i * 2 + k]) - lo[k]) / span[k];
                uint16_t u = uint16_t(std::round(65535.0 * std::fmax(0.0, std::fmin(1.0, t))));
                p[i * 4 + 2 * k] = uint8_t(u);
                p[i * 4 + 2 * k + 1] = uint8_t(u >> 8);
            }
        a["componentType"] = 5123;
        a["normalized"] = true;
        a.erase("min");
        a.erase("max");
        a["bufferView"] = view(p, count, 4, true, false);
        a.erase("byteOffset");
    }

    void add_extension(const char *name, bool required)
    {
        for (const char *list : {"extensionsUsed", "extensionsRequired"}) {
            if (!required && strcmp(list, "extensionsRequired") == 0)
                continue;
            json &l = doc[list];
            if (l.is_null())
                l = json::array();
            bool has = false;
            for (auto &e : l)
                has = has || e == name;
            if (!has)
                l.push_back(name);
        }
    }

    // Every textureInfo in a material (any object with an "index" under a
    // key ending in "Texture").
    static void texture_infos(json &j, std::vector<json *> &out)
    {
        if (j.is_object()) {
            for (auto it = j.begin(); it != j.end(); ++it) {
                const std::string &k = it.key();
                if (k.size() >= 7 && k.compare(k.size() - 7, 7, "Texture") == 0 &&
                    it.value().is_object() && it.value().contains("index"))
                    out.push_back(&it.value());
                else
                    texture_infos(it.value(), out);
            }
        } else if (j.is_array()) {
            for (auto &e : j)
                texture_infos(e, out);
        }
    }

    void run()
    {
        json &acc = doc["accessors"];
        if (quantize && doc.contains("skins"))
            die("skins are not handled by quantize");
        // Accessors of the meshes, by role; which views they use.
        std::map<size_t, std::string> role; // accessor -> attribute or "indices"
        std::map<size_t, int> mesh_of;      // POSITION accessor -> mesh
        // Meshes that share a POSITION accessor share a frame: each mesh's
        // group, by union-find.
        std::vector<int> group(doc["meshes"].size());
        for (size_t i = 0; i < group.size(); i++)
            group[i] = int(i);
        auto root = [&](int m) {
            while (group[size_t(m)] != m)
                m = group[size_t(m)] = group[size_t(group[size_t(m)])];
            return m;
        };
        std::set<size_t> mesh_views;
        for (size_t mi = 0; mi < doc["meshes"].size(); mi++)
            for (auto &pr : doc["meshes"][mi]["primitives"]) {
                if (pr.contains("targets")) {
                    if (quantize)
                        die("morph targets are not handled by quantize");
                    for (auto &t : pr["targets"])
                        for (auto it = t.begin(); it != t.end(); ++it) {
                            size_t ai = it.value();
                            std::string k = "target " + it.key();
                            if (role.count(ai) && role[ai] != k)
                                die("an accessor used as two attributes");
                            role[ai] = k;
                        }
                }
                if (pr.contains("extensions") &&
                    pr["extensions"].contains("KHR_draco_mesh_compression"))
                    die("Draco primitives are not handled");
                for (auto it = pr["attributes"].begin(); it != pr["attributes"].end(); ++it) {
                    size_t ai = it.value();
                    if (role.count(ai) && role[ai] != it.key())
                        die("an accessor used as two attributes");
                    role[ai] = it.key();
                    if (it.key() == "POSITION") {
                        if (mesh_of.count(ai))
                            group[size_t(root(int(mi)))] = root(mesh_of[ai]);
                        else
                            mesh_of[ai] = int(mi);
                    }
                }
                if (pr.contains("indices")) {
                    size_t ai = pr["indices"];
                    role[ai] = pr.value("mode", 4) == 4 ? "indices" : "other indices";
                }
            }
        for (auto &r : role)
            if (acc[r.first].contains("bufferView"))
                mesh_views.insert(acc[r.first]["bufferView"].get<size_t>());
        // The other views, copied (a view used by a mesh and by something
        // else too is copied as well).
        std::map<size_t, size_t> keep;
        auto used_elsewhere = [&](size_t vi) {
            for (size_t ai = 0; ai < acc.size(); ai++)
                if (!role.count(ai) && acc[ai].value("bufferView", size_t(-1)) == vi)
                    return true;
            for (auto &img : doc["images"])
                if (img.value("bufferView", size_t(-1)) == vi)
                    return true;
            return false;
        };
        for (size_t vi = 0; vi < doc["bufferViews"].size(); vi++) {
            if (mesh_views.count(vi) && !used_elsewhere(vi))
                continue;
            json v = doc["bufferViews"][vi];
            const bytes &b = in.at(v["buffer"].get<size_t>());
            size_t off = v.value("byteOffset", size_t(0)), len = v["byteLength"];
            if (off + len > b.size())
                die("bufferView " + std::to_string(vi) + " out of its buffer");
            v["buffer"] = 0;
            v["byteOffset"] = append(&b[off], len);
            keep[vi] = views.size();
            views.push_back(v);
        }
        for (size_t ai = 0; ai < acc.size(); ai++)
            if (!role.count(ai) && acc[ai].contains("bufferView"))
                acc[ai]["bufferView"] = keep.at(acc[ai]["bufferView"].get<size_t>());
        for (auto &img : doc["images"])
            if (img.contains("bufferView"))
                img["bufferView"] = keep.at(img["bufferView"].get<size_t>());

        // Quantization's per-mesh position frames and the file's UV frame.
        std::map<int, std::vector<double>> frame; // mesh -> cx, cy, cz, s
        double uv_lo[2] = {1e300, 1e300}, uv_hi[2] = {-1e300, -1e300};
        if (quantize) {
            std::map<int, std::vector<double>> box;
            for (auto &r : role) {
                if (r.second == "POSITION") {
                    std::vector<float> f = floats(acc[r.first], 3);
                    auto &b = box[root(mesh_of[r.first])];
                    if (b.empty())
                        b = {1e300, 1e300, 1e300, -1e300, -1e300, -1e300};
                    for (size_t i = 0; i < f.size(); i++) {
                        b[i % 3] = std::fmin(b[i % 3], f[i]);
                        b[3 + i % 3] = std::fmax(b[3 + i % 3], f[i]);
                    }
                } else if (r.second.rfind("TEXCOORD_", 0) == 0) {
                    std::vector<float> f = floats(acc[r.first], 2);
                    for (size_t i = 0; i < f.size(); i++) {
                        uv_lo[i % 2] = std::fmin(uv_lo[i % 2], f[i]);
                        uv_hi[i % 2] = std::fmax(uv_hi[i % 2], f[i]);
                    }
                }
            }
            for (auto &b : box) {
                double h = 0;
                for (int k = 0; k < 3; k++)
                    h = std::fmax(h, 0.5 * (b.second[3 + k] - b.second[k]));
                frame[b.first] = {0.5 * (b.second[0] + b.second[3]),
                                  0.5 * (b.second[1] + b.second[4]),
                                  0.5 * (b.second[2] + b.second[5]), h > 0 ? h / 32767.0 : 1.0};
            }
        }
        bool uv_unit = uv_lo[0] >= 0 && uv_lo[1] >= 0 && uv_hi[0] <= 1 && uv_hi[1] <= 1;
        double lo[2] = {0, 0}, span[2] = {1, 1};
        if (!uv_unit)
            for (int k = 0; k < 2; k++) {
                lo[k] = uv_lo[k];
                span[k] = uv_hi[k] > uv_lo[k] ? uv_hi[k] - uv_lo[k] : 1.0;
            }

        // The mesh accessors, each into a view of its own.
        for (auto &r : role) {
            json &a = acc[r.first];
            const std::string &k = r.second;
            if (k == "indices" || k == "other indices") {
                size_t elem;
                bytes e = elements(a, elem);
                size_t count = a["count"];
                a["bufferView"] = view(e, count, elem, false, k == "indices" && count % 3 == 0);
                a.erase("byteOffset");
            } else if (!quantize) {
                copy_attribute(a);
            } else if (k == "POSITION") {
                const auto &f = frame[root(mesh_of[r.first])];
                quantize_position(a, f.data(), f[3]);
            } else if (k == "NORMAL") {
                quantize_unit(a, 3);
            } else if (k == "TANGENT") {
                quantize_unit(a, 4);
            } else if (k.rfind("TEXCOORD_", 0) == 0) {
                quantize_uv(a, lo, span);
            } else {
                copy_attribute(a);
            }
        }

        if (quantize) {
            // Dequantization of positions: a child node per mesh node.
            json &nodes = doc["nodes"];
            size_t n0 = nodes.size();
            for (size_t ni = 0; ni < n0; ni++) {
                if (!nodes[ni].contains("mesh"))
                    continue;
                if (nodes[ni].contains("extensions") &&
                    nodes[ni]["extensions"].contains("EXT_mesh_gpu_instancing"))
                    die("instanced nodes are not handled");
                int mi = nodes[ni]["mesh"];
                if (!frame.count(root(mi)))
                    continue;
                const auto &f = frame[root(mi)];
                double s = f[3] * scale_error;
                json child = {
                    {"mesh", mi},
                    {"matrix", {s, 0, 0, 0, 0, s, 0, 0, 0, 0, s, 0, f[0], f[1], f[2], 1}}};
                nodes[ni].erase("mesh");
                nodes[ni]["children"].push_back(nodes.size());
                nodes.push_back(child);
            }
            if (!uv_unit) {
                for (auto &m : doc["materials"]) {
                    std::vector<json *> infos;
                    texture_infos(m, infos);
                    for (json *t : infos) {
                        json &x = (*t)["extensions"]["KHR_texture_transform"];
                        if (x.is_null())
                            x = json::object();
                        if (x.value("rotation", 0.0) != 0.0)
                            die("a rotated texture transform is not handled");
                        // uv' = o + sc uv and uv = lo + span q: o + sc lo + sc span q.
                        json o = x.value("offset", json::array({0.0, 0.0}));
                        json sc = x.value("scale", json::array({1.0, 1.0}));
                        double ox = o[0], oy = o[1], sx = sc[0], sy = sc[1];
                        x["offset"] = {ox + sx * lo[0], oy + sy * lo[1]};
                        x["scale"] = {sx * span[0], sy * span[1]};
                    }
                }
                add_extension("KHR_texture_transform", false);
            }
            add_extension("KHR_mesh_quantization", true);
        }
        if (meshopt)
            add_extension("EXT_meshopt_compression", true);
        doc["bufferViews"] = views;
        json buffers = json::array();
        buffers.push_back({{"byteLength", out.size()}});
        if (meshopt)
            buffers.push_back(
                {{"byteLength", fallback},
                 {"extensions", {{"EXT_meshopt_compression", {{"fallback", true}}}}}});
        doc["buffers"] = buffers;
    }

    void write(const std::string &path)
    {
        std::string j = doc.dump();
        while (j.size() % 4)
            j += ' ';
        while (out.size() % 4)
            out.push_back(0);
        bytes g;
        put32(g, 0x46546C67);
        put32(g, 2);
        put32(g, uint32_t(12 + 8 + j.size() + 8 + out.size()));
        put32(g, uint32_t(j.size()));
        put32(g, 0x4E4F534A);
        g.insert(g.end(), j.begin(), j.end());
        put32(g, uint32_t(out.size()));
        put32(g, 0x004E4942);
        g.insert(g.end(), out.begin(), out.end());
        FILE *f = fopen(path.c_str(), "wb");
        if (!f || fwrite(g.data(), 1, g.size(), f) != g.size() || fclose(f) != 0)
            die(path + ": cannot write");
    }
};

} // namespace

int main(int argc, char **argv)
{
    if (argc < 4) {
        fprintf(stderr,
                "usage: ptgltf-pack meshopt|quantize|quantize+meshopt IN.(gltf|glb) OUT.glb "
                "[--sequence] [--filter] [--corrupt] [--scale-error F]\n");
        return 2;
    }
    try {
        packer p;
        std::string mode = argv[1];
        if (mode != "meshopt" && mode != "quantize" && mode != "quantize+meshopt")
            die("mode '" + mode + "': meshopt, quantize or quantize+meshopt");
        p.meshopt = mode != "quantize";
        p.quantize = mode != "meshopt";
        for (int i = 4; i < argc; i++) {
            if (strcmp(argv[i], "--filter") == 0)
                p.octahedral = true;
            else if (strcmp(argv[i], "--sequence") == 0)
                p.sequence = true;
            else if (strcmp(argv[i], "--corrupt") == 0)
                p.corrupt = true;
            else if (strcmp(argv[i], "--scale-error") == 0 && i + 1 < argc)
                p.scale_error = atof(argv[++i]);
            else
                die(std::string("unknown option ") + argv[i]);
        }
        load(argv[2], p.doc, p.in);
        p.run();
        p.write(argv[3]);
    } catch (const std::exception &e) {
        fprintf(stderr, "ptgltf-pack: %s\n", e.what());
        return 2;
    }
    return 0;
}
