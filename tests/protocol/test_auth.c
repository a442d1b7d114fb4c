/*
 * test_auth.c - HMAC-SHA256 challenge-response and token files (protocol/auth.c).
 *
 * - The primitive against RFC 4231 test cases 1, 2 and 6 (the last with a key
 *   longer than SHA-256's block).
 * - The response is the primitive over "ptfarm-auth-v1" || nonce.
 * - verify accepts the right MAC and refuses a one-bit change at every bit, a
 *   wrong token and another nonce.
 * - Nonces are fresh.
 * - Token files: trailing white space stripped; empty, short (under 16 bytes)
 *   and over-long refused, at the limits; any permission for group or others
 *   refused with the mode and the chmod; not-a-file and missing refused.
 * - The server's WELCOME proof: its formula, apart from the peer's response,
 *   bound to both nonces and the token.
 */
#include <fcntl.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "protocol/auth.h"
#include "tests/check.h"

static void hex(const char *s, uint8_t *out)
{
    for (size_t i = 0; s[2 * i]; i++) {
        unsigned v;
        sscanf(s + 2 * i, "%2x", &v);
        out[i] = (uint8_t)v;
    }
}

static void test_rfc4231(void)
{
    uint8_t mac[32], want[32];
    pt_error err = {0};

    uint8_t key1[20];
    memset(key1, 0x0b, sizeof key1);
    CHECK(proto_auth_hmac_sha256(key1, 20, (const uint8_t *)"Hi There", 8, mac, &err) == PT_OK);
    hex("b0344c61d8db38535ca8afceaf0bf12b881dc200c9833da726e9376c2e32cff7", want);
    CHECK(memcmp(mac, want, 32) == 0);

    const char *data2 = "what do ya want for nothing?";
    CHECK(proto_auth_hmac_sha256((const uint8_t *)"Jefe", 4, (const uint8_t *)data2, strlen(data2),
                                 mac, &err) == PT_OK);
    hex("5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843", want);
    CHECK(memcmp(mac, want, 32) == 0);

    uint8_t key6[131];
    memset(key6, 0xaa, sizeof key6);
    const char *data6 = "Test Using Larger Than Block-Size Key - Hash Key First";
    CHECK(proto_auth_hmac_sha256(key6, sizeof key6, (const uint8_t *)data6, strlen(data6), mac,
                                 &err) == PT_OK);
    hex("60e431591ee0b67f0d8a26aacbf5b77f8e0bc6213728c5140546040f0ee37f54", want);
    CHECK(memcmp(mac, want, 32) == 0);

    static uint8_t big[PROTO_TOKEN_MAX + 1];
    CHECK(proto_auth_hmac_sha256(big, sizeof big, big, 1, mac, &err) == PT_ERR_ARG);
}

static void test_response(void)
{
    const uint8_t *token = (const uint8_t *)"correct horse battery staple";
    size_t tlen = strlen((const char *)token);
    uint8_t nonce[32], mac[32], ref[32], msg[14 + 32];
    pt_error err = {0};
    for (int i = 0; i < 32; i++)
        nonce[i] = (uint8_t)(i * 7 + 1);
    CHECK(proto_auth_response(token, tlen, nonce, mac, &err) == PT_OK);
    memcpy(msg, "ptfarm-auth-v1", 14);
    memcpy(msg + 14, nonce, 32);
    CHECK(proto_auth_hmac_sha256(token, tlen, msg, sizeof msg, ref, &err) == PT_OK);
    CHECK(memcmp(mac, ref, 32) == 0);

    CHECK(proto_auth_verify(token, tlen, nonce, mac, &err) == PT_OK);
    int refused = 0;
    for (int bit = 0; bit < 256; bit++) {
        mac[bit / 8] ^= (uint8_t)(1u << (bit % 8));
        refused += proto_auth_verify(token, tlen, nonce, mac, &err) == PT_ERR_AUTH;
        mac[bit / 8] ^= (uint8_t)(1u << (bit % 8));
    }
    CHECK(refused == 256);
    CHECK(proto_auth_verify(token, tlen - 1, nonce, mac, &err) == PT_ERR_AUTH);
    CHECK(strstr(err.msg, "wrong response") != NULL);
    nonce[31] ^= 1;
    CHECK(proto_auth_verify(token, tlen, nonce, mac, &err) == PT_ERR_AUTH);
    nonce[31] ^= 1;
    CHECK(proto_auth_verify(token, tlen, nonce, mac, &err) == PT_OK);

    /* Tokens over PROTO_TOKEN_MAX: refused, output untouched. The empty token
     * (no --token-file, loopback only) still gives a MAC that differs from a
     * real token's. */
    uint8_t out[32];
    memset(out, 0xEE, 32);
    CHECK(proto_auth_response(token, 0, nonce, out, &err) == PT_OK);
    CHECK(memcmp(out, mac, 32) != 0);
    memset(out, 0xEE, 32);
    static uint8_t big[PROTO_TOKEN_MAX + 1];
    CHECK(proto_auth_response(big, sizeof big, nonce, out, &err) == PT_ERR_ARG);
    CHECK(out[0] == 0xEE && out[31] == 0xEE);
    CHECK(proto_auth_verify(token, 0, nonce, mac, &err) == PT_ERR_AUTH);
    CHECK(proto_auth_response(big, PROTO_TOKEN_MAX, nonce, out, &err) == PT_OK);

    uint8_t n1[32], n2[32];
    CHECK(proto_auth_nonce(n1, &err) == PT_OK && proto_auth_nonce(n2, &err) == PT_OK);
    CHECK(memcmp(n1, n2, 32) != 0);
}

static char dir[512];

static const char *write_file(const char *name, const void *data, size_t n, mode_t mode)
{
    static char path[600];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    unlink(path);
    int fd = open(path, O_WRONLY | O_CREAT | O_TRUNC, 0600);
    if (fd < 0)
        return path;
    if (n && write(fd, data, n) != (ssize_t)n)
        fprintf(stderr, "short write to %s\n", path);
    fchmod(fd, mode);
    close(fd);
    return path;
}

static void test_token_file(void)
{
    const char *tmp = getenv("TMPDIR");
    snprintf(dir, sizeof dir, "%s/ptproto-auth-XXXXXX", tmp && *tmp ? tmp : "/tmp");
    if (!mkdtemp(dir)) {
        CHECKF(0, "mkdtemp %s", dir);
        return;
    }
    static uint8_t buf[PROTO_TOKEN_MAX + 16], content[PROTO_TOKEN_MAX + 8192];
    size_t len = 0;
    pt_error err = {0};
    const char *p;

    p = write_file("t1", "Xq7-pLm2#vRt9+Wz \t\r\n\n", 21, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &err) == PT_OK);
    CHECK(len == 16 && memcmp(buf, "Xq7-pLm2#vRt9+Wz", 16) == 0);
    /* Leading and inner white space is part of the token. */
    p = write_file("t2", " aB cD eF gH iJ kL mN oP\n", 25, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &err) == PT_OK);
    CHECK(len == 24 && memcmp(buf, " aB cD eF gH iJ kL mN oP", 24) == 0);

    /* Group or others may read, write or even execute it: refused with the
     * mode and the chmod that fixes it; outputs untouched. 0400 is fine. */
    static const mode_t loose[] = {0640, 0604, 0620, 0602, 0610, 0601, 0644, 0666};
    for (size_t i = 0; i < sizeof loose / sizeof loose[0]; i++) {
        p = write_file("t3", "0123456789abcdefgh\n", 19, loose[i]);
        len = 77;
        CHECK(proto_token_load(p, buf, sizeof buf, &len, &err) == PT_ERR_AUTH && len == 77);
        char mode[16];
        snprintf(mode, sizeof mode, "%04o", (unsigned)loose[i]);
        CHECKF(strstr(err.msg, mode) && strstr(err.msg, "chmod 600") && strstr(err.msg, "t3"), "%s",
               err.msg);
    }
    p = write_file("t3", "0123456789abcdefgh\n", 19, 0400);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &err) == PT_OK && len == 18);

    /* Empty, white space only and short: refused, with how to make a good one. */
    len = 77;
    p = write_file("e1", "", 0, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &err) == PT_ERR_FORMAT);
    p = write_file("e2", " \n\r\n\t", 5, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &err) == PT_ERR_FORMAT);
    CHECK(strstr(err.msg, "too short") != NULL && strstr(err.msg, "e2") != NULL);
    p = write_file("e3", "x\n", 2, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &err) == PT_ERR_FORMAT);
    CHECKF(strstr(err.msg, "1 bytes") && strstr(err.msg, "head -c 32 /dev/urandom | base64"), "%s",
           err.msg);
    /* One under the minimum, and the minimum. */
    p = write_file("e4", "0123456789abcde\n", 16, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &err) == PT_ERR_FORMAT);
    CHECK(len == 77);
    p = write_file("e4", "0123456789abcdef\n", 17, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &err) == PT_OK && len == PROTO_TOKEN_MIN);
    static const uint8_t sixteen[] = "0123456789abcdef";
    CHECK(proto_token_check(sixteen, PROTO_TOKEN_MIN - 1, "x", &err) == PT_ERR_FORMAT);
    CHECK(proto_token_check(sixteen, PROTO_TOKEN_MAX + 1, "x", &err) == PT_ERR_LIMIT);

    /* Too uniform to be secret: one byte repeated, a short pattern repeated,
     * a word doubled; each refused with how to make a good one, while
     * sixteen distinct bytes (64 bits) and a real token pass. */
    static const char *const weak[] = {"aaaaaaaaaaaaaaaa", "abcdabcdabcdabcd", "passwordpassword",
                                       "0000000000000000000000000000000000000000000001",
                                       "abababababababababababababababab"};
    for (size_t i = 0; i < sizeof weak / sizeof weak[0]; i++) {
        err.msg[0] = '\0';
        CHECKF(proto_token_check((const uint8_t *)weak[i], strlen(weak[i]), "w", &err) ==
                       PT_ERR_FORMAT &&
                   strstr(err.msg, "too uniform") && strstr(err.msg, PROTO_TOKEN_HOWTO),
               "%s: %s", weak[i], err.msg);
    }
    p = write_file("e5", "kkkkkkkkkkkkkkkkkkkkkkkkkkkkkkkk\n", 33, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &err) == PT_ERR_FORMAT &&
          strstr(err.msg, "too uniform") && strstr(err.msg, "e5"));
    CHECK(proto_token_check(sixteen, PROTO_TOKEN_MIN, "x", &err) == PT_OK);
    static const char good[] = "q8Vd3m0ZbW1yTtP5XkRrLc7JfHs2Ne9GaUo4Ei6Bl+Y=";
    CHECK(proto_token_check((const uint8_t *)good, strlen(good), "x", &err) == PT_OK);

    /* The size limit: 4096 bytes fit (with trailing new lines), 4097 do not. */
    for (size_t i = 0; i < sizeof content; i++)
        content[i] = (char)('!' + (i * 7 + i / 94) % 94);
    content[PROTO_TOKEN_MAX] = '\n';
    content[PROTO_TOKEN_MAX + 1] = '\n';
    p = write_file("l1", content, PROTO_TOKEN_MAX + 2, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &err) == PT_OK);
    CHECK(len == PROTO_TOKEN_MAX);
    /* ...but not into a smaller buffer. */
    len = 77;
    CHECK(proto_token_load(p, buf, 100, &len, &err) == PT_ERR_LIMIT && len == 77);
    for (size_t i = 0; i < sizeof content; i++)
        content[i] = (char)('!' + (i * 7 + i / 94) % 94);
    p = write_file("l2", content, PROTO_TOKEN_MAX + 1, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &err) == PT_ERR_LIMIT);
    p = write_file("l3", content, sizeof content, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &err) == PT_ERR_LIMIT);

    /* Not a regular file, and no file. */
    CHECK(proto_token_load(dir, buf, sizeof buf, &len, &err) == PT_ERR_IO);
    char missing[600];
    snprintf(missing, sizeof missing, "%s/none", dir);
    CHECK(proto_token_load(missing, buf, sizeof buf, &len, &err) == PT_ERR_IO);
    CHECK(err.sys_errno != 0 && strstr(err.msg, "none") != NULL);

    /* proto_secret_read: the whole file, NUL-terminated; the same mode rule. */
    uint8_t *data = NULL;
    size_t n = 0;
    p = write_file("s1", "alice 0123456789abcdef\n", 23, 0600);
    CHECK(proto_secret_read(p, "clients file", 100, &data, &n, &err) == PT_OK);
    CHECK(n == 23 && data && data[23] == '\0' && memcmp(data, "alice", 5) == 0);
    proto_secret_free(data, n + 1);
    CHECK(proto_secret_read(p, "clients file", 22, &data, &n, &err) == PT_ERR_LIMIT);
    p = write_file("s1", "alice 0123456789abcdef\n", 23, 0660);
    CHECK(proto_secret_read(p, "clients file", 100, &data, &n, &err) == PT_ERR_AUTH);
    CHECK(strstr(err.msg, "clients file") && strstr(err.msg, "0660"));

    /* The loaded token authenticates like the bytes it holds. */
    p = write_file("t4", "farm-token-farm-token\n", 22, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &err) == PT_OK);
    uint8_t nonce[32] = {1}, a[32], b[32];
    CHECK(proto_auth_response(buf, len, nonce, a, &err) == PT_OK);
    CHECK(proto_auth_response((const uint8_t *)"farm-token-farm-token", 21, nonce, b, &err) ==
          PT_OK);
    CHECK(memcmp(a, b, 32) == 0);

    static const char *names[] = {"t1", "t2", "t3", "t4", "e1", "e2",
                                  "e3", "e4", "l1", "l2", "l3", "s1"};
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++) {
        char path[600];
        snprintf(path, sizeof path, "%s/%s", dir, names[i]);
        unlink(path);
    }
    rmdir(dir);
}

/* The server's proof in WELCOME: HMAC(token, "ptfarm-welcome-v2" || Ns || Np),
 * apart from the peer's response (another label), checked in both nonces. */
static void test_server_proof(void)
{
    const uint8_t *token = (const uint8_t *)"0123456789abcdef-farm";
    size_t tlen = 21;
    uint8_t ns[32], np[32], proof[32], want[32], resp[32];
    for (int i = 0; i < 32; i++) {
        ns[i] = (uint8_t)i;
        np[i] = (uint8_t)(0x80 + i);
    }
    pt_error err = {0};
    CHECK(proto_auth_server_proof(token, tlen, ns, np, proof, &err) == PT_OK);
    uint8_t msg[17 + 64];
    memcpy(msg, "ptfarm-welcome-v2", 17);
    memcpy(msg + 17, ns, 32);
    memcpy(msg + 49, np, 32);
    CHECK(proto_auth_hmac_sha256(token, tlen, msg, sizeof msg, want, &err) == PT_OK);
    CHECK(memcmp(proof, want, 32) == 0);
    CHECK(proto_auth_check_server(token, tlen, ns, np, proof, &err) == PT_OK);
    /* Not the peer's response to the same nonce: no reflection. */
    CHECK(proto_auth_response(token, tlen, ns, resp, &err) == PT_OK);
    CHECK(memcmp(resp, proof, 32) != 0);
    CHECK(proto_auth_check_server(token, tlen, ns, np, resp, &err) == PT_ERR_AUTH);
    /* Another token, swapped nonces, one bit anywhere: refused. */
    CHECK(proto_auth_check_server((const uint8_t *)"0123456789abcdef-farX", tlen, ns, np, proof,
                                  &err) == PT_ERR_AUTH);
    CHECK(proto_auth_check_server(token, tlen, np, ns, proof, &err) == PT_ERR_AUTH);
    for (int bit = 0; bit < 256; bit++) {
        uint8_t bad[32];
        memcpy(bad, proof, 32);
        bad[bit / 8] ^= (uint8_t)(1u << (bit % 8));
        CHECK(proto_auth_check_server(token, tlen, ns, np, bad, &err) == PT_ERR_AUTH);
    }
    uint8_t np2[32];
    memcpy(np2, np, 32);
    np2[31] ^= 1;
    CHECK(proto_auth_check_server(token, tlen, ns, np2, proof, &err) == PT_ERR_AUTH);
}

int main(void)
{
    test_rfc4231();
    test_response();
    test_token_file();
    test_server_proof();
    return check_report();
}
