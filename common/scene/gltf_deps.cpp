// gltf_deps.cpp - the external files a glTF names (pt_gltf_dependencies in
// bundle.h), read from the JSON alone so a scene can be packed without being
// loaded. glTF 2.0 spec, sections 3.6.1 (buffers, uri) and 3.8.3 (images):
// relative URIs, percent-encoded (RFC 3986), or data: URIs (embedded).
#include <nlohmann/json.hpp>

#include <cstdio>
#include <cstring>
#include <new>
#include <string>
#include <vector>

extern "C" {
#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/base/json.h"
#include "common/scene/bundle.h"
#include "common/scene/uri.h"
}

namespace
{

const size_t kMaxJson = 256u << 20;

// The importer decodes with the same function (common/scene/uri.h).
std::string percent_decode(const std::string &s)
{
    std::string out(s.size(), '\0');
    out.resize(pt_uri_decode(s.data(), s.size(), &out[0]));
    return out;
}

uint32_t le32(const unsigned char *p)
{
    return uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24;
}

// The JSON text of a .gltf, or the JSON chunk of a .glb (glTF 2.0 spec, 4.4).
pt_status json_text(const char *path, std::string &json, pt_error *err)
{
    // pt_read_file reads a regular file only: a FIFO named as the scene
    // is refused, not waited on for ever.
    uint8_t *data = nullptr;
    size_t size = 0;
    pt_status st = pt_read_file(path, PT_BUNDLE_MAX_BYTES, &data, &size, err);
    if (st != PT_OK)
        return st;
    std::string bytes;
    try {
        bytes.assign(reinterpret_cast<const char *>(data), size);
    } catch (...) {
        pt_free(data);
        throw;
    }
    pt_free(data);
    if (bytes.size() >= 12 && std::memcmp(bytes.data(), "glTF", 4) == 0) {
        const unsigned char *p = reinterpret_cast<const unsigned char *>(bytes.data());
        if (bytes.size() < 20)
            return pt_error_set(err, PT_ERR_FORMAT, "%s: GLB truncated before its JSON chunk",
                                path);
        uint32_t len = le32(p + 12), type = le32(p + 16);
        if (type != 0x4E4F534Au || len > bytes.size() - 20)
            return pt_error_set(err, PT_ERR_FORMAT, "%s: GLB JSON chunk is missing or truncated",
                                path);
        json.assign(bytes.data() + 20, len);
    } else {
        json.swap(bytes);
    }
    if (json.size() > kMaxJson)
        return pt_error_set(err, PT_ERR_LIMIT, "%s: JSON is over %zu bytes", path, kMaxJson);
    size_t at = 0;
    if (pt_json_too_deep(json.data(), json.size(), PT_JSON_MAX_DEPTH, &at))
        return pt_error_set(err, PT_ERR_LIMIT,
                            "%s: the JSON nests objects and arrays more than %u deep (at byte %zu "
                            "of the JSON)",
                            path, PT_JSON_MAX_DEPTH, at);
    return PT_OK;
}

} // namespace

extern "C" pt_status pt_gltf_dependencies(const char *path, char ***names, uint32_t *count,
                                          pt_error *err)
{
    std::vector<std::string> found;
    try {
        std::string text;
        pt_status st = json_text(path, text, err);
        if (st != PT_OK)
            return st;
        nlohmann::json doc = nlohmann::json::parse(text, nullptr, false);
        if (doc.is_discarded() || !doc.is_object())
            return pt_error_set(err, PT_ERR_FORMAT, "%s: not valid glTF JSON", path);
        for (const char *key : {"buffers", "images"}) {
            auto it = doc.find(key);
            if (it == doc.end())
                continue;
            if (!it->is_array())
                return pt_error_set(err, PT_ERR_FORMAT, "%s: '%s' is not an array", path, key);
            size_t i = 0;
            for (const auto &e : *it) {
                auto u = e.is_object() ? e.find("uri") : e.end();
                if (e.is_object() && u != e.end()) {
                    if (!u->is_string())
                        return pt_error_set(err, PT_ERR_FORMAT, "%s: %s[%zu].uri is not a string",
                                            path, key, i);
                    std::string uri = u->get<std::string>();
                    if (uri.compare(0, 5, "data:") != 0) {
                        std::string name = percent_decode(uri);
                        // The importer refuses the same names (uri.h): say so now,
                        // before anything is sent.
                        const char *why = pt_uri_path_refusal(name.data(), name.size());
                        if (why)
                            return pt_error_set(err, PT_ERR_FORMAT,
                                                "%s: %s[%zu].uri '%.200s' %s: a scene may only "
                                                "name files inside its folder",
                                                path, key, i, uri.c_str(), why);
                        name.resize(pt_uri_path_clean(&name[0], name.size()));
                        bool dup = false;
                        for (const auto &f : found)
                            dup = dup || f == name;
                        if (!dup)
                            found.push_back(name);
                    }
                }
                i++;
            }
        }
    } catch (const std::bad_alloc &) {
        return pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory", path);
    } catch (const std::exception &e) {
        return pt_error_set(err, PT_ERR_FORMAT, "%s: %s", path, e.what());
    }
    if (found.size() >= PT_BUNDLE_MAX_FILES)
        return pt_error_set(err, PT_ERR_LIMIT, "%s: references %zu files (cap %u)", path,
                            found.size(), PT_BUNDLE_MAX_FILES - 1);
    char **arr = static_cast<char **>(pt_calloc(found.size() ? found.size() : 1, sizeof(char *)));
    if (!arr)
        return pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory", path);
    for (size_t i = 0; i < found.size(); i++) {
        arr[i] = pt_strdup(found[i].c_str());
        if (!arr[i]) {
            pt_gltf_dependencies_free(arr, static_cast<uint32_t>(i));
            return pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory", path);
        }
    }
    *names = arr;
    *count = static_cast<uint32_t>(found.size());
    return PT_OK;
}

extern "C" void pt_gltf_dependencies_free(char **names, uint32_t count)
{
    if (!names)
        return;
    for (uint32_t i = 0; i < count; i++)
        pt_free(names[i]);
    pt_free(names);
}
