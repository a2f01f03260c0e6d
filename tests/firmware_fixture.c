/* firmware_fixture.c - the firmware ELF in libsimavr for the simavr tests; the contract is in
 * tests/firmware_fixture.h. simavr's headers come by their /usr/include/simavr/ path (it is a
 * system include directory, so they are not held to -Wpedantic). */
#include "tests/firmware_fixture.h"

#include "recognize/recognize.h"
#include "tests/test.h"

#include <simavr/avr_ioport.h>
#include <simavr/avr_uart.h>
#include <simavr/sim_cycle_timers.h>

#include <errno.h>
#include <fcntl.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

static const char *firmware_elf(void)
{
    const char *e = getenv("GS_FIRMWARE_ELF");
    return e && *e ? e : fw_elf_default;
}

static void u64vec_push(u64vec *a, uint64_t x)
{
    if (a->n == a->cap) {
        a->cap = a->cap ? 2 * a->cap : 1024;
        uint64_t *nv = realloc(a->v, a->cap * sizeof *nv);
        if (!nv) abort();
        a->v = nv;
    }
    a->v[a->n++] = x;
}

static void u64vec_free(u64vec *a)
{
    free(a->v);
    a->v = NULL;
    a->n = a->cap = 0;
}

long u64vec_last_le(const u64vec *a, uint64_t x)
{
    long lo = 0, hi = (long)a->n - 1, r = -1;
    while (lo <= hi) {
        long mid = (lo + hi) / 2;
        if (a->v[mid] <= x) {
            r = mid;
            lo = mid + 1;
        } else {
            hi = mid - 1;
        }
    }
    return r;
}

/* ------------------------------------------------------------------ the simulation */

static void quiet_logger(avr_t *avr, const int level, const char *fmt, va_list ap)
{
    (void)avr;
    (void)level;
    (void)fmt;
    (void)ap;
}

/* simavr's raw sleep callback paces the simulation to the wall clock; we want it as fast as
 * it goes (the cycle count advances all the same). */
static void no_sleep(avr_t *avr, avr_cycle_count_t how_long)
{
    (void)avr;
    (void)how_long;
}

static avr_cycle_count_t edge_timer(avr_t *avr, avr_cycle_count_t when, void *param)
{
    fwsim *s = param;
    (void)when;
    s->level ^= 1u;
    u64vec_push(&s->applied, avr->cycle);
    avr_raise_irq(s->icp_irq, s->level);
    s->next_edge++;
    if (s->next_edge >= s->n_edges) return 0;
    uint64_t next = s->edges[s->next_edge];
    return next > avr->cycle ? next : avr->cycle + 1;
}

/* Pin hooks fire on DDR writes and unchanged values too: record level changes only. */
static void trig_hook(avr_irq_t *irq, uint32_t value, void *param)
{
    fwsim *s = param;
    (void)irq;
    uint8_t v = value & 1u;
    if (v == s->trig_level) return;
    s->trig_level = v;
    u64vec_push(v ? &s->trig_rise : &s->trig_fall, s->avr->cycle);
}

static void shut_hook(avr_irq_t *irq, uint32_t value, void *param)
{
    fwsim *s = param;
    (void)irq;
    uint8_t v = value & 1u;
    if (v == s->shut_level) return;
    s->shut_level = v;
    u64vec_push(v ? &s->shut_rise : &s->shut_fall, s->avr->cycle);
}

static int hexval(char c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

/* A firmware line "payload*HH": strips and checks the checksum (upper-case hex, XOR). */
static int strip_checksum(char *line)
{
    size_t n = strlen(line);
    if (n < 3 || line[n - 3] != '*') return -1;
    int hi = hexval(line[n - 2]), lo = hexval(line[n - 1]);
    if (hi < 0 || lo < 0) return -1;
    unsigned x = 0;
    for (size_t i = 0; i + 3 < n; i++) x ^= (unsigned char)line[i];
    if (x != (unsigned)(hi * 16 + lo)) return -1;
    line[n - 3] = '\0';
    return 0;
}

static void uart_out_hook(avr_irq_t *irq, uint32_t value, void *param)
{
    fwsim *s = param;
    (void)irq;
    char c = (char)value;
    if (s->pty_fd >= 0) {
        ssize_t w = write(s->pty_fd, &c, 1);
        (void)w;
    }
    if (c != '\n') {
        if (s->cur_len + 1 < sizeof s->cur) s->cur[s->cur_len++] = c;
        else s->bad_lines++;
        return;
    }
    s->cur[s->cur_len] = '\0';
    s->cur_len = 0;
    if (strip_checksum(s->cur) != 0) {
        s->bad_lines++;
        return;
    }
    if (s->n_lines == s->cap_lines) {
        s->cap_lines = s->cap_lines ? 2 * s->cap_lines : 256;
        simline *nl = realloc(s->lines, s->cap_lines * sizeof *nl);
        if (!nl) abort();
        s->lines = nl;
    }
    snprintf(s->lines[s->n_lines].text, LINE_MAX_CHARS, "%s", s->cur);
    s->lines[s->n_lines].cycle = s->avr->cycle;
    s->n_lines++;
}

static avr_cycle_count_t uart_in_timer(avr_t *avr, avr_cycle_count_t when, void *param)
{
    fwsim *s = param;
    (void)when;
    if (s->in_tail == s->in_head) {
        s->in_timer = 0;
        return 0;
    }
    avr_raise_irq(s->uart_in, (uint8_t)s->in[s->in_tail]);
    s->in_tail = (s->in_tail + 1) % sizeof s->in;
    if (s->in_tail == s->in_head) {
        s->in_timer = 0;
        return 0;
    }
    return avr->cycle + CHAR_CYCLES;
}

void fwsim_send_bytes(fwsim *s, const char *bytes, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        size_t next = (s->in_head + 1) % sizeof s->in;
        if (next == s->in_tail) break; /* full: dropped (never in these tests) */
        s->in[s->in_head] = bytes[i];
        s->in_head = next;
    }
    if (!s->in_timer && s->in_head != s->in_tail) {
        s->in_timer = 1;
        avr_cycle_timer_register(s->avr, CHAR_CYCLES, uart_in_timer, s);
    }
}

void fwsim_send(fwsim *s, const char *text)
{
    fwsim_send_bytes(s, text, strlen(text));
    fwsim_send_bytes(s, "\n", 1);
}

fwsim *fwsim_new(const uint64_t *edges, size_t n_edges, int rising_first)
{
    avr_global_logger_set(quiet_logger);
    fwsim *s = calloc(1, sizeof *s);
    elf_firmware_t *fw = calloc(1, sizeof *fw);
    if (!s || !fw) abort();
    s->fw = fw;
    s->pty_fd = -1;
    if (elf_read_firmware(firmware_elf(), fw) != 0) {
        CHECK_MSG(0, "cannot read the firmware ELF %s (make firmware)", firmware_elf());
        free(fw);
        free(s);
        return NULL;
    }
    CHECK_MSG(strcmp(fw->mmcu, "atmega328p") == 0, "ELF names mcu '%s'", fw->mmcu);
    CHECK_MSG(fw->frequency == 16000000u, "ELF names F_CPU %u", (unsigned)fw->frequency);
    s->avr = avr_make_mcu_by_name(fw->mmcu);
    if (!s->avr) {
        CHECK_MSG(0, "simavr does not know %s", fw->mmcu);
        free(fw);
        free(s);
        return NULL;
    }
    avr_init(s->avr);
    avr_load_firmware(s->avr, fw);
    /* paint the RAM above .data and .bss: what the stack never reached keeps the pattern */
    for (uint32_t a = RAM_START + fw->datasize + fw->bsssize; a <= s->avr->ramend; a++)
        s->avr->data[a] = STACK_PAINT;
    s->avr->sleep = no_sleep;
    s->avr->log = LOG_NONE;
    uint32_t uflags = 0; /* no usleep() on polled reads, no console echo */
    avr_ioctl(s->avr, AVR_IOCTL_UART_SET_FLAGS('0'), &uflags);

    s->icp_irq = avr_io_getirq(s->avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 0);
    avr_irq_register_notify(avr_io_getirq(s->avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 1), trig_hook,
                            s);
    avr_irq_register_notify(avr_io_getirq(s->avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 2), shut_hook,
                            s);
    avr_irq_register_notify(avr_io_getirq(s->avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                            uart_out_hook, s);
    s->uart_in = avr_io_getirq(s->avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);

    s->level = rising_first ? 0 : 1;
    avr_raise_irq(s->icp_irq, s->level);
    s->edges = edges;
    s->n_edges = n_edges;
    if (n_edges) avr_cycle_timer_register(s->avr, edges[0], edge_timer, s);
    return s;
}

long fwsim_stack_margin(const fwsim *s)
{
    uint32_t end = RAM_START + s->fw->datasize + s->fw->bsssize, a = end;
    while (a <= s->avr->ramend && s->avr->data[a] == STACK_PAINT) a++;
    return (long)a - (long)end;
}

void fwsim_free(fwsim *s)
{
    if (!s) return;
    avr_terminate(s->avr);
    u64vec_free(&s->applied);
    u64vec_free(&s->trig_rise);
    u64vec_free(&s->trig_fall);
    u64vec_free(&s->shut_rise);
    u64vec_free(&s->shut_fall);
    free(s->lines);
    free(s->fw);
    free(s);
}

int fwsim_run_until(fwsim *s, uint64_t until)
{
    while (s->avr->cycle < until) {
        int st = avr_run(s->avr);
        if (st == cpu_Done || st == cpu_Crashed) {
            CHECK_MSG(0, "the AVR core stopped (state %d) at cycle %llu", st,
                      (unsigned long long)s->avr->cycle);
            return -1;
        }
    }
    return 0;
}

long fwsim_wait_line(fwsim *s, size_t from, const char *prefix, uint64_t max_cycles)
{
    uint64_t end = s->avr->cycle + max_cycles;
    size_t seen = from;
    for (;;) {
        for (; seen < s->n_lines; seen++)
            if (strncmp(s->lines[seen].text, prefix, strlen(prefix)) == 0) return (long)seen;
        if (s->avr->cycle >= end) return -1;
        if (fwsim_run_until(s, s->avr->cycle + 1600) != 0) return -1; /* 100 us steps */
    }
}

const char *fwsim_cmd(fwsim *s, const char *cmd)
{
    size_t from = s->n_lines;
    fwsim_send(s, cmd);
    uint64_t end = s->avr->cycle + (uint64_t)(0.2 * CYCLES_PER_S);
    size_t seen = from;
    for (;;) {
        for (; seen < s->n_lines; seen++) {
            const char *t = s->lines[seen].text;
            if (strncmp(t, "OK ", 3) == 0 || strncmp(t, "ERR ", 4) == 0) return t;
        }
        if (s->avr->cycle >= end || fwsim_run_until(s, s->avr->cycle + 1600) != 0) break;
    }
    CHECK_MSG(0, "no reply to '%s'", cmd);
    return "";
}

double fw_field(const char *line, const char *key)
{
    char pat[32];
    snprintf(pat, sizeof pat, " %s=", key);
    const char *p = strstr(line, pat);
    return p ? strtod(p + strlen(pat), NULL) : NAN;
}

/* ------------------------------------------------------------------ crossing traces */

void trace_free(trace *t)
{
    free(t->edges);
    t->edges = NULL;
    t->n = 0;
}

int trace_from_mains(const char *rel, size_t max_crossings, trace *out)
{
    double *x = NULL, rate = 0, *t = NULL;
    size_t n = 0, count = 0;
    int rising_first = 0;
    memset(out, 0, sizeof *out);
    CHECK_OK(gs_mains_read(test_shared_path(rel), &x, &n, &rate));
    if (!x) return -1;
    double ss = 0;
    for (size_t i = 0; i < n; i++) ss += x[i] * x[i];
    double hysteresis = 0.1 * sqrt(ss / (double)n); /* a tenth of the RMS */
    CHECK_OK(gs_zero_crossings(x, n, rate, hysteresis, &t, &count, &rising_first));
    free(x);
    if (!t || count < 100) {
        free(t);
        return -1;
    }
    if (max_crossings && count > max_crossings) count = max_crossings;
    out->edges = malloc(count * sizeof *out->edges);
    if (!out->edges) abort();
    for (size_t i = 0; i < count; i++)
        out->edges[i] = LEAD_CYCLES + (uint64_t)llround((t[i] - t[0]) * CYCLES_PER_S);
    out->n = count;
    out->rising_first = rising_first;
    free(t);
    return 0;
}

void trace_synthetic(double f0, double a_hz, double period_s, double ramp_hz_per_s,
                            double asym_us, size_t count, trace *out)
{
    const double pi = 3.14159265358979323846;
    out->edges = malloc(count * sizeof *out->edges);
    if (!out->edges) abort();
    out->n = count;
    out->rising_first = 1;
    double t = 0;
    for (size_t i = 0; i < count; i++) {
        double target = (double)(i + 1) / 2.0; /* in cycles of the AC */
        for (int it = 0; it < 8; it++) {
            double w = 2 * pi * t / period_s;
            double ph = f0 * t + a_hz * period_s / (2 * pi) * (1 - cos(w)) +
                        ramp_hz_per_s * t * t / 2;
            double f = f0 + a_hz * sin(w) + ramp_hz_per_s * t;
            t -= (ph - target) / f;
        }
        /* odd crossings fall: delaying them lengthens the positive half periods */
        double shift = (i % 2 == 1) ? asym_us * 1e-6 : 0;
        out->edges[i] = LEAD_CYCLES + (uint64_t)llround((t + shift) * CYCLES_PER_S);
        t += 0.5 / (f0 + a_hz * sin(2 * pi * t / period_s) + ramp_hz_per_s * t); /* next guess */
    }
}

long fwsim_start_exposure(fwsim *s, int K, int k, long C, char mode)
{
    if (fwsim_run_until(s, s->avr->cycle + (uint64_t)(0.8 * CYCLES_PER_S)) != 0) return -1;
    char cmd[64];
    snprintf(cmd, sizeof cmd, "CFG %d %d %ld %c", K, k, C, mode);
    const char *r = fwsim_cmd(s, cmd);
    CHECK_MSG(strncmp(r, "OK CFG", 6) == 0, "%s -> %s", cmd, r);
    size_t from = s->n_lines;
    r = fwsim_cmd(s, "START");
    CHECK_MSG(strcmp(r, "OK START") == 0, "START -> %s", r);
    if (strcmp(r, "OK START") != 0) return -1;
    long ev = fwsim_wait_line(s, from, "EV START", (uint64_t)(0.1 * CYCLES_PER_S));
    CHECK_MSG(ev >= 0, "no EV START");
    return ev;
}

long fwsim_start_crossing(const fwsim *s)
{
    return s->shut_rise.n ? u64vec_last_le(&s->applied, s->shut_rise.v[0]) + 1 : -1;
}

long fwsim_wait_done(fwsim *s, size_t from, long C, int status_every)
{
    uint64_t end = s->avr->cycle + (uint64_t)((double)(C + 50) / 94.0 * CYCLES_PER_S);
    long done = -1;
    size_t next_status = status_every > 0 ? (size_t)status_every : (size_t)-1;
    while (done < 0 && s->avr->cycle < end) {
        done = fwsim_wait_line(s, from, "EV DONE", (uint64_t)(0.05 * CYCLES_PER_S));
        long f = fwsim_wait_line(s, from, "EV FAULT", 0);
        if (f >= 0) {
            CHECK_MSG(0, "exposure fault: %s", s->lines[f].text);
            return -1;
        }
        if (done < 0 && s->trig_rise.n / 2 >= next_status) {
            const char *st = fwsim_cmd(s, "STATUS");
            CHECK_MSG(strstr(st, "state=EXPOSING") || strstr(st, "state=DONE"), "%s", st);
            next_status += (size_t)status_every;
        }
    }
    CHECK_MSG(done >= 0, "no EV DONE after %ld cycles", C);
    if (done < 0) return -1;
    CHECK_MSG(fw_field(s->lines[done].text, "cycles") == (double)C, "%s", s->lines[done].text);
    CHECK(s->shut_rise.n == 1 && s->shut_fall.n == 1 && s->shut_level == 0);
    return fwsim_start_crossing(s);
}

long fwsim_run_exposure(fwsim *s, int K, int k, long C, char mode, int status_every)
{
    long ev = fwsim_start_exposure(s, K, k, C, mode);
    return ev < 0 ? -1 : fwsim_wait_done(s, (size_t)ev, C, status_every);
}

void fw_bridge_child(int master, const trace *tr, int report_fd)
{
    fwsim *s = fwsim_new(tr->edges, tr->n, tr->rising_first);
    if (!s) _exit(3);
    s->pty_fd = master;
    fcntl(master, F_SETFL, fcntl(master, F_GETFL) | O_NONBLOCK);
    struct timespec t0, t1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    size_t scanned = 0;
    for (;;) {
        if (fwsim_run_until(s, s->avr->cycle + 16000) != 0) _exit(4); /* 1 ms */
        for (; report_fd >= 0 && scanned < s->n_lines; scanned++) {
            const char *t = s->lines[scanned].text;
            if (strncmp(t, "EV DONE", 7) != 0 || !s->shut_rise.n) continue;
            /* the shutter pin rises at START; the exposure starts at the next crossing */
            fw_bridge_report r = {
                u64vec_last_le(&s->applied, s->shut_rise.v[s->shut_rise.n - 1]) + 1,
                (long)fw_field(t, "cycles")};
            if (write(report_fd, &r, sizeof r) != (ssize_t)sizeof r) _exit(6);
        }
        char buf[256];
        ssize_t r = read(master, buf, sizeof buf);
        if (r > 0) fwsim_send_bytes(s, buf, (size_t)r);
        else if (r == 0 || (errno != EAGAIN && errno != EINTR)) break; /* EIO: slave closed */
        clock_gettime(CLOCK_MONOTONIC, &t1);
        double wall = (double)(t1.tv_sec - t0.tv_sec) + 1e-9 * (double)(t1.tv_nsec - t0.tv_nsec);
        if ((double)s->avr->cycle / CYCLES_PER_S > 20.0 * wall + 0.5) usleep(1000);
        if (s->next_edge >= s->n_edges) _exit(5); /* the mains ran out */
    }
    fwsim_free(s);
    _exit(0);
}
