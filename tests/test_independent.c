/* test_independent.c - recognition scored on captures of the second, independent forward model
 * (tests/independent/render.py: NumPy, written from the paper, sharing no code with capture/)
 * against its truth and against the exact maximum-likelihood oracle that knows that model
 * (tests/independent/score.py). A recogniser tuned on its own simulator fails these: the global
 * model error it had gave pair accuracy 8 points below the oracle in mono at 3,000 e-, a mean
 * confidence of 0.67 at 95 % accuracy at 40,000 e-, and median chi2/dof 0.16-0.00; the uniform
 * reddening prior left RGB under extinction 6 points below the oracle. 150 lights per capture:
 * the bounds allow the sampling noise of that many lights (docs/recognition.md has the 600-light
 * figures). */
#include "tests/fixtures.h"
#include "tests/test.h"

#include <jansson.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#define PY "/usr/bin/python3"   /* Debian's, with python3-numpy (.ci/deps.sh) */

typedef struct {
    double pair, oracle_pair, ece_pair, mean_conf, chi2_median, conf_wrong, answered;
    int matched, truth;
} indep_score;

static double num(json_t *o, const char *path)
{
    char key[64];
    snprintf(key, sizeof key, "%s", path);
    json_t *v = o;
    for (char *tok = strtok(key, "."); tok && v; tok = strtok(NULL, ".")) v = json_object_get(v, tok);
    return json_is_number(v) ? json_number_value(v) : NAN;
}

/* Renders a capture with render.py's options, scores the default `recognize` on it. */
static int render_and_score(const char *name, const char *render_opts, indep_score *sc)
{
    static char out[1 << 16];
    const char *csv = fx_tmp("delight.csv"), *cap = fx_tmp(name), *js = fx_tmp("score.json");
    char csvb[512], capb[512], jsb[512];
    snprintf(csvb, sizeof csvb, "%s", csv);
    snprintf(capb, sizeof capb, "%s", cap);
    snprintf(jsb, sizeof jsb, "%s", js);
    if (!fx_exists(csvb) && fx_run(out, sizeof out, "%s delight export -o %s", test_bin(), csvb) != 0) {
        CHECK_MSG(0, "delight export: %s", out);
        return 0;
    }
    int rc = fx_run(out, sizeof out, PY " tests/independent/render.py %s --delight-csv %s %s",
                    capb, csvb, render_opts);
    CHECK_MSG(rc == 0, "render.py %s: %s", render_opts, out);
    if (rc != 0) return 0;
    rc = fx_run(out, sizeof out, PY " tests/independent/score.py %s --delight-csv %s --bin %s --jobs 2 --json %s",
                capb, csvb, test_bin(), jsb);
    CHECK_MSG(rc == 0, "score.py: %s", out);
    if (rc != 0) return 0;
    json_error_t err;
    json_t *root = json_load_file(jsb, 0, &err);
    CHECK_MSG(root != NULL, "%s: %s", jsb, err.text);
    if (!root) return 0;
    sc->pair = num(root, "pair_acc");
    sc->oracle_pair = num(root, "oracle_matched.pair_acc");
    sc->ece_pair = num(root, "ece_pair");
    sc->mean_conf = num(root, "mean_conf");
    sc->chi2_median = num(root, "median_chi2_dof");
    sc->conf_wrong = num(root, "confident_wrong.any");
    sc->answered = num(root, "answered_share");
    sc->matched = (int)num(root, "matched");
    sc->truth = (int)num(root, "truth");
    json_decref(root);
    printf("    %s: pair %.3f (oracle %.3f), ECE %.3f, mean confidence %.3f, median chi2/dof %.2f, "
           "answered %.2f, confident wrong %.3f, matched %d/%d\n",
           name, sc->pair, sc->oracle_pair, sc->ece_pair, sc->mean_conf, sc->chi2_median,
           sc->answered, sc->conf_wrong, sc->matched, sc->truth);
    return 1;
}

/* The checks every capture passes: every light found, no NaN, at most one confident wrong
 * answer, the best guesses within `gap` of the oracle, the noise measured (chi2/dof near 1). */
static void check_common(const indep_score *s, double gap)
{
    CHECK(s->matched >= s->truth - 2);
    CHECK(isfinite(s->pair) && isfinite(s->oracle_pair) && isfinite(s->ece_pair) && isfinite(s->mean_conf));
    CHECK_MSG(s->pair >= s->oracle_pair - gap, "pair %.3f, oracle %.3f", s->pair, s->oracle_pair);
    CHECK_MSG(s->chi2_median > 0.8 && s->chi2_median < 1.25, "median chi2/dof %.3f", s->chi2_median);
    CHECK_MSG(s->conf_wrong * s->answered * s->matched <= 1.0 + 1e-9, "confident wrong %.3f of %.0f answered",
              s->conf_wrong, s->answered * s->matched);
}

TEST_TIMEOUT(independent_mono_k26_best_guesses_match_the_oracle, 600)
{
    indep_score s;
    if (!render_and_score("mono26", "--bands 1 -K 26 --grid-hz 50 --lights 150 --electrons 3000 --seed 5", &s))
        return;
    check_common(&s, 0.04);
    CHECK_MSG(s.ece_pair < 0.10, "ECE %.3f", s.ece_pair);
}

TEST_TIMEOUT(independent_mono_k13_60hz_confidence_calibrated_when_bright, 600)
{
    /* K not divisible by 3, 60 Hz, 40,000 e-: most lights are right; so must their confidence say */
    indep_score s;
    if (!render_and_score("mono13", "--bands 1 -K 13 --grid-hz 60 --lights 150 --electrons 40000 --seed 7", &s))
        return;
    check_common(&s, 0.03);
    CHECK_MSG(fabs(s.mean_conf - s.pair) < 0.06, "mean confidence %.3f, accuracy %.3f", s.mean_conf, s.pair);
    CHECK_MSG(s.ece_pair < 0.10, "ECE %.3f", s.ece_pair);
}

TEST_TIMEOUT(independent_rgb_reddened_keeps_chromaticity, 600)
{
    /* extinction 1 / 0.8 / 0.55 (R, G, B) on every light: the population prior on the optical
     * depth gives chromaticity back (the uniform prior: 6 points below the oracle) */
    indep_score s;
    if (!render_and_score("rgb26", "--bands 3 -K 26 --grid-hz 50 --lights 150 --electrons 10000 "
                                   "--extinction 1,0.8,0.55 --seed 6", &s))
        return;
    check_common(&s, 0.03);
    CHECK_MSG(s.ece_pair < 0.10, "ECE %.3f", s.ece_pair);
}
