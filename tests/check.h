/*
 * check.h - the tiny test harness every test executable uses.
 *
 * CHECK(cond) records a failure with file:line and goes on; CHECKF adds a
 * printf-style explanation. A test's main returns check_report(), which prints
 * "N passed, N failed" and returns non-zero on any failure.
 */
#ifndef PT_TESTS_CHECK_H
#define PT_TESTS_CHECK_H

#include <stdio.h>
#include <stdlib.h>

static int check_passed_, check_failed_;

#define CHECK(cond)                                                                  \
    do {                                                                             \
        if (cond) {                                                                  \
            check_passed_++;                                                         \
        } else {                                                                     \
            check_failed_++;                                                         \
            fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond); \
        }                                                                            \
    } while (0)

#define CHECKF(cond, ...)                                                            \
    do {                                                                             \
        if (cond) {                                                                  \
            check_passed_++;                                                         \
        } else {                                                                     \
            check_failed_++;                                                         \
            fprintf(stderr, "%s:%d: CHECK failed: %s: ", __FILE__, __LINE__, #cond); \
            fprintf(stderr, __VA_ARGS__);                                            \
            fputc('\n', stderr);                                                     \
        }                                                                            \
    } while (0)

/* Shared assets are required in CI (CI=true); elsewhere they may be absent. */
static inline int check_shared_required(void)
{
    const char *ci = getenv("CI");
    return ci && *ci && ci[0] != '0' && ci[0] != 'f';
}

static inline int check_report(void)
{
    printf("%d passed, %d failed\n", check_passed_, check_failed_);
    return check_failed_ ? 1 : 0;
}

#endif
