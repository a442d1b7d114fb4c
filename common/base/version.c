#include "common/base/version.h"

#include <errno.h>
#include <stdio.h>
#include <string.h>

#ifndef PT_VERSION
#error "PT_VERSION must come from ptbase's compile definitions"
#endif

/* pt_build_id() is in the build's generated/build_id.c (cmake/build_id.cmake). */

int pt_version_print(const char *prog)
{
    /* A script that reads the line must not get a truncated one with status 0. */
    if (printf("%s %s (build %s)\n", prog, PT_VERSION, pt_build_id()) < 0 || fflush(stdout) != 0) {
        fprintf(stderr, "%s: cannot write the version: %s\n", prog, strerror(errno));
        return 1;
    }
    return 0;
}
