/*
 * main.c - ACam controller firmware for an Arduino Uno (ATmega328P, 16 MHz): AC-locked DMD
 * mask switching (paper Sec. 6, Figs. 7 and 9) and the serial protocol of docs/firmware.md.
 *
 * Pins (Arduino Uno):
 *   D8  = PB0 = ICP1  zero-crossing input: a square wave that follows the sign of the mains
 *                     voltage (opto-isolated detector); every edge is a crossing
 *   D9  = PB1         DMD mask-switch trigger: a 50 us pulse whose rising edge switches masks
 *   D10 = PB2         exposure (camera shutter): high from START to the end of the last window
 *   D13 = PB5         LED: on while the crossing tracker is locked
 *
 * Timing: Timer1 runs free at F_CPU / 8 (0.5 us ticks). The input capture timestamps every
 * crossing in hardware; the trigger edges are software writes at the start of naked interrupt
 * stubs, so they follow the compare match (or the capture) by ~10 cycles. The stubs need no
 * register: they test bits of GPIOR0 (which the handlers prepare in advance) with sbic/sbis and
 * set PB1 with sbi/cbi, then jump to the C handler. The capture handler re-enables interrupts at
 * once so that a compare event due at the same moment (the end of window K-1 coincides with the
 * next crossing) is not delayed by it; it first hands over the cycle planned a half period
 * earlier, then checks the crossing and plans the next cycle. The UART is polled by the main
 * loop; its interrupts only wake the CPU from idle sleep (naked, one register, ~1 us). No
 * interrupts-off section anywhere is longer than ~30 cycles while an exposure runs, which is
 * what bounds the trigger jitter (docs/firmware.md, "Timing accuracy").
 *
 * All scheduling decisions are in schedule.c (host-testable); this file only moves bits.
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <stdint.h>
#include <util/delay.h>

#include "avr_mcu_section.h"
#include "firmware/proto.h"
#include "firmware/schedule.h"

#if F_CPU != 16000000UL
#error "the tick constants of schedule.h assume F_CPU = 16 MHz"
#endif

/* Lets simavr (tests/test_firmware.c) know the chip and clock; not part of the HEX file. */
AVR_MCU(F_CPU, "atmega328p");

#define PIN_ZC PB0
#define PIN_TRIG PB1
#define PIN_SHUT PB2
#define PIN_LED PB5

/* GPIOR0 bits read by the naked stubs (GPIOR0 is bit-addressable: sbic/sbis/sbi/cbi) */
#define GP_LEVEL 0   /* level the next compare event gives the trigger */
#define GP_RISE 1    /* raise the trigger at the next crossing (window 0 starts there) */
#define GP_INCAPT 2  /* the capture handler is running */
#define GP_LOST 3    /* a capture edge arrived while it was running */

#define UART_UBRR 16u /* 115200 baud with U2X0: 16 MHz / (8 (16 + 1)) = 117647 (+2.1 %) */
#define UCSR0B_IDLE (_BV(RXEN0) | _BV(TXEN0))

/* ------------------------------------------------------------------ shared state */

static fw_tracker g_trk;
static fw_expo g_ex;
static volatile uint8_t g_last_event = FW_OK; /* last tracker verdict that was not OK */
static volatile uint8_t g_crossings;          /* counts crossings (wraps): see START */

/* Records from the interrupts to the main loop, which turns them into lines. One queue per
 * producer, so that no producer needs to disable interrupts: the capture handler (which runs
 * with interrupts on) writes `capt`; the compare and timeout handlers and the main loop (with
 * interrupts off) write `misc`. The main loop drains `capt` first. */
enum { REC_START = 1, REC_LOG, REC_DONE, REC_FAULT };
typedef struct {
    uint8_t kind, code;
    uint16_t ticks;
    uint32_t n;
} record;
#define RQ_LEN 16u
typedef struct {
    record r[RQ_LEN];
    volatile uint8_t head, tail, lost;
} rqueue;
static rqueue g_rq_capt, g_rq_misc;

static void rq_push(rqueue *q, uint8_t kind, uint8_t code, uint16_t ticks, uint32_t n)
{
    uint8_t h = q->head, next = (uint8_t)((h + 1u) & (RQ_LEN - 1u));
    if (next == q->tail) {
        q->lost = 1;
        return;
    }
    q->r[h].kind = kind;
    q->r[h].code = code;
    q->r[h].ticks = ticks;
    q->r[h].n = n;
    q->head = next; /* publish after the record is written (volatile orders the stores) */
}

/* ------------------------------------------------------------------ actions */

static void apply(fw_action *a, rqueue *q);

/* GPIOR0 and PORTB bits are set with sbi/cbi (single instructions), safe with interrupts on. */
static void sync_gpior(void)
{
    if (g_ex.rise_at_crossing) GPIOR0 |= _BV(GP_RISE);
    else GPIOR0 &= (uint8_t)~_BV(GP_RISE);
    if (fw_tracker_locked(&g_trk)) PORTB |= _BV(PIN_LED);
    else PORTB &= (uint8_t)~_BV(PIN_LED);
}

/* interrupts off */
static void abort_now(uint8_t fault, rqueue *q)
{
    fw_action a;
    a.flags = 0;
    fw_expo_abort(&g_ex, fault, &a);
    apply(&a, q);
}

/* Carries out an fw_action. Both compare interrupts stay enabled from reset on, so nothing
 * here writes TIMSK1 or TIFR1: a compare match with no chain running finds GP_LEVEL = 0 and
 * leaves the (low) trigger low. (This also keeps the firmware clear of simavr 1.6, whose TIFR1
 * write handler clears every pending Timer1 flag, docs/firmware.md.) OCR1A and TCNT1 are
 * 16-bit registers sharing the TEMP byte, so they are accessed with interrupts off. */
static void apply(fw_action *a, rqueue *q)
{
    uint16_t f = a->flags;
    if (f & FW_ACT_TRIGGER_LOW) {
        PORTB &= (uint8_t)~_BV(PIN_TRIG);
        GPIOR0 &= (uint8_t)~_BV(GP_RISE);
    }
    if (f & (FW_ACT_STOP_COMPARE | FW_ACT_TRIGGER_LOW)) GPIOR0 &= (uint8_t)~_BV(GP_LEVEL);
    if (f & FW_ACT_SHUTTER_ON) PORTB |= _BV(PIN_SHUT);
    if (f & FW_ACT_SHUTTER_OFF) PORTB &= (uint8_t)~_BV(PIN_SHUT);
    if (f & FW_ACT_CLOSE_PULSE) { /* a stop inside a window: the DMD on to the zero mask */
        _delay_us(FW_PULSE_TICKS / 2);
        PORTB |= _BV(PIN_TRIG);
        _delay_us(FW_PULSE_TICKS / 2);
        PORTB &= (uint8_t)~_BV(PIN_TRIG);
    }
    if (f & FW_ACT_STARTED) rq_push(q, REC_START, g_trk.grid_hz, a->log_ticks, 0);
    if (f & FW_ACT_LOG) rq_push(q, REC_LOG, 0, a->log_ticks, a->log_cycle);
    if (f & FW_ACT_DONE) rq_push(q, REC_DONE, 0, 0, g_ex.C);
    if (f & FW_ACT_FAULT) rq_push(q, REC_FAULT, g_ex.fault, 0, g_ex.n);
    if (f & FW_ACT_ARM_COMPARE) {
        uint8_t sreg = SREG;
        cli();
        OCR1A = a->compare_ticks;
        if (a->next_level) GPIOR0 |= _BV(GP_LEVEL);
        else GPIOR0 &= (uint8_t)~_BV(GP_LEVEL);
        /* a compare value already passed would only match after the 32 ms wrap */
        int16_t ahead = (int16_t)(a->compare_ticks - TCNT1);
        if (ahead < 1) abort_now(FW_LATE, &g_rq_misc);
        SREG = sreg;
    }
}

/* ------------------------------------------------------------------ interrupts */

/* Compare A: one trigger edge, exactly at the scheduled tick (+ the stub's ~14 cycles). */
ISR(TIMER1_COMPA_vect, ISR_NAKED)
{
    __asm__ __volatile__("sbic %[gp], %[lvl]\n\t"
                         "sbi %[port], %[trig]\n\t"
                         "sbis %[gp], %[lvl]\n\t"
                         "cbi %[port], %[trig]\n\t"
                         "jmp __vector_fw_compa\n\t"
                         :
                         : [gp] "I"(_SFR_IO_ADDR(GPIOR0)), [lvl] "I"(GP_LEVEL),
                           [port] "I"(_SFR_IO_ADDR(PORTB)), [trig] "I"(PIN_TRIG));
}

ISR(__vector_fw_compa)
{
    fw_action a;
    fw_expo_compare(&g_ex, &a);
    apply(&a, &g_rq_misc);
}

/* Capture: a zero crossing. Raises the trigger first when window 0 starts here. */
ISR(TIMER1_CAPT_vect, ISR_NAKED)
{
    __asm__ __volatile__("sbic %[gp], %[rise]\n\t"
                         "sbi %[port], %[trig]\n\t"
                         "sbic %[gp], %[incapt]\n\t"
                         "rjmp 1f\n\t"
                         "sbi %[gp], %[incapt]\n\t"
                         "sei\n\t"
                         "jmp __vector_fw_capt\n\t"
                         "1: sbi %[gp], %[lost]\n\t"
                         "reti\n\t"
                         :
                         : [gp] "I"(_SFR_IO_ADDR(GPIOR0)), [rise] "I"(GP_RISE),
                           [incapt] "I"(GP_INCAPT), [lost] "I"(GP_LOST),
                           [port] "I"(_SFR_IO_ADDR(PORTB)), [trig] "I"(PIN_TRIG));
}

/* Entered from the stub with interrupts enabled: the compare interrupt may preempt it at any
 * point except in the few-instruction cli() sections. */
ISR(__vector_fw_capt)
{
    /* provisional timeout, far ahead, so that compare B cannot fire while this handler works
     * (it is the deadline the tracker gives if this crossing is accepted) */
    uint16_t next_deadline = fw_tracker_next_deadline(&g_trk);
    cli();
    uint16_t now = ICR1;
    OCR1B = (uint16_t)(now + next_deadline);
    g_crossings++;
    sei();
    /* next edge: the opposite of the level now on the pin (re-synchronises after a glitch);
     * a flag raised by changing the edge is cleared (datasheet 16.6.3) */
    if (PINB & _BV(PIN_ZC)) TCCR1B &= (uint8_t)~_BV(ICES1);
    else TCCR1B |= _BV(ICES1);
    if (TIFR1 & _BV(ICF1)) TIFR1 = _BV(ICF1);

    /* first the cycle starting now: its events were planned a half period ago */
    fw_action a;
    fw_expo_crossing_fast(&g_ex, now, &a);
    if (a.flags & FW_ACT_ABORT) {
        cli();
        fw_expo_abort(&g_ex, a.abort_fault, &a);
        sei();
    }
    apply(&a, &g_rq_capt);

    /* then the checks, the log and the plan of the next cycle */
    uint16_t delta;
    uint8_t v = fw_tracker_crossing(&g_trk, now, &delta);
    if (GPIOR0 & _BV(GP_LOST)) {
        GPIOR0 &= (uint8_t)~_BV(GP_LOST);
        fw_tracker_timeout(&g_trk);
        fw_tracker_crossing(&g_trk, now, &delta); /* this crossing is the new reference */
        v = FW_SPURIOUS;
    }
    if (v != FW_OK) {
        g_last_event = v;
        uint16_t dl = (uint16_t)(now + fw_tracker_deadline(&g_trk));
        cli();
        OCR1B = dl;
        sei();
    }
    fw_expo_crossing_slow(&g_ex, &g_trk, v, delta, &a);
    if (a.flags & FW_ACT_ABORT) {
        cli();
        fw_expo_abort(&g_ex, a.abort_fault, &a);
        sei();
    }
    if (g_ex.log_done) { /* only at the last crossing of an exposure */
        cli();
        fw_expo_finish(&g_ex, &a);
        sei();
    }
    apply(&a, &g_rq_capt);
    sync_gpior();
    GPIOR0 &= (uint8_t)~_BV(GP_INCAPT);
}

/* Compare B: the next crossing is overdue (a missing crossing). Without a signal it matches
 * every 32 ms and finds the tracker already reset. */
ISR(TIMER1_COMPB_vect)
{
    if (!g_trk.have_ref) return;
    fw_tracker_timeout(&g_trk);
    g_last_event = FW_MISSING;
    abort_now(FW_MISSING, &g_rq_misc);
    sync_gpior();
}

/* UART receive / data-register-empty: only wake the main loop, which polls the UART. The
 * stub disables both interrupts (one register, SREG untouched: ~1 us). */
ISR(USART_RX_vect, ISR_NAKED)
{
    __asm__ __volatile__("push r24\n\t"
                         "ldi r24, %[b]\n\t"
                         "sts %[ucsr], r24\n\t"
                         "pop r24\n\t"
                         "reti\n\t"
                         :
                         : [b] "M"(UCSR0B_IDLE), [ucsr] "n"(_SFR_MEM_ADDR(UCSR0B)));
}
ISR(USART_UDRE_vect, ISR_ALIASOF(USART_RX_vect));

/* ------------------------------------------------------------------ serial output */

#define TX_LEN 256u
static char g_tx[TX_LEN];
static uint8_t g_tx_head, g_tx_tail; /* main loop only; uint8_t wraps at TX_LEN */

static uint8_t tx_free(void)
{
    return (uint8_t)(g_tx_tail - g_tx_head - 1u);
}

static void tx_line(fw_out *o)
{
    fw_out_end(o);
    if (tx_free() < o->len) return; /* callers check room first; never block */
    for (uint8_t i = 0; i < o->len; i++) g_tx[g_tx_head++] = o->buf[i];
}

static void tx_service(void)
{
    while (g_tx_tail != g_tx_head && (UCSR0A & _BV(UDRE0))) UDR0 = (uint8_t)g_tx[g_tx_tail++];
}

static void out_kv(fw_out *o, const char *key, uint32_t v)
{
    fw_out_char(o, ' ');
    fw_out_str(o, key);
    fw_out_char(o, '=');
    fw_out_u32(o, v);
}

static const char *state_name(uint8_t st)
{
    switch (st) {
    case FW_ST_ARMED: return "ARMED";
    case FW_ST_EXPOSING: return "EXPOSING";
    case FW_ST_DONE: return "DONE";
    case FW_ST_FAULT: return "FAULT";
    default: return "IDLE";
    }
}

/* 1/256 ticks -> ns: x 500 / 256 = x 125 / 64 */
static uint32_t q8_to_ns(uint32_t q8)
{
    return (q8 * 125u + 32u) >> 6;
}

/* ------------------------------------------------------------------ commands */

static void reply_err(fw_out *o, const char *code)
{
    fw_out_begin(o);
    fw_out_str(o, "ERR ");
    fw_out_str(o, code);
    tx_line(o);
}

/* Cycles completed in the current or last exposure (the 32-bit count is read atomically). */
static uint32_t cycles_done(void)
{
    cli();
    uint32_t n = g_ex.n;
    sei();
    uint8_t st = g_ex.state;
    if (st == FW_ST_IDLE && !g_ex.configured) return 0;
    if (st == FW_ST_ARMED) return 0;
    return n < g_ex.C ? n : g_ex.C;
}

/* The newest half period (0 if none), read atomically. */
static uint16_t last_half_ticks(void)
{
    cli();
    uint16_t h = g_trk.good ? g_trk.hist_ticks[(uint8_t)(g_trk.idx - 1u) & (FW_HIST - 1u)] : 0;
    sei();
    return h;
}

static void command(const fw_cmd *c)
{
    fw_out o;
    uint8_t busy = g_ex.state == FW_ST_ARMED || g_ex.state == FW_ST_EXPOSING;
    fw_out_begin(&o);
    switch (c->kind) {
    case FW_CMD_PING:
        fw_out_str(&o, "OK PING");
        break;
    case FW_CMD_VER:
        fw_out_str(&o, "OK VER acam 1");
        out_kv(&o, "fcpu", F_CPU);
        out_kv(&o, "tick_ns", FW_TICK_NS);
        out_kv(&o, "hist", FW_HIST);
        break;
    case FW_CMD_CFG: {
        if (busy) {
            reply_err(&o, "BUSY");
            return;
        }
        cli();
        uint8_t r = fw_expo_configure(&g_ex, c->K, c->k, c->C, c->mode);
        sei();
        if (r != FW_OK) {
            reply_err(&o, "RANGE");
            return;
        }
        fw_out_str(&o, "OK CFG");
        out_kv(&o, "K", c->K);
        out_kv(&o, "k", c->k);
        out_kv(&o, "C", c->C);
        fw_out_str(&o, c->mode == FW_MODE_LOCKED ? " mode=L" : " mode=F");
        break;
    }
    case FW_CMD_START: {
        if (busy) {
            reply_err(&o, "BUSY");
            return;
        }
        if (!g_ex.configured) {
            reply_err(&o, "NOCFG");
            return;
        }
        /* the arithmetic runs with interrupts on; it is committed only if no crossing came in
         * between (crossings are >= 7.9 ms apart, the preparation takes ~0.2 ms) */
        uint8_t s;
        for (;;) {
            fw_lock_info info;
            cli();
            fw_tracker_lock_info(&g_trk, &info);
            uint8_t seq = g_crossings;
            sei();
            s = fw_expo_prepare(&g_ex, &info);
            cli();
            if (seq == g_crossings) {
                if (s == FW_OK) {
                    fw_action a;
                    fw_expo_commit(&g_ex, &a);
                    apply(&a, &g_rq_misc);
                }
                sync_gpior();
                sei();
                break;
            }
            sei();
        }
        if (s == FW_MISSING) {
            reply_err(&o, "NOLOCK");
            return;
        }
        if (s != FW_OK) {
            reply_err(&o, "LIMIT");
            return;
        }
        fw_out_str(&o, "OK START");
        break;
    }
    case FW_CMD_STOP: {
        cli();
        abort_now(FW_STOPPED, &g_rq_misc);
        sync_gpior();
        sei();
        uint32_t n = cycles_done();
        fw_out_str(&o, "OK STOP");
        out_kv(&o, "cycles", n);
        break;
    }
    case FW_CMD_STATUS: {
        /* byte-sized fields are read as they are; multi-byte ones in short atomic sections, so
         * that a status query never delays a trigger edge by more than a few cycles */
        uint8_t st = g_ex.state, fault = g_ex.fault, lock = fw_tracker_locked(&g_trk);
        uint8_t grid = g_trk.grid_hz, K = g_ex.K, k = g_ex.k, mode = g_ex.mode;
        uint8_t ev = g_last_event;
        uint32_t n = cycles_done(), C = g_ex.C;
        uint16_t half = last_half_ticks();
        fw_out_str(&o, "OK STATUS state=");
        fw_out_str(&o, state_name(st));
        out_kv(&o, "lock", lock);
        out_kv(&o, "grid", grid);
        out_kv(&o, "cycles", n);
        out_kv(&o, "C", C);
        out_kv(&o, "K", K);
        out_kv(&o, "k", k);
        fw_out_str(&o, mode == FW_MODE_LOCKED ? " mode=L" : " mode=F");
        out_kv(&o, "half_ns", (uint32_t)half * FW_TICK_NS);
        fw_out_str(&o, " fault=");
        fw_out_str(&o, fw_fault_name(fault));
        fw_out_str(&o, " last=");
        fw_out_str(&o, fw_fault_name(ev));
        break;
    }
    case FW_CMD_COUNT: {
        uint32_t n = cycles_done();
        fw_out_str(&o, "OK COUNT ");
        fw_out_u32(&o, n);
        break;
    }
    case FW_CMD_HALF: {
        uint16_t half = last_half_ticks();
        cli();
        uint8_t good = g_trk.good;
        uint32_t sum = g_trk.sum_ticks;
        sei();
        fw_out_str(&o, "OK HALF");
        out_kv(&o, "last_ns", (uint32_t)half * FW_TICK_NS);
        /* mean of the last 64 half periods, when there are 64 */
        out_kv(&o, "mean_ns", good >= FW_HIST ? q8_to_ns(sum * (256u / FW_HIST)) : 0);
        break;
    }
    default:
        return;
    }
    tx_line(&o);
}

/* ------------------------------------------------------------------ main loop */

static fw_linebuf g_line;
static uint8_t g_line_bad; /* an overrun or framing error hit the line being received */

static void rx_service(void)
{
    while (UCSR0A & _BV(RXC0)) {
        if (tx_free() < FW_OUT_MAX) return; /* leave it in the UART until a reply fits */
        uint8_t status = UCSR0A;
        char ch = (char)UDR0;
        if (status & (_BV(DOR0) | _BV(FE0))) g_line_bad = 1;
        uint8_t r = fw_linebuf_feed(&g_line, ch);
        if (!r) continue;
        fw_out o;
        if (r == 2) {
            reply_err(&o, "LONG");
        } else if (g_line_bad) {
            reply_err(&o, "SYNTAX");
        } else {
            fw_cmd c;
            uint8_t e = fw_parse(g_line.buf, g_line.len, &c);
            if (e != FW_PERR_OK) reply_err(&o, fw_perr_name(e));
            else command(&c);
        }
        g_line_bad = 0;
        fw_linebuf_reset(&g_line);
    }
}

/* One record as a line. */
static void record_line(const record *r)
{
    fw_out o;
    fw_out_begin(&o);
    switch (r->kind) {
    case REC_START:
        fw_out_str(&o, "EV START");
        out_kv(&o, "grid", r->code);
        fw_out_str(&o, g_ex.mode == FW_MODE_LOCKED ? " mode=L" : " mode=F");
        /* locked: the prediction for cycle 0; free running: Delta_0 (and exactly, in q8) */
        out_kv(&o, "half_ns", g_ex.mode == FW_MODE_LOCKED ? (uint32_t)r->ticks * FW_TICK_NS
                                                          : q8_to_ns(g_ex.period_q8));
        if (g_ex.mode == FW_MODE_FREE) out_kv(&o, "period_q8", g_ex.period_q8);
        break;
    case REC_LOG:
        fw_out_str(&o, "D ");
        fw_out_u32(&o, r->n);
        fw_out_char(&o, ' ');
        fw_out_u32(&o, (uint32_t)r->ticks * FW_TICK_NS);
        break;
    case REC_DONE:
        fw_out_str(&o, "EV DONE");
        out_kv(&o, "cycles", r->n);
        break;
    default:
        fw_out_str(&o, "EV FAULT ");
        fw_out_str(&o, fw_fault_name(r->code));
        out_kv(&o, "cycle", r->n);
        break;
    }
    tx_line(&o);
}

static uint8_t rq_empty(const rqueue *q)
{
    return q->tail == q->head;
}

/* Takes one record of q (the producer never writes the slot at tail). */
static void rq_pop(rqueue *q, record *r)
{
    uint8_t t = q->tail;
    *r = q->r[t];
    q->tail = (uint8_t)((t + 1u) & (RQ_LEN - 1u));
}

static void record_service(void)
{
    record r;
    while (tx_free() >= FW_OUT_MAX && !rq_empty(&g_rq_capt)) {
        rq_pop(&g_rq_capt, &r);
        record_line(&r);
    }
    while (tx_free() >= FW_OUT_MAX && rq_empty(&g_rq_capt) && !rq_empty(&g_rq_misc)) {
        rq_pop(&g_rq_misc, &r);
        record_line(&r);
    }
    if ((g_rq_capt.lost || g_rq_misc.lost) && tx_free() >= FW_OUT_MAX) {
        cli();
        g_rq_capt.lost = 0;
        g_rq_misc.lost = 0;
        abort_now(FW_OVERFLOW, &g_rq_misc); /* a log with a hole is not a log */
        sync_gpior();
        sei();
    }
}

/* Sleep (idle: timers run) until an interrupt, unless there is work. */
static void idle(void)
{
    cli();
    uint8_t tx_pending = g_tx_tail != g_tx_head;
    if (!(UCSR0A & _BV(RXC0)) && rq_empty(&g_rq_capt) && rq_empty(&g_rq_misc) &&
        !(tx_pending && (UCSR0A & _BV(UDRE0)))) {
        UCSR0B = UCSR0B_IDLE | _BV(RXCIE0) | (tx_pending ? _BV(UDRIE0) : 0);
        sleep_enable();
        sei();
        sleep_cpu();
        sleep_disable();
    }
    sei();
}

int main(void)
{
    DDRB = _BV(PIN_TRIG) | _BV(PIN_SHUT) | _BV(PIN_LED);
    PORTB = 0;
    GPIOR0 = 0;
    fw_tracker_reset(&g_trk);
    fw_linebuf_reset(&g_line);

    UBRR0 = UART_UBRR;
    UCSR0A = _BV(U2X0);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00); /* 8N1 */
    UCSR0B = UCSR0B_IDLE;

    TCCR1A = 0; /* normal mode, OC1A/OC1B disconnected: the trigger is driven from PORTB */
    TCCR1B = _BV(CS11) | ((PINB & _BV(PIN_ZC)) ? 0 : _BV(ICES1)); /* clk/8; next edge */
    TIFR1 = _BV(ICF1) | _BV(OCF1A) | _BV(OCF1B);
    TIMSK1 = _BV(ICIE1) | _BV(OCIE1A) | _BV(OCIE1B); /* for good: see apply() */
    set_sleep_mode(SLEEP_MODE_IDLE);
    sei();

    fw_out o;
    fw_out_begin(&o);
    fw_out_str(&o, "EV BOOT acam 1");
    tx_line(&o);
    for (;;) {
        rx_service();
        record_service();
        tx_service();
        idle();
    }
}
