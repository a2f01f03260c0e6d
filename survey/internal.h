/* internal.h - survey/ internals: subcommands and CLI helpers. */
#ifndef GRIDSURVEY_SURVEY_INTERNAL_H
#define GRIDSURVEY_SURVEY_INTERNAL_H

#include "recognize/recognize.h"
#include "survey/survey.h"
#include "capture/capture.h"

#include <stdio.h>
#include <time.h>

/* Subcommands: argv[0] is the command name; return the exit status. */
int srv_cmd_delight(int argc, char **argv);
/* `delight plot`'s title: "DELIGHT BRFs, " and the grids of bulbs[0..count) (count >= 1), each
 * once, ascending: "50 Hz grid", "50 and 60 Hz grids" (each bulb's own is in the legend). */
void srv_delight_plot_title(const gs_bulb *const *bulbs, size_t count, char *title, size_t size);
int srv_cmd_locate(int argc, char **argv);
int srv_cmd_simulate(int argc, char **argv);
int srv_cmd_capture(int argc, char **argv);
int srv_cmd_stats(int argc, char **argv);
int srv_cmd_push(int argc, char **argv);
int srv_cmd_export(int argc, char **argv);
int srv_cmd_db(int argc, char **argv);
int srv_cmd_recognize(int argc, char **argv);
int srv_cmd_bench(int argc, char **argv);
int srv_cmd_run(int argc, char **argv);
int srv_cmd_evaluate(int argc, char **argv);
int srv_cmd_compare(int argc, char **argv);
int srv_cmd_unmix(int argc, char **argv);
int srv_cmd_relight(int argc, char **argv);
int srv_cmd_separate(int argc, char **argv);
/* `gridsurvey bench transport` (survey/bench_transport.c). */
int srv_bench_transport(int argc, char **argv);

/* ====================== light transport commands (transport_eval.c), shared between them */

/* DELIGHT: the SQLite file db (NULL: $GRIDSURVEY_DELIGHT, else the built-in database). */
gs_status srv_tr_delight(const char *db, gs_delight **out);
/* A simulated capture's transport truth (truth.json "transport", docs/light-transport.md): n
 * images tau Q (DN per cycle) of W x H x B, img[i * W * H * B + ...], with each one's light,
 * bulb and phase. GS_ENOTFOUND without one. */
typedef struct {
    int n, W, H, B;
    char (*light)[48];
    char (*bulb)[GS_ID_MAX];
    double *phase_deg;
    float *img;
} srv_tr_truth;
gs_status srv_tr_truth_load(const char *capdir, srv_tr_truth *t);
void srv_tr_truth_release(srv_tr_truth *t);
/* 1 when two (bulb, phase) are the same source (Eq. 15: the same bulb and BRF shift). */
int srv_tr_same_source(const char *bulb_a, double phase_a_deg, const char *bulb_b, double phase_b_deg);
/* The sum of the truth images of the source (bulb, phase) into out (W * H * B); *lights gets how
 * many lights it sums (0: none). */
gs_status srv_tr_truth_of(const srv_tr_truth *t, const char *bulb, double phase_deg, float *out,
                          int *lights);
/* The truth's bulb that an unmixed source (bulb, phase) stands for: the same bulb at the same
 * BRF shift, else a bulb of the same technology (DELIGHT d) at that shift (--sources auto may
 * recognise a similar model); NULL when none. */
const char *srv_tr_truth_match(const srv_tr_truth *t, const gs_delight *d, int grid_hz, int bands,
                               const char *bulb, double phase_deg);
/* ||est - truth||_F / ||truth||_F over the pixels whose every band of est is finite. */
double srv_tr_rel_error(const float *est, const float *truth, size_t P, int bands);
/* The normalized cross-correlation (Pearson) of a and b over the samples finite in both. */
double srv_tr_ncc(const float *a, const float *b, size_t n);
/* ============================================================ end of the light transport */

/* `gridsurvey bench pg` (survey/bench_pg.c), and the timing helpers of bench_db.c it shares:
 * `stats --by BY` on the SQLite db (or, db NULL, on conninfo's PostGIS database), and reading
 * every row of an SQL query on db. */
int srv_bench_pg(int argc, char **argv);
gs_status srv_bench_time_stats(srv_db *db, const char *conninfo, const char *by, double *sec);
gs_status srv_bench_time_view(srv_db *db, const char *sql, double *sec);

/* `gridsurvey bench accuracy` (survey/bench_accuracy.c); argv[0] is "accuracy". */
int srv_bench_accuracy(int argc, char **argv);
/* `gridsurvey bench render` (survey/bench_render.c). */
int srv_bench_render(int argc, char **argv);
/* `gridsurvey bench blobs` (survey/bench_blobs.c). */
int srv_bench_blobs(int argc, char **argv);
/* Its measurement: `frames` acquisitions (k = 0, 1, ...) of the scene with only the effects in
 * effects_mask (bits 1u << CAP_FX_*) that the scene lists, on `threads` threads
 * (cap_sim_set_threads), wall and CPU (the process's, all threads) time per frame. */
typedef struct {
    int frames;
    double seconds_per_frame;
    double cpu_seconds_per_frame;
    unsigned effects;            /* effects actually enabled */
    size_t lights, pixels;
} srv_render_time_result;
gs_status srv_render_time(const cap_scene *sc, unsigned effects_mask, int frames, int threads,
                          srv_render_time_result *out);

/* The Markdown phase-balance table of `gridsurvey stats` (cmd_stats.c) on stdout: groups,
 * counts, shares with Wilson intervals, six-phase columns when any group has such lights, and
 * the legend (o: the threshold and grouping; ungrouped: lights without a position). */
void srv_stats_print_table(const srv_phase_stats *g, size_t n, const srv_stats_opts *o, long ungrouped);

/* The statistics of stats.c over any source of detection rows (the SQLite database, or the
 * PostGIS one: pg_stats.c): the rows of one site consecutive (by survey first when
 * srv_stats_by_survey), each with its site (or -light id), survey, recognition and its site's
 * position (NaN when none). next sets *got = 0 at the end. */
typedef struct {
    int64_t id;
    const char *survey;
    srv_site_obs obs;
    double lat, lon;
} srv_stats_row;
typedef gs_status (*srv_stats_next)(void *ctx, srv_stats_row *row, int *got);
gs_status srv_stats_run(const srv_stats_opts *o, srv_stats_next next, void *ctx,
                        srv_phase_stats **groups, size_t *count, long *ungrouped);
int srv_stats_by_survey(const srv_stats_opts *o);
/* The centre of points, a cell grid's origin (stats.c): the mean latitude and the circular mean
 * longitude (NaN without a point). Zero it, add each point, get. */
typedef struct {
    double slat, ssin, scos;
    size_t n;
} srv_centre;
void srv_centre_add(srv_centre *c, double lat_deg, double lon_deg);
void srv_centre_get(const srv_centre *c, double *lat_deg, double *lon_deg);

/* Where a command's confirmation line goes: stderr when its output is "-" (stdout). */
FILE *srv_note_stream(const char *out);
/* A usage error of command cmd ("delight plot" for a subcommand): the one line "gridsurvey CMD:
 * MESSAGE (see gridsurvey help CMD)" on stderr; returns 2. */
int srv_usage_error(const char *cmd, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* A finite number option of cmd in [lo, hi] into *out: 1, or 0 after srv_usage_error. */
int srv_num_arg(const char *cmd, const char *opt, const char *arg, double lo, double hi, double *out);
/* As srv_num_arg, a bound excluded by open (SRV_OPEN_LO, SRV_OPEN_HI); an infinite bound is no
 * bound (the number stays finite). */
enum { SRV_OPEN_LO = 1, SRV_OPEN_HI = 2 };
int srv_num_arg_open(const char *cmd, const char *opt, const char *arg, double lo, double hi, int open, double *out);
/* --max-drift-windows of cmd: a number >= 0, or "none" (+inf: no frame left out for its drift),
 * into *out (rec_eq7_opts.max_drift_windows): 1, or 0 after srv_usage_error. */
int srv_drift_arg(const char *cmd, const char *arg, double *out);
/* An integer option of cmd in [lo, hi] (decimal digits only) into *out: 1, or 0 after
 * srv_usage_error. */
int srv_int_arg(const char *cmd, const char *opt, const char *arg, unsigned long long lo, unsigned long long hi,
                unsigned long long *out);
/* An option of cmd that is one of two integers, a or b, written as such (not 50.5, not 2): 1
 * into *out, or 0 after srv_usage_error. */
int srv_choice_arg(const char *cmd, const char *opt, const char *arg, int a, int b, int *out);
/* getopt's '?' in command cmd (getopt itself prints nothing: srv_main sets opterr = 0): the one
 * line naming the option (argv[optind - 1]) and the hint; returns 2. */
int srv_usage_hint(const char *cmd, char **argv);
/* The one-line usage error of -o given to a command that writes a directory (-o is always a
 * file; directories are --out-dir DIR, docs/reliability.md "Command-line habits"): returns 2. */
int srv_out_dir_hint(const char *cmd);
/* A failure of command cmd ("delight plot" for a subcommand): the one line "gridsurvey CMD:
 * DETAIL" (gs_detail() without a leading "CMD: " of its own; gs_strerror(s) when there is no
 * detail) on stderr; returns 1. */
int srv_error(const char *cmd, gs_status s);

/* An evaluation (survey/evaluate.c) as Markdown tables or a gridsurvey-evaluation/1 JSON
 * document (json != 0) on f. GS_EIO when f cannot be written. */
gs_status srv_eval_print(const srv_eval_report *r, const char *truth_path, int json, FILE *f);

/* ===================================== the survey database (db*.c), shared between its files */

#include <sqlite3.h>

/* Migration i takes the schema from version i to i + 1 (db_schema.c). */
typedef struct {
    const char *name;
    const char *const *sql;   /* NULL-terminated pieces (C99 limits literals to 4095 bytes) */
} srv_db_migration;
#define SRV_DB_MIGRATIONS SRV_DB_SCHEMA_VERSION
extern const srv_db_migration srv_db_migrations[SRV_DB_MIGRATIONS];

/* The prepared statements of a handle (their SQL in db_schema.c). */
enum {
    ST_ADD_DELIGHT, ST_GET_DELIGHT, ST_ADD_SURVEY, ST_GET_SURVEY, ST_ADD_STATION, ST_GET_STATION,
    ST_ADD_CAPTURE, ST_GET_CAPTURE, ST_ADD_FRAME, ST_ADD_LIGHT, ST_GET_LIGHT, ST_ADD_LOCATION,
    ST_ADD_FREQ, ST_DEL_CAPTURE, ST_FIND_CAPTURE, ST_COUNT
};
extern const char *const srv_db_stmt_sql[ST_COUNT];

struct srv_db {
    sqlite3 *db;
    char *path;
    int readonly;
    int created;                /* this handle created the file */
    int wal;                    /* this handle switched the file to WAL */
    int in_txn;
    int committing;             /* srv_db_commit's COMMIT is running (refuse_stray_commit) */
    sqlite3_stmt *st[ST_COUNT];
};

/* Helpers of db.c for db_rows.c: failures with the connection's message, the UTC time,
 * statements (prepared once per handle), binding (NaN and NULL text as SQL NULL), stepping,
 * and the transaction rules (writes need a transaction; auto_begin/auto_end wrap one call). */
gs_status srv_dbi_fail(srv_db *db, const char *what);
/* GS_ESQL "the transaction was lost" when the handle holds a transaction that SQLite has rolled
 * back by itself (out of memory, disk full), else GS_OK. */
gs_status srv_dbi_lost(srv_db *db, const char *what);
void srv_dbi_utc_now(char buf[32]);
gs_status srv_dbi_exec(srv_db *db, const char *sql, const char *what);
gs_status srv_dbi_stmt(srv_db *db, int which, sqlite3_stmt **out);
void srv_dbi_bind_real(sqlite3_stmt *q, int i, double v);
/* Column i as a double, NaN when NULL. */
double srv_dbi_col_real(sqlite3_stmt *q, int i);
/* A station's camera from its stored columns, SRV_SQL_CAMERA_COLS from column first on (NULL
 * numbers NaN; NULL distortion and refraction 0, none); the image size is not read (0). */
#define SRV_SQL_CAMERA_COLS(st)                                                                   \
    st ".lat_deg, " st ".lon_deg, " st ".height_m, " st ".heading_deg, " st ".pitch_deg, " st     \
    ".roll_deg, " st ".focal_px, " st ".cx_px, " st ".cy_px, " st ".k1, " st ".k2, " st ".refraction_k"
void srv_dbi_col_camera(sqlite3_stmt *q, int first, gis_camera *c);
void srv_dbi_bind_text(sqlite3_stmt *q, int i, const char *s);
void srv_dbi_bind_int_or_null(sqlite3_stmt *q, int i, int64_t v, int64_t none);
gs_status srv_dbi_step_returning(srv_db *db, sqlite3_stmt *q, int64_t *id, int *inserted, const char *what);
gs_status srv_dbi_step_id(srv_db *db, sqlite3_stmt *q, int64_t *id, const char *what);
gs_status srv_dbi_step_done(srv_db *db, sqlite3_stmt *q, const char *what);
gs_status srv_dbi_writable(srv_db *db);
gs_status srv_dbi_need_txn(srv_db *db, const char *what);
gs_status srv_dbi_auto_begin(srv_db *db, int *began);
gs_status srv_dbi_auto_end(srv_db *db, int began, gs_status s);
/* Associate one capture's new detections (sites.c; called inside its transaction). */
gs_status srv_dbi_associate_capture(srv_db *db, int64_t capture_id, long *created, long *joined, long *merged);
/* Fill o from the 8 columns bulb_id, technology, phase_deg, phase_sigma_deg, confidence,
 * bulb_confidence, phase_confidence, SRV_SQL_BULB_LABELS starting at column first. */
void srv_site_obs_from_row(sqlite3_stmt *q, int first, srv_site_obs *o);
/* A detection's bulb label count M (srv_site_obs.bulbs) in SQL over its capture c and DELIGHT
 * version dv (SQLite and PostgreSQL): the candidates its recognition used, or for a capture
 * stored before schema 5 (NULL) all of the DELIGHT's entries. */
#define SRV_SQL_BULB_LABELS "coalesce(c.candidate_bulbs, dv.bulbs)"
/* The camera pose key of a capture's station st (LEFT JOINed): its position, orientation and
 * focal length as text, 'none' without a station (one fixed, unknown camera). Stored in
 * light_sites.pose_key and site_views.pose_key: never change it (docs/survey-db.md). */
#define SRV_SQL_POSE_KEY(st)                                                                       \
    "CASE WHEN " st ".id IS NULL THEN 'none' ELSE printf('%.7f,%.7f,%.2f,%.3f,%.3f,%.3f,%.2f', " st \
    ".lat_deg, " st ".lon_deg, " st ".height_m, " st ".heading_deg, " st ".pitch_deg, " st            \
    ".roll_deg, " st ".focal_px) END"
/* The rows of site_views (schema 6) of the sites whose detections sd pass `where`: per site and
 * camera pose, its detections' mean pixel and count (sites.c; migration 6 fills them). */
#define SRV_SQL_SITE_VIEWS(where)                                                                  \
    "INSERT INTO site_views(site_id, pose_key, x_px, y_px, detections) SELECT sd.site_id, "      \
    SRV_SQL_POSE_KEY("st") ", avg(l.x_px), avg(l.y_px), count(*) FROM site_detections sd "       \
    "JOIN lights l ON l.id = sd.light_id JOIN captures c ON c.id = sd.capture_id "                \
    "LEFT JOIN stations st ON st.id = c.station_id " where " GROUP BY 1, 2"
/* ====================================================================== end of the database */

/* ============================ the shared PostGIS database (pg*.c), shared between its files */

#include <libpq-fe.h>

#define SRV_PG_LOCK_KEY "4747534442"   /* pg_advisory_xact_lock key of the migrations */
/* Connect and set search_path = gridsurvey, public; a writer applies the missing migrations
 * (pg_schema.c), a reader needs the schema at this version. The one-line failures name
 * PostgreSQL and what was being done. */
gs_status srv_pgi_connect(const char *conninfo, int writer, PGconn **out);
gs_status srv_pgi_fail(PGconn *c, const PGresult *r, const char *what);
gs_status srv_pgi_exec(PGconn *c, const char *sql, const char *what);
/* PQexecParams with n text parameters (NULL = SQL NULL), text results. */
PGresult *srv_pgi_query(PGconn *c, const char *sql, int n, const char *const *params);
/* 1 when a failed transaction may simply be retried (deadlock, serialization failure). */
int srv_pgi_retryable(const PGresult *r);
/* ====================================================================== end of PostGIS */

/* ============================= `bench accuracy` (bench_accuracy*.c), shared between its files */

#define NBINS 5
extern const double srv_acc_bin_edges[NBINS + 1];

/* Reliability bins of one reported confidence: lights matched to the truth, the sum of their
 * confidences and how many are right, per bin of srv_acc_bin_edges; ece the expected
 * calibration error (NaN: no light). */
typedef struct {
    double n[NBINS], conf[NBINS], right[NBINS];
    double ece;
} srv_acc_bins;

typedef struct {
    /* the setting */
    int hard, K, C, hdr, locked, continuous;   /* hard: 0 metro, 1 metro_hard, 2 metro_clear */
    int nominal_period;       /* free running with the scene's nominal half period (0: measured
                               * before each exposure, as the firmware does) */
    double max_drift_windows; /* rec_eq7_opts.max_drift_windows of its Eq. 7 (+inf: none;
                               * REC_DRIFT_AUTO: the default) */
    /* results */
    int ok;
    char err[512];
    long acquisitions;
    double delta_s, readout_cycles;
    double exposure_s, readout_s, capture_s;
    double compute_s;
    srv_eval_report ev;
    double snr_p90;
    double drift_windows;     /* gs_capture_window_drift of its capture, windows (0 locked) */
    int frames_kept;          /* its frames that drifted at most max_drift_windows */
    srv_acc_bins cal;         /* the answered lights by confidence, right = bulb and phase */
    srv_acc_bins phase_cal;   /* the lights with a phase by phase_confidence, right = the phase */
    long oracle_n;                 /* lights of the oracle subset matched to the truth */
    double ours_sub, oracle_sub;   /* right bulb and phase / matched, on that subset */
} srv_acc_point;

extern const char *const srv_acc_scene_names[3];

typedef struct {
    int x0, y0, w, h;       /* the window of the scene's image rendered */
} srv_acc_crop;
/* The report (bench_accuracy_report.c): the points as CSV, the accuracy-vs-time and calibration
 * plots (PNG), and the Markdown page. */
const char *srv_acc_ph_name(const srv_acc_point *p);
/* The point's window period: "locked", or free running "measured" or "nominal". */
const char *srv_acc_period_name(const srv_acc_point *p);
/* Its max_drift_windows as recognize --max-drift-windows takes it ("none" for +inf, "auto"), in buf. */
const char *srv_acc_threshold_name(const srv_acc_point *p, char *buf, size_t n);
gs_status srv_acc_write_csv(const char *path, const srv_acc_point *pts, size_t np);
/* The reliability bins of every point (pair and phase), one row per non-empty bin. */
gs_status srv_acc_write_bins_csv(const char *path, const srv_acc_point *pts, size_t np);
/* A rate axis over v[0..n) (rates in [0, 1]; NaN skipped): from the smallest rounded down to a
 * tenth (0 when that is below 0.5, or no value; at most 0.9) to 1, which stays in view, and 3 %
 * of that span beyond both ends, so a value at either end is drawn inside the frame, not on it;
 * *tick the major tick step, the largest of 0.2, 0.1, 0.05, 0.02 giving at least 4 ticks. */
void srv_acc_rate_axis(const double *v, size_t n, double *lo, double *hi, double *tick);
void srv_acc_plot_accuracy(const char *path, const srv_acc_point *pts, size_t np, const int *Ks, int nK);
void srv_acc_plot_calibration(const char *path, const srv_acc_point *pts, size_t np);
/* The --drift-sweep page: free-running points by period, C and Eq. 7's drift threshold. */
gs_status srv_acc_write_drift_doc(const char *path, const char *out, const char *base, const srv_acc_crop *cr,
                                  int quick, const srv_acc_point *pts, size_t np, double wall);
gs_status srv_acc_write_doc(const char *path, const char *out, const char *base, const srv_acc_crop *cr, int quick, const srv_acc_point *pts, size_t np, double wall, const int *Ks, int nK);
/* Store rows[0..n) as a capture of the point's survey under key, and evaluate that capture
 * (bench_accuracy.c). */
gs_status srv_acc_eval_subset(srv_db *db, int64_t survey_id, const char *key, const srv_light_row *rows,
                              size_t n, const char *truth, srv_eval_report *ev);
/* The oracle's ceiling on up to n_oracle unflagged lights of job j (bench_oracle.c): fills
 * p->oracle_n, ours_sub, oracle_sub (NaN without a subset); sub is scratch of j's light count. */
gs_status srv_acc_oracle(srv_db *db, const srv_run_report *rr, const srv_job *j,
                         const srv_light_row *rows, double transformer, double max_drift_windows, int n_oracle,
                         srv_light_row *sub, srv_acc_point *p);
/* ====================================================================== end of bench accuracy */

#endif
