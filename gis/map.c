/* map.c - a PNG map of located lights (gis.h): local east/north metres around the lights'
 * centre (GeographicLib LocalCartesian; grid north is true north at the centre), discs coloured
 * by phase class, 1-sigma error ellipses, stations, a legend, a scale bar and a north arrow.
 * Drawn with PLplot's memcairo driver into memory and encoded by the format kit (PLplot's
 * pngcairo driver crashed in plend, free() of an invalid pointer, when a write of its file
 * failed; docs/reliability.md). */
#include "gis/internal.h"

#include <math.h>
#include <plplot.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

void gis_map_opts_default(gis_map_opts *o)
{
    memset(o, 0, sizeof *o);
    o->width_px = 1200;
    o->height_px = 900;
    o->draw_ellipses = 1;
}

/* 1, 2 or 5 times a power of ten, at most x. */
static double nice_length(double x)
{
    double p = pow(10.0, floor(log10(x))), m = x / p;
    return (m >= 5.0 ? 5.0 : m >= 2.0 ? 2.0 : 1.0) * p;
}

static void disc(double x, double y, double r, int n)
{
    PLFLT px[64], py[64];
    if (n > 64) n = 64;
    for (int i = 0; i < n; i++) {
        double t = 2.0 * 3.14159265358979323846 * i / n;
        px[i] = x + r * cos(t);
        py[i] = y + r * sin(t);
    }
    plfill(n, px, py);
}

/* What the map's drawing needs: the lights' and stations' local coordinates (x, y, metres east
 * and north of lat0, lon0), the lights' phase classes and rows (ref; NULL for a station). */
typedef struct {
    const gis_map_opts *o;
    const double *x, *y;
    const gis_phase_class *cls;
    const gis_light *const *ref;
    size_t nl, np;
    double lat0, lon0;
} map_drawing;

/* The whole map, with PLplot's memcairo driver onto rgb (in a child process: gs_isolated). */
static gs_status draw_map(void *ctx, unsigned char *rgb)
{
    const map_drawing *md = ctx;
    const gis_map_opts *o = md->o;
    const double *x = md->x, *y = md->y, lat0 = md->lat0, lon0 = md->lon0;
    const gis_phase_class *cls = md->cls;
    const gis_light *const *ref = md->ref;
    size_t nl = md->nl, np = md->np;
    double half = 50.0;
    for (size_t k = 0; k < np; k++) {
        if (fabs(x[k]) > half) half = fabs(x[k]);
        if (fabs(y[k]) > half) half = fabs(y[k]);
    }
    /* A square data area: the data stay within the inner 74 %, leaving a frame for the scale
     * bar (bottom) and the north arrow (right) that never covers a light. */
    half *= 1.35;
    double hx = half, hy = half, span = 2.0 * half;

    plsdev("memcairo");
    plsmem(o->width_px, o->height_px, rgb);
    plscmap0n(16);
    plscol0(0, 255, 255, 255);   /* background */
    plscol0(1, 0, 0, 0);
    for (int c = 0; c < 5; c++) {
        unsigned char col[3];
        gis_phase_rgb((gis_phase_class)c, col);
        plscol0(2 + c, col[0], col[1], col[2]);
    }
    plscol0(7, 90, 90, 90);
    plsexit(gs_isolated_exit);   /* plexit: its reason the last line, the child ended */
    plinit();
    plcol0(1);
    pladv(0);
    plvpas(0.13, 0.70, 0.10, 0.90, 1.0);   /* equal scales; the legend goes to the right */
    plwind(-hx, hx, -hy, hy);
    plbox("bcfnst", 0.0, 0, "bcfnstv", 0.0, 0); /* fixed-point labels: no (x10^3) over the axis titles */
    char title[300], sub[200];
    snprintf(title, sizeof title, "%s", o->title ? o->title : "gridsurvey: located lights");
    snprintf(sub, sizeof sub, "east (m) from %.6f\u00b0, %.6f\u00b0 (WGS84)", lat0, gs_wrap180(lon0));
    pllab(sub, "north (m)", title);

    /* ellipses, then discs (so a disc stays visible inside a small ellipse) */
    double r_disc = span / 150.0;
    if (o->draw_ellipses) {
        PLFLT ex[73], ey[73];
        plwidth(1.0);
        for (size_t k = 0; k < nl; k++) {
            const gis_ellipse *e = &ref[k]->ellipse;
            if (!isfinite(e->semi_major_m) || !isfinite(e->semi_minor_m) || !isfinite(e->azimuth_deg))
                continue;
            double az = e->azimuth_deg * GIS_DEG, ua[2] = {sin(az), cos(az)}, ub[2] = {cos(az), -sin(az)};
            for (int i = 0; i <= 72; i++) {
                double t = 2.0 * 3.14159265358979323846 * i / 72;
                ex[i] = x[k] + e->semi_major_m * cos(t) * ua[0] + e->semi_minor_m * sin(t) * ub[0];
                ey[i] = y[k] + e->semi_major_m * cos(t) * ua[1] + e->semi_minor_m * sin(t) * ub[1];
            }
            plcol0(2 + (int)cls[k]);
            plline(73, ex, ey);
        }
    }
    int count[5] = {0};
    for (size_t k = 0; k < nl; k++) {
        plcol0(2 + (int)cls[k]);
        disc(x[k], y[k], r_disc, 32);
        count[cls[k]]++;
    }
    for (size_t k = nl; k < np; k++) {   /* stations: black triangles */
        PLFLT tx[3] = {x[k] - r_disc * 1.6, x[k] + r_disc * 1.6, x[k]};
        PLFLT ty[3] = {y[k] - r_disc * 1.2, y[k] - r_disc * 1.2, y[k] + r_disc * 1.8};
        plcol0(1);
        plfill(3, tx, ty);
        char lab[32];
        snprintf(lab, sizeof lab, "station %zu", k - nl + 1);
        plschr(0, 0.7);
        plptex(x[k], y[k] - r_disc * 4.0, 1.0, 0.0, 0.5, lab);
        plschr(0, 1.0);
    }

    /* scale bar, bottom left */
    double L = nice_length(span / 5.0), x0 = -hx + 0.05 * span, y0 = -hy + 0.035 * span;
    plcol0(1);
    plwidth(3.0);
    pljoin(x0, y0, x0 + L, y0);
    pljoin(x0, y0 - 0.008 * span, x0, y0 + 0.008 * span);
    pljoin(x0 + L, y0 - 0.008 * span, x0 + L, y0 + 0.008 * span);
    plwidth(1.0);
    char lab[64];
    if (L >= 1000.0) snprintf(lab, sizeof lab, "%g km", L / 1000.0);
    else snprintf(lab, sizeof lab, "%g m", L);
    plptex(x0 + 0.5 * L, y0 + 0.035 * span, 1.0, 0.0, 0.5, lab);   /* (the text is centred on its y) */

    /* north arrow, top right */
    double ax = hx - 0.06 * span, ay0 = hy - 0.17 * span, ay1 = hy - 0.08 * span;
    plwidth(3.0);
    pljoin(ax, ay0, ax, ay1);
    plwidth(1.0);
    PLFLT hx3[3] = {ax - 0.015 * span, ax + 0.015 * span, ax};
    PLFLT hy3[3] = {ay1 - 0.03 * span, ay1 - 0.03 * span, ay1 + 0.005 * span};
    plfill(3, hx3, hy3);
    plschr(0, 1.3);
    plptex(ax, ay1 + 0.04 * span, 1.0, 0.0, 0.5, "N");
    plschr(0, 1.0);

    /* legend */
    static const char *const names[5] = {"phase 0\u00b0", "phase 120\u00b0", "phase 240\u00b0",
                                         "not 0/120/240\u00b0", "unknown phase"};
    char text[5][64];
    const char *labels[5];
    PLINT opts[5], box_col[5], box_pat[5], text_col[5];
    PLFLT box_scale[5], box_width[5];
    for (int c = 0; c < 5; c++) {
        snprintf(text[c], sizeof text[c], "%s (%d)", names[c], count[c]);
        labels[c] = text[c];
        opts[c] = PL_LEGEND_COLOR_BOX;
        box_col[c] = 2 + c;
        text_col[c] = 1;
        box_pat[c] = 0;
        box_scale[c] = 0.8;
        box_width[c] = 1.0;
    }
    PLFLT lw, lh;
    pllegend(&lw, &lh, PL_LEGEND_BACKGROUND | PL_LEGEND_BOUNDING_BOX, PL_POSITION_RIGHT |
             PL_POSITION_OUTSIDE, 0.03, 0.0, 0.06, 0, 1, 1, 5, 1, 5, opts, 1.0, 0.8, 2.0, 0.0,
             text_col, (const char *const *)labels, box_col, box_pat, box_scale, box_width, NULL,
             NULL, NULL, NULL, NULL, NULL, NULL);
    plend();
    return GS_OK;
}

gs_status gis_map_png(const gis_light *lights, size_t n, const gis_map_opts *o, const char *path)
{
    gis_map_opts def;
    if (!o) {
        gis_map_opts_default(&def);
        o = &def;
    }
    if (n && !lights) return gs_fail(GS_EINVAL, "map: NULL lights");
    if (o->width_px < 200 || o->height_px < 200 || o->width_px > 10000 || o->height_px > 10000)
        return gs_fail(GS_EINVAL, "map: size %d x %d px: expected 200..10000", o->width_px, o->height_px);
    if (o->n_stations && !o->stations) return gs_fail(GS_EINVAL, "map: NULL stations");
    for (size_t i = 0; i < o->n_stations; i++) {
        gs_status s = gis_camera_check(&o->stations[i]);
        if (s != GS_OK) return s;
    }

    /* Reference: the first located light (else station), then the centre of the extent. */
    double lat0 = NAN, lon0 = NAN;
    size_t nl = 0;
    for (size_t i = 0; i < n; i++)
        if (isfinite(lights[i].lat_deg) && isfinite(lights[i].lon_deg)) {
            if (fabs(lights[i].lat_deg) > 90.0)
                return gs_fail(GS_EINVAL, "map: light %zu latitude %g", i, lights[i].lat_deg);
            if (!nl) {
                lat0 = lights[i].lat_deg;
                lon0 = lights[i].lon_deg;
            }
            nl++;
        }
    if (!nl && o->n_stations) {
        lat0 = o->stations[0].lat_deg;
        lon0 = o->stations[0].lon_deg;
    }
    if (!nl && !o->n_stations) return gs_fail(GS_EINVAL, "map: no located light and no station to draw");
    size_t np = nl + o->n_stations;
    double *x = malloc(sizeof *x * (np + 1)), *y = malloc(sizeof *y * (np + 1));
    gis_phase_class *cls = malloc(sizeof *cls * (np + 1));
    const gis_light **ref = malloc(sizeof *ref * (np + 1));
    if (!x || !y || !cls || !ref) {
        free(x);
        free(y);
        free(cls);
        free(ref);
        return gs_fail(GS_ENOMEM, "map: out of memory");
    }
    gs_status s = GS_OK;
    for (int pass = 0; pass < 2 && s == GS_OK; pass++) {
        double xmin = INFINITY, xmax = -INFINITY, ymin = INFINITY, ymax = -INFINITY;
        size_t k = 0;
        for (size_t i = 0; i < n + o->n_stations; i++) {
            double la, lo;
            if (i < n) {
                if (!(isfinite(lights[i].lat_deg) && isfinite(lights[i].lon_deg))) continue;
                la = lights[i].lat_deg;
                lo = lights[i].lon_deg;
                cls[k] = gis_phase_classify(lights[i].phase_deg);
                ref[k] = &lights[i];
            } else {
                la = o->stations[i - n].lat_deg;
                lo = o->stations[i - n].lon_deg;
                ref[k] = NULL;
            }
            double enu[3];
            if (gis_gl_local_fwd(lat0, lon0, 0.0, la, lo, 0.0, enu)) {
                s = GS_ENUMERIC;
                break;
            }
            x[k] = enu[0];
            y[k] = enu[1];
            if (x[k] < xmin) xmin = x[k];
            if (x[k] > xmax) xmax = x[k];
            if (y[k] < ymin) ymin = y[k];
            if (y[k] > ymax) ymax = y[k];
            k++;
        }
        if (s != GS_OK || pass == 1) break;
        /* re-centre on the middle of the extent */
        double mid[3] = {0.5 * (xmin + xmax), 0.5 * (ymin + ymax), 0.0}, h;
        if (gis_gl_local_rev(lat0, lon0, 0.0, mid, &lat0, &lon0, &h)) s = GS_ENUMERIC;
    }
    size_t npx = (size_t)o->width_px * (size_t)o->height_px;
    unsigned char *rgb = s == GS_OK ? malloc(3 * npx) : NULL;
    if (s == GS_OK && !rgb) s = gs_fail(GS_ENOMEM, "map: cannot hold a %dx%d image", o->width_px, o->height_px);
    if (s != GS_OK) {
        free(x);
        free(y);
        free(cls);
        free(ref);
        return s;
    }

    map_drawing md = {o, x, y, cls, ref, nl, np, lat0, lon0};
    memset(rgb, 255, 3 * npx);   /* the background: memcairo draws onto the buffer */
    s = gs_isolated(path, rgb, 3 * npx, draw_map, &md);
    free(x);
    free(y);
    free(cls);
    free(ref);
    unsigned char *png = NULL;
    size_t size = 0;
    if (s == GS_OK) s = gs_png_encode(rgb, o->width_px, o->height_px, 3, 8, &png, &size);
    free(rgb);
    if (s == GS_OK) s = gs_file_write_atomic(path, png, size);
    free(png);
    return s;
}
