/* plot.c - plots drawn with PLplot's cairo PNG driver: BRFs like the paper's Fig. 2 (bottom
 * right: each bulb's BRF over one flicker cycle, one panel per band) and per-light signals like
 * its Fig. 3 (normalised measured signals with their best-matching templates, and the same
 * signals shifted onto grid phase 0). */
#include "recognize/internal.h"

#include <math.h>
#include <string.h>

#include <plplot.h>
#include <stdio.h>
#include <stdlib.h>

/* A qualitative palette (Okabe-Ito, then other distinct hues) on PLplot's colour map 0. */
static const unsigned char palette[][3] = {
    {0, 0, 0},     {230, 159, 0}, {86, 180, 233}, {0, 158, 115}, {170, 150, 0}, {0, 114, 178},
    {213, 94, 0},  {204, 121, 167}, {120, 120, 120}, {80, 40, 120}, {150, 210, 0}, {0, 90, 60},
    {140, 40, 90}, {90, 90, 200},   {200, 60, 60},  {60, 160, 60},
};
#define PALETTE_N ((int)(sizeof palette / sizeof *palette))

/* 5 % of the span beyond both ends, so values at the ends are drawn inside the frame */
static void pad_range(double *ymin, double *ymax)
{
    double pad = 0.05 * (*ymax - *ymin);
    *ymin -= pad;
    *ymax += pad;
}

static const char *band_label(int bands, int band)
{
    static const char *const rgb[3] = {"red band", "green band", "blue band"};
    return bands == 1 ? "monochrome" : rgb[band];
}

/* What the BRF plot's drawing needs; x, y: scratch of the longest BRF + 1 points. */
typedef struct {
    const gs_bulb *const *bulbs;
    size_t count;
    const char *file;   /* PLplot writes it by name */
    const char *title;
    int bands;
    double ymin, ymax;
    double *x, *y;
} brf_plot;

/* The BRF plot (in a child process: gs_isolated). */
static gs_status draw_brfs(void *ctx, unsigned char *unused)
{
    (void)unused;
    const brf_plot *bp = ctx;
    const gs_bulb *const *bulbs = bp->bulbs;
    size_t count = bp->count;
    int bands = bp->bands;
    double ymin = bp->ymin, ymax = bp->ymax, *x = bp->x, *y = bp->y;
    const char *title = bp->title;
    plsdev("pngcairo");
    plsfnam(bp->file);
    plsetopt("geometry", bands == 1 ? "1100x700" : "1100x1400");
    plscmap0n(PALETTE_N + 1);
    plscol0(0, 255, 255, 255); /* background */
    for (int c = 0; c < PALETTE_N; c++) plscol0(c + 1, palette[c][0], palette[c][1], palette[c][2]);
    plsexit(gs_isolated_exit);   /* plexit: its reason the last line, the child ended */
    plstar(1, bands);
    const char *labels[PALETTE_N];   /* count < PALETTE_N (rec_plot_brfs) */
    PLINT opts[PALETTE_N], colors[PALETTE_N], styles[PALETTE_N];
    PLFLT widths[PALETTE_N];
    char text[PALETTE_N][160];
    for (int band = 0; band < bands; band++) {
        pladv(0);
        plvpor(0.11, 0.60, 0.12, 0.88);
        plwind(0.0, 1.0, ymin, ymax);
        plcol0(1);
        plwidth(1.0);
        plbox("bcnstg", 0.1, 0, "bcnstvg", 0, 0);
        char top[256];
        snprintf(top, sizeof top, "%s (%s)", title, band_label(bands, band));
        pllab("time in the flicker cycle, t / #gD", "BRF (mean 1)", top);
        for (size_t i = 0; i < count; i++) {
            const gs_brf *b = &bulbs[i]->brf;
            for (int j = 0; j <= b->n; j++) {   /* close the cycle: sample n is sample 0 */
                x[j] = (double)j / b->n;
                y[j] = b->v[(size_t)band * (size_t)b->n + (size_t)(j % b->n)];
            }
            int c = (int)i % (PALETTE_N - 1) + 2;
            plcol0(c);
            plwidth(2.0);
            plline(b->n + 1, x, y);
            snprintf(text[i], sizeof text[i], "%s (%s, %d Hz)", bulbs[i]->id,
                     gs_tech_name(bulbs[i]->type), bulbs[i]->grid_hz);
            labels[i] = text[i];
            opts[i] = PL_LEGEND_LINE;
            colors[i] = c;
            styles[i] = 1;
            widths[i] = 2.0;
        }
        PLFLT lw, lh;
        pllegend(&lw, &lh, PL_LEGEND_BACKGROUND | PL_LEGEND_BOUNDING_BOX,
                 PL_POSITION_RIGHT | PL_POSITION_OUTSIDE, 0.02, 0.0, 0.05, 0, 1,
                 1, (PLINT)count, 1, (PLINT)count, opts, 0.8, 0.6, 2.0, 0.0, colors,
                 (const char *const *)labels, NULL, NULL, NULL, NULL, colors, styles, widths, NULL,
                 NULL, NULL, NULL);
    }
    plend();
    return GS_OK;
}

gs_status rec_plot_brfs(const gs_bulb *const *bulbs, size_t count, const char *png_path,
                        const char *title)
{
    if (count == 0) return gs_fail(GS_EINVAL, "plot: no bulbs to plot");
    if (count > (size_t)PALETTE_N - 1)
        return gs_fail(GS_ELIMIT, "plot: %zu bulbs: at most %d fit one legible plot", count, PALETTE_N - 1);
    int bands = bulbs[0]->brf.bands;
    for (size_t i = 1; i < count; i++)
        if (bulbs[i]->brf.bands != bands)
            return gs_fail(GS_EINVAL, "plot: bulb %s has %d bands, %s has %d: expected the same",
                           bulbs[i]->id, bulbs[i]->brf.bands, bulbs[0]->id, bands);
    gs_atomic out;   /* PLplot writes by name (and exits the process on open failures) */
    gs_status ost = gs_atomic_open(&out, png_path, 0);
    if (ost != GS_OK) return ost;

    /* y: 0 (a dark sample) to at least 1.5, 5 % of the span beyond both, so a sample at 0 or
     * at the maximum is drawn inside the frame, not on it */
    double ymin = 0.0, ymax = 1.5;
    int nmax = 0;
    for (size_t i = 0; i < count; i++) {
        const gs_brf *b = &bulbs[i]->brf;
        for (int j = 0; j < b->n * b->bands; j++) {
            if (b->v[j] < ymin) ymin = b->v[j];
            if (b->v[j] > ymax) ymax = b->v[j];
        }
        if (b->n > nmax) nmax = b->n;
    }
    pad_range(&ymin, &ymax);
    double *x = malloc(sizeof *x * (size_t)(nmax + 1)), *y = malloc(sizeof *y * (size_t)(nmax + 1));
    if (!x || !y) {
        free(x);
        free(y);
        gs_atomic_abort(&out);
        return gs_fail(GS_ENOMEM, "plot: cannot allocate %d points", nmax);
    }

    brf_plot bp = {bulbs, count, out.tmp, title, bands, ymin, ymax, x, y};
    gs_status st = gs_isolated(png_path, NULL, 0, draw_brfs, &bp);
    free(x);
    free(y);
    if (st == GS_OK) return gs_atomic_commit(&out);
    gs_atomic_abort(&out);
    return st;
}

/* ------------------------------------------------------------ signal plots (Fig. 3) */

#define CURVE_N 200
#define MAX_SIGNAL_LIGHTS 16
_Static_assert(MAX_SIGNAL_LIGHTS <= PALETTE_N, "a colour per drawn bulb");

gs_status rec_plot_template(const gs_bulb *b, const rec_match *mt, double shift, int K, int band,
                            const double *u, size_t n, double *c, double complex *C)
{
    int nb = b->brf.n;
    gs_status st = gs_brf_spectrum(b->brf.v + (size_t)band * (size_t)nb, nb, C);
    if (st != GS_OK) return st;
    const double pi = 3.14159265358979323846;
    for (int h = 1; h < nb / 2; h++) {
        double a = pi * h / K;
        C[h] *= 2.0 * sin(a) / a;
    }
    for (size_t j = 0; j < n; j++) {
        double turns = fmod(u[j] - shift, 1.0);
        double complex z = cexp(I * 2.0 * pi * turns), zh = 1.0;
        double acc = creal(C[0]);
        for (int h = 1; h < nb / 2; h++) {
            zh *= z;
            acc += creal(C[h] * zh);
        }
        c[j] = (mt->band_flat[band] + mt->band_brightness[band] * acc / nb) / mt->brightness;
    }
    return GS_OK;
}

typedef struct {
    size_t light, count;   /* count: its bulb's eligible lights */
    int bulb, phase;       /* phase: 1 when known */
    double snr;
} light_rank;

/* By bulb (most lights first, then index), then best first (a known phase, then SNR). */
static int cmp_rank(const void *a, const void *b)
{
    const light_rank *x = a, *y = b;
    if (x->count != y->count) return x->count < y->count ? 1 : -1;
    if (x->bulb != y->bulb) return x->bulb < y->bulb ? -1 : 1;
    if (x->phase != y->phase) return x->phase < y->phase ? 1 : -1;
    if (x->snr != y->snr) return x->snr < y->snr ? 1 : -1;
    return x->light < y->light ? -1 : x->light > y->light;
}

static int cmp_pick(const void *a, const void *b)
{
    const rec_signal_pick *x = a, *y = b;
    return x->colour != y->colour ? x->colour - y->colour : x->symbol - y->symbol;
}

gs_status rec_signal_lights(const rec_matcher *m, const rec_catalog *cat, const rec_match *match,
                            size_t max, rec_signal_pick *pick, size_t *n)
{
    *n = 0;
    size_t nb = rec_matcher_bulb_count(m), na = 0, D = (size_t)cat->bands * (size_t)cat->K;
    light_rank *all = calloc(cat->count ? cat->count : 1, sizeof *all);
    size_t *count = calloc(nb ? nb : 1, sizeof *count);
    if (!all || !count) {
        free(all);
        free(count);
        return gs_fail(GS_ENOMEM, "signal plot: cannot rank %zu lights", cat->count);
    }
    for (size_t i = 0; i < cat->count; i++) {
        const rec_match *mt = &match[i];
        if (mt->bulb < 0 || (size_t)mt->bulb >= nb || (mt->flags & REC_MATCH_BULB_AMBIGUOUS) ||
            !(mt->brightness > 0.0))
            continue;
        double s = 0.0, v = 0.0;
        for (size_t d = 0; d < D; d++) {
            s += cat->signal[i * D + d];
            v += cat->sigma[i * D + d] * cat->sigma[i * D + d];
        }
        if (!(v > 0.0) || !isfinite(v)) continue;
        all[na] = (light_rank){i, 0, mt->bulb, rec_match_phase_known(m, mt), s / sqrt(v)};
        count[mt->bulb]++;
        na++;
    }
    for (size_t i = 0; i < na; i++) all[i].count = count[all[i].bulb];
    qsort(all, na, sizeof *all, cmp_rank);
    /* each bulb's lights are a run of all: the runs' r-th lights, round by round */
    size_t runs = 0;
    for (size_t i = 0; i < na; i++) runs += i == 0 || all[i].bulb != all[i - 1].bulb;
    if (runs > max) runs = max;
    for (int r = 0; r < REC_SIGNAL_SYMBOLS && *n < max; r++) {
        size_t start = 0;
        for (size_t g = 0; g < runs && *n < max; g++) {
            if ((size_t)r < all[start].count)
                pick[(*n)++] = (rec_signal_pick){all[start + (size_t)r].light, (int)g, r};
            start += all[start].count;
        }
    }
    qsort(pick, *n, sizeof *pick, cmp_pick);
    free(all);
    free(count);
    return GS_OK;
}

static const char *const symbols[REC_SIGNAL_SYMBOLS] = {
    "\xe2\x97\x8f", "\xe2\x96\xa0", "\xe2\x96\xb2", "\xe2\x97\x86",
    "\xe2\x96\xbc", "\xe2\x98\x85", "\xe2\x9c\x9a", "\xe2\x9c\x96"};

/* What the signal plot's drawing needs: the lights (pick[0..nl)), the y range, and scratch
 * curves (u: the curves' times, cv, tmp: rec_plot_template's; px, py, lo, hi: K points). */
typedef struct {
    const rec_matcher *m;
    const rec_catalog *cat;
    const rec_match *match;
    const rec_signal_pick *pick;
    size_t nl;
    int K, bands;
    size_t D;
    const char *title, *file;   /* PLplot writes file by name */
    double ymin, ymax;
    double *u, *cv;
    double complex *tmp;
    double *px, *py, *lo, *hi;
} signal_plot;

/* The signal plot (in a child process: gs_isolated). */
/* 1 when rec_match_catalog used frame k of cat: locked, or free running and not left out
 * (rec_frame_kept at m's threshold). */
static int frame_used(const rec_matcher *m, const rec_catalog *cat, int k)
{
    return !cat->drift_windows ||
           rec_frame_kept(cat->drift_windows[k], rec_drift_limit(m->o.max_drift_windows, cat->window_period));
}

static gs_status draw_signals(void *ctx, unsigned char *unused)
{
    (void)unused;
    const signal_plot *sp = ctx;
    const rec_matcher *m = sp->m;
    const rec_catalog *cat = sp->cat;
    const rec_match *match = sp->match;
    const rec_signal_pick *pick = sp->pick;
    size_t nl = sp->nl, D = sp->D;
    int K = sp->K, bands = sp->bands;
    const char *title = sp->title;
    double ymin = sp->ymin, ymax = sp->ymax, *u = sp->u, *cv = sp->cv, *px = sp->px, *py = sp->py, *lo = sp->lo,
           *hi = sp->hi;
    double complex *tmp = sp->tmp;
    gs_status st = GS_OK;
    plsdev("pngcairo");
    plsfnam(sp->file);
    char geom[32];
    snprintf(geom, sizeof geom, "1500x%d", bands == 1 ? 620 : 1500);
    plsetopt("geometry", geom);
    plscmap0n(PALETTE_N + 2);
    plscol0(0, 255, 255, 255);
    plscol0(1, 0, 0, 0);
    for (int c = 0; c < PALETTE_N; c++)   /* colour c: the palette from its second entry, black last */
        plscol0(c + 2, palette[(c + 1) % PALETTE_N][0], palette[(c + 1) % PALETTE_N][1],
                palette[(c + 1) % PALETTE_N][2]);
    plsexit(gs_isolated_exit);   /* plexit: its reason the last line, the child ended */
    plinit();
    pladv(0);
    static const char *const band_name[3] = {"red band", "green band", "blue band"};
    double top = 0.93, bottom = 0.05, gap = 0.09;
    double row_h = (top - bottom - gap * (bands - 1)) / bands;
    const char *labels[MAX_SIGNAL_LIGHTS], *syms[MAX_SIGNAL_LIGHTS];
    char text[MAX_SIGNAL_LIGHTS][120];
    PLINT opts[MAX_SIGNAL_LIGHTS], colors[MAX_SIGNAL_LIGHTS], styles[MAX_SIGNAL_LIGHTS];
    PLFLT widths[MAX_SIGNAL_LIGHTS], scales[MAX_SIGNAL_LIGHTS];
    PLINT numbers[MAX_SIGNAL_LIGHTS];
    for (int band = 0; band < bands && st == GS_OK; band++) {
        double y1 = top - band * (row_h + gap), y0 = y1 - row_h;
        for (int panel = 0; panel < 2 && st == GS_OK; panel++) {
            plvpor(panel ? 0.435 : 0.07, panel ? 0.73 : 0.37, y0, y1);
            plwind(0.0, 1.0, ymin, ymax);
            plcol0(1);
            plwidth(1.0);
            plschr(0, 0.6);
            plbox("bcnstg", 0.2, 2, "bcnstvg", 0, 0);
            char lab[300];
            const char *bn = bands == 1 ? "monochrome" : band_name[band];
            if (panel == 0)
                snprintf(lab, sizeof lab, "%s: measured/brightness and the fit", bn);
            else
                snprintf(lab, sizeof lab, "%s: shifted to grid phase 0", bn);
            /* (the right panel shares the left's y axis: a label of its own would sit on the
             * gap's tick labels) */
            pllab("time in the flicker cycle, t / #gD", panel == 0 ? "normalised signal" : "", lab);
            if (band == 0 && panel == 0 && title && *title) {
                plschr(0, 0.75);
                plmtex("t", 3.2, 0.0, 0.0, title);
                plschr(0, 0.6);
            }
            for (size_t l = 0; l < nl && st == GS_OK; l++) {
                size_t i = pick[l].light;
                const rec_match *mt = &match[i];
                const gs_bulb *b = rec_matcher_bulb(m, (size_t)mt->bulb);
                int phase_known = rec_match_phase_known(m, mt);
                double sh = gs_phase_to_shift(mt->phase_deg);
                if (panel == 1 && !phase_known) continue;
                /* the template (panel 0: at the light's phase; panel 1: at phase 0) */
                st = rec_plot_template(b, mt, panel ? 0.0 : sh, K, band, u, CURVE_N, cv, tmp);
                if (st != GS_OK) break;
                plcol0(pick[l].colour + 2);
                plwidth(panel ? 1.0 : 2.0);
                plline(CURVE_N, u, cv);
                /* the measured samples at the window centres (panel 1: minus the shift), of the
                 * frames the match used */
                double a = mt->brightness;
                int n = 0;
                for (int k = 0; k < K; k++) {
                    if (!frame_used(m, cat, k)) continue;
                    double t = (k + 0.5) / K - (panel ? sh : 0.0);
                    t -= floor(t);
                    size_t d = i * D + (size_t)band * (size_t)K + (size_t)k;
                    px[n] = t;
                    py[n] = cat->signal[d] / a;
                    lo[n] = (cat->signal[d] - cat->sigma[d]) / a;
                    hi[n] = (cat->signal[d] + cat->sigma[d]) / a;
                    n++;
                }
                plwidth(1.0);
                plerry(n, px, lo, hi);
                plschr(0, 0.45);
                plstring(n, px, py, symbols[pick[l].symbol]);
                plschr(0, 0.6);
            }
        }
        if (st != GS_OK) break;
        /* legend, right of the first row */
        if (band == 0) {
            for (size_t l = 0; l < nl; l++) {
                const rec_match *mt = &match[pick[l].light];
                const gs_bulb *b = rec_matcher_bulb(m, (size_t)mt->bulb);
                if (rec_match_phase_known(m, mt))
                    snprintf(text[l], sizeof text[l], "light %zu: %s, %.0f" REC_DEG, pick[l].light, b->id,
                             mt->phase_deg);
                else
                    snprintf(text[l], sizeof text[l], "light %zu: %s, phase ?", pick[l].light, b->id);
                labels[l] = text[l];
                syms[l] = symbols[pick[l].symbol];
                opts[l] = PL_LEGEND_LINE | PL_LEGEND_SYMBOL;
                colors[l] = pick[l].colour + 2;
                styles[l] = 1;
                widths[l] = 2.0;
                scales[l] = 0.5;
                numbers[l] = 2;
            }
            plvpor(0.755, 0.998, y0, y1);   /* (clear of the right panel's last tick label) */
            plwind(0.0, 1.0, 0.0, 1.0);
            if (nl) {
                PLFLT lw, lh;
                pllegend(&lw, &lh, PL_LEGEND_BACKGROUND | PL_LEGEND_BOUNDING_BOX,
                         PL_POSITION_LEFT | PL_POSITION_INSIDE | PL_POSITION_TOP, 0.0, 0.0,
                         0.05, 0, 1, 1, (PLINT)nl, 1, (PLINT)nl, opts, 0.6, 0.4, 2.0, 0.0, colors,
                         (const char *const *)labels, NULL, NULL, NULL, NULL, colors, styles,
                         widths, colors, scales, numbers, (const char *const *)syms);
            } else {
                plcol0(1);
                plschr(0, 0.8);
                plptex(0.5, 0.9, 1.0, 0.0, 0.5, "no recognised light");
            }
        }
    }
    plend();
    return st;
}

gs_status rec_plot_signals(const rec_matcher *m, const rec_catalog *cat, const rec_match *match,
                           int max_lights, const char *png_path, const char *title)
{
    if (!m || !cat || (cat->count && !match) || !png_path)
        return gs_fail(GS_EINVAL, "signal plot: expected a matcher, a catalog, its matches and a path");
    if (max_lights < 1 || max_lights > MAX_SIGNAL_LIGHTS)
        return gs_fail(GS_EINVAL, "signal plot: max_lights %d: expected 1 to %d", max_lights,
                       MAX_SIGNAL_LIGHTS);
    const gs_bulb *first = rec_matcher_bulb(m, 0);
    int K = cat->K, bands = cat->bands;
    if (cat->count && (!first || first->brf.bands != bands))
        return gs_fail(GS_EINVAL, "signal plot: the catalog has %d bands, the matcher %d", bands,
                       first ? first->brf.bands : 0);
    if (bands < 1 || bands > GS_MAX_BANDS) bands = first ? first->brf.bands : 1;
    if (K < 2) K = 2;
    size_t D = (size_t)bands * (size_t)K, nl = 0;
    rec_signal_pick pick[MAX_SIGNAL_LIGHTS];
    gs_status pst = rec_signal_lights(m, cat, match, (size_t)max_lights, pick, &nl);
    if (pst != GS_OK) return pst;

    gs_atomic out;   /* PLplot writes by name (and exits the process on open failures) */
    gs_status ost = gs_atomic_open(&out, png_path, 0);
    if (ost != GS_OK) return ost;

    double *u = malloc(sizeof *u * CURVE_N), *cv = malloc(sizeof *cv * CURVE_N);
    int nmax = 4;
    for (size_t i = 0; i < rec_matcher_bulb_count(m); i++)
        if (rec_matcher_bulb(m, i)->brf.n > nmax) nmax = rec_matcher_bulb(m, i)->brf.n;
    double complex *tmp = malloc(sizeof *tmp * (size_t)(nmax / 2 + 1));
    double *px = malloc(sizeof *px * (size_t)(K + 1)), *py = malloc(sizeof *py * (size_t)(K + 1));
    double *lo = malloc(sizeof *lo * (size_t)K), *hi = malloc(sizeof *hi * (size_t)K);
    if (!u || !cv || !tmp || !px || !py || !lo || !hi) {
        free(u); free(cv); free(tmp); free(px); free(py); free(lo); free(hi);
        gs_atomic_abort(&out);
        return gs_fail(GS_ENOMEM, "signal plot: cannot allocate curves");
    }
    for (int j = 0; j < CURVE_N; j++) u[j] = (double)j / (CURVE_N - 1);
    /* y range over every drawn value: the error bars' ends (below 0 for a dim sample), the
     * templates, 0 */
    double ymin = 0.0, ymax = 0.0;
    for (size_t l = 0; l < nl; l++) {
        size_t i = pick[l].light;
        double a = match[i].brightness;
        for (size_t d = 0; d < D; d++) {
            if (!frame_used(m, cat, (int)(d % (size_t)K))) continue;
            double lo_y = (cat->signal[i * D + d] - cat->sigma[i * D + d]) / a,
                   hi_y = (cat->signal[i * D + d] + cat->sigma[i * D + d]) / a;
            if (lo_y < ymin) ymin = lo_y;
            if (hi_y > ymax) ymax = hi_y;
        }
    }
    gs_status st = GS_OK;
    for (size_t l = 0; l < nl && st == GS_OK; l++) {
        const gs_bulb *b = rec_matcher_bulb(m, (size_t)match[pick[l].light].bulb);
        for (int band = 0; band < bands && st == GS_OK; band++) {
            st = rec_plot_template(b, &match[pick[l].light], 0.0, K, band, u, CURVE_N, cv, tmp);
            for (int j = 0; j < CURVE_N && st == GS_OK; j++) {
                if (cv[j] < ymin) ymin = cv[j];
                if (cv[j] > ymax) ymax = cv[j];
            }
        }
    }
    if (bands == 3 && ymax < 0.6) ymax = 0.6;
    if (bands == 1 && ymax < 1.5) ymax = 1.5;
    pad_range(&ymin, &ymax);

    signal_plot sp = {m, cat, match, pick, nl, K, bands, D, title, out.tmp, ymin, ymax, u, cv, tmp,
                      px, py, lo, hi};
    if (st == GS_OK) st = gs_isolated(png_path, NULL, 0, draw_signals, &sp);
    free(u); free(cv); free(tmp); free(px); free(py); free(lo); free(hi);
    if (st == GS_OK) return gs_atomic_commit(&out);
    gs_atomic_abort(&out);
    return st;
}
