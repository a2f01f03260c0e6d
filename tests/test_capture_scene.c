/* test_capture_scene.c - scene files (capture/scene.c, docs/scene.md): every error names the
 * file, the line and the field; GeoJSON lights; the built-in scenes (lab, metro). */
#include "tests/fixtures.h"
#include "tests/test.h"
#include "capture/sim.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char *head =
    "{\"format\": \"gridsurvey-scene/1\",\n"               /* 1 */
    " \"grid\": {\"nominal_hz\": 50},\n"                   /* 2 */
    " \"camera\": {\"width_px\": 64, \"height_px\": 48,\n" /* 3 */
    "   \"sensor\": {\"bands\": 3}},\n"                    /* 4 */
    " \"acam\": {\"K\": 10, \"cycles\": 40},\n";           /* 5 */

/* Parses head + rest; expects failure with a detail holding want. */
static void expect_error(const char *rest, const char *want, gs_status st_want)
{
    char text[4096];
    snprintf(text, sizeof text, "%s%s", head, rest);
    cap_scene sc;
    gs_status st = cap_scene_parse(text, "bad.json", test_tmpdir(), &sc);
    CHECK_MSG(st == st_want && strstr(gs_detail(), want), "wanted %s '%s', got %s '%s'",
              gs_strerror(st_want), want, gs_strerror(st), gs_detail());
    cap_scene_release(&sc);
}

TEST(scene_parse_errors_name_file_line_field)
{
    /* syntax: line and column */
    expect_error(" \"lights\": [\n  {\"bulb\": \"hps-150w\",, \"x_px\": 1}]}\n", "bad.json:7:", GS_EFORMAT);
    expect_error(" \"lights\": [\n  {\"bulb\": \"hps-150w\",, \"x_px\": 1}]}\n", "JSON syntax", GS_EFORMAT);
    /* a typo in a key */
    expect_error(" \"lihgts\": []}\n", "bad.json:6: field lihgts: unknown field", GS_EFORMAT);
    /* required field missing: the line of its parent */
    expect_error(" \"lights\": [\n  {\"x_px\": 1, \"y_px\": 2,\n   \"flux_e_per_cycle\": 5}]}\n",
                 "bad.json:7: field lights[0].bulb: expected a string (the field is missing)", GS_EFORMAT);
    /* a value out of range: the line of the value */
    expect_error(" \"lights\": [\n  {\"bulb\": \"hps-150w\", \"x_px\": 1, \"y_px\": 2, \"flux_e_per_cycle\": 5},\n"
                 "  {\"bulb\": \"hps-150w\", \"x_px\": 1,\n   \"y_px\": 2, \"flux_e_per_cycle\": -5}]}\n",
                 "bad.json:9: field lights[1].flux_e_per_cycle: expected a number from 0 to 1e+15 (got -5)", GS_EFORMAT);
    expect_error(" \"lights\": [{\"bulb\": \"hps-150w\", \"x_px\": 1, \"y_px\": 2, \"lat_deg\": 3, \"flux_e_per_cycle\": 5}]}\n",
                 "field lights[0].x_px: expected either x_px and y_px", GS_EFORMAT);
    expect_error(" \"lights\": [{\"bulb\": \"hps-150w\", \"x_px\": 1, \"y_px\": 2, \"lumens\": 5}]}\n",
                 "field lights[0].lumens: a light given in lumens needs its distance", GS_EFORMAT);
    expect_error(" \"lights\": [{\"bulb\": \"hps-150w\", \"lat_deg\": 32, \"lon_deg\": 35, \"height_m\": 10, \"lumens\": 5}]}\n",
                 "field lights[0].lat_deg: a geographic light needs camera.station", GS_EFORMAT);
    /* a light id given twice: --drop-light and truth.json name a light by its id */
    expect_error(" \"lights\": [\n  {\"id\": \"a\", \"bulb\": \"hps-150w\", \"x_px\": 1, \"y_px\": 2, \"flux_e_per_cycle\": 5},\n"
                 "  {\"id\": \"b\", \"bulb\": \"hps-150w\", \"x_px\": 3, \"y_px\": 2, \"flux_e_per_cycle\": 5},\n"
                 "  {\"id\": \"a\", \"bulb\": \"hps-150w\", \"x_px\": 5, \"y_px\": 2, \"flux_e_per_cycle\": 5}]}\n",
                 "bad.json:9: field lights[2].id: \"a\" is already the id of lights[0]: expected", GS_EFORMAT);
    /* effects */
    expect_error(" \"lights\": [],\n \"effects\": {\"shot_nois\": {}}}\n",
                 "bad.json:7: field effects.shot_nois: unknown effect; expected one of: frequency_wander", GS_EFORMAT);
    /* an effect without parameters names the keys it still takes */
    expect_error(" \"lights\": [],\n \"effects\": {\"shot_noise\": {\"foo\": 1}}}\n",
                 "bad.json:7: field effects.shot_noise.foo: unknown field; expected one of: comment, description, "
                 "or an extension named x_...", GS_EFORMAT);
    expect_error(" \"lights\": [],\n \"effects\": {\n  \"psf\": {\"sigma_px\": -1}}}\n",
                 "bad.json:8: field effects.psf.sigma_px: expected a number from 0.05 to 50 (got -1)", GS_EFORMAT);
    expect_error(" \"lights\": [],\n \"effects\": {\"free_running_drift\": {}}}\n",
                 "field effects.free_running_drift: expected acam.locked false", GS_EFORMAT);
    expect_error(" \"lights\": [],\n \"effects\": {\"blinking_sign\": {\"signs\": [{\"x_px\": 1, \"y_px\": 1, \"flux_e_per_cycle\": 4}]}}}\n",
                 "field effects.blinking_sign.signs[0].period_s: expected a number", GS_EFORMAT);
    /* whole-file checks */
    {
        cap_scene sc;
        CHECK(cap_scene_parse("{\"grid\": {}}", "nofmt.json", ".", &sc) == GS_EFORMAT);
        CHECK_MSG(strstr(gs_detail(), "nofmt.json:1: field format: expected a string (the field is missing)"), "%s", gs_detail());
        cap_scene_release(&sc);
        const char *t = "{\"format\": \"gridsurvey-scene/1\",\n \"grid\": {\"nominal_hz\": 50,\n  \"frequency\": {\"model\": \"random_walk\"}},\n"
                        " \"camera\": {\"width_px\": 8, \"height_px\": 8}, \"acam\": {\"K\": 4, \"cycles\": 8}, \"lights\": []}";
        CHECK(cap_scene_parse(t, "wander.json", ".", &sc) == GS_EFORMAT);
        CHECK_MSG(strstr(gs_detail(), "wander.json:3: field grid.frequency: a grid that deviates"), "%s", gs_detail());
        cap_scene_release(&sc);
        /* a free-running period for a locked ACam (it re-anchors at every crossing) was ignored */
        t = "{\"format\": \"gridsurvey-scene/1\",\n \"grid\": {\"nominal_hz\": 50},\n"
            " \"camera\": {\"width_px\": 8, \"height_px\": 8},\n \"acam\": {\"K\": 4, \"cycles\": 8,\n"
            "  \"free_running_period\": \"measured\"}, \"lights\": []}";
        CHECK(cap_scene_parse(t, "frp.json", ".", &sc) == GS_EFORMAT);
        CHECK_MSG(strstr(gs_detail(), "frp.json:5: field acam.free_running_period: ") &&
                  strstr(gs_detail(), "acam.locked false"), "%s", gs_detail());
        cap_scene_release(&sc);
        CHECK(cap_scene_read("/nonexistent/scene.json", &sc) == GS_ENOTFOUND);
        CHECK_MSG(strstr(gs_detail(), "/nonexistent/scene.json"), "%s", gs_detail());
        cap_scene_release(&sc);
    }
    /* an unknown bulb is found when the simulator looks it up: file, line, light */
    {
        char text[2048];
        snprintf(text, sizeof text, "%s \"lights\": [\n  {\"id\": \"x1\", \"bulb\": \"no-such-bulb\", \"x_px\": 1, \"y_px\": 2, \"flux_e_per_cycle\": 5}]}\n", head);
        const char *path = fx_tmp("unknown.json");
        FILE *f = fopen(path, "w");
        fputs(text, f);
        fclose(f);
        cap_scene sc;
        CHECK_OK(cap_scene_read(path, &sc));
        cap_sim *s = NULL;
        CHECK(cap_sim_new(&sc, NULL, &s) == GS_ENOTFOUND);
        CHECK_MSG(strstr(gs_detail(), "unknown.json:7: field lights (light x1): bulb 'no-such-bulb'"), "%s", gs_detail());
        cap_scene_release(&sc);
    }
}

TEST(scene_geojson_lights_projected_with_gis)
{
    char gj[1024], scene[4096];
    snprintf(gj, sizeof gj, "%s/lights.geojson", test_tmpdir());
    FILE *f = fopen(gj, "w");
    fputs("{\"type\": \"FeatureCollection\", \"features\": [\n"
          " {\"type\": \"Feature\", \"geometry\": {\"type\": \"Point\", \"coordinates\": [35.0300, 32.8200, 25]},\n"
          "  \"properties\": {\"id\": \"a\", \"bulb\": \"hps-150w\", \"phase_deg\": 120, \"lumens\": 15000}},\n"
          " {\"type\": \"Feature\", \"geometry\": {\"type\": \"Point\", \"coordinates\": [35.0250, 32.8150]},\n"
          "  \"properties\": {\"id\": \"b\", \"lumens\": 6000}}\n"
          "]}\n", f);
    fclose(f);
    const char *body =
        "{\"format\": \"gridsurvey-scene/1\",\n"
        " \"grid\": {\"nominal_hz\": 50},\n"
        " \"camera\": {\"width_px\": 800, \"height_px\": 600,\n"
        "   \"station\": {\"lat_deg\": 32.7940, \"lon_deg\": 34.9900, \"height_m\": 470},\n"
        "   \"pose\": {\"heading_deg\": 52, \"pitch_deg\": -5}, \"intrinsics\": {\"focal_px\": 2000}},\n"
        " \"acam\": {\"K\": 10, \"cycles\": 40},\n"
        " \"lights\": [{\"type\": \"geojson\", \"file\": \"lights.geojson\",\n"
        "              \"defaults\": {\"bulb\": \"mh-250w\", \"height_m\": 30}}]}\n";
    snprintf(scene, sizeof scene, "%s", body);
    cap_scene sc;
    CHECK_OK(cap_scene_parse(scene, "geo.json", test_tmpdir(), &sc));
    CHECK(sc.n_lights == 2);
    if (sc.n_lights == 2) {
        CHECK(!strcmp(sc.lights[0].bulb, "hps-150w") && !strcmp(sc.lights[1].bulb, "mh-250w"));
        CHECK(sc.lights[0].height_m == 25 && sc.lights[1].height_m == 30);
        for (int i = 0; i < 2; i++) {
            double x, y;
            int front;
            CHECK_OK(gis_project(&sc.cam, sc.lights[i].lat_deg, sc.lights[i].lon_deg, sc.lights[i].height_m, &x, &y, &front));
            CHECK(x == sc.lights[i].x_px && y == sc.lights[i].y_px && sc.lights[i].in_image);
            CHECK(sc.lights[i].distance_m > 3000 && sc.lights[i].distance_m < 6000);
            CHECK_NEAR(sc.lights[i].flux_e_per_cycle,
                       cap_scene_flux_from_lumens(&sc, sc.lights[i].lumens, sc.lights[i].distance_m), 1e-9);
        }
    }
    cap_scene_release(&sc);
    /* errors inside the GeoJSON name the GeoJSON file */
    f = fopen(gj, "w");
    fputs("{\"type\": \"FeatureCollection\", \"features\": [\n"
          " {\"type\": \"Feature\", \"geometry\": {\"type\": \"Point\", \"coordinates\": [35.03, 32.82, 25]},\n"
          "  \"properties\": {\"id\": \"a\", \"lumens\": 15000}}]}\n", f);
    fclose(f);
    snprintf(scene, sizeof scene, "%s", body);
    char *p = strstr(scene, ",\n              \"defaults\"");
    if (p) strcpy(p, "}]}\n");
    CHECK(cap_scene_parse(scene, "geo.json", test_tmpdir(), &sc) == GS_EFORMAT);
    CHECK_MSG(strstr(gs_detail(), "lights.geojson:3: field features[0].properties.bulb"), "%s", gs_detail());
    cap_scene_release(&sc);
    /* ids given twice: by an inline light and a feature, by two features */
    const char *feature = " {\"type\": \"Feature\", \"geometry\": {\"type\": \"Point\", \"coordinates\": [35.03, 32.82, 25]},\n"
                          "  \"properties\": {\"id\": \"%s\", \"lumens\": 15000}}";
    static const struct {
        const char *id2, *want;
    } dups[] = {
        {"x", "geo.json:9: field lights[1].id: \"x\" is already the id of light 1 of lights[0]: expected"},
        {"a", "geo.json:7: field lights[0]: light 1's id \"a\" is already the id of light 0 of lights[0]: expected"},
    };
    for (int i = 0; i < 2; i++) {
        f = fopen(gj, "w");
        fputs("{\"type\": \"FeatureCollection\", \"features\": [\n", f);
        fprintf(f, feature, "a");
        fputs(",\n", f);
        fprintf(f, feature, dups[i].id2);
        fputs("]}\n", f);
        fclose(f);
        snprintf(scene, sizeof scene, "%s", body);
        p = strstr(scene, "}}]}\n");
        if (p) strcpy(p, "}},\n {\"id\": \"x\", \"bulb\": \"hps-150w\", \"x_px\": 1, \"y_px\": 2, \"flux_e_per_cycle\": 5}]}\n");
        CHECK(cap_scene_parse(scene, "geo.json", test_tmpdir(), &sc) == GS_EFORMAT);
        CHECK_MSG(strstr(gs_detail(), dups[i].want), "%s", gs_detail());
        cap_scene_release(&sc);
    }
    /* an id too long is refused, not cut (two cut alike were refused as one id given twice) */
    char longid[64];
    memset(longid, 'L', 59);
    longid[59] = '\0';
    f = fopen(gj, "w");
    fputs("{\"type\": \"FeatureCollection\", \"features\": [\n", f);
    fprintf(f, feature, longid);
    fputs("]}\n", f);
    fclose(f);
    snprintf(scene, sizeof scene, "%s", body);
    CHECK(cap_scene_parse(scene, "geo.json", test_tmpdir(), &sc) == GS_EFORMAT);
    CHECK_MSG(strstr(gs_detail(), "field features[0].properties.id: expected an id shorter than 48 bytes"),
              "%s", gs_detail());
    cap_scene_release(&sc);
}

TEST(scene_builtin_lab_and_metro)
{
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, GS_BRF_N_DEFAULT));
    cap_scene sc;
    CHECK_OK(cap_scene_read("capture/scenes/lab.json", &sc));
    CHECK(sc.n_lights >= 6);
    CHECK(sc.acam.hdr);
    cap_scene_release(&sc);

    CHECK_OK(cap_scene_read("capture/scenes/metro.json", &sc));
    size_t in_image = 0;
    int tech[GS_TECH_COUNT] = {0}, n_tech = 0;
    double dmin = 1e9, dmax = 0;
    for (size_t i = 0; i < sc.n_lights; i++) {
        const cap_light *l = &sc.lights[i];
        in_image += l->in_image != 0;
        if (l->distance_m < dmin) dmin = l->distance_m;
        if (l->distance_m > dmax) dmax = l->distance_m;
        const gs_bulb *b = gs_delight_find(d, l->bulb, 50, 3);
        CHECK(b != NULL);
        if (b && !tech[b->type]++) n_tech++;
    }
    printf("    metro: %zu lights in the image, %d technologies, %.0f to %.0f m from the station\n",
           in_image, n_tech, dmin, dmax);
    CHECK(in_image >= 5000);
    CHECK(n_tech >= 6);
    CHECK(dmin >= 2000 && dmax <= 8000);
    CHECK(sc.acam.K >= 13 && sc.cam.width_px <= 2048);
    /* only what a city at night needs */
    CHECK(!(sc.fx.enabled & (1u << CAP_FX_HEADLIGHTS)) && !(sc.fx.enabled & (1u << CAP_FX_DMD_JITTER)));
    cap_sim *s = NULL;
    CHECK_OK(cap_sim_new(&sc, d, &s));
    cap_sim_free(s);
    cap_scene_release(&sc);
    gs_delight_free(d);
}

/* The scene's utc is written to capture.json, so it follows capture.json's rule (docs/formats.md):
 * "2017-13-45T99:00:00Z" passed the scene's looser check, the whole capture was rendered, and
 * writing capture.json failed, naming the output file, with the frames left on disk. */
TEST(scene_utc_checked_by_the_capture_format_rule)
{
    /* days a month does not have (a GeoPackage's time moved them to the next month: review) */
    static const char *const bad[] = {"2017-13-45T99:00:00Z", "2017-07-21T21:30:00", "2017-07-21T21:30:00Q",
                                      "2017-07-21T25:30:00+02:00", "2017-07-21T21:30:00.Z", "2024-02-31T12:00:00Z",
                                      "2023-02-29T12:00:00Z", "1900-02-29T12:00:00Z", "2017-04-31T00:00:00Z"};
    static const char *const good[] = {"2017-07-21T21:30:00Z", "2017-07-21T21:30:00.25+02:00", "2024-02-29T12:00:00Z",
                                       "2000-02-29T12:00:00Z", "2017-12-31T23:59:60Z"};
    char rest[256];
    for (size_t i = 0; i < sizeof bad / sizeof *bad; i++) {
        snprintf(rest, sizeof rest, " \"utc\": \"%s\",\n \"lights\": []}\n", bad[i]);
        expect_error(rest, "bad.json:6: field utc: ", GS_EFORMAT);
    }
    for (size_t i = 0; i < sizeof good / sizeof *good; i++) {
        char text[4096];
        snprintf(text, sizeof text, "%s \"utc\": \"%s\",\n \"lights\": []}\n", head, good[i]);
        cap_scene sc;
        CHECK_MSG(cap_scene_parse(text, "good.json", test_tmpdir(), &sc) == GS_OK, "%s: %s", good[i], gs_detail());
        cap_scene_release(&sc);
    }
    /* the command refuses it in one line naming the scene, before anything is rendered */
    char text[4096], out[4096];
    snprintf(text, sizeof text, "%s \"utc\": \"%s\",\n \"lights\": []}\n", head, bad[0]);
    const char *scene = fx_tmp("badutc.json"), *dir = fx_tmp("badutc-capture");
    FILE *f = fopen(scene, "w");
    fputs(text, f);
    fclose(f);
    CHECK(fx_run_bin(out, sizeof out, "%s simulate %s --out-dir %s -q", scene, dir, NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "badutc.json:6: field utc:"), "%s", out);
    CHECK(!fx_exists(dir));
}

/* A street grid whose min_range_m is not below its max_range_m keeps no light: it was read
 * without a word (a scene of no lights from that block); now refused naming both fields. */
TEST(scene_street_grid_ranges_must_leave_a_band)
{
    const char *geo =
        "{\"format\": \"gridsurvey-scene/1\",\n"
        " \"grid\": {\"nominal_hz\": 50},\n"
        " \"camera\": {\"width_px\": 64, \"height_px\": 48, \"station\": {\"lat_deg\": 32.79, \"lon_deg\": 34.99, \"height_m\": 470},\n"
        "   \"pose\": {\"heading_deg\": 52, \"pitch_deg\": -7}, \"intrinsics\": {\"focal_px\": 100}, \"sensor\": {\"bands\": 3}},\n"
        " \"acam\": {\"K\": 10, \"cycles\": 40},\n"
        " \"lights\": [{\"type\": \"street_grid\", \"center\": {\"lat_deg\": 32.823, \"lon_deg\": 35.04},\n"
        "   \"size_m\": [400, 400], \"street_spacing_m\": 100, \"light_spacing_m\": 40,\n"
        "   \"min_range_m\": %s, \"max_range_m\": 8000,\n"
        "   \"technologies\": [{\"bulb\": \"hps-150w\", \"weight\": 1, \"lumens\": 15000}]}]}\n";
    char text[4096];
    cap_scene sc;
    snprintf(text, sizeof text, geo, "9000");
    CHECK(cap_scene_parse(text, "grid.json", test_tmpdir(), &sc) == GS_EFORMAT);
    CHECK_MSG(strstr(gs_detail(), "grid.json:8: field lights[0].min_range_m: 9000: expected below "
                     "max_range_m = 8000"), "%s", gs_detail());
    cap_scene_release(&sc);
    snprintf(text, sizeof text, geo, "8000");
    CHECK(cap_scene_parse(text, "grid.json", test_tmpdir(), &sc) == GS_EFORMAT);
    cap_scene_release(&sc);
    snprintf(text, sizeof text, geo, "2000");
    CHECK_MSG(cap_scene_parse(text, "grid.json", test_tmpdir(), &sc) == GS_OK, "%s", gs_detail());
    CHECK(sc.n_lights > 0);
    cap_scene_release(&sc);
}
