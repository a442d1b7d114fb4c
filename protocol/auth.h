/*
 * auth.h - proof that a peer holds the farm's shared token.
 *
 * The handshake: the server sends CHALLENGE with a fresh 32-byte random nonce;
 * the peer answers AUTH with
 *     mac = HMAC-SHA256(key = token, message = "ptfarm-auth-v1" || nonce)
 * (RFC 2104, SHA-256 of FIPS 180-4; the label keeps these MACs apart from any
 * other use of the same token). The server computes the same and compares in
 * constant time. The token never travels; a recorded AUTH is useless against
 * another nonce. OpenSSL's libcrypto does the hashing and randomness.
 *
 * The token lives in a file (proto_token_load): its bytes up to trailing white
 * space, 1..PROTO_TOKEN_MAX bytes. A file that group or others may access is
 * still loaded but flagged, so the caller can warn.
 * Thread-safety: reentrant (OpenSSL 3's one-shot HMAC and RAND_bytes are).
 */
#ifndef PT_PROTOCOL_AUTH_H
#define PT_PROTOCOL_AUTH_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"
#include "protocol/msg.h"

#define PROTO_TOKEN_MAX 4096u
#define PROTO_AUTH_LABEL "ptfarm-auth-v1"

/* Fills nonce with PROTO_NONCE_SIZE bytes from the OS's CSPRNG (RAND_bytes).
 * PT_ERR_IO when the generator fails (nonce then undefined). */
pt_status proto_auth_nonce(uint8_t nonce[PROTO_NONCE_SIZE], pt_error *err);

/* The primitive underneath: out = HMAC-SHA256(key, data) (RFC 2104) through
 * libcrypto; exposed so that tests can check it against RFC 4231's vectors.
 * PT_ERR_ARG for a key over PROTO_TOKEN_MAX bytes, PT_ERR_AUTH if libcrypto fails. */
pt_status proto_auth_hmac_sha256(const uint8_t *key, size_t key_len, const uint8_t *data,
                                 size_t data_len, uint8_t out[PROTO_MAC_SIZE], pt_error *err);

/* out = HMAC-SHA256(token, PROTO_AUTH_LABEL || nonce). token_len must be
 * 0..PROTO_TOKEN_MAX (PT_ERR_ARG otherwise); an empty token is the
 * loopback-only mode of a coordinator started without --token-file; PT_ERR_AUTH if libcrypto fails.
 * out is untouched on failure. */
pt_status proto_auth_response(const uint8_t *token, size_t token_len,
                              const uint8_t nonce[PROTO_NONCE_SIZE], uint8_t out[PROTO_MAC_SIZE],
                              pt_error *err);

/* PT_OK when mac is the right response to nonce under token, PT_ERR_AUTH
 * otherwise (also when it cannot be computed). The comparison takes the same
 * time wherever the first difference is (CRYPTO_memcmp). */
pt_status proto_auth_verify(const uint8_t *token, size_t token_len,
                            const uint8_t nonce[PROTO_NONCE_SIZE],
                            const uint8_t mac[PROTO_MAC_SIZE], pt_error *err);

/* Reads the token file at path into buf (cap bytes) and strips trailing
 * spaces, tabs, CR and LF; *len is the token's length. Refuses (err names the
 * file): a file that cannot be opened or is not a regular file (PT_ERR_IO), an
 * empty token (PT_ERR_FORMAT), a token over PROTO_TOKEN_MAX bytes or over cap
 * (PT_ERR_LIMIT; judged on the bytes read, with a bounded read, so a huge or
 * growing file costs nothing and cannot overrun buf). *loose_perms (may be
 * NULL) is set to 1 when group or others have any permission on the file,
 * else 0: the token is still returned, and the caller should warn. buf, len
 * and loose_perms are untouched on failure. */
pt_status proto_token_load(const char *path, uint8_t *buf, size_t cap, size_t *len,
                           int *loose_perms, pt_error *err);

#endif
