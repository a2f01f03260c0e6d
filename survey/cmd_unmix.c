/* cmd_unmix.c - `gridsurvey unmix CAPDIR --sources FILE|auto --out-dir DIR`: AC light-transport
 * unmixing (paper Sec. 5.1, Eqs. 16-18) into one float TIFF per source, with --render each
 * source's HDR denoised K-frame sequence (Eq. 19), and the pictures of Fig. 4. With a simulated
 * capture's truth it prints each source's error (docs/light-transport.md). */
#include "survey/internal.h"

#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static const char unmix_usage[] =
    "usage: gridsurvey unmix CAPDIR --sources FILE|auto --out-dir DIR [OPTIONS]\n"
    "\n"
    "Unmixes a capture directory (gridsurvey-capture/1) of a scene lit by S AC sources into the\n"
    "image of each source alone (paper Sec. 5.1): I = T Q B per band (Eq. 13), T >= 0 per pixel\n"
    "by weighted non-negative least squares (Eq. 16) without saturated samples (Eq. 17), then B\n"
    "refined (Eq. 18) and Eq. 16 again. Sources of the same bulb and phase are one (Eq. 15).\n"
    "Writes DIR/sources.json (gridsurvey-sources/1), DIR/source_NN.tiff (32-bit float, tau_s Q_s\n"
    "in DN per flicker cycle, R G B in file order; NaN where no value can be given),\n"
    "DIR/sigma_NN.tiff (each value's 1-sigma from the noise, as source_NN.tiff),\n"
    "DIR/source_NN.png, DIR/mean.png (the input's mean image) and DIR/residual.tiff/.png (each\n"
    "pixel's weighted rms residual per degree of freedom: ~1 where the sources explain it, above\n"
    "where one is missing or its BRF wrong). docs/light-transport.md.\n"
    "\n"
    "  --sources FILE     {\"format\": \"gridsurvey-sources/1\", \"sources\": [{\"bulb\": ID,\n"
    "                     \"phase_deg\": P}, ...]} (bulb \"daylight\": a constant source)\n"
    "  --sources auto     the sources dominating pixels (bulbs in view, nearby surfaces),\n"
    "                     recognised per pixel with Eq. 7 (Sec. 5.1 (a), (b))\n"
    "  --out-dir DIR      output directory (created)\n"
    "  --render           also DIR/render_NN.tiff: each source's K frames (Eq. 19; HDR,\n"
    "                     denoised), one page per frame\n"
    "  --refine N         rounds of Eq. 18 + Eq. 16, 0..20 (default 1, as the paper)\n"
    "  --max-error F      predicted relative error of a source above which the problem is\n"
    "                     reported ill-posed (paper Fig. 10), > 0 (default 0.5)\n"
    "  --max-sources N    with auto: at most N sources, 1..16 (default 8)\n"
    "  --min-pixels N     with auto: a source must dominate at least N pixels (default 3)\n"
    "  --delight DB       DELIGHT SQLite file (default: $GRIDSURVEY_DELIGHT, else built-in)\n"
    "  --max-drift-windows W\n"
    "                     free running: the frames whose windows moved over W windows\n"
    "                     during the exposure are left out, >= 0, none or auto (none if\n"
    "                     capture.json's window_period is measured, else 0.5; default 0.5:\n"
    "                     unmixing does not raise the kept frames' noise as Eq. 7 does)\n"
    "  --progress         progress on stderr (default: when stderr is a terminal)\n"
    "  -q, --no-progress  no progress\n"
    "  --help             this text\n"
    "\n"
    "Examples:\n"
    "  gridsurvey simulate capture/scenes/lab_transport.json --out-dir build/lab-transport\n"
    "  gridsurvey unmix build/lab-transport --sources capture/scenes/lab_transport_sources.json \\\n"
    "                   --out-dir build/unmixed --render\n"
    "  gridsurvey unmix build/lab-transport --sources auto --out-dir build/unmixed-auto\n"
    "\n"
    "Exit status: 0 done, 1 failure or ill-posed (one line on stderr), 2 usage error.\n";

/* Eq. 16's passes over the pixels, on one terminal line. */
static void unmix_progress(void *ctx, double fraction)
{
    (void)ctx;
    fprintf(stderr, "\r\033[Kgridsurvey unmix: %3.0f %%", 100.0 * fraction);
    if (fraction >= 1.0) fputs("\r\033[K", stderr);
    fflush(stderr);
}

/* Each source's error against the truth, the denoising of the rendered sequence. */
static void print_truth(const char *capdir, const gs_capture *cap, const rec_sources *src,
                        const rec_unmix_result *r, const gs_delight *d, int render)
{
    srv_tr_truth t;
    if (srv_tr_truth_load(capdir, &t) != GS_OK) return;
    size_t P = (size_t)r->width * r->height, n = P * r->bands;
    float *tr = malloc(sizeof *tr * n);
    if (!tr || t.W != r->width || t.H != r->height || t.B != r->bands) {
        free(tr);
        srv_tr_truth_release(&t);
        return;
    }
    printf("truth (%s/truth.json):\n", capdir);
    int matched = 0;
    for (int s = 0; s < src->S; s++) {
        int lights;
        const char *as = srv_tr_truth_match(&t, d, cap->grid_hz, r->bands, src->bulb[s], src->phase_deg[s]);
        if (as) srv_tr_truth_of(&t, as, src->phase_deg[s], tr, &lights);
        else lights = 0;
        matched += lights;
        if (!lights) {
            printf("  source %02d %-20s %6.1f deg: no such source in the scene\n", s, src->bulb[s],
                   src->phase_deg[s]);
            continue;
        }
        double e = srv_tr_rel_error(r->tq + (size_t)s * n, tr, P, r->bands);
        printf("  source %02d %-20s %6.1f deg: relative error %.4f (%d light%s", s, src->bulb[s],
               src->phase_deg[s], e, lights, lights == 1 ? "" : "s");
        if (strcmp(as, src->bulb[s])) printf(" of %s, the same technology", as);
        printf(")\n");
    }
    if (matched < t.n) printf("  %d of the scene's %d sources not among the unmixed ones\n", t.n - matched, t.n);
    if (render) {
        /* the noise of the rendered sum against the input's, on the usable samples of known
         * pixels (the truth's sequence from its lights' BRFs) */
        double e_in = 0, e_out = 0;
        size_t m = 0;
        double *bt = malloc(sizeof *bt * (size_t)t.n * r->bands * r->K);
        int ok = bt != NULL;
        for (int i = 0; i < t.n && ok; i++) {
            double *row = bt + (size_t)i * r->bands * r->K;
            if (!strcmp(t.bulb[i], REC_DAYLIGHT)) {
                for (int j = 0; j < r->bands * r->K; j++) row[j] = 1;
                continue;
            }
            const gs_bulb *b = gs_delight_find(d, t.bulb[i], cap->grid_hz, r->bands);
            ok = b && gs_brf_integrate(&b->brf, gs_phase_to_shift(t.phase_deg[i]), r->K, row) == GS_OK;
        }
        for (size_t p = 0; p < P && ok; p++) {
            int known = 1;
            for (int s = 0; s < r->S; s++) known &= isfinite(r->tq[(size_t)s * n + p * r->bands]);
            if (!known) continue;
            int y = (int)(p / (size_t)r->width), x = (int)(p % (size_t)r->width);
            for (int k = 0; k < r->K; k++)
                for (int b = 0; b < r->bands; b++) {
                    double v = gs_capture_value(cap, k, y, x, b);
                    if (!isfinite(v)) continue;
                    double truth = 0, rend = 0;
                    for (int i = 0; i < t.n; i++)
                        truth += t.img[(size_t)i * n + p * r->bands + b] * bt[((size_t)i * r->bands + b) * r->K + k];
                    for (int s = 0; s < r->S; s++)
                        rend += r->tq[(size_t)s * n + p * r->bands + b] * r->b[((size_t)s * r->bands + b) * r->K + k];
                    e_in += (v - truth) * (v - truth);
                    e_out += (rend - truth) * (rend - truth);
                    m++;
                }
        }
        if (ok && m && e_in > 0)
            printf("  denoising (Eq. 19): rendered sequence rms error %.4g DN/cycle vs the input's "
                   "%.4g: %.1fx less noise (%zu samples)\n", sqrt(e_out / m), sqrt(e_in / m),
                   sqrt(e_in / e_out), m);
        free(bt);
    }
    free(tr);
    srv_tr_truth_release(&t);
}

int srv_cmd_unmix(int argc, char **argv)
{
    static const struct option longs[] = {
        {"sources", required_argument, 0, 's'}, {"out-dir", required_argument, 0, 'O'},
        {"render", no_argument, 0, 'r'},        {"refine", required_argument, 0, 'f'},
        {"max-error", required_argument, 0, 'e'}, {"max-sources", required_argument, 0, 'm'},
        {"delight", required_argument, 0, 'd'}, {"min-pixels", required_argument, 0, 'p'},
        {"max-drift-windows", required_argument, 0, 'W'}, {"progress", no_argument, 0, 'P'},
        {"no-progress", no_argument, 0, 'q'},   {"help", no_argument, 0, 'h'},
        {0, 0, 0, 0},
    };
    const char *sources = NULL, *out = NULL, *db = NULL;
    int render = 0, progress = isatty(2);
    double refine = 1, max_sources = 8, min_px = 3;
    rec_unmix_opts uo;
    rec_unmix_opts_default(&uo);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "o:hq", longs, NULL)) != -1) {
        switch (c) {
        case 's': sources = optarg; break;
        case 'O': out = optarg; break;
        case 'o': return srv_out_dir_hint("unmix");
        case 'r': render = 1; break;
        case 'd': db = optarg; break;
        case 'f':
            if (!srv_num_arg("unmix", "--refine", optarg, 0, 20, &refine) || refine != floor(refine)) return 2;
            break;
        case 'e':
            if (!srv_num_arg("unmix", "--max-error", optarg, 1e-9, 1e9, &uo.max_error)) return 2;
            break;
        case 'm':
            if (!srv_num_arg("unmix", "--max-sources", optarg, 1, REC_MAX_SOURCES, &max_sources) ||
                max_sources != floor(max_sources))
                return 2;
            break;
        case 'p':
            if (!srv_num_arg("unmix", "--min-pixels", optarg, 1, 1e9, &min_px) || min_px != floor(min_px)) return 2;
            break;
        case 'W':
            if (!srv_drift_arg("unmix", optarg, &uo.max_drift_windows)) return 2;
            break;
        case 'P': progress = 1; break;
        case 'q': progress = 0; break;
        case 'h': fputs(unmix_usage, stdout); return 0;
        default: return srv_usage_hint("unmix", argv);
        }
    }
    if (optind + 1 != argc || !sources || !out)
        return srv_usage_error("unmix", "expected one CAPDIR, --sources FILE|auto and --out-dir DIR");
    uo.refine = (int)refine;
    if (progress) uo.progress = unmix_progress;
    const char *capdir = argv[optind];
    gs_capture cap;
    gs_delight *d = NULL;
    rec_source_spec *specs = NULL;
    rec_sources src = {0};
    rec_unmix_result r = {0};
    rec_matcher *m = NULL;
    float *buf = NULL;
    double *bdb = NULL;
    int n = 0, into[REC_MAX_SOURCES];
    gs_status st = gs_capture_read(capdir, &cap);
    if (st == GS_OK) st = srv_tr_delight(db, &d);
    if (st == GS_OK && !strcmp(sources, "auto")) {
        size_t tested, dominated;
        rec_eq7_opts eo;
        rec_eq7_opts_default(&eo);
        eo.band_gains = 0;       /* the paper's Eq. 7: Q_beta is part of the source */
        eo.max_drift_windows = uo.max_drift_windows;
        eo.unknown_p = 0;        /* dominance is judged by the fit (rec_sources_auto) */
        eo.model_error = 0.04;   /* one pixel's fit: a fixed 4 % for the BRF's and the others'
                                  * light (rec_sources_auto's chi-square bound assumes it) */
        st = rec_matcher_new(d, cap.grid_hz, cap.bands, cap.K, &eo, &m);
        if (st == GS_OK)
            st = rec_sources_auto(&cap, m, 20, (int)min_px, (int)max_sources, &specs, &n, &tested,
                                  &dominated);
        if (st == GS_OK)
            printf("unmix: sources auto: %zu of %zu pixels dominated by one source (Eq. 7), %d "
                   "sources (each bulb and phase once, Eq. 15):", dominated, tested, n);
        for (int i = 0; i < n && st == GS_OK; i++)
            printf(" %s@%g", specs[i].bulb, specs[i].phase_deg);
        if (st == GS_OK) printf("\n");
    } else if (st == GS_OK) {
        st = rec_sources_read_specs(sources, &specs, &n);
    }
    if (st == GS_OK) st = rec_unmix_budget(capdir, &cap, n, render);
    if (st == GS_OK) st = rec_sources_build(d, specs, n, cap.grid_hz, cap.bands, cap.K, &src, into);
    if (st == GS_OK)
        for (int i = 0; i < n; i++)
            for (int j = 0; j < i; j++)
                if (into[i] == into[j]) {
                    printf("unmix: sources %d and %d (%s at %g and %g deg) are the same bulb and phase: "
                           "inseparable, merged (Eq. 15)\n", j, i, specs[i].bulb, specs[j].phase_deg,
                           specs[i].phase_deg);
                    break;
                }
    if (st == GS_OK) {
        bdb = malloc(sizeof *bdb * (size_t)src.S * src.bands * src.K);
        if (bdb) memcpy(bdb, src.b, sizeof *bdb * (size_t)src.S * src.bands * src.K);
        else st = gs_fail(GS_ENOMEM, "out of memory");
    }
    if (st == GS_OK) {
        st = rec_unmix(&cap, &src, &uo, &r);
        if (st != GS_OK && r.ill_posed) {
            /* every source's predicted error, on the error's one line */
            char errs[1024] = "";
            for (int s = 0; s < src.S; s++) {
                size_t u = strlen(errs);
                if (isfinite(r.predicted_error[s]) && r.predicted_error[s] > 0)
                    snprintf(errs + u, sizeof errs - u, "%s%02d %s at %g deg %.3g", u ? ", " : "", s,
                             src.bulb[s], src.phase_deg[s], r.predicted_error[s]);
            }
            if (*errs) gs_fail(st, "%s (predicted error of each source: %s)", gs_detail(), errs);
        }
    }
    size_t P = (size_t)cap.width * cap.height, nimg = P * (size_t)cap.bands;
    if (st == GS_OK) st = gs_dir_ensure(out);
    char files[REC_MAX_SOURCES][GS_PATH_MAX], rends[REC_MAX_SOURCES][GS_PATH_MAX];
    const char *fp[REC_MAX_SOURCES], *rp[REC_MAX_SOURCES];
    if (st == GS_OK && !(buf = malloc(sizeof *buf * nimg * (size_t)(render ? cap.K : 1))))
        st = gs_fail(GS_ENOMEM, "out of memory");
    for (int s = 0; s < src.S && st == GS_OK; s++) {
        char path[4096];
        snprintf(files[s], sizeof files[s], "source_%02d.tiff", s);
        fp[s] = files[s];
        rp[s] = NULL;
        if (!gs_path_join(path, sizeof path, out, files[s])) st = gs_fail(GS_EINVAL, "%s: path too long", out);
        if (st == GS_OK) st = gs_tiff_write_float(path, r.tq + (size_t)s * nimg, cap.width, cap.height, cap.bands, 1);
        char name[32];
        snprintf(name, sizeof name, "sigma_%02d.tiff", s);
        gs_path_join(path, sizeof path, out, name);
        if (st == GS_OK) st = gs_tiff_write_float(path, r.sigma + (size_t)s * nimg, cap.width, cap.height, cap.bands, 1);
        char png[32];
        snprintf(png, sizeof png, "source_%02d.png", s);
        gs_path_join(path, sizeof path, out, png);
        if (st == GS_OK) st = rec_write_image_png(path, r.tq + (size_t)s * nimg, cap.width, cap.height, cap.bands, 0);
        if (st == GS_OK && render) {
            snprintf(rends[s], sizeof rends[s], "render_%02d.tiff", s);
            rp[s] = rends[s];
            gs_path_join(path, sizeof path, out, rends[s]);
            st = rec_render_source(&r, s, buf);
            if (st == GS_OK) st = gs_tiff_write_float(path, buf, cap.width, cap.height, cap.bands, cap.K);
        }
    }
    if (st == GS_OK) {
        /* the input's mean image over the frames, saturated samples at the saturation level */
        gs_capture_mean_image(&cap, 1, buf);
        char path[4096];
        gs_path_join(path, sizeof path, out, "mean.png");
        st = rec_write_image_png(path, buf, cap.width, cap.height, cap.bands, 0);
        /* each pixel's weighted rms residual per degree of freedom: ~1 where the sources and
         * their BRFs explain it, above where one is missing or wrong (white at 3 and beyond) */
        gs_path_join(path, sizeof path, out, "residual.tiff");
        if (st == GS_OK) st = gs_tiff_write_float(path, r.residual, cap.width, cap.height, 1, 1);
        gs_path_join(path, sizeof path, out, "residual.png");
        if (st == GS_OK) st = rec_write_image_png(path, r.residual, cap.width, cap.height, 1, 3.0);
    }
    if (st == GS_OK) {
        char path[4096];
        rec_capture_meta meta;
        rec_capture_meta_of(&cap, &meta);
        gs_path_join(path, sizeof path, out, "sources.json");
        st = rec_sources_write(path, &src, &r, &meta, uo.refine, fp, render ? rp : NULL, bdb);
    }
    if (st == GS_OK) {
        printf("unmix: %s: %d sources, %dx%d x %d bands, K = %d; %zu pixels partly saturated, "
               "%zu without an answer, %zu source values without one in the others (a source the "
               "usable samples do not determine); weighted rms residual %.3f; QB condition",
               out, src.S, cap.width, cap.height, cap.bands, cap.K, r.partial_px, r.unknown_px,
               r.unknown_values - r.unknown_px * (size_t)src.S, r.rms_residual);
        for (int b = 0; b < cap.bands; b++) printf(" %.3g", r.cond[b]);
        printf("\n");
        for (int s = 0; s < src.S; s++) {
            double dev = 0;
            for (int i = 0; i < src.bands * src.K; i++) {
                double e = fabs(r.b[(size_t)s * src.bands * src.K + i] - bdb[(size_t)s * src.bands * src.K + i]);
                if (e > dev) dev = e;
            }
            printf("  source %02d %-20s %6.1f deg: predicted error %.4f, Eq. 18 moved its BRF by "
                   "at most %.4f\n", s, src.bulb[s], src.phase_deg[s], r.predicted_error[s], dev);
        }
        if (r.rms_residual > 2)
            fprintf(stderr, "unmix: warning: the sources explain the data only to a weighted rms "
                    "residual of %.2f noise sigmas (about 1 when they do): a source missing from the "
                    "list, or BRFs unlike the scene's (paper Fig. 10: expect crosstalk)\n", r.rms_residual);
        print_truth(capdir, &cap, &src, &r, d, render);
    }
    free(buf);
    free(bdb);
    free(specs);
    rec_matcher_free(m);
    rec_unmix_release(&r);
    rec_sources_release(&src);
    gs_delight_free(d);
    gs_capture_release(&cap);
    return st == GS_OK ? 0 : srv_error("unmix", st);
}
