#include "server/core.h"

#include <stdarg.h>
#include <stdio.h>
#include <time.h>

uint64_t srv_now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000u + (uint64_t)ts.tv_nsec / 1000000u;
}

void srv_log(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fputs("\rptserve: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputs("\033[K\n", stderr);
    va_end(ap);
}
