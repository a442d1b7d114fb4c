/*
 * text.h - text a peer chose, made safe to print.
 *
 * Names, job names, paths and error reasons come from peers; written raw to
 * a log or a terminal, a newline forges a log line and an ESC drives the
 * terminal. pt_text_escape copies printable ASCII (0x20-0x7e) as is and
 * writes every other byte as \xNN (lower-case hex), a backslash as \\, so
 * the result is one line of plain ASCII that names the original bytes
 * exactly. Bytes from 0x80 up are escaped too: it keeps C1 controls (0x9b is
 * a CSI on some terminals) and malformed UTF-8 out without a decoder, at the
 * price of showing non-ASCII names as escapes. Only for printing: what is
 * stored or sent keeps the peer's bytes. Pure functions: any thread may call
 * them.
 */
#ifndef PT_COMMON_BASE_TEXT_H
#define PT_COMMON_BASE_TEXT_H

#include <stddef.h>

/* A buffer that holds the escaped form of n bytes whole, with the NUL. */
#define PT_TEXT_ESCAPED_SIZE(n) ((n)*4u + 1u)

/* Escapes in_len bytes of in (NULs included) into out (cap bytes) and
 * returns out, always NUL-terminated when cap > 0. When the whole escaped
 * form does not fit, it ends at a whole escape followed by "..." (as much of
 * it as fits). in may be NULL when in_len is 0. */
char *pt_text_escape(const char *in, size_t in_len, char *out, size_t cap);

/* pt_text_escape of a NUL-terminated string (NULL reads as ""). */
char *pt_text_shown(const char *s, char *out, size_t cap);

#endif
