/* fuzz_link.c - the host side of the ACam controller's serial protocol (capture/acam_link.c):
 * the input after its 2 header bytes is everything the controller sends, queued on one end of a
 * socket pair whose writing side is then shut (the link reads it, then end of file: no call
 * waits for its timeout); the other end goes through cap_link_open_fd. The header is the
 * configuration (byte 0: K in its low 5 bits, free running if bit 7; byte 1: k in its low 5
 * bits, C in its top 3; out of range on purpose too). The calls are those of a session: ping,
 * configure, start, get_status, stop, cycle_count, then one exposure.
 *
 * Each call's status must be that of an independent reading of the stream (docs/firmware.md):
 * lines end in LF (an optional CR before it), at most 199 bytes, and carry "*HH", the XOR of the
 * bytes before the '*'; 1024 bytes without a newline are dropped as one bad line; a command's
 * reply is the first good line starting "OK " or "ERR ", other good lines (data, events) are
 * skipped. GS_OK only for "OK <command>"; a bad line is GS_EFORMAT, the end GS_EIO. A call may
 * still refuse the fields of an "OK" reply (GS_EFORMAT); what it returns then is checked. */
#include "capture/capture.h"
#include "tests/fuzz/fuzz.h"

#include <math.h>
#include <sys/socket.h>
#include <time.h>

#ifndef FUZZ_REPLAY
/* START retries every 50 ms while the controller answers ERR NOLOCK (for up to 2 s): waiting
 * is not parsing, so the fuzzing binary does not wait (the replay in `make check` does). */
int nanosleep(const struct timespec *req, struct timespec *rem)
{
    (void)req;
    (void)rem;
    return 0;
}
#endif

#define LINK_FUZZ_MAX 16384 /* input bytes queued (the socket's buffer holds them at once) */

/* The oracle's reading position in the stream. */
typedef struct {
    const uint8_t *p;
    size_t left;
} link_stream;

enum { LINE_GOOD, LINE_BAD, LINE_END };

/* The next line of the stream; a good one's text before "*HH" (up to its first NUL, as the link
 * compares C strings) in text[200]. */
static int link_next(link_stream *s, char *text)
{
    size_t window = s->left < 1024 ? s->left : 1024, n = 0;
    while (n < window && s->p[n] != '\n') n++;
    if (n == window) {
        if (s->left < 1024) return LINE_END; /* a partial line, then the end */
        s->p += 1024, s->left -= 1024;
        return LINE_BAD;
    }
    const uint8_t *line = s->p;
    s->p += n + 1, s->left -= n + 1;
    if (n && line[n - 1] == '\r') n--;
    if (n >= 200 || n < 3 || line[n - 3] != '*') return LINE_BAD;
    static const char hex[] = "0123456789ABCDEF0123456789abcdef";
    const char *hi = memchr(hex, line[n - 2], 32), *lo = memchr(hex, line[n - 1], 32);
    if (!line[n - 2] || !line[n - 1] || !hi || !lo) return LINE_BAD;
    unsigned sum = 0;
    for (size_t i = 0; i + 3 < n; i++) sum ^= line[i];
    if (sum != (unsigned)((hi - hex) % 16 * 16 + (lo - hex) % 16)) return LINE_BAD;
    memcpy(text, line, n - 3);
    text[n - 3] = '\0';
    return LINE_GOOD;
}

/* What a command expecting "OK <expect>" must return; its reply text in reply[200]. */
static gs_status link_expected(link_stream *s, const char *expect, char *reply)
{
    for (;;) {
        int k = link_next(s, reply);
        if (k == LINE_END) return GS_EIO;
        if (k == LINE_BAD) return GS_EFORMAT;
        if (!strncmp(reply, "ERR ", 4)) {
            const char *code = reply + 4;
            if (!strcmp(code, "RANGE") || !strcmp(code, "BUSY") || !strcmp(code, "NOCFG"))
                return GS_EINVAL;
            return strcmp(code, "LIMIT") ? GS_EIO : GS_ELIMIT;
        }
        if (!strncmp(reply, "OK ", 3)) {
            size_t n = strlen(expect);
            return !strncmp(reply + 3, expect, n) && (!reply[3 + n] || reply[3 + n] == ' ')
                       ? GS_OK
                       : GS_EFORMAT;
        }
    }
}

/* A call's status against the oracle's: equal, or GS_EFORMAT for the fields of an OK reply
 * when refusable. */
static void link_check(gs_status got, gs_status want, int fields)
{
    if (got != want && !(fields && want == GS_OK && got == GS_EFORMAT)) abort();
}

/* The first whitespace-separated token after " key=" in reply, as a long (0: absent). */
static int link_field(const char *reply, const char *key, long *v)
{
    char pat[24];
    snprintf(pat, sizeof pat, " %s=", key);
    const char *p = strstr(reply, pat);
    if (!p) return 0;
    char *end;
    *v = strtol(p + strlen(pat), &end, 10);
    return 1;
}

FUZZ_TARGET(link)
{
    if (size < 2 || size > LINK_FUZZ_MAX) return 0;
    cap_link_config c = {data[0] & 31, data[1] & 31, data[1] >> 5,
                         data[0] & 0x80 ? CAP_FREE_RUNNING : CAP_LOCKED};
    int valid = c.K >= 2 && c.K <= 26 && c.k < c.K && c.cycles >= 1;
    int sv[2];
    if (socketpair(AF_UNIX, SOCK_STREAM, 0, sv) != 0) abort();
    for (size_t off = 2; off < size;) {
        ssize_t w = write(sv[1], data + off, size - off);
        if (w <= 0) abort();
        off += (size_t)w;
    }
    if (shutdown(sv[1], SHUT_WR) != 0) abort();
    cap_link *l = NULL;
    if (cap_link_open_fd(sv[0], &l) != GS_OK) abort();
    cap_link_set_timeout_ms(l, 5000); /* never reached: the stream ends */

    link_stream s = {data + 2, size - 2};
    char reply[200];
    long v, n = -1;
    link_check(cap_link_ping(l), link_expected(&s, "PING", reply), 0);
    link_check(cap_link_configure(l, &c), valid ? link_expected(&s, "CFG", reply) : GS_EINVAL, 0);
    link_check(cap_link_start(l), link_expected(&s, "START", reply), 0);

    cap_link_status st;
    gs_status want = link_expected(&s, "STATUS", reply), got = cap_link_get_status(l, &st);
    link_check(got, want, 1);
    if (got == GS_OK &&
        (!st.state[0] || !memchr(st.state, 0, sizeof st.state) || !st.fault[0] ||
         !memchr(st.fault, 0, sizeof st.fault) || !memchr(st.last_event, 0, sizeof st.last_event) ||
         (st.mode != CAP_LOCKED && st.mode != CAP_FREE_RUNNING) || !isfinite(st.half_period_s) ||
         !link_field(reply, "cycles", &v) || v != st.cycles_done ||
         !link_field(reply, "K", &v) || v != st.K || !strstr(reply, " state=") ||
         !(strstr(reply, " mode=L") || strstr(reply, " mode=F"))))
        abort();

    want = link_expected(&s, "STOP", reply);
    got = cap_link_stop(l, &n);
    link_check(got, want, 1);
    if (got == GS_OK && (!link_field(reply, "cycles", &v) || v != n)) abort();

    want = link_expected(&s, "COUNT", reply);
    got = cap_link_cycle_count(l, &n);
    link_check(got, want, 1);
    if (got == GS_OK && (n < 0 || strtol(reply + 9, NULL, 10) != n)) abort();

    /* the exposure: complete when it succeeds, never longer than C */
    cap_exposure_log log;
    got = cap_link_expose(l, &c, &log);
    if (got == GS_OK && !(valid && log.cycles == (size_t)c.cycles)) abort();
    if (log.cycles > (size_t)(c.cycles > 0 ? c.cycles : 0) || !memchr(log.fault, 0, sizeof log.fault))
        abort();
    for (size_t i = 0; i < log.cycles; i++)
        if (!(log.half_period_s[i] >= 0 && log.half_period_s[i] < 5)) abort(); /* < 2^32 ns */
    cap_exposure_log_release(&log);
    cap_link_close(l);
    close(sv[1]);
    return 0;
}
