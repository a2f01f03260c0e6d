/* test_hostile.c - the defects that issue 16's hostile-input tries found, each a test named
 * after it: a use after free in `delight plot --ids`, the README's example, the output rules of
 * the format kit ("-", symlinks, FIFOs), non-regular inputs, one range for every scene light
 * field, `stats --by cell` on no located lights and on a tampered database, one rule for an
 * empty database file, a failed run's database, the memory budget before any allocation,
 * --match-px's range, survey names, and the CLI habits (--version, help CMD). */
#include "capture/capture.h"
#include "recognize/base/base.h"
#include "tests/fixtures.h"
#include "tests/test.h"
#include "tests/transport_fixture.h"

#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

static char out[1 << 20];

static int run(const char *fmt, const char *a, const char *b, const char *c)
{
    return fx_run_bin(out, sizeof out, fmt, a, b, c);
}

TEST(delight_plot_bad_ids_message_after_free)
{
    /* the message formatted the token after its list was freed: garbage, or an ASan report */
    const char *png = fx_tmp("bad.png");
    CHECK(run("%s delight plot --ids no-such-bulb-16,inc-a19-60w-120v --grid 60 -o %s", png, NULL, NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "bulb 'no-such-bulb-16' not in the database"), "%s", out);
    CHECK(!fx_exists(png));
}

TEST(readme_delight_plot_example_runs)
{
    /* the README's own example, as written there, with -o into the test's directory */
    size_t n;
    char *readme = fx_read_file("README.md", &n);
    CHECK(readme != NULL);
    if (!readme) return;
    char *line = strstr(readme, "build/gridsurvey delight plot --ids ");
    CHECK(line != NULL);
    if (line) {
        char *end = strstr(line, " -o ");
        CHECK(end != NULL);
        if (end) {
            *end = '\0';
            const char *args = line + strlen("build/gridsurvey ");
            const char *png = fx_tmp("readme.png");
            CHECK_MSG(run("%s %s -o %s", args, png, NULL) == 0, "%s", out);
            CHECK(fx_exists(png));
        }
    }
    free(readme);
}

TEST(output_dash_is_stdout_not_a_file_named_dash)
{
    char cmd[8192], bin[4096];
    CHECK(realpath(test_bin(), bin) != NULL);
    snprintf(cmd, sizeof cmd, "cd %s && %s delight export -o -", test_tmpdir(), bin);
    CHECK(test_run(cmd, out, sizeof out) == 0);
    CHECK(!strncmp(out, "bulb_id,type,name,", 18));
    CHECK(!fx_exists(fx_tmp("-")));
    /* a by-name writer (PLplot) to stdout: the PNG alone on stdout, the note on stderr */
    const char *png = fx_tmp("stdout.png");
    snprintf(cmd, sizeof cmd, "cd %s && %s delight plot --grid 50 -o - > %s", test_tmpdir(), bin, png);
    CHECK(test_run(cmd, out, sizeof out) == 0 && strstr(out, "wrote -"));
    size_t n = 0;
    char *data = fx_read_file(png, &n);
    CHECK(data && n > 20000 && !memcmp(data, "\x89PNG\r\n\x1a\n", 8));
    free(data);
    CHECK(!fx_exists(fx_tmp("-")));
    /* stats' -o F.csv as well (it was refused: "expected a NAME.csv file") */
    const char *db = fx_tmp("dash.sqlite");
    CHECK(run("%s db init --db %s", db, NULL, NULL) == 0);
    snprintf(cmd, sizeof cmd, "cd %s && %s stats --db %s --format csv -o -", test_tmpdir(), bin, db);
    CHECK_MSG(test_run(cmd, out, sizeof out) == 0 && !strncmp(out, "group,lat_deg,", 14), "%s", out);
    CHECK(!fx_exists(fx_tmp("-")) && !fx_exists(fx_tmp("-.csvt")));
}

TEST(output_symlink_target_replaced_link_kept)
{
    const char *target = fx_tmp("target.csv"), *link = fx_tmp("link.csv");
    fx_write_text(target, "old\n");
    CHECK(symlink(target, link) == 0);
    CHECK(run("%s delight export -o %s", link, NULL, NULL) == 0);
    struct stat sb;
    CHECK(lstat(link, &sb) == 0 && S_ISLNK(sb.st_mode));
    char *text = fx_read_file(target, NULL);
    CHECK(text && !strncmp(text, "bulb_id,", 8));
    free(text);
}

TEST(output_fifo_written_through_not_replaced)
{
    const char *fifo = fx_tmp("out.fifo"), *got = fx_tmp("from_fifo.csv");
    CHECK(mkfifo(fifo, 0600) == 0);
    char cmd[4096];
    snprintf(cmd, sizeof cmd, "cat %s > %s & %s delight export -o %s; s=$?; wait; exit $s", fifo, got,
             test_bin(), fifo);
    CHECK(test_run(cmd, out, sizeof out) == 0);
    struct stat sb;
    CHECK(lstat(fifo, &sb) == 0 && S_ISFIFO(sb.st_mode));
    char *text = fx_read_file(got, NULL);
    CHECK(text && !strncmp(text, "bulb_id,", 8));
    free(text);
}

TEST(output_kit_rules_devnull_and_by_name)
{
    /* a device is written through (the /dev/stdout-as-root report: never replaced) */
    gs_atomic a;
    CHECK_OK(gs_atomic_open(&a, "/dev/null", 1));
    fputs("x", a.f);
    CHECK_OK(gs_atomic_commit(&a));
    struct stat sb;
    CHECK(stat("/dev/null", &sb) == 0 && S_ISCHR(sb.st_mode));
    /* a by-name writer to a FIFO-like target goes through a scratch copy */
    CHECK_OK(gs_atomic_open(&a, "/dev/null", 0));
    fx_write_text(a.tmp, "by name\n");
    char scratch[sizeof a.tmp];
    snprintf(scratch, sizeof scratch, "%s", a.tmp);
    CHECK_OK(gs_atomic_commit(&a));
    CHECK(!fx_exists(scratch));
    /* a regular file still gets temp + rename */
    const char *reg = fx_tmp("reg.txt");
    CHECK_OK(gs_file_write_atomic(reg, "abc", 3));
    char *text = fx_read_file(reg, NULL);
    CHECK(text && !strcmp(text, "abc"));
    free(text);
}

TEST(input_fifo_and_devices_refused_unless_dash)
{
    const char *fifo = fx_tmp("in.fifo");
    CHECK(mkfifo(fifo, 0600) == 0);
    char *data = NULL;
    /* a FIFO without a writer would block forever; /dev/zero never ends */
    CHECK(gs_file_read(fifo, 0, &data, NULL) == GS_EINVAL && strstr(gs_detail(), "a FIFO"));
    CHECK(gs_file_read("/dev/zero", 0, &data, NULL) == GS_EINVAL && strstr(gs_detail(), "character device"));
    CHECK(gs_input_check("/dev/zero") == GS_EINVAL);
    CHECK(data == NULL);
    /* `locate --pixels /dev/zero` looped forever; `--pixels -` failed */
    CHECK(run("%s locate --station /nonexistent.json --pixels /dev/zero -o %s", fx_tmp("x.geojson"), NULL, NULL) != 0);
    char cmd[4096];
    snprintf(cmd, sizeof cmd, "printf 'id,x_px\\n' | %s locate --station %s --pixels - -o %s 2>&1; true",
             test_bin(), "/nonexistent.json", fx_tmp("y.geojson"));
    test_run(cmd, out, sizeof out);
    CHECK(!strstr(out, "-: cannot open"));
}

static const char geo_scene[] =
    "{\"format\": \"gridsurvey-scene/1\", \"grid\": {\"nominal_hz\": 50},\n"
    " \"camera\": {\"width_px\": 800, \"height_px\": 600,\n"
    "   \"station\": {\"lat_deg\": 32.7940, \"lon_deg\": 34.9900, \"height_m\": 470},\n"
    "   \"pose\": {\"heading_deg\": 52, \"pitch_deg\": -5}, \"intrinsics\": {\"focal_px\": 2000}},\n"
    " \"acam\": {\"K\": 10, \"cycles\": 40},\n"
    " \"lights\": [{\"type\": \"geojson\", \"file\": \"hostile.geojson\"%s}]}\n";

static gs_status geojson_light(const char *props, const char *defaults)
{
    char path[1024], scene[4096];
    snprintf(path, sizeof path, "%s/hostile.geojson", test_tmpdir());
    char text[2048];
    snprintf(text, sizeof text, "{\"type\": \"FeatureCollection\", \"features\": [\n"
             " {\"type\": \"Feature\", \"geometry\": {\"type\": \"Point\", \"coordinates\": [35.03, 32.82, 25]},\n"
             "  \"properties\": {\"id\": \"a\", \"bulb\": \"hps-150w\"%s}}]}\n", props);
    fx_write_text(path, text);
    snprintf(scene, sizeof scene, geo_scene, defaults);
    cap_scene sc;
    gs_status s = cap_scene_parse(scene, "geo.json", test_tmpdir(), &sc);
    if (s == GS_OK) cap_scene_release(&sc);
    return s;
}

TEST(geojson_lumens_same_range_as_inline)
{
    CHECK_OK(geojson_light(", \"lumens\": 15000", ""));
    /* 1e308 lm made NaN pixels and exit 0; the inline path bounds lumens to 0..1e9 */
    CHECK(geojson_light(", \"lumens\": 1e308", "") == GS_EFORMAT);
    CHECK_MSG(strstr(gs_detail(), "lumens") && strstr(gs_detail(), "1e+09"), "%s", gs_detail());
    CHECK(geojson_light(", \"lumens\": 1.5e9", "") == GS_EFORMAT);
    CHECK(geojson_light(", \"flux_e_per_cycle\": 1e16", "") == GS_EFORMAT);
    CHECK(geojson_light("", ", \"defaults\": {\"lumens\": 1e308}") == GS_EFORMAT);
    CHECK(geojson_light(", \"lumens\": 1000, \"phase_deg\": 1e300", "") == GS_EFORMAT);
    /* the feature's own flux overrides the defaults' lumens (not "both given") */
    CHECK_OK(geojson_light(", \"flux_e_per_cycle\": 5000", ", \"defaults\": {\"lumens\": 1000}"));
}

TEST(stats_by_cell_without_located_lights_and_tampered_latitude)
{
    const char *db = fx_tmp("cells.sqlite");
    CHECK(run("%s db init --db %s", db, NULL, NULL) == 0);
    /* no located light: qsort(NULL, 0, ...) before (UBSan: nonnull) */
    CHECK_MSG(run("%s stats --db %s --by cell:250", db, NULL, NULL) == 0, "%s", out);
    CHECK(run("%s db ingest-synthetic --db %s --captures 1 --lights 20", db, NULL, NULL) == 0);
    CHECK_MSG(run("%s stats --db %s --by cell:250", db, NULL, NULL) == 0, "%s", out);
    /* a text latitude reached (long)floor(NaN): in a detection's location (stats --detections)
     * and in a site's position (stats) */
    char cmd[4096];
    snprintf(cmd, sizeof cmd, "sqlite3 %s \"PRAGMA ignore_check_constraints = 1; UPDATE locations SET "
             "lat_deg = 'north' WHERE rowid = (SELECT min(rowid) FROM locations WHERE lat_deg IS NOT NULL)\"", db);
    CHECK(test_run(cmd, out, sizeof out) == 0);
    CHECK(run("%s stats --db %s --by cell:250 --detections", db, NULL, NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "lat_deg") && strstr(out, "north"), "%s", out);
    snprintf(cmd, sizeof cmd, "sqlite3 %s \"PRAGMA ignore_check_constraints = 1; UPDATE light_sites SET "
             "lat_deg = 'south' WHERE rowid = (SELECT min(rowid) FROM light_sites WHERE lat_deg IS NOT NULL)\"", db);
    CHECK(test_run(cmd, out, sizeof out) == 0);
    CHECK(run("%s stats --db %s --by cell:250", db, NULL, NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "lat_deg") && strstr(out, "south"), "%s", out);
}

TEST(db_empty_file_one_rule_for_every_command)
{
    const char *empty = fx_tmp("empty.sqlite");
    fx_write_text(empty, "");
    const char *cmds[] = {"%s db migrate --db %s", "%s db check --db %s", "%s stats --db %s",
                          "%s export --db %s -o x.geojson", "%s run capture/scenes/lab.json --db %s"};
    for (size_t i = 0; i < sizeof cmds / sizeof *cmds; i++) {
        CHECK_MSG(run(cmds[i], empty, NULL, NULL) == 1, "%s: %s", cmds[i], out);
        CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "an empty file (0 bytes)") &&
                  strstr(out, "db init"), "%s: %s", cmds[i], out);
        struct stat sb;
        CHECK(stat(empty, &sb) == 0 && sb.st_size == 0);   /* unchanged */
    }
    /* an SQLite file without a schema (a creation killed before its first table) likewise */
    const char *bare = fx_tmp("bare.sqlite");
    char cmd[4096];
    snprintf(cmd, sizeof cmd, "sqlite3 %s 'PRAGMA page_size = 4096; VACUUM'", bare);
    CHECK(test_run(cmd, out, sizeof out) == 0);
    CHECK(run("%s db check --db %s", bare, NULL, NULL) == 1 && strstr(out, "SQLite without a schema"));
    CHECK(run("%s db migrate --db %s", bare, NULL, NULL) == 1 && strstr(out, "SQLite without a schema"));
    /* only db init adopts it */
    CHECK(run("%s db init --db %s", empty, NULL, NULL) == 0);
    CHECK(run("%s db check --db %s", empty, NULL, NULL) == 0);
}

TEST(run_failed_leaves_no_new_database)
{
    /* fails after the database is opened: the capture exceeds a 1 MiB memory budget */
    const char *db = fx_tmp("failed.sqlite");
    CHECK(run("%s --max-memory 1M run capture/scenes/lab.json --db %s", db, NULL, NULL) == 1);
    CHECK_MSG(strstr(out, "memory budget"), "%s", out);
    CHECK(!fx_exists(db));
    char wal[1100];
    snprintf(wal, sizeof wal, "%s-wal", db);
    CHECK(!fx_exists(wal));
    /* a database that existed stays */
    CHECK(run("%s db init --db %s", db, NULL, NULL) == 0);
    CHECK(run("%s --max-memory 1M run capture/scenes/lab.json --db %s", db, NULL, NULL) == 1);
    CHECK(run("%s db check --db %s", db, NULL, NULL) == 0);
}

/* A capture directory whose capture.json declares W x H frames of K = 2, the frames as given. */
static const char *declared_capture(const char *name, int side, const char *frame0_kind)
{
    const char *dir = fx_tmp(name);
    mkdir(dir, 0777);
    char text[1024];
    snprintf(text, sizeof text, "{\"format\": \"gridsurvey-capture/1\", \"grid_hz\": 50, \"K\": 2, "
             "\"bands\": 1, \"width\": %d, \"height\": %d, \"saturation\": 4095, \"frames\": ["
             "{\"file\": \"f0.png\", \"k\": 0, \"cycles\": 10}, {\"file\": \"f1.png\", \"k\": 1, "
             "\"cycles\": 10}]}\n", side, side);
    fx_write_text(fx_path(dir, "capture.json"), text);
    fx_write_text(fx_path(dir, "f1.png"), "not a png");
    if (!strcmp(frame0_kind, "fifo")) CHECK(mkfifo(fx_path(dir, "f0.png"), 0600) == 0);
    else if (!strcmp(frame0_kind, "zero")) CHECK(symlink("/dev/zero", fx_path(dir, "f0.png")) == 0);
    else fx_write_text(fx_path(dir, "f0.png"), "not a png");
    return dir;
}

TEST(capture_memory_budget_checked_before_allocating)
{
    /* 32768^2 x 2 frames: ~2 GiB of samples and ~27 GiB of working images, from a few bytes */
    gs_capture c;
    const char *dir = declared_capture("huge", 32768, "file");
    gs_mem_budget_set((size_t)4 << 30);
    CHECK(gs_capture_read(dir, &c) == GS_ELIMIT);
    CHECK_MSG(strstr(gs_detail(), "memory budget of 4096.0 MiB") && strstr(gs_detail(), "32768x32768"),
              "%s", gs_detail());
    gs_mem_budget_set(0);
    /* the command line says the same in one line */
    CHECK(run("%s --max-memory 4G recognize %s", dir, NULL, NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "memory budget"), "%s", out);
    CHECK(run("%s recognize %s --max-memory=lots", dir, NULL, NULL) == 2);
    /* a trailing blank was read as the unit 'T' past the letters: "4 " as 4 PiB (review) */
    size_t bytes = 0;
    CHECK(gs_mem_parse("--max-memory", "4 ", &bytes) == GS_EINVAL && bytes == 0);
    CHECK(gs_mem_parse("--max-memory", "4G ", &bytes) == GS_EINVAL);
    CHECK(gs_mem_parse("--max-memory", "4GiB", &bytes) == GS_OK && bytes == ((size_t)4 << 30));
    /* a frame that is a FIFO blocked forever, a symlink to /dev/zero was read until malloc failed */
    CHECK(gs_capture_read(declared_capture("fifo", 64, "fifo"), &c) == GS_EINVAL && strstr(gs_detail(), "FIFO"));
    CHECK(gs_capture_read(declared_capture("zero", 64, "zero"), &c) == GS_EINVAL &&
          strstr(gs_detail(), "character device") && strstr(gs_detail(), "frames[0].file"));
    CHECK(c.raw == NULL);
}

/* GS_MAX_MEMORY gets the checks and the one-line usage error of --max-memory (a bad value was
 * ignored: the default budget applied); --max-memory, when given, is used instead. */
TEST(memory_budget_env_checked_like_the_option)
{
    const char *dir = declared_capture("envhuge", 32768, "file");
    CHECK(run("GS_MAX_MEMORY=garbage %s recognize %s", dir, NULL, NULL) == 2);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "GS_MAX_MEMORY 'garbage': expected a size"), "%s", out);
    CHECK(run("GS_MAX_MEMORY=-5 %s recognize %s", dir, NULL, NULL) == 2);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "GS_MAX_MEMORY '-5'"), "%s", out);
    CHECK(run("GS_MAX_MEMORY=4G %s recognize %s", dir, NULL, NULL) == 1);
    CHECK_MSG(strstr(out, "memory budget of 4096.0 MiB"), "%s", out);
    CHECK(run("GS_MAX_MEMORY=garbage %s --max-memory 2G recognize %s", dir, NULL, NULL) == 1);
    CHECK_MSG(strstr(out, "memory budget of 2048.0 MiB"), "%s", out);
    /* the help and version still answer */
    CHECK(run("GS_MAX_MEMORY=garbage %s --help", "", NULL, NULL) == 0);
    CHECK(run("GS_MAX_MEMORY=garbage %s --version", "", NULL, NULL) == 0);
    CHECK(run("GS_MAX_MEMORY=garbage %s help recognize", "", NULL, NULL) == 0);
}

TEST(capture_frame_larger_than_any_png_refused)
{
    const char *dir = declared_capture("bigfile", 8, "file");
    char *big = calloc(2 << 20, 1);
    CHECK(big != NULL);
    if (!big) return;
    fx_write_file(fx_path(dir, "f0.png"), big, 2 << 20);
    free(big);
    gs_capture c;
    CHECK(gs_capture_read(dir, &c) == GS_EFORMAT);
    CHECK_MSG(strstr(gs_detail(), "larger than any PNG of 8x8 pixels"), "%s", gs_detail());
}

/* ------------------------------------------------------------------ the render's and unmix's budget */

/* A scene of one light in the middle of a side x side x bands frame, K frames of `cycles`. */
static const char *budget_scene(const char *name, int side, int bands, int K, int cycles)
{
    const char *path = fx_tmp(name);
    char text[2048];
    snprintf(text, sizeof text,
             "{\"format\": \"gridsurvey-scene/1\", \"seed\": 1, \"grid\": {\"nominal_hz\": 50},\n"
             " \"camera\": {\"width_px\": %d, \"height_px\": %d, \"intrinsics\": {\"focal_px\": %d},\n"
             "   \"optics\": {\"aperture_mm\": 1.0, \"transmission\": 3e-4},\n"
             "   \"sensor\": {\"bands\": %d, \"bit_depth\": 12, \"full_well_e\": 20000, \"read_noise_e\": 4,\n"
             "              \"qe\": 0.6, \"gain_e_per_dn\": 5, \"black_level_dn\": 64}},\n"
             " \"acam\": {\"K\": %d, \"cycles\": %d, \"locked\": true, \"masks\": 64},\n"
             " \"lights\": [{\"id\": \"a\", \"bulb\": \"cfl-20w\", \"phase_deg\": 0, \"x_px\": %d, \"y_px\": %d,\n"
             "              \"distance_m\": 3, \"lumens\": 800}],\n"
             " \"effects\": {\"psf\": {\"sigma_px\": 1.5}, \"shot_noise\": {}, \"read_noise\": {}, \"adc\": {}}}\n",
             side, side, side, bands, K, cycles, side / 2, side / 2);
    fx_write_text(path, text);
    return path;
}

/* The peak resident memory of the command argv (the binary first), KiB: a child's own
 * ru_maxrss (wait4); -1 if it did not run or did not exit 0. */
static long peak_kib(const char *const argv[])
{
    fflush(NULL);
    pid_t pid = fork();
    if (pid == 0) {
        int null = open("/dev/null", O_WRONLY);
        dup2(null, 1);
        dup2(null, 2);
        execv(argv[0], (char *const *)argv);
        _exit(127);
    }
    int st;
    struct rusage ru;
    if (pid < 0 || wait4(pid, &st, 0, &ru) != pid || !WIFEXITED(st) || WEXITSTATUS(st)) return -1;
    return ru.ru_maxrss;
}

/* simulate, capture --backend sim and run allocated the render's frames and per-light tables
 * from the scene's declared sizes without a budget: a few hundred bytes of JSON declared
 * 32768 x 32768 x 3 samples (about 46 GiB to render), and a street grid of a few lines 10^8
 * lights. Now each is refused in one line before anything is allocated or written; a scene
 * just under the budget renders; and the constants bound the measured peak. */
TEST(scene_memory_budget_checked_before_rendering)
{
    const char *huge = budget_scene("huge.json", 32768, 3, 26, 64), *o = fx_tmp("huge-out"),
               *db = fx_tmp("huge.sqlite");
    CHECK(run("%s --max-memory 4G simulate %s --out-dir %s --no-progress", huge, o, NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "huge.json: camera.width_px x height_px x sensor.bands = "
              "32768x32768x3") && strstr(out, "memory budget of 4096.0 MiB"), "%s", out);
    CHECK(run("%s --max-memory 4G capture --backend sim --scene %s --out-dir %s", huge, o, NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "32768x32768x3"), "%s", out);
    CHECK(run("%s --max-memory 4G run %s --db %s --capture-dir %s", huge, db, o) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "32768x32768x3"), "%s", out);
    CHECK(!fx_exists(o) && !fx_exists(db));
    /* a 100 km square street grid, a light every 5 m: 4 x 10^8 lights, refused as they are made */
    const char *grid = fx_tmp("grid.json");
    fx_write_text(grid, "{\"format\": \"gridsurvey-scene/1\", \"grid\": {\"nominal_hz\": 50},\n"
                        " \"camera\": {\"width_px\": 64, \"height_px\": 64, \"intrinsics\": {\"focal_px\": 64},\n"
                        "   \"station\": {\"lat_deg\": 32.8, \"lon_deg\": 35.0, \"height_m\": 100},\n"
                        "   \"pose\": {\"heading_deg\": 0, \"pitch_deg\": -5}},\n"
                        " \"acam\": {\"K\": 26, \"cycles\": 64},\n"
                        " \"lights\": [{\"type\": \"street_grid\", \"center\": {\"lat_deg\": 33.3, \"lon_deg\": 35.0},\n"
                        "   \"size_m\": [100000, 100000], \"street_spacing_m\": 10, \"light_spacing_m\": 5,\n"
                        "   \"max_range_m\": 1e7, \"technologies\": [{\"bulb\": \"hps-150w\", \"lumens\": 15000}]}]}\n");
    CHECK(run("%s --max-memory 64M simulate %s --out-dir %s --no-progress", grid, o, NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "grid.json") && strstr(out, "lights[0]") &&
              strstr(out, "memory budget of 64.0 MiB"), "%s", out);
    CHECK(!fx_exists(o));
    /* just under the budget it renders, one byte less it does not (the budget in bytes) */
    const char *small = budget_scene("small.json", 256, 3, 2, 16), *o2 = fx_tmp("small-out");
    cap_scene sc;
    CHECK_OK(cap_scene_read(small, &sc));
    double b = cap_sim_bytes(&sc);
    cap_scene_release(&sc);
    char lim[64];
    snprintf(lim, sizeof lim, "%.0f", floor(b) - 1);
    CHECK(run("%s --max-memory %s simulate %s --out-dir %s --no-progress", lim, small, o2) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "256x256x3") && !fx_exists(o2), "%s", out);
    snprintf(lim, sizeof lim, "%.0f", ceil(b));
    CHECK_MSG(run("%s --max-memory %s simulate %s --out-dir %s --no-progress", lim, small, o2) == 0, "%s", out);
    CHECK(fx_exists(fx_path(o2, "capture.json")));
    /* the bound against the measured peak above the binary's baseline (not under ASan: its
     * shadow memory and quarantine are not the tool's); at least the frame's doubles and
     * samples (10 B per sample) must show, or the measurement measured nothing */
    if (fx_sanitized()) return;
    const char *big = budget_scene("big.json", 1024, 3, 2, 16), *o3 = fx_tmp("big-out");
    CHECK_OK(cap_scene_read(big, &sc));
    b = cap_sim_bytes(&sc);
    cap_scene_release(&sc);
    char bin[4096];
    CHECK(realpath(test_bin(), bin) != NULL);
    const char *const version[] = {bin, "--version", NULL};
    const char *const sim[] = {bin, "simulate", big, "--out-dir", o3, "--no-progress", NULL};
    long base = peak_kib(version), peak = peak_kib(sim);
    CHECK(base > 0 && peak > 0);
    double above = 1024.0 * (double)(peak - base), samples = 1024.0 * 1024 * 3;
    CHECK_MSG(above <= b && above >= 10 * samples, "peak %.1f MiB above the baseline, bound %.1f MiB",
              above / 1048576, b / 1048576);
}

/* A street grid is generated position by position, and positions out of range are dropped: a
 * grid of 4 x 10^8 positions with only a handful in range kept the memory small and ran for
 * minutes. Its positions are now counted first, against the budget as lights: refused at once,
 * in one line naming the block and the count; a grid whose positions fit generates. */
TEST(street_grid_positions_bounded_before_generating)
{
    const char *grid = fx_tmp("far.json"), *o = fx_tmp("far-out");
    static const char fmt[] =
        "{\"format\": \"gridsurvey-scene/1\", \"grid\": {\"nominal_hz\": 50},\n"
        " \"camera\": {\"width_px\": 64, \"height_px\": 64, \"intrinsics\": {\"focal_px\": 64},\n"
        "   \"station\": {\"lat_deg\": 32.8, \"lon_deg\": 35.0, \"height_m\": 100},\n"
        "   \"pose\": {\"heading_deg\": 0, \"pitch_deg\": -5}},\n"
        " \"acam\": {\"K\": 26, \"cycles\": 64},\n"
        " \"lights\": [{\"type\": \"street_grid\", \"center\": {\"lat_deg\": 32.81, \"lon_deg\": 35.0},\n"
        "   \"size_m\": [%d, %d], \"street_spacing_m\": 10, \"light_spacing_m\": 5,\n"
        "   \"max_range_m\": 1200, \"technologies\": [{\"bulb\": \"hps-150w\", \"lumens\": 15000}]}]}\n";
    char text[2048];
    snprintf(text, sizeof text, fmt, 100000, 100000);
    fx_write_text(grid, text);
    CHECK(run("%s --max-memory 1G simulate %s --out-dir %s --no-progress", grid, o, NULL) == 1);
    /* (100000 / 10 + 1) streets of 100000 / 5 positions, in each direction */
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "far.json") && strstr(out, "lights[0]") &&
              strstr(out, "a street grid of 400040000 positions") && strstr(out, "memory budget of 1024.0 MiB"),
              "%s", out);
    CHECK(!fx_exists(o));
    /* 2 km square: 2 x 201 x 400 = 160,800 positions, 0.5 GiB as lights: it fits and generates */
    snprintf(text, sizeof text, fmt, 2000, 2000);
    fx_write_text(grid, text);
    CHECK_MSG(run("%s --max-memory 1G simulate %s --out-dir %s --no-progress", grid, o, NULL) == 0, "%s", out);
    CHECK(fx_exists(fx_path(o, "truth.json")));
}

/* `run` on a scene checked recognition's budget only when it read the capture back, after
 * rendering all of it. Here the render fits the budget and the capture's recognition does not:
 * the run is refused at once, in one line naming the scene and recognition's sizes, with
 * nothing rendered and no database. */
TEST(run_on_a_scene_checks_recognition_budget_before_rendering)
{
    const char *scene = budget_scene("deep.json", 1024, 3, 26, 64), *o = fx_tmp("deep-out"),
               *db = fx_tmp("deep.sqlite");
    cap_scene sc;
    CHECK_OK(cap_scene_read(scene, &sc));
    double render = cap_sim_bytes(&sc), budget = 128.0 * 1048576;
    cap_scene_release(&sc);
    /* K = 26 frames of 3 bands: 3 B per sample and 27 + 0 per pixel, 261 MiB */
    double recognize = 1024.0 * 1024 * (26 * 3 * 3 + 27);
    CHECK_MSG(render < budget && recognize > budget, "render %.1f MiB, recognition %.1f MiB", render / 1048576,
              recognize / 1048576);
    CHECK(run("%s --max-memory 128M run %s --db %s --capture-dir %s", scene, db, o) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "deep.json: 26 frames of 1024x1024x3 samples and the "
              "working images") && strstr(out, "memory budget of 128.0 MiB"), "%s", out);
    CHECK(!fx_exists(o) && !fx_exists(db));
}

/* The smallest budget, in bytes, that check passes (a bisection over gs_mem_budget_set). */
static double budget_threshold(gs_status (*check)(const void *), const void *arg)
{
    double lo = 1048576, hi = 0x1p40;
    while (hi - lo > 1) {
        double mid = floor(0.5 * (lo + hi));
        gs_mem_budget_set((size_t)mid);
        if (check(arg) == GS_OK) hi = mid;
        else lo = mid;
    }
    gs_mem_budget_set(0);
    return hi;
}
typedef struct {
    const char *dir;
    const gs_capture *cap;
    const char *sources;
    const rec_capture_meta *meta;
    int S;
} budget_args;
static gs_status unmix_check(const void *a)
{
    const budget_args *b = a;
    return rec_unmix_budget(b->dir, b->cap, b->S, 1);
}
static gs_status separate_check(const void *a)
{
    const budget_args *b = a;
    return rec_separate_budget(b->dir, b->cap);
}
static gs_status relight_check(const void *a)
{
    const budget_args *b = a;
    return rec_relight_budget(b->sources, b->meta, b->S);
}

/* unmix allocated its source images (8 B per source sample) and, with --render, each source's
 * K frames from the capture's declared sizes, beyond what reading the capture is allowed;
 * relight allocated the source images, the relit frames and a capture from a sources file's
 * declared capture; separate its images. Each is now refused in one line, with nothing
 * written, one byte under its budget, and runs at it; unmix's constants bound its peak. */
TEST(unmix_memory_budget_checked_before_allocating)
{
    static const trfx_lamp lamps[] = {
        {"inc25", "inc-a60-25w-230v", 0, 11.2, 8.9, 3.8, 6e6},
        {"cfl23", "cfl-23w", 120, 52.9, 7.2, 4.2, 6e6},
        {"ledfil", "led-fil-4w-lin", 240, 32.0, 4.9, 4.5, 5e6},
    };
    trfx_opts o = {0};
    o.W = 160;
    o.H = 120;
    char *text = trfx_scene(&o, lamps, 3);
    const char *dir = fx_tmp("ucap"), *src = fx_tmp("usources.json"), *u = fx_tmp("unmixed"),
               *r = fx_tmp("relit"), *sep = fx_tmp("separated");
    gs_capture cap;
    int ok = trfx_render(text, dir, &cap);
    free(text);
    if (!ok) return;
    fx_write_text(src, "{\"format\": \"gridsurvey-sources/1\", \"sources\": [{\"bulb\": \"inc-a60-25w-230v\", "
                       "\"phase_deg\": 0}, {\"bulb\": \"cfl-23w\", \"phase_deg\": 120}, {\"bulb\": "
                       "\"led-fil-4w-lin\", \"phase_deg\": 240}]}\n");
    budget_args a = {dir, &cap, NULL, NULL, 3};
    double t = budget_threshold(unmix_check, &a), ts = budget_threshold(separate_check, &a);
    char lim[64];
    snprintf(lim, sizeof lim, "%.0f", t - 1);
    char args[4096];
    snprintf(args, sizeof args, "%s --sources %s --out-dir %s --render", dir, src, u);
    CHECK(run("%s --max-memory %s unmix %s", lim, args, NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "ucap/capture.json: unmix of 26 frames of 160x120x3 samples "
              "into 3 source images and 26 frames") && strstr(out, "memory budget"), "%s", out);
    CHECK(!fx_exists(u));
    snprintf(lim, sizeof lim, "%.0f", ts - 1);
    CHECK(run("%s --max-memory %s separate %s --out-dir %s", lim, dir, sep) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "separate of 26 frames") && !fx_exists(sep), "%s", out);
    /* at the budget unmix runs (the one run measured, outside ASan) */
    snprintf(lim, sizeof lim, "%.0f", t);
    char bin[4096], maxmem[80];
    CHECK(realpath(test_bin(), bin) != NULL);
    snprintf(maxmem, sizeof maxmem, "--max-memory=%s", lim);
    const char *const version[] = {bin, "--version", NULL};
    const char *const unmix[] = {bin, maxmem, "unmix", dir, "--sources", src, "--out-dir", u, "--render", NULL};
    long base = peak_kib(version), peak = peak_kib(unmix);
    CHECK_MSG(base > 0 && peak > 0 && fx_exists(fx_path(u, "sources.json")), "unmix at its budget failed");
    double above = 1024.0 * (double)(peak - base), samples = 160.0 * 120 * 3 * 26;
    if (!fx_sanitized())
        CHECK_MSG(above <= t && above >= 6 * samples, "unmix: peak %.1f MiB above the baseline, bound %.1f MiB",
                  above / 1048576, t / 1048576);
    /* relight from the sources file unmix wrote */
    char path[4200];
    snprintf(path, sizeof path, "%s/sources.json", u);
    rec_sources s;
    rec_capture_meta meta;
    char(*files)[GS_PATH_MAX] = NULL;
    CHECK_OK(rec_sources_read(path, &s, &meta, &files));
    budget_args ra = {NULL, NULL, path, &meta, s.S};
    double tr = budget_threshold(relight_check, &ra);
    rec_sources_release(&s);
    free(files);
    snprintf(lim, sizeof lim, "%.0f", tr - 1);
    CHECK(run("%s --max-memory %s relight %s --out-dir %s", lim, u, r) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "sources.json: relight of 26 frames") && !fx_exists(r), "%s", out);
    snprintf(lim, sizeof lim, "%.0f", tr);
    CHECK_MSG(run("%s --max-memory %s relight %s --out-dir %s", lim, u, r) == 0, "%s", out);
    gs_capture_release(&cap);
}

TEST(memory_size_parse)
{
    size_t b = 0;
    CHECK_OK(gs_mem_parse("--max-memory", "4G", &b));
    CHECK(b == (size_t)4 << 30);
    CHECK_OK(gs_mem_parse("--max-memory", "1.5GiB", &b));
    CHECK(b == (size_t)3 << 29);
    CHECK_OK(gs_mem_parse("--max-memory", "1048576", &b));
    CHECK(b == 1048576);
    CHECK(gs_mem_parse("--max-memory", "100K", &b) == GS_EINVAL);   /* below 1M */
    CHECK(gs_mem_parse("--max-memory", "4X", &b) == GS_EINVAL);
    CHECK(gs_mem_parse("GS_MAX_MEMORY", "nan", &b) == GS_EINVAL);
    CHECK(!strncmp(gs_detail(), "GS_MAX_MEMORY 'nan': ", 21));
    CHECK(gs_mem_budget() > 0);
}

TEST(evaluate_match_px_range)
{
    /* 1e308 went quadratic (1.5 GiB, 15 s) */
    CHECK(run("%s evaluate --db x.sqlite --truth t.json --match-px 1e308", NULL, NULL, NULL) == 2);
    CHECK(fx_count_lines(out) == 1 && strstr(out, "<= 64"));
}

TEST(survey_name_with_control_characters_refused_at_input)
{
    const char *db = fx_tmp("names.sqlite");
    CHECK(run("%s run capture/scenes/lab.json --db %s --survey \"$(printf 'a\\033[2Jb')\"", db, NULL, NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "control characters") && !strchr(out, '\033'), "%s", out);
    CHECK(run("%s run capture/scenes/lab.json --db %s --survey \"$(printf 'a\\nb')\"", db, NULL, NULL) == 1);
    CHECK(run("%s run capture/scenes/lab.json --db %s --survey \"$(printf 'a\\377b')\"", db, NULL, NULL) == 1);
    CHECK(!fx_exists(db));
    CHECK(gs_text_clean("Haifa \xc3\xa9t\xc3\xa9") && !gs_text_clean("a\x1b") && !gs_text_clean("\xff"));
}

TEST(cli_version_and_help_command)
{
    CHECK(run("%s --version", NULL, NULL, NULL) == 0);
    CHECK_MSG(strstr(out, "gridsurvey ") && strstr(out, "(git ") && strstr(out, "SQLite 3.") &&
              strstr(out, "GeographicLib ") && strstr(out, "OpenCV "), "%s", out);
    static char help[sizeof out];
    CHECK(run("%s stats --help", NULL, NULL, NULL) == 0);
    memcpy(help, out, sizeof out);
    CHECK(run("%s help stats", NULL, NULL, NULL) == 0);
    CHECK(!strcmp(help, out));
    CHECK(run("%s help nosuchcommand", NULL, NULL, NULL) == 2);
    /* help is a command too: its --help (and help help) is the usage, as `gridsurvey help` */
    CHECK(run("%s help", NULL, NULL, NULL) == 0);
    memcpy(help, out, sizeof out);
    CHECK(run("%s help --help", NULL, NULL, NULL) == 0);
    CHECK_MSG(!strcmp(help, out), "%s", out);
    CHECK(run("%s help help", NULL, NULL, NULL) == 0);
    CHECK_MSG(!strcmp(help, out), "%s", out);
    CHECK(run("%s help -h", NULL, NULL, NULL) == 0);
    CHECK_MSG(!strcmp(help, out), "%s", out);
    /* a usage error: one line with what is wrong and a hint; not the whole usage, nor getopt's
     * own line */
    CHECK(run("%s stats --frobnicate", NULL, NULL, NULL) == 2);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "'--frobnicate'") && strstr(out, "see gridsurvey help stats"),
              "%s", out);
    CHECK(run("%s export --db", NULL, NULL, NULL) == 2);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "missing value: '--db'"), "%s", out);
    /* a scene where a capture directory is expected: said so */
    CHECK(run("%s recognize capture/scenes/lab.json", NULL, NULL, NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "expected a capture directory"), "%s", out);
    CHECK(run("%s export --db x.sqlite", NULL, NULL, NULL) == 2);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "see gridsurvey help export"), "%s", out);
}

/* A missing required option or argument is the one-line usage error too, never the whole usage
 * (compare, capture and unmix printed their --help after the line, compare and bench render
 * for an unknown option). */
TEST(cli_usage_errors_one_line_not_the_usage)
{
    static const struct {
        const char *cmd, *names;
    } cases[] = {
        {"%s compare --db x.sqlite --survey metro", "--survey"},
        {"%s compare --db x.sqlite --survey a --survey b --frobnicate", "'--frobnicate'"},
        {"%s capture --backend replay --from x", "--out-dir"},
        {"%s unmix x --out-dir y", "--sources"},
        {"%s bench render --frames", "'--frames'"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        CHECK(run(cases[i].cmd, NULL, NULL, NULL) == 2);
        CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, cases[i].names) && strstr(out, "see gridsurvey help"),
                  "%s: %s", cases[i].cmd, out);
    }
}

TEST(cli_usage_errors_of_each_command_one_line_with_the_hint)
{
    /* these printed their own line (no hint, or another one, or the wrong option: db's named
     * its subcommand) instead of srv_usage_error's; each is a value or option on the command
     * line, refused before any file is read or written (but the scene --drop-light names) */
    static const struct {
        const char *cmd, *help, *names;
    } cases[] = {
        {"%s db check --frobnicate", "db check", "'--frobnicate'"},
        {"%s db ingest-synthetic --db x.sqlite --captures abc", "db ingest-synthetic", "--captures 'abc'"},
        {"%s db frobnicate", "db", "'frobnicate' is not a subcommand"},
        {"%s evaluate --db x.sqlite", "evaluate", "--truth"},
        {"%s export --db x.sqlite -o y.csv --phase 90", "export", "--phase '90'"},
        {"%s export --db x.sqlite -o y.xyz", "export", "y.xyz"},
        {"%s locate --station s.json --pixels p.csv -o o.csv --light-height-m abc", "locate", "--light-height-m 'abc'"},
        {"%s push --db x.sqlite --pg dbname=x --areas a.geojson", "push", "--field"},
        {"%s recognize --phases 5 x", "recognize", "--phases '5'"},
        {"%s run x.json --db x.sqlite --light-height-sigma-m inf", "run", "--light-height-sigma-m 'inf'"},
        {"%s separate", "separate", "CAPDIR"},
        {"%s simulate capture/scenes/window.json --out-dir x --seed -1", "simulate", "--seed '-1'"},
        {"%s simulate capture/scenes/window.json --out-dir x --drop-light nope", "simulate", "--drop-light nope"},
        {"%s stats --db x.sqlite --by nope", "stats", "--by 'nope'"},
        {"%s stats --db x.sqlite --format xml", "stats", "--format 'xml'"},
        /* bench's own lines: no hint, "(see --help)", or the hint of "bench" for a benchmark's */
        {"%s bench frobnicate", "bench", "'frobnicate' is not a benchmark"},
        {"%s bench recognize --frobnicate", "bench recognize", "'--frobnicate'"},
        {"%s bench recognize --lights --captures", "bench recognize", "--lights and --captures"},
        {"%s bench accuracy extra", "bench accuracy", "unexpected argument 'extra'"},
        {"%s bench db --max 5", "bench db", "--max '5'"},
        {"%s bench db --frobnicate", "bench db", "'--frobnicate'"},
        {"%s bench pg --pg dbname=x --min 5", "bench pg", "--min '5'"},
        {"%s bench pg", "bench pg", "--pg"},
        {"%s bench transport --frobnicate", "bench transport", "'--frobnicate'"},
        /* integers parsed by hand: "2x" read as 2 (sscanf), 2^32 + 256 as 256 (an int cast),
         * " -1" as 2^64 - 1 (strtoull skips the space, the check for '-' looked at it) */
        {"%s bench blobs /nonexistent/cap --reps 2x", "bench blobs", "--reps '2x'"},
        {"%s bench render /nonexistent/scene.json --frames 2x", "bench render", "--frames '2x'"},
        {"%s delight generate -o /nonexistent/x.db --n 4294967552", "delight", "--n '4294967552'"},
        {"%s db ingest-synthetic --db /nonexistent/x.sqlite --seed ' -1'", "db ingest-synthetic", "--seed ' -1'"},
        {"%s push --db /nonexistent/x.sqlite --pg dbname=x --batch ' 5'", "push", "--batch ' 5'"},
        /* numbers with an excluded bound (srv_num_arg_open): --watts inf was let through to the
         * file (exit 1, the recording's error), 0 and 1 are outside these ranges */
        {"%s delight add --from-recording /nonexistent/r.csv --watts inf --delight /nonexistent/x.db", "delight",
         "--watts 'inf': expected a number > 0 and < 100000"},
        {"%s recognize --blend-prior 1 x", "recognize", "--blend-prior '1': expected a number >= 0 and < 1"},
        {"%s recognize --threshold 0 x", "recognize", "--threshold '0': expected a number > 0 ("},
        {"%s recognize --max-drift-windows -1 x", "recognize", "--max-drift-windows '-1': expected a number >= 0, none or auto"},
        {"%s run x --db x.sqlite --max-drift-windows inf", "run", "--max-drift-windows 'inf': expected a number >= 0, none or auto"},
        {"%s unmix x --sources auto --out-dir o --max-drift-windows nan", "unmix",
         "--max-drift-windows 'nan': expected a number >= 0, none or auto"},
        {"%s recognize --transformer-deg nan x", "recognize", "--transformer-deg 'nan': expected a finite number"},
        /* the unit the option's name ends with, after its range */
        {"%s locate --light-height-m abc --station s.json --pixels p.csv", "locate",
         "--light-height-m 'abc': expected a number from -12000 to 100000 m ("},
        {"%s evaluate x --db x.sqlite --match-px 0", "evaluate", "--match-px '0': expected a number > 0 and <= "},
        {"%s run x --db x.sqlite --light-height-sigma-m -1", "run", "--light-height-sigma-m '-1': expected a number >= 0 m ("},
        /* a format locate cannot tell is a usage error, as export's (it exited 1) */
        {"%s locate --station s.json --pixels p.csv -o o.xyz", "locate", "o.xyz"},
        {"%s locate --station s.json --pixels p.csv -o o.csv --format xml", "locate", "format 'xml'"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        char line_start[64], hint[64];
        snprintf(line_start, sizeof line_start, "gridsurvey %s: ", cases[i].help);
        snprintf(hint, sizeof hint, " (see gridsurvey help %s)\n", cases[i].help);
        CHECK(run(cases[i].cmd, NULL, NULL, NULL) == 2);
        CHECK_MSG(fx_count_lines(out) == 1 && !strncmp(out, line_start, strlen(line_start)) &&
                  strstr(out, cases[i].names) && strstr(out, hint), "%s: %s", cases[i].cmd, out);
    }
    CHECK(!fx_exists("x"));
}

TEST(cli_write_failure_of_stdout_names_it)
{
    /* stats (and compare) said "cannot write the output" without naming it */
    const char *db = fx_tmp("empty.sqlite");
    CHECK(run("%s db init --db %s", db, NULL, NULL) == 0);
    CHECK(run("%s stats --db %s > /dev/full", db, NULL, NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && !strcmp(out, "gridsurvey stats: stdout: write failed\n"), "%s", out);
}

TEST(cli_failures_name_the_command_and_the_file_not_a_status_word)
{
    /* a library's error was "gridsurvey: not found: DETAIL" (its status word first, the command
     * unnamed); now the one line "gridsurvey CMD: DETAIL", DETAIL naming the file and field */
    const char *nodir = fx_tmp("no-such-capture"), *scene = fx_tmp("no-format.json");
    fx_write_text(scene, "{\"camera\": 3}\n");
    char want[3][1024];
    snprintf(want[0], sizeof want[0], "gridsurvey recognize: %s: no such directory: expected a capture directory", nodir);
    snprintf(want[1], sizeof want[1], "gridsurvey run: %s:1: field format: expected a string", scene);
    snprintf(want[2], sizeof want[2], "gridsurvey delight plot: --ids: bulb 'no-such-bulb-16' not in the database");
    CHECK(run("%s recognize %s", nodir, NULL, NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && !strncmp(out, want[0], strlen(want[0])), "%s", out);
    CHECK(run("%s run %s --db %s", scene, fx_tmp("no-format.sqlite"), NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && !strncmp(out, want[1], strlen(want[1])), "%s", out);
    CHECK(run("%s delight plot --ids no-such-bulb-16 -o %s", fx_tmp("none.png"), NULL, NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && !strncmp(out, want[2], strlen(want[2])), "%s", out);
}

TEST(recording_header_run_in_empty_middle_field)
{
    /* found by `make fuzz` (fuzz_recording): a first row of 2k-1 fields whose middle one is
     * empty made header_run_in read past that field's end (ASan: heap-buffer-overflow) */
    const char *path = fx_tmp("runin.csv");
    fx_write_text(path, "time,,value\n0,1\n0.001,2\n0.002,1\n");
    gs_bulb b;
    memset(&b, 0, sizeof b);
    gs_status s = gs_recording_to_bulb(path, 0, 64, &b, NULL);
    CHECK(s != GS_OK && strstr(gs_detail(), "runin.csv"));
    if (s == GS_OK) gs_bulb_release(&b);
}
