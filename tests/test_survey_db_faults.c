/* test_survey_db_faults.c - SQLite's own allocations failing inside a store, as SQLite's malloc
 * tests do it (sqlite3_config(SQLITE_CONFIG_MALLOC) with an allocator that fails its n-th call;
 * lookaside off, so that every allocation reaches it): a capture stored with SQLite's n-th
 * allocation failing, for every n (every 4th under the sanitizers), must either fail and leave
 * the database as it was, or succeed and leave it as an uninjected store does. SQLite answers some out-of-memory errors by rolling
 * the whole transaction back: a store that went on after one wrote rows outside any transaction
 * (#16, the allocation-site sweep's "FOREIGN KEY constraint failed").
 *
 * Oracle: survey_fx_db_state (every table's rows) before and after an uninjected store. */
#include "survey/survey.h"
#include "tests/fixtures.h"
#include "tests/survey_fixture.h"
#include "tests/test.h"

#include <math.h>
#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static sqlite3_mem_methods sys_mem;
static long alloc_calls, fail_at;   /* fail_at 0: count only */
static int armed;

static int alloc_fails(void)
{
    return armed && ++alloc_calls == fail_at;
}
static void *failing_malloc(int n)
{
    return alloc_fails() ? NULL : sys_mem.xMalloc(n);
}
static void *failing_realloc(void *p, int n)
{
    return alloc_fails() ? NULL : sys_mem.xRealloc(p, n);
}

/* SQLite's default allocator wrapped (each test runs in its own process: no need to undo). */
static int install_failing_allocator(void)
{
    static sqlite3_mem_methods m;
    if (sqlite3_shutdown() != SQLITE_OK || sqlite3_config(SQLITE_CONFIG_GETMALLOC, &sys_mem) != SQLITE_OK)
        return 0;
    m = sys_mem;
    m.xMalloc = failing_malloc;
    m.xRealloc = failing_realloc;
    return sqlite3_config(SQLITE_CONFIG_MALLOC, &m) == SQLITE_OK &&
           sqlite3_config(SQLITE_CONFIG_LOOKASIDE, 0, 0) == SQLITE_OK && sqlite3_initialize() == SQLITE_OK;
}

enum { NL = 6 };

/* A night's NL located lights: night 0 at lights 0..5, night 1 at lights 6, 7, 2..5 (two new
 * sites first, then four that join night 0's: a store that went on outside its transaction
 * commits the new sites). */
static void night_lights(int night, srv_light_row *l, srv_location_row *loc)
{
    double ky = 1.0 / (GIS_EARTH_RADIUS_M * M_PI / 180.0);
    for (int k = 0; k < NL; k++) {
        int i = night && k < 2 ? 6 + k : k;
        l[k] = survey_fx_sodium_light(k, 120.0 * (i % 3));
        srv_location_row_init(&loc[k]);
        loc[k].method = SRV_LOC_ONE_STATION;
        loc[k].lat_deg = 32.8 + 40.0 * i * ky + 0.3 * night * ky;
        loc[k].lon_deg = 35.0;
        loc[k].ellipse = (gis_ellipse){2.0, 1.0, 30.0};
    }
}

/* The base database's bytes (closed: no -wal beside it). */
static char *base_bytes;
static size_t base_size;

/* Stores night 1 into a copy of the base database at work, SQLite's at-th allocation failing
 * (0: none); in_survey: in a transaction that also adds a survey (as `run` stores: the capture
 * in a savepoint), else in srv_db_add_capture's own. The status. */
static gs_status store_night(const char *work, int64_t sid, int in_survey, long at)
{
    char wal[1100];
    snprintf(wal, sizeof wal, "%s-wal", work);
    unlink(wal);
    fx_write_file(work, base_bytes, base_size);
    srv_db *db = NULL;
    CHECK_OK(srv_db_open(work, SRV_DB_WRITE, &db));
    if (!db) return GS_EIO;
    srv_light_row l[NL];
    srv_location_row loc[NL];
    night_lights(1, l, loc);
    srv_capture_data cd = survey_fx_capture(sid, "night1", l, loc, NL);
    alloc_calls = 0;
    fail_at = at;
    armed = 1;
    gs_status s = GS_OK;
    if (in_survey) {
        srv_survey_row sr = {"second", NULL, NULL, NULL, 50};
        int64_t sid2;
        s = srv_db_begin(db);
        if (s == GS_OK) s = srv_db_add_survey(db, &sr, &sid2);
        if (s == GS_OK) s = srv_db_add_capture(db, &cd, NULL, NULL);
        if (s == GS_OK) s = srv_db_commit(db);
        else srv_db_rollback(db);
    } else {
        s = srv_db_add_capture(db, &cd, NULL, NULL);
    }
    armed = 0;
    srv_db_close(db);
    return s;
}

TEST(survey_db_store_survives_every_sqlite_allocation_failure)
{
    CHECK(install_failing_allocator());
    /* the stores on a tmpfs when there is one (their fsyncs are most of the time on a disk) */
    char shm[] = "/dev/shm/gridsurvey-XXXXXX", work[1100];
    const char *base = fx_tmp("base.sqlite"), *dir = mkdtemp(shm);
    snprintf(work, sizeof work, "%s/work.sqlite", dir ? dir : test_tmpdir());
    int64_t sid;
    srv_db *db = survey_fx_create(base, "city", &sid);
    if (!db) return;
    srv_light_row l[NL];
    srv_location_row loc[NL];
    night_lights(0, l, loc);
    srv_capture_data cd = survey_fx_capture(sid, "night0", l, loc, NL);
    CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    srv_db_close(db);
    char *before = survey_fx_db_state(base);
    base_bytes = fx_read_file(base, &base_size);
    for (int in_survey = 0; in_survey < 2; in_survey++) {
        CHECK_OK(store_night(work, sid, in_survey, 0));
        long n = alloc_calls;
        char *after = survey_fx_db_state(work);
        CHECK(n > 100 && strcmp(before, after) != 0);
        /* the store did join night 0's sites (else the association's lookups were not tried) */
        sqlite3 *h = NULL;
        CHECK(sqlite3_open_v2(work, &h, SQLITE_OPEN_READONLY, NULL) == SQLITE_OK);
        CHECK(survey_fx_query_long(h, "SELECT count(*) FROM light_sites WHERE detections = 2") == NL - 2);
        sqlite3_close(h);
        /* every allocation; every 4th under the sanitizers (which make each store slower) */
        long failed = 0, bad = 0, tried = 0, step = fx_sanitized() ? 4 : 1;
        for (long at = 1; at <= n; at += step, tried++) {
            gs_status s = store_night(work, sid, in_survey, at);
            char *st = survey_fx_db_state(work);
            failed += s != GS_OK;
            int ok = !strcmp(st, s == GS_OK ? after : before);
            if (!ok && bad++ < 3)
                test_failed(__FILE__, __LINE__, "%s store, SQLite allocation %ld of %ld failing: %s, and the "
                            "database is %s", in_survey ? "survey+capture" : "capture", at, n,
                            s == GS_OK ? "succeeded" : gs_detail(),
                            !strcmp(st, after) ? "complete" : !strcmp(st, before) ? "as before" : "neither");
            free(st);
        }
        CHECK_MSG(bad == 0, "%ld of %ld injected stores left the database wrong", bad, tried);
        CHECK_MSG(failed > tried / 2, "only %ld of %ld injected allocations failed the store", failed, tried);
        free(after);
    }
    free(before);
    free(base_bytes);
    if (dir) {
        unlink(work);
        rmdir(dir);
    }
}

/* The guard behind the sweep above (survey/db.c, refuse_stray_commit): once SQLite has rolled a
 * transaction back by itself (here: a ROLLBACK on the raw handle, as SQLite does on out of
 * memory or a full disk), a statement of the caller's would run in a transaction of its own and
 * be committed at once. It is refused: one message that the transaction was lost, nothing of it
 * stored, and the handle usable afterwards. Oracle: survey_fx_db_state before and after. */
TEST(survey_db_refuses_a_commit_after_sqlite_rolled_back)
{
    const char *path = fx_tmp("lost.sqlite");
    int64_t sid;
    srv_db *db = survey_fx_create(path, "city", &sid);
    if (!db) return;
    char *before = survey_fx_db_state(path);
    srv_survey_row sr = {"second", NULL, NULL, NULL, 50};
    int64_t sid2;
    CHECK_OK(srv_db_begin(db));
    CHECK_OK(srv_db_add_survey(db, &sr, &sid2));
    CHECK(sqlite3_exec(srv_db_sqlite(db), "ROLLBACK", NULL, NULL, NULL) == SQLITE_OK);
    srv_light_row l[NL];
    srv_location_row loc[NL];
    night_lights(0, l, loc);
    srv_capture_data cd = survey_fx_capture(sid, "night0", l, loc, NL);
    gs_status s = srv_db_add_capture(db, &cd, NULL, NULL);
    CHECK_MSG(s == GS_ESQL && fx_contains(gs_detail(), "the transaction was lost"), "%d: %s", s, gs_detail());
    /* a statement of its own (no savepoint) is refused at its commit */
    s = srv_db_add_survey(db, &sr, &sid2);
    CHECK_MSG(s == GS_ESQL && fx_contains(gs_detail(), "the transaction was lost"), "%d: %s", s, gs_detail());
    CHECK_OK(srv_db_rollback(db));
    char *after = survey_fx_db_state(path);
    CHECK_MSG(!strcmp(before, after), "%s", after);
    /* a new transaction works */
    CHECK_OK(srv_db_add_capture(db, &cd, NULL, NULL));
    srv_db_close(db);
    char *stored = survey_fx_db_state(path);
    CHECK(strcmp(stored, before) != 0);
    free(before);
    free(after);
    free(stored);
}
