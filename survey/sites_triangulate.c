/* sites_triangulate.c - two stations (survey.h, srv_triangulate_sites): a light site seen from
 * two stations is placed by intersecting its two sight lines' geodesics (gis_triangulate,
 * Karney's Gnomonic iteration), which needs no light height. Each bearing is its pixel's
 * (gis_pixel_bearing through the station's stored camera); its sigma is the cross-range part
 * of the detection's stored one-station ellipse over its distance: the height prior moves a
 * light along its sight line only, so what is across it is the bearing's error (pixel x,
 * heading, roll). */
#include "survey/internal.h"

#include <math.h>
#include <sqlite3.h>
#include <stdlib.h>
#include <string.h>

#define DEG (M_PI / 180.0)

/* The located detections of the given captures, one site after the other, stations in
 * capture order. */
static const char dets_sql[] =
    "SELECT sd.site_id, l.id, c.station_id, st.name, l.x_px, l.y_px, loc.lat_deg, loc.lon_deg, "
    "loc.semi_major_m, loc.semi_minor_m, loc.azimuth_deg, " SRV_SQL_CAMERA_COLS("st") " FROM site_detections sd JOIN lights l ON l.id = sd.light_id "
    "JOIN captures c ON c.id = sd.capture_id JOIN stations st ON st.id = c.station_id "
    "JOIN locations loc ON loc.light_id = l.id "
    "WHERE sd.capture_id IN (SELECT value FROM json_each(?1)) AND loc.lat_deg IS NOT NULL "
    "AND loc.semi_major_m IS NOT NULL ORDER BY sd.site_id, c.id, l.id";

typedef struct {
    int64_t site, light, station;
    char name[64];
    double x, y, lat, lon, a, b, az;
    gis_camera cam;
} det;

static void read_det(sqlite3_stmt *q, det *d)
{
    memset(d, 0, sizeof *d);
    d->site = sqlite3_column_int64(q, 0);
    d->light = sqlite3_column_int64(q, 1);
    d->station = sqlite3_column_int64(q, 2);
    const unsigned char *nm = sqlite3_column_text(q, 3);
    snprintf(d->name, sizeof d->name, "%s", nm ? (const char *)nm : "");
    double *f[7] = {&d->x, &d->y, &d->lat, &d->lon, &d->a, &d->b, &d->az};
    for (int k = 0; k < 7; k++) *f[k] = srv_dbi_col_real(q, 4 + k);
    srv_dbi_col_camera(q, 11, &d->cam);
}

/* 1 when two stations have no baseline (GIS_MIN_BASELINE_M: one roof stored under two names). */
static int same_place(const gis_camera *a, const gis_camera *b)
{
    double d, azi1, azi2;
    return gis_geodesic_inverse(a->lat_deg, a->lon_deg, b->lat_deg, b->lon_deg, &d, &azi1, &azi2) != GS_OK ||
           !(d > GIS_MIN_BASELINE_M);
}

/* The detection's bearing from its station and that bearing's 1-sigma, degrees. */
static gs_status bearing_of(const det *d, gis_bearing *b)
{
    double el, dist, azi1, azi2;
    b->lat_deg = d->cam.lat_deg;
    b->lon_deg = d->cam.lon_deg;
    gs_status s = gis_pixel_bearing(&d->cam, d->x, d->y, &b->azimuth_deg, &el);
    if (s == GS_OK) s = gis_geodesic_inverse(d->cam.lat_deg, d->cam.lon_deg, d->lat, d->lon, &dist, &azi1, &azi2);
    if (s != GS_OK) return s;
    /* variance along the direction phi of an ellipse with axes a, b, the major at az:
     * a^2 cos^2(phi - az) + b^2 sin^2(phi - az); phi across the sight line at the light */
    double t = (azi2 + 90.0 - d->az) * DEG;
    double var = d->a * d->a * cos(t) * cos(t) + d->b * d->b * sin(t) * sin(t);
    b->sigma_deg = dist > 0.0 ? sqrt(var) / dist / DEG : NAN;
    return isfinite(b->sigma_deg) ? GS_OK : gs_fail(GS_ENUMERIC, "light %lld: no bearing sigma",
                                                    (long long)d->light);
}

gs_status srv_triangulate_sites(srv_db *db, const int64_t *capture_ids, size_t n_captures,
                                srv_tri_site **out, size_t *n_out)
{
    *out = NULL;
    *n_out = 0;
    /* the capture ids as a JSON array for json_each */
    size_t size = 16 + 24 * n_captures, used = 0;
    char *ids = malloc(size);
    if (!ids) return gs_fail(GS_ENOMEM, "triangulate: out of memory");
    used += (size_t)snprintf(ids, size, "[");
    for (size_t i = 0; i < n_captures; i++)
        used += (size_t)snprintf(ids + used, size - used, "%s%lld", i ? "," : "", (long long)capture_ids[i]);
    snprintf(ids + used, size - used, "]");
    sqlite3_stmt *q = NULL;
    gs_status s = GS_OK;
    if (sqlite3_prepare_v2(srv_db_sqlite(db), dets_sql, -1, &q, NULL) != SQLITE_OK)
        s = srv_dbi_fail(db, "preparing the two-station query");
    if (s == GS_OK) sqlite3_bind_text(q, 1, ids, -1, SQLITE_TRANSIENT);
    srv_tri_site *res = NULL;
    size_t n = 0, cap = 0;
    det first, cur;
    int have_first = 0, done_site = 0;
    int rc = SQLITE_DONE;
    while (s == GS_OK && (rc = sqlite3_step(q)) == SQLITE_ROW) {
        read_det(q, &cur);
        if (!have_first || cur.site != first.site) {
            first = cur;
            have_first = 1;
            done_site = 0;
            continue;
        }
        if (done_site || cur.station == first.station || same_place(&cur.cam, &first.cam)) continue;
        done_site = 1;   /* the site's first two stations at two places */
        if (n == cap) {
            size_t nc = cap ? 2 * cap : 64;
            srv_tri_site *g = realloc(res, nc * sizeof *g);
            if (!g) {
                s = gs_fail(GS_ENOMEM, "triangulate: out of memory");
                break;
            }
            res = g;
            cap = nc;
        }
        srv_tri_site *t = &res[n];
        memset(t, 0, sizeof *t);
        t->site_id = first.site;
        const det *d[2] = {&first, &cur};
        gis_bearing bb[2];
        for (int k = 0; k < 2; k++) {
            t->light_id[k] = d[k]->light;
            snprintf(t->station[k], sizeof t->station[k], "%.63s", d[k]->name);
        }
        for (int k = 0; k < 2 && s == GS_OK; k++) {
            s = bearing_of(d[k], &bb[k]);
            t->sigma_bearing_deg[k] = bb[k].sigma_deg;
        }
        if (s == GS_OK) s = gis_triangulate(&bb[0], &bb[1], NULL, &t->fix);
        if (s != GS_OK && s != GS_ENOMEM) {   /* this site only: kept, with the reason */
            snprintf(t->error, sizeof t->error, "%s", gs_detail());
            t->fix.lat_deg = t->fix.lon_deg = t->fix.angle_deg = NAN;
            t->fix.ellipse.semi_major_m = t->fix.ellipse.semi_minor_m = t->fix.ellipse.azimuth_deg = NAN;
            s = GS_OK;
        }
        if (s == GS_OK) n++;
    }
    if (s == GS_OK && rc != SQLITE_DONE) s = srv_dbi_fail(db, "reading the two-station detections");
    sqlite3_finalize(q);
    free(ids);
    if (s != GS_OK) {
        free(res);
        return s;
    }
    *out = res;
    *n_out = n;
    return GS_OK;
}
