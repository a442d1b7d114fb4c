/*
 * net.h - the few socket helpers ptserve, ptworker and ptctl share.
 *
 * TCP over IPv4 or IPv6 by getaddrinfo. Listening sockets are non-blocking and
 * close-on-exec with SO_REUSEADDR; connecting sockets get TCP_NODELAY (frames
 * are small and latency matters more than packet count). No protocol here:
 * framing and messages are in protocol/.
 *
 * Threads: any thread may call them; a socket belongs to its caller.
 */
#ifndef PT_COMMON_BASE_NET_H
#define PT_COMMON_BASE_NET_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"

/* Splits "HOST:PORT", "[V6]:PORT" or ":PORT" (host empty) into its parts.
 * PT_ERR_ARG naming the text when it is not one of those. */
pt_status pt_net_split(const char *hostport, char *host, size_t host_cap, uint16_t *port,
                       pt_error *err);

/* Listens on host:port (host "" = all addresses); *bound_port receives the
 * port actually bound (useful with port 0). */
pt_status pt_net_listen(const char *host, uint16_t port, int *fd, uint16_t *bound_port,
                        pt_error *err);

/* Connects (blocking, with a timeout in milliseconds); the socket stays blocking. */
pt_status pt_net_connect(const char *host, uint16_t port, int timeout_ms, int *fd, pt_error *err);

pt_status pt_net_set_nonblock(int fd, pt_error *err);

/* 1 when host names only loopback addresses ("localhost", 127.0.0.0/8, ::1). */
int pt_net_host_is_loopback(const char *host);

/* Writes all n bytes to a blocking socket (EINTR retried, SIGPIPE avoided). */
pt_status pt_net_write_all(int fd, const void *buf, size_t n, pt_error *err);

#endif
