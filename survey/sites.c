/* sites.c - light identity (docs/survey-db.md, "Light sites"): each stored light (a detection)
 * is associated with a light site, one physical light, so that a light seen on several nights
 * or from several captures is counted once and its detections' evidence is combined.
 *
 * Association, per capture (in capture id order, detections not yet associated only, so it is
 * idempotent and resumable; inside the capture's transaction when called by
 * srv_db_add_capture):
 * - a located detection (position and finite 1-sigma ellipse, covariance C_d) is a candidate
 *   of a located site (position x_s, covariance C_s) when the Mahalanobis distance
 *   d2 = dx^T (C_d + C_s)^-1 dx < SRV_SITE_GATE_D2 (the 0.999 quantile of chi2 with 2 dof), dx in
 *   local east/north metres (WGS84, gis_metres_per_deg);
 * - every site keeps, per camera pose that saw it (the station's position, orientation and
 *   focal length; captures without a station count as one unknown, fixed camera), its
 *   detections' mean pixel (site_views); any other detection is a candidate of the sites seen
 *   from its pose within SRV_SITE_GATE_PX pixels (d2 = distance^2 in px^2), located or not, and
 *   a located detection of the pixel sites (no location) of its pose, which it upgrades;
 * - candidate pairs are assigned greedily, by position first, then by pixel, each by
 *   increasing d2, each site taking at most one detection of a capture; a located detection
 *   that joined a site by position merges into it the nearest pixel site of its pose and pixel
 *   that no detection of the capture took and that shares no capture with it; the unassigned
 *   detections found new sites.
 * A site's columns are then recomputed from all of its detections: its position is the
 * information-weighted mean (sum C_i^-1)^-1 sum C_i^-1 x_i with that covariance's ellipse, and
 * its bulb, phase and (bulb, phase) posteriors are products over the detections
 * (srv_site_combine). */
#include "survey/internal.h"

#include <math.h>
#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define DEG (M_PI / 180.0)

/* ------------------------------------------------------------------ posterior products */

/* One categorical posterior per observation: probability c on its label, (1 - c) / (M - 1) on
 * each of the M - 1 others (the uniform leftover: only the winner is stored). With a uniform
 * prior the product over observations, normalised over all M labels, is the combined
 * posterior. Returns the index (into labels) of the winner, its posterior in *post. */
static int label_product(char (*labels)[GS_ID_MAX + 8], const double *c, const long *M, size_t n,
                         double *post)
{
    int best = -1;
    double logs[64], lunnamed = 0.0, mmax = 2.0;
    size_t nl = 0;
    int idx[64];
    for (size_t i = 0; i < n && i < 64; i++) {
        idx[i] = -1;
        for (size_t j = 0; j < i; j++)
            if (idx[j] >= 0 && !strcmp(labels[j], labels[i])) {
                idx[i] = idx[j];
                break;
            }
        if (idx[i] < 0) idx[i] = (int)nl++;
        if ((double)M[i] > mmax) mmax = (double)M[i];
    }
    if (n > 64) n = 64;
    if (n == 1) {
        *post = c[0];
        return 0;
    }
    if (mmax < (double)nl) mmax = (double)nl;   /* at least the labels named (all of them may be) */
    for (size_t k = 0; k < nl; k++) logs[k] = 0.0;
    for (size_t i = 0; i < n; i++) {
        double ci = fmin(fmax(c[i], 1e-12), 1.0 - 1e-12);
        double Mi = fmax((double)M[i], mmax);
        double lo = log((1.0 - ci) / (Mi - 1.0)), hi = log(ci);
        for (size_t k = 0; k < nl; k++) logs[k] += (int)k == idx[i] ? hi : lo;
        lunnamed += lo;
    }
    double top = lunnamed;
    for (size_t k = 0; k < nl; k++)
        if (logs[k] > top) top = logs[k];
    double z = (mmax - (double)nl) * exp(lunnamed - top), pbest = -1.0;
    for (size_t k = 0; k < nl; k++) z += exp(logs[k] - top);
    for (size_t k = 0; k < nl; k++) {
        double p = exp(logs[k] - top) / z;
        if (p > pbest) {
            pbest = p;
            for (size_t i = 0; i < n; i++)
                if (idx[i] == (int)k) {
                    best = (int)i;
                    break;
                }
        }
    }
    *post = pbest;
    return best;
}

/* The phase label of a known phase: its class (0/120/240) when every phase of the site is in
 * one of those classes (three candidates), else its nearest multiple of 30 deg (the six-phase
 * candidates, or twelve for other phases). */
static void phase_label(double phase_deg, int three, char *out, size_t size)
{
    if (three) snprintf(out, size, "%d", 120 * gs_phase_class(phase_deg));
    else snprintf(out, size, "%d", ((int)lround(phase_deg / 30.0) % 12) * 30);
}

/* Whether every known phase of the detections is within 20 deg of 0/120/240 (the site's phase
 * labels are then those three classes, else the twelve multiples of 30 deg). */
static int phases_three(const srv_site_obs *o, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        if (isnan(o[i].phase_deg)) continue;
        int cl = gs_phase_class(o[i].phase_deg);
        if (cl < 0 || cl == 3) return 0;
    }
    return 1;
}

void srv_site_combine(const srv_site_obs *o, size_t n, srv_site_value *v)
{
    memset(v, 0, sizeof *v);
    v->phase_deg = v->phase_sigma_deg = NAN;
    v->detections = (long)n;
    if (!n) return;
    if (n == 1) {   /* one detection: its own answer */
        snprintf(v->bulb_id, sizeof v->bulb_id, "%s", o->bulb_id);
        snprintf(v->technology, sizeof v->technology, "%s", o->technology);
        v->phase_deg = o->phase_deg;
        v->phase_sigma_deg = o->phase_sigma_deg;
        v->confidence = o->confidence;
        v->bulb_confidence = o->bulb_confidence;
        v->phase_confidence = o->phase_confidence;
        return;
    }
    if (n > SRV_SITE_MAX_OBS) n = SRV_SITE_MAX_OBS;
    char lab[SRV_SITE_MAX_OBS][GS_ID_MAX + 8];
    double c[SRV_SITE_MAX_OBS];
    long M[SRV_SITE_MAX_OBS];
    size_t map[SRV_SITE_MAX_OBS], m = 0;
    int three = phases_three(o, n);
    long mphase = three ? 3 : 12;   /* 0/120/240, else the multiples of 30 deg */
    /* bulb */
    for (size_t i = 0; i < n; i++)
        if (o[i].bulb_id[0]) {
            snprintf(lab[m], sizeof lab[m], "%s", o[i].bulb_id);
            c[m] = o[i].bulb_confidence;
            M[m] = o[i].bulbs > 1 ? o[i].bulbs : 2;
            map[m++] = i;
        }
    if (m) {
        int w = label_product(lab, c, M, m, &v->bulb_confidence);
        snprintf(v->bulb_id, sizeof v->bulb_id, "%s", o[map[w]].bulb_id);
        snprintf(v->technology, sizeof v->technology, "%s", o[map[w]].technology);
    } else {   /* no bulb: the most confident detection's technology (if any) */
        for (size_t i = 0; i < n; i++)
            if (o[i].bulb_confidence >= v->bulb_confidence) {
                v->bulb_confidence = o[i].bulb_confidence;
                snprintf(v->technology, sizeof v->technology, "%s", o[i].technology);
            }
    }
    /* phase */
    m = 0;
    for (size_t i = 0; i < n; i++)
        if (!isnan(o[i].phase_deg)) {
            phase_label(o[i].phase_deg, three, lab[m], sizeof lab[m]);
            c[m] = o[i].phase_confidence;
            M[m] = mphase;
            map[m++] = i;
        }
    if (m) {
        int w = label_product(lab, c, M, m, &v->phase_confidence);
        char win[GS_ID_MAX + 8];
        snprintf(win, sizeof win, "%s", lab[w]);
        /* inverse-variance circular mean of the winning label's phases; a sigma of 0 (an
         * exact candidate phase) outweighs any other */
        double ss = 0.0, sc = 0.0, info = 0.0;
        int all_sigma = 1, exact = 0;
        for (size_t k = 0; k < m; k++)
            if (!strcmp(lab[k], win) && o[map[k]].phase_sigma_deg == 0.0) exact = 1;
        for (size_t k = 0; k < m; k++) {
            if (strcmp(lab[k], win)) continue;
            const srv_site_obs *x = &o[map[k]];
            double sg = x->phase_sigma_deg, wgt;
            if (exact) wgt = sg == 0.0 ? 1.0 : 0.0;
            else if (isfinite(sg) && sg > 0.0) wgt = 1.0 / (sg * sg);
            else {
                wgt = 1.0;
                all_sigma = 0;
            }
            ss += wgt * sin(x->phase_deg * DEG);
            sc += wgt * cos(x->phase_deg * DEG);
            info += wgt;
        }
        double ph = atan2(ss, sc) / DEG;
        if (ph < 0.0) ph += 360.0;
        if (ph >= 360.0) ph -= 360.0;
        v->phase_deg = ph;
        v->phase_sigma_deg = exact ? 0.0 : all_sigma ? 1.0 / sqrt(info) : NAN;
    } else {
        for (size_t i = 0; i < n; i++) v->phase_confidence = fmax(v->phase_confidence, o[i].phase_confidence);
    }
    /* the (bulb, phase) pair */
    m = 0;
    for (size_t i = 0; i < n; i++)
        if (o[i].bulb_id[0] && !isnan(o[i].phase_deg)) {
            char ph[8];
            phase_label(o[i].phase_deg, three, ph, sizeof ph);
            snprintf(lab[m], sizeof lab[m], "%.*s|%s", GS_ID_MAX - 1, o[i].bulb_id, ph);
            c[m] = o[i].confidence;
            M[m] = (o[i].bulbs > 1 ? o[i].bulbs : 2) * mphase;
            map[m++] = i;
        }
    if (m) label_product(lab, c, M, m, &v->confidence);
    else
        for (size_t i = 0; i < n; i++) v->confidence = fmax(v->confidence, o[i].confidence);
}

/* ------------------------------------------------------------------ geometry */

/* The covariance (east, north; m^2) of a 1-sigma ellipse (azimuth of the major axis clockwise
 * from north). */
static void ellipse_cov(double a, double b, double az_deg, double C[3])
{
    double s = sin(az_deg * DEG), c = cos(az_deg * DEG);
    C[0] = a * a * s * s + b * b * c * c;   /* ee */
    C[1] = (a * a - b * b) * s * c;         /* en */
    C[2] = a * a * c * c + b * b * s * s;   /* nn */
}

static void cov_ellipse(const double C[3], double *a, double *b, double *az_deg)
{
    double tr = C[0] + C[2], det = C[0] * C[2] - C[1] * C[1];
    double disc = sqrt(fmax(tr * tr / 4.0 - det, 0.0));
    double l1 = tr / 2.0 + disc, l2 = fmax(tr / 2.0 - disc, 0.0);
    *a = sqrt(l1);
    *b = sqrt(l2);
    /* eigenvector of l1: (C_en, l1 - C_ee) in (east, north) */
    double e = C[1], nn = l1 - C[0];
    if (fabs(e) < 1e-300 && fabs(nn) < 1e-300) {
        e = C[0] >= C[2] ? 1.0 : 0.0;
        nn = C[0] >= C[2] ? 0.0 : 1.0;
    }
    double az = atan2(e, nn) / DEG;
    while (az < 0.0) az += 180.0;
    while (az >= 180.0) az -= 180.0;
    *az_deg = az;
}

/* Mahalanobis d2 of the offset (dx east, dy north) under the covariance C. */
static double maha2(double dx, double dy, const double C[3])
{
    double det = C[0] * C[2] - C[1] * C[1];
    if (!(det > 0.0)) return INFINITY;
    return (C[2] * dx * dx - 2.0 * C[1] * dx * dy + C[0] * dy * dy) / det;
}

double srv_ellipse_maha2(double a_m, double b_m, double az_deg, double east_m, double north_m)
{
    double C[3];
    ellipse_cov(a_m, b_m, az_deg, C);
    return maha2(east_m, north_m, C);
}

/* ------------------------------------------------------------------ association */

typedef struct {
    int64_t light_id;
    double x_px, y_px, lat, lon, height, a, C[3];
    int located;
    srv_site_obs obs;      /* its recognition (a new site's combined answer) */
    int64_t site;          /* assigned site, 0 = none yet */
    double d2;
    int by_pixel, merged;  /* joined by pose and pixel; merged a pixel site into its own */
} detection;

/* A candidate (detection, site): by position (Mahalanobis d2) or by pose and pixel (px^2),
 * which come second; whether the site is located. */
typedef struct {
    double d2;
    size_t det;
    int64_t site;
    int by_pixel, site_located;
} pair;

static int cmp_pairs(const void *a, const void *b)
{
    const pair *x = a, *y = b;
    if (x->by_pixel != y->by_pixel) return x->by_pixel - y->by_pixel;
    if (x->d2 != y->d2) return x->d2 < y->d2 ? -1 : 1;
    if (x->det != y->det) return x->det < y->det ? -1 : 1;
    return x->site < y->site ? -1 : x->site > y->site;
}


static gs_status prep(srv_db *db, const char *sql, sqlite3_stmt **q)
{
    if (sqlite3_prepare_v2(srv_db_sqlite(db), sql, -1, q, NULL) != SQLITE_OK)
        return srv_dbi_fail(db, "preparing a light-site statement");
    return GS_OK;
}

static const char dets_sql[] =
    "SELECT l.id, l.x_px, l.y_px, loc.lat_deg, loc.lon_deg, loc.height_m, loc.semi_major_m, "
    "loc.semi_minor_m, loc.azimuth_deg, " SRV_SQL_POSE_KEY("st") ", "
    "l.bulb_id, l.technology, l.phase_deg, l.phase_sigma_deg, l.confidence, l.bulb_confidence, "
    "l.phase_confidence, " SRV_SQL_BULB_LABELS " "
    "FROM lights l JOIN captures c ON c.id = l.capture_id LEFT JOIN stations st ON st.id = c.station_id "
    "LEFT JOIN locations loc ON loc.light_id = l.id LEFT JOIN delight_versions dv ON dv.id = c.delight_id "
    "WHERE l.capture_id = ?1 AND NOT EXISTS (SELECT 1 FROM site_detections sd WHERE sd.light_id = l.id) "
    "ORDER BY l.light_index";
static const char geo_cand_sql[] =
    "SELECT s.id, s.lat_deg, s.lon_deg, s.semi_major_m, s.semi_minor_m, s.azimuth_deg "
    "FROM light_sites_rtree r CROSS JOIN light_sites s ON s.id = r.id "
    "WHERE r.max_lat >= ?1 AND r.min_lat <= ?2 AND r.max_lon >= ?3 AND r.min_lon <= ?4";
/* the sites seen from a pose within a pixel box (site_views), whether each is located */
static const char view_cand_sql[] =
    "SELECT v.site_id, v.x_px, v.y_px, s.pose_key IS NULL FROM site_views v JOIN light_sites s ON s.id = v.site_id "
    "WHERE v.pose_key = ?1 AND v.x_px BETWEEN ?2 AND ?3 AND v.y_px BETWEEN ?4 AND ?5";
static const char site_obs_sql[] =
    "SELECT l.bulb_id, l.technology, l.phase_deg, l.phase_sigma_deg, l.confidence, l.bulb_confidence, "
    "l.phase_confidence, " SRV_SQL_BULB_LABELS ", loc.lat_deg, loc.lon_deg, loc.height_m, loc.semi_major_m, "
    "loc.semi_minor_m, loc.azimuth_deg, l.x_px, l.y_px, " SRV_SQL_POSE_KEY("st") " FROM site_detections sd "
    "JOIN lights l ON l.id = sd.light_id JOIN captures c ON c.id = l.capture_id "
    "LEFT JOIN delight_versions dv ON dv.id = c.delight_id LEFT JOIN locations loc ON loc.light_id = l.id "
    "LEFT JOIN stations st ON st.id = c.station_id WHERE sd.site_id = ?1 ORDER BY sd.light_id";
static const char views_del_sql[] = "DELETE FROM site_views WHERE site_id = ?1";
static const char views_sql[] = SRV_SQL_SITE_VIEWS("WHERE sd.site_id = ?1");

static const char new_site_sql[] =
    "INSERT INTO light_sites(lat_deg, lon_deg, height_m, semi_major_m, semi_minor_m, azimuth_deg, "
    "pose_key, x_px, y_px, detections, captures, bulb_id, technology, phase_deg, phase_sigma_deg, "
    "confidence, bulb_confidence, phase_confidence) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, 1, "
    "1, ?10, ?11, ?12, ?13, ?14, ?15, ?16)";
static const char site_update_sql[] =
    "UPDATE light_sites SET lat_deg = ?1, lon_deg = ?2, height_m = ?3, semi_major_m = ?4, "
    "semi_minor_m = ?5, azimuth_deg = ?6, x_px = ?7, y_px = ?8, detections = ?9, captures = ?9, "
    "bulb_id = ?10, technology = ?11, phase_deg = ?12, phase_sigma_deg = ?13, confidence = ?14, "
    "bulb_confidence = ?15, phase_confidence = ?16, pose_key = ?18, stale = 0 WHERE id = ?17";

void srv_site_obs_from_row(sqlite3_stmt *q, int first, srv_site_obs *o)
{
    const char *b = (const char *)sqlite3_column_text(q, first);
    const char *t = (const char *)sqlite3_column_text(q, first + 1);
    snprintf(o->bulb_id, sizeof o->bulb_id, "%s", b ? b : "");
    snprintf(o->technology, sizeof o->technology, "%s", t ? t : "");
    o->phase_deg = srv_dbi_col_real(q, first + 2);
    o->phase_sigma_deg = srv_dbi_col_real(q, first + 3);
    o->confidence = sqlite3_column_double(q, first + 4);
    o->bulb_confidence = sqlite3_column_double(q, first + 5);
    o->phase_confidence = sqlite3_column_double(q, first + 6);
    o->bulbs = sqlite3_column_type(q, first + 7) == SQLITE_NULL ? 0 : sqlite3_column_int64(q, first + 7);
}

/* *v (of *cap elements of `size` bytes) grown to hold at least n. */
static gs_status grow(void *v, size_t *cap, size_t n, size_t size)
{
    if (n <= *cap) return GS_OK;
    size_t nc = *cap ? *cap : 64;
    while (nc < n) nc *= 2;
    void *nv = realloc(*(void **)v, nc * size);
    if (!nv) return gs_fail(GS_ENOMEM, "light sites: out of memory");
    *(void **)v = nv;
    *cap = nc;
    return GS_OK;
}

/* A site's combined answer as parameters 10..16 of new_site_sql / site_update_sql. */
static void bind_value(sqlite3_stmt *q, const srv_site_value *v)
{
    srv_dbi_bind_text(q, 10, v->bulb_id);
    srv_dbi_bind_text(q, 11, v->technology);
    srv_dbi_bind_real(q, 12, v->phase_deg);
    srv_dbi_bind_real(q, 13, v->phase_sigma_deg);
    sqlite3_bind_double(q, 14, fmin(fmax(v->confidence, 0.0), 1.0));
    sqlite3_bind_double(q, 15, fmin(fmax(v->bulb_confidence, 0.0), 1.0));
    sqlite3_bind_double(q, 16, fmin(fmax(v->phase_confidence, 0.0), 1.0));
}

/* The statements that keep a site: its detections (site_obs_sql), its update, its views'
 * deletion and insertion. */
typedef struct {
    sqlite3_stmt *obs, *update, *views_del, *views;
} site_stmts;

static gs_status prep_site_stmts(srv_db *db, site_stmts *q)
{
    gs_status s;
    if ((s = prep(db, site_obs_sql, &q->obs)) != GS_OK || (s = prep(db, site_update_sql, &q->update)) != GS_OK ||
        (s = prep(db, views_del_sql, &q->views_del)) != GS_OK)
        return s;
    return prep(db, views_sql, &q->views);
}

static void finalize_site_stmts(site_stmts *q)
{
    sqlite3_finalize(q->obs);
    sqlite3_finalize(q->update);
    sqlite3_finalize(q->views_del);
    sqlite3_finalize(q->views);
}

/* A site's views (site_views) recomputed from its detections. */
static gs_status refresh_views(srv_db *db, const site_stmts *q, int64_t site)
{
    gs_status s;
    sqlite3_reset(q->views_del);
    sqlite3_bind_int64(q->views_del, 1, site);
    if ((s = srv_dbi_step_done(db, q->views_del, "updating a light site's views")) != GS_OK) return s;
    sqlite3_reset(q->views);
    sqlite3_bind_int64(q->views, 1, site);
    return srv_dbi_step_done(db, q->views, "updating a light site's views");
}

/* Recompute a site's columns and views from its detections: located (pose_key NULL, in the
 * R*Tree) when one of them is, else a pixel site of its first detection's pose. */
static gs_status refresh_site(srv_db *db, const site_stmts *st, int64_t site)
{
    sqlite3_stmt *qo = st->obs, *qu = st->update;
    srv_site_obs *o = NULL;
    size_t n = 0, cap = 0;
    char *pose = NULL;   /* the first detection's (a key as long as its station's numbers) */
    double I[3] = {0, 0, 0}, ie = 0.0, in = 0.0, lat0 = NAN, lon0 = NAN, kx = NAN, ky = NAN, sx = 0, sy = 0, sh = 0;
    double shl = 0.0;   /* the heights of the located detections */
    long nh = 0, nhl = 0, nloc = 0;
    int rc;
    gs_status s = GS_OK;
    sqlite3_reset(qo);
    sqlite3_bind_int64(qo, 1, site);
    while ((rc = sqlite3_step(qo)) == SQLITE_ROW) {
        if ((s = grow(&o, &cap, n + 1, sizeof *o)) != GS_OK) break;
        srv_site_obs_from_row(qo, 0, &o[n++]);
        if (n == 1 && !(pose = strdup((const char *)sqlite3_column_text(qo, 16)))) {
            s = gs_fail(GS_ENOMEM, "light sites: out of memory");
            break;
        }
        double lat = srv_dbi_col_real(qo, 8), lon = srv_dbi_col_real(qo, 9), h = srv_dbi_col_real(qo, 10);
        double a = srv_dbi_col_real(qo, 11), b = srv_dbi_col_real(qo, 12), az = srv_dbi_col_real(qo, 13);
        sx += sqlite3_column_double(qo, 14);
        sy += sqlite3_column_double(qo, 15);
        if (isfinite(h)) {
            sh += h;
            nh++;
        }
        if (!isfinite(lat) || !(a > 0.0) || !isfinite(a) || !(b > 0.0) || !isfinite(b)) continue;
        if (isfinite(h)) {
            shl += h;
            nhl++;
        }
        if (isnan(lat0)) {   /* the local metres (WGS84, those of the ellipses) at the first */
            lat0 = lat;
            lon0 = lon;
            gis_metres_per_deg(lat0, &ky, &kx);
        }
        double C[3];
        ellipse_cov(a, b, isfinite(az) ? az : 0.0, C);
        double det = C[0] * C[2] - C[1] * C[1];
        double Ii[3] = {C[2] / det, -C[1] / det, C[0] / det};
        double x = kx * gs_wrap180(lon - lon0), y = ky * (lat - lat0);
        for (int j = 0; j < 3; j++) I[j] += Ii[j];
        ie += Ii[0] * x + Ii[1] * y;
        in += Ii[1] * x + Ii[2] * y;
        nloc++;
    }
    if (s == GS_OK && rc != SQLITE_DONE) s = srv_dbi_fail(db, "reading a site's detections");
    if (s == GS_OK && n) {
        srv_site_value v;
        srv_site_combine(o, n, &v);
        double lat = NAN, lon = NAN, a = NAN, b = NAN, az = NAN;
        if (nloc) {
            double det = I[0] * I[2] - I[1] * I[1];
            double C[3] = {I[2] / det, -I[1] / det, I[0] / det};
            double x = C[0] * ie + C[1] * in, y = C[1] * ie + C[2] * in;
            lat = lat0 + y / ky;
            lon = gs_wrap180(lon0 + x / kx);
            cov_ellipse(C, &a, &b, &az);
        }
        sqlite3_reset(qu);
        sqlite3_clear_bindings(qu);
        srv_dbi_bind_real(qu, 1, lat);
        srv_dbi_bind_real(qu, 2, lon);
        /* the height, like the position, of the located detections when there are any */
        srv_dbi_bind_real(qu, 3, nloc ? (nhl ? shl / (double)nhl : NAN) : nh ? sh / (double)nh : NAN);
        srv_dbi_bind_real(qu, 4, a);
        srv_dbi_bind_real(qu, 5, b);
        srv_dbi_bind_real(qu, 6, az);
        srv_dbi_bind_real(qu, 7, sx / (double)n);
        srv_dbi_bind_real(qu, 8, sy / (double)n);
        sqlite3_bind_int64(qu, 9, (sqlite3_int64)n);
        bind_value(qu, &v);
        sqlite3_bind_int64(qu, 17, site);
        if (!nloc) sqlite3_bind_text(qu, 18, pose, -1, SQLITE_TRANSIENT);
        s = srv_dbi_step_done(db, qu, "updating a light site");
        if (s == GS_OK) s = refresh_views(db, st, site);
    }
    free(o);
    free(pose);
    return s;
}

static int cmp_ids(const void *a, const void *b)
{
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return x < y ? -1 : x > y;
}

/* The first column of every row of sql (integers) into *ids, *n of them. */
static gs_status collect_ids(srv_db *db, const char *sql, int64_t **ids, size_t *cap, size_t *n)
{
    sqlite3_stmt *q;
    gs_status s = prep(db, sql, &q);
    *n = 0;
    int rc = SQLITE_DONE;
    while (s == GS_OK && (rc = sqlite3_step(q)) == SQLITE_ROW) {
        if ((s = grow(ids, cap, *n + 1, sizeof **ids)) == GS_OK) (*ids)[(*n)++] = sqlite3_column_int64(q, 0);
    }
    if (s == GS_OK && rc != SQLITE_DONE) s = srv_dbi_fail(db, "listing light sites");
    sqlite3_finalize(q);
    return s;
}

/* The candidate pairs of located detection d[i]: the located sites within the gate
 * d2 = dx^T (C_d + C_s)^-1 dx < SRV_SITE_GATE_D2, preselected by the site R*Tree in a box of
 * half-width sqrt(gate) (a_d + amax), amax the widest site ellipse; sites in held (they hold a
 * detection of the capture) are skipped. */
static gs_status geo_candidates(srv_db *db, sqlite3_stmt *q, const detection *d, size_t i, double amax,
                                const int64_t *held, size_t nheld, pair **p, size_t *capp, size_t *np)
{
    const detection *x = &d[i];
    /* the gate box's longitudes: one range, or two across the antimeridian (the sites are
     * stored in [-180, 180)) */
    double lon_range[2][2] = {{0.0, 0.0}, {0.0, 0.0}}, dlat;
    int nranges = 1, rc;
    double r = sqrt(SRV_SITE_GATE_D2) * (x->a + amax) * 1.01, ky, kx;
    gis_metres_per_deg(0.0, &ky, &kx);   /* the shortest metres per degree of latitude */
    dlat = r / ky;
    gis_metres_per_deg(fmin(fabs(x->lat) + dlat, 89.9), &ky, &kx);
    double dlon = fmin(r / kx, 180.0);
    lon_range[0][0] = x->lon - dlon;
    lon_range[0][1] = x->lon + dlon;
    if (lon_range[0][0] < -180.0) {
        lon_range[1][0] = lon_range[0][0] + 360.0;
        lon_range[1][1] = 180.0;
        nranges = 2;
    } else if (lon_range[0][1] >= 180.0) {
        lon_range[1][0] = -180.0;
        lon_range[1][1] = lon_range[0][1] - 360.0;
        nranges = 2;
    }
    for (int g = 0; g < nranges; g++) {
        sqlite3_reset(q);
        sqlite3_bind_double(q, 1, x->lat - dlat);
        sqlite3_bind_double(q, 2, x->lat + dlat);
        sqlite3_bind_double(q, 3, lon_range[g][0]);
        sqlite3_bind_double(q, 4, lon_range[g][1]);
        while ((rc = sqlite3_step(q)) == SQLITE_ROW) {
            double lat = srv_dbi_col_real(q, 1), lon = srv_dbi_col_real(q, 2), C[3];
            double a = srv_dbi_col_real(q, 3), b = srv_dbi_col_real(q, 4), az = srv_dbi_col_real(q, 5);
            if (!(a > 0.0) || !(b > 0.0)) continue;
            ellipse_cov(a, b, isfinite(az) ? az : 0.0, C);
            for (int j = 0; j < 3; j++) C[j] += x->C[j];
            gis_metres_per_deg(x->lat, &ky, &kx);
            double d2 = maha2(kx * gs_wrap180(x->lon - lon), ky * (x->lat - lat), C);
            if (!(d2 < SRV_SITE_GATE_D2)) continue;
            int64_t sid = sqlite3_column_int64(q, 0);
            if (nheld && bsearch(&sid, held, nheld, sizeof *held, cmp_ids)) continue;   /* has one */
            gs_status s = grow(p, capp, *np + 1, sizeof **p);
            if (s != GS_OK) return s;
            (*p)[(*np)++] = (pair){d2, i, sid, 0, 1};
        }
        if (rc != SQLITE_DONE) return srv_dbi_fail(db, "looking up light sites");
    }
    return GS_OK;
}

/* The candidate pairs of detection d[i] by pose and pixel, d2 in px^2 within
 * SRV_SITE_GATE_PX: the sites seen from its camera pose (q: site_views, their detections' mean
 * pixel from that pose); for a located detection only those without a location (it meets the
 * located ones by position). A pixel site's view of the pose, not light_sites' pixel: a site
 * that lost its located detections holds those of several poses. Sites in held are skipped. */
static gs_status pixel_candidates(srv_db *db, sqlite3_stmt *q, const char *pose, const detection *d, size_t i,
                                  const int64_t *held, size_t nheld, pair **p, size_t *capp, size_t *np)
{
    const detection *x = &d[i];
    int rc;
    sqlite3_reset(q);
    sqlite3_bind_text(q, 1, pose, -1, SQLITE_STATIC);
    sqlite3_bind_double(q, 2, x->x_px - SRV_SITE_GATE_PX);
    sqlite3_bind_double(q, 3, x->x_px + SRV_SITE_GATE_PX);
    sqlite3_bind_double(q, 4, x->y_px - SRV_SITE_GATE_PX);
    sqlite3_bind_double(q, 5, x->y_px + SRV_SITE_GATE_PX);
    while ((rc = sqlite3_step(q)) == SQLITE_ROW) {
        int located = sqlite3_column_int(q, 3);
        if (located && x->located) continue;
        double dx = x->x_px - sqlite3_column_double(q, 1), dy = x->y_px - sqlite3_column_double(q, 2);
        double d2 = dx * dx + dy * dy;
        if (!(d2 <= SRV_SITE_GATE_PX * SRV_SITE_GATE_PX)) continue;
        int64_t sid = sqlite3_column_int64(q, 0);
        if (nheld && bsearch(&sid, held, nheld, sizeof *held, cmp_ids)) continue;   /* has one */
        gs_status s = grow(p, capp, *np + 1, sizeof **p);
        if (s != GS_OK) return s;
        (*p)[(*np)++] = (pair){d2, i, sid, 1, located};
    }
    return rc == SQLITE_DONE ? GS_OK : srv_dbi_fail(db, "looking up light sites");
}

/* The statements of merge_sites: shared captures, moving detections, deleting a site. */
static gs_status prep_merge(srv_db *db, sqlite3_stmt *q[3])
{
    gs_status s;
    if ((s = prep(db, "SELECT count(*) FROM site_detections a JOIN site_detections b ON b.site_id = ?2 "
                      "AND b.capture_id = a.capture_id WHERE a.site_id = ?1", &q[0])) != GS_OK ||
        (s = prep(db, "UPDATE site_detections SET site_id = ?2 WHERE site_id = ?1", &q[1])) != GS_OK)
        return s;
    return prep(db, "DELETE FROM light_sites WHERE id = ?1", &q[2]);
}

/* Site `from`'s detections moved to site `into` and `from` deleted (its views with it), when
 * the two share no capture (*merged = 1); the caller refreshes `into`. */
static gs_status merge_sites(srv_db *db, sqlite3_stmt *q[3], int64_t into, int64_t from, int *merged)
{
    gs_status s;
    *merged = 0;
    sqlite3_reset(q[0]);
    sqlite3_bind_int64(q[0], 1, from);
    sqlite3_bind_int64(q[0], 2, into);
    if (sqlite3_step(q[0]) != SQLITE_ROW) return srv_dbi_fail(db, "merging light sites");
    if (sqlite3_column_int64(q[0], 0) > 0) return GS_OK;   /* two lights of one capture */
    for (int k = 1; k < 3; k++) {
        sqlite3_reset(q[k]);
        sqlite3_bind_int64(q[k], 1, from);
        if (k == 1) sqlite3_bind_int64(q[k], 2, into);
        if ((s = srv_dbi_step_done(db, q[k], "merging light sites")) != GS_OK) return s;
    }
    *merged = 1;
    return GS_OK;
}

/* Associate the not yet associated detections of one capture. */
static gs_status associate_capture(srv_db *db, int64_t cid, long *created, long *joined, long *merged_sites)
{
    sqlite3 *h = srv_db_sqlite(db);
    sqlite3_stmt *qd = NULL, *qg = NULL, *qv = NULL, *qi = NULL, *qa = NULL, *qm = NULL, *qw = NULL,
                 *qx[3] = {NULL, NULL, NULL};
    site_stmts st = {NULL, NULL, NULL, NULL};
    detection *d = NULL;
    pair *p = NULL;
    size_t nd = 0, capd = 0, np = 0, capp = 0;
    int64_t *touched = NULL, *taken = NULL, *held = NULL;
    size_t ntaken = 0, nheld = 0, capheld = 0;
    char *flag = NULL, *pose = NULL;   /* the capture's camera pose key (one per capture) */
    gs_status s = GS_OK;
    int rc;
    if ((s = prep(db, dets_sql, &qd)) != GS_OK || (s = prep(db, geo_cand_sql, &qg)) != GS_OK ||
        (s = prep(db, view_cand_sql, &qv)) != GS_OK ||
        (s = prep(db, new_site_sql, &qi)) != GS_OK ||
        (s = prep(db, "INSERT INTO site_detections(light_id, site_id, capture_id, d2) VALUES "
                      "(?1, ?2, ?3, ?4)", &qa)) != GS_OK ||
        (s = prep_site_stmts(db, &st)) != GS_OK || (s = prep_merge(db, qx)) != GS_OK ||
        (s = prep(db, "INSERT INTO site_views(site_id, pose_key, x_px, y_px, detections) VALUES "
                      "(?1, ?2, ?3, ?4, 1)", &qw)) != GS_OK ||
        (s = prep(db, "SELECT max(semi_major_m) FROM light_sites WHERE pose_key IS NULL", &qm)) != GS_OK)
        goto done;
    sqlite3_bind_int64(qd, 1, cid);
    while ((rc = sqlite3_step(qd)) == SQLITE_ROW) {
        if ((s = grow(&d, &capd, nd + 1, sizeof *d)) != GS_OK) goto done;
        detection *x = &d[nd++];
        memset(x, 0, sizeof *x);
        x->light_id = sqlite3_column_int64(qd, 0);
        x->x_px = sqlite3_column_double(qd, 1);
        x->y_px = sqlite3_column_double(qd, 2);
        x->lat = srv_dbi_col_real(qd, 3);
        x->lon = srv_dbi_col_real(qd, 4);
        x->height = srv_dbi_col_real(qd, 5);
        double a = srv_dbi_col_real(qd, 6), b = srv_dbi_col_real(qd, 7), az = srv_dbi_col_real(qd, 8);
        x->located = isfinite(x->lat) && a > 0.0 && isfinite(a) && b > 0.0 && isfinite(b);
        if (x->located) ellipse_cov(a, b, isfinite(az) ? az : 0.0, x->C);
        x->a = a;
        const char *pk = (const char *)sqlite3_column_text(qd, 9);
        if (!pose && !(pose = strdup(pk ? pk : "none"))) {
            s = gs_fail(GS_ENOMEM, "light sites: out of memory");
            goto done;
        }
        srv_site_obs_from_row(qd, 10, &x->obs);
    }
    if (rc != SQLITE_DONE) {
        s = srv_dbi_fail(db, "reading detections");
        goto done;
    }
    if (!nd) goto done;
    /* the sites that already hold a detection of this capture (none unless a capture was
     * associated in part) */
    char held_sql[96];
    snprintf(held_sql, sizeof held_sql, "SELECT site_id FROM site_detections WHERE capture_id = %lld "
             "ORDER BY site_id", (long long)cid);
    if ((s = collect_ids(db, held_sql, &held, &capheld, &nheld)) != GS_OK) goto done;
    double amax = 0.0;
    if ((rc = sqlite3_step(qm)) == SQLITE_ROW) amax = fmax(srv_dbi_col_real(qm, 0), 0.0);
    else if (rc != SQLITE_DONE) {   /* (SQLite may have rolled the transaction back) */
        s = srv_dbi_fail(db, "reading the widest site ellipse");
        goto done;
    }
    if (isnan(amax)) amax = 0.0;
    /* candidate pairs */
    for (size_t i = 0; i < nd && s == GS_OK; i++) {
        if (d[i].located) s = geo_candidates(db, qg, d, i, amax, held, nheld, &p, &capp, &np);
        if (s == GS_OK) s = pixel_candidates(db, qv, pose, d, i, held, nheld, &p, &capp, &np);
    }
    if (s != GS_OK) goto done;
    /* greedy assignment, by position first, then by pixel, each by increasing d2; a site takes
     * one detection of the capture */
    if (np) {   /* (qsort of a NULL array, even empty, is undefined) */
        qsort(p, np, sizeof *p, cmp_pairs);
        if ((s = grow(&taken, &ntaken, np, sizeof *taken)) != GS_OK) goto done;
        for (size_t k = 0; k < np; k++) taken[k] = p[k].site;
        qsort(taken, np, sizeof *taken, cmp_ids);
    }
    flag = calloc(np ? np : 1, 1);
    if (!flag) {
        s = gs_fail(GS_ENOMEM, "light sites: out of memory");
        goto done;
    }
    for (size_t k = 0; k < np; k++) {
        const int64_t *t = bsearch(&p[k].site, taken, np, sizeof *taken, cmp_ids);
        size_t ti = (size_t)(t - taken);
        if (d[p[k].det].site || flag[ti]) continue;
        flag[ti] = 1;
        d[p[k].det].site = p[k].site;
        d[p[k].det].d2 = p[k].d2;
        d[p[k].det].by_pixel = p[k].by_pixel;
        (*joined)++;
    }
    /* a located detection that joined a site by position merges into it the nearest pixel site
     * of its pose and pixel that no detection of this capture took and that shares no capture
     * with it (one light, seen unlocated from here and located from elsewhere): the pairs in
     * order of d2, a pixel site sharing a capture passed over */
    for (size_t k = 0; k < np; k++) {
        detection *x = &d[p[k].det];
        const int64_t *t = bsearch(&p[k].site, taken, np, sizeof *taken, cmp_ids);
        size_t ti = (size_t)(t - taken);
        if (!p[k].by_pixel || p[k].site_located || !x->site || x->by_pixel || x->merged || flag[ti]) continue;
        int merged = 0;
        if ((s = merge_sites(db, qx, x->site, p[k].site, &merged)) != GS_OK) goto done;
        flag[ti] = (char)merged;
        x->merged = merged;
        *merged_sites += merged;
    }
    touched = malloc(nd * sizeof *touched);
    if (!touched) {
        s = gs_fail(GS_ENOMEM, "light sites: out of memory");
        goto done;
    }
    for (size_t i = 0; i < nd; i++) {
        detection *x = &d[i];
        touched[i] = x->site;   /* an existing site is refreshed below */
        if (!x->site) {   /* a new site: the detection's own answer (srv_site_combine of one) */
            sqlite3_reset(qi);
            sqlite3_clear_bindings(qi);
            if (x->located) {
                double a, b, az;
                cov_ellipse(x->C, &a, &b, &az);
                sqlite3_bind_double(qi, 1, x->lat);
                sqlite3_bind_double(qi, 2, gs_wrap180(x->lon));
                srv_dbi_bind_real(qi, 4, a);
                srv_dbi_bind_real(qi, 5, b);
                srv_dbi_bind_real(qi, 6, az);
            } else {
                sqlite3_bind_text(qi, 7, pose, -1, SQLITE_STATIC);
            }
            srv_dbi_bind_real(qi, 3, x->height);
            sqlite3_bind_double(qi, 8, x->x_px);
            sqlite3_bind_double(qi, 9, x->y_px);
            srv_site_value v;
            srv_site_combine(&x->obs, 1, &v);
            bind_value(qi, &v);
            if ((s = srv_dbi_step_done(db, qi, "adding a light site")) != GS_OK) goto done;
            x->site = sqlite3_last_insert_rowid(h);
            x->d2 = NAN;
            (*created)++;
        }
        sqlite3_reset(qa);
        sqlite3_bind_int64(qa, 1, x->light_id);
        sqlite3_bind_int64(qa, 2, x->site);
        sqlite3_bind_int64(qa, 3, cid);
        srv_dbi_bind_real(qa, 4, x->d2);
        if ((s = srv_dbi_step_done(db, qa, "associating a detection")) != GS_OK) goto done;
        if (!touched[i]) {   /* a new site's view: its detection's pose and pixel */
            sqlite3_reset(qw);
            sqlite3_bind_int64(qw, 1, x->site);
            sqlite3_bind_text(qw, 2, pose, -1, SQLITE_STATIC);
            sqlite3_bind_double(qw, 3, x->x_px);
            sqlite3_bind_double(qw, 4, x->y_px);
            if ((s = srv_dbi_step_done(db, qw, "adding a light site's view")) != GS_OK) goto done;
        }
    }
    for (size_t i = 0; i < nd && s == GS_OK; i++)
        if (touched[i]) s = refresh_site(db, &st, touched[i]);
done:
    sqlite3_finalize(qd);
    sqlite3_finalize(qg);
    sqlite3_finalize(qv);
    sqlite3_finalize(qi);
    sqlite3_finalize(qa);
    sqlite3_finalize(qm);
    sqlite3_finalize(qw);
    finalize_site_stmts(&st);
    for (int k = 0; k < 3; k++) sqlite3_finalize(qx[k]);
    free(d);
    free(p);
    free(touched);
    free(taken);
    free(flag);
    free(held);
    free(pose);
    return s;
}

gs_status srv_dbi_associate_capture(srv_db *db, int64_t capture_id, long *created, long *joined, long *merged)
{
    return associate_capture(db, capture_id, created, joined, merged);
}

gs_status srv_db_associate(srv_db *db, long *created, long *joined, long *merged)
{
    if (!db) return gs_fail(GS_EINVAL, "srv_db_associate: NULL database");
    long c0 = 0, j0 = 0, m0 = 0;
    if (!created) created = &c0;
    if (!joined) joined = &j0;
    if (!merged) merged = &m0;
    *created = *joined = *merged = 0;
    int began;
    gs_status s = srv_dbi_auto_begin(db, &began);
    if (s != GS_OK) return s;
    site_stmts st = {NULL, NULL, NULL, NULL};
    int64_t *ids = NULL;
    size_t n = 0, cap = 0;
    s = collect_ids(db, "SELECT DISTINCT l.capture_id FROM lights l WHERE NOT EXISTS (SELECT 1 FROM "
                        "site_detections sd WHERE sd.light_id = l.id) ORDER BY l.capture_id",
                    &ids, &cap, &n);
    for (size_t i = 0; i < n && s == GS_OK; i++) s = associate_capture(db, ids[i], created, joined, merged);
    /* sites left stale by deleted detections */
    if (s == GS_OK) s = collect_ids(db, "SELECT id FROM light_sites WHERE stale = 1", &ids, &cap, &n);
    if (s == GS_OK && n && (s = prep_site_stmts(db, &st)) == GS_OK)
        for (size_t i = 0; i < n && s == GS_OK; i++) s = refresh_site(db, &st, ids[i]);
    finalize_site_stmts(&st);
    free(ids);
    return srv_dbi_auto_end(db, began, s);
}

/* ------------------------------------------------------------------ change detection */

/* P(two categorical posteriors name the same label): winners wa, wb with probabilities ca, cb,
 * the rest spread evenly over the M - 1 others (as in srv_site_combine). */
static double p_same(int same_winner, double ca, double cb, double M)
{
    double ra = (1.0 - ca) / (M - 1.0), rb = (1.0 - cb) / (M - 1.0);
    if (same_winner) return ca * cb + (M - 1.0) * ra * rb;
    return ca * rb + cb * ra + (M - 2.0) * ra * rb;
}

/* P(two phase posteriors name the same label), over the twelve multiples of 30 deg: each side
 * its winner's label w with c and the rest spread evenly over the other labels of its own set,
 * the classes 0/120/240 (labels 0, 4, 8) when three, else all twelve (as srv_site_combine:
 * a night with a transformer-phase detection has twelve, the other may have three). */
static double p_label(int l, int w, double c, int three)
{
    if (three && l % 4) return 0.0;
    return l == w ? c : (1.0 - c) / (three ? 2.0 : 11.0);
}

/* The winning phase's label of the twelve: its class's (0, 4, 8) when three, else its multiple
 * of 30 deg (phase_label's). */
static int phase_winner(const srv_site_value *v, int three)
{
    return three ? 4 * gs_phase_class(v->phase_deg) : (int)lround(gs_wrap360(v->phase_deg) / 30.0) % 12;
}

static double p_same_phase(const srv_site_value *a, int three_a, const srv_site_value *b, int three_b)
{
    int wa = phase_winner(a, three_a), wb = phase_winner(b, three_b);
    double p = 0.0;
    for (int l = 0; l < 12; l++) p += p_label(l, wa, a->phase_confidence, three_a) * p_label(l, wb, b->phase_confidence, three_b);
    return p;
}

static const char compare_sql[] =
    "SELECT sd.site_id, s.name = ?2, l.bulb_id, l.technology, l.phase_deg, l.phase_sigma_deg, "
    "l.confidence, l.bulb_confidence, l.phase_confidence, " SRV_SQL_BULB_LABELS ", ls.lat_deg, ls.lon_deg, "
    "ls.x_px, ls.y_px FROM site_detections sd JOIN lights l ON l.id = sd.light_id "
    "JOIN captures c ON c.id = l.capture_id JOIN surveys s ON s.id = c.survey_id "
    "JOIN light_sites ls ON ls.id = sd.site_id LEFT JOIN delight_versions dv ON dv.id = c.delight_id "
    "WHERE s.name IN (?1, ?2) ORDER BY sd.site_id, l.id";

/* The bulb labels' count M of a side (its detections' candidate bulbs, the largest; see
 * srv_site_combine). */
static double bulb_labels(const srv_site_obs *o, size_t n)
{
    double M = 2.0;
    for (size_t i = 0; i < n; i++) M = fmax(M, (double)o[i].bulbs);
    return M;
}

static void judge(srv_change *c, const srv_site_obs *oa, size_t na, const srv_site_obs *ob, size_t nb,
                  double min_p)
{
    srv_site_combine(oa, na, &c->a);
    srv_site_combine(ob, nb, &c->b);
    c->p_phase_change = c->p_bulb_change = NAN;
    if (!na) {
        c->kinds = SRV_CHANGE_APPEARED;
        return;
    }
    if (!nb) {
        c->kinds = SRV_CHANGE_VANISHED;
        return;
    }
    if (!isnan(c->a.phase_deg) && !isnan(c->b.phase_deg)) {
        /* each side's winner on its own labels (a phase of 18 deg is the class 0 of three, but
         * 30 deg of twelve) */
        int three_a = phases_three(oa, na), three_b = phases_three(ob, nb);
        int same = phase_winner(&c->a, three_a) == phase_winner(&c->b, three_b);
        c->p_phase_change = 1.0 - p_same_phase(&c->a, three_a, &c->b, three_b);
        if (!same && c->p_phase_change >= min_p) c->kinds |= SRV_CHANGE_PHASE;
    }
    if (c->a.bulb_id[0] && c->b.bulb_id[0]) {
        int same = !strcmp(c->a.bulb_id, c->b.bulb_id);
        double M = fmax(bulb_labels(oa, na), bulb_labels(ob, nb));
        c->p_bulb_change = 1.0 - p_same(same, c->a.bulb_confidence, c->b.bulb_confidence, M);
        if (!same && c->p_bulb_change >= min_p) c->kinds |= SRV_CHANGE_BULB;
    }
}

gs_status srv_compare(srv_db *db, const char *survey_a, const char *survey_b, double min_p,
                      srv_change **out, size_t *count, srv_compare_totals *t)
{
    if (!db || !survey_a || !survey_b || !out || !count || !t)
        return gs_fail(GS_EINVAL, "srv_compare: NULL argument");
    *out = NULL;
    *count = 0;
    memset(t, 0, sizeof *t);
    if (!(min_p >= 0.0 && min_p <= 1.0))
        return gs_fail(GS_EINVAL, "--min-p %g: expected a probability in [0, 1]", min_p);
    if (!strcmp(survey_a, survey_b)) return gs_fail(GS_EINVAL, "compare: the two surveys are the same ('%s')", survey_a);
    int64_t id;
    gs_status s;
    if ((s = srv_db_find_survey(db, survey_a, &id)) != GS_OK || (s = srv_db_find_survey(db, survey_b, &id)) != GS_OK)
        return s;
    sqlite3_stmt *q = NULL;
    if ((s = prep(db, compare_sql, &q)) != GS_OK) return s;
    sqlite3_bind_text(q, 1, survey_a, -1, SQLITE_STATIC);
    sqlite3_bind_text(q, 2, survey_b, -1, SQLITE_STATIC);
    srv_site_obs *oa = malloc(SRV_SITE_MAX_OBS * sizeof *oa), *ob = malloc(SRV_SITE_MAX_OBS * sizeof *ob);
    srv_change *v = NULL, cur;
    size_t n = 0, cap = 0, na = 0, nb = 0;
    int rc;
    if (!oa || !ob) s = gs_fail(GS_ENOMEM, "compare: out of memory");
    memset(&cur, 0, sizeof cur);
    while (s == GS_OK) {
        rc = sqlite3_step(q);
        int64_t site = rc == SQLITE_ROW ? sqlite3_column_int64(q, 0) : 0;
        if ((na || nb) && (rc != SQLITE_ROW || site != cur.site_id)) {
            judge(&cur, oa, na, ob, nb, min_p);
            t->sites_a += na > 0;
            t->sites_b += nb > 0;
            t->both += na && nb;
            if (cur.kinds) {
                if ((s = grow(&v, &cap, n + 1, sizeof *v)) != GS_OK) break;
                v[n++] = cur;
            } else if (na && nb) {
                t->unchanged++;
            }
            na = nb = 0;
        }
        if (rc != SQLITE_ROW) {
            if (rc != SQLITE_DONE) s = srv_dbi_fail(db, "comparing surveys");
            break;
        }
        if (!na && !nb) {
            memset(&cur, 0, sizeof cur);
            cur.site_id = site;
            cur.lat_deg = srv_dbi_col_real(q, 10);
            cur.lon_deg = srv_dbi_col_real(q, 11);
            cur.x_px = srv_dbi_col_real(q, 12);
            cur.y_px = srv_dbi_col_real(q, 13);
        }
        int in_b = sqlite3_column_int(q, 1);
        if (in_b && nb < SRV_SITE_MAX_OBS) srv_site_obs_from_row(q, 2, &ob[nb++]);
        else if (!in_b && na < SRV_SITE_MAX_OBS) srv_site_obs_from_row(q, 2, &oa[na++]);
    }
    sqlite3_finalize(q);
    free(oa);
    free(ob);
    if (s != GS_OK) {
        free(v);
        return s;
    }
    *out = v;
    *count = n;
    return GS_OK;
}
