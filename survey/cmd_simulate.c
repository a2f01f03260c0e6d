/* cmd_simulate.c - `gridsurvey simulate`: render a scene (gridsurvey-scene/1, docs/scene.md)
 * into a capture directory (docs/formats.md) plus truth.json, through the acquisition loop with
 * the `sim` backend (docs/capture.md). Seeded and deterministic; an interrupted run resumes. */
#include "survey/internal.h"
#include "capture/capture.h"

#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char simulate_usage[] =
    "usage: gridsurvey simulate SCENE.json --out-dir CAPDIR [--seed N] [--delight DB]\n"
    "                           [--force] [--stop-after N] [--progress | --no-progress | -q]\n"
    "                           [--stats] [--drop-light ID ...]\n"
    "\n"
    "Renders the scene's K frames as the ACam would acquire them (coded exposure over C\n"
    "cycles, mask matrix, HDR halving, the effects the scene lists) into CAPDIR: capture.json,\n"
    "frame_NNN.png (16-bit), hdr_NNN.png when HDR is on, truth.json (every light's pixel,\n"
    "position, bulb and phase) and acquisition.json (resume state). Running it again on an\n"
    "interrupted CAPDIR keeps the intact frames and renders the rest; the result is the same\n"
    "as an uninterrupted run.\n"
    "\n"
    "  --out-dir CAPDIR   the capture directory (created)\n"
    "  --seed N           override the scene's seed\n"
    "  --delight DB       DELIGHT SQLite file (default: the scene's, else the built-in database)\n"
    "  --force            start again even if CAPDIR holds progress of this scene\n"
    "  --stop-after N     stop after rendering N frames (resume later)\n"
    "  --progress         progress on stderr (default: when stderr is a terminal)\n"
    "  -q, --no-progress  no progress\n"
    "  --stats            print the pipeline's stages with their calls and time\n"
    "  --drop-light ID    render the scene without this light (repeatable; e.g. the reference\n"
    "                     for `gridsurvey relight` switching a source off)\n"
    "  --help             this text\n"
    "\n"
    "Built-in scenes: capture/scenes/lab.json, capture/scenes/metro.json (docs/scene.md).\n"
    "\n"
    "Examples:\n"
    "  gridsurvey simulate capture/scenes/lab.json --out-dir build/lab\n"
    "  gridsurvey simulate capture/scenes/lab.json --out-dir build/lab-no-mh70 --drop-light mh70\n";

static void print_stats(cap_sim *sim)
{
    printf("%-20s %10s %14s %10s\n", "stage", "calls", "items", "seconds");
    for (size_t i = 0; i < cap_sim_stage_count(sim); i++) {
        cap_stage_info si;
        if (cap_sim_stage(sim, i, &si) != GS_OK) continue;
        printf("%-20s %10llu %14llu %10.3f%s\n", si.name, si.calls, si.items, si.seconds,
               si.effect >= 0 ? "  (effect)" : "");
    }
}

int srv_cmd_simulate(int argc, char **argv)
{
    static const struct option longs[] = {
        {"out-dir", required_argument, 0, 'O'}, {"seed", required_argument, 0, 's'},
        {"delight", required_argument, 0, 'd'}, {"force", no_argument, 0, 'f'},
        {"stop-after", required_argument, 0, 'S'}, {"progress", no_argument, 0, 'p'},
        {"no-progress", no_argument, 0, 'n'},   {"stats", no_argument, 0, 't'},
        {"drop-light", required_argument, 0, 'x'},
        {"help", no_argument, 0, 'h'},          {0, 0, 0, 0},
    };
    const char *out = NULL, *delight = NULL;
    const char *drop[64];
    int ndrop = 0;
    unsigned long long seed = 0, stop = 0;
    int seed_given = 0;
    int stats = 0;
    cap_loop_opts lo;
    cap_loop_opts_default(&lo);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "o:hq", longs, NULL)) != -1) {
        switch (c) {
        case 'O': out = optarg; break;
        case 'o': return srv_out_dir_hint("simulate");
        case 'd': delight = optarg; break;
        case 'f': lo.force = 1; break;
        case 'p': lo.progress = 1; break;
        case 'n':
        case 'q': lo.progress = 0; break;
        case 't': stats = 1; break;
        case 'x':
            if (ndrop == 64) return srv_usage_error("simulate", "at most 64 --drop-light");
            drop[ndrop++] = optarg;
            break;
        case 's':
            if (!srv_int_arg("simulate", "--seed", optarg, 0, 0x7fffffff, &seed)) return 2;
            seed_given = 1;
            break;
        case 'S':
            if (!srv_int_arg("simulate", "--stop-after", optarg, 1, 1 << 20, &stop)) return 2;
            lo.stop_after = (int)stop;
            break;
        case 'h': fputs(simulate_usage, stdout); return 0;
        default: return srv_usage_hint("simulate", argv);
        }
    }
    if (optind + 1 != argc || !out) return srv_usage_error("simulate", "expected one SCENE.json and --out-dir CAPDIR");
    cap_scene sc;
    gs_status s = cap_scene_read(argv[optind], &sc);
    if (s != GS_OK) {
        cap_scene_release(&sc);
        return srv_error("simulate", s);
    }
    for (int i = 0; i < ndrop; i++) {
        size_t j = 0;
        while (j < sc.n_lights && strcmp(sc.lights[j].id, drop[i])) j++;
        if (j == sc.n_lights) {
            cap_scene_release(&sc);
            return srv_usage_error("simulate", "--drop-light %s: %s has no light with this id", drop[i], argv[optind]);
        }
        memmove(&sc.lights[j], &sc.lights[j + 1], (sc.n_lights - j - 1) * sizeof *sc.lights);
        sc.n_lights--;
    }
    if (seed_given) {
        sc.seed = seed;
        sc.freq.seed = sc.seed;
    }
    if (delight) {
        if (strlen(delight) >= sizeof sc.delight) {
            cap_scene_release(&sc);
            return srv_usage_error("simulate", "--delight: path too long (at most %zu bytes)", sizeof sc.delight - 1);
        }
        snprintf(sc.delight, sizeof sc.delight, "%s", delight);
    }
    cap_backend *be = NULL;
    s = cap_backend_sim_new(&sc, NULL, &be);
    size_t in_image = 0;
    for (size_t i = 0; i < sc.n_lights; i++) in_image += sc.lights[i].in_image != 0;
    cap_scene_release(&sc);
    if (s != GS_OK) return srv_error("simulate", s);
    cap_sim *sim = cap_backend_sim_handle(be);
    cap_loop_report rep;
    s = cap_loop_run(be, out, &lo, &rep);
    /* after the loop: a directory holding another configuration keeps its truth */
    if (s == GS_OK) s = cap_sim_write_truth(sim, out);
    if (s == GS_OK) {
        const cap_scene *ss = cap_sim_scene(sim);
        if (rep.complete)
            printf("simulate: %s: wrote %d frames (%d rendered, %d kept), %zu lights in the image, "
                   "%ld acquisitions, %.2f s\n", out, ss->acam.K, rep.frames_acquired, rep.frames_kept,
                   in_image, rep.acquisitions, rep.seconds);
        else
            printf("simulate: %s: stopped with %d of %d frames (%d rendered, %d kept): the same command "
                   "resumes; %zu lights in the image, %ld acquisitions, %.2f s\n", out,
                   rep.frames_acquired + rep.frames_kept, ss->acam.K, rep.frames_acquired, rep.frames_kept,
                   in_image, rep.acquisitions, rep.seconds);
        if (stats) print_stats(sim);
    }
    cap_backend_free(be);
    return s == GS_OK ? 0 : srv_error("simulate", s);
}
