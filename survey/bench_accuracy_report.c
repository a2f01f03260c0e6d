/* bench_accuracy_report.c - the report of `gridsurvey bench accuracy` (bench_accuracy.c runs the
 * points): DIR/accuracy.csv, the accuracy-vs-time and calibration plots, and the Markdown page
 * (docs/accuracy.md) with the numbers of the run. */
#define _XOPEN_SOURCE 700   /* nftw */
#include "survey/internal.h"
#include "capture/capture.h"

#include <cblas.h>
#include <errno.h>
#include <ftw.h>
#include <getopt.h>
#include <jansson.h>
#include <math.h>
#include <plplot.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>


/* ------------------------------------------------------------------ output */

const char *srv_acc_ph_name(const srv_acc_point *p)
{
    return p->continuous ? "continuous" : "3";
}

static void fmt_num(char *b, size_t n, double v, const char *f)
{
    if (isfinite(v)) snprintf(b, n, f, v);
    else snprintf(b, n, "-");
}

const char *srv_acc_period_name(const srv_acc_point *p)
{
    return p->locked ? "locked" : p->nominal_period ? "nominal" : "measured";
}

const char *srv_acc_threshold_name(const srv_acc_point *p, char *buf, size_t n)
{
    if (p->max_drift_windows == REC_DRIFT_AUTO) snprintf(buf, n, "auto");
    else if (isfinite(p->max_drift_windows)) snprintf(buf, n, "%g", p->max_drift_windows);
    else snprintf(buf, n, "none");
    return buf;
}

gs_status srv_acc_write_csv(const char *path, const srv_acc_point *pts, size_t np)
{
    FILE *f = fopen(path, "w");
    if (!f) return gs_fail(GS_EIO, "%s: cannot write: %s", path, strerror(errno));
    fprintf(f, "scene,K,C,hdr,locked,phases,acquisitions,exposure_s,readout_s,capture_s,compute_s,"
               "truth_lights,stored,matched,detection_rate,false_rate,bulb_accuracy,phase_accuracy,"
               "right_rate,bulb_unknown_rate,loc_median_m,loc_p95_m,snr_p90,ece,oracle_lights,"
               "pipeline_on_oracle_lights,oracle_accuracy,phase_ece,phase_answered,drift_windows,frames_kept,"
               "free_period,max_drift_windows\n");
    for (size_t i = 0; i < np; i++) {
        const srv_acc_point *p = &pts[i];
        char thr[32];
        if (!p->ok) continue;
        fprintf(f, "%s,%d,%d,%d,%d,%s,%ld,%.2f,%.2f,%.2f,%.3f,%ld,%ld,%ld,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,"
                   "%.2f,%.2f,%.2f,%.4f,%ld,%.4f,%.4f,%.4f,%ld,%.4f,%d,%s,%s\n",
                srv_acc_scene_names[p->hard], p->K, p->C, p->hdr, p->locked, srv_acc_ph_name(p), p->acquisitions,
                p->exposure_s, p->readout_s, p->capture_s, p->compute_s, p->ev.truth_in_image, p->ev.stored,
                p->ev.matched, p->ev.detection_rate, p->ev.false_rate, p->ev.bulb_accuracy,
                p->ev.phase_accuracy, p->ev.all_correct_rate, p->ev.bulb_unknown_rate, p->ev.loc_median_m,
                p->ev.loc_p95_m, p->snr_p90, p->cal.ece, p->oracle_n, p->ours_sub, p->oracle_sub, p->phase_cal.ece,
                p->ev.phase_answered, p->drift_windows, p->frames_kept, srv_acc_period_name(p),
                srv_acc_threshold_name(p, thr, sizeof thr));
    }
    int bad = ferror(f);
    if (fclose(f) != 0 || bad) return gs_fail(GS_EIO, "%s: write failed", path);
    return GS_OK;
}

gs_status srv_acc_write_bins_csv(const char *path, const srv_acc_point *pts, size_t np)
{
    FILE *f = fopen(path, "w");
    if (!f) return gs_fail(GS_EIO, "%s: cannot write: %s", path, strerror(errno));
    fprintf(f, "scene,K,C,hdr,locked,phases,confidence_of,bin_lo,bin_hi,matched_lights,mean_confidence,"
               "right_lights\n");
    for (size_t i = 0; i < np; i++) {
        const srv_acc_point *p = &pts[i];
        if (!p->ok) continue;
        for (int kind = 0; kind < 2; kind++) {
            const srv_acc_bins *c = kind ? &p->phase_cal : &p->cal;
            for (int b = 0; b < NBINS; b++)
                if (c->n[b] > 0)
                    fprintf(f, "%s,%d,%d,%d,%d,%s,%s,%.2f,%.2f,%.0f,%.6f,%.0f\n", srv_acc_scene_names[p->hard], p->K,
                            p->C, p->hdr, p->locked, srv_acc_ph_name(p), kind ? "phase" : "bulb_and_phase",
                            srv_acc_bin_edges[b], fmin(srv_acc_bin_edges[b + 1], 1.0), c->n[b], c->conf[b] / c->n[b],
                            c->right[b]);
        }
    }
    int bad = ferror(f);
    if (fclose(f) != 0 || bad) return gs_fail(GS_EIO, "%s: write failed", path);
    return GS_OK;
}

/* A point of the main grid (HDR on, locked, phases 0/120/240), not a variant. */
static int main_grid(const srv_acc_point *p)
{
    return p->ok && p->hdr && p->locked && !p->continuous;
}

/* Scene hard's reliability bins pooled over its main grid: lights matched, their summed
 * confidence and how many are right, per bin; of the pair's confidence (phase = 0) or the
 * phase's (1). */
static void pooled_bins(const srv_acc_point *pts, size_t np, int hard, int phase, double n[NBINS], double c[NBINS],
                        double r[NBINS])
{
    for (int b = 0; b < NBINS; b++) n[b] = c[b] = r[b] = 0;
    for (size_t i = 0; i < np; i++) {
        const srv_acc_point *p = &pts[i];
        if (!main_grid(p) || p->hard != hard) continue;
        const srv_acc_bins *cal = phase ? &p->phase_cal : &p->cal;
        for (int b = 0; b < NBINS; b++) {
            n[b] += cal->n[b];
            c[b] += cal->conf[b];
            r[b] += cal->right[b];
        }
    }
}

void srv_acc_rate_axis(const double *v, size_t n, double *lo, double *hi, double *tick)
{
    double vmin = INFINITY;
    for (size_t i = 0; i < n; i++)
        if (v[i] < vmin) vmin = v[i];   /* (a NaN compares false: skipped) */
    double bottom = isfinite(vmin) ? floor(vmin * 10.0 + 1e-9) / 10.0 : 0.0;   /* (0.7 stays 0.7) */
    if (bottom < 0.5) bottom = 0.0;
    if (bottom > 0.9) bottom = 0.9;
    double span = 1.0 - bottom, pad = 0.03 * span;
    *lo = bottom - pad;
    *hi = 1.0 + pad;
    static const double steps[] = {0.2, 0.1, 0.05, 0.02};
    *tick = steps[3];
    for (int i = 0; i < 3; i++)
        if (span / steps[i] > 3.999) {
            *tick = steps[i];
            break;
        }
}

/* The accuracy figure: per scene, right bulb and phase among detected lights (solid: the
 * pipeline; dashed: the oracle on its subset) and the detection rate, against capture seconds
 * (log), one curve per K. Curves use the main grid (HDR, locked, 3 phases). */
static const int kcolor[3] = {2, 3, 4};
#define CURVE_MAX 64

/* The points of scene hard's curve at K in the accuracy figure's panel (0: right of detected,
 * 1: detection rate): the pipeline's (xs, ys: log10 capture s, rate; *m of them) and, panel 0,
 * the oracle's (xo, yo; *mo). */
static void curve_points(const srv_acc_point *pts, size_t np, int hard, int panel, int K, double *xs, double *ys,
                         int *m, double *xo, double *yo, int *mo)
{
    *m = *mo = 0;
    for (size_t i = 0; i < np && *m < CURVE_MAX && *mo < CURVE_MAX; i++) {
        const srv_acc_point *p = &pts[i];
        if (!main_grid(p) || p->hard != hard || p->K != K) continue;
        double acc = p->ev.matched ? (double)p->ev.all_correct / (double)p->ev.matched : NAN;
        double y = panel ? p->ev.detection_rate : acc;
        if (isfinite(y)) {
            xs[*m] = log10(p->capture_s);
            ys[(*m)++] = y;
        }
        if (!panel && isfinite(p->oracle_sub)) {
            xo[*mo] = log10(p->capture_s);
            yo[(*mo)++] = p->oracle_sub;
        }
    }
}

void srv_acc_plot_accuracy(const char *path, const srv_acc_point *pts, size_t np, const int *Ks, int nK)
{
    plsdev("pngcairo");
    plsfnam(path);
    plsetopt("geometry", "1200x1300");
    plscmap0n(8);
    plscol0(0, 255, 255, 255);
    plscol0(1, 0, 0, 0);
    plscol0(2, 31, 119, 180);
    plscol0(3, 255, 127, 14);
    plscol0(4, 44, 160, 44);
    plscol0(5, 150, 150, 150);
    plstar(2, 3);
    double tmin = INFINITY, tmax = 0;
    for (size_t i = 0; i < np; i++)
        if (pts[i].ok) {
            tmin = fmin(tmin, pts[i].capture_s);
            tmax = fmax(tmax, pts[i].capture_s);
        }
    if (!(tmax > 0)) {
        tmin = 1;
        tmax = 10;
    }
    double lx0 = floor(log10(tmin)) - 0.05, lx1 = ceil(log10(tmax)) + 0.05;
    /* each column's rate axis, shared by its scenes, over every value it draws */
    double ylo[2], yhi[2], ytick[2];
    for (int panel = 0; panel < 2; panel++) {
        double ymin = INFINITY, xs[CURVE_MAX], ys[CURVE_MAX], xo[CURVE_MAX], yo[CURVE_MAX];
        for (int hard = 0; hard < 3; hard++)
            for (int ki = 0; ki < nK; ki++) {
                int m, mo;
                curve_points(pts, np, hard, panel, Ks[ki], xs, ys, &m, xo, yo, &mo);
                for (int j = 0; j < m; j++) ymin = fmin(ymin, ys[j]);
                for (int j = 0; mo > 1 && j < mo; j++) ymin = fmin(ymin, yo[j]);   /* (drawn: a line) */
            }
        srv_acc_rate_axis(&ymin, 1, &ylo[panel], &yhi[panel], &ytick[panel]);
    }
    for (int hard = 0; hard < 3; hard++)
        for (int panel = 0; panel < 2; panel++) {
            pladv(0);
            plvpor(0.16, 0.95, 0.14, 0.88);
            plwind(lx0, lx1, ylo[panel], yhi[panel]);
            plcol0(1);
            plwidth(1.0);
            plbox("bcnstlg", 0, 0, "bcnstvg", ytick[panel], 2);
            char top[128];
            snprintf(top, sizeof top, "%s: %s", srv_acc_scene_names[hard],
                     panel ? "detection rate" : "right bulb and phase (of detected)");
            pllab("capture time, s (ACam: A (C + R) #gD)", panel ? "detected / in image" : "accuracy", top);
            int drawn[3] = {0}, oracle_drawn = 0;   /* the legend names only these */
            for (int ki = 0; ki < nK; ki++) {
                double xs[CURVE_MAX], ys[CURVE_MAX], xo[CURVE_MAX], yo[CURVE_MAX];
                int m, mo;
                curve_points(pts, np, hard, panel, Ks[ki], xs, ys, &m, xo, yo, &mo);
                plcol0(kcolor[ki % 3]);
                plwidth(2.0);
                pllsty(1);
                if (m > 1) plline(m, xs, ys);
                if (m > 0) plpoin(m, xs, ys, 17);
                if (mo > 1) {
                    pllsty(2);
                    plline(mo, xo, yo);
                    pllsty(1);
                }
                if (ki < 3) drawn[ki] = m > 0;
                oracle_drawn |= mo > 1;
            }
            /* legend */
            const char *labels[4];
            char text[4][64];
            PLINT opts[4], colors[4], styles[4];
            PLFLT widths[4];
            int nl = 0;
            for (int ki = 0; ki < nK && nl < 3; ki++) {
                if (!drawn[ki]) continue;
                snprintf(text[nl], sizeof text[nl], "K = %d", Ks[ki]);
                labels[nl] = text[nl];
                opts[nl] = PL_LEGEND_LINE;
                colors[nl] = kcolor[ki % 3];
                styles[nl] = 1;
                widths[nl] = 2.0;
                nl++;
            }
            if (oracle_drawn) {
                snprintf(text[nl], sizeof text[nl], "ML oracle (dashed)");
                labels[nl] = text[nl];
                opts[nl] = PL_LEGEND_LINE;
                colors[nl] = 1;
                styles[nl] = 2;
                widths[nl] = 2.0;
                nl++;
            }
            PLFLT lw, lh;
            plcol0(1);
            if (nl)
                pllegend(&lw, &lh, PL_LEGEND_BACKGROUND | PL_LEGEND_BOUNDING_BOX,
                         PL_POSITION_BOTTOM | PL_POSITION_RIGHT | PL_POSITION_INSIDE, 0.02, 0.03, 0.1, 0, 1, 1, nl,
                         1, nl, opts, 0.8, 0.6, 2.0, 0.0, colors, (const char *const *)labels, NULL, NULL, NULL,
                         NULL, colors, styles, widths, NULL, NULL, NULL, NULL);
            else
                plptex(0.5 * (lx0 + lx1), 0.5 * (ylo[panel] + yhi[panel]), 1.0, 0.0, 0.5,
                       "no point of this scene in the sweep");
        }
    plend();
}

/* Calibration: per scene, accuracy of the stored lights against their reported confidence
 * (bins pooled over the scene's main grid: pooled_bins) with 95 % Wilson intervals, and the
 * diagonal; left the pair's confidence (right bulb and phase), right the phase's (right phase). */
void srv_acc_plot_calibration(const char *path, const srv_acc_point *pts, size_t np)
{
    plsdev("pngcairo");
    plsfnam(path);
    plsetopt("geometry", "1400x700");
    plscmap0n(8);
    plscol0(0, 255, 255, 255);
    plscol0(1, 0, 0, 0);
    plscol0(2, 31, 119, 180);
    plscol0(3, 214, 39, 40);
    plscol0(4, 44, 160, 44);
    plscol0(5, 150, 150, 150);
    plstar(2, 1);
    static const char *const ylab[2] = {"right bulb and phase", "right phase"},
                             *const title[2] = {"bulb and phase: lights with a bulb by confidence",
                                                "phase: lights with a phase by phase confidence"};
    for (int phase = 0; phase < 2; phase++) {
        pladv(phase + 1);
        plvpor(0.17, 0.93, 0.12, 0.90);
        /* x and y share the whole scale, so the diagonal is perfect calibration; bins span it */
        double a0, a1, tick;
        srv_acc_rate_axis(NULL, 0, &a0, &a1, &tick);
        plwind(a0, a1, a0, a1);
        plcol0(1);
        plbox("bcnstg", tick, 2, "bcnstvg", tick, 2);
        pllab("reported confidence (bin mean)", ylab[phase], "");
        plschr(0, 0.8);   /* the title fits its half of the picture */
        plmtex("t", 2.0, 0.5, 0.5, title[phase]);
        plschr(0, 1.0);
        double dx[2] = {0, 1}, dy[2] = {0, 1};
        plcol0(5);
        pllsty(2);
        plline(2, dx, dy);
        pllsty(1);
        const char *labels[3];
        PLINT opts[3], colors[3], styles[3];
        PLFLT widths[3], lw, lh;
        int nl = 0;   /* the legend names the scenes drawn */
        for (int hard = 0; hard < 3; hard++) {
            double n[NBINS], c[NBINS], r[NBINS];
            pooled_bins(pts, np, hard, phase, n, c, r);
            double xs[NBINS], ys[NBINS], lo[NBINS], hi[NBINS];
            int m = 0;
            for (int b = 0; b < NBINS; b++)
                if (n[b] > 0) {
                    xs[m] = c[b] / n[b];
                    ys[m] = srv_wilson(lround(r[b]), lround(n[b]), SRV_Z95, &lo[m], &hi[m]);
                    m++;
                }
            plcol0(2 + hard);
            plwidth(2.0);
            if (m > 1) plline(m, xs, ys);
            if (m > 0) {
                plpoin(m, xs, ys, 17);
                plwidth(1.0);
                plerry(m, xs, lo, hi);   /* a bin of few lights says little: its 95 % interval */
                labels[nl] = srv_acc_scene_names[hard];
                opts[nl] = PL_LEGEND_LINE;
                colors[nl] = 2 + hard;
                styles[nl] = 1;
                widths[nl++] = 2.0;
            }
        }
        plcol0(1);
        if (nl)
            pllegend(&lw, &lh, PL_LEGEND_BACKGROUND | PL_LEGEND_BOUNDING_BOX,
                     PL_POSITION_TOP | PL_POSITION_LEFT | PL_POSITION_INSIDE, 0.03, 0.03, 0.1, 0, 1, 1, nl, 1, nl,
                     opts, 0.8, 0.6, 2.0, 0.0, colors, labels, NULL, NULL, NULL, NULL, colors, styles, widths,
                     NULL, NULL, NULL, NULL);
        else
            plptex(0.5, 0.5, 1.0, 0.0, 0.5, "no answered light in the sweep");
    }
    plend();
}

static double right_of_detected(const srv_acc_point *p)
{
    return p->ev.matched ? (double)p->ev.all_correct / (double)p->ev.matched : NAN;
}

static const srv_acc_point *find_pt(const srv_acc_point *pts, size_t np, int hard, int K, int C)
{
    for (size_t i = 0; i < np; i++)
        if (main_grid(&pts[i]) && pts[i].hard == hard && pts[i].K == K && pts[i].C == C) return &pts[i];
    return NULL;
}

static void delta_line(FILE *f, const char *what, const srv_acc_point *a, const srv_acc_point *r)
{
    if (!a) {
        fprintf(f, "- **%s**: not in the sweep.\n", what);
        return;
    }
    fprintf(f, "- **%s** (C = %d, %.0f s): lights found right %.1f %% of those in the image (%+.1f points), "
               "right among detected %.1f %% (%+.1f), detected %.1f %% (%+.1f), location error median %.1f m / "
               "95th percentile %.1f m.\n",
            what, a->C, a->capture_s, 100 * a->ev.all_correct_rate, 100 * (a->ev.all_correct_rate - r->ev.all_correct_rate),
            100 * right_of_detected(a), 100 * (right_of_detected(a) - right_of_detected(r)), 100 * a->ev.detection_rate,
            100 * (a->ev.detection_rate - r->ev.detection_rate), a->ev.loc_median_m, a->ev.loc_p95_m);
}

gs_status srv_acc_write_doc(const char *path, const char *out, const char *base, const srv_acc_crop *cr, int quick,
                           const srv_acc_point *pts, size_t np, double wall, const int *Ks, int nK)
{
    FILE *f = fopen(path, "w");
    if (!f) return gs_fail(GS_EIO, "%s: cannot write: %s", path, strerror(errno));
    const char *leaf = strrchr(out, '/') ? strrchr(out, '/') + 1 : out;
    fprintf(f, "# What accuracy costs in time (`gridsurvey bench accuracy%s`)\n\n", quick ? " --quick" : "");
    fprintf(f, "Generated by `gridsurvey bench accuracy%s --out-dir %s` (survey/bench_accuracy.c), which "
               "wrote this file, `%s/accuracy.csv` and the plots. Reproduce:\n\n"
               "    make build/gridsurvey\n    build/gridsurvey bench accuracy --out-dir docs/accuracy    # also run by `make bench`\n\n"
               "Every number is deterministic given the scene's seed (the simulator, the pipeline and the "
               "oracle are), **except the compute times**, which are measured on the machine running it. "
               "This run took %.0f s of wall time.\n\n",
            quick ? " --quick" : "", out, leaf, wall);
    fprintf(f, "## What is swept\n\n"
               "Scene: `%s`, rendered through a %d x %d window of its %s image (pixels %d..%d x %d..%d: "
               "the same camera with the principal srv_acc_point moved, so the simulator only renders the lights "
               "in the window). **metro** is the scene as it is; **metro_hard** is the same with lower "
               "visibility (extinction at 8 km instead of 20 km), five times the turbulence (scintillation "
               "Cn2 = 1e-14 instead of 2e-15) and distractors that do not follow the mains (two blinking "
               "signs and a road of headlights inside the window); the variants are made by editing the parsed "
               "JSON in code (`write_scene`). Each point runs the survey pipeline exactly as `gridsurvey "
               "run` does (`srv_run`: the sim backend through the acquisition loop, blobs, Eq. 7, "
               "`gis_locate`, the survey database) and is scored by the pipeline's evaluation "
               "(`srv_evaluate`, one-to-one within 2 px against the simulator's truth.json).\n\n",
            base, cr->w, cr->h, "1600 x 900", cr->x0, cr->x0 + cr->w - 1, cr->y0, cr->y0 + cr->h - 1);
    fprintf(f, "Columns:\n\n"
               "- **capture s**: what this setting takes on an ACam, A (C + R) Delta: A acquisitions (K frames "
               "and their HDR repeats, counted by the acquisition loop), C cycles per frame, R = 10 readout "
               "cycles between acquisitions (the scene's `readout_cycles`), Delta = 1/(2 x 50 Hz) = 10 ms. "
               "The 64 cycles the controller needs to lock before the first frame are not counted.\n"
               "- **lock**: AC-locked, or free running (the windows timed with the half period measured "
               "before each exposure, as the firmware does, capture.json's `window_period` `measured`): "
               "the frames Eq. 7 kept of the K at its default threshold (`--max-drift-windows auto`: every "
               "frame of known drift for a measured period, else those whose windows moved at most %g "
               "windows across the flicker cycle during the exposure, `gs_capture_frame_drift`, "
               "capture.json's `window_drift_windows`; docs/recognition.md \"Free-running captures\"; "
               "docs/accuracy-drift.md measures other thresholds), and in parentheses the largest drift, "
               "in windows.\n"
               "- **compute s**: wall time of recognition and georeferencing (the pipeline's blobs, Eq. 7 "
               "and locate stages), measured, one core.\n"
               "- **det.**: detected lights / truth lights in the window; **false**: stored lights without a "
               "truth light within 2 px / stored.\n"
               "- **bulb**, **phase**: accuracy of the answers given (lights answered unknown or ambiguous "
               "are not counted; **unkn.** is the share of detected lights without a bulb); **right/det.**: "
               "detected lights with the right bulb and the right phase; **right/all**: the same over every "
               "truth light in the window (the survey's yield).\n"
               "- **loc. m**: location error of the detected lights (median / 95th percentile, metres, "
               "geodesic), `gis_locate` at the scene's light height.\n"
               "- **SNR90**: the 90th percentile of the detected lights' SNR (sum of signal / sqrt(sum of "
               "sigma^2)).\n"
               "- **ECE**: expected calibration error of the reported confidence (answered lights in the "
               "bins %s; each bin is stored as its own capture and scored by `srv_evaluate`); **phase ECE** "
               "the same of the phase confidence over the lights stored with a phase (what `stats "
               "--min-phase-confidence` filters on), right = the phase.\n"
               "- **oracle**: `rec_ml_oracle` (recognize/ml_oracle.c: the exact Poisson-Gaussian "
               "maximum-likelihood decision, brute force over every bulb at the six phases 0/120/240 and "
               "+30 deg, the truth's phase set) on the extracted signals of up to %d unflagged lights "
               "(no saturation, HDR, edge or deblending) per point, with the camera's noise model "
               "(gain x cycles electrons per DN/cycle, read and quantisation noise of the aperture's "
               "pixels, the background electrons from the extractor's sigma); *pipeline* is the "
               "pipeline's answers for the same lights (right bulb and phase / matched), *gap* the "
               "oracle's minus the pipeline's, in points. The oracle knows the scene's whole forward "
               "model (survey/bench_oracle.c): each light's extinction per band (its templates are "
               "reddened by the truth's `transmission`) and its scintillation (the truth's "
               "`scintillation_log_var` and `scintillation_rho` give each frame's relative flux "
               "variance over its C cycles; such frames are Gaussian with the Poisson-Gaussian "
               "variances plus that variance, common to the bands), so it is a ceiling when locked; free "
               "running, it leaves out the frames Eq. 7 leaves out and takes the others' windows as regular "
               "(Eq. 5) without raising their noise by their smear as Eq. 7 does: with drifted frames kept "
               "it is no ceiling (a negative gap).\n\n",
            REC_MAX_DRIFT_WINDOWS, "[0, 0.5), [0.5, 0.8), [0.8, 0.95), [0.95, 0.99), [0.99, 1]", quick ? 8 : 40);
    fprintf(f, "## Table\n\n");
    fprintf(f, "| scene | K | C | HDR | lock | phases | A | capture s | compute s | det. | false | bulb | phase | "
               "unkn. | right/det. | right/all | loc. m (med / p95) | SNR90 | ECE | phase ECE | oracle lights | pipeline | oracle | gap |\n");
    fprintf(f, "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for (size_t i = 0; i < np; i++) {
        const srv_acc_point *p = &pts[i];
        if (!p->ok) {
            fprintf(f, "| %s | %d | %d | %s | %s | %s | failed: %s |||||||||||||||||\n", srv_acc_scene_names[p->hard],
                    p->K, p->C, p->hdr ? "on" : "off", p->locked ? "locked" : "free", srv_acc_ph_name(p), p->err);
            continue;
        }
        char b[17][32];
        if (p->locked) snprintf(b[15], 32, "locked");
        else snprintf(b[15], 32, "free: %d of %d (%.2f)", p->frames_kept, p->K, p->drift_windows);
        fmt_num(b[0], 32, 100 * p->ev.detection_rate, "%.1f %%");
        fmt_num(b[1], 32, 100 * p->ev.false_rate, "%.1f %%");
        fmt_num(b[2], 32, 100 * p->ev.bulb_accuracy, "%.1f %%");
        fmt_num(b[3], 32, 100 * p->ev.phase_accuracy, "%.1f %%");
        fmt_num(b[4], 32, 100 * p->ev.bulb_unknown_rate, "%.1f %%");
        fmt_num(b[5], 32, 100 * right_of_detected(p), "%.1f %%");
        fmt_num(b[6], 32, 100 * p->ev.all_correct_rate, "%.1f %%");
        fmt_num(b[7], 32, p->ev.loc_median_m, "%.1f");
        fmt_num(b[8], 32, p->ev.loc_p95_m, "%.1f");
        fmt_num(b[9], 32, p->snr_p90, "%.0f");
        fmt_num(b[10], 32, p->cal.ece, "%.3f");
        fmt_num(b[14], 32, p->phase_cal.ece, "%.3f");
        fmt_num(b[11], 32, 100 * p->ours_sub, "%.1f %%");
        fmt_num(b[12], 32, 100 * p->oracle_sub, "%.1f %%");
        fmt_num(b[13], 32, 100 * (p->oracle_sub - p->ours_sub), "%+.1f");
        fprintf(f, "| %s | %d | %d | %s | %s | %s | %ld | %.1f | %.2f | %s | %s | %s | %s | %s | %s | %s | %s / %s | %s | %s | "
                   "%s | %ld | %s | %s | %s |\n",
                srv_acc_scene_names[p->hard], p->K, p->C, p->hdr ? "on" : "off", b[15],
                srv_acc_ph_name(p), p->acquisitions, p->capture_s, p->compute_s, b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7],
                b[8], b[9], b[10], b[14], p->oracle_n, b[11], b[12], b[13]);
    }
    long truth = 0;
    for (size_t i = 0; i < np; i++)
        if (pts[i].ok && !pts[i].hard) truth = pts[i].ev.truth_in_image;
    fprintf(f, "\n(%ld truth lights in the metro window.) The same numbers: [%s/accuracy.csv](%s/accuracy.csv).\n\n",
            truth, leaf, leaf);
    fprintf(f, "## Plots\n\n![accuracy against capture time](%s/accuracy_vs_time.png)\n\n"
               "Left: detected lights with the right bulb and phase (solid, the pipeline, every detected light) "
               "and the maximum-likelihood oracle on its subset (dashed); right: detection rate. One curve per "
               "K; HDR on, locked, phases 0/120/240. The variants (HDR off, free running, continuous phases) are "
               "table rows on metro_clear at K = 26. Each column's rate axis, shared by its scenes, runs from "
               "the lowest value drawn rounded down to a tenth (from 0 when that is below 0.5) to 1, with 3 %% "
               "of its span beyond both ends, so a point at either end is drawn inside the frame.\n\n"
               "![calibration](%s/calibration.png)\n\nAccuracy of the answered lights against their reported "
               "confidence, pooled over each scene's main grid (HDR on, locked, 3 phases; the variants' ECE is "
               "in the table); the dashed line is perfect calibration. Both axes run over the whole scale, 0 to 1 "
               "with 3 %% beyond both ends, so the diagonal is at 45 degrees and a bin at 0 or 1 is inside the "
               "frame. These captures are the project's own "
               "simulator's; calibration on a renderer the simulator does not share is in "
               "docs/recognition.md (\"Measured\", the independent renderer). The plot's bins, with the 95 %% "
               "Wilson interval of their share right (the plot's bars):\n\n"
               "| scene | confidence of | bin | lights | mean confidence | right | 95 %% interval |\n"
               "|---|---|---|---:|---:|---:|---|\n",
            leaf, leaf);
    for (int phase = 0; phase < 2; phase++)
        for (int hard = 0; hard < 3; hard++) {
            double n[NBINS], c[NBINS], r[NBINS];
            pooled_bins(pts, np, hard, phase, n, c, r);
            for (int b = 0; b < NBINS; b++)
                if (n[b] > 0) {
                    double lo, hi, y = srv_wilson(lround(r[b]), lround(n[b]), SRV_Z95, &lo, &hi);
                    fprintf(f, "| %s | %s | [%.2f, %.2f%s | %.0f | %.3f | %.3f | %.3f-%.3f |\n", srv_acc_scene_names[hard],
                            phase ? "phase" : "bulb and phase", srv_acc_bin_edges[b], fmin(srv_acc_bin_edges[b + 1], 1.0),
                            b + 1 < NBINS ? ")" : "]", n[b], c[b] / n[b], y, lo, hi);
                }
        }
    fprintf(f, "\nEvery point's bins: [%s/calibration.csv](%s/calibration.csv) (per point and kind, "
               "`confidence_of` bulb_and_phase or phase: the bin [bin_lo, bin_hi), the last closed, its "
               "lights matched to the truth, the mean confidence of all of its lights and how many of the "
               "matched are right).\n\n",
            leaf, leaf);

    /* the recommendation, from the metro curves */
    fprintf(f, "## Recommendation\n\n");
    const srv_acc_point *best = NULL, *rec = NULL;
    int rs = 0;   /* the scene the rule runs on: metro, or metro_clear when metro yields nothing */
    for (int pass = 0; pass < 2 && (!best || best->ev.all_correct_rate < 0.05); pass++) {
        rs = pass ? 2 : 0;
        best = NULL;
        for (size_t i = 0; i < np; i++) {
            const srv_acc_point *p = &pts[i];
            if (!main_grid(p) || p->hard != rs || !isfinite(p->ev.all_correct_rate)) continue;
            if (!best || p->ev.all_correct_rate > best->ev.all_correct_rate) best = p;
        }
    }
    if (best) {
        for (size_t i = 0; i < np; i++) {
            const srv_acc_point *p = &pts[i];
            if (!main_grid(p) || p->hard != rs || !isfinite(p->ev.all_correct_rate)) continue;
            if (p->ev.all_correct_rate >= best->ev.all_correct_rate - 0.02 && (!rec || p->capture_s < rec->capture_s)) rec = p;
        }
    }
    if (rs == 2 && best)
        fprintf(f, "**On metro as shipped the pipeline names no bulb at any setting** (every detected light is "
                   "answered unknown: extinction reddens the lights out of their DELIGHT chromaticity and "
                   "scintillation adds noise the capture's noise model does not have, so Eq. 7's chi-square "
                   "test rejects every bulb; docs/capture.md, \"What the effects do to recognition\"). More "
                   "capture time does not help: it only makes the rejection surer. The trade-off of the camera is "
                   "therefore read on **metro_clear** (the same city without extinction and scintillation), "
                   "which is what a survey gets on a clear, calm night or once Eq. 7 models the atmosphere.\n\n");
    if (!rec) {
        fprintf(f, "No point of the metro sweep has an evaluation: no recommendation.\n");
    } else {
        fprintf(f, "Rule (computed from the %s rows, HDR on, locked, 3 phases): the shortest capture whose "
                   "yield (truth lights found with the right bulb and phase) is within 2 points of the best "
                   "of the sweep (%.1f %% at K = %d, C = %d, %.0f s).\n\n",
                srv_acc_scene_names[rs], 100 * best->ev.all_correct_rate, best->K, best->C, best->capture_s);
        /* the sampling noise of a yield over the window's truth lights */
        double nt = (double)rec->ev.truth_in_image, y = rec->ev.all_correct_rate;
        if (nt > 0)
            fprintf(f, "Sampling noise: with %.0f truth lights one light is %.2f points, and the binomial "
                       "standard error of a yield y is sqrt(y (1 - y) / %.0f), %.1f points at the default's "
                       "below: differences of a point or so between settings are within it.\n\n",
                    nt, 100 / nt, nt, 100 * sqrt(y * (1 - y) / nt));
        fprintf(f, "**Default for a city survey: K = %d, C = %d** (%ld acquisitions, %.0f s per capture): %.1f %% of "
                   "the lights in view found with the right bulb and phase, %.1f %% of the detected ones right, "
                   "detection %.1f %%, location error %.1f m median / %.1f m at the 95th percentile, "
                   "%.2f s of compute for the window.\n\n",
                rec->K, rec->C, rec->acquisitions, rec->capture_s, 100 * rec->ev.all_correct_rate,
                100 * right_of_detected(rec), 100 * rec->ev.detection_rate, rec->ev.loc_median_m, rec->ev.loc_p95_m,
                rec->compute_s);
        delta_line(f, "Halving the capture time", find_pt(pts, np, rs, rec->K, rec->C / 2), rec);
        delta_line(f, "Doubling the capture time", find_pt(pts, np, rs, rec->K, rec->C * 2), rec);
        const srv_acc_point *h = find_pt(pts, np, 1, rec->K, rec->C);
        if (h)
            fprintf(f, "- **In bad seeing** (metro_hard at the same setting): %.1f %% found right, %.1f %% of the "
                       "detected right, detection %.1f %%.\n",
                    100 * h->ev.all_correct_rate, 100 * right_of_detected(h), 100 * h->ev.detection_rate);
        for (int ki = 0; ki < nK; ki++) {
            if (Ks[ki] == rec->K) continue;
            const srv_acc_point *o = find_pt(pts, np, rs, Ks[ki], rec->C);
            if (o)
                fprintf(f, "- **K = %d** at the same C: %.0f s, %.1f %% found right, %.1f %% of the detected right.\n",
                        Ks[ki], o->capture_s, 100 * o->ev.all_correct_rate, 100 * right_of_detected(o));
        }
        fprintf(f, "\nThe capture time is almost all exposure (A C Delta); the readouts add R/C of it. "
                   "Compute time hardly depends on the setting (it grows with the lights detected and with "
                   "K), so on the ACam time is the cost of accuracy.\n");
    }
    int bad = ferror(f);
    if (fclose(f) != 0 || bad) return gs_fail(GS_EIO, "%s: write failed", path);
    return GS_OK;
}


gs_status srv_acc_write_drift_doc(const char *path, const char *out, const char *base, const srv_acc_crop *cr,
                                  int quick, const srv_acc_point *pts, size_t np, double wall)
{
    FILE *f = fopen(path, "w");
    if (!f) return gs_fail(GS_EIO, "%s: cannot write: %s", path, strerror(errno));
    const char *leaf = strrchr(out, '/') ? strrchr(out, '/') + 1 : out;
    const char *q = quick ? " --quick" : "";
    fprintf(f, "# Free running: which frames Eq. 7 keeps (`gridsurvey bench accuracy --drift-sweep%s`)\n\n"
               "Generated by `gridsurvey bench accuracy --drift-sweep%s --out-dir %s` (survey/bench_accuracy.c), "
               "which wrote this file and `%s/accuracy.csv` (the columns of docs/accuracy.md's, with "
               "`free_period` and `max_drift_windows`). Every number is deterministic given the scene's seed "
               "except the times; this run took %.0f s of wall time. The thresholds of one period and C read "
               "one simulated capture (`gridsurvey run CAPDIR`): after the first, their `compute_s` includes "
               "generating the built-in DELIGHT, which a scene's render does otherwise.\n\n",
            q, q, out, leaf, wall);
    fprintf(f, "Scene `%s` without extinction and scintillation (metro_clear), through a %d x %d window (pixels "
               "%d..%d x %d..%d), HDR on, phases 0/120/240, the ACam free running: each frame's windows timed "
               "with a fixed half period P from the start of its exposure, so they move across the flicker "
               "over its C cycles (capture.json's `window_drift_windows`, docs/capture.md). **period**: P "
               "measured over the 64 cycles before each exposure, as the firmware does, or the grid's "
               "nominal one (a mode the firmware does not have: it shows a larger drift). **threshold**: "
               "`rec_eq7_opts.max_drift_windows` (`recognize --max-drift-windows`): a frame whose windows "
               "moved further is left out of Eq. 7, the others' noise is raised by their smear "
               "(docs/recognition.md, \"Free-running captures\"); *none* keeps every frame. The default, "
               "`auto`, is none when the period was measured (capture.json's `window_period`) and %g when "
               "it was nominal: the rows of that threshold are what the default gives. **kept**: "
               "the frames kept of the K, and in parentheses the largest drift, in windows. The other "
               "columns are docs/accuracy.md's: *bulb* and *phase* the accuracy of the answers given, *unkn.* "
               "the detected lights without a bulb, *right/det.* the detected lights with the right bulb and "
               "phase, ECE of the reported confidence, and the maximum-likelihood oracle on its subset "
               "(survey/bench_oracle.c), which leaves out the same frames but takes the kept ones' windows "
               "as regular (Eq. 5) without raising their noise: with drifted frames kept it is no "
               "ceiling (a negative gap). Discussed in docs/recognition.md, \"Free-running captures\".\n\n",
            base, cr->w, cr->h, cr->x0, cr->x0 + cr->w - 1, cr->y0, cr->y0 + cr->h - 1, REC_MAX_DRIFT_WINDOWS);
    fprintf(f, "| period | K | C | threshold | kept | capture s | det. | bulb | phase | unkn. | right/det. | ECE | "
               "oracle lights | pipeline | oracle | gap |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for (size_t i = 0; i < np; i++) {
        const srv_acc_point *p = &pts[i];
        char thr[32], b[12][40];
        srv_acc_threshold_name(p, thr, sizeof thr);
        if (!p->ok) {
            fprintf(f, "| %s | %d | %d | %s | failed: %s ||||||||||||\n", srv_acc_period_name(p), p->K, p->C, thr, p->err);
            continue;
        }
        snprintf(b[0], 40, "%d of %d (%.2f)", p->frames_kept, p->K, p->drift_windows);
        fmt_num(b[1], 40, 100 * p->ev.detection_rate, "%.1f %%");
        fmt_num(b[2], 40, 100 * p->ev.bulb_accuracy, "%.1f %%");
        fmt_num(b[3], 40, 100 * p->ev.phase_accuracy, "%.1f %%");
        fmt_num(b[4], 40, 100 * p->ev.bulb_unknown_rate, "%.1f %%");
        fmt_num(b[5], 40, 100 * right_of_detected(p), "%.1f %%");
        fmt_num(b[6], 40, p->cal.ece, "%.3f");
        fmt_num(b[7], 40, 100 * p->ours_sub, "%.1f %%");
        fmt_num(b[8], 40, 100 * p->oracle_sub, "%.1f %%");
        fmt_num(b[9], 40, 100 * (p->oracle_sub - p->ours_sub), "%+.1f");
        fprintf(f, "| %s | %d | %d | %s | %s | %.1f | %s | %s | %s | %s | %s | %s | %ld | %s | %s | %s |\n",
                srv_acc_period_name(p), p->K, p->C, thr, b[0], p->capture_s, b[1], b[2], b[3], b[4], b[5], b[6],
                p->oracle_n, b[7], b[8], b[9]);
    }
    int bad = ferror(f);
    if (fclose(f) != 0 || bad) return gs_fail(GS_EIO, "%s: write failed", path);
    return GS_OK;
}
