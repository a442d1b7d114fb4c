/*
 * cache.h - the worker's scene caches: bundles on disk, renderers in memory.
 *
 * On disk (wrk_cache): a folder holding, per scene, <hex>.bundle (the bundle's
 * bytes, named by the lower-case hex SHA-256 of those bytes) and <hex>/ (the
 * bundle unpacked). Both appear only by rename(2) of a finished temporary
 * (".tmp-<hex>-<pid>-<n>", fsync'd before the rename for the bundle), so a
 * crash never leaves a file or folder under a final name that looks complete
 * but is not. Several worker processes may share one folder: a rename that
 * loses a race to an identical result is harmless, and temporaries left by a
 * dead process (its pid no longer exists) are removed by wrk_cache_open.
 * A lookup re-hashes the bundle: a corrupt one is removed with its folder and
 * reported, so that the caller fetches it again.
 * The disk cache is used by one thread at a time (the I/O thread).
 *
 * In memory (wrk_scenes): loaded scenes with their renderer, keyed by scene
 * hash + render parameters + camera + environment (whose pt_env, built once
 * from the map in the scene's folder, lives and dies with the entry), at most `max` of them kept
 * while unused (least recently used evicted). Thread-safe: the first thread that asks for a key
 * loads and builds it outside the lock while later askers wait for it, so a
 * scene is built once however many render threads want it at the same time.
 */
#ifndef PT_WORKER_CACHE_H
#define PT_WORKER_CACHE_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"
#include "common/render/render.h"
#include "protocol/msg.h"

#define WRK_HASH_SIZE 32u

/* ---- on disk ------------------------------------------------------------------------ */

typedef struct wrk_cache wrk_cache;

/* Opens (creating it and its parents when missing) the cache folder dir and
 * removes the temporaries of processes that no longer exist. */
pt_status wrk_cache_open(const char *dir, wrk_cache **out, pt_error *err);
void wrk_cache_close(wrk_cache *c); /* accepts NULL */
const char *wrk_cache_dir(const wrk_cache *c);

/* Finds the scene with this content hash. PT_OK: entry (cap bytes) receives the
 * path of its entry file, unpacked again from the bundle when the folder was
 * missing. PT_AGAIN: not cached. PT_ERR_FORMAT: the cached bundle's bytes no
 * longer hash to its name or are malformed; both files were removed, so a
 * later lookup says PT_AGAIN. PT_ERR_IO / PT_ERR_NOMEM / PT_ERR_LIMIT
 * otherwise. Reads and hashes the whole bundle (about 1 s per GiB). */
pt_status wrk_cache_lookup(wrk_cache *c, const uint8_t hash[WRK_HASH_SIZE], char *entry, size_t cap,
                           pt_error *err);

/* Stores a fetched bundle: checks that SHA-256(data) equals hash (PT_ERR_FORMAT
 * otherwise, nothing written) and its layout, writes <hex>.bundle and unpacks
 * it into <hex>/, and puts the entry file's path in entry. */
pt_status wrk_cache_store(wrk_cache *c, const uint8_t hash[WRK_HASH_SIZE], const uint8_t *data,
                          size_t size, char *entry, size_t cap, pt_error *err);

/* ---- in memory ---------------------------------------------------------------------- */

typedef struct wrk_scenes wrk_scenes;
typedef struct wrk_scene_ref wrk_scene_ref; /* one use of a cached renderer */

/* max: entries kept while nobody uses them (at least 1). */
pt_status wrk_scenes_new(uint32_t max, wrk_scenes **out, pt_error *err);
/* Frees every entry; none may be in use. Accepts NULL. */
void wrk_scenes_free(wrk_scenes *s);

/* The pose of a frame of an animated scene: animate 1 poses it at time
 * seconds of animation ("" every animation; pt_scene_opts). */
typedef struct wrk_pose {
    int animate;
    double time;
    const char *animation;
} wrk_pose;

/* What a job asks of its scene beyond the file and the render params; each
 * field may be NULL, and each is part of the cache key:
 * - camera: NULL or "" the scene's default view; an unknown one fails the build;
 * - variant: a KHR_materials_variants name, NULL or "" each primitive's own
 *   material; an unknown one fails the build;
 * - env: the job's environment light, NULL none. A map is read from the
 *   scene's folder (entry_path's), and only under the one name a bundle keeps
 *   for it (PT_BUNDLE_ENV_NAME: PT_ERR_ARG for another); params->env is
 *   ignored (the entry's own pt_env is used);
 * - pose: NULL the file's still pose; else the scene posed, the time compared
 *   bit for bit, so a worker keeps the few frames it renders at once side by
 *   side and a frame's scene is built once per worker, when its first task
 *   arrives;
 * - shutter: motion blur's [open, close], seconds after the pose's time (0 for
 *   a still; protocol/msg.h's SHUTTER), NULL none; the scene is then loaded
 *   posed over [time + open, time + close] (pt_scene_opts.shutter_open,
 *   _close), its still at time + open, as ptworker --frame F --fps R
 *   --shutter O,C poses it. */
typedef struct wrk_scene_look {
    const char *camera;
    const char *variant;
    const proto_env *env;
    const wrk_pose *pose;
    const double *shutter; /* 2 values */
} wrk_scene_look;

/* The renderer for (hash, params, look), loading entry_path (the scene's
 * entry file) as look says (NULL: every field NULL) and building it when it
 * is not cached; blocks while another thread builds the same key. On failure
 * the error of that build is returned to it and to every thread that waited
 * for it, and the key is forgotten (a later acquire tries again). Release
 * each PT_OK reference with wrk_scenes_release. */
pt_status wrk_scenes_acquire(wrk_scenes *s, const uint8_t hash[WRK_HASH_SIZE],
                             const pt_render_params *params, const wrk_scene_look *look,
                             const char *entry_path, wrk_scene_ref **out, pt_error *err);
const pt_renderer *wrk_scene_renderer(const wrk_scene_ref *ref);
void wrk_scenes_release(wrk_scenes *s, wrk_scene_ref *ref); /* accepts NULL */

/* Scenes built so far (failed builds included) and entries held now (tests). */
uint64_t wrk_scenes_builds(wrk_scenes *s);
uint32_t wrk_scenes_count(wrk_scenes *s);
/* Seconds spent loading scenes and building renderers, over every build:
 * a frame-range job's per-frame set-up (each frame is a build). */
double wrk_scenes_build_seconds(wrk_scenes *s);

#endif
