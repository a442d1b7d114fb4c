#define _GNU_SOURCE /* O_DIRECTORY, O_CLOEXEC */
#include "common/base/fsutil.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <stdio.h>
#include <string.h>
#include <sys/random.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "common/base/alloc.h"

int pt_fsync_dir_of(const char *path)
{
    char dir[PATH_MAX];
    const char *slash = strrchr(path, '/');
    if (!slash)
        snprintf(dir, sizeof dir, ".");
    else if (slash == path)
        snprintf(dir, sizeof dir, "/");
    else if ((size_t)(slash - path) < sizeof dir)
        snprintf(dir, sizeof dir, "%.*s", (int)(slash - path), path);
    else {
        errno = ENAMETOOLONG;
        return -1;
    }
    return pt_fsync_dir(dir);
}

int pt_fsync_dir(const char *dir)
{
    int fd = open(dir, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (fd < 0)
        return -1;
    int rc = fsync(fd);
    int saved = errno;
    close(fd);
    errno = saved;
    if (rc != 0 && (errno == EINVAL || errno == ENOTSUP))
        rc = 0;
    return rc;
}

pt_status pt_write_file_atomic(const char *path, const void *data, size_t n, pt_error *err)
{
    return pt_write_file_atomic_mode(path, data, n, 0644, err);
}

pt_status pt_write_file_atomic_mode(const char *path, const void *data, size_t n, unsigned mode,
                                    pt_error *err)
{
    pt_temp t;
    pt_status st = pt_temp_open(path, mode, &t, err);
    if (st != PT_OK)
        return st;
    if (pt_write_all(t.fd, data, n) != 0) {
        st = pt_error_errno(err, PT_ERR_IO, "%s: write", path);
        pt_temp_abort(&t);
        return st;
    }
    return pt_temp_commit(&t, path, err);
}

/* 16 hex digits from the kernel's random source, so that the temporary's name
 * cannot be guessed (and a link planted at it in advance). */
static int random_hex16(char out[17])
{
    uint8_t r[8];
    size_t got = 0;
    while (got < sizeof r) {
        ssize_t n = getrandom(r + got, sizeof r - got, 0);
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0)
            return -1;
        got += (size_t)n;
    }
    static const char hex[] = "0123456789abcdef";
    for (size_t i = 0; i < sizeof r; i++) {
        out[2 * i] = hex[r[i] >> 4];
        out[2 * i + 1] = hex[r[i] & 15];
    }
    out[16] = '\0';
    return 0;
}

pt_status pt_temp_open(const char *path, unsigned mode, pt_temp *t, pt_error *err)
{
    t->fd = -1;
    t->path[0] = '\0';
    size_t plen = strlen(path);
    if (plen == 0 || path[plen - 1] == '/')
        return pt_error_set(err, PT_ERR_ARG, "'%s' is not a file name", path);
    for (int tries = 0; tries < 16; tries++) {
        char r[17];
        if (random_hex16(r) != 0)
            return pt_error_errno(err, PT_ERR_IO, "%s: no random bytes for a temporary name", path);
        if ((size_t)snprintf(t->path, sizeof t->path, "%s.tmp-%s", path, r) >= sizeof t->path)
            return pt_error_set(err, PT_ERR_IO, "%s: path too long", path);
        t->fd = open(t->path, O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, (mode_t)mode);
        if (t->fd >= 0)
            return PT_OK;
        if (errno != EEXIST)
            break;
    }
    pt_status st = pt_error_errno(err, PT_ERR_IO, "%s: cannot create its temporary file", path);
    t->path[0] = '\0';
    return st;
}

void pt_temp_abort(pt_temp *t)
{
    int saved = errno;
    if (t->fd >= 0)
        close(t->fd);
    t->fd = -1;
    if (t->path[0])
        unlink(t->path);
    t->path[0] = '\0';
    errno = saved;
}

pt_status pt_temp_commit(pt_temp *t, const char *path, pt_error *err)
{
    pt_status st;
    if (fsync(t->fd) != 0) {
        st = pt_error_errno(err, PT_ERR_IO, "%s: fsync", path);
        pt_temp_abort(t);
        return st;
    }
    int rc = close(t->fd);
    t->fd = -1;
    if (rc != 0) {
        st = pt_error_errno(err, PT_ERR_IO, "%s: close", path);
        pt_temp_abort(t);
        return st;
    }
    /* rename replaces a link at path rather than following it. */
    if (rename(t->path, path) != 0) {
        st = pt_error_errno(err, PT_ERR_IO, "%s: rename", path);
        pt_temp_abort(t);
        return st;
    }
    t->path[0] = '\0';
    if (pt_fsync_dir_of(path) != 0)
        return pt_error_errno(err, PT_ERR_IO, "%s: fsync of its folder", path);
    return PT_OK;
}

int pt_write_all(int fd, const void *data, size_t n)
{
    const uint8_t *p = data;
    while (n > 0) {
        /* At most 1 GiB a call: larger counts are cut short (Linux) or
         * refused (past SSIZE_MAX) anyway. */
        ssize_t w = write(fd, p, n < ((size_t)1 << 30) ? n : ((size_t)1 << 30));
        if (w < 0 && errno == EINTR)
            continue;
        if (w <= 0) {
            if (w == 0)
                errno = EIO; /* no progress and no reason: do not spin */
            return -1;
        }
        p += w;
        n -= (size_t)w;
    }
    return 0;
}

/* Reads the open fd (a regular file of at most max bytes) whole; closes it. */
static pt_status read_fd(int fd, const char *path, size_t max, uint8_t **out, size_t *len,
                         pt_error *err)
{
    struct stat sb;
    if (fstat(fd, &sb) != 0 || !S_ISREG(sb.st_mode)) {
        close(fd);
        return pt_error_set(err, PT_ERR_IO, "%s: not a regular file", path);
    }
    if ((uint64_t)sb.st_size > max) {
        close(fd);
        return pt_error_set(err, PT_ERR_LIMIT, "%s: %lld bytes is over the limit of %zu", path,
                            (long long)sb.st_size, max);
    }
    size_t size = (size_t)sb.st_size;
    uint8_t *buf = pt_malloc(size ? size : 1);
    if (!buf) {
        close(fd);
        return pt_error_set(err, PT_ERR_NOMEM, "%s: out of memory for %zu bytes", path, size);
    }
    size_t got = 0;
    while (got < size) {
        ssize_t r = read(fd, buf + got, size - got);
        if (r < 0 && errno == EINTR)
            continue;
        if (r <= 0) {
            pt_status st = r < 0 ? pt_error_errno(err, PT_ERR_IO, "%s: read", path)
                                 : pt_error_set(err, PT_ERR_IO, "%s: shrank while read", path);
            close(fd);
            pt_free(buf);
            return st;
        }
        got += (size_t)r;
    }
    close(fd);
    *out = buf;
    *len = size;
    return PT_OK;
}

pt_status pt_open_regular(const char *path, int follow, int *fd, pt_error *err)
{
    int f = open(path, O_RDONLY | O_CLOEXEC | O_NONBLOCK | (follow ? 0 : O_NOFOLLOW));
    if (f < 0) {
        if (errno == ELOOP && !follow)
            return pt_error_set(err, PT_ERR_FORMAT, "%s: a symbolic link; not read", path);
        return pt_error_errno(err, PT_ERR_IO, "%s", path);
    }
    struct stat sb;
    if (fstat(f, &sb) != 0 || !S_ISREG(sb.st_mode)) {
        close(f);
        return pt_error_set(err, PT_ERR_FORMAT, "%s: not a regular file; not read", path);
    }
    *fd = f;
    return PT_OK;
}

/* A FIFO named as a token or scene file does not block either. */
pt_status pt_read_file(const char *path, size_t max, uint8_t **out, size_t *len, pt_error *err)
{
    int fd;
    pt_status st = pt_open_regular(path, 1, &fd, err);
    return st != PT_OK ? st : read_fd(fd, path, max, out, len, err);
}

pt_status pt_read_file_nofollow(const char *path, size_t max, uint8_t **out, size_t *len,
                                pt_error *err)
{
    int fd;
    pt_status st = pt_open_regular(path, 0, &fd, err);
    return st != PT_OK ? st : read_fd(fd, path, max, out, len, err);
}

pt_status pt_read_file_beneath(int dirfd, const char *rel, size_t max, uint8_t **out, size_t *len,
                               pt_error *err)
{
    if (rel[0] == '/')
        return pt_error_set(err, PT_ERR_FORMAT, "%s: an absolute path", rel);
    char part[NAME_MAX + 1];
    int at = dirfd;
    const char *p = rel;
    pt_status st = PT_OK;
    for (;;) {
        const char *slash = strchr(p, '/');
        size_t n = slash ? (size_t)(slash - p) : strlen(p);
        if (n > NAME_MAX) {
            st = pt_error_set(err, PT_ERR_IO, "%s: a name is too long", rel);
            break;
        }
        memcpy(part, p, n);
        part[n] = '\0';
        if (n == 2 && part[0] == '.' && part[1] == '.') {
            st = pt_error_set(err, PT_ERR_FORMAT, "%s: leads out of its folder", rel);
            break;
        }
        if (slash && (n == 0 || (n == 1 && part[0] == '.'))) {
            p = slash + 1;
            continue;
        }
        int flags = O_RDONLY | O_CLOEXEC | O_NOFOLLOW | (slash ? O_DIRECTORY : O_NONBLOCK);
        int fd = n ? openat(at, part, flags) : -1;
        if (fd < 0) {
            int e = n ? errno : EISDIR;
            if (e == ELOOP || e == ENOTDIR || e == EISDIR)
                st = pt_error_set(err, PT_ERR_FORMAT, "%s: %s", rel,
                                  e == ELOOP     ? "a symbolic link"
                                  : e == ENOTDIR ? "a symbolic link or a file on the way"
                                                 : "not a file below its folder");
            else
                st = pt_error_set(err, PT_ERR_IO, "%s: %s", rel, strerror(e));
            break;
        }
        if (at != dirfd)
            close(at);
        at = -1;
        if (slash) {
            at = fd;
            p = slash + 1;
            continue;
        }
        struct stat sb;
        if (fstat(fd, &sb) != 0 || !S_ISREG(sb.st_mode)) {
            close(fd);
            return pt_error_set(err, PT_ERR_FORMAT, "%s: not a regular file", rel);
        }
        return read_fd(fd, rel, max, out, len, err);
    }
    if (at != dirfd && at >= 0)
        close(at);
    return st;
}

pt_status pt_mkdirs(const char *path, int private_, pt_error *err)
{
    char p[PATH_MAX];
    if ((size_t)snprintf(p, sizeof p, "%s", path) >= sizeof p)
        return pt_error_set(err, PT_ERR_IO, "%s: path too long", path);
    mode_t mode = private_ ? 0700 : 0755;
    for (char *s = p + 1;; s++) {
        if (*s == '/' || *s == '\0') {
            char c = *s;
            *s = '\0';
            if (mkdir(p, mode) != 0 && errno != EEXIST)
                return pt_error_errno(err, PT_ERR_IO, "%s: mkdir", p);
            *s = c;
            if (c == '\0')
                break;
        }
    }
    struct stat sb;
    if (stat(p, &sb) != 0 || !S_ISDIR(sb.st_mode))
        return pt_error_set(err, PT_ERR_IO, "%s: not a folder", path);
    return PT_OK;
}

int pt_remove_tree(const char *path)
{
    struct stat sb;
    if (lstat(path, &sb) != 0)
        return errno == ENOENT ? 0 : -1;
    if (!S_ISDIR(sb.st_mode))
        return unlink(path);
    DIR *d = opendir(path);
    if (!d)
        return -1;
    int rc = 0;
    struct dirent *e;
    while ((e = readdir(d)) != NULL) {
        if (strcmp(e->d_name, ".") == 0 || strcmp(e->d_name, "..") == 0)
            continue;
        char child[PATH_MAX];
        if ((size_t)snprintf(child, sizeof child, "%s/%s", path, e->d_name) >= sizeof child) {
            rc = -1;
            continue;
        }
        if (pt_remove_tree(child) != 0)
            rc = -1;
    }
    closedir(d);
    if (rmdir(path) != 0)
        rc = -1;
    return rc;
}

void pt_wait_for_file(const char *path)
{
    struct timespec ts = {0, 10 * 1000 * 1000};
    while (path[0] && access(path, F_OK) != 0)
        nanosleep(&ts, NULL);
}
