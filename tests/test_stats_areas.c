/* test_stats_areas.c - `stats --clip AREAS.geojson [--by feature:FIELD]`, `--bbox`, combined
 * groupings and the six-phase columns (survey/stats.c, survey/areas.c). Oracles: a brute-force
 * even-odd ray-casting point-in-polygon count written here over the sites' positions read with
 * plain SQL (independent of GEOS), plain-SQL box counts, and the marginal sums of a combination. */
#include "survey/survey.h"
#include "tests/fixtures.h"
#include "tests/survey_fixture.h"
#include "tests/test.h"

#include <math.h>
#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Rings of [lon, lat] vertices (closed: last = first), grouped into polygons; a feature is one or
 * more polygons (the first ring of each its exterior, the others holes). */
typedef struct {
    int n;
    double v[8][2];
} ring;
typedef struct {
    const char *name;
    int polys;
    int rings[2];       /* rings per polygon */
    ring r[3];
} feature;

#define CLON 35.02
#define CLAT 32.80
#define D 0.004   /* ~ 400 m in latitude */

static const feature F[3] = {
    /* an L-shaped (concave) polygon with a square hole */
    {"F1", 1, {2, 0}, {{7, {{CLON - 3 * D, CLAT - 3 * D}, {CLON + 1 * D, CLAT - 3 * D}, {CLON + 1 * D, CLAT - 1 * D},
                              {CLON - 1 * D, CLAT - 1 * D}, {CLON - 1 * D, CLAT + 2 * D}, {CLON - 3 * D, CLAT + 2 * D},
                              {CLON - 3 * D, CLAT - 3 * D}}},
                       {5, {{CLON - 2.5 * D, CLAT - 2.5 * D}, {CLON - 1.5 * D, CLAT - 2.5 * D},
                            {CLON - 1.5 * D, CLAT - 1.5 * D}, {CLON - 2.5 * D, CLAT - 1.5 * D},
                            {CLON - 2.5 * D, CLAT - 2.5 * D}}}}},
    /* two triangles */
    {"F2", 2, {1, 1}, {{4, {{CLON + 1.5 * D, CLAT}, {CLON + 4 * D, CLAT}, {CLON + 2.5 * D, CLAT + 3 * D}, {CLON + 1.5 * D, CLAT}}},
                       {4, {{CLON - 4 * D, CLAT + 3 * D}, {CLON - 2 * D, CLAT + 4 * D}, {CLON - 4 * D, CLAT + 4.5 * D}, {CLON - 4 * D, CLAT + 3 * D}}}}},
    /* a square overlapping F1: points in both belong to F1 (first in the file) */
    {"F3", 1, {1, 0}, {{5, {{CLON - 2 * D, CLAT - 2 * D}, {CLON + 3 * D, CLAT - 2 * D}, {CLON + 3 * D, CLAT - 4 * D},
                              {CLON - 2 * D, CLAT - 4 * D}, {CLON - 2 * D, CLAT - 2 * D}}}}},
};

static int ring_has(const ring *r, double lon, double lat)
{
    int in = 0;
    for (int i = 0, j = r->n - 2; i < r->n - 1; j = i++) {
        double xi = r->v[i][0], yi = r->v[i][1], xj = r->v[j][0], yj = r->v[j][1];
        if ((yi > lat) != (yj > lat) && lon < (xj - xi) * (lat - yi) / (yj - yi) + xi) in = !in;
    }
    return in;
}

/* Brute force: the first feature whose polygon has the point (even-odd over its rings). */
static int brute_feature(double lon, double lat)
{
    for (int f = 0; f < 3; f++) {
        int k = 0;
        for (int p = 0; p < F[f].polys; p++) {
            int in = 0;
            for (int r = 0; r < F[f].rings[p]; r++) in ^= ring_has(&F[f].r[k + r], lon, lat);
            k += F[f].rings[p];
            if (in) return f;
        }
    }
    return -1;
}

static void write_areas(const char *path)
{
    char text[8192];
    size_t u = (size_t)snprintf(text, sizeof text, "{\"type\": \"FeatureCollection\", \"features\": [");
    for (int f = 0; f < 3; f++) {
        u += (size_t)snprintf(text + u, sizeof text - u, "%s{\"type\": \"Feature\", \"properties\": {\"feeder\": \"%s\"}, "
                              "\"geometry\": {\"type\": \"%s\", \"coordinates\": %s", f ? ", " : "", F[f].name,
                              F[f].polys > 1 ? "MultiPolygon" : "Polygon", F[f].polys > 1 ? "[" : "");
        int k = 0;
        for (int p = 0; p < F[f].polys; p++) {
            u += (size_t)snprintf(text + u, sizeof text - u, "%s[", p ? ", " : "");
            for (int r = 0; r < F[f].rings[p]; r++, k++) {
                u += (size_t)snprintf(text + u, sizeof text - u, "%s[", r ? ", " : "");
                for (int i = 0; i < F[f].r[k].n; i++)
                    u += (size_t)snprintf(text + u, sizeof text - u, "%s[%.10f, %.10f]", i ? ", " : "",
                                          F[f].r[k].v[i][0], F[f].r[k].v[i][1]);
                u += (size_t)snprintf(text + u, sizeof text - u, "]");
            }
            u += (size_t)snprintf(text + u, sizeof text - u, "]");
        }
        u += (size_t)snprintf(text + u, sizeof text - u, "%s}}", F[f].polys > 1 ? "]" : "");
    }
    snprintf(text + u, sizeof text - u, "]}\n");
    fx_write_text(path, text);
}

/* Per feature (and 3 = inside none, 4 = the bbox), counts of lights and classes from SQL. */
typedef struct {
    long lights, unknown, other, n[3];
} tally;

static void add_class(tally *t, const char *cls)
{
    t->lights++;
    if (!strcmp(cls, "unknown")) t->unknown++;
    else if (!strcmp(cls, "other")) t->other++;
    else t->n[atoi(cls) / 120]++;
}

/* The CSV row of group name (its counts), 0 if absent. */
static int csv_row(const char *out, const char *group, tally *t)
{
    char pat[128];
    snprintf(pat, sizeof pat, "\n%s,", group);
    const char *p = strstr(out, pat);
    if (!p) return 0;
    p += strlen(pat);
    double lat, lon;
    long below;
    /* group,lat_deg,lon_deg,lights,below,unknown,other,n0,n120,n240 */
    if (*p == ',') p++;
    else if (sscanf(p, "%lf", &lat) == 1) p = strchr(p, ',') + 1;
    if (*p == ',') p++;
    else if (sscanf(p, "%lf", &lon) == 1) p = strchr(p, ',') + 1;
    return sscanf(p, "%ld,%ld,%ld,%ld,%ld,%ld,%ld", &t->lights, &below, &t->unknown, &t->other, &t->n[0],
                  &t->n[1], &t->n[2]) == 7;
}

static void check_tally(const char *what, const tally *got, const tally *want)
{
    CHECK_MSG(got->lights == want->lights && got->unknown == want->unknown && got->other == want->other &&
              got->n[0] == want->n[0] && got->n[1] == want->n[1] && got->n[2] == want->n[2],
              "%s: lights %ld/%ld unknown %ld/%ld other %ld/%ld n %ld,%ld,%ld / %ld,%ld,%ld", what,
              got->lights, want->lights, got->unknown, want->unknown, got->other, want->other, got->n[0],
              got->n[1], got->n[2], want->n[0], want->n[1], want->n[2]);
}

TEST(stats_clip_equals_brute_force_point_in_polygon)
{
    const char *db = fx_tmp("clip.sqlite"), *areas = fx_tmp("areas.geojson");
    srv_synth_opts so = survey_fx_synth_opts("clip", 30, 200, 21);
    so.lat_deg = CLAT;
    so.lon_deg = CLON;
    so.view_half_width_m = 2000;
    survey_fx_synth(db, &so);
    write_areas(areas);
    /* the oracle: every located site, its position and class from plain SQL */
    sqlite3 *h = NULL;
    CHECK(sqlite3_open_v2(db, &h, SQLITE_OPEN_READONLY, NULL) == SQLITE_OK);
    sqlite3_stmt *q = NULL;
    CHECK(sqlite3_prepare_v2(h, "SELECT lon_deg, lat_deg, phase_class FROM site_phase WHERE lat_deg IS NOT NULL",
                             -1, &q, NULL) == SQLITE_OK);
    tally want[5];
    memset(want, 0, sizeof want);
    const double bbox[4] = {CLON - 0.01, CLAT - 0.005, CLON + 0.003, CLAT + 0.012};
    while (q && sqlite3_step(q) == SQLITE_ROW) {
        double lon = sqlite3_column_double(q, 0), lat = sqlite3_column_double(q, 1);
        const char *cls = (const char *)sqlite3_column_text(q, 2);
        int f = brute_feature(lon, lat);
        add_class(&want[f < 0 ? 3 : f], cls);
        if (lon >= bbox[0] && lon <= bbox[2] && lat >= bbox[1] && lat <= bbox[3]) add_class(&want[4], cls);
    }
    sqlite3_finalize(q);
    long sites = survey_fx_query_long(h, "SELECT count(*) FROM light_sites");
    sqlite3_close(h);
    CHECK_MSG(want[0].lights > 100 && want[1].lights > 50 && want[2].lights > 50, "%ld %ld %ld",
              want[0].lights, want[1].lights, want[2].lights);
    char out[65536];
    int rc = fx_run(out, sizeof out, "%s stats --db %s --clip %s --by feature:feeder --format csv", test_bin(), db, areas);
    CHECK_MSG(rc == 0, "%d: %s", rc, out);
    for (int f = 0; f < 3; f++) {
        tally got;
        memset(&got, 0, sizeof got);
        CHECK_MSG(csv_row(out, F[f].name, &got), "no row %s in %s", F[f].name, out);
        check_tally(F[f].name, &got, &want[f]);
    }
    /* -o: a polygon layer GDAL reads (ogrinfo): the CSV, its .csvt types and .prj */
    const char *csv = fx_tmp("feeders.csv");
    rc = fx_run(out, sizeof out, "%s stats --db %s --clip %s --by feature:feeder --format csv -o %s", test_bin(),
                db, areas, csv);
    CHECK_MSG(rc == 0 && fx_exists(fx_tmp("feeders.csvt")) && fx_exists(fx_tmp("feeders.prj")), "%d: %s", rc, out);
    rc = fx_run(out, sizeof out, "ogrinfo -ro -al -so '%s'", csv);
    CHECK_MSG(rc == 0 && strstr(out, "Feature Count: 3") && strstr(out, "WGS 84") &&
              strstr(out, "n0: Integer") && strstr(out, "share0: Real") && strstr(out, "Geometry Column = geom_WKT"),
              "%d: %s", rc, out);
    /* the extent: the areas' vertices span CLON -+ 4 D, CLAT - 4 D .. CLAT + 4.5 D */
    char ext[160];
    snprintf(ext, sizeof ext, "Extent: (%.6f, %.6f) - (%.6f, %.6f)", CLON - 4 * D, CLAT - 4 * D, CLON + 4 * D,
             CLAT + 4.5 * D);
    CHECK_MSG(strstr(out, ext) != NULL, "expected %s in %s", ext, out);
    rc = fx_run(out, sizeof out, "ogrinfo -ro -al '%s'", csv);
    CHECK_MSG(rc == 0, "%d: %s", rc, out);
    for (int f = 0; f < 3; f++) {
        char key[64];
        snprintf(key, sizeof key, "group (String) = %s\n", F[f].name);
        const char *p = strstr(out, key), *next = p ? strstr(p, "OGRFeature(") : NULL;
        CHECK_MSG(p != NULL, "no feature %s in %s", F[f].name, out);
        if (!p) continue;
        long v[4] = {-1, -1, -1, -1};
        static const char *const fld[4] = {"lights (Integer) = ", "n0 (Integer) = ", "n120 (Integer) = ",
                                           "n240 (Integer) = "};
        for (int k = 0; k < 4; k++) {
            const char *at = strstr(p, fld[k]);
            if (at && (!next || at < next)) v[k] = atol(at + strlen(fld[k]));
        }
        CHECK_MSG(v[0] == want[f].lights && v[1] == want[f].n[0] && v[2] == want[f].n[1] && v[3] == want[f].n[2],
                  "%s: ogrinfo %ld %ld %ld %ld", F[f].name, v[0], v[1], v[2], v[3]);
        const char *g = strstr(p, F[f].polys > 1 ? "\n  MULTIPOLYGON ((" : "\n  POLYGON ((");
        CHECK_MSG(g && (!next || g < next), "%s: geometry type", F[f].name);
    }
    /* -o needs --format csv and a .csv name */
    rc = fx_run(out, sizeof out, "%s stats --db %s -o %s", test_bin(), db, csv);
    CHECK_MSG(rc == 2 && strstr(out, "NAME.csv"), "%d: %s", rc, out);
    /* --clip alone: one group, the union */
    rc = fx_run(out, sizeof out, "%s stats --db %s --clip %s --format csv", test_bin(), db, areas);
    tally got, uni = want[0];
    for (int f = 1; f < 3; f++) {
        uni.lights += want[f].lights;
        uni.unknown += want[f].unknown;
        uni.other += want[f].other;
        for (int k = 0; k < 3; k++) uni.n[k] += want[f].n[k];
    }
    memset(&got, 0, sizeof got);
    CHECK(rc == 0 && csv_row(out, "all", &got));
    check_tally("union", &got, &uni);
    CHECK(uni.lights + want[3].lights <= sites);
    /* --bbox */
    rc = fx_run(out, sizeof out, "%s stats --db %s --bbox %.10f,%.10f,%.10f,%.10f --format csv", test_bin(), db,
                bbox[0], bbox[1], bbox[2], bbox[3]);
    memset(&got, 0, sizeof got);
    CHECK_MSG(rc == 0 && csv_row(out, "all", &got), "%d: %s", rc, out);
    check_tally("bbox", &got, &want[4]);
    /* bad areas: one line naming the file and the feature */
    fx_write_text(fx_tmp("point.geojson"), "{\"type\": \"FeatureCollection\", \"features\": [{\"type\": "
                  "\"Feature\", \"properties\": {}, \"geometry\": {\"type\": \"Point\", \"coordinates\": [35, 32]}}]}");
    rc = fx_run(out, sizeof out, "%s stats --db %s --clip %s 2>&1", test_bin(), db, fx_tmp("point.geojson"));
    CHECK_MSG(rc == 1 && strstr(out, "point.geojson: feature 0: geometry type 'Point'"), "%d: %s", rc, out);
    rc = fx_run(out, sizeof out, "%s stats --db %s --clip %s --by feature:nope 2>&1", test_bin(), db, areas);
    CHECK_MSG(rc == 1 && strstr(out, "feature 0: property 'nope'"), "%d: %s", rc, out);
    rc = fx_run(out, sizeof out, "%s stats --db %s --by feature:feeder 2>&1", test_bin(), db);
    CHECK_MSG(rc == 2 && strstr(out, "needs --clip"), "%d: %s", rc, out);
}

/* --by technology,cell:500: each combination group sums to its --by cell and --by technology
 * margins; six-phase lights get their own counts. */
TEST(stats_combined_groupings_and_six_phases)
{
    const char *path = fx_tmp("combo.sqlite");
    srv_synth_opts so = survey_fx_synth_opts("combo", 20, 150, 5);
    so.view_half_width_m = 2000;
    survey_fx_synth(path, &so);
    srv_db *db = NULL;
    CHECK_OK(srv_db_open(path, SRV_DB_READ, &db));
    if (!db) return;
    srv_stats_opts o;
    srv_phase_stats *gc = NULL, *gt = NULL, *gb = NULL;
    size_t nc = 0, nt = 0, nb = 0;
    srv_stats_opts_default(&o);
    CHECK_OK(srv_stats_parse_by("technology,cell:500", &o));
    CHECK(o.by == SRV_BY_TECHNOLOGY && o.n_then == 1 && o.then[0] == SRV_BY_CELL && o.cell_m == 500);
    CHECK_OK(srv_stats_compute(db, &o, &gb, &nb, NULL));
    srv_stats_opts_default(&o);
    CHECK_OK(srv_stats_parse_by("cell:500", &o));
    CHECK_OK(srv_stats_compute(db, &o, &gc, &nc, NULL));
    srv_stats_opts_default(&o);
    CHECK_OK(srv_stats_parse_by("technology", &o));
    CHECK_OK(srv_stats_compute(db, &o, &gt, &nt, NULL));
    CHECK(nb > nc && nb > nt);
    for (size_t i = 0; i < nc; i++) {
        long lights = 0, n0 = 0;
        for (size_t j = 0; j < nb; j++) {
            const char *slash = strstr(gb[j].group, " / ");
            if (slash && !strcmp(slash + 3, gc[i].group)) {
                lights += gb[j].lights;
                n0 += gb[j].n[0];
                CHECK(gb[j].lat_deg == gc[i].lat_deg && gb[j].lon_deg == gc[i].lon_deg);
            }
        }
        CHECK_MSG(lights == gc[i].lights && n0 == gc[i].n[0], "cell %s: %ld vs %ld", gc[i].group, lights, gc[i].lights);
    }
    for (size_t i = 0; i < nt; i++) {
        long lights = 0;
        size_t len = strlen(gt[i].group);
        for (size_t j = 0; j < nb; j++)
            if (!strncmp(gb[j].group, gt[i].group, len) && !strncmp(gb[j].group + len, " / ", 3)) lights += gb[j].lights;
        long located = gt[i].lights;   /* the technology margin includes lights without a position */
        CHECK_MSG(lights <= located && lights > 0, "technology %s: %ld vs %ld", gt[i].group, lights, located);
    }
    free(gb);
    free(gc);
    free(gt);
    srv_stats_opts_default(&o);
    CHECK(srv_stats_parse_by("technology,technology", &o) == GS_EINVAL);
    CHECK(srv_stats_parse_by("all,cell:50", &o) == GS_EINVAL);
    CHECK(srv_stats_parse_by("technology,cell:50,survey,feature:x", &o) == GS_EINVAL);
    srv_db_close(db);
    /* six phases: 30/150/270 within 15 deg in their own columns, not "other" */
    int64_t sid;
    srv_db *w = survey_fx_create(fx_tmp("six.sqlite"), "six", &sid);
    if (!w) return;
    static const double ph[] = {0, 30, 44, 150, 162, 166, 270, 282, 120, 240, 60, NAN};
    enum { N = sizeof ph / sizeof *ph };
    srv_light_row l[N];
    for (int i = 0; i < N; i++) l[i] = survey_fx_light(i, 10.0 * i, 1, ph[i], 0.99);
    srv_capture_data cd = survey_fx_capture(sid, "c", l, NULL, N);
    CHECK_OK(srv_db_add_capture(w, &cd, NULL, NULL));
    srv_stats_opts_default(&o);
    CHECK_OK(srv_stats_compute(w, &o, &gb, &nb, NULL));
    /* 30, 44 -> 30; 150, 162 -> 150; 166 (16 deg off) -> other; 270, 282 -> 270; 60 -> other */
    CHECK(nb == 1 && gb[0].n30[0] == 2 && gb[0].n30[1] == 2 && gb[0].n30[2] == 2 && gb[0].other == 2 &&
          gb[0].n[0] == 1 && gb[0].n[1] == 1 && gb[0].n[2] == 1 && gb[0].unknown == 1 && gb[0].total == 3);
    free(gb);
    srv_db_close(w);
    char out[8192];
    int rc = fx_run(out, sizeof out, "%s stats --db %s", test_bin(), fx_tmp("six.sqlite"));
    CHECK_MSG(rc == 0 && strstr(out, "| 30 deg | 150 deg | 270 deg |") && strstr(out, "| 2 | 2 | 2 |"), "%s", out);
    rc = fx_run(out, sizeof out, "%s stats --db %s --format csv", test_bin(), fx_tmp("six.sqlite"));
    CHECK_MSG(rc == 0 && strstr(out, ",n30,n150,n270\n") && strstr(out, ",2,2,2\n"), "%s", out);
}

/* srv_areas_find and srv_areas_wkt on a square's edges (docs: a feature covers its boundary),
 * a longitude given 360 deg over, labels of numbers and booleans as JSON writes them, and a
 * vertex of nine decimals written back to nine decimals. */
TEST(stats_areas_boundary_labels_and_wkt_digits)
{
    const char *path = fx_tmp("edges.geojson");
    fx_write_text(path, "{\"type\": \"FeatureCollection\", \"features\": ["
                  "{\"type\": \"Feature\", \"properties\": {\"f\": 1234567.5}, \"geometry\": {\"type\": \"Polygon\", "
                  "\"coordinates\": [[[35.0, 32.8], [35.01, 32.8], [35.01, 32.81], [35.0, 32.81], [35.0, 32.8]]]}}, "
                  "{\"type\": \"Feature\", \"properties\": {\"f\": true}, \"geometry\": {\"type\": \"Polygon\", "
                  "\"coordinates\": [[[36.0, 32.8], [36.123456789, 32.8], [36.0, 32.9], [36.0, 32.8]]]}}]}\n");
    srv_areas *a = NULL;
    CHECK_OK(srv_areas_load(path, "f", &a));
    if (!a) return;
    CHECK(!strcmp(srv_areas_label(a, 0), "1234567.5") && !strcmp(srv_areas_label(a, 1), "true"));
    CHECK(srv_areas_find(a, 32.805, 35.005) == 0);
    CHECK(srv_areas_find(a, 32.81, 35.005) == 0);    /* north edge */
    CHECK(srv_areas_find(a, 32.805, 35.01) == 0);    /* east edge */
    CHECK(srv_areas_find(a, 32.81, 35.01) == 0);     /* north-east corner */
    CHECK(srv_areas_find(a, 32.8, 35.0) == 0);       /* south-west corner */
    CHECK(srv_areas_find(a, 32.805, 35.0100001) == -1);
    CHECK(srv_areas_find(a, 32.805, 395.005) == 0);  /* 35.005 + 360 */
    char *wkt = NULL;
    CHECK_OK(srv_areas_wkt(a, "true", &wkt));
    CHECK_MSG(wkt && strstr(wkt, "36.123456789 32.8"), "%s", wkt ? wkt : "(null)");
    free(wkt);
    srv_areas_free(a);
}

/* A light exactly on an area's edge or vertex is in it, whatever the edge's longitude: the point
 * used to go through gs_wrap180, whose (x + 180) - 180 moved an in-range longitude by an ulp
 * (35.02 became 35.02000000000001, outside a square whose east edge is 35.02; 35.01 happened to
 * round inwards). Oracle: the documented rule (a feature covers its boundary), for squares whose
 * east edges are the longitudes 35.001 ... 35.099 and -35.099 ... -35.001. */
TEST(stats_areas_boundary_at_any_longitude)
{
    const char *path = fx_tmp("edges_sweep.geojson");
    for (int sign = -1; sign <= 1; sign += 2)
        for (int k = 1; k < 100; k++) {
            double e = sign * (35.0 + k / 1000.0), w = e - 0.01;
            char text[512];
            snprintf(text, sizeof text, "{\"type\": \"FeatureCollection\", \"features\": [{\"type\": \"Feature\", "
                     "\"properties\": {}, \"geometry\": {\"type\": \"Polygon\", \"coordinates\": [[[%.3f, 32.8], "
                     "[%.3f, 32.8], [%.3f, 32.81], [%.3f, 32.81], [%.3f, 32.8]]]}}]}\n", w, e, e, w, w);
            fx_write_text(path, text);
            srv_areas *a = NULL;
            CHECK_OK(srv_areas_load(path, NULL, &a));
            if (!a) return;
            double lon_e, lon_w;
            char num[32];
            snprintf(num, sizeof num, "%.3f", e);
            lon_e = strtod(num, NULL);   /* the edge's longitude exactly as the file holds it */
            snprintf(num, sizeof num, "%.3f", w);
            lon_w = strtod(num, NULL);
            CHECK_MSG(srv_areas_find(a, 32.805, lon_e) == 0, "east edge %.17g", lon_e);
            CHECK_MSG(srv_areas_find(a, 32.81, lon_e) == 0, "north-east corner %.17g", lon_e);
            CHECK_MSG(srv_areas_find(a, 32.8, lon_w) == 0, "south-west corner %.17g", lon_w);
            CHECK_MSG(srv_areas_find(a, 32.805, lon_w) == 0, "west edge %.17g", lon_w);
            srv_areas_free(a);
        }
}

/* A light on the 180 deg meridian is stored at longitude -180 (gs_wrap180), but a polygon that
 * only reaches the meridian from the west draws it at +180: it did not cover the light (its
 * bounding box stops at +180). Now -180 is also tried as +180. Two squares, one each side of
 * the meridian, each with the meridian as an edge; lights at -180 and +180 and one degree away:
 * on the meridian the first square in the file holds it, whichever side it lies on. */
TEST(stats_areas_hold_the_180_meridian_from_either_side)
{
    const char *path = fx_tmp("meridian.geojson");
    fx_write_text(path, "{\"type\": \"FeatureCollection\", \"features\": ["
                        "{\"type\": \"Feature\", \"properties\": {\"name\": \"west\"}, \"geometry\": {\"type\": \"Polygon\", "
                        "\"coordinates\": [[[179, -17], [180, -17], [180, -16], [179, -16], [179, -17]]]}},"
                        "{\"type\": \"Feature\", \"properties\": {\"name\": \"east\"}, \"geometry\": {\"type\": \"Polygon\", "
                        "\"coordinates\": [[[-180, -17], [-179, -17], [-179, -16], [-180, -16], [-180, -17]]]}}]}\n");
    srv_areas *a = NULL;
    CHECK_OK(srv_areas_load(path, NULL, &a));
    if (!a) return;
    CHECK(srv_areas_find(a, -16.5, 180.0) == 0);
    CHECK(srv_areas_find(a, -16.5, -180.0) == 0);
    CHECK(srv_areas_find(a, -16.5, 540.0) == 0);
    CHECK(srv_areas_find(a, -16.5, 179.5) == 0);
    CHECK(srv_areas_find(a, -16.5, -179.5) == 1);
    CHECK(srv_areas_find(a, -16.5, 178.5) == -1);
    CHECK(srv_areas_find(a, -15.5, 180.0) == -1);
    srv_areas_free(a);
    /* the east square alone: the meridian is its edge at -180 */
    fx_write_text(path, "{\"type\": \"FeatureCollection\", \"features\": ["
                        "{\"type\": \"Feature\", \"properties\": {\"name\": \"east\"}, \"geometry\": {\"type\": \"Polygon\", "
                        "\"coordinates\": [[[-180, -17], [-179, -17], [-179, -16], [-180, -16], [-180, -17]]]}}]}\n");
    CHECK_OK(srv_areas_load(path, NULL, &a));
    if (!a) return;
    CHECK(srv_areas_find(a, -16.5, 180.0) == 0);
    CHECK(srv_areas_find(a, -16.5, -180.0) == 0);
    srv_areas_free(a);
}
