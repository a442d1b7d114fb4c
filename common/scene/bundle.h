/*
 * bundle.h - a scene and every file it references, as one byte string.
 *
 * The coordinator packs a scene (the .gltf/.glb entry file plus the external
 * buffers and images it names) into a bundle; workers fetch it by the SHA-256
 * of its bytes, cache it on disk and unpack it into a folder of their own.
 * Layout (little-endian):
 *
 *   offset  size  type   meaning
 *   0       4     bytes  magic "PTB1"
 *   4       4     u32    number of files, 1..PT_BUNDLE_MAX_FILES
 *   8       ...          each file: u16 name length, name bytes, u64 size, data
 *
 * File 0 is the entry file. A job's environment map (common/render/env.h)
 * travels as one more file named PT_BUNDLE_ENV_NAME, under a folder that
 * pt_bundle_pack refuses for a scene's own files, so the two cannot clash.
 * Names are relative paths ('/'-separated) that must
 * not be empty, absolute, contain "." or ".." components, backslashes, NUL or
 * control characters, or be longer than PT_BUNDLE_MAX_NAME: unpacking can
 * never write outside its folder. Every length is checked against the bytes
 * present before it is used.
 *
 * Threads: any thread may call them; a pt_bundle is immutable once built and
 * may be read by several threads (the coordinator's loop and its upload
 * verification thread).
 */
#ifndef PT_COMMON_SCENE_BUNDLE_H
#define PT_COMMON_SCENE_BUNDLE_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"

#define PT_BUNDLE_MAX_FILES 4096u
#define PT_BUNDLE_MAX_NAME 255u
#define PT_BUNDLE_MAX_BYTES (2ull << 30)
/* The environment map's name in a bundle (relative to the entry file's
 * folder, which is the bundle's top for a packed scene), and the folder it
 * sits in, which a scene's own files may not use. The map's format is told by
 * its bytes (common/image/envmap.h), so the name keeps no extension. */
#define PT_BUNDLE_RESERVED_DIR ".ptfarm"
#define PT_BUNDLE_ENV_NAME PT_BUNDLE_RESERVED_DIR "/environment"

typedef struct pt_bundle {
    uint8_t *data;
    size_t size;
    char hash[65]; /* SHA-256 of data, lower-case hex */
} pt_bundle;

/* Packs the scene at path with every external file it references (found by
 * pt_gltf_dependencies). On success *out is a new bundle (pt_bundle_free). */
pt_status pt_bundle_pack(const char *scene_path, pt_bundle **out, pt_error *err);

/* As pt_bundle_pack, and when env_path is not NULL the file there (an
 * environment map, not decoded here) as the last file, PT_BUNDLE_ENV_NAME.
 * A scene naming a file under PT_BUNDLE_RESERVED_DIR is refused
 * (PT_ERR_FORMAT), with or without a map. */
pt_status pt_bundle_pack_env(const char *scene_path, const char *env_path, pt_bundle **out,
                             pt_error *err);

/* 1 when the bundle (layout already checked) holds a file of this exact name;
 * its size goes to *size when size is not NULL. */
int pt_bundle_has_file(const pt_bundle *b, const char *name, uint64_t *size);

/* 1 when the entry file (file 0) lies at the bundle's top, not in a folder. */
int pt_bundle_entry_at_top(const pt_bundle *b);

/* Wraps bytes received from a peer (copied) after checking the layout. */
pt_status pt_bundle_from_bytes(const uint8_t *data, size_t size, pt_bundle **out, pt_error *err);

/* Writes the files under dir (created if missing) and puts the entry file's
 * path in entry_path. Checks the layout and names first; writes nothing on a
 * malformed bundle. */
pt_status pt_bundle_unpack(const pt_bundle *b, const char *dir, char *entry_path, size_t entry_cap,
                           pt_error *err);

void pt_bundle_free(pt_bundle *b); /* accepts NULL */

/* Checks a bundle's layout and file names; PT_ERR_FORMAT naming the problem. */
pt_status pt_bundle_check(const uint8_t *data, size_t size, pt_error *err);

/* The external files a .gltf/.glb names (buffers and images that are not
 * data: URIs), percent-decoded, relative to the scene's folder, in the order
 * of the JSON arrays, without duplicates. *names is a pt_malloc'd array of
 * pt_malloc'd strings; free with pt_gltf_dependencies_free. */
pt_status pt_gltf_dependencies(const char *path, char ***names, uint32_t *count, pt_error *err);
void pt_gltf_dependencies_free(char **names, uint32_t count);

#endif
