/* recording.c - a measured bulb from a photodiode recording (paper Sec. 3 and Fig. 2: DELIGHT's
 * BRFs are photodiode signals averaged over many flicker cycles, cropped to t in [0, Delta],
 * normalised by their temporal average, Eq. 4).
 *
 * Steps: read `time,value[,voltage]` rows as oscilloscopes write them; find the flicker
 * fundamental from the Hann-windowed spectrum (coarse), refined by phase dispersion
 * minimisation (Stellingwerf 1978: the frequency whose fold leaves the least within-bin
 * variance; any waveform shape, partial cycles) and a least-squares fit of the first harmonics
 * (smooth in f where the samples sit at a few phases); with a voltage column, fit a sine to the
 * voltage (as the paper's Fig. 2) for the grid frequency and time zero; over the recording's
 * whole cycles, sum each harmonic over the samples at their exact phases, up to the harmonics
 * the phases tell apart, and keep those that stand above the fold's noise and aliasing
 * (band-limited BRF, brf.c); normalise to mean 1. */
#include "recognize/base/internal.h"

#include <complex.h>
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

static const double two_pi = 6.283185307179586476925286766559;

/* Search range of the flicker fundamental: at least 2 cycles in the recording and 8 samples a
 * cycle, at most 10 kHz (mains flicker is 100/120 Hz, LED PWM up to a few kHz; faster ripple,
 * such as an electronic ballast's tens of kHz, averages out in a camera window). */
#define FLICKER_MAX_HZ 10000.0
/* Locked flicker is twice a 50/60 Hz grid within 3 % (the brief of recognize.h). */
#define LOCK_TOLERANCE 0.03
/* A harmonic is kept when its amplitude exceeds 4 noise scales (a false alarm probability of
 * e^-8 per harmonic for Gaussian noise); the search stops after 5 harmonics in a row below. */
#define HARMONIC_SNR 4.0
#define HARMONIC_GAP 5
/* A subharmonic with at least 10 % of the peak's power is the true fundamental. */
#define SUBHARMONIC_POWER 0.1
#define PDM_BINS 64
/* The least-squares fit of harmonics 1-3 refines the frequency within +-1/(4 T) of phase
 * dispersion's: that is flat, and can be off by about 1/8 cycle over the recording T (8 samples a
 * cycle at least), when the sample rate is a multiple of f and the samples sit at a few phases. */
#define REFINE_HARMONICS 3
/* The frequency searches stop when their bracket is narrower than FREQ_TOL_CYCLES / T, T the
 * recording's duration (1/T its frequency resolution). Folding at a frequency off by df drifts
 * the phase by df T cycles over the recording: a constant shift, which percent flicker does not
 * see, and a smear that scales harmonic h by sinc(pi h df T) ~ 1 - (pi h df T)^2 / 6, at
 * 1e-5 cycles 2e-9 for harmonics 1-3 and 4e-5 for the 512th (the last of a 1024-sample BRF):
 * the percent flicker moves far below the 0.1 point `delight add` prints, the flicker frequency
 * by under 2e-4 Hz for a 28 ms scope file (printed to 0.01 Hz). (It ran to 1e-10 of f, 3e-10 to
 * 2e-8 cycles: below the rounding of the least-squares cost, whose flat minimum moved by up to
 * 6e-4 Hz with another solver; and half the time of a 2M-sample import.) */
#define FREQ_TOL_CYCLES 1e-5
/* Harmonics h and h + d are told apart when the samples' phases alias them by at most 1 %. */
#define ALIAS_MAX 0.01

/* ------------------------------------------------------------------ reading */

typedef struct {
    double *t, *x, *volt;   /* times (s), values and (optional) voltages, as read */
    double t0, dt;          /* time of sample 0 and the sampling step, s */
    size_t n, cap;
} series;

/* Parse one row of fields: column 1 time, 2 value, vcol voltage (0: none); other columns are
 * ignored, an empty last one (a trailing comma) too. Returns 0, or the 1-based column that is
 * missing or not a number. */
static int parse_row(char **f, size_t count, int vcol, double *t, double *x, double *v)
{
    if (count > 1 && !*f[count - 1]) count--;
    int bad = 0;
    for (size_t c = 0; c < count; c++) {
        int col = (int)c + 1;
        double *dst = col == 1 ? t : col == 2 ? x : col == vcol ? v : NULL;
        if (dst && !gs_parse_number(f[c], dst) && !bad) bad = col;
    }
    int need = vcol > 2 ? vcol : 2;
    return bad ? bad : (int)count < need ? (int)count + 1 : 0;
}

/* A header that runs into the first sample ("ch1_time(s),ch1_value(V)-0.014,0.992"): a row of
 * 2k-1 fields whose k-th field ends in a number. Splits that field at the number's start and
 * returns the index of the first field of the sample (or 0 when the row is not one). */
static size_t header_run_in(char **f, size_t count)
{
    if (count < 3 || count % 2 == 0) return 0;
    char *mid = f[count / 2];
    if (!*mid) return 0;   /* (an empty field: mid + 1 would be past its end; found by fuzz_recording) */
    for (char *s = mid + 1; *s; s++) {   /* longest numeric suffix, non-empty prefix */
        double v;
        if (strchr("+-.0123456789", *s) && gs_parse_number(s, &v)) {
            memmove(mid, s, strlen(s) + 1);
            return count / 2;
        }
    }
    return 0;
}

static gs_status push(const char *path, series *s, double t, double x, double v)
{
    if (s->n == s->cap) {
        size_t cap = s->cap ? 2 * s->cap : 4096;
        double *nt = realloc(s->t, cap * sizeof *nt);
        if (nt) s->t = nt;
        double *nx = realloc(s->x, cap * sizeof *nx);
        if (nx) s->x = nx;
        double *nv = realloc(s->volt, cap * sizeof *nv);
        if (nv) s->volt = nv;
        if (!nt || !nx || !nv) return gs_fail(GS_ENOMEM, "%s: cannot hold %zu samples", path, cap);
        s->cap = cap;
    }
    s->t[s->n] = t;
    s->x[s->n] = x;
    s->volt[s->n] = v;
    s->n++;
    return GS_OK;
}

static const char *column_name(int col, int vcol)
{
    return col == 1 ? "time" : col == 2 ? "value" : col == vcol ? "voltage" : "column";
}

typedef struct {
    const char *path;
    int vcol;
    series *s;
} series_reader;

static gs_status series_row(void *ctx, char **f, size_t count, size_t line)
{
    series_reader *r = ctx;
    double t = 0, x = 0, v = 0;
    int bad = parse_row(f, count, r->vcol, &t, &x, &v);
    if (bad == 1 && r->s->n == 0) {
        /* Before the data: metadata (`Key:value,`) or the header, which may run into the
         * first sample. */
        size_t first = header_run_in(f, count);
        if (!first || parse_row(f + first, count - first, r->vcol, &t, &x, &v)) return GS_OK;
        bad = 0;
    }
    if (bad)
        return gs_fail(GS_EFORMAT, "%s:%zu: field %s (column %d): expected a finite number",
                       r->path, line, column_name(bad, r->vcol), bad);
    return push(r->path, r->s, t, x, v);
}

static gs_status read_series(const char *path, int vcol, series *s)
{
    series_reader r = {path, vcol, s};
    gs_status st = gs_csv_read(path, 0, series_row, &r);
    if (st == GS_OK && s->n < 64)
        st = gs_fail(GS_EFORMAT, "%s: %zu samples: expected at least 64 rows of time,value", path, s->n);
    if (st == GS_OK) {
        /* Uniform sampling: every time within half a step of t0 + i dt. */
        s->t0 = s->t[0];
        s->dt = (s->t[s->n - 1] - s->t[0]) / (double)(s->n - 1);
        for (size_t i = 0; i < s->n && st == GS_OK; i++)
            if (!(s->dt > 0) || fabs(s->t[i] - (s->t0 + (double)i * s->dt)) > 0.5 * s->dt)
                st = gs_fail(GS_EFORMAT, "%s: sample %zu: time %g s: expected uniform increasing "
                             "times (step %g s)", path, i + 1, s->t[i], s->dt);
    }
    return st;
}

/* ------------------------------------------------------------ frequency */

/* Coarse spectral peak of x in [f_lo, f_hi] (Hann window, zero-padded 2x), moved to a
 * subharmonic f/k (k = 4..2) that holds at least SUBHARMONIC_POWER of its power. */
static gs_status spectral_peak(const char *path, const double *x, size_t N, double dt, double f_lo,
                               double f_hi, double *f_peak)
{
    size_t P = 2 * N;
    double *buf = calloc(P, sizeof *buf);
    double complex *C = malloc((P / 2 + 1) * sizeof *C);
    double *pw = malloc((P / 2 + 1) * sizeof *pw);
    gs_status st = GS_OK;
    if (!buf || !C || !pw) st = gs_fail(GS_ENOMEM, "%s: cannot allocate a %zu-point DFT", path, P);
    if (st == GS_OK) {
        double mean = 0;
        for (size_t i = 0; i < N; i++) mean += x[i] / (double)N;
        for (size_t i = 0; i < N; i++)
            buf[i] = (x[i] - mean) * (0.5 - 0.5 * cos(two_pi * (double)i / (double)(N - 1)));
        st = gs_brf_spectrum(buf, (int)P, C);
    }
    if (st == GS_OK) {
        double df = 1.0 / ((double)P * dt);
        size_t lo = (size_t)ceil(f_lo / df), hi = (size_t)floor(f_hi / df), best = lo;
        if (hi > P / 2) hi = P / 2;
        if (hi < lo) hi = lo;
        for (size_t k = lo; k <= hi; k++) {
            pw[k] = creal(C[k]) * creal(C[k]) + cimag(C[k]) * cimag(C[k]);
            if (pw[k] > pw[best]) best = k;
        }
        size_t span = P / N;   /* +-1/T in bins */
        for (size_t div = 4, done = 0; div >= 2 && !done; div--) {
            size_t c = best / div;
            if (c < lo + span) continue;
            size_t sub = c - span;
            for (size_t k = c - span; k <= c + span && k <= hi; k++)
                if (pw[k] > pw[sub]) sub = k;
            if (pw[sub] >= SUBHARMONIC_POWER * pw[best]) {
                best = sub;
                done = 1;
            }
        }
        *f_peak = (double)best * df;
    }
    free(buf);
    free(C);
    free(pw);
    return st;
}

/* Phase of sample i at frequency f (cycles, [0,1)) relative to time offset t_ref from sample 0. */
static double phase_of(size_t i, double dt, double t_ref, double f)
{
    double ph = fmod(((double)i * dt - t_ref) * f, 1.0);
    return ph < 0 ? ph + 1.0 : ph;
}

/* Phase dispersion: the within-bin sum of squares of x folded at f into PDM_BINS bins. */
static double dispersion(const double *x, size_t N, double dt, double f)
{
    double s[PDM_BINS] = {0}, s2[PDM_BINS] = {0}, c[PDM_BINS] = {0};
    for (size_t i = 0; i < N; i++) {
        int b = (int)(phase_of(i, dt, 0.0, f) * PDM_BINS) % PDM_BINS;
        s[b] += x[i];
        s2[b] += x[i] * x[i];
        c[b] += 1;
    }
    double d = 0;
    for (int b = 0; b < PDM_BINS; b++)
        if (c[b] > 0) d += s2[b] - s[b] * s[b] / c[b];
    return d;
}

/* Residual sum of squares of the least-squares fit x ~ c + sum_{h=1..H} a_h cos(2 pi h f t) +
 * b_h sin(2 pi h f t) (t = i dt, H <= REFINE_HARMONICS); c, a_1 and b_1 out unless NULL. The
 * normal equations are symmetric positive definite: only their upper triangle is summed, and
 * solved by Cholesky (LAPACK dposv). HUGE_VAL when they are singular (never the minimum). */
static double harmonic_fit(const double *x, size_t N, double dt, double f, int H, double *a, double *b,
                           double *c)
{
    enum { P = 2 * REFINE_HARMONICS + 1 };
    int p = 2 * H + 1;
    double A[P * P] = {0}, rhs[P] = {0}, xx = 0;   /* A column-major: A[j + k P], j <= k */
    for (size_t i = 0; i < N; i++) {
        double w = two_pi * phase_of(i, dt, 0.0, f), r[P] = {1.0, cos(w), sin(w)};
        for (int h = 2; h <= H; h++) {   /* cos and sin of h w by the angle sum */
            r[2 * h - 1] = r[2 * h - 3] * r[1] - r[2 * h - 2] * r[2];
            r[2 * h] = r[2 * h - 2] * r[1] + r[2 * h - 3] * r[2];
        }
        for (int k = 0; k < p; k++) {
            for (int j = 0; j <= k; j++) A[j + k * P] += r[j] * r[k];
            rhs[k] += r[k] * x[i];
        }
        xx += x[i] * x[i];
    }
    double sol[P], fit = 0;
    memcpy(sol, rhs, sizeof sol);
    if (LAPACKE_dposv(LAPACK_COL_MAJOR, 'U', p, 1, A, P, sol, p) != 0) return HUGE_VAL;
    for (int k = 0; k < p; k++) fit += sol[k] * rhs[k];
    if (c) *c = sol[0];
    if (a) *a = sol[1];
    if (b) *b = sol[2];
    return xx - fit;   /* x'x - beta'X'x */
}

/* Golden-section minimum of cost over [lo, hi], to FREQ_TOL_CYCLES over the N dt recording. */
static double golden_min(double (*cost)(const double *, size_t, double, double), const double *x,
                         size_t N, double dt, double lo, double hi)
{
    const double g = 0.6180339887498949;
    double c = hi - g * (hi - lo), d = lo + g * (hi - lo);
    double fc = cost(x, N, dt, c), fd = cost(x, N, dt, d);
    while ((hi - lo) * (double)N * dt > FREQ_TOL_CYCLES) {
        if (fc < fd) {
            hi = d, d = c, fd = fc;
            c = hi - g * (hi - lo), fc = cost(x, N, dt, c);
        } else {
            lo = c, c = d, fc = fd;
            d = lo + g * (hi - lo), fd = cost(x, N, dt, d);
        }
    }
    return 0.5 * (lo + hi);
}

static double sine_cost(const double *x, size_t N, double dt, double f)
{
    return harmonic_fit(x, N, dt, f, 1, NULL, NULL, NULL);
}

static double harmonics_cost(const double *x, size_t N, double dt, double f)
{
    return harmonic_fit(x, N, dt, f, REFINE_HARMONICS, NULL, NULL, NULL);
}

/* The nominal grid (50 or 60) whose frequency times mult is within LOCK_TOLERANCE of f, or 0. */
static int nominal_grid(double f, double mult)
{
    for (int g = 50; g <= 60; g += 10)
        if (fabs(f - mult * g) <= LOCK_TOLERANCE * mult * g) return g;
    return 0;
}

/* --------------------------------------------------------------- folding */

static int bin_of(double phase, int n)
{
    return (int)floor(phase * n + 0.5) % n;   /* bins centred on j/n */
}

/* |mean of e^(2 pi i d phase)| over the first N samples at frequency f: the weight with which
 * harmonic h + d leaks into the sum of harmonic h (1 when the phases cannot tell them apart,
 * as at a sample rate d times f; about 1/N when the phases spread evenly). A geometric series:
 * each sample advances d f dt cycles. */
static double alias_weight(size_t N, double dt, double f, int d)
{
    double s = sin(M_PI * d * f * dt);
    return fabs(s) * (double)N < 1e-6 ? 1.0 : fabs(sin(M_PI * (double)N * d * f * dt) / s) / (double)N;
}

/* Fold x at f_fold with time zero t_ref (s from sample 0) into n bins; write the band-limited
 * waveform to out[0..n) and the harmonics kept to *harmonics. Only the samples spanning the
 * recording's whole cycles are used, so that each harmonic is a plain sum over the samples at
 * their exact phases: no partial cycle biases it, and it holds whether or not the sample rate
 * divides the period. (Weighting each sample by 1/(samples in its bin) does not: at a rate that
 * divides the period the samples sit at a few phases, a phase that straddles two bins counts
 * twice, and the harmonics leak into each other.) The bins give the noise only. Each sample's
 * phase is computed once (the fmod in phase_of is a good part of the fold's time). */
static gs_status fold(const char *path, const double *x, size_t N, double dt, double f_fold,
                      double t_ref, int n, double *out, int *harmonics)
{
    double whole = floor((double)N * dt * f_fold);
    if (whole >= 1) N = (size_t)llround(whole / (f_fold * dt));
    double *mean = calloc((size_t)n, sizeof *mean), *cnt = calloc((size_t)n, sizeof *cnt);
    double complex *C = calloc((size_t)(n / 2 + 1), sizeof *C);
    double *phase = malloc(N * sizeof *phase);
    if (!mean || !cnt || !C || !phase) {
        free(mean);
        free(cnt);
        free(C);
        free(phase);
        return gs_fail(GS_ENOMEM, "%s: cannot fold %zu samples into %d bins", path, N, n);
    }
    double dc = 0, rss = 0;
    for (size_t i = 0; i < N; i++) {
        phase[i] = phase_of(i, dt, t_ref, f_fold);
        int b = bin_of(phase[i], n);
        mean[b] += x[i];
        cnt[b] += 1;
        dc += x[i] / (double)N;
    }
    int filled = 0;
    for (int j = 0; j < n; j++)
        if (cnt[j] > 0) {
            mean[j] /= cnt[j];
            filled++;
        }
    /* The harmonics sum x minus its mean, so that rounding does not leak the (large) mean. */
    C[0] = dc * n;
    /* Harmonics up to h_max, none of which aliases into another by more than ALIAS_MAX. */
    int h_max = 0;
    double leak = 0;
    for (int d = 1; d <= n - 2; d++) {
        double a = alias_weight(N, dt, f_fold, d);
        if (a > ALIAS_MAX) break;
        leak = fmax(leak, a);
        h_max = d / 2;
    }
    int H = 0;
    for (size_t i = 0; i < N; i++) {
        double r = x[i] - mean[bin_of(phase[i], n)];
        rss += r * r;
        double w = (x[i] - dc) * n / (double)N;
        double complex e = cexp(-I * two_pi * phase[i]), z = 1.0;
        for (int h = 1; h <= h_max; h++) {
            z *= e;
            C[h] += w * z;
        }
    }
    /* Noise of a harmonic's amplitude 2|C_h|/n: each quadrature has variance 2 sigma^2 / N,
     * sigma^2 the within-bin variance. Harmonics are kept up to the last one above
     * HARMONIC_SNR noise scales (or above rounding, for noise-free data). */
    double dof = (double)N - filled;
    double scale = dof > 0 ? sqrt(2.0 * rss / dof / (double)N) : 0.0;
    double top = 0;
    for (int h = 1; h <= h_max; h++) top = fmax(top, 2.0 * cabs(C[h]) / n);
    double floor_amp = fmax(fmax(HARMONIC_SNR * scale, leak * top), 1e-12 * fabs(creal(C[0])) / n);
    for (int h = 1; h <= h_max && h - H <= HARMONIC_GAP; h++)
        if (2.0 * cabs(C[h]) / n > floor_amp) H = h;
    /* The trigonometric polynomial of harmonics 0..H at t = j/n (no Nyquist term). */
    for (int j = 0; j < n; j++) {
        double acc = creal(C[0]);
        for (int h = 1; h <= H; h++) {
            double turns = (double)(((long long)h * j) % n) / n;
            acc += 2.0 * creal(C[h] * cexp(I * two_pi * turns));
        }
        out[j] = acc / n;
    }
    *harmonics = H;
    free(mean);
    free(cnt);
    free(C);
    free(phase);
    if (filled < 4)
        return gs_fail(GS_EFORMAT, "%s: %d of %d phase bins hold samples: expected at least 4",
                       path, filled, n);
    return GS_OK;
}

/* -------------------------------------------------------------- the bulb */

static void names_from_path(const char *path, gs_bulb *out)
{
    const char *base = strrchr(path, '/');
    base = base ? base + 1 : path;
    size_t len = strlen(base);
    const char *dot = strrchr(base, '.');
    if (dot && dot > base) len = (size_t)(dot - base);
    size_t k = 0;
    for (size_t i = 0; i < len && k + 1 < GS_ID_MAX; i++) {
        char c = base[i];
        int ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                 c == '_' || c == '-' || c == '.';
        out->id[k++] = ok ? c : '_';
    }
    out->id[k] = '\0';
    if (k == 0) strcpy(out->id, "recording");
    k = 0;
    for (size_t i = 0; i < len && k + 1 < GS_NAME_MAX; i++)
        out->name[k++] = strchr(",\"\r\n", base[i]) ? ' ' : base[i];
    out->name[k] = '\0';
}

gs_status gs_recording_to_bulb(const char *path, int voltage_column, int n, gs_bulb *out,
                                gs_recording_info *info)
{
    memset(out, 0, sizeof *out);
    if (voltage_column == 1 || voltage_column == 2)
        return gs_fail(GS_EINVAL, "%s: voltage column %d: expected 0 (none) or a column after time "
                       "and value (>= 3)", path, voltage_column);
    if (voltage_column < 0) voltage_column = 0;
    gs_brf brf;
    gs_status st = gs_brf_init(&brf, n, 1);
    if (st != GS_OK) return st;
    series s = {0};
    if ((st = read_series(path, voltage_column, &s)) != GS_OK) goto done;

    size_t N = s.n;
    double dt = s.dt, T = (double)N * dt, rate = 1.0 / dt;
    double f_hi = fmin(rate / 8.0, FLICKER_MAX_HZ), f_lo = 2.0 / T;
    if (f_lo >= f_hi) {
        st = gs_fail(GS_EFORMAT, "%s: %.3g s at %.3g Hz: too short for two flicker cycles", path, T, rate);
        goto done;
    }
    double f_coarse, f;
    if ((st = spectral_peak(path, s.x, N, dt, f_lo, f_hi, &f_coarse)) != GS_OK) goto done;
    f = golden_min(dispersion, s.x, N, dt, fmax(f_coarse - 1.0 / T, 0.5 * f_coarse), f_coarse + 1.0 / T);
    f = golden_min(harmonics_cost, s.x, N, dt, f - 0.25 / T, f + 0.25 / T);

    /* Reference: a sine fitted to the outlet voltage gives the grid frequency and, at its first
     * negative-to-positive crossing, time zero (paper Fig. 2). */
    int grid = nominal_grid(f, 2.0), voltage_grid = 0;
    double f_fold = f, t_ref = 0.0;
    gs_ref ref = grid ? GS_REF_NONE : GS_REF_UNLOCKED;
    if (voltage_column) {
        double v_lo = fmax(40.0, 1.0 / T), fv;
        if (v_lo >= 70.0) {
            st = gs_fail(GS_EFORMAT, "%s: %.3g s: too short for one AC cycle of the voltage", path, T);
            goto done;
        }
        if ((st = spectral_peak(path, s.volt, N, dt, v_lo, 70.0, &fv)) != GS_OK) goto done;
        fv = golden_min(sine_cost, s.volt, N, dt, fmax(fv - 1.0 / T, 0.5 * fv), fv + 1.0 / T);
        voltage_grid = nominal_grid(fv, 1.0);
        if (!voltage_grid) {
            st = gs_fail(GS_EFORMAT, "%s: field voltage (column %d): %.4g Hz: expected a 50 or 60 Hz "
                         "mains voltage (+-3 %%)", path, voltage_column, fv);
            goto done;
        }
        if (grid == voltage_grid) {
            double a = 0, b = 0;
            if (harmonic_fit(s.volt, N, dt, fv, 1, &a, &b, NULL) == HUGE_VAL) {
                st = gs_fail(GS_ENUMERIC, "%s: field voltage (column %d): the %.4g Hz sine cannot be "
                             "fitted: expected samples spread over its cycle", path, voltage_column, fv);
                goto done;
            }
            /* a cos w + b sin w = R sin(w + phi), phi = atan2(a, b): rising zero at w = -phi. */
            double cyc = -atan2(a, b) / two_pi;
            t_ref = (cyc - floor(cyc)) / fv;
            f_fold = 2.0 * fv;
            ref = GS_REF_VOLTAGE;
        } else {
            grid = 0;
            ref = GS_REF_UNLOCKED;
        }
    }

    int harmonics = 0;
    if ((st = fold(path, s.x, N, dt, f_fold, t_ref, n, brf.v, &harmonics)) != GS_OK) goto done;
    /* A photodiode sees no negative light: a negative minimum is the scope's offset (the Hue
     * file sits at -16 mV when dark) or ringing, so raise the waveform to a minimum of 0. */
    double lo = brf.v[0];
    for (int j = 1; j < n; j++) lo = fmin(lo, brf.v[j]);
    if (lo < 0)
        for (int j = 0; j < n; j++) brf.v[j] -= lo;
    if (gs_brf_normalize(&brf, NULL) != GS_OK) {
        double sum = 0;
        for (int j = 0; j < n; j++) sum += brf.v[j];
        st = isfinite(sum) ? gs_fail(GS_ENUMERIC, "%s: field value: mean light level is not positive: "
                                     "expected a lit photodiode", path)
                           : gs_fail(GS_ENUMERIC, "%s: field value: mean light level is not a finite "
                                     "number (the values' sums overflow): expected a photodiode's "
                                     "readings", path);
        goto done;
    }
    if (harmonics == 0) {
        /* No flicker above the noise: a flat BRF, valid at any phase; its frequency is unknown. */
        f_fold = NAN;
        grid = voltage_grid;
        ref = voltage_grid ? GS_REF_VOLTAGE : GS_REF_NONE;
    }

    names_from_path(path, out);
    out->type = GS_TECH_UNKNOWN;
    out->watts = 0.0;
    out->grid_hz = grid ? grid : voltage_grid;
    strcpy(out->sensor, "photodiode");
    out->ref = ref;
    out->chroma[0] = 1.0;
    out->brf = brf;
    brf.v = NULL;
    if (info) {
        info->samples = N;
        info->sample_rate_hz = rate;
        info->flicker_hz = f_fold;
        info->cycles = T * f_fold;
        info->percent_flicker = gs_brf_percent_flicker(&out->brf, 0);
        info->grid_hz = grid;
        double top = s.x[0];
        for (size_t i = 1; i < N; i++) top = fmax(top, s.x[i]);
        size_t at_top = 0;
        for (size_t i = 0; i < N; i++)
            at_top += s.x[i] == top && ((i > 0 && s.x[i - 1] == top) || (i + 1 < N && s.x[i + 1] == top));
        info->clipped_share = (double)at_top / (double)N;
    }
done:
    gs_brf_release(&brf);
    free(s.t);
    free(s.x);
    free(s.volt);
    return st;
}
