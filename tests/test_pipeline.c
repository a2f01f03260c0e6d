/* test_pipeline.c - `gridsurvey run` (survey/pipeline.c, survey/cmd_run.c); `gridsurvey
 * evaluate` is tested in tests/test_evaluate.c.
 *
 * Oracles are independent of the code under test: stored lights are read with plain SQLite
 * queries and the simulator's truth.json with Jansson, and matched here by their own rule;
 * after each SIGKILL the database is inspected through a raw SQLite connection
 * (integrity_check, foreign_key_check, each capture complete); a resumed run is compared with
 * an uninterrupted one row by row; bad input is checked against the bytes of the database and a
 * listing of every file in the test directory.
 *
 * Cost: the built-in lab scene once (`pipeline_lab_end_to_end_matches_truth`, ~5 s), and a
 * half-size lab scene (320 x 240, C = 128, ~1 s per run) for everything else. */
#include "survey/survey.h"
#include "tests/fixtures.h"
#include "tests/survey_fixture.h"
#include "tests/test.h"

#include <dirent.h>
#include <fcntl.h>
#include <jansson.h>
#include <math.h>
#include <signal.h>
#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

static char out[1 << 17];
/* A printf-style shell command (tests/fixtures.h), its output in out. */
#define sh(...) fx_run(out, sizeof out, __VA_ARGS__)

static void write_small_lab(const char *path, double scale, const char *bulb)
{
    survey_lab_spec spec = survey_fx_lab_spec();
    if (bulb) spec.bulb[0] = bulb;
    survey_fx_small_lab(path, scale, &spec);
}

/* ------------------------------------------------------------------ independent readers */

typedef struct {
    double x, y, phase;
    char bulb[64], tech[64];
    int in_image;
} light;

/* Stored lights of a database (every capture), read with plain SQL. */
static size_t db_lights(const char *path, light *v, size_t max)
{
    sqlite3 *h = NULL;
    size_t n = 0;
    if (sqlite3_open_v2(path, &h, SQLITE_OPEN_READONLY, NULL) != SQLITE_OK) {
        test_failed(__FILE__, __LINE__, "%s: %s", path, sqlite3_errmsg(h));
        sqlite3_close(h);
        return 0;
    }
    sqlite3_stmt *q = NULL;
    if (sqlite3_prepare_v2(h, "SELECT x_px, y_px, coalesce(bulb_id, ''), coalesce(technology, ''), "
                              "phase_deg FROM lights ORDER BY id", -1, &q, NULL) == SQLITE_OK) {
        while (sqlite3_step(q) == SQLITE_ROW && n < max) {
            light *l = &v[n++];
            l->x = sqlite3_column_double(q, 0);
            l->y = sqlite3_column_double(q, 1);
            snprintf(l->bulb, sizeof l->bulb, "%s", (const char *)sqlite3_column_text(q, 2));
            snprintf(l->tech, sizeof l->tech, "%s", (const char *)sqlite3_column_text(q, 3));
            l->phase = sqlite3_column_type(q, 4) == SQLITE_NULL ? NAN : sqlite3_column_double(q, 4);
            l->in_image = 1;
        }
    }
    sqlite3_finalize(q);
    sqlite3_close(h);
    return n;
}

/* The lights of a truth.json, read with Jansson. */
static size_t truth_lights(const char *path, light *v, size_t max)
{
    json_error_t err;
    json_t *root = json_load_file(path, 0, &err), *arr = json_object_get(root, "lights");
    CHECK_MSG(root && json_is_array(arr), "%s: %s", path, err.text);
    size_t n = 0, i;
    json_t *o;
    json_array_foreach(arr, i, o) {
        if (n == max) break;
        light *l = &v[n++];
        l->x = json_number_value(json_object_get(o, "x_px"));
        l->y = json_number_value(json_object_get(o, "y_px"));
        l->phase = json_number_value(json_object_get(o, "phase_deg"));
        snprintf(l->bulb, sizeof l->bulb, "%s", json_string_value(json_object_get(o, "bulb")));
        snprintf(l->tech, sizeof l->tech, "%s", json_string_value(json_object_get(o, "technology")));
        l->in_image = json_is_true(json_object_get(o, "in_image"));
    }
    json_decref(root);
    return n;
}

static double phase_diff(double a, double b)
{
    double d = fmod(fabs(a - b), 360.0);
    return d > 180.0 ? 360.0 - d : d;
}

/* Every truth light in the image has a stored light within 2 px with its bulb, technology and
 * phase (within 20 deg); every stored light with a bulb is one of them. Returns lights right. */
static int check_against_truth(const char *db, const char *truth, int expect_in_image)
{
    light st[64], tr[64];
    size_t ns = db_lights(db, st, 64), nt = truth_lights(truth, tr, 64);
    int in_image = 0, right = 0, used[64] = {0};
    for (size_t j = 0; j < nt; j++) {
        if (!tr[j].in_image) continue;
        in_image++;
        int best = -1;
        double bd = 2.0;
        for (size_t i = 0; i < ns; i++) {
            double d = hypot(st[i].x - tr[j].x, st[i].y - tr[j].y);
            if (d <= bd) {
                bd = d;
                best = (int)i;
            }
        }
        CHECK_MSG(best >= 0, "%s: truth light at (%.1f, %.1f) was not detected", truth, tr[j].x, tr[j].y);
        if (best < 0) continue;
        used[best] = 1;
        const light *s = &st[best];
        int ok = !strcmp(s->bulb, tr[j].bulb) && !strcmp(s->tech, tr[j].tech) && isfinite(s->phase) &&
                 phase_diff(s->phase, tr[j].phase) <= 20.0;
        CHECK_MSG(ok, "light at (%.1f, %.1f): stored %s/%s/%.1f, truth %s/%s/%.1f", tr[j].x, tr[j].y,
                  s->bulb, s->tech, s->phase, tr[j].bulb, tr[j].tech, tr[j].phase);
        right += ok;
    }
    CHECK(in_image == expect_in_image);
    for (size_t i = 0; i < ns; i++)
        CHECK_MSG(used[i] || !st[i].bulb[0], "stored light %zu at (%.1f, %.1f) has bulb %s but no truth light",
                  i, st[i].x, st[i].y, st[i].bulb);
    return right;
}

/* Every row of the content tables as text, without ids, paths and timestamps (which differ
 * between two runs into different places), in a fixed order. */
static char *dump_db(const char *path)
{
    static const char *const queries[] = {
        "SELECT name, city, grid_hz, started_utc, notes FROM surveys ORDER BY name",
        "SELECT sha256, generator, source, bulbs FROM delight_versions ORDER BY sha256",
        "SELECT name, lat_deg, lon_deg, height_m, heading_deg, pitch_deg, roll_deg, focal_px, cx_px, "
        "cy_px, width_px, height_px, refraction_k, sigma_px, time_utc FROM stations ORDER BY name",
        "SELECT capture_key, utc, grid_hz, K, bands, width_px, height_px, locked, light_count, "
        "frame_count, frequency_count FROM captures ORDER BY capture_key",
        "SELECT k, file, cycles, hdr_map FROM frames ORDER BY capture_id, k",
        "SELECT light_index, x_px, y_px, area_px, peak_dn, saturated_px, blob_flags, brightness, snr, "
        "chi2, dof, p_value, bulb_id, technology, phase_deg, phase_fit_deg, phase_sigma_deg, "
        "confidence, bulb_confidence, phase_confidence, runner_bulb_id, runner_phase_deg, "
        "runner_confidence, match_flags FROM lights ORDER BY capture_id, light_index",
        "SELECT l.light_index, method, lat_deg, lon_deg, height_m, semi_major_m, semi_minor_m, "
        "azimuth_deg, range_m, flags FROM locations JOIN lights l ON l.id = light_id "
        "ORDER BY l.capture_id, l.light_index",
    };
    sqlite3 *h = NULL;
    if (sqlite3_open_v2(path, &h, SQLITE_OPEN_READONLY, NULL) != SQLITE_OK) {
        sqlite3_close(h);
        return NULL;
    }
    char *buf = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&buf, &len);
    for (size_t k = 0; k < sizeof queries / sizeof *queries; k++) {
        sqlite3_stmt *q = NULL;
        if (sqlite3_prepare_v2(h, queries[k], -1, &q, NULL) != SQLITE_OK) {
            test_failed(__FILE__, __LINE__, "%s: %s", queries[k], sqlite3_errmsg(h));
            continue;
        }
        fprintf(f, "## %zu\n", k);
        while (sqlite3_step(q) == SQLITE_ROW) {
            for (int c = 0; c < sqlite3_column_count(q); c++) {
                const unsigned char *t = sqlite3_column_text(q, c);
                fprintf(f, "%s%s", c ? "|" : "", t ? (const char *)t : "NULL");
            }
            fputc('\n', f);
        }
        sqlite3_finalize(q);
    }
    fclose(f);
    sqlite3_close(h);
    return buf;
}

/* survey_fx_query_long on a read-only connection to the database at path (-1 if none). */
static long query_long(const char *path, const char *sql)
{
    sqlite3 *h = NULL;
    long v = -1;
    if (sqlite3_open_v2(path, &h, SQLITE_OPEN_READONLY, NULL) == SQLITE_OK)
        v = survey_fx_query_long(h, sql);
    sqlite3_close(h);
    return v;
}

/* Row counts of every table, as one string. */
static void counts(const char *db, char *buf, size_t size)
{
    snprintf(buf, size, "surveys %ld stations %ld delight %ld captures %ld frames %ld lights %ld locations %ld",
             query_long(db, "SELECT count(*) FROM surveys"), query_long(db, "SELECT count(*) FROM stations"),
             query_long(db, "SELECT count(*) FROM delight_versions"),
             query_long(db, "SELECT count(*) FROM captures"), query_long(db, "SELECT count(*) FROM frames"),
             query_long(db, "SELECT count(*) FROM lights"), query_long(db, "SELECT count(*) FROM locations"));
}

/* ------------------------------------------------------------------ end to end */

/* The built-in lab scene through `gridsurvey run` (under ASan, GS_SAN=1, the same scene at half
 * size): the eight lights are stored with the truth's bulb, technology and phase (read back
 * with SQL and Jansson); the run prints the phase balance and the evaluation and writes the
 * GeoJSON (no map: the lab has no station). A second run, and a run on the capture directory
 * itself, store nothing new. */
TEST(pipeline_lab_end_to_end_matches_truth)
{
    char db[1024], cap[1024], truth[1024], scene[1024] = "capture/scenes/lab.json";
    snprintf(db, sizeof db, "%s", fx_tmp("lab.sqlite"));
    snprintf(cap, sizeof cap, "%s", fx_tmp("lab-capture"));
    snprintf(truth, sizeof truth, "%s", fx_tmp("lab-capture/truth.json"));
    if (fx_sanitized()) {
        snprintf(scene, sizeof scene, "%s", fx_tmp("lab.json"));
        write_small_lab(scene, 0.5, NULL);
    }
    int rc = sh("%s run %s --db %s", test_bin(), scene, db);
    CHECK_MSG(rc == 0, "run: %d: %s", rc, out);
    if (rc != 0) return;
    CHECK(strstr(out, "run: survey lab, capture ") != NULL);
    CHECK(strstr(out, "no station: stored without a location") != NULL);
    CHECK(strstr(out, "| all | ") != NULL);                               /* phase balance */
    CHECK(strstr(out, "| detection rate | 100.0 % | 8 / 8 ") != NULL);      /* evaluation */
    CHECK(strstr(out, "| bulb accuracy | 100.0 % | 8 / 8 ") != NULL);
    CHECK(strstr(out, "| phase accuracy | 100.0 % | 8 / 8 ") != NULL);
    CHECK(fx_exists(fx_tmp("lab.geojson")) && !fx_exists(fx_tmp("lab-map.png")));
    CHECK(check_against_truth(db, truth, 8) == 8);
    /* the GeoJSON holds every stored light, without a geometry */
    json_error_t err;
    json_t *g = json_load_file(fx_tmp("lab.geojson"), 0, &err);
    json_t *features = json_object_get(g, "features");
    CHECK(json_is_array(features) &&
          (long)json_array_size(features) == query_long(db, "SELECT count(*) FROM lights"));
    json_t *f0 = json_array_get(features, 0);
    CHECK(json_is_null(json_object_get(f0, "geometry")));
    json_decref(g);
    /* the grid frequency log: one row per frame, the values of capture.json (read with Jansson),
     * committed with the capture; its mean on the capture row */
    char capjson[1100];
    snprintf(capjson, sizeof capjson, "%s/capture.json", cap);
    json_t *cj = json_load_file(capjson, 0, &err);
    json_t *cframes = json_object_get(cj, "frames");
    long n_frames = (long)json_array_size(cframes);
    CHECK(n_frames == 26);
    CHECK(query_long(db, "SELECT count(*) FROM grid_frequency") == n_frames);
    CHECK(query_long(db, "SELECT frequency_count FROM captures") == n_frames);
    sqlite3 *h = NULL;
    CHECK(sqlite3_open_v2(db, &h, SQLITE_OPEN_READONLY, NULL) == SQLITE_OK);
    sqlite3_stmt *q = NULL;
    CHECK(sqlite3_prepare_v2(h, "SELECT t_s, window_s, frequency_hz, sigma_hz FROM grid_frequency "
                             "WHERE capture_id = (SELECT id FROM captures) AND seq = ?",
                             -1, &q, NULL) == SQLITE_OK);
    double sum = 0, last_t = -1;
    for (long i = 0; q && i < n_frames; i++) {
        json_t *fr = json_array_get(cframes, (size_t)i);
        double hz = json_number_value(json_object_get(fr, "grid_hz_measured"));
        double t = json_number_value(json_object_get(fr, "start_s"));
        double cyc = json_number_value(json_object_get(fr, "cycles"));
        CHECK(json_is_number(json_object_get(fr, "grid_hz_measured")) &&
              json_is_number(json_object_get(fr, "start_s")));
        CHECK_NEAR(hz, 50.0, 1e-9);   /* the lab's grid: constant at nominal */
        sum += hz;
        /* rows are in time order; the lab's frames are acquired in k order */
        sqlite3_reset(q);
        sqlite3_bind_int64(q, 1, i);
        CHECK(sqlite3_step(q) == SQLITE_ROW);
        CHECK(sqlite3_column_double(q, 0) == t && t > last_t);
        CHECK_NEAR(sqlite3_column_double(q, 1), cyc / (2.0 * hz), 1e-12);
        CHECK(sqlite3_column_double(q, 2) == hz);
        CHECK(sqlite3_column_type(q, 3) == SQLITE_NULL);
        last_t = t;
    }
    sqlite3_finalize(q);
    sqlite3_close(h);
    json_decref(cj);
    CHECK(query_long(db, "SELECT abs(mean_frequency_hz - 50.0) < 1e-9 AND "
                         "abs(sigma_frequency_hz) < 1e-9 FROM captures") == 1);
    CHECK_NEAR(sum / (double)n_frames, 50.0, 1e-9);

    char before[512], after[512];
    counts(db, before, sizeof before);
    CHECK(query_long(db, "SELECT count(*) FROM captures") == 1);
    CHECK(query_long(db, "SELECT count(*) FROM locations") == 0);
    rc = sh("%s run %s --db %s", test_bin(), scene, db);
    CHECK_MSG(rc == 0 && strstr(out, "already in"), "second run: %d: %s", rc, out);
    CHECK(strstr(out, "| detection rate | 100.0 % | 8 / 8 ") != NULL);
    /* the same capture from its directory, whose default survey name is the directory's: the
     * survey that holds it */
    rc = sh("%s run %s --db %s", test_bin(), cap, db);
    CHECK_MSG(rc == 0 && strstr(out, "already in") && strstr(out, "run: survey lab, capture "),
              "capture directory run: %d: %s", rc, out);
    counts(db, after, sizeof after);
    CHECK_MSG(!strcmp(before, after), "%s -> %s", before, after);
    CHECK(query_long(db, "SELECT count(*) FROM (SELECT survey_id, capture_key FROM captures "
                         "GROUP BY 1, 2 HAVING count(*) > 1)") == 0);
    /* `gridsurvey evaluate` on its own agrees with the run */
    rc = sh("%s evaluate --db %s --truth %s --format json", test_bin(), db, truth);
    CHECK(rc == 0);
    json_t *ev = json_loads(out, 0, &err);
    CHECK(json_integer_value(json_object_get(json_object_get(ev, "detection"), "count")) == 8);
    CHECK(json_integer_value(json_object_get(json_object_get(ev, "phase"), "count")) == 8);
    json_decref(ev);
    /* a truth file of another capture (here: another width, in another directory, so the only
     * capture is the candidate) is refused, naming the field */
    json_t *tj = json_load_file(truth, 0, &err);
    long long w = json_integer_value(json_object_get(tj, "width"));
    CHECK(w > 0 && json_object_set_new(tj, "width", json_integer(w + 1)) == 0);
    CHECK(mkdir(fx_tmp("other"), 0777) == 0 && json_dump_file(tj, fx_tmp("other/truth.json"), 0) == 0);
    json_decref(tj);
    rc = sh("%s evaluate --db %s --truth %s", test_bin(), db, fx_tmp("other/truth.json"));
    CHECK_MSG(rc != 0 && strstr(out, "truth.json: width ") && strstr(out, "a truth file of another capture"),
              "%d: %s", rc, out);
    /* another survey named on purpose stores it again (docs/pipeline.md: to redo a capture) */
    rc = sh("%s run %s --db %s --survey redo", test_bin(), cap, db);
    CHECK_MSG(rc == 0 && strstr(out, "stored as capture"), "--survey redo: %d: %s", rc, out);
    CHECK(query_long(db, "SELECT count(*) FROM captures") == 2);
    /* ... and says which survey holds it already (its sites would count it twice) */
    CHECK_MSG(strstr(out, "run: note: survey lab holds the same capture") != NULL, "%s", out);
}

/* A scene of geographic lights seen from a station: located at the scene's median height,
 * GeoJSON coordinates and the map written, location errors small against the truth. */
TEST(pipeline_geographic_scene_locates_lights)
{
    const char *scene = fx_tmp("geo.json"), *db = fx_tmp("geo.sqlite");
    survey_fx_geo_scene(scene, 1.0, 6, 128);
    int rc = sh("%s run %s --db %s", test_bin(), scene, db);
    CHECK_MSG(rc == 0, "run: %d: %s", rc, out);
    if (rc != 0) return;
    CHECK(strstr(out, "at 10.00 m above the ellipsoid (scene median)") != NULL);
    CHECK(strstr(out, "| detection rate | 100.0 % | 6 / 6 ") != NULL);
    CHECK(fx_exists(fx_tmp("geo-map.png")) && fx_exists(fx_tmp("geo.geojson")));
    CHECK(check_against_truth(db, fx_tmp("geo-capture/truth.json"), 6) == 6);
    CHECK(query_long(db, "SELECT count(*) FROM locations WHERE lat_deg IS NOT NULL AND height_m = 10") == 6);
    CHECK(query_long(db, "SELECT count(*) FROM stations WHERE name = 'geo' AND lat_deg = 32.8") == 1);
    rc = sh("%s evaluate --db %s --truth %s --format json", test_bin(), db, fx_tmp("geo-capture/truth.json"));
    json_error_t err;
    json_t *ev = json_loads(out, 0, &err), *loc = json_object_get(ev, "location_error");
    CHECK_MSG(rc == 0 && loc, "%s", out);
    CHECK(json_integer_value(json_object_get(loc, "pairs")) == 6);
    double med = json_number_value(json_object_get(loc, "median_m")),
           mx = json_number_value(json_object_get(loc, "max_m"));
    /* 0.05 px of centroid error at 8-15 deg below the horizon and 0.5-0.9 km: ~0.1-0.3 m */
    CHECK_MSG(med < 0.5 && mx < 1.5, "location error median %.3f m, max %.3f m", med, mx);
    json_decref(ev);
    /* the GeoJSON's positions are the stored ones */
    json_t *g = json_load_file(fx_tmp("geo.geojson"), 0, &err), *features = json_object_get(g, "features");
    size_t i;
    json_t *f;
    int with_geometry = 0;
    json_array_foreach(features, i, f) {
        json_t *c = json_object_get(json_object_get(f, "geometry"), "coordinates");
        with_geometry += json_is_array(c) && fabs(json_number_value(json_array_get(c, 1)) - 32.805) < 0.01;
    }
    CHECK(with_geometry >= 6);
    json_decref(g);
    /* a capture directory with a station needs the lights' height */
    rc = sh("%s run %s --db %s --survey other", test_bin(), fx_tmp("geo-capture"), db);
    CHECK_MSG(rc == 1 && fx_count_lines(out) == 1 && strstr(out, "--light-height-m"), "%d: %s", rc, out);
    /* the scene's capture, already in survey geo; another survey named on purpose stores it */
    rc = sh("%s run %s --db %s --light-height-m 10", test_bin(), fx_tmp("geo-capture"), db);
    CHECK_MSG(rc == 0 && strstr(out, "already in"), "%d: %s", rc, out);
    CHECK(query_long(db, "SELECT count(*) FROM captures") == 1);
    rc = sh("%s run %s --db %s --survey other --light-height-m 10", test_bin(), fx_tmp("geo-capture"), db);
    CHECK_MSG(rc == 0, "%d: %s", rc, out);
    CHECK(query_long(db, "SELECT count(*) FROM captures") == 2);
    /* two surveys whose names differ only by a character a file name cannot hold write two
     * files (both were a_b.geojson: the second overwrote the first's) */
    const char *od = fx_tmp("named");
    for (int k = 0; k < 2; k++) {
        rc = sh("%s run %s --db %s --survey %s --light-height-m 10 --out-dir %s", test_bin(), fx_tmp("geo-capture"),
                db, k ? "a_b" : "a/b", od);
        CHECK_MSG(rc == 0, "%d: %s", rc, out);
    }
    char p1[4096], p2[4096];
    snprintf(p1, sizeof p1, "%s/a%%2Fb.geojson", od);
    snprintf(p2, sizeof p2, "%s/a_b.geojson", od);
    CHECK(fx_exists(p1) && fx_exists(p2));
}

/* ------------------------------------------------------------------ SIGKILL and resume */

/* The child's progress callback: reports each stage on a pipe, and stops itself (SIGSTOP) at
 * the point the parent chose, so the parent's kill lands where it is meant to; continued, it
 * stops again at the next stage's first report, so that a kill meant for that stage lands
 * there at the latest, however slow the parent is. */
typedef struct {
    int fd;
    int stop_stage;            /* -1: never */
    const char *stop_detail;   /* prefix of the detail to stop at ("" = any) */
    int stopped;               /* stopped there already */
} child_ctx;

static void pipe_progress(void *ctx, srv_stage stage, const char *detail)
{
    child_ctx *c = ctx;
    char b = (char)('0' + (int)stage);
    if (write(c->fd, &b, 1) != 1) _exit(7);
    if (c->stopped ? (int)stage != c->stop_stage
                   : (int)stage == c->stop_stage && !strncmp(detail, c->stop_detail, strlen(c->stop_detail))) {
        c->stopped = 1;
        raise(SIGSTOP);
    }
}

/* The frames (frame_*.png) in dir. */
static int frames_in(const char *dir)
{
    DIR *d = opendir(dir);
    int n = 0;
    for (struct dirent *e; d && (e = readdir(d));) {
        size_t len = strlen(e->d_name);
        n += !strncmp(e->d_name, "frame_", 6) && len > 4 && !strcmp(e->d_name + len - 4, ".png");
    }
    if (d) closedir(d);
    return n;
}

/* Waits, the child continued in the capture, until it has written n more frames into cap, then
 * for u of its own time per frame: a kill then lands during the capture whatever the load, with
 * frames left to acquire (n is a fraction of them). 0 then, or when it stopped meanwhile (at the
 * next stage); 1 if it ended (*status). */
static int wait_frames(pid_t pid, const char *cap, int n, double u, int *status)
{
    int base = frames_in(cap);
    double t0 = gs_clock_s(CLOCK_MONOTONIC);
    while (frames_in(cap) < base + n) {
        pid_t w = waitpid(pid, status, WNOHANG | WUNTRACED);
        if (w == pid) return !WIFSTOPPED(*status);
        usleep(500);
    }
    usleep((useconds_t)(u * (gs_clock_s(CLOCK_MONOTONIC) - t0) / n * 1e6));
    return 0;
}

static void run_child(const char *scene, const char *db, const char *capdir, child_ctx *c)
{
    srv_run_opts o;
    srv_run_opts_default(&o);
    o.input = scene;
    o.db_path = db;
    o.capture_dir = capdir;
    o.progress = pipe_progress;
    o.progress_ctx = c;
    srv_run_report r;
    gs_status s = srv_run(&o, &r);
    _exit(s == GS_OK ? 0 : 5);
}

/* After a kill: through a raw connection, integrity_check ok, no foreign-key violation, every
 * capture complete (its lights and frames as counted when it was stored), at most one. The
 * number of those that failed (each a test failure too). */
static int check_after_kill(const char *db, int kill_no)
{
    if (!fx_exists(db)) return 0;
    sqlite3 *h = NULL;
    if (sqlite3_open_v2(db, &h, SQLITE_OPEN_READWRITE, NULL) != SQLITE_OK) {
        test_failed(__FILE__, __LINE__, "kill %d: %s: %s", kill_no, db, sqlite3_errmsg(h));
        sqlite3_close(h);
        return 1;
    }
    const char *ok = survey_fx_query_text(h, "PRAGMA integrity_check");
    int bad = strcmp(ok, "ok") != 0;
    CHECK_MSG(!bad, "kill %d: integrity_check: %s", kill_no, *ok ? ok : "(none)");
    static const char *const zero[] = {
        "SELECT count(*) FROM pragma_foreign_key_check",
        ("SELECT count(*) FROM captures c WHERE light_count != (SELECT count(*) FROM lights WHERE "
         "capture_id = c.id) OR frame_count != (SELECT count(*) FROM frames WHERE capture_id = c.id)"),
        "SELECT count(*) > 1 FROM captures",
    };
    for (size_t k = 0; survey_fx_has(h, "captures") && k < sizeof zero / sizeof *zero; k++) {
        long v = survey_fx_query_long(h, zero[k]);
        bad += v != 0;
        CHECK_MSG(v == 0, "kill %d: %s -> %ld", kill_no, zero[k], v);
    }
    sqlite3_close(h);
    return bad;
}

/* SIGKILL `run` 8 times at increasing points: at start-up; three times during the acquisition
 * (which resumes, so each kill lands further into it); at the start of blob extraction and
 * during Eq. 7; and twice in the database write: right before the capture's transaction and
 * shortly after it began (which may be after its commit). The child stops itself at the chosen
 * stage (its progress callback), the parent resumes it and kills it after a random delay: in
 * the capture, once a random number of frames more are on disk and a random part of the
 * child's own time per frame; elsewhere, scaled by that stage's duration in an uninterrupted
 * reference run, the child stopping itself at the next stage if it gets there first. So the
 * kills land where intended on any machine, loaded or under ASan: the capture's used to be
 * timed by the reference's too, and a reference slowed by load (2 to 3 x, measured on a loaded
 * 2-core machine) let the child finish the capture, even the run, before the kill (failing
 * "kills during the capture: 1" or "no kill during the database write"). After each kill the
 * database is consistent; a final run through the CLI resumes and yields exactly the
 * reference's rows and capture files (the same content key); one more run adds nothing. */
TEST(pipeline_sigkill_resumes_to_same_content)
{
    char scene[1024], ref_db[1024], db[1024], ref_cap[1024], cap[1024];
    snprintf(scene, sizeof scene, "%s", fx_tmp("small.json"));
    snprintf(ref_db, sizeof ref_db, "%s", fx_tmp("ref.sqlite"));
    snprintf(db, sizeof db, "%s", fx_tmp("crash.sqlite"));
    snprintf(ref_cap, sizeof ref_cap, "%s", fx_tmp("ref-cap"));
    snprintf(cap, sizeof cap, "%s", fx_tmp("crash-cap"));
    write_small_lab(scene, 0.25, NULL);
    srv_run_opts o;
    srv_run_opts_default(&o);
    o.input = scene;
    o.db_path = ref_db;
    o.capture_dir = ref_cap;
    srv_run_report ref;
    CHECK_OK(srv_run(&o, &ref));
    CHECK(check_against_truth(ref_db, fx_tmp("ref-cap/truth.json"), 8) == 8);
    static const struct {
        int stage;            /* where the child stops; -1: it does not */
        const char *detail;   /* ... at the call whose detail starts so */
        double lo, hi;        /* then the kill after a delay uniform in [lo, hi] x the stage's
                               * reference duration (start-up: seconds; the capture: after
                               * floor([lo, hi] x K) frames more, see wait_frames) */
    } plan[8] = {
        {-1, "", 0.001, 0.003},
        {SRV_STAGE_CAPTURE, "", 0.1, 0.2}, {SRV_STAGE_CAPTURE, "", 0.15, 0.25},
        {SRV_STAGE_CAPTURE, "", 0.15, 0.25},
        {SRV_STAGE_BLOBS, "", 0.0, 0.0},   {SRV_STAGE_MATCH, "", 0.0, 0.5},
        {SRV_STAGE_STORE, "capture:", 0.0, 0.0}, {SRV_STAGE_STORE, "capture:", 0.0, 1.0},
    };
    double store_tx_s = 0.002;   /* the capture's transaction: a few ms (lights are few) */
    int killed_in[SRV_STAGE_COUNT + 1] = {0};
    char trace[512] = "";
    uint64_t rng = 0x9e3779b97f4a7c15ull;
    for (int k = 0; k < 8; k++) {
        rng = rng * 6364136223846793005ull + 1442695040888963407ull;
        double u = (double)(rng >> 11) / 9007199254740992.0;
        double span = plan[k].stage < 0 ? 1.0
                      : plan[k].stage == SRV_STAGE_STORE ? store_tx_s : ref.seconds[plan[k].stage];
        double wait_s = (plan[k].lo + u * (plan[k].hi - plan[k].lo)) * span;
        child_ctx cc = {-1, plan[k].stage, plan[k].detail, 0};
        int fd;
        pid_t pid = fx_fork_pipe(&fd);
        if (pid == 0) {
            cc.fd = fd;
            run_child(scene, db, cap, &cc);
        }
        int status = 0, last = -1, gone = 0;
        char c;
        if (plan[k].stage >= 0) {
            /* wait until it stops itself (or ends: a stage it never reaches) */
            if (waitpid(pid, &status, WUNTRACED) == pid && !WIFSTOPPED(status)) gone = 1;
            while (read(fd, &c, 1) == 1 && !gone) {
                last = c - '0';
                if (last == plan[k].stage) break;
            }
            /* a zero delay kills it where it stopped; otherwise it runs on for wait_s */
            if (!gone && plan[k].hi > 0.0) kill(pid, SIGCONT);
        }
        if (!gone && plan[k].stage == SRV_STAGE_CAPTURE) {
            int more = (int)((plan[k].lo + u * (plan[k].hi - plan[k].lo)) * frames_in(ref_cap));
            rng = rng * 6364136223846793005ull + 1442695040888963407ull;
            gone = wait_frames(pid, cap, more > 1 ? more : 1, (double)(rng >> 11) / 9007199254740992.0, &status);
        } else if (!gone) {
            usleep((useconds_t)(wait_s * 1e6));
        }
        if (!gone) {
            kill(pid, SIGKILL);
            waitpid(pid, &status, 0);
        }
        while (read(fd, &c, 1) == 1) last = c - '0';   /* where it got to */
        close(fd);
        int was_killed = WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL;
        CHECK_MSG(was_killed || (WIFEXITED(status) && WEXITSTATUS(status) == 0),
                  "kill %d: the child exited with %d", k, WIFEXITED(status) ? WEXITSTATUS(status) : -1);
        if (was_killed) killed_in[last + 1]++;
        size_t used = strlen(trace);
        snprintf(trace + used, sizeof trace - used, " %s%s", last >= 0 ? srv_stage_name((srv_stage)last) : "start",
                 was_killed ? "" : "(done)");
        check_after_kill(db, k);
    }
    if (getenv("GS_TEST_VERBOSE")) printf("    killed in:%s\n", trace);
    CHECK_MSG(killed_in[SRV_STAGE_CAPTURE + 1] >= 2, "kills during the capture: %d (%s)",
              killed_in[SRV_STAGE_CAPTURE + 1], trace);
    CHECK_MSG(killed_in[SRV_STAGE_BLOBS + 1] + killed_in[SRV_STAGE_MATCH + 1] >= 1, "no kill during "
              "recognition (%s)", trace);
    CHECK_MSG(killed_in[SRV_STAGE_STORE + 1] >= 1, "no kill during the database write (%s)", trace);
    /* resume through the CLI, then once more */
    int rc = sh("%s run %s --db %s --capture-dir %s", test_bin(), scene, db, cap);
    CHECK_MSG(rc == 0, "resume: %d: %s", rc, out);
    rc = sh("%s run %s --db %s --capture-dir %s", test_bin(), scene, db, cap);
    CHECK_MSG(rc == 0 && strstr(out, "already in"), "last run: %d: %s", rc, out);
    char *a = dump_db(ref_db), *b = dump_db(db);
    CHECK_MSG(a && b && !strcmp(a, b), "the resumed database differs from the uninterrupted one");
    CHECK(b && strstr(b, ref.key) != NULL);
    free(a);
    free(b);
    CHECK(sh("cmp -s %s/frame_013.png %s/frame_013.png && cmp -s %s/truth.json %s/truth.json", ref_cap,
             cap, ref_cap, cap) == 0);
}

/* `gridsurvey run` (the CLI, a process of its own) SIGKILLed at a moment uniform over its whole
 * duration (1.05 x an uninterrupted run's, measured here), each time from scratch; then the
 * database is checked (check_after_kill), the run resumed to its end, and its rows and capture
 * files compared with the uninterrupted run's. Tries until `kills` kills have landed while the
 * run was going (at most 4 x kills tries; *before_end the tries whose run had ended first, checked
 * the same way). Counts corrupt databases, failed resumes and resumed databases whose rows differ
 * from the reference (duplicates among them) in *bad[3]; each is a test failure too. */
static void random_kills(int kills, uint64_t seed, int bad[3], int *before_end)
{
    char scene[1024], ref_db[1024], ref_cap[1024], db[1024], cap[1024];
    snprintf(scene, sizeof scene, "%s", fx_tmp("small.json"));
    snprintf(ref_db, sizeof ref_db, "%s", fx_tmp("ref.sqlite"));
    snprintf(ref_cap, sizeof ref_cap, "%s", fx_tmp("ref-cap"));
    snprintf(db, sizeof db, "%s", fx_tmp("kill.sqlite"));
    snprintf(cap, sizeof cap, "%s", fx_tmp("kill-cap"));
    write_small_lab(scene, 0.25, NULL);
    struct timespec t0, t1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    int rc = sh("%s run %s --db %s --capture-dir %s", test_bin(), scene, ref_db, ref_cap);
    clock_gettime(CLOCK_MONOTONIC, &t1);
    CHECK_MSG(rc == 0, "reference run: %s", out);
    double run_s = (double)(t1.tv_sec - t0.tv_sec) + 1e-9 * (double)(t1.tv_nsec - t0.tv_nsec);
    char *ref = dump_db(ref_db);
    bad[0] = bad[1] = bad[2] = 0;
    *before_end = 0;
    int landed = 0, k = 0;
    for (; landed < kills && k < 4 * kills; k++) {
        sh("rm -rf %s %s %s-wal %s-shm %s-journal", cap, db, db, db, db);
        double wait_s = gs_splitmix_uniform(&seed) * 1.05 * run_s;
        fflush(stdout);
        pid_t pid = fork();
        if (pid == 0) {
            int devnull = open("/dev/null", O_WRONLY);
            dup2(devnull, STDOUT_FILENO);
            dup2(devnull, STDERR_FILENO);
            execl(test_bin(), test_bin(), "run", scene, "--db", db, "--capture-dir", cap, (char *)NULL);
            _exit(127);
        }
        usleep((useconds_t)(wait_s * 1e6));
        kill(pid, SIGKILL);
        int status = 0;
        waitpid(pid, &status, 0);
        int hit = WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL;
        landed += hit;
        *before_end += !hit;
        bad[0] += check_after_kill(db, k) != 0;
        rc = sh("%s run %s --db %s --capture-dir %s", test_bin(), scene, db, cap);
        CHECK_MSG(rc == 0, "kill %d after %.3f s: resume: %d: %s", k, wait_s, rc, out);
        bad[1] += rc != 0;
        char *got = dump_db(db);
        int differs = !ref || !got || strcmp(ref, got) ||
                      sh("cmp -s %s/frame_013.png %s/frame_013.png && cmp -s %s/truth.json %s/truth.json", ref_cap,
                         cap, ref_cap, cap) != 0;
        CHECK_MSG(!differs, "kill %d after %.3f s: the resumed database or capture differs from the "
                  "uninterrupted one", k, wait_s);
        bad[2] += differs;
        free(got);
    }
    free(ref);
    CHECK_MSG(landed == kills, "%d of %d kills landed during the run in %d tries", landed, kills, k);
    if (getenv("GS_TEST_VERBOSE") || kills > 10)
        printf("    %d random SIGKILLs landed during a %.2f s run, %d tries (%d after it had ended): %d corrupt "
               "databases, %d failed resumes, %d resumed databases unlike the reference\n", landed, run_s, k,
               *before_end, bad[0], bad[1], bad[2]);
}

/* A few of the campaign's random kills (`make kills`: 100 of them, docs/reliability.md). */
TEST(pipeline_random_sigkills_resume_to_same_content)
{
    int bad[3], late;
    random_kills(2, 0x5eed1234ull, bad, &late);
    CHECK(bad[0] == 0 && bad[1] == 0 && bad[2] == 0);
}

/* `make kills`: GS_KILLS (default 100) random kills, seed GS_KILL_SEED. */
TEST_HIDDEN(pipeline_sigkill_campaign, 0)
{
    const char *n = getenv("GS_KILLS"), *seed = getenv("GS_KILL_SEED");
    int bad[3], late;
    random_kills(n ? atoi(n) : 100, seed ? strtoull(seed, NULL, 0) : 0x9e3779b97f4a7c15ull, bad, &late);
    CHECK(bad[0] == 0 && bad[1] == 0 && bad[2] == 0);
}

/* ------------------------------------------------------------------ bad input */

/* Every bad input gets one line on stderr and a non-zero exit, and nothing changes on disk:
 * the database's bytes, and the listing (path, size, mtime, mode) of every file around it. */
TEST(pipeline_bad_input_changes_nothing)
{
    const char *dir = test_tmpdir();
    const char *scene = fx_tmp("small.json"), *db = fx_tmp("ok.sqlite"), *cap = fx_tmp("ok-cap");
    write_small_lab(scene, 0.25, NULL);
    int rc = sh("%s run %s --db %s --capture-dir %s", test_bin(), scene, db, cap);
    CHECK_MSG(rc == 0, "%d: %s", rc, out);
    if (rc != 0) return;
    /* the bad inputs */
    fx_write_text(fx_tmp("syntax.json"), "{\"format\": \"gridsurvey-scene/1\", \"grid\": {\"nominal_hz\": 50,,}\n");
    write_small_lab(fx_tmp("bulb.json"), 0.25, "no-such-bulb-9w");
    fx_write_text(fx_tmp("notes.txt"), "not a database\n");
    fx_write_text(fx_tmp("afile"), "a regular file\n");
    fx_write_text(fx_tmp("station-bad.json"), "{\"format\": \"gridsurvey-station/1\", \"lat_deg\": 32.8,\n \"lon\": }\n");
    fx_write_text(fx_tmp("station-ok.json"),
               "{\"lat_deg\": 32.8, \"lon_deg\": 35, \"height_m\": 100, \"heading_deg\": 0, \"pitch_deg\": -5, "
               "\"focal_px\": 200, \"cx_px\": 79.5, \"cy_px\": 59.5, \"width_px\": 160, \"height_px\": 120}\n");
    fx_write_text(fx_tmp("station-size.json"),
               "{\"lat_deg\": 32.8, \"lon_deg\": 35, \"height_m\": 100, \"heading_deg\": 0, \"pitch_deg\": -5, "
               "\"focal_px\": 400, \"cx_px\": 159.5, \"cy_px\": 119.5, \"width_px\": 640, \"height_px\": 480}\n");
    sqlite3 *h = NULL;
    CHECK(sqlite3_open(fx_tmp("other.sqlite"), &h) == SQLITE_OK);
    CHECK(sqlite3_exec(h, "CREATE TABLE t(x); INSERT INTO t VALUES (1)", NULL, NULL, NULL) == SQLITE_OK);
    sqlite3_close(h);
    CHECK(sh("cd %s && cp -r ok-cap missing && rm missing/frame_003.png && cp -r ok-cap trunc && "
             "truncate -s 900 trunc/frame_005.png && cp -r ok-cap wrongk && "
             "sed -i 's/\"K\": 26/\"K\": 25/' wrongk/capture.json && grep -q '\"K\": 25' wrongk/capture.json",
             dir) == 0);
    if (geteuid() != 0) CHECK(mkdir(fx_tmp("ro"), 0555) == 0);
    char listing[1 << 15];
    snprintf(out, sizeof out, "cd %s && find . -printf '%%p %%s %%T@ %%m\\n' | sort", dir);
    CHECK(test_run(out, listing, sizeof listing) == 0);
    size_t size_before, size_after;
    char *db_bytes = fx_read_file(db, &size_before);
    char bin[4096];
    CHECK(realpath(test_bin(), bin) != NULL);
    struct {
        const char *args;
        const char *expect;   /* in the one line */
    } cases[] = {
        {"syntax.json --db ok.sqlite", "syntax.json:1:"},
        {"bulb.json --db ok.sqlite", "no-such-bulb-9w"},
        {"missing --db ok.sqlite", "frame_003.png"},
        {"trunc --db ok.sqlite", "frame_005.png"},
        {"wrongk --db ok.sqlite", "capture.json"},
        {"no-such-dir --db ok.sqlite", "no-such-dir"},
        {"ok-cap --db notes.txt", "not a survey database"},
        {"ok-cap --db other.sqlite", "not a survey database"},
        {"ok-cap --db afile/survey.sqlite", "afile/survey.sqlite"},
        {"ok-cap --db missing-dir/survey.sqlite", "missing-dir/survey.sqlite"},
        {"small.json --db ok.sqlite --capture-dir afile/cap", "afile/cap"},
        {"ok-cap --db ok.sqlite --out-dir afile/out", "afile/out"},
        {"ok-cap --db new.sqlite --station station-bad.json", "station-bad.json:2"},
        {"ok-cap --db new.sqlite --station station-size.json --light-height-m 5", "640x480"},
        {"ok-cap --db new.sqlite --station station-ok.json", "--light-height-m"},
        {"ok-cap --db new.sqlite --station station-ok.json --light-height-m 1e6", "--light-height-m"},
        {"ok-cap --db new.sqlite --capture-dir elsewhere", "--capture-dir"},
        {"ok-cap --db new.sqlite --delight notes.txt", "notes.txt"},
        {"ok-cap --db ro/new.sqlite", "ro/new.sqlite"},
    };
    size_t n_cases = sizeof cases / sizeof *cases - (geteuid() == 0);
    for (size_t i = 0; i < n_cases; i++) {
        rc = sh("cd %s && %s run %s", dir, bin, cases[i].args);
        CHECK_MSG(rc == 1 && fx_count_lines(out) == 1 && strstr(out, cases[i].expect) &&
                  !strncmp(out, "gridsurvey run: ", 16),
                  "run %s: exit %d, output: %s", cases[i].args, rc, out);
    }
    /* usage errors: exit 2 */
    rc = sh("%s run %s", test_bin(), scene);
    CHECK(rc == 2 && fx_count_lines(out) == 1 && strstr(out, "--db"));
    rc = sh("%s run %s --db %s --phases 4", test_bin(), scene, db);
    CHECK(rc == 2 && fx_count_lines(out) == 1);
    char listing2[1 << 15];
    snprintf(out, sizeof out, "cd %s && find . -printf '%%p %%s %%T@ %%m\\n' | sort", dir);
    CHECK(test_run(out, listing2, sizeof listing2) == 0);
    CHECK_MSG(!strcmp(listing, listing2), "files changed:\nbefore:\n%s\nafter:\n%s", listing, listing2);
    char *db_after = fx_read_file(db, &size_after);
    CHECK(db_bytes && db_after && size_before == size_after && !memcmp(db_bytes, db_after, size_after));
    free(db_bytes);
    free(db_after);
}

/* srv_job_read holds the shared lock until srv_job_release (`run` hashes the files it read for
 * its content key after reading them): meanwhile a writer's exclusive lock (flock(1) -n) is
 * refused, afterwards taken. */
TEST(capture_job_holds_the_read_lock_until_release)
{
    const char *dir = fx_tmp("job-lock");
    CHECK(sh("%s simulate capture/scenes/lab.json --out-dir %s -q", test_bin(), dir) == 0);
    srv_job j;
    memset(&j, 0, sizeof j);
    CHECK_OK(srv_job_read(&j, dir));
    CHECK(sh("flock -n -x %s true; echo $?", dir) == 0 && !strcmp(out, "1\n"));
    srv_job_release(&j);
    CHECK(sh("flock -n -x %s true; echo $?", dir) == 0 && !strcmp(out, "0\n"));
}

/* A survey job locked its capture directory twice: srv_job_read took the shared lock, then
 * gs_capture_read took one of its own (one more open and flock(2) of the directory per read).
 * It now reads under the job's lock (gs_capture_read_held): `recognize`, through srv_job_read,
 * locks the directory once, shared, as strace(1) sees its system calls. (A sanitizer build's
 * LeakSanitizer cannot run under ptrace: it is turned off for the traced run.) */
TEST(capture_job_locks_its_directory_once)
{
    const char *dir = fx_tmp("job-lock-once");
    CHECK(sh("%s simulate capture/scenes/lab.json --out-dir %s -q", test_bin(), dir) == 0);
    int rc = sh("ASAN_OPTIONS=${ASAN_OPTIONS:+$ASAN_OPTIONS:}detect_leaks=0 strace -f -qq -e trace=flock -o %s.trace "
                "%s recognize %s >/dev/null && grep -o 'flock(.*' %s.trace | tr -s ' '",
                dir, test_bin(), dir, dir);
    printf("    %s", out);
    CHECK_MSG(rc == 0 && fx_count_lines(out) == 1 && strstr(out, ", LOCK_SH|LOCK_NB) = 0\n"),
              "exit %d (strace(1) is needed), the flock calls of recognize:\n%s", rc, out);
}
