/* ac.c - the AC model of the grid (paper Sec. 2.1, Eq. 1: f = 1/(2 Delta), Delta the time
 * between successive zero crossings): sub-sample zero crossings of a sampled mains voltage
 * (a local least-squares fit of the fundamental and its 2nd and 3rd harmonics), the grid
 * frequency with a robust mean and its standard error, the slow frequency wander of long
 * recordings, and reading mains recordings with libsndfile.
 *
 * Error model of the standard error: crossing times carry errors of one std sigma_t (noise,
 * quantisation), correlated only between neighbours (their fits share samples). A mean of full
 * periods telescopes, so only the crossings at the ends of each run of accepted periods
 * contribute; sigma_t and the neighbours' covariance are estimated from second differences of
 * full periods, which cancel the (slow) frequency wander. */
#include "recognize/base/base.h"

#include <errno.h>
#include <lapacke.h>
#include <math.h>
#include <sndfile.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------------ zero crossings */

/* The root in [lo, hi] of the cubic through y[m..m+3] at u = 0..3 (u = index - m), given
 * dir * p(lo) <= 0 < dir * p(hi): Newton's method safeguarded by bisection. */
static double cubic_root(const double *y, double lo, double hi, int dir)
{
    /* Newton's forward differences -> monomial coefficients p(u) = a0 + a1 u + a2 u^2 + a3 u^3 */
    double d1 = y[1] - y[0], d2 = y[2] - 2 * y[1] + y[0], d3 = y[3] - 3 * y[2] + 3 * y[1] - y[0];
    double a0 = y[0], a1 = d1 - d2 / 2 + d3 / 3, a2 = d2 / 2 - d3 / 2, a3 = d3 / 6;
    double u = 0.5 * (lo + hi);
    for (int it = 0; it < 100 && hi - lo > 1e-15; it++) {
        double g = dir * (a0 + u * (a1 + u * (a2 + u * a3)));
        double dg = dir * (a1 + u * (2 * a2 + u * 3 * a3));
        if (g <= 0) lo = u;
        else hi = u;
        double next = dg > 0 ? u - g / dg : 0.5 * (lo + hi);
        if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
        if (fabs(next - u) < 1e-15) break;
        u = next;
    }
    return u;
}

/* Sub-sample index of the sign change between samples j and j+1 of y[0..n). */
static double crossing_index(const double *y, size_t n, size_t j, int dir)
{
    if (n < 4) /* too short for a cubic: linear */
        return (double)j + y[j] / (y[j] - y[j + 1]);
    size_t m = j > 0 ? j - 1 : 0; /* nodes j-1..j+2, clamped inside the record */
    if (m > n - 4) m = n - 4;
    return (double)m + cubic_root(y + m, (double)(j - m), (double)(j - m) + 1.0, dir);
}

/* ------------------------------------------------- local fit of the fundamental */

/* Harmonics of the local fit: the fundamental and 2-3 (a few % on real mains; 400 Hz sampling
 * of 50 Hz resolves no more). */
#define AC_FIT_HARMONICS 3
/* Full periods either side whose median is a crossing's local period. */
#define AC_PERIOD_SPAN 25
/* Pairs of successive second differences below which the crossings' covariance is taken as 0. */
#define AC_COV_MIN_PAIRS 30

/* The crossing near sub-sample index u (direction dir) of the least-squares fit of a DC term
 * and harmonics 1..H of the local period (samples) to the K ~ one period of samples around it,
 * re-centred until it moves < 1e-9 samples: interpolation that the shape of a mains waveform
 * does not bias, unlike a cubic through 4 samples. u itself when the period has too few
 * samples or the fit has no crossing within a quarter period of u. */
static double fit_crossing(const double *y, size_t n, double u, double period, int dir)
{
    int H = AC_FIT_HARMONICS;
    while (H > 0 && 2.0 * H >= period) H--; /* below the Nyquist frequency */
    long K = lround(period);
    if (K < 2 * H + 2) K = 2 * H + 2;
    if (H < 1 || (size_t)K > n) return u;
    const int m = 2 * H + 1;
    double w = 2 * M_PI / period, v = u;
    for (int pass = 0; pass < 4; pass++) {
        double i0 = ceil(v - 0.5 * (double)K);
        if (i0 < 0) i0 = 0;
        if (i0 > (double)(n - (size_t)K)) i0 = (double)(n - (size_t)K);
        double A[(2 * AC_FIT_HARMONICS + 1) * (2 * AC_FIT_HARMONICS + 1)] = {0};
        double c[2 * AC_FIT_HARMONICS + 1] = {0}, row[2 * AC_FIT_HARMONICS + 1];
        for (long i = (long)i0; i < (long)i0 + K; i++) {
            double th = w * ((double)i - v), c1 = cos(th), s1 = sin(th), ch = 1, sh = 0;
            row[0] = 1;
            for (int h = 1; h <= H; h++) { /* cos, sin of h th by angle addition */
                double t = ch * c1 - sh * s1;
                sh = sh * c1 + ch * s1;
                ch = t;
                row[2 * h - 1] = ch;
                row[2 * h] = sh;
            }
            for (int a = 0; a < m; a++) {
                c[a] += row[a] * y[i];
                for (int b = 0; b <= a; b++) A[a * m + b] += row[a] * row[b];
            }
        }
        if (LAPACKE_dposv(LAPACK_ROW_MAJOR, 'L', m, 1, A, m, c, 1) != 0) return u;
        /* Newton on the fitted waveform from the window's centre crossing */
        double d = 0, g = 1, dg = 0;
        for (int it = 0; it < 30; it++) {
            g = c[0];
            dg = 0;
            for (int h = 1; h <= H; h++) {
                double ch = cos(h * w * d), sh = sin(h * w * d);
                g += c[2 * h - 1] * ch + c[2 * h] * sh;
                dg += h * w * (c[2 * h] * ch - c[2 * h - 1] * sh);
            }
            if (!(dir * dg > 0)) return u;
            double step = g / dg;
            d -= step;
            if (fabs(d) > 0.25 * period) return u;
            if (fabs(step) < 1e-12) break;
        }
        if (fabs(g) > 1e-9 * fabs(dg)) return u;
        v += d;
        if (fabs(v - u) > 0.25 * period) return u;
        if (fabs(d) < 1e-9) break;
    }
    return v;
}

/* Refits crossings u[0..c) (c >= 3) of y in place, in two passes: each crossing's local period
 * is the median of the full periods u[i+2] - u[i] centred on it, up to AC_PERIOD_SPAN either
 * side (robust to a missing or spurious crossing), first of the cubic crossings, then of the refitted ones, whose
 * errors are ~100 times smaller (the fit's error grows with that of its period). */
static gs_status refit_crossings(const double *y, size_t n, double *u, size_t c, int first_dir)
{
    size_t np = c - 2;
    double *P = malloc(np * sizeof *P), *tmp = malloc((2 * AC_PERIOD_SPAN + 1) * sizeof *tmp);
    double *u0 = malloc(c * sizeof *u0);
    if (!P || !tmp || !u0) {
        free(P);
        free(tmp);
        free(u0);
        return gs_fail(GS_ENOMEM, "zero crossings: cannot allocate %zu crossings", c);
    }
    memcpy(u0, u, c * sizeof *u);
    for (int pass = 0; pass < 2; pass++) {
        for (size_t i = 0; i < np; i++) P[i] = u[i + 2] - u[i];
        for (size_t k = 0; k < c; k++) {
            /* periods P[k-1-h..k-1+h] centre on crossing k; h shrinks at the ends, where the
             * frequency's trend would otherwise bias a one-sided median */
            size_t h = k == 0 || k == c - 1 ? 0 : k - 1 < c - 2 - k ? k - 1 : c - 2 - k;
            if (h > AC_PERIOD_SPAN) h = AC_PERIOD_SPAN;
            size_t mid = k == 0 ? 0 : k == c - 1 ? np - 1 : k - 1;
            memcpy(tmp, P + mid - h, (2 * h + 1) * sizeof *tmp);
            double period = gs_median_d(tmp, 2 * h + 1);
            u[k] = fit_crossing(y, n, u0[k], period, k % 2 ? -first_dir : first_dir);
        }
    }
    free(P);
    free(tmp);
    free(u0);
    return GS_OK;
}

gs_status gs_zero_crossings(const double *x, size_t n, double rate_hz, double hysteresis,
                             double **t_s, size_t *count, int *rising_first)
{
    if (!t_s || !count || !rising_first || (!x && n > 0))
        return gs_fail(GS_EINVAL, "zero crossings: NULL argument");
    *t_s = NULL;
    *count = 0;
    *rising_first = 0;
    if (!(isfinite(rate_hz) && rate_hz > 0))
        return gs_fail(GS_EINVAL, "zero crossings: rate_hz = %g: expected a finite rate > 0", rate_hz);
    if (!(isfinite(hysteresis) && hysteresis >= 0))
        return gs_fail(GS_EINVAL, "zero crossings: hysteresis = %g: expected a finite value >= 0",
                       hysteresis);
    double sum = 0;
    for (size_t i = 0; i < n; i++) {
        if (!isfinite(x[i]))
            return gs_fail(GS_ENUMERIC, "zero crossings: sample %zu is %g: expected a finite value",
                           i, x[i]);
        sum += x[i];
    }
    if (n < 2) return GS_OK;
    double *y = malloc(n * sizeof *y);
    double *t = malloc(n * sizeof *t); /* at most n - 1 crossings */
    if (!y || !t) {
        free(y);
        free(t);
        return gs_fail(GS_ENOMEM, "zero crossings: cannot allocate %zu samples", n);
    }
    double mean = sum / (double)n;
    for (size_t i = 0; i < n; i++) y[i] = x[i] - mean;

    /* Schmitt trigger: the state flips only when y passes the opposite threshold; the crossing
     * is the midpoint of the first and last sign changes in the transition (one when clean). */
    int state = 0;      /* +1 above +h, -1 below -h, 0 not yet known */
    size_t since = 0;   /* last sample that confirmed the current state */
    size_t c = 0;
    for (size_t k = 0; k < n; k++) {
        int s = y[k] > hysteresis ? 1 : y[k] < -hysteresis ? -1 : 0;
        if (s == 0) continue;
        if (s == state || state == 0) {
            state = s;
            since = k;
            continue;
        }
        /* transition since -> k in direction s: first and last sign change in direction s */
        size_t first = k, last = k;
        for (size_t j = since; j < k; j++)
            if (s * y[j] <= 0 && s * y[j + 1] > 0) {
                if (first == k) first = j;
                last = j;
            }
        double u = crossing_index(y, n, first, s);
        if (last != first) u = 0.5 * (u + crossing_index(y, n, last, s));
        if (c == 0) *rising_first = s;
        t[c++] = u;
        state = s;
        since = k;
    }
    gs_status st = c >= 3 ? refit_crossings(y, n, t, c, *rising_first) : GS_OK;
    free(y);
    if (st != GS_OK || c == 0) {
        free(t);
        if (st != GS_OK) *rising_first = 0;
        return st;
    }
    for (size_t i = 0; i < c; i++) t[i] /= rate_hz;
    *t_s = t;
    *count = c;
    return GS_OK;
}

/* ------------------------------------------------------------ grid frequency */

/* Validates t[0..n) (finite, increasing, n >= 3) and computes the full-period frequencies
 * F[i] = 1/(t[i+2] - t[i]), i < n-2, their median and ok[i] = |F[i] - median| <= 5 robust
 * sigmas (1.4826 MAD; at least 1e-9 of the median so that exact data keep every period).
 * F and ok are allocated (free()). */
static gs_status full_periods(const char *who, const double *t, size_t n, double **F_out,
                              unsigned char **ok_out, double *median_hz)
{
    *F_out = NULL;
    *ok_out = NULL;
    if (n < 3)
        return gs_fail(GS_EINVAL, "%s: %zu zero crossings: expected at least 3 (one full AC period)",
                       who, n);
    if (!t) return gs_fail(GS_EINVAL, "%s: NULL crossing times", who);
    for (size_t i = 0; i < n; i++) {
        if (!isfinite(t[i]))
            return gs_fail(GS_ENUMERIC, "%s: t_s[%zu] = %g: expected a finite time", who, i, t[i]);
        if (i > 0 && !(t[i] > t[i - 1]))
            return gs_fail(GS_EINVAL, "%s: t_s[%zu] = %.17g: expected > t_s[%zu] = %.17g", who, i,
                           t[i], i - 1, t[i - 1]);
    }
    size_t np = n - 2;
    double *F = malloc(np * sizeof *F), *tmp = malloc(np * sizeof *tmp);
    unsigned char *ok = malloc(np);
    if (!F || !tmp || !ok) {
        free(F);
        free(tmp);
        free(ok);
        return gs_fail(GS_ENOMEM, "%s: cannot allocate %zu periods", who, np);
    }
    for (size_t i = 0; i < np; i++) F[i] = 1.0 / (t[i + 2] - t[i]);
    memcpy(tmp, F, np * sizeof *tmp);
    double med = gs_median_d(tmp, np);
    for (size_t i = 0; i < np; i++) tmp[i] = fabs(F[i] - med);
    double mad = gs_median_d(tmp, np);
    double tol = fmax(5 * 1.4826 * mad, 1e-9 * med);
    for (size_t i = 0; i < np; i++) ok[i] = fabs(F[i] - med) <= tol;
    free(tmp);
    *F_out = F;
    *ok_out = ok;
    *median_hz = med;
    return GS_OK;
}

gs_status gs_grid_frequency(const double *t_s, size_t n, double *f_cycle_hz,
                             gs_freq_stats *stats)
{
    if (!stats) return gs_fail(GS_EINVAL, "grid frequency: NULL stats");
    memset(stats, 0, sizeof *stats);
    double *F;
    unsigned char *ok;
    double med;
    gs_status st = full_periods("grid frequency", t_s, n, &F, &ok, &med);
    if (st != GS_OK) return st;
    size_t np = n - 2;
    /* Eq. 1 per flicker cycle */
    if (f_cycle_hz)
        for (size_t i = 0; i + 1 < n; i++) f_cycle_hz[i] = 1.0 / (2.0 * (t_s[i + 1] - t_s[i]));

    /* Robust mean: Eq. 1 on the mean accepted full period 2 Delta. */
    double sum_p = 0, sum_f = 0, sum_ff = 0;
    size_t acc = 0;
    for (size_t i = 0; i < np; i++)
        if (ok[i]) {
            sum_p += t_s[i + 2] - t_s[i];
            sum_f += F[i];
            acc++;
        }
    double mean_p = sum_p / (double)acc, mean_f = sum_f / (double)acc;
    for (size_t i = 0; i < np; i++)
        if (ok[i]) sum_ff += (F[i] - mean_f) * (F[i] - mean_f);

    /* Crossing-time errors: variance g0, and covariance g1 of neighbours (gs_zero_crossings'
     * fits of neighbouring crossings share samples; further ones do not), from the second
     * differences d_i = P_{i+2} - P_i = t_{i+4} - 2 t_{i+2} + t_i of accepted full periods:
     * var d_i = 6 g0, cov(d_i, d_{i+1}) = 2 g1. */
    double *d = malloc((np > 2 ? np - 2 : 1) * sizeof *d);
    if (!d) {
        free(F);
        free(ok);
        return gs_fail(GS_ENOMEM, "grid frequency: cannot allocate %zu periods", np);
    }
    double sd = 0, sdd = 0, sd1 = 0;
    size_t nd = 0, nd1 = 0;
    for (size_t i = 0; i + 2 < np; i++) {
        d[i] = ok[i] && ok[i + 2] ? (t_s[i + 4] - t_s[i + 2]) - (t_s[i + 2] - t_s[i]) : NAN;
        if (isnan(d[i])) continue;
        sd += d[i];
        nd++;
    }
    double dmean = nd ? sd / (double)nd : 0;
    for (size_t i = 0; i + 2 < np; i++) {
        if (isnan(d[i])) continue;
        sdd += (d[i] - dmean) * (d[i] - dmean);
        if (i + 3 < np && !isnan(d[i + 1])) {
            sd1 += (d[i] - dmean) * (d[i + 1] - dmean);
            nd1++;
        }
    }
    free(d);
    /* The mean period is sum_j c_j t_j / acc: c_j = (#accepted periods ending at j) - (#starting
     * at j), non-zero only at the ends of runs, so
     * var(mean_p) = (g0 sum c_j^2 + 2 g1 sum c_j c_{j+1}) / acc^2. */
    double sum_c2 = 0, sum_c1 = 0;
    int c_prev = 0;
    for (size_t j = 0; j < n; j++) {
        int cj = (j >= 2 && ok[j - 2]) - (j < np && ok[j]);
        sum_c2 += (double)(cj * cj);
        sum_c1 += (double)(cj * c_prev);
        c_prev = cj;
    }
    double sigma_mean = NAN;
    if (nd >= 2) {
        /* the covariance from at least AC_COV_MIN_PAIRS pairs (from fewer it is mostly noise, and
         * a negative one cancelled the variance: a standard error of 0), its correlation not below
         * -1/2 (the least a tridiagonal covariance of any length allows); above +1/2 it stands in
         * for correlations reaching further (the crossings' slow residual on real mains) */
        double g0 = sdd / (double)(nd - 1) / 6.0, g1 = nd1 >= AC_COV_MIN_PAIRS ? sd1 / (double)nd1 / 2.0 : 0.0;
        g1 = fmax(-0.5 * g0, g1);
        double var_sum = fmax(g0 * sum_c2 + 2.0 * g1 * sum_c1, 0);
        sigma_mean = sqrt(var_sum) / (double)acc / (mean_p * mean_p);
    }
    stats->mean_hz = 1.0 / mean_p;
    stats->sigma_mean_hz = sigma_mean;
    stats->median_hz = med;
    stats->std_hz = acc >= 2 ? sqrt(sum_ff / (double)(acc - 1)) : NAN;
    stats->periods = acc;
    stats->rejected = np - acc;
    free(F);
    free(ok);
    return GS_OK;
}

/* ---------------------------------------------------------- frequency wander */

/* Pearson correlation of the pairs (x[w], x[w + lag]) with both finite; NaN if < 3 pairs. */
static double lag_corr(const double *x, size_t nw, size_t lag)
{
    double sa = 0, sb = 0, saa = 0, sbb = 0, sab = 0;
    size_t m = 0;
    for (size_t w = 0; w + lag < nw; w++) {
        double a = x[w], b = x[w + lag];
        if (isnan(a) || isnan(b)) continue;
        sa += a;
        sb += b;
        m++;
    }
    if (m < 3) return NAN;
    double ma = sa / (double)m, mb = sb / (double)m;
    for (size_t w = 0; w + lag < nw; w++) {
        double a = x[w], b = x[w + lag];
        if (isnan(a) || isnan(b)) continue;
        saa += (a - ma) * (a - ma);
        sbb += (b - mb) * (b - mb);
        sab += (a - ma) * (b - mb);
    }
    return saa > 0 && sbb > 0 ? sab / sqrt(saa * sbb) : NAN;
}

gs_status gs_frequency_wander(const double *t_s, size_t n, double window_s, gs_wander *w)
{
    if (!w) return gs_fail(GS_EINVAL, "frequency wander: NULL result");
    memset(w, 0, sizeof *w);
    if (!(isfinite(window_s) && window_s > 0 && window_s <= 10))
        return gs_fail(GS_EINVAL, "frequency wander: window_s = %g: expected (0, 10] s", window_s);
    double *F;
    unsigned char *ok;
    double med;
    gs_status st = full_periods("frequency wander", t_s, n, &F, &ok, &med);
    if (st != GS_OK) return st;
    double span = t_s[n - 1] - t_s[0];
    if (span < 120) {
        free(F);
        free(ok);
        return gs_fail(GS_EINVAL, "frequency wander: crossings span %.3f s: expected >= 120 s", span);
    }
    size_t nw = (size_t)floor(span / window_s), np = n - 2;
    double *sum_p = calloc(nw, sizeof *sum_p), *x = malloc(nw * sizeof *x);
    size_t *cnt = calloc(nw, sizeof *cnt);
    if (!sum_p || !x || !cnt) {
        free(F);
        free(ok);
        free(sum_p);
        free(x);
        free(cnt);
        return gs_fail(GS_ENOMEM, "frequency wander: cannot allocate %zu windows", nw);
    }
    /* Each accepted full period belongs to the window holding its midpoint; a window's
     * frequency is Eq. 1 on its mean full period (NaN for a window without any). */
    for (size_t i = 0; i < np; i++) {
        if (!ok[i]) continue;
        double mid = 0.5 * (t_s[i] + t_s[i + 2]) - t_s[0];
        size_t k = (size_t)(mid / window_s);
        if (k >= nw) continue;
        sum_p[k] += t_s[i + 2] - t_s[i];
        cnt[k]++;
    }
    double s = 0, ss = 0, sd = 0, sdd = 0;
    size_t m = 0, md = 0;
    for (size_t k = 0; k < nw; k++) {
        x[k] = cnt[k] ? (double)cnt[k] / sum_p[k] : NAN;
        if (cnt[k]) {
            s += x[k];
            m++;
        }
        if (k > 0 && cnt[k] && cnt[k - 1]) {
            sd += x[k] - x[k - 1];
            md++;
        }
    }
    st = GS_OK;
    if (m < 3 || md < 3) {
        st = gs_fail(GS_EINVAL, "frequency wander: %zu of %zu windows hold accepted periods: "
                     "expected at least 3 consecutive", m, nw);
    } else {
        double mean = s / (double)m, dmean = sd / (double)md;
        for (size_t k = 0; k < nw; k++) {
            if (cnt[k]) ss += (x[k] - mean) * (x[k] - mean);
            if (k > 0 && cnt[k] && cnt[k - 1]) {
                double d = x[k] - x[k - 1] - dmean;
                sdd += d * d;
            }
        }
        w->mean_hz = mean;
        w->sigma_hz = sqrt(ss / (double)(m - 1));
        w->step_sigma_hz = sqrt(sdd / (double)(md - 1));
        w->corr_10s = lag_corr(x, nw, (size_t)lround(10.0 / window_s));
        w->corr_60s = lag_corr(x, nw, (size_t)lround(60.0 / window_s));
        w->windows = nw;
    }
    free(F);
    free(ok);
    free(sum_p);
    free(x);
    free(cnt);
    return st;
}

/* ------------------------------------------------------------ mains recordings */

static uint32_t le32(const unsigned char *b)
{
    return (uint32_t)b[0] | (uint32_t)b[1] << 8 | (uint32_t)b[2] << 16 | (uint32_t)b[3] << 24;
}

/* A RIFF/WAVE file's declared lengths against its size: libsndfile reads a truncated WAV
 * without complaint. Other formats are left to libsndfile. Sizes 0 and 0xFFFFFFFF mean
 * "unknown" (streamed WAV) and are not checked. */
static gs_status riff_check(const char *path, FILE *f, long size)
{
    unsigned char h[12];
    if (fseek(f, 0, SEEK_SET) != 0 || fread(h, 1, 12, f) != 12) return GS_OK;
    if (memcmp(h, "RIFF", 4) != 0 || memcmp(h + 8, "WAVE", 4) != 0) return GS_OK;
    uint32_t riff = le32(h + 4);
    if (riff != 0 && riff != 0xFFFFFFFFu && (long long)riff + 8 > (long long)size)
        return gs_fail(GS_EFORMAT, "%s: truncated: RIFF chunk size declares %lld bytes, file has %ld",
                       path, (long long)riff + 8, size);
    for (long long off = 12; off + 8 <= (long long)size;) {
        if (fseek(f, (long)off, SEEK_SET) != 0 || fread(h, 1, 8, f) != 8) break;
        uint32_t len = le32(h + 4);
        if (memcmp(h, "data", 4) == 0) {
            if (len != 0 && len != 0xFFFFFFFFu && off + 8 + len > (long long)size)
                return gs_fail(GS_EFORMAT, "%s: truncated: data chunk size declares %lu bytes, "
                               "file has %lld after the chunk header", path, (unsigned long)len,
                               (long long)size - off - 8);
            return GS_OK;
        }
        off += 8 + (long long)len + (len & 1);
    }
    return gs_fail(GS_EFORMAT, "%s: truncated: no data chunk in the file's %ld bytes", path, size);
}

gs_status gs_mains_read(const char *path, double **x, size_t *n, double *rate_hz)
{
    if (!path || !x || !n || !rate_hz) return gs_fail(GS_EINVAL, "mains read: NULL argument");
    *x = NULL;
    *n = 0;
    *rate_hz = 0;
    gs_status st = gs_input_check(path);   /* libsndfile reads by name: a regular file */
    if (st != GS_OK) return st;
    FILE *f = fopen(path, "rb");
    if (!f) return gs_fail(GS_EIO, "%s: cannot open: %s", path, strerror(errno));
    long size = fseek(f, 0, SEEK_END) == 0 ? ftell(f) : -1;
    st = size < 0 ? gs_fail(GS_EIO, "%s: cannot determine the file size", path)
                   : size == 0 ? gs_fail(GS_EFORMAT, "%s: empty file (0 bytes): expected an audio file", path)
                   : riff_check(path, f, size);
    fclose(f);
    if (st != GS_OK) return st;
    SF_INFO info;
    memset(&info, 0, sizeof info);
    SNDFILE *sf = sf_open(path, SFM_READ, &info);
    if (!sf) {
        int e = sf_error(NULL);
        return gs_fail(e == SF_ERR_SYSTEM ? GS_EIO : GS_EFORMAT,
                       "%s: header: not a readable audio file (libsndfile: %s)", path,
                       sf_strerror(NULL));
    }
    if (info.channels != 1)
        st = gs_fail(GS_EFORMAT, "%s: channels = %d: expected 1 (mono)", path, info.channels);
    else if (info.samplerate <= 0)
        st = gs_fail(GS_EFORMAT, "%s: sample rate = %d Hz: expected > 0", path, info.samplerate);
    else if (info.frames <= 0)
        st = gs_fail(GS_EFORMAT, "%s: frames = %lld: expected at least 1 sample", path,
                     (long long)info.frames);
    else if ((unsigned long long)info.frames > SIZE_MAX / sizeof(double))
        st = gs_fail(GS_ELIMIT, "%s: frames = %lld: too many to hold in memory", path,
                     (long long)info.frames);
    double *v = NULL;
    if (st == GS_OK) {
        v = malloc((size_t)info.frames * sizeof *v);
        if (!v) st = gs_fail(GS_ENOMEM, "%s: cannot allocate %lld samples", path, (long long)info.frames);
    }
    if (st == GS_OK) {
        sf_count_t r = sf_readf_double(sf, v, info.frames);
        if (r != info.frames)
            st = gs_fail(GS_EFORMAT, "%s: truncated: read %lld samples, header declares %lld", path,
                         (long long)r, (long long)info.frames);
    }
    for (sf_count_t i = 0; st == GS_OK && i < info.frames; i++)
        if (!isfinite(v[i]))
            st = gs_fail(GS_EFORMAT, "%s: sample %lld is %g: expected a finite value", path,
                         (long long)i, v[i]);
    sf_close(sf);
    if (st != GS_OK) {
        free(v);
        return st;
    }
    *x = v;
    *n = (size_t)info.frames;
    *rate_hz = info.samplerate;
    return GS_OK;
}
