/* backend_replay.c - the `replay` backend: serves the frames and HDR maps of an existing
 * capture directory (gs_capture_read validates it), e.g. to re-run the loop's bookkeeping, to
 * copy a capture, or to test consumers without a camera. */
#include "capture/internal.h"

#include <stdlib.h>
#include <string.h>

typedef struct {
    gs_capture cap;
    uint64_t fingerprint;
    int last_k;                 /* the last frame served, -1: none */
} replay_backend;

static gs_status replay_info(void *self, cap_acq_info *info)
{
    replay_backend *b = self;
    const gs_capture *c = &b->cap;
    memset(info, 0, sizeof *info);
    info->grid_hz = c->grid_hz;
    info->K = c->K;
    info->bands = c->bands;
    info->width = c->width;
    info->height = c->height;
    info->cycles = (long)c->frames[0].cycles;
    info->masks = 2;
    info->fixed_halvings = c->halvings != NULL;
    info->saturation_dn = c->saturation_dn;
    info->black_level_dn = c->black_level_dn;
    info->gain_e_per_dn = c->gain_e_per_dn;
    info->read_noise_dn = c->read_noise_dn;
    info->locked = c->locked;
    info->window_period = c->window_period;
    snprintf(info->utc, sizeof info->utc, "%s", c->utc);
    info->station_json = c->station_json;
    info->fingerprint = b->fingerprint;
    return GS_OK;
}

static gs_status replay_acquire(void *self, const cap_acquisition *a, unsigned char *halvings,
                                unsigned short *raw, double *cycles)
{
    replay_backend *b = self;
    const gs_capture *c = &b->cap;
    if (a->k < 0 || a->k >= c->K) return gs_fail(GS_EINVAL, "replay: frame %d of %d", a->k, c->K);
    size_t plane = (size_t)c->width * (size_t)c->height;
    /* gs_capture_read orders frames by their k */
    memcpy(raw, c->raw + plane * (size_t)c->bands * (size_t)a->k, plane * (size_t)c->bands * sizeof *raw);
    if (halvings) {
        if (c->halvings) memcpy(halvings, c->halvings + plane * (size_t)a->k, plane);
        else memset(halvings, 0, plane);
    }
    if (cycles) *cycles = c->frames[a->k].cycles;
    b->last_k = a->k;
    return GS_OK;
}

/* what the source capture.json holds for the frame (NaN when absent) */
static gs_status replay_timing(void *self, cap_acq_timing *t)
{
    replay_backend *b = self;
    if (b->last_k < 0) return GS_OK;
    t->grid_hz_measured = b->cap.frames[b->last_k].grid_hz_measured;
    t->start_s = b->cap.frames[b->last_k].start_s;
    t->window_half_period_s = b->cap.frames[b->last_k].window_half_period_s;
    t->window_drift_windows = b->cap.frames[b->last_k].window_drift_windows;
    return GS_OK;
}

static void replay_free(void *self)
{
    replay_backend *b = self;
    if (!b) return;
    gs_capture_release(&b->cap);
    free(b);
}

static const cap_backend_ops replay_ops = {"replay", replay_info, replay_acquire, replay_free,
                                            replay_timing};

gs_status cap_backend_replay_new(const char *dir, cap_backend **out)
{
    *out = NULL;
    replay_backend *b = calloc(1, sizeof *b);
    if (!b) return gs_fail(GS_ENOMEM, "replay backend: out of memory");
    b->last_k = -1;
    gs_status s = gs_capture_read(dir, &b->cap);
    if (s != GS_OK) {
        free(b);
        return s;
    }
    /* frames may be listed in any order: index them by k */
    for (int k = 0; k < b->cap.K; k++)
        if (b->cap.frames[k].k != k) {
            replay_free(b);
            return gs_fail(GS_EFORMAT, "%s: frames are not in k order after reading", dir);
        }
    char path[CAP_PATH_MAX + 16], *text = NULL;
    snprintf(path, sizeof path, "%s/capture.json", dir);
    size_t n = 0;
    s = gs_file_read(path, 0, &text, &n);
    if (s != GS_OK) {
        replay_free(b);
        return s;
    }
    b->fingerprint = cap_fnv1a(CAP_FNV_INIT ^ 0x7265706c6179ull, text, n);
    free(text);
    return cap_backend_wrap(&replay_ops, b, out);
}
