/* cli.c - gridsurvey's git-style subcommand dispatch and shared option helpers. */
#include "survey/internal.h"
#include "gis/gis.h"
#include "recognize/recognize.h"
#include "version.h"   /* GS_GIT_COMMIT, written by the Makefile into $(BUILD) */

#include <ctype.h>
#include <errno.h>
#include <fftw3.h>
#include <getopt.h>
#include <jansson.h>
#include <math.h>
#include <plplot.h>
#include <stdarg.h>
#include <sndfile.h>
#include <spng.h>
#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <tiffio.h>

static const struct {
    const char *name;
    int (*run)(int argc, char **argv);
    const char *summary;
} commands[] = {
    {"delight", srv_cmd_delight, "the DELIGHT bulb database: list, show, export, import, add, plot, generate"},
    {"locate", srv_cmd_locate, "locate lights from one station's pixels; GeoJSON, KML, GeoPackage, CSV, map"},
    {"simulate", srv_cmd_simulate, "render a scene into a capture directory and truth.json (ACam simulator)"},
    {"capture", srv_cmd_capture, "run the ACam acquisition loop: --backend sim, replay or hardware"},
    {"stats", srv_cmd_stats, "phase-balance statistics of a survey database (shares, Wilson CIs, chi-square)"},
    {"export", srv_cmd_export, "export a survey database's lights as GeoJSON, KML, GeoPackage or CSV"},
    {"push", srv_cmd_push, "copy a survey database into a shared PostgreSQL + PostGIS database"},
    {"db", srv_cmd_db, "survey database tools: init, migrate, check, ingest-synthetic"},
    {"recognize", srv_cmd_recognize, "bulb type and grid phase of every light in a capture (Eq. 7); maps, plots"},
    {"run", srv_cmd_run, "the whole job: capture (or a capture directory), recognize, locate, store; stats, maps"},
    {"compare", srv_cmd_compare, "changes between two surveys: rephased or replaced lights, appeared, vanished"},
    {"evaluate", srv_cmd_evaluate, "compare a survey database with a simulator's truth.json (rates, errors)"},
    {"unmix", srv_cmd_unmix, "light transport: unmix a capture into one image per source (Eqs. 16-19)"},
    {"relight", srv_cmd_relight, "relight unmixed sources: gain, off, other bulb or phase (Eq. 20)"},
    {"separate", srv_cmd_separate, "separate a window's reflection from the daylit scene behind it (Sec. 5.3)"},
    {"bench", srv_cmd_bench, "performance tables: recognize (Eq. 7), db, pg, render, blobs, accuracy, transport"},
};

static void usage(FILE *f)
{
    fprintf(f, "usage: gridsurvey [--max-memory SIZE] COMMAND [ARGS]   (gridsurvey help COMMAND\n"
               "       for details; gridsurvey --version)\n\n"
               "Surveys a city's electric grid from its lights at night (bulb type and grid phase\n"
               "of every light, from an AC-locked coded-exposure camera).\n\n"
               "  --max-memory SIZE  the memory budget for an input's pixels and working images,\n"
               "                     e.g. 4G (default: half the RAM, or $GS_MAX_MEMORY); accepted\n"
               "                     before or after COMMAND\n\ncommands:\n");
    for (size_t i = 0; i < sizeof commands / sizeof *commands; i++)
        fprintf(f, "  %-10s %s\n", commands[i].name, commands[i].summary);
}

/* gridsurvey --version: the tool, the commit it was built from, the libraries it runs with. */
static int version(void)
{
    printf("%s (git %s)\n", SRV_GENERATOR, GS_GIT_COMMIT);
    printf("SQLite %s, Jansson %s, %s, %s, libspng %s, OpenCV %s, GeographicLib %s\n",
           sqlite3_libversion(), jansson_version_str(), fftw_version, sf_version_string(),
           spng_version_string(), rec_opencv_version(), gis_geographiclib_version());
    char pl[80];
    plgver(pl);
    const char *tiff = TIFFGetVersion(), *nl = strchr(tiff, '\n');
    printf("PLplot %s, %.*s\n", pl, nl ? (int)(nl - tiff) : (int)strlen(tiff), tiff);
    return 0;
}

static int find_command(const char *name)
{
    for (size_t i = 0; i < sizeof commands / sizeof *commands; i++)
        if (!strcmp(name, commands[i].name)) return (int)i;
    fprintf(stderr, "gridsurvey: '%s' is not a command: expected one of", name);
    for (size_t i = 0; i < sizeof commands / sizeof *commands; i++)
        fprintf(stderr, " %s", commands[i].name);
    fprintf(stderr, " (see gridsurvey --help)\n");
    return -1;
}

/* The memory budget from what (--max-memory or GS_MAX_MEMORY) and its text: 0, or 2 after a
 * one-line usage error. */
static int set_max_memory(const char *what, const char *text)
{
    size_t bytes;
    if (gs_mem_parse(what, text, &bytes) != GS_OK) {
        fprintf(stderr, "gridsurvey: %s (see gridsurvey --help)\n", gs_detail());
        return 2;
    }
    gs_mem_budget_set(bytes);
    return 0;
}

/* Take the global --max-memory SIZE (or --max-memory=SIZE) out of argv, wherever it is before
 * a "--" (*given = 1). Returns 0, or 2 after a one-line usage error. */
static int take_max_memory(int *argc, char **argv, int *given)
{
    for (int i = 1; i < *argc && strcmp(argv[i], "--"); i++) {
        const char *v = NULL;
        int used = 0;
        if (!strcmp(argv[i], "--max-memory")) {
            if (i + 1 >= *argc) {
                fprintf(stderr, "gridsurvey: --max-memory needs a SIZE, e.g. 4G (see gridsurvey --help)\n");
                return 2;
            }
            v = argv[i + 1];
            used = 2;
        } else if (!strncmp(argv[i], "--max-memory=", 13)) {
            v = argv[i] + 13;
            used = 1;
        }
        if (!used) continue;
        if (set_max_memory("--max-memory", v)) return 2;
        *given = 1;
        for (int j = i; j + used <= *argc; j++) argv[j] = argv[j + used];   /* with the NULL */
        *argc -= used;
        i--;
    }
    return 0;
}

int srv_main(int argc, char **argv)
{
    opterr = 0;   /* the commands say what is wrong in one line of their own */
    int given = 0;
    if (take_max_memory(&argc, argv, &given)) return 2;
    if (argc < 2) {
        usage(stderr);
        return 2;
    }
    if (!strcmp(argv[1], "--version") || !strcmp(argv[1], "version")) return version();
    /* (help is a command too: `help --help` and `help help` are its usage) */
    int help_help = !strcmp(argv[1], "help") &&
                    (argc < 3 || !strcmp(argv[2], "--help") || !strcmp(argv[2], "-h") || !strcmp(argv[2], "help"));
    if (!strcmp(argv[1], "--help") || !strcmp(argv[1], "-h") || help_help) {
        usage(stdout);
        return 0;
    }
    if (!strcmp(argv[1], "help")) {   /* gridsurvey help CMD [SUB] = gridsurvey CMD [SUB] --help */
        int c = find_command(argv[2]);
        if (c < 0) return 2;
        char help[] = "--help";
        char *args[4] = {argv[2], argc > 3 ? argv[3] : help, argc > 3 ? help : NULL, NULL};
        return commands[c].run(argc > 3 ? 3 : 2, args);
    }
    int c = find_command(argv[1]);
    if (c < 0) return 2;
    /* without --max-memory, $GS_MAX_MEMORY, checked here: a bad value does not stop the help */
    const char *env = getenv("GS_MAX_MEMORY");
    if (!given && env && *env && set_max_memory("GS_MAX_MEMORY", env)) return 2;
    return commands[c].run(argc - 1, argv + 1);
}

int srv_usage_error(const char *cmd, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "gridsurvey %s: ", cmd);
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, " (see gridsurvey help %s)\n", cmd);
    va_end(ap);
    return 2;
}

int srv_usage_hint(const char *cmd, char **argv)
{
    return srv_usage_error(cmd, "unknown option or missing value: '%s'", optind > 1 ? argv[optind - 1] : "");
}

int srv_out_dir_hint(const char *cmd)
{
    return srv_usage_error(cmd, "-o names an output file; this command writes a directory: --out-dir DIR");
}

int srv_error(const char *cmd, gs_status s)
{
    /* the module's own "CMD: " (relight.c's "relight: source 00: ...") is the command's name */
    const char *d = gs_detail();
    size_t n = strlen(cmd);
    if (!strncmp(d, cmd, n) && d[n] == ':' && d[n + 1] == ' ') d += n + 2;
    fprintf(stderr, "gridsurvey %s: %s\n", cmd, *d ? d : gs_strerror(s));
    return 1;
}

FILE *srv_note_stream(const char *out)
{
    return out && !strcmp(out, "-") ? stderr : stdout;
}

/* The unit an option's name ends with (--light-height-m: " m"), "" for none: its range's. */
static const char *opt_unit(const char *opt)
{
    static const char *const units[][2] = {{"-m", " m"}, {"-px", " px"}, {"-deg", " deg"}, {"-hz", " Hz"}, {"-s", " s"}};
    size_t n = strlen(opt);
    for (size_t i = 0; i < sizeof units / sizeof *units; i++) {
        size_t k = strlen(units[i][0]);
        if (n > k && !strcmp(opt + n - k, units[i][0])) return units[i][1];
    }
    return "";
}

int srv_num_arg_open(const char *cmd, const char *opt, const char *arg, double lo, double hi, int open, double *out)
{
    double v = NAN;
    int in = gs_parse_number(arg, &v) && (open & SRV_OPEN_LO ? v > lo : v >= lo) &&
             (open & SRV_OPEN_HI ? v < hi : v <= hi);
    if (in) {
        *out = v;
        return 1;
    }
    char range[96] = "";
    if (!open && isfinite(lo) && isfinite(hi)) {
        snprintf(range, sizeof range, " from %g to %g", lo, hi);
    } else {
        if (isfinite(lo)) snprintf(range, sizeof range, " %s %g", open & SRV_OPEN_LO ? ">" : ">=", lo);
        if (isfinite(hi))
            snprintf(range + strlen(range), sizeof range - strlen(range), "%s %s %g", isfinite(lo) ? " and" : "",
                     open & SRV_OPEN_HI ? "<" : "<=", hi);
    }
    srv_usage_error(cmd, "%s '%s': expected a %snumber%s%s", opt, arg, *range ? "" : "finite ", range,
                    *range ? opt_unit(opt) : "");
    return 0;
}

int srv_num_arg(const char *cmd, const char *opt, const char *arg, double lo, double hi, double *out)
{
    return srv_num_arg_open(cmd, opt, arg, lo, hi, 0, out);
}

int srv_drift_arg(const char *cmd, const char *arg, double *out)
{
    if (!strcmp(arg, "none") || !strcmp(arg, "auto")) {
        *out = arg[0] == 'n' ? INFINITY : REC_DRIFT_AUTO;
        return 1;
    }
    if (gs_parse_number(arg, out) && *out >= 0) {
        *out += 0.0;   /* (-0 is 0) */
        return 1;
    }
    srv_usage_error(cmd, "--max-drift-windows '%s': expected a number >= 0, none or auto", arg);
    return 0;
}

int srv_choice_arg(const char *cmd, const char *opt, const char *arg, int a, int b, int *out)
{
    char sa[16], sb[16];
    snprintf(sa, sizeof sa, "%d", a);
    snprintf(sb, sizeof sb, "%d", b);
    if (strcmp(arg, sa) && strcmp(arg, sb)) {
        srv_usage_error(cmd, "%s '%s': expected %d or %d", opt, arg, a, b);
        return 0;
    }
    *out = strcmp(arg, sa) ? b : a;
    return 1;
}

int srv_int_arg(const char *cmd, const char *opt, const char *arg, unsigned long long lo, unsigned long long hi,
                unsigned long long *out)
{
    /* digits only: strtoull takes " -1" as 2^64 - 1 */
    int digit = isdigit((unsigned char)*arg) != 0;
    char *end = NULL;
    errno = 0;
    unsigned long long v = digit ? strtoull(arg, &end, 10) : 0;
    if (!digit || *end || errno == ERANGE || v < lo || v > hi) {
        srv_usage_error(cmd, "%s '%s': expected an integer from %llu to %llu", opt, arg, lo, hi);
        return 0;
    }
    *out = v;
    return 1;
}
