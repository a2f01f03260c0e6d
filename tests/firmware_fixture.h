/* firmware_fixture.h - the ACam controller firmware's real ELF in libsimavr, for the simavr
 * tests (tests/test_firmware*.c); implemented in tests/firmware_fixture.c.
 *
 * The harness drives ICP1 (PB0) with a square wave whose edges are zero crossings (from a mains
 * recording, or synthetic), records the trigger (PB1) and shutter (PB2) pins in CPU cycles of the
 * simulated 16 MHz clock, and bridges the UART with a single-threaded hook: bytes out are
 * collected into lines (each must carry a valid "*HH" checksum), bytes in are fed one per
 * character time. Failures are test failures (CHECKs); out of memory aborts. */
#ifndef GRIDSURVEY_TESTS_FIRMWARE_FIXTURE_H
#define GRIDSURVEY_TESTS_FIRMWARE_FIXTURE_H

#include <simavr/sim_avr.h>
#include <simavr/sim_elf.h>
#include <simavr/sim_irq.h>

#include <stddef.h>
#include <stdint.h>

#define CYCLES_PER_US 16.0
#define CYCLES_PER_S 16000000.0
#define FW_ERR_MAX_CYCLES (4.0 * CYCLES_PER_US) /* the 4 us */
#define CHAR_CYCLES 1500u                      /* > one 11-bit character at 117647 baud */
#define LEAD_CYCLES 32000u                     /* 2 ms after reset before the first crossing */
#define RAM_START 0x100u                       /* ATmega328P: SRAM after the 256 I/O bytes */
#define STACK_PAINT 0xA5u
#define STACK_MARGIN_MIN 128                   /* bytes that must stay unused (of 2048) */
#define LINE_MAX_CHARS 160

/* GS_FIRMWARE_ELF_DEFAULT: firmware/module.mk defines it for tests/test_firmware.c only, which
 * defines this. The ELF is GS_FIRMWARE_ELF, else this path. */
extern const char *const fw_elf_default;

/* ------------------------------------------------------------------ small containers */

typedef struct {
    uint64_t *v;
    size_t n, cap;
} u64vec;

/* Index of the last element <= x in sorted a (-1 if none). */
long u64vec_last_le(const u64vec *a, uint64_t x);

/* ------------------------------------------------------------------ the simulation */

typedef struct {
    char text[LINE_MAX_CHARS];
    uint64_t cycle;
} simline;

typedef struct {
    avr_t *avr;
    elf_firmware_t *fw;
    /* zero-crossing input: edge i toggles PB0 at (about) cycle edges[i] */
    const uint64_t *edges;
    size_t n_edges, next_edge;
    uint8_t level;
    u64vec applied; /* the cycle at which each edge was applied: the truth */
    avr_irq_t *icp_irq;
    /* outputs */
    uint8_t trig_level, shut_level;
    u64vec trig_rise, trig_fall, shut_rise, shut_fall;
    /* UART out: lines with their end cycle */
    char cur[LINE_MAX_CHARS];
    size_t cur_len;
    simline *lines;
    size_t n_lines, cap_lines;
    size_t bad_lines; /* no or wrong checksum, or overlong */
    /* UART in: a queue fed one character per CHAR_CYCLES */
    char in[4096];
    size_t in_head, in_tail;
    int in_timer;
    avr_irq_t *uart_in;
    int pty_fd; /* bridge: output bytes are also written here (-1: none) */
} fwsim;

/* A simulation of the firmware ELF with the crossing edges (sorted CPU cycles, borrowed; the
 * first edge rises from 0 when rising_first, else falls from 1). NULL (and a test failure) on
 * error. fwsim_free accepts NULL. */
fwsim *fwsim_new(const uint64_t *edges, size_t n_edges, int rising_first);
void fwsim_free(fwsim *s);
/* Bytes between the end of .bss and the deepest the stack has been. */
long fwsim_stack_margin(const fwsim *s);
/* Queues bytes for the UART; fwsim_send queues "text\n" (text as given: a test may add its own
 * "*HH"). */
void fwsim_send_bytes(fwsim *s, const char *bytes, size_t n);
void fwsim_send(fwsim *s, const char *text);
/* Runs until the cycle count reaches `until`. 0, or -1 (test failure) if the core stopped. */
int fwsim_run_until(fwsim *s, uint64_t until);
/* Runs until a line starting with `prefix` appears after line index `from`, for at most
 * max_cycles. Returns its index, or -1. */
long fwsim_wait_line(fwsim *s, size_t from, const char *prefix, uint64_t max_cycles);
/* Sends a command and returns its reply line ("OK ..." or "ERR ..."), skipping data and event
 * lines; "" on timeout (a test failure). The pointer is valid until the next line arrives. */
const char *fwsim_cmd(fwsim *s, const char *cmd);
/* The value of "key=" in a line (NAN if absent). */
double fw_field(const char *line, const char *key);

/* ------------------------------------------------------------------ crossing traces */

typedef struct {
    uint64_t *edges; /* CPU cycles */
    size_t n;
    int rising_first;
} trace;

void trace_free(trace *t);
/* The zero crossings of a real mains recording (shared data path rel, e.g. ENF-WHU) as CPU
 * cycles, the first at LEAD_CYCLES. At most max_crossings (0: all). 0, or -1. */
int trace_from_mains(const char *rel, size_t max_crossings, trace *out);
/* A synthetic mains: f(t) = f0 + a sin(2 pi t / period_s) + ramp t (Hz), whose phase
 * 2 pi (f0 t + a period_s / (2 pi) (1 - cos(2 pi t / period_s)) + ramp t^2 / 2) crosses each
 * multiple of pi at a crossing (found by Newton's method); the positive half periods are longer
 * than the negative ones by asym_us (a detector's asymmetry). The first crossing rises. */
void trace_synthetic(double f0, double a_hz, double period_s, double ramp_hz_per_s,
                     double asym_us, size_t count, trace *out);

/* ------------------------------------------------------------------ exposures */

/* Waits for the tracker to lock (64 half periods: 0.8 s of mains), configures window k of K, C
 * cycles, mode 'L' (locked) or 'F' (free running), starts, and waits for EV START. Returns the
 * index of the EV START line, or -1 (a test failure). */
long fwsim_start_exposure(fwsim *s, int K, int k, long C, char mode);
/* Index in s->applied of the crossing that started the exposure: the first one after the
 * shutter opened at START (-1 if it never did). */
long fwsim_start_crossing(const fwsim *s);
/* Waits for EV DONE of a C-cycle exposure (or a fault: a test failure), sending STATUS every
 * status_every cycles (0: never) - the firmware answers from its main loop, which must not
 * disturb the trigger timing. Returns the start crossing index, or -1. */
long fwsim_wait_done(fwsim *s, size_t from, long C, int status_every);
/* fwsim_start_exposure, then fwsim_wait_done. */
long fwsim_run_exposure(fwsim *s, int K, int k, long C, char mode, int status_every);

/* ------------------------------------------------------------------ the serial bridge */

/* What the bridge reports on its report descriptor after each EV DONE: the crossing (index into
 * the injected edges) that started the exposure, and its cycles. */
typedef struct {
    long start_crossing;
    long cycles;
} fw_bridge_report;

/* In a forked child: the simulation as a serial device. Runs the firmware and shuttles bytes
 * between its UART and the pty master, no faster than 20 x real time, until the slave side is
 * closed; then _exit(0) (3: no simulation, 4: the core stopped, 5: the mains ran out, 6: a
 * report could not be written). With report_fd >= 0, writes one fw_bridge_report there per
 * completed exposure. */
void fw_bridge_child(int master, const trace *tr, int report_fd) __attribute__((noreturn));

#endif
