/*
 * check.h - the tiny test harness every test executable uses.
 *
 * CHECK(cond) records a failure with file:line and goes on; CHECKF adds a
 * printf-style explanation; CHECK_SKIP says that a part of the test cannot run
 * here (an optional asset is absent outside CI). A test's main returns
 * check_report(), which prints "N passed, N failed" and returns 1 on any
 * failure, else CHECK_SKIP_STATUS when a part was skipped (ctest's
 * SKIP_RETURN_CODE: the test shows as not run rather than passed), else 0.
 */
#ifndef PT_TESTS_CHECK_H
#define PT_TESTS_CHECK_H

#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>

#define CHECK_SKIP_STATUS 77

static int check_passed_, check_failed_, check_skipped_;

#define CHECK(cond)                                                                                \
    do {                                                                                           \
        if (cond) {                                                                                \
            check_passed_++;                                                                       \
        } else {                                                                                   \
            check_failed_++;                                                                       \
            fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond);               \
        }                                                                                          \
    } while (0)

#define CHECKF(cond, ...)                                                                          \
    do {                                                                                           \
        if (cond) {                                                                                \
            check_passed_++;                                                                       \
        } else {                                                                                   \
            check_failed_++;                                                                       \
            fprintf(stderr, "%s:%d: CHECK failed: %s: ", __FILE__, __LINE__, #cond);               \
            fprintf(stderr, __VA_ARGS__);                                                          \
            fputc('\n', stderr);                                                                   \
        }                                                                                          \
    } while (0)

#define CHECK_SKIP(...)                                                                            \
    do {                                                                                           \
        check_skipped_++;                                                                          \
        printf("skipped: ");                                                                       \
        printf(__VA_ARGS__);                                                                       \
        putchar('\n');                                                                             \
    } while (0)

/* CHECK_SANITIZED: 1 in a sanitizer build (ASan, TSan; GCC defines
 * __SANITIZE_*__, clang answers __has_feature), else 0. The few statistical
 * tests whose power needs millions of samples run a quarter of them there
 * (CHECK_WORK) and ask a bound twice as loose: the sanitizers look for
 * memory and thread errors, which a quarter of the paths reach as well, and
 * the release build holds the full bound. */
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define CHECK_SANITIZED 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
#define CHECK_SANITIZED 1
#endif
#endif
#ifndef CHECK_SANITIZED
#define CHECK_SANITIZED 0
#endif
/* n samples, or a quarter of them (at least 1) in a sanitizer build. */
#define CHECK_WORK(n) (CHECK_SANITIZED ? ((n) / 4 > 0 ? (n) / 4 : 1) : (n))
/* A bound that a quarter of the samples (CHECK_WORK) holds to: twice b in a
 * sanitizer build, else b. */
#define CHECK_LOOSE(b) (CHECK_SANITIZED ? 2.0 * (b) : (b))
/* A farm job's samples that only need to outlast kills or rounds of leases
 * (which follow merged samples, not time): n, or half of n in a sanitizer
 * build, which renders them three to ten times slower. The shell tests'
 * twin is sanitized_spp (tests/integration/lib_build.sh). */
#define CHECK_JOB_SPP(n) (CHECK_SANITIZED ? (n) / 2 : (n))

/* Shared assets are required in CI (CI=true); elsewhere they may be absent. */
static inline int check_shared_required(void)
{
    const char *ci = getenv("CI");
    return ci && *ci && ci[0] != '0' && ci[0] != 'f';
}

/* 1 when the shared file at path can be read; else 0, after failing the
 * check where shared assets are required (CI) or noting a skip. */
static inline int check_shared_file(const char *path)
{
    if (access(path, R_OK) == 0)
        return 1;
    if (check_shared_required())
        CHECKF(0, "%s is missing (CI=true)", path);
    else
        CHECK_SKIP("%s is missing", path);
    return 0;
}

static inline int check_report(void)
{
    printf("%d passed, %d failed", check_passed_, check_failed_);
    if (check_skipped_)
        printf(", %d parts skipped", check_skipped_);
    putchar('\n');
    if (check_failed_)
        return 1;
    return check_skipped_ ? CHECK_SKIP_STATUS : 0;
}

#endif
