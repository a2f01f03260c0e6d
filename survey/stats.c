/* stats.c - phase-balance statistics of a survey database (docs/survey-db.md, "Statistics").
 *
 * Per group of lights: counts per phase class (0/120/240 within GS_PHASE_TOL_DEG, other,
 * unknown), the shares of the three phases among the lights of a known 0/120/240 phase, their
 * 95 % Wilson score intervals (Wilson 1927), Pearson's chi-square test of the uniform split
 * (1/3 each; 2 degrees of freedom, survival function exp(-x/2)), and an imbalance index
 * I = max_i |s_i - 1/3| / (1/3) (the NEMA MG-1 definition of voltage unbalance, "maximum
 * deviation from the mean divided by the mean", applied to the light counts: identical to
 * max_i |n_i - n/3| / (n/3)).
 *
 * Grouping (srv_group_by): all, technology, survey, a local metric grid of cells, or the lights
 * within a radius. Cells: equirectangular coordinates around the selection's mean latitude
 * lat0 and circular-mean longitude lon0, x = R cos(lat0) (lon - lon0), y = R (lat - lat0) with
 * R = GIS_EARTH_RADIUS_M (angles in radians, lon - lon0 wrapped to [-180, 180)); cell (E, N) =
 * (floor(x / size), floor(y / size)). The east-west scale error is |cos(lat)/cos(lat0) - 1| ~
 * tan(lat0) |lat - lat0| (5e-4 at 5 km from the centre at 33 deg N). Radius: the spherical
 * (haversine) distance on the sphere of radius R, which differs from the WGS84 geodesic by at
 * most 0.56 % (typically 0.2 %): 3 m at 500 m. Acceptable for a selection filter; gis/ has no
 * public geodesic-distance function and this module adds nothing to gis/. The R*Tree selects
 * candidates inside the circle's latitude/longitude box first. */
#include "survey/internal.h"

#include <math.h>
#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define DEG (M_PI / 180.0)

double srv_wilson(long k, long n, double z, double *lo, double *hi)
{
    double l = NAN, h = NAN, p = NAN;
    if (n > 0 && k >= 0 && k <= n && z > 0.0 && isfinite(z)) {
        double nn = (double)n;
        p = (double)k / nn;
        double z2 = z * z, den = 1.0 + z2 / nn;
        double centre = (p + z2 / (2.0 * nn)) / den;
        double half = z / den * sqrt(p * (1.0 - p) / nn + z2 / (4.0 * nn * nn));
        l = centre - half;
        h = centre + half;
        if (k == 0 || l < 0.0) l = 0.0;   /* exact at k = 0; clamp round-off */
        if (k == n || h > 1.0) h = 1.0;
    }
    if (lo) *lo = l;
    if (hi) *hi = h;
    return p;
}

void srv_phase_stats_finish(srv_phase_stats *g)
{
    g->total = g->n[0] + g->n[1] + g->n[2];
    g->flags = 0;
    for (int i = 0; i < 3; i++) g->share[i] = srv_wilson(g->n[i], g->total, SRV_Z95, &g->lo[i], &g->hi[i]);
    if (g->total <= 0) {
        g->chi2 = g->p_value = g->imbalance = NAN;
        g->flags |= SRV_STATS_EMPTY;
        return;
    }
    double e = (double)g->total / 3.0, chi2 = 0.0, dev = 0.0;
    for (int i = 0; i < 3; i++) {
        double d = (double)g->n[i] - e;
        chi2 += d * d / e;
        double ds = fabs(g->share[i] - 1.0 / 3.0);
        if (ds > dev) dev = ds;
    }
    g->chi2 = chi2;
    g->p_value = gs_chi2_sf(chi2, 2);
    g->imbalance = 3.0 * dev;
    if (e < 5.0) g->flags |= SRV_STATS_FEW;
}

void srv_centre_add(srv_centre *c, double lat_deg, double lon_deg)
{
    c->slat += lat_deg;
    c->ssin += sin(lon_deg * DEG);
    c->scos += cos(lon_deg * DEG);
    c->n++;
}

void srv_centre_get(const srv_centre *c, double *lat_deg, double *lon_deg)
{
    *lat_deg = c->n ? c->slat / (double)c->n : NAN;
    *lon_deg = c->n ? atan2(c->ssin, c->scos) / DEG : NAN;
}

void srv_stats_opts_default(srv_stats_opts *o)
{
    memset(o, 0, sizeof *o);
    o->by = SRV_BY_ALL;
    o->cell_m = o->lat_deg = o->lon_deg = o->radius_m = NAN;
    for (int i = 0; i < 4; i++) o->bbox[i] = NAN;
    o->cell_origin_deg[0] = o->cell_origin_deg[1] = NAN;
    o->min_phase_confidence = 0.0;
}

#define BY_EXPECTED "technology, survey, all, cell:SIZE_m, feature:FIELD, radius:LAT,LON,R_m, or up to " \
                    "three of technology, survey, cell:SIZE_m, feature:FIELD joined by commas"

/* One grouping of a --by list. */
static gs_status parse_part(const char *text, const char *part, srv_stats_opts *o, srv_group_by *by)
{
    if (!strcmp(part, "technology")) *by = SRV_BY_TECHNOLOGY;
    else if (!strcmp(part, "survey")) *by = SRV_BY_SURVEY;
    else if (!strcmp(part, "all")) *by = SRV_BY_ALL;
    else if (!strncmp(part, "cell:", 5)) {
        double v = NAN;
        const char *end = gs_number_prefix(part + 5, &v);
        if (!end || (*end && strcmp(end, "m")) || !(v >= 1.0) || v > 1e7)
            return gs_fail(GS_EINVAL, "--by '%s': expected cell:SIZE_m with a cell side of 1 to 1e7 "
                           "metres", text);
        *by = SRV_BY_CELL;
        o->cell_m = v;
    } else if (!strncmp(part, "feature:", 8) && part[8]) {
        *by = SRV_BY_FEATURE;
        snprintf(o->feature_field, sizeof o->feature_field, "%s", part + 8);
    } else {
        return gs_fail(GS_EINVAL, "--by '%s': expected " BY_EXPECTED, text);
    }
    return GS_OK;
}

gs_status srv_stats_parse_by(const char *text, srv_stats_opts *o)
{
    if (!text) return gs_fail(GS_EINVAL, "--by: expected " BY_EXPECTED);
    o->n_then = 0;
    if (!strncmp(text, "radius:", 7)) {
        double v[3];
        const char *p = text + 7;
        for (int i = 0; i < 3; i++) {
            const char *end = gs_number_prefix(p, &v[i]);
            if (!end || (i < 2 && *end != ',') || (i == 2 && *end && strcmp(end, "m")))
                return gs_fail(GS_EINVAL, "--by '%s': expected radius:LAT,LON,R_m (degrees, degrees, "
                               "metres)", text);
            p = end + 1;
        }
        if (fabs(v[0]) > 90.0 || !(v[2] > 0.0) || v[2] > 2.0e7)
            return gs_fail(GS_EINVAL, "--by '%s': expected a latitude in [-90, 90] and a radius in "
                           "(0, 2e7] metres", text);
        o->by = SRV_BY_RADIUS;
        o->lat_deg = v[0];
        o->lon_deg = v[1];
        o->radius_m = v[2];
        return GS_OK;
    }
    char buf[256];
    if (strlen(text) >= sizeof buf) return gs_fail(GS_EINVAL, "--by '%.40s...': too long", text);
    snprintf(buf, sizeof buf, "%s", text);
    srv_group_by parts[SRV_BY_MAX];
    int n = 0;
    for (char *save = NULL, *t = strtok_r(buf, ",", &save); t; t = strtok_r(NULL, ",", &save)) {
        if (n == SRV_BY_MAX) return gs_fail(GS_EINVAL, "--by '%s': expected " BY_EXPECTED, text);
        gs_status st = parse_part(text, t, o, &parts[n]);
        if (st != GS_OK) return st;
        for (int j = 0; j < n; j++)
            if (parts[j] == parts[n])
                return gs_fail(GS_EINVAL, "--by '%s': a grouping given twice", text);
        if (n && (parts[n] == SRV_BY_ALL || parts[0] == SRV_BY_ALL))
            return gs_fail(GS_EINVAL, "--by '%s': 'all' combines with nothing", text);
        n++;
    }
    if (!n) return gs_fail(GS_EINVAL, "--by '%s': expected " BY_EXPECTED, text);
    o->by = parts[0];
    for (int j = 1; j < n; j++) o->then[j - 1] = parts[j];
    o->n_then = n - 1;
    return GS_OK;
}

/* ------------------------------------------------------------------ groups */

typedef struct {
    srv_phase_stats g;
    long ix, iy;                /* cell indices */
} group;

typedef struct {
    group *v;
    size_t n, cap;
    size_t *slot;               /* open addressing: index + 1, 0 = empty */
    size_t slots;
} group_set;

static uint64_t hash_str(const char *s)
{
    uint64_t h = 1469598103934665603ull;   /* FNV-1a */
    for (; *s; s++) h = (h ^ (unsigned char)*s) * 1099511628211ull;
    return h;
}

static gs_status grow_slots(group_set *gs)
{
    size_t ns = gs->slots ? 2 * gs->slots : 64;
    size_t *nslot = calloc(ns, sizeof *nslot);
    if (!nslot) return gs_fail(GS_ENOMEM, "stats: out of memory for %zu groups", gs->n);
    for (size_t i = 0; i < gs->n; i++) {
        size_t h = (size_t)hash_str(gs->v[i].g.group) & (ns - 1);
        while (nslot[h]) h = (h + 1) & (ns - 1);
        nslot[h] = i + 1;
    }
    free(gs->slot);
    gs->slot = nslot;
    gs->slots = ns;
    return GS_OK;
}

/* The group named key (created with zero counts when new). */
static gs_status find_group(group_set *gs, const char *key, group **out)
{
    if (2 * (gs->n + 1) > gs->slots) {
        gs_status s = grow_slots(gs);
        if (s != GS_OK) return s;
    }
    size_t h = (size_t)hash_str(key) & (gs->slots - 1);
    while (gs->slot[h]) {
        group *g = &gs->v[gs->slot[h] - 1];
        if (!strcmp(g->g.group, key)) {
            *out = g;
            return GS_OK;
        }
        h = (h + 1) & (gs->slots - 1);
    }
    if (gs->n == gs->cap) {
        size_t nc = gs->cap ? 2 * gs->cap : 16;
        group *nv = realloc(gs->v, nc * sizeof *nv);
        if (!nv) return gs_fail(GS_ENOMEM, "stats: out of memory for %zu groups", nc);
        gs->v = nv;
        gs->cap = nc;
    }
    group *g = &gs->v[gs->n];
    memset(g, 0, sizeof *g);
    snprintf(g->g.group, sizeof g->g.group, "%s", key);
    g->g.lat_deg = g->g.lon_deg = NAN;
    gs->slot[h] = ++gs->n;
    *out = g;
    return GS_OK;
}

static void add_light(srv_phase_stats *g, double phase_deg, double phase_conf, double min_conf)
{
    g->lights++;
    if (phase_conf < min_conf) {
        g->below++;
        return;
    }
    int c = gs_phase_class(phase_deg);
    if (c < 0) g->unknown++;
    else if (c < 3) g->n[c]++;
    else {
        /* the six-phase candidates: 30, 150, 270 deg (+30 behind delta-wye), within 15 deg */
        int k6 = -1;
        for (int k = 0; k < 3; k++)
            if (fabs(gs_wrap180(phase_deg - 30.0 - 120.0 * k)) <= SRV_PHASE6_TOL_DEG) k6 = k;
        if (k6 >= 0) g->n30[k6]++;
        else g->other++;
    }
}

static int cmp_groups(const void *a, const void *b)
{
    const group *x = a, *y = b;
    return strcmp(x->g.group, y->g.group);
}

static int cmp_cells(const void *a, const void *b)
{
    const group *x = a, *y = b;
    if (x->iy != y->iy) return x->iy < y->iy ? -1 : 1;
    if (x->ix != y->ix) return x->ix < y->ix ? -1 : 1;
    return 0;
}

/* Great-circle distance on the sphere of radius GIS_EARTH_RADIUS_M (haversine). */
static double haversine_m(double lat1, double lon1, double lat2, double lon2)
{
    double dlat = (lat2 - lat1) * DEG, dlon = gs_wrap180(lon2 - lon1) * DEG;
    double a = sin(dlat / 2) * sin(dlat / 2) +
               cos(lat1 * DEG) * cos(lat2 * DEG) * sin(dlon / 2) * sin(dlon / 2);
    if (a > 1.0) a = 1.0;
    return 2.0 * GIS_EARTH_RADIUS_M * asin(sqrt(a));
}

/* A light site that passed the filters: its position, combined phase and the indices of its
 * technology and survey names (interned) and of its area. */
typedef struct {
    double lat, lon, phase, conf;
    int tech, survey, feature;
} site_row;

/* One row per detection, grouped by light site (docs/survey-db.md, "Light sites"): a detection
 * not associated (a database written before migration 3 and not yet migrated by `db migrate`)
 * is a site of its own, and so is every detection with opts.detections. The site's position; its recognition combined in C (srv_site_combine)
 * over the selected detections only (those of --survey, or per survey with --by survey). */
static const char scan_sql[] =
    "SELECT CASE WHEN ?2 THEN -l.id ELSE coalesce(sd.site_id, -l.id) END, s.name, l.bulb_id, "
    "l.technology, l.phase_deg, l.phase_sigma_deg, l.confidence, l.bulb_confidence, "
    "l.phase_confidence, " SRV_SQL_BULB_LABELS ", CASE WHEN ?2 THEN loc.lat_deg ELSE coalesce(ls.lat_deg, "
    "loc.lat_deg) END, CASE WHEN ?2 THEN loc.lon_deg ELSE coalesce(ls.lon_deg, loc.lon_deg) END "
    "FROM lights l JOIN captures c ON c.id = l.capture_id JOIN surveys s ON s.id = c.survey_id "
    "LEFT JOIN delight_versions dv ON dv.id = c.delight_id "
    "LEFT JOIN site_detections sd ON sd.light_id = l.id LEFT JOIN light_sites ls ON ls.id = sd.site_id "
    "LEFT JOIN locations loc ON loc.light_id = l.id WHERE (?1 IS NULL OR s.name = ?1) ";
static const char order_site_sql[] = "ORDER BY 1, l.id";
static const char order_survey_sql[] = "ORDER BY 2, 1, l.id";


/* A stored position (columns col, col + 1) is NULL (not located) or numbers in range: a
 * tampered database with text or out-of-range coordinates is refused rather than fed to floor()
 * and an integer cast. */
static gs_status check_position(sqlite3_stmt *q, int col, const char *path, double lat, double lon)
{
    int tl = sqlite3_column_type(q, col), tn = sqlite3_column_type(q, col + 1);
    if (tl == SQLITE_NULL && tn == SQLITE_NULL) return GS_OK;
    int num = (tl == SQLITE_FLOAT || tl == SQLITE_INTEGER) && (tn == SQLITE_FLOAT || tn == SQLITE_INTEGER);
    if (num && fabs(lat) <= 90.0 && fabs(lon) <= 540.0) return GS_OK;
    const char *lt = (const char *)sqlite3_column_text(q, col), *nt = (const char *)sqlite3_column_text(q, col + 1);
    return gs_fail(GS_EFORMAT, "%s: lat_deg, lon_deg of a light (locations, light_sites) = '%.40s', '%.40s': expected a latitude "
                   "in [-90, 90] and a longitude in [-540, 540] degrees, or NULL", path,
                   lt ? lt : "NULL", nt ? nt : "NULL");
}

/* A site being accumulated from its detections' rows. */
typedef struct {
    int64_t id;
    char survey[64];
    double lat, lon;
    srv_site_obs obs[SRV_SITE_MAX_OBS];
    size_t n;
} site_acc;

/* The index of name in the interning set (added when new). */
static gs_status intern(group_set *names, const char *name, int *index)
{
    group *g;
    gs_status s = find_group(names, name, &g);
    if (s == GS_OK) *index = (int)(g - names->v);
    return s;
}

int srv_bbox_contains(const double b[4], double lat, double lon)
{
    if (!(lat >= b[1] && lat <= b[3])) return 0;
    double x = gs_wrap180(lon), lo = gs_wrap180(b[0]), hi = gs_wrap180(b[2]);
    if (b[2] - b[0] >= 360.0) return 1;
    return lo <= hi ? (x >= lo && x <= hi) : (x >= lo || x <= hi);   /* across the antimeridian */
}

static int uses(const srv_stats_opts *o, srv_group_by by)
{
    if (o->by == by) return 1;
    for (int i = 0; i < o->n_then; i++)
        if (o->then[i] == by) return 1;
    return 0;
}

/* The options' consistency (both backends). */
static gs_status check_opts(const srv_stats_opts *o)
{
    if (!(o->min_phase_confidence >= 0.0 && o->min_phase_confidence <= 1.0))
        return gs_fail(GS_EINVAL, "--min-phase-confidence %g: expected a probability in [0, 1]", o->min_phase_confidence);
    if (uses(o, SRV_BY_CELL) && !(o->cell_m >= 1.0 && isfinite(o->cell_m)))
        return gs_fail(GS_EINVAL, "cell size %g m: expected >= 1 m", o->cell_m);
    if (o->by == SRV_BY_RADIUS && !(o->radius_m > 0.0 && isfinite(o->radius_m) &&
                                    fabs(o->lat_deg) <= 90.0 && isfinite(o->lon_deg)))
        return gs_fail(GS_EINVAL, "radius (%g, %g, %g m): expected a latitude in [-90, 90], a "
                       "finite longitude and a radius > 0", o->lat_deg, o->lon_deg, o->radius_m);
    if (uses(o, SRV_BY_FEATURE) && !o->areas)
        return gs_fail(GS_EINVAL, "--by feature:%s: needs the areas (--clip AREAS.geojson)", o->feature_field);
    if (!isnan(o->bbox[0]) && !(fabs(o->bbox[1]) <= 90.0 && fabs(o->bbox[3]) <= 90.0 && o->bbox[1] <= o->bbox[3] &&
                                isfinite(o->bbox[0]) && isfinite(o->bbox[2])))
        return gs_fail(GS_EINVAL, "--bbox %g,%g,%g,%g: expected MINLON,MINLAT,MAXLON,MAXLAT with "
                       "MINLAT <= MAXLAT in [-90, 90]", o->bbox[0], o->bbox[1], o->bbox[2], o->bbox[3]);
    return GS_OK;
}

int srv_stats_by_survey(const srv_stats_opts *o)
{
    return uses(o, SRV_BY_SURVEY);
}

/* The SQLite row source of srv_stats_run. */
typedef struct {
    sqlite3_stmt *q;
    const char *path;
} lite_rows;

static gs_status lite_next(void *ctx, srv_stats_row *row, int *got)
{
    lite_rows *x = ctx;
    int rc = sqlite3_step(x->q);
    *got = rc == SQLITE_ROW;
    if (!*got)
        return rc == SQLITE_DONE ? GS_OK
                                 : gs_fail(GS_ESQL, "%s: statistics query: %s", x->path,
                                           sqlite3_errmsg(sqlite3_db_handle(x->q)));
    row->id = sqlite3_column_int64(x->q, 0);
    row->survey = (const char *)sqlite3_column_text(x->q, 1);
    row->lat = srv_dbi_col_real(x->q, 10);
    row->lon = srv_dbi_col_real(x->q, 11);
    srv_site_obs_from_row(x->q, 2, &row->obs);
    return check_position(x->q, 10, x->path, row->lat, row->lon);
}

gs_status srv_stats_compute(srv_db *db, const srv_stats_opts *o, srv_phase_stats **groups,
                            size_t *count, long *ungrouped)
{
    if (!db || !o || !groups || !count) return gs_fail(GS_EINVAL, "srv_stats_compute: NULL argument");
    *groups = NULL;
    *count = 0;
    if (ungrouped) *ungrouped = 0;
    gs_status s;
    sqlite3 *h = srv_db_sqlite(db);
    lite_rows x = {NULL, srv_db_path(db)};
    char sql[sizeof scan_sql + 32];
    snprintf(sql, sizeof sql, "%s%s", scan_sql, uses(o, SRV_BY_SURVEY) ? order_survey_sql : order_site_sql);
    if (sqlite3_prepare_v2(h, sql, -1, &x.q, NULL) != SQLITE_OK)
        return gs_fail(GS_ESQL, "%s: statistics query: %s", x.path, sqlite3_errmsg(h));
    if (o->survey) sqlite3_bind_text(x.q, 1, o->survey, -1, SQLITE_STATIC);
    sqlite3_bind_int(x.q, 2, o->detections != 0);
    s = srv_stats_run(o, lite_next, &x, groups, count, ungrouped);
    sqlite3_finalize(x.q);
    return s;
}

gs_status srv_stats_run(const srv_stats_opts *o, srv_stats_next next, void *ctx,
                        srv_phase_stats **groups, size_t *count, long *ungrouped)
{
    *groups = NULL;
    *count = 0;
    if (ungrouped) *ungrouped = 0;
    gs_status s = check_opts(o);
    if (s != GS_OK) return s;
    int has_bbox = !isnan(o->bbox[0]);
    /* the groupings that need a position */
    int spatial = uses(o, SRV_BY_CELL) || uses(o, SRV_BY_FEATURE) || o->by == SRV_BY_RADIUS ||
                  has_bbox || o->areas;
    group_set gs = {0}, names = {0};
    site_row *rows = NULL;
    size_t nrows = 0, caprows = 0;
    long no_position = 0;
    site_acc *acc = calloc(1, sizeof *acc);
    if (!acc) {
        s = gs_fail(GS_ENOMEM, "stats: out of memory");
        goto done;
    }
    if (o->by == SRV_BY_ALL || o->by == SRV_BY_RADIUS) {
        group *g;   /* the one group exists even when empty */
        if ((s = find_group(&gs, o->by == SRV_BY_ALL ? "all" : "radius", &g)) != GS_OK) goto done;
        if (o->by == SRV_BY_RADIUS) {
            g->g.lat_deg = o->lat_deg;
            g->g.lon_deg = gs_wrap180(o->lon_deg);
        }
    }
    /* pass 1: the sites, combined and filtered */
    for (;;) {
        srv_stats_row row;
        int got;
        if ((s = next(ctx, &row, &got)) != GS_OK) goto done;
        int64_t id = got ? row.id : 0;
        const char *sv = got ? row.survey : NULL;
        if (acc->n && (!got || id != acc->id ||
                       (uses(o, SRV_BY_SURVEY) && strcmp(sv ? sv : "", acc->survey)))) {
            srv_site_value v;
            srv_site_combine(acc->obs, acc->n, &v);
            site_row r = {acc->lat, acc->lon, v.phase_deg, v.phase_confidence, 0, 0, -1};
            acc->n = 0;
            int keep = 1;
            if (spatial && isnan(r.lat)) {
                no_position++;
                keep = 0;
            }
            if (keep && o->by == SRV_BY_RADIUS)
                keep = haversine_m(o->lat_deg, o->lon_deg, r.lat, r.lon) <= o->radius_m;
            if (keep && has_bbox) keep = srv_bbox_contains(o->bbox, r.lat, r.lon);
            if (keep && o->areas) keep = (r.feature = srv_areas_find(o->areas, r.lat, r.lon)) >= 0;
            if (keep) {
                if ((s = intern(&names, *v.technology ? v.technology : "none", &r.tech)) != GS_OK ||
                    (s = intern(&names, acc->survey, &r.survey)) != GS_OK)
                    goto done;
                if (nrows == caprows) {
                    size_t nc = caprows ? 2 * caprows : 4096;
                    site_row *nr = realloc(rows, nc * sizeof *nr);
                    if (!nr) {
                        s = gs_fail(GS_ENOMEM, "stats: out of memory for %zu lights", nc);
                        goto done;
                    }
                    rows = nr;
                    caprows = nc;
                }
                rows[nrows++] = r;
            }
        }
        if (!got) break;
        if (!acc->n) {
            acc->id = id;
            snprintf(acc->survey, sizeof acc->survey, "%s", sv ? sv : "");
            acc->lat = row.lat;
            acc->lon = row.lon;
        }
        if (acc->n < SRV_SITE_MAX_OBS) acc->obs[acc->n++] = row.obs;
    }
    /* pass 2: the groups (cells need the selection's centre first) */
    double lat0 = 0.0, lon0 = 0.0, kx = 0.0, ky = GIS_EARTH_RADIUS_M * DEG;
    if (uses(o, SRV_BY_CELL) && nrows) {
        if (isfinite(o->cell_origin_deg[0]) && isfinite(o->cell_origin_deg[1])) {
            lat0 = o->cell_origin_deg[0];
            lon0 = o->cell_origin_deg[1];
        } else {
            srv_centre c = {0};
            for (size_t i = 0; i < nrows; i++) srv_centre_add(&c, rows[i].lat, rows[i].lon);
            srv_centre_get(&c, &lat0, &lon0);
        }
        kx = GIS_EARTH_RADIUS_M * cos(lat0 * DEG) * DEG;
    }
    for (size_t i = 0; i < nrows; i++) {
        const site_row *r = &rows[i];
        char key[3 * 96 + 8] = "";   /* fits srv_phase_stats.group */
        long ix = 0, iy = 0;
        int nparts = 1 + o->n_then;
        for (int k = 0; k < nparts; k++) {
            srv_group_by by = k ? o->then[k - 1] : o->by;
            char part[96];
            switch (by) {
            case SRV_BY_ALL: snprintf(part, sizeof part, "all"); break;
            case SRV_BY_RADIUS: snprintf(part, sizeof part, "radius"); break;
            case SRV_BY_TECHNOLOGY: snprintf(part, sizeof part, "%.95s", names.v[r->tech].g.group); break;
            case SRV_BY_SURVEY: snprintf(part, sizeof part, "%.95s", names.v[r->survey].g.group); break;
            case SRV_BY_FEATURE:
                snprintf(part, sizeof part, "%.95s", srv_areas_label(o->areas, (size_t)r->feature));
                break;
            case SRV_BY_CELL:
                ix = (long)floor(kx * gs_wrap180(r->lon - lon0) / o->cell_m);
                iy = (long)floor(ky * (r->lat - lat0) / o->cell_m);
                snprintf(part, sizeof part, "%ld,%ld", ix, iy);
                break;
            }
            size_t used = strlen(key);
            snprintf(key + used, sizeof key - used, "%s%s", k ? " / " : "", part);
        }
        group *g;
        if ((s = find_group(&gs, key, &g)) != GS_OK) goto done;
        if (!g->g.lights && uses(o, SRV_BY_CELL)) {
            g->ix = ix;
            g->iy = iy;
            g->g.lat_deg = lat0 + ((double)iy + 0.5) * o->cell_m / ky;
            g->g.lon_deg = kx > 0.0 ? gs_wrap180(lon0 + ((double)ix + 0.5) * o->cell_m / kx) : lon0;
        }
        add_light(&g->g, r->phase, r->conf, o->min_phase_confidence);
    }
    if (gs.n) qsort(gs.v, gs.n, sizeof *gs.v, o->by == SRV_BY_CELL && !o->n_then ? cmp_cells : cmp_groups);
    if (gs.n) {
        *groups = malloc(gs.n * sizeof **groups);
        if (!*groups) {
            s = gs_fail(GS_ENOMEM, "stats: out of memory for %zu groups", gs.n);
            goto done;
        }
        for (size_t i = 0; i < gs.n; i++) {
            (*groups)[i] = gs.v[i].g;
            srv_phase_stats_finish(&(*groups)[i]);
        }
        *count = gs.n;
    }
    if (ungrouped) *ungrouped = no_position;
done:
    free(gs.v);
    free(gs.slot);
    free(names.v);
    free(names.slot);
    free(rows);
    free(acc);
    return s;
}
