/*
 * fuzz_util.h - what the fuzz targets of files share: the invariant check
 * and a private scratch folder.
 *
 * The decoders of files (the glTF loader, the bundle, the state folder's
 * queue, checkpoints and results logs) are fuzzed through their real entry
 * points, which read real files: a target writes its input into the scratch
 * folder and calls them. The folder is made once per process, in /dev/shm
 * when there is one (no disk in the loop, and an fsync costs nothing), else
 * in $TMPDIR or /tmp, and removed at exit. Single-threaded, as libFuzzer
 * calls a target.
 */
#ifndef PT_TESTS_FUZZ_UTIL_H
#define PT_TESTS_FUZZ_UTIL_H

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "common/base/error.h"
#include "common/base/fsutil.h"

#define FUZZ_CHECK(cond)                                                                           \
    do {                                                                                           \
        if (!(cond)) {                                                                             \
            fprintf(stderr, "%s:%d: fuzz invariant broken: %s\n", __FILE__, __LINE__, #cond);      \
            abort();                                                                               \
        }                                                                                          \
    } while (0)

static char fuzz_dir_path[512];

static inline void fuzz_dir_remove(void)
{
    if (fuzz_dir_path[0])
        pt_remove_tree(fuzz_dir_path);
}

/* The scratch folder (made on first use; aborts when it cannot be). */
static inline const char *fuzz_dir(void)
{
    if (fuzz_dir_path[0])
        return fuzz_dir_path;
    struct stat sb;
    const char *base = getenv("TMPDIR");
    if (stat("/dev/shm", &sb) == 0 && S_ISDIR(sb.st_mode) && access("/dev/shm", W_OK) == 0)
        base = "/dev/shm";
    else if (!base || !base[0])
        base = "/tmp";
    snprintf(fuzz_dir_path, sizeof fuzz_dir_path, "%s/ptfuzz.XXXXXX", base);
    if (!mkdtemp(fuzz_dir_path)) {
        perror(fuzz_dir_path);
        abort();
    }
    atexit(fuzz_dir_remove);
    return fuzz_dir_path;
}

/* Writes dir/name with exactly data[0, len) (aborts on a write error: the
 * harness, not the code under test, failed). */
static inline void fuzz_write(const char *dir, const char *name, const void *data, size_t len)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "wb");
    if (!f || (len && fwrite(data, 1, len, f) != len) || fclose(f) != 0) {
        perror(path);
        abort();
    }
}

/* With PT_FUZZ_VERBOSE set, prints each verdict (to see what a corpus
 * reaches: replay the corpus with it). */
static inline void fuzz_note(const char *what, pt_status st, const pt_error *err)
{
    static int verbose = -1;
    if (verbose < 0)
        verbose = getenv("PT_FUZZ_VERBOSE") != NULL;
    if (verbose)
        fprintf(stderr, "  %s: %s\n", what, st == PT_OK ? "ok" : err->msg);
}

/* Removes dir/name if it is there. */
static inline void fuzz_unlink(const char *dir, const char *name)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    unlink(path);
}

#endif
