/* blobs_fit.c - step 9 of the blob extraction (recognize.h, rec_blobs_extract): the
 * multi-source PSF fit over the K frames, crowded-field photometry (DAOPHOT's PSF fitting,
 * Stetson 1987) with time as the extra dimension. docs/recognition.md, "Detection at
 * kilometre range", has the equations; in short, for one component with fit pixels p and
 * samples d = (band b, frame k):
 *   D_pd = sum_s P(p; x_s) F_sd + noise,  w_pb = 1 / (the pixel's variance averaged over k),
 * P a Gaussian PSF integrated over the pixel (its sigma free, shared by the component's sources,
 * from the capture's, within a factor FIT_SIGMA_RANGE), positions x_s free and
 * each source's per-frame fluxes F_sd free (its own template, scale and chromaticity). For
 * fixed positions F is linear least squares, per band A_b = sum_p w_pb P P^T,
 * F_.d = A_b^-1 sum_p w_pb P D_pd, and chi2 = sum w D^2 - sum_d F_.d . (sum_p w P D_pd); the
 * positions and sigma are found by Levenberg-Marquardt on the variable projection (Golub &
 * Pereyra 1973: the gradient and Gauss-Newton matrix of chi2 with F at its optimum). Sources are added one at a time at
 * the footprint pixel where a PSF explains the most residual (the matched filter on the
 * residual), while the chi-square drop is significant (Wilson-Hilferty z over BK + 2 degrees
 * of freedom above deblend_sigma), every source's flux is above FIT_SNR sigmas, and the new
 * source's fluxes are not a combination of the others' (span_z above deblend_sigma). A
 * component that is one spatial profile times one signal (rank1_z, PSF-free) is left as step 5
 * made it; so is one whose fit keeps a single source. A crowded component is fitted as groups
 * (DAOPHOT's): its lights within FIT_GROUP_SIGMA PSF sigmas of each other, each group over its
 * own lights' apertures. */
#include "recognize/internal.h"

#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define FIT_MAX_SOURCES 6
#define FIT_MAX_PX 400           /* components with more fit pixels are left as they are */
#define FIT_SNR 5.0              /* every source's flux over its noise */
#define FIT_MIN_SEP_SIGMA 0.5    /* sources closer than this many PSF sigmas are one */
/* Lights of one component closer than this many PSF sigmas (directly or through a chain) are
 * fitted together; farther groups apart (DAOPHOT's groups: a crowded component of many lights is
 * many small fits, each over its own lights' apertures). */
#define FIT_GROUP_SIGMA 6.0
/* One signal split in space (spatial_split): the fainter source's least flux share, the least
 * separation in PSF sigmas. */
#define SPLIT_MIN_SHARE 0.1
#define SPLIT_MIN_SEP_SIGMA 1.5
/* ... tried only where one source leaves a misfit above this z (a chance of 2 % for one light) */
#define SPLIT_SCREEN_Z 2.0
#define FIT_LM_ITER 40           /* Levenberg-Marquardt steps at most */
#define FIT_LM_LAMBDA_MAX 1e8    /* ... and its damping at most */
#define FIT_TOL_PX 0.01          /* it stops when a step moves no coordinate more than this */
#define FIT_CHI2_TOL 1e-3        /* ... or lowers chi2 by less than this */
#define RANK1_ITER 3              /* alternating least-squares rounds of the gate */
#define FIT_SIGMA_RANGE 2.0      /* each component's PSF sigma within this factor of the capture's */
/* The PSF model's relative error (DAOPHOT's "profile error"): each pixel's variance in the fit
 * gains (FIT_PROFILE_ERR x its mean level)^2, and so does each flux in span_z. */
#define FIT_PROFILE_ERR 0.03

typedef struct {
    const rec_blob_state *s;
    int n, B, K, BK;
    int *x, *y;           /* [n] fit pixels */
    double *D, *V;        /* [n * BK] value - background, its variance */
    double *w;            /* [n * B] */
    double wdd;           /* sum w D^2 */
    double lo_x, lo_y, hi_x, hi_y;   /* positions allowed (the footprint's box, +1 px) */
    double *P;            /* [FIT_MAX_SOURCES * n] */
    double *F;            /* [FIT_MAX_SOURCES * BK] fluxes of the last evaluation */
    double *Ainv;         /* [B * S * S] of the last evaluation */
    double *num;          /* [K] scratch */
    double *Dt, *wP;      /* [BK * n] D by sample, [FIT_MAX_SOURCES * n] w_pb P */
    int bx0, by0, bw, bh; /* the fit pixels' bounding box */
    double *gx, *gy;      /* [3 (bw + 1)], [3 (bh + 1)] scratch: the PSF's 1-D shares, derivatives */
    double *mean;         /* [3 n B] scratch of spatial_split */
    double *dP, *perp;    /* [6 FIT_MAX_SOURCES n] scratch of fit_gradient (3 N n), fit_moment_shift */
    double *wb, *wPb, *wperp;   /* [n], [FIT_MAX_SOURCES n], [6 FIT_MAX_SOURCES n] theirs too */
} fit_data;

/* The shares of a pixel-integrated 1-D Gaussian (centre c, sigma) in pixels lo .. lo + n - 1:
 * 0.5 (erf((x + 0.5 - c) / (sqrt 2 sigma)) - erf((x - 0.5 - c) / (sqrt 2 sigma))), each edge
 * once. The 2-D share is the product (rec_psf_share). */
static void psf_1d(int lo, int n, double c, double sigma, double *g)
{
    const double k = 1.0 / (sqrt(2.0) * sigma);
    double prev = erf((lo - 0.5 - c) * k);
    for (int i = 0; i < n; i++) {
        double e = erf((lo + i + 0.5 - c) * k);
        g[i] = 0.5 * (e - prev);
        prev = e;
    }
}

/* In-place inverse of the n x n symmetric positive matrix a (Gauss-Jordan, pivoting on the
 * diagonal); 0 when singular. */
static int small_inverse(double *a, int n)
{
    double inv[FIT_MAX_SOURCES * FIT_MAX_SOURCES];
    for (int i = 0; i < n * n; i++) inv[i] = 0;
    for (int i = 0; i < n; i++) inv[i * n + i] = 1;
    for (int c = 0; c < n; c++) {
        double piv = a[c * n + c];
        if (!(piv > 1e-300)) return 0;
        for (int j = 0; j < n; j++) {
            a[c * n + j] /= piv;
            inv[c * n + j] /= piv;
        }
        for (int r = 0; r < n; r++) {
            if (r == c) continue;
            double f = a[r * n + c];
            if (f == 0) continue;
            for (int j = 0; j < n; j++) {
                a[r * n + j] -= f * a[c * n + j];
                inv[r * n + j] -= f * inv[c * n + j];
            }
        }
    }
    memcpy(a, inv, sizeof(double) * (size_t)(n * n));
    return 1;
}

/* chi2 of N sources at pos[2 N] with the PSF sigma pos[2 N]; leaves P, F and Ainv. HUGE_VAL
 * outside the allowed box (positions; sigma within FIT_SIGMA_RANGE of the capture's) or when the
 * normal matrix is singular. */
static double fit_eval(fit_data *f, int N, const double *pos)
{
    const int n = f->n, B = f->B, K = f->K, BK = f->BK;
    const double sigma = pos[2 * N], s0 = f->s->psf_sigma;
    if (!(sigma >= s0 / FIT_SIGMA_RANGE && sigma <= s0 * FIT_SIGMA_RANGE)) return HUGE_VAL;
    for (int q = 0; q < N; q++)
        if (!(pos[2 * q] >= f->lo_x && pos[2 * q] <= f->hi_x && pos[2 * q + 1] >= f->lo_y &&
              pos[2 * q + 1] <= f->hi_y))
            return HUGE_VAL;
    for (int q = 0; q < N; q++) {
        psf_1d(f->bx0, f->bw, pos[2 * q], sigma, f->gx);
        psf_1d(f->by0, f->bh, pos[2 * q + 1], sigma, f->gy);
        for (int p = 0; p < n; p++) f->P[q * n + p] = f->gx[f->x[p] - f->bx0] * f->gy[f->y[p] - f->by0];
    }
    double chi2 = f->wdd;
    for (int b = 0; b < B; b++) {
        double *A = f->Ainv + (size_t)b * N * N;
        /* w P per source; A = (w P) P^T; each sample's right-hand side as dot products with
         * WD's rows */
        for (int q = 0; q < N; q++)
            for (int p = 0; p < n; p++) f->wP[q * n + p] = f->w[p * B + b] * f->P[q * n + p];
        for (int q = 0; q < N; q++)
            for (int t = q; t < N; t++) A[q * N + t] = A[t * N + q] = gs_dot(f->wP + q * n, f->P + t * n, n);
        if (!small_inverse(A, N)) return HUGE_VAL;
        for (int k = 0; k < K; k++) {
            const int d = b * K + k;
            const double *Dd = f->Dt + (size_t)d * n;
            double r[FIT_MAX_SOURCES];
            for (int q = 0; q < N; q++) r[q] = gs_dot(f->wP + q * n, Dd, n);
            for (int q = 0; q < N; q++) {
                double v = 0;
                for (int t = 0; t < N; t++) v += A[q * N + t] * r[t];
                f->F[q * BK + d] = v;
                chi2 -= v * r[q];
            }
        }
    }
    return chi2;
}

/* psf_1d and its derivatives by the centre c (dc) and by sigma (ds): with u the pixel edge's
 * offset from c and kappa = 1 / (sqrt 2 sigma), d erf(u kappa) / dc = -2 kappa exp(-u^2 kappa^2)
 * / sqrt(pi) and d erf(u kappa) / dsigma = -2 u kappa exp(-u^2 kappa^2) / (sqrt(pi) sigma). */
static void psf_1d_d(int lo, int n, double c, double sigma, double *g, double *dc, double *ds)
{
    const double k = 1.0 / (sqrt(2.0) * sigma), a = 2.0 / sqrt(M_PI);
    double u = lo - 0.5 - c, e0 = erf(u * k), x0 = exp(-u * u * k * k);
    double c0 = -a * k * x0, s0 = -a * u * k * x0 / sigma;
    for (int i = 0; i < n; i++) {
        u = lo + i + 0.5 - c;
        const double e = erf(u * k), x = exp(-u * u * k * k), ce = -a * k * x, se = -a * u * k * x / sigma;
        g[i] = 0.5 * (e - e0);
        dc[i] = 0.5 * (ce - c0);
        ds[i] = 0.5 * (se - s0);
        e0 = e, c0 = ce, s0 = se;
    }
}

/* For band b of the fit that fit_eval last evaluated (its P, F and Ainv), with S templates T
 * (S x n, template c belonging to source c / 3): f->perp and f->wperp the templates with the
 * part the fluxes absorb removed (per band, the weighted projection on the span of the P_q:
 * perp_c = T_c - P^T A^-1 (P W T_c)) and that times w_pb; f->wP the N sources' w_pb h_q(p),
 * h_q = sum_k R_p,bk F_q,bk for the residual R; FF_qt = sum_k F_q,bk F_t,bk. */
static void band_projection(fit_data *f, int N, int b, const double *T, int S, double *FF)
{
    const int n = f->n, K = f->K, BK = f->BK;
    const double *A = f->Ainv + (size_t)b * N * N;
    double *wb = f->wb, *wPb = f->wPb, *perp = f->perp, *wperp = f->wperp, *wh = f->wP;
    for (int p = 0; p < n; p++) wb[p] = f->w[p * f->B + b];
    for (int q = 0; q < N; q++)
        for (int p = 0; p < n; p++) wPb[q * n + p] = wb[p] * f->P[q * n + p];
    for (int c = 0; c < S; c++) {
        double pr[FIT_MAX_SOURCES];
        for (int q = 0; q < N; q++) pr[q] = gs_dot(wPb + q * n, T + c * n, n);
        double *pc = perp + c * n;
        memcpy(pc, T + c * n, sizeof(double) * (size_t)n);
        for (int q = 0; q < N; q++) {
            double v = 0;
            for (int t = 0; t < N; t++) v += A[q * N + t] * pr[t];
            for (int p = 0; p < n; p++) pc[p] -= v * f->P[q * n + p];
        }
        for (int p = 0; p < n; p++) wperp[c * n + p] = wb[p] * pc[p];
    }
    for (int q = 0; q < N; q++)
        for (int t = q; t < N; t++)
            FF[q * N + t] = FF[t * N + q] = gs_dot(f->F + q * BK + b * K, f->F + t * BK + b * K, K);
    /* h_q = sum_k (D_pk - sum_t P_t(p) F_tk) F_qk = sum_k D_pk F_qk - sum_t P_t(p) FF_tq */
    for (int q = 0; q < N; q++) {
        double *h = wh + q * n;
        for (int p = 0; p < n; p++) h[p] = gs_dot(f->D + (size_t)p * BK + b * K, f->F + q * BK + b * K, K);
        for (int t = 0; t < N; t++)
            for (int p = 0; p < n; p++) h[p] -= FF[t * N + q] * f->P[t * n + p];
        for (int p = 0; p < n; p++) h[p] *= wb[p];
    }
}

/* The derivatives of the N sources' P_q at pos (sigma pos[2 N]) over the fit pixels:
 * dP[(3 q + j) n + p], j = 0, 1, 2 for d/dx_q, d/dy_q, d/dsigma. */
static void derivative_templates(fit_data *f, int N, const double *pos, double *dP)
{
    const int n = f->n;
    const double sigma = pos[2 * N];
    double *gx = f->gx, *gy = f->gy, *dx = f->gx + f->bw + 1, *dy = f->gy + f->bh + 1;
    double *sx = dx + f->bw + 1, *sy = dy + f->bh + 1;
    for (int q = 0; q < N; q++) {
        psf_1d_d(f->bx0, f->bw, pos[2 * q], sigma, gx, dx, sx);
        psf_1d_d(f->by0, f->bh, pos[2 * q + 1], sigma, gy, dy, sy);
        for (int p = 0; p < n; p++) {
            const int ix = f->x[p] - f->bx0, iy = f->y[p] - f->by0;
            dP[(3 * q) * n + p] = dx[ix] * gy[iy];
            dP[(3 * q + 1) * n + p] = gx[ix] * dy[iy];
            dP[(3 * q + 2) * n + p] = sx[ix] * gy[iy] + gx[ix] * sy[iy];
        }
    }
}

/* The gradient g and the Gauss-Newton matrix H of chi2 over the m = 2 N + 1 parameters (x_q,
 * y_q, then sigma) at the point fit_eval last evaluated (its P, F and Ainv): the variable
 * projection of Golub & Pereyra (1973), Kaufman's (1975) form. With M_pd = sum_q P_q(p) F_qd
 * and F at its optimum, d chi2 / d theta_i = -2 sum_pd w_pb r_pd dM_pd / d theta_i (r = D - M);
 * H_ij = 2 sum_pd w_pb (dM / d theta_i)_perp (dM / d theta_j)_perp, where _perp removes the part
 * that the fluxes absorb (per band, the weighted projection on the span of the P_q). Each
 * dM / d theta_i is a sum over sources of dP_q(p) F_qd, so its projection is that of the dP_q:
 * the sums over the K frames separate. */
static void fit_gradient(fit_data *f, int N, const double *pos, double *g, double *H)
{
    const int n = f->n, B = f->B, m = 2 * N + 1, S = 3 * N;
    double *dP = f->dP, *perp = f->perp;   /* [3 N n]: d/dx_q, d/dy_q, d/dsigma of P_q */
    double *wh = f->wP;                     /* [N n] scratch (fit_eval's, set again there) */
    derivative_templates(f, N, pos, dP);
    for (int i = 0; i < m; i++) {
        g[i] = 0;
        for (int j = 0; j < m; j++) H[i * m + j] = 0;
    }
    /* the parameter of derivative column c = 3 q + j: x_q, y_q or sigma */
#define PARAM_OF(c) ((c) % 3 == 2 ? 2 * N : 2 * ((c) / 3) + (c) % 3)
    for (int b = 0; b < B; b++) {
        double FF[FIT_MAX_SOURCES * FIT_MAX_SOURCES];
        band_projection(f, N, b, dP, S, FF);
        for (int c = 0; c < S; c++) g[PARAM_OF(c)] -= 2 * gs_dot(dP + c * n, wh + (c / 3) * n, n);
        for (int c = 0; c < S; c++)
            for (int e = c; e < S; e++) {
                const double a = 2 * FF[(c / 3) * N + e / 3] * gs_dot(f->wperp + c * n, perp + e * n, n);
                const int i = PARAM_OF(c), j = PARAM_OF(e);
                H[i * m + j] += a;
                if (c != e) H[j * m + i] += a;
            }
    }
#undef PARAM_OF
}

/* The positions and sigma from pos (overwritten with the best) that minimise chi2:
 * Levenberg-Marquardt (Marquardt 1963) on fit_gradient's g and H, each step
 * (H + lambda diag H) delta = -g kept only when chi2 falls (outside fit_eval's box it is
 * HUGE_VAL: the step is refused and lambda grows). Stops when a step lowers chi2 by less than
 * FIT_CHI2_TOL or moves no coordinate by more than FIT_TOL_PX, or after FIT_LM_ITER steps. Its
 * chi2; P, F and Ainv are those of the best. */
static double fit_positions(fit_data *f, int N, double *pos)
{
    enum { MAXD = 2 * FIT_MAX_SOURCES + 1 };
    const int m = 2 * N + 1;
    double chi2 = fit_eval(f, N, pos), lambda = 1e-3;
    if (!isfinite(chi2)) return chi2;
    double g[MAXD], H[MAXD * MAXD], Hl[MAXD * MAXD], step[MAXD], trial[MAXD];
    int fresh = 1;   /* 1: P, F and Ainv are those of pos */
    fit_gradient(f, N, pos, g, H);
    for (int it = 0; it < FIT_LM_ITER; it++) {
        memcpy(Hl, H, sizeof(double) * (size_t)(m * m));
        for (int i = 0; i < m; i++) {
            Hl[i * m + i] *= 1 + lambda;
            step[i] = -g[i];
        }
        /* H is symmetric: its row-major storage is its column-major one (no copy by LAPACKE) */
        if (LAPACKE_dposv(LAPACK_COL_MAJOR, 'L', m, 1, Hl, m, step, m) != 0) {
            if ((lambda *= 10) > FIT_LM_LAMBDA_MAX) break;
            continue;
        }
        double move = 0;
        for (int i = 0; i < m; i++) {
            trial[i] = pos[i] + step[i];
            move = fmax(move, fabs(step[i]));
        }
        const double c = fit_eval(f, N, trial);
        fresh = 0;
        if (!(c < chi2)) {
            if ((lambda *= 10) > FIT_LM_LAMBDA_MAX || move < FIT_TOL_PX) break;
            continue;
        }
        memcpy(pos, trial, sizeof(double) * (size_t)m);
        const double drop = chi2 - c;
        chi2 = c;
        fresh = 1;
        lambda = fmax(lambda / 10, 1e-9);
        if (drop < FIT_CHI2_TOL || move < FIT_TOL_PX) break;
        fit_gradient(f, N, pos, g, H);
    }
    return fresh ? chi2 : fit_eval(f, N, pos);
}

/* Wilson-Hilferty: chi2 with nu degrees of freedom as a Gaussian z. */
static double wh_z(double chi2, double nu)
{
    if (!(chi2 > 0)) return -INFINITY;
    double a = 2.0 / (9.0 * nu);
    return (cbrt(chi2 / nu) - (1 - a)) / sqrt(a);
}

/* Source q's flux over its noise (sums over the BK samples; noise from A_b^-1). */
static double source_snr(const fit_data *f, int N, int q)
{
    double sum = 0, var = 0;
    for (int b = 0; b < f->B; b++)
        for (int k = 0; k < f->K; k++) {
            sum += f->F[q * f->BK + b * f->K + k];
            var += f->Ainv[(size_t)b * N * N + (size_t)q * N + q];
        }
    return var > 0 ? sum / sqrt(var) : 0;
}

/* How far, in Gaussian sigmas, the newest source's fluxes (q = N - 1) are from the span of the
 * others': per band, the least-squares combination sum_t c_bt F_t,b. of the other sources over
 * the K frames, then chi2 = sum_bk (F_q,bk - sum_t c_bt F_t,bk)^2 / (var F_q,bk + (FIT_PROFILE_ERR
 * F_q,bk)^2) over B (K - N + 1) degrees of freedom (Wilson-Hilferty). A PSF that is not quite
 * the model leaves residuals that are such a combination (sum_t (P_true - P_model)_t F_t), so a
 * source that only absorbs them is no light. */
static double span_z(const fit_data *f, int N)
{
    const int B = f->B, K = f->K, BK = f->BK, q = N - 1, m = N - 1;
    double chi2 = 0;
    for (int b = 0; b < B; b++) {
        double G[FIT_MAX_SOURCES * FIT_MAX_SOURCES], h[FIT_MAX_SOURCES], c[FIT_MAX_SOURCES];
        for (int i = 0; i < m; i++) {
            h[i] = 0;
            for (int j = 0; j < m; j++) {
                double g = 0;
                for (int k = 0; k < K; k++) g += f->F[i * BK + b * K + k] * f->F[j * BK + b * K + k];
                G[i * m + j] = g;
            }
            for (int k = 0; k < K; k++) h[i] += f->F[i * BK + b * K + k] * f->F[q * BK + b * K + k];
        }
        if (!small_inverse(G, m)) return INFINITY;
        for (int i = 0; i < m; i++) {
            c[i] = 0;
            for (int j = 0; j < m; j++) c[i] += G[i * m + j] * h[j];
        }
        const double vq = f->Ainv[(size_t)b * N * N + (size_t)q * N + q];
        for (int k = 0; k < K; k++) {
            double fq = f->F[q * BK + b * K + k], r = fq, v = vq + FIT_PROFILE_ERR * FIT_PROFILE_ERR * fq * fq;
            for (int i = 0; i < m; i++) {
                r -= c[i] * f->F[i * BK + b * K + k];
                v += c[i] * c[i] * f->Ainv[(size_t)b * N * N + (size_t)i * N + i];
            }
            chi2 += v > 0 ? r * r / v : 0;
        }
    }
    return wh_z(chi2, (double)B * (K - m));
}

/* The newest source (q = N - 1) of the fit at pos is a light of its own in space: at least
 * SPLIT_MIN_SEP_SIGMA PSF sigmas from every other source, and its flux (summed over the samples)
 * at least SPLIT_MIN_SHARE of each one's and each one's at least SPLIT_MIN_SHARE of its own
 * (a halo or a PSF that is not quite the model leaves far less). */
static int spatially_distinct(const fit_data *f, int N, const double *pos)
{
    const int q = N - 1;
    double fq = 0;
    for (int d = 0; d < f->BK; d++) fq += f->F[q * f->BK + d];
    for (int t = 0; t < q; t++) {
        double ft = 0;
        for (int d = 0; d < f->BK; d++) ft += f->F[t * f->BK + d];
        if (!(hypot(pos[2 * q] - pos[2 * t], pos[2 * q + 1] - pos[2 * t + 1]) >= SPLIT_MIN_SEP_SIGMA * pos[2 * N]) ||
            !(fmin(fq, ft) >= SPLIT_MIN_SHARE * fmax(fq, ft)))
            return 0;
    }
    return 1;
}

/* The N-source fit is acceptable: every source bright enough, none too close, and the newest
 * one's signal outside the span of the others' (span_z) or the newest a light of its own in
 * space. */
static int fit_ok(const fit_data *f, int N, const double *pos, double deblend_sigma)
{
    const double sigma = pos[2 * N];
    for (int q = 0; q < N; q++)
        if (!(source_snr(f, N, q) > FIT_SNR)) return 0;
    for (int q = 0; q < N; q++)
        for (int t = q + 1; t < N; t++)
            if (hypot(pos[2 * q] - pos[2 * t], pos[2 * q + 1] - pos[2 * t + 1]) < FIT_MIN_SEP_SIGMA * sigma) return 0;
    return span_z(f, N) > deblend_sigma || spatially_distinct(f, N, pos);
}

/* The matched filter of a PSF centred on pixel (cx, cy) (its 1-D shares in f->gx, rr pixels each
 * side) on the residual R: sum_bk (sum_p w_pb P_p R_p,bk)^2 / sum_p w_pb P_p^2. */
static double candidate_value(const fit_data *f, const double *R, int cx, int cy, int rr)
{
    const int n = f->n, B = f->B, K = f->K, BK = f->BK;
    double v = 0;
    for (int b = 0; b < B; b++) {
        double *num = f->num, den = 0;
        for (int k = 0; k < K; k++) num[k] = 0;
        for (int p = 0; p < n; p++) {
            int dx = f->x[p] - cx, dy = f->y[p] - cy;
            if (abs(dx) > rr || abs(dy) > rr) continue;
            double P = f->gx[dx + rr] * f->gx[dy + rr], wp = f->w[p * B + b] * P;
            den += wp * P;
            for (int k = 0; k < K; k++) num[k] += wp * R[(size_t)p * BK + b * K + k];
        }
        if (den > 0)
            for (int k = 0; k < K; k++) v += num[k] * num[k] / den;
    }
    return v;
}

typedef struct {
    double bound;
    int i;
} candidate;

static int cmp_candidate(const void *a, const void *b)
{
    const candidate *x = a, *y = b;
    if (x->bound != y->bound) return x->bound < y->bound ? 1 : -1;   /* largest bound first */
    return (x->i > y->i) - (x->i < y->i);
}

/* The footprint pixel (of fp[0..nfp)) where one more PSF explains the most of the residual of
 * the N-source fit at pos (F from that fit): max over c of
 * sum_d (sum_p w P_c R_pd)^2 / sum_p w P_c^2, the first in fp's order among equals. -1 when none
 * is far enough from the sources. By Cauchy-Schwarz a candidate's value is at most the
 * residual's energy sum_bk w_pb R_p,bk^2 summed over its window: candidates are tried in the
 * order of that bound and the search stops where the bound falls below the best value (the
 * same pixel as trying them all, which psf_fit_exhaustive does, and so does a search whose list
 * cannot be allocated). */
static int best_new_source(fit_data *f, int N, const double *pos, const int *fp, int nfp, double *R)
{
    const int n = f->n, B = f->B, K = f->K, BK = f->BK;
    const double sigma = pos[2 * N], reach = ceil(3 * sigma) + 0.5;
    const int W = f->s->W;
    double *e = f->wb;   /* [n] each pixel's residual energy (fit_gradient's scratch) */
    for (int p = 0; p < n; p++) {
        e[p] = 0;
        for (int d = 0; d < BK; d++) {
            double m = 0;
            for (int q = 0; q < N; q++) m += f->P[q * n + p] * f->F[q * BK + d];
            const double r = f->D[(size_t)p * BK + d] - m;
            R[(size_t)p * BK + d] = r;
            e[p] += f->w[p * B + d / K] * r * r;
        }
    }
    /* a PSF centred on a pixel: the same 1-D shares at every candidate */
    const int rr = (int)reach, span = 2 * rr + 1;
    psf_1d(-rr, span, 0.0, sigma, f->gx);
    /* NULL (exhaustive, or no memory for the list): all tried in order */
    candidate *c = f->s->o->psf_fit_exhaustive ? NULL : malloc(sizeof *c * (size_t)(nfp > 0 ? nfp : 1));
    int nc = 0, best = -1;
    double best_v = 0;
    for (int i = 0; i < nfp; i++) {
        int cx = fp[i] % W, cy = fp[i] / W, near = 0;
        for (int q = 0; q < N && !near; q++)
            near = hypot(cx - pos[2 * q], cy - pos[2 * q + 1]) < FIT_MIN_SEP_SIGMA * sigma;
        if (near) continue;
        if (!c) {
            const double v = candidate_value(f, R, cx, cy, rr);
            if (v > best_v) {
                best_v = v;
                best = i;
            }
            continue;
        }
        double E = 0;
        for (int p = 0; p < n; p++)
            if (abs(f->x[p] - cx) <= rr && abs(f->y[p] - cy) <= rr) E += e[p];
        c[nc++] = (candidate){E * (1 + 1e-9) + 1e-300, i};   /* rounding slack: a bound in floating point */
    }
    if (!c) return best;
    qsort(c, (size_t)nc, sizeof *c, cmp_candidate);
    for (int t = 0; t < nc && !(c[t].bound < best_v); t++) {
        const int i = c[t].i;
        const double v = candidate_value(f, R, fp[i] % W, fp[i] / W, rr);
        if (v > best_v || (v == best_v && best >= 0 && i < best)) {
            best_v = v;
            best = i;
        }
    }
    free(c);
    return best;
}

/* The gate: how far (Wilson-Hilferty z) the component is from one signal times one spatial
 * profile, D_p,bk = u_pb v_bk per band with u and v free (any PSF: a single light passes), by
 * alternating least squares; weights 1 / (V_pd + (FIT_PROFILE_ERR mean_k D_pb)^2). */
static double rank1_z(const fit_data *f, double *u, double *v)
{
    const int n = f->n, B = f->B, K = f->K, BK = f->BK;
    double chi2 = 0, dof = 0;
    for (int b = 0; b < B; b++) {
        for (int k = 0; k < K; k++) {
            v[k] = 0;
            for (int p = 0; p < n; p++) v[k] += f->D[(size_t)p * BK + b * K + k];
        }
        for (int it = 0; it < RANK1_ITER; it++) {
            for (int p = 0; p < n; p++) {
                double num = 0, den = 0, wp = f->w[p * B + b];
                for (int k = 0; k < K; k++) {
                    num += wp * f->D[(size_t)p * BK + b * K + k] * v[k];
                    den += wp * v[k] * v[k];
                }
                u[p] = den > 0 ? num / den : 0;
            }
            double den = 0;
            for (int k = 0; k < K; k++) v[k] = 0;
            for (int p = 0; p < n; p++) {   /* pixel by pixel: D's rows in memory order */
                const double wu = f->w[p * B + b] * u[p], *Dp = f->D + (size_t)p * BK + b * K;
                den += wu * u[p];
                for (int k = 0; k < K; k++) v[k] += wu * Dp[k];
            }
            for (int k = 0; k < K; k++) v[k] = den > 0 ? v[k] / den : 0;
        }
        for (int p = 0; p < n; p++)
            for (int k = 0; k < K; k++) {
                double r = f->D[(size_t)p * BK + b * K + k] - u[p] * v[k];
                chi2 += f->w[p * B + b] * r * r;
            }
        dof += (double)n * K - n - K + 1;
    }
    return dof > 0 ? wh_z(chi2, dof) : -INFINITY;
}

/* One light of the fit. */
typedef struct {
    int comp;             /* component label */
    double x, y, psf;     /* position, the component's fitted PSF sigma */
    double cov[3];        /* the position's covariance (xx, xy, yy), px^2 (fit_position_cov) */
    double mom[3];        /* its light's second moment in excess of the fit's PSF (fit_excess_moments) */
    double *sig, *sgm;    /* BK each (one allocation) */
} fit_light;

/* The fitted lights of every component, and per component whether it was replaced. */
typedef struct {
    fit_light *v;
    size_t n, cap;
} fit_list;

static gs_status push_light(fit_list *L, int comp, double x, double y, double psf, const double cov[3],
                            const double mom[3], int BK, double **sig)
{
    if (L->n == L->cap) {
        size_t nc = L->cap ? 2 * L->cap : 64;
        fit_light *nv = realloc(L->v, nc * sizeof *nv);
        if (!nv) return gs_fail(GS_ENOMEM, "blobs: cannot hold %zu fitted lights", nc);
        L->v = nv;
        L->cap = nc;
    }
    double *m = malloc(sizeof(double) * (size_t)BK * 2);
    if (!m) return gs_fail(GS_ENOMEM, "blobs: cannot hold a fitted light");
    L->v[L->n++] = (fit_light){comp, x, y, psf, {cov[0], cov[1], cov[2]}, {mom[0], mom[1], mom[2]}, m, m + BK};
    *sig = m;
    return GS_OK;
}

/* The second derivative of psf_1d's shares by the centre c: with u the pixel edge's offset from
 * c, d^2 erf(u kappa) / dc^2 = -4 kappa^3 u exp(-u^2 kappa^2) / sqrt(pi). */
static void psf_1d_d2(int lo, int n, double c, double sigma, double *d2)
{
    const double k = 1.0 / (sqrt(2.0) * sigma), a = -4.0 * k * k * k / sqrt(M_PI);
    double u = lo - 0.5 - c, h0 = a * u * exp(-u * u * k * k);
    for (int i = 0; i < n; i++) {
        u = lo + i + 0.5 - c;
        const double h = a * u * exp(-u * u * k * k);
        d2[i] = 0.5 * (h - h0);
        h0 = h;
    }
}

/* The N sources' second-moment templates at pos (sigma pos[2 N]) over the fit pixels:
 * T[(3 q + j) n + p] = (1/2) d_x^2 P_q, d_x d_y P_q (it carries 2 M_xy), (1/2) d_y^2 P_q. */
static void moment_templates(fit_data *f, int N, const double *pos, double *T)
{
    const int n = f->n;
    const double sigma = pos[2 * N];
    double *gx = f->gx, *gy = f->gy, *dx = f->gx + f->bw + 1, *dy = f->gy + f->bh + 1;
    double *sx = dx + f->bw + 1, *sy = dy + f->bh + 1;
    for (int q = 0; q < N; q++) {
        psf_1d_d(f->bx0, f->bw, pos[2 * q], sigma, gx, dx, sx);
        psf_1d_d(f->by0, f->bh, pos[2 * q + 1], sigma, gy, dy, sy);
        psf_1d_d2(f->bx0, f->bw, pos[2 * q], sigma, sx);
        psf_1d_d2(f->by0, f->bh, pos[2 * q + 1], sigma, sy);
        for (int p = 0; p < n; p++) {
            const int ix = f->x[p] - f->bx0, iy = f->y[p] - f->by0;
            T[(3 * q) * n + p] = 0.5 * sx[ix] * gy[iy];
            T[(3 * q + 1) * n + p] = dx[ix] * dy[iy];   /* 2 M_xy (1/2) d_x d_y P */
            T[(3 * q + 2) * n + p] = 0.5 * gx[ix] * sy[iy];
        }
    }
}

/* Each source's light in excess of one point: a source that is two or more unresolved lights
 * (centroid c, shares w_i at offsets delta_i, sum w_i delta_i = 0) images as
 * sum_i w_i P(p; c + delta_i) = P(p; c) + (1/2) sum_ab M_ab d_a d_b P(p; c) to second order,
 * M = sum_i w_i delta_i delta_i^T the intensity-weighted second moment of the lights about the
 * centroid. M of every source by linear least squares on the fit's residual (the templates
 * F_qd (1/2) d_a d_b P_q, each with the part that the fluxes absorb removed, as fit_gradient
 * does); mh[3 q ..] = (xx, xy, yy). A light of the blend is at offset delta_j from the centroid,
 * and for the brightest delta_j delta_j^T <= M. 0 when singular. */
static int fit_excess_moments(fit_data *f, int N, const double *pos, double *mh)
{
    enum { MAXM = 3 * FIT_MAX_SOURCES };
    const int n = f->n, B = f->B, S = 3 * N;
    double *T = f->dP, *perp = f->perp, *wh = f->wP;
    moment_templates(f, N, pos, T);
    double G[MAXM * MAXM], r[MAXM];
    for (int i = 0; i < S; i++) {
        r[i] = 0;
        for (int j = 0; j < S; j++) G[i * S + j] = 0;
    }
    for (int b = 0; b < B; b++) {
        double FF[FIT_MAX_SOURCES * FIT_MAX_SOURCES];
        band_projection(f, N, b, T, S, FF);
        for (int c = 0; c < S; c++) {
            r[c] += gs_dot(perp + c * n, wh + (c / 3) * n, n);
            for (int e = 0; e < S; e++) G[c * S + e] += FF[(c / 3) * N + e / 3] * gs_dot(f->wperp + c * n, perp + e * n, n);
        }
    }
    if (LAPACKE_dpotrf(LAPACK_COL_MAJOR, 'L', S, G, S) != 0 || LAPACKE_dpotri(LAPACK_COL_MAJOR, 'L', S, G, S) != 0)
        return 0;
    for (int c = 0; c < S; c++)
        for (int e = c + 1; e < S; e++) G[e * S + c] = G[c * S + e];   /* (lower: G[col * S + row]) */
    for (int c = 0; c < S; c++) {
        double v = 0;
        for (int e = 0; e < S; e++) v += G[c * S + e] * r[e];
        mh[c] = c % 3 == 1 ? 0.5 * v : v;   /* the xy template carries 2 M_xy */
    }
    return 1;
}

/* The positions' pull by the light the fit does not model: the Gauss-Newton step, from the fit
 * at pos (fit_eval evaluated there), of the model whose sources each have their second moment
 * free as well (fit_excess_moments' templates F_qd (1/2) d_a d_b P_q; the PSF sigma not, as the
 * moments' traces span it: dP / dsigma = sigma (d_xx + d_yy) P), the fluxes profiled out as in
 * fit_gradient. By Frisch-Waugh-Lovell the step is the positions' change when the residual's
 * moment structure (an unresolved blend's width, of the source or of a neighbour) is fitted
 * jointly with them: to first order the bias that light puts on the fitted positions. Each
 * moment has the prior precision 1 / s^4 (s^2 = sigma^2 + 1/12, the pixel-integrated PSF's
 * variance; lights of a blend lie within 2 s, so M <= s^2), which keeps the step finite where
 * sources nearly coincide. shift[2 q ..] = (dx, dy); 0 when its normal matrix is singular. */
static int fit_moment_shift(fit_data *f, int N, const double *pos, double *shift)
{
    enum { MAXZ = 5 * FIT_MAX_SOURCES };
    const int n = f->n, B = f->B, S = 3 * N, Z = 2 * N + S;
    const double s2 = pos[2 * N] * pos[2 * N] + 1.0 / 12.0;
    double *X = f->dP;   /* [2 S n]: derivative_templates (sigma's unused), moment_templates */
    derivative_templates(f, N, pos, X);
    moment_templates(f, N, pos, X + (size_t)S * n);
    /* parameter of template c: x_q, y_q (c < S, c % 3 < 2), then the 3 N moments */
#define PARAM_OF(c) ((c) < S ? 2 * ((c) / 3) + (c) % 3 : 2 * N + (c) - S)
#define USED(c) ((c) >= S || (c) % 3 != 2)
    double G[MAXZ * MAXZ], r[MAXZ];
    for (int i = 0; i < Z; i++) {
        r[i] = 0;
        for (int j = 0; j < Z; j++) G[i * Z + j] = 0;
    }
    for (int b = 0; b < B; b++) {
        double FF[FIT_MAX_SOURCES * FIT_MAX_SOURCES];
        band_projection(f, N, b, X, 2 * S, FF);
        for (int c = 0; c < 2 * S; c++) {
            if (!USED(c)) continue;
            const int sc = (c % S) / 3;
            r[PARAM_OF(c)] += gs_dot(f->perp + c * n, f->wP + sc * n, n);
            for (int e = 0; e < 2 * S; e++)
                if (USED(e))
                    G[PARAM_OF(c) * Z + PARAM_OF(e)] +=
                        FF[sc * N + (e % S) / 3] * gs_dot(f->wperp + c * n, f->perp + e * n, n);
        }
    }
#undef USED
#undef PARAM_OF
    for (int c = 0; c < S; c++)   /* the prior; the xy template's coefficient is 2 M_xy */
        G[(2 * N + c) * Z + 2 * N + c] += 1.0 / ((c % 3 == 1 ? 4.0 : 1.0) * s2 * s2);
    /* G is symmetric: its row-major storage is its column-major one */
    if (LAPACKE_dposv(LAPACK_COL_MAJOR, 'L', Z, 1, G, Z, r, Z) != 0) return 0;
    memcpy(shift, r, sizeof(double) * (size_t)(2 * N));
    return 1;
}

/* The covariance of the N sources' positions of the fit at pos (fit_eval evaluated there, its
 * chi2 given): the inverse Fisher matrix of the least-squares fit, 2 H^-1 with H fit_gradient's
 * Gauss-Newton matrix of chi2 (the fluxes and the PSF sigma profiled out: H is over the
 * positions and sigma, each derivative with the part the fluxes absorb removed), scaled by
 * chi2 / dof when the fit is worse than its noise model (Birge's ratio: a misfit, e.g. an
 * undetected neighbour, widens it). Two sources closer than about 2 PSF sigmas trade flux for
 * position, and this grows far beyond one light's sqrt(2) s / SNR. cov[3 q ..] = (xx, xy, yy)
 * of source q; NaN when H is singular. */
static void fit_position_cov(fit_data *f, int N, const double *pos, double chi2, double *cov)
{
    enum { MAXD = 2 * FIT_MAX_SOURCES + 1 };
    const int m = 2 * N + 1;
    double g[MAXD], H[MAXD * MAXD];
    fit_gradient(f, N, pos, g, H);
    const double dof = (double)f->n * f->BK - (double)N * f->BK - m;
    const double scale = 2.0 * (dof > 0 && chi2 > dof ? chi2 / dof : 1.0);
    /* H is symmetric: its row-major storage is its column-major one */
    int ok = LAPACKE_dpotrf(LAPACK_COL_MAJOR, 'L', m, H, m) == 0 && LAPACKE_dpotri(LAPACK_COL_MAJOR, 'L', m, H, m) == 0;
    for (int q = 0; q < N; q++) {
        const int i = 2 * q;   /* the lower triangle (column-major): H[col * m + row], row >= col */
        cov[3 * q] = ok ? scale * H[i * m + i] : NAN;
        cov[3 * q + 1] = ok ? scale * H[i * m + i + 1] : NAN;
        cov[3 * q + 2] = ok ? scale * H[(i + 1) * m + i + 1] : NAN;
    }
}

/* The N sources of the fit at pos as lights of L: each source's fluxes and their noise under
 * the fit's own noise model (its weights): var F_qd = sum_p (sum_t Ainv_qt w_pb P_tp)^2 (V_pd +
 * (FIT_PROFILE_ERR sum_t P_tp F_td)^2), the camera noise and the PSF model's error at the
 * pixel's modelled level. */
static gs_status emit_fit(fit_data *f, int comp, int N, const double *pos, fit_list *L)
{
    const int n = f->n, B = f->B, K = f->K, BK = f->BK;
    double cov[3 * FIT_MAX_SOURCES], mom[3 * FIT_MAX_SOURCES], sh[2 * FIT_MAX_SOURCES];
    fit_position_cov(f, N, pos, fit_eval(f, N, pos), cov);
    if (!fit_excess_moments(f, N, pos, mom))
        for (int i = 0; i < 3 * N; i++) mom[i] = NAN;
    /* the unmodelled light's pull: its size, not its sign (the moments are noisy), into the
     * covariance */
    else if (fit_moment_shift(f, N, pos, sh))
        for (int q = 0; q < N; q++) {
            cov[3 * q] += sh[2 * q] * sh[2 * q];
            cov[3 * q + 1] += sh[2 * q] * sh[2 * q + 1];
            cov[3 * q + 2] += sh[2 * q + 1] * sh[2 * q + 1];
        }
    for (int q = 0; q < N; q++) {
        double *sig = NULL;
        gs_status st = push_light(L, comp, pos[2 * q], pos[2 * q + 1], pos[2 * N], cov + 3 * q, mom + 3 * q, BK, &sig);
        if (st != GS_OK) return st;
        double *sgm = sig + BK;
        for (int b = 0; b < B; b++) {
            const double *A = f->Ainv + (size_t)b * N * N;
            for (int k = 0; k < K; k++) {
                const int d = b * K + k;
                double v = 0;
                for (int p = 0; p < n; p++) {
                    double g = 0, mod = 0;
                    for (int t = 0; t < N; t++) {
                        g += A[q * N + t] * f->P[t * n + p];
                        mod += f->P[t * n + p] * f->F[t * BK + d];
                    }
                    g *= f->w[p * B + b];
                    double pe = FIT_PROFILE_ERR * mod;
                    v += g * g * (f->V[(size_t)p * BK + d] + pe * pe);
                }
                sig[d] = f->F[q * BK + d];
                sgm[d] = sqrt(v);
            }
        }
    }
    return GS_OK;
}

/* The positive part of the symmetric 2 x 2 matrix m = (xx, xy, yy), in place: its eigenvalues
 * l1 >= l2, with l2 < 0 < l1 it is l1 (m - l2 I) / (l1 - l2) (the projection on l1's
 * eigenvector), with l1 <= 0 zero. */
static void positive_part(double m[3])
{
    const double t = 0.5 * (m[0] + m[2]), d = hypot(0.5 * (m[0] - m[2]), m[1]), l1 = t + d, l2 = t - d;
    if (l2 >= 0.0) return;
    if (!(l1 > 0.0)) {
        m[0] = m[1] = m[2] = 0.0;
        return;
    }
    const double k = l1 / (l1 - l2);
    m[0] = k * (m[0] - l2);
    m[1] = k * m[1];
    m[2] = k * (m[2] - l2);
}

/* The position covariance of each fitted light (rec_catalog.pos_cov_px2): the fit's own
 * (fit_position_cov, with the unmodelled light's pull: emit_fit) plus the positive part of its
 * light's second moment in excess of one light's PSF, M + (sigma^2 - sigma_1^2) I: the fit's
 * shared PSF sigma widens for a component whose sources are unresolved blends, so the excess is
 * taken against sigma_1, the median of the capture's fitted sigmas (most components hold single
 * lights). NaN where either is unknown. */
static gs_status fitted_position_cov(const fit_list *L, double *cov)
{
    double *sg = malloc(sizeof(double) * (L->n ? L->n : 1));
    if (!sg) return gs_fail(GS_ENOMEM, "blobs: cannot hold %zu fitted sigmas", L->n);
    for (size_t i = 0; i < L->n; i++) sg[i] = L->v[i].psf;
    const double s1 = gs_median_d(sg, L->n);
    free(sg);
    for (size_t i = 0; i < L->n; i++) {
        const fit_light *fl = &L->v[i];
        const double ds = fl->psf * fl->psf - s1 * s1;
        double m[3] = {fl->mom[0] + ds, fl->mom[1], fl->mom[2] + ds};
        positive_part(m);
        for (int c = 0; c < 3; c++) cov[3 * i + c] = fl->cov[c] + m[c];
    }
    return GS_OK;
}

/* One signal (the rank-1 gate passed) but maybe two lights: neighbours of the same bulb and
 * phase that step 5 took for one peak can only be told apart in space. The fit on the mean over
 * the frames (enough for the positions when every pixel carries the same signal): one source,
 * and where it leaves a misfit (z above SPLIT_SCREEN_Z) two. Two are kept when the chi2 drop is
 * significant (Wilson-Hilferty z over B + 2 degrees of freedom above deblend_sigma), both
 * sources are above FIT_SNR and the second is spatially_distinct; then the two sources'
 * per-frame fluxes from the full fit at those positions. Components with saturated pixels are
 * not split (their fit pixels are a ring). */
static gs_status spatial_split(fit_data *f, int comp, const int *fp, int nfp, const double *start, double *R,
                               fit_list *L, int *replaced)
{
    double *mean = f->mean;
    const int n = f->n, B = f->B, K = f->K, BK = f->BK, W = f->s->W;
    fit_data g = *f;
    g.K = 1;
    g.BK = B;
    g.D = mean;
    g.w = mean + (size_t)n * B;
    g.Dt = mean + 2 * (size_t)n * B;
    g.wdd = 0;
    for (int p = 0; p < n; p++)
        for (int b = 0; b < B; b++) {
            double dm = 0, vm = 0;
            for (int k = 0; k < K; k++) {
                dm += f->D[(size_t)p * BK + b * K + k];
                vm += f->V[(size_t)p * BK + b * K + k];
            }
            dm /= K;
            vm /= K;
            double v = vm / K + (dm > 0 ? FIT_PROFILE_ERR * FIT_PROFILE_ERR * dm * dm : 0.0);
            g.D[p * B + b] = g.Dt[(size_t)b * n + p] = dm;
            g.w[p * B + b] = v > 0 && isfinite(v) ? 1 / v : 0;
            g.wdd += g.w[p * B + b] * dm * dm;
        }
    double one[3] = {start[0], start[1], f->s->psf_sigma}, two[5];
    double c1 = fit_positions(&g, 1, one);
    /* one source fits, or none can be fitted (singular: its fluxes are not all set) */
    if (!(c1 < HUGE_VAL) || !(wh_z(c1, (double)n * B - B - 3) > SPLIT_SCREEN_Z)) return GS_OK;
    int i = best_new_source(&g, 1, one, fp, nfp, R);
    if (i < 0) return GS_OK;
    two[0] = one[0];
    two[1] = one[1];
    two[2] = fp[i] % W;
    two[3] = fp[i] / W;
    two[4] = one[2];
    double c2 = fit_positions(&g, 2, two);
    if (!(wh_z(c1 - c2, B + 2) > f->s->o->deblend_sigma)) return GS_OK;
    for (int q = 0; q < 2; q++)
        if (!(source_snr(&g, 2, q) > FIT_SNR)) return GS_OK;
    if (!spatially_distinct(&g, 2, two)) return GS_OK;
    *replaced = 1;
    return emit_fit(f, comp, 2, two, L);
}

/* Fit one component: its aperture pixels ap[0..nap), footprint pixels fp[0..nfp), the
 * positions start[2 N0] of its lights (brightest first). Appends its lights to L when the fit
 * holds two or more. */
static gs_status fit_component(fit_data *f, int comp, const int *ap, int nap, const int *fp, int nfp,
                               const double *start, int N0, double *R, fit_list *L, int *replaced)
{
    const rec_blob_state *s = f->s;
    const int B = f->B, K = f->K, BK = f->BK, W = s->W;
    *replaced = 0;
    int n = 0, nsat = 0;
    f->wdd = 0;
    for (int a = 0; a < nap; a++) {
        int p = ap[a];
        if (s->sat[p]) {
            nsat++;
            continue;
        }
        int x = p % W, y = p / W;
        double *V = f->V + (size_t)n * BK, *D = f->D + (size_t)n * BK;
        rec_blob_pixel_var(s, (size_t)p, V, D);   /* D: the levels, then minus the background */
        int node[4];
        double nw[4];
        const int nn = rec_mesh_weights(&s->mesh, x, y, node, nw), nodes = s->mesh.nx * s->mesh.ny;
        for (int k = 0; k < K; k++)
            for (int b = 0; b < B; b++) {
                const double *g = s->fval + ((size_t)k * B + (size_t)b) * (size_t)nodes;
                double bg = 0;
                for (int t = 0; t < nn; t++) bg += nw[t] * g[node[t]];
                D[b * K + k] -= bg;
            }
        for (int b = 0; b < B; b++) {
            double vm = 0, dm = 0;
            for (int k = 0; k < K; k++) {
                vm += V[b * K + k];
                dm += D[b * K + k];
            }
            vm /= K;
            dm /= K;
            if (dm > 0) vm += FIT_PROFILE_ERR * FIT_PROFILE_ERR * dm * dm;
            f->w[n * B + b] = vm > 0 && isfinite(vm) ? 1 / vm : 0;
            for (int k = 0; k < K; k++) f->wdd += f->w[n * B + b] * D[b * K + k] * D[b * K + k];
        }
        f->x[n] = x;
        f->y[n] = y;
        n++;
    }
    f->n = n;
    if (n < 4) return GS_OK;
    int x1 = f->x[0], y1 = f->y[0];
    f->bx0 = f->x[0];
    f->by0 = f->y[0];
    for (int p = 1; p < n; p++) {
        if (f->x[p] < f->bx0) f->bx0 = f->x[p];
        if (f->y[p] < f->by0) f->by0 = f->y[p];
        if (f->x[p] > x1) x1 = f->x[p];
        if (f->y[p] > y1) y1 = f->y[p];
    }
    f->bw = x1 - f->bx0 + 1;
    f->bh = y1 - f->by0 + 1;
    for (int p = 0; p < n; p++)
        for (int d = 0; d < BK; d++) f->Dt[(size_t)d * n + p] = f->D[(size_t)p * BK + d];
    f->lo_x = f->lo_y = HUGE_VAL;
    f->hi_x = f->hi_y = -HUGE_VAL;
    for (int i = 0; i < nfp; i++) {
        double x = fp[i] % W, y = fp[i] / W;
        if (x - 1 < f->lo_x) f->lo_x = x - 1;
        if (y - 1 < f->lo_y) f->lo_y = y - 1;
        if (x + 1 > f->hi_x) f->hi_x = x + 1;
        if (y + 1 > f->hi_y) f->hi_y = y + 1;
    }
    if (!(rank1_z(f, R, R + n) > s->o->deblend_sigma))   /* one signal: split only in space */
        return N0 == 1 && !nsat ? spatial_split(f, comp, fp, nfp, start, R, L, replaced) : GS_OK;
    double pos[2 * FIT_MAX_SOURCES + 1], trial[2 * FIT_MAX_SOURCES + 1];
    int N = N0;
    memcpy(pos, start, sizeof(double) * (size_t)(2 * N));
    pos[2 * N] = s->psf_sigma;
    double chi2 = fit_positions(f, N, pos);
    if (!(chi2 < HUGE_VAL)) return GS_OK;   /* no fit (singular): keep step 5's lights */
    if (N >= 2 && !fit_ok(f, N, pos, -INFINITY)) return GS_OK;   /* keep step 5's lights */
    while (N < FIT_MAX_SOURCES) {
        int i = best_new_source(f, N, pos, fp, nfp, R);
        if (i < 0) break;
        memcpy(trial, pos, sizeof(double) * (size_t)(2 * N));
        trial[2 * N] = fp[i] % W;
        trial[2 * N + 1] = fp[i] / W;
        trial[2 * N + 2] = pos[2 * N];
        /* the drop and the new signal at the candidate pixel first (one evaluation): only a
         * candidate that passes both there is worth the search (the search only lowers chi2) */
        double c2 = fit_eval(f, N + 1, trial);
        if (!(wh_z(chi2 - c2, BK + 2) > s->o->deblend_sigma) ||
            !(span_z(f, N + 1) > s->o->deblend_sigma || spatially_distinct(f, N + 1, trial)))
            break;
        c2 = fit_positions(f, N + 1, trial);
        if (!(wh_z(chi2 - c2, BK + 2) > s->o->deblend_sigma) || !fit_ok(f, N + 1, trial, s->o->deblend_sigma))
            break;
        N++;
        memcpy(pos, trial, sizeof(double) * (size_t)(2 * N + 1));
        chi2 = c2;
    }
    if (N < 2) return GS_OK;
    *replaced = 1;
    return emit_fit(f, comp, N, pos, L);
}

/* The owner among lights first..first+N-1 of L of pixel (x, y): the largest mean model flux. */
static int dominant(const fit_list *L, size_t first, size_t N, int x, int y, int BK)
{
    size_t best = first;
    double best_v = -HUGE_VAL;
    for (size_t q = first; q < first + N; q++) {
        double m = 0;
        for (int d = 0; d < BK; d++) m += L->v[q].sig[d];
        double v = rec_psf_share(x, y, L->v[q].x, L->v[q].y, L->v[q].psf) * m;
        if (v > best_v) {
            best_v = v;
            best = q;
        }
    }
    return (int)best;
}

typedef struct {
    int first, id;
} fit_order;

static int cmp_fit_order(const void *a, const void *b)
{
    const fit_order *x = a, *y = b;
    return (x->first > y->first) - (x->first < y->first);
}

static int uf_root(int *parent, int i)
{
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
}

/* The fit groups: unit_of[i] (1-based) for every light, from the lights' components comp_of
 * and positions; lights of a component within FIT_GROUP_SIGMA PSF sigmas of each other are one
 * group (union-find over each component's pairs). Returns the number of groups; -1 out of
 * memory. */
static int fit_groups(const rec_blob_state *s, const rec_catalog *cat, const int *comp_of, int *unit_of)
{
    const size_t n = cat->count;
    const double reach = FIT_GROUP_SIGMA * s->psf_sigma;
    int *parent = malloc(sizeof(int) * n), *order = malloc(sizeof(int) * n);
    int *cstart = calloc((size_t)s->ncomp + 2, sizeof(int));
    if (!parent || !order || !cstart) {
        free(parent);
        free(order);
        free(cstart);
        return -1;
    }
    for (size_t i = 0; i < n; i++) {
        parent[i] = (int)i;
        cstart[comp_of[i] + 1]++;
    }
    for (int l = 1; l <= s->ncomp + 1; l++) cstart[l] += cstart[l - 1];
    for (size_t i = 0; i < n; i++) order[cstart[comp_of[i]]++] = (int)i;   /* cstart[l]: end of l */
    for (int l = 0, a = 0; l <= s->ncomp; l++) {
        int b = cstart[l];
        for (int u = a; u < b; u++)
            for (int v = u + 1; v < b; v++) {
                int i = order[u], j = order[v];
                if (hypot(cat->x_px[i] - cat->x_px[j], cat->y_px[i] - cat->y_px[j]) <= reach)
                    parent[uf_root(parent, i)] = uf_root(parent, j);
            }
        a = b;
    }
    int units = 0;
    for (size_t i = 0; i < n; i++) unit_of[i] = 0;
    for (size_t i = 0; i < n; i++) {
        int r = uf_root(parent, (int)i);
        if (!unit_of[r]) unit_of[r] = ++units;
        unit_of[i] = unit_of[r];
    }
    free(parent);
    free(order);
    free(cstart);
    return units;
}

/* One thread's scratch of the fit: fit_data's arrays and the residual R. */
static int fit_data_alloc(fit_data *f, const rec_blob_state *s, double **R)
{
    const int B = s->bands, K = s->K, BK = B * K;
    memset(f, 0, sizeof *f);
    f->s = s;
    f->B = B;
    f->K = K;
    f->BK = BK;
    f->x = malloc(sizeof(int) * FIT_MAX_PX);
    f->y = malloc(sizeof(int) * FIT_MAX_PX);
    f->D = malloc(sizeof(double) * FIT_MAX_PX * (size_t)BK);
    f->V = malloc(sizeof(double) * FIT_MAX_PX * (size_t)BK);
    f->w = malloc(sizeof(double) * FIT_MAX_PX * (size_t)B);
    f->P = malloc(sizeof(double) * FIT_MAX_PX * FIT_MAX_SOURCES);
    f->F = malloc(sizeof(double) * FIT_MAX_SOURCES * (size_t)BK);
    f->Ainv = malloc(sizeof(double) * FIT_MAX_SOURCES * FIT_MAX_SOURCES * (size_t)B);
    f->num = malloc(sizeof(double) * (size_t)K);
    f->Dt = malloc(sizeof(double) * FIT_MAX_PX * (size_t)BK);
    f->wP = malloc(sizeof(double) * FIT_MAX_PX * FIT_MAX_SOURCES);
    f->gx = malloc(sizeof(double) * 3 * (FIT_MAX_PX + 1));   /* the shares and two derivatives */
    f->gy = malloc(sizeof(double) * 3 * (FIT_MAX_PX + 1));
    f->dP = malloc(sizeof(double) * 6 * FIT_MAX_SOURCES * FIT_MAX_PX);
    f->perp = malloc(sizeof(double) * 6 * FIT_MAX_SOURCES * FIT_MAX_PX);
    f->wb = malloc(sizeof(double) * FIT_MAX_PX);
    f->wPb = malloc(sizeof(double) * FIT_MAX_SOURCES * FIT_MAX_PX);
    f->wperp = malloc(sizeof(double) * 6 * FIT_MAX_SOURCES * FIT_MAX_PX);
    f->mean = malloc(sizeof(double) * 3 * FIT_MAX_PX * (size_t)B);
    *R = malloc(sizeof(double) * FIT_MAX_PX * (size_t)BK);
    return f->x && f->y && f->D && f->V && f->w && f->P && f->F && f->Ainv && f->num && f->Dt && f->wP &&
           f->gx && f->gy && f->mean && f->dP && f->perp && f->wb && f->wPb && f->wperp && *R;
}

static void fit_data_free(fit_data *f, double *R)
{
    free(f->x), free(f->y), free(f->D), free(f->V), free(f->w), free(f->P), free(f->F);
    free(f->Ainv), free(f->num), free(f->Dt), free(f->wP), free(f->gx), free(f->gy), free(f->mean);
    free(f->dP), free(f->perp), free(f->wb), free(f->wPb), free(f->wperp);
    free(R);
}

static void fit_list_free(fit_list *L)
{
    for (size_t i = 0; i < L->n; i++) free(L->v[i].sig);
    free(L->v);
    memset(L, 0, sizeof *L);
}

/* The fit groups 1..ngroups, split over threads: each part fits its groups in order into its own
 * list, first_new[l] the index of group l's first light in its part's list. Concatenated in part
 * order the lists are what one thread makes. */
typedef struct {
    const rec_blob_state *s;
    const rec_catalog *cat;
    const int *ap_start, *ap_pix, *fp_start, *fp_pix, *lt_start, *lt_list;
    int *replaced;
    size_t *first_new;
    fit_list lists[GS_MAX_THREADS];
    size_t begin[GS_MAX_THREADS];
} fit_groups_job;

static gs_status fit_groups_part(void *ctx, int part, size_t i0, size_t i1)
{
    fit_groups_job *j = ctx;
    const rec_catalog *cat = j->cat;
    fit_list *L = &j->lists[part];
    j->begin[part] = i0 + 1;
    fit_data f;
    double *R;
    gs_status st = GS_OK;
    if (!fit_data_alloc(&f, j->s, &R)) st = gs_fail(GS_ENOMEM, "blobs: cannot allocate the PSF fit");
    for (size_t l = i0 + 1; l < i1 + 1 && st == GS_OK; l++) {
        int nap = j->ap_start[l + 1] - j->ap_start[l], nl = j->lt_start[l + 1] - j->lt_start[l];
        j->first_new[l] = L->n;
        if (nl == 0 || nl > FIT_MAX_SOURCES || nap > FIT_MAX_PX) continue;
        double start[2 * FIT_MAX_SOURCES];
        int skip = 0;
        for (int q = 0; q < nl; q++) {
            int i = j->lt_list[j->lt_start[l] + q];
            skip |= (cat->flags[i] & REC_BLOB_NO_SIGNAL) != 0;
            start[2 * q] = cat->x_px[i];
            start[2 * q + 1] = cat->y_px[i];
        }
        if (skip) continue;
        st = fit_component(&f, (int)l, j->ap_pix + j->ap_start[l], nap, j->fp_pix + j->fp_start[l],
                           j->fp_start[l + 1] - j->fp_start[l], start, nl, R, L, &j->replaced[l]);
    }
    fit_data_free(&f, R);
    return st;
}

gs_status rec_blob_psf_fit(rec_blob_state *s, rec_catalog *cat)
{
    const int B = s->bands, K = s->K, BK = B * K, W = s->W;
    const size_t n = cat->count;
    if (!s->o->psf_fit || n == 0 || !(s->psf_sigma > 0) || !isfinite(s->o->deblend_sigma)) return GS_OK;
    gs_status st = GS_OK;
    /* arrays by fit group, at most one per light; nc: the groups + 1 once they are known */
    size_t nc = ((size_t)s->ncomp > n ? (size_t)s->ncomp : n) + 1;
    int *comp_of = calloc(n, sizeof *comp_of), *unit_of = calloc(n, sizeof *unit_of);
    int *ap_start = calloc(nc + 1, sizeof(int)), *fp_start = calloc(nc + 1, sizeof(int));
    int *ap_pix = NULL, *fp_pix = NULL;   /* (sized once the groups' pixels are counted) */
    int *fill = malloc(sizeof(int) * (nc + 1));
    int *lt_start = calloc(nc + 1, sizeof(int)), *lt_list = malloc(sizeof(int) * n);
    int *replaced = calloc(nc, sizeof(int));
    size_t *first_new = malloc(sizeof(size_t) * nc);
    fit_list L = {NULL, 0, 0};
    rec_catalog out;
    memset(&out, 0, sizeof out);
    fit_order *ord = NULL;
    int *newid = NULL;
    double *fit_cov = NULL;
    fit_groups_job *job = NULL;
    if (!comp_of || !unit_of || !ap_start || !fp_start || !fill || !lt_start || !lt_list || !replaced || !first_new) {
        st = gs_fail(GS_ENOMEM, "blobs: cannot allocate the PSF fit");
        goto done;
    }
    /* each light's component, its fit group, each group's aperture and footprint pixels */
    for (size_t p = 0; p < s->N; p++)
        if (s->fp[p] >= 0 && !comp_of[s->fp[p]]) comp_of[s->fp[p]] = s->comp[p];
    int units = fit_groups(s, cat, comp_of, unit_of);
    if (units < 0) {
        st = gs_fail(GS_ENOMEM, "blobs: cannot group %zu lights for the PSF fit", n);
        goto done;
    }
    nc = (size_t)units + 1;
    for (size_t p = 0; p < s->N; p++) {
        if (s->ap[p] >= 0) ap_start[unit_of[s->ap[p]] + 1]++;
        if (s->fp[p] >= 0) fp_start[unit_of[s->fp[p]] + 1]++;
    }
    for (size_t l = 1; l <= nc; l++) {
        ap_start[l] += ap_start[l - 1];
        fp_start[l] += fp_start[l - 1];
    }
    ap_pix = malloc(sizeof(int) * (size_t)(ap_start[nc] > 0 ? ap_start[nc] : 1));
    fp_pix = malloc(sizeof(int) * (size_t)(fp_start[nc] > 0 ? fp_start[nc] : 1));
    if (!ap_pix || !fp_pix) {
        st = gs_fail(GS_ENOMEM, "blobs: cannot allocate the PSF fit");
        goto done;
    }
    memcpy(fill, ap_start, sizeof(int) * nc);
    for (size_t p = 0; p < s->N; p++)
        if (s->ap[p] >= 0) ap_pix[fill[unit_of[s->ap[p]]]++] = (int)p;
    memcpy(fill, fp_start, sizeof(int) * nc);
    for (size_t p = 0; p < s->N; p++)
        if (s->fp[p] >= 0) fp_pix[fill[unit_of[s->fp[p]]]++] = (int)p;
    /* the lights of each group start the fit */
    for (size_t i = 0; i < n; i++) lt_start[unit_of[i] + 1]++;
    for (size_t l = 1; l <= nc; l++) lt_start[l] += lt_start[l - 1];
    memcpy(fill, lt_start, sizeof(int) * nc);
    for (size_t i = 0; i < n; i++) lt_list[fill[unit_of[i]]++] = (int)i;
    /* the groups on the blob options' threads, their lists joined in group order */
    job = calloc(1, sizeof *job);
    if (!job) {
        st = gs_fail(GS_ENOMEM, "blobs: cannot allocate the PSF fit");
        goto done;
    }
    *job = (fit_groups_job){.s = s, .cat = cat, .ap_start = ap_start, .ap_pix = ap_pix, .fp_start = fp_start,
                            .fp_pix = fp_pix, .lt_start = lt_start, .lt_list = lt_list, .replaced = replaced,
                            .first_new = first_new};
    /* (OpenBLAS single-threaded: its threads spun beside the groups' on matrices of at most
     * 3 x FIT_MAX_SOURCES, 1.44 s instead of 2.3-2.5 s on two threads) */
    int blas = gs_blas_serial();
    st = gs_parallel_for(s->o->threads, nc - 1, fit_groups_part, job);
    gs_blas_restore(blas);
    for (int p = 0; p < GS_MAX_THREADS && st == GS_OK; p++) {
        fit_list *Lp = &job->lists[p];
        if (!job->begin[p]) break;   /* parts 0..P-1 ran */
        size_t end = p + 1 < GS_MAX_THREADS && job->begin[p + 1] ? job->begin[p + 1] : nc;
        for (size_t l = job->begin[p]; l < end; l++) first_new[l] += L.n;
        if (!Lp->n) continue;
        if (L.n + Lp->n > L.cap) {
            fit_light *nv = realloc(L.v, (L.n + Lp->n) * sizeof *nv);
            if (!nv) {
                st = gs_fail(GS_ENOMEM, "blobs: cannot hold %zu fitted lights", L.n + Lp->n);
                break;
            }
            L.v = nv;
            L.cap = L.n + Lp->n;
        }
        memcpy(L.v + L.n, Lp->v, Lp->n * sizeof *Lp->v);
        L.n += Lp->n;
        free(Lp->v);
        memset(Lp, 0, sizeof *Lp);
    }
    if (st != GS_OK || L.n == 0) goto done;
    fit_cov = malloc(sizeof(double) * 3 * L.n);   /* by fitted light, reordered below */
    if (!fit_cov) {
        st = gs_fail(GS_ENOMEM, "blobs: cannot hold %zu position covariances", L.n);
        goto done;
    }
    if ((st = fitted_position_cov(&L, fit_cov)) != GS_OK) goto done;
    /* (the groups' pixel lists are done with: not beside the new catalog) */
    free(ap_pix);
    free(fp_pix);
    free(lt_list);
    ap_pix = fp_pix = lt_list = NULL;

    /* the new catalog: ids 0..n-1 the old lights, n + j the fitted ones; replaced components'
     * pixels go to their dominant fitted light; then raster order of the first footprint pixel */
    const size_t total = n + L.n;
    for (size_t p = 0; p < s->N; p++) {
        int i = s->ap[p] >= 0 ? s->ap[p] : -1;
        if (i < 0) continue;
        int l = unit_of[i];
        if (!replaced[l]) continue;
        size_t cnt = (l + 1 < (int)nc ? first_new[l + 1] : L.n) - first_new[l];
        int j = dominant(&L, first_new[l], cnt, (int)(p % (size_t)W), (int)(p / (size_t)W), BK);
        int was_fp = s->fp[p] >= 0;
        s->ap[p] = (int)n + j;
        if (was_fp) s->fp[p] = (int)n + j;
    }
    ord = malloc(sizeof *ord * total);
    newid = malloc(sizeof(int) * total);
    if (!ord || !newid) {
        st = gs_fail(GS_ENOMEM, "blobs: cannot order the fitted lights");
        goto done;
    }
    for (size_t i = 0; i < total; i++) ord[i] = (fit_order){-1, (int)i};
    for (size_t p = 0; p < s->N; p++)
        if (s->fp[p] >= 0 && ord[s->fp[p]].first < 0) ord[s->fp[p]].first = (int)p;
    size_t m = 0;
    for (size_t i = 0; i < total; i++)
        if (ord[i].first >= 0) ord[m++] = ord[i];
    qsort(ord, m, sizeof *ord, cmp_fit_order);
    for (size_t i = 0; i < total; i++) newid[i] = -1;
    for (size_t j = 0; j < m; j++) newid[ord[j].id] = (int)j;
    out.count = m;
    out.bands = B;
    out.K = K;
    out.width = cat->width;
    out.height = cat->height;
    out.x_px = malloc(sizeof(double) * m);
    out.y_px = malloc(sizeof(double) * m);
    out.area_px = calloc(m, sizeof(int));
    out.peak_dn = calloc(m, sizeof(double));
    out.saturated_px = calloc(m, sizeof(int));
    out.flags = calloc(m, sizeof(unsigned));
    out.pos_cov_px2 = malloc(sizeof(double) * 3 * m);
    out.signal = malloc(sizeof(double) * m * (size_t)BK);
    out.sigma = malloc(sizeof(double) * m * (size_t)BK);
    if (cat->labels) out.labels = malloc(sizeof(int) * s->N);
    if (!out.x_px || !out.y_px || !out.area_px || !out.peak_dn || !out.saturated_px || !out.flags ||
        !out.pos_cov_px2 || !out.signal || !out.sigma || (cat->labels && !out.labels)) {
        st = gs_fail(GS_ENOMEM, "blobs: cannot hold a catalog of %zu lights", m);
        goto done;
    }
    for (size_t j = 0; j < m; j++) {
        int id = ord[j].id;
        if (id < (int)n) {
            out.x_px[j] = cat->x_px[id];
            out.y_px[j] = cat->y_px[id];
            out.area_px[j] = cat->area_px[id];
            out.peak_dn[j] = cat->peak_dn[id];
            out.saturated_px[j] = cat->saturated_px[id];
            out.flags[j] = cat->flags[id];
            for (int c = 0; c < 3; c++)
                out.pos_cov_px2[3 * j + c] = cat->pos_cov_px2 ? cat->pos_cov_px2[3 * (size_t)id + c] : NAN;
            memcpy(out.signal + j * BK, cat->signal + (size_t)id * BK, sizeof(double) * (size_t)BK);
            memcpy(out.sigma + j * BK, cat->sigma + (size_t)id * BK, sizeof(double) * (size_t)BK);
        } else {
            const fit_light *fl = &L.v[id - (int)n];
            out.x_px[j] = fl->x;
            out.y_px[j] = fl->y;
            out.flags[j] = REC_BLOB_DEBLENDED | REC_BLOB_PSF_FIT;
            memcpy(out.pos_cov_px2 + 3 * j, fit_cov + 3 * (id - (int)n), sizeof(double) * 3);
            memcpy(out.signal + j * BK, fl->sig, sizeof(double) * (size_t)BK);
            memcpy(out.sigma + j * BK, fl->sgm, sizeof(double) * (size_t)BK);
        }
    }
    /* the fitted lights' footprint area, peak, saturation and flags from their pixels */
    for (size_t p = 0; p < s->N; p++) {
        if (s->ap[p] >= 0) s->ap[p] = newid[s->ap[p]];
        if (s->fp[p] >= 0) s->fp[p] = newid[s->fp[p]];
        int j = s->ap[p];
        if (j < 0 || !(out.flags[j] & REC_BLOB_PSF_FIT)) continue;
        int x = (int)(p % (size_t)W), y = (int)(p / (size_t)W);
        if (x == 0 || y == 0 || x == W - 1 || y == s->H - 1) out.flags[j] |= REC_BLOB_EDGE;
        if (s->hdr[p]) out.flags[j] |= REC_BLOB_HDR;
        if (s->sat[p]) {
            out.flags[j] |= REC_BLOB_SATURATED;
            out.saturated_px[j]++;
        }
        if (s->fp[p] != j) continue;
        out.area_px[j]++;
        for (int k = 0; k < K; k++) {
            const unsigned short *r = s->cap->raw + (s->N * (size_t)k + p) * (size_t)B;
            for (int b = 0; b < B; b++)
                if (r[b] > out.peak_dn[j]) out.peak_dn[j] = r[b];
        }
    }
    if (out.labels) memcpy(out.labels, s->ap, sizeof(int) * s->N);
    rec_catalog_release(cat);
    *cat = out;
    memset(&out, 0, sizeof out);
done:
    rec_catalog_release(&out);
    fit_list_free(&L);
    free(comp_of);
    free(unit_of);
    free(ap_start);
    free(fp_start);
    free(ap_pix);
    free(fp_pix);
    free(fill);
    free(lt_start);
    free(lt_list);
    free(replaced);
    free(first_new);
    if (job)
        for (int p = 0; p < GS_MAX_THREADS; p++) fit_list_free(&job->lists[p]);
    free(job);
    free(ord);
    free(newid);
    free(fit_cov);
    return st;
}
