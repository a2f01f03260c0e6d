/* db_schema.c - the survey database's schema (docs/survey-db.md): one migration per version,
 * in order (applied by db.c, each in its own transaction), and the SQL of the prepared
 * statements. */
#include "survey/internal.h"

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
/* The shares view over a counts view (grouping, grp, lights, unknown, other, n0, n120, n240,
 * n) and the balance view over it: Wilson bounds, chi2, p-value and imbalance. */
#define SHARES_BALANCE_SQL(counts, shares, balance) \
    "CREATE VIEW " shares " AS\n" \
    "SELECT *, 1.0 * n0 / n AS share0, 1.0 * n120 / n AS share120, 1.0 * n240 / n AS share240\n" \
    "FROM " counts ";\n" \
    "CREATE VIEW " balance " AS\n" \
    "SELECT grouping, grp, lights, unknown, other, n0, n120, n240, n,\n" \
    "  share0,\n" \
    "  (share0 + z2 / (2 * n) - z * sqrt(share0 * (1 - share0) / n + z2 / (4.0 * n * n))) / (1 + z2 / n) AS lo0,\n" \
    "  (share0 + z2 / (2 * n) + z * sqrt(share0 * (1 - share0) / n + z2 / (4.0 * n * n))) / (1 + z2 / n) AS hi0,\n" \
    "  share120,\n" \
    "  (share120 + z2 / (2 * n) - z * sqrt(share120 * (1 - share120) / n + z2 / (4.0 * n * n))) / (1 + z2 / n) AS lo120,\n" \
    "  (share120 + z2 / (2 * n) + z * sqrt(share120 * (1 - share120) / n + z2 / (4.0 * n * n))) / (1 + z2 / n) AS hi120,\n" \
    "  share240,\n" \
    "  (share240 + z2 / (2 * n) - z * sqrt(share240 * (1 - share240) / n + z2 / (4.0 * n * n))) / (1 + z2 / n) AS lo240,\n" \
    "  (share240 + z2 / (2 * n) + z * sqrt(share240 * (1 - share240) / n + z2 / (4.0 * n * n))) / (1 + z2 / n) AS hi240,\n" \
    "  chi2, exp(-chi2 / 2) AS p_value,\n" \
    "  3 * max(abs(share0 - 1.0 / 3), abs(share120 - 1.0 / 3), abs(share240 - 1.0 / 3)) AS imbalance\n" \
    "FROM (SELECT *, " Z95_SQL " AS z, " Z95_SQL " * " Z95_SQL " AS z2,\n" \
    "        CASE WHEN n > 0 THEN ((n0 - n / 3.0) * (n0 - n / 3.0) + (n120 - n / 3.0) * (n120 - n / 3.0)\n" \
    "                             + (n240 - n / 3.0) * (n240 - n / 3.0)) / (n / 3.0) END AS chi2\n" \
    "      FROM " shares ");\n"
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
    SHARES_BALANCE_SQL("phase_counts", "phase_shares", "phase_balance"),
    NULL};

/* Version 3: light identity (docs/survey-db.md, "Light sites"). A site is one physical light;
 * each stored light (a detection) belongs to one site (site_detections), at most one per
 * capture. survey/sites.c associates and keeps the combined columns; the R*Tree holds the
 * located sites' positions. Deleting detections marks their site stale (refreshed by the next
 * association) and removes a site left without any. */
static const char *const migration_3[] = {
    "CREATE TABLE light_sites(\n"
    "  id INTEGER PRIMARY KEY,\n"
    "  lat_deg REAL CHECK (lat_deg BETWEEN -90 AND 90),\n"
    "  lon_deg REAL CHECK (lon_deg >= -180 AND lon_deg < 180),\n"
    "  height_m REAL, semi_major_m REAL, semi_minor_m REAL, azimuth_deg REAL,\n"
    "  pose_key TEXT, x_px REAL, y_px REAL,\n"
    "  detections INTEGER NOT NULL DEFAULT 0, captures INTEGER NOT NULL DEFAULT 0,\n"
    "  bulb_id TEXT, technology TEXT,\n"
    "  phase_deg REAL CHECK (phase_deg >= 0 AND phase_deg < 360), phase_sigma_deg REAL,\n"
    "  confidence REAL CHECK (confidence BETWEEN 0 AND 1),\n"
    "  bulb_confidence REAL CHECK (bulb_confidence BETWEEN 0 AND 1),\n"
    "  phase_confidence REAL CHECK (phase_confidence BETWEEN 0 AND 1),\n"
    "  stale INTEGER NOT NULL DEFAULT 0 CHECK (stale IN (0, 1)),\n"
    "  CHECK ((lat_deg IS NULL) = (lon_deg IS NULL)));\n"
    "CREATE INDEX light_sites_pose ON light_sites(pose_key, x_px) WHERE pose_key IS NOT NULL;\n"
    "CREATE INDEX light_sites_major ON light_sites(semi_major_m) WHERE pose_key IS NULL;\n"
    "CREATE TABLE site_detections(\n"
    "  light_id INTEGER PRIMARY KEY REFERENCES lights(id) ON DELETE CASCADE,\n"
    "  site_id INTEGER NOT NULL REFERENCES light_sites(id) ON DELETE CASCADE,\n"
    "  capture_id INTEGER NOT NULL REFERENCES captures(id) ON DELETE CASCADE,\n"
    "  d2 REAL,\n"
    "  UNIQUE (site_id, capture_id));\n"
    "CREATE INDEX site_detections_capture ON site_detections(capture_id);\n"
    "CREATE VIRTUAL TABLE light_sites_rtree USING rtree(id, min_lon, max_lon, min_lat, max_lat);\n"
    "CREATE TRIGGER light_sites_rtree_insert AFTER INSERT ON light_sites\n"
    "  WHEN new.lat_deg IS NOT NULL AND new.pose_key IS NULL BEGIN\n"
    "  INSERT INTO light_sites_rtree VALUES (new.id, new.lon_deg, new.lon_deg, new.lat_deg,\n"
    "                                       new.lat_deg);\n"
    "END;\n"
    "CREATE TRIGGER light_sites_rtree_delete AFTER DELETE ON light_sites BEGIN\n"
    "  DELETE FROM light_sites_rtree WHERE id = old.id;\n"
    "END;\n"
    "CREATE TRIGGER light_sites_rtree_update AFTER UPDATE OF id, lat_deg, lon_deg, pose_key\n"
    "  ON light_sites BEGIN\n"
    "  DELETE FROM light_sites_rtree WHERE id = old.id;\n"
    "  INSERT INTO light_sites_rtree SELECT new.id, new.lon_deg, new.lon_deg, new.lat_deg,\n"
    "    new.lat_deg WHERE new.lat_deg IS NOT NULL AND new.pose_key IS NULL;\n"
    "END;\n"
    "CREATE TRIGGER site_detections_delete AFTER DELETE ON site_detections BEGIN\n"
    "  UPDATE light_sites SET stale = 1 WHERE id = old.site_id;\n"
    "  DELETE FROM light_sites WHERE id = old.site_id\n"
    "    AND NOT EXISTS (SELECT 1 FROM site_detections WHERE site_id = old.site_id);\n"
    "END;\n"
    "CREATE VIEW site_phase AS\n"
    "SELECT id AS site_id, coalesce(technology, 'none') AS technology, bulb_id, phase_deg,\n"
    "       CASE WHEN phase_deg IS NULL THEN 'unknown'\n"
    "            WHEN phase_deg <= 20 OR phase_deg >= 340 THEN '0'\n"
    "            WHEN phase_deg BETWEEN 100 AND 140 THEN '120'\n"
    "            WHEN phase_deg BETWEEN 220 AND 260 THEN '240'\n"
    "            ELSE 'other' END AS phase_class,\n"
    "       phase_sigma_deg, confidence, bulb_confidence, phase_confidence, detections, captures,\n"
    "       lat_deg, lon_deg, semi_major_m, semi_minor_m, azimuth_deg\n"
    "FROM light_sites;\n",
    NULL};


/* Version 4: the phase-balance views over light sites (docs/survey-db.md "Views"): one row per
 * physical light, its detections combined over every survey (light_sites' columns), grouped
 * as 'all' and 'technology'; gridsurvey stats (no --survey) gives the same counts. */
static const char *const migration_4[] = {
    "CREATE VIEW site_phase_counts AS\n"
    "WITH base AS MATERIALIZED (\n"
    "  SELECT technology, count(*) AS lights,\n"
    "         sum(phase_class = 'unknown') AS unknown, sum(phase_class = 'other') AS other,\n"
    "         sum(phase_class = '0') AS n0, sum(phase_class = '120') AS n120,\n"
    "         sum(phase_class = '240') AS n240\n"
    "  FROM site_phase GROUP BY technology),\n"
    "g(grouping, grp, lights, unknown, other, n0, n120, n240) AS (\n"
    "  SELECT 'all', 'all', lights, unknown, other, n0, n120, n240 FROM base\n"
    "  UNION ALL SELECT 'technology', technology, lights, unknown, other, n0, n120, n240 FROM base)\n"
    "SELECT grouping, grp, sum(lights) AS lights, sum(unknown) AS unknown, sum(other) AS other,\n"
    "       sum(n0) AS n0, sum(n120) AS n120, sum(n240) AS n240, sum(n0 + n120 + n240) AS n\n"
    "FROM g GROUP BY grouping, grp;\n",
    SHARES_BALANCE_SQL("site_phase_counts", "site_phase_shares", "site_phase_balance"),
    NULL};

/* Version 5: the bulbs each capture's recognition was matched against (its grid's and bands'
 * DELIGHT entries, rec_matcher_bulb_count), the M of a detection's bulb posterior in sites.c
 * (docs/survey-db.md "Light sites"); NULL for captures stored before, which fall back to
 * delight_versions.bulbs. */
static const char *const migration_5[] = {
    "ALTER TABLE captures ADD COLUMN candidate_bulbs INTEGER CHECK (candidate_bulbs > 0);\n",
    NULL};

/* Version 6: each site's views (docs/survey-db.md "Light sites"): per camera pose that saw it,
 * its detections' mean pixel, so that a detection of that pose and pixel finds the site whether
 * or not the site or the detection is located (sites.c); filled for the sites already stored. */
static const char *const migration_6[] = {
    "CREATE TABLE site_views(\n"
    "  site_id INTEGER NOT NULL REFERENCES light_sites(id) ON DELETE CASCADE,\n"
    "  pose_key TEXT NOT NULL, x_px REAL NOT NULL, y_px REAL NOT NULL,\n"
    "  detections INTEGER NOT NULL CHECK (detections > 0),\n"
    "  PRIMARY KEY (site_id, pose_key)) WITHOUT ROWID;\n"
    "CREATE INDEX site_views_pose ON site_views(pose_key, x_px, y_px);\n",
    SRV_SQL_SITE_VIEWS("") ";\n",
    NULL};

/* Version 7: light_sites(pose_key, x_px) dropped: since version 6 the association finds a
 * site by pose and pixel in site_views (sites.c), and each site written kept it up to date. */
static const char *const migration_7[] = {
    "DROP INDEX light_sites_pose;\n",
    NULL};

const srv_db_migration srv_db_migrations[SRV_DB_MIGRATIONS] = {
    {"tables, R*Tree and triggers", migration_1},
    {"phase-balance views", migration_2},
    {"light sites", migration_3},
    {"site phase-balance views", migration_4},
    {"candidate bulbs of each capture", migration_5},
    {"site views: the pose and pixel of each site", migration_6},
    {"pose index of light_sites dropped (site_views has it)", migration_7},
};

/* ------------------------------------------------------------------ statements */

const char *const srv_db_stmt_sql[ST_COUNT] = {
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
                       "ingested_utc, candidate_bulbs) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, "
                       "?10, ?11, ?12, ?13, ?14, ?15, ?16, ?17, ?18, ?19) ON CONFLICT DO NOTHING",
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
    [ST_FIND_CAPTURE] = "SELECT s.id, s.name FROM captures c JOIN surveys s ON s.id = c.survey_id "
                        "WHERE c.capture_key = ?1 ORDER BY s.name = ?2 DESC, c.id LIMIT 1",
};
