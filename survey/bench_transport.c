/* bench_transport.c - `gridsurvey bench transport`: the time of light-transport unmixing (paper
 * Sec. 5.1, rec_unmix: Eq. 16, Eq. 18, Eq. 16 again) on one core for captures of 1 megapixel
 * RGB with K = 26 and S = 5 (the target: under 10 s) and smaller ones, as a Markdown
 * table (make bench keeps it in docs/bench-transport.md). The captures are synthetic: smooth
 * random transport images times the DELIGHT BRFs of five bulbs on the three phases, with the
 * camera's noise (Gaussian, of the capture's noise model) and every 50th pixel four times
 * brighter (bulbs in view), some of them saturating in their brightest frames, so the timing
 * includes the discarded-sample path. */
#include "survey/internal.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static const rec_source_spec bench_sources[5] = {
    {"inc-a60-25w-230v", 0}, {"cfl-23w", 120}, {"led-fil-4w-lin", 240}, {"fl-t8-36w-tri", 0},
    {"mh-70w", 240}};

/* A synthetic capture of W x H x 3, K = 26, C = 256 lit by src; the truth tau Q in tq. */
static gs_status synth(const rec_sources *src, int W, int H, gs_capture *cap, float *tq)
{
    memset(cap, 0, sizeof *cap);
    cap->grid_hz = 50;
    cap->K = src->K;
    cap->bands = 3;
    cap->width = W;
    cap->height = H;
    cap->saturation_dn = 4060;
    cap->black_level_dn = 64;
    cap->gain_e_per_dn = 5;
    cap->read_noise_dn = 0.8;
    cap->locked = 1;
    gs_status st = gs_capture_alloc(cap);
    if (st != GS_OK) return st;
    size_t P = (size_t)W * H;
    int S = src->S, K = src->K;
    uint64_t seed = 14;
    for (int k = 0; k < K; k++) cap->frames[k].cycles = 256;
    /* each source: a smooth field (a few random bumps) of up to ~3 DN per cycle */
    for (int s = 0; s < S; s++) {
        double cx[4], cy[4], a[4];
        for (int i = 0; i < 4; i++) {
            cx[i] = gs_splitmix_uniform(&seed) * W;
            cy[i] = gs_splitmix_uniform(&seed) * H;
            a[i] = 1 + 2 * gs_splitmix_uniform(&seed);
        }
        for (size_t p = 0; p < P; p++) {
            double x = (double)(p % (size_t)W), y = (double)(p / (size_t)W), v = 0.05;
            for (int i = 0; i < 4; i++) {
                double d2 = ((x - cx[i]) * (x - cx[i]) + (y - cy[i]) * (y - cy[i])) / (0.1 * W * W);
                v += a[i] * exp(-d2);
            }
            for (int b = 0; b < 3; b++) tq[((size_t)s * P + p) * 3 + b] = (float)(v * src->q[s * 3 + b]);
        }
    }
    /* every 50th pixel four times brighter (bulbs in view) */
    for (size_t p = 0; p < P; p += 50)
        for (int s = 0; s < S; s++)
            for (int b = 0; b < 3; b++) tq[((size_t)s * P + p) * 3 + b] *= 4;
    gs_noise nz = gs_capture_noise(cap);
    for (int k = 0; k < K; k++)
        for (size_t p = 0; p < P; p++)
            for (int b = 0; b < 3; b++) {
                double mu = 0;
                for (int s = 0; s < S; s++)
                    mu += tq[((size_t)s * P + p) * 3 + b] * src->b[((size_t)s * 3 + b) * K + k];
                double raw = cap->black_level_dn + mu * 256;
                raw += sqrt(gs_noise_raw_var(&nz, raw)) * gs_splitmix_normal(&seed);
                raw = floor(raw + 0.5);
                cap->raw[((size_t)k * P + p) * 3 + b] = (unsigned short)(raw < 0 ? 0 : raw > 4095 ? 4095 : raw);
            }
    return GS_OK;
}

static const char transport_usage[] =
    "usage: gridsurvey bench transport [--quick]\n"
    "\n"
    "Times rec_unmix (Eqs. 16-18) on synthetic RGB captures of five sources, 256 x 256 to\n"
    "1024 x 1024 pixels (--quick: 256 x 256 only), and prints a Markdown table\n"
    "(docs/bench-transport.md).\n"
    "\n"
    "Example:\n"
    "  gridsurvey bench transport --quick\n";

int srv_bench_transport(int argc, char **argv)
{
    int quick = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
            fputs(transport_usage, stdout);
            return 0;
        }
        if (strcmp(argv[i], "--quick"))
            return srv_usage_error("bench transport", "unexpected argument '%s': expected --quick", argv[i]);
        quick = 1;
    }
    gs_delight *d = NULL;
    gs_status st = srv_tr_delight(NULL, &d);
    rec_sources src = {0};
    if (st == GS_OK) st = rec_sources_build(d, bench_sources, 5, 50, 3, 26, &src, NULL);
    if (st != GS_OK) {
        gs_delight_free(d);
        return srv_error("bench transport", st);
    }
    printf("# Light-transport unmixing time (`gridsurvey bench transport%s`)\n\n", quick ? " --quick" : "");
    printf("`rec_unmix` (paper Sec. 5.1: Eq. 16 per pixel and band with rec_nnls, Eq. 18, Eq. 16 "
           "again) on one core, S = 5 sources (five DELIGHT bulbs on the three phases), RGB, "
           "K = 26, on synthetic captures with the camera's noise and every 50th pixel four times "
           "brighter, some saturating in their brightest frames (survey/bench_transport.c). Wall time of the unmixing alone "
           "(the capture in memory), the best of 2 runs.\n\n");
    printf("| pixels | refine | seconds | Mpixel/s | partly saturated px | relative error (mean over sources) |\n");
    printf("| --- | --- | --- | --- | --- | --- |\n");
    int sizes[3][2] = {{256, 256}, {512, 512}, {1024, 1024}};
    for (int i = quick ? 0 : 0; i < (quick ? 1 : 3) && st == GS_OK; i++) {
        int W = sizes[i][0], H = sizes[i][1];
        size_t P = (size_t)W * H;
        float *tq = malloc(sizeof *tq * P * 3 * 5);
        gs_capture cap;
        if (!tq) st = gs_fail(GS_ENOMEM, "bench: out of memory");
        if (st == GS_OK) st = synth(&src, W, H, &cap, tq);
        for (int refine = 0; refine <= 1 && st == GS_OK; refine++) {
            rec_unmix_opts uo;
            rec_unmix_opts_default(&uo);
            uo.refine = refine;
            double best = INFINITY, err = 0;
            rec_unmix_result r;
            for (int rep = 0; rep < 2 && st == GS_OK; rep++) {
                double t0 = gs_clock_s(CLOCK_MONOTONIC);
                st = rec_unmix(&cap, &src, &uo, &r);
                double dt = gs_clock_s(CLOCK_MONOTONIC) - t0;
                if (dt < best) best = dt;
                if (st == GS_OK && rep == 1) {
                    err = 0;
                    for (int s = 0; s < 5; s++)
                        err += srv_tr_rel_error(r.tq + (size_t)s * P * 3, tq + (size_t)s * P * 3, P, 3) / 5;
                    printf("| %d x %d | %d | %.2f | %.2f | %zu | %.4f |\n", W, H, refine, best,
                           (double)P / best * 1e-6, r.partial_px, err);
                    fflush(stdout);
                }
                rec_unmix_release(&r);
            }
        }
        gs_capture_release(&cap);
        free(tq);
    }
    printf("\nTarget (issue 14): a 1-megapixel RGB K = 26 capture with S = 5 in under 10 s on one core.\n");
    rec_sources_release(&src);
    gs_delight_free(d);
    return st == GS_OK ? 0 : srv_error("bench transport", st);
}
