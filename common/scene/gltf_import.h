/*
 * gltf_import.h - internal glue between the glTF importer (gltf_import.cpp)
 * and the scene builder (scene.c). Not for use outside common/.
 *
 * The importer hashes the scene's files (the entry file, then each external
 * buffer and image in the order of the JSON arrays) rather than the built
 * data, so that a scene and its bundle agree; it hands that hash to the
 * builder before finishing it.
 *
 * Threads: the importer is reentrant (it keeps no global state); one call
 * builds one scene on the calling thread.
 */
#ifndef PT_COMMON_SCENE_GLTF_IMPORT_H
#define PT_COMMON_SCENE_GLTF_IMPORT_H

#include "common/base/error.h"
#include "common/scene/scene.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Sets the hash that pt_scene_builder_finish puts in scene->hash instead of
 * hashing the built data. hex: 64 lower-case hex digits. */
void pt_scene_builder_set_hash(pt_scene_builder *b, const char *hex);

/* Number of materials and textures added so far (the importer maps glTF
 * indices to builder indices with them). */
uint32_t pt_scene_builder_num_materials(const pt_scene_builder *b);

/* The vertices, triangles, cameras and punctual lights added so far, in
 * that order (the animation rig maps mesh instances to the scene's ranges
 * with them). */
void pt_scene_builder_counts(const pt_scene_builder *b, uint32_t counts[4]);

#ifdef __cplusplus
}
#endif

#endif
