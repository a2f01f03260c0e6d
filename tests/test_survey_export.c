/* test_survey_export.c - `gridsurvey export` and srv_db_read_lights (survey/): exports read
 * back by Jansson and SQLite with their filters checked against plain SQL, a bounding box
 * across the antimeridian, and bad arguments. */
#include "survey/survey.h"
#include "tests/fixtures.h"
#include "tests/survey_fixture.h"
#include "tests/test.h"

#include <jansson.h>
#include <math.h>
#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static char out[1 << 18];

/* `gridsurvey ...`: fmt's first %s is the binary (tests/fixtures.h); output in out. */
static int run(const char *fmt, const char *a, const char *b, const char *c)
{
    return fx_run_bin(out, sizeof out, fmt, a, b, c);
}

static json_t *load_geojson(const char *path, size_t *features)
{
    json_error_t err;
    json_t *root = json_load_file(path, 0, &err);
    CHECK_MSG(root != NULL, "%s: %s", path, err.text);
    json_t *f = root ? json_object_get(root, "features") : NULL;
    *features = f ? json_array_size(f) : 0;
    return root;
}

static sqlite3 *raw_open(const char *path)
{
    sqlite3 *h = NULL;
    CHECK(sqlite3_open_v2(path, &h, SQLITE_OPEN_READONLY, NULL) == SQLITE_OK);
    return h;
}

TEST(export_filters_match_sql)
{
    const char *path = fx_tmp("ex.sqlite");
    survey_fx_synth_square(path, "north", 8, 50, 21);
    survey_fx_synth_square(path, "south", 4, 50, 22);
    sqlite3 *h = raw_open(path);
    const char *geo = fx_tmp("all.geojson");
    size_t n = 0;
    CHECK(run("%s export --db %s -o %s", path, geo, NULL) == 0 && strstr(out, "exported 600 lights"));
    json_t *root = load_geojson(geo, &n);
    CHECK(n == 600);
    /* one feature checked field by field against its row */
    json_t *f0 = json_array_get(json_object_get(root, "features"), 0);
    json_t *props = json_object_get(f0, "properties");
    const char *id = json_string_value(json_object_get(props, "id"));
    char sql[512];
    snprintf(sql, sizeof sql, "SELECT technology FROM lights WHERE id = %s", id ? id : "0");
    CHECK(!strcmp(survey_fx_query_text(h, sql), json_string_value(json_object_get(props, "technology"))));
    json_decref(root);
    struct {
        const char *args;
        const char *sql;
    } cases[] = {
        {"--survey south", "SELECT count(*) FROM light_phase WHERE survey = 'south'"},
        {"--technology sodium_hp", "SELECT count(*) FROM lights WHERE technology = 'sodium_hp'"},
        {"--phase 120", "SELECT count(*) FROM light_phase WHERE phase_class = '120'"},
        {"--phase unknown", "SELECT count(*) FROM lights WHERE phase_deg IS NULL"},
        {"--min-confidence 0.8", "SELECT count(*) FROM lights WHERE confidence >= 0.8"},
        {"--survey north --phase 0 --min-confidence 0.7",
         "SELECT count(*) FROM light_phase WHERE survey = 'north' AND phase_class = '0' AND confidence >= 0.7"},
        {"--bbox 35.0,32.79,35.03,32.81",
         "SELECT count(*) FROM locations WHERE lon_deg BETWEEN 35.0 AND 35.03 AND lat_deg BETWEEN 32.79 AND 32.81"},
        {"--bbox 35.0,32.79,35.03,32.81 --technology led_linear",
         "SELECT count(*) FROM locations lo JOIN lights l ON l.id = lo.light_id WHERE lon_deg BETWEEN 35.0 AND "
         "35.03 AND lat_deg BETWEEN 32.79 AND 32.81 AND technology = 'led_linear'"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        long want = survey_fx_query_long(h, cases[i].sql);
        CHECK(want > 0 && want < 600);
        CHECK(run("%s export --db %s -o %s %s", path, geo, cases[i].args) == 0);
        root = load_geojson(geo, &n);
        CHECK_MSG((long)n == want, "export %s: %zu features, SQL says %ld", cases[i].args, n, want);
        json_decref(root);
    }
    sqlite3_close(h);
}

TEST(export_all_formats_read_back)
{
    const char *path = fx_tmp("fmt.sqlite");
    survey_fx_synth_square(path, "fmt", 2, 50, 4);
    const char *gpkg = fx_tmp("l.gpkg"), *kml = fx_tmp("l.kml"), *csv = fx_tmp("l.csv");
    CHECK(run("%s export --db %s -o %s", path, gpkg, NULL) == 0);
    sqlite3 *h = raw_open(gpkg);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM lights") == 100);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM lights WHERE geom IS NULL") == 2 * (50 / SRV_SYNTH_UNLOCATED_EVERY));
    /* each detection's site, as the survey database's site_detections has it */
    char sql[4400];
    snprintf(sql, sizeof sql, "ATTACH '%s' AS src", path);
    CHECK(sqlite3_exec(h, sql, NULL, NULL, NULL) == SQLITE_OK);
    long sited = survey_fx_query_long(h, "SELECT count(*) FROM src.site_detections");
    CHECK_MSG(sited > 0 && survey_fx_query_long(h, "SELECT count(*) FROM lights WHERE site IS NOT NULL") == sited,
              "%ld detections with a site", sited);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM lights g LEFT JOIN src.site_detections sd ON "
                                  "sd.light_id = CAST(g.id AS INTEGER) WHERE coalesce(g.site, '') != "
                                  "coalesce(CAST(sd.site_id AS TEXT), '')") == 0);
    sqlite3_close(h);
    CHECK(run("%s export --db %s -o %s", path, kml, NULL) == 0);
    char *text = fx_read_file(kml, NULL);
    CHECK(text && fx_count_of(text, "<Placemark") == 100);
    free(text);
    CHECK(run("%s export --db %s --format csv -o %s", path, csv, NULL) == 0);
    text = fx_read_file(csv, NULL);
    CHECK(text && fx_count_lines(text) == 101);
    free(text);
}

TEST(export_bbox_crosses_antimeridian)
{
    const char *path = fx_tmp("am.sqlite");
    int64_t sid;
    srv_db *db = survey_fx_create(path, "fiji", &sid);
    if (!db) return;
    const double lon[5] = {179.95, -179.95, 179.5, -179.5, 0.0};
    srv_light_row l[5];
    srv_location_row loc[5];
    for (int i = 0; i < 5; i++) {
        l[i] = survey_fx_sodium_light(i, 0);
        srv_location_row_init(&loc[i]);
        loc[i].method = SRV_LOC_TRUTH;
        loc[i].lat_deg = -16.5;
        loc[i].lon_deg = lon[i];
    }
    srv_capture_data cd = survey_fx_capture(sid, "am", l, loc, 5);
    CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    srv_export_opts o;
    srv_export_opts_default(&o);
    o.use_bbox = 1;
    o.bbox[0] = 179.9;
    o.bbox[1] = -17;
    o.bbox[2] = -179.9;
    o.bbox[3] = -16;
    gis_light *v = NULL;
    size_t n = 0;
    CHECK_OK(srv_db_read_lights(db, &o, &v, &n));
    CHECK(n == 2 && v && fabs(fabs(v[0].lon_deg) - 179.95) < 1e-9 && fabs(fabs(v[1].lon_deg) - 179.95) < 1e-9);
    free(v);
    o.bbox[0] = -1;
    o.bbox[2] = 1;
    CHECK_OK(srv_db_read_lights(db, &o, &v, &n));
    CHECK(n == 1 && v[0].lon_deg == 0.0 && v[0].lat_deg == -16.5);
    free(v);
    srv_db_close(db);
}

/* The 180 deg meridian is stored as -180 (longitudes in [-180, 180)): a box whose MAXLON is 180
 * holds it, as in stats --bbox. export missed it (its own test lon <= MAXLON, and an R*Tree
 * prefilter up to 180) while stats counted it. Oracle: the counts by construction, and stats on
 * the same boxes. */
TEST(export_bbox_holds_the_180_meridian_like_stats)
{
    const char *path = fx_tmp("m180.sqlite");
    int64_t sid;
    srv_db *db = survey_fx_create(path, "fiji", &sid);
    if (!db) return;
    const double lon[4] = {180.0, 179.99, -179.99, 0.0};
    srv_light_row l[4];
    srv_location_row loc[4];
    for (int i = 0; i < 4; i++) {
        l[i] = survey_fx_sodium_light(i, 0);
        srv_location_row_init(&loc[i]);
        loc[i].method = SRV_LOC_TRUTH;
        loc[i].lat_deg = -16.5;
        loc[i].lon_deg = lon[i];
    }
    srv_capture_data cd = survey_fx_capture(sid, "m180", l, loc, 4);
    CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    static const struct {
        double box[4];
        size_t n;
    } cases[] = {
        {{179.9, -17, 180, -16}, 2},  {{-180, -17, -179.9, -16}, 2}, {{-180, -17, 180, -16}, 4},
        {{179.9, -17, -179.9, -16}, 3}, {{180, -17, -179.9, -16}, 2}, {{-1, -17, 180, -16}, 3},
    };
    for (size_t k = 0; k < sizeof cases / sizeof *cases; k++) {
        srv_export_opts o;
        srv_export_opts_default(&o);
        o.use_bbox = 1;
        memcpy(o.bbox, cases[k].box, sizeof o.bbox);
        gis_light *v = NULL;
        size_t n = 0;
        CHECK_OK(srv_db_read_lights(db, &o, &v, &n));
        free(v);
        srv_stats_opts so;
        srv_stats_opts_default(&so);
        memcpy(so.bbox, cases[k].box, sizeof so.bbox);
        so.detections = 1;
        srv_phase_stats *g = NULL;
        size_t ng = 0;
        CHECK_OK(srv_stats_compute(db, &so, &g, &ng, NULL));
        long ns = ng == 1 ? g[0].lights : -1;
        free(g);
        CHECK_MSG(n == cases[k].n && ns == (long)cases[k].n, "box %g,%g,%g,%g: export %zu, stats %ld, expected %zu",
                  cases[k].box[0], cases[k].box[1], cases[k].box[2], cases[k].box[3], n, ns, cases[k].n);
    }
    srv_db_close(db);
}

TEST(export_bad_input)
{
    const char *path = fx_tmp("bad.sqlite");
    survey_fx_synth_square(path, "bad", 1, 10, 1);
    const char *geo = fx_tmp("o.geojson");
    CHECK(run("%s export --db %s -o %s --bbox 1,2,3", path, geo, NULL) == 2);
    CHECK(run("%s export --db %s -o %s --phase 90", path, geo, NULL) == 2);
    CHECK(run("%s export --db %s -o %s --technology plasma", path, geo, NULL) == 2);
    CHECK(run("%s export --db %s -o %s --min-confidence 1.5", path, geo, NULL) == 2);
    CHECK(run("%s export --db %s -o %s/x.shp", path, test_tmpdir(), NULL) == 2);
    CHECK(run("%s export --db %s -o %s --survey nobody", path, geo, NULL) == 1);
    CHECK(fx_count_lines(out) == 1 && strstr(out, "nobody"));
    CHECK(!fx_exists(geo));
    CHECK(run("%s export --help", NULL, NULL, NULL) == 0 && strstr(out, "--bbox"));
}
