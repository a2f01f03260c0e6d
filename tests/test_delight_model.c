/* test_delight_model.c - the built-in DELIGHT substitute (recognize/base/delight_model.c) against
 * shared/BULBS.md: coverage, validity, determinism, band limit, percent flicker per technology,
 * ballast and thermal lag inside the templates, per-channel physics, 50 vs 60 Hz consistency.
 *
 * Every oracle here is computed independently of the generator: phases and amplitudes come from
 * the DFT of the stored BRFs (gs_brf_spectrum), ranges from BULBS.md (quoted next to each).
 * Conventions (docs/design.md): t = 0 at a rising zero crossing of V(t) = sin(2 pi f t), so V^2
 * (the "unmediated bulb" of Sec. 2.2) peaks at t = Delta/2; a lag is the delay of the BRF's
 * fundamental peak behind that, in degrees of the flicker cycle.
 *
 * GS_VERBOSE=1 build/run_tests delight_model_percent_flicker prints the per-technology and per-bulb
 * tables that docs/delight-models.md quotes. */
#include "recognize/base/internal.h"
#include "tests/test.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define N 1024
static const double pi = 3.14159265358979323846;

static gs_delight *generate(int n)
{
    gs_delight *d = gs_delight_new();
    CHECK(d != NULL);
    if (d) CHECK_OK(gs_delight_generate(d, n));
    return d;
}

/* DFT coefficient h of x[0..n). */
static double complex harmonic(const double *x, int n, int h)
{
    double complex *C = malloc(sizeof *C * (size_t)(n / 2 + 1));
    CHECK(C != NULL);
    if (!C) return 0;
    CHECK_OK(gs_brf_spectrum(x, n, C));
    double complex c = C[h];
    free(C);
    return c;
}

/* Amplitude of harmonic h relative to the mean (BRFs have mean 1). */
static double amp(const double *x, int n, int h)
{
    return 2.0 * cabs(harmonic(x, n, h)) / n;
}

/* Lag of the fundamental's peak behind the V^2 peak (t = Delta/2), degrees of flicker, [0, 360). */
static double lag_deg(const double *x, int n)
{
    double u_peak = -carg(harmonic(x, n, 1)) / (2.0 * pi);
    double lag = fmod(360.0 * (u_peak - 0.5), 360.0);
    return lag < 0.0 ? lag + 360.0 : lag + 0.0;   /* + 0.0: no "-0" */
}

static const double *band(const gs_bulb *b, int k)
{
    return b->brf.v + (size_t)k * (size_t)b->brf.n;
}

static const gs_bulb *get(const gs_delight *d, const char *id, int hz, int bands)
{
    const gs_bulb *b = gs_delight_find(d, id, hz, bands);
    CHECK_MSG(b != NULL, "bulb %s at %d Hz with %d bands missing", id, hz, bands);
    return b;
}

/* The mono entries at 50 Hz: one per bulb (the iteration over bulbs in the tests below). */
#define FOR_BULBS(d, b)                                                                      \
    for (size_t i_ = 0; i_ < gs_delight_count(d); i_++)                                     \
        for (const gs_bulb *b = gs_delight_get(d, i_); b; b = NULL)                        \
            if (b->grid_hz == 50 && b->brf.bands == 1)

static int is_inductive(gs_tech t)
{
    return t == GS_TECH_FLUORESCENT_MAGNETIC || t == GS_TECH_SODIUM_HP || t == GS_TECH_SODIUM_LP ||
           t == GS_TECH_METAL_HALIDE || t == GS_TECH_MERCURY;
}

/* ------------------------------------------------------------------ coverage */

TEST(delight_model_covers_technologies_grids_and_sensors)
{
    gs_delight *d = generate(N);
    const char *sensors[2] = {"photodiode", "rgb"};
    for (int g = 0; g < 2; g++)
        for (int s = 0; s < 2; s++) {
            int hz = g ? 60 : 50, bulbs = 0, per_tech[GS_TECH_COUNT] = {0}, techs = 0;
            for (size_t i = 0; i < gs_delight_count(d); i++) {
                const gs_bulb *b = gs_delight_get(d, i);
                if (b->grid_hz != hz || strcmp(b->sensor, sensors[s])) continue;
                bulbs++;
                if (per_tech[b->type]++ == 0) techs++;
            }
            CHECK_MSG(bulbs >= 30, "%d Hz %s: %d bulbs, expected >= 30", hz, sensors[s], bulbs);
            CHECK_MSG(techs >= 9, "%d Hz %s: %d technologies, expected >= 9", hz, sensors[s], techs);
            for (int t = 0; t < GS_TECH_UNKNOWN; t++)
                CHECK_MSG(per_tech[t] >= 2, "%d Hz %s: %d bulbs of %s, expected >= 2", hz, sensors[s],
                          per_tech[t], gs_tech_name((gs_tech)t));
        }
    /* every bulb has all four entries */
    size_t ids = 0;
    FOR_BULBS(d, b) {
        ids++;
        CHECK(gs_delight_find(d, b->id, 50, 3) != NULL);
        CHECK(gs_delight_find(d, b->id, 60, 1) != NULL);
        CHECK(gs_delight_find(d, b->id, 60, 3) != NULL);
    }
    CHECK(gs_delight_count(d) == 4 * ids);
    gs_delight_free(d);
}

TEST(delight_model_entries_are_valid)
{
    gs_delight *d = generate(N);
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        CHECK_OK(gs_bulb_validate(b));
        CHECK(b->brf.n == N);
        CHECK(b->ref == GS_REF_VOLTAGE);
        CHECK_MSG(b->watts > 0.0 && b->watts < 2000.0, "%s: %g W", b->id, b->watts);
        CHECK(strchr(b->name, ',') == NULL && b->name[0]);
        int mono = !strcmp(b->sensor, "photodiode");
        CHECK(mono || !strcmp(b->sensor, "rgb"));
        CHECK(b->brf.bands == (mono ? 1 : 3));
        if (mono) CHECK(b->chroma[0] == 1.0);
        for (int k = 0; k < b->brf.bands; k++) {
            double s = 0;
            for (int j = 0; j < N; j++) s += band(b, k)[j];
            CHECK_NEAR(s / N, 1.0, 1e-12);
        }
    }
    gs_delight_free(d);
}

TEST(delight_model_is_deterministic)
{
    gs_delight *a = generate(N), *b = generate(N);
    CHECK(gs_delight_count(a) == gs_delight_count(b));
    for (size_t i = 0; i < gs_delight_count(a) && i < gs_delight_count(b); i++) {
        const gs_bulb *x = gs_delight_get(a, i), *y = gs_delight_get(b, i);
        CHECK(!strcmp(x->id, y->id) && !strcmp(x->name, y->name) && !strcmp(x->sensor, y->sensor));
        CHECK(x->type == y->type && x->grid_hz == y->grid_hz && x->ref == y->ref);
        CHECK(memcmp(&x->watts, &y->watts, sizeof x->watts) == 0);
        CHECK(memcmp(x->chroma, y->chroma, sizeof x->chroma) == 0);
        CHECK(x->brf.n == y->brf.n && x->brf.bands == y->brf.bands);
        CHECK_MSG(memcmp(x->brf.v, y->brf.v, sizeof(double) * (size_t)x->brf.n * (size_t)x->brf.bands) == 0,
                  "%s %d Hz %s: BRF differs between two runs", x->id, x->grid_hz, x->sensor);
    }
    gs_delight_free(a);
    gs_delight_free(b);
}

TEST(delight_model_rejects_bad_arguments_and_duplicates)
{
    CHECK(gs_delight_generate(NULL, N) == GS_EINVAL);
    gs_delight *d = gs_delight_new();
    CHECK(gs_delight_generate(d, 1023) == GS_EINVAL);
    CHECK(gs_delight_generate(d, 2) == GS_EINVAL);
    CHECK(gs_delight_generate(d, 0) == GS_EINVAL);
    CHECK(gs_delight_count(d) == 0);
    CHECK_OK(gs_delight_generate(d, 64));
    size_t count = gs_delight_count(d);
    CHECK(count > 0);
    CHECK(gs_delight_generate(d, 64) == GS_EINVAL);   /* all ids already present */
    CHECK(gs_delight_count(d) == count);              /* and nothing was added */
    gs_delight_free(d);
}

/* --------------------------------------------------------------- band limit */

TEST(delight_model_has_no_nyquist_component_and_shifts_compose)
{
    int sizes[3] = {16, 26, N};
    for (int si = 0; si < 3; si++) {
        int n = sizes[si];
        gs_delight *d = generate(n);
        double complex *C = malloc(sizeof *C * (size_t)(n / 2 + 1));
        for (size_t i = 0; C && i < gs_delight_count(d); i++) {
            const gs_bulb *b = gs_delight_get(d, i);
            CHECK(b->brf.n == n);
            for (int k = 0; k < b->brf.bands; k++) {
                CHECK_OK(gs_brf_spectrum(band(b, k), n, C));
                CHECK_MSG(cabs(C[n / 2]) / n < 1e-12, "%s %d Hz band %d, n=%d: Nyquist %g", b->id,
                          b->grid_hz, k, n, cabs(C[n / 2]) / n);
            }
        }
        free(C);
        /* consequence: fractional shifts compose exactly (gs_brf_shift) */
        const gs_bulb *b = get(d, "hps-150w", 50, 3);
        if (b) {
            gs_brf one, two, sum;
            CHECK_OK(gs_brf_init(&one, n, 3));
            CHECK_OK(gs_brf_init(&two, n, 3));
            CHECK_OK(gs_brf_init(&sum, n, 3));
            CHECK_OK(gs_brf_shift(&b->brf, 0.3137, &one));
            CHECK_OK(gs_brf_shift(&one, 0.4411, &two));
            CHECK_OK(gs_brf_shift(&b->brf, 0.3137 + 0.4411, &sum));
            double err = 0;
            for (int j = 0; j < 3 * n; j++) err = fmax(err, fabs(two.v[j] - sum.v[j]));
            CHECK_MSG(err < 1e-12, "n=%d: shifts do not compose (%g)", n, err);
            gs_brf_release(&one);
            gs_brf_release(&two);
            gs_brf_release(&sum);
        }
        gs_delight_free(d);
    }
}

/* ------------------------------------------------------------ percent flicker */

/* BULBS.md's percent-flicker column, per technology (all entries, both grids). */
static const struct {
    gs_tech tech;
    double lo, hi;
    const char *source;
} pf_rows[] = {
    {GS_TECH_INCANDESCENT, 4, 25, "120 V 4-6 % (50-60 W), 10 % (25 W) [M]; 230 V 7-12 % (40-100 W), 15-25 % (15-25 W) [D]"},
    {GS_TECH_HALOGEN, 1, 10, "mains 5-10 % [D/L]; 12 V on magnetic transformer 1-3 % [D]"},
    {GS_TECH_FLUORESCENT_MAGNETIC, 15, 40, "25-40 % halophosphate, 15-25 % triphosphor [L]"},
    {GS_TECH_FLUORESCENT_ELECTRONIC, 1, 10, "1-10 % [L]"},
    {GS_TECH_CFL, 5, 30, "5-30 % [L], 8.9 % measured [M]"},
    {GS_TECH_LED_CAPACITOR, 1, 40, "1-40 % [M: 2.5-36 % over 9 lamps]"},
    {GS_TECH_LED_LINEAR, 99, 100.5, "~100 % [D] (+0.5 for the band limit's ringing)"},
    {GS_TECH_LED_PWM, 0, 1, "100 % unlocked [M]; flat when AC-locked [D]: < 1 %"},
    {GS_TECH_SODIUM_HP, 90, 100, "90-100 % [L]"},
    {GS_TECH_SODIUM_LP, 80, 100, "80-100 % [L]"},
    {GS_TECH_METAL_HALIDE, 35, 60, "35-60 % [L]"},
    {GS_TECH_MERCURY, 35, 65, "50-65 % clear, 35-45 % coated [L]"},
};

/* Finer BULBS.md rows, matched by id substring; hz = 0: both grids, else the bulb's home grid
 * (BULBS.md's incandescent rows are 120 V at 60 Hz and 230 V at 50 Hz). */
static const struct {
    gs_tech tech;
    const char *id_part;
    int hz;
    double lo, hi;
    const char *source;
} pf_subrows[] = {
    {GS_TECH_INCANDESCENT, "-25w-120v", 60, 9, 11, "10 % (25 W, 120 V) [M], +-1"},
    {GS_TECH_INCANDESCENT, "-40w-120v", 60, 6, 9, "between 10 % (25 W) and 4-6 % (50-60 W) [M]"},
    {GS_TECH_INCANDESCENT, "-60w-120v", 60, 4, 6, "4-6 % (50-60 W, 120 V) [M]"},
    {GS_TECH_INCANDESCENT, "-100w-120v", 60, 4, 6, "4-6 % (>= 50 W, 120 V) [M]"},
    {GS_TECH_INCANDESCENT, "-25w-230v", 50, 15, 25, "15-25 % (15-25 W, 230 V) [D]"},
    {GS_TECH_INCANDESCENT, "-40w-230v", 50, 7, 12, "7-12 % (40-100 W, 230 V) [D]"},
    {GS_TECH_INCANDESCENT, "-60w-230v", 50, 7, 12, "7-12 % (40-100 W, 230 V) [D]"},
    {GS_TECH_INCANDESCENT, "-100w-230v", 50, 7, 12, "7-12 % (40-100 W, 230 V) [D]"},
    {GS_TECH_HALOGEN, "-12v", 0, 1, 3, "12 V on magnetic transformer 1-3 % [D]"},
    {GS_TECH_HALOGEN, "0v", 0, 5, 10, "mains 5-10 % [D/L]"},   /* -120v, -230v */
    {GS_TECH_FLUORESCENT_MAGNETIC, "-halo", 0, 25, 40, "25-40 % halophosphate [L]"},
    {GS_TECH_FLUORESCENT_MAGNETIC, "-tri", 0, 15, 25, "15-25 % triphosphor [L]"},
    {GS_TECH_CFL, "cfl-15w-m", 60, 8.8, 9.0, "8.9 % measured [M] (data/flicker/CFL.csv: 60 Hz mains)"},
    {GS_TECH_MERCURY, "-clear", 0, 50, 65, "50-65 % clear [L]"},
    {GS_TECH_MERCURY, "-coated", 0, 35, 45, "35-45 % coated [L]"},
};

TEST(delight_model_percent_flicker_in_bulbs_md_ranges)
{
    gs_delight *d = generate(N);
    int verbose = getenv("GS_VERBOSE") && *getenv("GS_VERBOSE");
    double lo[GS_TECH_COUNT][2], hi[GS_TECH_COUNT][2];
    int count[GS_TECH_COUNT] = {0};
    for (int t = 0; t < GS_TECH_COUNT; t++) lo[t][0] = lo[t][1] = INFINITY, hi[t][0] = hi[t][1] = -INFINITY;
    if (verbose)
        printf("| bulb | technology | W | PF 50 Hz | PF 60 Hz | FI 50 Hz | lag 50 Hz (deg) | lag 60 Hz (deg) | Q (R, G, B) |\n"
               "| --- | --- | --- | --- | --- | --- | --- | --- | --- |\n");
    FOR_BULBS(d, b50) {
        const gs_bulb *b60 = get(d, b50->id, 60, 1), *rgb = get(d, b50->id, 50, 3);
        if (!b60 || !rgb) continue;
        count[b50->type]++;
        int row = -1;
        for (size_t r = 0; r < sizeof pf_rows / sizeof *pf_rows; r++)
            if (pf_rows[r].tech == b50->type) row = (int)r;
        CHECK_MSG(row >= 0, "%s: technology %s has no BULBS.md row", b50->id, gs_tech_name(b50->type));
        const gs_bulb *e[2] = {b50, b60};
        for (int g = 0; g < 2; g++) {
            double pf = gs_brf_percent_flicker(&e[g]->brf, 0);
            lo[b50->type][g] = fmin(lo[b50->type][g], pf);
            hi[b50->type][g] = fmax(hi[b50->type][g], pf);
            if (row >= 0)
                CHECK_MSG(pf >= pf_rows[row].lo && pf <= pf_rows[row].hi,
                          "%s %d Hz: PF %.2f %% outside BULBS.md %s %g-%g %% (%s)", b50->id,
                          e[g]->grid_hz, pf, gs_tech_name(b50->type), pf_rows[row].lo,
                          pf_rows[row].hi, pf_rows[row].source);
            for (size_t r = 0; r < sizeof pf_subrows / sizeof *pf_subrows; r++) {
                if (pf_subrows[r].tech != b50->type ||
                    !strstr(b50->id, pf_subrows[r].id_part) ||
                    (pf_subrows[r].hz && pf_subrows[r].hz != e[g]->grid_hz))
                    continue;
                CHECK_MSG(pf >= pf_subrows[r].lo && pf <= pf_subrows[r].hi,
                          "%s %d Hz: PF %.2f %% outside BULBS.md %g-%g %% (%s)", b50->id,
                          e[g]->grid_hz, pf, pf_subrows[r].lo, pf_subrows[r].hi, pf_subrows[r].source);
            }
        }
        if (verbose) {
            double fi = 0;
            for (int j = 0; j < N; j++) fi += b50->brf.v[j] > 1.0 ? b50->brf.v[j] - 1.0 : 0.0;
            printf("| %s | %s | %g | %.2f | %.2f | %.3f | %.1f | %.1f | %.3f, %.3f, %.3f |\n", b50->id,
                   gs_tech_name(b50->type), b50->watts, gs_brf_percent_flicker(&b50->brf, 0),
                   gs_brf_percent_flicker(&b60->brf, 0), fi / N, lag_deg(b50->brf.v, N),
                   lag_deg(b60->brf.v, N), rgb->chroma[0], rgb->chroma[1], rgb->chroma[2]);
        }
    }
    if (verbose) {
        printf("\n| technology | bulbs | PF 50 Hz (%%) | PF 60 Hz (%%) | BULBS.md |\n| --- | --- | --- | --- | --- |\n");
        for (size_t r = 0; r < sizeof pf_rows / sizeof *pf_rows; r++) {
            gs_tech t = pf_rows[r].tech;
            printf("| %s | %d | %.2f-%.2f | %.2f-%.2f | %s |\n", gs_tech_name(t), count[t], lo[t][0],
                   hi[t][0], lo[t][1], hi[t][1], pf_rows[r].source);
        }
    }
    gs_delight_free(d);
}

/* ------------------------------------------------------------------ phase */

/* Ballast lag inside the template (BULBS.md "Facts": a series choke makes the lamp current lag the
 * voltage by 55-65 deg of the AC cycle = 110-130 deg of the flicker cycle). The light's
 * fundamental then lags V^2's by 110-130 deg plus at most the slowest first-order response in the
 * light path, atan(2 pi 2f tau_max) (phosphor or plasma afterglow), with 10 deg either side for
 * the waveform's shape (re-ignition spike, dark gap, |i|^gamma). A template referenced to the
 * lamp current instead would lag by only 0-75 deg. */
static double tau_max_s(const gs_bulb *b)
{
    switch (b->type) {
    case GS_TECH_FLUORESCENT_MAGNETIC: return 5e-3;    /* Tb green 2-5 ms [D] */
    case GS_TECH_SODIUM_HP: return 0.5e-3;             /* afterglow 0.1-0.5 ms [L/D] */
    case GS_TECH_SODIUM_LP: return 0.3e-3;             /* model: 0.1-0.3 ms */
    case GS_TECH_METAL_HALIDE: return 1.0e-3;          /* model: species 0.1-1 ms */
    case GS_TECH_MERCURY: return 2.1e-3;               /* model: arc 0.6 ms + Eu 1.5 ms */
    default: return 0.0;
    }
}

TEST(delight_model_ballast_lag_inside_template)
{
    gs_delight *d = generate(N);
    int tested = 0;
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        if (!is_inductive(b->type)) continue;
        double w = 2.0 * pi * 2.0 * b->grid_hz;
        double lo = 2 * 55 - 10, hi = 2 * 65 + atan(w * tau_max_s(b)) * 180.0 / pi + 10;
        for (int k = 0; k < b->brf.bands; k++) {
            double lag = lag_deg(band(b, k), N);
            CHECK_MSG(lag >= lo && lag <= hi, "%s %d Hz %s band %d: lag %.1f deg, expected %.0f-%.0f",
                      b->id, b->grid_hz, b->sensor, k, lag, lo, hi);
            tested++;
        }
        /* prompt channels: fluorescent blue (Hg lines + fast BAM/Sb phosphor), clear mercury
         * (lines, arc afterglow <= 0.6 ms) carry only the ballast lag */
        if (b->brf.bands == 3 && (b->type == GS_TECH_FLUORESCENT_MAGNETIC || strstr(b->id, "-clear"))) {
            double tau = b->type == GS_TECH_MERCURY ? 0.6e-3 : 10e-6;
            double lag = lag_deg(band(b, 2), N), top = 2 * 65 + atan(w * tau) * 180.0 / pi + 10;
            CHECK_MSG(lag >= lo && lag <= top, "%s %d Hz blue: lag %.1f deg, expected %.0f-%.0f",
                      b->id, b->grid_hz, lag, lo, top);
        }
    }
    CHECK(tested >= 4 * 15);
    gs_delight_free(d);
}

/* Incandescent and halogen (BULBS.md: thermal low-pass of V^2 with tau 30-60 ms [D], lag
 * ~85-89 deg [D]). For a first-order low-pass the lag is atan(2 pi 2f tau): recover tau from the
 * 50 Hz template, check it against 30-60 ms, and predict the 60 Hz template's lag and ripple
 * from it (the same filament at a faster supply). */
TEST(delight_model_filament_lag_and_time_constant)
{
    gs_delight *d = generate(N);
    int tested = 0;
    FOR_BULBS(d, b50) {
        if (b50->type != GS_TECH_INCANDESCENT && b50->type != GS_TECH_HALOGEN) continue;
        const gs_bulb *b60 = get(d, b50->id, 60, 1);
        if (!b60) continue;
        double lag50 = lag_deg(b50->brf.v, N), lag60 = lag_deg(b60->brf.v, N);
        CHECK_MSG(lag50 >= 85 && lag50 <= 89 && lag60 >= 85 && lag60 <= 89,
                  "%s: lag %.2f / %.2f deg at 50 / 60 Hz, expected 85-89", b50->id, lag50, lag60);
        double tau = tan(lag50 * pi / 180.0) / (2 * pi * 100.0);
        CHECK_MSG(tau >= 0.0295 && tau <= 0.0605, "%s: tau %.1f ms from the lag, expected 30-60", b50->id,
                  tau * 1e3);
        double pred60 = atan(2 * pi * 120.0 * tau) * 180.0 / pi;
        CHECK_MSG(fabs(lag60 - pred60) < 0.05, "%s: 60 Hz lag %.3f, first-order filter predicts %.3f",
                  b50->id, lag60, pred60);
        double ratio = amp(b60->brf.v, N, 1) / amp(b50->brf.v, N, 1);
        double pred = sqrt(1 + pow(2 * pi * 100 * tau, 2)) / sqrt(1 + pow(2 * pi * 120 * tau, 2));
        CHECK_MSG(ratio < 1.0 && fabs(ratio - pred) < 0.01,
                  "%s: 60/50 Hz ripple %.4f, first-order filter predicts %.4f", b50->id, ratio, pred);
        /* near-pure sinusoid at 2f: 2nd/1st harmonic <= 0.07 [M] */
        for (int g = 0; g < 2; g++) {
            const gs_bulb *b = g ? b60 : b50;
            double h21 = amp(b->brf.v, N, 2) / amp(b->brf.v, N, 1);
            CHECK_MSG(h21 <= 0.07, "%s %d Hz: 2nd/1st harmonic %.3f, BULBS.md [M] <= 0.07", b->id,
                      b->grid_hz, h21);
        }
        tested++;
    }
    CHECK(tested >= 8);
    gs_delight_free(d);
}

/* Ripple per band ~ d ln L / d ln T ~ hc/(lambda k T): blue ~1.45x red (BULBS.md [D]); through a
 * real camera's bands 1.3-1.6, green in between, all bands in phase (one filament temperature). */
TEST(delight_model_incandescent_blue_ripple_exceeds_red)
{
    gs_delight *d = generate(N);
    int tested = 0;
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        if ((b->type != GS_TECH_INCANDESCENT && b->type != GS_TECH_HALOGEN) || b->brf.bands != 3) continue;
        double r = amp(band(b, 0), N, 1), g = amp(band(b, 1), N, 1), bl = amp(band(b, 2), N, 1);
        CHECK_MSG(bl / r >= 1.3 && bl / r <= 1.6, "%s %d Hz: blue/red ripple %.3f", b->id, b->grid_hz, bl / r);
        CHECK(g > r && g < bl);
        CHECK_NEAR(lag_deg(band(b, 2), N), lag_deg(band(b, 0), N), 1e-6);
        CHECK_MSG(b->chroma[0] > b->chroma[1] && b->chroma[1] > b->chroma[2], "%s: warm white expected", b->id);
        tested++;
    }
    CHECK(tested >= 24);
    gs_delight_free(d);
}

/* ------------------------------------------------------- 50 vs 60 Hz physics */

/* The 60 Hz entry is the same physical bulb at a faster supply, not the 50 Hz samples: every model
 * with a time constant differs. The linear LED driver has none (its light is a function of |V|
 * alone, dark for (2/pi) asin(Vf/Vpk) of the cycle), so its templates must be equal instead. */
TEST(delight_model_60hz_is_the_same_bulb_not_a_copy)
{
    gs_delight *d = generate(N);
    FOR_BULBS(d, b50) {
        const gs_bulb *b60 = get(d, b50->id, 60, 1);
        if (!b60) continue;
        double diff = 0;
        for (int j = 0; j < N; j++) diff = fmax(diff, fabs(b50->brf.v[j] - b60->brf.v[j]));
        if (b50->type == GS_TECH_LED_LINEAR)
            CHECK_MSG(diff < 1e-9, "%s: linear driver differs by %g between 50 and 60 Hz", b50->id, diff);
        else
            CHECK_MSG(diff > (b50->type == GS_TECH_LED_PWM ? 1e-5 : 1e-3),
                      "%s: 60 Hz template equals the 50 Hz one (max diff %g)", b50->id, diff);
    }
    gs_delight_free(d);
}

/* BULBS.md: dark 33/49/65 % of the cycle for Vf/Vpk 0.5/0.7/0.85, i.e. (2/pi) asin(Vf/Vpk) for
 * Vf/Vpk in 0.5-0.85: 0.333-0.646 of the cycle. Dark = below 1 % of the mean. */
TEST(delight_model_led_linear_dark_interval)
{
    gs_delight *d = generate(N);
    int tested = 0;
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        if (b->type != GS_TECH_LED_LINEAR) continue;
        for (int k = 0; k < b->brf.bands; k++) {
            int dark = 0;
            for (int j = 0; j < N; j++) dark += band(b, k)[j] < 0.01;
            double frac = (double)dark / N;
            CHECK_MSG(frac >= 2 / pi * asin(0.5) - 0.02 && frac <= 2 / pi * asin(0.85) + 0.02,
                      "%s %d Hz band %d: dark %.3f of the cycle", b->id, b->grid_hz, k, frac);
            /* symmetric about the voltage peak: no lag (no time constant) */
            double lag = lag_deg(band(b, k), N);
            CHECK_MSG(fmin(lag, 360 - lag) < 0.01, "%s: linear driver lag %.3f deg", b->id, lag);
        }
        tested++;
    }
    CHECK(tested >= 8);
    gs_delight_free(d);
}

/* ------------------------------------------------------------- per-channel */

/* Phosphor afterglow (BULBS.md [D]): blue fast (deepest, prompt), green Tb 2-5 ms smoothed and
 * lagged, red Eu 1-1.5 ms mildly. Green must lag blue by at most the Tb filter's own lag,
 * atan(2 pi 2f 5 ms) (72-75 deg); for triphosphor lamps (tri, electronic, CFL) red sits between. */
TEST(delight_model_fluorescent_green_lags_red_and_blue)
{
    gs_delight *d = generate(N);
    int tested = 0;
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        if (b->brf.bands != 3 || (b->type != GS_TECH_FLUORESCENT_MAGNETIC &&
                                  b->type != GS_TECH_FLUORESCENT_ELECTRONIC && b->type != GS_TECH_CFL))
            continue;
        double lr = lag_deg(band(b, 0), N), lg = lag_deg(band(b, 1), N), lb = lag_deg(band(b, 2), N);
        double tb_lag = atan(2 * pi * 2 * b->grid_hz * 5e-3) * 180 / pi;
        CHECK_MSG(lg > lb + 5 && lg - lb < tb_lag, "%s %d Hz: green lag %.1f vs blue %.1f", b->id,
                  b->grid_hz, lg, lb);
        CHECK_MSG(amp(band(b, 2), N, 1) > amp(band(b, 1), N, 1), "%s: blue must be deepest", b->id);
        if (!strstr(b->id, "-halo"))
            CHECK_MSG(lg > lr && lr > lb, "%s %d Hz: lags R %.1f G %.1f B %.1f, expected B < R < G",
                      b->id, b->grid_hz, lr, lg, lb);
        tested++;
    }
    CHECK(tested >= 22);
    gs_delight_free(d);
}

/* KSF red phosphor (tau ~8 ms [L/D]) smooths and lags red; without it R, G, B share one BRF. */
TEST(delight_model_led_ksf_red_lags)
{
    gs_delight *d = generate(N);
    int ksf = 0, plain = 0;
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        if (b->brf.bands != 3 || (b->type != GS_TECH_LED_CAPACITOR && b->type != GS_TECH_LED_LINEAR))
            continue;
        if (strstr(b->id, "ksf")) {
            CHECK_MSG(lag_deg(band(b, 0), N) > lag_deg(band(b, 1), N) + 3, "%s: red does not lag", b->id);
            CHECK(amp(band(b, 0), N, 1) < 0.9 * amp(band(b, 1), N, 1));
            ksf++;
        } else {
            double diff = 0;
            for (int j = 0; j < N; j++)
                diff = fmax(diff, fmax(fabs(band(b, 0)[j] - band(b, 1)[j]), fabs(band(b, 2)[j] - band(b, 1)[j])));
            CHECK_MSG(diff < 1e-9, "%s: bands differ by %g without a slow phosphor", b->id, diff);
            plain++;
        }
    }
    CHECK(ksf >= 2 && plain >= 4);
    gs_delight_free(d);
}

/* Capacitor ripple shapes: LED capacitor drivers 2nd/1st 0.2-0.3 [M], fast rise near the voltage
 * peak and slow decay [M]; CFL 2nd/1st ~0.24 [M] (taken as 0.18-0.30). */
TEST(delight_model_capacitor_ripple_shape)
{
    gs_delight *d = generate(N);
    int tested = 0;
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        if (b->brf.bands != 1 || (b->type != GS_TECH_LED_CAPACITOR && b->type != GS_TECH_CFL)) continue;
        double h21 = amp(b->brf.v, N, 2) / amp(b->brf.v, N, 1);
        double lo = b->type == GS_TECH_CFL ? 0.18 : 0.2, hi = 0.3;
        CHECK_MSG(h21 >= lo && h21 <= hi, "%s %d Hz: 2nd/1st %.3f, expected %.2f-%.2f", b->id,
                  b->grid_hz, h21, lo, hi);
        if (b->type == GS_TECH_LED_CAPACITOR) {
            int jmax = 0, jmin = 0;
            for (int j = 1; j < N; j++) {
                if (b->brf.v[j] > b->brf.v[jmax]) jmax = j;
                if (b->brf.v[j] < b->brf.v[jmin]) jmin = j;
            }
            double umax = (double)jmax / N, rise = fmod((double)(jmax - jmin) / N + 1.0, 1.0);
            CHECK_MSG(umax > 0.45 && umax < 0.7, "%s: peak at %.3f of the cycle, expected near the "
                      "voltage peak (0.5)", b->id, umax);
            CHECK_MSG(rise < 0.5, "%s: rise takes %.2f of the cycle, expected a fast rise", b->id, rise);
        }
        tested++;
    }
    CHECK(tested >= 18);
    gs_delight_free(d);
}

/* PWM: 100 % at 200 Hz-25 kHz but not mains-locked [M]; an AC-locked template is flat [D]. */
TEST(delight_model_led_pwm_is_flat_when_locked)
{
    gs_delight *d = generate(N);
    int tested = 0;
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        if (b->type != GS_TECH_LED_PWM) continue;
        for (int k = 0; k < b->brf.bands; k++)
            CHECK_MSG(gs_brf_percent_flicker(&b->brf, k) < 1.0, "%s: PF %.3f", b->id,
                      gs_brf_percent_flicker(&b->brf, k));
        CHECK(b->ref == GS_REF_VOLTAGE);
        tested++;
    }
    CHECK(tested >= 8);
    gs_delight_free(d);
}

/* Sodium: LPS is 589 nm only, so R and G see it and B ~ 0 (BULBS.md [L]), and every band has the
 * same shape; HPS is mostly R and G with weak B [L]. */
TEST(delight_model_sodium_colour)
{
    gs_delight *d = generate(N);
    int lps = 0, hps = 0;
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        if (b->brf.bands != 3) continue;
        if (b->type == GS_TECH_SODIUM_LP) {
            CHECK_MSG(b->chroma[2] < 0.02, "%s: blue chromaticity %.4f, expected ~0", b->id, b->chroma[2]);
            CHECK(b->chroma[0] > 0.2 && b->chroma[1] > 0.2);
            double diff = 0;
            for (int j = 0; j < N; j++) diff = fmax(diff, fabs(band(b, 0)[j] - band(b, 2)[j]));
            CHECK_MSG(diff < 1e-9, "%s: one spectral line, yet bands differ by %g", b->id, diff);
            lps++;
        } else if (b->type == GS_TECH_SODIUM_HP) {
            CHECK_MSG(b->chroma[2] < 0.05 && b->chroma[0] > b->chroma[1], "%s: chromaticity %.3f %.3f %.3f",
                      b->id, b->chroma[0], b->chroma[1], b->chroma[2]);
            hps++;
        }
    }
    CHECK(lps >= 4 && hps >= 4);
    gs_delight_free(d);
}

/* Metal halide: species respond differently, so per-channel shapes differ [D]; mercury: lines
 * prompt and deep, the coating's red phosphor smoothed and lagged [D]. */
TEST(delight_model_metal_halide_and_mercury_channels)
{
    gs_delight *d = generate(N);
    int mh = 0, coated = 0, clear = 0;
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        if (b->brf.bands != 3) continue;
        if (b->type == GS_TECH_METAL_HALIDE) {
            double diff = 0;
            for (int j = 0; j < N; j++) diff = fmax(diff, fabs(band(b, 0)[j] - band(b, 2)[j]));
            CHECK_MSG(diff > 0.05, "%s: R and B shapes differ by only %g", b->id, diff);
            mh++;
        } else if (b->type == GS_TECH_MERCURY && strstr(b->id, "-coated")) {
            CHECK_MSG(lag_deg(band(b, 0), N) > lag_deg(band(b, 2), N) + 5, "%s: red does not lag", b->id);
            CHECK(amp(band(b, 0), N, 1) < amp(band(b, 2), N, 1));
            coated++;
        } else if (b->type == GS_TECH_MERCURY) {
            CHECK_NEAR(lag_deg(band(b, 0), N), lag_deg(band(b, 2), N), 1e-6);
            CHECK(b->chroma[0] < 0.35);   /* clear mercury light is blue-green */
            clear++;
        }
    }
    CHECK(mh >= 4 && coated >= 2 && clear >= 2);
    gs_delight_free(d);
}

/* ------------------------------------------------------------- consistency */

/* The photodiode BRF is what a sensor with the summed sensitivity of the three bands sees:
 * sum_b Q_b B_b (Eq. 6), for every bulb at both grids. */
TEST(delight_model_mono_is_chroma_weighted_rgb)
{
    gs_delight *d = generate(N);
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *m = gs_delight_get(d, i);
        if (m->brf.bands != 1) continue;
        const gs_bulb *c = get(d, m->id, m->grid_hz, 3);
        if (!c) continue;
        CHECK_NEAR(c->chroma[0] + c->chroma[1] + c->chroma[2], 1.0, 1e-12);
        double err = 0;
        for (int j = 0; j < N; j++) {
            double s = c->chroma[0] * band(c, 0)[j] + c->chroma[1] * band(c, 1)[j] + c->chroma[2] * band(c, 2)[j];
            err = fmax(err, fabs(s - m->brf.v[j]));
        }
        CHECK_MSG(err < 1e-9, "%s %d Hz: mono differs from sum Q B by %g", m->id, m->grid_hz, err);
    }
    gs_delight_free(d);
}

/* The same bulbs at another resolution: the PF targets apply to the physical waveform, so the
 * templates at n = 4096 agree with n = 1024 (both resolve the waveform). */
TEST(delight_model_resolution_independent)
{
    gs_delight *a = generate(N), *b = generate(4096);
    CHECK(gs_delight_count(a) == gs_delight_count(b));
    FOR_BULBS(a, x) {
        const gs_bulb *y = get(b, x->id, 50, 1);
        if (!y) continue;
        double pa = gs_brf_percent_flicker(&x->brf, 0), pb = gs_brf_percent_flicker(&y->brf, 0);
        CHECK_MSG(fabs(pa - pb) <= 0.01 * pa + 0.01, "%s: PF %.3f at n=1024, %.3f at n=4096", x->id, pa, pb);
        CHECK_NEAR(lag_deg(x->brf.v, N), lag_deg(y->brf.v, 4096), 0.05);
    }
    gs_delight_free(a);
    gs_delight_free(b);
}
