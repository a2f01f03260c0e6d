/* eq7_light.c - Eq. 7 for one light (rec_match_light, rec_match_catalog): the scores of every
 * template in double, the continuous-phase refinement, the flags and the answer. */
#include "recognize/internal.h"

#include <cblas.h>
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <fftw3.h>

/* ------------------------------------------------------------ one light */

/* chi2(s) of continuous bulb b with the scale(s) profiled (a >= 0), and its derivatives. */
typedef struct {
    double chi2, d1, d2;     /* chi2 and its first two derivatives in s */
    int nf;                  /* brightness parameters */
    double S[GS_MAX_BANDS], T[GS_MAX_BANDS];   /* sum w x t, sum w t^2 (per band with gains) */
} chi2_eval;

static void chi2_at(const rec_matcher *m, rec_eq7_work *w, size_t b, double s, double Sxx, chi2_eval *e)
{
    size_t K = (size_t)m->K;
    int nf = m->nfit;
    size_t span = m->bg ? K : (size_t)m->D;   /* samples of one brightness parameter */
    rec_eq7_template_at(m, b, s, w->tt, w->dt, w->d2t, w->acc);
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
double rec_eq7_loglik(double Sxx, double S, double T)
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
    if (nf == 1) return rec_eq7_loglik(Sxx, S[0], T[0]);
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

/* The reddened band model (recognize.h) for bulb b's per-band sums S_b = sum w x t, T_b =
 * sum w t^2 (templates of mean 1 per band): the per-band estimates a_b = S_b/T_b (variance
 * 1/T_b) are explained by a c_b(tau), c_b = Q_b exp(-tau f_b), each band free within the
 * tolerance t: a_b ~ N(a c_b, (t a c_b)^2) marginalised exactly,
 *   log p = -R/2 - sum_b log(1 + s_b^2 T_b)/2 - (sum v a_b^2 - B^2/A)/2 - log(A)/2 + log Phi(B/sqrt(A)),
 * R = Sxx - sum_b S_b^2/T_b, s_b = t a c_b, v_b = 1/(1/T_b + s_b^2), A = sum v c^2, B = sum v c a_b
 * (a marginalised over a > 0 with a flat prior, s_b from the plug-in a), then averaged over a
 * prior on tau over REC_TAU_N points of [REC_TAU_LO, REC_TAU_HI] (c_b tabulated per bulb in
 * m->red_c): uniform, or the light's population prior w->tau_logprior (eq7_population.c). With
 * t -> 0 and tau = 0 this is the paper's one brightness times Q_b. fit (may be NULL) gets the
 * most probable tau's numbers; ll_acc (may be NULL) accumulates exp(L(tau) + ll_logw), the prior
 * left out, per tau. */
typedef struct {
    double chi2;                 /* R + sum v (a_b - a c_b)^2 at the best tau */
    double a, tau, z;            /* the brightness, optical depth and a / sigma_a there */
    double band[GS_MAX_BANDS];   /* each band's brightness: the posterior mean of a_b */
} red_fit;

static double loglik_red(const rec_matcher *m, const rec_eq7_work *w, int bulb, double Sxx,
                         const double *S, const double *T, red_fit *fit, double *ll_acc,
                         double ll_logw)
{
    double tol = w->chroma_tol > 0.0 ? w->chroma_tol : m->o.chroma_tolerance;
    double R = Sxx, ah[GS_MAX_BANDS];
    int nb = m->bands, any = 0;
    for (int b = 0; b < nb; b++) {
        ah[b] = T[b] > 0.0 ? S[b] / T[b] : 0.0;
        if (T[b] > 0.0) {
            R -= S[b] * ah[b];
            any = 1;
        }
    }
    if (!any) return -INFINITY;
    if (R < 0.0) R = 0.0;
    /* the three rounds of s_b from the current brightness, for every tau at once: the taus are
     * independent, so the divisions of one overlap the others' (each tau's numbers are the same
     * operations in the same order as one tau alone). occ1 = prod_b (1 + s_b^2 T_b) - 1: the
     * occupation term sum_b log(1 + s_b^2 T_b) is log1p(occ1), one logarithm for the bands (and
     * with log A, one for both); only the last round's is used. A tau whose A is not > 0 in some
     * round has no likelihood. */
    const double *cb = m->red_c + (size_t)bulb * REC_TAU_N * (size_t)nb;
    double av[REC_TAU_N] = {0}, Av[REC_TAU_N], Bv[REC_TAU_N], Cv[REC_TAU_N], occv[REC_TAU_N];
    unsigned char dead[REC_TAU_N] = {0};
    for (int it = 0; it < 3; it++) {
        int first = 1;   /* the sums start at 0 (+0 + x, as a zeroed sum would) */
        for (int b = 0; b < nb; b++) {
            if (!(T[b] > 0.0)) continue;
            double Tb = T[b], iT = 1.0 / Tb, ab = ah[b];
            for (int i = 0; i < REC_TAU_N; i++) {
                double c = cb[(size_t)i * (size_t)nb + (size_t)b], a = av[i] > 0.0 ? av[i] : 0.0;
                double sb = tol * a * c, x = sb * sb * Tb, v = 1.0 / (iT + sb * sb);
                double A0 = first ? 0.0 : Av[i], B0 = first ? 0.0 : Bv[i], C0 = first ? 0.0 : Cv[i],
                       o0 = first ? 0.0 : occv[i];
                Av[i] = A0 + v * c * c;
                Bv[i] = B0 + v * c * ab;
                Cv[i] = C0 + v * ab * ab;
                occv[i] = o0 + (x + o0 * x);
            }
            first = 0;
        }
        for (int i = 0; i < REC_TAU_N; i++) {
            dead[i] |= !(Av[i] > 0.0);
            if (!dead[i]) av[i] = Bv[i] / Av[i];
        }
    }
    double Lt[REC_TAU_N], Lmax = -INFINITY;
    for (int i = 0; i < REC_TAU_N; i++) {
        double tau = rec_eq7_tau(i);
        const double *c = cb + (size_t)i * (size_t)nb;
        double a = av[i], A = Av[i], B = Bv[i], C = Cv[i], occ1 = occv[i];
        if (dead[i]) {
            Lt[i] = -INFINITY;
            continue;
        }
        double between = C - B * B / A;
        if (between < 0.0) between = 0.0;
        double z = B / sqrt(A);
        Lt[i] = -0.5 * (R + between) - 0.5 * log(A + A * occ1) + gs_log_phi(z);
        if (ll_acc) ll_acc[i] = rec_log_add(ll_acc[i], Lt[i] + ll_logw);
        if (w->has_tau_prior) Lt[i] += w->tau_logprior[i] + log((double)REC_TAU_N);
        if (Lt[i] > Lmax) {
            Lmax = Lt[i];
            if (fit) {
                fit->chi2 = R + between;
                fit->a = a > 0.0 ? a : 0.0;
                fit->tau = tau;
                fit->z = z > 0.0 ? z : 0.0;
                for (int b = 0; b < nb; b++) {
                    double sb = tol * fit->a * c[b];
                    /* posterior mean of a_b: data a_b (weight T_b) and prior a c_b (1/s_b^2) */
                    fit->band[b] = T[b] > 0.0 ? (sb > 0.0 ? (T[b] * ah[b] + fit->a * c[b] / (sb * sb)) /
                                                              (T[b] + 1.0 / (sb * sb))
                                                          : fit->a * c[b])
                                              : 0.0;
                    if (fit->band[b] < 0.0) fit->band[b] = 0.0;
                }
            }
        }
    }
    if (!isfinite(Lmax)) return -INFINITY;
    double sum = 0.0;
    for (int i = 0; i < REC_TAU_N; i++) sum += rec_exp_neg(Lt[i] - Lmax);
    return Lmax + log(sum / REC_TAU_N);
}

double rec_eq7_band_misfit(const rec_matcher *m, int bulb, const double *S, const double *T, double tol)
{
    rec_eq7_work w;
    memset(&w, 0, sizeof w);   /* only the tau prior (none) and the tolerance are read */
    w.chroma_tol = tol;
    double Sxx = 0.0;   /* = sum S^2/T: no residual within the bands, the fit's chi2 is the misfit */
    for (int b = 0; b < m->bands; b++)
        if (T[b] > 0.0) Sxx += S[b] * S[b] / T[b];
    red_fit rf;
    if (!isfinite(loglik_red(m, &w, bulb, Sxx, S, T, &rf, NULL, 0.0))) return INFINITY;
    return rf.chi2;
}

/* The log likelihood of bulb b's sums under the matcher's band model. */
static double loglik_bulb(const rec_matcher *m, const rec_eq7_work *w, int b, double Sxx,
                          const double *S, const double *T)
{
    return m->red ? loglik_red(m, w, b, Sxx, S, T, NULL, NULL, 0.0) : loglik_n(m->nfit, Sxx, S, T);
}

/* The sums of template j from the rec_eq7_work arrays ([f * M + j]). */
static void sums_of(const rec_matcher *m, const rec_eq7_work *w, size_t j, double *S, double *T)
{
    for (int f = 0; f < m->nfit; f++) {
        S[f] = w->S[(size_t)f * m->M + j];
        T[f] = w->T[(size_t)f * m->M + j];
    }
}

/* An upper bound of loglik_red for bulb b's sums: with v_b = T_b / (1 + s_b^2 T_b) <= T_b the
 * occupation term is sum_b log(v_b / T_b) / 2 <= 0 and A = sum v c^2 >= v_k c_k^2 for any used
 * band k, so -log(A)/2 - occ/2 <= -log(c_k^2 T_k)/2; between >= 0 and log Phi <= 0; c_k(tau) is
 * at least the bulb's smallest tabulated c_k (cmin); the tau prior adds at most its largest
 * log weight (lp_max). Every tau's L(tau) obeys it, so their prior-weighted mean does. */
static double red_bound(const rec_matcher *m, double Sxx, const double *S, const double *T,
                        const double *cmin, double lp_max)
{
    double R = Sxx, best = -INFINITY;
    for (int b = 0; b < m->bands; b++) {
        if (!(T[b] > 0.0)) continue;
        R -= S[b] * (S[b] / T[b]);
        double l = log(cmin[b] * cmin[b] * T[b]);
        if (l > best) best = l;
    }
    if (!isfinite(best)) return -INFINITY;
    if (R < 0.0) R = 0.0;
    double u = -0.5 * R - 0.5 * best + lp_max;
    return u + 1e-9 * (1.0 + fabs(u));   /* rounding slack: a bound in floating point too */
}

/* The reddened model's log likelihood of template j into w->L[j] (its tau terms into tau_ll
 * when collecting); returns it. */
static double red_exact(const rec_matcher *m, rec_eq7_work *w, size_t j, double Sxx)
{
    double Sv[GS_MAX_BANDS], Tv[GS_MAX_BANDS];
    sums_of(m, w, j, Sv, Tv);
    int b = m->tbulb[j];   /* every bulb weighs the same, whatever its phase grid */
    w->L[j] = loglik_red(m, w, b, Sxx, Sv, Tv, NULL, w->collect_tau ? w->tau_ll : NULL,
                         -log((double)m->count[b]));
    return w->L[j];
}

/* w->L of every template under the reddened model, exactly wherever it can matter and -inf
 * elsewhere (a bound-based screen; returns the largest L). Exact: every template whose bound
 * reaches within CUT_PIXEL of a computed L (the rest carry < e^-30 of the best's mass each: the
 * posterior to ~M e^-30, runner-ups below that may differ), each bulb's best template (the
 * runner-up's ranking), and every template that can be among the REC_NESTED_FIRST + 1 largest
 * L (the blend search's first templates). The bounds go in w->mass (rec_eq7_decide rewrites
 * it). */
static double red_screen(const rec_matcher *m, rec_eq7_work *w, double Sxx)
{
    size_t M = m->M;
    double *U = w->mass, lp_max = 0.0, Sv[GS_MAX_BANDS], Tv[GS_MAX_BANDS];
    if (w->has_tau_prior) {
        lp_max = -INFINITY;
        for (int i = 0; i < REC_TAU_N; i++) lp_max = fmax(lp_max, w->tau_logprior[i]);
        lp_max += log((double)REC_TAU_N);
    }
    size_t jbest = 0;
    for (size_t b = 0; b < m->nb; b++) {
        double cmin[GS_MAX_BANDS];
        for (int band = 0; band < m->bands; band++) {
            cmin[band] = INFINITY;
            for (int i = 0; i < REC_TAU_N; i++)
                cmin[band] = fmin(cmin[band], m->red_c[(b * REC_TAU_N + (size_t)i) * (size_t)m->bands + (size_t)band]);
        }
        for (size_t j = m->first[b]; j < m->first[b] + m->count[b]; j++) {
            sums_of(m, w, j, Sv, Tv);
            U[j] = red_bound(m, Sxx, Sv, Tv, cmin, lp_max);
            w->L[j] = NAN;   /* not computed */
            if (U[j] > U[jbest]) jbest = j;
        }
    }
    double lo = red_exact(m, w, jbest, Sxx);   /* Lmax >= lo */
    for (size_t b = 0; b < m->nb; b++) {
        size_t j0 = m->first[b], n = m->count[b], jb = j0;
        for (size_t j = j0; j < j0 + n; j++)
            if (U[j] > U[jb]) jb = j;
        double lb = isnan(w->L[jb]) ? red_exact(m, w, jb, Sxx) : w->L[jb];
        for (size_t j = j0; j < j0 + n; j++)
            if (isnan(w->L[j]) && (U[j] >= lo - CUT_PIXEL || U[j] >= lb)) red_exact(m, w, j, Sxx);
        for (size_t j = j0; j < j0 + n; j++)
            if (w->L[j] > lo) lo = w->L[j];
    }
    /* the REC_NESTED_FIRST + 1 largest computed L: a template whose bound is below the least of
     * them cannot be among them */
    double top[REC_NESTED_FIRST + 1];
    int nt = 0;
    for (size_t j = 0; j < M; j++) {
        double l = w->L[j];
        if (!isfinite(l) || (nt == REC_NESTED_FIRST + 1 && !(l > top[nt - 1]))) continue;
        int q = nt < REC_NESTED_FIRST + 1 ? nt++ : nt - 1;
        while (q > 0 && l > top[q - 1]) {
            top[q] = top[q - 1];
            q--;
        }
        top[q] = l;
    }
    double th = nt == REC_NESTED_FIRST + 1 ? top[nt - 1] : -INFINITY;
    double Lmax = -INFINITY;
    for (size_t j = 0; j < M; j++) {
        if (isnan(w->L[j])) w->L[j] = U[j] >= th ? red_exact(m, w, j, Sxx) : -INFINITY;
        if (w->L[j] > Lmax) Lmax = w->L[j];
    }
    return Lmax;
}

/* The light's K-point DFTs of wx and w per band into w->spec + nh (X, then W; [band * K + r]),
 * conjugated: conj(sum_k v_k e^{2 pi i r k / K}). */
void rec_eq7_light_dfts(const rec_matcher *m, rec_eq7_work *w)
{
    size_t K = (size_t)m->K, nh = (size_t)m->G / 2 + 1, D = (size_t)m->D;
    double complex *X = w->spec + nh, *W = X + D;
    for (int band = 0; band < m->bands; band++)
        for (size_t r = 0; r < K; r++) {
            double complex x = 0.0, v = 0.0;
            size_t rk = 0;   /* r k mod K */
            for (size_t k = 0; k < K; k++) {
                size_t d = (size_t)band * K + k;
                x += w->wx[d] * m->wk[rk];
                v += w->w[d] * m->wk[rk];
                rk += r;
                if (rk >= K) rk -= K;
            }
            X[(size_t)band * K + r] = conj(x);
            W[(size_t)band * K + r] = conj(v);
        }
}

void rec_eq7_grid_sums(const rec_matcher *m, rec_eq7_work *w, size_t b)
{
    size_t K = (size_t)m->K, nh = (size_t)m->G / 2 + 1, D = (size_t)m->D, M = m->M;
    const double complex *X = w->spec + nh, *W = X + D;
    int nf = m->nfit;
    for (int f = 0; f < nf; f++)
        for (int sq = 0; sq < 2; sq++) {
            /* the cross-spectrum of the parameter's bands (all of them with one gain) */
            int b0 = nf == 1 ? 0 : f, b1 = nf == 1 ? m->bands : f + 1;
            for (size_t r = 0, rk = 0; r < nh; r++) {
                double complex z = 0.0;
                for (int band = b0; band < b1; band++) {
                    size_t o = (b * (size_t)m->bands + (size_t)band) * nh + r;
                    z += sq ? m->bhat[o] * W[(size_t)band * K + rk] : m->ahat[o] * X[(size_t)band * K + rk];
                }
                w->spec[r] = z;
                if (++rk == K) rk = 0;
            }
            fftw_execute_dft_c2r((fftw_plan)m->c2r, (fftw_complex *)w->spec, w->grid);
            double *dst = (sq ? w->T : w->S) + (size_t)f * M + m->first[b];
            memcpy(dst, w->grid, sizeof *dst * (size_t)m->G);
        }
}

/* Refine continuous bulb b around its best grid cell j0: safeguarded Newton on the exact chi2(s)
 * within +-1 cell, then the peak's log likelihood and std. */
void rec_eq7_refine_peak(const rec_matcher *m, rec_eq7_work *w, size_t b, size_t j0, double Sxx)
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
    double Lp = loglik_bulb(m, w, (int)b, Sxx, e.S, e.T);
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

void rec_eq7_no_answer(rec_match *out, unsigned flags)
{
    memset(out, 0, sizeof *out);
    out->bulb = -1;
    out->runner_bulb = -1;
    out->shape_p_value = out->blend_p_value = 1.0;
    out->blend_bulb[0] = out->blend_bulb[1] = -1;
    out->flags = flags | REC_MATCH_BULB_AMBIGUOUS | REC_MATCH_PHASE_AMBIGUOUS;
}

/* The excess e2 of a fit (rec_eq7_excess): residuals r^2, camera variances s2 and band levels
 * mu2 of the n usable samples (units of c), dof. chi2(e2) = sum r^2 / (s2 + e2 mu2) falls
 * monotonically: bisection. */
static double excess_e2(const double *r2, const double *s2, const double *mu2, size_t n, int dof)
{
    double chi0 = 0.0, mmax = 0.0;
    for (size_t d = 0; d < n; d++) {
        chi0 += r2[d] / s2[d];
        if (mu2[d] / s2[d] > mmax) mmax = mu2[d] / s2[d];
    }
    if (!(chi0 > dof) || !(mmax > 0.0)) return 0.0;
    double lo = 0.0, hi = 1.0 / mmax;
    for (int it = 0; it < 200; it++) {
        double c = 0.0;
        for (size_t d = 0; d < n; d++) c += r2[d] / (s2[d] + hi * mu2[d]);
        if (c < dof || hi > 1e6) break;
        hi *= 4.0;
    }
    for (int it = 0; it < 60; it++) {
        double mid = 0.5 * (lo + hi), c = 0.0;
        for (size_t d = 0; d < n; d++) c += r2[d] / (s2[d] + mid * mu2[d]);
        if (c > dof) lo = mid;
        else hi = mid;
    }
    return 0.5 * (lo + hi);
}

/* Template j (or continuous bulb b at shift s, with its derivative in s when dt is not NULL)
 * into t, and its brightness per parameter a_f = S_f/T_f >= 0 from the light's weights. */
static void model_of(const rec_matcher *m, rec_eq7_work *w, int b, size_t j, double s, double *t,
                     double *dt, double *a_f)
{
    size_t D = (size_t)m->D, span = D / (size_t)m->nfit;
    if (m->cont[b]) rec_eq7_template_at(m, (size_t)b, s, t, dt, w->d2t, w->acc);
    else memcpy(t, m->t + j * D, sizeof *t * D);
    for (int f = 0; f < m->nfit; f++) {
        double S = 0.0, T = 0.0;
        for (size_t d = (size_t)f * span; d < (size_t)(f + 1) * span; d++) {
            S += w->wx[d] * t[d];
            T += w->w[d] * t[d] * t[d];
        }
        a_f[f] = (T > 0.0 && S > 0.0) ? S / T : 0.0;
    }
}

/* The excess noise is one flux factor per frame, common to the bands (scintillation is nearly
 * achromatic): the covariance of frame k is Sigma_k = diag(s^2) + e^2 u_k u_k^T (u the fitted
 * model), while the scores weigh the samples independently, w_d = 1/(s_d^2 + e^2 mu_b^2). For
 * that composite likelihood (Chandler & Bate 2007) the information along a direction Delta of
 * the model is H = Delta' W Delta but the score's variance J = Delta' W Sigma W Delta: kappa =
 * H/J (<= 1 kept) tempers the log likelihood so that posteriors and phase sigmas are calibrated.
 * phi = n tr((W Sigma)^2) / tr(W Sigma)^2 >= 1 inflates the variance of chi2 (Satterthwaite:
 * chi2 ~ phi chi2(dof/phi)). u, delta in units of c, s2 the camera variances. */
static void excess_correlation(const rec_matcher *m, const rec_eq7_work *w, const double *sigma,
                               double c, double fe, const double *u, const double *delta,
                               double *kappa, double *phi)
{
    size_t K = (size_t)m->K;
    double e2 = fe * fe, H = 0.0, J = 0.0, trB = 0.0, trB2 = 0.0;
    int n = 0;
    for (size_t k = 0; k < K; k++) {
        double wdu = 0.0, wu2[GS_MAX_BANDS] = {0};
        for (int b = 0; b < m->bands; b++) {
            size_t d = (size_t)b * K + k;
            double wd = w->w[d];
            if (!(wd > 0.0)) continue;
            double s2 = (sigma[d] / c) * (sigma[d] / c), v = s2 + e2 * u[d] * u[d];
            if (delta) {
                H += wd * delta[d] * delta[d];
                J += wd * delta[d] * wd * delta[d] * s2;
                wdu += wd * delta[d] * u[d];
            }
            trB += wd * v;
            trB2 += wd * v * wd * v;
            wu2[b] = wd * u[d] * u[d];
            n++;
        }
        J += e2 * wdu * wdu;
        for (int b = 0; b < m->bands; b++)
            for (int b2 = 0; b2 < m->bands; b2++)
                if (b2 != b) trB2 += e2 * e2 * wu2[b] * wu2[b2];
    }
    *kappa = (delta && H > 0.0 && J > H) ? H / J : 1.0;
    if (*kappa < 1e-3) *kappa = 1e-3;
    *phi = trB > 0.0 ? n * trB2 / (trB * trB) : 1.0;
    if (!(*phi >= 1.0)) *phi = 1.0;
}

/* Temper every score by kappa about Lmax (excess_correlation): L -> Lmax + kappa (L - Lmax),
 * the continuous peaks' widths by 1/sqrt(kappa). */
static void temper(const rec_matcher *m, rec_eq7_work *w, double Lmax, double kappa)
{
    for (size_t j = 0; j < m->M; j++)
        if (isfinite(w->L[j])) w->L[j] = Lmax + kappa * (w->L[j] - Lmax);
    for (size_t b = 0; b < m->nb; b++) {
        if (!m->cont[b] || !isfinite(w->peak_L[b])) continue;
        w->peak_L[b] = Lmax + kappa * (w->peak_L[b] - Lmax);
        w->peak_sig[b] /= sqrt(kappa);
        if (w->peak_sig[b] > INV_SQRT12) w->peak_sig[b] = INV_SQRT12;
    }
}

/* The light's own flat share with template t (the answer's): per brightness parameter the
 * weighted least squares of x = a t + beta m (m the template's band means), phi = beta / a with
 * its delta-method variance, combined over the parameters by inverse variance; w->fit_flat_var
 * inf when the template cannot tell the two apart (a near-flat BRF) or a is not positive. */
static void flat_share_of(const rec_matcher *m, rec_eq7_work *w, const double *t)
{
    size_t K = (size_t)m->K, D = (size_t)m->D, span = D / (size_t)m->nfit;
    double mb[GS_MAX_BANDS], num = 0.0, info = 0.0;
    for (int band = 0; band < m->bands; band++) {
        double sum = 0.0;
        for (size_t k = 0; k < K; k++) sum += t[(size_t)band * K + k];
        mb[band] = sum / (double)K;
    }
    for (int f = 0; f < m->nfit; f++) {
        double A11 = 0, A12 = 0, A22 = 0, b1 = 0, b2 = 0;
        for (size_t d = (size_t)f * span; d < (size_t)(f + 1) * span; d++) {
            double u = mb[d / K];
            A11 += w->w[d] * t[d] * t[d];
            A12 += w->w[d] * t[d] * u;
            A22 += w->w[d] * u * u;
            b1 += w->wx[d] * t[d];
            b2 += w->wx[d] * u;
        }
        double det = A11 * A22 - A12 * A12;
        if (!(det > 1e-12 * A11 * A22)) continue;
        double a = (A22 * b1 - A12 * b2) / det, beta = (A11 * b2 - A12 * b1) / det;
        if (!(a > 0.0)) continue;
        double phi = beta / a;
        double var = (A11 + 2.0 * phi * A12 + phi * phi * A22) / det / (a * a);
        if (!(var > 0.0) || !isfinite(var)) continue;
        num += phi / var;
        info += 1.0 / var;
    }
    w->fit_flat = info > 0.0 ? num / info : 0.0;
    w->fit_flat_var = info > 0.0 ? 1.0 / info : INFINITY;
}

gs_status rec_eq7_match_light_ws(const rec_matcher *m, rec_eq7_work *w, const double *signal,
                                 const double *sigma, double fe, rec_match *out,
                                 rec_eq7_excess *excess)
{
    size_t D = (size_t)m->D, M = m->M;
    unsigned flags = 0;
    if (excess) excess->valid = 0;
    w->fit_bulb = -1;
    w->other_lbf = NAN;
    w->fit_flat_var = INFINITY;
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
    /* the band levels: mu_b^2 = mean(x^2 - sigma^2) over the band's usable samples (>= 0), in
     * units of c. A multiplicative excess e per sample adds (e mu_b)^2 to each sample's variance:
     * on average over the band exactly the variance it causes (E chi2 = dof), spread evenly over
     * the K windows. */
    double mu2[GS_MAX_BANDS] = {0.0, 0.0, 0.0};
    {
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
            mu2[band] = (n > 0 && sum > 0.0 && isfinite(sum)) ? sum / n : 0.0;
        }
    }
    /* the flat share (rec_eq7_opts.flat_share): x = a (t + phi m) has band means a m_b (1 + phi),
     * so the flat part is phi / (1 + phi) of each band's mean, whatever the template */
    double flat_b[GS_MAX_BANDS] = {0.0, 0.0, 0.0};
    if (w->flat > 0.0) {
        size_t K = (size_t)m->K;
        for (int band = 0; band < m->bands; band++) {
            double sum = 0.0;
            int n = 0;
            for (size_t d = (size_t)band * K; d < (size_t)(band + 1) * K; d++)
                if (isfinite(signal[d]) && isfinite(sigma[d]) && sigma[d] > 0.0) sum += signal[d] / c, n++;
            flat_b[band] = n > 0 ? w->flat / (1.0 + w->flat) * sum / n : 0.0;
        }
    }
    for (size_t d = 0; d < D; d++) {
        double x = signal[d], s = sigma[d];
        w->w[d] = w->wx[d] = w->xs[d] = 0.0;
        if (!isfinite(x) || !isfinite(s) || !(s > 0.0)) continue;
        double ws = 1.0 / ((s / c) * (s / c) + fe * fe * mu2[d / (size_t)m->K]),
               xs = x / c - flat_b[d / (size_t)m->K];
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
        rec_eq7_no_answer(out, flags | REC_MATCH_BAD_INPUT);
        return GS_OK;
    }
    double Sxx = 0.0;
    for (size_t d = 0; d < D; d++) Sxx += w->wx[d] * w->xs[d];
    if (!isfinite(Sxx)) {
        rec_eq7_no_answer(out, flags | REC_MATCH_BAD_INPUT);
        return GS_OK;
    }
    /* all templates: S = T_mat wx, T = T_sq w (per band with band gains) */
    double Lmax = -INFINITY;
    /* the sums of every template (blocks of rows: continuous bulbs from the Fourier form, the
     * rest as matrix-vector products); one block of all M rows without the Fourier form */
    int fourier = m->fourier && !m->exhaustive;
    if (fourier) rec_eq7_light_dfts(m, w);
    for (size_t b = 0; b < (fourier ? m->nb : 1); b++) {
        if (fourier && m->cont[b]) {
            rec_eq7_grid_sums(m, w, b);
            continue;
        }
        size_t j0 = fourier ? m->first[b] : 0, n = fourier ? m->count[b] : M;
        size_t span = m->bg ? (size_t)m->K : D;
        for (int f = 0; f < m->nfit; f++) {
            size_t o = (size_t)f * span;
            cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)n, (int)span, 1.0, m->t + j0 * D + o, (int)D,
                        w->wx + o, 1, 0.0, w->S + (size_t)f * M + j0, 1);
            cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)n, (int)span, 1.0, m->tsq + j0 * D + o, (int)D,
                        w->w + o, 1, 0.0, w->T + (size_t)f * M + j0, 1);
        }
    }
    if (!m->bg) {
        for (size_t j = 0; j < M; j++) {
            w->L[j] = rec_eq7_loglik(Sxx, w->S[j], w->T[j]);
            if (w->L[j] > Lmax) Lmax = w->L[j];
        }
    } else {
        double Sv[GS_MAX_BANDS], Tv[GS_MAX_BANDS];
        if (w->collect_tau)
            for (int i = 0; i < REC_TAU_N; i++) w->tau_ll[i] = -INFINITY;
        if (m->red && !m->exhaustive) {
            Lmax = red_screen(m, w, Sxx);
        } else {
            for (size_t j = 0; j < M; j++) {
                sums_of(m, w, j, Sv, Tv);
                w->L[j] = m->red ? red_exact(m, w, j, Sxx) : loglik_n(m->nfit, Sxx, Sv, Tv);
                if (w->L[j] > Lmax) Lmax = w->L[j];
            }
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
        rec_eq7_refine_peak(m, w, b, jb, Sxx);
    }
    for (size_t b = 0; b < m->nb; b++)
        if (m->cont[b] && w->peak_L[b] > Lmax) Lmax = w->peak_L[b];
    w->ncand = 0;
    for (size_t j = 0; j < M; j++)
        rec_eq7_add_cand(m, w, j);   /* every pair counts for one light */
    rec_eq7_decision dec;
    rec_eq7_decide(m, w, Lmax, &dec);
    double kappa = 1.0, phi = 1.0;
    if (fe > 0.0 && dec.bulb >= 0) {
        /* the excess's correlation along the decision's direction: the best pair's phase
         * derivative (continuous), else the best model minus the runner-up's */
        double a1[GS_MAX_BANDS], a2[GS_MAX_BANDS];
        size_t span = D / (size_t)m->nfit;
        int cont = m->cont[dec.bulb], have = cont || dec.runner_bulb >= 0;
        model_of(m, w, dec.bulb, dec.tmpl, dec.shift, w->tt, cont ? w->dt : NULL, a1);
        if (!cont && have) model_of(m, w, dec.runner_bulb, dec.runner_tmpl, dec.runner_shift, w->tr, NULL, a2);
        for (size_t d = 0; d < D; d++) {
            double u = a1[d / span] * w->tt[d];
            w->r2[d] = cont ? a1[d / span] * w->dt[d] : u - (have ? a2[d / span] * w->tr[d] : 0.0);
            w->tt[d] = u;
        }
        excess_correlation(m, w, sigma, c, fe, w->tt, have ? w->r2 : NULL, &kappa, &phi);
        if (kappa < 1.0) {
            temper(m, w, Lmax, kappa);
            for (size_t j = 0; j < M; j++) rec_eq7_add_cand(m, w, j);   /* decide consumed them */
            rec_eq7_decide(m, w, Lmax, &dec);
        }
    }
    if (dec.bulb < 0) {
        rec_eq7_no_answer(out, flags | REC_MATCH_BAD_INPUT);
        return GS_OK;
    }
    /* the fit of the best pair: exact template at its shift */
    int bb = dec.bulb;
    const double *tb;
    if (m->cont[bb]) {
        rec_eq7_template_at(m, (size_t)bb, dec.shift, w->tt, NULL, NULL, w->acc);
        tb = w->tt;
    } else {
        tb = m->t + dec.tmpl * D;
    }
    /* the brightness per brightness parameter: a_f = S_f/T_f >= 0, or the reddened model's */
    int nf = m->nfit, nfree = 0;
    size_t span = D / (size_t)nf;
    double a_f[GS_MAX_BANDS] = {0}, Sv[GS_MAX_BANDS] = {0}, Tv[GS_MAX_BANDS] = {0};
    for (int f = 0; f < nf; f++) {
        double S = 0.0, T = 0.0;
        for (size_t d = (size_t)f * span; d < (size_t)(f + 1) * span; d++) {
            S += w->wx[d] * tb[d];
            T += w->w[d] * tb[d] * tb[d];
        }
        Sv[f] = S;
        Tv[f] = T;
        a_f[f] = (T > 0.0 && S > 0.0) ? S / T : 0.0;
        nfree += T > 0.0;
    }
    double snr;
    red_fit rf;
    w->fit_bulb = bb;
    memcpy(w->fit_S, Sv, sizeof w->fit_S);
    memcpy(w->fit_T, Tv, sizeof w->fit_T);
    if (m->red) {
        loglik_red(m, w, bb, Sxx, Sv, Tv, &rf, NULL, 0.0);
        for (int f = 0; f < nf; f++) a_f[f] = rf.band[f];
        snr = rf.z;
        nfree = 2;   /* brightness and optical depth */
    } else {
        /* a / sigma_a (one gain: a sqrt(T), sigma_a = 1/sqrt(T)) */
        snr = nf == 1 ? (Tv[0] > 0.0 ? a_f[0] * sqrt(Tv[0]) : 0.0) : snr_n(nf, Sv, Tv);
    }
    w->fit_z = snr;
    flat_share_of(m, w, tb);
    double a_sum = 0.0, chi2 = 0.0;
    for (int f = 0; f < nf; f++) {
        a_sum += a_f[f];
        for (size_t d = (size_t)f * span; d < (size_t)(f + 1) * span; d++) {
            double r = w->xs[d] - a_f[f] * tb[d];
            chi2 += w->w[d] * r * r;
        }
    }
    if (m->red) chi2 = rf.chi2;   /* the residual with the prior's share (recognize.h) */
    int npar = nfree + 1;   /* brightness(es) and phase */
    if (nf == 1) npar = 2;
    memset(out, 0, sizeof *out);
    out->brightness = a_sum * c;
    out->chi2 = chi2;
    out->dof = used > npar ? used - npar : 0;
    /* chi2 ~ phi chi2(dof / phi) with a correlated excess (excess_correlation) */
    long dof_eff = lround(out->dof / phi);
    out->p_value = out->dof >= 1 ? gs_chi2_sf(chi2 / phi, dof_eff > 1 ? (int)dof_eff : 1) : 1.0;
    out->model_error = fe;
    if (excess) {
        /* residuals against the camera noise alone (the fit is the same to first order) */
        size_t n = 0, K = (size_t)m->K;
        memset(excess, 0, sizeof *excess);
        for (size_t d = 0; d < D; d++) {
            if (!(w->w[d] > 0.0)) continue;
            double s = sigma[d] / c, r = w->xs[d] - a_f[d / span] * tb[d];
            w->r2[n] = r * r;
            w->s2[n] = s * s;
            w->m2[n] = mu2[d / K];
            excess->n_b[d / K] += 1.0;
            excess->s2_b[d / K] += s * s;
            n++;
        }
        for (int band = 0; band < m->bands; band++) {
            if (excess->n_b[band] > 0.0) excess->s2_b[band] /= excess->n_b[band];
            excess->mu2_b[band] = mu2[band];
        }
        excess->dof = out->dof;
        excess->valid = out->dof >= 1 && mu2[0] + mu2[1] + mu2[2] > 0.0;
        excess->e2 = excess->valid ? excess_e2(w->r2, w->s2, w->m2, n, out->dof) : 0.0;
    }
    out->bulb = bb;
    out->phase_deg = rec_eq7_report_phase(m, bb, dec.tmpl, dec.shift);
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
        dec.runner_bulb >= 0 ? rec_eq7_report_phase(m, dec.runner_bulb, dec.runner_tmpl, dec.runner_shift) : 0.0;
    out->runner_confidence = dec.runner_bulb >= 0 ? dec.runner_conf : 0.0;
    out->shape_p_value = out->blend_p_value = 1.0;
    out->p_other = out->p_blend = 0.0;
    out->blend_bulb[0] = out->blend_bulb[1] = -1;
    if (snr >= m->o.min_snr && m->o.unknown_p > 0.0) {
        /* the nested-model tests (eq7_nested.c): a second light, or a waveform not in DELIGHT */
        rec_eq7_nested nt;
        rec_eq7_nested_tests(m, w, tb, bb, dec.tmpl, dec.shift, phi, &nt);
        out->shape_p_value = nt.p_shape;
        out->blend_p_value = nt.p_blend;
        /* the posteriors are over DELIGHT and "a bulb not in it" (eq7_nested.c) */
        out->p_other = nt.p_other;
        w->other_lbf = nt.lbf_other;
        out->p_blend = nt.found ? nt.p_blend_post : 0.0;
        double one = (1.0 - out->p_other) * (1.0 - out->p_blend);   /* in DELIGHT, one light */
        out->confidence *= one;
        out->bulb_confidence *= one;
        out->phase_confidence *= one;
        out->runner_confidence *= one;
        int blend = nt.found && (nt.p_blend < m->o.unknown_p || out->p_blend > 0.5) &&
                    !(nt.extra_shape > 0 && nt.chi2_blend + 2.0 * nt.extra_blend > nt.chi2_shape + 2.0 * nt.extra_shape);
        if (blend) {
            flags |= REC_MATCH_BLEND;
            for (int q = 0; q < 2; q++) {
                size_t j = nt.tmpl[q];
                int b = j == (size_t)-1 ? bb : m->tbulb[j];
                out->blend_bulb[q] = b;
                out->blend_phase_deg[q] = j == (size_t)-1 ? out->phase_deg : rec_eq7_report_phase(m, b, j, m->shift[j]);
                out->blend_share[q] = nt.share[q];
            }
        } else if (nt.p_shape < m->o.unknown_p) {
            flags |= REC_MATCH_UNKNOWN;
        }
    }
    if (m->bulbs[bb].ref == GS_REF_NONE) flags |= REC_MATCH_PHASE_AMBIGUOUS;
    if (out->bulb_confidence < m->o.ambiguous_conf) flags |= REC_MATCH_BULB_AMBIGUOUS;
    if (out->phase_confidence < m->o.ambiguous_conf) flags |= REC_MATCH_PHASE_AMBIGUOUS;
    if (out->dof > 0 && out->p_value < m->o.unknown_p) flags |= REC_MATCH_UNKNOWN;
    if (snr < m->o.min_snr) flags |= REC_MATCH_DIM;
    if (flags & (REC_MATCH_UNKNOWN | REC_MATCH_DIM | REC_MATCH_BLEND)) {
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
    rec_eq7_work w;
    gs_status s = rec_eq7_work_alloc(m, &w);
    if (s != GS_OK) return s;
    w.flat = isfinite(m->o.flat_share) ? m->o.flat_share : 0.0;
    s = rec_eq7_match_light_ws(m, &w, signal, sigma,
                               isfinite(m->o.model_error) ? m->o.model_error : 0.0, out, NULL);
    rec_eq7_work_free(&w);
    return s;
}
