/* cmd_locate.c - `gridsurvey locate`: one-station location of lights from their pixels
 * (gis_locate: sight line -> surface at the lights' height above the WGS84 ellipsoid), written
 * as GeoJSON, KML, GeoPackage or CSV, optionally with a PNG map (docs/gis.md). */
#include "survey/internal.h"
#include "gis/gis.h"

#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char locate_usage[] =
    "usage: gridsurvey locate --station STATION.json --pixels PIXELS.csv -o FILE\n"
    "                         [--light-height-m H] [--format geojson|kml|gpkg|csv]\n"
    "                         [--map MAP.png] [--survey NAME] [--refraction]\n"
    "                         [--max-error-ratio R]\n"
    "\n"
    "Locates each light seen by one camera station: its sight line is intersected with the\n"
    "surface H metres above the WGS84 ellipsoid (Earth curvature exact), with a 1-sigma error\n"
    "ellipse from the pixel and pose sigmas. Lights whose sight line does not reach that\n"
    "surface, or whose ellipse exceeds R x range, are written without a position and flagged.\n"
    "\n"
    "  --station FILE   station JSON (gridsurvey-station/1): lat_deg, lon_deg, height_m,\n"
    "                   heading_deg, pitch_deg, [roll_deg], focal_px, cx_px, cy_px, [k1, k2,\n"
    "                   width_px, height_px, sigma_px, psf_sigma_px, sigma_heading_deg,\n"
    "                   sigma_pitch_deg, sigma_roll_deg, refraction_k, id, time_utc]  (docs/gis.md)\n"
    "  --pixels FILE    CSV with header id,x_px,y_px[,sigma_px]; image x right, y down, pixel\n"
    "                   centres at integers; sigma_px defaults to the station's (else 1),\n"
    "                   and is required when the station gives psf_sigma_px\n"
    "  --light-height-m H  the lights' height above the WGS84 ellipsoid, metres (default 0;\n"
    "                   note that ellipsoidal heights differ from heights above sea level by\n"
    "                   the geoid undulation, up to +-100 m)\n"
    "  --format F       geojson, kml, gpkg or csv (default: from the -o extension; it must\n"
    "                   not be another format's extension)\n"
    "  -o FILE          output file (replaced atomically)\n"
    "  --map FILE.png   also draw a map of the located lights\n"
    "  --survey NAME    the survey the lights belong to (stored with every light)\n"
    "  --refraction     standard atmospheric refraction (k = 0.13) for a station whose\n"
    "                   refraction_k is 0 or not given (one with its own k keeps it)\n"
    "  --max-error-ratio R  flag a light whose error ellipse exceeds R x range (0.25)\n"
    "  --help           this text\n"
    "\n"
    "Example:\n"
    "  gridsurvey locate --station station.json --pixels pixels.csv --light-height-m 30 \\\n"
    "                    -o lights.geojson --map lights.png\n";

typedef struct {
    char id[GIS_TEXT_MAX];
    double x_px, y_px, sigma_px;   /* sigma NaN = not given */
    int line;
} pixel_row;

static gs_status parse_number(const char *path, int line, const char *field, const char *text,
                              double *v)
{
    if (!gs_parse_number(text, v))
        return gs_fail(GS_EFORMAT, "%s:%d: %s: expected a finite number, got '%s'", path, line, field, text);
    return GS_OK;
}

typedef struct {
    const char *path;
    int header;          /* columns of the header, 0 before it */
    pixel_row *rows;
    size_t count, cap;
} pixel_reader;

static gs_status pixel_line(void *ctx, char **fld, size_t count, size_t line)
{
    pixel_reader *pr = ctx;
    const char *path = pr->path;
    int lineno = (int)line, n = (int)count;
    if (n == 0 || fld[0][0] == '#' || (n == 1 && !*fld[0])) return GS_OK;   /* comment */
    if (!pr->header) {
        static const char *const want[4] = {"id", "x_px", "y_px", "sigma_px"};
        if (n < 3 || n > 4)
            return gs_fail(GS_EFORMAT, "%s:%d: header: expected id,x_px,y_px[,sigma_px]", path, lineno);
        for (int i = 0; i < n; i++)
            if (strcmp(fld[i], want[i]))
                return gs_fail(GS_EFORMAT, "%s:%d: header column %d is '%s': expected '%s' "
                               "(id,x_px,y_px[,sigma_px])", path, lineno, i + 1, fld[i], want[i]);
        pr->header = n;
        return GS_OK;
    }
    if (n != pr->header)
        return gs_fail(GS_EFORMAT, "%s:%d: %d fields: expected %d like the header", path, lineno, n,
                       pr->header);
    if (pr->count == pr->cap) {
        size_t nc = pr->cap ? 2 * pr->cap : 64;
        pixel_row *nr = realloc(pr->rows, nc * sizeof *nr);
        if (!nr) return gs_fail(GS_ENOMEM, "%s: out of memory", path);
        pr->rows = nr;
        pr->cap = nc;
    }
    pixel_row *r = &pr->rows[pr->count];
    if (!*fld[0] || strlen(fld[0]) >= sizeof r->id || strchr(fld[0], '"') || !gs_text_clean(fld[0]))
        return gs_fail(GS_EFORMAT, "%s:%d: id: expected 1 to %zu characters without quotes or "
                       "control characters", path, lineno, sizeof r->id - 1);
    strcpy(r->id, fld[0]);
    r->line = lineno;
    r->sigma_px = NAN;
    gs_status s;
    if ((s = parse_number(path, lineno, "x_px", fld[1], &r->x_px)) != GS_OK ||
        (s = parse_number(path, lineno, "y_px", fld[2], &r->y_px)) != GS_OK)
        return s;
    if (pr->header == 4) {
        if ((s = parse_number(path, lineno, "sigma_px", fld[3], &r->sigma_px)) != GS_OK) return s;
        if (r->sigma_px < 0.0)
            return gs_fail(GS_EFORMAT, "%s:%d: sigma_px: expected a value >= 0, got %s", path,
                           lineno, fld[3]);
    }
    pr->count++;
    return GS_OK;
}

static int by_id_then_line(const void *a, const void *b)
{
    const pixel_row *p = *(const pixel_row *const *)a, *q = *(const pixel_row *const *)b;
    int c = strcmp(p->id, q->id);
    return c ? c : (p->line > q->line) - (p->line < q->line);
}

/* An id given twice: the one-line error at its second line. */
static gs_status unique_ids(const char *path, const pixel_row *rows, size_t n)
{
    const pixel_row **by = malloc((n ? n : 1) * sizeof *by);
    if (!by) return gs_fail(GS_ENOMEM, "%s: out of memory", path);
    for (size_t i = 0; i < n; i++) by[i] = &rows[i];
    qsort(by, n, sizeof *by, by_id_then_line);
    /* the earliest repeat, and the first line of its id (its run's first, by line) */
    const pixel_row *dup = NULL, *first = NULL;
    for (size_t i = 1, run = 0; i < n; i++) {
        if (strcmp(by[run]->id, by[i]->id)) {
            run = i;
        } else if (!dup || by[i]->line < dup->line) {
            dup = by[i];
            first = by[run];
        }
    }
    gs_status s = dup ? gs_fail(GS_EFORMAT, "%s:%d: id '%s': given on line %d already: expected each light's "
                                "id once", path, dup->line, dup->id, first->line)
                      : GS_OK;
    free(by);
    return s;
}

static gs_status read_pixels(const char *path, pixel_row **rows, size_t *count)
{
    pixel_reader pr = {.path = path};
    /* pixel lists are small: 256 MiB bounds a file that is not one */
    gs_status s = gs_csv_read(path, (size_t)256 << 20, pixel_line, &pr);
    if (s == GS_OK && !pr.header)
        s = gs_fail(GS_EFORMAT, "%s: no header line (id,x_px,y_px[,sigma_px])", path);
    if (s == GS_OK) s = unique_ids(path, pr.rows, pr.count);
    if (s != GS_OK) {
        free(pr.rows);
        pr.rows = NULL;
        pr.count = 0;
    }
    *rows = pr.rows;
    *count = pr.count;
    return s;
}

int srv_cmd_locate(int argc, char **argv)
{
    static const struct option longs[] = {
        {"station", required_argument, 0, 's'}, {"pixels", required_argument, 0, 'p'},
        {"light-height-m", required_argument, 0, 'H'}, {"format", required_argument, 0, 'f'},
        {"map", required_argument, 0, 'm'},     {"survey", required_argument, 0, 'S'},
        {"refraction", no_argument, 0, 'r'},
        {"max-error-ratio", required_argument, 0, 'R'}, {"help", no_argument, 0, 'h'},
        {0, 0, 0, 0},
    };
    const char *station_path = NULL, *pixels_path = NULL, *out = NULL, *format = NULL,
               *map = NULL, *survey = NULL;
    double height_m = 0.0;
    int refraction = 0;
    gis_locate_opts lo;
    gis_locate_opts_default(&lo);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "o:h", longs, NULL)) != -1) {
        switch (c) {
        case 's': station_path = optarg; break;
        case 'p': pixels_path = optarg; break;
        case 'o': out = optarg; break;
        case 'f': format = optarg; break;
        case 'm': map = optarg; break;
        case 'S': survey = optarg; break;
        case 'r': refraction = 1; break;
        case 'H':
            if (!srv_num_arg("locate", "--light-height-m", optarg, GIS_MIN_HEIGHT_M, GIS_MAX_HEIGHT_M, &height_m))
                return 2;
            break;
        case 'R':
            if (!srv_num_arg_open("locate", "--max-error-ratio", optarg, 0.0, INFINITY, SRV_OPEN_LO, &lo.max_error_ratio))
                return 2;
            break;
        case 'h': fputs(locate_usage, stdout); return 0;
        default: return srv_usage_hint("locate", argv);
        }
    }
    if (optind < argc) return srv_usage_error("locate", "unexpected argument '%s'", argv[optind]);
    if (!station_path || !pixels_path || !out)
        return srv_usage_error("locate", "--station, --pixels and -o are required");
    if (survey && strlen(survey) >= GIS_TEXT_MAX)
        return srv_usage_error("locate", "--survey: at most %d bytes", GIS_TEXT_MAX - 1);
    gis_format fmt;
    gs_status s = gis_format_choose(format, out, &fmt);
    if (s != GS_OK) return srv_usage_error("locate", "%s", gs_detail());

    gis_station st;
    s = gis_station_read(station_path, &st);
    if (s != GS_OK) return srv_error("locate", s);
    if (refraction && st.cam.refraction_k == 0.0) st.cam.refraction_k = GIS_REFRACTION_K_STANDARD;
    pixel_row *rows;
    size_t n;
    s = read_pixels(pixels_path, &rows, &n);
    if (s != GS_OK) return srv_error("locate", s);
    gis_light *lights = calloc(n ? n : 1, sizeof *lights);
    if (!lights) {
        free(rows);
        return srv_error("locate", gs_fail(GS_ENOMEM, "out of memory for %zu lights", n));
    }
    size_t nloc = 0, nflag = 0;
    for (size_t i = 0; i < n && s == GS_OK; i++) {
        gis_fix fx;
        /* with psf_sigma_px, the station's sigma_px is only the calibration residual: the
         * light's centroid sigma (from its SNR, docs/gis.md) must come from the CSV */
        if (isnan(rows[i].sigma_px) && !isnan(st.psf_sigma_px)) {
            s = gs_fail(GS_EFORMAT, "%s:%d: sigma_px: not given, and %s has psf_sigma_px (its "
                        "sigma_px is only the calibration residual): expected a sigma_px column, "
                        "each light's centroid sigma in px", pixels_path, rows[i].line, station_path);
            break;
        }
        double sig = isnan(rows[i].sigma_px) ? st.sigma_px : rows[i].sigma_px;
        s = gis_locate(&st.cam, rows[i].x_px, rows[i].y_px, sig, height_m, &lo, &fx);
        if (s != GS_OK) {
            s = gs_fail(s, "%s: light %s: %s", pixels_path, rows[i].id, gs_detail());
            break;
        }
        gis_light_init(&lights[i]);
        gis_light_set_fix(&lights[i], &fx);
        snprintf(lights[i].id, sizeof lights[i].id, "%s", rows[i].id);
        if (survey) snprintf(lights[i].survey, sizeof lights[i].survey, "%s", survey);
        snprintf(lights[i].time_utc, sizeof lights[i].time_utc, "%s", st.time_utc);
        if (fx.flags) {
            char fl[128];
            fprintf(stderr, "gridsurvey locate: light %s: not located (%s)\n", rows[i].id,
                    gis_flags_str(fx.flags, fl, sizeof fl));
            nflag++;
        } else {
            nloc++;
        }
    }
    if (s == GS_OK) s = gis_export(lights, n, fmt, out);
    if (s == GS_OK && map) {
        gis_map_opts mo;
        gis_map_opts_default(&mo);
        mo.stations = &st.cam;
        mo.n_stations = 1;
        mo.title = "gridsurvey locate";
        s = gis_map_png(lights, n, &mo, map);
    }
    free(rows);
    free(lights);
    if (s != GS_OK) return srv_error("locate", s);
    fprintf(srv_note_stream(out), "located %zu of %zu lights (%zu flagged) -> %s\n", nloc, n, nflag, out);
    return 0;
}
