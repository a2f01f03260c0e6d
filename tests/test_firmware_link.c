/* test_firmware_link.c - capture/'s host side of the ACam controller: the serial client against
 * a scripted device, then against the real firmware ELF in libsimavr (tests/firmware_fixture.h)
 * behind a pseudo-terminal, and the acquisition loop's hardware backend end to end with the fake
 * libgpiod (tests/fake_gpiod.h) replaying the same mains crossings. */
#include "capture/capture.h"
#include "tests/fake_gpiod.h"
#include "tests/firmware_fixture.h"
#include "tests/hw_fixture.h"
#include "tests/test.h"

#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <pty.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

/* ------------------------------------------------------------------ host client (capture/) */

/* Writes "payload*HH\n" (or payload as is when raw) to fd. */
static void script(int fd, const char *payload, int raw)
{
    char buf[256];
    unsigned x = 0;
    for (const char *p = payload; *p; p++) x ^= (unsigned char)*p;
    int n = raw ? snprintf(buf, sizeof buf, "%s\n", payload)
                : snprintf(buf, sizeof buf, "%s*%02X\n", payload, x);
    CHECK(write(fd, buf, (size_t)n) == n);
}

/* Reads what the client sent (non-blocking) into buf. */
static size_t sent(int fd, char *buf, size_t size)
{
    size_t used = 0;
    for (;;) {
        ssize_t r = recv(fd, buf + used, size - 1 - used, MSG_DONTWAIT);
        if (r <= 0) break;
        used += (size_t)r;
    }
    buf[used] = '\0';
    return used;
}

/* The client against a scripted device on a socket: replies, checksums, errors, the exposure
 * log and its faults. */
TEST(firmware_link_client_scripted)
{
    int sv[2];
    CHECK(socketpair(AF_UNIX, SOCK_STREAM, 0, sv) == 0);
    cap_link *l = NULL;
    CHECK_OK(cap_link_open_fd(sv[0], &l));
    if (!l) return;
    cap_link_set_timeout_ms(l, 200);
    char out[4096];

    script(sv[1], "OK PING", 0);
    CHECK_OK(cap_link_ping(l));
    sent(sv[1], out, sizeof out);
    CHECK_MSG(strcmp(out, "PING*10\n") == 0, "sent '%s'", out); /* P^I^N^G = 0x10 */
    script(sv[1], "OK PING*00", 1);
    CHECK(cap_link_ping(l) == GS_EFORMAT);
    script(sv[1], "OK PING", 1);
    CHECK(cap_link_ping(l) == GS_EFORMAT);
    CHECK(cap_link_ping(l) == GS_EIO); /* silence: the timeout */
    script(sv[1], "OK PONG", 0);
    CHECK(cap_link_ping(l) == GS_EFORMAT);
    sent(sv[1], out, sizeof out);

    cap_link_config c = {20, 3, 300, CAP_LOCKED};
    script(sv[1], "ERR RANGE", 0);
    CHECK(cap_link_configure(l, &c) == GS_EINVAL);
    sent(sv[1], out, sizeof out);
    CHECK_MSG(strncmp(out, "CFG 20 3 300 L*", 15) == 0, "sent '%s'", out);
    script(sv[1], "ERR LIMIT", 0);
    CHECK(cap_link_start(l) == GS_ELIMIT);
    script(sv[1], "ERR NOLOCK", 0);
    CHECK(cap_link_start(l) == GS_EIO);
    /* checked here, never sent */
    cap_link_config bad = {27, 3, 300, CAP_LOCKED};
    sent(sv[1], out, sizeof out);
    CHECK(cap_link_configure(l, &bad) == GS_EINVAL);
    bad = (cap_link_config){20, 20, 300, CAP_LOCKED};
    CHECK(cap_link_configure(l, &bad) == GS_EINVAL);
    bad = (cap_link_config){20, 3, 0, CAP_FREE_RUNNING};
    CHECK(cap_link_configure(l, &bad) == GS_EINVAL);
    CHECK(sent(sv[1], out, sizeof out) == 0);

    /* STATUS, with exposure lines in front of the reply */
    script(sv[1], "D 7 10000000", 0);
    script(sv[1], "OK STATUS state=EXPOSING lock=1 grid=50 cycles=7 C=300 K=20 k=3 mode=F "
                  "half_ns=10000500 fault=OK last=MISSING", 0);
    cap_link_status st;
    CHECK_OK(cap_link_get_status(l, &st));
    CHECK(!strcmp(st.state, "EXPOSING") && st.locked && st.grid_hz == 50 && st.cycles_done == 7);
    CHECK(st.cycles == 300 && st.K == 20 && st.k == 3 && st.mode == CAP_FREE_RUNNING);
    CHECK_NEAR(st.half_period_s, 10.0005e-3, 1e-12);
    CHECK(!strcmp(st.fault, "OK") && !strcmp(st.last_event, "MISSING"));
    script(sv[1], "OK STATUS state=IDLE lock=1", 0);
    CHECK(cap_link_get_status(l, &st) == GS_EFORMAT);
    script(sv[1], "OK COUNT 42", 0);
    long n = 0;
    CHECK_OK(cap_link_cycle_count(l, &n));
    CHECK(n == 42);
    script(sv[1], "OK STOP cycles=9", 0);
    CHECK_OK(cap_link_stop(l, &n));
    CHECK(n == 9);

    /* an exposure, after one NOLOCK */
    c = (cap_link_config){20, 3, 3, CAP_LOCKED};
    script(sv[1], "OK CFG K=20 k=3 C=3 mode=L", 0);
    script(sv[1], "ERR NOLOCK", 0);
    script(sv[1], "OK START", 0);
    script(sv[1], "EV START grid=50 mode=L half_ns=9999000", 0);
    script(sv[1], "D 0 10000500", 0);
    script(sv[1], "D 1 9999500", 0);
    script(sv[1], "D 2 10001000", 0);
    script(sv[1], "EV DONE cycles=3", 0);
    cap_exposure_log log;
    CHECK_OK(cap_link_expose(l, &c, &log));
    CHECK(log.cycles == 3 && log.grid_hz == 50 && log.fault[0] == '\0');
    CHECK_NEAR(log.start_half_period_s, 9.999e-3, 1e-12);
    CHECK_NEAR(log.half_period_s[1], 9.9995e-3, 1e-12);
    CHECK_NEAR(log.half_period_s[2], 10.001e-3, 1e-12);
    cap_exposure_log_release(&log);
    sent(sv[1], out, sizeof out);
    CHECK_MSG(strstr(out, "START*") && strstr(strstr(out, "START*") + 1, "START*"),
              "START not repeated after NOLOCK: '%s'", out);

    /* stopped by the firmware */
    static const struct {
        const char *fault;
        gs_status s;
    } faults[] = {{"SPURIOUS", GS_EIO}, {"MISSING", GS_EIO}, {"FREQ", GS_ELIMIT},
                  {"LIMIT", GS_ELIMIT}};
    for (size_t i = 0; i < 4; i++) {
        char ev[64];
        script(sv[1], "OK CFG K=20 k=3 C=3 mode=L", 0);
        script(sv[1], "OK START", 0);
        script(sv[1], "EV START grid=50 mode=L half_ns=9999000", 0);
        script(sv[1], "D 0 10000500", 0);
        snprintf(ev, sizeof ev, "EV FAULT %s cycle=1", faults[i].fault);
        script(sv[1], ev, 0);
        CHECK(cap_link_expose(l, &c, &log) == faults[i].s);
        CHECK(log.cycles == 1 && !strcmp(log.fault, faults[i].fault));
        cap_exposure_log_release(&log);
    }
    /* a hole in the log */
    script(sv[1], "OK CFG K=20 k=3 C=3 mode=L", 0);
    script(sv[1], "OK START", 0);
    script(sv[1], "EV START grid=50 mode=L half_ns=9999000", 0);
    script(sv[1], "D 0 10000500", 0);
    script(sv[1], "D 2 10000500", 0);
    CHECK(cap_link_expose(l, &c, &log) == GS_EFORMAT);
    cap_exposure_log_release(&log);
    /* the device goes away in the middle */
    script(sv[1], "OK CFG K=20 k=3 C=3 mode=L", 0);
    script(sv[1], "OK START", 0);
    script(sv[1], "D 0 10000500", 0); /* before EV START: out of order */
    CHECK(cap_link_expose(l, &c, &log) == GS_EFORMAT);
    cap_exposure_log_release(&log);
    close(sv[1]);
    CHECK(cap_link_ping(l) == GS_EIO);
    cap_link_close(l);
    cap_link_close(NULL);
    CHECK(cap_link_open("/nonexistent/tty", &l) == GS_EIO && l == NULL);
}

/* Found by tests/fuzz/fuzz_link.c (tests/fuzz/crashes/link/): a data line's half period of
 * 2^64 - 1 ns (strtoul's saturation) was logged as 1.8e10 s, and "-5" wrapped to the same. The
 * firmware writes every number as a uint32_t in plain digits (firmware/main.c, fw_out_u32), the
 * STATUS bytes at most 255: anything else is refused (GS_EFORMAT), whatever the field. */
TEST(firmware_link_half_period_beyond_u32)
{
    static const char *const bad_d[] = {"D 0 4294967296", "D 0 -5", "D 0 18446744073709551615",
                                        "D 0 +10000500", "D 0  10000500", "D -0 10000500"};
    cap_link_config c = {4, 1, 2, CAP_LOCKED};
    for (size_t i = 0; i <= sizeof bad_d / sizeof *bad_d; i++) {
        int sv[2];
        CHECK(socketpair(AF_UNIX, SOCK_STREAM, 0, sv) == 0);
        cap_link *l = NULL;
        CHECK_OK(cap_link_open_fd(sv[0], &l));
        if (!l) return;
        script(sv[1], "OK CFG K=4 k=1 C=2 mode=L", 0);
        script(sv[1], "OK START", 0);
        script(sv[1], "EV START grid=50 mode=L half_ns=9999000", 0);
        script(sv[1], i < sizeof bad_d / sizeof *bad_d ? bad_d[i] : "D 0 4294967295", 0);
        script(sv[1], "D 1 10000500", 0);
        script(sv[1], "EV DONE cycles=2", 0);
        cap_exposure_log log;
        gs_status s = cap_link_expose(l, &c, &log);
        if (i < sizeof bad_d / sizeof *bad_d) {
            CHECK_MSG(s == GS_EFORMAT && log.cycles == 0, "'%s' -> %s, %zu cycles", bad_d[i],
                      gs_strerror(s), log.cycles);
        } else { /* the largest the firmware can write: 4.294967295 s */
            CHECK_OK(s);
            CHECK(log.cycles == 2);
            if (log.cycles == 2) CHECK_NEAR(log.half_period_s[0], 4.294967295, 1e-12);
        }
        cap_exposure_log_release(&log);
        cap_link_close(l);
        close(sv[1]);
    }
    /* the same rule for the replies' fields */
    static const struct {
        const char *reply;
        int what; /* 0 STATUS, 1 COUNT, 2 STOP */
    } bad[] = {
        {"OK STATUS state=IDLE lock=1 grid=50 cycles=0 C=5 K=4294967298 k=1 mode=L half_ns=0 "
         "fault=OK last=OK", 0},
        {"OK STATUS state=IDLE lock=1 grid=306 cycles=0 C=5 K=4 k=1 mode=L half_ns=0 "
         "fault=OK last=OK", 0},
        {"OK STATUS state=IDLE lock=1 grid=50 cycles=0 C=5 K=4 k=1 mode=L half_ns=-1 "
         "fault=OK last=OK", 0},
        {"OK COUNT -1", 1}, {"OK COUNT 4294967296", 1}, {"OK COUNT", 1}, {"OK COUNT  7", 1},
        {"OK STOP cycles=+3", 2}, {"OK STOP cycles=99999999999", 2},
    };
    int sv[2];
    CHECK(socketpair(AF_UNIX, SOCK_STREAM, 0, sv) == 0);
    cap_link *l = NULL;
    CHECK_OK(cap_link_open_fd(sv[0], &l));
    if (!l) return;
    for (size_t i = 0; i < sizeof bad / sizeof *bad; i++) {
        script(sv[1], bad[i].reply, 0);
        cap_link_status st;
        long n;
        gs_status s = bad[i].what == 0   ? cap_link_get_status(l, &st)
                      : bad[i].what == 1 ? cap_link_cycle_count(l, &n)
                                         : cap_link_stop(l, &n);
        CHECK_MSG(s == GS_EFORMAT, "'%s' -> %s", bad[i].reply, gs_strerror(s));
    }
    script(sv[1], "OK COUNT 4294967295", 0);
    long n = 0;
    CHECK_OK(cap_link_cycle_count(l, &n));
    CHECK(n == 4294967295L);
    cap_link_close(l);
    close(sv[1]);
}

/* Does log match the half periods of the trace somewhere (within one 0.5 us tick and the
 * injection's few cycles)? Returns the crossing index of cycle 0, or -1. */
static long find_in_trace(const trace *tr, const cap_exposure_log *log)
{
    for (size_t s0 = 0; s0 + log->cycles + 1 < tr->n; s0++) {
        size_t n = 0;
        for (; n < log->cycles; n++) {
            double truth = (double)(tr->edges[s0 + n + 1] - tr->edges[s0 + n]) / CYCLES_PER_S;
            if (fabs(log->half_period_s[n] - truth) > 0.8e-6) break;
        }
        if (n == log->cycles) return (long)s0;
    }
    return -1;
}

/* A pseudo-terminal made raw before any byte flows (no echo of the firmware's lines); its
 * slave's name in name (NULL: not wanted). 0, or -1. */
static int open_raw_pty(int *master, int *slave, char *name)
{
    if (openpty(master, slave, name, NULL, NULL) != 0) return -1;
    struct termios tio;
    tcgetattr(*slave, &tio);
    cfmakeraw(&tio);
    tcsetattr(*slave, TCSANOW, &tio);
    return 0;
}

/* The bridge child ends by itself, with status 0, within 5 s of its slave side closing (it is
 * killed after that). */
static void reap_bridge(pid_t pid)
{
    int st = 0;
    pid_t w = 0;
    for (int i = 0; i < 500 && w == 0; i++) {
        w = waitpid(pid, &st, WNOHANG);
        if (w == 0) usleep(10000);
    }
    if (w == 0) {
        kill(pid, SIGKILL);
        waitpid(pid, &st, 0);
    }
    CHECK_MSG(w == pid && WIFEXITED(st) && WEXITSTATUS(st) == 0, "bridge exit %d",
              WIFEXITED(st) ? WEXITSTATUS(st) : -1);
}

/* End to end: capture/'s client drives the firmware in simavr through a pseudo-terminal; one
 * exposure of C cycles completes and its per-cycle log is the injected mains. */
TEST(firmware_link_pty_exposure_matches_trace)
{
    trace tr;
    if (trace_from_mains("data/mains/whu_003_ref.wav", 20000, &tr) != 0) return;
    int master = -1, slave = -1;
    char name[256];
    CHECK(open_raw_pty(&master, &slave, name) == 0);
    if (master < 0) return;
    fflush(stdout);
    pid_t pid = fork();
    if (pid == 0) {
        close(slave);
        fw_bridge_child(master, &tr, -1);
    }
    close(master);
    cap_link *l = NULL;
    CHECK_OK(cap_link_open(name, &l));
    close(slave);
    if (l) {
        cap_link_set_timeout_ms(l, 5000);
        CHECK_OK(cap_link_ping(l));
        cap_link_config c = {20, 3, 300, CAP_LOCKED};
        cap_exposure_log log;
        CHECK_OK(cap_link_expose(l, &c, &log));
        CHECK(log.cycles == 300 && log.grid_hz == 50);
        long at = log.cycles ? find_in_trace(&tr, &log) : -1;
        CHECK_MSG(at >= 64, "the log does not match the injected mains (at %ld)", at);
        double f_mean = 0;
        for (size_t i = 0; i < log.cycles; i++) f_mean += 1.0 / (2.0 * log.half_period_s[i]);
        printf("    pty: 300 cycles logged from crossing %ld, mean %.4f Hz\n", at,
               f_mean / (double)log.cycles);
        cap_exposure_log_release(&log);
        cap_link_status st;
        CHECK_OK(cap_link_get_status(l, &st));
        CHECK(!strcmp(st.state, "DONE") && st.cycles_done == 300 && st.grid_hz == 50);
        /* and free running through the same link */
        c = (cap_link_config){20, 10, 100, CAP_FREE_RUNNING};
        CHECK_OK(cap_link_expose(l, &c, &log));
        CHECK(log.cycles == 100 && find_in_trace(&tr, &log) >= 64);
        cap_exposure_log_release(&log);
        long n = 0;
        CHECK_OK(cap_link_cycle_count(l, &n));
        CHECK(n == 100);
        cap_link_close(l);
    }
    /* the child ends when the slave side closes */
    reap_bridge(pid);
    trace_free(&tr);
}

/* ------------------------------------------------------------------ capture loop, end to end */

#define E2E_K 4
#define E2E_C 50
#define E2E_W 16
#define E2E_H 12
#define E2E_GPIO_T0_S 1000.0 /* timestamp of the first crossing on the fake GPIO line */

static unsigned short e2e_pixel(int k, int x, int y, int b)
{
    return (unsigned short)(100 + 2000 * k + 37 * x + 11 * y + 500 * b);
}

/* The trace's first `count` crossings as a fake-GPIO event file (tests/fake_gpiod.h): the
 * same edges the simulation injects, in seconds from E2E_GPIO_T0_S, rising/falling in turn. */
static int e2e_write_events(const trace *tr, size_t count, const char *path)
{
    FILE *f = fopen(path, "w");
    if (!f || count > tr->n) {
        if (f) fclose(f);
        return -1;
    }
    for (size_t i = 0; i < count; i++) {
        long long ns = llround((double)(tr->edges[i] - tr->edges[0]) / CYCLES_PER_S * 1e9);
        long long sec = (long long)E2E_GPIO_T0_S + ns / 1000000000LL;
        int rising = (i % 2 == 0) == (tr->rising_first != 0);
        fprintf(f, "%lld %lld %d\n", sec, ns % 1000000000LL, rising ? 1 : 2);
    }
    fclose(f);
    return 0;
}

/* Mean half period (s) of the trace's half periods [from, from + n). */
static double trace_mean_half_s(const trace *tr, long from, long n)
{
    return (double)(tr->edges[from + n] - tr->edges[from]) / (double)n / CYCLES_PER_S;
}

/* Waits (at most timeout_ms) for one report of the bridge. 0, or -1. */
static int read_report(int fd, fw_bridge_report *r, int timeout_ms)
{
    struct pollfd p = {fd, POLLIN, 0};
    if (poll(&p, 1, timeout_ms) != 1) return -1;
    return read(fd, r, sizeof *r) == (ssize_t)sizeof *r ? 0 : -1;
}

/* End to end: the acquisition loop (cap_loop_run) with the hardware backend, whose controller is
 * the real firmware ELF in simavr behind a pseudo-terminal (the forked bridge), its GPIO the
 * fake libgpiod replaying the same mains crossings, its camera an image sequence. The loop runs
 * one frame at a time (stop_after = 1, then resumed) so that every acquisition's
 * cap_backend_hardware_log is seen: C cycles logged by the firmware, whose mean half period is
 * that of the injected crossings the exposure covered (reported by the bridge) within the
 * firmware's 0.5 us tick. */
TEST(firmware_hardware_backend_loop_e2e)
{
    struct timespec w0, w1;
    clock_gettime(CLOCK_MONOTONIC, &w0);
    const char *rec = "data/mains/whu_002_ref.wav";
    trace tr;
    if (trace_from_mains(rec, 20000, &tr) != 0) return;
    const char *tmp = test_tmpdir();
    char events[1024], out[1024];
    snprintf(events, sizeof events, "%s/zc.events", tmp);
    snprintf(out, sizeof out, "%s/capture", tmp);
    size_t n_events = (size_t)E2E_K * (E2E_C + 1) + 10;
    CHECK(e2e_write_events(&tr, n_events, events) == 0);
    CHECK(fake_gpiod_load_events(events, E2E_C + 1) == (int)n_events);
    size_t outputs0 = fake_gpiod_output_count(); /* the fake records across tests */
    const char *pattern = hw_fx_camera(E2E_K, E2E_W, E2E_H, e2e_pixel);

    int master = -1, slave = -1, rep[2] = {-1, -1};
    CHECK(open_raw_pty(&master, &slave, NULL) == 0);
    CHECK(pipe(rep) == 0);
    if (master < 0 || rep[0] < 0) {
        trace_free(&tr);
        return;
    }
    fflush(stdout);
    pid_t pid = fork();
    if (pid == 0) {
        close(slave);
        close(rep[0]);
        fw_bridge_child(master, &tr, rep[1]);
    }
    close(master);
    close(rep[1]);

    cap_hw_config hw;
    hw_fx_config(&hw, pattern, slave, E2E_K, E2E_C, E2E_W, E2E_H); /* the backend owns slave */
    hw.link_timeout_ms = 3000;
    hw.locked = 1;
    cap_backend *be = NULL;
    CHECK_OK(cap_backend_hardware_new(&hw, &be));
    long prev_end = -1;
    double err_max_ns = 0, gpio_link_max_us = 0;
    int acquired = 0;
    for (int k = 0; be && k < E2E_K; k++) {
        cap_loop_opts o;
        cap_loop_opts_default(&o);
        o.progress = 0;
        o.stop_after = 1;
        cap_loop_report r;
        gs_status st = cap_loop_run(be, out, &o, &r);
        CHECK_MSG(st == GS_OK, "frame %d: %s: %s", k, gs_strerror(st), gs_detail());
        if (st != GS_OK) break;
        CHECK_MSG(r.frames_acquired == 1 && r.frames_kept == k && r.complete == (k == E2E_K - 1),
                  "frame %d: acquired %d kept %d complete %d", k, r.frames_acquired,
                  r.frames_kept, r.complete);
        cap_hw_log log;
        CHECK_OK(cap_backend_hardware_log(be, &log));
        fw_bridge_report br = {-1, -1};
        CHECK_MSG(read_report(rep[0], &br, 5000) == 0, "frame %d: no report of the bridge", k);
        CHECK_MSG(br.cycles == E2E_C && log.link_cycles == E2E_C,
                  "frame %d: firmware EV DONE cycles=%ld, link logged %zu, C = %d", k, br.cycles,
                  log.link_cycles, E2E_C);
        /* each exposure after the lock (64 half periods) and after the previous one */
        CHECK_MSG(br.start_crossing >= 64 && br.start_crossing > prev_end &&
                      (size_t)(br.start_crossing + E2E_C) < tr.n,
                  "frame %d starts at crossing %ld (previous ended at %ld)", k, br.start_crossing,
                  prev_end);
        if (br.start_crossing < 0 || (size_t)(br.start_crossing + E2E_C) >= tr.n) break;
        prev_end = br.start_crossing + E2E_C;
        double truth = trace_mean_half_s(&tr, br.start_crossing, E2E_C);
        double err_ns = (log.link_mean_half_period_s - truth) * 1e9;
        CHECK_MSG(fabs(err_ns) <= 500.0, /* each D line is within one 0.5 us tick */
                  "frame %d: link mean half period %.4f us, injected %.4f us (crossings %ld..%ld "
                  "of %s)", k, log.link_mean_half_period_s * 1e6, truth * 1e6, br.start_crossing,
                  prev_end, rec);
        if (fabs(err_ns) > err_max_ns) err_max_ns = fabs(err_ns);
        /* the GPIO side: one crossing awaited, then the C queued during the exposure */
        long g0 = (long)k * (E2E_C + 1) + 1;
        CHECK(log.crossings == E2E_C);
        CHECK_NEAR(log.mean_half_period_s, trace_mean_half_s(&tr, g0, E2E_C - 1), 1e-9);
        double gl_us = fabs(log.mean_half_period_s - log.link_mean_half_period_s) * 1e6;
        if (gl_us > gpio_link_max_us) gpio_link_max_us = gl_us;
        printf("    frame %d: crossings %ld..%ld, link mean half period %.4f us (%.4f Hz), "
               "injected %.4f us, error %+.1f ns; GPIO %zu crossings %.4f us\n",
               k, br.start_crossing, prev_end, log.link_mean_half_period_s * 1e6,
               0.5 / log.link_mean_half_period_s, truth * 1e6, err_ns, log.crossings,
               log.mean_half_period_s * 1e6);
        acquired++;
    }
    /* the same mains on both sides (other moments of it): within 0.1 Hz at 50 Hz */
    CHECK_MSG(gpio_link_max_us <= 20.0, "GPIO and link mean half periods differ by %.2f us",
              gpio_link_max_us);
    CHECK(acquired == E2E_K);
    cap_backend_free(be); /* closes the pty: the bridge ends */
    CHECK(fake_gpiod_open_handles() == 0);
    CHECK(fake_gpiod_events_left() == 10);
    /* both outputs idle low, then per frame shutter up/down and a trigger pulse */
    CHECK_MSG(fake_gpiod_output_count() - outputs0 == 2 + 4 * E2E_K, "%zu GPIO writes",
              fake_gpiod_output_count() - outputs0);
    reap_bridge(pid);
    close(rep[0]);
    /* the frames in the capture directory are the camera's */
    char path[1100];
    snprintf(path, sizeof path, "%s/capture.json", out);
    CHECK_MSG(access(path, R_OK) == 0, "no %s", path);
    gs_capture cap;
    memset(&cap, 0, sizeof cap);
    CHECK_OK(gs_capture_read(out, &cap));
    if (cap.raw) {
        int same_size = cap.K == E2E_K && cap.width == E2E_W && cap.height == E2E_H && cap.bands == 3;
        CHECK(same_size);
        size_t bad = same_size ? hw_fx_camera_diff(&cap, E2E_K, E2E_W, E2E_H, e2e_pixel) : 0;
        CHECK_MSG(bad == 0, "%zu samples differ from the camera's", bad);
        CHECK(cap.locked == 1);
    }
    gs_capture_release(&cap);
    trace_free(&tr);
    clock_gettime(CLOCK_MONOTONIC, &w1);
    double wall = (double)(w1.tv_sec - w0.tv_sec) + 1e-9 * (double)(w1.tv_nsec - w0.tv_nsec);
    printf("    e2e: %d frames of C = %d, max |link - injected| %.1f ns, max |GPIO - link| %.2f "
           "us, %.2f s\n", acquired, E2E_C, err_max_ns, gpio_link_max_us, wall);
}
