/*
 * log.h - the coordinator's log line, at the bottom of server/: every part
 * logs through it, and it knows none of them.
 *
 * Threads: any thread may call srv_log (one fputs run per line).
 */
#ifndef PT_SERVER_LOG_H
#define PT_SERVER_LOG_H

/* One line on stderr, "ptserve: " first (over a progress line, if any). */
void srv_log(const char *fmt, ...) __attribute__((format(printf, 1, 2)));

#endif
