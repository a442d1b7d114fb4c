/*
 * error.h - the project's one status enum and the error detail that travels with it.
 *
 * A function that can fail returns a pt_status and fills an optional pt_error
 * (may be NULL) whose message names the thing at fault (file, field, peer).
 * PT_AGAIN means "need more bytes / would block" and is never an error.
 * Results go in out-parameters placed last and are untouched on failure.
 * Thread-safety: pt_error is caller-owned; the functions here are reentrant.
 */
#ifndef PT_COMMON_BASE_ERROR_H
#define PT_COMMON_BASE_ERROR_H

typedef enum pt_status {
    PT_OK = 0,
    PT_AGAIN,      /* need more input / would block; not an error */
    PT_ERR_NOMEM,  /* an allocation failed */
    PT_ERR_IO,     /* the OS said no (errno is kept) */
    PT_ERR_PROTO,  /* a peer broke the protocol */
    PT_ERR_LIMIT,  /* a size or count is over its cap */
    PT_ERR_FORMAT, /* a file or message is malformed */
    PT_ERR_AUTH,   /* authentication failed */
    PT_ERR_ARG     /* a caller passed something invalid */
} pt_status;

typedef struct pt_error {
    pt_status code;
    int sys_errno; /* errno at the time of a PT_ERR_IO, else 0 */
    char msg[512];
} pt_error;

/* Fills err (when not NULL) with code and a printf-style message; returns code. */
pt_status pt_error_set(pt_error *err, pt_status code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

/* Like pt_error_set, and appends ": strerror(errno)" and keeps errno. */
pt_status pt_error_errno(pt_error *err, pt_status code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

/* Static text for a status ("out of memory", ...). */
const char *pt_status_str(pt_status code);

/* Resets err to PT_OK with an empty message. Accepts NULL. */
void pt_error_clear(pt_error *err);

#endif
