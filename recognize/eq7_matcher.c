/* eq7.c - recognising a light's bulb and grid phase: paper Eq. 7,
 *   {beta, phi} = argmin_{beta in B, phi in P} sum_sigma || i_norm(sigma) - Q_beta(sigma) shift(phi, b_beta(sigma)) ||^2,
 * Sheinin, Schechner, Kutulakos, "Computational Imaging on the Electric Grid", CVPR 2017, Sec. 4.
 *
 * The estimator (docs/recognition.md has the derivation and the measured accuracy):
 * - Templates t_m = Q_beta(sigma) b_beta(sigma, shift) integrated to the K camera windows (Eq. 5:
 *   gs_brf_integrate for discrete phases; for continuous shifts the same window means from each
 *   bulb's Fourier series, which also gives exact derivatives in the shift) for every candidate
 *   bulb and phase. A template's mean over k, summed over bands, is 1, so the fitted scale a is the
 *   light's brightness (Eq. 6).
 * - Noise: independent Gaussian samples, std sigma_d, weights w_d = 1/sigma_d^2. The paper's
 *   normalisation by the mean brightness becomes a maximum-likelihood scale:
 *     a* = S/T, S = sum w x t, T = sum w t^2, chi2 = sum w x^2 - S^2/T.
 * - Posterior over (bulb, phase) with uniform priors, the scale marginalised over a > 0 with a flat
 *   prior (exact for the Gaussian model):
 *     log p_m = -chi2_m/2 - log(T_m)/2 + log Phi(S_m / sqrt(T_m)) + log prior.
 * - Continuous phase: a grid of G = max(8K, 96) shifts per cycle, then Newton's method on the exact
 *   chi2(s) (templates evaluated from their Fourier series), sigma_s from chi2'' (Delta chi2 = 1).
 *   One light's sums over every grid shift of a bulb are one G-point inverse FFT of the
 *   cross-spectrum of the template with the light's weights when K divides G (fourier_grid_setup).
 *   The posterior integrates over s: grid cells (periodic trapezoid rule, spectrally accurate for
 *   peaks wider than a cell) with the cells around each bulb's peak replaced by the Gaussian
 *   (Laplace) integral when the peak is narrower than a cell.
 * - Band gains (opts.band_gains, 3 bands): one brightness a_b per band, templates of mean 1 per
 *   band (no Q_beta): chi2 = sum w x^2 - sum_b S_b^2/T_b, log p_m sums -log(T_b)/2 +
 *   log Phi(S_b/sqrt(T_b)) over bands; a per-band gain (extinction reddening) cancels.
 * - Model error (opts.model_error): w_d = 1/(sigma_d^2 + (model_error mu_b)^2), mu_b the band's
 *   RMS signal level, the same for every template.
 * - Pixels (rec_match_pixels): one weight per row, so every score is a dot product x . t_m/|t_m|,
 *   computed for blocks of rows with one SGEMM (OpenBLAS), after a rigorous prefilter (a bound
 *   from the templates' principal subspace) has set aside the rows that are dim for every template.
 *   With band gains or a model error the scores are per band (one SGEMM of K columns per band).
 */
#include "recognize/internal.h"

#include <cblas.h>
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <lapacke.h>
#include <fftw3.h>

/* ------------------------------------------------------------ matcher */


void rec_eq7_opts_default(rec_eq7_opts *o)
{
    if (!o) return;
    o->phases = REC_PHASES_3;
    o->transformer_deg = 30.0;
    o->unknown_p = 1e-3;
    o->ambiguous_conf = 0.8;
    o->min_snr = 3.0;
    o->band_gains = REC_BANDS_REDDENED;
    o->chroma_tolerance = 0.05;
    o->model_error = NAN;
    o->other_prior = NAN;
    o->flat_share = NAN;
    o->blend_prior = 0.1;
    o->nested_tests = 1;
    o->threads = 0;
    o->max_drift_windows = REC_DRIFT_AUTO;
}

void rec_matcher_free(rec_matcher *m)
{
    if (!m) return;
    for (size_t b = 0; b < m->nb; b++) {
        gs_bulb_release(&m->bulbs[b]);
        if (m->F) free(m->F[b]);
    }
    free(m->bulbs);
    free(m->cont);
    free(m->first);
    free(m->count);
    free(m->t);
    free(m->tsq);
    free(m->tn);
    free(m->lnf);
    free(m->tnd);
    free(m->pe);
    free(m->pc);
    free(m->prho);
    free(m->lognorm);
    free(m->cellw);
    free(m->logcellw);
    free(m->ttr);
    free(m->tsqtr);
    free(m->ttrf);
    free(m->tsqtrf);
    free(m->tnorm);
    free(m->red_cmin);
    free(m->shift);
    free(m->tphase);
    free(m->tbulb);
    free(m->tcell);
    free(m->H);
    free(m->F);
    free(m->nyq);
    free(m->nfine);
    free(m->dftc);
    free(m->dfts);
    free(m->nyqs);
    free(m->nyqc);
    free(m->harm);
    free(m->bnorm);
    free(m->lbnorm);
    free(m->blog);
    free(m->tbn);
    free(m->tbnf);
    free(m->blnf);
    free(m->bib);
    free(m->bib2);
    free(m->red_c);
    free(m->ahat);
    free(m->bhat);
    free(m->fs_a);
    free(m->fs_tail);
    free(m->fs_lnfmin);
    free(m->fs_off);
    free(m->fs_tb);
    free(m->bs_a);
    free(m->bs_b);
    free(m->bs_at);
    free(m->bs_bt);
    free(m->bs_t2);
    if (m->c2r) fftw_destroy_plan((fftw_plan)m->c2r);
    rec_eq7_series_free(m);
    free(m);
}

size_t rec_matcher_bulb_count(const rec_matcher *m)
{
    return m ? m->nb : 0;
}

size_t rec_matcher_template_count(const rec_matcher *m)
{
    return m ? m->M : 0;
}

const double *rec_matcher_template(const rec_matcher *m, size_t j, int *bulb, double *shift_cycles)
{
    if (!m || j >= m->M) return NULL;
    if (bulb) *bulb = m->tbulb[j];
    if (shift_cycles) *shift_cycles = m->shift[j];
    return m->t + j * (size_t)m->D;
}

int rec_matcher_prefilter_dim(const rec_matcher *m)
{
    return m ? m->pr : 0;
}

const gs_bulb *rec_matcher_bulb(const rec_matcher *m, size_t i)
{
    return (m && i < m->nb) ? &m->bulbs[i] : NULL;
}

int rec_match_phase_known(const rec_matcher *m, const rec_match *mt)
{
    const gs_bulb *b = mt->bulb >= 0 ? rec_matcher_bulb(m, (size_t)mt->bulb) : NULL;
    return b && b->ref == GS_REF_VOLTAGE && !(mt->flags & REC_MATCH_PHASE_AMBIGUOUS);
}

static gs_status check_opts(const rec_eq7_opts *o)
{
    if (o->phases != REC_PHASES_3 && o->phases != REC_PHASES_6 && o->phases != REC_PHASES_CONTINUOUS)
        return gs_fail(GS_EINVAL, "Eq. 7 options: phases=%d: expected REC_PHASES_3, _6 or _CONTINUOUS",
                       (int)o->phases);
    if (!isfinite(o->transformer_deg))
        return gs_fail(GS_EINVAL, "Eq. 7 options: transformer_deg=%g: expected a finite angle",
                       o->transformer_deg);
    if (!(o->unknown_p >= 0.0 && o->unknown_p < 1.0))
        return gs_fail(GS_EINVAL, "Eq. 7 options: unknown_p=%g: expected [0, 1)", o->unknown_p);
    if (!(o->ambiguous_conf >= 0.0 && o->ambiguous_conf <= 1.0))
        return gs_fail(GS_EINVAL, "Eq. 7 options: ambiguous_conf=%g: expected [0, 1]", o->ambiguous_conf);
    if (!(o->min_snr >= 0.0 && o->min_snr < 1e6))
        return gs_fail(GS_EINVAL, "Eq. 7 options: min_snr=%g: expected [0, 1e6)", o->min_snr);
    if (o->band_gains < REC_BANDS_CHROMA || o->band_gains > REC_BANDS_REDDENED)
        return gs_fail(GS_EINVAL, "Eq. 7 options: band_gains=%d: expected 0 (chromaticity), 1 "
                       "(free) or 2 (reddened)", o->band_gains);
    if (!(o->chroma_tolerance >= 0.001 && o->chroma_tolerance <= 1.0))
        return gs_fail(GS_EINVAL, "Eq. 7 options: chroma_tolerance=%g: expected [0.001, 1]",
                       o->chroma_tolerance);
    if (!isnan(o->model_error) && !(o->model_error >= 0.0 && o->model_error < 1.0))
        return gs_fail(GS_EINVAL, "Eq. 7 options: model_error=%g: expected [0, 1) or NaN "
                       "(measured)", o->model_error);
    if (!isnan(o->other_prior) && !(o->other_prior >= 0.0 && o->other_prior < 1.0))
        return gs_fail(GS_EINVAL, "Eq. 7 options: other_prior=%g: expected [0, 1) or NaN (measured)",
                       o->other_prior);
    if (!isnan(o->flat_share) && !(o->flat_share >= 0.0 && o->flat_share < 0.5))
        return gs_fail(GS_EINVAL, "Eq. 7 options: flat_share=%g: expected [0, 0.5) or NaN (measured)",
                       o->flat_share);
    if (!(o->blend_prior >= 0.0 && o->blend_prior < 1.0))
        return gs_fail(GS_EINVAL, "Eq. 7 options: blend_prior=%g: expected [0, 1)", o->blend_prior);
    if (o->nested_tests != 0 && o->nested_tests != 1)
        return gs_fail(GS_EINVAL, "Eq. 7 options: nested_tests=%d: expected 0 or 1", o->nested_tests);
    if (o->threads < 0)
        return gs_fail(GS_EINVAL, "Eq. 7 options: threads=%d: expected >= 0 (0: the online CPUs)",
                       o->threads);
    if (!(o->max_drift_windows >= 0.0 || o->max_drift_windows == REC_DRIFT_AUTO))
        return gs_fail(GS_EINVAL, "Eq. 7 options: max_drift_windows=%g: expected [0, inf] or REC_DRIFT_AUTO (-1)",
                       o->max_drift_windows);
    return GS_OK;
}

/* Fourier coefficients of bulb b's window means (same algebra as gs_brf_integrate). */
static gs_status fourier_setup(rec_matcher *m, size_t b)
{
    const gs_bulb *bu = &m->bulbs[b];
    int n = bu->brf.n, K = m->K, bands = m->bands;
    double complex *C = malloc(sizeof *C * (size_t)(n / 2 + 1));
    if (!C) return gs_fail(GS_ENOMEM, "Eq. 7: cannot allocate a %d-point spectrum", n);
    int H = n / 2 - 1;
    double complex *F = calloc((size_t)bands * (size_t)(H + 1), sizeof *F);
    if (!F) {
        free(C);
        return gs_fail(GS_ENOMEM, "Eq. 7: cannot allocate Fourier templates");
    }
    int hmax = 0;
    for (int band = 0; band < bands; band++) {
        gs_status s = gs_brf_spectrum(bu->brf.v + (size_t)band * (size_t)n, n, C);
        if (s != GS_OK) {
            free(C);
            free(F);
            return s;
        }
        double q = m->bg ? 1.0 : bu->chroma[band];   /* band gains: each band of mean 1 */
        F[(size_t)band * (size_t)(H + 1)] = q * creal(C[0]) / n;
        for (int h = 1; h <= H; h++) {
            double complex w =
                (cexp(I * EQ7_TWO_PI * fmod((double)h / K, 1.0)) - 1.0) * K / (I * EQ7_TWO_PI * h);
            double complex f = 2.0 * q * C[h] * w / n;
            F[(size_t)band * (size_t)(H + 1) + (size_t)h] = f;
            if (cabs(f) > 1e-15) hmax = h > hmax ? h : hmax;
        }
        m->nyq[b * (size_t)bands + (size_t)band] = q * creal(C[n / 2]) / n;
    }
    free(C);
    /* keep harmonics up to the last non-negligible one (the dropped ones sum to < 1e-12) */
    if (hmax < H) {
        double complex *F2 = calloc((size_t)bands * (size_t)(hmax + 1), sizeof *F2);
        if (!F2) {
            free(F);
            return gs_fail(GS_ENOMEM, "Eq. 7: cannot allocate Fourier templates");
        }
        for (int band = 0; band < bands; band++)
            memcpy(F2 + (size_t)band * (size_t)(hmax + 1), F + (size_t)band * (size_t)(H + 1),
                   sizeof *F2 * (size_t)(hmax + 1));
        free(F);
        F = F2;
        H = hmax;
    }
    m->F[b] = F;
    m->H[b] = H;
    m->nfine[b] = n;
    for (int k = 0; k <= K; k++) {
        /* pi n k / K modulo 2 pi: n k mod 2K, exactly, then the angle */
        double a = M_PI * (double)((long)n * k % (2L * K)) / K;
        m->nyqs[b * (size_t)(K + 1) + (size_t)k] = sin(a);
        m->nyqc[b * (size_t)(K + 1) + (size_t)k] = cos(a);
    }
    return GS_OK;
}

/* The K-point inverse DFT of the folded harmonics, t_k = sum_q Re(A_q e^{2 pi i q k / K}), as
 * products with the tabulated cos and sin (m->dftc, m->dfts: [k K + q]), for up to three series
 * (the value and two derivatives); v[k] starts at base. */
GS_VECTOR_LOOP static void inverse_dft(const double *restrict c, const double *restrict sn, int K,
                                        const double *restrict re, const double *restrict im, double base,
                                        double *restrict v)
{
    for (int k = 0; k < K; k++) v[k] = base;
    for (int q = 0; q < K; q++)   /* the tables are symmetric: [q K + k] = [k K + q] */
        for (int k = 0; k < K; k++) v[k] += re[q] * c[q * K + k] - im[q] * sn[q * K + k];
}

/* A[(r + i) mod K] += g[i] for i < n, in the order of i (r < K): runs of consecutive bins. */
GS_VECTOR_LOOP static void fold_add(double complex *restrict A, int K, int r, const double complex *restrict g, int n)
{
    while (n > 0) {
        int len = K - r < n ? K - r : n;
        for (int i = 0; i < len; i++) A[r + i] += g[i];
        g += len;
        n -= len;
        r = 0;
    }
}

/* Exact template of continuous bulb b at shift s and its first two derivatives in s (any of
 * dt, d2t may be NULL). acc is scratch of REC_TEMPLATE_ACC * K complex values. The harmonics are
 * folded into K bins per band (harmonic h into h mod K, times e^{-2 pi i h s}, the factor shared
 * by the bands), then one inverse DFT per series; the Nyquist term sin(pi n (k/K - s)) from the
 * tabulated sin and cos of pi n k / K (m->nyqs, nyqc). */
void rec_eq7_template_at(const rec_matcher *m, size_t b, double s, double *t, double *dt,
                         double *d2t, double complex *acc)
{
    int K = m->K, H = m->H[b], n = m->nfine[b], deriv = dt || d2t, bands = m->bands;
    s = wrap01(s);
    double complex base = cexp(-I * EQ7_TWO_PI * s), pw[32];
    pw[0] = 1.0;
    for (int i = 1; i < 32; i++) pw[i] = pw[i - 1] * base;
    double pn = M_PI * n, sB = sin(pn * s), cB = cos(pn * s);
    const double *ns = m->nyqs + b * (size_t)(K + 1), *nc = m->nyqc + b * (size_t)(K + 1);
    /* the bins: band's series q at acc[(3 band + q) K]; then the split real and imaginary parts
     * of one band's, for the DFT's products */
    double *re = (double *)(acc + 3 * GS_MAX_BANDS * K), *im = re + 3 * K;
    for (int r = 0; r < 3 * bands * K; r++) acc[r] = 0.0;
    /* harmonic h's term F_h e^{-2 pi i h s}: e from cexp every 32 harmonics, times powers of
     * base within (independent products, then added to the bins in the order of h) */
    for (int h0 = 0; h0 <= H; h0 += 32) {
        double complex e0 = h0 ? cexp(-I * EQ7_TWO_PI * frac1((double)h0 * s)) : 1.0, eh[32], g[32];
        int hn = H + 1 - h0 < 32 ? H + 1 - h0 : 32, i0 = h0 ? 0 : 1;
        for (int i = 0; i < hn; i++) eh[i] = e0 * pw[i];
        for (int band = 0; band < bands; band++) {
            const double complex *F = m->F[b] + (size_t)band * (size_t)(H + 1);
            double complex *A0 = acc + 3 * band * K, *A1 = A0 + K, *A2 = A1 + K;
            /* (0 + F e: the sign of a zero term is lost in the bins' sums alike) */
            rec_eq7_cross_sum((const double *)(F + h0), (const double *)eh, 0, 1, (size_t)hn, (double *)g);
            int r = (h0 + i0) % K;
            fold_add(A0, K, r, g + i0, hn - i0);
            if (deriv) {
                double complex g1[32], g2[32];
                for (int i = i0; i < hn; i++) {
                    double w = EQ7_TWO_PI * (h0 + i);
                    g1[i] = g[i] * (-I * w);
                    g2[i] = g[i] * (-w * w);
                }
                fold_add(A1, K, r, g1 + i0, hn - i0);
                fold_add(A2, K, r, g2 + i0, hn - i0);
            }
        }
    }
    for (int band = 0; band < bands; band++) {
        const double complex *F = m->F[b] + (size_t)band * (size_t)(H + 1);
        const double complex *A = acc + 3 * band * K;
        for (int q = 0; q < 3 * K; q++) re[q] = creal(A[q]), im[q] = cimag(A[q]);
        size_t d0 = (size_t)band * (size_t)K;
        inverse_dft(m->dftc, m->dfts, K, re, im, creal(F[0]), t + d0);
        if (dt) inverse_dft(m->dftc, m->dfts, K, re + K, im + K, 0.0, dt + d0);
        if (d2t) inverse_dft(m->dftc, m->dfts, K, re + 2 * K, im + 2 * K, 0.0, d2t + d0);
        double nq = m->nyq[b * (size_t)bands + (size_t)band];
        if (nq == 0.0) continue;
        for (int k = 0; k < K; k++) {
            /* sin and cos of pi n (k/K - s) and of pi n ((k + 1)/K - s) */
            double sa = ns[k] * cB - nc[k] * sB, ca = nc[k] * cB + ns[k] * sB;
            double sb = ns[k + 1] * cB - nc[k + 1] * sB, cb = nc[k + 1] * cB + ns[k + 1] * sB;
            t[d0 + (size_t)k] += nq * (sb - sa) * K / pn;
            if (dt) dt[d0 + (size_t)k] += nq * -(cb - ca) * K;
            if (d2t) d2t[d0 + (size_t)k] += nq * -(sb - sa) * K * pn;
        }
    }
}

/* The tables of rec_eq7_template_at (with continuous bulbs): the K-point DFT's cos and sin (K^2
 * values, fewer than a grid's templates); per continuous bulb the sin and cos of pi n k / K,
 * k = 0..K, filled by fourier_setup. */
static gs_status template_tables(rec_matcher *m)
{
    int K = m->K;
    m->dftc = malloc(sizeof *m->dftc * (size_t)K * (size_t)K);
    m->dfts = malloc(sizeof *m->dfts * (size_t)K * (size_t)K);
    m->nyqs = calloc(m->nb * (size_t)(K + 1), sizeof *m->nyqs);
    m->nyqc = calloc(m->nb * (size_t)(K + 1), sizeof *m->nyqc);
    if (!m->dftc || !m->dfts || !m->nyqs || !m->nyqc)
        return gs_fail(GS_ENOMEM, "Eq. 7 matcher: cannot allocate the continuous templates' tables");
    for (int k = 0; k < K; k++)
        for (int q = 0; q < K; q++) {
            double complex wv = cexp(I * EQ7_TWO_PI * (double)((size_t)k * (size_t)q % (size_t)K) / K);
            m->dftc[k * K + q] = creal(wv);
            m->dfts[k * K + q] = cimag(wv);
        }
    return GS_OK;
}

/* The pixel prefilter: the top-R principal directions E of the unit templates, each template's
 * coefficients c_j = E t_j and residual rho_j = |t_j - E^T c_j|. R is chosen among
 * 0, 4, 8, 12, 16, 24, 32 (at most D/3) by a cost model: the prefilter costs 2 (D R + R M)
 * multiply-adds per row (small SGEMMs run at about half the speed), and the fraction f_R of rows
 * it cannot reject costs D M more; f_R is measured on 1024 rows of pure unit Gaussian noise
 * (a dark background) at the matcher's min_snr. No prefilter for D > 192. */
static gs_status prefilter_setup(rec_matcher *m)
{
    int D = m->D;
    size_t M = m->M;
    const int NR = M > 1600 ? 128 : 1024;   /* rows of the cost model (~2e6 dot products) */
    m->pr = 0;
    if (D > 192 || D < 12) return GS_OK;
    double *A = malloc(sizeof *A * (size_t)D * (size_t)D), *V = malloc(sizeof *V * (size_t)D * (size_t)D);
    double *ev = malloc(sizeof *ev * (size_t)D), *rho = malloc(sizeof *rho * M);
    double *C = malloc(sizeof *C * M * 32), *X = malloc(sizeof *X * (size_t)NR * (size_t)D);
    int *order = malloc(sizeof *order * (size_t)D);
    gs_status st = GS_OK;
    if (!A || !V || !ev || !rho || !C || !X || !order) {
        st = gs_fail(GS_ENOMEM, "Eq. 7 matcher: cannot allocate the pixel prefilter");
        goto done;
    }
    for (int a = 0; a < D; a++)
        for (int b = a; b < D; b++) {
            double g = 0.0;
            for (size_t j = 0; j < M; j++) g += m->tnd[j * (size_t)D + (size_t)a] * m->tnd[j * (size_t)D + (size_t)b];
            A[a * D + b] = A[b * D + a] = g;
        }
    /* eigen-decomposition (LAPACK dsyev): the eigenvectors overwrite A, one per column */
    if (LAPACKE_dsyev(LAPACK_ROW_MAJOR, 'V', 'U', D, A, D, ev) != 0) {
        st = gs_fail(GS_ENUMERIC, "Eq. 7 matcher: the templates' Gram matrix has no "
                     "eigen-decomposition (LAPACK dsyev failed)");
        goto done;
    }
    memcpy(V, A, sizeof *V * (size_t)D * (size_t)D);
    for (int i = 0; i < D; i++) order[i] = i;
    for (int i = 0; i < D; i++)   /* selection sort, descending eigenvalues */
        for (int k = i + 1; k < D; k++)
            if (ev[order[k]] > ev[order[i]]) {
                int tmp = order[i];
                order[i] = order[k];
                order[k] = tmp;
            }
    uint64_t rs = 0x5eed;
    for (size_t i = 0; i < (size_t)NR * (size_t)D; i++) X[i] = gs_splitmix_normal(&rs);
    static const int cand_r[] = {4, 8, 12, 16, 24, 32};
    int R = 0;
    double best_cost = (double)D * (double)M, lim = m->o.min_snr;
    for (size_t ci = 0; ci < sizeof cand_r / sizeof *cand_r; ci++) {
        int r = cand_r[ci];
        if (r > D / 3) break;
        for (size_t j = 0; j < M; j++) {
            const double *t = m->tnd + j * (size_t)D;
            double cc = 0.0;
            for (int q = 0; q < r; q++) {
                double c = 0.0;
                for (int d = 0; d < D; d++) c += V[d * D + order[q]] * t[d];
                C[j * 32 + (size_t)q] = c;
                cc += c * c;
            }
            rho[j] = sqrt(cc < 1.0 ? 1.0 - cc : 0.0);
        }
        int surv = 0;
        for (int i = 0; i < NR; i++) {
            const double *xr = X + (size_t)i * (size_t)D;
            double y[32], yy = 0.0, ss = 0.0;
            for (int d = 0; d < D; d++) ss += xr[d] * xr[d];
            for (int q = 0; q < r; q++) {
                y[q] = 0.0;
                for (int d = 0; d < D; d++) y[q] += V[d * D + order[q]] * xr[d];
                yy += y[q] * y[q];
            }
            double xp = sqrt(ss > yy ? ss - yy : 0.0), bound = -INFINITY;
            for (size_t j = 0; j < M && bound < lim; j++) {
                double v = rho[j] * xp;
                for (int q = 0; q < r; q++) v += C[j * 32 + (size_t)q] * y[q];
                bound = v > bound ? v : bound;
            }
            surv += bound >= lim;
        }
        double cost = 2.0 * ((double)D * r + (double)r * (double)M) + (double)surv / NR * (double)D * (double)M;
        if (cost < best_cost) {
            best_cost = cost;
            R = r;
        }
    }
    if (R > 0) {
        m->pe = malloc(sizeof *m->pe * (size_t)R * (size_t)D);
        m->pc = calloc(m->Mp * (size_t)R, sizeof *m->pc);
        m->prho = calloc(m->Mp, sizeof *m->prho);
        if (!m->pe || !m->pc || !m->prho) {
            st = gs_fail(GS_ENOMEM, "Eq. 7 matcher: cannot allocate the pixel prefilter");
        } else {
            for (int q = 0; q < R; q++)
                for (int d = 0; d < D; d++) m->pe[q * D + d] = (float)V[d * D + order[q]];
            for (size_t j = 0; j < M; j++) {
                const double *t = m->tnd + j * (size_t)D;
                double rr = 0.0;
                double *res = A;   /* scratch: the residual t - E^T c */
                for (int d = 0; d < D; d++) res[d] = t[d];
                for (int q = 0; q < R; q++) {
                    double c = 0.0;
                    for (int d = 0; d < D; d++) c += V[d * D + order[q]] * t[d];
                    m->pc[j * (size_t)R + (size_t)q] = (float)c;
                    for (int d = 0; d < D; d++) res[d] -= c * V[d * D + order[q]];
                }
                for (int d = 0; d < D; d++) rr += res[d] * res[d];
                /* rounded up: the bound must hold for the float basis too */
                m->prho[j] = (float)(sqrt(rr) * (1.0 + 1e-6) + 1e-7);
            }
            m->pr = R;
        }
    }
done:
    free(A);
    free(V);
    free(ev);
    free(rho);
    free(C);
    free(X);
    free(order);
    return st;
}

/* The Fourier form of the continuous grids (internal.h): when K divides G, window k's mean is
 * window 0's delayed by G/K cells, so for one light S_c = sum_k wx_k t_k(c) is the circular
 * correlation of t_0 with the weights placed every G/K cells: its DFT is the template's times
 * the conjugate K-point DFT of the weights (and T_c the same with t_0^2 and w). Here: the
 * template spectra and the G-point inverse plan (rec_eq7_grid_sums). */
static gs_status fourier_grid_setup(rec_matcher *m)
{
    int G = m->G, K = m->K, bands = m->bands;
    size_t nh = (size_t)G / 2 + 1, D = (size_t)m->D;
    m->fourier = 0;
    if (m->ncont == 0 || G % K != 0) return GS_OK;
    m->ahat = calloc(m->nb * (size_t)bands * nh, sizeof *m->ahat);
    m->bhat = calloc(m->nb * (size_t)bands * nh, sizeof *m->bhat);
    double *in = fftw_malloc(sizeof *in * (size_t)G);
    fftw_complex *out = fftw_malloc(sizeof *out * nh);
    gs_status st = GS_OK;
    if (!m->ahat || !m->bhat || !in || !out) {
        st = gs_fail(GS_ENOMEM, "Eq. 7 matcher: cannot allocate the template spectra");
        goto done;
    }
    fftw_plan fwd = fftw_plan_dft_r2c_1d(G, in, out, FFTW_ESTIMATE);
    m->c2r = fftw_plan_dft_c2r_1d(G, (fftw_complex *)out, in, FFTW_ESTIMATE);
    if (!fwd || !m->c2r) {
        if (fwd) fftw_destroy_plan(fwd);
        st = gs_fail(GS_ENUMERIC, "Eq. 7 matcher: no %d-point FFT plan", G);
        goto done;
    }
    for (size_t b = 0; b < m->nb; b++) {
        if (!m->cont[b]) continue;
        for (int band = 0; band < bands; band++)
            for (int sq = 0; sq < 2; sq++) {
                for (int c = 0; c < G; c++) {
                    double v = m->t[(m->first[b] + (size_t)c) * D + (size_t)band * (size_t)K];
                    in[c] = sq ? v * v : v;
                }
                fftw_execute(fwd);
                double complex *dst = (sq ? m->bhat : m->ahat) + (b * (size_t)bands + (size_t)band) * nh;
                for (size_t r = 0; r < nh; r++) dst[r] = out[r] / G;
            }
    }
    fftw_destroy_plan(fwd);
    m->fourier = 1;
done:
    fftw_free(in);
    fftw_free(out);
    return st;
}

gs_status rec_matcher_new(const gs_delight *d, int grid_hz, int bands, int K,
                          const rec_eq7_opts *o, rec_matcher **out)
{
    if (!out) return gs_fail(GS_EINVAL, "Eq. 7 matcher: out is NULL");
    *out = NULL;
    if (!d) return gs_fail(GS_EINVAL, "Eq. 7 matcher: DELIGHT is NULL");
    if (grid_hz != 50 && grid_hz != 60)
        return gs_fail(GS_EINVAL, "Eq. 7 matcher: grid_hz=%d: expected 50 or 60", grid_hz);
    if (bands != 1 && bands != 3)
        return gs_fail(GS_EINVAL, "Eq. 7 matcher: bands=%d: expected 1 or 3", bands);
    if (K < 2 || K > 4096)
        return gs_fail(GS_EINVAL, "Eq. 7 matcher: K=%d: expected 2 <= K <= 4096", K);
    rec_eq7_opts opts;
    rec_eq7_opts_default(&opts);
    if (o) opts = *o;
    gs_status s = check_opts(&opts);
    if (s != GS_OK) return s;

    rec_matcher *m = calloc(1, sizeof *m);
    if (!m) return gs_fail(GS_ENOMEM, "Eq. 7 matcher: out of memory");
    m->grid_hz = grid_hz;
    m->bands = bands;
    m->K = K;
    m->D = bands * K;
    m->o = opts;
    m->G = 8 * K > 96 ? 8 * K : 96;
    m->bg = opts.band_gains != REC_BANDS_CHROMA && bands > 1;
    m->red = opts.band_gains == REC_BANDS_REDDENED && bands > 1;
    m->nfit = m->bg ? bands : 1;
    m->fe_pix = isfinite(opts.model_error) ? opts.model_error : 0.0;
    m->bandpath = bands > 1 && (m->bg || m->fe_pix > 0.0);
    for (int band = 0; band < bands; band++)   /* Angstrom exponent 1.3 at 650/550/450 nm */
        m->red_f[band] = bands == 3 ? pow((650.0 - 100.0 * band) / 550.0, -1.3) - 1.0 : 0.0;
    size_t D = (size_t)m->D;

    /* candidate bulbs */
    size_t nd = gs_delight_count(d), nb = 0;
    for (size_t i = 0; i < nd; i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        if (b->grid_hz == grid_hz && b->brf.bands == bands && b->ref != GS_REF_UNLOCKED) nb++;
    }
    if (nb == 0) {
        rec_matcher_free(m);
        return gs_fail(GS_ENOTFOUND, "Eq. 7 matcher: no DELIGHT entry at %d Hz with %d band%s "
                       "(entries not locked to the mains are excluded)", grid_hz, bands,
                       bands > 1 ? "s" : "");
    }
    m->bulbs = calloc(nb, sizeof *m->bulbs);
    m->cont = calloc(nb, 1);
    m->first = calloc(nb, sizeof *m->first);
    m->count = calloc(nb, sizeof *m->count);
    m->H = calloc(nb, sizeof *m->H);
    m->F = calloc(nb, sizeof *m->F);
    m->nyq = calloc(nb * (size_t)bands, sizeof *m->nyq);
    m->nfine = calloc(nb, sizeof *m->nfine);
    m->harm = malloc(sizeof *m->harm * 2 * REC_SHAPE_H * (size_t)K);
    if (!m->bulbs || !m->cont || !m->first || !m->count || !m->H || !m->F || !m->nyq ||
        !m->nfine || !m->harm) {
        rec_matcher_free(m);
        return gs_fail(GS_ENOMEM, "Eq. 7 matcher: out of memory");
    }
    for (int h = 1; h <= REC_SHAPE_H; h++)
        for (int k = 0; k < K; k++) {
            double a = 2.0 * M_PI * h * (double)k / (double)K;
            m->harm[(size_t)(2 * (h - 1)) * (size_t)K + (size_t)k] = cos(a);
            m->harm[(size_t)(2 * (h - 1) + 1) * (size_t)K + (size_t)k] = sin(a);
        }
    for (size_t i = 0; i < nd; i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        if (!(b->grid_hz == grid_hz && b->brf.bands == bands && b->ref != GS_REF_UNLOCKED)) continue;
        gs_bulb *dst = &m->bulbs[m->nb];
        *dst = *b;
        dst->brf.v = NULL;
        s = gs_brf_copy(&dst->brf, &b->brf);
        if (s != GS_OK) {
            rec_matcher_free(m);
            return s;
        }
        m->nb++;
    }
    if (m->red) {
        /* the reddened chromaticities on the tau grid of eq7_scores.c's rec_eq7_loglik_red */
        m->red_c = malloc(sizeof *m->red_c * m->nb * REC_TAU_N * (size_t)bands);
        m->red_cmin = malloc(sizeof *m->red_cmin * m->nb * (size_t)bands);
        if (!m->red_c || !m->red_cmin) {
            rec_matcher_free(m);
            return gs_fail(GS_ENOMEM, "Eq. 7 matcher: out of memory");
        }
        for (size_t b = 0; b < m->nb; b++) {
            for (int band = 0; band < bands; band++) m->red_cmin[b * (size_t)bands + (size_t)band] = INFINITY;
            for (int i = 0; i < REC_TAU_N; i++) {
                double tau = rec_eq7_tau(i);
                for (int band = 0; band < bands; band++) {
                    double c = m->bulbs[b].chroma[band] * exp(-tau * m->red_f[band]);
                    m->red_c[(b * REC_TAU_N + (size_t)i) * (size_t)bands + (size_t)band] = c;
                    m->red_cmin[b * (size_t)bands + (size_t)band] = fmin(m->red_cmin[b * (size_t)bands + (size_t)band], c);
                }
            }
        }
    }

    /* phase set */
    if (opts.phases == REC_PHASES_CONTINUOUS) {
        m->np = 0;
    } else {
        m->np = opts.phases == REC_PHASES_6 ? 6 : 3;
        for (int p = 0; p < m->np; p++) {
            double deg = 120.0 * (p % 3) + (p >= 3 ? opts.transformer_deg : 0.0);
            deg = fmod(deg, 360.0);
            if (deg < 0.0) deg += 360.0;
            m->phase_deg[p] = deg >= 360.0 ? 0.0 : deg;
        }
        for (int p = 0; p < m->np; p++)
            for (int q = 0; q < p; q++)
                if (circ_dist(gs_phase_to_shift(m->phase_deg[p]), gs_phase_to_shift(m->phase_deg[q])) < 1e-9) {
                    double dp = m->phase_deg[p], dq = m->phase_deg[q];
                    rec_matcher_free(m);
                    return gs_fail(GS_EINVAL, "Eq. 7 matcher: transformer_deg=%g: phase %g deg gives the "
                                   "same BRF shift as %g deg (expected a shift that is not a multiple of 60 deg)",
                                   opts.transformer_deg, dp, dq);
                }
    }
    size_t M = 0;
    for (size_t b = 0; b < m->nb; b++) {
        m->cont[b] = opts.phases == REC_PHASES_CONTINUOUS || m->bulbs[b].ref == GS_REF_NONE;
        m->first[b] = M;
        m->count[b] = m->cont[b] ? (size_t)m->G : (size_t)m->np;
        M += m->count[b];
        m->ncont += m->cont[b];
    }
    if ((double)M * (double)D > 64.0 * 1024 * 1024) {
        rec_matcher_free(m);
        return gs_fail(GS_ELIMIT, "Eq. 7 matcher: %zu templates of %zu values exceed 64 Mi values "
                       "(use fewer bulbs, a smaller K or a discrete phase set)", M, D);
    }
    m->M = M;
    m->t = malloc(sizeof *m->t * M * D);
    m->tsq = malloc(sizeof *m->tsq * M * D);
    m->Mp = (M + LANES - 1) / LANES * LANES;
    m->tn = calloc(m->Mp * D, sizeof *m->tn);
    m->lnf = malloc(sizeof *m->lnf * m->Mp);
    m->tnd = malloc(sizeof *m->tnd * M * D);
    m->lognorm = malloc(sizeof *m->lognorm * M);
    m->tnorm = malloc(sizeof *m->tnorm * M);
    m->cellw = malloc(sizeof *m->cellw * M);
    m->logcellw = malloc(sizeof *m->logcellw * M);
    m->shift = malloc(sizeof *m->shift * M);
    m->tphase = malloc(sizeof *m->tphase * M);
    m->tbulb = malloc(sizeof *m->tbulb * M);
    m->tcell = malloc(sizeof *m->tcell * M);
    m->bnorm = malloc(sizeof *m->bnorm * M * (size_t)bands);
    m->lbnorm = malloc(sizeof *m->lbnorm * M * (size_t)bands);
    m->blog = malloc(sizeof *m->blog * M);
    /* (the per-band unit templates: the band path's only, 10 MB of a continuous DELIGHT) */
    m->tbn = m->bandpath ? malloc(sizeof *m->tbn * M * D) : NULL;
    m->tbnf = m->bandpath ? calloc(m->Mp * D, sizeof *m->tbnf) : NULL;
    m->blnf = malloc(sizeof *m->blnf * m->Mp);
    m->bib = malloc(sizeof *m->bib * m->Mp * (size_t)bands);
    m->bib2 = malloc(sizeof *m->bib2 * m->Mp * (size_t)bands);
    double *raw = malloc(sizeof *raw * D);
    double complex *acc = malloc(sizeof *acc * REC_TEMPLATE_ACC * (size_t)K);
    if (!m->t || !m->tsq || !m->tn || !m->lnf || !m->tnd || !m->lognorm || !m->tnorm || !m->cellw || !m->logcellw || !m->shift || !m->tphase ||
        !m->tbulb || !m->tcell || !m->bnorm || !m->lbnorm || !m->blog || (m->bandpath && (!m->tbn || !m->tbnf)) || !m->blnf || !m->bib || !m->bib2 || !raw ||
        !acc) {
        free(raw);
        free(acc);
        rec_matcher_free(m);
        return gs_fail(GS_ENOMEM, "Eq. 7 matcher: cannot allocate %zu templates", M);
    }
    s = m->ncont ? template_tables(m) : GS_OK;
    if (s != GS_OK) {
        free(raw);
        free(acc);
        rec_matcher_free(m);
        return s;
    }
    for (size_t b = 0; b < m->nb; b++) {
        const gs_bulb *bu = &m->bulbs[b];
        if (m->cont[b]) {
            s = fourier_setup(m, b);
            if (s != GS_OK) {
                free(raw);
                free(acc);
                rec_matcher_free(m);
                return s;
            }
        }
        for (size_t c = 0; c < m->count[b]; c++) {
            size_t j = m->first[b] + c;
            double sh, ph;
            if (m->cont[b]) {
                sh = (double)c / m->G;
                ph = bu->ref == GS_REF_NONE ? 0.0 : gs_shift_to_phase(sh);
                m->cellw[j] = 1.0 / m->G;
            } else {
                ph = m->phase_deg[c];
                sh = gs_phase_to_shift(ph);
                m->cellw[j] = 1.0 / m->np;
            }
            if (m->cont[b]) {
                /* the grid of a continuous bulb from its Fourier series (the same exact Eq. 5
                 * window means as gs_brf_integrate, ~100x cheaper per shift; chroma included) */
                rec_eq7_template_at(m, b, sh, raw, NULL, NULL, acc);
            } else {
                s = gs_brf_integrate(&bu->brf, sh, K, raw);
                if (s != GS_OK) {
                    free(raw);
                    free(acc);
                    rec_matcher_free(m);
                    return s;
                }
                if (!m->bg)   /* band gains: each band keeps its mean of 1 */
                    for (int band = 0; band < bands; band++)
                        for (int k = 0; k < K; k++) raw[band * K + k] *= bu->chroma[band];
            }
            double n2 = 0.0;
            for (int band = 0; band < bands; band++)
                for (int k = 0; k < K; k++) {
                    size_t dd = (size_t)band * (size_t)K + (size_t)k;
                    double v = raw[dd];
                    m->t[j * D + dd] = v;
                    m->tsq[j * D + dd] = v * v;
                    n2 += v * v;
                }
            if (!(n2 > 0.0) || !isfinite(n2)) {
                s = gs_fail(GS_ENUMERIC, "Eq. 7 matcher: bulb %s has an all-zero or non-finite "
                            "template", bu->id);
                free(raw);
                free(acc);
                rec_matcher_free(m);
                return s;
            }
            double inv = 1.0 / sqrt(n2);
            for (size_t dd = 0; dd < D; dd++) {
                m->tnd[j * D + dd] = m->t[j * D + dd] * inv;
                m->tn[j * D + dd] = (float)m->tnd[j * D + dd];
            }
            /* per band: norms, unit templates; with band gains the dim test (and the prefilter)
             * uses the unit vector of the summed brightness, sum_b t_b / |t_b|^2 */
            m->blog[j] = 0.0;
            double vv = 0.0;
            for (int band = 0; band < bands; band++) {
                double nb2 = 0.0;
                for (int k = 0; k < K; k++) nb2 += raw[band * K + k] * raw[band * K + k];
                double bn = sqrt(nb2);
                if (!(bn > 0.0) || !isfinite(bn)) {
                    s = gs_fail(GS_ENUMERIC, "Eq. 7 matcher: bulb %s has an all-zero band %d", bu->id, band);
                    free(raw);
                    free(acc);
                    rec_matcher_free(m);
                    return s;
                }
                m->bnorm[j * (size_t)bands + (size_t)band] = bn;
                m->lbnorm[j * (size_t)bands + (size_t)band] = log(bn);
                m->blog[j] += log(bn);
                for (int k = 0; k < K; k++) {
                    size_t dd = (size_t)band * (size_t)K + (size_t)k;
                    if (m->bandpath) {
                        m->tbn[j * D + dd] = raw[dd] / bn;
                        m->tbnf[j * D + dd] = (float)m->tbn[j * D + dd];
                    }
                    vv += raw[dd] * raw[dd] / (nb2 * nb2);
                }
            }
            if (m->bg) {
                double iv = 1.0 / sqrt(vv);
                for (int band = 0; band < bands; band++) {
                    double bn = m->bnorm[j * (size_t)bands + (size_t)band];
                    for (int k = 0; k < K; k++) {
                        size_t dd = (size_t)band * (size_t)K + (size_t)k;
                        m->tnd[j * D + dd] = raw[dd] / (bn * bn) * iv;
                        m->tn[j * D + dd] = (float)m->tnd[j * D + dd];
                    }
                }
            }
            m->lognorm[j] = 0.5 * log(n2);
            m->tnorm[j] = exp(m->lognorm[j]);
            m->logcellw[j] = log(m->cellw[j]);
            m->shift[j] = sh;
            m->tphase[j] = ph;
            m->tbulb[j] = (int)b;
            m->tcell[j] = (int)c;
        }
    }
    free(raw);
    free(acc);
    for (size_t j = 0; j < m->Mp; j++) {
        m->lnf[j] = j < M ? (float)m->lognorm[j] : 1e30f;
        m->blnf[j] = j < M ? (float)m->blog[j] : 1e30f;
        for (int band = 0; band < bands; band++) {
            double bn = j < M ? m->bnorm[j * (size_t)bands + (size_t)band] : 0.0;
            m->bib[(size_t)band * m->Mp + j] = j < M ? (float)(1.0 / bn) : 0.0f;
            m->bib2[(size_t)band * m->Mp + j] = j < M ? (float)(1.0 / (bn * bn)) : 1.0f;
        }
    }
    s = fourier_grid_setup(m);
    if (s == GS_OK) s = rec_eq7_series_setup(m);
    if (s == GS_OK) s = rec_eq7_sums_setup(m);
    if (s == GS_OK) s = rec_eq7_bulbscreen_setup(m);
    if (s != GS_OK) {
        rec_matcher_free(m);
        return s;
    }
    /* the Fourier screen (continuous grids) replaces the prefilter. The prefilter bounds
     * x . tnd_j; that bounds the dim statistic of the one-gain model with one sigma per row, and
     * of the band-gain model with any per-band sigma >= the row's (its unit vector is tnd_j),
     * but not of one gain with per-band sigmas: no prefilter then */
    s = rec_eq7_pixscreen_setup(m);
    if (s == GS_OK && !m->fs_on && !(m->bandpath && !m->bg)) s = prefilter_setup(m);
    if (s != GS_OK) {
        rec_matcher_free(m);
        return s;
    }
    int thr_dof = m->D - m->nfit - 1;
    m->chi2_thr = thr_dof >= 1 && opts.unknown_p > 0.0 ? gs_chi2_isf(opts.unknown_p, thr_dof) : INFINITY;
    int nt = 2 * (int)LOGPHI_ZMAX * LOGPHI_STEPS + 1;
    for (int i = 0; i < nt; i++) m->logphi_tab[i] = gs_log_phi(-LOGPHI_ZMAX + (double)i / LOGPHI_STEPS);
    m->logphi_tab[nt] = m->logphi_tab[nt - 1];
    *out = m;
    return GS_OK;
}

