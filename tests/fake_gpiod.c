/* fake_gpiod.c - a fake libgpiod v1.6 for the test binary (tests/fake_gpiod.h): the functions
 * capture/backend_hardware.c uses, with the real <gpiod.h> prototypes. */
#include "tests/fake_gpiod.h"

#include <errno.h>
#include <gpiod.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define FAKE_LINES 64

struct gpiod_chip {
    int open;
};

struct gpiod_line {
    unsigned offset;
    int requested;   /* 0 no, 1 events, 2 output */
    int value;
};

static struct gpiod_chip chip;
static struct gpiod_line lines[FAKE_LINES];
static struct gpiod_line_event *events;
static size_t n_events, next_event, pending_end, burst = 1;
static fake_gpiod_output *outputs;
static size_t n_outputs, cap_outputs;

int fake_gpiod_load_events(const char *path, size_t b)
{
    FILE *f = fopen(path, "r");
    if (!f) return -1;
    free(events);
    events = NULL;
    n_events = next_event = pending_end = 0;
    burst = b ? b : 1;
    size_t cap = 0;
    long long sec, nsec;
    int type;
    while (fscanf(f, "%lld %lld %d", &sec, &nsec, &type) == 3) {
        if (n_events == cap) {
            cap = cap ? cap * 2 : 1024;
            struct gpiod_line_event *ne = realloc(events, cap * sizeof *ne);
            if (!ne) break;
            events = ne;
        }
        events[n_events].ts.tv_sec = (time_t)sec;
        events[n_events].ts.tv_nsec = (long)nsec;
        events[n_events].event_type = type;
        n_events++;
    }
    fclose(f);
    return (int)n_events;
}

void fake_gpiod_queue_events(size_t n)
{
    if (pending_end < next_event) pending_end = next_event;
    pending_end = pending_end + n < n_events ? pending_end + n : n_events;
}

size_t fake_gpiod_output_count(void)
{
    return n_outputs;
}

fake_gpiod_output fake_gpiod_output_get(size_t i)
{
    fake_gpiod_output o = {0, -1};
    return i < n_outputs ? outputs[i] : o;
}

size_t fake_gpiod_events_left(void)
{
    return n_events - next_event;
}

int fake_gpiod_open_handles(void)
{
    int n = chip.open;
    for (int i = 0; i < FAKE_LINES; i++) n += lines[i].requested != 0;
    return n;
}

static void record(unsigned offset, int value)
{
    if (n_outputs == cap_outputs) {
        cap_outputs = cap_outputs ? cap_outputs * 2 : 256;
        fake_gpiod_output *no = realloc(outputs, cap_outputs * sizeof *no);
        if (!no) return;
        outputs = no;
    }
    outputs[n_outputs].offset = offset;
    outputs[n_outputs].value = value;
    n_outputs++;
}

struct gpiod_chip *gpiod_chip_open_by_name(const char *name)
{
    if (!name || !strcmp(name, "missing")) {
        errno = ENOENT;
        return NULL;
    }
    chip.open = 1;
    return &chip;
}

void gpiod_chip_close(struct gpiod_chip *c)
{
    if (c) c->open = 0;
}

struct gpiod_line *gpiod_chip_get_line(struct gpiod_chip *c, unsigned int offset)
{
    if (!c || !c->open || offset >= FAKE_LINES) {
        errno = EINVAL;
        return NULL;
    }
    lines[offset].offset = offset;
    return &lines[offset];
}

int gpiod_line_request_both_edges_events(struct gpiod_line *l, const char *consumer)
{
    (void)consumer;
    if (l->requested) {
        errno = EBUSY;
        return -1;
    }
    l->requested = 1;
    return 0;
}

int gpiod_line_request_output(struct gpiod_line *l, const char *consumer, int default_val)
{
    (void)consumer;
    if (l->requested) {
        errno = EBUSY;
        return -1;
    }
    l->requested = 2;
    l->value = default_val;
    record(l->offset, default_val);
    return 0;
}

int gpiod_line_set_value(struct gpiod_line *l, int value)
{
    if (l->requested != 2) {
        errno = EPERM;
        return -1;
    }
    l->value = value;
    record(l->offset, value);
    return 0;
}

void gpiod_line_release(struct gpiod_line *l)
{
    if (l) l->requested = 0;
}

int gpiod_line_event_wait(struct gpiod_line *l, const struct timespec *timeout)
{
    if (l->requested != 1) {
        errno = EPERM;
        return -1;
    }
    if (next_event < pending_end) return 1;
    if (timeout && (timeout->tv_sec || timeout->tv_nsec)) {
        if (next_event >= n_events) return 0;
        pending_end = next_event + burst < n_events ? next_event + burst : n_events;
        return 1;
    }
    return 0;
}

int gpiod_line_event_read(struct gpiod_line *l, struct gpiod_line_event *event)
{
    if (l->requested != 1 || next_event >= pending_end) {
        errno = EAGAIN;
        return -1;
    }
    *event = events[next_event++];
    return 0;
}
