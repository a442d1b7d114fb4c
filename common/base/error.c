#include "common/base/error.h"

#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

pt_status pt_error_set(pt_error *err, pt_status code, const char *fmt, ...)
{
    if (err) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(err->msg, sizeof err->msg, fmt, ap);
        va_end(ap);
        err->code = code;
        err->sys_errno = 0;
    }
    return code;
}

pt_status pt_error_errno(pt_error *err, pt_status code, const char *fmt, ...)
{
    int saved = errno;
    if (err) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(err->msg, sizeof err->msg, fmt, ap);
        va_end(ap);
        size_t n = strlen(err->msg);
        snprintf(err->msg + n, sizeof err->msg - n, ": %s", strerror(saved));
        err->code = code;
        err->sys_errno = saved;
    }
    return code;
}

const char *pt_status_str(pt_status code)
{
    switch (code) {
    case PT_OK:
        return "ok";
    case PT_AGAIN:
        return "again";
    case PT_ERR_NOMEM:
        return "out of memory";
    case PT_ERR_IO:
        return "I/O error";
    case PT_ERR_PROTO:
        return "protocol error";
    case PT_ERR_LIMIT:
        return "over a limit";
    case PT_ERR_FORMAT:
        return "malformed input";
    case PT_ERR_AUTH:
        return "authentication failed";
    case PT_ERR_ARG:
        return "invalid argument";
    }
    return "unknown status";
}

void pt_error_clear(pt_error *err)
{
    if (err) {
        err->code = PT_OK;
        err->sys_errno = 0;
        err->msg[0] = '\0';
    }
}
