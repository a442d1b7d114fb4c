#include "server/net/signal.h"

#include <errno.h>
#include <sched.h>
#include <signal.h>
#include <stdatomic.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

/* Lock-free atomics are async-signal-safe (C11 7.14.1.1). */
_Static_assert(ATOMIC_INT_LOCK_FREE == 2, "the signal handler needs lock-free atomic ints");

/* Atomics, not a volatile sig_atomic_t: the handler may run on any thread
 * and the loop reads the stop on its own. g_busy counts the handlers using
 * the wake pipe's write end now: a handler counts itself in before it reads
 * the descriptor, so a withdraw that then sees a count of 0 knows that no
 * handler holds the old number. */
static atomic_int g_stop;
static atomic_int g_wake_fd = -1;
static atomic_int g_busy;
static atomic_long g_test_pause_ns;

static void on_signal(int sig)
{
    atomic_store(&g_stop, sig);
    atomic_fetch_add(&g_busy, 1);
    int fd = atomic_load(&g_wake_fd);
    if (fd >= 0) {
        int saved = errno;
        long pause = atomic_load(&g_test_pause_ns);
        if (pause > 0) {
            struct timespec ts = {pause / 1000000000L, pause % 1000000000L};
            nanosleep(&ts, NULL); /* async-signal-safe */
        }
        char c = 1;
        ssize_t r = write(fd, &c, 1);
        (void)r;
        errno = saved;
    }
    atomic_fetch_sub(&g_busy, 1);
}

void srv_signal_attach(int wake_fd)
{
    atomic_store(&g_wake_fd, wake_fd);
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
}

void srv_signal_withdraw(void)
{
    atomic_store(&g_wake_fd, -1);
    /* A handler interrupting this thread runs to its end before the loop
     * below resumes; one on another thread is a write away from its end. */
    while (atomic_load(&g_busy) != 0)
        sched_yield();
}

int srv_signal_stopped(void)
{
    return atomic_load(&g_stop);
}

void srv_signal_test_pause(long nanoseconds)
{
    atomic_store(&g_test_pause_ns, nanoseconds);
}
