/* Tests for common/base/opt.c: every value form at its bounds, and every
 * reject path with the message that names the option. */
#include "common/base/opt.h"

#include <float.h>
#include <stdint.h>
#include <string.h>

#include "tests/check.h"

static void test_u32(void)
{
    pt_error err = {0};
    uint32_t v = 7;
    CHECK(pt_opt_u32("--spp", "1", 1, 10, &v, &err) == PT_OK && v == 1);
    CHECK(pt_opt_u32("--spp", "10", 1, 10, &v, &err) == PT_OK && v == 10);
    CHECK(pt_opt_u32("--seed", "0", 0, UINT32_MAX, &v, &err) == PT_OK && v == 0);
    CHECK(pt_opt_u32("--seed", "4294967295", 0, UINT32_MAX, &v, &err) == PT_OK && v == UINT32_MAX);
    CHECK(pt_opt_u32("--seed", "007", 0, 10, &v, &err) == PT_OK && v == 7);
    const char *bad[] = {"0",
                         "11",
                         "",
                         "-1",
                         "+5",
                         " 5",
                         "5 ",
                         "0x5",
                         "1e3",
                         "5.0",
                         "abc",
                         "4294967296",
                         "18446744073709551616",
                         "99999999999999999999999"};
    for (size_t i = 0; i < sizeof bad / sizeof *bad; i++) {
        v = 7;
        CHECKF(pt_opt_u32("--spp", bad[i], 1, 10, &v, &err) == PT_ERR_ARG && v == 7, "'%s'",
               bad[i]);
    }
    pt_opt_u32("--tile", "0", 1, 256, &v, &err);
    CHECKF(!strcmp(err.msg, "--tile: '0' is not a whole number in [1, 256]"), "%s", err.msg);
    CHECK(pt_opt_u32("--tile", "x", 1, 256, &v, NULL) == PT_ERR_ARG);
}

static void test_u64_i32(void)
{
    pt_error err = {0};
    uint64_t u = 3;
    CHECK(pt_opt_u64("job", "18446744073709551615", UINT64_MAX, &u, &err) == PT_OK &&
          u == UINT64_MAX);
    CHECK(pt_opt_u64("job", "18446744073709551616", UINT64_MAX, &u, &err) == PT_ERR_ARG);
    CHECK(pt_opt_u64("job", "-3", UINT64_MAX, &u, &err) == PT_ERR_ARG);
    CHECK(pt_opt_u64("job", "11", 10, &u, &err) == PT_ERR_ARG && u == UINT64_MAX);
    CHECK(strstr(err.msg, "[0, 10]") != NULL);

    int32_t i = 5;
    CHECK(pt_opt_i32("--priority", "-2147483648", INT32_MIN, INT32_MAX, &i, &err) == PT_OK &&
          i == INT32_MIN);
    CHECK(pt_opt_i32("--priority", "2147483647", INT32_MIN, INT32_MAX, &i, &err) == PT_OK &&
          i == INT32_MAX);
    CHECK(pt_opt_i32("--priority", "-0", INT32_MIN, INT32_MAX, &i, &err) == PT_OK && i == 0);
    const char *bad[] = {"2147483648", "-2147483649",         "", "-", "--1", "+1", "high",
                         "1.5",        "99999999999999999999"};
    for (size_t k = 0; k < sizeof bad / sizeof *bad; k++) {
        i = 5;
        CHECKF(pt_opt_i32("--priority", bad[k], INT32_MIN, INT32_MAX, &i, &err) == PT_ERR_ARG &&
                   i == 5,
               "'%s'", bad[k]);
    }
    CHECK(pt_opt_i32("--n", "-3", -2, 2, &i, &err) == PT_ERR_ARG);
    CHECKF(!strcmp(err.msg, "--n: '-3' is not a whole number in [-2, 2]"), "%s", err.msg);
}

static void test_double(void)
{
    pt_error err = {0};
    double d = 9;
    CHECK(pt_opt_double("--x", "0", 0, 1, &d, &err) == PT_OK && d == 0);
    CHECK(pt_opt_double("--x", "1", 0, 1, &d, &err) == PT_OK && d == 1);
    CHECK(pt_opt_double("--x", "2.5e-1", 0, 1, &d, &err) == PT_OK && d == 0.25);
    const char *bad[] = {"-0.1", "1.0001", "", "nan", "inf", "-inf", "1e999", "0.5x", "x"};
    for (size_t k = 0; k < sizeof bad / sizeof *bad; k++) {
        d = 9;
        CHECKF(pt_opt_double("--x", bad[k], 0, 1, &d, &err) == PT_ERR_ARG && d == 9, "'%s'",
               bad[k]);
    }
    CHECKF(!strcmp(err.msg, "--x: 'x' is not a number in [0, 1]"), "%s", err.msg);
    CHECK(pt_opt_double("--g", "-1", 0, DBL_MAX, &d, &err) == PT_ERR_ARG);
    CHECKF(!strcmp(err.msg, "--g: '-1' is not a number >= 0"), "%s", err.msg);
    CHECK(pt_opt_double("--c", "-1e300", -DBL_MAX, DBL_MAX, &d, &err) == PT_OK && d == -1e300);
    CHECK(pt_opt_double("--c", "inf", -DBL_MAX, DBL_MAX, &d, &err) == PT_ERR_ARG);
    CHECKF(!strcmp(err.msg, "--c: 'inf' is not a finite number"), "%s", err.msg);

    CHECK(pt_opt_positive("--e", "1e-9", 1e6, &d, &err) == PT_OK && d == 1e-9);
    CHECK(pt_opt_positive("--e", "1e6", 1e6, &d, &err) == PT_OK && d == 1e6);
    CHECK(pt_opt_positive("--e", "0", 1e6, &d, &err) == PT_ERR_ARG);
    CHECK(pt_opt_positive("--e", "1000001", 1e6, &d, &err) == PT_ERR_ARG);
    CHECKF(strstr(err.msg, "is not a positive number, at most") != NULL, "%s", err.msg);
    CHECK(pt_opt_positive("--g", "inf", DBL_MAX, &d, &err) == PT_ERR_ARG);
    CHECKF(!strcmp(err.msg, "--g: 'inf' is not a positive number"), "%s", err.msg);
    CHECK(pt_opt_positive("--g", "nan", DBL_MAX, &d, &err) == PT_ERR_ARG && d == 1e6);

    CHECK(pt_opt_seconds("--t", "0.001", 0.001, 86400, &d, &err) == PT_OK && d == 0.001);
    CHECK(pt_opt_seconds("--t", "86400", 0.001, 86400, &d, &err) == PT_OK && d == 86400);
    CHECK(pt_opt_seconds("--t", "0", 0.001, 86400, &d, &err) == PT_ERR_ARG);
    CHECK(pt_opt_seconds("--t", "86400.5", 0.001, 86400, &d, &err) == PT_ERR_ARG);
    CHECKF(!strcmp(err.msg, "--t: '86400.5' is not a number of seconds in [0.001, 86400]"), "%s",
           err.msg);
}

static void test_res(void)
{
    pt_error err = {0};
    uint32_t w = 1, h = 2;
    CHECK(pt_opt_res("--res", "640x480", 16384, &w, &h, &err) == PT_OK && w == 640 && h == 480);
    CHECK(pt_opt_res("--res", "16384x1", 16384, &w, &h, &err) == PT_OK && w == 16384 && h == 1);
    const char *bad[] = {"640",      "x480",     "640x",
                         "0x480",    "640x0",    "16385x1",
                         "1x16385",  "640X480",  "640x480x2",
                         "-640x480", "640 x480", "1234567890123456789012345678901234567890x1"};
    for (size_t k = 0; k < sizeof bad / sizeof *bad; k++) {
        w = 1, h = 2;
        CHECKF(pt_opt_res("--res", bad[k], 16384, &w, &h, &err) == PT_ERR_ARG && w == 1 && h == 2,
               "'%s'", bad[k]);
    }
    pt_opt_res("--res", "640", 16384, &w, &h, &err);
    CHECKF(!strcmp(err.msg, "--res: '640' is not WIDTHxHEIGHT"), "%s", err.msg);
    pt_opt_res("--res", "640x0", 16384, &w, &h, &err);
    CHECKF(!strcmp(err.msg, "--res height: '0' is not a whole number in [1, 16384]"), "%s",
           err.msg);
    pt_opt_res("--res", "0x5", 16384, &w, &h, &err);
    CHECKF(!strncmp(err.msg, "--res width: ", 13), "%s", err.msg);
}

static void test_shutter(void)
{
    pt_error err = {0};
    double v[2] = {7, 7};
    CHECK(pt_opt_shutter("--shutter", "0,0.5", v, &err) == PT_OK && v[0] == 0.0 && v[1] == 0.5);
    CHECK(pt_opt_shutter("--shutter", "0,1", v, &err) == PT_OK && v[0] == 0.0 && v[1] == 1.0);
    CHECK(pt_opt_shutter("--shutter", "0.25,0.25", v, &err) == PT_OK && v[0] == 0.25);
    const char *shape[] = {"",        ",",   "0",     "0,",    ",0.5",   "0;0.5",
                           "0,0.5,1", "a,b", "0,nan", "inf,1", "0 ,0.5x"};
    for (size_t i = 0; i < sizeof shape / sizeof *shape; i++) {
        v[0] = v[1] = 7;
        CHECKF(pt_opt_shutter("--shutter", shape[i], v, &err) == PT_ERR_ARG && v[0] == 7 &&
                   v[1] == 7 && strstr(err.msg, "is not OPEN,CLOSE"),
               "'%s': %s", shape[i], err.msg);
    }
    CHECK(pt_opt_shutter("--shutter", "-0.1,0.5", v, &err) == PT_ERR_ARG &&
          strstr(err.msg, "[0, 1]"));
    CHECK(pt_opt_shutter("--shutter", "0,1.5", v, &err) == PT_ERR_ARG && strstr(err.msg, "[0, 1]"));
    CHECK(pt_opt_shutter("--shutter", "0.6,0.4", v, &err) == PT_ERR_ARG &&
          strstr(err.msg, "opens (0.6) after it closes (0.4)"));
    CHECK(v[0] == 7 && v[1] == 7);
}

/* R,G,B and X,Y,Z: three numbers each, the same reader; colours >= 0. */
static void test_triples(void)
{
    pt_error err = {0};
    double v[3] = {9, 9, 9};
    CHECK(pt_opt_rgb("--background", "0.5,1,0", 1e20, v, &err) == PT_OK && v[0] == 0.5 &&
          v[1] == 1 && v[2] == 0);
    CHECK(pt_opt_rgb("--background", "-1,1,1", 1e20, v, &err) == PT_ERR_ARG && v[0] == 0.5);
    CHECKF(!strcmp(err.msg, "--background: '-1,1,1' is not R,G,B (three numbers in [0, 1e+20])"),
           "%s", err.msg);
    CHECK(pt_opt_point("--camera-at", "-1,2.5,-3e2", 1e15, v, &err) == PT_OK && v[0] == -1 &&
          v[1] == 2.5 && v[2] == -300);
    const char *bad[] = {"1,2", "1,2,3,4", "1,,3", "a,b,c", "1,2,nan", "1,2,inf", "", "2e15,0,0"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        CHECKF(pt_opt_point("--camera-at", bad[i], 1e15, v, &err) == PT_ERR_ARG, "'%s'", bad[i]);
        CHECK(strstr(err.msg, "is not X,Y,Z") != NULL && v[0] == -1);
    }
}

int main(void)
{
    test_triples();
    test_u32();
    test_u64_i32();
    test_double();
    test_res();
    test_shutter();
    return check_report();
}
