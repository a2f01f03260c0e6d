/* survey.h - the public interface of gridsurvey's survey/ module (prefix srv_): the command
 * line and, later, the survey database, statistics and pipeline. */
#ifndef GRIDSURVEY_SURVEY_H
#define GRIDSURVEY_SURVEY_H

#include "gis/gis.h"
#include "recognize/recognize.h"

#include <stddef.h>
#include <stdint.h>

/* Run the gridsurvey command line; returns the process exit status (0 ok, 1 failure with a
 * one-line message on stderr, 2 usage error). */
int srv_main(int argc, char **argv);

/* =====================================================================================
 * Survey database (survey/db.c; docs/survey-db.md is the specification)
 *
 * One SQLite file per project holding surveys, stations, captures (with their frames and grid
 * frequency log), lights (pixel, signal quality, recognized bulb and phase with confidences
 * and runner-up) and their locations (WGS84 position, error ellipse) with an R*Tree index,
 * and SQL views for phase-balance statistics.
 *
 * Identification: PRAGMA application_id = SRV_DB_APPLICATION_ID ('GSDB') and
 * PRAGMA user_version = schema version; meta('format') = SRV_DB_FORMAT. A file is refused
 * (GS_EFORMAT, one line naming the file, what was expected and what was found, nothing
 * written) unless it is such a database, or an empty SQLite file / a missing path when
 * creating. Migrations: an ordered list of SQL scripts; opening for writing applies the
 * missing ones, each in its own transaction that also sets user_version and adds a row to the
 * `migrations` table. A file of a newer schema is refused; a file of an older schema opened
 * read-only is refused with a hint to open it for writing once.
 *
 * Transactions and crash safety: WAL journal while a writer is open (synchronous = NORMAL;
 * the last writer to close checkpoints and returns the file to rollback mode, so at rest it
 * is one self-contained file), foreign keys on, a busy timeout of 10 s. Every write runs
 * inside a transaction; a capture's row, frames, lights,
 * locations and frequency log are committed together (srv_db_add_capture), so after a crash
 * (SIGKILL, power loss) each capture is either fully present or absent, and a re-run skips
 * the captures already committed (natural UNIQUE keys: a re-run never duplicates a row).
 * WAL + NORMAL survives any process crash; on power loss the last commits may roll back
 * (never corrupt), and a re-run redoes them.
 *
 * Thread safety: a handle is one SQLite connection; use it from one thread at a time.
 * Strings in the row structs are borrowed for the duration of the call; NULL or "" stores
 * SQL NULL. Non-finite doubles (NaN, +-Inf) store NULL.
 * ===================================================================================== */

#define SRV_DB_SCHEMA_VERSION 7
#define SRV_DB_APPLICATION_ID GS_SURVEY_DB_APPLICATION_ID   /* 'GSDB' (GeoPackage uses 'GPKG' = 0x47504B47) */
#define SRV_DB_FORMAT "gridsurvey-survey"
/* Written to migrations.generator and delight_versions.generator. */
#define SRV_GENERATOR "gridsurvey 0.1"

typedef struct srv_db srv_db;
struct sqlite3;

typedef enum {
    SRV_DB_READ,     /* read-only (SQLITE_OPEN_READONLY): every write fails with GS_EIO */
    SRV_DB_WRITE,    /* read-write; the file must exist; an older schema is migrated */
    SRV_DB_CREATE,   /* read-write; a missing file is created (never its directory) */
    SRV_DB_INIT      /* as _CREATE, and an existing empty file (0 bytes, or SQLite without a
                      * schema) is made a survey database: `db init` only */
} srv_db_mode;

/* Open (or create) a survey database. Errors, all one line naming path: GS_ENOTFOUND (missing
 * file and mode READ or WRITE), GS_EIO (cannot open or create: missing directory, parent
 * that is not a directory, no permission; a read-only file opened for writing), GS_EFORMAT (not
 * a survey database, or a newer / older schema as above; an empty file unless SRV_DB_INIT),
 * GS_ESQL. A new file is created complete under a temporary name and renamed into place, so a
 * killed creation leaves no file under path; never over a file another process made meanwhile
 * (that one is opened). On any error nothing is left on disk that was not
 * there before (a file created by this call is removed). */
gs_status srv_db_open(const char *path, srv_db_mode mode, srv_db **out);
/* Roll back an open transaction, finalize statements, close. Accepts NULL. */
void srv_db_close(srv_db *db);
/* srv_db_close, then remove the file if this handle created it (a failed job leaves no new
 * database behind), unless another connection has it open or a survey is stored in it (another
 * process's run). Accepts NULL. */
void srv_db_close_discard(srv_db *db);
/* The path given to srv_db_open (borrowed). */
const char *srv_db_path(const srv_db *db);
/* The SQLite connection, borrowed, for read queries (views, tests). Write through the API. */
struct sqlite3 *srv_db_sqlite(srv_db *db);
/* For migration tests and tools only: create a new database at schema version 1..
 * SRV_DB_SCHEMA_VERSION (GS_EINVAL otherwise; GS_EIO if path exists). */
gs_status srv_db_create_at_version(const char *path, int version);

/* BEGIN IMMEDIATE / COMMIT / ROLLBACK. begin inside a transaction is GS_EINVAL; rollback
 * without one is a no-op. GS_EIO on a read-only handle. */
gs_status srv_db_begin(srv_db *db);
gs_status srv_db_commit(srv_db *db);
gs_status srv_db_rollback(srv_db *db);
int srv_db_in_transaction(const srv_db *db);

/* --- rows. Each srv_*_init sets every number to NaN (integers to 0 or -1 as noted) and
 * every string to NULL. */

/* The DELIGHT database used: sha256 of its CSV export (srv_delight_fingerprint). */
typedef struct {
    char sha256[65];           /* 64 lower-case hex digits */
    const char *source;        /* file path, or "built-in" */
    const char *generator;     /* NULL = SRV_GENERATOR */
    long bulbs;                /* entries */
} srv_delight_row;
/* sha256 of gs_delight_export_csv(d) (byte-exact, so equal databases hash equally) and the
 * entry count. */
gs_status srv_delight_fingerprint(const gs_delight *d, const char *source, srv_delight_row *r);

typedef struct {
    const char *name;          /* required, unique (the natural key) */
    const char *city, *started_utc, *notes;
    int grid_hz;               /* 50, 60, or 0 = unknown */
} srv_survey_row;

typedef struct {
    int64_t survey_id;
    const char *name;          /* required, unique within the survey */
    gis_camera cam;            /* all numbers NaN = unknown (after srv_station_row_init) */
    double sigma_px;
    const char *time_utc;
} srv_station_row;

typedef struct {
    int64_t survey_id;         /* required */
    int64_t station_id;        /* 0 = none */
    int64_t delight_id;        /* 0 = none */
    const char *key;           /* required, unique within the survey: the resume key (e.g.
                                * the capture directory's name or a content hash) */
    const char *path, *utc;
    int grid_hz, K, bands, width_px, height_px;   /* 0 = unknown */
    int locked;                /* 1, 0, or -1 = unknown */
    double mean_frequency_hz, sigma_frequency_hz;
    long candidate_bulbs;      /* the bulbs its recognition was matched against (the DELIGHT
                                * entries of its grid and bands, rec_matcher_bulb_count); 0 =
                                * unknown */
} srv_capture_row;

typedef struct {
    int k;                     /* window index >= 0, unique within the capture */
    const char *file, *hdr_map;
    double cycles;
} srv_frame_row;

/* One recognized light (recognize/: rec_catalog entry + rec_match). */
typedef struct {
    int index;                 /* >= 0, unique within the capture (catalog index) */
    double x_px, y_px;         /* required, finite */
    int area_px, saturated_px; /* -1 = unknown */
    double peak_dn, brightness;
    double snr;                /* sum of signal / sqrt(sum of sigma^2) over usable samples */
    double chi2;
    int dof;                   /* -1 = unknown */
    double p_value;            /* [0, 1] */
    const char *bulb_id;       /* DELIGHT id, NULL = no answer */
    const char *technology;    /* gs_tech_name(), NULL = no answer */
    double phase_deg;          /* [0, 360) (wrapped); NaN = ambiguous or unknown */
    double phase_fit_deg;      /* the best fit's phase whatever its confidence; NaN = none */
    double phase_sigma_deg;
    double confidence;         /* [0, 1] posterior of (bulb, phase); NaN stores 0 */
    double bulb_confidence, phase_confidence;   /* [0, 1]; NaN stores 0 */
    const char *runner_bulb_id;
    double runner_phase_deg, runner_confidence;
    unsigned blob_flags;       /* REC_BLOB_* */
    unsigned match_flags;      /* REC_MATCH_* */
    double pos_cov_px2[3];     /* the PSF fit's position covariance (rec_catalog.pos_cov_px2;
                                * NaN = none); for the ellipses, not stored */
} srv_light_row;

typedef enum {
    SRV_LOC_NONE,              /* no location row */
    SRV_LOC_ONE_STATION,       /* gis_locate */
    SRV_LOC_TRIANGULATED,      /* gis_triangulate */
    SRV_LOC_TRUTH              /* from a simulator's truth.json */
} srv_loc_method;

typedef struct {
    srv_loc_method method;
    double lat_deg, lon_deg;   /* NaN = not located (flags say why); lon wrapped to [-180,180) */
    double height_m;
    gis_ellipse ellipse;       /* non-finite semi-axes store NULL */
    double range_m;
    unsigned flags;            /* GIS_FIX_* */
} srv_location_row;

typedef struct {
    double t_s;                /* start of the window, seconds from the capture's start */
    double window_s;           /* > 0: one cycle (1 / (2 f)) ... or 1 s */
    double frequency_hz;       /* > 0 */
    double sigma_hz;           /* NaN = unknown */
} srv_freq_row;

void srv_station_row_init(srv_station_row *r);
void srv_capture_row_init(srv_capture_row *r);
void srv_light_row_init(srv_light_row *r);
void srv_location_row_init(srv_location_row *r);

/* Fill the signal part of r (index, position, area, peak, saturated_px, blob flags, snr)
 * from light i of a blob catalog. */
void srv_light_from_catalog(srv_light_row *r, const rec_catalog *cat, size_t i);
/* Fill the recognition part from an Eq. 7 answer: bulb id and technology from the matcher's
 * bulb (NULL when m->bulb < 0); phase_deg NaN when m->flags has REC_MATCH_PHASE_AMBIGUOUS or
 * there is no bulb; runner-up likewise. The strings point into the matcher (borrowed: keep it
 * alive until the row is inserted). */
void srv_light_from_match(srv_light_row *r, const rec_match *m, const rec_matcher *mt);
/* A one-station fix (method SRV_LOC_ONE_STATION). */
void srv_location_from_fix(srv_location_row *r, const gis_fix *f);

/* --- inserts. "Get or add" by natural key: an existing row is not changed, its id returned. */
gs_status srv_db_add_delight(srv_db *db, const srv_delight_row *r, int64_t *id);
gs_status srv_db_add_survey(srv_db *db, const srv_survey_row *r, int64_t *id);
gs_status srv_db_add_station(srv_db *db, const srv_station_row *r, int64_t *id);
/* GS_ENOTFOUND when there is no survey of that name. */
gs_status srv_db_find_survey(srv_db *db, const char *name, int64_t *id);

/* Everything recognized in one capture, inserted atomically by srv_db_add_capture. */
typedef struct {
    srv_capture_row capture;
    const srv_frame_row *frames;
    size_t n_frames;
    const srv_light_row *lights;
    const srv_location_row *locations;   /* n_lights entries, parallel to lights; NULL = none */
    size_t n_lights;
    const srv_freq_row *frequency;       /* the grid frequency log, in time order */
    size_t n_frequency;
} srv_capture_data;

/* The resumable ingest: 1 in *done if the capture (survey_id, key) is committed. */
gs_status srv_db_capture_done(srv_db *db, int64_t survey_id, const char *key, int *done);
/* The survey of a committed capture with this key in any survey: the one named name when it
 * holds it, else the first (name and *survey_id set); GS_ENOTFOUND when none holds it. */
gs_status srv_db_capture_survey(srv_db *db, const char *key, int64_t *survey_id, char name[64]);
/* Insert a whole capture in one transaction (its own, or a SAVEPOINT inside the caller's), or
 * nothing: if (survey_id, key) is already present nothing is written and *skipped = 1
 * (either output may be NULL). Validation failures (GS_EINVAL naming the field and row) and
 * SQL errors roll back every row of this capture. */
gs_status srv_db_add_capture(srv_db *db, const srv_capture_data *c, int64_t *capture_id,
                             int *skipped);
/* Delete a capture and everything under it (cascades, R*Tree included); *deleted 0 if absent. */
gs_status srv_db_delete_capture(srv_db *db, int64_t survey_id, const char *key, int *deleted);

/* Low-level prepared-statement inserts; each requires an open transaction (GS_EINVAL
 * otherwise) and is idempotent (INSERT ... ON CONFLICT DO NOTHING on the natural key; an
 * existing row's id is returned). srv_db_add_capture is built on them. */
gs_status srv_db_insert_capture(srv_db *db, const srv_capture_row *r, size_t n_lights,
                                size_t n_frames, size_t n_frequency, int64_t *id);
gs_status srv_db_insert_frame(srv_db *db, int64_t capture_id, const srv_frame_row *r);
gs_status srv_db_insert_light(srv_db *db, int64_t capture_id, const srv_light_row *r,
                              int64_t *light_id);
gs_status srv_db_insert_location(srv_db *db, int64_t light_id, const srv_location_row *r);
gs_status srv_db_insert_frequency(srv_db *db, int64_t capture_id, int seq, const srv_freq_row *r);

/* Consistency report (`gridsurvey db check`): integrity_check, foreign_key_check, the R*Tree
 * against the located locations, and each capture's stored counts against its rows. */
typedef struct {
    int integrity_ok;          /* PRAGMA integrity_check = 'ok' */
    long fk_violations;        /* rows of PRAGMA foreign_key_check */
    long rtree_rows, located;  /* R*Tree entries; locations with a position */
    long rtree_mismatch;       /* entries without an equal located location, or vice versa */
    long incomplete_captures;  /* captures whose lights, frames or frequency rows differ from
                                * the counts recorded with them */
    long surveys, captures, lights, locations, frequency_rows;
    long sites;                /* light_sites rows */
    long unassociated;         /* lights without a site (srv_db_associate fixes them) */
    long stale_sites;          /* sites marked stale or whose detection or view count is off */
    long site_rtree_mismatch;  /* located sites minus light_sites_rtree entries */
    long wrong_types;          /* values of a REAL or INTEGER column that are text or blobs */
} srv_db_report;
gs_status srv_db_check(srv_db *db, srv_db_report *r);
/* 1 when every check passed. */
int srv_db_report_ok(const srv_db_report *r);

/* --- light identity (survey/sites.c; docs/survey-db.md, "Light sites"). Each stored light
 * (a detection) belongs to one light site (a physical light): srv_db_add_capture associates a
 * new capture's lights in its transaction, by position within the combined error ellipse
 * (Mahalanobis d2 < SRV_SITE_GATE_D2) or by pixel within SRV_SITE_GATE_PX of a site seen from
 * the same camera pose (a detection without a bounded location: any such site; a located one:
 * a site without a location, which it upgrades or merges into its own); otherwise a new site. */
#define SRV_SITE_GATE_D2 13.815510557964274   /* chi2 quantile 0.999 at 2 dof: -2 ln(0.001) */
#define SRV_SITE_GATE_PX 3.0
#define SRV_CHI2_2DOF_95 5.991464547107979    /* -2 ln(0.05): the 95 % ellipse of a 2-D normal */
/* x^T C^-1 x for the offset (east_m, north_m) and the covariance C of the 1-sigma ellipse
 * (a, b, azimuth of a clockwise from north); +inf for a degenerate ellipse. */
double srv_ellipse_maha2(double a_m, double b_m, double az_deg, double east_m, double north_m);
#define SRV_SITE_MAX_OBS 64                   /* detections combined per site (the first ones) */
/* Associate every detection not yet associated (captures in id order) and refresh the sites
 * left stale by deletions; its own transaction when the caller has none. Counts optional: the
 * detections that founded a site, those that joined one, and the sites merged into another
 * (one light seen unlocated and then located from the same pose: survey/sites.c), so the
 * sites grew by created - merged. */
gs_status srv_db_associate(srv_db *db, long *created, long *joined, long *merged);

/* One detection's recognition, as srv_site_combine reads it. */
typedef struct {
    char bulb_id[GS_ID_MAX];   /* "" = no bulb */
    char technology[24];
    double phase_deg, phase_sigma_deg;   /* NaN = unknown */
    double confidence, bulb_confidence, phase_confidence;
    long bulbs;                /* candidate bulbs of its capture's recognition (captures.
                                * candidate_bulbs, else its DELIGHT's entries; 0 = unknown) */
} srv_site_obs;
/* A site's combined recognition. */
typedef struct {
    char bulb_id[GS_ID_MAX], technology[24];
    double phase_deg, phase_sigma_deg;
    double confidence, bulb_confidence, phase_confidence;
    long detections;
} srv_site_value;
/* The product of the detections' posteriors (uniform prior): each detection puts its
 * confidence on its label and spreads the rest evenly over the M - 1 other labels (M for
 * bulbs = the largest of the detections' srv_site_obs.bulbs, the candidates their recognition
 * was matched against; 3 phases when every phase is within 20 deg of 0/120/240, else the
 * twelve multiples of 30 deg); the winner's normalised product. The phase is the
 * inverse-variance circular mean of the winning label's phases, its sigma
 * 1 / sqrt(sum sigma_i^-2). One detection is returned unchanged; unknown phases and bulbs
 * carry no evidence (without any, the highest single confidence). */
void srv_site_combine(const srv_site_obs *o, size_t n, srv_site_value *v);

/* --- change detection between two surveys of the same area (survey/sites.c; `gridsurvey
 * compare`, docs/survey-db.md "Changes"). Per site, each survey's detections combined
 * (srv_site_combine); a phase or bulb change is reported when the two winners differ and the
 * probability that they differ, 1 - sum_l P_A(l) P_B(l) (the posteriors as in
 * srv_site_combine), is at least min_p. */
enum {
    SRV_CHANGE_PHASE = 1u << 0,
    SRV_CHANGE_BULB = 1u << 1,
    SRV_CHANGE_APPEARED = 1u << 2,   /* detections in B only */
    SRV_CHANGE_VANISHED = 1u << 3    /* detections in A only */
};
typedef struct {
    int64_t site_id;
    double lat_deg, lon_deg;   /* the site's position (NaN for a pixel site) */
    double x_px, y_px;         /* its mean pixel */
    unsigned kinds;            /* SRV_CHANGE_* */
    srv_site_value a, b;       /* each survey's combined answer (detections 0: not seen) */
    double p_phase_change, p_bulb_change;   /* NaN when a side has no phase / bulb */
} srv_change;
typedef struct {
    long sites_a, sites_b, both, unchanged;   /* unchanged: in both, no change reported */
} srv_compare_totals;
/* The changed sites (by site id) in *out (free()); GS_ENOTFOUND for an unknown survey. */
gs_status srv_compare(srv_db *db, const char *survey_a, const char *survey_b, double min_p,
                      srv_change **out, size_t *count, srv_compare_totals *t);

/* =====================================================================================
 * Phase-balance statistics (survey/stats.c; definitions in docs/survey-db.md)
 * ===================================================================================== */

/* The 95 % two-sided normal quantile used by the Wilson intervals. */
#define SRV_Z95 1.959963984540054

/* Wilson score interval (E. B. Wilson, JASA 22, 209-212 (1927)) for k successes out of n at
 * normal quantile z (> 0): lo and hi in [0, 1]. Returns k/n; NaN (and NaN bounds) for n = 0,
 * k < 0 or k > n. */
double srv_wilson(long k, long n, double z, double *lo, double *hi);

typedef enum {
    SRV_BY_ALL,          /* one group */
    SRV_BY_TECHNOLOGY,   /* per technology ("none" for lights without a bulb) */
    SRV_BY_SURVEY,       /* per survey name */
    SRV_BY_CELL,         /* per cell of a local metric grid (located lights only) */
    SRV_BY_RADIUS,       /* one group: located lights within radius_m of (lat, lon) */
    SRV_BY_FEATURE       /* per area of opts.areas (its feature_field value) */
} srv_group_by;
#define SRV_BY_MAX 3             /* groupings combined in one --by */
#define SRV_PHASE6_TOL_DEG 15.0  /* the six-phase classes 30/150/270: within half their spacing */

/* Areas (survey/areas.c): the Polygon / MultiPolygon features of a GeoJSON FeatureCollection
 * (WGS84 lon/lat), through GEOS. GS_EFORMAT (one line naming the file, the feature and what is
 * expected) for anything else, an invalid polygon, or (field given) a feature without that
 * property (a string, number or boolean). */
typedef struct srv_areas srv_areas;
gs_status srv_areas_load(const char *path, const char *field, srv_areas **out);
void srv_areas_free(srv_areas *a);
size_t srv_areas_count(const srv_areas *a);
/* Feature i's label: its field value, else "feature I". */
const char *srv_areas_label(const srv_areas *a, size_t i);
/* The first feature (file order) covering the point (boundary included), -1 for none. */
int srv_areas_find(const srv_areas *a, double lat_deg, double lon_deg);
/* The union of the features labelled label as WKT (9 decimals, trimmed; malloc'd, free it):
 * the geometry of a stats group --by feature:FIELD. GS_ENOTFOUND when no feature has it. */
gs_status srv_areas_wkt(const srv_areas *a, const char *label, char **wkt);

typedef struct {
    srv_group_by by;           /* the grouping, or the first of a combination */
    srv_group_by then[SRV_BY_MAX - 1];   /* the others of a combination (n_then of them) */
    int n_then;
    double cell_m;             /* SRV_BY_CELL: cell side, metres (> 0) */
    double cell_origin_deg[2]; /* SRV_BY_CELL: the grid's origin, latitude and longitude (NaN:
                                * the selection's centre; `compare` gives both surveys one) */
    double lat_deg, lon_deg;   /* SRV_BY_RADIUS: centre */
    double radius_m;           /* SRV_BY_RADIUS: > 0, spherical distance (see stats.c) */
    double min_phase_confidence;    /* lights with phase_confidence below it are excluded (0) */
    const char *survey;        /* only this survey (NULL = all) */
    int detections;            /* 1: count detections (stored lights), not light sites (0) */
    double bbox[4];            /* MINLON, MINLAT, MAXLON, MAXLAT (NaN: none); MINLON > MAXLON
                                * crosses the antimeridian */
    const srv_areas *areas;    /* only sites inside one of these areas (NULL: none) */
    char feature_field[64];    /* SRV_BY_FEATURE: the areas' property naming each one */
} srv_stats_opts;
void srv_stats_opts_default(srv_stats_opts *o);
/* "technology" | "survey" | "all" | "cell:SIZE_m" | "feature:FIELD" | "radius:LAT,LON,R_m", or
 * up to SRV_BY_MAX of technology, survey, cell:SIZE_m, feature:FIELD joined by commas (groups
 * named "A / B"), into o (GS_EINVAL naming the text and what is expected). */
gs_status srv_stats_parse_by(const char *text, srv_stats_opts *o);

enum {
    SRV_STATS_EMPTY = 1u << 0,   /* no light of a known 0/120/240 phase: shares NaN */
    SRV_STATS_FEW = 1u << 1      /* expected count n/3 < 5: the chi-square p-value is only
                                  * approximate (Cochran's rule) */
};

typedef struct {
    char group[296];           /* "all", a technology, a survey, "E,N" cell indices, "radius", an
                                * area, or "A / B" for a combination */
    double lat_deg, lon_deg;   /* cell centre (SRV_BY_CELL), centre (SRV_BY_RADIUS), else NaN */
    long lights;               /* lights in the group */
    long below;                /* ... with phase_confidence < min_confidence (excluded) */
    long unknown;              /* ... kept, phase NULL (ambiguous / unknown) */
    long other;                /* ... kept, another phase (not 0/120/240 within GS_PHASE_TOL_DEG
                                * nor 30/150/270 within SRV_PHASE6_TOL_DEG) */
    long n30[3];               /* ... kept, phase 30, 150, 270 (six-phase surveys); not in the
                                * shares, which are of the three primary phases */
    long n[3];                 /* ... kept, phase 0, 120, 240 */
    long total;                /* n[0] + n[1] + n[2]: the denominator of the shares */
    double share[3];           /* n[i] / total */
    double lo[3], hi[3];       /* 95 % Wilson interval of each share */
    double chi2;               /* sum (n_i - total/3)^2 / (total/3): uniformity test, 2 dof */
    double p_value;            /* gs_chi2_sf(chi2, 2) */
    double imbalance;          /* max_i |share_i - 1/3| / (1/3), [0, 2]: 0 balanced, 2 all on
                                * one phase (NEMA MG-1 "max deviation from the mean / mean",
                                * applied to light counts) */
    unsigned flags;            /* SRV_STATS_* */
} srv_phase_stats;

/* Shares, intervals, chi2, p-value, imbalance and flags of g from its counts. */
void srv_phase_stats_finish(srv_phase_stats *g);

/* Phase-balance statistics per group, sorted by group name (cells by north then east index).
 * *groups is allocated (free()); *count may be 0. *ungrouped (may be NULL) receives the lights
 * left out of SRV_BY_CELL because they have no position (0 for the other groupings). */
gs_status srv_stats_compute(srv_db *db, const srv_stats_opts *o, srv_phase_stats **groups,
                            size_t *count, long *ungrouped);

/* The same statistics from the shared PostGIS database (conninfo: a libpq connection string;
 * survey/pg_stats.c): the same rows, read from PostgreSQL in the same order, through the same
 * computation, so the numbers equal those of srv_stats_compute on the data pushed. */
gs_status srv_stats_compute_pg(const char *conninfo, const srv_stats_opts *o, srv_phase_stats **groups,
                               size_t *count, long *ungrouped);

/* =====================================================================================
 * The shared PostGIS database (survey/pg*.c, docs/postgis.md): `gridsurvey push`
 *
 * Copies a survey database's surveys, stations, DELIGHT versions, captures (frames, frequency
 * log), lights, locations and light sites into the schema "gridsurvey" of a PostgreSQL +
 * PostGIS database (created and migrated on connection). Idempotent and resumable: a capture
 * is one transaction with its rows (keyed by survey name and capture_key), so a capture already
 * there is skipped and an interrupted push resumes where it stopped; sites are upserted by
 * their founding detection and only rewritten when they differ. Several stations may push at
 * once (unique keys, ON CONFLICT, retried deadlocks).
 * ===================================================================================== */

#define SRV_PG_SCHEMA_VERSION 3
#define SRV_PG_FORMAT "gridsurvey-survey-pg"
typedef struct {
    size_t batch_lights;       /* lights per transaction, whole captures (20000) */
    const char *areas;         /* a GeoJSON of areas to load too (NULL: none) */
    const char *areas_field;   /* their label property; the layer's name */
    int progress;              /* a line per 10 % on stderr */
} srv_push_opts;
void srv_push_opts_default(srv_push_opts *o);
typedef struct {
    size_t captures, captures_pushed;   /* in the file; newly pushed */
    size_t lights_pushed;
    size_t sites, sites_written;        /* in the file; inserted, changed or deleted (merged) */
    size_t areas;
    int retries;                        /* transactions retried after a deadlock */
} srv_push_report;
gs_status srv_pg_push(const char *db_path, const char *conninfo, const srv_push_opts *o,
                      srv_push_report *r);

/* =====================================================================================
 * Export (survey/cmd_export.c): database rows -> gis_light -> gis_export
 * ===================================================================================== */

typedef struct {
    const char *survey;        /* only this survey (NULL = all) */
    const char *technology;    /* only this technology ("none": no bulb), NULL = all */
    int phase;                 /* -2 = all (default); 0, 1, 2 = 0/120/240; 3 = other;
                                * -1 = unknown (NULL phase) */
    int use_bbox;              /* filter by bbox (located lights only; R*Tree) */
    double bbox[4];            /* min_lon, min_lat, max_lon, max_lat; min_lon > max_lon crosses
                                * the antimeridian */
    double min_confidence;     /* lights.confidence >= this (0 = all) */
} srv_export_opts;
void srv_export_opts_default(srv_export_opts *o);
/* The selected lights as gis_light (id = the light's database id; survey, capture time,
 * bulb, technology, phase (NaN when NULL), confidence, position, ellipse, GIS_FIX_* flags),
 * ordered by id. *lights is allocated (free()). */
gs_status srv_db_read_lights(srv_db *db, const srv_export_opts *o, gis_light **lights,
                             size_t *count);
/* The cameras of a survey's stations (every survey's when survey is NULL) with a full pose,
 * in the order they were stored; *cams is allocated (free()). */
gs_status srv_db_read_stations(srv_db *db, const char *survey, gis_camera **cams, size_t *count);

/* =====================================================================================
 * Synthetic surveys and the database benchmark (survey/bench_db.c; developer tools)
 * ===================================================================================== */

typedef struct {
    const char *survey;        /* survey name ("synthetic") */
    size_t captures;           /* captures (100) */
    size_t lights_per_capture; /* lights in every capture (100) */
    size_t batch;              /* captures per transaction, >= 1 (1) */
    unsigned long long seed;   /* (1) */
    double phase_weights[3];   /* relative frequency of 0/120/240 (1, 1, 1) */
    double ambiguous_fraction; /* lights stored with a NULL phase (0.05) */
    double lat_deg, lon_deg;   /* centre (Haifa bay: 32.80, 35.02) */
    double half_width_m;       /* capture view centres uniform in a square of this half-width
                                * around (lat, lon) (2000) */
    double view_half_width_m;  /* a capture's lights uniform in a square of this half-width
                                * around its view centre (250); a camera sees one district */
} srv_synth_opts;
void srv_synth_opts_default(srv_synth_opts *o);
/* Deterministic structure (so tests know the exact final counts): capture c has key
 * "synth-%06zu", SRV_SYNTH_FRAMES frames, SRV_SYNTH_FREQ frequency rows and
 * lights_per_capture lights; each light has a location row, unlocated (NULL position,
 * GIS_FIX_ABOVE_HORIZON) when index % SRV_SYNTH_UNLOCATED_EVERY == SRV_SYNTH_UNLOCATED_EVERY - 1.
 * The content (positions, technologies, phases, confidences) comes from the seed and c alone,
 * so an interrupted run resumed with the same options yields the same database. Captures
 * already present are skipped; *added (may be NULL) counts the new ones. */
#define SRV_SYNTH_FRAMES 8
#define SRV_SYNTH_FREQ 10
#define SRV_SYNTH_UNLOCATED_EVERY 25
gs_status srv_synth_ingest(srv_db *db, const srv_synth_opts *o, size_t *added);

/* `gridsurvey bench db [--quick] [--dir DIR] [--max N]`: ingest rate and query times at 1e4,
 * 1e5 and 1e6 lights (--quick: 1e4 only) as a Markdown table on stdout. argv[0] is "db". */
int srv_bench_db(int argc, char **argv);

/* =====================================================================================
 * The pipeline (survey/pipeline.c; docs/pipeline.md): `gridsurvey run`
 *
 * One capture from acquisition to the database:
 *   capture    a scene (gridsurvey-scene/1) is rendered by the sim backend through the
 *              acquisition loop (cap_loop_run: resumable) into a capture directory, with its
 *              truth.json; a capture directory is read as it is (gs_capture_read);
 *   recognize  lights as blobs with per-frame photometry (rec_blobs_extract), then Eq. 7 over
 *              DELIGHT (rec_match_catalog);
 *   locate     with a station (the capture's "station" object, or a station file), each light
 *              at the survey's light height (gis_locate); without one, lights are stored
 *              without a location;
 *   store      the capture, its frames, lights and locations in one transaction
 *              (srv_db_add_capture).
 * Resumable and idempotent: the capture's resume key is a content hash of its capture.json
 * and every file it names, so a re-run finds a committed capture (srv_db_capture_done) and
 * skips recognition; an interrupted acquisition resumes frame by frame; a process killed at
 * any point leaves a consistent database (no capture is ever partly stored).
 * Bad input is refused before anything is written: the scene or capture directory, the
 * station and DELIGHT files, the light height and the output locations are all checked before
 * the database is opened, and srv_db_open itself leaves nothing behind on failure.
 * ===================================================================================== */

/* Two stations (survey/sites_triangulate.c, docs/gis.md "Two stations in a survey"): every
 * light site with located detections in the given captures from two different stations (the
 * first two, in capture order) intersected by gis_triangulate from the detections' pixel
 * bearings (the stations' stored cameras). A bearing's 1-sigma is the cross-range part of its
 * one-station ellipse over its distance. *out is malloc'd (free it); flagged intersections
 * (GIS_FIX_BEHIND, NEAR_PARALLEL) are kept with NaN positions, and so is a site that cannot be
 * intersected at all (its error says why): one such site does not stop the others. */
typedef struct {
    int64_t site_id;
    int64_t light_id[2];             /* the two detections */
    char station[2][64];             /* their stations' names */
    double sigma_bearing_deg[2];
    gis_intersection fix;            /* position, 1-sigma ellipse, angle, flags */
    char error[160];                 /* why it could not be intersected ("" when fix says) */
} srv_tri_site;
gs_status srv_triangulate_sites(srv_db *db, const int64_t *capture_ids, size_t n_captures,
                                srv_tri_site **out, size_t *n_out);

/* Per-area share changes (survey/compare_shares.c): the phase counts of each group of o's
 * grouping and filters (o->survey ignored) in survey A and in survey B (srv_stats_compute of
 * each, light sites, their detections in that survey), joined by group name (A's groups first,
 * then B's others). For each phase i the two-proportion z test of share_b - share_a with the
 * pooled share p = (a_i + b_i) / (n_a + n_b): z = (s_b - s_a) / sqrt(p (1 - p) (1/n_a + 1/n_b)),
 * two-sided P = erfc(|z| / sqrt 2) (NaN when a total is 0 or p is 0 or 1); and Pearson's
 * chi-square of homogeneity of the 2 x 3 table (surveys x phases, phases with a count in either),
 * dof = phases - 1, P = gs_chi2_sf (NaN when dof < 1). The tests take the two surveys as
 * independent samples of the area's lights. GS_ENOTFOUND naming a survey that does not exist. */
typedef struct {
    char group[296];
    double lat_deg, lon_deg;   /* a cell's centre (on the grid both surveys share), the circle's
                                * with SRV_BY_RADIUS, else NaN */
    long n_a[3], total_a, n_b[3], total_b;   /* 0/120/240 counts and their sums */
    double share_a[3], share_b[3];
    double z[3], p[3];
    double chi2, p_value;
    int dof;
} srv_share_change;
gs_status srv_compare_shares(srv_db *db, const srv_stats_opts *o, const char *survey_a,
                             const char *survey_b, srv_share_change **out, size_t *count);
/* The tests of c from its counts (n_a, total_a, n_b, total_b). */
void srv_share_change_finish(srv_share_change *c);
/* "MINLON,MINLAT,MAXLON,MAXLAT" into bbox (GS_EINVAL naming the text otherwise). */
gs_status srv_parse_bbox(const char *text, double bbox[4]);
/* Whether (lat, lon) is in the box MINLON,MINLAT,MAXLON,MAXLAT (edges included; longitudes
 * compared wrapped to [-180, 180), so MAXLON 180 holds the meridian stored as -180 and
 * MINLON > MAXLON crosses the antimeridian): stats --bbox and export --bbox. */
int srv_bbox_contains(const double bbox[4], double lat_deg, double lon_deg);

/* The stages (survey/stages.c), each usable on its own: `run`, `recognize` and `bench
 * accuracy` call them. A job holds one capture through the stages; zero it first;
 * srv_job_release frees whatever the stages built (accepts NULL and a zeroed job). */
typedef struct {
    gs_capture cap;              /* srv_job_read (or the caller's) */
    int cap_locked, cap_lock_fd; /* srv_job_read: the directory's shared lock (gs_capture_lock) */
    const gs_delight *delight;   /* srv_job_matcher: the DELIGHT the matcher was built from */
    gs_delight *delight_owned;   /* ... when the job loaded or generated it */
    const char *delight_path;    /* borrowed; NULL = built-in */
    rec_matcher *matcher;        /* srv_job_matcher */
    rec_catalog cat;             /* srv_job_extract */
    rec_match *match;            /* srv_job_match: cat.count answers */
    rec_noise_report noise;      /* srv_job_match: where the excess noise came from */
    srv_light_row *lights;       /* srv_job_match: the rows (strings borrowed from the matcher) */
    srv_location_row *locs;      /* srv_job_locate: cat.count locations */
    size_t with_bulb, with_phase, located;
} srv_job;
void srv_job_release(srv_job *j);
/* acquire: the acquisition loop of backend be into capdir (resumable), then truth.json when be
 * is the sim backend; the loop's own progress line when progress. GS_EIO when the acquisition
 * stopped early. frames_* (may be NULL) report the loop's counts. */
struct cap_backend;
gs_status srv_job_acquire(struct cap_backend *be, const char *capdir, int progress,
                          int *frames_acquired, int *frames_kept);
/* read: the capture directory into j->cap, under its shared lock (gs_capture_lock; the read,
 * gs_capture_read_held, takes no second one), held until srv_job_release: no other process
 * acquires into it while the job's stages (and `run`'s content key of its files) use it. */
gs_status srv_job_read(srv_job *j, const char *capdir);
/* DELIGHT (the caller's d, borrowed until srv_job_release; else the file delight_path; else the
 * built-in database) and its Eq. 7 templates for a capture of grid_hz, bands and K; nothing when
 * j has a matcher already. GS_ENOTFOUND naming the database when no entry fits. */
gs_status srv_job_matcher(srv_job *j, const gs_delight *d, const char *delight_path, int grid_hz,
                          int bands, int K, const rec_eq7_opts *eq7);
/* extract: the lights of j->cap as blobs (rec_blobs_extract). */
gs_status srv_job_extract(srv_job *j, const rec_blob_opts *bo);
/* match: Eq. 7 for every light of j->cat, and its row; with_bulb / with_phase counted. */
gs_status srv_job_match(srv_job *j);
/* Free the capture's pixels (the later stages need only its metadata). */
void srv_job_drop_pixels(srv_job *j);
/* What the frames' window drift (gs_capture_frame_drift) means for a capture's answers, for the
 * commands' output: "" when locked; else "; free running: ..." with the largest drift and its
 * frame, or the frames rec_match_catalog leaves out at max_drift_windows (rec_eq7_opts,
 * REC_MATCH_DRIFT; auto: rec_drift_limit, and the period it followed). At most 300 characters:
 * n = 384 holds it. */
void srv_drift_note(const gs_capture *cap, double max_drift_windows, char *buf, size_t n);
/* A light's 1-sigma centroid error per image axis, px (docs/gis.md, "Calibrated ellipses"),
 * for a light without the PSF fit's covariance (srv_light_row.pos_cov_px2; srv_job_locate):
 * sqrt((sqrt(2) s / snr)^2 + floor_px^2 + c^2), floor_px the centroid's pixel-sampling bias
 * (rec_centroid_bias_px), s = sqrt(psf_sigma_px^2 + 1/12) the
 * pixel-integrated PSF sigma, snr the light's (srv_light_row.snr), c the crowding term: 0.012 s
 * for a light of the multi-source PSF fit (REC_BLOB_PSF_FIT), else 0.5 s when it was
 * deblended (REC_BLOB_DEBLENDED) or its footprint is crowded (srv_crowded_footprints), else 0.
 * NaN when snr is not finite and > 0, psf_sigma_px is NaN or floor_px not >= 0. */
double srv_centroid_sigma_px(double snr, unsigned blob_flags, int crowded, double psf_sigma_px,
                             double floor_px);
/* Marks crowded[i] = 1 for the lights whose footprint is too large for one light of their SNR:
 * area_px more than 4 robust sigmas above the capture's line area = a + b ln(snr), fitted by
 * least squares to its plain lights (no REC_BLOB_* flag) with those beyond 3 robust sigmas
 * (1.4826 MAD, at least 0.5 px: areas are whole pixels) dropped, three rounds: a neighbour
 * merged into the footprint undetected. All 0 with fewer than 10 plain lights. GS_ENOMEM (all 0) when out of memory. */
gs_status srv_crowded_footprints(const srv_light_row *lights, size_t n, unsigned char *crowded);
/* locate: every row from one station at the lights' height (gis_locate) with its 1-sigma
 * (sigma_height_m >= 0). Each light's pixel sigma: with the station's psf_sigma_px, its
 * centroid sigma (srv_centroid_sigma_px) and the station's sigma_px in quadrature; else (or
 * without an SNR) the station's sigma_px. */
gs_status srv_job_locate(srv_job *j, const gis_station *st, double height_m, double sigma_height_m);
/* store: the DELIGHT, survey and station rows (get or add), then the capture, its frames, grid
 * frequency log, lights and (with a station) locations in one transaction. */
typedef struct {
    const char *survey;          /* survey name */
    const gis_station *station;  /* NULL: none (no locations stored) */
    const char *key;             /* the capture's resume key */
    const char *path;            /* the capture directory as stored */
    /* called right before the transaction with the rows it holds; NULL = none */
    void (*before_commit)(void *ctx, size_t lights, int frames, size_t frequency_rows);
    void *ctx;
} srv_store_opts;
gs_status srv_job_store(srv_job *j, srv_db *db, const srv_store_opts *o, int64_t *survey_id,
                        int64_t *capture_id, int *skipped);

typedef enum {
    SRV_STAGE_CAPTURE,       /* acquisition loop (scene input) */
    SRV_STAGE_READ,          /* reading the capture directory, hashing its files */
    SRV_STAGE_BLOBS,         /* rec_blobs_extract */
    SRV_STAGE_MATCH,         /* DELIGHT, rec_matcher_new, rec_match_catalog */
    SRV_STAGE_LOCATE,        /* gis_locate per light */
    SRV_STAGE_STORE,         /* srv_db_add_capture (one transaction) */
    SRV_STAGE_COUNT
} srv_stage;
/* "capture", "read", "blobs", "match", "locate", "store"; NULL out of range. */
const char *srv_stage_name(srv_stage s);

typedef struct {
    const char *input;          /* SCENE.json or a capture directory (required) */
    const char *db_path;        /* the survey database; created when missing (required) */
    const char *station_path;   /* a gridsurvey-station/1 file overriding the capture's
                                 * "station" object (NULL: the capture's, if any) */
    const char *survey;         /* survey name, 1..63 bytes (NULL: the scene's "name", else the
                                 * scene file's stem; for a directory, its base name) */
    const char *capture_dir;    /* scene input: where the capture is acquired (NULL:
                                 * DBDIR/STEM-capture, STEM the scene file's stem); refused for
                                 * a directory input */
    double light_height_m;      /* height of the lights above the WGS84 ellipsoid, metres, in
                                 * [GIS_MIN_HEIGHT_M, GIS_MAX_HEIGHT_M]; NaN (default): a scene's
                                 * median height of its geographic lights. Required (GS_EINVAL)
                                 * when there is a station and no default. */
    double light_height_sigma_m;   /* the height's 1-sigma (the height prior of the error
                                    * ellipses), >= 0; NaN (default): with the scene's median,
                                    * the standard deviation of its geographic lights' heights,
                                    * else 0 */
    const char *delight_path;   /* DELIGHT SQLite file (NULL: a scene's "delight", else the
                                 * built-in database, gs_delight_generate) */
    rec_eq7_opts eq7;           /* Eq. 7 options (rec_eq7_opts_default) */
    double threshold_sigma;     /* blob detection threshold, noise sigmas > 0 (5) */
    int capture_progress;       /* the acquisition loop's own progress line on stderr (0) */
    /* Called at the start of each stage, and once more in SRV_STAGE_STORE right before the
     * capture's transaction (detail starting "capture:"); NULL = none. detail is a short
     * borrowed text. */
    void (*progress)(void *ctx, srv_stage stage, const char *detail);
    void *progress_ctx;
} srv_run_opts;
/* Defaults as in parentheses above; input and db_path NULL. */
void srv_run_opts_default(srv_run_opts *o);

typedef struct {
    char survey[64];
    int64_t survey_id, capture_id;   /* database ids */
    char key[72];                    /* the capture's resume key: "sha256:" + 64 hex digits */
    char capture_dir[4096];          /* the capture directory used */
    char truth_path[4096];           /* CAPDIR/truth.json when present, else "" */
    int scene;                       /* 1: the input was a scene */
    int skipped;                     /* 1: the capture was already committed: nothing written */
    char also_in[64];                /* stored under a named --survey while another survey of the
                                      * database holds the same capture: that survey ("" if none) */
    int frames_acquired, frames_kept;   /* scene input: this run's acquisition loop */
    size_t lights;                   /* lights of the capture (as stored) */
    size_t with_bulb, with_phase;    /* ... with a recognised bulb, with a phase */
    char drift_note[384];            /* srv_drift_note of the capture ("" when locked) */
    size_t located;                  /* ... with a position */
    int has_station;                 /* a station was used */
    gis_station station;             /* that station (when has_station) */
    double light_height_m;           /* used (NaN when nothing was located) */
    char height_source[32];          /* "--light-height-m", "scene median", or "" */
    double light_height_sigma_m;     /* its 1-sigma used for the ellipses */
    double seconds[SRV_STAGE_COUNT]; /* wall time per stage (0 for stages skipped) */
} srv_run_report;

/* Run the pipeline on one input (see above). *r is always filled as far as the run got.
 * Errors carry a one-line gs_detail() naming the file and what was expected: GS_EFORMAT (a
 * malformed scene, capture directory, station or DELIGHT file, a database that is not a
 * survey database), GS_ENOTFOUND (a missing input, frame or bulb), GS_EINVAL (options),
 * GS_EIO (unwritable locations), GS_ESQL. Not thread-safe (the acquisition loop and PLplot
 * are not). */
gs_status srv_run(const srv_run_opts *o, srv_run_report *r);

/* =====================================================================================
 * Evaluation against a simulator's truth (survey/evaluate.c; definitions in docs/pipeline.md)
 * ===================================================================================== */

/* The largest match radius: a light is a few pixels wide, and the matching's cost grows with
 * the radius squared (a huge radius made every pair a candidate). */
#define SRV_MATCH_PX_MAX 64.0
typedef struct {
    const char *survey;          /* NULL: any survey */
    const char *capture_key;     /* NULL: the capture whose stored path is the truth file's
                                  * directory, else the only capture of the selection */
    double match_px;             /* match radius, pixels, in (0, SRV_MATCH_PX_MAX] (2) */
} srv_eval_opts;
void srv_eval_opts_default(srv_eval_opts *o);

/* Phase classes of the confusion matrix: 0, 120, 240 deg (within GS_PHASE_TOL_DEG), another
 * phase, and (stored side only) none = ambiguous or unknown. */
#define SRV_EVAL_PHASE_CLASSES 5
/* Classes of the 95 % ellipse coverage (srv_eval_report.ellipse_class_*): plain lights (no blob
 * flag), lights of the PSF fit (REC_BLOB_PSF_FIT, whatever their other flags) outside the
 * truth's blend groups, and every light in a blend group; the other flagged lights (deblended,
 * saturated, ... without the PSF fit) in none. */
enum { SRV_ELLIPSE_PLAIN, SRV_ELLIPSE_PSF_FIT, SRV_ELLIPSE_BLEND_GROUP, SRV_ELLIPSE_CLASSES };

typedef struct {
    char survey[64];
    char capture_key[72];
    int64_t capture_id;
    double match_px;
    long truth_lights;           /* lights in truth.json */
    long truth_in_image;         /* ... on the sensor (in_image): the detection denominator */
    long stored;                 /* lights stored for the capture */
    long matched;                /* one-to-one pairs within match_px */
    long false_detections;       /* stored lights matched to no truth light: stored - matched */
    long bulb_answered;          /* matched lights with a bulb */
    long bulb_correct;           /* ... the truth's bulb id */
    long bulb_ambiguous;         /* ... flagged REC_MATCH_BULB_AMBIGUOUS (a bulb, not sure) */
    long tech_answered, tech_correct;   /* the same for the technology */
    long phase_answered;         /* matched lights with a phase (not ambiguous or unknown) */
    long phase_correct;          /* ... within GS_PHASE_TOL_DEG of the truth's phase (for a
                                  * truth on 0/120/240: the same phase class) */
    long all_correct;            /* matched lights with the right bulb and the right phase */
    long confusion[4][SRV_EVAL_PHASE_CLASSES];  /* [truth class][stored class] of matched
                                  * lights: classes 0, 120, 240, other (, none) */
    /* Resolvability (truth.json, docs/formats.md; a truth without it: every light resolvable) */
    long resolvable;             /* resolvable truth lights in the image */
    long resolvable_matched;     /* ... matched */
    long hidden;                 /* unresolvable lights in no blend group (a >= 10x brighter
                                  * light within 2 sigma) */
    long hidden_matched;         /* ... matched */
    long groups, group_lights;   /* blend groups (2+ close lights of comparable flux), lights */
    long groups_resolved;        /* groups whose every light is matched */
    long groups_flagged;         /* else: a matched stored light flagged REC_MATCH_BLEND */
    long groups_confident;       /* else: a matched stored light with a bulb, not ambiguous:
                                  * a blend reported as one confident bulb (the failure) */
    long groups_one_signal;      /* ... of which every light has one bulb and phase and every
                                  * answer is that one: their sum is one template, the answer right */
    long groups_unsure;          /* else: matched, but bulb unknown or ambiguous */
    long groups_missed;          /* else: no light of the group matched */
    long loc_pairs;              /* matched lights with a stored and a truth position */
    long loc_unlocated;          /* matched lights without a stored position */
    long ellipse_pairs;          /* loc_pairs whose stored ellipse is bounded */
    long ellipse_in95;           /* ... whose truth is inside the stored 95 % ellipse */
    double ellipse_coverage95;   /* ellipse_in95 / ellipse_pairs (a calibrated ellipse: 0.95) */
    long ellipse_class_pairs[SRV_ELLIPSE_CLASSES];   /* ellipse_pairs by class (SRV_ELLIPSE_*) */
    long ellipse_class_in95[SRV_ELLIPSE_CLASSES];    /* ... inside their 95 % ellipse */
    double loc_median_m, loc_p95_m, loc_max_m;  /* geodesic distance stored -> truth over the
                                  * loc_pairs (percentiles interpolated linearly between order
                                  * statistics, position (n - 1) q); NaN when loc_pairs = 0 */
    /* Rates (NaN when the denominator is 0) */
    double detection_rate;       /* matched / truth_in_image */
    double false_rate;           /* false_detections / stored */
    double resolvable_rate;      /* resolvable_matched / resolvable */
    double bulb_accuracy;        /* bulb_correct / bulb_answered */
    double tech_accuracy;        /* tech_correct / tech_answered */
    double phase_accuracy;       /* phase_correct / phase_answered */
    double bulb_unknown_rate;    /* (matched - bulb_answered) / matched */
    double phase_unknown_rate;   /* (matched - phase_answered) / matched */
    double all_correct_rate;     /* all_correct / truth_in_image */
} srv_eval_report;

/* Match the capture's stored lights to truth_path (gridsurvey-truth/1) by pixel position:
 * every (stored, truth in_image) pair closer than match_px, taken in increasing distance
 * (ties by stored then truth index), each light used at most once. Then the counts and rates
 * above. Errors: GS_ENOTFOUND (truth file, survey, capture), GS_EFORMAT (truth file, naming
 * the field), GS_EINVAL (several captures and no way to choose: the detail lists them). */
gs_status srv_evaluate(srv_db *db, const char *truth_path, const srv_eval_opts *o,
                       srv_eval_report *r);

#endif
