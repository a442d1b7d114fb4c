/*
 * adder.h - film adds off the event loop.
 *
 * Adding a result's tile to a job's film is the loop's largest cost per
 * result (a 32x32 tile reads and writes 72 KiB of a film too large for any
 * cache). The film's sums are exact integers and its bands are locked
 * (common/render/film.h), so adds commute and any thread may make them: the
 * loop keeps every decision (validation, the order of a tile's tasks, what
 * is merged) and hands the add itself to a few threads with srv_adder_post.
 * Each job counts its adds in flight in a srv_adds; srv_adder_settle waits
 * until they have landed, which every reader of the film's pixels on the
 * loop does first (server/sched/job.h says where). When the queue holds
 * SRV_ADDER_QUEUE_MAX adds, the add is made at once on the caller's thread
 * instead: the queue is a fixed ring, so a post never allocates or fails,
 * memory stays bounded and nothing is dropped.
 * Threads: one owner thread (the event loop's) calls every function; the
 * adding threads are internal.
 */
#ifndef PT_SERVER_ADDER_H
#define PT_SERVER_ADDER_H

#include <stdint.h>

#include "common/base/error.h"
#include "common/render/film.h"

#define SRV_ADDER_QUEUE_MAX 256u /* adds waiting, past which the caller adds itself */
#define SRV_ADDER_MAX_THREADS 64u
#define SRV_DEFAULT_MERGE_THREADS 2u /* ptserve --merge-threads */

typedef struct srv_adder srv_adder;

/* A job's adds in flight (owner's storage, zeroed; the adder counts them
 * under its lock). */
typedef struct srv_adds {
    uint64_t pending;
} srv_adds;

/* threads: 1 to SRV_ADDER_MAX_THREADS. */
pt_status srv_adder_new(uint32_t threads, srv_adder **out, pt_error *err);
/* Waits for every add, then stops the threads; accepts NULL. */
void srv_adder_free(srv_adder *a);

/* Adds px (a tile's sums, row-major over tile, allocated with pt_malloc;
 * taken: freed once added) to film, counted in g. */
void srv_adder_post(srv_adder *a, srv_adds *g, pt_film *film, pt_rect tile, pt_pixel_acc *px);
/* Returns once every add counted in g has landed in its film. */
void srv_adder_settle(srv_adder *a, const srv_adds *g);

/* Adds made on the threads and at once by the caller, so far. */
void srv_adder_counts(srv_adder *a, uint64_t *threaded, uint64_t *inline_adds);

#endif
