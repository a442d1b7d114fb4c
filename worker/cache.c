#include "worker/cache.h"

#include <assert.h>
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/clock.h"
#include "common/base/fsutil.h"
#include "common/base/hash.h"
#include "common/render/env.h"
#include "common/scene/bundle.h"
#include "common/scene/scene.h"

#define TMP_PREFIX ".tmp-"

struct wrk_cache {
    char dir[2048];
    uint64_t counter; /* makes each temporary's name unique within the process */
};

/* ---- file helpers ------------------------------------------------------------------- */

/* A temporary's name in the cache folder: .tmp-<hex>-<pid>-<n><suffix>. */
static void temp_path(wrk_cache *c, const char *hex, const char *suffix, char *out, size_t cap)
{
    snprintf(out, cap, "%s/" TMP_PREFIX "%s-%ld-%llu%s", c->dir, hex, (long)getpid(),
             (unsigned long long)++c->counter, suffix);
}

/* Removes the temporaries whose process is gone (killed in the middle of a store). */
static void clean_temps(const char *dir)
{
    DIR *d = opendir(dir);
    if (!d)
        return;
    struct dirent *e;
    char path[4096];
    size_t plen = strlen(TMP_PREFIX);
    while ((e = readdir(d)) != NULL) {
        const char *name = e->d_name;
        if (strncmp(name, TMP_PREFIX, plen) != 0 || strlen(name) < plen + 66 ||
            name[plen + 64] != '-')
            continue;
        char *end;
        long pid = strtol(name + plen + 65, &end, 10);
        if (pid <= 0 || *end != '-' || pid == (long)getpid())
            continue;
        if (kill((pid_t)pid, 0) == 0 || errno != ESRCH)
            continue; /* alive, or not ours to judge */
        int n = snprintf(path, sizeof path, "%s/%s", dir, name);
        if (n > 0 && (size_t)n < sizeof path)
            pt_remove_tree(path);
    }
    closedir(d);
}

pt_status wrk_cache_open(const char *dir, wrk_cache **out, pt_error *err)
{
    if (strlen(dir) + 128 >= sizeof((wrk_cache *)0)->dir)
        return pt_error_set(err, PT_ERR_ARG, "cache folder '%s': path too long", dir);
    pt_status st = pt_mkdirs(dir, 0, err);
    if (st != PT_OK)
        return st;
    wrk_cache *c = pt_calloc(1, sizeof *c);
    if (!c)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    snprintf(c->dir, sizeof c->dir, "%s", dir);
    clean_temps(c->dir);
    *out = c;
    return PT_OK;
}

void wrk_cache_close(wrk_cache *c)
{
    pt_free(c);
}

const char *wrk_cache_dir(const wrk_cache *c)
{
    return c->dir;
}

/* ---- bundles ------------------------------------------------------------------------ */

/* The entry file's name inside a bundle whose layout pt_bundle_check accepted:
 * magic(4) count(4) name_len(2) name. */
static void entry_name(const uint8_t *data, const char **name, size_t *len)
{
    *len = (size_t)data[8] | (size_t)data[9] << 8;
    *name = (const char *)data + 10;
}

static pt_status entry_path_of(const char *scene_dir, const uint8_t *data, char *entry, size_t cap,
                               pt_error *err)
{
    const char *name;
    size_t len;
    entry_name(data, &name, &len);
    int n = snprintf(entry, cap, "%s/%.*s", scene_dir, (int)len, name);
    if (n < 0 || (size_t)n >= cap)
        return pt_error_set(err, PT_ERR_LIMIT, "%s: entry path too long", scene_dir);
    return PT_OK;
}

/* Unpacks into a temporary folder and renames it to scene_dir, so that scene_dir
 * exists only complete. Losing the rename to another process is fine: its
 * folder holds the same bytes. */
static pt_status unpack(wrk_cache *c, const char *hex, const uint8_t *data, size_t size,
                        const char *scene_dir, pt_error *err)
{
    char tmp[2200], entry[4096];
    temp_path(c, hex, ".d", tmp, sizeof tmp);
    pt_bundle b;
    b.data = (uint8_t *)data;
    b.size = size;
    memcpy(b.hash, hex, 65);
    pt_status st = pt_bundle_unpack(&b, tmp, entry, sizeof entry, err);
    if (st != PT_OK) {
        pt_remove_tree(tmp);
        return st;
    }
    (void)pt_fsync_dir(tmp); /* best effort, as for the folder below */
    if (rename(tmp, scene_dir) != 0) {
        int e = errno;
        pt_remove_tree(tmp);
        if (e != EEXIST && e != ENOTEMPTY) {
            errno = e;
            return pt_error_errno(err, PT_ERR_IO, "%s: rename", scene_dir);
        }
    }
    (void)pt_fsync_dir(c->dir);
    return PT_OK;
}

static pt_status write_bundle(wrk_cache *c, const char *hex, const uint8_t *data, size_t size,
                              const char *bundle_path, pt_error *err)
{
    char tmp[2200];
    temp_path(c, hex, ".bundle", tmp, sizeof tmp);
    int fd = open(tmp, O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0644);
    if (fd < 0)
        return pt_error_errno(err, PT_ERR_IO, "%s", tmp);
    pt_status st = PT_OK;
    if (pt_write_all(fd, data, size) != 0)
        st = pt_error_errno(err, PT_ERR_IO, "%s: write", tmp);
    if (st == PT_OK && fsync(fd) != 0)
        st = pt_error_errno(err, PT_ERR_IO, "%s: fsync", tmp);
    if (close(fd) != 0 && st == PT_OK)
        st = pt_error_errno(err, PT_ERR_IO, "%s: close", tmp);
    if (st == PT_OK && rename(tmp, bundle_path) != 0)
        st = pt_error_errno(err, PT_ERR_IO, "%s: rename", bundle_path);
    if (st != PT_OK)
        unlink(tmp);
    return st;
}

static void paths(const wrk_cache *c, const char *hex, char *bundle_path, size_t bcap,
                  char *scene_dir, size_t scap)
{
    snprintf(bundle_path, bcap, "%s/%s.bundle", c->dir, hex);
    snprintf(scene_dir, scap, "%s/%s", c->dir, hex);
}

static int is_dir(const char *path)
{
    struct stat sb;
    return stat(path, &sb) == 0 && S_ISDIR(sb.st_mode);
}

static int is_file(const char *path)
{
    struct stat sb;
    return stat(path, &sb) == 0 && S_ISREG(sb.st_mode);
}

pt_status wrk_cache_lookup(wrk_cache *c, const uint8_t hash[WRK_HASH_SIZE], char *entry, size_t cap,
                           pt_error *err)
{
    char hex[65], bundle_path[2200], scene_dir[2200], got[65];
    pt_hash_hex(hash, hex);
    paths(c, hex, bundle_path, sizeof bundle_path, scene_dir, sizeof scene_dir);
    struct stat sb;
    if (stat(bundle_path, &sb) != 0) {
        if (errno != ENOENT)
            return pt_error_errno(err, PT_ERR_IO, "%s", bundle_path);
        /* A folder without its bundle cannot be checked: start again. */
        pt_remove_tree(scene_dir);
        return PT_AGAIN;
    }
    pt_status st;
    const char *why = NULL;
    uint8_t *data = NULL;
    if (!S_ISREG(sb.st_mode) || sb.st_size <= 0 ||
        (unsigned long long)sb.st_size > PT_BUNDLE_MAX_BYTES) {
        why = "not a bundle file of a possible size";
        goto corrupt;
    }
    size_t size;
    if ((st = pt_read_file(bundle_path, PT_BUNDLE_MAX_BYTES, &data, &size, err)) != PT_OK)
        return st;
    pt_sha256_hex(data, size, got);
    if (strcmp(got, hex) != 0) {
        why = "contents do not match its hash";
        goto corrupt;
    }
    if (pt_bundle_check(data, size, NULL) != PT_OK) {
        why = "malformed bundle";
        goto corrupt;
    }
    char tmp_entry[4096];
    if ((st = entry_path_of(scene_dir, data, tmp_entry, sizeof tmp_entry, err)) != PT_OK)
        goto done;
    if (is_dir(scene_dir) && !is_file(tmp_entry))
        pt_remove_tree(scene_dir); /* tampered with: unpack again */
    if (!is_dir(scene_dir) && (st = unpack(c, hex, data, size, scene_dir, err)) != PT_OK)
        goto done;
    if (strlen(tmp_entry) >= cap) {
        st = pt_error_set(err, PT_ERR_LIMIT, "%s: entry path too long", scene_dir);
        goto done;
    }
    memcpy(entry, tmp_entry, strlen(tmp_entry) + 1);
    st = PT_OK;
done:
    pt_free(data);
    return st;
corrupt:
    pt_free(data);
    unlink(bundle_path);
    pt_remove_tree(scene_dir);
    return pt_error_set(err, PT_ERR_FORMAT, "cached scene %s: %s; removed", bundle_path, why);
}

pt_status wrk_cache_store(wrk_cache *c, const uint8_t hash[WRK_HASH_SIZE], const uint8_t *data,
                          size_t size, char *entry, size_t cap, pt_error *err)
{
    char hex[65], got[65], bundle_path[2200], scene_dir[2200], tmp_entry[4096];
    pt_hash_hex(hash, hex);
    if (size == 0 || size > PT_BUNDLE_MAX_BYTES)
        return pt_error_set(err, PT_ERR_LIMIT, "scene %.12s: %zu bytes", hex, size);
    pt_sha256_hex(data, size, got);
    if (strcmp(got, hex) != 0)
        return pt_error_set(err, PT_ERR_FORMAT, "scene %.12s: received bytes hash to %.12s", hex,
                            got);
    pt_status st = pt_bundle_check(data, size, err);
    if (st != PT_OK)
        return st;
    paths(c, hex, bundle_path, sizeof bundle_path, scene_dir, sizeof scene_dir);
    if ((st = entry_path_of(scene_dir, data, tmp_entry, sizeof tmp_entry, err)) != PT_OK)
        return st;
    if (strlen(tmp_entry) >= cap)
        return pt_error_set(err, PT_ERR_LIMIT, "%s: entry path too long", scene_dir);
    if ((st = write_bundle(c, hex, data, size, bundle_path, err)) != PT_OK)
        return st;
    if (is_dir(scene_dir) && !is_file(tmp_entry))
        pt_remove_tree(scene_dir);
    if (!is_dir(scene_dir) && (st = unpack(c, hex, data, size, scene_dir, err)) != PT_OK)
        return st;
    memcpy(entry, tmp_entry, strlen(tmp_entry) + 1);
    return PT_OK;
}

/* ---- in memory ---------------------------------------------------------------------- */

enum { E_BUILDING, E_READY, E_FAILED };

struct wrk_scene_ref {
    uint8_t hash[WRK_HASH_SIZE];
    pt_render_params params;
    char camera[64];                  /* pt_camera's name: "" the default view */
    char variant[PROTO_MAX_NAME + 1]; /* KHR_materials_variants name: "" the default materials */
    proto_env env;                    /* the key's environment; proto_env_none when there is none */
    int animate;                      /* the pose (wrk_pose); time 0 and "" when still */
    uint64_t time_bits;
    char animation[PROTO_MAX_NAME + 1];
    double shutter[2]; /* motion blur's (SHUTTER), seconds after time; 0, 0 when off */
    pt_env *envobj;    /* built from it, NULL for none; outlives renderer */
    pt_scene *scene;
    pt_renderer *renderer;
    int state;
    pt_error err;      /* why the build failed (E_FAILED) */
    uint32_t refs;     /* holders and waiters */
    uint64_t last_use; /* for LRU eviction */
    wrk_scene_ref *next;
};

struct wrk_scenes {
    pthread_mutex_t mu;
    pthread_cond_t cv; /* an entry finished building */
    wrk_scene_ref *head;
    uint32_t count, max;
    uint64_t builds, tick;
    double build_seconds; /* loading and building, over every build */
    /* The loader's warnings said so far (FNV-1a of each): every frame of a
     * job builds its scene again, and a warning ("the scene has 3
     * animations; playing the first") is said once, not once a frame. */
    uint64_t said[64];
    uint32_t nsaid;
};

/* pt_scene_opts.warn for builds: each distinct message once per process
 * (past 64 distinct ones, the rest unfiltered). */
static void say_once(void *user, const char *msg)
{
    wrk_scenes *s = user;
    uint64_t h = 1469598103934665603ull;
    for (const unsigned char *p = (const unsigned char *)msg; *p; p++)
        h = (h ^ *p) * 1099511628211ull;
    pthread_mutex_lock(&s->mu);
    int seen = 0;
    for (uint32_t i = 0; i < s->nsaid && !seen; i++)
        seen = s->said[i] == h;
    if (!seen && s->nsaid < sizeof s->said / sizeof s->said[0])
        s->said[s->nsaid++] = h;
    pthread_mutex_unlock(&s->mu);
    if (!seen)
        fprintf(stderr, "warning: %s\n", msg);
}

pt_status wrk_scenes_new(uint32_t max, wrk_scenes **out, pt_error *err)
{
    wrk_scenes *s = pt_calloc(1, sizeof *s);
    if (!s)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    if (pthread_mutex_init(&s->mu, NULL) != 0) {
        pt_free(s);
        return pt_error_set(err, PT_ERR_NOMEM, "pthread_mutex_init");
    }
    if (pthread_cond_init(&s->cv, NULL) != 0) {
        pthread_mutex_destroy(&s->mu);
        pt_free(s);
        return pt_error_set(err, PT_ERR_NOMEM, "pthread_cond_init");
    }
    s->max = max ? max : 1;
    *out = s;
    return PT_OK;
}

static void entry_free(wrk_scene_ref *e)
{
    if (!e)
        return;
    pt_renderer_free(e->renderer);
    pt_env_free(e->envobj);
    pt_scene_free(e->scene);
    pt_free(e);
}

void wrk_scenes_free(wrk_scenes *s)
{
    if (!s)
        return;
    wrk_scene_ref *e = s->head;
    while (e) {
        wrk_scene_ref *next = e->next;
        assert(e->refs == 0);
        entry_free(e);
        e = next;
    }
    pthread_cond_destroy(&s->cv);
    pthread_mutex_destroy(&s->mu);
    pt_free(s);
}

static void unlink_entry(wrk_scenes *s, wrk_scene_ref *e)
{
    for (wrk_scene_ref **p = &s->head; *p; p = &(*p)->next)
        if (*p == e) {
            *p = e->next;
            e->next = NULL;
            s->count--;
            return;
        }
}

/* Under the lock: unlinks unused entries, least recently used first, until at
 * most max remain; returns them as a list to free after unlocking (freeing a
 * large scene takes a while). */
static wrk_scene_ref *evict(wrk_scenes *s)
{
    wrk_scene_ref *freed = NULL;
    while (s->count > s->max) {
        wrk_scene_ref *victim = NULL;
        for (wrk_scene_ref *e = s->head; e; e = e->next)
            if (e->refs == 0 && e->state == E_READY && (!victim || e->last_use < victim->last_use))
                victim = e;
        if (!victim)
            break; /* all in use: over the limit until one is released */
        unlink_entry(s, victim);
        victim->next = freed;
        freed = victim;
    }
    return freed;
}

static void free_list(wrk_scene_ref *e)
{
    while (e) {
        wrk_scene_ref *next = e->next;
        entry_free(e);
        e = next;
    }
}

static int same_params(const pt_render_params *a, const pt_render_params *b)
{
    return a->width == b->width && a->height == b->height && a->seed == b->seed &&
           a->max_depth == b->max_depth && a->rr_depth == b->rr_depth &&
           a->light_strategy == b->light_strategy && a->transparent == b->transparent &&
           a->passes == b->passes && a->guiding == b->guiding && a->bdpt == b->bdpt &&
           memcmp(&a->clamp_direct, &b->clamp_direct, sizeof a->clamp_direct) == 0 &&
           memcmp(&a->clamp_indirect, &b->clamp_indirect, sizeof a->clamp_indirect) == 0;
}

/* The environment of e, built once: the map from the scene's folder (the
 * bundle's file PT_BUNDLE_ENV_NAME beside the entry file), or a uniform one. */
static pt_status build_env(wrk_scene_ref *e, const char *entry_path)
{
    const proto_env *v = &e->env;
    if (v->background)
        return pt_env_uniform(pt_v3(v->rgb[0], v->rgb[1], v->rgb[2]), &e->envobj, &e->err);
    if (!v->name[0])
        return PT_OK;
    if (strcmp(v->name, PT_BUNDLE_ENV_NAME) != 0)
        return pt_error_set(&e->err, PT_ERR_ARG,
                            "environment map '%.64s' is not the bundle's " PT_BUNDLE_ENV_NAME,
                            v->name);
    const char *slash = strrchr(entry_path, '/');
    int dirlen = slash ? (int)(slash - entry_path) : 1;
    char path[4096];
    int n = snprintf(path, sizeof path, "%.*s/%s", dirlen, slash ? entry_path : ".", v->name);
    if (n < 0 || (size_t)n >= sizeof path)
        return pt_error_set(&e->err, PT_ERR_LIMIT, "%s: environment map path too long", entry_path);
    return pt_env_load(path, v->strength, v->rotate_deg, &e->envobj, &e->err);
}

/* Loading and building, outside the lock. */
static pt_status build(wrk_scenes *s, wrk_scene_ref *e, const char *entry_path)
{
    pt_scene_opts so;
    memset(&so, 0, sizeof so);
    so.warn = say_once;
    so.warn_user = s;
    so.camera_name = e->camera[0] ? e->camera : NULL;
    so.variant = e->variant[0] ? e->variant : NULL;
    so.animate = e->animate;
    memcpy(&so.time, &e->time_bits, sizeof so.time);
    so.animation = e->animation[0] ? e->animation : NULL;
    if (e->shutter[0] > 0.0 || e->shutter[1] > 0.0) {
        /* Posed over the shutter, seconds after the frame's time (a still's:
         * 0), the still at its opening (a closed shutter, open == close, is
         * that still alone): as ptworker --frame F --fps R --shutter O,C. */
        so.animate = 1;
        so.shutter_open = so.time + e->shutter[0];
        so.shutter_close = so.time + e->shutter[1];
        so.time = so.shutter_open;
    }
    pt_status st = build_env(e, entry_path);
    if (st != PT_OK)
        return st;
    st = pt_scene_load(entry_path, &so, &e->scene, &e->err);
    if (st != PT_OK)
        return st;
    e->params.env = e->envobj;
    return pt_renderer_new(e->scene, &e->params, &e->renderer, &e->err);
}

/* Under the lock: the waiter or builder e is done with a failed entry. */
static pt_status give_up(wrk_scene_ref *e, pt_error *err)
{
    pt_status st = e->err.code != PT_OK ? e->err.code : PT_ERR_IO;
    if (err)
        *err = e->err;
    if (--e->refs == 0)
        entry_free(e);
    return st;
}

pt_status wrk_scenes_acquire(wrk_scenes *s, const uint8_t hash[WRK_HASH_SIZE],
                             const pt_render_params *params, const wrk_scene_look *look,
                             const char *entry_path, wrk_scene_ref **out, pt_error *err)
{
    static const wrk_scene_look plain = {0};
    if (!look)
        look = &plain;
    const char *camera = look->camera, *variant = look->variant;
    const proto_env *env = look->env;
    const wrk_pose *pose = look->pose;
    const double *shutter = look->shutter;
    /* One key for the still pose, however the fields unused then were set. */
    int animate = pose && pose->animate;
    uint64_t time_bits = 0;
    const char *animation = "";
    if (animate) {
        memcpy(&time_bits, &pose->time, sizeof time_bits);
        animation = pose->animation ? pose->animation : "";
    }
    if (strlen(animation) > PROTO_MAX_NAME)
        return pt_error_set(err, PT_ERR_ARG, "animation name '%.64s...' is over %u bytes",
                            animation, PROTO_MAX_NAME);
    double sh[2] = {0.0, 0.0};
    if (shutter) {
        sh[0] = shutter[0];
        sh[1] = shutter[1];
    }
    /* One key for "no environment", however the fields unused then were set. */
    proto_env key;
    if (env && proto_env_any(env))
        key = *env;
    else
        proto_env_none(&key);
    if (!camera)
        camera = "";
    if (strlen(camera) >= sizeof((wrk_scene_ref *)0)->camera)
        return pt_error_set(err, PT_ERR_ARG, "camera name '%.64s...' is over %zu bytes", camera,
                            sizeof((wrk_scene_ref *)0)->camera - 1);
    if (!variant)
        variant = "";
    if (strlen(variant) >= sizeof((wrk_scene_ref *)0)->variant)
        return pt_error_set(err, PT_ERR_ARG, "variant name '%.64s...' is over %zu bytes", variant,
                            sizeof((wrk_scene_ref *)0)->variant - 1);
    pthread_mutex_lock(&s->mu);
    wrk_scene_ref *e = s->head;
    while (e &&
           !(memcmp(e->hash, hash, WRK_HASH_SIZE) == 0 && same_params(&e->params, params) &&
             strcmp(e->camera, camera) == 0 && strcmp(e->variant, variant) == 0 &&
             proto_env_same(&e->env, &key) && e->animate == animate && e->time_bits == time_bits &&
             strcmp(e->animation, animation) == 0 && memcmp(e->shutter, sh, sizeof sh) == 0))
        e = e->next;
    if (e) {
        e->refs++;
        while (e->state == E_BUILDING)
            pthread_cond_wait(&s->cv, &s->mu);
        if (e->state == E_FAILED) {
            pt_status st = give_up(e, err);
            pthread_mutex_unlock(&s->mu);
            return st;
        }
        e->last_use = ++s->tick;
        pthread_mutex_unlock(&s->mu);
        *out = e;
        return PT_OK;
    }
    e = pt_calloc(1, sizeof *e);
    if (!e) {
        pthread_mutex_unlock(&s->mu);
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    }
    memcpy(e->hash, hash, WRK_HASH_SIZE);
    e->params = *params;
    e->params.env = NULL;
    e->env = key;
    snprintf(e->camera, sizeof e->camera, "%s", camera);
    snprintf(e->variant, sizeof e->variant, "%s", variant);
    e->animate = animate;
    e->time_bits = time_bits;
    snprintf(e->animation, sizeof e->animation, "%s", animation);
    memcpy(e->shutter, sh, sizeof sh);
    e->state = E_BUILDING;
    e->refs = 1;
    e->next = s->head;
    s->head = e;
    s->count++;
    s->builds++;
    pthread_mutex_unlock(&s->mu);

    double t0 = pt_now_s();
    pt_status st = build(s, e, entry_path);
    double took = pt_now_s() - t0;

    pthread_mutex_lock(&s->mu);
    s->build_seconds += took;
    wrk_scene_ref *freed = NULL;
    if (st == PT_OK) {
        e->state = E_READY;
        e->last_use = ++s->tick;
        freed = evict(s);
    } else {
        e->state = E_FAILED;
        if (e->err.code == PT_OK)
            e->err.code = st;
        unlink_entry(s, e);
    }
    pthread_cond_broadcast(&s->cv);
    if (st != PT_OK) {
        st = give_up(e, err);
        pthread_mutex_unlock(&s->mu);
        return st;
    }
    pthread_mutex_unlock(&s->mu);
    free_list(freed);
    *out = e;
    return PT_OK;
}

const pt_renderer *wrk_scene_renderer(const wrk_scene_ref *ref)
{
    return ref->renderer;
}

void wrk_scenes_release(wrk_scenes *s, wrk_scene_ref *ref)
{
    if (!ref)
        return;
    pthread_mutex_lock(&s->mu);
    ref->refs--;
    ref->last_use = ++s->tick;
    wrk_scene_ref *freed = evict(s);
    pthread_mutex_unlock(&s->mu);
    free_list(freed);
}

uint64_t wrk_scenes_builds(wrk_scenes *s)
{
    pthread_mutex_lock(&s->mu);
    uint64_t n = s->builds;
    pthread_mutex_unlock(&s->mu);
    return n;
}

double wrk_scenes_build_seconds(wrk_scenes *s)
{
    pthread_mutex_lock(&s->mu);
    double t = s->build_seconds;
    pthread_mutex_unlock(&s->mu);
    return t;
}

uint32_t wrk_scenes_count(wrk_scenes *s)
{
    pthread_mutex_lock(&s->mu);
    uint32_t n = s->count;
    pthread_mutex_unlock(&s->mu);
    return n;
}
