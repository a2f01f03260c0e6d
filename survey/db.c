/* db.c - the survey database: SQLite with a versioned schema, migrations, prepared-statement
 * inserts, an atomic and resumable per-capture ingest, and a consistency check.
 * docs/survey-db.md is the specification (tables, views, migrations, crash safety).
 *
 * Identification: PRAGMA application_id = SRV_DB_APPLICATION_ID, PRAGMA user_version = the
 * schema version, meta('format') = SRV_DB_FORMAT. A file is identified through a read-only
 * connection before anything is written, so a file that is refused is never touched.
 *
 * Migrations: migrations[i] takes the schema from version i to i + 1, applied in order, each
 * in one BEGIN IMMEDIATE transaction that also records itself in the `migrations` table and
 * sets user_version (both transactional in SQLite: the header lives on page 1). A crash
 * during a migration leaves the previous version intact. */
#include "survey/internal.h"

#include <errno.h>
#include <math.h>
#include <sqlite3.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

/* ------------------------------------------------------------------ schema */

/* Version 1: the tables, the R*Tree and the triggers that keep it in sync with locations. */
static const char *const migration_1[] = {
    "CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL) WITHOUT ROWID;\n"
    "CREATE TABLE migrations(\n"
    "  version INTEGER PRIMARY KEY, name TEXT NOT NULL, applied_utc TEXT NOT NULL,\n"
    "  generator TEXT NOT NULL);\n"
    "CREATE TABLE delight_versions(\n"
    "  id INTEGER PRIMARY KEY,\n"
    "  sha256 TEXT NOT NULL CHECK (length(sha256) = 64),\n"
    "  generator TEXT NOT NULL, source TEXT NOT NULL,\n"
    "  bulbs INTEGER NOT NULL CHECK (bulbs >= 0),\n"
    "  added_utc TEXT NOT NULL,\n"
    "  UNIQUE (sha256, generator));\n"
    "CREATE TABLE surveys(\n"
    "  id INTEGER PRIMARY KEY,\n"
    "  name TEXT NOT NULL UNIQUE CHECK (length(name) BETWEEN 1 AND 63),\n"
    "  city TEXT, grid_hz INTEGER CHECK (grid_hz IN (50, 60)),\n"
    "  started_utc TEXT, notes TEXT, created_utc TEXT NOT NULL);\n"
    "CREATE TABLE stations(\n"
    "  id INTEGER PRIMARY KEY,\n"
    "  survey_id INTEGER NOT NULL REFERENCES surveys(id) ON DELETE CASCADE,\n"
    "  name TEXT NOT NULL,\n"
    "  lat_deg REAL CHECK (lat_deg BETWEEN -90 AND 90), lon_deg REAL, height_m REAL,\n"
    "  heading_deg REAL, pitch_deg REAL, roll_deg REAL,\n"
    "  sigma_heading_deg REAL, sigma_pitch_deg REAL, sigma_roll_deg REAL,\n"
    "  focal_px REAL, cx_px REAL, cy_px REAL, k1 REAL, k2 REAL,\n"
    "  width_px INTEGER, height_px INTEGER, refraction_k REAL, sigma_px REAL, time_utc TEXT,\n"
    "  UNIQUE (survey_id, name));\n"
    ,
    "CREATE TABLE captures(\n"
    "  id INTEGER PRIMARY KEY,\n"
    "  survey_id INTEGER NOT NULL REFERENCES surveys(id) ON DELETE CASCADE,\n"
    "  station_id INTEGER REFERENCES stations(id) ON DELETE SET NULL,\n"
    "  delight_id INTEGER REFERENCES delight_versions(id),\n"
    "  capture_key TEXT NOT NULL CHECK (length(capture_key) > 0),\n"
    "  path TEXT, utc TEXT,\n"
    "  grid_hz INTEGER CHECK (grid_hz IN (50, 60)),\n"
    "  K INTEGER CHECK (K >= 2), bands INTEGER CHECK (bands IN (1, 3)),\n"
    "  width_px INTEGER, height_px INTEGER, locked INTEGER CHECK (locked IN (0, 1)),\n"
    "  mean_frequency_hz REAL, sigma_frequency_hz REAL,\n"
    "  light_count INTEGER NOT NULL, frame_count INTEGER NOT NULL,\n"
    "  frequency_count INTEGER NOT NULL,\n"
    "  ingested_utc TEXT NOT NULL,\n"
    "  UNIQUE (survey_id, capture_key));\n"
    "CREATE INDEX captures_station ON captures(station_id);\n"
    "CREATE INDEX captures_delight ON captures(delight_id);\n"
    "CREATE TABLE frames(\n"
    "  capture_id INTEGER NOT NULL REFERENCES captures(id) ON DELETE CASCADE,\n"
    "  k INTEGER NOT NULL CHECK (k >= 0), file TEXT, cycles REAL, hdr_map TEXT,\n"
    "  PRIMARY KEY (capture_id, k)) WITHOUT ROWID;\n"
    ,
    "CREATE TABLE lights(\n"
    "  id INTEGER PRIMARY KEY,\n"
    "  capture_id INTEGER NOT NULL REFERENCES captures(id) ON DELETE CASCADE,\n"
    "  light_index INTEGER NOT NULL CHECK (light_index >= 0),\n"
    "  x_px REAL NOT NULL, y_px REAL NOT NULL,\n"
    "  area_px INTEGER, peak_dn REAL, saturated_px INTEGER,\n"
    "  blob_flags INTEGER NOT NULL DEFAULT 0,\n"
    "  brightness REAL, snr REAL, chi2 REAL, dof INTEGER,\n"
    "  p_value REAL CHECK (p_value BETWEEN 0 AND 1),\n"
    "  bulb_id TEXT, technology TEXT,\n"
    "  phase_deg REAL CHECK (phase_deg >= 0 AND phase_deg < 360),\n"
    "  phase_fit_deg REAL CHECK (phase_fit_deg >= 0 AND phase_fit_deg < 360),\n"
    "  phase_sigma_deg REAL,\n"
    "  confidence REAL NOT NULL CHECK (confidence BETWEEN 0 AND 1),\n"
    "  bulb_confidence REAL NOT NULL CHECK (bulb_confidence BETWEEN 0 AND 1),\n"
    "  phase_confidence REAL NOT NULL CHECK (phase_confidence BETWEEN 0 AND 1),\n"
    "  runner_bulb_id TEXT, runner_phase_deg REAL,\n"
    "  runner_confidence REAL CHECK (runner_confidence BETWEEN 0 AND 1),\n"
    "  match_flags INTEGER NOT NULL DEFAULT 0,\n"
    "  UNIQUE (capture_id, light_index));\n"
    "CREATE INDEX lights_technology ON lights(technology);\n"
    ,
    "CREATE TABLE locations(\n"
    "  light_id INTEGER PRIMARY KEY REFERENCES lights(id) ON DELETE CASCADE,\n"
    "  method TEXT NOT NULL CHECK (method IN ('one_station', 'triangulated', 'truth')),\n"
    "  lat_deg REAL CHECK (lat_deg BETWEEN -90 AND 90),\n"
    "  lon_deg REAL CHECK (lon_deg >= -180 AND lon_deg < 180),\n"
    "  height_m REAL, semi_major_m REAL, semi_minor_m REAL, azimuth_deg REAL, range_m REAL,\n"
    "  flags INTEGER NOT NULL DEFAULT 0,\n"
    "  CHECK ((lat_deg IS NULL) = (lon_deg IS NULL)));\n"
    "CREATE VIRTUAL TABLE locations_rtree USING rtree(id, min_lon, max_lon, min_lat, max_lat);\n"
    "CREATE TRIGGER locations_rtree_insert AFTER INSERT ON locations\n"
    "  WHEN new.lat_deg IS NOT NULL BEGIN\n"
    "  INSERT INTO locations_rtree VALUES (new.light_id, new.lon_deg, new.lon_deg,\n"
    "                                     new.lat_deg, new.lat_deg);\n"
    "END;\n"
    "CREATE TRIGGER locations_rtree_delete AFTER DELETE ON locations BEGIN\n"
    "  DELETE FROM locations_rtree WHERE id = old.light_id;\n"
    "END;\n"
    "CREATE TRIGGER locations_rtree_update AFTER UPDATE OF light_id, lat_deg, lon_deg ON locations\n"
    "  BEGIN\n"
    "  DELETE FROM locations_rtree WHERE id = old.light_id;\n"
    "  INSERT INTO locations_rtree SELECT new.light_id, new.lon_deg, new.lon_deg, new.lat_deg,\n"
    "                                     new.lat_deg WHERE new.lat_deg IS NOT NULL;\n"
    "END;\n"
    "CREATE TABLE grid_frequency(\n"
    "  capture_id INTEGER NOT NULL REFERENCES captures(id) ON DELETE CASCADE,\n"
    "  seq INTEGER NOT NULL CHECK (seq >= 0),\n"
    "  t_s REAL NOT NULL, window_s REAL NOT NULL CHECK (window_s > 0),\n"
    "  frequency_hz REAL NOT NULL CHECK (frequency_hz > 0), sigma_hz REAL,\n"
    "  PRIMARY KEY (capture_id, seq)) WITHOUT ROWID;\n"
    "INSERT INTO meta VALUES ('format', '" SRV_DB_FORMAT "');\n",
    NULL};

/* Version 2: phase-balance views (SQLite's math functions: sqrt, exp; Debian's libsqlite3 is
 * built with SQLITE_ENABLE_MATH_FUNCTIONS). The phase classes match gs_phase_class exactly
 * (phases are stored wrapped to [0, 360)); the Wilson interval uses z = SRV_Z95. */
#define Z95_SQL "1.959963984540054"
static const char *const migration_2[] = {
    "CREATE VIEW light_phase AS\n"
    "SELECT l.id AS light_id, s.id AS survey_id, s.name AS survey, c.capture_key,\n"
    "       coalesce(l.technology, 'none') AS technology, l.bulb_id, l.phase_deg,\n"
    "       CASE WHEN l.phase_deg IS NULL THEN 'unknown'\n"
    "            WHEN l.phase_deg <= 20 OR l.phase_deg >= 340 THEN '0'\n"
    "            WHEN l.phase_deg BETWEEN 100 AND 140 THEN '120'\n"
    "            WHEN l.phase_deg BETWEEN 220 AND 260 THEN '240'\n"
    "            ELSE 'other' END AS phase_class,\n"
    "       l.confidence, l.phase_confidence, loc.lat_deg, loc.lon_deg\n"
    "FROM lights l JOIN captures c ON c.id = l.capture_id JOIN surveys s ON s.id = c.survey_id\n"
    "LEFT JOIN locations loc ON loc.light_id = l.id;\n"
    /* one scan of the lights: counts per (survey, technology, class), then the groupings */
    "CREATE VIEW phase_counts AS\n"
    "WITH base AS MATERIALIZED (\n"
    "  SELECT survey, technology, count(*) AS lights,\n"
    "         sum(phase_class = 'unknown') AS unknown, sum(phase_class = 'other') AS other,\n"
    "         sum(phase_class = '0') AS n0, sum(phase_class = '120') AS n120,\n"
    "         sum(phase_class = '240') AS n240\n"
    "  FROM light_phase GROUP BY survey, technology),\n"
    "g(grouping, grp, lights, unknown, other, n0, n120, n240) AS (\n"
    "  SELECT 'all', 'all', lights, unknown, other, n0, n120, n240 FROM base\n"
    "  UNION ALL SELECT 'survey', survey, lights, unknown, other, n0, n120, n240 FROM base\n"
    "  UNION ALL SELECT 'technology', technology, lights, unknown, other, n0, n120, n240 FROM base)\n"
    "SELECT grouping, grp, sum(lights) AS lights, sum(unknown) AS unknown, sum(other) AS other,\n"
    "       sum(n0) AS n0, sum(n120) AS n120, sum(n240) AS n240, sum(n0 + n120 + n240) AS n\n"
    "FROM g GROUP BY grouping, grp;\n"
    ,
    "CREATE VIEW phase_shares AS\n"
    "SELECT *, 1.0 * n0 / n AS share0, 1.0 * n120 / n AS share120, 1.0 * n240 / n AS share240\n"
    "FROM phase_counts;\n"
    "CREATE VIEW phase_balance AS\n"
    "SELECT grouping, grp, lights, unknown, other, n0, n120, n240, n,\n"
    "  share0,\n"
    "  (share0 + z2 / (2 * n) - z * sqrt(share0 * (1 - share0) / n + z2 / (4.0 * n * n))) / (1 + z2 / n) AS lo0,\n"
    "  (share0 + z2 / (2 * n) + z * sqrt(share0 * (1 - share0) / n + z2 / (4.0 * n * n))) / (1 + z2 / n) AS hi0,\n"
    "  share120,\n"
    "  (share120 + z2 / (2 * n) - z * sqrt(share120 * (1 - share120) / n + z2 / (4.0 * n * n))) / (1 + z2 / n) AS lo120,\n"
    "  (share120 + z2 / (2 * n) + z * sqrt(share120 * (1 - share120) / n + z2 / (4.0 * n * n))) / (1 + z2 / n) AS hi120,\n"
    "  share240,\n"
    "  (share240 + z2 / (2 * n) - z * sqrt(share240 * (1 - share240) / n + z2 / (4.0 * n * n))) / (1 + z2 / n) AS lo240,\n"
    "  (share240 + z2 / (2 * n) + z * sqrt(share240 * (1 - share240) / n + z2 / (4.0 * n * n))) / (1 + z2 / n) AS hi240,\n"
    "  chi2, exp(-chi2 / 2) AS p_value,\n"
    "  3 * max(abs(share0 - 1.0 / 3), abs(share120 - 1.0 / 3), abs(share240 - 1.0 / 3)) AS imbalance\n"
    "FROM (SELECT *, " Z95_SQL " AS z, " Z95_SQL " * " Z95_SQL " AS z2,\n"
    "        CASE WHEN n > 0 THEN ((n0 - n / 3.0) * (n0 - n / 3.0) + (n120 - n / 3.0) * (n120 - n / 3.0)\n"
    "                             + (n240 - n / 3.0) * (n240 - n / 3.0)) / (n / 3.0) END AS chi2\n"
    "      FROM phase_shares);\n",
    NULL};

static const struct {
    const char *name;
    const char *const *sql;   /* NULL-terminated pieces (C99 limits literals to 4095 bytes) */
} migrations[] = {
    {"tables, R*Tree and triggers", migration_1},
    {"phase-balance views", migration_2},
};
_Static_assert(sizeof migrations / sizeof *migrations == SRV_DB_SCHEMA_VERSION,
               "one migration per schema version");

/* ------------------------------------------------------------------ handle */

enum {
    ST_ADD_DELIGHT, ST_GET_DELIGHT, ST_ADD_SURVEY, ST_GET_SURVEY, ST_ADD_STATION, ST_GET_STATION,
    ST_ADD_CAPTURE, ST_GET_CAPTURE, ST_ADD_FRAME, ST_ADD_LIGHT, ST_GET_LIGHT, ST_ADD_LOCATION,
    ST_ADD_FREQ, ST_DEL_CAPTURE, ST_COUNT
};

static const char *const stmt_sql[ST_COUNT] = {
    [ST_ADD_DELIGHT] = "INSERT INTO delight_versions(sha256, generator, source, bulbs, added_utc) "
                       "VALUES (?1, ?2, ?3, ?4, ?5) ON CONFLICT DO NOTHING",
    [ST_GET_DELIGHT] = "SELECT id FROM delight_versions WHERE sha256 = ?1 AND generator = ?2",
    [ST_ADD_SURVEY] = "INSERT INTO surveys(name, city, grid_hz, started_utc, notes, created_utc) "
                      "VALUES (?1, ?2, ?3, ?4, ?5, ?6) ON CONFLICT DO NOTHING",
    [ST_GET_SURVEY] = "SELECT id FROM surveys WHERE name = ?1",
    [ST_ADD_STATION] = "INSERT INTO stations(survey_id, name, lat_deg, lon_deg, height_m, "
                       "heading_deg, pitch_deg, roll_deg, sigma_heading_deg, sigma_pitch_deg, "
                       "sigma_roll_deg, focal_px, cx_px, cy_px, k1, k2, width_px, height_px, "
                       "refraction_k, sigma_px, time_utc) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, "
                       "?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16, ?17, ?18, ?19, ?20, ?21) "
                       "ON CONFLICT DO NOTHING",
    [ST_GET_STATION] = "SELECT id FROM stations WHERE survey_id = ?1 AND name = ?2",
    [ST_ADD_CAPTURE] = "INSERT INTO captures(survey_id, station_id, delight_id, capture_key, path, "
                       "utc, grid_hz, K, bands, width_px, height_px, locked, mean_frequency_hz, "
                       "sigma_frequency_hz, light_count, frame_count, frequency_count, "
                       "ingested_utc) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, "
                       "?13, ?14, ?15, ?16, ?17, ?18) ON CONFLICT DO NOTHING",
    [ST_GET_CAPTURE] = "SELECT id FROM captures WHERE survey_id = ?1 AND capture_key = ?2",
    [ST_ADD_FRAME] = "INSERT INTO frames(capture_id, k, file, cycles, hdr_map) "
                     "VALUES (?1, ?2, ?3, ?4, ?5) ON CONFLICT DO NOTHING",
    [ST_ADD_LIGHT] = "INSERT INTO lights(capture_id, light_index, x_px, y_px, area_px, peak_dn, "
                     "saturated_px, blob_flags, brightness, snr, chi2, dof, p_value, bulb_id, "
                     "technology, phase_deg, phase_fit_deg, phase_sigma_deg, confidence, "
                     "bulb_confidence, phase_confidence, runner_bulb_id, runner_phase_deg, "
                     "runner_confidence, match_flags) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, "
                     "?10, ?11, ?12, ?13, ?14, ?15, ?16, ?17, ?18, ?19, ?20, ?21, ?22, ?23, ?24, "
                     "?25) ON CONFLICT DO NOTHING",
    [ST_GET_LIGHT] = "SELECT id FROM lights WHERE capture_id = ?1 AND light_index = ?2",
    [ST_ADD_LOCATION] = "INSERT INTO locations(light_id, method, lat_deg, lon_deg, height_m, "
                        "semi_major_m, semi_minor_m, azimuth_deg, range_m, flags) VALUES (?1, ?2, "
                        "?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10) ON CONFLICT DO NOTHING",
    [ST_ADD_FREQ] = "INSERT INTO grid_frequency(capture_id, seq, t_s, window_s, frequency_hz, "
                    "sigma_hz) VALUES (?1, ?2, ?3, ?4, ?5, ?6) ON CONFLICT DO NOTHING",
    [ST_DEL_CAPTURE] = "DELETE FROM captures WHERE survey_id = ?1 AND capture_key = ?2",
};

struct srv_db {
    sqlite3 *db;
    char *path;
    int readonly;
    int wal;                    /* this handle switched the file to WAL */
    int in_txn;
    sqlite3_stmt *st[ST_COUNT];
};

/* GS_ESQL with the connection's message, "PATH: WHAT: MESSAGE". */
static gs_status sql_fail(sqlite3 *db, const char *path, const char *what)
{
    int code = db ? sqlite3_errcode(db) : SQLITE_NOMEM;
    const char *msg = db ? sqlite3_errmsg(db) : "out of memory";
    if (code == SQLITE_NOMEM) return gs_fail(GS_ENOMEM, "%s: %s: out of memory", path, what);
    if (code == SQLITE_READONLY)
        return gs_fail(GS_EIO, "%s: %s: the database is read-only (%s)", path, what, msg);
    if (code == SQLITE_CANTOPEN || code == SQLITE_IOERR || code == SQLITE_FULL)
        return gs_fail(GS_EIO, "%s: %s: %s", path, what, msg);
    if (code == SQLITE_NOTADB || code == SQLITE_CORRUPT)
        return gs_fail(GS_EFORMAT, "%s: %s: %s", path, what, msg);
    return gs_fail(GS_ESQL, "%s: %s: %s", path, what, msg);
}

static gs_status db_fail(srv_db *db, const char *what)
{
    return sql_fail(db->db, db->path, what);
}

static void utc_now(char buf[32])
{
    time_t t = time(NULL);
    struct tm tm;
    gmtime_r(&t, &tm);
    strftime(buf, 32, "%Y-%m-%dT%H:%M:%SZ", &tm);
}

static gs_status exec(srv_db *db, const char *sql, const char *what)
{
    if (sqlite3_exec(db->db, sql, NULL, NULL, NULL) != SQLITE_OK) return db_fail(db, what);
    return GS_OK;
}

static gs_status stmt(srv_db *db, int which, sqlite3_stmt **out)
{
    if (!db->st[which]) {
        if (sqlite3_prepare_v3(db->db, stmt_sql[which], -1, SQLITE_PREPARE_PERSISTENT,
                               &db->st[which], NULL) != SQLITE_OK)
            return db_fail(db, "preparing a statement");
    } else {
        sqlite3_reset(db->st[which]);
        sqlite3_clear_bindings(db->st[which]);
    }
    *out = db->st[which];
    return GS_OK;
}

static void bind_real(sqlite3_stmt *q, int i, double v)
{
    if (isfinite(v)) sqlite3_bind_double(q, i, v);
    else sqlite3_bind_null(q, i);
}

static void bind_text(sqlite3_stmt *q, int i, const char *s)
{
    if (s && *s) sqlite3_bind_text(q, i, s, -1, SQLITE_STATIC);
    else sqlite3_bind_null(q, i);
}

/* An integer, NULL when it equals `none`. */
static void bind_int_or_null(sqlite3_stmt *q, int i, int64_t v, int64_t none)
{
    if (v == none) sqlite3_bind_null(q, i);
    else sqlite3_bind_int64(q, i, v);
}

/* Step an "INSERT ... ON CONFLICT DO NOTHING": *inserted = 1 and *id = the new rowid, or
 * *inserted = 0 when the natural key existed (the caller looks the id up). sqlite3_changes()
 * counts the statement's own row (not the R*Tree trigger's). */
static gs_status step_returning(srv_db *db, sqlite3_stmt *q, int64_t *id, int *inserted,
                                const char *what)
{
    int rc = sqlite3_step(q);
    sqlite3_reset(q);
    if (rc != SQLITE_DONE) return db_fail(db, what);
    *inserted = sqlite3_changes(db->db) > 0;
    if (*inserted && id) *id = sqlite3_last_insert_rowid(db->db);
    return GS_OK;
}

static gs_status step_id(srv_db *db, sqlite3_stmt *q, int64_t *id, const char *what)
{
    int rc = sqlite3_step(q);
    if (rc == SQLITE_ROW) {
        if (id) *id = sqlite3_column_int64(q, 0);
        sqlite3_reset(q);
        return GS_OK;
    }
    sqlite3_reset(q);
    if (rc == SQLITE_DONE) return gs_fail(GS_ENOTFOUND, "%s: %s: not found", db->path, what);
    return db_fail(db, what);
}

static gs_status step_done(srv_db *db, sqlite3_stmt *q, const char *what)
{
    int rc = sqlite3_step(q);
    sqlite3_reset(q);
    if (rc != SQLITE_DONE) return db_fail(db, what);
    return GS_OK;
}

/* ------------------------------------------------------------------ transactions */

static gs_status writable(srv_db *db)
{
    if (db->readonly)
        return gs_fail(GS_EIO, "%s: opened read-only: cannot write to the survey database", db->path);
    return GS_OK;
}

gs_status srv_db_begin(srv_db *db)
{
    if (!db) return gs_fail(GS_EINVAL, "srv_db_begin: NULL database");
    gs_status s = writable(db);
    if (s != GS_OK) return s;
    if (db->in_txn) return gs_fail(GS_EINVAL, "%s: a transaction is already open", db->path);
    if ((s = exec(db, "BEGIN IMMEDIATE", "begin")) != GS_OK) return s;
    db->in_txn = 1;
    return GS_OK;
}

gs_status srv_db_commit(srv_db *db)
{
    if (!db) return gs_fail(GS_EINVAL, "srv_db_commit: NULL database");
    if (!db->in_txn) return gs_fail(GS_EINVAL, "%s: commit without a transaction", db->path);
    gs_status s = exec(db, "COMMIT", "commit");
    if (s != GS_OK) {
        char msg[512];
        snprintf(msg, sizeof msg, "%s", gs_detail());
        sqlite3_exec(db->db, "ROLLBACK", NULL, NULL, NULL);
        db->in_txn = 0;
        return gs_fail(s, "%s (rolled back)", msg);
    }
    db->in_txn = 0;
    return GS_OK;
}

gs_status srv_db_rollback(srv_db *db)
{
    if (!db || !db->in_txn) return GS_OK;
    db->in_txn = 0;
    if (sqlite3_get_autocommit(db->db)) return GS_OK;   /* SQLite already rolled back */
    return exec(db, "ROLLBACK", "rollback");
}

int srv_db_in_transaction(const srv_db *db)
{
    return db && db->in_txn;
}

static gs_status need_txn(srv_db *db, const char *what)
{
    gs_status s = writable(db);
    if (s != GS_OK) return s;
    if (!db->in_txn)
        return gs_fail(GS_EINVAL, "%s: %s outside a transaction (call srv_db_begin first)",
                       db->path, what);
    return GS_OK;
}

/* Run body-less helpers in a transaction of their own when the caller has none. */
static gs_status auto_begin(srv_db *db, int *began)
{
    *began = 0;
    gs_status s = writable(db);
    if (s != GS_OK || db->in_txn) return s;
    if ((s = srv_db_begin(db)) == GS_OK) *began = 1;
    return s;
}

static gs_status auto_end(srv_db *db, int began, gs_status s)
{
    if (!began) return s;
    if (s == GS_OK) return srv_db_commit(db);
    char msg[512];
    snprintf(msg, sizeof msg, "%s", gs_detail());
    srv_db_rollback(db);
    return gs_fail(s, "%s", msg);
}

/* ------------------------------------------------------------------ open */

typedef enum { KIND_EMPTY, KIND_SURVEY } db_kind;

/* Read PRAGMA-style integer. */
static int query_int(sqlite3 *db, const char *sql, int *v)
{
    sqlite3_stmt *q = NULL;
    int ok = sqlite3_prepare_v2(db, sql, -1, &q, NULL) == SQLITE_OK && sqlite3_step(q) == SQLITE_ROW;
    if (ok) *v = sqlite3_column_int(q, 0);
    sqlite3_finalize(q);
    return ok;
}

static const char *expected_text(void)
{
    return "expected a gridsurvey survey database (SQLite, application_id 0x47534442 'GSDB', "
           "schema version 1.." "2" ")";
}
_Static_assert(SRV_DB_SCHEMA_VERSION == 2, "update expected_text()");

/* Identify an existing file through a read-only connection (nothing is written). */
static gs_status identify(const char *path, off_t size, db_kind *kind, int *version)
{
    *version = 0;
    if (size == 0) {
        *kind = KIND_EMPTY;
        return GS_OK;
    }
    unsigned char head[16] = {0};
    FILE *f = fopen(path, "rb");
    if (!f) return gs_fail(GS_EIO, "%s: cannot read: %s", path, strerror(errno));
    size_t got = fread(head, 1, sizeof head, f);
    fclose(f);
    if (got < sizeof head || memcmp(head, "SQLite format 3", 16) != 0)
        return gs_fail(GS_EFORMAT, "%s: not a survey database: %s; found a file that is not "
                       "SQLite", path, expected_text());
    sqlite3 *db = NULL;
    gs_status s = GS_OK;
    if (sqlite3_open_v2(path, &db, SQLITE_OPEN_READONLY, NULL) != SQLITE_OK) {
        s = sql_fail(db, path, "open");
        sqlite3_close(db);
        return s;
    }
    int app = 0, user = 0, objects = 0, delight = 0;
    if (!query_int(db, "PRAGMA application_id", &app) || !query_int(db, "PRAGMA user_version", &user) ||
        !query_int(db, "SELECT count(*) FROM sqlite_master", &objects)) {
        s = sql_fail(db, path, "reading the header");
        if (s == GS_EFORMAT)
            s = gs_fail(GS_EFORMAT, "%s: not a survey database: %s; SQLite says: %s", path,
                        expected_text(), sqlite3_errmsg(db));
        sqlite3_close(db);
        return s;
    }
    query_int(db, "SELECT count(*) FROM sqlite_master WHERE name = 'delight_meta'", &delight);
    sqlite3_close(db);
    if ((unsigned)app == SRV_DB_APPLICATION_ID) {
        if (user > SRV_DB_SCHEMA_VERSION)
            return gs_fail(GS_EFORMAT, "%s: survey database schema version %d is newer than this "
                           "gridsurvey's %d: use a newer gridsurvey", path, user, SRV_DB_SCHEMA_VERSION);
        if (user < 1)
            return gs_fail(GS_EFORMAT, "%s: survey database with schema version %d: %s", path, user,
                           expected_text());
        *kind = KIND_SURVEY;
        *version = user;
        return GS_OK;
    }
    if (app == 0 && user == 0 && objects == 0) {
        *kind = KIND_EMPTY;
        return GS_OK;
    }
    char found[160];
    if ((unsigned)app == 0x47504B47u || (unsigned)app == 0x47503130u)
        snprintf(found, sizeof found, "a GeoPackage (application_id 'GPKG')");
    else if (delight)
        snprintf(found, sizeof found, "a DELIGHT bulb database (table delight_meta, schema "
                 "version %d)", user);
    else
        snprintf(found, sizeof found, "an SQLite database with application_id 0x%08X, "
                 "user_version %d and %d schema objects", (unsigned)app, user, objects);
    return gs_fail(GS_EFORMAT, "%s: not a survey database: %s; found %s", path, expected_text(), found);
}

/* Apply migrations so that the schema is at `target`, each in its own transaction. */
static gs_status migrate(srv_db *db, int target)
{
    for (;;) {
        gs_status s = srv_db_begin(db);
        if (s != GS_OK) return s;
        int version = 0;
        if (!query_int(db->db, "PRAGMA user_version", &version)) {
            s = db_fail(db, "reading the schema version");
            srv_db_rollback(db);
            return s;
        }
        if (version >= target) return srv_db_rollback(db);
        const char *name = migrations[version].name;
        char sql[512], now[32];
        utc_now(now);
        for (const char *const *part = migrations[version].sql; *part && s == GS_OK; part++)
            s = exec(db, *part, name);
        if (s != GS_OK) {
            srv_db_rollback(db);
            return s;
        }
        snprintf(sql, sizeof sql,
                 "%sINSERT INTO migrations VALUES (%d, '%s', '%s', '%s'); PRAGMA user_version = %d",
                 version == 0 ? "PRAGMA application_id = 1196639298; " : "", version + 1, name, now,
                 SRV_GENERATOR, version + 1);
        _Static_assert(SRV_DB_APPLICATION_ID == 1196639298, "application_id literal");
        if ((s = exec(db, sql, "recording the migration")) != GS_OK ||
            (version == 0 && (s = exec(db, "INSERT INTO meta VALUES ('created_utc', "
                                           "strftime('%Y-%m-%dT%H:%M:%SZ', 'now'))",
                                       "recording the creation time")) != GS_OK)) {
            srv_db_rollback(db);
            return s;
        }
        if ((s = srv_db_commit(db)) != GS_OK) return s;
    }
}

static void remove_created(const char *path)
{
    static const char *const suffix[] = {"", "-wal", "-shm", "-journal"};
    char p[4096];
    for (size_t i = 0; i < sizeof suffix / sizeof *suffix; i++) {
        snprintf(p, sizeof p, "%s%s", path, suffix[i]);
        unlink(p);
    }
}

static gs_status open_at(const char *path, srv_db_mode mode, int target, srv_db **out)
{
    *out = NULL;
    if (!path || !*path) return gs_fail(GS_EINVAL, "survey database: empty path");
    if (mode != SRV_DB_READ && mode != SRV_DB_WRITE && mode != SRV_DB_CREATE)
        return gs_fail(GS_EINVAL, "%s: open mode %d: expected SRV_DB_READ, _WRITE or _CREATE", path,
                       (int)mode);
    struct stat st;
    int exists = stat(path, &st) == 0;
    db_kind kind = KIND_EMPTY;
    int version = 0;
    gs_status s;
    if (!exists) {
        if (errno != ENOENT)
            return gs_fail(GS_EIO, "%s: cannot %s the survey database: %s", path,
                           mode == SRV_DB_CREATE ? "create" : "open", strerror(errno));
        if (mode != SRV_DB_CREATE)
            return gs_fail(GS_ENOTFOUND, "%s: no such survey database (create one with `gridsurvey "
                           "db init --db %s`)", path, path);
    } else {
        if (!S_ISREG(st.st_mode))
            return gs_fail(GS_EIO, "%s: not a regular file: %s", path, expected_text());
        if ((s = identify(path, st.st_size, &kind, &version)) != GS_OK) return s;
        if (kind == KIND_EMPTY && mode == SRV_DB_READ)
            return gs_fail(GS_EFORMAT, "%s: an empty file, not yet a survey database: %s", path,
                           expected_text());
        if (kind == KIND_SURVEY && version < target && mode == SRV_DB_READ)
            return gs_fail(GS_EFORMAT, "%s: survey database schema version %d is older than this "
                           "gridsurvey's %d: migrate it with `gridsurvey db migrate --db %s`", path,
                           version, target, path);
    }
    srv_db *db = calloc(1, sizeof *db);
    if (!db || !(db->path = strdup(path))) {
        free(db);
        return gs_fail(GS_ENOMEM, "%s: out of memory", path);
    }
    db->readonly = mode == SRV_DB_READ;
    int flags = db->readonly ? SQLITE_OPEN_READONLY
                             : SQLITE_OPEN_READWRITE | (exists ? 0 : SQLITE_OPEN_CREATE);
    int created = 0;
    if (sqlite3_open_v2(path, &db->db, flags | SQLITE_OPEN_NOMUTEX, NULL) != SQLITE_OK) {
        int sys = db->db ? sqlite3_system_errno(db->db) : 0;
        if (sqlite3_errcode(db->db) == SQLITE_CANTOPEN)
            s = gs_fail(GS_EIO, "%s: cannot %s the survey database: %s", path,
                        exists ? "open" : "create", sys ? strerror(sys) : sqlite3_errmsg(db->db));
        else
            s = sql_fail(db->db, path, "open");
        goto fail;
    }
    created = !exists;
    if (!db->readonly && sqlite3_db_readonly(db->db, "main") == 1) {
        s = gs_fail(GS_EIO, "%s: the file is read-only: cannot open the survey database for writing",
                    path);
        goto fail;
    }
    sqlite3_extended_result_codes(db->db, 0);
    sqlite3_busy_timeout(db->db, 10000);
    /* 64 MiB of page cache: the R*Tree and index inserts of a 1e6-light survey touch pages all
     * over the file (docs/survey-db.md, "Scale") */
    if ((s = exec(db, "PRAGMA foreign_keys = ON; PRAGMA cache_size = -65536", "setting pragmas")) != GS_OK)
        goto fail;
    if (!db->readonly) {
        sqlite3_stmt *q = NULL;
        const char *jm = NULL;
        if (sqlite3_prepare_v2(db->db, "PRAGMA journal_mode = WAL", -1, &q, NULL) == SQLITE_OK &&
            sqlite3_step(q) == SQLITE_ROW)
            jm = (const char *)sqlite3_column_text(q, 0);
        int wal = jm && !strcmp(jm, "wal");
        sqlite3_finalize(q);
        if (!wal) {
            s = db_fail(db, "switching to WAL");
            goto fail;
        }
        db->wal = 1;
        /* checkpoint every 10000 pages (40 MiB) rather than 1000: the R*Tree and index pages
         * that every capture rewrites reach the database file once per checkpoint */
        if ((s = exec(db, "PRAGMA synchronous = NORMAL; PRAGMA wal_autocheckpoint = 10000; "
                          "PRAGMA journal_size_limit = 67108864", "setting pragmas")) != GS_OK)
            goto fail;
        if ((s = migrate(db, target)) != GS_OK) goto fail;
    }
    *out = db;
    return GS_OK;
fail:
    {
        char msg[512];
        snprintf(msg, sizeof msg, "%s", gs_detail());
        srv_db_close(db);
        if (created) remove_created(path);
        return gs_fail(s, "%s", msg);
    }
}

gs_status srv_db_open(const char *path, srv_db_mode mode, srv_db **out)
{
    if (!out) return gs_fail(GS_EINVAL, "srv_db_open: NULL output");
    return open_at(path, mode, SRV_DB_SCHEMA_VERSION, out);
}

gs_status srv_db_create_at_version(const char *path, int version)
{
    if (version < 1 || version > SRV_DB_SCHEMA_VERSION)
        return gs_fail(GS_EINVAL, "schema version %d: expected 1..%d", version, SRV_DB_SCHEMA_VERSION);
    struct stat st;
    if (path && stat(path, &st) == 0) return gs_fail(GS_EIO, "%s: exists: expected a new path", path);
    srv_db *db;
    gs_status s = open_at(path, SRV_DB_CREATE, version, &db);
    srv_db_close(db);
    return s;
}

void srv_db_close(srv_db *db)
{
    if (!db) return;
    if (db->in_txn && db->db) sqlite3_exec(db->db, "ROLLBACK", NULL, NULL, NULL);
    for (int i = 0; i < ST_COUNT; i++) sqlite3_finalize(db->st[i]);
    /* At rest the file is self-contained: the last writer checkpoints and leaves WAL mode, so
     * readers (SQLITE_OPEN_READONLY) need no -wal/-shm files and leave none behind. With other
     * connections open this fails at once (no busy wait) and the file stays in WAL mode. */
    if (db->db && !db->readonly && db->wal) {
        sqlite3_busy_timeout(db->db, 0);
        sqlite3_exec(db->db, "PRAGMA journal_mode = DELETE", NULL, NULL, NULL);
    }
    sqlite3_close(db->db);
    free(db->path);
    free(db);
}

const char *srv_db_path(const srv_db *db)
{
    return db ? db->path : "";
}

struct sqlite3 *srv_db_sqlite(srv_db *db)
{
    return db ? db->db : NULL;
}

gs_status srv_delight_fingerprint(const gs_delight *d, const char *source, srv_delight_row *r)
{
    if (!d || !r) return gs_fail(GS_EINVAL, "srv_delight_fingerprint: NULL argument");
    memset(r, 0, sizeof *r);
    char *buf = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&buf, &len);
    if (!f) return gs_fail(GS_ENOMEM, "DELIGHT fingerprint: cannot open a memory stream");
    gs_status s = gs_delight_export_csv(d, f);
    if (fclose(f) != 0 && s == GS_OK) s = gs_fail(GS_ENOMEM, "DELIGHT fingerprint: out of memory");
    if (s == GS_OK) {
        gs_sha256_hex(buf, len, r->sha256);
        r->source = source && *source ? source : "built-in";
        r->generator = SRV_GENERATOR;
        r->bulbs = (long)gs_delight_count(d);
    }
    free(buf);
    return s;
}

/* ------------------------------------------------------------------ row helpers */

void srv_station_row_init(srv_station_row *r)
{
    memset(r, 0, sizeof *r);
    gis_camera *c = &r->cam;
    c->lat_deg = c->lon_deg = c->height_m = NAN;
    c->heading_deg = c->pitch_deg = c->roll_deg = NAN;
    c->sigma_heading_deg = c->sigma_pitch_deg = c->sigma_roll_deg = NAN;
    c->focal_px = c->cx_px = c->cy_px = c->k1 = c->k2 = c->refraction_k = NAN;
    r->sigma_px = NAN;
}

void srv_capture_row_init(srv_capture_row *r)
{
    memset(r, 0, sizeof *r);
    r->locked = -1;
    r->mean_frequency_hz = r->sigma_frequency_hz = NAN;
}

void srv_light_row_init(srv_light_row *r)
{
    memset(r, 0, sizeof *r);
    r->x_px = r->y_px = r->peak_dn = r->brightness = r->snr = r->chi2 = r->p_value = NAN;
    r->area_px = r->saturated_px = r->dof = -1;
    r->phase_deg = r->phase_fit_deg = r->phase_sigma_deg = NAN;
    r->confidence = r->bulb_confidence = r->phase_confidence = NAN;
    r->runner_phase_deg = r->runner_confidence = NAN;
}

void srv_location_row_init(srv_location_row *r)
{
    memset(r, 0, sizeof *r);
    r->method = SRV_LOC_NONE;
    r->lat_deg = r->lon_deg = r->height_m = r->range_m = NAN;
    r->ellipse.semi_major_m = r->ellipse.semi_minor_m = r->ellipse.azimuth_deg = NAN;
}

void srv_light_from_catalog(srv_light_row *r, const rec_catalog *cat, size_t i)
{
    if (!r || !cat || i >= cat->count) return;
    r->index = (int)i;
    r->x_px = cat->x_px[i];
    r->y_px = cat->y_px[i];
    r->area_px = cat->area_px ? cat->area_px[i] : -1;
    r->peak_dn = cat->peak_dn ? cat->peak_dn[i] : NAN;
    r->saturated_px = cat->saturated_px ? cat->saturated_px[i] : -1;
    r->blob_flags = cat->flags ? cat->flags[i] : 0;
    double sum = 0.0, var = 0.0;
    size_t m = (size_t)cat->bands * (size_t)cat->K;
    for (size_t j = 0; cat->signal && cat->sigma && j < m; j++) {
        double x = cat->signal[i * m + j], sg = cat->sigma[i * m + j];
        if (!isfinite(x) || !isfinite(sg) || !(sg > 0.0)) continue;
        sum += x;
        var += sg * sg;
    }
    r->snr = var > 0.0 ? sum / sqrt(var) : NAN;
}

void srv_light_from_match(srv_light_row *r, const rec_match *m, const rec_matcher *mt)
{
    if (!r || !m) return;
    const gs_bulb *b = m->bulb >= 0 && mt ? rec_matcher_bulb(mt, (size_t)m->bulb) : NULL;
    const gs_bulb *rb = m->runner_bulb >= 0 && mt ? rec_matcher_bulb(mt, (size_t)m->runner_bulb) : NULL;
    r->brightness = m->brightness;
    r->chi2 = m->chi2;
    r->dof = m->dof;
    r->p_value = m->p_value;
    r->bulb_id = b ? b->id : NULL;
    r->technology = b ? gs_tech_name(b->type) : NULL;
    r->phase_fit_deg = b ? m->phase_deg : NAN;
    r->phase_deg = b && !(m->flags & REC_MATCH_PHASE_AMBIGUOUS) ? m->phase_deg : NAN;
    r->phase_sigma_deg = b ? m->phase_sigma_deg : NAN;
    r->confidence = m->confidence;
    r->bulb_confidence = m->bulb_confidence;
    r->phase_confidence = m->phase_confidence;
    r->runner_bulb_id = rb ? rb->id : NULL;
    r->runner_phase_deg = rb ? m->runner_phase_deg : NAN;
    r->runner_confidence = rb ? m->runner_confidence : NAN;
    r->match_flags = m->flags;
}

void srv_location_from_fix(srv_location_row *r, const gis_fix *f)
{
    if (!r || !f) return;
    r->method = SRV_LOC_ONE_STATION;
    r->lat_deg = f->lat_deg;
    r->lon_deg = f->lon_deg;
    r->height_m = f->height_m;
    r->ellipse = f->ellipse;
    r->range_m = f->range_m;
    r->flags = f->flags;
}

/* [0, 360) */
static double wrap360(double d)
{
    double w = fmod(d, 360.0);
    if (w < 0.0) w += 360.0;
    return w >= 360.0 ? 0.0 : w;
}

/* [-180, 180) */
static double wrap180(double d)
{
    double w = wrap360(d + 180.0) - 180.0;
    return w < -180.0 ? -180.0 : w;
}

/* ------------------------------------------------------------------ inserts */

gs_status srv_db_add_delight(srv_db *db, const srv_delight_row *r, int64_t *id)
{
    if (!db || !r) return gs_fail(GS_EINVAL, "srv_db_add_delight: NULL argument");
    if (strlen(r->sha256) != 64 || strspn(r->sha256, "0123456789abcdef") != 64)
        return gs_fail(GS_EINVAL, "%s: delight sha256 '%.64s': expected 64 lower-case hex digits",
                       db->path, r->sha256);
    if (r->bulbs < 0) return gs_fail(GS_EINVAL, "%s: delight bulbs %ld: expected >= 0", db->path, r->bulbs);
    int began;
    gs_status s = auto_begin(db, &began);
    if (s != GS_OK) return s;
    const char *gen = r->generator && *r->generator ? r->generator : SRV_GENERATOR;
    sqlite3_stmt *q;
    char now[32];
    utc_now(now);
    int inserted = 0;
    if ((s = stmt(db, ST_ADD_DELIGHT, &q)) == GS_OK) {
        sqlite3_bind_text(q, 1, r->sha256, -1, SQLITE_STATIC);
        sqlite3_bind_text(q, 2, gen, -1, SQLITE_STATIC);
        sqlite3_bind_text(q, 3, r->source && *r->source ? r->source : "built-in", -1, SQLITE_STATIC);
        sqlite3_bind_int64(q, 4, r->bulbs);
        sqlite3_bind_text(q, 5, now, -1, SQLITE_TRANSIENT);
        s = step_returning(db, q, id, &inserted, "adding a DELIGHT version");
    }
    if (s == GS_OK && !inserted && (s = stmt(db, ST_GET_DELIGHT, &q)) == GS_OK) {
        sqlite3_bind_text(q, 1, r->sha256, -1, SQLITE_STATIC);
        sqlite3_bind_text(q, 2, gen, -1, SQLITE_STATIC);
        s = step_id(db, q, id, "looking up a DELIGHT version");
    }
    return auto_end(db, began, s);
}

gs_status srv_db_add_survey(srv_db *db, const srv_survey_row *r, int64_t *id)
{
    if (!db || !r) return gs_fail(GS_EINVAL, "srv_db_add_survey: NULL argument");
    if (!r->name || !*r->name || strlen(r->name) >= GIS_TEXT_MAX)
        return gs_fail(GS_EINVAL, "%s: survey name '%s': expected 1 to %d bytes", db->path,
                       r->name ? r->name : "", GIS_TEXT_MAX - 1);
    if (r->grid_hz != 0 && r->grid_hz != 50 && r->grid_hz != 60)
        return gs_fail(GS_EINVAL, "%s: survey %s: grid_hz %d: expected 50, 60 or 0 (unknown)",
                       db->path, r->name, r->grid_hz);
    int began;
    gs_status s = auto_begin(db, &began);
    if (s != GS_OK) return s;
    sqlite3_stmt *q;
    char now[32];
    utc_now(now);
    int inserted = 0;
    if ((s = stmt(db, ST_ADD_SURVEY, &q)) == GS_OK) {
        sqlite3_bind_text(q, 1, r->name, -1, SQLITE_STATIC);
        bind_text(q, 2, r->city);
        bind_int_or_null(q, 3, r->grid_hz, 0);
        bind_text(q, 4, r->started_utc);
        bind_text(q, 5, r->notes);
        sqlite3_bind_text(q, 6, now, -1, SQLITE_TRANSIENT);
        s = step_returning(db, q, id, &inserted, "adding a survey");
    }
    if (s == GS_OK && !inserted) s = srv_db_find_survey(db, r->name, id);
    return auto_end(db, began, s);
}

gs_status srv_db_find_survey(srv_db *db, const char *name, int64_t *id)
{
    if (!db || !name) return gs_fail(GS_EINVAL, "srv_db_find_survey: NULL argument");
    sqlite3_stmt *q;
    gs_status s = stmt(db, ST_GET_SURVEY, &q);
    if (s != GS_OK) return s;
    sqlite3_bind_text(q, 1, name, -1, SQLITE_STATIC);
    s = step_id(db, q, id, "looking up a survey");
    if (s == GS_ENOTFOUND) return gs_fail(s, "%s: no survey named '%s'", db->path, name);
    return s;
}

gs_status srv_db_add_station(srv_db *db, const srv_station_row *r, int64_t *id)
{
    if (!db || !r) return gs_fail(GS_EINVAL, "srv_db_add_station: NULL argument");
    if (!r->name || !*r->name)
        return gs_fail(GS_EINVAL, "%s: station: expected a name", db->path);
    const gis_camera *c = &r->cam;
    if (isfinite(c->lat_deg) && fabs(c->lat_deg) > 90.0)
        return gs_fail(GS_EINVAL, "%s: station %s: lat_deg %g: expected [-90, 90]", db->path, r->name,
                       c->lat_deg);
    int began;
    gs_status s = auto_begin(db, &began);
    if (s != GS_OK) return s;
    sqlite3_stmt *q;
    int inserted = 0;
    if ((s = stmt(db, ST_ADD_STATION, &q)) == GS_OK) {
        sqlite3_bind_int64(q, 1, r->survey_id);
        sqlite3_bind_text(q, 2, r->name, -1, SQLITE_STATIC);
        const double v[] = {c->lat_deg, isfinite(c->lon_deg) ? wrap180(c->lon_deg) : NAN,
                            c->height_m, c->heading_deg, c->pitch_deg, c->roll_deg,
                            c->sigma_heading_deg, c->sigma_pitch_deg, c->sigma_roll_deg,
                            c->focal_px, c->cx_px, c->cy_px, c->k1, c->k2};
        for (int i = 0; i < 14; i++) bind_real(q, 3 + i, v[i]);
        bind_int_or_null(q, 17, c->width_px, 0);
        bind_int_or_null(q, 18, c->height_px, 0);
        bind_real(q, 19, c->refraction_k);
        bind_real(q, 20, r->sigma_px);
        bind_text(q, 21, r->time_utc);
        s = step_returning(db, q, id, &inserted, "adding a station");
    }
    if (s == GS_OK && !inserted && (s = stmt(db, ST_GET_STATION, &q)) == GS_OK) {
        sqlite3_bind_int64(q, 1, r->survey_id);
        sqlite3_bind_text(q, 2, r->name, -1, SQLITE_STATIC);
        s = step_id(db, q, id, "looking up a station");
    }
    return auto_end(db, began, s);
}

gs_status srv_db_capture_done(srv_db *db, int64_t survey_id, const char *key, int *done)
{
    if (!db || !key || !done) return gs_fail(GS_EINVAL, "srv_db_capture_done: NULL argument");
    sqlite3_stmt *q;
    gs_status s = stmt(db, ST_GET_CAPTURE, &q);
    if (s != GS_OK) return s;
    sqlite3_bind_int64(q, 1, survey_id);
    sqlite3_bind_text(q, 2, key, -1, SQLITE_STATIC);
    s = step_id(db, q, NULL, "looking up a capture");
    *done = s == GS_OK;
    return s == GS_ENOTFOUND ? GS_OK : s;
}

gs_status srv_db_insert_capture(srv_db *db, const srv_capture_row *r, size_t n_lights,
                                size_t n_frames, size_t n_frequency, int64_t *id)
{
    if (!db || !r) return gs_fail(GS_EINVAL, "srv_db_insert_capture: NULL argument");
    gs_status s = need_txn(db, "inserting a capture");
    if (s != GS_OK) return s;
    if (!r->key || !*r->key) return gs_fail(GS_EINVAL, "%s: capture: expected a key", db->path);
    if (r->survey_id <= 0)
        return gs_fail(GS_EINVAL, "%s: capture %s: survey_id %lld: expected a survey's id", db->path,
                       r->key, (long long)r->survey_id);
    if ((r->grid_hz && r->grid_hz != 50 && r->grid_hz != 60) || (r->K && r->K < 2) ||
        (r->bands && r->bands != 1 && r->bands != 3) || r->locked < -1 || r->locked > 1)
        return gs_fail(GS_EINVAL, "%s: capture %s: grid_hz %d, K %d, bands %d, locked %d: expected "
                       "50/60, >= 2, 1/3 and 0/1 (0 or -1 for unknown)", db->path, r->key,
                       r->grid_hz, r->K, r->bands, r->locked);
    sqlite3_stmt *q;
    char now[32];
    utc_now(now);
    int inserted = 0;
    if ((s = stmt(db, ST_ADD_CAPTURE, &q)) != GS_OK) return s;
    sqlite3_bind_int64(q, 1, r->survey_id);
    bind_int_or_null(q, 2, r->station_id, 0);
    bind_int_or_null(q, 3, r->delight_id, 0);
    sqlite3_bind_text(q, 4, r->key, -1, SQLITE_STATIC);
    bind_text(q, 5, r->path);
    bind_text(q, 6, r->utc);
    bind_int_or_null(q, 7, r->grid_hz, 0);
    bind_int_or_null(q, 8, r->K, 0);
    bind_int_or_null(q, 9, r->bands, 0);
    bind_int_or_null(q, 10, r->width_px, 0);
    bind_int_or_null(q, 11, r->height_px, 0);
    bind_int_or_null(q, 12, r->locked, -1);
    bind_real(q, 13, r->mean_frequency_hz);
    bind_real(q, 14, r->sigma_frequency_hz);
    sqlite3_bind_int64(q, 15, (sqlite3_int64)n_lights);
    sqlite3_bind_int64(q, 16, (sqlite3_int64)n_frames);
    sqlite3_bind_int64(q, 17, (sqlite3_int64)n_frequency);
    sqlite3_bind_text(q, 18, now, -1, SQLITE_TRANSIENT);
    if ((s = step_returning(db, q, id, &inserted, "inserting a capture")) != GS_OK || inserted) return s;
    if ((s = stmt(db, ST_GET_CAPTURE, &q)) != GS_OK) return s;
    sqlite3_bind_int64(q, 1, r->survey_id);
    sqlite3_bind_text(q, 2, r->key, -1, SQLITE_STATIC);
    return step_id(db, q, id, "looking up a capture");
}

gs_status srv_db_insert_frame(srv_db *db, int64_t capture_id, const srv_frame_row *r)
{
    if (!db || !r) return gs_fail(GS_EINVAL, "srv_db_insert_frame: NULL argument");
    gs_status s = need_txn(db, "inserting a frame");
    if (s != GS_OK) return s;
    if (r->k < 0) return gs_fail(GS_EINVAL, "%s: frame k %d: expected >= 0", db->path, r->k);
    sqlite3_stmt *q;
    if ((s = stmt(db, ST_ADD_FRAME, &q)) != GS_OK) return s;
    sqlite3_bind_int64(q, 1, capture_id);
    sqlite3_bind_int(q, 2, r->k);
    bind_text(q, 3, r->file);
    bind_real(q, 4, r->cycles);
    bind_text(q, 5, r->hdr_map);
    return step_done(db, q, "inserting a frame");
}

/* A probability for storage: NaN -> 0; outside [0, 1] -> -1 (invalid). */
static double prob(double p)
{
    if (isnan(p)) return 0.0;
    return p >= 0.0 && p <= 1.0 ? p : -1.0;
}

gs_status srv_db_insert_light(srv_db *db, int64_t capture_id, const srv_light_row *r,
                              int64_t *light_id)
{
    if (!db || !r) return gs_fail(GS_EINVAL, "srv_db_insert_light: NULL argument");
    gs_status s = need_txn(db, "inserting a light");
    if (s != GS_OK) return s;
    if (r->index < 0) return gs_fail(GS_EINVAL, "%s: light index %d: expected >= 0", db->path, r->index);
    if (!isfinite(r->x_px) || !isfinite(r->y_px))
        return gs_fail(GS_EINVAL, "%s: light %d: x_px, y_px (%g, %g): expected finite pixels",
                       db->path, r->index, r->x_px, r->y_px);
    double conf = prob(r->confidence), bconf = prob(r->bulb_confidence),
           pconf = prob(r->phase_confidence);
    double rconf = isnan(r->runner_confidence) ? NAN : prob(r->runner_confidence);
    if (conf < 0 || bconf < 0 || pconf < 0 || rconf < 0 ||
        (isfinite(r->p_value) && (r->p_value < 0.0 || r->p_value > 1.0)))
        return gs_fail(GS_EINVAL, "%s: light %d: confidence %g, bulb %g, phase %g, runner %g, "
                       "p_value %g: expected probabilities in [0, 1]", db->path, r->index,
                       r->confidence, r->bulb_confidence, r->phase_confidence, r->runner_confidence,
                       r->p_value);
    gs_tech t;
    if (r->technology && *r->technology && gs_tech_parse(r->technology, &t) != GS_OK)
        return gs_fail(GS_EINVAL, "%s: light %d: technology '%s': expected a gs_tech_name() such "
                       "as 'sodium_hp' or 'led_linear'", db->path, r->index, r->technology);
    if ((r->bulb_id && strlen(r->bulb_id) >= GS_ID_MAX) ||
        (r->runner_bulb_id && strlen(r->runner_bulb_id) >= GS_ID_MAX))
        return gs_fail(GS_EINVAL, "%s: light %d: bulb id longer than %d bytes", db->path, r->index,
                       GS_ID_MAX - 1);
    sqlite3_stmt *q;
    if ((s = stmt(db, ST_ADD_LIGHT, &q)) != GS_OK) return s;
    sqlite3_bind_int64(q, 1, capture_id);
    sqlite3_bind_int(q, 2, r->index);
    sqlite3_bind_double(q, 3, r->x_px);
    sqlite3_bind_double(q, 4, r->y_px);
    bind_int_or_null(q, 5, r->area_px, -1);
    bind_real(q, 6, r->peak_dn);
    bind_int_or_null(q, 7, r->saturated_px, -1);
    sqlite3_bind_int64(q, 8, r->blob_flags);
    bind_real(q, 9, r->brightness);
    bind_real(q, 10, r->snr);
    bind_real(q, 11, r->chi2);
    bind_int_or_null(q, 12, r->dof, -1);
    bind_real(q, 13, r->p_value);
    bind_text(q, 14, r->bulb_id);
    bind_text(q, 15, r->technology);
    bind_real(q, 16, isfinite(r->phase_deg) ? wrap360(r->phase_deg) : NAN);
    bind_real(q, 17, isfinite(r->phase_fit_deg) ? wrap360(r->phase_fit_deg) : NAN);
    bind_real(q, 18, r->phase_sigma_deg);
    sqlite3_bind_double(q, 19, conf);
    sqlite3_bind_double(q, 20, bconf);
    sqlite3_bind_double(q, 21, pconf);
    bind_text(q, 22, r->runner_bulb_id);
    bind_real(q, 23, isfinite(r->runner_phase_deg) ? wrap360(r->runner_phase_deg) : NAN);
    bind_real(q, 24, rconf);
    sqlite3_bind_int64(q, 25, r->match_flags);
    int inserted = 0;
    if ((s = step_returning(db, q, light_id, &inserted, "inserting a light")) != GS_OK || inserted)
        return s;
    if ((s = stmt(db, ST_GET_LIGHT, &q)) != GS_OK) return s;
    sqlite3_bind_int64(q, 1, capture_id);
    sqlite3_bind_int(q, 2, r->index);
    return step_id(db, q, light_id, "looking up a light");
}

gs_status srv_db_insert_location(srv_db *db, int64_t light_id, const srv_location_row *r)
{
    static const char *const method[] = {"", "one_station", "triangulated", "truth"};
    if (!db || !r) return gs_fail(GS_EINVAL, "srv_db_insert_location: NULL argument");
    gs_status s = need_txn(db, "inserting a location");
    if (s != GS_OK) return s;
    if (r->method < SRV_LOC_ONE_STATION || r->method > SRV_LOC_TRUTH)
        return gs_fail(GS_EINVAL, "%s: location of light %lld: method %d: expected one_station, "
                       "triangulated or truth", db->path, (long long)light_id, (int)r->method);
    int has_lat = isfinite(r->lat_deg), has_lon = isfinite(r->lon_deg);
    if (has_lat != has_lon || (has_lat && fabs(r->lat_deg) > 90.0))
        return gs_fail(GS_EINVAL, "%s: location of light %lld: (%g, %g): expected a latitude in "
                       "[-90, 90] and a finite longitude, or both NaN (not located)", db->path,
                       (long long)light_id, r->lat_deg, r->lon_deg);
    sqlite3_stmt *q;
    if ((s = stmt(db, ST_ADD_LOCATION, &q)) != GS_OK) return s;
    sqlite3_bind_int64(q, 1, light_id);
    sqlite3_bind_text(q, 2, method[r->method], -1, SQLITE_STATIC);
    bind_real(q, 3, r->lat_deg);
    bind_real(q, 4, has_lon ? wrap180(r->lon_deg) : NAN);
    bind_real(q, 5, r->height_m);
    bind_real(q, 6, r->ellipse.semi_major_m);
    bind_real(q, 7, r->ellipse.semi_minor_m);
    bind_real(q, 8, r->ellipse.azimuth_deg);
    bind_real(q, 9, r->range_m);
    sqlite3_bind_int64(q, 10, r->flags);
    return step_done(db, q, "inserting a location");
}

gs_status srv_db_insert_frequency(srv_db *db, int64_t capture_id, int seq, const srv_freq_row *r)
{
    if (!db || !r) return gs_fail(GS_EINVAL, "srv_db_insert_frequency: NULL argument");
    gs_status s = need_txn(db, "inserting a frequency row");
    if (s != GS_OK) return s;
    if (seq < 0 || !isfinite(r->t_s) || !(r->window_s > 0.0) || !isfinite(r->window_s) ||
        !(r->frequency_hz > 0.0) || !isfinite(r->frequency_hz))
        return gs_fail(GS_EINVAL, "%s: frequency row %d: t_s %g, window_s %g, frequency_hz %g: "
                       "expected finite t, window > 0, frequency > 0", db->path, seq, r->t_s,
                       r->window_s, r->frequency_hz);
    sqlite3_stmt *q;
    if ((s = stmt(db, ST_ADD_FREQ, &q)) != GS_OK) return s;
    sqlite3_bind_int64(q, 1, capture_id);
    sqlite3_bind_int(q, 2, seq);
    sqlite3_bind_double(q, 3, r->t_s);
    sqlite3_bind_double(q, 4, r->window_s);
    sqlite3_bind_double(q, 5, r->frequency_hz);
    bind_real(q, 6, r->sigma_hz);
    return step_done(db, q, "inserting a frequency row");
}

/* ------------------------------------------------------------------ one capture, atomically */

static gs_status capture_rows(srv_db *db, const srv_capture_data *c, int64_t cid)
{
    gs_status s = GS_OK;
    for (size_t i = 0; i < c->n_frames && s == GS_OK; i++) s = srv_db_insert_frame(db, cid, &c->frames[i]);
    for (size_t i = 0; i < c->n_lights && s == GS_OK; i++) {
        int64_t lid = 0;
        s = srv_db_insert_light(db, cid, &c->lights[i], &lid);
        if (s == GS_OK && c->locations && c->locations[i].method != SRV_LOC_NONE)
            s = srv_db_insert_location(db, lid, &c->locations[i]);
    }
    for (size_t i = 0; i < c->n_frequency && s == GS_OK; i++) {
        if (i > (size_t)INT32_MAX) return gs_fail(GS_ELIMIT, "%s: too many frequency rows", db->path);
        s = srv_db_insert_frequency(db, cid, (int)i, &c->frequency[i]);
    }
    return s;
}

gs_status srv_db_add_capture(srv_db *db, const srv_capture_data *c, int64_t *capture_id,
                             int *skipped)
{
    if (!db || !c) return gs_fail(GS_EINVAL, "srv_db_add_capture: NULL argument");
    if ((c->n_frames && !c->frames) || (c->n_lights && !c->lights) ||
        (c->n_frequency && !c->frequency))
        return gs_fail(GS_EINVAL, "%s: capture %s: NULL array with a non-zero count", db->path,
                       c->capture.key ? c->capture.key : "");
    if (skipped) *skipped = 0;
    gs_status s = writable(db);
    if (s != GS_OK) return s;
    int own = !db->in_txn;
    if (own) s = srv_db_begin(db);
    else s = exec(db, "SAVEPOINT srv_capture", "savepoint");
    if (s != GS_OK) return s;
    db->in_txn = 1;
    int done = 0;
    int64_t cid = 0;
    s = srv_db_capture_done(db, c->capture.survey_id, c->capture.key ? c->capture.key : "", &done);
    if (s == GS_OK && done) {
        if (skipped) *skipped = 1;
        sqlite3_stmt *q;
        if ((s = stmt(db, ST_GET_CAPTURE, &q)) == GS_OK) {
            sqlite3_bind_int64(q, 1, c->capture.survey_id);
            sqlite3_bind_text(q, 2, c->capture.key, -1, SQLITE_STATIC);
            s = step_id(db, q, &cid, "looking up a capture");
        }
    } else if (s == GS_OK) {
        s = srv_db_insert_capture(db, &c->capture, c->n_lights, c->n_frames, c->n_frequency, &cid);
        if (s == GS_OK) s = capture_rows(db, c, cid);
    }
    if (s == GS_OK) {
        s = own ? srv_db_commit(db) : exec(db, "RELEASE srv_capture", "release");
        if (s == GS_OK && capture_id) *capture_id = cid;
        return s;
    }
    char msg[512];
    snprintf(msg, sizeof msg, "%s", gs_detail());
    if (own) {
        srv_db_rollback(db);
    } else if (!sqlite3_get_autocommit(db->db)) {
        sqlite3_exec(db->db, "ROLLBACK TO srv_capture; RELEASE srv_capture", NULL, NULL, NULL);
    } else {
        db->in_txn = 0;   /* SQLite rolled the whole transaction back (e.g. disk full) */
    }
    return gs_fail(s, "%s", msg);
}

gs_status srv_db_delete_capture(srv_db *db, int64_t survey_id, const char *key, int *deleted)
{
    if (!db || !key) return gs_fail(GS_EINVAL, "srv_db_delete_capture: NULL argument");
    int began;
    gs_status s = auto_begin(db, &began);
    if (s != GS_OK) return s;
    sqlite3_stmt *q;
    if ((s = stmt(db, ST_DEL_CAPTURE, &q)) == GS_OK) {
        sqlite3_bind_int64(q, 1, survey_id);
        sqlite3_bind_text(q, 2, key, -1, SQLITE_STATIC);
        s = step_done(db, q, "deleting a capture");
        if (s == GS_OK && deleted) *deleted = sqlite3_changes(db->db) > 0;
    }
    return auto_end(db, began, s);
}

/* ------------------------------------------------------------------ consistency check */

static gs_status count(srv_db *db, const char *sql, long *v)
{
    sqlite3_stmt *q = NULL;
    if (sqlite3_prepare_v2(db->db, sql, -1, &q, NULL) != SQLITE_OK) return db_fail(db, "check");
    int rc = sqlite3_step(q);
    *v = rc == SQLITE_ROW ? (long)sqlite3_column_int64(q, 0) : 0;
    sqlite3_finalize(q);
    if (rc != SQLITE_ROW && rc != SQLITE_DONE) return db_fail(db, "check");
    return GS_OK;
}

gs_status srv_db_check(srv_db *db, srv_db_report *r)
{
    if (!db || !r) return gs_fail(GS_EINVAL, "srv_db_check: NULL argument");
    memset(r, 0, sizeof *r);
    sqlite3_stmt *q = NULL;
    if (sqlite3_prepare_v2(db->db, "PRAGMA integrity_check", -1, &q, NULL) != SQLITE_OK)
        return db_fail(db, "integrity_check");
    int rc = sqlite3_step(q);
    const char *res = rc == SQLITE_ROW ? (const char *)sqlite3_column_text(q, 0) : NULL;
    r->integrity_ok = res && !strcmp(res, "ok");
    sqlite3_finalize(q);
    if (sqlite3_prepare_v2(db->db, "SELECT rtreecheck('locations_rtree')", -1, &q, NULL) != SQLITE_OK)
        return db_fail(db, "rtreecheck");
    rc = sqlite3_step(q);
    res = rc == SQLITE_ROW ? (const char *)sqlite3_column_text(q, 0) : NULL;
    if (!res || strcmp(res, "ok")) r->integrity_ok = 0;
    sqlite3_finalize(q);
    long a = 0, b = 0;
    gs_status s;
    if ((s = count(db, "SELECT count(*) FROM pragma_foreign_key_check", &r->fk_violations)) != GS_OK ||
        (s = count(db, "SELECT count(*) FROM locations_rtree", &r->rtree_rows)) != GS_OK ||
        (s = count(db, "SELECT count(*) FROM locations WHERE lat_deg IS NOT NULL", &r->located)) != GS_OK ||
        (s = count(db, "SELECT count(*) FROM locations l WHERE l.lat_deg IS NOT NULL AND NOT EXISTS "
                       "(SELECT 1 FROM locations_rtree r WHERE r.id = l.light_id AND r.min_lon <= "
                       "l.lon_deg AND r.max_lon >= l.lon_deg AND r.min_lat <= l.lat_deg AND "
                       "r.max_lat >= l.lat_deg)", &a)) != GS_OK ||
        (s = count(db, "SELECT count(*) FROM locations_rtree r WHERE NOT EXISTS (SELECT 1 FROM "
                       "locations l WHERE l.light_id = r.id AND l.lat_deg IS NOT NULL)", &b)) != GS_OK ||
        (s = count(db, "SELECT count(*) FROM captures c WHERE light_count != (SELECT count(*) FROM "
                       "lights WHERE capture_id = c.id) OR frame_count != (SELECT count(*) FROM "
                       "frames WHERE capture_id = c.id) OR frequency_count != (SELECT count(*) "
                       "FROM grid_frequency WHERE capture_id = c.id)", &r->incomplete_captures)) != GS_OK ||
        (s = count(db, "SELECT count(*) FROM surveys", &r->surveys)) != GS_OK ||
        (s = count(db, "SELECT count(*) FROM captures", &r->captures)) != GS_OK ||
        (s = count(db, "SELECT count(*) FROM lights", &r->lights)) != GS_OK ||
        (s = count(db, "SELECT count(*) FROM locations", &r->locations)) != GS_OK ||
        (s = count(db, "SELECT count(*) FROM grid_frequency", &r->frequency_rows)) != GS_OK)
        return s;
    r->rtree_mismatch = a + b;
    return GS_OK;
}

int srv_db_report_ok(const srv_db_report *r)
{
    return r && r->integrity_ok && r->fk_violations == 0 && r->rtree_rows == r->located &&
           r->rtree_mismatch == 0 && r->incomplete_captures == 0;
}
