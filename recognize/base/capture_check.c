/* capture_check.c - the rules of the capture directory format (docs/formats.md), one place for
 * the reader, the writer and every module that builds a capture in memory: the field ranges,
 * file names, ISO 8601 times and the frames table. */
#include "recognize/base/internal.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

/* A frame or HDR-map file name: [A-Za-z0-9._-]+ ending in ".png", not starting with '.',
 * shorter than GS_PATH_MAX. No directories: the capture is one flat folder. */
int gs_capture_valid_name(const char *s)
{
    size_t n = strnlen(s, GS_PATH_MAX);
    if (n < 5 || n >= GS_PATH_MAX || s[0] == '.' || strcmp(s + n - 4, ".png") != 0) return 0;
    for (size_t i = 0; i < n; i++) {
        char c = s[i];
        if (!((c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
              c == '.' || c == '_' || c == '-'))
            return 0;
    }
    return 1;
}

/* `count` decimal digits at s, as an int in [lo, hi]; 0 on failure. */
static int digits(const char *s, int count, int lo, int hi, int *out)
{
    int v = 0;
    for (int i = 0; i < count; i++) {
        if (s[i] < '0' || s[i] > '9') return 0;
        v = v * 10 + (s[i] - '0');
    }
    if (v < lo || v > hi) return 0;
    if (out) *out = v;
    return 1;
}

/* ISO 8601 date-time: YYYY-MM-DDThh:mm:ss[.f+](Z|+hh:mm|-hh:mm), shorter than 40 bytes, a day
 * that its month has (a second of 60, a leap second, is ISO's). */
int gs_capture_valid_utc(const char *s)
{
    size_t n = strnlen(s, 40);
    if (n >= 40 || n < 20) return 0;
    int y = 0, mo = 0, d = 0;
    static const int days[12] = {31, 29, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31};
    if (!digits(s, 4, 0, 9999, &y) || s[4] != '-' || !digits(s + 5, 2, 1, 12, &mo) ||
        s[7] != '-' || !digits(s + 8, 2, 1, 31, &d) || d > days[mo - 1] ||
        (mo == 2 && d == 29 && !(y % 4 == 0 && (y % 100 != 0 || y % 400 == 0))) || s[10] != 'T' ||
        !digits(s + 11, 2, 0, 23, NULL) || s[13] != ':' || !digits(s + 14, 2, 0, 59, NULL) ||
        s[16] != ':' || !digits(s + 17, 2, 0, 60, NULL))
        return 0;
    size_t i = 19;
    if (s[i] == '.') {
        i++;
        size_t start = i;
        while (s[i] >= '0' && s[i] <= '9') i++;
        if (i == start) return 0;
    }
    if (s[i] == 'Z') return s[i + 1] == '\0';
    if (s[i] != '+' && s[i] != '-') return 0;
    return digits(s + i + 1, 2, 0, 23, NULL) && s[i + 3] == ':' &&
           digits(s + i + 4, 2, 0, 59, NULL) && s[i + 6] == '\0';
}

static int set_problem(gs_capture_problem *pr, const char *field, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
static int set_problem(gs_capture_problem *pr, const char *field, const char *fmt, ...)
{
    snprintf(pr->field, sizeof pr->field, "%s", field);
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(pr->expect, sizeof pr->expect, fmt, ap);
    va_end(ap);
    return 0;
}

int gs_capture_check_geometry(const gs_capture *c, gs_capture_problem *pr)
{
    if (c->K < 2 || c->K > GS_CAPTURE_MAX_K) return set_problem(pr, "K", GS_CAPTURE_EXP_K);
    if (c->bands != 1 && c->bands != 3) return set_problem(pr, "bands", GS_CAPTURE_EXP_BANDS);
    if (c->width < 1 || c->width > GS_CAPTURE_MAX_SIDE) return set_problem(pr, "width", GS_CAPTURE_EXP_SIDE);
    if (c->height < 1 || c->height > GS_CAPTURE_MAX_SIDE) return set_problem(pr, "height", GS_CAPTURE_EXP_SIDE);
    return 1;
}

int gs_capture_check_fields(const gs_capture *c, gs_capture_problem *pr)
{
    if (c->grid_hz != 50 && c->grid_hz != 60) return set_problem(pr, "grid_hz", GS_CAPTURE_EXP_GRID);
    if (!gs_capture_check_geometry(c, pr)) return 0;
    if (!(c->black_level_dn >= 0 && c->black_level_dn < GS_CAPTURE_MAX_SATURATION))
        return set_problem(pr, "black_level", "a number >= 0 and < 65536");
    if (!(c->saturation_dn > c->black_level_dn && c->saturation_dn <= GS_CAPTURE_MAX_SATURATION))
        return set_problem(pr, "saturation", "a number > black_level (%.17g) and <= 65536",
                           c->black_level_dn);
    if (!(isfinite(c->gain_e_per_dn) && c->gain_e_per_dn >= 0))
        return set_problem(pr, "gain_e_per_dn", GS_CAPTURE_EXP_NONNEG);
    if (!(isfinite(c->read_noise_dn) && c->read_noise_dn >= 0))
        return set_problem(pr, "read_noise_dn", GS_CAPTURE_EXP_NONNEG);
    if (c->locked != 0 && c->locked != 1) return set_problem(pr, "locked", GS_CAPTURE_EXP_LOCKED);
    if (c->window_period != GS_PERIOD_UNKNOWN && !(gs_period_name(c->window_period) && !c->locked))
        return set_problem(pr, "window_period", GS_CAPTURE_EXP_PERIOD_SOURCE);
    if (memchr(c->utc, '\0', sizeof c->utc) == NULL || (c->utc[0] && !gs_capture_valid_utc(c->utc)))
        return set_problem(pr, "utc", GS_CAPTURE_EXP_UTC);
    for (int k = 0; k < c->K; k++) {
        const gs_frame_info *f = &c->frames[k];
        char field[64];
        snprintf(field, sizeof field, "frames[%d].k", k);
        if (f->k != k) return set_problem(pr, field, "%d (frames are held in k order)", k);
        snprintf(field, sizeof field, "frames[%d].cycles", k);
        if (!(isfinite(f->cycles) && f->cycles > 0)) return set_problem(pr, field, GS_CAPTURE_EXP_CYCLES);
        snprintf(field, sizeof field, "frames[%d].grid_hz_measured", k);
        if (!isnan(f->grid_hz_measured) &&
            !(isfinite(f->grid_hz_measured) && f->grid_hz_measured >= 45 &&
              f->grid_hz_measured <= 65))
            return set_problem(pr, field, GS_CAPTURE_EXP_HZ_MEASURED);
        snprintf(field, sizeof field, "frames[%d].start_s", k);
        if (!isnan(f->start_s) && !(isfinite(f->start_s) && f->start_s >= 0))
            return set_problem(pr, field, GS_CAPTURE_EXP_START);
        snprintf(field, sizeof field, "frames[%d].window_half_period_s", k);
        if (!isnan(f->window_half_period_s) &&
            !(!c->locked && isfinite(f->window_half_period_s) &&
              f->window_half_period_s >= GS_WINDOW_HALF_PERIOD_MIN_S &&
              f->window_half_period_s <= GS_WINDOW_HALF_PERIOD_MAX_S))
            return set_problem(pr, field, GS_CAPTURE_EXP_WINDOW_PERIOD);
        snprintf(field, sizeof field, "frames[%d].window_drift_windows", k);
        if (!isnan(f->window_drift_windows) &&
            !(!c->locked && isfinite(f->window_drift_windows) && f->window_drift_windows >= 0))
            return set_problem(pr, field, GS_CAPTURE_EXP_WINDOW_DRIFT);
        snprintf(field, sizeof field, "frames[%d].file", k);
        if (!gs_capture_valid_name(f->file)) return set_problem(pr, field, GS_CAPTURE_EXP_FILE);
        snprintf(field, sizeof field, "frames[%d].hdr_map", k);
        if (memchr(f->hdr_map, '\0', sizeof f->hdr_map) == NULL ||
            (f->hdr_map[0] && !gs_capture_valid_name(f->hdr_map)))
            return set_problem(pr, field, "\"\" (no map) or " GS_CAPTURE_EXP_FILE);
        /* every file of the directory is named once */
        for (int j = 0; j < k; j++) {
            const gs_frame_info *g = &c->frames[j];
            if (strcmp(f->file, g->file) == 0 || strcmp(f->file, g->hdr_map) == 0 ||
                (f->hdr_map[0] && (strcmp(f->hdr_map, g->file) == 0 ||
                                   strcmp(f->hdr_map, g->hdr_map) == 0))) {
                snprintf(field, sizeof field, "frames[%d]", k);
                return set_problem(pr, field, "file names used by no other frame (frames[%d] "
                                   "names the same file)", j);
            }
        }
        if (f->hdr_map[0] && strcmp(f->file, f->hdr_map) == 0) {
            snprintf(field, sizeof field, "frames[%d].hdr_map", k);
            return set_problem(pr, field, "a file other than the frame's own");
        }
    }
    return 1;
}

gs_status gs_capture_check(const gs_capture *cap, const char *who)
{
    gs_capture_problem pr;
    if (!cap || !cap->frames) return gs_fail(GS_EINVAL, "%s: no capture or no frames table", who);
    if (!gs_capture_check_fields(cap, &pr))
        return gs_fail(GS_EINVAL, "%s: field %s: expected %s", who, pr.field, pr.expect);
    return GS_OK;
}

const char *gs_period_name(int window_period)
{
    return window_period == GS_PERIOD_MEASURED ? "measured" : window_period == GS_PERIOD_NOMINAL ? "nominal" : NULL;
}

/* Free running, window k starts at k P / K + c P after the exposure's first crossing, so over
 * its C cycles it moves by C (P / Delta - 1) cycles against the flicker (against Eq. 5's window
 * [k/K, (k+1)/K) of every cycle), Delta = 1 / (2 f) the exposure's mean half period (Eq. 1):
 * K C |2 P f - 1| windows, the net motion; the recorded range when there is one. */
double gs_capture_frame_drift(const gs_capture *cap, int k)
{
    if (cap->locked) return 0.0;
    const gs_frame_info *f = &cap->frames[k];
    if (f->window_drift_windows >= 0.0) return f->window_drift_windows;
    double d = (double)cap->K * f->cycles * fabs(2.0 * f->window_half_period_s * f->grid_hz_measured - 1.0);
    return isfinite(d) ? d : NAN;
}

double gs_capture_window_drift(const gs_capture *cap, int *frame)
{
    if (frame) *frame = -1;
    double worst = 0.0;
    for (int k = 0; k < cap->K; k++) {
        double d = gs_capture_frame_drift(cap, k);
        if (isnan(d)) {
            if (frame) *frame = k;
            return NAN;
        }
        if (d > worst || (frame && *frame < 0)) {
            worst = d;
            if (frame) *frame = k;
        }
    }
    return worst;
}
