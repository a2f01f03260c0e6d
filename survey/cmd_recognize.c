/* cmd_recognize.c - `gridsurvey recognize CAPDIR`: the bulb type and grid phase of every light in
 * a capture directory (paper Sec. 4, Eq. 7): blobs and their per-frame photometry, Eq. 7 over
 * DELIGHT, a table or a "gridsurvey-lights/1" JSON document (docs/recognize-cli.md), and with
 * --maps the per-pixel maps (Fig. 1) and signal plots (Fig. 3). */
#include "survey/internal.h"

#include <errno.h>
#include <getopt.h>
#include <jansson.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define LIGHTS_FORMAT "gridsurvey-lights/1"
#define SIGNAL_PLOT_LIGHTS 12

static const char recognize_usage[] =
    "usage: gridsurvey recognize CAPDIR [OPTIONS]\n"
    "\n"
    "Recognizes the bulb type and electric-grid phase of every light in a capture directory\n"
    "(docs/formats.md, gridsurvey-capture/1): lights as blobs with per-frame photometry, then\n"
    "the paper's Eq. 7 against DELIGHT. Prints a table, or JSON (docs/recognize-cli.md).\n"
    "Free running (locked false), frames whose windows drifted over --max-drift-windows are\n"
    "left out (flag drift; the header says how many); the maps stop at half a window.\n"
    "\n"
    "  --format F              table (default) or json (a gridsurvey-lights/1 document)\n"
    "  --phases 3|6|continuous candidate grid phases: 3 = 0/120/240 deg (default); 6 = those\n"
    "                          and the same + --transformer-deg (delta-wye transformers);\n"
    "                          continuous = any phase, with its 1-sigma uncertainty\n"
    "  --transformer-deg D     AC phase shift of a delta-wye transformer, deg (default 30; with\n"
    "                          --phases 6 not a multiple of 60)\n"
    "  --ambiguous-below X     posterior below which a bulb or phase is reported ambiguous\n"
    "                          (phase null in JSON), 0..1 (default 0.8)\n"
    "  --band-model M          RGB: reddened (default: one brightness times the chromaticity\n"
    "                          reddened by extinction, each band within --chroma-tolerance of\n"
    "                          it), free (one free brightness per band) or chroma (one\n"
    "                          brightness times the chromaticity: the paper's Eq. 7)\n"
    "  --chroma-tolerance F    reddened: relative spread of each band around it, 0.001..1\n"
    "                          (default 0.05), for the first passes: the final pass uses the\n"
    "                          spread measured from the capture's bright lights\n"
    "  --model-error F|auto    relative excess noise of every light (scintillation), 0..1, or\n"
    "                          auto (default): measured from the capture's other lights\n"
    "  --other-prior P|auto    prior probability that a bulb is not in DELIGHT, 0..1 (0: the\n"
    "                          paper's closed world), or auto (default): the share measured\n"
    "                          from the capture's lights\n"
    "  --flat-share F|auto     share of each light's flux that does not flicker (a halo of\n"
    "                          many lamps' light), 0..0.5 of its flickering flux, subtracted\n"
    "                          before Eq. 7; or auto (default): measured from the capture's\n"
    "                          lights (0 unless significant)\n"
    "  --blend-prior P         prior probability that a light is two lights in one aperture,\n"
    "                          0..1 (default 0.1; 0: never a blend by the posterior)\n"
    "  --nested-tests on|off   the tests of each light's best fit against a second light and\n"
    "                          a bulb not in DELIGHT (default on); off: Eq. 7 alone (with\n"
    "                          --band-model chroma --model-error 0 --other-prior 0\n"
    "                          --flat-share 0, exactly the paper's)\n"
    "  --max-drift-windows W   free running: the most a kept frame's windows moved, >= 0, none\n"
    "                          (all of known drift) or auto (default: none if the period was\n"
    "                          measured, else 0.5)\n"
    "  --threshold S           detection threshold of lights and mapped pixels, noise sigmas > 0\n"
    "                          (default 5)\n"
    "  --delight DB            the DELIGHT SQLite file (default: $GRIDSURVEY_DELIGHT, else the\n"
    "                          built-in database from the lamp models)\n"
    "  --maps DIR              also write DIR/phase_map.png, bulb_map.png, confidence_map.png\n"
    "                          (per-pixel Eq. 7, paper Fig. 1) and signals.png (Fig. 3)\n"
    "  --progress              progress on stderr (default: when stderr is a terminal)\n"
    "  -q, --no-progress       no progress\n"
    "  --help                  this text\n";
/* (two strings: one would exceed the 4095 characters C99 promises) */
static const char recognize_examples[] =
    "\n"
    "Examples (build/lab: see gridsurvey help simulate):\n"
    "  gridsurvey recognize build/lab --maps build/lab-maps\n"
    "  gridsurvey recognize build/lab --format json --ambiguous-below 0.9 > build/lab-lights.json\n"
    "  gridsurvey recognize build/lab --band-model chroma --model-error 0 --other-prior 0 --flat-share 0 --nested-tests off\n"
    "\n"
    "Exit status: 0 done, 1 failure (one line on stderr), 2 usage error.\n";

typedef struct {
    const char *capdir, *db, *maps;
    int json;
    int progress;   /* progress on stderr (default: when it is a terminal) */
    rec_eq7_opts eq7;
    double threshold;
} recognize_opts;

/* Progress on stderr when on (--progress, or stderr a terminal); each call overwrites the line. */
static int progress_on;

static void progress(const char *fmt, ...) __attribute__((format(printf, 1, 2)));

static void progress(const char *fmt, ...)
{
    if (!progress_on) return;
    va_list ap;
    va_start(ap, fmt);
    fputs("\r\033[Kgridsurvey recognize: ", stderr);
    vfprintf(stderr, fmt, ap);
    va_end(ap);
    fflush(stderr);
}

static void progress_done(void)
{
    if (!progress_on) return;
    fputs("\r\033[K", stderr);
    fflush(stderr);
}

static void map_progress(void *ctx, double fraction)
{
    (void)ctx;
    progress("per-pixel Eq. 7: %3.0f %% of the lit pixels", 100.0 * fraction);
}

/* "auto" (NaN: measured from the capture) or a number in [0, hi) into *v; 0 when neither. */
static int auto_or_share(const char *arg, double hi, double *v)
{
    if (!strcmp(arg, "auto")) {
        *v = NAN;
        return 1;
    }
    double x;
    if (!gs_parse_number(arg, &x) || !(x >= 0.0 && x < hi)) return 0;
    *v = x;
    return 1;
}

/* Returns -1 to go on, else the exit status. */
static int parse_opts(int argc, char **argv, recognize_opts *o)
{
    static const struct option longs[] = {
        {"format", required_argument, 0, 'f'},
        {"phases", required_argument, 0, 'p'},
        {"transformer-deg", required_argument, 0, 't'},
        {"ambiguous-below", required_argument, 0, 'c'},
        {"threshold", required_argument, 0, 's'},
        {"band-model", required_argument, 0, 'g'},
        {"chroma-tolerance", required_argument, 0, 'T'},
        {"model-error", required_argument, 0, 'e'},
        {"other-prior", required_argument, 0, 'O'},
        {"flat-share", required_argument, 0, 'F'},
        {"blend-prior", required_argument, 0, 'B'},
        {"nested-tests", required_argument, 0, 'N'},
        {"max-drift-windows", required_argument, 0, 'W'},
        {"delight", required_argument, 0, 'd'},
        {"maps", required_argument, 0, 'm'},
        {"progress", no_argument, 0, 'P'},
        {"no-progress", no_argument, 0, 'q'},
        {"help", no_argument, 0, 'h'},
        {0, 0, 0, 0},
    };
    memset(o, 0, sizeof *o);
    rec_eq7_opts_default(&o->eq7);
    o->threshold = 5.0;
    o->progress = isatty(2);
    o->db = getenv("GRIDSURVEY_DELIGHT");
    if (o->db && !*o->db) o->db = NULL;
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, ":hq", longs, NULL)) != -1) {
        switch (c) {
        case 'f':
            if (!strcmp(optarg, "json") || !strcmp(optarg, "table")) o->json = !strcmp(optarg, "json");
            else return srv_usage_error("recognize", "--format '%s': expected table or json", optarg);
            break;
        case 'P': o->progress = 1; break;
        case 'q': o->progress = 0; break;
        case 'd': o->db = optarg; break;
        case 'm': o->maps = optarg; break;
        case 'p':
            if (!strcmp(optarg, "3")) o->eq7.phases = REC_PHASES_3;
            else if (!strcmp(optarg, "6")) o->eq7.phases = REC_PHASES_6;
            else if (!strcmp(optarg, "continuous")) o->eq7.phases = REC_PHASES_CONTINUOUS;
            else return srv_usage_error("recognize", "--phases '%s': expected 3, 6 or continuous", optarg);
            break;
        case 't':
            if (!srv_num_arg("recognize", "--transformer-deg", optarg, -INFINITY, INFINITY, &o->eq7.transformer_deg))
                return 2;
            break;
        case 'c':
            if (!srv_num_arg("recognize", "--ambiguous-below", optarg, 0.0, 1.0, &o->eq7.ambiguous_conf)) return 2;
            break;
        case 'g':
            if (!strcmp(optarg, "reddened")) o->eq7.band_gains = REC_BANDS_REDDENED;
            else if (!strcmp(optarg, "free")) o->eq7.band_gains = REC_BANDS_FREE;
            else if (!strcmp(optarg, "chroma")) o->eq7.band_gains = REC_BANDS_CHROMA;
            else return srv_usage_error("recognize", "--band-model '%s': expected reddened, free or chroma", optarg);
            break;
        case 'T':
            if (!srv_num_arg("recognize", "--chroma-tolerance", optarg, 0.001, 1.0, &o->eq7.chroma_tolerance)) return 2;
            break;
        case 'e':
            if (!auto_or_share(optarg, 1.0, &o->eq7.model_error))
                return srv_usage_error("recognize", "--model-error '%s': expected auto or a fraction from 0 to below 1", optarg);
            break;
        case 'O':
            if (!auto_or_share(optarg, 1.0, &o->eq7.other_prior))
                return srv_usage_error("recognize", "--other-prior '%s': expected auto or a probability from 0 to below 1", optarg);
            break;
        case 'F':
            if (!auto_or_share(optarg, 0.5, &o->eq7.flat_share))
                return srv_usage_error("recognize", "--flat-share '%s': expected auto or a share from 0 to below 0.5", optarg);
            break;
        case 'B':
            if (!srv_num_arg_open("recognize", "--blend-prior", optarg, 0.0, 1.0, SRV_OPEN_HI, &o->eq7.blend_prior))
                return 2;
            break;
        case 'N':
            if (!strcmp(optarg, "on") || !strcmp(optarg, "off")) o->eq7.nested_tests = !strcmp(optarg, "on");
            else return srv_usage_error("recognize", "--nested-tests '%s': expected on or off", optarg);
            break;
        case 'W':
            if (!srv_drift_arg("recognize", optarg, &o->eq7.max_drift_windows)) return 2;
            break;
        case 's':
            if (!srv_num_arg_open("recognize", "--threshold", optarg, 0.0, INFINITY, SRV_OPEN_LO, &o->threshold)) return 2;
            break;
        case 'h': fputs(recognize_usage, stdout), fputs(recognize_examples, stdout); return 0;
        case ':': return srv_usage_error("recognize", "option '%s' needs a value", argv[optind - 1]);
        default: return srv_usage_error("recognize", "unknown option '%s'", argv[optind - 1]);
        }
    }
    if (argc - optind != 1)
        return srv_usage_error("recognize", "%s", argc - optind < 1 ? "expected a capture directory"
                                                   : "expected exactly one capture directory");
    o->capdir = argv[optind];
    return -1;
}

/* ------------------------------------------------------------------ output */

static const struct {
    unsigned bit;
    int match;   /* 0: REC_BLOB_*, 1: REC_MATCH_* */
    const char *name;
} flag_names[] = {
    {REC_BLOB_EDGE, 0, "edge"},
    {REC_BLOB_SATURATED, 0, "saturated"},
    {REC_BLOB_DEBLENDED, 0, "deblended"},
    {REC_BLOB_HDR, 0, "hdr"},
    {REC_BLOB_NO_SIGNAL, 0, "no_signal"},
    {REC_BLOB_PSF_FIT, 0, "psf_fit"},
    {REC_MATCH_UNKNOWN, 1, "unknown"},
    {REC_MATCH_PHASE_AMBIGUOUS, 1, "phase_ambiguous"},
    {REC_MATCH_BULB_AMBIGUOUS, 1, "bulb_ambiguous"},
    {REC_MATCH_DIM, 1, "dim"},
    {REC_MATCH_BAD_INPUT, 1, "bad_input"},
    {REC_MATCH_BLEND, 1, "blend"},
    {REC_MATCH_DRIFT, 1, "drift"},
};
#define N_FLAGS (sizeof flag_names / sizeof *flag_names)

static int has_flag(size_t f, unsigned blob_flags, const rec_match *mt)
{
    return (flag_names[f].match ? mt->flags : blob_flags) & flag_names[f].bit;
}

/* A phase in [0, 360) as printed with this many decimals: 0 where it would read 360 (359.97
 * with one decimal). */
static double shown_deg(double deg, int decimals)
{
    double scale = pow(10.0, decimals);
    return round(deg * scale) / scale >= 360.0 ? 0.0 : deg;
}

static const char *phases_name(rec_phase_set p)
{
    return p == REC_PHASES_6 ? "6" : p == REC_PHASES_CONTINUOUS ? "continuous" : "3";
}

static void print_table(const recognize_opts *o, const gs_capture *cap, const rec_matcher *m,
                        const rec_catalog *cat, const rec_match *mt, const rec_noise_report *noise)
{
    char drift[384];
    srv_drift_note(cap, o->eq7.max_drift_windows, drift, sizeof drift);
    printf("capture %s: %d Hz grid, K = %d, %d band%s, %dx%d pixels%s; DELIGHT %s (%zu candidate "
           "bulbs); phases %s\n",
           o->capdir, cap->grid_hz, cap->K, cap->bands, cap->bands == 1 ? "" : "s", cap->width,
           cap->height, drift,
           o->db ? o->db : "built-in", rec_matcher_bulb_count(m),
           o->eq7.phases == REC_PHASES_3 ? "0/120/240 deg"
           : o->eq7.phases == REC_PHASES_6 ? "0/120/240 deg and + transformer" : "continuous");
    printf("excess noise: %s", rec_noise_source_name(noise->source));
    if (noise->source == REC_NOISE_POPULATION)
        printf(" (median %.4f, from %zu lights)", noise->median_model_error, noise->lights_used);
    else if (noise->source == REC_NOISE_FIXED)
        printf(" (%.4f)", noise->median_model_error);
    else
        printf(" (too few lights to measure it: the camera's noise alone)");
    if (cap->bands > 1 && o->eq7.band_gains == REC_BANDS_REDDENED)
        printf("; reddening prior: %s", noise->reddening_lights ? "population" : "uniform");
    if (noise->reddening_lights)
        printf(" (from %zu lights), band tolerance %.3f", noise->reddening_lights, noise->chroma_tolerance);
    if (noise->other_lights)
        printf("; bulbs not in DELIGHT: %.1f %% (from %zu lights)", 100.0 * noise->other_prior, noise->other_lights);
    if (noise->flat_share > 0.0)
        printf("; flat share %.4f%s", noise->flat_share, noise->flat_lights ? " (measured, each light's within its spread)" : "");
    static const char *const kinds[REC_FLAT_KINDS] = REC_FLAT_KIND_NAMES;
    for (int k = 0; k < REC_FLAT_KINDS; k++)
        if (noise->flat_kind_lights[k])
            printf("; %s %.4f (from %zu lights)", kinds[k], noise->flat_kind_share[k], noise->flat_kind_lights[k]);
    printf("\n");
    printf("%4s %8s %8s %5s  %-22s %-22s %15s %6s  %-28s %9s %9s  %s\n", "id", "x", "y", "area",
           "bulb", "technology", "phase (deg)", "conf", "runner-up (conf)", "chi2/dof", "p-value",
           "flags");
    size_t with_bulb = 0, with_phase = 0;
    for (size_t i = 0; i < cat->count; i++) {
        const rec_match *r = &mt[i];
        const gs_bulb *b = r->bulb >= 0 ? rec_matcher_bulb(m, (size_t)r->bulb) : NULL;
        const gs_bulb *rb = r->runner_bulb >= 0 ? rec_matcher_bulb(m, (size_t)r->runner_bulb) : NULL;
        char phase[32] = "-", runner[64] = "-", flags[160] = "", chi[32];
        if (rec_match_phase_known(m, r)) {
            snprintf(phase, sizeof phase, "%.1f +- %.1f", shown_deg(r->phase_deg, 1), r->phase_sigma_deg);
            with_phase++;
        }
        if (b) with_bulb++;
        if (rb)
            snprintf(runner, sizeof runner, "%s @ %.0f (%.3f)", rb->id, shown_deg(r->runner_phase_deg, 0),
                     r->runner_confidence);
        for (size_t f = 0; f < N_FLAGS; f++)
            if (has_flag(f, cat->flags[i], r)) {
                size_t used = strlen(flags);
                snprintf(flags + used, sizeof flags - used, "%s%s", used ? "," : "", flag_names[f].name);
            }
        snprintf(chi, sizeof chi, "%.2f", r->dof > 0 ? r->chi2 / r->dof : r->chi2);
        printf("%4zu %8.2f %8.2f %5d  %-22s %-22s %15s %6.3f  %-28s %9s %9.3g  %s\n", i,
               cat->x_px[i], cat->y_px[i], cat->area_px[i], b ? b->id : "unknown",
               b ? gs_tech_name(b->type) : "-", phase, r->confidence, runner, chi, r->p_value,
               *flags ? flags : "-");
    }
    printf("%zu light%s: %zu with a bulb, %zu with a phase\n", cat->count, cat->count == 1 ? "" : "s", with_bulb,
           with_phase);
}

/* json_real that never holds NaN/Inf (the library's fields are finite; this is a guard). */
static json_t *jreal(double v)
{
    return isfinite(v) ? json_real(v) : json_null();
}

static json_t *light_json(const rec_matcher *m, const rec_catalog *cat, const rec_match *r, size_t i)
{
    const gs_bulb *b = r->bulb >= 0 ? rec_matcher_bulb(m, (size_t)r->bulb) : NULL;
    const gs_bulb *rb = r->runner_bulb >= 0 ? rec_matcher_bulb(m, (size_t)r->runner_bulb) : NULL;
    int ph = rec_match_phase_known(m, r);
    json_t *l = json_object();
    json_object_set_new(l, "id", json_integer((json_int_t)i));
    json_object_set_new(l, "x", jreal(cat->x_px[i]));
    json_object_set_new(l, "y", jreal(cat->y_px[i]));
    json_object_set_new(l, "area_px", json_integer(cat->area_px[i]));
    json_object_set_new(l, "peak_dn", jreal(cat->peak_dn[i]));
    json_object_set_new(l, "saturated_px", json_integer(cat->saturated_px[i]));
    json_object_set_new(l, "brightness", jreal(r->brightness));
    json_object_set_new(l, "bulb", b ? json_string(b->id) : json_null());
    json_object_set_new(l, "technology", b ? json_string(gs_tech_name(b->type)) : json_null());
    json_object_set_new(l, "phase_deg", ph ? jreal(r->phase_deg) : json_null());
    json_object_set_new(l, "phase_sigma_deg", ph ? jreal(r->phase_sigma_deg) : json_null());
    json_object_set_new(l, "confidence", jreal(r->confidence));
    json_object_set_new(l, "bulb_confidence", jreal(r->bulb_confidence));
    json_object_set_new(l, "phase_confidence", jreal(r->phase_confidence));
    if (rb) {
        json_t *ru = json_object();
        json_object_set_new(ru, "bulb", json_string(rb->id));
        json_object_set_new(ru, "technology", json_string(gs_tech_name(rb->type)));
        json_object_set_new(ru, "phase_deg", jreal(r->runner_phase_deg));
        json_object_set_new(ru, "confidence", jreal(r->runner_confidence));
        json_object_set_new(l, "runner_up", ru);
    } else {
        json_object_set_new(l, "runner_up", json_null());
    }
    json_object_set_new(l, "chi2", jreal(r->chi2));
    json_object_set_new(l, "dof", json_integer(r->dof));
    json_object_set_new(l, "p_value", jreal(r->p_value));
    json_object_set_new(l, "model_error", jreal(r->model_error));
    json_object_set_new(l, "shape_p_value", jreal(r->shape_p_value));
    json_object_set_new(l, "p_other", jreal(r->p_other));
    json_object_set_new(l, "p_blend", jreal(r->p_blend));
    if (r->flags & REC_MATCH_BLEND) {
        json_t *bl = json_array();
        for (int q = 0; q < 2; q++) {
            const gs_bulb *cb = rec_matcher_bulb(m, (size_t)r->blend_bulb[q]);
            json_t *c = json_object();
            json_object_set_new(c, "bulb", json_string(cb->id));
            json_object_set_new(c, "technology", json_string(gs_tech_name(cb->type)));
            json_object_set_new(c, "phase_deg", cb->ref == GS_REF_VOLTAGE ? jreal(r->blend_phase_deg[q]) : json_null());
            json_object_set_new(c, "share", jreal(r->blend_share[q]));
            json_array_append_new(bl, c);
        }
        json_object_set_new(l, "blend", bl);
    } else {
        json_object_set_new(l, "blend", json_null());
    }
    json_object_set_new(l, "blend_p_value", jreal(r->blend_p_value));
    json_t *fl = json_array();
    for (size_t f = 0; f < N_FLAGS; f++)
        if (has_flag(f, cat->flags[i], r)) json_array_append_new(fl, json_string(flag_names[f].name));
    json_object_set_new(l, "flags", fl);
    return l;
}

static const char *band_model_name(int bm)
{
    return bm == REC_BANDS_REDDENED ? "reddened" : bm == REC_BANDS_FREE ? "free" : "chroma";
}

static gs_status print_json(const recognize_opts *o, const gs_capture *cap, const rec_matcher *m,
                            const rec_catalog *cat, const rec_match *mt, const rec_noise_report *noise)
{
    json_t *root = json_object();
    json_object_set_new(root, "format", json_string(LIGHTS_FORMAT));
    json_t *c = json_object();
    json_object_set_new(c, "dir", json_string(o->capdir));
    json_object_set_new(c, "grid_hz", json_integer(cap->grid_hz));
    json_object_set_new(c, "K", json_integer(cap->K));
    json_object_set_new(c, "bands", json_integer(cap->bands));
    json_object_set_new(c, "width", json_integer(cap->width));
    json_object_set_new(c, "height", json_integer(cap->height));
    json_object_set_new(c, "locked", json_boolean(cap->locked));
    const char *period = gs_period_name(cap->window_period);
    json_object_set_new(c, "window_period", period ? json_string(period) : json_null());
    double drift = gs_capture_window_drift(cap, NULL);
    json_object_set_new(c, "drift_windows", isfinite(drift) ? json_real(drift) : json_null());
    json_object_set_new(c, "frames_left_out", json_integer(rec_frames_left_out(cap, o->eq7.max_drift_windows, NULL)));
    json_object_set_new(c, "utc", cap->utc[0] ? json_string(cap->utc) : json_null());
    json_t *station = cap->station_json ? json_loads(cap->station_json, 0, NULL) : NULL;
    json_object_set_new(c, "station", station ? station : json_null());
    json_object_set_new(root, "capture", c);
    json_t *r = json_object();
    json_object_set_new(r, "delight", o->db ? json_string(o->db) : json_string("built-in"));
    json_object_set_new(r, "candidates", json_integer((json_int_t)rec_matcher_bulb_count(m)));
    json_object_set_new(r, "phases", json_string(phases_name(o->eq7.phases)));
    json_object_set_new(r, "transformer_deg", jreal(o->eq7.transformer_deg));
    json_object_set_new(r, "min_confidence", jreal(o->eq7.ambiguous_conf));
    json_object_set_new(r, "unknown_p", jreal(o->eq7.unknown_p));
    json_object_set_new(r, "min_snr", jreal(o->eq7.min_snr));
    json_object_set_new(r, "max_drift_windows", jreal(rec_drift_limit(o->eq7.max_drift_windows, cap->window_period)));
    json_object_set_new(r, "max_drift_windows_auto", json_boolean(o->eq7.max_drift_windows == REC_DRIFT_AUTO));
    json_object_set_new(r, "threshold_sigma", jreal(o->threshold));
    json_object_set_new(r, "band_model", json_string(cap->bands > 1 ? band_model_name(o->eq7.band_gains) : "mono"));
    json_object_set_new(r, "chroma_tolerance", jreal(o->eq7.chroma_tolerance));
    json_object_set_new(r, "other_prior", isnan(o->eq7.other_prior) ? json_string("auto") : jreal(o->eq7.other_prior));
    json_object_set_new(r, "flat_share", isnan(o->eq7.flat_share) ? json_string("auto") : jreal(o->eq7.flat_share));
    json_object_set_new(r, "blend_prior", jreal(o->eq7.blend_prior));
    json_object_set_new(r, "nested_tests", json_boolean(o->eq7.nested_tests));
    json_object_set_new(r, "model_error", isnan(o->eq7.model_error) ? json_string("auto") : jreal(o->eq7.model_error));
    json_t *nz = json_object();
    json_object_set_new(nz, "source", json_string(rec_noise_source_name(noise->source)));
    json_object_set_new(nz, "lights_used", json_integer((json_int_t)noise->lights_used));
    json_object_set_new(nz, "median_model_error", jreal(noise->median_model_error));
    json_object_set_new(nz, "reddening_prior_lights", json_integer((json_int_t)noise->reddening_lights));
    json_object_set_new(nz, "chroma_tolerance", jreal(noise->chroma_tolerance));
    json_object_set_new(nz, "other_prior", jreal(noise->other_prior));
    json_object_set_new(nz, "flat_share", jreal(noise->flat_share));
    json_object_set_new(nz, "flat_spread", jreal(noise->flat_spread));
    json_object_set_new(nz, "flat_lights", json_integer((json_int_t)noise->flat_lights));
    static const char *const kinds[REC_FLAT_KINDS] = REC_FLAT_KIND_NAMES;
    json_t *fk = json_object();
    for (int k = 0; k < REC_FLAT_KINDS; k++) {
        json_t *e = json_object();
        json_object_set_new(e, "share", jreal(noise->flat_kind_share[k]));
        json_object_set_new(e, "lights", json_integer((json_int_t)noise->flat_kind_lights[k]));
        json_object_set_new(fk, kinds[k], e);
    }
    json_object_set_new(nz, "flat_kinds", fk);
    json_object_set_new(nz, "other_lights", json_integer((json_int_t)noise->other_lights));
    json_object_set_new(r, "noise", nz);
    json_object_set_new(root, "recognition", r);
    size_t with_bulb = 0, with_phase = 0;
    json_t *lights = json_array();
    for (size_t i = 0; i < cat->count; i++) {
        with_bulb += mt[i].bulb >= 0;
        with_phase += (size_t)rec_match_phase_known(m, &mt[i]);
        json_array_append_new(lights, light_json(m, cat, &mt[i], i));
    }
    json_t *s = json_object();
    json_object_set_new(s, "lights", json_integer((json_int_t)cat->count));
    json_object_set_new(s, "with_bulb", json_integer((json_int_t)with_bulb));
    json_object_set_new(s, "with_phase", json_integer((json_int_t)with_phase));
    json_object_set_new(root, "summary", s);
    json_object_set_new(root, "lights", lights);
    gs_status st = GS_OK;
    if (json_dumpf(root, stdout, JSON_INDENT(2) | JSON_PRESERVE_ORDER | JSON_REAL_PRECISION(12)) != 0)
        st = gs_fail(GS_EIO, "stdout: cannot write the JSON document");
    else
        putchar('\n');
    json_decref(root);
    return st;
}

/* ------------------------------------------------------------------ maps */

/* Create the --maps directory (one level) up front, so a bad path fails before any work. */
static gs_status maps_dir(const char *dir)
{
    if (mkdir(dir, 0777) != 0 && errno != EEXIST)
        return gs_fail(GS_EIO, "%s: cannot create the maps directory: %s", dir, strerror(errno));
    struct stat sb;
    if (stat(dir, &sb) != 0 || !S_ISDIR(sb.st_mode))
        return gs_fail(GS_EIO, "%s: not a directory (--maps)", dir);
    return GS_OK;
}

static gs_status write_maps(const recognize_opts *o, const gs_capture *cap, const rec_matcher *m,
                            const rec_catalog *cat, const rec_match *mt)
{
    char path[4096];
    rec_pixel_maps pm;
    rec_map_opts mo;
    rec_map_opts_default(&mo);
    mo.threshold_sigma = o->threshold;
    mo.progress = map_progress;
    progress("per-pixel Eq. 7 ...");
    gs_status st = rec_pixel_maps_compute(cap, m, &o->eq7, &mo, &pm);
    if (st != GS_OK) return st;
    if (pm.drift_unanswered)
        fprintf(stderr, "gridsurvey recognize: note: the maps answer no pixel: a frame's windows drifted over "
                        "%g windows in this free-running capture, which a pixel's one noise level cannot model "
                        "(docs/recognition.md, \"Free-running captures\")\n",
                pm.drift_limit_windows);
    progress("drawing maps ...");
    snprintf(path, sizeof path, "%s/phase_map.png", o->maps);
    st = rec_map_write_phase_png(&pm, path);
    if (st == GS_OK) {
        snprintf(path, sizeof path, "%s/bulb_map.png", o->maps);
        st = rec_map_write_bulb_png(&pm, m, path);
    }
    if (st == GS_OK) {
        snprintf(path, sizeof path, "%s/confidence_map.png", o->maps);
        st = rec_map_write_confidence_png(&pm, path);
    }
    if (st == GS_OK) {
        snprintf(path, sizeof path, "%s/signals.png", o->maps);
        char title[160];
        snprintf(title, sizeof title, "%d Hz, K = %d", cap->grid_hz, cap->K);
        st = rec_plot_signals(m, cat, mt, SIGNAL_PLOT_LIGHTS, path, title);
    }
    rec_pixel_maps_release(&pm);
    return st;
}

/* ------------------------------------------------------------------ command */

int srv_cmd_recognize(int argc, char **argv)
{
    recognize_opts o;
    int rc = parse_opts(argc, argv, &o);
    if (rc >= 0) return rc;
    progress_on = o.progress;

    srv_job j;
    memset(&j, 0, sizeof j);
    gs_status st = o.maps ? maps_dir(o.maps) : GS_OK;
    if (st == GS_OK) {
        progress("reading %s ...", o.capdir);
        st = srv_job_read(&j, o.capdir);
    }
    if (st == GS_OK) {
        progress("loading DELIGHT, building Eq. 7 templates ...");
        st = srv_job_matcher(&j, NULL, o.db, j.cap.grid_hz, j.cap.bands, j.cap.K, &o.eq7);
    }
    if (st == GS_OK) {
        progress("extracting lights ...");
        rec_blob_opts bo;
        rec_blob_opts_default(&bo);
        bo.threshold_sigma = o.threshold;
        st = srv_job_extract(&j, &bo);
    }
    if (st == GS_OK) {
        progress("matching %zu lights ...", j.cat.count);
        st = srv_job_match(&j);
    }
    if (st == GS_OK && o.maps) st = write_maps(&o, &j.cap, j.matcher, &j.cat, j.match);
    progress_done();
    if (st == GS_OK) {
        if (o.json) st = print_json(&o, &j.cap, j.matcher, &j.cat, j.match, &j.noise);
        else print_table(&o, &j.cap, j.matcher, &j.cat, j.match, &j.noise);
        if (fflush(stdout) != 0 && st == GS_OK) st = gs_fail(GS_EIO, "stdout: write failed");
    }
    srv_job_release(&j);
    return st == GS_OK ? 0 : srv_error("recognize", st);
}
