/* pg_push.c - `gridsurvey push`: a survey database (SQLite) into the shared PostGIS database
 * (docs/postgis.md). Order: the DELIGHT versions, surveys and stations (get or add by their
 * natural keys), then the captures, each with its frames, frequency log, lights and locations in
 * the transaction that inserts its captures row (whole captures, batch_lights lights per
 * transaction), then the light sites and their detections (upserted, batch_lights sites per
 * transaction), then the areas. A captures row that is already there (ON CONFLICT) was
 * committed with all its rows by an earlier push, from this station or another, and is skipped:
 * re-pushing adds nothing, an interrupted push resumes at the first missing capture, and
 * concurrent pushers of the same capture wait on its unique key and then skip it. Deadlocks
 * between pushers (PostgreSQL aborts one of them) are retried. Rows are streamed with COPY;
 * doubles are written with 17 significant digits, so they arrive bit-exact. */
#include "survey/internal.h"

#include <jansson.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

void srv_push_opts_default(srv_push_opts *o)
{
    memset(o, 0, sizeof *o);
    o->batch_lights = 20000;
}

/* SQLite id -> PostgreSQL id, appended in increasing SQLite id order. */
typedef struct {
    int64_t *from, *to;
    size_t n, cap;
} id_map;

static gs_status map_put(id_map *m, int64_t from, int64_t to)
{
    if (m->n && m->from[m->n - 1] == from) {   /* a retried transaction sets it again */
        m->to[m->n - 1] = to;
        return GS_OK;
    }
    if (m->n == m->cap) {
        size_t nc = m->cap ? 2 * m->cap : 256;
        int64_t *f = realloc(m->from, nc * sizeof *f);
        if (f) m->from = f;
        int64_t *t = f ? realloc(m->to, nc * sizeof *t) : NULL;
        if (!t) return gs_fail(GS_ENOMEM, "push: out of memory");
        m->to = t;
        m->cap = nc;
    }
    m->from[m->n] = from;
    m->to[m->n++] = to;
    return GS_OK;
}

static int map_get(const id_map *m, int64_t from, int64_t *to)
{
    size_t lo = 0, hi = m->n;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (m->from[mid] < from) lo = mid + 1;
        else hi = mid;
    }
    if (lo == m->n || m->from[lo] != from) return 0;
    *to = m->to[lo];
    return 1;
}

static void map_free(id_map *m)
{
    free(m->from);
    free(m->to);
}

typedef struct {
    PGconn *c;
    sqlite3 *h;
    const char *path;
    int retry;                  /* the last failure may be retried */
    id_map delight, survey, station, capture;
    char *buf;                  /* a COPY line */
    size_t len, cap;
} push_ctx;

/* Check r's status (then cleared); records whether a failure is retryable. */
static gs_status res(push_ctx *x, PGresult *r, ExecStatusType want, const char *what)
{
    gs_status s = GS_OK;
    if (PQresultStatus(r) != want) {
        x->retry = srv_pgi_retryable(r);
        s = srv_pgi_fail(x->c, r, what);
    }
    PQclear(r);
    return s;
}

static gs_status lite_fail(push_ctx *x, const char *what)
{
    return gs_fail(GS_ESQL, "%s: %s: %s", x->path, what, sqlite3_errmsg(x->h));
}

static gs_status put(push_ctx *x, const char *s, size_t n)
{
    if (x->len + n + 1 > x->cap) {
        size_t nc = x->cap ? x->cap : 4096;
        while (nc < x->len + n + 1) nc *= 2;
        char *b = realloc(x->buf, nc);
        if (!b) return gs_fail(GS_ENOMEM, "push: out of memory");
        x->buf = b;
        x->cap = nc;
    }
    memcpy(x->buf + x->len, s, n);
    x->len += n;
    return GS_OK;
}

/* Column i of q in COPY text format (NULL = \N; text escaped; doubles bit-exact; ids through
 * map when given). */
static gs_status put_value(push_ctx *x, sqlite3_stmt *q, int i, const id_map *map)
{
    char num[40];
    switch (sqlite3_column_type(q, i)) {
    case SQLITE_NULL: return put(x, "\\N", 2);
    case SQLITE_INTEGER: {
        int64_t v = sqlite3_column_int64(q, i);
        if (map && !map_get(map, v, &v))
            return gs_fail(GS_EFORMAT, "%s: %s = %lld: no such row pushed", x->path,
                           sqlite3_column_name(q, i), (long long)v);
        return put(x, num, (size_t)snprintf(num, sizeof num, "%lld", (long long)v));
    }
    case SQLITE_FLOAT: {
        double v = sqlite3_column_double(q, i);
        if (isnan(v)) return put(x, "NaN", 3);
        if (isinf(v)) return v > 0 ? put(x, "Infinity", 8) : put(x, "-Infinity", 9);
        return put(x, num, (size_t)snprintf(num, sizeof num, "%.17g", v));
    }
    default: {
        const unsigned char *t = sqlite3_column_text(q, i);
        int n = sqlite3_column_bytes(q, i);
        for (int k = 0; k < n; k++) {
            char e[2] = {'\\', 0};
            switch (t[k]) {
            case '\\': e[1] = '\\'; break;
            case '\t': e[1] = 't'; break;
            case '\n': e[1] = 'n'; break;
            case '\r': e[1] = 'r'; break;
            default: break;
            }
            gs_status s = e[1] ? put(x, e, 2) : put(x, (const char *)t + k, 1);
            if (s != GS_OK) return s;
        }
        return GS_OK;
    }
    }
}

/* COPY the rows of q (bound by the caller) into copy_sql's table: each line is prefix (may be
 * NULL) and q's columns, column i through maps[i] when maps is given. *rows counts them. */
static gs_status copy_rows(push_ctx *x, const char *copy_sql, const char *prefix, sqlite3_stmt *q,
                           const id_map *const *maps, size_t *rows)
{
    gs_status s = res(x, PQexec(x->c, copy_sql), PGRES_COPY_IN, copy_sql);
    if (s != GS_OK) return s;
    int ncol = sqlite3_column_count(q), rc;
    size_t n = 0;
    while (s == GS_OK && (rc = sqlite3_step(q)) == SQLITE_ROW) {
        x->len = 0;
        if (prefix) s = put(x, prefix, strlen(prefix));
        for (int i = 0; i < ncol && s == GS_OK; i++) {
            if (i) s = put(x, "\t", 1);
            if (s == GS_OK) s = put_value(x, q, i, maps ? maps[i] : NULL);
        }
        if (s == GS_OK) s = put(x, "\n", 1);
        if (s == GS_OK && PQputCopyData(x->c, x->buf, (int)x->len) != 1)
            s = srv_pgi_fail(x->c, NULL, "COPY");
        n++;
    }
    if (s == GS_OK && rc != SQLITE_DONE) s = lite_fail(x, "reading rows to push");
    sqlite3_reset(q);
    if (PQputCopyEnd(x->c, s == GS_OK ? NULL : "push failed") != 1 && s == GS_OK)
        s = srv_pgi_fail(x->c, NULL, "COPY");
    PGresult *r;
    while ((r = PQgetResult(x->c))) {
        if (s == GS_OK) s = res(x, r, PGRES_COMMAND_OK, copy_sql);
        else PQclear(r);   /* keep the first failure's detail */
    }
    if (rows) *rows = n;
    return s;
}

/* Bind q's row i as text parameters (NULL as SQL NULL; ids through maps). */
static gs_status row_params(push_ctx *x, sqlite3_stmt *q, const id_map *const *maps, int n,
                            char (*store)[48], const char **params)
{
    for (int i = 0; i < n; i++) {
        int t = sqlite3_column_type(q, i);
        if (t == SQLITE_NULL) {
            params[i] = NULL;
        } else if (t == SQLITE_INTEGER || (maps && maps[i])) {
            int64_t v = sqlite3_column_int64(q, i);
            if (maps && maps[i] && !map_get(maps[i], v, &v))
                return gs_fail(GS_EFORMAT, "%s: %s = %lld: no such row pushed", x->path,
                               sqlite3_column_name(q, i), (long long)v);
            snprintf(store[i], sizeof store[i], "%lld", (long long)v);
            params[i] = store[i];
        } else if (t == SQLITE_FLOAT) {
            snprintf(store[i], sizeof store[i], "%.17g", sqlite3_column_double(q, i));
            params[i] = store[i];
        } else {
            params[i] = (const char *)sqlite3_column_text(q, i);
        }
    }
    return GS_OK;
}

/* Insert-or-get: ins (ON CONFLICT DO NOTHING RETURNING id) with q's n columns, else get with
 * its key columns (the parameters key[0..nkey)); a separate statement, so that in READ
 * COMMITTED it sees a row another pusher committed while ins waited for it. */
static gs_status get_or_add(push_ctx *x, sqlite3_stmt *q, const id_map *const *maps, int n,
                            const char *ins, const char *get, const int *key, int nkey,
                            int64_t *id, int *inserted, const char *what)
{
    char store[32][48];
    const char *p[32], *kp[4];
    gs_status s = row_params(x, q, maps, n, store, p);
    if (s != GS_OK) return s;
    PGresult *r = srv_pgi_query(x->c, ins, n, p);
    if (PQresultStatus(r) != PGRES_TUPLES_OK) return res(x, r, PGRES_TUPLES_OK, what);
    *inserted = PQntuples(r) == 1;
    if (*inserted) *id = strtoll(PQgetvalue(r, 0, 0), NULL, 10);
    PQclear(r);
    if (*inserted) return GS_OK;
    for (int i = 0; i < nkey; i++) kp[i] = p[key[i]];
    r = srv_pgi_query(x->c, get, nkey, kp);
    if (PQresultStatus(r) != PGRES_TUPLES_OK || PQntuples(r) != 1) {
        if (PQresultStatus(r) == PGRES_TUPLES_OK) {
            PQclear(r);
            return gs_fail(GS_ESQL, "PostgreSQL: %s: the row vanished", what);
        }
        return res(x, r, PGRES_TUPLES_OK, what);
    }
    *id = strtoll(PQgetvalue(r, 0, 0), NULL, 10);
    PQclear(r);
    return GS_OK;
}

/* ------------------------------------------------------------------ the rows */

static const char delight_lite[] =
    "SELECT sha256, generator, source, bulbs, added_utc, id FROM delight_versions ORDER BY id";
static const char delight_ins[] =
    "INSERT INTO delight_versions(sha256, generator, source, bulbs, added_utc) "
    "VALUES ($1, $2, $3, $4, $5) ON CONFLICT DO NOTHING RETURNING id";
static const char delight_get[] = "SELECT id FROM delight_versions WHERE sha256 = $1 AND generator = $2";

static const char survey_lite[] =
    "SELECT name, city, grid_hz, started_utc, notes, created_utc, id FROM surveys ORDER BY id";
static const char survey_ins[] =
    "INSERT INTO surveys(name, city, grid_hz, started_utc, notes, created_utc) "
    "VALUES ($1, $2, $3, $4, $5, $6) ON CONFLICT DO NOTHING RETURNING id";
static const char survey_get[] = "SELECT id FROM surveys WHERE name = $1";

#define STATION_COLS "survey_id, name, lat_deg, lon_deg, height_m, heading_deg, pitch_deg, " \
    "roll_deg, sigma_heading_deg, sigma_pitch_deg, sigma_roll_deg, focal_px, cx_px, cy_px, k1, " \
    "k2, width_px, height_px, refraction_k, sigma_px, time_utc"
static const char station_lite[] = "SELECT " STATION_COLS ", id FROM stations ORDER BY id";
static const char station_ins[] =
    "INSERT INTO stations(" STATION_COLS ") VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, "
    "$11, $12, $13, $14, $15, $16, $17, $18, $19, $20, $21) ON CONFLICT DO NOTHING RETURNING id";
static const char station_get[] = "SELECT id FROM stations WHERE survey_id = $1 AND name = $2";

#define CAPTURE_COLS "survey_id, station_id, delight_id, capture_key, path, utc, grid_hz, K, " \
    "bands, width_px, height_px, locked, mean_frequency_hz, sigma_frequency_hz, light_count, " \
    "frame_count, frequency_count, ingested_utc, candidate_bulbs"
static const char capture_ins[] =
    "INSERT INTO captures(" CAPTURE_COLS ") VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, "
    "$11, $12, $13, $14, $15, $16, $17, $18, $19) ON CONFLICT DO NOTHING RETURNING id";
static const char capture_get[] = "SELECT id FROM captures WHERE survey_id = $1 AND capture_key = $2";

#define LIGHT_COLS "light_index, x_px, y_px, area_px, peak_dn, saturated_px, blob_flags, " \
    "brightness, snr, chi2, dof, p_value, bulb_id, technology, phase_deg, phase_fit_deg, " \
    "phase_sigma_deg, confidence, bulb_confidence, phase_confidence, runner_bulb_id, " \
    "runner_phase_deg, runner_confidence, match_flags"
#define LOCATION_COLS "method, lat_deg, lon_deg, height_m, semi_major_m, semi_minor_m, " \
    "azimuth_deg, range_m, flags"
static const char *const part_lite[4] = {
    "SELECT " LIGHT_COLS " FROM lights WHERE capture_id = ?1 ORDER BY light_index",
    "SELECT l.light_index, loc.method, loc.lat_deg, loc.lon_deg, loc.height_m, loc.semi_major_m, "
    "loc.semi_minor_m, loc.azimuth_deg, loc.range_m, loc.flags FROM locations loc "
    "JOIN lights l ON l.id = loc.light_id WHERE l.capture_id = ?1 ORDER BY l.light_index",
    "SELECT k, file, cycles, hdr_map FROM frames WHERE capture_id = ?1 ORDER BY k",
    ("SELECT seq, t_s, window_s, frequency_hz, sigma_hz FROM grid_frequency WHERE capture_id = ?1 "
     "ORDER BY seq"),   /* (parenthesised: clang's -Wstring-concatenation) */
};
static const char *const part_copy[4] = {
    "COPY lights(capture_id, " LIGHT_COLS ") FROM STDIN",
    "COPY locations(capture_id, light_index, " LOCATION_COLS ") FROM STDIN",
    "COPY frames(capture_id, k, file, cycles, hdr_map) FROM STDIN",
    "COPY grid_frequency(capture_id, seq, t_s, window_s, frequency_hz, sigma_hz) FROM STDIN",
};

#define SITE_COLS "lat_deg, lon_deg, height_m, semi_major_m, semi_minor_m, azimuth_deg, " \
    "pose_key, x_px, y_px, detections, captures, bulb_id, technology, phase_deg, " \
    "phase_sigma_deg, confidence, bulb_confidence, phase_confidence"
#define SITE_COLS_T \
    "t.lat_deg, t.lon_deg, t.height_m, t.semi_major_m, t.semi_minor_m, t.azimuth_deg, " \
    "t.pose_key, t.x_px, t.y_px, t.detections, t.captures, t.bulb_id, t.technology, " \
    "t.phase_deg, t.phase_sigma_deg, t.confidence, t.bulb_confidence, t.phase_confidence"
#define SITE_COLS_X \
    "EXCLUDED.lat_deg, EXCLUDED.lon_deg, EXCLUDED.height_m, EXCLUDED.semi_major_m, " \
    "EXCLUDED.semi_minor_m, EXCLUDED.azimuth_deg, EXCLUDED.pose_key, EXCLUDED.x_px, " \
    "EXCLUDED.y_px, EXCLUDED.detections, EXCLUDED.captures, EXCLUDED.bulb_id, " \
    "EXCLUDED.technology, EXCLUDED.phase_deg, EXCLUDED.phase_sigma_deg, EXCLUDED.confidence, " \
    "EXCLUDED.bulb_confidence, EXCLUDED.phase_confidence"
/* a site's founder: its detection of lowest id */
#define FOUNDER(site) "(SELECT min(light_id) FROM site_detections WHERE site_id = " site ")"
static const char site_lite[] =
    "SELECT ls.id, l.capture_id, l.light_index, ls.lat_deg, ls.lon_deg, ls.height_m, "
    "ls.semi_major_m, ls.semi_minor_m, ls.azimuth_deg, ls.pose_key, ls.x_px, ls.y_px, "
    "ls.detections, ls.captures, ls.bulb_id, ls.technology, ls.phase_deg, ls.phase_sigma_deg, "
    "ls.confidence, ls.bulb_confidence, ls.phase_confidence FROM light_sites ls "
    "JOIN lights l ON l.id = " FOUNDER("ls.id") " WHERE ls.id > ?1 ORDER BY ls.id LIMIT ?2";
static const char det_lite[] =
    "SELECT l.capture_id, l.light_index, f.capture_id, f.light_index, sd.d2 "
    "FROM site_detections sd JOIN lights l ON l.id = sd.light_id "
    "JOIN lights f ON f.id = " FOUNDER("sd.site_id") " "
    "WHERE sd.site_id > ?1 AND sd.site_id <= ?2 ORDER BY sd.light_id";
static const char stage_sql[] =
    "CREATE TEMP TABLE stage_sites(seq bigint, origin_capture_id bigint, origin_light_index integer, "
    "lat_deg float8, lon_deg float8, height_m float8, semi_major_m float8, semi_minor_m float8, "
    "azimuth_deg float8, pose_key text, x_px float8, y_px float8, detections integer, "
    "captures integer, bulb_id text, technology text, phase_deg float8, phase_sigma_deg float8, "
    "confidence float8, bulb_confidence float8, phase_confidence float8) ON COMMIT DELETE ROWS;\n"
    "CREATE TEMP TABLE stage_detections(capture_id bigint, light_index integer, "
    "origin_capture_id bigint, origin_light_index integer, d2 float8) ON COMMIT DELETE ROWS;\n"
    "CREATE TEMP TABLE stage_moved(site_id bigint) ON COMMIT DELETE ROWS";
/* the sites the staged detections belong to before their upsert, and those of them the upsert
 * left without detections (a site the file merged into another: sites.c), deleted in the same
 * transaction, so no push, killed or not, leaves an empty site */
static const char moved_sql[] =
    "INSERT INTO stage_moved SELECT t.site_id FROM site_detections t JOIN stage_detections d "
    "ON t.capture_id = d.capture_id AND t.light_index = d.light_index";
static const char drop_emptied_sql[] =
    "DELETE FROM light_sites s WHERE s.id IN (SELECT site_id FROM stage_moved) "
    "AND NOT EXISTS (SELECT 1 FROM site_detections d WHERE d.site_id = s.id)";
static const char site_upsert[] =
    "INSERT INTO light_sites AS t (origin_capture_id, origin_light_index, " SITE_COLS ") "
    "SELECT origin_capture_id, origin_light_index, " SITE_COLS " FROM stage_sites ORDER BY seq "
    "ON CONFLICT (origin_capture_id, origin_light_index) DO UPDATE SET (" SITE_COLS ") = (" SITE_COLS_X ") "
    "WHERE (" SITE_COLS_T ") IS DISTINCT FROM (" SITE_COLS_X ")";
static const char det_upsert[] =
    "INSERT INTO site_detections AS t (capture_id, light_index, site_id, d2) "
    "SELECT d.capture_id, d.light_index, s.id, d.d2 FROM stage_detections d "
    "JOIN light_sites s ON s.origin_capture_id = d.origin_capture_id "
    "AND s.origin_light_index = d.origin_light_index "
    "ON CONFLICT (capture_id, light_index) DO UPDATE SET site_id = EXCLUDED.site_id, d2 = EXCLUDED.d2 "
    "WHERE (t.site_id, t.d2) IS DISTINCT FROM (EXCLUDED.site_id, EXCLUDED.d2)";

/* ------------------------------------------------------------------ transactions */

/* One transaction of fn, retried (up to 20 times) when PostgreSQL aborted it for a deadlock
 * or a serialization failure. */
typedef gs_status (*txn_fn)(push_ctx *x, void *arg);
static gs_status in_txn(push_ctx *x, txn_fn fn, void *arg, srv_push_report *r)
{
    for (int attempt = 0;; attempt++) {
        x->retry = 0;
        gs_status s = res(x, PQexec(x->c, "BEGIN"), PGRES_COMMAND_OK, "BEGIN");
        if (s == GS_OK) s = fn(x, arg);
        if (s == GS_OK) s = res(x, PQexec(x->c, "COMMIT"), PGRES_COMMAND_OK, "COMMIT");
        if (s == GS_OK) return GS_OK;
        PQclear(PQexec(x->c, "ROLLBACK"));
        if (!x->retry || attempt == 20) return s;
        r->retries++;
    }
}

/* The DELIGHT versions, surveys and stations (get or add). */
static gs_status push_setup(push_ctx *x, void *arg)
{
    (void)arg;
    static const int dkey[] = {0, 1}, skey[] = {0}, stkey[] = {0, 1};
    const struct {
        const char *lite, *ins, *get, *what;
        const int *key;
        int nkey;
        id_map *map;
    } t[3] = {
        {delight_lite, delight_ins, delight_get, "pushing a DELIGHT version", dkey, 2, &x->delight},
        {survey_lite, survey_ins, survey_get, "pushing a survey", skey, 1, &x->survey},
        {station_lite, station_ins, station_get, "pushing a station", stkey, 2, &x->station},
    };
    gs_status s = GS_OK;
    for (int k = 0; k < 3 && s == GS_OK; k++) {
        t[k].map->n = 0;
        sqlite3_stmt *q;
        if (sqlite3_prepare_v2(x->h, t[k].lite, -1, &q, NULL) != SQLITE_OK) return lite_fail(x, t[k].what);
        int n = sqlite3_column_count(q) - 1, rc;   /* the last column is the SQLite id */
        const id_map *maps[32] = {k == 2 ? &x->survey : NULL};
        while (s == GS_OK && (rc = sqlite3_step(q)) == SQLITE_ROW) {
            int64_t id;
            int ins;
            s = get_or_add(x, q, maps, n, t[k].ins, t[k].get, t[k].key, t[k].nkey, &id, &ins, t[k].what);
            if (s == GS_OK) s = map_put(t[k].map, sqlite3_column_int64(q, n), id);
        }
        if (s == GS_OK && rc != SQLITE_DONE) s = lite_fail(x, t[k].what);
        sqlite3_finalize(q);
    }
    return s;
}

/* A batch of captures [first, end) of the list q (stepped by the caller). */
typedef struct {
    sqlite3_stmt *list, *part[4];
    size_t pushed, lights;       /* this batch's */
    size_t limit;                /* lights per batch */
    int more;                    /* the list has more rows after this batch, from next_id */
    int64_t first_id, next_id;   /* the batch's first capture (SQLite id), the next batch's */
    size_t mapped;               /* captures mapped before this batch */
} capture_batch;

static gs_status push_captures(push_ctx *x, void *arg)
{
    capture_batch *b = arg;
    b->pushed = b->lights = 0;
    x->capture.n = b->mapped;   /* a retried batch maps its captures again */
    sqlite3_reset(b->list);
    sqlite3_bind_int64(b->list, 1, b->first_id);
    const id_map *maps[20] = {&x->survey, &x->station, &x->delight};
    int rc;
    gs_status s = GS_OK;
    size_t in_batch = 0;
    while (s == GS_OK && (rc = sqlite3_step(b->list)) == SQLITE_ROW) {
        int64_t lite_id = sqlite3_column_int64(b->list, 19);
        if (in_batch >= b->limit) {   /* the next batch starts here */
            b->next_id = lite_id;
            b->more = 1;
            return GS_OK;
        }
        int64_t id;
        int ins;
        static const int key[] = {0, 3};
        s = get_or_add(x, b->list, maps, 19, capture_ins, capture_get, key, 2, &id, &ins, "pushing a capture");
        if (s == GS_OK) s = map_put(&x->capture, lite_id, id);
        in_batch += (size_t)sqlite3_column_int64(b->list, 14) + 1;
        if (s != GS_OK || !ins) continue;
        char prefix[32];
        snprintf(prefix, sizeof prefix, "%lld\t", (long long)id);
        for (int k = 0; k < 4 && s == GS_OK; k++) {
            size_t n;
            sqlite3_bind_int64(b->part[k], 1, lite_id);
            s = copy_rows(x, part_copy[k], prefix, b->part[k], NULL, &n);
            if (k == 0) b->lights += n;
        }
        b->pushed++;
    }
    if (s == GS_OK && rc != SQLITE_DONE) s = lite_fail(x, "reading the captures");
    b->more = 0;
    return s;
}

typedef struct {
    sqlite3_stmt *sites, *dets;
    int64_t after, last;         /* sites (after, last] */
    size_t limit, n, written;
} site_batch;

static gs_status push_sites(push_ctx *x, void *arg)
{
    site_batch *b = arg;
    const id_map *smaps[21] = {NULL, &x->capture}, *dmaps[5] = {&x->capture, NULL, &x->capture};
    sqlite3_bind_int64(b->sites, 1, b->after);
    sqlite3_bind_int64(b->sites, 2, (int64_t)b->limit);
    gs_status s = copy_rows(x, "COPY stage_sites FROM STDIN", NULL, b->sites, smaps, &b->n);
    if (s != GS_OK || !b->n) return s;
    PGresult *r = PQexec(x->c, "SELECT max(seq) FROM stage_sites");
    if (PQresultStatus(r) == PGRES_TUPLES_OK) b->last = strtoll(PQgetvalue(r, 0, 0), NULL, 10);
    if ((s = res(x, r, PGRES_TUPLES_OK, "staging sites")) != GS_OK) return s;
    r = PQexec(x->c, site_upsert);
    if (PQresultStatus(r) == PGRES_COMMAND_OK) b->written = strtoull(PQcmdTuples(r), NULL, 10);
    if ((s = res(x, r, PGRES_COMMAND_OK, "upserting light sites")) != GS_OK) return s;
    sqlite3_bind_int64(b->dets, 1, b->after);
    sqlite3_bind_int64(b->dets, 2, b->last);
    if ((s = copy_rows(x, "COPY stage_detections FROM STDIN", NULL, b->dets, dmaps, NULL)) != GS_OK ||
        (s = res(x, PQexec(x->c, moved_sql), PGRES_COMMAND_OK, "upserting site detections")) != GS_OK ||
        (s = res(x, PQexec(x->c, det_upsert), PGRES_COMMAND_OK, "upserting site detections")) != GS_OK)
        return s;
    r = PQexec(x->c, drop_emptied_sql);
    if (PQresultStatus(r) == PGRES_COMMAND_OK) b->written += strtoull(PQcmdTuples(r), NULL, 10);
    return res(x, r, PGRES_COMMAND_OK, "deleting merged light sites");
}

/* ------------------------------------------------------------------ areas */

typedef struct {
    const srv_push_opts *o;
    const srv_areas *areas;
    json_t *features;
    size_t n;
} area_load;

static gs_status push_areas(push_ctx *x, void *arg)
{
    area_load *a = arg;
    gs_status s = GS_OK;
    for (size_t i = 0; i < a->n && s == GS_OK; i++) {
        json_t *g = json_object_get(json_array_get(a->features, i), "geometry");
        char *gj = json_dumps(g, JSON_COMPACT), ord[24];
        if (!gj) return gs_fail(GS_ENOMEM, "push: out of memory");
        snprintf(ord, sizeof ord, "%zu", i);
        const char *p[] = {a->o->areas_field, ord, srv_areas_label(a->areas, i), gj};
        s = res(x, srv_pgi_query(x->c,
                    "INSERT INTO areas AS t (layer, ord, label, geom) VALUES ($1, $2, $3, "
                    "ST_Multi(ST_SetSRID(ST_GeomFromGeoJSON($4), 4326))) ON CONFLICT (layer, ord) "
                    "DO UPDATE SET label = EXCLUDED.label, geom = EXCLUDED.geom "
                    "WHERE (t.label, ST_AsEWKB(t.geom)) IS DISTINCT FROM "
                    "(EXCLUDED.label, ST_AsEWKB(EXCLUDED.geom))", 4, p),
                PGRES_COMMAND_OK, "loading an area");
        free(gj);
    }
    char n[24];
    snprintf(n, sizeof n, "%zu", a->n);
    const char *p[] = {a->o->areas_field, n};
    if (s == GS_OK)
        s = res(x, srv_pgi_query(x->c, "DELETE FROM areas WHERE layer = $1 AND ord >= $2", 2, p),
                PGRES_COMMAND_OK, "replacing the areas");
    return s;
}

static gs_status load_areas(push_ctx *x, const srv_push_opts *o, srv_push_report *r)
{
    if (!o->areas_field || !*o->areas_field)
        return gs_fail(GS_EINVAL, "--areas %s: needs --field FIELD (the label property)", o->areas);
    srv_areas *areas;
    gs_status s = srv_areas_load(o->areas, o->areas_field, &areas);   /* validates */
    if (s != GS_OK) return s;
    json_error_t e;
    json_t *root = json_load_file(o->areas, 0, &e);
    area_load a = {o, areas, json_object_get(root, "features"), srv_areas_count(areas)};
    if (json_array_size(a.features) != a.n)
        s = gs_fail(GS_EFORMAT, "%s: expected %zu features", o->areas, a.n);
    if (s == GS_OK) s = in_txn(x, push_areas, &a, r);
    if (s == GS_OK) r->areas = a.n;
    json_decref(root);
    srv_areas_free(areas);
    return s;
}

/* ------------------------------------------------------------------ push */

static gs_status prepare(push_ctx *x, const char *sql, sqlite3_stmt **q)
{
    return sqlite3_prepare_v2(x->h, sql, -1, q, NULL) == SQLITE_OK ? GS_OK : lite_fail(x, "preparing a query");
}

static gs_status count_rows(push_ctx *x, const char *sql, size_t *n)
{
    sqlite3_stmt *q;
    gs_status s = prepare(x, sql, &q);
    if (s != GS_OK) return s;
    if (sqlite3_step(q) == SQLITE_ROW) *n = (size_t)sqlite3_column_int64(q, 0);
    else s = lite_fail(x, "counting rows");
    sqlite3_finalize(q);
    return s;
}

gs_status srv_pg_push(const char *db_path, const char *conninfo, const srv_push_opts *o,
                      srv_push_report *r)
{
    if (!db_path || !conninfo || !o || !r) return gs_fail(GS_EINVAL, "srv_pg_push: NULL argument");
    memset(r, 0, sizeof *r);
    size_t limit = o->batch_lights ? o->batch_lights : 1;
    srv_db *db;
    gs_status s = srv_db_open(db_path, SRV_DB_READ, &db);
    if (s != GS_OK) return s;
    push_ctx x = {.h = srv_db_sqlite(db), .path = srv_db_path(db)};
    capture_batch cb = {.limit = limit, .first_id = -1};
    site_batch sb = {.limit = limit};
    if ((s = srv_pgi_connect(conninfo, 1, &x.c)) != GS_OK) goto done;
    if ((s = srv_pgi_exec(x.c, stage_sql, "creating the staging tables")) != GS_OK ||
        (s = count_rows(&x, "SELECT count(*) FROM captures", &r->captures)) != GS_OK ||
        (s = count_rows(&x, "SELECT count(*) FROM light_sites", &r->sites)) != GS_OK ||
        (s = in_txn(&x, push_setup, NULL, r)) != GS_OK)
        goto done;
    if ((s = prepare(&x, "SELECT " CAPTURE_COLS ", id FROM captures WHERE id >= ?1 ORDER BY id", &cb.list)))
        goto done;
    for (int k = 0; k < 4; k++)
        if ((s = prepare(&x, part_lite[k], &cb.part[k])) != GS_OK) goto done;
    size_t done_captures = 0, step = r->captures / 10 + 1, next = step;
    do {
        if ((s = in_txn(&x, push_captures, &cb, r)) != GS_OK) goto done;
        cb.first_id = cb.next_id;
        cb.mapped = x.capture.n;
        r->captures_pushed += cb.pushed;
        r->lights_pushed += cb.lights;
        done_captures = x.capture.n;
        if (o->progress && done_captures >= next) {
            fprintf(stderr, "push: %zu of %zu captures\n", done_captures, r->captures);
            next = done_captures + step;
        }
    } while (cb.more);
    if ((s = prepare(&x, site_lite, &sb.sites)) != GS_OK || (s = prepare(&x, det_lite, &sb.dets)) != GS_OK)
        goto done;
    for (sb.after = 0;; sb.after = sb.last) {
        sb.n = sb.written = 0;
        if ((s = in_txn(&x, push_sites, &sb, r)) != GS_OK) goto done;
        if (!sb.n) break;
        r->sites_written += sb.written;
    }
    if (o->areas) s = load_areas(&x, o, r);
done:
    sqlite3_finalize(cb.list);
    for (int k = 0; k < 4; k++) sqlite3_finalize(cb.part[k]);
    sqlite3_finalize(sb.sites);
    sqlite3_finalize(sb.dets);
    if (x.c) PQfinish(x.c);
    map_free(&x.delight);
    map_free(&x.survey);
    map_free(&x.station);
    map_free(&x.capture);
    free(x.buf);
    srv_db_close(db);
    return s;
}
