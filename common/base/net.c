#include "common/base/net.h"

#include <errno.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

pt_status pt_net_split(const char *hostport, char *host, size_t host_cap, uint16_t *port,
                       pt_error *err)
{
    const char *colon, *h = hostport;
    size_t hl;
    if (hostport[0] == '[') {
        const char *close_br = strchr(hostport, ']');
        if (!close_br || close_br[1] != ':')
            return pt_error_set(err, PT_ERR_ARG, "'%s' is not [ADDRESS]:PORT", hostport);
        h = hostport + 1;
        hl = (size_t)(close_br - h);
        colon = close_br + 1;
    } else {
        colon = strrchr(hostport, ':');
        if (!colon)
            return pt_error_set(err, PT_ERR_ARG, "'%s' is not HOST:PORT", hostport);
        hl = (size_t)(colon - hostport);
    }
    if (hl >= host_cap)
        return pt_error_set(err, PT_ERR_ARG, "'%s': host name too long", hostport);
    char *end;
    errno = 0;
    long p = strtol(colon + 1, &end, 10);
    if (errno || end == colon + 1 || *end || p < 0 || p > 65535)
        return pt_error_set(err, PT_ERR_ARG, "'%s': port must be 0..65535", hostport);
    memcpy(host, h, hl);
    host[hl] = '\0';
    *port = (uint16_t)p;
    return PT_OK;
}

static pt_status resolve(const char *host, uint16_t port, int passive, struct addrinfo **res,
                         pt_error *err)
{
    struct addrinfo hints;
    memset(&hints, 0, sizeof hints);
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    hints.ai_flags = passive ? AI_PASSIVE : 0;
    char ps[8];
    snprintf(ps, sizeof ps, "%u", port);
    int rc = getaddrinfo(host && *host ? host : NULL, ps, &hints, res);
    if (rc != 0)
        return pt_error_set(err, PT_ERR_IO, "cannot resolve '%s': %s", host, gai_strerror(rc));
    return PT_OK;
}

pt_status pt_net_set_nonblock(int fd, pt_error *err)
{
    int fl = fcntl(fd, F_GETFL);
    if (fl < 0 || fcntl(fd, F_SETFL, fl | O_NONBLOCK) < 0)
        return pt_error_errno(err, PT_ERR_IO, "fcntl O_NONBLOCK");
    return PT_OK;
}

pt_status pt_net_listen(const char *host, uint16_t port, int *fd_out, uint16_t *bound_port,
                        pt_error *err)
{
    struct addrinfo *res = NULL;
    pt_status st = resolve(host, port, 1, &res, err);
    if (st != PT_OK)
        return st;
    int fd = -1;
    for (struct addrinfo *a = res; a; a = a->ai_next) {
        fd = socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC, a->ai_protocol);
        if (fd < 0)
            continue;
        int one = 1;
        setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
        if (bind(fd, a->ai_addr, a->ai_addrlen) == 0 && listen(fd, 128) == 0)
            break;
        pt_error_errno(err, PT_ERR_IO, "cannot listen on %s:%u", host && *host ? host : "*", port);
        close(fd);
        fd = -1;
    }
    freeaddrinfo(res);
    if (fd < 0)
        return err && err->code != PT_OK
                   ? err->code
                   : pt_error_set(err, PT_ERR_IO, "cannot listen on port %u", port);
    if ((st = pt_net_set_nonblock(fd, err)) != PT_OK) {
        close(fd);
        return st;
    }
    struct sockaddr_storage ss;
    socklen_t sl = sizeof ss;
    uint16_t bp = port;
    if (getsockname(fd, (struct sockaddr *)&ss, &sl) == 0) {
        if (ss.ss_family == AF_INET)
            bp = ntohs(((struct sockaddr_in *)&ss)->sin_port);
        else if (ss.ss_family == AF_INET6)
            bp = ntohs(((struct sockaddr_in6 *)&ss)->sin6_port);
    }
    *fd_out = fd;
    if (bound_port)
        *bound_port = bp;
    return PT_OK;
}

pt_status pt_net_connect(const char *host, uint16_t port, int timeout_ms, int *fd_out,
                         pt_error *err)
{
    struct addrinfo *res = NULL;
    pt_status st = resolve(host, port, 0, &res, err);
    if (st != PT_OK)
        return st;
    int fd = -1;
    st = PT_ERR_IO;
    for (struct addrinfo *a = res; a; a = a->ai_next) {
        fd = socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC | SOCK_NONBLOCK, a->ai_protocol);
        if (fd < 0)
            continue;
        int rc = connect(fd, a->ai_addr, a->ai_addrlen);
        if (rc != 0 && errno == EINPROGRESS) {
            struct pollfd p = {fd, POLLOUT, 0};
            rc = poll(&p, 1, timeout_ms);
            if (rc == 1) {
                int soerr = 0;
                socklen_t l = sizeof soerr;
                getsockopt(fd, SOL_SOCKET, SO_ERROR, &soerr, &l);
                errno = soerr;
                rc = soerr ? -1 : 0;
            } else {
                errno = rc == 0 ? ETIMEDOUT : errno;
                rc = -1;
            }
        }
        if (rc == 0) {
            int fl = fcntl(fd, F_GETFL);
            fcntl(fd, F_SETFL, fl & ~O_NONBLOCK);
            int one = 1;
            setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
            st = PT_OK;
            break;
        }
        pt_error_errno(err, PT_ERR_IO, "cannot connect to %s:%u", host, port);
        close(fd);
        fd = -1;
    }
    freeaddrinfo(res);
    if (st != PT_OK)
        return err && err->code != PT_OK
                   ? err->code
                   : pt_error_set(err, PT_ERR_IO, "cannot connect to %s:%u", host, port);
    *fd_out = fd;
    return PT_OK;
}

int pt_net_host_is_loopback(const char *host)
{
    if (!host || !*host)
        return 0;
    struct addrinfo *res = NULL;
    if (resolve(host, 0, 0, &res, NULL) != PT_OK)
        return 0;
    int all = 1;
    for (struct addrinfo *a = res; a; a = a->ai_next) {
        if (a->ai_family == AF_INET) {
            uint32_t ip = ntohl(((struct sockaddr_in *)a->ai_addr)->sin_addr.s_addr);
            all = all && (ip >> 24) == 127;
        } else if (a->ai_family == AF_INET6) {
            const struct in6_addr *ip = &((struct sockaddr_in6 *)a->ai_addr)->sin6_addr;
            all = all && IN6_IS_ADDR_LOOPBACK(ip);
        } else {
            all = 0;
        }
    }
    freeaddrinfo(res);
    return all;
}

pt_status pt_net_write_all(int fd, const void *buf, size_t n, pt_error *err)
{
    const uint8_t *p = buf;
    while (n > 0) {
        ssize_t w = send(fd, p, n, MSG_NOSIGNAL);
        if (w < 0 && errno == EINTR)
            continue;
        if (w <= 0)
            return pt_error_errno(err, PT_ERR_IO, "send");
        p += w;
        n -= (size_t)w;
    }
    return PT_OK;
}
