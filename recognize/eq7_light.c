/* eq7_light.c - Eq. 7 for one light (rec_match_light, rec_match_catalog): the scores of every
 * template in double, the continuous-phase refinement, the flags and the answer. */
#include "recognize/internal.h"

#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* The least share of the winner's template energy (sum t^2) on the usable samples for an
 * answer (eq7_few_usable_samples_never_confidently_wrong) */
#define SHOWN_SHARE_MIN 0.05

/* ------------------------------------------------------------ one light */

/* chi2(s) of continuous bulb b with the scale(s) profiled (a >= 0), and its derivatives. */
typedef struct {
    double chi2, d1, d2;     /* chi2 and its first two derivatives in s */
    int nf;                  /* brightness parameters */
    double S[GS_MAX_BANDS], T[GS_MAX_BANDS];   /* sum w x t, sum w t^2 (per band with gains) */
} chi2_eval;

static void chi2_at(const rec_matcher *m, rec_eq7_work *w, size_t b, double s, double Sxx, chi2_eval *e)
{
    int nf = m->nfit;
    double S1[GS_MAX_BANDS], S2[GS_MAX_BANDS], T1[GS_MAX_BANDS], T2[GS_MAX_BANDS];
    rec_eq7_series_at(m, w, b, s, e->S, S1, S2, e->T, T1, T2);
    e->nf = nf;
    e->chi2 = Sxx;
    e->d1 = e->d2 = 0.0;
    for (int f = 0; f < nf; f++) {
        double S = e->S[f], T = e->T[f];
        /* a* <= 0 (or no samples): the constrained fit is a = 0, this part of chi2 flat */
        if (!(T > 0.0) || S <= 0.0) continue;
        /* f = S^2/T, chi2 = Sxx - sum f */
        double f0 = S * S / T;
        double f1 = 2.0 * S * S1[f] / T - S * S * T1[f] / (T * T);
        double f2 = (2.0 * S1[f] * S1[f] + 2.0 * S * S2[f]) / T - 4.0 * S * S1[f] * T1[f] / (T * T) -
                    S * S * T2[f] / (T * T) + 2.0 * S * S * T1[f] * T1[f] / (T * T * T);
        e->chi2 -= f0;
        e->d1 -= f1;
        e->d2 -= f2;
    }
    if (e->chi2 < 0.0) e->chi2 = 0.0;
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

/* The log likelihood of bulb b's sums under the matcher's band model. */
static double loglik_bulb(const rec_matcher *m, const rec_eq7_work *w, int b, double Sxx,
                          const double *S, const double *T)
{
    return m->red ? rec_eq7_loglik_red(m, w, b, Sxx, S, T, NULL, NULL, 0.0) : rec_eq7_loglik_n(m->nfit, Sxx, S, T);
}

/* Refine continuous bulb b around its best grid cell j0: safeguarded Newton on the exact chi2(s)
 * within +-1 cell (its sums from eq7_series.c: rec_eq7_series_row taken for the row), then the
 * peak's log likelihood and std. */
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
        rec_eq7_sums_of(m, w, js[i], Sv, Tv);
        q[i] = Sxx - gain_n(m->nfit, Sv, Tv);
    }
    double den = q[0] - 2.0 * q[1] + q[2];
    double u = den > 0.0 ? 0.5 * cell * (q[0] - q[2]) / den : 0.0;
    if (u < -cell) u = -cell;
    if (u > cell) u = cell;
    double lo = -cell, hi = cell;
    chi2_eval e;
    rec_eq7_series_bulb(m, w, b);
    for (int it = 0;; it++) {   /* (the peak: the last u evaluated, e) */
        chi2_at(m, w, b, sc + u, Sxx, &e);
        if (e.d1 > 0.0) hi = u;
        else lo = u;
        double step;
        if (e.d2 > 0.0) step = -e.d1 / e.d2;
        else step = e.d1 > 0.0 ? -0.25 * (u - lo) : 0.25 * (hi - u);
        double un = u + step;
        if (!(un > lo && un < hi)) un = 0.5 * (lo + hi);
        /* 2e-9 deg of phase, and 1e-4 of the peak's std (chi2 within 1e-8 of its least) */
        double tol = e.d2 > 0.0 ? fmin(1e-4 * sqrt(2.0 / e.d2), 1e-11) : 1e-11;
        if (fabs(un - u) < tol || hi - lo < 1e-11 || it == 59) break;
        u = un;
    }
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
        rec_eq7_sums_of(m, w, j0, Sv, Tv);
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

/* The sums S_f = sum w x t and T_f = sum w t^2 of template t per brightness parameter, and the
 * brightness a_f = S_f/T_f >= 0. */
static void fit_sums(const rec_matcher *m, const rec_eq7_work *w, const double *t, double *S, double *T,
                     double *a_f)
{
    size_t span = (size_t)m->D / (size_t)m->nfit;
    for (int f = 0; f < m->nfit; f++) {
        double s = 0.0, q = 0.0;
        for (size_t d = (size_t)f * span; d < (size_t)(f + 1) * span; d++) {
            s += w->wx[d] * t[d];
            q += w->w[d] * t[d] * t[d];
        }
        S[f] = s;
        T[f] = q;
        a_f[f] = (q > 0.0 && s > 0.0) ? s / q : 0.0;
    }
}

/* Template j (or continuous bulb b at shift s, with its derivative in s when dt is not NULL)
 * into t, and its brightness per parameter a_f from the light's weights. */
static void model_of(const rec_matcher *m, rec_eq7_work *w, int b, size_t j, double s, double *t,
                     double *dt, double *a_f)
{
    size_t D = (size_t)m->D;
    double S[GS_MAX_BANDS], T[GS_MAX_BANDS];
    if (m->cont[b]) rec_eq7_template_at(m, (size_t)b, s, t, dt, NULL, w->acc);
    else memcpy(t, m->t + j * D, sizeof *t * D);
    fit_sums(m, w, t, S, T, a_f);
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
    for (size_t b = 0; b < m->nb; b++) {
        if (!rec_eq7_bulb_active(m, w, b)) continue;
        for (size_t j = m->first[b]; j < m->first[b] + m->count[b]; j++)
            if (isfinite(w->L[j])) w->L[j] = Lmax + kappa * (w->L[j] - Lmax);
    }
    for (size_t b = 0; b < m->nb; b++) {
        if (!w->has_peak[b] || !isfinite(w->peak_L[b])) continue;
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

/* The passes of rec_eq7_light_prepare over a light's samples, written for the vectorizer
 * (GS_VECTOR_LOOP). Comparisons stay in plain loops, which the vectorizer takes after cloning:
 * gcc (12) lowers a comparison of generic vectors for the baseline target in every clone, to
 * scalar code. Sums in 8 interleaved partial sums, taken in a fixed order (lane k sums the samples
 * d = k mod 8 in order, the last ones in lane 0); an unusable sample adds +0, as a select would.
 * The largest and least of positive values by their bits: for doubles >= 0 the bit patterns
 * order as the values. */
#define PREP_LANES 8
typedef double prep_vd __attribute__((vector_size(PREP_LANES * sizeof(double))));

/* ok[d] = 1 where sample d is usable (finite signal, finite sigma > 0), else 0, and its signal
 * and sigma in xc, sc (0 where unusable); the largest usable sigma into *cmax; returns how many
 * are bad (neither usable nor dropped: sigma = +inf). */
GS_VECTOR_LOOP static int prep_scan(const double *restrict x, const double *restrict s, size_t D, double *restrict ok,
                                     double *restrict xc, double *restrict sc, double *cmax)
{
    for (size_t d = 0; d < D; d++) {
        int u = (fabs(x[d]) <= DBL_MAX) & (fabs(s[d]) <= DBL_MAX) & (s[d] > 0.0);
        ok[d] = u ? 1.0 : 0.0;
        xc[d] = u ? x[d] : 0.0;
        sc[d] = u ? s[d] : 0.0;
    }
    long long top = 0, left = 0;   /* the largest sigma's bits; samples neither usable nor dropped */
    for (size_t d = 0; d < D; d++) {
        long long bits;
        memcpy(&bits, &sc[d], sizeof bits);
        top = bits > top ? bits : top;
        left += (ok[d] == 0.0) & !(s[d] > DBL_MAX);
    }
    memcpy(cmax, &top, sizeof *cmax);
    return (int)left;
}

/* Over one band's usable samples (xc, sc from prep_scan), in units of c = 1/(ic1 ic2):
 * sum x^2 - sigma^2 and sum x; returns their count. */
GS_VECTOR_LOOP static int prep_band(const double *restrict xc, const double *restrict sc, const double *restrict ok,
                                     size_t K, double ic1, double ic2, double *sum2, double *sum1)
{
    prep_vd a = {0}, b = {0}, n = {0};
    size_t d = 0;
    for (; d + PREP_LANES <= K; d += PREP_LANES) {
        prep_vd xv, sv, u;
        REC_VLOAD(xv, xc + d);
        REC_VLOAD(sv, sc + d);
        REC_VLOAD(u, ok + d);
        xv = xv * ic1 * ic2;
        sv = sv * ic1 * ic2;
        a += xv * xv - sv * sv;
        b += xv;
        n += u;
    }
    for (; d < K; d++) {
        double xv = xc[d] * ic1 * ic2, sv = sc[d] * ic1 * ic2;
        a[0] += xv * xv - sv * sv;
        b[0] += xv;
        n[0] += ok[d];
    }
    double A = 0.0, B = 0.0, N = 0.0;
    for (int k = 0; k < PREP_LANES; k++) A += a[k], B += b[k], N += n[k];
    *sum1 = B;
    *sum2 = A;
    return (int)N;
}

/* One band's weights ws = 1/(sigma^2 + fe2mu2) and samples xs = x - flat (units of c) where
 * usable and finite (w, wx, xs 0 elsewhere); adds sum ws xs^2 to *Sxx and lowers *wmin to their
 * least weight; returns the samples used, and the usable ones whose weight overflowed in *bad. */
GS_VECTOR_LOOP static int prep_weights(const double *restrict xc, const double *restrict sc, const double *restrict ok,
                                        size_t K, double ic1, double ic2, double fe2mu2, double flat, double *restrict w,
                                        double *restrict wx, double *restrict xs, double *Sxx, double *wmin,
                                        int *bad)
{
    int used = 0, over = 0;
    for (size_t d = 0; d < K; d++) {
        double sv = sc[d] * ic1 * ic2, ws = 1.0 / (sv * sv + fe2mu2), xv = xc[d] * ic1 * ic2 - flat;
        int u = ok[d] != 0.0, good = u & (fabs(ws) <= DBL_MAX) & (fabs(ws * xv * xv) <= DBL_MAX);
        w[d] = good ? ws : 0.0;
        xs[d] = good ? xv : 0.0;
        wx[d] = good ? ws * xv : 0.0;
        used += good;
        over += u & !good;
    }
    long long least = 0x7ff0000000000000LL;   /* the least positive weight's bits (+inf: none) */
    for (size_t d = 0; d < K; d++) {
        long long bits;
        memcpy(&bits, &w[d], sizeof bits);
        least = bits > 0 && bits < least ? bits : least;
    }
    prep_vd sxx = {0};
    size_t d = 0;
    for (; d + PREP_LANES <= K; d += PREP_LANES) {
        prep_vd wxv, xsv;
        REC_VLOAD(wxv, wx + d);
        REC_VLOAD(xsv, xs + d);
        sxx += wxv * xsv;
    }
    for (; d < K; d++) sxx[0] += wx[d] * xs[d];
    double S = 0.0, m;
    memcpy(&m, &least, sizeof m);
    for (int k = 0; k < PREP_LANES; k++) S += sxx[k];
    if (*wmin > 0.0 && *wmin < m) m = *wmin;
    *Sxx += S;
    *wmin = m < INFINITY ? m : *wmin;
    *bad += over;
    return used;
}

void rec_eq7_grid_peak(const rec_matcher *m, rec_eq7_work *w, size_t b, size_t jb)
{
    w->has_peak[b] = 1;
    w->peak_s[b] = m->shift[jb];
    w->peak_L[b] = w->L[jb];
    w->peak_sig[b] = INV_SQRT12;
    w->peak_cell[b] = jb;
}

/* What the catalog keeps of a light's fit (eq7_noise.c), for a light without one. */
static void fit_none(rec_eq7_work *w)
{
    w->fit_bulb = -1;
    w->other_lbf = NAN;
    w->fit_flat_var = INFINITY;
    for (int i = 0; i < REC_TAU_N; i++) w->tau_ll[i] = -INFINITY;
}

int rec_eq7_light_prepare(const rec_matcher *m, rec_eq7_work *w, size_t q, const double *signal,
                          const double *sigma, double fe, rec_match *out)
{
    size_t D = (size_t)m->D, K = (size_t)m->K;
    rec_eq7_work_row(m, w, q);
    rec_eq7_prep *p = &w->prep[q];
    memset(p, 0, sizeof *p);
    /* usable samples: finite signal, finite sigma > 0; sigma = +inf marks a dropped sample */
    double c, *ok = w->r2, *xc = w->s2, *sc = w->m2;   /* (scratch until the answer) */
    int bad = prep_scan(signal, sigma, D, ok, xc, sc, &c);
    /* the band levels: mu_b^2 = mean(x^2 - sigma^2) over the band's usable samples (>= 0), in
     * units of c. A multiplicative excess e per sample adds (e mu_b)^2 to each sample's variance:
     * on average over the band exactly the variance it causes (E chi2 = dof), spread evenly over
     * the K windows. The flat share (rec_eq7_opts.flat_share): x = a (t + phi m) has band means
     * a m_b (1 + phi), so the flat part is phi / (1 + phi) of each band's mean, whatever the
     * template. */
    /* 1/c in two factors: 1 and 1/c, or, for a c so small (subnormal) that 1/c overflows, 2^600
     * and 1/(2^600 c) */
    double ic1 = 1.0 / c <= DBL_MAX ? 1.0 : 0x1p600, ic2 = 1.0 / (ic1 * c), *mu2 = p->mu2, Sxx = 0.0;
    int used = 0;
    for (int band = 0; band < m->bands; band++) {
        size_t o = (size_t)band * K;
        double sum2, sum1;
        int n = prep_band(xc + o, sc + o, ok + o, K, ic1, ic2, &sum2, &sum1);
        mu2[band] = (n > 0 && sum2 > 0.0 && isfinite(sum2)) ? sum2 / n : 0.0;
        double flat = w->flat > 0.0 && n > 0 ? w->flat / (1.0 + w->flat) * sum1 / n : 0.0;
        p->flat[band] = flat;
        int nb = prep_weights(xc + o, sc + o, ok + o, K, ic1, ic2, fe * fe * mu2[band], flat, w->w + o,
                              w->wx + o, w->xs + o, &Sxx, &p->wmin[m->nfit == 1 ? 0 : band], &bad);
        used += nb;
        if (m->nfit > 1) p->full[band] = nb == (int)K;
    }
    if (m->nfit == 1) p->full[0] = used == (int)D;
    unsigned flags = bad ? REC_MATCH_BAD_INPUT : 0u;
    if (used == 0 || !isfinite(Sxx)) {
        rec_eq7_no_answer(out, flags | REC_MATCH_BAD_INPUT);
        fit_none(w);
        return 0;
    }
    p->used = used;
    p->flags = flags;
    p->c = c;
    p->Sxx = Sxx;
    return 1;
}

gs_status rec_eq7_light_finish(const rec_matcher *m, rec_eq7_work *w, size_t q, const double *sigma,
                               double fe, rec_match *out, rec_eq7_excess *excess)
{
    size_t D = (size_t)m->D;
    rec_eq7_work_row(m, w, q);
    const rec_eq7_prep *p = &w->prep[q];
    unsigned flags = p->flags;
    int used = p->used;
    double c = p->c, Sxx = p->Sxx;
    const double *mu2 = p->mu2;
    if (excess) excess->valid = 0;
    fit_none(w);
    /* every template's score where it can matter (eq7_scores.c) */
    double Lmax = rec_eq7_screen(m, w, p, Sxx);
    /* continuous bulbs near the top: refine their peaks exactly */
    int series_row = 0;
    memset(w->has_peak, 0, m->nb);
    for (size_t b = 0; m->ncont && b < m->nb; b++) {
        if (!m->cont[b] || !rec_eq7_bulb_active(m, w, b)) continue;   /* (no peak: screened out) */
        size_t jb = m->first[b] + rec_eq7_argmax(w->L + m->first[b], m->count[b]);
        if (!(w->L[jb] >= Lmax - CUT_REFINE)) {
            rec_eq7_grid_peak(m, w, b, jb);   /* negligible: grid values only */
            continue;
        }
        if (!series_row) rec_eq7_series_row(m, w, rec_eq7_bulb_screen(m));   /* (its DFTs: the screen's) */
        series_row = 1;
        rec_eq7_refine_peak(m, w, b, jb, Sxx);
    }
    for (size_t b = 0; m->ncont && b < m->nb; b++)
        if (w->has_peak[b] && w->peak_L[b] > Lmax) Lmax = w->peak_L[b];
    w->ncand = 0;
    rec_eq7_add_done(m, w);   /* every scored pair counts for one light */
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
            /* tempered, a score d nats below Lmax comes kappa d below it: the screen's cut widens */
            rec_eq7_screen_widen(m, w, p, Sxx, Lmax, CUT_PIXEL / kappa);
            temper(m, w, Lmax, kappa);
            rec_eq7_add_done(m, w);   /* decide consumed them */
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
    fit_sums(m, w, tb, Sv, Tv, a_f);
    for (int f = 0; f < nf; f++) nfree += Tv[f] > 0.0;
    double snr;
    rec_red_fit rf;
    w->fit_bulb = bb;
    memcpy(w->fit_S, Sv, sizeof w->fit_S);
    memcpy(w->fit_T, Tv, sizeof w->fit_T);
    if (m->red) {
        rec_eq7_loglik_red(m, w, bb, Sxx, Sv, Tv, &rf, NULL, 0.0);
        for (int f = 0; f < nf; f++) a_f[f] = rf.band[f];
        snr = rf.z;
        nfree = 2;   /* brightness and optical depth */
    } else {
        /* a / sigma_a (one gain: a sqrt(T), sigma_a = 1/sqrt(T)) */
        snr = nf == 1 ? (Tv[0] > 0.0 ? a_f[0] * sqrt(Tv[0]) : 0.0) : snr_n(nf, Sv, Tv);
    }
    w->fit_z = snr;
    if (w->want_flat) flat_share_of(m, w, tb);
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
    for (int b = 0; b < m->bands; b++) {
        out->band_brightness[b] = (nf == 1 ? a_f[0] * m->bulbs[bb].chroma[b] : a_f[b]) * c;
        out->band_flat[b] = p->flat[b] * c;
    }
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
    if (m->o.nested_tests && snr >= m->o.min_snr && m->o.unknown_p > 0.0) {
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
            for (int c2 = 0; c2 < 2; c2++) {
                size_t j = nt.tmpl[c2];
                int b = j == (size_t)-1 ? bb : m->tbulb[j];
                out->blend_bulb[c2] = b;
                out->blend_phase_deg[c2] = j == (size_t)-1 ? out->phase_deg : rec_eq7_report_phase(m, b, j, m->shift[j]);
                out->blend_share[c2] = nt.share[c2];
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
    /* a winner that holds almost none of its template's energy on the usable samples (the others
     * saturated: sigma = +inf) fits them with any brightness, and the flat prior's -log(T)/2
     * favours it (docs/recognition.md "Dropped samples and the brightness prior"): the data do not
     * show its light, so no answer */
    double t_used = 0.0, t_all = 0.0;
    for (size_t d = 0; d < D; d++) {
        t_all += tb[d] * tb[d];
        if (w->w[d] > 0.0) t_used += tb[d] * tb[d];
    }
    int unseen = t_used < SHOWN_SHARE_MIN * t_all;
    if ((flags & (REC_MATCH_UNKNOWN | REC_MATCH_DIM | REC_MATCH_BLEND)) || unseen) {
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

gs_status rec_eq7_match_light_ws(const rec_matcher *m, rec_eq7_work *w, const double *signal,
                                 const double *sigma, double fe, rec_match *out,
                                 rec_eq7_excess *excess)
{
    if (excess) excess->valid = 0;
    if (!rec_eq7_light_prepare(m, w, 0, signal, sigma, fe, out)) return GS_OK;
    rec_eq7_block_sums(m, w, 1);
    return rec_eq7_light_finish(m, w, 0, sigma, fe, out, excess);
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
