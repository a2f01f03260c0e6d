/* compare_shares.c - per-area phase-share changes between two surveys (survey.h,
 * srv_compare_shares; docs/survey-db.md "Changes between surveys"): srv_stats_compute of each
 * survey with the same grouping and filters, groups joined by name, and for each group the
 * two-proportion z test of every phase's share and the chi-square test of homogeneity of the
 * 0/120/240 split (a 2 x 3 contingency table). */
#include "survey/internal.h"

#include <math.h>
#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

gs_status srv_parse_bbox(const char *text, double bbox[4])
{
    char extra;
    if (sscanf(text, "%lf,%lf,%lf,%lf%c", &bbox[0], &bbox[1], &bbox[2], &bbox[3], &extra) != 4 ||
        !(fabs(bbox[1]) <= 90.0 && fabs(bbox[3]) <= 90.0 && bbox[1] <= bbox[3] && isfinite(bbox[0]) &&
          isfinite(bbox[2])))
        return gs_fail(GS_EINVAL, "--bbox '%s': expected MINLON,MINLAT,MAXLON,MAXLAT (degrees, "
                       "MINLAT <= MAXLAT)", text);
    return GS_OK;
}

/* The tests of c from its counts (two-proportion z with the pooled share, two-sided; Pearson's
 * chi-square of homogeneity over the phases either survey has). */
void srv_share_change_finish(srv_share_change *c)
{
    long na = c->total_a, nb = c->total_b;
    double N = (double)(na + nb), chi2 = 0.0;
    int cols = 0;
    for (int i = 0; i < 3; i++) {
        c->share_a[i] = na ? (double)c->n_a[i] / (double)na : NAN;
        c->share_b[i] = nb ? (double)c->n_b[i] / (double)nb : NAN;
        c->z[i] = c->p[i] = NAN;
        long col = c->n_a[i] + c->n_b[i];
        if (!na || !nb || !col) continue;
        double pool = (double)col / N, se = sqrt(pool * (1.0 - pool) * (1.0 / (double)na + 1.0 / (double)nb));
        if (se > 0.0) {
            c->z[i] = (c->share_b[i] - c->share_a[i]) / se;
            c->p[i] = erfc(fabs(c->z[i]) / M_SQRT2);
        }
        /* expected counts: row total x column total / N */
        double ea = (double)na * (double)col / N, eb = (double)nb * (double)col / N;
        chi2 += (c->n_a[i] - ea) * (c->n_a[i] - ea) / ea + (c->n_b[i] - eb) * (c->n_b[i] - eb) / eb;
        cols++;
    }
    c->dof = cols - 1;
    c->chi2 = c->dof >= 1 ? chi2 : NAN;
    c->p_value = c->dof >= 1 ? gs_chi2_sf(chi2, c->dof) : NAN;
}

static srv_share_change *find(srv_share_change *v, size_t n, const char *group)
{
    for (size_t i = 0; i < n; i++)
        if (!strcmp(v[i].group, group)) return &v[i];
    return NULL;
}

/* One cell grid for both surveys (each selection's own centre put the same index on different
 * ground): centred on their located lights. */
static gs_status joint_origin(srv_db *db, const char *a, const char *b, double origin[2])
{
    static const char sql[] =
        "SELECT loc.lat_deg, loc.lon_deg FROM locations loc JOIN lights l ON l.id = loc.light_id "
        "JOIN captures c ON c.id = l.capture_id JOIN surveys s ON s.id = c.survey_id "
        "WHERE s.name IN (?1, ?2) AND loc.lat_deg IS NOT NULL AND loc.lon_deg IS NOT NULL";
    sqlite3 *h = srv_db_sqlite(db);
    sqlite3_stmt *q = NULL;
    if (sqlite3_prepare_v2(h, sql, -1, &q, NULL) != SQLITE_OK) return srv_dbi_fail(db, "compare: positions");
    sqlite3_bind_text(q, 1, a, -1, SQLITE_STATIC);
    sqlite3_bind_text(q, 2, b, -1, SQLITE_STATIC);
    srv_centre c = {0};
    int rc;
    while ((rc = sqlite3_step(q)) == SQLITE_ROW) {
        double lat = sqlite3_column_double(q, 0), lon = sqlite3_column_double(q, 1);
        if (isfinite(lat) && isfinite(lon)) srv_centre_add(&c, lat, lon);
    }
    gs_status s = rc == SQLITE_DONE ? GS_OK : srv_dbi_fail(db, "compare: positions");
    sqlite3_finalize(q);
    srv_centre_get(&c, &origin[0], &origin[1]);
    return s;
}

gs_status srv_compare_shares(srv_db *db, const srv_stats_opts *o, const char *survey_a,
                             const char *survey_b, srv_share_change **out, size_t *count)
{
    *out = NULL;
    *count = 0;
    srv_phase_stats *g[2] = {NULL, NULL};
    size_t ng[2] = {0, 0};
    const char *sv[2] = {survey_a, survey_b};
    double origin[2] = {o->cell_origin_deg[0], o->cell_origin_deg[1]};
    gs_status s = GS_OK;
    if (isfinite(o->cell_m) && !(isfinite(origin[0]) && isfinite(origin[1])))
        s = joint_origin(db, survey_a, survey_b, origin);
    for (int k = 0; k < 2 && s == GS_OK; k++) {
        int64_t id;
        srv_stats_opts ok = *o;
        ok.survey = sv[k];
        ok.cell_origin_deg[0] = origin[0];
        ok.cell_origin_deg[1] = origin[1];
        if ((s = srv_db_find_survey(db, sv[k], &id)) == GS_OK) s = srv_stats_compute(db, &ok, &g[k], &ng[k], NULL);
    }
    srv_share_change *v = s == GS_OK ? calloc(ng[0] + ng[1] + 1, sizeof *v) : NULL;
    if (s == GS_OK && !v) s = gs_fail(GS_ENOMEM, "compare: out of memory");
    size_t n = 0;
    for (int k = 0; k < 2 && s == GS_OK; k++)
        for (size_t i = 0; i < ng[k]; i++) {
            srv_share_change *c = find(v, n, g[k][i].group);
            if (!c) {
                c = &v[n++];
                snprintf(c->group, sizeof c->group, "%s", g[k][i].group);
                c->lat_deg = g[k][i].lat_deg;
                c->lon_deg = g[k][i].lon_deg;
            }
            long *dst = k ? c->n_b : c->n_a;
            for (int p = 0; p < 3; p++) dst[p] = g[k][i].n[p];
            *(k ? &c->total_b : &c->total_a) = g[k][i].total;
        }
    for (size_t i = 0; i < n; i++) srv_share_change_finish(&v[i]);
    free(g[0]);
    free(g[1]);
    if (s != GS_OK) {
        free(v);
        return s;
    }
    *out = v;
    *count = n;
    return GS_OK;
}
