/* aclock.c - the AC timeline of a capture and the ACam's window timing (paper Sec. 6, Fig. 9):
 * zero crossings of the reference outlet from a constant frequency, a random walk with the
 * statistics of real grids (shared/data/README.md) or a real mains recording; the C windows of
 * one exposure, AC-locked (re-anchored at every crossing) or free running (a fixed period from
 * the first crossing); and the temporal blur that free running causes. */
#include "capture/internal.h"

#include <limits.h>
#include <stdlib.h>
#include <string.h>

struct cap_ac {
    cap_freq_model model;
    int grid_hz;
    double half_s;        /* constant model: the half period */
    double nominal_half_s;
    double *t;            /* crossing times (random walk, trace) */
    long n, cap;
    /* random walk state */
    cap_freq_config cfg;
    gs_rng rng;
    double y, z, w;       /* slow cascade (y -> z) and fast part */
    double a, sy, b, sw;  /* per-cycle AR coefficients and innovations */
};

static gs_status grow(cap_ac *ac, long need)
{
    if (need <= ac->cap) return GS_OK;
    long nc = ac->cap ? ac->cap : 4096;
    while (nc < need) nc *= 2;
    double *nt = realloc(ac->t, sizeof *nt * (size_t)nc);
    if (!nt) return gs_fail(GS_ENOMEM, "AC timeline: cannot hold %ld crossings", nc);
    ac->t = nt;
    ac->cap = nc;
    return GS_OK;
}

static gs_status load_trace(cap_ac *ac, const cap_freq_config *f)
{
    double *x = NULL, *tc = NULL, rate;
    size_t n = 0, count = 0;
    int rising_first = 0;
    gs_status s = gs_mains_read(f->wav, &x, &n, &rate);
    if (s != GS_OK) return s;
    double mean = 0, rms = 0;
    for (size_t i = 0; i < n; i++) mean += x[i];
    mean /= n ? (double)n : 1.0;
    for (size_t i = 0; i < n; i++) rms += (x[i] - mean) * (x[i] - mean);
    rms = n ? sqrt(rms / (double)n) : 0;
    s = gs_zero_crossings(x, n, rate, 0.1 * rms, &tc, &count, &rising_first);
    free(x);
    if (s != GS_OK) return gs_fail(s, "%s: %s", f->wav, gs_detail());
    /* first rising crossing at or after start_s */
    size_t i0 = 0;
    while (i0 < count && (tc[i0] < f->start_s || ((i0 % 2 == 0) != (rising_first > 0))))
        i0++;
    if (count < 100 || i0 + 100 >= count) {
        free(tc);
        return gs_fail(GS_EFORMAT, "%s: %zu zero crossings after %g s: expected a mains "
                       "recording of at least 1 s after the start", f->wav,
                       count > i0 ? count - i0 : 0, f->start_s);
    }
    long m = (long)(count - i0);
    s = grow(ac, m);
    if (s != GS_OK) {
        free(tc);
        return s;
    }
    /* the crossings as the ACam's detector sees them (the firmware's tests inject these):
     * rising and falling ones alternate by the recording's even harmonics, which the locked
     * prediction Delta_{n-2} follows */
    for (long c = 0; c < m; c++) ac->t[c] = tc[i0 + (size_t)c] - tc[i0];
    free(tc);
    ac->n = m;
    double hz = (double)(m - 1) / (2.0 * ac->t[m - 1]);
    if (fabs(hz - ac->grid_hz) > 0.05 * ac->grid_hz)
        return gs_fail(GS_EFORMAT, "%s: the recording's mains frequency is %.3f Hz: the scene's "
                       "grid is %d Hz", f->wav, hz, ac->grid_hz);
    return GS_OK;
}

gs_status cap_ac_new(const cap_freq_config *f, int grid_hz, cap_ac **out)
{
    *out = NULL;
    if (grid_hz != 50 && grid_hz != 60)
        return gs_fail(GS_EINVAL, "AC timeline: grid %d Hz: expected 50 or 60", grid_hz);
    cap_ac *ac = calloc(1, sizeof *ac);
    if (!ac) return gs_fail(GS_ENOMEM, "AC timeline: out of memory");
    ac->model = f->model;
    ac->grid_hz = grid_hz;
    ac->cfg = *f;
    ac->nominal_half_s = 1.0 / (2.0 * grid_hz);
    gs_status s = GS_OK;
    switch (f->model) {
    case CAP_FREQ_CONSTANT:
        if (!(f->hz > 0.8 * grid_hz && f->hz < 1.2 * grid_hz))
            s = gs_fail(GS_EINVAL, "AC timeline: constant %g Hz: expected within 20 %% of %d Hz",
                        f->hz, grid_hz);
        ac->half_s = 1.0 / (2.0 * f->hz);
        break;
    case CAP_FREQ_RANDOM_WALK: {
        if (!(f->hz > 0.8 * grid_hz && f->hz < 1.2 * grid_hz) || !(f->sigma_hz >= 0) ||
            !(f->fast_sigma_hz >= 0) || !(f->corr_time_s > 0) || !(f->fast_corr_time_s > 0)) {
            s = gs_fail(GS_EINVAL, "AC timeline: random walk mean %g Hz, sigma %g / %g Hz, "
                        "times %g / %g s: expected a mean near %d Hz, sigmas >= 0, times > 0",
                        f->hz, f->sigma_hz, f->fast_sigma_hz, f->corr_time_s,
                        f->fast_corr_time_s, grid_hz);
            break;
        }
        double dt = ac->nominal_half_s;
        ac->a = exp(-dt / f->corr_time_s);
        ac->sy = sqrt(2.0) * f->sigma_hz * sqrt(1.0 - ac->a * ac->a);
        ac->b = exp(-dt / f->fast_corr_time_s);
        ac->sw = f->fast_sigma_hz * sqrt(1.0 - ac->b * ac->b);
        gs_rng_init(&ac->rng, f->seed, CAP_TAG_FREQ, 0, 0);
        /* stationary start: z ~ N(0, sigma^2), y correlated 1/sqrt(2) with z, var 2 sigma^2 */
        double e1 = gs_rng_normal(&ac->rng), e2 = gs_rng_normal(&ac->rng);
        ac->z = f->sigma_hz * e1;
        ac->y = sqrt(2.0) * f->sigma_hz * (e1 + e2) / sqrt(2.0);
        ac->w = f->fast_sigma_hz * gs_rng_normal(&ac->rng);
        s = grow(ac, 1);
        if (s == GS_OK) {
            ac->t[0] = 0.0;
            ac->n = 1;
        }
        break;
    }
    case CAP_FREQ_TRACE:
        s = load_trace(ac, f);
        break;
    default:
        s = gs_fail(GS_EINVAL, "AC timeline: unknown frequency model %d", (int)f->model);
    }
    if (s != GS_OK) {
        cap_ac_free(ac);
        return s;
    }
    *out = ac;
    return GS_OK;
}

void cap_ac_free(cap_ac *ac)
{
    if (!ac) return;
    free(ac->t);
    free(ac);
}

long cap_ac_available(const cap_ac *ac)
{
    return ac->model == CAP_FREQ_TRACE ? ac->n : LONG_MAX;
}

gs_status cap_ac_time(cap_ac *ac, long c, double *t_s)
{
    if (c < 0) return gs_fail(GS_EINVAL, "AC timeline: crossing %ld", c);
    switch (ac->model) {
    case CAP_FREQ_CONSTANT:
        *t_s = (double)c * ac->half_s;
        return GS_OK;
    case CAP_FREQ_TRACE:
        if (c >= ac->n)
            return gs_fail(GS_ELIMIT, "the mains trace %s provides %ld crossings (%.1f s) after "
                           "its start; this capture needs crossing %ld: use a longer recording, "
                           "an earlier start_s, fewer cycles or fewer frames", ac->cfg.wav,
                           ac->n, ac->t[ac->n - 1], c);
        *t_s = ac->t[c];
        return GS_OK;
    case CAP_FREQ_RANDOM_WALK:
        if (c >= ac->n) {
            gs_status s = grow(ac, c + 1);
            if (s != GS_OK) return s;
            for (long i = ac->n; i <= c; i++) {
                ac->y = ac->a * ac->y + ac->sy * gs_rng_normal(&ac->rng);
                ac->z = ac->a * ac->z + (1.0 - ac->a) * ac->y;
                ac->w = ac->b * ac->w + ac->sw * gs_rng_normal(&ac->rng);
                double f = ac->cfg.hz + ac->z + ac->w;
                ac->t[i] = ac->t[i - 1] + 1.0 / (2.0 * f);
            }
            ac->n = c + 1;
        }
        *t_s = ac->t[c];
        return GS_OK;
    }
    return gs_fail(GS_EINVAL, "AC timeline: unknown model");
}

/* Reference phase of time t: j + (t - t_j) / (t_{j+1} - t_j) with t_j <= t < t_{j+1}, searched
 * from *hint (updated). */
static gs_status phase_at(cap_ac *ac, double t, long *hint, double *phase)
{
    long j = *hint < 0 ? 0 : *hint;
    double tj, tj1;
    gs_status s;
    if ((s = cap_ac_time(ac, j, &tj)) != GS_OK) return s;
    while (t < tj && j > 0) {
        j--;
        if ((s = cap_ac_time(ac, j, &tj)) != GS_OK) return s;
    }
    for (;;) {
        if ((s = cap_ac_time(ac, j + 1, &tj1)) != GS_OK) return s;
        if (t < tj1 || tj1 <= tj) break;
        j++;
        tj = tj1;
    }
    *hint = j;
    /* before crossing 0: extrapolate with the first half period */
    *phase = (double)j + (t - tj) / (tj1 - tj);
    return GS_OK;
}

gs_status cap_ac_window_period(cap_ac *ac, const cap_window_config *w, double *half_period_s)
{
    *half_period_s = NAN;
    if (w->mode != CAP_FREE_RUNNING) return GS_OK;
    /* nominal: a fixed count of the controller's clock ticks, off by its error; measured: timed
     * with the clock it was measured with, so the error cancels */
    double P = ac->nominal_half_s * (1.0 + 1e-6 * w->clock_ppm);
    if (w->free_period_measured) {
        long back = w->first_cycle < 64 ? w->first_cycle : 64;
        if (back > 0) {
            double t_first, tb;
            gs_status s = cap_ac_time(ac, w->first_cycle, &t_first);
            if (s == GS_OK) s = cap_ac_time(ac, w->first_cycle - back, &tb);
            if (s != GS_OK) return s;
            P = (t_first - tb) / (double)back;
        }
    }
    *half_period_s = P;
    return GS_OK;
}

double cap_window_drift(const double *delta, long cycles, double P, int K)
{
    double elapsed = 0.0, lo = 0.0, hi = 0.0;
    for (long c = 0; c <= cycles; c++) {
        if (c % 2 == 0 || c == cycles) {
            double off = ((double)c * P - elapsed) / delta[c < cycles ? c : cycles - 1];
            lo = off < lo ? off : lo;
            hi = off > hi ? off : hi;
        }
        if (c < cycles) elapsed += delta[c];
    }
    return (double)K * (hi - lo);
}

gs_status cap_ac_windows(cap_ac *ac, const cap_window_config *w, cap_windows *out)
{
    memset(out, 0, sizeof *out);
    if (w->K < 2 || w->k < 0 || w->k >= w->K || w->cycles < 1 || w->first_cycle < 0 ||
        !(w->jitter_us >= 0) || !isfinite(w->clock_ppm))
        return gs_fail(GS_EINVAL, "AC windows: K %d, k %d, C %ld, first %ld, jitter %g us",
                       w->K, w->k, w->cycles, w->first_cycle, w->jitter_us);
    size_t C = (size_t)w->cycles;
    out->t0_s = malloc(sizeof(double) * C);
    out->t1_s = malloc(sizeof(double) * C);
    out->phase0 = malloc(sizeof(double) * C);
    out->phase1 = malloc(sizeof(double) * C);
    if (!out->t0_s || !out->t1_s || !out->phase0 || !out->phase1) {
        cap_windows_release(out);
        return gs_fail(GS_ENOMEM, "AC windows: out of memory");
    }
    out->cycles = w->cycles;
    out->first_cycle = w->first_cycle;
    out->K = w->K;
    out->k = w->k;
    gs_rng rng;
    gs_rng_init(&rng, w->jitter_seed, CAP_TAG_JITTER, (uint64_t)w->first_cycle, (uint64_t)w->k);
    double K = w->K;
    gs_status s = GS_OK;
    double t_first, P;
    if ((s = cap_ac_time(ac, w->first_cycle, &t_first)) != GS_OK ||
        (s = cap_ac_window_period(ac, w, &P)) != GS_OK)
        goto fail;
    long hint = w->first_cycle;
    for (long c = 0; c < w->cycles; c++) {
        long g = w->first_cycle + c;
        double ts, te;
        if (w->mode == CAP_LOCKED) {
            double tg, tp;
            if ((s = cap_ac_time(ac, g, &tg)) != GS_OK) goto fail;
            /* the firmware's prediction (firmware/schedule.c, plan_locked with
             * fw_tracker_predict_next): Delta_{g-2}, the half period of the same polarity one
             * AC period earlier */
            double pred = ac->nominal_half_s;
            if (g >= 2) {
                double tq;
                if ((s = cap_ac_time(ac, g - 2, &tp)) != GS_OK || (s = cap_ac_time(ac, g - 1, &tq)) != GS_OK)
                    goto fail;
                pred = tq - tp;
            } else if (g == 1) {
                if ((s = cap_ac_time(ac, 0, &tp)) != GS_OK) goto fail;
                pred = tg - tp;
            }
            ts = tg + w->k * pred / K;
            te = tg + (w->k + 1) * pred / K;
        } else {
            ts = t_first + (double)c * P + w->k * P / K;
            te = ts + P / K;
        }
        if (w->jitter_us > 0) {
            ts += 1e-6 * w->jitter_us * gs_rng_normal(&rng);
            te += 1e-6 * w->jitter_us * gs_rng_normal(&rng);
            if (te <= ts) te = ts + 1e-9;
        }
        out->t0_s[c] = ts;
        out->t1_s[c] = te;
        if ((s = phase_at(ac, ts, &hint, &out->phase0[c])) != GS_OK) goto fail;
        long h2 = hint;
        if ((s = phase_at(ac, te, &h2, &out->phase1[c])) != GS_OK) goto fail;
    }
    return GS_OK;
fail:
    cap_windows_release(out);
    return s;
}

void cap_windows_release(cap_windows *w)
{
    if (!w) return;
    free(w->t0_s);
    free(w->t1_s);
    free(w->phase0);
    free(w->phase1);
    memset(w, 0, sizeof *w);
}

gs_status cap_windows_blur(const cap_windows *w, cap_blur *out)
{
    memset(out, 0, sizeof *out);
    if (!w || w->cycles < 1) return gs_fail(GS_EINVAL, "blur: no windows");
    /* the ideal window of cycle c: [first + c + k/K, first + c + (k+1)/K) */
    double first = (double)w->first_cycle + (w->k + 0.5) / w->K;
    double sum = 0, sum2 = 0, lo = INFINITY, hi = -INFINITY, lsum = 0, lsum2 = 0;
    for (long c = 0; c < w->cycles; c++) {
        double centre = 0.5 * (w->phase0[c] + w->phase1[c]) - (first + (double)c);
        sum += centre;
        sum2 += centre * centre;
        if (centre < lo) lo = centre;
        if (centre > hi) hi = centre;
        double len = w->phase1[c] - w->phase0[c];
        lsum += len;
        lsum2 += len * len;
    }
    double n = (double)w->cycles;
    double mean = sum / n, lmean = lsum / n;
    out->mean_offset_cycles = mean;
    out->spread_cycles = sqrt(fmax(sum2 / n - mean * mean, 0.0));
    out->range_cycles = hi - lo;
    out->length_rel_std = sqrt(fmax(lsum2 / n - lmean * lmean, 0.0)) / lmean;
    return GS_OK;
}

gs_status cap_brf_expose(const gs_brf *b, double shift_cycles, const cap_windows *w, double *out)
{
    if (!w || w->cycles < 1) return gs_fail(GS_EINVAL, "expose: no windows");
    cap_brf_table t;
    gs_status s = cap_brf_table_init(&t, b, 4096);
    if (s != GS_OK) return s;
    for (int band = 0; band < b->bands; band++) {
        double sum = 0, len = 0;
        for (long c = 0; c < w->cycles; c++) {
            sum += cap_brf_table_integral(&t, band, shift_cycles, w->phase0[c], w->phase1[c]);
            len += w->phase1[c] - w->phase0[c];
        }
        /* the length-weighted mean of the BRF over the windows */
        out[band] = sum / len;
    }
    cap_brf_table_release(&t);
    return GS_OK;
}
