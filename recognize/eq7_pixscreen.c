/* eq7_pixscreen.c - the pixel path's Fourier screen for continuous phases (rec_match_pixels with
 * the paper's one-brightness model, every bulb continuous; docs/recognition.md "Continuous
 * phases: the Fourier screen").
 *
 * When K divides the grid G, window k of a continuous bulb is window 0 delayed by G/K cells
 * (internal.h), so a row's score at grid cell c is a trigonometric sum,
 *   x . t_bc = sum_{n < G} C_bn e^{2 pi i n c / G},  C_bn = sum_band ahat_{b,band,n} X_{band, n mod K},
 * X the K-point DFT of the row's band. Hence every grid score of bulb b obeys
 *   x . t_bc / |t_bc| <= max(C_b0 + sum_{n>0} f_n |C_bn|, 0) / min_c |t_bc|   (f_n = 1 for n = 0,
 *   G/2, else 2; the constant term C_b0 is real),
 * from 3 (K/2 + 1) complex products per bulb instead of 3 K G multiply-adds (eq7_bulbscreen.c),
 * plus the float scores' rounding. The screen gives float scores only to the bulbs that can matter, by
 * pixel_row's own rules (eq7_pixels.c):
 *  1. the bulb of the largest bound; a row whose bounds all stay below min_snr sigma is dim for
 *     every template (pixel_row's early out);
 *  2. if the scores so far are below min_snr sigma (or not positive): every bulb whose bound
 *     reaches it (else the row is dim);
 *  3. every bulb whose bound on U_j = max(s_j, 0)^2 / (2 sigma^2) - log |t_j| reaches within
 *     CUT_PIXEL (and the rounding slack) of the largest U so far: pixel_row's threshold is at
 *     least that much (log Phi(z) >= -log 2 for the best bound's z >= 0), so every candidate is
 *     among them, and so is the best bound; every bulb if a score within the rounding of 0 may
 *     hold that bound (log Phi has no floor below 0), or if U overflows.
 * A bulb left out is not read (pixel_row reads the ranges of the scored bulbs, widened to whole
 * vectors, where the others' scores are 0): as if its scores were 0, its U = -log |t_j| would
 * stay below its true U, so it is neither a candidate nor the best bound, and 0 is not above any
 * score that decides. The scores come from
 * bulb_scores, whose every score is one chain of multiply-adds in sample order; the answers are
 * those of that kernel on every bulb (REC_FS_ALL), bit for bit (tests/test_eq7_pixels.c).
 * (SGEMM's scores differ from it in the last bits: its kernels depend on the shapes.) */
#include "recognize/internal.h"

#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

gs_status rec_eq7_pixscreen_setup(rec_matcher *m)
{
    int K = m->K, bands = m->bands;
    size_t nb = m->nb;
    /* (a discrete matcher with shape-only bulbs keeps its prefilter) */
    if (!m->fourier || m->bandpath || (size_t)m->ncont != nb) return GS_OK;
    m->fs_lnfmin = malloc(sizeof *m->fs_lnfmin * nb);
    if (!m->fs_lnfmin) return gs_fail(GS_ENOMEM, "Eq. 7 matcher: cannot allocate the pixel Fourier screen");
    for (size_t b = 0; b < nb; b++) {
        double lmin = INFINITY;
        for (size_t c = 0; c < m->count[b]; c++) {
            double l = m->lognorm[m->first[b] + c];
            lmin = l < lmin ? l : lmin;
        }
        m->fs_lnfmin[b] = lmin;
    }
    /* harmonics 0..K/2 exactly; the others grouped by n mod K (eq7_bulbscreen.c), scaled by
     * 1 / min |t| */
    size_t np = rec_eq7_harmonics_np(m);
    m->fs_a = calloc(nb * (size_t)bands * 2 * np, sizeof *m->fs_a);
    m->fs_tail = calloc(nb * (size_t)bands * (size_t)K, sizeof *m->fs_tail);
    if (!m->fs_a || !m->fs_tail) return gs_fail(GS_ENOMEM, "Eq. 7 matcher: cannot allocate the pixel Fourier screen");
    for (size_t b = 0; b < nb; b++)
        rec_eq7_harmonic_table(m, m->ahat, b, exp(-m->fs_lnfmin[b]), m->fs_a + b * (size_t)bands * 2 * np,
                               m->fs_tail + b * (size_t)bands * (size_t)K);
    size_t D = (size_t)m->D, all = 0;
    m->fs_off = malloc(sizeof *m->fs_off * nb);
    for (size_t b = 0; m->fs_off && b < nb; b++) {
        m->fs_off[b] = all;
        all += (m->count[b] + LANES - 1) / LANES * D * LANES;
    }
    m->fs_tb = calloc(all ? all : 1, sizeof *m->fs_tb);
    if (!m->fs_off || !m->fs_tb) return gs_fail(GS_ENOMEM, "Eq. 7 matcher: cannot allocate the pixel Fourier screen");
    for (size_t b = 0; b < nb; b++)
        for (size_t c = 0; c < m->count[b]; c++)
            for (size_t d = 0; d < D; d++)
                m->fs_tb[m->fs_off[b] + (c / LANES * D + d) * LANES + c % LANES] = m->tn[(m->first[b] + c) * D + d];
    m->fs_on = REC_FS_ON;
    return GS_OK;
}

gs_status rec_eq7_pixscreen_alloc(const rec_matcher *m, size_t B, rec_pixscreen_work *sw)
{
    memset(sw, 0, sizeof *sw);
    if (!m->fs_on) return GS_OK;
    size_t nb = m->nb, gmax = 0;
    for (size_t b = 0; b < nb; b++) gmax = m->count[b] > gmax ? m->count[b] : gmax;
    sw->bound = malloc(sizeof *sw->bound * B * nb);
    sw->state = malloc(sizeof *sw->state * B * nb);
    sw->row = malloc(sizeof *sw->row * B);
    sw->y = malloc(sizeof *sw->y * (size_t)m->bands * 2 * (size_t)m->K);
    sw->yx = malloc(sizeof *sw->yx * (size_t)m->bands * 2 * rec_eq7_harmonics_np(m));
    sw->xa = malloc(sizeof *sw->xa * (size_t)m->bands * (size_t)m->K);
    sw->xd = malloc(sizeof *sw->xd * (size_t)m->D);
    sw->tail = malloc(sizeof *sw->tail * nb);
    gmax = (gmax + LANES - 1) / LANES * LANES;
    sw->xg = malloc(sizeof *sw->xg * (B + 3) * (size_t)m->D);
    sw->og = malloc(sizeof *sw->og * (B + 3) * gmax);
    sw->idx = malloc(sizeof *sw->idx * B);
    if (!sw->bound || !sw->state || !sw->row || !sw->y || !sw->yx || !sw->xa || !sw->xd || !sw->tail || !sw->xg || !sw->og || !sw->idx) {
        rec_eq7_pixscreen_free(sw);
        return gs_fail(GS_ENOMEM, "Eq. 7 pixels: cannot allocate the Fourier screen for %zu rows", B);
    }
    return GS_OK;
}

void rec_eq7_pixscreen_free(rec_pixscreen_work *sw)
{
    free(sw->bound);
    free(sw->state);
    free(sw->row);
    free(sw->y);
    free(sw->yx);
    free(sw->xa);
    free(sw->xd);
    free(sw->tail);
    free(sw->xg);
    free(sw->og);
    free(sw->idx);
    memset(sw, 0, sizeof *sw);
}

/* out[r * ldo + c] = x_r . t_c for the n rows of x (a multiple of 4; ld D) and a bulb's cnt
 * unit templates tb (its blocks in fs_tb: read in order, which the prefetcher follows; with every
 * block's D vectors a stride apart, as a transposed matrix had them, each load missed the
 * cache): vectors of LANES templates times 4 rows, each score one chain of multiply-adds over d
 * in order, so a row's scores do not depend on the rows that share its call (the screen's
 * answers are those of every bulb scored by this kernel, bit for bit). */
typedef float scr_vf __attribute__((vector_size(LANES * sizeof(float))));
typedef int scr_vi __attribute__((vector_size(LANES * sizeof(int))));
GS_VECTOR_LOOP static void bulb_scores(const float *tb, size_t D, const float *x, size_t n, size_t cnt, float *out,
                                       size_t ldo)
{
    for (size_t c = 0; c < cnt; c += LANES)
        for (size_t r = 0; r < n; r += 4) {
            const float *x0 = x + r * D, *x1 = x0 + D, *x2 = x1 + D, *x3 = x2 + D, *tc = tb + c * D;
            scr_vf a0 = {0}, a1 = {0}, a2 = {0}, a3 = {0};
            for (size_t d = 0; d < D; d++) {
                scr_vf t;
                REC_VLOAD(t, tc + d * LANES);
                a0 += x0[d] * t;
                a1 += x1[d] * t;
                a2 += x2[d] * t;
                a3 += x3[d] * t;
            }
            memcpy(out + r * ldo + c, &a0, sizeof a0);
            memcpy(out + (r + 1) * ldo + c, &a1, sizeof a1);
            memcpy(out + (r + 2) * ldo + c, &a2, sizeof a2);
            memcpy(out + (r + 3) * ldo + c, &a3, sizeof a3);
        }
}

/* Over the n scores o: the largest score, the largest float bound U = max(o, 0)^2 hf - lnf (as
 * pixel_row's row_bounds, up to rounding), and the largest U of a score <= eps (which may be <= 0
 * in double); LANES at a time, then the last ones. */
GS_VECTOR_LOOP static void scan_scores(const float *o, const float *lnf, size_t n, float hf, float eps, float *out)
{
    scr_vf ms, mu, mn, zero = {0}, ninf;
    for (int q = 0; q < LANES; q++) ms[q] = mu[q] = mn[q] = ninf[q] = -INFINITY;
    size_t c = 0;
    for (; c + LANES <= n; c += LANES) {
        scr_vf s, l;
        REC_VLOAD(s, o + c);
        REC_VLOAD(l, lnf + c);
        scr_vi pos = s > zero;
        scr_vf v = REC_VSELECT(scr_vf, scr_vi, pos, s, zero), u = v * v * hf - l;
        scr_vf nl = REC_VSELECT(scr_vf, scr_vi, s > eps, ninf, u);
        ms = REC_VSELECT(scr_vf, scr_vi, s > ms, s, ms);
        mu = REC_VSELECT(scr_vf, scr_vi, u > mu, u, mu);
        mn = REC_VSELECT(scr_vf, scr_vi, nl > mn, nl, mn);
    }
    float a = -INFINITY, b = -INFINITY, d = -INFINITY;
    for (int q = 0; q < LANES; q++) {
        a = ms[q] > a ? ms[q] : a;
        b = mu[q] > b ? mu[q] : b;
        d = mn[q] > d ? mn[q] : d;
    }
    for (; c < n; c++) {
        float v = o[c] > 0.0f ? o[c] : 0.0f, u = v * v * hf - lnf[c];
        a = o[c] > a ? o[c] : a;
        b = u > b ? u : b;
        if (!(o[c] > eps) && u > d) d = u;
    }
    out[0] = a;
    out[1] = b;
    out[2] = d;
}

enum { ST_NONE = 0, ST_WANT = 1, ST_DONE = 2 };

/* The float scores of the wanted (row, bulb) pairs: per bulb its rows (gathered, padded to a
 * multiple of 4 with zeros) against its templates by bulb_scores, scattered into sc; each row's
 * largest score, largest U and largest U of a score <= eps (scan_scores). */
static void score_wanted(const rec_matcher *m, rec_pixscreen_work *sw, const float *xs, size_t ns, float *sc)
{
    size_t D = (size_t)m->D, nb = m->nb, Mp = m->Mp;
    for (size_t b = 0; b < nb; b++) {
        size_t n = 0, cnt = m->count[b], f0 = m->first[b];
        for (size_t k = 0; k < ns; k++)
            if (sw->state[k * nb + b] == ST_WANT) {
                sw->state[k * nb + b] = ST_DONE;
                memcpy(sw->xg + n * D, xs + k * D, sizeof *xs * D);
                sw->idx[n++] = k;
            }
        if (n == 0) continue;
        size_t n4 = (n + 3) / 4 * 4, ldo = (cnt + LANES - 1) / LANES * LANES;
        memset(sw->xg + n * D, 0, sizeof *sw->xg * (n4 - n) * D);
        bulb_scores(m->fs_tb + m->fs_off[b], D, sw->xg, n4, cnt, sw->og, ldo);
        for (size_t i = 0; i < n; i++) {
            size_t k = sw->idx[i];
            rec_pixscreen_row *r = &sw->row[k];
            const float *o = sw->og + i * ldo;
            memcpy(sc + k * Mp + f0, o, sizeof *o * cnt);
            float v[3];
            scan_scores(o, m->lnf + f0, cnt, r->hf, r->eps, v);
            r->smax = v[0] > r->smax ? v[0] : r->smax;
            r->umax = v[1] > r->umax ? v[1] : r->umax;
            r->nmax = v[2] > r->nmax ? v[2] : r->nmax;
        }
    }
}

void rec_eq7_pixscreen(const rec_matcher *m, rec_pixscreen_work *sw, const float *xs, size_t ns,
                       const float *noise_sigma, const size_t *rows, float *sc, unsigned char *keep)
{
    size_t D = (size_t)m->D, K = (size_t)m->K, nb = m->nb, Mp = m->Mp, np = rec_eq7_harmonics_np(m);
    int bands = m->bands;
    const double min_snr = m->o.min_snr;
    for (size_t k = 0; k < ns; k++) {
        rec_pixscreen_row *r = &sw->row[k];
        unsigned char *st = sw->state + k * nb;
        double sg = noise_sigma[rows[k]];
        double ss = rec_pix_sumsq(xs + k * D, D);
        keep[k] = isfinite(ss) != 0;   /* pixel_row answers no row with a NaN or Inf */
        memset(st, ST_NONE, nb);
        if (!keep[k]) continue;
        double inv = 1.0 / sg, Sxx = ss * inv * inv, xn = sqrt(ss);
        /* a float score's error: the templates rounded to float and D multiply-adds, twice (the
         * double DFT's, ~K 1e-16 |x|, is far inside the factor 2) */
        double serr = 2.0 * (double)(D + 2) * FLT_EPSILON * 0.5 * xn;
        r->eps = (float)serr;
        r->hf = (float)(0.5 * inv * inv);
        r->err = rec_pix_float_err(Sxx);
        r->smax = -INFINITY;
        r->umax = -INFINITY;
        r->nmax = -INFINITY;
        /* the row's DFT, X_q = sum_k x_k e^{-2 pi i q k / K} ((re, im) pairs), and at harmonics
         * 0..n_kept (X_{n mod K}) */
        double *y = sw->y;
        for (size_t d = 0; d < D; d++) sw->xd[d] = xs[k * D + d];
        for (int band = 0; band < bands; band++)
            rec_eq7_dft(sw->xd + (size_t)band * K, m->dftc, m->dfts, K, y + (size_t)band * 2 * K);
        rec_eq7_harmonic_row(m, (const double complex *)y, K, sw->yx, sw->xa);
        gs_dot_rows(sw->xa, m->fs_tail, (size_t)bands * K, (size_t)bands * K, NULL, nb, 1.0, sw->tail);
        /* slack: the float score's rounding */
        double bmax = -INFINITY;
        for (size_t b = 0; b < nb; b++) {
            double c0, e = rec_eq7_harmonic_extent(m->fs_a + b * (size_t)bands * 2 * np, sw->yx, bands, np, sw->tail[b],
                                                   &c0, NULL);
            /* the constant term with its sign; at least 0 (the bound of a value <= 0 scaled by
             * 1/min |t| would not be one) */
            double bd = fmax(e - fabs(c0) + c0 + 1e-9 * e, 0.0) + serr;
            if (!(bd <= DBL_MAX)) bd = INFINITY;   /* an overflowed DFT: scored */
            sw->bound[k * nb + b] = bd;
            bmax = bd > bmax ? bd : bmax;
        }
        if (!(bmax >= min_snr * sg) && m->fs_on != REC_FS_ALL) {   /* 1: dim for every template */
            keep[k] = 0;
            continue;
        }
        for (size_t b = 0; b < nb; b++)
            if (m->fs_on == REC_FS_ALL || sw->bound[k * nb + b] >= bmax) st[b] = ST_WANT;
    }
    score_wanted(m, sw, xs, ns, sc);
    for (size_t k = 0; k < ns; k++) {   /* 2 */
        double lim = min_snr * noise_sigma[rows[k]];
        if (!keep[k] || ((double)sw->row[k].smax >= lim && sw->row[k].smax > 0.0f)) continue;
        for (size_t b = 0; b < nb; b++)
            if (sw->state[k * nb + b] == ST_NONE && sw->bound[k * nb + b] >= lim) sw->state[k * nb + b] = ST_WANT;
    }
    score_wanted(m, sw, xs, ns, sc);
    for (int pass = 0; pass < 2; pass++) {   /* 3, then every bulb where the best U's score <= 0 */
        for (size_t k = 0; k < ns; k++) {
            rec_pixscreen_row *r = &sw->row[k];
            if (!keep[k]) continue;
            if (pass == 0 && m->fs_on != REC_FS_ALL &&
                (!((double)r->smax >= min_snr * noise_sigma[rows[k]]) || !(r->smax > 0.0f))) {
                keep[k] = 0;   /* 2: dim */
                continue;
            }
            unsigned char *st = sw->state + k * nb;
            /* U here and in row_bounds may round differently (fused or not): the slack */
            double umax = r->umax - 1e-5 * (fabs(r->umax) + 1.0);
            double thr = umax - CUT_PIXEL - 3.0 * r->err - M_LN2 - 1e-3;
            if (r->nmax >= umax || !(thr > -INFINITY && thr < INFINITY)) {
                /* the best bound may have a score <= 0, or U overflows: every bulb */
                for (size_t b = 0; b < nb; b++)
                    if (st[b] == ST_NONE) st[b] = ST_WANT;
                continue;
            }
            if (pass == 1) continue;
            for (size_t b = 0; b < nb; b++) {
                if (st[b] != ST_NONE) continue;
                double v = sw->bound[k * nb + b] > 0.0 ? sw->bound[k * nb + b] : 0.0;
                double ub = v * v * r->hf - m->fs_lnfmin[b];
                if (ub + 1e-5 * (fabs(ub) + 1.0) + r->err >= thr) st[b] = ST_WANT;
            }
        }
        score_wanted(m, sw, xs, ns, sc);
    }
    for (size_t k = 0; k < ns; k++) {   /* 0 where the ranges reach the bulbs left out, and the padding */
        if (!keep[k]) continue;
        float *o = sc + k * Mp;
        memset(o + m->M, 0, sizeof *o * (Mp - m->M));
        for (size_t b = 0; b < nb; b++) {
            if (sw->state[k * nb + b] == ST_DONE) continue;
            /* its first and last partial vectors (a grid of G >= 96 cells holds whole ones) */
            size_t lo = m->first[b], hi = lo + m->count[b];
            size_t a = lo + (LANES - lo % LANES) % LANES, z = hi - hi % LANES;
            if (a > lo) memset(o + lo, 0, sizeof *o * (a - lo));   /* (none when the grids fill */
            if (hi > z) memset(o + z, 0, sizeof *o * (hi - z));    /* whole vectors: G = 208) */
        }
    }
}

size_t rec_eq7_pixscreen_ranges(const rec_matcher *m, const rec_pixscreen_work *sw, size_t k, size_t *range)
{
    size_t n = 0, nb = m->nb;
    for (size_t b = 0; b < nb; b++) {
        if (sw->state[k * nb + b] != ST_DONE) continue;
        size_t lo = m->first[b] / LANES * LANES, hi = (m->first[b] + m->count[b] + LANES - 1) / LANES * LANES;
        if (n > 0 && lo <= range[2 * n - 1]) {
            range[2 * n - 1] = hi;
        } else {
            range[2 * n] = lo;
            range[2 * n + 1] = hi;
            n++;
        }
    }
    return n;
}
