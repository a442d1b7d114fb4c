/*
 * hash.h - SHA-256 and the hex text of hashes.
 *
 * Scenes and bundles are named by the SHA-256 of their bytes (OpenSSL's
 * libcrypto), written as 64 lower-case hex digits; peers send the 32 raw
 * bytes. Every conversion between the two is here, so that the coordinator,
 * the worker cache and ptctl agree on one spelling. Pure functions: any
 * thread may call them.
 */
#ifndef PT_COMMON_BASE_HASH_H
#define PT_COMMON_BASE_HASH_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"

#define PT_HASH_SIZE 32u /* bytes of a SHA-256 */
#define PT_HASH_HEX 65u  /* its hex text with the NUL */

/* A 32-byte hash as lower-case hex (65 bytes with the NUL). */
void pt_hash_hex(const uint8_t hash[32], char out[65]);

/* SHA-256 of bytes, the 32 raw bytes as peers send them. A failure of the
 * digest (it has none for in-memory bytes) gives 32 zero bytes. */
void pt_sha256(const uint8_t *data, size_t size, uint8_t out[32]);

/* SHA-256 of the bytes of the open file fd, from its start to its end,
 * read in 1 MiB pieces with pread (fd's offset is left alone), so a file of
 * any size is hashed in constant memory. PT_ERR_IO when a read fails,
 * PT_ERR_NOMEM; out is untouched on failure. */
pt_status pt_sha256_fd(int fd, uint8_t out[32], pt_error *err);

/* SHA-256 of bytes as lower-case hex (65 bytes with the NUL): pt_sha256 then
 * pt_hash_hex, so a failure gives 64 zeros. */
void pt_sha256_hex(const uint8_t *data, size_t size, char out[65]);

/* The value of one hex digit (either case), or -1 for any other character. */
int pt_hex_digit(char ch);

/* Decodes exactly 2n hex digits (either case) of hex into n bytes. Returns 0,
 * or -1, leaving out untouched, when hex is shorter or longer than 2n digits
 * or holds a character that is not a hex digit. */
int pt_hex_decode(const char *hex, uint8_t *out, size_t n);

#endif
