/* test_delight_store.c - DELIGHT storage (paper Sec. 3): exact CSV and SQLite round trips,
 * rejection of files that are not DELIGHT databases, and malformed CSV rejected atomically
 * with a detail naming the file, line and field. */
#include "recognize/base/internal.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* A band-limited BRF from a sum of cosines with awkward coefficients (so %.17g matters). */
static void make_bulb(gs_bulb *b, const char *id, int grid_hz, const char *sensor, int bands, int n,
                      gs_tech type, gs_ref ref, double seed)
{
    memset(b, 0, sizeof *b);
    snprintf(b->id, sizeof b->id, "%s", id);
    snprintf(b->name, sizeof b->name, "test bulb %s (%.1f W)", id, 10 * seed);
    snprintf(b->sensor, sizeof b->sensor, "%s", sensor);
    b->type = type;
    b->ref = ref;
    b->grid_hz = grid_hz;
    b->watts = 10 * seed + 1.0 / 3.0;
    CHECK_OK(gs_brf_init(&b->brf, n, bands));
    for (int band = 0; band < bands; band++)
        for (int j = 0; j < n; j++) {
            double t = (double)j / n;
            b->brf.v[band * n + j] = 2.0 + seed * cos(2 * M_PI * (t - 0.1 * band)) +
                                     0.3 * cos(2 * M_PI * 2 * t + seed) + 0.01 * sin(2 * M_PI * 5 * t);
        }
    CHECK_OK(gs_brf_normalize(&b->brf, NULL));
    if (bands == 1) {
        b->chroma[0] = 1;
    } else {
        b->chroma[0] = 0.41 / 1.3;
        b->chroma[1] = 0.53 / 1.3;
        b->chroma[2] = 1 - b->chroma[0] - b->chroma[1];
    }
}

/* Four entries: mono and RGB, both grids, every reference kind. */
static gs_delight *make_db(int n)
{
    gs_delight *d = gs_delight_new();
    gs_bulb b;
    make_bulb(&b, "inc-60W", 50, "photodiode", 1, n, GS_TECH_INCANDESCENT, GS_REF_VOLTAGE, 0.11);
    CHECK_OK(gs_delight_add(d, &b));
    gs_bulb_release(&b);
    make_bulb(&b, "inc-60W", 50, "rgb", 3, n, GS_TECH_INCANDESCENT, GS_REF_VOLTAGE, 0.13);
    CHECK_OK(gs_delight_add(d, &b));
    gs_bulb_release(&b);
    make_bulb(&b, "Sodium_HP.250", 60, "rgb", 3, n, GS_TECH_SODIUM_HP, GS_REF_NONE, 0.9);
    CHECK_OK(gs_delight_add(d, &b));
    gs_bulb_release(&b);
    make_bulb(&b, "hue", 60, "photodiode", 1, n, GS_TECH_LED_PWM, GS_REF_UNLOCKED, 0.97);
    CHECK_OK(gs_delight_add(d, &b));
    gs_bulb_release(&b);
    return d;
}

/* Every field equal, BRF samples bit for bit. */
static int same_bulb(const gs_bulb *a, const gs_bulb *b)
{
    size_t vals = (size_t)a->brf.n * (size_t)a->brf.bands;
    return strcmp(a->id, b->id) == 0 && strcmp(a->name, b->name) == 0 &&
           strcmp(a->sensor, b->sensor) == 0 && a->type == b->type && a->ref == b->ref &&
           a->grid_hz == b->grid_hz && memcmp(&a->watts, &b->watts, sizeof a->watts) == 0 &&
           a->brf.n == b->brf.n && a->brf.bands == b->brf.bands &&
           memcmp(a->chroma, b->chroma, sizeof(double) * (size_t)a->brf.bands) == 0 &&
           memcmp(a->brf.v, b->brf.v, vals * sizeof(double)) == 0;
}

static int same_db(const gs_delight *a, const gs_delight *b)
{
    if (gs_delight_count(a) != gs_delight_count(b)) return 0;
    for (size_t i = 0; i < gs_delight_count(a); i++)
        if (!same_bulb(gs_delight_get(a, i), gs_delight_get(b, i))) return 0;
    return 1;
}

static void export_to(const gs_delight *d, const char *path)
{
    FILE *f = fopen(path, "w");
    CHECK(f != NULL);
    if (!f) return;
    CHECK_OK(gs_delight_export_csv(d, f));
    fclose(f);
}

/* ------------------------------------------------------------------- CSV */

TEST(delight_csv_round_trip_exact)
{
    gs_delight *d = make_db(1024), *e = gs_delight_new();
    const char *a = fx_tmp("a.csv"), *b = fx_tmp("b.csv");
    export_to(d, a);
    CHECK_OK(gs_delight_import_csv(e, a));
    CHECK(same_db(d, e));
    export_to(e, b);
    size_t la, lb;
    char *ta = fx_read_file(a, &la), *tb = fx_read_file(b, &lb);
    CHECK(ta && tb && la == lb && memcmp(ta, tb, la) == 0);
    /* the header and the first row's leading fields, exactly */
    CHECK(ta && strncmp(ta, "bulb_id,type,name,watts,grid_hz,sensor,band,chromaticity,n,v0,v1,", 65) == 0);
    CHECK(ta && strstr(ta, ",v1023\n") != NULL && strstr(ta, ",v1024") == NULL);
    CHECK(ta && strstr(ta, "\ninc-60W,incandescent,test bulb inc-60W (1.1 W),1.4333333333333333,50,"
                           "photodiode/voltage,mono,1,1024,") != NULL);
    CHECK(ta && strstr(ta, "\nSodium_HP.250,sodium_hp,") && strstr(ta, ",60,rgb/none,G,"));
    CHECK(ta && strstr(ta, ",photodiode/unlocked,mono,"));
    free(ta);
    free(tb);
    /* import appends */
    gs_delight *f = make_db(8);
    gs_delight_free(e);
    e = gs_delight_new();
    export_to(f, a);
    gs_bulb extra;
    make_bulb(&extra, "first", 50, "photodiode", 1, 8, GS_TECH_CFL, GS_REF_NONE, 0.2);
    CHECK_OK(gs_delight_add(e, &extra));
    CHECK_OK(gs_delight_import_csv(e, a));
    CHECK(gs_delight_count(e) == 5);
    CHECK(same_bulb(gs_delight_get(e, 0), &extra));
    CHECK(same_bulb(gs_delight_get(e, 4), gs_delight_get(f, 3)));
    gs_bulb_release(&extra);
    gs_delight_free(d);
    gs_delight_free(e);
    gs_delight_free(f);
}

TEST(delight_csv_crlf_bom_and_empty_database)
{
    gs_delight *d = make_db(16), *e = gs_delight_new();
    const char *a = fx_tmp("a.csv"), *b = fx_tmp("crlf.csv");
    export_to(d, a);
    char *text = fx_read_file(a, NULL);
    FILE *f = fopen(b, "wb");
    CHECK(text && f);
    if (text && f) {
        fputs("\xEF\xBB\xBF", f);
        for (char *c = text; *c; c++) {
            if (*c == '\n') fputc('\r', f);
            fputc(*c, f);
        }
    }
    if (f) fclose(f);
    free(text);
    CHECK_OK(gs_delight_import_csv(e, b));
    CHECK(same_db(d, e));
    /* an empty database exports a header only, which imports as nothing */
    gs_delight *empty = gs_delight_new(), *g = gs_delight_new();
    export_to(empty, a);
    char *h = fx_read_file(a, NULL);
    CHECK(h && strcmp(h, "bulb_id,type,name,watts,grid_hz,sensor,band,chromaticity,n\n") == 0);
    free(h);
    CHECK_OK(gs_delight_import_csv(g, a));
    CHECK(gs_delight_count(g) == 0);
    gs_delight_free(d);
    gs_delight_free(e);
    gs_delight_free(empty);
    gs_delight_free(g);
}

#define HDR "bulb_id,type,name,watts,grid_hz,sensor,band,chromaticity,n,v0,v1,v2,v3\n"
#define MONO "a,cfl,A lamp,13,50,photodiode/voltage,mono,1,4,1.5,0.5,1.25,0.75\n"
#define RED "b,led_pwm,B,9,60,rgb/none,R,0.25,4,1,1,1,1\n"
#define GREEN "b,led_pwm,B,9,60,rgb/none,G,0.5,4,2,0,2,0\n"
#define BLUE "b,led_pwm,B,9,60,rgb/none,B,0.25,4,1,1,1,1\n"

TEST(delight_csv_small_file_imports)
{
    const char *p = fx_tmp("ok.csv");
    fx_write_text(p, HDR MONO RED GREEN BLUE);
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_import_csv(d, p));
    CHECK(gs_delight_count(d) == 2);
    const gs_bulb *b = gs_delight_find(d, "b", 60, 3);
    CHECK(b && b->ref == GS_REF_NONE && b->type == GS_TECH_LED_PWM && b->brf.v[4] == 2.0 &&
          b->chroma[1] == 0.5 && strcmp(b->sensor, "rgb") == 0);
    gs_delight_free(d);
}

TEST(delight_csv_malformed_rejected_atomically)
{
    static const struct {
        const char *label, *text;
        int line;
        const char *field;
    } cases[] = {
        {"empty", "", 1, "bulb_id"},
        {"wrong header", "bulb,type,name,watts,grid_hz,sensor,band,chromaticity,n,v0\n" MONO, 1, "bulb_id"},
        {"header gap", "bulb_id,type,name,watts,grid_hz,sensor,band,chromaticity,n,v0,v2\n", 1, "v1"},
        {"truncated row", HDR MONO "b,led_pwm,B,9,60,rgb/none,R,0.25,4,1,1\n", 3, "v2"},
        {"truncated fixed", HDR MONO "b,led_pwm,B,9\n", 3, "grid_hz"},
        {"nan value", HDR MONO RED "b,led_pwm,B,9,60,rgb/none,G,0.5,4,2,nan,2,0\n" BLUE, 4, "v1"},
        {"inf watts", HDR "a,cfl,A lamp,inf,50,photodiode/voltage,mono,1,4,1,1,1,1\n", 2, "watts"},
        {"bad number", HDR MONO RED GREEN "b,led_pwm,B,9,60,rgb/none,B,0.25x,4,1,1,1,1\n", 5, "chromaticity"},
        {"bad value", HDR "a,cfl,A,13,50,photodiode/voltage,mono,1,4,1.5,0.5,1.2.5,0.75\n", 2, "v2"},
        {"missing band", HDR RED GREEN MONO, 4, "band"},
        {"missing band at end", HDR MONO RED GREEN, 5, "band"},
        {"band order", HDR RED BLUE GREEN, 3, "band"},
        {"first band", HDR GREEN, 2, "band"},
        {"n mismatch", HDR "a,cfl,A,13,50,photodiode/voltage,mono,1,4,1.5,0.5,1.25,0.75,1\n", 2, "v4"},
        {"n too big", HDR "a,cfl,A,13,50,photodiode/voltage,mono,1,6,1,1,1,1,1,1\n", 2, "n"},
        {"unknown type", HDR "a,fire,A,13,50,photodiode/voltage,mono,1,4,1,1,1,1\n", 2, "type"},
        {"bad grid", HDR "a,cfl,A,13,55,photodiode/voltage,mono,1,4,1,1,1,1\n", 2, "grid_hz"},
        {"bad reference", HDR "a,cfl,A,13,50,photodiode/phase,mono,1,4,1,1,1,1\n", 2, "sensor"},
        {"no reference", HDR "a,cfl,A,13,50,photodiode,mono,1,4,1,1,1,1\n", 2, "sensor"},
        {"not consecutive", HDR MONO RED GREEN BLUE MONO, 6, "bulb_id"},
        {"type differs", HDR RED "b,cfl,B,9,60,rgb/none,G,0.5,4,2,0,2,0\n" BLUE, 3, "type"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        char name[64];
        snprintf(name, sizeof name, "bad%zu.csv", i);
        const char *p = fx_tmp(name);
        fx_write_text(p, cases[i].text);
        gs_delight *d = gs_delight_new();
        gs_bulb keep;
        make_bulb(&keep, "kept", 50, "photodiode", 1, 4, GS_TECH_HALOGEN, GS_REF_VOLTAGE, 0.3);
        CHECK_OK(gs_delight_add(d, &keep));
        gs_bulb_release(&keep);
        gs_status s = gs_delight_import_csv(d, p);
        char where[700], field[64];
        snprintf(where, sizeof where, "%s:%d: ", p, cases[i].line);
        snprintf(field, sizeof field, "field %s: expected ", cases[i].field);
        CHECK_MSG(s == GS_EFORMAT, "%s: status %s", cases[i].label, gs_strerror(s));
        CHECK_MSG(strncmp(gs_detail(), where, strlen(where)) == 0 && strstr(gs_detail(), field),
                  "%s: detail '%s': expected '%s... %s'", cases[i].label, gs_detail(), where, field);
        CHECK_MSG(!strchr(gs_detail(), '\n'), "%s: detail is not one line", cases[i].label);
        CHECK_MSG(gs_delight_count(d) == 1, "%s: %zu entries after a failed import", cases[i].label,
                  gs_delight_count(d));
        gs_delight_free(d);
    }
}

TEST(delight_csv_inconsistent_entry_and_duplicates)
{
    /* a BRF whose mean is not 1 fails validation; the detail names the file and the line */
    const char *p = fx_tmp("mean.csv");
    fx_write_text(p, HDR MONO "c,cfl,C,13,50,photodiode/voltage,mono,1,4,2,2,2,2\n");
    gs_delight *d = gs_delight_new();
    CHECK(gs_delight_import_csv(d, p) == GS_EINVAL);
    char where[700];
    snprintf(where, sizeof where, "%s:3: ", p);
    CHECK_MSG(strncmp(gs_detail(), where, strlen(where)) == 0, "detail '%s'", gs_detail());
    CHECK(gs_delight_count(d) == 0);
    /* importing a bulb already present adds nothing */
    const char *q = fx_tmp("dup.csv");
    fx_write_text(q, HDR RED GREEN BLUE MONO);
    fx_write_text(p, HDR MONO);
    CHECK_OK(gs_delight_import_csv(d, p));
    CHECK(gs_delight_import_csv(d, q) == GS_EINVAL);
    CHECK(strstr(gs_detail(), q) && strstr(gs_detail(), "already"));
    CHECK(gs_delight_count(d) == 1);
    CHECK(gs_delight_import_csv(d, fx_tmp("missing.csv")) == GS_ENOTFOUND);
    /* a missing band names the bulb, and a file that ends before it says so ("field band:
     * expected B" alone, at a line past the end, read like a typo in a band column) */
    fx_write_text(p, HDR RED GREEN);
    CHECK(gs_delight_import_csv(d, p) == GS_EFORMAT);
    CHECK_MSG(strstr(gs_detail(), ":4: field band: expected B, the next band of bulb b: the file ends "
                     "before it"), "%s", gs_detail());
    fx_write_text(p, HDR RED GREEN RED);
    CHECK(gs_delight_import_csv(d, p) == GS_EFORMAT);
    CHECK_MSG(strstr(gs_detail(), ":4: field band: expected B, the next band of bulb b (found R)"),
              "%s", gs_detail());
    /* a header with samples alone (a file cut short after it) made an empty database, exit 0 */
    fx_write_text(p, HDR);
    CHECK(gs_delight_import_csv(d, p) == GS_EFORMAT);
    CHECK_MSG(strstr(gs_detail(), ":2: no bulb after a header of 4 samples"), "%s", gs_detail());
    CHECK(gs_delight_count(d) == 1);
    gs_delight_free(d);
}

/* ---------------------------------------------------------------- SQLite */

TEST(delight_sqlite_round_trip_exact)
{
    gs_delight *d = make_db(1024), *e = gs_delight_new();
    const char *db = fx_tmp("delight.sqlite");
    CHECK_OK(gs_delight_save(d, db));
    CHECK_OK(gs_delight_load(e, db));
    CHECK(same_db(d, e));
    /* saving again replaces the tables (no duplicates); load appends */
    gs_delight *small = make_db(8);
    CHECK_OK(gs_delight_save(small, db));
    gs_delight *g = gs_delight_new();
    CHECK_OK(gs_delight_load(g, db));
    CHECK(same_db(small, g));
    CHECK(gs_delight_load(g, db) == GS_EINVAL);   /* all already present */
    CHECK(gs_delight_count(g) == 4);
    gs_delight_free(d);
    gs_delight_free(e);
    gs_delight_free(small);
    gs_delight_free(g);
}

static int query_int(sqlite3 *db, const char *sql)
{
    sqlite3_stmt *q = NULL;
    int v = -1;
    if (sqlite3_prepare_v2(db, sql, -1, &q, NULL) == SQLITE_OK && sqlite3_step(q) == SQLITE_ROW)
        v = sqlite3_column_int(q, 0);
    sqlite3_finalize(q);
    return v;
}

TEST(delight_sqlite_schema_versioned)
{
    gs_delight *d = make_db(16);
    const char *path = fx_tmp("delight.sqlite");
    CHECK_OK(gs_delight_save(d, path));
    sqlite3 *db = NULL;
    CHECK(sqlite3_open(path, &db) == SQLITE_OK);
    CHECK(query_int(db, "PRAGMA user_version") == GS_DELIGHT_SCHEMA_VERSION);
    CHECK(query_int(db, "SELECT count(*) FROM delight_meta WHERE key = 'format' AND value = "
                        "'gridsurvey-delight'") == 1);
    CHECK(query_int(db, "SELECT value FROM delight_meta WHERE key = 'schema_version'") ==
          GS_DELIGHT_SCHEMA_VERSION);
    CHECK(query_int(db, "SELECT count(*) FROM delight_bulbs") == 4);
    CHECK(query_int(db, "SELECT count(*) FROM delight_brf_bands") == 8);
    CHECK(query_int(db, "SELECT count(*) FROM pragma_foreign_key_check") == 0);
    CHECK(query_int(db, "SELECT count(*) FROM pragma_foreign_key_list('delight_brf_bands')") == 3);
    /* samples: n little-endian doubles */
    sqlite3_stmt *q = NULL;
    CHECK(sqlite3_prepare_v2(db, "SELECT samples FROM delight_brf_bands WHERE bulb_id = 'hue'", -1,
                             &q, NULL) == SQLITE_OK);
    if (q && sqlite3_step(q) == SQLITE_ROW) {
        const unsigned char *p = sqlite3_column_blob(q, 0);
        CHECK(sqlite3_column_bytes(q, 0) == 16 * 8);
        unsigned long long u = 0;
        for (int k = 0; k < 8; k++) u |= (unsigned long long)p[8 + k] << (8 * k);
        double v;
        memcpy(&v, &u, sizeof v);
        CHECK(v == gs_delight_get(d, 3)->brf.v[1]);
    } else {
        CHECK(!"no samples row");
    }
    sqlite3_finalize(q);
    sqlite3_close(db);
    gs_delight_free(d);
}

TEST(delight_sqlite_rejects_other_files)
{
    gs_delight *d = make_db(8);
    size_t before = gs_delight_count(d);
    /* an SQLite file that is not a DELIGHT database */
    const char *other = fx_tmp("other.sqlite");
    sqlite3 *db = NULL;
    CHECK(sqlite3_open(other, &db) == SQLITE_OK);
    CHECK(sqlite3_exec(db, "CREATE TABLE lights(id INTEGER); PRAGMA user_version = 7", NULL, NULL,
                       NULL) == SQLITE_OK);
    sqlite3_close(db);
    CHECK(gs_delight_load(d, other) == GS_EFORMAT);
    CHECK(strstr(gs_detail(), other) && strstr(gs_detail(), "gridsurvey-delight") &&
          !strchr(gs_detail(), '\n') && !strstr(gs_detail(), "survey database"));
    /* a survey database (its application_id) given for a DELIGHT one is named so */
    const char *survey = fx_tmp("survey-as-delight.sqlite");
    CHECK(sqlite3_open(survey, &db) == SQLITE_OK);
    CHECK(sqlite3_exec(db, "CREATE TABLE surveys(id INTEGER); PRAGMA user_version = 5; PRAGMA application_id = "
                       "1196639298", NULL, NULL, NULL) == SQLITE_OK);
    sqlite3_close(db);
    CHECK(gs_delight_load(d, survey) == GS_EFORMAT);
    CHECK_MSG(strstr(gs_detail(), survey) && strstr(gs_detail(), "a survey database, which goes with --db"), "%s",
              gs_detail());
    /* ... and save refuses to overwrite it */
    CHECK(gs_delight_save(d, other) == GS_EFORMAT);
    CHECK(strstr(gs_detail(), other) != NULL);
    CHECK(sqlite3_open(other, &db) == SQLITE_OK);
    CHECK(query_int(db, "PRAGMA user_version") == 7);
    CHECK(query_int(db, "SELECT count(*) FROM sqlite_master WHERE name LIKE 'delight%'") == 0);
    sqlite3_close(db);
    /* an SQLite file with user_version 1 but no DELIGHT tables */
    const char *fake = fx_tmp("fake.sqlite");
    CHECK(sqlite3_open(fake, &db) == SQLITE_OK);
    CHECK(sqlite3_exec(db, "CREATE TABLE t(x); PRAGMA user_version = 1", NULL, NULL, NULL) == SQLITE_OK);
    sqlite3_close(db);
    CHECK(gs_delight_load(d, fake) == GS_EFORMAT);
    CHECK(strstr(gs_detail(), fake) != NULL);
    /* a text file */
    const char *text = fx_tmp("delight.csv");
    fx_write_text(text, "bulb_id,type,name,watts,grid_hz,sensor,band,chromaticity,n\n"
                     "this is not an SQLite database, but it is long enough to look like one\n");
    CHECK(gs_delight_load(d, text) == GS_EFORMAT);
    CHECK(strstr(gs_detail(), text) && strstr(gs_detail(), "DELIGHT"));
    /* a missing file */
    CHECK(gs_delight_load(d, fx_tmp("missing.sqlite")) == GS_ENOTFOUND);
    CHECK(gs_delight_count(d) == before);
    gs_delight_free(d);
}

TEST(delight_sqlite_bad_entry_rejected_atomically)
{
    gs_delight *d = make_db(8);
    const char *path = fx_tmp("delight.sqlite");
    CHECK_OK(gs_delight_save(d, path));
    sqlite3 *db = NULL;
    CHECK(sqlite3_open(path, &db) == SQLITE_OK);
    /* the last bulb's BRF becomes all zeros (mean 0): invalid */
    CHECK(sqlite3_exec(db, "UPDATE delight_brf_bands SET samples = zeroblob(64) WHERE bulb_id = 'hue'",
                       NULL, NULL, NULL) == SQLITE_OK);
    sqlite3_close(db);
    gs_delight *e = gs_delight_new();
    gs_bulb keep;
    make_bulb(&keep, "kept", 50, "photodiode", 1, 8, GS_TECH_HALOGEN, GS_REF_VOLTAGE, 0.3);
    CHECK_OK(gs_delight_add(e, &keep));
    gs_bulb_release(&keep);
    CHECK(gs_delight_load(e, path) == GS_EINVAL);
    CHECK(strstr(gs_detail(), path) && strstr(gs_detail(), "hue"));
    CHECK(gs_delight_count(e) == 1);
    /* a missing band */
    CHECK_OK(gs_delight_save(d, path));
    CHECK(sqlite3_open(path, &db) == SQLITE_OK);
    CHECK(sqlite3_exec(db, "DELETE FROM delight_brf_bands WHERE sensor = 'rgb' AND band = 2 AND "
                           "grid_hz = 60", NULL, NULL, NULL) == SQLITE_OK);
    sqlite3_close(db);
    CHECK(gs_delight_load(e, path) == GS_EFORMAT);
    CHECK(strstr(gs_detail(), path) && strstr(gs_detail(), "Sodium_HP.250"));
    CHECK(gs_delight_count(e) == 1);
    gs_delight_free(d);
    gs_delight_free(e);
}
