/* test_uncertainty.c - calibrated error ellipses (survey/stages.c srv_centroid_sigma_px, gis
 * height prior): a small street-grid scene (a few hundred lights 2-3 km from a hilltop
 * station, another PSF and seed than the metro scene the constants were measured on) run
 * through `gridsurvey run`; `gridsurvey evaluate` (itself checked against a hand-made database
 * in tests/test_evaluate.c) gives the share of truth lights inside their stored 95 % ellipse.
 * It must lie in 90-99 % (95 % calibrated; with ~160 lights the binomial sd is 1.7 points)
 * and leave that band when the stored ellipses are made 3x wider or narrower (plain SQL on the
 * locations), so the band tests the calibration. The metro scene gives 96.2 % (docs/gis.md). */
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

TEST(uncertainty_ellipse_coverage_in_band)
{
    const char *scene = fx_tmp("grid.json"), *db = fx_tmp("grid.sqlite");
    fx_write_text(scene,
        "{\"format\": \"gridsurvey-scene/1\", \"name\": \"grid\", \"seed\": 11,\n"
        " \"grid\": {\"nominal_hz\": 50},\n"
        " \"camera\": {\"width_px\": 480, \"height_px\": 270,\n"
        "   \"station\": {\"lat_deg\": 32.7940, \"lon_deg\": 34.9900, \"height_m\": 470.0},\n"
        "   \"pose\": {\"heading_deg\": 52.0, \"pitch_deg\": -10.5, \"roll_deg\": 0.0},\n"
        "   \"intrinsics\": {\"focal_px\": 1200}, \"refraction_k\": 0.13,\n"
        "   \"optics\": {\"aperture_mm\": 2.0, \"transmission\": 0.3},\n"
        "   \"sensor\": {\"bands\": 3, \"bit_depth\": 12, \"full_well_e\": 20000, \"read_noise_e\": 3,\n"
        "              \"qe\": 0.6, \"gain_e_per_dn\": 5, \"black_level_dn\": 64}},\n"
        " \"acam\": {\"K\": 26, \"cycles\": 256, \"locked\": true, \"masks\": 64,\n"
        "          \"hdr\": {\"enabled\": true, \"max_saturated_px\": 50}},\n"
        " \"lights\": [{\"type\": \"street_grid\", \"center\": {\"lat_deg\": 32.8110, \"lon_deg\": 35.0140},\n"
        "   \"size_m\": [4000, 4000], \"rotation_deg\": 25, \"street_spacing_m\": 250, \"light_spacing_m\": 80,\n"
        "   \"jitter_m\": 2, \"ground_height_m\": 20, \"pole_height_m\": 9, \"min_range_m\": 2000,\n"
        "   \"max_range_m\": 3500, \"district_m\": 400, \"transformer_fraction\": 0, \"lumens_spread\": 0.3,\n"
        "   \"technologies\": [{\"bulb\": \"hps-150w\", \"weight\": 50, \"lumens\": 15000},\n"
        "                     {\"bulb\": \"mh-250w\", \"weight\": 25, \"lumens\": 20000},\n"
        "                     {\"bulb\": \"lps-90w\", \"weight\": 25, \"lumens\": 13500}]}],\n"
        " \"effects\": {\"extinction\": {\"visibility_km\": 20, \"angstrom_exponent\": 1.3},\n"
        "   \"psf\": {\"sigma_px\": 1.1}, \"ambient\": {\"e_per_px_cycle\": 0.3}, \"shot_noise\": {},\n"
        "   \"saturation\": {}, \"read_noise\": {}, \"adc\": {}}}\n");
    int rc = sh("%s run %s --db %s", test_bin(), scene, db);
    CHECK_MSG(rc == 0, "run: %d: %s", rc, out);
    if (rc != 0) return;
    CHECK_MSG(strstr(out, "(scene median), height sigma 0.00 m") != NULL, "%s", out);
    const char *truth = fx_tmp("grid-capture/truth.json");
    long pairs;
    double c = coverage(db, truth, &pairs);
    CHECK_MSG(pairs >= 150, "only %ld located matched lights", pairs);
    CHECK_MSG(c >= 0.90 && c <= 0.99, "95 %% ellipse coverage %.4f of %ld: expected 0.90-0.99", c, pairs);
    if (getenv("GS_TEST_VERBOSE")) printf("    coverage %.4f of %ld\n", c, pairs);
    scale_ellipses(db, 3.0);
    double wide = coverage(db, truth, &pairs);
    CHECK_MSG(wide > 0.99, "3x wider ellipses: coverage %.4f, inside the band", wide);
    scale_ellipses(db, 1.0 / 9.0);
    double narrow = coverage(db, truth, &pairs);
    CHECK_MSG(narrow < 0.90, "3x narrower ellipses: coverage %.4f, inside the band", narrow);
    if (getenv("GS_TEST_VERBOSE")) printf("    3x wider %.4f, 3x narrower %.4f\n", wide, narrow);
}
