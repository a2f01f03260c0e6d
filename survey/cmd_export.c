/* cmd_export.c - `gridsurvey export`: lights of a survey database as GeoJSON, KML, GeoPackage
 * or CSV. Rows become gis_light values and gis/'s writers do the rest (gis_export: atomic
 * replacement, every format's conventions in docs/gis.md). The bounding-box filter uses the
 * R*Tree (locations_rtree) and then the exact stored coordinates. */
#include "survey/internal.h"

#include <getopt.h>
#include <math.h>
#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char export_usage[] =
    "usage: gridsurvey export --db DB -o FILE [--format geojson|kml|gpkg|csv] [--survey NAME]\n"
    "                         [--technology TECH] [--phase 0|120|240|other|unknown]\n"
    "                         [--bbox MINLON,MINLAT,MAXLON,MAXLAT] [--min-confidence X]\n"
    "                         [--precision D]\n"
    "\n"
    "Writes the lights of a survey database, one feature per detection, with their bulb,\n"
    "technology, phase, confidence, position, error ellipse and light site (the physical light\n"
    "that stats counts once: its detections share it; docs/gis.md has each format). Lights\n"
    "without a position are written without a geometry unless --bbox is given.\n"
    "\n"
    "  --db DB             the survey database (read-only)\n"
    "  -o FILE             output file (replaced atomically)\n"
    "  --format F          geojson, kml, gpkg or csv (default: from the -o extension; it\n"
    "                      must not be another format's extension)\n"
    "  --survey NAME       only this survey\n"
    "  --technology TECH   only this technology (sodium_hp, led_linear, ...; none = no bulb)\n"
    "  --phase P           only lights on phase 0, 120 or 240 (within 20 deg), another phase\n"
    "                      (other), or an ambiguous/unknown one (unknown)\n"
    "  --bbox A,B,C,D      only located lights with MINLON <= lon <= MAXLON and MINLAT <= lat\n"
    "                      <= MAXLAT, degrees (MINLON > MAXLON crosses the antimeridian)\n"
    "  --min-confidence X  only lights whose confidence (posterior of bulb and phase) is >= X\n"
    "  --precision D       GeoJSON: longitudes and latitudes to D decimals, 0 to 12 (default 7,\n"
    "                      1.1 cm; heights to the millimetre)\n"
    "  --help              this text\n"
    "\n"
    "Examples:\n"
    "  gridsurvey export --db city.sqlite -o lights.geojson\n"
    "  gridsurvey export --db city.sqlite -o phase120.gpkg --phase 120 --min-confidence 0.9 \\\n"
    "                    --bbox 34.98,32.78,35.05,32.82\n";

void srv_export_opts_default(srv_export_opts *o)
{
    memset(o, 0, sizeof *o);
    o->phase = -2;
    o->min_confidence = 0.0;
}

static const char select_sql[] =
    "SELECT l.id, s.name, c.utc, l.bulb_id, l.technology, l.phase_deg, l.confidence, loc.lat_deg, "
    "loc.lon_deg, loc.height_m, loc.semi_major_m, loc.semi_minor_m, loc.azimuth_deg, loc.flags, "
    "(SELECT sd.site_id FROM site_detections sd WHERE sd.light_id = l.id) ";
static const char plain_from[] =
    "FROM lights l JOIN captures c ON c.id = l.capture_id JOIN surveys s ON s.id = c.survey_id "
    "LEFT JOIN locations loc ON loc.light_id = l.id WHERE 1 ";
/* The R*Tree first (CROSS JOIN fixes the order); bounds ?4..?7 = min_lon, max_lon, min_lat,
 * max_lat as an overlap test (the R*Tree's 32-bit boxes are rounded outward). */
static const char rtree_from[] =
    "FROM locations_rtree r CROSS JOIN locations loc ON loc.light_id = r.id "
    "CROSS JOIN lights l ON l.id = r.id CROSS JOIN captures c ON c.id = l.capture_id "
    "CROSS JOIN surveys s ON s.id = c.survey_id "
    "WHERE r.max_lon >= ?4 AND r.min_lon <= ?5 AND r.max_lat >= ?6 AND r.min_lat <= ?7 ";
static const char filters[] =
    "AND (?1 IS NULL OR s.name = ?1) AND (?2 IS NULL OR coalesce(l.technology, 'none') = ?2) "
    "AND l.confidence >= ?3 ORDER BY l.id";


static void col_text(sqlite3_stmt *q, int i, char *dst, size_t size)
{
    const char *t = (const char *)sqlite3_column_text(q, i);
    snprintf(dst, size, "%s", t ? t : "");
}

gs_status srv_db_read_lights(srv_db *db, const srv_export_opts *o, gis_light **lights,
                             size_t *count)
{
    if (!db || !o || !lights || !count) return gs_fail(GS_EINVAL, "srv_db_read_lights: NULL argument");
    *lights = NULL;
    *count = 0;
    if (o->phase < -2 || o->phase > 3)
        return gs_fail(GS_EINVAL, "export: phase filter %d: expected -2 (all), -1 (unknown), 0..2 "
                       "(0/120/240) or 3 (other)", o->phase);
    if (!(o->min_confidence >= 0.0 && o->min_confidence <= 1.0))
        return gs_fail(GS_EINVAL, "--min-confidence %g: expected [0, 1]", o->min_confidence);
    if (o->use_bbox) {
        for (int i = 0; i < 4; i++)
            if (!isfinite(o->bbox[i]))
                return gs_fail(GS_EINVAL, "--bbox: expected 4 finite numbers");
        if (o->bbox[1] > o->bbox[3] || fabs(o->bbox[1]) > 90.0 || fabs(o->bbox[3]) > 90.0 ||
            fabs(o->bbox[0]) > 180.0 || fabs(o->bbox[2]) > 180.0)
            return gs_fail(GS_EINVAL, "--bbox %g,%g,%g,%g: expected MINLON,MINLAT,MAXLON,MAXLAT "
                           "with longitudes in [-180, 180] and -90 <= MINLAT <= MAXLAT <= 90",
                           o->bbox[0], o->bbox[1], o->bbox[2], o->bbox[3]);
    }
    sqlite3 *h = srv_db_sqlite(db);
    char sql[2048];
    snprintf(sql, sizeof sql, "%s%s%s", select_sql, o->use_bbox ? rtree_from : plain_from, filters);
    sqlite3_stmt *q = NULL;
    if (sqlite3_prepare_v2(h, sql, -1, &q, NULL) != SQLITE_OK)
        return gs_fail(GS_ESQL, "%s: export query: %s", srv_db_path(db), sqlite3_errmsg(h));
    if (o->survey) sqlite3_bind_text(q, 1, o->survey, -1, SQLITE_STATIC);
    if (o->technology) sqlite3_bind_text(q, 2, o->technology, -1, SQLITE_STATIC);
    sqlite3_bind_double(q, 3, o->min_confidence);
    if (o->use_bbox) {
        /* the R*Tree over every longitude when the box crosses or reaches 180 deg (stored -180) */
        int wraps = o->bbox[0] > o->bbox[2] || o->bbox[2] >= 180.0;
        sqlite3_bind_double(q, 4, wraps ? -180.0 : o->bbox[0]);
        sqlite3_bind_double(q, 5, wraps ? 180.0 : o->bbox[2]);
        sqlite3_bind_double(q, 6, o->bbox[1]);
        sqlite3_bind_double(q, 7, o->bbox[3]);
    }
    gis_light *v = NULL;
    size_t n = 0, cap = 0;
    gs_status s = GS_OK;
    int rc;
    while ((rc = sqlite3_step(q)) == SQLITE_ROW) {
        double phase = srv_dbi_col_real(q, 5), lat = srv_dbi_col_real(q, 7), lon = srv_dbi_col_real(q, 8);
        if (o->phase != -2 && gs_phase_class(phase) != o->phase) continue;
        if (o->use_bbox && !srv_bbox_contains(o->bbox, lat, lon)) continue;
        if (n == cap) {
            size_t nc = cap ? 2 * cap : 256;
            gis_light *nv = realloc(v, nc * sizeof *nv);
            if (!nv) {
                s = gs_fail(GS_ENOMEM, "export: out of memory for %zu lights", nc);
                break;
            }
            v = nv;
            cap = nc;
        }
        gis_light *l = &v[n++];
        gis_light_init(l);
        snprintf(l->id, sizeof l->id, "%lld", (long long)sqlite3_column_int64(q, 0));
        col_text(q, 1, l->survey, sizeof l->survey);
        col_text(q, 2, l->time_utc, sizeof l->time_utc);
        col_text(q, 3, l->bulb_id, sizeof l->bulb_id);
        col_text(q, 4, l->technology, sizeof l->technology);
        l->phase_deg = phase;
        l->confidence = srv_dbi_col_real(q, 6);
        l->lat_deg = lat;
        l->lon_deg = lon;
        l->height_m = srv_dbi_col_real(q, 9);
        l->ellipse.semi_major_m = srv_dbi_col_real(q, 10);
        l->ellipse.semi_minor_m = srv_dbi_col_real(q, 11);
        l->ellipse.azimuth_deg = srv_dbi_col_real(q, 12);
        l->flags = (unsigned)sqlite3_column_int64(q, 13);
        if (sqlite3_column_type(q, 14) != SQLITE_NULL)
            snprintf(l->site, sizeof l->site, "%lld", (long long)sqlite3_column_int64(q, 14));
    }
    if (s == GS_OK && rc != SQLITE_DONE)
        s = gs_fail(GS_ESQL, "%s: export query: %s", srv_db_path(db), sqlite3_errmsg(h));
    sqlite3_finalize(q);
    if (s != GS_OK) {
        free(v);
        return s;
    }
    *lights = v;
    *count = n;
    return GS_OK;
}

gs_status srv_db_read_stations(srv_db *db, const char *survey, gis_camera **cams, size_t *count)
{
    static const char sql[] =
        "SELECT " SRV_SQL_CAMERA_COLS("st") ", st.width_px, st.height_px "
        "FROM stations st JOIN surveys s ON s.id = st.survey_id WHERE ?1 IS NULL OR s.name = ?1 ORDER BY st.id";
    *cams = NULL;
    *count = 0;
    sqlite3 *h = srv_db_sqlite(db);
    sqlite3_stmt *q = NULL;
    if (sqlite3_prepare_v2(h, sql, -1, &q, NULL) != SQLITE_OK)
        return gs_fail(GS_ESQL, "%s: stations query: %s", srv_db_path(db), sqlite3_errmsg(h));
    if (survey) sqlite3_bind_text(q, 1, survey, -1, SQLITE_STATIC);
    gis_camera *v = NULL;
    size_t n = 0;
    gs_status s = GS_OK;
    int rc;
    while ((rc = sqlite3_step(q)) == SQLITE_ROW) {
        gis_camera *nv = realloc(v, (n + 1) * sizeof *nv);
        if (!nv) {
            s = gs_fail(GS_ENOMEM, "%s: out of memory for %zu stations", srv_db_path(db), n + 1);
            break;
        }
        v = nv;
        gis_camera *c = &v[n];
        srv_dbi_col_camera(q, 0, c);
        c->width_px = sqlite3_column_int(q, 12);
        c->height_px = sqlite3_column_int(q, 13);
        /* a station stored without a full pose (no camera) is not drawn */
        n += isfinite(c->lat_deg) && isfinite(c->lon_deg) && gis_camera_check(c) == GS_OK;
    }
    if (s == GS_OK && rc != SQLITE_DONE) s = gs_fail(GS_ESQL, "%s: stations query: %s", srv_db_path(db), sqlite3_errmsg(h));
    sqlite3_finalize(q);
    if (s != GS_OK) {
        free(v);
        return s;
    }
    *cams = v;
    *count = n;
    return GS_OK;
}

static int parse_bbox(const char *text, double b[4])
{
    const char *p = text;
    for (int i = 0; i < 4; i++) {
        const char *end = gs_number_prefix(p, &b[i]);
        if (!end || (i < 3 && *end != ',') || (i == 3 && *end)) return 0;
        p = end + 1;
    }
    return 1;
}

int srv_cmd_export(int argc, char **argv)
{
    static const struct option longs[] = {
        {"db", required_argument, 0, 'd'},
        {"format", required_argument, 0, 'f'},     {"survey", required_argument, 0, 'S'},
        {"technology", required_argument, 0, 't'}, {"phase", required_argument, 0, 'p'},
        {"bbox", required_argument, 0, 'b'},       {"min-confidence", required_argument, 0, 'c'},
        {"precision", required_argument, 0, 'P'},  {"help", no_argument, 0, 'h'},
        {0, 0, 0, 0},
    };
    const char *path = NULL, *out = NULL, *format = NULL;
    int decimals = GIS_GEOJSON_DECIMALS;
    srv_export_opts o;
    srv_export_opts_default(&o);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "o:h", longs, NULL)) != -1) {
        switch (c) {
        case 'd': path = optarg; break;
        case 'o': out = optarg; break;
        case 'f': format = optarg; break;
        case 'P': {
            unsigned long long v;
            if (!srv_int_arg("export", "--precision", optarg, 0, GIS_GEOJSON_DECIMALS_MAX, &v)) return 2;
            decimals = (int)v;
            break;
        }
        case 'S': o.survey = optarg; break;
        case 't':
            if (strcmp(optarg, "none")) {
                gs_tech t;
                if (gs_tech_parse(optarg, &t) != GS_OK)
                    return srv_usage_error("export", "--technology '%s': expected a technology name "
                                           "(sodium_hp, led_linear, cfl, ...) or none", optarg);
            }
            o.technology = optarg;
            break;
        case 'p':
            if (!strcmp(optarg, "0")) o.phase = 0;
            else if (!strcmp(optarg, "120")) o.phase = 1;
            else if (!strcmp(optarg, "240")) o.phase = 2;
            else if (!strcmp(optarg, "other")) o.phase = 3;
            else if (!strcmp(optarg, "unknown")) o.phase = -1;
            else return srv_usage_error("export", "--phase '%s': expected 0, 120, 240, other or unknown", optarg);
            break;
        case 'b':
            if (!parse_bbox(optarg, o.bbox) || o.bbox[1] > o.bbox[3] || fabs(o.bbox[1]) > 90.0 ||
                fabs(o.bbox[3]) > 90.0 || fabs(o.bbox[0]) > 180.0 || fabs(o.bbox[2]) > 180.0)
                return srv_usage_error("export", "--bbox '%s': expected MINLON,MINLAT,MAXLON,MAXLAT in "
                                       "degrees with MINLAT <= MAXLAT", optarg);
            o.use_bbox = 1;
            break;
        case 'c':
            if (!srv_num_arg("export", "--min-confidence", optarg, 0.0, 1.0, &o.min_confidence)) return 2;
            break;
        case 'h': fputs(export_usage, stdout); return 0;
        default: return srv_usage_hint("export", argv);
        }
    }
    if (optind < argc) return srv_usage_error("export", "unexpected argument '%s'", argv[optind]);
    if (!path || !out) return srv_usage_error("export", "--db and -o are required");
    gis_format fmt;
    gs_status s = gis_format_choose(format, out, &fmt);
    if (s != GS_OK) return srv_usage_error("export", "%s", gs_detail());
    srv_db *db;
    if ((s = srv_db_open(path, SRV_DB_READ, &db)) != GS_OK) return srv_error("export", s);
    if (o.survey) {
        int64_t id;
        if ((s = srv_db_find_survey(db, o.survey, &id)) != GS_OK) {
            srv_db_close(db);
            return srv_error("export", s);
        }
    }
    gis_light *lights = NULL;
    size_t n = 0;
    s = srv_db_read_lights(db, &o, &lights, &n);
    srv_db_close(db);
    if (s == GS_OK)
        s = fmt == GIS_FORMAT_GEOJSON ? gis_export_geojson_decimals(lights, n, out, decimals)
                                      : gis_export(lights, n, fmt, out);
    free(lights);
    if (s != GS_OK) return srv_error("export", s);
    fprintf(srv_note_stream(out), "exported %zu light%s -> %s\n", n, n == 1 ? "" : "s", out);
    return 0;
}
