/* eq7_scores.c - Eq. 7's log likelihoods of one light under the band models (recognize.h): one
 * brightness, one per band, the reddened chromaticity; their upper bounds from a template's sums;
 * and the screen that makes them exact only where they can matter (docs/recognition.md, "The
 * screen"): a template whose bound lies CUT_PIXEL nats below a computed score carries less than
 * e^-30 of that template's posterior mass. */
#include "recognize/internal.h"

#include <float.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#if defined(__GNUC__) && !defined(__clang__)
/* glibc's vector math (libmvec): the score loops below call these (the AVX-512 clone: 8 at a time) */
__attribute__((simd("notinbranch"))) double erfc(double);
__attribute__((simd("notinbranch"))) double log(double);
__attribute__((simd("notinbranch"))) double log1p(double);
__attribute__((simd("notinbranch"))) double exp(double);
#endif

/* ------------------------------------------------------------ log likelihoods */

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
double rec_eq7_loglik_n(int nf, double Sxx, const double *S, const double *T)
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
 * left out, per tau (rec_red_fit: recognize/internal.h). */
/* The reddened model's terms of each tau from its sums A, B, C and occupation occ (dead: none):
 * L(tau) without the prior and log Phi(z) into Lt (-inf where dead), log Phi(z) from erfc into
 * lphi (for z > -20: below, gs_log_phi's series), z = B / sqrt(A) into zt, the between-band
 * misfit into bt. */
GS_VECTOR_LOOP static void red_taus(const double *restrict A, const double *restrict B, const double *restrict C,
                                     const double *restrict occ, const long long *restrict dead, double R,
                                     double *restrict Lt, double *restrict lphi, double *restrict zt,
                                     double *restrict bt)
{
    for (int i = 0; i < REC_TAU_N; i++) {
        double a = dead[i] ? 1.0 : A[i], between = C[i] - B[i] * B[i] / a, z = B[i] / sqrt(a);
        between = between < 0.0 ? 0.0 : between;
        double e = 0.5 * erfc(fabs(z) * M_SQRT1_2), p = log1p(-e), q = log(e);
        Lt[i] = dead[i] ? -INFINITY : -0.5 * (R + between) - 0.5 * log(a + a * occ[i]);
        lphi[i] = z > 0.0 ? p : q;
        zt[i] = z;
        bt[i] = between;
    }
}

/* One band's terms of a round of the reddened model for every tau: s_b = t a c_b from the
 * current brightness av (clamped at 0), then A += v c^2, B += v c a_b, C += v a_b^2 and the
 * occupation occ += x + occ x, x = s_b^2 T_b, v = 1 / (1/T_b + s_b^2). */
GS_VECTOR_LOOP static void red_round(const double *restrict c, const double *restrict av, double tol,
                                      double Tb, double ab, double *restrict A, double *restrict B,
                                      double *restrict C, double *restrict occ)
{
    double iT = 1.0 / Tb;
    for (int i = 0; i < REC_TAU_N; i++) {
        double a = av[i] > 0.0 ? av[i] : 0.0;
        double sb = tol * a * c[i], x = sb * sb * Tb, v = 1.0 / (iT + sb * sb);
        A[i] = A[i] + v * c[i] * c[i];
        B[i] = B[i] + v * c[i] * ab;
        C[i] = C[i] + v * ab * ab;
        occ[i] = occ[i] + (x + occ[i] * x);
    }
}

/* After a round: a tau whose A is not > 0 is dead from now on, the others' brightness B / A. */
GS_VECTOR_LOOP static void red_brightness(const double *restrict A, const double *restrict B,
                                           long long *restrict dead, double *restrict av)
{
    for (int i = 0; i < REC_TAU_N; i++) {
        dead[i] |= !(A[i] > 0.0);
        double a = B[i] / A[i];   /* (only kept where alive) */
        av[i] = dead[i] ? av[i] : a;
    }
}

/* The per-band estimates ah_b = S_b / T_b (0 where T_b <= 0) and the residual within the bands
 * R = max(Sxx - sum_b S_b ah_b, 0) of the reddened model; 0 when no band has T_b > 0. */
static int red_residual(const rec_matcher *m, double Sxx, const double *S, const double *T, double *ah, double *R)
{
    int any = 0;
    *R = Sxx;
    for (int b = 0; b < m->bands; b++) {
        ah[b] = T[b] > 0.0 ? S[b] / T[b] : 0.0;
        if (T[b] > 0.0) {
            *R -= S[b] * ah[b];
            any = 1;
        }
    }
    if (*R < 0.0) *R = 0.0;
    return any;
}

/* The three rounds of the reddened model of bulb b's per-band estimates ah (the bands with
 * T_b > 0) for every tau (rec_eq7_loglik_red): the last round's A, B, C and occupation, the
 * brightness av and the dead taus. */
static void red_rounds(const rec_matcher *m, int bulb, const double *T, const double *ah, double tol, double *av,
                       double *A, double *B, double *C, double *occ, long long *dead)
{
    int nb = m->bands;
    const double *cb = m->red_c + (size_t)bulb * REC_TAU_N * (size_t)nb;
    double ccol[GS_MAX_BANDS][REC_TAU_N];   /* each band's c_b(tau), contiguous */
    for (int b = 0; b < nb; b++)
        for (int i = 0; i < REC_TAU_N; i++) ccol[b][i] = cb[(size_t)i * (size_t)nb + (size_t)b];
    for (int it = 0; it < 3; it++) {
        for (int i = 0; i < REC_TAU_N; i++) A[i] = B[i] = C[i] = occ[i] = 0.0;
        for (int b = 0; b < nb; b++)
            if (T[b] > 0.0) red_round(ccol[b], av, tol, T[b], ah[b], A, B, C, occ);
        red_brightness(A, B, dead, av);
    }
}

/* Each live tau's -(R + between)/2 - log_lo(A (1 + occ))/2 (+ the tau prior prior[i], NULL:
 * none) into u (-inf where dead), log_lo(x) = e log 2 for a normal x in [2^e, 2^(e+1)), at most
 * log x (to within e 2e-17 in floating point, far inside the bound's slack), and -inf for any
 * other x (u = +inf or NaN then: no bound, as tighten keeps the old one): L(tau) without its
 * log Phi(z) <= 0 and with a logarithm from below. */
GS_VECTOR_LOOP static void red_tau_bounds(const double *restrict A, const double *restrict B,
                                          const double *restrict C, const double *restrict occ,
                                          const long long *restrict dead, double R, const double *restrict prior,
                                          double *restrict u)
{
    for (int i = 0; i < REC_TAU_N; i++) {
        double a = dead[i] ? 1.0 : A[i], between = C[i] - B[i] * B[i] / a, x = a + a * occ[i];
        between = between < 0.0 ? 0.0 : between;
        uint64_t bits;
        memcpy(&bits, &x, sizeof bits);
        double lo = x >= DBL_MIN ? (double)((long long)(bits >> 52) - 1023) * M_LN2 : -INFINITY;
        u[i] = dead[i] ? -INFINITY : -0.5 * (R + between) - 0.5 * lo + (prior ? prior[i] : 0.0);
    }
}

GS_VECTOR_LOOP void rec_eq7_exp_below(const double *restrict L, size_t n, double Lmax, double *restrict ex)
{
    for (size_t i = 0; i < n; i++) {
        double d = L[i] - Lmax, e = exp(d > -746.0 ? d : 0.0);
        ex[i] = d > -746.0 ? e : 0.0;
    }
}

double rec_eq7_loglik_red(const rec_matcher *m, const rec_eq7_work *w, int bulb, double Sxx,
                          const double *S, const double *T, rec_red_fit *fit, double *ll_acc,
                          double ll_logw)
{
    double tol = w->chroma_tol > 0.0 ? w->chroma_tol : m->o.chroma_tolerance;
    double R, ah[GS_MAX_BANDS];
    int nb = m->bands;
    if (!red_residual(m, Sxx, S, T, ah, &R)) return -INFINITY;
    /* the three rounds of s_b from the current brightness, for every tau at once: the taus are
     * independent, so the divisions of one overlap the others' (each tau's numbers are the same
     * operations in the same order as one tau alone). occ1 = prod_b (1 + s_b^2 T_b) - 1: the
     * occupation term sum_b log(1 + s_b^2 T_b) is log1p(occ1), one logarithm for the bands (and
     * with log A, one for both); only the last round's is used. A tau whose A is not > 0 in some
     * round has no likelihood. */
    const double *cb = m->red_c + (size_t)bulb * REC_TAU_N * (size_t)nb;
    double av[REC_TAU_N] = {0}, Av[REC_TAU_N], Bv[REC_TAU_N], Cv[REC_TAU_N], occv[REC_TAU_N];
    long long dead[REC_TAU_N] = {0};   /* (as wide as a double: red_taus vectorizes) */
    red_rounds(m, bulb, T, ah, tol, av, Av, Bv, Cv, occv, dead);
    double Lt[REC_TAU_N], lphi[REC_TAU_N], zt[REC_TAU_N], bt[REC_TAU_N], Lmax = -INFINITY;
    red_taus(Av, Bv, Cv, occv, dead, R, Lt, lphi, zt, bt);
    for (int i = 0; i < REC_TAU_N; i++) {
        double tau = rec_eq7_tau(i);
        const double *c = cb + (size_t)i * (size_t)nb;
        double a = av[i], z = zt[i], between = bt[i];
        if (dead[i]) continue;
        Lt[i] += z > -20.0 ? lphi[i] : gs_log_phi(z);
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
                    /* posterior mean of a_b: data a_b (weight T_b) and prior a c_b (1/s_b^2);
                     * the prior's alone where 1/s_b^2 overflows (a light ~1e-160 of its noise) */
                    fit->band[b] = T[b] > 0.0 ? (1.0 / (sb * sb) < INFINITY ? (T[b] * ah[b] + fit->a * c[b] / (sb * sb)) /
                                                              (T[b] + 1.0 / (sb * sb))
                                                          : fit->a * c[b])
                                              : 0.0;
                    if (fit->band[b] < 0.0) fit->band[b] = 0.0;
                }
            }
        }
    }
    if (!isfinite(Lmax)) return -INFINITY;
    double ex[REC_TAU_N], sum = 0.0;
    rec_eq7_exp_below(Lt, REC_TAU_N, Lmax, ex);
    for (int i = 0; i < REC_TAU_N; i++) sum += ex[i];
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
    rec_red_fit rf;
    if (!isfinite(rec_eq7_loglik_red(m, &w, bulb, Sxx, S, T, &rf, NULL, 0.0))) return INFINITY;
    return rf.chi2;
}


/* ------------------------------------------------------------ bounds */

/* An upper bound of rec_eq7_loglik_red for bulb b's sums: with v_b = T_b / (1 + s_b^2 T_b) <= T_b
 * the occupation term is sum_b log(v_b / T_b) / 2 <= 0 and A = sum v c^2 >= v_k c_k^2 for any used
 * band k, so -log(A)/2 - occ/2 <= -log(c_k^2 T_k)/2; between >= 0 and log Phi <= 0; c_k(tau) is
 * at least the bulb's smallest tabulated c_k (m->red_cmin); the tau prior adds at most its
 * largest log weight (lp_max). Every tau's L(tau) obeys it, so their prior-weighted mean does. */
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

static void red_bounds(const rec_matcher *m, rec_eq7_work *w, double Sxx, size_t *jbest)
{
    double lp_max = 0.0, Sv[GS_MAX_BANDS], Tv[GS_MAX_BANDS];
    if (w->has_tau_prior) {
        lp_max = -INFINITY;
        for (int i = 0; i < REC_TAU_N; i++) lp_max = fmax(lp_max, w->tau_logprior[i]);
        lp_max += log((double)REC_TAU_N);
    }
    size_t jb = 0;
    for (size_t j = 0; j < m->M; j++) {
        rec_eq7_sums_of(m, w, j, Sv, Tv);
        w->U[j] = red_bound(m, Sxx, Sv, Tv, m->red_cmin + (size_t)m->tbulb[j] * (size_t)m->bands, lp_max);
        jb = w->U[j] > w->U[jb] ? j : jb;
    }
    *jbest = jb;
}

/* The reddened model's bound of one template from its rounds (red_rounds: the arithmetic of
 * rec_eq7_loglik_red without its erfc and with its logarithms from below; red_tau_bounds): its
 * L is the log of the prior-weighted mean of exp L(tau), below the same mean of the taus'
 * bounds. Several times cheaper than the exact L and within a nat or so of it (log Phi(z) ~ 0
 * for a fit of any brightness), where red_bound's chromaticity-blind bound is far
 * above (see the screen's test, eq7_reddened_tight_bounds_hold). */
static double red_tight_bound(const rec_matcher *m, const rec_eq7_work *w, size_t j, double Sxx, const double *prior)
{
    double S[GS_MAX_BANDS], T[GS_MAX_BANDS], R, ah[GS_MAX_BANDS];
    rec_eq7_sums_of(m, w, j, S, T);
    if (!red_residual(m, Sxx, S, T, ah, &R)) return -INFINITY;
    double tol = w->chroma_tol > 0.0 ? w->chroma_tol : m->o.chroma_tolerance;
    double av[REC_TAU_N] = {0}, A[REC_TAU_N], B[REC_TAU_N], C[REC_TAU_N], occ[REC_TAU_N];
    long long dead[REC_TAU_N] = {0};
    red_rounds(m, m->tbulb[j], T, ah, tol, av, A, B, C, occ, dead);
    double ut[REC_TAU_N], ex[REC_TAU_N], mx = -INFINITY, sum = 0.0;
    red_tau_bounds(A, B, C, occ, dead, R, prior, ut);
    for (int i = 0; i < REC_TAU_N; i++) mx = ut[i] > mx ? ut[i] : mx;
    if (!(mx > -INFINITY)) return mx;
    rec_eq7_exp_below(ut, REC_TAU_N, mx, ex);
    for (int i = 0; i < REC_TAU_N; i++) sum += ex[i];
    double u = mx + log(sum / REC_TAU_N);   /* L = log mean_tau exp(L(tau)) <= that of the bounds */
    return u + 1e-9 * (1.0 + fabs(u));      /* rounding slack */
}

/* The screen's passes over every template: the largest bound, with its first index, 8 lanes at
 * a time (each lane keeps the first of its largest); and the bounds themselves, written plainly
 * for the compiler to vectorize (GS_VECTOR_LOOP). */
typedef double scr_vd __attribute__((vector_size(8 * sizeof(double))));
typedef long long scr_vl __attribute__((vector_size(8 * sizeof(long long))));

/* v[0..n) = x. */
GS_VECTOR_LOOP static void scr_fill(double *v, size_t n, double x)
{
    for (size_t j = 0; j < n; j++) v[j] = x;
}

/* The first index of the largest of U[0..M) (0 when every one is -inf). */
GS_VECTOR_CLONES size_t rec_eq7_argmax(const double *U, size_t M)
{
    size_t j = 0, jb = 0;
    double mx = -INFINITY;
    if (M >= 8) {
        scr_vd vm;
        scr_vl vi = {0, 1, 2, 3, 4, 5, 6, 7}, vj = vi, step = {8, 8, 8, 8, 8, 8, 8, 8};
        memcpy(&vm, U, sizeof vm);
        for (j = 8; j + 8 <= M; j += 8) {
            scr_vd u;
            memcpy(&u, U + j, sizeof u);
            vj += step;
            scr_vl gt = u > vm;
            vm = (scr_vd)((gt & (scr_vl)u) | (~gt & (scr_vl)vm));
            vi = (gt & vj) | (~gt & vi);
        }
        for (int q = 0; q < 8; q++)
            if (vm[q] > mx || (vm[q] == mx && (size_t)vi[q] < jb)) mx = vm[q], jb = (size_t)vi[q];
    }
    for (; j < M; j++)
        if (U[j] > mx) mx = U[j], jb = j;
    return jb;
}

/* The one-brightness bound below (free_bounds) of every template: U = c0 - lognorm +
 * min(g - Sxx, 0)/2 plus the slack, g = S^2/T where S > 0 (T > 0), -inf where T <= 0; without
 * lognorm (a light with dropped samples), -log(T)/2 in place of c0 - lognorm. */
GS_VECTOR_LOOP static void scr_bounds_1(const double *S, const double *T, const double *lognorm, size_t M,
                                         double c0, double Sxx, double slack, double *U)
{
    for (size_t j = 0; j < M; j++) {
        double s = S[j], t = T[j];
        double g = s > 0.0 && t > 0.0 ? s * (s / t) : 0.0, d = g - Sxx;
        double u = (lognorm ? c0 - lognorm[j] : -0.5 * log(t > 0.0 ? t : 1.0)) + 0.5 * (d < 0.0 ? d : 0.0);
        U[j] = t > 0.0 ? u + (1e-9 * (1.0 + fabs(u)) + slack) : -INFINITY;
    }
}

/* scr_bounds_1 from the float sums (rec_eq7_float_sums), their rows scaled by powers of two (the
 * sums by 1/isx and 1/isw): the scaled S and T within es_j = es |t_j| + eabs and et_j = et T_f +
 * eabs of their float values Sf, Tf (float's rounding over D terms, es = gamma_(D+3) |wx|, et =
 * gamma / (1 - gamma); |sum w x t| <= |w x| |t|; eabs for subnormal terms), the bound taken at
 * the box's worst corner, S + es_j over T - et_j: +inf where T - et_j <= 0 (scored exactly). */
GS_VECTOR_LOOP static void scr_bounds_1f(const float *Sf, const float *Tf, const double *tnorm, const double *lognorm,
                                          size_t M, double c0, double Sxx, double slack, double es, double et,
                                          double eabs, double isx, double isw, double *U)
{
    for (size_t j = 0; j < M; j++) {   /* the term of T: in its own loop, no logarithm with lognorm */
        double t = Tf[j], lo = (t - (et * t + eabs)) * isw;
        U[j] = lognorm ? c0 - lognorm[j] : lo > 0.0 ? -0.5 * log(lo) : INFINITY;
    }
    for (size_t j = 0; j < M; j++) {
        double s = ((double)Sf[j] + (es * tnorm[j] + eabs)) * isx, t = Tf[j], lo = (t - (et * t + eabs)) * isw;
        double q = s * (s / (lo > 0.0 ? lo : 1.0)), g = s > 0.0 ? (lo > 0.0 ? q : INFINITY) : 0.0, d = g - Sxx;
        double u = U[j] + 0.5 * (d < 0.0 ? d : 0.0);
        U[j] = u + (1e-9 * (1.0 + fabs(u)) + slack);
    }
}

/* The bounds of rec_eq7_loglik_n: log Phi(z) <= 0, and a brightness whose S_f <= 0 adds at most
 * z_f^2/2 + log Phi(z_f) <= log(1/2) < 0 to L, so with g = sum over S_f > 0 of S_f^2/T_f
 *   L <= -max(Sxx - g, 0)/2 - sum_f log(T_f)/2.
 * When every sample of brightness f has a weight, T_f = sum w t^2 >= w_min |t_f|^2 (w_min the
 * light's least weight there, |t_f| the template's norm over the brightness's samples,
 * tabulated): no logarithm per template. Otherwise (a dropped sample: saturated, masked, bad)
 * that need not hold and log T_f itself is taken. A brightness whose samples a template misses
 * (T_f = 0) adds no term to its L: the bound's term is kept from going below 0 then. Rounding
 * slack: L's own chi2 cancels as Sxx - g does, to some 1e-16 Sxx. Into U[j0..j0 + n). */
static void free_bounds(const rec_matcher *m, rec_eq7_work *w, const rec_eq7_prep *p, double Sxx, size_t j0,
                        size_t n)
{
    size_t M = m->M;
    int nf = m->nfit;
    double slack = 1e-12 * Sxx, *U = w->U;
    if (rec_eq7_float_sums(m)) {   /* (one brightness; every template discrete) */
        double u = 0x1p-24 * (double)(m->D + 3), gam = u / (1.0 - u);
        scr_bounds_1f(w->Sf + j0, w->Tf + j0, m->tnorm + j0, p->full[0] ? m->lognorm + j0 : NULL, n,
                      -0.5 * log(p->wmin[0]), Sxx, slack, gam * w->wxn, gam / (1.0 - gam), 4.0 * m->D * 0x1p-90,
                      1.0 / w->fsx, 1.0 / w->fsw, U + j0);
        return;
    }
    if (nf == 1) {
        scr_bounds_1(w->S + j0, w->T + j0, p->full[0] ? m->lognorm + j0 : NULL, n, -0.5 * log(p->wmin[0]), Sxx,
                     slack, U + j0);
        return;
    }
    double cf[GS_MAX_BANDS];
    for (int f = 0; f < nf; f++) cf[f] = p->wmin[f] > 0.0 ? -0.5 * log(p->wmin[f]) : 0.0;
    for (size_t j = j0; j < j0 + n; j++) {
        double g = 0.0, u = 0.0;
        int any = 0;
        for (int f = 0; f < nf; f++) {
            double S = w->S[(size_t)f * M + j], T = w->T[(size_t)f * M + j];
            if (!(p->wmin[f] > 0.0)) continue;   /* no usable sample: no brightness */
            double c = p->full[f] ? cf[f] - m->lbnorm[j * (size_t)m->bands + (size_t)f] : T > 0.0 ? -0.5 * log(T) : 0.0;
            if (!(T > 0.0)) {
                u += c > 0.0 ? c : 0.0;
                continue;
            }
            any = 1;
            u += c;
            if (S > 0.0) g += S * (S / T);
        }
        double d = g - Sxx;
        u += 0.5 * (d < 0.0 ? d : 0.0);
        U[j] = any ? u + 1e-9 * (1.0 + fabs(u)) + slack : -INFINITY;
    }
}

/* ------------------------------------------------------------ many scores at once */

/* rec_eq7_loglik_n of the templates idx[0..n) into w->L[idx[i]], vectorized (the same terms;
 * glibc's vector logarithm and erfc): log Phi(z) is log1p(-e) or log(e), e = erfc(|z| / sqrt 2)
 * / 2; where z <= -20, rec_eq7_loglik_n again (scores_free_fix: its asymptotic series, as
 * gs_log_phi). */
GS_VECTOR_LOOP static void scores_1(const double *restrict S, const double *restrict T, const size_t *restrict idx,
                                     size_t n, double Sxx, double *restrict L)
{
    for (size_t i = 0; i < n; i++) {
        double sv = S[idx[i]], tv = T[idx[i]];
        int use = tv > 0.0;
        double sq = sqrt(use ? tv : 1.0), z = sv / sq, chi2 = Sxx - sv * z / sq;
        double e = 0.5 * erfc(fabs(z) * M_SQRT1_2), a = log1p(-e), b = log(e), lt = log(use ? tv : 1.0);
        double c = -0.5 * (chi2 > 0.0 ? chi2 : 0.0) - 0.5 * lt + (z > 0.0 ? a : b);
        L[idx[i]] = use ? c : -INFINITY;
    }
}

/* One brightness parameter f's terms (T_f > 0): z_f^2 into chi2[i] (subtracted), -log(T_f)/2 +
 * log Phi(z_f) into l[i], use[i] set. */
GS_VECTOR_LOOP static void scores_band(const double *restrict S, const double *restrict T, const size_t *restrict idx,
                                        size_t n, double *restrict chi2, double *restrict l, int *restrict use)
{
    for (size_t i = 0; i < n; i++) {
        double sv = S[idx[i]], tv = T[idx[i]];
        int u = tv > 0.0;
        double sq = sqrt(u ? tv : 1.0), z = sv / sq;
        double e = 0.5 * erfc(fabs(z) * M_SQRT1_2), a = log1p(-e), b = log(e), lt = log(u ? tv : 1.0);
        chi2[i] -= u ? z * z : 0.0;
        l[i] += u ? -0.5 * lt + (z > 0.0 ? a : b) : 0.0;
        use[i] |= u;
    }
}

static void scores_free(const rec_matcher *m, rec_eq7_work *w, const size_t *idx, size_t n, double Sxx)
{
    if (m->nfit == 1) {
        scores_1(w->S, w->T, idx, n, Sxx, w->L);
        return;
    }
    /* per brightness into the scratch (w->tt, w->dt: D values; use: on the stack), in pieces */
    int use[REC_NESTED_MAX_D];
    size_t piece = (size_t)m->D < sizeof use / sizeof *use ? (size_t)m->D : sizeof use / sizeof *use;
    double *chi2 = w->tt, *l = w->dt;
    for (size_t i0 = 0; i0 < n; i0 += piece) {
        size_t k = n - i0 < piece ? n - i0 : piece;
        for (size_t i = 0; i < k; i++) chi2[i] = Sxx, l[i] = 0.0, use[i] = 0;
        for (int f = 0; f < m->nfit; f++)
            scores_band(w->S + (size_t)f * m->M, w->T + (size_t)f * m->M, idx + i0, k, chi2, l, use);
        for (size_t i = 0; i < k; i++)
            w->L[idx[i0 + i]] = use[i] ? -0.5 * (chi2[i] > 0.0 ? chi2[i] : 0.0) + l[i] : -INFINITY;
    }
}

static void scores_free_fix(const rec_matcher *m, const rec_eq7_work *w, const size_t *idx, size_t n, double Sxx)
{
    for (size_t i = 0; i < n; i++)
        for (int f = 0; f < m->nfit; f++) {
            double sv = w->S[(size_t)f * m->M + idx[i]], tv = w->T[(size_t)f * m->M + idx[i]];
            if (tv > 0.0 && !(sv / sqrt(tv) > -20.0)) {
                w->L[idx[i]] = rec_eq7_loglik_fit(m, (rec_eq7_work *)w, idx[i], Sxx);
                break;
            }
        }
}

/* ------------------------------------------------------------ the screen */

double rec_eq7_loglik_fit(const rec_matcher *m, rec_eq7_work *w, size_t j, double Sxx)
{
    double Sv[GS_MAX_BANDS], Tv[GS_MAX_BANDS];
    rec_eq7_exact_sums(m, w, &j, 1);
    rec_eq7_sums_of(m, w, j, Sv, Tv);
    if (!m->red) return rec_eq7_loglik_n(m->nfit, Sxx, Sv, Tv);
    int b = m->tbulb[j];   /* every bulb weighs the same, whatever its phase grid */
    return rec_eq7_loglik_red(m, w, b, Sxx, Sv, Tv, NULL, w->collect_tau ? w->tau_ll : NULL,
                              -log((double)m->count[b]));
}

/* The screen of one light: its sums, the largest exact L so far, and the two largest ranks (L +
 * log cellw, as eq7_decide.c ranks discrete pairs) of its exact discrete templates. */
typedef struct {
    const rec_matcher *m;
    rec_eq7_work *w;
    const rec_eq7_prep *p;
    double Sxx, Lmax, r1, r2;
    const double *prior;            /* the tau prior's log weights + log REC_TAU_N (NULL: none) */
    double prior_v[REC_TAU_N];
} screen;

/* A screen of one light (its sums in w, Lmax the best score so far). */
static void screen_init(screen *sc, const rec_matcher *m, rec_eq7_work *w, const rec_eq7_prep *p, double Sxx,
                        double Lmax)
{
    sc->m = m;
    sc->w = w;
    sc->p = p;
    sc->Sxx = Sxx;
    sc->Lmax = Lmax;
    sc->r1 = sc->r2 = -INFINITY;
    sc->prior = NULL;
    if (!m->red || !w->has_tau_prior) return;
    for (int i = 0; i < REC_TAU_N; i++) sc->prior_v[i] = w->tau_logprior[i] + log((double)REC_TAU_N);
    sc->prior = sc->prior_v;
}

/* Template j's exact L (scored: already in w->L); its bound is spent (-inf: the passes below look
 * for the largest bound of the templates not yet exact). */
static double scored(screen *sc, size_t j)
{
    const rec_matcher *m = sc->m;
    rec_eq7_work *w = sc->w;
    double L = w->L[j];
    w->done[j] = 1;
    w->U[j] = -INFINITY;
    if (L > sc->Lmax) sc->Lmax = L;
    if (!m->ncont || !m->cont[m->tbulb[j]]) {
        double r = L + m->logcellw[j];
        if (r > sc->r1) sc->r2 = sc->r1, sc->r1 = r;
        else if (r > sc->r2) sc->r2 = r;
    }
    return L;
}

static double exact(screen *sc, size_t j)
{
    sc->w->L[j] = rec_eq7_loglik_fit(sc->m, sc->w, j, sc->Sxx);
    return scored(sc, j);
}

/* Template j's bound, made tight once (the reddened model: red_tight_bound) unless exact. */
static double tighten(screen *sc, size_t j)
{
    rec_eq7_work *w = sc->w;
    if (sc->m->red && !w->tight[j] && !w->done[j]) {
        w->tight[j] = 1;
        double t = red_tight_bound(sc->m, w, j, sc->Sxx, sc->prior);
        if (t < w->U[j]) w->U[j] = t;
    }
    return w->U[j];
}

/* Whether template j's bound is final (tight, or a model without tight bounds); if not, it is
 * made tight now and may no longer be the largest. */
static int bound_final(screen *sc, size_t j)
{
    if (!sc->m->red || sc->w->tight[j]) return 1;
    tighten(sc, j);
    return 0;
}

/* exact() of the templates idx[0..n): the free models' scores at once. */
static void exact_set(screen *sc, const size_t *idx, size_t n)
{
    const rec_matcher *m = sc->m;
    rec_eq7_work *w = sc->w;
    if (m->red) {
        for (size_t i = 0; i < n; i++) exact(sc, idx[i]);
        return;
    }
    rec_eq7_exact_sums(m, w, idx, n);
    scores_free(m, w, idx, n, sc->Sxx);
    scores_free_fix(m, w, idx, n, sc->Sxx);
    for (size_t i = 0; i < n; i++) scored(sc, idx[i]);
}

/* any = whether one of the 8 values at p is at least its lane of t (a macro: a vector argument
 * would take the ABI of the widest clone). */
#define SCR_ANY_AT_LEAST(any, p, t)                                                                  \
    do {                                                                                            \
        scr_vd u_;                                                                                  \
        memcpy(&u_, (p), sizeof u_);                                                                \
        scr_vl ge_ = u_ >= (t);                                                                     \
        (any) = 0;                                                                                  \
        for (int q_ = 0; q_ < 8; q_++) (any) |= ge_[q_];                                            \
    } while (0)

/* The indices j in [j0, j1) with U[j] >= th and U[j] > -inf into out, in order; returns how
 * many. Blocks of 8 none of which reaches th are skipped by one vector compare. */
GS_VECTOR_CLONES static size_t scr_at_least(const double *U, size_t j0, size_t j1, double th, size_t *out)
{
    size_t n = 0, j = j0;
    scr_vd t;
    for (int q = 0; q < 8; q++) t[q] = th;
    for (; j + 8 <= j1; j += 8) {
        long long any;
        SCR_ANY_AT_LEAST(any, U + j, t);
        if (!any) continue;
        for (size_t i = j; i < j + 8; i++)
            if (U[i] >= th && U[i] > -INFINITY) out[n++] = i;
    }
    for (; j < j1; j++)
        if (U[j] >= th && U[j] > -INFINITY) out[n++] = j;
    return n;
}

/* The first i < n with U[i] >= th (n if none). */
GS_VECTOR_CLONES static size_t scr_first_at_least(const double *U, size_t n, double th)
{
    size_t i = 0;
    scr_vd t;
    for (int q = 0; q < 8; q++) t[q] = th;
    for (; i + 8 <= n; i += 8) {
        long long any;
        SCR_ANY_AT_LEAST(any, U + i, t);
        if (any) break;
    }
    while (i < n && !(U[i] >= th)) i++;
    return i;
}

/* exact() of every template not yet exact whose bound is at least th (its tight bound, where
 * there is one: tighten). */
static void exact_at_least(screen *sc, double th)
{
    const rec_matcher *m = sc->m;
    rec_eq7_work *w = sc->w;
    size_t n = 0, k = 0;   /* (w->cand: free while the screen runs) */
    if (rec_eq7_bulb_screen(m))   /* the bulbs with bounds: the open ones */
        for (size_t b = 0; b < m->nb; b++)
            n += rec_eq7_bulb_active(m, w, b) ? scr_at_least(w->U, m->first[b], m->first[b] + m->count[b], th, w->cand + n) : 0;
    else
        n = scr_at_least(w->U, 0, m->M, th, w->cand);
    for (size_t i = 0; i < n; i++)
        if (tighten(sc, w->cand[i]) >= th) w->cand[k++] = w->cand[i];
    exact_set(sc, w->cand, k);
}

/* The discrete template of the largest bound not yet exact (M: none), its bound + log cellw in *u. */
static size_t best_discrete_bound(const rec_matcher *m, const rec_eq7_work *w, double *u)
{
    size_t jn = m->M;
    if (!m->ncont) {   /* every cellw the same */
        jn = rec_eq7_argmax(w->U, m->M);
        *u = w->U[jn] + m->logcellw[jn];
        return w->U[jn] > -INFINITY ? jn : m->M;
    }
    *u = -INFINITY;
    for (size_t j = 0; j < m->M; j++)
        if (!m->cont[m->tbulb[j]] && w->U[j] + m->logcellw[j] > *u) {
            *u = w->U[j] + m->logcellw[j];
            jn = j;
        }
    return jn;
}

/* The nested tests' first templates (eq7_nested.c): every template that can be among the
 * REC_NESTED_FIRST + 1 largest L: the largest bounds exact until there are as many exact scores,
 * then every template whose bound is not below the least of the largest. */
static void nested_first(screen *sc)
{
    const rec_matcher *m = sc->m;
    rec_eq7_work *w = sc->w;
    size_t ndone = 0;
    for (size_t j = 0; j < m->M; j++) ndone += w->done[j] && isfinite(w->L[j]);
    while (ndone < REC_NESTED_FIRST + 1) {
        size_t jn = rec_eq7_argmax(w->U, m->M);
        if (!(w->U[jn] > -INFINITY)) break;
        if (bound_final(sc, jn)) ndone += isfinite(exact(sc, jn));
    }
    double top[REC_NESTED_FIRST + 1];
    int nt = 0;
    for (size_t j = 0; j < m->M; j++) {
        double l = w->L[j];
        if (!w->done[j] || !isfinite(l) || (nt == REC_NESTED_FIRST + 1 && !(l > top[nt - 1]))) continue;
        int q = nt < REC_NESTED_FIRST + 1 ? nt++ : nt - 1;
        while (q > 0 && l > top[q - 1]) {
            top[q] = top[q - 1];
            q--;
        }
        top[q] = l;
    }
    double th = nt == REC_NESTED_FIRST + 1 ? top[nt - 1] : -INFINITY;
    exact_at_least(sc, th);
}

/* Continuous bulb b's best grid cell exact, and every one of its cells whose bound reaches the
 * best so far (jb: a cell already exact, or M): its peak is refined or ranked from there. The
 * reddened model: tight bounds, best first, and no bulb whose every bound is below the cut. */
static void bulb_best(screen *sc, size_t b, size_t jb)
{
    const rec_matcher *m = sc->m;
    rec_eq7_work *w = sc->w;
    double *U = w->U;
    size_t j0 = m->first[b], n = m->count[b], jm = j0 + rec_eq7_argmax(U + j0, n);
    double lb = jb >= j0 && jb < j0 + n ? w->L[jb] : -INFINITY;   /* its exact ones so far */
    if (m->red) {
        /* a bulb whose every bound is below the cut has no pair within it (it can only be a
         * runner-up with a posterior below e^-30); the others best first, each bound tight
         * before it counts */
        if (lb == -INFINITY && !(U[jm] >= sc->Lmax - CUT_PIXEL)) return;
        for (;;) {
            jm = j0 + rec_eq7_argmax(U + j0, n);
            if (!(U[jm] > -INFINITY) || !(U[jm] >= lb)) break;
            if (bound_final(sc, jm)) lb = fmax(lb, exact(sc, jm));
        }
        return;
    }
    if (U[jm] > lb) lb = fmax(lb, exact(sc, jm));
    for (size_t j = j0; lb > -INFINITY && j < j0 + n; j++) {
        j += scr_first_at_least(U + j, j0 + n - j, lb);
        if (j < j0 + n) lb = fmax(lb, exact(sc, j));
    }
}

/* The screen of bulbs (m->bs_on): continuous bulb b's grids, its cells' bounds, its best. */
static void open_bulb(screen *sc, size_t b)
{
    rec_eq7_work *w = sc->w;
    scr_fill(w->L + sc->m->first[b], sc->m->count[b], -INFINITY);
    rec_eq7_grid_sums(sc->m, w, b);
    free_bounds(sc->m, w, sc->p, sc->Sxx, sc->m->first[b], sc->m->count[b]);
    w->open[b] = 1;
    bulb_best(sc, b, sc->m->M);
}

/* w->border[i0..n) sorted by the bulbs' bounds w->bub, largest first (insertion: nb is small) */
static void border_sort(rec_eq7_work *w, size_t i0, size_t n)
{
    for (size_t i = i0 + 1; i < n; i++) {
        size_t b = w->border[i], k = i;
        for (; k > i0 && w->bub[w->border[k - 1]] < w->bub[b]; k--) w->border[k] = w->border[k - 1];
        w->border[k] = b;
    }
}

/* The screen of bulbs (every bulb continuous): each bulb's bound (eq7_bulbscreen.c); no grid
 * open yet. */
static void bulb_bounds(screen *sc)
{
    const rec_matcher *m = sc->m;
    rec_eq7_work *w = sc->w;
    rec_eq7_light_dfts(m, w);
    rec_eq7_bulb_bounds(m, w, sc->p, sc->Sxx, w->bub);
    memset(w->open, 0, m->nb);
}

/* w->border[1..n): the bulbs other than b0 whose bound reaches th, largest first, ties in index
 * order (the order a sort of every bulb would give them, without sorting those below the cut);
 * when there is none, w->border[1] is the largest of the others. Returns n. */
static size_t border_within(rec_eq7_work *w, size_t nb, size_t b0, double th)
{
    size_t n = 1, top = nb;
    for (size_t b = 0; b < nb; b++) {
        if (b == b0) continue;
        if (w->bub[b] >= th) w->border[n++] = b;
        if (top == nb || w->bub[b] > w->bub[top]) top = b;
    }
    if (n == 1 && top < nb) w->border[1] = top;
    border_sort(w, 1, n);
    return n;
}

/* Exact: the best bound's template; for each continuous bulb its best (bulb_best; with the
 * screen of bulbs, only the bulb of the largest bound, the next by coupled bound, and those whose
 * coupled bound reaches within CUT_PIXEL of the best L so far, largest first: the others' cells
 * are all below the cut, and stay -inf); every template whose bound is within CUT_PIXEL of the
 * best computed L (the posterior's mass; in one pass, its threshold only rises); the runner-up
 * (the two best discrete templates: the best bound of the rest while it beats the second rank);
 * with the nested tests their first templates. */
double rec_eq7_screen(const rec_matcher *m, rec_eq7_work *w, const rec_eq7_prep *p, double Sxx)
{
    size_t M = m->M;
    double *U = w->U;
    screen sc;
    screen_init(&sc, m, w, p, Sxx, -INFINITY);
    memset(w->done, 0, M);
    if (m->red) memset(w->tight, 0, M);
    if (rec_eq7_float_sums(m)) memset(w->have, 0, M);
    if (!rec_eq7_bulb_screen(m)) scr_fill(w->L, M, -INFINITY);   /* (else per bulb: bulb_bounds, open_bulb) */
    if (m->exhaustive) {
        for (size_t j = 0; j < M; j++) w->cand[j] = j;
        exact_set(&sc, w->cand, M);
        return sc.Lmax;
    }
    if (rec_eq7_bulb_screen(m)) {
        bulb_bounds(&sc);
        /* (two at least: a runner-up bulb exists whenever the database has one) */
        w->border[0] = rec_eq7_argmax(w->bub, m->nb);
        open_bulb(&sc, w->border[0]);
        /* the others within the cut by their first bounds: their coupled bounds, largest first */
        double th0 = sc.Lmax - CUT_PIXEL;
        size_t n = border_within(w, m->nb, w->border[0], th0);
        for (size_t i = 1; i < n; i++) w->bub[w->border[i]] = rec_eq7_bulb_tighten(m, w, p, Sxx, w->border[i], th0);
        border_sort(w, 1, n);
        for (size_t i = 1; i < m->nb; i++) {
            size_t b = w->border[i];
            double th = sc.Lmax - CUT_PIXEL;
            if (i >= 2) {
                if (i >= n || !(w->bub[b] >= th)) break;
                if (th > th0) w->bub[b] = rec_eq7_bulb_tighten(m, w, p, Sxx, b, th);
                if (!(w->bub[b] >= th)) continue;
            }
            open_bulb(&sc, b);
        }
    } else {
        size_t jb = 0;
        if (m->red) red_bounds(m, w, Sxx, &jb);
        else {
            free_bounds(m, w, p, Sxx, 0, M);
            jb = rec_eq7_argmax(U, M);
        }
        if (!(U[jb] > -INFINITY)) return -INFINITY;
        while (!bound_final(&sc, jb)) {   /* the best final bound's template */
            /* every bound at least this one's tight bound, tight, in one pass */
            size_t n = scr_at_least(U, 0, M, U[jb], w->cand);
            for (size_t i = 0; i < n; i++) tighten(&sc, w->cand[i]);
            jb = rec_eq7_argmax(U, M);
        }
        if (!(U[jb] > -INFINITY)) return -INFINITY;
        exact(&sc, jb);
        for (size_t b = 0; m->ncont && b < m->nb; b++)
            if (m->cont[b]) bulb_best(&sc, b, jb);
    }
    exact_at_least(&sc, sc.Lmax - CUT_PIXEL);
    if ((size_t)m->ncont < m->nb)
        for (;;) {
            double u;
            size_t jn = best_discrete_bound(m, w, &u);
            if (jn == M || !(u > sc.r2)) break;
            if (bound_final(&sc, jn)) exact(&sc, jn);
        }
    if (m->o.nested_tests) nested_first(&sc);
    return sc.Lmax;
}

void rec_eq7_screen_widen(const rec_matcher *m, rec_eq7_work *w, const rec_eq7_prep *p, double Sxx, double Lmax,
                          double cut)
{
    screen sc;
    screen_init(&sc, m, w, p, Sxx, Lmax);
    for (size_t b = 0; rec_eq7_bulb_screen(m) && b < m->nb; b++)
        if (!w->open[b] && w->bub[b] >= Lmax - cut) {
            open_bulb(&sc, b);   /* its grid peak, as the bulbs too far below to refine */
            rec_eq7_grid_peak(m, w, b, m->first[b] + rec_eq7_argmax(w->L + m->first[b], m->count[b]));
        }
    exact_at_least(&sc, Lmax - cut);
}
