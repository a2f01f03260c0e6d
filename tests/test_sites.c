/* test_sites.c - light identity (survey/sites.c, docs/survey-db.md "Light sites"): detections
 * of the same physical light on several nights form one site, statistics count sites, and the
 * combined posteriors and ellipses are narrower than each night's. Oracles: the generating
 * truth (which light each detection came from), the analytic product of two posteriors and of
 * two Gaussian position estimates, and brute-force counts in plain SQL. */
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

enum { NL = 120 };

typedef struct {
    double lat, lon, a, b, az;
    int phase;
} truth_light;

/* NL lights on a 40 m grid (ellipses 1-3 m, so distinct lights are > 10 sigma apart). */
static void make_truth(truth_light *t)
{
    uint64_t rng = 99;
    double ky = 1.0 / (GIS_EARTH_RADIUS_M * M_PI / 180.0), kx = ky / cos(32.8 * M_PI / 180.0);
    for (int i = 0; i < NL; i++) {
        t[i].lat = 32.8 + (i / 12) * 40.0 * ky;
        t[i].lon = 35.0 + (i % 12) * 40.0 * kx;
        t[i].a = 1.0 + 2.0 * gs_splitmix_uniform(&rng);
        t[i].b = t[i].a * (0.3 + 0.7 * gs_splitmix_uniform(&rng));
        t[i].az = 180.0 * gs_splitmix_uniform(&rng);
        t[i].phase = 120 * (i % 3);
    }
}

/* One night: every light detected at truth + N(0, its ellipse), phase right with confidence
 * conf; the capture's lights in a shuffled order (so index != truth index). */
static void night(srv_db *db, int64_t sid, const char *key, const truth_light *t, uint64_t seed,
                  double conf, int *order)
{
    srv_light_row l[NL];
    srv_location_row loc[NL];
    uint64_t rng = seed;
    for (int i = 0; i < NL; i++) order[i] = i;
    for (int i = NL - 1; i > 0; i--) {
        int j = (int)(gs_splitmix64(&rng) % (uint64_t)(i + 1)), x = order[i];
        order[i] = order[j];
        order[j] = x;
    }
    double ky = 1.0 / (GIS_EARTH_RADIUS_M * M_PI / 180.0);
    for (int k = 0; k < NL; k++) {
        const truth_light *x = &t[order[k]];
        l[k] = survey_fx_light(k, 10.0 * k, 5.0, x->phase, conf);
        l[k].bulb_id = "hps-70w";
        l[k].technology = "sodium_hp";
        l[k].phase_sigma_deg = 4.0;
        srv_location_row_init(&loc[k]);
        loc[k].method = SRV_LOC_ONE_STATION;
        double u = gs_splitmix_normal(&rng) * x->a, v = gs_splitmix_normal(&rng) * x->b;   /* along major, minor */
        double s = sin(x->az * M_PI / 180.0), c = cos(x->az * M_PI / 180.0);
        double e = u * s + v * c, n = u * c - v * s;
        loc[k].lat_deg = x->lat + n * ky;
        loc[k].lon_deg = x->lon + e * ky / cos(x->lat * M_PI / 180.0);
        loc[k].ellipse = (gis_ellipse){x->a, x->b, x->az};
    }
    srv_capture_data cd = survey_fx_capture(sid, key, l, loc, NL);
    CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
}

TEST(sites_two_nights_same_count_narrower)
{
    const char *path = fx_tmp("sites.sqlite");
    int64_t sid;
    srv_db *db = survey_fx_create(path, "city", &sid);
    if (!db) return;
    truth_light t[NL];
    make_truth(t);
    int o1[NL], o2[NL];
    night(db, sid, "night1", t, 1, 0.9, o1);
    sqlite3 *h = srv_db_sqlite(db);
    CHECK(SQ(h, "SELECT count(*) FROM light_sites") == NL);
    srv_phase_stats one = survey_fx_stats_all(db, 0);
    night(db, sid, "night2", t, 2, 0.9, o2);
    /* the same number of sites, each with one detection per night, from one truth light */
    CHECK(SQ(h, "SELECT count(*) FROM light_sites") == NL);
    CHECK(SQ(h, "SELECT count(*) FROM light_sites WHERE detections = 2") == NL);
    sqlite3_stmt *q = NULL;
    CHECK(sqlite3_prepare_v2(h, "SELECT sd.site_id, c.capture_key, l.light_index FROM site_detections sd "
                                "JOIN lights l ON l.id = sd.light_id JOIN captures c ON c.id = l.capture_id "
                                "ORDER BY sd.site_id, c.capture_key", -1, &q, NULL) == SQLITE_OK);
    int pairs = 0;
    while (q && sqlite3_step(q) == SQLITE_ROW) {
        int64_t s1 = sqlite3_column_int64(q, 0);
        int i1 = sqlite3_column_int(q, 2);
        CHECK(sqlite3_step(q) == SQLITE_ROW && sqlite3_column_int64(q, 0) == s1);
        int i2 = sqlite3_column_int(q, 2);
        CHECK_MSG(o1[i1] == o2[i2], "site %lld joins truth lights %d and %d", (long long)s1, o1[i1], o2[i2]);
        pairs++;
    }
    sqlite3_finalize(q);
    CHECK(pairs == NL);
    /* statistics count sites: the same n and the same Wilson intervals as one night (two
     * nights do not make twice the lights), and the detections are still there on request */
    srv_phase_stats two = survey_fx_stats_all(db, 0), det = survey_fx_stats_all(db, 1);
    CHECK(two.lights == NL && two.total == NL && one.total == NL && det.lights == 2 * NL);
    for (int k = 0; k < 3; k++) {
        CHECK(two.n[k] == one.n[k] && two.n[k] == NL / 3);
        CHECK_NEAR(two.hi[k] - two.lo[k], one.hi[k] - one.lo[k], 1e-15);
        CHECK(det.hi[k] - det.lo[k] < two.hi[k] - two.lo[k]);   /* what counting twice claimed */
    }
    /* narrower posteriors: the analytic product of two 0.9 posteriors over 3 phases,
     * 0.81 / (0.81 + 2 (0.05)^2), and phase sigma 4 / sqrt(2) */
    double want = 0.81 / (0.81 + 2 * 0.05 * 0.05);
    CHECK(sqlite3_prepare_v2(h, "SELECT min(phase_confidence), max(phase_confidence), min(phase_sigma_deg), "
                                "max(phase_sigma_deg) FROM light_sites", -1, &q, NULL) == SQLITE_OK);
    CHECK(q && sqlite3_step(q) == SQLITE_ROW);
    CHECK_NEAR(sqlite3_column_double(q, 0), want, 1e-12);
    CHECK_NEAR(sqlite3_column_double(q, 1), want, 1e-12);
    CHECK_NEAR(sqlite3_column_double(q, 2), 4.0 / sqrt(2.0), 1e-12);
    CHECK_NEAR(sqlite3_column_double(q, 3), 4.0 / sqrt(2.0), 1e-12);
    sqlite3_finalize(q);
    /* narrower ellipses: two equal covariances combine to half the covariance (axes / sqrt 2),
     * at the mean of the two positions */
    CHECK(sqlite3_prepare_v2(h, "SELECT s.semi_major_m, s.semi_minor_m, s.lat_deg, s.lon_deg, "
                                "avg(loc.lat_deg), avg(loc.lon_deg), max(loc.semi_major_m), "
                                "max(loc.semi_minor_m), min(abs(s.phase_deg - l.phase_deg)) FROM light_sites s "
                                "JOIN site_detections sd ON sd.site_id = s.id JOIN locations loc "
                                "ON loc.light_id = sd.light_id JOIN lights l ON l.id = sd.light_id "
                                "GROUP BY s.id", -1, &q, NULL) == SQLITE_OK);
    int sites = 0;
    while (q && sqlite3_step(q) == SQLITE_ROW) {
        CHECK_NEAR(sqlite3_column_double(q, 0), sqlite3_column_double(q, 6) / sqrt(2.0), 1e-6);
        CHECK_NEAR(sqlite3_column_double(q, 1), sqlite3_column_double(q, 7) / sqrt(2.0), 1e-6);
        CHECK_NEAR(sqlite3_column_double(q, 2), sqlite3_column_double(q, 4), 1e-11);
        CHECK_NEAR(sqlite3_column_double(q, 3), sqlite3_column_double(q, 5), 1e-11);
        CHECK(sqlite3_column_double(q, 8) < 1e-9);
        sites++;
    }
    sqlite3_finalize(q);
    CHECK(sites == NL);
    /* idempotent and resumable: the same night again is skipped, associating again adds
     * nothing; deleting a night leaves every site with one detection, refreshed */
    night(db, sid, "night2", t, 2, 0.9, o2);
    long created = -1, joined = -1;
    CHECK_OK(srv_db_associate(db, &created, &joined, NULL));
    CHECK(created == 0 && joined == 0 && SQ(h, "SELECT count(*) FROM light_sites") == NL);
    int deleted = 0;
    CHECK_OK(srv_db_delete_capture(db, sid, "night1", &deleted));
    CHECK(deleted && SQ(h, "SELECT count(*) FROM light_sites WHERE stale = 1") == NL);
    CHECK_OK(srv_db_associate(db, &created, &joined, NULL));
    CHECK(SQ(h, "SELECT count(*) FROM light_sites WHERE stale = 0 AND detections = 1 AND "
                "abs(phase_confidence - 0.9) < 1e-12") == NL);
    srv_db_report r;
    CHECK_OK(srv_db_check(db, &r));
    CHECK(srv_db_report_ok(&r) && r.sites == NL && r.unassociated == 0);
    CHECK_OK(srv_db_delete_capture(db, sid, "night2", &deleted));
    CHECK(SQ(h, "SELECT count(*) FROM light_sites") == 0 && SQ(h, "SELECT count(*) FROM light_sites_rtree") == 0);
    srv_db_close(db);
}

/* The product over detections that disagree, against the formula written out: bulbs out of
 * M = 10 entries, phases in 3 classes; one detection is returned as it is. */
TEST(sites_combine_posterior_product)
{
    srv_site_obs o[3];
    memset(o, 0, sizeof o);
    const char *bulbs[3] = {"a", "a", "b"};
    double pc[3] = {0.9, 0.8, 0.7}, bc[3] = {0.6, 0.7, 0.9}, ph[3] = {0, 0, 120};
    for (int i = 0; i < 3; i++) {
        snprintf(o[i].bulb_id, sizeof o[i].bulb_id, "%s", bulbs[i]);
        snprintf(o[i].technology, sizeof o[i].technology, "t%s", bulbs[i]);
        o[i].phase_deg = ph[i];
        o[i].phase_sigma_deg = 2.0 + i;
        o[i].phase_confidence = pc[i];
        o[i].bulb_confidence = bc[i];
        o[i].confidence = pc[i] * bc[i];
        o[i].bulbs = 10;
    }
    srv_site_value v;
    srv_site_combine(o, 1, &v);
    CHECK(!strcmp(v.bulb_id, "a") && v.phase_deg == 0.0 && v.phase_confidence == 0.9 &&
          v.bulb_confidence == 0.6 && v.phase_sigma_deg == 2.0);
    srv_site_combine(o, 3, &v);
    /* phase: labels 0, 0, 120 of 3 */
    double p0 = 0.9 * 0.8 * 0.15, p120 = 0.05 * 0.1 * 0.7, p240 = 0.05 * 0.1 * 0.15;
    CHECK_NEAR(v.phase_confidence, p0 / (p0 + p120 + p240), 1e-12);
    CHECK(v.phase_deg == 0.0);
    CHECK_NEAR(v.phase_sigma_deg, 1.0 / sqrt(1.0 / 4 + 1.0 / 9), 1e-12);
    /* bulb: a, a, b of 10; the 8 unnamed bulbs share the same product */
    double qa = 0.6 * 0.7 * (0.1 / 9), qb = (0.4 / 9) * (0.3 / 9) * 0.9, qo = (0.4 / 9) * (0.3 / 9) * (0.1 / 9);
    CHECK_NEAR(v.bulb_confidence, qa / (qa + qb + 8 * qo), 1e-12);
    CHECK(!strcmp(v.bulb_id, "a") && !strcmp(v.technology, "ta"));
    /* unknown phases carry no evidence */
    o[2].phase_deg = NAN;
    srv_site_combine(o, 3, &v);
    p0 = 0.9 * 0.8;
    double pother = 0.05 * 0.1;
    CHECK_NEAR(v.phase_confidence, p0 / (p0 + 2 * pother), 1e-12);
}

/* The bulb labels M of a detection are the bulbs its recognition was matched against
 * (captures.candidate_bulbs: the DELIGHT entries of its grid and bands), not every entry of the
 * DELIGHT version (a grid engineer's trial: 200 entries, 50 candidates of a 50 Hz RGB capture).
 * Two nights (surveys june, july) of three pixel sites, bulb confidences 0.527 and 0.605:
 * site x = 100 the same bulb both nights, x = 200 another bulb the second night, both in
 * captures recorded with 50 candidates; x = 300 the same bulb in captures stored without the
 * count (NULL), which fall back to the DELIGHT's 200 entries. Oracle: the documented posterior
 * product and P(bulb differs) written out with M = 50 (and 200). */
TEST(sites_bulb_labels_are_the_candidates)
{
    const char *path = fx_tmp("cand.sqlite");
    int64_t sid[2];
    srv_db *db = survey_fx_create(path, "june", &sid[0]);
    if (!db) return;
    srv_survey_row july = {"july", NULL, NULL, NULL, 50};
    CHECK_OK(srv_db_add_survey(db, &july, &sid[1]));
    srv_delight_row dv = {.source = "built-in", .bulbs = 200};
    memset(dv.sha256, 'a', 64);
    int64_t did = 0;
    CHECK_OK(srv_db_add_delight(db, &dv, &did));
    const double cb[2] = {0.527, 0.605};
    for (int night_i = 0; night_i < 2; night_i++)
        for (int counted = 0; counted < 2; counted++) {
            srv_light_row l[2];
            size_t n = 0;
            if (counted) {
                l[n] = survey_fx_light((int)n, 100.0, 50.0, 0.0, 0.9);
                l[n++].bulb_id = "led-a";
                l[n] = survey_fx_light((int)n, 200.0, 50.0, 0.0, 0.9);
                l[n++].bulb_id = night_i ? "hps-b" : "led-a";
            } else {
                l[n] = survey_fx_light((int)n, 300.0, 50.0, 0.0, 0.9);
                l[n++].bulb_id = "led-a";
            }
            for (size_t i = 0; i < n; i++) {
                l[i].technology = "led_linear";
                l[i].bulb_confidence = cb[night_i];
            }
            char key[32];
            snprintf(key, sizeof key, "n%d-%s", night_i + 1, counted ? "counted" : "old");
            srv_capture_data cd = survey_fx_capture(sid[night_i], key, l, NULL, n);
            cd.capture.delight_id = did;
            cd.capture.grid_hz = 50;
            cd.capture.bands = 3;
            cd.capture.candidate_bulbs = counted ? 50 : 0;
            CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
        }
    sqlite3 *h = srv_db_sqlite(db);
    CHECK(SQ(h, "SELECT count(*) FROM captures WHERE candidate_bulbs = 50") == 2 &&
          SQ(h, "SELECT count(*) FROM captures WHERE candidate_bulbs IS NULL") == 2);
    CHECK(SQ(h, "SELECT count(*) FROM light_sites WHERE detections = 2") == 3);
    /* the same bulb on both nights: c1 c2 / (c1 c2 + (M - 1) r1 r2), r = (1 - c) / (M - 1) */
    const double Ms[2] = {50.0, 200.0}, xs[2] = {100.0, 300.0};
    for (int k = 0; k < 2; k++) {
        double M = Ms[k], r1 = (1.0 - cb[0]) / (M - 1.0), r2 = (1.0 - cb[1]) / (M - 1.0);
        double want = cb[0] * cb[1] / (cb[0] * cb[1] + (M - 1.0) * r1 * r2);
        char sql[160];
        snprintf(sql, sizeof sql, "SELECT bulb_confidence FROM light_sites WHERE x_px = %.1f", xs[k]);
        double got = strtod(survey_fx_query_text(h, sql), NULL);   /* 15 digits or more */
        CHECK_MSG(fabs(got - want) < 1e-12, "site x %.0f: bulb confidence %.6f, M = %.0f gives %.6f", xs[k],
                  got, M, want);
    }
    /* compare: P(bulb differs) = 1 - [c_A r_B + c_B r_A + (M - 2) r_A r_B] with M = 50, the
     * trial's 0.9862 (M = 200 gave 0.9966) */
    srv_change *ch = NULL;
    size_t nch = 0;
    srv_compare_totals t;
    CHECK_OK(srv_compare(db, "june", "july", 0.9, &ch, &nch, &t));
    double M = 50.0, ra = (1.0 - cb[0]) / (M - 1.0), rb = (1.0 - cb[1]) / (M - 1.0);
    double want = 1.0 - (cb[0] * rb + cb[1] * ra + (M - 2.0) * ra * rb);
    CHECK(fabs(want - 0.9862) < 5e-5);
    CHECK_MSG(nch == 1 && ch[0].kinds == SRV_CHANGE_BULB && fabs(ch[0].x_px - 200.0) < 1e-9,
              "%zu changes", nch);
    if (nch == 1)
        CHECK_MSG(fabs(ch[0].p_bulb_change - want) < 1e-12, "P(bulb differs) %.6f, M = 50 gives %.6f",
                  ch[0].p_bulb_change, want);
    free(ch);
    /* a negative count is refused, naming the field */
    srv_light_row l0 = survey_fx_light(0, 1.0, 1.0, 0.0, 0.9);
    srv_capture_data bad = survey_fx_capture(sid[0], "bad", &l0, NULL, 1);
    bad.capture.candidate_bulbs = -1;
    CHECK(srv_db_add_capture(db, &bad, NULL, NULL) == GS_EINVAL && strstr(gs_detail(), "candidate_bulbs"));
    srv_db_close(db);
}

/* Two nights of the lab scene through `gridsurvey run` (no station: lights associated by
 * pixel, the captures counting as one fixed camera): 8 sites, not 16; n = 8 in stats. */
TEST(sites_lab_two_nights_cli)
{
    char out[16384], db[1024], scene[1024];
    snprintf(db, sizeof db, "%s", fx_tmp("lab2.sqlite"));
    survey_lab_spec spec = survey_fx_lab_spec();
    for (int night_i = 0; night_i < 2; night_i++) {
        spec.seed = 4 + night_i;
        snprintf(scene, sizeof scene, "%s", fx_tmp(night_i ? "lab-n2.json" : "lab-n1.json"));
        survey_fx_small_lab(scene, 0.5, &spec);
        char cap[1024];
        snprintf(cap, sizeof cap, "%s", fx_tmp(night_i ? "lab-n2-cap" : "lab-n1-cap"));
        int rc = fx_run(out, sizeof out, "%s run %s --db %s --survey lab --capture-dir %s", test_bin(),
                        scene, db, cap);
        CHECK_MSG(rc == 0, "night %d: %d: %s", night_i + 1, rc, out);
    }
    sqlite3 *h = NULL;
    CHECK(sqlite3_open_v2(db, &h, SQLITE_OPEN_READONLY, NULL) == SQLITE_OK);
    CHECK(SQ(h, "SELECT count(*) FROM captures") == 2 && SQ(h, "SELECT count(*) FROM lights") == 16);
    /* each capture records its candidate bulbs: the built-in DELIGHT's entries of its grid and
     * band count that are locked to the mains (counted here), fewer than all the entries */
    gs_delight *d = NULL;
    CHECK_OK(gs_delight_open(NULL, &d));
    long grid = SQ(h, "SELECT max(grid_hz) FROM captures"), bands = SQ(h, "SELECT max(bands) FROM captures"), nb = 0;
    for (size_t i = 0; d && i < gs_delight_count(d); i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        nb += b->grid_hz == grid && b->brf.bands == bands && b->ref != GS_REF_UNLOCKED;
    }
    char sql[160];
    snprintf(sql, sizeof sql, "SELECT count(*) FROM captures WHERE candidate_bulbs = %ld", nb);
    CHECK_MSG(SQ(h, sql) == 2 && nb > 0 && nb < (long)gs_delight_count(d), "%ld of %zu entries", nb,
              d ? gs_delight_count(d) : 0);
    gs_delight_free(d);
    CHECK(SQ(h, "SELECT count(*) FROM light_sites") == 8);
    CHECK(SQ(h, "SELECT count(*) FROM light_sites WHERE detections = 2") == 8);
    /* each site's two detections are the same light: the same bulb and phase both nights */
    CHECK(SQ(h, "SELECT count(*) FROM (SELECT sd.site_id FROM site_detections sd JOIN lights l ON "
                "l.id = sd.light_id GROUP BY sd.site_id HAVING count(DISTINCT l.bulb_id) = 1 AND "
                "count(DISTINCT l.phase_deg) = 1)") == 8);
    /* narrower: each site's phase confidence above both of its detections' (equal when one is
     * already 1), its phase sigma not above (the lab's phases are exact candidates: 0) */
    CHECK(SQ(h, "SELECT count(*) FROM light_sites s WHERE s.phase_sigma_deg <= (SELECT min(l.phase_sigma_deg) "
                "FROM site_detections sd JOIN lights l ON l.id = sd.light_id WHERE sd.site_id = s.id) "
                "AND (s.phase_confidence > (SELECT max(l.phase_confidence) FROM site_detections sd "
                "JOIN lights l ON l.id = sd.light_id WHERE sd.site_id = s.id) OR s.phase_confidence = 1.0)") == 8);
    CHECK(SQ(h, "SELECT count(*) FROM light_sites s WHERE s.phase_confidence > (SELECT max(l.phase_confidence) "
                "FROM site_detections sd JOIN lights l ON l.id = sd.light_id WHERE sd.site_id = s.id)") >= 1);
    sqlite3_close(h);
    int rc = fx_run(out, sizeof out, "%s stats --db %s --format csv", test_bin(), db);
    CHECK_MSG(rc == 0 && strstr(out, "\nall,,,8,0,0,0,"), "%d: %s", rc, out);
    rc = fx_run(out, sizeof out, "%s stats --db %s --format csv --detections", test_bin(), db);
    CHECK_MSG(rc == 0 && strstr(out, "\nall,,,16,0,0,0,"), "%d: %s", rc, out);
    rc = fx_run(out, sizeof out, "%s db check --db %s", test_bin(), db);
    CHECK_MSG(rc == 0 && strstr(out, "8 light sites, 0 lights without a site"), "%d: %s", rc, out);
}

/* The lab scene surveyed twice (survey A; survey B another night, three lights rephased and one
 * lamp replaced): `compare` reports exactly those four sites, with the right kinds and values,
 * and nothing appeared or vanished. */
TEST(sites_compare_rephased_and_replaced)
{
    char out[16384], db[1024];
    snprintf(db, sizeof db, "%s", fx_tmp("cmp.sqlite"));
    survey_lab_spec a = survey_fx_lab_spec(), b = a;
    b.seed = 5;
    static const int rephased[3] = {0, 4, 6}, new_phase[3] = {240, 0, 240};
    for (int i = 0; i < 3; i++) b.phase_deg[rephased[i]] = new_phase[i];
    const int replaced = 3;
    b.bulb[replaced] = "led-a60-9w-cap";
    const survey_lab_spec *sp[2] = {&a, &b};
    static const char *const names[2] = {"before", "after"};
    for (int k = 0; k < 2; k++) {
        char scene[1024], cap[1024];
        snprintf(scene, sizeof scene, "%s/%s.json", fx_tmp(""), names[k]);
        snprintf(cap, sizeof cap, "%s/%s-cap", fx_tmp(""), names[k]);
        survey_fx_small_lab(scene, 0.5, sp[k]);
        int rc = fx_run(out, sizeof out, "%s run %s --db %s --survey %s --capture-dir %s", test_bin(), scene, db,
                        names[k], cap);
        CHECK_MSG(rc == 0 && strstr(out, "| detection rate | 100.0 % | 8 / 8 "), "%s: %d: %s", names[k], rc, out);
    }
    int rc = fx_run(out, sizeof out, "%s compare --db %s --survey before --survey after --format csv", test_bin(), db);
    CHECK_MSG(rc == 0, "%d: %s", rc, out);
    /* the truth: which site is which lab light, by the site's pixel (the lab's x at scale 1/2) */
    int lines = 0, phase = 0, bulb = 0;
    for (char *line = strchr(out, '\n'); line && line[1]; line = strchr(line + 1, '\n')) {
        long long site;
        double x, y;
        char kind[32];
        if (sscanf(line + 1, "%lld,,,%lf,%lf,%31[^,]", &site, &x, &y, kind) != 4) {
            test_failed(__FILE__, __LINE__, "unparsed row: %.120s", line + 1);
            continue;
        }
        lines++;
        int which = -1;
        for (int i = 0; i < 8; i++) {
            double lx = survey_fx_lab_x_px(i, 0.5), ly = survey_fx_lab_y_px(i, 0.5);
            if (fabs(x - lx) < 1.5 && fabs(y - ly) < 1.5) which = i;
        }
        int is_rephased = which == rephased[0] || which == rephased[1] || which == rephased[2];
        if (!strcmp(kind, "phase")) {
            phase++;
            CHECK_MSG(is_rephased, "phase change at light %d", which);
        } else if (!strcmp(kind, "bulb")) {
            bulb++;
            CHECK_MSG(which == replaced && strstr(line, ",led-a60-9w-cap,"), "bulb change at light %d: %.200s",
                      which, line + 1);
        } else {
            test_failed(__FILE__, __LINE__, "unexpected change %s at light %d", kind, which);
        }
    }
    CHECK_MSG(lines == 4 && phase == 3 && bulb == 1, "%d rows, %d phase, %d bulb: %s", lines, phase, bulb, out);
    rc = fx_run(out, sizeof out, "%s compare --db %s --survey before --survey after", test_bin(), db);
    CHECK_MSG(rc == 0 && strstr(out, "in both: 8 (4 unchanged); changes: 3 phase, 1 bulb, 0 appeared, 0 vanished"),
              "%d: %s", rc, out);
    rc = fx_run(out, sizeof out, "%s compare --db %s --survey before --survey nope 2>&1", test_bin(), db);
    CHECK_MSG(rc == 1 && strstr(out, "nope"), "%d: %s", rc, out);
}

/* srv_site_combine where its label sets have edges, against the product written out (the
 * leftover (1 - c) / (M - 1) on each of the M - 1 other labels, normalised over all M):
 * all three phases named (M = 3: no fourth label), bulbs of DELIGHTs of 10 and 20 entries (both
 * over the larger), a pair's labels (M = bulbs x 3), six-phase labels (the nearest multiple of
 * 30 deg: 29 and 31 are one label), and an exact phase (sigma 0) outweighing any other. */
TEST(sites_combine_label_edges)
{
    srv_site_obs o[3];
    srv_site_value v;
    memset(o, 0, sizeof o);
    const double pc[3] = {0.9, 0.8, 0.7};
    for (int i = 0; i < 3; i++) {
        o[i].phase_deg = 120.0 * i;
        o[i].phase_sigma_deg = 2.0;
        o[i].phase_confidence = pc[i];
    }
    srv_site_combine(o, 3, &v);
    double p0 = 0.9 * 0.1 * 0.15, p120 = 0.05 * 0.8 * 0.15, p240 = 0.05 * 0.1 * 0.7;
    CHECK(v.phase_deg == 0.0 && v.phase_sigma_deg == 2.0);
    CHECK_NEAR(v.phase_confidence, p0 / (p0 + p120 + p240), 1e-12);
    /* bulbs a (0.6 of 10) and b (0.7 of 20): both spread over 20 */
    memset(o, 0, sizeof o);
    snprintf(o[0].bulb_id, sizeof o[0].bulb_id, "a");
    snprintf(o[1].bulb_id, sizeof o[1].bulb_id, "b");
    o[0].bulb_confidence = 0.6;
    o[1].bulb_confidence = 0.7;
    o[0].bulbs = 10;
    o[1].bulbs = 20;
    o[0].phase_deg = o[1].phase_deg = NAN;
    srv_site_combine(o, 2, &v);
    double qa = 0.6 * (0.3 / 19), qb = (0.4 / 19) * 0.7, qo = (0.4 / 19) * (0.3 / 19);
    CHECK(!strcmp(v.bulb_id, "b"));
    CHECK_NEAR(v.bulb_confidence, qb / (qa + qb + 18 * qo), 1e-12);
    /* the pair (a, 0 deg) twice at 0.5, a of 10 bulbs: 30 pairs */
    memset(o, 0, sizeof o);
    for (int i = 0; i < 2; i++) {
        snprintf(o[i].bulb_id, sizeof o[i].bulb_id, "a");
        o[i].bulbs = 10;
        o[i].phase_deg = 0.0;
        o[i].phase_sigma_deg = 2.0;
        o[i].confidence = o[i].bulb_confidence = o[i].phase_confidence = 0.5;
    }
    srv_site_combine(o, 2, &v);
    CHECK_NEAR(v.confidence, 0.25 / (0.25 + 29 * (0.5 / 29) * (0.5 / 29)), 1e-12);
    /* 29 and 31 deg (other: twelve labels) are the label 30; their mean 30 */
    o[0].phase_deg = 29.0;
    o[1].phase_deg = 31.0;
    o[0].phase_confidence = 0.9;
    o[1].phase_confidence = 0.8;
    srv_site_combine(o, 2, &v);
    CHECK_NEAR(v.phase_deg, 30.0, 1e-12);
    CHECK_NEAR(v.phase_confidence, 0.72 / (0.72 + 11 * (0.1 / 11) * (0.2 / 11)), 1e-12);
    /* an exact phase (sigma 0) and a measured one of the same class: the exact one */
    o[0].phase_deg = 0.0;
    o[0].phase_sigma_deg = 0.0;
    o[1].phase_deg = 10.0;
    srv_site_combine(o, 2, &v);
    CHECK(v.phase_deg == 0.0 && v.phase_sigma_deg == 0.0);
}
