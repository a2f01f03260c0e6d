/* test_uncertainty.c - calibrated error ellipses (survey/stages.c srv_centroid_sigma_px, gis
 * height prior): a small street-grid scene (a few hundred lights 2-3 km from a hilltop
 * station, another PSF and seed than the metro scene the constants were measured on) run
 * through `gridsurvey run`; `gridsurvey evaluate` (itself checked against a hand-made database
 * in tests/test_evaluate.c) gives the share of truth lights inside their stored 95 % ellipse.
 * It must lie in 90-99 % (95 % calibrated; with ~160 lights the binomial sd is 1.7 points)
 * and leave that band when the stored ellipses are made 3x wider or narrower (plain SQL on the
 * locations), so the band tests the calibration. The metro scene gives 96.2 % (docs/gis.md).
 * A second scene looks at its lights along grazing sight lines (a low station, 2-4 km, lights
 * 40 m apart along the streets): the streets that run away from it crowd into unresolved
 * blends, whose PSF-fit positions err by a good part of a pixel, tens of metres on the ground. */
#include "survey/survey.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <jansson.h>
#include <math.h>
#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static char out[1 << 17];
#define sh(...) fx_run(out, sizeof out, __VA_ARGS__)

/* evaluate's ellipse95_coverage and ellipse_pairs (NaN, -1 on failure) */
static double coverage(const char *db, const char *truth, long *pairs)
{
    *pairs = -1;
    int rc = sh("%s evaluate --db %s --truth %s --format json", test_bin(), db, truth);
    CHECK_MSG(rc == 0, "evaluate: %d: %s", rc, out);
    json_error_t err;
    json_t *ev = json_loads(out, 0, &err), *loc = json_object_get(ev, "location_error");
    double c = loc ? json_number_value(json_object_get(loc, "ellipse95_coverage")) : NAN;
    if (loc) *pairs = (long)json_integer_value(json_object_get(loc, "ellipse_pairs"));
    json_decref(ev);
    return c;
}

static void scale_ellipses(const char *db, double k)
{
    sqlite3 *h = NULL;
    char sql[200];
    snprintf(sql, sizeof sql, "UPDATE locations SET semi_major_m = semi_major_m * %.17g, "
             "semi_minor_m = semi_minor_m * %.17g", k, k);
    CHECK(sqlite3_open(db, &h) == SQLITE_OK && sqlite3_exec(h, sql, NULL, NULL, NULL) == SQLITE_OK);
    sqlite3_close(h);
}

/* Runs scene (named name) and checks its 95 % coverage in 90-99 % of at least min_pairs lights,
 * below 90 % with the ellipses 3x narrower and, when check_wide, above 99 % 3x wider. */
static void coverage_in_band(const char *name, const char *scene_json, long min_pairs, int check_wide)
{
    char scene[64], db[64], truth[96];
    snprintf(scene, sizeof scene, "%s.json", name);
    snprintf(db, sizeof db, "%s.sqlite", name);
    snprintf(truth, sizeof truth, "%s-capture/truth.json", name);
    const char *scene_p = fx_tmp(scene), *db_p = fx_tmp(db), *truth_p = fx_tmp(truth);
    fx_write_text(scene_p, scene_json);
    int rc = sh("%s run %s --db %s", test_bin(), scene_p, db_p);
    CHECK_MSG(rc == 0, "run: %d: %s", rc, out);
    if (rc != 0) return;
    CHECK_MSG(strstr(out, "(scene median), height sigma 0.00 m") != NULL, "%s", out);
    long pairs;
    double c = coverage(db_p, truth_p, &pairs);
    CHECK_MSG(pairs >= min_pairs, "%s: only %ld located matched lights", name, pairs);
    CHECK_MSG(c >= 0.90 && c <= 0.99, "%s: 95 %% ellipse coverage %.4f of %ld: expected 0.90-0.99", name, c, pairs);
    if (getenv("GS_TEST_VERBOSE")) printf("    %s: coverage %.4f of %ld\n", name, c, pairs);
    scale_ellipses(db_p, 3.0);
    double wide = coverage(db_p, truth_p, &pairs);
    CHECK_MSG(!check_wide || wide > 0.99, "%s: 3x wider ellipses: coverage %.4f, inside the band", name, wide);
    scale_ellipses(db_p, 1.0 / 9.0);
    double narrow = coverage(db_p, truth_p, &pairs);
    CHECK_MSG(narrow < 0.90, "%s: 3x narrower ellipses: coverage %.4f, inside the band", name, narrow);
    if (getenv("GS_TEST_VERBOSE")) printf("    3x wider %.4f, 3x narrower %.4f\n", wide, narrow);
}

#define SCENE_CAMERA(height_m, pitch_deg) \
    " \"camera\": {\"width_px\": 480, \"height_px\": 270,\n" \
    "   \"station\": {\"lat_deg\": 32.7940, \"lon_deg\": 34.9900, \"height_m\": " height_m "},\n" \
    "   \"pose\": {\"heading_deg\": 52.0, \"pitch_deg\": " pitch_deg ", \"roll_deg\": 0.0},\n" \
    "   \"intrinsics\": {\"focal_px\": 1200}, \"refraction_k\": 0.13,\n" \
    "   \"optics\": {\"aperture_mm\": 2.0, \"transmission\": 0.3},\n" \
    "   \"sensor\": {\"bands\": 3, \"bit_depth\": 12, \"full_well_e\": 20000, \"read_noise_e\": 3,\n" \
    "              \"qe\": 0.6, \"gain_e_per_dn\": 5, \"black_level_dn\": 64}},\n" \
    " \"acam\": {\"K\": 26, \"cycles\": 256, \"locked\": true, \"masks\": 64,\n" \
    "          \"hdr\": {\"enabled\": true, \"max_saturated_px\": 50}},\n"
#define SCENE_TECHNOLOGIES \
    "   \"technologies\": [{\"bulb\": \"hps-150w\", \"weight\": 50, \"lumens\": 15000},\n" \
    "                     {\"bulb\": \"mh-250w\", \"weight\": 25, \"lumens\": 20000},\n" \
    "                     {\"bulb\": \"lps-90w\", \"weight\": 25, \"lumens\": 13500}]}],\n"
#define SCENE_EFFECTS(psf_px) \
    " \"effects\": {\"extinction\": {\"visibility_km\": 20, \"angstrom_exponent\": 1.3},\n" \
    "   \"psf\": {\"sigma_px\": " psf_px "}, \"ambient\": {\"e_per_px_cycle\": 0.3}, \"shot_noise\": {},\n" \
    "   \"saturation\": {}, \"read_noise\": {}, \"adc\": {}}}\n"

TEST(uncertainty_ellipse_coverage_in_band)
{
    coverage_in_band("grid",
        "{\"format\": \"gridsurvey-scene/1\", \"name\": \"grid\", \"seed\": 11,\n"
        " \"grid\": {\"nominal_hz\": 50},\n" SCENE_CAMERA("470.0", "-10.5")
        " \"lights\": [{\"type\": \"street_grid\", \"center\": {\"lat_deg\": 32.8110, \"lon_deg\": 35.0140},\n"
        "   \"size_m\": [4000, 4000], \"rotation_deg\": 25, \"street_spacing_m\": 250, \"light_spacing_m\": 80,\n"
        "   \"jitter_m\": 2, \"ground_height_m\": 20, \"pole_height_m\": 9, \"min_range_m\": 2000,\n"
        "   \"max_range_m\": 3500, \"district_m\": 400, \"transformer_fraction\": 0, \"lumens_spread\": 0.3,\n"
        SCENE_TECHNOLOGIES SCENE_EFFECTS("1.1"), 150, 1);
}

/* The grazing vantage (200 m up, pitch -3.3 deg): 86.5 % of 274 when a PSF-fit light's ellipse
 * had a fixed 0.012 s of crowding, blind to an unresolved neighbour (metro seen from another
 * station: 78.3 %); with the fit's covariance and its light's excess second moment, 93.4 %.
 * 3x wider it is 97.4 %, not above 99 %: a few blends err beyond any Gaussian (a light matched
 * to the fainter of a pair, three or more lights in one source), so that check is left out. */
TEST(uncertainty_ellipse_coverage_grazing_blends)
{
    coverage_in_band("graze",
        "{\"format\": \"gridsurvey-scene/1\", \"name\": \"graze\", \"seed\": 23,\n"
        " \"grid\": {\"nominal_hz\": 50},\n" SCENE_CAMERA("200.0", "-3.3")
        " \"lights\": [{\"type\": \"street_grid\", \"center\": {\"lat_deg\": 32.8107, \"lon_deg\": 35.0153},\n"
        "   \"size_m\": [5000, 5000], \"rotation_deg\": 25, \"street_spacing_m\": 200, \"light_spacing_m\": 40,\n"
        "   \"jitter_m\": 2, \"ground_height_m\": 20, \"pole_height_m\": 9, \"min_range_m\": 2000,\n"
        "   \"max_range_m\": 4000, \"district_m\": 400, \"transformer_fraction\": 0, \"lumens_spread\": 0.3,\n"
        SCENE_TECHNOLOGIES SCENE_EFFECTS("0.9"), 250, 0);
}

/* The crowding rule on integer areas: the 16 isolated lights (44 px apart, PSF sigma 1 px; the
 * truth of test_two_stations.c's east capture) of one capture, their SNRs and areas as
 * measured: equal SNRs within 0.2 %, areas 30-33 px. None has a neighbour in its footprint, so
 * none is crowded; the same capture with one light's area 20 px larger (a merged neighbour, the
 * 19-39 px of docs/gis.md) flags that light. The fit over 0.2 % of ln SNR put a slope of 212
 * px through the rounding of the areas, its robust sigma 0.16 px (below the 0.29 px of rounding
 * to whole pixels), and flagged the light of 33 px, 0.92 px above the line: its ellipse was 750x
 * wider across the sight line than its neighbours'. */
TEST(uncertainty_crowded_footprints_integer_areas)
{
    static const double snr_area[16][2] = {
        {2237.118606, 32}, {2233.972039, 32}, {2234.112108, 32}, {2236.484768, 30}, {2234.396807, 32},
        {2234.513950, 32}, {2235.685170, 32}, {2233.915249, 31}, {2235.517220, 33}, {2233.709580, 32},
        {2235.204315, 32}, {2234.778105, 30}, {2235.936703, 32}, {2234.773484, 32}, {2232.958000, 32},
        {2233.275473, 32}};
    srv_light_row l[16];
    unsigned char crowded[16];
    for (int merged = 0; merged < 2; merged++) {
        for (int i = 0; i < 16; i++) {
            srv_light_row_init(&l[i]);
            l[i].snr = snr_area[i][0];
            l[i].area_px = (int)snr_area[i][1] + (merged && i == 5 ? 20 : 0);
        }
        CHECK_OK(srv_crowded_footprints(l, 16, crowded));
        for (int i = 0; i < 16; i++)
            CHECK_MSG(crowded[i] == (merged && i == 5), "%s: light %d (area %d px) crowded %d",
                      merged ? "light 5 with a merged neighbour" : "isolated lights", i, l[i].area_px, crowded[i]);
    }
}
