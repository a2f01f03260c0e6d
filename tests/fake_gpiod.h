/* fake_gpiod.h - a small fake of libgpiod v1.6 (tests/fake_gpiod.c), linked into the test
 * binary instead of the real library (Makefile): capture/backend_hardware.c runs unchanged
 * against it. Input lines replay an event file; outputs are recorded.
 *
 * Event file: one event per line, "SECONDS NANOSECONDS TYPE" (TYPE 1 rising, 2 falling, as
 * GPIOD_LINE_EVENT_*). Events become pending in bursts: a wait with a non-zero timeout makes
 * the next `burst` events pending (the crossings the kernel queues during an exposure) and
 * returns 1; a wait with a zero timeout returns 1 while events are pending, else 0
 * (fake_gpiod_queue_events queues some ahead, as the kernel does between reads). A chip named
 * "missing" cannot be opened (ENOENT). */
#ifndef GRIDSURVEY_TESTS_FAKE_GPIOD_H
#define GRIDSURVEY_TESTS_FAKE_GPIOD_H

#include <stddef.h>

typedef struct {
    unsigned offset;
    int value;
} fake_gpiod_output;

/* Load the events (replacing earlier ones); returns the count or -1. */
int fake_gpiod_load_events(const char *path, size_t burst);
/* Recorded output writes, in order (request defaults included). */
size_t fake_gpiod_output_count(void);
fake_gpiod_output fake_gpiod_output_get(size_t i);
/* Makes the next n events pending now: crossings the kernel queued while nobody read the line
 * (a frame's readout between two acquisitions). */
void fake_gpiod_queue_events(size_t n);
/* Events not yet read. */
size_t fake_gpiod_events_left(void);
/* Lines requested and not released, chips open. */
int fake_gpiod_open_handles(void);

#endif
