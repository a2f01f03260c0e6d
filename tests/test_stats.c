/* test_stats.c - phase-balance statistics (survey/stats.c, `gridsurvey stats`): Wilson
 * intervals against textbook values and an independent closed form, the chi-square survival
 * function against tabulated quantiles, phase classes against gis_phase_classify, the SQL views
 * against the C computation, the p-value distribution of uniform populations (spread over
 * (0, 1), not all tiny) and of an imbalanced one (tiny), grouping by cell and radius with
 * lights placed at known metric offsets, the Haifa-like example end to end, and the database
 * benchmark in --quick mode. */
#include "gis/gis.h"
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
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

static char out[1 << 18];

/* `gridsurvey ...`: fmt's first %s is the binary (tests/fixtures.h); output in out. */
static int run(const char *fmt, const char *a, const char *b, const char *c)
{
    return fx_run_bin(out, sizeof out, fmt, a, b, c);
}

/* ------------------------------------------------------------------ formulas */

/* The Wilson interval as the roots of (p_hat - p)^2 = z^2 p (1 - p) / n, a quadratic in p:
 * (1 + z2/n) p^2 - (2 p_hat + z2/n) p + p_hat^2 = 0 (independent of srv_wilson's form). */
static void wilson_roots(long k, long n, double z, double *lo, double *hi)
{
    double ph = (double)k / (double)n, a = 1.0 + z * z / (double)n, b = -(2.0 * ph + z * z / (double)n),
           c = ph * ph;
    double disc = sqrt(b * b - 4.0 * a * c);
    /* numerically stable pair of roots */
    double q = -0.5 * (b - disc);
    double r1 = q / a, r2 = q != 0.0 ? c / q : 0.0;
    *lo = fmin(r1, r2);
    *hi = fmax(r1, r2);
}

TEST(stats_wilson_textbook_values)
{
    /* Newcombe, Statistics in Medicine 17, 857-872 (1998), Table I, method 3 (Wilson score
     * without continuity correction), 95 %: 81/263, 15/148, 0/20, 1/29. */
    static const struct {
        long k, n;
        double lo, hi;
    } t[] = {{81, 263, 0.2553, 0.3662}, {15, 148, 0.0624, 0.1605}, {0, 20, 0.0, 0.1611},
             {1, 29, 0.0061, 0.1718}};
    for (size_t i = 0; i < sizeof t / sizeof *t; i++) {
        double lo, hi;
        double p = srv_wilson(t[i].k, t[i].n, SRV_Z95, &lo, &hi);
        CHECK_NEAR(p, (double)t[i].k / (double)t[i].n, 1e-15);
        CHECK_NEAR(lo, t[i].lo, 5e-5);
        CHECK_NEAR(hi, t[i].hi, 5e-5);
    }
    /* the Haifa-like shares of 1000 lights: 33.4 / 36.3 / 30.3 % */
    static const long k1000[3] = {334, 363, 303};
    for (int i = 0; i < 3; i++) {
        double lo, hi, rlo, rhi;
        srv_wilson(k1000[i], 1000, SRV_Z95, &lo, &hi);
        wilson_roots(k1000[i], 1000, SRV_Z95, &rlo, &rhi);
        CHECK_NEAR(lo, rlo, 1e-14);
        CHECK_NEAR(hi, rhi, 1e-14);
    }
    double lo, hi;
    srv_wilson(334, 1000, SRV_Z95, &lo, &hi);
    CHECK_NEAR(lo, 0.3055, 1e-4);   /* 33.4 % [30.5, 36.4] */
    CHECK_NEAR(hi, 0.3639, 1e-4);
    /* a sweep against the quadratic's roots, z = 1.96 and 2.576 */
    for (long n = 1; n <= 300; n += 7)
        for (long k = 0; k <= n; k += 1 + n / 10) {
            double z = n % 2 ? SRV_Z95 : 2.5758293035489;
            double rlo, rhi;
            srv_wilson(k, n, z, &lo, &hi);
            wilson_roots(k, n, z, &rlo, &rhi);
            CHECK_NEAR(lo, fmax(rlo, 0.0), 1e-12);
            CHECK_NEAR(hi, fmin(rhi, 1.0), 1e-12);
        }
    srv_wilson(5, 5, SRV_Z95, &lo, &hi);
    CHECK(hi == 1.0 && lo < 1.0);
    CHECK(isnan(srv_wilson(0, 0, SRV_Z95, &lo, &hi)) && isnan(lo) && isnan(hi));
    CHECK(isnan(srv_wilson(6, 5, SRV_Z95, &lo, &hi)));
}

TEST(stats_chi2_sf_known_values)
{
    /* upper quantiles of the chi-square distribution (e.g. Abramowitz & Stegun Table 26.8;
     * values to 15 digits from the inverse regularised gamma) */
    static const struct {
        double x;
        int dof;
        double p;
    } t[] = {
        {5.991464547107979, 2, 0.05},  {9.210340371976183, 2, 0.01},
        {13.815510557964274, 2, 0.001}, {3.841458820694124, 1, 0.05},
        {6.634896601021214, 1, 0.01},  {7.814727903251178, 3, 0.05},
        {13.276704135987622, 4, 0.01}, {18.307038053275146, 10, 0.05},
        {1.3862943611198906, 2, 0.5},  {0.454936423119572, 1, 0.5},
    };
    for (size_t i = 0; i < sizeof t / sizeof *t; i++)
        CHECK_NEAR(gs_chi2_sf(t[i].x, t[i].dof), t[i].p, 1e-11 * t[i].p);
    /* 2 dof is exactly exp(-x/2) */
    for (double x = 0.01; x < 1400.0; x *= 1.7) CHECK(gs_chi2_sf(x, 2) == exp(-x / 2));
    CHECK(gs_chi2_sf(0.0, 2) == 1.0 && gs_chi2_sf(-3.0, 5) == 1.0);
    CHECK(isnan(gs_chi2_sf(NAN, 2)) && isnan(gs_chi2_sf(1.0, 0)));
    CHECK(gs_chi2_sf(INFINITY, 2) == 0.0);
}

TEST(stats_phase_class_matches_gis)
{
    for (double p = -720.0; p <= 720.0; p += 0.125) {
        int c = gs_phase_class(p);
        gis_phase_class g = gis_phase_classify(p);
        CHECK_MSG(c == (int)g || (c == 3 && g == GIS_PHASE_OTHER), "phase %g: %d vs gis %d", p, c, (int)g);
    }
    CHECK(gs_phase_class(NAN) == -1);
    CHECK(gs_phase_class(20.0) == 0 && gs_phase_class(20.000001) == 3);
    CHECK(gs_phase_class(340.0) == 0 && gs_phase_class(339.99999) == 3);
    CHECK(gs_phase_class(100.0) == 1 && gs_phase_class(260.0) == 2 && gs_phase_class(359.999) == 0);
}

/* ------------------------------------------------------------------ database */

/* A synthetic survey of uniform layout, phases in the ratio w0 : w1 : w2. */
static void synth(const char *path, const char *survey, size_t captures, size_t lights,
                  unsigned long long seed, double w0, double w1, double w2, double half_width_m)
{
    srv_synth_opts o = survey_fx_synth_opts(survey, captures, lights, seed);
    o.phase_weights[0] = w0;
    o.phase_weights[1] = w1;
    o.phase_weights[2] = w2;
    o.view_half_width_m = half_width_m;
    survey_fx_synth(path, &o);
}

static srv_phase_stats *compute(srv_db *db, const char *by, double min_conf, size_t *n, long *ungrouped)
{
    srv_stats_opts o;
    srv_stats_opts_default(&o);
    CHECK_OK(srv_stats_parse_by(by, &o));
    o.min_phase_confidence = min_conf;
    o.detections = 1;   /* the synthetic lights are all distinct: counted as stored */
    srv_phase_stats *g = NULL;
    CHECK_OK(srv_stats_compute(db, &o, &g, n, ungrouped));
    return g;
}

/* Every group of srv_stats_compute (sites, or detections) by each grouping equals its row of
 * the SQL view (a phase_balance-shaped view); returns the rows checked. */
static int check_balance_view(srv_db *db, const char *view, int detections, const char *const *groupings,
                              int n_groupings)
{
    sqlite3 *h = srv_db_sqlite(db);
    sqlite3_stmt *q = NULL;
    int checked = 0;
    for (int gi = 0; gi < n_groupings; gi++) {
        size_t n = 0;
        srv_stats_opts o;
        srv_stats_opts_default(&o);
        CHECK_OK(srv_stats_parse_by(groupings[gi], &o));
        o.detections = detections;
        srv_phase_stats *g = NULL;
        CHECK_OK(srv_stats_compute(db, &o, &g, &n, NULL));
        CHECK(n >= 1);
        for (size_t i = 0; i < n; i++) {
            char sql[512];
            snprintf(sql, sizeof sql, "SELECT lights, unknown, other, n0, n120, n240, n, share0, lo0, "
                     "hi0, share120, lo120, hi120, share240, lo240, hi240, chi2, p_value, imbalance "
                     "FROM %s WHERE grouping = '%s' AND grp = '%s'", view, groupings[gi], g[i].group);
            CHECK(sqlite3_prepare_v2(h, sql, -1, &q, NULL) == SQLITE_OK);
            if (sqlite3_step(q) != SQLITE_ROW) {
                test_failed(__FILE__, __LINE__, "no %s row for %s %s", view, groupings[gi], g[i].group);
                sqlite3_finalize(q);
                continue;
            }
            /* the views' "other" includes the six-phase classes 30/150/270 */
            long other = g[i].other + g[i].n30[0] + g[i].n30[1] + g[i].n30[2];
            long want[7] = {g[i].lights, g[i].unknown, other, g[i].n[0], g[i].n[1], g[i].n[2], g[i].total};
            for (int k = 0; k < 7; k++)
                CHECK_MSG(sqlite3_column_int64(q, k) == want[k], "%s %s %s column %d: %lld vs %ld", view,
                          groupings[gi], g[i].group, k, (long long)sqlite3_column_int64(q, k), want[k]);
            double wantr[12] = {g[i].share[0], g[i].lo[0], g[i].hi[0], g[i].share[1], g[i].lo[1],
                                g[i].hi[1], g[i].share[2], g[i].lo[2], g[i].hi[2], g[i].chi2,
                                g[i].p_value, g[i].imbalance};
            for (int k = 0; k < 12; k++)
                CHECK_NEAR(sqlite3_column_double(q, 7 + k), wantr[k], 1e-12 * fmax(1.0, fabs(wantr[k])));
            sqlite3_finalize(q);
            checked++;
        }
        free(g);
    }
    return checked;
}

/* phase_counts and phase_balance (SQL) equal the C computation for every group. */
TEST(stats_sql_views_match_c)
{
    const char *path = fx_tmp("v.sqlite");
    synth(path, "east", 10, 80, 3, 1, 1, 1, 2000);
    synth(path, "west", 6, 80, 4, 3, 2, 1, 2000);
    srv_db *db = NULL;
    CHECK_OK(srv_db_open(path, SRV_DB_WRITE, &db));
    if (!db) return;
    /* phases on the class edges, written through the API (stored wrapped) */
    static const double edge[] = {20.0, 340.0, 100.0, 140.0, 220.0, 260.0, 20.0000001,
                                  339.9999999, 99.9999999, 260.0000001, 359.9999999, -0.0000001,
                                  720.0, 60.0, 180.0, 300.0};
    enum { NE = sizeof edge / sizeof *edge };
    srv_light_row l[NE];
    for (int i = 0; i < NE; i++) l[i] = survey_fx_light(i, i, i, edge[i], 1.0);
    int64_t sid;
    CHECK_OK(srv_db_find_survey(db, "east", &sid));
    srv_capture_data cd = survey_fx_capture(sid, "edges", l, NULL, NE);
    CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    sqlite3 *h = srv_db_sqlite(db);
    /* per light: the view's class equals gs_phase_class of the stored phase */
    sqlite3_stmt *q = NULL;
    CHECK(sqlite3_prepare_v2(h, "SELECT phase_deg, phase_class FROM light_phase", -1, &q, NULL) == SQLITE_OK);
    static const char *const names[] = {"0", "120", "240", "other"};
    long rows = 0;
    while (sqlite3_step(q) == SQLITE_ROW) {
        double p = sqlite3_column_type(q, 0) == SQLITE_NULL ? NAN : sqlite3_column_double(q, 0);
        int c = gs_phase_class(p);
        const char *sqlc = (const char *)sqlite3_column_text(q, 1);
        CHECK_MSG(!strcmp(sqlc, c < 0 ? "unknown" : names[c]), "phase %.10g: SQL %s, C %d", p, sqlc, c);
        rows++;
    }
    sqlite3_finalize(q);
    CHECK(rows == 16 * 80 + NE);
    static const char *const groupings[] = {"all", "survey", "technology"};
    int checked = check_balance_view(db, "phase_balance", 1, groupings, 3);
    CHECK(checked >= 1 + 2 + 7);
    /* the edge capture: 20, 340, 100, 140, 220, 260, 359.9999999, -1e-7 (-> 359.9999999), 720
     * (-> 0) are on a phase; 20.0000001, 339.9999999, 99.9999999, 260.0000001, 60, 180, 300
     * are other */
    CHECK(sqlite3_prepare_v2(h, "SELECT sum(phase_class = 'other'), sum(phase_class IN ('0','120','240')) "
                                "FROM light_phase WHERE capture_key = 'edges'", -1, &q, NULL) == SQLITE_OK);
    CHECK(sqlite3_step(q) == SQLITE_ROW && sqlite3_column_int(q, 0) == 7 && sqlite3_column_int(q, 1) == 9);
    sqlite3_finalize(q);
    srv_db_close(db);
}

/* site_phase_balance (SQL, migration 4) equals stats over light sites: two surveys of the same
 * synthetic lights (same seed, so each site joins one detection of each, their posteriors
 * combined), a third survey elsewhere, and pixel sites without a location. */
TEST(stats_site_sql_views_match_c)
{
    const char *path = fx_tmp("sv.sqlite");
    synth(path, "night1", 4, 60, 7, 1, 1, 1, 2000);
    synth(path, "night2", 4, 60, 7, 1, 1, 1, 2000);
    synth(path, "other", 3, 60, 8, 3, 2, 1, 2000);
    srv_db *db = NULL;
    CHECK_OK(srv_db_open(path, SRV_DB_WRITE, &db));
    if (!db) return;
    static const double edge[] = {20.0, 340.0, 100.0, 140.0, 220.0, 260.0, 20.0000001, 60.0, 30.0, 150.0};
    enum { NE = sizeof edge / sizeof *edge };
    srv_light_row l[NE];
    for (int i = 0; i < NE; i++) l[i] = survey_fx_light(i, 10.0 * i, 10.0, edge[i], 0.9);
    int64_t sid;
    CHECK_OK(srv_db_find_survey(db, "other", &sid));
    srv_capture_data cd = survey_fx_capture(sid, "edges", l, NULL, NE);
    CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    sqlite3 *h = srv_db_sqlite(db);
    long sites = survey_fx_query_long(h, "SELECT count(*) FROM light_sites");
    long two = survey_fx_query_long(h, "SELECT count(*) FROM light_sites WHERE detections = 2");
    CHECK_MSG(two >= 200 && sites < 11 * 60 + NE, "%ld sites, %ld with two detections", sites, two);
    CHECK(survey_fx_query_long(h, "SELECT lights FROM site_phase_balance WHERE grouping = 'all'") == sites);
    static const char *const groupings[] = {"all", "technology"};
    int checked = check_balance_view(db, "site_phase_balance", 0, groupings, 2);
    CHECK(checked >= 1 + 5);
    srv_db_close(db);
}

TEST(stats_min_confidence_unknown_other)
{
    const char *path = fx_tmp("c.sqlite");
    int64_t sid;
    srv_db *db = survey_fx_create(path, "conf", &sid);
    if (!db) return;
    /* phase, phase confidence */
    static const double spec[][2] = {{0, 0.99}, {0, 0.95}, {0, 0.5}, {120, 0.97}, {120, 0.2},
                                     {240, 0.91}, {NAN, 0.3}, {NAN, 0.95}, {60, 0.99}, {240, 0.9}};
    enum { N = sizeof spec / sizeof *spec };
    srv_light_row l[N];
    for (int i = 0; i < N; i++) {
        l[i] = survey_fx_light(i, 1, 1, spec[i][0], 0.5);
        l[i].phase_confidence = spec[i][1];
        l[i].technology = i % 2 ? "cfl" : NULL;
    }
    srv_capture_data cd = survey_fx_capture(sid, "c", l, NULL, N);
    CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    size_t n = 0;
    srv_phase_stats *g = compute(db, "all", 0.0, &n, NULL);
    CHECK(n == 1 && g[0].lights == 10 && g[0].below == 0 && g[0].unknown == 2 && g[0].other == 1);
    CHECK(g[0].n[0] == 3 && g[0].n[1] == 2 && g[0].n[2] == 2 && g[0].total == 7);
    CHECK(g[0].flags & SRV_STATS_FEW);
    free(g);
    g = compute(db, "all", 0.9, &n, NULL);
    CHECK(n == 1 && g[0].lights == 10 && g[0].below == 3 && g[0].unknown == 1 && g[0].other == 1);
    CHECK(g[0].n[0] == 2 && g[0].n[1] == 1 && g[0].n[2] == 2 && g[0].total == 5);
    CHECK_NEAR(g[0].share[0], 0.4, 1e-15);
    CHECK_NEAR(g[0].chi2, ((2 - 5 / 3.0) * (2 - 5 / 3.0) * 2 + (1 - 5 / 3.0) * (1 - 5 / 3.0)) / (5 / 3.0), 1e-12);
    CHECK_NEAR(g[0].imbalance, 3 * fabs(0.2 - 1 / 3.0), 1e-12);
    free(g);
    g = compute(db, "technology", 0.0, &n, NULL);
    CHECK(n == 2 && !strcmp(g[0].group, "cfl") && !strcmp(g[1].group, "none"));
    CHECK(g[0].lights == 5 && g[1].lights == 5);
    free(g);
    /* everything below the threshold: an empty group says so instead of inventing shares */
    g = compute(db, "all", 1.0, &n, NULL);
    CHECK(n == 1 && g[0].total == 0 && (g[0].flags & SRV_STATS_EMPTY) && isnan(g[0].share[0]) &&
          isnan(g[0].p_value) && isnan(g[0].imbalance));
    free(g);
    srv_db_close(db);
}

/* Uniform populations give p-values spread over (0, 1); an imbalanced one gives a tiny p. */
TEST(stats_pvalues_uniform_vs_imbalanced)
{
    const char *uni = fx_tmp("u.sqlite"), *imb = fx_tmp("i.sqlite");
    synth(uni, "uniform", 100, 150, 17, 1, 1, 1, 2000);   /* 15000 lights over 4 km x 4 km */
    srv_db *db = NULL;
    CHECK_OK(srv_db_open(uni, SRV_DB_READ, &db));
    if (!db) return;
    size_t n = 0;
    long ungrouped = -1;
    srv_phase_stats *g = compute(db, "cell:250", 0.0, &n, &ungrouped);
    CHECK_MSG(n >= 256 && n <= 289, "%zu cells", n);   /* 16 x 16 cells, 17 x 17 when offset */
    CHECK(ungrouped == 100 * (150 / SRV_SYNTH_UNLOCATED_EVERY));
    int below05 = 0, below001 = 0, used = 0;
    double *p = malloc(n * sizeof *p);
    for (size_t i = 0; i < n; i++) {
        if (g[i].total < 30) continue;
        p[used++] = g[i].p_value;
        below05 += g[i].p_value < 0.05;
        below001 += g[i].p_value < 0.001;
    }
    CHECK(used >= 200);
    /* Kolmogorov-Smirnov distance to U(0,1) */
    for (int i = 1; i < used; i++)
        for (int j = i; j > 0 && p[j - 1] > p[j]; j--) {
            double t = p[j];
            p[j] = p[j - 1];
            p[j - 1] = t;
        }
    double ks = 0.0;
    for (int i = 0; i < used; i++)
        ks = fmax(ks, fmax(fabs((i + 1.0) / used - p[i]), fabs(p[i] - (double)i / used)));
    CHECK_MSG(ks < 1.63 / sqrt(used) + 0.03, "KS distance %.3f over %d cells", ks, used);   /* 1 % level (+ discreteness) */
    CHECK_MSG(below05 >= 0.01 * used && below05 <= 0.10 * used, "%d of %d cells with p < 0.05", below05, used);
    CHECK(below001 <= 0.02 * used);
    double median = p[used / 2];
    CHECK_MSG(median > 0.3 && median < 0.7, "median p %.3f", median);
    free(p);
    free(g);
    g = compute(db, "all", 0.0, &n, NULL);
    CHECK(n == 1 && g[0].p_value > 1e-3);
    free(g);
    srv_db_close(db);
    synth(imb, "imbalanced", 10, 300, 18, 0.5, 0.3, 0.2, 2000);
    CHECK_OK(srv_db_open(imb, SRV_DB_READ, &db));
    if (!db) return;
    g = compute(db, "all", 0.0, &n, NULL);
    CHECK(n == 1 && g[0].p_value < 1e-30 && g[0].imbalance > 0.35 && g[0].imbalance < 0.65);
    CHECK(g[0].lo[0] > 0.45 && g[0].hi[2] < 0.23);
    free(g);
    srv_db_close(db);
}

/* Lights at known metric offsets: cells of 100 m hold exactly the lights placed in them; the
 * radius filter keeps those at 400 m and drops those at 600 m. */
TEST(stats_by_cell_and_radius)
{
    const char *path = fx_tmp("geo.sqlite");
    int64_t sid;
    srv_db *db = survey_fx_create(path, "geo", &sid);
    if (!db) return;
    const double lat0 = 32.8, lon0 = 35.0, R = GIS_EARTH_RADIUS_M, d2r = M_PI / 180.0;
    /* 4 cells at (+-50, +-50) m, cell c holding 3 + c lights on phase c % 3; plus 8 lights at
     * 400 m and 12 at 600 m in all directions (symmetric, so the mean stays at the centre) */
    enum { MAXL = 64 };
    srv_light_row l[MAXL];
    srv_location_row loc[MAXL];
    int nl = 0;
    const double cx[4] = {-50, 50, -50, 50}, cy[4] = {-50, -50, 50, 50};
    for (int c = 0; c < 4; c++)
        for (int k = 0; k < 3 + c; k++) {
            l[nl] = survey_fx_light(nl, 0, 0, 120.0 * (c % 3), 1);
            srv_location_row_init(&loc[nl]);
            loc[nl].method = SRV_LOC_TRUTH;
            double dx = cx[c] + (k - 1) * 5.0 * (c % 2 ? 1 : -1), dy = cy[c];
            loc[nl].lat_deg = lat0 + dy / R / d2r;
            loc[nl].lon_deg = lon0 + dx / (R * cos(lat0 * d2r)) / d2r;
            nl++;
        }
    int base = nl;
    for (int ring = 0; ring < 2; ring++) {
        int count = ring ? 12 : 8;
        double dist = ring ? 600.0 : 400.0;
        for (int k = 0; k < count; k++) {
            double az = 2 * M_PI * k / count;
            l[nl] = survey_fx_light(nl, 0, 0, ring ? 240.0 : 0.0, 1);
            srv_location_row_init(&loc[nl]);
            loc[nl].method = SRV_LOC_TRUTH;
            /* spherical destination point */
            double d = dist / R, la1 = lat0 * d2r;
            double la2 = asin(sin(la1) * cos(d) + cos(la1) * sin(d) * cos(az));
            double lo2 = lon0 * d2r + atan2(sin(az) * sin(d) * cos(la1), cos(d) - sin(la1) * sin(la2));
            loc[nl].lat_deg = la2 / d2r;
            loc[nl].lon_deg = lo2 / d2r;
            nl++;
        }
    }
    (void)base;
    srv_capture_data cd = survey_fx_capture(sid, "geo", l, loc, (size_t)nl);
    CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    size_t n = 0;
    char by[128];
    snprintf(by, sizeof by, "radius:%.10f,%.10f,500", lat0, lon0);
    srv_phase_stats *g = compute(db, by, 0.0, &n, NULL);
    CHECK_MSG(n == 1 && g[0].lights == 18 + 8 && g[0].n[0] == 3 + 6 + 8 && g[0].n[1] == 4 && g[0].n[2] == 5,
              "radius: %ld lights, %ld / %ld / %ld", g[0].lights, g[0].n[0], g[0].n[1], g[0].n[2]);
    free(g);
    snprintf(by, sizeof by, "radius:%.10f,%.10f,700m", lat0, lon0);
    g = compute(db, by, 0.0, &n, NULL);
    CHECK(n == 1 && g[0].lights == nl);
    free(g);
    snprintf(by, sizeof by, "radius:%.10f,%.10f,30", lat0, lon0 + 0.5);
    g = compute(db, by, 0.0, &n, NULL);
    CHECK(n == 1 && g[0].lights == 0 && (g[0].flags & SRV_STATS_EMPTY));
    free(g);
    /* cells: the 4 inner ones hold 3, 4, 5, 6 lights on phases 0, 120, 240, 0; the rings add
     * cells of their own at 400 and 600 m */
    g = compute(db, "cell:100", 0.0, &n, NULL);
    const char *want[4] = {"-1,-1", "0,-1", "-1,0", "0,0"};
    for (int c = 0; c < 4; c++) {
        int found = 0;
        for (size_t i = 0; i < n; i++) {
            if (strcmp(g[i].group, want[c])) continue;
            found = 1;
            int extra = 0;   /* no ring light falls within 100 m of the centre */
            CHECK_MSG(g[i].lights == 3 + c + extra, "cell %s: %ld lights", want[c], g[i].lights);
            CHECK(g[i].n[c % 3] == 3 + c);
            /* the cell's centre: (index + 1/2) cells from the mean position of the lights */
            double mlat = 0, mlon = 0;
            for (int k = 0; k < nl; k++) {
                mlat += loc[k].lat_deg / nl;
                mlon += loc[k].lon_deg / nl;
            }
            int ix = c % 2 ? 0 : -1, iy = c < 2 ? -1 : 0;
            double clat = mlat + (iy + 0.5) * 100.0 / R / d2r;
            double clon = mlon + (ix + 0.5) * 100.0 / (R * cos(mlat * d2r)) / d2r;
            CHECK_NEAR(g[i].lat_deg, clat, 1e-9);
            CHECK_NEAR(g[i].lon_deg, clon, 1e-9);
        }
        CHECK_MSG(found, "cell %s missing", want[c]);
    }
    long total = 0;
    for (size_t i = 0; i < n; i++) total += g[i].lights;
    CHECK(total == nl);
    free(g);
    srv_db_close(db);
}

/* The paper's Haifa-like answer with its uncertainty, end to end through the CLI. */
TEST(stats_cli_haifa_example)
{
    const char *path = fx_tmp("haifa.sqlite");
    srv_db *db = NULL;
    CHECK_OK(srv_db_open(path, SRV_DB_CREATE, &db));
    if (!db) return;
    srv_survey_row sr = {"haifa", "Haifa", NULL, NULL, 50};
    int64_t sid;
    CHECK_OK(srv_db_add_survey(db, &sr, &sid));
    enum { N = 1000 };
    srv_light_row *l = malloc(N * sizeof *l);
    for (int i = 0; i < N; i++) {
        l[i] = survey_fx_light(i, i, i, i < 334 ? 0.0 : i < 334 + 363 ? 120.0 : 240.0, 0.99);
        l[i].technology = "sodium_hp";
        l[i].bulb_id = "sodium_hp_150w";
    }
    srv_capture_data cd = survey_fx_capture(sid, "bay", l, NULL, N);
    CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    srv_db_close(db);
    free(l);
    CHECK(run("%s stats --db %s", path, NULL, NULL) == 0);
    CHECK(strstr(out, "| all | 1000 | 0 | 0 | 0 | 1000 | 33.4 % [30.5, 36.4] (334) | 36.3 % [33.4, 39.3] (363) | "
                      "30.3 % [27.5, 33.2] (303) | 5.40 | 0.0671 | 0.091 |") != NULL);
    /* the footnote names the threshold only when one is given: every light (0.99) below 0.995 */
    CHECK(strstr(out, "below: none (no phase-confidence threshold); ") != NULL);
    CHECK(run("%s stats --db %s --min-phase-confidence 0.995", path, NULL, NULL) == 0);
    CHECK(strstr(out, "| all | 1000 | 1000 | 0 | 0 | 0 |") != NULL &&
          strstr(out, "below: phase confidence < 0.995 (left out); ") != NULL);
    CHECK(run("%s stats --db %s --format json --by technology", path, NULL, NULL) == 0);
    json_error_t err;
    json_t *root = json_loads(out, 0, &err);
    CHECK_MSG(root != NULL, "JSON: %s", err.text);
    json_t *g0 = json_array_get(json_object_get(root, "groups"), 0);
    CHECK(!strcmp(json_string_value(json_object_get(g0, "group")), "sodium_hp"));
    double chi2 = (pow(334 - 1000 / 3.0, 2) + pow(363 - 1000 / 3.0, 2) + pow(303 - 1000 / 3.0, 2)) / (1000 / 3.0);
    CHECK_NEAR(json_real_value(json_object_get(g0, "chi2")), chi2, 1e-8);
    CHECK_NEAR(json_real_value(json_object_get(g0, "p_value")), exp(-chi2 / 2), 1e-10);
    CHECK_NEAR(json_real_value(json_object_get(json_object_get(g0, "shares"), "120")), 0.363, 1e-12);
    double rlo, rhi;
    wilson_roots(363, 1000, SRV_Z95, &rlo, &rhi);
    json_t *ci = json_object_get(json_object_get(g0, "wilson95"), "120");
    CHECK_NEAR(json_real_value(json_array_get(ci, 0)), rlo, 1e-9);
    CHECK_NEAR(json_real_value(json_array_get(ci, 1)), rhi, 1e-9);
    CHECK_NEAR(json_real_value(json_object_get(g0, "imbalance")), 3 * (1 / 3.0 - 0.303), 1e-9);
    json_decref(root);
    CHECK(run("%s stats --db %s --format csv --survey haifa", path, NULL, NULL) == 0);
    CHECK(fx_count_lines(out) == 2 && !strncmp(out, "group,lat_deg,lon_deg,lights,", 29));
    CHECK(strstr(out, "\nall,,,1000,0,0,0,334,363,303,1000,0.334,") != NULL);
}

TEST(stats_cli_bad_input)
{
    const char *path = fx_tmp("b.sqlite");
    synth(path, "b", 1, 10, 1, 1, 1, 1, 100);
    CHECK(run("%s stats --help", NULL, NULL, NULL) == 0 && strstr(out, "Wilson"));
    CHECK(run("%s stats --db %s --by colour", path, NULL, NULL) == 2 && fx_count_lines(out) == 1);
    CHECK(run("%s stats --db %s --by cell:0", path, NULL, NULL) == 2);
    CHECK(run("%s stats --db %s --by radius:95,1,100", path, NULL, NULL) == 2);
    CHECK(run("%s stats --db %s --min-phase-confidence 1.5", path, NULL, NULL) == 2);
    CHECK(run("%s stats --db %s --format xml", path, NULL, NULL) == 2);
    CHECK(run("%s stats", NULL, NULL, NULL) == 2);
    CHECK(run("%s stats --db %s --survey nobody", path, NULL, NULL) == 1);
    CHECK(fx_count_lines(out) == 1 && strstr(out, "nobody"));
    CHECK(run("%s stats --db %s --by cell:100m --format csv", path, NULL, NULL) == 0);
    CHECK(run("%s stats --db %s --by survey", path, NULL, NULL) == 0 && strstr(out, "| b |"));
}

/* `gridsurvey bench db --quick` (srv_bench_db) runs and prints its Markdown table. */
TEST(stats_bench_db_quick_runs)
{
    const char *log = fx_tmp("bench.md");
    fflush(stdout);
    int saved = dup(1), fd = open(log, O_WRONLY | O_CREAT | O_TRUNC, 0644);
    CHECK(saved >= 0 && fd >= 0);
    if (saved < 0 || fd < 0) return;
    dup2(fd, 1);
    close(fd);
    char a0[] = "db", a1[] = "--quick", a2[] = "--dir";
    char *argv[] = {a0, a1, a2, (char *)test_tmpdir(), NULL};
    int rc = srv_bench_db(4, argv);
    fflush(stdout);
    dup2(saved, 1);
    close(saved);
    CHECK(rc == 0);
    char *md = fx_read_file(log, NULL);
    CHECK(md && strstr(md, "| lights | ingest s | lights/s |") != NULL);
    CHECK(md && strstr(md, "\n| 10000 | ") != NULL);
    free(md);
    const char *p = fx_tmp("bench.sqlite");
    struct stat st;
    CHECK(stat(p, &st) != 0);   /* removed without --keep */
}
