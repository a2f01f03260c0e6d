/* test_sites_poses.c - one light, located on one night and not on another (docs/survey-db.md
 * "Light sites"): a detection of the same camera pose and pixel joins the site whether or not
 * the site or the detection is located, so the site count is the light count in any order of
 * the captures. Oracles: the generating truth (which light each detection came from), the
 * information-weighted mean of two circular position errors written out, and every order of
 * the captures associated from scratch (their partitions must all be the truth's). A pose key
 * longer than any fixed buffer is not cut. */
#include "survey/internal.h"
#include "survey/survey.h"
#include "tests/fixtures.h"
#include "tests/survey_fixture.h"
#include "tests/test.h"

#include <math.h>
#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define SQ(h, sql) survey_fx_query_long(h, sql)

enum { NL = 24, NCAP = 4 };
static const double LAT0 = 32.8, LON0 = 35.0, SIGMA_P_M = 1.0, SIGMA_Q_M = 1.5, NOISE_PX = 0.3;

typedef struct {
    double east_m, north_m, h_m, lat, lon, px[2][2];   /* px[pose][x, y] */
} truth_light;

/* Two roofs looking at the lights from the west (P) and the east (Q), 600 m apart. */
static gis_camera roof(int q)
{
    gis_camera c;
    memset(&c, 0, sizeof c);
    double kn, ke;
    gis_metres_per_deg(LAT0, &kn, &ke);
    c.lat_deg = LAT0;
    c.lon_deg = LON0 + (q ? 600.0 : 0.0) / ke;
    c.height_m = 10.0;
    c.heading_deg = q ? 270.0 : 90.0;
    c.pitch_deg = -2.0;
    c.focal_px = 2000.0;
    c.cx_px = 999.5;
    c.cy_px = 999.5;
    c.width_px = c.height_px = 2000;
    return c;
}

static void place(truth_light *t, double east_m, double north_m, double h_m)
{
    double kn, ke;
    gis_metres_per_deg(LAT0, &kn, &ke);
    t->east_m = east_m;
    t->north_m = north_m;
    t->h_m = h_m;
    t->lat = LAT0 + north_m / kn;
    t->lon = LON0 + east_m / ke;
    for (int q = 0; q < 2; q++) {
        gis_camera c = roof(q);
        int in_front = 0;
        CHECK_OK(gis_project(&c, t->lat, t->lon, t->h_m, &t->px[q][0], &t->px[q][1], &in_front));
        CHECK(in_front && gis_in_image(&c, t->px[q][0], t->px[q][1]));
    }
}

/* NL lights between the roofs (in both images): lights 0 and 1 on nearly one sight line of P,
 * 5 px apart from there (100 m apart on the ground; see seen()), the others at least 15 m (10 sigma of the located
 * ellipses) and 8 px (from both roofs) from each other. */
static void make_truth(truth_light *t)
{
    place(&t[0], 200.0, 10.0, 7.0);
    place(&t[1], 300.0, 15.0 + 300.0 * 5.0 / 2000.0, 5.5);   /* 1.5 times as far, 5 px north */
    uint64_t rng = 7;
    for (int n = 2; n < NL;) {
        place(&t[n], 200.0 + 200.0 * gs_splitmix_uniform(&rng), -70.0 + 140.0 * gs_splitmix_uniform(&rng),
              5.0 + 4.0 * gs_splitmix_uniform(&rng));
        int ok = 1;
        for (int k = 0; k < n && ok; k++) {
            ok = hypot(t[n].east_m - t[k].east_m, t[n].north_m - t[k].north_m) > 15.0;
            for (int q = 0; q < 2 && ok; q++)
                ok = hypot(t[n].px[q][0] - t[k].px[q][0], t[n].px[q][1] - t[k].px[q][1]) > 8.0;
        }
        n += ok;
    }
}

/* Whether capture c sees light i: light 1 only in july from P (hidden from Q, new in july), where
 * light 0 is not seen (off that night): the two never share a capture, so only the pixel gate
 * (3 px) keeps them apart. */
static int seen(int c, int i)
{
    return i == 1 ? c == 1 : !(i == 0 && c == 1);
}

/* Capture c: 0 located from P (survey june), 1 unlocated from P (july: no second station, no
 * height prior, an unbounded ellipse with a position and a height), 2 located from Q (june), 3 unlocated from Q (july: no
 * location row). Its lights in a shuffled order, order[k] = the truth light of light k (NL - 1
 * of them). */
static const char *const cap_key[NCAP] = {"june-p", "july-p", "june-q", "july-q"};

static void add_capture(srv_db *db, const int64_t survey[2], int64_t station[2][2], int c,
                        const truth_light *t, int *order, int resume)
{
    srv_light_row l[NL];
    srv_location_row loc[NL];
    int q = c / 2, located = c % 2 == 0;
    uint64_t rng = 100 + (uint64_t)c;
    int n = 0;
    for (int i = 0; i < NL; i++)
        if (seen(c, i)) order[n++] = i;
    for (int i = n - 1; i > 0; i--) {
        int j = (int)(gs_splitmix64(&rng) % (uint64_t)(i + 1)), x = order[i];
        order[i] = order[j];
        order[j] = x;
    }
    double kn, ke, sigma = q ? SIGMA_Q_M : SIGMA_P_M;
    gis_metres_per_deg(LAT0, &kn, &ke);
    for (int k = 0; k < n; k++) {
        const truth_light *x = &t[order[k]];
        l[k] = survey_fx_light(k, x->px[q][0] + NOISE_PX * gs_splitmix_normal(&rng),
                               x->px[q][1] + NOISE_PX * gs_splitmix_normal(&rng), 120.0 * (order[k] % 3), 0.9);
        srv_location_row_init(&loc[k]);
        loc[k].method = SRV_LOC_ONE_STATION;
        if (located) {
            loc[k].lat_deg = x->lat + sigma * gs_splitmix_normal(&rng) / kn;
            loc[k].lon_deg = x->lon + sigma * gs_splitmix_normal(&rng) / ke;
            loc[k].height_m = x->h_m;
            loc[k].ellipse = (gis_ellipse){sigma, sigma, 0.0};
        } else {   /* unbounded (no height prior): a point 50 m off, a height, infinite axes */
            loc[k].lat_deg = x->lat + 50.0 / kn;
            loc[k].lon_deg = x->lon;
            loc[k].height_m = 99.0;
            loc[k].ellipse = (gis_ellipse){INFINITY, INFINITY, 0.0};
        }
    }
    srv_capture_data cd = survey_fx_capture(survey[!located], cap_key[c], l, c == 3 ? NULL : loc, (size_t)n);
    cd.capture.station_id = station[!located][q];
    if (!resume) {
        CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
        return;
    }
    /* the rows alone, as a file of schema 2 holds them (srv_db_associate, run by `db migrate`,
     * associates them later) */
    int64_t cid = 0, lid = 0;
    CHECK_OK(srv_db_begin(db));
    CHECK_OK(srv_db_insert_capture(db, &cd.capture, cd.n_lights, 0, 0, &cid));
    for (size_t k = 0; k < cd.n_lights; k++) {
        CHECK_OK(srv_db_insert_light(db, cid, &l[k], &lid));
        if (cd.locations) CHECK_OK(srv_db_insert_location(db, lid, &loc[k]));
    }
    CHECK_OK(srv_db_commit(db));
}

/* A database of the two surveys and both roofs in each (the same cameras: the same poses). */
static srv_db *create(const char *name, int64_t survey[2], int64_t station[2][2])
{
    srv_db *db = survey_fx_create(fx_tmp(name), "june", &survey[0]);
    if (!db) return NULL;
    srv_survey_row sr = {.name = "july"};
    CHECK_OK(srv_db_add_survey(db, &sr, &survey[1]));
    for (int s = 0; s < 2; s++)
        for (int q = 0; q < 2; q++) {
            srv_station_row r;
            srv_station_row_init(&r);
            r.survey_id = survey[s];
            r.name = q ? "roof-q" : "roof-p";
            r.cam = roof(q);
            r.cam.sigma_heading_deg = r.cam.sigma_pitch_deg = r.cam.sigma_roll_deg = 0.0;
            r.sigma_px = NOISE_PX;
            CHECK_OK(srv_db_add_station(db, &r, &station[s][q]));
        }
    return db;
}

/* Checks that the sites are the truth's partition: every site's detections come from one
 * truth light and every truth light's from one site (site[c][i]: capture c's detection of
 * truth light i, 0 when not seen). Returns the number of sites. */
static long check_partition(sqlite3 *h, int orders[NCAP][NL], const char *label)
{
    int64_t site[NCAP][NL];
    memset(site, 0, sizeof site);
    sqlite3_stmt *q = NULL;
    CHECK(sqlite3_prepare_v2(h, "SELECT c.capture_key, l.light_index, sd.site_id FROM site_detections sd "
                                "JOIN lights l ON l.id = sd.light_id JOIN captures c ON c.id = l.capture_id",
                             -1, &q, NULL) == SQLITE_OK);
    while (q && sqlite3_step(q) == SQLITE_ROW) {
        const char *key = (const char *)sqlite3_column_text(q, 0);
        int k = sqlite3_column_int(q, 1);
        for (int c = 0; c < NCAP; c++)
            if (!strcmp(key, cap_key[c])) site[c][orders[c][k]] = sqlite3_column_int64(q, 2);
    }
    sqlite3_finalize(q);
    int wrong = 0;
    for (int i = 0; i < NL; i++)
        for (int c = 0; c < NCAP; c++) {
            if (!seen(c, i)) continue;
            int c0 = i == 1;   /* the first capture seeing light i */
            wrong += site[c][i] != site[c0][i];   /* one site per truth light ... */
            for (int j = 0; j < i; j++) wrong += site[c][i] == site[j == 1][j];   /* ... and per site */
        }
    CHECK_MSG(!wrong, "%s: %d detections in a site that is not their light's alone", label, wrong);
    return SQ(h, "SELECT count(*) FROM light_sites");
}

/* NL lights, each located in june from P and from Q and seen unlocated in july from both: NL
 * sites (3 NL - 3 before: june's located sites and one pixel site per roof for july),
 * whatever the order the four captures are associated in (all 24, each as it is added and by
 * srv_db_associate after all are stored, the resume of `db migrate`); light 1, seen in july from
 * P only, 5 px from where P saw light 0 in june (the pixel gate is 3 px), stays a pixel site of
 * its own; each other site's position and ellipse are the information-weighted mean of its two
 * located detections alone (circles of 1 and 1.5 m: x = (x_P / 1 + x_Q / 2.25) /
 * (1 + 1 / 2.25), axes 1 / sqrt(1 + 1 / 2.25)), its height theirs (not the 99 m of july's
 * unbounded fixes from P), and `stats` counts NL lights. */
TEST(sites_located_and_unlocated_nights_one_site)
{
    truth_light t[NL];
    make_truth(t);
    double dpair = hypot(t[0].px[0][0] - t[1].px[0][0], t[0].px[0][1] - t[1].px[0][1]);
    CHECK_MSG(dpair > 4.5 && dpair < 6.0, "lights 0 and 1 are %.2f px apart from P", dpair);
    int perm[NCAP] = {0, 1, 2, 3}, count = 0;
    for (int resume = 0;; resume = !resume) {
        char name[64], label[80];
        snprintf(name, sizeof name, "poses%d%d%d%d%d.sqlite", perm[0], perm[1], perm[2], perm[3], resume);
        snprintf(label, sizeof label, "order %s %s %s %s%s", cap_key[perm[0]], cap_key[perm[1]], cap_key[perm[2]],
                 cap_key[perm[3]], resume ? " (resumed)" : "");
        int64_t survey[2], station[2][2];
        srv_db *db = create(name, survey, station);
        if (!db) return;
        int orders[NCAP][NL];
        for (int k = 0; k < NCAP; k++) add_capture(db, survey, station, perm[k], t, orders[perm[k]], resume);
        sqlite3 *h = srv_db_sqlite(db);
        if (resume) {
            CHECK(SQ(h, "SELECT count(*) FROM light_sites") == 0);
            long created = -1, joined = -1, merged = -1;
            CHECK_OK(srv_db_associate(db, &created, &joined, &merged));
            /* `db migrate`'s counts: every detection founded or joined a site, and the sites
             * left are those founded less those merged away */
            CHECK_MSG(created + joined == SQ(h, "SELECT count(*) FROM lights") &&
                          created - merged == SQ(h, "SELECT count(*) FROM light_sites"),
                      "%s: created %ld, joined %ld, merged %ld", label, created, joined, merged);
        }
        long sites = check_partition(h, orders, label);
        CHECK_MSG(sites == NL, "%s: %ld sites for %d lights", label, sites, NL);
        CHECK(SQ(h, "SELECT count(*) FROM light_sites WHERE lat_deg IS NULL OR pose_key IS NOT NULL") == 1);
        srv_phase_stats st = survey_fx_stats_all(db, 0);
        CHECK_MSG(st.lights == NL, "%s: stats counts %ld lights", label, (long)st.lights);
        /* positions: the located detections' combination, the unlocated ones carry none */
        sqlite3_stmt *q = NULL;
        CHECK(sqlite3_prepare_v2(h, "SELECT s.lat_deg, s.lon_deg, s.semi_major_m, s.semi_minor_m, s.height_m, "
                                    "max(CASE WHEN c.capture_key = 'june-p' THEN loc.lat_deg END), "
                                    "max(CASE WHEN c.capture_key = 'june-p' THEN loc.lon_deg END), "
                                    "max(CASE WHEN c.capture_key = 'june-q' THEN loc.lat_deg END), "
                                    "max(CASE WHEN c.capture_key = 'june-q' THEN loc.lon_deg END), "
                                    "max(CASE WHEN c.capture_key = 'june-p' THEN loc.height_m END) "
                                    "FROM light_sites s JOIN site_detections sd ON sd.site_id = s.id "
                                    "JOIN lights l ON l.id = sd.light_id JOIN captures c ON c.id = l.capture_id "
                                    "LEFT JOIN locations loc ON loc.light_id = l.id WHERE s.lat_deg IS NOT NULL "
                                    "GROUP BY s.id",
                                 -1, &q, NULL) == SQLITE_OK);
        double kn, ke, wp = 1.0 / (SIGMA_P_M * SIGMA_P_M), wq = 1.0 / (SIGMA_Q_M * SIGMA_Q_M), worst = 0.0;
        gis_metres_per_deg(LAT0, &kn, &ke);
        int rows = 0;
        while (q && sqlite3_step(q) == SQLITE_ROW) {
            double v[10];
            for (int k = 0; k < 10; k++) v[k] = sqlite3_column_double(q, k);
            /* metres north and east of the P detection */
            double n = wq * (v[7] - v[5]) * kn / (wp + wq), e = wq * (v[8] - v[6]) * ke / (wp + wq);
            worst = fmax(worst, hypot((v[0] - v[5]) * kn - n, (v[1] - v[6]) * ke - e));
            worst = fmax(worst, fabs(v[2] - 1.0 / sqrt(wp + wq)) + fabs(v[3] - 1.0 / sqrt(wp + wq)));
            worst = fmax(worst, fabs(v[4] - v[9]));   /* june's height (both nights'), not july's 99 m */
            rows++;
        }
        sqlite3_finalize(q);
        CHECK(rows == NL - 1);
        CHECK_MSG(worst < 1e-6, "%s: a site's position, axes or height off the combination by %.3g m", label, worst);
        srv_db_close(db);
        count++;
        if (!resume) continue;
        /* the next permutation (lexicographic) */
        int i = NCAP - 2;
        while (i >= 0 && perm[i] > perm[i + 1]) i--;
        if (i < 0) break;
        int j = NCAP - 1;
        while (perm[j] < perm[i]) j--;
        int x = perm[i];
        perm[i] = perm[j];
        perm[j] = x;
        for (int a = i + 1, b = NCAP - 1; a < b; a++, b--) {
            x = perm[a];
            perm[a] = perm[b];
            perm[b] = x;
        }
    }
    CHECK(count == 48);
}

/* A located site whose located detections are deleted becomes a pixel site of its first
 * detection's pose, its light_sites pixel the mean over both roofs' july detections (a pixel of
 * neither pose); its views stay per pose. Storing the june captures again must rejoin every light
 * (the truth's partition, NL sites): each located detection finds its pixel site through the view
 * of its own pose. Before, a located detection looked at light_sites' pixel of the site's first
 * pose only, missed every such site and june's two located detections founded a second site
 * per light. */
TEST(sites_pixel_site_of_two_poses_found_by_its_views)
{
    truth_light t[NL];
    make_truth(t);
    int64_t survey[2], station[2][2];
    srv_db *db = create("poses_deleted.sqlite", survey, station);
    if (!db) return;
    int orders[NCAP][NL];
    for (int c = 0; c < NCAP; c++) add_capture(db, survey, station, c, t, orders[c], 0);
    sqlite3 *h = srv_db_sqlite(db);
    CHECK(check_partition(h, orders, "stored") == NL);
    int deleted = 0;
    CHECK_OK(srv_db_delete_capture(db, survey[0], cap_key[0], &deleted));
    CHECK(deleted == 1);
    CHECK_OK(srv_db_delete_capture(db, survey[0], cap_key[2], &deleted));
    CHECK(deleted == 1);
    CHECK_OK(srv_db_associate(db, NULL, NULL, NULL));
    /* every site a pixel site now; the NL - 2 seen from both roofs in july hold two poses */
    CHECK(SQ(h, "SELECT count(*) FROM light_sites WHERE pose_key IS NULL") == 0);
    CHECK(SQ(h, "SELECT count(*) FROM (SELECT site_id FROM site_views GROUP BY site_id HAVING count(*) = 2)") ==
          NL - 2);
    add_capture(db, survey, station, 0, t, orders[0], 0);
    add_capture(db, survey, station, 2, t, orders[2], 0);
    long sites = check_partition(h, orders, "june stored again");
    CHECK_MSG(sites == NL, "%ld sites for %d lights", sites, NL);
    srv_db_report r;
    CHECK_OK(srv_db_check(db, &r));
    CHECK(srv_db_report_ok(&r) && r.unassociated == 0);
    srv_db_close(db);
}

/* A camera pose's key holds its station's numbers as printed (survey/internal.h,
 * SRV_SQL_POSE_KEY): a roll of 1e250 deg (valid: gis_camera_check wraps angles) makes it 270
 * characters. Three nights of 12 unlocated lights from that roof are 12 sites of 3 detections:
 * the association kept a 200-byte copy of the key, so once a site's views were written again
 * from SQL (the full key) the third night's lookups (the cut copy) missed them, founding 12
 * more sites. */
TEST(sites_long_pose_key_not_cut)
{
    enum { N = 12 };
    int64_t survey = 0, station = 0;
    srv_db *db = survey_fx_create(fx_tmp("longpose.sqlite"), "nights", &survey);
    if (!db) return;
    srv_station_row r;
    srv_station_row_init(&r);
    r.survey_id = survey;
    r.name = "roof";
    r.cam = roof(0);
    r.cam.roll_deg = 1e250;
    CHECK_OK(srv_db_add_station(db, &r, &station));
    sqlite3 *h = srv_db_sqlite(db);
    CHECK_MSG(SQ(h, "SELECT length(" SRV_SQL_POSE_KEY("st") ") FROM stations st") > 250, "a short key");
    uint64_t rng = 3;
    for (int night = 0; night < 3; night++) {
        srv_light_row l[N];
        for (int k = 0; k < N; k++)
            l[k] = survey_fx_light(k, 100.0 + 40.0 * k + 0.3 * gs_splitmix_normal(&rng),
                                   500.0 + 0.3 * gs_splitmix_normal(&rng), 0.0, 0.9);
        char key[24];
        snprintf(key, sizeof key, "night%d", night);
        srv_capture_data cd = survey_fx_capture(survey, key, l, NULL, N);
        cd.capture.station_id = station;
        CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    }
    CHECK_MSG(SQ(h, "SELECT count(*) FROM light_sites") == N && SQ(h, "SELECT min(detections) FROM light_sites") == 3,
              "%ld sites, the least of %ld detections", SQ(h, "SELECT count(*) FROM light_sites"),
              SQ(h, "SELECT min(detections) FROM light_sites"));
    srv_db_close(db);
}
