/*
 * test_auth.c - HMAC-SHA256 challenge-response and token files (protocol/auth.c).
 *
 * - The primitive against RFC 4231 test cases 1, 2 and 6 (the last with a key
 *   longer than SHA-256's block).
 * - The response is the primitive over "ptfarm-auth-v1" || nonce.
 * - verify accepts the right MAC and refuses a one-bit change at every bit, a
 *   wrong token and another nonce.
 * - Nonces are fresh.
 * - Token files: trailing white space stripped, empty and over-long refused,
 *   at the limits, loose permissions flagged, not-a-file and missing refused.
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
    int loose = -1;
    pt_error err = {0};
    const char *p;

    p = write_file("t1", "s3cret \t\r\n\n", 11, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &loose, &err) == PT_OK);
    CHECK(len == 6 && memcmp(buf, "s3cret", 6) == 0 && loose == 0);
    /* Leading and inner white space is part of the token. */
    p = write_file("t2", " a b\n", 5, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, NULL, &err) == PT_OK);
    CHECK(len == 4 && memcmp(buf, " a b", 4) == 0);
    /* Loose permissions: loaded, flagged. */
    p = write_file("t3", "tok\n", 4, 0640);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &loose, &err) == PT_OK && loose == 1);
    p = write_file("t3", "tok\n", 4, 0604);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &loose, &err) == PT_OK && loose == 1);
    p = write_file("t3", "tok\n", 4, 0400);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &loose, &err) == PT_OK && loose == 0);

    /* Empty and white space only: refused, outputs untouched. */
    len = 77;
    loose = 5;
    p = write_file("e1", "", 0, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &loose, &err) == PT_ERR_FORMAT);
    p = write_file("e2", " \n\r\n\t", 5, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, &loose, &err) == PT_ERR_FORMAT);
    CHECK(strstr(err.msg, "empty") != NULL && strstr(err.msg, "e2") != NULL);
    CHECK(len == 77 && loose == 5);

    /* The size limit: 4096 bytes fit (with trailing new lines), 4097 do not. */
    memset(content, 'k', sizeof content);
    content[PROTO_TOKEN_MAX] = '\n';
    content[PROTO_TOKEN_MAX + 1] = '\n';
    p = write_file("l1", content, PROTO_TOKEN_MAX + 2, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, NULL, &err) == PT_OK);
    CHECK(len == PROTO_TOKEN_MAX);
    /* ...but not into a smaller buffer. */
    len = 77;
    CHECK(proto_token_load(p, buf, 100, &len, NULL, &err) == PT_ERR_LIMIT && len == 77);
    memset(content, 'k', sizeof content);
    p = write_file("l2", content, PROTO_TOKEN_MAX + 1, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, NULL, &err) == PT_ERR_LIMIT);
    p = write_file("l3", content, sizeof content, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, NULL, &err) == PT_ERR_LIMIT);

    /* Not a regular file, and no file. */
    CHECK(proto_token_load(dir, buf, sizeof buf, &len, NULL, &err) == PT_ERR_IO);
    char missing[600];
    snprintf(missing, sizeof missing, "%s/none", dir);
    CHECK(proto_token_load(missing, buf, sizeof buf, &len, NULL, &err) == PT_ERR_IO);
    CHECK(err.sys_errno != 0 && strstr(err.msg, "none") != NULL);

    /* The loaded token authenticates like the bytes it holds. */
    p = write_file("t4", "farm-token\n", 11, 0600);
    CHECK(proto_token_load(p, buf, sizeof buf, &len, NULL, &err) == PT_OK);
    uint8_t nonce[32] = {1}, a[32], b[32];
    CHECK(proto_auth_response(buf, len, nonce, a, &err) == PT_OK);
    CHECK(proto_auth_response((const uint8_t *)"farm-token", 10, nonce, b, &err) == PT_OK);
    CHECK(memcmp(a, b, 32) == 0);

    static const char *names[] = {"t1", "t2", "t3", "t4", "e1", "e2", "l1", "l2", "l3"};
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++) {
        char path[600];
        snprintf(path, sizeof path, "%s/%s", dir, names[i]);
        unlink(path);
    }
    rmdir(dir);
}

int main(void)
{
    test_rfc4231();
    test_response();
    test_token_file();
    return check_report();
}
