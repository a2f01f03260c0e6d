/* eq7_nested.c - two nested-model tests of a light's best fit (docs/recognition.md, "Blends and
 * bulbs not in DELIGHT"), more powerful than the chi-square test against the alternatives that
 * happen: a smooth deformation of the template (a bulb not in DELIGHT) and a second template (two
 * lights in one aperture). Both compare unconstrained weighted least squares fits on the light's
 * weights (rec_eq7_work w, wx, xs, in units of c); with the matcher's brightness parameters (one,
 * or one per band) the null model is linear, the alternatives add columns, so under the null
 * chi2_null - chi2_alt ~ chi2(extra columns) (a correlated excess widens it: / phi). */
#include "recognize/internal.h"

#include <cblas.h>
#include <math.h>
#include <string.h>

#define MAX_COLS (GS_MAX_BANDS * (1 + 2 * REC_SHAPE_H))

/* Cholesky of the n x n symmetric A (lower triangle used) in place; log det A, or NAN when A is
 * not positive definite. */
static double chol(double *A, int n)
{
    double ld = 0.0;
    for (int i = 0; i < n; i++)
        for (int j = 0; j <= i; j++) {
            double s = A[i * n + j];
            for (int k = 0; k < j; k++) s -= A[i * n + k] * A[j * n + k];
            if (i == j) {
                if (!(s > 1e-12 * A[i * n + i])) return NAN;
                A[i * n + i] = sqrt(s);
                ld += log(A[i * n + i]);
            } else {
                A[i * n + j] = s / A[j * n + j];
            }
        }
    return 2.0 * ld;
}

/* Solve L L^T x = b in place (L from chol). */
static void chol_solve(const double *L, int n, double *b)
{
    for (int i = 0; i < n; i++) {
        for (int k = 0; k < i; k++) b[i] -= L[i * n + k] * b[k];
        b[i] /= L[i * n + i];
    }
    for (int i = n - 1; i >= 0; i--) {
        for (int k = i + 1; k < n; k++) b[i] -= L[k * n + i] * b[k];
        b[i] /= L[i * n + i];
    }
}

/* The samples [lo, hi) outside which column c is zero (the columns of one band: a third of D).
 * Sums skip the zero terms: adding a zero product leaves a sum that starts at +0 unchanged, so
 * they are the same numbers as over all D samples. */
typedef struct {
    size_t lo, hi;
} span;

static span span_of(const double *c, size_t D)
{
    span r = {0, D};
    while (r.lo < D && c[r.lo] == 0.0) r.lo++;
    while (r.hi > r.lo && c[r.hi - 1] == 0.0) r.hi--;
    return r;
}

/* out[j] = sum over d of w_d a_d c_j,d for the n columns c_j = cols + j D (spans sc[j]), over
 * a's span and four columns at a time (independent sums in one pass; each sum's terms in the
 * order of d, those outside its column's span zero). */
static void wdots(const double *w, const double *a, span sa, const double *cols, size_t D,
                  const span *sc, int n, double *out)
{
    for (int j0 = 0; j0 < n; j0 += 4) {
        int nj = n - j0 < 4 ? n - j0 : 4;
        size_t lo = D, hi = 0;
        for (int j = j0; j < j0 + nj; j++) {
            if (sc[j].lo < lo) lo = sc[j].lo;
            if (sc[j].hi > hi) hi = sc[j].hi;
        }
        if (sa.lo > lo) lo = sa.lo;
        if (sa.hi < hi) hi = sa.hi;
        const double *c0 = cols + (size_t)j0 * D, *c1 = c0 + (nj > 1 ? D : 0),
                     *c2 = c0 + (nj > 2 ? 2 * D : 0), *c3 = c0 + (nj > 3 ? 3 * D : 0);
        double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
        for (size_t d = lo; d < hi; d++) {
            double u = w[d] * a[d];
            s0 += u * c0[d];
            s1 += u * c1[d];
            s2 += u * c2[d];
            s3 += u * c3[d];
        }
        double v[4] = {s0, s1, s2, s3};
        for (int j = 0; j < nj; j++) out[j0 + j] = v[j];
    }
}

/* The weighted least-squares fit of y (xs when NULL) on ncol columns (cols[c * D + d]): the
 * coefficients into coef, the residuals into res (may be NULL), chi2 from the residuals
 * themselves (Sxx - fit would cancel at high SNR); -1 when the normal equations are singular. */
static double ls_fit(const rec_eq7_work *w, size_t D, const double *y, const double *cols, int ncol,
                     double *coef, double *res)
{
    double A[MAX_COLS * MAX_COLS] = {0}, own[REC_NESTED_MAX_D];
    span sp[MAX_COLS] = {{0, 0}};
    if (!y) y = w->xs;
    if (!res) res = own;
    span sy = span_of(y, D);
    for (int i = 0; i < ncol; i++) sp[i] = span_of(cols + (size_t)i * D, D);
    wdots(w->w, y, sy, cols, D, sp, ncol, coef);
    for (int i = 0; i < ncol; i++) wdots(w->w, cols + (size_t)i * D, sp[i], cols, D, sp, i + 1, A + i * ncol);
    if (isnan(chol(A, ncol))) return -1.0;
    chol_solve(A, ncol, coef);
    memcpy(res, y, sizeof *res * D);
    for (int i = 0; i < ncol; i++)
        for (size_t d = sp[i].lo; d < sp[i].hi; d++) res[d] -= coef[i] * cols[(size_t)i * D + d];
    double chi2 = 0.0;
    for (size_t d = 0; d < D; d++)
        if (w->w[d] > 0.0) chi2 += w->w[d] * res[d] * res[d];
    return chi2;
}

static double ls_chi2(const rec_eq7_work *w, size_t D, const double *cols, int ncol)
{
    double coef[MAX_COLS];
    return ls_fit(w, D, NULL, cols, ncol, coef, NULL);
}

/* log of the Bayes factor of "a bulb not in DELIGHT near this template" against the template,
 * for each of the ntau deformation sizes taus (into lb): the nh deformation columns (after the
 * nt template columns in cols) with coefficients ~ N(0, (tau level_b)^2), level_b the fitted
 * model's mean in the column's band, marginalised exactly (linear Gaussian), with the
 * brightness profiled: with P the columns made W-orthogonal to the template's, G = P'WP,
 * b = P'Wr (r the template fit's residual), S the prior variances: log BF = b'(G + S^-1)^-1 b / 2
 * - log det(I + S G) / 2 (P, G and b do not depend on tau). phi deflates the data term for a
 * correlated excess. scratch: (nh + 1) * D doubles. */
static void other_log_bf(const rec_eq7_work *w, size_t D, size_t K, double *cols, int nt, int nh,
                         const double *taus, int ntau, double phi, double *scratch, double *lb)
{
    double coef[MAX_COLS], level[GS_MAX_BANDS] = {0}, *r = scratch, *P = scratch + D;
    for (int t = 0; t < ntau; t++) lb[t] = -INFINITY;
    if (ls_fit(w, D, NULL, cols, nt, coef, r) < 0.0) return;
    for (size_t d = 0; d < D; d++) {   /* the fitted model's mean per band */
        double v = 0.0;
        for (int i = 0; i < nt; i++) v += coef[i] * cols[(size_t)i * D + d];
        level[d / K] += v / (double)K;
    }
    double G0[MAX_COLS * MAX_COLS], b[MAX_COLS];
    span sp[MAX_COLS] = {{0, 0}}, sr = span_of(r, D);
    size_t band[MAX_COLS];
    for (int h = 0; h < nh; h++) {
        const double *ph = cols + (size_t)(nt + h) * D;
        double c2[MAX_COLS];
        if (ls_fit(w, D, ph, cols, nt, c2, P + (size_t)h * D) < 0.0) return;
        sp[h] = span_of(P + (size_t)h * D, D);
        span sh = span_of(ph, D);
        band[h] = sh.lo < D ? sh.lo / K : 0;   /* the column's band: its first nonzero sample's */
    }
    for (int i = 0; i < nh; i++) {
        wdots(w->w, P + (size_t)i * D, sp[i], r, D, &sr, 1, b + i);   /* w p_i r, in that order */
        wdots(w->w, P + (size_t)i * D, sp[i], P, D, sp, i + 1, G0 + i * nh);
    }
    for (int t = 0; t < ntau; t++) {
        double G[MAX_COLS * MAX_COLS], lds = 0.0;
        int ok = 1;
        memcpy(G, G0, sizeof *G * (size_t)(nh * nh));
        for (int i = 0; i < nh && ok; i++) {
            double sd = taus[t] * fabs(level[band[i]]);
            ok = sd > 0.0;
            G[i * nh + i] += 1.0 / (sd * sd);
            lds += 2.0 * log(sd);
        }
        double ld = ok ? chol(G, nh) : NAN;
        if (isnan(ld)) continue;
        double y[MAX_COLS], q = 0.0;
        memcpy(y, b, sizeof *y * (size_t)nh);
        chol_solve(G, nh, y);
        for (int i = 0; i < nh; i++) q += b[i] * y[i];
        lb[t] = 0.5 * q / phi - 0.5 * (ld + lds);
    }
}

/* The template columns of template t: one column (one brightness) or one per band. */
static int template_cols(const rec_matcher *m, const double *t, double *cols)
{
    size_t D = (size_t)m->D, K = (size_t)m->K;
    if (m->nfit == 1) {
        memcpy(cols, t, sizeof *cols * D);
        return 1;
    }
    memset(cols, 0, sizeof *cols * D * (size_t)m->bands);
    for (int b = 0; b < m->bands; b++)
        memcpy(cols + (size_t)b * D + (size_t)b * K, t + (size_t)b * K, sizeof *cols * K);
    return m->bands;
}

/* Template j is bulb b within two cells of shift s (the same template for a discrete set). */
static int near(const rec_matcher *m, size_t j, int b, double s)
{
    if (m->tbulb[j] != b) return 0;
    double ds = fabs(m->shift[j] - s);
    ds = ds > 0.5 ? 1.0 - ds : ds;
    return m->cont[b] ? ds < 2.0 / m->G : ds < 1e-9;
}

/* ok[j] = 0 for bulb b's templates near shift s. */
static void mask_near(const rec_matcher *m, int b, double s, double *ok)
{
    for (size_t j = m->first[b]; j < m->first[b] + m->count[b]; j++)
        if (near(m, j, b, s)) ok[j] = 0.0;
}

static double tail(double delta, int extra, double phi)
{
    if (extra < 1) return 1.0;
    long dof = lround(extra / phi);
    return gs_chi2_sf(delta / phi, dof > 1 ? (int)dof : 1);
}

/* The blend search's pairs of first template r (its sums S1, T11 > 0 in one brightness) with
 * every template j (S2, T22, and T12 their cross sums): what t_j explains beyond t_r in that
 * brightness, (S2 - T12 S1/T11)^2 / (T22 - T12^2/T11), added to gain[j]; ok[j] = 0 where either
 * brightness of the 2 x 2 least squares would be negative (a2 = r2 / q, a1 = (S1 - T12 a2) / T11:
 * their numerators' signs) or q is not positive. */
GS_VECTOR_LOOP static void pair_gains(const double *restrict S2, const double *restrict T22, const double *restrict T12,
                                       size_t M, double S1, double T11, double *restrict gain, double *restrict ok)
{
    double a1 = S1 / T11, i11 = 1.0 / T11;
    for (size_t j = 0; j < M; j++) {
        double r2 = S2[j] - T12[j] * a1, q = T22[j] - T12[j] * T12[j] * i11, a2 = r2 / q;
        int good = (r2 >= 0.0) & (q > 1e-9 * T22[j]) & (S1 - T12[j] * a2 >= 0.0);
        gain[j] += good ? r2 * a2 : 0.0;
        ok[j] = good ? ok[j] : 0.0;
    }
}

GS_VECTOR_LOOP static void pair_init(double *restrict gain, double *restrict ok, size_t M)
{
    for (size_t j = 0; j < M; j++) gain[j] = 0.0, ok[j] = 1.0;
}

/* ok[j] = base + gain[j] where ok[j] != 0 (a number), else -inf: the pairs' chi2 drops. */
GS_VECTOR_LOOP static void pair_deltas(const double *restrict gain, double *restrict ok, size_t M, double base)
{
    for (size_t j = 0; j < M; j++) {
        double d = base + gain[j];
        ok[j] = ok[j] != 0.0 && d > -INFINITY ? d : -INFINITY;
    }
}

void rec_eq7_nested_tests(const rec_matcher *m, rec_eq7_work *w, const double *tb, int best_bulb,
                          size_t best_tmpl, double best_shift, double phi, rec_eq7_nested *out)
{
    size_t D = (size_t)m->D, K = (size_t)m->K, M = m->M;
    int B = m->bands, nf = m->nfit;
    double cols[MAX_COLS * REC_NESTED_MAX_D];
    memset(out, 0, sizeof *out);
    out->p_shape = out->p_blend = 1.0;
    out->tmpl[0] = out->tmpl[1] = (size_t)-1;
    if (D > REC_NESTED_MAX_D) return;
    int used_bands = 0, used = 0;
    for (int b = 0; b < B; b++) {
        int n = 0;
        for (size_t k = 0; k < K; k++) n += w->w[(size_t)b * K + k] > 0.0;
        used_bands += n > 0;
        used += n;
    }
    /* the null: the best template, unconstrained */
    int nc = template_cols(m, tb, cols);
    double chi0 = ls_chi2(w, D, cols, nc);
    if (chi0 < 0.0) return;
    out->chi2_null = chi0;

    /* a smooth deformation: + harmonics 1..H per band (H <= (K - 2) / 2: the columns stay fewer
     * than the frames) */
    int H = REC_SHAPE_H < ((int)K - 2) / 2 ? REC_SHAPE_H : ((int)K - 2) / 2, nsh = nc;
    for (int b = 0; b < B && H >= 1; b++)
        for (int h = 1; h <= H; h++)
            for (int q = 0; q < 2; q++) {
                double *c = cols + (size_t)nsh * D;
                memset(c, 0, sizeof *c * D);
                memcpy(c + (size_t)b * K, m->harm + (size_t)(2 * (h - 1) + q) * K, sizeof *c * K);
                nsh++;
            }
    out->p_other = 0.0;
    out->lbf_other = NAN;
    if (H >= 1 && used > nsh + 1) {
        double chi_sh = ls_chi2(w, D, cols, nsh);
        if (chi_sh >= 0.0) {
            out->chi2_shape = chi_sh;
            out->extra_shape = 2 * H * used_bands;
            out->p_shape = tail(chi0 - chi_sh, out->extra_shape, phi);
        }
        /* the posterior of "not in DELIGHT" (prior other_prior) */
        static const double taus[] = REC_OTHER_TAUS;   /* a mixture over the deformation's size */
        const int nt = (int)(sizeof taus / sizeof *taus);
        double lb[8], lmax = -INFINITY, sum = 0.0;
        other_log_bf(w, D, K, cols, nc, nsh - nc, taus, nt, phi, w->scratch, lb);
        for (int i = 0; i < nt; i++)
            if (lb[i] > lmax) lmax = lb[i];
        for (int i = 0; i < nt && isfinite(lmax); i++) sum += exp(lb[i] - lmax);
        double lbf = isfinite(lmax) ? lmax + log(sum / nt) : -INFINITY;
        out->lbf_other = lbf;
        /* the prior: the capture's measured share (rec_match_catalog), the options', or (NaN
         * for one light alone) the closed world */
        double pr = w->has_other_prior ? w->other_prior : isnan(m->o.other_prior) ? 0.0 : m->o.other_prior;
        double lo = pr > 0.0 ? log(pr / (1.0 - pr)) + lbf : -INFINITY;
        out->p_other = lo > 0.0 ? 1.0 / (1.0 + exp(-lo)) : exp(lo) / (1.0 + exp(lo));
    }

    /* a second template: for the best fit and the next best templates j1, every template j2 (not
     * the first one's bulb within two cells), by per-band 2 x 2 least squares with both
     * brightnesses >= 0; the sums of j2 from the work arrays (S, T), the cross terms
     * T12 = T_mat (w t1) */
    if (used <= 2 * nf + 2) return;
    /* the first templates: the best fit, then the next best grid templates by L (ties to the
     * lower index), in one pass */
    size_t first[REC_NESTED_FIRST];
    int nr = 1;
    first[0] = best_tmpl;
    for (size_t j = 0; j < M; j++) {
        if (j == best_tmpl || !isfinite(w->L[j])) continue;
        if (nr == REC_NESTED_FIRST && !(w->L[j] > w->L[first[nr - 1]])) continue;
        int q = nr < REC_NESTED_FIRST ? nr++ : nr - 1;
        while (q > 1 && w->L[j] > w->L[first[q - 1]]) {
            first[q] = first[q - 1];
            q--;
        }
        first[q] = j;
    }
    int nfirst = nr - 1;
    /* their weighted templates u_r = w t_r (D x nr) and the cross sums of every template with
     * each, T12 = T_mat U (per band with band gains): one matrix product */
    double S1v[REC_NESTED_FIRST][GS_MAX_BANDS], T11v[REC_NESTED_FIRST][GS_MAX_BANDS], e1v[REC_NESTED_FIRST];
    double *U = w->scratch;   /* D * REC_NESTED_FIRST doubles (rec_eq7_work_alloc) */
    _Static_assert(REC_NESTED_FIRST <= 2 * 3 * GS_MAX_BANDS + 1, "the scratch holds U");
    for (int r = 0; r < nr; r++) {
        const double *t1 = r == 0 ? tb : m->t + first[r] * D;
        double e1 = 0.0;
        for (int f = 0; f < nf; f++) S1v[r][f] = T11v[r][f] = 0.0;
        size_t span_f = nf == 1 ? D : K;   /* the samples of one brightness parameter */
        for (int f = 0; f < nf; f++) {
            double S1 = 0.0, T11 = 0.0;
            for (size_t d = (size_t)f * span_f; d < (size_t)(f + 1) * span_f; d++) {
                S1 += w->wx[d] * t1[d];
                T11 += w->w[d] * t1[d] * t1[d];
                U[d * REC_NESTED_FIRST + (size_t)r] = w->w[d] * t1[d];
            }
            S1v[r][f] = S1;
            T11v[r][f] = T11;
        }
        for (int f = 0; f < nf; f++) e1 += T11v[r][f] > 0.0 ? S1v[r][f] * S1v[r][f] / T11v[r][f] : 0.0;
        e1v[r] = e1;
    }
    if (m->fourier && !m->exhaustive && (size_t)m->ncont == m->nb) {
        /* every template a continuous grid: each first template's cross sums with a bulb's grid
         * from their Fourier form, as the light's own sums (eq7_sums.c), not one product with
         * all nb G templates */
        double *u = w->dt;   /* (D: free here) */
        for (int r = 0; r < nr; r++) {
            for (size_t d = 0; d < D; d++) u[d] = U[d * REC_NESTED_FIRST + (size_t)r];
            rec_eq7_band_dfts(m, u, w->spec_v);
            for (int f = 0; f < nf; f++)
                for (size_t b = 0; b < m->nb; b++)
                    rec_eq7_grid_dots(m, w, b, f, w->spec_v,
                                      w->t12 + ((size_t)f * REC_NESTED_FIRST + (size_t)r) * M + m->first[b]);
        }
    } else {
        for (int f = 0; f < nf; f++) {   /* T12 = U' T_mat': [f][r][j] */
            size_t off = nf == 1 ? 0 : (size_t)f * K, len = nf == 1 ? D : K;
            cblas_dgemm(CblasRowMajor, CblasTrans, CblasTrans, nr, (int)M, (int)len, 1.0, U + off * REC_NESTED_FIRST,
                        REC_NESTED_FIRST, m->t + off, (int)D, 0.0, w->t12 + (size_t)f * REC_NESTED_FIRST * M, (int)M);
        }
    }
    /* a second template: for each first template j1, every template j2 (not the first one's
     * bulb within two cells), by per-band 2 x 2 least squares with both brightnesses >= 0; the
     * sums of j2 from the work arrays (S, T) */
    double best_delta = 0.0, e0 = e1v[0], best_occam = 0.0, *gain = w->tmp, *ok = w->tmp + M;
    size_t best_j = M;
    int best_r = 0;
    for (int r = 0; r < nr; r++) {
        int b1 = r == 0 ? best_bulb : m->tbulb[first[r]];
        double s1 = r == 0 ? best_shift : m->shift[first[r]];
        pair_init(gain, ok, M);
        for (int f = 0; f < nf; f++)
            if (T11v[r][f] > 0.0)
                pair_gains(w->S + (size_t)f * M, w->T + (size_t)f * M, w->t12 + ((size_t)f * REC_NESTED_FIRST + (size_t)r) * M,
                           M, S1v[r][f], T11v[r][f], gain, ok);
        /* the first template of the largest drop, itself and its neighbours (and the best
         * fit's, r > 0: paired at r = 0) left out */
        mask_near(m, b1, s1, ok);
        if (r > 0) mask_near(m, best_bulb, best_shift, ok);
        pair_deltas(gain, ok, M, e1v[r] - e0);
        size_t j = rec_eq7_argmax(ok, M);
        double delta = ok[j];   /* chi2 of the best fit minus the pair's */
        if (!(delta > best_delta)) continue;
        best_delta = delta;
        best_j = j;
        best_r = r;
    }
    /* a pair of two first templates was searched in both orders (the second's not next to the
     * best fit), and rounding picked one (the same Delta, not the same Occam factor): the first
     * is the one of higher L, as the best fit is when it is in the pair */
    for (int r = 1; best_j < M && r < best_r; r++)
        if (first[r] == best_j && !near(m, first[best_r], best_bulb, best_shift)) {
            best_j = first[best_r];
            best_r = r;
            break;
        }
    if (best_j < M) {
        /* the winner's shares and the second brightness's Occam factor: its std 1/sqrt(q)
         * against a flat prior on [0, the light's brightness in the band] */
        const double *S1 = S1v[best_r], *T11 = T11v[best_r];
        double a1s = 0.0, a2s = 0.0, occam = 0.0;
        for (int f = 0; f < nf; f++) {
            if (!(T11[f] > 0.0)) continue;
            double S2 = w->S[(size_t)f * M + best_j], T22 = w->T[(size_t)f * M + best_j];
            double T12 = w->t12[((size_t)f * REC_NESTED_FIRST + (size_t)best_r) * M + best_j];
            double r2 = S2 - T12 * S1[f] / T11[f], q = T22 - T12 * T12 / T11[f];
            double a2 = r2 / q, a1 = (S1[f] - T12 * a2) / T11[f];
            a1s += a1;
            a2s += a2;
            double atot = S1[f] / T11[f];
            occam += atot > 0.0 ? 0.5 * log(2.0 * M_PI / q) - log(atot) : 0.0;
        }
        out->tmpl[0] = best_r == 0 ? (size_t)-1 : first[best_r];
        out->tmpl[1] = best_j;
        out->share[0] = a1s + a2s > 0.0 ? a1s / (a1s + a2s) : 0.5;
        out->share[1] = 1.0 - out->share[0];
        best_occam = occam < 0.0 ? occam : 0.0;
    }
    if (!(best_delta > 0.0)) return;
    /* the winner's chi2 again from its residuals (the search's sums cancel at high SNR) */
    const double *t1 = out->tmpl[0] == (size_t)-1 ? tb : m->t + out->tmpl[0] * D;
    int n1 = template_cols(m, t1, cols);
    int n2 = template_cols(m, m->t + out->tmpl[1] * D, cols + (size_t)n1 * D);
    double chi_pair = ls_chi2(w, D, cols, n1 + n2);
    if (!(chi_pair >= 0.0) || !(chi_pair < chi0)) return;
    best_delta = chi0 - chi_pair;
    out->chi2_blend = chi_pair;
    out->extra_blend = nf + 1;
    /* the posterior of a blend (prior blend_prior): the pair's evidence over the single's,
     * each template a priori 1/M (the pair in either order), the second brightness's Occam
     * factor: BF = 2 exp(delta / 2) occam / M (its best term: a lower bound) */
    double pb = m->o.blend_prior, lbf = log(2.0 / (double)M) + 0.5 * best_delta / phi + best_occam;
    double lo = pb > 0.0 ? log(pb / (1.0 - pb)) + lbf : -INFINITY;
    out->p_blend_post = lo > 0.0 ? 1.0 / (1.0 + exp(-lo)) : exp(lo) / (1.0 + exp(lo));
    /* the second template was searched over M for 1 + nfirst first ones: Bonferroni */
    double p = tail(best_delta, nf, phi) * (double)M * (double)(1 + nfirst);
    out->p_blend = p < 1.0 ? p : 1.0;
    out->found = 1;
}
