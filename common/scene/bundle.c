#include "common/scene/bundle.h"

#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "common/base/hash.h"

static const uint8_t MAGIC[4] = {'P', 'T', 'B', '1'};

/* A name may only lead downwards from the bundle's folder. */
static int name_ok(const char *name, size_t len)
{
    if (len == 0 || len > PT_BUNDLE_MAX_NAME || name[0] == '/')
        return 0;
    size_t start = 0;
    for (size_t i = 0; i <= len; i++) {
        if (i == len || name[i] == '/') {
            size_t n = i - start;
            if (n == 0 || (n == 1 && name[start] == '.') ||
                (n == 2 && name[start] == '.' && name[start + 1] == '.'))
                return 0;
            start = i + 1;
            continue;
        }
        unsigned char c = (unsigned char)name[i];
        if (c < 0x20 || c == 0x7f || c == '\\')
            return 0;
    }
    return 1;
}

static uint64_t rd_u64(const uint8_t *p)
{
    uint64_t v = 0;
    for (int i = 7; i >= 0; i--)
        v = (v << 8) | p[i];
    return v;
}

static void wr_u64(uint8_t *p, uint64_t v)
{
    for (int i = 0; i < 8; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}

/* Walks the layout; calls fn for each file when fn is not NULL. */
typedef pt_status (*entry_fn)(void *user, uint32_t index, const char *name, size_t name_len,
                              const uint8_t *data, uint64_t size, pt_error *err);

static pt_status walk(const uint8_t *data, size_t size, entry_fn fn, void *user, pt_error *err)
{
    if (size < 8 || memcmp(data, MAGIC, 4) != 0)
        return pt_error_set(err, PT_ERR_FORMAT, "scene bundle: bad magic or truncated header");
    uint32_t count = (uint32_t)data[4] | (uint32_t)data[5] << 8 | (uint32_t)data[6] << 16 |
                     (uint32_t)data[7] << 24;
    if (count == 0 || count > PT_BUNDLE_MAX_FILES)
        return pt_error_set(err, PT_ERR_FORMAT, "scene bundle: %u files (1..%u allowed)", count,
                            PT_BUNDLE_MAX_FILES);
    const uint8_t *p = data + 8, *end = data + size;
    for (uint32_t i = 0; i < count; i++) {
        if (end - p < 2)
            return pt_error_set(err, PT_ERR_FORMAT, "scene bundle: file %u: truncated name length",
                                i);
        size_t nl = (size_t)p[0] | (size_t)p[1] << 8;
        p += 2;
        if ((size_t)(end - p) < nl)
            return pt_error_set(err, PT_ERR_FORMAT, "scene bundle: file %u: truncated name", i);
        const char *name = (const char *)p;
        if (!name_ok(name, nl))
            return pt_error_set(err, PT_ERR_FORMAT,
                                "scene bundle: file %u: name '%.*s' is not a plain relative path",
                                i, (int)(nl > 64 ? 64 : nl), name);
        p += nl;
        if (end - p < 8)
            return pt_error_set(err, PT_ERR_FORMAT, "scene bundle: file %u: truncated size", i);
        uint64_t fs = rd_u64(p);
        p += 8;
        if ((uint64_t)(end - p) < fs)
            return pt_error_set(err, PT_ERR_FORMAT,
                                "scene bundle: file %u ('%.*s'): declares %llu bytes, %zu present",
                                i, (int)nl, name, (unsigned long long)fs, (size_t)(end - p));
        if (fn) {
            pt_status st = fn(user, i, name, nl, p, fs, err);
            if (st != PT_OK)
                return st;
        }
        p += fs;
    }
    if (p != end)
        return pt_error_set(err, PT_ERR_FORMAT, "scene bundle: %zu trailing bytes",
                            (size_t)(end - p));
    return PT_OK;
}

pt_status pt_bundle_check(const uint8_t *data, size_t size, pt_error *err)
{
    if (size > PT_BUNDLE_MAX_BYTES)
        return pt_error_set(err, PT_ERR_LIMIT, "scene bundle: %zu bytes is over the cap", size);
    return walk(data, size, NULL, NULL, err);
}

pt_status pt_bundle_from_bytes(const uint8_t *data, size_t size, pt_bundle **out, pt_error *err)
{
    pt_status st = pt_bundle_check(data, size, err);
    if (st != PT_OK)
        return st;
    pt_bundle *b = pt_calloc(1, sizeof *b);
    uint8_t *copy = pt_malloc(size);
    if (!b || !copy) {
        pt_free(b);
        pt_free(copy);
        return pt_error_set(err, PT_ERR_NOMEM, "scene bundle: out of memory for %zu bytes", size);
    }
    memcpy(copy, data, size);
    b->data = copy;
    b->size = size;
    pt_sha256_hex(copy, size, b->hash);
    *out = b;
    return PT_OK;
}

void pt_bundle_free(pt_bundle *b)
{
    if (b) {
        pt_free(b->data);
        pt_free(b);
    }
}

typedef struct find_ctx {
    const char *name;
    size_t len;
    int found, entry_top;
    uint64_t size;
} find_ctx;

static pt_status find_entry(void *user, uint32_t index, const char *name, size_t name_len,
                            const uint8_t *data, uint64_t size, pt_error *err)
{
    (void)data;
    (void)err;
    find_ctx *c = user;
    if (index == 0)
        c->entry_top = memchr(name, '/', name_len) == NULL;
    if (c->name && name_len == c->len && memcmp(name, c->name, name_len) == 0) {
        c->found = 1;
        c->size = size;
    }
    return PT_OK;
}

int pt_bundle_has_file(const pt_bundle *b, const char *name, uint64_t *size)
{
    find_ctx c = {name, strlen(name), 0, 0, 0};
    if (walk(b->data, b->size, find_entry, &c, NULL) != PT_OK || !c.found)
        return 0;
    if (size)
        *size = c.size;
    return 1;
}

int pt_bundle_entry_at_top(const pt_bundle *b)
{
    find_ctx c = {NULL, 0, 0, 0, 0};
    return walk(b->data, b->size, find_entry, &c, NULL) == PT_OK && c.entry_top;
}

/* 1 when name lies in the folder kept for the files ptfarm adds (the map). */
static int name_reserved(const char *name)
{
    size_t n = strlen(PT_BUNDLE_RESERVED_DIR);
    return strncmp(name, PT_BUNDLE_RESERVED_DIR, n) == 0 && (name[n] == '/' || name[n] == '\0');
}

pt_status pt_bundle_pack(const char *scene_path, pt_bundle **out, pt_error *err)
{
    return pt_bundle_pack_env(scene_path, NULL, out, err);
}

pt_status pt_bundle_pack_env(const char *scene_path, const char *env_path, pt_bundle **out,
                             pt_error *err)
{
    char **deps = NULL;
    uint32_t ndeps = 0;
    pt_status st = pt_gltf_dependencies(scene_path, &deps, &ndeps, err);
    if (st != PT_OK)
        return st;
    uint32_t nfiles = ndeps + 1 + (env_path != NULL);
    uint8_t **bufs = pt_calloc(nfiles, sizeof *bufs);
    size_t *sizes = pt_calloc(nfiles, sizeof *sizes);
    const char **names = pt_calloc(nfiles, sizeof *names);
    pt_bundle *b = NULL;
    char path[4096];
    int dir_fd = -1;
    if (!bufs || !sizes || !names) {
        st = pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory", scene_path);
        goto fail;
    }
    const char *slash = strrchr(scene_path, '/');
    size_t dirlen = slash ? (size_t)(slash - scene_path) + 1 : 0;
    names[0] = slash ? slash + 1 : scene_path;
    snprintf(path, sizeof path, "%.*s", dirlen ? (int)dirlen : 1, dirlen ? scene_path : ".");
    if (ndeps && (dir_fd = open(path, O_RDONLY | O_DIRECTORY | O_CLOEXEC)) < 0) {
        st = pt_error_errno(err, PT_ERR_IO, "%s: its folder", scene_path);
        goto fail;
    }
    for (uint32_t i = 0; i < ndeps; i++)
        names[i + 1] = deps[i];
    if (env_path)
        names[nfiles - 1] = PT_BUNDLE_ENV_NAME;
    size_t total = 8;
    for (uint32_t i = 0; i < nfiles; i++) {
        int is_env = env_path && i == nfiles - 1;
        size_t nl = strlen(names[i]);
        if (!name_ok(names[i], nl)) {
            st = pt_error_set(err, PT_ERR_FORMAT,
                              "%s: references '%s', which is not a file inside its folder",
                              scene_path, names[i]);
            goto fail;
        }
        if (!is_env && name_reserved(names[i])) {
            st = pt_error_set(err, PT_ERR_FORMAT,
                              "%s: references '%s'; the folder '" PT_BUNDLE_RESERVED_DIR
                              "' is reserved for the files ptfarm adds (the environment map)",
                              scene_path, names[i]);
            goto fail;
        }
        if (is_env || i == 0) {
            /* The files the user named: followed if links, but only a
             * regular file is read (a FIFO does not block). */
            snprintf(path, sizeof path, "%s", is_env ? env_path : scene_path);
            st = pt_read_file(path, PT_BUNDLE_MAX_BYTES, &bufs[i], &sizes[i], err);
        } else {
            /* The files the scene names: read as the server and the workers
             * will read them, below the scene's folder with no link on the
             * way, so a link planted there cannot send its target away. */
            pt_error e2 = {0};
            st = pt_read_file_beneath(dir_fd, names[i], PT_BUNDLE_MAX_BYTES, &bufs[i], &sizes[i],
                                      &e2);
            if (st != PT_OK)
                pt_error_set(err, st, "%s: references %s", scene_path, e2.msg);
        }
        if (st != PT_OK)
            goto fail;
        total += 2 + nl + 8 + sizes[i];
        if (total > PT_BUNDLE_MAX_BYTES) {
            st = pt_error_set(err, PT_ERR_LIMIT, "%s: the scene's files are over the size cap",
                              scene_path);
            goto fail;
        }
    }
    b = pt_calloc(1, sizeof *b);
    if (!b || !(b->data = pt_malloc(total))) {
        st = pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory for the bundle", scene_path);
        goto fail;
    }
    uint8_t *p = b->data;
    memcpy(p, MAGIC, 4);
    p[4] = (uint8_t)nfiles;
    p[5] = (uint8_t)(nfiles >> 8);
    p[6] = (uint8_t)(nfiles >> 16);
    p[7] = (uint8_t)(nfiles >> 24);
    p += 8;
    for (uint32_t i = 0; i < nfiles; i++) {
        size_t nl = strlen(names[i]);
        p[0] = (uint8_t)nl;
        p[1] = (uint8_t)(nl >> 8);
        memcpy(p + 2, names[i], nl);
        p += 2 + nl;
        wr_u64(p, sizes[i]);
        p += 8;
        memcpy(p, bufs[i], sizes[i]);
        p += sizes[i];
    }
    b->size = total;
    pt_sha256_hex(b->data, b->size, b->hash);
    *out = b;
    b = NULL;
    st = PT_OK;
fail:
    pt_bundle_free(b);
    if (bufs)
        for (uint32_t i = 0; i < nfiles; i++)
            pt_free(bufs[i]);
    pt_free(bufs);
    pt_free(sizes);
    pt_free(names);
    pt_gltf_dependencies_free(deps, ndeps);
    if (dir_fd >= 0)
        close(dir_fd);
    return st;
}

typedef struct unpack_ctx {
    const char *dir;
    char *entry;
    size_t entry_cap;
} unpack_ctx;

static pt_status write_entry(void *user, uint32_t index, const char *name, size_t name_len,
                             const uint8_t *data, uint64_t size, pt_error *err)
{
    unpack_ctx *c = user;
    char path[4096];
    int n = snprintf(path, sizeof path, "%s/%.*s", c->dir, (int)name_len, name);
    if (n < 0 || (size_t)n >= sizeof path)
        return pt_error_set(err, PT_ERR_LIMIT, "scene bundle: path too long under %s", c->dir);
    /* The file's folders first: the unpack folder and any below it (none
     * to make for a file directly under "/"). */
    char *slash = strrchr(path, '/');
    pt_status st = PT_OK;
    if (slash > path) {
        *slash = '\0';
        st = pt_mkdirs(path, 0, err);
        *slash = '/';
    }
    if (st != PT_OK)
        return st;
    int fd = open(path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC | O_NOFOLLOW, 0644);
    if (fd < 0)
        return pt_error_errno(err, PT_ERR_IO, "%s", path);
    if (pt_write_all(fd, data, (size_t)size) != 0) {
        pt_error_errno(err, PT_ERR_IO, "%s: write", path);
        close(fd);
        return PT_ERR_IO;
    }
    if (close(fd) != 0)
        return pt_error_errno(err, PT_ERR_IO, "%s: close", path);
    if (index == 0) {
        if ((size_t)n >= c->entry_cap)
            return pt_error_set(err, PT_ERR_LIMIT, "scene bundle: entry path too long");
        memcpy(c->entry, path, (size_t)n + 1);
    }
    return PT_OK;
}

pt_status pt_bundle_unpack(const pt_bundle *b, const char *dir, char *entry_path, size_t entry_cap,
                           pt_error *err)
{
    pt_status st = pt_bundle_check(b->data, b->size, err);
    if (st != PT_OK)
        return st;
    if (mkdir(dir, 0755) != 0 && errno != EEXIST)
        return pt_error_errno(err, PT_ERR_IO, "%s: mkdir", dir);
    unpack_ctx c = {dir, entry_path, entry_cap};
    return walk(b->data, b->size, write_entry, &c, err);
}
