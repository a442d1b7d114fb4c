/*
 * test_io.c - workers' connections read by I/O threads (server/net/io.h), over
 * real sockets (socketpair): frames come out whole and in order per
 * connection, RESULTs decoded (the frame kept or not), what the loop had
 * buffered before the attach first; a bad frame and an end of stream are
 * items after the frames before them; a close has the thread close the
 * descriptor; the input memory is counted and given back; a full queue
 * stops the reading until the loop takes.
 */
#define _DEFAULT_SOURCE /* usleep */
#include <errno.h>
#include <fcntl.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/clock.h"
#include "server/net/io.h"
#include "server/net/loop.h"
#include "tests/check.h"
#include "tests/protocol/samples.h"

static _Atomic uint64_t in_held;

static srv_peer_limits limits(void)
{
    srv_peer_limits l = {0};
    l.max_input_mem = 64u << 20;
    l.frame_grace_ms = 30000;
    l.min_rate = 16 * 1024;
    return l;
}

/* Frame i of a connection: RESULT (sample_result, task id i) when i is odd,
 * else a HEARTBEAT. */
static void frame_of(int i, proto_writer *w)
{
    proto_writer p;
    proto_writer_init(&p, 1 << 20);
    if (i % 2) {
        proto_result r = sample_result(0);
        r.task_id = (uint64_t)i;
        CHECK(proto_msg_encode_result(&p, &r, NULL) == PT_OK);
        CHECK(proto_frame_encode(w, PROTO_MSG_RESULT, p.buf, p.len, NULL) == PT_OK);
    } else {
        sample_frame(12, 0, w); /* any whole frame of the samples */
    }
    proto_writer_fini(&p);
}

/* Takes items until n have come or 5 s pass; returns them (a list). */
static srv_io_item *take_n(srv_io *io, int n, int *got)
{
    srv_io_item *head = NULL, **tail = &head;
    *got = 0;
    double t0 = pt_now_s();
    while (*got < n && pt_now_s() - t0 < 5.0) {
        uint64_t bytes;
        srv_io_item *it = srv_io_take(io, &bytes);
        if (!it) {
            usleep(2000);
            continue;
        }
        *tail = it;
        while (*tail) {
            (*got)++;
            tail = &(*tail)->next;
        }
    }
    return head;
}

static void free_items(srv_io_item *it)
{
    while (it) {
        srv_io_item *n = it->next;
        srv_io_item_free(it);
        it = n;
    }
}

/* Two connections, each with frames buffered before the attach and sent
 * after; then a bad frame on one and an end of stream on the other. */
static void frames_in_order(int keep_results)
{
    srv_peer_limits l = limits();
    srv_io *io = NULL;
    CHECK(srv_io_new(2, &l, &in_held, keep_results, NULL, &io, NULL) == PT_OK);
    if (!io)
        return;
    int sp[2][2];
    enum { N = 40 };
    for (int c = 0; c < 2; c++) {
        CHECK(socketpair(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK, 0, sp[c]) == 0);
        /* What the loop read past the AUTH: the first three frames. */
        proto_frame_reader in;
        proto_frame_reader_init(&in, SRV_IN_START, PROTO_FRAME_OVERHEAD + PROTO_MAX_PAYLOAD);
        proto_writer w;
        proto_writer_init(&w, 1 << 22);
        for (int i = 0; i < 3; i++)
            frame_of(i, &w);
        uint8_t *p;
        size_t room;
        CHECK(proto_frame_reader_space(&in, &p, &room, NULL) == PT_OK && room >= w.len);
        memcpy(p, w.buf, w.len);
        proto_frame_reader_commit(&in, w.len);
        CHECK(srv_io_attach(io, 100 + (uint64_t)c, sp[c][0], &in, 1u << 20, NULL) == PT_OK);
        CHECK(in.buf == NULL && in.len == 0); /* moved */
        proto_writer_reset(&w);
        for (int i = 3; i < N; i++)
            frame_of(i, &w);
        CHECK(send(sp[c][1], w.buf, w.len, 0) == (ssize_t)w.len);
        proto_writer_fini(&w);
    }
    /* Connection 100 sends garbage; 101 hangs up. */
    CHECK(send(sp[0][1], "XXXXXXXXXXXXXXXX", 16, 0) == 16);
    close(sp[1][1]);
    int got;
    srv_io_item *items = take_n(io, 2 * (N + 1), &got);
    CHECKF(got == 2 * (N + 1), "%d items of %d", got, 2 * (N + 1));
    int next[2] = {0, 0}, ordered = 1, decoded = 1, ended[2] = {0, 0};
    for (srv_io_item *it = items; it; it = it->next) {
        int c = (int)(it->conn - 100);
        CHECK(c == 0 || c == 1);
        if (c < 0 || c > 1)
            continue;
        if (it->kind != SRV_IO_FRAME) {
            ended[c] = it->kind;
            CHECK(next[c] == N); /* after every frame before it */
            continue;
        }
        int i = next[c]++;
        if (i % 2) {
            decoded &= it->f.type == PROTO_MSG_RESULT && it->decoded &&
                       it->r.task_id == (uint64_t)i && it->r.owns_pixels && it->r.npixels == 12 &&
                       memcmp(it->r.pixels, sample_pixels, sizeof sample_pixels) == 0;
            /* The frame whole when kept: header, payload, checksum. */
            decoded &= keep_results ? it->frame && it->f.payload == it->frame + PROTO_FRAME_HEADER
                                    : !it->frame && !it->f.payload;
        } else {
            ordered &= it->f.type != PROTO_MSG_RESULT && it->frame != NULL;
        }
    }
    CHECK(ordered && decoded);
    CHECK(ended[0] == SRV_IO_ERROR && ended[1] == SRV_IO_EOF);
    for (srv_io_item *it = items; it; it = it->next)
        if (it->kind == SRV_IO_ERROR)
            CHECKF(strstr(it->msg, "magic") && it->code == PROTO_E_PROTOCOL, "%s", it->msg);
    free_items(items);
    /* The loop closes both: the threads close the descriptors. */
    srv_io_close(io, 100, sp[0][0]);
    srv_io_close(io, 101, sp[1][0]);
    double t0 = pt_now_s();
    while ((fcntl(sp[0][0], F_GETFD) != -1 || fcntl(sp[1][0], F_GETFD) != -1) &&
           pt_now_s() - t0 < 5.0)
        usleep(2000);
    CHECK(fcntl(sp[0][0], F_GETFD) == -1 && errno == EBADF);
    CHECK(fcntl(sp[1][0], F_GETFD) == -1);
    close(sp[0][1]);
    srv_io_free(io);
    CHECK(in_held == 0);
}

/* Nothing taken: the queue fills to SRV_IO_QUEUE_BYTES and the thread stops
 * reading, so the sender's socket fills; after a take it reads on. */
static void full_queue_stops(void)
{
    srv_peer_limits l = limits();
    srv_io *io = NULL;
    CHECK(srv_io_new(1, &l, &in_held, 1, NULL, &io, NULL) == PT_OK);
    if (!io)
        return;
    int sp[2];
    CHECK(socketpair(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK, 0, sp) == 0);
    proto_frame_reader in;
    proto_frame_reader_init(&in, SRV_IN_START, PROTO_FRAME_OVERHEAD + PROTO_MAX_PAYLOAD);
    CHECK(srv_io_attach(io, 7, sp[0], &in, 1u << 20, NULL) == PT_OK);
    /* 1 MiB frames (an unknown payload is fine here: the loop judges it). */
    size_t big = 1u << 20;
    uint8_t *payload = pt_calloc(1, big);
    proto_writer w;
    proto_writer_init(&w, 2 * big);
    CHECK(proto_frame_encode(&w, PROTO_MSG_HEARTBEAT, payload, big - 64, NULL) == PT_OK);
    size_t sent = 0, off = 0;
    double t0 = pt_now_s(), t_last = t0;
    /* Send until nothing moves for 500 ms. */
    while (pt_now_s() - t_last < 0.5 && pt_now_s() - t0 < 20.0) {
        ssize_t k = send(sp[1], w.buf + off, w.len - off, MSG_DONTWAIT);
        if (k > 0) {
            sent += (size_t)k;
            off = (off + (size_t)k) % w.len;
            t_last = pt_now_s();
        } else {
            usleep(1000);
        }
    }
    CHECKF(sent >= SRV_IO_QUEUE_BYTES && sent < SRV_IO_QUEUE_BYTES + (64u << 20),
           "%zu bytes went in before the reading stopped", sent);
    int got;
    srv_io_item *items = take_n(io, 1, &got);
    free_items(items);
    /* Taken: it reads again. */
    t0 = pt_now_s();
    ssize_t k = -1;
    while (k <= 0 && pt_now_s() - t0 < 5.0) {
        k = send(sp[1], w.buf + off, w.len - off, MSG_DONTWAIT);
        if (k <= 0)
            usleep(2000);
        else
            off = (off + (size_t)k) % w.len;
    }
    CHECKF(k > 0, "the reading did not resume after the take");
    srv_io_close(io, 7, sp[0]);
    close(sp[1]);
    srv_io_free(io);
    CHECK(in_held == 0);
    proto_writer_fini(&w);
    pt_free(payload);
}

static void bad_threads(void)
{
    srv_peer_limits l = limits();
    srv_io *io = NULL;
    pt_error err = {0};
    CHECK(srv_io_new(0, &l, &in_held, 0, NULL, &io, &err) == PT_ERR_ARG && !io);
    CHECK(srv_io_new(SRV_IO_MAX_THREADS + 1, &l, &in_held, 0, NULL, &io, &err) == PT_ERR_ARG);
    srv_io_free(NULL);
}

int main(void)
{
    int64_t live = pt_alloc_live();
    frames_in_order(1);
    frames_in_order(0);
    full_queue_stops();
    bad_threads();
    CHECK(pt_alloc_live() == live);
    return check_report();
}
