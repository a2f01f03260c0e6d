/* bench_render.c - `gridsurvey bench render`: the simulator's render time per frame on a
 * built-in scene with no effect, each listed effect alone, and all of them, showing that the
 * time grows only with the effects enabled (docs/capture.md: one stage per listed effect). */
#include "capture/capture.h"
#include "survey/internal.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

gs_status srv_render_time(const cap_scene *sc, unsigned effects_mask, int frames, int threads,
                          srv_render_time_result *out)
{
    memset(out, 0, sizeof *out);
    if (frames < 1) return gs_fail(GS_EINVAL, "bench: %d frames", frames);
    cap_scene tmp = *sc;
    tmp.fx.enabled &= effects_mask;
    if (!((tmp.fx.enabled >> CAP_FX_READ_NOISE) & 1)) tmp.fx.read_noise.sigma_e = 0;
    cap_sim *s = NULL;
    gs_status st = cap_sim_new(&tmp, NULL, &s);
    if (st != GS_OK) return st;
    cap_sim_set_threads(s, threads);
    int K = sc->acam.K;
    size_t npx = (size_t)sc->cam.width_px * (size_t)sc->cam.height_px;
    unsigned short *raw = malloc(npx * (size_t)sc->bands * sizeof *raw);
    if (!raw) {
        cap_sim_free(s);
        return gs_fail(GS_ENOMEM, "bench: out of memory");
    }
    double t0 = gs_clock_s(CLOCK_MONOTONIC), c0 = gs_clock_s(CLOCK_PROCESS_CPUTIME_ID);
    for (int i = 0; i < frames && st == GS_OK; i++) st = cap_sim_render(s, i % K, 0, i, NULL, raw, NULL);
    double dt = gs_clock_s(CLOCK_MONOTONIC) - t0, dc = gs_clock_s(CLOCK_PROCESS_CPUTIME_ID) - c0;
    out->frames = frames;
    out->seconds_per_frame = dt / frames;
    out->cpu_seconds_per_frame = dc / frames;
    out->effects = tmp.fx.enabled;
    out->lights = sc->n_lights;
    out->pixels = npx;
    free(raw);
    cap_sim_free(s);
    return st;
}

/* One row: the 1-thread wall and CPU time (and the wall's ratio to no effects), the n-thread
 * wall and CPU times. */
static void print_row(const char *name, const srv_render_time_result *none,
                      const srv_render_time_result *one, const srv_render_time_result *n)
{
    printf("| %s | %.4f | %.4f | %.1f | %.4f | %.4f | %.2f |\n", name, one->seconds_per_frame,
           one->cpu_seconds_per_frame, one->seconds_per_frame / none->seconds_per_frame,
           n->seconds_per_frame, n->cpu_seconds_per_frame,
           one->seconds_per_frame / n->seconds_per_frame);
}

static const char render_usage[] =
    "usage: gridsurvey bench render [SCENE.json] [--frames N]\n"
    "\n"
    "Renders N acquisitions (default 3) of SCENE (default capture/scenes/metro.json) with no\n"
    "effect, with each effect the scene lists alone, and with all of them, on one thread and on\n"
    "the online CPUs, and prints the wall and CPU time per frame as a Markdown table.\n"
    "\n"
    "Example:\n"
    "  gridsurvey bench render capture/scenes/lab.json --frames 1\n";

int srv_bench_render(int argc, char **argv)
{
    const char *path = "capture/scenes/metro.json";
    int frames = 3;
    unsigned long long v;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
            fputs(render_usage, stdout);
            return 0;
        }
        if (!strcmp(argv[i], "--frames") && i + 1 < argc) {
            if (!srv_int_arg("bench render", "--frames", argv[++i], 1, 1000, &v)) return 2;
            frames = (int)v;
        } else if (argv[i][0] == '-') {
            return srv_usage_error("bench render", "unknown option or missing value: '%s'", argv[i]);
        } else {
            path = argv[i];
        }
    }
    cap_scene sc;
    gs_status s = cap_scene_read(path, &sc);
    if (s != GS_OK) {
        cap_scene_release(&sc);
        return srv_error("bench render", s);
    }
    int nt = gs_threads_resolve(0);
    printf("# Simulator render time (`gridsurvey bench render`)\n\n"
           "Scene `%s`: %zu lights, %d x %d pixels, %d bands; %d acquisitions per row, seconds "
           "per frame on 1 thread and on %d (the online CPUs; the frames are the same bits, "
           "tests/test_capture_sim.c), wall and CPU (all threads). Only the effects in a row run "
           "(docs/capture.md). The machine's other load shows as wall > CPU / threads.\n\n"
           "| effects | 1 thread, wall s | 1 thread, CPU s | x no-effect time | %d threads, wall s | "
           "%d threads, CPU s | wall speed-up |\n|---|---:|---:|---:|---:|---:|---:|\n",
           path, sc.n_lights, sc.cam.width_px, sc.cam.height_px, sc.bands, frames, nt, nt, nt);
    srv_render_time_result none, none_n;
    s = srv_render_time(&sc, 0, frames, 1, &none);
    if (s == GS_OK) s = srv_render_time(&sc, 0, frames, nt, &none_n);
    if (s == GS_OK) print_row("none", &none, &none, &none_n);
    for (int e = 0; e < CAP_FX_COUNT && s == GS_OK; e++) {
        if (!(sc.fx.enabled & (1u << e))) continue;
        srv_render_time_result one, one_n;
        s = srv_render_time(&sc, 1u << e, frames, 1, &one);
        if (s == GS_OK) s = srv_render_time(&sc, 1u << e, frames, nt, &one_n);
        if (s == GS_OK) print_row(cap_effect_name((cap_effect)e), &none, &one, &one_n);
    }
    srv_render_time_result all, all_n;
    if (s == GS_OK) s = srv_render_time(&sc, ~0u, frames, 1, &all);
    if (s == GS_OK) s = srv_render_time(&sc, ~0u, frames, nt, &all_n);
    if (s == GS_OK) print_row("all listed", &none, &all, &all_n);
    cap_scene_release(&sc);
    return s == GS_OK ? 0 : srv_error("bench render", s);
}
