#include "server/log.h"

#include <stdarg.h>
#include <stdio.h>

void srv_log(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fputs("\rptserve: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputs("\033[K\n", stderr);
    va_end(ap);
}
