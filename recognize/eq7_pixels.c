/* eq7_pixels.c - Eq. 7 per pixel (rec_match_pixels): the scores as SGEMM blocks of rows after
 * the rigorous dark-row prefilter, per band with band gains or a model error (docs/recognition.md). */
#include "recognize/internal.h"

#include <cblas.h>
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------------ pixels */

/* 8 floats and 8 doubles as vectors (gcc's vector types: the lane-by-lane loops were compiled
 * as scalar code): the partial sums below are lanes of one vector, the same sums. */
typedef float pix_v8f __attribute__((vector_size(8 * sizeof(float))));
typedef double pix_v8d __attribute__((vector_size(8 * sizeof(double))));

/* xd = the n floats of x as doubles. */
GS_VECTOR_LOOP static void to_double(const float *restrict x, size_t n, double *restrict xd)
{
    for (size_t i = 0; i < n; i++) xd[i] = x[i];
}

/* Sum of squares of n floats in double, 8 partial sums (the chain would be latency bound). */
GS_VECTOR_LOOP double rec_pix_sumsq(const float *x, size_t n)
{
    pix_v8d a = {0};
    size_t i = 0;
    for (; i + 8 <= n; i += 8) {
        pix_v8f xf;
        REC_VLOAD(xf, x + i);
        pix_v8d xd = __builtin_convertvector(xf, pix_v8d);
        a += xd * xd;
    }
    for (; i < n; i++) a[0] += (double)x[i] * (double)x[i];
    return ((a[0] + a[1]) + (a[2] + a[3])) + ((a[4] + a[5]) + (a[6] + a[7]));
}

GS_VECTOR_LOOP static double dot_fd(const float *x, const double *t, size_t n)
{
    pix_v8d a = {0};
    size_t i = 0;
    for (; i + 8 <= n; i += 8) {
        pix_v8f xf;
        pix_v8d tv;
        REC_VLOAD(xf, x + i);
        REC_VLOAD(tv, t + i);
        a += __builtin_convertvector(xf, pix_v8d) * tv;
    }
    for (; i < n; i++) a[0] += (double)x[i] * t[i];
    return ((a[0] + a[1]) + (a[2] + a[3])) + ((a[4] + a[5]) + (a[6] + a[7]));
}

/* LANES floats as one vector (gcc's vector types: the compiler did not vectorize the row loops
 * written lane by lane, nor a lane loop with an early exit), a select by mask (the same values as
 * the scalar a > b ? a : b), and the test whether any lane of a comparison holds. The row loops
 * read LANES floats at a time: their rows are padded to a multiple of LANES. */
typedef float pix_vf __attribute__((vector_size(LANES * sizeof(float))));
typedef int pix_vi __attribute__((vector_size(LANES * sizeof(int))));
#define PIX_SELECT(m, a, b) REC_VSELECT(pix_vf, pix_vi, m, a, b)   /* m ? a : b */
typedef int pix_vi8 __attribute__((vector_size(LANES / 2 * sizeof(int))));
typedef int pix_vi4 __attribute__((vector_size(LANES / 4 * sizeof(int))));
#define PIX_ANY(m, any)                                                                            \
    do {                                                                                           \
        pix_vi8 h_[2];                                                                             \
        pix_vi4 q_[2];                                                                             \
        uint64_t w_[2];                                                                            \
        memcpy(h_, &(m), sizeof h_);                                                               \
        h_[0] |= h_[1];                                                                            \
        memcpy(q_, h_, sizeof q_);                                                                 \
        q_[0] |= q_[1];                                                                            \
        memcpy(w_, q_, sizeof w_);                                                                 \
        (any) = (w_[0] | w_[1]) != 0;                                                              \
    } while (0)

/* max_j (sh_j + rho_j xp) over n (a multiple of LANES) prefilter scores. */
GS_VECTOR_LOOP static float row_bound_perp(const float *sh, const float *rho, float xp, size_t n)
{
    pix_vf mx;
    for (int q = 0; q < LANES; q++) mx[q] = -FLT_MAX;
    for (size_t j = 0; j < n; j += LANES) {
        pix_vf a, r;
        REC_VLOAD(a, sh + j);
        REC_VLOAD(r, rho + j);
        pix_vf v = a + r * xp;
        mx = PIX_SELECT(v > mx, v, mx);
    }
    float r = mx[0];
    for (int q = 1; q < LANES; q++) r = mx[q] > r ? mx[q] : r;
    return r;
}

/* For every continuous-phase bulb among the candidates, the grid cell of highest likelihood
 * (w->peak_cell, w->has_peak), where the sub-cell refinement starts. */
static void continuous_peaks(const rec_matcher *m, rec_eq7_work *w)
{
    const size_t *cand = w->cand, n = w->ncand;
    const double *L = w->L;
    memset(w->has_peak, 0, m->nb);
    for (size_t i = 0; i < n;) {   /* by runs of one bulb's candidates (in the order of j) */
        size_t b = (size_t)m->tbulb[cand[i]], e = i + 1;
        while (e < n && (size_t)m->tbulb[cand[e]] == b) e++;
        if (m->cont[b]) {
            size_t jb = cand[i];   /* the first largest L of the run */
            for (size_t q = i + 1; q < e; q++)
                if (L[cand[q]] > L[jb]) jb = cand[q];
            w->has_peak[b] = 1;
            w->peak_cell[b] = jb;
            w->peak_L[b] = L[jb];   /* (the peak cell's L until the refinement sets it) */
        }
        i = e;
    }
}

/* Pixel log likelihood (as rec_eq7_loglik() with T = |t|^2 / sigma^2, up to a row constant) from the
 * normalised score z = x.t/(|t| sigma); Sxx = |x|^2 / sigma^2. */
static inline double pix_L(const rec_matcher *m, size_t j, double z, double Sxx)
{
    return -0.5 * (Sxx - z * z) - m->lognorm[j] + rec_eq7_log_phi_fast(m, z);
}

/* The largest of n floats (n a multiple of LANES), in LANES partial maxima; NaN-safe in the
 * sense that a row of NaN scores gives NaN. */
GS_VECTOR_LOOP static float row_max(const float *s, size_t n)
{
    pix_vf mx;
    REC_VLOAD(mx, s);
    for (size_t j = LANES; j < n; j += LANES) {
        pix_vf x;
        REC_VLOAD(x, s + j);
        mx = PIX_SELECT(x > mx, x, mx);
    }
    float r = mx[0];
    for (int q = 1; q < LANES; q++) r = mx[q] > r ? mx[q] : r;
    return r;
}

/* u[j] = max(s_j, 0)^2 hf - lnf[j] (the bound U_j in float) for n scores; returns max u. */
GS_VECTOR_LOOP static float row_bounds(const float *s, const float *lnf, float hf, float *u, size_t n)
{
    pix_vf mx, zero = {0};
    for (int q = 0; q < LANES; q++) mx[q] = -FLT_MAX;
    for (size_t j = 0; j < n; j += LANES) {
        pix_vf x, l;
        REC_VLOAD(x, s + j);
        REC_VLOAD(l, lnf + j);
        pix_vf v = PIX_SELECT(x > 0.0f, x, zero);
        pix_vf uu = v * v * hf - l;
        memcpy(u + j, &uu, sizeof uu);
        mx = PIX_SELECT(uu > mx, uu, mx);
    }
    float r = mx[0];
    for (int q = 1; q < LANES; q++) r = mx[q] > r ? mx[q] : r;
    return r;
}

/* The first index where u is v (n - 1 if none); u holds a multiple of LANES floats. */
GS_VECTOR_LOOP static size_t first_equal(const float *u, size_t n, float v)
{
    size_t j = 0;
    for (; j + LANES <= n; j += LANES) {
        pix_vf x;
        REC_VLOAD(x, u + j);
        pix_vi m = x == v;
        int any;
        PIX_ANY(m, any);
        if (any) break;
    }
    while (j + 1 < n && u[j] != v) j++;
    return j;
}

/* The indices j0 + j, j < n, with (double)u[j] + err >= thr into out, in order; returns their
 * number. (u[j] >= lo, lo a float just below thr - err, is the vectorized pre-test; u holds n
 * rounded up to a multiple of LANES floats.) */
GS_VECTOR_LOOP static size_t at_least(const float *u, size_t n, size_t j0, float lo, double err, double thr,
                                      size_t *out)
{
    size_t k = 0;
    for (size_t j = 0; j < n; j += LANES) {
        pix_vf x;
        REC_VLOAD(x, u + j);
        pix_vi m = x >= lo;
        int any;
        PIX_ANY(m, any);
        if (!any) continue;
        for (size_t q = j; q < j + LANES && q < n; q++)
            if ((double)u[q] + err >= thr) out[k++] = j0 + q;
    }
    return k;
}

/* A float phase in [0, 360) (a double just below 360 rounds up to 360.0f). */
static float phase_f(double deg)
{
    float f = (float)deg;
    return f >= 360.0f ? 0.0f : f;
}

/* Scratch of the pixel path. */
typedef struct {
    rec_eq7_work w;
    float *sc;       /* [B * Mp] full scores of a block of surviving rows */
    float *xs;       /* [B * D] surviving rows, gathered */
    size_t *rows;    /* [B] their row indices */
    float *y, *sh;   /* [B * r], [B * Mp] prefilter projections and approximate scores */
    float *ub;       /* [Mp] bounds of one row */
    double *zz;      /* [M] normalised scores of one row (band path: brightness / its std) */
    double *gg;      /* [M] band path: Sxx - chi2 of the constrained fit */
    double *xd;      /* [D] one row in double */
    rec_pixscreen_work fs;   /* the Fourier screen's (m->fs_on) */
    unsigned char *keep;     /* [B] rows it keeps */
    size_t *range;           /* [2 nb] a row's ranges of scored templates (rec_eq7_pixscreen_ranges) */
    double *gd;              /* [G] a bulb's grid of dots (rec_eq7_exact_z) */
    int rest;                /* blocks still to go without the prefilter */
} pix_work;

static void pix_free(pix_work *p)
{
    rec_eq7_work_free(&p->w);
    free(p->sc);
    free(p->xs);
    free(p->rows);
    free(p->y);
    free(p->sh);
    free(p->ub);
    free(p->zz);
    free(p->gg);
    free(p->xd);
    rec_eq7_pixscreen_free(&p->fs);
    free(p->keep);
    free(p->range);
    free(p->gd);
}

#define GRID_RUN 32
void rec_eq7_exact_z(const rec_matcher *m, rec_eq7_work *w, double *gd, const double *xd, double inv,
                     const size_t *cand, size_t n, int grids, double *zz)
{
    int dfts = 0;
    for (size_t i = 0; i < n;) {
        int b = m->tbulb[cand[i]];
        size_t e = i + 1;
        while (e < n && m->tbulb[cand[e]] == b) e++;
        if (grids && m->fourier && m->cont[b] && e - i >= GRID_RUN) {
            if (!dfts) rec_eq7_band_dfts(m, xd, w->spec_v);
            dfts = 1;
            rec_eq7_grid_dots(m, w, (size_t)b, 0, w->spec_v, gd);
            for (size_t q = i; q < e; q++) zz[cand[q]] = gd[m->tcell[cand[q]]] / m->tnorm[cand[q]] * inv;
        } else {
            gs_dot_rows(xd, m->tnd, (size_t)m->D, (size_t)m->D, cand + i, e - i, inv, zz);
        }
        i = e;
    }
}

/* The answer for one surviving row: x row xr, its float scores srow over the nrange ranges of
 * templates range ([lo, hi) pairs, multiples of LANES; the others are not read), noise sigma sg. */
static void pixel_row(const rec_matcher *m, pix_work *pw, const float *xr, const float *srow,
                      const size_t *range, size_t nrange, double sg, int *bulb_out, float *phase_out,
                      float *conf_out)
{
    size_t D = (size_t)m->D, M = m->M;
    rec_eq7_work *w = &pw->w;
    double *zz = pw->zz, *xd = pw->xd;
    float *ub = pw->ub;
    const double min_snr = m->o.min_snr;
    /* early out: every template too dim; a row with a NaN has NaN scores and stops here too */
    float smax = -INFINITY;
    for (size_t i = 0; i < nrange; i++) {
        float v = row_max(srow + range[2 * i], range[2 * i + 1] - range[2 * i]);
        smax = v > smax || isnan(v) ? v : smax;
    }
    if (!((double)smax >= min_snr * sg) || !(smax > 0.0f)) return;
    double ss = rec_pix_sumsq(xr, D);
    if (!isfinite(ss)) return;
    double inv = 1.0 / sg, Sxx = ss * inv * inv;
    /* bounds U_j >= L_j + Sxx/2 (log Phi <= 0) from the float scores; the first largest */
    float umax = -FLT_MAX;
    for (size_t i = 0; i < nrange; i++) {
        size_t lo = range[2 * i];
        float v = row_bounds(srow + lo, m->lnf + lo, (float)(0.5 * inv * inv), ub + lo, range[2 * i + 1] - lo);
        umax = v > umax ? v : umax;
    }
    size_t ju = M - 1;
    for (size_t i = 0; i < nrange; i++) {
        size_t lo = range[2 * i], hi = range[2 * i + 1] < M ? range[2 * i + 1] : M;
        if (lo >= hi) continue;
        size_t j = lo + first_equal(ub + lo, hi - lo, umax);
        if (ub[j] == umax) {
            ju = j;
            break;
        }
    }
    /* error of z^2/2 from the float scores (float dot products, templates rounded to float,
     * the float bound itself): at most 8.9e-7 Sxx measured over 3e7 scores of the generated
     * DELIGHT (K = 26, RGB); FLOAT_ERR allows twice that. Above 1e-3 nats the candidates are
     * rescored in double, so the posterior does not depend on float rounding. */
    double err = rec_pix_float_err(Sxx);
    int exact = err > 1e-3;
    if (exact) to_double(xr, D, xd);
    double zu = exact ? gs_dot(xd, m->tnd + ju * D, D) * inv : srow[ju] * inv;
    /* candidates: the templates whose bound reaches within CUT_PIXEL of a template's L */
    double thr = pix_L(m, ju, zu, Sxx) + 0.5 * Sxx - CUT_PIXEL - 2.0 * err;
    w->ncand = 0;
    for (size_t i = 0; i < nrange; i++) {
        size_t lo = range[2 * i], hi = range[2 * i + 1] < M ? range[2 * i + 1] : M;
        if (lo >= hi) continue;
        w->ncand += at_least(ub + lo, hi - lo, lo, nextafterf((float)(thr - err), -INFINITY), err, thr,
                             w->cand + w->ncand);
    }
    rec_eq7_mark_cands(w, 1);
    const size_t *cand = w->cand, ncand = w->ncand;
    /* the grids' dots only below Sxx = 1e12: beyond, the chi-square Sxx - z^2 would lose its
     * units to their rounding (the inverse FFT's, ~1e-15 of |x| / sigma). Many candidates: one
     * matrix-vector product with every template, but behind the Fourier screen (below 1e12)
     * each bulb's grid from its cross-spectrum, a third of the cost */
    int grids = Sxx < 1e12;
    if (exact && ncand > M / 4 && !(m->fs_on && grids)) {
        cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)M, (int)D, inv, m->tnd, (int)D, xd, 1, 0.0, zz, 1);
    } else {
        if (exact) {
            rec_eq7_exact_z(m, w, pw->gd, xd, inv, cand, ncand, grids, zz);
        } else {
            for (size_t ci = 0; ci < ncand; ci++) zz[cand[ci]] = srow[cand[ci]] * inv;
        }
    }
    double Lmax = -INFINITY, *L = w->L;
    for (size_t ci = 0; ci < ncand; ci++) {
        size_t j = cand[ci];
        L[j] = pix_L(m, j, zz[j], Sxx);
        if (L[j] > Lmax) Lmax = L[j];
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
                    rec_eq7_series_row(m, w, 0);
                    wset = 1;
                }
                size_t js[3] = {jm, j0, jp};
                for (int q = 0; q < 3; q++) {
                    w->S[js[q]] = dot_fd(xr, m->t + js[q] * D, D) * inv;
                    w->T[js[q]] = exp(2.0 * m->lognorm[js[q]]);
                }
                rec_eq7_refine_peak(m, w, b, j0, Sxx);
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
    rec_eq7_decision dec;
    rec_eq7_decide(m, w, Lmax, &dec);
    if (dec.bulb < 0) return;
    double zb = zz[dec.tmpl];
    if (!(zb >= min_snr)) return;                                    /* dim */
    if (Sxx - zb * zb > m->chi2_thr) return;                          /* unknown */
    *bulb_out = dec.bulb;
    if (phase_out) *phase_out = phase_f(rec_eq7_report_phase(m, dec.bulb, dec.tmpl, dec.shift));
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
            L += rec_eq7_log_phi_fast(m, z);
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
    return -0.5 * (Sxx - z * z) - 0.5 * log(T) + rec_eq7_log_phi_fast(m, z);
}

/* The band path's float bounds of n templates (a multiple of LANES; bands blocks of n scores in
 * s, ib, ib2), a vector of LANES templates at a time: u_j = sum_b max(s_jb fi_b, 0)^2 / 2 -
 * blnf_j, and the largest snr^2 kept with its sign, num |num| / den (num = sum_b s_jb ib_jb,
 * den = sum_b fv_b ib2_jb), returned. */
GS_VECTOR_LOOP static float band_bounds(const float *s, size_t n, int nb, const float *fi, const float *fv,
                                         const float *blnf, const float *ib, const float *ib2, float *u)
{
    pix_vf mxs, zero = {0};
    for (int q = 0; q < LANES; q++) mxs[q] = -FLT_MAX;
    for (size_t j0 = 0; j0 < n; j0 += LANES) {
        pix_vf num = zero, den = zero, uu;
        REC_VLOAD(uu, blnf + j0);
        uu = -uu;
        for (int b = 0; b < nb; b++) {
            pix_vf sb, ibb, ib2b;
            REC_VLOAD(sb, s + (size_t)b * n + j0);
            REC_VLOAD(ibb, ib + (size_t)b * n + j0);
            REC_VLOAD(ib2b, ib2 + (size_t)b * n + j0);
            pix_vf z = sb * fi[b], zp = PIX_SELECT(z > 0.0f, z, zero);
            uu += 0.5f * zp * zp;
            num += sb * ibb;
            den += fv[b] * ib2b;
        }
        memcpy(u + j0, &uu, sizeof uu);
        pix_vf s2 = num * PIX_SELECT(num > 0.0f, num, -num) / den;
        mxs = PIX_SELECT(s2 > mxs, s2, mxs);
    }
    float r = mxs[0];
    for (int q = 1; q < LANES; q++) r = mxs[q] > r ? mxs[q] : r;
    return r;
}

/* rec_match_pixels for matchers with per-band brightness or model error (m->bandpath): srow
 * holds the row's float scores per band (bands blocks of Mp). The same rec_eq7_decision as pixel_row,
 * with the band model of rec_eq7_match_light_ws (per-band sigma^2 = sg^2 + (model_error mu_b)^2). */
static void pixel_row_band(const rec_matcher *m, pix_work *pw, const float *xr, const float *srow,
                           double sg, int *bulb_out, float *phase_out, float *conf_out)
{
    size_t D = (size_t)m->D, M = m->M, Mp = m->Mp, K = (size_t)m->K;
    int nb = m->bands;
    rec_eq7_work *w = &pw->w;
    double *zz = pw->zz, *gg = pw->gg, *xd = pw->xd;
    float *ub = pw->ub;
    const double min_snr = m->o.min_snr, fe = m->fe_pix;
    double var[GS_MAX_BANDS], inv[GS_MAX_BANDS], Sxx = 0.0;
    for (int b = 0; b < nb; b++) {
        const float *xb = xr + (size_t)b * K;
        double ssb = rec_pix_sumsq(xb, K), ms = ssb / (double)K - sg * sg;   /* RMS signal level^2 */
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
        float s2max = band_bounds(srow, Mp, nb, fi, fv, m->blnf, m->bib, m->bib2, ub);
        smax = s2max > 0.0f ? sqrt((double)s2max) * (1.0 + 1e-5) : 0.0;   /* float slack */
        umax = row_max(ub, Mp);
        ju = first_equal(ub, M, umax);
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
    double err = rec_pix_float_err(Sxx);
    int exact = err > 1e-3;
    if (exact) {
        to_double(xr, D, xd);
        for (int b = 0; b < nb; b++) p[b] = gs_dot(xd + (size_t)b * K, m->tbn + ju * D + (size_t)b * K, K);
    } else {
        for (int b = 0; b < nb; b++) p[b] = srow[(size_t)b * Mp + ju];
    }
    double g0, s0;
    double thr = band_terms(m, ju, p, var, Sxx, &g0, &s0) + 0.5 * Sxx - CUT_PIXEL - 2.0 * err;
    w->ncand = at_least(ub, M, 0, nextafterf((float)(thr - err), -INFINITY), err, thr, w->cand);
    rec_eq7_mark_cands(w, 1);
    double Lmax = -INFINITY;
    for (size_t ci = 0; ci < w->ncand; ci++) {
        size_t j = w->cand[ci];
        if (exact)
            for (int b = 0; b < nb; b++) p[b] = gs_dot(xd + (size_t)b * K, m->tbn + j * D + (size_t)b * K, K);
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
                    rec_eq7_series_row(m, w, 0);
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
                rec_eq7_refine_peak(m, w, b, j0, Sxx);
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
                        p[band] = gs_dot(xd + (size_t)band * K, m->tbn + jj * D + (size_t)band * K, K);
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
    rec_eq7_decision dec;
    rec_eq7_decide(m, w, Lmax, &dec);
    if (dec.bulb < 0) return;
    if (!(zz[dec.tmpl] >= min_snr)) return;                          /* dim */
    if (Sxx - gg[dec.tmpl] > m->chi2_thr) return;                    /* unknown */
    *bulb_out = dec.bulb;
    if (phase_out) *phase_out = phase_f(rec_eq7_report_phase(m, dec.bulb, dec.tmpl, dec.shift));
    if (conf_out) *conf_out = (float)dec.conf;
}

/* A row's float scores in a block: one per template, with band gains one per band. */
static size_t pix_row_scores(const rec_matcher *m)
{
    return m->Mp * (m->bandpath ? (size_t)m->bands : 1);
}

/* A part's scratch for blocks of up to B rows. */
static gs_status pix_alloc(const rec_matcher *m, size_t B, pix_work *pw)
{
    size_t D = (size_t)m->D, Mp = m->Mp, R = (size_t)m->pr;
    gs_status st = rec_eq7_work_alloc(m, &pw->w);
    if (st != GS_OK) return st;
    pw->sc = malloc(sizeof *pw->sc * B * pix_row_scores(m));
    pw->xs = malloc(sizeof *pw->xs * B * D);
    pw->rows = malloc(sizeof *pw->rows * B);
    pw->y = malloc(sizeof *pw->y * B * (R ? R : 1));
    pw->sh = m->fs_on ? NULL : malloc(sizeof *pw->sh * B * Mp);   /* (no prefilter behind the Fourier screen) */
    pw->ub = calloc(Mp, sizeof *pw->ub);   /* (read whole by the LANES-wide tests) */
    pw->zz = malloc(sizeof *pw->zz * m->M);
    pw->gg = malloc(sizeof *pw->gg * m->M);
    pw->xd = malloc(sizeof *pw->xd * D);
    pw->keep = malloc(B);
    pw->range = malloc(sizeof *pw->range * 2 * m->nb);
    pw->gd = malloc(sizeof *pw->gd * (size_t)(m->G > 0 ? m->G : 1));
    st = rec_eq7_pixscreen_alloc(m, B, &pw->fs);
    if (st != GS_OK) return st;
    if (!pw->keep || !pw->range || !pw->gd || !pw->sc || !pw->xs || !pw->rows || !pw->y || (!m->fs_on && !pw->sh) || !pw->ub || !pw->zz ||
        !pw->gg || !pw->xd)
        return gs_fail(GS_ENOMEM, "Eq. 7 pixels: cannot allocate a %zu x %zu score block", B, Mp);
    return GS_OK;
}

/* The rows [r0, r0 + nr) of rec_match_pixels with the part's scratch pw. */
static void pix_block(const rec_matcher *m, pix_work *pw, const float *x, const float *noise_sigma, size_t r0,
                      size_t nr, int *bulb, float *phase_deg, float *confidence)
{
    size_t D = (size_t)m->D, Mp = m->Mp, R = (size_t)m->pr;
    const double min_snr = m->o.min_snr;
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
     * the full test would find) and needs no full scores. It pays only where it rejects rows:
     * after a block where it passed more than 3/4 of them (an all-lit region) the part's next
     * PIX_PREFILTER_REST blocks go without it (the same answers: a row it rejects is dim for
     * every template). */
    size_t ns = 0;
    int prefilter = R && pw->rest == 0 && !m->fs_on;
    pw->rest -= pw->rest > 0;
    if (prefilter) {
        cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)nr, (int)R, (int)D, 1.0f, xb,
                    (int)D, m->pe, (int)D, 0.0f, pw->y, (int)R);
        cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)nr, (int)Mp, (int)R, 1.0f, pw->y,
                    (int)R, m->pc, (int)R, 0.0f, pw->sh, (int)Mp);
    }
    for (size_t i = 0; i < nr; i++) {
        double sg = noise_sigma[r0 + i];
        if (!(sg > 0.0) || !isfinite(sg)) continue;
        if (prefilter) {
            const float *xr = xb + i * D;
            double ss = rec_pix_sumsq(xr, D), yy = 0.0;
            for (size_t q = 0; q < R; q++) yy += (double)pw->y[i * R + q] * pw->y[i * R + q];
            /* |x_perp| from |x|^2 - |y|^2, plus the rounding of both (an upper bound) */
            float xp = (float)sqrt((ss > yy ? ss - yy : 0.0) + 1e-6 * ss);
            float bound = row_bound_perp(pw->sh + i * Mp, m->prho, xp, Mp);
            /* slack for the float scores of the prefilter */
            if (!((double)bound + 1e-5 * sqrt(ss) >= min_snr * sg) || !isfinite(ss)) continue;
        }
        pw->rows[ns++] = r0 + i;
    }
    if (prefilter && 4 * ns > 3 * nr) pw->rest = PIX_PREFILTER_REST;
    if (ns == 0) return;
    const float *xs = xb;
    if (ns < nr) {
        for (size_t k = 0; k < ns; k++)
            memcpy(pw->xs + k * D, x + pw->rows[k] * D, sizeof *pw->xs * D);
        xs = pw->xs;
    }
    if (m->bandpath) {
        /* per-band scores x_b . u_jb: one SGEMM of K columns per band, scores of row k at
         * sc[k * bands * Mp + b * Mp + j] */
        size_t K = (size_t)m->K, nsc = (size_t)m->bands, ld = nsc * Mp;
        for (size_t band = 0; band < nsc; band++)
            cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)ns, (int)Mp, (int)K, 1.0f,
                        xs + band * K, (int)D, m->tbnf + band * K, (int)D, 0.0f, pw->sc + band * Mp,
                        (int)ld);
        for (size_t k = 0; k < ns; k++) {
            size_t r = pw->rows[k];
            pixel_row_band(m, pw, xs + k * D, pw->sc + k * ld, noise_sigma[r], &bulb[r],
                           phase_deg ? &phase_deg[r] : NULL, confidence ? &confidence[r] : NULL);
        }
        return;
    }
    if (m->fs_on) {
        rec_eq7_pixscreen(m, &pw->fs, xs, ns, noise_sigma, pw->rows, pw->sc, pw->keep);
    } else {
        cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)ns, (int)Mp, (int)D, 1.0f, xs, (int)D,
                    m->tn, (int)D, 0.0f, pw->sc, (int)Mp);
        memset(pw->keep, 1, ns);
    }
    size_t all[2] = {0, Mp};
    for (size_t k = 0; k < ns; k++) {
        size_t r = pw->rows[k];
        if (!pw->keep[k]) continue;
        size_t nrange = m->fs_on ? rec_eq7_pixscreen_ranges(m, &pw->fs, k, pw->range) : 1;
        pixel_row(m, pw, xs + k * D, pw->sc + k * Mp, m->fs_on ? pw->range : all, nrange, noise_sigma[r],
                  &bulb[r], phase_deg ? &phase_deg[r] : NULL, confidence ? &confidence[r] : NULL);
    }
}

/* rec_match_pixels over threads: blocks of B rows taken in turn, one scratch per part. */
typedef struct {
    const rec_matcher *m;
    const float *x, *noise_sigma;
    size_t P, B;
    int *bulb;
    float *phase_deg, *confidence;
    pix_work *pw;   /* [threads] */
} pix_job;

static gs_status pix_part(void *ctx, int part, size_t begin, size_t end)
{
    pix_job *j = ctx;
    pix_work *pw = &j->pw[part];
    if (!pw->ub) {
        gs_status st = pix_alloc(j->m, j->B, pw);
        if (st != GS_OK) return st;
    }
    for (size_t blk = begin; blk < end; blk++) {
        size_t r0 = blk * j->B, nr = j->P - r0 < j->B ? j->P - r0 : j->B;
        pix_block(j->m, pw, j->x, j->noise_sigma, r0, nr, j->bulb, j->phase_deg, j->confidence);
    }
    return GS_OK;
}

gs_status rec_match_pixels(const rec_matcher *m, const float *x, const float *noise_sigma,
                           size_t P, int *bulb, float *phase_deg, float *confidence)
{
    if (!m || (P > 0 && (!x || !noise_sigma || !bulb)))
        return gs_fail(GS_EINVAL, "Eq. 7 pixels: matcher, x, noise_sigma and bulb must not be NULL");
    if (P == 0) return GS_OK;
    /* PIX_BLOCK rows a block, fewer (down to 64: the band path's SGEMMs want rows) where the
     * scores of all templates would pass PIX_BLOCK_BYTES (a continuous DELIGHT: 10,400 a row
     * at K = 26, three times that with per-band scores; the rows are independent, so the
     * answers do not depend on B) */
    size_t B = PIX_BLOCK_BYTES / (sizeof(float) * pix_row_scores(m));
    B = B > PIX_BLOCK ? PIX_BLOCK : B < 64 ? 64 : B;
    B = P < B ? P : B;
    size_t nblk = (P + B - 1) / B;
    int threads = gs_threads_resolve(m->o.threads);
    if ((size_t)threads > nblk) threads = (int)nblk;
    pix_job j = {m, x, noise_sigma, P, B, bulb, phase_deg, confidence, calloc((size_t)threads, sizeof *j.pw)};
    if (!j.pw) return gs_fail(GS_ENOMEM, "Eq. 7 pixels: cannot allocate scratch for %d threads", threads);
    /* On several threads OpenBLAS runs single-threaded for the call: a block's small SGEMMs
     * gain nothing from its threads, and its threaded SGEMMs called from two threads at once
     * contend (docs/recognition.md). The rows are independent: the same answers on any number
     * of threads. */
    int blas = threads > 1 ? gs_blas_serial() : 1;
    gs_status st = gs_parallel_chunks(threads, nblk, 1, pix_part, &j);
    gs_blas_restore(blas);
    for (int t = 0; t < threads; t++) pix_free(&j.pw[t]);
    free(j.pw);
    return st;
}
