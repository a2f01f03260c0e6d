/* test_brf.c - BRF invariants (Eqs. 4-6): mean 1, integration preserves the mean, a one-cycle
 * shift is the identity, shifts compose, integer shifts are circular shifts, window integrals
 * match brute-force quadrature, the three grid-phase shifts. */
#include "recognize/base/internal.h"
#include "tests/test.h"

#include <stdlib.h>

/* A band-limited test BRF: a few harmonics with known amplitudes and phases per band. */
static void make_brf(gs_brf *b, int n, int bands)
{
    CHECK_OK(gs_brf_init(b, n, bands));
    for (int band = 0; band < bands; band++)
        for (int j = 0; j < n; j++) {
            double t = (double)j / n;
            b->v[band * n + j] = 1.0 + 0.5 * cos(2 * M_PI * (t - 0.1 * band)) +
                                 0.2 * sin(2 * M_PI * 3 * t + band) + 0.05 * cos(2 * M_PI * 17 * t);
        }
}

/* The analytic value of make_brf's function at t (cycles), band. */
static double brf_at(double t, int band)
{
    return 1.0 + 0.5 * cos(2 * M_PI * (t - 0.1 * band)) + 0.2 * sin(2 * M_PI * 3 * t + band) +
           0.05 * cos(2 * M_PI * 17 * t);
}

TEST(brf_normalize_mean_one)
{
    gs_brf b;
    make_brf(&b, 256, 3);
    for (int i = 0; i < 256 * 3; i++) b.v[i] *= 3.7 + (i / 256);
    double mean[3];
    CHECK_OK(gs_brf_normalize(&b, mean));
    for (int band = 0; band < 3; band++) {
        double s = 0;
        for (int j = 0; j < 256; j++) s += b.v[band * 256 + j];
        CHECK_NEAR(s / 256, 1.0, 1e-12);
        CHECK_NEAR(mean[band], 3.7 + band, 1e-12);
    }
    gs_brf_release(&b);
}

TEST(brf_normalize_rejects_zero_and_nan)
{
    gs_brf b;
    CHECK_OK(gs_brf_init(&b, 8, 1));
    CHECK(gs_brf_normalize(&b, NULL) == GS_ENUMERIC);
    for (int j = 0; j < 8; j++) b.v[j] = 1;
    b.v[3] = NAN;
    CHECK(gs_brf_normalize(&b, NULL) == GS_ENUMERIC);
    gs_brf_release(&b);
}

TEST(eq5_integration_preserves_mean_any_k)
{
    gs_brf b;
    make_brf(&b, 1024, 3);
    int Ks[] = {2, 3, 7, 8, 13, 22, 26, 1000};
    for (size_t i = 0; i < sizeof Ks / sizeof *Ks; i++) {
        int K = Ks[i];
        double *out = malloc(sizeof *out * 3 * (size_t)K);
        CHECK_OK(gs_brf_integrate(&b, 0.37, K, out));
        for (int band = 0; band < 3; band++) {
            double s = 0;
            for (int k = 0; k < K; k++) s += out[band * K + k];
            CHECK_NEAR(s / K, 1.0, 1e-12);
        }
        free(out);
    }
    gs_brf_release(&b);
}

TEST(eq5_integration_matches_quadrature)
{
    /* Oracle: Simpson's rule on the analytic function over each shifted window. */
    gs_brf b;
    make_brf(&b, 256, 3);
    int K = 13;
    double shift = 0.2345;
    double out[3 * 13];
    CHECK_OK(gs_brf_integrate(&b, shift, K, out));
    for (int band = 0; band < 3; band++)
        for (int k = 0; k < K; k++) {
            int m = 2000;
            double a = (double)k / K, h = 1.0 / K / m, s = 0;
            for (int i = 0; i <= m; i++) {
                double w = (i == 0 || i == m) ? 1 : (i % 2 ? 4 : 2);
                s += w * brf_at(a + i * h - shift, band);
            }
            CHECK_NEAR(out[band * K + k], s * h / 3 * K, 1e-9);
        }
    gs_brf_release(&b);
}

TEST(brf_shift_one_cycle_is_identity)
{
    gs_brf b, s;
    make_brf(&b, 512, 1);
    CHECK_OK(gs_brf_init(&s, 512, 1));
    CHECK_OK(gs_brf_shift(&b, 1.0, &s));
    for (int j = 0; j < 512; j++) CHECK_NEAR(s.v[j], b.v[j], 1e-12);
    CHECK_OK(gs_brf_shift(&b, -3.0, &s));
    for (int j = 0; j < 512; j++) CHECK_NEAR(s.v[j], b.v[j], 1e-12);
    gs_brf_release(&b);
    gs_brf_release(&s);
}

TEST(brf_shifts_compose)
{
    gs_brf b, ab, c;
    make_brf(&b, 1024, 3);
    CHECK_OK(gs_brf_init(&ab, 1024, 3));
    CHECK_OK(gs_brf_init(&c, 1024, 3));
    double a = 0.123456789, d = 0.7654321;
    CHECK_OK(gs_brf_shift(&b, a, &ab));
    CHECK_OK(gs_brf_shift(&ab, d, &ab)); /* in place */
    CHECK_OK(gs_brf_shift(&b, a + d, &c));
    for (int j = 0; j < 3 * 1024; j++) CHECK_NEAR(ab.v[j], c.v[j], 1e-12);
    /* and a fractional shift equals the analytic delayed function */
    for (int band = 0; band < 3; band++)
        for (int j = 0; j < 1024; j++)
            CHECK_NEAR(c.v[band * 1024 + j], brf_at((double)j / 1024 - a - d, band), 1e-12);
    gs_brf_release(&b);
    gs_brf_release(&ab);
    gs_brf_release(&c);
}

TEST(brf_integer_shift_is_circular_shift)
{
    /* Any samples (not band-limited, with a Nyquist component): a shift by m/n cycles moves
     * the samples by m places. */
    gs_brf b, s;
    CHECK_OK(gs_brf_init(&b, 64, 1));
    CHECK_OK(gs_brf_init(&s, 64, 1));
    srand(7);
    for (int j = 0; j < 64; j++) b.v[j] = (double)rand() / RAND_MAX;
    for (int m = -70; m <= 70; m += 7) {
        CHECK_OK(gs_brf_shift(&b, (double)m / 64, &s));
        for (int j = 0; j < 64; j++) CHECK_NEAR(s.v[(j + m + 640) % 64], b.v[j], 1e-12);
    }
    gs_brf_release(&b);
    gs_brf_release(&s);
}

TEST(grid_phase_shifts_0_120_240)
{
    CHECK_NEAR(gs_phase_to_shift(0), 0.0, 1e-15);
    CHECK_NEAR(gs_phase_to_shift(120), 2.0 / 3, 1e-15);
    CHECK_NEAR(gs_phase_to_shift(240), 1.0 / 3, 1e-15);
    CHECK_NEAR(gs_phase_to_shift(360), 0.0, 1e-15);
    CHECK_NEAR(gs_phase_to_shift(-120), 1.0 / 3, 1e-15);
    CHECK_NEAR(gs_shift_to_phase(0), 0.0, 1e-12);
    CHECK_NEAR(gs_shift_to_phase(2.0 / 3), 120.0, 1e-12);
    CHECK_NEAR(gs_shift_to_phase(1.0 / 3), 240.0, 1e-12);
    /* a shift just below a whole cycle is phase 0, inside [0, 360): 180 s + 180 rounds to 360 */
    for (double s = nextafter(1.0, 0.0), i = 0; i < 64; i++, s = nextafter(s, 0.0)) {
        double q = gs_shift_to_phase(s);
        CHECK_MSG(q >= 0.0 && q < 360.0 && (q < 1e-9 || q > 360.0 - 1e-9), "shift %.17g: phase %.17g", s, q);
    }
    /* round trip for any phase, modulo the 180 deg a flicker cannot tell apart */
    for (double p = 0; p < 360; p += 7.5) {
        double q = gs_shift_to_phase(gs_phase_to_shift(p));
        double d = fmod(fabs(p - q), 180.0);
        CHECK_NEAR(d < 90 ? d : 180 - d, 0.0, 1e-9);
    }
}

TEST(grid_phase_shift_of_integrated_brf)
{
    /* Shifting by phase 120 deg at K = 3 rotates the three window means by two places. */
    gs_brf b;
    make_brf(&b, 768, 1);
    double w0[3], w120[3];
    CHECK_OK(gs_brf_integrate(&b, 0.0, 3, w0));
    CHECK_OK(gs_brf_integrate(&b, gs_phase_to_shift(120), 3, w120));
    for (int k = 0; k < 3; k++) CHECK_NEAR(w120[(k + 2) % 3], w0[k], 1e-12);
    gs_brf_release(&b);
}

TEST(eq6_chromaticity)
{
    double mean[3] = {2, 3, 5}, Q[3];
    CHECK_NEAR(gs_chromaticity(mean, 3, Q), 10.0, 0);
    CHECK_NEAR(Q[0], 0.2, 1e-15);
    CHECK_NEAR(Q[2], 0.5, 1e-15);
    double zero[3] = {0, 0, 0};
    CHECK(isnan(gs_chromaticity(zero, 3, Q)));
}

TEST(brf_percent_flicker)
{
    gs_brf b;
    CHECK_OK(gs_brf_init(&b, 100, 1));
    for (int j = 0; j < 100; j++) b.v[j] = 1.0 + 0.25 * sin(2 * M_PI * j / 100.0);
    CHECK_NEAR(gs_brf_percent_flicker(&b, 0), 25.0, 1e-3);
    gs_brf_release(&b);
}
