/* brf.c - bulb response functions (paper Eqs. 3-6): normalisation, exact fractional shifts and
 * exact window integrals (Eq. 5) of the trigonometric polynomial through the samples, the
 * grid-phase-to-shift mapping and chromaticity.
 *
 * Representation: n samples x_j at t = j/n cycles define
 *   x(t) = (1/n) [C_0 + sum_{h=1}^{n/2-1} 2 Re(C_h e^{2 pi i h t}) + C_{n/2} cos(pi n t)]
 * with C_h the DFT of x (FFTW r2c). A delay by s cycles multiplies C_h by e^{-2 pi i h s}; the
 * Nyquist term becomes cos(pi n (t - s)), which at the sample points is C_{n/2} cos(pi n s):
 * integer-sample delays are therefore exact circular shifts, and fractional delays compose
 * exactly for BRFs without a Nyquist component (the generated DELIGHT has none). */
#include "recognize/base/internal.h"

#include <complex.h>
#include <fftw3.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

static const double two_pi = 6.283185307179586476925286766559;

gs_status gs_brf_init(gs_brf *b, int n, int bands)
{
    b->n = 0;
    b->bands = 0;
    b->v = NULL;
    if (n < 4 || n % 2 != 0 || n > (1 << 20))
        return gs_fail(GS_EINVAL, "BRF: samples per cycle n=%d: expected an even number in [4, 2^20]", n);
    if (bands != 1 && bands != 3)
        return gs_fail(GS_EINVAL, "BRF: bands=%d: expected 1 or 3", bands);
    b->v = calloc((size_t)n * (size_t)bands, sizeof *b->v);
    if (!b->v) return gs_fail(GS_ENOMEM, "BRF: cannot allocate %d x %d samples", bands, n);
    b->n = n;
    b->bands = bands;
    return GS_OK;
}

void gs_brf_release(gs_brf *b)
{
    if (!b) return;
    free(b->v);
    b->v = NULL;
    b->n = 0;
    b->bands = 0;
}

gs_status gs_brf_copy(gs_brf *dst, const gs_brf *src)
{
    gs_status s = gs_brf_init(dst, src->n, src->bands);
    if (s != GS_OK) return s;
    memcpy(dst->v, src->v, (size_t)src->n * (size_t)src->bands * sizeof *dst->v);
    return GS_OK;
}

gs_status gs_brf_normalize(gs_brf *b, double *mean_out)
{
    for (int band = 0; band < b->bands; band++) {
        double *x = b->v + (size_t)band * (size_t)b->n;
        double sum = 0.0;
        for (int i = 0; i < b->n; i++) sum += x[i];
        double mean = sum / b->n;
        if (!isfinite(mean) || mean <= 0.0)
            return gs_fail(GS_ENUMERIC, "BRF: band %d has mean %g: expected a finite mean > 0", band, mean);
        for (int i = 0; i < b->n; i++) x[i] /= mean;
        if (mean_out) mean_out[band] = mean;
    }
    return GS_OK;
}

gs_status gs_brf_spectrum(const double *x, int n, double complex *C)
{
    double *in = fftw_malloc(sizeof *in * (size_t)n);
    fftw_complex *out = fftw_malloc(sizeof *out * (size_t)(n / 2 + 1));
    if (!in || !out) {
        fftw_free(in);
        fftw_free(out);
        return gs_fail(GS_ENOMEM, "BRF: cannot allocate a %d-point DFT", n);
    }
    fftw_plan p = fftw_plan_dft_r2c_1d(n, in, out, FFTW_ESTIMATE);
    memcpy(in, x, sizeof *in * (size_t)n);
    fftw_execute(p);
    for (int h = 0; h <= n / 2; h++) C[h] = out[h]; /* complex.h first: fftw_complex is C99 complex */
    fftw_destroy_plan(p);
    fftw_free(in);
    fftw_free(out);
    return GS_OK;
}

/* e^{-2 pi i h s} with the product h*s reduced modulo 1 first (keeps large h exact). */
static double complex delay_factor(int h, double s)
{
    double turns = fmod((double)h * s, 1.0);
    return cexp(-I * two_pi * turns);
}

static int finite_samples(const gs_brf *b)
{
    for (size_t i = 0; i < (size_t)b->n * (size_t)b->bands; i++)
        if (!isfinite(b->v[i])) return 0;
    return 1;
}

gs_status gs_brf_shift(const gs_brf *in, double shift_cycles, gs_brf *out)
{
    if (!isfinite(shift_cycles))
        return gs_fail(GS_EINVAL, "BRF shift: %g cycles: expected a finite number", shift_cycles);
    if (out->n != in->n || out->bands != in->bands || !out->v)
        return gs_fail(GS_EINVAL, "BRF shift: output is %dx%d, input %dx%d", out->bands, out->n,
                       in->bands, in->n);
    if (!finite_samples(in)) return gs_fail(GS_ENUMERIC, "BRF shift: input has non-finite samples");
    int n = in->n;
    double *x = fftw_malloc(sizeof *x * (size_t)n);
    fftw_complex *C = fftw_malloc(sizeof *C * (size_t)(n / 2 + 1));
    if (!x || !C) {
        fftw_free(x);
        fftw_free(C);
        return gs_fail(GS_ENOMEM, "BRF shift: cannot allocate a %d-point DFT", n);
    }
    fftw_plan fwd = fftw_plan_dft_r2c_1d(n, x, C, FFTW_ESTIMATE);
    fftw_plan inv = fftw_plan_dft_c2r_1d(n, C, x, FFTW_ESTIMATE);
    for (int band = 0; band < in->bands; band++) {
        memcpy(x, in->v + (size_t)band * (size_t)n, sizeof *x * (size_t)n);
        fftw_execute(fwd);
        for (int h = 1; h < n / 2; h++) C[h] *= delay_factor(h, shift_cycles);
        /* Nyquist: cos(pi n (t - s)) sampled at t = j/n gives cos(pi n s) (-1)^j. */
        C[n / 2] = creal(C[n / 2]) * cos(M_PI * fmod((double)n * shift_cycles, 2.0));
        fftw_execute(inv);
        double *dst = out->v + (size_t)band * (size_t)n;
        for (int j = 0; j < n; j++) dst[j] = x[j] / n;
    }
    fftw_destroy_plan(fwd);
    fftw_destroy_plan(inv);
    fftw_free(x);
    fftw_free(C);
    return GS_OK;
}

gs_status gs_brf_integrate(const gs_brf *b, double shift_cycles, int K, double *out)
{
    if (K < 2 || K > 1 << 16) return gs_fail(GS_EINVAL, "Eq. 5: K=%d: expected K >= 2", K);
    if (!isfinite(shift_cycles))
        return gs_fail(GS_EINVAL, "Eq. 5: shift %g cycles: expected a finite number", shift_cycles);
    if (!finite_samples(b)) return gs_fail(GS_ENUMERIC, "Eq. 5: BRF has non-finite samples");
    int n = b->n;
    double complex *C = malloc(sizeof *C * (size_t)(n / 2 + 1)), *root = malloc(sizeof *root * (size_t)K);
    if (!C || !root) {
        free(C);
        free(root);
        return gs_fail(GS_ENOMEM, "Eq. 5: cannot allocate a %d-point DFT", n);
    }
    /* e^{2 pi i h k/K} takes K values: e^{2 pi i j/K}, j = h k mod K */
    for (int j = 0; j < K; j++) root[j] = cexp(I * two_pi * ((double)j / K));
    for (int band = 0; band < b->bands; band++) {
        gs_status s = gs_brf_spectrum(b->v + (size_t)band * (size_t)n, n, C);
        if (s != GS_OK) {
            free(C);
            free(root);
            return s;
        }
        /* Window mean of e^{2 pi i h (t - s)} over [k/K, (k+1)/K):
         *   e^{-2 pi i h s} e^{2 pi i h k/K} (e^{2 pi i h/K} - 1) K / (2 pi i h). */
        for (int h = 1; h < n / 2; h++) {
            double complex w = (cexp(I * two_pi * fmod((double)h / K, 1.0)) - 1.0) * K / (I * two_pi * h);
            C[h] *= w * delay_factor(h, shift_cycles);
        }
        double *dst = out + (size_t)band * (size_t)K;
        double nyq = creal(C[n / 2]);
        double s_mod = fmod(shift_cycles, 2.0);
        for (int k = 0; k < K; k++) {
            double acc = 0.0;
            for (int h = 1; h < n / 2; h++) acc += creal(C[h] * root[((long long)h * k) % K]);
            /* Nyquist: mean of cos(pi n (t - s)) over the window. */
            double a = (double)k / K - s_mod, bb = (double)(k + 1) / K - s_mod;
            double nyq_mean = (sin(M_PI * n * bb) - sin(M_PI * n * a)) * K / (M_PI * n);
            dst[k] = (creal(C[0]) + 2.0 * acc + nyq * nyq_mean) / n;
        }
    }
    free(C);
    free(root);
    return GS_OK;
}

double gs_brf_percent_flicker(const gs_brf *b, int band)
{
    if (band < 0 || band >= b->bands) return NAN;
    const double *x = b->v + (size_t)band * (size_t)b->n;
    double lo = x[0], hi = x[0];
    for (int i = 1; i < b->n; i++) {
        if (x[i] < lo) lo = x[i];
        if (x[i] > hi) hi = x[i];
    }
    return (hi + lo) > 0.0 ? 100.0 * (hi - lo) / (hi + lo) : NAN;
}

double gs_phase_to_shift(double phase_deg)
{
    double s = fmod(phase_deg / 180.0, 1.0);   /* phi/pi cycles (docs/design.md) */
    if (s < 0) s += 1.0;
    return s >= 1.0 ? 0.0 : s;
}

/* Distance of deg to the nearest multiple of 120 (a grid phase of the 3-phase set). */
static double off_grid_deg(double deg)
{
    double r = fmod(deg, 120.0);
    return r < 60.0 ? r : 120.0 - r;
}

double gs_shift_to_phase(double shift_cycles)
{
    /* The flicker repeats every half AC period, so a shift fixes the phase only modulo
     * 180 deg: of the two candidates, report the one nearer to 0/120/240. */
    double s = fmod(shift_cycles, 1.0);
    if (s < 0) s += 1.0;
    double a = fmod(180.0 * s, 180.0), b = a + 180.0;
    if (b >= 360.0) b = 0.0;   /* a just below 180 rounds a + 180 up to 360: the same phase as 0 */
    return off_grid_deg(a) <= off_grid_deg(b) ? a : b;
}

double gs_chromaticity(const double *mean, int bands, double *Q)
{
    double sum = 0.0;
    for (int b = 0; b < bands; b++) sum += mean[b];
    if (!isfinite(sum) || sum <= 0.0) return NAN;
    for (int b = 0; b < bands; b++) Q[b] = mean[b] / sum;
    return sum;
}

int gs_phase_class(double phase_deg)
{
    if (!isfinite(phase_deg)) return -1;
    double p = fmod(phase_deg, 360.0);
    if (p < 0.0) p += 360.0;
    if (p >= 360.0) p = 0.0;
    /* the comparisons of the survey database's light_phase view (docs/survey-db.md) */
    if (p <= GS_PHASE_TOL_DEG || p >= 360.0 - GS_PHASE_TOL_DEG) return 0;
    if (p >= 120.0 - GS_PHASE_TOL_DEG && p <= 120.0 + GS_PHASE_TOL_DEG) return 1;
    if (p >= 240.0 - GS_PHASE_TOL_DEG && p <= 240.0 + GS_PHASE_TOL_DEG) return 2;
    return 3;
}
