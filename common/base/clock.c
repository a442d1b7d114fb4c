#include "common/base/clock.h"

#include <pthread.h>
#include <stdio.h>
#include <time.h>

static double seconds_of(clockid_t id)
{
    struct timespec ts;
    clock_gettime(id, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

uint64_t pt_now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000u + (uint64_t)ts.tv_nsec / 1000000u;
}

double pt_now_s(void)
{
    return seconds_of(CLOCK_MONOTONIC);
}

double pt_cpu_s(void)
{
    return seconds_of(CLOCK_PROCESS_CPUTIME_ID);
}

double pt_thread_cpu_s(void)
{
    return seconds_of(CLOCK_THREAD_CPUTIME_ID);
}

void pt_format_eta(double s, char *buf, size_t n)
{
    /* The negated test also sends NaN to "--". */
    if (!(s >= 0) || s > 360000)
        snprintf(buf, n, "--");
    else if (s >= 3600)
        snprintf(buf, n, "%dh%02dm", (int)(s / 3600), (int)(s / 60) % 60);
    else if (s >= 60)
        snprintf(buf, n, "%dm%02ds", (int)(s / 60), (int)s % 60);
    else
        snprintf(buf, n, "%.0fs", s);
}

void pt_format_progress(unsigned thousandths, double seconds, char *buf, size_t n)
{
    char eta[32];
    pt_format_eta(thousandths ? seconds * (1000.0 - thousandths) / thousandths : -1.0, eta,
                  sizeof eta);
    snprintf(buf, n, "%5.1f%%  ETA %s", thousandths / 10.0, eta);
}

void pt_progress_line_report(unsigned thousandths, double seconds, void *line)
{
    pt_progress_line *l = line;
    char text[64];
    pt_format_progress(thousandths, seconds, text, sizeof text);
    fprintf(stderr, "\r%s %s   ", l->what, text);
    l->printed = 1;
}

void pt_progress_line_end(pt_progress_line *line)
{
    if (line->printed)
        fputc('\n', stderr);
    line->printed = 0;
}

typedef struct reported {
    int (*fn)(void *);
    void *arg;
    int ret;
    atomic_int done;
} reported;

static void *reported_main(void *p)
{
    reported *r = p;
    r->ret = r->fn(r->arg);
    atomic_store(&r->done, 1);
    return NULL;
}

int pt_run_reported(int (*fn)(void *), void *arg, atomic_uint *progress,
                    void (*report)(unsigned progress, double seconds, void *ctx), void *ctx)
{
    reported r = {.fn = fn, .arg = arg};
    atomic_init(&r.done, 0);
    pthread_t t;
    if (pthread_create(&t, NULL, reported_main, &r) != 0)
        return fn(arg);
    double t0 = pt_now_s(), last = t0;
    while (!atomic_load(&r.done)) {
        struct timespec ts = {0, 50 * 1000 * 1000};
        nanosleep(&ts, NULL);
        double now = pt_now_s();
        if (now - last >= 1.0 && !atomic_load(&r.done)) {
            last = now;
            report(atomic_load(progress), now - t0, ctx);
        }
    }
    pthread_join(t, NULL);
    return r.ret;
}
