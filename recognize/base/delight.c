/* delight.c - the in-memory DELIGHT collection (paper Sec. 3), technology names and entry
 * validation. Storage (SQLite, CSV) and the physical generator live in their own files. */
#include "recognize/base/internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

struct gs_delight {
    gs_bulb *bulbs;
    size_t count, cap;
};

static const char *const tech_names[GS_TECH_COUNT] = {
    [GS_TECH_INCANDESCENT] = "incandescent",
    [GS_TECH_HALOGEN] = "halogen",
    [GS_TECH_FLUORESCENT_MAGNETIC] = "fluorescent_magnetic",
    [GS_TECH_FLUORESCENT_ELECTRONIC] = "fluorescent_electronic",
    [GS_TECH_CFL] = "cfl",
    [GS_TECH_LED_CAPACITOR] = "led_capacitor",
    [GS_TECH_LED_LINEAR] = "led_linear",
    [GS_TECH_LED_PWM] = "led_pwm",
    [GS_TECH_SODIUM_HP] = "sodium_hp",
    [GS_TECH_SODIUM_LP] = "sodium_lp",
    [GS_TECH_METAL_HALIDE] = "metal_halide",
    [GS_TECH_MERCURY] = "mercury",
    [GS_TECH_UNKNOWN] = "unknown",
};

const char *gs_tech_name(gs_tech t)
{
    return (t >= 0 && t < GS_TECH_COUNT) ? tech_names[t] : "invalid";
}

gs_status gs_tech_parse(const char *name, gs_tech *t)
{
    for (int i = 0; i < GS_TECH_COUNT; i++) {
        if (strcmp(name, tech_names[i]) == 0) {
            *t = (gs_tech)i;
            return GS_OK;
        }
    }
    return gs_fail(GS_ENOTFOUND, "technology '%s': expected one of incandescent, halogen, "
                   "fluorescent_magnetic, fluorescent_electronic, cfl, led_capacitor, led_linear, "
                   "led_pwm, sodium_hp, sodium_lp, metal_halide, mercury, unknown", name);
}

const char *gs_ref_name(gs_ref r)
{
    switch (r) {
    case GS_REF_VOLTAGE: return "voltage";
    case GS_REF_NONE: return "none";
    case GS_REF_UNLOCKED: return "unlocked";
    }
    return "invalid";
}

void gs_bulb_release(gs_bulb *b)
{
    if (b) gs_brf_release(&b->brf);
}

gs_delight *gs_delight_new(void)
{
    return calloc(1, sizeof(gs_delight));
}

void gs_delight_free(gs_delight *d)
{
    if (!d) return;
    for (size_t i = 0; i < d->count; i++) gs_bulb_release(&d->bulbs[i]);
    free(d->bulbs);
    free(d);
}

size_t gs_delight_count(const gs_delight *d)
{
    return d->count;
}

const gs_bulb *gs_delight_get(const gs_delight *d, size_t i)
{
    return i < d->count ? &d->bulbs[i] : NULL;
}

const gs_bulb *gs_delight_find(const gs_delight *d, const char *id, int grid_hz, int bands)
{
    for (size_t i = 0; i < d->count; i++) {
        const gs_bulb *b = &d->bulbs[i];
        if (strcmp(b->id, id) == 0 && (grid_hz <= 0 || b->grid_hz == grid_hz) &&
            (bands <= 0 || b->brf.bands == bands))
            return b;
    }
    return NULL;
}

static int valid_id(const char *id)
{
    if (!*id) return 0;
    for (const char *c = id; *c; c++)
        if (!((*c >= 'a' && *c <= 'z') || (*c >= 'A' && *c <= 'Z') || (*c >= '0' && *c <= '9') ||
              *c == '_' || *c == '-' || *c == '.'))
            return 0;
    return 1;
}

/* The checks every entry passes, whatever its source (generator, SQLite, CSV, recording). */
gs_status gs_bulb_validate(const gs_bulb *b)
{
    if (!valid_id(b->id))
        return gs_fail(GS_EINVAL, "bulb_id '%s': expected letters, digits, '_', '-' or '.'", b->id);
    if (b->type < 0 || b->type >= GS_TECH_COUNT)
        return gs_fail(GS_EINVAL, "bulb %s: type %d: expected a technology", b->id, (int)b->type);
    for (const char *c = b->name; *c; c++)
        if ((unsigned char)*c < 0x20 || *c == 0x7f)
            return gs_fail(GS_EINVAL, "bulb %s: name: expected no control character (line break, "
                           "tab, ...)", b->id);
    if (!(b->watts >= 0.0 && b->watts < GS_WATTS_MAX))
        return gs_fail(GS_EINVAL, "bulb %s: watts=%g: expected 0 <= watts < %g", b->id, b->watts, GS_WATTS_MAX);
    if (b->grid_hz != 50 && b->grid_hz != 60)
        return gs_fail(GS_EINVAL, "bulb %s: grid_hz=%d: expected 50 or 60", b->id, b->grid_hz);
    if (!b->sensor[0] || strpbrk(b->sensor, ",/\n\r\""))
        return gs_fail(GS_EINVAL, "bulb %s: sensor '%s': expected a non-empty name without ',' or '/'",
                       b->id, b->sensor);
    if (b->ref != GS_REF_VOLTAGE && b->ref != GS_REF_NONE && b->ref != GS_REF_UNLOCKED)
        return gs_fail(GS_EINVAL, "bulb %s: reference %d: expected voltage, none or unlocked", b->id,
                       (int)b->ref);
    if (!b->brf.v || (b->brf.bands != 1 && b->brf.bands != 3) || b->brf.n < 4)
        return gs_fail(GS_EINVAL, "bulb %s: BRF missing or with %d bands: expected 1 or 3", b->id,
                       b->brf.bands);
    double qsum = 0.0;
    for (int band = 0; band < b->brf.bands; band++) {
        if (!(b->chroma[band] >= 0.0 && b->chroma[band] <= 1.0))
            return gs_fail(GS_EINVAL, "bulb %s: chromaticity[%d]=%g: expected [0,1]", b->id, band,
                           b->chroma[band]);
        qsum += b->chroma[band];
        double sum = 0.0;
        const double *x = b->brf.v + (size_t)band * (size_t)b->brf.n;
        for (int i = 0; i < b->brf.n; i++) {
            if (!isfinite(x[i]))
                return gs_fail(GS_ENUMERIC, "bulb %s: band %d sample v%d is %g: expected a finite value",
                               b->id, band, i, x[i]);
            sum += x[i];
        }
        if (fabs(sum / b->brf.n - 1.0) > 1e-6)
            return gs_fail(GS_EINVAL, "bulb %s: band %d BRF mean %.9g: expected 1", b->id, band,
                           sum / b->brf.n);
    }
    if (fabs(qsum - 1.0) > 1e-6)
        return gs_fail(GS_EINVAL, "bulb %s: chromaticities sum to %.9g: expected 1", b->id, qsum);
    return GS_OK;
}

gs_status gs_delight_add(gs_delight *d, const gs_bulb *b)
{
    gs_status s = gs_bulb_validate(b);
    if (s != GS_OK) return s;
    for (size_t i = 0; i < d->count; i++) {
        const gs_bulb *o = &d->bulbs[i];
        if (strcmp(o->id, b->id) == 0 && o->grid_hz == b->grid_hz && strcmp(o->sensor, b->sensor) == 0)
            return gs_fail(GS_EINVAL, "bulb %s at %d Hz with sensor %s: already in the database",
                           b->id, b->grid_hz, b->sensor);
    }
    if (d->count == d->cap) {
        size_t cap = d->cap ? 2 * d->cap : 64;
        gs_bulb *nb = realloc(d->bulbs, cap * sizeof *nb);
        if (!nb) return gs_fail(GS_ENOMEM, "DELIGHT: cannot grow to %zu bulbs", cap);
        d->bulbs = nb;
        d->cap = cap;
    }
    gs_bulb *dst = &d->bulbs[d->count];
    *dst = *b;
    s = gs_brf_copy(&dst->brf, &b->brf);
    if (s != GS_OK) return s;
    d->count++;
    return GS_OK;
}
