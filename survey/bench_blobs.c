/* bench_blobs.c - `gridsurvey bench blobs`: the time of the blob extraction (rec_blobs_extract,
 * the per-light path's first stage) on a capture directory, without and with the multi-source
 * PSF fit (docs/recognition.md, "Detection at kilometre range"), on one thread and on the online
 * CPUs: what the fit's deblending costs in time. */
#include "recognize/recognize.h"
#include "survey/internal.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char blobs_usage[] =
    "usage: gridsurvey bench blobs CAPDIR [--reps N]\n"
    "\n"
    "Extracts the lights of the capture directory CAPDIR (docs/formats.md) N times (default 3)\n"
    "without and with the multi-source PSF fit, on one thread and on the online CPUs, and prints\n"
    "the best wall time, its run's CPU time (all threads) and the lights found as a Markdown\n"
    "table. The catalog is the same on any number of threads.\n"
    "\n"
    "Example:\n"
    "  gridsurvey bench blobs build/demo/metro-capture --reps 5\n";

/* One row: the best of reps runs of rec_blobs_extract with psf_fit and threads. */
static gs_status blobs_row(const gs_capture *cap, int psf_fit, int threads, int reps)
{
    double best = INFINITY, best_cpu = 0;
    size_t lights = 0;
    for (int r = 0; r < reps; r++) {
        rec_blob_opts o;
        rec_blob_opts_default(&o);
        o.psf_fit = psf_fit;
        o.threads = threads;
        rec_catalog cat;
        double t0 = gs_clock_s(CLOCK_MONOTONIC), c0 = gs_clock_s(CLOCK_PROCESS_CPUTIME_ID);
        gs_status st = rec_blobs_extract(cap, &o, &cat);
        double dt = gs_clock_s(CLOCK_MONOTONIC) - t0, dc = gs_clock_s(CLOCK_PROCESS_CPUTIME_ID) - c0;
        if (st != GS_OK) return st;
        lights = cat.count;
        rec_catalog_release(&cat);
        if (dt < best) {
            best = dt;
            best_cpu = dc;
        }
    }
    printf("| %s | %d | %.3f | %.3f | %zu |\n", psf_fit ? "on" : "off", threads, best, best_cpu, lights);
    return GS_OK;
}

int srv_bench_blobs(int argc, char **argv)
{
    const char *dir = NULL;
    int reps = 3;
    unsigned long long v;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
            fputs(blobs_usage, stdout);
            return 0;
        }
        if (!strcmp(argv[i], "--reps") && i + 1 < argc) {
            if (!srv_int_arg("bench blobs", "--reps", argv[++i], 1, 100, &v)) return 2;
            reps = (int)v;
        } else if (argv[i][0] == '-' || dir) {
            return srv_usage_error("bench blobs", "unexpected argument '%s'", argv[i]);
        } else {
            dir = argv[i];
        }
    }
    if (!dir) return srv_usage_error("bench blobs", "expected a capture directory");
    gs_capture cap;
    gs_status st = gs_capture_read(dir, &cap);
    if (st != GS_OK) return srv_error("bench blobs", st);
    int nt = gs_threads_resolve(0);
    printf("# Blob extraction time (`gridsurvey bench blobs`)\n\n"
           "Capture `%s`: %d x %d pixels, %d bands, K = %d; the best of %d runs of rec_blobs_extract "
           "(default options), wall and CPU (all threads) seconds. The machine's other load shows as "
           "wall > CPU / threads.\n\n"
           "| PSF fit | threads | wall s | CPU s | lights |\n|---|---:|---:|---:|---:|\n",
           dir, cap.width, cap.height, cap.bands, cap.K, reps);
    for (int fit = 0; fit <= 1 && st == GS_OK; fit++) {
        st = blobs_row(&cap, fit, 1, reps);
        if (st == GS_OK && nt > 1) st = blobs_row(&cap, fit, nt, reps);
    }
    gs_capture_release(&cap);
    return st == GS_OK ? 0 : srv_error("bench blobs", st);
}
