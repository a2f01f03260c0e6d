/* test_capture_format.c - the capture directory (gridsurvey-capture/1, docs/formats.md):
 * bit-exact round trips through rec_capture_write_* / gs_capture_read, a directory written by
 * an independent program (Python with OpenCV and numpy, JSON by hand) read correctly, every
 * malformed input rejected with a detail naming the file, the JSON line and the field, the
 * writer's own validation, atomic writes, gs_capture_value, and a mutation fuzz of
 * capture.json (no crash, every failure explained). */
#include "recognize/base/internal.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <dirent.h>
#include <fcntl.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

/* ------------------------------------------------------------------ helpers */

/* A new directory TMPDIR/name (its path lives as fx_tmp's, tests/fixtures.h). */
static const char *subdir(const char *name)
{
    const char *p = fx_tmp(name);
    mkdir(p, 0700);
    return p;
}

static uint64_t rng = 1;

/* A capture with every field set and pixels spanning 0..65535. */
static void make_capture(gs_capture *c, int K, int bands, int W, int H, int hdr)
{
    memset(c, 0, sizeof *c);
    c->grid_hz = 60;
    c->K = K;
    c->bands = bands;
    c->width = W;
    c->height = H;
    c->saturation_dn = 65535;
    c->black_level_dn = 64.5;
    c->gain_e_per_dn = 0.37;
    c->read_noise_dn = 2.25;
    c->locked = 0;
    snprintf(c->utc, sizeof c->utc, "2017-07-21T22:05:00.125+03:00");
    c->station_json = strdup("{\"name\":\"Haifa roof\",\"lat\":32.79,\"lon\":35.02,\"h\":[1,2.5]}");
    CHECK_OK(gs_capture_alloc(c));
    if (hdr) CHECK_OK(gs_capture_alloc_hdr(c));
    rng = 99;
    size_t n = (size_t)K * W * H * bands;
    for (size_t i = 0; i < n; i++) c->raw[i] = (unsigned short)gs_splitmix64(&rng);
    c->raw[0] = 0;
    c->raw[n - 1] = 65535;
    for (int k = 0; k < K; k++) c->frames[k].cycles = k == 1 ? 0.1 : 500 + 0.25 * k;
    if (hdr) {
        for (size_t i = 0; i < (size_t)K * W * H; i++)
            c->halvings[i] = (unsigned char)(gs_splitmix64(&rng) % (GS_MAX_HALVINGS + 1));
        /* frame 2 has no map: its halvings must be 0 */
        c->frames[2].hdr_map[0] = '\0';
        memset(c->halvings + (size_t)2 * W * H, 0, (size_t)W * H);
    }
}

static void write_capture(const char *dir, const gs_capture *c)
{
    for (int k = 0; k < c->K; k++) CHECK_OK(gs_capture_write_frame(dir, c, k));
    CHECK_OK(gs_capture_write_json(dir, c));
}

static void check_same(const gs_capture *a, const gs_capture *b)
{
    CHECK(a->grid_hz == b->grid_hz && a->K == b->K && a->bands == b->bands);
    CHECK(a->width == b->width && a->height == b->height);
    CHECK(a->saturation_dn == b->saturation_dn && a->black_level_dn == b->black_level_dn);
    CHECK(a->gain_e_per_dn == b->gain_e_per_dn && a->read_noise_dn == b->read_noise_dn);
    CHECK(a->locked == b->locked && a->window_period == b->window_period && strcmp(a->utc, b->utc) == 0);
    CHECK((a->station_json == NULL) == (b->station_json == NULL));
    if (a->station_json && b->station_json) CHECK(strcmp(a->station_json, b->station_json) == 0);
    for (int k = 0; k < a->K && k < b->K; k++) {
        CHECK(strcmp(a->frames[k].file, b->frames[k].file) == 0);
        CHECK(strcmp(a->frames[k].hdr_map, b->frames[k].hdr_map) == 0);
        CHECK(a->frames[k].k == k && b->frames[k].k == k);
        CHECK(a->frames[k].cycles == b->frames[k].cycles);
        /* exact, NaN (absent) included */
        CHECK(a->frames[k].grid_hz_measured == b->frames[k].grid_hz_measured ||
              (isnan(a->frames[k].grid_hz_measured) && isnan(b->frames[k].grid_hz_measured)));
        CHECK(a->frames[k].start_s == b->frames[k].start_s ||
              (isnan(a->frames[k].start_s) && isnan(b->frames[k].start_s)));
        CHECK(a->frames[k].window_half_period_s == b->frames[k].window_half_period_s ||
              (isnan(a->frames[k].window_half_period_s) && isnan(b->frames[k].window_half_period_s)));
    }
    size_t n = (size_t)a->K * a->width * a->height;
    CHECK(memcmp(a->raw, b->raw, n * a->bands * sizeof *a->raw) == 0);
    CHECK((a->halvings == NULL) == (b->halvings == NULL));
    if (a->halvings && b->halvings) CHECK(memcmp(a->halvings, b->halvings, n) == 0);
}

/* ------------------------------------------------------------- round trips */

TEST(capture_format_round_trip_rgb_hdr)
{
    const char *dir = subdir("cap");
    gs_capture a, b;
    make_capture(&a, 5, 3, 37, 23, 1);
    write_capture(dir, &a);
    CHECK_OK(gs_capture_read(dir, &b));
    check_same(&a, &b);
    /* a second write over the first (atomic replacement) and read again */
    a.raw[7] ^= 0x5555;
    write_capture(dir, &a);
    gs_capture_release(&b);
    CHECK_OK(gs_capture_read(dir, &b));
    check_same(&a, &b);
    /* nothing but the capture's files: no temporary file left behind */
    DIR *d = opendir(dir);
    int files = 0;
    for (struct dirent *e; d && (e = readdir(d));) {
        if (e->d_name[0] == '.' && (!e->d_name[1] || (e->d_name[1] == '.' && !e->d_name[2]))) continue;
        CHECK_MSG(strstr(e->d_name, ".tmp") == NULL, "left over: %s", e->d_name);
        files++;
    }
    if (d) closedir(d);
    CHECK(files == 1 + 5 + 4); /* capture.json, 5 frames, 4 maps */
    gs_capture_release(&a);
    gs_capture_release(&b);
    CHECK(b.raw == NULL && b.frames == NULL && b.station_json == NULL);
    gs_capture_release(NULL);
}

/* gs_capture_read takes the directory's lock shared itself; gs_capture_read_held, for a caller
 * that holds it (srv_job_read), takes none. While a writer holds the directory (here this
 * process, through an open file description of its own, as flock(1) -x would), the first refuses
 * in one line naming it and leaves the capture zeroed; the second reads what was written, bit for
 * bit, as the first does once the directory is free. */
TEST(capture_read_held_takes_no_second_lock)
{
    gs_capture a, b;
    make_capture(&a, 3, 3, 5, 4, 1);
    const char *dir = subdir("held");
    write_capture(dir, &a);
    int fd = open(dir, O_RDONLY | O_DIRECTORY);
    CHECK(fd >= 0 && flock(fd, LOCK_EX) == 0);
    CHECK(gs_capture_read(dir, &b) == GS_EIO);
    CHECK_MSG(strstr(gs_detail(), dir) && strstr(gs_detail(), "another process is acquiring"), "%s", gs_detail());
    CHECK(!b.frames && !b.raw && !b.halvings && b.K == 0);
    CHECK_OK(gs_capture_read_held(dir, &b));
    check_same(&a, &b);
    gs_capture_release(&b);
    close(fd);
    CHECK_OK(gs_capture_read(dir, &b));
    check_same(&a, &b);
    gs_capture_release(&b);
    gs_capture_release(&a);
}

TEST(capture_format_round_trip_mono_defaults)
{
    const char *dir = subdir("mono");
    gs_capture a, b;
    make_capture(&a, 2, 1, 1, 1, 0);
    free(a.station_json);
    a.station_json = NULL;
    a.utc[0] = '\0';
    a.saturation_dn = 65536; /* nothing saturates */
    a.black_level_dn = 0;
    write_capture(dir, &a);
    CHECK_OK(gs_capture_read(dir, &b));
    check_same(&a, &b);
    CHECK(b.halvings == NULL && b.station_json == NULL && b.utc[0] == '\0');
    gs_capture_release(&a);
    gs_capture_release(&b);
    /* defaults of the optional fields */
    const char *dir2 = subdir("defaults");
    make_capture(&a, 2, 1, 3, 2, 0);
    write_capture(dir2, &a);
    fx_write_text(fx_path(dir2, "capture.json"),
               "{\"format\": \"gridsurvey-capture/1\", \"grid_hz\": 50, \"K\": 2, \"bands\": 1,\n"
               " \"width\": 3, \"height\": 2, \"saturation\": 4095, \"frames\": [\n"
               " {\"file\": \"frame_001.png\", \"k\": 1, \"cycles\": 10},\n"
               " {\"file\": \"frame_000.png\", \"k\": 0, \"cycles\": 20, \"hdr_map\": \"\"}]}\n");
    CHECK_OK(gs_capture_read(dir2, &b));
    CHECK(b.black_level_dn == 0 && b.gain_e_per_dn == 0 && b.read_noise_dn == 1 && b.locked == 1);
    CHECK(b.frames[0].cycles == 20 && b.frames[1].cycles == 10 && b.halvings == NULL);
    CHECK(strcmp(b.frames[0].file, "frame_000.png") == 0);
    CHECK(memcmp(a.raw, b.raw, 2 * 3 * 2 * sizeof *a.raw) == 0);
    gs_capture_release(&a);
    gs_capture_release(&b);
}

/* The pixel formula the Python writer uses. */
static unsigned short py_value(int x, int y, int k, int b)
{
    return (unsigned short)((x * 4099 + y * 131 + k * 1009 + b * 20011) % 65536);
}

TEST(capture_format_independent_python_writer)
{
    const char *dir = subdir("py");
    char script[1024], cmd[3072], out[4096];
    snprintf(script, sizeof script, "%s/writer.py", test_tmpdir());
    fx_write_text(script,
        "# An independent writer of gridsurvey-capture/1: numpy + OpenCV, JSON by hand.\n"
        "import os, sys\n"
        "import numpy as np\n"
        "import cv2\n"
        "d = sys.argv[1]\n"
        "W, H, K = 13, 7, 3\n"
        "y, x = np.mgrid[0:H, 0:W]\n"
        "for k in range(K):\n"
        "    rgb = np.zeros((H, W, 3), np.uint16)\n"
        "    for b in range(3):\n"
        "        rgb[:, :, b] = (x * 4099 + y * 131 + k * 1009 + b * 20011) % 65536\n"
        "    assert cv2.imwrite(os.path.join(d, 'img-%d.png' % k), rgb[:, :, ::-1])  # OpenCV is BGR\n"
        "hdr = ((x + y) % 4).astype(np.uint8)\n"
        "assert cv2.imwrite(os.path.join(d, 'halvings_1.png'), hdr)\n"
        "frames = ['{\"k\": 2, \"file\": \"img-2.png\", \"cycles\": 1500}',\n"
        "          '{\"cycles\": 100.5, \"k\": 0, \"file\": \"img-0.png\"}',\n"
        "          '{\"file\": \"img-1.png\", \"k\": 1, \"cycles\": 800, \"hdr_map\": \"halvings_1.png\"}']\n"
        "text = ('{\\n  \"x_writer\": \"python\",\\n  \"frames\": [\\n    ' + ',\\n    '.join(frames) +\n"
        "        '\\n  ],\\n  \"height\": 7, \"width\": 13, \"bands\": 3, \"K\": 3, \"grid_hz\": 60,\\n'\n"
        "        '  \"saturation\": 65535.0, \"read_noise_dn\": 4.5, \"gain_e_per_dn\": 1.25,\\n'\n"
        "        '  \"locked\": false, \"utc\": \"2024-02-29T23:59:60Z\",\\n'\n"
        "        '  \"station\": {\"name\": \"roof\", \"lat\": 32.5},\\n'\n"
        "        '  \"format\": \"gridsurvey-capture/1\"\\n}\\n')\n"
        "open(os.path.join(d, 'capture.json'), 'w').write(text)\n");
    snprintf(cmd, sizeof cmd, "/usr/bin/python3 '%s' '%s'", script, dir);
    int rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 0, "python writer failed (%d): %s (needs python3-opencv, python3-numpy)", rc, out);
    if (rc != 0) return;
    gs_capture c;
    CHECK_OK(gs_capture_read(dir, &c));
    if (!c.raw) return;
    CHECK(c.K == 3 && c.bands == 3 && c.width == 13 && c.height == 7 && c.grid_hz == 60);
    CHECK(c.saturation_dn == 65535 && c.read_noise_dn == 4.5 && c.gain_e_per_dn == 1.25);
    CHECK(c.black_level_dn == 0 && c.locked == 0 && strcmp(c.utc, "2024-02-29T23:59:60Z") == 0);
    CHECK(c.station_json && strcmp(c.station_json, "{\"name\":\"roof\",\"lat\":32.5}") == 0);
    CHECK(c.frames[0].cycles == 100.5 && c.frames[1].cycles == 800 && c.frames[2].cycles == 1500);
    CHECK(strcmp(c.frames[1].hdr_map, "halvings_1.png") == 0 && c.frames[0].hdr_map[0] == '\0');
    int bad = 0;
    for (int k = 0; k < 3; k++)
        for (int y = 0; y < 7; y++)
            for (int x = 0; x < 13; x++)
                for (int b = 0; b < 3; b++)
                    bad += c.raw[((k * 7 + y) * 13 + x) * 3 + b] != py_value(x, y, k, b);
    CHECK_MSG(bad == 0, "%d samples differ (R, G, B order?)", bad);
    bad = 0;
    for (int k = 0; k < 3; k++)
        for (int y = 0; y < 7; y++)
            for (int x = 0; x < 13; x++)
                bad += c.halvings[(k * 7 + y) * 13 + x] != (k == 1 ? (x + y) % 4 : 0);
    CHECK(bad == 0);
    /* and the value of a halved sample: (raw - 0) * 2^h / 800, h = (3 + 2) % 4 = 1 */
    CHECK_NEAR(gs_capture_value(&c, 1, 2, 3, 2), py_value(3, 2, 1, 2) * 2.0 / 800, 1e-12);
    gs_capture_release(&c);
}

/* ----------------------------------------------------- malformed capture.json */

/* A valid 5x4 mono capture with K = 3 whose capture.json has one field a line:
 *  1 {                                      8   "saturation": 4095,
 *  2   "format": "gridsurvey-capture/1",    9   "frames": [
 *  3   "grid_hz": 50,                       10    {"file": "frame_000.png", "k": 0, "cycles": 100},
 *  4   "K": 3,                              11    {"file": "frame_001.png", "k": 1, "cycles": 100},
 *  5   "bands": 1,                          12    {"file": "frame_002.png", "k": 2, "cycles": 100}
 *  6   "width": 5,                          13  ]
 *  7   "height": 4,                         14 } */
static const char *const json_lines[14] = {
    "{",
    "  \"format\": \"gridsurvey-capture/1\",",
    "  \"grid_hz\": 50,",
    "  \"K\": 3,",
    "  \"bands\": 1,",
    "  \"width\": 5,",
    "  \"height\": 4,",
    "  \"saturation\": 4095,",
    "  \"frames\": [",
    "    {\"file\": \"frame_000.png\", \"k\": 0, \"cycles\": 100},",
    "    {\"file\": \"frame_001.png\", \"k\": 1, \"cycles\": 100},",
    "    {\"file\": \"frame_002.png\", \"k\": 2, \"cycles\": 100}",
    "  ]",
    "}",
};

/* Write the valid capture with line `line` (1-based; 0: none) replaced by `text`. */
static const char *small_capture(const char *name, int line, const char *text)
{
    const char *dir = subdir(name);
    gs_capture c;
    memset(&c, 0, sizeof c);
    c.grid_hz = 50;
    c.K = 3;
    c.bands = 1;
    c.width = 5;
    c.height = 4;
    c.saturation_dn = 4095;
    c.read_noise_dn = 1;
    c.locked = 1;
    CHECK_OK(gs_capture_alloc(&c));
    for (int i = 0; i < 3 * 20; i++) c.raw[i] = (unsigned short)(i * 61);
    for (int k = 0; k < 3; k++) {
        c.frames[k].cycles = 100;
        CHECK_OK(gs_capture_write_frame(dir, &c, k));
    }
    gs_capture_release(&c);
    char text_all[4096] = "";
    for (int i = 0; i < 14; i++) {
        strcat(text_all, i + 1 == line ? text : json_lines[i]);
        strcat(text_all, "\n");
    }
    fx_write_text(fx_path(dir, "capture.json"), text_all);
    return dir;
}

/* gs_capture_read fails with status st and a detail holding every string of want[]. */
static void expect_error(const char *dir, gs_status st, const char *const *want)
{
    gs_capture c;
    memset(&c, 0x5a, sizeof c);
    gs_status got = gs_capture_read(dir, &c);
    CHECK_MSG(got == st, "%s: status %s, expected %s (%s)", dir, gs_strerror(got), gs_strerror(st),
              gs_detail());
    for (int i = 0; want[i]; i++)
        CHECK_MSG(strstr(gs_detail(), want[i]) != NULL, "detail \"%s\" lacks \"%s\"", gs_detail(),
                  want[i]);
    CHECK(c.raw == NULL && c.frames == NULL && c.station_json == NULL && c.K == 0);
}

TEST(capture_format_valid_small_reads)
{
    const char *dir = small_capture("valid", 0, NULL);
    gs_capture c;
    CHECK_OK(gs_capture_read(dir, &c));
    CHECK(c.K == 3 && c.raw && c.raw[59] == 59 * 61);
    gs_capture_release(&c);
}

TEST(capture_format_missing_json)
{
    const char *dir = subdir("nojson");
    expect_error(dir, GS_ENOTFOUND, (const char *[]){"nojson/capture.json", "cannot open", NULL});
}

TEST(capture_format_bad_json_syntax)
{
    expect_error(small_capture("syntax", 7, "  \"height\": 4,,"), GS_EFORMAT,
                 (const char *[]){"capture.json:7:", "JSON syntax", NULL});
    expect_error(small_capture("dupkey", 4, "  \"K\": 3, \"K\": 3,"), GS_EFORMAT,
                 (const char *[]){"capture.json:4:", "duplicate", NULL});
    expect_error(small_capture("truncjson", 14, ""), GS_EFORMAT,
                 (const char *[]){"capture.json:", "JSON syntax", NULL});
    expect_error(small_capture("array", 1, "["), GS_EFORMAT, (const char *[]){"capture.json", NULL});
}

TEST(capture_format_wrong_format_string)
{
    expect_error(small_capture("fmt", 2, "  \"format\": \"gridsurvey-capture/2\","), GS_EFORMAT,
                 (const char *[]){"capture.json:2: field format: expected the string "
                                  "\"gridsurvey-capture/1\"", NULL});
    expect_error(small_capture("nofmt", 2, ""), GS_EFORMAT,
                 (const char *[]){"capture.json:1: field format", "missing", NULL});
}

TEST(capture_format_k_mismatch)
{
    expect_error(small_capture("k4", 4, "  \"K\": 4,"), GS_EFORMAT,
                 (const char *[]){"capture.json:9: field frames: expected an array of K = 4 frame "
                                  "objects", NULL});
    expect_error(small_capture("k1", 4, "  \"K\": 1,"), GS_EFORMAT,
                 (const char *[]){"capture.json:4: field K: expected an integer from 2 to 1024", NULL});
}

TEST(capture_format_duplicate_k)
{
    expect_error(small_capture("dupk", 12, "    {\"file\": \"frame_002.png\", \"k\": 1, \"cycles\": 100}"),
                 GS_EFORMAT,
                 (const char *[]){"capture.json:12: field frames[2].k: expected each k from 0 to 2 "
                                  "exactly once (k = 1 is also frames[1].k)", NULL});
    expect_error(small_capture("bigk", 12, "    {\"file\": \"frame_002.png\", \"k\": 3, \"cycles\": 100}"),
                 GS_EFORMAT, (const char *[]){"capture.json:12: field frames[2].k", NULL});
    expect_error(small_capture("dupfile", 12, "    {\"file\": \"frame_001.png\", \"k\": 2, \"cycles\": 100}"),
                 GS_EFORMAT, (const char *[]){"capture.json:12: field frames[2]", "same file", NULL});
}

TEST(capture_format_field_errors)
{
    static const struct {
        int line;
        const char *text, *want;
    } cases[] = {
        {3, "  \"grid_hz\": 55,", "capture.json:3: field grid_hz: expected 50 or 60"},
        {5, "  \"bands\": 2,", "capture.json:5: field bands: expected 1 or 3"},
        {6, "  \"width\": 5.5,", "capture.json:6: field width: expected an integer from 1 to 32768"},
        {6, "", "capture.json:1: field width: expected an integer from 1 to 32768 (the field is missing)"},
        {7, "  \"height\": \"4\",", "capture.json:7: field height"},
        {8, "  \"saturation\": 0,", "capture.json:8: field saturation: expected a number > black_level"},
        {8, "  \"saturation\": 70000,", "capture.json:8: field saturation"},
        {8, "  \"saturation\": 4095, \"black_level\": 5000,", "capture.json:8: field saturation"},
        {8, "  \"saturation\": 4095, \"black_level\": -1,", "capture.json:8: field black_level"},
        {8, "  \"saturation\": 4095, \"read_noise_dn\": -1,", "capture.json:8: field read_noise_dn"},
        {8, "  \"saturation\": 4095, \"gain_e_per_dn\": null,", "capture.json:8: field gain_e_per_dn"},
        {8, "  \"saturation\": 4095, \"locked\": \"yes\",", "capture.json:8: field locked: expected true or false"},
        {8, "  \"saturation\": 4095, \"utc\": \"yesterday\",", "capture.json:8: field utc: expected an ISO 8601"},
        {8, "  \"saturation\": 4095, \"utc\": \"2017-13-01T00:00:00Z\",", "field utc"},
        {8, "  \"saturation\": 4095, \"station\": [1, 2],", "capture.json:8: field station: expected a JSON object"},
        {8, "  \"saturation\": 4095, \"colour\": 1,", "capture.json:8: field colour: unknown field"},
        {9, "  \"frames\": {}, \"x_rest\": [", "capture.json:9: field frames: expected an array of K = 3"},
        {10, "    {\"file\": \"frame_000.png\", \"k\": 0, \"cycles\": 0},", "capture.json:10: field frames[0].cycles: expected a finite number > 0"},
        {11, "    {\"file\": \"frame_001.png\", \"k\": 1},", "capture.json:11: field frames[1].cycles", },
        {11, "    {\"file\": \"../frame_001.png\", \"k\": 1, \"cycles\": 100},", "capture.json:11: field frames[1].file: expected a file name"},
        {11, "    {\"file\": \"frame_001.tif\", \"k\": 1, \"cycles\": 100},", "capture.json:11: field frames[1].file"},
        {11, "    {\"file\": \"frame_001.png\", \"k\": -1, \"cycles\": 100},", "capture.json:11: field frames[1].k: expected an integer from 0 to K-1 = 2"},
        {11, "    {\"file\": \"frame_001.png\", \"k\": 1, \"cycles\": 100, \"hdr_map\": 3},", "capture.json:11: field frames[1].hdr_map"},
        {11, "    {\"file\": \"frame_001.png\", \"k\": 1, \"cycles\": 100, \"hdr_map\": \"frame_001.png\"},", "capture.json:11: field frames[1]"},
        {11, "    {\"file\": \"frame_001.png\", \"k\": 1, \"cycles\": 100, \"exposure\": 3},", "capture.json:11: field frames[1].exposure"},
        {11, "    7,", "capture.json:11: field frames[1]: expected an object"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        char name[32];
        snprintf(name, sizeof name, "field%zu", i);
        expect_error(small_capture(name, cases[i].line, cases[i].text), GS_EFORMAT,
                     (const char *[]){cases[i].want, NULL});
    }
    /* extensions are ignored */
    gs_capture c;
    CHECK_OK(gs_capture_read(small_capture("ext", 8, "  \"saturation\": 4095, \"x_scene\": {\"a\": 1},"), &c));
    gs_capture_release(&c);
}

/* The optional per-frame "grid_hz_measured", "start_s" and "window_half_period_s" (free running
 * only), and the capture's "window_period" (free running only): absent = NaN or
 * GS_PERIOD_UNKNOWN, exact round trip, out-of-range values refused by the reader (naming file,
 * line and field) and the writer. */
TEST(capture_format_grid_frequency_fields)
{
    const char *dir = subdir("freq");
    gs_capture a, b;
    make_capture(&a, 4, 1, 3, 2, 0);
    for (int k = 0; k < 4; k++) CHECK(isnan(a.frames[k].grid_hz_measured) && isnan(a.frames[k].start_s));
    a.frames[0].grid_hz_measured = 50.036686617969742;
    a.frames[0].start_s = 0;
    a.frames[2].grid_hz_measured = 59.99;
    a.frames[2].start_s = 6.1953800000000001;
    a.frames[3].start_s = 9.25;               /* a start without a frequency */
    for (int k = 0; k < 4; k++) CHECK(isnan(a.frames[k].window_half_period_s));
    a.frames[0].window_half_period_s = 0.0099932623456789012;   /* (a free-running capture) */
    a.frames[2].window_drift_windows = 0.62;
    CHECK(a.window_period == GS_PERIOD_UNKNOWN);
    for (int wp = GS_PERIOD_MEASURED; wp <= GS_PERIOD_NOMINAL; wp++) {   /* (each, read back) */
        a.window_period = wp;
        write_capture(dir, &a);
        CHECK_OK(gs_capture_read(dir, &b));
        check_same(&a, &b);
        gs_capture_release(&b);
    }
    write_capture(dir, &a);
    const char *path = fx_path(dir, "capture.json");
    char *text = fx_read_file(path, NULL);
    CHECK(text && strstr(text, "\"window_period\": \"nominal\",") &&
          strstr(text, "\"grid_hz_measured\": 50.0366866179697") &&
          strstr(text, "\"start_s\": 0") && strstr(text, "\"window_half_period_s\": 0.00999326234567890") &&
          strstr(text, "\"window_drift_windows\": 0.62"));
    free(text);
    CHECK_OK(gs_capture_read(dir, &b));
    check_same(&a, &b);
    CHECK(b.frames[0].grid_hz_measured == 50.036686617969742 && b.frames[2].start_s == 6.1953800000000001);
    CHECK(isnan(b.frames[1].grid_hz_measured) && isnan(b.frames[1].start_s));
    CHECK(isnan(b.frames[3].grid_hz_measured) && b.frames[3].start_s == 9.25);
    CHECK(b.frames[0].window_half_period_s == 0.0099932623456789012 && isnan(b.frames[1].window_half_period_s));
    CHECK(b.frames[2].window_drift_windows == 0.62 && isnan(b.frames[0].window_drift_windows));
    gs_capture_release(&b);
    /* the writer validates too */
    a.frames[1].grid_hz_measured = 70;
    CHECK(gs_capture_write_json(dir, &a) == GS_EINVAL);
    CHECK(strstr(gs_detail(), "field frames[1].grid_hz_measured") != NULL);
    a.frames[1].grid_hz_measured = NAN;
    a.frames[1].start_s = -0.5;
    CHECK(gs_capture_write_json(dir, &a) == GS_EINVAL);
    CHECK(strstr(gs_detail(), "field frames[1].start_s") != NULL);
    a.frames[1].start_s = NAN;
    a.frames[1].window_half_period_s = 0.02;    /* 25 Hz */
    CHECK(gs_capture_write_json(dir, &a) == GS_EINVAL);
    CHECK(strstr(gs_detail(), "field frames[1].window_half_period_s") != NULL);
    a.frames[1].window_half_period_s = NAN;
    a.frames[3].window_drift_windows = -0.1;
    CHECK(gs_capture_write_json(dir, &a) == GS_EINVAL);
    CHECK(strstr(gs_detail(), "field frames[3].window_drift_windows: expected a finite number >= 0 (windows), "
                              "only when locked is false") != NULL);
    a.frames[3].window_drift_windows = NAN;
    a.window_period = 3;
    CHECK(gs_capture_write_json(dir, &a) == GS_EINVAL);
    CHECK(strstr(gs_detail(), "field window_period: expected \"measured\" or \"nominal\", only when locked is "
                              "false") != NULL);
    a.window_period = GS_PERIOD_UNKNOWN;
    a.locked = 1;                               /* locked windows have no period of their own */
    CHECK(gs_capture_write_json(dir, &a) == GS_EINVAL);
    CHECK(strstr(gs_detail(), "field frames[0].window_half_period_s: expected a finite number from 1/130 "
                              "to 1/90 (s), only when locked is false") != NULL);
    gs_capture_release(&a);

    /* a capture without them (the small one) reads NaN */
    gs_capture c;
    CHECK_OK(gs_capture_read(small_capture("freq_absent", 0, NULL), &c));
    for (int k = 0; k < c.K; k++) CHECK(isnan(c.frames[k].grid_hz_measured) && isnan(c.frames[k].start_s));
    CHECK(c.window_period == GS_PERIOD_UNKNOWN);
    gs_capture_release(&c);
    CHECK_OK(gs_capture_read(small_capture("period_ok", 8, "  \"saturation\": 4095, \"locked\": false, "
                                            "\"window_period\": \"measured\","), &c));
    CHECK(c.window_period == GS_PERIOD_MEASURED);
    gs_capture_release(&c);
    CHECK_OK(gs_capture_read(small_capture("freq_ok", 11, "    {\"file\": \"frame_001.png\", \"k\": 1, "
                                            "\"cycles\": 100, \"grid_hz_measured\": 45, \"start_s\": 2},"), &c));
    CHECK(c.frames[1].grid_hz_measured == 45 && c.frames[1].start_s == 2);
    gs_capture_release(&c);
    static const struct {
        const char *text, *want;
    } cases[] = {
        {"    {\"file\": \"frame_001.png\", \"k\": 1, \"cycles\": 100, \"grid_hz_measured\": 70},",
         "capture.json:11: field frames[1].grid_hz_measured: expected a finite number from 45 to 65"},
        {"    {\"file\": \"frame_001.png\", \"k\": 1, \"cycles\": 100, \"grid_hz_measured\": \"50\"},",
         "capture.json:11: field frames[1].grid_hz_measured"},
        {"    {\"file\": \"frame_001.png\", \"k\": 1, \"cycles\": 100, \"grid_hz_measured\": null},",
         "capture.json:11: field frames[1].grid_hz_measured"},
        {"    {\"file\": \"frame_001.png\", \"k\": 1, \"cycles\": 100, \"start_s\": -1},",
         "capture.json:11: field frames[1].start_s: expected a finite number >= 0"},
        {"    {\"file\": \"frame_001.png\", \"k\": 1, \"cycles\": 100, \"window_half_period_s\": 0.01},",
         "capture.json:11: field frames[1].window_half_period_s: expected a finite number from 1/130 to "
         "1/90 (s), only when locked is false"},
        {"    {\"file\": \"frame_001.png\", \"k\": 1, \"cycles\": 100, \"window_drift_windows\": 0.2},",
         "capture.json:11: field frames[1].window_drift_windows: expected a finite number >= 0 (windows), "
         "only when locked is false"},
        {"  \"saturation\": 4095, \"window_period\": \"measured\",",   /* (locked) */
         "field window_period: expected \"measured\" or \"nominal\", only when locked is false"},
        {"  \"saturation\": 4095, \"locked\": false, \"window_period\": \"guessed\",",
         "capture.json:8: field window_period: expected \"measured\" or \"nominal\", not \"guessed\""},
        {"  \"saturation\": 4095, \"locked\": false, \"window_period\": 1,",
         "capture.json:8: field window_period: expected \"measured\" or \"nominal\" (a string)"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        char name[32];
        snprintf(name, sizeof name, "freq_bad%zu", i);
        expect_error(small_capture(name, strncmp(cases[i].text, "  \"sat", 6) ? 11 : 8, cases[i].text), GS_EFORMAT,
                     (const char *[]){cases[i].want, NULL});
    }
}

/* ------------------------------------------------------- malformed frames */

static void replace_png(const char *dir, const char *name, int w, int h, int ch, int depth16)
{
    void *px = calloc((size_t)w * h * ch, depth16 ? 2 : 1);
    unsigned char *png;
    size_t n;
    CHECK_OK(gs_png_encode(px, w, h, ch, depth16 ? 16 : 8, &png, &n));
    fx_write_file(fx_path(dir, name), png, n);
    free(png);
    free(px);
}

TEST(capture_format_missing_frame_file)
{
    const char *dir = small_capture("nofile", 0, NULL);
    const char *path = fx_path(dir, "frame_001.png");
    CHECK(unlink(path) == 0);
    expect_error(dir, GS_ENOTFOUND,
                 (const char *[]){"nofile/frame_001.png: cannot open",
                                  "(capture.json:11: frames[1].file)", NULL});
}

TEST(capture_format_truncated_png)
{
    const char *dir = small_capture("trunc", 0, NULL);
    const char *path = fx_path(dir, "frame_002.png");
    size_t n;
    char *b = fx_read_file(path, &n);
    CHECK(b && n > 60);
    /* cut inside the image data, and exactly before IEND */
    fx_write_file(fx_path(dir, "frame_002.png"), b, n / 2);
    expect_error(dir, GS_EFORMAT, (const char *[]){"trunc/frame_002.png: truncated PNG",
                                                   "(capture.json:12: frames[2].file)", NULL});
    fx_write_file(fx_path(dir, "frame_002.png"), b, n - 12);
    expect_error(dir, GS_EFORMAT, (const char *[]){"frame_002.png: truncated PNG", "IEND", NULL});
    /* cut inside IEND, its CRC included (libspng reads a CRC cut short as none: these read
     * as whole files) */
    for (size_t cut = 1; cut <= 11; cut++) {
        fx_write_file(fx_path(dir, "frame_002.png"), b, n - cut);
        expect_error(dir, GS_EFORMAT, (const char *[]){"frame_002.png: truncated PNG", "IEND", NULL});
    }
    fx_write_file(fx_path(dir, "frame_002.png"), b, 5);
    expect_error(dir, GS_EFORMAT, (const char *[]){"frame_002.png: not a PNG", NULL});
    fx_write_file(fx_path(dir, "frame_002.png"), "", 0);
    expect_error(dir, GS_EFORMAT, (const char *[]){"frame_002.png: not a PNG", NULL});
    /* a file without the signature is not a PNG whatever its size (8-32 bytes are shorter than
     * the signature and IHDR that the decoder reads at once); the signature cut short is */
    fx_write_file(fx_path(dir, "frame_002.png"), "garbage\n", 8);
    expect_error(dir, GS_EFORMAT, (const char *[]){"frame_002.png: not a PNG file (no PNG signature)", NULL});
    fx_write_file(fx_path(dir, "frame_002.png"), "not a PNG file, 31 bytes long.\n", 31);
    expect_error(dir, GS_EFORMAT, (const char *[]){"frame_002.png: not a PNG file (no PNG signature)", NULL});
    fx_write_file(fx_path(dir, "frame_002.png"), b, 20);
    expect_error(dir, GS_EFORMAT, (const char *[]){"frame_002.png: truncated PNG", NULL});
    /* a corrupted byte inside the compressed data (libspng finds the broken deflate stream
     * before the chunk's CRC) */
    b[n / 2] ^= 0x40;
    fx_write_file(fx_path(dir, "frame_002.png"), b, n);
    expect_error(dir, GS_EFORMAT, (const char *[]){"frame_002.png: corrupt PNG", "IDAT", NULL});
    /* a corrupted byte in the last chunk (IEND's CRC): only the CRC can tell */
    b[n - 1] ^= 0x01;
    b[n / 2] ^= 0x40;
    fx_write_file(fx_path(dir, "frame_002.png"), b, n);
    expect_error(dir, GS_EFORMAT, (const char *[]){"frame_002.png: corrupt PNG", "CRC", NULL});
    free(b);
}

/* The frames are read on every CPU (gs_capture_read): the error is still the first bad frame's
 * in k order, whichever part of the split reads it, and a read after the failure is whole. */
TEST(capture_format_frames_read_in_parallel_fail_at_the_first_bad_frame)
{
    char dir[1024];
    snprintf(dir, sizeof dir, "%s", subdir("parallel"));
    gs_capture a, b;
    make_capture(&a, 9, 3, 17, 11, 1);
    write_capture(dir, &a);
    CHECK_OK(gs_capture_read(dir, &b));
    check_same(&a, &b);
    gs_capture_release(&b);
    size_t n0, n1;
    char *f1 = fx_read_file(fx_path(dir, "frame_001.png"), &n0), *h7 = fx_read_file(fx_path(dir, "hdr_007.png"), &n1);
    CHECK(f1 && h7 && n0 > 60 && n1 > 60);
    /* a frame of the last part alone, then one of the first part too: the first in k order */
    fx_write_file(fx_path(dir, "hdr_007.png"), h7, n1 / 2);
    expect_error(dir, GS_EFORMAT, (const char *[]){"parallel/hdr_007.png: truncated PNG",
                                                   "frames[7].hdr_map)", NULL});
    fx_write_file(fx_path(dir, "frame_001.png"), f1, n0 / 2);
    for (int rep = 0; rep < 5; rep++)
        expect_error(dir, GS_EFORMAT, (const char *[]){"parallel/frame_001.png: truncated PNG",
                                                       "frames[1].file)", NULL});
    fx_write_file(fx_path(dir, "frame_001.png"), f1, n0);
    fx_write_file(fx_path(dir, "hdr_007.png"), h7, n1);
    CHECK_OK(gs_capture_read(dir, &b));
    check_same(&a, &b);
    free(f1);
    free(h7);
    gs_capture_release(&a);
    gs_capture_release(&b);
}

TEST(capture_format_8bit_png)
{
    const char *dir = small_capture("eight", 0, NULL);
    replace_png(dir, "frame_000.png", 5, 4, 1, 0);
    expect_error(dir, GS_EFORMAT, (const char *[]){"eight/frame_000.png: PNG has 8-bit samples: "
                                                   "expected 16-bit", "capture.json:10", NULL});
}

TEST(capture_format_wrong_size_or_channels)
{
    const char *dir = small_capture("size", 0, NULL);
    replace_png(dir, "frame_001.png", 6, 4, 1, 1);
    expect_error(dir, GS_EFORMAT, (const char *[]){"size/frame_001.png: PNG is 6x4 pixels: expected "
                                                   "width x height = 5x4", NULL});
    replace_png(dir, "frame_001.png", 5, 4, 3, 1);
    expect_error(dir, GS_EFORMAT, (const char *[]){"frame_001.png: PNG colour type is RGB: expected "
                                                   "grey (1 channel)", NULL});
}

TEST(capture_format_bad_hdr_map)
{
    const char *dir = small_capture("hdr", 11,
        "    {\"file\": \"frame_001.png\", \"k\": 1, \"cycles\": 100, \"hdr_map\": \"h1.png\"},");
    expect_error(dir, GS_ENOTFOUND, (const char *[]){"hdr/h1.png: cannot open",
                                                     "capture.json:11: frames[1].hdr_map", NULL});
    replace_png(dir, "h1.png", 5, 4, 1, 1);
    expect_error(dir, GS_EFORMAT, (const char *[]){"h1.png: PNG has 16-bit samples: expected 8-bit", NULL});
    unsigned char h[20] = {0};
    h[13] = 17;
    unsigned char *png;
    size_t n;
    CHECK_OK(gs_png_encode(h, 5, 4, 1, 8, &png, &n));
    fx_write_file(fx_path(dir, "h1.png"), png, n);
    free(png);
    expect_error(dir, GS_EFORMAT, (const char *[]){"h1.png: pixel (x 3, y 2) holds 17 halvings: "
                                                   "expected 0 to 16", NULL});
    h[13] = 16;
    CHECK_OK(gs_png_encode(h, 5, 4, 1, 8, &png, &n));
    fx_write_file(fx_path(dir, "h1.png"), png, n);
    free(png);
    gs_capture c;
    CHECK_OK(gs_capture_read(dir, &c));
    CHECK(c.halvings && c.halvings[20 + 13] == 16 && c.halvings[13] == 0);
    gs_capture_release(&c);
}

/* ---------------------------------------------------------------- writer */

TEST(capture_format_writer_validates)
{
    const char *dir = subdir("w");
    gs_capture c;
    make_capture(&c, 3, 1, 4, 4, 0);
    /* capture.json before its frames */
    CHECK(gs_capture_write_json(dir, &c) == GS_ENOTFOUND);
    CHECK(strstr(gs_detail(), "frame_000.png") != NULL);
    write_capture(dir, &c);
    c.frames[1].cycles = 0;
    CHECK(gs_capture_write_json(dir, &c) == GS_EINVAL);
    CHECK(strstr(gs_detail(), "field frames[1].cycles") != NULL);
    c.frames[1].cycles = 10;
    c.K = 1;
    CHECK(gs_capture_write_json(dir, &c) == GS_EINVAL && strstr(gs_detail(), "field K"));
    c.K = 3;
    snprintf(c.frames[2].file, GS_PATH_MAX, "a/b.png");
    CHECK(gs_capture_write_frame(dir, &c, 2) == GS_EINVAL);
    CHECK(gs_capture_write_json(dir, &c) == GS_EINVAL && strstr(gs_detail(), "frames[2].file"));
    snprintf(c.frames[2].file, GS_PATH_MAX, "frame_000.png");
    CHECK(gs_capture_write_json(dir, &c) == GS_EINVAL && strstr(gs_detail(), "same file"));
    snprintf(c.frames[2].file, GS_PATH_MAX, "frame_002.png");
    snprintf(c.utc, sizeof c.utc, "today");
    CHECK(gs_capture_write_json(dir, &c) == GS_EINVAL && strstr(gs_detail(), "field utc"));
    c.utc[0] = '\0';
    free(c.station_json);
    c.station_json = strdup("[1, 2]");
    CHECK(gs_capture_write_json(dir, &c) == GS_EINVAL && strstr(gs_detail(), "field station"));
    free(c.station_json);
    c.station_json = NULL;
    c.read_noise_dn = NAN;
    CHECK(gs_capture_write_json(dir, &c) == GS_EINVAL && strstr(gs_detail(), "read_noise_dn"));
    c.read_noise_dn = 1;
    CHECK(gs_capture_write_frame(dir, &c, 3) == GS_EINVAL);
    CHECK(gs_capture_write_frame(dir, &c, -1) == GS_EINVAL);
    /* a halved pixel in a frame without a map would be lost */
    CHECK_OK(gs_capture_alloc_hdr(&c));
    CHECK(gs_capture_alloc_hdr(&c) == GS_EINVAL);
    c.frames[0].hdr_map[0] = '\0';
    c.halvings[3] = 1;
    CHECK(gs_capture_write_frame(dir, &c, 0) == GS_EINVAL && strstr(gs_detail(), "hdr_map"));
    c.halvings[3] = 0;
    c.halvings[16 + 3] = 17;
    CHECK(gs_capture_write_frame(dir, &c, 1) == GS_EINVAL && strstr(gs_detail(), "halvings"));
    c.halvings[16 + 3] = 0;
    CHECK(gs_capture_alloc(&c) == GS_EINVAL); /* already allocated */
    gs_capture_release(&c);
    memset(&c, 0, sizeof c);
    c.K = 3;
    c.bands = 2;
    c.width = c.height = 1;
    CHECK(gs_capture_alloc(&c) == GS_EINVAL && strstr(gs_detail(), "field bands"));
    CHECK(gs_capture_alloc(NULL) == GS_EINVAL);
}

TEST(capture_format_value)
{
    gs_capture c;
    memset(&c, 0, sizeof c);
    c.grid_hz = 50;
    c.K = 2;
    c.bands = 3;
    c.width = 2;
    c.height = 1;
    c.saturation_dn = 4000;
    c.black_level_dn = 100;
    CHECK(isnan(gs_capture_value(&c, 0, 0, 0, 0))); /* no pixels */
    CHECK_OK(gs_capture_alloc(&c));
    CHECK_OK(gs_capture_alloc_hdr(&c));
    c.frames[0].cycles = 200;
    c.frames[1].cycles = 50;
    c.raw[0] = 300;                         /* k 0, x 0, R */
    c.raw[(2 + 1) * 3 + 2] = 90;            /* k 1, x 1, B: below the black level */
    c.raw[(2 + 0) * 3 + 1] = 4000;          /* k 1, x 0, G: saturated */
    c.halvings[2 + 1] = 3;                  /* k 1, x 1: 50 / 8 cycles */
    CHECK_NEAR(gs_capture_value(&c, 0, 0, 0, 0), 1.0, 0);
    CHECK_NEAR(gs_capture_value(&c, 1, 0, 1, 2), -10 * 8.0 / 50, 1e-15);
    CHECK(isnan(gs_capture_value(&c, 1, 0, 0, 1)));
    CHECK_NEAR(gs_capture_value(&c, 1, 0, 0, 0), -100 / 50.0, 1e-15);
    CHECK(isnan(gs_capture_value(&c, 2, 0, 0, 0)) && isnan(gs_capture_value(&c, 0, 1, 0, 0)));
    CHECK(isnan(gs_capture_value(&c, 0, 0, 2, 0)) && isnan(gs_capture_value(&c, 0, 0, 0, 3)));
    CHECK(isnan(gs_capture_value(&c, -1, 0, 0, 0)) && isnan(gs_capture_value(NULL, 0, 0, 0, 0)));
    c.frames[0].cycles = 0;
    CHECK(isnan(gs_capture_value(&c, 0, 0, 0, 0)));
    gs_capture_release(&c);
}

/* Mutations of a valid capture.json (byte flips, insertions, deletions, truncations): the reader
 * never crashes (the sanitizer build checks memory), fails with a detail naming capture.json or a
 * frame, or reads a capture that passes its own checks. */
TEST(capture_format_fuzz_json)
{
    const char *dir = small_capture("fuzz", 8, "  \"saturation\": 4095, \"utc\": \"2017-07-21T22:05:00Z\", "
                                    "\"station\": {\"a\": [1, {\"b\": \"c\\\"d\"}]}, \"black_level\": 1,");
    const char *path = fx_path(dir, "capture.json");
    size_t n;
    char *orig = fx_read_file(path, &n);
    CHECK(orig != NULL);
    if (!orig) return;
    static const char alphabet[] = "{}[]\":,0123456789.-eE \n\\tfnrux_K";
    rng = 4242;
    int ok = 0, failed = 0;
    char *buf = malloc(n + 64);
    for (int it = 0; it < 400; it++) {
        size_t len = n;
        memcpy(buf, orig, n);
        int edits = 1 + (int)(gs_splitmix64(&rng) % 3);
        for (int e = 0; e < edits; e++) {
            size_t pos = len ? gs_splitmix64(&rng) % len : 0;
            switch (gs_splitmix64(&rng) % 4) {
            case 0: buf[pos] = alphabet[gs_splitmix64(&rng) % (sizeof alphabet - 1)]; break;
            case 1:
                if (len + 1 < n + 64) {
                    memmove(buf + pos + 1, buf + pos, len - pos);
                    buf[pos] = alphabet[gs_splitmix64(&rng) % (sizeof alphabet - 1)];
                    len++;
                }
                break;
            case 2:
                if (len) {
                    memmove(buf + pos, buf + pos + 1, len - pos - 1);
                    len--;
                }
                break;
            case 3: len = pos; break;
            }
        }
        fx_write_file(path, buf, len);
        gs_capture c;
        gs_status st = gs_capture_read(dir, &c);
        if (st == GS_OK) {
            ok++;
            CHECK(c.raw && c.frames && c.K >= 2 && gs_capture_check(&c, "fuzz") == GS_OK);
            gs_capture_release(&c);
        } else {
            failed++;
            CHECK_MSG(strstr(gs_detail(), "capture.json") || strstr(gs_detail(), ".png"),
                      "unexplained failure: %s", gs_detail());
            CHECK(c.raw == NULL && c.frames == NULL);
        }
    }
    printf("    400 mutations: %d read, %d rejected\n", ok, failed);
    CHECK(failed > 200);
    free(buf);
    free(orig);
}
