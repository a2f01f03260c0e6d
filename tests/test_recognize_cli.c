/* test_recognize_cli.c - `gridsurvey recognize` end to end (paper Sec. 4, Eq. 7; Figs. 1 and 3)
 * on captures rendered by an independent program (tests/recognize_fixture.h): bulbs and phases
 * in the JSON and the table, the paper's model flags, continuous and six phases, a DELIGHT
 * subset (unknown, not a confident wrong answer), one-line errors and --help. The maps:
 * tests/test_recognize_maps.c. */
#include "recognize/recognize.h"
#include "recognize/internal.h"
#include "tests/fixtures.h"
#include "tests/recognize_fixture.h"
#include "tests/test.h"

#include <jansson.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

static char out[1 << 20];

/* Every light of the scene found at its position with its bulb and (discrete) phase. */
static void check_discrete(json_t *root, const recfx_scene *s)
{
    CHECK(!strcmp(json_string_value(json_object_get(root, "format")), "gridsurvey-lights/1"));
    CHECK(json_array_size(json_object_get(root, "lights")) == (size_t)s->count);
    for (int i = 0; i < s->count; i++) {
        const recfx_light *t = &s->lights[i];
        json_t *l = recfx_light_near(root, t->x, t->y);
        CHECK_MSG(l != NULL, "light %s at (%.1f, %.1f) not found", t->bulb, t->x, t->y);
        if (!l) continue;
        const char *bulb = json_string_value(json_object_get(l, "bulb"));
        CHECK_MSG(bulb && !strcmp(bulb, t->bulb), "light at (%.1f, %.1f): bulb %s, expected %s",
                  t->x, t->y, bulb ? bulb : "null", t->bulb);
        json_t *ph = json_object_get(l, "phase_deg");
        CHECK_MSG(json_is_number(ph) && fabs(recfx_circ_diff_deg(json_number_value(ph), t->phase_deg)) < 1e-9,
                  "light %s: phase %g, expected %g", t->bulb, json_number_value(ph), t->phase_deg);
        CHECK(json_number_value(json_object_get(l, "confidence")) >= 0.8);
        CHECK(json_number_value(json_object_get(l, "p_value")) >= 1e-3);
        CHECK(json_array_size(json_object_get(l, "flags")) == 0);
        CHECK(json_is_string(json_object_get(l, "technology")));
        CHECK(json_is_integer(json_object_get(l, "dof")) && json_integer_value(json_object_get(l, "dof")) > 0);
    }
}

TEST(recognize_cli_json_bulbs_and_phases)
{
    const char *dir = recfx_render(&recfx_scene_a);
    unsetenv("GRIDSURVEY_DELIGHT");   /* this one generates the built-in database itself */
    json_t *root = recfx_recognize_ok(dir, 1);
    if (!root) return;
    check_discrete(root, &recfx_scene_a);
    json_t *cap = json_object_get(root, "capture");
    CHECK(json_integer_value(json_object_get(cap, "grid_hz")) == 50);
    CHECK(json_integer_value(json_object_get(cap, "K")) == 26);
    CHECK(json_integer_value(json_object_get(cap, "bands")) == 3);
    CHECK(json_integer_value(json_object_get(cap, "width")) == 160);
    CHECK(json_is_true(json_object_get(cap, "locked")));
    CHECK(!strcmp(json_string_value(json_object_get(cap, "utc")), "2017-07-21T22:05:00Z"));
    CHECK_NEAR(json_number_value(json_object_get(json_object_get(cap, "station"), "lat")), 32.79, 1e-12);
    json_t *rcg = json_object_get(root, "recognition");
    CHECK(!strcmp(json_string_value(json_object_get(rcg, "phases")), "3"));
    CHECK(!strcmp(json_string_value(json_object_get(rcg, "delight")), "built-in"));
    CHECK(json_integer_value(json_object_get(rcg, "candidates")) >= 30);
    json_t *sum = json_object_get(root, "summary");
    CHECK(json_integer_value(json_object_get(sum, "lights")) == 6);
    CHECK(json_integer_value(json_object_get(sum, "with_bulb")) == 6);
    CHECK(json_integer_value(json_object_get(sum, "with_phase")) == 6);
    /* brightness is the fitted flux: sum over bands of the mean per-cycle flux (Eq. 6) */
    for (int i = 0; i < recfx_scene_a.count; i++) {
        json_t *l = recfx_light_near(root, recfx_lights_a[i].x, recfx_lights_a[i].y);
        if (!l) continue;
        CHECK_NEAR(json_number_value(json_object_get(l, "brightness")), recfx_lights_a[i].flux, 0.03 * recfx_lights_a[i].flux);
        json_t *ru = json_object_get(l, "runner_up");
        CHECK(json_is_null(ru) || (json_is_string(json_object_get(ru, "bulb")) &&
                                   json_number_value(json_object_get(ru, "confidence")) < 0.2));
        CHECK(json_number_value(json_object_get(l, "phase_sigma_deg")) == 0.0);
    }
    json_decref(root);
}

/* --band-gains off --model-error 0 is the paper's Eq. 7: these unreddened lights are recognized
 * just the same, and the JSON says which model ran; --nested-tests off runs Eq. 7 alone. */
TEST(recognize_cli_paper_model_flags)
{
    recfx_cached_delight();
    const char *dir = recfx_render(&recfx_scene_a);
    char args[1200];
    snprintf(args, sizeof args, "%s --band-model chroma --model-error 0", dir);
    json_t *root = recfx_recognize_ok(args, 0);
    if (!root) return;
    check_discrete(root, &recfx_scene_a);
    json_t *rcg = json_object_get(root, "recognition");
    CHECK(!strcmp(json_string_value(json_object_get(rcg, "band_model")), "chroma"));
    CHECK(json_number_value(json_object_get(rcg, "model_error")) == 0.0);
    json_t *nz = json_object_get(rcg, "noise");
    CHECK(!strcmp(json_string_value(json_object_get(nz, "source")), "fixed"));
    json_decref(root);
    snprintf(args, sizeof args, "%s --model-error 0.1 --band-model free", dir);
    root = recfx_recognize_ok(args, 0);
    if (!root) return;
    rcg = json_object_get(root, "recognition");
    CHECK(!strcmp(json_string_value(json_object_get(rcg, "band_model")), "free"));
    CHECK_NEAR(json_number_value(json_object_get(rcg, "model_error")), 0.1, 1e-15);
    json_t *l0 = json_array_get(json_object_get(root, "lights"), 0);
    CHECK_NEAR(json_number_value(json_object_get(l0, "model_error")), 0.1, 1e-15);
    json_decref(root);
    /* --nested-tests off: Eq. 7 alone, exactly the paper's with the flags above: the same answers
     * as with the tests on for these single database lights, no test run (shape p-value 1,
     * p_other and p_blend 0; with the tests on, each light's shape test gives a p-value below 1) */
    const char *paper = "--band-model chroma --model-error 0 --other-prior 0 --flat-share 0";
    json_t *with = NULL, *without = NULL;
    snprintf(args, sizeof args, "%s %s --nested-tests on", dir, paper);
    with = recfx_recognize_ok(args, 0);
    snprintf(args, sizeof args, "%s %s --nested-tests off", dir, paper);
    without = recfx_recognize_ok(args, 0);
    if (!with || !without) return;
    CHECK(json_is_true(json_object_get(json_object_get(with, "recognition"), "nested_tests")));
    CHECK(json_is_false(json_object_get(json_object_get(without, "recognition"), "nested_tests")));
    json_t *lw = json_object_get(with, "lights"), *lo = json_object_get(without, "lights");
    CHECK(json_array_size(lw) == 6 && json_array_size(lo) == 6);
    for (size_t i = 0; i < json_array_size(lo); i++) {
        json_t *a = json_array_get(lw, i), *b = json_array_get(lo, i);
        CHECK(!strcmp(json_string_value(json_object_get(a, "bulb")), json_string_value(json_object_get(b, "bulb"))));
        CHECK(json_number_value(json_object_get(a, "phase_deg")) == json_number_value(json_object_get(b, "phase_deg")));
        CHECK(json_number_value(json_object_get(a, "shape_p_value")) < 1.0);
        CHECK(json_number_value(json_object_get(b, "shape_p_value")) == 1.0);
        CHECK(json_number_value(json_object_get(b, "p_other")) == 0.0 && json_number_value(json_object_get(b, "p_blend")) == 0.0);
    }
    json_decref(with);
    json_decref(without);
    /* a fixed flat share is what the last pass used, and said so */
    snprintf(args, sizeof args, "%s --flat-share 0.01", dir);
    root = recfx_recognize_ok(args, 0);
    if (!root) return;
    rcg = json_object_get(root, "recognition");
    CHECK_NEAR(json_number_value(json_object_get(rcg, "flat_share")), 0.01, 1e-15);
    nz = json_object_get(rcg, "noise");
    CHECK_NEAR(json_number_value(json_object_get(nz, "flat_share")), 0.01, 1e-15);
    CHECK(json_integer_value(json_object_get(nz, "flat_lights")) == 0);
    json_decref(root);
    /* the defaults: reddened, the excess measured (the scene's few lights: the camera noise,
     * said so, or the population) */
    root = recfx_recognize_ok(dir, 0);
    if (!root) return;
    rcg = json_object_get(root, "recognition");
    CHECK(!strcmp(json_string_value(json_object_get(rcg, "band_model")), "reddened"));
    CHECK(!strcmp(json_string_value(json_object_get(rcg, "model_error")), "auto"));
    nz = json_object_get(rcg, "noise");
    const char *src = json_string_value(json_object_get(nz, "source"));
    size_t used = (size_t)json_integer_value(json_object_get(nz, "lights_used"));
    CHECK_MSG(src && ((!strcmp(src, "camera") && used == 0) || (!strcmp(src, "population") && used >= 8)),
              "noise source %s from %zu lights", src ? src : "(none)", used);
    json_decref(root);
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "%s recognize %s --band-model maybe", test_bin(), dir);
    CHECK(test_run(cmd, out, sizeof out) == 2 && strstr(out, "--band-model"));
    snprintf(cmd, sizeof cmd, "%s recognize %s --model-error 2", test_bin(), dir);
    CHECK(test_run(cmd, out, sizeof out) == 2 && strstr(out, "--model-error"));
    snprintf(cmd, sizeof cmd, "%s recognize %s --flat-share 0.5", test_bin(), dir);
    CHECK(test_run(cmd, out, sizeof out) == 2 && strstr(out, "--flat-share"));
    snprintf(cmd, sizeof cmd, "%s recognize %s --nested-tests maybe", test_bin(), dir);
    CHECK(test_run(cmd, out, sizeof out) == 2 && strstr(out, "--nested-tests"));
}

TEST(recognize_cli_mono_60hz_table)
{
    recfx_cached_delight();
    const char *dir = recfx_render(&recfx_scene_b);
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "%s recognize %s", test_bin(), dir);
    int rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 0, "exit %d: %s", rc, out);
    CHECK(strstr(out, "60 Hz grid, K = 22, 1 band,") != NULL);
    CHECK(strstr(out, "4 lights: 4 with a bulb, 4 with a phase") != NULL);
    for (int i = 0; i < recfx_scene_b.count; i++) {
        /* the light's row: its bulb, then its phase "P.0 +- 0.0" */
        char phase[32];
        snprintf(phase, sizeof phase, " %.1f +- 0.0 ", recfx_lights_b[i].phase_deg);
        const char *line = out;
        int found = 0;
        while (line && *line && !found) {
            const char *end = strchr(line, '\n');
            size_t len = end ? (size_t)(end - line) : strlen(line);
            char buf[512];
            snprintf(buf, sizeof buf, "%.*s", (int)(len < sizeof buf ? len : sizeof buf - 1), line);
            char id[64];
            snprintf(id, sizeof id, "  %s ", recfx_lights_b[i].bulb);
            found = strstr(buf, id) && strstr(buf, phase) && !strstr(buf, "unknown");
            line = end ? end + 1 : NULL;
        }
        CHECK_MSG(found, "no table row with %s at %s:\n%s", recfx_lights_b[i].bulb, phase, out);
    }
}

/* One light is "1 light", not "1 lights": recognize's summary, run's and export's lines. */
TEST(recognize_cli_one_light_singular)
{
    static const recfx_light one[] = {{30.4, 22.7, 400, "hps-150w", 120}};
    static const recfx_scene scene = {"one", 60, 22, 1, 64, 48, 19, one, 1};
    recfx_cached_delight();
    const char *dir = recfx_render(&scene);
    CHECK(fx_run(out, sizeof out, "%s recognize %s", test_bin(), dir) == 0);
    CHECK_MSG(strstr(out, "\n1 light: 1 with a bulb, 1 with a phase\n"), "%s", out);
    /* (run: a copy without the renderer's station, whose fields are not a gridsurvey-station/1) */
    char copy[1024], path[1100];
    snprintf(copy, sizeof copy, "%s/one", test_tmpdir());
    CHECK(fx_run(out, sizeof out, "rm -rf %s && cp -r %s %s", copy, dir, copy) == 0);
    snprintf(path, sizeof path, "%s/capture.json", copy);
    json_t *root = json_load_file(path, 0, NULL);
    CHECK(root && json_object_del(root, "station") == 0 && json_dump_file(root, path, JSON_INDENT(1)) == 0);
    json_decref(root);
    CHECK(fx_run(out, sizeof out, "%s run %s --db %s/one.sqlite --no-progress && %s export --db %s/one.sqlite -o %s/one.csv",
                 test_bin(), copy, test_tmpdir(), test_bin(), test_tmpdir(), test_tmpdir()) == 0);
    CHECK_MSG(strstr(out, "run: 1 light, 1 with a bulb, 1 with a phase") && strstr(out, "exported 1 light ->"), "%s", out);
}

TEST(recognize_cli_continuous_phase_within_sigma)
{
    json_t *root = recfx_recognize_scene(&recfx_scene_c, "--phases continuous", 1, 0);
    if (!root) return;
    CHECK(!strcmp(json_string_value(json_object_get(json_object_get(root, "recognition"), "phases")),
                  "continuous"));
    CHECK(json_array_size(json_object_get(root, "lights")) == (size_t)recfx_scene_c.count);
    const char *path = fx_tmp("maps/phase_map.png");
    int w = 0, h = 0;
    unsigned char *px = recfx_read_png(path, &w, &h);
    int s = recfx_doc_scale(recfx_scene_c.width, recfx_scene_c.height);
    for (int i = 0; i < recfx_scene_c.count; i++) {
        const recfx_light *t = &recfx_lights_c[i];
        json_t *l = recfx_light_near(root, t->x, t->y);
        CHECK_MSG(l != NULL, "light %s not found", t->bulb);
        if (!l) continue;
        const char *bulb = json_string_value(json_object_get(l, "bulb"));
        CHECK_MSG(bulb && !strcmp(bulb, t->bulb), "bulb %s, expected %s", bulb ? bulb : "null", t->bulb);
        double phase = json_number_value(json_object_get(l, "phase_deg"));
        double sigma = json_number_value(json_object_get(l, "phase_sigma_deg"));
        /* within 3 reported sigmas, and the sigma is informative (not the uniform 51.96) */
        CHECK_MSG(sigma > 0.0 && sigma < 3.0, "light %s: sigma %g deg", t->bulb, sigma);
        CHECK_MSG(fabs(recfx_circ_diff_deg(phase, t->phase_deg)) <= 3.0 * sigma,
                  "light %s: phase %.4f +- %.4f, true %.1f", t->bulb, phase, sigma, t->phase_deg);
        /* Fig. 1 for continuous phases: the hue wheel (hue = phase) at the light's centre */
        if (px && w == (s * recfx_scene_c.width > 480 ? s * recfx_scene_c.width : 480)) {
            double hue = recfx_hue_deg(recfx_map_at(px, w, s, t->x, t->y));
            CHECK_MSG(isfinite(hue) && fabs(recfx_circ_diff_deg(hue, t->phase_deg)) < 6.0,
                      "light %s: map hue %.1f, phase %.1f", t->bulb, hue, t->phase_deg);
        }
    }
    CHECK(w == 640 && h > s * recfx_scene_c.height);
    free(px);
    json_decref(root);
}

TEST(recognize_cli_six_phases_transformer)
{
    json_t *root = recfx_recognize_scene(&recfx_scene_d, "--phases 6 --transformer-deg 30", 0, 0);
    if (!root) return;
    check_discrete(root, &recfx_scene_d);
    CHECK(!strcmp(json_string_value(json_object_get(json_object_get(root, "recognition"), "phases")), "6"));
    json_decref(root);
    /* the same lights with only 0/120/240 allowed: the 30/150/270 ones fit nothing (unknown) */
    root = recfx_recognize_scene(&recfx_scene_d, "", 0, 0);
    if (!root) return;
    for (int i = 0; i < recfx_scene_d.count; i++) {
        json_t *l = recfx_light_near(root, recfx_lights_d[i].x, recfx_lights_d[i].y);
        CHECK(l != NULL);
        if (!l || recfx_lights_d[i].phase_deg == 120) continue;
        CHECK_MSG(json_is_null(json_object_get(l, "bulb")) && recfx_has_flag(l, "unknown") &&
                      json_is_null(json_object_get(l, "phase_deg")),
                  "light %s at %g deg with phases 3: expected unknown", recfx_lights_d[i].bulb, recfx_lights_d[i].phase_deg);
    }
    json_decref(root);
}

TEST(recognize_cli_delight_subset_unknown)
{
    const char *dir = recfx_render(&recfx_scene_a);
    char sub[1024], db[1024], cmd[4096];
    snprintf(sub, sizeof sub, "%s/sub.csv", test_tmpdir());
    snprintf(db, sizeof db, "%s/sub.sqlite", test_tmpdir());
    snprintf(cmd, sizeof cmd, "%s delight export | grep -E '^(bulb_id|hps-150w|mh-250w),' > %s && "
                              "%s delight import %s --delight %s",
             test_bin(), sub, test_bin(), sub, db);
    CHECK_MSG(test_run(cmd, out, sizeof out) == 0, "%s", out);
    for (int how = 0; how < 2; how++) {
        char args[3000];
        /* how 0: $GRIDSURVEY_DELIGHT; how 1: --delight wins over a bad $GRIDSURVEY_DELIGHT */
        if (how == 0) snprintf(args, sizeof args, "%s", dir);
        else snprintf(args, sizeof args, "%s --delight %s", dir, db);
        setenv("GRIDSURVEY_DELIGHT", how == 0 ? db : "/nonexistent/delight.sqlite", 1);
        json_t *root = recfx_recognize_ok(args, 0);
        if (!root) continue;
        CHECK(json_integer_value(json_object_get(json_object_get(root, "recognition"), "candidates")) == 2);
        for (int i = 0; i < recfx_scene_a.count; i++) {
            json_t *l = recfx_light_near(root, recfx_lights_a[i].x, recfx_lights_a[i].y);
            CHECK(l != NULL);
            if (!l) continue;
            int known = !strcmp(recfx_lights_a[i].bulb, "hps-150w") || !strcmp(recfx_lights_a[i].bulb, "mh-250w");
            const char *bulb = json_string_value(json_object_get(l, "bulb"));
            if (known) {
                CHECK(bulb && !strcmp(bulb, recfx_lights_a[i].bulb));
                continue;
            }
            /* not in the database: unknown, not a confident wrong answer; the best fit is the
             * runner-up */
            CHECK_MSG(json_is_null(json_object_get(l, "bulb")) && recfx_has_flag(l, "unknown"),
                      "light %s: bulb %s, expected null and unknown", recfx_lights_a[i].bulb, bulb ? bulb : "null");
            CHECK(json_is_null(json_object_get(l, "technology")));
            CHECK(json_is_null(json_object_get(l, "phase_deg")));
            CHECK(json_number_value(json_object_get(l, "p_value")) < 1e-3);
            CHECK(json_is_object(json_object_get(l, "runner_up")));
        }
        json_decref(root);
    }
    unsetenv("GRIDSURVEY_DELIGHT");
}

/* A copy of scene A's capture (the independent renderer's, its windows ideal) declared free
 * running, each frame's windows timed with P = 10 ms at a grid frequency that moves them
 * drift windows over the exposure (NaN: without the timing fields); every fifth frame (k = 0,
 * 5, ...) with odd_drift recorded as its range (window_drift_windows) when it differs; with
 * corrupt, those frames hold frame 1's pixels. No station. */
static void free_running_copy(const char *src, const char *name, double drift, double odd_drift, int corrupt,
                              const char *period, char *dir, size_t n)
{
    snprintf(dir, n, "%s/free_%s", test_tmpdir(), name);
    char o[1024];
    CHECK_MSG(fx_run(o, sizeof o, "rm -rf %s && cp -r %s %s", dir, src, dir) == 0, "%s", o);
    char path[1100];
    snprintf(path, sizeof path, "%s/capture.json", dir);
    json_error_t err;
    json_t *root = json_load_file(path, 0, &err);
    CHECK_MSG(root != NULL, "%s: %s", path, err.text);
    if (!root) return;
    json_object_set_new(root, "locked", json_false());
    if (period) json_object_set_new(root, "window_period", json_string(period));
    json_object_del(root, "station");   /* (the renderer's carries a field `run` does not take) */
    int K = (int)json_integer_value(json_object_get(root, "K"));
    json_t *frames = json_object_get(root, "frames"), *f;
    const char *one = json_string_value(json_object_get(json_array_get(frames, 1), "file"));
    size_t i;
    json_array_foreach(frames, i, f) {
        int k = (int)json_integer_value(json_object_get(f, "k"));
        double C = json_number_value(json_object_get(f, "cycles"));
        if (!isnan(drift)) {
            json_object_set_new(f, "window_half_period_s", json_real(0.01));
            json_object_set_new(f, "grid_hz_measured", json_real((1.0 + drift / (K * C)) / (2.0 * 0.01)));
        }
        if (k % 5 == 0 && !isnan(odd_drift) && odd_drift != drift)
            json_object_set_new(f, "window_drift_windows", json_real(odd_drift));
        if (corrupt && k % 5 == 0)
            CHECK(fx_run(o, sizeof o, "cp %s/%s %s/%s", dir, one, dir,
                         json_string_value(json_object_get(f, "file"))) == 0);
    }
    CHECK(json_dump_file(root, path, JSON_INDENT(2)) == 0);
    json_decref(root);
}

/* Free running, a frame whose windows moved more than half a window over its exposure is not a
 * sample of Eq. 5's window k (a smeared capture's answers were confident and wrong,
 * docs/recognition.md "Free-running captures"): rec_match_catalog leaves its samples out, and
 * the lights are answered from the other frames (flag drift). Here six of the 26 frames are
 * overwritten with frame 1: left out, the answers are the locked capture's; kept (drifting less
 * than half a window), the same pixels change them. With every frame out, or capture.json
 * without the timing, no light is answered; the maps (one noise per pixel row, no sample left
 * out) answer no pixel once a frame is out. --max-drift-windows moves the threshold (none:
 * every frame with a known drift kept), for the maps too. Its default, auto, keeps every frame
 * when capture.json's window_period is "measured" (the maps still stop at half a window), and
 * is 0.5 when it is "nominal" or absent. */
TEST(recognize_cli_free_running_drift_leaves_frames_out)
{
    const char *src = recfx_render(&recfx_scene_a);
    const char *dbp = recfx_cached_delight();
    json_t *locked = recfx_recognize_ok(src, 1);
    if (!locked) return;
    CHECK(json_real_value(json_object_get(json_object_get(locked, "capture"), "drift_windows")) == 0.0);
    gs_delight *d = NULL;
    CHECK_OK(gs_delight_open(dbp, &d));
    rec_matcher *m = NULL;
    size_t matched_locked = 0;
    static const struct {
        const char *name;
        double drift, odd_drift;
        int corrupt, answers, same, out;   /* out: frames left out */
        const char *note;
        double max;                         /* --max-drift-windows (0: the default, auto;
                                             * REC_DRIFT_AUTO: auto given) */
        const char *period;                 /* capture.json's window_period (NULL: absent) */
    } cases[] = {
        {"small", 0.45, 0.45, 0, 1, 1, 0, "free running: the windows drifted at most 0.45 windows over an exposure", 0, NULL},
        {"some_out", 0.45, 0.55, 1, 1, 1, 6, "6 of 26 frames left out (flag drift): 6 drifted over 0.5 windows "
                                              "(the most 0.55, frame 0) (--max-drift-windows auto, the period not "
                                              "recorded: capture.json has no window_period)", 0, NULL},
        {"some_kept", 0.45, 0.45, 1, 1, 0, 0, "drifted at most 0.45", 0, NULL},
        {"all_out", 0.55, 0.55, 0, 0, 0, 26, "26 of 26 frames left out", 0, NULL},
        {"unknown", NAN, NAN, 0, 0, 0, 26, "26 of 26 frames left out (flag drift): 26 without the timing to "
                                            "tell (window_drift_windows, or window_half_period_s and "
                                            "grid_hz_measured)", 0, NULL},
        {"keeps_at_0.6", 0.45, 0.55, 1, 1, 0, 0, "drifted at most 0.55 windows over an exposure (frame 0)", 0.6, NULL},
        {"drops_at_0.4", 0.45, 0.45, 0, 0, 0, 26, "26 of 26 frames left out (flag drift): 26 drifted over 0.4 windows", 0.4, NULL},
        {"keeps_at_none", 3.0, 3.0, 0, 1, 1, 0, "drifted at most 3 windows", INFINITY, NULL},
        {"measured_keeps", 3.0, 3.0, 0, 1, 1, 0, "drifted at most 3 windows over an exposure (frame 0), every frame "
                                                 "kept: the period was measured (--max-drift-windows auto)", 0, "measured"},
        {"measured_some_kept", 0.45, 0.55, 1, 1, 0, 0, "drifted at most 0.55 windows over an exposure (frame 0), "
                                                       "every frame kept", 0, "measured"},
        {"measured_at_0.5", 0.45, 0.55, 1, 1, 1, 6, "6 of 26 frames left out (flag drift): 6 drifted over 0.5 windows",
         0.5, "measured"},
        {"nominal_some_out", 0.45, 0.55, 1, 1, 1, 6, "6 of 26 frames left out (flag drift): 6 drifted over 0.5 windows "
                                                     "(the most 0.55, frame 0) (--max-drift-windows auto, the period nominal)",
         REC_DRIFT_AUTO, "nominal"},
    };
    int nc = (int)(sizeof cases / sizeof *cases);
    for (int v = -1; v < nc && d; v++) {
        char dir[1024];
        if (v >= 0)
            free_running_copy(src, cases[v].name, cases[v].drift, cases[v].odd_drift, cases[v].corrupt, cases[v].period,
                              dir, sizeof dir);
        else snprintf(dir, sizeof dir, "%s", src);
        /* the maps: every lit pixel answered while no frame is out, else none */
        gs_capture cap;
        CHECK_OK(gs_capture_read(dir, &cap));
        if (!m) CHECK_OK(rec_matcher_new(d, cap.grid_hz, cap.bands, cap.K, NULL, &m));
        double opt = v >= 0 && cases[v].max ? cases[v].max : REC_DRIFT_AUTO;
        int measured = v >= 0 && cases[v].period && !strcmp(cases[v].period, "measured");
        CHECK(cap.window_period == (v < 0 || !cases[v].period ? GS_PERIOD_UNKNOWN
                                    : measured                ? GS_PERIOD_MEASURED : GS_PERIOD_NOMINAL));
        double max = opt == REC_DRIFT_AUTO ? (measured ? INFINITY : REC_MAX_DRIFT_WINDOWS) : opt;   /* (what auto means) */
        rec_eq7_opts eo;
        rec_eq7_opts_default(&eo);
        eo.max_drift_windows = opt;
        rec_matcher *mv = NULL;
        if (opt != REC_DRIFT_AUTO) CHECK_OK(rec_matcher_new(d, cap.grid_hz, cap.bands, cap.K, &eo, &mv));
        rec_pixel_maps pm;
        CHECK_OK(rec_pixel_maps_compute(&cap, mv ? mv : m, NULL, NULL, &pm));
        rec_matcher_free(mv);
        /* (the maps: no pixel once a frame drifted over the threshold or over
         * REC_MAX_DRIFT_WINDOWS, whose smear they cannot model) */
        int maps_none = v >= 0 && (cases[v].out || !(fmax(cases[v].drift, cases[v].odd_drift) <= REC_MAX_DRIFT_WINDOWS));
        CHECK_MSG(pm.drift_unanswered == maps_none, "%s: drift_unanswered %d", v >= 0 ? cases[v].name : "locked",
                  pm.drift_unanswered);
        CHECK(pm.drift_limit_windows == fmin(max, REC_MAX_DRIFT_WINDOWS));
        if (v < 0) matched_locked = pm.matched;
        else if (!cases[v].corrupt || maps_none)
            CHECK_MSG(pm.matched == (maps_none ? 0 : matched_locked), "%s: %zu pixels matched (locked %zu)",
                      cases[v].name, pm.matched, matched_locked);
        else CHECK_MSG(pm.matched > 0, "%s: no pixel matched", cases[v].name);
        rec_pixel_maps_release(&pm);
        gs_capture_release(&cap);
        if (v < 0) continue;
        char args[1200];
        if (cases[v].max && isinf(cases[v].max)) snprintf(args, sizeof args, "%s --max-drift-windows none", dir);
        else if (cases[v].max == REC_DRIFT_AUTO) snprintf(args, sizeof args, "%s --max-drift-windows auto", dir);
        else if (cases[v].max) snprintf(args, sizeof args, "%s --max-drift-windows %g", dir, cases[v].max);
        else snprintf(args, sizeof args, "%s", dir);
        json_t *root = recfx_recognize_ok(args, 1);
        if (!root) continue;
        json_t *mx = json_object_get(json_object_get(root, "recognition"), "max_drift_windows");
        CHECK_MSG(isinf(max) ? json_is_null(mx) : json_real_value(mx) == max, "%s: max_drift_windows", cases[v].name);
        CHECK(json_is_true(json_object_get(json_object_get(root, "recognition"), "max_drift_windows_auto")) ==
              (opt == REC_DRIFT_AUTO));
        json_t *wp = json_object_get(json_object_get(root, "capture"), "window_period");
        CHECK_MSG(cases[v].period ? json_is_string(wp) && !strcmp(json_string_value(wp), cases[v].period) : json_is_null(wp),
                  "%s: window_period", cases[v].name);
        json_t *wd = json_object_get(json_object_get(root, "capture"), "drift_windows");
        CHECK(json_integer_value(json_object_get(json_object_get(root, "capture"), "frames_left_out")) == cases[v].out);
        CHECK(isnan(cases[v].drift) ? json_is_null(wd) : fabs(json_real_value(wd) - fmax(cases[v].drift, cases[v].odd_drift)) < 1e-9);
        int changed = 0;
        for (int i = 0; i < recfx_scene_a.count; i++) {
            json_t *l = recfx_light_near(root, recfx_lights_a[i].x, recfx_lights_a[i].y);
            json_t *l0 = recfx_light_near(locked, recfx_lights_a[i].x, recfx_lights_a[i].y);
            CHECK(l && l0);
            if (!l || !l0) continue;
            const char *want = json_string_value(json_object_get(l0, "bulb"));
            const char *bulb = json_string_value(json_object_get(l, "bulb"));
            CHECK(want && !strcmp(want, recfx_lights_a[i].bulb));
            CHECK_MSG(recfx_has_flag(l, "drift"), "%s: light %s flags", cases[v].name, want);
            int same = bulb && want && !strcmp(bulb, want) &&
                       json_equal(json_object_get(l, "phase_deg"), json_object_get(l0, "phase_deg"));
            changed += !same;
            if (cases[v].same) CHECK_MSG(same, "%s: light %s answered %s", cases[v].name, want, bulb ? bulb : "null");
            if (!cases[v].answers)
                CHECK_MSG(!bulb && recfx_has_flag(l, "bad_input") && json_number_value(json_object_get(l, "confidence")) == 0.0,
                          "%s: light %s answered %s", cases[v].name, want, bulb ? bulb : "null");
        }
        /* (the overwritten frames, kept, change answers: the case above is not vacuous) */
        if (cases[v].answers && !cases[v].same) CHECK_MSG(changed > 0, "%s: no answer changed", cases[v].name);
        json_decref(root);
        /* the table says why */
        CHECK(fx_run(out, sizeof out, "%s recognize %s", test_bin(), args) == 0);
        CHECK_MSG(strstr(out, cases[v].note), "%s: %s", cases[v].name, out);
        if (!strcmp(cases[v].name, "measured_keeps")) {   /* every frame kept, the maps still empty: why */
            CHECK(fx_run(out, sizeof out, "%s recognize %s --maps %s/maps_measured", test_bin(), dir, test_tmpdir()) == 0);
            CHECK_MSG(strstr(out, "every frame kept: the period was measured") &&
                          strstr(out, "note: the maps answer no pixel: a frame's windows drifted over 0.5 windows"),
                      "%s", out);
        }
        if (v == 1) {   /* the maps say why they are empty; `run` says it too, storing the same answers */
            CHECK(fx_run(out, sizeof out, "%s recognize %s --maps %s/maps_out", test_bin(), dir, test_tmpdir()) == 0);
            CHECK_MSG(strstr(out, "note: the maps answer no pixel: a frame's windows drifted over 0.5 windows"),
                      "%s", out);
            CHECK(fx_run(out, sizeof out, "%s run %s --db %s/free.sqlite", test_bin(), dir, test_tmpdir()) == 0);
            CHECK_MSG(strstr(out, "run: note: free running: 6 of 26 frames left out") &&
                          strstr(out, "lights, 6 with a bulb, 6 with a phase"), "%s", out);
            /* run's threshold: nothing left out at 0.6 (another survey database: a stored
             * capture keeps its answers) */
            CHECK(fx_run(out, sizeof out, "%s run %s --db %s/free06.sqlite --max-drift-windows 0.6", test_bin(), dir,
                         test_tmpdir()) == 0);
            CHECK_MSG(strstr(out, "run: note: free running: the windows drifted at most 0.55 windows") &&
                          !strstr(out, "left out"), "%s", out);
            /* -0 is 0 (not "-0 windows") */
            CHECK(fx_run(out, sizeof out, "%s recognize %s --max-drift-windows -0", test_bin(), dir) == 0);
            CHECK_MSG(strstr(out, "26 drifted over 0 windows") && !strstr(out, "-0"), "%s", out);
        }
    }
    rec_matcher_free(m);
    gs_delight_free(d);
    json_decref(locked);
}

/* The lab scene (eight bright lamps, a few metres away) free running with the firmware's
 * measured period over a wandering grid: at C = 64 its windows move up to 0.09 windows, at
 * C = 256 five frames over half a window. Leaving those out and raising the kept frames' noise
 * by their smear (rec_match_catalog), every lamp gets the truth's bulb and phase, as locked; with
 * Eq. 5's windows taken as exact, the brightest failed the fit (7 and 4 of 8 answered). */
TEST(recognize_free_running_lab_answered_as_locked)
{
    static const int Cs[2] = {64, 256};
    for (int i = 0; i < 2; i++) {
        char scene[1024], dir[1024], db[1024], text[16384];
        snprintf(scene, sizeof scene, "%s/lab_free_%d.json", test_tmpdir(), Cs[i]);
        snprintf(dir, sizeof dir, "%s/lab_free_%d", test_tmpdir(), Cs[i]);
        snprintf(db, sizeof db, "%s/lab_free_%d.sqlite", test_tmpdir(), Cs[i]);
        json_error_t err;
        json_t *sc = json_load_file("capture/scenes/lab.json", 0, &err);
        CHECK_MSG(sc != NULL, "lab.json: %s", err.text);
        if (!sc) return;
        json_t *acam = json_object_get(sc, "acam");
        json_object_set_new(acam, "cycles", json_integer(Cs[i]));
        json_object_set_new(acam, "locked", json_false());
        json_object_set_new(acam, "free_running_period", json_string("measured"));
        json_t *freq = json_object();
        json_object_set_new(freq, "model", json_string("random_walk"));
        json_object_set_new(json_object_get(sc, "grid"), "frequency", freq);
        json_object_set_new(json_object_get(sc, "effects"), "frequency_wander", json_object());
        CHECK(json_dump_file(sc, scene, 0) == 0);
        json_decref(sc);
        CHECK_MSG(fx_run(text, sizeof text, "%s run %s --db %s --capture-dir %s --no-progress && %s evaluate --db %s "
                         "--truth %s/truth.json --format json", test_bin(), scene, db, dir, test_bin(), db, dir) == 0,
                  "%s", text);
        const char *js = strstr(text, "{\n  \"format\": \"gridsurvey-evaluation/1\"");
        json_t *ev = js ? json_loads(js, 0, &err) : NULL;
        CHECK_MSG(ev != NULL, "%s", text);
        if (!ev) continue;
        long right = (long)json_integer_value(json_object_get(json_object_get(ev, "bulb_and_phase"), "count"));
        printf("    C = %d: %ld of 8 lamps with the right bulb and phase; %s\n", Cs[i], right,
               strstr(text, "run: note: free running") ? "noted" : "no note");
        CHECK(right == 8 && strstr(text, "run: note: free running"));
        json_decref(ev);
    }
}

static int run1(const char *args, const char *extra)
{
    char cmd[4096];
    snprintf(cmd, sizeof cmd, "%s recognize %s %s", test_bin(), args, extra ? extra : "");
    return test_run(cmd, out, sizeof out);
}

TEST(recognize_cli_bad_inputs_one_line_errors)
{
    recfx_cached_delight();
    const char *good = recfx_render(&recfx_scene_e);   /* the smallest capture: errors come fast */
    char cmd_buf[8192];
    char missing[1024], bad[1024], path[1100], file[1200];
    snprintf(missing, sizeof missing, "%s/no-such-capture", test_tmpdir());
    CHECK(run1(missing, NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "no-such-capture"), "%s", out);

    snprintf(bad, sizeof bad, "%s/bad", test_tmpdir());
    mkdir(bad, 0700);
    snprintf(path, sizeof path, "%s/capture.json", bad);
    fx_write_text(path, "{\"format\": \"gridsurvey-capture/1\", \"grid_hz\": 50,\n \"K\": 26,\n");
    CHECK(run1(bad, "--format json") == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "capture.json"), "%s", out);

    CHECK(run1(good, "--phases 5") == 2);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "--phases"), "%s", out);
    CHECK(run1(good, "--phases") == 2);
    CHECK_MSG(fx_count_lines(out) == 1, "%s", out);
    CHECK(run1(good, "--format xml") == 2);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "--format 'xml'"), "%s", out);
    CHECK(run1(good, "--ambiguous-below 1.5") == 2);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "--ambiguous-below"), "%s", out);
    CHECK(run1(good, "--threshold -1") == 2);
    CHECK_MSG(fx_count_lines(out) == 1, "%s", out);
    CHECK(run1(good, "--transformer-deg abc") == 2);
    CHECK_MSG(fx_count_lines(out) == 1, "%s", out);
    CHECK(run1(good, "--frobnicate") == 2);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "frobnicate"), "%s", out);
    CHECK(run1("", NULL) == 2);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "capture directory"), "%s", out);
    CHECK(run1(good, good) == 2);
    CHECK_MSG(fx_count_lines(out) == 1, "%s", out);
    /* a transformer shift that repeats 0/120/240 */
    CHECK(run1(good, "--phases 6 --transformer-deg 120") == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "transformer"), "%s", out);
    /* a DELIGHT file that is missing or not a database */
    CHECK(run1(good, "--delight /nonexistent/delight.sqlite") == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "gridsurvey recognize: /nonexistent/delight.sqlite"), "%s", out);
    CHECK(run1(good, "--delight tests/test.h") == 1);
    CHECK_MSG(fx_count_lines(out) == 1, "%s", out);
    /* a DELIGHT without an entry for the capture's grid frequency (only 60 Hz rows) */
    const char *db60 = fx_tmp("only60.sqlite");
    snprintf(cmd_buf, sizeof cmd_buf, "grep -E '^(bulb_id|hps-150w,[^,]*,[^,]*,[^,]*,60),' "
             "%s/delight-export.csv > %s/only60.csv && %s delight import %s/only60.csv --delight %s",
             recfx_cache_root(), test_tmpdir(), test_bin(), test_tmpdir(), db60);
    CHECK_MSG(test_run(cmd_buf, out, sizeof out) == 0, "%s", out);
    snprintf(file, sizeof file, "--delight %s", db60);
    CHECK(run1(good, file) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "no usable monochrome entry") && strstr(out, "50 Hz"),
              "%s", out);
    /* --maps naming a regular file */
    snprintf(file, sizeof file, "--maps %s", path);
    CHECK(run1(good, file) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "capture.json"), "%s", out);
    /* a frame file gone missing after capture.json was written */
    char cmd[4096];
    snprintf(cmd, sizeof cmd, "cp -r %s %s/partial && rm %s/partial/frame_003.png", good,
             test_tmpdir(), test_tmpdir());
    CHECK(test_run(cmd, out, sizeof out) == 0);
    snprintf(path, sizeof path, "%s/partial", test_tmpdir());
    CHECK(run1(path, NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "frame_003.png"), "%s", out);
    /* and the maps directory of a failed run holds no partial pictures */
    char maps_arg[1300];
    snprintf(maps_arg, sizeof maps_arg, "--maps %s/failmaps", test_tmpdir());
    CHECK(run1(path, maps_arg) == 1);
    snprintf(cmd, sizeof cmd, "ls -A %s/failmaps", test_tmpdir());
    CHECK(test_run(cmd, out, sizeof out) == 0);
    CHECK_MSG(out[0] == '\0', "left behind: %s", out);
}

TEST(recognize_cli_help)
{
    CHECK(run1("--help", NULL) == 0);
    CHECK(strstr(out, "usage: gridsurvey recognize CAPDIR") && strstr(out, "--phases 3|6|continuous") &&
          strstr(out, "--maps DIR") && strstr(out, "--format F") && strstr(out, "--ambiguous-below") &&
          strstr(out, "--transformer-deg") && strstr(out, "--delight"));
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "%s --help", test_bin());
    CHECK(test_run(cmd, out, sizeof out) == 0 && strstr(out, "recognize") && strstr(out, "bench"));
    snprintf(cmd, sizeof cmd, "%s bench --help", test_bin());
    CHECK(test_run(cmd, out, sizeof out) == 0 && strstr(out, "bench recognize"));
    snprintf(cmd, sizeof cmd, "%s bench frobnicate", test_bin());
    CHECK(test_run(cmd, out, sizeof out) == 2 && fx_count_lines(out) == 1);
}
