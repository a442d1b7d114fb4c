#include "common/base/hash.h"

#include <errno.h>
#include <openssl/evp.h>
#include <string.h>
#include <sys/types.h>
#include <unistd.h>

#include "common/base/alloc.h"

void pt_hash_hex(const uint8_t hash[32], char out[65])
{
    static const char hex[] = "0123456789abcdef";
    for (unsigned i = 0; i < 32; i++) {
        out[2 * i] = hex[hash[i] >> 4];
        out[2 * i + 1] = hex[hash[i] & 15];
    }
    out[64] = '\0';
}

void pt_sha256(const uint8_t *data, size_t size, uint8_t out[32])
{
    unsigned char md[EVP_MAX_MD_SIZE];
    unsigned int len = 0;
    if (!EVP_Digest(data, size, md, &len, EVP_sha256(), NULL) || len != 32)
        memset(md, 0, 32);
    memcpy(out, md, 32);
}

pt_status pt_sha256_fd(int fd, uint8_t out[32], pt_error *err)
{
    enum { PIECE = 1 << 20 };
    uint8_t *buf = pt_malloc(PIECE);
    EVP_MD_CTX *ctx = EVP_MD_CTX_new();
    pt_status st = PT_OK;
    if (!buf || !ctx || !EVP_DigestInit_ex(ctx, EVP_sha256(), NULL)) {
        st = pt_error_set(err, PT_ERR_NOMEM, "SHA-256: out of memory");
        goto done;
    }
    for (off_t at = 0;;) {
        ssize_t n = pread(fd, buf, PIECE, at);
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0) {
            st = pt_error_errno(err, PT_ERR_IO, "SHA-256: read");
            goto done;
        }
        if (n == 0)
            break;
        EVP_DigestUpdate(ctx, buf, (size_t)n);
        at += n;
    }
    unsigned char md[EVP_MAX_MD_SIZE];
    unsigned int len = 0;
    if (!EVP_DigestFinal_ex(ctx, md, &len) || len != 32) {
        st = pt_error_set(err, PT_ERR_NOMEM, "SHA-256: the digest failed");
        goto done;
    }
    memcpy(out, md, 32);
done:
    EVP_MD_CTX_free(ctx);
    pt_free(buf);
    return st;
}

void pt_sha256_hex(const uint8_t *data, size_t size, char out[65])
{
    uint8_t md[32];
    pt_sha256(data, size, md);
    pt_hash_hex(md, out);
}

int pt_hex_digit(char ch)
{
    if (ch >= '0' && ch <= '9')
        return ch - '0';
    if (ch >= 'a' && ch <= 'f')
        return ch - 'a' + 10;
    if (ch >= 'A' && ch <= 'F')
        return ch - 'A' + 10;
    return -1;
}

int pt_hex_decode(const char *hex, uint8_t *out, size_t n)
{
    if (strnlen(hex, 2 * n + 1) != 2 * n)
        return -1;
    for (size_t i = 0; i < n; i++)
        if (pt_hex_digit(hex[2 * i]) < 0 || pt_hex_digit(hex[2 * i + 1]) < 0)
            return -1;
    for (size_t i = 0; i < n; i++)
        out[i] = (uint8_t)(pt_hex_digit(hex[2 * i]) << 4 | pt_hex_digit(hex[2 * i + 1]));
    return 0;
}
