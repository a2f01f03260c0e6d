/* test_gis_export.c - gis/ exports read back by independent readers: GDAL's ogrinfo (GeoJSON,
 * KML, GeoPackage, CSV: feature counts, WKT positions in lon/lat order, attributes),
 * validate_gpkg.py --extra, SQLite itself for the GeoPackage header and blobs, Jansson for the
 * RFC 7946 structure, OpenCV (python3-opencv) for the map's colours; atomic replacement; and
 * `gridsurvey locate` end to end. */
#include "gis/gis.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <dirent.h>
#include <jansson.h>
#include <math.h>
#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static char out[1 << 18];

/* Six lights: the three phases, another phase, an unknown phase, and one not located; two
 * near the antimeridian; a survey name that needs escaping in every format. */
static size_t sample_lights(gis_light *l)
{
    static const struct {
        const char *id;
        double lat, lon, h, phase, conf;
        const char *bulb, *tech;
    } s[6] = {
        {"L1", 40.1, -75.2, 30.5, 0.0, 0.97, "cfl_1", "cfl"},
        {"L2", 40.1005, -75.2004, 31.0, 120.0, 0.91, "sodium_hp_2", "sodium_hp"},
        {"L3", 40.1010, -75.1996, 29.0, 240.0, 0.88, "led_lin_3", "led_linear"},
        {"L4", -16.5, 179.99995, 12.0, 57.0, 0.5, "inc_4", "incandescent"},
        {"L5", -16.5001, -179.99995, 12.5, NAN, NAN, "", ""},
        {"L6", NAN, NAN, NAN, 240.0, 0.7, "cfl_1", "cfl"},
    };
    for (int i = 0; i < 6; i++) {
        gis_light_init(&l[i]);
        snprintf(l[i].id, sizeof l[i].id, "%s", s[i].id);
        l[i].lat_deg = s[i].lat;
        l[i].lon_deg = s[i].lon;
        l[i].height_m = s[i].h;
        l[i].phase_deg = s[i].phase;
        l[i].confidence = s[i].conf;
        snprintf(l[i].bulb_id, sizeof l[i].bulb_id, "%s", s[i].bulb);
        snprintf(l[i].technology, sizeof l[i].technology, "%s", s[i].tech);
        snprintf(l[i].survey, sizeof l[i].survey, "%s", "Main St & <Elm>, \"north\"");
        snprintf(l[i].time_utc, sizeof l[i].time_utc, "%s", "2024-05-01T21:30:00Z");
        if (isfinite(s[i].lat)) {
            l[i].ellipse.semi_major_m = 2.5 + i;
            l[i].ellipse.semi_minor_m = 0.5;
            l[i].ellipse.azimuth_deg = 30.0;
        } else {
            l[i].flags = GIS_FIX_ABOVE_HORIZON;
        }
    }
    return 6;
}

/* Point WKT of light i as ogrinfo prints it (lon first), or "" when not located. */
static void check_ogr_points(const char *text, int z)
{
    CHECK_MSG(fx_contains(text, z ? "POINT Z (-75.2 40.1 30.5)" : "POINT (-75.2 40.1)"), "%s", text);
    CHECK(fx_contains(text, z ? "POINT Z (-75.2004 40.1005 31)" : "POINT (-75.2004 40.1005)"));
    CHECK(fx_contains(text, z ? "POINT Z (179.99995 -16.5 12)" : "POINT (179.99995 -16.5)"));
    CHECK(fx_contains(text, z ? "POINT Z (-179.99995 -16.5001 12.5)" : "POINT (-179.99995 -16.5001)"));
    CHECK(fx_count_of(text, "POINT") == 5);
}

static void check_ogr_attributes(const char *text)
{
    CHECK_MSG(fx_count_of(text, "Main St & <Elm>, \"north\"") == 6, "%s", text);
    CHECK(fx_contains(text, "bulb (String) = sodium_hp_2"));
    CHECK(fx_contains(text, "technology (String) = led_linear"));
    CHECK(fx_contains(text, "phase (Real) = 240"));
    CHECK(fx_contains(text, "confidence (Real) = 0.91"));
    /* GDAL's GeoJSON reader recognises the ISO 8601 text as a DateTime */
    CHECK(fx_contains(text, "time (String) = 2024-05-01T21:30:00Z") ||
          fx_contains(text, "time (DateTime) = 2024/05/01 21:30:00+00"));
    CHECK(fx_contains(text, "flags (String) = above_horizon"));
}

/* `ogrinfo -ro -al OPTS 'path'` (GDAL), its output in out. */
static int ogrinfo(const char *opts, const char *path)
{
    return fx_run(out, sizeof out, "ogrinfo -ro -al %s '%s'", opts, path);
}

/* The sample lights exported by `export` to TMPDIR/name; the path. */
static const char *export_sample(gs_status (*export)(const gis_light *, size_t, const char *),
                                 const char *name)
{
    gis_light l[6];
    size_t n = sample_lights(l);
    const char *path = fx_tmp(name);
    CHECK_OK(export(l, n, path));
    return path;
}

TEST(gis_export_geojson_ogrinfo_rfc7946)
{
    const char *path = export_sample(gis_export_geojson, "lights.geojson");
    CHECK(ogrinfo("-so", path) == 0);
    CHECK_MSG(fx_contains(out, "Feature Count: 6"), "%s", out);
    CHECK(ogrinfo("", path) == 0);
    check_ogr_points(out, 1);
    check_ogr_attributes(out);
    /* RFC 7946 structure, read independently */
    json_error_t e;
    json_t *root = json_load_file(path, 0, &e);
    CHECK(root != NULL);
    if (!root) return;
    CHECK(!strcmp(json_string_value(json_object_get(root, "type")), "FeatureCollection"));
    CHECK(json_object_get(root, "crs") == NULL);   /* RFC 7946: no crs member */
    json_t *fs = json_object_get(root, "features");
    CHECK(json_array_size(fs) == 6);
    json_t *c = json_object_get(json_object_get(json_array_get(fs, 0), "geometry"), "coordinates");
    CHECK_NEAR(json_real_value(json_array_get(c, 0)), -75.2, 1e-12);   /* longitude first */
    CHECK_NEAR(json_real_value(json_array_get(c, 1)), 40.1, 1e-12);
    CHECK_NEAR(json_real_value(json_array_get(c, 2)), 30.5, 1e-12);
    CHECK(json_is_null(json_object_get(json_array_get(fs, 5), "geometry")));
    CHECK(json_is_null(json_object_get(json_object_get(json_array_get(fs, 4), "properties"), "phase")));
    json_decref(root);
}

TEST(gis_export_kml_ogrinfo)
{
    const char *path = export_sample(gis_export_kml, "lights.kml");
    CHECK(ogrinfo("", path) == 0);
    CHECK_MSG(fx_contains(out, "Feature Count: 6") || fx_count_of(out, "OGRFeature(") == 6, "%s", out);
    CHECK(fx_count_of(out, "OGRFeature(") == 6);
    check_ogr_points(out, 0);
    check_ogr_attributes(out);
    /* styles: a placemark of each phase class */
    char *kml = fx_read_file(path, NULL);
    CHECK(kml != NULL);
    if (!kml) return;
    CHECK(fx_count_of(kml, "<styleUrl>#phase0</styleUrl>") == 1);
    CHECK(fx_count_of(kml, "<styleUrl>#phase240</styleUrl>") == 2);
    CHECK(fx_count_of(kml, "<styleUrl>#phase_other</styleUrl>") == 1);
    CHECK(fx_count_of(kml, "<styleUrl>#phase_unknown</styleUrl>") == 1);
    CHECK(fx_contains(kml, "<color>ff005ed5</color>"));   /* 0 deg: vermillion (213, 94, 0), aabbggrr */
    free(kml);
}

TEST(gis_export_gpkg_validates)
{
    const char *path = export_sample(gis_export_gpkg, "lights.gpkg");
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "/usr/bin/python3 /usr/lib/python3/dist-packages/osgeo_utils/samples/"
                              "validate_gpkg.py --extra '%s'", path);
    int rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 0 && !fx_contains(out, "rror") && !fx_contains(out, "arning"), "validate_gpkg: %d: %s", rc, out);
    CHECK(ogrinfo("-so", path) == 0);
    CHECK_MSG(fx_contains(out, "Feature Count: 6") && fx_contains(out, "Geometry: Point") &&
              fx_contains(out, "WGS 84") && !fx_contains(out, "arning"), "%s", out);
    CHECK(ogrinfo("", path) == 0);
    check_ogr_points(out, 0);
    check_ogr_attributes(out);
    /* header and blobs, read with SQLite */
    sqlite3 *db;
    CHECK(sqlite3_open_v2(path, &db, SQLITE_OPEN_READONLY, NULL) == SQLITE_OK);
    sqlite3_stmt *st;
    const char *q[4] = {"PRAGMA application_id", "PRAGMA user_version",
                        "SELECT count(*) FROM lights WHERE length(geom) = 29",
                        "SELECT count(*) FROM lights WHERE geom IS NULL"};
    const long long want[4] = {1196444487, 10300, 5, 1};
    for (int i = 0; i < 4; i++) {
        CHECK(sqlite3_prepare_v2(db, q[i], -1, &st, NULL) == SQLITE_OK);
        CHECK(sqlite3_step(st) == SQLITE_ROW);
        CHECK_MSG(sqlite3_column_int64(st, 0) == want[i], "%s = %lld, expected %lld", q[i],
                  sqlite3_column_int64(st, 0), want[i]);
        sqlite3_finalize(st);
    }
    CHECK(sqlite3_prepare_v2(db, "SELECT geom FROM lights WHERE id = 'L1'", -1, &st, NULL) == SQLITE_OK);
    CHECK(sqlite3_step(st) == SQLITE_ROW);
    const unsigned char *b = sqlite3_column_blob(st, 0);
    double x, y;
    CHECK(b && b[0] == 'G' && b[1] == 'P' && b[2] == 0 && b[3] == 1 && b[4] == 0xe6 && b[5] == 0x10);
    if (b) {
        memcpy(&x, b + 13, 8);   /* little-endian host */
        memcpy(&y, b + 21, 8);
        CHECK_NEAR(x, -75.2, 0);   /* x = longitude */
        CHECK_NEAR(y, 40.1, 0);
    }
    sqlite3_finalize(st);
    /* the R*Tree index: one box per located light, each containing its point (the R*Tree
     * rounds to float32 outward), its six triggers and its extension row */
    const char *q2[5] = {"SELECT count(*) FROM rtree_lights_geom",
                         "SELECT count(*) FROM rtree_lights_geom r JOIN lights l ON l.fid = r.id WHERE "
                         "r.minx <= -75.2 + 1e-5 AND r.maxx >= -75.2 - 1e-5 AND l.id = 'L1'",
                         "SELECT count(*) FROM sqlite_master WHERE type = 'trigger' AND name LIKE 'rtree_lights_geom_%'",
                         "SELECT count(*) FROM gpkg_extensions WHERE table_name = 'lights' AND column_name = 'geom' "
                         "AND extension_name = 'gpkg_rtree_index'",
                         "SELECT count(*) FROM layer_styles WHERE f_table_name = 'lights' AND useAsDefault = 1"};
    const long long want2[5] = {5, 1, 6, 1, 1};
    for (int i = 0; i < 5; i++) {
        CHECK(sqlite3_prepare_v2(db, q2[i], -1, &st, NULL) == SQLITE_OK);
        CHECK(sqlite3_step(st) == SQLITE_ROW);
        CHECK_MSG(sqlite3_column_int64(st, 0) == want2[i], "%s = %lld, expected %lld", q2[i],
                  sqlite3_column_int64(st, 0), want2[i]);
        sqlite3_finalize(st);
    }
    sqlite3_close(db);
    /* GDAL sees the index and uses it for a spatial filter; the time is a DateTime */
    CHECK(fx_run(out, sizeof out, "ogrinfo -ro '%s' -sql \"SELECT HasSpatialIndex('lights', 'geom')\"", path) == 0);
    CHECK_MSG(fx_contains(out, "= 1"), "%s", out);
    CHECK(ogrinfo("-spat -75.3 40.0 -75.1 40.2", path) == 0);
    CHECK_MSG(fx_count_of(out, "OGRFeature(") == 3, "%s", out);
    CHECK(ogrinfo("", path) == 0);
    CHECK_MSG(fx_contains(out, "time (DateTime) = 2024/05/01 21:30:00"), "%s", out);
    /* the QGIS style: XML with one category per phase class, in the KML's colours */
    snprintf(cmd, sizeof cmd, "/usr/bin/python3 -c \"import sqlite3, xml.etree.ElementTree as E; "
             "q = sqlite3.connect('%s').execute('SELECT styleQML FROM layer_styles').fetchone()[0]; "
             "r = E.fromstring(q.split('\\n', 1)[1]).find('renderer-v2'); "
             "print(r.get('type'), len(r.find('categories')), "
             "' '.join(o.get('value') for o in r.iter('Option') if o.get('name') == 'color'))\"", path);
    rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 0 && fx_contains(out, "categorizedSymbol 5 213,94,0,255 0,158,115,255 0,114,178,255 "
                                          "204,121,167,255 128,128,128,255"), "%d: %s", rc, out);
}


/* The GeoPackage's DATETIME column is UTC: a time with a UTC offset (valid ISO 8601, as a
 * capture's utc or a station's time_utc may be) is converted, not stored NULL as it was while
 * GeoJSON and CSV kept it. Oracle: GNU date -u on the same text. */
TEST(gis_export_gpkg_time_offset_to_utc)
{
    static const char *const times[4] = {"2026-03-01T01:30:00.250+02:00", "2024-12-31T21:15:59-05:30",
                                         "2024-02-28T23:59:59.999-00:01", "2024-05-01T21:30:00Z"};
    gis_light l[4];
    for (int i = 0; i < 4; i++) {
        gis_light_init(&l[i]);
        snprintf(l[i].id, sizeof l[i].id, "T%d", i);
        l[i].lat_deg = 10.0;
        l[i].lon_deg = 20.0 + i;
        snprintf(l[i].time_utc, sizeof l[i].time_utc, "%s", times[i]);
    }
    const char *path = fx_tmp("times.gpkg");
    CHECK(gis_export_gpkg(l, 4, path) == GS_OK);
    sqlite3 *db;
    CHECK(sqlite3_open_v2(path, &db, SQLITE_OPEN_READONLY, NULL) == SQLITE_OK);
    for (int i = 0; i < 4; i++) {
        char want[128] = "";
        CHECK(fx_run(want, sizeof want, "date -u -d '%s' +%%Y-%%m-%%dT%%H:%%M:%%S.%%3NZ", times[i]) == 0);
        want[strcspn(want, "\n")] = '\0';
        sqlite3_stmt *st;
        char q[96];
        snprintf(q, sizeof q, "SELECT time FROM lights WHERE id = 'T%d'", i);
        CHECK(sqlite3_prepare_v2(db, q, -1, &st, NULL) == SQLITE_OK);
        CHECK(sqlite3_step(st) == SQLITE_ROW);
        const char *got = (const char *)sqlite3_column_text(st, 0);
        CHECK_MSG(got && !strcmp(got, want), "%s: stored %s, date -u says %s", times[i], got ? got : "NULL", want);
        sqlite3_finalize(st);
    }
    sqlite3_close(db);
}

/* A UTC time with milliseconds is stored with those milliseconds, every one of 0..999 at each
 * second of a minute: they were floor(seconds x 1000) of the parsed seconds, and 01.005 s is the
 * double 1.00499999..., stored as .004 (372 of the 60000 were a millisecond early). Oracle: the
 * text itself (already UTC, already three decimals). */
TEST(gis_export_gpkg_time_keeps_its_milliseconds)
{
    enum { N = 60 * 1000 };
    gis_light *l = calloc(N, sizeof *l);
    if (!l) return;
    for (int i = 0; i < N; i++) {
        gis_light_init(&l[i]);
        snprintf(l[i].id, sizeof l[i].id, "%d", i);
        snprintf(l[i].time_utc, sizeof l[i].time_utc, "2024-05-01T21:30:%02d.%03dZ", i / 1000, i % 1000);
    }
    const char *path = fx_tmp("ms.gpkg");
    CHECK(gis_export_gpkg(l, N, path) == GS_OK);
    sqlite3 *db;
    sqlite3_stmt *st;
    CHECK(sqlite3_open_v2(path, &db, SQLITE_OPEN_READONLY, NULL) == SQLITE_OK);
    CHECK(sqlite3_prepare_v2(db, "SELECT id, time FROM lights ORDER BY fid", -1, &st, NULL) == SQLITE_OK);
    int rows = 0, wrong = 0;
    while (sqlite3_step(st) == SQLITE_ROW) {
        int i = atoi((const char *)sqlite3_column_text(st, 0));
        const char *got = (const char *)sqlite3_column_text(st, 1);
        rows++;
        if (i < 0 || i >= N || !got || strcmp(got, l[i].time_utc)) {
            if (!wrong) CHECK_MSG(0, "%s stored as %s", i >= 0 && i < N ? l[i].time_utc : "?", got ? got : "NULL");
            wrong++;
        }
    }
    CHECK_MSG(rows == N && wrong == 0, "%d rows, %d times changed", rows, wrong);
    sqlite3_finalize(st);
    sqlite3_close(db);
    free(l);
}

/* GeoJSON coordinates carry 7 decimals by default (1.1 cm), --precision otherwise. */
TEST(gis_export_geojson_seven_decimals)
{
    gis_light l[6];
    size_t n = sample_lights(l);
    l[0].lon_deg = -75.200000049;   /* 4.9e-8: gone at 7 decimals */
    l[1].lat_deg = 40.10050000051;
    l[0].height_m = 30.50049;
    const char *path = fx_tmp("d.geojson");
    CHECK_OK(gis_export_geojson(l, n, path));
    char *text = fx_read_file(path, NULL);
    CHECK_MSG(text && fx_contains(text, "-75.2,") && fx_contains(text, "40.1005,") && fx_contains(text, "30.5\n"),
              "%s", text ? text : "");
    free(text);
    CHECK_OK(gis_export_geojson_decimals(l, n, path, 3));
    text = fx_read_file(path, NULL);
    CHECK_MSG(text && fx_contains(text, "40.101,") && fx_contains(text, "-75.2,"), "%s", text ? text : "");
    free(text);
    /* 12 decimals of a three-digit longitude, written out in full (15 significant digits) */
    l[0].lon_deg = -179.987654321012;
    CHECK_OK(gis_export_geojson_decimals(l, n, path, 12));
    text = fx_read_file(path, NULL);
    CHECK_MSG(text && fx_contains(text, "-179.987654321012,"), "%s", text ? text : "");
    free(text);
    CHECK(gis_export_geojson_decimals(l, n, path, 13) == GS_EINVAL);   /* (13-15 printed 12) */
}

TEST(gis_export_csv_ogrinfo)
{
    const char *path = export_sample(gis_export_csv, "lights.csv");
    /* GDAL finds the geometry by itself in the WKT column (KEEP_GEOM_COLUMNS=NO only hides the
     * column's text, which would print every POINT twice) */
    CHECK(ogrinfo("-oo KEEP_GEOM_COLUMNS=NO -oo AUTODETECT_TYPE=YES", path) == 0);
    CHECK(fx_count_of(out, "OGRFeature(") == 6);
    check_ogr_points(out, 0);
    /* and the lon/lat columns when told their names */
    CHECK(ogrinfo("-oo X_POSSIBLE_NAMES=lon_deg -oo Y_POSSIBLE_NAMES=lat_deg -oo GEOM_POSSIBLE_NAMES=none "
                  "-oo KEEP_GEOM_COLUMNS=NO", path) == 0);
    CHECK_MSG(fx_contains(out, "  POINT (-75.2 40.1)") && fx_contains(out, "  POINT (-179.99995 -16.5001)"), "%s", out);
    CHECK_MSG(fx_count_of(out, "Main St & <Elm>, \"north\"") == 6, "%s", out);
    CHECK(fx_contains(out, "bulb (String) = sodium_hp_2"));
    CHECK(fx_contains(out, "flags (String) = above_horizon"));
}

static int count_tmp_files(const char *dir)
{
    DIR *d = opendir(dir);
    int n = 0;
    if (!d) return -1;
    struct dirent *e;
    while ((e = readdir(d))) n += strstr(e->d_name, ".tmp.") != NULL;
    closedir(d);
    return n;
}

TEST(gis_export_atomic_replace)
{
    gis_light l[6];
    size_t n = sample_lights(l);
    const char *path = fx_tmp("a.geojson");
    FILE *f = fopen(path, "w");
    fputs("old content\n", f);
    fclose(f);
    /* a failing export (control character) leaves the old file */
    gis_light bad[6];
    memcpy(bad, l, sizeof bad);
    bad[2].survey[0] = '\n';
    const gis_format fmts[4] = {GIS_FORMAT_GEOJSON, GIS_FORMAT_KML, GIS_FORMAT_GPKG, GIS_FORMAT_CSV};
    for (int k = 0; k < 4; k++) CHECK(gis_export(bad, n, fmts[k], path) == GS_EINVAL);
    f = fopen(path, "r");
    char line[64] = "";
    CHECK(f && fgets(line, sizeof line, f) && !strcmp(line, "old content\n"));
    if (f) fclose(f);
    /* success replaces it; no temporary file is left */
    CHECK_OK(gis_export(l, n, GIS_FORMAT_GEOJSON, path));
    f = fopen(path, "r");
    CHECK(f && fgets(line, sizeof line, f) && !strcmp(line, "{\n"));
    if (f) fclose(f);
    /* an unwritable place fails with GS_EIO and creates nothing */
    for (int k = 0; k < 4; k++) CHECK(gis_export(l, n, fmts[k], fx_tmp("missing/dir/x.out")) == GS_EIO);
    CHECK(count_tmp_files(test_tmpdir()) == 0);
    /* formats by name and by extension */
    gis_format fm;
    CHECK_OK(gis_format_from_path("x/y.GPKG", &fm));
    CHECK(fm == GIS_FORMAT_GPKG);
    CHECK_OK(gis_format_from_path("y.json", &fm));
    CHECK(fm == GIS_FORMAT_GEOJSON);
    CHECK(gis_format_from_path("y.shp", &fm) == GS_EINVAL);
    CHECK(gis_format_parse("KML", &fm) == GS_OK && fm == GIS_FORMAT_KML);
    /* NaN latitude with a finite longitude is inconsistent */
    l[0].lat_deg = NAN;
    CHECK(gis_export_csv(l, n, fx_tmp("b.csv")) == GS_EINVAL);
    l[0].lat_deg = INFINITY;
    CHECK(gis_export_csv(l, n, fx_tmp("b.csv")) == GS_ENUMERIC);
}

TEST(gis_map_png_phase_colours)
{
    gis_light l[6];
    size_t n = sample_lights(l);
    /* a local cluster: move the two antimeridian lights next to the others */
    l[3].lat_deg = 40.0995;
    l[3].lon_deg = -75.2008;
    l[4].lat_deg = 40.1008;
    l[4].lon_deg = -75.2010;
    gis_camera st;
    memset(&st, 0, sizeof st);
    st.lat_deg = 40.098;
    st.lon_deg = -75.201;
    st.height_m = 50;
    st.focal_px = 1000;
    gis_map_opts o;
    gis_map_opts_default(&o);
    o.stations = &st;
    o.n_stations = 1;
    o.width_px = 900;
    o.height_px = 700;
    const char *path = fx_tmp("map.png");
    CHECK_OK(gis_map_png(l, n, &o, path));
    /* count pixels of each class colour (exact RGB inside the discs) with OpenCV */
    char cmd[2048];
    snprintf(cmd, sizeof cmd,
             "/usr/bin/python3 -c \"import cv2, numpy as np\n"
             "im = cv2.imread('%s', cv2.IMREAD_COLOR)\n"
             "print('size', im.shape[1], im.shape[0])\n"
             "for r, g, b in [(213, 94, 0), (0, 158, 115), (0, 114, 178), (204, 121, 167), (128, 128, 128)]:\n"
             "    print('count', int(np.all(im == (b, g, r), axis=2).sum()))\n\"", path);
    CHECK(test_run(cmd, out, sizeof out) == 0);
    int w = 0, h = 0, c[5] = {0};
    const char *p = strstr(out, "size");
    CHECK(p && sscanf(p, "size %d %d", &w, &h) == 2);
    CHECK(w == 900 && h == 700);
    for (int k = 0; k < 5 && p; k++) {
        p = strstr(p + 1, "count");
        if (p) sscanf(p, "count %d", &c[k]);
    }
    /* each class appears: a disc (plus its legend box) */
    for (int k = 0; k < 5; k++) CHECK_MSG(c[k] > 50, "class %d: %d pixels\n%s", k, c[k], out);
    /* nothing to draw is an error, not an empty picture */
    CHECK(gis_map_png(l + 5, 1, NULL, fx_tmp("empty.png")) == GS_EINVAL);
}

/* ------------------------------------------------------------- the CLI */

TEST(gis_cli_locate)
{
    char st[1024], px[1024], res[1024];
    snprintf(st, sizeof st, "%s", fx_tmp("station.json"));
    snprintf(px, sizeof px, "%s", fx_tmp("pixels.csv"));
    snprintf(res, sizeof res, "%s", fx_tmp("out.geojson"));
    fx_write_text(st, "{\"format\": \"gridsurvey-station/1\", \"lat_deg\": 40.0, \"lon_deg\": -75.0,\n"
                   " \"height_m\": 120.0, \"heading_deg\": 30, \"pitch_deg\": -5, \"roll_deg\": 1,\n"
                   " \"focal_px\": 2000, \"cx_px\": 959.5, \"cy_px\": 539.5, \"k1\": -0.05, \"k2\": 0.01,\n"
                   " \"sigma_px\": 0.5, \"sigma_heading_deg\": 0.05, \"sigma_pitch_deg\": 0.05,\n"
                   " \"time_utc\": \"2024-05-01T21:30:00Z\"}\n");
    fx_write_text(px, "id,x_px,y_px,sigma_px\nA,959.5,539.5,0.3\nB,100,800,1\nUP,959.5,100,1\n");
    /* PLplot's cairo driver leaves fontconfig's caches allocated at exit: suppress those
     * (third-party) leaks only, when this runs under LeakSanitizer */
    char supp[1024], cmd[8192];
    snprintf(supp, sizeof supp, "%s", fx_tmp("lsan.supp"));
    fx_write_text(supp, "leak:libfontconfig.so\nleak:libltdl.so\n");
    snprintf(cmd, sizeof cmd, "LSAN_OPTIONS=suppressions=%s %s locate --station %s --pixels %s "
             "--light-height-m 30 --survey s1 -o %s --map %s", supp, test_bin(), st, px, res, fx_tmp("m.png"));
    int rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 0 && fx_contains(out, "located 2 of 3 lights"), "%d: %s", rc, out);
    CHECK(fx_contains(out, "light UP: not located (above_horizon)"));
    /* the file holds what the library computes for the same input */
    gis_station s;
    CHECK_OK(gis_station_read(st, &s));
    gis_fix fx;
    CHECK_OK(gis_locate(&s.cam, 100, 800, 1.0, 30.0, NULL, &fx));
    json_error_t e;
    json_t *root = json_load_file(res, 0, &e);
    CHECK(root != NULL);
    if (root) {
        json_t *fs = json_object_get(root, "features");
        CHECK(json_array_size(fs) == 3);
        json_t *f1 = json_array_get(fs, 1), *pr = json_object_get(f1, "properties");
        json_t *c = json_object_get(json_object_get(f1, "geometry"), "coordinates");
        CHECK(!strcmp(json_string_value(json_object_get(pr, "id")), "B"));
        CHECK(!strcmp(json_string_value(json_object_get(pr, "survey")), "s1"));
        CHECK(!strcmp(json_string_value(json_object_get(pr, "time")), "2024-05-01T21:30:00Z"));
        /* GeoJSON keeps 7 decimals: within 5e-8 deg (half the last digit) */
        CHECK_NEAR(json_real_value(json_array_get(c, 0)), fx.lon_deg, 5.000001e-8);
        CHECK_NEAR(json_real_value(json_array_get(c, 1)), fx.lat_deg, 5.000001e-8);
        CHECK_NEAR(json_real_value(json_object_get(pr, "err_major_m")), fx.ellipse.semi_major_m, 1e-9);
        CHECK(json_is_null(json_object_get(json_array_get(fs, 2), "geometry")));
        json_decref(root);
    }
    /* GeoPackage through the CLI validates too */
    const char *gpkg = fx_tmp("o.gpkg");
    snprintf(cmd, sizeof cmd, "%s locate --station %s --pixels %s --format gpkg -o %s && "
             "/usr/bin/python3 /usr/lib/python3/dist-packages/osgeo_utils/samples/validate_gpkg.py --extra %s",
             test_bin(), st, px, gpkg, gpkg);
    rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 0, "%s", out);
    /* --help, usage errors (2) and bad input (1, one line naming file, line and field) */
    snprintf(cmd, sizeof cmd, "%s locate --help", test_bin());
    CHECK(test_run(cmd, out, sizeof out) == 0 && fx_contains(out, "usage: gridsurvey locate"));
    snprintf(cmd, sizeof cmd, "%s locate --station %s -o %s", test_bin(), st, res);
    CHECK(test_run(cmd, out, sizeof out) == 2);
    fx_write_text(px, "id,x_px,y_px\nA,1,2\nB,1e,2\n");
    snprintf(cmd, sizeof cmd, "%s locate --station %s --pixels %s -o %s", test_bin(), st, px, res);
    rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 1 && fx_contains(out, "pixels.csv:3: x_px: expected a finite number, got '1e'"), "%d: %s", rc, out);
    fx_write_text(px, "id,x_px,y_px\nA,1,2\nB,0x10,2\n");   /* (was read as 16) */
    rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 1 && fx_contains(out, "pixels.csv:3: x_px: expected a finite number, got '0x10'"), "%d: %s", rc, out);
    /* an id twice (two lights of one name in every export), a control character in one (the
     * exporters refused it after the work) */
    fx_write_text(px, "id,x_px,y_px\nB,1,2\nA,3,4\nC,5,6\nA,7,8\nB,9,9\n");
    rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 1 && fx_count_lines(out) == 1 &&
              fx_contains(out, "pixels.csv:5: id 'A': given on line 3 already"), "%d: %s", rc, out);
    fx_write_text(px, "id,x_px,y_px\nA,1,2\nB\tC,3,4\n");
    rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 1 && fx_contains(out, "pixels.csv:3: id: expected 1 to"), "%d: %s", rc, out);
    fx_write_text(px, "id,x,y\nA,1,2\n");
    rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 1 && fx_contains(out, "pixels.csv:1: header column 2 is 'x'"), "%d: %s", rc, out);
    fx_write_text(px, "id,x_px,y_px\nA,1,2\n");
    fx_write_text(st, "{\"lat_deg\": 40.0, \"lon_deg\": -75.0,\n \"height_m\": 120.0,\n \"heading_deg\": 30,\n"
                   " \"pitch_deg\": -95, \"focal_px\": 2000, \"cx_px\": 959.5, \"cy_px\": 539.5}\n");
    rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 1 && fx_contains(out, "station.json:4: field pitch_deg: pitch_deg = -95"), "%d: %s", rc, out);
    CHECK(fx_count_of(out, "\n") == 1);
    /* an output format it cannot tell is a usage error, as export's */
    snprintf(cmd, sizeof cmd, "%s locate --station %s --pixels %s -o %s", test_bin(), st, px, fx_tmp("x.shp"));
    CHECK(test_run(cmd, out, sizeof out) == 2 && fx_contains(out, "cannot tell the format"));
    /* --format against the extension of another format: GeoJSON was written to x.kml; a name
     * without a known extension takes any format, and .json is GeoJSON's */
    fx_write_text(st, "{\"lat_deg\": 40.0, \"lon_deg\": -75.0,\n \"height_m\": 120.0,\n \"heading_deg\": 30,\n"
                   " \"pitch_deg\": -10, \"focal_px\": 2000, \"cx_px\": 959.5, \"cy_px\": 539.5}\n");
    snprintf(cmd, sizeof cmd, "%s locate --station %s --pixels %s -o %s --format geojson", test_bin(), st, px,
             fx_tmp("x.kml"));
    rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 2 && fx_count_lines(out) == 1 && fx_contains(out, "--format geojson but ") &&
              fx_contains(out, "x.kml's extension is another format's") && !fx_exists(fx_tmp("x.kml")), "%d: %s", rc, out);
    snprintf(cmd, sizeof cmd, "%s locate --station %s --pixels %s -o %s --format geojson", test_bin(), st, px,
             fx_tmp("x.json"));
    CHECK(test_run(cmd, out, sizeof out) == 0 && fx_exists(fx_tmp("x.json")));
    snprintf(cmd, sizeof cmd, "%s locate --station %s --pixels %s -o %s --format csv", test_bin(), st, px,
             fx_tmp("x.out"));
    CHECK(test_run(cmd, out, sizeof out) == 0 && fx_exists(fx_tmp("x.out")));
}

/* A station with psf_sigma_px (as every capture.json's own, which `gridsurvey run` uses) has a
 * sigma_px that is only the calibration residual (0 when not given): each light's centroid
 * sigma comes from its SNR, which a pixels CSV does not have. Without a sigma_px column,
 * locate wrote every error ellipse as 0 m; now it asks for the column, naming the file, line
 * and field, and writes nothing. With the column, the ellipse is the library's at that sigma. */
TEST(gis_cli_locate_with_a_psf_station_needs_each_light_sigma)
{
    char st[1024], px[1024], res[1024], cmd[4096];
    snprintf(st, sizeof st, "%s", fx_tmp("psf-station.json"));
    snprintf(px, sizeof px, "%s", fx_tmp("psf-pixels.csv"));
    snprintf(res, sizeof res, "%s", fx_tmp("psf-out.geojson"));
    fx_write_text(st, "{\"lat_deg\": 32.794, \"lon_deg\": 34.99, \"height_m\": 470.0,\n"
                   " \"heading_deg\": 52, \"pitch_deg\": -7.2, \"focal_px\": 4000, \"cx_px\": 799.5,\n"
                   " \"cy_px\": 449.5, \"psf_sigma_px\": 0.8}\n");
    fx_write_text(px, "id,x_px,y_px\nA,800,500\n");
    snprintf(cmd, sizeof cmd, "%s locate --station %s --pixels %s --light-height-m 30 -o %s",
             test_bin(), st, px, res);
    int rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 1 && fx_count_lines(out) == 1 && fx_contains(out, "psf-pixels.csv:2: sigma_px:") &&
              fx_contains(out, "psf_sigma_px"), "%d: %s", rc, out);
    CHECK(!fx_exists(res));
    fx_write_text(px, "id,x_px,y_px,sigma_px\nA,800,500,0.25\n");
    rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 0, "%d: %s", rc, out);
    gis_station s;
    CHECK_OK(gis_station_read(st, &s));
    gis_fix fx;
    CHECK_OK(gis_locate(&s.cam, 800, 500, 0.25, 30.0, NULL, &fx));
    CHECK(fx.ellipse.semi_major_m > 0.0);
    json_error_t e;
    json_t *root = json_load_file(res, 0, &e);
    CHECK(root != NULL);
    if (root) {
        json_t *pr = json_object_get(json_array_get(json_object_get(root, "features"), 0), "properties");
        CHECK_NEAR(json_real_value(json_object_get(pr, "err_major_m")), fx.ellipse.semi_major_m, 1e-9);
        json_decref(root);
    }
}

/* Jansson's allocator failing at its n-th call (json_set_alloc_funcs). */
static long jansson_calls, jansson_fail_at;
static void *jansson_failing_malloc(size_t n)
{
    return ++jansson_calls == jansson_fail_at ? NULL : malloc(n);
}

/* The GeoJSON writer with Jansson's n-th allocation failing, for every n: it fails with
 * GS_ENOMEM leaving the older file, or writes the same bytes as without the failure. Through
 * json_dumps, a failed append of an object's key to Jansson's buffer was ignored and the
 * document written without it, exit 0 (found by the fault-injection sweep, #16). */
TEST(geojson_export_allocation_failure_never_drops_a_property)
{
    gis_light l[6];
    size_t n = sample_lights(l);
    char ref[1100], path[1100];
    snprintf(ref, sizeof ref, "%s", fx_tmp("ref.geojson"));
    snprintf(path, sizeof path, "%s", fx_tmp("out.geojson"));
    CHECK_OK(gis_export_geojson(l, n, ref));
    size_t ref_size = 0;
    char *want = fx_read_file(ref, &ref_size);
    long failed = 0, points = 0;
    for (jansson_fail_at = 1;; jansson_fail_at++) {
        fx_write_text(path, "old\n");
        jansson_calls = 0;
        json_set_alloc_funcs(jansson_failing_malloc, free);
        gs_status s = gis_export_geojson(l, n, path);
        json_set_alloc_funcs(malloc, free);
        if (jansson_calls < jansson_fail_at) break;   /* no failure any more: all tried */
        points++;
        size_t size = 0;
        char *got = fx_read_file(path, &size);
        if (s == GS_OK)
            CHECK_MSG(got && want && size == ref_size && !memcmp(got, want, size),
                      "allocation %ld failed, the export succeeded, and its file differs", jansson_fail_at);
        else
            CHECK_MSG(s == GS_ENOMEM && got && !strcmp(got, "old\n"), "allocation %ld: status %d, file %s",
                      jansson_fail_at, (int)s, got ? "changed" : "gone");
        failed += s != GS_OK;
        free(got);
    }
    CHECK(points > 100 && failed == points);
    free(want);
}
