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
 * and a bulb whose bound is below the screen's cut never has its grids computed. */
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
 * harmonics at a time (gcc's vector types: the loop over n was compiled as scalar code). */
typedef double bs_vd __attribute__((vector_size(BS_LANES * sizeof(double))));
GS_VECTOR_LOOP static double harmonic_sum(const double *a, const double *y, int bands, size_t np)
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
        bs_vd q = re * re + im * im;
        double t[BS_LANES];
        memcpy(t, &q, sizeof t);
        for (int i = 0; i < BS_LANES; i++) t[i] = sqrt(t[i]);
        memcpy(&q, t, sizeof q);
        acc += q;
    }
    return ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]));
}

double rec_eq7_harmonic_extent(const double *a, const double *tail, const double *y, const double *ya, int bands,
                               size_t np, size_t K, double *c0)
{
    double c = 0.0;
    for (int band = 0; band < bands; band++) c += a[(size_t)band * 2 * np] * y[(size_t)band * 2 * np];
    *c0 = c;
    return harmonic_sum(a, y, bands, np) + gs_dot(tail, ya, (size_t)bands * K);
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

void rec_eq7_bulb_bounds(const rec_matcher *m, rec_eq7_work *w, const rec_eq7_prep *p, double Sxx, double *U)
{
    size_t nb = m->nb, bands = (size_t)m->bands, K = (size_t)m->K, np = rec_eq7_harmonics_np(m);
    size_t nh = (size_t)m->G / 2 + 1, la = bands * 2 * np, lt = bands * K;
    int nf = m->nfit;
    const double complex *X = w->spec + nh, *W = X + bands * nh;   /* rec_eq7_light_dfts */
    double *yx = w->bs_y, *yw = yx + la, *xa = yw + la, *wa = xa + lt;
    rec_eq7_harmonic_row(m, X, nh, yx, xa);
    rec_eq7_harmonic_row(m, W, nh, yw, wa);
    for (size_t b = 0; b < nb; b++) {
        double u = 0.0, g = 0.0;
        int none = 0;   /* no bound: the bulb is opened */
        for (int f = 0; f < nf && !none; f++) {
            if (!(p->wmin[f] > 0.0)) continue;   /* no usable sample: no brightness */
            size_t b0 = nf == 1 ? 0 : (size_t)f, nbf = nf == 1 ? bands : 1, ka = b0 * 2 * np, kt = b0 * K;
            double cs, ct;
            double es = rec_eq7_harmonic_extent(m->bs_a + b * la + ka, m->bs_at + b * lt + kt, yx + ka, xa + kt,
                                                (int)nbf, np, K, &cs);
            double et = rec_eq7_harmonic_extent(m->bs_b + b * la + ka, m->bs_bt + b * lt + kt, yw + ka, wa + kt,
                                                (int)nbf, np, K, &ct);
            /* the sums' constant terms with their signs; rounding: the FFT's and these sums', far
             * inside 1e-9 of the magnitudes' sum */
            double sb = es - fabs(cs) + cs + 1e-9 * es, tb = ct - (et - fabs(ct)) - 1e-9 * et;
            if (p->full[f]) {
                double tw = p->wmin[f] * m->bs_t2[b * (size_t)nf + (size_t)f] * (1.0 - 1e-12);
                tb = tw > tb ? tw : tb;
            }
            if (!(tb > 0.0) || !(sb <= 1e300)) {
                none = 1;
                break;
            }
            u -= 0.5 * log(tb);
            g += sb > 0.0 ? sb * (sb / tb) : 0.0;   /* (S <= 0 adds nothing: free_bounds) */
        }
        double d = g - Sxx, v = u + 0.5 * (d < 0.0 ? d : 0.0);
        v += 1e-9 * (1.0 + fabs(v)) + 1e-12 * Sxx;
        U[b] = none || !(v > -INFINITY) ? INFINITY : v;
    }
}
