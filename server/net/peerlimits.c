#include "server/net/peerlimits.h"

#include <stdio.h>

/* The time a transfer of size bytes may take: the grace, or longer at the
 * minimum rate. */
uint64_t srv_allowed_ms(const srv_peer_limits *l, uint64_t size)
{
    uint64_t at_rate = size * 1000u / l->min_rate;
    return at_rate > l->frame_grace_ms ? at_rate : l->frame_grace_ms;
}

int srv_frame_too_slow(const srv_peer_limits *l, const proto_frame_reader *in, uint64_t t_frame,
                       uint64_t now, char *why, size_t n)
{
    size_t held = proto_frame_reader_pending(in);
    uint64_t size = 0;
    if (held >= PROTO_FRAME_HEADER)
        size = PROTO_FRAME_OVERHEAD + (uint64_t)proto_frame_payload_len(in->buf + in->start);
    /* Until its header is here a frame's size is unknown: the grace alone. */
    if (!(held > 0 && (size == 0 || held < size) && now - t_frame > srv_allowed_ms(l, size)))
        return 0;
    snprintf(why, n,
             "frame of %llu bytes too slow: %zu received in %.1f s (the minimum is %.1f KiB/s "
             "after %.1f s)",
             (unsigned long long)size, held, (now - t_frame) / 1000.0, l->min_rate / 1024.0,
             l->frame_grace_ms / 1000.0);
    return 1;
}
