#include "server/core.h"

#include <stdarg.h>
#include <stdio.h>

void srv_log(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fputs("\rptserve: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputs("\033[K\n", stderr);
    va_end(ap);
}

void srv_histogram_add(srv_histogram *h, double seconds)
{
    double bound = SRV_HIST_FIRST;
    for (int i = 0; i < SRV_HIST_BUCKETS; i++, bound *= SRV_HIST_FACTOR)
        if (seconds <= bound)
            h->buckets[i]++;
    h->count++;
    h->sum += seconds;
}
