/* export.c - exports of located lights (gis.h): GeoJSON (RFC 7946), KML 2.2, GeoPackage 1.3
 * (OGC 12-128r18) and CSV (RFC 4180), each written atomically (gs_atomic). */
#include "gis/internal.h"

#include <ctype.h>
#include <errno.h>
#include <jansson.h>
#include <math.h>
#include <sqlite3.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <time.h>
#include <unistd.h>

/* ---------------------------------------------------------------- lights */

void gis_light_init(gis_light *l)
{
    memset(l, 0, sizeof *l);
    l->lat_deg = l->lon_deg = l->height_m = NAN;
    l->ellipse = gis_ellipse_nan();
    l->phase_deg = l->confidence = NAN;
}

void gis_light_set_fix(gis_light *l, const gis_fix *f)
{
    l->lat_deg = f->lat_deg;
    l->lon_deg = f->lon_deg;
    l->height_m = f->height_m;
    l->ellipse = f->ellipse;
    l->flags = f->flags;
}

gis_phase_class gis_phase_classify(double phase_deg)
{
    int c = gs_phase_class(phase_deg);
    return c < 0 ? GIS_PHASE_UNKNOWN : (gis_phase_class)c;
}

void gis_phase_rgb(gis_phase_class c, unsigned char rgb[3])
{
    static const unsigned char col[5][3] = {
        {213, 94, 0}, {0, 158, 115}, {0, 114, 178}, {204, 121, 167}, {128, 128, 128},
    };
    int i = (int)c < 0 || (int)c > 4 ? 4 : (int)c;
    memcpy(rgb, col[i], 3);
}

gs_status gis_format_parse(const char *name, gis_format *f)
{
    static const struct {
        const char *name;
        gis_format f;
    } names[] = {{"geojson", GIS_FORMAT_GEOJSON}, {"kml", GIS_FORMAT_KML},
                 {"gpkg", GIS_FORMAT_GPKG}, {"csv", GIS_FORMAT_CSV}};
    for (size_t i = 0; name && i < sizeof names / sizeof *names; i++)
        if (!strcasecmp(name, names[i].name)) {
            *f = names[i].f;
            return GS_OK;
        }
    return gs_fail(GS_EINVAL, "format '%s': expected geojson, kml, gpkg or csv", name ? name : "");
}

gs_status gis_format_from_path(const char *path, gis_format *f)
{
    const char *dot = path ? strrchr(path, '.') : NULL;
    if (dot && !strcasecmp(dot, ".json")) {
        *f = GIS_FORMAT_GEOJSON;
        return GS_OK;
    }
    if (dot && gis_format_parse(dot + 1, f) == GS_OK) return GS_OK;
    return gs_fail(GS_EINVAL, "%s: cannot tell the format from the extension: expected .geojson, "
                   ".json, .kml, .gpkg or .csv (or give the format)", path ? path : "");
}

gs_status gis_format_choose(const char *name, const char *path, gis_format *f)
{
    if (!name) return gis_format_from_path(path, f);
    gis_format by_path;
    gs_status s = gis_format_parse(name, f);
    if (s == GS_OK && gis_format_from_path(path, &by_path) == GS_OK && by_path != *f)
        s = gs_fail(GS_EINVAL, "--format %s but %s's extension is another format's: name the file for "
                    "the format, or leave --format out", name, path);
    return s;
}

static int located(const gis_light *l)
{
    return isfinite(l->lat_deg) && isfinite(l->lon_deg);
}

static gs_status check_lights(const gis_light *lights, size_t n)
{
    if (n && !lights) return gs_fail(GS_EINVAL, "export: NULL lights");
    for (size_t i = 0; i < n; i++) {
        const gis_light *l = &lights[i];
        const struct {
            const char *s;
            size_t size;
            const char *name;
        } str[] = {{l->id, sizeof l->id, "id"},
                   {l->bulb_id, sizeof l->bulb_id, "bulb"},
                   {l->technology, sizeof l->technology, "technology"},
                   {l->survey, sizeof l->survey, "survey"},
                   {l->time_utc, sizeof l->time_utc, "time"},
                   {l->site, sizeof l->site, "site"}};
        for (size_t k = 0; k < sizeof str / sizeof *str; k++)
            if (!memchr(str[k].s, '\0', str[k].size) || !gs_text_clean(str[k].s))
                return gs_fail(GS_EINVAL, "export: light %zu: %s: expected NUL-terminated UTF-8 "
                               "text without control characters", i, str[k].name);
        if (isnan(l->lat_deg) != isnan(l->lon_deg))
            return gs_fail(GS_EINVAL, "export: light %zu (%s): latitude %g, longitude %g: both or "
                           "neither must be NaN", i, l->id, l->lat_deg, l->lon_deg);
        if (isinf(l->lat_deg) || isinf(l->lon_deg) || fabs(l->lat_deg) > 90.0 || isinf(l->height_m))
            return gs_fail(GS_ENUMERIC, "export: light %zu (%s): position (%g, %g, %g): expected "
                           "latitude in [-90, 90], finite values or NaN", i, l->id, l->lat_deg,
                           l->lon_deg, l->height_m);
        if (isinf(l->phase_deg) || !(isnan(l->confidence) || (l->confidence >= 0.0 && l->confidence <= 1.0)))
            return gs_fail(GS_EINVAL, "export: light %zu (%s): phase %g, confidence %g: expected a "
                           "finite phase or NaN, confidence in [0, 1] or NaN", i, l->id,
                           l->phase_deg, l->confidence);
    }
    return GS_OK;
}

/* Attributes shared by every format, in this order. */
typedef enum { A_TEXT, A_REAL } akind;
typedef struct {
    const char *name;
    akind kind;
    const char *kml_type;
} attr;
static const attr attrs[] = {
    {"id", A_TEXT, "string"},          {"bulb", A_TEXT, "string"},
    {"technology", A_TEXT, "string"},  {"phase", A_REAL, "double"},
    {"confidence", A_REAL, "double"},  {"survey", A_TEXT, "string"},
    {"time", A_TEXT, "string"},        {"height_m", A_REAL, "double"},
    {"err_major_m", A_REAL, "double"}, {"err_minor_m", A_REAL, "double"},
    {"err_azimuth_deg", A_REAL, "double"}, {"flags", A_TEXT, "string"},
    {"site", A_TEXT, "string"},
};
#define N_ATTRS (sizeof attrs / sizeof *attrs)

/* Attribute k of light l: a string (NULL when empty/unknown) or a number (NaN when unknown). */
static const char *attr_text(const gis_light *l, size_t k, char *buf, size_t size)
{
    const char *s = NULL;
    switch (k) {
    case 0: s = l->id; break;
    case 1: s = l->bulb_id; break;
    case 2: s = l->technology; break;
    case 5: s = l->survey; break;
    case 6: s = l->time_utc; break;
    case 11: s = gis_flags_str(l->flags, buf, size); break;
    case 12: s = l->site; break;
    default: break;
    }
    return s && *s ? s : NULL;
}

static double attr_real(const gis_light *l, size_t k)
{
    double v = NAN;
    switch (k) {
    case 3: v = isfinite(l->phase_deg) ? gs_wrap360(l->phase_deg) : NAN; break;
    case 4: v = l->confidence; break;
    case 7: v = l->height_m; break;
    case 8: v = l->ellipse.semi_major_m; break;
    case 9: v = l->ellipse.semi_minor_m; break;
    case 10: v = l->ellipse.azimuth_deg; break;
    default: break;
    }
    return isfinite(v) ? v : NAN;   /* an unbounded ellipse is "unknown" in files */
}

/* ---------------------------------------------------------------- GeoJSON */

/* v rounded to `decimals` decimal places (printed with 15 significant digits, it then shows
 * no more than those: 7 decimals of a longitude need at most 10 digits). */
static double round_to(double v, int decimals)
{
    double k = pow(10.0, decimals);
    return round(v * k) / k;
}

gs_status gis_export_geojson(const gis_light *lights, size_t n, const char *path)
{
    return gis_export_geojson_decimals(lights, n, path, GIS_GEOJSON_DECIMALS);
}

/* json_dump_callback's output, growing; failed once an append could not be made. */
typedef struct {
    char *p;
    size_t n, cap;
    int failed;
} dump_buf;

static int dump_append(const char *bytes, size_t size, void *data)
{
    dump_buf *d = data;
    if (d->failed) return -1;
    if (d->n + size + 1 > d->cap) {
        size_t cap = d->cap ? d->cap : 4096;
        while (cap < d->n + size + 1) cap *= 2;
        char *q = realloc(d->p, cap);
        if (!q) {
            d->failed = 1;
            return -1;
        }
        d->p = q;
        d->cap = cap;
    }
    memcpy(d->p + d->n, bytes, size);
    d->n += size;
    d->p[d->n] = '\0';
    return 0;
}

gs_status gis_export_geojson_decimals(const gis_light *lights, size_t n, const char *path, int decimals)
{
    if (decimals < 0 || decimals > GIS_GEOJSON_DECIMALS_MAX)
        return gs_fail(GS_EINVAL, "%s: %d coordinate decimals: expected 0 to %d", path, decimals,
                       GIS_GEOJSON_DECIMALS_MAX);
    gs_status s = check_lights(lights, n);
    if (s != GS_OK) return s;
    json_t *root = json_object(), *features = json_array();
    char *text = NULL;
    if (!root || !features) goto nomem;
    if (json_object_set_new(root, "type", json_string("FeatureCollection")) ||
        json_object_set(root, "features", features))
        goto nomem;
    for (size_t i = 0; i < n; i++) {
        const gis_light *l = &lights[i];
        json_t *f = json_object(), *props = json_object(), *geom = json_null();
        if (!f || !props) {
            json_decref(f);
            json_decref(props);
            goto nomem;
        }
        /* every step checked: an allocation that failed used to drop the property silently
         * (#16, fault injection); each set steals its value, even when it fails */
        int bad = 0;
        if (located(l)) {
            json_t *c = json_array();
            /* RFC 7946: lon, lat; heights to the millimetre */
            bad |= !c || json_array_append_new(c, json_real(round_to(gs_wrap180(l->lon_deg), decimals))) ||
                   json_array_append_new(c, json_real(round_to(l->lat_deg, decimals)));
            if (isfinite(l->height_m)) bad |= !c || json_array_append_new(c, json_real(round_to(l->height_m, 3)));
            geom = c ? json_pack("{s:s, s:o}", "type", "Point", "coordinates", c) : NULL;
            bad |= !geom;
        }
        char buf[128];
        for (size_t k = 0; k < N_ATTRS; k++) {
            json_t *v;
            if (attrs[k].kind == A_TEXT) {
                const char *t = attr_text(l, k, buf, sizeof buf);
                v = t ? json_string(t) : json_null();
            } else {
                double d = attr_real(l, k);
                v = isnan(d) ? json_null() : json_real(d);
            }
            bad |= json_object_set_new(props, attrs[k].name, v) != 0;
        }
        bad |= json_object_set_new(f, "type", json_string("Feature")) != 0;
        bad |= json_object_set_new(f, "geometry", geom ? geom : json_null()) != 0;
        bad |= json_object_set_new(f, "properties", props) != 0;
        if (bad) {
            json_decref(f);
            goto nomem;
        }
        if (json_array_append_new(features, f)) goto nomem;
    }
    /* not json_dumps: jansson ignores a failed append of an object's key to its own buffer and
     * returned a document without it (#16, fault injection); ours records the failure */
    dump_buf out = {NULL, 0, 0, 0};
    if (json_dump_callback(root, dump_append, &out, JSON_INDENT(1) | JSON_PRESERVE_ORDER |
                           JSON_REAL_PRECISION(15)) || out.failed || !out.p) {
        free(out.p);
        goto nomem;
    }
    text = out.p;
    json_decref(features);
    json_decref(root);
    gs_atomic a;
    s = gs_atomic_open(&a, path, 1);
    if (s == GS_OK) {
        fputs(text, a.f);
        fputc('\n', a.f);
        s = gs_atomic_commit(&a);
    }
    free(text);
    return s;
nomem:
    json_decref(features);
    json_decref(root);
    return gs_fail(GS_ENOMEM, "%s: out of memory building the GeoJSON", path);
}

/* ---------------------------------------------------------------- KML */

static void xml_text(FILE *f, const char *s)
{
    for (; *s; s++) {
        switch (*s) {
        case '<': fputs("&lt;", f); break;
        case '>': fputs("&gt;", f); break;
        case '&': fputs("&amp;", f); break;
        case '"': fputs("&quot;", f); break;
        case '\'': fputs("&apos;", f); break;
        default: fputc(*s, f);
        }
    }
}

gs_status gis_export_kml(const gis_light *lights, size_t n, const char *path)
{
    gs_status s = check_lights(lights, n);
    if (s != GS_OK) return s;
    gs_atomic a;
    s = gs_atomic_open(&a, path, 1);
    if (s != GS_OK) return s;
    FILE *f = a.f;
    static const char *const style_id[5] = {"phase0", "phase120", "phase240", "phase_other", "phase_unknown"};
    fputs("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
          "<kml xmlns=\"http://www.opengis.net/kml/2.2\">\n<Document>\n"
          "<name>gridsurvey lights</name>\n", f);
    for (int c = 0; c < 5; c++) {
        unsigned char rgb[3];
        gis_phase_rgb((gis_phase_class)c, rgb);
        /* KML colours are aabbggrr */
        fprintf(f, "<Style id=\"%s\"><IconStyle><color>ff%02x%02x%02x</color><scale>0.8</scale>"
                   "<Icon><href>http://maps.google.com/mapfiles/kml/shapes/shaded_dot.png</href>"
                   "</Icon></IconStyle></Style>\n", style_id[c], rgb[2], rgb[1], rgb[0]);
    }
    fputs("<Schema name=\"light\" id=\"light\">\n", f);
    for (size_t k = 1; k < N_ATTRS; k++)   /* id is the Placemark's name */
        fprintf(f, " <SimpleField name=\"%s\" type=\"%s\"/>\n", attrs[k].name, attrs[k].kml_type);
    fputs("</Schema>\n", f);
    char buf[128];
    for (size_t i = 0; i < n; i++) {
        const gis_light *l = &lights[i];
        fputs("<Placemark>\n <name>", f);
        xml_text(f, l->id);
        fprintf(f, "</name>\n <styleUrl>#%s</styleUrl>\n", style_id[gis_phase_classify(l->phase_deg)]);
        fputs(" <ExtendedData><SchemaData schemaUrl=\"#light\">\n", f);
        for (size_t k = 1; k < N_ATTRS; k++) {
            if (attrs[k].kind == A_TEXT) {
                const char *t = attr_text(l, k, buf, sizeof buf);
                if (!t) continue;
                fprintf(f, "  <SimpleData name=\"%s\">", attrs[k].name);
                xml_text(f, t);
                fputs("</SimpleData>\n", f);
            } else {
                double d = attr_real(l, k);
                if (!isnan(d)) fprintf(f, "  <SimpleData name=\"%s\">%.10g</SimpleData>\n", attrs[k].name, d);
            }
        }
        fputs(" </SchemaData></ExtendedData>\n", f);
        if (located(l))
            fprintf(f, " <Point><coordinates>%.10f,%.10f</coordinates></Point>\n",
                    gs_wrap180(l->lon_deg), l->lat_deg);
        fputs("</Placemark>\n", f);
    }
    fputs("</Document>\n</kml>\n", f);
    return gs_atomic_commit(&a);
}

/* ---------------------------------------------------------------- CSV */

static void csv_text(FILE *f, const char *s)
{
    if (!s) return;
    if (!strpbrk(s, ",\"\r\n")) {
        fputs(s, f);
        return;
    }
    fputc('"', f);
    for (; *s; s++) {
        if (*s == '"') fputc('"', f);
        fputc(*s, f);
    }
    fputc('"', f);
}

gs_status gis_export_csv(const gis_light *lights, size_t n, const char *path)
{
    gs_status s = check_lights(lights, n);
    if (s != GS_OK) return s;
    gs_atomic a;
    s = gs_atomic_open(&a, path, 1);
    if (s != GS_OK) return s;
    FILE *f = a.f;
    fputs("id,lat_deg,lon_deg", f);
    for (size_t k = 1; k < N_ATTRS; k++) fprintf(f, ",%s", attrs[k].name);
    fputs(",WKT\r\n", f);   /* GDAL's CSV driver reads a column named WKT as the geometry */
    char buf[128];
    for (size_t i = 0; i < n; i++) {
        const gis_light *l = &lights[i];
        csv_text(f, l->id);
        if (located(l)) fprintf(f, ",%.10f,%.10f", l->lat_deg, gs_wrap180(l->lon_deg));
        else fputs(",,", f);
        for (size_t k = 1; k < N_ATTRS; k++) {
            fputc(',', f);
            if (attrs[k].kind == A_TEXT) {
                csv_text(f, attr_text(l, k, buf, sizeof buf));
            } else {
                double d = attr_real(l, k);
                if (!isnan(d)) fprintf(f, "%.10g", d);
            }
        }
        if (located(l)) fprintf(f, ",POINT (%.10f %.10f)", gs_wrap180(l->lon_deg), l->lat_deg);
        else fputc(',', f);
        fputs("\r\n", f);
    }
    return gs_atomic_commit(&a);
}

/* ---------------------------------------------------------------- GeoPackage */

/* A GeoPackage point blob (GeoPackage 1.3 Sec. 2.1.3): "GP", version 0, flags 0x01 (little
 * endian, no envelope, not empty), int32 srs_id, then WKB Point (little endian, type 1,
 * x = longitude, y = latitude): 8 + 21 = 29 bytes. */
static void gpkg_point(unsigned char blob[29], double lon, double lat)
{
    int32_t srs = 4326;
    uint32_t type = 1;
    blob[0] = 'G';
    blob[1] = 'P';
    blob[2] = 0;
    blob[3] = 0x01;
    for (int i = 0; i < 4; i++) blob[4 + i] = (unsigned char)(((uint32_t)srs >> (8 * i)) & 0xff);
    blob[8] = 1;
    for (int i = 0; i < 4; i++) blob[9 + i] = (unsigned char)((type >> (8 * i)) & 0xff);
    uint64_t u;
    memcpy(&u, &lon, 8);
    for (int i = 0; i < 8; i++) blob[13 + i] = (unsigned char)((u >> (8 * i)) & 0xff);
    memcpy(&u, &lat, 8);
    for (int i = 0; i < 8; i++) blob[21 + i] = (unsigned char)((u >> (8 * i)) & 0xff);
}

static const char gpkg_schema[] =
    "PRAGMA application_id = 1196444487;\n"   /* 'GPKG' */
    "PRAGMA user_version = 10300;\n"          /* 1.3.0 (GDAL 3.6 warns on 10400) */
    "CREATE TABLE gpkg_spatial_ref_sys (srs_name TEXT NOT NULL, srs_id INTEGER PRIMARY KEY, "
    "organization TEXT NOT NULL, organization_coordsys_id INTEGER NOT NULL, "
    "definition TEXT NOT NULL, description TEXT);\n"
    "INSERT INTO gpkg_spatial_ref_sys VALUES ('Undefined cartesian SRS', -1, 'NONE', -1, "
    "'undefined', 'undefined cartesian coordinate reference system');\n"
    "INSERT INTO gpkg_spatial_ref_sys VALUES ('Undefined geographic SRS', 0, 'NONE', 0, "
    "'undefined', 'undefined geographic coordinate reference system');\n"
    "INSERT INTO gpkg_spatial_ref_sys VALUES ('WGS 84 geodetic', 4326, 'EPSG', 4326, "
    "'GEOGCS[\"WGS 84\",DATUM[\"WGS_1984\",SPHEROID[\"WGS 84\",6378137,298.257223563,"
    "AUTHORITY[\"EPSG\",\"7030\"]],AUTHORITY[\"EPSG\",\"6326\"]],PRIMEM[\"Greenwich\",0,"
    "AUTHORITY[\"EPSG\",\"8901\"]],UNIT[\"degree\",0.0174532925199433,AUTHORITY[\"EPSG\",\"9122\"]],"
    "AXIS[\"Latitude\",NORTH],AXIS[\"Longitude\",EAST],AUTHORITY[\"EPSG\",\"4326\"]]', "
    "'longitude/latitude coordinates in decimal degrees on the WGS 84 spheroid');\n"
    "CREATE TABLE gpkg_contents (table_name TEXT NOT NULL PRIMARY KEY, data_type TEXT NOT NULL, "
    "identifier TEXT UNIQUE, description TEXT DEFAULT '', last_change DATETIME NOT NULL DEFAULT "
    "(strftime('%Y-%m-%dT%H:%M:%fZ','now')), min_x DOUBLE, min_y DOUBLE, max_x DOUBLE, "
    "max_y DOUBLE, srs_id INTEGER, CONSTRAINT fk_gc_r_srs_id FOREIGN KEY (srs_id) REFERENCES "
    "gpkg_spatial_ref_sys(srs_id));\n"
    "CREATE TABLE gpkg_geometry_columns (table_name TEXT NOT NULL, column_name TEXT NOT NULL, "
    "geometry_type_name TEXT NOT NULL, srs_id INTEGER NOT NULL, z TINYINT NOT NULL, "
    "m TINYINT NOT NULL, CONSTRAINT pk_geom_cols PRIMARY KEY (table_name, column_name), "
    "CONSTRAINT uk_gc_table_name UNIQUE (table_name), CONSTRAINT fk_gc_tn FOREIGN KEY "
    "(table_name) REFERENCES gpkg_contents(table_name), CONSTRAINT fk_gc_srs FOREIGN KEY "
    "(srs_id) REFERENCES gpkg_spatial_ref_sys (srs_id));\n"
    "CREATE TABLE lights (fid INTEGER PRIMARY KEY AUTOINCREMENT NOT NULL, geom POINT, "
    "id TEXT, bulb TEXT, technology TEXT, phase REAL, confidence REAL, survey TEXT, time DATETIME, "
    "height_m REAL, err_major_m REAL, err_minor_m REAL, err_azimuth_deg REAL, flags TEXT, site TEXT);\n"
    "INSERT INTO gpkg_geometry_columns VALUES ('lights', 'geom', 'POINT', 4326, 0, 0);\n"
    /* the R*Tree spatial index extension (GeoPackage 1.3 Annex F.3), filled directly below */
    "CREATE TABLE gpkg_extensions (table_name TEXT, column_name TEXT, extension_name TEXT NOT NULL, "
    "definition TEXT NOT NULL, scope TEXT NOT NULL, CONSTRAINT ge_tce UNIQUE (table_name, "
    "column_name, extension_name));\n"
    "INSERT INTO gpkg_extensions VALUES ('lights', 'geom', 'gpkg_rtree_index', "
    "'http://www.geopackage.org/spec120/#extension_rtree', 'write-only');\n"
    "CREATE VIRTUAL TABLE rtree_lights_geom USING rtree(id, minx, maxx, miny, maxy);\n"
    /* QGIS's style table: the default style of the layer */
    "CREATE TABLE layer_styles (id INTEGER PRIMARY KEY AUTOINCREMENT, f_table_catalog TEXT(256), "
    "f_table_schema TEXT(256), f_table_name TEXT(256), f_geometry_column TEXT(256), "
    "styleName TEXT(30), styleQML TEXT, styleSLD TEXT, useAsDefault BOOLEAN, description TEXT, "
    "owner TEXT(30), ui TEXT(30), update_time DATETIME DEFAULT "
    "(strftime('%Y-%m-%dT%H:%M:%fZ','now')));\n"
    "INSERT INTO gpkg_contents (table_name, data_type, identifier, description) VALUES "
    "('layer_styles', 'attributes', 'layer_styles', 'QGIS layer styles');\n";

/* The index's triggers (Annex F.3, GeoPackage 1.3), created after the rows are in: they call the
 * ST_* SQL functions that GeoPackage readers (GDAL, QGIS) register on their connections, which
 * this writer's connection does not have (docs/gis.md). */
static const char gpkg_rtree_triggers[] =
    "CREATE TRIGGER rtree_lights_geom_insert AFTER INSERT ON lights WHEN (new.geom NOT NULL AND "
    "NOT ST_IsEmpty(NEW.geom)) BEGIN INSERT OR REPLACE INTO rtree_lights_geom VALUES (NEW.fid, "
    "ST_MinX(NEW.geom), ST_MaxX(NEW.geom), ST_MinY(NEW.geom), ST_MaxY(NEW.geom)); END;\n"
    "CREATE TRIGGER rtree_lights_geom_update1 AFTER UPDATE OF geom ON lights WHEN OLD.fid = "
    "NEW.fid AND (NEW.geom NOTNULL AND NOT ST_IsEmpty(NEW.geom)) BEGIN INSERT OR REPLACE INTO "
    "rtree_lights_geom VALUES (NEW.fid, ST_MinX(NEW.geom), ST_MaxX(NEW.geom), ST_MinY(NEW.geom), "
    "ST_MaxY(NEW.geom)); END;\n"
    "CREATE TRIGGER rtree_lights_geom_update2 AFTER UPDATE OF geom ON lights WHEN OLD.fid = "
    "NEW.fid AND (NEW.geom ISNULL OR ST_IsEmpty(NEW.geom)) BEGIN DELETE FROM rtree_lights_geom "
    "WHERE id = OLD.fid; END;\n"
    "CREATE TRIGGER rtree_lights_geom_update3 AFTER UPDATE ON lights WHEN OLD.fid != NEW.fid AND "
    "(NEW.geom NOTNULL AND NOT ST_IsEmpty(NEW.geom)) BEGIN DELETE FROM rtree_lights_geom WHERE "
    "id = OLD.fid; INSERT OR REPLACE INTO rtree_lights_geom VALUES (NEW.fid, ST_MinX(NEW.geom), "
    "ST_MaxX(NEW.geom), ST_MinY(NEW.geom), ST_MaxY(NEW.geom)); END;\n"
    "CREATE TRIGGER rtree_lights_geom_update4 AFTER UPDATE ON lights WHEN OLD.fid != NEW.fid AND "
    "(NEW.geom ISNULL OR ST_IsEmpty(NEW.geom)) BEGIN DELETE FROM rtree_lights_geom WHERE id IN "
    "(OLD.fid, NEW.fid); END;\n"
    "CREATE TRIGGER rtree_lights_geom_delete AFTER DELETE ON lights WHEN old.geom NOT NULL BEGIN "
    "DELETE FROM rtree_lights_geom WHERE id = OLD.fid; END;\n";

/* The QGIS style (QML) of the lights layer: categories by phase class with the KML's colours
 * (gis_phase_rgb), the class computed from the phase like gs_phase_class. */
static char *gpkg_qml(void)
{
    static const char *const value[5] = {"0", "120", "240", "other", "unknown"};
    static const char *const label[5] = {"0 deg", "120 deg", "240 deg", "not 0/120/240 deg", "unknown phase"};
    size_t size = 8192, used = 0;
    char *q = malloc(size);
    if (!q) return NULL;
    used += (size_t)snprintf(q + used, size - used,
        "<!DOCTYPE qgis PUBLIC 'http://mrcc.com/qgis.dtd' 'SYSTEM'>\n"
        "<qgis version=\"3.22.0\" styleCategories=\"Symbology\">\n"
        " <renderer-v2 type=\"categorizedSymbol\" attr=\"CASE WHEN &quot;phase&quot; IS NULL THEN "
        "'unknown' WHEN &quot;phase&quot; &lt;= 20 OR &quot;phase&quot; &gt;= 340 THEN '0' WHEN "
        "&quot;phase&quot; BETWEEN 100 AND 140 THEN '120' WHEN &quot;phase&quot; BETWEEN 220 AND "
        "260 THEN '240' ELSE 'other' END\" symbollevels=\"0\" enableorderby=\"0\" forceraster=\"0\">\n"
        "  <categories>\n");
    for (int c = 0; c < 5; c++)
        used += (size_t)snprintf(q + used, size - used, "   <category render=\"true\" value=\"%s\" "
                                 "symbol=\"%d\" label=\"%s\"/>\n", value[c], c, label[c]);
    used += (size_t)snprintf(q + used, size - used, "  </categories>\n  <symbols>\n");
    for (int c = 0; c < 5; c++) {
        unsigned char rgb[3];
        gis_phase_rgb((gis_phase_class)c, rgb);
        used += (size_t)snprintf(q + used, size - used,
            "   <symbol type=\"marker\" name=\"%d\" alpha=\"1\" clip_to_extent=\"1\" force_rhr=\"0\">\n"
            "    <layer class=\"SimpleMarker\" pass=\"0\" locked=\"0\" enabled=\"1\">\n"
            "     <Option type=\"Map\">\n"
            "      <Option type=\"QString\" name=\"color\" value=\"%d,%d,%d,255\"/>\n"
            "      <Option type=\"QString\" name=\"name\" value=\"circle\"/>\n"
            "      <Option type=\"QString\" name=\"outline_style\" value=\"no\"/>\n"
            "      <Option type=\"QString\" name=\"size\" value=\"2.4\"/>\n"
            "     </Option>\n    </layer>\n   </symbol>\n", c, rgb[0], rgb[1], rgb[2]);
    }
    snprintf(q + used, size - used, "  </symbols>\n </renderer-v2>\n</qgis>\n");
    return q;
}

/* An ISO 8601 time as a capture's utc holds it (gs_capture_valid_utc: "YYYY-MM-DDTHH:MM:SS[.f]"
 * then "Z" or a UTC offset "+hh:mm"/"-hh:mm") as GeoPackage's DATETIME text, in UTC:
 * "YYYY-MM-DDTHH:MM:SS.SSSZ" (out: 64 bytes); 0 when t is not one. */
static int gpkg_datetime(const char *t, char out[64])
{
    int y, mo, d, h, mi, sec, n = 0, oh = 0, om = 0, ms = 0;
    if (!t || !gs_capture_valid_utc(t) || sscanf(t, "%4d-%2d-%2dT%2d:%2d:%2d%n", &y, &mo, &d, &h, &mi, &sec, &n) != 6)
        return 0;
    const char *z = t + n;
    /* the milliseconds: the fraction's first three digits, from the text (the double 1.005 is
     * 1.00499..., and floor(1000 x) made .005 s .004 s) */
    if (*z == '.') {
        int k = 0;
        for (z++; isdigit((unsigned char)*z); z++, k++)
            if (k < 3) ms = 10 * ms + (*z - '0');
        for (; k < 3; k++) ms *= 10;
    }
    int sign = z[0] == '+' ? 1 : z[0] == '-' ? -1 : 0;
    if (sign && sscanf(z + 1, "%2d:%2d", &oh, &om) != 2) return 0;
    struct tm tm = {.tm_year = y - 1900, .tm_mon = mo - 1, .tm_mday = d, .tm_hour = h,
                    .tm_min = mi - sign * (60 * oh + om), .tm_sec = sec};
    time_t utc = timegm(&tm);   /* normalises the shifted fields */
    if (!gmtime_r(&utc, &tm)) return 0;
    snprintf(out, 64, "%04d-%02d-%02dT%02d:%02d:%02d.%03dZ", tm.tm_year + 1900, tm.tm_mon + 1,
             tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec, ms);
    return 1;
}

gs_status gis_export_gpkg(const gis_light *lights, size_t n, const char *path)
{
    gs_status s = check_lights(lights, n);
    if (s != GS_OK) return s;
    gs_atomic a;
    s = gs_atomic_open(&a, path, 0);
    if (s != GS_OK) return s;
    sqlite3 *db = NULL;
    sqlite3_stmt *st = NULL;
    char *err = NULL;
    if (sqlite3_open_v2(a.tmp, &db, SQLITE_OPEN_READWRITE, NULL) != SQLITE_OK) goto sql_error;
    if (sqlite3_exec(db, "BEGIN", NULL, NULL, &err) != SQLITE_OK) goto sql_error;
    if (sqlite3_exec(db, gpkg_schema, NULL, NULL, &err) != SQLITE_OK) goto sql_error;
    double minx = INFINITY, miny = INFINITY, maxx = -INFINITY, maxy = -INFINITY;
    if (sqlite3_prepare_v2(db,
                           "INSERT INTO lights (geom, id, bulb, technology, phase, confidence, "
                           "survey, time, height_m, err_major_m, err_minor_m, err_azimuth_deg, "
                           "flags, site) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                           -1, &st, NULL) != SQLITE_OK)
        goto sql_error;
    char buf[128];
    for (size_t i = 0; i < n; i++) {
        const gis_light *l = &lights[i];
        sqlite3_reset(st);
        sqlite3_clear_bindings(st);
        /* every bind checked: a text or blob copy that could not be allocated left the column
         * NULL and the row went in without it (#16, fault injection) */
        int brc = SQLITE_OK;
        if (located(l)) {
            unsigned char blob[29];
            double lon = gs_wrap180(l->lon_deg);
            gpkg_point(blob, lon, l->lat_deg);
            brc |= sqlite3_bind_blob(st, 1, blob, (int)sizeof blob, SQLITE_TRANSIENT);
            if (lon < minx) minx = lon;
            if (lon > maxx) maxx = lon;
            if (l->lat_deg < miny) miny = l->lat_deg;
            if (l->lat_deg > maxy) maxy = l->lat_deg;
        } else {
            sqlite3_bind_null(st, 1);
        }
        for (size_t k = 0; k < N_ATTRS; k++) {
            int col = (int)k + 2;
            char when[64];
            if (attrs[k].kind == A_TEXT) {
                const char *t = attr_text(l, k, buf, sizeof buf);
                if (k == 6) t = gpkg_datetime(t, when) ? when : NULL;   /* time: DATETIME */
                if (t) brc |= sqlite3_bind_text(st, col, t, -1, SQLITE_TRANSIENT);
                else sqlite3_bind_null(st, col);
            } else {
                double d = attr_real(l, k);
                if (isnan(d)) sqlite3_bind_null(st, col);
                else brc |= sqlite3_bind_double(st, col, d);
            }
        }
        if (brc != SQLITE_OK || sqlite3_step(st) != SQLITE_DONE) goto sql_error;
    }
    sqlite3_finalize(st);
    st = NULL;
    if (sqlite3_prepare_v2(db,
                           "INSERT INTO gpkg_contents (table_name, data_type, identifier, "
                           "description, min_x, min_y, max_x, max_y, srs_id) VALUES ('lights', "
                           "'features', 'lights', 'gridsurvey located lights (heights are "
                           "ellipsoidal, WGS84)', ?, ?, ?, ?, 4326)",
                           -1, &st, NULL) != SQLITE_OK)
        goto sql_error;
    if (isfinite(minx)) {
        sqlite3_bind_double(st, 1, minx);
        sqlite3_bind_double(st, 2, miny);
        sqlite3_bind_double(st, 3, maxx);
        sqlite3_bind_double(st, 4, maxy);
    }
    if (sqlite3_step(st) != SQLITE_DONE) goto sql_error;
    sqlite3_finalize(st);
    st = NULL;
    /* the spatial index, its triggers, the style */
    if (sqlite3_prepare_v2(db, "INSERT INTO rtree_lights_geom VALUES (?, ?, ?, ?, ?)", -1, &st, NULL) != SQLITE_OK)
        goto sql_error;
    for (size_t i = 0, fid = 1; i < n; i++, fid++) {
        const gis_light *l = &lights[i];
        if (!located(l)) continue;
        double lon = gs_wrap180(l->lon_deg);
        sqlite3_reset(st);
        sqlite3_bind_int64(st, 1, (sqlite3_int64)fid);
        sqlite3_bind_double(st, 2, lon);
        sqlite3_bind_double(st, 3, lon);
        sqlite3_bind_double(st, 4, l->lat_deg);
        sqlite3_bind_double(st, 5, l->lat_deg);
        if (sqlite3_step(st) != SQLITE_DONE) goto sql_error;
    }
    sqlite3_finalize(st);
    st = NULL;
    if (sqlite3_exec(db, gpkg_rtree_triggers, NULL, NULL, &err) != SQLITE_OK) goto sql_error;
    char *qml = gpkg_qml();
    if (!qml) {
        s = gs_fail(GS_ENOMEM, "%s: out of memory for the layer style", path);
        sqlite3_close(db);
        gs_atomic_abort(&a);
        return s;
    }
    int qrc = sqlite3_prepare_v2(db, "INSERT INTO layer_styles (f_table_catalog, f_table_schema, "
                                     "f_table_name, f_geometry_column, styleName, styleQML, styleSLD, "
                                     "useAsDefault, description, owner, ui) VALUES ('', '', 'lights', "
                                     "'geom', 'phase', ?, '', 1, 'lights coloured by grid phase class "
                                     "(as the KML)', 'gridsurvey', NULL)", -1, &st, NULL);
    if (qrc == SQLITE_OK) {
        qrc = sqlite3_bind_text(st, 1, qml, -1, SQLITE_TRANSIENT) == SQLITE_OK && sqlite3_step(st) == SQLITE_DONE
                  ? SQLITE_OK : SQLITE_ERROR;
    }
    free(qml);
    if (qrc != SQLITE_OK) goto sql_error;
    sqlite3_finalize(st);
    st = NULL;
    if (sqlite3_exec(db, "COMMIT", NULL, NULL, &err) != SQLITE_OK) goto sql_error;
    if (sqlite3_close(db) != SQLITE_OK) {
        db = NULL;
        gs_atomic_abort(&a);
        return gs_fail(GS_ESQL, "%s: cannot close the GeoPackage", path);
    }
    return gs_atomic_commit(&a);
sql_error:
    s = gs_fail(GS_ESQL, "%s: SQLite: %s", path, err ? err : db ? sqlite3_errmsg(db) : "cannot open");
    sqlite3_free(err);
    sqlite3_finalize(st);
    sqlite3_close(db);
    gs_atomic_abort(&a);
    return s;
}

gs_status gis_export(const gis_light *lights, size_t n, gis_format f, const char *path)
{
    switch (f) {
    case GIS_FORMAT_GEOJSON: return gis_export_geojson(lights, n, path);
    case GIS_FORMAT_KML: return gis_export_kml(lights, n, path);
    case GIS_FORMAT_GPKG: return gis_export_gpkg(lights, n, path);
    case GIS_FORMAT_CSV: return gis_export_csv(lights, n, path);
    }
    return gs_fail(GS_EINVAL, "export: unknown format %d", (int)f);
}
