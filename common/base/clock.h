/*
 * clock.h - the time the project reads, and how it prints a time left.
 *
 * Every timer, lease, heartbeat and progress rate reads the monotonic clock
 * (CLOCK_MONOTONIC): it never steps back when the wall clock is set, so a
 * difference of two readings is a true duration. Readings are comparable only
 * within one process; they are never sent to a peer or written to a file.
 * The CPU clocks measure work, not waits for a core, for the benchmarks.
 * Thread-safety: any thread may call any of these (clock_gettime is
 * reentrant; pt_format_eta writes only to the caller's buffer).
 */
#ifndef PT_COMMON_BASE_CLOCK_H
#define PT_COMMON_BASE_CLOCK_H

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

#endif
