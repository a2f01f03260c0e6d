/* survey_fixture.h - survey databases for the tests of survey/ (tests/survey_fixture.c),
 * prefix survey_fx_: plain SQL queries on a raw connection, the synthetic survey written to a
 * file, and light and capture rows built by hand. Failures are test failures (CHECKs). */
#ifndef GRIDSURVEY_TESTS_SURVEY_FIXTURE_H
#define GRIDSURVEY_TESTS_SURVEY_FIXTURE_H

#include "survey/survey.h"

#include <sqlite3.h>

/* The first column of sql's first row as an integer; -1 and a test failure when there is none.
 * The text variant's result is in a static buffer (the next call overwrites it), "" if none. */
long survey_fx_query_long(sqlite3 *h, const char *sql);
const char *survey_fx_query_text(sqlite3 *h, const char *sql);
/* 1 if the schema has an object of that name (0 also when it cannot be read: no failure). */
int survey_fx_has(sqlite3 *h, const char *name);

/* srv_synth_opts_default with these set and half_width_m = 0 (every capture sees the whole
 * square); the caller may change more before survey_fx_synth. */
srv_synth_opts survey_fx_synth_opts(const char *survey, size_t captures, size_t lights,
                                    unsigned long long seed);
/* Opens (creating) the database at path, ingests the synthetic survey o, closes it. */
void survey_fx_synth(const char *path, const srv_synth_opts *o);
/* survey_fx_synth of a small survey whose every capture sees the whole 4 km square
 * (view_half_width_m = 2000). */
void survey_fx_synth_square(const char *path, const char *survey, size_t captures, size_t lights,
                            unsigned long long seed);

/* Opens (creating) the database at path and adds a survey of that name (50 Hz, nothing else
 * set): its id in *survey_id. NULL (a test failure) when it cannot be opened; close it. */
srv_db *survey_fx_create(const char *path, const char *survey, int64_t *survey_id);

/* srv_light_row_init, then index, position (px), phase (deg; NaN: unknown) and confidence for
 * all three confidences (overall, bulb, phase). Borrowed strings stay NULL. */
srv_light_row survey_fx_light(int index, double x_px, double y_px, double phase_deg,
                              double confidence);
/* A valid light: index i at (10 + i, 20) px, bulb sodium_hp_150w, confidence 0.95. */
srv_light_row survey_fx_sodium_light(int i, double phase_deg);
/* A capture row of survey_id named key with n lights and their locations (NULL: none); the
 * pointers are borrowed; add it with srv_db_add_capture. */
srv_capture_data survey_fx_capture(int64_t survey_id, const char *key, srv_light_row *lights,
                                   srv_location_row *locations, size_t n);
/* The whole database's phase statistics, one group (srv_stats_compute with the default options:
 * light sites; detections 1: every detection); zeros if not one group. */
srv_phase_stats survey_fx_stats_all(srv_db *db, int detections);

/* The lab scene's eight lights (capture/scenes/lab.json): bulbs, phases and the noise seed,
 * which a test may change (another night: another seed; a rephased or replaced light). */
typedef struct {
    const char *bulb[8];
    int phase_deg[8];
    int seed;
} survey_lab_spec;
survey_lab_spec survey_fx_lab_spec(void);   /* the lab's, seed 4 */
/* Light i's pixel in the small lab scene at that scale. */
double survey_fx_lab_x_px(int i, double scale);
double survey_fx_lab_y_px(int i, double scale);
/* The lab scene (capture/scenes/lab.json) made small, written to path as a scene file (see
 * survey_fixture.c). */
void survey_fx_small_lab(const char *path, double scale, const survey_lab_spec *spec);
/* A scene of geographic lights seen from a station, located by `run` (see survey_fixture.c). */
void survey_fx_geo_scene(const char *path, double scale, int n_lights, int cycles);

/* Every table's rows of the database at path (all columns but the times of writing), in a fixed
 * order, after an integrity check; "absent" or "unreadable: ..." if so. The caller frees. */
char *survey_fx_db_state(const char *path);

#endif
