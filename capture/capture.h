/*
 * capture.h - the public interface of gridsurvey's capture/ module (prefix cap_).
 *
 * ACam acquisition (paper Sec. 6): coded exposure over C flicker cycles, AC-locked mask
 * switching, and its backends. This header starts with the host side of the ACam controller
 * link.
 *
 * Conventions: as recognize.h (gs_status, thread-local gs_detail(), destructors accept NULL,
 * ownership stated per function). A flicker cycle lasts Delta = 1/(2 f) (Eq. 1).
 */
#ifndef GRIDSURVEY_CAPTURE_H
#define GRIDSURVEY_CAPTURE_H

#include "recognize/recognize.h"

#include <stddef.h>

/* ------------------------------------ ACam controller link (firmware/ over a serial port) */

/* The host side of the serial protocol of the ACam controller firmware (firmware/,
 * docs/firmware.md): an Arduino Uno that tracks the mains zero crossings and emits the DMD
 * mask-switch trigger at the start and end of window k of every flicker cycle, AC-locked (paper
 * Sec. 6) or free running, for C cycles, and reports the measured half period of every cycle.
 * Lines are ASCII, "*HH"-checksummed (XOR, as NMEA 0183) in both directions. One link is used
 * from one thread. */
typedef struct cap_link cap_link;

typedef enum {
    CAP_LOCKED = 0,      /* windows re-anchored on every detected crossing (the paper's mode) */
    CAP_FREE_RUNNING = 1 /* windows at the period measured before the start, never re-anchored */
} cap_lock_mode;

typedef struct {
    int K;               /* windows per flicker cycle: 2..26 at 50 Hz, 2..22 at 60 Hz (Fig. 7) */
    int k;               /* the window exposed, 0..K-1: [k Delta/K, (k+1) Delta/K) */
    long cycles;         /* C, flicker cycles: 1..1000000 (the paper uses 100..1500) */
    cap_lock_mode mode;
} cap_link_config;

/* Opens a serial device (raw, 115200 8N1) holding the controller. GS_EIO (naming the path and
 * errno) if it cannot be opened or configured. Free with cap_link_close. */
gs_status cap_link_open(const char *path, cap_link **out);
/* Wraps an open descriptor (a tty is set raw 115200 8N1; a pipe or socket is used as is). The
 * link owns fd from then on, also on failure. */
gs_status cap_link_open_fd(int fd, cap_link **out);
/* Closes the descriptor and frees the link (NULL: nothing). Does not stop an exposure. */
void cap_link_close(cap_link *l);
/* Longest wait for a reply or for the next per-cycle line, ms (default 1000; >= 1). */
void cap_link_set_timeout_ms(cap_link *l, int timeout_ms);

/* The commands. Errors: GS_EIO for a timeout, an I/O error, a line the firmware reports as
 * corrupted (ERR SYNTAX, CHECKSUM, LONG) or no lock on the mains (ERR NOLOCK); GS_EFORMAT for a
 * reply with a bad checksum or an unexpected form; GS_EINVAL for a configuration out of range
 * (ERR RANGE, or checked here first), a command while an exposure runs (ERR BUSY) or START
 * before a configuration (ERR NOCFG); GS_ELIMIT for ERR LIMIT (K above the grid's limit, or
 * windows shorter than the DMD's 370 us). The detail names the command and the reply. */
gs_status cap_link_ping(cap_link *l);
gs_status cap_link_configure(cap_link *l, const cap_link_config *c);
gs_status cap_link_start(cap_link *l);
/* Stops a running exposure (no-op otherwise); cycles_done (may be NULL) gets its count. */
gs_status cap_link_stop(cap_link *l, long *cycles_done);

typedef struct {
    char state[12];       /* IDLE, ARMED, EXPOSING, DONE or FAULT */
    int locked;           /* the firmware has 64 consistent half periods */
    int grid_hz;          /* 50 or 60 when locked, else 0 */
    long cycles_done;     /* of the current or last exposure */
    long cycles;          /* C configured */
    int K, k;
    cap_lock_mode mode;
    double half_period_s; /* the last measured half period (0 if none) */
    char fault[12];       /* what stopped the last exposure: OK, SPURIOUS, MISSING, FREQ, LIMIT,
                           * LATE, OVERFLOW, STOPPED */
    char last_event[12];  /* the last crossing the tracker rejected (OK if none) */
} cap_link_status;
gs_status cap_link_get_status(cap_link *l, cap_link_status *st);
gs_status cap_link_cycle_count(cap_link *l, long *cycles_done);

/* The per-cycle log of one exposure: the grid frequency during it is 1 / (2 half_period_s[n])
 * (Eq. 1; successive half periods alternate by the detector's asymmetry, so average pairs). */
typedef struct {
    size_t cycles;               /* cycles logged: C when the exposure completed */
    double *half_period_s;       /* [cycles], owned: the measured Delta_n (0.5 us resolution,
                                  * and the Uno's clock tolerance, docs/firmware.md) */
    int grid_hz;                 /* 50 or 60 */
    double start_half_period_s;  /* locked: the prediction for cycle 0; free: Delta_0 */
    char fault[12];              /* "" when complete, else the firmware's fault name */
} cap_exposure_log;

/* Runs one exposure: CFG, START (repeated every 50 ms for up to 2 s while the firmware answers
 * ERR NOLOCK, i.e. right after power-up or a glitch), then collects one line per cycle until
 * EV DONE. *log is overwritten (release it with cap_exposure_log_release, also on failure).
 * Returns GS_OK with log->cycles == C. An EV FAULT returns GS_ELIMIT for FREQ and LIMIT, else
 * GS_EIO, with the cycles logged before it and log->fault set; silence for longer than the
 * link timeout returns GS_EIO (the exposure may still run: call cap_link_stop). */
gs_status cap_link_expose(cap_link *l, const cap_link_config *c, cap_exposure_log *log);
void cap_exposure_log_release(cap_exposure_log *log);

#endif
