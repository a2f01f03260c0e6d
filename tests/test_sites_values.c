/* test_sites_values.c - the numbers of light identity (survey/sites.c, docs/survey-db.md "Light
 * sites" and "Changes between surveys") that tests/test_sites.c does not pin: the stored
 * association distance, the candidate box, one detection per capture and site, the combined
 * ellipse's orientation and height, and compare's P(phase differs). Oracles written here: the
 * Mahalanobis distance of offsets placed in local metres, the information sum of two ellipses
 * with its orientation from the closed form 0.5 atan2(2 C_en, C_nn - C_ee), and each survey's
 * posterior over every label (the product of the detections', brute force) for
 * 1 - sum_l P_A(l) P_B(l). */
#include "survey/survey.h"
#include "tests/fixtures.h"
#include "tests/gis_fixture.h"
#include "tests/survey_fixture.h"
#include "tests/test.h"

#include <math.h>
#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define SQ(h, sql) survey_fx_query_long(h, sql)
/* Local metres per degree north (*n) and east (*e) at lat: WGS84's radii of curvature M and
 * N cos(lat), written out (the metres of the stored ellipses). */
static void m_per_deg(double lat, double *n, double *e)
{
    const double a = 6378137.0, f = 1.0 / 298.257223563, e2 = f * (2.0 - f);
    const double w = 1.0 - e2 * sin(lat * D2R) * sin(lat * D2R), N = a / sqrt(w);
    *n = N * (1.0 - e2) / w * D2R;
    *e = N * cos(lat * D2R) * D2R;
}

/* A located light east_m, north_m from (lat0, lon0) with a circular (a = b) or elliptic
 * ellipse, its location row in *loc. */
static srv_light_row located(int i, double lat0, double lon0, double east_m, double north_m, double a,
                             double b, double az, double height_m, srv_location_row *loc)
{
    srv_light_row l = survey_fx_light(i, 20.0 * i, 10.0, 0.0, 0.9);
    srv_location_row_init(loc);
    loc->method = SRV_LOC_ONE_STATION;
    double kn, ke;
    m_per_deg(lat0, &kn, &ke);
    loc->lat_deg = lat0 + north_m / kn;
    loc->lon_deg = lon0 + east_m / ke;
    loc->height_m = height_m;
    loc->ellipse = (gis_ellipse){a, b, az};
    return l;
}

static double query_real(sqlite3 *h, const char *fmt, long long id)
{
    char sql[256];
    snprintf(sql, sizeof sql, fmt, id);
    sqlite3_stmt *q = NULL;
    double v = NAN;
    if (sqlite3_prepare_v2(h, sql, -1, &q, NULL) == SQLITE_OK && sqlite3_step(q) == SQLITE_ROW &&
        sqlite3_column_type(q, 0) != SQLITE_NULL)
        v = sqlite3_column_double(q, 0);
    sqlite3_finalize(q);
    return v;
}

/* At 60 deg north (a degree of longitude is half a degree of latitude): a site L0 with a 2 m
 * circle and a wide one L1 (100 m circle) 1 km north. The next capture's D0, 3 m east of L0 (2 m
 * circle), is at d2 = 9 / (4 + 4) = 1.125 (4.5 if the east offset were taken in degrees of
 * latitude); D0b, 5 m north of L0 (d2 3.125), is a candidate of the same site but the site
 * takes one detection of a capture, the nearer: D0b founds a site; D2, 60 m north of L1 (1 m
 * circle), is at d2 = 3600 / 10001, found only when the candidate box is widened by the
 * widest site ellipse (its own gives 3.8 m). A light added to that capture later (associated
 * by srv_db_associate) 1 m west of L0 founds a site: the sites near it hold a detection of
 * that capture. */
TEST(sites_association_distance_box_one_per_capture)
{
    const double lat0 = 60.0, lon0 = 10.0;
    int64_t sid;
    srv_db *db = survey_fx_create(fx_tmp("assoc.sqlite"), "s", &sid);
    if (!db) return;
    sqlite3 *h = srv_db_sqlite(db);
    srv_light_row l[3];
    srv_location_row loc[3];
    l[0] = located(0, lat0, lon0, 0.0, 0.0, 2.0, 2.0, 0.0, 10.0, &loc[0]);
    l[1] = located(1, lat0, lon0, 0.0, 1000.0, 100.0, 100.0, 0.0, 10.0, &loc[1]);
    srv_capture_data c1 = survey_fx_capture(sid, "c1", l, loc, 2);
    CHECK_OK(srv_db_add_capture(db, &c1, NULL, NULL));
    l[0] = located(0, lat0, lon0, 3.0, 0.0, 2.0, 2.0, 0.0, 10.0, &loc[0]);      /* D0 */
    l[1] = located(1, lat0, lon0, 0.0, 5.0, 2.0, 2.0, 0.0, 10.0, &loc[1]);      /* D0b */
    l[2] = located(2, lat0, lon0, 0.0, 1060.0, 1.0, 1.0, 0.0, 10.0, &loc[2]);   /* D2 */
    srv_capture_data c2 = survey_fx_capture(sid, "c2", l, loc, 3);
    CHECK_OK(srv_db_add_capture(db, &c2, NULL, NULL));
    /* sites by founding light: L0 = light 1, L1 = light 2 */
    const char *site_of = "SELECT site_id FROM site_detections sd JOIN lights l ON l.id = sd.light_id "
                          "JOIN captures c ON c.id = l.capture_id WHERE c.capture_key = '%s' AND l.light_index = %d";
    char sql[400];
    long s[2][3];
    for (int k = 0; k < 2; k++)
        for (int i = 0; i < 3 - (k == 0); i++) {
            snprintf(sql, sizeof sql, site_of, k ? "c2" : "c1", i);
            s[k][i] = SQ(h, sql);
        }
    CHECK_MSG(s[1][0] == s[0][0], "D0 in site %ld, L0's is %ld", s[1][0], s[0][0]);
    CHECK_MSG(s[1][1] != s[0][0] && s[1][1] != s[0][1], "D0b in site %ld (L0 %ld, L1 %ld)", s[1][1], s[0][0],
              s[0][1]);
    CHECK_MSG(s[1][2] == s[0][1], "D2 in site %ld, L1's is %ld", s[1][2], s[0][1]);
    CHECK(SQ(h, "SELECT count(*) FROM light_sites") == 3);
    const char *d2_of = "SELECT sd.d2 FROM site_detections sd JOIN lights l ON l.id = sd.light_id "
                        "JOIN captures c ON c.id = l.capture_id WHERE c.capture_key = 'c2' AND l.light_index = %lld";
    double d2[3] = {query_real(h, d2_of, 0), query_real(h, d2_of, 1), query_real(h, d2_of, 2)};
    CHECK_MSG(fabs(d2[0] - 9.0 / 8.0) < 1e-9, "D0: d2 %.12g, expected 1.125", d2[0]);
    CHECK_MSG(isnan(d2[1]), "D0b: d2 %.12g, expected NULL (a site of its own)", d2[1]);
    /* (60 m placed in the metres of 60 deg N, 1 km south: M differs by 1.6e-6 there, d2 by 3e-6) */
    CHECK_MSG(fabs(d2[2] - 3600.0 / 10001.0) < 2e-6, "D2: d2 %.12g, expected %.12g", d2[2], 3600.0 / 10001.0);
    /* a light of c2 stored after its association, 1 m west of L0: within the gate of L0's site
     * (d2 = 2.5^2 / (2 + 4), the site now at 1.5 m east with a 1.41 m circle) and of D0b's
     * (26 / 8), but both hold a detection of c2, so it founds a site */
    srv_light_row late = located(3, lat0, lon0, -1.0, 0.0, 2.0, 2.0, 0.0, 10.0, &loc[0]);
    int64_t cid = SQ(h, "SELECT id FROM captures WHERE capture_key = 'c2'"), lid = 0;
    CHECK_OK(srv_db_begin(db));
    CHECK_OK(srv_db_insert_light(db, cid, &late, &lid));
    CHECK_OK(srv_db_insert_location(db, lid, &loc[0]));
    CHECK_OK(srv_db_commit(db));
    long created = -1, joined = -1;
    CHECK_OK(srv_db_associate(db, &created, &joined, NULL));
    CHECK_MSG(created == 1 && joined == 0, "created %ld, joined %ld", created, joined);
    snprintf(sql, sizeof sql, "SELECT s.detections FROM site_detections sd JOIN light_sites s ON s.id = "
             "sd.site_id WHERE sd.light_id = %lld AND sd.d2 IS NULL", (long long)lid);
    CHECK(SQ(h, sql) == 1 && SQ(h, "SELECT count(*) FROM light_sites") == 4);
    CHECK(SQ(h, "SELECT count(*) FROM (SELECT 1 FROM site_detections GROUP BY site_id, capture_id "
                "HAVING count(*) > 1)") == 0);
    srv_db_close(db);
}

/* Two detections of one light (1 m apart at 45 deg north), ellipses 3 x 1 m at 30 deg and
 * 2.5 x 0.8 m at 110 deg, heights 10 m and none: the site's ellipse is that of
 * (C_1^-1 + C_2^-1)^-1, its orientation 0.5 atan2(2 C_en, C_nn - C_ee) (mod 180), its height
 * the one known (10 m). Two detections without a location (a pixel site) have no height. */
TEST(sites_combined_ellipse_azimuth_and_height)
{
    const double lat0 = 45.0, lon0 = 7.0;
    int64_t sid;
    srv_db *db = survey_fx_create(fx_tmp("ellipse.sqlite"), "s", &sid);
    if (!db) return;
    sqlite3 *h = srv_db_sqlite(db);
    const gis_ellipse e[2] = {{3.0, 1.0, 30.0}, {2.5, 0.8, 110.0}};
    const double east[2] = {0.0, 1.0}, height[2] = {10.0, NAN};
    for (int k = 0; k < 2; k++) {
        srv_light_row l[2];
        srv_location_row loc[2];
        l[0] = located(0, lat0, lon0, east[k], 0.0, e[k].semi_major_m, e[k].semi_minor_m, e[k].azimuth_deg,
                       height[k], &loc[0]);
        l[1] = survey_fx_light(1, 300.0, 200.0, 0.0, 0.9);   /* no location: a pixel site */
        srv_location_row_init(&loc[1]);
        srv_capture_data cd = survey_fx_capture(sid, k ? "n2" : "n1", l, loc, 2);
        CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    }
    CHECK(SQ(h, "SELECT count(*) FROM light_sites WHERE detections = 2") == 2 &&
          SQ(h, "SELECT count(*) FROM light_sites") == 2);
    /* the information sum */
    double I[3] = {0, 0, 0}, ie = 0, in = 0;
    for (int k = 0; k < 2; k++) {
        double C[3];
        gisfx_ellipse_cov(&e[k], C);
        double det = C[0] * C[2] - C[1] * C[1], Ii[3] = {C[2] / det, -C[1] / det, C[0] / det};
        for (int j = 0; j < 3; j++) I[j] += Ii[j];
        ie += Ii[0] * east[k];
        in += Ii[1] * east[k];
    }
    double det = I[0] * I[2] - I[1] * I[1], C[3] = {I[2] / det, -I[1] / det, I[0] / det};
    double tr = C[0] + C[2], disc = sqrt(0.25 * (C[0] - C[2]) * (C[0] - C[2]) + C[1] * C[1]);
    double a = sqrt(0.5 * tr + disc), b = sqrt(0.5 * tr - disc);
    double az = 0.5 * atan2(2.0 * C[1], C[2] - C[0]) / D2R;
    if (az < 0.0) az += 180.0;
    double x_e = C[0] * ie + C[1] * in, x_n = C[1] * ie + C[2] * in;
    sqlite3_stmt *q = NULL;
    CHECK(sqlite3_prepare_v2(h, "SELECT semi_major_m, semi_minor_m, azimuth_deg, height_m, lat_deg, lon_deg "
                                "FROM light_sites WHERE lat_deg IS NOT NULL", -1, &q, NULL) == SQLITE_OK);
    CHECK(q && sqlite3_step(q) == SQLITE_ROW);
    double got_az = sqlite3_column_double(q, 2);
    CHECK_MSG(fabs(sqlite3_column_double(q, 0) - a) < 1e-9 && fabs(sqlite3_column_double(q, 1) - b) < 1e-9,
              "axes %.9f x %.9f, expected %.9f x %.9f", sqlite3_column_double(q, 0), sqlite3_column_double(q, 1), a, b);
    CHECK_MSG(fabs(got_az - az) < 1e-7, "azimuth %.9f, expected %.9f", got_az, az);
    CHECK_MSG(sqlite3_column_type(q, 3) != SQLITE_NULL && fabs(sqlite3_column_double(q, 3) - 10.0) < 1e-12,
              "height %s, expected 10 (the one detection with a height)", sqlite3_column_text(q, 3));
    double kn, ke;
    m_per_deg(lat0, &kn, &ke);
    CHECK_NEAR((sqlite3_column_double(q, 4) - lat0) * kn, x_n, 1e-6);
    CHECK_NEAR((sqlite3_column_double(q, 5) - lon0) * ke, x_e, 1e-6);
    sqlite3_finalize(q);
    CHECK_MSG(SQ(h, "SELECT count(*) FROM light_sites WHERE lat_deg IS NULL AND height_m IS NULL") == 1,
              "the pixel site's height: %s", survey_fx_query_text(h, "SELECT quote(height_m) FROM light_sites "
                                                                     "WHERE lat_deg IS NULL"));
    srv_db_close(db);
}

/* ------------------------------------------------------------------ compare */

/* Survey s's posterior over the labels, phases: P(l) proportional to the product over its
 * detections of c_i on its label and (1 - c_i) / (M - 1) on the others (docs/survey-db.md,
 * "Light sites"), every label l written out. */
static void posterior(const double *phase, const double *c, int n, int twelve, double *P)
{
    int M = twelve ? 12 : 3;
    double z = 0.0;
    for (int l = 0; l < M; l++) {
        P[l] = 1.0;
        for (int i = 0; i < n; i++) {
            int li = twelve ? (int)lround(phase[i] / 30.0) % 12 : (int)lround(phase[i] / 120.0) % 3;
            P[l] *= li == l ? c[i] : (1.0 - c[i]) / (M - 1);
        }
        z += P[l];
    }
    for (int l = 0; l < M; l++) P[l] /= z;
}

/* Six pixel sites seen twice in survey a and once in survey b (phase confidences c), against
 * P(phase differs) = 1 - sum_l P_a(l) P_b(l): the same winner (0 deg; 150 deg of twelve),
 * reported for their bulb change, and different winners (0 vs 120; 30 vs 90 of twelve; 0 of
 * three in a vs 150 of twelve in b, each side's posterior over its own labels: a's three classes
 * are the labels 0, 120, 240 of b's twelve; it spread a's three-class confidence over twelve:
 * 0.951 for 0.964; 30 of twelve in a, its phase 18 deg, vs 0 of three in b: different labels,
 * a phase change, although 18 deg is in the class 0: it was judged the same winner, no change
 * at P 0.99; a's 150 deg at confidence 1/12 says nothing, so its posterior is the other's). At
 * --min-p 0.5 the same winner is no phase change although P >= 0.5. */
TEST(sites_compare_phase_change_probabilities)
{
    int64_t sid[2];
    srv_db *db = survey_fx_create(fx_tmp("pcmp.sqlite"), "a", &sid[0]);
    if (!db) return;
    srv_survey_row sb = {"b", NULL, NULL, NULL, 50};
    CHECK_OK(srv_db_add_survey(db, &sb, &sid[1]));
    enum { NS = 6 };
    static const struct {
        double x, phase[3], c[3];   /* a1, a2, b1 */
        const char *bulb_b;
        int twelve_a, twelve_b;
    } S[NS] = {
        {100, {0, 0, 0}, {0.6, 0.7, 0.5}, "q", 0, 0},
        {200, {0, 0, 120}, {0.8, 0.6, 0.9}, "p", 0, 0},
        {300, {29, 31, 90}, {0.9, 0.8, 0.7}, "p", 1, 1},
        {400, {150, 150, 151}, {0.6, 0.5, 0.4}, "q", 1, 1},
        {500, {0, 0, 150}, {0.6, 0.5, 0.6}, "p", 0, 1},
        {600, {18, 150, 0}, {0.9, 1.0 / 12.0, 0.9}, "p", 1, 0},
    };
    static const char *const keys[3] = {"a1", "a2", "b1"};
    for (int k = 0; k < 3; k++) {
        srv_light_row l[NS];
        for (int i = 0; i < NS; i++) {
            l[i] = survey_fx_light(i, S[i].x, 50.0, S[i].phase[k], S[i].c[k]);
            l[i].bulb_id = k == 2 ? S[i].bulb_b : "p";
            l[i].technology = "led_linear";
            l[i].bulb_confidence = 0.99;
            l[i].phase_sigma_deg = 2.0;
        }
        srv_capture_data cd = survey_fx_capture(sid[k == 2], keys[k], l, NULL, NS);
        CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    }
    CHECK(SQ(srv_db_sqlite(db), "SELECT count(*) FROM light_sites WHERE detections = 3") == NS);
    srv_change *ch = NULL;
    size_t nch = 0;
    srv_compare_totals t;
    CHECK_OK(srv_compare(db, "a", "b", 0.5, &ch, &nch, &t));
    CHECK_MSG(nch == NS, "%zu changes, expected %d", nch, NS);
    for (size_t j = 0; j < nch; j++) {
        int i = -1;
        for (int k = 0; k < NS; k++)
            if (fabs(ch[j].x_px - S[k].x) < 1e-9) i = k;
        if (i < 0) {
            test_failed(__FILE__, __LINE__, "a change at x %.1f", ch[j].x_px);
            continue;
        }
        double Pa[12], Pb[12], same = 0.0;
        posterior(S[i].phase, S[i].c, 2, S[i].twelve_a, Pa);
        posterior(S[i].phase + 2, S[i].c + 2, 1, S[i].twelve_b, Pb);
        for (int l = 0; l < 12; l++) {   /* (three classes: the labels 0, 4, 8 of the twelve) */
            double pa = S[i].twelve_a ? Pa[l] : l % 4 ? 0.0 : Pa[l / 4];
            double pb = S[i].twelve_b ? Pb[l] : l % 4 ? 0.0 : Pb[l / 4];
            same += pa * pb;
        }
        CHECK_MSG(fabs(ch[j].p_phase_change - (1.0 - same)) < 1e-12, "site x %.0f: P(phase differs) %.15f, "
                  "expected %.15f", S[i].x, ch[j].p_phase_change, 1.0 - same);
        unsigned want = strcmp(S[i].bulb_b, "p") ? SRV_CHANGE_BULB : SRV_CHANGE_PHASE;
        CHECK_MSG(ch[j].kinds == want && 1.0 - same >= 0.5, "site x %.0f: kinds %#x, expected %#x (P %.3f)",
                  S[i].x, ch[j].kinds, want, 1.0 - same);
    }
    free(ch);
    srv_db_close(db);
}

/* One light on the 180 deg meridian (17 deg south, Fiji's longitude) detected on two nights
 * 0.2 m west and 0.2 m east of it (2 m circles): stored at +179.999998 and -179.999998, 0.4 m
 * apart, so d2 = 0.16 / (4 + 4) = 0.02 and one site at the meridian with axes 2 / sqrt(2); a
 * second light 3 m west, detected on the same nights 0.2 m either side of it, is the control
 * that never crosses the meridian. The candidate box of the first night's site ran from
 * 179.99998 to 180.00002 and missed the site stored at -179.999998: two sites of one light. */
TEST(sites_one_light_across_the_antimeridian)
{
    const double lat0 = -17.0, lon0 = 180.0;
    int64_t sid;
    srv_db *db = survey_fx_create(fx_tmp("antimeridian.sqlite"), "s", &sid);
    if (!db) return;
    sqlite3 *h = srv_db_sqlite(db);
    for (int k = 0; k < 2; k++) {
        double side = k ? 0.2 : -0.2;
        srv_light_row l[2];
        srv_location_row loc[2];
        l[0] = located(0, lat0, lon0, side, 0.0, 2.0, 2.0, 0.0, 10.0, &loc[0]);
        l[1] = located(1, lat0, lon0, -3.0 + side, 0.0, 2.0, 2.0, 0.0, 10.0, &loc[1]);
        srv_capture_data cd = survey_fx_capture(sid, k ? "n2" : "n1", l, loc, 2);
        CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    }
    CHECK(SQ(h, "SELECT count(*) FROM locations WHERE lon_deg < 0") == 1);   /* both sides stored */
    long sites = SQ(h, "SELECT count(*) FROM light_sites");
    CHECK_MSG(sites == 2 && SQ(h, "SELECT count(*) FROM light_sites WHERE detections = 2") == 2,
              "%ld sites (expected 2 of 2 detections each)", sites);
    const char *d2_of = "SELECT sd.d2 FROM site_detections sd JOIN lights l ON l.id = sd.light_id "
                        "JOIN captures c ON c.id = l.capture_id WHERE c.capture_key = 'n2' AND l.light_index = %lld";
    for (long long i = 0; i < 2; i++) {
        double d2 = query_real(h, d2_of, i);
        CHECK_MSG(fabs(d2 - 0.02) < 1e-9, "light %lld: d2 %.12g, expected 0.02", i, d2);
    }
    /* the site of the first light: at the meridian (+-180), axes 2 / sqrt(2) */
    double lon = query_real(h, "SELECT lon_deg FROM light_sites WHERE abs(lon_deg) > 179.99999 AND %lld", 1);
    double lat = query_real(h, "SELECT lat_deg FROM light_sites WHERE abs(lon_deg) > 179.99999 AND %lld", 1);
    double kn, ke;
    m_per_deg(lat0, &kn, &ke);
    double east = (180.0 - fabs(lon)) * ke;
    CHECK_MSG(fabs(east) < 1e-6 && fabs(lat - lat0) * kn < 1e-6, "site at %.9f, %.9f: %.3g m from the "
              "meridian", lat, lon, east);
    double a = query_real(h, "SELECT semi_major_m FROM light_sites WHERE abs(lon_deg) > 179.99999 AND %lld", 1);
    CHECK_MSG(fabs(a - sqrt(2.0)) < 1e-9, "axis %.12g, expected sqrt(2)", a);
    srv_db_close(db);
}

/* Two stations' detections of one light at 45 deg N, each 1 mm wide across its sight line and
 * 15 m long along it (a one-station location at a wrong height), 15 m and 12 m from the light
 * along sight lines at azimuths 30 and 150 deg: the site is their crossing, the light. The
 * offsets are placed here in WGS84 local metres (m_per_deg), as gis_locate's ellipses are. The site's metres were those
 * of the mean sphere, 0.3 % short north-south and 0.2 % east-west at 45 deg: the lines crossed
 * 3.9 cm from the light, 30-50 sigma of the site's 1.4 x 0.8 mm ellipse. */
TEST(sites_two_sight_lines_cross_at_the_light)
{
    const double lat0 = 45.0, lon0 = 7.0;
    double kn, ke;
    m_per_deg(lat0, &kn, &ke);
    int64_t sid;
    srv_db *db = survey_fx_create(fx_tmp("crossing.sqlite"), "s", &sid);
    if (!db) return;
    sqlite3 *h = srv_db_sqlite(db);
    const double az[2] = {30.0, 150.0}, along[2] = {15.0, -12.0};
    for (int k = 0; k < 2; k++) {
        srv_light_row l = survey_fx_light(0, 100.0, 100.0, 0.0, 0.9);
        srv_location_row loc;
        srv_location_row_init(&loc);
        loc.method = SRV_LOC_ONE_STATION;
        loc.lat_deg = lat0 + along[k] * cos(az[k] * D2R) / kn;
        loc.lon_deg = lon0 + along[k] * sin(az[k] * D2R) / ke;
        loc.height_m = 10.0;
        loc.ellipse = (gis_ellipse){15.0, 0.001, az[k]};
        srv_capture_data cd = survey_fx_capture(sid, k ? "west" : "east", &l, &loc, 1);
        CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    }
    CHECK(SQ(h, "SELECT count(*) FROM light_sites") == 1);
    double lat = query_real(h, "SELECT lat_deg FROM light_sites WHERE id = %lld", 1);
    double lon = query_real(h, "SELECT lon_deg FROM light_sites WHERE id = %lld", 1);
    double a = query_real(h, "SELECT semi_major_m FROM light_sites WHERE id = %lld", 1);
    double b = query_real(h, "SELECT semi_minor_m FROM light_sites WHERE id = %lld", 1);
    double de = (lon - lon0) * ke, dn = (lat - lat0) * kn;
    CHECK_MSG(hypot(de, dn) < 1e-4 && b > 5e-4 && a < 2e-3, "site %.3f mm east, %.3f mm north of the light, "
              "ellipse %.3f x %.3f mm", 1e3 * de, 1e3 * dn, 1e3 * a, 1e3 * b);
    srv_db_close(db);
}
