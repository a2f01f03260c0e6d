/* test_survey_db.c - the survey database (survey/db.c): schema and migrations, refusal of
 * files that are not survey databases (nothing changed on disk), unwritable paths, read-only
 * handles, idempotent and atomic ingest, the R*Tree kept in sync, SIGKILL at random points
 * during ingest followed by a resume (checked through a raw SQLite connection, independently of
 * the library). `gridsurvey export`: tests/test_survey_export.c. */
#include "gis/gis.h"
#include "survey/survey.h"
#include "tests/fixtures.h"
#include "tests/survey_fixture.h"
#include "tests/test.h"

#include <math.h>
#include <signal.h>
#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

static char out[1 << 18];

/* `gridsurvey ...`: fmt's first %s is the binary (tests/fixtures.h); output in out. */
static int run(const char *fmt, const char *a, const char *b, const char *c)
{
    return fx_run_bin(out, sizeof out, fmt, a, b, c);
}

/* The file at path after `db migrate` (and `db check`: ok), opened for writing; NULL if it does
 * not open. */
static srv_db *migrated(const char *path)
{
    CHECK(run("%s db migrate --db %s", path, NULL, NULL) == 0);
    CHECK(run("%s db check --db %s", path, NULL, NULL) == 0 && strstr(out, ": ok"));
    srv_db *db = NULL;
    CHECK_OK(srv_db_open(path, SRV_DB_WRITE, &db));
    return db;
}

static int sidecars(const char *path)
{
    static const char *const suffix[] = {"-wal", "-shm", "-journal"};
    char p[1100];
    int n = 0;
    for (int i = 0; i < 3; i++) {
        snprintf(p, sizeof p, "%s%s", path, suffix[i]);
        n += fx_exists(p);
    }
    return n;
}

/* A file's bytes, size and modification time, to prove that nothing changed. */
typedef struct {
    char *bytes;
    size_t size;
    struct timespec mtime;
    int sidecars;
} snapshot;

static snapshot take(const char *path)
{
    snapshot s = {0};
    struct stat st;
    if (stat(path, &st) != 0) return s;
    s.mtime = st.st_mtim;
    s.sidecars = sidecars(path);
    FILE *f = fopen(path, "rb");
    if (!f) return s;
    s.bytes = malloc((size_t)st.st_size + 1);
    s.size = fread(s.bytes, 1, (size_t)st.st_size, f);
    fclose(f);
    return s;
}

static int unchanged(const char *path, snapshot *before)
{
    snapshot now = take(path);
    int same = now.bytes && before->bytes && now.size == before->size &&
               !memcmp(now.bytes, before->bytes, now.size) &&
               now.mtime.tv_sec == before->mtime.tv_sec &&
               now.mtime.tv_nsec == before->mtime.tv_nsec && now.sidecars == before->sidecars;
    free(now.bytes);
    return same;
}

/* ------------------------------------------------------------------ schema */

TEST(survey_db_schema_created)
{
    const char *path = fx_tmp("s.sqlite");
    srv_db *db = NULL;
    CHECK_OK(srv_db_open(path, SRV_DB_CREATE, &db));
    if (!db) return;
    sqlite3 *h = srv_db_sqlite(db);
    CHECK(survey_fx_query_long(h, "PRAGMA application_id") == SRV_DB_APPLICATION_ID);
    CHECK(survey_fx_query_long(h, "PRAGMA user_version") == SRV_DB_SCHEMA_VERSION);
    CHECK(survey_fx_query_long(h, "PRAGMA foreign_keys") == 1);
    CHECK(!strcmp(survey_fx_query_text(h, "PRAGMA journal_mode"), "wal"));
    CHECK(survey_fx_query_long(h, "PRAGMA synchronous") == 1);   /* NORMAL */
    CHECK(!strcmp(survey_fx_query_text(h, "SELECT value FROM meta WHERE key = 'format'"), SRV_DB_FORMAT));
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM migrations") == SRV_DB_SCHEMA_VERSION);
    static const char *const objects[] = {
        "surveys", "stations", "captures", "frames", "lights", "locations", "locations_rtree",
        "grid_frequency", "delight_versions", "migrations", "meta", "light_phase",
        "phase_counts", "phase_balance", "locations_rtree_insert", "locations_rtree_delete",
    };
    for (size_t i = 0; i < sizeof objects / sizeof *objects; i++) {
        char sql[256];
        snprintf(sql, sizeof sql, "SELECT count(*) FROM sqlite_master WHERE name = '%s'", objects[i]);
        CHECK_MSG(survey_fx_query_long(h, sql) == 1, "schema object %s missing", objects[i]);
    }
    /* the views need SQLite's math functions (Debian's build has them) */
    CHECK(sqlite3_compileoption_used("ENABLE_MATH_FUNCTIONS") == 1);
    srv_db_close(db);
    /* reopening (all modes) keeps everything; no migration runs twice */
    CHECK_OK(srv_db_open(path, SRV_DB_WRITE, &db));
    CHECK(survey_fx_query_long(srv_db_sqlite(db), "SELECT count(*) FROM migrations") == SRV_DB_SCHEMA_VERSION);
    srv_db_close(db);
    CHECK_OK(srv_db_open(path, SRV_DB_READ, &db));
    srv_db_close(db);
    /* CLI */
    CHECK(run("%s db init --db %s", fx_tmp("cli.sqlite"), NULL, NULL) == 0);
    CHECK(run("%s db check --db %s", fx_tmp("cli.sqlite"), NULL, NULL) == 0 && strstr(out, ": ok"));
    CHECK(run("%s db --help", NULL, NULL, NULL) == 0 && strstr(out, "ingest-synthetic"));
}

TEST(survey_db_migrates_from_v1)
{
    const char *path = fx_tmp("v1.sqlite");
    CHECK_OK(srv_db_create_at_version(path, 1));
    sqlite3 *h = NULL;
    CHECK(sqlite3_open_v2(path, &h, SQLITE_OPEN_READWRITE, NULL) == SQLITE_OK);
    CHECK(survey_fx_query_long(h, "PRAGMA user_version") == 1);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM sqlite_master WHERE name = 'phase_balance'") == 0);
    CHECK(sqlite3_exec(h, "INSERT INTO surveys(name, created_utc) VALUES ('old', 'then');"
                          "INSERT INTO captures(survey_id, capture_key, light_count, frame_count, "
                          "frequency_count, ingested_utc) VALUES (1, 'c1', 1, 0, 0, 'then');"
                          "INSERT INTO lights(capture_id, light_index, x_px, y_px, phase_deg, "
                          "confidence, bulb_confidence, phase_confidence) VALUES (1, 0, 5, 6, 120, "
                          "1, 1, 1)", NULL, NULL, NULL) == SQLITE_OK);
    sqlite3_close(h);
    /* read-only: refused with a hint, file untouched */
    snapshot before = take(path);
    srv_db *db = NULL;
    CHECK(srv_db_open(path, SRV_DB_READ, &db) == GS_EFORMAT && !db);
    CHECK(strstr(gs_detail(), "older") && strstr(gs_detail(), "db migrate") && strstr(gs_detail(), path));
    CHECK(unchanged(path, &before));
    free(before.bytes);
    /* the CLI migrates: one transaction per step, history in `migrations` */
    CHECK(run("%s db migrate --db %s", path, NULL, NULL) == 0);
    CHECK_OK(srv_db_open(path, SRV_DB_READ, &db));
    if (!db) return;
    h = srv_db_sqlite(db);
    CHECK(survey_fx_query_long(h, "PRAGMA user_version") == SRV_DB_SCHEMA_VERSION);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM migrations") == SRV_DB_SCHEMA_VERSION);
    CHECK(survey_fx_query_long(h, "SELECT group_concat(version) = '1,2,3,4,5,6,7' FROM (SELECT version FROM migrations ORDER BY version)") == 1);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM sqlite_master WHERE name = 'light_sites_pose'") == 0);
    CHECK(survey_fx_query_long(h, "SELECT n120 FROM phase_counts WHERE grouping = 'all'") == 1);
    CHECK(survey_fx_query_long(h, "SELECT n120 FROM site_phase_counts WHERE grouping = 'all'") == 1);
    /* migrate associated the old light with a new site of its own */
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM light_sites WHERE phase_deg = 120 AND detections = 1") == 1);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM site_detections") == 1);
    srv_db_close(db);
}

/* Version 4 -> 5 (captures.candidate_bulbs): the captures stored before keep NULL and their
 * site's bulb posterior falls back to the DELIGHT's entry count (docs/survey-db.md "Light
 * sites"): two detections of one light, bulb confidences 0.6 and 0.7, a DELIGHT of 200
 * entries, against c1 c2 / (c1 c2 + (M - 1) r1 r2) with M = 200; a capture stored after the
 * migration records its count. */
TEST(survey_db_migrates_candidate_bulbs)
{
    const char *path = fx_tmp("v4.sqlite");
    CHECK_OK(srv_db_create_at_version(path, 4));
    sqlite3 *h = NULL;
    CHECK(sqlite3_open_v2(path, &h, SQLITE_OPEN_READWRITE, NULL) == SQLITE_OK);
    CHECK(sqlite3_exec(h, "INSERT INTO surveys(name, created_utc) VALUES ('old', 'then');"
                          "INSERT INTO delight_versions(sha256, generator, source, bulbs, added_utc) "
                          "VALUES (printf('%064d', 0), 'g', 'built-in', 200, 'then');"
                          "INSERT INTO captures(survey_id, delight_id, capture_key, light_count, frame_count, "
                          "frequency_count, ingested_utc) VALUES (1, 1, 'c1', 1, 0, 0, 'then'), "
                          "(1, 1, 'c2', 1, 0, 0, 'then');"
                          "INSERT INTO lights(capture_id, light_index, x_px, y_px, bulb_id, technology, "
                          "confidence, bulb_confidence, phase_confidence) VALUES "
                          "(1, 0, 5, 6, 'hps-70w', 'sodium_hp', 0.6, 0.6, 0), "
                          "(2, 0, 5, 6, 'hps-70w', 'sodium_hp', 0.7, 0.7, 0)", NULL, NULL, NULL) == SQLITE_OK);
    sqlite3_close(h);
    srv_db *db = migrated(path);
    if (!db) return;
    h = srv_db_sqlite(db);
    CHECK(survey_fx_query_long(h, "SELECT max(version) FROM migrations") == SRV_DB_SCHEMA_VERSION);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM captures WHERE candidate_bulbs IS NULL") == 2);
    const double M = 200.0, r1 = 0.4 / (M - 1.0), r2 = 0.3 / (M - 1.0);
    double want = 0.42 / (0.42 + (M - 1.0) * r1 * r2);
    double got = strtod(survey_fx_query_text(h, "SELECT bulb_confidence FROM light_sites WHERE detections = 2"), NULL);
    CHECK_MSG(fabs(got - want) < 1e-12, "bulb confidence %.15f, M = 200 gives %.15f", got, want);
    srv_light_row l;
    srv_light_row_init(&l);
    l.x_px = l.y_px = 1.0;
    srv_capture_data cd;
    memset(&cd, 0, sizeof cd);
    srv_capture_row_init(&cd.capture);
    cd.capture.survey_id = 1;
    cd.capture.key = "c3";
    cd.capture.candidate_bulbs = 50;
    cd.lights = &l;
    cd.n_lights = 1;
    CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    CHECK(survey_fx_query_long(h, "SELECT candidate_bulbs FROM captures WHERE capture_key = 'c3'") == 50);
    srv_db_close(db);
}

/* Version 5 -> 6 (site_views): a file associated before, one light located by a june capture
 * and seen unlocated from the same roof in july, is two sites there (a located and a pixel
 * site; a third, distant light a pixel site too). The migration gives each site its view:
 * the roof's pose key (written out here with C's printf) and its detection's pixel; the file
 * checks ok; a located capture from that roof at that pixel joins the located site by
 * position and merges the pixel site into it: one site of three detections, its view their
 * mean pixel. */
TEST(survey_db_migrates_site_views)
{
    const char *path = fx_tmp("v5.sqlite");
    CHECK_OK(srv_db_create_at_version(path, 5));
    sqlite3 *h = NULL;
    CHECK(sqlite3_open_v2(path, &h, SQLITE_OPEN_READWRITE, NULL) == SQLITE_OK);
    CHECK(sqlite3_exec(h, "INSERT INTO surveys(name, created_utc) VALUES ('june', 'then'), ('july', 'then');"
                          "INSERT INTO stations(survey_id, name, lat_deg, lon_deg, height_m, heading_deg, "
                          "pitch_deg, roll_deg, focal_px) VALUES (1, 'roof', 32.8, 35.0, 10, 90, -2, 0, 2000), "
                          "(2, 'roof', 32.8, 35.0, 10, 90, -2, 0, 2000);"
                          "INSERT INTO captures(survey_id, station_id, capture_key, light_count, frame_count, "
                          "frequency_count, ingested_utc) VALUES (1, 1, 'c1', 1, 0, 0, 'then'), "
                          "(2, 2, 'c2', 2, 0, 0, 'then');"
                          "INSERT INTO lights(capture_id, light_index, x_px, y_px, confidence, bulb_confidence, "
                          "phase_confidence) VALUES (1, 0, 500.25, 300.5, 0, 0, 0), (2, 0, 501, 299.75, 0, 0, 0), "
                          "(2, 1, 900, 300, 0, 0, 0);"
                          "INSERT INTO locations(light_id, method, lat_deg, lon_deg, semi_major_m, semi_minor_m, "
                          "azimuth_deg) VALUES (1, 'one_station', 32.801, 35.002, 1, 1, 0);"
                          "INSERT INTO light_sites(lat_deg, lon_deg, semi_major_m, semi_minor_m, azimuth_deg, "
                          "pose_key, x_px, y_px, detections, captures) VALUES "
                          "(32.801, 35.002, 1, 1, 0, NULL, 500.25, 300.5, 1, 1), "
                          "(NULL, NULL, NULL, NULL, NULL, '32.8000000,35.0000000,10.00,90.000,-2.000,0.000,2000.00', "
                          "501, 299.75, 1, 1), "
                          "(NULL, NULL, NULL, NULL, NULL, '32.8000000,35.0000000,10.00,90.000,-2.000,0.000,2000.00', "
                          "900, 300, 1, 1);"
                          "INSERT INTO site_detections(light_id, site_id, capture_id) VALUES (1, 1, 1), (2, 2, 2), "
                          "(3, 3, 2)", NULL, NULL, NULL) == SQLITE_OK);
    sqlite3_close(h);
    srv_db *db = migrated(path);
    if (!db) return;
    h = srv_db_sqlite(db);
    char key[96], want[512];
    snprintf(key, sizeof key, "%.7f,%.7f,%.2f,%.3f,%.3f,%.3f,%.2f", 32.8, 35.0, 10.0, 90.0, -2.0, 0.0, 2000.0);
    snprintf(want, sizeof want, "1 %s 500.25 300.5 1|2 %s 501.0 299.75 1|3 %s 900.0 300.0 1", key, key, key);
    const char *got = survey_fx_query_text(h, "SELECT group_concat(site_id || ' ' || pose_key || ' ' || x_px || ' ' "
                                              "|| y_px || ' ' || detections, '|') FROM (SELECT * FROM site_views "
                                              "ORDER BY site_id)");
    CHECK_MSG(!strcmp(got, want), "site_views: %s\nexpected:   %s", got, want);
    /* a located june detection from the roof, 0.5 m north of site 1, at the july pixel */
    srv_light_row l;
    srv_light_row_init(&l);
    l.x_px = 500.5;
    l.y_px = 300.25;
    l.confidence = l.bulb_confidence = l.phase_confidence = 0.0;
    srv_location_row loc;
    srv_location_row_init(&loc);
    loc.method = SRV_LOC_ONE_STATION;
    double kn, ke;
    gis_metres_per_deg(32.801, &kn, &ke);
    loc.lat_deg = 32.801 + 0.5 / kn;
    loc.lon_deg = 35.002;
    loc.ellipse = (gis_ellipse){1.0, 1.0, 0.0};
    srv_capture_data cd = survey_fx_capture(1, "c3", &l, &loc, 1);
    cd.capture.station_id = 1;
    CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM light_sites") == 2);
    CHECK(survey_fx_query_long(h, "SELECT detections FROM light_sites WHERE id = 1") == 3);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM site_views") == 2);
    double mx = (500.25 + 501.0 + 500.5) / 3.0, my = (300.5 + 299.75 + 300.25) / 3.0;
    double vx = strtod(survey_fx_query_text(h, "SELECT x_px FROM site_views WHERE site_id = 1"), NULL);
    double vy = strtod(survey_fx_query_text(h, "SELECT y_px FROM site_views WHERE site_id = 1"), NULL);
    CHECK_MSG(fabs(vx - mx) < 1e-9 && fabs(vy - my) < 1e-9, "view (%.12g, %.12g), mean (%.12g, %.12g)", vx, vy, mx, my);
    srv_db_close(db);
    CHECK(run("%s db check --db %s", path, NULL, NULL) == 0 && strstr(out, ": ok"));
}

TEST(survey_db_refuses_newer_schema)
{
    const char *path = fx_tmp("new.sqlite");
    CHECK_OK(srv_db_create_at_version(path, SRV_DB_SCHEMA_VERSION));
    sqlite3 *h = NULL;
    CHECK(sqlite3_open_v2(path, &h, SQLITE_OPEN_READWRITE, NULL) == SQLITE_OK);
    CHECK(sqlite3_exec(h, "PRAGMA journal_mode = DELETE; PRAGMA user_version = 99", NULL, NULL, NULL) == SQLITE_OK);
    sqlite3_close(h);
    snapshot before = take(path);
    for (int mode = SRV_DB_READ; mode <= SRV_DB_CREATE; mode++) {
        srv_db *db = NULL;
        CHECK(srv_db_open(path, (srv_db_mode)mode, &db) == GS_EFORMAT && !db);
        CHECK(strstr(gs_detail(), "newer") && strstr(gs_detail(), "99"));
    }
    CHECK(unchanged(path, &before));
    free(before.bytes);
}

/* ------------------------------------------------------------------ bad input */

/* Files that are not survey databases: text, a DELIGHT database, a GeoPackage, an unrelated
 * SQLite database. Every mode refuses each with a one-line error naming the file, and nothing
 * on disk changes (bytes, mtime, no -wal/-shm/-journal). */
TEST(survey_db_refuses_foreign_files)
{
    const char *text = fx_tmp("notes.txt"), *delight = fx_tmp("delight.sqlite"), *gpkg = fx_tmp("l.gpkg"),
               *other = fx_tmp("other.sqlite");
    fx_write_text(text, "this is not a database\nsecond line\n");
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_save(d, delight));
    gs_delight_free(d);
    gis_light l;
    gis_light_init(&l);
    snprintf(l.id, sizeof l.id, "L1");
    l.lat_deg = 32.8;
    l.lon_deg = 35.0;
    CHECK_OK(gis_export_gpkg(&l, 1, gpkg));
    sqlite3 *h = NULL;
    CHECK(sqlite3_open(other, &h) == SQLITE_OK);
    CHECK(sqlite3_exec(h, "CREATE TABLE foo(x); INSERT INTO foo VALUES (1)", NULL, NULL, NULL) == SQLITE_OK);
    sqlite3_close(h);
    const char *files[4] = {text, delight, gpkg, other};
    const char *found[4] = {"not SQLite", "DELIGHT", "GeoPackage", "application_id 0x00000000"};
    for (int i = 0; i < 4; i++) {
        snapshot before = take(files[i]);
        CHECK(before.bytes != NULL);
        for (int mode = SRV_DB_READ; mode <= SRV_DB_CREATE; mode++) {
            srv_db *db = NULL;
            gs_status s = srv_db_open(files[i], (srv_db_mode)mode, &db);
            CHECK_MSG(s == GS_EFORMAT && !db, "%s mode %d: %s", files[i], mode, gs_detail());
            CHECK_MSG(strstr(gs_detail(), files[i]) && strstr(gs_detail(), "not a survey database") &&
                      strstr(gs_detail(), found[i]) && !strchr(gs_detail(), '\n'),
                      "detail: %s", gs_detail());
            srv_db_close(db);
        }
        const char *geo = fx_tmp("x.geojson");
        CHECK(run("%s stats --db %s", files[i], NULL, NULL) == 1);
        CHECK(fx_count_lines(out) == 1 && strstr(out, files[i]) && strstr(out, "not a survey database"));
        CHECK(run("%s export --db %s -o %s", files[i], geo, NULL) == 1);
        CHECK(fx_count_lines(out) == 1 && strstr(out, files[i]));
        CHECK(!fx_exists(geo));
        if (i % 2 == 0) {   /* the writers too (each CLI run costs a process start) */
            CHECK(run("%s db ingest-synthetic --db %s --captures 2", files[i], NULL, NULL) == 1);
            CHECK(fx_count_lines(out) == 1 && strstr(out, files[i]));
        } else {
            CHECK(run("%s db migrate --db %s", files[i], NULL, NULL) == 1);
        }
        CHECK_MSG(unchanged(files[i], &before), "%s changed on disk", files[i]);
        free(before.bytes);
    }
    /* a directory passed as the database */
    srv_db *db = NULL;
    CHECK(srv_db_open(test_tmpdir(), SRV_DB_CREATE, &db) == GS_EIO && !db);
}

/* Paths that cannot be created: the parent is a regular file, the directory does not exist,
 * (as non-root) the directory is read-only. Root ignores directory permissions, so the first
 * two are the ones CI can rely on. Nothing is created anywhere. */
TEST(survey_db_unwritable_paths)
{
    const char *file = fx_tmp("plain");
    fx_write_text(file, "x\n");
    snapshot before = take(file);
    char under_file[1100], missing_dir[1100];
    snprintf(under_file, sizeof under_file, "%s/survey.sqlite", file);
    snprintf(missing_dir, sizeof missing_dir, "%s/no/such/dir/survey.sqlite", test_tmpdir());
    const char *paths[2] = {under_file, missing_dir};
    for (int i = 0; i < 2; i++) {
        srv_db *db = NULL;
        CHECK(srv_db_open(paths[i], SRV_DB_CREATE, &db) == GS_EIO && !db);
        CHECK(strstr(gs_detail(), paths[i]) != NULL);
        CHECK(run("%s db init --db %s", paths[i], NULL, NULL) == 1);
        CHECK(fx_count_lines(out) == 1 && strstr(out, paths[i]));
        CHECK(run("%s db ingest-synthetic --db %s", paths[i], NULL, NULL) == 1);
        CHECK(!fx_exists(paths[i]));
    }
    CHECK(unchanged(file, &before));
    free(before.bytes);
    CHECK(!fx_exists(fx_tmp("no")));
    /* a missing database is not created by readers */
    const char *missing = fx_tmp("missing.sqlite");
    srv_db *db = NULL;
    CHECK(srv_db_open(missing, SRV_DB_READ, &db) == GS_ENOTFOUND && !db);
    CHECK(srv_db_open(missing, SRV_DB_WRITE, &db) == GS_ENOTFOUND && !db);
    CHECK(run("%s stats --db %s", missing, NULL, NULL) == 1 && fx_count_lines(out) == 1 && strstr(out, missing));
    CHECK(run("%s export --db %s -o %s", missing, fx_tmp("m.csv"), NULL) == 1);
    CHECK(!fx_exists(missing) && sidecars(missing) == 0 && !fx_exists(fx_tmp("m.csv")));
    if (geteuid() != 0) {
        const char *ro = fx_tmp("ro");
        CHECK(mkdir(ro, 0555) == 0);
        char p[1100];
        snprintf(p, sizeof p, "%s/s.sqlite", ro);
        CHECK(srv_db_open(p, SRV_DB_CREATE, &db) == GS_EIO && !db);
        CHECK(!fx_exists(p));
        chmod(ro, 0755);
    }
}

/* A handle opened read-only (SQLITE_OPEN_READONLY) refuses every write cleanly; as non-root a
 * file without write permission is refused for writing. The file is unchanged. */
TEST(survey_db_readonly_refuses_writes)
{
    const char *path = fx_tmp("ro.sqlite");
    survey_fx_synth_square(path, "ro", 3, 10, 5);
    snapshot before = take(path);
    srv_db *db = NULL;
    CHECK_OK(srv_db_open(path, SRV_DB_READ, &db));
    if (!db) return;
    CHECK(srv_db_begin(db) == GS_EIO && strstr(gs_detail(), "read-only") && strstr(gs_detail(), path));
    srv_survey_row sr = {"another", NULL, NULL, NULL, 50};
    int64_t id = 0;
    CHECK(srv_db_add_survey(db, &sr, &id) == GS_EIO);
    srv_capture_data cd = survey_fx_capture(1, "new", NULL, NULL, 0);
    CHECK(srv_db_add_capture(db, &cd, NULL, NULL) == GS_EIO);
    int deleted = 0;
    CHECK(srv_db_delete_capture(db, 1, "synth-000000", &deleted) == GS_EIO);
    /* a raw write on the borrowed connection fails too (SQLITE_OPEN_READONLY) */
    CHECK(sqlite3_exec(srv_db_sqlite(db), "DELETE FROM lights", NULL, NULL, NULL) == SQLITE_READONLY);
    srv_synth_opts o;
    srv_synth_opts_default(&o);
    CHECK(srv_synth_ingest(db, &o, NULL) == GS_EIO);
    srv_db_close(db);
    CHECK(unchanged(path, &before));
    if (geteuid() != 0) {
        CHECK(chmod(path, 0444) == 0);
        CHECK(srv_db_open(path, SRV_DB_WRITE, &db) == GS_EIO && !db);
        CHECK(strstr(gs_detail(), "read-only") != NULL);
        CHECK(run("%s db ingest-synthetic --db %s", path, NULL, NULL) == 1 && fx_count_lines(out) == 1);
        chmod(path, 0644);
        CHECK(unchanged(path, &before));
    }
    free(before.bytes);
}

/* ------------------------------------------------------------------ ingest */

TEST(survey_db_resume_never_duplicates)
{
    const char *path = fx_tmp("dup.sqlite");
    srv_db *db = NULL;
    CHECK_OK(srv_db_open(path, SRV_DB_CREATE, &db));
    if (!db) return;
    srv_synth_opts o;
    srv_synth_opts_default(&o);
    o.captures = 12;
    o.lights_per_capture = 30;
    size_t added = 99;
    CHECK_OK(srv_synth_ingest(db, &o, &added));
    CHECK(added == 12);
    sqlite3 *h = srv_db_sqlite(db);
    long lights = survey_fx_query_long(h, "SELECT count(*) FROM lights");
    CHECK(lights == 360);
    CHECK_OK(srv_synth_ingest(db, &o, &added));
    CHECK(added == 0);
    o.captures = 15;
    o.batch = 2;
    CHECK_OK(srv_synth_ingest(db, &o, &added));
    CHECK(added == 3);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM lights") == 450);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM surveys") == 1);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM stations") == 1);
    /* get-or-add by natural key */
    int64_t a = 0, b = 0;
    srv_survey_row sr = {"synthetic", "elsewhere", NULL, NULL, 60};
    CHECK_OK(srv_db_add_survey(db, &sr, &a));
    CHECK_OK(srv_db_find_survey(db, "synthetic", &b));
    CHECK(a == b && a > 0);
    CHECK(srv_db_find_survey(db, "nope", &b) == GS_ENOTFOUND);
    /* the low-level inserts are idempotent on their keys and need a transaction */
    srv_light_row lr;
    srv_light_row_init(&lr);
    lr.index = 3;
    lr.x_px = lr.y_px = 1.0;
    int64_t lid = 0, lid2 = 0, cid = 0;
    CHECK(srv_db_insert_light(db, 1, &lr, &lid) == GS_EINVAL);
    CHECK(strstr(gs_detail(), "outside a transaction") != NULL);
    CHECK_OK(srv_db_begin(db));
    CHECK(srv_db_begin(db) == GS_EINVAL);
    srv_capture_row cr;
    srv_capture_row_init(&cr);
    cr.survey_id = a;
    cr.key = "synth-000001";
    CHECK_OK(srv_db_insert_capture(db, &cr, 30, 8, 10, &cid));
    CHECK(cid == survey_fx_query_long(h, "SELECT id FROM captures WHERE capture_key = 'synth-000001'"));
    CHECK_OK(srv_db_insert_light(db, cid, &lr, &lid));
    CHECK_OK(srv_db_insert_light(db, cid, &lr, &lid2));
    CHECK(lid == lid2 && lid > 0);
    CHECK_OK(srv_db_commit(db));
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM lights") == 450);
    int done = 0;
    CHECK_OK(srv_db_capture_done(db, a, "synth-000014", &done));
    CHECK(done == 1);
    CHECK_OK(srv_db_capture_done(db, a, "synth-000015", &done));
    CHECK(done == 0);
    srv_db_report r;
    CHECK_OK(srv_db_check(db, &r));
    CHECK(srv_db_report_ok(&r));
    srv_db_close(db);
}

/* A capture that fails half-way leaves nothing of itself: not in its own transaction, not
 * inside the caller's (SAVEPOINT), where the captures before it survive. */
TEST(survey_db_capture_atomic_on_error)
{
    const char *path = fx_tmp("atomic.sqlite");
    int64_t sid;
    srv_db *db = survey_fx_create(path, "atomic", &sid);
    if (!db) return;
    sqlite3 *h = srv_db_sqlite(db);
    srv_light_row lights[4] = {survey_fx_sodium_light(0, 0), survey_fx_sodium_light(1, 120),
                               survey_fx_sodium_light(2, 240), survey_fx_sodium_light(3, 0)};
    lights[3].confidence = 1.5;   /* invalid: the 4th light fails after 3 were inserted */
    srv_location_row locs[4];
    for (int i = 0; i < 4; i++) {
        srv_location_row_init(&locs[i]);
        locs[i].method = SRV_LOC_ONE_STATION;
        locs[i].lat_deg = 32.8 + 0.001 * i;
        locs[i].lon_deg = 35.0;
    }
    srv_frame_row frames[2] = {{0, "frame_000.png", NULL, 10}, {1, "frame_001.png", NULL, 10}};
    srv_freq_row freq[2] = {{0, 1, 50.01, NAN}, {1, 1, 50.02, NAN}};
    srv_capture_data cd = survey_fx_capture(sid, "bad", lights, locs, 4);
    cd.frames = frames;
    cd.n_frames = 2;
    cd.frequency = freq;
    cd.n_frequency = 2;
    CHECK(srv_db_add_capture(db, &cd, NULL, NULL) == GS_EINVAL);
    CHECK(strstr(gs_detail(), "light 3") && strstr(gs_detail(), "confidence"));
    CHECK(!srv_db_in_transaction(db));
    static const char *const tables[] = {"captures", "frames", "lights", "locations",
                                         "locations_rtree", "grid_frequency"};
    for (int t = 0; t < 6; t++) {
        char sql[128];
        snprintf(sql, sizeof sql, "SELECT count(*) FROM %s", tables[t]);
        CHECK_MSG(survey_fx_query_long(h, sql) == 0, "%s not empty after a failed capture", tables[t]);
    }
    /* inside the caller's transaction: capture "good" commits, "bad" is rolled back alone */
    CHECK_OK(srv_db_begin(db));
    cd.capture.key = "good";
    cd.n_lights = 3;
    int64_t cid = 0;
    int skipped = 1;
    CHECK_OK(srv_db_add_capture(db, &cd, &cid, &skipped));
    CHECK(cid > 0 && skipped == 0);
    cd.capture.key = "bad";
    cd.n_lights = 4;
    CHECK(srv_db_add_capture(db, &cd, NULL, NULL) == GS_EINVAL);
    CHECK(srv_db_in_transaction(db));
    CHECK_OK(srv_db_commit(db));
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM captures") == 1);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM lights") == 3);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM locations_rtree") == 3);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM frames") == 2);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM grid_frequency") == 2);
    /* the same capture again is skipped, not duplicated */
    cd.capture.key = "good";
    cd.n_lights = 3;
    int64_t cid2 = 0;
    CHECK_OK(srv_db_add_capture(db, &cd, &cid2, &skipped));
    CHECK(skipped == 1 && cid2 == cid);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM lights") == 3);
    /* invalid rows name their field */
    srv_light_row bad = survey_fx_sodium_light(9, 0);
    bad.technology = "plasma";
    cd.capture.key = "tech";
    cd.lights = &bad;
    cd.locations = NULL;
    cd.n_lights = 1;
    CHECK(srv_db_add_capture(db, &cd, NULL, NULL) == GS_EINVAL && strstr(gs_detail(), "plasma"));
    srv_location_row half;
    srv_location_row_init(&half);
    half.method = SRV_LOC_ONE_STATION;
    half.lat_deg = 10.0;   /* longitude missing */
    bad = survey_fx_sodium_light(9, 0);
    cd.locations = &half;
    CHECK(srv_db_add_capture(db, &cd, NULL, NULL) == GS_EINVAL && strstr(gs_detail(), "location"));
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM captures") == 1);
    srv_db_close(db);
}

TEST(survey_db_rtree_follows_locations)
{
    const char *path = fx_tmp("rt.sqlite");
    survey_fx_synth_square(path, "rt", 6, 50, 3);
    srv_db *db = NULL;
    CHECK_OK(srv_db_open(path, SRV_DB_WRITE, &db));
    if (!db) return;
    sqlite3 *h = srv_db_sqlite(db);
    long located = 6 * (50 - 50 / SRV_SYNTH_UNLOCATED_EVERY);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM locations") == 300);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM locations WHERE lat_deg IS NOT NULL") == located);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM locations_rtree") == located);
    int64_t sid = 0;
    CHECK_OK(srv_db_find_survey(db, "rt", &sid));
    int deleted = 0;
    CHECK_OK(srv_db_delete_capture(db, sid, "synth-000002", &deleted));
    CHECK(deleted == 1);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM locations_rtree") == located - located / 6);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM lights") == 250);
    CHECK_OK(srv_db_delete_capture(db, sid, "synth-000002", &deleted));
    CHECK(deleted == 0);
    /* an update moves the R*Tree entry (trigger) */
    CHECK(sqlite3_exec(h, "UPDATE locations SET lat_deg = 10.5, lon_deg = 20.5 WHERE light_id = "
                          "(SELECT min(light_id) FROM locations WHERE lat_deg IS NOT NULL)",
                       NULL, NULL, NULL) == SQLITE_OK);
    CHECK(survey_fx_query_long(h, "SELECT count(*) FROM locations_rtree WHERE min_lat <= 10.5 AND max_lat >= "
                        "10.5 AND min_lon <= 20.5 AND max_lon >= 20.5") == 1);
    srv_db_report r;
    CHECK_OK(srv_db_check(db, &r));
    CHECK(srv_db_report_ok(&r) && r.rtree_rows == r.located);
    /* a desynchronised R*Tree is detected */
    CHECK(sqlite3_exec(h, "DELETE FROM locations_rtree WHERE id = (SELECT max(id) FROM "
                          "locations_rtree)", NULL, NULL, NULL) == SQLITE_OK);
    CHECK_OK(srv_db_check(db, &r));
    CHECK(!srv_db_report_ok(&r) && r.rtree_mismatch == 1);
    srv_db_close(db);
    CHECK(run("%s db check --db %s", path, NULL, NULL) == 1 && strstr(out, "FAILED"));
}

/* ------------------------------------------------------------------ crash safety */

typedef struct {
    long captures, lights, frames, freq, locations, located, rtree, bad_captures, fk;
    int integrity_ok;
} raw_state;

/* Inspect the database through a raw SQLite connection (not the library). */
static int raw_inspect(const char *path, const srv_synth_opts *o, raw_state *st)
{
    memset(st, 0, sizeof *st);
    st->integrity_ok = 1;
    if (!fx_exists(path)) return 1;
    sqlite3 *h = NULL;
    if (sqlite3_open_v2(path, &h, SQLITE_OPEN_READWRITE, NULL) != SQLITE_OK) {
        test_failed(__FILE__, __LINE__, "%s: cannot open after a kill: %s", path, sqlite3_errmsg(h));
        sqlite3_close(h);
        return 0;
    }
    st->integrity_ok = !strcmp(survey_fx_query_text(h, "PRAGMA integrity_check"), "ok");
    if (survey_fx_has(h, "lights")) {
        CHECK(!strcmp(survey_fx_query_text(h, "SELECT rtreecheck('locations_rtree')"), "ok"));
        st->fk = survey_fx_query_long(h, "SELECT count(*) FROM pragma_foreign_key_check");
        st->captures = survey_fx_query_long(h, "SELECT count(*) FROM captures");
        st->lights = survey_fx_query_long(h, "SELECT count(*) FROM lights");
        st->frames = survey_fx_query_long(h, "SELECT count(*) FROM frames");
        st->freq = survey_fx_query_long(h, "SELECT count(*) FROM grid_frequency");
        st->locations = survey_fx_query_long(h, "SELECT count(*) FROM locations");
        st->located = survey_fx_query_long(h, "SELECT count(*) FROM locations WHERE lat_deg IS NOT NULL");
        st->rtree = survey_fx_query_long(h, "SELECT count(*) FROM locations_rtree");
        /* every capture complete, by the synthetic survey's known structure */
        long located_per = 0;
        for (size_t j = 0; j < o->lights_per_capture; j++)
            located_per += j % SRV_SYNTH_UNLOCATED_EVERY != SRV_SYNTH_UNLOCATED_EVERY - 1;
        char sql[1024];
        snprintf(sql, sizeof sql,
                 "SELECT count(*) FROM captures c WHERE "
                 "(SELECT count(*) FROM lights WHERE capture_id = c.id) != %zu OR "
                 "(SELECT count(*) FROM frames WHERE capture_id = c.id) != %d OR "
                 "(SELECT count(*) FROM grid_frequency WHERE capture_id = c.id) != %d OR "
                 "(SELECT count(*) FROM locations lo JOIN lights l ON l.id = lo.light_id "
                 " WHERE l.capture_id = c.id AND lo.lat_deg IS NOT NULL) != %ld",
                 o->lights_per_capture, SRV_SYNTH_FRAMES, SRV_SYNTH_FREQ, located_per);
        st->bad_captures = survey_fx_query_long(h, sql);
        /* no orphan rows either */
        st->bad_captures += survey_fx_query_long(h, "SELECT count(*) FROM lights WHERE capture_id NOT IN (SELECT id FROM captures)");
    }
    sqlite3_close(h);
    return 1;
}

static void child_ingest(const char *path, const srv_synth_opts *o, int ready_fd)
{
    srv_db *db = NULL;
    if (srv_db_open(path, SRV_DB_CREATE, &db) != GS_OK) _exit(3);
    if (ready_fd >= 0) {
        char c = 'r';
        if (write(ready_fd, &c, 1) != 1) _exit(4);
        close(ready_fd);
    }
    gs_status s = srv_synth_ingest(db, o, NULL);
    srv_db_close(db);
    _exit(s == GS_OK ? 0 : 5);
}

/* SIGKILL a writer at random points (during creation, migration, ingest, commits) 16 times;
 * after each kill the database is consistent, no capture is partial, nothing committed is
 * lost; a final run resumes to the exact expected counts, and another run adds nothing. */
TEST(survey_db_sigkill_resume_no_partial_capture)
{
    const char *path = fx_tmp("crash.sqlite");
    srv_synth_opts o;
    srv_synth_opts_default(&o);
    o.survey = "crash";
    o.captures = 480;
    o.lights_per_capture = 30;
    o.seed = 11;
    uint64_t rng = 0x5eedull;
    long prev = 0;
    int mid = 0;
    /* The kill window adapts to the machine (ASan is several times slower): it doubles after a
     * kill that landed before the first commit and halves after one that let the writer get
     * through more than 1/8 of the survey, so most kills land mid-ingest. */
    unsigned window_us = 20000;
    char trace[1024] = "";
    for (int kill_no = 0; kill_no < 16; kill_no++) {
        o.batch = 1 + (size_t)kill_no % 3;
        rng = rng * 6364136223846793005ull + 1442695040888963407ull;
        unsigned r = (unsigned)(rng >> 33);
        int early = kill_no % 4 == 0;   /* kill before or while the database is opened */
        int fd;
        pid_t pid = fx_fork_pipe(&fd);
        if (pid == 0) child_ingest(path, &o, fd);
        if (early) {
            usleep(r % 4000);
        } else {
            char c;
            if (read(fd, &c, 1) != 1) {
                /* the child died before it was ready: report its status below */
            }
            usleep(r % window_us);
        }
        close(fd);
        kill(pid, SIGKILL);
        int status = 0;
        waitpid(pid, &status, 0);
        CHECK_MSG(WIFSIGNALED(status) || (WIFEXITED(status) && WEXITSTATUS(status) == 0),
                  "writer exited with %d before the kill", WIFEXITED(status) ? WEXITSTATUS(status) : -1);
        raw_state st;
        if (!raw_inspect(path, &o, &st)) return;
        CHECK_MSG(st.integrity_ok, "kill %d: integrity_check failed", kill_no);
        CHECK_MSG(st.fk == 0, "kill %d: %ld foreign-key violations", kill_no, st.fk);
        CHECK_MSG(st.rtree == st.located, "kill %d: R*Tree %ld vs located %ld", kill_no, st.rtree, st.located);
        CHECK_MSG(st.bad_captures == 0, "kill %d: %ld partial captures", kill_no, st.bad_captures);
        CHECK_MSG(st.captures >= prev, "kill %d: committed captures lost (%ld < %ld)", kill_no, st.captures, prev);
        CHECK(st.lights == st.captures * (long)o.lights_per_capture);
        CHECK(st.frames == st.captures * SRV_SYNTH_FRAMES && st.freq == st.captures * SRV_SYNTH_FREQ);
        CHECK(st.locations == st.lights);
        if (st.captures > prev && st.captures < (long)o.captures) mid++;
        size_t used = strlen(trace);
        snprintf(trace + used, sizeof trace - used, " %ld", st.captures);
        if (!early) {
            if (st.captures == prev && window_us < 2000000) window_us *= 2;
            else if (st.captures - prev > (long)o.captures / 8 && window_us > 1000) window_us /= 2;
        }
        prev = st.captures;
    }
    CHECK_MSG(mid >= 4, "only %d kills landed during the ingest (captures after each kill:%s)", mid, trace);
    if (getenv("GS_TEST_VERBOSE")) printf("    captures after each kill:%s\n", trace);
    /* resume to completion, then once more */
    for (int pass = 0; pass < 2; pass++) {
        srv_db *db = NULL;
        CHECK_OK(srv_db_open(path, SRV_DB_CREATE, &db));
        if (!db) return;
        size_t added = 0;
        CHECK_OK(srv_synth_ingest(db, &o, &added));
        if (pass == 1) CHECK(added == 0);
        else CHECK((long)added == (long)o.captures - prev);
        srv_db_report r;
        CHECK_OK(srv_db_check(db, &r));
        CHECK(srv_db_report_ok(&r));
        srv_db_close(db);
        raw_state st;
        raw_inspect(path, &o, &st);
        CHECK(st.integrity_ok && st.fk == 0 && st.bad_captures == 0);
        CHECK(st.captures == (long)o.captures);
        CHECK(st.lights == (long)(o.captures * o.lights_per_capture));
        CHECK(st.rtree == st.located && st.located == (long)o.captures * (30 - 1));
        CHECK(st.frames == (long)o.captures * SRV_SYNTH_FRAMES);
    }
    /* the CLI writer is killed and resumed the same way */
    const char *cli = fx_tmp("cli-crash.sqlite");
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "%s db ingest-synthetic --db %s --captures 200 --lights 40 --batch 2 "
             "& sleep 0.3; kill -9 $! 2>/dev/null; wait; %s db ingest-synthetic --db %s "
             "--captures 200 --lights 40 && %s db check --db %s", test_bin(), cli, test_bin(), cli,
             test_bin(), cli);
    CHECK(test_run(cmd, out, sizeof out) == 0);
    CHECK(strstr(out, "200 captures, 8000 lights") != NULL);
}

/* ------------------------------------------------------------------ helpers */

TEST(survey_db_sha256_and_delight_fingerprint)
{
    char hex[65];
    gs_sha256_hex("abc", 3, hex);
    CHECK(!strcmp(hex, "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"));
    gs_sha256_hex("", 0, hex);
    CHECK(!strcmp(hex, "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"));
    const char *two = "abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq";
    gs_sha256_hex(two, strlen(two), hex);
    CHECK(!strcmp(hex, "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1"));
    char *mill = malloc(1000000);
    memset(mill, 'a', 1000000);
    gs_sha256_hex(mill, 1000000, hex);
    CHECK(!strcmp(hex, "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0"));
    free(mill);
    gs_delight *d1 = gs_delight_new(), *d2 = gs_delight_new();
    CHECK_OK(gs_delight_generate(d1, 256));
    for (size_t i = 0; i < gs_delight_count(d1); i++) CHECK_OK(gs_delight_add(d2, gs_delight_get(d1, i)));
    srv_delight_row r1, r2;
    CHECK_OK(srv_delight_fingerprint(d1, NULL, &r1));
    CHECK_OK(srv_delight_fingerprint(d2, "copy.sqlite", &r2));
    CHECK(!strcmp(r1.sha256, r2.sha256) && r1.bulbs == (long)gs_delight_count(d1) && r1.bulbs > 0);
    CHECK(!strcmp(r1.source, "built-in"));
    gs_delight *d3 = gs_delight_new();
    CHECK_OK(gs_delight_add(d3, gs_delight_get(d1, 0)));
    srv_delight_row r3;
    CHECK_OK(srv_delight_fingerprint(d3, NULL, &r3));
    CHECK(strcmp(r1.sha256, r3.sha256) != 0 && r3.bulbs == 1);
    srv_db *db = NULL;
    CHECK_OK(srv_db_open(fx_tmp("fp.sqlite"), SRV_DB_CREATE, &db));
    int64_t a = 0, b = 0, c = 0;
    CHECK_OK(srv_db_add_delight(db, &r1, &a));
    CHECK_OK(srv_db_add_delight(db, &r2, &b));
    CHECK_OK(srv_db_add_delight(db, &r3, &c));
    CHECK(a == b && a != c && a > 0 && c > 0);
    CHECK(survey_fx_query_long(srv_db_sqlite(db), "SELECT count(*) FROM delight_versions") == 2);
    srv_db_close(db);
    gs_delight_free(d1);
    gs_delight_free(d2);
    gs_delight_free(d3);
}

TEST(survey_db_rows_from_recognition)
{
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, 256));
    rec_matcher *mt = NULL;
    CHECK_OK(rec_matcher_new(d, 50, 1, 16, NULL, &mt));
    if (!mt) {
        gs_delight_free(d);
        return;
    }
    rec_match m = {0};
    m.bulb = 1;
    m.phase_deg = 240.0;
    m.confidence = 0.9;
    m.bulb_confidence = 0.95;
    m.phase_confidence = 0.97;
    m.runner_bulb = 0;
    m.runner_phase_deg = 120.0;
    m.runner_confidence = 0.05;
    m.p_value = 0.4;
    m.dof = 14;
    srv_light_row r;
    srv_light_row_init(&r);
    srv_light_from_match(&r, &m, mt);
    CHECK(r.bulb_id && !strcmp(r.bulb_id, rec_matcher_bulb(mt, 1)->id));
    CHECK(r.technology && !strcmp(r.technology, gs_tech_name(rec_matcher_bulb(mt, 1)->type)));
    CHECK(r.phase_deg == 240.0 && r.phase_fit_deg == 240.0 && r.runner_phase_deg == 120.0);
    CHECK(r.runner_bulb_id && !strcmp(r.runner_bulb_id, rec_matcher_bulb(mt, 0)->id));
    m.flags = REC_MATCH_PHASE_AMBIGUOUS;
    srv_light_from_match(&r, &m, mt);
    CHECK(isnan(r.phase_deg) && r.phase_fit_deg == 240.0);   /* ambiguous: stored NULL */
    m.bulb = -1;
    m.runner_bulb = -1;
    m.flags = REC_MATCH_DIM;
    srv_light_from_match(&r, &m, mt);
    CHECK(!r.bulb_id && !r.technology && isnan(r.phase_deg) && !r.runner_bulb_id);
    gis_fix f = {0};
    f.lat_deg = 32.8;
    f.lon_deg = 215.0;   /* stored wrapped to [-180, 180) */
    f.height_m = 30;
    f.range_m = 1200;
    f.ellipse.semi_major_m = INFINITY;
    f.ellipse.semi_minor_m = 2;
    f.flags = GIS_FIX_GRAZING;
    srv_location_row loc;
    srv_location_from_fix(&loc, &f);
    CHECK(loc.method == SRV_LOC_ONE_STATION && loc.flags == GIS_FIX_GRAZING);
    srv_db *db = NULL;
    CHECK_OK(srv_db_open(fx_tmp("rows.sqlite"), SRV_DB_CREATE, &db));
    srv_survey_row sr = {"rows", NULL, NULL, NULL, 50};
    int64_t sid = 0;
    CHECK_OK(srv_db_add_survey(db, &sr, &sid));
    m.bulb = 1;
    m.flags = 0;
    srv_light_from_match(&r, &m, mt);
    r.x_px = 3;
    r.y_px = 4;
    r.phase_deg = -120.0;   /* stored wrapped: 240 */
    srv_capture_data cd = survey_fx_capture(sid, "k", &r, &loc, 1);
    CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    sqlite3 *h = srv_db_sqlite(db);
    CHECK(survey_fx_query_long(h, "SELECT phase_deg = 240 AND dof = 14 FROM lights") == 1);
    CHECK(survey_fx_query_long(h, "SELECT lon_deg = -145 AND semi_major_m IS NULL AND semi_minor_m = 2 FROM locations") == 1);
    srv_db_close(db);
    rec_matcher_free(mt);
    gs_delight_free(d);
}

/* The survey names stored in path, read through a raw connection ("" when none or no file). */
static void stored_surveys(const char *path, char *names, size_t size)
{
    names[0] = '\0';
    sqlite3 *h = NULL;
    sqlite3_stmt *q = NULL;
    if (fx_exists(path) && sqlite3_open_v2(path, &h, SQLITE_OPEN_READONLY, NULL) == SQLITE_OK &&
        sqlite3_prepare_v2(h, "SELECT name FROM surveys ORDER BY name", -1, &q, NULL) == SQLITE_OK)
        while (sqlite3_step(q) == SQLITE_ROW) {
            size_t n = strlen(names);
            snprintf(names + n, size - n, "%s;", (const char *)sqlite3_column_text(q, 0));
        }
    sqlite3_finalize(q);
    sqlite3_close(h);
}

/* A failed run removes the database it created (srv_db_close_discard), but not one that another
 * process has used meanwhile: concurrent runs into a new file had the failed one delete the
 * file that the others had committed to (their captures lost, exit 1 on a missing database). */
TEST(survey_db_discard_keeps_a_database_another_run_used)
{
    const char *path = fx_tmp("discard.sqlite");
    char names[256];
    srv_survey_row june = {.name = "june"}, july = {.name = "july"};
    int64_t id;
    /* another run stored a survey and closed: the file stays, with it */
    srv_db *a = NULL, *b = NULL;
    CHECK_OK(srv_db_open(path, SRV_DB_CREATE, &a));
    CHECK_OK(srv_db_open(path, SRV_DB_WRITE, &b));
    CHECK_OK(srv_db_add_survey(b, &june, &id));
    srv_db_close(b);
    srv_db_close_discard(a);
    stored_surveys(path, names, sizeof names);
    CHECK_MSG(!strcmp(names, "june;"), "stored after the discard: '%s'", names);
    remove(path);
    /* another run has it open, yet to store: the file stays, and its later commit is kept */
    CHECK_OK(srv_db_open(path, SRV_DB_CREATE, &a));
    CHECK_OK(srv_db_open(path, SRV_DB_WRITE, &b));
    srv_db_close_discard(a);
    CHECK_OK(srv_db_add_survey(b, &july, &id));
    srv_db_close(b);
    stored_surveys(path, names, sizeof names);
    CHECK_MSG(!strcmp(names, "july;"), "stored after the discard: '%s'", names);
    CHECK_OK(srv_db_open(path, SRV_DB_READ, &b));
    srv_db_report r;
    CHECK_OK(srv_db_check(b, &r));
    CHECK(r.integrity_ok);
    srv_db_close(b);
    remove(path);
    /* alone, unused: removed with its sidecars, as before */
    CHECK_OK(srv_db_open(path, SRV_DB_CREATE, &a));
    srv_db_close_discard(a);
    CHECK(!fx_exists(path) && sidecars(path) == 0);
}

/* Six processes store a survey each into one database that none of them finds: each creation
 * renamed its new file over the one another process had created and written (surveys lost with
 * exit 0, or "disk I/O error" from a -wal of another file), and a process that opened the file
 * while another switched its journal failed at once ("reading the header: database is locked",
 * before the busy timeout was set). Now every process exits 0 and all six surveys are there. */
TEST(survey_db_concurrent_creators_keep_every_survey)
{
    const char *path = fx_tmp("creators.sqlite");
    char cmd[4096], names[256];
    for (int trial = 0; trial < 5; trial++) {
        remove(path);
        snprintf(cmd, sizeof cmd, "for i in 1 2 3 4 5 6; do (%%s db ingest-synthetic --db %%s --survey s$i "
                 "--captures 1 --lights 3 > /dev/null || echo \"s$i failed\") & done; wait");
        CHECK(run(cmd, path, NULL, NULL) == 0);
        CHECK_MSG(out[0] == '\0', "trial %d: %s", trial, out);
        stored_surveys(path, names, sizeof names);
        CHECK_MSG(!strcmp(names, "s1;s2;s3;s4;s5;s6;"), "trial %d: surveys '%s'", trial, names);
    }
    CHECK(run("%s db check --db %s", path, NULL, NULL) == 0);
}

/* A database path that is a symlink to nothing is written through (its target made), as
 * before the creators took turns: their race check took the link itself for another's file,
 * failed and left the target empty (0 bytes). Likewise `delight import` into such a link. */
TEST(survey_db_and_delight_through_a_symlink_to_nothing)
{
    const char *link = fx_tmp("link.sqlite"), *target = fx_tmp("target.sqlite");
    remove(link);
    remove(target);
    CHECK(symlink("target.sqlite", link) == 0);
    CHECK_MSG(run("%s db ingest-synthetic --db %s --survey s --captures 1 --lights 3", link, NULL, NULL) == 0, "%s", out);
    CHECK_MSG(run("%s db check --db %s", target, NULL, NULL) == 0 && strstr(out, "1 surveys"), "%s", out);
    const char *dlink = fx_tmp("dlink.db"), *dtarget = fx_tmp("dtarget.db"), *csv = fx_tmp("one.csv");
    remove(dlink);
    remove(dtarget);
    CHECK(symlink("dtarget.db", dlink) == 0);
    CHECK(run("%s delight export -o %s", csv, NULL, NULL) == 0);
    CHECK_MSG(run("%s delight import %s --delight %s", csv, dlink, NULL) == 0, "%s", out);
    CHECK_MSG(run("%s delight list --delight %s", dtarget, NULL, NULL) == 0 && strlen(out) > 100, "%s", out);
}

/* A row that breaks a CHECK constraint (written by another program with ignore_check_constraints)
 * is an integrity failure of `db check`: SQLite does not parse the CHECK constraints of a
 * database opened read-only, so integrity_check on db check's read-only connection said ok
 * (exit 0) where the sqlite3 shell, read-write, lists "CHECK constraint failed in captures". */
TEST(survey_db_check_finds_rows_breaking_check_constraints)
{
    const char *path = fx_tmp("checks.sqlite");
    CHECK(run("%s db ingest-synthetic --db %s --captures 2 --lights 5", path, NULL, NULL) == 0);
    CHECK(run("%s db check --db %s", path, NULL, NULL) == 0);
    sqlite3 *h = NULL;
    CHECK(sqlite3_open(path, &h) == SQLITE_OK);
    CHECK(sqlite3_exec(h, "PRAGMA ignore_check_constraints = 1; UPDATE captures SET K = 0 WHERE id = 1",
                       NULL, NULL, NULL) == SQLITE_OK);
    /* the oracle: SQLite's own check on a read-write connection */
    sqlite3_stmt *q = NULL;
    CHECK(sqlite3_exec(h, "PRAGMA ignore_check_constraints = 0", NULL, NULL, NULL) == SQLITE_OK);
    CHECK(sqlite3_prepare_v2(h, "PRAGMA integrity_check", -1, &q, NULL) == SQLITE_OK && sqlite3_step(q) == SQLITE_ROW);
    CHECK_MSG(!strcmp((const char *)sqlite3_column_text(q, 0), "CHECK constraint failed in captures"), "%s",
              (const char *)sqlite3_column_text(q, 0));
    sqlite3_finalize(q);
    sqlite3_close(h);
    CHECK(run("%s db check --db %s", path, NULL, NULL) == 1);
    CHECK_MSG(strstr(out, "integrity FAILED"), "%s", out);
    CHECK(sidecars(path) == 0);   /* (the check writes nothing) */
    /* text in REAL and INTEGER columns that no CHECK guards (stats and exports read it as 0):
     * 'abc' as a light's x_px and a frame count, counted by typeof, the oracle */
    const char *typed = fx_tmp("types.sqlite");
    CHECK(run("%s db ingest-synthetic --db %s --captures 2 --lights 5", typed, NULL, NULL) == 0);
    CHECK(sqlite3_open(typed, &h) == SQLITE_OK);
    CHECK(sqlite3_exec(h, "UPDATE lights SET x_px = 'abc' WHERE id = 1; UPDATE lights SET peak_dn = x'00' WHERE id = 2",
                       NULL, NULL, NULL) == SQLITE_OK);
    CHECK(sqlite3_prepare_v2(h, "SELECT count(*) FROM lights WHERE typeof(x_px) = 'text' OR typeof(peak_dn) = 'blob'",
                             -1, &q, NULL) == SQLITE_OK && sqlite3_step(q) == SQLITE_ROW);
    CHECK(sqlite3_column_int(q, 0) == 2);
    sqlite3_finalize(q);
    sqlite3_close(h);
    CHECK(run("%s db check --db %s", typed, NULL, NULL) == 1);
    CHECK_MSG(strstr(out, "integrity ok") && strstr(out, "2 numbers stored as text: FAILED"), "%s", out);
}
