/* test_pg.c - `gridsurvey push` and `stats --pg` (survey/pg*.c, docs/postgis.md) against a
 * throw-away PostgreSQL + PostGIS cluster (tests/pg_fixture.c). Oracles: the SQLite file's own
 * row counts and `stats --db` output (byte-equal), its phase_balance view and srv_stats_compute
 * (the PostGIS views to 1e-12), the union of the pushed files' natural keys counted with plain
 * SQL, and the xmin of every row (a re-push rewrites none). */
#include "survey/survey.h"
#include "tests/pg_fixture.h"
#include "tests/survey_fixture.h"
#include "tests/test.h"

#include <math.h>
#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char *const tables[] = {"surveys", "stations", "delight_versions", "captures", "frames",
                                     "grid_frequency", "lights", "locations", "light_sites",
                                     "site_detections"};
#define NTABLES (sizeof tables / sizeof *tables)

static char out_a[1 << 16], out_b[1 << 16];

static int push(const char *db, const char *pg, const char *extra, char *out, size_t size)
{
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "%s push --db %s --pg '%s' %s", test_bin(), db, pg, extra ? extra : "");
    return test_run(cmd, out, size);
}

/* Every table's row count in the SQLite file equals PostgreSQL's. */
static void check_counts_equal(const char *db, PGconn *c)
{
    sqlite3 *h;
    CHECK(sqlite3_open_v2(db, &h, SQLITE_OPEN_READONLY, NULL) == SQLITE_OK);
    for (size_t i = 0; i < NTABLES; i++) {
        char sql[128];
        snprintf(sql, sizeof sql, "SELECT count(*) FROM %s", tables[i]);
        long a = survey_fx_query_long(h, sql);
        snprintf(sql, sizeof sql, "SELECT count(*) FROM gridsurvey.%s", tables[i]);
        long b = pg_fx_long(c, sql);
        CHECK_MSG(a == b && (a > 0 || !strcmp(tables[i], "delight_versions")), "%s: %ld rows in SQLite, %ld in PostgreSQL", tables[i], a, b);
    }
    sqlite3_close(h);
}

/* No capture in PostgreSQL lacks a row its counts promise (a pushed capture is complete). */
static long incomplete_captures(PGconn *c)
{
    return pg_fx_long(c, "SELECT count(*) FROM gridsurvey.captures c WHERE "
                         "light_count <> (SELECT count(*) FROM gridsurvey.lights l WHERE l.capture_id = c.id) "
                         "OR light_count <> (SELECT count(*) FROM gridsurvey.locations l WHERE l.capture_id = c.id) "
                         "OR frame_count <> (SELECT count(*) FROM gridsurvey.frames f WHERE f.capture_id = c.id) "
                         "OR frequency_count <> (SELECT count(*) FROM gridsurvey.grid_frequency f "
                         "WHERE f.capture_id = c.id)");
}

/* `stats --db` and `stats --pg` print the same bytes. */
static void check_stats_equal(const char *db, const char *pg, const char *args)
{
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "%s stats --db %s %s", test_bin(), db, args);
    int ra = test_run(cmd, out_a, sizeof out_a);
    snprintf(cmd, sizeof cmd, "%s stats --pg '%s' %s", test_bin(), pg, args);
    int rb = test_run(cmd, out_b, sizeof out_b);
    CHECK_MSG(ra == 0 && rb == 0 && !strcmp(out_a, out_b) && strlen(out_a) > 100,
              "stats %s: --db (status %d) and --pg (status %d) differ:\n%s\n---\n%s", args, ra, rb,
              out_a, out_b);
}

static void write_feeders(const char *path)
{
    FILE *f = fopen(path, "w");
    CHECK(f != NULL);
    if (!f) return;
    fputs("{\"type\": \"FeatureCollection\", \"features\": [\n"
          "{\"type\": \"Feature\", \"properties\": {\"feeder\": \"F1\"}, \"geometry\": {\"type\": \"Polygon\","
          " \"coordinates\": [[[35.012, 32.795], [35.021, 32.795], [35.021, 32.803], [35.012, 32.803],"
          " [35.012, 32.795]], [[35.015, 32.798], [35.017, 32.798], [35.017, 32.800], [35.015, 32.798]]]}},\n"
          "{\"type\": \"Feature\", \"properties\": {\"feeder\": \"F2\"}, \"geometry\": {\"type\": \"MultiPolygon\","
          " \"coordinates\": [[[[35.019, 32.797], [35.028, 32.797], [35.028, 32.806], [35.019, 32.806],"
          " [35.019, 32.797]]], [[[35.010, 32.804], [35.016, 32.804], [35.013, 32.808], [35.010, 32.804]]]]}}\n"
          "]}\n", f);
    fclose(f);
}

/* Two surveys (10 + 6 captures of 200 lights around one point, so sites gather detections from
 * several captures and both surveys) in one file. */
static void two_surveys(const char *db)
{
    srv_synth_opts o = survey_fx_synth_opts("alpha", 10, 200, 3);
    o.half_width_m = 300.0;
    survey_fx_synth(db, &o);
    o = survey_fx_synth_opts("beta", 6, 200, 4);
    o.half_width_m = 300.0;
    survey_fx_synth(db, &o);
}

/* The bulb labels of the site posteriors (docs/survey-db.md "Light sites"): a DELIGHT version
 * of 200 entries for every capture, survey alpha's captures matched against 7 candidates, beta's
 * stored without the count (NULL: the 200 entries), so that stats over alpha, beta and both
 * combine with different M; the sites recomputed with them (as if ingested so). */
static void set_bulb_labels(const char *db)
{
    sqlite3 *h;
    CHECK(sqlite3_open_v2(db, &h, SQLITE_OPEN_READWRITE, NULL) == SQLITE_OK);
    CHECK(sqlite3_exec(h, "INSERT INTO delight_versions(sha256, generator, source, bulbs, added_utc) "
                          "VALUES (printf('%064d', 0), 'g', 'built-in', 200, 'then');"
                          "UPDATE captures SET delight_id = 1, candidate_bulbs = CASE WHEN survey_id = "
                          "(SELECT id FROM surveys WHERE name = 'alpha') THEN 7 END;"
                          "UPDATE light_sites SET stale = 1", NULL, NULL, NULL) == SQLITE_OK);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM captures WHERE candidate_bulbs = 7") == 10);
    sqlite3_close(h);
    srv_db *w = NULL;
    CHECK_OK(srv_db_open(db, SRV_DB_WRITE, &w));
    if (w) CHECK_OK(srv_db_associate(w, NULL, NULL, NULL));
    srv_db_close(w);
}

static double col(const PGresult *r, int i, const char *name)
{
    int j = PQfnumber(r, name);
    return j < 0 || PQgetisnull(r, i, j) ? NAN : strtod(PQgetvalue(r, i, j), NULL);
}

static int same(double a, double b)
{
    return (isnan(a) && isnan(b)) || fabs(a - b) <= 1e-12;
}

/* Row i of a PostGIS balance view equals g (counts exact; a six-phase light is 'other' there). */
static void check_balance_row(const PGresult *r, int i, const srv_phase_stats *g, const char *what)
{
    long other = g->other + g->n30[0] + g->n30[1] + g->n30[2];
    CHECK_MSG(col(r, i, "lights") == g->lights && col(r, i, "unknown") == g->unknown &&
              col(r, i, "other") == other && col(r, i, "n0") == g->n[0] && col(r, i, "n120") == g->n[1] &&
              col(r, i, "n240") == g->n[2] && col(r, i, "n") == g->total,
              "%s %s: counts %g %g %g / %g %g %g vs %ld %ld %ld / %ld %ld %ld", what, g->group,
              col(r, i, "lights"), col(r, i, "unknown"), col(r, i, "other"), col(r, i, "n0"),
              col(r, i, "n120"), col(r, i, "n240"), g->lights, g->unknown, other, g->n[0], g->n[1], g->n[2]);
    static const char *const names[] = {"share0", "lo0", "hi0", "share120", "lo120", "hi120",
                                        "share240", "lo240", "hi240", "chi2", "p_value", "imbalance"};
    double v[] = {g->share[0], g->lo[0], g->hi[0], g->share[1], g->lo[1], g->hi[1], g->share[2],
                  g->lo[2], g->hi[2], g->chi2, g->p_value, g->imbalance};
    for (int k = 0; k < 12; k++)
        CHECK_MSG(same(col(r, i, names[k]), v[k]), "%s %s: %s %.17g vs %.17g", what, g->group, names[k],
                  col(r, i, names[k]), v[k]);
}

/* The C statistics of the SQLite file under o. */
static srv_phase_stats *c_stats(const char *db, const srv_stats_opts *o, size_t *n)
{
    srv_db *h = NULL;
    srv_phase_stats *g = NULL;
    *n = 0;
    CHECK_OK(srv_db_open(db, SRV_DB_READ, &h));
    if (h) CHECK_OK(srv_stats_compute(h, o, &g, n, NULL));
    srv_db_close(h);
    return g;
}

/* The PostGIS views (site_balance, site_balance_cells, area_balance, phase_balance) give the
 * numbers of srv_stats_compute and of the SQLite phase_balance view. */
static void check_views(const char *db, const char *feeders, PGconn *c)
{
    srv_stats_opts o;
    size_t n;
    srv_stats_opts_default(&o);
    CHECK_OK(srv_stats_parse_by("technology", &o));
    srv_phase_stats *g = c_stats(db, &o, &n);
    PGresult *r = PQexec(c, "SELECT * FROM gridsurvey.site_balance WHERE grouping = 'technology' "
                            "ORDER BY grp COLLATE \"C\"");
    CHECK_MSG(PQntuples(r) == (int)n && n >= 3, "site_balance: %d technologies, stats %zu", PQntuples(r), n);
    for (size_t i = 0; i < n && (int)i < PQntuples(r); i++) {
        CHECK(!strcmp(PQgetvalue(r, (int)i, PQfnumber(r, "grp")), g[i].group));
        check_balance_row(r, (int)i, &g[i], "site_balance");
    }
    PQclear(r);
    free(g);

    srv_stats_opts_default(&o);
    CHECK_OK(srv_stats_parse_by("cell:250", &o));
    g = c_stats(db, &o, &n);
    r = PQexec(c, "SELECT * FROM gridsurvey.site_balance_cells(250)");
    CHECK_MSG(PQntuples(r) == (int)n && n >= 4, "site_balance_cells: %d cells, stats %zu", PQntuples(r), n);
    for (size_t i = 0; i < n && (int)i < PQntuples(r); i++) {
        char name[64];
        snprintf(name, sizeof name, "%s,%s", PQgetvalue(r, (int)i, 0), PQgetvalue(r, (int)i, 1));
        CHECK_MSG(!strcmp(name, g[i].group), "cell %zu: %s vs %s", i, name, g[i].group);
        CHECK(fabs(col(r, (int)i, "lat_deg") - g[i].lat_deg) < 1e-9 &&
              fabs(col(r, (int)i, "lon_deg") - g[i].lon_deg) < 1e-9);
        check_balance_row(r, (int)i, &g[i], "site_balance_cells");
    }
    PQclear(r);
    free(g);

    srv_areas *areas = NULL;
    CHECK_OK(srv_areas_load(feeders, "feeder", &areas));
    srv_stats_opts_default(&o);
    CHECK_OK(srv_stats_parse_by("feature:feeder", &o));
    o.areas = areas;
    g = c_stats(db, &o, &n);
    r = PQexec(c, "SELECT * FROM gridsurvey.area_balance WHERE layer = 'feeder' ORDER BY label");
    CHECK_MSG(PQntuples(r) == (int)n && n == 2, "area_balance: %d areas, stats %zu", PQntuples(r), n);
    for (size_t i = 0; i < n && (int)i < PQntuples(r); i++) {
        CHECK(!strcmp(PQgetvalue(r, (int)i, PQfnumber(r, "label")), g[i].group));
        check_balance_row(r, (int)i, &g[i], "area_balance");
    }
    PQclear(r);
    free(g);
    srv_areas_free(areas);

    /* detections: the SQLite view, row by row */
    sqlite3 *h;
    sqlite3_stmt *q;
    CHECK(sqlite3_open_v2(db, &h, SQLITE_OPEN_READONLY, NULL) == SQLITE_OK);
    CHECK(sqlite3_prepare_v2(h, "SELECT grouping, grp, lights, unknown, other, n0, n120, n240, n, share0, lo0, hi0, "
                                "share120, lo120, hi120, share240, lo240, hi240, chi2, p_value, imbalance "
                                "FROM phase_balance ORDER BY grouping, grp", -1, &q, NULL) == SQLITE_OK);
    r = PQexec(c, "SELECT grouping, grp, lights, unknown, other, n0, n120, n240, n, share0, lo0, hi0, "
                  "share120, lo120, hi120, share240, lo240, hi240, chi2, p_value, imbalance "
                  "FROM gridsurvey.phase_balance ORDER BY grouping COLLATE \"C\", grp COLLATE \"C\"");
    int i = 0;
    while (sqlite3_step(q) == SQLITE_ROW) {
        CHECK_MSG(i < PQntuples(r), "phase_balance: fewer rows in PostgreSQL");
        if (i >= PQntuples(r)) break;
        CHECK(!strcmp((const char *)sqlite3_column_text(q, 1), PQgetvalue(r, i, 1)));
        for (int k = 2; k < 21; k++) {
            double a = sqlite3_column_double(q, k), b = strtod(PQgetvalue(r, i, k), NULL);
            /* the SQLite view does not clamp the Wilson bounds to [0, 1] */
            CHECK_MSG(fabs(a - b) <= 1e-12, "phase_balance %s %s: column %d: %.17g vs %.17g",
                      sqlite3_column_text(q, 0), sqlite3_column_text(q, 1), k, a, b);
        }
        i++;
    }
    CHECK_MSG(i == PQntuples(r) && i >= 5, "phase_balance: %d rows in SQLite, %d in PostgreSQL", i, PQntuples(r));
    PQclear(r);
    sqlite3_finalize(q);
    sqlite3_close(h);
}

TEST_TIMEOUT(pg_push_then_stats_equal_sqlite, 600)
{
    const char *pg0 = pg_fx_database("push_stats");
    if (!pg0) return;
    char pg[256], db[512], feeders[512], extra[600];
    snprintf(pg, sizeof pg, "%s", pg0);
    snprintf(db, sizeof db, "%s/a.sqlite", test_tmpdir());
    snprintf(feeders, sizeof feeders, "%s/feeders.geojson", test_tmpdir());
    two_surveys(db);
    set_bulb_labels(db);
    write_feeders(feeders);
    /* nothing pushed yet: a reader refuses (and creates nothing) */
    char cmd[1024];
    snprintf(cmd, sizeof cmd, "%s stats --pg '%s'", test_bin(), pg);
    CHECK(test_run(cmd, out_b, sizeof out_b) == 1 && strstr(out_b, "no schema gridsurvey"));
    snprintf(extra, sizeof extra, "--areas %s --field feeder", feeders);
    CHECK_MSG(push(db, pg, extra, out_a, sizeof out_a) == 0, "push: %s", out_a);
    PGconn *c = pg_fx_connect(pg);
    if (!c) return;
    check_counts_equal(db, c);
    CHECK(incomplete_captures(c) == 0);
    CHECK(pg_fx_long(c, "SELECT count(*) FROM gridsurvey.areas") == 2);
    CHECK(pg_fx_long(c, "SELECT count(*) FROM gridsurvey.captures c JOIN gridsurvey.surveys s ON "
                        "s.id = c.survey_id WHERE s.name = 'alpha' AND c.candidate_bulbs = 7") == 10 &&
          pg_fx_long(c, "SELECT count(*) FROM gridsurvey.captures WHERE candidate_bulbs IS NULL") == 6);
    /* positions as PostGIS points */
    CHECK(pg_fx_long(c, "SELECT count(*) FROM gridsurvey.locations WHERE geom IS NOT NULL AND "
                        "ST_X(geom) = lon_deg AND ST_Y(geom) = lat_deg") ==
          pg_fx_long(c, "SELECT count(*) FROM gridsurvey.locations WHERE lat_deg IS NOT NULL"));
    static const char *const args[] = {
        "--format csv", "--by technology --format csv", "--by survey --format csv",
        "--by cell:250 --format csv", "--by technology,cell:500", "--by survey,technology --format csv",
        "--detections --by technology --format csv", "--min-phase-confidence 0.9 --by cell:300 --format csv",
        "--survey beta --by technology --format csv", "--by radius:32.80,35.02,400 --format csv",
        "--bbox 35.012,32.795,35.024,32.805 --by technology --format csv",
    };
    for (size_t i = 0; i < sizeof args / sizeof *args; i++) check_stats_equal(db, pg, args[i]);
    snprintf(extra, sizeof extra, "--clip %s --by feature:feeder,technology --format csv", feeders);
    check_stats_equal(db, pg, extra);
    check_views(db, feeders, c);
    /* a survey that is not there: the same refusal as --db */
    snprintf(cmd, sizeof cmd, "%s stats --pg '%s' --survey nosuch", test_bin(), pg);
    CHECK(test_run(cmd, out_b, sizeof out_b) != 0 && strstr(out_b, "no survey named 'nosuch'"));
    PQfinish(c);
}

/* The sum over every row of each table of its xmin, and the counts: a re-push that rewrote a
 * row would change its xmin. */
static void table_digest(PGconn *c, long counts[NTABLES], double xmins[NTABLES])
{
    for (size_t i = 0; i < NTABLES; i++) {
        char sql[160];
        snprintf(sql, sizeof sql, "SELECT count(*) FROM gridsurvey.%s", tables[i]);
        counts[i] = pg_fx_long(c, sql);
        snprintf(sql, sizeof sql, "SELECT coalesce(sum(xmin::text::bigint), 0) FROM gridsurvey.%s", tables[i]);
        xmins[i] = pg_fx_double(c, sql);
    }
}

TEST_TIMEOUT(pg_repush_changes_nothing_and_adds_new_captures, 600)
{
    const char *pg0 = pg_fx_database("repush");
    if (!pg0) return;
    char pg[256], db[512];
    snprintf(pg, sizeof pg, "%s", pg0);
    snprintf(db, sizeof db, "%s/a.sqlite", test_tmpdir());
    srv_synth_opts o = survey_fx_synth_opts("alpha", 10, 200, 7);
    o.half_width_m = 300.0;
    survey_fx_synth(db, &o);
    CHECK_MSG(push(db, pg, NULL, out_a, sizeof out_a) == 0, "push: %s", out_a);
    PGconn *c = pg_fx_connect(pg);
    if (!c) return;
    long n0[NTABLES], n1[NTABLES];
    double x0[NTABLES], x1[NTABLES];
    table_digest(c, n0, x0);
    CHECK_MSG(push(db, pg, NULL, out_a, sizeof out_a) == 0 && strstr(out_a, "(0 new, 0 lights)") &&
              strstr(out_a, "(0 written)"), "re-push: %s", out_a);
    table_digest(c, n1, x1);
    for (size_t i = 0; i < NTABLES; i++)
        CHECK_MSG(n0[i] == n1[i] && x0[i] == x1[i] && (n0[i] > 0 || i == 2), "%s: %ld rows (xmin sum %.0f), then %ld (%.0f)",
                  tables[i], n0[i], x0[i], n1[i], x1[i]);
    /* two more captures in the file: a push adds exactly them and refreshes the sites they joined */
    o.captures = 12;
    survey_fx_synth(db, &o);
    CHECK_MSG(push(db, pg, NULL, out_a, sizeof out_a) == 0 && strstr(out_a, "(2 new, 400 lights)"), "push: %s", out_a);
    check_counts_equal(db, c);
    CHECK(incomplete_captures(c) == 0);
    check_stats_equal(db, pg, "--by technology --format csv");
    PQfinish(c);
}

/* Four stations push at once: each file holds the survey "common" (the same captures: every
 * pusher races for each of them) and one of its own, far apart. */
TEST_TIMEOUT(pg_four_concurrent_pushers_give_the_union, 600)
{
    const char *pg0 = pg_fx_database("concurrent");
    if (!pg0) return;
    char pg[256], db[4][512], merged[512];
    snprintf(pg, sizeof pg, "%s", pg0);
    snprintf(merged, sizeof merged, "%s/merged.sqlite", test_tmpdir());
    srv_synth_opts common = survey_fx_synth_opts("common", 8, 200, 11);
    common.half_width_m = 300.0;
    survey_fx_synth(merged, &common);
    for (int i = 0; i < 4; i++) {
        char name[16];
        snprintf(name, sizeof name, "own%d", i);
        snprintf(db[i], sizeof db[i], "%s/station%d.sqlite", test_tmpdir(), i);
        survey_fx_synth(db[i], &common);
        srv_synth_opts own = survey_fx_synth_opts(name, 6, 200, 20 + (unsigned long long)i);
        own.half_width_m = 300.0;
        own.lat_deg = 32.80 + 0.05 * (i + 1);   /* 5.5 km apart: no shared sites */
        survey_fx_synth(db[i], &own);
        survey_fx_synth(merged, &own);
    }
    char cmd[4096];
    int used = snprintf(cmd, sizeof cmd, "fail=0; ");
    for (int i = 0; i < 4; i++)
        used += snprintf(cmd + used, sizeof cmd - (size_t)used, "%s push --db %s --pg '%s' --batch 400 & p%d=$!; ",
                         test_bin(), db[i], pg, i);
    snprintf(cmd + used, sizeof cmd - (size_t)used,
             "for p in $p0 $p1 $p2 $p3; do wait $p || fail=1; done; exit $fail");
    CHECK_MSG(test_run(cmd, out_a, sizeof out_a) == 0, "pushers: %s", out_a);
    PGconn *c = pg_fx_connect(pg);
    if (!c) return;
    /* the union of the natural keys, counted in the files: the merged file holds each once */
    check_counts_equal(merged, c);
    CHECK(pg_fx_long(c, "SELECT count(*) FROM gridsurvey.captures") == 8 + 4 * 6);
    CHECK(pg_fx_long(c, "SELECT count(*) FROM gridsurvey.lights") == (8 + 4 * 6) * 200);
    CHECK(pg_fx_long(c, "SELECT count(*) FROM gridsurvey.surveys") == 5);
    CHECK(incomplete_captures(c) == 0);
    check_stats_equal(merged, pg, "--by survey,technology --format csv");
    check_stats_equal(merged, pg, "--detections --by technology --format csv");
    PQfinish(c);
}

/* A push stopped by a failure (a trigger refusing one capture), then one killed (SIGKILL) while
 * the server holds it inside a capture's transaction: the committed captures are complete, and
 * a new push completes the rest without a duplicate. */
TEST_TIMEOUT(pg_interrupted_push_resumes_without_duplicates, 600)
{
    const char *pg0 = pg_fx_database("interrupted");
    if (!pg0) return;
    char pg[256], db[512], empty[512], cmd[2048];
    snprintf(pg, sizeof pg, "%s", pg0);
    snprintf(db, sizeof db, "%s/a.sqlite", test_tmpdir());
    snprintf(empty, sizeof empty, "%s/empty.sqlite", test_tmpdir());
    srv_synth_opts o = survey_fx_synth_opts("alpha", 12, 150, 5);
    o.half_width_m = 300.0;
    survey_fx_synth(db, &o);
    srv_db *e = NULL;
    CHECK_OK(srv_db_open(empty, SRV_DB_CREATE, &e));
    srv_db_close(e);
    CHECK_MSG(push(empty, pg, NULL, out_a, sizeof out_a) == 0, "push (schema): %s", out_a);
    PGconn *c = pg_fx_connect(pg);
    if (!c) return;
    pg_fx_exec(c, "CREATE FUNCTION public.refuse() RETURNS trigger LANGUAGE plpgsql AS $$ BEGIN "
                  "IF NEW.capture_key = 'synth-000007' THEN RAISE EXCEPTION 'forced failure'; END IF; "
                  "RETURN NEW; END $$");
    pg_fx_exec(c, "CREATE TRIGGER refuse BEFORE INSERT ON gridsurvey.captures FOR EACH ROW "
                  "EXECUTE FUNCTION public.refuse()");
    CHECK_MSG(push(db, pg, "--batch 1", out_a, sizeof out_a) != 0 && strstr(out_a, "forced failure"),
              "push: %s", out_a);
    CHECK(pg_fx_long(c, "SELECT count(*) FROM gridsurvey.captures") == 7);
    CHECK(incomplete_captures(c) == 0);
    CHECK(pg_fx_long(c, "SELECT count(*) FROM gridsurvey.light_sites") == 0);
    pg_fx_exec(c, "DROP TRIGGER refuse ON gridsurvey.captures");
    CHECK_MSG(push(db, pg, "--batch 1", out_a, sizeof out_a) == 0 && strstr(out_a, "(5 new, 750 lights)"),
              "resumed push: %s", out_a);
    check_counts_equal(db, c);
    CHECK(incomplete_captures(c) == 0);
    check_stats_equal(db, pg, "--by cell:250 --format csv");

    /* killed: a second database; the server sleeps inside capture 5's transaction */
    const char *pg1 = pg_fx_database("killed");
    if (!pg1) return;
    snprintf(pg, sizeof pg, "%s", pg1);
    PQfinish(c);
    CHECK_MSG(push(empty, pg, NULL, out_a, sizeof out_a) == 0, "push (schema): %s", out_a);
    c = pg_fx_connect(pg);
    if (!c) return;
    pg_fx_exec(c, "CREATE FUNCTION public.stall() RETURNS trigger LANGUAGE plpgsql AS $$ BEGIN "
                  "IF NEW.capture_key = 'synth-000005' THEN PERFORM pg_sleep(3); END IF; RETURN NEW; END $$");
    pg_fx_exec(c, "CREATE TRIGGER stall BEFORE INSERT ON gridsurvey.captures FOR EACH ROW "
                  "EXECUTE FUNCTION public.stall()");
    char pidfile[600];
    snprintf(pidfile, sizeof pidfile, "%s/push.pid", test_tmpdir());
    snprintf(cmd, sizeof cmd, "%s push --db %s --pg '%s' --batch 1 >/dev/null 2>&1 & echo $! > %s",
             test_bin(), db, pg, pidfile);
    CHECK(test_run(cmd, NULL, 0) == 0);
    long sleeping = 0;
    for (int i = 0; i < 1200 && sleeping == 0; i++) {   /* up to 60 s */
        sleeping = pg_fx_long(c, "SELECT count(*) FROM pg_stat_activity WHERE wait_event = 'PgSleep'");
        if (!sleeping) test_run("sleep 0.05", NULL, 0);
    }
    CHECK_MSG(sleeping == 1, "the push never reached capture 5");
    snprintf(cmd, sizeof cmd, "kill -9 $(cat %s)", pidfile);
    CHECK(test_run(cmd, NULL, 0) == 0);
    pg_fx_exec(c, "DROP TRIGGER stall ON gridsurvey.captures");   /* waits for the orphan's end */
    CHECK(pg_fx_long(c, "SELECT count(*) FROM gridsurvey.captures") == 5);
    CHECK(incomplete_captures(c) == 0);
    CHECK_MSG(push(db, pg, NULL, out_a, sizeof out_a) == 0 && strstr(out_a, "(7 new, 1050 lights)"),
              "resumed push: %s", out_a);
    check_counts_equal(db, c);
    CHECK(incomplete_captures(c) == 0);
    check_stats_equal(db, pg, "--by technology --format csv");
    PQfinish(c);
}
