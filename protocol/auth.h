/*
 * auth.h - proof that a peer holds the farm's token, and that the server does.
 *
 * The handshake is mutual: the server sends CHALLENGE with a fresh 32-byte
 * random nonce Ns; the peer answers AUTH with its own fresh nonce Np and
 *     mac = HMAC-SHA256(key = token, message = "ptfarm-auth-v1" || Ns)
 * (RFC 2104, SHA-256 of FIPS 180-4; the label keeps these MACs apart from any
 * other use of the same token). The server computes the same and compares in
 * constant time; only then does it send WELCOME with
 *     proof = HMAC-SHA256(key = token, "ptfarm-welcome-v2" || Ns || Np)
 * which the peer checks before it sends anything else, so a worker or ptctl
 * pointed at a listener that does not know the token stops there (a fake
 * coordinator could otherwise hand out scenes or swallow results). The two
 * labels differ, so neither MAC can be reflected as the other. The token never
 * travels; a recorded AUTH or WELCOME is useless against other nonces. This
 * authenticates the two ends, it does not protect the stream after WELCOME.
 * OpenSSL's libcrypto does the hashing and randomness.
 *
 * Secrets live in files that only their owner may read or write
 * (proto_secret_read: a file that group or others may access is refused with
 * its mode and the chmod that fixes it). A token (proto_token_load) is the
 * file's bytes up to trailing white space, PROTO_TOKEN_MIN..PROTO_TOKEN_MAX
 * bytes of enough variety (PROTO_TOKEN_MIN_BITS): a short or uniform token
 * would fall to guessing.
 * Thread-safety: reentrant (OpenSSL 3's one-shot HMAC and RAND_bytes are).
 */
#ifndef PT_PROTOCOL_AUTH_H
#define PT_PROTOCOL_AUTH_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"
#include "protocol/msg.h"

#define PROTO_TOKEN_MAX 4096u
#define PROTO_TOKEN_MIN 16u /* bytes after trimming: 32 random bytes in base64 are 44 */
#define PROTO_AUTH_LABEL "ptfarm-auth-v1"
#define PROTO_WELCOME_LABEL "ptfarm-welcome-v2"
/* How to make a good token, for the messages that refuse a bad one. */
#define PROTO_TOKEN_HOWTO "head -c 32 /dev/urandom | base64 > FILE && chmod 600 FILE"

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

/* proof = HMAC-SHA256(token, PROTO_WELCOME_LABEL || server_nonce || peer_nonce):
 * what the server's WELCOME carries. Same token rules and errors as
 * proto_auth_response; out is untouched on failure. */
pt_status proto_auth_server_proof(const uint8_t *token, size_t token_len,
                                  const uint8_t server_nonce[PROTO_NONCE_SIZE],
                                  const uint8_t peer_nonce[PROTO_NONCE_SIZE],
                                  uint8_t out[PROTO_MAC_SIZE], pt_error *err);

/* PT_OK when proof is the server's right answer for the two nonces under
 * token, PT_ERR_AUTH otherwise (compared in constant time). */
pt_status proto_auth_check_server(const uint8_t *token, size_t token_len,
                                  const uint8_t server_nonce[PROTO_NONCE_SIZE],
                                  const uint8_t peer_nonce[PROTO_NONCE_SIZE],
                                  const uint8_t proof[PROTO_MAC_SIZE], pt_error *err);

/* Reads the whole secret file at path (what = "token file", "clients file":
 * names it in messages) into a new pt_malloc'd buffer *data of *len bytes
 * (plus a NUL after them, not counted); the caller cleanses and frees it
 * (proto_secret_free). Refuses, with err naming the file: a file that cannot
 * be opened or is not a regular file (PT_ERR_IO); a file that group or others
 * may read, write or execute (PT_ERR_AUTH, with its mode and "chmod 600
 * PATH"); more than max bytes (PT_ERR_LIMIT, judged with a bounded read, so a
 * huge or growing file costs nothing); PT_ERR_NOMEM. The mode is judged on the
 * opened file (fstat), so a link swapped after a check cannot slip past it.
 * Outputs are untouched on failure. */
pt_status proto_secret_read(const char *path, const char *what, size_t max, uint8_t **data,
                            size_t *len, pt_error *err);
/* Overwrites len bytes of data with zeros (not optimised away) and frees it. Accepts NULL. */
void proto_secret_free(uint8_t *data, size_t len);

/* The least a token's bytes must hold by their own statistics: len times
 * the entropy of their byte frequencies, in bits. 16 distinct bytes (the
 * shortest token) hold 64; a token of 32 random bytes in base64, about
 * 230. It catches what a person types in a hurry: one byte repeated, a
 * short pattern repeated, a word doubled. It cannot see a guessable phrase. */
#define PROTO_TOKEN_MIN_BITS 64.0

/* PT_OK when the token tok of len bytes is allowed: PROTO_TOKEN_MIN..
 * PROTO_TOKEN_MAX bytes holding at least PROTO_TOKEN_MIN_BITS. Otherwise
 * PT_ERR_FORMAT (empty, short or too uniform: the message says how to make
 * a good one) or PT_ERR_LIMIT; what names the token in the message. */
pt_status proto_token_check(const uint8_t *tok, size_t len, const char *what, pt_error *err);

/* Reads the token file at path (proto_secret_read's rules) into buf (cap
 * bytes) and strips trailing spaces, tabs, CR and LF; *len is the token's
 * length, which proto_token_check must accept. buf and len are untouched on
 * failure. */
pt_status proto_token_load(const char *path, uint8_t *buf, size_t cap, size_t *len, pt_error *err);

#endif
