/* test_evaluate.c - `gridsurvey evaluate` (survey/evaluate.c): a hand-made database checked
 * against answers worked out by hand, with positions placed by GeographicLib's GeodSolve (a
 * separate program) at known geodesic distances, and one-to-one nearest-first matching. */
#include "survey/survey.h"
#include "survey/internal.h"
#include "tests/fixtures.h"
#include "tests/survey_fixture.h"
#include "tests/test.h"

#include <jansson.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

static char out[1 << 17];
/* A printf-style shell command (tests/fixtures.h), its output in out. */
#define sh(...) fx_run(out, sizeof out, __VA_ARGS__)

/* GeodSolve (GeographicLib's own program): the point s12_m from (lat, lon) at azimuth azi. */
static int geod_direct(double lat, double lon, double azi, double s12, double *lat2, double *lon2)
{
    char cmd[256], res[256];
    snprintf(cmd, sizeof cmd, "echo %.12f %.12f %.12f %.12f | GeodSolve -p 9", lat, lon, azi, s12);
    if (test_run(cmd, res, sizeof res) != 0) return 0;
    return sscanf(res, "%lf %lf", lat2, lon2) == 2;
}

typedef struct {
    double x, y;
    const char *bulb, *tech;
    double phase;            /* NaN: ambiguous */
    int loc;                 /* 0: no location row, 1: unlocated row, 2: located */
    double lat, lon;
} hand_light;

/* A hand-made capture with known answers (worked out in the comments), evaluated by the API
 * and by the CLI (table and JSON). */
TEST(evaluate_hand_made_db_known_answers)
{
    if (sh("echo 0 0 0 1 | GeodSolve") != 0) {
        printf("    (GeodSolve not installed: geographiclib-tools)\n");
        CHECK(0);
        return;
    }
    char capdir[1024], truth[1024], db[1024];
    snprintf(capdir, sizeof capdir, "%s", fx_tmp("cap"));
    snprintf(truth, sizeof truth, "%s", fx_tmp("cap/truth.json"));
    snprintf(db, sizeof db, "%s", fx_tmp("ev.sqlite"));
    CHECK(mkdir(capdir, 0777) == 0);
    /* Truth: T0..T6; T5 is off the image. T6 sits 1.5 px from T0 (one-to-one, nearest first). */
    const double T[7][2] = {{100, 100}, {200, 100}, {300, 100}, {400, 100}, {500, 100}, {600, 100}, {101.5, 100}};
    const double Tlat[7] = {32.80, 32.81, 32.82, 32.83, 32.84, 32.85, 32.86}, Tlon = 35.0;
    char text[4096];
    snprintf(text, sizeof text,
             "{\"format\": \"gridsurvey-truth/1\", \"scene\": \"hand\", \"lights\": [\n"
             "{\"id\": \"T0\", \"x_px\": %g, \"y_px\": %g, \"in_image\": true, \"lat_deg\": %.2f, \"lon_deg\": 35.0, \"bulb\": \"bulbA\", \"technology\": \"incandescent\", \"phase_deg\": 0.0},\n"
             "{\"id\": \"T1\", \"x_px\": %g, \"y_px\": %g, \"in_image\": true, \"lat_deg\": %.2f, \"lon_deg\": 35.0, \"bulb\": \"bulbB\", \"technology\": \"cfl\", \"phase_deg\": 120.0, \"blend_group\": 0},\n"
             "{\"id\": \"T2\", \"x_px\": %g, \"y_px\": %g, \"in_image\": true, \"lat_deg\": %.2f, \"lon_deg\": 35.0, \"bulb\": \"bulbC\", \"technology\": \"sodium_hp\", \"phase_deg\": 240.0},\n"
             "{\"id\": \"T3\", \"x_px\": %g, \"y_px\": %g, \"in_image\": true, \"lat_deg\": %.2f, \"lon_deg\": 35.0, \"bulb\": \"bulbC\", \"technology\": \"sodium_hp\", \"phase_deg\": 30.0},\n"
             "{\"id\": \"T4\", \"x_px\": %g, \"y_px\": %g, \"in_image\": true, \"bulb\": \"bulbA\", \"technology\": \"incandescent\", \"phase_deg\": 0.0},\n"
             "{\"id\": \"T5\", \"x_px\": %g, \"y_px\": %g, \"in_image\": false, \"bulb\": \"bulbA\", \"technology\": \"incandescent\", \"phase_deg\": 0.0},\n"
             "{\"id\": \"T6\", \"x_px\": %g, \"y_px\": %g, \"in_image\": true, \"lat_deg\": %.2f, \"lon_deg\": 35.0, \"bulb\": \"bulbB\", \"technology\": \"cfl\", \"phase_deg\": 240.0}\n"
             "]}\n",
             T[0][0], T[0][1], Tlat[0], T[1][0], T[1][1], Tlat[1], T[2][0], T[2][1], Tlat[2], T[3][0], T[3][1],
             Tlat[3], T[4][0], T[4][1], T[5][0], T[5][1], T[6][0], T[6][1], Tlat[6]);
    fx_write_text(truth, text);
    /* Stored: S0 -> T0 (0.54 px; T6 is 1.01 px away but S1 takes it at 0.4 px), right bulb, phase
     * 350 vs 0 (10 deg: right), located 3 m from T0. S1 -> T6: right bulb, phase 215 vs 240
     * (25 deg: wrong, class "other"), located 10 m away. S2 -> T1 (1.41 px): wrong bulb of the
     * right technology, phase 125 (right), located 20 m away. S3: 2.5 px from T2 (matched only
     * with R = 3: right bulb and phase, unlocated row). S4 -> T3: right bulb, ambiguous phase, no
     * location row. S5: nothing near. S6: next to T5, which is off the image. */
    hand_light S[7] = {
        {100.5, 100.2, "bulbA", "incandescent", 350.0, 2, 0, 0},
        {101.9, 100.0, "bulbB", "cfl", 215.0, 2, 0, 0},
        {201.0, 101.0, "bulbX", "cfl", 125.0, 2, 0, 0},
        {300.0, 102.5, "bulbC", "sodium_hp", 240.0, 1, NAN, NAN},
        {400.3, 99.8, "bulbC", "sodium_hp", NAN, 0, NAN, NAN},
        {700.0, 700.0, NULL, NULL, NAN, 1, NAN, NAN},
        {599.5, 100.0, "bulbA", "incandescent", 0.0, 1, NAN, NAN},
    };
    CHECK(geod_direct(Tlat[0], Tlon, 90.0, 3.0, &S[0].lat, &S[0].lon));
    CHECK(geod_direct(Tlat[6], Tlon, 0.0, 10.0, &S[1].lat, &S[1].lon));
    CHECK(geod_direct(Tlat[1], Tlon, 45.0, 20.0, &S[2].lat, &S[2].lon));
    int64_t sid = 0, sid2 = 0, cid = 0;
    srv_db *h = survey_fx_create(db, "hand", &sid);
    if (!h) return;
    srv_light_row L[7];
    srv_location_row loc[7];
    for (int i = 0; i < 7; i++) {
        L[i] = survey_fx_light(i, S[i].x, S[i].y, S[i].phase, 0.9);
        L[i].bulb_id = S[i].bulb;
        L[i].technology = S[i].tech;
        L[i].match_flags = i == 2 ? REC_MATCH_BULB_AMBIGUOUS : 0;
        L[i].blob_flags = i == 1 || i == 2 ? REC_BLOB_PSF_FIT : 0;
        srv_location_row_init(&loc[i]);
        loc[i].method = S[i].loc ? SRV_LOC_ONE_STATION : SRV_LOC_NONE;
        if (S[i].loc == 2) {
            loc[i].lat_deg = S[i].lat;
            loc[i].lon_deg = S[i].lon;
            loc[i].height_m = 10.0;
            /* S0: 3 m along a 2 m major axis (east): d2 = 2.25, inside the 95 % ellipse; S1:
             * 10 m north across a 3 m minor axis (major east): d2 = 11.1, outside (with east
             * and north swapped it would be 4, inside); S2: 20 m at 45 deg along a 12 m major
             * axis at 45 deg: d2 = 2.78, inside */
            static const gis_ellipse E[3] = {{2.0, 1.0, 90.0}, {5.0, 3.0, 90.0}, {12.0, 2.0, 45.0}};
            loc[i].ellipse = E[i];
        } else if (S[i].loc == 1) {
            loc[i].flags = GIS_FIX_ABOVE_HORIZON;
        }
    }
    char abs_dir[4096];
    CHECK(realpath(capdir, abs_dir) != NULL);
    srv_capture_data cd = survey_fx_capture(sid, "hand-1", L, loc, 7);
    cd.capture.path = abs_dir;
    cd.capture.grid_hz = 50;
    CHECK_OK(srv_db_add_capture(h, &cd, &cid, NULL));
    /* a second survey with another capture elsewhere: not the one the truth describes */
    srv_survey_row sv2 = {.name = "other", .grid_hz = 50};
    CHECK_OK(srv_db_add_survey(h, &sv2, &sid2));
    srv_capture_row_init(&cd.capture);
    cd.capture.survey_id = sid2;
    cd.capture.key = "other-1";
    cd.capture.path = "/nowhere";
    cd.capture.grid_hz = 50;
    cd.locations = NULL;
    cd.n_lights = 2;
    CHECK_OK(srv_db_add_capture(h, &cd, NULL, NULL));

    srv_eval_opts o;
    srv_eval_opts_default(&o);
    CHECK(o.match_px == 2.0);
    srv_eval_report r;
    CHECK_OK(srv_evaluate(h, truth, &o, &r));
    CHECK(!strcmp(r.survey, "hand") && !strcmp(r.capture_key, "hand-1") && r.capture_id == cid);
    CHECK(r.truth_lights == 7 && r.truth_in_image == 6 && r.stored == 7);
    CHECK(r.matched == 4 && r.false_detections == 3);   /* S0, S1, S2, S4; false S3, S5, S6 */
    CHECK_NEAR(r.detection_rate, 4.0 / 6.0, 1e-15);
    CHECK_NEAR(r.false_rate, 3.0 / 7.0, 1e-15);
    CHECK(r.bulb_answered == 4 && r.bulb_correct == 3 && r.bulb_ambiguous == 1);
    CHECK(r.tech_answered == 4 && r.tech_correct == 4);
    CHECK(r.phase_answered == 3 && r.phase_correct == 2);
    CHECK_NEAR(r.phase_accuracy, 2.0 / 3.0, 1e-15);
    CHECK_NEAR(r.bulb_unknown_rate, 0.0, 0.0);
    CHECK_NEAR(r.phase_unknown_rate, 0.25, 1e-15);
    CHECK(r.all_correct == 1);   /* S0 only */
    CHECK_NEAR(r.all_correct_rate, 1.0 / 6.0, 1e-15);
    CHECK(r.confusion[0][0] == 1 && r.confusion[2][3] == 1 && r.confusion[1][1] == 1 && r.confusion[3][4] == 1);
    long total = 0;
    for (int t = 0; t < 4; t++)
        for (int c = 0; c < SRV_EVAL_PHASE_CLASSES; c++) total += r.confusion[t][c];
    CHECK(total == 4);
    /* location errors 3, 10, 20 m: median 10, 95th percentile 10 + 0.9 * 10 = 19 (position
     * 0.95 * 2 = 1.9), max 20; S4 has no location */
    CHECK(r.loc_pairs == 3 && r.loc_unlocated == 1);
    CHECK_NEAR(r.loc_median_m, 10.0, 1e-6);
    CHECK_NEAR(r.loc_p95_m, 19.0, 1e-6);
    CHECK_NEAR(r.loc_max_m, 20.0, 1e-6);
    CHECK(r.ellipse_pairs == 3 && r.ellipse_in95 == 2);
    CHECK_NEAR(r.ellipse_coverage95, 2.0 / 3.0, 1e-15);
    /* by class: S0 plain (inside), S1 of the PSF fit (outside), S2 of the PSF fit but its T1 in
     * a blend group (inside) */
    CHECK(r.ellipse_class_pairs[SRV_ELLIPSE_PLAIN] == 1 && r.ellipse_class_in95[SRV_ELLIPSE_PLAIN] == 1);
    CHECK(r.ellipse_class_pairs[SRV_ELLIPSE_PSF_FIT] == 1 && r.ellipse_class_in95[SRV_ELLIPSE_PSF_FIT] == 0);
    CHECK(r.ellipse_class_pairs[SRV_ELLIPSE_BLEND_GROUP] == 1 && r.ellipse_class_in95[SRV_ELLIPSE_BLEND_GROUP] == 1);
    /* R = 3 takes in S3 -> T2: right bulb and phase; its location row is unlocated */
    o.match_px = 3.0;
    CHECK_OK(srv_evaluate(h, truth, &o, &r));
    CHECK(r.matched == 5 && r.false_detections == 2 && r.bulb_correct == 4 && r.phase_correct == 3);
    CHECK(r.phase_answered == 4 && r.all_correct == 2 && r.loc_unlocated == 2 && r.loc_pairs == 3);
    /* an explicit capture key or survey chooses the same capture */
    o.match_px = 2.0;
    o.survey = "hand";
    CHECK_OK(srv_evaluate(h, truth, &o, &r));
    CHECK(r.matched == 4);
    o.survey = NULL;
    o.capture_key = "other-1";
    CHECK_OK(srv_evaluate(h, truth, &o, &r));
    CHECK(r.stored == 2 && !strcmp(r.survey, "other"));
    /* errors: a key that is not there (not a fallback to the truth's directory), a survey */
    o.capture_key = "nope-1";
    CHECK(srv_evaluate(h, truth, &o, &r) == GS_ENOTFOUND && strstr(gs_detail(), "nope-1"));
    o.capture_key = NULL;
    o.survey = "nope";
    CHECK(srv_evaluate(h, truth, &o, &r) == GS_ENOTFOUND);
    o.survey = NULL;
    o.match_px = 0.0;
    CHECK(srv_evaluate(h, truth, &o, &r) == GS_EINVAL);
    srv_db_close(h);

    /* the CLI: the same numbers as a table and as JSON */
    int rc = sh("%s evaluate --db %s --truth %s", test_bin(), db, truth);
    CHECK_MSG(rc == 0, "%d: %s", rc, out);
    CHECK(strstr(out, "| detection rate | 66.7 % | 4 / 6 truth lights in the image |") != NULL);
    CHECK(strstr(out, "| false detections | 42.9 % | 3 / 7 stored lights |") != NULL);
    CHECK(strstr(out, "| bulb accuracy | 75.0 % | 3 / 4 ") != NULL);
    CHECK(strstr(out, "| phase accuracy | 66.7 % | 2 / 3 ") != NULL);
    CHECK(strstr(out, "| location error, median | 10.00 m |") != NULL);
    CHECK(strstr(out, "| location error, 95th percentile | 19.00 m |") != NULL);
    CHECK(strstr(out, "| 95 % ellipse coverage | 66.7 % | 2 of 3 truth lights") != NULL);
    CHECK(strstr(out, "| 95 % ellipse coverage, plain lights (no blob flag) | 100.0 % | 1 of 1 |") != NULL);
    CHECK(strstr(out, "| 95 % ellipse coverage, PSF-fit lights outside blend groups | 0.0 % | 0 of 1 |") != NULL);
    CHECK(strstr(out, "| 95 % ellipse coverage, lights in blend groups | 100.0 % | 1 of 1 |") != NULL);
    CHECK(strstr(out, "| 240 | 0 | 0 | 0 | 1 | 0 |") != NULL);
    rc = sh("%s evaluate --db %s --truth %s --match-px 3 --format json", test_bin(), db, truth);
    json_error_t err;
    json_t *j = json_loads(out, 0, &err);
    CHECK_MSG(rc == 0 && j, "%d: %s", rc, out);
    CHECK(!strcmp(json_string_value(json_object_get(j, "format")), "gridsurvey-evaluation/1"));
    CHECK(json_integer_value(json_object_get(j, "matched")) == 5);
    CHECK_NEAR(json_number_value(json_object_get(json_object_get(j, "detection"), "rate")), 5.0 / 6.0, 1e-9);
    CHECK_NEAR(json_number_value(json_object_get(json_object_get(j, "location_error"), "p95_m")), 19.0, 1e-6);
    json_t *byc = json_object_get(json_object_get(j, "location_error"), "ellipse95_by_class");
    CHECK(json_integer_value(json_object_get(json_object_get(byc, "psf_fit"), "of")) == 1 &&
          json_integer_value(json_object_get(json_object_get(byc, "psf_fit"), "count")) == 0 &&
          json_integer_value(json_object_get(json_object_get(byc, "blend_group"), "count")) == 1);
    CHECK(json_integer_value(json_object_get(json_object_get(json_object_get(j, "phase_confusion"), "other"),
                                             "none")) == 1);
    json_decref(j);
    /* CLI errors: one line, exit 1 (failures) or 2 (usage) */
    fx_write_text(fx_tmp("bad-truth.json"), "{\"format\": \"gridsurvey-scene/1\", \"lights\": []}\n");
    CHECK(sh("%s evaluate --db %s --truth %s", test_bin(), db, fx_tmp("bad-truth.json")) == 1 &&
          fx_count_lines(out) == 1 && strstr(out, "gridsurvey-truth/1"));
    fx_write_text(fx_tmp("bad-truth2.json"), "{\"format\": \"gridsurvey-truth/1\", \"lights\": [{\"x_px\": 1}]}\n");
    CHECK(sh("%s evaluate --db %s --truth %s", test_bin(), db, fx_tmp("bad-truth2.json")) == 1 &&
          fx_count_lines(out) == 1 && strstr(out, "lights[0].in_image"));
    CHECK(sh("%s evaluate --db %s --truth %s", test_bin(), db, fx_tmp("none.json")) == 1 && fx_count_lines(out) == 1);
    CHECK(sh("%s evaluate --db %s --truth %s", test_bin(), fx_tmp("bad-truth.json"), truth) == 1 &&
          strstr(out, "not a survey database"));
    CHECK(sh("%s evaluate --db %s --truth %s --match-px -1", test_bin(), db, truth) == 2 && fx_count_lines(out) == 1);
    CHECK(sh("%s evaluate --db %s", test_bin(), db) == 2 && fx_count_lines(out) == 1);
    /* a truth elsewhere and two captures to choose from: refused, naming them */
    CHECK(mkdir(fx_tmp("elsewhere"), 0777) == 0);
    CHECK(sh("cp %s %s/", truth, fx_tmp("elsewhere")) == 0);
    CHECK(sh("%s evaluate --db %s --truth %s/truth.json", test_bin(), db, fx_tmp("elsewhere")) == 1 &&
          fx_count_lines(out) == 1 && strstr(out, "hand/hand-1") && strstr(out, "--survey"));
    CHECK(sh("%s evaluate --db %s --truth %s/truth.json --survey hand", test_bin(), db, fx_tmp("elsewhere")) == 0);
}

/* Matching is one-to-one and nearest first, whatever the order of the rows: a crowded cluster
 * (every stored light within R of every truth light) matches all of them once, and the pair
 * taken first is the closest. */
TEST(evaluate_matching_one_to_one_nearest_first)
{
    const char *capdir = fx_tmp("c"), *truth = fx_tmp("c/truth.json"), *db = fx_tmp("m.sqlite");
    CHECK(mkdir(capdir, 0777) == 0);
    fx_write_text(truth,
               "{\"format\": \"gridsurvey-truth/1\", \"lights\": [\n"
               "{\"x_px\": 10.0, \"y_px\": 10.0, \"in_image\": true, \"bulb\": \"a\", \"technology\": \"cfl\", \"phase_deg\": 0},\n"
               "{\"x_px\": 10.8, \"y_px\": 10.0, \"in_image\": true, \"bulb\": \"b\", \"technology\": \"cfl\", \"phase_deg\": 120},\n"
               "{\"x_px\": 11.6, \"y_px\": 10.0, \"in_image\": true, \"bulb\": \"c\", \"technology\": \"cfl\", \"phase_deg\": 240}]}\n");
    /* stored in reverse order; each 0.1 px right of its truth light */
    const double xs[3] = {11.7, 10.9, 10.1};
    const char *bulbs[3] = {"c", "b", "a"};
    const double ph[3] = {240, 120, 0};
    srv_db *h = NULL;
    CHECK_OK(srv_db_open(db, SRV_DB_CREATE, &h));
    if (!h) return;
    int64_t sid;
    srv_survey_row sv = {.name = "m"};
    CHECK_OK(srv_db_add_survey(h, &sv, &sid));
    srv_light_row L[3];
    for (int i = 0; i < 3; i++) {
        L[i] = survey_fx_light(i, xs[i], 10.0, ph[i], 1.0);
        L[i].bulb_id = bulbs[i];
        L[i].technology = "cfl";
    }
    srv_capture_data cd = survey_fx_capture(sid, "k", L, NULL, 3);
    CHECK_OK(srv_db_add_capture(h, &cd, NULL, NULL));
    srv_eval_opts o;
    srv_eval_opts_default(&o);
    o.match_px = 5.0;
    srv_eval_report r;
    CHECK_OK(srv_evaluate(h, truth, &o, &r));
    CHECK(r.matched == 3 && r.bulb_correct == 3 && r.phase_correct == 3 && r.false_detections == 0);
    srv_db_close(h);
}

/* Resolvability (docs/formats.md): the outcome of each blend group by the rules of survey.h,
 * five groups, one per outcome, hand-counted; a hidden light and two resolvable ones. */
TEST(evaluate_blend_groups_outcomes)
{
    const char *capdir = fx_tmp("g"), *truth = fx_tmp("g/truth.json"), *db = fx_tmp("g.sqlite");
    CHECK(mkdir(capdir, 0777) == 0);
    /* groups 0 resolved, 1 flagged, 2 confident single (one signal), 3 unsure, 4 missed, 5
     * confident single of two phases; at x = 10, 30, ... */
    char text[8192];
    size_t n = (size_t)snprintf(text, sizeof text, "{\"format\": \"gridsurvey-truth/1\", \"lights\": [\n");
    for (int g = 0; g < 6; g++)
        for (int m = 0; m < 2; m++)
            n += (size_t)snprintf(text + n, sizeof text - n,
                                  "{\"x_px\": %d.%d, \"y_px\": 10, \"in_image\": true, \"bulb\": \"a\", "
                                  "\"phase_deg\": %d, \"resolvable\": false, \"blend_group\": %d},\n",
                                  10 + 20 * g, 8 * m, g == 5 && m ? 120 : 0, g);
    n += (size_t)snprintf(text + n, sizeof text - n,
                          "{\"x_px\": 10, \"y_px\": 40, \"in_image\": true, \"bulb\": \"a\", \"phase_deg\": 0},\n"
                          "{\"x_px\": 30, \"y_px\": 40, \"in_image\": true, \"bulb\": \"a\", \"phase_deg\": 0, "
                          "\"resolvable\": true, \"blend_group\": null},\n"
                          "{\"x_px\": 31, \"y_px\": 40, \"in_image\": true, \"bulb\": \"a\", \"phase_deg\": 0, "
                          "\"resolvable\": false, \"blend_group\": null}]}\n");
    fx_write_text(truth, text);
    srv_db *h = NULL;
    CHECK_OK(srv_db_open(db, SRV_DB_CREATE, &h));
    if (!h) return;
    int64_t sid;
    srv_survey_row sv = {.name = "g"};
    CHECK_OK(srv_db_add_survey(h, &sv, &sid));
    /* group 0: both; 1: one, blend; 2: one, a bulb; 3: one, no bulb; the first resolvable one;
     * group 5: one, a bulb */
    const double xs[7] = {10.0, 10.8, 30.0, 50.0, 70.0, 10.0, 110.0}, ys[7] = {10, 10, 10, 10, 10, 40, 10};
    const unsigned fl[7] = {0, 0, REC_MATCH_BLEND, 0, 0, 0, 0};
    const char *bulb[7] = {"a", "a", "a", "a", NULL, "a", "a"};
    srv_light_row L[7];
    for (int i = 0; i < 7; i++) {
        L[i] = survey_fx_light(i, xs[i], ys[i], 0, 1.0);
        L[i].bulb_id = bulb[i];
        L[i].match_flags = fl[i];
    }
    srv_capture_data cd = survey_fx_capture(sid, "k", L, NULL, 7);
    CHECK_OK(srv_db_add_capture(h, &cd, NULL, NULL));
    srv_eval_report r;
    CHECK_OK(srv_evaluate(h, truth, NULL, &r));
    CHECK(r.groups == 6 && r.group_lights == 12);
    CHECK(r.groups_resolved == 1 && r.groups_flagged == 1 && r.groups_confident == 2 &&
          r.groups_one_signal == 1 && r.groups_unsure == 1 && r.groups_missed == 1);
    CHECK(r.resolvable == 2 && r.resolvable_matched == 1 && r.hidden == 1 && r.hidden_matched == 0);
    CHECK_NEAR(r.resolvable_rate, 0.5, 1e-12);
    /* a blend group that is not an integer: one line naming the light */
    fx_write_text(truth, "{\"format\": \"gridsurvey-truth/1\", \"lights\": [{\"x_px\": 1, \"y_px\": 1, "
                         "\"in_image\": true, \"bulb\": \"a\", \"blend_group\": 0.5}]}\n");
    CHECK(srv_evaluate(h, truth, NULL, &r) == GS_EFORMAT && strstr(gs_detail(), "lights[0]"));
    srv_db_close(h);
}

/* A share that is not all never reads 100.0 %, one that is not none never 0.0 %: one decimal,
 * or as many more as it takes (the demo's 5211 of 5213 technologies once read 100.0 %). */
TEST(evaluate_shares_near_all_or_none_not_rounded_to_it)
{
    srv_eval_report r;
    memset(&r, 0, sizeof r);
    r.truth_in_image = r.matched = r.stored = 100000;
    r.false_detections = 1;
    r.tech_answered = 5213, r.tech_correct = 5211;
    r.phase_answered = 5212, r.phase_correct = 5211;
    r.bulb_answered = 5213, r.bulb_correct = 5206;
    r.detection_rate = 1.0;
    r.false_rate = 1.0 / 100000;
    r.tech_accuracy = 5211.0 / 5213;
    r.phase_accuracy = 5211.0 / 5212;
    r.bulb_accuracy = 5206.0 / 5213;
    r.resolvable_rate = r.bulb_unknown_rate = r.phase_unknown_rate = r.all_correct_rate = 0.0;
    r.ellipse_pairs = 0;
    r.loc_median_m = r.loc_p95_m = r.loc_max_m = NAN;
    char *text = NULL;
    size_t size = 0;
    FILE *f = open_memstream(&text, &size);
    CHECK(f != NULL);
    if (!f) return;
    CHECK_OK(srv_eval_print(&r, "truth.json", 0, f));
    fclose(f);
    CHECK_MSG(strstr(text, "| technology accuracy | 99.96 % |") && strstr(text, "| phase accuracy | 99.98 % |") &&
                  strstr(text, "| bulb accuracy | 99.9 % |") && strstr(text, "| detection rate | 100.0 % |") &&
                  strstr(text, "| false detections | 0.001 % |") && strstr(text, "| bulb unknown | 0.0 % |"),
              "%s", text);
    free(text);
}
