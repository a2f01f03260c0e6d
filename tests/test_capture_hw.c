/* test_capture_hw.c - the hardware backend (capture/backend_hardware.c) against fakes: the fake
 * libgpiod (tests/fake_gpiod.c) replays zero crossings taken from a real mains recording and
 * records the shutter and trigger outputs; a forked fake ACam controller speaks the firmware's
 * serial protocol on a socketpair; the camera is OpenCV VideoCapture on a 16-bit PNG sequence
 * (CAP_IMAGES). The production code path runs unchanged. */
#define _GNU_SOURCE /* dladdr */
#include "tests/test.h"
#include "tests/fake_gpiod.h"
#include "tests/hw_fixture.h"
#include "capture/capture.h"
#include "capture/internal.h"
#include "firmware/schedule.h"

#include <dlfcn.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#define HW_K 4
#define HW_C 50
#define HW_W 32
#define HW_H 24

static void send_line(int fd, const char *text)
{
    unsigned x = 0;
    for (const char *p = text; *p; p++) x ^= (unsigned char)*p;
    char buf[256];
    int n = snprintf(buf, sizeof buf, "%s*%02X\n", text, x);
    if (write(fd, buf, (size_t)n) != n) _exit(3);
}

/* The fake controller: PING, CFG, START (then one D line per cycle and EV DONE), STOP. */
static void fake_controller(int fd, const char *log_path)
{
    FILE *log = fopen(log_path, "w");
    char line[256];
    size_t n = 0;
    long C = 0;
    for (;;) {
        char c;
        ssize_t got = read(fd, &c, 1);
        if (got <= 0) break;
        if (c != '\n') {
            if (n + 1 < sizeof line) line[n++] = c;
            continue;
        }
        line[n] = '\0';
        n = 0;
        char *star = strrchr(line, '*');
        if (star) *star = '\0';
        if (log) {
            fprintf(log, "%s\n", line);
            fflush(log);
        }
        if (!strcmp(line, "PING")) send_line(fd, "OK PING");
        else if (!strncmp(line, "CFG ", 4)) {
            int K, k;
            char mode;
            if (sscanf(line + 4, "%d %d %ld %c", &K, &k, &C, &mode) == 4) send_line(fd, "OK CFG");
            else send_line(fd, "ERR SYNTAX");
        } else if (!strcmp(line, "START")) {
            send_line(fd, "OK START");
            send_line(fd, "EV START grid=50 half_ns=9999000");   /* (free running: its period) */
            for (long i = 0; i < C; i++) {
                char d[64];
                snprintf(d, sizeof d, "D %ld %ld", i, 10000000L + (i % 2 ? 1500L : -1500L));
                send_line(fd, d);
            }
            send_line(fd, "EV DONE");
        } else if (!strcmp(line, "STOP")) send_line(fd, "OK STOP cycles=0");
        else send_line(fd, "ERR SYNTAX");
    }
    if (log) fclose(log);
    _exit(0);
}

static int masks_loaded;
static int load_masks(void *user, int masks, const unsigned char *halvings, int w, int h)
{
    (void)user;
    (void)halvings;
    if (masks != 2 || w != HW_W || h != HW_H) return 1;
    masks_loaded++;
    return 0;
}

/* Zero crossings of a real mains recording as a GPIO event file. */
static int write_events(const char *path, size_t count)
{
    double *x = NULL, *t = NULL, rate;
    size_t n = 0, nc = 0;
    int rising;
    if (gs_mains_read(test_shared_path("data/mains/whu_002_ref.wav"), &x, &n, &rate) != GS_OK) return 0;
    gs_status s = gs_zero_crossings(x, n, rate, 0.05, &t, &nc, &rising);
    free(x);
    if (s != GS_OK || nc < count) {
        free(t);
        return 0;
    }
    FILE *f = fopen(path, "w");
    for (size_t i = 0; i < count; i++) {
        double ts = 5000.0 + t[i];
        long long sec = (long long)ts;
        fprintf(f, "%lld %lld %d\n", sec, (long long)((ts - (double)sec) * 1e9),
                ((i % 2 == 0) == (rising > 0)) ? 1 : 2);
    }
    fclose(f);
    free(t);
    return 1;
}

/* The camera's known pattern (tests/hw_fixture.h). */
static unsigned short hw_pixel(int k, int x, int y, int b)
{
    return (unsigned short)(64 + 1000 * k + 31 * x + 7 * y + 300 * b);
}

static pid_t start_controller(int *fd, const char *log_path)
{
    int sv[2];
    if (socketpair(AF_UNIX, SOCK_STREAM, 0, sv) != 0) return -1;
    fflush(stdout);
    pid_t pid = fork();
    if (pid == 0) {
        close(sv[0]);
        fake_controller(sv[1], log_path);
    }
    close(sv[1]);
    *fd = sv[0];
    return pid;
}

/* The fakes of a K-frame capture: the GPIO line's crossings (a real mains recording's, as the
 * event file events, and 10 more), the camera's frames and the controller (its child process,
 * returned; its log in log_path), and *hw configured for them (saturation 65535). */
static pid_t start_fakes(const char *events, const char *log_path, cap_hw_config *hw)
{
    CHECK(write_events(events, HW_K * (HW_C + 1) + 10));
    CHECK(fake_gpiod_load_events(events, HW_C + 1) == HW_K * (HW_C + 1) + 10);
    const char *pattern = hw_fx_camera(HW_K, HW_W, HW_H, hw_pixel);
    int fd = -1;
    pid_t child = start_controller(&fd, log_path);
    CHECK(child > 0);
    hw_fx_config(hw, pattern, fd, HW_K, HW_C, HW_W, HW_H);
    hw->saturation_dn = 65535;
    return child;
}

TEST(capture_hardware_backend_with_fakes)
{
    const char *tmp = test_tmpdir();
    char events[1024], log_path[1024], out[1024];
    snprintf(events, sizeof events, "%s/zc.events", tmp);
    snprintf(log_path, sizeof log_path, "%s/controller.log", tmp);
    snprintf(out, sizeof out, "%s/capture", tmp);
    cap_hw_config hw;
    pid_t child = start_fakes(events, log_path, &hw);
    hw.load_masks = load_masks;
    cap_backend *be = NULL;
    CHECK_OK(cap_backend_hardware_new(&hw, &be));
    if (be) {
        CHECK(!strcmp(cap_backend_name(be), "hardware"));
        cap_loop_opts o;
        cap_loop_opts_default(&o);
        o.progress = 0;
        cap_loop_report rep;
        CHECK_OK(cap_loop_run(be, out, &o, &rep));
        CHECK(rep.complete && rep.frames_acquired == HW_K && rep.acquisitions == HW_K);
        cap_hw_log log;
        CHECK_OK(cap_backend_hardware_log(be, &log));
        printf("    last frame: %zu crossings on the GPIO (mean half period %.6f s), %zu cycles "
               "logged by the controller (%.6f s)\n", log.crossings, log.mean_half_period_s,
               log.link_cycles, log.link_mean_half_period_s);
        CHECK(log.crossings == HW_C);
        CHECK_NEAR(log.mean_half_period_s, 0.01, 2e-5);
        CHECK(log.link_cycles == HW_C);
        CHECK_NEAR(log.link_mean_half_period_s, 0.01, 1e-9);
        CHECK(masks_loaded == HW_K);
        CHECK(fake_gpiod_events_left() == 10);
        cap_backend_free(be);
    }
    CHECK(fake_gpiod_open_handles() == 0);
    int st = 0;
    waitpid(child, &st, 0);
    CHECK(WIFEXITED(st) && WEXITSTATUS(st) == 0);
    /* outputs: both idle low, then per frame shutter up/down and a trigger pulse */
    CHECK(fake_gpiod_output_count() == 2 + 4 * HW_K);
    static const int expect[4][2] = {{22, 1}, {22, 0}, {27, 1}, {27, 0}};
    for (int k = 0; k < HW_K; k++)
        for (int j = 0; j < 4; j++) {
            fake_gpiod_output e = fake_gpiod_output_get(2 + 4 * (size_t)k + (size_t)j);
            CHECK_MSG(e.offset == (unsigned)expect[j][0] && e.value == expect[j][1],
                      "output %d of frame %d: line %u value %d", j, k, e.offset, e.value);
        }
    /* the controller saw PING and one CFG per frame: window k of K, C cycles, locked */
    FILE *f = fopen(log_path, "r");
    char line[256];
    int cfg = 0, starts = 0, ping = 0;
    while (f && fgets(line, sizeof line, f)) {
        char want[64];
        snprintf(want, sizeof want, "CFG %d %d %d L\n", HW_K, cfg, HW_C);
        if (!strncmp(line, "CFG", 3)) {
            CHECK_MSG(!strcmp(line, want), "got %s wanted %s", line, want);
            cfg++;
        }
        starts += !strcmp(line, "START\n");
        ping += !strcmp(line, "PING\n");
    }
    if (f) fclose(f);
    CHECK(cfg == HW_K && starts == HW_K && ping == 1);
    /* the frames are the camera's */
    gs_capture cap;
    CHECK_OK(gs_capture_read(out, &cap));
    if (cap.raw) {
        size_t n = (size_t)HW_K * HW_W * HW_H * 3;
        size_t bad = hw_fx_camera_diff(&cap, HW_K, HW_W, HW_H, hw_pixel);
        CHECK_MSG(bad == 0, "%zu of %zu samples differ from the camera's", bad, n);
        CHECK(cap.locked == 1 && cap.utc[0] != '\0');
    }
    gs_capture_release(&cap);
}

/* The kernel queues every crossing of the GPIO line (libgpiod v1 edge events) between two
 * acquisitions, while the frame is read out and written: the acquisition must wait for a new
 * crossing, not take a queued one as the start of its exposure. Frame 0, then 3 crossings
 * queued, then frame 1: frame 1 starts at the crossing after them (start_s against the event
 * file's times), and its exposure's C crossings are the ones logged (stale: 2 crossings read
 * and frame 1's start 3 half periods early). */
TEST(capture_hardware_waits_for_a_new_crossing)
{
    const char *tmp = test_tmpdir();
    char events[1024], log_path[1024];
    snprintf(events, sizeof events, "%s/zc.events", tmp);
    snprintf(log_path, sizeof log_path, "%s/controller.log", tmp);
    size_t n_ev = 2 * (HW_C + 1) + 13;
    CHECK(write_events(events, n_ev));
    CHECK(fake_gpiod_load_events(events, HW_C + 1) == (int)n_ev);
    /* the event file's times, as written */
    double *ts = malloc(n_ev * sizeof *ts);
    FILE *f = fopen(events, "r");
    for (size_t i = 0; f && ts && i < n_ev; i++) {
        long long sec, nsec;
        int type;
        if (fscanf(f, "%lld %lld %d", &sec, &nsec, &type) != 3) break;
        ts[i] = (double)sec + 1e-9 * (double)nsec;
    }
    if (f) fclose(f);
    const char *pattern = hw_fx_camera(2, HW_W, HW_H, hw_pixel);
    int fd = -1;
    pid_t child = start_controller(&fd, log_path);
    CHECK(child > 0);
    cap_hw_config hw;
    hw_fx_config(&hw, pattern, fd, 2, HW_C, HW_W, HW_H);
    cap_backend *be = NULL;
    CHECK_OK(cap_backend_hardware_new(&hw, &be));
    unsigned char *halv = calloc((size_t)HW_W * HW_H, 1);
    unsigned short *raw = malloc(sizeof *raw * (size_t)HW_W * HW_H * 3);
    for (int k = 0; be && ts && halv && raw && k < 2; k++) {
        if (k == 1) fake_gpiod_queue_events(3);
        cap_acquisition a = {k, 0, k, 0, 0};
        CHECK_OK(cap_backend_acquire(be, &a, halv, raw, NULL));
        cap_acq_timing tm;
        cap_hw_log log;
        CHECK_OK(cap_backend_timing(be, &tm));
        CHECK_OK(cap_backend_hardware_log(be, &log));
        size_t first = k == 0 ? 0 : (HW_C + 1) + 3; /* the crossing the exposure waited for */
        double want = ts[first] - ts[0];
        double mean = (ts[first + HW_C] - ts[first + 1]) / (HW_C - 1);
        printf("    frame %d: start %.4f s (its crossing %.4f s), %zu crossings logged, mean "
               "half period %.6f s (%.6f s)\n", k, tm.start_s, want, log.crossings,
               log.mean_half_period_s, mean);
        CHECK_MSG(fabs(tm.start_s - want) < 1e-6, "frame %d starts at %.6f s, its crossing at "
                  "%.6f s", k, tm.start_s, want);
        CHECK(log.crossings == HW_C);
        CHECK_NEAR(log.mean_half_period_s, mean, 1e-9);
    }
    CHECK(fake_gpiod_events_left() == 10);
    free(halv);
    free(raw);
    free(ts);
    cap_backend_free(be);
    int st = 0;
    if (child > 0) waitpid(child, &st, 0);
    CHECK(fake_gpiod_open_handles() == 0);
}

/* Free running, the controller times the windows with the half period it measured before the
 * start (EV START half_ns, the fake's 9.999 ms): the backend reports it for capture.json's
 * window_half_period_s, in the clock of the per-cycle log its grid_hz_measured comes from, and
 * from that log how far the windows moved (window_drift_windows); locked, neither (NaN). */
TEST(capture_hardware_reports_the_free_running_period)
{
    const char *tmp = test_tmpdir();
    char events[1024], log_path[1024], out[1100];
    snprintf(events, sizeof events, "%s/zc.events", tmp);
    snprintf(log_path, sizeof log_path, "%s/controller.log", tmp);
    for (int locked = 0; locked < 2; locked++) {
        cap_hw_config hw;
        pid_t child = start_fakes(events, log_path, &hw);
        hw.locked = locked;
        cap_backend *be = NULL;
        CHECK_OK(cap_backend_hardware_new(&hw, &be));
        snprintf(out, sizeof out, "%s/capture_%d", tmp, locked);
        cap_loop_opts o;
        cap_loop_opts_default(&o);
        o.progress = 0;
        if (be) CHECK_OK(cap_loop_run(be, out, &o, NULL));
        cap_backend_free(be);
        int st = 0;
        if (child > 0) waitpid(child, &st, 0);
        gs_capture cap;
        CHECK_OK(gs_capture_read(out, &cap));
        CHECK(cap.window_period == (locked ? GS_PERIOD_UNKNOWN : GS_PERIOD_MEASURED));   /* (the firmware's) */
        for (int k = 0; cap.frames && k < cap.K; k++) {
            CHECK_NEAR(cap.frames[k].grid_hz_measured, 50.0, 1e-9);   /* the log's mean: 10 ms */
            if (locked) CHECK(isnan(cap.frames[k].window_half_period_s));
            else CHECK_NEAR(cap.frames[k].window_half_period_s, 0.009999, 1e-15);
            /* the log's half periods alternate 10 ms -+ 1.5 us from cycle 0 (the detector's
             * asymmetry): at the crossings of one polarity, even c, the windows are c (P - 10 ms)
             * behind, over half periods of 9.9985 ms; at the end, c = C (even), over the last
             * cycle's 10.0015 ms. (K C |2 P f - 1|, the net motion, is K C 1e-4.) */
            double want = HW_K * fmax((HW_C - 2) * 1e-6 / 9.9985e-3, HW_C * 1e-6 / 10.0015e-3);
            if (locked) CHECK(isnan(cap.frames[k].window_drift_windows));
            else CHECK_NEAR(cap.frames[k].window_drift_windows, want, 1e-9);
        }
        if (cap.frames)
            CHECK_NEAR(gs_capture_window_drift(&cap, NULL),
                       locked ? 0.0 : HW_K * fmax((HW_C - 2) * 1e-6 / 9.9985e-3, HW_C * 1e-6 / 10.0015e-3), 1e-9);
        gs_capture_release(&cap);
    }
    CHECK(fake_gpiod_open_handles() == 0);
}

/* Acquiring frame 0 of W x HW_H with backend be (freed; NULL: nothing) fails with want and a
 * detail holding detail. */
static void expect_acquire_fails(cap_backend *be, int W, gs_status want, const char *detail)
{
    if (!be) return;
    unsigned char *halv = calloc((size_t)W * HW_H, 1);
    unsigned short *raw = malloc(sizeof *raw * (size_t)W * HW_H * 3);
    cap_acquisition a = {0, 0, 0, 0, 0};
    CHECK(cap_backend_acquire(be, &a, halv, raw, NULL) == want);
    CHECK_MSG(strstr(gs_detail(), detail), "%s", gs_detail());
    free(raw);
    free(halv);
    cap_backend_free(be);
}

/* The camera's exposure spans the shutter's opening: the controller's lock (START retried up to
 * its wait) and C half periods at the slowest grid the firmware accepts (its longest full period
 * in ticks of 8 CPU cycles at 16 MHz), without a needless second. It was C / (2 f_nominal) +
 * 0.05 s: C = 1500 at 49.8 Hz already lasts 15.060 s, 0.01 s more. */
TEST(capture_hardware_exposure_spans_the_slowest_grid)
{
    static const long cycles[] = {1, 64, 512, 1500, 100000};
    const struct {
        int hz;
        unsigned max_ticks;
    } grids[] = {{50, FW_P50_MAX_TICKS}, {60, FW_P60_MAX_TICKS}};
    for (size_t g = 0; g < 2; g++)
        for (size_t i = 0; i < sizeof cycles / sizeof *cycles; i++) {
            double tick_s = FW_TICK_CYCLES / 16e6, half_s = 0.5 * grids[g].max_ticks * tick_s;
            double need = CAP_LINK_LOCK_WAIT_MS / 1000.0 + (double)cycles[i] * half_s, e = cap_hw_exposure_s(cycles[i], grids[g].hz, 0.05);
            CHECK_MSG(e >= need + 0.05 && e <= need + 0.05 + 2e-4 * need, "%d Hz, C = %ld: %.6f s for %.6f s",
                      grids[g].hz, cycles[i], e, need);
        }
    double at_49_8 = 1500 / (2 * 49.8);
    CHECK(cap_hw_exposure_s(1500, 50, 0.05) > at_49_8 + CAP_LINK_LOCK_WAIT_MS / 1000.0);
}

/* The exposure went to OpenCV's CAP_PROP_EXPOSURE in seconds whatever the backend: V4L2 passes
 * it to exposure_time_absolute, in 100 us, so an ACam's 5.3 s was 0.53 ms, and the value read
 * back was never looked at. Now V4L2 gets 1e4 units a second (others, of unknown unit, the
 * seconds as before, not read back), and an exposure read back more than 2 % short of the one
 * asked (a camera that clamps it to its range) fails in one line naming both. */
TEST(capture_hardware_exposure_in_the_backends_unit_and_read_back)
{
    CHECK(cap_vio_units_per_s("V4L2") == 1e4);
    CHECK(isnan(cap_vio_units_per_s("CV_IMAGES")) && isnan(cap_vio_units_per_s("")) && isnan(cap_vio_units_per_s(NULL)));
    CHECK_OK(cap_hw_exposure_check("/dev/video0", 5.3, 5.3));
    CHECK_OK(cap_hw_exposure_check("/dev/video0", 5.3, 5.3 * 0.981));
    CHECK_OK(cap_hw_exposure_check("/dev/video0", 5.3, 7.0));   /* longer: still spans the cycles */
    CHECK_OK(cap_hw_exposure_check("/dev/video0", 5.3, NAN));   /* not read back */
    CHECK(cap_hw_exposure_check("/dev/video0", 5.3, 0.5) == GS_ELIMIT);
    CHECK_MSG(strstr(gs_detail(), "camera /dev/video0: exposure 5.3 s asked, it set 0.5 s: outside its range") &&
              !strchr(gs_detail(), '\n'), "%s", gs_detail());
}

TEST(capture_hardware_backend_failures)
{
    const char *tmp = test_tmpdir();
    char events[1024], log_path[1024];
    snprintf(events, sizeof events, "%s/zc.events", tmp);
    snprintf(log_path, sizeof log_path, "%s/controller.log", tmp);
    const char *pattern = hw_fx_camera(HW_K, HW_W, HW_H, hw_pixel);
    cap_hw_config hw;
    cap_hw_config_default(&hw);
    hw.camera = pattern;
    hw.camera_images = 1;
    hw.gpio_chip = "missing";
    hw.zc_line = 17;
    hw.width = HW_W;
    hw.height = HW_H;
    hw.bands = 3;
    hw.K = HW_K;
    hw.cycles = HW_C;
    int fd;
    pid_t child = start_controller(&fd, log_path);
    hw.serial_fd = fd;
    cap_backend *be = NULL;
    CHECK(cap_backend_hardware_new(&hw, &be) == GS_EIO && !be);
    CHECK_MSG(strstr(gs_detail(), "gpio chip missing"), "%s", gs_detail());
    waitpid(child, NULL, 0);
    /* no crossings at all: the mains is not sensed */
    FILE *f = fopen(events, "w");
    fclose(f);
    CHECK(fake_gpiod_load_events(events, 10) == 0);
    child = start_controller(&fd, log_path);
    hw.serial_fd = fd;
    hw.gpio_chip = "gpiochip0";
    CHECK_OK(cap_backend_hardware_new(&hw, &be));
    expect_acquire_fails(be, HW_W, GS_EIO, "no mains zero crossing on gpio line 17");
    waitpid(child, NULL, 0);
    /* a wrong camera size */
    CHECK(write_events(events, 200));
    CHECK(fake_gpiod_load_events(events, 60) == 200);
    child = start_controller(&fd, log_path);
    hw.serial_fd = fd;
    hw.width = HW_W + 1;
    CHECK_OK(cap_backend_hardware_new(&hw, &be));
    expect_acquire_fails(be, HW_W + 1, GS_EFORMAT, "expected 33x24");
    waitpid(child, NULL, 0);
    CHECK(fake_gpiod_open_handles() == 0);
}

/* The camera plugin (capture/videoio.c): found in the installed layout BIN/../lib/gridsurvey/
 * when it is not beside the binary, and working from there; one line naming both places when it
 * is in neither, and the missing entry points when the file there is another library. */
TEST(capture_camera_plugin_installed_layout_and_load_errors)
{
    const char *tmp = test_tmpdir();
    const char *gsbin = test_bin(), *slash = strrchr(gsbin, '/');
    int dir_len = slash ? (int)(slash - gsbin) : 1;
    char built[1200], bin[1200], lib[1200], installed[1300], cmd[5000];
    snprintf(built, sizeof built, "%.*s/gridsurvey-videoio.so", dir_len, slash ? gsbin : ".");
    snprintf(bin, sizeof bin, "%s/prefix/bin", tmp);
    snprintf(lib, sizeof lib, "%s/prefix/lib/gridsurvey", tmp);
    snprintf(installed, sizeof installed, "%s/gridsurvey-videoio.so", lib);
    /* a link, not a copy: the same file as the built plugin, so not a second copy in the process */
    snprintf(cmd, sizeof cmd, "mkdir -p '%s' '%s' && ln -s \"$(realpath '%s')\" '%s'", bin, lib, built,
             installed);
    CHECK(system(cmd) == 0);

    cap_vio_api api;
    CHECK_OK(cap_vio_plugin_load(bin, &api));
    if (api.handle) {
        const char *pattern = hw_fx_camera(HW_K, HW_W, HW_H, hw_pixel);
        cap_vio *v = NULL;
        CHECK_OK(api.open(pattern, 1, &v));
        unsigned short *raw = malloc(sizeof *raw * HW_W * HW_H * 3);
        if (v && raw) {
            CHECK_OK(api.read(v, HW_W, HW_H, 3, raw));
            size_t bad = 0;
            for (int y = 0; y < HW_H; y++)
                for (int x = 0; x < HW_W; x++)
                    for (int b = 0; b < 3; b++)
                        bad += raw[((size_t)y * HW_W + (size_t)x) * 3 + (size_t)b] != hw_pixel(0, x, y, b);
            CHECK_MSG(bad == 0, "%zu samples of frame 0 differ from the camera's", bad);
            CHECK(api.read(v, HW_W + 1, HW_H, 3, raw) == GS_EFORMAT);
            /* its backend's name: an image sequence's, whose exposure unit is unknown */
            const char *be = api.backend(v);
            CHECK_MSG(be && *be && isnan(cap_vio_units_per_s(be)), "backend '%s'", be ? be : "(null)");
        }
        free(raw);
        if (v) api.close(v);
        dlclose(api.handle);
    }

    /* in neither place: both named, each with its reason. Another prefix: a plugin loaded once
     * may stay loaded (dlclose need not unload it), and dlopen matches loaded objects by path. */
    snprintf(bin, sizeof bin, "%s/prefix2/bin", tmp);
    snprintf(lib, sizeof lib, "%s/prefix2/lib/gridsurvey", tmp);
    snprintf(installed, sizeof installed, "%s/gridsurvey-videoio.so", lib);
    snprintf(cmd, sizeof cmd, "mkdir -p '%s' '%s'", bin, lib);
    CHECK(system(cmd) == 0);
    CHECK(cap_vio_plugin_load(bin, &api) == GS_EIO && !api.open);
    const char *d = gs_detail();
    CHECK_MSG(strstr(d, "cannot load the OpenCV camera plugin") && strstr(d, bin) &&
              strstr(d, "/../lib/gridsurvey/gridsurvey-videoio.so") && !strchr(d, '\n'), "%s", d);
    /* not a library */
    FILE *f = fopen(installed, "w");
    if (f) {
        fputs("not an ELF file\n", f);
        fclose(f);
    }
    CHECK(cap_vio_plugin_load(bin, &api) == GS_EIO);
    CHECK_MSG(strstr(gs_detail(), "invalid ELF header") || strstr(gs_detail(), "too short"), "%s", gs_detail());
    /* a library without the entry points: SQLite's */
    Dl_info info;
    void *sym = dlsym(RTLD_DEFAULT, "sqlite3_libversion");
    CHECK(sym && dladdr(sym, &info) && info.dli_fname);
    snprintf(cmd, sizeof cmd, "cp '%s' '%s'", info.dli_fname, installed);
    CHECK(system(cmd) == 0);
    CHECK(cap_vio_plugin_load(bin, &api) == GS_EIO && !api.handle);
    CHECK_MSG(strstr(gs_detail(), "lacks its entry points"), "%s", gs_detail());
}
