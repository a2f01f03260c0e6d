/* unmix.c - AC light-transport unmixing (paper Sec. 5.1, Eqs. 16-18): per pixel and band the
 * transport T >= 0 of I = T Q B by weighted non-negative least squares (Eq. 16) with the
 * weights of Eq. 17, then the refinement of B (Eq. 18) and Eq. 16 again; Eq. 19's rendering.
 * docs/light-transport.md has the model, the weights and the measured errors. */
#include "recognize/recognize.h"

#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define SMAX REC_MAX_SOURCES

void rec_unmix_opts_default(rec_unmix_opts *o)
{
    memset(o, 0, sizeof *o);
    o->refine = 1;
    o->max_error = 0.5;
    o->max_inflation = 10;
    o->brf_sigma = 0.05;
    o->max_drift_windows = REC_MAX_DRIFT_WINDOWS;   /* (not auto: the kept frames' noise is not raised) */
}

void rec_unmix_release(rec_unmix_result *r)
{
    if (!r) return;
    free(r->tq);
    free(r->sigma);
    free(r->b);
    free(r->state);
    free(r->residual);
    memset(r, 0, sizeof *r);
}

/* The unmixing state shared by the passes. */
typedef struct {
    const gs_capture *cap;
    const rec_sources *src;
    const rec_unmix_opts *o;
    int W, H, B, K, S;
    gs_noise nz;
    double *A;        /* [band][k][s] = q_s b_s[k] (the columns of (QB)^T) */
    double *G0;       /* [band][S x S] A^T A */
    double *G0inv;    /* [band][S x S] its inverse */
    double *bcur;     /* current B, as src->b */
    /* per pixel scratch */
    double *v;        /* [k * B + band] per-cycle values */
    double *c;        /* [k] effective cycles cycles_k / 2^h */
    unsigned char *use;
    unsigned char *kept;  /* [k] the frame kept (rec_frames_left_out), once per capture */
    int left_out;         /* frames not kept */
    unsigned short *act;  /* [P] the sources each pixel determines (bit s): given a value */
    unsigned short *fit;  /* [P] the sources in its fit (a superset) */
    double rawmax;        /* the pixel's largest raw sample */
    double *kmax;         /* [k] its largest raw sample of frame k */
    double censor_dn;     /* samples above this raw level are left out of Eq. 18 */
    /* Eq. 18 accumulators: [band][S x S] of the pixels with every sample usable and the same
     * exposure, [band][k][S x S] of the others, [band][k][S], pixels accumulated per band */
    double *Gc, *Gk, *hk, nacc[GS_MAX_BANDS];
    /* noise-propagated variance and signal per source (pass 0), [0] of the pixels with every
     * sample usable, [1] of those with some saturated (the predicted errors' when there is no
     * complete pixel) */
    double var_sum[2][SMAX], sig_sum[2][SMAX];
    double chi2, dof;   /* the last Eq. 16's weighted residual and its degrees of freedom */
} ux;

/* The weight 1/var of a per-cycle value of a pixel at level mu (DN per cycle) that integrated
 * c cycles (the capture's noise model, docs/formats.md). */
static double weight(const gs_noise *nz, double mu, double c)
{
    double e = mu > 0 ? mu * c : 0.0;
    double var = (nz->read_var_dn2 + e * nz->inv_gain) / (c * c);
    return 1.0 / var;
}

/* Samples of pixel p: values, effective cycles and usability (Eq. 17: no band saturated; and
 * the frame's windows kept, rec_frame_kept: a free-running frame smeared across the flicker
 * follows no BRF). Returns the usable count; *uniform = 1 when every sample is usable with the
 * same cycles. */
static int gather(ux *u, size_t p, int *uniform)
{
    const gs_capture *cap = u->cap;
    int B = u->B, K = u->K, n = 0, uni = 1;
    u->rawmax = 0;
    size_t plane = (size_t)u->W * (size_t)u->H;
    for (int k = 0; k < K; k++) {
        int h = cap->halvings ? cap->halvings[(size_t)k * plane + p] : 0;
        double c = cap->frames[k].cycles / (double)(1u << h);
        const unsigned short *raw = cap->raw + ((size_t)k * plane + p) * (size_t)B;
        int ok = u->kept[k];
        for (int b = 0; b < B; b++) {
            if (raw[b] >= cap->saturation_dn) ok = 0;
            u->v[k * B + b] = ((double)raw[b] - cap->black_level_dn) / c;
        }
        u->c[k] = c;
        u->use[k] = (unsigned char)ok;
        u->kmax[k] = 0;
        for (int b = 0; b < B; b++)
            if (raw[b] > u->kmax[k]) u->kmax[k] = raw[b];
        if (u->kmax[k] > u->rawmax) u->rawmax = u->kmax[k];
        n += ok;
        if (!ok || c != u->c[0]) uni = 0;
    }
    *uniform = uni;
    return n;
}

/* Cholesky inverse of the n x n SPD matrix G into Gi (n <= SMAX; a pixel's system is too small
 * for LAPACK's call overhead); 0 if not numerically positive definite. */
static int spd_inverse(const double *G, int n, double *Gi)
{
    double L[SMAX * SMAX], Li[SMAX * SMAX];
    for (int i = 0; i < n; i++)
        for (int j = 0; j <= i; j++) {
            double s = G[i * n + j];
            for (int r = 0; r < j; r++) s -= L[i * n + r] * L[j * n + r];
            if (i == j) {
                if (!(s > 1e-13 * G[i * n + i]) || !(s > 0)) return 0;
                L[i * n + i] = sqrt(s);
            } else {
                L[i * n + j] = s / L[j * n + j];
            }
        }
    /* L^-1 (lower), then G^-1 = L^-T L^-1 */
    for (int j = 0; j < n; j++) {
        for (int i = 0; i < j; i++) Li[i * n + j] = 0;
        Li[j * n + j] = 1 / L[j * n + j];
        for (int i = j + 1; i < n; i++) {
            double s = 0;
            for (int r = j; r < i; r++) s -= L[i * n + r] * Li[r * n + j];
            Li[i * n + j] = s / L[i * n + i];
        }
    }
    for (int i = 0; i < n; i++)
        for (int j = 0; j <= i; j++) {
            double s = 0;
            for (int r = i; r < n; r++) s += Li[r * n + i] * Li[r * n + j];
            Gi[i * n + j] = Gi[j * n + i] = s;
        }
    return 1;
}

/* The sources of a pixel that its usable samples determine (Eq. 17 may have discarded what
 * measured one). When G of every source is positive definite, all of them stay in the fit, so
 * the others are not biased by a poorly measured one; returned: those whose variance (G^-1)_ss
 * is at most max_inflation times their variance from all K samples (Gfull^-1)_ss (the others
 * are fitted but have no value), *fit every source. When it is singular (fewer usable samples
 * than sources, or samples that cannot tell two apart), no source has a value: a fit without
 * one of them would give its light to the others. *fit is then the largest set on which G is
 * positive definite (dropping, while it is singular, the source least observed relative to all
 * K samples), for the pixel's model, and 0 is returned. */
static unsigned determined(const double *G, const double *Gfull, int S, double max_inflation,
                           unsigned *fit)
{
    unsigned act = (1u << S) - 1;
    while (act) {
        int idx[SMAX], m = 0;
        for (int s = 0; s < S; s++)
            if (act >> s & 1u) idx[m++] = s;
        double Ga[SMAX * SMAX], Gf[SMAX * SMAX], Gi[SMAX * SMAX], Gfi[SMAX * SMAX];
        for (int i = 0; i < m; i++)
            for (int j = 0; j < m; j++) {
                Ga[i * m + j] = G[idx[i] * S + idx[j]];
                Gf[i * m + j] = Gfull[idx[i] * S + idx[j]];
            }
        if (!spd_inverse(Gf, m, Gfi)) break;
        if (spd_inverse(Ga, m, Gi)) {
            *fit = act;
            if (m < S) return 0;   /* a source left out: the others carry its light */
            unsigned det = act;
            for (int i = 0; i < m; i++)
                if (!(Gi[i * m + i] <= max_inflation * Gfi[i * m + i])) det &= ~(1u << idx[i]);
            return det;
        }
        /* singular: the least observed source goes */
        int worst = 0;
        double wr = -1;
        for (int i = 0; i < m; i++) {
            double rr = Ga[i * m + i] > 0 ? Gf[i * m + i] / Ga[i * m + i] : INFINITY;
            if (rr > wr) {
                wr = rr;
                worst = i;
            }
        }
        act &= ~(1u << idx[worst]);
    }
    *fit = 0;
    return 0;
}

/* A, G0 and G0inv of the current B; the condition of the row-normalised QB per band (cond)
 * and its numerical rank (the smallest over bands). */
static gs_status setup_design(ux *u, double *cond, int *rank)
{
    int B = u->B, K = u->K, S = u->S;
    *rank = S;
    for (int b = 0; b < B; b++) {
        double *A = u->A + (size_t)b * K * S;
        double M[SMAX * 1024];
        for (int s = 0; s < S; s++) {
            double nrm = 0;
            for (int k = 0; k < K; k++) {
                A[k * S + s] = u->src->q[s * B + b] * u->bcur[((size_t)s * B + b) * K + k];
                nrm += A[k * S + s] * A[k * S + s];
            }
            nrm = nrm > 0 ? 1.0 / sqrt(nrm) : 0.0;
            for (int k = 0; k < K; k++) M[s * K + k] = A[k * S + s] * nrm;
        }
        double sv[SMAX], superb[SMAX];
        int m = S < K ? S : K;
        if (LAPACKE_dgesvd(LAPACK_ROW_MAJOR, 'N', 'N', S, K, M, K, sv, NULL, 1, NULL, 1, superb) != 0)
            return gs_fail(GS_ENUMERIC, "unmix: the SVD of QB (band %d) did not converge", b);
        int r = 0;
        for (int i = 0; i < m; i++) r += sv[i] > 1e-10 * sv[0];
        if (r < *rank) *rank = r;
        cond[b] = S > K || !(sv[S - 1] > 0) ? INFINITY : sv[0] / sv[S - 1];
        double *G = u->G0 + (size_t)b * S * S;
        for (int i = 0; i < S; i++)
            for (int j = 0; j < S; j++) {
                double g = 0;
                for (int k = 0; k < K; k++) g += A[k * S + i] * A[k * S + j];
                G[i * S + j] = g;
            }
        if (r == S && !spd_inverse(G, S, u->G0inv + (size_t)b * S * S)) *rank = S - 1;
    }
    return GS_OK;
}

/* The mean of the pixel's usable values of band b (gather first). */
static double usable_mean(const ux *u, int b)
{
    double s = 0;
    int n = 0;
    for (int k = 0; k < u->K; k++)
        if (u->use[k]) {
            s += u->v[k * u->B + b];
            n++;
        }
    return n ? s / n : 0.0;
}

/* The weighted normal equations of Eq. 16 for band b of the gathered pixel at level mu: G and h
 * from the usable samples (weights wk, 0 for the discarded), Gf as if every sample were usable. */
static void build_normal(const ux *u, int b, double mu, double *G, double *Gf, double *h, double *wk)
{
    int S = u->S, K = u->K, B = u->B;
    const double *A = u->A + (size_t)b * K * S;
    memset(G, 0, sizeof *G * (size_t)S * S);
    memset(Gf, 0, sizeof *Gf * (size_t)S * S);
    memset(h, 0, sizeof *h * (size_t)S);
    for (int k = 0; k < K; k++) {
        double wf = weight(&u->nz, mu, u->c[k]);
        wk[k] = u->use[k] ? wf : 0.0;
        const double *a = A + (size_t)k * S;
        double wv = wk[k] * u->v[k * B + b];
        for (int i = 0; i < S; i++) {
            h[i] += wv * a[i];
            for (int j = 0; j <= i; j++) {
                G[i * S + j] += wk[k] * a[i] * a[j];
                Gf[i * S + j] += wf * a[i] * a[j];
            }
        }
    }
    for (int i = 0; i < S; i++)
        for (int j = 0; j < i; j++) {
            G[j * S + i] = G[i * S + j];
            Gf[j * S + i] = Gf[i * S + j];
        }
}

/* Eq. 16's noise variance of each unconstrained t_s of band b: the covariance
 * Gi (sum_k wk^2 var_k a_k a_k^T) Gi, var_k the noise model's at sample k's fitted level (sum_s
 * a_ks t_s: a flickering source moves it far from the pixel's mean, at which the weights wk were
 * taken), over the usable samples (wk > 0). Gi is the inverse of the weighted normal matrix. */
static void eq16_variance(const ux *u, int b, const double *Gi, const double *wk, const double *t,
                          double *var)
{
    int S = u->S, K = u->K;
    const double *A = u->A + (size_t)b * K * S;
    for (int s = 0; s < S; s++) var[s] = 0;
    for (int k = 0; k < K; k++) {
        if (!(wk[k] > 0)) continue;
        const double *a = A + (size_t)k * S;
        double m = 0;
        for (int s = 0; s < S; s++) m += a[s] * t[s];
        double f = wk[k] * wk[k] / weight(&u->nz, m, u->c[k]);
        for (int i = 0; i < S; i++) {
            double r = 0;   /* (Gi a_k)_i */
            for (int j = 0; j < S; j++) r += Gi[i * S + j] * a[j];
            var[i] += f * r * r;
        }
    }
}

/* x = argmin over x >= 0 on the sources of mask act (others 0) of x^T G x / 2 - h^T x. */
static int nnls_on(const double *G, const double *h, int S, unsigned act, double *x)
{
    int idx[SMAX], m = 0;
    for (int s = 0; s < S; s++) {
        x[s] = 0;
        if (act >> s & 1u) idx[m++] = s;
    }
    double Ga[SMAX * SMAX] = {0}, ha[SMAX] = {0}, xa[SMAX];
    for (int i = 0; i < m; i++) {
        ha[i] = h[idx[i]];
        for (int j = 0; j < m; j++) Ga[i * m + j] = G[idx[i] * S + idx[j]];
    }
    if (rec_nnls(Ga, ha, m, xa) < 0) return 0;
    for (int i = 0; i < m; i++) x[idx[i]] = xa[i];
    return 1;
}

/* Eq. 18's normal equations from a pixel whose samples differ in exposure or were discarded
 * (G, h, wk of build_normal): the linear estimate G^-1 h and, per usable sample below the
 * censoring level, its terms less their noise (the corrected score of finish in eq18). */
static void eq18_add(ux *u, int b, const double *G, const double *h, const double *wk)
{
    int S = u->S, K = u->K, B = u->B;
    double Gi[SMAX * SMAX], tuq[SMAX];
    if (!spd_inverse(G, S, Gi)) return;
    for (int i = 0; i < S; i++) {
        double x = 0;
        for (int j = 0; j < S; j++) x += Gi[i * S + j] * h[j];
        tuq[i] = x * u->src->q[i * B + b];
    }
    const double *A = u->A + (size_t)b * K * S;
    for (int k = 0; k < K; k++) {
        if (!(wk[k] > 0) || u->kmax[k] > u->censor_dn) continue;
        double *Gk = u->Gk + ((size_t)b * K + k) * S * S, *hk = u->hk + ((size_t)b * K + k) * S;
        double wv = wk[k] * u->v[k * B + b];
        for (int i = 0; i < S; i++) {
            double qi = u->src->q[i * B + b], c = 0;
            for (int j = 0; j < S; j++) c += Gi[i * S + j] * A[k * S + j];
            hk[i] += wv * tuq[i] - wk[k] * qi * c;
            for (int j = 0; j < S; j++)
                Gk[i * S + j] += wk[k] * (tuq[i] * tuq[j] - qi * Gi[i * S + j] * u->src->q[j * B + b]);
        }
    }
}

/* One pass of Eq. 16 over every pixel, the weights from the pixel's mean usable value (every
 * pass). pass 0 also finds the sources each pixel determines and the predicted errors; later
 * passes fit the pixels pass 0 fitted, with the refined B. accumulate: collect Eq. 18's normal
 * equations (pixels determining every source). */
static gs_status eq16_pass(ux *u, rec_unmix_result *r, int pass, int accumulate)
{
    int B = u->B, K = u->K, S = u->S;
    size_t P = (size_t)u->W * (size_t)u->H;
    const unsigned all = (1u << S) - 1;
    u->chi2 = 0;
    u->dof = 0;
    for (size_t p = 0; p < P; p++) {
        if (u->o->progress && (p & 65535) == 0)
            u->o->progress(u->o->progress_ctx, ((double)pass + (double)p / (double)P) /
                                                   (double)(u->o->refine + 1));
        float *tq[SMAX], *sq[SMAX];
        for (int s = 0; s < S; s++) {
            tq[s] = r->tq + ((size_t)s * P + p) * (size_t)B;
            sq[s] = r->sigma + ((size_t)s * P + p) * (size_t)B;
        }
        r->residual[p] = NAN;
        if (pass > 0 && !u->fit[p]) continue;
        double chi2_p = 0, dof_p = 0;   /* the pixel's, over its bands */
        int uniform;
        int n = gather(u, p, &uniform);
        if (pass == 0) {
            r->state[p] = n == K ? REC_UNMIX_OK : REC_UNMIX_PARTIAL;
            u->act[p] = u->fit[p] = (unsigned short)(n >= 1 ? all : 0);
            /* the sources the usable samples determine, in every band */
            for (int b = 0; b < B && !uniform && u->fit[p]; b++) {
                double G[SMAX * SMAX], Gf[SMAX * SMAX], h[SMAX], wk[1024];
                unsigned fit;
                build_normal(u, b, usable_mean(u, b), G, Gf, h, wk);
                u->act[p] &= (unsigned short)determined(G, Gf, S, u->o->max_inflation, &fit);
                u->fit[p] &= (unsigned short)fit;
            }
            u->act[p] &= u->fit[p];
        }
        for (int b = 0; b < B && u->fit[p]; b++) {
            const double *A = u->A + (size_t)b * K * S;
            double mu = usable_mean(u, b);
            double G[SMAX * SMAX], h[SMAX] = {0}, t[SMAX], tu[SMAX], w0 = 0, var[SMAX];
            double wk[1024], Gw[SMAX * SMAX];   /* Gw: the weighted normal matrix's inverse */
            int have_gw = 0;
            for (int s = 0; s < S; s++) var[s] = NAN;
            unsigned act = u->act[p], fit = u->fit[p];
            if (uniform) {
                w0 = weight(&u->nz, mu, u->c[0]);
                for (int k = 0; k < K; k++) {
                    wk[k] = w0;
                    double v = u->v[k * B + b];
                    for (int s = 0; s < S; s++) h[s] += v * A[k * S + s];
                }
                /* unconstrained first (G0^-1 h): usually already >= 0 */
                const double *Gi = u->G0inv + (size_t)b * S * S;
                int neg = 0;
                for (int i = 0; i < S; i++) {
                    double x = 0;
                    for (int j = 0; j < S; j++) x += Gi[i * S + j] * h[j];
                    t[i] = tu[i] = x;
                    neg |= x < 0;
                }
                if (neg && !nnls_on(u->G0 + (size_t)b * S * S, h, S, all, t)) act = fit = 0;
                for (int i = 0; i < S * S; i++) Gw[i] = Gi[i] / w0;
                have_gw = 1;
            } else {
                double Gf[SMAX * SMAX];
                build_normal(u, b, mu, G, Gf, h, wk);
                /* the covariance where it is kept: the last pass's sigmas (the one that does not
                 * accumulate Eq. 18) and pass 0's predicted errors */
                int need = !accumulate || (pass == 0 && act == all);
                if (need && fit == all && spd_inverse(G, S, Gw)) have_gw = 1;
                if (!nnls_on(G, h, S, fit, t)) act = fit = 0;
                if (accumulate && act == all) eq18_add(u, b, G, h, wk);
            }
            if (!fit) u->act[p] = u->fit[p] = 0;
            if (!u->fit[p]) break;
            /* the pixels determining every source: their noise counts towards what the data
             * support (the predicted errors), those with every sample usable (HDR exposures may
             * differ) apart from the partly saturated */
            int given = pass == 0 && act == all, part = n < K;
            if (have_gw && (!accumulate || given)) {
                eq16_variance(u, b, Gw, wk, t, var);
                for (int s = 0; s < S && given; s++) {
                    double q = u->src->q[s * B + b];
                    u->var_sum[part][s] += var[s] * q * q;
                }
            }
            double tqv[SMAX];
            for (int s = 0; s < S; s++) {
                tqv[s] = t[s] * u->src->q[s * B + b];
                tq[s][b] = (float)tqv[s];
                sq[s][b] = (float)(sqrt(var[s]) * u->src->q[s * B + b]);
                if (given) u->sig_sum[part][s] += tqv[s] * tqv[s];
            }
            /* residual of this fit, over the usable samples less the sources fitted */
            for (int k = 0; k < K; k++) {
                if (!u->use[k]) continue;
                double m = 0;
                for (int s = 0; s < S; s++) m += A[k * S + s] * t[s];
                double e = u->v[k * B + b] - m;
                chi2_p += wk[k] * e * e;
                dof_p += 1;
            }
            dof_p -= __builtin_popcount(fit);
            /* and not near saturation (censor_dn) */
            if (!accumulate || act != all || !uniform || u->rawmax > u->censor_dn) continue;
            /* Eq. 18's normal equations (the model I_pk = sum_s tq_s B_sk) from the linear,
             * unconstrained Eq. 16 estimates of the pixels with every sample usable: their
             * noise is known (G^-1), so finish_eq18 removes its bias (errors in variables) */
            double tuq[SMAX], *Gc = u->Gc + (size_t)b * S * S, *hk = u->hk + (size_t)b * K * S;
            for (int s = 0; s < S; s++) tuq[s] = tu[s] * u->src->q[s * B + b];
            for (int i = 0; i < S; i++)
                for (int j = 0; j <= i; j++) Gc[i * S + j] += w0 * tuq[i] * tuq[j];
            for (int k = 0; k < K; k++) {
                double wv = w0 * u->v[k * B + b];
                for (int i = 0; i < S; i++) hk[k * S + i] += wv * tuq[i];
            }
            u->nacc[b] += 1;
        }
        if (u->fit[p]) {   /* (a fit that failed in a later band has no residual) */
            u->chi2 += chi2_p;
            u->dof += dof_p;
            if (dof_p > 0) r->residual[p] = (float)sqrt(chi2_p / dof_p);
        }
        if (!u->act[p]) r->state[p] = REC_UNMIX_UNKNOWN;
        for (int s = 0; s < S; s++)
            if (!(u->act[p] >> s & 1u))
                for (int b = 0; b < B; b++) tq[s][b] = sq[s][b] = NAN;
    }
    return GS_OK;
}

/* Eq. 18: each column k of B (per band) by NNLS over all pixels, the fixed sources' rows kept;
 * each free source's change from the database then shrunk by c = max(0, 1 - N / D) (positive-
 * part James-Stein), D its squared size and N its noise (the trace of the normal equations'
 * inverse), so a change the noise explains is not made; then each free row renormalised to mean
 * 1 (the scale moves into T at the next Eq. 16). */
static gs_status eq18(ux *u)
{
    int B = u->B, K = u->K, S = u->S;
    size_t nb = (size_t)S * B * K;
    double *rows = u->bcur, *nw = malloc(sizeof *nw * nb * 2), *var = nw + nb;
    if (!nw) return gs_fail(GS_ENOMEM, "unmix: out of memory");
    memcpy(nw, rows, sizeof *nw * nb);
    memset(var, 0, sizeof *var * nb);
    int fr[SMAX], nf = 0;
    for (int s = 0; s < S; s++)
        if (!u->src->fixed[s]) fr[nf++] = s;
    double prior = 1.0 / (u->o->brf_sigma * u->o->brf_sigma);
    for (int b = 0; b < B && nf > 0; b++)
        for (int k = 0; k < K; k++) {
            double G[SMAX * SMAX], h[SMAX];
            /* the corrected score: E[w tq tq^T] = w T T^T + Q G0^-1 Q and E[w v_k tq] =
             * w (T^T b_k) T + Q G0^-1 a_k per pixel (G = w G0 of Eq. 16), so n of each are
             * subtracted */
            const double *Gc = u->Gc + (size_t)b * S * S, *Gi = u->G0inv + (size_t)b * S * S;
            const double *a = u->A + ((size_t)b * K + k) * S;
            double n = u->nacc[b];
            for (int i = 0; i < S; i++) {
                double qi = u->src->q[i * B + b], c = 0;
                for (int j = 0; j < S; j++) c += Gi[i * S + j] * a[j];
                h[i] = u->hk[((size_t)b * K + k) * S + i] - n * qi * c;
                for (int j = 0; j <= i; j++)
                    G[i * S + j] = G[j * S + i] = Gc[i * S + j] - n * qi * Gi[i * S + j] * u->src->q[j * B + b] +
                                                  u->Gk[((size_t)b * K + k) * S * S + (size_t)i * S + j];
            }
            /* the free sources' system, the fixed ones' contribution moved to h */
            double Gf[SMAX * SMAX], Gfi[SMAX * SMAX], hf[SMAX], x[SMAX];
            for (int i = 0; i < nf; i++) {
                hf[i] = h[fr[i]];
                for (int s = 0; s < S; s++)
                    if (u->src->fixed[s]) hf[i] -= G[fr[i] * S + s] * rows[((size_t)s * B + b) * K + k];
                for (int j = 0; j < nf; j++) Gf[i * nf + j] = G[fr[i] * S + fr[j]];
                /* "B is allowed to change a bit": a Gaussian prior of std brf_sigma about the
                 * database's B */
                Gf[i * nf + i] += prior;
                hf[i] += prior * u->src->b[((size_t)fr[i] * B + b) * K + k];
            }
            if (rec_nnls(Gf, hf, nf, x) < 0 || !spd_inverse(Gf, nf, Gfi)) continue;
            for (int i = 0; i < nf; i++) {
                size_t at = ((size_t)fr[i] * B + b) * K + k;
                nw[at] = x[i];
                var[at] = Gfi[i * nf + i];
            }
        }
    for (int i = 0; i < nf; i++) {
        int s = fr[i];
        const double *db = u->src->b + (size_t)s * B * K;
        double *x = nw + (size_t)s * B * K, D = 0, N = 0;
        for (int j = 0; j < B * K; j++) {
            D += (x[j] - db[j]) * (x[j] - db[j]);
            N += var[(size_t)s * B * K + j];
        }
        double c = D > 0 ? fmax(0, 1 - N / D) : 0;
        for (int b = 0; b < B; b++) {
            double mean = 0, row[1024];
            for (int k = 0; k < K; k++) {
                row[k] = db[b * K + k] + c * (x[b * K + k] - db[b * K + k]);
                mean += row[k] / K;
            }
            if (!(mean > 0)) continue;   /* no light of this source anywhere: keep its BRF */
            for (int k = 0; k < K; k++) rows[((size_t)s * B + b) * K + k] = row[k] / mean;
        }
    }
    free(nw);
    return GS_OK;
}

/* The bytes of a capture of P pixels x K frames x B bands (2 B per sample, 1 per HDR map
 * pixel), of S source images of 12 B (unmix, the values' and their sigmas' floats among them) or
 * 4 B (relight) per sample, of F frames of floats, and the per-pixel rest, against the budget;
 * what names them. */
static gs_status transport_budget(const char *file, const char *cmd, int W, int H, int B, int K, int S,
                                  double source_bytes, int F)
{
    double P = (double)W * H, N = P * B;
    double bytes = REC_TRANSPORT_BASE_BYTES + N * K * 2.0 + P * K + S * N * source_bytes + F * N * 4.0 +
                   P * REC_TRANSPORT_BYTES_PER_PIXEL;
    char what[4400];
    snprintf(what, sizeof what, "%s: %s of %d frames of %dx%dx%d samples into %d source images and %d frames "
             "(%.0f MiB and %d B per pixel besides)", file, cmd, K, W, H, B, S, F, REC_TRANSPORT_BASE_BYTES / 1048576,
             REC_TRANSPORT_BYTES_PER_PIXEL);
    return gs_mem_check(bytes, what);
}

gs_status rec_unmix_budget(const char *capdir, const gs_capture *cap, int S, int render)
{
    char file[4200];
    snprintf(file, sizeof file, "%s/capture.json", capdir);
    /* the command's image buffer: one source's K frames (--render) or one image */
    return transport_budget(file, "unmix", cap->width, cap->height, cap->bands, cap->K, S, 12.0,
                            render ? cap->K : 1);
}

gs_status rec_separate_budget(const char *capdir, const gs_capture *cap)
{
    char file[4200];
    snprintf(file, sizeof file, "%s/capture.json", capdir);
    /* the frames' grey values (one float per pixel and frame: K / B frames of B bands), the
     * transmitted and reflected images (two floats per sample), the mean image */
    return transport_budget(file, "separate", cap->width, cap->height, cap->bands, cap->K, 0, 0.0,
                            (cap->K + cap->bands - 1) / cap->bands + 3);
}

gs_status rec_relight_budget(const char *sources_json, const rec_capture_meta *m, int S)
{
    /* the source images (floats), the relit frames, their mean and the capture made of them */
    return transport_budget(sources_json, "relight", m->width, m->height, m->bands, m->K, S, 4.0, m->K + 1);
}

gs_status rec_unmix(const gs_capture *cap, const rec_sources *src, const rec_unmix_opts *o_in,
                    rec_unmix_result *r)
{
    memset(r, 0, sizeof *r);
    rec_unmix_opts od;
    if (!o_in) {
        rec_unmix_opts_default(&od);
        o_in = &od;
    }
    if (!cap || !src || !cap->raw) return gs_fail(GS_EINVAL, "unmix: no capture or sources");
    gs_status st = gs_capture_check(cap, "unmix");
    if (st != GS_OK) return st;
    if (src->bands != cap->bands || src->K != cap->K || src->S < 1 || src->S > SMAX)
        return gs_fail(GS_EINVAL, "unmix: %d sources of %d bands and K = %d for a capture of %d "
                       "bands and K = %d: expected 1..%d sources of the capture's bands and K",
                       src->S, src->bands, src->K, cap->bands, cap->K, SMAX);
    if (o_in->refine < 0 || o_in->refine > 20 || !(o_in->max_error > 0) || !(o_in->max_inflation > 1) ||
        !(o_in->brf_sigma > 0) || !isfinite(o_in->brf_sigma) ||
        !(o_in->max_drift_windows >= 0 || o_in->max_drift_windows == REC_DRIFT_AUTO))
        return gs_fail(GS_EINVAL, "unmix: refine %d (expected 0..20), max_error %g (> 0), "
                       "max_inflation %g (> 1), brf_sigma %g (> 0), max_drift_windows %g (>= 0 or "
                       "REC_DRIFT_AUTO, -1)",
                       o_in->refine, o_in->max_error, o_in->max_inflation, o_in->brf_sigma,
                       o_in->max_drift_windows);
    int W = cap->width, H = cap->height, B = cap->bands, K = cap->K, S = src->S;
    size_t P = (size_t)W * (size_t)H;
    ux u;
    memset(&u, 0, sizeof u);
    u.cap = cap;
    u.src = src;
    u.o = o_in;
    u.W = W;
    u.H = H;
    u.B = B;
    u.K = K;
    u.S = S;
    u.nz = gs_capture_noise(cap);
    r->width = W;
    r->height = H;
    r->bands = B;
    r->S = S;
    r->K = K;
    size_t nb = (size_t)S * B * K;
    u.A = malloc(sizeof *u.A * (size_t)B * K * S);
    u.G0 = calloc((size_t)B * S * S, sizeof *u.G0);
    u.G0inv = calloc((size_t)B * S * S, sizeof *u.G0inv);
    u.v = malloc(sizeof *u.v * (size_t)K * B);
    u.c = malloc(sizeof *u.c * (size_t)K);
    u.use = malloc((size_t)K);
    u.kept = malloc((size_t)K);
    u.act = calloc(P, sizeof *u.act);
    u.fit = calloc(P, sizeof *u.fit);
    u.Gc = malloc(sizeof *u.Gc * (size_t)B * S * S);
    u.Gk = malloc(sizeof *u.Gk * (size_t)B * K * S * S);
    u.kmax = malloc(sizeof *u.kmax * (size_t)K);
    /* within 10 % of the saturation the samples that stayed below it are biased low (censored):
     * they would pass for a flatter BRF peak */
    u.censor_dn = cap->black_level_dn + 0.9 * (cap->saturation_dn - cap->black_level_dn);
    u.hk = malloc(sizeof *u.hk * (size_t)B * K * S);
    r->b = malloc(sizeof *r->b * nb);
    r->tq = malloc(sizeof *r->tq * (size_t)S * P * B);
    r->sigma = malloc(sizeof *r->sigma * (size_t)S * P * B);
    r->state = calloc(P, 1);
    r->residual = malloc(sizeof *r->residual * P);
    if (!u.A || !u.G0 || !u.G0inv || !u.v || !u.c || !u.use || !u.kept || !u.act || !u.fit || !u.Gc || !u.Gk || !u.kmax || !u.hk || !r->b ||
        !r->tq || !r->sigma || !r->state || !r->residual) {
        st = gs_fail(GS_ENOMEM, "unmix: cannot hold %d source images of %d x %d x %d", S, W, H, B);
        goto done;
    }
    memcpy(r->b, src->b, sizeof *r->b * nb);
    u.bcur = r->b;
    u.left_out = rec_frames_left_out(cap, o_in->max_drift_windows, u.kept);
    int rank;
    if ((st = setup_design(&u, r->cond, &rank)) != GS_OK) goto done;
    if (S > K || rank < S) {
        r->ill_posed = 1;
        st = gs_fail(GS_ENUMERIC, "ill-posed: %d sources but QB (the sources' chromaticity times "
                     "BRF over K = %d windows) has rank %d: the data support at most %d sources "
                     "(paper Fig. 10); merge or drop sources", S, K, rank, rank);
        goto done;
    }
    for (int pass = 0; pass <= o_in->refine; pass++) {
        int acc = pass < o_in->refine;
        if (acc) {
            memset(u.nacc, 0, sizeof u.nacc);
            memset(u.Gk, 0, sizeof *u.Gk * (size_t)B * K * S * S);
            memset(u.Gc, 0, sizeof *u.Gc * (size_t)B * S * S);
            memset(u.hk, 0, sizeof *u.hk * (size_t)B * K * S);
        }
        if ((st = eq16_pass(&u, r, pass, acc)) != GS_OK) goto done;
        if (pass == 0) {
            double worst = 0, all = 0, sig[SMAX];
            int ws = 0;
            for (int s = 0; s < S; s++) {
                /* over the pixels with every sample usable, or the partly saturated ones where
                 * they hold most of the source's light */
                int part = u.sig_sum[1][s] > u.sig_sum[0][s];
                sig[s] = u.sig_sum[0][s] + u.sig_sum[1][s];
                all += sig[s];
                r->predicted_error[s] = u.sig_sum[part][s] > 0 ? sqrt(u.var_sum[part][s] / u.sig_sum[part][s]) : INFINITY;
                if (!(r->predicted_error[s] <= worst)) {
                    worst = r->predicted_error[s];
                    ws = s;
                }
            }
            if (!(worst <= o_in->max_error)) {
                r->ill_posed = 1;
                double cmax = 0;
                for (int b = 0; b < B; b++)
                    if (r->cond[b] > cmax) cmax = r->cond[b];
                /* its share of the fitted light tells a source without light (not in the scene,
                 * or at another phase) from sources the data cannot tell apart */
                char why[160] = "";
                double kept_drift = 0.0;   /* (the largest of the frames kept) */
                for (int k = 0; k < K; k++)
                    if (u.kept[k]) kept_drift = fmax(kept_drift, gs_capture_frame_drift(cap, k));
                if (u.left_out)
                    snprintf(why, sizeof why, "; %d of %d frames left out, their windows drifted over %g windows "
                             "(free running, --max-drift-windows)", u.left_out, K,
                             rec_drift_limit(o_in->max_drift_windows, cap->window_period));
                else if (kept_drift > 0.0)
                    snprintf(why, sizeof why, "; free running, the frames' windows drifted up to %.3g windows, "
                             "their noise not raised (--max-drift-windows)", kept_drift);
                st = gs_fail(GS_ENUMERIC, "ill-posed: source %02d (%s at %g deg) would be %.3g %% "
                             "noise (predicted relative error %.3g > %g; QB's condition number "
                             "%.3g; its image holds %.2g %% of the fitted images' energy%s): the data do not support %d "
                             "sources (paper Fig. 10)",
                             ws, src->bulb[ws], src->phase_deg[ws], 100 * worst, worst,
                             o_in->max_error, cmax, all > 0 ? 100 * sig[ws] / all : 0.0, why, S);
                goto done;
            }
        }
        if (acc) {
            if ((st = eq18(&u)) != GS_OK) goto done;
            int rk;
            double cnd[GS_MAX_BANDS];
            if ((st = setup_design(&u, cnd, &rk)) != GS_OK) goto done;
            if (rk < S) {
                st = gs_fail(GS_ENUMERIC, "unmix: the refined B (Eq. 18) lost rank: use --refine 0");
                goto done;
            }
        }
    }
    for (size_t p = 0; p < P; p++) {
        r->partial_px += r->state[p] == REC_UNMIX_PARTIAL;
        r->unknown_px += r->state[p] == REC_UNMIX_UNKNOWN;
        for (int s = 0; s < S; s++) r->unknown_values += !(u.act[p] >> s & 1u);
    }
    r->rms_residual = u.dof > 0 ? sqrt(u.chi2 / u.dof) : NAN;
    if (o_in->progress) o_in->progress(o_in->progress_ctx, 1.0);
done:
    free(u.A);
    free(u.G0);
    free(u.G0inv);
    free(u.v);
    free(u.c);
    free(u.use);
    free(u.kept);
    free(u.act);
    free(u.fit);
    free(u.Gc);
    free(u.Gk);
    free(u.kmax);
    free(u.hk);
    if (st != GS_OK) {
        free(r->tq);
        free(r->sigma);
        free(r->residual);
        r->tq = NULL;
        r->sigma = NULL;
        r->residual = NULL;
    }
    return st;
}

gs_status rec_render_source(const rec_unmix_result *r, int s, float *out)
{
    if (!r || !r->tq || s < 0 || s >= r->S || !out)
        return gs_fail(GS_EINVAL, "render: source %d of %d", s, r ? r->S : 0);
    size_t P = (size_t)r->width * (size_t)r->height;
    int B = r->bands, K = r->K;
    const float *tq = r->tq + (size_t)s * P * B;
    for (int k = 0; k < K; k++)
        for (size_t p = 0; p < P; p++)
            for (int b = 0; b < B; b++)
                out[((size_t)k * P + p) * B + b] =
                    tq[p * B + b] * (float)r->b[((size_t)s * B + b) * K + k];
    return GS_OK;
}
