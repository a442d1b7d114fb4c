/* Tests for common/base/clock.c: the monotonic readings and the ETA text. */
#include "common/base/clock.h"

#include <math.h>
#include <string.h>
#include <time.h>

#include "tests/check.h"

static void test_monotonic(void)
{
    uint64_t m0 = pt_now_ms();
    double s0 = pt_now_s();
    struct timespec d = {0, 20 * 1000000L};
    nanosleep(&d, NULL);
    uint64_t m1 = pt_now_ms();
    double s1 = pt_now_s();
    CHECKF(m1 - m0 >= 19 && m1 >= m0, "%llu ms", (unsigned long long)(m1 - m0));
    CHECKF(s1 - s0 >= 0.019, "%g s", s1 - s0);
    /* The two readings are of one clock. */
    CHECK(fabs((double)m1 / 1000.0 - s1) < 0.5);
}

static void test_cpu(void)
{
    double p0 = pt_cpu_s(), t0 = pt_thread_cpu_s();
    volatile double x = 0;
    for (int i = 0; i < 2000000; i++)
        x += i * 1e-9;
    CHECK(x > 0); /* the loop ran: some CPU time passed */
    CHECK(pt_cpu_s() >= p0 && pt_thread_cpu_s() >= t0);
    CHECK(pt_thread_cpu_s() > 0 && pt_cpu_s() > 0);
}

static void eta_is(double s, const char *want)
{
    char buf[32];
    pt_format_eta(s, buf, sizeof buf);
    CHECKF(!strcmp(buf, want), "%g s: '%s', want '%s'", s, buf, want);
}

static void test_eta(void)
{
    eta_is(-1, "--");
    eta_is(NAN, "--");
    eta_is(INFINITY, "--");
    eta_is(360000.5, "--");
    eta_is(360000, "100h00m");
    eta_is(3600, "1h00m");
    eta_is(3599.9, "59m59s");
    eta_is(3725, "1h02m");
    eta_is(187, "3m07s");
    eta_is(60, "1m00s");
    eta_is(59.4, "59s");
    eta_is(0, "0s");
    eta_is(0.4, "0s");
    /* Cut to the buffer, never overrun. */
    char small[3] = {'x', 'x', 'x'};
    pt_format_eta(3725, small, sizeof small);
    CHECK(!strcmp(small, "1h"));
}

int main(void)
{
    test_monotonic();
    test_cpu();
    test_eta();
    return check_report();
}
