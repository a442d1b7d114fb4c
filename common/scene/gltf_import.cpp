// gltf_import.cpp - pt_scene_load: glTF 2.0 (.gltf and .glb) to a pt_scene,
// through tinygltf for the JSON and GLB containers.
//
// tinygltf parses; everything it hands back is treated as untrusted. Every
// accessor read is bounds-checked here (glTF 2.0 spec, 3.6.2 "Accessors" and
// 3.6.2.4 "Data Alignment": offset + stride * (count - 1) + element size must
// lie within the buffer view, and the view within its buffer), with
// overflow-checked arithmetic; every index into a glTF array (nodes, meshes,
// accessors, textures, images, cameras) is checked before use. Geometry goes
// through pt_scene_builder, which validates coordinates and indices again.
//
// Images: tinygltf is told not to decode anything (a loader callback that
// only keeps data: URI bytes) and not to read external images; the importer
// decodes, with stb_image from the system's libstb, only the images that a
// material actually uses as base colour, metal-rough, emissive or
// transmission texture, to RGBA8 (1-4 channels and 16-bit data are converted
// by stb_image). Every such image's size is read from its header and checked
// against PT_SCENE_MAX_IMAGE_TEXELS and, summed, PT_SCENE_MAX_TEXELS before
// the first one is decoded; the meshes' triangles, every instance counted,
// are checked against PT_SCENE_MAX_TRIANGLES before that (check_triangles).
//
// Materials follow the core metallic-roughness model (spec 3.9.2) with
// KHR_materials_emissive_strength, KHR_materials_specular (its textures
// too) and glass (KHR_materials_transmission, _ior, _volume:
// add_transmission), or instead of it KHR_materials_pbrSpecularGlossiness
// (add_spec_gloss) or KHR_materials_unlit, and KHR_materials_iridescence
// (add_iridescence), KHR_materials_anisotropy (add_anisotropy) and
// KHR_materials_diffuse_transmission (add_diffuse_transmission), and
// KHR_materials_dispersion's factor; what the renderer does not support is
// reported once per kind through opts->warn.
// KHR_lights_punctual lights become pt_punctual lights (scene.h: units).
// KHR_materials_variants: with opts->variant naming one of the root's
// variants, a primitive whose mappings list that variant uses the mapped
// material instead of its own (choose_variant, variant_material); without
// one the extension is not read at all, so nothing changes.
//
// External files: every buffer and image URI is a name below the entry
// file's folder and nothing else (pt_uri_path_refusal: no absolute path, no
// "..", no backslash, no NUL), read by pt_read_file_beneath from that
// folder's descriptor, which refuses a symbolic link anywhere on the way and
// anything but a regular file, and checks the size cap before reading.
// tinygltf reads buffers through FsCallbacks that go there too, and is given
// no base folder, so its messages name the URI, never a path of this machine.
// The coordinator loads scenes that clients send (server/api/upload.c), so this
// is what keeps a client from making it open a file of its choosing.
//
// scene->hash: SHA-256 of the entry file's bytes, then each external
// buffer and image file in the order of the JSON arrays (a data: URI or a GLB
// chunk is already inside the entry file).

#define TINYGLTF_IMPLEMENTATION
#define TINYGLTF_NO_STB_IMAGE_WRITE
#define TINYGLTF_NO_EXTERNAL_IMAGE
// stb_image's implementation lives in libstb.so; tinygltf only includes the
// header (STB_IMAGE_IMPLEMENTATION is deliberately left undefined).
#include <tiny_gltf.h>

#include <nlohmann/json.hpp>

#include <stb_image.h>

#include <openssl/evp.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <dirent.h>
#include <fcntl.h>
#include <fstream>
#include <map>
#include <memory>
#include <new>
#include <set>
#include <string>
#include <sys/stat.h>
#include <unistd.h>
#include <vector>

#include "common/scene/anim_rig.hpp"

extern "C" {
#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/base/hash.h"
#include "common/base/json.h"
#include "common/scene/anim.h"
#include "common/scene/draco.h"
#include "common/scene/gltf_import.h"
#include "common/scene/meshopt.h"
#include "common/scene/motion.h"
#include "common/scene/scene.h"
#include "common/scene/uri.h"
#include "common/scene/webp.h"
}

namespace
{

const uint64_t kMaxFileBytes = 1ull << 30; // tinygltf takes an unsigned int length
const int kMaxNodeDepth = 128;
const uint64_t kMaxNodeVisits = 1u << 22;

// A failure that already carries its pt_error; thrown to unwind the importer.
struct load_failure {
    pt_status st;
};

struct importer {
    std::string path; // as given, for messages
    std::string base; // folder of the entry file, for relative URIs
    const pt_scene_opts *opts;
    pt_error *err;
    tinygltf::Model model;
    pt_scene_builder *b = nullptr;
    std::set<std::string> warned;
    std::vector<std::vector<unsigned char>> data_uri_images; // by image index
    std::map<std::string, std::vector<unsigned char>> files; // external files read for the hash
    std::map<std::pair<int, int>, uint32_t> tex_map;         // (gltf texture, srgb) -> builder
    std::map<int, std::vector<unsigned char>> dense;   // accessor -> its elements, made dense once
    std::map<std::pair<int, int>, int> draco_indices;  // (mesh, primitive) -> indices set aside
    std::set<std::pair<int, int>> draco_done;          // primitives decoded into dense
    std::map<int, std::vector<unsigned char>> meshopt; // buffer view -> its decoded bytes
    uint32_t default_material = UINT32_MAX;
    int variant = -1; // KHR_materials_variants index chosen by opts->variant; -1: none
    uint64_t node_visits = 0;
    uint64_t texels = 0;       // decoded so far, summed over the textures (PT_SCENE_MAX_TEXELS)
    bool headers_only = false; // read_materials: images' headers only, nothing built
    int dirfd = -1;            // the entry file's folder, opened on first use
    pt_anim *rig = nullptr;    // pt_anim_load: the rig being read (anim.h); else nullptr
    bool still = false;        // the rig poses a still: no animation, time 0 (load_still)
    pt_status fs_st = PT_OK;   // the first failure of a read tinygltf asked for
    std::string fs_msg;        // and its message (names the URI only)
    // EXT_mesh_gpu_instancing kept as instances (gpu_instanced): the visits
    // of such nodes, placed once the flat meshes are all added.
    struct instanced_visit {
        int node;
        std::array<double, 16> world;
    };
    std::vector<instanced_visit> instanced;
    std::vector<char> gpu_instanced; // per node: its instances are kept as instances

    importer() = default;
    importer(const importer &) = delete;
    importer &operator=(const importer &) = delete;
    ~importer()
    {
        if (dirfd >= 0)
            close(dirfd);
    }

    [[noreturn]] void fail(pt_status st, const char *fmt, ...) __attribute__((format(printf, 3, 4)))
    {
        char msg[448];
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(msg, sizeof msg, fmt, ap);
        va_end(ap);
        pt_error_set(err, st, "%s: %s", path.c_str(), msg);
        throw load_failure{st};
    }

    void warn_once(const std::string &key, const std::string &msg)
    {
        if (!warned.insert(key).second)
            return;
        std::string full = path + ": " + msg;
        if (opts && opts->warn)
            opts->warn(opts->warn_user, full.c_str());
        else
            fprintf(stderr, "warning: %s\n", full.c_str());
    }

    void check_builder(pt_status st, pt_error *e)
    {
        if (st == PT_OK)
            return;
        // Prefix the builder's message with the file name.
        pt_error inner = *e;
        fail(st, "%s", inner.msg);
    }
};

struct image_loader_ctx {
    std::vector<std::vector<unsigned char>> *data_uri_images;
};

// tinygltf's image callback. Keeps the bytes of data: URI images for later
// decoding; for images in buffer views it does not touch the bytes, because
// tinygltf hands us &buffer[byteOffset] without checking the view's range.
bool keep_image_bytes(tinygltf::Image *image, const int idx, std::string *, std::string *, int, int,
                      const unsigned char *bytes, int size, void *user)
{
    auto *ctx = static_cast<image_loader_ctx *>(user);
    if (idx < 0)
        return false;
    if (ctx->data_uri_images->size() <= size_t(idx))
        ctx->data_uri_images->resize(size_t(idx) + 1);
    if (image->bufferView < 0 && bytes && size > 0)
        (*ctx->data_uri_images)[size_t(idx)].assign(bytes, bytes + size);
    return true;
}

// Moves len pt_malloc'd bytes into out, freeing them whatever happens.
void take_bytes(uint8_t *data, size_t len, std::vector<unsigned char> &out)
{
    try {
        out.assign(data, data + len);
    } catch (...) {
        pt_free(data);
        throw;
    }
    pt_free(data);
}

// The scene's own file: a regular file only (a FIFO is refused, not waited
// on), at most kMaxFileBytes. A folder named as the scene is answered with
// the scene files in it, which is what its user meant.
void read_entry(importer &im, std::vector<unsigned char> &out)
{
    struct stat sb;
    if (stat(im.path.c_str(), &sb) == 0 && S_ISDIR(sb.st_mode)) {
        std::string found;
        if (DIR *d = opendir(im.path.c_str())) {
            while (struct dirent *e = readdir(d)) {
                std::string n = e->d_name;
                bool scene = n.size() > 5 && (n.compare(n.size() - 5, 5, ".gltf") == 0 ||
                                              n.compare(n.size() - 4, 4, ".glb") == 0);
                if (scene && found.size() < 200)
                    found += (found.empty() ? "" : ", ") + n;
            }
            closedir(d);
        }
        if (found.empty())
            im.fail(PT_ERR_ARG, "a folder, with no .gltf or .glb in it; give a scene file");
        im.fail(PT_ERR_ARG, "a folder; give the scene file in it: %s", found.c_str());
    }
    uint8_t *data = nullptr;
    size_t len = 0;
    pt_error e = {};
    pt_status st = pt_read_file(im.path.c_str(), kMaxFileBytes, &data, &len, &e);
    if (st != PT_OK) {
        if (im.err) {
            *im.err = e;
            im.err->code = st;
        }
        throw load_failure{st};
    }
    take_bytes(data, len, out);
}

// A URI or file name as a message may show it: printable ASCII, the rest as
// \xNN, at most 120 bytes.
std::string shown(const std::string &s)
{
    std::string out;
    for (unsigned char c : s) {
        if (out.size() >= 120) {
            out += "...";
            break;
        }
        if (c >= 0x20 && c < 0x7f && c != '\\') {
            out += char(c);
        } else {
            char hex[8];
            snprintf(hex, sizeof hex, "\\x%02x", c);
            out += hex;
        }
    }
    return out;
}

// Reads the external file a decoded URI names, below the entry file's folder
// only (see the top of this file). On failure, *msg is "'name': why", naming
// nothing but the name as the scene wrote it (escaped).
pt_status read_inside(importer &im, const std::string &name, std::vector<unsigned char> &out,
                      std::string *msg)
{
    const char *why = pt_uri_path_refusal(name.data(), name.size());
    if (why) {
        *msg = "'" + shown(name) + "' " + why;
        return PT_ERR_FORMAT;
    }
    if (im.dirfd < 0) {
        im.dirfd =
            open(im.base.empty() ? "." : im.base.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
        if (im.dirfd < 0) {
            *msg = "'" + shown(name) + "': the scene's folder cannot be opened: " + strerror(errno);
            return PT_ERR_IO;
        }
    }
    uint8_t *data = nullptr;
    size_t len = 0;
    pt_error e{};
    pt_status st = pt_read_file_beneath(im.dirfd, name.c_str(), kMaxFileBytes, &data, &len, &e);
    if (st != PT_OK) {
        // e.msg is "<name>: why"; show the name escaped.
        const char *rest = e.msg;
        if (strncmp(rest, name.c_str(), name.size()) == 0 && rest[name.size()] == ':')
            rest += name.size() + 1;
        *msg = "'" + shown(name) + "':" + rest;
        return st;
    }
    take_bytes(data, len, out);
    return PT_OK;
}

// tinygltf's file callbacks (it reads the buffers): every name goes through
// read_inside. Given an empty base folder, tinygltf asks for the decoded URI
// itself; saying every file exists keeps it from trying "./" + URI, and the
// real answer comes from the read.
bool fs_exists(const std::string &, void *)
{
    return true;
}
std::string fs_expand(const std::string &path, void *)
{
    return path;
}
bool fs_read(std::vector<unsigned char> *out, std::string *err, const std::string &name, void *user)
{
    auto *im = static_cast<importer *>(user);
    std::string msg;
    pt_status st = read_inside(*im, name, *out, &msg);
    if (st == PT_OK)
        return true;
    if (im->fs_st == PT_OK) {
        im->fs_st = st;
        im->fs_msg = msg;
    }
    if (err)
        *err = "refused";
    return false;
}
bool fs_write(std::string *err, const std::string &, const std::vector<unsigned char> &, void *)
{
    if (err)
        *err = "writing is not allowed";
    return false;
}

// RFC 3986 percent-decoding of a relative URI.
// The bundle packer decodes with the same function (gltf_deps.cpp), so a
// bundle carries the files the importer opens.
std::string uri_decode(const std::string &s)
{
    std::string out(s.size(), '\0');
    out.resize(pt_uri_decode(s.data(), s.size(), &out[0]));
    return out;
}

bool is_data_uri(const std::string &u)
{
    return u.compare(0, 5, "data:") == 0;
}

bool add_ok(uint64_t a, uint64_t b, uint64_t *r)
{
    return !__builtin_add_overflow(a, b, r);
}
bool mul_ok(uint64_t a, uint64_t b, uint64_t *r)
{
    return !__builtin_mul_overflow(a, b, r);
}

int comp_size(int ct)
{
    switch (ct) {
    case TINYGLTF_COMPONENT_TYPE_BYTE:
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
        return 1;
    case TINYGLTF_COMPONENT_TYPE_SHORT:
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT:
        return 2;
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT:
    case TINYGLTF_COMPONENT_TYPE_FLOAT:
        return 4;
    default:
        return 0;
    }
}

int type_comps(int t)
{
    switch (t) {
    case TINYGLTF_TYPE_SCALAR:
        return 1;
    case TINYGLTF_TYPE_VEC2:
        return 2;
    case TINYGLTF_TYPE_VEC3:
        return 3;
    case TINYGLTF_TYPE_VEC4:
        return 4;
    case TINYGLTF_TYPE_MAT4:
        return 16;
    default:
        return 0;
    }
}

// The bytes of accessor `ai`, checked: a pointer to element 0 and the stride,
// or data == nullptr for an accessor without a buffer view (all zeros).
struct view_span {
    const unsigned char *data;
    uint64_t stride;
    uint64_t count;
    int ctype;
    bool normalized;
};

// The bytes of bufferView vi, checked to lie within its buffer. ai and what
// only name the reader in messages.
std::pair<const unsigned char *, uint64_t> meshopt_view(importer &im, int vi, int ai,
                                                        const char *what);

std::pair<const unsigned char *, uint64_t> view_bytes(importer &im, int vi, int ai,
                                                      const char *what)
{
    const tinygltf::Model &m = im.model;
    if (vi < 0 || size_t(vi) >= m.bufferViews.size())
        im.fail(PT_ERR_FORMAT, "accessor %d (%s): bufferView %d out of range (%zu views)", ai, what,
                vi, m.bufferViews.size());
    const tinygltf::BufferView &v = m.bufferViews[size_t(vi)];
    if (v.extensions.count("EXT_meshopt_compression"))
        return meshopt_view(im, vi, ai, what);
    if (v.buffer < 0 || size_t(v.buffer) >= m.buffers.size())
        im.fail(PT_ERR_FORMAT, "accessor %d (%s): bufferView %d names buffer %d, out of range", ai,
                what, vi, v.buffer);
    const std::vector<unsigned char> &buf = m.buffers[size_t(v.buffer)].data;
    uint64_t view_end;
    if (!add_ok(v.byteOffset, v.byteLength, &view_end) || view_end > buf.size())
        im.fail(PT_ERR_FORMAT,
                "accessor %d (%s): bufferView %d (offset %zu, length %zu) is outside buffer %d "
                "(%zu bytes)",
                ai, what, vi, v.byteOffset, v.byteLength, v.buffer, buf.size());
    return {buf.data() + v.byteOffset, v.byteLength};
}

// EXT_meshopt_compression: buffer view vi decoded once from the bytes its
// extension names (buffer, byteOffset, byteLength) into count x byteStride
// bytes, which must be the view's byteLength (the extension's README). The
// view's own buffer is the uncompressed fallback, often absent
// (prepare_json). The decoded size is capped before anything is allocated.
std::pair<const unsigned char *, uint64_t> meshopt_view(importer &im, int vi, int ai,
                                                        const char *what)
{
    auto done = im.meshopt.find(vi);
    if (done != im.meshopt.end())
        return {done->second.data(), done->second.size()};
    const tinygltf::Model &m = im.model;
    const tinygltf::BufferView &v = m.bufferViews[size_t(vi)];
    const tinygltf::Value &e = v.extensions.at("EXT_meshopt_compression");
    auto num = [&](const char *key, double dflt, bool required) {
        const tinygltf::Value &x = e.Get(key);
        if (!x.IsNumber()) {
            if (required)
                im.fail(PT_ERR_FORMAT,
                        "accessor %d (%s): bufferView %d: EXT_meshopt_compression has no %s", ai,
                        what, vi, key);
            return dflt;
        }
        double d = x.GetNumberAsDouble();
        if (!(d >= 0.0 && d <= 9007199254740992.0) || d != std::floor(d))
            im.fail(PT_ERR_FORMAT,
                    "accessor %d (%s): bufferView %d: EXT_meshopt_compression %s is %g", ai, what,
                    vi, key, d);
        return d;
    };
    if (!e.IsObject())
        im.fail(PT_ERR_FORMAT,
                "accessor %d (%s): bufferView %d: EXT_meshopt_compression is not "
                "an object",
                ai, what, vi);
    double buf = num("buffer", 0, true), off = num("byteOffset", 0, false);
    double len = num("byteLength", 0, true), stride = num("byteStride", 0, true);
    double count = num("count", 0, true);
    std::string mode = e.Get("mode").IsString() ? e.Get("mode").Get<std::string>() : "";
    std::string filter = e.Get("filter").IsString() ? e.Get("filter").Get<std::string>() : "NONE";
    int md = mode == "ATTRIBUTES"  ? PT_MESHOPT_ATTRIBUTES
             : mode == "TRIANGLES" ? PT_MESHOPT_TRIANGLES
             : mode == "INDICES"   ? PT_MESHOPT_INDICES
                                   : -1;
    int fl = filter == "NONE"          ? PT_MESHOPT_NONE
             : filter == "OCTAHEDRAL"  ? PT_MESHOPT_OCTAHEDRAL
             : filter == "QUATERNION"  ? PT_MESHOPT_QUATERNION
             : filter == "EXPONENTIAL" ? PT_MESHOPT_EXPONENTIAL
                                       : -1;
    if (md < 0 || fl < 0)
        im.fail(PT_ERR_FORMAT,
                "accessor %d (%s): bufferView %d: EXT_meshopt_compression mode '%.20s' / filter "
                "'%.20s' unknown",
                ai, what, vi, shown(mode).c_str(), shown(filter).c_str());
    if (buf >= double(m.buffers.size()))
        im.fail(PT_ERR_FORMAT,
                "accessor %d (%s): bufferView %d: EXT_meshopt_compression buffer %g out of range",
                ai, what, vi, buf);
    const std::vector<unsigned char> &src = m.buffers[size_t(buf)].data;
    if (off + len > double(src.size()))
        im.fail(PT_ERR_FORMAT,
                "accessor %d (%s): bufferView %d: EXT_meshopt_compression bytes %g + %g are "
                "outside buffer %g (%zu bytes)",
                ai, what, vi, off, len, buf, src.size());
    double size = count * stride;
    const double cap = double(PT_SCENE_MAX_TRIANGLES) * 3.0 * 16.0; // the accessors' cap
    if (size > cap)
        im.fail(PT_ERR_LIMIT,
                "accessor %d (%s): bufferView %d: EXT_meshopt_compression decodes to %g bytes "
                "(at most %g)",
                ai, what, vi, size, cap);
    if (size != double(v.byteLength))
        im.fail(PT_ERR_FORMAT,
                "accessor %d (%s): bufferView %d: EXT_meshopt_compression count x byteStride = "
                "%g, the view's byteLength %zu",
                ai, what, vi, size, v.byteLength);
    std::vector<unsigned char> out(static_cast<size_t>(size));
    pt_error me{};
    pt_status st = pt_meshopt_decode(src.data() + size_t(off), size_t(len), uint64_t(count),
                                     uint32_t(stride), md, fl, out.data(), &me);
    if (st != PT_OK)
        im.fail(st, "accessor %d (%s): bufferView %d: %s", ai, what, vi, me.msg);
    auto &kept = im.meshopt[vi] = std::move(out);
    return {kept.data(), kept.size()};
}

// Element 0 of `count` elements of `elem` bytes at byte `offset` of
// bufferView vi, `stride` apart (the view's byteStride when it has one,
// else elem), checked to lie within the view.
const unsigned char *view_elements(importer &im, int vi, uint64_t offset, uint64_t count,
                                   uint64_t elem, uint64_t *stride, int ai, const char *what)
{
    auto vb = view_bytes(im, vi, ai, what);
    const tinygltf::BufferView &v = im.model.bufferViews[size_t(vi)];
    *stride = elem;
    if (v.byteStride != 0) {
        if (v.byteStride < elem)
            im.fail(PT_ERR_FORMAT,
                    "accessor %d (%s): bufferView %d stride %zu is under the %llu "
                    "bytes of an element",
                    ai, what, vi, v.byteStride, (unsigned long long)elem);
        *stride = v.byteStride;
    }
    uint64_t last, end;
    if (!mul_ok(*stride, count - 1, &last) || !add_ok(last, offset, &last) ||
        !add_ok(last, elem, &end) || end > vb.second)
        im.fail(PT_ERR_FORMAT,
                "accessor %d (%s): %llu elements at offset %llu, stride %llu run past the end of "
                "bufferView %d (%llu bytes)",
                ai, what, (unsigned long long)count, (unsigned long long)offset,
                (unsigned long long)*stride, vi, (unsigned long long)vb.second);
    return vb.first + offset;
}

// A sparse accessor (glTF 2.0, 3.6.2.3) made dense: its base (the buffer
// view's elements, or zeros without one) with sparse.count elements
// replaced. The indices must be u8/u16/u32, strictly increasing and under
// the accessor's count; the values are tightly packed elements.
std::vector<unsigned char> sparse_dense(importer &im, int ai, const char *what, view_span s)
{
    const tinygltf::Accessor &a = im.model.accessors[size_t(ai)];
    uint64_t elem = uint64_t(comp_size(a.componentType)) * uint64_t(type_comps(a.type));
    std::vector<unsigned char> out(size_t(s.count * elem), 0);
    if (a.bufferView >= 0) {
        uint64_t stride;
        const unsigned char *base =
            view_elements(im, a.bufferView, a.byteOffset, s.count, elem, &stride, ai, what);
        for (uint64_t i = 0; i < s.count; i++)
            memcpy(&out[size_t(i * elem)], base + i * stride, size_t(elem));
    }
    const auto &sp = a.sparse;
    if (sp.count < 1 || uint64_t(sp.count) > s.count)
        im.fail(PT_ERR_FORMAT, "accessor %d (%s): sparse count %d is not in [1, %llu]", ai, what,
                sp.count, (unsigned long long)s.count);
    int is = sp.indices.componentType == TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE    ? 1
             : sp.indices.componentType == TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT ? 2
             : sp.indices.componentType == TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT   ? 4
                                                                                  : 0;
    if (is == 0)
        im.fail(PT_ERR_FORMAT,
                "accessor %d (%s): sparse indices' component type %d is not u8/u16/u32", ai, what,
                sp.indices.componentType);
    if (sp.indices.byteOffset < 0 || sp.values.byteOffset < 0)
        im.fail(PT_ERR_FORMAT, "accessor %d (%s): a sparse byteOffset is negative", ai, what);
    uint64_t n = uint64_t(sp.count), istride, vstride;
    const unsigned char *ip =
        view_elements(im, sp.indices.bufferView, uint64_t(sp.indices.byteOffset), n, uint64_t(is),
                      &istride, ai, what);
    const unsigned char *vp = view_elements(
        im, sp.values.bufferView, uint64_t(sp.values.byteOffset), n, elem, &vstride, ai, what);
    // The spec's sparse views have no byteStride: elements are tightly packed.
    istride = uint64_t(is);
    vstride = elem;
    uint64_t prev = 0;
    for (uint64_t k = 0; k < n; k++) {
        const unsigned char *p = ip + k * istride;
        uint64_t idx = is == 1   ? p[0]
                       : is == 2 ? uint64_t(p[0] | p[1] << 8)
                                 : uint64_t(p[0]) | uint64_t(p[1]) << 8 | uint64_t(p[2]) << 16 |
                                       uint64_t(p[3]) << 24;
        if (idx >= s.count)
            im.fail(PT_ERR_FORMAT,
                    "accessor %d (%s): sparse index %llu at %llu is out of range (count %llu)", ai,
                    what, (unsigned long long)idx, (unsigned long long)k,
                    (unsigned long long)s.count);
        if (k > 0 && idx <= prev)
            im.fail(PT_ERR_FORMAT,
                    "accessor %d (%s): sparse indices do not strictly increase (%llu after %llu)",
                    ai, what, (unsigned long long)idx, (unsigned long long)prev);
        prev = idx;
        memcpy(&out[size_t(idx * elem)], vp + k * vstride, size_t(elem));
    }
    return out;
}

view_span accessor_span(importer &im, int ai, const char *what, int want_type, uint64_t max_count)
{
    const tinygltf::Model &m = im.model;
    if (ai < 0 || size_t(ai) >= m.accessors.size())
        im.fail(PT_ERR_FORMAT, "accessor %d (%s): no such accessor (%zu accessors)", ai, what,
                m.accessors.size());
    const tinygltf::Accessor &a = m.accessors[size_t(ai)];
    int cs = comp_size(a.componentType), nc = type_comps(a.type);
    if (cs == 0 || nc != type_comps(want_type))
        im.fail(PT_ERR_FORMAT, "accessor %d (%s): unexpected type %d / component type %d", ai, what,
                a.type, a.componentType);
    if (a.count == 0)
        im.fail(PT_ERR_FORMAT, "accessor %d (%s): count is 0", ai, what);
    if (uint64_t(a.count) > max_count)
        im.fail(PT_ERR_LIMIT, "accessor %d (%s): count %zu is over the cap %llu", ai, what, a.count,
                (unsigned long long)max_count);
    view_span s{nullptr, uint64_t(cs) * uint64_t(nc), uint64_t(a.count), a.componentType,
                a.normalized};
    // Accessors made dense once (sparse ones, decoded ones): tightly packed.
    auto d = im.dense.find(ai);
    if (d == im.dense.end() && a.sparse.isSparse)
        d = im.dense.emplace(ai, sparse_dense(im, ai, what, s)).first;
    if (d != im.dense.end()) {
        if (d->second.size() != s.count * s.stride)
            im.fail(PT_ERR_FORMAT, "accessor %d (%s): decoded to %zu bytes, not %llu", ai, what,
                    d->second.size(), (unsigned long long)(s.count * s.stride));
        s.data = d->second.data();
        return s;
    }
    if (a.bufferView < 0)
        return s; // glTF 3.6.2.1: no buffer view means zeros
    s.data = view_elements(im, a.bufferView, a.byteOffset, s.count, s.stride, &s.stride, ai, what);
    return s;
}

float read_comp(const unsigned char *p, int ct, bool normalized)
{
    switch (ct) {
    case TINYGLTF_COMPONENT_TYPE_FLOAT: {
        float f;
        memcpy(&f, p, 4);
        return f;
    }
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
        return normalized ? p[0] / 255.0f : float(p[0]);
    case TINYGLTF_COMPONENT_TYPE_BYTE: {
        float f = float(int8_t(p[0]));
        return normalized ? std::fmax(f / 127.0f, -1.0f) : f;
    }
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: {
        uint16_t u = uint16_t(p[0] | p[1] << 8);
        return normalized ? u / 65535.0f : float(u);
    }
    case TINYGLTF_COMPONENT_TYPE_SHORT: {
        float f = float(int16_t(uint16_t(p[0] | p[1] << 8)));
        return normalized ? std::fmax(f / 32767.0f, -1.0f) : f;
    }
    default: {
        uint32_t u =
            uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24;
        return float(u);
    }
    }
}

// Which component types an attribute may have, as floats after reading
// (read_comp: a normalized integer is scaled to [0, 1] or [-1, 1], another
// converted as it is).
enum comp_kinds {
    COMP_FLOAT, // FLOAT only
    COMP_UNORM, // FLOAT, normalized u8/u16 (core TEXCOORD_n, COLOR_n, 3.7.2.1)
    COMP_SNORM, // FLOAT, normalized i8/i16, and normalized u8/u16 where core allows them
    COMP_INT16, // FLOAT, i8/u8/i16/u16, normalized or not
};

// Whether component type ct (normalized or not) is one that kinds allows.
// KHR_mesh_quantization ("Extending Mesh Attributes") widens the core
// attributes: POSITION and TEXCOORD_n to every 8- and 16-bit type,
// normalized or not (COMP_INT16); NORMAL and TANGENT to normalized i8/i16
// (COMP_SNORM); morph target deltas likewise. u32 is never a vertex
// attribute's type.
bool comp_allowed(int ct, bool normalized, comp_kinds kinds)
{
    bool signed8_16 = ct == TINYGLTF_COMPONENT_TYPE_BYTE || ct == TINYGLTF_COMPONENT_TYPE_SHORT;
    bool unsigned8_16 =
        ct == TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE || ct == TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT;
    if (ct == TINYGLTF_COMPONENT_TYPE_FLOAT)
        return true;
    switch (kinds) {
    case COMP_FLOAT:
        return false;
    case COMP_UNORM:
        return unsigned8_16 && normalized;
    case COMP_SNORM:
        return (signed8_16 || unsigned8_16) && normalized;
    case COMP_INT16:
        return signed8_16 || unsigned8_16;
    }
    return false;
}

// Reads a float attribute whose component types kinds allows.
void read_floats(importer &im, int ai, const char *what, int type, comp_kinds kinds,
                 std::vector<float> &out)
{
    view_span s = accessor_span(im, ai, what, type, PT_SCENE_MAX_TRIANGLES * 3ull);
    int nc = type_comps(type);
    if (!comp_allowed(s.ctype, s.normalized, kinds))
        im.fail(PT_ERR_FORMAT, "accessor %d (%s): component type %d%s is not supported", ai, what,
                s.ctype, s.normalized ? " (normalized)" : "");
    out.assign(size_t(s.count) * size_t(nc), 0.0f);
    if (!s.data)
        return;
    int cs = comp_size(s.ctype);
    for (uint64_t i = 0; i < s.count; i++) {
        const unsigned char *e = s.data + i * s.stride;
        for (int c = 0; c < nc; c++)
            out[size_t(i) * size_t(nc) + size_t(c)] = read_comp(e + c * cs, s.ctype, s.normalized);
    }
}

void read_indices(importer &im, int ai, const char *what, std::vector<uint32_t> &out)
{
    view_span s = accessor_span(im, ai, what, TINYGLTF_TYPE_SCALAR, PT_SCENE_MAX_TRIANGLES * 3ull);
    if (s.ctype != TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE &&
        s.ctype != TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT &&
        s.ctype != TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT)
        im.fail(PT_ERR_FORMAT, "accessor %d (%s): index component type %d is not u8/u16/u32", ai,
                what, s.ctype);
    out.assign(size_t(s.count), 0);
    if (!s.data)
        return;
    for (uint64_t i = 0; i < s.count; i++) {
        const unsigned char *p = s.data + i * s.stride;
        uint32_t v;
        if (s.ctype == TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE)
            v = p[0];
        else if (s.ctype == TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT)
            v = uint32_t(p[0] | p[1] << 8);
        else
            v = uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24;
        out[size_t(i)] = v;
    }
}

// Column-major 4x4 products and the node's local matrix (spec 3.5.3:
// matrix, or T * R * S with R from the unit quaternion (x, y, z, w)).
typedef std::array<double, 16> mat4;

mat4 mat_mul(const mat4 &a, const mat4 &b)
{
    mat4 r{};
    for (int c = 0; c < 4; c++)
        for (int rr = 0; rr < 4; rr++) {
            double s = 0;
            for (int k = 0; k < 4; k++)
                s += a[size_t(k * 4 + rr)] * b[size_t(c * 4 + k)];
            r[size_t(c * 4 + rr)] = s;
        }
    return r;
}

mat4 identity()
{
    mat4 m{};
    m[0] = m[5] = m[10] = m[15] = 1.0;
    return m;
}

mat4 local_matrix(importer &im, const tinygltf::Node &n, int ni)
{
    mat4 m = identity();
    if (!n.matrix.empty()) {
        if (n.matrix.size() != 16)
            im.fail(PT_ERR_FORMAT, "node %d: matrix has %zu numbers, not 16", ni, n.matrix.size());
        for (size_t i = 0; i < 16; i++)
            m[i] = n.matrix[i];
    } else {
        double t[3] = {0, 0, 0}, s[3] = {1, 1, 1}, q[4] = {0, 0, 0, 1};
        if (!n.translation.empty() && n.translation.size() != 3)
            im.fail(PT_ERR_FORMAT, "node %d: translation needs 3 numbers", ni);
        if (!n.scale.empty() && n.scale.size() != 3)
            im.fail(PT_ERR_FORMAT, "node %d: scale needs 3 numbers", ni);
        if (!n.rotation.empty() && n.rotation.size() != 4)
            im.fail(PT_ERR_FORMAT, "node %d: rotation needs 4 numbers", ni);
        for (size_t i = 0; i < n.translation.size(); i++)
            t[i] = n.translation[i];
        for (size_t i = 0; i < n.scale.size(); i++)
            s[i] = n.scale[i];
        for (size_t i = 0; i < n.rotation.size(); i++)
            q[i] = n.rotation[i];
        pt_rig::trs_matrix(t, q, s, m.data());
    }
    for (double v : m)
        if (!std::isfinite(v))
            im.fail(PT_ERR_FORMAT, "node %d: transform is not finite", ni);
    return m;
}

const char *name_or(const std::string &s, const char *dflt)
{
    return s.empty() ? dflt : s.c_str();
}

int wrap_mode(int gl)
{
    switch (gl) {
    case TINYGLTF_TEXTURE_WRAP_CLAMP_TO_EDGE:
        return PT_WRAP_CLAMP;
    case TINYGLTF_TEXTURE_WRAP_MIRRORED_REPEAT:
        return PT_WRAP_MIRROR;
    default:
        return PT_WRAP_REPEAT;
    }
}

uint32_t be32(const unsigned char *p)
{
    return uint32_t(p[0]) << 24 | uint32_t(p[1]) << 16 | uint32_t(p[2]) << 8 | uint32_t(p[3]);
}

// Whether a PNG's image data inflates to no more than its IHDR's size needs
// (true for anything that is not a PNG, and for a PNG too broken for
// stb_image to read, which refuses it itself). stb_image sizes its output
// from the header but grows it while the zlib stream goes on, to 2 GiB: a
// 2 MB PNG that claims 1x1 took a worker to 2 GB and 3 s of CPU a texture,
// through every cap on texels. So the stream is inflated once here into a
// buffer of the header's size, which refuses any more, and freed before
// stb_image decodes the file. Chunks: PNG spec (ISO 15948) 5.3 and 11.2.2;
// the raw size of a row is its filter byte and ceil(width x channels x
// depth / 8) bytes; Adam7 (8.2) adds at most a filter and a padding byte to
// each of at most 2 h + 7 pass rows. An Apple "CgBI" PNG's stream has no
// zlib header, as stb_image reads it.
bool png_inflates_within(const unsigned char *p, size_t n)
{
    static const unsigned char sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
    if (n < 8 || memcmp(p, sig, 8) != 0)
        return true;
    bool cgbi = false, ihdr = false;
    uint32_t w = 0, h = 0;
    int depth = 0, ctype = -1;
    std::vector<char> z;
    for (size_t off = 8; n - off >= 12;) {
        uint32_t len = be32(p + off);
        if (len > n - off - 12)
            break;
        const unsigned char *type = p + off + 4, *d = p + off + 8;
        if (memcmp(type, "CgBI", 4) == 0) {
            cgbi = true;
        } else if (memcmp(type, "IHDR", 4) == 0 && len >= 13) {
            w = be32(d);
            h = be32(d + 4);
            depth = d[8];
            ctype = d[9];
            ihdr = true;
        } else if (memcmp(type, "IDAT", 4) == 0) {
            z.insert(z.end(), d, d + len);
        } else if (memcmp(type, "IEND", 4) == 0) {
            break;
        }
        off += 12 + size_t(len);
    }
    int ch = ctype == 0 || ctype == 3 ? 1 : ctype == 4 ? 2 : ctype == 2 ? 3 : ctype == 6 ? 4 : 0;
    if (!ihdr || z.empty() || ch == 0 || depth < 1 || depth > 16 || z.size() > size_t(INT32_MAX))
        return true;
    uint64_t row = (uint64_t(w) * uint64_t(ch) * uint64_t(depth) + 7) / 8 + 1;
    uint64_t limit = row * h + 4 * uint64_t(h) + 16;
    if (limit > uint64_t(INT32_MAX))
        return false; // no image under the texel caps needs this much
    std::unique_ptr<char[]> out(new char[size_t(limit)]);
    int got = cgbi
                  ? stbi_zlib_decode_noheader_buffer(out.get(), int(limit), z.data(), int(z.size()))
                  : stbi_zlib_decode_buffer(out.get(), int(limit), z.data(), int(z.size()));
    return got >= 0;
}

// The encoded bytes of image `ii`, wherever they live.
std::pair<const unsigned char *, size_t> image_bytes(importer &im, int ii, const char *ctx)
{
    const tinygltf::Model &m = im.model;
    const tinygltf::Image &img = m.images[size_t(ii)];
    if (img.bufferView >= 0) {
        if (size_t(img.bufferView) >= m.bufferViews.size())
            im.fail(PT_ERR_FORMAT, "%s: image %d: bufferView %d out of range", ctx, ii,
                    img.bufferView);
        const tinygltf::BufferView &v = m.bufferViews[size_t(img.bufferView)];
        if (v.buffer < 0 || size_t(v.buffer) >= m.buffers.size())
            im.fail(PT_ERR_FORMAT, "%s: image %d: buffer %d out of range", ctx, ii, v.buffer);
        const std::vector<unsigned char> &buf = m.buffers[size_t(v.buffer)].data;
        uint64_t end;
        if (!add_ok(v.byteOffset, v.byteLength, &end) || end > buf.size() || v.byteLength == 0)
            im.fail(PT_ERR_FORMAT, "%s: image %d: bufferView %d is outside its buffer", ctx, ii,
                    img.bufferView);
        return {buf.data() + v.byteOffset, v.byteLength};
    }
    if (is_data_uri(img.uri) || img.uri.empty()) {
        if (size_t(ii) >= im.data_uri_images.size() || im.data_uri_images[size_t(ii)].empty())
            im.fail(PT_ERR_FORMAT, "%s: image %d has no data", ctx, ii);
        const auto &d = im.data_uri_images[size_t(ii)];
        return {d.data(), d.size()};
    }
    auto it = im.files.find(uri_decode(img.uri));
    if (it == im.files.end())
        im.fail(PT_ERR_IO, "%s: image %d ('%s') could not be read", ctx, ii, img.uri.c_str());
    return {it->second.data(), it->second.size()};
}

double ext_number(const tinygltf::Value &obj, const char *key, double dflt);

// The numbers of array `key` of obj into out[0..n) where present and numeric.
void ext_numbers(const tinygltf::Value &obj, const char *key, float *out, int n)
{
    if (!obj.IsObject() || !obj.Has(key))
        return;
    const tinygltf::Value &a = obj.Get(key);
    for (int c = 0; c < n && a.IsArray() && size_t(c) < a.ArrayLen(); c++)
        if (a.Get(c).IsNumber())
            out[c] = float(a.Get(c).GetNumberAsDouble());
}

// A textureInfo's coordinate set and KHR_texture_transform (whose texCoord,
// when given, overrides the textureInfo's).
pt_tex_xform slot_transform(importer &im, const char *ctx, int tex_coord,
                            const tinygltf::ExtensionMap &ext)
{
    pt_tex_xform x = pt_tex_xform_identity();
    auto tt = ext.find("KHR_texture_transform");
    if (tt != ext.end()) {
        float off[2] = {0.0f, 0.0f}, sc[2] = {1.0f, 1.0f};
        ext_numbers(tt->second, "offset", off, 2);
        ext_numbers(tt->second, "scale", sc, 2);
        float rot = float(ext_number(tt->second, "rotation", 0.0));
        tex_coord = int(ext_number(tt->second, "texCoord", double(tex_coord)));
        if (!std::isfinite(off[0]) || !std::isfinite(off[1]) || !std::isfinite(sc[0]) ||
            !std::isfinite(sc[1]) || !std::isfinite(rot))
            im.fail(PT_ERR_FORMAT, "%s: KHR_texture_transform has a non-finite number", ctx);
        x = pt_tex_xform_make(off, rot, sc, 0);
    }
    if (tex_coord == 1) {
        x.texcoord = 1;
    } else if (tex_coord != 0) {
        im.warn_once("texcoord", std::string(ctx) + " uses TEXCOORD_" + std::to_string(tex_coord) +
                                     "; TEXCOORD_0 is used instead (sets 0 and 1 are read)");
    }
    return x;
}

// The image a texture decodes: EXT_texture_webp's source when it has one
// (the image its author prefers; libwebp decodes it), else the core source,
// a PNG or JPEG. KHR_texture_basisu's KTX2 source is never decoded (Debian
// has no Basis Universal transcoder): the core source is its fallback, and
// without one the texture is refused naming KTX2.
int texture_source(importer &im, const tinygltf::Texture &t, const char *ctx)
{
    auto wx = t.extensions.find("EXT_texture_webp");
    if (wx != t.extensions.end()) {
        const tinygltf::Value &v = wx->second.Get("source");
        if (!wx->second.IsObject() || !v.IsNumber())
            im.fail(PT_ERR_FORMAT, "%s: EXT_texture_webp has no source", ctx);
        double d = v.GetNumberAsDouble();
        return d >= 0.0 && d < double(INT32_MAX) ? int(d) : -1;
    }
    if (t.source < 0 && t.extensions.count("KHR_texture_basisu"))
        im.fail(PT_ERR_FORMAT,
                "%s: its only image is KTX2 (KHR_texture_basisu), which ptfarm cannot decode; "
                "export a PNG or JPEG fallback",
                ctx);
    return t.source;
}

// Builder texture for glTF texture `index` used as `slot` of material `mi`,
// and the slot's coordinate set and transform into *xf. With
// im.headers_only, the image's header alone is read and checked against the
// caps and its texels counted; nothing is decoded and -1 is returned.
int32_t texture_for(importer &im, int mi, const char *slot, int index, int tex_coord,
                    const tinygltf::ExtensionMap &ext, bool srgb, pt_tex_xform *xf)
{
    *xf = pt_tex_xform_identity();
    if (index < 0)
        return -1;
    const tinygltf::Model &m = im.model;
    const char *mname = name_or(m.materials[size_t(mi)].name, "");
    char ctx[200];
    snprintf(ctx, sizeof ctx, "material %d ('%.64s') %s: texture %d", mi, mname, slot, index);
    if (size_t(index) >= m.textures.size())
        im.fail(PT_ERR_FORMAT, "%s: no such texture (%zu textures)", ctx, m.textures.size());
    *xf = slot_transform(im, ctx, tex_coord, ext);
    auto key = std::make_pair(index, srgb ? 1 : 0);
    auto found = im.tex_map.find(key);
    if (found != im.tex_map.end())
        return int32_t(found->second);
    const tinygltf::Texture &t = m.textures[size_t(index)];
    int src = texture_source(im, t, ctx);
    if (src < 0 || size_t(src) >= m.images.size())
        im.fail(PT_ERR_FORMAT, "%s points at image %d, which does not exist (%zu images)", ctx, src,
                m.images.size());
    auto bytes = image_bytes(im, src, ctx);
    bool webp = pt_webp_is(bytes.first, bytes.second) != 0;
    if (bytes.second >= 12 && memcmp(bytes.first, "\xabKTX 20\xbb\r\n\x1a\n", 12) == 0)
        im.fail(PT_ERR_FORMAT,
                "%s: image %d is KTX2 (KHR_texture_basisu), which ptfarm cannot decode, and the "
                "texture offers no PNG or JPEG source",
                ctx, src);
    if (bytes.second > size_t(INT32_MAX))
        im.fail(PT_ERR_LIMIT, "%s: image %d is too large", ctx, src);
    int w = 0, h = 0, comp = 0;
    if (webp) {
        uint32_t ww = 0, wh = 0;
        pt_error we{};
        pt_status wst = pt_webp_size(bytes.first, bytes.second, &ww, &wh, &we);
        if (wst != PT_OK)
            im.fail(wst, "%s: image %d cannot be decoded: %s", ctx, src, we.msg);
        if (ww > PT_SCENE_MAX_TEXTURE_DIM || wh > PT_SCENE_MAX_TEXTURE_DIM)
            im.fail(PT_ERR_LIMIT, "%s: image %d is %ux%u (at most %u a side)", ctx, src, ww, wh,
                    PT_SCENE_MAX_TEXTURE_DIM);
        w = int(ww);
        h = int(wh);
    } else if (!stbi_info_from_memory(bytes.first, int(bytes.second), &w, &h, &comp)) {
        im.fail(PT_ERR_FORMAT, "%s: image %d cannot be decoded: %s", ctx, src,
                stbi_failure_reason());
    }
    if (w <= 0 || h <= 0 || uint32_t(w) > PT_SCENE_MAX_TEXTURE_DIM ||
        uint32_t(h) > PT_SCENE_MAX_TEXTURE_DIM)
        im.fail(PT_ERR_LIMIT, "%s: image %d is %dx%d (at most %u a side)", ctx, src, w, h,
                PT_SCENE_MAX_TEXTURE_DIM);
    // The header's size decides before the decoder allocates anything: a
    // 1 MB PNG of zeros may claim 16384^2, 1 GiB once decoded. stb_image
    // sizes its buffers from the same header fields (PNG IHDR, JPEG SOF, the
    // BMP, TGA, GIF, PSD, PIC, PNM and Radiance headers).
    const tinygltf::Image &img = m.images[size_t(src)];
    char what[96]; // "image 3", and its file's name when it has one
    int k = snprintf(what, sizeof what, "image %d", src);
    if (!img.uri.empty() && !is_data_uri(img.uri))
        snprintf(what + k, sizeof what - size_t(k), " ('%.64s')", img.uri.c_str());
    const int hw = w, hh = h;
    uint64_t texels = uint64_t(w) * uint64_t(h);
    if (texels > PT_SCENE_MAX_IMAGE_TEXELS)
        im.fail(PT_ERR_LIMIT, "%s: %s is %dx%d, %llu texels (at most %llu an image)", ctx, what, w,
                h, (unsigned long long)texels, (unsigned long long)PT_SCENE_MAX_IMAGE_TEXELS);
    if (texels > PT_SCENE_MAX_TEXELS - im.texels)
        im.fail(PT_ERR_LIMIT,
                "%s: %s is %dx%d, which makes %llu texels in the scene's textures (at most "
                "%llu a scene)",
                ctx, what, w, h, (unsigned long long)(im.texels + texels),
                (unsigned long long)PT_SCENE_MAX_TEXELS);
    if (im.headers_only) {
        im.texels += texels;
        im.tex_map[key] = 0;
        return -1;
    }
    if (!webp && !png_inflates_within(bytes.first, bytes.second))
        im.fail(PT_ERR_FORMAT,
                "%s: %s: its PNG data does not inflate to the %dx%d its header gives (longer, "
                "or broken)",
                ctx, what, w, h);
    const tinygltf::Sampler *smp = nullptr;
    if (t.sampler >= 0) {
        if (size_t(t.sampler) >= m.samplers.size())
            im.fail(PT_ERR_FORMAT, "%s: sampler %d out of range", ctx, t.sampler);
        smp = &m.samplers[size_t(t.sampler)];
    }
    unsigned char *px = nullptr;
    if (!webp) {
        px = stbi_load_from_memory(bytes.first, int(bytes.second), &w, &h, &comp, 4);
        if (!px)
            im.fail(PT_ERR_FORMAT, "%s: image %d cannot be decoded: %s", ctx, src,
                    stbi_failure_reason());
        if (w != hw || h != hh) {
            stbi_image_free(px);
            im.fail(PT_ERR_FORMAT, "%s: image %d decodes to %dx%d, its header says %dx%d", ctx, src,
                    w, h, hw, hh);
        }
    }
    size_t n = size_t(w) * size_t(h) * 4;
    pt_texture tex{};
    tex.width = uint32_t(w);
    tex.height = uint32_t(h);
    tex.rgba = static_cast<uint8_t *>(pt_malloc(n));
    if (!tex.rgba) {
        stbi_image_free(px);
        im.fail(PT_ERR_NOMEM, "%s: out of memory", ctx);
    }
    if (webp) {
        pt_error we{};
        pt_status wst =
            pt_webp_decode(bytes.first, bytes.second, uint32_t(w), uint32_t(h), tex.rgba, &we);
        if (wst != PT_OK) {
            pt_free(tex.rgba);
            im.fail(wst, "%s: image %d cannot be decoded: %s", ctx, src, we.msg);
        }
    } else {
        memcpy(tex.rgba, px, n);
        stbi_image_free(px);
    }
    im.texels += texels;
    tex.srgb = srgb ? 1 : 0;
    tex.wrap_s = tex.wrap_t = PT_WRAP_REPEAT;
    if (smp) {
        tex.wrap_s = wrap_mode(smp->wrapS);
        tex.wrap_t = wrap_mode(smp->wrapT);
        // The magFilter decides (scene.h, pt_texture_sample).
        tex.nearest = smp->magFilter == TINYGLTF_TEXTURE_FILTER_NEAREST ? 1 : 0;
    }
    uint32_t idx = 0;
    pt_error e{};
    im.check_builder(pt_scene_builder_add_texture(im.b, &tex, &idx, &e), &e);
    im.tex_map[key] = idx;
    return int32_t(idx);
}

double ext_number(const tinygltf::Value &obj, const char *key, double dflt)
{
    if (!obj.IsObject() || !obj.Has(key))
        return dflt;
    const tinygltf::Value &v = obj.Get(key);
    return v.IsNumber() ? v.GetNumberAsDouble() : dflt;
}

// A TextureInfo from an extension's JSON object (tinygltf parses only the
// core material's), or index -1.
tinygltf::TextureInfo ext_texture(const tinygltf::Value &obj, const char *key)
{
    tinygltf::TextureInfo info;
    if (!obj.IsObject() || !obj.Has(key))
        return info;
    const tinygltf::Value &t = obj.Get(key);
    if (!t.IsObject())
        return info;
    if (t.Has("index") && t.Get("index").IsNumber())
        info.index = int(t.Get("index").GetNumberAsDouble());
    if (t.Has("texCoord") && t.Get("texCoord").IsNumber())
        info.texCoord = int(t.Get("texCoord").GetNumberAsDouble());
    if (t.Has("extensions") && t.Get("extensions").IsObject()) {
        const tinygltf::Value &e = t.Get("extensions");
        for (const auto &k : e.Keys())
            info.extensions[k] = e.Get(k);
    }
    return info;
}

// KHR_materials_transmission, KHR_materials_ior and KHR_materials_volume
// into pm (scene.h: the fields; an infinite attenuationDistance is 0 there).
// The volume's thickness texture is ignored: thickness only decides thin or
// not, and the renderer traces the mesh itself.
void add_transmission(importer &im, int mi, const tinygltf::Material &g, pt_material &pm)
{
    auto tr = g.extensions.find("KHR_materials_transmission");
    if (tr != g.extensions.end()) {
        pm.transmission = float(ext_number(tr->second, "transmissionFactor", 0.0));
        const tinygltf::TextureInfo tt = ext_texture(tr->second, "transmissionTexture");
        pm.transmission_tex = texture_for(im, mi, "transmissionTexture", tt.index, tt.texCoord,
                                          tt.extensions, false, &pm.tex_xf[PT_SLOT_TRANSMISSION]);
    }
    auto io = g.extensions.find("KHR_materials_ior");
    if (io != g.extensions.end())
        pm.ior = float(ext_number(io->second, "ior", 1.5));
    // An opaque dielectric's F0 is ((ior - 1) / (ior + 1))^2 x the specular
    // colour (KHR_materials_ior with KHR_materials_specular): the base
    // scales its colour by 0.04 (ior 1.5), so the colour takes the ratio.
    if (pm.ior != 1.5f && pm.transmission == 0.0f) {
        if (pm.ior == 0.0f || (pm.ior >= 1.0f && std::isfinite(pm.ior))) {
            float r = (pm.ior - 1.0f) / (pm.ior + 1.0f);
            for (int c = 0; c < 3; c++)
                pm.specular_color[c] *= r * r / 0.04f;
        } else {
            im.warn_once("ior-opaque", "material " + std::to_string(mi) + ": KHR_materials_ior " +
                                           std::to_string(pm.ior) +
                                           " is not 0 or >= 1; the material keeps ior 1.5");
        }
    }
    auto vo = g.extensions.find("KHR_materials_volume");
    if (vo != g.extensions.end()) {
        pm.thickness = float(ext_number(vo->second, "thicknessFactor", 0.0));
        double d = ext_number(vo->second, "attenuationDistance", 0.0);
        pm.attenuation_distance = std::isinf(d) && d > 0 ? 0.0f : float(d);
        if (vo->second.IsObject() && vo->second.Has("attenuationColor")) {
            const tinygltf::Value &a = vo->second.Get("attenuationColor");
            for (int c = 0; c < 3 && a.IsArray() && size_t(c) < a.ArrayLen(); c++)
                if (a.Get(c).IsNumber())
                    pm.attenuation_color[c] = float(a.Get(c).GetNumberAsDouble());
        }
        // thicknessTexture is not read, and nothing is lost: it bakes the
        // distance through the mesh for renderers that do not trace it;
        // here every ray crosses the mesh itself, as thicknessFactor > 0
        // (a volume boundary) asks.
    }
}

// KHR_materials_clearcoat and KHR_materials_sheen factors and textures into
// pm, the factors clamped to [0, 1] as the extensions define them, and the
// clearcoat normal texture with its scale.
void add_layers(importer &im, int mi, const tinygltf::Material &g, pt_material &pm)
{
    auto unit = [](double v) { return float(v > 0.0 ? (v < 1.0 ? v : 1.0) : 0.0); };
    auto tex = [&](const tinygltf::Value &ext, const char *key, bool srgb, int slot) {
        const tinygltf::TextureInfo t = ext_texture(ext, key);
        return texture_for(im, mi, key, t.index, t.texCoord, t.extensions, srgb, &pm.tex_xf[slot]);
    };
    auto cc = g.extensions.find("KHR_materials_clearcoat");
    if (cc != g.extensions.end()) {
        pm.clearcoat = unit(ext_number(cc->second, "clearcoatFactor", 0.0));
        pm.clearcoat_roughness = unit(ext_number(cc->second, "clearcoatRoughnessFactor", 0.0));
        pm.clearcoat_tex = tex(cc->second, "clearcoatTexture", false, PT_SLOT_CLEARCOAT);
        pm.clearcoat_rough_tex =
            tex(cc->second, "clearcoatRoughnessTexture", false, PT_SLOT_CLEARCOAT_ROUGH);
        // The coat's own normal map: a normalTextureInfo (its scale scales
        // x and y as normalTexture's does), read with the base's tangents.
        if (cc->second.IsObject() && cc->second.Has("clearcoatNormalTexture")) {
            pm.clearcoat_normal_tex =
                tex(cc->second, "clearcoatNormalTexture", false, PT_SLOT_CLEARCOAT_NORMAL);
            pm.clearcoat_normal_scale =
                float(ext_number(cc->second.Get("clearcoatNormalTexture"), "scale", 1.0));
        }
    }
    auto sh = g.extensions.find("KHR_materials_sheen");
    if (sh != g.extensions.end()) {
        float c[3] = {0.0f, 0.0f, 0.0f};
        ext_numbers(sh->second, "sheenColorFactor", c, 3);
        for (int i = 0; i < 3; i++)
            pm.sheen_color[i] = unit(c[i]);
        pm.sheen_roughness = unit(ext_number(sh->second, "sheenRoughnessFactor", 0.0));
        pm.sheen_color_tex = tex(sh->second, "sheenColorTexture", true, PT_SLOT_SHEEN_COLOR);
        pm.sheen_rough_tex = tex(sh->second, "sheenRoughnessTexture", false, PT_SLOT_SHEEN_ROUGH);
    }
}

// The extensions the importer reads (README, "glTF extensions"). glTF 2.0
// spec 3.12: a loader must refuse a file whose extensionsRequired lists one
// it does not support; one only in extensionsUsed may be ignored, which is
// reported once, by name, with the same key as a material's use of it.
bool ext_supported(const std::string &name)
{
    static const std::set<std::string> supported = {
        "KHR_draco_mesh_compression",          // draco_primitive
        "KHR_lights_punctual",                 // add_light
        "KHR_materials_clearcoat",             // add_layers
        "KHR_materials_emissive_strength",     // read_materials
        "KHR_materials_ior",                   // add_transmission
        "KHR_materials_sheen",                 // add_layers
        "KHR_materials_specular",              // read_materials (factors)
        "KHR_materials_transmission",          // add_transmission
        "KHR_materials_unlit",                 // read_materials: pm.unlit
        "KHR_materials_variants",              // choose_variant
        "KHR_materials_volume",                // add_transmission
        "KHR_mesh_quantization",               // comp_allowed
        "KHR_texture_transform",               // slot_transform
        "KHR_xmp",                             // metadata: nothing to render
        "KHR_xmp_json_ld",                     // metadata: nothing to render
        "EXT_mesh_gpu_instancing",             // instance_matrices
        "EXT_meshopt_compression",             // meshopt_view, meshopt.c
        "EXT_texture_webp",                    // texture_source, webp.c
        "KHR_texture_basisu",                  // texture_source: the PNG/JPEG fallback
        "KHR_materials_pbrSpecularGlossiness", // read_materials
        "KHR_materials_iridescence",           // read_materials
        "KHR_materials_anisotropy",            // read_materials
        "KHR_materials_diffuse_transmission",  // read_materials
        "KHR_materials_dispersion",            // read_materials
    };
    return supported.count(name) != 0;
}

void warn_ext_ignored(importer &im, const std::string &name, const std::string &where)
{
    im.warn_once("ext:" + name,
                 "extension " + shown(name) + " is not supported; " + where + " is ignored");
}

// KHR_materials_pbrSpecularGlossiness into pm (scene.h): the diffuse as the
// base colour (its factor, its sRGB texture with alpha), the specular and
// glossiness factors and their texture. The metallic-roughness inputs are
// then not read, nor the extensions built on them (the material's loader
// warns about each by name).
void add_spec_gloss(importer &im, int mi, const tinygltf::Value &sg, pt_material &pm)
{
    pm.spec_gloss = 1;
    pm.metallic = 0.0f;
    for (int c = 0; c < 4; c++)
        pm.base_color[c] = 1.0f;
    ext_numbers(sg, "diffuseFactor", pm.base_color, 4);
    ext_numbers(sg, "specularFactor", pm.sg_specular, 3);
    pm.sg_glossiness = float(ext_number(sg, "glossinessFactor", 1.0));
    const tinygltf::TextureInfo dt = ext_texture(sg, "diffuseTexture"),
                                gt = ext_texture(sg, "specularGlossinessTexture");
    pm.base_color_tex = texture_for(im, mi, "diffuseTexture", dt.index, dt.texCoord, dt.extensions,
                                    true, &pm.tex_xf[PT_SLOT_BASE]);
    pm.sg_tex = texture_for(im, mi, "specularGlossinessTexture", gt.index, gt.texCoord,
                            gt.extensions, true, &pm.tex_xf[PT_SLOT_SPEC_GLOSS]);
}

// KHR_materials_iridescence into pm (scene.h): the factor and its texture
// (R), the film's ior, the thickness range and its texture (G).
void add_iridescence(importer &im, int mi, const tinygltf::Material &g, pt_material &pm)
{
    auto ir = g.extensions.find("KHR_materials_iridescence");
    if (ir == g.extensions.end())
        return;
    const tinygltf::Value &v = ir->second;
    pm.iridescence = float(ext_number(v, "iridescenceFactor", 0.0));
    pm.iridescence_ior = float(ext_number(v, "iridescenceIor", 1.3));
    pm.irid_thickness_min = float(ext_number(v, "iridescenceThicknessMinimum", 100.0));
    pm.irid_thickness_max = float(ext_number(v, "iridescenceThicknessMaximum", 400.0));
    const tinygltf::TextureInfo it = ext_texture(v, "iridescenceTexture"),
                                tt = ext_texture(v, "iridescenceThicknessTexture");
    pm.iridescence_tex = texture_for(im, mi, "iridescenceTexture", it.index, it.texCoord,
                                     it.extensions, false, &pm.tex_xf[PT_SLOT_IRIDESCENCE]);
    pm.irid_thickness_tex =
        texture_for(im, mi, "iridescenceThicknessTexture", tt.index, tt.texCoord, tt.extensions,
                    false, &pm.tex_xf[PT_SLOT_IRID_THICKNESS]);
}

// KHR_materials_anisotropy into pm (scene.h): strength, rotation and the
// texture (RG direction, B strength, linear). On a transmitting material it
// is ignored, with a warning.
void add_anisotropy(importer &im, int mi, const tinygltf::Material &g, pt_material &pm)
{
    auto an = g.extensions.find("KHR_materials_anisotropy");
    if (an == g.extensions.end())
        return;
    pm.anisotropy = float(ext_number(an->second, "anisotropyStrength", 0.0));
    pm.anisotropy_rotation = float(ext_number(an->second, "anisotropyRotation", 0.0));
    const tinygltf::TextureInfo at = ext_texture(an->second, "anisotropyTexture");
    pm.anisotropy_tex = texture_for(im, mi, "anisotropyTexture", at.index, at.texCoord,
                                    at.extensions, false, &pm.tex_xf[PT_SLOT_ANISOTROPY]);
    if (pm.anisotropy > 0.0f && pm.transmission > 0.0f)
        im.warn_once("aniso-glass", "material " + std::to_string(mi) +
                                        ": KHR_materials_anisotropy on a transmitting material is "
                                        "ignored (it shapes opaque materials' reflection only)");
}

// KHR_materials_diffuse_transmission into pm (scene.h): the factor and its
// texture (A), the colour and its texture (RGB, sRGB). The renderer treats
// the surface as a thin wall; on a transmitting material it is ignored,
// with a warning.
void add_diffuse_transmission(importer &im, int mi, const tinygltf::Material &g, pt_material &pm)
{
    auto dt = g.extensions.find("KHR_materials_diffuse_transmission");
    if (dt == g.extensions.end())
        return;
    const tinygltf::Value &v = dt->second;
    pm.diffuse_transmission = float(ext_number(v, "diffuseTransmissionFactor", 0.0));
    ext_numbers(v, "diffuseTransmissionColorFactor", pm.diffuse_transmission_color, 3);
    const tinygltf::TextureInfo ft = ext_texture(v, "diffuseTransmissionTexture"),
                                ct = ext_texture(v, "diffuseTransmissionColorTexture");
    pm.diffuse_transmission_tex =
        texture_for(im, mi, "diffuseTransmissionTexture", ft.index, ft.texCoord, ft.extensions,
                    false, &pm.tex_xf[PT_SLOT_DIFFUSE_TRANSMISSION]);
    pm.diffuse_transmission_color_tex =
        texture_for(im, mi, "diffuseTransmissionColorTexture", ct.index, ct.texCoord, ct.extensions,
                    true, &pm.tex_xf[PT_SLOT_DIFFUSE_TRANSMISSION_COLOR]);
    if (pm.diffuse_transmission > 0.0f && pm.transmission > 0.0f)
        im.warn_once("dt-glass", "material " + std::to_string(mi) +
                                     ": KHR_materials_diffuse_transmission on a transmitting "
                                     "material is ignored (its glass is kept)");
}

void read_materials(importer &im)
{
    const tinygltf::Model &m = im.model;
    for (size_t i = 0; i < m.materials.size(); i++) {
        const tinygltf::Material &g = m.materials[i];
        int mi = int(i);
        pt_material pm = pt_material_default();
        snprintf(pm.name, sizeof pm.name, "%s",
                 g.name.empty() ? ("material " + std::to_string(i)).c_str() : g.name.c_str());
        const auto &pbr = g.pbrMetallicRoughness;
        for (size_t c = 0; c < 4 && c < pbr.baseColorFactor.size(); c++)
            pm.base_color[c] = float(pbr.baseColorFactor[c]);
        pm.metallic = float(pbr.metallicFactor);
        pm.roughness = float(pbr.roughnessFactor);
        double strength = 1.0;
        auto es = g.extensions.find("KHR_materials_emissive_strength");
        if (es != g.extensions.end())
            strength = ext_number(es->second, "emissiveStrength", 1.0);
        for (size_t c = 0; c < 3; c++)
            pm.emissive[c] =
                c < g.emissiveFactor.size() ? float(g.emissiveFactor[c] * strength) : 0.0f;
        auto sp = g.extensions.find("KHR_materials_specular");
        if (sp != g.extensions.end()) {
            pm.specular = float(ext_number(sp->second, "specularFactor", 1.0));
            if (sp->second.IsObject() && sp->second.Has("specularColorFactor")) {
                const tinygltf::Value &a = sp->second.Get("specularColorFactor");
                for (int c = 0; c < 3 && a.IsArray() && size_t(c) < a.ArrayLen(); c++)
                    if (a.Get(c).IsNumber())
                        pm.specular_color[c] = float(a.Get(c).GetNumberAsDouble());
            }
            // specularTexture's A and specularColorTexture's RGB (sRGB).
            const tinygltf::TextureInfo st = ext_texture(sp->second, "specularTexture"),
                                        sc = ext_texture(sp->second, "specularColorTexture");
            pm.specular_tex = texture_for(im, mi, "specularTexture", st.index, st.texCoord,
                                          st.extensions, false, &pm.tex_xf[PT_SLOT_SPECULAR]);
            pm.specular_color_tex =
                texture_for(im, mi, "specularColorTexture", sc.index, sc.texCoord, sc.extensions,
                            true, &pm.tex_xf[PT_SLOT_SPECULAR_COLOR]);
        }
        // KHR_materials_unlit keeps the base colour, its alpha and
        // doubleSided; what lights or shades (emission included) is not read.
        pm.unlit = g.extensions.count("KHR_materials_unlit") ? 1 : 0;
        auto sg = g.extensions.find("KHR_materials_pbrSpecularGlossiness");
        if (sg != g.extensions.end() && !pm.unlit)
            add_spec_gloss(im, mi, sg->second, pm);
        if (!pm.unlit && !pm.spec_gloss) {
            add_transmission(im, mi, g, pm);
            add_layers(im, mi, g, pm);
            add_iridescence(im, mi, g, pm);
            add_anisotropy(im, mi, g, pm);
            add_diffuse_transmission(im, mi, g, pm);
            auto ds = g.extensions.find("KHR_materials_dispersion");
            if (ds != g.extensions.end())
                pm.dispersion = float(ext_number(ds->second, "dispersion", 0.0));
        } else if (pm.spec_gloss) {
            // The extension replaces metallic-roughness and the extensions
            // built on it.
            for (const char *x :
                 {"KHR_materials_transmission", "KHR_materials_clearcoat", "KHR_materials_sheen",
                  "KHR_materials_iridescence", "KHR_materials_anisotropy",
                  "KHR_materials_diffuse_transmission", "KHR_materials_specular",
                  "KHR_materials_ior", "KHR_materials_volume", "KHR_materials_dispersion"})
                if (g.extensions.count(x))
                    im.warn_once(std::string("sg-") + x,
                                 "material " + std::to_string(mi) + ": " + x +
                                     " beside KHR_materials_pbrSpecularGlossiness is ignored "
                                     "(it extends metallic-roughness)");
        }
        pm.double_sided = g.doubleSided ? 1 : 0;
        for (const auto &e : g.extensions)
            if (!ext_supported(e.first))
                warn_ext_ignored(im, e.first,
                                 "material " + std::to_string(i) + " ('" + shown(g.name) + "')");
        if (g.occlusionTexture.index >= 0 && !pm.unlit)
            im.warn_once("occlusionTexture",
                         "occlusion textures are ignored (material " + std::to_string(i) + ")");
        if (g.alphaMode == "MASK")
            pm.alpha_mode = PT_ALPHA_MASK;
        else if (g.alphaMode == "BLEND")
            pm.alpha_mode = PT_ALPHA_BLEND;
        else if (!g.alphaMode.empty() && g.alphaMode != "OPAQUE")
            im.fail(PT_ERR_FORMAT, "material %d: alphaMode '%s' is not OPAQUE, MASK or BLEND", mi,
                    shown(g.alphaMode).c_str());
        pm.alpha_cutoff = float(g.alphaCutoff);
        const tinygltf::TextureInfo &bt = pbr.baseColorTexture, &mt = pbr.metallicRoughnessTexture,
                                    &et = g.emissiveTexture;
        const tinygltf::NormalTextureInfo &nt = g.normalTexture;
        if (!pm.spec_gloss)
            pm.base_color_tex = texture_for(im, mi, "baseColorTexture", bt.index, bt.texCoord,
                                            bt.extensions, true, &pm.tex_xf[PT_SLOT_BASE]);
        if (!pm.unlit && !pm.spec_gloss)
            pm.metal_rough_tex =
                texture_for(im, mi, "metallicRoughnessTexture", mt.index, mt.texCoord,
                            mt.extensions, false, &pm.tex_xf[PT_SLOT_METAL_ROUGH]);
        if (!pm.unlit) {
            pm.emissive_tex = texture_for(im, mi, "emissiveTexture", et.index, et.texCoord,
                                          et.extensions, true, &pm.tex_xf[PT_SLOT_EMISSIVE]);
            // Normal textures hold vectors: linear, whatever the image says.
            pm.normal_tex = texture_for(im, mi, "normalTexture", nt.index, nt.texCoord,
                                        nt.extensions, false, &pm.tex_xf[PT_SLOT_NORMAL]);
            pm.normal_scale = float(nt.scale);
        }
        if (im.headers_only)
            continue;
        uint32_t idx;
        pt_error e{};
        pt_status st = pt_scene_builder_add_material(im.b, &pm, &idx, &e);
        if (st != PT_OK)
            im.fail(st, "material %d: %s", mi, e.msg);
    }
}

// The materials, and the textures they use decoded, in two passes: the
// first reads the images' headers alone, so that the scene's texels are
// checked against PT_SCENE_MAX_TEXELS before any image is decoded (a cap
// checked as images decode would let a scene hold nearly all of it first).
void add_materials(importer &im)
{
    im.headers_only = true;
    read_materials(im);
    im.headers_only = false;
    im.tex_map.clear();
    im.texels = 0;
    read_materials(im);
}

uint32_t material_index(importer &im, int mat, const char *what)
{
    if (mat >= 0) {
        if (size_t(mat) >= im.model.materials.size())
            im.fail(PT_ERR_FORMAT, "%s: material %d out of range (%zu materials)", what, mat,
                    im.model.materials.size());
        return uint32_t(mat);
    }
    if (im.default_material == UINT32_MAX) {
        pt_material d = pt_material_default();
        pt_error e{};
        uint32_t idx;
        im.check_builder(pt_scene_builder_add_material(im.b, &d, &idx, &e), &e);
        im.default_material = idx;
    }
    return im.default_material;
}

// The material primitive p uses: the one its KHR_materials_variants mappings
// give the chosen variant, else its own. Mappings are checked only when a
// variant is chosen (a file rendered without one loads as it always has).
int variant_material(importer &im, const tinygltf::Primitive &p, const char *what)
{
    if (im.variant < 0)
        return p.material;
    auto ext = p.extensions.find("KHR_materials_variants");
    if (ext == p.extensions.end())
        return p.material;
    const tinygltf::Value &maps = ext->second.Get("mappings");
    if (!maps.IsArray())
        im.fail(PT_ERR_FORMAT, "%s: KHR_materials_variants has no mappings array", what);
    for (size_t i = 0; i < maps.ArrayLen(); i++) {
        const tinygltf::Value &mp = maps.Get(int(i));
        const tinygltf::Value &mat = mp.Get("material");
        const tinygltf::Value &vs = mp.Get("variants");
        if (!mp.IsObject() || !mat.IsNumber() || !vs.IsArray())
            im.fail(PT_ERR_FORMAT,
                    "%s: KHR_materials_variants mapping %zu needs material and variants", what, i);
        for (size_t k = 0; k < vs.ArrayLen(); k++)
            if (vs.Get(int(k)).IsNumber() && vs.Get(int(k)).GetNumberAsInt() == im.variant)
                return mat.GetNumberAsInt(); // range-checked by material_index
    }
    return p.material;
}

// Resolves opts->variant against the root's KHR_materials_variants list; an
// unknown name is PT_ERR_ARG naming the file's variants (as an unknown camera).
void choose_variant(importer &im)
{
    const char *name = im.opts ? im.opts->variant : nullptr;
    if (!name)
        return;
    std::vector<std::string> names;
    auto ext = im.model.extensions.find("KHR_materials_variants");
    if (ext != im.model.extensions.end()) {
        const tinygltf::Value &vs = ext->second.Get("variants");
        for (size_t i = 0; vs.IsArray() && i < vs.ArrayLen(); i++) {
            const tinygltf::Value &n = vs.Get(int(i)).Get("name");
            names.push_back(n.IsString() ? n.Get<std::string>() : std::string());
        }
    }
    for (size_t i = 0; i < names.size(); i++)
        if (names[i] == name) {
            im.variant = int(i);
            return;
        }
    if (names.empty())
        im.fail(PT_ERR_ARG, "no variant named '%.64s': the scene has no variants", name);
    std::string list;
    for (size_t i = 0; i < names.size() && list.size() < 300; i++)
        list += (i ? ", '" : "'") + names[i].substr(0, 64) + "'";
    if (list.size() >= 300)
        list += "...";
    im.fail(PT_ERR_ARG, "no variant named '%.64s'; variants: %s", name, list.c_str());
}

// KHR_draco_mesh_compression: primitive (mesh, pi)'s Draco buffer view
// decoded once into the dense elements of the accessors it replaces (its
// indices and the attributes its "attributes" map names), converted to each
// accessor's component type, so every reader takes them as any accessor.
// The decoded counts must be the accessors' (a buffer that lies about its
// counts is refused, naming both), within the same caps as any accessor.
void draco_primitive(importer &im, int mesh, int pi, const char *what)
{
    const tinygltf::Primitive &p = im.model.meshes[size_t(mesh)].primitives[size_t(pi)];
    auto ext = p.extensions.find("KHR_draco_mesh_compression");
    if (ext == p.extensions.end() || !im.draco_done.insert({mesh, pi}).second)
        return;
    const tinygltf::Value &e = ext->second;
    if (!e.IsObject() || !e.Get("bufferView").IsNumber() || !e.Get("attributes").IsObject())
        im.fail(PT_ERR_FORMAT, "%s: KHR_draco_mesh_compression needs bufferView and attributes",
                what);
    double bvd = e.Get("bufferView").GetNumberAsDouble();
    if (!(bvd >= 0.0 && bvd < double(im.model.bufferViews.size())))
        im.fail(PT_ERR_FORMAT, "%s: KHR_draco_mesh_compression bufferView %g out of range", what,
                bvd);
    auto bytes = view_bytes(im, int(bvd), -1, what);
    const uint64_t cap = PT_SCENE_MAX_TRIANGLES * 3ull;
    pt_draco_mesh *dm = nullptr;
    pt_error de{};
    pt_status st =
        pt_draco_decode(bytes.first, size_t(bytes.second), cap, PT_SCENE_MAX_TRIANGLES, &dm, &de);
    if (st != PT_OK)
        im.fail(st, "%s: KHR_draco_mesh_compression bufferView %d: %s", what, int(bvd), de.msg);
    std::unique_ptr<pt_draco_mesh, void (*)(pt_draco_mesh *)> guard(dm, pt_draco_free);
    uint64_t np = pt_draco_points(dm), nf = pt_draco_faces(dm);
    auto claim = [&](int ai, const char *name) -> const tinygltf::Accessor & {
        if (ai < 0 || size_t(ai) >= im.model.accessors.size())
            im.fail(PT_ERR_FORMAT, "%s: %s accessor %d out of range", what, name, ai);
        if (im.dense.count(ai))
            im.fail(PT_ERR_FORMAT,
                    "%s: accessor %d (%s) is decoded twice (shared by Draco "
                    "primitives or sparse)",
                    what, ai, name);
        return im.model.accessors[size_t(ai)];
    };
    auto idx_it = im.draco_indices.find({mesh, pi});
    int ia = idx_it != im.draco_indices.end() ? idx_it->second : p.indices;
    if (ia >= 0) {
        const tinygltf::Accessor &a = claim(ia, "indices");
        if (uint64_t(a.count) != 3 * nf)
            im.fail(PT_ERR_FORMAT,
                    "%s: indices accessor %d says %zu indices, the Draco buffer holds %llu "
                    "triangles (%llu)",
                    what, ia, a.count, (unsigned long long)nf, (unsigned long long)(3 * nf));
        int cs = comp_size(a.componentType);
        if (a.type != TINYGLTF_TYPE_SCALAR ||
            (cs != 1 && cs != 2 && a.componentType != TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT))
            im.fail(PT_ERR_FORMAT, "%s: indices accessor %d is not u8/u16/u32", what, ia);
        std::vector<uint32_t> tri(size_t(3 * nf));
        pt_draco_indices(dm, tri.data());
        std::vector<unsigned char> out(tri.size() * size_t(cs));
        uint64_t max = cs == 1 ? 0xffu : cs == 2 ? 0xffffu : 0xffffffffu;
        for (size_t i = 0; i < tri.size(); i++) {
            if (tri[i] > max)
                im.fail(PT_ERR_FORMAT, "%s: Draco index %u does not fit accessor %d's type", what,
                        tri[i], ia);
            for (int k = 0; k < cs; k++)
                out[i * size_t(cs) + size_t(k)] = uint8_t(tri[i] >> (8 * k));
        }
        im.dense.emplace(ia, std::move(out));
    } else if (nf * 3 != np) {
        im.fail(PT_ERR_FORMAT,
                "%s: no indices, but the Draco buffer holds %llu triangles over %llu "
                "points",
                what, (unsigned long long)nf, (unsigned long long)np);
    }
    const tinygltf::Value &attrs = e.Get("attributes");
    for (const auto &name : attrs.Keys()) {
        const tinygltf::Value &id = attrs.Get(name);
        auto at = p.attributes.find(name);
        if (at == p.attributes.end())
            im.fail(PT_ERR_FORMAT,
                    "%s: KHR_draco_mesh_compression decodes %.40s, which the "
                    "primitive does not have",
                    what, shown(name).c_str());
        if (!id.IsNumber() || !(id.GetNumberAsDouble() >= 0.0) ||
            id.GetNumberAsDouble() > double(UINT32_MAX))
            im.fail(PT_ERR_FORMAT, "%s: KHR_draco_mesh_compression attribute %.40s has no id", what,
                    shown(name).c_str());
        const tinygltf::Accessor &a = claim(at->second, name.c_str());
        if (uint64_t(a.count) != np)
            im.fail(PT_ERR_FORMAT,
                    "%s: accessor %d (%.40s) says %zu elements, the Draco buffer holds %llu points",
                    what, at->second, shown(name).c_str(), a.count, (unsigned long long)np);
        int cs = comp_size(a.componentType), nc = type_comps(a.type);
        if (cs == 0 || nc == 0 || nc > 4)
            im.fail(PT_ERR_FORMAT, "%s: accessor %d (%.40s): type %d / component type %d", what,
                    at->second, shown(name).c_str(), a.type, a.componentType);
        std::vector<unsigned char> out(size_t(np) * size_t(nc) * size_t(cs));
        st = pt_draco_attribute(dm, uint32_t(id.GetNumberAsDouble()), a.componentType, nc,
                                out.data(), &de);
        if (st != PT_OK)
            im.fail(st, "%s: %.40s: %s", what, shown(name).c_str(), de.msg);
        im.dense.emplace(at->second, std::move(out));
    }
}

// The triangles of primitive p (of nv vertices) as a list of vertex
// indices: its indices, else 0 .. nv - 1, with strips and fans unrolled.
std::vector<uint32_t> triangle_list(importer &im, const tinygltf::Primitive &p, uint64_t nv,
                                    const char *what)
{
    int mode = p.mode < 0 ? TINYGLTF_MODE_TRIANGLES : p.mode;
    char w2[160];
    std::vector<uint32_t> idx;
    if (p.indices >= 0) {
        snprintf(w2, sizeof w2, "indices of %s", what);
        read_indices(im, p.indices, w2, idx);
        for (size_t i = 0; i < idx.size(); i++)
            if (idx[i] >= nv)
                im.fail(PT_ERR_FORMAT,
                        "accessor %d (%s): index %u at %zu out of range (%llu "
                        "vertices)",
                        p.indices, w2, idx[i], i, (unsigned long long)nv);
    } else {
        idx.resize(size_t(nv));
        for (size_t i = 0; i < idx.size(); i++)
            idx[i] = uint32_t(i);
    }
    // Strips and fans to a triangle list (spec 3.7.2.1, primitive modes).
    std::vector<uint32_t> tri;
    if (mode == TINYGLTF_MODE_TRIANGLES) {
        if (idx.size() % 3 != 0)
            im.fail(PT_ERR_FORMAT, "%s: %zu indices is not a multiple of 3", what, idx.size());
        tri.swap(idx);
    } else {
        for (size_t i = 2; i < idx.size(); i++) {
            if (mode == TINYGLTF_MODE_TRIANGLE_STRIP) {
                bool odd = i % 2 == 1;
                tri.push_back(idx[odd ? i - 1 : i - 2]);
                tri.push_back(idx[odd ? i - 2 : i - 1]);
            } else {
                tri.push_back(idx[0]);
                tri.push_back(idx[i - 1]);
            }
            tri.push_back(idx[i]);
        }
    }
    return tri;
}

// Attribute a (per floats a vertex) at the corners tri names, one vertex a
// corner (empty stays empty).
std::vector<float> unweld(const std::vector<float> &a, const std::vector<uint32_t> &tri, size_t per)
{
    std::vector<float> out;
    if (a.empty())
        return out;
    out.resize(tri.size() * per);
    for (size_t k = 0; k < tri.size(); k++)
        for (size_t c = 0; c < per; c++)
            out[k * per + c] = a[size_t(tri[k]) * per + c];
    return out;
}

void add_primitive(importer &im, int mesh, int pi, const mat4 &world)
{
    const tinygltf::Primitive &p = im.model.meshes[size_t(mesh)].primitives[size_t(pi)];
    char what[96];
    snprintf(what, sizeof what, "mesh %d primitive %d", mesh, pi);
    draco_primitive(im, mesh, pi, what);
    int mode = p.mode < 0 ? TINYGLTF_MODE_TRIANGLES : p.mode;
    if (mode != TINYGLTF_MODE_TRIANGLES && mode != TINYGLTF_MODE_TRIANGLE_STRIP &&
        mode != TINYGLTF_MODE_TRIANGLE_FAN) {
        im.warn_once("mode" + std::to_string(mode), std::string(what) + ": primitive mode " +
                                                        std::to_string(mode) +
                                                        " (points or lines) is not rendered");
        return;
    }
    for (const auto &a : p.attributes)
        if (a.first != "POSITION" && a.first != "NORMAL" && a.first != "TEXCOORD_0" &&
            a.first != "TANGENT" && a.first.compare(0, 9, "TEXCOORD_") != 0 &&
            a.first != "COLOR_0" && a.first.compare(0, 1, "_") != 0 &&
            !(im.rig && (a.first == "JOINTS_0" || a.first == "WEIGHTS_0" || a.first == "JOINTS_1" ||
                         a.first == "WEIGHTS_1")))
            im.warn_once("attr:" + a.first,
                         std::string(what) + ": attribute " + a.first + " is ignored");
    auto pos_it = p.attributes.find("POSITION");
    if (pos_it == p.attributes.end())
        im.fail(PT_ERR_FORMAT, "%s: no POSITION attribute", what);
    char w2[160];
    std::vector<float> pos, nrm, uv;
    snprintf(w2, sizeof w2, "POSITION of %s", what);
    read_floats(im, pos_it->second, w2, TINYGLTF_TYPE_VEC3, COMP_INT16, pos);
    uint64_t nv = pos.size() / 3;
    auto n_it = p.attributes.find("NORMAL");
    if (n_it != p.attributes.end()) {
        snprintf(w2, sizeof w2, "NORMAL of %s", what);
        read_floats(im, n_it->second, w2, TINYGLTF_TYPE_VEC3, COMP_SNORM, nrm);
        if (nrm.size() / 3 != nv)
            im.fail(PT_ERR_FORMAT, "accessor %d (%s): %zu normals for %llu positions", n_it->second,
                    w2, nrm.size() / 3, (unsigned long long)nv);
    }
    auto t_it = p.attributes.find("TEXCOORD_0");
    if (t_it != p.attributes.end()) {
        snprintf(w2, sizeof w2, "TEXCOORD_0 of %s", what);
        read_floats(im, t_it->second, w2, TINYGLTF_TYPE_VEC2, COMP_INT16, uv);
        if (uv.size() / 2 != nv)
            im.fail(PT_ERR_FORMAT, "accessor %d (%s): %zu texcoords for %llu positions",
                    t_it->second, w2, uv.size() / 2, (unsigned long long)nv);
    }
    // TEXCOORD_1, TANGENT and COLOR_0 (glTF 3.7.2.1: COLOR_0 is a VEC3 or VEC4 of
    // floats or normalized unsigned bytes or shorts; TANGENT a VEC4 of floats).
    std::vector<float> uv1, tan, col;
    auto u1_it = p.attributes.find("TEXCOORD_1");
    if (u1_it != p.attributes.end()) {
        snprintf(w2, sizeof w2, "TEXCOORD_1 of %s", what);
        read_floats(im, u1_it->second, w2, TINYGLTF_TYPE_VEC2, COMP_INT16, uv1);
        if (uv1.size() / 2 != nv)
            im.fail(PT_ERR_FORMAT, "accessor %d (%s): %zu texcoords for %llu positions",
                    u1_it->second, w2, uv1.size() / 2, (unsigned long long)nv);
    }
    auto tg_it = p.attributes.find("TANGENT");
    if (tg_it != p.attributes.end()) {
        snprintf(w2, sizeof w2, "TANGENT of %s", what);
        read_floats(im, tg_it->second, w2, TINYGLTF_TYPE_VEC4, COMP_SNORM, tan);
        if (tan.size() / 4 != nv)
            im.fail(PT_ERR_FORMAT, "accessor %d (%s): %zu tangents for %llu positions",
                    tg_it->second, w2, tan.size() / 4, (unsigned long long)nv);
        // w is +-1 by the spec; files round it, so its sign is what counts.
        for (size_t i = 3; i < tan.size(); i += 4)
            tan[i] = tan[i] < 0.0f ? -1.0f : 1.0f;
    }
    auto c_it = p.attributes.find("COLOR_0");
    if (c_it != p.attributes.end()) {
        snprintf(w2, sizeof w2, "COLOR_0 of %s", what);
        int ai = c_it->second;
        bool vec3 = ai >= 0 && size_t(ai) < im.model.accessors.size() &&
                    im.model.accessors[size_t(ai)].type == TINYGLTF_TYPE_VEC3;
        std::vector<float> raw;
        read_floats(im, ai, w2, vec3 ? TINYGLTF_TYPE_VEC3 : TINYGLTF_TYPE_VEC4, COMP_UNORM, raw);
        int nc = vec3 ? 3 : 4;
        if (raw.size() / size_t(nc) != nv)
            im.fail(PT_ERR_FORMAT, "accessor %d (%s): %zu colours for %llu positions", ai, w2,
                    raw.size() / size_t(nc), (unsigned long long)nv);
        col.assign(size_t(nv) * 4, 1.0f);
        for (size_t v = 0; v < size_t(nv); v++)
            for (int c = 0; c < nc; c++)
                col[v * 4 + size_t(c)] = raw[v * size_t(nc) + size_t(c)];
    }
    std::vector<uint32_t> tri = triangle_list(im, p, nv, what);
    if (nrm.empty()) {
        // glTF 2.0 (3.7.2.1): without NORMAL, flat normals, and TANGENT is
        // ignored. Each triangle gets corners of its own, whose area-weighted
        // normal (the builder's) is the face's.
        pos = unweld(pos, tri, 3);
        uv = unweld(uv, tri, 2);
        uv1 = unweld(uv1, tri, 2);
        col = unweld(col, tri, 4);
        tan.clear();
        nv = tri.size();
        for (size_t k = 0; k < tri.size(); k++)
            tri[k] = uint32_t(k);
    }
    uint32_t mat = material_index(im, variant_material(im, p, what), what);
    float xf[16];
    double xd[16];
    for (size_t i = 0; i < 16; i++) {
        xf[i] = float(world[i]);
        xd[i] = xf[i]; // the float matrix, as pt_scene_builder_add_mesh has always used
    }
    pt_mesh_extra ex{uv1.empty() ? nullptr : uv1.data(), tan.empty() ? nullptr : tan.data(),
                     col.empty() ? nullptr : col.data()};
    pt_error e{};
    pt_status st =
        pt_scene_builder_add_mesh_extra(im.b, what, pos.data(), nrm.empty() ? nullptr : nrm.data(),
                                        uv.empty() ? nullptr : uv.data(), &ex, uint32_t(nv),
                                        tri.data(), uint32_t(tri.size() / 3), xd, mat, &e);
    im.check_builder(st, &e);
}

void add_camera(importer &im, int ni, int ci, const mat4 &w)
{
    const tinygltf::Model &m = im.model;
    if (ci < 0 || size_t(ci) >= m.cameras.size())
        im.fail(PT_ERR_FORMAT, "node %d: camera %d out of range (%zu cameras)", ni, ci,
                m.cameras.size());
    const tinygltf::Camera &c = m.cameras[size_t(ci)];
    const tinygltf::Node &n = m.nodes[size_t(ni)];
    if (c.type != "perspective" && c.type != "orthographic") {
        im.warn_once("camera:" + c.type, "camera " + std::to_string(ci) + " is '" + c.type +
                                             "', not perspective or orthographic; ignored");
        return;
    }
    pt_camera pc{};
    std::string name = !c.name.empty()   ? c.name
                       : !n.name.empty() ? n.name
                                         : "camera " + std::to_string(ci);
    snprintf(pc.name, sizeof pc.name, "%s", name.c_str());
    snprintf(pc.node, sizeof pc.node, "%s", n.name.c_str());
    pc.position = pt_v3(float(w[12]), float(w[13]), float(w[14]));
    pt_vec3 fwd = pt_v3(float(-w[8]), float(-w[9]), float(-w[10]));
    pt_vec3 up = pt_v3(float(w[4]), float(w[5]), float(w[6]));
    pc.forward = pt_v3_norm(fwd);
    pc.right = pt_v3_norm(pt_v3_cross(pc.forward, up));
    pc.up = pt_v3_cross(pc.right, pc.forward);
    if (c.type == "orthographic") {
        // xmag and ymag are half the view's width and height (glTF 2.0,
        // 3.10.3); a negative one mirrors in a projection matrix, which a
        // ray tracer does not need, so their sizes are used.
        pc.ortho = 1;
        pc.xmag = float(std::fabs(c.orthographic.xmag));
        pc.ymag = float(std::fabs(c.orthographic.ymag));
        pc.yfov = 0.0f;
        pc.aspect = pc.ymag > 0.0f ? pc.xmag / pc.ymag : 0.0f;
        pc.znear = float(c.orthographic.znear);
    } else {
        pc.yfov = float(c.perspective.yfov);
        pc.aspect = float(c.perspective.aspectRatio);
        pc.znear = float(c.perspective.znear);
    }
    if (!(pt_v3_len(pc.right) > 0.5f))
        im.fail(PT_ERR_FORMAT, "node %d: camera %d ('%s') has a degenerate transform", ni, ci,
                pc.name);
    pt_error e{};
    pt_status st = pt_scene_builder_add_camera(im.b, &pc, &e);
    if (st != PT_OK)
        im.fail(st, "node %d: %s", ni, e.msg);
}

// A node's KHR_lights_punctual light: placed at the node's origin, shining
// down its -Z; scale changes neither the cone nor the intensity (the
// extension's README, "Defining Lights").
void add_light(importer &im, int ni, const tinygltf::Value &ext, const mat4 &w)
{
    const tinygltf::Model &m = im.model;
    if (!ext.IsObject() || !ext.Has("light") || !ext.Get("light").IsNumber())
        im.fail(PT_ERR_FORMAT, "node %d: KHR_lights_punctual has no light index", ni);
    double li = ext.Get("light").GetNumberAsDouble();
    if (!(li >= 0.0) || li >= double(m.lights.size()) || li != double(int(li)))
        im.fail(PT_ERR_FORMAT, "node %d: light %g out of range (%zu lights)", ni, li,
                m.lights.size());
    const tinygltf::Light &l = m.lights[size_t(li)];
    pt_punctual p{};
    std::string name = !l.name.empty()                     ? l.name
                       : !m.nodes[size_t(ni)].name.empty() ? m.nodes[size_t(ni)].name
                                                           : "light " + std::to_string(int(li));
    snprintf(p.name, sizeof p.name, "%s", name.c_str());
    if (l.type == "point")
        p.type = PT_PUNCTUAL_POINT;
    else if (l.type == "spot")
        p.type = PT_PUNCTUAL_SPOT;
    else if (l.type == "directional")
        p.type = PT_PUNCTUAL_DIRECTIONAL;
    else
        im.fail(PT_ERR_FORMAT, "light %d ('%s'): type '%.32s' is not point, spot or directional",
                int(li), p.name, l.type.c_str());
    double c[3] = {1.0, 1.0, 1.0};
    if (!l.color.empty()) {
        if (l.color.size() != 3)
            im.fail(PT_ERR_FORMAT, "light %d ('%s'): color has %zu numbers, not 3", int(li), p.name,
                    l.color.size());
        for (int k = 0; k < 3; k++)
            c[k] = l.color[size_t(k)];
    }
    for (int k = 0; k < 3; k++)
        if (!(c[k] >= 0.0 && c[k] <= 1.0))
            im.fail(PT_ERR_FORMAT, "light %d ('%s'): color is not in [0, 1]", int(li), p.name);
    if (!(l.intensity >= 0.0) || !std::isfinite(l.intensity))
        im.fail(PT_ERR_FORMAT, "light %d ('%s'): intensity is negative or not finite", int(li),
                p.name);
    p.intensity =
        pt_v3(float(c[0] * l.intensity), float(c[1] * l.intensity), float(c[2] * l.intensity));
    p.range = float(l.range);
    double d[3] = {-w[8], -w[9], -w[10]};
    double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if (!(len > 0.0) || !std::isfinite(len))
        im.fail(PT_ERR_FORMAT, "node %d: light '%s' has a degenerate transform", ni, p.name);
    p.direction = pt_v3(float(d[0] / len), float(d[1] / len), float(d[2] / len));
    if (p.type == PT_PUNCTUAL_SPOT) {
        double inner = l.spot.innerConeAngle, outer = l.spot.outerConeAngle;
        if (!(inner >= 0.0 && inner < outer && outer <= 1.5707963267948966 + 1e-6))
            im.fail(PT_ERR_FORMAT,
                    "light %d ('%s'): spot cone angles %g, %g are not 0 <= inner < outer <= pi/2",
                    int(li), p.name, inner, outer);
        p.cos_inner = float(std::cos(inner));
        p.cos_outer = float(std::cos(outer));
        if (!(p.cos_inner > p.cos_outer)) // angles too close to tell apart in float
            p.cos_inner = std::nextafter(p.cos_outer, 2.0f);
        if (p.cos_outer < 0.0f)
            p.cos_outer = 0.0f;
    }
    const double pos[3] = {w[12], w[13], w[14]};
    pt_error e{};
    pt_status st = pt_scene_builder_add_punctual(im.b, &p, pos, &e);
    if (st != PT_OK)
        im.fail(st, "node %d: %s", ni, e.msg);
}

// ---- the animation rig (anim.h), read only for pt_anim_load -------------------------

// An accessor of `type` as floats, of a component type kinds allows
// (glTF 3.11: rotations and weights may be normalized integers; morph
// deltas 3.7.2.2, and KHR_mesh_quantization's).
void rig_floats(importer &im, int ai, const char *what, int type, comp_kinds kinds,
                uint64_t max_count, std::vector<float> &out)
{
    view_span s = accessor_span(im, ai, what, type, max_count);
    int nc = type_comps(type);
    if (!comp_allowed(s.ctype, s.normalized, kinds))
        im.fail(PT_ERR_FORMAT, "accessor %d (%s): component type %d is not supported", ai, what,
                s.ctype);
    out.assign(size_t(s.count) * size_t(nc), 0.0f);
    if (!s.data)
        return;
    int cs = comp_size(s.ctype);
    for (uint64_t i = 0; i < s.count; i++)
        for (int c = 0; c < nc; c++)
            out[size_t(i) * size_t(nc) + size_t(c)] =
                read_comp(s.data + i * s.stride + uint64_t(c * cs), s.ctype, s.normalized);
    for (size_t i = 0; i < out.size(); i++)
        if (!std::isfinite(out[i]))
            im.fail(PT_ERR_FORMAT, "accessor %d (%s): element %zu is not finite", ai, what,
                    i / size_t(nc));
}

// The skin attributes of a primitive instance: JOINTS_n (u8/u16) and
// WEIGHTS_n (float or normalized u8/u16) for n = 0 and, when present, 1;
// every joint index must name one of the skin's joints.
void rig_skin_attrs(importer &im, const tinygltf::Primitive &p, const char *what, int skin,
                    pt_rig::prim &rp)
{
    size_t nj = im.model.skins[size_t(skin)].joints.size();
    int sets = p.attributes.count("JOINTS_1") && p.attributes.count("WEIGHTS_1") ? 2 : 1;
    rp.influences = 4 * sets;
    rp.joints.assign(size_t(rp.nv) * size_t(rp.influences), 0);
    rp.weights.assign(size_t(rp.nv) * size_t(rp.influences), 0.0f);
    for (int set = 0; set < sets; set++) {
        std::string jn = "JOINTS_" + std::to_string(set), wn = "WEIGHTS_" + std::to_string(set);
        auto j_it = p.attributes.find(jn), w_it = p.attributes.find(wn);
        if (j_it == p.attributes.end() || w_it == p.attributes.end())
            im.fail(PT_ERR_FORMAT, "%s: skinned by skin %d but has no %s and %s", what, skin,
                    jn.c_str(), wn.c_str());
        char w2[200];
        snprintf(w2, sizeof w2, "%s of %s", jn.c_str(), what);
        view_span js = accessor_span(im, j_it->second, w2, TINYGLTF_TYPE_VEC4, rp.nv);
        if (js.count != rp.nv)
            im.fail(PT_ERR_FORMAT, "accessor %d (%s): %llu joints for %u positions", j_it->second,
                    w2, (unsigned long long)js.count, rp.nv);
        if (js.ctype != TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE &&
            js.ctype != TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT)
            im.fail(PT_ERR_FORMAT, "accessor %d (%s): component type %d is not u8/u16",
                    j_it->second, w2, js.ctype);
        std::vector<float> wt;
        char w3[200];
        snprintf(w3, sizeof w3, "%s of %s", wn.c_str(), what);
        rig_floats(im, w_it->second, w3, TINYGLTF_TYPE_VEC4, COMP_UNORM, rp.nv, wt);
        if (wt.size() / 4 != rp.nv)
            im.fail(PT_ERR_FORMAT, "accessor %d (%s): %zu weights for %u positions", w_it->second,
                    w3, wt.size() / 4, rp.nv);
        for (uint32_t v = 0; v < rp.nv; v++)
            for (int c = 0; c < 4; c++) {
                uint32_t j = 0;
                if (js.data) {
                    const unsigned char *e = js.data + v * js.stride;
                    j = js.ctype == TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE
                            ? e[c]
                            : uint32_t(e[2 * c] | e[2 * c + 1] << 8);
                }
                if (j >= nj)
                    im.fail(PT_ERR_FORMAT,
                            "accessor %d (%s): vertex %u names joint %u, but skin %d has %zu "
                            "joints",
                            j_it->second, w2, v, j, skin, nj);
                size_t o = size_t(v) * size_t(rp.influences) + size_t(set * 4 + c);
                rp.joints[o] = j;
                rp.weights[o] = wt[size_t(v) * 4 + size_t(c)];
            }
    }
}

// Records mesh primitive `pi` of node ni, which the builder stored in the
// ranges between the counts `before` and `after`, with its rest data.
void rig_add_primitive(importer &im, int ni, int mesh, int pi, const uint32_t before[4],
                       const uint32_t after[4], const double *inst)
{
    if (after[0] == before[0])
        return; // not rendered (points, lines, no triangles)
    const tinygltf::Node &n = im.model.nodes[size_t(ni)];
    const tinygltf::Primitive &p = im.model.meshes[size_t(mesh)].primitives[size_t(pi)];
    char what[96];
    snprintf(what, sizeof what, "mesh %d primitive %d", mesh, pi);
    pt_rig::prim rp;
    rp.node = ni;
    rp.mesh = mesh;
    rp.index = pi;
    rp.v0 = before[0];
    rp.nv = after[0] - before[0];
    rp.t0 = before[1];
    rp.nt = after[1] - before[1];
    char w2[160];
    snprintf(w2, sizeof w2, "POSITION of %s", what);
    read_floats(im, p.attributes.at("POSITION"), w2, TINYGLTF_TYPE_VEC3, COMP_INT16, rp.pos);
    // Without NORMAL the builder stored one vertex a corner (add_primitive):
    // read the file's vertices, then do the same.
    const bool flat = p.attributes.find("NORMAL") == p.attributes.end();
    const uint32_t nv_built = rp.nv;
    const uint32_t nv_file = uint32_t(rp.pos.size() / 3);
    if (flat)
        rp.nv = nv_file;
    auto n_it = p.attributes.find("NORMAL");
    if (n_it != p.attributes.end()) {
        snprintf(w2, sizeof w2, "NORMAL of %s", what);
        read_floats(im, n_it->second, w2, TINYGLTF_TYPE_VEC3, COMP_SNORM, rp.nrm);
    }
    auto tg_it = p.attributes.find("TANGENT");
    if (tg_it != p.attributes.end()) {
        snprintf(w2, sizeof w2, "TANGENT of %s", what);
        read_floats(im, tg_it->second, w2, TINYGLTF_TYPE_VEC4, COMP_SNORM, rp.tan);
        for (size_t i = 3; i < rp.tan.size(); i += 4)
            rp.tan[i] = rp.tan[i] < 0.0f ? -1.0f : 1.0f;
    }
    if (rp.pos.size() / 3 != rp.nv || (!rp.nrm.empty() && rp.nrm.size() / 3 != rp.nv) ||
        (!rp.tan.empty() && rp.tan.size() / 4 != rp.nv))
        im.fail(PT_ERR_FORMAT, "%s: attribute counts disagree", what);
    if (p.targets.size() > PT_ANIM_MAX_TARGETS)
        im.fail(PT_ERR_LIMIT, "%s: %zu morph targets (at most %u)", what, p.targets.size(),
                PT_ANIM_MAX_TARGETS);
    for (size_t k = 0; k < p.targets.size(); k++) {
        rp.dpos.emplace_back();
        rp.dnrm.emplace_back();
        rp.dtan.emplace_back();
        static const char *names[3] = {"POSITION", "NORMAL", "TANGENT"};
        std::vector<float> *dst[3] = {&rp.dpos.back(), &rp.dnrm.back(), &rp.dtan.back()};
        for (int a = 0; a < 3; a++) {
            auto it = p.targets[k].find(names[a]);
            if (it == p.targets[k].end())
                continue;
            snprintf(w2, sizeof w2, "morph target %zu %s of %s", k, names[a], what);
            rig_floats(im, it->second, w2, TINYGLTF_TYPE_VEC3, a == 0 ? COMP_INT16 : COMP_SNORM,
                       rp.nv, *dst[a]);
            if (dst[a]->size() / 3 != rp.nv)
                im.fail(PT_ERR_FORMAT, "accessor %d (%s): %zu deltas for %u positions", it->second,
                        w2, dst[a]->size() / 3, rp.nv);
        }
    }
    if (n.skin >= 0) {
        if (size_t(n.skin) >= im.model.skins.size())
            im.fail(PT_ERR_FORMAT, "node %d: skin %d out of range (%zu skins)", ni, n.skin,
                    im.model.skins.size());
        rp.skin = n.skin;
        rig_skin_attrs(im, p, what, n.skin, rp);
    }
    if (flat) {
        std::vector<uint32_t> tri = triangle_list(im, p, rp.nv, what);
        if (tri.size() != nv_built)
            im.fail(PT_ERR_FORMAT, "%s: attribute counts disagree", what);
        rp.pos = unweld(rp.pos, tri, 3);
        rp.tan.clear(); // ignored without NORMAL (glTF 2.0, 3.7.2.1)
        for (size_t k = 0; k < rp.dpos.size(); k++) {
            rp.dpos[k] = unweld(rp.dpos[k], tri, 3);
            rp.dnrm[k].clear();
            rp.dtan[k].clear();
        }
        if (rp.influences > 0) {
            size_t in = size_t(rp.influences);
            std::vector<uint32_t> j(tri.size() * in);
            for (size_t k = 0; k < tri.size(); k++)
                for (size_t c = 0; c < in; c++)
                    j[k * in + c] = rp.joints[size_t(tri[k]) * in + c];
            rp.joints.swap(j);
            rp.weights = unweld(rp.weights, tri, in);
        }
        rp.nv = nv_built;
    }
    if (rp.tan.empty()) {
        // The tangents the load generated in the mesh's space (the builder's,
        // from the same numbers), mapped by the pose as a TANGENT would be.
        std::vector<float> uvs[2];
        for (int set = 0; set < 2; set++) {
            auto it = p.attributes.find(set ? "TEXCOORD_1" : "TEXCOORD_0");
            if (it == p.attributes.end())
                continue;
            snprintf(w2, sizeof w2, "TEXCOORD_%d of %s", set, what);
            read_floats(im, it->second, w2, TINYGLTF_TYPE_VEC2, COMP_INT16, uvs[set]);
        }
        std::vector<uint32_t> tri;
        if (flat) {
            tri.resize(rp.nv);
            for (uint32_t k = 0; k < rp.nv; k++)
                tri[k] = k;
            if (!uvs[0].empty() || !uvs[1].empty()) {
                std::vector<uint32_t> corners = triangle_list(im, p, nv_file, what);
                for (auto &u : uvs) {
                    if (!u.empty() && u.size() / 2 != nv_file)
                        im.fail(PT_ERR_FORMAT, "%s: attribute counts disagree", what);
                    if (!u.empty())
                        u = unweld(u, corners, 2);
                }
            }
        } else {
            tri = triangle_list(im, p, rp.nv, what);
        }
        bool ok = tri.size() % 3 == 0;
        for (auto &u : uvs)
            ok = ok && (u.empty() || u.size() / 2 == rp.nv);
        if (!ok)
            im.fail(PT_ERR_FORMAT, "%s: attribute counts disagree", what);
        uint32_t mat = material_index(im, variant_material(im, p, what), what);
        std::vector<float> tg(size_t(rp.nv) * 4);
        int made = 0;
        pt_error e{};
        pt_status st = pt_scene_builder_mesh_tangents(
            im.b, mat, rp.pos.data(), rp.nrm.empty() ? nullptr : rp.nrm.data(),
            uvs[0].empty() ? nullptr : uvs[0].data(), uvs[1].empty() ? nullptr : uvs[1].data(),
            rp.nv, tri.data(), uint32_t(tri.size() / 3), tg.data(), &made, &e);
        im.check_builder(st, &e);
        if (made)
            rp.tan.swap(tg);
    }
    if (inst) {
        rp.has_inst = true;
        memcpy(rp.inst, inst, sizeof rp.inst);
    }
    im.rig->prims.push_back(std::move(rp));
}

void rig_add_placed(importer &im, int ni, bool camera, const uint32_t before[4],
                    const uint32_t after[4])
{
    int k = camera ? 2 : 3;
    if (after[k] == before[k])
        return; // a camera of a type that is ignored
    pt_rig::placed pl;
    pl.node = ni;
    pl.index = before[k];
    (camera ? im.rig->cameras : im.rig->lights).push_back(pl);
}

// The number of morph targets of mesh mi (all its primitives must agree).
size_t rig_targets(importer &im, int mi)
{
    const tinygltf::Mesh &mesh = im.model.meshes[size_t(mi)];
    size_t n = mesh.primitives.empty() ? 0 : mesh.primitives[0].targets.size();
    for (size_t p = 1; p < mesh.primitives.size(); p++)
        if (mesh.primitives[p].targets.size() != n)
            im.fail(PT_ERR_FORMAT, "mesh %d: primitive %zu has %zu morph targets, primitive 0 %zu",
                    mi, p, mesh.primitives[p].targets.size(), n);
    return n;
}

// Nodes: parents (each node has at most one), local TRS, morph weights, and
// an order with every node after its parent; a node left out of that order
// lies on a cycle of the hierarchy.
void rig_nodes(importer &im)
{
    const tinygltf::Model &m = im.model;
    pt_anim &a = *im.rig;
    size_t nn = m.nodes.size();
    a.nodes.resize(nn);
    for (size_t i = 0; i < nn; i++) {
        const tinygltf::Node &n = m.nodes[i];
        pt_rig::node &rn = a.nodes[i];
        for (int c : n.children) {
            if (c < 0 || size_t(c) >= nn)
                im.fail(PT_ERR_FORMAT, "node %zu: child %d out of range (%zu nodes)", i, c, nn);
            if (a.nodes[size_t(c)].parent >= 0 || size_t(c) == i)
                im.fail(PT_ERR_FORMAT, "node %d has more than one parent (nodes %d and %zu)", c,
                        a.nodes[size_t(c)].parent, i);
            a.nodes[size_t(c)].parent = int(i);
        }
        if (!n.matrix.empty()) {
            mat4 lm = local_matrix(im, n, int(i));
            rn.has_matrix = true;
            for (size_t k = 0; k < 16; k++)
                rn.matrix[k] = lm[k];
        } else {
            (void)local_matrix(im, n, int(i)); // checks the sizes and finiteness
            for (size_t k = 0; k < n.translation.size(); k++)
                rn.t[k] = n.translation[k];
            for (size_t k = 0; k < n.rotation.size(); k++)
                rn.r[k] = n.rotation[k];
            for (size_t k = 0; k < n.scale.size(); k++)
                rn.s[k] = n.scale[k];
        }
        size_t nt = 0;
        if (n.mesh >= 0 && size_t(n.mesh) < m.meshes.size()) {
            nt = rig_targets(im, n.mesh);
            const std::vector<double> &mw = m.meshes[size_t(n.mesh)].weights;
            if (!mw.empty() && mw.size() != nt)
                im.fail(PT_ERR_FORMAT, "mesh %d: %zu weights for %zu morph targets", n.mesh,
                        mw.size(), nt);
            if (!n.weights.empty() && n.weights.size() != nt)
                im.fail(PT_ERR_FORMAT, "node %zu: %zu weights for %zu morph targets of mesh %d", i,
                        n.weights.size(), nt, n.mesh);
            rn.weights = !n.weights.empty() ? n.weights : mw;
            rn.weights.resize(nt, 0.0);
            for (double w : rn.weights)
                if (!std::isfinite(w))
                    im.fail(PT_ERR_FORMAT, "node %zu: a morph weight is not finite", i);
        } else if (!n.weights.empty()) {
            im.fail(PT_ERR_FORMAT, "node %zu: %zu weights but no mesh with morph targets", i,
                    n.weights.size());
        }
    }
    std::vector<char> placed(nn, 0);
    std::vector<int> stack;
    for (size_t i = 0; i < nn; i++)
        if (a.nodes[i].parent < 0)
            stack.push_back(int(i));
    while (!stack.empty()) {
        int ni = stack.back();
        stack.pop_back();
        placed[size_t(ni)] = 1;
        a.order.push_back(ni);
        for (int c : m.nodes[size_t(ni)].children)
            stack.push_back(c);
    }
    for (size_t s = 0; s < m.skins.size(); s++)
        for (int j : m.skins[s].joints)
            if (j >= 0 && size_t(j) < nn && !placed[size_t(j)])
                im.fail(PT_ERR_FORMAT, "skin %zu: joint node %d: the node hierarchy has a cycle", s,
                        j);
    for (size_t i = 0; i < nn; i++)
        if (!placed[i])
            im.fail(PT_ERR_FORMAT, "node %zu: the node hierarchy has a cycle", i);
}

void rig_skins(importer &im)
{
    const tinygltf::Model &m = im.model;
    for (size_t s = 0; s < m.skins.size(); s++) {
        const tinygltf::Skin &sk = m.skins[s];
        pt_rig::skin rs;
        if (sk.joints.empty())
            im.fail(PT_ERR_FORMAT, "skin %zu: no joints", s);
        if (sk.joints.size() > PT_ANIM_MAX_JOINTS)
            im.fail(PT_ERR_LIMIT, "skin %zu: %zu joints (at most %u)", s, sk.joints.size(),
                    PT_ANIM_MAX_JOINTS);
        for (int j : sk.joints)
            if (j < 0 || size_t(j) >= m.nodes.size())
                im.fail(PT_ERR_FORMAT, "skin %zu: joint node %d out of range (%zu nodes)", s, j,
                        m.nodes.size());
        rs.joints = sk.joints;
        rs.ibm.assign(16 * sk.joints.size(), 0.0);
        for (size_t j = 0; j < sk.joints.size(); j++)
            for (int d = 0; d < 4; d++)
                rs.ibm[16 * j + size_t(d * 5)] = 1.0; // identity by default
        if (sk.inverseBindMatrices >= 0) {
            char what[80];
            snprintf(what, sizeof what, "inverseBindMatrices of skin %zu", s);
            std::vector<float> f;
            rig_floats(im, sk.inverseBindMatrices, what, TINYGLTF_TYPE_MAT4, COMP_FLOAT,
                       PT_ANIM_MAX_JOINTS, f);
            if (f.size() / 16 != sk.joints.size())
                im.fail(PT_ERR_FORMAT, "skin %zu: %zu inverse bind matrices for %zu joints", s,
                        f.size() / 16, sk.joints.size());
            for (size_t k = 0; k < f.size(); k++)
                rs.ibm[k] = f[k];
        }
        im.rig->skins.push_back(std::move(rs));
    }
}

// The animation(s) opts->animation names: -1 all, else one index. None
// named: the first, said once when there are several (playing them all at
// once is rarely what a file with a walk and a run means); "all" (unless
// an animation has that name): every one.
int rig_choose(importer &im)
{
    const char *name = im.opts ? im.opts->animation : nullptr;
    const auto &as = im.model.animations;
    if (!name || !*name) {
        if (as.size() < 2)
            return -1;
        im.warn_once("anim-first", "the scene has " + std::to_string(as.size()) +
                                       " animations; playing the first, 0 '" +
                                       shown(as[0].name.substr(0, 64)) +
                                       "' (--animation NAME, INDEX or all chooses)");
        return 0;
    }
    for (size_t i = 0; i < as.size(); i++)
        if (as[i].name == name)
            return int(i);
    if (strcmp(name, "all") == 0)
        return -1;
    char *end = nullptr;
    errno = 0;
    unsigned long idx = strtoul(name, &end, 10);
    if (name[0] >= '0' && name[0] <= '9' && end && !*end && errno == 0 && idx < as.size())
        return int(idx);
    if (as.empty())
        im.fail(PT_ERR_ARG, "no animation '%.64s': the scene has no animations",
                shown(name).c_str());
    std::string list;
    for (size_t i = 0; i < as.size() && list.size() < 300; i++)
        list += (i ? ", " : "") + std::to_string(i) + " '" + shown(as[i].name.substr(0, 64)) + "'";
    if (list.size() >= 300)
        list += "...";
    im.fail(PT_ERR_ARG, "no animation '%.64s'; animations: %s", shown(name).c_str(), list.c_str());
}

// Every animation is checked (a malformed one fails the load whichever is
// chosen); the chosen one's channels go to the rig, one sampler each.
void rig_animations(importer &im)
{
    const tinygltf::Model &m = im.model;
    pt_anim &a = *im.rig;
    int chosen = rig_choose(im);
    bool any = false;
    for (size_t ai = 0; ai < m.animations.size(); ai++) {
        const tinygltf::Animation &an = m.animations[ai];
        char ctx[120];
        snprintf(ctx, sizeof ctx, "animation %zu ('%.48s')", ai, shown(an.name).c_str());
        std::map<std::array<int, 4>, int> read; // (sampler, comps, type, normalized ok) -> index
        for (size_t ci = 0; ci < an.channels.size(); ci++) {
            const tinygltf::AnimationChannel &ch = an.channels[ci];
            if (ch.target_node < 0) { // no node: an extension's target (glTF 3.11)
                im.warn_once("anim-no-node", std::string(ctx) + " channel " + std::to_string(ci) +
                                                 " has no target node (an extension's); ignored");
                continue;
            }
            if (size_t(ch.target_node) >= m.nodes.size())
                im.fail(PT_ERR_FORMAT, "%s channel %zu: node %d out of range (%zu nodes)", ctx, ci,
                        ch.target_node, m.nodes.size());
            int path;
            int comps;
            int type;
            const tinygltf::Node &tn = m.nodes[size_t(ch.target_node)];
            if (ch.target_path == "translation") {
                path = pt_rig::PATH_T, comps = 3, type = TINYGLTF_TYPE_VEC3;
            } else if (ch.target_path == "rotation") {
                path = pt_rig::PATH_R, comps = 4, type = TINYGLTF_TYPE_VEC4;
            } else if (ch.target_path == "scale") {
                path = pt_rig::PATH_S, comps = 3, type = TINYGLTF_TYPE_VEC3;
            } else if (ch.target_path == "weights") {
                path = pt_rig::PATH_W, type = TINYGLTF_TYPE_SCALAR;
                comps = int(a.nodes[size_t(ch.target_node)].weights.size());
                if (comps == 0)
                    im.fail(PT_ERR_FORMAT,
                            "%s channel %zu: animates the weights of node %d, which has no "
                            "morph targets",
                            ctx, ci, ch.target_node);
            } else {
                im.warn_once("anim-path:" + ch.target_path,
                             std::string(ctx) + " channel " + std::to_string(ci) + ": path '" +
                                 shown(ch.target_path) + "' is not animated");
                continue;
            }
            if (path != pt_rig::PATH_W && !tn.matrix.empty())
                im.fail(PT_ERR_FORMAT, "%s channel %zu: animates node %d, which has a matrix", ctx,
                        ci, ch.target_node);
            if (ch.sampler < 0 || size_t(ch.sampler) >= an.samplers.size())
                im.fail(PT_ERR_FORMAT, "%s channel %zu: sampler %d out of range (%zu samplers)",
                        ctx, ci, ch.sampler, an.samplers.size());
            bool take = chosen < 0 || size_t(chosen) == ai;
            // A sampler that several channels share is read once (as the
            // same kind of value): a file cannot multiply its keys by
            // repeating channels.
            std::array<int, 4> key = {ch.sampler, comps, type,
                                      path == pt_rig::PATH_R || path == pt_rig::PATH_W};
            auto seen = read.find(key);
            if (seen != read.end()) {
                if (take)
                    a.channels.push_back({ch.target_node, path, seen->second});
                continue;
            }
            const tinygltf::AnimationSampler &sm = an.samplers[size_t(ch.sampler)];
            char sctx[200];
            snprintf(sctx, sizeof sctx, "%s sampler %d", ctx, ch.sampler);
            pt_rig::sampler rs;
            rs.comps = comps;
            if (sm.interpolation == "STEP")
                rs.interp = pt_rig::INTERP_STEP;
            else if (sm.interpolation == "CUBICSPLINE")
                rs.interp = pt_rig::INTERP_CUBIC;
            else if (sm.interpolation.empty() || sm.interpolation == "LINEAR")
                rs.interp = pt_rig::INTERP_LINEAR;
            else
                im.fail(PT_ERR_FORMAT,
                        "%s: interpolation '%.32s' is not STEP, LINEAR or CUBICSPLINE", sctx,
                        shown(sm.interpolation).c_str());
            char what[240];
            snprintf(what, sizeof what, "input of %s", sctx);
            rig_floats(im, sm.input, what, TINYGLTF_TYPE_SCALAR, COMP_FLOAT, PT_ANIM_MAX_KEYS,
                       rs.in);
            for (size_t k = 1; k < rs.in.size(); k++)
                if (!(rs.in[k] > rs.in[k - 1]))
                    im.fail(PT_ERR_FORMAT,
                            "%s: input times are not increasing at key %zu (%g after %g)", sctx, k,
                            double(rs.in[k]), double(rs.in[k - 1]));
            snprintf(what, sizeof what, "output of %s", sctx);
            rig_floats(im, sm.output, what, type,
                       path == pt_rig::PATH_R || path == pt_rig::PATH_W ? COMP_SNORM : COMP_FLOAT,
                       uint64_t(PT_ANIM_MAX_KEYS) * 3 * PT_ANIM_MAX_TARGETS, rs.out);
            size_t per = size_t(comps) * (rs.interp == pt_rig::INTERP_CUBIC ? 3 : 1);
            if (rs.out.size() != rs.in.size() * per)
                im.fail(PT_ERR_FORMAT,
                        "%s: %zu output numbers for %zu keys (%s %s needs %zu a key)", sctx,
                        rs.out.size(), rs.in.size(), sm.interpolation.c_str(),
                        ch.target_path.c_str(), per);
            read[key] = take ? int(a.samplers.size()) : -1;
            if (!take)
                continue;
            double t0 = rs.in.front(), t1 = rs.in.back();
            a.start = any ? std::fmin(a.start, t0) : t0;
            a.end = any ? std::fmax(a.end, t1) : t1;
            any = true;
            pt_rig::channel rc;
            rc.node = ch.target_node;
            rc.path = path;
            rc.sampler = int(a.samplers.size());
            a.samplers.push_back(std::move(rs));
            a.channels.push_back(rc);
        }
    }
}

// Whether nothing in the file can move: no animations, skins or morph targets.
bool rig_static(const tinygltf::Model &m)
{
    if (!m.animations.empty() || !m.skins.empty())
        return false;
    for (const auto &mesh : m.meshes)
        for (const auto &p : mesh.primitives)
            if (!p.targets.empty())
                return false;
    return true;
}

// Whether a still looks as it would without a rig: no skins, and every
// morph target at weight 0 by default (node.weights, else mesh.weights).
// Such a still builds none and costs what it always has.
bool still_static(const tinygltf::Model &m)
{
    if (!m.skins.empty())
        return false;
    auto zero = [](const std::vector<double> &w) {
        for (double x : w)
            if (x != 0.0)
                return false;
        return true;
    };
    for (const auto &mesh : m.meshes)
        if (!zero(mesh.weights))
            return false;
    for (const auto &n : m.nodes)
        if (!zero(n.weights))
            return false;
    return true;
}

// After the scene's nodes were visited: the rest of the rig.
void rig_finish(importer &im)
{
    rig_nodes(im);
    rig_skins(im);
    if (!im.still)
        rig_animations(im);
    // What a pose must compute: instances under a node whose TRS a chosen
    // channel animates (or under such an ancestor), skinned or morphed ones,
    // and cameras and lights under animated nodes. The rest keep the load's
    // values, so a static part of an animated scene keeps a still's bits and
    // costs a pose nothing.
    pt_anim &a = *im.rig;
    std::vector<char> animated(a.nodes.size(), 0);
    for (const auto &ch : a.channels)
        if (ch.path != pt_rig::PATH_W)
            animated[size_t(ch.node)] = 1;
    for (int ni : a.order)
        if (a.nodes[size_t(ni)].parent >= 0 && animated[size_t(a.nodes[size_t(ni)].parent)])
            animated[size_t(ni)] = 1;
    a.moves = false;
    for (auto &p : a.prims) {
        p.dynamic = animated[size_t(p.node)] || p.skin >= 0 || !p.dpos.empty();
        a.moves = a.moves || p.dynamic;
    }
    for (auto *list : {&a.cameras, &a.lights})
        for (auto &pl : *list) {
            pl.dynamic = animated[size_t(pl.node)] != 0;
            a.moves = a.moves || pl.dynamic;
        }
}

// EXT_mesh_gpu_instancing on node n: the accessor of its attribute with
// the largest count and that count, or {-1, 0} without the extension.
// Counts only: instance_matrices reads them and checks that they agree.
std::pair<int, uint64_t> instance_count(const tinygltf::Model &m, const tinygltf::Node &n)
{
    auto ext = n.extensions.find("EXT_mesh_gpu_instancing");
    if (ext == n.extensions.end() || !ext->second.IsObject())
        return {-1, 0};
    const tinygltf::Value &at = ext->second.Get("attributes");
    if (!at.IsObject())
        return {-1, 0};
    std::pair<int, uint64_t> most{-1, 0};
    for (const auto &k : at.Keys()) {
        const tinygltf::Value &v = at.Get(k);
        if (!v.IsNumber())
            continue;
        double ai = v.GetNumberAsDouble();
        if (ai >= 0.0 && ai < double(m.accessors.size()) &&
            uint64_t(m.accessors[size_t(ai)].count) > most.second)
            most = {int(ai), uint64_t(m.accessors[size_t(ai)].count)};
    }
    return most;
}

// EXT_mesh_gpu_instancing: node ni's instances, each the matrix T * R * S
// of its TRANSLATION (float VEC3), ROTATION (unit quaternion, float or
// normalized i8/i16 VEC4) and SCALE (float VEC3) attributes, which must all
// have the instance count; none without the extension. Each instance is
// the node's mesh under global(node) * instance. The mesh is copied once
// an instance (the triangle caps count every copy: check_triangles), not
// instanced in the accelerator.
std::vector<mat4> instance_matrices(importer &im, int ni)
{
    const tinygltf::Node &n = im.model.nodes[size_t(ni)];
    std::vector<mat4> out;
    auto ext = n.extensions.find("EXT_mesh_gpu_instancing");
    if (ext == n.extensions.end())
        return out;
    const tinygltf::Value &at = ext->second.Get("attributes");
    if (!ext->second.IsObject() || !at.IsObject())
        im.fail(PT_ERR_FORMAT, "node %d: EXT_mesh_gpu_instancing has no attributes", ni);
    std::vector<float> t, r, s;
    uint64_t count = 0;
    for (const auto &k : at.Keys()) {
        const tinygltf::Value &v = at.Get(k);
        bool tr = k == "TRANSLATION", ro = k == "ROTATION", sc = k == "SCALE";
        if (!tr && !ro && !sc) {
            im.warn_once("inst-attr:" + k, "node " + std::to_string(ni) +
                                               ": EXT_mesh_gpu_instancing attribute " + shown(k) +
                                               " is ignored");
            continue;
        }
        if (!v.IsNumber())
            im.fail(PT_ERR_FORMAT, "node %d: EXT_mesh_gpu_instancing %s is not an accessor", ni,
                    k.c_str());
        char what[96];
        snprintf(what, sizeof what, "EXT_mesh_gpu_instancing %s of node %d", k.c_str(), ni);
        std::vector<float> &dst = tr ? t : ro ? r : s;
        read_floats(im, int(v.GetNumberAsDouble()), what,
                    ro ? TINYGLTF_TYPE_VEC4 : TINYGLTF_TYPE_VEC3, ro ? COMP_SNORM : COMP_FLOAT,
                    dst);
        uint64_t c = dst.size() / (ro ? 4 : 3);
        if (count && c != count)
            im.fail(PT_ERR_FORMAT,
                    "node %d: EXT_mesh_gpu_instancing attributes disagree on the count (%llu "
                    "and %llu)",
                    ni, (unsigned long long)count, (unsigned long long)c);
        count = c;
    }
    if (count == 0)
        im.fail(PT_ERR_FORMAT,
                "node %d: EXT_mesh_gpu_instancing has no TRANSLATION, ROTATION "
                "or SCALE",
                ni);
    out.resize(size_t(count));
    for (size_t i = 0; i < out.size(); i++) {
        double tt[3] = {0, 0, 0}, q[4] = {0, 0, 0, 1}, ss[3] = {1, 1, 1};
        for (int c = 0; c < 3 && !t.empty(); c++)
            tt[c] = t[3 * i + size_t(c)];
        for (int c = 0; c < 4 && !r.empty(); c++)
            q[c] = r[4 * i + size_t(c)];
        for (int c = 0; c < 3 && !s.empty(); c++)
            ss[c] = s[3 * i + size_t(c)];
        pt_rig::trs_matrix(tt, q, ss, out[i].data());
        for (double x : out[i])
            if (!std::isfinite(x))
                im.fail(PT_ERR_FORMAT,
                        "node %d: EXT_mesh_gpu_instancing instance %zu is not "
                        "finite",
                        ni, i);
    }
    return out;
}

// A portal node: extras {"ptfarm_portal": true} (or a number other than 0),
// which Blender's glTF exporter writes from an object's custom property of
// that name (Include > Custom Properties).
bool is_portal(const tinygltf::Node &n)
{
    if (!n.extras.IsObject() || !n.extras.Has("ptfarm_portal"))
        return false;
    const tinygltf::Value &v = n.extras.Get("ptfarm_portal");
    return (v.IsBool() && v.Get<bool>()) || (v.IsNumber() && v.GetNumberAsDouble() != 0.0);
}

// A portal node's mesh (PT_FEAT_PORTAL): its triangles under the node's
// world matrix become openings the environment lights the scene through,
// not geometry. They are placed as the file's still is (an animation does
// not move them) and take no EXT_mesh_gpu_instancing copies. A node that
// mirrors (its world matrix's determinant negative) makes a primitive's
// front face clockwise (glTF 2.0, 3.7.4), so its corners are taken in the
// other order: the front stays the side the file means (the scene builder
// flips a mesh's winding alike).
void add_portal(importer &im, int ni, int mesh, const mat4 &w)
{
    const double det = w[0] * (w[5] * w[10] - w[9] * w[6]) - w[4] * (w[1] * w[10] - w[9] * w[2]) +
                       w[8] * (w[1] * w[6] - w[5] * w[2]);
    const size_t order[2][3] = {{0, 1, 2}, {0, 2, 1}};
    const size_t *corner = order[det < 0.0];
    const tinygltf::Mesh &m = im.model.meshes[size_t(mesh)];
    const tinygltf::Node &n = im.model.nodes[size_t(ni)];
    std::string name = n.name.empty() ? "node " + std::to_string(ni) : n.name;
    for (size_t pi = 0; pi < m.primitives.size(); pi++) {
        const tinygltf::Primitive &p = m.primitives[pi];
        char what[160];
        snprintf(what, sizeof what, "portal %.64s (mesh %d primitive %zu)", name.c_str(), mesh, pi);
        draco_primitive(im, mesh, int(pi), what);
        int mode = p.mode < 0 ? TINYGLTF_MODE_TRIANGLES : p.mode;
        if (mode != TINYGLTF_MODE_TRIANGLES && mode != TINYGLTF_MODE_TRIANGLE_STRIP &&
            mode != TINYGLTF_MODE_TRIANGLE_FAN)
            im.fail(PT_ERR_FORMAT, "%s: primitive mode %d is not triangles", what, mode);
        auto pos_it = p.attributes.find("POSITION");
        if (pos_it == p.attributes.end())
            im.fail(PT_ERR_FORMAT, "%s: no POSITION attribute", what);
        std::vector<float> pos;
        read_floats(im, pos_it->second, what, TINYGLTF_TYPE_VEC3, COMP_INT16, pos);
        std::vector<uint32_t> tri = triangle_list(im, p, pos.size() / 3, what);
        for (size_t t = 0; t + 2 < tri.size(); t += 3) {
            double v[9];
            for (int k = 0; k < 3; k++) {
                const float *q = &pos[3 * size_t(tri[t + corner[k]])];
                for (int r = 0; r < 3; r++)
                    v[3 * k + r] = w[size_t(r)] * q[0] + w[size_t(4 + r)] * q[1] +
                                   w[size_t(8 + r)] * q[2] + w[size_t(12 + r)];
            }
            pt_error e{};
            im.check_builder(pt_scene_builder_add_portal(im.b, v, name.c_str(), &e), &e);
        }
    }
}

void visit(importer &im, int ni, const mat4 &parent, int depth, std::vector<char> &on_path)
{
    const tinygltf::Model &m = im.model;
    if (ni < 0 || size_t(ni) >= m.nodes.size())
        im.fail(PT_ERR_FORMAT, "node %d out of range (%zu nodes)", ni, m.nodes.size());
    if (depth > kMaxNodeDepth)
        im.fail(PT_ERR_LIMIT, "node %d: hierarchy deeper than %d", ni, kMaxNodeDepth);
    if (on_path[size_t(ni)])
        im.fail(PT_ERR_FORMAT, "node %d: the node hierarchy has a cycle", ni);
    if (++im.node_visits > kMaxNodeVisits)
        im.fail(PT_ERR_LIMIT, "node %d: more than %llu node instances", ni,
                (unsigned long long)kMaxNodeVisits);
    on_path[size_t(ni)] = 1;
    const tinygltf::Node &n = m.nodes[size_t(ni)];
    mat4 w = mat_mul(parent, local_matrix(im, n, ni));
    // With a rig, the builder's counts around each addition map it to the
    // scene's ranges (anim_rig.hpp).
    uint32_t before[4], after[4];
    if (n.mesh >= 0) {
        if (size_t(n.mesh) >= m.meshes.size())
            im.fail(PT_ERR_FORMAT, "node %d: mesh %d out of range (%zu meshes)", ni, n.mesh,
                    m.meshes.size());
        if (is_portal(n)) {
            add_portal(im, ni, n.mesh, w);
            goto children;
        }
        const tinygltf::Mesh &mesh = m.meshes[size_t(n.mesh)];
        // Cryptomatte's object: the node, by its name.
        pt_error oe{};
        std::string oname = n.name.empty() ? "node " + std::to_string(ni) : n.name;
        im.check_builder(pt_scene_builder_set_object(im.b, oname.c_str(), &oe), &oe);
        if (!im.gpu_instanced.empty() && im.gpu_instanced[size_t(ni)]) {
            im.instanced.push_back({ni, w}); // add_instanced
            goto children;
        }
        std::vector<mat4> inst = instance_matrices(im, ni);
        size_t copies = inst.empty() ? 1 : inst.size();
        for (size_t k = 0; k < copies; k++) {
            mat4 wk = inst.empty() ? w : mat_mul(w, inst[k]);
            for (size_t p = 0; p < mesh.primitives.size(); p++) {
                if (im.rig)
                    pt_scene_builder_counts(im.b, before);
                add_primitive(im, n.mesh, int(p), wk);
                if (im.rig) {
                    pt_scene_builder_counts(im.b, after);
                    rig_add_primitive(im, ni, n.mesh, int(p), before, after,
                                      inst.empty() ? nullptr : inst[k].data());
                }
            }
        }
    }
children:
    if (n.camera >= 0) {
        if (im.rig)
            pt_scene_builder_counts(im.b, before);
        add_camera(im, ni, n.camera, w);
        if (im.rig) {
            pt_scene_builder_counts(im.b, after);
            rig_add_placed(im, ni, true, before, after);
        }
    }
    auto lx = n.extensions.find("KHR_lights_punctual");
    if (lx != n.extensions.end()) {
        if (im.rig)
            pt_scene_builder_counts(im.b, before);
        add_light(im, ni, lx->second, w);
        if (im.rig) {
            pt_scene_builder_counts(im.b, after);
            rig_add_placed(im, ni, false, before, after);
        }
    }
    for (int c : n.children)
        visit(im, c, w, depth + 1, on_path);
    on_path[size_t(ni)] = 0;
}

// Whether node n's EXT_mesh_gpu_instancing instances can be kept as
// instances (a prototype placed by each, PT_FEAT_INSTANCES) rather than
// copies: a still without a rig (a pose moves each copy's vertices), and
// a mesh with nothing emissive (each light needs its triangles in scene
// space) and no KHR_materials_variants mapping (which could pick an
// emissive material).
bool gpu_instanced(const importer &im, const tinygltf::Node &n)
{
    const tinygltf::Model &m = im.model;
    if (im.rig || n.mesh < 0 || size_t(n.mesh) >= m.meshes.size() || instance_count(m, n).first < 0)
        return false;
    for (const auto &p : m.meshes[size_t(n.mesh)].primitives) {
        if (p.extensions.count("KHR_materials_variants"))
            return false;
        if (p.material < 0 || size_t(p.material) >= m.materials.size())
            continue;
        const tinygltf::Material &g = m.materials[size_t(p.material)];
        double strength = 1.0;
        auto es = g.extensions.find("KHR_materials_emissive_strength");
        if (es != g.extensions.end())
            strength = ext_number(es->second, "emissiveStrength", 1.0);
        for (double f : g.emissiveFactor)
            if (!(f * strength <= 0.0)) // NaN too: let the copies' checks name it
                return false;
    }
    return true;
}

// The instanced visits (visit): each node's mesh once as a prototype,
// shared by every node that instances it, then one instance for each of the
// node's instances under its world matrix, in the node's Cryptomatte object
// (its name, else "node N"), as its copies would be: the prototype's
// triangles are named by the first node, its instances each by their own.
// After every flat mesh, as the builder wants.
void add_instanced(importer &im)
{
    std::map<int, uint32_t> proto_of_mesh;
    for (const auto &v : im.instanced) {
        const tinygltf::Node &n = im.model.nodes[size_t(v.node)];
        std::vector<mat4> inst = instance_matrices(im, v.node);
        auto it = proto_of_mesh.find(n.mesh);
        uint32_t proto;
        pt_error e{};
        std::string oname = n.name.empty() ? "node " + std::to_string(v.node) : n.name;
        im.check_builder(pt_scene_builder_set_object(im.b, oname.c_str(), &e), &e);
        if (it == proto_of_mesh.end()) {
            im.check_builder(pt_scene_builder_begin_prototype(im.b, &proto, &e), &e);
            const tinygltf::Mesh &mesh = im.model.meshes[size_t(n.mesh)];
            for (size_t p = 0; p < mesh.primitives.size(); p++)
                add_primitive(im, n.mesh, int(p), identity());
            im.check_builder(pt_scene_builder_end_prototype(im.b, &e), &e);
            proto_of_mesh[n.mesh] = proto;
        } else {
            proto = it->second;
        }
        for (size_t k = 0; k < inst.size(); k++) {
            mat4 wk = mat_mul(v.world, inst[k]);
            pt_status st = pt_scene_builder_add_instance(im.b, proto, wk.data(), &e);
            if (st != PT_OK)
                im.fail(st, "node %d: EXT_mesh_gpu_instancing instance %zu: %s", v.node, k, e.msg);
        }
    }
}

uint64_t sat_add(uint64_t a, uint64_t b)
{
    return a > UINT64_MAX - b ? UINT64_MAX : a + b;
}

uint64_t sat_mul(uint64_t a, uint64_t b)
{
    uint64_t r;
    return __builtin_mul_overflow(a, b, &r) ? UINT64_MAX : r;
}

// Triangles and vertices, as the builder counts them, and morph target
// deltas (vertices x targets), as the rig keeps them.
// inst: EXT_mesh_gpu_instancing instances kept as instances.
struct geo_count {
    uint64_t tri = 0, vtx = 0, deltas = 0, inst = 0;
    void add(const geo_count &o)
    {
        tri = sat_add(tri, o.tri);
        vtx = sat_add(vtx, o.vtx);
        deltas = sat_add(deltas, o.deltas);
        inst = sat_add(inst, o.inst);
    }
};

// What add_primitive adds to the builder for one instance of mesh `mi`, from
// the accessors' counts alone (nothing for a primitive it skips or refuses:
// it reports those itself).
geo_count mesh_count(const tinygltf::Model &m, int mi)
{
    geo_count n;
    for (const auto &p : m.meshes[size_t(mi)].primitives) {
        int mode = p.mode < 0 ? TINYGLTF_MODE_TRIANGLES : p.mode;
        if (mode != TINYGLTF_MODE_TRIANGLES && mode != TINYGLTF_MODE_TRIANGLE_STRIP &&
            mode != TINYGLTF_MODE_TRIANGLE_FAN)
            continue;
        auto it = p.attributes.find("POSITION");
        int pa = it == p.attributes.end() ? -1 : it->second;
        if (pa < 0 || size_t(pa) >= m.accessors.size())
            continue;
        int ai = p.indices >= 0 ? p.indices : pa;
        if (size_t(ai) >= m.accessors.size())
            continue;
        // An accessor over the cap is refused by its reader, which names it.
        uint64_t c = uint64_t(m.accessors[size_t(ai)].count);
        uint64_t v = uint64_t(m.accessors[size_t(pa)].count);
        if (c > PT_SCENE_MAX_TRIANGLES * 3ull || v > PT_SCENE_MAX_TRIANGLES * 3ull)
            continue;
        geo_count g;
        g.tri = mode == TINYGLTF_MODE_TRIANGLES ? c / 3 : c >= 3 ? c - 2 : 0;
        // Without NORMAL, one vertex a corner (add_primitive).
        g.vtx = p.attributes.count("NORMAL") ? v : 3 * g.tri;
        g.deltas = g.vtx * uint64_t(p.targets.size() < PT_ANIM_MAX_TARGETS ? p.targets.size()
                                                                           : PT_ANIM_MAX_TARGETS);
        n.add(g);
    }
    return n;
}

// What is under node ni, every instance counted, remembered per node: a
// node may have several parents, and the count of a deep graph of shared
// nodes is a product that no walk could afford. Bad indices, cycles and
// depth count nothing here; visit() refuses them.
geo_count node_count(const tinygltf::Model &m, int ni, int depth,
                     const std::vector<geo_count> &per_mesh, std::vector<geo_count> &memo,
                     std::vector<char> &state, const std::vector<char> &instanced)
{
    if (ni < 0 || size_t(ni) >= m.nodes.size() || depth > kMaxNodeDepth)
        return geo_count();
    char &st = state[size_t(ni)];
    if (st != 0)
        return st == 2 ? memo[size_t(ni)] : geo_count();
    st = 1;
    const tinygltf::Node &n = m.nodes[size_t(ni)];
    geo_count t;
    if (n.mesh >= 0 && size_t(n.mesh) < m.meshes.size()) {
        t = per_mesh[size_t(n.mesh)];
        uint64_t copies = instance_count(m, n).second;
        if (instanced[size_t(ni)]) // the mesh once (at most: prototypes are shared)
            t.inst = copies;
        else if (copies > 1) // EXT_mesh_gpu_instancing: one copy an instance
            t = geo_count{sat_mul(t.tri, copies), sat_mul(t.vtx, copies), sat_mul(t.deltas, copies),
                          0};
    }
    for (int c : n.children)
        t.add(node_count(m, c, depth + 1, per_mesh, memo, state, instanced));
    st = 2;
    memo[size_t(ni)] = t;
    return t;
}

// Refuses a scene whose meshes, once instanced by its nodes, make more than
// PT_SCENE_MAX_TRIANGLES triangles or PT_SCENE_MAX_VERTICES vertices, before
// anything is read or decoded: a small file can instance one mesh many times
// over (u8 indices make a triangle of 3 bytes). The builder checks the same
// caps as it goes.
void check_triangles(importer &im, int si)
{
    const tinygltf::Model &m = im.model;
    // EXT_mesh_gpu_instancing: a node's instances are capped before
    // anything reads the accessors (a count of 2^31 in a few bytes of
    // JSON): kept as instances (gpu_instanced), by PT_SCENE_MAX_INSTANCES;
    // as copies of the mesh, as triangles are.
    im.gpu_instanced.assign(m.nodes.size(), 0);
    for (size_t i = 0; i < m.nodes.size(); i++) {
        std::pair<int, uint64_t> ic = instance_count(m, m.nodes[i]);
        im.gpu_instanced[i] = gpu_instanced(im, m.nodes[i]);
        if (im.gpu_instanced[i] && ic.second > PT_SCENE_MAX_INSTANCES)
            im.fail(PT_ERR_LIMIT,
                    "node %zu: EXT_mesh_gpu_instancing: %llu instances (accessor %d), over the "
                    "cap of %u a scene",
                    i, (unsigned long long)ic.second, ic.first, PT_SCENE_MAX_INSTANCES);
        if (!im.gpu_instanced[i] && ic.second > PT_SCENE_MAX_TRIANGLES)
            im.fail(PT_ERR_LIMIT,
                    "node %zu: EXT_mesh_gpu_instancing: %llu instances (accessor %d), over the "
                    "cap of %u a scene (instances are copied: the mesh is emissive, or posed)",
                    i, (unsigned long long)ic.second, ic.first, PT_SCENE_MAX_TRIANGLES);
    }
    std::vector<geo_count> per_mesh(m.meshes.size()), memo(m.nodes.size());
    std::vector<char> state(m.nodes.size(), 0);
    for (size_t i = 0; i < m.meshes.size(); i++)
        per_mesh[i] = mesh_count(m, int(i));
    geo_count total;
    for (int ni : m.scenes[size_t(si)].nodes)
        total.add(node_count(m, ni, 0, per_mesh, memo, state, im.gpu_instanced));
    if (total.inst > PT_SCENE_MAX_INSTANCES)
        im.fail(PT_ERR_LIMIT,
                "scene %d: %llu EXT_mesh_gpu_instancing instances once every node is counted, "
                "over the cap of %u a scene",
                si, (unsigned long long)total.inst, PT_SCENE_MAX_INSTANCES);
    uint32_t max_tri = PT_SCENE_MAX_TRIANGLES;
    if (im.opts && im.opts->max_triangles && im.opts->max_triangles < max_tri)
        max_tri = im.opts->max_triangles;
    if (total.tri > max_tri)
        im.fail(PT_ERR_LIMIT,
                "scene %d: %llu triangles once every instance of its meshes is counted, over the "
                "cap of %u a scene",
                si, (unsigned long long)total.tri, max_tri);
    if (total.vtx > 3ull * max_tri)
        im.fail(PT_ERR_LIMIT,
                "scene %d: %llu vertices once every instance of its meshes is counted, over the "
                "cap of %llu a scene",
                si, (unsigned long long)total.vtx, 3ull * max_tri);
    // Only a rig keeps the deltas: a still ignores morph targets. A lower
    // triangle cap lowers this one in proportion.
    unsigned long long max_deltas =
        (unsigned long long)PT_ANIM_MAX_MORPH_DELTAS / PT_SCENE_MAX_TRIANGLES * max_tri;
    if (im.rig && total.deltas > max_deltas)
        im.fail(PT_ERR_LIMIT,
                "scene %d: %llu morph target deltas (vertices x targets) once every instance of "
                "its meshes is counted, over the cap of %llu a scene for an animated load",
                si, (unsigned long long)total.deltas, max_deltas);
}

// Reads the external buffer and image files (for the hash and for decoding),
// in the order of the JSON arrays, and hashes them after the entry file.
void hash_files(importer &im, const std::vector<unsigned char> &entry)
{
    EVP_MD_CTX *ctx = EVP_MD_CTX_new();
    if (!ctx)
        im.fail(PT_ERR_NOMEM, "out of memory");
    struct guard {
        EVP_MD_CTX *c;
        ~guard() { EVP_MD_CTX_free(c); }
    } g{ctx};
    EVP_DigestInit_ex(ctx, EVP_sha256(), nullptr);
    EVP_DigestUpdate(ctx, entry.data(), entry.size());
    std::vector<std::string> uris;
    for (const auto &buf : im.model.buffers)
        if (!buf.uri.empty() && !is_data_uri(buf.uri))
            uris.push_back(uri_decode(buf.uri));
    size_t nbuf = uris.size();
    for (const auto &img : im.model.images)
        if (img.bufferView < 0 && !img.uri.empty() && !is_data_uri(img.uri))
            uris.push_back(uri_decode(img.uri));
    for (size_t i = 0; i < uris.size(); i++) {
        if (im.files.count(uris[i]))
            continue; // hashed once, like the bundle stores it once
        std::vector<unsigned char> bytes;
        std::string msg;
        pt_status st = read_inside(im, uris[i], bytes, &msg);
        if (st != PT_OK) {
            // A missing image is a warning (the material keeps its factors);
            // a name that leads out of the folder, a link or a device is not.
            if (i < nbuf || st != PT_ERR_IO)
                im.fail(st, "%s file %s", i < nbuf ? "buffer" : "image", msg.c_str());
            im.warn_once("img:" + uris[i], "image file " + msg);
            continue;
        }
        EVP_DigestUpdate(ctx, bytes.data(), bytes.size());
        im.files.emplace(uris[i], std::move(bytes));
    }
    // Zeroed first: a failed digest reads as 64 zeros, as pt_sha256_hex's does.
    unsigned char md[EVP_MAX_MD_SIZE] = {0};
    EVP_DigestFinal_ex(ctx, md, nullptr);
    char hex[PT_HASH_HEX];
    pt_hash_hex(md, hex);
    pt_scene_builder_set_hash(im.b, hex);
    // Buffers are in the model already; keep only the image files.
    std::set<std::string> image_uris(uris.begin() + long(nbuf), uris.end());
    for (size_t i = 0; i < nbuf; i++)
        if (!image_uris.count(uris[i]))
            im.files.erase(uris[i]);
}

// The JSON given to tinygltf, where two extensions need it changed:
// - tinygltf refuses a primitive whose indices accessor has no buffer view,
//   which is how KHR_draco_mesh_compression primitives come (their indices
//   are in the Draco buffer): their "indices" are set aside
//   (im.draco_indices) and put back once it has parsed;
// - EXT_meshopt_compression's fallback buffers may have no uri and no data
//   (the extension's README, "fallback"), which tinygltf reads as a file
//   named "": they get a 4-byte data: URI instead, and views of them are
//   only ever read decoded (meshopt_view);
// - tinygltf decodes data: URIs of a few MIME types only: an image's
//   "data:image/webp;base64," (EXT_texture_webp) or "data:image/ktx2;..."
//   is given as application/octet-stream, whose bytes it keeps as they are.
// text is the JSON (a GLB's first chunk); the rewritten document is
// returned, or "" when nothing changed (or the JSON does not parse:
// tinygltf says why).
std::string prepare_json(importer &im, const char *text, size_t n)
{
    static const char draco[] = "KHR_draco_mesh_compression", meshopt[] = "EXT_meshopt_compression";
    std::string all(text, n);
    static const char webp_uri[] = "data:image/webp;base64,",
                      ktx2_uri[] = "data:image/ktx2;base64,";
    if (all.find(draco) == std::string::npos && all.find(meshopt) == std::string::npos &&
        all.find(webp_uri) == std::string::npos && all.find(ktx2_uri) == std::string::npos)
        return std::string();
    nlohmann::json doc = nlohmann::json::parse(text, text + n, nullptr, false);
    if (doc.is_discarded() || !doc.is_object())
        return std::string();
    bool any = false;
    if (doc.contains("meshes") && doc["meshes"].is_array()) {
        auto &meshes = doc["meshes"];
        for (size_t mi = 0; mi < meshes.size(); mi++) {
            auto &mesh = meshes[mi];
            if (!mesh.is_object() || !mesh.contains("primitives") || !mesh["primitives"].is_array())
                continue;
            auto &prims = mesh["primitives"];
            for (size_t pi = 0; pi < prims.size(); pi++) {
                auto &pr = prims[pi];
                if (!pr.is_object() || !pr.contains("indices") ||
                    !pr["indices"].is_number_integer() || !pr.contains("extensions") ||
                    !pr["extensions"].is_object() || !pr["extensions"].contains(draco))
                    continue;
                long long ia = pr["indices"].get<long long>();
                if (ia < 0 || ia > INT32_MAX)
                    continue; // tinygltf refuses it
                im.draco_indices[{int(mi), int(pi)}] = int(ia);
                pr.erase("indices");
                any = true;
            }
        }
    }
    if (doc.contains("buffers") && doc["buffers"].is_array())
        for (auto &b : doc["buffers"]) {
            if (!b.is_object() || b.contains("uri") || !b.contains("extensions") ||
                !b["extensions"].is_object() || !b["extensions"].contains(meshopt))
                continue;
            const auto &e = b["extensions"][meshopt];
            if (!e.is_object() || !e.contains("fallback") || e["fallback"] != true)
                continue;
            b["uri"] = "data:application/octet-stream;base64,AAAAAA==";
            b["byteLength"] = 4;
            any = true;
        }
    if (doc.contains("images") && doc["images"].is_array())
        for (auto &img : doc["images"]) {
            if (!img.is_object() || !img.contains("uri") || !img["uri"].is_string())
                continue;
            std::string u = img["uri"].get<std::string>();
            for (const char *pre : {webp_uri, ktx2_uri})
                if (u.compare(0, strlen(pre), pre) == 0) {
                    img["uri"] = "data:application/octet-stream;base64," + u.substr(strlen(pre));
                    any = true;
                }
        }
    return any ? doc.dump() : std::string();
}

void parse(importer &im, const std::vector<unsigned char> &bytes)
{
    tinygltf::TinyGLTF loader;
    image_loader_ctx ictx{&im.data_uri_images};
    loader.SetImageLoader(keep_image_bytes, &ictx);
    tinygltf::FsCallbacks fs = {fs_exists, fs_expand, fs_read, fs_write, &im};
    loader.SetFsCallbacks(fs);
    std::string terr, twarn;
    bool ok, glb = false;
    if (bytes.empty())
        im.fail(PT_ERR_FORMAT, "file is empty");
    const std::vector<unsigned char> *src = &bytes; // what tinygltf parses
    std::vector<unsigned char> rewritten;
    bool glb_name = im.path.size() >= 4 && im.path.compare(im.path.size() - 4, 4, ".glb") == 0;
    glb = (bytes.size() >= 4 && memcmp(bytes.data(), "glTF", 4) == 0) || glb_name;
    if (glb && bytes.size() < 20)
        im.fail(PT_ERR_FORMAT, "GLB header truncated (%zu bytes)", bytes.size());
    // The JSON's nesting is bounded before tinygltf, whose conversion of the
    // document recurses once per level, sees it (common/base/json.h). A GLB's
    // JSON is its first chunk (glTF 2.0, 4.4.3); a bad chunk length is
    // tinygltf's to refuse, so only the bytes present are scanned.
    {
        const char *text = reinterpret_cast<const char *>(bytes.data());
        size_t n = bytes.size(), at = 0;
        if (glb) {
            size_t len = size_t(bytes[12]) | size_t(bytes[13]) << 8 | size_t(bytes[14]) << 16 |
                         size_t(bytes[15]) << 24;
            text += 20;
            n = len < n - 20 ? len : n - 20;
        }
        if (pt_json_too_deep(text, n, PT_JSON_MAX_DEPTH, &at))
            im.fail(PT_ERR_LIMIT, "%s nests objects and arrays more than %u deep (at byte %zu)",
                    glb ? "the GLB's JSON chunk" : "the JSON", PT_JSON_MAX_DEPTH,
                    at + (glb ? 20 : 0));
        std::string jtext = prepare_json(im, text, n);
        if (!jtext.empty()) {
            // The same file with that JSON: a GLB keeps its header and its
            // chunks after the JSON chunk (lengths updated, JSON padded with
            // spaces to 4 bytes, glTF 2.0 4.4.3.1).
            if (glb) {
                while (jtext.size() % 4)
                    jtext += ' ';
                size_t rest = 20 + n;
                uint32_t total = uint32_t(20 + jtext.size() + (bytes.size() - rest));
                uint32_t jl = uint32_t(jtext.size());
                unsigned char h[20];
                memcpy(h, bytes.data(), 20);
                for (int k = 0; k < 4; k++) {
                    h[8 + k] = uint8_t(total >> (8 * k));
                    h[12 + k] = uint8_t(jl >> (8 * k));
                }
                rewritten.assign(h, h + 20);
                rewritten.insert(rewritten.end(), jtext.begin(), jtext.end());
                rewritten.insert(rewritten.end(), bytes.begin() + long(rest), bytes.end());
            } else {
                rewritten.assign(jtext.begin(), jtext.end());
            }
            src = &rewritten;
        }
    }
    if (glb) {
        ok = loader.LoadBinaryFromMemory(&im.model, &terr, &twarn, src->data(),
                                         unsigned(src->size()), "");
    } else {
        ok = loader.LoadASCIIFromString(&im.model, &terr, &twarn,
                                        reinterpret_cast<const char *>(src->data()),
                                        unsigned(src->size()), "");
    }
    for (const auto &d : im.draco_indices) // put back (prepare_json)
        if (ok && size_t(d.first.first) < im.model.meshes.size() &&
            size_t(d.first.second) < im.model.meshes[size_t(d.first.first)].primitives.size())
            im.model.meshes[size_t(d.first.first)].primitives[size_t(d.first.second)].indices =
                d.second;
    // tinygltf's messages end in newlines; keep the first line or two.
    auto tidy = [](std::string s) {
        for (char &c : s)
            if (c == '\n' || c == '\r')
                c = ' ';
        while (!s.empty() && s.back() == ' ')
            s.pop_back();
        if (s.size() > 300)
            s.resize(300);
        return s;
    };
    if (!ok && im.fs_st != PT_OK)
        im.fail(im.fs_st, "buffer file %s", im.fs_msg.c_str());
    if (!ok) {
        // Every file tinygltf reads goes through fs_read, whose failures are
        // reported just above; what is left is the content's fault (its
        // "not found" means a JSON object, never a file: fs_exists says yes).
        std::string msg = tidy(terr.empty() ? twarn : terr);
        im.fail(PT_ERR_FORMAT, "%s: %s", glb ? "invalid or truncated GLB" : "invalid glTF JSON",
                msg.c_str());
    }
    if (!twarn.empty())
        im.warn_once("tinygltf:" + twarn, "tinygltf: " + tidy(twarn));
}

void check_extensions(importer &im)
{
    const tinygltf::Model &m = im.model;
    for (const auto &r : m.extensionsRequired)
        if (!ext_supported(r))
            im.fail(PT_ERR_FORMAT,
                    "requires extension %.80s (extensionsRequired), which ptfarm does not "
                    "support",
                    shown(r).c_str());
    for (const auto &u : m.extensionsUsed)
        if (!ext_supported(u))
            warn_ext_ignored(im, u, "what uses it");
}

void import(importer &im)
{
    std::vector<unsigned char> bytes;
    read_entry(im, bytes);
    parse(im, bytes);
    tinygltf::Model &m = im.model;
    hash_files(im, bytes);
    check_extensions(im);
    choose_variant(im);
    // A file with nothing to animate (no animations, skins or morph
    // targets), and a still that needs no pose (still_static), get no rig:
    // the load reads and costs what a still's always has, and gives the same
    // bits.
    pt_anim *rig = im.rig;
    if (rig && (rig_static(m) || (im.still && still_static(m)))) {
        if (!im.still)
            rig_choose(im); // an animation named in a file without any is still an error
        im.rig = nullptr;
    }
    int dsi = m.defaultScene >= 0 ? m.defaultScene : 0;
    if (size_t(dsi) < m.scenes.size()) // else refused below
        check_triangles(im, dsi);
    add_materials(im);
    std::vector<char> on_path(m.nodes.size(), 0);
    if (!m.scenes.empty()) {
        int si = m.defaultScene >= 0 ? m.defaultScene : 0;
        if (size_t(si) >= m.scenes.size())
            im.fail(PT_ERR_FORMAT, "scene %d out of range (%zu scenes)", si, m.scenes.size());
        for (int ni : m.scenes[size_t(si)].nodes)
            visit(im, ni, identity(), 0, on_path);
        add_instanced(im);
        if (im.rig)
            rig_finish(im);
        im.rig = rig;
    } else {
        im.fail(PT_ERR_FORMAT, "no scenes: nothing to render");
    }
}

} // namespace

// pt_scene_load, and with rig_out pt_anim_load: the rig is read along the
// way, and the built scene is then posed at opts->time. A still (rig_out
// nullptr, not animate) is posed too when the file has skins or morph
// targets, as viewers show it: no animation, so every node at its own TRS
// (the skin at the pose its nodes give, normally its bind pose) and every
// morphed mesh at its default weights (node.weights, else mesh.weights,
// else 0); the rig is then dropped. A file with neither never builds one.
static pt_status load(const char *path, const pt_scene_opts *opts, pt_scene **out,
                      pt_anim **rig_out, pt_error *err)
{
    if (!path || !out)
        return pt_error_set(err, PT_ERR_ARG, "pt_scene_load: no path");
    pt_anim *rig = nullptr;
    bool still = !rig_out;
    double t = still || !opts ? 0.0 : opts->time;
    if (!(t >= 0.0) || !std::isfinite(t))
        return pt_error_set(err, PT_ERR_ARG, "%s: animation time %g is negative or not finite",
                            path, t);
    rig = new (std::nothrow) pt_anim;
    if (!rig)
        return pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory", path);
    pt_scene_builder *b = nullptr;
    pt_status st = pt_scene_builder_new(&b, err);
    if (st != PT_OK) {
        pt_anim_free(rig);
        return st;
    }
    try {
        importer im;
        im.path = path;
        im.opts = opts;
        im.err = err;
        im.b = b;
        im.rig = rig;
        im.still = still;
        size_t slash = im.path.rfind('/');
        im.base = slash == std::string::npos ? std::string() : im.path.substr(0, slash + 1);
        import(im);
    } catch (const load_failure &f) {
        pt_scene_builder_free(b);
        pt_anim_free(rig);
        return f.st;
    } catch (const std::bad_alloc &) {
        pt_scene_builder_free(b);
        pt_anim_free(rig);
        return pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory", path);
    } catch (const std::exception &ex) {
        pt_scene_builder_free(b);
        pt_anim_free(rig);
        return pt_error_set(err, PT_ERR_FORMAT, "%s: %s", path, ex.what());
    } catch (...) {
        pt_scene_builder_free(b);
        pt_anim_free(rig);
        return pt_error_set(err, PT_ERR_FORMAT, "%s: unexpected error", path);
    }
    pt_error e{};
    pt_scene *s = nullptr;
    st = pt_scene_builder_finish(b, opts, &s, &e);
    if (st != PT_OK) {
        pt_anim_free(rig);
        return pt_error_set(err, st, "%s: %s", path, e.msg);
    }
    if (rig) {
        rig->scale = opts && opts->scale != 0.0f ? double(opts->scale) : 1.0;
        if (opts) {
            rig->translate[0] = opts->translate.x;
            rig->translate[1] = opts->translate.y;
            rig->translate[2] = opts->translate.z;
        }
        // scene->camera as choose_camera (scene.c) chose it.
        rig->camera = pt_scene_find_camera(s, opts ? opts->camera_name : nullptr);
        st = rig->moves ? pt_anim_pose(rig, t, s, &e) : PT_OK;
        if (st != PT_OK) {
            pt_anim_free(rig);
            pt_scene_free(s);
            return pt_error_set(err, st, "%s: %s", path, e.msg);
        }
        if (rig_out)
            *rig_out = rig;
        else
            pt_anim_free(rig);
    }
    *out = s;
    return PT_OK;
}

extern "C" pt_status pt_scene_load(const char *path, const pt_scene_opts *opts, pt_scene **out,
                                   pt_error *err)
{
    if (!opts || !opts->animate)
        return load(path, opts, out, nullptr, err);
    pt_anim *rig = nullptr;
    pt_status st = load(path, opts, out, &rig, err);
    // Motion blur: the scene posed over the shutter (common/scene/motion.h).
    if (st == PT_OK && opts->shutter_close > opts->shutter_open) {
        st = pt_motion_from_anim(*out, rig, opts->shutter_open, opts->shutter_close, err);
        if (st != PT_OK) {
            pt_scene_free(*out);
            *out = nullptr;
        }
    }
    pt_anim_free(rig);
    return st;
}

extern "C" pt_status pt_anim_load(const char *path, const pt_scene_opts *opts, pt_scene **scene,
                                  pt_anim **anim, pt_error *err)
{
    if (!anim)
        return pt_error_set(err, PT_ERR_ARG, "pt_anim_load: no rig to return");
    return load(path, opts, scene, anim, err);
}

// ---- ptworker --list -----------------------------------------------------------------

namespace
{

// The file's own lists, read as the loader reads it: animations with their
// time ranges, variants, extensions.
void list_model(importer &im, FILE *out)
{
    std::vector<unsigned char> bytes;
    read_entry(im, bytes);
    parse(im, bytes);
    const tinygltf::Model &m = im.model;
    fprintf(out, "animations (%zu)%s\n", m.animations.size(),
            m.animations.size() > 1 ? ": the first plays unless --animation NAME|INDEX|all" : "");
    for (size_t i = 0; i < m.animations.size(); i++) {
        const tinygltf::Animation &a = m.animations[i];
        double lo = INFINITY, hi = -INFINITY;
        for (const auto &s : a.samplers) {
            if (s.input < 0 || size_t(s.input) >= m.accessors.size())
                continue;
            const tinygltf::Accessor &acc = m.accessors[size_t(s.input)];
            if (!acc.minValues.empty())
                lo = std::min(lo, acc.minValues[0]);
            if (!acc.maxValues.empty())
                hi = std::max(hi, acc.maxValues[0]);
        }
        fprintf(out, "  %zu '%s': %zu channels", i, shown(a.name.substr(0, 64)).c_str(),
                a.channels.size());
        if (lo <= hi)
            fprintf(out, ", %g to %g s", lo, hi);
        fputc('\n', out);
    }
    std::vector<std::string> variants;
    auto ext = m.extensions.find("KHR_materials_variants");
    if (ext != m.extensions.end()) {
        const tinygltf::Value &vs = ext->second.Get("variants");
        for (size_t i = 0; vs.IsArray() && i < vs.ArrayLen(); i++) {
            const tinygltf::Value &n = vs.Get(int(i)).Get("name");
            variants.push_back(n.IsString() ? n.Get<std::string>() : std::string());
        }
    }
    fprintf(out, "variants (%zu)%s\n", variants.size(), variants.empty() ? "" : ": --variant NAME");
    for (size_t i = 0; i < variants.size(); i++)
        fprintf(out, "  %zu '%s'\n", i, shown(variants[i].substr(0, 64)).c_str());
    fprintf(out, "extensions used (%zu)", m.extensionsUsed.size());
    for (size_t i = 0; i < m.extensionsUsed.size(); i++)
        fprintf(out, "%s%s", i ? ", " : ": ", shown(m.extensionsUsed[i].substr(0, 64)).c_str());
    fputc('\n', out);
    if (!m.extensionsRequired.empty()) {
        fprintf(out, "extensions required (%zu)", m.extensionsRequired.size());
        for (size_t i = 0; i < m.extensionsRequired.size(); i++)
            fprintf(out, "%s%s", i ? ", " : ": ",
                    shown(m.extensionsRequired[i].substr(0, 64)).c_str());
        fputc('\n', out);
    }
}

} // namespace

extern "C" pt_status pt_scene_list(const char *path, FILE *out, pt_scene_list_more *more, void *ctx,
                                   pt_error *err)
{
    // The built still: the cameras in the order --camera numbers them, the
    // lights, the sizes; with every check of a load (caps, hostile files).
    pt_scene_opts so{};
    // What a still ignores (skins: an animation's) is no news to a listing.
    so.warn = [](void *, const char *) {};
    pt_scene *s = nullptr;
    pt_status st = pt_scene_load(path, &so, &s, err);
    if (st != PT_OK)
        return st;
    fprintf(out, "%s: %u triangles, %u materials, %u textures\n", path, s->num_triangles,
            s->num_materials, s->num_textures);
    if (s->num_instances > 0) {
        uint64_t seen = s->num_flat_triangles;
        for (uint32_t i = 0; i < s->num_instances; i++)
            seen += s->prototypes[s->instances[i].proto].num_tris;
        fprintf(out,
                "instances (EXT_mesh_gpu_instancing): %u of %u meshes, %llu triangles "
                "once placed\n",
                s->num_instances, s->num_prototypes, (unsigned long long)seen);
    }
    fprintf(out, "cameras (%u)%s\n", s->num_cameras,
            s->num_cameras ? ": --camera NAME, NODE or INDEX; the first by default"
                           : ": none; a view framing the scene is used");
    for (uint32_t i = 0; i < s->num_cameras; i++) {
        const pt_camera *c = &s->cameras[i];
        fprintf(out, "  %u '%s'", i, c->name);
        if (c->node[0] && strcmp(c->node, c->name) != 0)
            fprintf(out, " (node '%s')", c->node);
        if (c->ortho)
            fprintf(out, ": orthographic, %g x %g\n", 2.0 * c->xmag, 2.0 * c->ymag);
        else
            fprintf(out, ": perspective, %.4g degrees high\n", c->yfov * 180.0 / PT_PI);
    }
    static const char *const kinds[] = {"point", "spot", "directional"};
    fprintf(out, "lights (%u)\n", s->num_punctual);
    for (uint32_t i = 0; i < s->num_punctual; i++) {
        const pt_punctual *l = &s->punctual[i];
        fprintf(out, "  %u '%s': %s\n", i, l->name,
                l->type >= 0 && l->type <= 2 ? kinds[l->type] : "?");
    }
    fprintf(out, "emissive triangles: %s\n", s->features & PT_FEAT_EMITTERS ? "yes" : "none");
    fprintf(out, "environment portals: %u triangles%s\n", s->num_portals,
            s->num_portals ? " (the map is sampled through them as well)"
                           : " (a mesh node with extras \"ptfarm_portal\": true)");
    // Which way each faces (its front, counter-clockwise: into the room), by
    // distinct direction, so a portal wound the wrong way shows before a render.
    std::vector<std::pair<std::array<float, 3>, unsigned>> fronts;
    for (uint32_t i = 0; i < s->num_portals; i++) {
        const float *n = s->portal_fronts + 3 * size_t(i);
        std::array<float, 3> d{std::round(n[0] * 1000.0f) / 1000.0f + 0.0f,
                               std::round(n[1] * 1000.0f) / 1000.0f + 0.0f,
                               std::round(n[2] * 1000.0f) / 1000.0f + 0.0f};
        auto f =
            std::find_if(fronts.begin(), fronts.end(), [&](const auto &e) { return e.first == d; });
        if (f == fronts.end())
            fronts.push_back({d, 1u});
        else
            f->second++;
    }
    for (const auto &f : fronts)
        fprintf(out, "  front towards (%.3g, %.3g, %.3g): %u triangle%s\n", double(f.first[0]),
                double(f.first[1]), double(f.first[2]), f.second, f.second == 1 ? "" : "s");
    if (more)
        more(s, out, ctx);
    pt_scene_free(s);
    try {
        importer im;
        im.path = path;
        im.opts = &so;
        im.err = err;
        size_t slash = im.path.rfind('/');
        im.base = slash == std::string::npos ? std::string() : im.path.substr(0, slash + 1);
        list_model(im, out);
    } catch (const load_failure &f) {
        return f.st;
    } catch (const std::bad_alloc &) {
        return pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory", path);
    } catch (const std::exception &ex) {
        return pt_error_set(err, PT_ERR_FORMAT, "%s: %s", path, ex.what());
    }
    return PT_OK;
}
