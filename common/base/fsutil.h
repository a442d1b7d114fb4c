/*
 * fsutil.h - durable file operations shared by the coordinator, the worker
 * cache and the image writers.
 *
 * "Durable" means: after the call returns PT_OK, a crash of the process or of
 * the machine leaves either the old or the new contents in place, never a mix
 * (temp file in the same folder, fsync, rename, fsync of the folder).
 *
 * Every file this project writes into place goes through pt_temp_open and
 * pt_temp_commit (or pt_write_file_atomic, built on them): the temporary is
 * created with O_CREAT|O_EXCL|O_NOFOLLOW under an unpredictable name (random
 * bytes from getrandom), so a link or file planted in the folder is never
 * opened, and the final rename(2) replaces whatever is at the destination,
 * a symbolic link included, instead of writing through it.
 *
 * Threads: any thread may call them; two writers of the same path race as
 * rename(2) does (the last one wins, whole).
 */
#ifndef PT_COMMON_BASE_FSUTIL_H
#define PT_COMMON_BASE_FSUTIL_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"

/* fsync of the folder that holds path, so a rename or create in it survives a
 * crash. Filesystems that refuse fsync on folders are not a failure. Returns
 * 0, or -1 with errno set. */
int pt_fsync_dir_of(const char *path);

/* fsync of the folder dir itself (after files were created in it), with the
 * same tolerance. Returns 0, or -1 with errno set. */
int pt_fsync_dir(const char *dir);

/* Writes the n bytes of data to fd, whatever the short writes and EINTR.
 * Returns 0, or -1 with errno set (EIO when write made no progress); how
 * much was written is then unknown. */
int pt_write_all(int fd, const void *data, size_t n);

/* A temporary file being written beside its destination. */
typedef struct pt_temp {
    int fd; /* open for writing; -1 once committed or aborted */
    char path[4096];
} pt_temp;

/* Creates "<path>.tmp-<16 random hex digits>" with O_WRONLY|O_CREAT|O_EXCL|
 * O_NOFOLLOW|O_CLOEXEC and mode (before umask), trying new names when one
 * exists. PT_ERR_ARG when path is empty or ends in '/'; PT_ERR_IO naming
 * path (err->sys_errno kept: ENOSPC, EDQUOT, EACCES...). */
pt_status pt_temp_open(const char *path, unsigned mode, pt_temp *t, pt_error *err);

/* fsync and close t, rename it to path (replacing a file or a link there,
 * never following it), fsync of the folder. On failure t is removed and
 * PT_ERR_IO names path (errno kept), also when only the folder's fsync
 * failed after the rename. t is closed in every case. */
pt_status pt_temp_commit(pt_temp *t, const char *path, pt_error *err);

/* Closes and removes t (a write that failed); accepts one already closed. */
void pt_temp_abort(pt_temp *t);

/* Replaces path with the n bytes of data, durably (see above), mode 0644
 * before umask. PT_ERR_ARG when path is empty or ends in '/'; PT_ERR_IO naming
 * path (no temporary file is left behind), also when the folder's fsync fails
 * after the rename. */
pt_status pt_write_file_atomic(const char *path, const void *data, size_t n, pt_error *err);

/* pt_write_file_atomic with the new file's mode before umask (e.g. 0666 for a
 * file handed to the user, as readable as any new file of theirs). */
pt_status pt_write_file_atomic_mode(const char *path, const void *data, size_t n, unsigned mode,
                                    pt_error *err);

/* Reads the whole file into a pt_malloc'd buffer (*out, *len; free with
 * pt_free). PT_ERR_IO naming path when it cannot be read, PT_ERR_FORMAT when
 * it is not a regular file (a FIFO is refused, not waited on), PT_ERR_LIMIT
 * when it is larger than max bytes, PT_ERR_NOMEM. */
pt_status pt_read_file(const char *path, size_t max, uint8_t **out, size_t *len, pt_error *err);

/* Opens path read-only for reading a regular file, into *fd (O_CLOEXEC;
 * close it). Never blocks: the open is O_NONBLOCK, so a FIFO at path is
 * refused, not waited on. With follow 0 a symbolic link at path's last
 * component is refused too (O_NOFOLLOW), for names in a folder that others
 * may write to, such as the output folder. PT_ERR_FORMAT for a link or a
 * file that is not regular, PT_ERR_IO (errno kept, so ENOENT can be told
 * apart) when it cannot be opened. *fd is untouched on failure. */
pt_status pt_open_regular(const char *path, int follow, int *fd, pt_error *err);

/* pt_read_file that does not follow a symbolic link at path's last component
 * and reads a regular file only (a FIFO does not block): PT_ERR_FORMAT for a
 * link or another kind of file, else as pt_read_file (errno kept on
 * PT_ERR_IO, so ENOENT can be told apart). For files in a folder that others
 * may write to, such as the output folder. */
pt_status pt_read_file_nofollow(const char *path, size_t max, uint8_t **out, size_t *len,
                                pt_error *err);

/* pt_read_file for rel, a relative name ('/'-separated) below the folder
 * dirfd, that never leaves that folder: each folder on the way is opened
 * with O_NOFOLLOW|O_DIRECTORY from the one before, and the file itself with
 * O_NOFOLLOW|O_NONBLOCK, so a symbolic link anywhere is refused, and so is
 * a name that is not a regular file (a FIFO does not block, /dev/zero is not
 * read). "." and empty components are skipped; ".." is refused (callers
 * check names first: pt_uri_path_refusal). Messages name rel, never the
 * folder. PT_ERR_FORMAT for a link, a non-folder on the way, a file that is
 * not regular, "..", or an absolute rel; PT_ERR_LIMIT over max bytes (checked
 * before reading); PT_ERR_IO when missing or unreadable; PT_ERR_NOMEM. */
pt_status pt_read_file_beneath(int dirfd, const char *rel, size_t max, uint8_t **out, size_t *len,
                               pt_error *err);

/* mkdir -p with mode 0755 (0700 with private), each component created if missing. */
pt_status pt_mkdirs(const char *path, int private_, pt_error *err);

/* rm -r of a folder this program created (files and folders below it; links
 * are removed, not followed). Missing is fine. Returns 0, or -1 with errno. */
int pt_remove_tree(const char *path);

/* Test hooks' gate: waits until path exists, polling every 10 ms; returns at
 * once for an empty path. The coordinator's threads hold a write on it when
 * a test names a gate file in the environment (PTSERVE_TEST_*_GATE). */
void pt_wait_for_file(const char *path);

#endif
