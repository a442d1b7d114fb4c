#include "protocol/auth.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <openssl/hmac.h>
#include <openssl/rand.h>

#include "common/base/alloc.h"

pt_status proto_auth_nonce(uint8_t nonce[PROTO_NONCE_SIZE], pt_error *err)
{
    if (RAND_bytes(nonce, (int)PROTO_NONCE_SIZE) != 1)
        return pt_error_set(err, PT_ERR_IO, "auth: the random generator failed");
    return PT_OK;
}

pt_status proto_auth_hmac_sha256(const uint8_t *key, size_t key_len, const uint8_t *data,
                                 size_t data_len, uint8_t out[PROTO_MAC_SIZE], pt_error *err)
{
    if (key_len > PROTO_TOKEN_MAX)
        return pt_error_set(err, PT_ERR_ARG, "auth: key of %zu bytes over %u", key_len,
                            PROTO_TOKEN_MAX);
    uint8_t mac[EVP_MAX_MD_SIZE];
    unsigned int mac_len = 0;
    /* OpenSSL reads no key bytes when key_len is 0 but wants a non-NULL pointer. */
    static const uint8_t empty[1];
    if (!HMAC(EVP_sha256(), key_len ? key : empty, (int)key_len, data, data_len, mac, &mac_len) ||
        mac_len != PROTO_MAC_SIZE)
        return pt_error_set(err, PT_ERR_AUTH, "auth: HMAC-SHA256 failed");
    memcpy(out, mac, PROTO_MAC_SIZE);
    OPENSSL_cleanse(mac, sizeof mac);
    return PT_OK;
}

pt_status proto_auth_response(const uint8_t *token, size_t token_len,
                              const uint8_t nonce[PROTO_NONCE_SIZE], uint8_t out[PROTO_MAC_SIZE],
                              pt_error *err)
{
    if (token_len > PROTO_TOKEN_MAX || (token_len > 0 && !token))
        return pt_error_set(err, PT_ERR_ARG, "auth: token of %zu bytes (0..%u)", token_len,
                            PROTO_TOKEN_MAX);
    uint8_t msg[sizeof PROTO_AUTH_LABEL - 1 + PROTO_NONCE_SIZE];
    memcpy(msg, PROTO_AUTH_LABEL, sizeof PROTO_AUTH_LABEL - 1);
    memcpy(msg + sizeof PROTO_AUTH_LABEL - 1, nonce, PROTO_NONCE_SIZE);
    return proto_auth_hmac_sha256(token, token_len, msg, sizeof msg, out, err);
}

pt_status proto_auth_verify(const uint8_t *token, size_t token_len,
                            const uint8_t nonce[PROTO_NONCE_SIZE],
                            const uint8_t mac[PROTO_MAC_SIZE], pt_error *err)
{
    uint8_t want[PROTO_MAC_SIZE];
    pt_status st = proto_auth_response(token, token_len, nonce, want, err);
    if (st != PT_OK)
        return pt_error_set(err, PT_ERR_AUTH, "auth: cannot compute the expected response");
    /* An early-exit memcmp would tell a timing attacker how many leading bytes
     * of a forged MAC are right. */
    int diff = CRYPTO_memcmp(want, mac, PROTO_MAC_SIZE);
    OPENSSL_cleanse(want, sizeof want);
    if (diff != 0)
        return pt_error_set(err, PT_ERR_AUTH, "auth: wrong response to the challenge");
    return PT_OK;
}

pt_status proto_auth_server_proof(const uint8_t *token, size_t token_len,
                                  const uint8_t server_nonce[PROTO_NONCE_SIZE],
                                  const uint8_t peer_nonce[PROTO_NONCE_SIZE],
                                  uint8_t out[PROTO_MAC_SIZE], pt_error *err)
{
    if (token_len > PROTO_TOKEN_MAX || (token_len > 0 && !token))
        return pt_error_set(err, PT_ERR_ARG, "auth: token of %zu bytes (0..%u)", token_len,
                            PROTO_TOKEN_MAX);
    const size_t nl = sizeof PROTO_WELCOME_LABEL - 1;
    uint8_t msg[sizeof PROTO_WELCOME_LABEL - 1 + 2 * PROTO_NONCE_SIZE];
    memcpy(msg, PROTO_WELCOME_LABEL, nl);
    memcpy(msg + nl, server_nonce, PROTO_NONCE_SIZE);
    memcpy(msg + nl + PROTO_NONCE_SIZE, peer_nonce, PROTO_NONCE_SIZE);
    return proto_auth_hmac_sha256(token, token_len, msg, sizeof msg, out, err);
}

pt_status proto_auth_check_server(const uint8_t *token, size_t token_len,
                                  const uint8_t server_nonce[PROTO_NONCE_SIZE],
                                  const uint8_t peer_nonce[PROTO_NONCE_SIZE],
                                  const uint8_t proof[PROTO_MAC_SIZE], pt_error *err)
{
    uint8_t want[PROTO_MAC_SIZE];
    if (proto_auth_server_proof(token, token_len, server_nonce, peer_nonce, want, err) != PT_OK)
        return pt_error_set(err, PT_ERR_AUTH, "auth: cannot compute the expected proof");
    int diff = CRYPTO_memcmp(want, proof, PROTO_MAC_SIZE);
    OPENSSL_cleanse(want, sizeof want);
    if (diff != 0)
        return pt_error_set(err, PT_ERR_AUTH, "auth: wrong proof in WELCOME");
    return PT_OK;
}

void proto_secret_free(uint8_t *data, size_t len)
{
    if (!data)
        return;
    OPENSSL_cleanse(data, len);
    pt_free(data);
}

pt_status proto_secret_read(const char *path, const char *what, size_t max, uint8_t **data,
                            size_t *len, pt_error *err)
{
    pt_status st = PT_OK;
    uint8_t *buf = NULL;
    size_t n = 0;
    int fd = open(path, O_RDONLY | O_CLOEXEC | O_NOCTTY);
    if (fd < 0)
        return pt_error_errno(err, PT_ERR_IO, "%s %s", what, path);
    struct stat sb;
    if (fstat(fd, &sb) != 0) {
        st = pt_error_errno(err, PT_ERR_IO, "%s %s", what, path);
        goto fail;
    }
    if (!S_ISREG(sb.st_mode)) {
        st = pt_error_set(err, PT_ERR_IO, "%s %s: not a regular file", what, path);
        goto fail;
    }
    /* Another user who can read the secret can join the farm; one who can
     * write it can lock everyone out or pick the token. */
    if (sb.st_mode & (S_IRWXG | S_IRWXO)) {
        st = pt_error_set(err, PT_ERR_AUTH,
                          "%s %s has mode %04o: other users may read or change it; "
                          "run: chmod 600 %s",
                          what, path, (unsigned)(sb.st_mode & 07777), path);
        goto fail;
    }
    /* One byte over max tells a file that is too long without reading it all. */
    buf = pt_malloc(max + 2);
    if (!buf) {
        st = pt_error_set(err, PT_ERR_NOMEM, "%s %s: out of memory", what, path);
        goto fail;
    }
    for (;;) {
        if (n == max + 1) {
            st = pt_error_set(err, PT_ERR_LIMIT, "%s %s: over %zu bytes", what, path, max);
            goto fail;
        }
        ssize_t got = read(fd, buf + n, max + 1 - n);
        if (got < 0) {
            if (errno == EINTR)
                continue;
            st = pt_error_errno(err, PT_ERR_IO, "%s %s", what, path);
            goto fail;
        }
        if (got == 0)
            break;
        n += (size_t)got;
    }
    buf[n] = '\0';
    *data = buf;
    *len = n;
    close(fd);
    return PT_OK;
fail:
    proto_secret_free(buf, max + 2);
    close(fd);
    return st;
}

/* len x the Shannon entropy of tok's byte frequencies, in bits. */
static double token_bits(const uint8_t *tok, size_t len)
{
    uint32_t count[256] = {0};
    for (size_t i = 0; i < len; i++)
        count[tok[i]]++;
    double bits = 0.0;
    for (int b = 0; b < 256; b++)
        if (count[b])
            bits -= count[b] * log2((double)count[b] / (double)len);
    return bits;
}

pt_status proto_token_check(const uint8_t *tok, size_t len, const char *what, pt_error *err)
{
    if (len < PROTO_TOKEN_MIN)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "%s: token of %zu bytes is too short (at least %u); make one with: "
                            "%s",
                            what, len, PROTO_TOKEN_MIN, PROTO_TOKEN_HOWTO);
    if (len > PROTO_TOKEN_MAX)
        return pt_error_set(err, PT_ERR_LIMIT, "%s: token of %zu bytes is over %u", what, len,
                            PROTO_TOKEN_MAX);
    /* With a margin, so that a token at the bound (16 distinct bytes) is
     * not refused for a last bit lost to rounding. */
    double bits = token_bits(tok, len);
    if (bits + 1e-9 < PROTO_TOKEN_MIN_BITS)
        return pt_error_set(err, PT_ERR_FORMAT,
                            "%s: token is too uniform to be secret (its bytes hold about %.0f "
                            "bits, at least %.0f are needed); make one with: %s",
                            what, bits, PROTO_TOKEN_MIN_BITS, PROTO_TOKEN_HOWTO);
    return PT_OK;
}

pt_status proto_token_load(const char *path, uint8_t *buf, size_t cap, size_t *len, pt_error *err)
{
    uint8_t *data = NULL;
    size_t n = 0;
    /* Room for a maximal token plus generous trailing white space. */
    const size_t max = PROTO_TOKEN_MAX + 256;
    pt_status st = proto_secret_read(path, "token file", max, &data, &n, err);
    if (st != PT_OK)
        return st;
    while (n > 0 && (data[n - 1] == ' ' || data[n - 1] == '\t' || data[n - 1] == '\r' ||
                     data[n - 1] == '\n'))
        n--;
    char what[600];
    snprintf(what, sizeof what, "token file %s", path);
    if ((st = proto_token_check(data, n, what, err)) != PT_OK)
        goto done;
    if (n > cap) {
        st = pt_error_set(err, PT_ERR_LIMIT, "%s: token of %zu bytes over %zu", what, n, cap);
        goto done;
    }
    memcpy(buf, data, n);
    *len = n;
done:
    proto_secret_free(data, max + 2);
    return st;
}
