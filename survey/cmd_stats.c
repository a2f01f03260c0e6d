/* cmd_stats.c - `gridsurvey stats`: phase-balance statistics of a survey database
 * (survey/stats.c; definitions in docs/survey-db.md). */
#include "survey/internal.h"

#include <getopt.h>
#include <jansson.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char stats_usage[] =
    "usage: gridsurvey stats (--db DB | --pg CONNINFO) [--by G[,G2[,G3]]] [--clip AREAS.geojson]\n"
    "                        [--bbox MINLON,MINLAT,MAXLON,MAXLAT] [--survey NAME]\n"
    "                        [--min-phase-confidence X] [--format table|json|csv] [-o F.csv]\n"
    "                        [--detections]\n"
    "\n"
    "Phase balance of the surveyed lights: per group, the lights on each grid phase (0, 120,\n"
    "240 deg, within 20 deg), their shares with 95 % Wilson intervals, a chi-square test of the\n"
    "uniform split (2 dof) and the imbalance index max |share - 1/3| / (1/3) (0 = balanced,\n"
    "2 = all on one phase). Lights whose phase is ambiguous or unknown, or another phase, are\n"
    "counted apart and not in the shares; lights on 30/150/270 deg (six-phase surveys, within\n"
    "15 deg) get their own columns.\n"
    "\n"
    "  --db DB             the survey database (read-only)\n"
    "  --pg CONNINFO       or the shared PostGIS database `gridsurvey push` fills (a libpq\n"
    "                      connection string; the same numbers on the same data)\n"
    "  --by G              all (default), technology, survey, cell:SIZE_m (a local metric grid\n"
    "                      of SIZE_m cells around the lights' mean latitude; located lights\n"
    "                      only), feature:FIELD (per area of --clip, named by its property\n"
    "                      FIELD) or radius:LAT,LON,R_m (located lights within R_m metres,\n"
    "                      spherical distance); or up to three of technology, survey,\n"
    "                      cell:SIZE_m, feature:FIELD joined by commas (e.g.\n"
    "                      technology,cell:500): one group per combination, \"A / B\"\n"
    "  --clip FILE         only located lights inside the Polygon / MultiPolygon features of\n"
    "                      this GeoJSON FeatureCollection (WGS84; boundary included)\n"
    "  --bbox B            only located lights in MINLON,MINLAT,MAXLON,MAXLAT (degrees;\n"
    "                      MINLON > MAXLON crosses the antimeridian)\n"
    "  --survey NAME       only this survey\n"
    "  --min-phase-confidence X  leave out lights whose phase confidence (posterior of the\n"
    "                      phase, as one light in DELIGHT) is below X, in [0, 1] (default 0);\n"
    "                      in bad seeing it is capped below 1 though the phases are right\n"
    "                      (docs/recognition.md, limitations): pick X from bench accuracy's\n"
    "                      phase calibration\n"
    "  --format F          table (Markdown, default), json or csv; with --by feature:FIELD the\n"
    "                      CSV's last column, WKT, is each area's polygon (GDAL reads the\n"
    "                      file as a polygon layer: QGIS, ogr2ogr)\n"
    "  -o F.csv            write the CSV to F.csv (replaced atomically) instead of stdout, with\n"
    "                      GDAL's F.csvt (column types) and, with the WKT column, F.prj (WGS84)\n"
    "  --detections        count every stored detection; by default a light seen on several\n"
    "                      nights or captures (one light site) counts once, its detections'\n"
    "                      posteriors combined (docs/survey-db.md, \"Light sites\")\n"
    "  --help              this text\n"
    "\n"
    "Examples:\n"
    "  gridsurvey stats --db city.sqlite --by technology --min-phase-confidence 0.9\n"
    "  gridsurvey stats --db city.sqlite --clip feeders.geojson --by feature:feeder --format csv \\\n"
    "                   -o feeders-balance.csv\n";

typedef enum { FMT_TABLE, FMT_JSON, FMT_CSV } out_format;

static const char *part_name(const srv_stats_opts *o, srv_group_by by, char *buf, size_t size)
{
    switch (by) {
    case SRV_BY_ALL: return "all";
    case SRV_BY_TECHNOLOGY: return "technology";
    case SRV_BY_SURVEY: return "survey";
    case SRV_BY_CELL: snprintf(buf, size, "cell:%g", o->cell_m); return buf;
    case SRV_BY_FEATURE: snprintf(buf, size, "feature:%s", o->feature_field); return buf;
    case SRV_BY_RADIUS:
        snprintf(buf, size, "radius:%.7f,%.7f,%g", o->lat_deg, o->lon_deg, o->radius_m);
        return buf;
    }
    return "?";
}

/* The --by text, combinations joined by commas. */
static const char *by_name(const srv_stats_opts *o, char *buf, size_t size)
{
    char part[128];
    snprintf(buf, size, "%s", part_name(o, o->by, part, sizeof part));
    for (int i = 0; i < o->n_then; i++) {
        size_t used = strlen(buf);
        snprintf(buf + used, size - used, ",%s", part_name(o, o->then[i], part, sizeof part));
    }
    return buf;
}

static void pct(char *buf, size_t size, const srv_phase_stats *g, int i)
{
    if (g->total <= 0) snprintf(buf, size, "- (0)");
    else
        snprintf(buf, size, "%.1f %% [%.1f, %.1f] (%ld)", 100.0 * g->share[i], 100.0 * g->lo[i],
                 100.0 * g->hi[i], g->n[i]);
}

void srv_stats_print_table(const srv_phase_stats *g, size_t n, const srv_stats_opts *o, long ungrouped)
{
    int cells = o->by == SRV_BY_RADIUS;
    for (size_t i = 0; i < n; i++) cells |= !isnan(g[i].lat_deg);
    int six = 0;   /* six-phase columns when any light is on 30/150/270 deg */
    for (size_t i = 0; i < n; i++) six |= g[i].n30[0] || g[i].n30[1] || g[i].n30[2];
    printf("| group |%s lights | below | unknown | other | n | 0 deg | 120 deg | 240 deg |%s chi2 | p | imbalance |\n",
           cells ? " lat, lon |" : "", six ? " 30 deg | 150 deg | 270 deg |" : "");
    printf("|---|%s---:|---:|---:|---:|---:|---|---|---|%s---:|---:|---:|\n", cells ? "---|" : "",
           six ? "---:|---:|---:|" : "");
    for (size_t i = 0; i < n; i++) {
        char c[3][64], ll[64] = "", c6[64] = "";
        for (int k = 0; k < 3; k++) pct(c[k], sizeof c[k], &g[i], k);
        if (cells) snprintf(ll, sizeof ll, " %.6f, %.6f |", g[i].lat_deg, g[i].lon_deg);
        if (six) snprintf(c6, sizeof c6, " %ld | %ld | %ld |", g[i].n30[0], g[i].n30[1], g[i].n30[2]);
        printf("| %s |%s %ld | %ld | %ld | %ld | %ld | %s | %s | %s |%s", g[i].group, ll, g[i].lights,
               g[i].below, g[i].unknown, g[i].other, g[i].total, c[0], c[1], c[2], c6);
        if (g[i].total > 0)
            printf(" %.2f | %.3g%s | %.3f |\n", g[i].chi2, g[i].p_value,
                   g[i].flags & SRV_STATS_FEW ? " (few)" : "", g[i].imbalance);
        else
            printf(" - | - | - |\n");
    }
    printf("\nShares of the lights on a known 0/120/240 deg phase (n), 95 %% Wilson intervals; "
           "chi2: uniformity test (2 dof), p = exp(-chi2/2); imbalance = max |share - 1/3| / (1/3).\n");
    if (o->min_phase_confidence > 0.0)
        printf("below: phase confidence < %g (left out); ", o->min_phase_confidence);
    else
        printf("below: none (no phase-confidence threshold); ");
    printf("unknown: ambiguous or unrecognized phase; other: a phase not within 20 deg of 0/120/240%s.",
           six ? " nor 15 deg of 30/150/270 (the six-phase columns, counts outside the shares)" : "");
    if (ungrouped > 0) printf(" %ld lights without a position are in no cell.", ungrouped);
    int few = 0;
    for (size_t i = 0; i < n; i++) few |= (g[i].flags & SRV_STATS_FEW) != 0;
    printf("%s\n", few ? " (few): fewer than 5 expected per phase, p approximate." : "");
}

/* The CSV (RFC 4180) to f; with areas (--by feature:FIELD alone), a last column WKT holding
 * each group's area (srv_areas_wkt), which GDAL's CSV driver reads as the geometry. */
static gs_status print_csv(FILE *f, const srv_phase_stats *g, size_t n, const srv_areas *areas)
{
    fprintf(f, "group,lat_deg,lon_deg,lights,below_confidence,unknown,other,n0,n120,n240,n,"
            "share0,lo0,hi0,share120,lo120,hi120,share240,lo240,hi240,chi2,p_value,imbalance,flags,"
            "n30,n150,n270%s\n", areas ? ",WKT" : "");
    for (size_t i = 0; i < n; i++) {
        const srv_phase_stats *x = &g[i];
        int quote = strpbrk(x->group, ",\"\n") != NULL;
        if (quote) {
            fputc('"', f);
            for (const char *p = x->group; *p; p++) {
                if (*p == '"') fputc('"', f);
                fputc(*p, f);
            }
            fputc('"', f);
        } else {
            fputs(x->group, f);
        }
        double v[] = {x->lat_deg, x->lon_deg};
        for (int k = 0; k < 2; k++) isnan(v[k]) ? fprintf(f, ",") : fprintf(f, ",%.7f", v[k]);
        fprintf(f, ",%ld,%ld,%ld,%ld,%ld,%ld,%ld,%ld", x->lights, x->below, x->unknown, x->other, x->n[0],
                x->n[1], x->n[2], x->total);
        double r[] = {x->share[0], x->lo[0], x->hi[0], x->share[1], x->lo[1], x->hi[1], x->share[2],
                      x->lo[2], x->hi[2], x->chi2, x->p_value, x->imbalance};
        for (int k = 0; k < 12; k++) isnan(r[k]) ? fprintf(f, ",") : fprintf(f, ",%.10g", r[k]);
        fprintf(f, ",%u,%ld,%ld,%ld", x->flags, x->n30[0], x->n30[1], x->n30[2]);
        if (areas) {
            char *wkt = NULL;
            gs_status s = srv_areas_wkt(areas, x->group, &wkt);
            if (s != GS_OK) return s;
            fprintf(f, ",\"%s\"", wkt);   /* WKT has no quote to double */
            free(wkt);
        }
        fputc('\n', f);
    }
    return GS_OK;
}

/* GDAL's sidecars of a CSV NAME.csv: NAME.csvt, the column types (so counts import as
 * integers and WKT as the geometry), and NAME.prj, WGS84 (EPSG:4326 axes lon, lat). */
static gs_status write_sidecars(const char *csv_path, int wkt)
{
    char path[4200];
    size_t stem = strlen(csv_path) - 4;
    static const char prj[] = "GEOGCS[\"WGS 84\",DATUM[\"WGS_1984\",SPHEROID[\"WGS 84\",6378137,"
                              "298.257223563]],PRIMEM[\"Greenwich\",0],UNIT[\"degree\",0.0174532925199433]]";
    gs_atomic a;
    snprintf(path, sizeof path, "%.*s.csvt", (int)stem, csv_path);
    gs_status s = gs_atomic_open(&a, path, 1);
    if (s != GS_OK) return s;
    fputs("\"String\",\"Real\",\"Real\"", a.f);
    for (int k = 0; k < 8; k++) fputs(",\"Integer\"", a.f);
    for (int k = 0; k < 12; k++) fputs(",\"Real\"", a.f);
    for (int k = 0; k < 4; k++) fputs(",\"Integer\"", a.f);
    fputs(wkt ? ",\"WKT\"\n" : "\n", a.f);
    if ((s = gs_atomic_commit(&a)) != GS_OK || !wkt) return s;
    snprintf(path, sizeof path, "%.*s.prj", (int)stem, csv_path);
    if ((s = gs_atomic_open(&a, path, 1)) != GS_OK) return s;
    fputs(prj, a.f);
    return gs_atomic_commit(&a);
}

static json_t *real_or_null(double v)
{
    return isfinite(v) ? json_real(v) : json_null();
}

static int print_json(const srv_phase_stats *g, size_t n, const srv_stats_opts *o, const char *db,
                      long ungrouped)
{
    char buf[128];
    json_t *root = json_object(), *arr = json_array();
    json_object_set_new(root, "db", json_string(db));
    json_object_set_new(root, "by", json_string(by_name(o, buf, sizeof buf)));
    json_object_set_new(root, "survey", o->survey ? json_string(o->survey) : json_null());
    json_object_set_new(root, "min_phase_confidence", json_real(o->min_phase_confidence));
    json_object_set_new(root, "confidence_level", json_real(0.95));
    json_object_set_new(root, "lights_without_position", json_integer(ungrouped));
    static const char *const ph[3] = {"0", "120", "240"};
    for (size_t i = 0; i < n; i++) {
        const srv_phase_stats *x = &g[i];
        json_t *e = json_object(), *counts = json_object(), *shares = json_object(),
               *ci = json_object();
        json_object_set_new(e, "group", json_string(x->group));
        if (!isnan(x->lat_deg)) {
            json_object_set_new(e, "lat_deg", json_real(x->lat_deg));
            json_object_set_new(e, "lon_deg", json_real(x->lon_deg));
        }
        json_object_set_new(e, "lights", json_integer(x->lights));
        json_object_set_new(e, "below_confidence", json_integer(x->below));
        json_object_set_new(e, "unknown", json_integer(x->unknown));
        json_object_set_new(e, "other", json_integer(x->other));
        for (int k = 0; k < 3; k++) {
            json_object_set_new(counts, ph[k], json_integer(x->n[k]));
            json_object_set_new(shares, ph[k], real_or_null(x->share[k]));
            json_t *pair = json_array();
            json_array_append_new(pair, real_or_null(x->lo[k]));
            json_array_append_new(pair, real_or_null(x->hi[k]));
            json_object_set_new(ci, ph[k], pair);
        }
        static const char *const ph6[3] = {"30", "150", "270"};
        for (int k = 0; k < 3; k++) json_object_set_new(counts, ph6[k], json_integer(x->n30[k]));
        json_object_set_new(e, "counts", counts);
        json_object_set_new(e, "n", json_integer(x->total));
        json_object_set_new(e, "shares", shares);
        json_object_set_new(e, "wilson95", ci);
        json_object_set_new(e, "chi2", real_or_null(x->chi2));
        json_object_set_new(e, "dof", json_integer(2));
        json_object_set_new(e, "p_value", real_or_null(x->p_value));
        json_object_set_new(e, "imbalance", real_or_null(x->imbalance));
        json_object_set_new(e, "few", json_boolean(x->flags & SRV_STATS_FEW));
        json_array_append_new(arr, e);
    }
    json_object_set_new(root, "groups", arr);
    int rc = json_dumpf(root, stdout, JSON_INDENT(2) | JSON_REAL_PRECISION(10));
    putchar('\n');
    json_decref(root);
    return rc;
}

int srv_cmd_stats(int argc, char **argv)
{
    static const struct option longs[] = {
        {"db", required_argument, 0, 'd'},     {"by", required_argument, 0, 'b'},
        {"survey", required_argument, 0, 'S'}, {"min-phase-confidence", required_argument, 0, 'c'},
        {"format", required_argument, 0, 'f'}, {"help", no_argument, 0, 'h'},
        {"detections", no_argument, 0, 'D'},   {"clip", required_argument, 0, 'C'},
        {"bbox", required_argument, 0, 'B'},   {"pg", required_argument, 0, 'p'},
        {0, 0, 0, 0},
    };
    const char *path = NULL, *clip = NULL, *conninfo = NULL, *output = NULL;
    srv_stats_opts o;
    srv_stats_opts_default(&o);
    out_format fmt = FMT_TABLE;
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "ho:", longs, NULL)) != -1) {
        switch (c) {
        case 'd': path = optarg; break;
        case 'p': conninfo = optarg; break;
        case 'o': output = strcmp(optarg, "-") ? optarg : NULL; break;   /* -: stdout, as without -o */
        case 'S': o.survey = optarg; break;
        case 'b':
            if (srv_stats_parse_by(optarg, &o) != GS_OK) return srv_usage_error("stats", "%s", gs_detail());
            break;
        case 'c':
            if (!srv_num_arg("stats", "--min-phase-confidence", optarg, 0.0, 1.0, &o.min_phase_confidence)) return 2;
            break;
        case 'f':
            if (!strcmp(optarg, "table")) fmt = FMT_TABLE;
            else if (!strcmp(optarg, "json")) fmt = FMT_JSON;
            else if (!strcmp(optarg, "csv")) fmt = FMT_CSV;
            else return srv_usage_error("stats", "--format '%s': expected table, json or csv", optarg);
            break;
        case 'D': o.detections = 1; break;
        case 'C': clip = optarg; break;
        case 'B':
            if (srv_parse_bbox(optarg, o.bbox) != GS_OK) return srv_usage_error("stats", "%s", gs_detail());
            break;
        case 'h': fputs(stats_usage, stdout); return 0;
        default: return srv_usage_hint("stats", argv);
        }
    }
    if (optind < argc) return srv_usage_error("stats", "unexpected argument '%s'", argv[optind]);
    if (!path == !conninfo) return srv_usage_error("stats", "expected one of --db and --pg");
    if (output && (fmt != FMT_CSV || strlen(output) < 5 || strcmp(output + strlen(output) - 4, ".csv")))
        return srv_usage_error("stats", "-o '%s': expected a NAME.csv file and --format csv", output);
    int by_feature = o.by == SRV_BY_FEATURE;
    for (int i = 0; i < o.n_then; i++) by_feature |= o.then[i] == SRV_BY_FEATURE;
    if (by_feature && !clip)
        return srv_usage_error("stats", "--by feature:%s needs --clip AREAS.geojson", o.feature_field);
    srv_areas *areas = NULL;
    gs_status s;
    if (clip && (s = srv_areas_load(clip, by_feature ? o.feature_field : NULL, &areas)) != GS_OK)
        return srv_error("stats", s);
    o.areas = areas;
    srv_phase_stats *g = NULL;
    size_t n = 0;
    long ungrouped = 0;
    if (conninfo) {
        s = srv_stats_compute_pg(conninfo, &o, &g, &n, &ungrouped);
    } else {
        srv_db *db = NULL;
        s = srv_db_open(path, SRV_DB_READ, &db);
        int64_t id;
        if (s == GS_OK && o.survey) s = srv_db_find_survey(db, o.survey, &id);
        if (s == GS_OK) s = srv_stats_compute(db, &o, &g, &n, &ungrouped);
        if (db) srv_db_close(db);
    }
    if (s == GS_OK && fmt == FMT_CSV) {
        /* the file replaced atomically (no -o: stdout); the areas' geometry when the
         * groups are the areas */
        gs_atomic a;
        const srv_areas *wkt = o.by == SRV_BY_FEATURE && !o.n_then ? areas : NULL;
        s = gs_atomic_open(&a, output ? output : "-", 1);
        if (s == GS_OK) s = print_csv(a.f, g, n, wkt);
        if (s == GS_OK) s = gs_atomic_commit(&a);
        else gs_atomic_abort(&a);
        if (s == GS_OK && output) s = write_sidecars(output, wkt != NULL);
        if (s == GS_OK && output) fprintf(stderr, "wrote %s (%zu groups)\n", output, n);
    }
    srv_areas_free(areas);
    if (s != GS_OK) {
        free(g);
        return srv_error("stats", s);
    }
    int rc = 0;
    if (fmt == FMT_TABLE) srv_stats_print_table(g, n, &o, ungrouped);
    else if (fmt == FMT_JSON) rc = print_json(g, n, &o, path ? path : "postgresql", ungrouped);
    free(g);
    if (rc != 0 || fflush(stdout) != 0 || ferror(stdout))
        return srv_error("stats", gs_fail(GS_EIO, "stdout: write failed"));
    return 0;
}
