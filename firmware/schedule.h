/*
 * schedule.h - the timing core of the ACam controller firmware (prefix fw_): zero-crossing
 * tracking (half-period estimation, glitch and frequency checks) and AC-locked or free-running
 * scheduling of the DMD mask-switch trigger (paper Sec. 6, "AC-locked mask switching", Fig. 7).
 *
 * Plain C11 with no I/O and no interrupts: firmware/main.c calls it from its Timer1 interrupt
 * handlers on the ATmega328P (avr-gcc), and tests/test_firmware_logic.c compiles the same file
 * with the host gcc and drives it with synthetic crossing times.
 *
 * Time base: Timer1 ticks, F_CPU / 8 = 2 MHz on a 16 MHz Arduino Uno, so 1 tick = 0.5 us =
 * 8 CPU cycles. Times are 16-bit tick counts that wrap every 32.768 ms; only differences of
 * less than 2^15 ticks are ever formed, so the wrap is harmless.
 *
 * Model (docs/firmware.md): crossing n at time t_n starts flicker cycle n, which lasts
 * Delta_n = t_{n+1} - t_n (Eq. 1: f = 1 / (2 Delta)). Window k of K is [k Delta/K, (k+1) Delta/K).
 * Locked mode predicts Delta_n by Delta_{n-2}, the half period of the same polarity one AC
 * period earlier (the zero-crossing detector's asymmetry and the mains' even harmonics make
 * successive half periods alternate by 10-30 us; same-polarity ones agree to ~2 us rms on the
 * ENF-WHU recordings), and re-anchors every cycle on the crossing just detected:
 *   edge j of cycle n at t_n + round(j Delta_{n-2} / K),  j = k (window start), k+1 (end).
 * Free-running mode fixes Delta_0, the mean of the 64 half periods before the start, and
 * never re-anchors: edge j of cycle n at t_0 + n Delta_0 + j Delta_0 / K (1/256-tick fixed point).
 */
#ifndef GRIDSURVEY_FW_SCHEDULE_H
#define GRIDSURVEY_FW_SCHEDULE_H

#include <stdint.h>

/* ------------------------------------------------------------------ constants */

#define FW_TICK_CYCLES 8u        /* CPU cycles per Timer1 tick (prescaler 8) */
#define FW_TICK_NS 500u          /* at F_CPU = 16 MHz */
#define FW_TICKS_PER_S 2000000ul

#define FW_HIST 64u              /* half periods kept (power of two): lock needs this many */
#define FW_GLITCH_SHIFT 4        /* a half period may differ from its prediction by 1/16 */
#define FW_PULSE_TICKS 100u      /* trigger pulse width, 50 us (only the rising edge counts) */
/* Compare events are scheduled this many ticks early: the compare flag rises one timer tick
 * after TCNT1 reaches OCR1A (ATmega328P datasheet 16.7), the edge follows within ~1 us. */
#define FW_COMPARE_LEAD_TICKS 1u
/* Shortest time a DMD mask may be held: the paper's DMD switches masks at 2.7 kHz at most
 * (Sec. 1), i.e. 370.4 us = 740.7 ticks; rounded up. This is what limits K to 26 at 50 Hz
 * (10 ms / 26 = 384.6 us) and to 22 at 60 Hz (8.33 ms / 22 = 378.8 us) (Fig. 7). */
#define FW_MIN_HOLD_TICKS 741u
#define FW_K_MIN 2u
#define FW_K_MAX_50 26u          /* paper Fig. 7 */
#define FW_K_MAX_60 22u          /* paper Fig. 7 */
#define FW_C_MAX 1000000ul       /* paper: C = 100 ... 1500 cycles in practice */

/* Accepted grid frequencies, nominal +-3 Hz, as full AC periods in ticks. */
#define FW_P50_MIN_TICKS 37736u  /* 53 Hz */
#define FW_P50_MAX_TICKS 42553u  /* 47 Hz */
#define FW_P60_MIN_TICKS 31746u  /* 63 Hz */
#define FW_P60_MAX_TICKS 35088u  /* 57 Hz */
/* Before two half periods are known, a half period must lie within 30-70 % of an accepted
 * full period (detector asymmetry up to 40/60). */
#define FW_HALF_MIN_TICKS 9524u  /* 0.3 x 31746 */
#define FW_HALF_MAX_TICKS 29787u /* 0.7 x 42553 */

/* ------------------------------------------------------------------ faults */

/* Why a crossing was rejected or an exposure stopped (docs/firmware.md, EV FAULT). */
typedef enum {
    FW_OK = 0,
    FW_SPURIOUS,   /* a crossing came more than 1/16 of the predicted half period early */
    FW_MISSING,    /* no crossing by 1/16 after the predicted one (or a half period too long) */
    FW_FREQ,       /* a full AC period outside 47-53 Hz / 57-63 Hz, or a 50/60 Hz change */
    FW_LIMIT,      /* a window shorter than FW_MIN_HOLD_TICKS, or K above the grid's limit */
    FW_LATE,       /* internal: a trigger event would have been scheduled in the past */
    FW_OVERFLOW,   /* internal: the record queue to the serial line overflowed */
    FW_STOPPED,    /* the host sent STOP */
    FW_FAULT_COUNT
} fw_fault;

/* A static upper-case name ("OK", "SPURIOUS", ...); "?" for an unknown code. */
const char *fw_fault_name(uint8_t fault);

/* ------------------------------------------------------------------ tracker */

/* The zero-crossing tracker: the last FW_HIST half periods and their sum. (Scalars first: on
 * the AVR a field within 63 bytes of the pointer is one instruction away.) */
typedef struct {
    uint32_t sum_ticks;           /* sum of the last min(good, FW_HIST) half periods */
    uint16_t last_ticks;          /* time of the last accepted crossing */
    uint8_t idx;                  /* next write position */
    uint8_t good;                 /* consecutive accepted half periods (saturates at 255) */
    uint8_t have_ref;             /* last_ticks holds a crossing */
    uint8_t grid_hz;              /* 50 or 60 once locked, else 0 */
    uint16_t hist_ticks[FW_HIST]; /* half periods, the newest at hist_ticks[(idx - 1) % FW_HIST] */
} fw_tracker;

void fw_tracker_reset(fw_tracker *t);
/* A crossing at time now_ticks. Returns FW_OK and the half period that just ended in
 * *delta_ticks (0 when this is the first crossing after a reset), or a fault (FW_SPURIOUS,
 * FW_MISSING, FW_FREQ) after which the tracker restarts from this crossing. */
uint8_t fw_tracker_crossing(fw_tracker *t, uint16_t now_ticks, uint16_t *delta_ticks);
/* No crossing arrived by the deadline: resets the tracker (the next crossing is a new start). */
void fw_tracker_timeout(fw_tracker *t);
/* Locked: FW_HIST consecutive good half periods whose mean is in a grid band (grid_hz set). */
uint8_t fw_tracker_locked(const fw_tracker *t);
/* Prediction of the half period now running (Delta_{n-2}); 0 if fewer than two are known. */
uint16_t fw_tracker_predict(const fw_tracker *t);
/* Prediction of the half period after it (Delta_{n-1}, the newest); 0 if none is known. */
uint16_t fw_tracker_predict_next(const fw_tracker *t);
/* The deadline fw_tracker_deadline will give once a crossing now arriving is accepted (the
 * prediction for the half period after it is the newest one known now). */
uint16_t fw_tracker_next_deadline(const fw_tracker *t);
/* Ticks after the last crossing at which the next one is overdue: prediction + 1/16, or
 * FW_HALF_MAX_TICKS without a prediction. */
uint16_t fw_tracker_deadline(const fw_tracker *t);
/* Grid of a full AC period: 50, 60 or 0 (out of range). */
uint8_t fw_grid_of_period(uint16_t period_ticks);

/* ------------------------------------------------------------------ exposure */

enum { FW_MODE_LOCKED = 0, FW_MODE_FREE = 1 };
enum { FW_ST_IDLE = 0, FW_ST_ARMED, FW_ST_EXPOSING, FW_ST_DONE, FW_ST_FAULT };

#define FW_CHAIN_MAX 4
#define FW_SLOTS 3

/* The trigger events of one cycle, in time order: compare values anchor_ticks + off_ticks[i]
 * (the due times less FW_COMPARE_LEAD_TICKS) and the level each sets (bit i of levels). Three
 * slots rotate: the cycle running (possibly still finishing, window K-1), the one handed over,
 * and the one being planned; nothing is copied in the interrupt handlers. */
typedef struct {
    uint16_t off_ticks[FW_CHAIN_MAX];
    uint16_t anchor_ticks;
    uint8_t levels;
    uint8_t count;
} fw_chain;

typedef struct {
    /* run state (hot fields first, see fw_tracker) */
    uint8_t state, fault;
    uint8_t cur, cur_i;           /* slot of the running chain, and its next event */
    uint8_t chain_active, has_pending, pending;
    uint8_t plan, plan_ok;        /* locked: slot planned for the next cycle, and ready */
    uint8_t events_done, log_done;
    uint8_t rise_at_crossing;     /* raise the trigger at the next crossing (cycle start) */
    /* rising trigger edges since the DMD last showed a zero mask, mod 2, counted where they are
     * made: at crossings (fw_expo_crossing_fast) and at compare events (fw_expo_compare); each
     * written by one interrupt only. Odd: the DMD shows a window's mask m_j (Eq. 23). */
    uint8_t rises_zc, rises_cmp;
    uint32_t n;                   /* exposure cycle that started at the last crossing */
    uint32_t chain_cycle;         /* cycle whose events the running chain holds */
    uint32_t pending_cycle;
    uint32_t anchor_q8;           /* free-running: t_0 + chain_cycle Delta_0, 1/256 ticks */
    /* configuration (fw_expo_configure) */
    uint8_t K, k, mode;
    uint8_t configured;
    uint32_t C;
    /* fixed at arming (fw_expo_prepare) */
    uint16_t m_start, m_end;      /* round(65536 j / K) for j = k, k + 1 (locked) */
    uint16_t plan_pred;           /* the prediction cycle 0 was planned with (EV START) */
    uint32_t period_q8;           /* free-running Delta_0, 1/256 ticks */
    uint32_t off_start_q8, off_end_q8; /* free-running k Delta_0 / K, (k+1) Delta_0 / K */
    fw_chain slot[FW_SLOTS];
} fw_expo;

/* What the interrupt handler must do after a call (bits of fw_action.flags). */
enum {
    FW_ACT_ARM_COMPARE = 1u << 0,  /* set the compare to compare_ticks, next level next_level */
    FW_ACT_STOP_COMPARE = 1u << 1, /* no more events in this chain (the compare goes quiet) */
    FW_ACT_SHUTTER_ON = 1u << 2,
    FW_ACT_SHUTTER_OFF = 1u << 3,
    FW_ACT_TRIGGER_LOW = 1u << 4,  /* force the trigger low (exposure stopped) */
    FW_ACT_LOG = 1u << 5,          /* record "cycle log_cycle lasted log_ticks" */
    FW_ACT_STARTED = 1u << 6,      /* the exposure began at this crossing */
    FW_ACT_DONE = 1u << 7,         /* the exposure completed */
    FW_ACT_FAULT = 1u << 8,        /* the exposure stopped with e->fault */
    FW_ACT_ABORT = 1u << 9,        /* call fw_expo_abort(abort_fault) with interrupts off */
    FW_ACT_CLOSE_PULSE = 1u << 10  /* after the shutter: one more trigger pulse, so that the
                                    * DMD steps from m_j to the zero mask after it (a stop
                                    * inside a window) */
};

typedef struct {
    uint16_t flags;
    uint16_t compare_ticks;
    uint8_t next_level;
    uint8_t abort_fault;
    uint32_t log_cycle;
    uint16_t log_ticks;            /* FW_ACT_LOG: the half period; FW_ACT_STARTED: the prediction */
} fw_action;

/* Sets and validates the configuration: FW_K_MIN <= K <= FW_K_MAX_50, k < K, 1 <= C <= FW_C_MAX,
 * mode FW_MODE_LOCKED or FW_MODE_FREE, and zeroes the cycle count. Returns FW_OK or FW_LIMIT
 * (nothing changed). Not while an exposure is armed or running (the caller answers BUSY). */
uint8_t fw_expo_configure(fw_expo *e, uint8_t K, uint8_t k, uint32_t C, uint8_t mode);
/* What arming needs of the tracker: a few bytes that the firmware copies with interrupts off. */
typedef struct {
    uint8_t locked, grid_hz;
    uint16_t newest_ticks, previous_ticks; /* the last two half periods */
    uint32_t sum_ticks;                    /* of the last FW_HIST */
} fw_lock_info;
void fw_tracker_lock_info(const fw_tracker *t, fw_lock_info *info);
/* Prepares an exposure to start at the crossing after the one `info` was taken at: needs a lock,
 * K within the grid's limit (26 at 50 Hz, 22 at 60 Hz) and windows of at least
 * FW_MIN_HOLD_TICKS. Returns FW_OK, FW_LIMIT, or FW_MISSING when not locked (the caller reports
 * "NOLOCK"). Touches only what the interrupt handlers ignore until fw_expo_commit. */
uint8_t fw_expo_prepare(fw_expo *e, const fw_lock_info *info);
/* Arms the prepared exposure and opens the shutter (a few stores: call with interrupts off,
 * and only if no crossing came since the lock info was taken). The DMD shows mask 0 until the
 * first window, so the camera integrates nothing before it. */
void fw_expo_commit(fw_expo *e, fw_action *a);
/* fw_tracker_lock_info + fw_expo_prepare + fw_expo_commit, for callers without interrupts. */
uint8_t fw_expo_arm(fw_expo *e, const fw_tracker *t, fw_action *a);
/* A crossing at now_ticks, in two parts. fw_expo_crossing_fast runs first in the capture
 * handler, before the crossing is even checked: it starts an armed exposure or counts the
 * cycle, and hands the planned chain of the cycle starting now to the compare (locked). Then
 * the tracker judges the crossing, and fw_expo_crossing_slow takes its verdict (a bad one asks
 * for fw_expo_abort through FW_ACT_ABORT), logs the half period that ended, and plans the next
 * cycle (a window shorter than the DMD can hold asks for FW_LIMIT). Both may run with interrupts
 * on (see schedule.c). */
void fw_expo_crossing_fast(fw_expo *e, uint16_t now_ticks, fw_action *a);
void fw_expo_crossing_slow(fw_expo *e, const fw_tracker *t, uint8_t verdict,
                           uint16_t delta_ticks, fw_action *a);
/* Event cur_i of the running chain (slot cur) just fired (its level is already applied).
 * Call with interrupts off (it is the compare interrupt). */
void fw_expo_compare(fw_expo *e, fw_action *a);
/* Declares the exposure done once its last events ran and its C half periods were logged.
 * Call with interrupts off after fw_expo_crossing_slow (fw_expo_compare calls it itself). */
void fw_expo_finish(fw_expo *e, fw_action *a);
/* Stops an exposure (FW_STOPPED from the host, FW_MISSING from the timeout, FW_LATE, ...). A stop
 * after an odd number of rising edges (inside a window, or at a crossing that raised window 0)
 * asks for FW_ACT_CLOSE_PULSE: the DMD then rests on a zero mask and the next exposure finds
 * M = [m1 0 m2 0 ...] where it expects it. */
void fw_expo_abort(fw_expo *e, uint8_t fault, fw_action *a);

/* Offset of edge j (0..K) after the anchoring crossing for a predicted half period, locked mode:
 * round(j pred / K) via the multipliers fixed at arming (error < 0.7 tick). */
uint16_t fw_locked_offset(const fw_expo *e, uint16_t pred_ticks, uint8_t j);

#endif
