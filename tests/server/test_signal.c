/*
 * test_signal.c - a Ctrl-C that arrives while the coordinator closes its
 * loop never writes into a descriptor the process has reused.
 *
 * The handler (server/net/signal.c) is made to pause between reading the
 * wake descriptor and writing to it (srv_signal_test_pause), on a thread of
 * its own. While it pauses, the loop's thread withdraws the pipe, closes it
 * and opens a new one, which takes the same descriptor numbers. The withdraw
 * must wait for the handler: its byte lands in the old pipe before that is
 * closed, and the new pipe stays empty. Without the wait the byte went into
 * the new pipe, whatever it was. A signal after the withdraw writes nowhere.
 */
#define _GNU_SOURCE /* pipe2 */
#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <signal.h>
#include <time.h>
#include <unistd.h>

#include "server/net/signal.h"
#include "tests/check.h"

static void *raise_int(void *arg)
{
    (void)arg;
    raise(SIGINT); /* the handler runs on this thread */
    return NULL;
}

static void nap_ms(long ms)
{
    struct timespec ts = {ms / 1000, (ms % 1000) * 1000000L};
    nanosleep(&ts, NULL);
}

/* Bytes waiting in a non-blocking pipe's read end (reads them). */
static int pending(int fd)
{
    char buf[16];
    int n = 0;
    ssize_t r;
    while ((r = read(fd, buf, sizeof buf)) > 0)
        n += (int)r;
    return n;
}

int main(void)
{
    int a[2];
    CHECK(pipe2(a, O_NONBLOCK | O_CLOEXEC) == 0);
    srv_signal_attach(a[1]);
    srv_signal_test_pause(400L * 1000 * 1000);
    CHECK(srv_signal_stopped() == 0);

    pthread_t t;
    CHECK(pthread_create(&t, NULL, raise_int, NULL) == 0);
    /* The handler sets the stop first and then reads the descriptor:
     * once the stop shows, it is (within a few instructions) in its pause. */
    for (int i = 0; i < 5000 && srv_signal_stopped() == 0; i++)
        nap_ms(2);
    CHECK(srv_signal_stopped() == SIGINT);
    nap_ms(50);

    srv_signal_withdraw();
    CHECKF(pending(a[0]) == 1, "the handler's byte is in the old pipe once withdraw returns");
    close(a[0]);
    close(a[1]);
    int b[2];
    CHECK(pipe2(b, O_NONBLOCK | O_CLOEXEC) == 0);
    CHECKF((b[0] == a[0] || b[0] == a[1]) && (b[1] == a[0] || b[1] == a[1]),
           "the new pipe reuses the old numbers (%d, %d; were %d, %d)", b[0], b[1], a[0], a[1]);
    pthread_join(t, NULL);
    CHECKF(pending(b[0]) == 0, "no byte in the pipe opened after the withdraw");

    /* A signal after the withdraw: the stop is recorded, nothing written. */
    srv_signal_test_pause(0);
    CHECK(pthread_create(&t, NULL, raise_int, NULL) == 0);
    pthread_join(t, NULL);
    CHECK(srv_signal_stopped() == SIGINT);
    CHECK(pending(b[0]) == 0);
    close(b[0]);
    close(b[1]);
    return check_report();
}
