/* bench_accuracy.c - `gridsurvey bench accuracy [--quick] [--out DIR]`: what accuracy costs in
 * time (issue #8, docs/accuracy.md). Sweeps the ACam acquisition (cycles per frame C, windows
 * K, HDR, locked / free running, Eq. 7 phase set) on a window of the built-in metropolitan
 * scene and on a hard variant of it, and for each point runs the survey pipeline as `gridsurvey
 * run` does (srv_run: simulate the capture through the acquisition loop, blobs, Eq. 7, locate,
 * store) and scores it with the pipeline's evaluation (srv_evaluate). Per point:
 *   capture time   the ACam's real acquisition time: A (C + R) Delta, A acquisitions (K frames
 *                  plus HDR repeats, from the loop's acquisition.json), R readout cycles
 *                  between acquisitions, Delta = 1/(2 f);
 *   compute time   of recognition and georeferencing (srv_run's blobs + match + locate stages);
 *   accuracy       detection, bulb, phase, location error against the simulator's truth;
 *   calibration    the stored lights binned by reported confidence, each bin stored as its own
 *                  capture in the point's database and scored by srv_evaluate;
 *   the oracle     rec_ml_oracle (the exact Poisson-Gaussian maximum-likelihood decision) on the
 *                  same lights' extracted signals with the camera's noise model, stored as a
 *                  capture and scored by srv_evaluate, next to the pipeline's answers for the
 *                  same lights.
 * Writes DIR/accuracy.csv, DIR/accuracy_vs_time.png, DIR/calibration.png and the Markdown
 * report DIR.md (docs/accuracy.md for --out docs/accuracy). Deterministic for the scene's seed
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

#define NBINS 5
static const double bin_edges[NBINS + 1] = {0.0, 0.5, 0.8, 0.95, 0.99, 1.0000001};

typedef struct {
    /* the setting */
    int hard, K, C, hdr, locked, continuous;   /* hard: 0 metro, 1 metro_hard, 2 metro_clear */
    /* results */
    int ok;
    char err[512];
    long acquisitions;
    double delta_s, readout_cycles;
    double exposure_s, readout_s, capture_s;
    double compute_s, sim_s;
    srv_eval_report ev;
    double snr_p90;
    double bin_n[NBINS], bin_conf[NBINS], bin_right[NBINS];
    double ece;
    long oracle_n;                 /* lights of the oracle subset matched to the truth */
    double ours_sub, oracle_sub;   /* right bulb and phase / matched, on that subset */
} point;

static const char *const scene_names[3] = {"metro", "metro_hard", "metro_clear"};

static double now_s(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

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

/* ------------------------------------------------------------------ the scene of a point */

typedef struct {
    int x0, y0, w, h;       /* the window of the scene's image rendered */
} crop;

static void jset(json_t *o, const char *k, json_t *v)
{
    json_object_set_new(o, k, v);
}

/* The metro scene of a point: a crop (smaller sensor, principal point moved: the same camera
 * looking at the same city), the ACam settings, and for the hard variant lower visibility
 * (8 km instead of 20), 5x the turbulence (Cn2 1e-14) and distractors (two blinking signs and
 * a road of headlights inside the window). */
static gs_status write_scene(const char *base, const point *p, const crop *c, const char *path,
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

/* ------------------------------------------------------------------ one point */

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Store rows[0..n) as a capture of the point's survey under key, and evaluate that capture. */
static gs_status eval_subset(srv_db *db, int64_t survey_id, const char *key, const srv_light_row *rows,
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

#define ORACLE_PHASES_MAX 12

static gs_status run_point(const char *base, const crop *cr, const char *work, int n_oracle,
                           const gs_delight *dl, point *p)
{
    char dir[4096], scene[4200], dbp[4200], capdir[4200];   /* paths stay below 4096 */
    int len = snprintf(dir, sizeof dir, "%s/%s-K%d-C%d-%s-%s-%s", work, scene_names[p->hard], p->K, p->C,
                       p->hdr ? "hdr" : "nohdr", p->locked ? "locked" : "free", p->continuous ? "cont" : "ph3");
    if (len < 0 || (size_t)len >= sizeof dir - 32) return gs_fail(GS_EINVAL, "%s: work directory path too long", work);
    rm_rf(dir);
    gs_status s = mkdir_p(dir);
    if (s != GS_OK) return s;
    snprintf(scene, sizeof scene, "%s/scene.json", dir);
    snprintf(dbp, sizeof dbp, "%s/survey.sqlite", dir);
    snprintf(capdir, sizeof capdir, "%s/capture", dir);
    double grid_hz = 50, transformer = 30;
    if ((s = write_scene(base, p, cr, scene, &p->readout_cycles, &grid_hz, &transformer)) != GS_OK) return s;
    p->delta_s = 1.0 / (2.0 * grid_hz);

    /* the pipeline, as `gridsurvey run` */
    srv_run_opts ro;
    srv_run_opts_default(&ro);
    ro.input = scene;
    ro.db_path = dbp;
    ro.capture_dir = capdir;
    if (p->continuous) ro.eq7.phases = REC_PHASES_CONTINUOUS;
    srv_run_report rr;
    if ((s = srv_run(&ro, &rr)) != GS_OK) return s;
    p->sim_s = rr.seconds[SRV_STAGE_CAPTURE];
    p->compute_s = rr.seconds[SRV_STAGE_BLOBS] + rr.seconds[SRV_STAGE_MATCH] + rr.seconds[SRV_STAGE_LOCATE];
    if ((s = read_acquisitions(capdir, &p->acquisitions)) != GS_OK) return s;
    p->exposure_s = (double)p->acquisitions * p->C * p->delta_s;
    p->readout_s = (double)p->acquisitions * p->readout_cycles * p->delta_s;
    p->capture_s = p->exposure_s + p->readout_s;

    srv_db *db = NULL;
    gs_capture cap;
    memset(&cap, 0, sizeof cap);
    rec_catalog cat;
    memset(&cat, 0, sizeof cat);
    rec_matcher *m = NULL;
    rec_match *mt = NULL;
    srv_light_row *rows = NULL, *sub = NULL;
    double *snr = NULL, *tab = NULL, *x = NULL;
    int *npix = NULL;
    rec_pg_noise *nz = NULL;
    if ((s = srv_db_open(dbp, SRV_DB_WRITE, &db)) != GS_OK) goto done;
    srv_eval_opts eo;
    srv_eval_opts_default(&eo);
    if ((s = srv_evaluate(db, rr.truth_path, &eo, &p->ev)) != GS_OK) goto done;

    /* the same lights again (deterministic: the pipeline's catalog and answers), with the
     * aperture of each for the oracle's noise model */
    if ((s = gs_capture_read(capdir, &cap)) != GS_OK) goto done;
    rec_blob_opts bo;
    rec_blob_opts_default(&bo);
    bo.threshold_sigma = ro.threshold_sigma;
    bo.labels = 1;
    if ((s = rec_blobs_extract(&cap, &bo, &cat)) != GS_OK) goto done;
    if (cat.count != rr.lights) {
        s = gs_fail(GS_ENUMERIC, "%s: %zu lights extracted again, the pipeline stored %zu", capdir,
                    cat.count, rr.lights);
        goto done;
    }
    size_t n = cat.count;
    int K = cat.K, B = cat.bands, D = K * B;
    mt = calloc(n ? n : 1, sizeof *mt);
    rows = calloc(n ? n : 1, sizeof *rows);
    sub = calloc(n ? n : 1, sizeof *sub);
    snr = calloc(n ? n : 1, sizeof *snr);
    npix = calloc(n ? n : 1, sizeof *npix);
    x = calloc((size_t)D, sizeof *x);
    nz = calloc((size_t)D, sizeof *nz);
    if (!mt || !rows || !sub || !snr || !npix || !x || !nz) {
        s = gs_fail(GS_ENOMEM, "bench accuracy: out of memory");
        goto done;
    }
    if ((s = rec_matcher_new(dl, cap.grid_hz, B, K, &ro.eq7, &m)) != GS_OK) goto done;
    if ((s = rec_match_catalog(m, &cat, mt)) != GS_OK) goto done;
    size_t with_bulb = 0;
    for (size_t i = 0; i < n; i++) {
        srv_light_row_init(&rows[i]);
        srv_light_from_catalog(&rows[i], &cat, i);
        srv_light_from_match(&rows[i], &mt[i], m);
        snr[i] = rows[i].snr;
        with_bulb += rows[i].bulb_id != NULL;
    }
    if (with_bulb != rr.with_bulb) {
        s = gs_fail(GS_ENUMERIC, "%s: %zu lights with a bulb again, the pipeline stored %zu", capdir,
                    with_bulb, rr.with_bulb);
        goto done;
    }
    if (n) {
        qsort(snr, n, sizeof *snr, cmp_double);
        double pos = 0.9 * (double)(n - 1);
        size_t i0 = (size_t)floor(pos);
        p->snr_p90 = i0 + 1 < n ? snr[i0] + (pos - (double)i0) * (snr[i0 + 1] - snr[i0]) : snr[n - 1];
    }

    /* calibration: the answered lights by reported confidence, one capture per bin */
    double ece_num = 0, ece_den = 0;
    for (int b = 0; b < NBINS; b++) {
        size_t k = 0;
        double conf = 0;
        for (size_t i = 0; i < n; i++) {
            if (mt[i].bulb < 0 || !(mt[i].confidence >= bin_edges[b] && mt[i].confidence < bin_edges[b + 1])) continue;
            sub[k] = rows[i];
            sub[k].index = (int)k;
            conf += mt[i].confidence;
            k++;
        }
        if (!k) continue;
        char key[64];
        snprintf(key, sizeof key, "calibration-bin-%d", b);
        srv_eval_report ev;
        if ((s = eval_subset(db, rr.survey_id, key, sub, k, rr.truth_path, &ev)) != GS_OK) goto done;
        /* the bin's matched lights; its mean confidence over all of its lights */
        p->bin_n[b] = (double)ev.matched;
        p->bin_conf[b] = conf / (double)k * (double)ev.matched;
        p->bin_right[b] = (double)ev.all_correct;
        if (ev.matched) {
            ece_num += fabs((double)ev.all_correct - p->bin_conf[b]);
            ece_den += (double)ev.matched;
        }
    }
    p->ece = ece_den > 0 ? ece_num / ece_den : NAN;

    /* the oracle: templates of the matcher's voltage-referenced bulbs at the grid's phases
     * (0/120/240 and the same + the transformer's shift: the truth's phase set) */
    if (cap.gain_e_per_dn > 0 && n_oracle > 0) {
        double phases[6] = {0, 120, 240, fmod(transformer + 360.0, 360.0), fmod(transformer + 480.0, 360.0),
                            fmod(transformer + 600.0, 360.0)};
        size_t nb = rec_matcher_bulb_count(m);
        int M = 0;
        tab = malloc(sizeof *tab * nb * 6 * (size_t)D);
        int *tb = malloc(sizeof *tb * nb * 6);
        double *tp = malloc(sizeof *tp * nb * 6);
        if (!tab || !tb || !tp) {
            free(tb);
            free(tp);
            s = gs_fail(GS_ENOMEM, "bench accuracy: out of memory for the oracle");
            goto done;
        }
        for (size_t b = 0; b < nb && s == GS_OK; b++) {
            const gs_bulb *bu = rec_matcher_bulb(m, b);
            if (bu->ref != GS_REF_VOLTAGE) continue;
            for (int ph = 0; ph < 6 && s == GS_OK; ph++) {
                double *t = tab + (size_t)M * (size_t)D;
                s = gs_brf_integrate(&bu->brf, gs_phase_to_shift(phases[ph]), K, t);
                for (int d = 0; d < D; d++) t[d] *= bu->chroma[d / K];
                tb[M] = (int)b;
                tp[M] = phases[ph];
                M++;
            }
        }
        /* aperture sizes */
        for (size_t q = 0; q < (size_t)cat.width * (size_t)cat.height; q++)
            if (cat.labels[q] >= 0 && (size_t)cat.labels[q] < n) npix[cat.labels[q]]++;
        /* the subset: unflagged lights (no saturation, HDR, edge or deblending), evenly spaced */
        size_t eligible = 0;
        const unsigned bad = REC_BLOB_EDGE | REC_BLOB_SATURATED | REC_BLOB_DEBLENDED | REC_BLOB_HDR | REC_BLOB_NO_SIGNAL;
        for (size_t i = 0; i < n; i++) eligible += !(cat.flags[i] & bad) && npix[i] > 0;
        size_t want = eligible < (size_t)n_oracle ? eligible : (size_t)n_oracle, seen = 0, k = 0;
        srv_light_row *orc = calloc(want ? want : 1, sizeof *orc);
        if (!orc) s = gs_fail(GS_ENOMEM, "bench accuracy: out of memory");
        double r2 = gs_capture_noise(&cap).read_var_dn2;
        for (size_t i = 0; i < n && k < want && s == GS_OK; i++) {
            if ((cat.flags[i] & bad) || npix[i] <= 0) continue;
            if (seen++ != k * eligible / want) continue;
            /* the camera's noise of an aperture sum of npix pixels, in DN per cycle: Poisson
             * electrons (gain_e_per_dn * cycles per unit), read + quantisation noise of npix
             * pixels, and the background's electrons: the shot part of the extractor's sigma
             * (which is shot + read + background estimate) less the light's own, per band */
            for (int band = 0; band < B; band++) {
                double bg = 0;
                for (int kk = 0; kk < K; kk++) {
                    int d = band * K + kk;
                    double c = cap.frames[kk].cycles, g = cap.gain_e_per_dn * c;
                    double sig = cat.sigma[i * (size_t)D + (size_t)d];
                    x[d] = cat.signal[i * (size_t)D + (size_t)d];
                    double tot_e = (sig * sig * c * c - npix[i] * r2) * cap.gain_e_per_dn * cap.gain_e_per_dn;
                    bg += (tot_e - x[d] * g) / K;
                    nz[d].gain = g;
                    nz[d].read_dn = sqrt(npix[i] * r2) / c;
                }
                for (int kk = 0; kk < K; kk++) nz[band * K + kk].bg_e = bg > 0 ? bg : 0;
            }
            int best = 0;
            if ((s = rec_ml_oracle(nz, 1, x, tab, M, D, &best, NULL)) != GS_OK) break;
            const gs_bulb *bu = rec_matcher_bulb(m, (size_t)tb[best]);
            sub[k] = rows[i];
            sub[k].index = (int)k;
            orc[k] = rows[i];
            orc[k].index = (int)k;
            orc[k].bulb_id = bu->id;
            orc[k].technology = gs_tech_name(bu->type);
            orc[k].phase_deg = tp[best];
            orc[k].phase_fit_deg = tp[best];
            orc[k].confidence = orc[k].bulb_confidence = orc[k].phase_confidence = 1.0;
            orc[k].runner_bulb_id = NULL;
            orc[k].runner_phase_deg = NAN;
            orc[k].runner_confidence = 0;
            orc[k].match_flags = 0;
            k++;
        }
        free(tb);
        free(tp);
        srv_eval_report eo1, eo2;
        if (s == GS_OK && k) s = eval_subset(db, rr.survey_id, "oracle-subset-pipeline", sub, k, rr.truth_path, &eo1);
        if (s == GS_OK && k) s = eval_subset(db, rr.survey_id, "oracle-subset-oracle", orc, k, rr.truth_path, &eo2);
        free(orc);
        if (s != GS_OK) goto done;
        if (k) {
            p->oracle_n = eo1.matched;
            p->ours_sub = eo1.matched ? (double)eo1.all_correct / (double)eo1.matched : NAN;
            p->oracle_sub = eo2.matched ? (double)eo2.all_correct / (double)eo2.matched : NAN;
        } else {
            p->ours_sub = p->oracle_sub = NAN;
        }
    } else {
        p->ours_sub = p->oracle_sub = NAN;
    }
done:
    free(nz);
    free(x);
    free(tab);
    free(npix);
    free(snr);
    free(sub);
    free(rows);
    free(mt);
    rec_matcher_free(m);
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
    srv_db_close(db);
    return s;
}

/* ------------------------------------------------------------------ output */

static const char *ph_name(const point *p)
{
    return p->continuous ? "continuous" : "3";
}

static void fmt_num(char *b, size_t n, double v, const char *f)
{
    if (isfinite(v)) snprintf(b, n, f, v);
    else snprintf(b, n, "-");
}

static gs_status write_csv(const char *path, const point *pts, size_t np)
{
    FILE *f = fopen(path, "w");
    if (!f) return gs_fail(GS_EIO, "%s: cannot write: %s", path, strerror(errno));
    fprintf(f, "scene,K,C,hdr,locked,phases,acquisitions,exposure_s,readout_s,capture_s,compute_s,"
               "truth_lights,stored,matched,detection_rate,false_rate,bulb_accuracy,phase_accuracy,"
               "right_rate,bulb_unknown_rate,loc_median_m,loc_p95_m,snr_p90,ece,oracle_lights,"
               "pipeline_on_oracle_lights,oracle_accuracy\n");
    for (size_t i = 0; i < np; i++) {
        const point *p = &pts[i];
        if (!p->ok) continue;
        fprintf(f, "%s,%d,%d,%d,%d,%s,%ld,%.2f,%.2f,%.2f,%.3f,%ld,%ld,%ld,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,"
                   "%.2f,%.2f,%.2f,%.4f,%ld,%.4f,%.4f\n",
                scene_names[p->hard], p->K, p->C, p->hdr, p->locked, ph_name(p), p->acquisitions,
                p->exposure_s, p->readout_s, p->capture_s, p->compute_s, p->ev.truth_in_image, p->ev.stored,
                p->ev.matched, p->ev.detection_rate, p->ev.false_rate, p->ev.bulb_accuracy,
                p->ev.phase_accuracy, p->ev.all_correct_rate, p->ev.bulb_unknown_rate, p->ev.loc_median_m,
                p->ev.loc_p95_m, p->snr_p90, p->ece, p->oracle_n, p->ours_sub, p->oracle_sub);
    }
    int bad = ferror(f);
    if (fclose(f) != 0 || bad) return gs_fail(GS_EIO, "%s: write failed", path);
    return GS_OK;
}

/* The accuracy figure: per scene, right bulb and phase among detected lights (solid: the
 * pipeline; dashed: the oracle on its subset) and the detection rate, against capture seconds
 * (log), one curve per K. Curves use the main grid (HDR, locked, 3 phases). */
static const int kcolor[3] = {2, 3, 4};

static void plot_accuracy(const char *path, const point *pts, size_t np, const int *Ks, int nK)
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
    for (int hard = 0; hard < 3; hard++)
        for (int panel = 0; panel < 2; panel++) {
            pladv(0);
            plvpor(0.16, 0.95, 0.14, 0.88);
            plwind(lx0, lx1, 0.0, 1.0);
            plcol0(1);
            plwidth(1.0);
            plbox("bcnstlg", 0, 0, "bcnstvg", 0.2, 2);
            char top[128];
            snprintf(top, sizeof top, "%s: %s", scene_names[hard],
                     panel ? "detection rate" : "right bulb and phase (of detected)");
            pllab("capture time, s (ACam: A (C + R) #gD)", panel ? "detected / in image" : "accuracy", top);
            for (int ki = 0; ki < nK; ki++) {
                double xs[64], ys[64], yo[64];
                int m = 0, mo = 0;
                double xo[64];
                for (size_t i = 0; i < np && m < 64; i++) {
                    const point *p = &pts[i];
                    if (!p->ok || p->hard != hard || p->K != Ks[ki] || !p->hdr || !p->locked || p->continuous) continue;
                    double acc = p->ev.matched ? (double)p->ev.all_correct / (double)p->ev.matched : NAN;
                    double y = panel ? p->ev.detection_rate : acc;
                    if (isfinite(y)) {
                        xs[m] = log10(p->capture_s);
                        ys[m++] = y;
                    }
                    if (!panel && isfinite(p->oracle_sub)) {
                        xo[mo] = log10(p->capture_s);
                        yo[mo++] = p->oracle_sub;
                    }
                }
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
            }
            /* legend */
            const char *labels[4];
            char text[4][64];
            PLINT opts[4], colors[4], styles[4];
            PLFLT widths[4];
            int nl = 0;
            for (int ki = 0; ki < nK && nl < 3; ki++) {
                snprintf(text[nl], sizeof text[nl], "K = %d", Ks[ki]);
                labels[nl] = text[nl];
                opts[nl] = PL_LEGEND_LINE;
                colors[nl] = kcolor[ki % 3];
                styles[nl] = 1;
                widths[nl] = 2.0;
                nl++;
            }
            if (!panel) {
                snprintf(text[nl], sizeof text[nl], "ML oracle (dashed)");
                labels[nl] = text[nl];
                opts[nl] = PL_LEGEND_LINE;
                colors[nl] = 1;
                styles[nl] = 2;
                widths[nl] = 2.0;
                nl++;
            }
            PLFLT lw, lh;
            pllegend(&lw, &lh, PL_LEGEND_BACKGROUND | PL_LEGEND_BOUNDING_BOX, PL_POSITION_BOTTOM | PL_POSITION_RIGHT | PL_POSITION_INSIDE,
                     0.02, 0.03, 0.1, 0, 1, 1, nl, 1, nl, opts, 0.8, 0.6, 2.0, 0.0, colors, (const char *const *)labels,
                     NULL, NULL, NULL, NULL, colors, styles, widths, NULL, NULL, NULL, NULL);
        }
    plend();
}

/* Calibration: per scene, accuracy of the stored lights against their reported confidence
 * (bins pooled over the main grid), with the diagonal. */
static void plot_calibration(const char *path, const point *pts, size_t np)
{
    plsdev("pngcairo");
    plsfnam(path);
    plsetopt("geometry", "800x700");
    plscmap0n(8);
    plscol0(0, 255, 255, 255);
    plscol0(1, 0, 0, 0);
    plscol0(2, 31, 119, 180);
    plscol0(3, 214, 39, 40);
    plscol0(4, 44, 160, 44);
    plscol0(5, 150, 150, 150);
    plstar(1, 1);
    pladv(0);
    plvpor(0.12, 0.95, 0.12, 0.90);
    plwind(0, 1, 0, 1);
    plcol0(1);
    plbox("bcnstg", 0.2, 2, "bcnstvg", 0.2, 2);
    pllab("reported confidence (bin mean)", "right bulb and phase", "calibration: stored lights by confidence");
    double dx[2] = {0, 1}, dy[2] = {0, 1};
    plcol0(5);
    pllsty(2);
    plline(2, dx, dy);
    pllsty(1);
    for (int hard = 0; hard < 3; hard++) {
        double n[NBINS] = {0}, c[NBINS] = {0}, r[NBINS] = {0};
        for (size_t i = 0; i < np; i++) {
            const point *p = &pts[i];
            if (!p->ok || p->hard != hard) continue;
            for (int b = 0; b < NBINS; b++) {
                n[b] += p->bin_n[b];
                c[b] += p->bin_conf[b];
                r[b] += p->bin_right[b];
            }
        }
        double xs[NBINS], ys[NBINS];
        int m = 0;
        for (int b = 0; b < NBINS; b++)
            if (n[b] > 0) {
                xs[m] = c[b] / n[b];
                ys[m++] = r[b] / n[b];
            }
        plcol0(2 + hard);
        plwidth(2.0);
        if (m > 1) plline(m, xs, ys);
        if (m > 0) plpoin(m, xs, ys, 17);
    }
    const char *labels[3] = {"metro", "metro_hard", "metro_clear"};
    PLINT opts[3] = {PL_LEGEND_LINE, PL_LEGEND_LINE, PL_LEGEND_LINE}, colors[3] = {2, 3, 4}, styles[3] = {1, 1, 1};
    PLFLT widths[3] = {2, 2, 2}, lw, lh;
    pllegend(&lw, &lh, PL_LEGEND_BACKGROUND | PL_LEGEND_BOUNDING_BOX, PL_POSITION_TOP | PL_POSITION_LEFT | PL_POSITION_INSIDE,
             0.03, 0.03, 0.1, 0, 1, 1, 3, 1, 3, opts, 0.8, 0.6, 2.0, 0.0, colors, labels, NULL, NULL, NULL, NULL,
             colors, styles, widths, NULL, NULL, NULL, NULL);
    plend();
}

static double right_of_detected(const point *p)
{
    return p->ev.matched ? (double)p->ev.all_correct / (double)p->ev.matched : NAN;
}

static const point *find_pt(const point *pts, size_t np, int hard, int K, int C)
{
    for (size_t i = 0; i < np; i++)
        if (pts[i].ok && pts[i].hard == hard && pts[i].K == K && pts[i].C == C && pts[i].hdr &&
            pts[i].locked && !pts[i].continuous)
            return &pts[i];
    return NULL;
}

static void delta_line(FILE *f, const char *what, const point *a, const point *r)
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

static gs_status write_doc(const char *path, const char *out, const char *base, const crop *cr, int quick,
                           const point *pts, size_t np, double wall, const int *Ks, int nK)
{
    FILE *f = fopen(path, "w");
    if (!f) return gs_fail(GS_EIO, "%s: cannot write: %s", path, strerror(errno));
    const char *leaf = strrchr(out, '/') ? strrchr(out, '/') + 1 : out;
    fprintf(f, "# What accuracy costs in time (`gridsurvey bench accuracy%s`)\n\n", quick ? " --quick" : "");
    fprintf(f, "Generated by `gridsurvey bench accuracy%s --out %s` (survey/bench_accuracy.c), which "
               "wrote this file, `%s/accuracy.csv` and the plots. Reproduce:\n\n"
               "    make build/gridsurvey\n    build/gridsurvey bench accuracy --out docs/accuracy    # also run by `make bench`\n\n"
               "Every number is deterministic given the scene's seed (the simulator, the pipeline and the "
               "oracle are), **except the compute times**, which are measured on the machine running it. "
               "This run took %.0f s of wall time.\n\n",
            quick ? " --quick" : "", out, leaf, wall);
    fprintf(f, "## What is swept\n\n"
               "Scene: `%s`, rendered through a %d x %d window of its %s image (pixels %d..%d x %d..%d: "
               "the same camera with the principal point moved, so the simulator only renders the lights "
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
               "bins %s; each bin is stored as its own capture and scored by `srv_evaluate`).\n"
               "- **oracle**: `rec_ml_oracle` (recognize/ml_oracle.c: the exact Poisson-Gaussian "
               "maximum-likelihood decision, brute force over every bulb at the six phases 0/120/240 and "
               "+30 deg, the truth's phase set) on the extracted signals of up to %d unflagged lights "
               "(no saturation, HDR, edge or deblending) per point, with the camera's noise model "
               "(gain x cycles electrons per DN/cycle, read and quantisation noise of the aperture's "
               "pixels, the background electrons from the extractor's sigma); *pipeline* is the "
               "pipeline's answers for the same lights (right bulb and phase / matched). The oracle "
               "knows neither scintillation nor extinction (they are not camera noise), so where they "
               "dominate it is an optimum for the camera, not for the atmosphere.\n\n",
            "[0, 0.5), [0.5, 0.8), [0.8, 0.95), [0.95, 0.99), [0.99, 1]", quick ? 8 : 40);
    fprintf(f, "## Table\n\n");
    fprintf(f, "| scene | K | C | HDR | lock | phases | A | capture s | compute s | det. | false | bulb | phase | "
               "unkn. | right/det. | right/all | loc. m (med / p95) | SNR90 | ECE | oracle lights | pipeline | oracle |\n");
    fprintf(f, "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for (size_t i = 0; i < np; i++) {
        const point *p = &pts[i];
        if (!p->ok) {
            fprintf(f, "| %s | %d | %d | %s | %s | %s | failed: %s |||||||||||||||\n", scene_names[p->hard],
                    p->K, p->C, p->hdr ? "on" : "off", p->locked ? "locked" : "free", ph_name(p), p->err);
            continue;
        }
        char b[16][32];
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
        fmt_num(b[10], 32, p->ece, "%.3f");
        fmt_num(b[11], 32, 100 * p->ours_sub, "%.1f %%");
        fmt_num(b[12], 32, 100 * p->oracle_sub, "%.1f %%");
        fprintf(f, "| %s | %d | %d | %s | %s | %s | %ld | %.1f | %.2f | %s | %s | %s | %s | %s | %s | %s | %s / %s | %s | %s | "
                   "%ld | %s | %s |\n",
                scene_names[p->hard], p->K, p->C, p->hdr ? "on" : "off", p->locked ? "locked" : "free",
                ph_name(p), p->acquisitions, p->capture_s, p->compute_s, b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7],
                b[8], b[9], b[10], p->oracle_n, b[11], b[12]);
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
               "table rows on metro_clear at K = 26.\n\n"
               "![calibration](%s/calibration.png)\n\nAccuracy of the answered lights against their reported "
               "confidence, pooled over every point of each scene; the dashed line is perfect calibration.\n\n",
            leaf, leaf);

    /* the recommendation, from the metro curves */
    fprintf(f, "## Recommendation\n\n");
    const point *best = NULL, *rec = NULL;
    int rs = 0;   /* the scene the rule runs on: metro, or metro_clear when metro yields nothing */
    for (int pass = 0; pass < 2 && (!best || best->ev.all_correct_rate < 0.05); pass++) {
        rs = pass ? 2 : 0;
        best = NULL;
        for (size_t i = 0; i < np; i++) {
            const point *p = &pts[i];
            if (!p->ok || p->hard != rs || !p->hdr || !p->locked || p->continuous || !isfinite(p->ev.all_correct_rate)) continue;
            if (!best || p->ev.all_correct_rate > best->ev.all_correct_rate) best = p;
        }
    }
    if (best) {
        for (size_t i = 0; i < np; i++) {
            const point *p = &pts[i];
            if (!p->ok || p->hard != rs || !p->hdr || !p->locked || p->continuous || !isfinite(p->ev.all_correct_rate)) continue;
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
                scene_names[rs], 100 * best->ev.all_correct_rate, best->K, best->C, best->capture_s);
        fprintf(f, "**Default for a city survey: K = %d, C = %d** (%ld acquisitions, %.0f s per capture): %.1f %% of "
                   "the lights in view found with the right bulb and phase, %.1f %% of the detected ones right, "
                   "detection %.1f %%, location error %.1f m median / %.1f m at the 95th percentile, "
                   "%.2f s of compute for the window.\n\n",
                rec->K, rec->C, rec->acquisitions, rec->capture_s, 100 * rec->ev.all_correct_rate,
                100 * right_of_detected(rec), 100 * rec->ev.detection_rate, rec->ev.loc_median_m, rec->ev.loc_p95_m,
                rec->compute_s);
        delta_line(f, "Halving the capture time", find_pt(pts, np, rs, rec->K, rec->C / 2), rec);
        delta_line(f, "Doubling the capture time", find_pt(pts, np, rs, rec->K, rec->C * 2), rec);
        const point *h = find_pt(pts, np, 1, rec->K, rec->C);
        if (h)
            fprintf(f, "- **In bad seeing** (metro_hard at the same setting): %.1f %% found right, %.1f %% of the "
                       "detected right, detection %.1f %%.\n",
                    100 * h->ev.all_correct_rate, 100 * right_of_detected(h), 100 * h->ev.detection_rate);
        for (int ki = 0; ki < nK; ki++) {
            if (Ks[ki] == rec->K) continue;
            const point *o = find_pt(pts, np, rs, Ks[ki], rec->C);
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

/* ------------------------------------------------------------------ main */

static const char acc_usage[] =
    "usage: gridsurvey bench accuracy [--quick] [--out DIR] [--scene FILE] [--keep]\n"
    "\n"
    "Sweeps the ACam acquisition (cycles per frame C, windows K, HDR, locked / free running, Eq. 7\n"
    "phase set) on a window of the metro scene and a hard variant, runs the survey pipeline on each\n"
    "point and scores it against the simulator's truth, next to the maximum-likelihood oracle.\n"
    "Writes DIR/accuracy.csv, DIR/accuracy_vs_time.png, DIR/calibration.png and DIR.md\n"
    "(default DIR: build/accuracy). --quick: a few points on a small window (seconds).\n"
    "--scene: the base scene (capture/scenes/metro.json). --keep: keep the work directory.\n";

int srv_bench_accuracy(int argc, char **argv)
{
    static const struct option longs[] = {{"quick", no_argument, 0, 'q'}, {"out", required_argument, 0, 'o'},
                                          {"scene", required_argument, 0, 's'}, {"keep", no_argument, 0, 'k'},
                                          {"help", no_argument, 0, 'h'}, {0, 0, 0, 0}};
    int quick = 0, keep = 0, c;
    const char *out = "build/accuracy", *base = "capture/scenes/metro.json";
    optind = 1;
    opterr = 0;
    while ((c = getopt_long(argc, argv, "ho:", longs, NULL)) != -1) {
        if (c == 'q') quick = 1;
        else if (c == 'o') out = optarg;
        else if (c == 's') base = optarg;
        else if (c == 'k') keep = 1;
        else if (c == 'h') {
            fputs(acc_usage, stdout);
            return 0;
        } else {
            fprintf(stderr, "gridsurvey bench accuracy: bad option '%s' (see --help)\n", argv[optind - 1]);
            return 2;
        }
    }
    if (optind != argc) {
        fprintf(stderr, "gridsurvey bench accuracy: unexpected argument '%s' (see --help)\n", argv[optind]);
        return 2;
    }
    openblas_set_num_threads(1);
    double t_start = now_s();
    gs_status s = mkdir_p(out);
    if (s != GS_OK) return srv_error(s);
    char work[4096];
    const char *tmp = getenv("TMPDIR");
    snprintf(work, sizeof work, "%s/gs-accuracy-XXXXXX", tmp && *tmp ? tmp : "/tmp");
    if (!mkdtemp(work)) return srv_error(gs_fail(GS_EIO, "%s: cannot create: %s", work, strerror(errno)));

    /* the sweep: the main grid (HDR, locked, 3 phases) over K and C on both scenes, then the
     * variants at K = 26 on metro */
    crop cr = quick ? (crop){720, 390, 160, 120} : (crop){600, 338, 400, 225};
    static const int Ks_full[] = {8, 13, 26}, Cs_full[] = {32, 64, 128, 256, 512, 1024};
    static const int Ks_quick[] = {8}, Cs_quick[] = {32, 64};
    const int *Ks = quick ? Ks_quick : Ks_full, *Cs = quick ? Cs_quick : Cs_full;
    int nK = quick ? 1 : 3, nC = quick ? 2 : 6;
    size_t cap_pts = 128, np = 0;
    point *pts = calloc(cap_pts, sizeof *pts);
    if (!pts) return srv_error(gs_fail(GS_ENOMEM, "out of memory"));
    for (int hard = 0; hard < (quick ? 1 : 3); hard++)
        for (int ki = 0; ki < nK; ki++)
            for (int ci = 0; ci < nC; ci++)
                if (hard != 1 || Ks[ki] != 13)   /* metro_hard: K = 8 and 26 only (time) */
                    pts[np++] = (point){.hard = hard, .K = Ks[ki], .C = Cs[ci], .hdr = 1, .locked = 1};
    if (!quick) {
        static const int Cv[] = {128, 512};
        for (int v = 0; v < 3; v++)
            for (int ci = 0; ci < 2; ci++)
                pts[np++] = (point){.hard = 2, .K = 26, .C = Cv[ci], .hdr = v != 0, .locked = v != 1, .continuous = v == 2};
    } else {
        pts[np++] = (point){.hard = 2, .K = 8, .C = 64, .hdr = 1, .locked = 1};
        pts[np++] = (point){.K = 8, .C = 64, .hdr = 0, .locked = 1};
    }
    gs_delight *dl = gs_delight_new();
    s = dl ? gs_delight_generate(dl, GS_BRF_N_DEFAULT) : gs_fail(GS_ENOMEM, "out of memory");
    if (s != GS_OK) {
        gs_delight_free(dl);
        free(pts);
        return srv_error(s);
    }
    int failed = 0;
    for (size_t i = 0; i < np; i++) {
        point *p = &pts[i];
        double t0 = now_s();
        s = run_point(base, &cr, work, quick ? 8 : 40, dl, p);
        p->ok = s == GS_OK;
        if (!p->ok) {
            snprintf(p->err, sizeof p->err, "%s: %s", gs_strerror(s), gs_detail());
            failed++;
        }
        fprintf(stderr, "bench accuracy: %s K=%d C=%d hdr=%d locked=%d phases=%s: %s (%.1f s)\n",
                scene_names[p->hard], p->K, p->C, p->hdr, p->locked, ph_name(p),
                p->ok ? "ok" : p->err, now_s() - t0);
        if (!keep) rm_rf(work), mkdir(work, 0700);
    }
    gs_delight_free(dl);
    char path[4400];
    snprintf(path, sizeof path, "%s/accuracy.csv", out);
    s = write_csv(path, pts, np);
    if (s == GS_OK) {
        snprintf(path, sizeof path, "%s/accuracy_vs_time.png", out);
        plot_accuracy(path, pts, np, Ks, nK);
        snprintf(path, sizeof path, "%s/calibration.png", out);
        plot_calibration(path, pts, np);
        char doc[4400];
        size_t len = strlen(out);
        while (len > 1 && out[len - 1] == '/') len--;
        snprintf(doc, sizeof doc, "%.*s.md", (int)len, out);
        s = write_doc(doc, out, base, &cr, quick, pts, np, now_s() - t_start, Ks, nK);
    }
    if (!keep) rm_rf(work);
    else fprintf(stderr, "bench accuracy: work directory kept: %s\n", work);
    free(pts);
    if (s != GS_OK) return srv_error(s);
    fprintf(stderr, "bench accuracy: %zu points (%d failed) in %.0f s\n", np, failed, now_s() - t_start);
    return failed ? 1 : 0;
}
