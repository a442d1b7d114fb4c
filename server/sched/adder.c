#define _GNU_SOURCE /* pthread_setname_np */
#include "server/sched/adder.h"

#include <pthread.h>

#include "common/base/alloc.h"

typedef struct add_item {
    pt_film *film;
    pt_rect tile;
    pt_pixel_acc *px;
    srv_adds *g;
} add_item;

struct srv_adder {
    pthread_mutex_t mu;
    pthread_cond_t work; /* an item was queued, or stop */
    pthread_cond_t done; /* a group's count reached 0 */
    add_item ring[SRV_ADDER_QUEUE_MAX];
    uint32_t head, len;
    uint32_t idle;    /* threads waiting on work */
    uint32_t waiters; /* callers waiting on done */
    int stop;
    uint64_t threaded, inline_adds;
    uint32_t nthreads;
    pthread_t threads[SRV_ADDER_MAX_THREADS];
};

static void *adder_main(void *p)
{
    srv_adder *a = p;
    pthread_setname_np(pthread_self(), "pt-merge"); /* for top and the farm-scale bench */
    pthread_mutex_lock(&a->mu);
    for (;;) {
        while (!a->len && !a->stop) {
            a->idle++;
            pthread_cond_wait(&a->work, &a->mu);
            a->idle--;
        }
        if (!a->len)
            break;
        add_item it = a->ring[a->head];
        a->head = (a->head + 1) % SRV_ADDER_QUEUE_MAX;
        a->len--;
        pthread_mutex_unlock(&a->mu);

        pt_film_add_tile(it.film, it.tile, it.px);
        pt_free(it.px);

        pthread_mutex_lock(&a->mu);
        a->threaded++;
        if (--it.g->pending == 0 && a->waiters)
            pthread_cond_broadcast(&a->done);
    }
    pthread_mutex_unlock(&a->mu);
    return NULL;
}

pt_status srv_adder_new(uint32_t threads, srv_adder **out, pt_error *err)
{
    if (threads < 1 || threads > SRV_ADDER_MAX_THREADS)
        return pt_error_set(err, PT_ERR_ARG, "merge threads: %u is not 1 to %u", threads,
                            SRV_ADDER_MAX_THREADS);
    srv_adder *a = pt_calloc(1, sizeof *a);
    if (!a)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    pthread_mutex_init(&a->mu, NULL);
    pthread_cond_init(&a->work, NULL);
    pthread_cond_init(&a->done, NULL);
    for (; a->nthreads < threads; a->nthreads++)
        if (pthread_create(&a->threads[a->nthreads], NULL, adder_main, a) != 0) {
            srv_adder_free(a);
            return pt_error_set(err, PT_ERR_NOMEM, "cannot start a merge thread");
        }
    *out = a;
    return PT_OK;
}

void srv_adder_free(srv_adder *a)
{
    if (!a)
        return;
    pthread_mutex_lock(&a->mu);
    a->stop = 1; /* the threads empty the queue before they leave */
    pthread_cond_broadcast(&a->work);
    pthread_mutex_unlock(&a->mu);
    for (uint32_t i = 0; i < a->nthreads; i++)
        pthread_join(a->threads[i], NULL);
    pthread_mutex_destroy(&a->mu);
    pthread_cond_destroy(&a->work);
    pthread_cond_destroy(&a->done);
    pt_free(a);
}

void srv_adder_post(srv_adder *a, srv_adds *g, pt_film *film, pt_rect tile, pt_pixel_acc *px)
{
    pthread_mutex_lock(&a->mu);
    if (a->len == SRV_ADDER_QUEUE_MAX) {
        /* Full: the loop adds this one itself (backpressure, not loss). */
        a->inline_adds++;
        pthread_mutex_unlock(&a->mu);
        pt_film_add_tile(film, tile, px);
        pt_free(px);
        return;
    }
    a->ring[(a->head + a->len) % SRV_ADDER_QUEUE_MAX] = (add_item){film, tile, px, g};
    a->len++;
    g->pending++;
    int wake = a->idle > 0;
    pthread_mutex_unlock(&a->mu);
    /* Signalled after the unlock: a thread woken under the lock would block
     * on it at once, and the unlock would then have to wake it again (two
     * system calls per add where one does). It finds the item either way:
     * it checks the ring under the lock before it waits. */
    if (wake)
        pthread_cond_signal(&a->work);
}

void srv_adder_settle(srv_adder *a, const srv_adds *g)
{
    pthread_mutex_lock(&a->mu);
    while (g->pending) {
        a->waiters++;
        pthread_cond_wait(&a->done, &a->mu);
        a->waiters--;
    }
    pthread_mutex_unlock(&a->mu);
}

void srv_adder_counts(srv_adder *a, uint64_t *threaded, uint64_t *inline_adds)
{
    pthread_mutex_lock(&a->mu);
    *threaded = a->threaded;
    *inline_adds = a->inline_adds;
    pthread_mutex_unlock(&a->mu);
}
