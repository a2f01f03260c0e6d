/* status.c - the tool's one status enum and its thread-local detail string (gs_*). */
#include "recognize/base/base.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>

static _Thread_local char detail[1024];

const char *gs_strerror(gs_status s)
{
    switch (s) {
    case GS_OK: return "ok";
    case GS_EINVAL: return "invalid argument";
    case GS_EIO: return "input/output error";
    case GS_EFORMAT: return "bad file format";
    case GS_ENOMEM: return "out of memory";
    case GS_ESQL: return "database error";
    case GS_ENOTFOUND: return "not found";
    case GS_ENUMERIC: return "numerical error";
    case GS_ELIMIT: return "limit exceeded";
    }
    return "unknown status";
}

const char *gs_detail(void)
{
    return detail;
}

gs_status gs_fail(gs_status s, const char *fmt, ...)
{
    /* through a copy, so an argument may be gs_detail() itself (adding context to it) */
    char buf[sizeof detail];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    /* one line, whatever a library or a file name put in it: trailing white space (OpenCV ends
     * its messages with a newline) dropped, other control bytes shown as spaces */
    size_t n = strlen(buf);
    while (n > 0 && (unsigned char)buf[n - 1] <= ' ') buf[--n] = '\0';
    for (size_t i = 0; i < n; i++)
        if ((unsigned char)buf[i] < ' ' || buf[i] == 0x7f) buf[i] = ' ';
    memcpy(detail, buf, sizeof detail);
    return s;
}
