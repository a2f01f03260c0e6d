/* test_two_stations.c - `gridsurvey run` with two stations of one area (survey/cmd_run.c,
 * survey/sites_triangulate.c srv_triangulate_sites): 16 lights at heights 8-12 m seen from
 * two stations 600 m apart, each run assuming the lights' median height (10 m, the height
 * prior's sigma their spread). The oracle is the simulator's truth.json of each capture, read
 * here with Jansson: each triangulated site's two detections (plain SQL) are matched to the
 * truth by pixel in their own capture, must be the same truth light, and the intersection
 * must lie within its ellipse of that light's true position (east/north offsets from the
 * WGS84 radii of curvature, written here). One-station positions are off by up to 20 m along
 * the sight line (the height error over the tangent of the depression); the triangulation
 * needs no height. */
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

#define LAT0 32.8
#define LON0 35.0

static void write_scene(const char *path, const char *name, double east_m, double heading_deg)
{
    static const char *const bulbs[4] = {"hps-70w", "mh-70w", "fl-t8-36w-tri", "inc-a60-60w-230v"};
    char lights[8192] = "";
    for (int i = 0; i < 16; i++) {
        double e = -60.0 + 40.0 * (i % 4), n = 550.0 + 66.7 * (i / 4);
        size_t used = strlen(lights);
        snprintf(lights + used, sizeof lights - used,
                 "%s{\"id\": \"L%d\", \"bulb\": \"%s\", \"phase_deg\": %d, \"lat_deg\": %.9f, "
                 "\"lon_deg\": %.9f, \"height_m\": %d, \"flux_e_per_cycle\": 40000}",
                 i ? ",\n" : "", i, bulbs[i % 4], 120 * (i % 3), LAT0 + n / 110900.0,
                 LON0 + e / 93400.0, 8 + i % 5);
    }
    char text[12288];
    snprintf(text, sizeof text,
             "{\"format\": \"gridsurvey-scene/1\", \"name\": \"%s\", \"seed\": 7,\n"
             " \"grid\": {\"nominal_hz\": 50},\n"
             " \"camera\": {\"width_px\": 320, \"height_px\": 240,\n"
             "   \"station\": {\"lat_deg\": %.9f, \"lon_deg\": %.9f, \"height_m\": 80},\n"
             "   \"pose\": {\"heading_deg\": %.3f, \"pitch_deg\": -5.6, \"roll_deg\": 0},\n"
             "   \"intrinsics\": {\"focal_px\": 800},\n"
             "   \"sensor\": {\"bands\": 3, \"bit_depth\": 12, \"full_well_e\": 60000, \"read_noise_e\": 4,\n"
             "              \"qe\": 0.6, \"gain_e_per_dn\": 15, \"black_level_dn\": 64}},\n"
             " \"acam\": {\"K\": 26, \"cycles\": 128, \"locked\": true, \"masks\": 64,\n"
             "          \"hdr\": {\"enabled\": true, \"max_saturated_px\": 0}},\n"
             " \"lights\": [%s],\n"
             " \"effects\": {\"psf\": {\"sigma_px\": 1.0}, \"shot_noise\": {}, \"saturation\": {},\n"
             "             \"read_noise\": {}, \"adc\": {}}}\n",
             name, LAT0, LON0 + east_m / 93400.0, heading_deg, lights);
    fx_write_text(path, text);
}

typedef struct {
    double x, y, lat, lon;
    char id[16];
} truth_light;

/* The in-image lights of a truth.json (at most cap). */
static size_t read_truth(const char *path, truth_light *t, size_t cap)
{
    json_error_t err;
    json_t *root = json_load_file(path, 0, &err), *ls = json_object_get(root, "lights");
    CHECK_MSG(root && ls, "%s: %s", path, err.text);
    size_t i, n = 0;
    json_t *l;
    json_array_foreach(ls, i, l) {
        if (!json_is_true(json_object_get(l, "in_image")) || n == cap) continue;
        t[n].x = json_number_value(json_object_get(l, "x_px"));
        t[n].y = json_number_value(json_object_get(l, "y_px"));
        t[n].lat = json_number_value(json_object_get(l, "lat_deg"));
        t[n].lon = json_number_value(json_object_get(l, "lon_deg"));
        snprintf(t[n].id, sizeof t[n].id, "%s", json_string_value(json_object_get(l, "id")));
        n++;
    }
    json_decref(root);
    return n;
}

/* The truth light within 2 px of the stored light's pixel; NULL if none. */
static const truth_light *match(sqlite3 *h, int64_t light_id, truth_light *const tr[2], const size_t nt[2])
{
    sqlite3_stmt *q;
    const truth_light *best = NULL;
    if (sqlite3_prepare_v2(h, "SELECT l.x_px, l.y_px, c.path FROM lights l JOIN captures c ON "
                           "c.id = l.capture_id WHERE l.id = ?1", -1, &q, NULL) != SQLITE_OK)
        return NULL;
    sqlite3_bind_int64(q, 1, light_id);
    if (sqlite3_step(q) == SQLITE_ROW) {
        double x = sqlite3_column_double(q, 0), y = sqlite3_column_double(q, 1);
        int k = strstr((const char *)sqlite3_column_text(q, 2), "west-capture") != NULL;
        double bd = 4.0;
        for (size_t i = 0; i < nt[k]; i++) {
            double d = (tr[k][i].x - x) * (tr[k][i].x - x) + (tr[k][i].y - y) * (tr[k][i].y - y);
            if (d < bd) bd = d, best = &tr[k][i];
        }
    }
    sqlite3_finalize(q);
    return best;
}

/* (east, north) metres of (lat, lon) from (lat0, lon0): WGS84 radii of curvature at the mean
 * latitude (1e-6 relative over a kilometre). */
static void en_offset(double lat0, double lon0, double lat, double lon, double *e, double *n)
{
    const double a = 6378137.0, f = 1 / 298.257223563, e2 = f * (2 - f), d = M_PI / 180;
    double phi = 0.5 * (lat0 + lat) * d, w = 1 - e2 * sin(phi) * sin(phi);
    double N = a / sqrt(w), M = a * (1 - e2) / (w * sqrt(w));
    *e = (lon - lon0) * d * N * cos(phi);
    *n = (lat - lat0) * d * M;
}

TEST(two_stations_triangulate_within_their_ellipses)
{
    const char *east = fx_tmp("east.json"), *west = fx_tmp("west.json"), *db = fx_tmp("town.sqlite");
    /* both look at the centre of the lights (650 m north, 0 east) from 300 m east and west */
    double h = atan2(300.0, 650.0) / (M_PI / 180);
    write_scene(east, "east", 300.0, 360.0 - h);
    write_scene(west, "west", -300.0, h);
    int rc = sh("%s run %s %s --survey town --db %s", test_bin(), east, west, db);
    CHECK_MSG(rc == 0, "run: %d: %s", rc, out);
    if (rc != 0) return;
    /* one survey of two inputs: its balance and map once, after both; each capture's evaluation */
    int balances = 0, maps = 0, evals = 0;
    for (const char *p = out; (p = strstr(p, "Phase balance of survey town")); p++) balances++;
    for (const char *p = out; (p = strstr(p, "town-map.png")); p++) maps++;
    for (const char *p = out; (p = strstr(p, "\nEvaluation against ")); p++) evals++;
    const char *last_run = strstr(strstr(out, "run: survey town") + 1, "run: survey town");
    CHECK_MSG(balances == 1 && maps == 1 && evals == 2 && last_run &&
                  strstr(out, "Phase balance of survey town") > last_run,
              "%d balance tables, %d maps, %d evaluations, the table %s the second input:\n%s", balances, maps,
              evals, last_run && strstr(out, "Phase balance of survey town") > last_run ? "after" : "before", out);
    /* the same capture given twice is evaluated once; a failing later input still gets the
     * earlier inputs' survey reported, then its own one-line error */
    rc = sh("%s run %s %s --survey town --db %s", test_bin(), east, east, db);
    evals = 0;
    for (const char *p = out; (p = strstr(p, "\nEvaluation against ")); p++) evals++;
    CHECK_MSG(rc == 0 && evals == 1, "%d, %d evaluations: %s", rc, evals, out);
    char missing[2100];
    snprintf(missing, sizeof missing, "%s", fx_tmp("no-such-scene.json"));
    rc = sh("%s run %s %s --survey town --db %s", test_bin(), east, missing, db);
    CHECK_MSG(rc == 1 && strstr(out, "Phase balance of survey town") && strstr(out, "gridsurvey run: ") &&
                  strstr(out, "no-such-scene.json"),
              "%d: %s", rc, out);
    rc = sh("%s run %s %s --survey town --db %s", test_bin(), east, west, db);   /* (the output below) */
    CHECK(rc == 0);
    const char *two = strstr(out, "\nTwo stations");
    CHECK_MSG(two && strstr(two, "16 light sites seen from two stations, 16 triangulated, 0 flagged"), "%s", out);
    if (two && getenv("GS_TEST_VERBOSE")) fputs(two, stdout);
    truth_light te[32], tw[32];
    truth_light *tr[2] = {te, tw};
    size_t nt[2] = {read_truth(fx_tmp("east-capture/truth.json"), te, 32),
                    read_truth(fx_tmp("west-capture/truth.json"), tw, 32)};
    CHECK(nt[0] == 16 && nt[1] == 16);

    srv_db *d = NULL;
    CHECK_OK(srv_db_open(db, SRV_DB_READ, &d));
    sqlite3 *hq = NULL;
    CHECK(sqlite3_open_v2(db, &hq, SQLITE_OPEN_READONLY, NULL) == SQLITE_OK);
    int64_t caps[2] = {1, 2};
    srv_tri_site *t = NULL;
    size_t n = 0;
    CHECK_OK(srv_triangulate_sites(d, caps, 2, &t, &n));
    CHECK_MSG(n == 16, "%zu sites seen from both stations, expected 16", n);
    int inside95 = 0, inside999 = 0;
    double worst = 0;
    for (size_t i = 0; i < n; i++) {
        const truth_light *a = match(hq, t[i].light_id[0], tr, nt), *b = match(hq, t[i].light_id[1], tr, nt);
        CHECK_MSG(a && b && !strcmp(a->id, b->id), "site %lld: its detections are %s and %s",
                  (long long)t[i].site_id, a ? a->id : "-", b ? b->id : "-");
        CHECK(strcmp(t[i].station[0], t[i].station[1]) != 0);
        const gis_intersection *x = &t[i].fix;
        CHECK_MSG(x->flags == 0 && x->angle_deg > 30.0, "site %lld: flags %u, angle %.1f",
                  (long long)t[i].site_id, x->flags, x->angle_deg);
        if (!a || !isfinite(x->lat_deg)) continue;
        double de, dn;
        en_offset(x->lat_deg, x->lon_deg, a->lat, a->lon, &de, &dn);
        /* d2 = v^T C^-1 v in the ellipse's axes (major at azimuth az from north) */
        double az = x->ellipse.azimuth_deg * M_PI / 180;
        double u = de * sin(az) + dn * cos(az), v = de * cos(az) - dn * sin(az);
        double d2 = u * u / (x->ellipse.semi_major_m * x->ellipse.semi_major_m) +
                    v * v / (x->ellipse.semi_minor_m * x->ellipse.semi_minor_m);
        inside95 += d2 <= 5.991;
        inside999 += d2 <= 13.816;
        if (hypot(de, dn) > worst) worst = hypot(de, dn);
        if (getenv("GS_TEST_VERBOSE"))
            printf("    %s: error %.3f m, ellipse %.3f x %.3f m, d2 %.2f\n", a->id, hypot(de, dn),
                   x->ellipse.semi_major_m, x->ellipse.semi_minor_m, d2);
    }
    CHECK_MSG(inside999 == (int)n && inside95 >= (int)n - 2, "%d of %zu inside their 95 %% ellipse, "
              "%d inside 99.9 %%", inside95, n, inside999);
    /* the one-station positions are off by metres along the sight lines (heights 8-12 m) */
    double one_max = 0;
    sqlite3_stmt *q;
    CHECK(sqlite3_prepare_v2(hq, "SELECT l.id, loc.lat_deg, loc.lon_deg FROM lights l JOIN locations "
                             "loc ON loc.light_id = l.id", -1, &q, NULL) == SQLITE_OK);
    while (sqlite3_step(q) == SQLITE_ROW) {
        const truth_light *a = match(hq, sqlite3_column_int64(q, 0), tr, nt);
        double de, dn;
        if (!a) continue;
        en_offset(sqlite3_column_double(q, 1), sqlite3_column_double(q, 2), a->lat, a->lon, &de, &dn);
        if (hypot(de, dn) > one_max) one_max = hypot(de, dn);
    }
    sqlite3_finalize(q);
    if (getenv("GS_TEST_VERBOSE")) printf("    worst error: triangulated %.4f m, one station %.3f m\n", worst, one_max);
    CHECK_MSG(one_max > 10.0 && worst < 0.1 * one_max, "worst error: triangulated %.3f m, one station %.3f m",
              worst, one_max);
    /* the survey's map draws both stations: their stored cameras, as the scenes placed them */
    gis_camera *cams = NULL;
    size_t nc = 0;
    CHECK_OK(srv_db_read_stations(d, "town", &cams, &nc));
    CHECK_MSG(nc == 2, "%zu stations", nc);
    for (size_t k = 0; k < nc && nc == 2; k++) {
        double east_m = k == 0 ? 300.0 : -300.0;
        CHECK_NEAR(cams[k].lat_deg, LAT0, 1e-9);
        CHECK_NEAR(cams[k].lon_deg, LON0 + east_m / 93400.0, 1e-9);
        CHECK_NEAR(cams[k].heading_deg, k == 0 ? 360.0 - h : h, 1e-3);
        CHECK_NEAR(cams[k].focal_px, 800.0, 1e-9);
    }
    free(cams);
    CHECK_OK(srv_db_read_stations(d, "no such survey", &cams, &nc));
    CHECK(nc == 0 && cams == NULL);
    free(t);
    sqlite3_close(hq);
    srv_db_close(d);
}
