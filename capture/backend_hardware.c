/* backend_hardware.c - the `hardware` backend (paper Sec. 6, Figs. 7-8): an off-the-shelf
 * camera through OpenCV VideoCapture (videoio.c, its plugin), the mains zero crossings and the
 * camera's shutter and trigger lines through libgpiod v1.6 (written against <gpiod.h>; the
 * tests link a fake libgpiod that replays an event file and records the outputs, so this code
 * path is tested unchanged), and the ACam controller over its serial link (cap_link_*, which
 * locks the DMD's mask switching to the crossings). The DMD's masks are loaded by its own tool
 * through the load_masks callback. */
#include "capture/internal.h"

#include <errno.h>
#include <gpiod.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#define GPIO_CONSUMER "gridsurvey"

typedef struct {
    cap_hw_config cfg;
    char camera[CAP_PATH_MAX], serial[CAP_PATH_MAX], chip_name[64];
    cap_vio *cam;
    cap_link *link;
    struct gpiod_chip *chip;
    struct gpiod_line *zc, *shutter, *trigger;
    cap_hw_log log;
    cap_acq_timing timing;      /* of the last acquisition */
    double origin_s;            /* start of the capture's first exposure (index 0), NaN: unseen */
    char utc[40];
    uint64_t fingerprint;
} hw_backend;

void cap_hw_config_default(cap_hw_config *c)
{
    memset(c, 0, sizeof *c);
    c->exposure_margin_s = 0.05;
    c->serial_fd = -1;
    c->link_timeout_ms = 1000;
    c->zc_line = c->shutter_line = c->trigger_line = -1;
    c->zc_timeout_ms = 1000;
    c->grid_hz = 50;
    c->K = 26;
    c->bands = 1;
    c->cycles = 500;
    c->masks = 2;
    c->locked = 1;
    c->saturation_dn = 65535;
    c->read_noise_dn = 1;
}

static gs_status hw_info(void *self, cap_acq_info *info)
{
    hw_backend *b = self;
    const cap_hw_config *c = &b->cfg;
    memset(info, 0, sizeof *info);
    info->grid_hz = c->grid_hz;
    info->K = c->K;
    info->bands = c->bands;
    info->width = c->width;
    info->height = c->height;
    info->cycles = c->cycles;
    info->masks = c->masks;
    info->max_halvings = c->load_masks ? cap_acam_max_halvings(c->masks) : 0;
    info->hdr = c->hdr;
    info->hdr_max_rounds = info->max_halvings;
    info->saturation_dn = c->saturation_dn;
    info->black_level_dn = c->black_level_dn;
    info->gain_e_per_dn = c->gain_e_per_dn;
    info->read_noise_dn = c->read_noise_dn;
    info->locked = c->locked;
    info->window_period = c->locked ? GS_PERIOD_UNKNOWN : GS_PERIOD_MEASURED;   /* (the firmware's Delta_0) */
    snprintf(info->utc, sizeof info->utc, "%s", b->utc);
    info->fingerprint = b->fingerprint;
    return GS_OK;
}

static double ts_s(const struct timespec *t)
{
    return (double)t->tv_sec + 1e-9 * (double)t->tv_nsec;
}

static gs_status gpio_fail(const char *what, int line)
{
    return gs_fail(GS_EIO, "gpio %s line %d: %s", what, line, strerror(errno));
}

static gs_status set_line(struct gpiod_line *l, int offset, int value)
{
    if (l && gpiod_line_set_value(l, value) != 0) return gpio_fail("set", offset);
    return GS_OK;
}

static gs_status hw_acquire(void *self, const cap_acquisition *a, unsigned char *halvings,
                            unsigned short *raw, double *cycles)
{
    hw_backend *b = self;
    const cap_hw_config *c = &b->cfg;
    gs_status s;
    memset(&b->log, 0, sizeof b->log);
    b->log.mean_half_period_s = NAN;
    b->log.link_mean_half_period_s = NAN;
    b->timing.grid_hz_measured = b->timing.start_s = b->timing.window_half_period_s = NAN;
    b->timing.window_drift_windows = NAN;
    struct timespec t_open;
    clock_gettime(CLOCK_MONOTONIC, &t_open);
    /* 1. the DMD's masks: the HDR loop's halvings are the rows of M */
    if (c->load_masks && c->load_masks(c->load_masks_user, c->masks, halvings, c->width, c->height))
        return gs_fail(GS_EIO, "hardware: loading the DMD masks for frame %d pass %d failed",
                       a->k, a->pass);
    /* 2. mains present: wait for a new zero crossing (the kernel queued every crossing since
     * the last read, during the previous frame's readout: those are dropped first) */
    if (b->zc) {
        struct timespec zero = {0, 0};
        int w;
        while ((w = gpiod_line_event_wait(b->zc, &zero)) == 1) {
            struct gpiod_line_event old;
            if (gpiod_line_event_read(b->zc, &old) != 0) return gpio_fail("event read", c->zc_line);
        }
        if (w < 0) return gpio_fail("event wait", c->zc_line);
        struct timespec to = {c->zc_timeout_ms / 1000, (long)(c->zc_timeout_ms % 1000) * 1000000L};
        w = gpiod_line_event_wait(b->zc, &to);
        if (w < 0) return gpio_fail("event wait", c->zc_line);
        if (w == 0)
            return gs_fail(GS_EIO, "hardware: no mains zero crossing on gpio line %d within %d ms",
                           c->zc_line, c->zc_timeout_ms);
        struct gpiod_line_event ev;
        if (gpiod_line_event_read(b->zc, &ev) != 0) return gpio_fail("event read", c->zc_line);
        t_open = ev.ts;   /* the exposure starts at this crossing */
    }
    /* 3. shutter open, 4. C cycles of window k through the controller, 5. shutter closed */
    if ((s = set_line(b->shutter, c->shutter_line, 1)) != GS_OK) return s;
    cap_link_config lc = {c->K, a->k, c->cycles, c->locked ? CAP_LOCKED : CAP_FREE_RUNNING};
    cap_exposure_log elog;
    s = cap_link_expose(b->link, &lc, &elog);
    gs_status s2 = set_line(b->shutter, c->shutter_line, 0);
    if (s == GS_OK) s = s2;
    if (s == GS_OK) {
        double sum = 0;
        for (size_t i = 0; i < elog.cycles; i++) sum += elog.half_period_s[i];
        b->log.link_cycles = elog.cycles;
        b->log.link_mean_half_period_s = elog.cycles ? sum / (double)elog.cycles : NAN;
        /* free running, the windows follow the period measured before the start (Delta_0) */
        if (!c->locked) {
            b->timing.window_half_period_s = elog.start_half_period_s;
            b->timing.window_drift_windows =
                cap_window_drift(elog.half_period_s, (long)elog.cycles, elog.start_half_period_s, c->K);
        }
    }
    cap_exposure_log_release(&elog);
    if (s != GS_OK) return gs_fail(s, "hardware: frame %d: %s", a->k, gs_detail());
    /* the trigger pulse reads the frame out */
    if ((s = set_line(b->trigger, c->trigger_line, 1)) != GS_OK ||
        (s = set_line(b->trigger, c->trigger_line, 0)) != GS_OK)
        return s;
    /* 6. the crossings seen during the exposure (kernel-queued, timestamped) */
    if (b->zc) {
        struct timespec zero = {0, 0};
        double first = 0, last = 0;
        size_t n = 0;
        for (;;) {
            int w = gpiod_line_event_wait(b->zc, &zero);
            if (w < 0) return gpio_fail("event wait", c->zc_line);
            if (w == 0) break;
            struct gpiod_line_event ev;
            if (gpiod_line_event_read(b->zc, &ev) != 0) return gpio_fail("event read", c->zc_line);
            double t = ts_s(&ev.ts);
            if (!n) first = t;
            last = t;
            n++;
        }
        b->log.crossings = n;
        b->log.mean_half_period_s = n >= 2 ? (last - first) / (double)(n - 1) : NAN;
    }
    /* 7. the frame */
    s = cap_vio_read(b->cam, c->width, c->height, c->bands, raw);
    if (s != GS_OK) return gs_fail(s, "hardware: frame %d: %s", a->k, gs_detail());
    if (cycles) *cycles = (double)c->cycles;
    /* the grid frequency during the exposure: f = 1 / (2 Delta) over the controller's log */
    double d = b->log.link_mean_half_period_s;
    if (isfinite(d) && d > 0) b->timing.grid_hz_measured = 1.0 / (2.0 * d);
    if (a->index == 0 && a->pass == 0) b->origin_s = ts_s(&t_open);
    if (isfinite(b->origin_s)) b->timing.start_s = ts_s(&t_open) - b->origin_s;
    return GS_OK;
}

static gs_status hw_timing(void *self, cap_acq_timing *t)
{
    *t = ((hw_backend *)self)->timing;
    return GS_OK;
}

static void hw_free(void *self)
{
    hw_backend *b = self;
    if (!b) return;
    if (b->zc) gpiod_line_release(b->zc);
    if (b->shutter) gpiod_line_release(b->shutter);
    if (b->trigger) gpiod_line_release(b->trigger);
    if (b->chip) gpiod_chip_close(b->chip);
    cap_link_close(b->link);
    cap_vio_close(b->cam);
    free(b);
}

static const cap_backend_ops hw_ops = {"hardware", hw_info, hw_acquire, hw_free,
                                         hw_timing};

gs_status cap_backend_hardware_new(const cap_hw_config *c, cap_backend **out)
{
    *out = NULL;
    cap_acam_config ac;
    cap_acam_config_default(&ac);
    ac.grid_hz = c->grid_hz;
    ac.K = c->K;
    ac.cycles = c->cycles;
    ac.masks = c->masks;
    ac.hdr = c->hdr;
    gs_status s = cap_acam_check(&ac);
    if (s != GS_OK) {
        if (c->serial_fd >= 0) close(c->serial_fd);
        return gs_fail(s, "hardware: %s", gs_detail());
    }
    if (!c->camera)
        s = gs_fail(GS_EINVAL, "hardware: no camera source");
    else if (c->width < 1 || c->height < 1)
        s = gs_fail(GS_EINVAL, "hardware: camera size %dx%d: expected at least 1x1", c->width,
                    c->height);
    else if (c->bands != 1 && c->bands != 3)
        s = gs_fail(GS_EINVAL, "hardware: %d bands: expected 1 or 3", c->bands);
    else if (!(c->saturation_dn > c->black_level_dn) || c->saturation_dn > 65536)
        s = gs_fail(GS_EINVAL, "hardware: saturation %g DN: expected above the black level %g DN "
                    "and at most 65536", c->saturation_dn, c->black_level_dn);
    if (s != GS_OK) {
        if (c->serial_fd >= 0) close(c->serial_fd);
        return s;
    }
    if (c->hdr && !c->load_masks) {
        if (c->serial_fd >= 0) close(c->serial_fd);
        return gs_fail(GS_EINVAL, "hardware: HDR needs a way to load the DMD's masks "
                       "(load_masks)");
    }
    hw_backend *b = calloc(1, sizeof *b);
    if (!b) {
        if (c->serial_fd >= 0) close(c->serial_fd);
        return gs_fail(GS_ENOMEM, "hardware: out of memory");
    }
    b->cfg = *c;
    b->origin_s = NAN;
    b->timing.grid_hz_measured = b->timing.start_s = b->timing.window_half_period_s = NAN;
    b->timing.window_drift_windows = NAN;
    snprintf(b->camera, sizeof b->camera, "%s", c->camera);
    b->cfg.camera = b->camera;
    if (c->serial) snprintf(b->serial, sizeof b->serial, "%s", c->serial);
    b->cfg.serial = c->serial ? b->serial : NULL;
    if (c->gpio_chip) snprintf(b->chip_name, sizeof b->chip_name, "%s", c->gpio_chip);
    b->cfg.gpio_chip = c->gpio_chip ? b->chip_name : NULL;
    /* the controller link (owns serial_fd from here) */
    if (c->serial) s = cap_link_open(c->serial, &b->link);
    else if (c->serial_fd >= 0) s = cap_link_open_fd(c->serial_fd, &b->link);
    else s = gs_fail(GS_EINVAL, "hardware: no ACam controller (serial port)");
    if (s != GS_OK) goto fail;
    cap_link_set_timeout_ms(b->link, c->link_timeout_ms);
    if ((s = cap_link_ping(b->link)) != GS_OK) goto fail;
    /* GPIO */
    if (c->gpio_chip) {
        b->chip = gpiod_chip_open_by_name(c->gpio_chip);
        if (!b->chip) {
            s = gs_fail(GS_EIO, "hardware: gpio chip %s: %s", c->gpio_chip, strerror(errno));
            goto fail;
        }
        if (c->zc_line >= 0) {
            b->zc = gpiod_chip_get_line(b->chip, (unsigned)c->zc_line);
            if (!b->zc || gpiod_line_request_both_edges_events(b->zc, GPIO_CONSUMER) != 0) {
                s = gpio_fail("zero-crossing input", c->zc_line);
                b->zc = NULL;
                goto fail;
            }
        }
        int outs[2] = {c->shutter_line, c->trigger_line};
        struct gpiod_line **dst[2] = {&b->shutter, &b->trigger};
        for (int i = 0; i < 2; i++) {
            if (outs[i] < 0) continue;
            *dst[i] = gpiod_chip_get_line(b->chip, (unsigned)outs[i]);
            if (!*dst[i] || gpiod_line_request_output(*dst[i], GPIO_CONSUMER, 0) != 0) {
                s = gpio_fail(i ? "trigger output" : "shutter output", outs[i]);
                *dst[i] = NULL;
                goto fail;
            }
        }
    }
    /* the camera, its exposure spanning the C cycles */
    if ((s = cap_vio_open(b->camera, c->camera_images, &b->cam)) != GS_OK) goto fail;
    double actual;
    double exposure = cap_hw_exposure_s(c->cycles, c->grid_hz, c->exposure_margin_s);
    if ((s = cap_vio_set_exposure(b->cam, exposure, &actual)) != GS_OK ||
        (s = cap_hw_exposure_check(b->camera, exposure, actual)) != GS_OK)
        goto fail;
    time_t now = time(NULL);
    struct tm tmv;
    gmtime_r(&now, &tmv);
    strftime(b->utc, sizeof b->utc, "%Y-%m-%dT%H:%M:%SZ", &tmv);
    long nums[9] = {c->grid_hz, c->K, c->bands, c->width, c->height, c->cycles, c->masks,
                    c->locked, c->hdr};
    b->fingerprint = cap_fnv1a(CAP_FNV_INIT, nums, sizeof nums);
    b->fingerprint = cap_fnv1a(b->fingerprint, b->camera, strlen(b->camera));
    return cap_backend_wrap(&hw_ops, b, out);
fail:
    hw_free(b);
    return s;
}

gs_status cap_hw_exposure_check(const char *camera, double asked_s, double actual_s)
{
    /* (a longer exposure still spans the shutter's opening) */
    if (!isfinite(actual_s) || actual_s >= 0.98 * asked_s) return GS_OK;
    return gs_fail(GS_ELIMIT, "camera %s: exposure %.4g s asked, it set %.4g s: outside its range (the "
                   "frame must span the lock wait and C cycles: fewer cycles, or a camera with longer "
                   "exposures)", camera, asked_s, actual_s);
}

double cap_hw_exposure_s(long cycles, int grid_hz, double margin_s)
{
    /* (1e-4 over: the firmware's longest period, in whole ticks, is a little longer) */
    return CAP_LINK_LOCK_WAIT_MS / 1000.0 + 1.0001 * (double)cycles / (2.0 * (grid_hz - CAP_GRID_BAND_HZ)) + margin_s;
}

gs_status cap_backend_hardware_log(cap_backend *be, cap_hw_log *log)
{
    hw_backend *b = cap_backend_self(be, &hw_ops);
    if (!b) return gs_fail(GS_EINVAL, "not a hardware backend");
    *log = b->log;
    return GS_OK;
}
