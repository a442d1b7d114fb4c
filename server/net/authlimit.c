#include "server/net/authlimit.h"

#include <stdio.h>
#include <string.h>

#include "server/log.h"

void srv_authlimit_addr(const char *peer, char out[SRV_AUTHLIMIT_ADDR])
{
    const char *colon = strrchr(peer, ':');
    size_t n = colon ? (size_t)(colon - peer) : strlen(peer);
    if (n >= SRV_AUTHLIMIT_ADDR)
        n = SRV_AUTHLIMIT_ADDR - 1;
    memcpy(out, peer, n);
    out[n] = '\0';
}

/* An entry that has served its time: no block, no failure for FORGET_MS. */
static int stale(const srv_authlimit_entry *e, uint64_t now)
{
    uint64_t since = e->blocked_until > e->last ? e->blocked_until : e->last;
    return now >= since && now - since >= SRV_AUTHLIMIT_FORGET_MS;
}

static srv_authlimit_entry *find(srv_authlimit *l, const char *addr, uint64_t now)
{
    for (int i = 0; i < SRV_AUTHLIMIT_ENTRIES; i++) {
        srv_authlimit_entry *e = &l->e[i];
        if (e->addr[0] && strcmp(e->addr, addr) == 0) {
            if (stale(e, now)) {
                memset(e, 0, sizeof *e);
                return NULL;
            }
            return e;
        }
    }
    return NULL;
}

/* A slot for a new address: a free or stale one, else the one idle longest. */
static srv_authlimit_entry *take(srv_authlimit *l, const char *addr, uint64_t now)
{
    srv_authlimit_entry *best = &l->e[0];
    for (int i = 0; i < SRV_AUTHLIMIT_ENTRIES; i++) {
        srv_authlimit_entry *e = &l->e[i];
        if (!e->addr[0] || stale(e, now)) {
            best = e;
            break;
        }
        uint64_t a = e->blocked_until > e->last ? e->blocked_until : e->last;
        uint64_t b = best->blocked_until > best->last ? best->blocked_until : best->last;
        if (a < b)
            best = e;
    }
    memset(best, 0, sizeof *best);
    snprintf(best->addr, sizeof best->addr, "%s", addr);
    return best;
}

/* 1 when one more line fits this window; the first line of a new window
 * says how many the last one dropped. */
static int may_log(srv_authlimit *l, uint64_t now)
{
    if (now - l->log_window >= SRV_AUTHLIMIT_LOG_MS) {
        if (l->log_dropped)
            srv_log("%u lines about failed authentications were not logged", l->log_dropped);
        l->log_window = now;
        l->log_lines = 0;
        l->log_dropped = 0;
    }
    if (l->log_lines >= SRV_AUTHLIMIT_LOG_LINES) {
        l->log_dropped++;
        return 0;
    }
    l->log_lines++;
    return 1;
}

uint64_t srv_authlimit_blocked(srv_authlimit *l, const char *addr, uint64_t now)
{
    srv_authlimit_entry *e = find(l, addr, now);
    if (!e || now >= e->blocked_until)
        return 0;
    e->refused++;
    return e->blocked_until - now;
}

uint64_t srv_authlimit_failed(srv_authlimit *l, const char *addr, const char *who, uint64_t now)
{
    srv_authlimit_entry *e = find(l, addr, now);
    if (!e)
        e = take(l, addr, now);
    e->fails++;
    e->last = now;
    if (e->fails < SRV_AUTHLIMIT_FREE) {
        if (may_log(l, now))
            srv_log("peer %s%s%s: authentication failed (wrong token), %u in a row", addr,
                    who[0] ? " " : "", who, e->fails);
        return 0;
    }
    uint32_t k = e->fails - SRV_AUTHLIMIT_FREE;
    uint64_t ms = k >= 16 ? SRV_AUTHLIMIT_MAX_MS : 1000ull << k;
    if (ms > SRV_AUTHLIMIT_MAX_MS)
        ms = SRV_AUTHLIMIT_MAX_MS;
    e->blocked_until = now + ms;
    if (may_log(l, now)) {
        srv_log("peer %s%s%s: %u failed authentications in a row; refusing %s for %.0f s "
                "(%u handshakes refused since the last such line)",
                addr, who[0] ? " " : "", who, e->fails, addr, (double)ms / 1000.0, e->refused);
        e->refused = 0;
    }
    return ms;
}
