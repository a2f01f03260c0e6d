/* delight_store.c - DELIGHT (paper Sec. 3) on disk: a versioned SQLite table set and CSV.
 *
 * SQLite schema, version GS_DELIGHT_SCHEMA_VERSION (= PRAGMA user_version):
 *   delight_meta(key TEXT PRIMARY KEY, value TEXT)  -- format = gridsurvey-delight, schema_version
 *   delight_bulbs(bulb_id, grid_hz, sensor, ref, type, name, watts, bands, n,
 *                 PRIMARY KEY (bulb_id, grid_hz, sensor))         -- rowid keeps the order
 *   delight_brf_bands(bulb_id, grid_hz, sensor, band, chromaticity, n, samples,
 *                     PRIMARY KEY (bulb_id, grid_hz, sensor, band),
 *                     FOREIGN KEY (bulb_id, grid_hz, sensor) REFERENCES delight_bulbs)
 * samples is a BLOB of n little-endian IEEE-754 doubles.
 *
 * Loading and importing build a temporary collection (every entry checked by gs_delight_add)
 * and append it to d only when the whole file is good. */
#include "recognize/base/internal.h"

#include <errno.h>
#include <math.h>
#include <sqlite3.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#define FORMAT_NAME "gridsurvey-delight"

static const char *band_name(int bands, int band)
{
    static const char *const rgb[3] = {"R", "G", "B"};
    return bands == 1 ? "mono" : rgb[band];
}

static int same_key(const gs_bulb *a, const gs_bulb *b)
{
    return strcmp(a->id, b->id) == 0 && a->grid_hz == b->grid_hz && strcmp(a->sensor, b->sensor) == 0;
}

/* Append every bulb of src to d; a clash with an entry of d adds nothing. Only running out of
 * memory half-way could leave a prefix of src in d. */
static gs_status append_all(gs_delight *d, const gs_delight *src, const char *path)
{
    for (size_t i = 0; i < gs_delight_count(src); i++)
        for (size_t j = 0; j < gs_delight_count(d); j++) {
            const gs_bulb *a = gs_delight_get(src, i), *b = gs_delight_get(d, j);
            if (same_key(a, b))
                return gs_fail(GS_EINVAL, "%s: bulb %s at %d Hz with sensor %s: already in the "
                               "database", path, a->id, a->grid_hz, a->sensor);
        }
    for (size_t i = 0; i < gs_delight_count(src); i++) {
        gs_status s = gs_delight_add(d, gs_delight_get(src, i));
        if (s != GS_OK) return s;
    }
    return GS_OK;
}

/* Prefix the current detail with a location ("FILE" or "FILE:LINE"). */
static gs_status with_location(gs_status s, const char *path, size_t line)
{
    char msg[512];
    snprintf(msg, sizeof msg, "%s", gs_detail());
    if (line) return gs_fail(s, "%s:%zu: %s", path, line, msg);
    return gs_fail(s, "%s: %s", path, msg);
}

static int parse_ref(const char *s, gs_ref *r)
{
    for (int i = GS_REF_VOLTAGE; i <= GS_REF_UNLOCKED; i++)
        if (strcmp(s, gs_ref_name((gs_ref)i)) == 0) {
            *r = (gs_ref)i;
            return 1;
        }
    return 0;
}

/* Copy a bounded string; 0 if it does not fit. */
static int copy_str(char *dst, size_t cap, const char *src)
{
    size_t len = strlen(src);
    if (len >= cap) return 0;
    memcpy(dst, src, len + 1);
    return 1;
}

/* ------------------------------------------------------------------ SQLite */

static const char *const schema_sql =
    "DROP TABLE IF EXISTS delight_brf_bands;"
    "DROP TABLE IF EXISTS delight_bulbs;"
    "DROP TABLE IF EXISTS delight_meta;"
    "CREATE TABLE delight_meta(key TEXT PRIMARY KEY, value TEXT NOT NULL);"
    "CREATE TABLE delight_bulbs("
    " bulb_id TEXT NOT NULL, grid_hz INTEGER NOT NULL CHECK (grid_hz IN (50, 60)),"
    " sensor TEXT NOT NULL, ref TEXT NOT NULL CHECK (ref IN ('voltage', 'none', 'unlocked')),"
    " type TEXT NOT NULL, name TEXT NOT NULL, watts REAL NOT NULL,"
    " bands INTEGER NOT NULL CHECK (bands IN (1, 3)), n INTEGER NOT NULL,"
    " PRIMARY KEY (bulb_id, grid_hz, sensor));"
    "CREATE TABLE delight_brf_bands("
    " bulb_id TEXT NOT NULL, grid_hz INTEGER NOT NULL, sensor TEXT NOT NULL,"
    " band INTEGER NOT NULL, chromaticity REAL NOT NULL, n INTEGER NOT NULL,"
    " samples BLOB NOT NULL CHECK (length(samples) = 8 * n),"
    " PRIMARY KEY (bulb_id, grid_hz, sensor, band),"
    " FOREIGN KEY (bulb_id, grid_hz, sensor) REFERENCES delight_bulbs (bulb_id, grid_hz, sensor)"
    "  ON DELETE CASCADE);"
    "INSERT INTO delight_meta VALUES ('format', '" FORMAT_NAME "');";

const char *gs_sqlite_errmsg(sqlite3 *db, char *buf, size_t size)
{
    if (!db) {
        snprintf(buf, size, "out of memory");
        return buf;
    }
    int code = sqlite3_errcode(db) & 0xff, sys = sqlite3_system_errno(db);
    if ((code == SQLITE_IOERR || code == SQLITE_FULL || code == SQLITE_CANTOPEN) && sys > 0)
        snprintf(buf, size, "%s (%s)", sqlite3_errmsg(db), strerror(sys));
    else
        snprintf(buf, size, "%s", sqlite3_errmsg(db));
    return buf;
}

static gs_status sql_fail(sqlite3 *db, const char *path, const char *what)
{
    int code = db ? sqlite3_errcode(db) : SQLITE_NOMEM;
    char buf[512];
    const char *msg = gs_sqlite_errmsg(db, buf, sizeof buf);
    if (code == SQLITE_NOTADB)
        return gs_fail(GS_EFORMAT, "%s: not a DELIGHT database: expected an SQLite file with format "
                       "'%s', schema version %d (%s)", path, FORMAT_NAME, GS_DELIGHT_SCHEMA_VERSION, msg);
    if (code == SQLITE_CANTOPEN) return gs_fail(GS_EIO, "%s: cannot open: %s", path, msg);
    return gs_fail(GS_ESQL, "%s: %s: %s", path, what, msg);
}

/* PRAGMA user_version of db into *v. */
static gs_status user_version(sqlite3 *db, const char *path, int *v)
{
    sqlite3_stmt *q = NULL;
    if (sqlite3_prepare_v2(db, "PRAGMA user_version", -1, &q, NULL) != SQLITE_OK ||
        sqlite3_step(q) != SQLITE_ROW) {
        gs_status s = sql_fail(db, path, "reading the schema version");
        sqlite3_finalize(q);
        return s;
    }
    *v = sqlite3_column_int(q, 0);
    sqlite3_finalize(q);
    return GS_OK;
}

static void put_le(unsigned char *p, double v)
{
    uint64_t u;
    memcpy(&u, &v, sizeof u);
    for (int k = 0; k < 8; k++) p[k] = (unsigned char)(u >> (8 * k));
}

static double get_le(const unsigned char *p)
{
    uint64_t u = 0;
    for (int k = 0; k < 8; k++) u |= (uint64_t)p[k] << (8 * k);
    double v;
    memcpy(&v, &u, sizeof v);
    return v;
}

/* gs_delight_save into the SQLite file `file` (path: the name in messages). */
static gs_status save_at(const gs_delight *d, const char *file, const char *path)
{
    sqlite3 *db = NULL;
    sqlite3_stmt *ins_bulb = NULL, *ins_band = NULL;
    unsigned char *blob = NULL;
    int in_txn = 0, version = 0;
    gs_status s = GS_OK;
    if (sqlite3_open_v2(file, &db, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE, NULL) != SQLITE_OK) {
        s = sql_fail(db, path, "open");
        goto done;
    }
    sqlite3_busy_timeout(db, GS_DELIGHT_BUSY_MS);   /* another process's import: wait for it */
    if ((s = user_version(db, path, &version)) != GS_OK) goto done;
    if (version != 0 && version != GS_DELIGHT_SCHEMA_VERSION) {
        s = gs_fail(GS_EFORMAT, "%s: schema version %d: expected a new file or a DELIGHT database "
                    "(version %d); not overwriting", path, version, GS_DELIGHT_SCHEMA_VERSION);
        goto done;
    }
    if (sqlite3_exec(db, "PRAGMA foreign_keys = ON; BEGIN IMMEDIATE", NULL, NULL, NULL) != SQLITE_OK) {
        s = sql_fail(db, path, "begin");
        goto done;
    }
    in_txn = 1;
    char pragma[96];
    snprintf(pragma, sizeof pragma,
             "INSERT INTO delight_meta VALUES ('schema_version', '%d'); PRAGMA user_version = %d",
             GS_DELIGHT_SCHEMA_VERSION, GS_DELIGHT_SCHEMA_VERSION);
    if (sqlite3_exec(db, schema_sql, NULL, NULL, NULL) != SQLITE_OK ||
        sqlite3_exec(db, pragma, NULL, NULL, NULL) != SQLITE_OK) {
        s = sql_fail(db, path, "creating the DELIGHT tables");
        goto done;
    }
    if (sqlite3_prepare_v2(db, "INSERT INTO delight_bulbs VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)", -1,
                           &ins_bulb, NULL) != SQLITE_OK ||
        sqlite3_prepare_v2(db, "INSERT INTO delight_brf_bands VALUES (?, ?, ?, ?, ?, ?, ?)", -1,
                           &ins_band, NULL) != SQLITE_OK) {
        s = sql_fail(db, path, "preparing inserts");
        goto done;
    }
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        int n = b->brf.n;
        sqlite3_reset(ins_bulb);
        sqlite3_bind_text(ins_bulb, 1, b->id, -1, SQLITE_STATIC);
        sqlite3_bind_int(ins_bulb, 2, b->grid_hz);
        sqlite3_bind_text(ins_bulb, 3, b->sensor, -1, SQLITE_STATIC);
        sqlite3_bind_text(ins_bulb, 4, gs_ref_name(b->ref), -1, SQLITE_STATIC);
        sqlite3_bind_text(ins_bulb, 5, gs_tech_name(b->type), -1, SQLITE_STATIC);
        sqlite3_bind_text(ins_bulb, 6, b->name, -1, SQLITE_STATIC);
        sqlite3_bind_double(ins_bulb, 7, b->watts);
        sqlite3_bind_int(ins_bulb, 8, b->brf.bands);
        sqlite3_bind_int(ins_bulb, 9, n);
        if (sqlite3_step(ins_bulb) != SQLITE_DONE) {
            s = sql_fail(db, path, "inserting a bulb");
            goto done;
        }
        unsigned char *nb = realloc(blob, 8 * (size_t)n);
        if (!nb) {
            s = gs_fail(GS_ENOMEM, "%s: cannot allocate a %d-sample BRF", path, n);
            goto done;
        }
        blob = nb;
        for (int band = 0; band < b->brf.bands; band++) {
            for (int j = 0; j < n; j++) put_le(blob + 8 * (size_t)j, b->brf.v[(size_t)band * n + j]);
            sqlite3_reset(ins_band);
            sqlite3_bind_text(ins_band, 1, b->id, -1, SQLITE_STATIC);
            sqlite3_bind_int(ins_band, 2, b->grid_hz);
            sqlite3_bind_text(ins_band, 3, b->sensor, -1, SQLITE_STATIC);
            sqlite3_bind_int(ins_band, 4, band);
            sqlite3_bind_double(ins_band, 5, b->chroma[band]);
            sqlite3_bind_int(ins_band, 6, n);
            sqlite3_bind_blob(ins_band, 7, blob, 8 * n, SQLITE_STATIC);
            if (sqlite3_step(ins_band) != SQLITE_DONE) {
                s = sql_fail(db, path, "inserting a BRF band");
                goto done;
            }
        }
    }
    if (sqlite3_exec(db, "COMMIT", NULL, NULL, NULL) != SQLITE_OK) {
        s = sql_fail(db, path, "commit");
        goto done;
    }
    in_txn = 0;
done:
    sqlite3_finalize(ins_band);
    sqlite3_finalize(ins_bulb);
    if (in_txn) sqlite3_exec(db, "ROLLBACK", NULL, NULL, NULL);
    sqlite3_close(db);
    free(blob);
    return s;
}

/* A new file is built complete under a temporary name and renamed into place (gs_atomic_*), so
 * a failure (a full disk, an I/O error) leaves no half-made file under path (#16, fault
 * injection); never over one another process made meanwhile (*raced = 1, nothing written). */
gs_status gs_delight_save_new(const gs_delight *d, const char *path, int *raced)
{
    *raced = 0;
    gs_atomic a;
    gs_status s = gs_atomic_open(&a, path, 0);
    if (s != GS_OK) return s;
    if ((s = save_at(d, a.tmp, path)) == GS_OK) return gs_atomic_commit_new(&a, raced);
    gs_atomic_abort(&a);
    return s;
}

/* An existing database gets its tables replaced in one transaction, a new one
 * gs_delight_save_new. */
gs_status gs_delight_save(const gs_delight *d, const char *path)
{
    struct stat st;
    if (lstat(path, &st) == 0 || errno != ENOENT) return save_at(d, path, path);
    int raced;
    gs_status s = gs_delight_save_new(d, path, &raced);
    return s == GS_OK && raced ? save_at(d, path, path) : s;
}

/* The BRF bands of bulb b (id, grid_hz, sensor, bands and n set) from the band query q. */
static gs_status load_bands(sqlite3 *db, sqlite3_stmt *q, const char *path, gs_bulb *b)
{
    sqlite3_reset(q);
    sqlite3_bind_text(q, 1, b->id, -1, SQLITE_STATIC);
    sqlite3_bind_int(q, 2, b->grid_hz);
    sqlite3_bind_text(q, 3, b->sensor, -1, SQLITE_STATIC);
    int got = 0, rc;
    while ((rc = sqlite3_step(q)) == SQLITE_ROW) {
        int band = sqlite3_column_int(q, 0), n = sqlite3_column_int(q, 2);
        const unsigned char *p = sqlite3_column_blob(q, 3);
        int bytes = sqlite3_column_bytes(q, 3);
        if (band != got || band >= b->brf.bands || n != b->brf.n || bytes != 8 * n || !p)
            return gs_fail(GS_EFORMAT, "%s: bulb %s at %d Hz, sensor %s: band %d (n %d, %d bytes): "
                           "expected band %d of %d with %d samples", path, b->id, b->grid_hz,
                           b->sensor, band, n, bytes, got, b->brf.bands, b->brf.n);
        b->chroma[band] = sqlite3_column_double(q, 1);
        for (int j = 0; j < n; j++) b->brf.v[(size_t)band * n + j] = get_le(p + 8 * (size_t)j);
        got++;
    }
    if (rc != SQLITE_DONE) return sql_fail(db, path, "reading BRF bands");
    if (got != b->brf.bands)
        return gs_fail(GS_EFORMAT, "%s: bulb %s at %d Hz, sensor %s: %d BRF bands: expected %d", path,
                       b->id, b->grid_hz, b->sensor, got, b->brf.bands);
    return GS_OK;
}

/* One row of the bulb query q into *b (BRF allocated, bands not yet read). */
static gs_status load_bulb(sqlite3_stmt *q, const char *path, gs_bulb *b)
{
    memset(b, 0, sizeof *b);
    const char *id = (const char *)sqlite3_column_text(q, 0);
    const char *sensor = (const char *)sqlite3_column_text(q, 2);
    const char *ref = (const char *)sqlite3_column_text(q, 3);
    const char *type = (const char *)sqlite3_column_text(q, 4);
    const char *name = (const char *)sqlite3_column_text(q, 5);
    if (!id || !sensor || !ref || !type || !name || !copy_str(b->id, sizeof b->id, id) ||
        !copy_str(b->sensor, sizeof b->sensor, sensor) || !copy_str(b->name, sizeof b->name, name))
        return gs_fail(GS_EFORMAT, "%s: bulb '%s': expected bulb_id, sensor and name of at most %d, "
                       "%d and %d characters", path, id ? id : "", GS_ID_MAX - 1,
                       GS_SENSOR_MAX - 1, GS_NAME_MAX - 1);
    b->grid_hz = sqlite3_column_int(q, 1);
    if (!parse_ref(ref, &b->ref))
        return gs_fail(GS_EFORMAT, "%s: bulb %s: ref '%s': expected voltage, none or unlocked", path,
                       b->id, ref);
    if (gs_tech_parse(type, &b->type) != GS_OK) return with_location(GS_EFORMAT, path, 0);
    b->watts = sqlite3_column_double(q, 6);
    return gs_brf_init(&b->brf, sqlite3_column_int(q, 8), sqlite3_column_int(q, 7));
}

gs_status gs_delight_open(const char *path, gs_delight **out)
{
    if (!(*out = gs_delight_new())) return gs_fail(GS_ENOMEM, "cannot allocate the DELIGHT database");
    gs_status st = path ? gs_delight_load(*out, path) : gs_delight_generate(*out, GS_BRF_N_DEFAULT);
    if (st != GS_OK) {
        gs_delight_free(*out);
        *out = NULL;
    }
    return st;
}

gs_status gs_delight_load(gs_delight *d, const char *path)
{
    gs_status s = gs_input_check(path);   /* SQLite opens by name: a missing file is not found */
    if (s != GS_OK) return s;
    sqlite3 *db = NULL;
    sqlite3_stmt *meta = NULL, *bulbs = NULL, *bands = NULL;
    gs_delight *tmp = gs_delight_new();
    gs_bulb b = {0};
    int version = 0;
    if (!tmp) return gs_fail(GS_ENOMEM, "%s: cannot allocate a DELIGHT database", path);
    if (sqlite3_open_v2(path, &db, SQLITE_OPEN_READONLY, NULL) != SQLITE_OK) {
        s = sql_fail(db, path, "open");
        goto done;
    }
    sqlite3_busy_timeout(db, GS_DELIGHT_BUSY_MS);
    if ((s = user_version(db, path, &version)) != GS_OK) goto done;
    const char *format = NULL;
    if (version == GS_DELIGHT_SCHEMA_VERSION &&
        sqlite3_prepare_v2(db, "SELECT value FROM delight_meta WHERE key = 'format'", -1, &meta,
                           NULL) == SQLITE_OK &&
        sqlite3_step(meta) == SQLITE_ROW)
        format = (const char *)sqlite3_column_text(meta, 0);
    if (!format || strcmp(format, FORMAT_NAME) != 0) {
        sqlite3_stmt *q = NULL;
        int app = sqlite3_prepare_v2(db, "PRAGMA application_id", -1, &q, NULL) == SQLITE_OK &&
                          sqlite3_step(q) == SQLITE_ROW ? sqlite3_column_int(q, 0) : 0;
        sqlite3_finalize(q);
        s = gs_fail(GS_EFORMAT, "%s: not a DELIGHT database: expected format '%s' with schema version "
                    "%d (found user_version %d, format '%s'%s)", path, FORMAT_NAME,
                    GS_DELIGHT_SCHEMA_VERSION, version, format ? format : "none",
                    (unsigned)app == GS_SURVEY_DB_APPLICATION_ID ? ": a survey database, which goes with --db" : "");
        goto done;
    }
    if (sqlite3_prepare_v2(db, "SELECT bulb_id, grid_hz, sensor, ref, type, name, watts, bands, n "
                           "FROM delight_bulbs ORDER BY rowid", -1, &bulbs, NULL) != SQLITE_OK ||
        sqlite3_prepare_v2(db, "SELECT band, chromaticity, n, samples FROM delight_brf_bands "
                           "WHERE bulb_id = ? AND grid_hz = ? AND sensor = ? ORDER BY band", -1,
                           &bands, NULL) != SQLITE_OK) {
        s = sql_fail(db, path, "reading the DELIGHT tables");
        goto done;
    }
    int rc;
    while ((rc = sqlite3_step(bulbs)) == SQLITE_ROW) {
        if ((s = load_bulb(bulbs, path, &b)) != GS_OK) goto done;
        if ((s = load_bands(db, bands, path, &b)) != GS_OK) goto done;
        if ((s = gs_delight_add(tmp, &b)) != GS_OK) {
            s = with_location(s, path, 0);
            goto done;
        }
        gs_bulb_release(&b);
    }
    if (rc != SQLITE_DONE) {
        s = sql_fail(db, path, "reading bulbs");
        goto done;
    }
    s = append_all(d, tmp, path);
done:
    gs_bulb_release(&b);
    sqlite3_finalize(meta);
    sqlite3_finalize(bulbs);
    sqlite3_finalize(bands);
    sqlite3_close(db);
    gs_delight_free(tmp);
    return s;
}

/* --------------------------------------------------------------------- CSV */

static const char *const csv_columns[] = {"bulb_id", "type", "name", "watts", "grid_hz",
                                          "sensor", "band", "chromaticity", "n"};
#define CSV_FIXED 9

gs_status gs_delight_export_csv(const gs_delight *d, FILE *out)
{
    int max_n = 0;
    for (size_t i = 0; i < gs_delight_count(d); i++)
        if (gs_delight_get(d, i)->brf.n > max_n) max_n = gs_delight_get(d, i)->brf.n;
    for (int c = 0; c < CSV_FIXED; c++) fprintf(out, "%s%s", c ? "," : "", csv_columns[c]);
    for (int j = 0; j < max_n; j++) fprintf(out, ",v%d", j);
    fputc('\n', out);
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        for (int band = 0; band < b->brf.bands; band++) {
            fprintf(out, "%s,%s,", b->id, gs_tech_name(b->type));
            gs_csv_write_field(out, b->name);   /* the one free-text field: quoted if it must be */
            fprintf(out, ",%.17g,%d,%s/%s,%s,%.17g,%d", b->watts, b->grid_hz, b->sensor,
                    gs_ref_name(b->ref), band_name(b->brf.bands, band), b->chroma[band], b->brf.n);
            const double *v = b->brf.v + (size_t)band * (size_t)b->brf.n;
            for (int j = 0; j < b->brf.n; j++) fprintf(out, ",%.17g", v[j]);
            fputc('\n', out);
        }
    }
    if (fflush(out) != 0 || ferror(out)) return gs_fail(GS_EIO, "DELIGHT CSV export: write failed");
    return GS_OK;
}

static int parse_int(const char *s, long lo, long hi, int *v)
{
    char *end;
    if (!*s) return 0;
    long x = strtol(s, &end, 10);
    if (*end != '\0' || x < lo || x > hi) return 0;
    *v = (int)x;
    return 1;
}

/* One row of the CSV: its fields. */
typedef struct {
    char **f;
    size_t count;
} fields;

/* The import state: the bulb being assembled from consecutive rows. */
typedef struct {
    const char *path;
    size_t line, first_line;
    int have_header;
    int header_n;      /* v columns in the header */
    int active;        /* a bulb is being assembled */
    int next_band;
    gs_bulb b;
    gs_delight *tmp;   /* the bulbs read so far */
} csv_state;

static gs_status bad_field(const csv_state *st, const char *name, const char *expected)
{
    return gs_fail(GS_EFORMAT, "%s:%zu: field %s: expected %s", st->path, st->line, name, expected);
}

static gs_status check_header(csv_state *st, const fields *fs)
{
    size_t cols = fs->count > CSV_FIXED ? fs->count : CSV_FIXED;
    for (size_t c = 0; c < cols; c++) {
        char want[32], msg[192];
        if (c < CSV_FIXED) snprintf(want, sizeof want, "%s", csv_columns[c]);
        else snprintf(want, sizeof want, "v%zu", c - CSV_FIXED);
        if (c >= fs->count || strcmp(fs->f[c], want) != 0) {
            snprintf(msg, sizeof msg, "header column %zu to be '%s' (header bulb_id,type,name,watts,"
                     "grid_hz,sensor,band,chromaticity,n,v0,...)", c + 1, want);
            return bad_field(st, want, msg);
        }
    }
    st->header_n = (int)(fs->count - CSV_FIXED);
    return GS_OK;
}

/* Finish the bulb being assembled: add it to tmp. */
static gs_status finish_bulb(csv_state *st, gs_delight *tmp)
{
    gs_status s = gs_delight_add(tmp, &st->b);
    gs_bulb_release(&st->b);
    st->active = 0;
    return s == GS_OK ? s : with_location(s, st->path, st->first_line);
}

static gs_status import_row(csv_state *st, fields *fs, gs_delight *tmp)
{
    if (fs->count < CSV_FIXED) return bad_field(st, csv_columns[fs->count], "a value (truncated row)");
    char **f = fs->f;
    gs_bulb r = {0};
    if (!*f[0] || !copy_str(r.id, sizeof r.id, f[0])) return bad_field(st, "bulb_id", "1 to 47 characters");
    if (gs_tech_parse(f[1], &r.type) != GS_OK)
        return bad_field(st, "type", "a technology (incandescent, halogen, cfl, led_pwm, ..., unknown)");
    if (!copy_str(r.name, sizeof r.name, f[2])) return bad_field(st, "name", "at most 95 characters");
    if (!gs_parse_number(f[3], &r.watts)) return bad_field(st, "watts", "a finite number");
    if (!parse_int(f[4], 50, 60, &r.grid_hz) || (r.grid_hz != 50 && r.grid_hz != 60))
        return bad_field(st, "grid_hz", "50 or 60");
    char *slash = strrchr(f[5], '/');
    if (slash) *slash = '\0';
    if (!slash || !*f[5] || !copy_str(r.sensor, sizeof r.sensor, f[5]) || !parse_ref(slash + 1, &r.ref))
        return bad_field(st, "sensor", "SENSOR/REF with REF voltage, none or unlocked");
    double chroma;
    if (!gs_parse_number(f[7], &chroma)) return bad_field(st, "chromaticity", "a finite number");
    int n;
    if (!parse_int(f[8], 4, st->header_n, &n) || n % 2)
        return bad_field(st, "n", "an even sample count from 4 to the header's v columns");
    if (fs->count != (size_t)CSV_FIXED + (size_t)n) {
        char name[16], msg[80];
        snprintf(name, sizeof name, "v%zu", fs->count > (size_t)CSV_FIXED + n ? (size_t)n
                                                                              : fs->count - CSV_FIXED);
        snprintf(msg, sizeof msg, "exactly %d values v0..v%d (row has %zu)", n, n - 1, fs->count - CSV_FIXED);
        return bad_field(st, name, msg);
    }

    if (st->active && !same_key(&st->b, &r)) {
        char msg[96];
        snprintf(msg, sizeof msg, "band %s of bulb %s from line %zu",
                 band_name(st->b.brf.bands, st->next_band), st->b.id, st->first_line);
        return bad_field(st, "band", msg);
    }
    if (!st->active) {
        int bands = strcmp(f[6], "mono") == 0 ? 1 : strcmp(f[6], "R") == 0 ? 3 : 0;
        if (!bands) return bad_field(st, "band", "mono or R (the first band of a bulb)");
        for (size_t i = 0; i < gs_delight_count(tmp); i++)
            if (same_key(gs_delight_get(tmp, i), &r))
                return bad_field(st, "bulb_id", "the rows of one bulb, grid and sensor to be consecutive");
        st->b = r;
        gs_status s = gs_brf_init(&st->b.brf, n, bands);
        if (s != GS_OK) return s;
        st->active = 1;
        st->next_band = 0;
        st->first_line = st->line;
    } else {
        const gs_bulb *b = &st->b;
        if (strcmp(f[6], band_name(b->brf.bands, st->next_band)) != 0) {
            char msg[160];
            snprintf(msg, sizeof msg, "%s, the next band of bulb %.40s (found %.20s)",
                     band_name(b->brf.bands, st->next_band), b->id, f[6]);
            return bad_field(st, "band", msg);
        }
        if (r.type != b->type) return bad_field(st, "type", "the same type in every band of a bulb");
        if (strcmp(r.name, b->name) != 0) return bad_field(st, "name", "the same name in every band");
        if (r.watts != b->watts) return bad_field(st, "watts", "the same watts in every band");
        if (r.ref != b->ref) return bad_field(st, "sensor", "the same SENSOR/REF in every band");
        if (n != b->brf.n) return bad_field(st, "n", "the same n in every band");
    }
    st->b.chroma[st->next_band] = chroma;
    double *v = st->b.brf.v + (size_t)st->next_band * (size_t)n;
    for (int j = 0; j < n; j++)
        if (!gs_parse_number(f[CSV_FIXED + j], &v[j])) {
            char name[16];
            snprintf(name, sizeof name, "v%d", j);
            return bad_field(st, name, "a finite number");
        }
    if (++st->next_band == st->b.brf.bands) return finish_bulb(st, tmp);
    return GS_OK;
}

static gs_status import_line(void *ctx, char **f, size_t count, size_t line)
{
    csv_state *st = ctx;
    st->line = line;
    fields fs = {f, count};
    if (!st->have_header) {
        st->have_header = 1;
        return check_header(st, &fs);
    }
    return import_row(st, &fs, st->tmp);
}

gs_status gs_delight_import_csv(gs_delight *d, const char *path)
{
    gs_delight *tmp = gs_delight_new();
    if (!tmp) return gs_fail(GS_ENOMEM, "%s: cannot allocate a DELIGHT database", path);
    csv_state st = {.path = path, .tmp = tmp};
    gs_status s = gs_csv_read(path, 0, import_line, &st);
    if (s == GS_OK && !st.have_header)
        s = gs_fail(GS_EFORMAT, "%s:1: field bulb_id: expected the header bulb_id,type,name,watts,"
                    "grid_hz,sensor,band,chromaticity,n,v0,... (the file is empty)", path);
    if (s == GS_OK && st.active) {
        char msg[160];
        snprintf(msg, sizeof msg, "%s, the next band of bulb %.40s: the file ends before it",
                 band_name(st.b.brf.bands, st.next_band), st.b.id);
        st.line++;
        s = bad_field(&st, "band", msg);
    }
    /* a header with sample columns but no row is a file cut short (it made an empty database);
     * an empty database's export is the header without them */
    if (s == GS_OK && gs_delight_count(tmp) == 0 && st.header_n > 0)
        s = gs_fail(GS_EFORMAT, "%s:%zu: no bulb after a header of %d samples: expected its entries (a "
                    "file cut short?)", path, st.line + 1, st.header_n);
    if (s == GS_OK) s = append_all(d, tmp, path);
    gs_bulb_release(&st.b);
    gs_delight_free(tmp);
    return s;
}
