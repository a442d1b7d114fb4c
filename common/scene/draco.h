/*
 * draco.h - the mesh decoder of KHR_draco_mesh_compression (Draco 1.5,
 * Debian's libdraco), for the glTF importer.
 *
 * A decoded mesh is a list of points (each with a value of every attribute)
 * and of triangles over them. The bytes are untrusted: a decode failure, a
 * mesh that is not a triangle mesh, counts over the caller's caps, a face
 * naming a point past the count, an attribute id the mesh does not have or
 * one with fewer components than asked are PT_ERR_FORMAT / PT_ERR_LIMIT with
 * a message that says which; nothing is trusted from the header alone.
 *
 * Values are converted to the glTF component type asked for (5120-5126, as
 * the accessor gives it) with Draco's own conversion, which treats integers
 * as normalized when the attribute says so; floats pass unchanged.
 *
 * Threads: a pt_draco_mesh belongs to one thread at a time.
 */
#ifndef PT_COMMON_SCENE_DRACO_H
#define PT_COMMON_SCENE_DRACO_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct pt_draco_mesh pt_draco_mesh;

/* Decodes data[0, len) as a Draco triangle mesh of at most max_points points
 * and max_faces triangles. */
pt_status pt_draco_decode(const uint8_t *data, size_t len, uint64_t max_points, uint64_t max_faces,
                          pt_draco_mesh **out, pt_error *err);
void pt_draco_free(pt_draco_mesh *m);

uint32_t pt_draco_points(const pt_draco_mesh *m);
uint32_t pt_draco_faces(const pt_draco_mesh *m);

/* The faces' point indices, 3 a face, into out (3 x pt_draco_faces). */
void pt_draco_indices(const pt_draco_mesh *m, uint32_t *out);

/* Attribute unique_id of every point, ncomp components each of glTF
 * component type ctype, tightly packed into out (points x ncomp x size). */
pt_status pt_draco_attribute(const pt_draco_mesh *m, uint32_t unique_id, int ctype, int ncomp,
                             void *out, pt_error *err);

#ifdef __cplusplus
}
#endif

#endif
