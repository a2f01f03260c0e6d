/* recognize_fixture.h - captures for the tests of `gridsurvey recognize` and its maps
 * (tests/test_recognize_cli.c, tests/test_recognize_maps.c), implemented in
 * tests/recognize_fixture.c, prefix recfx_.
 *
 * The captures are written by an independent program: a Python script (numpy only) that
 * follows docs/formats.md by hand (16-bit PNGs chunk by chunk, capture.json) and renders lights
 * whose per-window signals it integrates itself from the DELIGHT BRFs exported as CSV by
 * `gridsurvey delight export` (Fourier series of each BRF, delayed by phi/pi cycles, averaged
 * over the K windows: docs/design.md, Eq. 5), plus Gaussian read noise matching capture.json.
 * Renders are cached in the runner's temporary root, so tests that share a scene render it
 * once. JSON output is parsed with Jansson; map PNGs are read back with gs_png_decode. */
#ifndef GRIDSURVEY_TESTS_RECOGNIZE_FIXTURE_H
#define GRIDSURVEY_TESTS_RECOGNIZE_FIXTURE_H

#include <jansson.h>
#include <stddef.h>

typedef struct {
    double x, y, flux;
    const char *bulb;
    double phase_deg;
} recfx_light;

typedef struct {
    const char *key;        /* cache name */
    int grid_hz, K, bands, width, height;
    unsigned seed;
    const recfx_light *lights;
    int count;
} recfx_scene;

/* Scene A: RGB, 50 Hz, K = 26, six technologies on the three phases. B: monochrome, 60 Hz,
 * K = 22 (the ACam's 60 Hz K). C: phases off the 0/120/240 set (each nearer to the set than its
 * +180 twin, which a flicker cannot tell apart: docs/design.md). D: a delta-wye transformer's
 * 30 deg shift. E: sky and noise only. */
extern const recfx_light recfx_lights_a[], recfx_lights_b[], recfx_lights_c[], recfx_lights_d[];
extern const recfx_scene recfx_scene_a, recfx_scene_b, recfx_scene_c, recfx_scene_d,
    recfx_scene_e;

/* The runner's temporary root (parent of this test's directory), shared by the tests of a run;
 * a static buffer. */
const char *recfx_cache_root(void);
/* The built-in DELIGHT as a SQLite file, generated once per run; sets GRIDSURVEY_DELIGHT to it
 * for the commands the test runs (generating it in every command would cost 0.25 s each). */
const char *recfx_cached_delight(void);
/* Renders scene s (once per run; also exports the DELIGHT as CSV once) and returns its capture
 * directory (a static buffer). */
const char *recfx_render(const recfx_scene *s);

/* Runs `gridsurvey recognize ARGS --format json` (stderr to a file) and parses stdout as JSON
 * (json_decref it; NULL and a test failure when it is not JSON); the exit status must be 0,
 * and with quiet nothing may be on stderr. */
json_t *recfx_recognize_ok(const char *args, int quiet);
/* recfx_recognize_ok on scene s (rendered, with the cached DELIGHT) with flags, and with maps
 * "--maps TMPDIR/maps". */
json_t *recfx_recognize_scene(const recfx_scene *s, const char *flags, int maps, int quiet);
/* Nothing on stderr (under the sanitizers, LeakSanitizer may list its suppressions there). */
int recfx_quiet_stderr(const char *err);
/* The JSON light within 1 px of (x, y), or NULL. */
json_t *recfx_light_near(json_t *root, double x, double y);
/* 1 if light l's "flags" hold name. */
int recfx_has_flag(json_t *l, const char *name);
/* a - b wrapped to [-180, 180] degrees. */
double recfx_circ_diff_deg(double a, double b);

/* Hue in degrees of an RGB colour (NaN for grey). */
double recfx_hue_deg(const unsigned char *p);
/* A map PNG: checks the signature, reads the size from IHDR and decodes it as 8-bit RGB.
 * Returns the pixels (free()) or NULL. */
unsigned char *recfx_read_png(const char *path, int *w, int *h);
/* The map colour at the centre of capture pixel (x, y) (rounded), at scale s. */
const unsigned char *recfx_map_at(const unsigned char *px, int png_w, int s, double x, double y);
/* docs/recognize-cli.md: s = clamp(floor(640 / max(W, H)), 1, 16); image max(s W, 480) wide. */
int recfx_doc_scale(int w, int h);
/* The colour of a pure hue at phase 0/120/240: the phase's channel dominates. */
void recfx_check_phase_colour(const unsigned char *p, double phase, const char *what);

#endif
