/* pg_stats.c - `gridsurvey stats --pg`: the statistics of stats.c over the shared PostGIS
 * database. The query is stats.c's scan over the PostgreSQL tables (one row per detection, a
 * site's rows consecutive, detections in push order, which is the file's order), read through a
 * cursor in one REPEATABLE READ transaction (a consistent snapshot while stations push); the
 * numbers are computed by srv_stats_run, so they equal `stats --db` on the same data. Names
 * sort bytewise (COLLATE "C"), as in SQLite. */
#include "survey/internal.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char pg_scan_sql[] =
    "DECLARE scan NO SCROLL CURSOR FOR "
    "SELECT CASE WHEN $2::boolean THEN -l.id ELSE coalesce(sd.site_id, -l.id) END, s.name, "
    "l.bulb_id, l.technology, l.phase_deg, l.phase_sigma_deg, l.confidence, l.bulb_confidence, "
    "l.phase_confidence, " SRV_SQL_BULB_LABELS ", "
    "CASE WHEN $2::boolean THEN loc.lat_deg ELSE coalesce(ls.lat_deg, loc.lat_deg) END, "
    "CASE WHEN $2::boolean THEN loc.lon_deg ELSE coalesce(ls.lon_deg, loc.lon_deg) END "
    "FROM lights l JOIN captures c ON c.id = l.capture_id JOIN surveys s ON s.id = c.survey_id "
    "LEFT JOIN delight_versions dv ON dv.id = c.delight_id "
    "LEFT JOIN site_detections sd ON sd.capture_id = l.capture_id AND sd.light_index = l.light_index "
    "LEFT JOIN light_sites ls ON ls.id = sd.site_id "
    "LEFT JOIN locations loc ON loc.capture_id = l.capture_id AND loc.light_index = l.light_index "
    "WHERE ($1::text IS NULL OR s.name = $1::text) ";

typedef struct {
    PGconn *c;
    PGresult *r;                /* the current FETCH */
    int i, n;                   /* its next row, its rows */
    char survey[64];
} pg_rows;

static double real_at(const PGresult *r, int i, int j)
{
    return PQgetisnull(r, i, j) ? NAN : strtod(PQgetvalue(r, i, j), NULL);
}

static gs_status pg_next(void *ctx, srv_stats_row *row, int *got)
{
    pg_rows *x = ctx;
    *got = 0;
    if (x->i == x->n) {
        PQclear(x->r);
        x->r = PQexec(x->c, "FETCH 20000 FROM scan");
        if (PQresultStatus(x->r) != PGRES_TUPLES_OK) return srv_pgi_fail(x->c, x->r, "statistics query");
        x->i = 0;
        x->n = PQntuples(x->r);
        if (!x->n) return GS_OK;
    }
    const PGresult *r = x->r;
    int i = x->i++;
    row->id = strtoll(PQgetvalue(r, i, 0), NULL, 10);
    snprintf(x->survey, sizeof x->survey, "%s", PQgetvalue(r, i, 1));
    row->survey = x->survey;
    srv_site_obs *o = &row->obs;
    snprintf(o->bulb_id, sizeof o->bulb_id, "%s", PQgetvalue(r, i, 2));   /* "" when NULL */
    snprintf(o->technology, sizeof o->technology, "%s", PQgetvalue(r, i, 3));
    o->phase_deg = real_at(r, i, 4);
    o->phase_sigma_deg = real_at(r, i, 5);
    o->confidence = real_at(r, i, 6);
    o->bulb_confidence = real_at(r, i, 7);
    o->phase_confidence = real_at(r, i, 8);
    o->bulbs = PQgetisnull(r, i, 9) ? 0 : strtol(PQgetvalue(r, i, 9), NULL, 10);
    row->lat = real_at(r, i, 10);
    row->lon = real_at(r, i, 11);
    *got = 1;
    return GS_OK;
}

gs_status srv_stats_compute_pg(const char *conninfo, const srv_stats_opts *o, srv_phase_stats **groups,
                               size_t *count, long *ungrouped)
{
    if (!conninfo || !o || !groups || !count) return gs_fail(GS_EINVAL, "srv_stats_compute_pg: NULL argument");
    *groups = NULL;
    *count = 0;
    if (ungrouped) *ungrouped = 0;
    pg_rows x = {0};
    gs_status s = srv_pgi_connect(conninfo, 0, &x.c);
    if (s != GS_OK) return s;
    char sql[sizeof pg_scan_sql + 64];
    snprintf(sql, sizeof sql, "%s%s", pg_scan_sql,
             srv_stats_by_survey(o) ? "ORDER BY s.name COLLATE \"C\", 1, l.id" : "ORDER BY 1, l.id");
    const char *p[] = {o->survey, o->detections ? "true" : "false"};
    if ((s = srv_pgi_exec(x.c, "BEGIN ISOLATION LEVEL REPEATABLE READ READ ONLY", "BEGIN")) != GS_OK)
        goto done;
    if (o->survey) {
        PGresult *r = srv_pgi_query(x.c, "SELECT 1 FROM surveys WHERE name = $1", 1, p);
        if (PQresultStatus(r) != PGRES_TUPLES_OK) s = srv_pgi_fail(x.c, r, "looking up a survey");
        else if (PQntuples(r) == 0) s = gs_fail(GS_ENOTFOUND, "PostgreSQL: no survey named '%s'", o->survey);
        PQclear(r);
        if (s != GS_OK) goto done;
    }
    PGresult *r = srv_pgi_query(x.c, sql, 2, p);
    s = PQresultStatus(r) == PGRES_COMMAND_OK ? GS_OK : srv_pgi_fail(x.c, r, "statistics query");
    PQclear(r);
    if (s == GS_OK) s = srv_stats_run(o, pg_next, &x, groups, count, ungrouped);
done:
    PQclear(x.r);
    PQfinish(x.c);
    return s;
}
