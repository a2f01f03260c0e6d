/* test_eq7_continuous.c - Eq. 7 with continuous phases (recognize/eq7.c): exact sub-sample
 * recovery, the templates against closed-form Eq. 5 window means of trigonometric shapes, a
 * fine-grid oracle with golden-section refinement for noisy lights, and the wraparound of
 * the phase at 0 with a calibrated sigma. */
#include "recognize/recognize.h"
#include "tests/eq7_fixture.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Closed-form Eq. 5 window means of the trigonometric shapes (sine, saw, harm): the mean of
 * cos(2 pi h (t - s) + phi) over [k/K, (k+1)/K] is
 * [sin(2 pi h ((k+1)/K - s) + phi) - sin(2 pi h (k/K - s) + phi)] K / (2 pi h).
 * Independent of recognize/ (no FFT); their sample means are 1, so normalising changes nothing. */
static int harmonic_terms(int shape, int band, int *h, double *amp, double *phi)
{
    int n = 0;
    switch (shape) {
    case SHAPE_SINE:
        h[n] = 1, amp[n] = 0.25 + 0.05 * band, phi[n++] = -2 * M_PI * (0.24 + 0.01 * band);
        break;
    case SHAPE_SAW:
        for (int k = 1; k <= 15; k++) h[n] = k, amp[n] = 0.18 / k, phi[n++] = -2 * M_PI * k * 0.3 - M_PI / 2;
        break;
    case SHAPE_HARM:
        h[n] = 1, amp[n] = 0.3 - 0.08 * band, phi[n++] = -2 * M_PI * (0.33 + 0.04 * band);
        h[n] = 2, amp[n] = 0.12, phi[n++] = 1.0 + 0.3 * band;
        h[n] = 3, amp[n] = 0.05, phi[n++] = -M_PI / 2;
        break;
    }
    return n;
}

static void analytic_template(int shape, const double *chroma, double s, int K, double *t)
{
    int h[16];
    double amp[16], phi[16];
    for (int band = 0; band < 3; band++) {
        int n = harmonic_terms(shape, band, h, amp, phi);
        for (int k = 0; k < K; k++) {
            double v = 1.0;
            for (int i = 0; i < n; i++) {
                double w = 2 * M_PI * h[i];
                v += amp[i] * (sin(w * ((double)(k + 1) / K - s) + phi[i]) - sin(w * ((double)k / K - s) + phi[i])) *
                     K / w;
            }
            t[band * K + k] = chroma[band] * v;
        }
    }
}

TEST(eq7_exact_recovery_continuous_subsample)
{
    gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
    rec_matcher *m = eq7fx_new_matcher(d, 50, 3, 26, REC_PHASES_CONTINUOUS);
    double x[78], sg[78];
    uint64_t rs = 2;
    double shifts[] = {0.0, 0.0123456, 1.0 / 3, 0.5004, 0.77777, 0.9991, 0.3141592};
    for (size_t b = 0; b < 4; b++)
        for (size_t i = 0; i < sizeof shifts / sizeof *shifts; i++) {
            eq7fx_render(rec_matcher_bulb(m, b), shifts[i], 26, 80.0, 0.0, &rs, x, sg);
            rec_match r;
            CHECK_OK(rec_match_light(m, x, sg, &r));
            CHECK(eq7fx_all_finite(&r));
            CHECK(r.bulb == (int)b);
            double s = gs_phase_to_shift(r.phase_deg);
            CHECK_MSG(eq7fx_cdist(s, shifts[i]) < 1e-7, "bulb %zu shift %g: got %.9f", b, shifts[i], s);
            CHECK(r.phase_sigma_deg < 1e-4 && r.phase_sigma_deg > 0);
            CHECK(r.confidence > 0.999);
            CHECK_NEAR(r.brightness, 80.0, 1e-5);
            /* lights rendered with gs_brf_integrate, noise 1e-9 of the brightness: the
             * matcher's Fourier templates agree to ~1e-11 */
            CHECK_MSG(r.chi2 < 1e-2, "bulb %zu shift %g: chi2 %g", b, shifts[i], r.chi2);
        }
    /* the pixel path: parabolic refinement of the grid scores, within a small part of a cell */
    float xf[7 * 78], sf[7];
    for (size_t i = 0; i < 7; i++) {
        eq7fx_render(rec_matcher_bulb(m, 2), shifts[i], 26, 80.0, 0.0, &rs, x, sg);
        for (int k = 0; k < 78; k++) xf[i * 78 + k] = (float)x[k];
        sf[i] = 1e-3f;
    }
    int pb[7];
    float pp[7], pc[7];
    CHECK_OK(rec_match_pixels(m, xf, sf, 7, pb, pp, pc));
    for (size_t i = 0; i < 7; i++) {
        CHECK(pb[i] == 2);
        CHECK_MSG(eq7fx_cdist(gs_phase_to_shift(pp[i]), shifts[i]) < 0.1 / 208, "pixel shift %g: %g",
                  shifts[i], gs_phase_to_shift(pp[i]));
    }
    rec_matcher_free(m);
    gs_delight_free(d);
}

TEST(eq7_analytic_templates)
{
    /* the matcher's templates (gs_brf_integrate) against the closed form, any shift */
    int shapes[3] = {SHAPE_SINE, SHAPE_SAW, SHAPE_HARM};
    const char *ids[3] = {"sine", "saw", "harm"};
    double t[78], ta[78];
    uint64_t rs = 31;
    for (int i = 0; i < 3; i++) {
        gs_bulb b;
        eq7fx_make_bulb(&b, ids[i], shapes[i], 50, 3, GS_REF_VOLTAGE, eq7fx_chroma[i], 1024);
        for (int trial = 0; trial < 20; trial++) {
            double sh = gs_splitmix_uniform(&rs);
            eq7fx_template(&b, sh, 26, t);
            analytic_template(shapes[i], eq7fx_chroma[i], sh, 26, ta);
            for (int k = 0; k < 78; k++) CHECK_NEAR(t[k], ta[k], 1e-12);
        }
        gs_bulb_release(&b);
    }
}

/* Continuous phases with noise against a fine-grid oracle on closed-form templates: 2048 shifts
 * per cycle, golden section on chi2(s) between the neighbours of the best; sigma from a
 * finite-difference curvature; the bulb posterior from the Riemann sum over the fine grid. */
TEST(eq7_continuous_matches_fine_grid_oracle)
{
    gs_delight *d = gs_delight_new();
    int shapes[3] = {SHAPE_SINE, SHAPE_SAW, SHAPE_HARM};
    const char *ids[3] = {"sine", "saw", "harm"};
    for (int i = 0; i < 3; i++) {
        gs_bulb b;
        eq7fx_make_bulb(&b, ids[i], shapes[i], 50, 3, GS_REF_VOLTAGE, eq7fx_chroma[i], 1024);
        CHECK_OK(gs_delight_add(d, &b));
        gs_bulb_release(&b);
    }
    rec_matcher *m = eq7fx_new_matcher(d, 50, 3, 26, REC_PHASES_CONTINUOUS);
    int K = 26, D = 78, G = 2048, nb = 3;
    double *tab = malloc(sizeof *tab * (size_t)nb * (size_t)G * (size_t)D);
    for (int b = 0; b < nb; b++)
        for (int g = 0; g < G; g++)
            analytic_template(shapes[b], eq7fx_chroma[b], (double)g / G, K, tab + ((size_t)b * (size_t)G + (size_t)g) * (size_t)D);
    double *L = malloc(sizeof *L * (size_t)nb * (size_t)G);
    double x[78], sg[78], t[78];
    uint64_t rs = 3;
    int trials = fx_sanitized() ? 16 : 48;
    int posterior_checked = 0, ambiguous_checked = 0;
    for (int trial = 0; trial < trials; trial++) {
        int b0 = trial % nb;
        double s0 = gs_splitmix_uniform(&rs);
        double snr = trial % 4 == 0 ? 0.7 : trial % 4 == 1 ? 3 : trial % 4 == 2 ? 15 : 100;
        analytic_template(shapes[b0], eq7fx_chroma[b0], s0, K, t);
        eq7fx_render_t(t, D, 300.0, 100.0 / snr, &rs, x, sg);
        rec_match r;
        CHECK_OK(rec_match_light(m, x, sg, &r));
        CHECK(eq7fx_all_finite(&r));
        /* oracle: the posterior of every bulb (Riemann sum on the fine grid), then the chi2
         * minimum of the bulb we answered */
        int ab = r.bulb >= 0 ? r.bulb : r.runner_bulb;
        double ph = r.bulb >= 0 ? r.phase_deg : r.runner_phase_deg;
        CHECK(ab >= 0 && ab < nb);
        if (ab < 0 || ab >= nb) continue;
        double Sxx = 0;
        for (int k = 0; k < D; k++) Sxx += x[k] * x[k] / (sg[k] * sg[k]);
        double best = INFINITY, lmax = -INFINITY, chi_min_all = INFINITY;
        int gb = 0, b_ml = 0;
        for (int b = 0; b < nb; b++)
            for (int g = 0; g < G; g++) {
                const double *tt = tab + ((size_t)b * (size_t)G + (size_t)g) * (size_t)D;
                double S = 0, T = 0;
                for (int k = 0; k < D; k++) {
                    S += x[k] * tt[k] / (sg[k] * sg[k]);
                    T += tt[k] * tt[k] / (sg[k] * sg[k]);
                }
                double z = S / sqrt(T);
                double *l = &L[(size_t)b * (size_t)G + (size_t)g];
                *l = -0.5 * (Sxx - z * z) - 0.5 * log(T) + eq7fx_log_phi(z);
                if (*l > lmax) lmax = *l;
                double c2 = S > 0 ? Sxx - z * z : Sxx;
                if (b == ab && c2 < best) {
                    best = c2;
                    gb = g;
                }
                if (c2 < chi_min_all) {
                    chi_min_all = c2;
                    b_ml = b;
                }
            }
        double Zt = 0, Zb[3] = {0, 0, 0};
        for (int b = 0; b < nb; b++)
            for (int g = 0; g < G; g++) {
                double e = exp(L[(size_t)b * (size_t)G + (size_t)g] - lmax);
                Zt += e;
                Zb[b] += e;
            }
        /* a clear winner must be ours */
        if (Zb[b_ml] / Zt > 0.9) CHECK_MSG(ab == b_ml, "trial %d: bulb %d oracle %d (posterior %g)", trial, ab,
                                           b_ml, Zb[b_ml] / Zt);
        /* golden section on chi2 within +-1 fine cell */
        double lo = (double)(gb - 1) / G, hi = (double)(gb + 1) / G;
        double gr = (sqrt(5.0) - 1) / 2;
#define CHI2_AT(s_, out_)                                                                \
    do {                                                                                 \
        analytic_template(shapes[ab], eq7fx_chroma[ab], (s_), K, t);                       \
        double S_ = 0, T_ = 0;                                                           \
        for (int k = 0; k < D; k++) {                                                    \
            S_ += x[k] * t[k] / (sg[k] * sg[k]);                                         \
            T_ += t[k] * t[k] / (sg[k] * sg[k]);                                         \
        }                                                                                \
        (out_) = Sxx - S_ * S_ / T_;                                                     \
    } while (0)
        double c = hi - gr * (hi - lo), e2 = lo + gr * (hi - lo), fc, fe;
        CHI2_AT(c, fc);
        CHI2_AT(e2, fe);
        for (int it = 0; it < 40; it++) {
            if (fc < fe) {
                hi = e2;
                e2 = c;
                fe = fc;
                c = hi - gr * (hi - lo);
                CHI2_AT(c, fc);
            } else {
                lo = c;
                c = e2;
                fc = fe;
                e2 = lo + gr * (hi - lo);
                CHI2_AT(e2, fe);
            }
        }
        double s_or = 0.5 * (lo + hi), f0, fp, fm, hstep = 1e-4;
        CHI2_AT(s_or, f0);
        CHI2_AT(s_or + hstep, fp);
        CHI2_AT(s_or - hstep, fm);
        double sig_or = sqrt(2.0 / ((fp + fm - 2 * f0) / (hstep * hstep)));
#undef CHI2_AT
        if (snr >= 3) {   /* at sample SNR 0.7 a bulb's chi2 can have two minima */
            double s_est = gs_phase_to_shift(ph);
            CHECK_MSG(eq7fx_cdist(s_est, s_or) < 1e-7 + 1e-3 * sig_or, "trial %d: shift %.8f oracle %.8f (sigma %g)",
                      trial, s_est, s_or, sig_or);
            CHECK_NEAR(r.chi2, f0, 1e-7 * (1 + f0));
            if (r.bulb >= 0) CHECK_NEAR(r.phase_sigma_deg / 180.0, sig_or, 0.01 * sig_or);
        }
        /* the Riemann sum is exact for peaks wider than a few fine cells */
        if (r.bulb >= 0 && sig_or > 8.0 / G) {
            CHECK_NEAR(r.bulb_confidence, Zb[ab] / Zt, 1e-3);
            posterior_checked++;
            if (Zb[ab] / Zt < 0.99) ambiguous_checked++;
        }
    }
    CHECK_MSG(posterior_checked >= trials / 3 && ambiguous_checked >= 2, "%d posteriors compared, %d below 0.99",
              posterior_checked, ambiguous_checked);
    free(L);
    free(tab);
    rec_matcher_free(m);
    gs_delight_free(d);
}

TEST(eq7_continuous_phase_wraparound)
{
    /* True shifts just either side of 0 (phase near 0 / 180 deg): the estimate is within its
     * uncertainty in circular distance, and over many lights the normalised errors have unit
     * RMS (the reported sigma is calibrated). */
    gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
    rec_matcher *m = eq7fx_new_matcher(d, 50, 3, 26, REC_PHASES_CONTINUOUS);
    double x[78], sg[78];
    uint64_t rs = 13;
    double shifts[] = {0.0, 0.0004, 0.9996, 0.9999, 0.002, 0.998};
    double sum2 = 0, sumchi = 0;
    int n = 0, unknown = 0;
    for (int trial = 0; trial < 240; trial++) {
        size_t b = (size_t)trial % 4;
        double s0 = shifts[trial % 6];
        eq7fx_render(rec_matcher_bulb(m, b), s0, 26, 500.0, 500.0 / 3 / 25, &rs, x, sg);
        rec_match r;
        CHECK_OK(rec_match_light(m, x, sg, &r));
        CHECK(eq7fx_all_finite(&r));
        sumchi += r.chi2;
        if (r.flags & REC_MATCH_UNKNOWN) unknown++;
        if (r.bulb < 0) continue;
        CHECK_MSG(r.bulb == (int)b, "trial %d: bulb %d (true %zu) flags %u conf %g", trial, r.bulb,
                  b, r.flags, r.bulb_confidence);
        if (r.bulb != (int)b) continue;
        double s = gs_phase_to_shift(r.phase_deg), sig = r.phase_sigma_deg / 180.0;
        double e = eq7fx_cdist(s, s0);
        CHECK_MSG(e < 5 * sig, "trial %d: shift %.6f true %.6f sigma %.2e", trial, s, s0, sig);
        CHECK(!(r.flags & REC_MATCH_PHASE_AMBIGUOUS));
        sum2 += (e / sig) * (e / sig);
        n++;
    }
    double rms = sqrt(sum2 / n);
    CHECK_MSG(rms > 0.85 && rms < 1.15, "normalised phase error RMS %.3f", rms);
    /* the refined fit is the chi2 minimum: its mean is dof = 76 (std of the mean 0.8) */
    CHECK_MSG(fabs(sumchi / 240 - 76) < 3.5, "mean chi2 %.2f, expected 76", sumchi / 240);
    CHECK(unknown <= 3);
    CHECK(n >= 236);
    rec_matcher_free(m);
    gs_delight_free(d);
}
