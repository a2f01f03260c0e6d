/* eq7_population.c - what a capture's lights tell about each other (rec_match_catalog's last
 * pass, docs/recognition.md "Band model" and "Bulbs not in DELIGHT"): the prior on the reddened
 * band model's optical depth, the band tolerance, and the share of bulbs not in DELIGHT.
 *
 * Extinction reddens a light by its line of sight, not by its lamp: lights at similar range
 * share their optical depth tau. At low SNR one light's tau is poorly known and a uniform prior
 * on it lets the band ratios absorb the chromaticity (Eq. 6) that tells bulbs apart; the
 * capture's bright lights know tau well. The prior for light l is the distribution of tau over
 * the capture's clean lights near l's image row (a range proxy for a camera looking down on a
 * city), estimated as the nonparametric maximum likelihood mixing distribution on the tau grid
 * (Kiefer & Wolfowitz 1956; EM, Laird 1978) from every light's likelihood of tau marginalised
 * over the bulbs and phases, kernel-weighted in row, with light l's own share removed
 * (leave-one-out: its misfit does not pull its prior) and a floor so a light unlike its
 * neighbours can still say so.
 *
 * The band tolerance (how far a lamp's band ratios stray from its bulb's reddened chromaticity:
 * white balance, lamp-to-lamp spread) is measured too, from the capture's bright lights: the
 * value at which their median band misfit (1 dof: three bands less brightness and tau) is the
 * chi-square median. A tolerance wider than the lamps' spread gives the chromaticity away. */
#include "recognize/internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Row kernel: a third of the image height (as the excess noise's), evaluated at TAU_CENTERS
 * rows and interpolated linearly. */
#define TAU_KERNEL_ROWS 3.0
#define TAU_CENTERS 8
/* EM iterations (from the uniform distribution; fewer keep the estimate smoother). */
#define TAU_EM_ITERATIONS 100
/* Share of the uniform prior mixed in. */
#define TAU_FLOOR 0.05
/* Fewer clean lights than this: the uniform prior. A centre whose kernel weights sum to less
 * than TAU_MIN_WEIGHT lights uses the global distribution. */
#define TAU_MIN_LIGHTS 8
#define TAU_MIN_WEIGHT 3.0

/* EM for the mixing distribution pi over the grid from the likelihoods P (nr x N, each row
 * scaled to max 1) with weights kw (NULL: 1). */
static void npmle(const double *P, const double *kw, size_t nr, double *pi)
{
    double acc[REC_TAU_N], W = 0.0;
    for (size_t l = 0; l < nr; l++) W += kw ? kw[l] : 1.0;
    for (int i = 0; i < REC_TAU_N; i++) pi[i] = 1.0 / REC_TAU_N;
    for (int it = 0; it < TAU_EM_ITERATIONS; it++) {
        memset(acc, 0, sizeof acc);
        for (size_t l = 0; l < nr; l++) {
            const double *p = P + l * REC_TAU_N;
            double den = 0.0, wl = kw ? kw[l] : 1.0;
            if (!(wl > 1e-12)) continue;
            for (int i = 0; i < REC_TAU_N; i++) den += pi[i] * p[i];
            if (!(den > 0.0)) continue;
            for (int i = 0; i < REC_TAU_N; i++) acc[i] += wl * pi[i] * p[i] / den;
        }
        for (int i = 0; i < REC_TAU_N; i++) pi[i] = acc[i] / W;
    }
}

size_t rec_eq7_tau_prior(const double *tau_ll, const unsigned char *is_ref, const double *y_px,
                         size_t n, int height, double *logprior)
{
    size_t nr = 0;
    for (size_t l = 0; l < n; l++) nr += is_ref[l] != 0;
    if (nr < TAU_MIN_LIGHTS) return 0;
    double *P = malloc(nr * REC_TAU_N * sizeof *P), *kw = malloc(nr * sizeof *kw);
    size_t *idx = malloc(nr * sizeof *idx);
    double (*pi)[REC_TAU_N] = malloc((TAU_CENTERS + 1) * sizeof *pi);
    double Wc[TAU_CENTERS + 1], yc[TAU_CENTERS];
    if (!P || !kw || !idx || !pi) {
        free(P), free(kw), free(idx), free(pi);
        return 0;   /* the uniform prior: recognition still correct, less informed */
    }
    nr = 0;
    for (size_t l = 0; l < n; l++) {
        if (!is_ref[l]) continue;
        double mx = -INFINITY;
        for (int i = 0; i < REC_TAU_N; i++)
            if (tau_ll[l * REC_TAU_N + i] > mx) mx = tau_ll[l * REC_TAU_N + i];
        for (int i = 0; i < REC_TAU_N; i++)
            P[nr * REC_TAU_N + i] = isfinite(mx) ? exp(tau_ll[l * REC_TAU_N + i] - mx) : 1.0;
        idx[nr++] = l;
    }
    double hy = (height > 0 ? height : 1) / TAU_KERNEL_ROWS;
    npmle(P, NULL, nr, pi[TAU_CENTERS]);   /* the global distribution */
    Wc[TAU_CENTERS] = (double)nr;
    for (int c = 0; c < TAU_CENTERS; c++) {
        yc[c] = (c + 0.5) * (height > 0 ? height : 1) / TAU_CENTERS;
        Wc[c] = 0.0;
        for (size_t r = 0; r < nr; r++) {
            double d = y_px ? (y_px[idx[r]] - yc[c]) / hy : 0.0;
            kw[r] = exp(-0.5 * d * d);
            Wc[c] += kw[r];
        }
        if (Wc[c] < TAU_MIN_WEIGHT) {
            memcpy(pi[c], pi[TAU_CENTERS], sizeof pi[c]);
            Wc[c] = -1.0;   /* global: no leave-one-out by kernel */
        } else {
            npmle(P, kw, nr, pi[c]);
        }
    }
    size_t r = 0;
    for (size_t l = 0; l < n; l++) {
        int self = is_ref[l] != 0;
        const double *p = self ? P + r * REC_TAU_N : NULL;
        double y = y_px ? y_px[l] : 0.0, u = y / ((height > 0 ? height : 1) / (double)TAU_CENTERS) - 0.5;
        int c0 = (int)floor(u);
        double t = u - c0;
        if (c0 < 0) c0 = 0, t = 0.0;
        if (c0 >= TAU_CENTERS - 1) c0 = TAU_CENTERS - 1, t = 0.0;
        double prior[REC_TAU_N] = {0}, sum = 0.0;
        for (int q = 0; q < 2; q++) {
            int c = c0 + q;
            double wq = q ? t : 1.0 - t;
            if (!(wq > 0.0)) continue;
            const double *pc = pi[Wc[c] < 0.0 ? TAU_CENTERS : c];
            double W = Wc[c] < 0.0 ? Wc[TAU_CENTERS] : Wc[c], ws = 1.0, den = 0.0, loo[REC_TAU_N];
            if (self && Wc[c] >= 0.0) {
                double d = (y - yc[c]) / hy;
                ws = exp(-0.5 * d * d);
            }
            if (self)
                for (int i = 0; i < REC_TAU_N; i++) den += pc[i] * p[i];
            for (int i = 0; i < REC_TAU_N; i++) {
                /* leave-one-out: W pi minus the light's own EM responsibility */
                double own = self && den > 0.0 ? ws * pc[i] * p[i] / den : 0.0;
                loo[i] = W - (self ? ws : 0.0) > 0.0 ? (W * pc[i] - own) / (W - (self ? ws : 0.0)) : pc[i];
                if (!(loo[i] > 0.0)) loo[i] = 0.0;
                prior[i] += wq * loo[i];
            }
        }
        for (int i = 0; i < REC_TAU_N; i++) sum += prior[i];
        for (int i = 0; i < REC_TAU_N; i++) {
            double v = (sum > 0.0 ? prior[i] / sum : 1.0 / REC_TAU_N) * (1.0 - TAU_FLOOR) + TAU_FLOOR / REC_TAU_N;
            logprior[l * REC_TAU_N + i] = log(v);
        }
        r += self;
    }
    free(P), free(kw), free(idx), free(pi);
    return nr;
}

/* Bright references for the band tolerance: a / sigma_a at least this; at least TAU_MIN_LIGHTS. */
#define TOL_MIN_SNR 20.0
#define TOL_LO 0.001
#define TOL_HI 1.0
#define CHI2_1_MEDIAN 0.45493642311957

/* The median band misfit of the n references at tolerance tol (misfit falls as tol grows). */
static double median_misfit(const rec_matcher *m, size_t n, const size_t *idx, const int *bulb,
                            const double *S, const double *T, double tol, double *scratch)
{
    for (size_t r = 0; r < n; r++) {
        size_t i = idx[r];
        scratch[r] = rec_eq7_band_misfit(m, bulb[i], S + i * GS_MAX_BANDS, T + i * GS_MAX_BANDS, tol);
    }
    return gs_median_d(scratch, n);
}

double rec_eq7_chroma_tolerance(const rec_matcher *m, size_t n, const int *bulb, const double *S,
                                const double *T, const double *z, const unsigned char *is_ref)
{
    size_t nr = 0;
    for (size_t i = 0; i < n; i++) nr += is_ref[i] && bulb[i] >= 0 && z[i] >= TOL_MIN_SNR;
    if (nr < TAU_MIN_LIGHTS) return 0.0;
    size_t *idx = malloc(nr * sizeof *idx);
    double *scratch = malloc(nr * sizeof *scratch);
    if (!idx || !scratch) {
        free(idx), free(scratch);
        return 0.0;
    }
    nr = 0;
    for (size_t i = 0; i < n; i++)
        if (is_ref[i] && bulb[i] >= 0 && z[i] >= TOL_MIN_SNR) idx[nr++] = i;
    double lo = log(TOL_LO), hi = log(TOL_HI), t;
    if (median_misfit(m, nr, idx, bulb, S, T, TOL_LO, scratch) <= CHI2_1_MEDIAN) {
        t = TOL_LO;   /* the lamps agree with their chromaticity within the noise */
    } else if (median_misfit(m, nr, idx, bulb, S, T, TOL_HI, scratch) > CHI2_1_MEDIAN) {
        t = TOL_HI;
    } else {
        for (int it = 0; it < 30; it++) {   /* bisection in log t */
            double mid = 0.5 * (lo + hi);
            if (median_misfit(m, nr, idx, bulb, S, T, exp(mid), scratch) > CHI2_1_MEDIAN) lo = mid;
            else hi = mid;
        }
        t = exp(0.5 * (lo + hi));
    }
    free(idx);
    free(scratch);
    return t;
}

/* The share of bulbs not in DELIGHT: EM for pi over the references' log Bayes factors B_l of
 * "a deformed template" against the best one (eq7_nested.c), pi <- mean_l pi e^B_l / (pi e^B_l
 * + 1 - pi), from pi = 0.1, kept within [OTHER_LO, OTHER_HI]. */
#define OTHER_LO 0.001
#define OTHER_HI 0.9
#define OTHER_EM_ITERATIONS 200

double rec_eq7_other_share(const double *lbf, const unsigned char *is_ref, size_t n, size_t *used)
{
    size_t nr = 0;
    for (size_t i = 0; i < n; i++) nr += is_ref[i] && isfinite(lbf[i]);
    *used = nr;
    if (nr < TAU_MIN_LIGHTS) return NAN;
    double pi = 0.1;
    for (int it = 0; it < OTHER_EM_ITERATIONS; it++) {
        double acc = 0.0, lo = log(pi / (1.0 - pi));
        for (size_t i = 0; i < n; i++) {
            if (!is_ref[i] || !isfinite(lbf[i])) continue;
            double x = lo + lbf[i];   /* the posterior log odds */
            acc += x > 0.0 ? 1.0 / (1.0 + exp(-x)) : exp(x) / (1.0 + exp(x));
        }
        pi = acc / (double)nr;
        if (pi < OTHER_LO) pi = OTHER_LO;
        if (pi > OTHER_HI) pi = OTHER_HI;
    }
    return pi;
}

/* The capture's flat share (rec_eq7_opts.flat_share): the weighted median (weights 1/var) of the
 * references' own estimates phi_l (rec_eq7_work.fit_flat, with the answer's template); kept only
 * when positive and above FLAT_Z standard errors, else 0; at most REC_FLAT_MAX.
 * The error is robust (the lights' shares differ by more than their noise, and blends are
 * outliers): 1.2533 (the median's efficiency) x 1.4826 x the weighted median absolute deviation
 * over the square root of the effective count (sum w)^2 / sum w^2; never below the estimates'
 * own noise 1.2533 / sqrt(sum w) (a few bright lights: the deviation can be 0). */
#define FLAT_Z 3.0

typedef struct {
    double phi, w;
} flat_ref;

static int cmp_flat(const void *a, const void *b)
{
    double x = ((const flat_ref *)a)->phi, y = ((const flat_ref *)b)->phi;
    return (x > y) - (x < y);
}

/* The weighted median of r[0..n) sorted by phi, total weight sw. */
static double flat_median(const flat_ref *r, size_t n, double sw)
{
    double acc = 0.0;
    for (size_t j = 0; j < n; j++)
        if ((acc += r[j].w) >= 0.5 * sw) return r[j].phi;
    return r[n - 1].phi;
}

gs_status rec_eq7_flat_share(const double *phi, const double *var, const unsigned char *is_ref,
                             size_t n, double *share, double *spread, size_t *used)
{
    *share = NAN;
    *spread = 0.0;
    *used = 0;
    flat_ref *r = malloc((n ? 2 * n : 1) * sizeof *r);
    if (!r) return gs_fail(GS_ENOMEM, "Eq. 7: out of memory for %zu lights' flat shares", n);
    size_t nr = 0;
    double sw = 0.0, sw2 = 0.0;
    for (size_t i = 0; i < n; i++)
        if (is_ref[i] && isfinite(phi[i]) && var[i] > 0.0 && isfinite(var[i])) {
            r[nr].phi = phi[i];
            r[nr].w = 1.0 / var[i];
            sw += r[nr].w;
            sw2 += r[nr].w * r[nr].w;
            nr++;
        }
    *used = nr;
    if (nr < TAU_MIN_LIGHTS) {
        free(r);
        return GS_OK;
    }
    qsort(r, nr, sizeof *r, cmp_flat);
    double med = flat_median(r, nr, sw);
    /* the robust std of the estimates, and the spread of the shares: its square less the
     * estimates' typical (weighted median) variance */
    flat_ref *dev = r + nr;
    for (size_t j = 0; j < nr; j++) dev[j] = (flat_ref){fabs(r[j].phi - med), r[j].w};
    qsort(dev, nr, sizeof *dev, cmp_flat);
    double sd = 1.4826 * flat_median(dev, nr, sw), se = 1.2533 * sd * sqrt(sw2) / sw;
    if (1.2533 / sqrt(sw) > se) se = 1.2533 / sqrt(sw);   /* never below the estimates' own noise */
    for (size_t j = 0; j < nr; j++) dev[j] = (flat_ref){1.0 / r[j].w, r[j].w};
    qsort(dev, nr, sizeof *dev, cmp_flat);
    double excess = sd * sd - flat_median(dev, nr, sw);
    free(r);
    *share = !(med > FLAT_Z * se) ? 0.0 : med < REC_FLAT_MAX ? med : REC_FLAT_MAX;
    *spread = *share > 0.0 && excess > 0.0 ? sqrt(excess) : 0.0;
    return GS_OK;
}
