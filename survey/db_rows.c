/* db_rows.c - rows of the survey database: initialisers, the mapping from recognition and
 * location results, and the inserts, one capture at a time in one transaction (srv_db_add_capture:
 * complete or absent, never partial). */
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


/* ------------------------------------------------------------------ row helpers */

void srv_station_row_init(srv_station_row *r)
{
    memset(r, 0, sizeof *r);
    gis_camera *c = &r->cam;
    c->lat_deg = c->lon_deg = c->height_m = NAN;
    c->heading_deg = c->pitch_deg = c->roll_deg = NAN;
    c->sigma_heading_deg = c->sigma_pitch_deg = c->sigma_roll_deg = NAN;
    c->focal_px = c->cx_px = c->cy_px = c->k1 = c->k2 = c->refraction_k = NAN;
    r->sigma_px = NAN;
}

void srv_capture_row_init(srv_capture_row *r)
{
    memset(r, 0, sizeof *r);
    r->locked = -1;
    r->mean_frequency_hz = r->sigma_frequency_hz = NAN;
}

void srv_light_row_init(srv_light_row *r)
{
    memset(r, 0, sizeof *r);
    r->x_px = r->y_px = r->peak_dn = r->brightness = r->snr = r->chi2 = r->p_value = NAN;
    r->area_px = r->saturated_px = r->dof = -1;
    r->phase_deg = r->phase_fit_deg = r->phase_sigma_deg = NAN;
    r->confidence = r->bulb_confidence = r->phase_confidence = NAN;
    r->runner_phase_deg = r->runner_confidence = NAN;
    r->pos_cov_px2[0] = r->pos_cov_px2[1] = r->pos_cov_px2[2] = NAN;
}

void srv_location_row_init(srv_location_row *r)
{
    memset(r, 0, sizeof *r);
    r->method = SRV_LOC_NONE;
    r->lat_deg = r->lon_deg = r->height_m = r->range_m = NAN;
    r->ellipse.semi_major_m = r->ellipse.semi_minor_m = r->ellipse.azimuth_deg = NAN;
}

void srv_light_from_catalog(srv_light_row *r, const rec_catalog *cat, size_t i)
{
    if (!r || !cat || i >= cat->count) return;
    r->index = (int)i;
    r->x_px = cat->x_px[i];
    r->y_px = cat->y_px[i];
    r->area_px = cat->area_px ? cat->area_px[i] : -1;
    r->peak_dn = cat->peak_dn ? cat->peak_dn[i] : NAN;
    r->saturated_px = cat->saturated_px ? cat->saturated_px[i] : -1;
    r->blob_flags = cat->flags ? cat->flags[i] : 0;
    for (int c = 0; c < 3; c++) r->pos_cov_px2[c] = cat->pos_cov_px2 ? cat->pos_cov_px2[3 * i + c] : NAN;
    double sum = 0.0, var = 0.0;
    size_t m = (size_t)cat->bands * (size_t)cat->K;
    for (size_t j = 0; cat->signal && cat->sigma && j < m; j++) {
        double x = cat->signal[i * m + j], sg = cat->sigma[i * m + j];
        if (!isfinite(x) || !isfinite(sg) || !(sg > 0.0)) continue;
        sum += x;
        var += sg * sg;
    }
    r->snr = var > 0.0 ? sum / sqrt(var) : NAN;
}

void srv_light_from_match(srv_light_row *r, const rec_match *m, const rec_matcher *mt)
{
    if (!r || !m) return;
    const gs_bulb *b = m->bulb >= 0 && mt ? rec_matcher_bulb(mt, (size_t)m->bulb) : NULL;
    const gs_bulb *rb = m->runner_bulb >= 0 && mt ? rec_matcher_bulb(mt, (size_t)m->runner_bulb) : NULL;
    r->brightness = m->brightness;
    r->chi2 = m->chi2;
    r->dof = m->dof;
    r->p_value = m->p_value;
    r->bulb_id = b ? b->id : NULL;
    r->technology = b ? gs_tech_name(b->type) : NULL;
    r->phase_fit_deg = b ? m->phase_deg : NAN;
    r->phase_deg = b && !(m->flags & REC_MATCH_PHASE_AMBIGUOUS) ? m->phase_deg : NAN;
    r->phase_sigma_deg = b ? m->phase_sigma_deg : NAN;
    r->confidence = m->confidence;
    r->bulb_confidence = m->bulb_confidence;
    r->phase_confidence = m->phase_confidence;
    r->runner_bulb_id = rb ? rb->id : NULL;
    r->runner_phase_deg = rb ? m->runner_phase_deg : NAN;
    r->runner_confidence = rb ? m->runner_confidence : NAN;
    r->match_flags = m->flags;
}

void srv_location_from_fix(srv_location_row *r, const gis_fix *f)
{
    if (!r || !f) return;
    r->method = SRV_LOC_ONE_STATION;
    r->lat_deg = f->lat_deg;
    r->lon_deg = f->lon_deg;
    r->height_m = f->height_m;
    r->ellipse = f->ellipse;
    r->range_m = f->range_m;
    r->flags = f->flags;
}

/* ------------------------------------------------------------------ inserts */

gs_status srv_db_add_delight(srv_db *db, const srv_delight_row *r, int64_t *id)
{
    if (!db || !r) return gs_fail(GS_EINVAL, "srv_db_add_delight: NULL argument");
    if (strlen(r->sha256) != 64 || strspn(r->sha256, "0123456789abcdef") != 64)
        return gs_fail(GS_EINVAL, "%s: delight sha256 '%.64s': expected 64 lower-case hex digits",
                       db->path, r->sha256);
    if (r->bulbs < 0) return gs_fail(GS_EINVAL, "%s: delight bulbs %ld: expected >= 0", db->path, r->bulbs);
    int began;
    gs_status s = srv_dbi_auto_begin(db, &began);
    if (s != GS_OK) return s;
    const char *gen = r->generator && *r->generator ? r->generator : SRV_GENERATOR;
    sqlite3_stmt *q;
    char now[32];
    srv_dbi_utc_now(now);
    int inserted = 0;
    if ((s = srv_dbi_stmt(db, ST_ADD_DELIGHT, &q)) == GS_OK) {
        sqlite3_bind_text(q, 1, r->sha256, -1, SQLITE_STATIC);
        sqlite3_bind_text(q, 2, gen, -1, SQLITE_STATIC);
        sqlite3_bind_text(q, 3, r->source && *r->source ? r->source : "built-in", -1, SQLITE_STATIC);
        sqlite3_bind_int64(q, 4, r->bulbs);
        sqlite3_bind_text(q, 5, now, -1, SQLITE_TRANSIENT);
        s = srv_dbi_step_returning(db, q, id, &inserted, "adding a DELIGHT version");
    }
    if (s == GS_OK && !inserted && (s = srv_dbi_stmt(db, ST_GET_DELIGHT, &q)) == GS_OK) {
        sqlite3_bind_text(q, 1, r->sha256, -1, SQLITE_STATIC);
        sqlite3_bind_text(q, 2, gen, -1, SQLITE_STATIC);
        s = srv_dbi_step_id(db, q, id, "looking up a DELIGHT version");
    }
    return srv_dbi_auto_end(db, began, s);
}

gs_status srv_db_add_survey(srv_db *db, const srv_survey_row *r, int64_t *id)
{
    if (!db || !r) return gs_fail(GS_EINVAL, "srv_db_add_survey: NULL argument");
    if (!r->name || !*r->name || strlen(r->name) >= GIS_TEXT_MAX)
        return gs_fail(GS_EINVAL, "%s: survey name '%s': expected 1 to %d bytes", db->path,
                       r->name ? r->name : "", GIS_TEXT_MAX - 1);
    if (r->grid_hz != 0 && r->grid_hz != 50 && r->grid_hz != 60)
        return gs_fail(GS_EINVAL, "%s: survey %s: grid_hz %d: expected 50, 60 or 0 (unknown)",
                       db->path, r->name, r->grid_hz);
    int began;
    gs_status s = srv_dbi_auto_begin(db, &began);
    if (s != GS_OK) return s;
    sqlite3_stmt *q;
    char now[32];
    srv_dbi_utc_now(now);
    int inserted = 0;
    if ((s = srv_dbi_stmt(db, ST_ADD_SURVEY, &q)) == GS_OK) {
        sqlite3_bind_text(q, 1, r->name, -1, SQLITE_STATIC);
        srv_dbi_bind_text(q, 2, r->city);
        srv_dbi_bind_int_or_null(q, 3, r->grid_hz, 0);
        srv_dbi_bind_text(q, 4, r->started_utc);
        srv_dbi_bind_text(q, 5, r->notes);
        sqlite3_bind_text(q, 6, now, -1, SQLITE_TRANSIENT);
        s = srv_dbi_step_returning(db, q, id, &inserted, "adding a survey");
    }
    if (s == GS_OK && !inserted) s = srv_db_find_survey(db, r->name, id);
    return srv_dbi_auto_end(db, began, s);
}

gs_status srv_db_find_survey(srv_db *db, const char *name, int64_t *id)
{
    if (!db || !name) return gs_fail(GS_EINVAL, "srv_db_find_survey: NULL argument");
    sqlite3_stmt *q;
    gs_status s = srv_dbi_stmt(db, ST_GET_SURVEY, &q);
    if (s != GS_OK) return s;
    sqlite3_bind_text(q, 1, name, -1, SQLITE_STATIC);
    s = srv_dbi_step_id(db, q, id, "looking up a survey");
    if (s == GS_ENOTFOUND) return gs_fail(s, "%s: no survey named '%s'", db->path, name);
    return s;
}

gs_status srv_db_add_station(srv_db *db, const srv_station_row *r, int64_t *id)
{
    if (!db || !r) return gs_fail(GS_EINVAL, "srv_db_add_station: NULL argument");
    if (!r->name || !*r->name)
        return gs_fail(GS_EINVAL, "%s: station: expected a name", db->path);
    const gis_camera *c = &r->cam;
    if (isfinite(c->lat_deg) && fabs(c->lat_deg) > 90.0)
        return gs_fail(GS_EINVAL, "%s: station %s: lat_deg %g: expected [-90, 90]", db->path, r->name,
                       c->lat_deg);
    int began;
    gs_status s = srv_dbi_auto_begin(db, &began);
    if (s != GS_OK) return s;
    sqlite3_stmt *q;
    int inserted = 0;
    if ((s = srv_dbi_stmt(db, ST_ADD_STATION, &q)) == GS_OK) {
        sqlite3_bind_int64(q, 1, r->survey_id);
        sqlite3_bind_text(q, 2, r->name, -1, SQLITE_STATIC);
        const double v[] = {c->lat_deg, isfinite(c->lon_deg) ? gs_wrap180(c->lon_deg) : NAN,
                            c->height_m, c->heading_deg, c->pitch_deg, c->roll_deg,
                            c->sigma_heading_deg, c->sigma_pitch_deg, c->sigma_roll_deg,
                            c->focal_px, c->cx_px, c->cy_px, c->k1, c->k2};
        for (int i = 0; i < 14; i++) srv_dbi_bind_real(q, 3 + i, v[i]);
        srv_dbi_bind_int_or_null(q, 17, c->width_px, 0);
        srv_dbi_bind_int_or_null(q, 18, c->height_px, 0);
        srv_dbi_bind_real(q, 19, c->refraction_k);
        srv_dbi_bind_real(q, 20, r->sigma_px);
        srv_dbi_bind_text(q, 21, r->time_utc);
        s = srv_dbi_step_returning(db, q, id, &inserted, "adding a station");
    }
    if (s == GS_OK && !inserted && (s = srv_dbi_stmt(db, ST_GET_STATION, &q)) == GS_OK) {
        sqlite3_bind_int64(q, 1, r->survey_id);
        sqlite3_bind_text(q, 2, r->name, -1, SQLITE_STATIC);
        s = srv_dbi_step_id(db, q, id, "looking up a station");
    }
    return srv_dbi_auto_end(db, began, s);
}

gs_status srv_db_capture_done(srv_db *db, int64_t survey_id, const char *key, int *done)
{
    if (!db || !key || !done) return gs_fail(GS_EINVAL, "srv_db_capture_done: NULL argument");
    sqlite3_stmt *q;
    gs_status s = srv_dbi_stmt(db, ST_GET_CAPTURE, &q);
    if (s != GS_OK) return s;
    sqlite3_bind_int64(q, 1, survey_id);
    sqlite3_bind_text(q, 2, key, -1, SQLITE_STATIC);
    s = srv_dbi_step_id(db, q, NULL, "looking up a capture");
    *done = s == GS_OK;
    return s == GS_ENOTFOUND ? GS_OK : s;
}

gs_status srv_db_capture_survey(srv_db *db, const char *key, int64_t *survey_id, char name[64])
{
    if (!db || !key || !survey_id || !name) return gs_fail(GS_EINVAL, "srv_db_capture_survey: NULL argument");
    sqlite3_stmt *q;
    gs_status s = srv_dbi_stmt(db, ST_FIND_CAPTURE, &q);
    if (s != GS_OK) return s;
    sqlite3_bind_text(q, 1, key, -1, SQLITE_STATIC);
    sqlite3_bind_text(q, 2, name, -1, SQLITE_TRANSIENT);   /* (name is overwritten below) */
    int rc = sqlite3_step(q);
    if (rc == SQLITE_ROW) {
        *survey_id = sqlite3_column_int64(q, 0);
        const unsigned char *t = sqlite3_column_text(q, 1);
        snprintf(name, 64, "%s", t ? (const char *)t : "");
    }
    sqlite3_reset(q);
    if (rc == SQLITE_DONE) return gs_fail(GS_ENOTFOUND, "%s: no capture %s", db->path, key);
    return rc == SQLITE_ROW ? GS_OK : srv_dbi_fail(db, "looking up a capture's survey");
}

gs_status srv_db_insert_capture(srv_db *db, const srv_capture_row *r, size_t n_lights,
                                size_t n_frames, size_t n_frequency, int64_t *id)
{
    if (!db || !r) return gs_fail(GS_EINVAL, "srv_db_insert_capture: NULL argument");
    gs_status s = srv_dbi_need_txn(db, "inserting a capture");
    if (s != GS_OK) return s;
    if (!r->key || !*r->key) return gs_fail(GS_EINVAL, "%s: capture: expected a key", db->path);
    if (r->survey_id <= 0)
        return gs_fail(GS_EINVAL, "%s: capture %s: survey_id %lld: expected a survey's id", db->path,
                       r->key, (long long)r->survey_id);
    if ((r->grid_hz && r->grid_hz != 50 && r->grid_hz != 60) || (r->K && r->K < 2) ||
        (r->bands && r->bands != 1 && r->bands != 3) || r->locked < -1 || r->locked > 1)
        return gs_fail(GS_EINVAL, "%s: capture %s: grid_hz %d, K %d, bands %d, locked %d: expected "
                       "50/60, >= 2, 1/3 and 0/1 (0 or -1 for unknown)", db->path, r->key,
                       r->grid_hz, r->K, r->bands, r->locked);
    if (r->candidate_bulbs < 0)
        return gs_fail(GS_EINVAL, "%s: capture %s: candidate_bulbs %ld: expected >= 1 (0 for unknown)",
                       db->path, r->key, r->candidate_bulbs);
    sqlite3_stmt *q;
    char now[32];
    srv_dbi_utc_now(now);
    int inserted = 0;
    if ((s = srv_dbi_stmt(db, ST_ADD_CAPTURE, &q)) != GS_OK) return s;
    sqlite3_bind_int64(q, 1, r->survey_id);
    srv_dbi_bind_int_or_null(q, 2, r->station_id, 0);
    srv_dbi_bind_int_or_null(q, 3, r->delight_id, 0);
    sqlite3_bind_text(q, 4, r->key, -1, SQLITE_STATIC);
    srv_dbi_bind_text(q, 5, r->path);
    srv_dbi_bind_text(q, 6, r->utc);
    srv_dbi_bind_int_or_null(q, 7, r->grid_hz, 0);
    srv_dbi_bind_int_or_null(q, 8, r->K, 0);
    srv_dbi_bind_int_or_null(q, 9, r->bands, 0);
    srv_dbi_bind_int_or_null(q, 10, r->width_px, 0);
    srv_dbi_bind_int_or_null(q, 11, r->height_px, 0);
    srv_dbi_bind_int_or_null(q, 12, r->locked, -1);
    srv_dbi_bind_real(q, 13, r->mean_frequency_hz);
    srv_dbi_bind_real(q, 14, r->sigma_frequency_hz);
    sqlite3_bind_int64(q, 15, (sqlite3_int64)n_lights);
    sqlite3_bind_int64(q, 16, (sqlite3_int64)n_frames);
    sqlite3_bind_int64(q, 17, (sqlite3_int64)n_frequency);
    sqlite3_bind_text(q, 18, now, -1, SQLITE_TRANSIENT);
    srv_dbi_bind_int_or_null(q, 19, r->candidate_bulbs, 0);
    if ((s = srv_dbi_step_returning(db, q, id, &inserted, "inserting a capture")) != GS_OK || inserted) return s;
    if ((s = srv_dbi_stmt(db, ST_GET_CAPTURE, &q)) != GS_OK) return s;
    sqlite3_bind_int64(q, 1, r->survey_id);
    sqlite3_bind_text(q, 2, r->key, -1, SQLITE_STATIC);
    return srv_dbi_step_id(db, q, id, "looking up a capture");
}

gs_status srv_db_insert_frame(srv_db *db, int64_t capture_id, const srv_frame_row *r)
{
    if (!db || !r) return gs_fail(GS_EINVAL, "srv_db_insert_frame: NULL argument");
    gs_status s = srv_dbi_need_txn(db, "inserting a frame");
    if (s != GS_OK) return s;
    if (r->k < 0) return gs_fail(GS_EINVAL, "%s: frame k %d: expected >= 0", db->path, r->k);
    sqlite3_stmt *q;
    if ((s = srv_dbi_stmt(db, ST_ADD_FRAME, &q)) != GS_OK) return s;
    sqlite3_bind_int64(q, 1, capture_id);
    sqlite3_bind_int(q, 2, r->k);
    srv_dbi_bind_text(q, 3, r->file);
    srv_dbi_bind_real(q, 4, r->cycles);
    srv_dbi_bind_text(q, 5, r->hdr_map);
    return srv_dbi_step_done(db, q, "inserting a frame");
}

/* A probability for storage: NaN -> 0; outside [0, 1] -> -1 (invalid). */
static double prob(double p)
{
    if (isnan(p)) return 0.0;
    return p >= 0.0 && p <= 1.0 ? p : -1.0;
}

gs_status srv_db_insert_light(srv_db *db, int64_t capture_id, const srv_light_row *r,
                              int64_t *light_id)
{
    if (!db || !r) return gs_fail(GS_EINVAL, "srv_db_insert_light: NULL argument");
    gs_status s = srv_dbi_need_txn(db, "inserting a light");
    if (s != GS_OK) return s;
    if (r->index < 0) return gs_fail(GS_EINVAL, "%s: light index %d: expected >= 0", db->path, r->index);
    if (!isfinite(r->x_px) || !isfinite(r->y_px))
        return gs_fail(GS_EINVAL, "%s: light %d: x_px, y_px (%g, %g): expected finite pixels",
                       db->path, r->index, r->x_px, r->y_px);
    double conf = prob(r->confidence), bconf = prob(r->bulb_confidence),
           pconf = prob(r->phase_confidence);
    double rconf = isnan(r->runner_confidence) ? NAN : prob(r->runner_confidence);
    if (conf < 0 || bconf < 0 || pconf < 0 || rconf < 0 ||
        (isfinite(r->p_value) && (r->p_value < 0.0 || r->p_value > 1.0)))
        return gs_fail(GS_EINVAL, "%s: light %d: confidence %g, bulb %g, phase %g, runner %g, "
                       "p_value %g: expected probabilities in [0, 1]", db->path, r->index,
                       r->confidence, r->bulb_confidence, r->phase_confidence, r->runner_confidence,
                       r->p_value);
    gs_tech t;
    if (r->technology && *r->technology && gs_tech_parse(r->technology, &t) != GS_OK)
        return gs_fail(GS_EINVAL, "%s: light %d: technology '%s': expected a gs_tech_name() such "
                       "as 'sodium_hp' or 'led_linear'", db->path, r->index, r->technology);
    if ((r->bulb_id && strlen(r->bulb_id) >= GS_ID_MAX) ||
        (r->runner_bulb_id && strlen(r->runner_bulb_id) >= GS_ID_MAX))
        return gs_fail(GS_EINVAL, "%s: light %d: bulb id longer than %d bytes", db->path, r->index,
                       GS_ID_MAX - 1);
    sqlite3_stmt *q;
    if ((s = srv_dbi_stmt(db, ST_ADD_LIGHT, &q)) != GS_OK) return s;
    sqlite3_bind_int64(q, 1, capture_id);
    sqlite3_bind_int(q, 2, r->index);
    sqlite3_bind_double(q, 3, r->x_px);
    sqlite3_bind_double(q, 4, r->y_px);
    srv_dbi_bind_int_or_null(q, 5, r->area_px, -1);
    srv_dbi_bind_real(q, 6, r->peak_dn);
    srv_dbi_bind_int_or_null(q, 7, r->saturated_px, -1);
    sqlite3_bind_int64(q, 8, r->blob_flags);
    srv_dbi_bind_real(q, 9, r->brightness);
    srv_dbi_bind_real(q, 10, r->snr);
    srv_dbi_bind_real(q, 11, r->chi2);
    srv_dbi_bind_int_or_null(q, 12, r->dof, -1);
    srv_dbi_bind_real(q, 13, r->p_value);
    srv_dbi_bind_text(q, 14, r->bulb_id);
    srv_dbi_bind_text(q, 15, r->technology);
    srv_dbi_bind_real(q, 16, isfinite(r->phase_deg) ? gs_wrap360(r->phase_deg) : NAN);
    srv_dbi_bind_real(q, 17, isfinite(r->phase_fit_deg) ? gs_wrap360(r->phase_fit_deg) : NAN);
    srv_dbi_bind_real(q, 18, r->phase_sigma_deg);
    sqlite3_bind_double(q, 19, conf);
    sqlite3_bind_double(q, 20, bconf);
    sqlite3_bind_double(q, 21, pconf);
    srv_dbi_bind_text(q, 22, r->runner_bulb_id);
    srv_dbi_bind_real(q, 23, isfinite(r->runner_phase_deg) ? gs_wrap360(r->runner_phase_deg) : NAN);
    srv_dbi_bind_real(q, 24, rconf);
    sqlite3_bind_int64(q, 25, r->match_flags);
    int inserted = 0;
    if ((s = srv_dbi_step_returning(db, q, light_id, &inserted, "inserting a light")) != GS_OK || inserted)
        return s;
    if ((s = srv_dbi_stmt(db, ST_GET_LIGHT, &q)) != GS_OK) return s;
    sqlite3_bind_int64(q, 1, capture_id);
    sqlite3_bind_int(q, 2, r->index);
    return srv_dbi_step_id(db, q, light_id, "looking up a light");
}

gs_status srv_db_insert_location(srv_db *db, int64_t light_id, const srv_location_row *r)
{
    static const char *const method[] = {"", "one_station", "triangulated", "truth"};
    if (!db || !r) return gs_fail(GS_EINVAL, "srv_db_insert_location: NULL argument");
    gs_status s = srv_dbi_need_txn(db, "inserting a location");
    if (s != GS_OK) return s;
    if (r->method < SRV_LOC_ONE_STATION || r->method > SRV_LOC_TRUTH)
        return gs_fail(GS_EINVAL, "%s: location of light %lld: method %d: expected one_station, "
                       "triangulated or truth", db->path, (long long)light_id, (int)r->method);
    int has_lat = isfinite(r->lat_deg), has_lon = isfinite(r->lon_deg);
    if (has_lat != has_lon || (has_lat && fabs(r->lat_deg) > 90.0))
        return gs_fail(GS_EINVAL, "%s: location of light %lld: (%g, %g): expected a latitude in "
                       "[-90, 90] and a finite longitude, or both NaN (not located)", db->path,
                       (long long)light_id, r->lat_deg, r->lon_deg);
    sqlite3_stmt *q;
    if ((s = srv_dbi_stmt(db, ST_ADD_LOCATION, &q)) != GS_OK) return s;
    sqlite3_bind_int64(q, 1, light_id);
    sqlite3_bind_text(q, 2, method[r->method], -1, SQLITE_STATIC);
    srv_dbi_bind_real(q, 3, r->lat_deg);
    srv_dbi_bind_real(q, 4, has_lon ? gs_wrap180(r->lon_deg) : NAN);
    srv_dbi_bind_real(q, 5, r->height_m);
    srv_dbi_bind_real(q, 6, r->ellipse.semi_major_m);
    srv_dbi_bind_real(q, 7, r->ellipse.semi_minor_m);
    srv_dbi_bind_real(q, 8, r->ellipse.azimuth_deg);
    srv_dbi_bind_real(q, 9, r->range_m);
    sqlite3_bind_int64(q, 10, r->flags);
    return srv_dbi_step_done(db, q, "inserting a location");
}

gs_status srv_db_insert_frequency(srv_db *db, int64_t capture_id, int seq, const srv_freq_row *r)
{
    if (!db || !r) return gs_fail(GS_EINVAL, "srv_db_insert_frequency: NULL argument");
    gs_status s = srv_dbi_need_txn(db, "inserting a frequency row");
    if (s != GS_OK) return s;
    if (seq < 0 || !isfinite(r->t_s) || !(r->window_s > 0.0) || !isfinite(r->window_s) ||
        !(r->frequency_hz > 0.0) || !isfinite(r->frequency_hz))
        return gs_fail(GS_EINVAL, "%s: frequency row %d: t_s %g, window_s %g, frequency_hz %g: "
                       "expected finite t, window > 0, frequency > 0", db->path, seq, r->t_s,
                       r->window_s, r->frequency_hz);
    sqlite3_stmt *q;
    if ((s = srv_dbi_stmt(db, ST_ADD_FREQ, &q)) != GS_OK) return s;
    sqlite3_bind_int64(q, 1, capture_id);
    sqlite3_bind_int(q, 2, seq);
    sqlite3_bind_double(q, 3, r->t_s);
    sqlite3_bind_double(q, 4, r->window_s);
    sqlite3_bind_double(q, 5, r->frequency_hz);
    srv_dbi_bind_real(q, 6, r->sigma_hz);
    return srv_dbi_step_done(db, q, "inserting a frequency row");
}

/* ------------------------------------------------------------------ one capture, atomically */

static gs_status capture_rows(srv_db *db, const srv_capture_data *c, int64_t cid)
{
    gs_status s = GS_OK;
    for (size_t i = 0; i < c->n_frames && s == GS_OK; i++) s = srv_db_insert_frame(db, cid, &c->frames[i]);
    for (size_t i = 0; i < c->n_lights && s == GS_OK; i++) {
        int64_t lid = 0;
        s = srv_db_insert_light(db, cid, &c->lights[i], &lid);
        if (s == GS_OK && c->locations && c->locations[i].method != SRV_LOC_NONE)
            s = srv_db_insert_location(db, lid, &c->locations[i]);
    }
    for (size_t i = 0; i < c->n_frequency && s == GS_OK; i++) {
        if (i > (size_t)INT32_MAX) return gs_fail(GS_ELIMIT, "%s: too many frequency rows", db->path);
        s = srv_db_insert_frequency(db, cid, (int)i, &c->frequency[i]);
    }
    return s;
}

gs_status srv_db_add_capture(srv_db *db, const srv_capture_data *c, int64_t *capture_id,
                             int *skipped)
{
    if (!db || !c) return gs_fail(GS_EINVAL, "srv_db_add_capture: NULL argument");
    if ((c->n_frames && !c->frames) || (c->n_lights && !c->lights) ||
        (c->n_frequency && !c->frequency))
        return gs_fail(GS_EINVAL, "%s: capture %s: NULL array with a non-zero count", db->path,
                       c->capture.key ? c->capture.key : "");
    if (skipped) *skipped = 0;
    gs_status s = srv_dbi_writable(db);
    if (s != GS_OK) return s;
    int own = !db->in_txn;
    if (own) s = srv_db_begin(db);
    else if ((s = srv_dbi_lost(db, "storing a capture")) == GS_OK)   /* (a savepoint would begin anew) */
        s = srv_dbi_exec(db, "SAVEPOINT srv_capture", "savepoint");
    if (s != GS_OK) return s;
    db->in_txn = 1;
    int done = 0;
    int64_t cid = 0;
    s = srv_db_capture_done(db, c->capture.survey_id, c->capture.key ? c->capture.key : "", &done);
    if (s == GS_OK && done) {
        if (skipped) *skipped = 1;
        sqlite3_stmt *q;
        if ((s = srv_dbi_stmt(db, ST_GET_CAPTURE, &q)) == GS_OK) {
            sqlite3_bind_int64(q, 1, c->capture.survey_id);
            sqlite3_bind_text(q, 2, c->capture.key, -1, SQLITE_STATIC);
            s = srv_dbi_step_id(db, q, &cid, "looking up a capture");
        }
    } else if (s == GS_OK) {
        s = srv_db_insert_capture(db, &c->capture, c->n_lights, c->n_frames, c->n_frequency, &cid);
        if (s == GS_OK) s = capture_rows(db, c, cid);
        long created = 0, joined = 0, merged = 0;
        if (s == GS_OK) s = srv_dbi_associate_capture(db, cid, &created, &joined, &merged);
    }
    if (s == GS_OK) {
        s = own ? srv_db_commit(db) : srv_dbi_exec(db, "RELEASE srv_capture", "release");
        if (s == GS_OK && capture_id) *capture_id = cid;
        return s;
    }
    char msg[512];
    snprintf(msg, sizeof msg, "%s", gs_detail());
    if (own) {
        srv_db_rollback(db);
    } else if (!sqlite3_get_autocommit(db->db)) {
        sqlite3_exec(db->db, "ROLLBACK TO srv_capture; RELEASE srv_capture", NULL, NULL, NULL);
    } else {
        db->in_txn = 0;   /* SQLite rolled the whole transaction back (e.g. disk full) */
    }
    return gs_fail(s, "%s", msg);
}

gs_status srv_db_delete_capture(srv_db *db, int64_t survey_id, const char *key, int *deleted)
{
    if (!db || !key) return gs_fail(GS_EINVAL, "srv_db_delete_capture: NULL argument");
    int began;
    gs_status s = srv_dbi_auto_begin(db, &began);
    if (s != GS_OK) return s;
    sqlite3_stmt *q;
    if ((s = srv_dbi_stmt(db, ST_DEL_CAPTURE, &q)) == GS_OK) {
        sqlite3_bind_int64(q, 1, survey_id);
        sqlite3_bind_text(q, 2, key, -1, SQLITE_STATIC);
        s = srv_dbi_step_done(db, q, "deleting a capture");
        if (s == GS_OK && deleted) *deleted = sqlite3_changes(db->db) > 0;
    }
    return srv_dbi_auto_end(db, began, s);
}

