/* cmd_capture.c - `gridsurvey capture`: the ACam acquisition loop (docs/capture.md) with one of
 * its backends: sim (a scene), replay (a capture directory) or hardware (camera + GPIO +
 * controller). Frames are written as acquired; an interrupted capture resumes. */
#include "survey/internal.h"
#include "capture/capture.h"

#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char capture_usage[] =
    "usage: gridsurvey capture --backend sim|replay|hardware --out-dir CAPDIR [OPTIONS]\n"
    "\n"
    "  sim:       --scene SCENE.json [--seed N]          render a scene (also writes truth.json)\n"
    "  replay:    --from CAPDIR                           serve an existing capture's frames\n"
    "  hardware:  --camera SRC [--camera-images]          OpenCV VideoCapture source (index, path,\n"
    "                                                     or an image-sequence pattern)\n"
    "             --serial TTY                            the ACam controller (firmware/)\n"
    "             [--gpio-chip CHIP --zc-line N]          mains zero crossings (libgpiod)\n"
    "             [--shutter-line N] [--trigger-line N]   camera shutter gate and trigger\n"
    "             --width W --height H [--bands 1|3]\n"
    "             [--grid 50|60] [--K K] [--cycles C] [--masks M] [--free-running]\n"
    "             [--saturation DN] [--black-level DN] [--gain E] [--read-noise DN]\n"
    "  common:    [--hdr | --no-hdr] [--max-rounds N] [--max-saturated N]\n"
    "             [--stop-after N] [--force] [--progress | --no-progress | -q]\n"
    "\n"
    "  --hdr, --no-hdr    HDR (paper Sec. 6: a frame with saturated pixels is acquired again\n"
    "                     with their exposures halved) on or off (default: the scene's acam.hdr;\n"
    "                     replay serves the capture's own HDR maps; hardware: off)\n"
    "  --max-rounds N     HDR rounds per frame, at most the exact halvings of M/2 (default: the\n"
    "                     scene's; 0 = as many as the masks allow)\n"
    "  --max-saturated N  HDR stops once at most N pixels saturate (default: the scene's, 0)\n"
    "  --free-running     hardware: windows timed with the half period measured before each\n"
    "                     exposure instead of re-anchored at every crossing (paper Sec. 6, Fig. 9);\n"
    "                     capture.json records it and how far the windows moved\n"
    "                     (window_half_period_s, window_drift_windows; window_period\n"
    "                     measured), and recognition keeps every frame by default, raising\n"
    "                     each one's noise by its smear (docs/recognition.md)\n"
    "  --stop-after N     stop after acquiring N frames (run again to resume)\n"
    "  --force            start again even if CAPDIR holds an acquisition of another\n"
    "                     configuration\n"
    "\n"
    "An option of another backend than --backend's is a usage error (sim and replay take the\n"
    "camera and the ACam's numbers from the scene or the capture).\n"
    "\n"
    "Frames go to CAPDIR as they are acquired; running the same command again resumes an\n"
    "interrupted capture (acquisition.json) and re-acquires only missing or damaged frames.\n"
    "The hardware backend needs a DMD mask loader for HDR (not available from this command).\n"
    "\n"
    "Examples:\n"
    "  gridsurvey capture --backend sim --scene capture/scenes/lab.json --out-dir build/lab\n"
    "  gridsurvey capture --backend replay --from build/lab --out-dir build/lab-copy\n"
    "  gridsurvey capture --backend hardware --camera 0 --serial /dev/ttyACM0 --width 1920 \\\n"
    "                     --height 1080 --bands 3 --grid 50 --out-dir night-01\n";

/* The backends, and the options (their getopt values below) that only each of them uses. */
enum { SIM, REPLAY, HARDWARE, BACKENDS };
static const char *const backends[BACKENDS] = {"sim", "replay", "hardware"};
static const char *const backend_opts[BACKENDS] = {"sS", "F", "cITgzutWHBGKCMfalnr"};

int srv_cmd_capture(int argc, char **argv)
{
    static const struct option longs[] = {
        {"backend", required_argument, 0, 'b'}, {"out-dir", required_argument, 0, 'O'},
        {"scene", required_argument, 0, 's'},   {"seed", required_argument, 0, 'S'},
        {"from", required_argument, 0, 'F'},    {"camera", required_argument, 0, 'c'},
        {"camera-images", no_argument, 0, 'I'}, {"serial", required_argument, 0, 'T'},
        {"gpio-chip", required_argument, 0, 'g'}, {"zc-line", required_argument, 0, 'z'},
        {"shutter-line", required_argument, 0, 'u'}, {"trigger-line", required_argument, 0, 't'},
        {"width", required_argument, 0, 'W'},   {"height", required_argument, 0, 'H'},
        {"bands", required_argument, 0, 'B'},   {"grid", required_argument, 0, 'G'},
        {"K", required_argument, 0, 'K'},       {"cycles", required_argument, 0, 'C'},
        {"masks", required_argument, 0, 'M'},   {"free-running", no_argument, 0, 'f'},
        {"saturation", required_argument, 0, 'a'}, {"black-level", required_argument, 0, 'l'},
        {"gain", required_argument, 0, 'n'},    {"read-noise", required_argument, 0, 'r'},
        {"hdr", no_argument, 0, 'x'},           {"no-hdr", no_argument, 0, 'X'},
        {"max-rounds", required_argument, 0, 'R'}, {"max-saturated", required_argument, 0, 'm'},
        {"stop-after", required_argument, 0, 'A'}, {"force", no_argument, 0, 'E'},
        {"progress", no_argument, 0, 'p'},      {"no-progress", no_argument, 0, 'P'},
        {"help", no_argument, 0, 'h'},          {0, 0, 0, 0},
    };
    const char *backend = NULL, *out = NULL, *scene = NULL, *from = NULL;
    const char *given[BACKENDS] = {NULL};   /* each backend's first option given, by name */
    double seed = -1;
    unsigned long long u;
    cap_hw_config hw;
    cap_hw_config_default(&hw);
    cap_loop_opts lo;
    cap_loop_opts_default(&lo);
    optind = 1;
    int c, li = 0;
    while ((c = getopt_long(argc, argv, "o:hq", longs, &li)) != -1) {
        for (int b = 0; b < BACKENDS; b++)
            if (!given[b] && strchr(backend_opts[b], c)) given[b] = longs[li].name;
        switch (c) {
        case 'b': backend = optarg; break;
        case 'O': out = optarg; break;
        case 'o': return srv_out_dir_hint("capture");
        case 's': scene = optarg; break;
        case 'F': from = optarg; break;
        case 'c': hw.camera = optarg; break;
        case 'I': hw.camera_images = 1; break;
        case 'T': hw.serial = optarg; break;
        case 'g': hw.gpio_chip = optarg; break;
        case 'f': hw.locked = 0; break;
        case 'x': lo.hdr = 1; break;
        case 'X': lo.hdr = 0; break;
        case 'E': lo.force = 1; break;
        case 'p': lo.progress = 1; break;
        case 'P':
        case 'q': lo.progress = 0; break;
        case 'S': if (!srv_int_arg("capture", "--seed", optarg, 0, 2147483647, &u)) return 2; seed = (double)u; break;
        case 'z': if (!srv_int_arg("capture", "--zc-line", optarg, 0, 1023, &u)) return 2; hw.zc_line = (int)u; break;
        case 'u': if (!srv_int_arg("capture", "--shutter-line", optarg, 0, 1023, &u)) return 2; hw.shutter_line = (int)u; break;
        case 't': if (!srv_int_arg("capture", "--trigger-line", optarg, 0, 1023, &u)) return 2; hw.trigger_line = (int)u; break;
        case 'W': if (!srv_int_arg("capture", "--width", optarg, 1, 32768, &u)) return 2; hw.width = (int)u; break;
        case 'H': if (!srv_int_arg("capture", "--height", optarg, 1, 32768, &u)) return 2; hw.height = (int)u; break;
        case 'B': if (!srv_choice_arg("capture", "--bands", optarg, 1, 3, &hw.bands)) return 2; break;
        case 'G': if (!srv_choice_arg("capture", "--grid", optarg, 50, 60, &hw.grid_hz)) return 2; break;
        case 'K': if (!srv_int_arg("capture", "--K", optarg, 2, 1024, &u)) return 2; hw.K = (int)u; break;
        case 'C': if (!srv_int_arg("capture", "--cycles", optarg, 1, 1000000, &u)) return 2; hw.cycles = (long)u; break;
        case 'M': if (!srv_int_arg("capture", "--masks", optarg, 2, 1000, &u)) return 2; hw.masks = (int)u; break;
        case 'a': if (!srv_num_arg("capture", "--saturation", optarg, 1, 65536, &hw.saturation_dn)) return 2; break;
        case 'l': if (!srv_num_arg("capture", "--black-level", optarg, 0, 65535, &hw.black_level_dn)) return 2; break;
        case 'n': if (!srv_num_arg("capture", "--gain", optarg, 0, 1e6, &hw.gain_e_per_dn)) return 2; break;
        case 'r': if (!srv_num_arg("capture", "--read-noise", optarg, 0, 1e6, &hw.read_noise_dn)) return 2; break;
        case 'R': if (!srv_int_arg("capture", "--max-rounds", optarg, 0, 16, &u)) return 2; lo.hdr_max_rounds = (int)u; break;
        case 'm': if (!srv_int_arg("capture", "--max-saturated", optarg, 0, 1000000000, &u)) return 2; lo.hdr_max_saturated_px = (int)u; break;
        case 'A': if (!srv_int_arg("capture", "--stop-after", optarg, 1, 1048576, &u)) return 2; lo.stop_after = (int)u; break;
        case 'h': fputs(capture_usage, stdout); return 0;
        default: return srv_usage_hint("capture", argv);
        }
    }
    if (optind < argc) return srv_usage_error("capture", "unexpected argument '%s'", argv[optind]);
    if (!backend || !out) return srv_usage_error("capture", "--backend and --out-dir are required");
    int which = 0;
    while (which < BACKENDS && strcmp(backend, backends[which])) which++;
    if (which == BACKENDS)
        return srv_usage_error("capture", "--backend '%s': expected sim, replay or hardware", backend);
    for (int b = 0; b < BACKENDS; b++)
        if (given[b] && b != which)
            return srv_usage_error("capture", "--%s is an option of the %s backend, not of --backend %s",
                                   given[b], backends[b], backend);
    cap_backend *be = NULL;
    gs_status s;
    if (which == SIM) {
        if (!scene) return srv_usage_error("capture", "--backend sim needs --scene");
        cap_scene sc;
        s = cap_scene_read(scene, &sc);
        if (s == GS_OK && seed >= 0) {
            sc.seed = (unsigned long long)seed;
            sc.freq.seed = sc.seed;
        }
        if (s == GS_OK) s = cap_backend_sim_new(&sc, NULL, &be);
        cap_scene_release(&sc);
    } else if (which == REPLAY) {
        if (!from) return srv_usage_error("capture", "--backend replay needs --from CAPDIR");
        s = cap_backend_replay_new(from, &be);
    } else {
        if (!hw.camera || !hw.serial || !hw.width || !hw.height)
            return srv_usage_error("capture", "--backend hardware needs --camera, --serial, --width and --height");
        if (lo.hdr == 1)
            return srv_usage_error("capture", "--hdr: the hardware backend needs a DMD mask loader, "
                                   "which this command does not have");
        s = cap_backend_hardware_new(&hw, &be);
    }
    if (s != GS_OK) return srv_error("capture", s);
    cap_loop_report rep;
    s = cap_loop_run(be, out, &lo, &rep);
    if (s == GS_OK && which == SIM) s = cap_sim_write_truth(cap_backend_sim_handle(be), out);
    if (s == GS_OK)
        printf("capture (%s): %s: %s, %d frames acquired, %d kept, %ld acquisitions, %.2f s\n",
               backend, out, rep.complete ? "complete" : "partial", rep.frames_acquired,
               rep.frames_kept, rep.acquisitions, rep.seconds);
    cap_backend_free(be);
    return s == GS_OK ? 0 : srv_error("capture", s);
}
