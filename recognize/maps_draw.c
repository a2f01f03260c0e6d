/* maps_draw.c - the map PNGs (recognize.h: rec_map_write_*_png): composed pixel by pixel (exact
 * colours, so a test can read them back), the legend text drawn on top by PLplot's memcairo
 * driver, then encoded with libspng (gs_png_encode). */
#include "recognize/internal.h"

#include <math.h>
#include <plplot.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define MAP_MIN_WIDTH 480    /* the legend needs this much width */
#define V_MIN 0.35           /* HSV value of the faintest mapped pixel */

/* Distinct colours for the listed bulbs (Tableau 20's first twelve), then a dark one for the
 * other bulbs; every entry used (rec_bulb_legend). */
const unsigned char rec_bulb_palette[][3] = {
    {31, 119, 180},  {255, 127, 14},  {44, 160, 44},   {214, 39, 40},   {148, 103, 189},
    {140, 86, 75},   {227, 119, 194}, {188, 189, 34},  {23, 190, 207},  {174, 199, 232},
    {255, 187, 120}, {152, 223, 138}, {0, 90, 60},
};
_Static_assert(sizeof rec_bulb_palette / sizeof *rec_bulb_palette == REC_BULB_LEGEND_MAX + 1,
               "a colour per listed bulb and the other's, none unused");

/* ------------------------------------------------------------ canvas and legend */

typedef struct {
    double x, y, size_mm, just;   /* just: 0 left-aligned at x, 1 right-aligned */
    char text[160];
} label;

typedef struct {
    int w, h;
    unsigned char *rgb;
    label *labels;
    size_t nlabels, cap_labels;
} canvas;

static void canvas_free(canvas *c)
{
    free(c->rgb);
    free(c->labels);
}

static void put_px(canvas *c, int x, int y, const unsigned char col[3])
{
    if (x < 0 || y < 0 || x >= c->w || y >= c->h) return;
    memcpy(c->rgb + 3 * ((size_t)y * (size_t)c->w + (size_t)x), col, 3);
}

static void fill_rect(canvas *c, int x0, int y0, int w, int h, const unsigned char col[3])
{
    for (int y = y0; y < y0 + h; y++)
        for (int x = x0; x < x0 + w; x++) put_px(c, x, y, col);
}

static const unsigned char ink[3] = {0, 0, 0},
                           grey_col[3] = {128, 128, 128}, white_col[3] = {255, 255, 255},
                           dark_col[3] = {0, 0, 0};

static void swatch(canvas *c, int x0, int y0, int side, const unsigned char col[3])
{
    fill_rect(c, x0, y0, side, side, ink);
    fill_rect(c, x0 + 1, y0 + 1, side - 2, side - 2, col);
}

static gs_status add_label(canvas *c, double x, double y, double size_mm, const char *fmt, ...)
    __attribute__((format(printf, 5, 6)));
static gs_status add_label(canvas *c, double x, double y, double size_mm, const char *fmt, ...)
{
    if (c->nlabels == c->cap_labels) {
        size_t n = c->cap_labels ? 2 * c->cap_labels : 32;
        label *l = realloc(c->labels, sizeof *l * n);
        if (!l) return gs_fail(GS_ENOMEM, "maps: cannot hold %zu legend labels", n);
        c->labels = l;
        c->cap_labels = n;
    }
    label *l = &c->labels[c->nlabels++];
    l->x = x;
    l->y = y;
    l->size_mm = size_mm;
    l->just = 0.0;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(l->text, sizeof l->text, fmt, ap);
    va_end(ap);
    return GS_OK;
}

/* The queued labels, with PLplot's memcairo driver onto rgb (in a child process: gs_isolated). */
static gs_status draw_labels(void *ctx, unsigned char *rgb)
{
    const canvas *c = ctx;
    plsdev("memcairo");
    plsmem(c->w, c->h, rgb);
    plsexit(gs_isolated_exit);   /* plexit: its reason the last line, the child ended */
    plinit();
    pladv(0);
    plvpor(0.0, 1.0, 0.0, 1.0);
    plwind(0.0, c->w, c->h, 0.0);   /* pixel coordinates, y down */
    plscol0(1, 0, 0, 0);
    plcol0(1);
    for (size_t i = 0; i < c->nlabels; i++) {
        plschr(c->labels[i].size_mm, 1.0);
        plptex(c->labels[i].x, c->labels[i].y, 1.0, 0.0, c->labels[i].just, c->labels[i].text);
    }
    plend();
    return GS_OK;
}

/* Draw the queued labels onto the pixels, then encode the PNG. */
static gs_status canvas_write(canvas *c, const char *path)
{
    if (c->nlabels) {
        gs_status s = gs_isolated(path, c->rgb, (size_t)c->w * (size_t)c->h * 3, draw_labels, c);
        if (s != GS_OK) return s;
    }
    unsigned char *png = NULL;
    size_t size = 0;
    gs_status st = gs_png_encode(c->rgb, c->w, c->h, 3, 8, &png, &size);
    if (st == GS_OK) st = gs_file_write_atomic(path, png, size);
    free(png);
    return st;
}

/* HSV (h in degrees, s and v in [0, 1]) to 8-bit RGB. */
static void hsv_rgb(double h, double s, double v, unsigned char out[3])
{
    h = fmod(h, 360.0);
    if (h < 0) h += 360.0;
    double c = v * s, hp = h / 60.0, x = c * (1.0 - fabs(fmod(hp, 2.0) - 1.0)), r = 0, g = 0, b = 0;
    switch ((int)hp) {
    case 0: r = c; g = x; break;
    case 1: r = x; g = c; break;
    case 2: g = c; b = x; break;
    case 3: g = x; b = c; break;
    case 4: r = x; b = c; break;
    default: r = c; b = x; break;
    }
    double mn = v - c;
    out[0] = (unsigned char)lround(255.0 * (r + mn));
    out[1] = (unsigned char)lround(255.0 * (g + mn));
    out[2] = (unsigned char)lround(255.0 * (b + mn));
}

/* Viridis at 5 control points, linearly interpolated (t in [0, 1]). */
static void conf_rgb(double t, unsigned char out[3])
{
    static const double cp[5][3] = {{68, 1, 84}, {59, 82, 139}, {33, 145, 140}, {94, 201, 98}, {253, 231, 37}};
    if (!(t >= 0.0)) t = 0.0;
    if (t > 1.0) t = 1.0;
    double u = t * 4.0;
    int i = (int)u;
    if (i > 3) i = 3;
    double f = u - i;
    for (int c = 0; c < 3; c++) out[c] = (unsigned char)lround(cp[i][c] + f * (cp[i + 1][c] - cp[i][c]));
}

/* The HSV value of a mapped pixel from its SNR: V_MIN at the threshold, 1 at the 99th percentile
 * of the mapped pixels. */
typedef struct {
    double log_thr, log_span;
} vscale;

static int cmp_float(const void *a, const void *b)
{
    float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

static gs_status vscale_make(const rec_pixel_maps *pm, vscale *vs)
{
    size_t np = (size_t)pm->width * (size_t)pm->height, n = 0;
    for (size_t p = 0; p < np; p++) n += pm->state[p] == REC_PIX_MATCHED || pm->state[p] == REC_PIX_NO_ANSWER;
    vs->log_thr = log(pm->threshold_sigma);
    vs->log_span = 0.0;
    if (n == 0) return GS_OK;
    float *v = malloc(sizeof *v * n);
    if (!v) return gs_fail(GS_ENOMEM, "maps: cannot sort %zu pixels", n);
    n = 0;
    for (size_t p = 0; p < np; p++)
        if (pm->state[p] == REC_PIX_MATCHED || pm->state[p] == REC_PIX_NO_ANSWER) v[n++] = pm->snr[p];
    qsort(v, n, sizeof *v, cmp_float);
    double hi = v[(size_t)(0.99 * (double)(n - 1))];
    free(v);
    if (hi > pm->threshold_sigma * 1.0001) vs->log_span = log(hi) - vs->log_thr;
    return GS_OK;
}

static double vscale_at(const vscale *vs, double snr)
{
    if (vs->log_span <= 0.0) return 1.0;
    double t = snr > 0.0 ? (log(snr) - vs->log_thr) / vs->log_span : 0.0;
    if (!(t > 0.0)) t = 0.0;
    if (t > 1.0) t = 1.0;
    return V_MIN + (1.0 - V_MIN) * t;
}

/* A canvas holding the scaled map area and a legend band of legend_h rows below it. */
static gs_status canvas_new(canvas *c, const rec_pixel_maps *pm, int legend_h, int *scale)
{
    memset(c, 0, sizeof *c);
    int s = rec_map_scale(pm->width, pm->height);
    long w = (long)s * pm->width, h = (long)s * pm->height + legend_h;
    if (w < MAP_MIN_WIDTH) w = MAP_MIN_WIDTH;
    if (w > 65535 || h > 65535) return gs_fail(GS_ELIMIT, "maps: a %ldx%ld image is too large", w, h);
    c->w = (int)w;
    c->h = (int)h;
    c->rgb = malloc((size_t)c->w * (size_t)c->h * 3);
    if (!c->rgb) return gs_fail(GS_ENOMEM, "maps: cannot allocate a %dx%d image", c->w, c->h);
    memset(c->rgb, 255, (size_t)c->w * (size_t)c->h * 3);   /* legend paper */
    fill_rect(c, 0, 0, s * pm->width, s * pm->height, dark_col);
    *scale = s;
    return GS_OK;
}

static void map_px(canvas *c, int s, int x, int y, const unsigned char col[3])
{
    fill_rect(c, s * x, s * y, s, s, col);
}

/* Legend items in columns: swatches of 16 px and their labels. */
typedef struct {
    unsigned char rgb[3];
    char text[120];
} key_item;

#define ROW_H 22
#define LEGEND_TOP 8
#define TITLE_H 26
#define TEXT_MM 3.4
#define CHAR_PX 7.5   /* a label character's width at TEXT_MM, at most (digits: ~7) */

/* The columns' width: at least 320 px, and the longest label's with a margin. */
static int legend_col_w(const key_item *items, size_t n)
{
    int w = 320;
    for (size_t i = 0; i < n; i++) {
        int need = 24 + (int)ceil(CHAR_PX * (double)strlen(items[i].text)) + 24;
        if (need > w) w = need;
    }
    return w;
}

static int legend_rows(int width, const key_item *items, size_t n)
{
    int cols = width / legend_col_w(items, n);
    if (cols < 1) cols = 1;
    return (int)((n + (size_t)cols - 1) / (size_t)cols);
}

static gs_status draw_items(canvas *c, int y0, const key_item *items, size_t n)
{
    int col_w = legend_col_w(items, n), rows = legend_rows(c->w, items, n);
    for (size_t i = 0; i < n; i++) {
        int col = (int)(i / (size_t)rows), row = (int)(i % (size_t)rows);
        int x = 12 + col * col_w, y = y0 + row * ROW_H;
        swatch(c, x, y + 2, 16, items[i].rgb);
        gs_status st = add_label(c, x + 24, y + 10, TEXT_MM, "%s", items[i].text);
        if (st != GS_OK) return st;
    }
    return GS_OK;
}


/* ------------------------------------------------------------ phase map */

gs_status rec_map_write_phase_png(const rec_pixel_maps *pm, const char *path)
{
    if (!pm || !pm->state || !path) return gs_fail(GS_EINVAL, "phase map: no maps or no path");
    key_item items[10];
    size_t n = 0;
    double set[6] = {0.0, 120.0, 240.0, 0, 0, 0};
    int nset = 0;
    if (pm->phases != REC_PHASES_CONTINUOUS) {
        nset = pm->phases == REC_PHASES_6 ? 6 : 3;
        for (int i = 3; i < nset; i++) set[i] = fmod(set[i - 3] + pm->transformer_deg + 720.0, 360.0);
        for (int i = 0; i < nset; i++) {
            hsv_rgb(set[i], 1.0, 1.0, items[n].rgb);
            snprintf(items[n++].text, sizeof items[0].text, "%g" REC_DEG "%s", set[i],
                     i >= 3 ? " (transformer)" : "");
        }
    }
    memcpy(items[n].rgb, grey_col, 3);
    snprintf(items[n++].text, sizeof items[0].text, "ambiguous (conf. < %.2g) or unknown",
             pm->ambiguous_conf);
    memcpy(items[n].rgb, white_col, 3);
    snprintf(items[n++].text, sizeof items[0].text, "saturated");
    memcpy(items[n].rgb, dark_col, 3);
    snprintf(items[n++].text, sizeof items[0].text, "below %g sigma", pm->threshold_sigma);

    int probe_w = rec_map_scale(pm->width, pm->height) * pm->width;
    if (probe_w < MAP_MIN_WIDTH) probe_w = MAP_MIN_WIDTH;
    int bar_h = pm->phases == REC_PHASES_CONTINUOUS ? 16 + 22 : 0;
    int legend_h = LEGEND_TOP + TITLE_H + bar_h + legend_rows(probe_w, items, n) * ROW_H + 8;
    canvas c;
    int s;
    gs_status st = canvas_new(&c, pm, legend_h, &s);
    if (st != GS_OK) return st;
    vscale vs;
    st = vscale_make(pm, &vs);
    for (int y = 0; y < pm->height && st == GS_OK; y++)
        for (int x = 0; x < pm->width; x++) {
            size_t p = (size_t)y * (size_t)pm->width + (size_t)x;
            unsigned char col[3];
            double v = vscale_at(&vs, pm->snr[p]);
            if (pm->state[p] == REC_PIX_SATURATED) memcpy(col, white_col, 3);
            else if (pm->state[p] == REC_PIX_MATCHED && pm->confidence[p] >= pm->ambiguous_conf)
                hsv_rgb(pm->phase_deg[p], 1.0, v, col);
            else if (pm->state[p] == REC_PIX_MATCHED || pm->state[p] == REC_PIX_NO_ANSWER)
                hsv_rgb(0.0, 0.0, 0.5 * v, col);   /* ambiguous or no answer */
            else continue;
            map_px(&c, s, x, y, col);
        }
    int y0 = s * pm->height + LEGEND_TOP;
    if (st == GS_OK)
        st = add_label(&c, 12, y0 + 10, 3.8, "grid phase per pixel (Eq. 7; hue = phase, brightness = signal)%s",
                       pm->phases == REC_PHASES_CONTINUOUS ? ", continuous" : "");
    y0 += TITLE_H;
    if (st == GS_OK && pm->phases == REC_PHASES_CONTINUOUS) {
        int bw = c.w - 24 < 720 ? c.w - 24 : 720;
        for (int i = 0; i < bw; i++) {
            unsigned char col[3];
            hsv_rgb(360.0 * i / bw, 1.0, 1.0, col);
            fill_rect(&c, 12 + i, y0, 1, 16, col);
        }
        for (int t = 0; t <= 360 && st == GS_OK; t += 60) {
            int xt = 12 + (int)lround((double)bw * t / 360.0);
            fill_rect(&c, xt, y0 + 16, 1, 4, ink);
            st = add_label(&c, xt - (t ? (t == 360 ? 0 : 10) : 0), y0 + 28, TEXT_MM, "%d" REC_DEG, t);
            if (st == GS_OK && t == 360) c.labels[c.nlabels - 1].just = 1.0;
        }
        y0 += bar_h;
    }
    if (st == GS_OK) st = draw_items(&c, y0, items, n);
    if (st == GS_OK) st = canvas_write(&c, path);
    canvas_free(&c);
    return st;
}

/* ------------------------------------------------------------ bulb map */

size_t rec_bulb_legend(const size_t *px, size_t nb, size_t *listed, int *colour, size_t *other_bulbs,
                       size_t *other_px)
{
    size_t total = 0, n = 0;
    for (size_t b = 0; b < nb; b++) {
        total += px[b];
        colour[b] = px[b] ? REC_BULB_OTHER_COLOUR : -1;
    }
    while (n < REC_BULB_LEGEND_MAX) {   /* the commonest unlisted bulb, while it has its share */
        size_t best = nb;
        for (size_t b = 0; b < nb; b++)
            if (colour[b] == REC_BULB_OTHER_COLOUR && (best == nb || px[b] > px[best])) best = b;
        if (best == nb || (double)px[best] < REC_BULB_LEGEND_SHARE * (double)total) break;
        colour[best] = (int)n;
        listed[n++] = best;
    }
    *other_bulbs = *other_px = 0;
    for (size_t b = 0; b < nb; b++)
        if (colour[b] == REC_BULB_OTHER_COLOUR) {
            (*other_bulbs)++;
            *other_px += px[b];
        }
    return n;
}

gs_status rec_map_write_bulb_png(const rec_pixel_maps *pm, const rec_matcher *m, const char *path)
{
    if (!pm || !pm->state || !m || !path) return gs_fail(GS_EINVAL, "bulb map: no maps, matcher or path");
    size_t nb = rec_matcher_bulb_count(m), np = (size_t)pm->width * (size_t)pm->height;
    size_t *px = calloc(nb ? nb : 1, sizeof *px), listed[REC_BULB_LEGEND_MAX];
    int *colour = calloc(nb ? nb : 1, sizeof *colour);
    key_item items[REC_BULB_LEGEND_MAX + 4];   /* the bulbs, other and three states */
    if (!px || !colour) {
        free(px);
        free(colour);
        return gs_fail(GS_ENOMEM, "bulb map: cannot allocate the legend");
    }
    for (size_t p = 0; p < np; p++)   /* the confident pixels: the coloured ones */
        if (pm->state[p] == REC_PIX_MATCHED && pm->confidence[p] >= pm->ambiguous_conf && pm->bulb[p] >= 0 &&
            (size_t)pm->bulb[p] < nb)
            px[pm->bulb[p]]++;
    size_t other_bulbs, other_px, n = 0, nl = rec_bulb_legend(px, nb, listed, colour, &other_bulbs, &other_px);
    for (size_t i = 0; i < nl; i++) {
        const gs_bulb *b = rec_matcher_bulb(m, listed[i]);
        memcpy(items[n].rgb, rec_bulb_palette[colour[listed[i]]], 3);
        snprintf(items[n++].text, sizeof items[0].text, "%s (%s), %zu px", b->id, gs_tech_name(b->type),
                 px[listed[i]]);
    }
    if (other_bulbs) {
        memcpy(items[n].rgb, rec_bulb_palette[REC_BULB_OTHER_COLOUR], 3);
        snprintf(items[n++].text, sizeof items[0].text, "other (%zu bulb%s, %zu px)", other_bulbs,
                 other_bulbs == 1 ? "" : "s", other_px);
    }
    memcpy(items[n].rgb, grey_col, 3);
    snprintf(items[n++].text, sizeof items[0].text, "ambiguous (conf. < %.2g), unknown, dim or bad input",
             pm->ambiguous_conf);
    memcpy(items[n].rgb, white_col, 3);
    snprintf(items[n++].text, sizeof items[0].text, "saturated");
    memcpy(items[n].rgb, dark_col, 3);
    snprintf(items[n++].text, sizeof items[0].text, "below %g sigma", pm->threshold_sigma);

    int probe_w = rec_map_scale(pm->width, pm->height) * pm->width;
    if (probe_w < MAP_MIN_WIDTH) probe_w = MAP_MIN_WIDTH;
    int legend_h = LEGEND_TOP + TITLE_H + legend_rows(probe_w, items, n) * ROW_H + 8;
    canvas c;
    int s;
    gs_status st = canvas_new(&c, pm, legend_h, &s);
    vscale vs;
    if (st == GS_OK) st = vscale_make(pm, &vs);
    for (int y = 0; y < pm->height && st == GS_OK; y++)
        for (int x = 0; x < pm->width; x++) {
            size_t p = (size_t)y * (size_t)pm->width + (size_t)x;
            unsigned char col[3];
            double v = vscale_at(&vs, pm->snr[p]);
            if (pm->state[p] == REC_PIX_SATURATED) memcpy(col, white_col, 3);
            else if (pm->state[p] == REC_PIX_MATCHED && pm->confidence[p] >= pm->ambiguous_conf)
                for (int k = 0; k < 3; k++) col[k] = (unsigned char)lround(v * rec_bulb_palette[colour[pm->bulb[p]]][k]);
            else if (pm->state[p] == REC_PIX_MATCHED || pm->state[p] == REC_PIX_NO_ANSWER)
                hsv_rgb(0.0, 0.0, 0.5 * v, col);   /* ambiguous or no answer */
            else continue;
            map_px(&c, s, x, y, col);
        }
    int y0 = s * pm->height + LEGEND_TOP;
    if (st == GS_OK)
        st = add_label(&c, 12, y0 + 10, 3.8, "bulb per pixel (Eq. 7 over DELIGHT; brightness = signal)");
    if (st == GS_OK) st = draw_items(&c, y0 + TITLE_H, items, n);
    if (st == GS_OK) st = canvas_write(&c, path);
    if (c.rgb) canvas_free(&c);
    free(px);
    free(colour);
    return st;
}

/* ------------------------------------------------------------ confidence map */

gs_status rec_map_write_confidence_png(const rec_pixel_maps *pm, const char *path)
{
    if (!pm || !pm->state || !path) return gs_fail(GS_EINVAL, "confidence map: no maps or no path");
    key_item items[3];
    memcpy(items[0].rgb, grey_col, 3);
    snprintf(items[0].text, sizeof items[0].text, "unknown, dim or bad input");
    memcpy(items[1].rgb, white_col, 3);
    snprintf(items[1].text, sizeof items[1].text, "saturated");
    memcpy(items[2].rgb, dark_col, 3);
    snprintf(items[2].text, sizeof items[2].text, "below %g sigma", pm->threshold_sigma);
    int bar_h = 16 + 22;
    int probe_w = rec_map_scale(pm->width, pm->height) * pm->width;
    if (probe_w < MAP_MIN_WIDTH) probe_w = MAP_MIN_WIDTH;
    int legend_h = LEGEND_TOP + TITLE_H + bar_h + legend_rows(probe_w, items, 3) * ROW_H + 8;
    canvas c;
    int s;
    gs_status st = canvas_new(&c, pm, legend_h, &s);
    if (st != GS_OK) return st;
    for (int y = 0; y < pm->height; y++)
        for (int x = 0; x < pm->width; x++) {
            size_t p = (size_t)y * (size_t)pm->width + (size_t)x;
            unsigned char col[3];
            if (pm->state[p] == REC_PIX_SATURATED) memcpy(col, white_col, 3);
            else if (pm->state[p] == REC_PIX_MATCHED) conf_rgb(pm->confidence[p], col);
            else if (pm->state[p] == REC_PIX_NO_ANSWER) memcpy(col, grey_col, 3);
            else continue;
            map_px(&c, s, x, y, col);
        }
    int y0 = s * pm->height + LEGEND_TOP;
    st = add_label(&c, 12, y0 + 10, 3.8, "posterior of the best (bulb, phase) pair per pixel (Eq. 7)");
    y0 += TITLE_H;
    int bw = c.w - 24 < 600 ? c.w - 24 : 600;
    for (int i = 0; i < bw; i++) {
        unsigned char col[3];
        conf_rgb((double)i / (bw - 1), col);
        fill_rect(&c, 12 + i, y0, 1, 16, col);
    }
    for (int t = 0; t <= 4 && st == GS_OK; t++) {
        int xt = 12 + (int)lround((double)(bw - 1) * t / 4.0);
        fill_rect(&c, xt, y0 + 16, 1, 4, ink);
        st = add_label(&c, xt - (t && t < 4 ? 12 : 0), y0 + 28, TEXT_MM, "%.2f", t / 4.0);
        if (st == GS_OK && t == 4) c.labels[c.nlabels - 1].just = 1.0;
    }
    y0 += bar_h;
    if (st == GS_OK) st = draw_items(&c, y0, items, 3);
    if (st == GS_OK) st = canvas_write(&c, path);
    canvas_free(&c);
    return st;
}

