/* schedule.c - the timing core of the ACam controller (see schedule.h and docs/firmware.md):
 * zero-crossing tracking and the AC-locked / free-running trigger schedule of the paper's
 * Sec. 6 ("AC-locked mask switching", Figs. 7 and 9). Plain C11: built by avr-gcc into the
 * firmware and by the host gcc into the unit tests.
 *
 * Concurrency contract (firmware/main.c): fw_tracker_* and fw_expo_crossing_fast/_slow run in
 * the capture interrupt with interrupts enabled, so the compare interrupt (fw_expo_compare) may
 * preempt them. They share the running chain only through the mailbox `pending`/`has_pending`
 * (a slot index): the capture side writes the mailbox and only then looks at chain_active; when
 * no chain is active no compare event is due (the compare register still holds the last event,
 * 32.8 ms away), so nothing can race a direct load. The slot being planned is never the running
 * or the handed-over one. State changes that both sides make (fw_expo_finish, fw_expo_abort)
 * are called with interrupts disabled. */
#include "firmware/schedule.h"

#include <stdatomic.h>

/* Keeps the compiler from moving memory accesses across this point (no CPU fence needed on a
 * single-core AVR). */
#define FW_BARRIER() atomic_signal_fence(memory_order_seq_cst)

static const char *const fault_names[FW_FAULT_COUNT] = {
    "OK", "SPURIOUS", "MISSING", "FREQ", "LIMIT", "LATE", "OVERFLOW", "STOPPED"};

const char *fw_fault_name(uint8_t fault)
{
    return fault < FW_FAULT_COUNT ? fault_names[fault] : "?";
}

/* ------------------------------------------------------------------ tracker */

void fw_tracker_reset(fw_tracker *t)
{
    t->sum_ticks = 0;
    t->last_ticks = 0;
    t->idx = 0;
    t->good = 0;
    t->have_ref = 0;
    t->grid_hz = 0;
}

uint8_t fw_grid_of_period(uint16_t period_ticks)
{
    if (period_ticks >= FW_P50_MIN_TICKS && period_ticks <= FW_P50_MAX_TICKS) return 50;
    if (period_ticks >= FW_P60_MIN_TICKS && period_ticks <= FW_P60_MAX_TICKS) return 60;
    return 0;
}

/* The half period `back` entries before the newest one (back = 1: the newest). */
static uint16_t hist_back(const fw_tracker *t, uint8_t back)
{
    return t->hist_ticks[(uint8_t)(t->idx - back) & (FW_HIST - 1u)];
}

uint8_t fw_tracker_crossing(fw_tracker *t, uint16_t now_ticks, uint16_t *delta_ticks)
{
    *delta_ticks = 0;
    if (!t->have_ref) {
        t->last_ticks = now_ticks;
        t->have_ref = 1;
        return FW_OK;
    }
    uint16_t d = (uint16_t)(now_ticks - t->last_ticks);
    t->last_ticks = now_ticks;
    *delta_ticks = d;

    uint8_t verdict = FW_OK;
    if (t->good >= 2) {
        /* Delta_{n-2} predicts Delta_n (same polarity); +-1/16 covers the grid's wander and
         * the detector's jitter with a wide margin (docs/firmware.md) */
        uint16_t pred = hist_back(t, 2), tol = (uint16_t)(pred >> FW_GLITCH_SHIFT);
        if (d < (uint16_t)(pred - tol)) verdict = FW_SPURIOUS;
        else if (d > (uint16_t)(pred + tol)) verdict = FW_MISSING;
    } else if (d < FW_HALF_MIN_TICKS) {
        verdict = FW_SPURIOUS;
    } else if (d > FW_HALF_MAX_TICKS) {
        verdict = FW_MISSING;
    }
    if (verdict == FW_OK && t->good >= 1) {
        /* a full AC period (immune to the half-period alternation) must be in a grid band */
        uint8_t g = fw_grid_of_period((uint16_t)(d + hist_back(t, 1)));
        if (!g || (t->grid_hz && g != t->grid_hz)) verdict = FW_FREQ;
    }
    if (verdict != FW_OK) {
        t->good = 0;     /* restart from this crossing: FW_HIST fresh half periods to re-lock */
        t->sum_ticks = 0;
        t->grid_hz = 0;
        return verdict;
    }
    if (t->good >= FW_HIST) t->sum_ticks -= t->hist_ticks[t->idx];
    t->hist_ticks[t->idx] = d;
    t->idx = (uint8_t)((t->idx + 1u) & (FW_HIST - 1u));
    t->sum_ticks += d;
    if (t->good < 255) t->good++;
    if (t->good >= FW_HIST && !t->grid_hz) {
        /* mean full period of the last FW_HIST half periods = sum / (FW_HIST / 2) */
        t->grid_hz = fw_grid_of_period((uint16_t)(t->sum_ticks / (FW_HIST / 2u)));
    }
    return FW_OK;
}

void fw_tracker_timeout(fw_tracker *t)
{
    fw_tracker_reset(t);
}

uint8_t fw_tracker_locked(const fw_tracker *t)
{
    return t->good >= FW_HIST && t->grid_hz != 0;
}

uint16_t fw_tracker_predict(const fw_tracker *t)
{
    return t->good >= 2 ? hist_back(t, 2) : 0;
}

uint16_t fw_tracker_predict_next(const fw_tracker *t)
{
    return t->good >= 1 ? hist_back(t, 1) : 0;
}

static uint16_t deadline_of(uint16_t pred)
{
    return pred ? (uint16_t)(pred + (pred >> FW_GLITCH_SHIFT)) : (uint16_t)FW_HALF_MAX_TICKS;
}

uint16_t fw_tracker_next_deadline(const fw_tracker *t)
{
    return deadline_of(fw_tracker_predict_next(t));
}

uint16_t fw_tracker_deadline(const fw_tracker *t)
{
    return deadline_of(fw_tracker_predict(t));
}

/* ------------------------------------------------------------------ exposure */

uint8_t fw_expo_configure(fw_expo *e, uint8_t K, uint8_t k, uint32_t C, uint8_t mode)
{
    if (K < FW_K_MIN || K > FW_K_MAX_50 || k >= K || C < 1 || C > FW_C_MAX ||
        (mode != FW_MODE_LOCKED && mode != FW_MODE_FREE))
        return FW_LIMIT;
    e->K = K;
    e->k = k;
    e->C = C;
    e->mode = mode;
    e->configured = 1;
    e->n = 0; /* STATUS counts the cycles of the exposure configured */
    return FW_OK;
}

/* round(65536 j / K) for 0 < j < K */
static uint16_t multiplier(uint8_t j, uint8_t K)
{
    return (uint16_t)((((uint32_t)j << 16) + K / 2u) / K);
}

uint16_t fw_locked_offset(const fw_expo *e, uint16_t pred_ticks, uint8_t j)
{
    if (j == 0) return 0;
    if (j >= e->K) return pred_ticks;
    uint16_t m = j == e->k ? e->m_start : e->m_end;
    return (uint16_t)(((uint32_t)pred_ticks * m + 0x8000u) >> 16);
}

static uint8_t plan_locked(fw_expo *e, uint16_t pred);

void fw_tracker_lock_info(const fw_tracker *t, fw_lock_info *info)
{
    info->locked = fw_tracker_locked(t);
    info->grid_hz = t->grid_hz;
    info->newest_ticks = t->good >= 1 ? hist_back(t, 1) : 0;
    info->previous_ticks = t->good >= 2 ? hist_back(t, 2) : 0;
    info->sum_ticks = t->sum_ticks;
}

uint8_t fw_expo_prepare(fw_expo *e, const fw_lock_info *info)
{
    if (!e->configured) return FW_LIMIT;
    if (!info->locked) return FW_MISSING;
    if (e->K > (info->grid_hz == 60 ? FW_K_MAX_60 : FW_K_MAX_50)) return FW_LIMIT;
    /* the shorter of the two polarities must still give windows the DMD can hold */
    uint16_t shorter =
        info->newest_ticks < info->previous_ticks ? info->newest_ticks : info->previous_ticks;
    if ((uint32_t)FW_MIN_HOLD_TICKS * e->K > shorter) return FW_LIMIT;

    e->m_start = e->k ? multiplier(e->k, e->K) : 0;
    e->m_end = (uint8_t)(e->k + 1u) < e->K ? multiplier((uint8_t)(e->k + 1u), e->K) : 0;
    /* free running: Delta_0 = (sum of the last 64 half periods) / 64, in 1/256 ticks exactly */
    e->period_q8 = info->sum_ticks * (256u / FW_HIST);
    e->off_start_q8 = (e->period_q8 * e->k + e->K / 2u) / e->K;
    e->off_end_q8 = (e->period_q8 * (uint32_t)(e->k + 1u) + e->K / 2u) / e->K;
    if (e->mode == FW_MODE_LOCKED) {
        /* cycle 0 starts at the next crossing; Delta_{-2} is the newest half period */
        e->plan = 0;
        e->plan_pred = info->newest_ticks;
        if (plan_locked(e, e->plan_pred) != FW_OK) return FW_LIMIT;
    }
    return FW_OK;
}

void fw_expo_commit(fw_expo *e, fw_action *a)
{
    a->flags = FW_ACT_SHUTTER_ON;
    e->fault = FW_OK;
    e->n = 0;
    e->chain_cycle = 0;
    e->chain_active = 0;
    e->has_pending = 0;
    e->cur = 0;
    e->cur_i = 0;
    e->events_done = 0;
    e->log_done = 0;
    e->rise_at_crossing = e->k == 0; /* window 0 starts at the crossing itself */
    e->state = FW_ST_ARMED;
}

uint8_t fw_expo_arm(fw_expo *e, const fw_tracker *t, fw_action *a)
{
    fw_lock_info info;
    fw_tracker_lock_info(t, &info);
    a->flags = 0;
    uint8_t r = fw_expo_prepare(e, &info);
    if (r == FW_OK) fw_expo_commit(e, a);
    return r;
}

static uint8_t next_slot(uint8_t slot)
{
    return slot == FW_SLOTS - 1u ? 0 : (uint8_t)(slot + 1u);
}

/* Adds an event due at anchor + at_ticks (armed FW_COMPARE_LEAD_TICKS early). */
static void chain_add(fw_chain *c, uint16_t at_ticks, uint8_t level)
{
    c->off_ticks[c->count] = (uint16_t)(at_ticks - FW_COMPARE_LEAD_TICKS);
    if (level) c->levels |= (uint8_t)(1u << c->count);
    c->count++;
}

/* Makes slot the running chain (of cycle `cycle`) and asks for its first compare. */
static void chain_load(fw_expo *e, uint8_t slot, uint32_t cycle, fw_action *a)
{
    const fw_chain *c = &e->slot[slot];
    e->cur = slot;
    e->cur_i = 0;
    e->chain_cycle = cycle;
    e->chain_active = 1;
    a->flags |= FW_ACT_ARM_COMPARE;
    a->compare_ticks = (uint16_t)(c->anchor_ticks + c->off_ticks[0]);
    a->next_level = c->levels & 1u;
}

/* Free running: the events of cycle e->chain_cycle (anchor_q8 = t_0 + n Delta_0) into slot,
 * as absolute times, and loads them. */
static void chain_free(fw_expo *e, uint8_t slot, uint8_t skip_first_rise, fw_action *a)
{
    fw_chain *c = &e->slot[slot];
    uint16_t s = (uint16_t)((e->anchor_q8 + e->off_start_q8 + 128u) >> 8);
    uint16_t end = (uint16_t)((e->anchor_q8 + e->off_end_q8 + 128u) >> 8);
    c->count = 0;
    c->levels = 0;
    c->anchor_ticks = 0;
    if (!skip_first_rise) chain_add(c, s, 1);
    chain_add(c, (uint16_t)(s + FW_PULSE_TICKS), 0);
    chain_add(c, end, 1);
    chain_add(c, (uint16_t)(end + FW_PULSE_TICKS), 0);
    chain_load(e, slot, e->chain_cycle, a);
}

/* Locked: plans the events of the next cycle into slot e->plan, as offsets from its crossing,
 * for a predicted half period pred. FW_LIMIT (nothing planned) when its window would be shorter
 * than the DMD's hold time. */
static uint8_t plan_locked(fw_expo *e, uint16_t pred)
{
    uint16_t s = fw_locked_offset(e, pred, e->k);
    uint16_t end = fw_locked_offset(e, pred, (uint8_t)(e->k + 1u));
    e->plan_ok = 0;
    if (!pred || (uint16_t)(end - s) < FW_MIN_HOLD_TICKS) return FW_LIMIT;
    fw_chain *c = &e->slot[e->plan];
    c->count = 0;
    c->levels = 0;
    if (e->k == 0) {
        chain_add(c, FW_PULSE_TICKS, 0); /* the rise is done at the crossing */
    } else {
        chain_add(c, s, 1);
        chain_add(c, (uint16_t)(s + FW_PULSE_TICKS), 0);
    }
    chain_add(c, end, 1);
    chain_add(c, (uint16_t)(end + FW_PULSE_TICKS), 0);
    e->plan_ok = 1;
    return FW_OK;
}

/* Hands the chain in slot (of `cycle`) over: through the mailbox when a chain is still running
 * (window K-1 ends at the predicted crossing, which may come after the real one). */
static uint8_t chain_hand_over(fw_expo *e, uint8_t slot, uint32_t cycle, fw_action *a)
{
    if (e->has_pending) return FW_LATE; /* the previous hand-over was never taken */
    e->pending = slot;
    e->pending_cycle = cycle;
    FW_BARRIER();
    e->has_pending = 1;
    FW_BARRIER();
    if (!e->chain_active) { /* no compare event is due: nobody else can take the mailbox */
        e->has_pending = 0;
        chain_load(e, slot, cycle, a);
    }
    return FW_OK;
}

void fw_expo_crossing_fast(fw_expo *e, uint16_t now_ticks, fw_action *a)
{
    a->flags = 0;
    uint8_t st = e->state;
    if (st != FW_ST_ARMED && st != FW_ST_EXPOSING) return;
    if (e->rise_at_crossing) e->rises_zc ^= 1u; /* the capture stub raised the trigger */
    if (st == FW_ST_ARMED) {
        e->state = FW_ST_EXPOSING;
        e->n = 0;
        a->flags |= FW_ACT_STARTED;
        if (e->mode != FW_MODE_LOCKED) {
            a->log_ticks = 0;
            e->anchor_q8 = (uint32_t)now_ticks << 8;
            e->chain_cycle = 0;
            chain_free(e, 0, e->k == 0, a);
            e->rise_at_crossing = 0; /* only cycle 0 starts at a crossing */
            return;
        }
        a->log_ticks = e->plan_pred;
    } else {
        e->n++; /* the crossing ends cycle n - 1 and starts cycle n */
        if (e->mode != FW_MODE_LOCKED || e->n >= e->C) return;
    }
    /* locked: the chain planned a half period ago, anchored at this crossing */
    uint8_t f = FW_LATE; /* unless the previous crossing planned this cycle */
    if (e->plan_ok) {
        e->plan_ok = 0;
        e->slot[e->plan].anchor_ticks = now_ticks;
        f = chain_hand_over(e, e->plan, e->n, a);
    }
    if (f != FW_OK) {
        a->flags |= FW_ACT_ABORT;
        a->abort_fault = f;
    }
}

void fw_expo_crossing_slow(fw_expo *e, const fw_tracker *t, uint8_t verdict,
                           uint16_t delta_ticks, fw_action *a)
{
    a->flags = 0;
    if (e->state != FW_ST_EXPOSING) return;
    uint8_t f = verdict;
    if (f != FW_OK && e->n > 0) e->n--; /* a bad crossing started no cycle: report the one it hit */
    if (f == FW_OK) {
        if (e->n >= 1 && e->n <= e->C) {
            a->flags |= FW_ACT_LOG;
            a->log_cycle = e->n - 1u;
            a->log_ticks = delta_ticks;
        }
        if (e->n >= e->C) e->log_done = 1;
        if (e->mode == FW_MODE_LOCKED) {
            /* cycle n + 1 is predicted by Delta_{n-1}, the half period that just ended; its
             * slot is the one cycle n - 2 used, long finished */
            if (e->n + 1u < e->C) {
                e->plan = next_slot(e->plan);
                f = plan_locked(e, fw_tracker_predict_next(t));
            }
            e->rise_at_crossing = e->k == 0 && e->n + 1u < e->C;
        }
    }
    if (f != FW_OK) {
        a->flags |= FW_ACT_ABORT;
        a->abort_fault = f;
    }
}

void fw_expo_compare(fw_expo *e, fw_action *a)
{
    a->flags = 0;
    if (!e->chain_active) {
        a->flags |= FW_ACT_STOP_COMPARE;
        return;
    }
    const fw_chain *c = &e->slot[e->cur];
    e->rises_cmp ^= (uint8_t)((c->levels >> e->cur_i) & 1u); /* the level the stub just set */
    uint8_t i = (uint8_t)(e->cur_i + 1u);
    e->cur_i = i;
    if (i < c->count) {
        a->flags |= FW_ACT_ARM_COMPARE;
        a->compare_ticks = (uint16_t)(c->anchor_ticks + c->off_ticks[i]);
        a->next_level = (uint8_t)((c->levels >> i) & 1u);
        return;
    }
    /* the chain of cycle chain_cycle is complete */
    e->chain_active = 0;
    FW_BARRIER();
    if (e->chain_cycle + 1u >= e->C) {
        e->events_done = 1;
        a->flags |= FW_ACT_STOP_COMPARE | FW_ACT_SHUTTER_OFF;
        fw_expo_finish(e, a);
        return;
    }
    if (e->mode == FW_MODE_FREE) {
        e->chain_cycle++;
        e->anchor_q8 += e->period_q8;
        chain_free(e, next_slot(e->cur), 0, a);
        return;
    }
    if (e->has_pending) {
        e->has_pending = 0;
        chain_load(e, e->pending, e->pending_cycle, a);
        return;
    }
    a->flags |= FW_ACT_STOP_COMPARE;
}

void fw_expo_finish(fw_expo *e, fw_action *a)
{
    if (e->state == FW_ST_EXPOSING && e->events_done && e->log_done) {
        e->state = FW_ST_DONE;
        a->flags |= FW_ACT_DONE;
    }
}

void fw_expo_abort(fw_expo *e, uint8_t fault, fw_action *a)
{
    if (e->state != FW_ST_ARMED && e->state != FW_ST_EXPOSING) return;
    e->state = fault == FW_STOPPED ? FW_ST_IDLE : FW_ST_FAULT;
    e->fault = fault;
    e->chain_active = 0;
    e->has_pending = 0;
    e->plan_ok = 0;
    e->rise_at_crossing = 0;
    a->flags &= (uint16_t)~(FW_ACT_ARM_COMPARE | FW_ACT_SHUTTER_ON | FW_ACT_DONE);
    a->flags |= FW_ACT_STOP_COMPARE | FW_ACT_TRIGGER_LOW | FW_ACT_SHUTTER_OFF;
    if (e->rises_zc ^ e->rises_cmp) a->flags |= FW_ACT_CLOSE_PULSE;
    e->rises_zc = e->rises_cmp = 0;
    if (fault != FW_STOPPED) a->flags |= FW_ACT_FAULT;
}
