// gltf_writer.hpp - hand-written glTF files for the importer's tests: a
// JSON document whose one buffer is a data: URI, built accessor by accessor.
#ifndef PT_TESTS_COMMON_SCENE_GLTF_WRITER_HPP
#define PT_TESTS_COMMON_SCENE_GLTF_WRITER_HPP

#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

namespace pt_test
{

inline std::string base64(const std::vector<unsigned char> &d)
{
    static const char *al = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    std::string o;
    for (size_t i = 0; i < d.size(); i += 3) {
        uint32_t v = uint32_t(d[i]) << 16;
        if (i + 1 < d.size())
            v |= uint32_t(d[i + 1]) << 8;
        if (i + 2 < d.size())
            v |= d[i + 2];
        o += al[v >> 18 & 63];
        o += al[v >> 12 & 63];
        o += i + 1 < d.size() ? al[v >> 6 & 63] : '=';
        o += i + 2 < d.size() ? al[v & 63] : '=';
    }
    return o;
}

// A file under construction: buffer views over one buffer, and accessors
// (add: an accessor with a view of its own; accessor: any JSON).
struct gltf {
    std::vector<unsigned char> buf;
    std::string accessors, views;
    int n = 0;  // accessors
    int nv = 0; // buffer views
    int view(const void *data, size_t bytes, size_t stride = 0)
    {
        while (buf.size() % 4)
            buf.push_back(0);
        size_t off = buf.size();
        buf.insert(buf.end(), (const unsigned char *)data, (const unsigned char *)data + bytes);
        char v[160];
        int k = snprintf(v, sizeof v, "%s{\"buffer\":0,\"byteOffset\":%zu,\"byteLength\":%zu",
                         nv ? "," : "", off, bytes);
        snprintf(v + k, sizeof v - size_t(k), stride ? ",\"byteStride\":%zu}" : "}", stride);
        views += v;
        return nv++;
    }
    int accessor(const std::string &json)
    {
        accessors += (n ? "," : "") + json;
        return n++;
    }
    int add(const void *data, size_t bytes, int ctype, const char *type, size_t count,
            bool normalized = false, size_t stride = 0)
    {
        int v = view(data, bytes, stride);
        char a[200];
        snprintf(a, sizeof a,
                 "{\"bufferView\":%d,\"componentType\":%d,\"count\":%zu,\"type\":\"%s\"%s}", v,
                 ctype, count, type, normalized ? ",\"normalized\":true" : "");
        return accessor(a);
    }
    int floats(const std::vector<float> &f, const char *type, size_t per)
    {
        return add(f.data(), f.size() * 4, 5126, type, f.size() / per);
    }
    // The file: one scene of node 0 and the given JSON members.
    std::string json(const std::string &members)
    {
        return "{\"asset\":{\"version\":\"2.0\"},\"scenes\":[{\"nodes\":[0]}]," + members +
               ",\"accessors\":[" + accessors + "],\"bufferViews\":[" + views +
               "],\"buffers\":[{\"byteLength\":" + std::to_string(buf.size()) +
               ",\"uri\":\"data:application/octet-stream;base64," + base64(buf) + "\"}]}";
    }
};

} // namespace pt_test

#endif
