/* test_bench_accuracy.c - `gridsurvey bench accuracy --quick` (survey/bench_accuracy.c): the
 * sweep runs and its numbers are consistent. No timing asserts. */
#include "tests/test.h"
#include "recognize/recognize.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct {
    char scene[32], phases[16];
    int K, C, hdr, locked;
    long acq;
    double exposure, readout, capture, compute;
    double rates[8];   /* detection, false, bulb, phase, right, unknown, pipeline subset, oracle */
    double snr, ece, phase_ece;
    long oracle_n, truth_lights, phase_answered;
    double cal_num[2], cal_den[2];   /* from calibration.csv: sum |right - confidence|, lights */
    double bin_lights[2], bin_right[2];   /* ... and the sums of its bins' lights and right ones */
} row;

static int file_size_ok(const char *path, const char *magic)
{
    FILE *f = fopen(path, "rb");
    if (!f) return 0;
    char b[8] = {0};
    size_t n = fread(b, 1, sizeof b, f);
    fclose(f);
    return n >= strlen(magic) && !memcmp(b, magic, strlen(magic));
}

static double num(const char *s)
{
    return strcmp(s, "nan") ? atof(s) : NAN;
}

TEST(bench_accuracy_quick_consistent)
{
    char out[2048], cmd[4096], log[8192];
    snprintf(out, sizeof out, "%s/acc", test_tmpdir());
    snprintf(cmd, sizeof cmd, "%s bench accuracy --quick --out-dir %s", test_bin(), out);
    int rc = test_run(cmd, log, sizeof log);
    CHECK_MSG(rc == 0, "%s -> %d:\n%s", cmd, rc, log);
    char path[2200];
    snprintf(path, sizeof path, "%s/accuracy_vs_time.png", out);
    CHECK_MSG(file_size_ok(path, "\x89PNG"), "%s: not a PNG", path);
    snprintf(path, sizeof path, "%s/calibration.png", out);
    CHECK_MSG(file_size_ok(path, "\x89PNG"), "%s: not a PNG", path);
    snprintf(path, sizeof path, "%s.md", out);
    CHECK_MSG(file_size_ok(path, "# What"), "%s: no report", path);
    snprintf(path, sizeof path, "%s/accuracy.csv", out);
    FILE *f = fopen(path, "r");
    CHECK_MSG(f != NULL, "%s: missing", path);
    if (!f) return;
    char line[4096];
    row rows[32];
    int n = 0;
    CHECK(fgets(line, sizeof line, f) && !strncmp(line, "scene,K,C,", 10));
    while (n < 32 && fgets(line, sizeof line, f)) {
        char *fld[32];
        int nf = 0;
        for (char *t = strtok(line, ",\n"); t && nf < 32; t = strtok(NULL, ",\n")) fld[nf++] = t;
        CHECK_MSG(nf == 29, "CSV row with %d fields", nf);
        if (nf != 29) continue;
        row *r = &rows[n++];
        snprintf(r->scene, sizeof r->scene, "%s", fld[0]);
        r->K = atoi(fld[1]);
        r->C = atoi(fld[2]);
        r->hdr = atoi(fld[3]);
        r->locked = atoi(fld[4]);
        snprintf(r->phases, sizeof r->phases, "%s", fld[5]);
        r->acq = atol(fld[6]);
        r->exposure = num(fld[7]);
        r->readout = num(fld[8]);
        r->capture = num(fld[9]);
        r->compute = num(fld[10]);
        int ri[8] = {14, 15, 16, 17, 18, 19, 25, 26};
        for (int k = 0; k < 8; k++) r->rates[k] = num(fld[ri[k]]);
        r->snr = num(fld[22]);
        r->ece = num(fld[23]);
        r->oracle_n = atol(fld[24]);
        r->phase_ece = num(fld[27]);
        r->phase_answered = atol(fld[28]);
        r->truth_lights = atol(fld[11]);
        r->bin_lights[0] = r->bin_lights[1] = r->bin_right[0] = r->bin_right[1] = 0;
        r->cal_num[0] = r->cal_num[1] = r->cal_den[0] = r->cal_den[1] = 0;
    }
    fclose(f);
    /* every point's reliability bins: in range, a stored phase only at or above the ambiguity
     * threshold, and the ECE columns recomputed from them */
    rec_eq7_opts eo;
    rec_eq7_opts_default(&eo);
    snprintf(path, sizeof path, "%s/calibration.csv", out);
    f = fopen(path, "r");
    CHECK_MSG(f != NULL, "%s: missing", path);
    if (!f) return;
    CHECK(fgets(line, sizeof line, f) &&
          !strcmp(line, "scene,K,C,hdr,locked,phases,confidence_of,bin_lo,bin_hi,matched_lights,mean_confidence,"
                        "right_lights\n"));
    int bins = 0;
    while (fgets(line, sizeof line, f)) {
        char *fld[16];
        int nf = 0;
        for (char *t = strtok(line, ",\n"); t && nf < 16; t = strtok(NULL, ",\n")) fld[nf++] = t;
        CHECK_MSG(nf == 12, "calibration row with %d fields", nf);
        if (nf != 12) continue;
        int phase = !strcmp(fld[6], "phase");
        double lo = num(fld[7]), hi = num(fld[8]), lights = num(fld[9]), mean = num(fld[10]), right = num(fld[11]);
        CHECK_MSG(lights >= 1 && right >= 0 && right <= lights && mean >= lo && mean <= hi,
                  "%s K=%s C=%s %s bin [%g, %g]: %g lights, mean %g, %g right", fld[0], fld[1], fld[2], fld[6], lo,
                  hi, lights, mean, right);
        if (phase) CHECK_MSG(lo >= eo.ambiguous_conf - 1e-9, "a stored phase in the bin [%g, %g)", lo, hi);
        bins++;
        for (int i = 0; i < n; i++) {
            row *r = &rows[i];
            if (strcmp(r->scene, fld[0]) || r->K != atoi(fld[1]) || r->C != atoi(fld[2]) || r->hdr != atoi(fld[3]) ||
                r->locked != atoi(fld[4]) || strcmp(r->phases, fld[5]))
                continue;
            r->cal_num[phase] += fabs(right - mean * lights);
            r->cal_den[phase] += lights;
            r->bin_lights[phase] += lights;
            r->bin_right[phase] += right;
        }
    }
    fclose(f);
    CHECK(bins >= n);
    for (int i = 0; i < n; i++) {
        row *r = &rows[i];
        double ece[2] = {r->ece, r->phase_ece};
        for (int k = 0; k < 2; k++)
            if (r->cal_den[k] > 0) CHECK_NEAR(ece[k], r->cal_num[k] / r->cal_den[k], 2e-4);
            else CHECK(isnan(ece[k]));
        /* the bins partition the answers the whole capture's evaluation scored (each bin is
         * scored on its own: its one-to-one matching may differ by a light): the phase bins
         * hold its phases and their right ones (phase accuracy x phases), the pair bins its
         * right bulb and phase (right/all x truth lights) */
        double tol = 1.0;   /* (a light: the quick points' sums are exact) */
        CHECK_MSG(fabs(r->bin_lights[1] - (double)r->phase_answered) <= tol &&
                      fabs(r->bin_right[1] - r->rates[3] * (double)r->phase_answered) <= tol &&
                      fabs(r->bin_right[0] - r->rates[4] * (double)r->truth_lights) <= tol,
                  "%s K=%d C=%d: phase bins %g lights, %g right (capture: %ld phases, %.0f right); pair bins "
                  "%g right (capture %.0f)", r->scene, r->K, r->C, r->bin_lights[1], r->bin_right[1],
                  r->phase_answered, r->rates[3] * (double)r->phase_answered, r->bin_right[0],
                  r->rates[4] * (double)r->truth_lights);
    }
    CHECK_MSG(n >= 4, "%d rows", n);
    const double delta = 0.01, readout_cycles = 10;   /* 50 Hz; the scene's readout_cycles */
    for (int i = 0; i < n; i++) {
        row *r = &rows[i];
        /* rates in [0, 1] (NaN: no denominator) */
        for (int k = 0; k < 8; k++)
            CHECK_MSG(isnan(r->rates[k]) || (r->rates[k] >= 0 && r->rates[k] <= 1), "%s C=%d: rate %d = %g",
                      r->scene, r->C, k, r->rates[k]);
        CHECK(isnan(r->ece) || (r->ece >= 0 && r->ece <= 1));
        CHECK(r->rates[0] > 0.5);   /* the window's lights are found */
        /* capture time: A (C + R) Delta exactly, A = K frames + HDR repeats */
        CHECK_MSG(r->acq >= r->K && (r->hdr || r->acq == r->K), "%s C=%d: %ld acquisitions for K = %d",
                  r->scene, r->C, r->acq, r->K);
        CHECK_NEAR(r->exposure, (double)r->acq * r->C * delta, 0.006);
        CHECK_NEAR(r->readout, (double)r->acq * readout_cycles * delta, 0.006);
        CHECK_NEAR(r->capture, r->exposure + r->readout, 0.011);
        CHECK_NEAR(r->capture, (double)r->acq * (r->C + readout_cycles) * delta, 0.006);
        CHECK(r->compute >= 0);
        /* the oracle is at least as good as the pipeline on the same lights (8 lights: a
         * tolerance of 2 lights) */
        if (r->oracle_n > 0)
            CHECK_MSG(r->rates[7] >= r->rates[6] - 2.0 / (double)r->oracle_n - 1e-9,
                      "%s C=%d: oracle %.3f, pipeline %.3f", r->scene, r->C, r->rates[7], r->rates[6]);
        /* more cycles never reduce the SNR (same scene and setting) */
        for (int j = 0; j < n; j++) {
            row *q = &rows[j];
            if (strcmp(q->scene, r->scene) || strcmp(q->phases, r->phases) || q->K != r->K || q->hdr != r->hdr ||
                q->locked != r->locked || q->C <= r->C)
                continue;
            CHECK_MSG(q->snr >= r->snr, "%s K=%d: SNR %.1f at C=%d, %.1f at C=%d", r->scene, r->K, r->snr, r->C,
                      q->snr, q->C);
        }
    }
}
