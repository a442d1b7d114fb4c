/* meshopt.c - pt_meshopt_decode: EXT_meshopt_compression buffer views
 * through meshoptimizer's decoders (meshoptimizer.h). See meshopt.h. */
#include "common/scene/meshopt.h"

#include <meshoptimizer.h>

pt_status pt_meshopt_decode(const uint8_t *src, size_t len, uint64_t count, uint32_t stride,
                            int mode, int filter, uint8_t *out, pt_error *err)
{
    if (count == 0)
        return pt_error_set(err, PT_ERR_FORMAT, "EXT_meshopt_compression: count is 0");
    int rc;
    switch (mode) {
    case PT_MESHOPT_ATTRIBUTES:
        if (stride == 0 || stride > 256 || stride % 4 != 0)
            return pt_error_set(err, PT_ERR_FORMAT,
                                "EXT_meshopt_compression: ATTRIBUTES stride %u is not a multiple "
                                "of 4 up to 256",
                                stride);
        rc = meshopt_decodeVertexBuffer(out, (size_t)count, stride, src, len);
        break;
    case PT_MESHOPT_TRIANGLES:
    case PT_MESHOPT_INDICES:
        if (stride != 2 && stride != 4)
            return pt_error_set(err, PT_ERR_FORMAT,
                                "EXT_meshopt_compression: index stride %u is not 2 or 4", stride);
        if (mode == PT_MESHOPT_TRIANGLES && count % 3 != 0)
            return pt_error_set(err, PT_ERR_FORMAT,
                                "EXT_meshopt_compression: TRIANGLES count %llu is not a multiple "
                                "of 3",
                                (unsigned long long)count);
        rc = mode == PT_MESHOPT_TRIANGLES
                 ? meshopt_decodeIndexBuffer(out, (size_t)count, stride, src, len)
                 : meshopt_decodeIndexSequence(out, (size_t)count, stride, src, len);
        break;
    default:
        return pt_error_set(err, PT_ERR_FORMAT, "EXT_meshopt_compression: unknown mode");
    }
    if (rc != 0)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "EXT_meshopt_compression: the stream does not decode (error %d)", rc);
    if (filter != PT_MESHOPT_NONE && mode != PT_MESHOPT_ATTRIBUTES)
        return pt_error_set(err, PT_ERR_FORMAT, "EXT_meshopt_compression: a filter on indices");
    switch (filter) {
    case PT_MESHOPT_NONE:
        break;
    case PT_MESHOPT_OCTAHEDRAL:
        if (stride != 4 && stride != 8)
            return pt_error_set(err, PT_ERR_FORMAT,
                                "EXT_meshopt_compression: OCTAHEDRAL stride %u is not 4 or 8",
                                stride);
        meshopt_decodeFilterOct(out, (size_t)count, stride);
        break;
    case PT_MESHOPT_QUATERNION:
        if (stride != 8)
            return pt_error_set(err, PT_ERR_FORMAT,
                                "EXT_meshopt_compression: QUATERNION stride %u is not 8", stride);
        meshopt_decodeFilterQuat(out, (size_t)count, stride);
        break;
    case PT_MESHOPT_EXPONENTIAL:
        meshopt_decodeFilterExp(out, (size_t)count, stride);
        break;
    default:
        return pt_error_set(err, PT_ERR_FORMAT, "EXT_meshopt_compression: unknown filter");
    }
    return PT_OK;
}
