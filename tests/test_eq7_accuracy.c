/* test_eq7_accuracy.c - accuracy and calibration of Eq. 7 recognition (recognize/eq7.c) on
 * synthetic lights with the real noise of a camera: Poisson shot noise (known gain) on the light
 * and a subtracted sky background, plus Gaussian read noise.
 *
 * Oracle: the maximum-likelihood decision under the exact noise model (rec_ml_oracle,
 * recognize/ml_oracle.c, written without anything from eq7.c): for every (bulb, phase) the exact
 * Poisson-Gaussian likelihood
 *   p(x | mu) = sum_n Pois(n; g (mu + bg)) N(x + bg - n/g; 0, r^2),
 * the brightness profiled by golden-section search, the best pair kept. eq7.c instead assumes
 * Gaussian noise with the plug-in std sigma^2 = r^2 + max(x + bg, 0)/g that a blob extractor
 * reports. Both see the same lights (a paired comparison), so the difference of accuracies has a
 * small standard error: sqrt(discordant fraction / N).
 *
 * Calibration: lights reported at confidence c are right a fraction ~c of the time (expected
 * calibration error over confidence bins).
 * The table printed here is the one in docs/recognition.md; reproduce it with
 *   build/run_tests eq7_accuracy
 * (GS_SAN=1, set by `make test-asan`, uses fewer lights). */
#include "recognize/recognize.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* log n! for n < NFACT */
#define NFACT 200000
static double *lfact;

static void lfact_init(void)
{
    if (lfact) return;
    lfact = malloc(sizeof *lfact * NFACT);
    lfact[0] = 0.0;
    for (int n = 1; n < NFACT; n++) lfact[n] = lfact[n - 1] + log((double)n);
}

/* An exact Poisson sample: inversion, enumerating outcomes outwards from the mode. */
static long rng_poisson(uint64_t *s, double lam)
{
    if (lam <= 0.0) return 0;
    long mode = (long)floor(lam);
    double u = gs_splitmix_uniform(s);
    double pm = exp(-lam + mode * log(lam) - lfact[mode]);
    double up = pm, dn = pm;
    long hi = mode, lo = mode;
    u -= pm;
    if (u <= 0) return mode;
    for (;;) {
        /* next outcome above, then below */
        up *= lam / (double)(hi + 1);
        hi++;
        u -= up;
        if (u <= 0) return hi;
        if (lo > 0) {
            dn *= (double)lo / lam;
            lo--;
            u -= dn;
            if (u <= 0) return lo;
        }
        if (up < 1e-300 && (lo == 0 || dn < 1e-300)) return mode;   /* u within rounding of 1 */
    }
}

/* The camera: gain (electrons per DN), read noise (DN), sky background (electrons per sample,
 * subtracted from the data as a known level): rec_pg_noise, the same for every sample. */
typedef rec_pg_noise camera;

static void camera_init(camera *c, double gain, double read_dn, double bg_e)
{
    c->gain = gain;
    c->read_dn = read_dn;
    c->bg_e = bg_e;
}

/* log p(x | mean mu DN of the light) for one sample, exact (recognize/ml_oracle.c). */
static double log_pg(const camera *c, double x, double mu)
{
    return rec_pg_log_likelihood(c, x, mu);
}

/* The oracle: max over templates of the likelihood profiled over a > 0 (rec_ml_oracle). */
static int oracle_ml(const camera *c, const double *x, const double *tab, int M, int D)
{
    int best = -1;
    CHECK_OK(rec_ml_oracle(c, 0, NULL, x, tab, M, D, &best, NULL));
    return best;
}

TEST(eq7_accuracy_poisson_log_likelihood)
{
    /* the oracle's likelihood against a brute-force sum over every n, and normalisation */
    lfact_init();
    camera c;
    camera_init(&c, 1.5, 1.3, 4.0);
    double mus[] = {0.0, 0.3, 5.0, 80.0};
    for (int i = 0; i < 4; i++) {
        double mu = mus[i], lam = c.gain * mu + c.bg_e, integral = 0;
        for (double x = -30; x <= 200; x += 0.01) integral += exp(log_pg(&c, x, mu)) * 0.01;
        CHECK_NEAR(integral, 1.0, 1e-6);
        for (double x = -5; x < 120; x += 7.3) {
            double s = 0;
            for (int n = 0; n < 2000; n++) {
                double xe = x + c.bg_e / c.gain - n / c.gain;
                s += exp(-lam + n * log(lam) - lfact[n] - xe * xe / (2 * c.read_dn * c.read_dn)) /
                     (c.read_dn * sqrt(2 * M_PI));
            }
            CHECK_NEAR(log_pg(&c, x, mu), log(s), 1e-9);
        }
    }
    /* Poisson sampler: mean and variance */
    uint64_t rs = 5;
    double lams[] = {0.7, 12.0, 450.0};
    for (int i = 0; i < 3; i++) {
        double s = 0, s2 = 0;
        int n = 40000;
        for (int k = 0; k < n; k++) {
            double v = (double)rng_poisson(&rs, lams[i]);
            s += v;
            s2 += v * v;
        }
        double mean = s / n, var = s2 / n - mean * mean;
        CHECK_NEAR(mean, lams[i], 5 * sqrt(lams[i] / n));
        CHECK_NEAR(var, lams[i], 0.05 * lams[i]);
    }
}

/* The database of the test: one bulb of each mains-locked technology from the generated
 * DELIGHT, and two near-identical incandescents (bulb ambiguity). */
static const char *const accuracy_ids[] = {
    "inc-a60-60w-230v", "inc-a60-100w-230v", "hal-mr16-35w-12v", "fl-t8-36w-tri", "fle-t5-28w",
    "cfl-11w", "led-a19-8w-cap", "led-street-60w-lin3", "hps-150w", "mh-150w", "hg-125w-coated",
};
#define NACC (sizeof accuracy_ids / sizeof *accuracy_ids)

typedef struct {
    double mean_e;      /* mean electrons of the light per sample */
    int n;              /* lights */
    double acc_pair, acc_bulb, acc_phase;              /* eq7.c */
    double or_pair, or_bulb, or_phase;                 /* oracle */
    double ece, mean_conf;
    double disc;        /* fraction of lights where the two pair answers differ in correctness */
    double unknown;     /* fraction flagged UNKNOWN with the default options */
    double own_pair;    /* pair accuracy with sigma from each sample's own value */
} acc_row;

/* Run n lights at mean_e electrons per sample; fill the row and the calibration bins. */
#define NBINS 8
static const double bin_edges[NBINS + 1] = {0.0, 0.4, 0.55, 0.7, 0.8, 0.9, 0.97, 0.995, 1.0001};

static void run_level(const gs_delight *d, const camera *cam, double mean_e, int n, uint64_t seed,
                      acc_row *row, double *bin_n, double *bin_conf, double *bin_right)
{
    int K = 26, D = 78;
    rec_eq7_opts o;
    rec_eq7_opts_default(&o);
    o.min_snr = 0;      /* compare the estimators, not the flags */
    o.unknown_p = 0;
    o.band_gains = 0;   /* the oracle's model: one brightness times Q_beta, exact templates */
    o.model_error = 0.0;
    o.other_prior = 0.0;
    o.blend_prior = 0.0;
    rec_matcher *m = NULL, *mdef = NULL;
    CHECK_OK(rec_matcher_new(d, 50, 3, K, &o, &m));
    CHECK_OK(rec_matcher_new(d, 50, 3, K, NULL, &mdef));
    int nb = (int)rec_matcher_bulb_count(m), M = nb * 3;
    double *tab = malloc(sizeof *tab * (size_t)M * (size_t)D);
    for (int b = 0; b < nb; b++)
        for (int p = 0; p < 3; p++) {
            const gs_bulb *bu = rec_matcher_bulb(m, (size_t)b);
            double *t = tab + (size_t)(b * 3 + p) * (size_t)D;
            CHECK_OK(gs_brf_integrate(&bu->brf, gs_phase_to_shift(120.0 * p), K, t));
            for (int k = 0; k < D; k++) t[k] *= bu->chroma[k / K];
        }
    uint64_t rs = seed;
    int ok_pair = 0, ok_bulb = 0, ok_phase = 0, or_pair = 0, or_bulb = 0, or_phase = 0, disc = 0, unk = 0;
    double x[78], sg[78], sg_own[78], sum_conf = 0;
    int own_pair = 0;
    for (int i = 0; i < n; i++) {
        int b = (int)(gs_splitmix64(&rs) % (uint64_t)nb), p = (int)(gs_splitmix64(&rs) % 3);
        const double *t = tab + (size_t)(b * 3 + p) * (size_t)D;
        /* brightness: the mean sample (a / 3 in DN) holds mean_e electrons */
        double a = 3.0 * mean_e / cam->gain;
        for (int k = 0; k < D; k++) {
            double mu = a * t[k] > 0 ? a * t[k] : 0;
            long ne = rng_poisson(&rs, cam->gain * mu + cam->bg_e);
            x[k] = ((double)ne - cam->bg_e) / cam->gain + cam->read_dn * gs_splitmix_normal(&rs);
        }
        /* the noise std given to Eq. 7: shot noise of the band's mean level (a smoothed
         * estimate, docs/recognition.md) and, for comparison, of each sample's own value */
        for (int band = 0; band < 3; band++) {
            double mean = 0;
            for (int k = 0; k < K; k++) mean += x[band * K + k] / K;
            for (int k = 0; k < K; k++) {
                double lvl = mean + cam->bg_e / cam->gain, own = x[band * K + k] + cam->bg_e / cam->gain;
                sg[band * K + k] = sqrt(cam->read_dn * cam->read_dn + (lvl > 0 ? lvl / cam->gain : 0));
                sg_own[band * K + k] = sqrt(cam->read_dn * cam->read_dn + (own > 0 ? own / cam->gain : 0));
            }
        }
        rec_match r, rd, ro;
        CHECK_OK(rec_match_light(m, x, sg, &r));
        CHECK_OK(rec_match_light(mdef, x, sg, &rd));
        CHECK_OK(rec_match_light(m, x, sg_own, &ro));
        if (rd.flags & REC_MATCH_UNKNOWN) unk++;
        own_pair += ro.bulb == b && (int)lround(ro.phase_deg / 120.0) % 3 == p;
        int rb = r.bulb, rp = (int)lround(r.phase_deg / 120.0) % 3;
        CHECK(rb >= 0);
        int okb = rb == b, okp = rp == p;
        ok_bulb += okb;
        ok_phase += okp;
        ok_pair += okb && okp;
        int j = oracle_ml(cam, x, tab, M, D);
        int ob = j / 3 == b, op = j % 3 == p;
        or_bulb += ob;
        or_phase += op;
        or_pair += ob && op;
        disc += (okb && okp) != (ob && op);
        sum_conf += r.confidence;
        for (int k = 0; k < NBINS; k++)
            if (r.confidence >= bin_edges[k] && r.confidence < bin_edges[k + 1]) {
                bin_n[k] += 1;
                bin_conf[k] += r.confidence;
                bin_right[k] += okb && okp;
            }
    }
    row->mean_e = mean_e;
    row->n = n;
    row->acc_pair = (double)ok_pair / n;
    row->acc_bulb = (double)ok_bulb / n;
    row->acc_phase = (double)ok_phase / n;
    row->or_pair = (double)or_pair / n;
    row->or_bulb = (double)or_bulb / n;
    row->or_phase = (double)or_phase / n;
    row->disc = (double)disc / n;
    row->mean_conf = sum_conf / n;
    row->unknown = (double)unk / n;
    row->own_pair = (double)own_pair / n;
    free(tab);
    rec_matcher_free(m);
    rec_matcher_free(mdef);
}

static double ece_of(const double *bn, const double *bc, const double *br, double *worst, int min_n)
{
    double total = 0, e = 0;
    *worst = 0;
    for (int k = 0; k < NBINS; k++) total += bn[k];
    for (int k = 0; k < NBINS; k++) {
        if (bn[k] == 0) continue;
        double gap = fabs(br[k] / bn[k] - bc[k] / bn[k]);
        e += bn[k] / total * gap;
        /* a bin's gap beyond 3 binomial standard errors (and 3 points) */
        double c = bc[k] / bn[k], se = sqrt(c * (1 - c) / bn[k] + 1e-12);
        if (bn[k] >= min_n && gap - 3 * se > *worst) *worst = gap - 3 * se;
    }
    return e;
}

TEST(eq7_accuracy_vs_poisson_oracle)
{
    lfact_init();
    gs_delight *all = gs_delight_new(), *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(all, 1024));
    for (size_t i = 0; i < NACC; i++) {
        const gs_bulb *b = gs_delight_find(all, accuracy_ids[i], 50, 3);
        CHECK_MSG(b != NULL, "generated DELIGHT has no %s", accuracy_ids[i]);
        if (b) CHECK_OK(gs_delight_add(d, b));
    }
    gs_delight_free(all);
    camera cam;
    camera_init(&cam, 1.0, 2.0, 4.0);   /* 1 e-/DN, 2 e- read noise, 4 e- sky per sample */
    int san = fx_sanitized();
    int n = san ? 300 : 1600;
    double levels[] = {3, 10, 30, 100};
    int nl = sizeof levels / sizeof *levels;
    acc_row rows[4];
    double bn_all[NBINS] = {0}, bc_all[NBINS] = {0}, br_all[NBINS] = {0};
    printf("    Eq. 7 accuracy, %d lights per level, %zu bulbs x 3 phases, K = 26 RGB, gain 1 e-/DN, "
           "read 2 e-, sky 4 e-\n", n, NACC);
    printf("    %8s %8s | %6s %6s %6s | %6s %6s %6s | %6s %6s %6s | %6s | %6s\n", "e-/samp", "SNR/samp",
           "pair", "bulb", "phase", "O.pair", "O.bulb", "O.phas", "conf", "ECE", "disc", "unkn", "own.pr");
    for (int l = 0; l < nl; l++) {
        double bn[NBINS] = {0}, bc[NBINS] = {0}, br[NBINS] = {0};
        run_level(d, &cam, levels[l], n, 1000 + (uint64_t)l, &rows[l], bn, bc, br);
        double worst;
        rows[l].ece = ece_of(bn, bc, br, &worst, 50);
        for (int k = 0; k < NBINS; k++) {
            bn_all[k] += bn[k];
            bc_all[k] += bc[k];
            br_all[k] += br[k];
        }
        acc_row *r = &rows[l];
        double e = levels[l], snr = e / sqrt(e + cam.bg_e + cam.read_dn * cam.read_dn * cam.gain * cam.gain);
        printf("    %8.0f %8.2f | %6.3f %6.3f %6.3f | %6.3f %6.3f %6.3f | %6.3f %6.3f %6.3f | %6.4f | %6.3f\n", e,
               snr, r->acc_pair, r->acc_bulb, r->acc_phase, r->or_pair, r->or_bulb, r->or_phase, r->mean_conf,
               r->ece, r->disc, r->unknown, r->own_pair);
        /* within 1 percentage point of the oracle, or within 2.5 standard errors of the paired
         * difference when that is larger (small SAN runs) */
        double se = sqrt(r->disc / n + 1.0 / ((double)n * n));
        double tol = fmax(0.01, 2.5 * se);
        CHECK_MSG(r->acc_pair >= r->or_pair - tol, "level %g: pair accuracy %.4f, oracle %.4f", e,
                  r->acc_pair, r->or_pair);
        CHECK_MSG(r->acc_bulb >= r->or_bulb - fmax(0.01, tol), "level %g: bulb accuracy %.4f, oracle %.4f",
                  e, r->acc_bulb, r->or_bulb);
        CHECK_MSG(r->acc_phase >= r->or_phase - fmax(0.01, tol), "level %g: phase accuracy %.4f, oracle %.4f",
                  e, r->acc_phase, r->or_phase);
        /* calibration: expected calibration error and no badly calibrated bin */
        CHECK_MSG(r->ece < (san ? 0.06 : 0.03), "level %g: ECE %.4f", e, r->ece);
        CHECK_MSG(worst < 0.03, "level %g: a confidence bin is off by %.3f beyond 3 sigma", e, worst);
        CHECK_MSG(r->unknown < 0.01, "level %g: %.4f flagged unknown (expected ~1e-3)", e, r->unknown);
    }
    /* the levels span the interesting range: from mostly wrong to mostly right */
    CHECK(rows[0].acc_pair < 0.7 && rows[nl - 1].acc_pair > 0.9);
    double worst;
    double ece = ece_of(bn_all, bc_all, br_all, &worst, 100);
    printf("    calibration over all levels (ECE %.4f):\n    %12s %7s %9s %9s\n", ece, "confidence", "lights",
           "mean conf", "accuracy");
    for (int k = 0; k < NBINS; k++)
        if (bn_all[k] > 0)
            printf("    [%4.3f,%5.3f) %7.0f %9.3f %9.3f\n", bin_edges[k], bin_edges[k + 1] > 1 ? 1.0 : bin_edges[k + 1],
                   bn_all[k], bc_all[k] / bn_all[k], br_all[k] / bn_all[k]);
    CHECK_MSG(ece < (san ? 0.04 : 0.02), "overall ECE %.4f", ece);
    CHECK_MSG(worst < 0.02, "overall: a confidence bin is off by %.3f beyond 3 sigma", worst);
    gs_delight_free(d);
    free(lfact);
    lfact = NULL;
}
