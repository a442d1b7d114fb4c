#include "protocol/auth.h"

#include <errno.h>
#include <fcntl.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <openssl/hmac.h>
#include <openssl/rand.h>

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

pt_status proto_token_load(const char *path, uint8_t *buf, size_t cap, size_t *len,
                           int *loose_perms, pt_error *err)
{
    /* Room for a maximal token plus generous trailing white space; anything
     * longer is refused without reading further. */
    uint8_t tmp[PROTO_TOKEN_MAX + 256];
    size_t n = 0;
    pt_status st = PT_OK;
    int fd = open(path, O_RDONLY | O_CLOEXEC | O_NOCTTY);
    if (fd < 0)
        return pt_error_errno(err, PT_ERR_IO, "token file %s", path);
    struct stat sb;
    if (fstat(fd, &sb) != 0) {
        st = pt_error_errno(err, PT_ERR_IO, "token file %s", path);
        goto fail;
    }
    if (!S_ISREG(sb.st_mode)) {
        st = pt_error_set(err, PT_ERR_IO, "token file %s: not a regular file", path);
        goto fail;
    }
    for (;;) {
        if (n == sizeof tmp) {
            st = pt_error_set(err, PT_ERR_LIMIT, "token file %s: over %u bytes", path,
                              PROTO_TOKEN_MAX);
            goto fail;
        }
        ssize_t got = read(fd, tmp + n, sizeof tmp - n);
        if (got < 0) {
            if (errno == EINTR)
                continue;
            st = pt_error_errno(err, PT_ERR_IO, "token file %s", path);
            goto fail;
        }
        if (got == 0)
            break;
        n += (size_t)got;
    }
    while (n > 0 &&
           (tmp[n - 1] == ' ' || tmp[n - 1] == '\t' || tmp[n - 1] == '\r' || tmp[n - 1] == '\n'))
        n--;
    if (n == 0) {
        st = pt_error_set(err, PT_ERR_FORMAT, "token file %s: empty token", path);
        goto fail;
    }
    if (n > PROTO_TOKEN_MAX || n > cap) {
        st = pt_error_set(err, PT_ERR_LIMIT, "token file %s: token of %zu bytes over %zu", path, n,
                          cap < PROTO_TOKEN_MAX ? cap : (size_t)PROTO_TOKEN_MAX);
        goto fail;
    }
    memcpy(buf, tmp, n);
    *len = n;
    if (loose_perms)
        *loose_perms = (sb.st_mode & (S_IRWXG | S_IRWXO)) != 0;
fail:
    OPENSSL_cleanse(tmp, sizeof tmp);
    close(fd);
    return st;
}
