/* test_eq7_model.c - Eq. 7's default model beyond the paper (recognize/eq7.c): one brightness
 * per band (extinction reddening) and a model error (scintillation), against the paper's single
 * brightness times Q_beta; a bulb not in the database stays unknown; pixels agree with lights. */
#include "recognize/internal.h"
#include "recognize/recognize.h"
#include "tests/eq7_fixture.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The default options (the reddened band model, the excess noise measured per capture), phases
 * ps. */
static rec_matcher *new_matcher_default(const gs_delight *d, int bands, rec_phase_set ps)
{
    rec_eq7_opts o;
    rec_eq7_opts_default(&o);
    CHECK(o.band_gains == REC_BANDS_REDDENED && isnan(o.model_error));
    o.phases = ps;
    rec_matcher *m = NULL;
    CHECK_OK(rec_matcher_new(d, 50, bands, 26, &o, &m));
    return m;
}

/* A 640 x 480 catalog of n RGB K = 26 lights: its signal, sigma and rows allocated (the rest
 * NULL; rec_catalog_release frees it). */
static rec_catalog catalog_rgb26(size_t n)
{
    rec_catalog cat = {.count = n, .bands = 3, .K = 26, .width = 640, .height = 480};
    cat.signal = malloc(sizeof *cat.signal * n * 78);
    cat.sigma = malloc(sizeof *cat.sigma * n * 78);
    cat.y_px = malloc(sizeof *cat.y_px * n);
    CHECK(cat.signal && cat.sigma && cat.y_px);
    return cat;
}

/* A light of bulb b at shift s: per-band gains g[band] (extinction reddening), a per-window
 * log-normal multiplicative factor of log-std scint (the same for every band: scintillation is
 * one random flux per frame), then Gaussian noise of std sigma. */
static void render_fx(const gs_bulb *b, double s, double a, const double *g, double scint,
                      double sigma, uint64_t *rs, double *x, double *sg)
{
    int K = 26;
    eq7fx_template(b, s, K, x);
    double f[26];
    for (int k = 0; k < K; k++) f[k] = scint > 0 ? exp(scint * gs_splitmix_normal(rs) - 0.5 * scint * scint) : 1.0;
    for (int band = 0; band < 3; band++)
        for (int k = 0; k < K; k++) {
            int d = band * K + k;
            x[d] = a * g[band] * f[k] * x[d] + sigma * gs_splitmix_normal(rs);
            sg[d] = sigma;
        }
}

TEST(eq7_extinction_reddened_light_recognized)
{
    /* Extinction scales the bands by about 1.0/0.8/0.6 (R/G/B; shared/BULBS.md): with one
     * brightness per band (the default) every bulb and phase is still recognised, not unknown,
     * at a per-sample SNR of ~100; the paper's single brightness times Q_beta calls the same
     * lights unknown. Pixels agree. */
    gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
    rec_matcher *m = new_matcher_default(d, 3, REC_PHASES_3);
    rec_matcher *m0 = eq7fx_new_matcher(d, 50, 3, 26, REC_PHASES_3);
    CHECK(rec_matcher_bulb_count(m) == 5);
    const double g[3] = {1.0, 0.8, 0.6};
    double x[78], sg[78];
    float xf[78 * 24], sf[24];
    int truth_b[24];
    double truth_p[24];
    uint64_t rs = 31;
    int n = 0, unknown0 = 0;
    for (size_t b = 0; b < 4; b++)   /* not the flat bulb (0.1 % flicker: no phase) */
        for (int p = 0; p < 3; p++)
            for (int rep = 0; rep < 2; rep++) {
                double a = 1000.0, sigma = a / 3 / 100;
                render_fx(rec_matcher_bulb(m, b), gs_phase_to_shift(eq7fx_p3[p]), a, g, 0.0, sigma, &rs, x, sg);
                rec_match r;
                CHECK_OK(rec_match_light(m, x, sg, &r));
                CHECK(eq7fx_all_finite(&r));
                CHECK_MSG(r.bulb == (int)b && fabs(r.phase_deg - eq7fx_p3[p]) < 1e-9,
                          "bulb %zu phase %g: got %d %g (flags %u, p %g)", b, eq7fx_p3[p], r.bulb,
                          r.phase_deg, r.flags, r.p_value);
                CHECK(!(r.flags & (REC_MATCH_UNKNOWN | REC_MATCH_DIM)));
                CHECK(r.confidence > 0.99);
                CHECK(r.dof == 78 - 2 - 1);   /* brightness, optical depth, phase */
                /* brightness: the sum of the per-band means, a (0.45 + 0.35 0.8 + 0.2 0.6)-ish */
                const double *q = rec_matcher_bulb(m, b)->chroma;
                CHECK_NEAR(r.brightness, a * (q[0] * g[0] + q[1] * g[1] + q[2] * g[2]), 0.01 * a);
                CHECK_OK(rec_match_light(m0, x, sg, &r));
                unknown0 += !!(r.flags & REC_MATCH_UNKNOWN);
                for (int k = 0; k < 78; k++) xf[n * 78 + k] = (float)x[k];
                sf[n] = (float)sigma;
                truth_b[n] = (int)b;
                truth_p[n] = eq7fx_p3[p];
                n++;
            }
    CHECK_MSG(unknown0 == n, "one brightness times Q_beta: %d of %d reddened lights unknown", unknown0, n);
    int pb[24];
    float pp[24], pc[24];
    CHECK_OK(rec_match_pixels(m, xf, sf, (size_t)n, pb, pp, pc));
    for (int i = 0; i < n; i++) {
        CHECK_MSG(pb[i] == truth_b[i] && fabs(pp[i] - truth_p[i]) < 1e-3, "pixel %d: %d %g", i, pb[i], pp[i]);
        CHECK(pc[i] > 0.99f);
    }
    rec_matcher_free(m);
    rec_matcher_free(m0);
    gs_delight_free(d);
}

TEST(eq7_scintillation_multiplicative_noise)
{
    /* Scintillation: a log-normal flux factor per frame (log-std 3 %; the metro scene's lights
     * have 1-5 % at 1-5 km) at a per-sample SNR of 100 (without it), 400 lights of a catalog:
     * rec_match_catalog measures the excess from the population (e close to 0.03, not assumed),
     * and with it the lights are recognised and calibrated; with the camera noise alone the
     * chi-square test rejects most of them. Continuous phases too. */
    gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
    rec_matcher *m = new_matcher_default(d, 3, REC_PHASES_3);
    rec_eq7_opts o0;
    rec_eq7_opts_default(&o0);
    o0.model_error = 0.0;   /* the camera noise alone */
    rec_matcher *m0 = NULL;
    CHECK_OK(rec_matcher_new(d, 50, 3, 26, &o0, &m0));
    const double g[3] = {1.0, 0.85, 0.7};
    size_t n = 400;
    rec_catalog cat = catalog_rgb26(n);
    rec_match *r = malloc(sizeof *r * n), *r0 = malloc(sizeof *r0 * n);
    uint64_t rs = 41;
    for (size_t i = 0; i < n; i++) {
        double a = 1000.0, sigma = a / 3 / 100;
        render_fx(rec_matcher_bulb(m, i % 4), gs_phase_to_shift(eq7fx_p3[(i / 4) % 3]), a, g, 0.03, sigma,
                  &rs, cat.signal + i * 78, cat.sigma + i * 78);
        cat.y_px[i] = 480.0 * gs_splitmix_uniform(&rs);
    }
    rec_noise_report nr, nr0;
    CHECK_OK(rec_match_catalog(m, &cat, r, &nr));
    CHECK_OK(rec_match_catalog(m0, &cat, r0, &nr0));
    CHECK(nr.source == REC_NOISE_POPULATION && nr.lights_used > n / 2);
    CHECK(nr0.source == REC_NOISE_FIXED && nr0.median_model_error == 0.0);
    CHECK_MSG(nr.median_model_error > 0.022 && nr.median_model_error < 0.038,
              "measured excess %g (truth 0.03)", nr.median_model_error);
    int right = 0, unknown = 0, unknown0 = 0, answered = 0;
    double conf_sum = 0.0, chi2_sum = 0.0;
    for (size_t i = 0; i < n; i++) {
        CHECK(eq7fx_all_finite(&r[i]));
        CHECK(r[i].model_error > 0.015 && r[i].model_error < 0.045);
        unknown += !!(r[i].flags & REC_MATCH_UNKNOWN);
        unknown0 += !!(r0[i].flags & REC_MATCH_UNKNOWN);
        chi2_sum += r[i].chi2 / r[i].dof;
        if (r[i].bulb >= 0) {
            answered++;
            conf_sum += r[i].confidence;
            right += r[i].bulb == (int)(i % 4) && fabs(r[i].phase_deg - eq7fx_p3[(i / 4) % 3]) < 1e-9;
        }
    }
    printf("    scintillation 3 %%: measured e %.4f from %zu lights; %d of %zu answered, %d right, "
           "mean confidence %.4f, unknown %d (camera noise alone %d), mean chi2/dof %.3f\n",
           nr.median_model_error, nr.lights_used, answered, n, right, conf_sum / answered, unknown,
           unknown0, chi2_sum / n);
    CHECK_MSG(unknown <= (int)n / 50, "%d of %zu unknown", unknown, n);
    CHECK(unknown0 > (int)n / 2);
    CHECK(right >= answered - 2);
    /* calibrated: the mean confidence is within 3 points of the accuracy */
    CHECK_NEAR(conf_sum / answered, (double)right / answered, 0.03);
    /* the chi-square is what the measured noise says: its mean near 1 */
    CHECK_MSG(chi2_sum / n > 0.8 && chi2_sum / n < 1.25, "mean chi2/dof %g", chi2_sum / n);
    rec_matcher_free(m0);
    rec_matcher_free(m);
    /* continuous phases: the phase is found and its sigma calibrated (RMS of error / sigma
     * within 0.8-1.25, docs/recognition.md), with the excess measured as above */
    m = new_matcher_default(d, 3, REC_PHASES_CONTINUOUS);
    double *truth = malloc(sizeof *truth * n);
    for (size_t i = 0; i < n; i++) {
        truth[i] = gs_phase_to_shift(360.0 * gs_splitmix_uniform(&rs));
        render_fx(rec_matcher_bulb(m, i % 4), truth[i], 1000.0, g, 0.03, 1000.0 / 3 / 100, &rs,
                  cat.signal + i * 78, cat.sigma + i * 78);
    }
    CHECK_OK(rec_match_catalog(m, &cat, r, &nr));
    double nerr2 = 0.0;
    int nc = 0;
    for (size_t i = 0; i < n; i++) {
        CHECK(eq7fx_all_finite(&r[i]));
        if (r[i].bulb != (int)(i % 4)) continue;
        double e = eq7fx_cdist(gs_phase_to_shift(r[i].phase_deg), truth[i]) * 180.0 / r[i].phase_sigma_deg;
        nerr2 += e * e;
        nc++;
    }
    printf("    continuous: %d of %zu recognised, RMS error / sigma %.3f\n", nc, n, sqrt(nerr2 / nc));
    CHECK_MSG(nc >= (int)n * 95 / 100, "%d of %zu continuous lights recognised", nc, n);
    CHECK_MSG(sqrt(nerr2 / nc) > 0.8 && sqrt(nerr2 / nc) < 1.25, "normalised phase error RMS %g",
              sqrt(nerr2 / nc));
    free(truth);
    free(r0);
    free(r);
    rec_catalog_release(&cat);
    rec_matcher_free(m);
    gs_delight_free(d);
}

typedef struct {
    double e2, w;
} excess_w;

static int cmp_excess_w(const void *a, const void *b)
{
    double x = ((const excess_w *)a)->e2, y = ((const excess_w *)b)->e2;
    return (x > y) - (x < y);
}

/* The kernel median of the true excesses e_j^2 over the other lights j, weights exp(-dy^2/2) in
 * rows of a third of the height (the lights alike in brightness and noise): what the capture's
 * estimate of light i's excess tends to (eq7_noise.c), its square root. */
static double smoothed_excess(const double *e, const double *y, size_t n, size_t i, double hy)
{
    excess_w *v = malloc(sizeof *v * n);
    double sum = 0.0;
    size_t m = 0;
    for (size_t j = 0; j < n; j++) {
        if (j == i) continue;
        double dy = (y[j] - y[i]) / hy;
        v[m] = (excess_w){e[j] * e[j], exp(-0.5 * dy * dy)};
        sum += v[m++].w;
    }
    qsort(v, m, sizeof *v, cmp_excess_w);
    double acc = 0.0, med = v[m - 1].e2;
    for (size_t a = 0; a < m; a++) {
        acc += v[a].w;
        if (acc >= 0.5 * sum) {
            med = v[a].e2;
            break;
        }
    }
    free(v);
    return sqrt(med);
}

/* The excess noise of each light follows the capture's: here it grows with the image row (from
 * 2 % at the top to 5 % at the bottom, as a longer path through the air would), over more lights
 * than a light's kernel median takes (eq7_noise.c, NOISE_MAX_REFS: a sample stratified in e2).
 * Each light's excess against the kernel median of the true ones (smoothed_excess, the estimate's
 * limit: the kernel is a third of the image high), for every 20th light and in the top and
 * bottom fifths. A sample of the lowest excesses, or no kernel, would not match. Four identical
 * lights five decades brighter than the others have kernel weights on each other only: their e2
 * are equal, so the sample (every second reference by e2 here) holds two of them and each sees
 * one or two others (an effective count near 2); their excess is the fallback, over a sample the
 * global median of all references (the report's median_model_error, the same bits), not a
 * median of the sample nor of the others. */
TEST(eq7_excess_follows_the_rows_over_many_lights)
{
    gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
    rec_matcher *m = new_matcher_default(d, 3, REC_PHASES_3);
    const double g[3] = {1.0, 0.85, 0.7};
    size_t n = 9004, bright = 9000;   /* lights from `bright` on: 1e8 (copies of one), the others 1000 */
    rec_catalog cat = catalog_rgb26(n);
    rec_match *r = malloc(sizeof *r * n);
    double *truth = malloc(sizeof *truth * n);
    uint64_t rs = 43;
    for (size_t i = 0; i < n; i++) {
        double a = i < bright ? 1000.0 : 1e8;
        cat.y_px[i] = 480.0 * gs_splitmix_uniform(&rs);
        truth[i] = 0.02 + 0.03 * cat.y_px[i] / 480.0;
        render_fx(rec_matcher_bulb(m, i % 4), gs_phase_to_shift(eq7fx_p3[(i / 4) % 3]), a, g, truth[i], a / 3 / 100,
                  &rs, cat.signal + i * 78, cat.sigma + i * 78);
    }
    for (size_t i = bright + 1; i < n; i++) {   /* the bright lights: copies of the first */
        cat.y_px[i] = cat.y_px[bright];
        truth[i] = truth[bright];
        memcpy(cat.signal + i * 78, cat.signal + bright * 78, sizeof *cat.signal * 78);
        memcpy(cat.sigma + i * 78, cat.sigma + bright * 78, sizeof *cat.sigma * 78);
    }
    rec_noise_report nr;
    CHECK_OK(rec_match_catalog(m, &cat, r, &nr));
    CHECK(nr.source == REC_NOISE_POPULATION && nr.lights_used > n / 2);
    CHECK_MSG(nr.lights_used > NOISE_MAX_REFS, "%zu references: the medians' sample not taken", nr.lights_used);
    size_t close = 0, checked = 0, top = 0, bottom = 0;
    double est[2] = {0.0, 0.0}, lim[2] = {0.0, 0.0};
    for (size_t i = 0; i < n; i += 20) {
        double s = smoothed_excess(truth, cat.y_px, n, i, 480.0 / 3.0);
        close += fabs(r[i].model_error - s) <= 0.1 * s;
        checked++;
        int q = cat.y_px[i] < 96.0 ? 0 : cat.y_px[i] >= 384.0 ? 1 : -1;
        if (q < 0) continue;
        est[q] += r[i].model_error;
        lim[q] += s;
        q ? bottom++ : top++;
    }
    printf("    excess 2-5 %% by row, %zu lights (%zu references): %zu of %zu within 10 %% of the kernel "
           "median of the truth; mean %.4f (%.4f) in the top fifth, %.4f (%.4f) in the bottom fifth\n",
           n, nr.lights_used, close, checked, est[0] / top, lim[0] / top, est[1] / bottom, lim[1] / bottom);
    CHECK_MSG(close >= checked * 95 / 100, "%zu of %zu lights' excess within 10 %%", close, checked);
    CHECK_NEAR(est[0] / top, lim[0] / top, 0.07 * lim[0] / top);
    CHECK_NEAR(est[1] / bottom, lim[1] / bottom, 0.07 * lim[1] / bottom);
    for (size_t i = bright; i < n; i++)
        CHECK_MSG(r[i].bulb >= 0 && r[i].model_error == nr.median_model_error,
                  "bright light %zu: bulb %d, excess %.9g, the global median %.9g", i, r[i].bulb,
                  r[i].model_error, nr.median_model_error);
    free(truth);
    free(r);
    rec_catalog_release(&cat);
    rec_matcher_free(m);
    gs_delight_free(d);
}

TEST(eq7_unknown_bulb_still_unknown_with_model_error)
{
    /* A bulb not in the database (another waveform) at a per-sample SNR of 30-300 is UNKNOWN
     * with the defaults (band gains, model_error 0.04), reddened or not, with 2 % scintillation,
     * in lights and pixels;
     * so is a database bulb's waveform with a different shape in one band only. */
    gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
    rec_matcher *m = new_matcher_default(d, 3, REC_PHASES_3);
    gs_bulb odd;
    eq7fx_make_bulb(&odd, "odd", SHAPE_ODD, 50, 3, GS_REF_VOLTAGE, eq7fx_chroma[6], 1024);
    const double g1[3] = {1, 1, 1}, g2[3] = {1.0, 0.8, 0.6};
    double x[78], sg[78];
    float xf[78 * 60], sf[60];
    uint64_t rs = 51;
    int n = 0;
    for (int trial = 0; trial < 60; trial++) {
        double snr = trial % 3 == 0 ? 30.0 : trial % 3 == 1 ? 100.0 : 300.0, a = 1000.0;
        render_fx(&odd, gs_phase_to_shift(eq7fx_p3[trial % 3]), a, (trial & 1) ? g2 : g1, 0.02,
                  a / 3 / snr, &rs, x, sg);
        rec_match r;
        CHECK_OK(rec_match_light(m, x, sg, &r));
        CHECK(eq7fx_all_finite(&r));
        CHECK_MSG(r.bulb == -1 && (r.flags & REC_MATCH_UNKNOWN), "trial %d (snr %g): bulb %d p %g",
                  trial, snr, r.bulb, r.p_value);
        CHECK(r.runner_bulb >= 0 && r.confidence == 0);
        for (int k = 0; k < 78; k++) xf[n * 78 + k] = (float)x[k];
        sf[n++] = (float)sg[0];
    }
    int pb[60];
    CHECK_OK(rec_match_pixels(m, xf, sf, (size_t)n, pb, NULL, NULL));
    for (int i = 0; i < n; i++) CHECK_MSG(pb[i] == -1, "pixel %d: bulb %d", i, pb[i]);
    /* a database bulb (saw) whose blue band has the harm shape: a chimera, unknown */
    gs_bulb chim;
    eq7fx_make_bulb(&chim, "chimera", SHAPE_SAW, 50, 3, GS_REF_VOLTAGE, eq7fx_chroma[1], 1024);
    for (int j = 0; j < 1024; j++) chim.brf.v[2 * 1024 + j] = eq7fx_shape_at(SHAPE_HARM, j / 1024.0, 2);
    CHECK_OK(gs_brf_normalize(&chim.brf, NULL));
    for (int trial = 0; trial < 20; trial++) {
        render_fx(&chim, gs_phase_to_shift(eq7fx_p3[trial % 3]), 1000.0, g1, 0.02, 1000.0 / 3 / 100, &rs, x, sg);
        rec_match r;
        CHECK_OK(rec_match_light(m, x, sg, &r));
        CHECK_MSG(r.bulb == -1 && (r.flags & REC_MATCH_UNKNOWN), "chimera %d: bulb %d", trial, r.bulb);
    }
    gs_bulb_release(&chim);
    gs_bulb_release(&odd);
    rec_matcher_free(m);
    gs_delight_free(d);
}

TEST(eq7_band_gains_pixels_equal_lights)
{
    /* With one brightness per band (REC_BANDS_FREE, what the pixel path runs for the reddened
     * model too) and a fixed excess of 0 (pixels weigh samples independently: no tempering for a
     * correlated excess, recognize.h), rec_match_pixels gives rec_match_light's answer on the
     * generated DELIGHT, rows of every brightness (around the dim threshold up to a per-sample
     * SNR of ~100), reddened, through the prefilter. */
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, 1024));
    rec_eq7_opts o;
    rec_eq7_opts_default(&o);
    o.band_gains = REC_BANDS_FREE;
    o.model_error = 0.0;
    o.other_prior = 0.0;   /* nor the "not in DELIGHT" and blend posteriors */
    o.blend_prior = 0.0;
    rec_matcher *m = NULL;
    CHECK_OK(rec_matcher_new(d, 50, 3, 26, &o, &m));
    size_t nb = rec_matcher_bulb_count(m);
    eq7fx_rows px;
    eq7fx_rows_alloc(&px, fx_sanitized() ? 1500 : 6000);
    double x[78], sg[78];
    const double g[3] = {1.0, 0.8, 0.6};
    uint64_t rs = 61;
    for (size_t i = 0; i < px.n; i++) {
        double a = (i % 4 == 0) ? 0.0 : (i % 4 == 3) ? 300.0 * gs_splitmix_uniform(&rs) : 1.0 + 4.0 * gs_splitmix_uniform(&rs);
        render_fx(rec_matcher_bulb(m, i % nb), gs_phase_to_shift(eq7fx_p3[(i / nb) % 3]), a, g, 0.0, 1.0,
                  &rs, x, sg);
        for (int k = 0; k < 78; k++) px.x[i * 78 + k] = (float)x[k];
    }
    CHECK_OK(rec_match_pixels(m, px.x, px.sigma, px.n, px.bulb, px.phase, px.conf));
    /* a near tie of the best two pairs may go either way with float scores */
    int answered = 0, mism = eq7fx_rows_vs_lights(m, &px, 1, 1, &answered);
    CHECK_MSG(mism <= (int)(px.n / 2000), "%d of %zu rows differ from rec_match_light", mism, px.n);
    CHECK(answered > (int)px.n / 3);
    /* a fixed excess: the pixels' band weights are the lights'; only the lights' tempering for
     * the correlated excess moves their answers, on few rows (near ties of a bright light) */
    rec_matcher_free(m);
    o.model_error = 0.02;
    CHECK_OK(rec_matcher_new(d, 50, 3, 26, &o, &m));
    CHECK_OK(rec_match_pixels(m, px.x, px.sigma, px.n, px.bulb, px.phase, px.conf));
    mism = 0;
    for (size_t i = 0; i < px.n; i++) {
        for (int k = 0; k < 78; k++) {
            x[k] = px.x[i * 78 + k];
            sg[k] = px.sigma[i];
        }
        rec_match l;
        CHECK_OK(rec_match_light(m, x, sg, &l));
        mism += l.bulb != px.bulb[i] || (l.bulb >= 0 && fabs(l.phase_deg - px.phase[i]) > 1e-3);
    }
    printf("    model_error 0.02: %d of %zu answers differ from rec_match_light\n", mism, px.n);
    CHECK_MSG(mism <= (int)(px.n / 50), "%d of %zu answers differ from rec_match_light", mism, px.n);
    eq7fx_rows_free(&px);
    rec_matcher_free(m);
    gs_delight_free(d);
}

TEST(eq7_band_tolerance_and_reddening_prior_measured)
{
    /* 400 lights reddened by optical depth 1 (the model's law, f_b - 1 = (lambda_b / 550 nm)^-1.3
     * - 1 at 650/550/450 nm), each lamp's bands strayed by a Gaussian relative spread s, per-sample
     * SNR 100: rec_match_catalog measures the spread (s = 4 %: 2.8-5.6 %; s = 0: at most the tau
     * grid's floor, 2.5 %), builds the tau prior from the population, and recognises the lights. */
    gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
    rec_matcher *m = new_matcher_default(d, 3, REC_PHASES_3);
    size_t n = 400;
    rec_catalog cat = catalog_rgb26(n);
    rec_match *r = malloc(sizeof *r * n);
    const double spread[2] = {0.04, 0.0};
    for (int t = 0; t < 2; t++) {
        uint64_t rs = 97 + (uint64_t)t;
        for (size_t i = 0; i < n; i++) {
            double g[3];
            for (int b = 0; b < 3; b++)
                g[b] = exp(-(pow((650.0 - 100.0 * b) / 550.0, -1.3) - 1.0)) * (1.0 + spread[t] * gs_splitmix_normal(&rs));
            double a = 1000.0;
            render_fx(rec_matcher_bulb(m, i % 4), gs_phase_to_shift(eq7fx_p3[(i / 4) % 3]), a, g, 0.0, a / 3 / 100,
                      &rs, cat.signal + i * 78, cat.sigma + i * 78);
            cat.y_px[i] = 480.0 * gs_splitmix_uniform(&rs);
        }
        rec_noise_report nr;
        CHECK_OK(rec_match_catalog(m, &cat, r, &nr));
        int right = 0, wrong = 0;
        for (size_t i = 0; i < n; i++) {
            CHECK(eq7fx_all_finite(&r[i]));
            if (r[i].bulb < 0) continue;
            int ok = r[i].bulb == (int)(i % 4) && fabs(r[i].phase_deg - eq7fx_p3[(i / 4) % 3]) < 1e-9;
            right += ok;
            wrong += !ok;
        }
        printf("    band spread %.3f: measured tolerance %.4f, tau prior from %zu lights; %d right, %d wrong\n",
               spread[t], nr.chroma_tolerance, nr.reddening_lights, right, wrong);
        CHECK(nr.reddening_lights > n / 2);
        if (t == 0) CHECK_MSG(nr.chroma_tolerance > 0.028 && nr.chroma_tolerance < 0.056, "tolerance %g", nr.chroma_tolerance);
        else CHECK_MSG(nr.chroma_tolerance <= 0.025, "tolerance %g", nr.chroma_tolerance);
        CHECK(right >= (int)n * 95 / 100);
        CHECK(wrong <= 2);
    }
    free(r);
    rec_catalog_release(&cat);
    rec_matcher_free(m);
    gs_delight_free(d);
}

/* rec_match_catalog splits its lights over threads (both passes and the excess medians): 2 and
 * 3 threads give the one-thread answers bit for bit, with the excess measured (pass 2 runs) and
 * some lights without signal. */
TEST(eq7_catalog_threads_bit_identical_to_one_thread)
{
    gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
    const double g[3] = {1.0, 0.85, 0.7};
    size_t n = 40;
    rec_catalog cat = catalog_rgb26(n);
    unsigned *flags = calloc(n, sizeof *flags);
    rec_match *r[3];
    rec_noise_report nr[3];
    rec_phase_set sets[2] = {REC_PHASES_6, REC_PHASES_CONTINUOUS};
    for (int si = 0; si < 2; si++) {
        uint64_t rs = 77;
        rec_matcher *m[3] = {NULL, NULL, NULL};
        for (int t = 0; t < 3; t++) {
            rec_eq7_opts o;
            rec_eq7_opts_default(&o);
            o.phases = sets[si];
            o.threads = t + 1;
            CHECK_OK(rec_matcher_new(d, 50, 3, 26, &o, &m[t]));
            r[t] = calloc(n, sizeof *r[t]);
        }
        if (!m[0] || !m[1] || !m[2]) break;
        for (size_t i = 0; i < n; i++) {
            double a = 300.0 * (1.0 + (double)(i % 7)), sigma = 1000.0 / 3 / 100;
            render_fx(rec_matcher_bulb(m[0], i % 4), gs_phase_to_shift(eq7fx_p3[(i / 4) % 3]), a, g, 0.03,
                      sigma, &rs, cat.signal + i * 78, cat.sigma + i * 78);
            cat.y_px[i] = 480.0 * gs_splitmix_uniform(&rs);
            flags[i] = i % 23 == 5 ? REC_BLOB_NO_SIGNAL : 0;
        }
        cat.flags = flags;
        for (int t = 0; t < 3; t++) CHECK_OK(rec_match_catalog(m[t], &cat, r[t], &nr[t]));
        CHECK(nr[0].source == REC_NOISE_POPULATION);
        int answered = 0;
        for (size_t i = 0; i < n; i++) answered += r[0][i].bulb >= 0;
        CHECK_MSG(answered > (int)n / 2, "%d of %zu answered", answered, n);
        for (int t = 1; t < 3; t++) {
            CHECK(nr[t].source == nr[0].source && nr[t].lights_used == nr[0].lights_used &&
                  nr[t].median_model_error == nr[0].median_model_error);
            for (size_t i = 0; i < n; i++) {
                const rec_match *a = &r[0][i], *b = &r[t][i];
                int same = a->bulb == b->bulb && a->phase_deg == b->phase_deg &&
                           a->phase_sigma_deg == b->phase_sigma_deg && a->brightness == b->brightness &&
                           a->chi2 == b->chi2 && a->dof == b->dof && a->p_value == b->p_value &&
                           a->confidence == b->confidence && a->bulb_confidence == b->bulb_confidence &&
                           a->phase_confidence == b->phase_confidence && a->runner_bulb == b->runner_bulb &&
                           a->runner_phase_deg == b->runner_phase_deg &&
                           a->runner_confidence == b->runner_confidence && a->model_error == b->model_error &&
                           a->shape_p_value == b->shape_p_value && a->p_other == b->p_other &&
                           a->blend_p_value == b->blend_p_value && a->p_blend == b->p_blend &&
                           a->flags == b->flags;
                CHECK_MSG(same, "phases %d, %d threads, light %zu differs from one thread", (int)sets[si],
                          t + 1, i);
            }
        }
        for (int t = 0; t < 3; t++) {
            rec_matcher_free(m[t]);
            free(r[t]);
        }
    }
    free(flags);
    free(cat.signal);
    free(cat.sigma);
    free(cat.y_px);
    gs_delight_free(d);
}

/* n lights of bulbs 0-3 and the three phases at a per-sample SNR of snr, with a flat share of
 * their flickering flux added (x = a g_b (t + phi_i m_b), m_b the template's band mean; phi_i
 * normal of mean phi and std spread, at least 0) and 0.1 % scintillation (clear air), in rows spread over the
 * image. */
static void render_flat_catalog(const rec_matcher *m, rec_catalog *cat, size_t n, double phi, double spread,
                                double snr, uint64_t *rs)
{
    const double g[3] = {1.0, 0.85, 0.7};
    for (size_t i = 0; i < n; i++) {
        double a = 1000.0, sigma = a / snr, *x = cat->signal + i * 78;
        render_fx(rec_matcher_bulb(m, i % 4), gs_phase_to_shift(eq7fx_p3[(i / 4) % 3]), a, g, 0.001, sigma, rs,
                  x, cat->sigma + i * 78);
        double t[78], phi_i = fmax(0.0, phi + spread * gs_splitmix_normal(rs));
        eq7fx_template(rec_matcher_bulb(m, i % 4), gs_phase_to_shift(eq7fx_p3[(i / 4) % 3]), 26, t);
        for (int band = 0; band < 3; band++) {
            double mb = 0.0;
            for (int k = 0; k < 26; k++) mb += t[band * 26 + k] / 26.0;
            for (int k = 0; k < 26; k++) x[band * 26 + k] += a * g[band] * phi_i * mb;
        }
        cat->y_px[i] = 480.0 * gs_splitmix_uniform(rs);
    }
}

/* Right answers (bulb and phase) and unknown lights of a catalog rendered by render_flat_catalog. */
static void count_flat(const rec_match *r, size_t n, int *right, int *unknown)
{
    *right = *unknown = 0;
    for (size_t i = 0; i < n; i++) {
        CHECK(eq7fx_all_finite(&r[i]));
        *unknown += !!(r[i].flags & REC_MATCH_UNKNOWN);
        *right += r[i].bulb == (int)(i % 4) && fabs(r[i].phase_deg - eq7fx_p3[(i / 4) % 3]) < 1e-9 &&
                  !(r[i].flags & (REC_MATCH_UNKNOWN | REC_MATCH_PHASE_AMBIGUOUS | REC_MATCH_BULB_AMBIGUOUS));
    }
}

TEST(eq7_flat_share_measured_and_subtracted)
{
    /* A share of each light's flux that does not flicker (a halo of many lamps' scattered light
     * taken for the light's: the metro scene's flat skyglow) lowers its flicker depth; at a high
     * SNR in clear air that is a significant misfit to every template. The oracle is the injected
     * share, 0.02 with a spread of 0.006 over the lights: rec_match_catalog measures both (within
     * 20 % and 50 %), subtracts each light's, and the lights are answered, the excess noise the
     * scintillation's; without it (flat_share 0) most are unknown or ambiguous and the excess is
     * inflated by the misfit; with the injected mean fixed for every light, better but not as
     * good. With no flat share the measurement finds none (0: not significant) and every answer
     * is the same bits as with flat_share 0. */
    gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
    rec_matcher *m = new_matcher_default(d, 3, REC_PHASES_3);
    rec_eq7_opts o;
    rec_eq7_opts_default(&o);
    o.flat_share = 0.0;
    rec_matcher *m_off = NULL, *m_fix = NULL;
    CHECK_OK(rec_matcher_new(d, 50, 3, 26, &o, &m_off));
    o.flat_share = 0.02;
    CHECK_OK(rec_matcher_new(d, 50, 3, 26, &o, &m_fix));
    size_t n = 240;
    rec_catalog cat = catalog_rgb26(n);
    rec_match *r = malloc(sizeof *r * n), *r_off = malloc(sizeof *r_off * n), *r_fix = malloc(sizeof *r_fix * n);
    uint64_t rs = 73;
    render_flat_catalog(m, &cat, n, 0.02, 0.006, 2000.0, &rs);
    rec_noise_report nr, nr_off, nr_fix;
    CHECK_OK(rec_match_catalog(m, &cat, r, &nr));
    CHECK_OK(rec_match_catalog(m_off, &cat, r_off, &nr_off));
    CHECK_OK(rec_match_catalog(m_fix, &cat, r_fix, &nr_fix));
    int right, unknown, right_off, unknown_off, right_fix, unknown_fix;
    count_flat(r, n, &right, &unknown);
    count_flat(r_off, n, &right_off, &unknown_off);
    count_flat(r_fix, n, &right_fix, &unknown_fix);
    printf("    flat share 0.02 +- 0.006 at SNR 2000: measured %.5f +- %.5f from %zu lights; right %d unknown %d of %zu "
           "(off: %d, %d; fixed 0.02: %d, %d); excess %.4f (off %.4f, fixed %.4f)\n", nr.flat_share, nr.flat_spread, nr.flat_lights, right, unknown, n, right_off,
           unknown_off, right_fix, unknown_fix, nr.median_model_error, nr_off.median_model_error, nr_fix.median_model_error);
    CHECK(nr.flat_lights > n / 2 && nr_off.flat_lights == 0 && nr_off.flat_share == 0.0);
    CHECK_NEAR(nr.flat_share, 0.02, 0.004);
    CHECK_NEAR(nr.flat_spread, 0.006, 0.003);
    CHECK(nr_fix.flat_share == 0.02 && nr_fix.flat_lights == 0);
    for (int k = 0; k < REC_FLAT_KINDS; k++)   /* (a fixed share: every kind's) */
        CHECK(nr_fix.flat_kind_share[k] == 0.02 && nr_fix.flat_kind_lights[k] == 0);
    CHECK_MSG(unknown_off > (int)n / 10 && right_off < (int)n * 6 / 10, "without the flat share: %d right, %d unknown",
              right_off, unknown_off);
    CHECK_MSG(right >= (int)n * 95 / 100, "measured: %d of %zu right", right, n);
    /* one share for every light leaves the lights' spread: each light's own share is needed */
    CHECK_MSG(right_fix > right_off && right_fix < right, "fixed: %d of %zu right", right_fix, n);
    /* and the excess noise is the scintillation's (0.1 %), not the misfit's */
    CHECK_MSG(nr.median_model_error > 0.0005 && nr.median_model_error < 0.0015 && nr_off.median_model_error > 0.002,
              "excess %g, without the flat share %g (truth 0.001)", nr.median_model_error, nr_off.median_model_error);
    /* no flat share: none measured, the same answers as with it off */
    render_flat_catalog(m, &cat, n, 0.0, 0.0, 2000.0, &rs);
    CHECK_OK(rec_match_catalog(m, &cat, r, &nr));
    CHECK_OK(rec_match_catalog(m_off, &cat, r_off, &nr_off));
    CHECK_MSG(nr.flat_share == 0.0 && nr.flat_lights > n / 2, "no flat share: measured %g from %zu", nr.flat_share,
              nr.flat_lights);
    for (size_t i = 0; i < n; i++)
        CHECK(r[i].bulb == r_off[i].bulb && r[i].phase_deg == r_off[i].phase_deg &&
              r[i].confidence == r_off[i].confidence && r[i].flags == r_off[i].flags);
    count_flat(r, n, &right, &unknown);
    CHECK_MSG(right >= (int)n * 95 / 100, "no flat share: %d of %zu right", right, n);
    free(r), free(r_off), free(r_fix);
    rec_catalog_release(&cat);
    rec_matcher_free(m_fix);
    rec_matcher_free(m_off);
    rec_matcher_free(m);
    gs_delight_free(d);
}

TEST(eq7_flat_share_per_photometry_kind)
{
    /* How much of a halo a light's photometry takes depends on how it was measured: on
     * metro_clear at C = 1024 (docs/accuracy.md) the aperture lights' own shares are about 0.012,
     * the PSF fit's 0.021 and those of PSF fits on the ring of a saturated core 0.03-0.044. Each
     * light is shrunk to the share of the lights measured alike. The oracle is the injected
     * shares and the lights' bulbs and phases: 180 aperture lights at 0.012 +- 0.003 and 60
     * PSF-fit lights with a saturated pixel at 0.04 +- 0.004 (per-sample SNR 2,000). Both kinds
     * are answered right; the same lights without their kinds (one population) leave most of the
     * saturated ones unknown: their shares held within 3 spreads of the aperture lights'. */
    gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
    rec_matcher *m = new_matcher_default(d, 3, REC_PHASES_3);
    size_t n = 240, n_ap = 180;   /* n_ap a multiple of 12: the bulbs and phases go on */
    rec_catalog cat = catalog_rgb26(n);
    cat.flags = calloc(n, sizeof *cat.flags);
    rec_match *r = malloc(sizeof *r * n), *r_one = malloc(sizeof *r_one * n);
    CHECK(cat.flags && r && r_one);
    uint64_t rs = 79;
    rec_catalog ring = cat;
    ring.signal += n_ap * 78;
    ring.sigma += n_ap * 78;
    ring.y_px += n_ap;
    render_flat_catalog(m, &cat, n_ap, 0.012, 0.003, 2000.0, &rs);
    render_flat_catalog(m, &ring, n - n_ap, 0.04, 0.004, 2000.0, &rs);
    CHECK_OK(rec_match_catalog(m, &cat, r_one, NULL));
    for (size_t i = n_ap; i < n; i++) cat.flags[i] = REC_BLOB_PSF_FIT | REC_BLOB_SATURATED;
    rec_noise_report nr;
    CHECK_OK(rec_match_catalog(m, &cat, r, &nr));
    int right_ap, unknown_ap, right_ring, unknown_ring, right_one, unknown_one;
    count_flat(r, n_ap, &right_ap, &unknown_ap);
    count_flat(r + n_ap, n - n_ap, &right_ring, &unknown_ring);
    count_flat(r_one + n_ap, n - n_ap, &right_one, &unknown_one);
    printf("    aperture lights at 0.012: %d of %zu right (%d unknown); saturated PSF fits at 0.04: %d of %zu right "
           "(%d unknown), as one population %d (%d unknown); the capture's share %.4f +- %.4f\n",
           right_ap, n_ap, unknown_ap, right_ring, n - n_ap, unknown_ring, right_one, unknown_one, nr.flat_share,
           nr.flat_spread);
    CHECK_NEAR(nr.flat_share, 0.012, 0.003);
    /* the report: each kind's share from its own lights; the kinds without lights the capture's */
    printf("    kinds: aperture %.4f from %zu, saturated PSF fits %.4f from %zu\n", nr.flat_kind_share[0],
           nr.flat_kind_lights[0], nr.flat_kind_share[3], nr.flat_kind_lights[3]);
    CHECK_NEAR(nr.flat_kind_share[0], 0.012, 0.003);
    CHECK_NEAR(nr.flat_kind_share[3], 0.04, 0.006);
    CHECK(nr.flat_kind_lights[0] > n_ap / 2 && nr.flat_kind_lights[0] <= n_ap);
    CHECK(nr.flat_kind_lights[3] > (n - n_ap) / 2 && nr.flat_kind_lights[3] <= n - n_ap);
    CHECK(nr.flat_kind_lights[1] == 0 && nr.flat_kind_lights[2] == 0);
    CHECK(nr.flat_kind_share[1] == nr.flat_share && nr.flat_kind_share[2] == nr.flat_share);
    CHECK_MSG(right_ap >= (int)n_ap * 95 / 100, "aperture lights: %d of %zu right", right_ap, n_ap);
    CHECK_MSG(right_ring >= (int)(n - n_ap) * 95 / 100, "saturated PSF fits: %d of %zu right", right_ring, n - n_ap);
    CHECK_MSG(unknown_one > (int)(n - n_ap) / 2, "one population: %d of %zu unknown", unknown_one, n - n_ap);
    free(r), free(r_one);
    rec_catalog_release(&cat);
    rec_matcher_free(m);
    gs_delight_free(d);
}
