/*
 * authlimit.h - failed authentications per address, and the backoff that
 * slows a token guesser down.
 *
 * Each address (the peer's IP, without the port) that fails the challenge
 * gets an entry. The first SRV_AUTHLIMIT_FREE - 1 failures cost nothing
 * more; the next one blocks the address for 1 s, and each failure after a
 * block has run out blocks it twice as long, up to SRV_AUTHLIMIT_MAX_MS. While an address is
 * blocked its handshakes are refused at HELLO (and an AUTH already under way at AUTH) without
 * computing a MAC, with "retry in N s"; those refusals neither extend the block nor count as
 * failures. An address with no failure and no block for SRV_AUTHLIMIT_FORGET_MS is forgotten. A
 * right token does not clear an address's failures (a peer sharing a NAT address with a guesser
 * would otherwise hand it fresh tries). The table is fixed
 * (SRV_AUTHLIMIT_ENTRIES); when full, the entry idle longest gives way.
 *
 * Nothing here sleeps: a blocked address is answered at once, so the event
 * loop never waits on it. Logging is bounded: a failure is logged while its
 * address has had fewer than SRV_AUTHLIMIT_FREE, then one line per block
 * (with the refusals since the last line); at most SRV_AUTHLIMIT_LOG_LINES
 * lines per SRV_AUTHLIMIT_LOG_MS over all addresses, the lines dropped
 * counted in the next one.
 *
 * A zeroed srv_authlimit is empty and ready; it owns no memory.
 * Threads: the event-loop thread only. Times in ms (pt_now_ms).
 */
#ifndef PT_SERVER_AUTHLIMIT_H
#define PT_SERVER_AUTHLIMIT_H

#include <stdint.h>

#define SRV_AUTHLIMIT_ENTRIES 256
#define SRV_AUTHLIMIT_FREE 5 /* the 5th failure in a row starts the first block */
#define SRV_AUTHLIMIT_MAX_MS 60000u
#define SRV_AUTHLIMIT_FORGET_MS 60000u
#define SRV_AUTHLIMIT_LOG_LINES 20u
#define SRV_AUTHLIMIT_LOG_MS 10000u
#define SRV_AUTHLIMIT_ADDR 64 /* an IPv6 address in text, NUL included */

typedef struct srv_authlimit_entry {
    char addr[SRV_AUTHLIMIT_ADDR]; /* "" when the slot is free */
    uint32_t fails;                /* failures since the address was last forgotten */
    uint32_t refused;              /* handshakes refused while blocked, not yet logged */
    uint64_t last, blocked_until;  /* last failure; end of the current block */
} srv_authlimit_entry;

typedef struct srv_authlimit {
    srv_authlimit_entry e[SRV_AUTHLIMIT_ENTRIES];
    uint64_t log_window; /* start of the current logging window */
    uint32_t log_lines, log_dropped;
} srv_authlimit;

/* The address part of a peer "HOST:PORT" (IPv6 as inet_ntop writes it,
 * without brackets) into out (SRV_AUTHLIMIT_ADDR bytes). */
void srv_authlimit_addr(const char *peer, char out[SRV_AUTHLIMIT_ADDR]);

/* Milliseconds that addr stays blocked (0: it may try now). A blocked
 * answer is counted as a refusal for the next log line. */
uint64_t srv_authlimit_blocked(srv_authlimit *l, const char *addr, uint64_t now);

/* Records a failed authentication from addr (who: the peer's name, escaped,
 * for the log) and logs it within the limits above. Returns the block it
 * starts in ms (0: none yet). */
uint64_t srv_authlimit_failed(srv_authlimit *l, const char *addr, const char *who, uint64_t now);

#endif
