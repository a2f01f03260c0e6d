/* test_stats_edges.c - the statistics (survey/stats.c) where the geometry and the classes have
 * edges: cells, boxes and circles across the antimeridian, a box of the whole world, a radius of
 * 2,000 km (where an error of the haversine's latitudes shows), --by survey when the two surveys
 * share a light site, and the class and flag boundaries (15 deg of a six-phase class, n/3 = 5).
 * Oracles: lights placed by the spherical destination-point formula at known distances and
 * offsets (their cells and circles known by construction), and the documented boundaries
 * (docs/survey-db.md, "Statistics"). */
#include "survey/survey.h"
#include "tests/fixtures.h"
#include "tests/survey_fixture.h"
#include "tests/test.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define D2R (M_PI / 180.0)

/* The point at distance dist_m and azimuth az_deg from (lat, lon) on the sphere of radius
 * GIS_EARTH_RADIUS_M, longitude wrapped to [-180, 180). */
static void destination(double lat, double lon, double dist_m, double az_deg, double *lat2, double *lon2)
{
    double d = dist_m / GIS_EARTH_RADIUS_M, la1 = lat * D2R, az = az_deg * D2R;
    double la2 = asin(sin(la1) * cos(d) + cos(la1) * sin(d) * cos(az));
    double lo2 = lon * D2R + atan2(sin(az) * sin(d) * cos(la1), cos(d) - sin(la1) * sin(la2));
    *lat2 = la2 / D2R;
    *lon2 = fmod(lo2 / D2R + 540.0, 360.0) - 180.0;
}

/* One capture of survey sid: n lights at (lat, lon), phases ph (NULL: all 0), 1 m ellipses. */
static void add_located(srv_db *db, int64_t sid, const char *key, const double *lat, const double *lon,
                        const double *ph, int n)
{
    srv_light_row *l = calloc((size_t)n, sizeof *l);
    srv_location_row *loc = calloc((size_t)n, sizeof *loc);
    for (int i = 0; i < n; i++) {
        l[i] = survey_fx_light(i, 10.0 * i, 10.0, ph ? ph[i] : 0.0, 0.99);
        srv_location_row_init(&loc[i]);
        loc[i].method = SRV_LOC_ONE_STATION;
        loc[i].lat_deg = lat[i];
        loc[i].lon_deg = lon[i];
        loc[i].ellipse = (gis_ellipse){1.0, 1.0, 0.0};
    }
    srv_capture_data cd = survey_fx_capture(sid, key, l, loc, (size_t)n);
    CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    free(l);
    free(loc);
}

/* srv_stats_compute of db by `by` (NULL: all) and the box bbox (NULL: none). */
static srv_phase_stats *stats_of(srv_db *db, const char *by, const double *bbox, size_t *n)
{
    srv_stats_opts o;
    srv_stats_opts_default(&o);
    if (by) CHECK_OK(srv_stats_parse_by(by, &o));
    if (bbox) memcpy(o.bbox, bbox, sizeof o.bbox);
    srv_phase_stats *g = NULL;
    *n = 0;
    CHECK_OK(srv_stats_compute(db, &o, &g, n, NULL));
    return g;
}

/* The lights of one group (-1 when absent). */
static long group_lights(const srv_phase_stats *g, size_t n, const char *name)
{
    for (size_t i = 0; i < n; i++)
        if (!strcmp(g[i].group, name)) return g[i].lights;
    return -1;
}

/* Four 100 m cells around a centre on the antimeridian (17 deg S, Fiji), cell c holding 3 + c
 * lights 50 m east or west and north or south of it: the same cells as anywhere else, and
 * boxes and circles across 180 deg hold them all. */
TEST(stats_cells_boxes_and_circles_across_the_antimeridian)
{
    int64_t sid;
    srv_db *db = survey_fx_create(fx_tmp("fiji.sqlite"), "fiji", &sid);
    if (!db) return;
    const double lat0 = -17.0, lon0 = 180.0, cx[4] = {-50, 50, -50, 50}, cy[4] = {-50, -50, 50, 50};
    double lat[18], lon[18], ph[18];
    int n = 0;
    for (int c = 0; c < 4; c++)
        for (int k = 0; k < 3 + c; k++, n++) {
            double dx = cx[c] + (k - 1) * 5.0 * (c % 2 ? 1 : -1), dy = cy[c];   /* symmetric: mean at the centre */
            double e_lat, e_lon;
            destination(lat0, lon0, fabs(dx), dx < 0 ? 270.0 : 90.0, &e_lat, &e_lon);
            lat[n] = lat0 + dy / GIS_EARTH_RADIUS_M / D2R;
            lon[n] = e_lon;
            ph[n] = 120.0 * (c % 3);
        }
    add_located(db, sid, "c", lat, lon, ph, n);
    size_t ng = 0;
    srv_phase_stats *g = stats_of(db, "cell:100", NULL, &ng);
    static const char *const want[4] = {"-1,-1", "0,-1", "-1,0", "0,0"};
    CHECK_MSG(ng == 4, "%zu cells", ng);
    for (int c = 0; c < 4; c++) CHECK_MSG(group_lights(g, ng, want[c]) == 3 + c, "cell %s", want[c]);
    free(g);
    /* a box across the antimeridian (MINLON > MAXLON) holds all; one beside it none */
    const double across[4] = {179.99, lat0 - 0.01, -179.99, lat0 + 0.01}, beside[4] = {179.0, lat0 - 0.01, 179.5, lat0 + 0.01};
    g = stats_of(db, NULL, across, &ng);
    CHECK(ng == 1 && g[0].lights == n);
    free(g);
    g = stats_of(db, NULL, beside, &ng);
    CHECK(ng == 1 && g[0].lights == 0);
    free(g);
    /* the whole world: -180 .. 180 (after wrapping both ends are -180) */
    const double world[4] = {-180.0, -90.0, 180.0, 90.0};
    g = stats_of(db, NULL, world, &ng);
    CHECK_MSG(ng == 1 && g[0].lights == n, "whole world: %ld lights", ng ? g[0].lights : -1);
    free(g);
    /* a circle of 100 m around the centre, given as 180 or -180 (the farthest light: 55 x 50 m) */
    g = stats_of(db, "radius:-17,180,100", NULL, &ng);
    CHECK(ng == 1 && g[0].lights == n);
    free(g);
    g = stats_of(db, "radius:-17,-180,100", NULL, &ng);
    CHECK(ng == 1 && g[0].lights == n);
    free(g);
    srv_db_close(db);
}

/* Lights 1 % inside and outside a 2,000 km circle at 50 deg N, every 30 deg of azimuth: the
 * circle holds exactly the inner ones (a haversine with the wrong latitude's cosine misplaces
 * the northern and southern ones by several per cent). */
TEST(stats_radius_of_2000_km_is_the_great_circle)
{
    int64_t sid;
    srv_db *db = survey_fx_create(fx_tmp("far.sqlite"), "far", &sid);
    if (!db) return;
    const double lat0 = 50.0, lon0 = 10.0, r = 2.0e6;
    double lat[24], lon[24], ph[24];
    for (int i = 0; i < 24; i++) {
        int outer = i >= 12;
        destination(lat0, lon0, r * (outer ? 1.01 : 0.99), 30.0 * (i % 12) + 15.0, &lat[i], &lon[i]);
        ph[i] = outer ? 240.0 : 0.0;
    }
    add_located(db, sid, "c", lat, lon, ph, 24);
    size_t ng = 0;
    srv_phase_stats *g = stats_of(db, "radius:50,10,2000000", NULL, &ng);
    CHECK_MSG(ng == 1 && g[0].lights == 12 && g[0].n[0] == 12 && g[0].n[2] == 0, "%ld lights, %ld on 240",
              ng ? g[0].lights : -1, ng ? g[0].n[2] : -1);
    free(g);
    srv_db_close(db);
}

/* --by survey over light sites: a site seen in both surveys counts once in each, with that
 * survey's own detections; here survey one's last site is survey two's first (so the rows of
 * the two surveys meet on the same site id). */
TEST(stats_by_survey_splits_a_shared_site)
{
    int64_t s1, s2;
    srv_db *db = survey_fx_create(fx_tmp("shared.sqlite"), "one", &s1);
    if (!db) return;
    srv_survey_row sr = {.name = "two", .grid_hz = 50};
    CHECK_OK(srv_db_add_survey(db, &sr, &s2));
    /* 10 lights 30 m apart on a line; survey one sees 0..5 on phase 0, survey two 5..9 on 120 */
    double lat[10], lon[10], ph0[10], ph1[10];
    for (int i = 0; i < 10; i++) {
        destination(32.8, 35.0, 30.0 * i, 90.0, &lat[i], &lon[i]);
        ph0[i] = 0.0;
        ph1[i] = 120.0;
    }
    add_located(db, s1, "a", lat, lon, ph0, 6);
    add_located(db, s2, "b", lat + 5, lon + 5, ph1, 5);
    sqlite3 *h = srv_db_sqlite(db);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM light_sites") == 10);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM light_sites WHERE detections = 2") == 1);
    size_t ng = 0;
    srv_phase_stats *g = stats_of(db, "survey", NULL, &ng);
    CHECK(ng == 2);
    for (size_t i = 0; i < ng; i++) {
        int two = !strcmp(g[i].group, "two");
        CHECK_MSG(g[i].lights == (two ? 5 : 6) && g[i].n[two] == g[i].lights && g[i].total == g[i].lights,
                  "survey %s: %ld lights, %ld / %ld / %ld", g[i].group, g[i].lights, g[i].n[0], g[i].n[1], g[i].n[2]);
    }
    free(g);
    srv_db_close(db);
}

/* The documented boundaries: a six-phase class takes phases within 15 deg of it (15 included);
 * a group is flagged few when n/3 < 5 (n = 15 is not). */
TEST(stats_six_phase_and_few_boundaries)
{
    int64_t sid;
    srv_db *db = survey_fx_create(fx_tmp("edge6.sqlite"), "edge6", &sid);
    if (!db) return;
    /* 15 deg above 30, 150, 270 (binary fractions: exact), 15.25 deg above two of them, and 15
     * deg below 150 and 270, which is within 20 deg of 120 and 240 (their classes) */
    static const double ph[] = {45.0, 165.0, 285.0, 45.25, 165.25, 135.0, 255.0};
    enum { N = sizeof ph / sizeof *ph };
    srv_light_row l[N];
    for (int i = 0; i < N; i++) l[i] = survey_fx_light(i, 10.0 * i, 1, ph[i], 0.99);
    srv_capture_data cd = survey_fx_capture(sid, "c", l, NULL, N);
    CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    size_t ng = 0;
    srv_phase_stats *g = stats_of(db, NULL, NULL, &ng);
    CHECK_MSG(ng == 1 && g[0].n30[0] == 1 && g[0].n30[1] == 1 && g[0].n30[2] == 1 && g[0].other == 2 &&
              g[0].n[0] == 0 && g[0].n[1] == 1 && g[0].n[2] == 1,
              "30/150/270: %ld %ld %ld, other %ld", g[0].n30[0], g[0].n30[1], g[0].n30[2], g[0].other);
    free(g);
    srv_db_close(db);
    for (long n = 12; n <= 18; n++) {
        srv_phase_stats s;
        memset(&s, 0, sizeof s);
        s.n[0] = n / 3 + (n % 3 > 0);
        s.n[1] = n / 3 + (n % 3 > 1);
        s.n[2] = n / 3;
        srv_phase_stats_finish(&s);
        CHECK_MSG(s.total == n && !!(s.flags & SRV_STATS_FEW) == (n < 15), "n = %ld: flags %d", n, s.flags);
    }
}
