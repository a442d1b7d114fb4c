/*
 * peerlimits.h - the limits on reading one peer that both readers apply:
 * the event loop (server/net/loop.h) and the I/O threads (server/net/io.h).
 *
 * Owns the input memory accounting's unit (what a buffer holds past the
 * SRV_IN_START every connection has) and the rate rule for a frame in
 * progress (srv_peer_limits, server/config.h: the grace, the minimum rate).
 * Below both readers: it knows neither connections nor threads.
 *
 * Threads: pure functions of their arguments; any thread may call them.
 */
#ifndef PT_SERVER_PEERLIMITS_H
#define PT_SERVER_PEERLIMITS_H

#include <stddef.h>
#include <stdint.h>

#include "protocol/frame.h"
#include "server/config.h"

#define SRV_IN_START (64u * 1024u) /* every connection's first input buffer */

/* Input bytes a buffer of cap bytes counts against max_input_mem: what it
 * holds past the SRV_IN_START every connection has (server/net/io.h counts its
 * threads' buffers so too). */
static inline uint64_t srv_in_counted(size_t cap)
{
    return cap > SRV_IN_START ? cap - SRV_IN_START : 0;
}

/* The time a transfer of size bytes may take: the grace, or longer at the
 * minimum rate. */
uint64_t srv_allowed_ms(const srv_peer_limits *l, uint64_t size);

/* The rate rule's first part (server/net/loop.h) for the frame in progress in
 * the reader in (begun at t_frame). 1 when it is too slow, with the reason
 * in why. */
int srv_frame_too_slow(const srv_peer_limits *l, const proto_frame_reader *in, uint64_t t_frame,
                       uint64_t now, char *why, size_t n);

#endif
