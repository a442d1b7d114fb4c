#include "server/core.h"

void srv_histogram_add(srv_histogram *h, double seconds)
{
    double bound = SRV_HIST_FIRST;
    for (int i = 0; i < SRV_HIST_BUCKETS; i++, bound *= SRV_HIST_FACTOR)
        if (seconds <= bound)
            h->buckets[i]++;
    h->count++;
    h->sum += seconds;
}
