/* eq7_bulbscreen.c - bounds of every grid sum of a continuous bulb from the magnitudes of its
 * cross-spectrum (the Fourier form, internal.h: K divides G), without the grid's inverse FFT:
 * for the pixel path's Fourier screen (eq7_pixscreen.c) and the light path's screen of bulbs
 * (rec_eq7_screen, eq7_scores.c; docs/recognition.md, "Continuous phases": "Per light: the
 * screen of bulbs", and "Pixels": "the Fourier screen").
 *
 * A row v's sum with bulb b's templates at grid cell c is a trigonometric sum,
 *   sum_k v_k t_k(c) = sum_{n <= G/2} f_n Re(C_bn e^{2 pi i n c / G}),
 *   C_bn = sum_band hat_{b,band,n} V_{band, n mod K}
 * (f_n = 1 for n = 0, G/2, else 2; hat the bulb's spectrum over the grid, ahat for t and bhat
 * for t^2; V the K-point DFT of the row's band), so every cell's sum <= C_b0 + sum_{n>0} f_n |C_bn|: from
 * 3 (K/2 + 1) complex products per bulb, the harmonics n <= K/2 exactly and the others grouped
 * by q = n mod K (sum_band tail_{b,band,q} |V_band,q|, tail the sum of |f_n hat_n| over those n);
 * the constant term C_0 (real) with its sign.
 *
 * The light path (weights w, weighted values wx): S_c = sum w x t_c and T_c = sum w t_c^2 are
 * such sums, so per brightness f (its bands)
 *   S_fc <= Sb_f = C_0 + sum_{n>0} f_n |C_n|,   T_fc >= Tb_f = C'_0 - sum_{n>0} f_n |C'_n|
 * (C_0 = sum_band ahat_0 X_0 is real and keeps its sign: the bound of a row whose mean is below
 * zero drops by 2 |C_0|; C' of bhat and the DFT of w), and T_fc >= w_min |t_fc|^2 when
 * no sample of f is dropped. With them free_bounds' bound (eq7_scores.c) holds for every cell:
 *   L_c <= -max(Sxx - sum_f Sb_f^2 / Tb_f, 0)/2 - sum_f log(Tb_f)/2,
 * and a bulb whose bound is below the screen's cut never has its grids computed. Those bounds
 * take S's largest and T's least value at once; rec_eq7_bulb_tighten's coupled bound (below)
 * joins them where unequal weights make the two peak at different cells. */
#include "recognize/internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define BS_LANES 8   /* harmonics padded to a multiple of 8 doubles */

size_t rec_eq7_harmonics_np(const rec_matcher *m)
{
    return ((size_t)m->K / 2 + 1 + BS_LANES - 1) / BS_LANES * BS_LANES;
}

void rec_eq7_harmonic_table(const rec_matcher *m, const double complex *hat, size_t b, double scale, double *a,
                            double *tail)
{
    size_t K = (size_t)m->K, G = (size_t)m->G, nh = G / 2 + 1, keep = K / 2, np = rec_eq7_harmonics_np(m);
    for (int band = 0; band < m->bands; band++) {
        const double complex *h = hat + (b * (size_t)m->bands + (size_t)band) * nh;
        double *ab = a + (size_t)band * 2 * np, *tb = tail + (size_t)band * K;
        for (size_t n = 0; n < nh; n++) {
            double complex v = h[n] * ((n == 0 || 2 * n == G ? 1.0 : 2.0) * scale);
            if (n > keep) {
                tb[n % K] += cabs(v);
                continue;
            }
            ab[n] = creal(v);
            ab[np + n] = cimag(v);
        }
    }
}

/* sum over n < np of |sum_band a_band,n y_band,n| (complex; re and im blocks of np each), 8
 * harmonics at a time (gcc's vector types: the loop over n was compiled as scalar code); the
 * complex sums themselves into z (re and im blocks of np) unless NULL. */
typedef double bs_vd __attribute__((vector_size(BS_LANES * sizeof(double))));
GS_VECTOR_LOOP static double harmonic_sum(const double *a, const double *y, int bands, size_t np, double *z)
{
    bs_vd acc = {0};
    for (size_t n = 0; n < np; n += BS_LANES) {
        bs_vd re = {0}, im = {0};
        for (int band = 0; band < bands; band++) {
            const double *ab = a + (size_t)band * 2 * np + n, *yb = y + (size_t)band * 2 * np + n;
            bs_vd ar, ai, yr, yi;
            REC_VLOAD(ar, ab);
            REC_VLOAD(ai, ab + np);
            REC_VLOAD(yr, yb);
            REC_VLOAD(yi, yb + np);
            re += ar * yr - ai * yi;
            im += ar * yi + ai * yr;
        }
        if (z) {
            memcpy(z + n, &re, sizeof re);
            memcpy(z + np + n, &im, sizeof im);
        }
        bs_vd q = re * re + im * im;
        double t[BS_LANES];
        memcpy(t, &q, sizeof t);
        for (int i = 0; i < BS_LANES; i++) t[i] = sqrt(t[i]);
        memcpy(&q, t, sizeof q);
        acc += q;
    }
    return ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]));
}

double rec_eq7_harmonic_extent(const double *a, const double *y, int bands, size_t np, double tail_sum, double *c0,
                               double *z)
{
    double c = 0.0;
    for (int band = 0; band < bands; band++) c += a[(size_t)band * 2 * np] * y[(size_t)band * 2 * np];
    *c0 = c;
    return harmonic_sum(a, y, bands, np, z) + tail_sum;
}

void rec_eq7_harmonic_row(const rec_matcher *m, const double complex *V, size_t ldv, double *y, double *ya)
{
    size_t K = (size_t)m->K, keep = K / 2, np = rec_eq7_harmonics_np(m);
    for (int band = 0; band < m->bands; band++) {
        const double complex *vb = V + (size_t)band * ldv;
        double *yb = y + (size_t)band * 2 * np;
        for (size_t n = 0; n < np; n++) {
            yb[n] = n <= keep ? creal(vb[n]) : 0.0;
            yb[np + n] = n <= keep ? cimag(vb[n]) : 0.0;
        }
        /* (not cabs: hypot's care took 2 % of a light; a square beyond DBL_MAX gives +inf, no
         * bound: the bulb is scored) */
        for (size_t q = 0; q < K; q++)
            ya[(size_t)band * K + q] = sqrt(creal(vb[q]) * creal(vb[q]) + cimag(vb[q]) * cimag(vb[q]));
    }
}

gs_status rec_eq7_bulbscreen_setup(rec_matcher *m)
{
    /* (every bulb continuous: with discrete bulbs, a closed one could be the runner-up that sets an
     * excess's direction, eq7_light.c) */
    if (!m->fourier || m->red || m->o.nested_tests || (size_t)m->ncont != m->nb) return GS_OK;
    size_t nb = m->nb, bands = (size_t)m->bands, K = (size_t)m->K, np = rec_eq7_harmonics_np(m);
    size_t la = bands * 2 * np, lt = bands * K, nf = (size_t)m->nfit;
    m->bs_a = calloc(nb * la, sizeof *m->bs_a);
    m->bs_b = calloc(nb * la, sizeof *m->bs_b);
    m->bs_at = calloc(nb * lt, sizeof *m->bs_at);
    m->bs_bt = calloc(nb * lt, sizeof *m->bs_bt);
    m->bs_t2 = calloc(nb * nf, sizeof *m->bs_t2);
    if (!m->bs_a || !m->bs_b || !m->bs_at || !m->bs_bt || !m->bs_t2)
        return gs_fail(GS_ENOMEM, "Eq. 7 matcher: cannot allocate the light path's screen of bulbs");
    for (size_t b = 0; b < nb; b++) {
        rec_eq7_harmonic_table(m, m->ahat, b, 1.0, m->bs_a + b * la, m->bs_at + b * lt);
        rec_eq7_harmonic_table(m, m->bhat, b, 1.0, m->bs_b + b * la, m->bs_bt + b * lt);
        /* the least |t_fc|^2 over the bulb's cells, per brightness */
        for (size_t f = 0; f < nf; f++) {
            double lo = INFINITY;
            for (size_t j = m->first[b]; j < m->first[b] + m->count[b]; j++) {
                double t2 = nf == 1 ? exp(2.0 * m->lognorm[j]) : m->bnorm[j * bands + f] * m->bnorm[j * bands + f];
                lo = t2 < lo ? t2 : lo;
            }
            m->bs_t2[b * nf + f] = lo;
        }
    }
    m->bs_on = 1;
    return GS_OK;
}

/* Brightness f of bulb b against the light's rows (rec_eq7_bulb_bounds' harmonic rows in
 * w->bs_y): its terms (rec_eq7_bulb_terms), its cross-spectra C, C' into w->bs_z. Rounding: the
 * FFT's and these sums', far inside 1e-9 of the magnitudes' sums. */
static void bulb_terms(const rec_matcher *m, rec_eq7_work *w, const rec_eq7_prep *p, size_t b, int f,
                       rec_eq7_bulb_terms *t)
{
    size_t bands = (size_t)m->bands, np = rec_eq7_harmonics_np(m), la = bands * 2 * np;
    size_t nf = (size_t)m->nfit, b0 = nf == 1 ? 0 : (size_t)f, nbf = nf == 1 ? bands : 1;
    size_t ka = b0 * 2 * np;
    const double *yx = w->bs_y, *yw = yx + la;
    double *z = w->bs_z + (b * nf + (size_t)f) * 4 * np;
    t->tail_s = w->bs_tmp[(size_t)f * 2 * m->nb + b];
    t->tail_t = w->bs_tmp[((size_t)f * 2 + 1) * m->nb + b];
    t->es = rec_eq7_harmonic_extent(m->bs_a + b * la + ka, yx + ka, (int)nbf, np, t->tail_s, &t->cs, z);
    t->et = rec_eq7_harmonic_extent(m->bs_b + b * la + ka, yw + ka, (int)nbf, np, t->tail_t, &t->ct, z + 2 * np);
    t->sb = t->es - fabs(t->cs) + t->cs + 1e-9 * t->es;
    t->tb = t->ct - (t->et - fabs(t->ct)) - 1e-9 * t->et;
    t->tw = p->full[f] ? p->wmin[f] * m->bs_t2[b * nf + (size_t)f] * (1.0 - 1e-12) : 0.0;
    t->tb = t->tw > t->tb ? t->tw : t->tb;
}

/* lt[i] = log(tb) of the n terms t[i] (1 where tb <= 0: not used), in the clones' vector log. */
GS_VECTOR_LOOP static void terms_logs(const rec_eq7_bulb_terms *t, size_t n, double *lt)
{
    for (size_t i = 0; i < n; i++) lt[i] = log(t[i].tb > 0.0 ? t[i].tb : 1.0);
}

/* Over the brightnesses with a usable sample (lt: log(tb_f), terms_logs): u = -sum_f log(tb_f)/2 and g_f = sb_f^2/tb_f (0 where
 * sb_f <= 0: S <= 0 adds nothing, free_bounds); 0 (no bound) where some tb_f is not positive or
 * sb_f is beyond 1e300 or NaN. */
static int terms_sums(const rec_eq7_bulb_terms *t, const rec_eq7_prep *p, int nf, const double *lt, double *u,
                      double *g)
{
    *u = 0.0;
    for (int f = 0; f < nf; f++) {
        g[f] = 0.0;
        if (!(p->wmin[f] > 0.0)) continue;   /* no usable sample: no brightness */
        if (!(t[f].tb > 0.0) || !(t[f].sb <= 1e300)) return 0;
        *u -= 0.5 * lt[f];
        g[f] = t[f].sb > 0.0 ? t[f].sb * (t[f].sb / t[f].tb) : 0.0;
    }
    return 1;
}

/* The bound on L from each brightness's bounds u = -sum_f log(tb_f)/2 and g >= sum_f S_f^2/T_f
 * (free_bounds' bound, eq7_scores.c), with the rounding's margin. */
static double bound_of(double u, double g, double Sxx)
{
    double d = g - Sxx, v = u + 0.5 * (d < 0.0 ? d : 0.0);
    v += 1e-9 * (1.0 + fabs(v)) + 1e-12 * Sxx;
    return v > -INFINITY ? v : INFINITY;
}

void rec_eq7_bulb_bounds(const rec_matcher *m, rec_eq7_work *w, const rec_eq7_prep *p, double Sxx, double *U)
{
    size_t nb = m->nb, bands = (size_t)m->bands, np = rec_eq7_harmonics_np(m), la = bands * 2 * np;
    size_t nh = (size_t)m->G / 2 + 1, lt = bands * (size_t)m->K;
    const double complex *X = w->spec + nh, *W = X + bands * nh;   /* rec_eq7_light_dfts */
    double *yx = w->bs_y, *yw = yx + la, *xa = yw + la, *wa = xa + lt;
    rec_eq7_harmonic_row(m, X, nh, yx, xa);
    rec_eq7_harmonic_row(m, W, nh, yw, wa);
    for (int f = 0; f < m->nfit; f++) {   /* every bulb's tail sums, of S and of T */
        if (!(p->wmin[f] > 0.0)) continue;
        size_t kt = m->nfit == 1 ? 0 : (size_t)f * m->K, n = m->nfit == 1 ? lt : (size_t)m->K;
        gs_dot_rows(xa + kt, m->bs_at + kt, lt, n, NULL, nb, 1.0, w->bs_tmp + (size_t)f * 2 * nb);
        gs_dot_rows(wa + kt, m->bs_bt + kt, lt, n, NULL, nb, 1.0, w->bs_tmp + ((size_t)f * 2 + 1) * nb);
    }
    for (size_t b = 0; b < nb; b++)
        for (int f = 0; f < m->nfit; f++) {
            rec_eq7_bulb_terms *t = &w->bs_t[b * (size_t)m->nfit + (size_t)f];
            if (p->wmin[f] > 0.0) bulb_terms(m, w, p, b, f, t);
            else t->tb = 0.0;   /* (no brightness: terms_sums passes it over) */
        }
    double *logs = w->bs_tmp;   /* (the tails' sums are in the terms now) */
    terms_logs(w->bs_t, nb * (size_t)m->nfit, logs);
    for (size_t b = 0; b < nb; b++) {
        rec_eq7_bulb_terms *t = w->bs_t + b * (size_t)m->nfit;
        double *ug = w->bs_ug + b * (1 + (size_t)m->nfit), gs = 0.0;   /* (for rec_eq7_bulb_tighten) */
        int ok = terms_sums(t, p, m->nfit, logs + b * (size_t)m->nfit, ug, ug + 1);
        for (int f = 0; f < m->nfit; f++) gs += ug[1 + f];
        U[b] = ok ? bound_of(ug[0], gs, Sxx) : INFINITY;   /* (no bound: the bulb is opened) */
    }
}

/* The coupled bound. At every cell, S^2/T (S > 0; else 0) = max_{mu >= 0} 4 mu (S - mu T), and
 * S - mu T is itself a trigonometric sum, of the cross-spectra C - mu C', so
 *   S^2/T <= max_{mu >= 0} A(mu),   A(mu) = 4 mu h(mu),
 *   h(mu) = C_0 + tail_S - mu (C'_0 - tail_T) + phi(mu),   phi(mu) = sum_{0 < n <= K/2} f_n |C_n - mu C'_n|
 * (the tails' harmonics by the triangle inequality; rounding: 1e-9 (es + mu et)), and with every
 * sample A(mu) <= 4 mu (sb - mu w_min |t|^2) too. phi, a sum of norms of affine functions, is
 * convex, so on [mu_a, mu_c] h is at most its chord and A at most a quadratic whose maximum is
 * exact: a branch and bound over mu in [0, sb/(2 tb)] (each cell's best mu, S/(2T), lies there),
 * at most BS_INTERVALS intervals. S and T peak at different cells with unequal weights; this
 * bound couples them there, where sb and tb alone cannot. Where h overflows (+inf, NaN) only
 * 4 mu (sb - mu tw) bounds, or nothing (+inf) without it. */
typedef struct {
    const double *zr, *zi, *tr, *ti;   /* C_n and C'_n, n < np */
    size_t np;
    double c0, slope, e0, e1;          /* h(mu) = c0 - mu slope + phi(mu) + 1e-9 (e0 + mu e1) */
    double sb, tw;                     /* the bound 4 mu (sb - mu tw) (tw 0: none) */
} bs_coupled;

GS_VECTOR_LOOP static double coupled_h(const bs_coupled *c, double mu)
{
    double phi = 0.0;
    for (size_t n = 1; n < c->np; n++) phi += sqrt((c->zr[n] - mu * c->tr[n]) * (c->zr[n] - mu * c->tr[n]) +
                                                    (c->zi[n] - mu * c->ti[n]) * (c->zi[n] - mu * c->ti[n]));
    return c->c0 - mu * c->slope + phi + 1e-9 * (c->e0 + mu * c->e1);
}

/* max over [a, b] of 4 mu (p + q mu) */
static double quad_max(double p, double q, double a, double b)
{
    double v = 4.0 * a * (p + q * a), vb = 4.0 * b * (p + q * b);
    v = vb > v ? vb : v;
    if (q < 0.0) {
        double x = -0.5 * (p / q);   /* (not p / (2 q): 2 q may overflow) */
        if (x > a && x < b) v = 4.0 * x * (p + q * x) > v ? 4.0 * x * (p + q * x) : v;
    }
    return v;
}

/* the bound function min(A, 4 mu (sb - mu tw)) at mu (h = h(mu)) */
static double coupled_at(const bs_coupled *c, double mu, double h)
{
    double a = 4.0 * mu * h, b = c->tw > 0.0 ? 4.0 * mu * (c->sb - mu * c->tw) : INFINITY;
    return a < b ? a : b;
}

/* its bound over [a, b] from h's chord, at least 0 (NaN: +inf) */
static double coupled_interval(const bs_coupled *c, double a, double b, double ha, double hb)
{
    double q = (hb - ha) / (b - a), v = quad_max(ha - q * a, q, a, b);
    if (c->tw > 0.0) {
        double vw = quad_max(c->sb, -c->tw, a, b);
        v = vw < v || v != v ? vw : v;
    }
    return v > 0.0 ? v : v <= 0.0 ? 0.0 : INFINITY;
}

#define BS_INTERVALS 48
double rec_eq7_coupled_gain(const double *z, size_t np, const rec_eq7_bulb_terms *t, double stop)
{
    bs_coupled c = {.zr = z, .zi = z + np, .tr = z + 2 * np, .ti = z + 3 * np, .np = np,
                    .c0 = t->cs + t->tail_s, .slope = t->ct - t->tail_t, .e0 = t->es, .e1 = t->et,
                    .sb = t->sb, .tw = t->tw};
    double ia[BS_INTERVALS], ib[BS_INTERVALS], ha[BS_INTERVALS], hb[BS_INTERVALS], up[BS_INTERVALS];
    int n = 1;
    ia[0] = 0.0, ib[0] = 0.5 * t->sb / t->tb, ha[0] = coupled_h(&c, 0.0), hb[0] = coupled_h(&c, ib[0]);
    up[0] = coupled_interval(&c, ia[0], ib[0], ha[0], hb[0]);
    double lo = coupled_at(&c, ib[0], hb[0]);
    lo = lo > 0.0 ? lo : 0.0;
    for (;;) {
        int i = 0;
        for (int k = 1; k < n; k++) i = up[k] > up[i] ? k : i;
        if (up[i] < stop || lo >= stop || up[i] - lo <= 1e-6 * up[i] || n == BS_INTERVALS) return up[i];
        double mid = 0.5 * (ia[i] + ib[i]), hm = coupled_h(&c, mid), v = coupled_at(&c, mid, hm);
        lo = v > lo ? v : lo;
        ia[n] = mid, ib[n] = ib[i], ha[n] = hm, hb[n] = hb[i];
        ib[i] = mid, hb[i] = hm;
        up[i] = coupled_interval(&c, ia[i], ib[i], ha[i], hb[i]);
        up[n] = coupled_interval(&c, ia[n], ib[n], ha[n], hb[n]);
        n++;
    }
}

double rec_eq7_bulb_tighten(const rec_matcher *m, rec_eq7_work *w, const rec_eq7_prep *p, double Sxx, size_t b,
                            double th)
{
    size_t np = rec_eq7_harmonics_np(m);
    int nf = m->nfit;
    const rec_eq7_bulb_terms *t = w->bs_t + b * (size_t)nf;
    if (!(w->bub[b] < INFINITY)) return w->bub[b];   /* (no bound: terms_sums failed) */
    const double *ug = w->bs_ug + b * (1 + (size_t)nf);   /* rec_eq7_bulb_bounds' */
    double u = ug[0], g[GS_MAX_BANDS], gs = 0.0;
    for (int f = 0; f < nf; f++) gs += g[f] = ug[1 + f];
    /* sum_f g_f below gth gives a bound below th (the margin: bound_of's rounding's); th = -inf:
     * each brightness's bound as tight as it gets (stop NaN); +inf: its first chord */
    double gth = isfinite(th) ? Sxx + 2.0 * (th - u) - 1e-6 * (1.0 + fabs(th) + fabs(u) + Sxx) : th > 0.0 ? th : NAN;
    for (int f = 0; f < nf; f++) {
        if (!(p->wmin[f] > 0.0) || !(t[f].sb > 0.0)) continue;
        double gc = rec_eq7_coupled_gain(w->bs_z + (b * (size_t)nf + (size_t)f) * 4 * np, np, &t[f], gth - (gs - g[f]));
        if (gc < g[f]) gs -= g[f] - gc, g[f] = gc;
    }
    double v = bound_of(u, gs, Sxx);
    return v < w->bub[b] ? v : w->bub[b];
}
