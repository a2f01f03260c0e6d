/* test_capture_loop.c - the acquisition loop (capture/loop.c): frames written as acquired, an
 * interrupted capture (stopped after N frames, killed, or with a damaged frame) resumes to the
 * same files as an uninterrupted run; another configuration is refused; replay round trip. */
#include "tests/test.h"
#include "tests/fixtures.h"
#include "capture/capture.h"
#include "recognize/recognize.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define SMALL_K 8

static const char *small_scene =
    "{\"format\": \"gridsurvey-scene/1\", \"name\": \"small\", \"seed\": %d,\n"
    " \"grid\": {\"nominal_hz\": 50, \"frequency\": {\"model\": \"random_walk\"}},\n"
    " \"camera\": {\"width_px\": 96, \"height_px\": 64,\n"
    "   \"sensor\": {\"bands\": 3, \"bit_depth\": 12, \"full_well_e\": 20000, \"read_noise_e\": 3, \"gain_e_per_dn\": 5, \"black_level_dn\": 64}},\n"
    " \"acam\": {\"K\": 8, \"cycles\": 64, \"masks\": 16, \"hdr\": true},\n"
    " \"lights\": [\n"
    "  {\"bulb\": \"hps-150w\", \"x_px\": 20.2, \"y_px\": 20.7, \"distance_m\": 3000, \"flux_e_per_cycle\": 90000},\n"
    "  {\"bulb\": \"mh-250w\", \"phase_deg\": 120, \"x_px\": 70.5, \"y_px\": 40.1, \"distance_m\": 5000, \"flux_e_per_cycle\": 20000},\n"
    "  {\"bulb\": \"led-street-60w-lin3\", \"phase_deg\": 240, \"x_px\": 50, \"y_px\": 12, \"distance_m\": 4000, \"flux_e_per_cycle\": 5000}],\n"
    " \"effects\": {\"frequency_wander\": {}, \"scintillation\": {\"intensity_variance\": 0.2}, \"psf\": {\"sigma_px\": 1.0},\n"
    "   \"ambient\": {\"e_per_px_cycle\": 2}, \"shot_noise\": {}, \"saturation\": {}, \"read_noise\": {}, \"adc\": {}}}\n";

static void write_small(const char *path, int seed)
{
    FILE *f = fopen(path, "w");
    fprintf(f, small_scene, seed);
    fclose(f);
}

/* The small scene with its text cut replaced by insert. */
static void write_small_edited(const char *path, int seed, const char *cut, const char *insert)
{
    char text[4096];
    snprintf(text, sizeof text, small_scene, seed);
    char *at = strstr(text, cut);
    CHECK_MSG(at != NULL, "the small scene has no %s", cut);
    FILE *f = fopen(path, "w");
    if (at) fprintf(f, "%.*s%s%s", (int)(at - text), text, insert, at + strlen(cut));
    fclose(f);
}

/* The small scene free running with the measured period: its capture.json has every frame's
 * window_half_period_s and window_drift_windows, which acquisition.json carries over a resume
 * and replay copies. */
static void write_small_free(const char *path, int seed)
{
    write_small_edited(path, seed, "\"hdr\": true}",
                       "\"hdr\": true, \"locked\": false, \"free_running_period\": \"measured\"}");
}

/* Every frame of dir/capture.json has a window_half_period_s and a window_drift_windows, and
 * its window_period is write_small_free's, measured. */
static int has_window_periods(const char *dir)
{
    gs_capture cap;
    memset(&cap, 0, sizeof cap);
    if (gs_capture_read(dir, &cap) != GS_OK) return 0;
    int ok = !cap.locked && cap.window_period == GS_PERIOD_MEASURED;
    for (int k = 0; k < cap.K; k++)
        ok &= cap.frames[k].window_half_period_s > 0 && cap.frames[k].window_drift_windows >= 0;
    gs_capture_release(&cap);
    return ok;
}

/* The small scene without shot noise and saturation: its first noise stage is to_dn. */
static void write_small_without_shot_noise(const char *path, int seed)
{
    write_small_edited(path, seed, "\"shot_noise\": {}, \"saturation\": {}, ", "");
}

/* 1 if dir_a/name and dir_b/name have the same bytes. */
static int same_file(const char *a, const char *b, const char *name)
{
    char pa[1024], pb[1024];
    snprintf(pa, sizeof pa, "%s/%s", a, name);
    snprintf(pb, sizeof pb, "%s/%s", b, name);
    FILE *fa = fopen(pa, "rb"), *fb = fopen(pb, "rb");
    int same = fa && fb;
    while (same) {
        int ca = fgetc(fa), cb = fgetc(fb);
        if (ca != cb) same = 0;
        if (ca == EOF || cb == EOF) break;
    }
    if (fa) fclose(fa);
    if (fb) fclose(fb);
    return same;
}

static int same_capture(const char *a, const char *b, int with_progress)
{
    int ok = same_file(a, b, "capture.json");
    if (with_progress) ok &= same_file(a, b, "acquisition.json");
    for (int k = 0; k < SMALL_K; k++) {
        char n[32];
        snprintf(n, sizeof n, "frame_%03d.png", k);
        ok &= same_file(a, b, n);
        snprintf(n, sizeof n, "hdr_%03d.png", k);
        ok &= same_file(a, b, n);
    }
    return ok;
}

static int whole_passes;   /* cap_loop_opts.hdr_whole_passes of run() */

static gs_status run(const char *scene_path, const char *dir, int stop_after, int force,
                     cap_loop_report *rep)
{
    cap_scene sc;
    gs_status s = cap_scene_read(scene_path, &sc);
    cap_backend *be = NULL;
    if (s == GS_OK) s = cap_backend_sim_new(&sc, NULL, &be);
    cap_scene_release(&sc);
    if (s != GS_OK) return s;
    cap_loop_opts o;
    cap_loop_opts_default(&o);
    o.progress = 0;
    o.stop_after = stop_after;
    o.force = force;
    o.hdr_whole_passes = whole_passes;
    s = cap_loop_run(be, dir, &o, rep);
    cap_backend_free(be);
    return s;
}

TEST(capture_resume_after_stop_and_damage_identical)
{
    char scene[1024], other[1024], a[1024], b[1024];
    const char *tmp = test_tmpdir();
    snprintf(scene, sizeof scene, "%s/small.json", tmp);
    snprintf(other, sizeof other, "%s/other.json", tmp);
    snprintf(a, sizeof a, "%s/a", tmp);
    snprintf(b, sizeof b, "%s/b", tmp);
    write_small(scene, 21);
    write_small(other, 22);
    cap_loop_report r;
    CHECK_OK(run(scene, a, 0, 0, &r));
    CHECK(r.complete && r.frames_acquired == SMALL_K && r.max_passes >= 2);
    long acquisitions = r.acquisitions;
    /* stop after 3 frames: a partial directory without capture.json */
    CHECK_OK(run(scene, b, 3, 0, &r));
    CHECK(!r.complete && r.frames_acquired == 3);
    CHECK(access(b, F_OK) == 0);
    char cj[1100];
    snprintf(cj, sizeof cj, "%s/capture.json", b);
    CHECK(access(cj, F_OK) != 0);
    /* another configuration refuses to mix with it */
    CHECK(run(other, b, 0, 0, &r) == GS_EINVAL);
    CHECK_MSG(strstr(gs_detail(), "another configuration"), "%s", gs_detail());
    /* resume: the 3 frames are kept, the rest acquired, the files are those of run a */
    CHECK_OK(run(scene, b, 0, 0, &r));
    CHECK(r.complete && r.frames_kept == 3 && r.frames_acquired == SMALL_K - 3);
    CHECK(r.acquisitions == acquisitions);
    CHECK_MSG(same_capture(a, b, 1), "a resumed capture differs from an uninterrupted one");
    /* complete: nothing to do */
    CHECK_OK(run(scene, b, 0, 0, &r));
    CHECK(r.complete && r.frames_kept == SMALL_K && r.frames_acquired == 0);
    /* a damaged frame (truncated) and a damaged map are acquired again, identically */
    char f2[1100];
    snprintf(f2, sizeof f2, "%s/frame_002.png", b);
    CHECK(truncate(f2, 100) == 0);
    snprintf(f2, sizeof f2, "%s/hdr_006.png", b);
    FILE *f = fopen(f2, "r+b");
    if (f) {
        fseek(f, 40, SEEK_SET);
        fputc(0x55, f);
        fclose(f);
    }
    CHECK_OK(run(scene, b, 0, 0, &r));
    CHECK_MSG(r.complete && r.frames_acquired == 2 && r.frames_kept == SMALL_K - 2,
              "acquired %d kept %d", r.frames_acquired, r.frames_kept);
    CHECK_MSG(same_capture(a, b, 1), "frames re-acquired after damage differ");
    /* force: starts again (same result) */
    CHECK_OK(run(scene, b, 0, 1, &r));
    CHECK(r.frames_acquired == SMALL_K);
    CHECK(same_capture(a, b, 1));
    /* the capture reads back */
    gs_capture cap;
    CHECK_OK(gs_capture_read(b, &cap));
    CHECK(cap.K == SMALL_K && cap.bands == 3 && cap.halvings != NULL);
    gs_capture_release(&cap);
}

/* The HDR loop's probes (cap_sim_render_hdr: a pass that more rounds may follow renders its
 * noise only on the rows that can saturate; a probe that is the frame's last pass gets its other
 * rows afterwards): the same files, byte for byte, as every pass acquired whole. Both kinds of
 * probe happen here (followed by another round, and completed as the last pass). */
/* Also without shot noise (the probe then decides before to_dn: its bound is in electrons). */
TEST(capture_hdr_probes_give_the_same_files_as_whole_passes)
{
    for (int shot = 1; shot >= 0; shot--) {
        char scene[1024], a[1024], b[1024];
        const char *tmp = test_tmpdir();
        snprintf(scene, sizeof scene, "%s/probe%d.json", tmp, shot);
        snprintf(a, sizeof a, "%s/probed%d", tmp, shot);
        snprintf(b, sizeof b, "%s/whole%d", tmp, shot);
        if (shot) write_small(scene, 23);
        else write_small_without_shot_noise(scene, 23);
        cap_loop_report ra, rb;
        CHECK_OK(run(scene, a, 0, 0, &ra));
        whole_passes = 1;
        gs_status s = run(scene, b, 0, 0, &rb);
        whole_passes = 0;
        CHECK_OK(s);
        CHECK(ra.complete && rb.complete && ra.max_passes >= 2 && ra.acquisitions == rb.acquisitions);
        /* (with shot noise both kinds of probe happen: one followed by more rounds, one completed) */
        CHECK_MSG(ra.probes > ra.probes_kept && (ra.probes_kept > 0 || !shot), "shot noise %d: probes %ld, "
                  "completed %ld", shot, ra.probes, ra.probes_kept);
        CHECK(rb.probes == 0 && rb.probes_kept == 0);
        CHECK_MSG(same_capture(a, b, 1), "shot noise %d: a capture with probes differs from one with "
                  "whole passes", shot);
    }
}

TEST(capture_resume_after_kill_cli)
{
    char cmd[16384], out[4096], bin[2048];
    const char *tmp = test_tmpdir();
    if (!realpath(test_bin(), bin)) snprintf(bin, sizeof bin, "%s", test_bin());
    char scene[1024];
    snprintf(scene, sizeof scene, "%s/small.json", tmp);
    write_small_free(scene, 5);
    /* kill -9 as soon as the first frame is recorded, then resume */
    snprintf(cmd, sizeof cmd,
             "cd %s && %s simulate small.json --out-dir full --no-progress >/dev/null && "
             "(%s simulate small.json --out-dir killed --no-progress >/dev/null & pid=$!; "
             " while ! grep -q '\"k\": 0' killed/acquisition.json 2>/dev/null; do sleep 0.005; done; "
             " kill -9 $pid; wait $pid; echo \"exit $?\"; "
             " if [ -f killed/capture.json ]; then echo finished-before-kill; else echo interrupted; fi; "
             " grep -c '\"k\":' killed/acquisition.json) && "
             "%s simulate small.json --out-dir killed --no-progress && diff -r full killed && echo SAME",
             tmp, bin, bin, bin);
    int rc = test_run(cmd, out, sizeof out);
    printf("    %s", out);
    CHECK_MSG(rc == 0 && strstr(out, "SAME"), "rc %d: %s", rc, out);
    CHECK(strstr(out, "kept") != NULL);
    char dir[1100];
    snprintf(dir, sizeof dir, "%s/killed", tmp);
    CHECK(has_window_periods(dir));
}

TEST(capture_replay_roundtrip)
{
    char scene[1024], a[1024], c[1024];
    const char *tmp = test_tmpdir();
    snprintf(scene, sizeof scene, "%s/small.json", tmp);
    snprintf(a, sizeof a, "%s/a", tmp);
    snprintf(c, sizeof c, "%s/c", tmp);
    write_small_free(scene, 9);
    cap_loop_report r;
    CHECK_OK(run(scene, a, 0, 0, &r));
    cap_backend *be = NULL;
    CHECK_OK(cap_backend_replay_new(a, &be));
    if (!be) return;
    CHECK(!strcmp(cap_backend_name(be), "replay"));
    cap_acq_info info;
    CHECK_OK(cap_backend_info(be, &info));
    CHECK(info.K == SMALL_K && info.fixed_halvings && info.max_halvings == 0);
    cap_loop_opts o;
    cap_loop_opts_default(&o);
    o.progress = 0;
    o.stop_after = 4;
    CHECK_OK(cap_loop_run(be, c, &o, &r));
    CHECK(!r.complete);
    o.stop_after = 0;
    CHECK_OK(cap_loop_run(be, c, &o, &r));
    CHECK(r.complete && r.frames_kept == 4);
    CHECK_MSG(same_capture(a, c, 0), "a replayed capture differs from its source");
    CHECK(has_window_periods(c));
    cap_backend_free(be);
    /* the CLI route */
    char cmd[4096], out[2048];
    snprintf(cmd, sizeof cmd, "%s capture --backend replay --from %s --out-dir %s/d --no-progress && diff %s/frame_005.png %s/d/frame_005.png && echo SAME",
             test_bin(), a, tmp, a, tmp);
    int rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 0 && strstr(out, "SAME"), "%s", out);
    snprintf(cmd, sizeof cmd, "%s capture --backend sim --scene %s --out-dir %s/e --no-progress",
             test_bin(), scene, tmp);
    rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 0, "%s", out);
    char e[1100];
    snprintf(e, sizeof e, "%s/e", tmp);
    CHECK_MSG(same_capture(a, e, 1), "capture --backend sim differs from the loop");
}

/* An option of another backend than --backend's is a usage error naming it and its backend,
 * before anything is written (--K with sim was ignored: the scene's K was captured). */
TEST(capture_cli_options_of_another_backend_refused)
{
    char scene[1024], o[1024], out[4096];
    snprintf(scene, sizeof scene, "%s/other.json", test_tmpdir());
    snprintf(o, sizeof o, "%s/other-out", test_tmpdir());
    write_small(scene, 3);
    static const struct {
        const char *args, *option, *backend;
    } cases[] = {
        {"--backend sim --scene %s --out-dir %s --K 7", "--K", "hardware"},
        {"--backend sim --scene %s --out-dir %s --camera 3 --serial /dev/x", "--camera", "hardware"},
        {"--backend replay --from %s --out-dir %s --seed 4", "--seed", "sim"},
        {"--backend hardware --camera %s --out-dir %s --serial /dev/x --width 8 --height 8 --from x",
         "--from", "replay"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        char args[3000];
        snprintf(args, sizeof args, cases[i].args, scene, o);
        CHECK_MSG(fx_run(out, sizeof out, "%s capture %s", test_bin(), args) == 2 &&
                  fx_count_lines(out) == 1 && strstr(out, cases[i].option) && strstr(out, cases[i].backend),
                  "%s: %s", args, out);
        CHECK(!fx_exists(o));
    }
    /* a missing required option: one line too, not the whole usage */
    CHECK(fx_run(out, sizeof out, "%s capture --backend sim --scene %s", test_bin(), scene) == 2);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "--out-dir"), "%s", out);
}

/* The hardware backend's counts (K, C, M, sizes, lines, rounds) are integers and its grid and
 * bands take two values each: anything else is a usage error naming the option and what it
 * expects (--K 7.5 was truncated to K = 7 and --cycles 1.5 to C = 1, silently; --bands 2
 * failed later in one message about the camera, size, bands and saturation together, which a
 * saturation below the black level still gets). */
TEST(capture_cli_hardware_numbers_refused_by_name)
{
    char o[1024], out[4096];
    snprintf(o, sizeof o, "%s/hwnum-out", test_tmpdir());
    static const struct {
        const char *opt, *value, *expected;
    } cases[] = {
        {"--K", "7.5", "integer"},        {"--cycles", "1.5", "integer"},
        {"--masks", "4.5", "integer"},    {"--width", "8.5", "integer"},
        {"--zc-line", "1.5", "integer"},  {"--max-rounds", "1.5", "integer"},
        {"--max-saturated", "0.5", "integer"}, {"--stop-after", "1.5", "integer"},
        {"--K", "1e1", "integer"},        {"--bands", "2", "1 or 3"},
        {"--grid", "55", "50 or 60"},     {"--grid", "50.5", "50 or 60"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        int rc = fx_run(out, sizeof out, "%s capture --backend hardware --camera 0 --serial "
                        "/dev/null --width 8 --height 8 --out-dir %s %s %s", test_bin(), o,
                        cases[i].opt, cases[i].value);
        CHECK_MSG(rc == 2 && fx_count_lines(out) == 1 && strstr(out, cases[i].opt) &&
                  strstr(out, cases[i].value) && strstr(out, cases[i].expected),
                  "%s %s: rc %d: %s", cases[i].opt, cases[i].value, rc, out);
        CHECK(!fx_exists(o));
    }
    /* two fields together: the message names both with their values */
    int rc = fx_run(out, sizeof out, "%s capture --backend hardware --camera 0 --serial /dev/null "
                    "--width 8 --height 8 --out-dir %s --saturation 100 --black-level 200",
                    test_bin(), o);
    CHECK_MSG(rc != 0 && fx_count_lines(out) == 1 && strstr(out, "saturation 100") &&
              strstr(out, "black level 200") && !strstr(out, "bands"), "rc %d: %s", rc, out);
    CHECK(!fx_exists(o));
}

/* More HDR rounds than the masks allow is an error naming the option and the limit, before
 * anything is written: M = 16 masks halve exactly 3 times (8 -> 4 -> 2 -> 1), paper Sec. 6
 * (--max-rounds 9 ran with 3 rounds and exit 0). 3 rounds are accepted and no pixel of the
 * capture is halved more often. */
TEST(capture_cli_max_rounds_beyond_the_masks_refused)
{
    char scene[1024], o[1024], out[4096];
    snprintf(scene, sizeof scene, "%s/rounds.json", test_tmpdir());
    snprintf(o, sizeof o, "%s/rounds-out", test_tmpdir());
    write_small(scene, 5);
    int rc = fx_run(out, sizeof out, "%s capture --backend sim --scene %s --out-dir %s "
                    "--max-rounds 4 -q", test_bin(), scene, o);
    CHECK_MSG(rc == 1 && fx_count_lines(out) == 1 && strstr(out, "--max-rounds 4") &&
              strstr(out, "at most 3"), "rc %d: %s", rc, out);
    CHECK(!fx_exists(o));
    rc = fx_run(out, sizeof out, "%s capture --backend sim --scene %s --out-dir %s "
                "--max-rounds 3 -q", test_bin(), scene, o);
    CHECK_MSG(rc == 0, "rc %d: %s", rc, out);
    gs_capture cap;
    memset(&cap, 0, sizeof cap);
    CHECK_OK(gs_capture_read(o, &cap));
    int hmax = 0;
    size_t n = (size_t)cap.K * (size_t)cap.width * (size_t)cap.height;
    for (size_t i = 0; cap.halvings && i < n; i++)
        if (cap.halvings[i] > hmax) hmax = cap.halvings[i];
    CHECK_MSG(hmax >= 1 && hmax <= 3, "largest halving count %d", hmax);
    gs_capture_release(&cap);
}

/* ------------------------------------------------------------------ grid frequency per frame */

/* Acquires the scene `text` into dir with the sim backend and reads the capture back into cap
 * (zeroed first); *step: the crossings from one acquisition's start to the next (C + readout). */
static gs_status run_text(const char *text, const char *dir, long *step, gs_capture *cap)
{
    cap_scene sc;
    memset(cap, 0, sizeof *cap);
    gs_status s = cap_scene_parse(text, "freq.json", ".", &sc);
    if (s != GS_OK) return s;
    *step = sc.acam.cycles + sc.readout_cycles;
    cap_backend *be = NULL;
    s = cap_backend_sim_new(&sc, NULL, &be);
    if (s == GS_OK) {
        cap_loop_opts o;
        cap_loop_opts_default(&o);
        o.progress = 0;
        s = cap_loop_run(be, dir, &o, NULL);
    }
    cap_backend_free(be);
    cap_scene_release(&sc);
    return s == GS_OK ? gs_capture_read(dir, cap) : s;
}

static const char *freq_scene =
    "{\"format\": \"gridsurvey-scene/1\", \"seed\": 3,\n"
    " \"grid\": {\"nominal_hz\": 50, \"frequency\": %s},\n"
    " \"camera\": {\"width_px\": 8, \"height_px\": 8, \"sensor\": {\"bands\": 1}},\n"
    " \"acam\": {\"K\": 4, \"cycles\": %d},\n"
    " \"lights\": [{\"bulb\": \"hps-150w\", \"x_px\": 3, \"y_px\": 3, \"flux_e_per_cycle\": 5000}],\n"
    " \"effects\": {%s}}\n";

/* The crossings of the mains recording wav (malloc'd, *count of them; NULL and a test failure
 * when it cannot be read), and in *i0 the first rising one: crossing 0 of the trace timeline as
 * docs/scene.md defines it, each time the crossing's own. */
static double *trace_crossings(const char *wav, size_t *count, size_t *i0)
{
    double *x = NULL, *tc = NULL, rate = 0, mean = 0, rms = 0;
    size_t n = 0;
    int rising_first = 0;
    *count = *i0 = 0;
    CHECK_OK(gs_mains_read(wav, &x, &n, &rate));
    for (size_t i = 0; i < n; i++) mean += x[i];
    mean /= n ? (double)n : 1.0;
    for (size_t i = 0; i < n; i++) rms += (x[i] - mean) * (x[i] - mean);
    rms = n ? sqrt(rms / (double)n) : 0;
    CHECK_OK(gs_zero_crossings(x, n, rate, 0.1 * rms, &tc, count, &rising_first));
    free(x);
    while (*i0 < *count && (*i0 % 2 == 0) != (rising_first > 0)) (*i0)++;
    return tc;
}

/* capture.json carries each exposure's mean grid frequency and start: the frequency model's
 * exactly for a constant grid, and for a real mains recording C / (2 (t_end - t_start)) of the
 * recording's own crossings (Eq. 1): the simulator's, from gs_mains_read + gs_zero_crossings, to
 * the last bit (the bookkeeping), and an independent oracle's, within its own error. */
TEST(capture_records_grid_frequency_per_frame)
{
    const char *tmp = test_tmpdir();
    char text[2048], dir[1024];
    gs_capture cap;
    /* constant 50.02 Hz (frequency_wander on) and nominal 50 Hz (no timing effect) */
    const double want_hz[2] = {50.02, 50.0};
    for (int v = 0; v < 2; v++) {
        snprintf(text, sizeof text, freq_scene,
                 v == 0 ? "{\"model\": \"constant\", \"hz\": 50.02}" : "{\"model\": \"constant\"}",
                 50, v == 0 ? "\"frequency_wander\": {}" : "");
        snprintf(dir, sizeof dir, "%s/freq_const_%d", tmp, v);
        long step = 0;
        CHECK_OK(run_text(text, dir, &step, &cap));
        for (int k = 0; k < cap.K; k++) {
            CHECK_NEAR(cap.frames[k].grid_hz_measured, want_hz[v], 1e-9);
            /* acquisition k starts k (C + readout) crossings after the first */
            CHECK_NEAR(cap.frames[k].start_s, (double)(k * step) / (2.0 * want_hz[v]), 1e-9);
        }
        gs_capture_release(&cap);
    }

    /* a real mains recording */
    const char *wav = test_shared_path("data/mains/whu_001_ref.wav");
    char wav_path[1024];
    snprintf(wav_path, sizeof wav_path, "%s", wav);
    char freq[1200];
    snprintf(freq, sizeof freq, "{\"model\": \"trace\", \"wav\": \"%s\"}", wav_path);
    int C = 300;
    snprintf(text, sizeof text, freq_scene, freq, C, "\"frequency_wander\": {}");
    snprintf(dir, sizeof dir, "%s/freq_trace", tmp);
    long step = 0;
    CHECK_OK(run_text(text, dir, &step, &cap));
    if (!cap.frames) return;
    size_t count = 0, i0 = 0;
    double *tc = trace_crossings(wav_path, &count, &i0);
    double worst = 0, t_first = 0;
    for (int k = 0; k < cap.K && tc; k++) {
        size_t c0 = i0 + 64 + (size_t)(k * step), c1 = c0 + (size_t)C;
        CHECK(c1 < count);
        if (c1 >= count) break;
        double t0 = tc[c0], t1 = tc[c1];
        if (k == 0) t_first = t0;
        double f = (double)C / (2.0 * (t1 - t0));
        double got = cap.frames[k].grid_hz_measured;
        printf("    frame %d: start %.6f s, %.6f Hz (recording's crossings %.6f Hz)\n", k,
               cap.frames[k].start_s, got, f);
        CHECK(got > 49.9 && got < 50.1);
        CHECK_NEAR(got, f, 1e-9);
        CHECK_NEAR(cap.frames[k].start_s, t0 - t_first, 1e-9);
        if (fabs(got - f) > worst) worst = fabs(got - f);
        if (k > 0) CHECK(got != cap.frames[k - 1].grid_hz_measured);
    }
    printf("    trace: largest |capture.json - recording| %.2e Hz\n", worst);
    free(tc);
    /* the independent oracle (tests/independent/mains_oracle.py --frames): its own crossings
     * (the fundamental's, by a least-squares phase) and Eq. 1 over each exposure's C half
     * periods: within 1.5e-4 Hz (it differs from Eq. 1 on the waveform's crossings by up to 7e-5
     * Hz on whu_001; neighbouring frames differ by 6e-4 to 1.4e-3 Hz) and 2e-5 s of start_s */
    char out[4096];
    int rc = fx_run(out, sizeof out, "/usr/bin/python3 tests/independent/mains_oracle.py --frames 64 %ld %d %d %s",
                    step, C, cap.K, wav_path);
    CHECK_MSG(rc == 0, "mains_oracle.py (needs /usr/bin/python3 with python3-numpy): %s", out);
    const char *p = out;
    for (int k = 0; rc == 0 && k < cap.K; k++) {
        int kk = -1;
        double start_s = NAN, hz = NAN;
        CHECK_MSG(p && sscanf(p, "frame %d %lf %lf", &kk, &start_s, &hz) == 3 && kk == k, "oracle: %s", out);
        printf("    oracle frame %d: start %.6f s, %.6f Hz\n", k, start_s, hz);
        CHECK_NEAR(cap.frames[k].grid_hz_measured, hz, 1.5e-4);
        CHECK_NEAR(cap.frames[k].start_s, start_s, 2e-5);
        p = strchr(p, '\n');
        if (p) p++;
    }
    gs_capture_release(&cap);
}

/* Reference phase of time t on the crossings tc (crossing index + fraction of its half period,
 * as docs/scene.md defines the timeline), by bisection. */
static double crossing_phase(const double *tc, size_t count, double t)
{
    size_t lo = 0, hi = count - 1;
    while (hi - lo > 1) {
        size_t mid = (lo + hi) / 2;
        if (tc[mid] <= t) lo = mid;
        else hi = mid;
    }
    return (double)lo + (t - tc[lo]) / (tc[lo + 1] - tc[lo]);
}

/* Free running, capture.json records each exposure's window period: the nominal one, or the
 * mean of the 64 half periods before the exposure (the firmware's), here recomputed from a real
 * mains recording's own crossings. The drift it implies (gs_capture_window_drift: K C |2 P f - 1|
 * windows) is the windows' true motion over the exposure, the reference phase of window k's
 * start after C periods P against at the first (the oracle, on the same crossings), within
 * 1 % + 0.002 windows. Locked
 * captures record no period and drift 0; a free-running one without it drifts by NaN. A
 * controller clock's error moves a nominal period, not a measured one (constant grid).
 * capture.json's window_period says which (none locked). */
TEST(capture_records_free_running_window_period)
{
    const char *tmp = test_tmpdir();
    const char *wav = test_shared_path("data/mains/whu_001_ref.wav");
    char text[2048], dir[1024], freq[1200];
    snprintf(freq, sizeof freq, "{\"model\": \"trace\", \"wav\": \"%s\"}", wav);
    const int C = 300;
    size_t count = 0, i0 = 0;
    double *tc = trace_crossings(wav, &count, &i0);
    static const char *const acam[3] = {"\"locked\": false, \"free_running_period\": \"measured\"",
                                        "\"locked\": false", "\"locked\": true"};
    for (int v = 0; v < 3 && tc; v++) {
        snprintf(text, sizeof text,
                 "{\"format\": \"gridsurvey-scene/1\", \"seed\": 3,\n"
                 " \"grid\": {\"nominal_hz\": 50, \"frequency\": %s},\n"
                 " \"camera\": {\"width_px\": 8, \"height_px\": 8, \"sensor\": {\"bands\": 1}},\n"
                 " \"acam\": {\"K\": 4, \"cycles\": %d, %s},\n"
                 " \"lights\": [{\"bulb\": \"hps-150w\", \"x_px\": 3, \"y_px\": 3, \"flux_e_per_cycle\": 5000}],\n"
                 " \"effects\": {\"frequency_wander\": {}}}\n", freq, C, acam[v]);
        snprintf(dir, sizeof dir, "%s/window_period_%d", tmp, v);
        long step = 0;
        gs_capture cap;
        CHECK_OK(run_text(text, dir, &step, &cap));
        if (!cap.frames) continue;
        int frame = -2;
        double drift = gs_capture_window_drift(&cap, &frame), worst = 0;
        CHECK_MSG(cap.window_period == (v == 0 ? GS_PERIOD_MEASURED : v == 1 ? GS_PERIOD_NOMINAL : GS_PERIOD_UNKNOWN),
                  "variant %d: window_period %d", v, cap.window_period);
        if (v == 2) {
            for (int k = 0; k < cap.K; k++)
                CHECK(isnan(cap.frames[k].window_half_period_s) && isnan(cap.frames[k].window_drift_windows));
            CHECK(drift == 0.0);
            gs_capture_release(&cap);
            continue;
        }
        int worst_k = -1;
        for (int k = 0; k < cap.K; k++) {
            size_t c0 = i0 + 64 + (size_t)(k * step);
            CHECK(c0 + (size_t)C + 2 < count);
            if (c0 + (size_t)C + 2 >= count) break;
            double P = v == 0 ? (tc[c0] - tc[c0 - 64]) / 64.0 : 0.01;
            CHECK_NEAR(cap.frames[k].window_half_period_s, P, 1e-12);
            /* the oracle: where window k starts after C periods, against where it started */
            double t0 = tc[c0] + k * P / cap.K;
            double moved = (crossing_phase(tc, count, t0 + C * P) - (double)(c0 + (size_t)C)) -
                           (crossing_phase(tc, count, t0) - (double)c0);
            double want = cap.K * fabs(moved);
            double got = cap.K * cap.frames[k].cycles *
                         fabs(2.0 * cap.frames[k].window_half_period_s * cap.frames[k].grid_hz_measured - 1.0);
            printf("    %s period, frame %d: P %.9f s, drift %.4f windows (oracle %.4f)\n",
                   v == 0 ? "measured" : "nominal", k, cap.frames[k].window_half_period_s, got, want);
            /* (the mean half period against the one the window ends in: 0.1 % of the drift and
             * 1e-3 windows; the decision is at 0.5) */
            CHECK_NEAR(got, want, 0.01 * want + 2e-3);
            /* the recorded range of the offset: the same crossings' at every even cycle and at
             * the end (C even) */
            double lo = 0, hi = 0;
            for (int c = 0; c <= C; c += 2) {
                size_t i = c0 + (size_t)(c < C ? c : C - 1);
                double off = (c * P - (tc[c0 + (size_t)c] - tc[c0])) / (tc[i + 1] - tc[i]);
                lo = fmin(lo, off);
                hi = fmax(hi, off);
            }
            double range = cap.K * (hi - lo);
            printf("      range %.4f windows (oracle %.4f)\n", cap.frames[k].window_drift_windows, range);
            CHECK_NEAR(cap.frames[k].window_drift_windows, range, 1e-9);
            CHECK(range >= got - 2e-3);   /* (it holds the net motion) */
            if (range > worst) worst = range, worst_k = k;
        }
        CHECK_NEAR(drift, worst, 1e-12);
        CHECK(frame == worst_k);
        /* without the range, the net motion from the period; without either, unknown */
        cap.frames[2].window_drift_windows = NAN;
        CHECK(gs_capture_frame_drift(&cap, 2) == cap.K * cap.frames[2].cycles *
                                                     fabs(2.0 * cap.frames[2].window_half_period_s *
                                                          cap.frames[2].grid_hz_measured - 1.0));
        cap.frames[2].window_half_period_s = NAN;
        CHECK(isnan(gs_capture_window_drift(&cap, &frame)) && frame == 2);
        gs_capture_release(&cap);
    }
    free(tc);
    /* a constant 50 Hz grid and a controller clock 200 ppm fast: a nominal period is off by it,
     * K C 2e-4 windows; a measured one, timed with the same clock, not at all */
    for (int measured = 0; measured < 2; measured++) {
        snprintf(text, sizeof text,
                 "{\"format\": \"gridsurvey-scene/1\", \"seed\": 3,\n"
                 " \"grid\": {\"nominal_hz\": 50, \"frequency\": {\"model\": \"constant\"}},\n"
                 " \"camera\": {\"width_px\": 8, \"height_px\": 8, \"sensor\": {\"bands\": 1}},\n"
                 " \"acam\": {\"K\": 4, \"cycles\": %d, \"locked\": false, \"free_running_period\": \"%s\"},\n"
                 " \"lights\": [{\"bulb\": \"hps-150w\", \"x_px\": 3, \"y_px\": 3, \"flux_e_per_cycle\": 5000}],\n"
                 " \"effects\": {\"frequency_wander\": {}, \"free_running_drift\": {\"clock_ppm\": 200}}}\n",
                 C, measured ? "measured" : "nominal");
        snprintf(dir, sizeof dir, "%s/window_period_ppm_%d", tmp, measured);
        long step = 0;
        gs_capture cap;
        CHECK_OK(run_text(text, dir, &step, &cap));
        for (int k = 0; cap.frames && k < cap.K; k++) {
            CHECK_NEAR(cap.frames[k].window_half_period_s, measured ? 0.01 : 0.01 * (1 + 2e-4), 1e-15);
            CHECK_NEAR(gs_capture_frame_drift(&cap, k), measured ? 0.0 : cap.K * C * 2e-4, 1e-9);
        }
        gs_capture_release(&cap);
    }
}

/* Shell fragments of the lock tests: another process holding the capture directory dir's lock
 * (util-linux flock(1), the same flock(2) the loop takes; how: -x or -s) until RELEASE_LOCK(n),
 * through the fifo reln (mkfifo it first): no race with the commands run meanwhile. */
#define HOLD_LOCK(how, dir, n)                                                                    \
    "(flock " how " " dir " sh -c 'touch held" n "; read x < rel" n "' >/dev/null 2>&1 & pid=$!; " \
    " while [ ! -e held" n " ]; do sleep 0.005; done; "
#define RELEASE_LOCK(n) "echo > rel" n "; wait $pid; "

/* The binary's and the lab scene's absolute paths (for commands run in the test's directory,
 * which it returns). */
static const char *lab_paths(char bin[2048], char lab[2048])
{
    if (!realpath(test_bin(), bin)) snprintf(bin, 2048, "%s", test_bin());
    CHECK(realpath("capture/scenes/lab.json", lab) != NULL);
    return test_tmpdir();
}

/* Two acquisitions into one capture directory at once: the second took the first's temporary
 * files for a killed run's and removed them, so either failed with "frame_000.png: cannot
 * replace it: No such file or directory", or both went on writing frames and acquisition.json
 * (a hardware capture's frames from two acquisitions). Now the directory is locked while a
 * process acquires into it (released when it ends, killed or not): the second fails in one line
 * naming it (and that it may give another directory), the first completes the capture made
 * alone, byte for byte. */
TEST(capture_directory_one_writer_at_a_time)
{
    /* another writer holds the directory's lock (util-linux flock(1), the same flock(2) the loop
     * takes: no race with a second simulate that could finish first on a loaded machine): the
     * loop refuses in one line and leaves the directory alone; once it is free, the capture is
     * the same as one made alone */
    char cmd[16384], out[8192], bin[2048], lab[2048];
    const char *tmp = lab_paths(bin, lab);
    snprintf(cmd, sizeof cmd,
             "cd %s && %s simulate %s --out-dir alone -q >/dev/null && mkdir shared && mkfifo rel0 && "
             HOLD_LOCK("-x", "shared", "0")
             " %s simulate %s --out-dir shared -q >/dev/null 2>second.err; echo \"second $?\"; "
             " ls shared | wc -l; " RELEASE_LOCK("0")
             " %s simulate %s --out-dir shared -q >/dev/null; echo \"after $?\"); "
             "cat second.err; diff -r alone shared && echo SAME",
             tmp, bin, lab, bin, lab, bin, lab);
    int rc = test_run(cmd, out, sizeof out);
    printf("    %s", out);
    CHECK_MSG(rc == 0 && strstr(out, "second 1\n0\nafter 0\n") && fx_count_lines(out) == 5 && strstr(out, "SAME"),
              "rc %d: %s", rc, out);
    /* a writer's refusal, with a writer's way out (the loop's first, shared lock is refused
     * before its exclusive one is tried: it gave a reader's message, without the hint) */
    CHECK_MSG(strstr(out, "shared: another process is acquiring into this capture directory: wait for it to end, "
                          "or give another directory\n"), "%s", out);
}

/* A reader of a capture directory took no lock: `recognize` or `run` could read frames of two
 * acquisitions while another process re-acquired into it (each frame file is replaced whole,
 * but not all at once), and `run`'s content key could hash files other than those it read. Now
 * readers take the directory's lock shared: with a writer holding it (flock(1) standing for
 * one), `recognize` fails in one line naming the directory; with a reader holding it shared, a
 * `simulate` that finds the capture complete has nothing to do and succeeds, but an acquisition
 * into it fails, naming the directory, and writes nothing; once free, both work. */
TEST(capture_directory_not_read_while_acquired)
{
    char cmd[32768], out[8192], bin[2048], lab[2048];
    const char *tmp = lab_paths(bin, lab);
    snprintf(cmd, sizeof cmd,
             "cd %s && %s simulate %s --out-dir rd -q >/dev/null && cp -r rd before && mkfifo rel1 rel2 && "
             HOLD_LOCK("-x", "rd", "1")
             " %s recognize rd >/dev/null 2>r.err; echo \"read $?\"; " RELEASE_LOCK("1")
             " %s recognize rd >/dev/null 2>&1; echo \"read after $?\"); "
             HOLD_LOCK("-s", "rd", "2")
             " %s simulate %s --out-dir rd -q >/dev/null 2>&1; echo \"complete $?\"; "
             " %s simulate %s --out-dir rd --force -q >/dev/null 2>w.err; echo \"write $?\"; "
             " diff -r before rd >/dev/null && echo UNTOUCHED; " RELEASE_LOCK("2")
             " %s simulate %s --out-dir rd --force -q >/dev/null 2>&1; echo \"write after $?\"); "
             "cat r.err w.err",
             tmp, bin, lab, bin, bin, bin, lab, bin, lab, bin, lab);
    int rc = test_run(cmd, out, sizeof out);
    printf("    %s", out);
    CHECK_MSG(rc == 0 && strstr(out, "read 1\nread after 0\ncomplete 0\nwrite 1\nUNTOUCHED\nwrite after 0\n"), "rc %d: %s",
              rc, out);
    CHECK_MSG(strstr(out, "rd: another process is acquiring into this capture directory: wait for it to end\n") &&
              strstr(out, "rd: another process is acquiring into this capture directory or reading it: wait "
                     "for it to end, or give another directory\n") && fx_count_lines(out) == 8, "%s", out);
}

/* simulate --stop-after printed "partial:  26 frames (5 rendered, 0 kept)", as if 26 frames had
 * been written; now it says how many of them it has and that the same command resumes, and the
 * resumed run counts the frames it kept. */
TEST(simulate_stop_after_says_how_far_it_got)
{
    char cmd[16384], out[4096], bin[2048], lab[2048];
    const char *tmp = lab_paths(bin, lab);
    snprintf(cmd, sizeof cmd, "cd %s && %s simulate %s --out-dir stop -q --stop-after 3 && %s simulate %s --out-dir stop -q",
             tmp, bin, lab, bin, lab);
    int rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 0 && strstr(out, "simulate: stop: stopped with 3 of 26 frames (3 rendered, 0 kept): the same command "
                                     "resumes; ") &&
              strstr(out, "simulate: stop: wrote 26 frames (23 rendered, 3 kept), "), "%d: %s", rc, out);
}
