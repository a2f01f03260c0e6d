/* cmd_relight.c - `gridsurvey relight DIR --set N=gain:A[,bulb:ID][,phase:DEG] ... --out-dir CAPDIR`:
 * generalised relighting (paper Sec. 5.2, Eq. 20) of what `unmix` wrote, as a capture directory
 * (gridsurvey-capture/1, so `recognize` reads it back) with a PNG preview. */
#include "survey/internal.h"

#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char relight_usage[] =
    "usage: gridsurvey relight DIR --set N=gain:A[,bulb:ID][,phase:DEG] ...\n"
    "                          --out-dir CAPDIR [--delight DB] [--compare CAPDIR2]\n"
    "\n"
    "Relights the sources that `gridsurvey unmix` wrote to DIR (sources.json, source_NN.tiff):\n"
    "I = T [A Q B]^relight (paper Eq. 20). Each --set changes source N (00, 01, ...): gain:A\n"
    "amplifies it (0 switches it off), bulb:ID gives it another DELIGHT bulb's chromaticity\n"
    "and BRF (or \"daylight\"), phase:DEG another grid phase (modulo 360); each key at most\n"
    "once per source. Sources not named keep gain 1, their bulb and phase and the BRF refined\n"
    "by unmix. Writes CAPDIR as a capture directory (16-bit frames with HDR maps where the\n"
    "result exceeds the sensor; pixels without a value saturated) of the input capture's\n"
    "numbers, and CAPDIR/preview.png (the mean image).\n"
    "\n"
    "  --set N=...        a source's change (repeatable)\n"
    "  --out-dir CAPDIR   the capture directory to write\n"
    "  --delight DB       DELIGHT SQLite file (default: $GRIDSURVEY_DELIGHT, else built-in)\n"
    "  --compare CAPDIR2  print the relative difference of the result's mean image from\n"
    "                     CAPDIR2's (e.g. a capture rendered without the switched-off source)\n"
    "  --help             this text\n"
    "\n"
    "\n"
    "Examples (DIR from the examples of gridsurvey help unmix):\n"
    "  gridsurvey relight build/unmixed --set 2=gain:3.5 --set 0=bulb:hps-70w \\\n"
    "                     --out-dir build/relit\n"
    "  gridsurvey relight build/unmixed --set 4=gain:0 --out-dir build/relit-mh70-off\n"
    "\n"
    "Exit status: 0 done, 1 failure (one line on stderr), 2 usage error.\n";

/* "N=gain:A,bulb:ID,phase:DEG" into set[N]; given[N] holds the keys (bits 1 gain, 2 bulb, 4 phase)
 * that earlier --set gave source N: each key once per source. */
static int parse_set(const char *arg, int S, rec_relight_set *set, unsigned *given)
{
    char buf[256];
    snprintf(buf, sizeof buf, "%s", arg);
    char *eq = strchr(buf, '=');
    char *end;
    long n = strtol(buf, &end, 10);
    if (!eq || end != eq || end == buf || n < 0 || n >= S) {
        srv_usage_error("relight", "--set '%s': expected N=gain:A[,bulb:ID][,phase:DEG] with N from 0 "
                        "to %d", arg, S - 1);
        return 0;
    }
    rec_relight_set *r = &set[n];
    /* items split at every comma: an empty one (no change at all, a stray comma) is an error */
    for (char *tok = eq + 1, *next; tok; tok = next) {
        if ((next = strchr(tok, ','))) *next++ = '\0';
        char *colon = strchr(tok, ':');
        if (!colon) goto bad;
        *colon = '\0';
        const char *val = colon + 1;
        unsigned key = !strcmp(tok, "gain") ? 1 : !strcmp(tok, "bulb") ? 2 : !strcmp(tok, "phase") ? 4 : 0;
        if (!key) goto bad;
        if (given[n] & key) {
            srv_usage_error("relight", "--set '%s': source %ld: %s given twice: expected each of gain, "
                            "bulb and phase at most once per source", arg, n, tok);
            return 0;
        }
        given[n] |= key;
        if (key == 1) {
            if (!gs_parse_number(val, &r->gain) || !(r->gain >= 0)) goto bad;
        } else if (key == 2) {
            if (!*val || strlen(val) >= sizeof r->bulb) goto bad;
            snprintf(r->bulb, sizeof r->bulb, "%s", val);
        } else {
            if (!gs_parse_number(val, &r->phase_deg)) goto bad;
            r->phase_deg = gs_wrap360(r->phase_deg);   /* 400 is 40 deg, -120 is 240 */
            r->set_phase = 1;
        }
    }
    return 1;
bad:
    srv_usage_error("relight", "--set '%s': source %ld: expected N=gain:A[,bulb:ID][,phase:DEG] (A a "
                    "number >= 0, DEG a number)", arg, n);
    return 0;
}

int srv_cmd_relight(int argc, char **argv)
{
    static const struct option longs[] = {
        {"set", required_argument, 0, 's'},     {"out-dir", required_argument, 0, 'O'},
        {"delight", required_argument, 0, 'd'}, {"compare", required_argument, 0, 'c'},
        {"help", no_argument, 0, 'h'},          {0, 0, 0, 0},
    };
    const char *out = NULL, *db = NULL, *cmp = NULL;
    const char *sets[64];
    int nsets = 0;
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "o:h", longs, NULL)) != -1) {
        switch (c) {
        case 's':
            if (nsets == 64) {
                return srv_usage_error("relight", "at most 64 --set");
            }
            sets[nsets++] = optarg;
            break;
        case 'O': out = optarg; break;
        case 'o': return srv_out_dir_hint("relight");
        case 'd': db = optarg; break;
        case 'c': cmp = optarg; break;
        case 'h': fputs(relight_usage, stdout); return 0;
        default: return srv_usage_hint("relight", argv);
        }
    }
    if (optind + 1 != argc || !out) {
        return srv_usage_error("relight", "expected one DIR and --out-dir CAPDIR");
    }
    const char *dir = argv[optind];
    char path[4096];
    rec_sources src;
    rec_capture_meta meta;
    char(*files)[GS_PATH_MAX] = NULL;
    if (!gs_path_join(path, sizeof path, dir, "sources.json")) {
        return srv_usage_error("relight", "DIR '%s': path too long", dir);
    }
    gs_status st = rec_sources_read(path, &src, &meta, &files);
    if (st == GS_OK && (st = rec_relight_budget(path, &meta, src.S)) != GS_OK) {
        rec_sources_release(&src);
        free(files);
    }
    if (st != GS_OK) return srv_error("relight", st);
    rec_relight_set set[REC_MAX_SOURCES];
    unsigned given[REC_MAX_SOURCES] = {0};
    memset(set, 0, sizeof set);
    for (int s = 0; s < src.S; s++) set[s].gain = 1;
    for (int i = 0; i < nsets; i++)
        if (!parse_set(sets[i], src.S, set, given)) {
            rec_sources_release(&src);
            free(files);
            return 2;
        }
    size_t P = (size_t)meta.width * meta.height, n = P * (size_t)meta.bands;
    float *tq = malloc(sizeof *tq * n * (size_t)src.S), *frames = malloc(sizeof *frames * n * (size_t)meta.K);
    float *mean = malloc(sizeof *mean * n);
    gs_delight *d = NULL;
    gs_capture rc = {0}, other = {0};
    if (!tq || !frames || !mean) st = gs_fail(GS_ENOMEM, "out of memory");
    for (int s = 0; s < src.S && st == GS_OK; s++) {
        int w, h, b, pages;
        float *img;
        gs_path_join(path, sizeof path, dir, files[s]);
        if ((st = gs_tiff_read_float(path, &w, &h, &b, &pages, &img)) != GS_OK) break;
        if (w != meta.width || h != meta.height || b != meta.bands || pages != 1)
            st = gs_fail(GS_EFORMAT, "%s: %dx%d, %d bands, %d pages: expected %dx%d, %d bands, 1 page "
                         "(sources.json's capture)", path, w, h, b, pages, meta.width, meta.height, meta.bands);
        else memcpy(tq + (size_t)s * n, img, sizeof *img * n);
        free(img);
    }
    if (st == GS_OK) st = srv_tr_delight(db, &d);
    if (st == GS_OK) st = rec_relight(&src, tq, meta.width, meta.height, d, meta.grid_hz, set, frames);
    if (st == GS_OK) st = rec_frames_to_capture(&meta, frames, &rc);
    for (int k = 0; k < meta.K && st == GS_OK; k++) st = gs_capture_write_frame(out, &rc, k);
    if (st == GS_OK) st = gs_capture_write_json(out, &rc);
    if (st == GS_OK) {
        for (size_t i = 0; i < n; i++) {
            double s = 0;
            for (int k = 0; k < meta.K; k++) s += frames[(size_t)k * n + i];
            mean[i] = (float)(s / meta.K);
        }
        gs_path_join(path, sizeof path, out, "preview.png");
        st = rec_write_image_png(path, mean, meta.width, meta.height, meta.bands, 0);
    }
    if (st == GS_OK) {
        printf("relight: %s: %d frames of %dx%d x %d bands (Eq. 20):", out, meta.K, meta.width,
               meta.height, meta.bands);
        for (int s = 0; s < src.S; s++)
            printf("%s %02d %s@%g x%g", s ? ";" : "", s, set[s].bulb[0] ? set[s].bulb : src.bulb[s],
                   set[s].set_phase ? set[s].phase_deg : src.phase_deg[s], set[s].gain);
        printf("\n");
    }
    if (st == GS_OK && cmp) {
        /* the difference from another capture, on the pixels both give a value for */
        st = gs_capture_read(cmp, &other);
        if (st == GS_OK && (other.width != meta.width || other.height != meta.height || other.bands != meta.bands))
            st = gs_fail(GS_EINVAL, "%s: %dx%d x %d bands: expected %dx%d x %d as the relit capture",
                         cmp, other.width, other.height, other.bands, meta.width, meta.height, meta.bands);
        if (st == GS_OK) {
            float *om = malloc(sizeof *om * n), *rm = malloc(sizeof *rm * n);
            if (!om || !rm) st = gs_fail(GS_ENOMEM, "out of memory");
            else {
                gs_capture_mean_image(&other, 0, om);
                gs_capture_mean_image(&rc, 0, rm);
                for (size_t i = 0; i < n; i++)
                    if (!isfinite(om[i])) rm[i] = NAN;
                double e = srv_tr_rel_error(rm, om, P, meta.bands);
                printf("relight: relative difference of the mean image from %s: %.4f\n", cmp, e);
            }
            free(om);
            free(rm);
        }
    }
    free(tq);
    free(frames);
    free(mean);
    free(files);
    gs_delight_free(d);
    gs_capture_release(&rc);
    gs_capture_release(&other);
    rec_sources_release(&src);
    return st == GS_OK ? 0 : srv_error("relight", st);
}
