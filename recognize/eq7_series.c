/* eq7_series.c - a continuous bulb's sums S(s) = sum_k w_k x_k t_k(s) and T(s) = sum_k w_k
 * t_k(s)^2 at any shift s, with their first two derivatives in s, from Fourier series: the
 * Newton steps of the peak refinement (rec_eq7_refine_peak, eq7_light.c).
 *
 * A window mean is one periodic function of k/K - s, t_k(s) = f(k/K - s), with
 *   f(x) = Re sum_{h=0}^{H} A_h e^{2 pi i h x}
 * (rec_eq7_template_at's series, its Nyquist term as harmonic n/2), and f^2 = Re sum_{g=0}^{2H}
 * B_g e^{2 pi i g x}. With the row's K-point DFTs X_r = sum_k w_k x_k e^{2 pi i r k / K} and
 * W_r = sum_k w_k e^{2 pi i r k / K} (per band),
 *   S(s) = Re sum_h A_h X_{h mod K} e^{-2 pi i h s},   T(s) = Re sum_g B_g W_{g mod K} e^{-2 pi i g s}:
 * per shift one pass over 3H + 2 terms (the bands of one brightness summed into one series), not
 * the template's harmonic fold and three K x K inverse DFTs per band. The derivatives come from
 * the same terms times (2 pi h)^i. B is tabulated per bulb by an FFT of f^2 sampled at N > 4H
 * points (2H harmonics: no aliasing) in long double, x86-64's 64-bit mantissa: its rounding, some
 * 1e-19 of f^2's largest value per harmonic, stays below the sums' 1e-11 when T'' multiplies it
 * by g^2 (up to 10^6; in double it did not: so neither under valgrind, whose x87 is double). */
#include "recognize/internal.h"

#include <fftw3.h>
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

_Static_assert(LDBL_MANT_DIG >= 64, "the refinement's tables need a long double of 64 bits of mantissa or more");
#define SER_LANES 8
#define SER_PAD(n) (((n) + SER_LANES - 1) / SER_LANES * SER_LANES)
typedef double ser_vd __attribute__((vector_size(SER_LANES * sizeof(double))));

void rec_eq7_series_free(rec_matcher *m)
{
    for (size_t b = 0; m->rs_a && b < m->nb; b++) free(m->rs_a[b]);
    for (size_t b = 0; m->rs_b && b < m->nb; b++) free(m->rs_b[b]);
    free(m->rs_a);
    free(m->rs_b);
    free(m->rs_h);
}

/* The Nyquist term of rec_eq7_template_at, nyq K / (pi n) (sin(pi n (x + 1/K)) - sin(pi n x)),
 * is Re(nyq c e^{i pi n x}): harmonic n/2 of f, c = -i K / (pi n) (e^{i pi n / K} - 1) (pi n / K
 * modulo 2 pi exactly). */
static double complex nyquist_factor(int n, int K)
{
    double an = M_PI * (double)((long)n % (2L * K)) / K;
    return -I * K / (M_PI * n) * (cexp(I * an) - 1.0);
}

/* Bulb b's A and B, band by band, each real parts then imaginary parts, zero padded to SER_PAD. */
static gs_status series_bulb(rec_matcher *m, size_t b, int hs)
{
    int K = m->K, n = m->nfine[b], H = m->H[b], bands = m->bands;
    size_t la = SER_PAD((size_t)hs + 1), lb = SER_PAD(2 * (size_t)hs + 1), N = 8, nh;
    while (N <= 4 * (size_t)hs + 1) N *= 2;
    nh = N / 2 + 1;
    m->rs_a[b] = calloc((size_t)bands * 2 * la, sizeof **m->rs_a);
    m->rs_b[b] = calloc((size_t)bands * 2 * lb, sizeof **m->rs_b);
    long double *y = fftwl_malloc(sizeof *y * N);
    fftwl_complex *Y = fftwl_malloc(sizeof *Y * nh);
    gs_status st = GS_OK;
    fftwl_plan inv = NULL, fwd = NULL;
    if (!m->rs_a[b] || !m->rs_b[b] || !y || !Y) {
        st = gs_fail(GS_ENOMEM, "Eq. 7 matcher: cannot allocate the refinement's %d harmonics", hs);
        goto done;
    }
    /* f to samples, f^2 back */
    inv = fftwl_plan_dft_c2r_1d((int)N, Y, y, FFTW_ESTIMATE);
    fwd = fftwl_plan_dft_r2c_1d((int)N, y, Y, FFTW_ESTIMATE);
    if (!inv || !fwd) {
        st = gs_fail(GS_ENUMERIC, "Eq. 7 matcher: no %zu-point FFT plan", N);
        goto done;
    }
    double complex nyw = nyquist_factor(n, K);
    for (int band = 0; band < bands; band++) {
        const double complex *F = m->F[b] + (size_t)band * (size_t)(H + 1);
        double *ar = m->rs_a[b] + (size_t)band * 2 * la, *ai = ar + la;
        ar[0] = creal(F[0]);
        for (int h = 1; h <= H; h++) ar[h] = creal(F[h]), ai[h] = cimag(F[h]);
        double nq = m->nyq[b * (size_t)bands + (size_t)band];
        if (hs > H) ar[hs] = creal(nq * nyw), ai[hs] = cimag(nq * nyw);
        /* f on N points (Y_0 = A_0, Y_h = A_h / 2) */
        memset(Y, 0, sizeof *Y * nh);
        Y[0] = ar[0];
        for (int h = 1; h <= hs; h++) Y[h] = 0.5L * ((long double)ar[h] + I * (long double)ai[h]);
        fftwl_execute(inv);
        for (size_t j = 0; j < N; j++) y[j] *= y[j];
        fftwl_execute(fwd);
        double *br = m->rs_b[b] + (size_t)band * 2 * lb, *bi = br + lb;
        br[0] = (double)(creall(Y[0]) / (long double)N);
        for (int g = 1; g <= 2 * hs; g++)
            br[g] = (double)(2.0L * creall(Y[g]) / (long double)N), bi[g] = (double)(2.0L * cimagl(Y[g]) / (long double)N);
    }
done:
    if (inv) fftwl_destroy_plan(inv);
    if (fwd) fftwl_destroy_plan(fwd);
    fftwl_free(y);
    fftwl_free(Y);
    return st;
}

gs_status rec_eq7_series_setup(rec_matcher *m)
{
    if (!m->ncont) return GS_OK;
    m->rs_h = calloc(m->nb, sizeof *m->rs_h);
    m->rs_a = calloc(m->nb, sizeof *m->rs_a);
    m->rs_b = calloc(m->nb, sizeof *m->rs_b);
    if (!m->rs_h || !m->rs_a || !m->rs_b) return gs_fail(GS_ENOMEM, "Eq. 7 matcher: out of memory");
    m->rs_hmax = 0;
    for (size_t b = 0; b < m->nb; b++) {
        if (!m->cont[b]) continue;
        /* the Nyquist harmonic where it is kept as fourier_setup keeps the others (> 1e-15) */
        int hs = m->H[b];
        double complex c = nyquist_factor(m->nfine[b], m->K);
        for (int band = 0; band < m->bands; band++)
            if (cabs(m->nyq[b * (size_t)m->bands + (size_t)band] * c) > 1e-15) hs = m->nfine[b] / 2;
        m->rs_h[b] = hs;
        if (hs > m->rs_hmax) m->rs_hmax = hs;
        gs_status st = series_bulb(m, b, hs);
        if (st != GS_OK) return st;
    }
    return GS_OK;
}

size_t rec_eq7_series_work_size(const rec_matcher *m)
{
    if (!m->ncont) return 0;
    size_t la = SER_PAD((size_t)m->rs_hmax + 1), lb = SER_PAD(2 * (size_t)m->rs_hmax + 1);
    /* the row's DFTs (4 bands K), the products (nfit (2 la + 2 lb)) */
    return 4 * (size_t)m->D + (size_t)m->nfit * (2 * la + 2 * lb);
}

/* c = sum_q a_q X_q,(h mod K) over h < n (complex, split parts; a_q at a + q lda, X_q at x + q K),
 * added from 0 in the order of q: the bands of one brightness's series, in rows of K harmonics
 * (h = h0 + r, X_r); nq a constant where it is inlined, for the vectorizer. */
static inline __attribute__((always_inline)) void series_rows(const double *restrict ar, const double *restrict ai,
                                                              size_t lda, const double *restrict xr,
                                                              const double *restrict xi, size_t K, int nq, size_t n,
                                                              double *restrict cr, double *restrict ci)
{
    for (size_t h0 = 0; h0 < n; h0 += K) {
        size_t nr = n - h0 < K ? n - h0 : K;
        for (size_t r = 0; r < nr; r++) {
            double sr = 0.0, si = 0.0;
            for (int q = 0; q < nq; q++) {
                double a = ar[(size_t)q * lda + h0 + r], b = ai[(size_t)q * lda + h0 + r];
                double u = xr[(size_t)q * K + r], v = xi[(size_t)q * K + r];
                sr += a * u - b * v;
                si += a * v + b * u;
            }
            cr[h0 + r] = sr;
            ci[h0 + r] = si;
        }
    }
}

/* series_rows, then 0 in c's padding up to npad (what series_eval reads). */
GS_VECTOR_LOOP static void series_products(const double *restrict ar, const double *restrict ai, size_t lda,
                                           const double *restrict xr, const double *restrict xi, int K, int nq,
                                           size_t n, size_t npad, double *restrict cr, double *restrict ci)
{
    if (nq == 3) series_rows(ar, ai, lda, xr, xi, (size_t)K, 3, n, cr, ci);
    else if (nq == 1) series_rows(ar, ai, lda, xr, xi, (size_t)K, 1, n, cr, ci);
    else series_rows(ar, ai, lda, xr, xi, (size_t)K, nq, n, cr, ci);
    for (size_t h = n; h < npad; h++) cr[h] = ci[h] = 0.0;
}

void rec_eq7_series_row(const rec_matcher *m, rec_eq7_work *w, int have_dfts)
{
    size_t K = (size_t)m->K, nh = (size_t)m->G / 2 + 1, bn = (size_t)m->bands * nh;
    double *xr = w->rs, *xi = xr + m->D, *vr = xi + m->D, *vi = vr + m->D;
    /* X and W per band: the conjugates of rec_eq7_band_dfts' bins 0..K-1 */
    for (int q = 0; q < 2; q++) {
        const double complex *src = have_dfts ? w->spec + nh + (size_t)q * bn : w->spec_v;
        if (!have_dfts) rec_eq7_band_dfts(m, q ? w->w : w->wx, w->spec_v);
        for (int band = 0; band < m->bands; band++)
            for (size_t r = 0; r < K; r++) {
                double complex x = src[(size_t)band * nh + r];
                (q ? vr : xr)[(size_t)band * K + r] = creal(x);
                (q ? vi : xi)[(size_t)band * K + r] = -cimag(x);
            }
    }
}

void rec_eq7_series_bulb(const rec_matcher *m, rec_eq7_work *w, size_t b)
{
    int K = m->K, bands = m->bands, hs = m->rs_h[b], nf = m->nfit;
    size_t la = SER_PAD((size_t)m->rs_hmax + 1), lb = SER_PAD(2 * (size_t)m->rs_hmax + 1);
    size_t lab = SER_PAD((size_t)hs + 1), lbb = SER_PAD(2 * (size_t)hs + 1);
    const double *xr = w->rs, *xi = xr + m->D, *vr = xi + m->D, *vi = vr + m->D;
    double *cs = w->rs + 4 * (size_t)m->D, *ct = cs + 2 * (size_t)nf * la;
    for (int f = 0; f < nf; f++) {   /* the bands of brightness f */
        int q0 = nf == 1 ? 0 : f, nq = nf == 1 ? bands : 1;
        size_t o = (size_t)q0 * (size_t)K;
        const double *ar = m->rs_a[b] + (size_t)q0 * 2 * lab, *br = m->rs_b[b] + (size_t)q0 * 2 * lbb;
        double *sr = cs + (size_t)f * 2 * la, *tr = ct + (size_t)f * 2 * lb;
        series_products(ar, ar + lab, 2 * lab, xr + o, xi + o, K, nq, (size_t)hs + 1, lab, sr, sr + la);
        series_products(br, br + lbb, 2 * lbb, vr + o, vi + o, K, nq, 2 * (size_t)hs + 1, lbb, tr, tr + lb);
    }
}

/* sum_g Re(c_g e_g), sum_g g Im(c_g e_g), sum_g g^2 Re(c_g e_g) of one series over h .. h + 8:
 * its SER_LANES partial sums acc[0..2] (lanes in a fixed order). */
#define SER_ACC(acc, cr, ci, h, c, d, g)                                                            \
    do {                                                                                            \
        ser_vd a_, b_;                                                                              \
        memcpy(&a_, (cr) + (h), sizeof a_);                                                         \
        memcpy(&b_, (ci) + (h), sizeof b_);                                                         \
        ser_vd re_ = a_ * (c) - b_ * (d);                                                           \
        (acc)[0] += re_;                                                                            \
        (acc)[1] += (g) * (a_ * (d) + b_ * (c));                                                    \
        (acc)[2] += (g) * (g) * re_;                                                                \
    } while (0)

/* Every brightness's S series (na terms, at cs + f 2 la: real parts, then imaginary) and T series
 * (nbb terms, at ct + f 2 lb) at shift s, with their derivatives' sums (SER_ACC) into
 * o[f][S, T][3]. The powers e_g = e^{-2 pi i g s} block by block as they are needed: 32 powers of
 * e^{-2 pi i s} times each block's own, from cexp every 8 blocks (relative error some 100 eps).
 * nf a constant where it is inlined: the sums stay in registers. */
static inline __attribute__((always_inline)) void series_eval_n(double s, const double *cs, size_t la,
                                                                const double *ct, size_t lb, int nf, size_t na,
                                                                size_t nbb, double (*o)[2][3])
{
    ser_vd pr[4], pi[4], acc[GS_MAX_BANDS][2][3];
    double complex e1 = cexp(-I * EQ7_TWO_PI * s), p = 1.0;
    for (int i = 0; i < 32; i++) {
        pr[i / SER_LANES][i % SER_LANES] = creal(p), pi[i / SER_LANES][i % SER_LANES] = cimag(p);
        p *= e1;
    }
    for (int f = 0; f < nf; f++)
        for (int st = 0; st < 2; st++)
            for (int k = 0; k < 3; k++)
                for (int l = 0; l < SER_LANES; l++) acc[f][st][k][l] = 0.0;
    double complex e32 = cexp(-I * EQ7_TWO_PI * frac1(32.0 * s)), q = 1.0;
    ser_vd g = {0, 1, 2, 3, 4, 5, 6, 7}, step;   /* the lanes' g, exact integers */
    for (int l = 0; l < SER_LANES; l++) step[l] = SER_LANES;
    for (size_t j = 0; j * 32 < nbb; j++) {
        if (j % 8 == 0 && j) q = cexp(-I * EQ7_TWO_PI * frac1((double)(32 * j) * s));
        double qr = creal(q), qi = cimag(q);
        for (size_t v = 0; v < 4 && 32 * j + SER_LANES * v < nbb; v++, g += step) {
            size_t h = 32 * j + SER_LANES * v;
            ser_vd c = qr * pr[v] - qi * pi[v], d = qr * pi[v] + qi * pr[v];
            for (int f = 0; f < nf; f++) {
                const double *sr = cs + (size_t)f * 2 * la, *tr = ct + (size_t)f * 2 * lb;
                if (h < na) SER_ACC(acc[f][0], sr, sr + la, h, c, d, g);
                SER_ACC(acc[f][1], tr, tr + lb, h, c, d, g);
            }
        }
        q *= e32;
    }
    for (int f = 0; f < nf; f++)
        for (int st = 0; st < 2; st++)
            for (int k = 0; k < 3; k++) {
                o[f][st][k] = 0.0;
                for (int l = 0; l < SER_LANES; l++) o[f][st][k] += acc[f][st][k][l];
            }
}

GS_VECTOR_CLONES static void series_eval(double s, const double *cs, size_t la, const double *ct, size_t lb, int nf,
                                         size_t na, size_t nbb, double (*o)[2][3])
{
    if (nf == 1) series_eval_n(s, cs, la, ct, lb, 1, na, nbb, o);
    else series_eval_n(s, cs, la, ct, lb, nf, na, nbb, o);
}

void rec_eq7_series_at(const rec_matcher *m, rec_eq7_work *w, size_t b, double s, double *S, double *S1,
                       double *S2, double *T, double *T1, double *T2)
{
    int hs = m->rs_h[b];
    size_t la = SER_PAD((size_t)m->rs_hmax + 1), lb = SER_PAD(2 * (size_t)m->rs_hmax + 1);
    double *cs = w->rs + 4 * (size_t)m->D, *ct = cs + 2 * (size_t)m->nfit * la, tp = EQ7_TWO_PI;
    double o[GS_MAX_BANDS][2][3];
    series_eval(wrap01(s), cs, la, ct, lb, m->nfit, SER_PAD((size_t)hs + 1), SER_PAD(2 * (size_t)hs + 1), o);
    for (int f = 0; f < m->nfit; f++) {
        S[f] = o[f][0][0], S1[f] = tp * o[f][0][1], S2[f] = -tp * tp * o[f][0][2];
        T[f] = o[f][1][0], T1[f] = tp * o[f][1][1], T2[f] = -tp * tp * o[f][1][2];
    }
}
