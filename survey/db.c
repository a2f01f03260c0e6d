/* db.c - the survey database: SQLite with a versioned schema, migrations, prepared-statement
 * inserts, an atomic and resumable per-capture ingest, and a consistency check.
 * docs/survey-db.md is the specification (tables, views, migrations, crash safety).
 *
 * Identification: PRAGMA application_id = SRV_DB_APPLICATION_ID, PRAGMA user_version = the
 * schema version, meta('format') = SRV_DB_FORMAT. A file is identified through a read-only
 * connection before anything is written, so a file that is refused is never touched.
 *
 * Migrations: srv_db_migrations[i] takes the schema from version i to i + 1, applied in order, each
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

/* ------------------------------------------------------------------ handle */

/* GS_ESQL with the connection's message, "PATH: WHAT: MESSAGE". */
static gs_status sql_fail(sqlite3 *db, const char *path, const char *what)
{
    int code = db ? sqlite3_errcode(db) : SQLITE_NOMEM;
    char buf[512];
    const char *msg = gs_sqlite_errmsg(db, buf, sizeof buf);
    if (code == SQLITE_NOMEM) return gs_fail(GS_ENOMEM, "%s: %s: out of memory", path, what);
    if (code == SQLITE_READONLY)
        return gs_fail(GS_EIO, "%s: %s: the database is read-only (%s)", path, what, msg);
    if (code == SQLITE_CANTOPEN || code == SQLITE_IOERR || code == SQLITE_FULL)
        return gs_fail(GS_EIO, "%s: %s: %s", path, what, msg);
    if (code == SQLITE_NOTADB || code == SQLITE_CORRUPT)
        return gs_fail(GS_EFORMAT, "%s: %s: %s", path, what, msg);
    return gs_fail(GS_ESQL, "%s: %s: %s", path, what, msg);
}

gs_status srv_dbi_lost(srv_db *db, const char *what)
{
    if (!db->in_txn || !sqlite3_get_autocommit(db->db)) return GS_OK;
    return gs_fail(GS_ESQL, "%s: %s: the transaction was lost (SQLite rolled it back after an "
                   "earlier failure): nothing of it was stored", db->path, what);
}

gs_status srv_dbi_fail(srv_db *db, const char *what)
{
    gs_status s;
    if (sqlite3_errcode(db->db) == SQLITE_CONSTRAINT && (s = srv_dbi_lost(db, what)) != GS_OK) return s;
    return sql_fail(db->db, db->path, what);
}

/* SQLite's commit hook: while the handle holds a transaction, only srv_db_commit commits.
 * SQLite rolls a whole transaction back by itself on some errors (out of memory even in a read,
 * a full disk); a caller that missed one would go on writing each statement in a transaction of
 * its own, half of a capture. Such a commit is refused (the statement fails, SQLITE_CONSTRAINT
 * from the hook; srv_dbi_fail names it, srv_dbi_lost). */
static int refuse_stray_commit(void *arg)
{
    const srv_db *db = arg;
    return db->in_txn && !db->committing;
}

void srv_dbi_utc_now(char buf[32])
{
    time_t t = time(NULL);
    struct tm tm;
    gmtime_r(&t, &tm);
    strftime(buf, 32, "%Y-%m-%dT%H:%M:%SZ", &tm);
}

gs_status srv_dbi_exec(srv_db *db, const char *sql, const char *what)
{
    if (sqlite3_exec(db->db, sql, NULL, NULL, NULL) != SQLITE_OK) return srv_dbi_fail(db, what);
    return GS_OK;
}

gs_status srv_dbi_stmt(srv_db *db, int which, sqlite3_stmt **out)
{
    if (!db->st[which]) {
        if (sqlite3_prepare_v3(db->db, srv_db_stmt_sql[which], -1, SQLITE_PREPARE_PERSISTENT,
                               &db->st[which], NULL) != SQLITE_OK)
            return srv_dbi_fail(db, "preparing a statement");
    } else {
        sqlite3_reset(db->st[which]);
        sqlite3_clear_bindings(db->st[which]);
    }
    *out = db->st[which];
    return GS_OK;
}

void srv_dbi_bind_real(sqlite3_stmt *q, int i, double v)
{
    if (isfinite(v)) sqlite3_bind_double(q, i, v);
    else sqlite3_bind_null(q, i);
}

double srv_dbi_col_real(sqlite3_stmt *q, int i)
{
    return sqlite3_column_type(q, i) == SQLITE_NULL ? NAN : sqlite3_column_double(q, i);
}

void srv_dbi_col_camera(sqlite3_stmt *q, int first, gis_camera *c)
{
    memset(c, 0, sizeof *c);
    double *v[12] = {&c->lat_deg, &c->lon_deg, &c->height_m, &c->heading_deg, &c->pitch_deg, &c->roll_deg,
                     &c->focal_px, &c->cx_px, &c->cy_px, &c->k1, &c->k2, &c->refraction_k};
    for (int k = 0; k < 12; k++) {
        *v[k] = srv_dbi_col_real(q, first + k);
        if (k >= 9 && isnan(*v[k])) *v[k] = 0.0;   /* no distortion, no refraction */
    }
}

void srv_dbi_bind_text(sqlite3_stmt *q, int i, const char *s)
{
    if (s && *s) sqlite3_bind_text(q, i, s, -1, SQLITE_STATIC);
    else sqlite3_bind_null(q, i);
}

/* An integer, NULL when it equals `none`. */
void srv_dbi_bind_int_or_null(sqlite3_stmt *q, int i, int64_t v, int64_t none)
{
    if (v == none) sqlite3_bind_null(q, i);
    else sqlite3_bind_int64(q, i, v);
}

/* Step an "INSERT ... ON CONFLICT DO NOTHING": *inserted = 1 and *id = the new rowid, or
 * *inserted = 0 when the natural key existed (the caller looks the id up). sqlite3_changes()
 * counts the statement's own row (not the R*Tree trigger's). */
gs_status srv_dbi_step_returning(srv_db *db, sqlite3_stmt *q, int64_t *id, int *inserted,
                                const char *what)
{
    int rc = sqlite3_step(q);
    sqlite3_reset(q);
    if (rc != SQLITE_DONE) return srv_dbi_fail(db, what);
    *inserted = sqlite3_changes(db->db) > 0;
    if (*inserted && id) *id = sqlite3_last_insert_rowid(db->db);
    return GS_OK;
}

gs_status srv_dbi_step_id(srv_db *db, sqlite3_stmt *q, int64_t *id, const char *what)
{
    int rc = sqlite3_step(q);
    if (rc == SQLITE_ROW) {
        if (id) *id = sqlite3_column_int64(q, 0);
        sqlite3_reset(q);
        return GS_OK;
    }
    sqlite3_reset(q);
    if (rc == SQLITE_DONE) return gs_fail(GS_ENOTFOUND, "%s: %s: not found", db->path, what);
    return srv_dbi_fail(db, what);
}

gs_status srv_dbi_step_done(srv_db *db, sqlite3_stmt *q, const char *what)
{
    int rc = sqlite3_step(q);
    sqlite3_reset(q);
    if (rc != SQLITE_DONE) return srv_dbi_fail(db, what);
    return GS_OK;
}

/* ------------------------------------------------------------------ transactions */

gs_status srv_dbi_writable(srv_db *db)
{
    if (db->readonly)
        return gs_fail(GS_EIO, "%s: opened read-only: cannot write to the survey database", db->path);
    return GS_OK;
}

gs_status srv_db_begin(srv_db *db)
{
    if (!db) return gs_fail(GS_EINVAL, "srv_db_begin: NULL database");
    gs_status s = srv_dbi_writable(db);
    if (s != GS_OK) return s;
    if (db->in_txn) return gs_fail(GS_EINVAL, "%s: a transaction is already open", db->path);
    if ((s = srv_dbi_exec(db, "BEGIN IMMEDIATE", "begin")) != GS_OK) return s;
    db->in_txn = 1;
    return GS_OK;
}

gs_status srv_db_commit(srv_db *db)
{
    if (!db) return gs_fail(GS_EINVAL, "srv_db_commit: NULL database");
    if (!db->in_txn) return gs_fail(GS_EINVAL, "%s: commit without a transaction", db->path);
    db->committing = 1;
    gs_status s = srv_dbi_exec(db, "COMMIT", "commit");
    db->committing = 0;
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
    return srv_dbi_exec(db, "ROLLBACK", "rollback");
}

int srv_db_in_transaction(const srv_db *db)
{
    return db && db->in_txn;
}

gs_status srv_dbi_need_txn(srv_db *db, const char *what)
{
    gs_status s = srv_dbi_writable(db);
    if (s != GS_OK) return s;
    if (!db->in_txn)
        return gs_fail(GS_EINVAL, "%s: %s outside a transaction (call srv_db_begin first)",
                       db->path, what);
    return GS_OK;
}

/* Run body-less helpers in a transaction of their own when the caller has none. */
gs_status srv_dbi_auto_begin(srv_db *db, int *began)
{
    *began = 0;
    gs_status s = srv_dbi_writable(db);
    if (s != GS_OK || db->in_txn) return s;
    if ((s = srv_db_begin(db)) == GS_OK) *began = 1;
    return s;
}

gs_status srv_dbi_auto_end(srv_db *db, int began, gs_status s)
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
           "schema version 1.." "7" ")";
}
_Static_assert(SRV_DB_SCHEMA_VERSION == 7, "update expected_text()");

/* The 16-byte header of an existing file: SQLite's, or a one-line error. */
static gs_status check_header(const char *path)
{
    unsigned char head[16] = {0};
    FILE *f = fopen(path, "rb");
    if (!f) return gs_fail(GS_EIO, "%s: cannot read: %s", path, strerror(errno));
    size_t got = fread(head, 1, sizeof head, f);
    fclose(f);
    if (got < sizeof head || memcmp(head, "SQLite format 3", 16) != 0)
        return gs_fail(GS_EFORMAT, "%s: not a survey database: %s; found a file that is not "
                       "SQLite", path, expected_text());
    return GS_OK;
}

/* What an existing SQLite file is, read through the connection open on it (nothing is written;
 * the schema is read once, for this and for what the connection does next). */
static gs_status identify(sqlite3 *db, const char *path, db_kind *kind, int *version)
{
    *version = 0;
    gs_status s = GS_OK;
    int app = 0, user = 0, objects = 0, delight = 0;
    if (!query_int(db, "PRAGMA application_id", &app) || !query_int(db, "PRAGMA user_version", &user) ||
        !query_int(db, "SELECT count(*) FROM sqlite_master", &objects)) {
        s = sql_fail(db, path, "reading the header");
        if (s == GS_EFORMAT)
            s = gs_fail(GS_EFORMAT, "%s: not a survey database: %s; SQLite says: %s", path,
                        expected_text(), sqlite3_errmsg(db));
        return s;
    }
    query_int(db, "SELECT count(*) FROM sqlite_master WHERE name = 'delight_meta'", &delight);
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
            s = srv_dbi_fail(db, "reading the schema version");
            srv_db_rollback(db);
            return s;
        }
        if (version >= target) return srv_db_rollback(db);
        const char *name = srv_db_migrations[version].name;
        char sql[512], now[32];
        srv_dbi_utc_now(now);
        for (const char *const *part = srv_db_migrations[version].sql; *part && s == GS_OK; part++)
            s = srv_dbi_exec(db, *part, name);
        if (s != GS_OK) {
            srv_db_rollback(db);
            return s;
        }
        snprintf(sql, sizeof sql,
                 "%sINSERT INTO migrations VALUES (%d, '%s', '%s', '%s'); PRAGMA user_version = %d",
                 version == 0 ? "PRAGMA application_id = 1196639298; " : "", version + 1, name, now,
                 SRV_GENERATOR, version + 1);
        _Static_assert(SRV_DB_APPLICATION_ID == 1196639298, "application_id literal");
        if ((s = srv_dbi_exec(db, sql, "recording the migration")) != GS_OK ||
            (version == 0 && (s = srv_dbi_exec(db, "INSERT INTO meta VALUES ('created_utc', "
                                           "strftime('%Y-%m-%dT%H:%M:%SZ', 'now'))",
                                       "recording the creation time")) != GS_OK)) {
            srv_db_rollback(db);
            return s;
        }
        if ((s = srv_db_commit(db)) != GS_OK) return s;
    }
}

/* The database file and its sidecars, the file last: once it is gone another creator may make a
 * new one at path, whose own -wal and -shm must not be the ones removed here. */
static void remove_created(const char *path)
{
    static const char *const suffix[] = {"-wal", "-shm", "-journal", ""};
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
    if (!strcmp(path, "-"))
        return gs_fail(GS_EINVAL, "--db -: a survey database is a file, not standard input or output");
    if (mode != SRV_DB_READ && mode != SRV_DB_WRITE && mode != SRV_DB_CREATE && mode != SRV_DB_INIT)
        return gs_fail(GS_EINVAL, "%s: open mode %d: expected SRV_DB_READ, _WRITE, _CREATE or _INIT",
                       path, (int)mode);
    struct stat st;
    int exists = stat(path, &st) == 0;
    db_kind kind = KIND_EMPTY;
    int version = 0;
    gs_status s;
    if (!exists) {
        if (errno != ENOENT)
            return gs_fail(GS_EIO, "%s: cannot %s the survey database: %s", path,
                           mode == SRV_DB_CREATE ? "create" : "open", strerror(errno));
        if (mode != SRV_DB_CREATE && mode != SRV_DB_INIT)
            return gs_fail(GS_ENOTFOUND, "%s: no such survey database (create one with `gridsurvey "
                           "db init --db %s`)", path, path);
        /* built complete under a temporary name, then renamed: no half-made file under path */
        gs_atomic a;
        if (gs_atomic_open(&a, path, 0) != GS_OK) {
            char msg[512];
            snprintf(msg, sizeof msg, "%s", gs_detail());
            return gs_fail(GS_EIO, "cannot create the survey database: %s", msg);
        }
        srv_db *fresh = NULL;
        s = open_at(a.tmp, SRV_DB_INIT, target, &fresh);
        srv_db_close(fresh);
        size_t tl = strlen(a.tmp);
        if (s != GS_OK && !strncmp(gs_detail(), a.tmp, tl) && !strncmp(gs_detail() + tl, ": ", 2)) {
            /* (named as the file the user gave, not the temporary one it is built in) */
            char msg[512];
            snprintf(msg, sizeof msg, "%s", gs_detail() + tl + 2);
            s = gs_fail(s, "%s: cannot create the survey database: %s", path, msg);
        }
        /* closing folds the write-ahead log into the file; if that failed (a full disk, an I/O
         * error), the file alone is not the database: nothing is renamed into place */
        char wal[sizeof a.tmp + 8];
        snprintf(wal, sizeof wal, "%s-wal", a.tmp);
        struct stat ws;
        if (s == GS_OK && lstat(wal, &ws) == 0)
            s = gs_fail(GS_EIO, "%s: cannot create the survey database: writing it failed (a full "
                        "disk or an I/O error)", path);
        int raced = 0;
        if (s == GS_OK) s = gs_atomic_commit_new(&a, &raced);
        else gs_atomic_abort(&a);
        if (s != GS_OK) return s;
        if (raced) return open_at(path, mode, target, out);   /* another process's, now */
        if ((s = open_at(path, SRV_DB_WRITE, target, out)) != GS_OK) {
            remove_created(path);
            return s;
        }
        (*out)->created = 1;
        return GS_OK;
    } else {
        if (!S_ISREG(st.st_mode))
            return gs_fail(GS_EIO, "%s: not a regular file: %s", path, expected_text());
        if (st.st_size > 0 && (s = check_header(path)) != GS_OK) return s;
    }
    srv_db *db = calloc(1, sizeof *db);
    if (!db || !(db->path = strdup(path))) {
        free(db);
        return gs_fail(GS_ENOMEM, "%s: out of memory", path);
    }
    db->readonly = mode == SRV_DB_READ;
    /* (the file exists: a new one was made above, under a temporary name) */
    int flags = db->readonly ? SQLITE_OPEN_READONLY : SQLITE_OPEN_READWRITE;
    if (sqlite3_open_v2(path, &db->db, flags | SQLITE_OPEN_NOMUTEX, NULL) != SQLITE_OK) {
        int sys = db->db ? sqlite3_system_errno(db->db) : 0;
        if (sqlite3_errcode(db->db) == SQLITE_CANTOPEN)
            s = gs_fail(GS_EIO, "%s: cannot open the survey database: %s", path,
                        sys ? strerror(sys) : sqlite3_errmsg(db->db));
        else
            s = sql_fail(db->db, path, "open");
        goto fail;
    }
    /* (before the first read: a writer leaving or entering WAL mode locks the file a moment) */
    sqlite3_busy_timeout(db->db, 10000);
    if (st.st_size > 0 && (s = identify(db->db, path, &kind, &version)) != GS_OK) goto fail;
    /* one rule for every command: only `db init` makes an empty file a survey database */
    if (kind == KIND_EMPTY && mode != SRV_DB_INIT) {
        s = gs_fail(GS_EFORMAT, "%s: an empty file (%s), not a survey database: %s; remove it, or "
                    "make it one with `gridsurvey db init --db %s`", path,
                    st.st_size ? "SQLite without a schema" : "0 bytes", expected_text(), path);
        goto fail;
    }
    if (kind == KIND_SURVEY && version < target && mode == SRV_DB_READ) {
        s = gs_fail(GS_EFORMAT, "%s: survey database schema version %d is older than this "
                    "gridsurvey's %d: migrate it with `gridsurvey db migrate --db %s`", path,
                    version, target, path);
        goto fail;
    }
    if (!db->readonly && sqlite3_db_readonly(db->db, "main") == 1) {
        s = gs_fail(GS_EIO, "%s: the file is read-only: cannot open the survey database for writing",
                    path);
        goto fail;
    }
    sqlite3_extended_result_codes(db->db, 0);
    sqlite3_commit_hook(db->db, refuse_stray_commit, db);
    /* 64 MiB of page cache: the R*Tree and index inserts of a 1e6-light survey touch pages all
     * over the file (docs/survey-db.md, "Scale") */
    if ((s = srv_dbi_exec(db, "PRAGMA foreign_keys = ON; PRAGMA cache_size = -65536", "setting pragmas")) != GS_OK)
        goto fail;
    if (!db->readonly) {
        /* two openers of a new file switch it at once: the one holding its shared lock while the
         * other waits for the exclusive one gets SQLITE_BUSY at once, without the busy handler
         * (SQLite's deadlock rule), so it tries again, up to the busy timeout */
        int wal = 0, busy = 1;
        double until = gs_clock_s(CLOCK_MONOTONIC) + 10.0;
        while (!wal && busy) {
            sqlite3_stmt *q = NULL;
            int rc = sqlite3_prepare_v2(db->db, "PRAGMA journal_mode = WAL", -1, &q, NULL);
            if (rc == SQLITE_OK) rc = sqlite3_step(q);
            const char *jm = rc == SQLITE_ROW ? (const char *)sqlite3_column_text(q, 0) : NULL;
            wal = jm && !strcmp(jm, "wal");
            busy = !wal && (sqlite3_errcode(db->db) == SQLITE_BUSY || rc == SQLITE_BUSY) &&
                   gs_clock_s(CLOCK_MONOTONIC) < until;
            sqlite3_finalize(q);
            if (busy) nanosleep(&(struct timespec){0, 10000000L}, NULL);
        }
        if (!wal) {
            s = srv_dbi_fail(db, "switching to WAL");
            goto fail;
        }
        db->wal = 1;
        /* checkpoint every 10000 pages (40 MiB) rather than 1000: the R*Tree and index pages
         * that every capture rewrites reach the database file once per checkpoint */
        if ((s = srv_dbi_exec(db, "PRAGMA synchronous = NORMAL; PRAGMA wal_autocheckpoint = 10000; "
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

/* For srv_db_close_discard: 1 when no other connection has the file open (leaving WAL mode
 * needs the only one) and no survey is stored in it (by another run, closed since), the file
 * then held under an exclusive lock until closed, so that nobody begins to use it before it is
 * removed (one that opened it already cannot write to it once it is: SQLite refuses a write to
 * a moved file outside WAL mode); else 0: the file stays. */
static int unused_by_others(srv_db *db)
{
    if (db->in_txn) sqlite3_exec(db->db, "ROLLBACK", NULL, NULL, NULL);
    db->in_txn = 0;
    sqlite3_busy_timeout(db->db, 0);
    sqlite3_stmt *q = NULL;
    int ok = sqlite3_prepare_v2(db->db, "PRAGMA journal_mode = DELETE", -1, &q, NULL) == SQLITE_OK &&
             sqlite3_step(q) == SQLITE_ROW && !strcmp((const char *)sqlite3_column_text(q, 0), "delete");
    sqlite3_finalize(q);
    if (!ok) return 0;
    db->wal = 0;
    if (sqlite3_exec(db->db, "BEGIN EXCLUSIVE", NULL, NULL, NULL) != SQLITE_OK) return 0;
    db->in_txn = 1;   /* (srv_db_close rolls it back) */
    ok = sqlite3_prepare_v2(db->db, "SELECT count(*) FROM surveys", -1, &q, NULL) == SQLITE_OK &&
         sqlite3_step(q) == SQLITE_ROW && sqlite3_column_int64(q, 0) == 0;
    sqlite3_finalize(q);
    return ok;
}

void srv_db_close_discard(srv_db *db)
{
    if (!db) return;
    if (db->created && db->db && unused_by_others(db)) remove_created(db->path);
    srv_db_close(db);
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

/* ------------------------------------------------------------------ consistency check */

static gs_status count(srv_db *db, const char *sql, long *v)
{
    sqlite3_stmt *q = NULL;
    if (sqlite3_prepare_v2(db->db, sql, -1, &q, NULL) != SQLITE_OK) return srv_dbi_fail(db, "check");
    int rc = sqlite3_step(q);
    *v = rc == SQLITE_ROW ? (long)sqlite3_column_int64(q, 0) : 0;
    sqlite3_finalize(q);
    if (rc != SQLITE_ROW && rc != SQLITE_DONE) return srv_dbi_fail(db, "check");
    return GS_OK;
}

/* Values of the declared REAL and INTEGER columns of every ordinary table that are text or
 * blobs: SQLite stores them (type affinity converts only what reads as a number), no CHECK
 * says otherwise for most columns, and the readers take such a value as 0. One count query per
 * table, its columns from pragma_table_info. */
static gs_status wrong_types(srv_db *db, long *n)
{
    *n = 0;
    sqlite3_stmt *t = NULL;
    if (sqlite3_prepare_v2(db->db, "SELECT name FROM sqlite_schema WHERE type = 'table' AND name NOT GLOB "
                           "'sqlite_*' AND sql NOT GLOB 'CREATE VIRTUAL*' AND name NOT GLOB '*_rtree_*'",
                           -1, &t, NULL) != SQLITE_OK)
        return srv_dbi_fail(db, "check");
    gs_status s = GS_OK;
    int rc = SQLITE_DONE;
    while (s == GS_OK && (rc = sqlite3_step(t)) == SQLITE_ROW) {
        const char *table = (const char *)sqlite3_column_text(t, 0);
        char *cols = sqlite3_mprintf("SELECT group_concat(printf('typeof(\"%%w\") NOT IN (''null'', ''integer''%%s)', "
                                     "name, CASE WHEN upper(type) = 'REAL' THEN ', ''real''' ELSE '' END), ' OR ') "
                                     "FROM pragma_table_info(%Q) WHERE upper(type) IN ('REAL', 'INTEGER')", table);
        sqlite3_stmt *c = NULL;
        if (!cols || sqlite3_prepare_v2(db->db, cols, -1, &c, NULL) != SQLITE_OK) {
            sqlite3_free(cols);
            s = cols ? srv_dbi_fail(db, "check") : gs_fail(GS_ENOMEM, "%s: check: out of memory", db->path);
            break;
        }
        sqlite3_free(cols);
        const char *where = sqlite3_step(c) == SQLITE_ROW ? (const char *)sqlite3_column_text(c, 0) : NULL;
        if (where) {
            char *sql = sqlite3_mprintf("SELECT count(*) FROM \"%w\" WHERE %s", table, where);
            long v = 0;
            s = sql ? count(db, sql, &v) : gs_fail(GS_ENOMEM, "%s: check: out of memory", db->path);
            sqlite3_free(sql);
            *n += v;
        }
        sqlite3_finalize(c);
    }
    if (s == GS_OK && rc != SQLITE_DONE) s = srv_dbi_fail(db, "check");
    sqlite3_finalize(t);
    return s;
}

gs_status srv_db_check(srv_db *db, srv_db_report *r)
{
    if (!db || !r) return gs_fail(GS_EINVAL, "srv_db_check: NULL argument");
    memset(r, 0, sizeof *r);
    sqlite3_stmt *q = NULL;
    /* SQLite does not parse the CHECK constraints of a database opened read-only, so its
     * integrity_check there passes a row that breaks one: a handle opened read-only checks
     * through a second connection, read-write but query_only (its own when the file itself
     * cannot be written) */
    sqlite3 *rw = NULL;
    if (db->readonly) {
        int ok = sqlite3_open_v2(db->path, &rw, SQLITE_OPEN_READWRITE | SQLITE_OPEN_NOMUTEX, NULL) ==
                 SQLITE_OK && sqlite3_db_readonly(rw, "main") == 0;
        if (ok) sqlite3_busy_timeout(rw, 10000);
        if (!ok || sqlite3_exec(rw, "PRAGMA query_only = 1", NULL, NULL, NULL) != SQLITE_OK) {
            sqlite3_close(rw);
            rw = NULL;
        }
    }
    sqlite3 *h = rw ? rw : db->db;
    if (sqlite3_prepare_v2(h, "PRAGMA integrity_check", -1, &q, NULL) != SQLITE_OK) {
        gs_status s = sql_fail(h, db->path, "integrity_check");
        sqlite3_close(rw);
        return s;
    }
    int rc = sqlite3_step(q);
    const char *res = rc == SQLITE_ROW ? (const char *)sqlite3_column_text(q, 0) : NULL;
    r->integrity_ok = res && !strcmp(res, "ok");
    sqlite3_finalize(q);
    sqlite3_close(rw);
    static const char *const rtrees[] = {"SELECT rtreecheck('locations_rtree')",
                                         "SELECT rtreecheck('light_sites_rtree')"};
    for (int i = 0; i < 2; i++) {
        if (sqlite3_prepare_v2(db->db, rtrees[i], -1, &q, NULL) != SQLITE_OK)
            return srv_dbi_fail(db, "rtreecheck");
        rc = sqlite3_step(q);
        res = rc == SQLITE_ROW ? (const char *)sqlite3_column_text(q, 0) : NULL;
        if (!res || strcmp(res, "ok")) r->integrity_ok = 0;
        sqlite3_finalize(q);
    }
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
        (s = count(db, "SELECT count(*) FROM grid_frequency", &r->frequency_rows)) != GS_OK ||
        (s = count(db, "SELECT count(*) FROM light_sites", &r->sites)) != GS_OK ||
        (s = count(db, "SELECT count(*) FROM lights l WHERE NOT EXISTS (SELECT 1 FROM "
                       "site_detections sd WHERE sd.light_id = l.id)", &r->unassociated)) != GS_OK ||
        (s = count(db, "SELECT count(*) FROM light_sites s WHERE stale = 1 OR detections != "
                       "(SELECT count(*) FROM site_detections sd WHERE sd.site_id = s.id) OR detections != "
                       "(SELECT coalesce(sum(detections), 0) FROM site_views v WHERE v.site_id = s.id)",
                   &r->stale_sites)) != GS_OK ||
        (s = count(db, "SELECT (SELECT count(*) FROM light_sites WHERE lat_deg IS NOT NULL AND "
                       "pose_key IS NULL) - (SELECT count(*) FROM light_sites_rtree)", &r->site_rtree_mismatch)) != GS_OK ||
        (s = wrong_types(db, &r->wrong_types)) != GS_OK)
        return s;
    r->rtree_mismatch = a + b;
    return GS_OK;
}

int srv_db_report_ok(const srv_db_report *r)
{
    return r && r->integrity_ok && r->fk_violations == 0 && r->rtree_rows == r->located &&
           r->rtree_mismatch == 0 && r->incomplete_captures == 0 && r->unassociated == 0 &&
           r->stale_sites == 0 && r->site_rtree_mismatch == 0 && r->wrong_types == 0;
}
