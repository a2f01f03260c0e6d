/* bench_db.c - synthetic surveys (a developer tool for tests, crash tests and benchmarks) and
 * `gridsurvey bench db`: ingest rate and query times of the survey database at 1e4, 1e5 and
 * 1e6 lights (docs/survey-db.md, "Scale"). */
#include "survey/internal.h"

#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

/* ------------------------------------------------------------------ synthetic survey */

void srv_synth_opts_default(srv_synth_opts *o)
{
    memset(o, 0, sizeof *o);
    o->survey = "synthetic";
    o->captures = 100;
    o->lights_per_capture = 100;
    o->batch = 1;
    o->seed = 1;
    o->phase_weights[0] = o->phase_weights[1] = o->phase_weights[2] = 1.0;
    o->ambiguous_fraction = 0.05;
    o->lat_deg = 32.80;
    o->lon_deg = 35.02;
    o->half_width_m = 2000.0;
    o->view_half_width_m = 250.0;
}


static double unif(uint64_t *s)
{
    return (double)(gs_splitmix64(s) >> 11) * 0x1.0p-53;
}

static double wrap_phase(double d)
{
    double w = fmod(d, 360.0);
    if (w < 0.0) w += 360.0;
    return w >= 360.0 ? 0.0 : w;
}

static const struct {
    const char *bulb, *tech;
    double weight;
} synth_bulbs[] = {
    {"sodium_hp_150w", "sodium_hp", 0.35},
    {"led_linear_60w", "led_linear", 0.25},
    {"cfl_23w", "cfl", 0.10},
    {"metal_halide_100w", "metal_halide", 0.10},
    {"fluorescent_magnetic_36w", "fluorescent_magnetic", 0.10},
    {"incandescent_100w", "incandescent", 0.05},
    {"mercury_125w", "mercury", 0.05},
};
#define N_SYNTH_BULBS (sizeof synth_bulbs / sizeof *synth_bulbs)

typedef struct {
    srv_frame_row frames[SRV_SYNTH_FRAMES];
    char names[SRV_SYNTH_FRAMES][24];
    srv_freq_row freq[SRV_SYNTH_FREQ];
    srv_light_row *lights;
    srv_location_row *locs;
    char key[32];
} synth_buf;

/* Capture c of the synthetic survey: a function of (seed, c) only. */
static void synth_capture(const srv_synth_opts *o, size_t c, int64_t survey_id, int64_t station_id,
                          synth_buf *b, srv_capture_data *d)
{
    uint64_t rng = o->seed * 0x2545f4914f6cdd1dull ^ (uint64_t)c * 0x9e3779b97f4a7c15ull;
    gs_splitmix64(&rng);
    snprintf(b->key, sizeof b->key, "synth-%06zu", c);
    memset(d, 0, sizeof *d);
    srv_capture_row_init(&d->capture);
    d->capture.survey_id = survey_id;
    d->capture.station_id = station_id;
    d->capture.key = b->key;
    d->capture.utc = "2017-06-01T22:00:00Z";
    d->capture.grid_hz = 50;
    d->capture.K = SRV_SYNTH_FRAMES;
    d->capture.bands = 1;
    d->capture.width_px = d->capture.height_px = 1024;
    d->capture.locked = 1;
    double f0 = 50.0 + 0.02 * (unif(&rng) - 0.5);
    d->capture.mean_frequency_hz = f0;
    for (int k = 0; k < SRV_SYNTH_FRAMES; k++) {
        snprintf(b->names[k], sizeof b->names[k], "frame_%03d.png", k);
        b->frames[k] = (srv_frame_row){k, b->names[k], NULL, 100.0};
    }
    for (int i = 0; i < SRV_SYNTH_FREQ; i++)
        b->freq[i] = (srv_freq_row){(double)i, 1.0, f0 + 0.002 * (unif(&rng) - 0.5), 1e-4};
    d->frames = b->frames;
    d->n_frames = SRV_SYNTH_FRAMES;
    d->frequency = b->freq;
    d->n_frequency = SRV_SYNTH_FREQ;
    double wsum = o->phase_weights[0] + o->phase_weights[1] + o->phase_weights[2];
    double vx = o->half_width_m * (2.0 * unif(&rng) - 1.0), vy = o->half_width_m * (2.0 * unif(&rng) - 1.0);
    double kx = 1.0 / (GIS_EARTH_RADIUS_M * cos(o->lat_deg * M_PI / 180.0)) * 180.0 / M_PI;
    double ky = 1.0 / GIS_EARTH_RADIUS_M * 180.0 / M_PI;
    for (size_t j = 0; j < o->lights_per_capture; j++) {
        srv_light_row *l = &b->lights[j];
        srv_location_row *loc = &b->locs[j];
        srv_light_row_init(l);
        l->index = (int)j;
        l->x_px = 1024.0 * unif(&rng);
        l->y_px = 1024.0 * unif(&rng);
        l->area_px = 4 + (int)(gs_splitmix64(&rng) % 30);
        l->peak_dn = 1000.0 + 60000.0 * unif(&rng);
        l->brightness = 50.0 + 5000.0 * unif(&rng);
        l->snr = 10.0 + 200.0 * unif(&rng);
        l->dof = SRV_SYNTH_FRAMES - 2;
        l->chi2 = (double)l->dof * (0.5 + unif(&rng));
        l->p_value = unif(&rng);
        double u = unif(&rng), acc = 0.0;
        size_t bi = 0;
        for (; bi + 1 < N_SYNTH_BULBS; bi++) {
            acc += synth_bulbs[bi].weight;
            if (u < acc) break;
        }
        l->bulb_id = synth_bulbs[bi].bulb;
        l->technology = synth_bulbs[bi].tech;
        double w = unif(&rng) * wsum;
        int ph = w < o->phase_weights[0] ? 0 : w < o->phase_weights[0] + o->phase_weights[1] ? 1 : 2;
        double fit = wrap_phase(120.0 * ph + 2.0 * (unif(&rng) - 0.5));
        int ambiguous = unif(&rng) < o->ambiguous_fraction;
        l->phase_fit_deg = fit;
        l->phase_deg = ambiguous ? NAN : fit;
        l->phase_sigma_deg = 0.0;
        l->phase_confidence = ambiguous ? 0.4 + 0.4 * unif(&rng) : 0.8 + 0.2 * unif(&rng);
        l->bulb_confidence = 0.6 + 0.4 * unif(&rng);
        l->confidence = l->phase_confidence * l->bulb_confidence;
        l->runner_bulb_id = synth_bulbs[(bi + 1) % N_SYNTH_BULBS].bulb;
        l->runner_phase_deg = wrap_phase(fit + 120.0);
        l->runner_confidence = 0.5 * (1.0 - l->confidence);
        l->match_flags = ambiguous ? REC_MATCH_PHASE_AMBIGUOUS : 0;
        srv_location_row_init(loc);
        loc->method = SRV_LOC_ONE_STATION;
        double ex = vx + o->view_half_width_m * (2.0 * unif(&rng) - 1.0);
        double ny = vy + o->view_half_width_m * (2.0 * unif(&rng) - 1.0);
        if (j % SRV_SYNTH_UNLOCATED_EVERY == SRV_SYNTH_UNLOCATED_EVERY - 1) {
            loc->flags = GIS_FIX_ABOVE_HORIZON;
        } else {
            loc->lat_deg = o->lat_deg + ny * ky;
            loc->lon_deg = o->lon_deg + ex * kx;
            loc->height_m = 20.0 + 10.0 * unif(&rng);
            loc->ellipse.semi_major_m = 1.0 + 10.0 * unif(&rng);
            loc->ellipse.semi_minor_m = loc->ellipse.semi_major_m * (0.2 + 0.8 * unif(&rng));
            loc->ellipse.azimuth_deg = 180.0 * unif(&rng);
            loc->range_m = 500.0 + 3000.0 * unif(&rng);
        }
    }
    d->lights = b->lights;
    d->locations = b->locs;
    d->n_lights = o->lights_per_capture;
}

gs_status srv_synth_ingest(srv_db *db, const srv_synth_opts *o, size_t *added)
{
    if (added) *added = 0;
    if (!db || !o) return gs_fail(GS_EINVAL, "srv_synth_ingest: NULL argument");
    if (o->batch < 1 || o->lights_per_capture > 1000000 || o->captures > 100000000 ||
        !(o->phase_weights[0] >= 0 && o->phase_weights[1] >= 0 && o->phase_weights[2] >= 0 &&
          o->phase_weights[0] + o->phase_weights[1] + o->phase_weights[2] > 0) ||
        !(o->ambiguous_fraction >= 0.0 && o->ambiguous_fraction <= 1.0) ||
        !(fabs(o->lat_deg) < 80.0) || !isfinite(o->lon_deg) || !(o->half_width_m >= 0.0) ||
        !(o->view_half_width_m >= 0.0) || o->half_width_m + o->view_half_width_m > 1e6)
        return gs_fail(GS_EINVAL, "synthetic survey: expected batch >= 1, <= 1e6 lights per capture, "
                       "weights >= 0 with a positive sum, ambiguous fraction in [0, 1], |lat| < 80, half-widths "
                       ">= 0 summing to <= 1000 km");
    srv_survey_row sr = {o->survey ? o->survey : "synthetic", "synthetic", NULL, "synthetic survey", 50};
    int64_t survey_id, station_id;
    gs_status s = srv_db_add_survey(db, &sr, &survey_id);
    if (s != GS_OK) return s;
    srv_station_row st;
    srv_station_row_init(&st);
    st.survey_id = survey_id;
    st.name = "synthetic-station";
    st.cam.lat_deg = o->lat_deg;
    st.cam.lon_deg = o->lon_deg;
    st.cam.height_m = 100.0;
    if ((s = srv_db_add_station(db, &st, &station_id)) != GS_OK) return s;
    synth_buf b;
    size_t nl = o->lights_per_capture ? o->lights_per_capture : 1;
    b.lights = malloc(nl * sizeof *b.lights);
    b.locs = malloc(nl * sizeof *b.locs);
    if (!b.lights || !b.locs) {
        free(b.lights);
        free(b.locs);
        return gs_fail(GS_ENOMEM, "synthetic survey: out of memory");
    }
    size_t in_batch = 0;
    for (size_t c = 0; c < o->captures && s == GS_OK; c++) {
        int done = 0;
        char key[32];
        snprintf(key, sizeof key, "synth-%06zu", c);
        if ((s = srv_db_capture_done(db, survey_id, key, &done)) != GS_OK || done) continue;
        if (!in_batch && o->batch > 1 && (s = srv_db_begin(db)) != GS_OK) break;
        srv_capture_data d;
        synth_capture(o, c, survey_id, station_id, &b, &d);
        int skipped = 0;
        s = srv_db_add_capture(db, &d, NULL, &skipped);
        if (s == GS_OK && !skipped && added) (*added)++;
        if (o->batch > 1 && s == GS_OK && ++in_batch == o->batch) {
            s = srv_db_commit(db);
            in_batch = 0;
        }
    }
    if (srv_db_in_transaction(db)) {
        if (s == GS_OK) s = srv_db_commit(db);
        else {
            char msg[512];
            snprintf(msg, sizeof msg, "%s", gs_detail());
            srv_db_rollback(db);
            s = gs_fail(s, "%s", msg);
        }
    }
    free(b.lights);
    free(b.locs);
    return s;
}

/* ------------------------------------------------------------------ benchmark */

static const char bench_usage[] =
    "usage: gridsurvey bench db [--quick] [--max N] [--dir DIR] [--keep]\n"
    "\n"
    "Ingests a synthetic survey (1000 lights per capture, one transaction per capture, WAL,\n"
    "synchronous=NORMAL) and grows it through 1e4, 1e5, 1e6 lights (up to N), timing at each\n"
    "size the ingest and the queries: stats by technology, by 250 m cell and within 500 m\n"
    "(R*Tree), the phase_balance SQL view, reading the lights of a 1 km x 1 km box (R*Tree)\n"
    "and `db check`. Prints a Markdown table.\n"
    "\n"
    "  --quick    1e4 lights only (a smoke test)\n"
    "  --max N    largest size (default 1000000; sizes are powers of ten from 1e4)\n"
    "  --dir DIR  where to write bench.sqlite (default: a new temporary directory, removed)\n"
    "  --keep     keep the database\n"
    "\n"
    "Example:\n"
    "  gridsurvey bench db --quick\n";

gs_status srv_bench_time_stats(srv_db *db, const char *conninfo, const char *by, double *sec)
{
    srv_stats_opts o;
    srv_stats_opts_default(&o);
    gs_status s = srv_stats_parse_by(by, &o);
    if (s != GS_OK) return s;
    srv_phase_stats *g = NULL;
    size_t n = 0;
    double t0 = gs_clock_s(CLOCK_MONOTONIC);
    s = db ? srv_stats_compute(db, &o, &g, &n, NULL) : srv_stats_compute_pg(conninfo, &o, &g, &n, NULL);
    *sec = gs_clock_s(CLOCK_MONOTONIC) - t0;
    free(g);
    return s;
}

gs_status srv_bench_time_view(srv_db *db, const char *sql, double *sec)
{
    sqlite3 *h = srv_db_sqlite(db);
    sqlite3_stmt *q = NULL;
    double t0 = gs_clock_s(CLOCK_MONOTONIC);
    if (sqlite3_prepare_v2(h, sql, -1, &q, NULL) != SQLITE_OK)
        return gs_fail(GS_ESQL, "%s: %s", sql, sqlite3_errmsg(h));
    int rc;
    while ((rc = sqlite3_step(q)) == SQLITE_ROW) {}
    sqlite3_finalize(q);
    *sec = gs_clock_s(CLOCK_MONOTONIC) - t0;
    return rc == SQLITE_DONE ? GS_OK : gs_fail(GS_ESQL, "%s: %s", sql, sqlite3_errmsg(h));
}

int srv_bench_db(int argc, char **argv)
{
    static const struct option longs[] = {
        {"quick", no_argument, 0, 'q'}, {"max", required_argument, 0, 'm'},
        {"dir", required_argument, 0, 'd'}, {"keep", no_argument, 0, 'k'},
        {"help", no_argument, 0, 'h'}, {0, 0, 0, 0},
    };
    long max = 1000000;
    unsigned long long v;
    int keep = 0;
    const char *dir = NULL;
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "h", longs, NULL)) != -1) {
        switch (c) {
        case 'q': max = 10000; break;
        case 'm':
            if (!srv_int_arg("bench db", "--max", optarg, 10000, 100000000, &v)) return 2;
            max = (long)v;
            break;
        case 'd': dir = optarg; break;
        case 'k': keep = 1; break;
        case 'h': fputs(bench_usage, stdout); return 0;
        default: return srv_usage_hint("bench db", argv);
        }
    }
    char tmp[256] = "", path[4096];
    if (!dir) {
        snprintf(tmp, sizeof tmp, "/tmp/gridsurvey-bench-db.XXXXXX");
        if (!mkdtemp(tmp))
            return srv_error("bench db", gs_fail(GS_EIO, "%s: cannot create a temporary directory: %s", tmp,
                                                 strerror(errno)));
        dir = tmp;
    }
    snprintf(path, sizeof path, "%s/bench.sqlite", dir);
    srv_db *db;
    gs_status s = srv_db_open(path, SRV_DB_CREATE, &db);
    if (s != GS_OK) return srv_error("bench db", s);
    srv_synth_opts o;
    srv_synth_opts_default(&o);
    o.survey = "bench";
    o.lights_per_capture = 1000;
    printf("# Survey database (`gridsurvey bench db`)\n\n"
           "One survey of synthetic lights (%zu per capture, one transaction per capture) ingested "
           "through srv_db_add_capture into a fresh file, growing to each size in turn; then the "
           "statistics queries on the whole survey. Wall-clock seconds on this machine.\n\n",
           o.lights_per_capture);
    printf("| lights | ingest s | lights/s | file+WAL MB | stats technology s | stats cell:250m s | "
           "stats radius:500m s | view phase_balance s | bbox 1 km2 read s | db check s |\n"
           "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    fflush(stdout);
    long have = 0;
    double lat_half = 500.0 / GIS_EARTH_RADIUS_M * 180.0 / M_PI;
    double lon_half = lat_half / cos(o.lat_deg * M_PI / 180.0);
    char radius[96];
    snprintf(radius, sizeof radius, "radius:%.6f,%.6f,500", o.lat_deg, o.lon_deg);
    for (long size = 10000; size <= max && s == GS_OK; size *= 10) {
        o.captures = (size_t)(size / 1000);
        double t0 = gs_clock_s(CLOCK_MONOTONIC);
        s = srv_synth_ingest(db, &o, NULL);
        double ingest = gs_clock_s(CLOCK_MONOTONIC) - t0;
        if (s != GS_OK) break;
        double t_tech = 0, t_cell = 0, t_rad = 0, t_view = 0, t_box = 0, t_check = 0;
        if ((s = srv_bench_time_stats(db, NULL, "technology", &t_tech)) != GS_OK ||
            (s = srv_bench_time_stats(db, NULL, "cell:250", &t_cell)) != GS_OK ||
            (s = srv_bench_time_stats(db, NULL, radius, &t_rad)) != GS_OK ||
            (s = srv_bench_time_view(db, "SELECT * FROM phase_balance", &t_view)) != GS_OK)
            break;
        srv_export_opts eo;
        srv_export_opts_default(&eo);
        eo.use_bbox = 1;
        eo.bbox[0] = o.lon_deg - lon_half;
        eo.bbox[1] = o.lat_deg - lat_half;
        eo.bbox[2] = o.lon_deg + lon_half;
        eo.bbox[3] = o.lat_deg + lat_half;
        gis_light *l = NULL;
        size_t nl = 0;
        t0 = gs_clock_s(CLOCK_MONOTONIC);
        s = srv_db_read_lights(db, &eo, &l, &nl);
        t_box = gs_clock_s(CLOCK_MONOTONIC) - t0;
        free(l);
        if (s != GS_OK) break;
        srv_db_report rep;
        t0 = gs_clock_s(CLOCK_MONOTONIC);
        s = srv_db_check(db, &rep);
        t_check = gs_clock_s(CLOCK_MONOTONIC) - t0;
        if (s == GS_OK && !srv_db_report_ok(&rep))
            s = gs_fail(GS_EFORMAT, "%s: db check failed at %ld lights", path, size);
        if (s != GS_OK) break;
        struct stat st;
        double mb = 0.0;
        if (stat(path, &st) == 0) mb += (double)st.st_size;
        char wal[4200];
        snprintf(wal, sizeof wal, "%s-wal", path);
        if (stat(wal, &st) == 0) mb += (double)st.st_size;
        printf("| %ld | %.2f | %.0f | %.1f | %.3f | %.3f | %.4f | %.3f | %.4f | %.2f |\n", size, ingest,
               (double)(size - have) / ingest, mb / 1048576.0, t_tech, t_cell, t_rad, t_view, t_box,
               t_check);
        fflush(stdout);
        have = size;
    }
    srv_db_close(db);
    if (!keep) {
        char p[4200];
        static const char *const suffix[] = {"", "-wal", "-shm"};
        for (int i = 0; i < 3; i++) {
            snprintf(p, sizeof p, "%s%s", path, suffix[i]);
            unlink(p);
        }
        if (*tmp) rmdir(tmp);
    }
    if (s != GS_OK) return srv_error("bench db", s);
    return 0;
}
