/* test_firmware_logic.c - the ACam controller's timing core and protocol (firmware/schedule.c,
 * firmware/proto.c) compiled with the host gcc and tested natively (paper Sec. 6: AC-locked
 * mask switching, Fig. 7 limits). The files are included so that their static helpers are
 * tested as built into the firmware.
 *
 * A small event model replays what firmware/main.c does with the core (capture -> tracker ->
 * exposure -> actions; compare -> exposure -> actions) on 32-bit tick times, so the schedule is
 * checked against independently computed window edges without the simulator; the real
 * firmware in simavr is tests/test_firmware.c. */
#include "firmware/proto.c"
#include "firmware/schedule.c"

#include "tests/test.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------------------ helpers */

/* Feeds a crossing at absolute tick time now (the tracker sees its low 16 bits). */
static uint8_t feed(fw_tracker *t, uint32_t now, uint16_t *delta)
{
    return fw_tracker_crossing(t, (uint16_t)now, delta);
}

/* Crossing times of a mains whose positive half period lasts hp ticks and negative hn,
 * starting at t0 (chosen near the 16-bit wrap so that wrapping is exercised). */
static uint32_t alt_time(uint32_t t0, uint32_t hp, uint32_t hn, size_t i)
{
    return t0 + (uint32_t)(i / 2) * (hp + hn) + (i % 2 ? hp : 0);
}

/* Locks a tracker on 50 Hz with 40 us asymmetry; returns the time of the last crossing fed. */
static uint32_t lock_50(fw_tracker *t, size_t crossings)
{
    fw_tracker_reset(t);
    uint16_t d;
    uint32_t now = 0;
    for (size_t i = 0; i < crossings; i++) {
        now = alt_time(65000, 20040, 19960, i);
        uint8_t v = feed(t, now, &d);
        CHECK_MSG(v == FW_OK, "crossing %zu: %s", i, fw_fault_name(v));
    }
    return now;
}

/* ------------------------------------------------------------------ tracker */

TEST(firmware_logic_tracker_locks_on_64_half_periods)
{
    fw_tracker t;
    fw_tracker_reset(&t);
    uint16_t d;
    for (size_t i = 0; i < 70; i++) {
        uint32_t now = alt_time(65000, 20040, 19960, i);
        CHECK(feed(&t, now, &d) == FW_OK);
        /* 64 half periods need 65 crossings */
        CHECK_MSG(fw_tracker_locked(&t) == (i >= 64), "crossing %zu locked=%d", i,
                  fw_tracker_locked(&t));
        if (i >= 1) CHECK(d == (i % 2 ? 20040 : 19960));
        if (i >= 3) {
            /* the prediction of the half period now starting is the same-polarity one */
            CHECK(fw_tracker_predict(&t) == (i % 2 ? 19960 : 20040));
            uint16_t p = fw_tracker_predict(&t);
            CHECK(fw_tracker_deadline(&t) == p + p / 16);
        }
    }
    CHECK(t.grid_hz == 50);
    CHECK(t.sum_ticks == 32u * (20040 + 19960));
}

TEST(firmware_logic_tracker_60hz_and_out_of_band)
{
    fw_tracker t;
    fw_tracker_reset(&t);
    uint16_t d;
    for (size_t i = 0; i < 66; i++) CHECK(feed(&t, alt_time(1000, 16667, 16666, i), &d) == FW_OK);
    CHECK(fw_tracker_locked(&t) && t.grid_hz == 60);
    /* 55 Hz is in neither band: every full period is rejected, it never locks */
    fw_tracker_reset(&t);
    int freq = 0;
    for (size_t i = 0; i < 200; i++)
        if (feed(&t, alt_time(1000, 18182, 18182, i), &d) == FW_FREQ) freq++;
    CHECK(!fw_tracker_locked(&t));
    CHECK_MSG(freq >= 90, "%d FREQ verdicts", freq);
    /* the band edges, as full periods (Eq. 1: f = 1 / (2 Delta)) */
    CHECK(fw_grid_of_period(37736) == 50 && fw_grid_of_period(37735) == 0);
    CHECK(fw_grid_of_period(42553) == 50 && fw_grid_of_period(42554) == 0);
    CHECK(fw_grid_of_period(31746) == 60 && fw_grid_of_period(31745) == 0);
    CHECK(fw_grid_of_period(35088) == 60 && fw_grid_of_period(35089) == 0);
}

TEST(firmware_logic_tracker_glitch_tolerance_edges)
{
    /* a half period may differ from Delta_{n-2} by pred/16 and no more */
    for (int c = 0; c < 4; c++) {
        fw_tracker t;
        uint32_t now = lock_50(&t, 70);
        uint16_t pred = fw_tracker_predict(&t), tol = pred >> 4, d;
        static const int off[4] = {0, -1, 0, 1};
        uint16_t len = c < 2 ? (uint16_t)(pred - tol + off[c]) : (uint16_t)(pred + tol + off[c]);
        uint8_t want = c == 1 ? FW_SPURIOUS : c == 3 ? FW_MISSING : FW_OK;
        uint8_t v = feed(&t, now + len, &d);
        CHECK_MSG(v == want, "case %d: %s", c, fw_fault_name(v));
        CHECK(d == len);
        CHECK(fw_tracker_locked(&t) == (want == FW_OK));
    }
}

TEST(firmware_logic_tracker_spurious_missing_timeout)
{
    fw_tracker t;
    uint16_t d;
    /* spurious: an extra crossing 3 ms into a half period */
    uint32_t now = lock_50(&t, 70);
    CHECK(feed(&t, now + 6000, &d) == FW_SPURIOUS);
    CHECK(!fw_tracker_locked(&t) && t.good == 0 && t.have_ref);
    /* relock: 64 more accepted half periods (starting from the spurious crossing) */
    uint32_t base = now + 6000;
    for (size_t i = 1; i <= 64; i++) {
        uint8_t v = feed(&t, base + (uint32_t)i * 20000, &d);
        CHECK_MSG(v == FW_OK, "relock %zu: %s", i, fw_fault_name(v));
    }
    CHECK(fw_tracker_locked(&t));
    /* missing: the next crossing after two half periods */
    now = lock_50(&t, 70);
    CHECK(feed(&t, now + 20040 + 19960, &d) == FW_MISSING);
    /* the timeout forgets the reference: the next crossing only re-anchors */
    now = lock_50(&t, 70);
    fw_tracker_timeout(&t);
    CHECK(!t.have_ref && !fw_tracker_locked(&t));
    CHECK(feed(&t, now + 90000, &d) == FW_OK && d == 0);
    CHECK(fw_tracker_deadline(&t) == FW_HALF_MAX_TICKS);
    /* before two half periods are known: only the coarse bounds */
    fw_tracker_reset(&t);
    CHECK(feed(&t, 100, &d) == FW_OK);
    CHECK(feed(&t, 100 + FW_HALF_MIN_TICKS - 1, &d) == FW_SPURIOUS);
    fw_tracker_reset(&t);
    CHECK(feed(&t, 100, &d) == FW_OK);
    CHECK(feed(&t, 100 + FW_HALF_MAX_TICKS + 1, &d) == FW_MISSING);
}

/* A slow ramp out of the 50 Hz band is reported as FREQ at the first full period above
 * 53 Hz, counted here independently from the crossing times. */
TEST(firmware_logic_tracker_ramp_out_of_band)
{
    fw_tracker t;
    fw_tracker_reset(&t);
    uint16_t d;
    double f = 50.0, time_s = 0;
    uint32_t times[2000];
    size_t n = 0, expect = 0;
    while (n < 2000) {
        times[n] = 500 + (uint32_t)llround(time_s * 2e6);
        if (!expect && n >= 2) {
            double full = (double)(times[n] - times[n - 2]);
            if (full < FW_P50_MIN_TICKS) expect = n;
        }
        n++;
        time_s += 1.0 / (2 * f);
        f += 0.002; /* 0.2 Hz/s */
    }
    size_t got = 0;
    for (size_t i = 0; i < n && !got; i++)
        if (feed(&t, times[i], &d) == FW_FREQ) got = i;
    CHECK_MSG(expect > 0 && got == expect, "FREQ at crossing %zu, expected %zu", got, expect);
}

/* ------------------------------------------------------------------ offsets and arming */

TEST(firmware_logic_locked_offsets_within_07_tick)
{
    static const uint16_t preds[] = {9524, 15000, 16667, 18900, 20000, 21276, 25000, 29787};
    double worst = 0;
    for (uint8_t K = FW_K_MIN; K <= FW_K_MAX_50; K++)
        for (uint8_t k = 0; k < K; k++) {
            fw_expo e;
            memset(&e, 0, sizeof e);
            CHECK(fw_expo_configure(&e, K, k, 100, FW_MODE_LOCKED) == FW_OK);
            e.m_start = k ? multiplier(k, K) : 0;
            e.m_end = k + 1 < K ? multiplier((uint8_t)(k + 1), K) : 0;
            for (size_t p = 0; p < sizeof preds / sizeof preds[0]; p++)
                for (uint8_t j = k; j <= k + 1; j++) {
                    double exact = (double)j * preds[p] / K;
                    double err = fabs(fw_locked_offset(&e, preds[p], j) - exact);
                    if (err > worst) worst = err;
                }
        }
    CHECK_MSG(worst < 0.7, "worst offset error %.3f ticks", worst);
}

TEST(firmware_logic_arm_checks_grid_limits)
{
    fw_tracker t;
    fw_expo e;
    fw_action act;
    memset(&e, 0, sizeof e);
    /* not configured / not locked */
    lock_50(&t, 70);
    CHECK(fw_expo_arm(&e, &t, &act) == FW_LIMIT);
    CHECK(fw_expo_configure(&e, 26, 25, 10, FW_MODE_LOCKED) == FW_OK);
    fw_tracker u;
    lock_50(&u, 30);
    CHECK(fw_expo_arm(&e, &u, &act) == FW_MISSING);
    /* 50 Hz: K = 26 is the paper's limit (Fig. 7) */
    CHECK(fw_expo_arm(&e, &t, &act) == FW_OK && e.state == FW_ST_ARMED);
    CHECK(act.flags == FW_ACT_SHUTTER_ON);
    /* configure refuses what no grid allows */
    CHECK(fw_expo_configure(&e, 27, 0, 10, FW_MODE_LOCKED) == FW_LIMIT);
    CHECK(fw_expo_configure(&e, 1, 0, 10, FW_MODE_LOCKED) == FW_LIMIT);
    CHECK(fw_expo_configure(&e, 10, 10, 10, FW_MODE_LOCKED) == FW_LIMIT);
    CHECK(fw_expo_configure(&e, 10, 0, 0, FW_MODE_LOCKED) == FW_LIMIT);
    CHECK(fw_expo_configure(&e, 10, 0, FW_C_MAX + 1, FW_MODE_LOCKED) == FW_LIMIT);
    CHECK(fw_expo_configure(&e, 10, 0, 10, 2) == FW_LIMIT);
    /* 60 Hz: K = 22 is the limit */
    fw_tracker_reset(&t);
    uint16_t d;
    for (size_t i = 0; i < 70; i++) feed(&t, alt_time(7, 16667, 16667, i), &d);
    CHECK(t.grid_hz == 60);
    e.state = FW_ST_IDLE;
    CHECK(fw_expo_configure(&e, 23, 0, 10, FW_MODE_LOCKED) == FW_OK);
    CHECK(fw_expo_arm(&e, &t, &act) == FW_LIMIT);
    CHECK(fw_expo_configure(&e, 22, 0, 10, FW_MODE_LOCKED) == FW_OK);
    CHECK(fw_expo_arm(&e, &t, &act) == FW_OK);
    /* a fast 50 Hz grid (52.5 Hz): 9524 us / 26 = 366 us < 370.4 us, the DMD cannot hold it */
    fw_tracker_reset(&t);
    for (size_t i = 0; i < 70; i++) feed(&t, alt_time(7, 19048, 19048, i), &d);
    CHECK(t.grid_hz == 50);
    e.state = FW_ST_IDLE;
    CHECK(fw_expo_configure(&e, 26, 3, 10, FW_MODE_LOCKED) == FW_OK);
    CHECK(fw_expo_arm(&e, &t, &act) == FW_LIMIT);
    CHECK(fw_expo_configure(&e, 25, 3, 10, FW_MODE_LOCKED) == FW_OK);
    CHECK(fw_expo_arm(&e, &t, &act) == FW_OK);
}

/* ------------------------------------------------------------------ the event model */

typedef struct {
    uint32_t t;      /* tick time of the trigger edge */
    uint8_t level;
} model_edge;

typedef struct {
    fw_tracker trk;
    fw_expo ex;
    uint8_t trig, rise_flag, shutter;
    uint16_t cmp;         /* compare value */
    uint32_t cmp_from;    /* time it was armed */
    uint8_t cmp_level, cmp_live;
    model_edge *edges;
    size_t n_edges, cap;
    uint32_t log_n;       /* D records */
    uint32_t shutter_on, shutter_off;
    int started, done, fault;
} model;

static void model_edge_at(model *m, uint32_t t, uint8_t level)
{
    if (m->trig == level) return;
    /* the trigger moves only while the shutter is open (or falls when it closes) */
    CHECK_MSG(m->shutter || level == 0, "trigger rise at %u with the shutter closed", t);
    m->trig = level;
    if (m->n_edges == m->cap) {
        m->cap = m->cap ? 2 * m->cap : 4096;
        m->edges = realloc(m->edges, m->cap * sizeof *m->edges);
        if (!m->edges) abort();
    }
    m->edges[m->n_edges].t = t;
    m->edges[m->n_edges++].level = level;
}

/* as apply() in firmware/main.c; a crossing is handled as by its capture handler: the
 * planned chain first, then the tracker, the log and the next plan */
static void model_apply(model *m, const fw_action *a, uint32_t now)
{
    if (a->flags & FW_ACT_TRIGGER_LOW) {
        model_edge_at(m, now, 0);
        m->rise_flag = 0;
    }
    if (a->flags & (FW_ACT_STOP_COMPARE | FW_ACT_TRIGGER_LOW)) m->cmp_level = 0;
    if (a->flags & (FW_ACT_STOP_COMPARE | FW_ACT_TRIGGER_LOW)) m->cmp_live = 0;
    if (a->flags & FW_ACT_SHUTTER_ON) {
        m->shutter = 1;
        m->shutter_on = now;
    }
    if (a->flags & FW_ACT_SHUTTER_OFF && m->shutter) {
        m->shutter = 0;
        m->shutter_off = now;
    }
    if (a->flags & FW_ACT_STARTED) m->started++;
    if (a->flags & FW_ACT_LOG) {
        CHECK(a->log_cycle == m->log_n);
        m->log_n++;
    }
    if (a->flags & FW_ACT_CLOSE_PULSE) { /* after the shutter, as apply() does */
        m->shutter = 1; /* the only rise allowed with the shutter closed */
        model_edge_at(m, now + FW_PULSE_TICKS, 1);
        model_edge_at(m, now + 2 * FW_PULSE_TICKS, 0);
        m->shutter = 0;
    }
    if (a->flags & FW_ACT_DONE) m->done++;
    if (a->flags & FW_ACT_FAULT) m->fault = m->ex.fault;
    if (a->flags & FW_ACT_ARM_COMPARE) {
        m->cmp = a->compare_ticks;
        m->cmp_from = now;
        m->cmp_level = a->next_level;
        m->cmp_live = 1;
        CHECK_MSG((int16_t)(a->compare_ticks - (uint16_t)now) >= 1, "compare armed in the past");
    }
}

/* When the armed compare fires: one tick after TCNT1 reaches the compare value. */
static uint32_t model_cmp_time(const model *m)
{
    return m->cmp_from + (uint16_t)(m->cmp - (uint16_t)m->cmp_from) + 1u;
}

static void model_run_compares(model *m, uint32_t until)
{
    while (m->cmp_live && model_cmp_time(m) < until) {
        uint32_t at = model_cmp_time(m);
        model_edge_at(m, at, m->cmp_level);
        fw_action a;
        fw_expo_compare(&m->ex, &a);
        if (!(a.flags & FW_ACT_ARM_COMPARE)) m->cmp_live = 0;
        model_apply(m, &a, at);
    }
}

/* A crossing at absolute tick time now, as the capture interrupt handles it. */
static void model_crossing(model *m, uint32_t now)
{
    model_run_compares(m, now);
    if (m->rise_flag) model_edge_at(m, now, 1);
    fw_action a;
    fw_expo_crossing_fast(&m->ex, (uint16_t)now, &a);
    if (a.flags & FW_ACT_ABORT) fw_expo_abort(&m->ex, a.abort_fault, &a);
    model_apply(m, &a, now);
    uint16_t delta;
    uint8_t v = fw_tracker_crossing(&m->trk, (uint16_t)now, &delta);
    fw_expo_crossing_slow(&m->ex, &m->trk, v, delta, &a);
    if (a.flags & FW_ACT_ABORT) fw_expo_abort(&m->ex, a.abort_fault, &a);
    if (m->ex.log_done) fw_expo_finish(&m->ex, &a);
    model_apply(m, &a, now);
    m->rise_flag = m->ex.rise_at_crossing;
}

/* START between two crossings, at time now (as the main loop does it) */
static void model_arm(model *m, uint32_t now)
{
    fw_action a;
    CHECK(fw_expo_arm(&m->ex, &m->trk, &a) == FW_OK);
    model_apply(m, &a, now);
    m->rise_flag = m->ex.rise_at_crossing;
}

static void model_free(model *m)
{
    free(m->edges);
}

/* Runs a locked exposure of window k of K over C cycles on crossings times[0..n) (exposure
 * armed after crossing `arm_after`), then checks every rising edge against the independent
 * formula: start of window k at t_n + round(k Delta_{n-2} / K), end at t_n + round((k+1)
 * Delta_{n-2} / K), Delta from the crossing times (no tick rounding here: exact integers). */
static void check_locked_schedule(const uint32_t *times, size_t n, size_t arm_after, uint8_t K,
                                  uint8_t k, uint32_t C)
{
    model m;
    memset(&m, 0, sizeof m);
    fw_tracker_reset(&m.trk);
    for (size_t i = 0; i <= arm_after; i++) model_crossing(&m, times[i]);
    CHECK(fw_expo_configure(&m.ex, K, k, C, FW_MODE_LOCKED) == FW_OK);
    model_arm(&m, times[arm_after] + 50);
    for (size_t i = arm_after + 1; i < n; i++) model_crossing(&m, times[i]);
    model_run_compares(&m, times[n - 1] + 100000);
    size_t s = arm_after + 1; /* the start crossing */
    CHECK_MSG(m.done == 1 && m.fault == 0 && m.started == 1, "done %d fault %d", m.done, m.fault);
    CHECK(m.log_n == C);
    CHECK(m.shutter_on == times[arm_after] + 50 && !m.shutter);
    size_t rises = 0, worst_i = 0;
    double worst = 0;
    for (size_t i = 0; i < m.n_edges; i++) {
        if (!m.edges[i].level) continue;
        uint32_t cyc = (uint32_t)(rises / 2), j = k + (uint32_t)(rises % 2);
        double pred = (double)(times[s + cyc - 1] - times[s + cyc - 2]);
        double want = (double)times[s + cyc] + (double)j * pred / K;
        double err = (double)m.edges[i].t - want;
        if (fabs(err) > fabs(worst)) {
            worst = err;
            worst_i = rises;
        }
        rises++;
    }
    CHECK_MSG(rises == 2 * C, "%zu rising edges for %u cycles", rises, C);
    /* the multiplier rounding (< 0.7 tick); the compare lead cancels the late flag */
    CHECK_MSG(fabs(worst) <= 0.7, "K=%u k=%u: edge %zu off by %.2f ticks", K, k, worst_i, worst);
    /* pulses: every rise is followed by a fall FW_PULSE_TICKS later */
    for (size_t i = 0; i + 1 < m.n_edges; i++)
        if (m.edges[i].level) CHECK(m.edges[i + 1].t - m.edges[i].t == FW_PULSE_TICKS);
    model_free(&m);
}

TEST(firmware_logic_locked_schedule_every_window)
{
    /* 50 Hz with wander and a 40 us asymmetry, crossings near the 16-bit wrap */
    enum { N = 400 };
    uint32_t times[N];
    double t = 65000;
    for (size_t i = 0; i < N; i++) {
        times[i] = (uint32_t)llround(t);
        t += 20000 + (i % 2 ? -40 : 40) + 30 * sin((double)i / 17.0);
    }
    for (uint8_t K = 2; K <= 26; K += 6)
        for (uint8_t k = 0; k < K; k += (uint8_t)(K > 4 ? K / 3 : 1))
            check_locked_schedule(times, N, 80, K, k, 200);
    /* the two special windows at the paper's limit: 0 (starts at the crossing) and K-1 (ends
     * at the predicted crossing, handed over through the mailbox when the crossing comes first) */
    check_locked_schedule(times, N, 80, 26, 0, 300);
    check_locked_schedule(times, N, 80, 26, 25, 300);
    check_locked_schedule(times, N, 80, 2, 1, 300);
}

TEST(firmware_logic_free_running_follows_fixed_period)
{
    /* 49.95 Hz crossings, exposure armed with Delta_0 from the 64 half periods before */
    enum { N = 20000 };
    uint32_t *times = malloc(N * sizeof *times);
    if (!times) abort();
    for (size_t i = 0; i < N; i++) times[i] = 1000 + (uint32_t)llround((double)i * 20020.02);
    model m;
    memset(&m, 0, sizeof m);
    fw_tracker_reset(&m.trk);
    size_t arm_after = 100, C = N - 300;
    for (size_t i = 0; i <= arm_after; i++) model_crossing(&m, times[i]);
    CHECK(fw_expo_configure(&m.ex, 20, 0, (uint32_t)C, FW_MODE_FREE) == FW_OK);
    model_arm(&m, times[arm_after] + 50);
    /* Delta_0 exactly: the sum of the 64 half periods before arming, in 1/256 ticks */
    uint32_t sum = times[arm_after] - times[arm_after - 64];
    CHECK(m.ex.period_q8 == sum * 4u);
    for (size_t i = arm_after + 1; i < N; i++) model_crossing(&m, times[i]);
    model_run_compares(&m, times[N - 1] + 100000);
    CHECK(m.done == 1 && m.fault == 0);
    /* rise 2n at t_s + n Delta_0, rise 2n+1 at t_s + n Delta_0 + Delta_0 / K: no accumulated
     * rounding over ~20000 cycles (the anchor is kept in 1/256 ticks) */
    double d0 = (double)sum / 64.0, worst = 0;
    size_t rises = 0;
    uint32_t ts = times[arm_after + 1];
    for (size_t i = 0; i < m.n_edges; i++) {
        if (!m.edges[i].level) continue;
        double want = (double)ts + (double)(rises / 2) * d0 + (rises % 2) * d0 / 20.0;
        double err = (double)m.edges[i].t - want;
        if (fabs(err) > worst) worst = fabs(err);
        rises++;
    }
    CHECK(rises == 2 * C);
    CHECK_MSG(worst <= 0.51, "free-running edge off by %.2f ticks", worst);
    model_free(&m);
    free(times);
}

/* The rising trigger edges of the model, mod 2 (1: the DMD left on a window's mask m_j). */
static unsigned model_rises_odd(const model *m)
{
    unsigned r = 0;
    for (size_t i = 0; i < m->n_edges; i++) r += m->edges[i].level;
    return r % 2;
}

/* A spurious crossing inside window 3 of 10 (2000-tick half periods of 20000: window 3 is
 * 6000-8000 ticks into the cycle) stops the exposure after an odd number of rising edges; the
 * stop adds one pulse so that the DMD rests on a zero mask (Eq. 23). Outside a window (at
 * 13000 ticks) and for the host's STOP before the first window, no pulse is added. */
TEST(firmware_logic_stop_inside_a_window_closes_the_dmd)
{
    enum { N = 200 };
    static const uint32_t glitch_at[] = {7000, 13000};
    for (size_t g = 0; g < 2; g++) {
        model m;
        memset(&m, 0, sizeof m);
        fw_tracker_reset(&m.trk);
        uint32_t t = 5, pulse_from = 0;
        for (size_t i = 0; i <= 80; i++, t += 20000) model_crossing(&m, t);
        CHECK(fw_expo_configure(&m.ex, 10, 3, 100, FW_MODE_LOCKED) == FW_OK);
        model_arm(&m, t - 20000 + 50);
        for (size_t i = 81; i < N; i++, t += 20000) {
            if (i == 131) {
                model_run_compares(&m, t - 20000 + glitch_at[g]);
                pulse_from = (uint32_t)m.n_edges;
                model_crossing(&m, t - 20000 + glitch_at[g]);
            }
            model_crossing(&m, t);
        }
        model_run_compares(&m, t + 100000);
        CHECK(m.fault == FW_SPURIOUS && m.trig == 0 && !m.shutter);
        CHECK_MSG(model_rises_odd(&m) == 0, "glitch at %u: the DMD left on m_j", glitch_at[g]);
        /* the added pulse: only after the shutter closed, and only inside a window */
        size_t added = 0;
        for (size_t i = pulse_from; i < m.n_edges; i++)
            added += m.edges[i].level && m.edges[i].t > m.shutter_off;
        CHECK_MSG(added == (g == 0), "glitch at %u: %zu pulses after the shutter", glitch_at[g],
                  added);
        model_free(&m);
    }
}

TEST(firmware_logic_exposure_faults_stop_everything)
{
    enum { N = 300 };
    uint32_t times[N];
    for (size_t i = 0; i < N; i++) times[i] = 5 + (uint32_t)i * 20000u;
    /* a spurious crossing in cycle 50 */
    model m;
    memset(&m, 0, sizeof m);
    fw_tracker_reset(&m.trk);
    for (size_t i = 0; i <= 80; i++) model_crossing(&m, times[i]);
    CHECK(fw_expo_configure(&m.ex, 10, 3, 150, FW_MODE_LOCKED) == FW_OK);
    model_arm(&m, times[80] + 50);
    for (size_t i = 81; i < N; i++) {
        if (i == 131) model_crossing(&m, times[i] - 7000);
        model_crossing(&m, times[i]);
    }
    model_run_compares(&m, times[N - 1] + 100000);
    CHECK(m.fault == FW_SPURIOUS && m.done == 0 && m.ex.state == FW_ST_FAULT);
    CHECK_MSG(m.ex.n == 49, "fault reported in cycle %u, the glitch is in 49", m.ex.n);
    CHECK(m.trig == 0 && !m.shutter && m.shutter_off == times[131] - 7000);
    CHECK_MSG(m.log_n == 49, "%u cycles logged", m.log_n);
    /* the host's STOP */
    fw_action a = {0, 0, 0, 0, 0, 0};
    memset(&m.ex, 0, sizeof m.ex);
    fw_tracker_reset(&m.trk);
    for (size_t i = 0; i <= 80; i++) model_crossing(&m, times[i]);
    CHECK(fw_expo_configure(&m.ex, 10, 3, 150, FW_MODE_LOCKED) == FW_OK);
    model_arm(&m, times[80] + 50);
    fw_expo_abort(&m.ex, FW_STOPPED, &a);
    CHECK(m.ex.state == FW_ST_IDLE && !(a.flags & FW_ACT_FAULT));
    CHECK(a.flags & FW_ACT_TRIGGER_LOW && a.flags & FW_ACT_SHUTTER_OFF);
    /* a second hand-over while the first is still waiting is an internal LATE */
    m.ex.chain_active = 1;
    m.ex.has_pending = 1;
    fw_action b = {0, 0, 0, 0, 0, 0};
    CHECK(chain_hand_over(&m.ex, 1, 5, &b) == FW_LATE);
    /* an unplanned cycle is an internal LATE too */
    memset(&m.ex, 0, sizeof m.ex);
    CHECK(fw_expo_configure(&m.ex, 10, 3, 150, FW_MODE_LOCKED) == FW_OK);
    m.ex.state = FW_ST_EXPOSING;
    m.ex.plan_ok = 0;
    fw_expo_crossing_fast(&m.ex, 1234, &b);
    CHECK((b.flags & FW_ACT_ABORT) && b.abort_fault == FW_LATE);
    model_free(&m);
}

/* ------------------------------------------------------------------ protocol */

static uint8_t parse(const char *line, fw_cmd *c)
{
    return fw_parse(line, (uint8_t)strlen(line), c);
}

TEST(firmware_logic_proto_parse)
{
    fw_cmd c;
    CHECK(parse("CFG 20 3 500 L", &c) == FW_PERR_OK && c.kind == FW_CMD_CFG);
    CHECK(c.K == 20 && c.k == 3 && c.C == 500 && c.mode == FW_MODE_LOCKED);
    CHECK(parse("CFG 26 25 1000000 F", &c) == FW_PERR_OK && c.mode == FW_MODE_FREE);
    CHECK(parse("", &c) == FW_PERR_OK && c.kind == FW_CMD_NONE);
    static const struct {
        const char *line;
        uint8_t kind;
    } ok[] = {{"PING", FW_CMD_PING},     {"VER", FW_CMD_VER},     {"START", FW_CMD_START},
              {"STOP", FW_CMD_STOP},     {"STATUS", FW_CMD_STATUS}, {"COUNT", FW_CMD_COUNT},
              {"HALF", FW_CMD_HALF}};
    for (size_t i = 0; i < sizeof ok / sizeof ok[0]; i++)
        CHECK_MSG(parse(ok[i].line, &c) == FW_PERR_OK && c.kind == ok[i].kind, "%s", ok[i].line);
    static const struct {
        const char *line;
        uint8_t err;
    } bad[] = {
        {"ping", FW_PERR_SYNTAX},           {"PING ", FW_PERR_SYNTAX},
        {" PING", FW_PERR_SYNTAX},          {"PING  X", FW_PERR_SYNTAX},
        {"PING X", FW_PERR_SYNTAX},         {"CFG 20 3 500", FW_PERR_SYNTAX},
        {"CFG 20 3 500 L X", FW_PERR_SYNTAX}, {"CFG 20 3 5x0 L", FW_PERR_SYNTAX},
        {"CFG -2 3 500 L", FW_PERR_SYNTAX}, {"CFG 20 3 500 LL", FW_PERR_SYNTAX},
        {"CFG 20 3 500 X", FW_PERR_RANGE},  {"CFG 27 3 500 L", FW_PERR_RANGE},
        {"CFG 1 0 500 L", FW_PERR_RANGE},   {"CFG 20 20 500 L", FW_PERR_RANGE},
        {"CFG 20 3 0 L", FW_PERR_RANGE},    {"CFG 20 3 1000001 L", FW_PERR_RANGE},
        {"CFG 20 3 99999999999 L", FW_PERR_RANGE}, {"CFG 256 3 5 L", FW_PERR_RANGE},
        {"PING*", FW_PERR_SYNTAX},          {"PING*4", FW_PERR_SYNTAX},
        {"PING*4G", FW_PERR_SYNTAX},        {"PING*00", FW_PERR_CHECKSUM},
        {"PI\tNG", FW_PERR_SYNTAX},         {"STOP*1B*00", FW_PERR_SYNTAX}};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        uint8_t e = parse(bad[i].line, &c);
        CHECK_MSG(e == bad[i].err, "'%s' -> %s, expected %s", bad[i].line, fw_perr_name(e),
                  fw_perr_name(bad[i].err));
    }
    /* a valid checksum, in either case of hex digit */
    char line[32];
    snprintf(line, sizeof line, "STATUS*%02X", fw_checksum("STATUS", 6));
    CHECK(parse(line, &c) == FW_PERR_OK && c.kind == FW_CMD_STATUS);
    snprintf(line, sizeof line, "STATUS*%02x", fw_checksum("STATUS", 6));
    CHECK(parse(line, &c) == FW_PERR_OK);
}

TEST(firmware_logic_proto_lines_and_numbers)
{
    fw_linebuf lb;
    fw_linebuf_reset(&lb);
    const char *in = "PING\r\nSTATUS\n";
    int lines = 0;
    for (const char *p = in; *p; p++)
        if (fw_linebuf_feed(&lb, *p) == 1) {
            CHECK(lines != 0 || strcmp(lb.buf, "PING") == 0);
            CHECK(lines != 1 || strcmp(lb.buf, "STATUS") == 0);
            lines++;
            fw_linebuf_reset(&lb);
        }
    CHECK(lines == 2);
    /* an overlong line is reported once, at its newline, and the next line is clean */
    uint8_t r = 0;
    for (int i = 0; i < 100; i++) CHECK((r = fw_linebuf_feed(&lb, 'A')) == 0);
    CHECK(fw_linebuf_feed(&lb, '\n') == 2);
    fw_linebuf_reset(&lb);
    for (const char *p = "PING"; *p; p++) fw_linebuf_feed(&lb, *p);
    CHECK(fw_linebuf_feed(&lb, '\n') == 1 && strcmp(lb.buf, "PING") == 0);
    /* exactly FW_LINE_MAX characters still fit */
    fw_linebuf_reset(&lb);
    for (unsigned i = 0; i < FW_LINE_MAX; i++) fw_linebuf_feed(&lb, 'B');
    CHECK(fw_linebuf_feed(&lb, '\n') == 1 && lb.len == FW_LINE_MAX);

    static const uint32_t v[] = {0, 9, 10, 99, 100, 1000000, 4294967295u, 10000500};
    for (size_t i = 0; i < sizeof v / sizeof v[0]; i++) {
        fw_out o;
        fw_out_begin(&o);
        fw_out_u32(&o, v[i]);
        o.buf[o.len] = '\0';
        char want[16];
        snprintf(want, sizeof want, "%lu", (unsigned long)v[i]);
        CHECK_MSG(strcmp(o.buf, want) == 0, "%s vs %s", o.buf, want);
    }
    fw_out o;
    fw_out_begin(&o);
    fw_out_str(&o, "OK PING");
    fw_out_end(&o);
    CHECK(o.len == 11 && memcmp(o.buf, "OK PING*", 8) == 0 && o.buf[10] == '\n');
    char hex[3] = {o.buf[8], o.buf[9], 0};
    CHECK(strtoul(hex, NULL, 16) == fw_checksum("OK PING", 7));
    /* output never overruns its buffer */
    fw_out_begin(&o);
    for (int i = 0; i < 300; i++) fw_out_char(&o, 'x');
    fw_out_end(&o);
    CHECK(o.len == FW_OUT_MAX && o.buf[FW_OUT_MAX - 1] == '\n');
}
