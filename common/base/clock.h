/*
 * clock.h - the time the project reads, and how it prints a time left.
 *
 * Every timer, lease, heartbeat and progress rate reads the monotonic clock
 * (CLOCK_MONOTONIC): it never steps back when the wall clock is set, so a
 * difference of two readings is a true duration. Readings are comparable only
 * within one process; they are never sent to a peer or written to a file.
 * The CPU clocks measure work, not waits for a core, for the benchmarks.
 * Thread-safety: any thread may call any of these (clock_gettime is
 * reentrant; pt_format_eta writes only to the caller's buffer;
 * pt_run_reported starts and joins a thread of its own).
 */
#ifndef PT_COMMON_BASE_CLOCK_H
#define PT_COMMON_BASE_CLOCK_H

#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

/* Milliseconds of the monotonic clock, from an unspecified start. */
uint64_t pt_now_ms(void);

/* Seconds of the monotonic clock, from an unspecified start, to the nanosecond. */
double pt_now_s(void);

/* Seconds of CPU time used by all the threads of this process. */
double pt_cpu_s(void);

/* Seconds of CPU time used by the calling thread. */
double pt_thread_cpu_s(void);

/* A time left for a progress line, into buf (n bytes, cut to fit):
 * "--" when unknown (negative, NaN) or over 100 hours, "1h02m" from an hour,
 * "3m07s" from a minute, "42s" below (rounded to the second). */
void pt_format_eta(double seconds, char *buf, size_t n);

/* A progress line's "45.3%  ETA 12s" for thousandths of the work done in
 * seconds so far (the time left extrapolated), into buf (n bytes). */
void pt_format_progress(unsigned thousandths, double seconds, char *buf, size_t n);

/* A progress line on stderr for pt_run_reported: report with
 * pt_progress_line_report (ctx: the line), "\r<what> 45.3%  ETA 12s";
 * pt_progress_line_end ends it with a newline once one was printed. */
typedef struct pt_progress_line {
    const char *what; /* "ptdenoise:", "ptworker: denoising" */
    int printed;
} pt_progress_line;
void pt_progress_line_report(unsigned thousandths, double seconds, void *line);
void pt_progress_line_end(pt_progress_line *line);

/* Runs fn(arg) on a thread of its own while the calling thread calls
 * report(*progress, seconds since the start, ctx) about once a second (not
 * at all when fn takes under a second; progress in whatever unit fn keeps
 * it, read atomically), and returns fn's value: a progress line for work
 * that reports how far it is but runs on its own threads (the denoiser).
 * When no thread can be started fn runs on the caller, unreported. */
int pt_run_reported(int (*fn)(void *), void *arg, atomic_uint *progress,
                    void (*report)(unsigned progress, double seconds, void *ctx), void *ctx);

#endif
