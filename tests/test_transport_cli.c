/* test_transport_cli.c - the light-transport commands end to end: simulate, unmix (a sources
 * file and auto), relight into a capture that recognize reads back, separate; their files read
 * by independent readers (GDAL, Jansson) and their one-line errors. */
#include "tests/fixtures.h"
#include "tests/test.h"
#include "tests/transport_fixture.h"

#include <jansson.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const trfx_lamp lamps3[] = {
    {"inc25", "inc-a60-25w-230v", 0, 11.2, 8.9, 3.8, 6e6},
    {"cfl23", "cfl-23w", 120, 52.9, 7.2, 4.2, 6e6},
    {"ledfil", "led-fil-4w-lin", 240, 32.0, 4.9, 4.5, 5e6},
};

static const char *sources3 =
    "{\"format\": \"gridsurvey-sources/1\",\n"
    " \"sources\": [{\"bulb\": \"inc-a60-25w-230v\", \"phase_deg\": 0},\n"
    "             {\"bulb\": \"cfl-23w\", \"phase_deg\": 120},\n"
    "             {\"bulb\": \"led-fil-4w-lin\", \"phase_deg\": 240}]}\n";

/* The three-lamp scene simulated by the command into CAPDIR (returns it). */
static const char *simulate3(void)
{
    trfx_opts o = {0};
    o.hdr_rounds = 3;
    char *text = trfx_scene(&o, lamps3, 3);
    const char *scene = fx_tmp("three.json");
    fx_write_text(scene, text);
    free(text);
    static char cap[512];
    snprintf(cap, sizeof cap, "%s", fx_tmp("three"));
    char out[4096];
    int rc = fx_run(out, sizeof out, "%s simulate '%s' --out-dir '%s' --no-progress 2>&1", test_bin(), scene, cap);
    CHECK_MSG(rc == 0, "simulate: %s", out);
    return cap;
}

TEST(unmix_relight_cli_float_tiffs_gdal_and_a_capture_recognize_reads)
{
    const char *cap = simulate3();
    const char *src = fx_tmp("sources.json"), *dir = fx_tmp("unmixed"), *rel = fx_tmp("relit");
    fx_write_text(src, sources3);
    char out[16384];
    int rc = fx_run(out, sizeof out, "%s unmix '%s' --sources '%s' --out-dir '%s' --render 2>&1", test_bin(), cap, src, dir);
    CHECK_MSG(rc == 0, "unmix: %s", out);
    CHECK(fx_contains(out, "relative error"));   /* the capture has a truth */
    CHECK(fx_contains(out, "denoising"));
    CHECK(!fx_contains(out, "gridsurvey unmix:"));   /* no progress: stderr is not a terminal */
    /* progress on stderr when asked; -q after it wins */
    CHECK(fx_run(out, sizeof out, "%s unmix '%s' --sources '%s' --out-dir '%s' --progress 2>&1 >/dev/null", test_bin(), cap,
                 src, fx_tmp("progress")) == 0);
    CHECK_MSG(fx_contains(out, "gridsurvey unmix: 100 %"), "%s", out);
    CHECK(fx_run(out, sizeof out, "%s unmix '%s' --sources '%s' --out-dir '%s' --progress -q 2>&1 >/dev/null", test_bin(),
                 cap, src, fx_tmp("quiet")) == 0);
    CHECK_MSG(!fx_contains(out, "gridsurvey unmix:"), "%s", out);
    /* GDAL reads each source as three Float32 bands, and the rendered sequence as K pages */
    CHECK(fx_run(out, sizeof out, "gdalinfo '%s/source_02.tiff' 2>&1", dir) == 0);
    CHECK(fx_count_of(out, "Type=Float32") == 3 && fx_contains(out, "Size is 64, 48"));
    CHECK(fx_run(out, sizeof out, "gdalinfo '%s/render_01.tiff' 2>&1", dir) == 0);
    CHECK(fx_contains(out, "SUBDATASET_26_NAME") && !fx_contains(out, "SUBDATASET_27_NAME"));
    CHECK(fx_exists(fx_path(dir, "source_00.png")) && fx_exists(fx_path(dir, "mean.png")));
    /* sources.json: the input's format with each source's file, chromaticity and K-sample BRFs */
    json_error_t je;
    json_t *j = json_load_file(fx_path(dir, "sources.json"), 0, &je);
    CHECK(j != NULL);
    json_t *arr = json_object_get(j, "sources");
    CHECK(!strcmp(json_string_value(json_object_get(j, "format")), "gridsurvey-sources/1"));
    CHECK(json_array_size(arr) == 3);
    json_t *s1 = json_array_get(arr, 1);
    CHECK(!strcmp(json_string_value(json_object_get(s1, "file")), "source_01.tiff"));
    CHECK(json_array_size(json_object_get(s1, "chromaticity")) == 3);
    CHECK(json_array_size(json_array_get(json_object_get(s1, "brf"), 2)) == 26);
    json_decref(j);
    /* relight: one source off, another bulb and phase for the first (-120 deg: 240); recognize
     * reads it back */
    rc = fx_run(out, sizeof out, "%s relight '%s' --set 1=gain:0 --set 0=gain:2,bulb:hps-70w,phase:-120 "
                "--out-dir '%s' 2>&1", test_bin(), dir, rel);
    CHECK_MSG(rc == 0, "relight: %s", out);
    CHECK(fx_contains(out, "00 hps-70w@240 x2") && fx_contains(out, "01 cfl-23w@120 x0"));
    CHECK(fx_exists(fx_path(rel, "preview.png")));
    rc = fx_run(out, sizeof out, "%s recognize '%s' 2>&1", test_bin(), rel);
    CHECK_MSG(rc == 0 && fx_contains(out, "K = 26"), "recognize: %s", out);
    gs_capture c;
    CHECK_OK(gs_capture_read(rel, &c));
    CHECK(c.K == 26 && c.bands == 3 && c.halvings != NULL);
    gs_capture_release(&c);
}

TEST(unmix_cli_sources_auto_finds_the_lamps_in_view)
{
    const char *cap = simulate3();
    char out[16384];
    int rc = fx_run(out, sizeof out, "%s unmix '%s' --sources auto --out-dir '%s' 2>&1", test_bin(), cap, fx_tmp("auto"));
    CHECK_MSG(rc == 0, "unmix auto: %s", out);
    printf("    %.*s\n", (int)(strchr(out, '\n') ? strchr(out, '\n') - out : 200), out);
    /* every lamp's technology at its phase (a similar model may stand for it), nothing else */
    CHECK(fx_contains(out, "inc-a60") && fx_contains(out, "@0"));
    CHECK(fx_contains(out, "cfl-") && fx_contains(out, "@120"));
    CHECK(fx_contains(out, "led-fil-4w-lin@240"));
    CHECK(fx_contains(out, " 3 sources"));
}

TEST(transport_cli_bad_input_one_line_errors)
{
    const char *cap = simulate3();
    char out[8192];
    const char *f = fx_tmp("bad.json");
    /* a typo'd key: file, line and field */
    fx_write_text(f, "{\"format\": \"gridsurvey-sources/1\",\n \"sources\": [\n  {\"bulb\": \"cfl-23w\", \"phase\": 120}]}\n");
    int rc = fx_run(out, sizeof out, "%s unmix '%s' --sources '%s' --out-dir '%s' 2>&1", test_bin(), cap, f, fx_tmp("o"));
    CHECK(rc == 1 && fx_contains(out, "bad.json:3: field sources[0]") && fx_count_lines(out) == 1);
    fx_write_text(f, "{\"format\": \"gridsurvey-sources/2\", \"sources\": []}");
    rc = fx_run(out, sizeof out, "%s unmix '%s' --sources '%s' --out-dir '%s' 2>&1", test_bin(), cap, f, fx_tmp("o"));
    CHECK(rc == 1 && fx_contains(out, "field format") && fx_contains(out, "gridsurvey-sources/1"));
    fx_write_text(f, "{\"format\": \"gridsurvey-sources/1\", \"sources\": [{\"bulb\": \"nope\", \"phase_deg\": 0}]}");
    rc = fx_run(out, sizeof out, "%s unmix '%s' --sources '%s' --out-dir '%s' 2>&1", test_bin(), cap, f, fx_tmp("o"));
    CHECK(rc == 1 && fx_contains(out, "bulb 'nope'") && fx_contains(out, "DELIGHT"));
    /* a fourth source the data cannot tell from the first (two incandescent models at one
     * phase, Fig. 10): ill-posed, exit 1, nothing written */
    fx_write_text(f, "{\"format\": \"gridsurvey-sources/1\", \"sources\": [{\"bulb\": \"inc-a60-25w-230v\", "
                     "\"phase_deg\": 0}, {\"bulb\": \"inc-a60-40w-230v\", \"phase_deg\": 0}, {\"bulb\": \"cfl-23w\", "
                     "\"phase_deg\": 120}, {\"bulb\": \"led-fil-4w-lin\", \"phase_deg\": 240}]}");
    rc = fx_run(out, sizeof out, "%s unmix '%s' --sources '%s' --out-dir '%s' 2>&1", test_bin(), cap, f, fx_tmp("ill"));
    CHECK_MSG(rc == 1 && fx_contains(out, "ill-posed") && !fx_exists(fx_path(fx_tmp("ill"), "sources.json")), "%s", out);
    /* one line, with every source's predicted error (they were lines of their own before it) */
    CHECK_MSG(fx_count_lines(out) == 1 && !strncmp(out, "gridsurvey unmix: ill-posed", 27) &&
              fx_contains(out, "(predicted error of each source: 00 inc-a60-25w-230v at 0 deg ") &&
              fx_contains(out, ", 01 inc-a60-40w-230v at 0 deg "), "%s", out);
    /* the same capture free running, every frame's windows drifted 0.3 windows and kept: the
     * error says so, and still ends with the last source's error (the line is not cut) */
    char path[1100];
    const char *fr = fx_tmp("free");
    CHECK(fx_run(out, sizeof out, "rm -rf '%s' && cp -r '%s' '%s'", fr, cap, fr) == 0);
    snprintf(path, sizeof path, "%s/capture.json", fr);
    json_t *cj = json_load_file(path, 0, NULL);
    CHECK(cj != NULL);
    if (cj) {
        json_object_set_new(cj, "locked", json_false());
        size_t i;
        json_t *fj;
        json_array_foreach(json_object_get(cj, "frames"), i, fj) json_object_set_new(fj, "window_drift_windows", json_real(0.3));
        CHECK(json_dump_file(cj, path, JSON_INDENT(1)) == 0);
        json_decref(cj);
    }
    rc = fx_run(out, sizeof out, "%s unmix '%s' --sources '%s' --out-dir '%s' 2>&1", test_bin(), fr, f, fx_tmp("ill2"));
    CHECK_MSG(rc == 1 && fx_count_lines(out) == 1 &&
              fx_contains(out, "; free running, the frames' windows drifted up to 0.3 windows, their noise not raised") &&
              fx_contains(out, ", 03 led-fil-4w-lin at 240 deg "), "%s", out);
    /* simulate --drop-light: an id the scene lacks is a usage error; a real one renders without it */
    CHECK(fx_run(out, sizeof out, "%s simulate capture/scenes/window.json --out-dir '%s' --drop-light nope 2>&1",
                 test_bin(), fx_tmp("w")) == 2 && fx_contains(out, "no light with this id"));
    CHECK(fx_run(out, sizeof out, "%s simulate capture/scenes/window.json --out-dir '%s' --drop-light tube --no-progress 2>&1",
                 test_bin(), fx_tmp("w")) == 0 && fx_contains(out, "0 lights in the image"));
    /* usage errors and help */
    CHECK(fx_run(out, sizeof out, "%s unmix '%s' --out-dir x 2>&1", test_bin(), cap) == 2);
    CHECK(fx_run(out, sizeof out, "%s unmix '%s' --sources auto --out-dir x --refine 99 2>&1", test_bin(), cap) == 2);
    CHECK(fx_run(out, sizeof out, "%s relight '%s' --set 7=gain:1 --out-dir x 2>&1", test_bin(), fx_tmp("nowhere")) == 1);
    CHECK(fx_run(out, sizeof out, "%s separate 2>&1", test_bin()) == 2);
    const char *cmds[3] = {"unmix", "relight", "separate"};
    for (int i = 0; i < 3; i++) {
        CHECK(fx_run(out, sizeof out, "%s %s --help", test_bin(), cmds[i]) == 0);
        CHECK(fx_contains(out, "usage: gridsurvey"));
    }
    /* a bad --set on real sources */
    const char *src = fx_tmp("s.json"), *dir = fx_tmp("u");
    fx_write_text(src, sources3);
    CHECK(fx_run(out, sizeof out, "%s unmix '%s' --sources '%s' --out-dir '%s' 2>&1", test_bin(), cap, src, dir) == 0);
    rc = fx_run(out, sizeof out, "%s relight '%s' --set 1=gain:-2 --out-dir '%s' 2>&1", test_bin(), dir, fx_tmp("r"));
    CHECK(rc == 2 && fx_contains(out, "--set '1=gain:-2'"));
    rc = fx_run(out, sizeof out, "%s relight '%s' --set 5=gain:1 --out-dir '%s' 2>&1", test_bin(), dir, fx_tmp("r"));
    CHECK(rc == 2 && fx_contains(out, "N from 0 to 2"));
    /* no change, or a key given twice (in one --set or two): which value is meant is unknown */
    rc = fx_run(out, sizeof out, "%s relight '%s' --set 0= --out-dir '%s' 2>&1", test_bin(), dir, fx_tmp("r"));
    CHECK_MSG(rc == 2 && fx_contains(out, "--set '0=': source 0: expected") && fx_count_lines(out) == 1, "%s", out);
    rc = fx_run(out, sizeof out, "%s relight '%s' --set 0=gain:2, --out-dir '%s' 2>&1", test_bin(), dir, fx_tmp("r"));
    CHECK_MSG(rc == 2 && fx_contains(out, "--set '0=gain:2,': source 0: expected"), "%s", out);
    rc = fx_run(out, sizeof out, "%s relight '%s' --set 0=gain:2,gain:3 --out-dir '%s' 2>&1", test_bin(), dir, fx_tmp("r"));
    CHECK_MSG(rc == 2 && fx_contains(out, "--set '0=gain:2,gain:3': source 0: gain given twice") &&
              fx_count_lines(out) == 1, "%s", out);
    rc = fx_run(out, sizeof out, "%s relight '%s' --set 1=phase:0 --set 1=bulb:cfl-23w,phase:120 --out-dir '%s' 2>&1",
                test_bin(), dir, fx_tmp("r"));
    CHECK_MSG(rc == 2 && fx_contains(out, "--set '1=bulb:cfl-23w,phase:120': source 1: phase given twice"), "%s", out);
    /* the library's error as the command's one line, without a status word or a second "relight:" */
    rc = fx_run(out, sizeof out, "%s relight '%s' --set 0=bulb:none --out-dir '%s' 2>&1", test_bin(), dir, fx_tmp("r"));
    CHECK_MSG(rc == 1 && !strncmp(out, "gridsurvey relight: source 00: bulb 'none': expected a DELIGHT bulb id", 70) &&
              fx_count_lines(out) == 1, "%s", out);
}

TEST(separate_cli_writes_float_tiffs_and_compares_with_the_truth)
{
    char out[8192];
    const char *cap = fx_tmp("window"), *dir = fx_tmp("sep");
    int rc = fx_run(out, sizeof out, "%s simulate capture/scenes/window.json --out-dir '%s' --no-progress 2>&1", test_bin(), cap);
    CHECK_MSG(rc == 0, "simulate: %s", out);
    rc = fx_run(out, sizeof out, "%s separate '%s' --out-dir '%s' 2>&1", test_bin(), cap, dir);
    CHECK_MSG(rc == 0, "separate: %s", out);
    printf("    %s", strstr(out, "truth:") ? strstr(out, "truth:") : out);
    double nt = 0, nr = 0;
    const char *t = strstr(out, "transmitted ");
    CHECK(t && sscanf(t, "transmitted %lf, reflection %lf", &nt, &nr) == 2);
    CHECK(nt >= 0.97 && nr >= 0.97);
    CHECK(fx_run(out, sizeof out, "gdalinfo '%s/reflection.tiff' 2>&1", dir) == 0);
    CHECK(fx_count_of(out, "Type=Float32") == 3);
    CHECK(fx_exists(fx_path(dir, "transmitted.png")) && fx_exists(fx_path(dir, "reflection.png")));
}
