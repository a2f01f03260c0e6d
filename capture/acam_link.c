/* acam_link.c - the host side of the ACam controller's serial protocol (capture.h,
 * docs/firmware.md): checksummed lines over a tty (or any descriptor), commands with their
 * replies, and one exposure with its per-cycle half-period log (paper Sec. 6: the Arduino that
 * locks the DMD mask switching to the mains zero crossings). */
#include "capture/capture.h"

#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#define LINK_LINE_MAX 200       /* longer than any firmware line (firmware/proto.h: 128) */
#define LINK_LOCK_RETRY_MS 50

struct cap_link {
    int fd;
    int is_socket;
    int timeout_ms;
    char in[1024]; /* received bytes not yet returned as lines */
    size_t in_len;
};

/* ------------------------------------------------------------------ plumbing */

static double now_ms(void)
{
    return 1e3 * gs_clock_s(CLOCK_MONOTONIC);
}

static unsigned checksum(const char *s, size_t n)
{
    unsigned x = 0;
    for (size_t i = 0; i < n; i++) x ^= (unsigned char)s[i];
    return x;
}

static int hexval(char c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    return -1;
}

/* Sends "cmd*HH\n". */
static gs_status send_line(cap_link *l, const char *cmd)
{
    char buf[LINK_LINE_MAX];
    size_t n = strlen(cmd);
    if (n + 5 > sizeof buf) return gs_fail(GS_EINVAL, "acam link: command too long: %s", cmd);
    int len = snprintf(buf, sizeof buf, "%s*%02X\n", cmd, checksum(cmd, n));
    size_t off = 0;
    while (off < (size_t)len) {
        /* a socket whose peer has gone must give EPIPE, not kill the process with SIGPIPE */
        ssize_t w = l->is_socket ? send(l->fd, buf + off, (size_t)len - off, MSG_NOSIGNAL)
                                 : write(l->fd, buf + off, (size_t)len - off);
        if (w < 0 && errno == EINTR) continue;
        if (w < 0) return gs_fail(GS_EIO, "acam link: write '%s': %s", cmd, strerror(errno));
        off += (size_t)w;
    }
    return GS_OK;
}

/* The next line (without "*HH" and newline) into line[LINK_LINE_MAX], waiting until
 * deadline_ms (CLOCK_MONOTONIC ms). GS_EIO on timeout, end of file or error; GS_EFORMAT for a
 * bad or missing checksum or an overlong line. */
static gs_status read_line(cap_link *l, char *line, double deadline_ms)
{
    for (;;) {
        char *nl = memchr(l->in, '\n', l->in_len);
        if (nl) {
            size_t n = (size_t)(nl - l->in);
            size_t used = n + 1;
            if (n && l->in[n - 1] == '\r') n--;
            if (n >= LINK_LINE_MAX) {
                memmove(l->in, l->in + used, l->in_len - used);
                l->in_len -= used;
                return gs_fail(GS_EFORMAT, "acam link: a line of %zu bytes", n);
            }
            memcpy(line, l->in, n);
            line[n] = '\0';
            memmove(l->in, l->in + used, l->in_len - used);
            l->in_len -= used;
            int hi = n >= 3 ? hexval(line[n - 2]) : -1, lo = n >= 3 ? hexval(line[n - 1]) : -1;
            if (n < 3 || line[n - 3] != '*' || hi < 0 || lo < 0)
                return gs_fail(GS_EFORMAT, "acam link: line without checksum: '%s'", line);
            if (checksum(line, n - 3) != (unsigned)(hi * 16 + lo))
                return gs_fail(GS_EFORMAT, "acam link: bad checksum: '%s'", line);
            line[n - 3] = '\0';
            return GS_OK;
        }
        if (l->in_len == sizeof l->in) { /* no newline in a full buffer */
            l->in_len = 0;
            return gs_fail(GS_EFORMAT, "acam link: a line longer than %zu bytes", sizeof l->in);
        }
        double left = deadline_ms - now_ms();
        if (left <= 0) return gs_fail(GS_EIO, "acam link: no reply within the timeout");
        struct pollfd p = {l->fd, POLLIN, 0};
        int r = poll(&p, 1, (int)(left + 1));
        if (r < 0 && errno == EINTR) continue;
        if (r < 0) return gs_fail(GS_EIO, "acam link: poll: %s", strerror(errno));
        if (r == 0) continue;
        ssize_t got = read(l->fd, l->in + l->in_len, sizeof l->in - l->in_len);
        if (got < 0 && (errno == EINTR || errno == EAGAIN)) continue;
        if (got < 0) return gs_fail(GS_EIO, "acam link: read: %s", strerror(errno));
        if (got == 0) return gs_fail(GS_EIO, "acam link: the device closed the line");
        l->in_len += (size_t)got;
    }
}

/* ERR code -> status, as documented in capture.h. */
static gs_status err_status(const char *code)
{
    if (!strcmp(code, "RANGE") || !strcmp(code, "BUSY") || !strcmp(code, "NOCFG"))
        return GS_EINVAL;
    if (!strcmp(code, "LIMIT")) return GS_ELIMIT;
    return GS_EIO; /* SYNTAX, CHECKSUM, LONG, NOLOCK, unknown */
}

/* Sends cmd and returns its reply ("OK <expect>..." required) in reply[LINK_LINE_MAX]. Data
 * and event lines arriving meanwhile are skipped. *err_code gets the code of an ERR reply
 * (may be NULL). */
static gs_status command(cap_link *l, const char *cmd, const char *expect, char *reply,
                         char *err_code, size_t err_code_size)
{
    gs_status s = send_line(l, cmd);
    if (s != GS_OK) return s;
    double deadline = now_ms() + l->timeout_ms;
    for (;;) {
        s = read_line(l, reply, deadline);
        if (s == GS_EIO) return gs_fail(GS_EIO, "acam link: %s: %s", cmd, gs_detail());
        if (s != GS_OK) return s;
        if (!strncmp(reply, "ERR ", 4)) {
            if (err_code) snprintf(err_code, err_code_size, "%s", reply + 4);
            return gs_fail(err_status(reply + 4), "acam link: %s -> %s", cmd, reply);
        }
        if (!strncmp(reply, "OK ", 3)) {
            size_t n = strlen(expect);
            if (strncmp(reply + 3, expect, n) || (reply[3 + n] != '\0' && reply[3 + n] != ' '))
                return gs_fail(GS_EFORMAT, "acam link: %s -> unexpected reply '%s'", cmd, reply);
            return GS_OK;
        }
        /* "D ..." or "EV ..." from an exposure: not ours */
    }
}

/* "key=value" of a reply as text ("" if absent). */
static void field_text(const char *line, const char *key, char *out, size_t size)
{
    char pat[24];
    snprintf(pat, sizeof pat, " %s=", key);
    const char *p = strstr(line, pat);
    size_t n = 0;
    if (p) {
        p += strlen(pat);
        while (p[n] && p[n] != ' ') n++;
    }
    if (n >= size) n = size - 1;
    if (p) memcpy(out, p, n);
    out[n] = '\0';
}

#define LINK_U32_MAX 4294967295L /* the firmware's numbers are uint32_t (fw_out_u32) */
#define LINK_U8_MAX 255L         /* and its STATUS lock, grid, K and k bytes */

/* text[0..len) as a number the way the firmware writes one (decimal digits only), at most max;
 * -1 if it is not one. */
static long decimal(const char *text, size_t len, long max)
{
    if (!len || len > 10) return -1;
    long x = 0;
    for (size_t i = 0; i < len; i++) {
        if (text[i] < '0' || text[i] > '9') return -1;
        x = 10 * x + (text[i] - '0');
    }
    return x <= max ? x : -1;
}

/* "key=<number>" of a reply, at most max; GS_EFORMAT if absent or not such a number. */
static gs_status field_long(const char *line, const char *key, long max, long *v)
{
    char text[24];
    field_text(line, key, text, sizeof text);
    long x = decimal(text, strlen(text), max);
    if (x < 0)
        return gs_fail(GS_EFORMAT, "acam link: '%s': field %s: expected an integer 0..%ld", line,
                       key, max);
    *v = x;
    return GS_OK;
}

/* ------------------------------------------------------------------ public */

gs_status cap_link_open_fd(int fd, cap_link **out)
{
    *out = NULL;
    if (fd < 0) return gs_fail(GS_EINVAL, "acam link: no descriptor");
    if (isatty(fd)) {
        struct termios tio;
        if (tcgetattr(fd, &tio) != 0) {
            int e = errno;
            close(fd);
            return gs_fail(GS_EIO, "acam link: tcgetattr: %s", strerror(e));
        }
        cfmakeraw(&tio); /* 8 data bits, no parity, no echo, no line editing */
        tio.c_cflag &= (tcflag_t)~(CSTOPB | CRTSCTS);
        tio.c_cflag |= CLOCAL | CREAD;
        tio.c_cc[VMIN] = 0;
        tio.c_cc[VTIME] = 0;
        cfsetispeed(&tio, B115200);
        cfsetospeed(&tio, B115200);
        if (tcsetattr(fd, TCSANOW, &tio) != 0) {
            int e = errno;
            close(fd);
            return gs_fail(GS_EIO, "acam link: tcsetattr: %s", strerror(e));
        }
    }
    cap_link *l = calloc(1, sizeof *l);
    if (!l) {
        close(fd);
        return gs_fail(GS_ENOMEM, "acam link: out of memory");
    }
    l->fd = fd;
    struct stat st;
    l->is_socket = fstat(fd, &st) == 0 && S_ISSOCK(st.st_mode);
    l->timeout_ms = 1000;
    *out = l;
    return GS_OK;
}

gs_status cap_link_open(const char *path, cap_link **out)
{
    *out = NULL;
    int fd = open(path, O_RDWR | O_NOCTTY | O_CLOEXEC);
    if (fd < 0) return gs_fail(GS_EIO, "acam link: open %s: %s", path, strerror(errno));
    gs_status s = cap_link_open_fd(fd, out);
    if (s != GS_OK) return gs_fail(s, "%s: %s", path, gs_detail());
    return GS_OK;
}

void cap_link_close(cap_link *l)
{
    if (!l) return;
    close(l->fd);
    free(l);
}

void cap_link_set_timeout_ms(cap_link *l, int timeout_ms)
{
    l->timeout_ms = timeout_ms >= 1 ? timeout_ms : 1;
}

gs_status cap_link_ping(cap_link *l)
{
    char reply[LINK_LINE_MAX];
    return command(l, "PING", "PING", reply, NULL, 0);
}

gs_status cap_link_configure(cap_link *l, const cap_link_config *c)
{
    if (c->K < 2 || c->K > 26 || c->k < 0 || c->k >= c->K || c->cycles < 1 ||
        c->cycles > 1000000 || (c->mode != CAP_LOCKED && c->mode != CAP_FREE_RUNNING))
        return gs_fail(GS_EINVAL,
                       "acam link: configuration K=%d k=%d C=%ld: expected 2 <= K <= 26, "
                       "0 <= k < K, 1 <= C <= 1000000",
                       c->K, c->k, c->cycles);
    char cmd[64], reply[LINK_LINE_MAX];
    snprintf(cmd, sizeof cmd, "CFG %d %d %ld %c", c->K, c->k, c->cycles,
             c->mode == CAP_LOCKED ? 'L' : 'F');
    return command(l, cmd, "CFG", reply, NULL, 0);
}

gs_status cap_link_start(cap_link *l)
{
    char reply[LINK_LINE_MAX];
    return command(l, "START", "START", reply, NULL, 0);
}

gs_status cap_link_stop(cap_link *l, long *cycles_done)
{
    char reply[LINK_LINE_MAX];
    gs_status s = command(l, "STOP", "STOP", reply, NULL, 0);
    long n = 0;
    if (s == GS_OK) s = field_long(reply, "cycles", LINK_U32_MAX, &n);
    if (s == GS_OK && cycles_done) *cycles_done = n;
    return s;
}

gs_status cap_link_get_status(cap_link *l, cap_link_status *st)
{
    char reply[LINK_LINE_MAX], mode[4];
    memset(st, 0, sizeof *st);
    gs_status s = command(l, "STATUS", "STATUS", reply, NULL, 0);
    if (s != GS_OK) return s;
    long lock, grid, done, C, K, k, half_ns;
    if ((s = field_long(reply, "lock", LINK_U8_MAX, &lock)) != GS_OK ||
        (s = field_long(reply, "grid", LINK_U8_MAX, &grid)) != GS_OK ||
        (s = field_long(reply, "cycles", LINK_U32_MAX, &done)) != GS_OK ||
        (s = field_long(reply, "C", LINK_U32_MAX, &C)) != GS_OK ||
        (s = field_long(reply, "K", LINK_U8_MAX, &K)) != GS_OK ||
        (s = field_long(reply, "k", LINK_U8_MAX, &k)) != GS_OK ||
        (s = field_long(reply, "half_ns", LINK_U32_MAX, &half_ns)) != GS_OK)
        return s;
    field_text(reply, "state", st->state, sizeof st->state);
    field_text(reply, "fault", st->fault, sizeof st->fault);
    field_text(reply, "last", st->last_event, sizeof st->last_event);
    field_text(reply, "mode", mode, sizeof mode);
    if (!st->state[0] || !st->fault[0] || (strcmp(mode, "L") && strcmp(mode, "F")))
        return gs_fail(GS_EFORMAT, "acam link: STATUS -> '%s'", reply);
    st->locked = lock != 0;
    st->grid_hz = (int)grid;
    st->cycles_done = done;
    st->cycles = C;
    st->K = (int)K;
    st->k = (int)k;
    st->mode = mode[0] == 'L' ? CAP_LOCKED : CAP_FREE_RUNNING;
    st->half_period_s = (double)half_ns * 1e-9;
    return GS_OK;
}

gs_status cap_link_cycle_count(cap_link *l, long *cycles_done)
{
    char reply[LINK_LINE_MAX];
    gs_status s = command(l, "COUNT", "COUNT", reply, NULL, 0);
    if (s != GS_OK) return s;
    long n = reply[8] ? decimal(reply + 9, strlen(reply + 9), LINK_U32_MAX) : -1;
    if (n < 0)
        return gs_fail(GS_EFORMAT, "acam link: COUNT -> '%s'", reply);
    *cycles_done = n;
    return GS_OK;
}

void cap_exposure_log_release(cap_exposure_log *log)
{
    if (!log) return;
    free(log->half_period_s);
    memset(log, 0, sizeof *log);
}

gs_status cap_link_expose(cap_link *l, const cap_link_config *c, cap_exposure_log *log)
{
    memset(log, 0, sizeof *log);
    gs_status s = cap_link_configure(l, c);
    if (s != GS_OK) return s;
    log->half_period_s = calloc((size_t)c->cycles, sizeof *log->half_period_s);
    if (!log->half_period_s) return gs_fail(GS_ENOMEM, "acam link: out of memory");

    /* START, waiting for the lock if the firmware has just seen a disturbance */
    double lock_deadline = now_ms() + CAP_LINK_LOCK_WAIT_MS;   /* (64 half periods = 0.64 s) */
    char reply[LINK_LINE_MAX], code[16];
    for (;;) {
        code[0] = '\0';
        s = command(l, "START", "START", reply, code, sizeof code);
        if (s == GS_OK) break;
        if (strcmp(code, "NOLOCK") || now_ms() > lock_deadline) return s;
        struct timespec ts = {0, LINK_LOCK_RETRY_MS * 1000000L};
        nanosleep(&ts, NULL);
    }

    /* EV START, one "D n half_ns" per cycle in order, EV DONE (or EV FAULT) */
    char line[LINK_LINE_MAX];
    int started = 0;
    for (;;) {
        s = read_line(l, line, now_ms() + l->timeout_ms);
        if (s == GS_EIO)
            return gs_fail(GS_EIO, "acam link: exposure: silent after %zu of %ld cycles (%s)",
                           log->cycles, c->cycles, gs_detail());
        if (s != GS_OK) return s;
        if (!strncmp(line, "EV START", 8)) {
            long grid, half_ns;
            if ((s = field_long(line, "grid", LINK_U8_MAX, &grid)) != GS_OK ||
                (s = field_long(line, "half_ns", LINK_U32_MAX, &half_ns)) != GS_OK)
                return s;
            log->grid_hz = (int)grid;
            log->start_half_period_s = (double)half_ns * 1e-9;
            started = 1;
        } else if (line[0] == 'D' && line[1] == ' ') {
            /* "D <n> <half period, ns>" */
            const char *sp = strchr(line + 2, ' ');
            long n = sp ? decimal(line + 2, (size_t)(sp - line - 2), LINK_U32_MAX) : -1;
            long ns = sp ? decimal(sp + 1, strlen(sp + 1), LINK_U32_MAX) : -1;
            if (n < 0 || ns < 0)
                return gs_fail(GS_EFORMAT, "acam link: exposure: bad data line '%s'", line);
            if (!started || n != (long)log->cycles || n >= c->cycles)
                return gs_fail(GS_EFORMAT,
                               "acam link: exposure: line '%s' out of order (expected cycle %zu)",
                               line, log->cycles);
            log->half_period_s[log->cycles++] = (double)ns * 1e-9;
        } else if (!strncmp(line, "EV DONE", 7)) {
            if (log->cycles != (size_t)c->cycles)
                return gs_fail(GS_EFORMAT, "acam link: exposure: DONE after %zu of %ld cycles",
                               log->cycles, c->cycles);
            return GS_OK;
        } else if (!strncmp(line, "EV FAULT ", 9)) {
            size_t n = strcspn(line + 9, " ");
            if (n >= sizeof log->fault) n = sizeof log->fault - 1;
            memcpy(log->fault, line + 9, n);
            log->fault[n] = '\0';
            gs_status fs = !strcmp(log->fault, "FREQ") || !strcmp(log->fault, "LIMIT")
                               ? GS_ELIMIT
                               : GS_EIO;
            return gs_fail(fs, "acam link: exposure stopped by the firmware after %zu of %ld "
                               "cycles: %s", log->cycles, c->cycles, line);
        }
        /* other lines (a late reply, EV BOOT) are not part of the exposure */
    }
}
