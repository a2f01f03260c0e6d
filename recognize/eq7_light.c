/* eq7_light.c - Eq. 7 for one light (rec_match_light, rec_match_catalog): the scores of every
 * template in double, the continuous-phase refinement, the flags and the answer. */
#include "recognize/internal.h"

#include <cblas.h>
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

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

/* The sums of template j from the rec_eq7_work arrays ([f * M + j]). */
static void sums_of(const rec_matcher *m, const rec_eq7_work *w, size_t j, double *S, double *T)
{
    for (int f = 0; f < m->nfit; f++) {
        S[f] = w->S[(size_t)f * m->M + j];
        T[f] = w->T[(size_t)f * m->M + j];
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

gs_status rec_eq7_match_light_ws(const rec_matcher *m, rec_eq7_work *w, const double *signal,
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
            w->L[j] = rec_eq7_loglik(Sxx, w->S[j], w->T[j]);
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
        rec_eq7_refine_peak(m, w, b, jb, Sxx);
    }
    for (size_t b = 0; b < m->nb; b++)
        if (m->cont[b] && w->peak_L[b] > Lmax) Lmax = w->peak_L[b];
    w->ncand = 0;
    for (size_t j = 0; j < M; j++)
        rec_eq7_add_cand(m, w, j);   /* every pair counts for one light */
    rec_eq7_decision dec;
    rec_eq7_decide(m, w, Lmax, &dec);
    if (dec.bulb < 0) {
        no_answer(out, flags | REC_MATCH_BAD_INPUT);
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
    rec_eq7_work w;
    gs_status s = rec_eq7_work_alloc(m, &w);
    if (s != GS_OK) return s;
    s = rec_eq7_match_light_ws(m, &w, signal, sigma, out);
    rec_eq7_work_free(&w);
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
    rec_eq7_work w;
    gs_status s = rec_eq7_work_alloc(m, &w);
    if (s != GS_OK) return s;
    size_t D = (size_t)m->D;
    for (size_t i = 0; i < cat->count && s == GS_OK; i++) {
        if (cat->flags && (cat->flags[i] & REC_BLOB_NO_SIGNAL)) {
            no_answer(&out[i], REC_MATCH_BAD_INPUT);
            continue;
        }
        s = rec_eq7_match_light_ws(m, &w, cat->signal + i * D, cat->sigma + i * D, &out[i]);
    }
    rec_eq7_work_free(&w);
    return s;
}
