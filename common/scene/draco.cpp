// draco.cpp - pt_draco_*: KHR_draco_mesh_compression meshes through
// libdraco's Decoder (draco/compression/decode.h). See draco.h.
#include <draco/compression/decode.h>
#include <draco/core/varint_decoding.h>
#include <draco/metadata/geometry_metadata.h>
#include <draco/metadata/metadata_decoder.h>

#include <cstring>
#include <memory>
#include <new>

extern "C" {
#include "common/scene/draco.h"
}

struct pt_draco_mesh {
    std::unique_ptr<draco::Mesh> mesh;
};

namespace
{

template <typename T>
bool convert_all(const draco::Mesh &mesh, const draco::PointAttribute &a, int ncomp, void *out)
{
    T v[16];
    T *o = static_cast<T *>(out);
    for (draco::PointIndex i(0); i < mesh.num_points(); ++i) {
        draco::AttributeValueIndex vi = a.mapped_index(i);
        if (vi.value() >= a.size())
            return false;
        if (!a.ConvertValue<T>(vi, int8_t(ncomp), v))
            return false;
        memcpy(o + size_t(i.value()) * size_t(ncomp), v, sizeof(T) * size_t(ncomp));
    }
    return true;
}

// The counts a Draco 2.2 mesh's connectivity header declares, read before
// libdraco sizes its tables from them: libdraco checks them only against
// its index types, so a 73-byte buffer can make it allocate gigabytes
// (found by fuzz_draco). Layout per the Draco bitstream specification 2.2,
// the version KHR_draco_mesh_compression is written against: header
// ("DRACO", major, minor, encoder type, method, flags), the metadata
// section when flags has 0x8000, then sequential connectivity (varint
// faces, varint points) or EdgeBreaker's (traversal type byte, varint
// encoded vertices, varint faces). Any other version is refused.
pt_status declared_counts(const uint8_t *data, size_t len, uint64_t *points, uint64_t *faces,
                          pt_error *err)
{
    draco::DecoderBuffer b;
    b.Init(reinterpret_cast<const char *>(data), len);
    char magic[5];
    uint8_t major, minor, type, method;
    uint16_t flags;
    if (!b.Decode(magic, 5) || memcmp(magic, "DRACO", 5) != 0 || !b.Decode(&major) ||
        !b.Decode(&minor) || !b.Decode(&type) || !b.Decode(&method) || !b.Decode(&flags))
        return pt_error_set(err, PT_ERR_FORMAT, "Draco: not a Draco header");
    if (major != 2 || minor != 2)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "Draco: bitstream version %u.%u (KHR_draco_mesh_compression "
                            "is version 2.2)",
                            major, minor);
    if (type != draco::TRIANGULAR_MESH)
        return pt_error_set(err, PT_ERR_FORMAT, "Draco: not a triangle mesh (a point cloud)");
    if (flags & 0x8000) {
        draco::GeometryMetadata md;
        draco::MetadataDecoder mdec;
        if (!mdec.DecodeGeometryMetadata(&b, &md))
            return pt_error_set(err, PT_ERR_FORMAT, "Draco: bad metadata section");
    }
    uint32_t np = 0, nf = 0;
    bool ok;
    if (method == 0) {
        ok = draco::DecodeVarint(&nf, &b) && draco::DecodeVarint(&np, &b);
    } else if (method == 1) {
        uint8_t traversal;
        ok = b.Decode(&traversal) && draco::DecodeVarint(&np, &b) && draco::DecodeVarint(&nf, &b);
    } else {
        return pt_error_set(err, PT_ERR_FORMAT, "Draco: connectivity method %u", method);
    }
    if (!ok)
        return pt_error_set(err, PT_ERR_FORMAT, "Draco: connectivity header cut short");
    *points = np;
    *faces = nf;
    return PT_OK;
}

} // namespace

extern "C" pt_status pt_draco_decode(const uint8_t *data, size_t len, uint64_t max_points,
                                     uint64_t max_faces, pt_draco_mesh **out, pt_error *err)
{
    try {
        uint64_t dp = 0, df = 0;
        pt_status hs = declared_counts(data, len, &dp, &df, err);
        if (hs != PT_OK)
            return hs;
        if (dp > max_points || df > max_faces)
            return pt_error_set(err, PT_ERR_LIMIT,
                                "Draco: the header declares %llu points and %llu triangles "
                                "(at most %llu and %llu)",
                                (unsigned long long)dp, (unsigned long long)df,
                                (unsigned long long)max_points, (unsigned long long)max_faces);
        draco::DecoderBuffer buf;
        buf.Init(reinterpret_cast<const char *>(data), len);
        auto type = draco::Decoder::GetEncodedGeometryType(&buf);
        if (!type.ok())
            return pt_error_set(err, PT_ERR_FORMAT, "Draco: %.200s", type.status().error_msg());
        if (type.value() != draco::TRIANGULAR_MESH)
            return pt_error_set(err, PT_ERR_FORMAT, "Draco: not a triangle mesh (a point cloud)");
        draco::Decoder dec;
        auto res = dec.DecodeMeshFromBuffer(&buf);
        if (!res.ok())
            return pt_error_set(err, PT_ERR_FORMAT, "Draco: %.200s", res.status().error_msg());
        std::unique_ptr<draco::Mesh> mesh = std::move(res).value();
        if (!mesh)
            return pt_error_set(err, PT_ERR_FORMAT, "Draco: no mesh decoded");
        uint64_t np = mesh->num_points(), nf = mesh->num_faces();
        if (np > max_points || nf > max_faces)
            return pt_error_set(err, PT_ERR_LIMIT,
                                "Draco: %llu points and %llu triangles (at most %llu and %llu)",
                                (unsigned long long)np, (unsigned long long)nf,
                                (unsigned long long)max_points, (unsigned long long)max_faces);
        for (draco::FaceIndex f(0); f < mesh->num_faces(); ++f)
            for (int k = 0; k < 3; k++)
                if (mesh->face(f)[k].value() >= np)
                    return pt_error_set(err, PT_ERR_FORMAT,
                                        "Draco: triangle %u names point %u of %llu", f.value(),
                                        mesh->face(f)[k].value(), (unsigned long long)np);
        pt_draco_mesh *m = new pt_draco_mesh;
        m->mesh = std::move(mesh);
        *out = m;
        return PT_OK;
    } catch (const std::bad_alloc &) {
        return pt_error_set(err, PT_ERR_NOMEM, "Draco: out of memory");
    } catch (...) {
        return pt_error_set(err, PT_ERR_FORMAT, "Draco: the decoder failed");
    }
}

extern "C" void pt_draco_free(pt_draco_mesh *m)
{
    delete m;
}

extern "C" uint32_t pt_draco_points(const pt_draco_mesh *m)
{
    return m->mesh->num_points();
}

extern "C" uint32_t pt_draco_faces(const pt_draco_mesh *m)
{
    return m->mesh->num_faces();
}

extern "C" void pt_draco_indices(const pt_draco_mesh *m, uint32_t *out)
{
    for (draco::FaceIndex f(0); f < m->mesh->num_faces(); ++f)
        for (int k = 0; k < 3; k++)
            out[3 * size_t(f.value()) + size_t(k)] = m->mesh->face(f)[k].value();
}

extern "C" pt_status pt_draco_attribute(const pt_draco_mesh *m, uint32_t unique_id, int ctype,
                                        int ncomp, void *out, pt_error *err)
{
    const draco::PointAttribute *a = m->mesh->GetAttributeByUniqueId(unique_id);
    if (!a)
        return pt_error_set(err, PT_ERR_FORMAT, "Draco: the mesh has no attribute %u", unique_id);
    if (ncomp < 1 || ncomp > 16 || a->num_components() < ncomp)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "Draco: attribute %u has %d components, the accessor wants %d",
                            unique_id, int(a->num_components()), ncomp);
    /* glTF accessors hold integers and floats only; a bool attribute's
     * bytes would be read as bool by Draco's conversion, whatever they
     * hold (undefined for any byte but 0 and 1). */
    if (a->data_type() == draco::DT_BOOL || a->data_type() == draco::DT_INVALID ||
        a->data_type() >= draco::DT_TYPES_COUNT)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "Draco: attribute %u has a data type glTF has no accessor for",
                            unique_id);
    const draco::Mesh &mesh = *m->mesh;
    bool ok;
    switch (ctype) {
    case 5120:
        ok = convert_all<int8_t>(mesh, *a, ncomp, out);
        break;
    case 5121:
        ok = convert_all<uint8_t>(mesh, *a, ncomp, out);
        break;
    case 5122:
        ok = convert_all<int16_t>(mesh, *a, ncomp, out);
        break;
    case 5123:
        ok = convert_all<uint16_t>(mesh, *a, ncomp, out);
        break;
    case 5125:
        ok = convert_all<uint32_t>(mesh, *a, ncomp, out);
        break;
    case 5126:
        ok = convert_all<float>(mesh, *a, ncomp, out);
        break;
    default:
        return pt_error_set(err, PT_ERR_FORMAT, "Draco: component type %d", ctype);
    }
    if (!ok)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "Draco: attribute %u does not convert to component type %d", unique_id,
                            ctype);
    return PT_OK;
}
