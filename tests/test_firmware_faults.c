/* test_firmware_faults.c - the ACam controller firmware in libsimavr (tests/firmware_fixture.h):
 * glitches on the zero-crossing input (a spurious or a missing crossing), a grid leaving its
 * band, windows shorter than the DMD can hold, and the serial protocol with malformed commands.
 * Every fault stops the exposure, says so, and leaves both outputs low. */
#include "tests/firmware_fixture.h"
#include "tests/test.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------------------ glitches */

/* Runs an exposure on `edges` that must end in "EV FAULT <code>"; returns the fault line's
 * cycle= value (-1 on failure) and the start crossing in *s0. */
static long expect_fault(fwsim *s, int K, int k, long C, const char *code, long *s0)
{
    *s0 = -1;
    long ev = fwsim_start_exposure(s, K, k, C, 'L');
    if (ev < 0) return -1;
    long f = fwsim_wait_line(s, (size_t)ev, "EV FAULT", (uint64_t)((double)C / 90.0 * CYCLES_PER_S));
    CHECK_MSG(f >= 0, "no EV FAULT %s", code);
    if (f < 0) return -1;
    char want[32];
    snprintf(want, sizeof want, "EV FAULT %s ", code);
    CHECK_MSG(strncmp(s->lines[f].text, want, strlen(want)) == 0, "%s", s->lines[f].text);
    CHECK_MSG(fwsim_wait_line(s, (size_t)ev, "EV DONE", 0) < 0, "DONE after a fault");
    *s0 = fwsim_start_crossing(s);
    /* stopped, and it says so */
    const char *st = fwsim_cmd(s, "STATUS");
    char fault[32];
    snprintf(fault, sizeof fault, "fault=%s", code);
    CHECK_MSG(strstr(st, "state=FAULT") && strstr(st, fault), "%s", st);
    CHECK(s->shut_level == 0 && s->trig_level == 0 && s->shut_fall.n == 1);
    /* and stays stopped: no trigger edge afterwards */
    size_t rises = s->trig_rise.n;
    fwsim_run_until(s, s->avr->cycle + (uint64_t)(0.1 * CYCLES_PER_S));
    CHECK_MSG(s->trig_rise.n == rises, "trigger edges after the fault");
    return (long)fw_field(s->lines[f].text, "cycle");
}

/* The number of D lines (cycles logged). */
static long count_d(const fwsim *s)
{
    long d = 0;
    for (size_t i = 0; i < s->n_lines; i++) d += s->lines[i].text[0] == 'D';
    return d;
}

/* A 200 us pulse on the detector output 3 ms into half period 200 (two extra edges). */
TEST(firmware_glitch_spurious_crossing)
{
    trace tr;
    if (trace_from_mains("data/mains/whu_002_ref.wav", 800, &tr) != 0) return;
    uint64_t *e = malloc((tr.n + 2) * sizeof *e);
    if (!e) abort();
    memcpy(e, tr.edges, 201 * sizeof *e);
    e[201] = tr.edges[200] + 3 * 16000;
    e[202] = e[201] + 200 * 16;
    memcpy(e + 203, tr.edges + 201, (tr.n - 201) * sizeof *e);
    fwsim *s = fwsim_new(e, tr.n + 2, tr.rising_first);
    if (!s) return;
    long s0;
    long n = expect_fault(s, 20, 7, 500, "SPURIOUS", &s0);
    if (n >= 0 && s0 >= 0) {
        CHECK_MSG(n == 200 - s0, "fault in cycle %ld, the glitch is in cycle %ld", n, 200 - s0);
        /* detected at the glitch's first edge, by the end of its capture handler (< 100 us) */
        uint64_t glitch = s->applied.v[201];
        printf("    spurious edge in cycle %ld: stopped %.1f us after it\n", n,
               ((double)s->shut_fall.v[0] - (double)glitch) / CYCLES_PER_US);
        CHECK_MSG(s->shut_fall.v[0] >= glitch && s->shut_fall.v[0] - glitch < 100 * 16,
                  "shutter closed %.1f us after the glitch",
                  ((double)s->shut_fall.v[0] - (double)glitch) / CYCLES_PER_US);
        /* window 7 of 20 starts 3.5 ms in: cycle n never got its window */
        CHECK_MSG(s->trig_rise.n == (size_t)(2 * n), "%zu rising edges", s->trig_rise.n);
        CHECK(count_d(s) == n);
    }
    CHECK(s->bad_lines == 0);
    fwsim_free(s);
    free(e);
    trace_free(&tr);
}

/* A fault while a window is open must not leave the DMD on a non-zero mask. The DMD steps to
 * its next mask at each rising trigger edge through M = [m1 0 m2 0 ...] (Eq. 23): an exposure
 * that stops after an odd number of rising edges leaves it exposing, and the next exposure
 * (with the same masks loaded: no HDR) then starts on a zero mask where it expects m1, so it
 * integrates everything but window k. A 200 us glitch inside window 7 of 20 of cycle 200
 * (3.75 ms into it; window 7 is 3.5-4.0 ms), and one at 3 ms with k = 0 (window 0 rises at the
 * crossing itself, so the glitch's own edge raises the trigger): the exposure stops with
 * SPURIOUS, and the rising edges add up to an even number, each at least one 50 us pulse
 * width after the one before (the DMD's mask is then a zero mask again). */
TEST(firmware_fault_inside_a_window_leaves_the_dmd_on_a_zero_mask)
{
    static const struct {
        int k;
        double glitch_us;
    } cases[] = {{7, 3750.0}, {0, 3000.0}};
    trace tr;
    if (trace_from_mains("data/mains/whu_002_ref.wav", 800, &tr) != 0) return;
    for (size_t ci = 0; ci < sizeof cases / sizeof *cases; ci++) {
        uint64_t *e = malloc((tr.n + 2) * sizeof *e);
        if (!e) abort();
        memcpy(e, tr.edges, 201 * sizeof *e);
        e[201] = tr.edges[200] + (uint64_t)(cases[ci].glitch_us * CYCLES_PER_US);
        e[202] = e[201] + 200 * 16;
        memcpy(e + 203, tr.edges + 201, (tr.n - 201) * sizeof *e);
        fwsim *s = fwsim_new(e, tr.n + 2, tr.rising_first);
        if (!s) break;
        long s0;
        long n = expect_fault(s, 20, cases[ci].k, 500, "SPURIOUS", &s0);
        if (n >= 0 && s0 >= 0) {
            uint64_t gap = UINT64_MAX;
            for (size_t i = 1; i < s->trig_rise.n; i++)
                if (s->trig_rise.v[i] - s->trig_rise.v[i - 1] < gap)
                    gap = s->trig_rise.v[i] - s->trig_rise.v[i - 1];
            printf("    k=%d, glitch %.0f us into cycle %ld: %zu rising edges, closest two %.1f us "
                   "apart\n", cases[ci].k, cases[ci].glitch_us, n, s->trig_rise.n,
                   (double)gap / CYCLES_PER_US);
            CHECK_MSG(s->trig_rise.n % 2 == 0, "k=%d: %zu rising edges: the DMD is left on m_j",
                      cases[ci].k, s->trig_rise.n);
            CHECK_MSG(gap >= 50 * 16, "k=%d: rising edges %.1f us apart", cases[ci].k,
                      (double)gap / CYCLES_PER_US);
        }
        CHECK(s->bad_lines == 0);
        fwsim_free(s);
        free(e);
    }
    trace_free(&tr);
}

/* Crossing 200 is missing: detected 1/16 of a half period after it was due. */
TEST(firmware_glitch_missing_crossing)
{
    trace tr;
    if (trace_from_mains("data/mains/whu_002_ref.wav", 800, &tr) != 0) return;
    uint64_t *e = malloc(tr.n * sizeof *e);
    if (!e) abort();
    memcpy(e, tr.edges, 200 * sizeof *e);
    memcpy(e + 200, tr.edges + 201, (tr.n - 201) * sizeof *e);
    fwsim *s = fwsim_new(e, tr.n - 1, tr.rising_first);
    if (!s) return;
    long s0;
    long n = expect_fault(s, 20, 7, 500, "MISSING", &s0);
    if (n >= 0 && s0 >= 0) {
        CHECK_MSG(n == 199 - s0, "fault in cycle %ld, the missing crossing ends cycle %ld", n,
                  199 - s0);
        /* the deadline: t_199 + Delta_197 * 17/16 (in ticks of 8 cycles) */
        const uint64_t *t = tr.edges;
        double due = (double)t[199] + (double)(t[198] - t[197]) * 17.0 / 16.0;
        double late_us = ((double)s->shut_fall.v[0] - due) / CYCLES_PER_US;
        printf("    missing crossing after cycle %ld: stopped %.1f us after its deadline "
               "(%.0f us after it was due)\n", n, late_us,
               ((double)s->shut_fall.v[0] - (double)t[200]) / CYCLES_PER_US);
        CHECK_MSG(late_us > -2.0 && late_us < 20.0, "stopped %.1f us after the deadline",
                  late_us);
        CHECK(s->trig_rise.n == (size_t)(2 * (n + 1)));
        CHECK(count_d(s) == n);
    }
    CHECK(s->bad_lines == 0);
    fwsim_free(s);
    free(e);
    trace_free(&tr);
}

/* The first crossing i at which the full AC period t_i - t_{i-2} is shorter than the 53 Hz
 * limit (hold_K = 0), or the first cycle i whose window k of hold_K, predicted from
 * Delta_{i-2} with the firmware's integer arithmetic (round(65536 j / K) multipliers), would
 * be shorter than the DMD's 741 ticks (paper: 2.7 kHz). The firmware measures Delta in ticks to
 * within one, and the two rounded offsets make the window length jitter by a tick near the
 * limit, and not monotonically (at K = 26, k = 5: 741 ticks for a prediction of 19258 ticks,
 * 740 for 19259). ticks_off 0: the exact prediction; 1: the first cycle where a prediction off
 * by one tick could already be too short; 2: the first where every prediction within one tick
 * is too short (the latest the firmware can find it: which of the three it measures depends on
 * the capture's phase within a tick, which moved with the firmware's RAM layout). */
static size_t first_beyond(const trace *tr, size_t from, int hold_K, int k, int ticks_off)
{
    uint32_t K = (uint32_t)(hold_K ? hold_K : 1);
    uint32_t m0 = (((uint32_t)k << 16) + K / 2) / K, m1 = (((uint32_t)(k + 1) << 16) + K / 2) / K;
    for (size_t i = from; i < tr->n; i++) {
        if (hold_K) {
            uint32_t pred = (uint32_t)((tr->edges[i - 1] - tr->edges[i - 2]) / 8);
            int short_n = 0, tried = 0;
            for (int d = ticks_off ? -1 : 0; d <= (ticks_off ? 1 : 0); d++, tried++) {
                uint32_t p = pred + (uint32_t)d;
                uint32_t s = (p * m0 + 0x8000u) >> 16, e = (p * m1 + 0x8000u) >> 16;
                short_n += e - s < 741u;
            }
            if (ticks_off == 2 ? short_n == tried : short_n > 0) return i;
        } else if ((double)(tr->edges[i] - tr->edges[i - 2]) / 8.0 < 37736.0) {
            return i;
        }
    }
    return 0;
}

/* A grid ramping out of the 50 Hz band (+0.5 Hz/s) stops the exposure at 53 Hz. */
TEST(firmware_glitch_frequency_out_of_range)
{
    trace tr;
    trace_synthetic(50.0, 0.0, 1.0, 0.5, 0.0, 1400, &tr);
    fwsim *s = fwsim_new(tr.edges, tr.n, tr.rising_first);
    if (!s) return;
    long s0;
    long n = expect_fault(s, 10, 4, 2000, "FREQ", &s0);
    if (n >= 0 && s0 >= 0) {
        /* the crossing that ends the first too-short period ends cycle want */
        long want = (long)first_beyond(&tr, (size_t)s0, 0, 0, 0) - s0 - 1;
        CHECK_MSG(labs(n - want) <= 1, "FREQ in cycle %ld, the band is left in cycle %ld", n,
                  want);
        double f = 16e6 / (double)(tr.edges[s0 + n + 1] - tr.edges[s0 + n - 1]);
        printf("    stopped at %.3f Hz (cycle %ld)\n", f, n);
        CHECK(f > 52.99 && f < 53.01);
    }
    CHECK(s->bad_lines == 0);
    fwsim_free(s);
    trace_free(&tr);
}

/* At K = 26 the same ramp stops the exposure earlier, when a window would be held for less than
 * the DMD's 370.4 us (about 51.9 Hz): masks are never switched faster than the DMD allows; the
 * fault comes before the cycle that would need it. */
TEST(firmware_limit_window_shorter_than_dmd_hold)
{
    trace tr;
    trace_synthetic(50.0, 0.0, 1.0, 0.5, 0.0, 1400, &tr);
    fwsim *s = fwsim_new(tr.edges, tr.n, tr.rising_first);
    if (!s) return;
    long s0;
    long n = expect_fault(s, 26, 5, 2000, "LIMIT", &s0);
    if (n >= 0 && s0 >= 0) {
        /* found while planning that cycle, a half period ahead: reported in the one before */
        long lo = (long)first_beyond(&tr, (size_t)s0, 26, 5, 1) - s0 - 1;
        long hi = (long)first_beyond(&tr, (size_t)s0, 26, 5, 2) - s0 - 1;
        CHECK_MSG(n >= lo && n <= hi, "LIMIT in cycle %ld, expected %ld..%ld", n, lo, hi);
        double min_hold = 1e30;
        for (size_t i = 0; i + 1 < s->trig_rise.n; i++) {
            double h = (double)(s->trig_rise.v[i + 1] - s->trig_rise.v[i]) / CYCLES_PER_US;
            if (h < min_hold) min_hold = h;
        }
        printf("    stopped in cycle %ld; shortest mask %.1f us\n", n, min_hold);
        CHECK(min_hold >= 370.4);
    }
    CHECK(s->bad_lines == 0);
    fwsim_free(s);
    trace_free(&tr);
}

/* ------------------------------------------------------------------ serial protocol */

static const char *checked(fwsim *s, const char *cmd, const char *want_prefix)
{
    const char *r = fwsim_cmd(s, cmd);
    CHECK_MSG(strncmp(r, want_prefix, strlen(want_prefix)) == 0, "'%s' -> '%s', expected '%s'",
              cmd, r, want_prefix);
    return r;
}

TEST(firmware_serial_protocol_and_malformed_commands)
{
    trace tr;
    trace_synthetic(50.0, 0.0, 1.0, 0.0, 30.0, 800, &tr);
    fwsim *s = fwsim_new(tr.edges, tr.n, tr.rising_first);
    if (!s) return;
    CHECK(fwsim_wait_line(s, 0, "EV BOOT acam 1", (uint64_t)(0.01 * CYCLES_PER_S)) == 0);
    /* before any configuration and before the lock */
    checked(s, "START", "ERR NOCFG");
    checked(s, "CFG 10 2 5 L", "OK CFG K=10 k=2 C=5 mode=L");
    checked(s, "START", "ERR NOLOCK");
    const char *st = checked(s, "STATUS", "OK STATUS state=IDLE lock=0 grid=0");
    (void)st;
    checked(s, "VER", "OK VER acam 1 fcpu=16000000 tick_ns=500 hist=64");
    /* malformed commands, each with its error, and the firmware keeps answering */
    checked(s, "FOO", "ERR SYNTAX");
    checked(s, "ping", "ERR SYNTAX");
    checked(s, "PING ", "ERR SYNTAX");
    checked(s, "PING*00", "ERR CHECKSUM");
    checked(s, "PING*5", "ERR SYNTAX");
    checked(s, "CFG 10 2 5", "ERR SYNTAX");
    checked(s, "CFG 10 x 5 L", "ERR SYNTAX");
    checked(s, "CFG 27 2 5 L", "ERR RANGE");
    checked(s, "CFG 10 10 5 L", "ERR RANGE");
    checked(s, "CFG 10 2 0 L", "ERR RANGE");
    checked(s, "CFG 10 2 5 Q", "ERR RANGE");
    checked(s, "CFG 10 2 1000001 L", "ERR RANGE");
    checked(s, "\x01\x02\x7f", "ERR SYNTAX");
    checked(s, "PING PING PING PING PING PING PING PING PING PING PING", "ERR LONG");
    fwsim_send(s, ""); /* an empty line is ignored: the next reply is PING's */
    char line[32];
    snprintf(line, sizeof line, "PING*%02X", 'P' ^ 'I' ^ 'N' ^ 'G');
    checked(s, line, "OK PING");
    checked(s, "PING\r", "OK PING"); /* CRLF */
    /* the failed CFGs did not change the configuration */
    fwsim_run_until(s, (uint64_t)(0.9 * CYCLES_PER_S));
    st = checked(s, "STATUS", "OK STATUS state=IDLE lock=1 grid=50");
    CHECK_MSG(fw_field(st, "K") == 10 && fw_field(st, "k") == 2 && fw_field(st, "C") == 5, "%s", st);
    /* HALF: the last half period within one 0.5 us tick of the injected one */
    const char *h = checked(s, "HALF", "OK HALF");
    long last = u64vec_last_le(&s->applied, s->lines[s->n_lines - 1].cycle);
    double truth_ns = 0;
    if (last >= 1) truth_ns = (double)(s->applied.v[last] - s->applied.v[last - 1]) / 16.0 * 1000.0;
    CHECK_MSG(fabs(fw_field(h, "last_ns") - truth_ns) <= 500.0, "%s vs %.0f ns", h, truth_ns);
    CHECK_NEAR(fw_field(h, "mean_ns"), 1e7, 500.0);
    checked(s, "COUNT", "OK COUNT 0");
    /* an exposure, interrupted */
    checked(s, "CFG 10 2 300 L", "OK CFG");
    checked(s, "START", "OK START");
    checked(s, "START", "ERR BUSY");
    checked(s, "CFG 10 2 5 L", "ERR BUSY");
    fwsim_run_until(s, s->avr->cycle + (uint64_t)(0.3 * CYCLES_PER_S));
    st = checked(s, "STATUS", "OK STATUS state=EXPOSING lock=1 grid=50");
    double c1 = fw_field(st, "cycles");
    const char *cnt = checked(s, "COUNT", "OK COUNT ");
    CHECK_MSG(atof(cnt + 9) >= c1 && c1 >= 25, "%s after %s", cnt, st);
    const char *stop = checked(s, "STOP", "OK STOP cycles=");
    double stopped = fw_field(stop, "cycles");
    size_t rises = s->trig_rise.n;
    fwsim_run_until(s, s->avr->cycle + (uint64_t)(0.1 * CYCLES_PER_S));
    CHECK(s->trig_rise.n == rises && s->trig_level == 0 && s->shut_level == 0);
    st = checked(s, "STATUS", "OK STATUS state=IDLE");
    CHECK_MSG(strstr(st, "fault=STOPPED") && fw_field(st, "cycles") == stopped, "%s", st);
    /* and a complete one */
    checked(s, "CFG 10 2 5 L", "OK CFG");
    size_t from = s->n_lines;
    checked(s, "START", "OK START");
    CHECK(fwsim_wait_line(s, from, "EV DONE cycles=5", (uint64_t)(0.2 * CYCLES_PER_S)) >= 0);
    checked(s, "COUNT", "OK COUNT 5");
    checked(s, "STATUS", "OK STATUS state=DONE lock=1 grid=50 cycles=5 C=5 K=10 k=2 mode=L");
    checked(s, "STOP", "OK STOP cycles=5"); /* nothing to stop */
    CHECK_MSG(s->bad_lines == 0, "%zu lines without a valid checksum", s->bad_lines);
    CHECK_MSG(fwsim_stack_margin(s) >= STACK_MARGIN_MIN, "stack margin %ld bytes",
              fwsim_stack_margin(s));
    fwsim_free(s);
    trace_free(&tr);
}

/* K <= 22 on a 60 Hz grid (Fig. 7): K = 23 is refused at START, K = 22 runs. */
TEST(firmware_k_limit_60hz)
{
    trace tr;
    trace_synthetic(60.0, 0.0, 1.0, 0.0, 0.0, 400, &tr);
    fwsim *s = fwsim_new(tr.edges, tr.n, tr.rising_first);
    if (!s) return;
    fwsim_run_until(s, (uint64_t)(0.8 * CYCLES_PER_S));
    checked(s, "STATUS", "OK STATUS state=IDLE lock=1 grid=60");
    checked(s, "CFG 23 0 10 L", "OK CFG");
    checked(s, "START", "ERR LIMIT");
    checked(s, "CFG 22 21 10 L", "OK CFG");
    size_t from = s->n_lines;
    checked(s, "START", "OK START");
    CHECK(fwsim_wait_line(s, from, "EV DONE cycles=10", (uint64_t)(0.3 * CYCLES_PER_S)) >= 0);
    CHECK(s->trig_rise.n == 20);
    fwsim_free(s);
    trace_free(&tr);
}
