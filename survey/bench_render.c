/* bench_render.c - `gridsurvey bench render`: the simulator's render time per frame on a
 * built-in scene with no effect, each listed effect alone, and all of them, showing that the
 * time grows only with the effects enabled (docs/capture.md: one stage per listed effect). */
#include "capture/capture.h"
#include "survey/internal.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

gs_status srv_render_time(const cap_scene *sc, unsigned effects_mask, int frames,
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
    int K = sc->acam.K;
    size_t npx = (size_t)sc->cam.width_px * (size_t)sc->cam.height_px;
    unsigned short *raw = malloc(npx * (size_t)sc->bands * sizeof *raw);
    if (!raw) {
        cap_sim_free(s);
        return gs_fail(GS_ENOMEM, "bench: out of memory");
    }
    double t0 = now_s();
    for (int i = 0; i < frames && st == GS_OK; i++) st = cap_sim_render(s, i % K, 0, i, NULL, raw, NULL);
    double dt = now_s() - t0;
    out->frames = frames;
    out->seconds_per_frame = dt / frames;
    out->effects = tmp.fx.enabled;
    out->lights = sc->n_lights;
    out->pixels = npx;
    free(raw);
    cap_sim_free(s);
    return st;
}

static const char render_usage[] =
    "usage: gridsurvey bench render [SCENE.json] [--frames N]\n"
    "\n"
    "Renders N acquisitions (default 3) of SCENE (default capture/scenes/metro.json) with no\n"
    "effect, with each effect the scene lists alone, and with all of them, and prints the wall\n"
    "time per frame as a Markdown table.\n";

int srv_bench_render(int argc, char **argv)
{
    const char *path = "capture/scenes/metro.json";
    int frames = 3;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
            fputs(render_usage, stdout);
            return 0;
        }
        if (!strcmp(argv[i], "--frames") && i + 1 < argc) {
            if (sscanf(argv[++i], "%d", &frames) != 1 || frames < 1 || frames > 1000) {
                fprintf(stderr, "gridsurvey bench render: --frames '%s': expected 1..1000\n", argv[i]);
                return 2;
            }
        } else if (argv[i][0] == '-') {
            fputs(render_usage, stderr);
            return 2;
        } else {
            path = argv[i];
        }
    }
    cap_scene sc;
    gs_status s = cap_scene_read(path, &sc);
    if (s != GS_OK) {
        cap_scene_release(&sc);
        return srv_error(s);
    }
    printf("# Simulator render time (`gridsurvey bench render`)\n\n"
           "Scene `%s`: %zu lights, %d x %d pixels, %d bands; %d acquisitions per row, wall "
           "seconds per frame. Only the effects in a row run (docs/capture.md).\n\n"
           "| effects | seconds per frame | x no-effect time |\n|---|---:|---:|\n",
           path, sc.n_lights, sc.cam.width_px, sc.cam.height_px, sc.bands, frames);
    srv_render_time_result none;
    s = srv_render_time(&sc, 0, frames, &none);
    if (s == GS_OK) printf("| none | %.4f | 1.0 |\n", none.seconds_per_frame);
    for (int e = 0; e < CAP_FX_COUNT && s == GS_OK; e++) {
        if (!(sc.fx.enabled & (1u << e))) continue;
        srv_render_time_result one;
        s = srv_render_time(&sc, 1u << e, frames, &one);
        if (s == GS_OK)
            printf("| %s | %.4f | %.1f |\n", cap_effect_name((cap_effect)e), one.seconds_per_frame,
                   one.seconds_per_frame / none.seconds_per_frame);
    }
    srv_render_time_result all;
    if (s == GS_OK) s = srv_render_time(&sc, ~0u, frames, &all);
    if (s == GS_OK)
        printf("| all listed | %.4f | %.1f |\n", all.seconds_per_frame,
               all.seconds_per_frame / none.seconds_per_frame);
    cap_scene_release(&sc);
    return s == GS_OK ? 0 : srv_error(s);
}
