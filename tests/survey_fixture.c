/* survey_fixture.c - survey databases for the tests; the contract is in tests/survey_fixture.h. */
#include "tests/survey_fixture.h"

#include "tests/fixtures.h"
#include "tests/test.h"

#include <stdio.h>
#include <stdlib.h>
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

srv_phase_stats survey_fx_stats_all(srv_db *db, int detections)
{
    srv_stats_opts o;
    srv_stats_opts_default(&o);
    o.detections = detections;
    srv_phase_stats *g = NULL, r;
    size_t n = 0;
    memset(&r, 0, sizeof r);
    CHECK_OK(srv_stats_compute(db, &o, &g, &n, NULL));
    if (n == 1) r = g[0];
    free(g);
    return r;
}

/* ------------------------------------------------------------------ the small lab scene */

static const struct lab_light {
    const char *id, *bulb;
    int phase;
    double x, y, d, lm;
} lab_lights[8] = {
    {"inc60", "inc-a60-60w-230v", 0, 110.3, 140.6, 3.0, 710},
    {"cfl20", "cfl-20w", 120, 250.7, 120.2, 3.5, 1200},
    {"led9", "led-a60-9w-cap", 240, 390.1, 135.9, 3.0, 806},
    {"fl36", "fl-t8-36w-tri", 0, 530.4, 150.3, 4.0, 3350},
    {"hps70", "hps-70w", 120, 140.8, 330.5, 8.0, 6000},
    {"ledfil", "led-fil-4w-lin", 240, 280.2, 345.1, 2.0, 470},
    {"hal42", "hal-a60-42w-230v", 120, 420.6, 320.8, 2.5, 630},
    {"mh70", "mh-70w", 240, 545.5, 360.2, 10.0, 5500},
};

double survey_fx_lab_x_px(int i, double scale)
{
    return (lab_lights[i].x + 0.5) * scale - 0.5;
}

double survey_fx_lab_y_px(int i, double scale)
{
    return (lab_lights[i].y + 0.5) * scale - 0.5;
}

survey_lab_spec survey_fx_lab_spec(void)
{
    survey_lab_spec s;
    for (int i = 0; i < 8; i++) {
        s.bulb[i] = lab_lights[i].bulb;
        s.phase_deg[i] = lab_lights[i].phase;
    }
    s.seed = 4;
    return s;
}

/* The lab scene (capture/scenes/lab.json) made small: the same eight bulbs, phases, fluxes and
 * effects at `scale` times the pixel coordinates and image size (1/2: 320 x 240, 1/4: 160 x 120;
 * the focal length scales too, so the lights' angles are the lab's), C = 128 cycles instead of
 * 256, with the bulbs, phases and noise seed of spec. */
void survey_fx_small_lab(const char *path, double scale, const survey_lab_spec *spec)
{
    const struct lab_light *L = lab_lights;
    char lights[2048] = "";
    for (int i = 0; i < 8; i++) {
        size_t used = strlen(lights);
        snprintf(lights + used, sizeof lights - used,
                 "%s    {\"id\": \"%s\", \"bulb\": \"%s\", \"phase_deg\": %d, \"x_px\": %.4f, \"y_px\": %.4f, "
                 "\"distance_m\": %g, \"lumens\": %g}", i ? ",\n" : "", L[i].id,
                 spec->bulb[i], spec->phase_deg[i], survey_fx_lab_x_px(i, scale),
                 survey_fx_lab_y_px(i, scale), L[i].d, L[i].lm);
    }
    char text[4096];
    snprintf(text, sizeof text,
        "{\n"
        "  \"format\": \"gridsurvey-scene/1\",\n"
        "  \"name\": \"lab\",\n"
        "  \"seed\": %d,\n"
        "  \"grid\": {\"nominal_hz\": 50},\n"
        "  \"camera\": {\n"
        "    \"width_px\": %d, \"height_px\": %d,\n"
        "    \"intrinsics\": {\"focal_px\": %g},\n"
        "    \"optics\": {\"aperture_mm\": 1.0, \"transmission\": 3e-4},\n"
        "    \"sensor\": {\"bands\": 3, \"bit_depth\": 12, \"full_well_e\": 20000, \"read_noise_e\": 4,\n"
        "               \"qe\": 0.6, \"gain_e_per_dn\": 5, \"black_level_dn\": 64}\n"
        "  },\n"
        "  \"acam\": {\"K\": 26, \"cycles\": 128, \"locked\": true, \"masks\": 64,\n"
        "           \"hdr\": {\"enabled\": true, \"max_saturated_px\": 0}},\n"
        "  \"lights\": [\n%s\n  ],\n"
        "  \"effects\": {\"psf\": {\"sigma_px\": 1.5}, \"ambient\": {\"e_per_px_cycle\": 0.5},\n"
        "              \"shot_noise\": {}, \"saturation\": {}, \"read_noise\": {}, \"adc\": {}}\n"
        "}\n", spec->seed, (int)(640 * scale), (int)(480 * scale), 800 * scale, lights);
    fx_write_text(path, text);
}


/* A scene of geographic lights seen from a station (the scene of
 * pipeline_geographic_scene_locates_lights): a station 120 m above the ellipsoid looking north,
 * the first n_lights (1..6) of six lights 10 m up, 450-850 m away, on the three phases; a
 * 320 x 240 image and 800 px focal length times scale (the lights' angles are kept), K = 26,
 * C = cycles. */
void survey_fx_geo_scene(const char *path, double scale, int n_lights, int cycles)
{
    static const struct {
        double north_m, east_m;
        const char *bulb;
        int phase;
    } L[] = {
        {450, -40, "inc-a60-60w-230v", 0}, {500, 30, "cfl-20w", 120}, {600, -60, "led-a60-9w-cap", 240},
        {650, 50, "fl-t8-36w-tri", 0},    {750, 0, "hps-70w", 120},  {850, -80, "mh-70w", 240},
    };
    char lights[4096] = "";
    for (int i = 0; i < n_lights && i < 6; i++) {
        size_t used = strlen(lights);
        snprintf(lights + used, sizeof lights - used,
                 "%s{\"id\": \"g%d\", \"bulb\": \"%s\", \"phase_deg\": %d, \"lat_deg\": %.9f, "
                 "\"lon_deg\": %.9f, \"height_m\": 10, \"flux_e_per_cycle\": 40000}",
                 i ? ",\n" : "", i, L[i].bulb, L[i].phase, 32.8 + L[i].north_m / 110900.0,
                 35.0 + L[i].east_m / 93400.0);
    }
    char text[8192];
    snprintf(text, sizeof text,
             "{\"format\": \"gridsurvey-scene/1\", \"name\": \"geo\", \"seed\": 3,\n"
             " \"grid\": {\"nominal_hz\": 50},\n"
             " \"camera\": {\"width_px\": %d, \"height_px\": %d,\n"
             "   \"station\": {\"lat_deg\": 32.8, \"lon_deg\": 35.0, \"height_m\": 120},\n"
             "   \"pose\": {\"heading_deg\": 0, \"pitch_deg\": -9, \"roll_deg\": 0},\n"
             "   \"intrinsics\": {\"focal_px\": %g},\n"
             "   \"sensor\": {\"bands\": 3, \"bit_depth\": 12, \"full_well_e\": 60000, \"read_noise_e\": 4,\n"
             "              \"qe\": 0.6, \"gain_e_per_dn\": 15, \"black_level_dn\": 64}},\n"
             " \"acam\": {\"K\": 26, \"cycles\": %d, \"locked\": true, \"masks\": 64,\n"
             "          \"hdr\": {\"enabled\": true, \"max_saturated_px\": 0}},\n"
             " \"lights\": [%s],\n"
             " \"effects\": {\"psf\": {\"sigma_px\": 1.2}, \"shot_noise\": {}, \"saturation\": {},\n"
             "             \"read_noise\": {}, \"adc\": {}}}\n", (int)(320 * scale), (int)(240 * scale),
             800 * scale, cycles, lights);
    fx_write_text(path, text);
}

/* ------------------------------------------------------------------ the state of a database */

/* Every table's rows (all columns but the times of writing: the survey database's
 * applied_utc, added_utc, created_utc, ingested_utc, a GeoPackage's last_change and
 * update_time, and the value of a meta row with such a key), in a fixed order, after an
 * integrity check; "absent" if there is no such file, "unreadable: ..." if it cannot be read.
 * The caller frees. */
char *survey_fx_db_state(const char *path)
{
    static const char times[] = " applied_utc added_utc created_utc ingested_utc last_change update_time ";
    if (!fx_exists(path)) return strdup("absent");
    sqlite3 *h = NULL;
    char *buf = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&buf, &len);
    if (sqlite3_open_v2(path, &h, SQLITE_OPEN_READONLY, NULL) != SQLITE_OK) {
        fprintf(f, "unreadable: %s", sqlite3_errmsg(h));
        goto done;
    }
    sqlite3_stmt *t = NULL;
    /* (no survey_fx_query_*: a file that is not a database is a state, not a test failure) */
    static const char *const head[] = {"PRAGMA integrity_check", "PRAGMA user_version"};
    for (int i = 0; i < 2; i++) {
        if (sqlite3_prepare_v2(h, head[i], -1, &t, NULL) != SQLITE_OK || sqlite3_step(t) != SQLITE_ROW) {
            fprintf(f, "unreadable: %s", sqlite3_errmsg(h));
            sqlite3_finalize(t);
            goto done;
        }
        fprintf(f, "%s: %s\n", head[i], (const char *)sqlite3_column_text(t, 0));
        sqlite3_finalize(t);
    }
    if (sqlite3_prepare_v2(h, "SELECT name, sql FROM sqlite_master WHERE type = 'table' AND name NOT "
                              "LIKE 'sqlite_%' ORDER BY name", -1, &t, NULL) != SQLITE_OK) {
        fprintf(f, "unreadable: %s", sqlite3_errmsg(h));
        goto done;
    }
    while (sqlite3_step(t) == SQLITE_ROW) {
        const char *name = (const char *)sqlite3_column_text(t, 0);
        fprintf(f, "## %s\n%s\n", name, (const char *)sqlite3_column_text(t, 1));
        char cols[2048] = "", order[2048] = "", sql[4500];
        snprintf(sql, sizeof sql, "SELECT name FROM pragma_table_info('%s') ORDER BY cid", name);
        sqlite3_stmt *c = NULL;
        int n = 0;
        if (sqlite3_prepare_v2(h, sql, -1, &c, NULL) == SQLITE_OK) {
            while (sqlite3_step(c) == SQLITE_ROW) {
                const char *col = (const char *)sqlite3_column_text(c, 0);
                char spaced[300];
                snprintf(spaced, sizeof spaced, " %s ", col);
                if (strstr(times, spaced))
                    continue;
                size_t u = strlen(cols), v = strlen(order);
                snprintf(cols + u, sizeof cols - u, "%s\"%s\"", n ? ", " : "", col);
                snprintf(order + v, sizeof order - v, "%s%d", n ? ", " : "", n + 1);
                n++;
            }
        }
        sqlite3_finalize(c);
        if (!n) continue;
        snprintf(sql, sizeof sql, "SELECT %s FROM \"%s\" ORDER BY %s", cols, name, order);
        sqlite3_stmt *q = NULL;
        if (sqlite3_prepare_v2(h, sql, -1, &q, NULL) != SQLITE_OK) {
            fprintf(f, "unreadable: %s\n", sqlite3_errmsg(h));
            continue;
        }
        while (sqlite3_step(q) == SQLITE_ROW) {
            /* a key-value row (the meta table) whose key is such a time: its value is masked */
            char key[300];
            const unsigned char *k0 = sqlite3_column_text(q, 0);
            snprintf(key, sizeof key, " %s ", k0 ? (const char *)k0 : "");
            int mask = strstr(times, key) != NULL;
            for (int i = 0; i < sqlite3_column_count(q); i++) {
                const unsigned char *v = sqlite3_column_text(q, i);
                fprintf(f, "%s%s", i ? "|" : "", mask && i ? "*" : v ? (const char *)v : "NULL");
            }
            fputc('\n', f);
        }
        sqlite3_finalize(q);
    }
    sqlite3_finalize(t);
done:
    sqlite3_close(h);
    fclose(f);
    return buf;
}
