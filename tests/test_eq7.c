/* test_eq7.c - Eq. 7 recognition (recognize/eq7.c) against independent oracles: a brute-force
 * triple loop (bulb x phase x sample, plain doubles, tests/eq7_fixture.h, written from the model
 * in docs/recognition.md) on every bulb, phase and window count K, and closed forms of the
 * chi-square tail. DELIGHT sets are built by hand (tests/eq7_fixture.h); the generated DELIGHT
 * is used where named. The other Eq. 7 tests: tests/test_eq7_hard.c (named hard cases,
 * shared/STYLE.md rule 13), test_eq7_continuous.c (continuous phases), test_eq7_pixels.c
 * (catalogs and pixels), test_eq7_model.c (band gains and model error). */
#include "recognize/recognize.h"
#include "tests/eq7_fixture.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* rec_match_light and rec_match_pixels against the brute-force oracle on noisy lights of every
 * bulb and phase at several SNRs (3-phase set). */
static void compare_with_oracle(int grid_hz, int bands, int K, int trials, uint64_t seed)
{
    gs_delight *d = eq7fx_make_db(grid_hz, bands, 1, 1);
    rec_matcher *m = eq7fx_new_matcher(d, grid_hz, bands, K, REC_PHASES_3);
    int D = bands * K;
    size_t nb = rec_matcher_bulb_count(m);
    CHECK(nb == 6);
    double *x = malloc(sizeof *x * (size_t)D), *sg = malloc(sizeof *sg * (size_t)D);
    float *xf = malloc(sizeof *xf * (size_t)D * (size_t)trials), *sf = malloc(sizeof *sf * (size_t)trials);
    eq7fx_oracle_result *orr = malloc(sizeof *orr * (size_t)trials);
    eq7fx_ttab tb;
    eq7fx_ttab_init(&tb, d, grid_hz, bands, K, eq7fx_p3, 3);
    CHECK(tb.nb == (int)nb);
    uint64_t rs = seed;
    int compared = 0;
    for (int i = 0; i < trials; i++) {
        int bi = i % (int)nb, pi = (i / (int)nb) % 3;
        double snr = (i % 4 == 0) ? 2.0 : (i % 4 == 1) ? 8.0 : (i % 4 == 2) ? 30.0 : 200.0;
        double a = 1000.0;
        double sigma = a / bands / snr;   /* a template's mean sample is 1/bands */
        eq7fx_render_t(eq7fx_ttab_row(&tb, bi, pi), D, a, sigma, &rs, x, sg);
        for (int k = 0; k < D; k++) xf[(size_t)i * (size_t)D + (size_t)k] = (float)x[k];
        sf[i] = (float)sigma;
        rec_match r;
        CHECK_OK(rec_match_light(m, x, sg, &r));
        CHECK(eq7fx_all_finite(&r));
        eq7fx_oracle_discrete(&tb, eq7fx_p3, x, sg, &orr[i]);
        eq7fx_oracle_result *o = &orr[i];
        int answer = r.bulb >= 0 ? r.bulb : r.runner_bulb;   /* dim/unknown: best fit in runner */
        double conf = r.bulb >= 0 ? r.confidence : r.runner_confidence;
        double ph = r.bulb >= 0 ? r.phase_deg : r.runner_phase_deg;
        CHECK_MSG(answer == o->bulb, "trial %d: bulb %d, oracle %d", i, answer, o->bulb);
        CHECK_NEAR(ph, o->phase_deg, 1e-9);
        CHECK_NEAR(conf, o->conf, 1e-9);
        CHECK_NEAR(r.chi2, o->chi2, 1e-7 * (1 + o->chi2));
        CHECK_NEAR(r.brightness, o->brightness, 1e-9 * a);
        if (r.bulb >= 0) {
            CHECK_NEAR(r.bulb_confidence, o->bulb_conf, 1e-9);
            CHECK_NEAR(r.phase_confidence, o->phase_conf, 1e-9);
            CHECK(r.runner_bulb == o->runner_bulb);
            CHECK_NEAR(r.runner_phase_deg, o->runner_phase_deg, 1e-9);
            CHECK_NEAR(r.runner_confidence, o->runner_conf, 1e-9);
            CHECK(!!(r.flags & REC_MATCH_BULB_AMBIGUOUS) == (o->bulb_conf < 0.8));
            CHECK(!!(r.flags & REC_MATCH_PHASE_AMBIGUOUS) == (o->phase_conf < 0.8));
            compared++;
        }
        CHECK(!!(r.flags & REC_MATCH_DIM) == (o->z < 3.0));
        CHECK_NEAR(r.p_value, gs_chi2_sf(o->chi2, D - 2), 1e-9);
    }
    CHECK(compared > trials / 2);
    /* the pixel path on the same rows */
    int *pb = malloc(sizeof *pb * (size_t)trials);
    float *pp = malloc(sizeof *pp * (size_t)trials), *pc = malloc(sizeof *pc * (size_t)trials);
    CHECK_OK(rec_match_pixels(m, xf, sf, (size_t)trials, pb, pp, pc));
    double p_thr = 1e-3;
    for (int i = 0; i < trials; i++) {
        eq7fx_oracle_result *o = &orr[i];
        int unknown = gs_chi2_sf(o->chi2, D - 2) < p_thr;
        int expect = (o->z < 3.0 || unknown) ? -1 : o->bulb;
        /* float input: skip rows whose decision sits on a knife edge */
        if (fabs(o->z - 3.0) < 1e-3 || fabs(gs_chi2_sf(o->chi2, D - 2) - p_thr) < 1e-5) continue;
        CHECK_MSG(pb[i] == expect, "pixel %d: bulb %d, oracle %d", i, pb[i], expect);
        if (expect >= 0) {
            CHECK_NEAR(pp[i], o->phase_deg, 1e-3);
            CHECK_NEAR(pc[i], o->conf, 2e-4);
        } else {
            CHECK(pc[i] == 0.0f);
        }
    }
    free(pb);
    free(pp);
    free(pc);
    free(x);
    free(sg);
    free(xf);
    free(sf);
    free(orr);
    free(tb.t);
    rec_matcher_free(m);
    gs_delight_free(d);
}

/* Noiseless lights of every bulb at every phase are recovered with confidence ~1 (sigma 1e-7 of
 * the brightness per sample). Templates that coincide (K too small to tell them apart) must be
 * reported ambiguous instead. */
static void exact_recovery(gs_delight *d, int grid_hz, int bands, int K, rec_phase_set ps,
                           const double *phases, int np)
{
    rec_matcher *m = eq7fx_new_matcher(d, grid_hz, bands, K, ps);
    int D = bands * K;
    double *x = malloc(sizeof *x * (size_t)D), *sg = malloc(sizeof *sg * (size_t)D);
    eq7fx_ttab tb;
    eq7fx_ttab_init(&tb, d, grid_hz, bands, K, phases, np);
    size_t nb = rec_matcher_bulb_count(m);
    CHECK(tb.nb == (int)nb);
    uint64_t rs = 1;
    for (size_t b = 0; b < nb; b++)
        for (int p = 0; p < np; p++) {
            eq7fx_render_t(eq7fx_ttab_row(&tb, (int)b, p), D, 50.0, 0.0, &rs, x, sg);
            /* nearest other (bulb, phase) template: relative residual after the best scale */
            double dmin = INFINITY;
            for (size_t b2 = 0; b2 < nb; b2++)
                for (int p2 = 0; p2 < np; p2++) {
                    if (b2 == b && p2 == p) continue;
                    const double *t2 = eq7fx_ttab_row(&tb, (int)b2, p2);
                    double num = 0, tt = 0, xx = 0;
                    for (int k = 0; k < D; k++) {
                        num += x[k] * t2[k];
                        tt += t2[k] * t2[k];
                        xx += x[k] * x[k];
                    }
                    double res = xx - num * num / tt;
                    res = res > 0 ? sqrt(res / xx) : 0;
                    dmin = res < dmin ? res : dmin;
                }
            rec_match r;
            CHECK_OK(rec_match_light(m, x, sg, &r));
            CHECK(eq7fx_all_finite(&r));
            if (dmin > 1e-5) {
                CHECK_MSG(r.bulb == (int)b, "K=%d bulb %zu phase %g: got %d (flags %u)", K, b,
                          phases[p], r.bulb, r.flags);
                CHECK_MSG(fabs(r.phase_deg - phases[p]) < 1e-9, "K=%d bulb %zu phase %g: phase %g",
                          K, b, phases[p], r.phase_deg);
                CHECK(r.confidence > 0.999);
                CHECK(!(r.flags & (REC_MATCH_BULB_AMBIGUOUS | REC_MATCH_PHASE_AMBIGUOUS |
                                   REC_MATCH_UNKNOWN | REC_MATCH_DIM)));
                CHECK_NEAR(r.brightness, 50.0, 1e-6);
            } else {
                /* indistinguishable: never a confident wrong answer */
                int wrong = r.bulb != (int)b || fabs(r.phase_deg - phases[p]) > 1e-9;
                CHECK(!(wrong && r.confidence > 0.8));
            }
        }
    free(x);
    free(sg);
    free(tb.t);
    rec_matcher_free(m);
}

/* closed forms: even dof: Q = e^{-x} sum_{j < dof/2} x^j / j!; odd dof: erfc(sqrt x) +
 * e^{-x} sum_{j=1}^{(dof-1)/2} x^{j-1/2} / Gamma(j + 1/2), x = chi2/2 */
static double chi2_sf_closed(double chi2, int dof)
{
    double x = chi2 / 2, s = 0;
    if (dof % 2 == 0) {
        double term = 1;
        for (int j = 0; j < dof / 2; j++) {
            if (j) term *= x / j;
            s += term;
        }
        return exp(-x) * s;
    }
    double term = sqrt(x) / tgamma(1.5);
    for (int j = 1; j <= (dof - 1) / 2; j++) {
        if (j > 1) term *= x / (j - 0.5);
        s += term;
    }
    return erfc(sqrt(x)) + exp(-x) * s;
}

TEST(eq7_chi2_sf_known_values)
{
    /* textbook critical values */
    CHECK_NEAR(gs_chi2_sf(3.841458820694124, 1), 0.05, 1e-14);
    CHECK_NEAR(gs_chi2_sf(5.991464547107979, 2), 0.05, 1e-14);
    CHECK_NEAR(gs_chi2_sf(16.918977604620448, 9), 0.05, 1e-13);
    CHECK_NEAR(gs_chi2_sf(6.634896601021214, 1), 0.01, 1e-14);
    int dofs[] = {1, 2, 3, 4, 5, 10, 11, 24, 37, 76, 77, 200, 1001};
    for (size_t i = 0; i < sizeof dofs / sizeof *dofs; i++)
        for (double c = 0.01; c < 1400; c *= 1.37) {
            int dof = dofs[i];
            double want = chi2_sf_closed(c, dof), got = gs_chi2_sf(c, dof);
            if (want > 1e-280)
                CHECK_MSG(fabs(got - want) <= 1e-12 * want + 1e-15, "dof %d chi2 %g: %.17g vs %.17g",
                          dof, c, got, want);
        }
    CHECK(gs_chi2_sf(0, 5) == 1.0);
    CHECK(gs_chi2_sf(-3, 5) == 1.0);
    CHECK(isnan(gs_chi2_sf(5, 0)));   /* no degrees of freedom: undefined */
    CHECK(gs_chi2_sf(INFINITY, 5) == 0.0);
    CHECK(isnan(gs_chi2_sf(NAN, 5)));
    CHECK(gs_chi2_sf(1e6, 76) >= 0.0 && gs_chi2_sf(1e6, 76) < 1e-300);
    /* far beyond: 0, not NaN (the fraction's recurrences would overflow between rescalings) */
    CHECK(gs_chi2_sf(1e40, 1) == 0.0 && gs_chi2_sf(1e300, 76) == 0.0 && gs_chi2_sf(1.7e308, 1001) == 0.0);
    /* large dof: the mean is near the median (Wilson-Hilferty: Q(dof) ~ 0.5 - 0.0188/sqrt(...)) */
    double q = gs_chi2_sf(20000, 20000);
    CHECK(q > 0.49 && q < 0.5);
}

TEST(eq7_matcher_arguments)
{
    gs_delight *d = eq7fx_make_db(50, 3, 0, 1);
    rec_matcher *m = (rec_matcher *)&m;
    CHECK(rec_matcher_new(d, 55, 3, 26, NULL, &m) == GS_EINVAL && m == NULL);
    CHECK(rec_matcher_new(d, 50, 2, 26, NULL, &m) == GS_EINVAL);
    CHECK(rec_matcher_new(d, 50, 3, 1, NULL, &m) == GS_EINVAL);
    CHECK(rec_matcher_new(NULL, 50, 3, 26, NULL, &m) == GS_EINVAL);
    CHECK(rec_matcher_new(d, 50, 3, 26, NULL, NULL) == GS_EINVAL);
    CHECK(rec_matcher_new(d, 50, 1, 26, NULL, &m) == GS_ENOTFOUND);   /* no mono entries */
    rec_eq7_opts o;
    rec_eq7_opts_default(&o);
    CHECK(o.phases == REC_PHASES_3 && o.transformer_deg == 30 && o.unknown_p == 1e-3 &&
          o.ambiguous_conf == 0.8 && o.min_snr == 3);
    o.phases = REC_PHASES_6;
    o.transformer_deg = 60;   /* 60 deg repeats the shift of 240 deg */
    CHECK(rec_matcher_new(d, 50, 3, 26, &o, &m) == GS_EINVAL);
    o.transformer_deg = NAN;
    CHECK(rec_matcher_new(d, 50, 3, 26, &o, &m) == GS_EINVAL);
    rec_eq7_opts_default(&o);
    o.unknown_p = 1.0;
    CHECK(rec_matcher_new(d, 50, 3, 26, &o, &m) == GS_EINVAL);
    rec_eq7_opts_default(&o);
    o.ambiguous_conf = -0.1;
    CHECK(rec_matcher_new(d, 50, 3, 26, &o, &m) == GS_EINVAL);
    rec_eq7_opts_default(&o);
    o.min_snr = NAN;
    CHECK(rec_matcher_new(d, 50, 3, 26, &o, &m) == GS_EINVAL);
    rec_eq7_opts_default(&o);
    o.phases = (rec_phase_set)7;
    CHECK(rec_matcher_new(d, 50, 3, 26, &o, &m) == GS_EINVAL);
    rec_eq7_opts_default(&o);
    CHECK(o.max_drift_windows == REC_DRIFT_AUTO);
    o.max_drift_windows = -0.1;
    CHECK(rec_matcher_new(d, 50, 3, 26, &o, &m) == GS_EINVAL);
    o.max_drift_windows = NAN;
    CHECK(rec_matcher_new(d, 50, 3, 26, &o, &m) == GS_EINVAL);
    o.max_drift_windows = INFINITY;   /* (none) */
    CHECK_OK(rec_matcher_new(d, 50, 3, 26, &o, &m));
    rec_matcher_free(m);
    m = NULL;
    /* unlocked entries are never candidates */
    gs_bulb b;
    eq7fx_make_bulb(&b, "pwm", SHAPE_FLAT, 50, 3, GS_REF_UNLOCKED, eq7fx_chroma[0], 64);
    CHECK_OK(gs_delight_add(d, &b));
    gs_bulb_release(&b);
    CHECK_OK(rec_matcher_new(d, 50, 3, 26, NULL, &m));
    CHECK(rec_matcher_bulb_count(m) == 5);
    for (size_t i = 0; i < rec_matcher_bulb_count(m); i++) {
        CHECK(rec_matcher_bulb(m, i)->ref != GS_REF_UNLOCKED);
        CHECK(rec_matcher_bulb(m, i)->grid_hz == 50);
    }
    CHECK(rec_matcher_bulb(m, 5) == NULL);
    /* the matcher borrows nothing from d */
    gs_delight_free(d);
    CHECK(strcmp(rec_matcher_bulb(m, 1)->id, "saw") == 0);
    CHECK_NEAR(rec_matcher_bulb(m, 1)->brf.v[3], eq7fx_shape_at(SHAPE_SAW, 3.0 / 1024, 0) /
               1.0, 0.5);
    double x[78], s[78];
    rec_match r;
    for (int k = 0; k < 78; k++) x[k] = s[k] = 1;
    CHECK(rec_match_light(NULL, x, s, &r) == GS_EINVAL);
    CHECK(rec_match_light(m, NULL, s, &r) == GS_EINVAL);
    CHECK(rec_match_light(m, x, s, NULL) == GS_EINVAL);
    CHECK(rec_match_pixels(m, NULL, NULL, 0, NULL, NULL, NULL) == GS_OK);
    CHECK(rec_match_pixels(m, NULL, NULL, 3, NULL, NULL, NULL) == GS_EINVAL);
    rec_matcher_free(m);
    rec_matcher_free(NULL);
    CHECK(rec_matcher_bulb_count(NULL) == 0);
    rec_eq7_opts_default(NULL);
}

TEST(eq7_matches_brute_force_rgb_k26)
{
    compare_with_oracle(50, 3, 26, 400, 11);
}

TEST(eq7_matches_brute_force_mono_k13)
{
    compare_with_oracle(50, 1, 13, 400, 12);
}

TEST(eq7_exact_recovery_3_phases)
{
    gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
    exact_recovery(d, 50, 3, 26, REC_PHASES_3, eq7fx_p3, 3);
    gs_delight_free(d);
    d = eq7fx_make_db(50, 1, 0, 0);
    exact_recovery(d, 50, 1, 26, REC_PHASES_3, eq7fx_p3, 3);
    gs_delight_free(d);
}

TEST(eq7_exact_recovery_generated_delight)
{
    /* every 50 Hz RGB bulb of the built-in DELIGHT at every phase, K = 26 */
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, 1024));
    exact_recovery(d, 50, 3, 26, REC_PHASES_3, eq7fx_p3, 3);
    gs_delight_free(d);
}

TEST(eq7_six_phase_transformer)
{
    /* A delta-wye transformer shifts the AC by +-30 deg (+-60 deg of flicker phase, shared/BULBS.md):
     * with REC_PHASES_6 lights at 30/150/270 are recovered exactly; with the 3-phase set the
     * same lights are not given a confident wrong phase (unknown or ambiguous). */
    gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
    double P6[6] = {0, 120, 240, 30, 150, 270};
    exact_recovery(d, 50, 3, 26, REC_PHASES_6, P6, 6);
    rec_eq7_opts o;
    rec_eq7_opts_default(&o);
    o.phases = REC_PHASES_6;
    o.transformer_deg = -30;   /* 330, 90, 210: the same shifts as +30, reported as this set */
    rec_matcher *m6 = NULL, *m3 = NULL;
    CHECK_OK(rec_matcher_new(d, 50, 3, 26, &o, &m6));
    CHECK_OK(rec_matcher_new(d, 50, 3, 26, NULL, &m3));
    double x[78], sg[78];
    uint64_t rs = 5;
    double Pm[3] = {330, 90, 210};
    for (size_t b = 0; b < 4; b++)   /* not the flat bulb */
        for (int p = 0; p < 3; p++) {
            eq7fx_render(rec_matcher_bulb(m6, b), gs_phase_to_shift(Pm[p]), 26, 100.0, 0.5, &rs, x, sg);
            rec_match r;
            CHECK_OK(rec_match_light(m6, x, sg, &r));
            CHECK(r.bulb == (int)b && fabs(r.phase_deg - Pm[p]) < 1e-9);
            CHECK_OK(rec_match_light(m3, x, sg, &r));
            int confident_phase = r.bulb >= 0 && !(r.flags & REC_MATCH_PHASE_AMBIGUOUS);
            CHECK_MSG(!confident_phase, "bulb %zu phase %g: 3-phase set answered phase %g conf %g",
                      b, Pm[p], r.phase_deg, r.phase_confidence);
        }
    rec_matcher_free(m6);
    rec_matcher_free(m3);
    gs_delight_free(d);
}

TEST(eq7_k2)
{
    /* K = 2: one flicker number per band. Mono has dof = 0 (no chi-square test, p = 1). */
    gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
    exact_recovery(d, 50, 3, 2, REC_PHASES_3, eq7fx_p3, 3);
    compare_with_oracle(50, 3, 2, 120, 21);
    gs_delight_free(d);
    d = eq7fx_make_db(50, 1, 0, 0);
    rec_matcher *m = eq7fx_new_matcher(d, 50, 1, 2, REC_PHASES_3);
    double x[2], sg[2];
    uint64_t rs = 3;
    eq7fx_render(rec_matcher_bulb(m, 1), 0.0, 2, 10.0, 0.01, &rs, x, sg);
    rec_match r;
    CHECK_OK(rec_match_light(m, x, sg, &r));
    CHECK(eq7fx_all_finite(&r));
    CHECK(r.dof == 0 && r.p_value == 1.0 && !(r.flags & REC_MATCH_UNKNOWN));
    /* two numbers cannot identify one of 15 (bulb, phase) pairs: ambiguous, never confident-wrong */
    CHECK(r.bulb != -1 || (r.flags & REC_MATCH_DIM));
    rec_matcher_free(m);
    gs_delight_free(d);
}

TEST(eq7_k_not_multiple_of_3)
{
    int Ks[] = {13, 7, 5};
    for (int i = 0; i < 3; i++) {
        gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
        exact_recovery(d, 50, 3, Ks[i], REC_PHASES_3, eq7fx_p3, 3);
        double P6[6] = {0, 120, 240, 30, 150, 270};
        exact_recovery(d, 50, 3, Ks[i], REC_PHASES_6, P6, 6);
        gs_delight_free(d);
        compare_with_oracle(50, 3, Ks[i], 120, 30 + (uint64_t)i);
    }
}

TEST(eq7_k26)
{
    gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
    exact_recovery(d, 50, 3, 26, REC_PHASES_3, eq7fx_p3, 3);
    gs_delight_free(d);
    compare_with_oracle(50, 3, 26, 200, 41);
    compare_with_oracle(50, 1, 26, 200, 42);
}

TEST(eq7_60hz)
{
    /* 60 Hz entries only (the 50 Hz entries with the same ids have another shape) */
    gs_delight *d = eq7fx_make_db(60, 3, 0, 1);
    rec_matcher *m = eq7fx_new_matcher(d, 60, 3, 20, REC_PHASES_3);
    CHECK(rec_matcher_bulb_count(m) == 5);
    for (size_t b = 0; b < 5; b++) CHECK(rec_matcher_bulb(m, b)->grid_hz == 60);
    rec_matcher_free(m);
    exact_recovery(d, 60, 3, 20, REC_PHASES_3, eq7fx_p3, 3);
    gs_delight_free(d);
    compare_with_oracle(60, 3, 20, 200, 51);
    /* the generated DELIGHT at 60 Hz */
    d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, 1024));
    exact_recovery(d, 60, 3, 26, REC_PHASES_3, eq7fx_p3, 3);
    gs_delight_free(d);
}
