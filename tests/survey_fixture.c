/* survey_fixture.c - survey databases for the tests; the contract is in tests/survey_fixture.h. */
#include "tests/survey_fixture.h"

#include "tests/test.h"

#include <stdio.h>
#include <string.h>

long survey_fx_query_long(sqlite3 *h, const char *sql)
{
    sqlite3_stmt *q = NULL;
    long v = -1;
    if (sqlite3_prepare_v2(h, sql, -1, &q, NULL) == SQLITE_OK && sqlite3_step(q) == SQLITE_ROW)
        v = (long)sqlite3_column_int64(q, 0);
    else
        test_failed(__FILE__, __LINE__, "query '%s': %s", sql, sqlite3_errmsg(h));
    sqlite3_finalize(q);
    return v;
}

const char *survey_fx_query_text(sqlite3 *h, const char *sql)
{
    static char buf[256];
    sqlite3_stmt *q = NULL;
    buf[0] = '\0';
    if (sqlite3_prepare_v2(h, sql, -1, &q, NULL) == SQLITE_OK && sqlite3_step(q) == SQLITE_ROW &&
        sqlite3_column_text(q, 0))
        snprintf(buf, sizeof buf, "%s", (const char *)sqlite3_column_text(q, 0));
    sqlite3_finalize(q);
    return buf;
}

int survey_fx_has(sqlite3 *h, const char *name)
{
    sqlite3_stmt *q = NULL;
    int n = 0;
    const char *sql = "SELECT count(*) FROM sqlite_master WHERE name = ?";
    if (sqlite3_prepare_v2(h, sql, -1, &q, NULL) == SQLITE_OK &&
        sqlite3_bind_text(q, 1, name, -1, SQLITE_STATIC) == SQLITE_OK && sqlite3_step(q) == SQLITE_ROW)
        n = sqlite3_column_int(q, 0);
    sqlite3_finalize(q);
    return n > 0;
}

srv_synth_opts survey_fx_synth_opts(const char *survey, size_t captures, size_t lights,
                                    unsigned long long seed)
{
    srv_synth_opts o;
    srv_synth_opts_default(&o);
    o.survey = survey;
    o.captures = captures;
    o.lights_per_capture = lights;
    o.seed = seed;
    o.half_width_m = 0.0;
    return o;
}

void survey_fx_synth(const char *path, const srv_synth_opts *o)
{
    srv_db *db = NULL;
    CHECK_OK(srv_db_open(path, SRV_DB_CREATE, &db));
    CHECK_OK(srv_synth_ingest(db, o, NULL));
    srv_db_close(db);
}

void survey_fx_synth_square(const char *path, const char *survey, size_t captures, size_t lights,
                            unsigned long long seed)
{
    srv_synth_opts o = survey_fx_synth_opts(survey, captures, lights, seed);
    o.view_half_width_m = 2000.0;
    survey_fx_synth(path, &o);
}

srv_db *survey_fx_create(const char *path, const char *survey, int64_t *survey_id)
{
    srv_db *db = NULL;
    *survey_id = 0;
    CHECK_OK(srv_db_open(path, SRV_DB_CREATE, &db));
    if (!db) return NULL;
    srv_survey_row sr = {survey, NULL, NULL, NULL, 50};
    CHECK_OK(srv_db_add_survey(db, &sr, survey_id));
    return db;
}

srv_light_row survey_fx_light(int index, double x_px, double y_px, double phase_deg,
                              double confidence)
{
    srv_light_row l;
    srv_light_row_init(&l);
    l.index = index;
    l.x_px = x_px;
    l.y_px = y_px;
    l.phase_deg = phase_deg;
    l.confidence = l.bulb_confidence = l.phase_confidence = confidence;
    return l;
}

srv_light_row survey_fx_sodium_light(int i, double phase_deg)
{
    srv_light_row l = survey_fx_light(i, 10.0 + i, 20.0, phase_deg, 0.95);
    l.bulb_id = "sodium_hp_150w";
    l.technology = "sodium_hp";
    return l;
}

srv_capture_data survey_fx_capture(int64_t survey_id, const char *key, srv_light_row *lights,
                                   srv_location_row *locations, size_t n)
{
    srv_capture_data cd;
    memset(&cd, 0, sizeof cd);
    srv_capture_row_init(&cd.capture);
    cd.capture.survey_id = survey_id;
    cd.capture.key = key;
    cd.lights = lights;
    cd.locations = locations;
    cd.n_lights = n;
    return cd;
}
