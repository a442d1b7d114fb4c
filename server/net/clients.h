/*
 * clients.h - per-client tokens: who a client is, from the token it proves.
 *
 * `ptserve --clients-file FILE` names the clients: one "NAME TOKEN" per line,
 * separated by spaces or tabs; blank lines and lines whose first non-blank
 * byte is '#' are ignored. NAME is 1..PROTO_MAX_NAME printable ASCII bytes
 * without spaces; TOKEN follows proto_token_check (PROTO_TOKEN_MIN bytes or
 * more) and may not be the shared token nor another line's token. A NAME may
 * appear on several lines (several tokens, e.g. while one is replaced). The
 * file obeys proto_secret_read's rules (mode 0600 or stricter), at most
 * SRV_CLIENTS_MAX_BYTES and SRV_CLIENTS_MAX entries.
 *
 * A client that answers the challenge with the MAC of one of these tokens
 * is that line's NAME, whatever name its HELLO declared: the server tries
 * every entry against the response (no early exit, so the time does not
 * say which line matched). That costs one HMAC per entry for every AUTH
 * that is not the shared token's: about 3 us each, 0.75 ms for a full file
 * of SRV_CLIENTS_MAX entries on the event loop (measured), which the
 * per-address backoff (server/net/authlimit.h) bounds for wrong answers. The
 * shared token (--token-file) is tried first and makes a peer an admin.
 *
 * Threads: loaded before the loop; read only by the event-loop thread.
 */
#ifndef PT_SERVER_CLIENTS_H
#define PT_SERVER_CLIENTS_H

#include <stddef.h>
#include <stdint.h>

#include "common/base/error.h"
#include "protocol/msg.h"

#define SRV_CLIENTS_MAX 256u
#define SRV_CLIENTS_MAX_BYTES (1u << 20)

typedef struct srv_clients srv_clients;

/* Loads path (see above). admin/admin_len is the shared token, which no
 * entry may repeat. *out is a new srv_clients (srv_clients_free) on success;
 * err names the file and line at fault otherwise (PT_ERR_FORMAT for a bad
 * line, proto_secret_read's errors for the file). */
pt_status srv_clients_load(const char *path, const uint8_t *admin, size_t admin_len,
                           srv_clients **out, pt_error *err);

/* Number of entries. */
uint32_t srv_clients_count(const srv_clients *cl);

/* The entry whose token gives mac for nonce (proto_auth_verify), or -1.
 * On a match *token and *token_len borrow that entry's token (for the
 * WELCOME proof) and *name its NAME. */
int srv_clients_match(const srv_clients *cl, const uint8_t nonce[PROTO_NONCE_SIZE],
                      const uint8_t mac[PROTO_MAC_SIZE], const char **name, const uint8_t **token,
                      size_t *token_len);

/* Cleanses the tokens and frees. Accepts NULL. */
void srv_clients_free(srv_clients *cl);

#endif
