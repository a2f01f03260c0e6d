/* bench.c - `gridsurvey bench`: performance tables as Markdown (make bench writes docs/bench-*.md).
 *   bench recognize [--quick]  Eq. 7 throughput (paper Sec. 4): rec_match_pixels in pixels/s and
 *                              rec_match_catalog in lights/s against K, bands, database size and
 *                              pixel count, next to a plain triple-loop reference of the same
 *                              search written here (independent of recognize/eq7_*.c), with the
 *                              agreement of the two and each configuration's peak memory.
 *   bench db ...               the survey database (survey/bench_db.c).
 *   bench pg ...               SQLite vs the shared PostGIS database (survey/bench_pg.c).
 * One core: OpenBLAS runs single-threaded (openblas_set_num_threads(1)). Each configuration runs
 * in a child process so that its peak resident set (VmHWM) is its own. */
#include "survey/internal.h"

#include <cblas.h>
#include <getopt.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

static const char bench_usage[] =
    "usage: gridsurvey bench recognize [--quick] [--lights | --captures] [--numpy SCRIPT]   Eq. 7 throughput tables (Markdown)\n"
    "       gridsurvey bench db [--quick] ...       survey database tables (bench db --help)\n"
    "       gridsurvey bench pg --pg CONNINFO ...   SQLite vs PostGIS: push and stats (bench pg --help)\n"
    "       gridsurvey bench render [SCENE]         simulator time per effect (bench render --help)\n"
    "       gridsurvey bench blobs CAPDIR           blob extraction time, without and with the PSF fit\n"
    "       gridsurvey bench accuracy [--quick] ... accuracy against capture time (bench accuracy --help;\n"
    "                                               --drift-sweep: free running, docs/accuracy-drift.md)\n"
    "       gridsurvey bench transport [--quick]    light-transport unmixing time (docs/bench-transport.md)\n"
    "\n"
    "bench recognize: rec_match_pixels (pixels/s) and rec_match_catalog (lights/s) against K,\n"
    "bands, DELIGHT size and pixel count, one core, next to a plain triple-loop reference of the\n"
    "same search; --quick runs a small subset (seconds); --lights only the per-light tables\n"
    "(rec_match_catalog); --captures only the whole-capture table (rec_pixel_maps_compute and\n"
    "rec_blobs_extract); --numpy SCRIPT also times the NumPy\n"
    "implementation of that search on the 1-megapixel rows (survey/bench_eq7_numpy.py).\n"
    "\n"
    "Examples:\n"
    "  gridsurvey bench recognize --quick --numpy survey/bench_eq7_numpy.py\n"
    "  gridsurvey bench db --quick\n"
    "  gridsurvey bench render capture/scenes/lab.json --frames 1\n"
    "  gridsurvey bench blobs build/demo/metro-capture --reps 5\n"
    "  gridsurvey bench accuracy --quick --out-dir build/accuracy-quick\n"
    "  gridsurvey bench transport --quick\n"
    "  gridsurvey bench pg --pg \"host=127.0.0.1 port=5432 dbname=bench\" --max 100000\n";

/* ------------------------------------------------------------------ helpers */

/* The paper's Eq. 7 (one brightness per light with chromaticity templates, no excess noise, the
 * closed world, one light per aperture: no flat share and no nested-model tests): the model the
 * triple-loop reference below implements, so both compute the same thing (with the posterior,
 * which the reference does not). The survey's options have their own rows. */
static void bench_eq7_opts(rec_eq7_opts *eo)
{
    rec_eq7_opts_default(eo);
    eo->band_gains = REC_BANDS_CHROMA;
    eo->model_error = 0.0;
    eo->other_prior = 0.0;
    eo->flat_share = 0.0;
    eo->blend_prior = 0.0;
    eo->nested_tests = 0;
    eo->threads = 1;
}


/* ------------------------------------------------------------------ the reference */

/* Templates of Eq. 7, built here from the bulbs: t[d] = Q_b(band) * (the BRF delayed by the
 * phase's shift, averaged over window k) (Eq. 5), d = band * K + k, for the phases 0/120/240 or a
 * grid of shifts. */
typedef struct {
    size_t M;
    int D;
    int nshift;         /* shifts per bulb (ref_build) */
    double *t;          /* [M * D] */
    double *norm;       /* [M] |t| */
    int *bulb;          /* [M] */
    double *phase;      /* [M] deg */
} ref_templates;

static void ref_free(ref_templates *r)
{
    free(r->t);
    free(r->norm);
    free(r->bulb);
    free(r->phase);
}

/* Templates at nshift shifts per cycle: 3 = the phases 0/120/240 (the discrete search), else the
 * grid of shifts c / nshift (the continuous search's grid, before its refinement). */
static gs_status ref_build(const rec_matcher *m, int K, int nshift, ref_templates *r)
{
    memset(r, 0, sizeof *r);
    size_t nb = rec_matcher_bulb_count(m);
    int bands = rec_matcher_bulb(m, 0)->brf.bands;
    r->D = bands * K;
    r->nshift = nshift;
    r->M = (size_t)nshift * nb;
    r->t = malloc(sizeof *r->t * r->M * (size_t)r->D);
    r->norm = malloc(sizeof *r->norm * r->M);
    r->bulb = malloc(sizeof *r->bulb * r->M);
    r->phase = malloc(sizeof *r->phase * r->M);
    if (!r->t || !r->norm || !r->bulb || !r->phase) {
        ref_free(r);
        return gs_fail(GS_ENOMEM, "bench: cannot allocate reference templates");
    }
    for (size_t b = 0; b < nb; b++) {
        const gs_bulb *bb = rec_matcher_bulb(m, b);
        if (bb->ref != GS_REF_VOLTAGE) {
            ref_free(r);
            return gs_fail(GS_EINVAL, "bench: bulb %s is not voltage-referenced: the reference "
                           "search covers 0/120/240 only", bb->id);
        }
        for (int p = 0; p < nshift; p++) {
            size_t j = (size_t)nshift * b + (size_t)p;
            double *t = r->t + j * (size_t)r->D;
            double s = nshift == 3 ? gs_phase_to_shift(120.0 * p) : (double)p / nshift;
            gs_status st = gs_brf_integrate(&bb->brf, s, K, t);
            if (st != GS_OK) {
                ref_free(r);
                return st;
            }
            double n2 = 0.0;
            for (int band = 0; band < bands; band++)
                for (int k = 0; k < K; k++) {
                    t[band * K + k] *= bb->chroma[band];
                    n2 += t[band * K + k] * t[band * K + k];
                }
            r->norm[j] = sqrt(n2);
            r->bulb[j] = (int)b;
            r->phase[j] = nshift == 3 ? 120.0 * p : gs_shift_to_phase(s);
        }
    }
    return GS_OK;
}

/* The same search, plainly: for every row, every template, every value. w = per-value weights
 * (1/sigma^2). The posterior of (bulb, phase) with the scale marginalised (recognize.h):
 * L = -chi2/2 - log(T)/2 + log Phi(S/sqrt(T)); the answer is the maximum, unless its z = S/sqrt(T)
 * is below min_snr (dim) or its chi2 above the unknown threshold at dof = D - 2. */
static void ref_search(const ref_templates *r, const float *x, const double *w, double min_snr,
                       double chi2_thr, int *bulb, double *phase)
{
    size_t D = (size_t)r->D;
    double Sxx = 0.0;
    for (size_t d = 0; d < D; d++) Sxx += w[d] * (double)x[d] * (double)x[d];
    double best = -INFINITY, bz = 0.0;
    size_t bj = 0;
    for (size_t j = 0; j < r->M; j++) {
        const double *t = r->t + j * D;
        double S = 0.0, T = 0.0;
        for (size_t d = 0; d < D; d++) {
            S += w[d] * (double)x[d] * t[d];
            T += w[d] * t[d] * t[d];
        }
        double z = S / sqrt(T);
        double L = -0.5 * (Sxx - z * z) - 0.5 * log(T) + gs_log_phi(z);
        if (L > best) {
            best = L;
            bj = j;
            bz = z;
        }
    }
    *bulb = -1;
    *phase = 0.0;
    if (!(bz >= min_snr) || Sxx - bz * bz > chi2_thr) return;
    *bulb = r->bulb[bj];
    *phase = r->phase[bj];
}

/* ------------------------------------------------------------------ one configuration */

typedef struct {
    int K, bands, bulbs, continuous;
    size_t pixels;          /* 0: a lights or capture row */
    double lit;
    size_t lights;          /* lights row: lights matched; capture row: lights rendered */
    int side;               /* capture row: a side x side capture through rec_pixel_maps_compute */
    int defaults;           /* lights or pixels row: 1 rec_eq7_opts_default (the survey's options); 2 the
                             * paper's model with the nested-model tests */
    int threads;            /* rec_eq7_opts.threads of the row (0: one) */
    int numpy;              /* pixels row: also time survey/bench_eq7_numpy.py (--numpy) */
} config;

typedef struct {
    int ok;
    char detail[256];
    size_t templates;
    double seconds, rate;          /* rec_match_* */
    double ref_seconds, ref_rate;  /* triple loop, on ref_rows rows */
    size_t ref_rows;
    double agree;                  /* fraction of ref rows with the same answer */
    double sgemm_rate;             /* pixels/s of the SGEMM alone (scores of every template) */
    size_t mapped, matched;        /* capture row: pixels above the threshold, with a bulb */
    double blob_seconds;           /* capture row: rec_blobs_extract */
    long blob_maxrss_kib;          /* (its peak from the resident set before it; -1: cannot tell) */
    int maps_peak_apart;           /* capture row: maxrss_kib is the maps' own (not the rendering's) */
    size_t blobs;                  /* capture row: lights it found */
    double lit_correct;            /* lit rows with the true bulb and phase (fast path) */
    double numpy_rate, numpy_agree;   /* the NumPy search: pixels/s, rows answered as here */
    long maxrss_kib;
} result;

/* The process's peak resident set so far, KiB: VmHWM, which peak_rss_reset can lower
 * (getrusage's ru_maxrss where /proc is not there). */
static long peak_rss_kib(void)
{
    long kib = -1;
    char line[256];
    FILE *f = fopen("/proc/self/status", "r");
    while (f && kib < 0 && fgets(line, sizeof line, f))
        if (!strncmp(line, "VmHWM:", 6)) kib = atol(line + 6);
    if (f) fclose(f);
    if (kib >= 0) return kib;
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    return ru.ru_maxrss;
}

/* Lower the peak to the resident set now (Linux: clear_refs 5); 0 if it cannot. */
static int peak_rss_reset(void)
{
    FILE *f = fopen("/proc/self/clear_refs", "w");
    if (!f) return 0;
    int ok = fputs("5", f) >= 0;
    return fclose(f) == 0 && ok;
}

/* The continuous matcher's grid of shifts per cycle (its templates per bulb: every bulb here is
 * voltage-referenced), the reference's search with continuous phases. */
static int grid_shifts(const rec_matcher *m)
{
    return (int)(rec_matcher_template_count(m) / rec_matcher_bulb_count(m));
}

/* Whether the reference's answer (bulb b, phase) from the templates g is the fast path's (fb,
 * fphase): the same phase (within 1e-3 deg) on 0/120/240; on a grid of G shifts the same shift
 * within one cell (180 / G deg: the matcher refines its best cell to within a cell of it; a shift
 * fixes the phase modulo 180 deg), plus 1e-3 deg for the pixel path's float phases. */
static int ref_agrees(const ref_templates *g, int b, double phase, int fb, double fphase)
{
    if (b != fb) return 0;
    if (b < 0) return 1;
    if (g->nshift == 3) return fabs(phase - fphase) < 1e-3;
    return fabs(remainder(phase - fphase, 180.0)) <= 180.0 / g->nshift + 1e-3;
}

/* A DELIGHT with `count` of d's entries for 50 Hz and this band count, spread evenly over them
 * (the entries come grouped by technology). count 0 = all. */
static gs_status subset(const gs_delight *d, int bands, int count, gs_delight **out)
{
    const char *sensor = bands == 3 ? "rgb" : "photodiode";
    size_t n = 0;
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        n += b->grid_hz == 50 && !strcmp(b->sensor, sensor) && b->ref == GS_REF_VOLTAGE;
    }
    size_t want = count <= 0 || (size_t)count > n ? n : (size_t)count;
    gs_delight *s = gs_delight_new();
    if (!s) return gs_fail(GS_ENOMEM, "bench: cannot allocate a database");
    size_t seen = 0, added = 0;
    for (size_t i = 0; i < gs_delight_count(d) && added < want; i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        if (b->grid_hz != 50 || strcmp(b->sensor, sensor) || b->ref != GS_REF_VOLTAGE) continue;
        /* take entry `seen` when it is the next of want evenly spaced picks */
        if (seen++ != added * n / want) continue;
        gs_status st = gs_delight_add(s, b);
        if (st != GS_OK) {
            gs_delight_free(s);
            return st;
        }
        added++;
    }
    *out = s;
    return GS_OK;
}

#define REF_ROWS_MAX 4096
#define REPS 3              /* timings are the best of REPS runs (the machine may be shared) */
#define LIGHTS_ONE_RUN 1000000  /* a catalog of this many lights is timed once (minutes a run) */
#define SNR 10.0            /* lit rows and lights: mean sample = SNR noise sigmas */
#define POOL (1u << 20)

/* The --numpy script (survey/bench_eq7_numpy.py), NULL without. */
static const char *numpy_script;

/* The same rows through the NumPy implementation of rec_match_pixels' search (the paper's model
 * as the reference; with free_gains the survey's defaults per pixel, free band gains), one core
 * (OPENBLAS_NUM_THREADS=1): its rate and the fraction of rows with the same answer as
 * rec_match_pixels (bulb, phase). Inputs and answers pass through files in a temporary
 * directory. */
static gs_status run_numpy(const ref_templates *r, const float *x, size_t P, double min_snr,
                           double chi2_thr, int free_gains, int bands, const int *bulb,
                           const float *ph, result *res)
{
    char dir[] = "/tmp/gs-bench-numpy-XXXXXX", path[512], cmd[1400];
    if (!mkdtemp(dir)) return gs_fail(GS_EIO, "bench: cannot create a temporary directory");
    size_t D = (size_t)r->D;
    gs_status st = GS_OK;
    FILE *f;
    snprintf(path, sizeof path, "%s/t.f64", dir);
    if (!(f = fopen(path, "wb")) || fwrite(r->t, sizeof *r->t, r->M * D, f) != r->M * D) st = gs_fail(GS_EIO, "bench: %s: cannot write", path);
    if (f) fclose(f);
    snprintf(path, sizeof path, "%s/x.f32", dir);
    if (st == GS_OK && (!(f = fopen(path, "wb")) || fwrite(x, sizeof *x, P * D, f) != P * D)) st = gs_fail(GS_EIO, "bench: %s: cannot write", path);
    if (st == GS_OK && f) fclose(f);
    snprintf(path, sizeof path, "%s/params.txt", dir);
    if (st == GS_OK && (f = fopen(path, "w"))) {
        fprintf(f, "%zu %zu %zu %.17g %.17g %d %s %d\n", r->M, D, P, min_snr, chi2_thr, REPS,
                free_gains ? "free" : "chroma", bands);
        fclose(f);
    }
    snprintf(cmd, sizeof cmd, "OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 /usr/bin/python3 '%s' '%s'", numpy_script, dir);
    if (st == GS_OK && system(cmd) != 0) st = gs_fail(GS_EIO, "bench: %s failed", numpy_script);
    double sec = NAN;
    snprintf(path, sizeof path, "%s/seconds.txt", dir);
    if (st == GS_OK && (!(f = fopen(path, "r")) || fscanf(f, "%lf", &sec) != 1)) st = gs_fail(GS_EIO, "bench: %s: no time", path);
    if (st == GS_OK && f) fclose(f);
    int *ans = st == GS_OK ? malloc(sizeof *ans * P) : NULL;
    snprintf(path, sizeof path, "%s/answers.i32", dir);
    if (st == GS_OK && (!ans || !(f = fopen(path, "rb")) || fread(ans, sizeof *ans, P, f) != P)) st = gs_fail(GS_EIO, "bench: %s: no answers", path);
    if (st == GS_OK && f) fclose(f);
    if (st == GS_OK) {
        size_t same = 0;
        for (size_t p = 0; p < P; p++) {
            int b = ans[p] >= 0 ? r->bulb[ans[p]] : -1;
            same += ref_agrees(r, b, b >= 0 ? r->phase[ans[p]] : 0.0, bulb[p], ph[p]);
        }
        res->numpy_rate = (double)P / sec;
        res->numpy_agree = (double)same / (double)P;
    }
    free(ans);
    static const char *files[] = {"t.f64", "x.f32", "params.txt", "seconds.txt", "answers.i32"};
    for (size_t i = 0; i < sizeof files / sizeof *files; i++) {
        snprintf(path, sizeof path, "%s/%s", dir, files[i]);
        remove(path);
    }
    rmdir(dir);
    return st;
}

static gs_status run_pixels(const config *c, rec_matcher *m, result *res)
{
    rec_eq7_opts eo;
    bench_eq7_opts(&eo);
    size_t P = c->pixels, D = (size_t)c->bands * (size_t)c->K;
    float *x = malloc(sizeof *x * P * D), *sg = malloc(sizeof *sg * P), *pool = malloc(sizeof *pool * POOL);
    int *truth = malloc(sizeof *truth * P), *bulb = malloc(sizeof *bulb * P);
    float *ph = malloc(sizeof *ph * P), *cf = malloc(sizeof *cf * P);
    /* r: the lit rows' templates (0/120/240); g: the reference's (r, or the continuous grid) */
    ref_templates r, rg;
    memset(&r, 0, sizeof r);
    memset(&rg, 0, sizeof rg);
    const ref_templates *g = c->continuous ? &rg : &r;
    gs_status st = GS_OK;
    if (!x || !sg || !pool || !truth || !bulb || !ph || !cf)
        st = gs_fail(GS_ENOMEM, "bench: cannot allocate %zu pixels", P);
    if (st == GS_OK) st = ref_build(m, c->K, 3, &r);
    if (st == GS_OK) {
        uint64_t rs = 12345;
        for (size_t i = 0; i < POOL; i++) pool[i] = (float)gs_splitmix_normal(&rs);
        double a = SNR * c->bands;   /* a template's mean sample is 1 / bands */
        for (size_t p = 0; p < P; p++) {
            sg[p] = 1.0f;
            const float *noise = pool + gs_splitmix64(&rs) % (POOL - D);
            int on = gs_splitmix_uniform(&rs) < c->lit;
            size_t j = (size_t)(gs_splitmix_uniform(&rs) * (double)r.M) % r.M;
            truth[p] = on ? (int)j : -1;
            const double *t = r.t + j * D;
            for (size_t d = 0; d < D; d++) x[p * D + d] = (float)((on ? a * t[d] : 0.0) + noise[d]);
        }
        res->seconds = INFINITY;
        for (int rep = 0; rep < REPS && st == GS_OK; rep++) {
            double t0 = gs_clock_s(CLOCK_MONOTONIC);
            st = rec_match_pixels(m, x, sg, P, bulb, ph, cf);
            res->seconds = fmin(res->seconds, gs_clock_s(CLOCK_MONOTONIC) - t0);
        }
        res->maxrss_kib = peak_rss_kib();   /* (before the grid reference's templates and scores) */
        res->rate = (double)P / res->seconds;
        res->templates = r.M;
    }
    if (st == GS_OK && c->continuous) st = ref_build(m, c->K, grid_shifts(m), &rg);
    if (st == GS_OK) {
        /* the floor of any matrix-product implementation: the scores alone (of every grid
         * template with continuous phases), one SGEMM per block of 4096 rows (512 of the
         * continuous grids: 21 MB of scores), no decision */
        size_t B = c->continuous ? 512 : 4096, M = g->M;
        float *tf = malloc(sizeof *tf * M * D), *sc = malloc(sizeof *sc * B * M);
        if (tf && sc) {
            for (size_t i = 0; i < M * D; i++) tf[i] = (float)g->t[i];
            double best = INFINITY;
            for (int rep = 0; rep < REPS; rep++) {
                double t0 = gs_clock_s(CLOCK_MONOTONIC);
                for (size_t r0 = 0; r0 < P; r0 += B) {
                    size_t nr = P - r0 < B ? P - r0 : B;
                    cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)nr, (int)M, (int)D,
                                1.0f, x + r0 * D, (int)D, tf, (int)D, 0.0f, sc, (int)M);
                }
                best = fmin(best, gs_clock_s(CLOCK_MONOTONIC) - t0);
            }
            res->sgemm_rate = (double)P / best;
        }
        free(tf);
        free(sc);
    }
    if (st == GS_OK) {
        size_t nref = P < REF_ROWS_MAX ? P : REF_ROWS_MAX, same = 0;
        double *w = malloc(sizeof *w * D);
        if (!w) st = gs_fail(GS_ENOMEM, "bench: cannot allocate weights");
        for (size_t d = 0; w && d < D; d++) w[d] = 1.0;
        double thr = gs_chi2_isf(eo.unknown_p, (int)D - 2);
        double t0 = gs_clock_s(CLOCK_MONOTONIC);
        for (size_t p = 0; w && p < nref; p++) {
            int b;
            double phase;
            ref_search(g, x + p * D, w, eo.min_snr, thr, &b, &phase);
            same += ref_agrees(g, b, phase, bulb[p], ph[p]);
        }
        res->ref_seconds = gs_clock_s(CLOCK_MONOTONIC) - t0;
        res->ref_rows = nref;
        res->ref_rate = (double)nref / res->ref_seconds;
        res->agree = (double)same / (double)nref;
        free(w);
        /* NumPy runs the same search as rec_match_pixels: with the survey's defaults the free
         * band gains (unknown at dof D - bands - 1, as the matcher's) */
        int free_gains = c->defaults == 1 && c->bands > 1;
        double np_thr = free_gains ? gs_chi2_isf(eo.unknown_p, (int)D - c->bands - 1) : thr;
        if (st == GS_OK && c->numpy && numpy_script && !c->continuous)
            st = run_numpy(&r, x, P, eo.min_snr, np_thr, free_gains, c->bands, bulb, ph, res);
    }
    if (st == GS_OK) {
        size_t lit = 0, right = 0;
        for (size_t p = 0; p < P; p++) {
            if (truth[p] < 0) continue;
            lit++;
            size_t j = (size_t)truth[p];
            double dphi = fabs(fmod(ph[p] - r.phase[j] + 540.0, 360.0) - 180.0);
            right += bulb[p] == r.bulb[j] && dphi < (c->continuous ? 2.0 : 1e-3);
        }
        res->lit_correct = lit ? (double)right / (double)lit : NAN;
    }
    ref_free(&r);
    ref_free(&rg);
    free(x); free(sg); free(pool); free(truth); free(bulb); free(ph); free(cf);
    return st;
}

static gs_status run_lights(const config *c, rec_matcher *m, result *res)
{
    rec_eq7_opts eo;
    bench_eq7_opts(&eo);
    size_t N = c->lights, D = (size_t)c->bands * (size_t)c->K;
    rec_catalog cat;
    memset(&cat, 0, sizeof cat);
    cat.count = N;
    cat.bands = c->bands;
    cat.K = c->K;
    cat.x_px = calloc(N, sizeof *cat.x_px);
    cat.y_px = calloc(N, sizeof *cat.y_px);
    cat.area_px = calloc(N, sizeof *cat.area_px);
    cat.peak_dn = calloc(N, sizeof *cat.peak_dn);
    cat.saturated_px = calloc(N, sizeof *cat.saturated_px);
    cat.flags = calloc(N, sizeof *cat.flags);
    cat.signal = malloc(sizeof *cat.signal * N * D);
    cat.sigma = malloc(sizeof *cat.sigma * N * D);
    rec_match *mt = malloc(sizeof *mt * N);
    int *truth = malloc(sizeof *truth * N);
    float *xf = malloc(sizeof *xf * D);
    double *w = malloc(sizeof *w * D);
    ref_templates r, rg;   /* as in run_pixels */
    memset(&r, 0, sizeof r);
    memset(&rg, 0, sizeof rg);
    const ref_templates *g = c->continuous ? &rg : &r;
    gs_status st = GS_OK;
    if (!cat.x_px || !cat.y_px || !cat.area_px || !cat.peak_dn || !cat.saturated_px ||
        !cat.flags || !cat.signal || !cat.sigma || !mt || !truth || !xf || !w)
        st = gs_fail(GS_ENOMEM, "bench: cannot allocate %zu lights", N);
    if (st == GS_OK) st = ref_build(m, c->K, 3, &r);
    if (st == GS_OK) {
        uint64_t rs = 777;
        for (size_t i = 0; i < N; i++) {
            size_t j = (size_t)(gs_splitmix_uniform(&rs) * (double)r.M) % r.M;
            truth[i] = (int)j;
            double a = 1000.0 * c->bands;   /* brightness, sum over bands of the mean */
            for (size_t d = 0; d < D; d++) {
                /* noise std varies per sample (a light's samples differ in shot noise) */
                double s = (1000.0 / SNR) * (0.5 + gs_splitmix_uniform(&rs));
                cat.sigma[i * D + d] = s;
                cat.signal[i * D + d] = a * r.t[j * D + d] + s * gs_splitmix_normal(&rs);
            }
        }
        res->seconds = INFINITY;
        for (int rep = 0; rep < (N < LIGHTS_ONE_RUN ? REPS : 1) && st == GS_OK; rep++) {
            double t0 = gs_clock_s(CLOCK_MONOTONIC);
            st = rec_match_catalog(m, &cat, mt, NULL);
            res->seconds = fmin(res->seconds, gs_clock_s(CLOCK_MONOTONIC) - t0);
        }
        res->maxrss_kib = peak_rss_kib();
        res->rate = (double)N / res->seconds;
        res->templates = r.M;
    }
    if (st == GS_OK && c->continuous) st = ref_build(m, c->K, grid_shifts(m), &rg);
    if (st == GS_OK) {
        size_t nref = N < REF_ROWS_MAX ? N : REF_ROWS_MAX, same = 0;
        double thr = gs_chi2_isf(eo.unknown_p, (int)D - 2);
        double t0 = gs_clock_s(CLOCK_MONOTONIC);
        for (size_t i = 0; i < nref; i++) {
            for (size_t d = 0; d < D; d++) {
                xf[d] = (float)cat.signal[i * D + d];
                w[d] = 1.0 / (cat.sigma[i * D + d] * cat.sigma[i * D + d]);
            }
            int b;
            double phase;
            ref_search(g, xf, w, eo.min_snr, thr, &b, &phase);
            same += ref_agrees(g, b, phase, mt[i].bulb >= 0 ? mt[i].bulb : -1, mt[i].phase_deg);
        }
        res->ref_seconds = gs_clock_s(CLOCK_MONOTONIC) - t0;
        res->ref_rows = nref;
        res->ref_rate = (double)nref / res->ref_seconds;
        res->agree = (double)same / (double)nref;
    }
    if (st == GS_OK) {
        size_t right = 0;
        for (size_t i = 0; i < N; i++) {
            size_t j = (size_t)truth[i];
            double dphi = fabs(fmod(mt[i].phase_deg - r.phase[j] + 540.0, 360.0) - 180.0);
            right += mt[i].bulb == r.bulb[j] && dphi < (c->continuous ? 2.0 : 1e-3);
        }
        res->lit_correct = (double)right / (double)N;
    }
    ref_free(&r);
    ref_free(&rg);
    rec_catalog_release(&cat);
    free(mt); free(truth); free(xf); free(w);
    return st;
}

/* A side x side capture of c->lights Gaussian lights (PSF sigma 1.3 px, random template of m,
 * flux 200..2000 DN per cycle) over a sky of 0.5 DN per cycle with read noise 3 DN at 50 cycles,
 * through rec_pixel_maps_compute (background, threshold, Eq. 7 on the pixels above it). */
static gs_status run_capture(const config *c, rec_matcher *m, result *res)
{
    rec_eq7_opts eo;
    bench_eq7_opts(&eo);
    if (c->continuous) eo.phases = REC_PHASES_CONTINUOUS;
    gs_capture cap;
    memset(&cap, 0, sizeof cap);
    cap.grid_hz = 50;
    cap.K = c->K;
    cap.bands = c->bands;
    cap.width = cap.height = c->side;
    cap.saturation_dn = 65536;
    cap.black_level_dn = 64;
    cap.read_noise_dn = 3;
    cap.locked = 1;
    ref_templates r;
    memset(&r, 0, sizeof r);
    float *pool = malloc(sizeof *pool * POOL);
    gs_status st = pool ? gs_capture_alloc(&cap) : gs_fail(GS_ENOMEM, "bench: capture");
    if (st == GS_OK) st = ref_build(m, c->K, 3, &r);
    if (st == GS_OK) {
        const double cycles = 50.0, sky = 0.5;
        size_t np = (size_t)c->side * (size_t)c->side, D = (size_t)r.D;
        size_t n = np * (size_t)c->K * (size_t)c->bands;
        uint64_t rs = 4242;
        for (size_t i = 0; i < POOL; i++) pool[i] = (float)gs_splitmix_normal(&rs);
        for (int k = 0; k < c->K; k++) cap.frames[k].cycles = cycles;
        /* sky and read noise, then the lights added (rounded to DN) */
        for (size_t i = 0; i < n; i += 4096) {
            const float *noise = pool + gs_splitmix64(&rs) % (POOL - 4096);
            size_t e = i + 4096 < n ? i + 4096 : n;
            for (size_t q = i; q < e; q++)
                cap.raw[q] = (unsigned short)lround(fmax(0.0, 64.0 + cycles * sky + 3.0 * noise[q - i]));
        }
        for (size_t l = 0; l < c->lights; l++) {
            double x0 = 4 + gs_splitmix_uniform(&rs) * (c->side - 8), y0 = 4 + gs_splitmix_uniform(&rs) * (c->side - 8);
            double F = 200.0 + 1800.0 * gs_splitmix_uniform(&rs);
            size_t j = (size_t)(gs_splitmix_uniform(&rs) * (double)r.M) % r.M;
            for (int y = (int)y0 - 4; y <= (int)y0 + 4; y++)
                for (int x = (int)x0 - 4; x <= (int)x0 + 4; x++) {
                    double g = exp(-((x - x0) * (x - x0) + (y - y0) * (y - y0)) / (2 * 1.69)) / (2 * 3.14159265 * 1.69);
                    size_t p = (size_t)y * (size_t)c->side + (size_t)x;
                    for (size_t d = 0; d < D; d++) {
                        size_t band = d / (size_t)c->K, k = d % (size_t)c->K;
                        unsigned short *q = &cap.raw[(k * np + p) * (size_t)c->bands + band];
                        double v = *q + cycles * F * g * r.t[j * D + d];
                        *q = (unsigned short)lround(fmin(v, 65535.0));
                    }
                }
        }
        free(pool);   /* (before the timed runs: not in their peak) */
        pool = NULL;
        res->seconds = INFINITY;
        /* the maps' peak from what is resident now (the frames, the matcher); without
         * clear_refs the row's peak so far, the rendering's included (and the table says so) */
        res->maps_peak_apart = peak_rss_reset();
        for (int rep = 0; rep < REPS && st == GS_OK; rep++) {
            rec_pixel_maps pm;
            double t0 = gs_clock_s(CLOCK_MONOTONIC);
            st = rec_pixel_maps_compute(&cap, m, &eo, NULL, &pm);
            res->seconds = fmin(res->seconds, gs_clock_s(CLOCK_MONOTONIC) - t0);
            res->mapped = pm.mapped;
            res->matched = pm.matched;
            rec_pixel_maps_release(&pm);
        }
        res->rate = (double)np / res->seconds;
        res->maxrss_kib = peak_rss_kib();   /* (the maps', as recognize --maps runs them) */
        res->templates = r.M;
        /* the same capture through the blob extractor (the per-light path's first stage) */
        res->blob_seconds = INFINITY;
        int apart = peak_rss_reset();
        for (int rep = 0; rep < REPS && st == GS_OK; rep++) {
            rec_blob_opts bo;
            rec_blob_opts_default(&bo);
            rec_catalog cat;
            double t0 = gs_clock_s(CLOCK_MONOTONIC);
            st = rec_blobs_extract(&cap, &bo, &cat);
            res->blob_seconds = fmin(res->blob_seconds, gs_clock_s(CLOCK_MONOTONIC) - t0);
            res->blobs = cat.count;
            rec_catalog_release(&cat);
        }
        res->blob_maxrss_kib = apart ? peak_rss_kib() : -1;
    }
    ref_free(&r);
    free(pool);
    gs_capture_release(&cap);
    return st;
}

/* Run one configuration in a child process; its result comes back through a pipe. */
static void run_config(const gs_delight *all, const config *c, result *res)
{
    memset(res, 0, sizeof *res);
    int fd[2];
    if (pipe(fd) != 0) {
        snprintf(res->detail, sizeof res->detail, "pipe failed");
        return;
    }
    fflush(stdout);
    pid_t pid = fork();
    if (pid == 0) {
        close(fd[0]);
        result r;
        memset(&r, 0, sizeof r);
        openblas_set_num_threads(1);
        gs_delight *d = NULL;
        rec_matcher *m = NULL;
        gs_status st = subset(all, c->bands, c->bulbs, &d);
        rec_eq7_opts eo;
        bench_eq7_opts(&eo);
        if (c->defaults == 1) rec_eq7_opts_default(&eo);
        if (c->defaults == 2) eo.nested_tests = 1;
        eo.threads = c->threads > 0 ? c->threads : 1;
        if (c->continuous) eo.phases = REC_PHASES_CONTINUOUS;
        if (st == GS_OK) st = rec_matcher_new(d, 50, c->bands, c->K, &eo, &m);
        if (st == GS_OK)
            st = c->side ? run_capture(c, m, &r) : c->pixels ? run_pixels(c, m, &r) : run_lights(c, m, &r);
        if (c->continuous && st == GS_OK) r.templates = rec_matcher_template_count(m);   /* the grids' */
        r.ok = st == GS_OK;
        if (!r.ok) snprintf(r.detail, sizeof r.detail, "%s: %s", gs_strerror(st), gs_detail());
        rec_matcher_free(m);
        gs_delight_free(d);
        ssize_t wr = write(fd[1], &r, sizeof r);
        _exit(wr == (ssize_t)sizeof r ? 0 : 1);
    }
    close(fd[1]);
    if (pid < 0) {
        close(fd[0]);
        snprintf(res->detail, sizeof res->detail, "fork failed");
        return;
    }
    size_t got = 0;
    while (got < sizeof *res) {
        ssize_t n = read(fd[0], (char *)res + got, sizeof *res - got);
        if (n <= 0) break;
        got += (size_t)n;
    }
    close(fd[0]);
    int wst;
    waitpid(pid, &wst, 0);
    if (got != sizeof *res) {
        memset(res, 0, sizeof *res);
        snprintf(res->detail, sizeof res->detail, "the benchmark process died (status %d)", wst);
    }
}

/* ------------------------------------------------------------------ tables */

static const char *bulbs_label(int bulbs, char *buf, size_t n)
{
    if (bulbs <= 0) snprintf(buf, n, "all");
    else snprintf(buf, n, "%d", bulbs);
    return buf;
}

static void pixel_row(const gs_delight *all, const config *c, int *failed)
{
    result r;
    run_config(all, c, &r);
    char bl[16], label[64];
    snprintf(label, sizeof label, "%s%s%s", bulbs_label(c->bulbs, bl, sizeof bl),
             c->continuous ? " (continuous)" : "", c->defaults == 1 ? " (survey's defaults)" : "");
    if (!r.ok) {
        printf("| %d | %d | %s | | %zu | %.2f | failed: %s | | | | | | | |\n", c->K, c->bands, label,
               c->pixels, c->lit, r.detail);
        (*failed)++;
        return;
    }
    char ref[64] = "-", speed[32] = "-", agree[32] = "-";
    if (r.ref_rows) {
        snprintf(ref, sizeof ref, "%.3f", r.ref_rate / 1e6);
        snprintf(speed, sizeof speed, "%.1fx", r.rate / r.ref_rate);
        snprintf(agree, sizeof agree, "%.4f", r.agree);
    }
    char lit[32] = "-", sgemm[32] = "-";
    if (isfinite(r.lit_correct)) snprintf(lit, sizeof lit, "%.3f", r.lit_correct);
    if (r.sgemm_rate > 0) snprintf(sgemm, sizeof sgemm, "%.2f", r.sgemm_rate / 1e6);
    char np[96] = "";
    if (c->numpy && r.numpy_rate > 0)
        snprintf(np, sizeof np, " %.3f | %.1fx | %.4f |", r.numpy_rate / 1e6, r.rate / r.numpy_rate, r.numpy_agree);
    else if (c->numpy)
        snprintf(np, sizeof np, " - | - | - |");
    printf("| %d | %d | %s | %zu | 2^%d | %.2f | %.3f | **%.3f** | %s | %s | %s | %s | %s | %.0f |%s\n",
           c->K, c->bands, label, r.templates,
           (int)lround(log2((double)c->pixels)), c->lit, r.seconds, r.rate / 1e6, sgemm, ref, speed,
           agree, lit, r.maxrss_kib / 1024.0, np);
    fflush(stdout);
}

static void light_row(const gs_delight *all, const config *c, int *failed)
{
    result r;
    run_config(all, c, &r);
    char bl[16];
    if (!r.ok) {
        printf("| %d | %d | %s | | %zu | failed: %s | | | | | |\n", c->K, c->bands,
               bulbs_label(c->bulbs, bl, sizeof bl), c->lights, r.detail);
        (*failed)++;
        return;
    }
    char ref[64] = "-", speed[32] = "-", agree[32] = "-";
    if (r.ref_rows) {
        snprintf(ref, sizeof ref, "%.0f", r.ref_rate);
        snprintf(speed, sizeof speed, r.rate < r.ref_rate ? "%.2fx" : "%.1fx", r.rate / r.ref_rate);
        snprintf(agree, sizeof agree, "%.4f", r.agree);
    }
    printf("| %d | %d | %s%s | %zu | %zu | %.3f | **%.0f** | %s | %s | %s | %.3f | %.0f |\n", c->K,
           c->bands, bulbs_label(c->bulbs, bl, sizeof bl), c->continuous ? " (continuous)" : "",
           r.templates, c->lights, r.seconds, r.rate, ref, speed,
           agree, r.lit_correct, r.maxrss_kib / 1024.0);
    fflush(stdout);
}

static void capture_row(const gs_delight *all, const config *c, int *failed)
{
    result r;
    run_config(all, c, &r);
    if (!r.ok) {
        printf("| %dx%d%s | %zu | failed: %s | | | | | | | | | |\n", c->side, c->side, c->continuous ? " (continuous)" : "",
               c->lights, r.detail);
        (*failed)++;
        return;
    }
    double np = (double)c->side * c->side;
    double stack_mib = np * c->K * c->bands * 2.0 / (1024.0 * 1024.0);   /* 16-bit raw frames */
    char blob_rss[32] = "-", rss[48];
    snprintf(rss, sizeof rss, "%.0f%s", r.maxrss_kib / 1024.0, r.maps_peak_apart ? "" : " (with the rendering)");
    if (r.blob_maxrss_kib > 0) snprintf(blob_rss, sizeof blob_rss, "%.0f", r.blob_maxrss_kib / 1024.0);
    printf("| %dx%d%s | %zu | %zu (%.1f %%) | %zu | %.3f | **%.2f** | %s | %.0f | %.2f | %.3f | %zu | %s |\n", c->side,
           c->side, c->continuous ? " (continuous)" : "", c->lights, r.mapped, 100.0 * (double)r.mapped / np, r.matched, r.seconds,
           r.rate / 1e6, rss, stack_mib, r.maxrss_kib / 1024.0 / stack_mib, r.blob_seconds, r.blobs,
           blob_rss);
    fflush(stdout);
}

static void pixel_header(int numpy)
{
    printf("| K | bands | bulbs | templates | pixels | lit | seconds | Mpixel/s | SGEMM only Mpixel/s "
           "| reference Mpixel/s | speed-up | agree | lit correct | peak RSS MiB |%s\n",
           numpy ? " NumPy Mpixel/s | vs NumPy | NumPy agree |" : "");
    printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|%s\n", numpy ? "---|---|---|" : "");
}

static void light_header(void)
{
    printf("| K | bands | bulbs | templates | lights | seconds | lights/s | reference lights/s | "
           "speed-up | agree | correct | peak RSS MiB |\n");
    printf("|---|---|---|---|---|---|---|---|---|---|---|---|\n");
}

static int bench_recognize(int argc, char **argv)
{
    static const struct option longs[] = {{"quick", no_argument, 0, 'q'},
                                          {"lights", no_argument, 0, 'l'},
                                          {"captures", no_argument, 0, 'c'},
                                          {"numpy", required_argument, 0, 'n'},
                                          {"help", no_argument, 0, 'h'},
                                          {0, 0, 0, 0}};
    int quick = 0, lights_only = 0, captures_only = 0, c;
    optind = 1;
    numpy_script = NULL;
    while ((c = getopt_long(argc, argv, "h", longs, NULL)) != -1) {
        if (c == 'q') quick = 1;
        else if (c == 'l') lights_only = 1;
        else if (c == 'c') captures_only = 1;
        else if (c == 'n') numpy_script = optarg;
        else if (c == 'h') {
            fputs(bench_usage, stdout);
            return 0;
        } else {
            return srv_usage_hint("bench recognize", argv);
        }
    }
    if (optind != argc) return srv_usage_error("bench recognize", "unexpected argument '%s'", argv[optind]);
    if (lights_only && captures_only)
        return srv_usage_error("bench recognize", "--lights and --captures: expected one of them");
    gs_delight *all = NULL;
    gs_status st = gs_delight_open(NULL, &all);
    if (st != GS_OK) return srv_error("bench recognize", st);
    int failed = 0;
    static const int Ks[] = {8, 13, 26}, bandss[] = {1, 3}, bulbss[] = {10, 25, 0};
    double t_start = gs_clock_s(CLOCK_MONOTONIC);

    printf("# Eq. 7 throughput (`gridsurvey bench recognize%s`)\n\n", quick ? " --quick" : "");
    printf("The matcher runs the paper's Eq. 7: one brightness per light times the chromaticity "
           "templates, the camera's noise, the closed world, one light per aperture "
           "(rec_eq7_opts band_gains = chroma, model_error = 0, other_prior = 0, flat_share = 0, "
           "nested_tests = 0; `gridsurvey recognize --band-model chroma --model-error 0 "
           "--other-prior 0 --flat-share 0 --nested-tests off`): what the reference computes, and "
           "besides the posterior, the runner-up and the chi-square p-value, which the reference "
           "does not. The survey's defaults (docs/recognition.md: the reddened band model, the "
           "excess measured per capture, the nested-model tests) are timed per pixel in the rows "
           "marked so and per light in the last tables.\n\n");
    printf("One core (OpenBLAS single-threaded), built-in DELIGHT at 50 Hz (all = every voltage-"
           "referenced entry of the sensor), phases 0/120/240 unless marked continuous. Synthetic "
           "data: a lit row/light is a random template at a mean sample of %.0f noise sigmas "
           "plus Gaussian noise. *reference* is a plain triple loop (rows x templates x values, "
           "double precision) of the same search written in survey/bench.c, independent of "
           "recognize/eq7_*.c, timed on the first min(rows, %d) rows; *agree* is the fraction of "
           "those rows where both give the same answer (bulb and phase, or no answer). Peak RSS is "
           "the peak resident set (VmHWM) of the process running that row, read after the timed runs (inputs "
           "included: 4 bytes x values x pixels; the continuous rows' grid reference and the SGEMM's "
           "scores come after). Times are the best of %d runs. *SGEMM only* times the score matrix alone (rows x templates, one "
           "cblas_sgemm per 4096 rows, no decision): the floor of a matrix-product "
           "implementation on this machine. *lit correct*: lit rows answered with their true "
           "bulb and phase.\n\n", SNR, REF_ROWS_MAX, REPS);

    if (lights_only) goto lights;
    if (captures_only) goto captures;
    printf("## Per pixel: rec_match_pixels\n\n");
    pixel_header(0);
    size_t P0 = quick ? (size_t)1 << 14 : (size_t)1 << 18;
    for (size_t ki = 0; ki < 3; ki++)
        for (size_t bi = 0; bi < 2; bi++)
            for (size_t di = 0; di < 3; di++) {
                if (quick && !(ki == 2 || (bi == 1 && di == 2))) continue;
                config cf = {Ks[ki], bandss[bi], bulbss[di], 0, P0, 0.1, 0, 0, 0, 0, 0};
                pixel_row(all, &cf, &failed);
            }
    printf("\n### 1-megapixel RGB capture, K = 26, whole database\n\n");
    if (numpy_script)
        printf("*NumPy*: the same rows through %s, the reference's search in its best NumPy form "
               "(float32 scores of blocks of rows against every unit template as one matrix "
               "product, the rest vectorised; /usr/bin/python3, one core: OPENBLAS_NUM_THREADS=1), "
               "best of %d runs in this process's run; *vs NumPy* is rec_match_pixels' rate over "
               "its, *NumPy agree* the fraction of rows both answer alike.\n\n", numpy_script, REPS);
    printf("Rows marked *survey's defaults* run rec_match_pixels with rec_eq7_opts_default, as "
           "`gridsurvey recognize --maps` does: the pixel path runs the reddened band model as free "
           "band gains (a brightness per band; no model error, which the defaults measure per "
           "capture for lights only). %sThe triple-loop reference stays the paper's model, so its "
           "*agree* measures the models' difference too.\n\n",
           numpy_script ? "Their NumPy column runs that same search (the script's free model: "
                          "scores and log Phi per band). " : "");
    pixel_header(numpy_script != NULL);
    static const double lits[] = {0.0, 0.1, 1.0};
    for (int e = quick ? 14 : 16; e <= (quick ? 16 : 20); e += 2)
        for (size_t li = 0; li < 3; li++) {
            if (quick && li != 1) continue;
            config cf = {26, 3, 0, 0, (size_t)1 << e, lits[li], 0, 0, 0, 0, numpy_script != NULL};
            pixel_row(all, &cf, &failed);
        }
    /* the survey's options (issue #17's target: 10x NumPy with them, all-lit included) */
    for (int e = quick ? 14 : 18; e <= (quick ? 14 : 20); e += 2)
        for (size_t li = 1; li < 3; li++) {
            config cf = {26, 3, 0, 0, (size_t)1 << e, lits[li], 0, 0, 1, 0, numpy_script != NULL};
            pixel_row(all, &cf, &failed);
        }
    for (size_t li = 0; li < 3; li++) {   /* continuous phases: dark, 10 % lit, all lit */
        if (quick && li != 1) continue;
        config cf = {26, 3, 0, 1, (size_t)1 << (quick ? 10 : 14), lits[li], 0, 0, 0, 0, numpy_script != NULL};
        pixel_row(all, &cf, &failed);
    }

captures:
    printf("\n### A whole capture through the per-pixel maps: rec_pixel_maps_compute\n\n");
    printf("K = 26, RGB, whole database, phases 0/120/240 unless marked continuous (every phase, as "
           "in the per-pixel rows above: what `recognize --maps --phases continuous` waits for). The "
           "capture is rendered in memory: "
           "Gaussian lights (PSF sigma 1.3 px) of random templates over a sky with read noise; "
           "the maps compute a background mesh, threshold every pixel at 5 sigma and run "
           "rec_match_pixels on the pixels above it only. Mpixel/s counts every pixel of the "
           "capture. *frame stack*: the capture's 16-bit raw frames (side^2 x K x bands x 2 bytes); "
           "*peak RSS*: the process's (VmHWM) after the maps' timed runs, as `recognize --maps` "
           "runs them: the frame stack, the matcher and both passes. *blobs*: the same capture "
           "through rec_blobs_extract (default options), the first stage of the per-light path, "
           "the lights it found and its own peak (the high-water mark lowered to the resident "
           "set before it: /proc/self/clear_refs; the frame stack and the row's matcher stay "
           "resident).\n\n");
    printf("| capture | lights | pixels above threshold | with a bulb | seconds | capture Mpixel/s | "
           "peak RSS MiB | frame stack MiB | peak / stack | blobs seconds | blobs found | blobs peak RSS MiB |\n"
           "|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    static const size_t nlights[] = {200, 2000, 20000};
    for (size_t li = 0; li < 3; li++) {
        if (quick && li == 2) continue;
        config cf = {26, 3, 0, 0, 0, 0.0, quick ? nlights[li] / 16 : nlights[li], quick ? 256 : 1024, 0, 0, 0};
        capture_row(all, &cf, &failed);
    }
    {
        config cf = {26, 3, 0, 1, 0, 0.0, quick ? nlights[1] / 16 : nlights[1], quick ? 256 : 1024, 0, 0, 0};
        capture_row(all, &cf, &failed);
    }
    if (captures_only) goto done;

lights:
    printf("\n## Per light: rec_match_catalog\n\n");
    printf("Each light: a random template at a mean sample of 1000, per-sample noise std uniform in "
           "50..150 (so the weights differ by up to 9x within a light), %d lights per row; "
           "*correct*: lights answered with their true bulb and phase.\n\n", quick ? 1000 : 20000);
    light_header();
    size_t L0 = quick ? 1000 : 20000;
    for (size_t ki = 0; ki < 3; ki++)
        for (size_t bi = 0; bi < 2; bi++)
            for (size_t di = 0; di < 3; di++) {
                if (quick && !(ki == 2 && (di == 2 || bi == 1))) continue;
                config cf = {Ks[ki], bandss[bi], bulbss[di], 0, 0, 0.0, L0, 0, 0, 0, 0};
                light_row(all, &cf, &failed);
            }
    {   /* (enough lights for a tenth of a second: fewer time the call's set-up and the machine's noise) */
        config cf = {26, 3, 0, 1, 0, 0.0, quick ? 50 : 4000, 0, 0, 0, 0};
        light_row(all, &cf, &failed);
    }
    printf("\n### Time against the number of lights\n\nK = 26, RGB, whole database, the paper's model, "
           "one thread: the same lights as above, 10^3 to 10^%d of them (10^6: one run, not the "
           "best of %d).\n\n", quick ? 4 : 6, REPS);
    light_header();
    for (size_t n = 1000; n <= (quick ? 10000u : LIGHTS_ONE_RUN); n *= 10) {
        config cf = {26, 3, 0, 0, 0, 0.0, n, 0, 0, 0, 0};
        light_row(all, &cf, &failed);
    }
    printf("\n*continuous* rows search every phase (a grid of G = max(8K, 96) shifts per cycle, refined); "
           "their templates column counts those grid shifts. Their *reference* is the same triple "
           "loop over every template of that grid (the search before its refinement), their *SGEMM "
           "only* the scores of every grid template (blocks of 512 rows), and "
           "*agree* counts the same bulb with the same shift within one grid cell (180/G deg; the "
           "refinement stays within a cell of the best one), or no answer from both. "
           "Per pixel they go through the Fourier screen (docs/recognition.md, \"Continuous phases: "
           "the Fourier screen\"): only the grids of the bulbs it cannot rule out are scored.\n");
    int nt = gs_threads_resolve(0);
    printf("\n## What the nested-model tests cost\n\n"
           "The paper's model as above, with the nested-model tests of each light's best fit on "
           "(rec_eq7_opts.nested_tests: a second template against the best fit and the next 15 by "
           "score, a smooth deformation, a bulb not in DELIGHT; docs/recognition.md), one "
           "thread.\n\n");
    light_header();
    for (int ci = 0; ci < 2; ci++) {
        config cf = {26, 3, 0, ci, 0, 0.0, ci ? (quick ? 50 : 300) : (quick ? 1000 : 20000), 0, 2, 1, 0};
        light_row(all, &cf, &failed);
    }
    printf("\n## Per light with the survey's options, 1 and %d threads\n\n"
           "The rows above use the paper's model (one brightness times the chromaticity, no excess "
           "noise) on one thread. These use rec_eq7_opts_default, as `gridsurvey run` and `recognize` "
           "do: the reddened band model, the excess noise measured from the population (two passes), "
           "the blend and shape tests; then on the online CPUs (rec_eq7_opts.threads: the answers "
           "are the same bits, tests/test_eq7_model.c). *agree* compares with the triple loop of the "
           "paper's model, so it measures the models' difference too. On one thread also 16,000 and "
           "64,000 lights: the population's steps stay linear in the lights (docs/recognition.md, "
           "\"Noise\").\n\n", nt);
    light_header();
    for (int ti = 0; ti < 2; ti++) {
        if (ti == 1 && nt == 1) break;
        printf("| %s |||||||||||\n", ti ? "**threads: the online CPUs**" : "**threads: 1**");
        size_t n0 = quick ? 300 : 4000, n1 = quick || ti ? n0 : 64000;   /* one thread: the scaling too */
        for (size_t n = n0; n <= n1; n *= 4) {
            config cf = {26, 3, 0, 0, 0, 0.0, n, 0, 1, ti ? nt : 1, 0};
            light_row(all, &cf, &failed);
        }
        config cc = {26, 3, 0, 1, 0, 0.0, quick ? 30 : 200, 0, 1, ti ? nt : 1, 0};
        light_row(all, &cc, &failed);
    }
    if (nt > 1) {
        printf("\n## The paper's model on %d threads\n\n"
               "Rows of the tables above, now with rec_eq7_opts.threads = %d (rec_match_pixels: blocks of "
               "rows taken in turn, OpenBLAS single-threaded; rec_match_catalog: lights in chunks; "
               "the answers are the same as on one thread: tests/test_eq7_pixels.c, "
               "test_eq7_model.c). Seconds are wall-clock time; *reference* and *SGEMM only* stay on one "
               "thread. Per light with continuous phases %d lights (%d above: two threads take the "
               "lights in chunks).\n\n",
               nt, nt, quick ? 200 : 20000, quick ? 50 : 4000);
        if (!lights_only) {
            pixel_header(0);
            for (size_t li = 0; li < 3; li++) {
                if (quick && li != 1) continue;
                config cf = {26, 3, 0, 0, (size_t)1 << (quick ? 16 : 20), lits[li], 0, 0, 0, nt, 0};
                pixel_row(all, &cf, &failed);
            }
            for (size_t li = 0; li < 3; li++) {
                if (quick && li != 1) continue;
                config cf = {26, 3, 0, 1, (size_t)1 << (quick ? 10 : 14), lits[li], 0, 0, 0, nt, 0};
                pixel_row(all, &cf, &failed);
            }
            printf("\n");
        }
        light_header();
        for (int ci = 0; ci < 2; ci++) {
            config cf = {26, 3, 0, ci, 0, 0.0, ci ? (quick ? 200 : 20000) : L0, 0, 0, nt, 0};
            light_row(all, &cf, &failed);
        }
    }
done:
    printf("\nTotal %.0f s.\n", gs_clock_s(CLOCK_MONOTONIC) - t_start);
    gs_delight_free(all);
    return failed ? 1 : 0;
}

int srv_cmd_bench(int argc, char **argv)
{
    if (argc < 2 || !strcmp(argv[1], "--help") || !strcmp(argv[1], "-h")) {
        fputs(bench_usage, argc < 2 ? stderr : stdout);
        return argc < 2 ? 2 : 0;
    }
    if (!strcmp(argv[1], "recognize")) return bench_recognize(argc - 1, argv + 1);
    if (!strcmp(argv[1], "db")) return srv_bench_db(argc - 1, argv + 1);
    if (!strcmp(argv[1], "pg")) return srv_bench_pg(argc - 1, argv + 1);
    if (!strcmp(argv[1], "accuracy")) return srv_bench_accuracy(argc - 1, argv + 1);
    if (!strcmp(argv[1], "render")) return srv_bench_render(argc - 1, argv + 1);
    if (!strcmp(argv[1], "blobs")) return srv_bench_blobs(argc - 1, argv + 1);
    if (!strcmp(argv[1], "transport")) return srv_bench_transport(argc - 1, argv + 1);
    return srv_usage_error("bench", "'%s' is not a benchmark: expected recognize, db, pg, render, blobs, accuracy "
                           "or transport", argv[1]);
}
