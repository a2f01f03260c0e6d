/* test_compare_shares.c - per-area phase-share changes between two surveys (survey/
 * compare_shares.c, `gridsurvey compare --by`): a hand-made database of two surveys over three
 * feeder areas with counts chosen here, against the z statistics, P-values and chi-square
 * worked out by hand (and with Python's math.erfc):
 *   w: A 30/30/40 of 100, B 20/30/50 of 100.
 *      0 deg: pooled 50/200, se = sqrt(0.25 x 0.75 x 0.02) = 0.0612372, z = -0.1 / se = -1.6329932,
 *             P = erfc(1.6329932 / sqrt 2) = 0.1024704;
 *      120 deg: z = 0, P = 1;
 *      240 deg: pooled 0.45, se = sqrt(0.45 x 0.55 x 0.02) = 0.0703562, z = 1.4213381, P = 0.1552185;
 *      homogeneity: expected 25/30/45 in each survey, chi2 = 1 + 1 + 0 + 0 + 25/45 + 25/45
 *      = 3.1111111 (2 dof), P = exp(-chi2 / 2) = 0.2110721.
 *   e: 10/10/10 in both: z = 0, P = 1, chi2 = 0, P = 1.
 *   n: A 5/0/0, B none: no test (NaN), A's shares 1/0/0.
 * Each survey's lights are their own sites (20 m apart, 1 m ellipses). */
#include "survey/survey.h"
#include "tests/fixtures.h"
#include "tests/survey_fixture.h"
#include "tests/test.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static char out[1 << 16];

/* areas: w = lon [35.000, 35.010], e = lon [35.020, 35.030], both lat [32.800, 32.810];
 * n = lat [32.820, 32.830], lon [35.000, 35.010] */
static const char areas_json[] =
    "{\"type\": \"FeatureCollection\", \"features\": [\n"
    " {\"type\": \"Feature\", \"properties\": {\"feeder\": \"w\"}, \"geometry\": {\"type\": \"Polygon\",\n"
    "  \"coordinates\": [[[35.0, 32.8], [35.01, 32.8], [35.01, 32.81], [35.0, 32.81], [35.0, 32.8]]]}},\n"
    " {\"type\": \"Feature\", \"properties\": {\"feeder\": \"e\"}, \"geometry\": {\"type\": \"Polygon\",\n"
    "  \"coordinates\": [[[35.02, 32.8], [35.03, 32.8], [35.03, 32.81], [35.02, 32.81], [35.02, 32.8]]]}},\n"
    " {\"type\": \"Feature\", \"properties\": {\"feeder\": \"n\"}, \"geometry\": {\"type\": \"Polygon\",\n"
    "  \"coordinates\": [[[35.0, 32.82], [35.01, 32.82], [35.01, 32.83], [35.0, 32.83], [35.0, 32.82]]]}}]}\n";

/* counts[area][phase] lights of one survey, on a 20 m grid inside each area (offset by the
 * survey so no light of B joins a site of A). */
static void add_survey(srv_db *db, int64_t sid, const char *key, const int counts[3][3], double offset_m)
{
    static const double lon0[3] = {35.0005, 35.0205, 35.0005}, lat0[3] = {32.8005, 32.8005, 32.8205};
    srv_light_row l[200];
    srv_location_row loc[200];
    int k = 0;
    double ky = 1.0 / 111000.0, kx = ky / cos(32.8 * M_PI / 180.0);
    for (int a = 0; a < 3; a++)
        for (int p = 0; p < 3; p++)
            for (int j = 0; j < counts[a][p]; j++, k++) {
                int q = p * 40 + j;   /* cell in the area: 8 per row */
                l[k] = survey_fx_light(k, 10.0 + k, 20.0, 120.0 * p, 0.99);
                l[k].bulb_id = "hps-70w";
                l[k].technology = "sodium_hp";
                srv_location_row_init(&loc[k]);
                loc[k].method = SRV_LOC_ONE_STATION;
                loc[k].lat_deg = lat0[a] + (20.0 * (q / 8) + offset_m) * ky;
                loc[k].lon_deg = lon0[a] + (20.0 * (q % 8) + offset_m) * kx;
                loc[k].ellipse = (gis_ellipse){1.0, 1.0, 0.0};
            }
    srv_capture_data cd = survey_fx_capture(sid, key, l, loc, (size_t)k);
    CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
}

/* Surveys A and B with the counts ca, cb (areas x phases) in a database at path, the feeders
 * at geo, and srv_compare_shares by feeder into *v, *n; the database stays open (NULL if it
 * could not be made), its options in *o and areas in *areas. */
static srv_db *compare_by_feeder(const char *path, const char *geo, const int ca[3][3], const int cb[3][3],
                                 srv_stats_opts *o, srv_areas **areas, srv_share_change **v, size_t *n)
{
    fx_write_text(geo, areas_json);
    int64_t a_id, b_id;
    srv_db *db = survey_fx_create(path, "A", &a_id);
    if (!db) return NULL;
    srv_survey_row sb = {.name = "B", .grid_hz = 50};
    CHECK_OK(srv_db_add_survey(db, &sb, &b_id));
    add_survey(db, a_id, "cap-a", ca, 0.0);
    add_survey(db, b_id, "cap-b", cb, 10.0);
    *areas = NULL;
    CHECK_OK(srv_areas_load(geo, "feeder", areas));
    srv_stats_opts_default(o);
    CHECK_OK(srv_stats_parse_by("feature:feeder", o));
    o->areas = *areas;
    *v = NULL;
    *n = 0;
    CHECK_OK(srv_compare_shares(db, o, "A", "B", v, n));
    return db;
}

TEST(compare_shares_two_proportion_oracle)
{
    const char *path = fx_tmp("shares.sqlite"), *geo = fx_tmp("feeders.geojson");
    static const int ca[3][3] = {{30, 30, 40}, {10, 10, 10}, {5, 0, 0}};
    static const int cb[3][3] = {{20, 30, 50}, {10, 10, 10}, {0, 0, 0}};
    srv_stats_opts o;
    srv_areas *areas;
    srv_share_change *v;
    size_t n;
    srv_db *db = compare_by_feeder(path, geo, ca, cb, &o, &areas, &v, &n);
    if (!db) return;
    CHECK(n == 3);
    const srv_share_change *w = NULL, *e = NULL, *nn = NULL;
    for (size_t i = 0; i < n; i++) {
        if (!strcmp(v[i].group, "w")) w = &v[i];
        if (!strcmp(v[i].group, "e")) e = &v[i];
        if (!strcmp(v[i].group, "n")) nn = &v[i];
    }
    CHECK(w && e && nn);
    if (w && e && nn) {
        CHECK(w->total_a == 100 && w->total_b == 100 && w->n_a[2] == 40 && w->n_b[0] == 20);
        CHECK_NEAR(w->z[0], -1.6329931618554518, 1e-12);
        CHECK_NEAR(w->p[0], 0.1024704348597495, 1e-12);
        CHECK_NEAR(w->z[1], 0.0, 1e-12);
        CHECK_NEAR(w->p[1], 1.0, 1e-12);
        CHECK_NEAR(w->z[2], 1.4213381090374024, 1e-12);
        CHECK_NEAR(w->p[2], 0.1552184896846842, 1e-12);
        CHECK_NEAR(w->chi2, 28.0 / 9.0, 1e-12);
        CHECK(w->dof == 2);
        CHECK_NEAR(w->p_value, 0.2110720877910902, 1e-12);
        CHECK(e->total_a == 30 && e->total_b == 30);
        CHECK_NEAR(e->chi2, 0.0, 1e-12);
        CHECK_NEAR(e->p_value, 1.0, 1e-12);
        CHECK(nn->total_a == 5 && nn->total_b == 0 && isnan(nn->z[0]) && isnan(nn->chi2));
        CHECK_NEAR(nn->share_a[0], 1.0, 0);
    }
    free(v);
    /* a survey that does not exist */
    CHECK(srv_compare_shares(db, &o, "A", "C", &v, &n) == GS_ENOTFOUND);
    srv_areas_free(areas);
    srv_db_close(db);

    int rc = fx_run(out, sizeof out, "%s compare --db %s --survey A --survey B --by feature:feeder --clip %s",
                    test_bin(), path, geo);
    CHECK_MSG(rc == 0 && strstr(out, "| w | 100 | 100 | 30.0 % -> 20.0 % (-10.0 pp, z -1.63, P 0.1025) | "
                                      "30.0 % -> 30.0 % (+0.0 pp, z 0.00, P 1.0000) | 40.0 % -> 50.0 % "
                                      "(+10.0 pp, z 1.42, P 0.1552) | 3.11 | 0.2111 |"), "%d: %s", rc, out);
    CHECK_MSG(strstr(out, "| n | 5 | 0 | 100.0 % -> - | 0.0 % -> - | 0.0 % -> - | - | - |"), "%s", out);
    rc = fx_run(out, sizeof out, "%s compare --db %s --survey A --survey B --by feature:feeder", test_bin(), path);
    CHECK_MSG(rc == 2 && strstr(out, "needs --clip"), "%d: %s", rc, out);
    rc = fx_run(out, sizeof out, "%s compare --db %s --survey A --survey B --by survey", test_bin(), path);
    CHECK_MSG(rc == 2, "%d: %s", rc, out);
}

/* Unequal survey sizes and a phase neither survey has (hand-computed): area w, A 10/0/20 of 30,
 * B 30/0/30 of 60. 0 deg: pooled 40/90 = 4/9, se = sqrt(4/9 x 5/9 x (1/30 + 1/60)) = 1/9,
 * z = (1/2 - 1/3) / (1/9) = 1.5, P = erfc(1.5 / sqrt 2) = 0.13361440253771617 (Python's
 * math.erfc); 240 deg: z = -1.5, the same P; 120 deg: no lights, no test. Homogeneity over the
 * two phases present (1 dof): expected 40/3, 50/3 (A) and 80/3, 100/3 (B), chi2 = 2.25 = z^2,
 * P = erfc(sqrt(2.25 / 2)), the same P. */
TEST(compare_shares_unequal_sizes_one_dof)
{
    const char *path = fx_tmp("shares2.sqlite"), *geo = fx_tmp("feeders2.geojson");
    static const int ca[3][3] = {{10, 0, 20}, {0, 0, 0}, {0, 0, 0}};
    static const int cb[3][3] = {{30, 0, 30}, {0, 0, 0}, {0, 0, 0}};
    srv_stats_opts o;
    srv_areas *areas;
    srv_share_change *v;
    size_t n;
    srv_db *db = compare_by_feeder(path, geo, ca, cb, &o, &areas, &v, &n);
    if (!db) return;
    CHECK(n == 1 && v && !strcmp(v[0].group, "w"));
    if (n == 1 && v) {
        const double P = 0.13361440253771617;
        CHECK(v[0].total_a == 30 && v[0].total_b == 60);
        CHECK_NEAR(v[0].share_a[2], 2.0 / 3.0, 1e-15);
        CHECK_NEAR(v[0].share_b[2], 0.5, 1e-15);
        CHECK_NEAR(v[0].z[0], 1.5, 1e-12);
        CHECK_NEAR(v[0].p[0], P, 1e-12);
        CHECK(isnan(v[0].z[1]) && isnan(v[0].p[1]));
        CHECK_NEAR(v[0].z[2], -1.5, 1e-12);
        CHECK_NEAR(v[0].p[2], P, 1e-12);
        CHECK(v[0].dof == 1);
        CHECK_NEAR(v[0].chi2, 2.25, 1e-12);
        CHECK_NEAR(v[0].p_value, P, 1e-12);
    }
    free(v);
    srv_areas_free(areas);
    srv_db_close(db);
}

/* compare --by cell ran each survey's statistics on a grid centred on its own lights, so one
 * cell index meant different ground in the two: B, the same lights as A plus 60 more 2 km north,
 * had its grid 0.7 km north of A's, and the cells of the lights both surveys share compared
 * different lights. Now both are on one grid: every cell holding A's lights holds B's same
 * lights (its counts equal, phase by phase), and B's 60 northern lights are in cells of their
 * own. */
TEST(compare_by_cell_one_grid_for_both_surveys)
{
    const char *path = fx_tmp("cells.sqlite");
    static const int ca[3][3] = {{30, 30, 40}, {10, 10, 10}, {0, 0, 0}};
    static const int cb[3][3] = {{30, 30, 40}, {10, 10, 10}, {60, 0, 0}};
    int64_t a_id, b_id;
    srv_db *db = survey_fx_create(path, "A", &a_id);
    if (!db) return;
    srv_survey_row sb = {.name = "B", .grid_hz = 50};
    CHECK_OK(srv_db_add_survey(db, &sb, &b_id));
    add_survey(db, a_id, "cap-a", ca, 0.0);
    add_survey(db, b_id, "cap-b", cb, 0.0);
    srv_stats_opts o;
    srv_stats_opts_default(&o);
    o.detections = 1;
    CHECK_OK(srv_stats_parse_by("cell:500", &o));
    srv_share_change *v = NULL;
    size_t n = 0;
    CHECK_OK(srv_compare_shares(db, &o, "A", "B", &v, &n));
    long shared = 0, b_only = 0;
    for (size_t i = 0; i < n; i++) {
        /* each cell's centre: within half a cell (250 m, 0.0023 deg of latitude, 0.0027 of
         * longitude) of its lights, the shared ones in w and e (lat 32.8005-32.8100, lon
         * 35.0005-35.0300), B's own in n (lat 32.8205 and up) */
        double lat = v[i].lat_deg, lon = v[i].lon_deg;
        CHECK_MSG(lon > 35.0005 - 0.0027 && lon < 35.03 + 0.0027, "cell %s: lon %.6f", v[i].group, lon);
        if (v[i].total_a == 0) {
            CHECK_MSG(lat > 32.8205 - 0.0023, "cell %s: lat %.6f", v[i].group, lat);
            b_only += v[i].total_b;
            continue;
        }
        CHECK_MSG(lat > 32.8005 - 0.0023 && lat < 32.81 + 0.0023, "cell %s: lat %.6f", v[i].group, lat);
        for (int p = 0; p < 3; p++)
            CHECK_MSG(v[i].n_a[p] == v[i].n_b[p], "cell %s phase %d: A %ld, B %ld", v[i].group, 120 * p,
                      v[i].n_a[p], v[i].n_b[p]);
        shared += v[i].total_a;
    }
    CHECK_MSG(shared == 130 && b_only == 60, "A's lights in cells with B's: %ld of 130; B's alone: %ld of 60", shared,
              b_only);
    free(v);
    srv_db_close(db);
    /* the CLI gives the centres: the table's lat, lon column and the CSV's lat_deg, lon_deg */
    int rc = fx_run(out, sizeof out, "%s compare --db %s --survey A --survey B --by cell:500", test_bin(),
                    path);
    CHECK_MSG(rc == 0 && strstr(out, "| group | lat, lon | n A | n B |") && strstr(out, "| 32.8"), "%d: %s", rc, out);
    rc = fx_run(out, sizeof out, "%s compare --db %s --survey A --survey B --by cell:500 --format csv",
                test_bin(), path);
    CHECK_MSG(rc == 0 && !strncmp(out, "group,lat_deg,lon_deg,n_a,n_b,", 30) && strstr(out, ",32.8"), "%d: %s", rc, out);
}
