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
#include "recognize/recognize.h"
#include "recognize/internal.h"

#include <cblas.h>
#include <lapacke.h>
#include <complex.h>
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static const double two_pi = 6.283185307179586476925286766559;
#define INV_SQRT12 0.28867513459481288225457439025098  /* std of a uniform shift, cycles */
#define CUT_PIXEL 30.0    /* nats: pairs this far below the best are < 1e-13 of it */
#define CUT_REFINE 30.0   /* nats: continuous bulbs this far below the best keep their grid peak */
#define FLOAT_ERR 2e-6    /* error of z^2/2 from float scores, per unit |x|^2/sigma^2 */
#define PHASE_WINDOW 0.16666666666666666  /* +-30 deg of phase = +-1/6 cycle of shift */
#define PIX_BLOCK 1024    /* rows per SGEMM block */
#define LANES 16          /* row loops in blocks of 16 floats (vectorised by the compiler) */
#define LOGPHI_ZMAX 12.0
#define LOGPHI_STEPS 32   /* table points per unit of z */

/* ------------------------------------------------------------ numerics */

/* Phi(z) */
static double phi_cdf(double z)
{
    return 0.5 * erfc(-z * M_SQRT1_2);
}

/* Circular distance of two shifts, cycles, in [0, 0.5]. */
static double circ_dist(double a, double b)
{
    double d = fmod(fabs(a - b), 1.0);
    return d > 0.5 ? 1.0 - d : d;
}

static double wrap01(double s)
{
    s = fmod(s, 1.0);
    if (s < 0.0) s += 1.0;
    return s >= 1.0 ? 0.0 : s;
}

/* ------------------------------------------------------------ matcher */

struct rec_matcher {
    int grid_hz, bands, K, D;           /* D = bands * K values per light */
    rec_eq7_opts o;
    size_t nb;                          /* candidate bulbs */
    gs_bulb *bulbs;                    /* owned copies */
    int np;                             /* discrete phases (3 or 6), 0 in continuous mode */
    double phase_deg[6];
    int G;                              /* grid cells per cycle for continuous bulbs */
    unsigned char *cont;                /* [nb] bulb searched over a continuous shift */
    size_t *first, *count;              /* [nb] its templates */
    size_t M;                           /* templates */
    double *t;                          /* [M * D] templates */
    double *tsq;                        /* [M * D] squared templates */
    size_t Mp;                          /* M rounded up to a multiple of LANES */
    float *tn;                          /* [Mp * D] templates / |t| (pixels), zero padded */
    float *lnf;                         /* [Mp] log |t| as float, 1e30 for padding */
    double *tnd;                        /* [M * D] templates / |t| in double */
    int pr;                             /* prefilter dimension R (0: no prefilter) */
    float *pe;                          /* [R * D] orthonormal basis of the prefilter */
    float *pc;                          /* [Mp * R] template coefficients in that basis */
    float *prho;                        /* [Mp] residual norms of the unit templates */
    int ncont;                          /* bulbs searched over a continuous shift */
    double *lognorm;                    /* [M] log |t| */
    double *cellw;                      /* [M] prior mass of the template within its bulb */
    double *shift;                      /* [M] cycles */
    double *tphase;                     /* [M] grid phase, deg (0 for GS_REF_NONE bulbs) */
    int *tbulb, *tcell;                 /* [M] bulb, index among the bulb's templates */
    /* Fourier series of the window means, continuous bulbs only:
     * t_k(s) = F0 + sum_h Re(F_h e^{2 pi i h (k/K - s)}) + nyquist term. */
    int *H;                             /* [nb] harmonics kept */
    double complex **F;                 /* [nb] -> [bands * (H + 1)], F[band * (H+1) + h] */
    double *nyq;                        /* [nb * bands] Nyquist coefficient */
    int *nfine;                         /* [nb] BRF samples per cycle */
    double complex *wk;                 /* [K] e^{2 pi i j / K} */
    double chi2_thr;                    /* pixels: chi2 at p = unknown_p, dof D - nfit - 1 */
    /* per-band brightness (band_gains) and model error */
    int bg;                             /* one brightness per band (band_gains and bands > 1) */
    int nfit;                           /* brightness parameters: bands (bg) or 1 */
    int bandpath;                       /* pixels: per-band scores (bands > 1, bg or model error) */
    double *bnorm;                      /* [M * bands] |t_j| over band b's K values */
    double *blog;                       /* [M] sum over bands of log |t_jb| */
    double *tbn;                        /* [M * D] templates, each band of unit norm */
    float *tbnf;                        /* [Mp * D] the same in float, zero padded */
    float *blnf;                        /* [Mp] blog as float, 1e30 for padding */
    float *bib, *bib2;                  /* [bands * Mp] 1/|t_jb|, 1/|t_jb|^2 (padding 0, 1) */
    double logphi_tab[2 * (int)LOGPHI_ZMAX * LOGPHI_STEPS + 2];
};

void rec_eq7_opts_default(rec_eq7_opts *o)
{
    if (!o) return;
    o->phases = REC_PHASES_3;
    o->transformer_deg = 30.0;
    o->unknown_p = 1e-3;
    o->ambiguous_conf = 0.8;
    o->min_snr = 3.0;
    o->band_gains = 1;
    o->model_error = 0.04;
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
    free(m->shift);
    free(m->tphase);
    free(m->tbulb);
    free(m->tcell);
    free(m->H);
    free(m->F);
    free(m->nyq);
    free(m->nfine);
    free(m->wk);
    free(m->bnorm);
    free(m->blog);
    free(m->tbn);
    free(m->tbnf);
    free(m->blnf);
    free(m->bib);
    free(m->bib2);
    free(m);
}

size_t rec_matcher_bulb_count(const rec_matcher *m)
{
    return m ? m->nb : 0;
}

const gs_bulb *rec_matcher_bulb(const rec_matcher *m, size_t i)
{
    return (m && i < m->nb) ? &m->bulbs[i] : NULL;
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
    if (o->band_gains != 0 && o->band_gains != 1)
        return gs_fail(GS_EINVAL, "Eq. 7 options: band_gains=%d: expected 0 or 1", o->band_gains);
    if (!(o->model_error >= 0.0 && o->model_error < 1.0))
        return gs_fail(GS_EINVAL, "Eq. 7 options: model_error=%g: expected [0, 1)", o->model_error);
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
                (cexp(I * two_pi * fmod((double)h / K, 1.0)) - 1.0) * K / (I * two_pi * h);
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
    return GS_OK;
}

/* Exact template of continuous bulb b at shift s and its first two derivatives in s (any of
 * dt, d2t may be NULL). acc is scratch of 3 * K complex values. */
static void template_at(const rec_matcher *m, size_t b, double s, double *t, double *dt,
                        double *d2t, double complex *acc)
{
    int K = m->K, H = m->H[b], n = m->nfine[b];
    s = wrap01(s);
    double complex *A0 = acc, *A1 = acc + K, *A2 = acc + 2 * K;
    double complex base = cexp(-I * two_pi * s);
    for (int band = 0; band < m->bands; band++) {
        const double complex *F = m->F[b] + (size_t)band * (size_t)(H + 1);
        for (int r = 0; r < K; r++) A0[r] = A1[r] = A2[r] = 0.0;
        double complex e = 1.0;
        int r = 0;
        if (dt || d2t) {
            for (int h = 1; h <= H; h++) {
                if ((h & 31) == 0) e = cexp(-I * two_pi * fmod((double)h * s, 1.0));
                else e *= base;
                if (++r == K) r = 0;
                double complex g = F[h] * e;
                double w = two_pi * h;
                A0[r] += g;
                A1[r] += g * (-I * w);
                A2[r] += g * (-w * w);
            }
        } else {
            for (int h = 1; h <= H; h++) {
                if ((h & 31) == 0) e = cexp(-I * two_pi * fmod((double)h * s, 1.0));
                else e *= base;
                if (++r == K) r = 0;
                A0[r] += F[h] * e;
            }
        }
        double nq = m->nyq[b * (size_t)m->bands + (size_t)band];
        for (int k = 0; k < K; k++) {
            double v0 = creal(F[0]), v1 = 0.0, v2 = 0.0;
            int rk = 0;   /* r k mod K */
            for (int q = 0; q < K; q++) {
                double complex wv = m->wk[rk];
                v0 += creal(A0[q]) * creal(wv) - cimag(A0[q]) * cimag(wv);
                if (dt || d2t) {
                    v1 += creal(A1[q]) * creal(wv) - cimag(A1[q]) * cimag(wv);
                    v2 += creal(A2[q]) * creal(wv) - cimag(A2[q]) * cimag(wv);
                }
                rk += k;
                if (rk >= K) rk -= K;
            }
            if (nq != 0.0) {
                double a = (double)k / K - s, bb = (double)(k + 1) / K - s, pn = M_PI * n;
                v0 += nq * (sin(pn * bb) - sin(pn * a)) * K / pn;
                v1 += nq * -(cos(pn * bb) - cos(pn * a)) * K;
                v2 += nq * -(sin(pn * bb) - sin(pn * a)) * K * pn;
            }
            size_t d = (size_t)band * (size_t)K + (size_t)k;
            t[d] = v0;
            if (dt) dt[d] = v1;
            if (d2t) d2t[d] = v2;
        }
    }
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
    m->bg = opts.band_gains && bands > 1;
    m->nfit = m->bg ? bands : 1;
    m->bandpath = bands > 1 && (m->bg || opts.model_error > 0.0);
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
    m->wk = malloc(sizeof *m->wk * (size_t)K);
    if (!m->bulbs || !m->cont || !m->first || !m->count || !m->H || !m->F || !m->nyq ||
        !m->nfine || !m->wk) {
        rec_matcher_free(m);
        return gs_fail(GS_ENOMEM, "Eq. 7 matcher: out of memory");
    }
    for (int j = 0; j < K; j++) m->wk[j] = cexp(I * two_pi * (double)j / K);
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
    m->cellw = malloc(sizeof *m->cellw * M);
    m->shift = malloc(sizeof *m->shift * M);
    m->tphase = malloc(sizeof *m->tphase * M);
    m->tbulb = malloc(sizeof *m->tbulb * M);
    m->tcell = malloc(sizeof *m->tcell * M);
    m->bnorm = malloc(sizeof *m->bnorm * M * (size_t)bands);
    m->blog = malloc(sizeof *m->blog * M);
    m->tbn = malloc(sizeof *m->tbn * M * D);
    m->tbnf = calloc(m->Mp * D, sizeof *m->tbnf);
    m->blnf = malloc(sizeof *m->blnf * m->Mp);
    m->bib = malloc(sizeof *m->bib * m->Mp * (size_t)bands);
    m->bib2 = malloc(sizeof *m->bib2 * m->Mp * (size_t)bands);
    double *raw = malloc(sizeof *raw * D);
    double complex *acc = malloc(sizeof *acc * 3 * (size_t)K);
    if (!m->t || !m->tsq || !m->tn || !m->lnf || !m->tnd || !m->lognorm || !m->cellw || !m->shift || !m->tphase ||
        !m->tbulb || !m->tcell || !m->bnorm || !m->blog || !m->tbn || !m->tbnf || !m->blnf || !m->bib || !m->bib2 || !raw ||
        !acc) {
        free(raw);
        free(acc);
        rec_matcher_free(m);
        return gs_fail(GS_ENOMEM, "Eq. 7 matcher: cannot allocate %zu templates", M);
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
                template_at(m, b, sh, raw, NULL, NULL, acc);
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
                m->blog[j] += log(bn);
                for (int k = 0; k < K; k++) {
                    size_t dd = (size_t)band * (size_t)K + (size_t)k;
                    m->tbn[j * D + dd] = raw[dd] / bn;
                    m->tbnf[j * D + dd] = (float)m->tbn[j * D + dd];
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
    for (size_t b = 0; b < m->nb; b++) m->ncont += m->cont[b];
    /* the prefilter bounds x . tnd_j; that bounds the dim statistic of the one-gain model with
     * one sigma per row, and of the band-gain model with any per-band sigma >= the row's (its
     * unit vector is tnd_j), but not of one gain with per-band sigmas: no prefilter then */
    s = (m->bandpath && !m->bg) ? GS_OK : prefilter_setup(m);
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

/* log Phi(z) from the matcher's table (error < 4e-5), for the pixel path. */
static double log_phi_fast(const rec_matcher *m, double z)
{
    if (z >= LOGPHI_ZMAX) return 0.0;
    if (z <= -LOGPHI_ZMAX) return gs_log_phi(z);
    double u = (z + LOGPHI_ZMAX) * LOGPHI_STEPS;
    int i = (int)u;
    double f = u - i;
    return m->logphi_tab[i] + f * (m->logphi_tab[i + 1] - m->logphi_tab[i]);
}

/* ------------------------------------------------------------ the decision */

/* Scratch for one light or pixel. */
typedef struct {
    double *L;              /* [M] log likelihood (valid for candidates) */
    double *mass;           /* [M] posterior mass relative to the best */
    size_t *cand;           /* [M + 3 nb] candidate templates */
    size_t ncand;
    unsigned char *mark;    /* [M] in cand */
    double *bmass;          /* [nb] */
    double *wmass;          /* [nb] mass within +-1/6 cycle of the bulb's peak (continuous) */
    unsigned char *has_peak;/* [nb] */
    double *peak_s, *peak_L, *peak_sig;   /* [nb] refined peak: shift, log lik, std (cycles) */
    double *peak_z;                        /* [nb] brightness / its std at the peak */
    double *peak_gain;                     /* [nb] Sxx - chi2 at the peak */
    size_t *peak_cell;      /* [nb] template of the best grid cell */
    /* light path */
    double *S, *T, *w, *wx, *xs;           /* [nfit * M] ([f * M + j]), [nfit * M], [D] x 3 */
    double *tt, *dt, *d2t;                 /* [D] */
    double complex *acc;                   /* [3 K] */
} work;

static void work_free(work *w)
{
    free(w->L);
    free(w->mass);
    free(w->cand);
    free(w->mark);
    free(w->bmass);
    free(w->wmass);
    free(w->has_peak);
    free(w->peak_s);
    free(w->peak_L);
    free(w->peak_sig);
    free(w->peak_z);
    free(w->peak_gain);
    free(w->peak_cell);
    free(w->S);
    free(w->T);
    free(w->w);
    free(w->wx);
    free(w->xs);
    free(w->tt);
    free(w->dt);
    free(w->d2t);
    free(w->acc);
    memset(w, 0, sizeof *w);
}

static gs_status work_alloc(const rec_matcher *m, work *w)
{
    memset(w, 0, sizeof *w);
    size_t M = m->M, nb = m->nb, D = (size_t)m->D;
    w->L = malloc(sizeof *w->L * M);
    w->mass = malloc(sizeof *w->mass * M);
    w->cand = malloc(sizeof *w->cand * (M + 3 * nb));
    w->mark = calloc(M, 1);
    w->bmass = malloc(sizeof *w->bmass * nb);
    w->wmass = malloc(sizeof *w->wmass * nb);
    w->has_peak = calloc(nb, 1);
    w->peak_s = malloc(sizeof *w->peak_s * nb);
    w->peak_L = malloc(sizeof *w->peak_L * nb);
    w->peak_sig = malloc(sizeof *w->peak_sig * nb);
    w->peak_z = malloc(sizeof *w->peak_z * nb);
    w->peak_gain = malloc(sizeof *w->peak_gain * nb);
    w->peak_cell = malloc(sizeof *w->peak_cell * nb);
    w->S = malloc(sizeof *w->S * M * (size_t)m->nfit);
    w->T = malloc(sizeof *w->T * M * (size_t)m->nfit);
    w->w = malloc(sizeof *w->w * D);
    w->wx = malloc(sizeof *w->wx * D);
    w->xs = malloc(sizeof *w->xs * D);
    w->tt = malloc(sizeof *w->tt * D);
    w->dt = malloc(sizeof *w->dt * D);
    w->d2t = malloc(sizeof *w->d2t * D);
    w->acc = malloc(sizeof *w->acc * 3 * (size_t)m->K);
    if (!w->L || !w->mass || !w->cand || !w->mark || !w->bmass || !w->wmass || !w->has_peak ||
        !w->peak_s || !w->peak_L || !w->peak_sig || !w->peak_z || !w->peak_gain || !w->peak_cell || !w->S || !w->T || !w->w ||
        !w->wx || !w->xs || !w->tt || !w->dt || !w->d2t || !w->acc) {
        work_free(w);
        return gs_fail(GS_ENOMEM, "Eq. 7: cannot allocate scratch for %zu templates", M);
    }
    return GS_OK;
}

typedef struct {
    int bulb;               /* -1: nothing finite */
    size_t tmpl;            /* the fitted template (continuous: best grid cell) */
    double shift;           /* cycles */
    double conf, bulb_conf, phase_conf;
    int runner_bulb;
    double runner_shift, runner_conf;
    size_t runner_tmpl;
} decision;

/* The phase (deg) to report for bulb b at shift s via template j. */
static double report_phase(const rec_matcher *m, int b, size_t j, double s)
{
    if (m->bulbs[b].ref == GS_REF_NONE) return 0.0;
    if (!m->cont[b]) return m->tphase[j];
    return gs_shift_to_phase(s);
}

static void add_cand(const rec_matcher *m, work *w, size_t j)
{
    (void)m;
    if (!w->mark[j]) {
        w->mark[j] = 1;
        w->cand[w->ncand++] = j;
    }
}

/* A pair candidate for the best / runner-up: log of its mass relative to exp(Lmax). */
typedef struct {
    double lm;
    int bulb;
    size_t tmpl;
    double shift;
} pair_c;

static void consider(pair_c *best, pair_c *second, double lm, int bulb, size_t tmpl, double shift)
{
    if (!(lm > -INFINITY)) return;
    pair_c c = {lm, bulb, tmpl, shift};
    if (best->bulb < 0 || lm > best->lm) {
        *second = *best;
        *best = c;
    } else if (second->bulb < 0 || lm > second->lm) {
        *second = c;
    }
}

/* log of a summed mass, or the fallback when it underflowed (used for ranking only) */
static double log_mass(double mass, double fallback)
{
    return mass > 0.0 ? log(mass) : fallback;
}

/* Posterior over (bulb, phase) from w->L of the candidates (w->cand) and the refined peaks of
 * continuous bulbs. Lmax is the largest log likelihood (grid or peak). Pairs are ranked by
 * their log mass, so a runner-up exists even when its posterior underflows. */
static void decide(const rec_matcher *m, work *w, double Lmax, decision *dec)
{
    size_t nb = m->nb;
    double cell = 1.0 / m->G;
    dec->bulb = -1;
    dec->runner_bulb = -1;
    dec->conf = dec->bulb_conf = dec->phase_conf = dec->runner_conf = 0.0;
    dec->tmpl = dec->runner_tmpl = 0;
    dec->shift = dec->runner_shift = 0.0;
    if (!isfinite(Lmax)) goto done;
    for (size_t i = 0; i < w->ncand; i++) {
        size_t j = w->cand[i];
        w->mass[j] = isfinite(w->L[j]) ? exp(w->L[j] - Lmax) * m->cellw[j] : 0.0;
    }
    /* Laplace correction of the cells around narrow peaks (narrower than a cell) */
    for (size_t b = 0; m->ncont && b < nb; b++) {
        if (!m->cont[b] || !w->has_peak[b] || !(w->peak_sig[b] < cell)) continue;
        size_t c0 = (size_t)m->tcell[w->peak_cell[b]];
        double d0 = w->peak_s[b] - (double)c0 / m->G;   /* peak relative to the cell centre */
        d0 -= floor(d0 + 0.5);
        double amp = exp(w->peak_L[b] - Lmax) * sqrt(2.0 * M_PI) * w->peak_sig[b];
        for (int dc = -1; dc <= 1; dc++) {
            size_t c = (c0 + (size_t)m->G + (size_t)(long)dc) % (size_t)m->G;
            size_t j = m->first[b] + c;
            double lo = (dc - 0.5) * cell - d0, hi = (dc + 0.5) * cell - d0;
            if (!w->mark[j]) {
                add_cand(m, w, j);
                w->L[j] = -INFINITY;
            }
            w->mass[j] = amp * (phi_cdf(hi / w->peak_sig[b]) - phi_cdf(lo / w->peak_sig[b]));
        }
    }
    for (size_t i = 0; i < w->ncand; i++) {
        int b = m->tbulb[w->cand[i]];
        w->bmass[b] = w->wmass[b] = 0.0;
    }
    double Z = 0.0;
    for (size_t i = 0; i < w->ncand; i++) {
        size_t j = w->cand[i];
        Z += w->mass[j];
        w->bmass[m->tbulb[j]] += w->mass[j];
        int b = m->tbulb[j];
        if (m->cont[b] && w->has_peak[b] && circ_dist(m->shift[j], w->peak_s[b]) <= PHASE_WINDOW)
            w->wmass[b] += w->mass[j];
    }
    if (!(Z > 0.0) || !isfinite(Z)) goto done;
    /* pairs: discrete (bulb, phase) templates; continuous voltage bulbs (bulb, +-30 deg around
     * the peak); shape-only bulbs as a whole */
    pair_c best = {-INFINITY, -1, 0, 0.0}, second = {-INFINITY, -1, 0, 0.0};
    for (size_t i = 0; i < w->ncand; i++) {
        size_t j = w->cand[i];
        int b = m->tbulb[j];
        if (m->cont[b]) continue;
        consider(&best, &second, w->L[j] - Lmax + log(m->cellw[j]), b, j, m->shift[j]);
    }
    for (size_t b = 0; m->ncont && b < nb; b++) {
        if (!m->cont[b] || !w->has_peak[b]) continue;
        double pm = m->bulbs[b].ref == GS_REF_NONE ? w->bmass[b] : w->wmass[b];
        double sg = w->peak_sig[b] < cell ? w->peak_sig[b] * sqrt(2.0 * M_PI) : cell;
        consider(&best, &second, log_mass(pm, w->peak_L[b] - Lmax + log(sg)), (int)b,
                 w->peak_cell[b], w->peak_s[b]);
    }
    if (best.bulb < 0) goto done;
    int bb = best.bulb;
    /* a continuous voltage winner's mass outside its window is a runner-up candidate */
    if (m->cont[bb] && m->bulbs[bb].ref != GS_REF_NONE) {
        double out_mass = 0.0, top = -INFINITY;
        size_t jt = 0;
        for (size_t i = 0; i < w->ncand; i++) {
            size_t j = w->cand[i];
            if (m->tbulb[j] != bb || circ_dist(m->shift[j], best.shift) <= PHASE_WINDOW) continue;
            out_mass += w->mass[j];
            if (w->L[j] > top) {
                top = w->L[j];
                jt = j;
            }
        }
        double lmo = log_mass(out_mass, top - Lmax + log(cell));
        if (top > -INFINITY && (second.bulb < 0 || lmo > second.lm)) {
            pair_c c = {lmo, bb, jt, m->shift[jt]};
            second = c;
        }
    }
    dec->bulb = bb;
    dec->tmpl = best.tmpl;
    dec->shift = best.shift;
    dec->conf = exp(best.lm) / Z;
    dec->bulb_conf = w->bmass[bb] / Z;
    if (second.bulb >= 0) {
        dec->runner_bulb = second.bulb;
        dec->runner_tmpl = second.tmpl;
        dec->runner_shift = second.shift;
        dec->runner_conf = exp(second.lm) / Z;
    }
    if (m->bulbs[bb].ref != GS_REF_NONE) {
        double pc = 0.0;
        for (size_t i = 0; i < w->ncand; i++) {
            size_t j = w->cand[i];
            int b = m->tbulb[j];
            if (m->bulbs[b].ref == GS_REF_NONE) continue;
            if (m->cont[bb]) {
                if (circ_dist(m->shift[j], dec->shift) <= PHASE_WINDOW) pc += w->mass[j];
            } else if (m->tcell[j] == m->tcell[dec->tmpl]) {
                pc += w->mass[j];
            }
        }
        dec->phase_conf = pc / Z;
    }
    if (dec->conf > 1.0) dec->conf = 1.0;
    if (dec->bulb_conf > 1.0) dec->bulb_conf = 1.0;
    if (dec->phase_conf > 1.0) dec->phase_conf = 1.0;
    if (dec->runner_conf > 1.0) dec->runner_conf = 1.0;
done:
    for (size_t i = 0; i < w->ncand; i++) w->mark[w->cand[i]] = 0;
    w->ncand = 0;
}

/* ------------------------------------------------------------ one light */

/* chi2(s) of continuous bulb b with the scale(s) profiled (a >= 0), and its derivatives. */
typedef struct {
    double chi2, d1, d2;     /* chi2 and its first two derivatives in s */
    int nf;                  /* brightness parameters */
    double S[GS_MAX_BANDS], T[GS_MAX_BANDS];   /* sum w x t, sum w t^2 (per band with gains) */
} chi2_eval;

static void chi2_at(const rec_matcher *m, work *w, size_t b, double s, double Sxx, chi2_eval *e)
{
    size_t K = (size_t)m->K;
    int nf = m->nfit;
    size_t span = m->bg ? K : (size_t)m->D;   /* samples of one brightness parameter */
    template_at(m, b, s, w->tt, w->dt, w->d2t, w->acc);
    e->nf = nf;
    e->chi2 = Sxx;
    e->d1 = e->d2 = 0.0;
    for (int f = 0; f < nf; f++) {
        double S = 0, S1 = 0, S2 = 0, T = 0, T1 = 0, T2 = 0;
        for (size_t d = (size_t)f * span; d < (size_t)(f + 1) * span; d++) {
            double t = w->tt[d], t1 = w->dt[d], t2 = w->d2t[d];
            S += w->wx[d] * t;
            S1 += w->wx[d] * t1;
            S2 += w->wx[d] * t2;
            T += w->w[d] * t * t;
            T1 += 2.0 * w->w[d] * t * t1;
            T2 += 2.0 * w->w[d] * (t1 * t1 + t * t2);
        }
        e->S[f] = S;
        e->T[f] = T;
        /* a* <= 0 (or no samples): the constrained fit is a = 0, this part of chi2 flat */
        if (!(T > 0.0) || S <= 0.0) continue;
        /* f = S^2/T, chi2 = Sxx - sum f */
        double f0 = S * S / T;
        double f1 = 2.0 * S * S1 / T - S * S * T1 / (T * T);
        double f2 = (2.0 * S1 * S1 + 2.0 * S * S2) / T - 4.0 * S * S1 * T1 / (T * T) -
                    S * S * T2 / (T * T) + 2.0 * S * S * T1 * T1 / (T * T * T);
        e->chi2 -= f0;
        e->d1 -= f1;
        e->d2 -= f2;
    }
    if (e->chi2 < 0.0) e->chi2 = 0.0;
}

/* Log likelihood (no prior) for sums S, T: -chi2/2 - log(T)/2 + log Phi(S/sqrt(T)). */
static double loglik(double Sxx, double S, double T)
{
    if (!(T > 0.0)) return -INFINITY;
    double z = S / sqrt(T);
    double chi2 = Sxx - S * z / sqrt(T);
    if (chi2 < 0.0) chi2 = 0.0;
    return -0.5 * chi2 - 0.5 * log(T) + gs_log_phi(z);
}

/* The same with nf brightness parameters (one per band, each marginalised over a_b > 0 with a
 * flat prior): -chi2/2 + sum_b (-log(T_b)/2 + log Phi(S_b/sqrt(T_b))); a band without usable
 * samples (T_b = 0 for every template) has no parameter. */
static double loglik_n(int nf, double Sxx, const double *S, const double *T)
{
    if (nf == 1) return loglik(Sxx, S[0], T[0]);
    double chi2 = Sxx, l = 0.0;
    int any = 0;
    for (int f = 0; f < nf; f++) {
        if (!(T[f] > 0.0)) continue;
        double z = S[f] / sqrt(T[f]);
        chi2 -= z * z;
        l += -0.5 * log(T[f]) + gs_log_phi(z);
        any = 1;
    }
    if (!any) return -INFINITY;
    if (chi2 < 0.0) chi2 = 0.0;
    return -0.5 * chi2 + l;
}

/* Brightness / its std: S/sqrt(T) for one gain; with band gains sum_b a_b / sqrt(sum_b 1/T_b),
 * a_b = S_b/T_b (unconstrained: a linear statistic, as the one-gain z); 0 when not positive. */
static double snr_n(int nf, const double *S, const double *T)
{
    if (nf == 1) return (S[0] > 0.0 && T[0] > 0.0) ? S[0] / sqrt(T[0]) : 0.0;
    double num = 0.0, den = 0.0;
    for (int f = 0; f < nf; f++) {
        if (!(T[f] > 0.0)) continue;
        num += S[f] / T[f];
        den += 1.0 / T[f];
    }
    double z = den > 0.0 ? num / sqrt(den) : 0.0;
    return z > 0.0 ? z : 0.0;
}

/* Sxx - chi2 of the constrained fit (a_b >= 0) from the sums. */
static double gain_n(int nf, const double *S, const double *T)
{
    double g = 0.0;
    for (int f = 0; f < nf; f++)
        if (S[f] > 0.0 && T[f] > 0.0) g += S[f] * S[f] / T[f];
    return g;
}

/* The sums of template j from the work arrays ([f * M + j]). */
static void sums_of(const rec_matcher *m, const work *w, size_t j, double *S, double *T)
{
    for (int f = 0; f < m->nfit; f++) {
        S[f] = w->S[(size_t)f * m->M + j];
        T[f] = w->T[(size_t)f * m->M + j];
    }
}

/* Refine continuous bulb b around its best grid cell j0: safeguarded Newton on the exact chi2(s)
 * within +-1 cell, then the peak's log likelihood and std. */
static void refine_peak(const rec_matcher *m, work *w, size_t b, size_t j0, double Sxx)
{
    double cell = 1.0 / m->G;
    size_t c0 = (size_t)m->tcell[j0], G = (size_t)m->G;
    size_t jm = m->first[b] + (c0 + G - 1) % G, jp = m->first[b] + (c0 + 1) % G;
    double sc = (double)c0 / m->G;
    /* grid chi2 (profiled, a >= 0) at the three cells */
    double q[3], Sv[GS_MAX_BANDS], Tv[GS_MAX_BANDS];
    size_t js[3] = {jm, j0, jp};
    for (int i = 0; i < 3; i++) {
        sums_of(m, w, js[i], Sv, Tv);
        q[i] = Sxx - gain_n(m->nfit, Sv, Tv);
    }
    double den = q[0] - 2.0 * q[1] + q[2];
    double u = den > 0.0 ? 0.5 * cell * (q[0] - q[2]) / den : 0.0;
    if (u < -cell) u = -cell;
    if (u > cell) u = cell;
    double lo = -cell, hi = cell;
    chi2_eval e;
    for (int it = 0; it < 60; it++) {
        chi2_at(m, w, b, sc + u, Sxx, &e);
        if (e.d1 > 0.0) hi = u;
        else lo = u;
        double step;
        if (e.d2 > 0.0) step = -e.d1 / e.d2;
        else step = e.d1 > 0.0 ? -0.25 * (u - lo) : 0.25 * (hi - u);
        double un = u + step;
        if (!(un > lo && un < hi)) un = 0.5 * (lo + hi);
        if (fabs(un - u) < 1e-11 || hi - lo < 1e-11) {   /* 2e-9 deg of phase */
            u = un;
            break;
        }
        u = un;
    }
    chi2_at(m, w, b, sc + u, Sxx, &e);
    double sig = (e.d2 > 0.0) ? sqrt(2.0 / e.d2) : INV_SQRT12;
    if (!(sig < INV_SQRT12)) sig = INV_SQRT12;
    double Lp = loglik_n(e.nf, Sxx, e.S, e.T);
    double gp = Sxx - e.chi2;
    /* never below the grid: if the refinement did not improve, keep the best cell */
    if (!(Lp >= w->L[j0])) {
        u = 0.0;
        Lp = w->L[j0];
        gp = Sxx - q[1];
        double den2 = q[0] - 2.0 * q[1] + q[2];
        sig = den2 > 0.0 ? cell * sqrt(2.0 / den2) : INV_SQRT12;
        if (!(sig < INV_SQRT12)) sig = INV_SQRT12;
    }
    w->has_peak[b] = 1;
    w->peak_z[b] = snr_n(e.nf, e.S, e.T);
    if (u == 0.0) {
        sums_of(m, w, j0, Sv, Tv);
        w->peak_z[b] = snr_n(m->nfit, Sv, Tv);
    }
    w->peak_gain[b] = gp;
    w->peak_s[b] = wrap01(sc + u);
    w->peak_L[b] = Lp;
    w->peak_sig[b] = sig;
    w->peak_cell[b] = j0;
}

static void no_answer(rec_match *out, unsigned flags)
{
    memset(out, 0, sizeof *out);
    out->bulb = -1;
    out->runner_bulb = -1;
    out->flags = flags | REC_MATCH_BULB_AMBIGUOUS | REC_MATCH_PHASE_AMBIGUOUS;
}

static gs_status match_light_ws(const rec_matcher *m, work *w, const double *signal,
                                const double *sigma, rec_match *out)
{
    size_t D = (size_t)m->D, M = m->M;
    unsigned flags = 0;
    /* usable samples: finite signal, finite sigma > 0; sigma = +inf marks a dropped sample */
    double c = 0.0;
    int used = 0;
    for (size_t d = 0; d < D; d++) {
        double x = signal[d], s = sigma[d];
        if (isinf(s) && s > 0.0) continue;
        if (!isfinite(x) || !isfinite(s) || !(s > 0.0)) {
            flags |= REC_MATCH_BAD_INPUT;
            continue;
        }
        if (s > c) c = s;
    }
    /* model error: the variance of each sample gains (model_error mu_b)^2, mu_b the RMS signal
     * level of the band: mu_b^2 = mean(x^2 - sigma^2) over its usable samples (>= 0), in units of
     * c. A multiplicative error of model_error per sample then adds, on average over the band,
     * exactly the variance assumed (E chi2 = dof), though spread evenly over the K windows. */
    double mu[GS_MAX_BANDS] = {0.0, 0.0, 0.0};
    const double fe = m->o.model_error;
    if (fe > 0.0) {
        size_t K = (size_t)m->K;
        for (int band = 0; band < m->bands; band++) {
            double sum = 0.0;
            int n = 0;
            for (size_t d = (size_t)band * K; d < (size_t)(band + 1) * K; d++) {
                double x = signal[d], s = sigma[d];
                if (!isfinite(x) || !isfinite(s) || !(s > 0.0)) continue;
                sum += (x / c) * (x / c) - (s / c) * (s / c);
                n++;
            }
            mu[band] = (n > 0 && sum > 0.0 && isfinite(sum)) ? fe * sqrt(sum / n) : 0.0;
        }
    }
    for (size_t d = 0; d < D; d++) {
        double x = signal[d], s = sigma[d];
        w->w[d] = w->wx[d] = w->xs[d] = 0.0;
        if (!isfinite(x) || !isfinite(s) || !(s > 0.0)) continue;
        double me = mu[d / (size_t)m->K];
        double ws = 1.0 / ((s / c) * (s / c) + me * me), xs = x / c;
        if (!isfinite(ws) || !isfinite(ws * xs * xs)) {
            flags |= REC_MATCH_BAD_INPUT;
            continue;
        }
        w->w[d] = ws;
        w->xs[d] = xs;
        w->wx[d] = ws * xs;
        used++;
    }
    if (used == 0) {
        no_answer(out, flags | REC_MATCH_BAD_INPUT);
        return GS_OK;
    }
    double Sxx = 0.0;
    for (size_t d = 0; d < D; d++) Sxx += w->wx[d] * w->xs[d];
    if (!isfinite(Sxx)) {
        no_answer(out, flags | REC_MATCH_BAD_INPUT);
        return GS_OK;
    }
    /* all templates: S = T_mat wx, T = T_sq w (per band with band gains) */
    double Lmax = -INFINITY;
    if (!m->bg) {
        cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)M, (int)D, 1.0, m->t, (int)D, w->wx, 1, 0.0, w->S, 1);
        cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)M, (int)D, 1.0, m->tsq, (int)D, w->w, 1, 0.0, w->T, 1);
        for (size_t j = 0; j < M; j++) {
            w->L[j] = loglik(Sxx, w->S[j], w->T[j]);
            if (w->L[j] > Lmax) Lmax = w->L[j];
        }
    } else {
        int K = m->K;
        for (int band = 0; band < m->bands; band++) {
            cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)M, K, 1.0, m->t + (size_t)band * (size_t)K,
                        (int)D, w->wx + (size_t)band * (size_t)K, 1, 0.0, w->S + (size_t)band * M, 1);
            cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)M, K, 1.0, m->tsq + (size_t)band * (size_t)K,
                        (int)D, w->w + (size_t)band * (size_t)K, 1, 0.0, w->T + (size_t)band * M, 1);
        }
        double Sv[GS_MAX_BANDS], Tv[GS_MAX_BANDS];
        for (size_t j = 0; j < M; j++) {
            sums_of(m, w, j, Sv, Tv);
            w->L[j] = loglik_n(m->nfit, Sxx, Sv, Tv);
            if (w->L[j] > Lmax) Lmax = w->L[j];
        }
    }
    /* continuous bulbs near the top: refine their peaks exactly */
    for (size_t b = 0; b < m->nb; b++) {
        w->has_peak[b] = 0;
        if (!m->cont[b]) continue;
        size_t jb = m->first[b];
        for (size_t c2 = 1; c2 < m->count[b]; c2++)
            if (w->L[m->first[b] + c2] > w->L[jb]) jb = m->first[b] + c2;
        if (!(w->L[jb] >= Lmax - CUT_REFINE)) {
            w->has_peak[b] = 1;   /* negligible: grid values only */
            w->peak_s[b] = m->shift[jb];
            w->peak_L[b] = w->L[jb];
            w->peak_sig[b] = INV_SQRT12;
            w->peak_cell[b] = jb;
            continue;
        }
        refine_peak(m, w, b, jb, Sxx);
    }
    for (size_t b = 0; b < m->nb; b++)
        if (m->cont[b] && w->peak_L[b] > Lmax) Lmax = w->peak_L[b];
    w->ncand = 0;
    for (size_t j = 0; j < M; j++)
        add_cand(m, w, j);   /* every pair counts for one light */
    decision dec;
    decide(m, w, Lmax, &dec);
    if (dec.bulb < 0) {
        no_answer(out, flags | REC_MATCH_BAD_INPUT);
        return GS_OK;
    }
    /* the fit of the best pair: exact template at its shift */
    int bb = dec.bulb;
    const double *tb;
    if (m->cont[bb]) {
        template_at(m, (size_t)bb, dec.shift, w->tt, NULL, NULL, w->acc);
        tb = w->tt;
    } else {
        tb = m->t + dec.tmpl * D;
    }
    /* one brightness (or one per band) a_f = S_f/T_f >= 0 */
    int nf = m->nfit, nfree = 0;
    size_t span = D / (size_t)nf;
    double a_sum = 0.0, chi2 = 0.0, Sv[GS_MAX_BANDS], Tv[GS_MAX_BANDS];
    for (int f = 0; f < nf; f++) {
        double S = 0.0, T = 0.0;
        for (size_t d = (size_t)f * span; d < (size_t)(f + 1) * span; d++) {
            S += w->wx[d] * tb[d];
            T += w->w[d] * tb[d] * tb[d];
        }
        Sv[f] = S;
        Tv[f] = T;
        double a = (T > 0.0 && S > 0.0) ? S / T : 0.0;
        nfree += T > 0.0;
        a_sum += a;
        for (size_t d = (size_t)f * span; d < (size_t)(f + 1) * span; d++) {
            double r = w->xs[d] - a * tb[d];
            chi2 += w->w[d] * r * r;
        }
    }
    /* a / sigma_a (one gain: a sqrt(T), sigma_a = 1/sqrt(T)) */
    double snr = nf == 1 ? (Tv[0] > 0.0 ? a_sum * sqrt(Tv[0]) : 0.0) : snr_n(nf, Sv, Tv);
    int npar = nfree + 1;   /* brightness(es) and phase */
    if (nf == 1) npar = 2;
    memset(out, 0, sizeof *out);
    out->brightness = a_sum * c;
    out->chi2 = chi2;
    out->dof = used > npar ? used - npar : 0;
    out->p_value = out->dof >= 1 ? gs_chi2_sf(chi2, out->dof) : 1.0;
    out->bulb = bb;
    out->phase_deg = report_phase(m, bb, dec.tmpl, dec.shift);
    out->phase_sigma_deg = 0.0;
    if (m->cont[bb]) {
        double sg = m->bulbs[bb].ref == GS_REF_NONE ? INV_SQRT12 : w->peak_sig[bb];
        out->phase_sigma_deg = 180.0 * sg;
    }
    out->confidence = dec.conf;
    out->bulb_confidence = dec.bulb_conf;
    out->phase_confidence = dec.phase_conf;
    out->runner_bulb = dec.runner_bulb;
    out->runner_phase_deg =
        dec.runner_bulb >= 0 ? report_phase(m, dec.runner_bulb, dec.runner_tmpl, dec.runner_shift) : 0.0;
    out->runner_confidence = dec.runner_bulb >= 0 ? dec.runner_conf : 0.0;
    if (m->bulbs[bb].ref == GS_REF_NONE) flags |= REC_MATCH_PHASE_AMBIGUOUS;
    if (out->bulb_confidence < m->o.ambiguous_conf) flags |= REC_MATCH_BULB_AMBIGUOUS;
    if (out->phase_confidence < m->o.ambiguous_conf) flags |= REC_MATCH_PHASE_AMBIGUOUS;
    if (out->dof > 0 && out->p_value < m->o.unknown_p) flags |= REC_MATCH_UNKNOWN;
    if (snr < m->o.min_snr) flags |= REC_MATCH_DIM;
    if (flags & (REC_MATCH_UNKNOWN | REC_MATCH_DIM)) {
        /* no answer; the best fit within the database moves to the runner-up fields */
        out->runner_bulb = out->bulb;
        out->runner_phase_deg = out->phase_deg;
        out->runner_confidence = out->confidence;
        out->bulb = -1;
        out->phase_deg = 0.0;
        if (m->cont[bb]) out->phase_sigma_deg = 180.0 * INV_SQRT12;
        out->confidence = out->bulb_confidence = out->phase_confidence = 0.0;
        flags |= REC_MATCH_BULB_AMBIGUOUS | REC_MATCH_PHASE_AMBIGUOUS;
    }
    out->flags = flags;
    return GS_OK;
}

gs_status rec_match_light(const rec_matcher *m, const double *signal, const double *sigma,
                          rec_match *out)
{
    if (!m || !signal || !sigma || !out)
        return gs_fail(GS_EINVAL, "Eq. 7: matcher, signal, sigma and out must not be NULL");
    work w;
    gs_status s = work_alloc(m, &w);
    if (s != GS_OK) return s;
    s = match_light_ws(m, &w, signal, sigma, out);
    work_free(&w);
    return s;
}

gs_status rec_match_catalog(const rec_matcher *m, const rec_catalog *cat, rec_match *out)
{
    if (!m || !cat) return gs_fail(GS_EINVAL, "Eq. 7: matcher and catalog must not be NULL");
    if (cat->count == 0) return GS_OK;
    if (!out || !cat->signal || !cat->sigma)
        return gs_fail(GS_EINVAL, "Eq. 7: catalog of %zu lights without signal, sigma or output",
                       cat->count);
    if (cat->bands != m->bands || cat->K != m->K)
        return gs_fail(GS_EINVAL, "Eq. 7: catalog has %d bands x K=%d, the matcher %d bands x K=%d",
                       cat->bands, cat->K, m->bands, m->K);
    work w;
    gs_status s = work_alloc(m, &w);
    if (s != GS_OK) return s;
    size_t D = (size_t)m->D;
    for (size_t i = 0; i < cat->count && s == GS_OK; i++) {
        if (cat->flags && (cat->flags[i] & REC_BLOB_NO_SIGNAL)) {
            no_answer(&out[i], REC_MATCH_BAD_INPUT);
            continue;
        }
        s = match_light_ws(m, &w, cat->signal + i * D, cat->sigma + i * D, &out[i]);
    }
    work_free(&w);
    return s;
}

/* ------------------------------------------------------------ pixels */

/* Sum of squares of n floats in double, 8 partial sums (the chain would be latency bound). */
static double sumsq_f(const float *x, size_t n)
{
    double a[8] = {0, 0, 0, 0, 0, 0, 0, 0};
    size_t i = 0;
    for (; i + 8 <= n; i += 8)
        for (int k = 0; k < 8; k++) a[k] += (double)x[i + k] * (double)x[i + k];
    for (; i < n; i++) a[0] += (double)x[i] * (double)x[i];
    return ((a[0] + a[1]) + (a[2] + a[3])) + ((a[4] + a[5]) + (a[6] + a[7]));
}

static double dot_fd(const float *x, const double *t, size_t n)
{
    double a[8] = {0, 0, 0, 0, 0, 0, 0, 0};
    size_t i = 0;
    for (; i + 8 <= n; i += 8)
        for (int k = 0; k < 8; k++) a[k] += (double)x[i + k] * t[i + k];
    for (; i < n; i++) a[0] += (double)x[i] * t[i];
    return ((a[0] + a[1]) + (a[2] + a[3])) + ((a[4] + a[5]) + (a[6] + a[7]));
}

static double dot_dd(const double *x, const double *t, size_t n)
{
    double a[8] = {0, 0, 0, 0, 0, 0, 0, 0};
    size_t i = 0;
    for (; i + 8 <= n; i += 8)
        for (int k = 0; k < 8; k++) a[k] += x[i + k] * t[i + k];
    for (; i < n; i++) a[0] += x[i] * t[i];
    return ((a[0] + a[1]) + (a[2] + a[3])) + ((a[4] + a[5]) + (a[6] + a[7]));
}

/* max_j (sh_j + rho_j xp) over n (a multiple of LANES) prefilter scores. */
static float row_bound_perp(const float *sh, const float *rho, float xp, size_t n)
{
    float mx[LANES];
    for (int q = 0; q < LANES; q++) mx[q] = -FLT_MAX;
    for (size_t j = 0; j < n; j += LANES)
        for (int q = 0; q < LANES; q++) {
            float v = sh[j + q] + rho[j + q] * xp;
            mx[q] = v > mx[q] ? v : mx[q];
        }
    float r = mx[0];
    for (int q = 1; q < LANES; q++) r = mx[q] > r ? mx[q] : r;
    return r;
}

/* For every continuous-phase bulb among the candidates, the grid cell of highest likelihood
 * (w->peak_cell, w->has_peak), where the sub-cell refinement starts. */
static void continuous_peaks(const rec_matcher *m, work *w)
{
    for (size_t b = 0; b < m->nb; b++) w->has_peak[b] = 0;
    for (size_t ci = 0; ci < w->ncand; ci++) {
        size_t j = w->cand[ci];
        size_t b = (size_t)m->tbulb[j];
        if (!m->cont[b]) continue;
        if (!w->has_peak[b] || w->L[j] > w->L[w->peak_cell[b]]) {
            w->has_peak[b] = 1;
            w->peak_cell[b] = j;
        }
    }
}

/* Pixel log likelihood (as loglik() with T = |t|^2 / sigma^2, up to a row constant) from the
 * normalised score z = x.t/(|t| sigma); Sxx = |x|^2 / sigma^2. */
static double pix_L(const rec_matcher *m, size_t j, double z, double Sxx)
{
    return -0.5 * (Sxx - z * z) - m->lognorm[j] + log_phi_fast(m, z);
}

/* The largest of n floats (n a multiple of LANES), in LANES partial maxima; NaN-safe in the
 * sense that a row of NaN scores gives NaN. */
static float row_max(const float *s, size_t n)
{
    float mx[LANES];
    for (int q = 0; q < LANES; q++) mx[q] = s[q];
    for (size_t j = LANES; j < n; j += LANES)
        for (int q = 0; q < LANES; q++) mx[q] = s[j + q] > mx[q] ? s[j + q] : mx[q];
    float r = mx[0];
    for (int q = 1; q < LANES; q++) r = mx[q] > r ? mx[q] : r;
    return r;
}

/* u[j] = max(s_j, 0)^2 hf - lnf[j] (the bound U_j in float) for n scores; returns max u. */
static float row_bounds(const float *s, const float *lnf, float hf, float *u, size_t n)
{
    float mx[LANES];
    for (int q = 0; q < LANES; q++) mx[q] = -FLT_MAX;
    for (size_t j = 0; j < n; j += LANES)
        for (int q = 0; q < LANES; q++) {
            float v = s[j + q] > 0.0f ? s[j + q] : 0.0f;
            float uu = v * v * hf - lnf[j + q];
            u[j + q] = uu;
            mx[q] = uu > mx[q] ? uu : mx[q];
        }
    float r = mx[0];
    for (int q = 1; q < LANES; q++) r = mx[q] > r ? mx[q] : r;
    return r;
}

/* A float phase in [0, 360) (a double just below 360 rounds up to 360.0f). */
static float phase_f(double deg)
{
    float f = (float)deg;
    return f >= 360.0f ? 0.0f : f;
}

/* Scratch of the pixel path. */
typedef struct {
    work w;
    float *sc;       /* [B * Mp] full scores of a block of surviving rows */
    float *xs;       /* [B * D] surviving rows, gathered */
    size_t *rows;    /* [B] their row indices */
    float *y, *sh;   /* [B * r], [B * Mp] prefilter projections and approximate scores */
    float *ub;       /* [Mp] bounds of one row */
    double *zz;      /* [M] normalised scores of one row (band path: brightness / its std) */
    double *gg;      /* [M] band path: Sxx - chi2 of the constrained fit */
    double *xd;      /* [D] one row in double */
} pix_work;

static void pix_free(pix_work *p)
{
    work_free(&p->w);
    free(p->sc);
    free(p->xs);
    free(p->rows);
    free(p->y);
    free(p->sh);
    free(p->ub);
    free(p->zz);
    free(p->gg);
    free(p->xd);
}

/* The answer for one surviving row: x row xr, its full float scores srow, noise sigma sg. */
static void pixel_row(const rec_matcher *m, pix_work *pw, const float *xr, const float *srow,
                      double sg, int *bulb_out, float *phase_out, float *conf_out)
{
    size_t D = (size_t)m->D, M = m->M, Mp = m->Mp;
    work *w = &pw->w;
    double *zz = pw->zz, *xd = pw->xd;
    float *ub = pw->ub;
    const double min_snr = m->o.min_snr;
    /* early out: every template too dim; a row with a NaN has NaN scores and stops here too */
    float smax = row_max(srow, Mp);
    if (!((double)smax >= min_snr * sg) || !(smax > 0.0f)) return;
    double ss = sumsq_f(xr, D);
    if (!isfinite(ss)) return;
    double inv = 1.0 / sg, Sxx = ss * inv * inv;
    /* bounds U_j >= L_j + Sxx/2 (log Phi <= 0) from the float scores */
    float umax = row_bounds(srow, m->lnf, (float)(0.5 * inv * inv), ub, Mp);
    size_t ju = 0;
    while (ju + 1 < M && ub[ju] != umax) ju++;
    /* error of z^2/2 from the float scores (float dot products, templates rounded to float,
     * the float bound itself): at most 8.9e-7 Sxx measured over 3e7 scores of the generated
     * DELIGHT (K = 26, RGB); FLOAT_ERR allows twice that. Above 1e-3 nats the candidates are
     * rescored in double, so the posterior does not depend on float rounding. */
    double err = FLOAT_ERR * Sxx + 1e-6;
    int exact = err > 1e-3;
    if (exact)
        for (size_t d = 0; d < D; d++) xd[d] = xr[d];
    double zu = exact ? dot_dd(xd, m->tnd + ju * D, D) * inv : srow[ju] * inv;
    /* candidates: the templates whose bound reaches within CUT_PIXEL of a template's L */
    double thr = pix_L(m, ju, zu, Sxx) + 0.5 * Sxx - CUT_PIXEL - 2.0 * err;
    w->ncand = 0;
    for (size_t j = 0; j < M; j++)
        if ((double)ub[j] + err >= thr) add_cand(m, w, j);
    if (exact && w->ncand > M / 4) {   /* many: one matrix-vector product for all templates */
        cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)M, (int)D, inv, m->tnd, (int)D, xd, 1, 0.0, zz, 1);
    } else {
        for (size_t ci = 0; ci < w->ncand; ci++) {
            size_t j = w->cand[ci];
            zz[j] = exact ? dot_dd(xd, m->tnd + j * D, D) * inv : srow[j] * inv;
        }
    }
    double Lmax = -INFINITY;
    for (size_t ci = 0; ci < w->ncand; ci++) {
        size_t j = w->cand[ci];
        w->L[j] = pix_L(m, j, zz[j], Sxx);
        if (w->L[j] > Lmax) Lmax = w->L[j];
    }
    /* continuous bulbs: refine around their best candidate cell */
    if (m->ncont) {
        continuous_peaks(m, w);
        int wset = 0;
        /* the leading continuous bulb (by its best cell) */
        size_t lead = m->nb;
        for (size_t b = 0; b < m->nb; b++)
            if (m->cont[b] && w->has_peak[b] && (lead == m->nb || w->L[w->peak_cell[b]] > w->L[w->peak_cell[lead]]))
                lead = b;
        for (size_t b = 0; b < m->nb; b++) {
            if (!m->cont[b] || !w->has_peak[b]) continue;
            size_t j0 = w->peak_cell[b], G = (size_t)m->G, c0 = (size_t)m->tcell[j0];
            size_t jm = m->first[b] + (c0 + G - 1) % G, jp = m->first[b] + (c0 + 1) % G;
            if (Sxx > 1e4 && (b == lead || w->L[j0] >= Lmax - 2.0)) {
                /* bright: a parabola through the grid is not exact enough for the chi-square
                 * test, so refine on the exact templates as for one light (weights 1) */
                if (!wset) {
                    for (size_t d = 0; d < D; d++) {
                        w->xs[d] = w->wx[d] = xr[d] * inv;
                        w->w[d] = 1.0;
                    }
                    wset = 1;
                }
                size_t js[3] = {jm, j0, jp};
                for (int q = 0; q < 3; q++) {
                    w->S[js[q]] = dot_fd(xr, m->t + js[q] * D, D) * inv;
                    w->T[js[q]] = exp(2.0 * m->lognorm[js[q]]);
                }
                refine_peak(m, w, b, j0, Sxx);
                zz[j0] = w->peak_z[b];
                if (w->peak_L[b] > Lmax) Lmax = w->peak_L[b];
                continue;
            }
            double zm = exact ? dot_fd(xr, m->tnd + jm * D, D) * inv : srow[jm] * inv;
            double zp = exact ? dot_fd(xr, m->tnd + jp * D, D) * inv : srow[jp] * inv;
            double q0 = zz[j0] > 0 ? zz[j0] * zz[j0] : 0, qm = zm > 0 ? zm * zm : 0,
                   qp = zp > 0 ? zp * zp : 0;
            double cell = 1.0 / m->G, den = qm - 2.0 * q0 + qp, u = 0.0, qpk = q0, sig = INV_SQRT12;
            if (den < 0.0) {
                u = 0.5 * cell * (qm - qp) / den;
                if (u < -cell) u = -cell;
                if (u > cell) u = cell;
                qpk = q0 - (qp - qm) * (qp - qm) / (8.0 * den);
                sig = cell * sqrt(-2.0 / den);
                if (!(sig < INV_SQRT12)) sig = INV_SQRT12;
            }
            double zpk = sqrt(qpk > q0 ? qpk : q0);
            w->peak_s[b] = wrap01((double)c0 / m->G + u);
            w->peak_L[b] = pix_L(m, j0, zpk, Sxx);
            if (w->peak_L[b] < w->L[j0]) w->peak_L[b] = w->L[j0];
            w->peak_sig[b] = sig;
            if (w->peak_L[b] > Lmax) Lmax = w->peak_L[b];
            zz[j0] = zpk;   /* the z of the refined fit, for the dim and unknown tests */
        }
    }
    decision dec;
    decide(m, w, Lmax, &dec);
    if (dec.bulb < 0) return;
    double zb = zz[dec.tmpl];
    if (!(zb >= min_snr)) return;                                    /* dim */
    if (Sxx - zb * zb > m->chi2_thr) return;                          /* unknown */
    *bulb_out = dec.bulb;
    if (phase_out) *phase_out = phase_f(report_phase(m, dec.bulb, dec.tmpl, dec.shift));
    if (conf_out) *conf_out = (float)dec.conf;
}

/* Band path of one template: p[b] = x_b . u_jb (u_jb the unit template of band b), var[b] the
 * band's noise variance (the row's sigma^2 plus model error). Returns the log likelihood up to a
 * row constant; *gain = Sxx - chi2 of the constrained fit, *snr = brightness / its std. */
static double band_terms(const rec_matcher *m, size_t j, const double *p, const double *var,
                         double Sxx, double *gain, double *snr)
{
    int nb = m->bands;
    const double *bn = m->bnorm + j * (size_t)nb;
    if (m->bg) {
        double L = 0.0, zz = 0.0, g = 0.0, num = 0.0, den = 0.0;
        for (int b = 0; b < nb; b++) {
            double z = p[b] * (1.0 / sqrt(var[b]));
            L += log_phi_fast(m, z);
            zz += z * z;
            g += z > 0.0 ? z * z : 0.0;
            num += p[b] / bn[b];                 /* a_b = x_b . t_b / |t_b|^2 */
            den += var[b] / (bn[b] * bn[b]);     /* var(a_b) */
        }
        *gain = g;
        *snr = num / sqrt(den);
        return L - 0.5 * (Sxx - zz) - m->blog[j];
    }
    double S = 0.0, T = 0.0;
    for (int b = 0; b < nb; b++) {
        S += p[b] * bn[b] / var[b];
        T += bn[b] * bn[b] / var[b];
    }
    double z = S / sqrt(T);
    *gain = z > 0.0 ? z * z : 0.0;
    *snr = z;
    return -0.5 * (Sxx - z * z) - 0.5 * log(T) + log_phi_fast(m, z);
}

/* rec_match_pixels for matchers with per-band brightness or model error (m->bandpath): srow
 * holds the row's float scores per band (bands blocks of Mp). The same decision as pixel_row,
 * with the band model of match_light_ws (per-band sigma^2 = sg^2 + (model_error mu_b)^2). */
static void pixel_row_band(const rec_matcher *m, pix_work *pw, const float *xr, const float *srow,
                           double sg, int *bulb_out, float *phase_out, float *conf_out)
{
    size_t D = (size_t)m->D, M = m->M, Mp = m->Mp, K = (size_t)m->K;
    int nb = m->bands;
    work *w = &pw->w;
    double *zz = pw->zz, *gg = pw->gg, *xd = pw->xd;
    float *ub = pw->ub;
    const double min_snr = m->o.min_snr, fe = m->o.model_error;
    double var[GS_MAX_BANDS], inv[GS_MAX_BANDS], Sxx = 0.0;
    for (int b = 0; b < nb; b++) {
        const float *xb = xr + (size_t)b * K;
        double ssb = sumsq_f(xb, K), ms = ssb / (double)K - sg * sg;   /* RMS signal level^2 */
        double mu2 = ms > 0.0 ? fe * fe * ms : 0.0;
        var[b] = sg * sg + mu2;
        inv[b] = 1.0 / sqrt(var[b]);
        Sxx += ssb / var[b];
    }
    if (!isfinite(Sxx)) return;
    /* the dim test and upper bounds U_j >= L_j + Sxx/2 from the float scores */
    double smax = -INFINITY;
    float umax = -FLT_MAX;
    size_t ju = 0;
    double p[GS_MAX_BANDS];
    if (m->bg) {
        /* in float, 16 lanes (vectorised): the bound and snr^2 sign-kept (num |num| / den) */
        float fi[GS_MAX_BANDS], fv[GS_MAX_BANDS];
        for (int b = 0; b < nb; b++) {
            fi[b] = (float)inv[b];
            fv[b] = (float)var[b];
        }
        float mxs[LANES];
        for (int q = 0; q < LANES; q++) mxs[q] = -FLT_MAX;
        for (size_t j0 = 0; j0 < Mp; j0 += LANES) {
            float num[LANES], den[LANES], uu[LANES];
            for (int q = 0; q < LANES; q++) {
                num[q] = 0.0f;
                den[q] = 0.0f;
                uu[q] = -m->blnf[j0 + (size_t)q];
            }
            for (int b = 0; b < nb; b++) {
                const float *sb = srow + (size_t)b * Mp + j0, *ib = m->bib + (size_t)b * Mp + j0,
                            *ib2 = m->bib2 + (size_t)b * Mp + j0;
                for (int q = 0; q < LANES; q++) {
                    float z = sb[q] * fi[b], zp = z > 0.0f ? z : 0.0f;
                    uu[q] += 0.5f * zp * zp;
                    num[q] += sb[q] * ib[q];
                    den[q] += fv[b] * ib2[q];
                }
            }
            for (int q = 0; q < LANES; q++) {
                ub[j0 + (size_t)q] = uu[q];
                float s2 = num[q] * (num[q] > 0.0f ? num[q] : -num[q]) / den[q];
                mxs[q] = s2 > mxs[q] ? s2 : mxs[q];
            }
        }
        float s2max = mxs[0];
        for (int q = 1; q < LANES; q++) s2max = mxs[q] > s2max ? mxs[q] : s2max;
        smax = s2max > 0.0f ? sqrt((double)s2max) * (1.0 + 1e-5) : 0.0;   /* float slack */
        umax = row_max(ub, Mp);
        while (ju + 1 < M && ub[ju] != umax) ju++;
    } else {
        /* one gain with per-band sigmas: exact terms for every template (no bound needed) */
        for (size_t j = 0; j < M; j++) {
            for (int b = 0; b < nb; b++) p[b] = srow[(size_t)b * Mp + j];
            double g, sn;
            double L = band_terms(m, j, p, var, Sxx, &g, &sn);
            ub[j] = (float)(L + 0.5 * Sxx + 1e-3 * (1.0 + fabs(L + 0.5 * Sxx)));
            if (ub[j] > umax) {
                umax = ub[j];
                ju = j;
            }
            if (sn > smax) smax = sn;
        }
    }
    if (!(smax >= min_snr) || !(smax > 0.0)) return;   /* every template too dim (or NaN) */
    double err = FLOAT_ERR * Sxx + 1e-6;
    int exact = err > 1e-3;
    if (exact)
        for (size_t d = 0; d < D; d++) xd[d] = xr[d];
    if (exact)
        for (int b = 0; b < nb; b++) p[b] = dot_dd(xd + (size_t)b * K, m->tbn + ju * D + (size_t)b * K, K);
    else
        for (int b = 0; b < nb; b++) p[b] = srow[(size_t)b * Mp + ju];
    double g0, s0;
    double thr = band_terms(m, ju, p, var, Sxx, &g0, &s0) + 0.5 * Sxx - CUT_PIXEL - 2.0 * err;
    w->ncand = 0;
    for (size_t j = 0; j < M; j++)
        if ((double)ub[j] + err >= thr) add_cand(m, w, j);
    double Lmax = -INFINITY;
    for (size_t ci = 0; ci < w->ncand; ci++) {
        size_t j = w->cand[ci];
        if (exact)
            for (int b = 0; b < nb; b++) p[b] = dot_dd(xd + (size_t)b * K, m->tbn + j * D + (size_t)b * K, K);
        else
            for (int b = 0; b < nb; b++) p[b] = srow[(size_t)b * Mp + j];
        w->L[j] = band_terms(m, j, p, var, Sxx, &gg[j], &zz[j]);
        if (w->L[j] > Lmax) Lmax = w->L[j];
    }
    if (m->ncont) {
        continuous_peaks(m, w);
        size_t lead = m->nb;
        for (size_t b = 0; b < m->nb; b++)
            if (m->cont[b] && w->has_peak[b] && (lead == m->nb || w->L[w->peak_cell[b]] > w->L[w->peak_cell[lead]]))
                lead = b;
        int wset = 0;
        for (size_t b = 0; b < m->nb; b++) {
            if (!m->cont[b] || !w->has_peak[b]) continue;
            size_t j0 = w->peak_cell[b], G = (size_t)m->G, c0 = (size_t)m->tcell[j0];
            size_t jm = m->first[b] + (c0 + G - 1) % G, jp = m->first[b] + (c0 + 1) % G;
            if (Sxx > 1e4 && (b == lead || w->L[j0] >= Lmax - 2.0)) {
                /* bright: Newton on the exact templates, as for one light. Band gains: each band
                 * scaled to unit noise (the scale is absorbed by a_b, and T_b = |t_b|^2 matches
                 * band_terms); one gain: weights 1/var_b */
                if (!wset) {
                    for (size_t d = 0; d < D; d++) {
                        double iv = inv[d / K];
                        if (m->bg) {
                            w->xs[d] = w->wx[d] = xr[d] * iv;
                            w->w[d] = 1.0;
                        } else {
                            w->xs[d] = xr[d];
                            w->w[d] = iv * iv;
                            w->wx[d] = w->w[d] * xr[d];
                        }
                    }
                    wset = 1;
                }
                size_t js[3] = {jm, j0, jp};
                for (int q = 0; q < 3; q++) {
                    const double *tj = m->t + js[q] * D;
                    if (m->bg) {
                        for (int band = 0; band < nb; band++) {
                            w->S[(size_t)band * M + js[q]] = dot_fd(xr + (size_t)band * K, tj + (size_t)band * K, K) * inv[band];
                            double bnv = m->bnorm[js[q] * (size_t)nb + (size_t)band];
                            w->T[(size_t)band * M + js[q]] = bnv * bnv;
                        }
                    } else {
                        double S = 0.0, T = 0.0;
                        for (int band = 0; band < nb; band++) {
                            double bnv = m->bnorm[js[q] * (size_t)nb + (size_t)band];
                            S += dot_fd(xr + (size_t)band * K, tj + (size_t)band * K, K) / var[band];
                            T += bnv * bnv / var[band];
                        }
                        w->S[js[q]] = S;
                        w->T[js[q]] = T;
                    }
                }
                refine_peak(m, w, b, j0, Sxx);
                zz[j0] = w->peak_z[b];
                gg[j0] = w->peak_gain[b];
                if (w->peak_L[b] > Lmax) Lmax = w->peak_L[b];
                continue;
            }
            /* parabola through the grid's fit gains */
            double gm, gp, sm, sp;
            for (int q = 0; q < 2; q++) {
                size_t jj = q ? jp : jm;
                if (exact)
                    for (int band = 0; band < nb; band++)
                        p[band] = dot_dd(xd + (size_t)band * K, m->tbn + jj * D + (size_t)band * K, K);
                else
                    for (int band = 0; band < nb; band++) p[band] = srow[(size_t)band * Mp + jj];
                band_terms(m, jj, p, var, Sxx, q ? &gp : &gm, q ? &sp : &sm);
            }
            double q0 = gg[j0], cell = 1.0 / m->G, den = gm - 2.0 * q0 + gp, u = 0.0, qpk = q0,
                   sig = INV_SQRT12;
            if (den < 0.0) {
                u = 0.5 * cell * (gm - gp) / den;
                if (u < -cell) u = -cell;
                if (u > cell) u = cell;
                qpk = q0 - (gp - gm) * (gp - gm) / (8.0 * den);
                sig = cell * sqrt(-2.0 / den);
                if (!(sig < INV_SQRT12)) sig = INV_SQRT12;
            }
            if (qpk < q0) qpk = q0;
            w->peak_s[b] = wrap01((double)c0 / m->G + u);
            w->peak_L[b] = w->L[j0] + 0.5 * (qpk - q0);
            w->peak_sig[b] = sig;
            if (w->peak_L[b] > Lmax) Lmax = w->peak_L[b];
            gg[j0] = qpk;
        }
    }
    decision dec;
    decide(m, w, Lmax, &dec);
    if (dec.bulb < 0) return;
    if (!(zz[dec.tmpl] >= min_snr)) return;                          /* dim */
    if (Sxx - gg[dec.tmpl] > m->chi2_thr) return;                    /* unknown */
    *bulb_out = dec.bulb;
    if (phase_out) *phase_out = phase_f(report_phase(m, dec.bulb, dec.tmpl, dec.shift));
    if (conf_out) *conf_out = (float)dec.conf;
}

gs_status rec_match_pixels(const rec_matcher *m, const float *x, const float *noise_sigma,
                           size_t P, int *bulb, float *phase_deg, float *confidence)
{
    if (!m || (P > 0 && (!x || !noise_sigma || !bulb)))
        return gs_fail(GS_EINVAL, "Eq. 7 pixels: matcher, x, noise_sigma and bulb must not be NULL");
    if (P == 0) return GS_OK;
    size_t D = (size_t)m->D, Mp = m->Mp, R = (size_t)m->pr;
    size_t B = P < PIX_BLOCK ? P : PIX_BLOCK;
    pix_work pw;
    memset(&pw, 0, sizeof pw);
    gs_status st = work_alloc(m, &pw.w);
    if (st != GS_OK) return st;
    size_t nsc = m->bandpath ? (size_t)m->bands : 1;   /* score blocks: one per band */
    pw.sc = malloc(sizeof *pw.sc * B * Mp * nsc);
    pw.xs = malloc(sizeof *pw.xs * B * D);
    pw.rows = malloc(sizeof *pw.rows * B);
    pw.y = malloc(sizeof *pw.y * B * (R ? R : 1));
    pw.sh = malloc(sizeof *pw.sh * B * Mp);
    pw.ub = malloc(sizeof *pw.ub * Mp);
    pw.zz = malloc(sizeof *pw.zz * m->M);
    pw.gg = malloc(sizeof *pw.gg * m->M);
    pw.xd = malloc(sizeof *pw.xd * D);
    if (!pw.sc || !pw.xs || !pw.rows || !pw.y || !pw.sh || !pw.ub || !pw.zz || !pw.gg || !pw.xd) {
        pix_free(&pw);
        return gs_fail(GS_ENOMEM, "Eq. 7 pixels: cannot allocate a %zu x %zu score block", B, Mp);
    }
    const double min_snr = m->o.min_snr;
    for (size_t r0 = 0; r0 < P; r0 += B) {
        size_t nr = P - r0 < B ? P - r0 : B;
        const float *xb = x + r0 * D;
        for (size_t i = 0; i < nr; i++) {
            bulb[r0 + i] = -1;
            if (phase_deg) phase_deg[r0 + i] = 0.0f;
            if (confidence) confidence[r0 + i] = 0.0f;
        }
        /* Prefilter (when the templates are close to an R-dimensional subspace E): with
         * y = E x, x_perp = x - E^T y and t_j = E^T c_j + r_j, |r_j| = rho_j,
         *   x . t_j <= c_j . y + rho_j |x_perp|,
         * so a row whose bound stays below min_snr sigma is dim for every template (exactly as
         * the full test would find) and needs no full scores. */
        size_t ns = 0;
        if (R) {
            cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)nr, (int)R, (int)D, 1.0f, xb,
                        (int)D, m->pe, (int)D, 0.0f, pw.y, (int)R);
            cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)nr, (int)Mp, (int)R, 1.0f, pw.y,
                        (int)R, m->pc, (int)R, 0.0f, pw.sh, (int)Mp);
        }
        for (size_t i = 0; i < nr; i++) {
            double sg = noise_sigma[r0 + i];
            if (!(sg > 0.0) || !isfinite(sg)) continue;
            if (R) {
                const float *xr = xb + i * D;
                double ss = sumsq_f(xr, D), yy = 0.0;
                for (size_t q = 0; q < R; q++) yy += (double)pw.y[i * R + q] * pw.y[i * R + q];
                /* |x_perp| from |x|^2 - |y|^2, plus the rounding of both (an upper bound) */
                float xp = (float)sqrt((ss > yy ? ss - yy : 0.0) + 1e-6 * ss);
                float bound = row_bound_perp(pw.sh + i * Mp, m->prho, xp, Mp);
                /* slack for the float scores of the prefilter */
                if (!((double)bound + 1e-5 * sqrt(ss) >= min_snr * sg) || !isfinite(ss)) continue;
            }
            pw.rows[ns++] = r0 + i;
        }
        if (ns == 0) continue;
        const float *xs = xb;
        if (ns < nr) {
            for (size_t k = 0; k < ns; k++)
                memcpy(pw.xs + k * D, x + pw.rows[k] * D, sizeof *pw.xs * D);
            xs = pw.xs;
        }
        if (m->bandpath) {
            /* per-band scores x_b . u_jb: one SGEMM of K columns per band, scores of row k at
             * sc[k * bands * Mp + b * Mp + j] */
            size_t K = (size_t)m->K, ld = nsc * Mp;
            for (size_t band = 0; band < nsc; band++)
                cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)ns, (int)Mp, (int)K, 1.0f,
                            xs + band * K, (int)D, m->tbnf + band * K, (int)D, 0.0f, pw.sc + band * Mp,
                            (int)ld);
            for (size_t k = 0; k < ns; k++) {
                size_t r = pw.rows[k];
                pixel_row_band(m, &pw, xs + k * D, pw.sc + k * ld, noise_sigma[r], &bulb[r],
                               phase_deg ? &phase_deg[r] : NULL, confidence ? &confidence[r] : NULL);
            }
            continue;
        }
        cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)ns, (int)Mp, (int)D, 1.0f, xs,
                    (int)D, m->tn, (int)D, 0.0f, pw.sc, (int)Mp);
        for (size_t k = 0; k < ns; k++) {
            size_t r = pw.rows[k];
            pixel_row(m, &pw, xs + k * D, pw.sc + k * Mp, noise_sigma[r], &bulb[r],
                      phase_deg ? &phase_deg[r] : NULL, confidence ? &confidence[r] : NULL);
        }
    }
    pix_free(&pw);
    return GS_OK;
}

/* ------------------------------------------------------------ bench */

gs_status rec_bench_eq7(const rec_matcher *m, size_t pixels, double lit_fraction, double snr,
                        unsigned long seed, rec_eq7_bench *out)
{
    if (!m || !out || pixels == 0 || !(lit_fraction >= 0.0 && lit_fraction <= 1.0) || !(snr > 0.0))
        return gs_fail(GS_EINVAL, "Eq. 7 bench: expected a matcher, pixels > 0, lit_fraction in "
                       "[0, 1], snr > 0 and an output");
    memset(out, 0, sizeof *out);
    size_t D = (size_t)m->D;
    float *x = malloc(sizeof *x * pixels * D);
    float *sg = malloc(sizeof *sg * pixels);
    int *truth = malloc(sizeof *truth * pixels);
    int *bulb = malloc(sizeof *bulb * pixels);
    float *ph = malloc(sizeof *ph * pixels), *cf = malloc(sizeof *cf * pixels);
    if (!x || !sg || !truth || !bulb || !ph || !cf) {
        free(x);
        free(sg);
        free(truth);
        free(bulb);
        free(ph);
        free(cf);
        return gs_fail(GS_ENOMEM, "Eq. 7 bench: cannot allocate %zu pixels", pixels);
    }
    uint64_t rs = seed;
    size_t lit = 0;
    for (size_t r = 0; r < pixels; r++) {
        sg[r] = 1.0f;
        truth[r] = -1;
        int on = gs_splitmix_uniform(&rs) < lit_fraction;
        size_t j = (size_t)(gs_splitmix_uniform(&rs) * (double)m->M) % m->M;
        /* brightness so the mean sample is snr noise sigmas */
        /* a template's mean sample is 1/bands: a = snr * bands gives a mean sample of snr */
        double a = on ? snr * m->bands : 0.0;
        for (size_t d = 0; d < D; d++)
            x[r * D + d] = (float)(a * m->t[j * D + d] + gs_splitmix_normal(&rs));
        if (on) {
            truth[r] = (int)j;
            lit++;
        }
    }
    struct timespec t0, t1, c0, c1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &c0);
    gs_status s = rec_match_pixels(m, x, sg, pixels, bulb, ph, cf);
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &c1);
    clock_gettime(CLOCK_MONOTONIC, &t1);
    double sec = (double)(t1.tv_sec - t0.tv_sec) + 1e-9 * (double)(t1.tv_nsec - t0.tv_nsec);
    double cpu = (double)(c1.tv_sec - c0.tv_sec) + 1e-9 * (double)(c1.tv_nsec - c0.tv_nsec);
    size_t right = 0;
    for (size_t r = 0; r < pixels && s == GS_OK; r++) {
        if (truth[r] < 0) continue;
        size_t j = (size_t)truth[r];
        int phase_ok = m->bulbs[m->tbulb[j]].ref == GS_REF_NONE ||
                       circ_dist(gs_phase_to_shift(ph[r]), m->shift[j]) < (m->np ? 1e-6 : 0.02);
        if (bulb[r] == m->tbulb[j] && phase_ok) right++;
    }
    out->pixels = pixels;
    out->lit = lit;
    out->templates = m->M;
    out->prefilter_dim = m->pr;
    out->values_per_pixel = (int)D;
    out->seconds = sec;
    out->pixels_per_s = sec > 0 ? (double)pixels / sec : 0.0;
    out->cpu_seconds = cpu;
    out->pixels_per_cpu_s = cpu > 0 ? (double)pixels / cpu : 0.0;
    out->lit_accuracy = lit ? (double)right / (double)lit : 0.0;
    free(x);
    free(sg);
    free(truth);
    free(bulb);
    free(ph);
    free(cf);
    return s;
}
