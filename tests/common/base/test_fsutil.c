/* Tests for common/base/fsutil.c: the atomic write (modes, reject paths, no
 * temporary left behind, links planted in the folder never written through),
 * the folder removal, the read that follows no link, and the read confined
 * below a folder (no link anywhere, regular files only, the cap before
 * reading). */
#include "common/base/fsutil.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "tests/check.h"

static int count_entries(const char *dir)
{
    DIR *d = opendir(dir);
    if (!d)
        return -1;
    int n = 0;
    for (struct dirent *e; (e = readdir(d));)
        n += strcmp(e->d_name, ".") != 0 && strcmp(e->d_name, "..") != 0;
    closedir(d);
    return n;
}

static int file_is(const char *path, const char *want)
{
    char buf[64] = {0};
    FILE *f = fopen(path, "rb");
    if (!f)
        return 0;
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    return n == strlen(want) && memcmp(buf, want, n) == 0;
}

static void test_write_atomic(const char *dir)
{
    char path[256], bad[300];
    snprintf(path, sizeof path, "%s/state.bin", dir);
    pt_error err = {0};
    CHECK(pt_write_file_atomic(path, "first", 5, &err) == PT_OK && file_is(path, "first"));
    CHECK(pt_write_file_atomic(path, "second!", 7, &err) == PT_OK && file_is(path, "second!"));
    CHECK(pt_write_file_atomic(path, "", 0, &err) == PT_OK && file_is(path, ""));
    CHECK(count_entries(dir) == 1);
    struct stat sb;
    CHECK(stat(path, &sb) == 0 && (sb.st_mode & 0777) == 0644);

    /* The mode is the caller's, less the umask. */
    umask(002);
    CHECK(pt_write_file_atomic_mode(path, "img", 3, 0666, &err) == PT_OK && file_is(path, "img"));
    CHECK(stat(path, &sb) == 0 && (sb.st_mode & 0777) == 0664);
    umask(022);
    CHECK(pt_write_file_atomic_mode(path, "img", 3, 0600, &err) == PT_OK);
    CHECK(stat(path, &sb) == 0 && (sb.st_mode & 0777) == 0600);

    /* Reject paths: not a file name, a missing folder, a folder as the target. */
    CHECK(pt_write_file_atomic("", "x", 1, &err) == PT_ERR_ARG);
    snprintf(bad, sizeof bad, "%s/", dir);
    CHECK(pt_write_file_atomic_mode(bad, "x", 1, 0666, &err) == PT_ERR_ARG);
    CHECK(strstr(err.msg, "not a file name") != NULL);
    snprintf(bad, sizeof bad, "%s/missing/out.exr", dir);
    CHECK(pt_write_file_atomic(bad, "x", 1, &err) == PT_ERR_IO && strstr(err.msg, "missing"));
    snprintf(bad, sizeof bad, "%s/sub", dir);
    CHECK(mkdir(bad, 0755) == 0);
    CHECK(pt_write_file_atomic(bad, "x", 1, &err) == PT_ERR_IO);
    CHECK(count_entries(dir) == 2); /* state.bin and sub: no temporary left */
    CHECK(file_is(path, "img"));
}

static void test_write_all_and_sync(const char *dir)
{
    char path[300], sub[300];
    snprintf(path, sizeof path, "%s/all.bin", dir);
    static uint8_t big[3 << 20];
    for (size_t i = 0; i < sizeof big; i++)
        big[i] = (uint8_t)(i * 31);
    int fd = open(path, O_WRONLY | O_CREAT | O_TRUNC, 0644);
    CHECK(fd >= 0 && pt_write_all(fd, big, sizeof big) == 0 && pt_write_all(fd, big, 0) == 0);
    close(fd);
    struct stat sb;
    CHECK(stat(path, &sb) == 0 && sb.st_size == (off_t)sizeof big);
    /* A descriptor that cannot be written: -1 with the reason. */
    fd = open(path, O_RDONLY);
    errno = 0;
    CHECK(fd >= 0 && pt_write_all(fd, "x", 1) == -1 && errno == EBADF);
    close(fd);
    CHECK(unlink(path) == 0);

    CHECK(pt_fsync_dir(dir) == 0);
    CHECK(pt_fsync_dir_of(path) == 0); /* the folder of a file, present or not */
    snprintf(sub, sizeof sub, "%s/none", dir);
    errno = 0;
    CHECK(pt_fsync_dir(sub) == -1 && errno == ENOENT);
    CHECK(pt_write_file_atomic(path, "x", 1, NULL) == PT_OK);
    errno = 0;
    CHECK(pt_fsync_dir(path) == -1 && errno == ENOTDIR);
    CHECK(unlink(path) == 0);
}

static void test_remove_tree(const char *dir)
{
    char p[300];
    snprintf(p, sizeof p, "%s/t/a/b", dir);
    pt_error err = {0};
    CHECK(pt_mkdirs(p, 0, &err) == PT_OK);
    snprintf(p, sizeof p, "%s/t/a/b/f", dir);
    CHECK(pt_write_file_atomic(p, "x", 1, &err) == PT_OK);
    snprintf(p, sizeof p, "%s/t", dir);
    CHECK(pt_remove_tree(p) == 0 && access(p, F_OK) != 0);
    CHECK(pt_remove_tree(p) == 0); /* missing is fine */
}

/* pt_read_file_beneath from dir/in: what lies below is read; a link (to a
 * file or a folder, inside or out), "..", an absolute name, a FIFO, a folder
 * and an oversized file are refused, and no message names dir. */
static void test_read_beneath(const char *dir)
{
    char p[300], q[300];
    pt_error err = {0};
    snprintf(p, sizeof p, "%s/in/sub", dir);
    CHECK(pt_mkdirs(p, 0, &err) == PT_OK);
    snprintf(p, sizeof p, "%s/in/sub/a.bin", dir);
    CHECK(pt_write_file_atomic(p, "inside", 6, &err) == PT_OK);
    snprintf(p, sizeof p, "%s/secret", dir);
    CHECK(pt_write_file_atomic(p, "SECRET", 6, &err) == PT_OK);
    snprintf(q, sizeof q, "%s/in/up.bin", dir);
    CHECK(symlink("../secret", q) == 0);
    snprintf(q, sizeof q, "%s/in/same.bin", dir);
    CHECK(symlink("sub/a.bin", q) == 0);
    snprintf(q, sizeof q, "%s/in/out", dir);
    CHECK(symlink(dir, q) == 0);
    snprintf(q, sizeof q, "%s/in/fifo", dir);
    CHECK(mkfifo(q, 0600) == 0);
    snprintf(q, sizeof q, "%s/in", dir);
    int fd = open(q, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    CHECK(fd >= 0);

    uint8_t *data = NULL;
    size_t len = 0;
    const char *good[] = {"sub/a.bin", "./sub/a.bin", "sub//a.bin"};
    for (size_t i = 0; i < sizeof good / sizeof *good; i++) {
        data = NULL;
        CHECKF(pt_read_file_beneath(fd, good[i], 100, &data, &len, &err) == PT_OK && len == 6 &&
                   memcmp(data, "inside", 6) == 0,
               "%s: %s", good[i], err.msg);
        pt_free(data);
    }
    char abs[300];
    snprintf(abs, sizeof abs, "%s/secret", dir);
    const char *bad[] = {"up.bin", "same.bin", "out/secret", "../secret", "sub/../../secret",
                         abs,      "fifo",     "sub",        "sub/",      "/dev/zero",
                         "."};
    alarm(30); /* the FIFO must not block */
    for (size_t i = 0; i < sizeof bad / sizeof *bad; i++) {
        data = NULL;
        err.msg[0] = '\0';
        pt_status st = pt_read_file_beneath(fd, bad[i], 100, &data, &len, &err);
        CHECKF(st == PT_ERR_FORMAT && data == NULL, "%s: %d %s", bad[i], (int)st, err.msg);
        CHECKF(strncmp(err.msg, bad[i], strlen(bad[i])) == 0, "%s: %s", bad[i], err.msg);
        CHECKF(!strstr(err.msg + strlen(bad[i]), dir) && !strstr(err.msg, "SECRET"), "%s: %s",
               bad[i], err.msg);
    }
    alarm(0);
    CHECK(pt_read_file_beneath(fd, "sub/a.bin", 5, &data, &len, &err) == PT_ERR_LIMIT);
    CHECK(pt_read_file_beneath(fd, "sub/none", 100, &data, &len, &err) == PT_ERR_IO &&
          strstr(err.msg, "sub/none"));
    close(fd);
}

/* A folder others can write to (an output folder): links planted at the
 * destination and at the names temporaries used to have are not followed,
 * and temporaries are named unpredictably and created exclusively. */
static void test_planted_links(const char *dir)
{
    char sub[256], victim[256], path[300], link2[400];
    snprintf(sub, sizeof sub, "%s/out", dir);
    snprintf(victim, sizeof victim, "%s/victim", dir);
    CHECK(mkdir(sub, 0755) == 0);
    pt_error err = {0};
    CHECK(pt_write_file_atomic(victim, "precious", 8, &err) == PT_OK);
    snprintf(path, sizeof path, "%s/1-img.exr", sub);
    CHECK(symlink(victim, path) == 0);
    /* The old scheme's names: path.tmp.PID.N for the first few N. */
    for (int i = 0; i < 4; i++) {
        snprintf(link2, sizeof link2, "%s.tmp.%ld.%d", path, (long)getpid(), i);
        CHECK(symlink(victim, link2) == 0);
    }
    CHECK(pt_write_file_atomic(path, "image", 5, &err) == PT_OK);
    CHECK(file_is(victim, "precious"));
    struct stat sb;
    CHECKF(lstat(path, &sb) == 0 && S_ISREG(sb.st_mode), "the link was written through");
    CHECK(file_is(path, "image"));
    CHECK(count_entries(sub) == 5); /* the image and the four planted links */

    /* Two temporaries of one path have different, random names; the
     * file is created exclusively and never through a link. */
    pt_temp a, b;
    CHECK(pt_temp_open(path, 0644, &a, &err) == PT_OK);
    CHECK(pt_temp_open(path, 0644, &b, &err) == PT_OK);
    CHECK(strcmp(a.path, b.path) != 0 && strncmp(a.path, path, strlen(path)) == 0);
    CHECK(strlen(a.path) == strlen(path) + 5 + 16);
    char bpath[sizeof b.path];
    snprintf(bpath, sizeof bpath, "%s", b.path);
    CHECK(access(bpath, F_OK) == 0);
    pt_temp_abort(&b);
    CHECK(access(bpath, F_OK) != 0);
    CHECK(pt_write_all(a.fd, "temp", 4) == 0);
    CHECK(pt_temp_commit(&a, path, &err) == PT_OK && file_is(path, "temp"));
    CHECK(count_entries(sub) == 5);

    /* The read that follows no link: a link and a FIFO are refused. */
    uint8_t *data = NULL;
    size_t len = 0;
    CHECK(pt_read_file_nofollow(path, 100, &data, &len, &err) == PT_OK && len == 4);
    pt_free(data);
    CHECK(pt_read_file_nofollow(link2, 100, &data, &len, &err) == PT_ERR_FORMAT &&
          strstr(err.msg, "link"));
    snprintf(link2, sizeof link2, "%s/fifo", sub);
    CHECK(mkfifo(link2, 0600) == 0);
    CHECK(pt_read_file_nofollow(link2, 100, &data, &len, &err) == PT_ERR_FORMAT);
    /* The read that follows links does not block on a FIFO either. */
    CHECK(pt_read_file(link2, 100, &data, &len, &err) == PT_ERR_FORMAT &&
          strstr(err.msg, "not a regular file"));
    snprintf(link2, sizeof link2, "%s/none", sub);
    CHECK(pt_read_file_nofollow(link2, 100, &data, &len, &err) == PT_ERR_IO &&
          err.sys_errno == ENOENT);
    CHECK(file_is(victim, "precious"));
}

int main(void)
{
    umask(022);
    char dir[] = "/tmp/test_fsutil_XXXXXX";
    if (!mkdtemp(dir)) {
        perror("mkdtemp");
        return 1;
    }
    test_write_atomic(dir);
    test_write_all_and_sync(dir);
    test_remove_tree(dir);
    test_read_beneath(dir);
    test_planted_links(dir);
    CHECK(pt_remove_tree(dir) == 0 && access(dir, F_OK) != 0);
    return check_report();
}
