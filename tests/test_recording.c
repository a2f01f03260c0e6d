/* test_recording.c - measured bulbs from photodiode recordings (paper Sec. 3, Fig. 2): the real
 * beautiful-flicker files reproduce their listed percent flicker; synthetic recordings with a
 * voltage column give the analytic BRF at the right phase, noise-free ones without it their
 * closed-form percent flicker at any frequency and sample rate; scope file variants (BOM,
 * metadata, a header running into the first sample, CRLF, a space in the name) parse
 * identically. */
#include "recognize/base/internal.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static void write_file(const char *path, const char *a, const char *b)
{
    FILE *f = fopen(path, "wb");
    CHECK(f != NULL);
    if (!f) return;
    fputs(a, f);
    if (b) fputs(b, f);
    fclose(f);
}

/* Percent flicker listed in shared/data/README.md (folding at ~120 Hz); Hue is PWM, ~100 %. */
static const struct {
    const char *file;
    double pf;
} listed[] = {
    {"Sylvania_60W.csv", 4.9},  {"Feit 60W.csv", 4.0},     {"CFL.csv", 8.9},
    {"GE_Align_PM.csv", 9.6},   {"Old_IKEA_LED.csv", 14.7}, {"Ecosmart_Candelabra_LED.csv", 29.6},
    {"Soraa_Healthy.csv", 35.7}, {"GE_Classic_LED.csv", 2.5}, {"IKEA_Lunnom.csv", 0.1},
    {"Hue_Color_Day.csv", 100.0},
};

TEST(recording_real_files_percent_flicker)
{
    for (size_t i = 0; i < sizeof listed / sizeof *listed; i++) {
        char rel[128];
        snprintf(rel, sizeof rel, "data/flicker/%s", listed[i].file);
        gs_bulb b;
        gs_recording_info info;
        gs_status s = gs_recording_to_bulb(test_shared_path(rel), 0, GS_BRF_N_DEFAULT, &b, &info);
        CHECK_MSG(s == GS_OK, "%s: %s: %s", listed[i].file, gs_strerror(s), gs_detail());
        if (s != GS_OK) continue;
        int pwm = strncmp(listed[i].file, "Hue", 3) == 0;
        printf("    %-28s listed %5.1f  imported %7.3f  flicker %8.2f Hz\n", listed[i].file,
               listed[i].pf, info.percent_flicker, info.flicker_hz);
        CHECK_MSG(fabs(info.percent_flicker - listed[i].pf) <= 1.0, "%s: percent flicker %.3f, listed %.1f",
                  listed[i].file, info.percent_flicker, listed[i].pf);
        CHECK_NEAR(gs_brf_percent_flicker(&b.brf, 0), info.percent_flicker, 1e-12);
        CHECK(info.samples == (pwm ? 2800u : 14000u));
        CHECK_NEAR(info.sample_rate_hz, pwm ? 1e6 : 5e5, 1e-3);
        CHECK_NEAR(info.flicker_hz, pwm ? 1000.0 : 120.0, pwm ? 10.0 : 2.0);
        CHECK(info.grid_hz == (pwm ? 0 : 60) && b.grid_hz == info.grid_hz);
        CHECK(b.ref == (pwm ? GS_REF_UNLOCKED : GS_REF_NONE));
        CHECK(b.brf.n == GS_BRF_N_DEFAULT && b.brf.bands == 1 && b.chroma[0] == 1.0);
        CHECK(b.type == GS_TECH_UNKNOWN && strcmp(b.sensor, "photodiode") == 0);
        if (pwm) b.grid_hz = 60;   /* the caller's to set when the recording cannot tell */
        CHECK_MSG(gs_bulb_validate(&b) == GS_OK, "%s: %s", listed[i].file, gs_detail());
        gs_bulb_release(&b);
    }
}

TEST(recording_id_and_name_from_file_name)
{
    gs_bulb b;
    CHECK_OK(gs_recording_to_bulb(test_shared_path("data/flicker/Feit 60W.csv"), 0, 256, &b, NULL));
    CHECK(strcmp(b.id, "Feit_60W") == 0 && strcmp(b.name, "Feit 60W") == 0);
    gs_bulb_release(&b);
}

/* Deterministic Gaussian noise (LCG + Box-Muller). */
static double noise(unsigned long long *state)
{
    double u[2];
    for (int k = 0; k < 2; k++) {
        *state = *state * 6364136223846793005ULL + 1442695040888963407ULL;
        u[k] = ((double)(*state >> 11) + 0.5) / 9007199254740992.0;
    }
    return sqrt(-2 * log(u[0])) * cos(2 * M_PI * u[1]);
}

/* The analytic test BRF at t cycles (mean 1). */
static double brf_at(double t)
{
    return 1.0 + 0.3 * cos(2 * M_PI * t) + 0.1 * sin(4 * M_PI * t + 0.7) + 0.05 * cos(6 * M_PI * t - 1.1);
}

/* A scope-like recording: mains at ac_hz with its rising zero crossing at t_zero, a lamp whose
 * BRF is delayed by shift cycles, time,value,voltage columns; duration_s at rate_hz. */
static void write_synthetic(const char *path, double ac_hz, double t_zero, double shift, double rate_hz,
                            double duration_s, double sigma)
{
    FILE *f = fopen(path, "w");
    CHECK(f != NULL);
    if (!f) return;
    unsigned long long st = 12345;
    size_t n = (size_t)(duration_s * rate_hz);
    double t_first = -0.5 * duration_s;
    for (size_t i = 0; i < n; i++) {
        double t = t_first + (double)i / rate_hz;
        double cyc = (t - t_zero) * 2 * ac_hz;   /* flicker cycles since time zero */
        double light = 0.4 * brf_at(cyc - shift) + sigma * noise(&st);
        double volt = 325 * sin(2 * M_PI * ac_hz * (t - t_zero)) + 0.5;
        fprintf(f, "%.9g,%.6g,%.6g\n", t, light, volt);
    }
    fclose(f);
}

/* max |recovered - analytic delayed by shift| over the n samples */
static double brf_error(const gs_brf *b, double shift)
{
    double e = 0;
    for (int j = 0; j < b->n; j++) e = fmax(e, fabs(b->v[j] - brf_at((double)j / b->n - shift)));
    return e;
}

TEST(recording_synthetic_voltage_brf_and_phase)
{
    static const struct {
        double ac_hz, t_zero, shift, rate_hz, sigma;
    } cases[] = {
        {50.0, 0.0031, 0.0, 50e3, 0.0},         /* noise-free, 50 Hz */
        {50.03, -0.0123, 2.0 / 3.0, 50e3, 0.004}, /* phase 120 deg: shift 2/3 cycle */
        {59.98, 0.0007, 1.0 / 3.0, 100e3, 0.004}, /* 60 Hz grid, phase 240 deg */
    };
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        const char *p = fx_tmp("synthetic.csv");
        write_synthetic(p, cases[i].ac_hz, cases[i].t_zero, cases[i].shift, cases[i].rate_hz, 0.3,
                        cases[i].sigma);
        gs_bulb b;
        gs_recording_info info;
        gs_status s = gs_recording_to_bulb(p, 3, 512, &b, &info);
        CHECK_MSG(s == GS_OK, "case %zu: %s", i, gs_detail());
        if (s != GS_OK) continue;
        int grid = cases[i].ac_hz < 55 ? 50 : 60;
        CHECK(b.ref == GS_REF_VOLTAGE && b.grid_hz == grid && info.grid_hz == grid);
        CHECK_NEAR(info.flicker_hz, 2 * cases[i].ac_hz, 1e-6 * cases[i].ac_hz);
        CHECK_NEAR(info.cycles, 0.3 * 2 * cases[i].ac_hz, 0.01);
        double err = brf_error(&b.brf, cases[i].shift);
        CHECK_MSG(err < (cases[i].sigma > 0 ? 3e-3 : 1e-4), "case %zu: max error %g", i, err);
        /* the phase is right: a shift of 1/3 cycle either way fits much worse */
        CHECK(brf_error(&b.brf, cases[i].shift + 1.0 / 3.0) > 0.2);
        CHECK(brf_error(&b.brf, cases[i].shift - 1.0 / 3.0) > 0.2);
        double pf_true = 0, lo = 1e9, hi = -1e9;
        for (int j = 0; j < 100000; j++) {
            double v = brf_at(j / 1e5);
            lo = fmin(lo, v);
            hi = fmax(hi, v);
        }
        pf_true = 100 * (hi - lo) / (hi + lo);
        CHECK_NEAR(info.percent_flicker, pf_true, 0.5);
        CHECK_OK(gs_bulb_validate(&b));
        gs_bulb_release(&b);
    }
}

TEST(recording_pwm_is_unlocked)
{
    const char *p = fx_tmp("pwm.csv");
    FILE *f = fopen(p, "w");
    CHECK(f != NULL);
    if (!f) return;
    for (int i = 0; i < 20000; i++) {   /* 1.03 kHz PWM, 30 % duty, 1 us steps, 20 ms */
        double ph = fmod(i * 1e-6 * 1030.0, 1.0);
        fprintf(f, "%.6f,%g\n", i * 1e-6, ph < 0.3 ? 0.9 : -0.012);
    }
    fclose(f);
    gs_bulb b;
    gs_recording_info info;
    CHECK_OK(gs_recording_to_bulb(p, 0, 1024, &b, &info));
    CHECK(b.ref == GS_REF_UNLOCKED && info.grid_hz == 0 && b.grid_hz == 0);
    CHECK_NEAR(info.flicker_hz, 1030.0, 1.0);
    CHECK_NEAR(info.percent_flicker, 100.0, 1e-9);
    gs_bulb_release(&b);
}

/* Analytic oracle: waveforms whose percent flicker and BRF are known in closed form, at flicker
 * frequencies locked (100, 120 Hz) and not (200 Hz-1 kHz), sampled at rates that divide the
 * period (100 kHz, 48 kHz: the samples sit at a few phases) and rates that do not (44.1 kHz,
 * 12,345 Hz), over 2.5 to 240 cycles, noise-free; the frequency within the search's stopping
 * tolerance, 1e-5 cycles over the recording (docs/delight.md). shape 0: 1 + m sin^2(pi phi),
 * PF m / (2 + m); shape 1: 1 + a cos(2 pi phi) + b cos(4 pi phi) with 4 b < a (extremes at
 * phi = 0, 1/2), PF a / (1 + b). */
static double oracle_at(int shape, double phi)
{
    return shape ? 1 + 0.6 * cos(2 * M_PI * phi) + 0.1 * cos(4 * M_PI * phi)
                 : 1 + 0.5 * pow(sin(M_PI * phi), 2);
}

TEST(recording_percent_flicker_analytic_oracle)
{
    static const struct {
        double flicker_hz, rate_hz, duration_s;
        int shape;
    } cases[] = {
        {100, 100e3, 0.2, 0},  {200, 100e3, 0.2, 0},  {500, 100e3, 0.2, 0},  {1000, 100e3, 0.2, 0},
        {120, 48e3, 0.1, 1},   {1000, 48e3, 0.05, 1}, {500, 44.1e3, 0.2, 1}, {137.3, 12345, 0.2, 0},
        {1030, 12345, 0.05, 1}, {120, 5000, 2.0, 1},   /* 240 cycles */
    };
    for (size_t c = 0; c < sizeof cases / sizeof *cases; c++) {
        const char *p = fx_tmp("oracle.csv");
        FILE *f = fopen(p, "w");
        CHECK(f != NULL);
        if (!f) return;
        size_t n = (size_t)(cases[c].duration_s * cases[c].rate_hz);
        for (size_t i = 0; i < n; i++) {
            double t = (double)i / cases[c].rate_hz;
            fprintf(f, "%.9g,%.12g\n", t, oracle_at(cases[c].shape, cases[c].flicker_hz * t));
        }
        fclose(f);
        gs_bulb b;
        gs_recording_info info;
        gs_status s = gs_recording_to_bulb(p, 0, 1024, &b, &info);
        CHECK_MSG(s == GS_OK, "case %zu: %s", c, gs_detail());
        if (s != GS_OK) continue;
        double pf = cases[c].shape ? 100 * 0.6 / 1.1 : 100 * 0.5 / 2.5;
        double mean = cases[c].shape ? 1.0 : 1.25;
        CHECK_MSG(fabs(info.flicker_hz - cases[c].flicker_hz) < 1e-6 * cases[c].flicker_hz,
                  "case %zu: flicker %.9g Hz", c, info.flicker_hz);
        double drift = fabs(info.flicker_hz - cases[c].flicker_hz) * cases[c].duration_s;
        CHECK_MSG(drift <= 1e-5, "case %zu: flicker off by %.3g cycles over the recording", c, drift);
        CHECK_MSG(fabs(info.percent_flicker - pf) < 0.05, "case %zu (%g Hz at %g Hz): percent flicker "
                  "%.4f, expected %.4f", c, cases[c].flicker_hz, cases[c].rate_hz, info.percent_flicker, pf);
        /* time zero is the first sample: the BRF is the waveform over its mean */
        double err = 0;
        for (int j = 0; j < 1024; j++)
            err = fmax(err, fabs(b.brf.v[j] - oracle_at(cases[c].shape, j / 1024.0) / mean));
        CHECK_MSG(err < 1e-3, "case %zu: BRF max error %g", c, err);
        int locked = cases[c].flicker_hz == 100 || cases[c].flicker_hz == 120;
        CHECK(b.ref == (locked ? GS_REF_NONE : GS_REF_UNLOCKED));
        gs_bulb_release(&b);
    }
}

TEST(recording_flat_lamp_has_no_frequency)
{
    const char *p = fx_tmp("dc.csv");
    FILE *f = fopen(p, "w");
    CHECK(f != NULL);
    if (!f) return;
    for (int i = 0; i < 5000; i++) fprintf(f, "%.6f,0.25\n", i * 1e-5);
    fclose(f);
    gs_bulb b;
    gs_recording_info info;
    CHECK_OK(gs_recording_to_bulb(p, 0, 64, &b, &info));
    CHECK(isnan(info.flicker_hz) && b.ref == GS_REF_NONE && info.grid_hz == 0);
    CHECK_NEAR(info.percent_flicker, 0.0, 1e-9);
    for (int j = 0; j < 64; j++) CHECK_NEAR(b.brf.v[j], 1.0, 1e-12);
    gs_bulb_release(&b);
}

/* The scope's metadata block (shared/data/flicker/info.csv), with CRLF line ends. */
#define SCOPE_META "\xEF\xBB\xBF" "Channel:Channel1,\r\nCapture Time:2019-03-07 17:51:24.841,\r\n" \
    "Length:14000000,\r\nSample Rate:500MSa/s,\r\nInterval:2ns,\r\nTime Base:2ms/div,\r\n"  \
    "Delay:0s,\r\nVertical Sensitivity:200mV/div,\r\nVertical Offset:-1.36V,\r\n"        \
    "ch1_time(s),ch1_value(V)"

static int same_result(const char *path, const gs_bulb *ref_b, const gs_recording_info *ref_i)
{
    gs_bulb b;
    gs_recording_info info;
    gs_status s = gs_recording_to_bulb(path, 0, 1024, &b, &info);
    CHECK_MSG(s == GS_OK, "%s: %s", path, gs_detail());
    if (s != GS_OK) return 0;
    int same = memcmp(b.brf.v, ref_b->brf.v, sizeof(double) * 1024) == 0 &&
               info.samples == ref_i->samples && info.flicker_hz == ref_i->flicker_hz &&
               info.percent_flicker == ref_i->percent_flicker && b.ref == ref_b->ref;
    gs_bulb_release(&b);
    return same;
}

TEST(recording_scope_variants_parse_identically)
{
    const char *plain = test_shared_path("data/flicker/CFL.csv");
    gs_bulb ref_b;
    gs_recording_info ref_i;
    CHECK_OK(gs_recording_to_bulb(plain, 0, 1024, &ref_b, &ref_i));
    char *data = fx_read_file(plain, NULL);
    CHECK(data != NULL);
    if (!data) return;
    /* BOM + metadata + header on its own line */
    const char *a = fx_tmp("meta.csv");
    write_file(a, SCOPE_META "\r\n", data);
    CHECK(same_result(a, &ref_b, &ref_i));
    /* ... with the header running straight into the first sample */
    const char *b = fx_tmp("runin.csv");
    write_file(b, SCOPE_META, data);
    CHECK(same_result(b, &ref_b, &ref_i));
    /* LF instead of CRLF, and a file name with a space */
    char *lf = malloc(strlen(data) + 1), *o = lf;
    for (const char *c = data; *c; c++)
        if (*c != '\r') *o++ = *c;
    *o = '\0';
    const char *c = fx_tmp("my CFL bulb.csv");
    write_file(c, lf, "\n");
    CHECK(same_result(c, &ref_b, &ref_i));
    gs_bulb named;
    CHECK_OK(gs_recording_to_bulb(c, 0, 64, &named, NULL));
    CHECK(strcmp(named.id, "my_CFL_bulb") == 0 && strcmp(named.name, "my CFL bulb") == 0);
    gs_bulb_release(&named);
    free(lf);
    free(data);
    gs_bulb_release(&ref_b);
}

TEST(recording_rejects_bad_input)
{
    gs_bulb b;
    char expect[700];
    /* a non-numeric value in the data */
    const char *p = fx_tmp("bad.csv");
    FILE *f = fopen(p, "w");
    CHECK(f != NULL);
    if (!f) return;
    fputs("Channel:Channel1,\n", f);
    for (int i = 0; i < 1000; i++) fprintf(f, "%.6f,%s\n", i * 1e-5, i == 500 ? "0.5V" : "0.5");
    fclose(f);
    CHECK(gs_recording_to_bulb(p, 0, 64, &b, NULL) == GS_EFORMAT);
    snprintf(expect, sizeof expect, "%s:502: field value (column 2): expected", p);
    CHECK_MSG(strncmp(gs_detail(), expect, strlen(expect)) == 0, "detail '%s'", gs_detail());
    /* a missing voltage column */
    f = fopen(p, "w");
    for (int i = 0; i < 1000; i++) fprintf(f, "%.6f,0.5\n", i * 1e-5);
    fclose(f);
    CHECK(gs_recording_to_bulb(p, 3, 64, &b, NULL) == GS_EFORMAT);
    CHECK(strstr(gs_detail(), p) && strstr(gs_detail(), "field voltage (column 3)"));
    CHECK(gs_recording_to_bulb(p, 2, 64, &b, NULL) == GS_EINVAL);
    CHECK(gs_recording_to_bulb(p, 0, 63, &b, NULL) == GS_EINVAL);
    /* non-uniform time, empty file, metadata only, missing file */
    f = fopen(p, "w");
    for (int i = 0; i < 1000; i++) fprintf(f, "%.6f,0.5\n", (i + (i > 600 ? 20 : 0)) * 1e-5);
    fclose(f);
    CHECK(gs_recording_to_bulb(p, 0, 64, &b, NULL) == GS_EFORMAT);
    CHECK(strstr(gs_detail(), p) && strstr(gs_detail(), "uniform"));
    write_file(p, "", NULL);
    CHECK(gs_recording_to_bulb(p, 0, 64, &b, NULL) == GS_EFORMAT);
    CHECK(strstr(gs_detail(), p) != NULL);
    CHECK(gs_recording_to_bulb(test_shared_path("data/flicker/info.csv"), 0, 64, &b, NULL) == GS_EFORMAT);
    CHECK(gs_recording_to_bulb(fx_tmp("missing.csv"), 0, 64, &b, NULL) == GS_ENOTFOUND);
    /* a voltage that is not mains */
    f = fopen(p, "w");
    for (int i = 0; i < 30000; i++)
        fprintf(f, "%.6f,%g,%g\n", i * 1e-5, 1 + 0.1 * cos(2 * M_PI * 100 * i * 1e-5),
                sin(2 * M_PI * 43 * i * 1e-5));
    fclose(f);
    CHECK(gs_recording_to_bulb(p, 3, 64, &b, NULL) == GS_EFORMAT);
    CHECK(strstr(gs_detail(), "field voltage") != NULL);
    /* values whose sums overflow: the mean is infinite, not "not positive" as it was told */
    f = fopen(p, "w");
    for (int i = 0; i < 1000; i++) fprintf(f, "%.6f,%s\n", i * 1e-5, i % 7 ? "1e308" : "0.5");
    fclose(f);
    CHECK(gs_recording_to_bulb(p, 0, 64, &b, NULL) == GS_ENUMERIC);
    CHECK_MSG(strstr(gs_detail(), p) && strstr(gs_detail(), "not a finite number"), "%s", gs_detail());
}
