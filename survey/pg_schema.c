/* pg_schema.c - the shared PostGIS survey database (docs/postgis.md): the connection, its
 * versioned schema "gridsurvey" (one migration per version, applied in order under an advisory
 * lock, each in its own transaction with its migrations row) and the helpers of pg_push.c and
 * pg_stats.c. The tables mirror the SQLite schema (db_schema.c, docs/survey-db.md) with stable
 * identities for the rows that several stations push: a survey by its name, a capture by
 * (survey, capture_key), a light by (capture, light_index), a light site by its founding
 * detection (the site's detection of lowest id in the file that pushed it). */
#include "survey/internal.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Version 1: the tables. Positions are also PostGIS points (SRID 4326, x = lon, y = lat),
 * generated from lat_deg/lon_deg, with GiST indexes, so QGIS reads the layers directly. */
static const char *const pg_migration_1[] = {
    "CREATE EXTENSION IF NOT EXISTS postgis SCHEMA public;\n"
    "CREATE TABLE meta(key text PRIMARY KEY, value text NOT NULL);\n"
    "INSERT INTO meta VALUES ('format', '" SRV_PG_FORMAT "');\n"
    "CREATE TABLE delight_versions(\n"
    "  id bigserial PRIMARY KEY, sha256 text NOT NULL CHECK (length(sha256) = 64),\n"
    "  generator text NOT NULL, source text NOT NULL, bulbs integer NOT NULL CHECK (bulbs >= 0),\n"
    "  added_utc text NOT NULL, UNIQUE (sha256, generator));\n"
    "CREATE TABLE surveys(\n"
    "  id bigserial PRIMARY KEY,\n"
    "  name text NOT NULL UNIQUE CHECK (length(name) BETWEEN 1 AND 63),\n"
    "  city text, grid_hz integer CHECK (grid_hz IN (50, 60)), started_utc text, notes text,\n"
    "  created_utc text NOT NULL);\n"
    "CREATE TABLE stations(\n"
    "  id bigserial PRIMARY KEY,\n"
    "  survey_id bigint NOT NULL REFERENCES surveys(id) ON DELETE CASCADE, name text NOT NULL,\n"
    "  lat_deg float8 CHECK (lat_deg BETWEEN -90 AND 90), lon_deg float8, height_m float8,\n"
    "  heading_deg float8, pitch_deg float8, roll_deg float8, sigma_heading_deg float8,\n"
    "  sigma_pitch_deg float8, sigma_roll_deg float8, focal_px float8, cx_px float8, cy_px float8,\n"
    "  k1 float8, k2 float8, width_px integer, height_px integer, refraction_k float8,\n"
    "  sigma_px float8, time_utc text,\n"
    "  geom geometry(Point, 4326) GENERATED ALWAYS AS\n"
    "    (ST_SetSRID(ST_MakePoint(lon_deg, lat_deg), 4326)) STORED,\n"
    "  UNIQUE (survey_id, name));\n"
    "CREATE TABLE captures(\n"
    "  id bigserial PRIMARY KEY,\n"
    "  survey_id bigint NOT NULL REFERENCES surveys(id) ON DELETE CASCADE,\n"
    "  station_id bigint REFERENCES stations(id) ON DELETE SET NULL,\n"
    "  delight_id bigint REFERENCES delight_versions(id),\n"
    "  capture_key text NOT NULL CHECK (length(capture_key) > 0), path text, utc text,\n"
    "  grid_hz integer CHECK (grid_hz IN (50, 60)), K integer CHECK (K >= 2),\n"
    "  bands integer CHECK (bands IN (1, 3)), width_px integer, height_px integer,\n"
    "  locked integer CHECK (locked IN (0, 1)), mean_frequency_hz float8, sigma_frequency_hz float8,\n"
    "  light_count integer NOT NULL, frame_count integer NOT NULL, frequency_count integer NOT NULL,\n"
    "  ingested_utc text NOT NULL, pushed_utc text NOT NULL DEFAULT\n"
    "    to_char(now() AT TIME ZONE 'UTC', 'YYYY-MM-DD\"T\"HH24:MI:SS\"Z\"'),\n"
    "  UNIQUE (survey_id, capture_key));\n"
    "CREATE INDEX captures_station ON captures(station_id);\n"
    "CREATE TABLE frames(\n"
    "  capture_id bigint NOT NULL REFERENCES captures(id) ON DELETE CASCADE,\n"
    "  k integer NOT NULL CHECK (k >= 0), file text, cycles float8, hdr_map text,\n"
    "  PRIMARY KEY (capture_id, k));\n"
    "CREATE TABLE grid_frequency(\n"
    "  capture_id bigint NOT NULL REFERENCES captures(id) ON DELETE CASCADE,\n"
    "  seq integer NOT NULL CHECK (seq >= 0), t_s float8 NOT NULL,\n"
    "  window_s float8 NOT NULL CHECK (window_s > 0),\n"
    "  frequency_hz float8 NOT NULL CHECK (frequency_hz > 0), sigma_hz float8,\n"
    "  PRIMARY KEY (capture_id, seq));\n"
    ,
    "CREATE TABLE lights(\n"
    "  id bigserial PRIMARY KEY,\n"
    "  capture_id bigint NOT NULL REFERENCES captures(id) ON DELETE CASCADE,\n"
    "  light_index integer NOT NULL CHECK (light_index >= 0),\n"
    "  x_px float8 NOT NULL, y_px float8 NOT NULL, area_px integer, peak_dn float8,\n"
    "  saturated_px integer, blob_flags integer NOT NULL DEFAULT 0, brightness float8, snr float8,\n"
    "  chi2 float8, dof integer, p_value float8 CHECK (p_value BETWEEN 0 AND 1),\n"
    "  bulb_id text, technology text,\n"
    "  phase_deg float8 CHECK (phase_deg >= 0 AND phase_deg < 360),\n"
    "  phase_fit_deg float8 CHECK (phase_fit_deg >= 0 AND phase_fit_deg < 360),\n"
    "  phase_sigma_deg float8,\n"
    "  confidence float8 NOT NULL CHECK (confidence BETWEEN 0 AND 1),\n"
    "  bulb_confidence float8 NOT NULL CHECK (bulb_confidence BETWEEN 0 AND 1),\n"
    "  phase_confidence float8 NOT NULL CHECK (phase_confidence BETWEEN 0 AND 1),\n"
    "  runner_bulb_id text, runner_phase_deg float8,\n"
    "  runner_confidence float8 CHECK (runner_confidence BETWEEN 0 AND 1),\n"
    "  match_flags integer NOT NULL DEFAULT 0,\n"
    "  UNIQUE (capture_id, light_index));\n"
    "CREATE INDEX lights_technology ON lights(technology);\n"
    "CREATE TABLE locations(\n"
    "  capture_id bigint NOT NULL, light_index integer NOT NULL,\n"
    "  method text NOT NULL CHECK (method IN ('one_station', 'triangulated', 'truth')),\n"
    "  lat_deg float8 CHECK (lat_deg BETWEEN -90 AND 90),\n"
    "  lon_deg float8 CHECK (lon_deg >= -180 AND lon_deg < 180),\n"
    "  height_m float8, semi_major_m float8, semi_minor_m float8, azimuth_deg float8, range_m float8,\n"
    "  flags integer NOT NULL DEFAULT 0,\n"
    "  geom geometry(Point, 4326) GENERATED ALWAYS AS\n"
    "    (ST_SetSRID(ST_MakePoint(lon_deg, lat_deg), 4326)) STORED,\n"
    "  PRIMARY KEY (capture_id, light_index),\n"
    "  FOREIGN KEY (capture_id, light_index) REFERENCES lights(capture_id, light_index)\n"
    "    ON DELETE CASCADE,\n"
    "  CHECK ((lat_deg IS NULL) = (lon_deg IS NULL)));\n"
    "CREATE INDEX locations_geom ON locations USING gist(geom);\n"
    ,
    "CREATE TABLE light_sites(\n"
    "  id bigserial PRIMARY KEY,\n"
    "  origin_capture_id bigint NOT NULL, origin_light_index integer NOT NULL,\n"
    "  lat_deg float8 CHECK (lat_deg BETWEEN -90 AND 90),\n"
    "  lon_deg float8 CHECK (lon_deg >= -180 AND lon_deg < 180),\n"
    "  height_m float8, semi_major_m float8, semi_minor_m float8, azimuth_deg float8,\n"
    "  pose_key text, x_px float8, y_px float8,\n"
    "  detections integer NOT NULL, captures integer NOT NULL, bulb_id text, technology text,\n"
    "  phase_deg float8 CHECK (phase_deg >= 0 AND phase_deg < 360), phase_sigma_deg float8,\n"
    "  confidence float8 CHECK (confidence BETWEEN 0 AND 1),\n"
    "  bulb_confidence float8 CHECK (bulb_confidence BETWEEN 0 AND 1),\n"
    "  phase_confidence float8 CHECK (phase_confidence BETWEEN 0 AND 1),\n"
    "  geom geometry(Point, 4326) GENERATED ALWAYS AS\n"
    "    (ST_SetSRID(ST_MakePoint(lon_deg, lat_deg), 4326)) STORED,\n"
    "  UNIQUE (origin_capture_id, origin_light_index),\n"
    "  FOREIGN KEY (origin_capture_id, origin_light_index)\n"
    "    REFERENCES lights(capture_id, light_index) ON DELETE CASCADE,\n"
    "  CHECK ((lat_deg IS NULL) = (lon_deg IS NULL)));\n"
    "CREATE INDEX light_sites_geom ON light_sites USING gist(geom);\n"
    "CREATE TABLE site_detections(\n"
    "  capture_id bigint NOT NULL, light_index integer NOT NULL,\n"
    "  site_id bigint NOT NULL REFERENCES light_sites(id) ON DELETE CASCADE, d2 float8,\n"
    "  PRIMARY KEY (capture_id, light_index),\n"
    "  FOREIGN KEY (capture_id, light_index) REFERENCES lights(capture_id, light_index)\n"
    "    ON DELETE CASCADE);\n"
    "CREATE INDEX site_detections_site ON site_detections(site_id);\n"
    /* a utility's areas (e.g. feeder polygons), per layer in the order of their file */
    "CREATE TABLE areas(\n"
    "  layer text NOT NULL, ord integer NOT NULL CHECK (ord >= 0), label text NOT NULL,\n"
    "  geom geometry(MultiPolygon, 4326) NOT NULL, PRIMARY KEY (layer, ord));\n"
    "CREATE INDEX areas_geom ON areas USING gist(geom);\n",
    NULL};

/* Version 2: the statistics views. The phase classes, the Wilson interval (z = SRV_Z95, with
 * the clamps of srv_wilson), chi2 and p = exp(-chi2 / 2) and the imbalance are those of
 * stats.c, in the same operation order. */
/* The per-phase counts of a view over rows with a phase_class (phase_class()), one line each. */
#define PG_PHASE_COUNTS \
    "       count(*) FILTER (WHERE phase_class = 'unknown') AS unknown,\n" \
    "       count(*) FILTER (WHERE phase_class = 'other') AS other,\n" \
    "       count(*) FILTER (WHERE phase_class = '0') AS n0,\n" \
    "       count(*) FILTER (WHERE phase_class = '120') AS n120,\n" \
    "       count(*) FILTER (WHERE phase_class = '240') AS n240,\n" \
    "       count(*) FILTER (WHERE phase_class IN ('0', '120', '240')) AS n\n"
#define PG_Z95 "1.959963984540054"
static const char *const pg_migration_2[] = {
    "CREATE FUNCTION phase_class(p float8) RETURNS text LANGUAGE sql IMMUTABLE AS $$\n"
    "  SELECT CASE WHEN p IS NULL THEN 'unknown' WHEN p <= 20 OR p >= 340 THEN '0'\n"
    "              WHEN p BETWEEN 100 AND 140 THEN '120' WHEN p BETWEEN 220 AND 260 THEN '240'\n"
    "              ELSE 'other' END $$;\n"
    "CREATE FUNCTION wilson(k bigint, n bigint, OUT share float8, OUT lo float8, OUT hi float8)\n"
    "  LANGUAGE sql IMMUTABLE AS $$\n"
    "  SELECT p, CASE WHEN k = 0 OR c - h < 0 THEN 0 ELSE c - h END,\n"
    "         CASE WHEN k = n OR c + h > 1 THEN 1 ELSE c + h END\n"
    "  FROM (SELECT p, (p + z2 / (2.0::float8 * nn)) / (1.0::float8 + z2 / nn) AS c,\n"
    "               z / (1.0::float8 + z2 / nn) * sqrt(p * (1.0::float8 - p) / nn\n"
    "                                            + z2 / (4.0::float8 * nn * nn)) AS h\n"
    "        FROM (SELECT k::float8 / n::float8 AS p, n::float8 AS nn, " PG_Z95 "::float8 AS z,\n"
    "                     " PG_Z95 "::float8 * " PG_Z95 "::float8 AS z2 WHERE n > 0) a) b $$;\n"
    /* gs_wrap180 */
    "CREATE FUNCTION wrap180(a float8) RETURNS float8 LANGUAGE sql IMMUTABLE AS $$\n"
    "  SELECT CASE WHEN r >= 360 THEN 0 ELSE r END - 180\n"
    "  FROM (SELECT (a + 180) - 360 * floor((a + 180) / 360) AS r) x $$;\n"
    "CREATE FUNCTION balance(n0 bigint, n120 bigint, n240 bigint,\n"
    "  OUT share0 float8, OUT lo0 float8, OUT hi0 float8, OUT share120 float8, OUT lo120 float8,\n"
    "  OUT hi120 float8, OUT share240 float8, OUT lo240 float8, OUT hi240 float8,\n"
    "  OUT chi2 float8, OUT p_value float8, OUT imbalance float8)\n"
    "  LANGUAGE sql IMMUTABLE AS $$\n"
    "  SELECT w0.share, w0.lo, w0.hi, w1.share, w1.lo, w1.hi, w2.share, w2.lo, w2.hi, x.chi2,\n"
    "         exp(-x.chi2 / 2), 3 * greatest(abs(w0.share - 1.0::float8 / 3), abs(w1.share - 1.0::float8 / 3),\n"
    "                                       abs(w2.share - 1.0::float8 / 3))\n"
    "  FROM (SELECT n0 + n120 + n240 AS n) t\n"
    "  CROSS JOIN LATERAL (SELECT CASE WHEN t.n > 0 THEN (n0 - t.n / 3.0::float8) * (n0 - t.n / 3.0::float8)\n"
    "      / (t.n / 3.0::float8) + (n120 - t.n / 3.0::float8) * (n120 - t.n / 3.0::float8) / (t.n / 3.0::float8)\n"
    "      + (n240 - t.n / 3.0::float8) * (n240 - t.n / 3.0::float8) / (t.n / 3.0::float8) END AS chi2) x\n"
    "  LEFT JOIN LATERAL gridsurvey.wilson(n0, t.n) w0 ON true\n"
    "  LEFT JOIN LATERAL gridsurvey.wilson(n120, t.n) w1 ON true\n"
    "  LEFT JOIN LATERAL gridsurvey.wilson(n240, t.n) w2 ON true $$;\n"
    ,
    /* detections (like the SQLite views) */
    "CREATE VIEW light_phase AS\n"
    "SELECT l.id AS light_id, s.id AS survey_id, s.name AS survey, c.capture_key,\n"
    "       coalesce(l.technology, 'none') AS technology, l.bulb_id, l.phase_deg,\n"
    "       phase_class(l.phase_deg) AS phase_class, l.confidence, l.phase_confidence,\n"
    "       loc.lat_deg, loc.lon_deg, loc.geom\n"
    "FROM lights l JOIN captures c ON c.id = l.capture_id JOIN surveys s ON s.id = c.survey_id\n"
    "LEFT JOIN locations loc ON loc.capture_id = l.capture_id AND loc.light_index = l.light_index;\n"
    "CREATE VIEW phase_counts AS\n"
    "SELECT CASE WHEN GROUPING(survey) = 0 THEN 'survey' WHEN GROUPING(technology) = 0\n"
    "            THEN 'technology' ELSE 'all' END AS grouping,\n"
    "       coalesce(survey, technology, 'all') AS grp, count(*) AS lights,\n"
    PG_PHASE_COUNTS
    "FROM light_phase GROUP BY GROUPING SETS ((), (survey), (technology));\n"
    "CREATE VIEW phase_balance AS\n"
    "SELECT c.*, b.* FROM phase_counts c CROSS JOIN LATERAL balance(c.n0, c.n120, c.n240) b;\n"
    /* light sites (like gridsurvey stats: every survey, no threshold) */
    "CREATE VIEW site_phase AS\n"
    "SELECT id AS site_id, coalesce(technology, 'none') AS technology, bulb_id, phase_deg,\n"
    "       phase_class(phase_deg) AS phase_class, phase_sigma_deg, confidence, bulb_confidence,\n"
    "       phase_confidence, detections, captures, lat_deg, lon_deg, semi_major_m, semi_minor_m,\n"
    "       azimuth_deg, geom\n"
    "FROM light_sites;\n"
    ,
    "CREATE VIEW site_counts AS\n"
    "SELECT CASE WHEN GROUPING(technology) = 0 THEN 'technology' ELSE 'all' END AS grouping,\n"
    "       coalesce(technology, 'all') AS grp, count(*) AS lights,\n"
    PG_PHASE_COUNTS
    "FROM site_phase GROUP BY GROUPING SETS ((), (technology));\n"
    "CREATE VIEW site_balance AS\n"
    "SELECT c.*, b.* FROM site_counts c CROSS JOIN LATERAL balance(c.n0, c.n120, c.n240) b;\n"
    /* each located site in the first area (in file order) of each layer that covers it, the
     * rule of --clip (boundary included) */
    "CREATE VIEW area_sites AS\n"
    "SELECT DISTINCT ON (a.layer, s.site_id) a.layer, a.label, a.ord, s.*\n"
    "FROM site_phase s JOIN areas a ON ST_Covers(a.geom, s.geom)\n"
    "ORDER BY a.layer, s.site_id, a.ord;\n"
    "CREATE VIEW area_balance AS\n"
    "SELECT c.*, b.* FROM (\n"
    "  SELECT layer, label, count(*) AS lights,\n"
    PG_PHASE_COUNTS
    "  FROM area_sites GROUP BY layer, label) c\n"
    "CROSS JOIN LATERAL balance(c.n0, c.n120, c.n240) b;\n"
    /* the same with each area's outline, for a map (QGIS: style by imbalance or p_value) */
    "CREATE VIEW area_balance_map AS\n"
    "SELECT b.layer || ':' || b.label AS area_id, b.*, g.geom\n"
    "FROM area_balance b JOIN (SELECT layer, label,\n"
    "  ST_Multi(ST_Union(geom))::geometry(MultiPolygon, 4326) AS geom FROM areas\n"
    "  GROUP BY layer, label) g USING (layer, label);\n"
    ,
    /* cells of size_m metres on the local grid of stats.c (around the located sites' mean
     * latitude and circular-mean longitude) */
    "CREATE FUNCTION site_balance_cells(size_m float8) RETURNS TABLE(\n"
    "  ix bigint, iy bigint, lat_deg float8, lon_deg float8, lights bigint, unknown bigint,\n"
    "  other bigint, n0 bigint, n120 bigint, n240 bigint, n bigint, share0 float8, lo0 float8,\n"
    "  hi0 float8, share120 float8, lo120 float8, hi120 float8, share240 float8, lo240 float8,\n"
    "  hi240 float8, chi2 float8, p_value float8, imbalance float8)\n"
    "LANGUAGE sql STABLE AS $$\n"
    "WITH located AS (SELECT * FROM gridsurvey.site_phase WHERE lat_deg IS NOT NULL),\n"
    "centre AS (SELECT avg(lat_deg) AS lat0, degrees(atan2(sum(sin(radians(lon_deg))),\n"
    "                  sum(cos(radians(lon_deg))))) AS lon0 FROM located),\n"
    "k AS (SELECT lat0, lon0, 6371008.8 * cos(lat0 * (pi() / 180)) * (pi() / 180) AS kx,\n"
    "             6371008.8 * (pi() / 180) AS ky FROM centre),\n"
    "cells AS (SELECT floor(k.kx * gridsurvey.wrap180(s.lon_deg - k.lon0) / size_m)::bigint AS ix,\n"
    "                 floor(k.ky * (s.lat_deg - k.lat0) / size_m)::bigint AS iy, s.phase_class\n"
    "          FROM located s CROSS JOIN k),\n"
    "c AS (SELECT ix, iy, count(*) AS lights,\n"
    PG_PHASE_COUNTS
    "       FROM cells GROUP BY ix, iy)\n"
    "SELECT c.ix, c.iy, k.lat0 + (c.iy + 0.5::float8) * size_m / k.ky,\n"
    "       gridsurvey.wrap180(k.lon0 + (c.ix + 0.5::float8) * size_m / k.kx),\n"
    "       c.lights, c.unknown, c.other, c.n0, c.n120, c.n240, c.n, b.*\n"
    "FROM c CROSS JOIN k CROSS JOIN LATERAL gridsurvey.balance(c.n0, c.n120, c.n240) b\n"
    "ORDER BY c.iy, c.ix $$;\n",
    NULL};

/* Version 3: the SQLite schema's version 5, captures.candidate_bulbs (NULL for captures pushed
 * before, like the SQLite rows stored before). */
static const char *const pg_migration_3[] = {
    "ALTER TABLE captures ADD COLUMN candidate_bulbs integer CHECK (candidate_bulbs > 0);\n",
    NULL};

static const struct {
    const char *name;
    const char *const *sql;
} pg_migrations[SRV_PG_SCHEMA_VERSION] = {
    {"tables", pg_migration_1},
    {"statistics views", pg_migration_2},
    {"candidate bulbs of each capture", pg_migration_3},
};

/* ------------------------------------------------------------------ helpers */

gs_status srv_pgi_fail(PGconn *c, const PGresult *r, const char *what)
{
    const char *m = r ? PQresultErrorMessage(r) : PQerrorMessage(c);
    size_t n = strlen(m);
    while (n && (m[n - 1] == '\n' || m[n - 1] == ' ')) n--;
    const char *nl = memchr(m, '\n', n);   /* the first line: libpq adds DETAIL/CONTEXT lines */
    return gs_fail(GS_ESQL, "PostgreSQL: %s: %.*s", what, (int)(nl ? (size_t)(nl - m) : n), m);
}

gs_status srv_pgi_exec(PGconn *c, const char *sql, const char *what)
{
    PGresult *r = PQexec(c, sql);
    ExecStatusType st = PQresultStatus(r);
    gs_status s = st == PGRES_COMMAND_OK || st == PGRES_TUPLES_OK ? GS_OK : srv_pgi_fail(c, r, what);
    PQclear(r);
    return s;
}

PGresult *srv_pgi_query(PGconn *c, const char *sql, int n, const char *const *params)
{
    return PQexecParams(c, sql, n, NULL, params, NULL, NULL, 0);
}

int srv_pgi_retryable(const PGresult *r)
{
    const char *state = r ? PQresultErrorField(r, PG_DIAG_SQLSTATE) : NULL;
    /* serialization failure, deadlock detected */
    return state && (!strcmp(state, "40001") || !strcmp(state, "40P01"));
}

static void quiet_notices(void *arg, const char *message)
{
    (void)arg;
    (void)message;
}

/* The schema's version (0: none yet); inside the migration transaction. */
static gs_status schema_version(PGconn *c, int *version)
{
    PGresult *r = PQexec(c, "SELECT coalesce(max(version), 0) FROM gridsurvey.migrations");
    if (PQresultStatus(r) != PGRES_TUPLES_OK) {
        gs_status s = srv_pgi_fail(c, r, "reading the schema version");
        PQclear(r);
        return s;
    }
    *version = atoi(PQgetvalue(r, 0, 0));
    PQclear(r);
    return GS_OK;
}

/* Apply the missing migrations, one transaction each, serialized between sessions by a
 * transaction-level advisory lock (two stations connecting at once never apply a step twice;
 * a failure leaves the previous version). */
static gs_status migrate(PGconn *c)
{
    for (;;) {
        gs_status s = srv_pgi_exec(c, "BEGIN", "BEGIN");
        if (s != GS_OK) return s;
        int v = 0;
        if ((s = srv_pgi_exec(c, "SELECT pg_advisory_xact_lock(" SRV_PG_LOCK_KEY ")", "locking the schema")) ||
            (s = srv_pgi_exec(c, "CREATE SCHEMA IF NOT EXISTS gridsurvey;\n"
                                 "CREATE TABLE IF NOT EXISTS gridsurvey.migrations(\n"
                                 "  version integer PRIMARY KEY, name text NOT NULL,\n"
                                 "  applied_utc text NOT NULL, generator text NOT NULL)",
                              "creating the schema")) ||
            (s = schema_version(c, &v)))
            goto fail;
        if (v > SRV_PG_SCHEMA_VERSION) {
            s = gs_fail(GS_EFORMAT, "PostgreSQL: schema gridsurvey is at version %d, newer than this "
                        "gridsurvey's %d: use a newer gridsurvey", v, SRV_PG_SCHEMA_VERSION);
            goto fail;
        }
        if (v == SRV_PG_SCHEMA_VERSION) return srv_pgi_exec(c, "COMMIT", "COMMIT");
        for (const char *const *p = pg_migrations[v].sql; *p; p++)
            if ((s = srv_pgi_exec(c, *p, pg_migrations[v].name)) != GS_OK) goto fail;
        char vs[16], utc[32];
        snprintf(vs, sizeof vs, "%d", v + 1);
        srv_dbi_utc_now(utc);
        const char *params[] = {vs, pg_migrations[v].name, utc, SRV_GENERATOR};
        PGresult *r = srv_pgi_query(c, "INSERT INTO gridsurvey.migrations VALUES ($1, $2, $3, $4)", 4, params);
        s = PQresultStatus(r) == PGRES_COMMAND_OK ? GS_OK : srv_pgi_fail(c, r, "recording a migration");
        PQclear(r);
        if (s != GS_OK || (s = srv_pgi_exec(c, "COMMIT", "COMMIT")) != GS_OK) goto fail;
        continue;
    fail:
        PQclear(PQexec(c, "ROLLBACK"));
        return s;
    }
}

/* A reader's check: the schema exists at this version. */
static gs_status check_version(PGconn *c)
{
    PGresult *r = PQexec(c, "SELECT to_regclass('gridsurvey.migrations') IS NOT NULL");
    int exists = PQresultStatus(r) == PGRES_TUPLES_OK && !strcmp(PQgetvalue(r, 0, 0), "t");
    gs_status s = PQresultStatus(r) == PGRES_TUPLES_OK ? GS_OK : srv_pgi_fail(c, r, "reading the schema");
    PQclear(r);
    if (s != GS_OK) return s;
    if (!exists)
        return gs_fail(GS_ENOTFOUND, "PostgreSQL: no schema gridsurvey in database '%s' (nothing "
                       "pushed yet: gridsurvey push --db FILE --pg CONNINFO)", PQdb(c));
    int v = 0;
    if ((s = schema_version(c, &v)) != GS_OK) return s;
    if (v != SRV_PG_SCHEMA_VERSION)
        return gs_fail(GS_EFORMAT, "PostgreSQL: schema gridsurvey is at version %d, expected %d (%s)",
                       v, SRV_PG_SCHEMA_VERSION, v < SRV_PG_SCHEMA_VERSION ?
                       "a push with this gridsurvey migrates it" : "use a newer gridsurvey");
    return GS_OK;
}

gs_status srv_pgi_connect(const char *conninfo, int writer, PGconn **out)
{
    *out = NULL;
    if (!conninfo) return gs_fail(GS_EINVAL, "--pg: expected a PostgreSQL connection string");
    PGconn *c = PQconnectdb(conninfo);
    if (!c) return gs_fail(GS_ENOMEM, "PostgreSQL: out of memory");
    if (PQstatus(c) != CONNECTION_OK) {
        gs_status s = srv_pgi_fail(c, NULL, "cannot connect");
        PQfinish(c);
        return s;
    }
    PQsetNoticeProcessor(c, quiet_notices, NULL);
    gs_status s = srv_pgi_exec(c, "SET search_path = gridsurvey, public", "setting the search path");
    if (s == GS_OK) s = writer ? migrate(c) : check_version(c);
    if (s != GS_OK) {
        PQfinish(c);
        return s;
    }
    *out = c;
    return GS_OK;
}
