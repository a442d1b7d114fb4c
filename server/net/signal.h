/*
 * signal.h - SIGINT and SIGTERM for the coordinator's event loop.
 *
 * The handler records which signal came (srv_signal_stopped) and writes a
 * byte into the loop's wake pipe so that epoll_wait returns. It runs on
 * whichever thread the kernel picks, at any moment, also while the loop
 * closes: srv_signal_withdraw takes the pipe away from it and returns only
 * once no handler can still write into it, so the pipe may then be closed
 * and its descriptor number reused without a late byte landing in whatever
 * the process opens next.
 *
 * Threads: the loop's thread calls srv_signal_attach and
 * srv_signal_withdraw; srv_signal_stopped may be read anywhere.
 */
#ifndef PT_SERVER_SIGNAL_H
#define PT_SERVER_SIGNAL_H

/* Installs the handlers (SIGINT, SIGTERM; SIGPIPE ignored) and has them
 * write to wake_fd (a pipe's non-blocking write end). */
void srv_signal_attach(int wake_fd);

/* Takes wake_fd from the handlers; returns once none is using it. */
void srv_signal_withdraw(void);

/* The signal that asked the coordinator to stop, or 0. */
int srv_signal_stopped(void);

/* Tests only: the handler pauses this long after it has read the wake
 * descriptor and before it writes, which widens the window that
 * srv_signal_withdraw closes. */
void srv_signal_test_pause(long nanoseconds);

#endif
