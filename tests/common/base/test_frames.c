/* Tests for common/base/frames.c: frame ranges at their bounds and every
 * reject path, frame numbers and indices, times, and the '#' pattern. */
#include "common/base/frames.h"

#include <string.h>

#include "tests/check.h"

static void test_parse(void)
{
    pt_error err = {0};
    pt_frames f = {9, 9, 9};
    CHECK(pt_frames_parse("--frames", "1-10", &f, &err) == PT_OK && f.first == 1 && f.last == 10 &&
          f.step == 1 && pt_frames_count(&f) == 10);
    CHECK(pt_frames_parse("--frames", "0-9:3", &f, &err) == PT_OK && f.step == 3 &&
          pt_frames_count(&f) == 4);
    CHECK(pt_frames_parse("--frames", "0-10:3", &f, &err) == PT_OK && pt_frames_count(&f) == 4 &&
          pt_frames_number(&f, 3) == 9);
    CHECK(pt_frames_parse("--frames", "7", &f, &err) == PT_OK && f.first == 7 && f.last == 7 &&
          pt_frames_count(&f) == 1);
    CHECK(pt_frames_parse("--frames", "5-5", &f, &err) == PT_OK && pt_frames_count(&f) == 1);
    CHECK(pt_frames_parse("--frames", "0-99999", &f, &err) == PT_OK &&
          pt_frames_count(&f) == PT_FRAMES_MAX_COUNT);
    CHECK(pt_frames_parse("--frames", "900000-999999", &f, &err) == PT_OK &&
          pt_frames_count(&f) == PT_FRAMES_MAX_COUNT);
    CHECK(pt_frames_parse("--frames", "0-999999:10", &f, &err) == PT_OK &&
          pt_frames_count(&f) == PT_FRAMES_MAX_COUNT);
    pt_frames keep = f;
    /* Malformed, each refused naming the option, *out untouched. */
    const char *bad[] = {"",      "-",     "1-",    "-5",      "a-b",     "1-2:",
                         "1-2:x", "1-2-3", "1:2",   " 1-2",    "1-2 ",    "+1-2",
                         "1-+2",  "0x1-2", "1.5-2", "1-2:3:4", "1e3-2e3", "1234567890-1234567891"};
    for (size_t i = 0; i < sizeof bad / sizeof *bad; i++) {
        CHECKF(pt_frames_parse("--frames", bad[i], &f, &err) == PT_ERR_ARG, "'%s'", bad[i]);
        CHECKF(strstr(err.msg, "--frames") && strstr(err.msg, "A-B[:STEP]"), "'%s': %s", bad[i],
               err.msg);
    }
    CHECK(memcmp(&f, &keep, sizeof f) == 0);
    CHECK(pt_frames_parse("--frames", "10-3", &f, &err) == PT_ERR_ARG &&
          strstr(err.msg, "ends before it starts"));
    CHECK(pt_frames_parse("--frames", "1-10:0", &f, &err) == PT_ERR_ARG &&
          strstr(err.msg, "STEP 0"));
    CHECK(pt_frames_parse("--frames", "0-100000", &f, &err) == PT_ERR_ARG &&
          strstr(err.msg, "100001 frames, over the cap of 100000"));
    CHECK(pt_frames_parse("--frames", "0-1000000", &f, &err) == PT_ERR_ARG &&
          strstr(err.msg, "highest frame number"));
    CHECK(memcmp(&f, &keep, sizeof f) == 0);
}

static void test_check(void)
{
    pt_frames none = {0, 0, 0}, ok = {3, 9, 2}, rev = {9, 3, 1}, zero = {1, 2, 0};
    pt_frames big = {0, 100000, 1}, high = {0, 1000000, 100};
    CHECK(pt_frames_check(&none, NULL) == PT_OK && pt_frames_count(&none) == 0);
    CHECK(pt_frames_check(&ok, NULL) == PT_OK);
    CHECK(pt_frames_check(&rev, NULL) == PT_ERR_ARG && pt_frames_count(&rev) == 0);
    CHECK(pt_frames_check(&zero, NULL) == PT_ERR_ARG);
    CHECK(pt_frames_check(&big, NULL) == PT_ERR_ARG);
    CHECK(pt_frames_check(&high, NULL) == PT_ERR_ARG);
}

static void test_index(void)
{
    pt_frames f = {10, 20, 5};
    CHECK(pt_frames_index(&f, 10) == 0 && pt_frames_index(&f, 15) == 1 &&
          pt_frames_index(&f, 20) == 2);
    CHECK(pt_frames_index(&f, 11) == -1 && pt_frames_index(&f, 5) == -1 &&
          pt_frames_index(&f, 25) == -1);
    for (uint32_t i = 0; i < pt_frames_count(&f); i++)
        CHECK(pt_frames_index(&f, pt_frames_number(&f, i)) == (int64_t)i);
    /* Frame F is at F / fps seconds: the one definition standalone shares. */
    CHECK(pt_frames_time(0, 24.0) == 0.0);
    CHECK(pt_frames_time(12, 24.0) == 0.5);
    CHECK(pt_frames_time(7, 30.0) == 7.0 / 30.0);
}

static void test_name(void)
{
    pt_error err = {0};
    char out[64];
    CHECK(pt_frames_name("shot.####.exr", 7, out, sizeof out, &err) == PT_OK &&
          strcmp(out, "shot.0007.exr") == 0);
    CHECK(pt_frames_name("shot.####.exr", 123456, out, sizeof out, &err) == PT_OK &&
          strcmp(out, "shot.123456.exr") == 0); /* wider than the run: written whole */
    CHECK(pt_frames_name("f#.exr", 3, out, sizeof out, &err) == PT_OK &&
          strcmp(out, "f3.exr") == 0);
    /* The last run only: an earlier '#' is part of the folder or name. */
    CHECK(pt_frames_name("a#b/shot_##.exr", 5, out, sizeof out, &err) == PT_OK &&
          strcmp(out, "a#b/shot_05.exr") == 0);
    CHECK(pt_frames_name("######", 42, out, sizeof out, &err) == PT_OK &&
          strcmp(out, "000042") == 0);
    CHECK(pt_frames_has_pattern("x.#.exr") && !pt_frames_has_pattern("x.exr"));
    CHECK(pt_frames_name("shot.exr", 1, out, sizeof out, &err) == PT_ERR_ARG &&
          strstr(err.msg, "no '#'"));
    CHECK(pt_frames_name("shot.####.exr", 1, out, 8, &err) == PT_ERR_LIMIT);
}

int main(void)
{
    test_parse();
    test_check();
    test_index();
    test_name();
    return check_report();
}
