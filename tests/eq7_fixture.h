/* eq7_fixture.h - what the Eq. 7 tests (tests/test_eq7*.c) share, implemented in
 * tests/eq7_fixture.c, prefix eq7fx_: a hand-made DELIGHT (sums of harmonics, sawtooth, a
 * sodium-like gap, a near-flat BRF, two near-identical bulbs, one shape no other bulb has),
 * the brute-force oracle (bulb x phase x sample in plain doubles, from the model in
 * docs/recognition.md, independently of recognize/eq7.c), rendered lights, and the
 * comparison of rec_match_pixels with rec_match_light. Failures are test failures (CHECKs). */
#ifndef GRIDSURVEY_TESTS_EQ7_FIXTURE_H
#define GRIDSURVEY_TESTS_EQ7_FIXTURE_H

#include "recognize/recognize.h"

#include <stddef.h>
#include <stdint.h>

/* ------------------------------------------------------------------ the hand-made DELIGHT */

/* The shapes, t in cycles (per-band lag and depth like phosphors). */
enum { SHAPE_SINE, SHAPE_SAW, SHAPE_HARM, SHAPE_GAP, SHAPE_FLAT, SHAPE_SINE_TWIN, SHAPE_ODD };

/* Chromaticities by bulb: sine, saw, harm, gap, flat, sine-twin (= sine's), odd. */
extern const double eq7fx_chroma[7][3];
/* The 3-phase set, degrees. */
extern const double eq7fx_p3[3];

/* A shape's value at t cycles in band 0..2. */
double eq7fx_shape_at(int shape, double t, int band);
/* Bulb `id` of a shape with n samples per band (bands 1 or 3, chroma used for 3), its BRF
 * normalised (mean 1); release with gs_bulb_release. */
void eq7fx_make_bulb(gs_bulb *b, const char *id, int shape, int grid_hz, int bands, gs_ref ref,
                     const double *chroma, int n);
/* sine, saw, harm, gap, flat at grid_hz (and optionally the twin of sine, and every id at the
 * other grid frequency with SHAPE_ODD, which must never be a candidate), bands 1 or 3. */
gs_delight *eq7fx_make_db(int grid_hz, int bands, int with_twin, int with_other_grid);

/* ------------------------------------------------------------------ the oracle */

/* Template of bulb b at shift s (cycles): chroma * Eq. 5 window means, t[band * K + k]. */
void eq7fx_template(const gs_bulb *b, double s, int K, double *t);
/* log Phi(z), written independently of eq7.c (fine for z > -35). */
double eq7fx_log_phi(double z);

/* The brute-force Eq. 7 posterior's answer for a discrete phase set. */
typedef struct {
    int bulb;
    double phase_deg, conf, bulb_conf, phase_conf, chi2, brightness;
    int runner_bulb;
    double runner_phase_deg, runner_conf;
    double z;   /* brightness / its std */
} eq7fx_oracle_result;

/* Templates of every candidate bulb (the matcher's filter, in database order) at np phases,
 * computed once: t[(b * np + p) * D + k]; the caller frees t. */
typedef struct {
    int nb, np, D, K;
    double *t;
} eq7fx_ttab;

void eq7fx_ttab_init(eq7fx_ttab *tb, const gs_delight *d, int grid_hz, int bands, int K,
                     const double *ph, int np);
const double *eq7fx_ttab_row(const eq7fx_ttab *tb, int b, int p);
/* The posterior over every bulb x every phase ph[] of tb for samples x with std sigma
 * (non-finite values and sigma <= 0 are skipped). */
void eq7fx_oracle_discrete(const eq7fx_ttab *tb, const double *ph, const double *x,
                           const double *sigma, eq7fx_oracle_result *r);

/* ------------------------------------------------------------------ lights */

/* A light from a template: a * t + Gaussian noise of std sigma from the stream rs (sigma 0:
 * noiseless, reported sigma 1e-9 a). D = bands * K samples. */
void eq7fx_render_t(const double *t, int D, double a, double sigma, uint64_t *rs, double *x,
                    double *sg);
/* The same for bulb b at shift s. */
void eq7fx_render(const gs_bulb *b, double s, int K, double a, double sigma, uint64_t *rs,
                  double *x, double *sg);
/* Every field of r finite and in range. */
int eq7fx_all_finite(const rec_match *r);
/* Circular distance of two shifts (cycles). */
double eq7fx_cdist(double a, double b);

/* A matcher of the paper's model (one brightness times Q_beta, exact templates: what the
 * brute-force oracles implement; band_gains = 0, model_error = 0); NULL and a test failure on
 * error. */
rec_matcher *eq7fx_new_matcher(const gs_delight *d, int grid_hz, int bands, int K,
                               rec_phase_set ps);

/* ------------------------------------------------------------------ pixels */

/* n rows of 78 samples (RGB, K = 26) with sigma 1 each, and rec_match_pixels' answers. */
typedef struct {
    size_t n;
    float *x, *sigma;
    int *bulb;
    float *phase, *conf;
} eq7fx_rows;

void eq7fx_rows_alloc(eq7fx_rows *r, size_t n);
void eq7fx_rows_free(eq7fx_rows *r);
/* rec_match_light on rows 0, step, 2 step, ... against the pixel answers (call
 * rec_match_pixels first): the rows that differ in the bulb, or in the phase by more than
 * 1e-3 deg or the confidence by more than 2e-4 (with ties_ok, a near tie of the best two pairs,
 * |confidence - runner's| < 1e-3, is not counted); the first five are printed. Rows
 * rec_match_light gave a bulb in *answered (may be NULL). Rows the light path flags by a
 * nested-model test (blend, shape; the pixel path has none) are skipped, and must be rare. */
int eq7fx_rows_vs_lights(const rec_matcher *m, const eq7fx_rows *r, size_t step, int ties_ok,
                         int *answered);

#endif
