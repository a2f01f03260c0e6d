/* cmd_separate.c - `gridsurvey separate CAPDIR --out-dir DIR`: a window's semi-reflection separated
 * from the daylit scene behind it (paper Sec. 5.3, Eqs. 21-22, Fig. 6). */
#include "survey/internal.h"

#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char separate_usage[] =
    "usage: gridsurvey separate CAPDIR --out-dir DIR\n"
    "\n"
    "Separates a capture of a window (paper Sec. 5.3): daylight through it (constant: BRF all\n"
    "ones) and the reflection of an indoor scene lit by one AC source of unknown bulb and phase.\n"
    "The AC component comes from frame differences (Eqs. 21-22), the transmitted one with the\n"
    "scalar A that minimises the mutual information of the two. Writes DIR/transmitted.tiff and\n"
    "DIR/reflection.tiff (32-bit float, DN per cycle: the cycle-mean images when the model\n"
    "holds, else up to scale; NaN where saturated) and their PNGs, and DIR/mean.png.\n"
    "\n"
    "  --out-dir DIR  output directory (created)\n"
    "  --help         this text\n"
    "\n"
    "\n"
    "Examples:\n"
    "  gridsurvey simulate capture/scenes/window.json --out-dir build/window\n"
    "  gridsurvey separate build/window --out-dir build/separated\n"
    "\n"
    "Exit status: 0 done, 1 failure (one line on stderr), 2 usage error.\n";

int srv_cmd_separate(int argc, char **argv)
{
    static const struct option longs[] = {
        {"out-dir", required_argument, 0, 'O'}, {"help", no_argument, 0, 'h'}, {0, 0, 0, 0},
    };
    const char *out = NULL;
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "o:h", longs, NULL)) != -1) {
        switch (c) {
        case 'O': out = optarg; break;
        case 'o': return srv_out_dir_hint("separate");
        case 'h': fputs(separate_usage, stdout); return 0;
        default: return srv_usage_hint("separate", argv);
        }
    }
    if (optind + 1 != argc || !out) return srv_usage_error("separate", "expected one CAPDIR and --out-dir DIR");
    const char *capdir = argv[optind];
    gs_capture cap;
    rec_separation sep = {0};
    gs_status st = gs_capture_read(capdir, &cap);
    if (st == GS_OK) st = rec_separate_budget(capdir, &cap);
    if (st == GS_OK) st = rec_separate(&cap, &sep);
    if (st == GS_OK) st = gs_dir_ensure(out);
    size_t n = (size_t)cap.width * cap.height * (size_t)cap.bands;
    const char *names[2] = {"transmitted", "reflection"};
    const float *imgs[2] = {sep.transmitted, sep.reflection};
    for (int i = 0; i < 2 && st == GS_OK; i++) {
        char path[4096], file[64];
        snprintf(file, sizeof file, "%s.tiff", names[i]);
        if (!gs_path_join(path, sizeof path, out, file)) st = gs_fail(GS_EINVAL, "%s: path too long", out);
        if (st == GS_OK) st = gs_tiff_write_float(path, imgs[i], cap.width, cap.height, cap.bands, 1);
        snprintf(file, sizeof file, "%s.png", names[i]);
        gs_path_join(path, sizeof path, out, file);
        if (st == GS_OK) st = rec_write_image_png(path, imgs[i], cap.width, cap.height, cap.bands, 0);
    }
    if (st == GS_OK) {
        float *mean = malloc(sizeof *mean * n);
        if (!mean) st = gs_fail(GS_ENOMEM, "out of memory");
        for (size_t i = 0; mean && i < n; i++) mean[i] = sep.transmitted[i] + sep.reflection[i];
        char path[4096];
        gs_path_join(path, sizeof path, out, "mean.png");
        if (st == GS_OK) st = rec_write_image_png(path, mean, cap.width, cap.height, cap.bands, 0);
        free(mean);
    }
    if (st == GS_OK) {
        printf("separate: %s: transmitted.tiff, reflection.tiff (Sec. 5.3);", out);
        for (int b = 0; b < cap.bands; b++)
            printf(" band %d: A %.4f, mutual information %.4f nats (%.4f without separation)", b,
                   sep.A[b], sep.mi[b], sep.mi_a0[b]);
        printf("\n");
        srv_tr_truth t;
        if (srv_tr_truth_load(capdir, &t) == GS_OK && t.W == cap.width && t.H == cap.height &&
            t.B == cap.bands) {
            /* the truth's constant (daylight) sources against its AC ones */
            float *to = calloc(n, sizeof *to), *ta = calloc(n, sizeof *ta);
            if (to && ta) {
                for (int i = 0; i < t.n; i++)
                    for (size_t j = 0; j < n; j++)
                        (strcmp(t.bulb[i], REC_DAYLIGHT) ? ta : to)[j] += t.img[(size_t)i * n + j];
                printf("truth: normalized cross-correlation transmitted %.4f, reflection %.4f\n",
                       srv_tr_ncc(sep.transmitted, to, n), srv_tr_ncc(sep.reflection, ta, n));
            }
            free(to);
            free(ta);
            srv_tr_truth_release(&t);
        }
    }
    rec_separation_release(&sep);
    gs_capture_release(&cap);
    return st == GS_OK ? 0 : srv_error("separate", st);
}
