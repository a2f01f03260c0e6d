/* test_bench_accuracy.c - `gridsurvey bench accuracy --quick` (survey/bench_accuracy.c): the
 * sweep runs and its numbers are consistent; its plots read back (points at 0 and 1 inside the
 * frame, rate axes from the data, legends of the drawn curves). No timing asserts. */
#include "tests/fixtures.h"
#include "tests/recognize_fixture.h"
#include "tests/test.h"
#include "recognize/recognize.h"
#include "survey/internal.h"

#include <math.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct {
    char scene[32], phases[16];
    int K, C, hdr, locked;
    long acq;
    double exposure, readout, capture, compute;
    double rates[8];   /* detection, false, bulb, phase, right, unknown, pipeline subset, oracle */
    double snr, ece, phase_ece;
    long oracle_n, truth_lights, phase_answered;
    double cal_num[2], cal_den[2];   /* from calibration.csv: sum |right - confidence|, lights */
    double bin_lights[2], bin_right[2];   /* ... and the sums of its bins' lights and right ones */
} row;

static int file_size_ok(const char *path, const char *magic)
{
    FILE *f = fopen(path, "rb");
    if (!f) return 0;
    char b[8] = {0};
    size_t n = fread(b, 1, sizeof b, f);
    fclose(f);
    return n >= strlen(magic) && !memcmp(b, magic, strlen(magic));
}

static double num(const char *s)
{
    return strcmp(s, "nan") ? atof(s) : NAN;
}

#define CSV_FIELDS 33   /* accuracy.csv's */

/* The CSV file OUT/name (`bench accuracy --out-dir OUT`), its header read into line (NULL:
 * missing, which fails the test). */
static FILE *csv_open(const char *out, const char *name, char *line, size_t size)
{
    char path[2200];
    snprintf(path, sizeof path, "%s/%s", out, name);
    FILE *f = fopen(path, "r");
    CHECK_MSG(f != NULL, "%s: missing", path);
    line[0] = '\0';
    if (f) CHECK_MSG(fgets(line, (int)size, f) != NULL, "%s: empty", path);
    return f;
}

/* The next row of f split at its commas into fld; a row of other than nf fields (at most
 * CSV_FIELDS) fails the test and is skipped. 0 at the end. */
static int csv_row(FILE *f, char *line, size_t size, char *fld[CSV_FIELDS], int nf)
{
    while (fgets(line, (int)size, f)) {
        char *all[CSV_FIELDS + 8];
        int got = 0;
        for (char *t = strtok(line, ",\n"); t && got < CSV_FIELDS + 8; t = strtok(NULL, ",\n")) all[got++] = t;
        CHECK_MSG(got == nf, "CSV row with %d fields, not %d", got, nf);
        if (got != nf) continue;
        memcpy(fld, all, sizeof *fld * (size_t)nf);
        return 1;
    }
    return 0;
}

TEST(bench_accuracy_quick_consistent)
{
    char out[2048], cmd[4096], log[8192];
    snprintf(out, sizeof out, "%s/acc", test_tmpdir());
    snprintf(cmd, sizeof cmd, "%s bench accuracy --quick --out-dir %s", test_bin(), out);
    int rc = test_run(cmd, log, sizeof log);
    CHECK_MSG(rc == 0, "%s -> %d:\n%s", cmd, rc, log);
    char path[2200];
    snprintf(path, sizeof path, "%s/accuracy_vs_time.png", out);
    CHECK_MSG(file_size_ok(path, "\x89PNG"), "%s: not a PNG", path);
    snprintf(path, sizeof path, "%s/calibration.png", out);
    CHECK_MSG(file_size_ok(path, "\x89PNG"), "%s: not a PNG", path);
    snprintf(path, sizeof path, "%s.md", out);
    CHECK_MSG(file_size_ok(path, "# What"), "%s: no report", path);
    char line[4096], *fld[CSV_FIELDS];
    FILE *f = csv_open(out, "accuracy.csv", line, sizeof line);
    if (!f) return;
    row rows[32];
    int n = 0;
    CHECK(!strncmp(line, "scene,K,C,", 10));
    int free_rows = 0;
    while (n < 32 && csv_row(f, line, sizeof line, fld, CSV_FIELDS)) {
        row *r = &rows[n++];
        snprintf(r->scene, sizeof r->scene, "%s", fld[0]);
        r->K = atoi(fld[1]);
        r->C = atoi(fld[2]);
        r->hdr = atoi(fld[3]);
        r->locked = atoi(fld[4]);
        snprintf(r->phases, sizeof r->phases, "%s", fld[5]);
        r->acq = atol(fld[6]);
        r->exposure = num(fld[7]);
        r->readout = num(fld[8]);
        r->capture = num(fld[9]);
        r->compute = num(fld[10]);
        int ri[8] = {14, 15, 16, 17, 18, 19, 25, 26};
        for (int k = 0; k < 8; k++) r->rates[k] = num(fld[ri[k]]);
        r->snr = num(fld[22]);
        r->ece = num(fld[23]);
        r->oracle_n = atol(fld[24]);
        r->phase_ece = num(fld[27]);
        r->phase_answered = atol(fld[28]);
        /* a locked capture's windows do not drift: every frame kept; the free-running point's
         * (K = 8, C = 1024) drift more than half a window in some frame, which Eq. 7's default
         * (auto) keeps: the period was measured */
        if (r->locked) CHECK(num(fld[29]) == 0.0 && atoi(fld[30]) == r->K);
        else CHECK(num(fld[29]) > 0.5 && atoi(fld[30]) == r->K);
        /* (free running as the firmware does it, Eq. 7's default threshold) */
        CHECK(!strcmp(fld[31], r->locked ? "locked" : "measured") && !strcmp(fld[32], "auto"));
        free_rows += !r->locked;
        r->truth_lights = atol(fld[11]);
        r->bin_lights[0] = r->bin_lights[1] = r->bin_right[0] = r->bin_right[1] = 0;
        r->cal_num[0] = r->cal_num[1] = r->cal_den[0] = r->cal_den[1] = 0;
    }
    fclose(f);
    CHECK(free_rows == 1);
    snprintf(path, sizeof path, "%s.md", out);
    char *md = fx_read_file(path, NULL);
    CHECK(md && strstr(md, "| metro | 8 | 1024 | on | free: "));
    free(md);
    /* every point's reliability bins: in range, a stored phase only at or above the ambiguity
     * threshold, and the ECE columns recomputed from them */
    rec_eq7_opts eo;
    rec_eq7_opts_default(&eo);
    f = csv_open(out, "calibration.csv", line, sizeof line);
    if (!f) return;
    CHECK(!strcmp(line, "scene,K,C,hdr,locked,phases,confidence_of,bin_lo,bin_hi,matched_lights,mean_confidence,"
                        "right_lights\n"));
    int bins = 0;
    while (csv_row(f, line, sizeof line, fld, 12)) {
        int phase = !strcmp(fld[6], "phase");
        double lo = num(fld[7]), hi = num(fld[8]), lights = num(fld[9]), mean = num(fld[10]), right = num(fld[11]);
        CHECK_MSG(lights >= 1 && right >= 0 && right <= lights && mean >= lo && mean <= hi,
                  "%s K=%s C=%s %s bin [%g, %g]: %g lights, mean %g, %g right", fld[0], fld[1], fld[2], fld[6], lo,
                  hi, lights, mean, right);
        if (phase) CHECK_MSG(lo >= eo.ambiguous_conf - 1e-9, "a stored phase in the bin [%g, %g)", lo, hi);
        bins++;
        for (int i = 0; i < n; i++) {
            row *r = &rows[i];
            if (strcmp(r->scene, fld[0]) || r->K != atoi(fld[1]) || r->C != atoi(fld[2]) || r->hdr != atoi(fld[3]) ||
                r->locked != atoi(fld[4]) || strcmp(r->phases, fld[5]))
                continue;
            r->cal_num[phase] += fabs(right - mean * lights);
            r->cal_den[phase] += lights;
            r->bin_lights[phase] += lights;
            r->bin_right[phase] += right;
        }
    }
    fclose(f);
    CHECK(bins >= n);
    for (int i = 0; i < n; i++) {
        row *r = &rows[i];
        double ece[2] = {r->ece, r->phase_ece};
        for (int k = 0; k < 2; k++)
            if (r->cal_den[k] > 0) CHECK_NEAR(ece[k], r->cal_num[k] / r->cal_den[k], 2e-4);
            else CHECK(isnan(ece[k]));
        /* the bins partition the answers the whole capture's evaluation scored (each bin is
         * scored on its own: its one-to-one matching may differ by a light): the phase bins
         * hold its phases and their right ones (phase accuracy x phases), the pair bins its
         * right bulb and phase (right/all x truth lights) */
        double tol = 1.0;   /* (a light: the quick points' sums are exact) */
        CHECK_MSG(fabs(r->bin_lights[1] - (double)r->phase_answered) <= tol &&
                      fabs(r->bin_right[1] - r->rates[3] * (double)r->phase_answered) <= tol &&
                      fabs(r->bin_right[0] - r->rates[4] * (double)r->truth_lights) <= tol,
                  "%s K=%d C=%d: phase bins %g lights, %g right (capture: %ld phases, %.0f right); pair bins "
                  "%g right (capture %.0f)", r->scene, r->K, r->C, r->bin_lights[1], r->bin_right[1],
                  r->phase_answered, r->rates[3] * (double)r->phase_answered, r->bin_right[0],
                  r->rates[4] * (double)r->truth_lights);
    }
    CHECK_MSG(n >= 4, "%d rows", n);
    const double delta = 0.01, readout_cycles = 10;   /* 50 Hz; the scene's readout_cycles */
    for (int i = 0; i < n; i++) {
        row *r = &rows[i];
        /* rates in [0, 1] (NaN: no denominator) */
        for (int k = 0; k < 8; k++)
            CHECK_MSG(isnan(r->rates[k]) || (r->rates[k] >= 0 && r->rates[k] <= 1), "%s C=%d: rate %d = %g",
                      r->scene, r->C, k, r->rates[k]);
        CHECK(isnan(r->ece) || (r->ece >= 0 && r->ece <= 1));
        CHECK(r->rates[0] > 0.5);   /* the window's lights are found */
        /* capture time: A (C + R) Delta exactly, A = K frames + HDR repeats */
        CHECK_MSG(r->acq >= r->K && (r->hdr || r->acq == r->K), "%s C=%d: %ld acquisitions for K = %d",
                  r->scene, r->C, r->acq, r->K);
        CHECK_NEAR(r->exposure, (double)r->acq * r->C * delta, 0.006);
        CHECK_NEAR(r->readout, (double)r->acq * readout_cycles * delta, 0.006);
        CHECK_NEAR(r->capture, r->exposure + r->readout, 0.011);
        CHECK_NEAR(r->capture, (double)r->acq * (r->C + readout_cycles) * delta, 0.006);
        CHECK(r->compute >= 0);
        /* the oracle is at least as good as the pipeline on the same lights (8 lights: a
         * tolerance of 2 lights) */
        if (r->oracle_n > 0)
            CHECK_MSG(r->rates[7] >= r->rates[6] - 2.0 / (double)r->oracle_n - 1e-9,
                      "%s C=%d: oracle %.3f, pipeline %.3f", r->scene, r->C, r->rates[7], r->rates[6]);
        /* more cycles never reduce the SNR (same scene and setting) */
        for (int j = 0; j < n; j++) {
            row *q = &rows[j];
            if (strcmp(q->scene, r->scene) || strcmp(q->phases, r->phases) || q->K != r->K || q->hdr != r->hdr ||
                q->locked != r->locked || q->C <= r->C)
                continue;
            CHECK_MSG(q->snr >= r->snr, "%s K=%d: SNR %.1f at C=%d, %.1f at C=%d", r->scene, r->K, r->snr, r->C,
                      q->snr, q->C);
        }
    }
}

/* `bench accuracy --drift-sweep --quick`: one free-running capture per period (measured before
 * each exposure, nominal) recognised at Eq. 7's thresholds 0.25 and none. The same capture for
 * both thresholds (simulated once: the second threshold's work directory (--keep) has none of
 * its own; the same drift); none keeps every frame, 0.25 leaves out some (the largest drift is
 * beyond it); the nominal period drifts further than the measured one; the page lists every
 * point. */
TEST(bench_accuracy_drift_sweep_quick)
{
    char out[2048], cmd[4096], log[8192];
    snprintf(out, sizeof out, "%s/drift", test_tmpdir());
    snprintf(cmd, sizeof cmd, "mkdir -p %s/work && TMPDIR=%s/work %s bench accuracy --drift-sweep --quick --keep --out-dir %s",
             test_tmpdir(), test_tmpdir(), test_bin(), out);
    int rc = test_run(cmd, log, sizeof log);
    CHECK_MSG(rc == 0, "%s -> %d:\n%s", cmd, rc, log);
    for (int nominal = 0; nominal < 2; nominal++) {
        const char *p = nominal ? "free-nominal" : "free";
        snprintf(cmd, sizeof cmd, "cd %s/work/gs-accuracy-* && test -f metro_clear-K8-C1024-hdr-%s-ph3-0.25/capture/capture.json "
                 "&& test -f metro_clear-K8-C1024-hdr-%s-ph3-none/survey.sqlite && test ! -e metro_clear-K8-C1024-hdr-%s-ph3-none/capture",
                 test_tmpdir(), p, p, p);
        rc = test_run(cmd, log, sizeof log);
        CHECK_MSG(rc == 0, "%s: the second threshold simulated its own capture, or the first none:\n%s", p, log);
    }
    char path[2200], line[4096], *fld[CSV_FIELDS];
    FILE *f = csv_open(out, "accuracy.csv", line, sizeof line);
    if (!f) return;
    CHECK(strstr(line, ",drift_windows,frames_kept,free_period,max_drift_windows\n"));
    double drift[2][2] = {{NAN, NAN}, {NAN, NAN}}, unknown[2][2] = {{NAN, NAN}, {NAN, NAN}};   /* [nominal][none] */
    int kept[2][2] = {{-1, -1}, {-1, -1}}, n = 0;
    while (csv_row(f, line, sizeof line, fld, CSV_FIELDS)) {
        CHECK(!strcmp(fld[0], "metro_clear") && atoi(fld[1]) == 8 && atoi(fld[2]) == 1024 && atoi(fld[4]) == 0);
        int nominal = !strcmp(fld[31], "nominal"), none = !strcmp(fld[32], "none");
        CHECK(nominal || !strcmp(fld[31], "measured"));
        CHECK(none || num(fld[32]) == 0.25);
        drift[nominal][none] = num(fld[29]);
        kept[nominal][none] = atoi(fld[30]);
        unknown[nominal][none] = num(fld[19]);
        n++;
    }
    fclose(f);
    CHECK(n == 4);
    for (int nominal = 0; nominal < 2; nominal++) {
        CHECK_MSG(drift[nominal][0] == drift[nominal][1] && drift[nominal][0] > 0.25,
                  "period %d: drift %g and %g", nominal, drift[nominal][0], drift[nominal][1]);
        CHECK_MSG(kept[nominal][1] == 8 && kept[nominal][0] >= 0 && kept[nominal][0] < 8,
                  "period %d: %d frames kept at 0.25, %d at none", nominal, kept[nominal][0], kept[nominal][1]);
    }
    CHECK(drift[1][0] > drift[0][0]);
    /* the threshold reaches the pipeline's Eq. 7: with the nominal period's one frame or none
     * kept at 0.25, more lights go unknown than with every frame kept */
    CHECK_MSG(unknown[1][0] > unknown[1][1], "nominal: unknown %g at 0.25, %g at none", unknown[1][0], unknown[1][1]);
    snprintf(path, sizeof path, "%s.md", out);
    char *md = fx_read_file(path, NULL);
    CHECK(md && strstr(md, "| measured | 8 | 1024 | 0.25 | ") && strstr(md, "| measured | 8 | 1024 | none | 8 of 8 (") &&
          strstr(md, "| nominal | 8 | 1024 | 0.25 | ") && strstr(md, "| nominal | 8 | 1024 | none | 8 of 8 ("));
    free(md);
}

/* ------------------------------------------------ the plots, read back (Python, PIL + NumPy) */


/* A main-grid point of scene hard whose right rate, detection rate and oracle are all y, with
 * every light in its top confidence bin (both kinds). */
static srv_acc_point plot_point(int hard, int K, int C, double y)
{
    srv_acc_point p;
    memset(&p, 0, sizeof p);
    p.hard = hard;
    p.K = K;
    p.C = C;
    p.hdr = p.locked = p.ok = 1;
    p.capture_s = 0.01 * K * C;
    p.ev.matched = 100;
    p.ev.all_correct = lround(100 * y);
    p.ev.detection_rate = y;
    p.oracle_sub = y;
    p.cal.n[NBINS - 1] = p.phase_cal.n[NBINS - 1] = 100;
    p.cal.conf[NBINS - 1] = p.phase_cal.conf[NBINS - 1] = 100 * y;
    p.cal.right[NBINS - 1] = p.phase_cal.right[NBINS - 1] = lround(100 * y);
    return p;
}

/* Pixels of colour r,g,b (within 8 per channel) in the picture's cell (col, prow) of a cols x rows
 * grid of panels, within its fractions [x0, x1) x [y0, y1); -1 when the reader fails. */
static long colour_in(const char *png, int cols, int rows, int col, int prow, double x0, double x1,
                      double y0, double y1, int r, int g, int b)
{
    char cmd[2048], out[256];
    snprintf(cmd, sizeof cmd,
             "/usr/bin/python3 -c \"import numpy as np; from PIL import Image\n"
             "im = np.asarray(Image.open('%s').convert('RGB')).astype(int)\n"
             "h, w = im.shape[0] // %d, im.shape[1] // %d\n"
             "c = im[%d * h:%d * h, %d * w:%d * w]\n"
             "c = c[int(%g * h):int(%g * h), int(%g * w):int(%g * w)]\n"
             "print('px', int((np.abs(c - (%d, %d, %d)).max(axis=2) <= 8).sum()))\"",
             png, rows, cols, prow, prow + 1, col, col + 1, y0, y1, x0, x1, r, g, b);
    if (test_run(cmd, out, sizeof out) != 0) return -1;
    const char *p = strstr(out, "px ");
    return p ? atol(p + 3) : -1;
}

static long colour_px(const char *png, int cols, int rows, int col, int prow, int r, int g, int b)
{
    return colour_in(png, cols, rows, col, prow, 0, 1, 0, 1, r, g, b);
}

TEST(bench_accuracy_plots_show_perfect_points_and_only_drawn_curves)
{
    static const int Ks[2] = {8, 13};
    char at1[1100], at09[1100], cal1[1100], cal09[1100];
    snprintf(at1, sizeof at1, "%s/acc1.png", test_tmpdir());
    snprintf(at09, sizeof at09, "%s/acc09.png", test_tmpdir());
    snprintf(cal1, sizeof cal1, "%s/cal1.png", test_tmpdir());
    snprintf(cal09, sizeof cal09, "%s/cal09.png", test_tmpdir());
    /* metro at K = 8 only; the same curves at 1 (a perfect run) and at 0.9 */
    srv_acc_point p1[3] = {plot_point(0, 8, 32, 1.0), plot_point(0, 8, 64, 1.0), plot_point(2, 8, 64, 1.0)};
    srv_acc_point p09[3] = {plot_point(0, 8, 32, 0.9), plot_point(0, 8, 64, 0.9), plot_point(2, 8, 64, 0.9)};
    srv_acc_plot_accuracy(at1, p1, 3, Ks, 2);
    srv_acc_plot_accuracy(at09, p09, 3, Ks, 2);
    srv_acc_plot_calibration(cal1, p1, 2);
    srv_acc_plot_calibration(cal09, p09, 2);
    /* a curve at 1 (the top of the scale) shows as much of itself as the same curve at 0.9:
     * neither hidden under the frame nor clipped by it (K = 8's blue; calibration: metro's) */
    for (int panel = 0; panel < 2; panel++) {
        /* (the curves' part of the panel: the accuracy legends are at the bottom, the
         * calibration legends on the left) */
        long n1 = colour_in(at1, 2, 3, panel, 0, 0, 1, 0, 0.5, 31, 119, 180),
             n09 = colour_in(at09, 2, 3, panel, 0, 0, 1, 0, 0.5, 31, 119, 180);
        CHECK_MSG(n1 > 0 && n1 >= 0.9 * n09, "accuracy panel %d: %ld blue px at 1, %ld at 0.9", panel, n1, n09);
        /* metro_clear's single point: a marker */
        n1 = colour_in(at1, 2, 3, panel, 2, 0, 1, 0, 0.5, 31, 119, 180);
        n09 = colour_in(at09, 2, 3, panel, 2, 0, 1, 0, 0.5, 31, 119, 180);
        CHECK_MSG(n1 > 0 && n1 >= 0.9 * n09, "accuracy panel %d, one point: %ld blue px at 1, %ld at 0.9", panel,
                  n1, n09);
        n1 = colour_in(cal1, 2, 1, panel, 0, 0.6, 1, 0, 1, 31, 119, 180);
        n09 = colour_in(cal09, 2, 1, panel, 0, 0.6, 1, 0, 1, 31, 119, 180);
        CHECK_MSG(n1 > 0 && n1 >= 0.9 * n09, "calibration panel %d: %ld blue px at 1, %ld at 0.9", panel, n1, n09);
    }
    /* the legends name only what is drawn: no K = 13 (orange) anywhere, and the scene without
     * points (metro_hard) has no K = 8 entry either; calibration: no metro_hard (red) */
    for (int prow = 0; prow < 3; prow++)
        for (int panel = 0; panel < 2; panel++) {
            CHECK_MSG(colour_px(at1, 2, 3, panel, prow, 255, 127, 14) == 0, "row %d panel %d: K = 13 named", prow,
                      panel);
            if (prow == 1) {
                long n = colour_px(at1, 2, 3, panel, prow, 31, 119, 180);
                CHECK_MSG(n == 0, "row %d panel %d: %ld px of K = 8 without its points", prow, panel, n);
            }
        }
    for (int panel = 0; panel < 2; panel++) {
        CHECK(colour_px(cal1, 2, 1, panel, 0, 214, 39, 40) == 0);
    }
}

/* The calibration titles fit their panels: no ink in the title band at the panels' outer
 * columns (the middle of the picture, its right edge), where a clipped title is cut. */
TEST(bench_accuracy_calibration_titles_fit)
{
    char png[1100], cmd[2048], out[256];
    snprintf(png, sizeof png, "%s/cal_titles.png", test_tmpdir());
    srv_acc_point p = plot_point(0, 8, 32, 0.9);
    srv_acc_plot_calibration(png, &p, 1);
    snprintf(cmd, sizeof cmd,
             "/usr/bin/python3 -c \"import numpy as np; from PIL import Image\n"
             "im = np.asarray(Image.open('%s').convert('RGB')).astype(int)\n"
             "h, w = im.shape[:2]\n"
             "band = im[:int(0.08 * h)].sum(axis=2) < 384\n"
             "print('ink', int(band.any(axis=0).sum()), int(band[:, w // 2 - 6:w // 2 + 6].sum()), "
             "int(band[:, w - 6:].sum()), int(band[:, :6].sum()))\"",
             png);
    CHECK(test_run(cmd, out, sizeof out) == 0);
    long cols = 0, mid = -1, right = -1, left = -1;
    const char *q = strstr(out, "ink ");
    CHECK_MSG(q && sscanf(q, "ink %ld %ld %ld %ld", &cols, &mid, &right, &left) == 4, "%s", out);
    CHECK_MSG(cols > 200, "no title ink: %s", out);   /* the titles are there */
    CHECK_MSG(mid == 0 && right == 0 && left == 0, "title ink at a panel's edge (middle %ld, right %ld, left %ld)",
              mid, right, left);
}

/* The rate axis (srv_acc_rate_axis) covers every value and 1 with room inside the frame at both
 * ends, starts at 0 only when a value is below 0.5, and otherwise shows the data, not the empty
 * scale below them; its ticks are a few, on a 1-2-5 step. */
TEST(bench_accuracy_rate_axis_fits_the_data)
{
    static const double sets[][4] = {
        {0.75, 0.98, 1.0, 0.93}, {0.99, 0.995, 0.992, 0.99}, {1, 1, 1, 1},   {0.3, 1, 0.9, 0.8},
        {0.0, 0.5, 1, 1},        {0.51, 0.6, NAN, 0.7},       {0.7, 0.7, 0.7, 0.7}, {NAN, NAN, NAN, NAN}};
    for (size_t s = 0; s < sizeof sets / sizeof *sets; s++) {
        double vmin = INFINITY, lo, hi, tick;
        for (int i = 0; i < 4; i++) vmin = fmin(vmin, sets[s][i]);   /* (fmin skips a NaN) */
        srv_acc_rate_axis(sets[s], 4, &lo, &hi, &tick);
        if (isinf(vmin)) vmin = 0.0;   /* no value: the whole scale */
        double span = hi - lo, room = 0.02 * span;   /* a few pixels of the panel's ~320 */
        CHECK_MSG(lo < vmin - room && hi > 1.0 + room, "set %zu: [%g, %g] over %g..1", s, lo, hi, vmin);
        if (vmin > 0.5)
            CHECK_MSG(lo > 0.4 && 1.0 - vmin >= 0.25 * (hi - lo) - 0.03,
                      "set %zu: [%g, %g]: the data (%g..1) squeezed", s, lo, hi, vmin);
        else
            CHECK_MSG(lo < 0.0 && lo > -0.1, "set %zu: [%g, %g]: 0 not in view", s, lo, hi);
        double ticks = span / tick;
        CHECK_MSG(ticks >= 4 && ticks <= 12 && (fabs(tick - 0.2) < 1e-12 || fabs(tick - 0.1) < 1e-12 ||
                                                 fabs(tick - 0.05) < 1e-12 || fabs(tick - 0.02) < 1e-12),
                  "set %zu: [%g, %g] ticked every %g", s, lo, hi, tick);
    }
    double lo, hi, tick;   /* no value: the whole scale, as calibration's axes */
    srv_acc_rate_axis(NULL, 0, &lo, &hi, &tick);
    CHECK_MSG(lo < 0.0 && lo > -0.1 && hi > 1.0 && hi < 1.1, "[%g, %g]", lo, hi);
}

/* The frame's rows (the first and last inked across most of the panel) and the lowest row of
 * colour r,g,b among the panel's left half (the accuracy legends are at the right, the
 * calibration's at the left: right = 1 reads the right half) in cell (col, prow) of a cols x
 * rows picture; 0 when the picture cannot be read. */
static int frame_and_lowest(const char *png, int cols, int rows, int col, int prow, int right, int r, int g, int b,
                            int *top, int *bottom, int *lowest)
{
    int w = 0, h = 0;
    unsigned char *px = recfx_read_png(png, &w, &h);
    if (!px) return 0;
    int cw = w / cols, ch = h / rows, x0 = col * cw, y0 = prow * ch;
    *top = *bottom = *lowest = -1;
    for (int y = y0; y < y0 + ch; y++) {
        int ink = 0, mine = 0;
        for (int x = x0; x < x0 + cw; x++) {
            const unsigned char *p = px + 3 * ((size_t)y * (size_t)w + (size_t)x);
            ink += p[0] < 200 || p[1] < 200 || p[2] < 200;
            int half = x >= x0 + cw / 2;
            mine += half == right && abs(p[0] - r) <= 8 && abs(p[1] - g) <= 8 && abs(p[2] - b) <= 8;
        }
        if (ink > cw / 2) {
            if (*top < 0) *top = y - y0;
            *bottom = y - y0;
        }
        if (mine) *lowest = y - y0;
    }
    free(px);
    return 1;
}

/* The accuracy plot's rate axes come from the data: curves at 0.8 (accuracy and detection) are
 * drawn low in their panels, inside the frame, not squeezed against 1 over an empty scale; a
 * calibration bin none of whose lights is right (at 0) is inside the frame too. */
TEST(bench_accuracy_plots_axes_from_the_data)
{
    static const int Ks[1] = {8};
    char acc[1100], cal[1100];
    snprintf(acc, sizeof acc, "%s/acc08.png", test_tmpdir());
    snprintf(cal, sizeof cal, "%s/cal0.png", test_tmpdir());
    srv_acc_point p[2] = {plot_point(0, 8, 32, 0.8), plot_point(0, 8, 64, 0.8)};
    srv_acc_plot_accuracy(acc, p, 2, Ks, 1);
    for (int panel = 0; panel < 2; panel++) {
        int top, bottom, lowest;
        if (!frame_and_lowest(acc, 2, 3, panel, 0, 0, 31, 119, 180, &top, &bottom, &lowest)) return;
        CHECK_MSG(top >= 0 && bottom - top > 100 && lowest > 0, "panel %d: frame %d..%d, curve to %d", panel, top,
                  bottom, lowest);
        double up = (double)(bottom - lowest) / (bottom - top);   /* 0.8 over [0, 1.03]: 0.78 */
        CHECK_MSG(lowest < bottom - 2 && up < 0.25, "panel %d: 0.8 drawn at %.2f of the frame's height (row %d of %d..%d)",
                  panel, up, lowest, top, bottom);
    }
    p[0].cal.right[NBINS - 1] = 0;   /* metro's one bin: confidence 0.8, none right */
    srv_acc_plot_calibration(cal, p, 1);
    int top, bottom, lowest;
    if (!frame_and_lowest(cal, 2, 1, 0, 0, 1, 31, 119, 180, &top, &bottom, &lowest)) return;
    CHECK_MSG(top >= 0 && lowest > 0 && lowest < bottom - 2, "calibration: the bin at 0 reaches row %d, frame %d..%d",
              lowest, top, bottom);
}
