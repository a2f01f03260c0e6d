/* bench_accuracy.c - `gridsurvey bench accuracy [--quick] [--out-dir DIR]`: what accuracy costs in
 * time (docs/accuracy.md). Sweeps the ACam acquisition (cycles per frame C, windows
 * K, HDR, locked / free running, Eq. 7 phase set) on a window of the built-in metropolitan
 * scene and on a hard variant of it, and for each point runs the survey pipeline as `gridsurvey
 * run` does (srv_run: simulate the capture through the acquisition loop, blobs, Eq. 7, locate,
 * store) and scores it with the pipeline's evaluation (srv_evaluate). Per point:
 *   capture time   the ACam's real acquisition time: A (C + R) Delta, A acquisitions (K frames
 *                  plus HDR repeats, from the loop's acquisition.json), R readout cycles
 *                  between acquisitions, Delta = 1/(2 f);
 *   compute time   of recognition and georeferencing (srv_run's blobs + match + locate stages);
 *   accuracy       detection, bulb, phase, location error against the simulator's truth;
 *   calibration    the stored lights binned by reported confidence (and those with a phase by
 *                  phase confidence), each bin stored as its own capture in the point's database
 *                  and scored by srv_evaluate;
 *   the oracle     rec_ml_oracle (the exact Poisson-Gaussian maximum-likelihood decision) on the
 *                  same lights' extracted signals with the camera's noise model, stored as a
 *                  capture and scored by srv_evaluate, next to the pipeline's answers for the
 *                  same lights.
 * Writes DIR/accuracy.csv, DIR/calibration.csv (every point's reliability bins),
 * DIR/accuracy_vs_time.png, DIR/calibration.png and the Markdown
 * report DIR.md (docs/accuracy.md for --out-dir docs/accuracy). Deterministic for the scene's seed
 * except the compute times. */
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


const double srv_acc_bin_edges[NBINS + 1] = {0.0, 0.5, 0.8, 0.95, 0.99, 1.0000001};
const char *const srv_acc_scene_names[3] = {"metro", "metro_hard", "metro_clear"};

static int rm_one(const char *p, const struct stat *sb, int flag, struct FTW *f)
{
    (void)sb;
    (void)flag;
    (void)f;
    return remove(p);
}

static void rm_rf(const char *path)
{
    nftw(path, rm_one, 16, FTW_DEPTH | FTW_PHYS);
}

static gs_status mkdir_p(const char *path)
{
    char buf[4096];
    snprintf(buf, sizeof buf, "%s", path);
    for (char *p = buf + 1; *p; p++) {
        if (*p != '/') continue;
        *p = 0;
        if (mkdir(buf, 0777) != 0 && errno != EEXIST)
            return gs_fail(GS_EIO, "%s: cannot create: %s", buf, strerror(errno));
        *p = '/';
    }
    if (mkdir(buf, 0777) != 0 && errno != EEXIST)
        return gs_fail(GS_EIO, "%s: cannot create: %s", buf, strerror(errno));
    return GS_OK;
}

/* ------------------------------------------------------------------ the scene of a srv_acc_point */


static void jset(json_t *o, const char *k, json_t *v)
{
    json_object_set_new(o, k, v);
}

/* The metro scene of a point: a crop (smaller sensor, principal point moved: the same camera
 * looking at the same city), the ACam settings, and for the hard variant lower visibility
 * (8 km instead of 20), 5x the turbulence (Cn2 1e-14) and distractors (two blinking signs and
 * a road of headlights inside the window). */
static gs_status write_scene(const char *base, const srv_acc_point *p, const srv_acc_crop *c, const char *path,
                             double *readout_cycles, double *grid_hz, double *transformer_deg)
{
    json_error_t je;
    json_t *root = json_load_file(base, JSON_REJECT_DUPLICATES, &je);
    if (!root) return gs_fail(GS_EFORMAT, "%s:%d: %s", base, je.line, je.text);
    json_t *cam = json_object_get(root, "camera"), *acam = json_object_get(root, "acam");
    json_t *grid = json_object_get(root, "grid");
    if (!json_is_object(cam) || !json_is_object(acam) || !json_is_object(grid)) {
        json_decref(root);
        return gs_fail(GS_EFORMAT, "%s: expected camera, acam and grid objects", base);
    }
    int W = (int)json_integer_value(json_object_get(cam, "width_px"));
    int H = (int)json_integer_value(json_object_get(cam, "height_px"));
    json_t *in = json_object_get(cam, "intrinsics");
    if (!json_is_object(in)) {
        in = json_object();
        jset(cam, "intrinsics", in);
    }
    double cx = json_is_number(json_object_get(in, "cx_px")) ? json_number_value(json_object_get(in, "cx_px")) : W / 2.0;
    double cy = json_is_number(json_object_get(in, "cy_px")) ? json_number_value(json_object_get(in, "cy_px")) : H / 2.0;
    if (!json_is_number(json_object_get(in, "focal_px"))) jset(in, "focal_px", json_real(W));
    jset(in, "cx_px", json_real(cx - c->x0));
    jset(in, "cy_px", json_real(cy - c->y0));
    jset(cam, "width_px", json_integer(c->w));
    jset(cam, "height_px", json_integer(c->h));
    jset(acam, "K", json_integer(p->K));
    jset(acam, "cycles", json_integer(p->C));
    jset(acam, "locked", json_boolean(p->locked));
    /* free running as the firmware does it: the period measured over the 64 cycles before (or
     * the nominal one, a mode the firmware does not have: --drift-sweep) */
    if (!p->locked) jset(acam, "free_running_period", json_string(p->nominal_period ? "nominal" : "measured"));
    if (!json_is_integer(json_object_get(acam, "masks"))) jset(acam, "masks", json_integer(64));
    json_t *hdr = json_object();
    jset(hdr, "enabled", json_boolean(p->hdr));
    jset(hdr, "max_saturated_px", json_integer(10));
    jset(acam, "hdr", hdr);
    *readout_cycles = json_is_integer(json_object_get(acam, "readout_cycles"))
                          ? (double)json_integer_value(json_object_get(acam, "readout_cycles")) : 10.0;
    *grid_hz = (double)json_integer_value(json_object_get(grid, "nominal_hz"));
    *transformer_deg = json_is_number(json_object_get(grid, "transformer_deg"))
                           ? json_number_value(json_object_get(grid, "transformer_deg")) : 30.0;
    if (p->hard == 2) {
        json_t *fx = json_object_get(root, "effects");
        jset(root, "name", json_string("metro_clear"));
        if (json_is_object(fx)) {
            json_object_del(fx, "extinction");
            json_object_del(fx, "scintillation");
        }
    } else if (p->hard) {
        json_t *fx = json_object_get(root, "effects");
        if (!json_is_object(fx)) {
            fx = json_object();
            jset(root, "effects", fx);
        }
        jset(root, "name", json_string("metro_hard"));
        json_t *ext = json_object();
        jset(ext, "visibility_km", json_real(8.0));
        jset(ext, "angstrom_exponent", json_real(1.3));
        jset(fx, "extinction", ext);
        json_t *sc = json_object();
        jset(sc, "cn2", json_real(1e-14));
        jset(sc, "crosswind_m_s", json_real(2.0));
        jset(fx, "scintillation", sc);
        json_t *signs = json_array();
        for (int i = 0; i < 2; i++) {
            json_t *s = json_object();
            jset(s, "x_px", json_real(c->w * (0.25 + 0.5 * i)));
            jset(s, "y_px", json_real(c->h * 0.3));
            jset(s, "width_px", json_real(3));
            jset(s, "height_px", json_real(2));
            jset(s, "period_s", json_real(0.7 + 0.6 * i));
            jset(s, "duty", json_real(0.5));
            jset(s, "flux_e_per_cycle", json_real(400.0));
            json_array_append_new(signs, s);
        }
        json_t *sb = json_object();
        jset(sb, "signs", signs);
        jset(fx, "blinking_sign", sb);
        json_t *car = json_object(), *cars = json_array(), *hl = json_object();
        json_t *from = json_array(), *to = json_array();
        json_array_append_new(from, json_real(0));
        json_array_append_new(from, json_real(c->h * 0.8));
        json_array_append_new(to, json_real(c->w));
        json_array_append_new(to, json_real(c->h * 0.7));
        jset(car, "from", from);
        jset(car, "to", to);
        jset(car, "speed_px_s", json_real(15.0));
        jset(car, "period_s", json_real(20.0));
        jset(car, "flux_e_per_cycle", json_real(300.0));
        json_array_append_new(cars, car);
        jset(hl, "cars", cars);
        jset(fx, "headlights", hl);
    }
    int rc = json_dump_file(root, path, JSON_INDENT(1));
    json_decref(root);
    if (rc != 0) return gs_fail(GS_EIO, "%s: cannot write the scene", path);
    return GS_OK;
}

static gs_status read_acquisitions(const char *capdir, long *n)
{
    char path[4400];
    snprintf(path, sizeof path, "%s/acquisition.json", capdir);
    json_error_t je;
    json_t *root = json_load_file(path, 0, &je);
    if (!root) return gs_fail(GS_EFORMAT, "%s:%d: %s", path, je.line, je.text);
    json_t *a = json_object_get(root, "acquisitions");
    gs_status s = json_is_integer(a) ? GS_OK : gs_fail(GS_EFORMAT, "%s: no acquisitions count", path);
    if (s == GS_OK) *n = (long)json_integer_value(a);
    json_decref(root);
    return s;
}

/* ------------------------------------------------------------------ one srv_acc_point */

gs_status srv_acc_eval_subset(srv_db *db, int64_t survey_id, const char *key, const srv_light_row *rows,
                             size_t n, const char *truth, srv_eval_report *ev)
{
    srv_capture_data cd;
    memset(&cd, 0, sizeof cd);
    srv_capture_row_init(&cd.capture);
    cd.capture.survey_id = survey_id;
    cd.capture.key = key;
    cd.lights = rows;
    cd.n_lights = n;
    gs_status s = srv_db_add_capture(db, &cd, NULL, NULL);
    if (s != GS_OK) return s;
    srv_eval_opts eo;
    srv_eval_opts_default(&eo);
    eo.capture_key = key;
    return srv_evaluate(db, truth, &eo, ev);
}

/* Reliability bins of the point's lights (rows and their answers mt, n of them; sub scratch of n
 * rows): by confidence the lights with a bulb, right = bulb and phase (phase = 0); by
 * phase_confidence the lights stored with a phase, right = the phase (phase = 1). Each bin is
 * stored as its own capture and scored by srv_evaluate. */
static gs_status calibrate(srv_db *db, const srv_run_report *rr, const rec_match *mt, const srv_light_row *rows,
                           size_t n, int phase, srv_light_row *sub, srv_acc_bins *out)
{
    double ece_num = 0, ece_den = 0;
    memset(out, 0, sizeof *out);
    for (int b = 0; b < NBINS; b++) {
        size_t k = 0;
        double conf = 0;
        for (size_t i = 0; i < n; i++) {
            double c = phase ? rows[i].phase_confidence : mt[i].confidence;
            int answered = phase ? isfinite(rows[i].phase_deg) : mt[i].bulb >= 0;
            if (!answered || !(c >= srv_acc_bin_edges[b] && c < srv_acc_bin_edges[b + 1])) continue;
            sub[k] = rows[i];
            sub[k].index = (int)k;
            conf += c;
            k++;
        }
        if (!k) continue;
        char key[64];
        snprintf(key, sizeof key, "%scalibration-bin-%d", phase ? "phase-" : "", b);
        srv_eval_report ev;
        gs_status s = srv_acc_eval_subset(db, rr->survey_id, key, sub, k, rr->truth_path, &ev);
        if (s != GS_OK) return s;
        /* the bin's matched lights; its mean confidence over all of its lights */
        out->n[b] = (double)ev.matched;
        out->conf[b] = conf / (double)k * (double)ev.matched;
        out->right[b] = (double)(phase ? ev.phase_correct : ev.all_correct);
        if (ev.matched) {
            ece_num += fabs(out->right[b] - out->conf[b]);
            ece_den += (double)ev.matched;
        }
    }
    out->ece = ece_den > 0 ? ece_num / ece_den : NAN;
    return GS_OK;
}

/* 1 when a and b simulate the same capture (they differ at most in Eq. 7's options) */
static int same_setting(const srv_acc_point *a, const srv_acc_point *b)
{
    return a->hard == b->hard && a->K == b->K && a->C == b->C && a->hdr == b->hdr && a->locked == b->locked &&
           a->nominal_period == b->nominal_period;
}

/* One point: its scene simulated into capdir = DIR/capture (DIR = work/its name), the lights'
 * height (the scene's median) and its sigma into height_m; or with reuse, capdir and height_m as
 * they are: the capture of an earlier point of the same setting (only the Eq. 7 options differ). */
static gs_status run_point(const char *base, const srv_acc_crop *cr, const char *work, int n_oracle,
                           const gs_delight *dl, int reuse, srv_acc_point *p, char capdir[4200],
                           double height_m[2])
{
    char dir[4096], scene[4200], dbp[4200], thr[32];   /* paths stay below 4096 */
    int len = snprintf(dir, sizeof dir, "%s/%s-K%d-C%d-%s-%s-%s-%s", work, srv_acc_scene_names[p->hard], p->K, p->C,
                       p->hdr ? "hdr" : "nohdr", p->locked ? "locked" : p->nominal_period ? "free-nominal" : "free",
                       p->continuous ? "cont" : "ph3", srv_acc_threshold_name(p, thr, sizeof thr));
    if (len < 0 || (size_t)len >= sizeof dir - 32) return gs_fail(GS_EINVAL, "%s: work directory path too long", work);
    rm_rf(dir);
    gs_status s = mkdir_p(dir);
    if (s != GS_OK) return s;
    snprintf(scene, sizeof scene, "%s/scene.json", dir);
    snprintf(dbp, sizeof dbp, "%s/survey.sqlite", dir);
    if (!reuse) snprintf(capdir, 4200, "%s/capture", dir);
    double grid_hz = 50, transformer = 30;
    if ((s = write_scene(base, p, cr, scene, &p->readout_cycles, &grid_hz, &transformer)) != GS_OK) return s;
    p->delta_s = 1.0 / (2.0 * grid_hz);

    /* the pipeline, as `gridsurvey run` */
    srv_run_opts ro;
    srv_run_opts_default(&ro);
    ro.input = reuse ? capdir : scene;
    ro.db_path = dbp;
    ro.capture_dir = reuse ? NULL : capdir;
    if (reuse) ro.light_height_m = height_m[0], ro.light_height_sigma_m = height_m[1];
    if (p->continuous) ro.eq7.phases = REC_PHASES_CONTINUOUS;
    ro.eq7.max_drift_windows = p->max_drift_windows;
    srv_run_report rr;
    if ((s = srv_run(&ro, &rr)) != GS_OK) return s;
    height_m[0] = rr.light_height_m, height_m[1] = rr.light_height_sigma_m;
    p->compute_s = rr.seconds[SRV_STAGE_BLOBS] + rr.seconds[SRV_STAGE_MATCH] + rr.seconds[SRV_STAGE_LOCATE];
    if ((s = read_acquisitions(capdir, &p->acquisitions)) != GS_OK) return s;
    p->exposure_s = (double)p->acquisitions * p->C * p->delta_s;
    p->readout_s = (double)p->acquisitions * p->readout_cycles * p->delta_s;
    p->capture_s = p->exposure_s + p->readout_s;

    srv_db *db = NULL;
    srv_job j;
    memset(&j, 0, sizeof j);
    srv_light_row *sub = NULL;
    double *snr = NULL;
    if ((s = srv_db_open(dbp, SRV_DB_WRITE, &db)) != GS_OK) goto done;
    srv_eval_opts eo;
    srv_eval_opts_default(&eo);
    if ((s = srv_evaluate(db, rr.truth_path, &eo, &p->ev)) != GS_OK) goto done;

    /* the same lights again (deterministic: the pipeline's catalog and answers), with the
     * aperture of each for the oracle's noise model */
    rec_blob_opts bo;
    rec_blob_opts_default(&bo);
    bo.threshold_sigma = ro.threshold_sigma;
    bo.labels = 1;
    if ((s = srv_job_read(&j, capdir)) != GS_OK ||
        (s = srv_job_extract(&j, &bo)) != GS_OK)
        goto done;
    p->drift_windows = gs_capture_window_drift(&j.cap, NULL);
    p->frames_kept = j.cap.K - rec_frames_left_out(&j.cap, ro.eq7.max_drift_windows, NULL);
    if (j.cat.count != rr.lights) {
        s = gs_fail(GS_ENUMERIC, "%s: %zu lights extracted again, the pipeline stored %zu", capdir,
                    j.cat.count, rr.lights);
        goto done;
    }
    size_t n = j.cat.count;
    int K = j.cat.K, B = j.cat.bands;
    sub = calloc(n ? n : 1, sizeof *sub);
    snr = calloc(n ? n : 1, sizeof *snr);
    if (!sub || !snr) {
        s = gs_fail(GS_ENOMEM, "bench accuracy: out of memory");
        goto done;
    }
    if ((s = srv_job_matcher(&j, dl, NULL, j.cap.grid_hz, B, K, &ro.eq7)) != GS_OK ||
        (s = srv_job_match(&j)) != GS_OK)
        goto done;
    const rec_match *mt = j.match;
    const srv_light_row *rows = j.lights;
    for (size_t i = 0; i < n; i++) snr[i] = rows[i].snr;
    if (j.with_bulb != rr.with_bulb) {
        s = gs_fail(GS_ENUMERIC, "%s: %zu lights with a bulb again, the pipeline stored %zu", capdir,
                    j.with_bulb, rr.with_bulb);
        goto done;
    }
    if (n) {
        qsort(snr, n, sizeof *snr, gs_cmp_double);
        double pos = 0.9 * (double)(n - 1);
        size_t i0 = (size_t)floor(pos);
        p->snr_p90 = i0 + 1 < n ? snr[i0] + (pos - (double)i0) * (snr[i0 + 1] - snr[i0]) : snr[n - 1];
    }

    /* calibration: the answered lights by confidence, the lights with a phase by phase confidence */
    if ((s = calibrate(db, &rr, mt, rows, n, 0, sub, &p->cal)) != GS_OK ||
        (s = calibrate(db, &rr, mt, rows, n, 1, sub, &p->phase_cal)) != GS_OK)
        goto done;

    /* the oracle on a subset of the same lights (bench_oracle.c) */
    s = srv_acc_oracle(db, &rr, &j, rows, transformer, ro.eq7.max_drift_windows, n_oracle, sub, p);
done:
    free(snr);
    free(sub);
    srv_job_release(&j);
    srv_db_close(db);
    return s;
}

/* ------------------------------------------------------------------ main */

static const char acc_usage[] =
    "usage: gridsurvey bench accuracy [--quick] [--drift-sweep] [--out-dir DIR] [--scene FILE] [--keep]\n"
    "\n"
    "Sweeps the ACam acquisition (cycles per frame C, windows K, HDR, locked / free running, Eq. 7\n"
    "phase set) on a window of the metro scene and a hard variant, runs the survey pipeline on each\n"
    "point and scores it against the simulator's truth, next to the maximum-likelihood oracle.\n"
    "Writes DIR/accuracy.csv, DIR/calibration.csv, DIR/accuracy_vs_time.png, DIR/calibration.png and DIR.md\n"
    "(default DIR: build/accuracy). --quick: a few points on a small window (seconds).\n"
    "--scene: the base scene (capture/scenes/metro.json). --keep: keep the work directory.\n"
    "--drift-sweep: instead, free running on metro_clear at K = 26, C = 64..1024, the period\n"
    "measured or nominal, Eq. 7's --max-drift-windows 0.25, 0.5, 1 and none (--quick: K = 8,\n"
    "C = 1024, 0.25 and none); writes DIR/accuracy.csv and DIR.md (default DIR:\n"
    "build/accuracy-drift).\n"
    "\n"
    "Examples:\n"
    "  gridsurvey bench accuracy --quick --out-dir build/accuracy-quick\n"
    "  gridsurvey bench accuracy --out-dir docs/accuracy   # docs/accuracy.md (make bench)\n"
    "  gridsurvey bench accuracy --drift-sweep --out-dir docs/accuracy-drift   # (make bench)\n";

int srv_bench_accuracy(int argc, char **argv)
{
    static const struct option longs[] = {{"quick", no_argument, 0, 'q'}, {"out-dir", required_argument, 0, 'O'},
                                          {"scene", required_argument, 0, 's'}, {"keep", no_argument, 0, 'k'},
                                          {"drift-sweep", no_argument, 0, 'D'},
                                          {"help", no_argument, 0, 'h'}, {0, 0, 0, 0}};
    int quick = 0, keep = 0, drift_sweep = 0, c;
    const char *out = NULL, *base = "capture/scenes/metro.json";
    optind = 1;
    while ((c = getopt_long(argc, argv, "ho:", longs, NULL)) != -1) {
        if (c == 'q') quick = 1;
        else if (c == 'O') out = optarg;
        else if (c == 'o') return srv_out_dir_hint("bench accuracy");
        else if (c == 's') base = optarg;
        else if (c == 'k') keep = 1;
        else if (c == 'D') drift_sweep = 1;
        else if (c == 'h') {
            fputs(acc_usage, stdout);
            return 0;
        } else {
            return srv_usage_hint("bench accuracy", argv);
        }
    }
    if (optind != argc) return srv_usage_error("bench accuracy", "unexpected argument '%s'", argv[optind]);
    if (!out) out = drift_sweep ? "build/accuracy-drift" : "build/accuracy";
    openblas_set_num_threads(1);
    double t_start = gs_clock_s(CLOCK_MONOTONIC);
    gs_status s = mkdir_p(out);
    if (s != GS_OK) return srv_error("bench accuracy", s);
    char work[4096];
    const char *tmp = getenv("TMPDIR");
    snprintf(work, sizeof work, "%s/gs-accuracy-XXXXXX", tmp && *tmp ? tmp : "/tmp");
    if (!mkdtemp(work)) return srv_error("bench accuracy", gs_fail(GS_EIO, "%s: cannot create: %s", work, strerror(errno)));

    /* the sweep: the main grid (HDR, locked, 3 phases) over K and C on both scenes, then the
     * variants at K = 26 on metro */
    srv_acc_crop cr = quick ? (srv_acc_crop){720, 390, 160, 120} : (srv_acc_crop){600, 338, 400, 225};
    static const int Ks_full[] = {8, 13, 26}, Cs_full[] = {32, 64, 128, 256, 512, 1024};
    static const int Ks_quick[] = {8}, Cs_quick[] = {32, 64};
    const int *Ks = quick ? Ks_quick : Ks_full, *Cs = quick ? Cs_quick : Cs_full;
    int nK = quick ? 1 : 3, nC = quick ? 2 : 6;
    size_t cap_pts = 128, np = 0;
    srv_acc_point *pts = calloc(cap_pts, sizeof *pts);
    if (!pts) return srv_error("bench accuracy", gs_fail(GS_ENOMEM, "out of memory"));
    for (int hard = 0; hard < (quick ? 1 : 3) && !drift_sweep; hard++)
        for (int ki = 0; ki < nK; ki++)
            for (int ci = 0; ci < nC; ci++)
                if (hard != 1 || Ks[ki] != 13)   /* metro_hard: K = 8 and 26 only (time) */
                    pts[np++] = (srv_acc_point){.hard = hard, .K = Ks[ki], .C = Cs[ci], .hdr = 1, .locked = 1};
    if (drift_sweep) {
        /* free running: the period measured or nominal, Eq. 7's threshold (docs/recognition.md) */
        static const int Csw[] = {64, 128, 256, 512, 1024}, Cq[] = {1024};
        static const double Tsw[] = {0.25, REC_MAX_DRIFT_WINDOWS, 1.0, INFINITY}, Tq[] = {0.25, INFINITY};
        const int *Cd = quick ? Cq : Csw;
        const double *Td = quick ? Tq : Tsw;
        int nCd = quick ? 1 : 5, nTd = quick ? 2 : 4;
        for (int nominal = 0; nominal < 2; nominal++)
            for (int ci = 0; ci < nCd; ci++)
                for (int ti = 0; ti < nTd; ti++)
                    pts[np++] = (srv_acc_point){.hard = 2, .K = quick ? 8 : 26, .C = Cd[ci], .hdr = 1, .locked = 0,
                                                .nominal_period = nominal, .max_drift_windows = Td[ti]};
    } else if (!quick) {
        /* (free running at C = 128 to 1024, the period measured: the windows move up to
         * several windows, and Eq. 7's default keeps every frame, raising its noise) */
        static const int Cv[] = {128, 512}, Cfree[] = {128, 256, 512, 1024};
        for (int v = 0; v < 3; v++)
            for (int ci = 0; ci < (v == 1 ? 4 : 2); ci++)
                pts[np++] = (srv_acc_point){.hard = 2, .K = 26, .C = v == 1 ? Cfree[ci] : Cv[ci], .hdr = v != 0,
                                            .locked = v != 1, .continuous = v == 2};
    } else {
        pts[np++] = (srv_acc_point){.hard = 2, .K = 8, .C = 64, .hdr = 1, .locked = 1};
        pts[np++] = (srv_acc_point){.K = 8, .C = 64, .hdr = 0, .locked = 1};
        pts[np++] = (srv_acc_point){.K = 8, .C = 1024, .hdr = 1, .locked = 0};
    }
    for (size_t i = 0; i < np && !drift_sweep; i++) pts[i].max_drift_windows = REC_DRIFT_AUTO;
    gs_delight *dl = NULL;
    if ((s = gs_delight_open(NULL, &dl)) != GS_OK) {
        free(pts);
        return srv_error("bench accuracy", s);
    }
    int failed = 0;
    char capdir[4200];
    double height_m[2] = {NAN, NAN};
    for (size_t i = 0; i < np; i++) {
        srv_acc_point *p = &pts[i];
        double t0 = gs_clock_s(CLOCK_MONOTONIC);
        /* (the drift sweep's thresholds of one setting read the same capture) */
        const srv_acc_point *q = i ? &pts[i - 1] : NULL;
        int reuse = q && q->ok && same_setting(q, p);
        s = run_point(base, &cr, work, quick ? 8 : 40, dl, reuse, p, capdir, height_m);
        p->ok = s == GS_OK;
        if (!p->ok) {
            snprintf(p->err, sizeof p->err, "%s: %s", gs_strerror(s), gs_detail());
            failed++;
        }
        char thr[32];
        fprintf(stderr, "bench accuracy: %s K=%d C=%d hdr=%d %s phases=%s max drift %s: %s (%.1f s)\n",
                srv_acc_scene_names[p->hard], p->K, p->C, p->hdr, srv_acc_period_name(p), srv_acc_ph_name(p),
                srv_acc_threshold_name(p, thr, sizeof thr),
                p->ok ? "ok" : p->err, gs_clock_s(CLOCK_MONOTONIC) - t0);
        if (!keep && !(i + 1 < np && p->ok && same_setting(p, &pts[i + 1]))) rm_rf(work), mkdir(work, 0700);
    }
    gs_delight_free(dl);
    char path[4400];
    snprintf(path, sizeof path, "%s/accuracy.csv", out);
    s = srv_acc_write_csv(path, pts, np);
    char doc[4400];
    size_t len = strlen(out);
    while (len > 1 && out[len - 1] == '/') len--;
    snprintf(doc, sizeof doc, "%.*s.md", (int)len, out);
    if (s == GS_OK && drift_sweep) {
        s = srv_acc_write_drift_doc(doc, out, base, &cr, quick, pts, np, gs_clock_s(CLOCK_MONOTONIC) - t_start);
    } else if (s == GS_OK) {
        snprintf(path, sizeof path, "%s/calibration.csv", out);
        s = srv_acc_write_bins_csv(path, pts, np);
    }
    if (s == GS_OK && !drift_sweep) {
        snprintf(path, sizeof path, "%s/accuracy_vs_time.png", out);
        srv_acc_plot_accuracy(path, pts, np, Ks, nK);
        snprintf(path, sizeof path, "%s/calibration.png", out);
        srv_acc_plot_calibration(path, pts, np);
        s = srv_acc_write_doc(doc, out, base, &cr, quick, pts, np, gs_clock_s(CLOCK_MONOTONIC) - t_start, Ks, nK);
    }
    if (!keep) rm_rf(work);
    else fprintf(stderr, "bench accuracy: work directory kept: %s\n", work);
    free(pts);
    if (s != GS_OK) return srv_error("bench accuracy", s);
    fprintf(stderr, "bench accuracy: %zu points (%d failed) in %.0f s\n", np, failed, gs_clock_s(CLOCK_MONOTONIC) - t_start);
    return failed ? 1 : 0;
}
