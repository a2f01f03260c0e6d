/* cmd_run.c - `gridsurvey run`: the whole job on one capture (survey/pipeline.c), then the
 * survey's phase-balance table (srv_stats_compute), its lights as GeoJSON and a PNG map
 * (gis_export, gis_map_png), and, when the capture directory holds the simulator's
 * truth.json, the evaluation (survey/evaluate.c). docs/pipeline.md. */
#include "survey/internal.h"

#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

static const char run_usage[] =
    "usage: gridsurvey run SCENE.json|CAPDIR [MORE ...] --db survey.sqlite [--station FILE]\n"
    "                      [--survey NAME]\n"
    "                      [--capture-dir DIR] [--light-height-m H] [--light-height-sigma-m S]\n"
    "                      [--phases 3|6|continuous] [--unknown-p P] [--delight DB]\n"
    "                      [--max-drift-windows W]\n"
    "                      [--out-dir DIR] [--progress | --no-progress | -q]\n"
    "\n"
    "The whole job on one capture: a scene (gridsurvey-scene/1) is acquired by the simulator\n"
    "through the ACam acquisition loop into a capture directory (resumable), a capture directory\n"
    "is read as it is; then lights and their per-frame photometry, bulb and grid phase by the\n"
    "paper's Eq. 7 against DELIGHT, each light located from the station at the lights' height,\n"
    "and everything stored in the survey database in one transaction. A capture already in the\n"
    "survey is skipped (never stored twice); an interrupted run resumes. Then prints the\n"
    "survey's phase balance, writes DIR/SURVEY.geojson and DIR/SURVEY-map.png, and when the\n"
    "capture directory holds the simulator's truth.json, prints the evaluation against it.\n"
    "Several inputs (e.g. two stations of one area) are run in turn, each its own capture and\n"
    "station; each survey's balance, files and evaluations follow its last input; then the\n"
    "light sites seen from two stations are triangulated (gis_triangulate) and listed with\n"
    "their 1-sigma ellipses.\n"
    "\n"
    "Examples:\n"
    "  gridsurvey run build/lab --db build/lab.sqlite   # build/lab: gridsurvey help simulate\n"
    "  gridsurvey run capture/scenes/metro.json --phases 6 --db build/demo/survey.sqlite\n"
    "  gridsurvey run east.json west.json --survey town --db town.sqlite\n"
    "\n"
    "  --db FILE            the survey database (created if missing)\n"
    "  --station FILE       the station (gridsurvey-station/1, docs/gis.md) instead of the\n"
    "                       capture's \"station\" object; without any, lights are stored\n"
    "                       without a location\n"
    "  --survey NAME        the survey the lights are stored under (default: the scene's name,\n"
    "                       or the capture directory's; without --survey a capture that any\n"
    "                       survey of the database holds is skipped, and reported as that\n"
    "                       survey's)\n"
    "  --capture-dir DIR    scene input: the capture directory (default: next to the database,\n"
    "                       SCENE-capture)\n"
    "  --light-height-m H   the lights' height above the WGS84 ellipsoid, m (default for a scene:\n"
    "                       the median height of its geographic lights; required for a capture\n"
    "                       directory with a station)\n"
    "  --light-height-sigma-m S  its 1-sigma for the error ellipses, m (default: with the\n"
    "                       scene's median, the spread of its lights' heights, else 0)\n"
    "  --phases P           candidate grid phases: 3 = 0/120/240 deg (default), 6 = those and\n"
    "                       + 30 deg (delta-wye transformers), continuous\n"
    "  --unknown-p P        Eq. 7's goodness-of-fit gate: a light whose best fit has a chi-square\n"
    "                       p-value below P gets no bulb (unknown), in [0, 1); 0 turns the gate\n"
    "                       off (default 0.001)\n"
    "  --max-drift-windows W\n"
    "                       free running: Eq. 7 leaves out the frames whose windows moved\n"
    "                       over W windows during the exposure, >= 0, none (keep every frame\n"
    "                       of known drift) or auto (default: none when capture.json's\n"
    "                       window_period is measured, as the firmware's, else 0.5). A capture\n"
    "                       already in the survey keeps its answers: run it into another --survey\n"
    "  --delight DB         DELIGHT SQLite file (default: $GRIDSURVEY_DELIGHT, else the scene's,\n"
    "                       else the built-in database)\n"
    "  --out-dir DIR        where the GeoJSON and the map go (default: the database's directory)\n"
    "  --progress           progress on stderr (default: when stderr is a terminal)\n"
    "  -q, --no-progress    no progress\n"
    "  --help               this text\n"
    "\n"
    "Exit status: 0 done, 1 failure (one line on\n"
    "stderr; bad input changes nothing on disk), 2 usage error.\n";

static void tty_progress(void *ctx, srv_stage stage, const char *detail)
{
    (void)ctx;
    fprintf(stderr, "gridsurvey run: %s: %s\n", srv_stage_name(stage), detail);
    fflush(stderr);
}

/* A survey name as a file name: letters, digits, '-', '_' and a '.' not first as they are, every
 * other byte as %XX, so that two names never share a file ('a/b' is a%2Fb, 'a_b' stays);
 * size >= 3 x the name's bytes + 1 (a name has at most 63). */
static void safe_name(const char *name, char *buf, size_t size)
{
    size_t n = 0;
    for (const char *p = name; *p && n + 4 <= size; p++) {
        unsigned char ch = (unsigned char)*p;
        int ok = (ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9') ||
                 ch == '-' || ch == '_' || (ch == '.' && n > 0);
        n += ok ? (size_t)snprintf(buf + n, size - n, "%c", ch) : (size_t)snprintf(buf + n, size - n, "%%%02X", ch);
    }
    buf[n] = '\0';
    if (!n) snprintf(buf, size, "survey");
}

/* The --out-dir directory: exists and is writable, or its parent is a writable directory. */
static gs_status check_out_dir(const char *path)
{
    struct stat sb;
    if (stat(path, &sb) == 0) {
        if (!S_ISDIR(sb.st_mode)) return gs_fail(GS_EIO, "%s: --out-dir exists and is not a directory", path);
        if (access(path, W_OK | X_OK) != 0)
            return gs_fail(GS_EIO, "%s: --out-dir is not writable: %s", path, strerror(errno));
        return GS_OK;
    }
    if (errno != ENOENT) return gs_fail(GS_EIO, "%s: --out-dir: %s", path, strerror(errno));
    char parent[4096];
    gs_path_dir(path, parent, sizeof parent);
    if (stat(parent, &sb) != 0 || !S_ISDIR(sb.st_mode) || access(parent, W_OK | X_OK) != 0)
        return gs_fail(GS_EIO, "%s: cannot create the --out-dir directory: %s is not a writable directory",
                       path, parent);
    return GS_OK;
}

/* The phase-balance table of the survey: all its lights, then per technology. */
static gs_status print_balance(srv_db *db, const char *survey)
{
    srv_phase_stats *all = NULL, *tech = NULL;
    size_t n_all = 0, n_tech = 0;
    srv_stats_opts o;
    srv_stats_opts_default(&o);
    o.survey = survey;
    gs_status s = srv_stats_compute(db, &o, &all, &n_all, NULL);
    if (s == GS_OK && (s = srv_stats_parse_by("technology", &o)) == GS_OK)
        s = srv_stats_compute(db, &o, &tech, &n_tech, NULL);
    srv_phase_stats *g = s == GS_OK ? malloc((n_all + n_tech + 1) * sizeof *g) : NULL;
    if (s == GS_OK && !g) s = gs_fail(GS_ENOMEM, "run: out of memory for the phase-balance table");
    if (s == GS_OK) {
        printf("\nPhase balance of survey %s (srv_stats_compute; gridsurvey stats --db DB --survey %s "
               "--by technology):\n\n", survey, survey);
        for (size_t i = 0; i < n_all + n_tech; i++) {
            g[i] = i < n_all ? all[i] : tech[i - n_all];
            if (i >= n_all) snprintf(g[i].group, sizeof g[i].group, "technology %.200s", tech[i - n_all].group);
        }
        srv_stats_print_table(g, n_all + n_tech, &o, 0);
    }
    free(g);
    free(all);
    free(tech);
    return s;
}

/* GeoJSON of the survey's lights and the PNG map of the located ones. */
static gs_status write_outputs(srv_db *db, const srv_run_report *r, const char *out_dir)
{
    if (mkdir(out_dir, 0777) != 0 && errno != EEXIST)
        return gs_fail(GS_EIO, "%s: cannot create the --out-dir directory: %s", out_dir, strerror(errno));
    srv_export_opts eo;
    srv_export_opts_default(&eo);
    eo.survey = r->survey;
    gis_light *lights = NULL;
    size_t n = 0, located = 0;
    gs_status s = srv_db_read_lights(db, &eo, &lights, &n);
    if (s != GS_OK) return s;
    for (size_t i = 0; i < n; i++) located += isfinite(lights[i].lat_deg);
    char name[3 * 64 + 1], path[4400];
    safe_name(r->survey, name, sizeof name);
    snprintf(path, sizeof path, "%s/%s.geojson", out_dir, name);
    s = gis_export(lights, n, GIS_FORMAT_GEOJSON, path);
    if (s == GS_OK) printf("\nwrote %s (%zu light%s, %zu located)\n", path, n, n == 1 ? "" : "s", located);
    /* every station of the survey (a second station's run maps the first's detections too) */
    gis_camera *cams = NULL;
    size_t n_cams = 0;
    if (s == GS_OK) s = srv_db_read_stations(db, r->survey, &cams, &n_cams);
    if (s == GS_OK && (located > 0 || n_cams > 0)) {
        char title[160];
        snprintf(title, sizeof title, "gridsurvey: survey %s, %zu located detections by phase", r->survey, located);
        gis_map_opts mo;
        gis_map_opts_default(&mo);
        mo.title = title;
        mo.stations = cams;
        mo.n_stations = n_cams;
        snprintf(path, sizeof path, "%s/%s-map.png", out_dir, name);
        s = gis_map_png(lights, n, &mo, path);
        if (s == GS_OK) printf("wrote %s\n", path);
    } else if (s == GS_OK) {
        printf("map: none (no located light and no station: the capture has no \"station\"; see --station)\n");
    }
    free(cams);
    free(lights);
    return s;
}

/* One input: srv_run and its lines. */
static gs_status run_one(const srv_run_opts *op, srv_run_report *rep)
{
    const srv_run_opts o = *op;
    srv_run_report r;
    gs_status s = srv_run(&o, &r);
    if (s != GS_OK) return s;
    printf("run: survey %s, capture %s (key %.19s...)", r.survey, r.capture_dir, r.key);
    if (r.scene) printf(": %d frames acquired, %d kept from an earlier run", r.frames_acquired, r.frames_kept);
    printf("\n");
    printf("run: %zu light%s, %zu with a bulb, %zu with a phase, %zu located", r.lights, r.lights == 1 ? "" : "s",
           r.with_bulb, r.with_phase, r.located);
    if (isfinite(r.light_height_m))
        printf(" at %.2f m above the ellipsoid (%s), height sigma %.2f m", r.light_height_m,
               r.height_source, r.light_height_sigma_m);
    else if (!r.has_station)
        printf(" (no station: stored without a location)");
    printf("\n");
    if (r.drift_note[0]) printf("run: note: %s\n", r.drift_note + 2);
    if (r.skipped) {
        printf("run: already in %s (capture id %lld): nothing stored; the counts above are its stored answers "
               "(other options apply to another --survey or database)\n", o.db_path, (long long)r.capture_id);
    } else {
        printf("run: stored as capture %lld in %s; seconds:", (long long)r.capture_id, o.db_path);
        for (int k = 0; k < SRV_STAGE_COUNT; k++)
            if (r.seconds[k] > 0.0) printf(" %s %.2f", srv_stage_name((srv_stage)k), r.seconds[k]);
        printf("\n");
        if (r.also_in[0])
            printf("run: note: survey %s holds the same capture: a light site joining both counts its "
                   "detections twice as evidence (delete one to redo it: docs/pipeline.md)\n", r.also_in);
    }
    *rep = r;
    return GS_OK;
}

/* After the inputs, once per survey (after its last input): its balance, GeoJSON and map, then
 * the evaluation of each of its captures that has a truth.json. */
static gs_status report_surveys(const char *db_path, const srv_run_report *reps, int n, const char *out_dir)
{
    srv_db *db = NULL;
    gs_status s = srv_db_open(db_path, SRV_DB_READ, &db);
    for (int i = 0; i < n && s == GS_OK; i++) {
        int later = 0;
        for (int j = i + 1; j < n; j++) later |= !strcmp(reps[j].survey, reps[i].survey);
        if (later) continue;
        s = print_balance(db, reps[i].survey);
        if (s == GS_OK) s = write_outputs(db, &reps[i], out_dir);
        for (int j = 0; j <= i && s == GS_OK; j++) {
            const srv_run_report *r = &reps[j];
            int again = 0;   /* (the same capture given twice is evaluated once) */
            for (int k = 0; k < j; k++) again |= !strcmp(reps[k].survey, r->survey) && !strcmp(reps[k].key, r->key);
            if (again || strcmp(r->survey, reps[i].survey) || !r->truth_path[0]) continue;
            srv_eval_opts eo;
            srv_eval_opts_default(&eo);
            eo.survey = r->survey;
            eo.capture_key = r->key;
            srv_eval_report er;
            s = srv_evaluate(db, r->truth_path, &eo, &er);
            if (s == GS_OK) {
                printf("\n");
                s = srv_eval_print(&er, r->truth_path, 0, stdout);
            }
        }
    }
    srv_db_close(db);
    return s;
}

/* Two stations: the sites seen from two stations of the inputs' captures, triangulated. */
static gs_status print_triangulated(const char *db_path, const srv_run_report *reps, size_t n)
{
    srv_db *db = NULL;
    srv_tri_site *t = NULL;
    size_t nt = 0, ok = 0;
    int64_t *captures = malloc(n * sizeof *captures);
    if (!captures) return gs_fail(GS_ENOMEM, "out of memory");
    for (size_t i = 0; i < n; i++) captures[i] = reps[i].capture_id;
    gs_status s = srv_db_open(db_path, SRV_DB_READ, &db);
    if (s == GS_OK) s = srv_triangulate_sites(db, captures, n, &t, &nt);
    srv_db_close(db);
    free(captures);
    if (s != GS_OK) return s;
    for (size_t i = 0; i < nt; i++) ok += isfinite(t[i].fix.lat_deg);
    printf("\nTwo stations (srv_triangulate_sites, gis_triangulate): %zu light sites seen from two "
           "stations, %zu triangulated, %zu flagged (behind a station, near-parallel, or not "
           "intersectable: the reason in flags)\n\n", nt, ok, nt - ok);
    if (nt) printf("| site | stations | lat_deg | lon_deg | semi-major m | semi-minor m | azimuth deg | angle deg | flags |\n"
                   "|---:|---|---:|---:|---:|---:|---:|---:|---|\n");
    for (size_t i = 0; i < nt; i++) {
        const gis_intersection *x = &t[i].fix;
        char fl[96];
        printf("| %lld | %s, %s | %.7f | %.7f | %.3f | %.3f | %.1f | %.1f | %s |\n", (long long)t[i].site_id,
               t[i].station[0], t[i].station[1], x->lat_deg, x->lon_deg, x->ellipse.semi_major_m,
               x->ellipse.semi_minor_m, x->ellipse.azimuth_deg, x->angle_deg,
               t[i].error[0] ? t[i].error : gis_flags_str(x->flags, fl, sizeof fl));
    }
    free(t);
    return GS_OK;
}

int srv_cmd_run(int argc, char **argv)
{
    static const struct option longs[] = {
        {"db", required_argument, 0, 'd'},          {"station", required_argument, 0, 's'},
        {"survey", required_argument, 0, 'S'},      {"capture-dir", required_argument, 0, 'c'},
        {"light-height-m", required_argument, 0, 'H'}, {"phases", required_argument, 0, 'p'},
        {"delight", required_argument, 0, 'D'},     {"out-dir", required_argument, 0, 'O'},
        {"unknown-p", required_argument, 0, 'u'},   {"light-height-sigma-m", required_argument, 0, 'G'},
        {"progress", no_argument, 0, 'P'},          {"no-progress", no_argument, 0, 'q'},
        {"max-drift-windows", required_argument, 0, 'W'},
        {"help", no_argument, 0, 'h'},              {0, 0, 0, 0},
    };
    srv_run_opts o;
    srv_run_opts_default(&o);
    const char *out = NULL;
    int progress = isatty(2);
    o.delight_path = getenv("GRIDSURVEY_DELIGHT");
    if (o.delight_path && !*o.delight_path) o.delight_path = NULL;
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, ":hqo:", longs, NULL)) != -1) {
        switch (c) {
        case 'd': o.db_path = optarg; break;
        case 's': o.station_path = optarg; break;
        case 'S': o.survey = optarg; break;
        case 'c': o.capture_dir = optarg; break;
        case 'D': o.delight_path = optarg; break;
        case 'O': out = optarg; break;
        case 'o': return srv_out_dir_hint("run");
        case 'P': progress = 1; break;
        case 'q': progress = 0; break;
        case 'H':
            if (!srv_num_arg("run", "--light-height-m", optarg, -INFINITY, INFINITY, &o.light_height_m)) return 2;
            break;
        case 'G':
            if (!srv_num_arg("run", "--light-height-sigma-m", optarg, 0.0, INFINITY, &o.light_height_sigma_m)) return 2;
            break;
        case 'u':
            if (!srv_num_arg_open("run", "--unknown-p", optarg, 0.0, 1.0, SRV_OPEN_HI, &o.eq7.unknown_p)) return 2;
            break;
        case 'p':
            if (!strcmp(optarg, "3")) o.eq7.phases = REC_PHASES_3;
            else if (!strcmp(optarg, "6")) o.eq7.phases = REC_PHASES_6;
            else if (!strcmp(optarg, "continuous")) o.eq7.phases = REC_PHASES_CONTINUOUS;
            else return srv_usage_error("run", "--phases '%s': expected 3, 6 or continuous", optarg);
            break;
        case 'W':
            if (!srv_drift_arg("run", optarg, &o.eq7.max_drift_windows)) return 2;
            break;
        case 'h': fputs(run_usage, stdout); return 0;
        case ':': return srv_usage_error("run", "option '%s' needs a value", argv[optind - 1]);
        default: return srv_usage_error("run", "unknown option '%s'", argv[optind - 1]);
        }
    }
    if (argc - optind < 1) return srv_usage_error("run", "expected a scene file or a capture directory");
    int n_inputs = argc - optind;
    if (n_inputs > 1 && (o.capture_dir || o.station_path))
        return srv_usage_error("run", "--capture-dir and --station take one input (each input has its own "
                               "capture directory and station)");
    if (!o.db_path) return srv_usage_error("run", "--db is required");
    /* --out-dir is checked before anything is written; the default, the database's directory, is
     * checked by opening the database */
    char out_dir[4096];
    if (out) snprintf(out_dir, sizeof out_dir, "%s", out);
    else gs_path_dir(o.db_path, out_dir, sizeof out_dir);
    gs_status s = out ? check_out_dir(out_dir) : GS_OK;
    if (s != GS_OK) return srv_error("run", s);
    if (progress) {
        o.progress = tty_progress;
        o.capture_progress = 1;
    }
    srv_run_report *reps = calloc((size_t)n_inputs, sizeof *reps);
    if (!reps) s = gs_fail(GS_ENOMEM, "out of memory");
    int done = 0;
    for (; done < n_inputs && s == GS_OK; done++) {
        o.input = argv[optind + done];
        s = run_one(&o, &reps[done]);
    }
    /* the surveys of the inputs that were stored are reported even when a later one failed */
    int ok_inputs = s == GS_OK ? n_inputs : done - 1;
    if (ok_inputs > 0) {
        char failed[1024];
        snprintf(failed, sizeof failed, "%s", s == GS_OK ? "" : gs_detail());
        gs_status sr = report_surveys(o.db_path, reps, ok_inputs, out_dir);
        if (s == GS_OK) s = sr;
        else s = gs_fail(s, "%s", failed);   /* (the input's error, not the report's) */
    }
    if (s == GS_OK && n_inputs > 1) s = print_triangulated(o.db_path, reps, (size_t)n_inputs);
    free(reps);
    if (s == GS_OK && fflush(stdout) != 0) s = gs_fail(GS_EIO, "stdout: write failed");
    return s == GS_OK ? 0 : srv_error("run", s);
}
