/*
 * io.h - workers' connections read off the event loop.
 *
 * With --io-threads N, a worker's connection goes to one of N I/O threads
 * once it has authenticated (srv_io_attach, with the bytes the loop had
 * buffered): the thread receives its bytes, cuts them into frames (each
 * checksum checked, each length against the worker's cap), decodes every
 * RESULT into pixels of its own, and queues the frames, in order, for the
 * loop (srv_io_take). Receiving, checksumming and decoding were most of the
 * loop's cost per result; what stays on the loop is what must be decided in
 * one place: validation, the order of each tile's merges, leases, replies.
 *
 * The loop keeps the connection: it writes to it, and decides when it
 * closes; srv_io_close then has the thread stop reading and close the
 * descriptor (so its number is not reused while the thread may read it).
 * The thread applies the loop's limits to what it reads (server/net/loop.h):
 * its input buffers count in the same total (in_held: a frame that does not
 * fit waits, the connection is not read meanwhile), and the rate rule (a
 * frame too slow for its size, or stalled mid-frame for the grace, is an
 * error item: the loop sends ERROR and closes). An end of stream or a bad
 * frame is an item too, after the frames before it. While the items waiting
 * for the loop hold SRV_IO_QUEUE_BYTES, the threads stop reading: TCP holds
 * the rest at the workers.
 *
 * Threads: the loop's thread calls every function; the I/O threads are
 * internal and touch only their connections' descriptors and readers, the
 * queue (under its lock) and in_held (atomically).
 */
#ifndef PT_SERVER_IO_H
#define PT_SERVER_IO_H

#include <stdatomic.h>
#include <stdint.h>

#include "common/base/error.h"
#include "protocol/frame.h"
#include "protocol/msg.h"
#include "server/config.h"

#define SRV_IO_MAX_THREADS 64u
#define SRV_DEFAULT_IO_THREADS 2u      /* ptserve --io-threads */
#define SRV_IO_QUEUE_BYTES (64u << 20) /* items waiting past this: the threads stop reading */

typedef struct srv_io srv_io;

enum { SRV_IO_FRAME, SRV_IO_ERROR, SRV_IO_EOF };

/* What a thread read from one connection. */
typedef struct srv_io_item {
    struct srv_io_item *next;
    uint64_t conn; /* the connection's id */
    int kind;      /* SRV_IO_* */
    /* FRAME: f's payload points into frame (the whole frame as received:
     * header, payload, checksum), except for a RESULT whose frame is not
     * kept (srv_io_new's keep_results 0): then f.payload is NULL. */
    proto_frame f;
    uint8_t *frame;
    int decoded;    /* a RESULT decoded into r, its pixels its own */
    int checked;    /* ... and passed srv_io_new's check (its pixels plausible) */
    proto_result r; /* decoded: fini'd by srv_io_item_free unless taken */
    uint16_t code;  /* ERROR: the PROTO_E_* to answer with */
    char msg[512];  /* ERROR: why (pt_error's size) */
} srv_io_item;

/* threads: 1 to SRV_IO_MAX_THREADS. in_held: the loop's count of input
 * bytes (srv_in_counted, server/net/loop.h), against lim->max_input_mem.
 * keep_results: RESULT frames are kept whole (the results log writes them).
 * check (may be NULL): run by the threads over each decoded RESULT, 1 when
 * its pixels are plausible (the worker session's, srv_session.check_result).
 * srv_io_fd is to be polled for reading: items wait. */
pt_status srv_io_new(uint32_t threads, const srv_peer_limits *lim, _Atomic uint64_t *in_held,
                     int keep_results, int (*check)(const proto_result *r), srv_io **out,
                     pt_error *err);
/* Stops the threads and closes every descriptor they still hold; frees the
 * items not taken. Accepts NULL. */
void srv_io_free(srv_io *io);
int srv_io_fd(const srv_io *io);

/* Hands connection id (descriptor fd, its frames' payload cap) to a thread;
 * in: what the loop received and did not decode yet, moved (the loop's
 * reader is left empty, as after init, and its memory is the thread's to
 * count from now on). PT_ERR_NOMEM leaves everything with the loop. */
pt_status srv_io_attach(srv_io *io, uint64_t id, int fd, proto_frame_reader *in, uint32_t cap,
                        pt_error *err);
/* The loop is done with connection id: the thread stops reading it and
 * closes fd (the loop must not). */
void srv_io_close(srv_io *io, uint64_t id, int fd);

/* Takes every item waiting, oldest first (a connection's in the order
 * read), and lets the threads read again if the queue had stopped them.
 * *bytes receives the bytes the threads have received since the last take. */
srv_io_item *srv_io_take(srv_io *io, uint64_t *bytes);
void srv_io_item_free(srv_io_item *it); /* one item; accepts NULL */

#endif
