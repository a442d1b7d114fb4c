/*
 * test_authlimit.c - the per-address backoff of failed authentications
 * (server/net/authlimit.c), on made-up times: no clock, no sockets.
 *
 * - The 5th failure in a row blocks for 1 s; each failure after a block has
 *   run out doubles it, up to 60 s; refusals while blocked extend nothing.
 * - Addresses are apart; the port is not part of the address (IPv4, IPv6).
 * - An address quiet for a minute after its last block is forgotten.
 * - A full table gives the slot of the entry idle longest to a new address,
 *   and a blocked address survives a flood of new ones for a while.
 */
#include <stdio.h>
#include <string.h>

#include "server/net/authlimit.h"
#include "tests/check.h"

static srv_authlimit lim;

static void test_schedule(void)
{
    memset(&lim, 0, sizeof lim);
    uint64_t t = 1000000;
    for (int i = 1; i < SRV_AUTHLIMIT_FREE; i++) {
        CHECK(srv_authlimit_blocked(&lim, "10.0.0.1", t) == 0);
        CHECK(srv_authlimit_failed(&lim, "10.0.0.1", "x", t) == 0);
        t += 10;
    }
    CHECK(srv_authlimit_failed(&lim, "10.0.0.1", "x", t) == 1000);
    CHECK(srv_authlimit_blocked(&lim, "10.0.0.1", t) == 1000);
    CHECK(srv_authlimit_blocked(&lim, "10.0.0.1", t + 999) == 1);
    /* Refusals do not extend the block. */
    for (int i = 0; i < 100; i++)
        CHECK(srv_authlimit_blocked(&lim, "10.0.0.1", t + 500) == 500);
    CHECK(srv_authlimit_blocked(&lim, "10.0.0.1", t + 1000) == 0);
    /* Another address is not touched. */
    CHECK(srv_authlimit_blocked(&lim, "10.0.0.2", t) == 0);
    /* Each failure after a block doubles the next, to the cap. */
    uint64_t want = 2000;
    t += 1000;
    for (int i = 0; i < 12; i++) {
        uint64_t got = srv_authlimit_failed(&lim, "10.0.0.1", "x", t);
        CHECKF(got == want, "block %d: %llu ms, want %llu", i, (unsigned long long)got,
               (unsigned long long)want);
        t += got;
        want = want * 2 > SRV_AUTHLIMIT_MAX_MS ? SRV_AUTHLIMIT_MAX_MS : want * 2;
    }
    /* Quiet for a minute after the last block ends: forgotten, 4 free tries again. */
    t += SRV_AUTHLIMIT_FORGET_MS;
    CHECK(srv_authlimit_blocked(&lim, "10.0.0.1", t) == 0);
    CHECK(srv_authlimit_failed(&lim, "10.0.0.1", "x", t) == 0);
}

static void test_addr(void)
{
    char a[SRV_AUTHLIMIT_ADDR];
    srv_authlimit_addr("127.0.0.1:4242", a);
    CHECK(strcmp(a, "127.0.0.1") == 0);
    srv_authlimit_addr("::1:4242", a);
    CHECK(strcmp(a, "::1") == 0);
    srv_authlimit_addr("fe80::1:2:3", a);
    CHECK(strcmp(a, "fe80::1:2") == 0);
    srv_authlimit_addr("noport", a);
    CHECK(strcmp(a, "noport") == 0);
}

static void test_full_table(void)
{
    memset(&lim, 0, sizeof lim);
    uint64_t t = 5000000;
    /* A guesser gets blocked... */
    for (int i = 0; i < SRV_AUTHLIMIT_FREE; i++)
        srv_authlimit_failed(&lim, "192.0.2.1", "g", t);
    CHECK(srv_authlimit_blocked(&lim, "192.0.2.1", t) == 1000);
    /* ...then fails once more later for a long block. */
    t += 1000;
    CHECK(srv_authlimit_failed(&lim, "192.0.2.1", "g", t) == 2000);
    /* Fewer new addresses than slots: the block holds. */
    char addr[SRV_AUTHLIMIT_ADDR];
    for (int i = 0; i < SRV_AUTHLIMIT_ENTRIES - 1; i++) {
        snprintf(addr, sizeof addr, "198.51.100.%d", i);
        srv_authlimit_failed(&lim, addr, "f", t + 1);
    }
    CHECK(srv_authlimit_blocked(&lim, "192.0.2.1", t + 10) > 0);
    /* One more address takes a slot: the one idle longest goes (the
     * blocked guesser's runs to t + 2000, later than the others' t + 1). */
    srv_authlimit_failed(&lim, "203.0.113.9", "n", t + 20);
    CHECK(srv_authlimit_blocked(&lim, "192.0.2.1", t + 30) > 0);
    int gone = 0;
    for (int i = 0; i < SRV_AUTHLIMIT_ENTRIES - 1; i++) {
        snprintf(addr, sizeof addr, "198.51.100.%d", i);
        int found = 0;
        for (int k = 0; k < SRV_AUTHLIMIT_ENTRIES; k++)
            found |= strcmp(lim.e[k].addr, addr) == 0;
        gone += !found;
    }
    CHECK(gone == 1);
}

int main(void)
{
    test_schedule();
    test_addr();
    test_full_table();
    return check_report();
}
