/* cmd_delight.c - `gridsurvey delight`: list, show, export, import, add, plot and generate the
 * DELIGHT bulb database (paper Sec. 3; our substitute is described in docs/delight.md). */
#include "survey/internal.h"

#include <errno.h>
#include <fcntl.h>
#include <getopt.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

static const char delight_usage[] =
    "usage: gridsurvey delight SUBCOMMAND [OPTIONS]\n"
    "\n"
    "  list      [--grid 50|60] [--sensor S]     one line per entry with its percent flicker\n"
    "  show      ID [--grid 50|60] [--sensor S]  an entry's metadata and its BRF at K=26\n"
    "  export    [-o FILE.csv]                   CSV (docs/delight.md) to FILE or stdout\n"
    "  import    FILE.csv...  --delight DB       add CSV entries to DB (created if missing)\n"
    "  add       --from-recording FILE [--voltage-column C] [--id ID] [--name NAME]\n"
    "            [--type TECH] [--watts W] [--grid 50|60] --delight DB\n"
    "                                            a photodiode recording (time,value CSV) as a BRF\n"
    "  plot      -o FILE.png [--ids A,B,...] [--grid 50|60] [--sensor S]\n"
    "                                            BRFs over one cycle per band (paper Fig. 2)\n"
    "  generate  -o DB [--n N]                   write the built-in database to a SQLite file\n"
    "\n"
    "Common options:\n"
    "  --delight DB   the DELIGHT SQLite file (default: $GRIDSURVEY_DELIGHT, else the built-in\n"
    "                 database generated in memory from the lamp models)\n"
    "  --help         this text\n"
    "\n"
    "Examples:\n"
    "  gridsurvey delight list --grid 50\n"
    "  gridsurvey delight show hps-70w --grid 50\n"
    "  gridsurvey delight export -o delight.csv\n"
    "  gridsurvey delight import delight.csv --delight my-delight.sqlite\n"
    "  gridsurvey delight add --from-recording lamp.csv --id my-lamp --type led_linear --watts 9 \\\n"
    "                         --grid 50 --delight my-delight.sqlite\n"
    "  gridsurvey delight plot --ids inc-a19-60w-120v,hps-150w --grid 60 -o brfs.png\n"
    "  gridsurvey delight generate -o delight.sqlite\n";

typedef struct {
    const char *db, *out, *ids, *recording, *id, *name, *sensor;
    int grid_hz, voltage_column, n, has_type;
    gs_tech type;   /* --type, when has_type */
    double watts;
} delight_opts;

/* Parse the options shared by the subcommands; positional arguments stay in argv[optind..). */
static int parse_opts(int argc, char **argv, delight_opts *o)
{
    static const struct option longs[] = {
        {"delight", required_argument, 0, 'd'},
        {"ids", required_argument, 0, 'i'},     {"from-recording", required_argument, 0, 'r'},
        {"id", required_argument, 0, 'I'},      {"name", required_argument, 0, 'N'},
        {"type", required_argument, 0, 't'},    {"grid", required_argument, 0, 'g'},
        {"sensor", required_argument, 0, 's'},  {"voltage-column", required_argument, 0, 'v'},
        {"n", required_argument, 0, 'n'},       {"watts", required_argument, 0, 'w'},
        {"help", no_argument, 0, 'h'},          {0, 0, 0, 0},
    };
    memset(o, 0, sizeof *o);
    o->db = getenv("GRIDSURVEY_DELIGHT");
    if (o->db && !*o->db) o->db = NULL;
    o->n = GS_BRF_N_DEFAULT;
    optind = 1;
    int c;
    unsigned long long v;
    while ((c = getopt_long(argc, argv, "o:h", longs, NULL)) != -1) {
        switch (c) {
        case 'd': o->db = optarg; break;
        case 'o': o->out = optarg; break;
        case 'i': o->ids = optarg; break;
        case 'r': o->recording = optarg; break;
        case 'I': o->id = optarg; break;
        case 'N': o->name = optarg; break;
        case 't':
            if (gs_tech_parse(optarg, &o->type) != GS_OK) return srv_usage_error("delight", "--type: %s", gs_detail());
            o->has_type = 1;
            break;
        case 's': o->sensor = optarg; break;
        case 'g':
            if (!srv_choice_arg("delight", "--grid", optarg, 50, 60, &o->grid_hz)) return 2;
            break;
        case 'v':
            if (!srv_int_arg("delight", "--voltage-column", optarg, 2, INT_MAX, &v)) return 2;
            o->voltage_column = (int)v;
            break;
        case 'n':
            /* 2^20: gs_delight_generate's and the BRF's largest n */
            if (!srv_int_arg("delight", "--n", optarg, 256, 1 << 20, &v)) return 2;
            if (v % 2) return srv_usage_error("delight", "--n '%s': expected an even number", optarg);
            o->n = (int)v;
            break;
        case 'w':
            if (!srv_num_arg_open("delight", "--watts", optarg, 0.0, GS_WATTS_MAX, SRV_OPEN_LO | SRV_OPEN_HI, &o->watts))
                return 2;
            break;
        case 'h': fputs(delight_usage, stdout); return 0;
        default: return srv_usage_hint("delight", argv);
        }
    }
    return -1;
}

/* The database to read: the --delight file, or the built-in one. */
static gs_status open_delight(const delight_opts *o, gs_delight **out)
{
    gs_delight *d = gs_delight_new();
    if (!d) return gs_fail(GS_ENOMEM, "cannot allocate the DELIGHT database");
    gs_status s = o->db ? gs_delight_load(d, o->db) : gs_delight_generate(d, o->n);
    if (s != GS_OK) {
        gs_delight_free(d);
        return s;
    }
    *out = d;
    return GS_OK;
}

static int matches(const gs_bulb *b, const delight_opts *o)
{
    return (!o->grid_hz || b->grid_hz == o->grid_hz) && (!o->sensor || !strcmp(b->sensor, o->sensor));
}

/* 1 if one of the first n entries of d was measured with sensor. */
static int has_sensor(const gs_delight *d, size_t n, const char *sensor)
{
    for (size_t i = 0; i < n; i++)
        if (!strcmp(gs_delight_get(d, i)->sensor, sensor)) return 1;
    return 0;
}

/* The usage error of a --sensor that d lacks, listing the sensors d has: returns 2. */
static int sensor_hint(const gs_delight *d, const char *sensor)
{
    char names[512] = "";
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const char *s = gs_delight_get(d, i)->sensor;
        size_t u = strlen(names);
        if (!has_sensor(d, i, s)) snprintf(names + u, sizeof names - u, "%s%s", u ? ", " : "", s);
    }
    return srv_usage_error("delight", "--sensor '%s': expected a sensor of the database: %s", sensor,
                           *names ? names : "none (it is empty)");
}

static int cmd_list(const gs_delight *d, const delight_opts *o)
{
    printf("%-22s %-22s %4s %-10s %-8s %7s  %-28s %s\n", "bulb_id", "type", "Hz", "sensor", "ref",
           "watts", "percent flicker (per band)", "name");
    size_t shown = 0;
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        if (!matches(b, o)) continue;
        char pf[64] = "";
        for (int band = 0; band < b->brf.bands; band++) {
            size_t used = strlen(pf);
            snprintf(pf + used, sizeof pf - used, "%s%.1f", band ? " / " : "",
                     gs_brf_percent_flicker(&b->brf, band));
        }
        char watts[32] = "-";   /* (0: not given) */
        if (b->watts > 0) snprintf(watts, sizeof watts, "%.1f", b->watts);
        printf("%-22s %-22s %4d %-10s %-8s %7s  %-28s %s\n", b->id, gs_tech_name(b->type), b->grid_hz,
               b->sensor, gs_ref_name(b->ref), watts, pf, b->name);
        shown++;
    }
    int techs[GS_TECH_COUNT] = {0}, n_tech = 0;
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        if (matches(b, o) && !techs[b->type]++) n_tech++;
    }
    printf("%zu entries over %d technologies\n", shown, n_tech);
    return 0;
}

static int cmd_show(const gs_delight *d, const delight_opts *o, const char *id)
{
    int shown = 0;
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        if (strcmp(b->id, id) || !matches(b, o)) continue;
        char watts[32] = "power not given";
        if (b->watts > 0) snprintf(watts, sizeof watts, "%.1f W", b->watts);
        printf("%s: %s, %s, %s, %d Hz, sensor %s, reference %s, %d samples per cycle\n", b->id, b->name,
               gs_tech_name(b->type), watts, b->grid_hz, b->sensor, gs_ref_name(b->ref), b->brf.n);
        enum { K = 26 };
        double w[GS_MAX_BANDS * K];
        gs_status s = gs_brf_integrate(&b->brf, 0.0, K, w);
        if (s != GS_OK) return srv_error("delight show", s);
        for (int band = 0; band < b->brf.bands; band++) {
            printf("  band %d: chromaticity %.4f, percent flicker %.2f, K=26 windows:", band,
                   b->chroma[band], gs_brf_percent_flicker(&b->brf, band));
            for (int k = 0; k < K; k++) printf(" %.4f", w[band * K + k]);
            putchar('\n');
        }
        shown++;
    }
    if (!shown) return srv_error("delight show", gs_fail(GS_ENOTFOUND, "bulb '%s': no such entry in the database", id));
    return 0;
}

static int cmd_export(const gs_delight *d, const delight_opts *o)
{
    gs_atomic a;   /* no -o, or -o -: stdout */
    gs_status s = gs_atomic_open(&a, o->out ? o->out : "-", 1);
    if (s == GS_OK) s = gs_delight_export_csv(d, a.f);
    if (s == GS_OK) s = gs_atomic_commit(&a);
    else gs_atomic_abort(&a);
    return s == GS_OK ? 0 : srv_error("delight export", s);
}

/* Load DB if it exists (else start empty), let add() change it, save it back; cmd names the
 * command in an error. Only a path that does not exist starts empty: a database that cannot be
 * opened (out of memory, out of file descriptors, no permission) is an error, never replaced by
 * the new bulbs alone. Processes that modify one database take turns (an flock of the file from
 * the load to the save; a new file made by another meanwhile is loaded and added to instead), so
 * none saves over bulbs another added after its load. */
static int modify_db(const char *cmd, const char *db, gs_status (*add)(gs_delight *, const void *),
                     const void *arg)
{
    gs_status s = GS_OK;
    for (int raced = 1; raced && s == GS_OK;) {
        raced = 0;
        gs_delight *d = gs_delight_new();
        if (!d) return srv_error(cmd, gs_fail(GS_ENOMEM, "cannot allocate the DELIGHT database"));
        struct stat st;
        int exists = stat(db, &st) == 0, fd = -1;
        if (exists) {
            if (S_ISREG(st.st_mode) && (fd = open(db, O_RDONLY | O_CLOEXEC)) >= 0) flock(fd, LOCK_EX);
            s = gs_delight_load(d, db);   /* (which refuses what is not a regular file) */
        } else if (errno != ENOENT) {
            s = gs_fail(GS_EIO, "%s: cannot open the DELIGHT database: %s", db, strerror(errno));
        }
        if (s == GS_OK) s = add(d, arg);
        if (s == GS_OK) s = exists ? gs_delight_save(d, db) : gs_delight_save_new(d, db, &raced);
        if (fd >= 0) close(fd);
        gs_delight_free(d);
    }
    return s == GS_OK ? 0 : srv_error(cmd, s);
}

typedef struct {
    char **files;
    int count;
} csv_list;

static gs_status add_csvs(gs_delight *d, const void *arg)
{
    const csv_list *l = arg;
    for (int i = 0; i < l->count; i++) {
        gs_status s = gs_delight_import_csv(d, l->files[i]);
        if (s != GS_OK) return s;
    }
    return GS_OK;
}

static gs_status add_recording(gs_delight *d, const void *arg)
{
    const delight_opts *o = arg;
    gs_bulb b;
    gs_recording_info info;
    gs_status s = gs_recording_to_bulb(o->recording, o->voltage_column, o->n, &b, &info);
    if (s != GS_OK) return s;
    if (o->id) snprintf(b.id, sizeof b.id, "%s", o->id);
    if (o->name) snprintf(b.name, sizeof b.name, "%s", o->name);
    if (o->watts > 0) b.watts = o->watts;
    if (o->grid_hz && b.grid_hz && o->grid_hz != b.grid_hz)
        s = gs_fail(GS_EINVAL, "%s: --grid %d, but the flicker at %.2f Hz says a %d Hz grid",
                    o->recording, o->grid_hz, info.flicker_hz, b.grid_hz);
    else if (!b.grid_hz && !o->grid_hz)
        s = gs_fail(GS_EINVAL, "%s: flicker at %.2f Hz is not locked to a 50/60 Hz grid: "
                    "expected --grid 50|60 to file it", o->recording, info.flicker_hz);
    else if (!b.grid_hz)
        b.grid_hz = o->grid_hz;
    if (o->has_type) b.type = o->type;
    if (s == GS_OK) s = gs_delight_add(d, &b);
    /* no flicker found: the cycles of the nominal 2 x grid over the recording's duration */
    int found = isfinite(info.flicker_hz);
    double flicker_hz = found ? info.flicker_hz : 2.0 * b.grid_hz;
    double cycles = found ? info.cycles : (double)info.samples / info.sample_rate_hz * flicker_hz;
    if (s == GS_OK)
        printf("added %s: %zu samples at %.0f Hz, %s %.2f Hz over %.1f cycles, grid %d Hz, "
               "percent flicker %.1f, reference %s\n",
               b.id, info.samples, info.sample_rate_hz, found ? "flicker" : "no flicker found, nominal",
               flicker_hz, cycles, b.grid_hz, info.percent_flicker, gs_ref_name(b.ref));
    /* filed, but say so: a light clipped at the top of the recorder's range (the flat top reads
     * as less flicker than the lamp's) */
    if (s == GS_OK && info.clipped_share > 0.01 && info.percent_flicker > 1.0)
        fprintf(stderr, "gridsurvey delight add: warning: %s: %.1f %% of the samples sit at the "
                "recording's largest value, in runs: a clipped light? its percent flicker (%.1f) then "
                "reads low; record it within the instrument's range\n", o->recording,
                100.0 * info.clipped_share, info.percent_flicker);
    /* filed, but say so (with --grid, or a voltage column's grid): its BRF spans one cycle of its
     * own flicker, not a grid half-cycle */
    if (s == GS_OK && b.ref == GS_REF_UNLOCKED && isfinite(info.flicker_hz))
        fprintf(stderr, "gridsurvey delight add: warning: %s: flicker at %.2f Hz is not twice the "
                "%d Hz grid (%d Hz +-3 %%): a wrong --grid or voltage column, or a lamp with its own "
                "driver frequency (PWM); filed as reference unlocked, its BRF one %.2f Hz cycle, "
                "never used by Eq. 7\n", o->recording, info.flicker_hz, b.grid_hz, 2 * b.grid_hz,
                info.flicker_hz);
    gs_bulb_release(&b);
    return s;
}

void srv_delight_plot_title(const gs_bulb *const *bulbs, size_t count, char *title, size_t size)
{
    size_t len = (size_t)snprintf(title, size, "DELIGHT BRFs, ");
    int n = 0;
    for (int prev = INT_MIN;; n++) {   /* the next grid above prev */
        int next = INT_MAX;
        for (size_t i = 0; i < count; i++)
            if (bulbs[i]->grid_hz > prev && bulbs[i]->grid_hz < next) next = bulbs[i]->grid_hz;
        if (next == INT_MAX) break;
        if (len < size)
            len += (size_t)snprintf(title + len, size - len, "%s%d", n ? " and " : "", next);
        prev = next;
    }
    if (len < size) snprintf(title + len, size - len, " Hz grid%s", n > 1 ? "s" : "");
}

static int cmd_plot(const gs_delight *d, const delight_opts *o)
{
    enum { MAX_PLOT = 15 };
    const gs_bulb *pick[MAX_PLOT];
    size_t count = 0;
    if (o->ids) {
        char *list = strdup(o->ids), *save = NULL;
        if (!list) return srv_error("delight plot", gs_fail(GS_ENOMEM, "out of memory"));
        for (char *tok = strtok_r(list, ",", &save); tok; tok = strtok_r(NULL, ",", &save)) {
            const gs_bulb *b = NULL;
            for (size_t i = 0; i < gs_delight_count(d) && !b; i++) {
                const gs_bulb *c = gs_delight_get(d, i);
                if (!strcmp(c->id, tok) && matches(c, o) && (o->sensor || c->brf.bands == 1)) b = c;
            }
            if (!b || count == MAX_PLOT) {
                /* the message formats tok, which lives in list: free it after */
                gs_status e = b ? gs_fail(GS_ELIMIT, "--ids: at most %d bulbs", MAX_PLOT)
                                : gs_fail(GS_ENOTFOUND, "--ids: bulb '%s' not in the database", tok);
                free(list);
                return srv_error("delight plot", e);
            }
            pick[count++] = b;
        }
        free(list);
    } else {
        /* One bulb of each technology, as in the paper's Fig. 2. */
        int seen[GS_TECH_COUNT] = {0};
        for (size_t i = 0; i < gs_delight_count(d) && count < MAX_PLOT; i++) {
            const gs_bulb *b = gs_delight_get(d, i);
            if (!matches(b, o) || (!o->sensor && b->brf.bands != 1) || seen[b->type]++) continue;
            if (count && b->grid_hz != pick[0]->grid_hz) continue;
            pick[count++] = b;
        }
    }
    if (!count) return srv_error("delight plot", gs_fail(GS_ENOTFOUND, "no bulb matches"));
    char title[128];
    srv_delight_plot_title(pick, count, title, sizeof title);
    gs_status s = rec_plot_brfs(pick, count, o->out, title);
    if (s != GS_OK) return srv_error("delight plot", s);
    fprintf(srv_note_stream(o->out), "wrote %s (%zu bulbs)\n", o->out, count);
    return 0;
}

int srv_cmd_delight(int argc, char **argv)
{
    if (argc < 2 || !strcmp(argv[1], "--help") || !strcmp(argv[1], "-h")) {
        fputs(delight_usage, argc < 2 ? stderr : stdout);
        return argc < 2 ? 2 : 0;
    }
    const char *sub = argv[1];
    delight_opts o;
    int rc = parse_opts(argc - 1, argv + 1, &o);
    if (rc >= 0) return rc;
    int npos = argc - 1 - optind;
    char **pos = argv + 1 + optind;

    if (!strcmp(sub, "import")) {
        if (!o.db || npos < 1) return srv_usage_error("delight import", "expected FILE.csv... and --delight DB");
        csv_list l = {pos, npos};
        return modify_db("delight import", o.db, add_csvs, &l);
    }
    if (!strcmp(sub, "add")) {
        if (!o.db || !o.recording)
            return srv_usage_error("delight add", "expected --from-recording FILE and --delight DB");
        return modify_db("delight add", o.db, add_recording, &o);
    }
    if (!strcmp(sub, "generate")) {
        if (!o.out) return srv_usage_error("delight generate", "-o DB is required");
        gs_delight *d = gs_delight_new();
        gs_status s = d ? gs_delight_generate(d, o.n) : gs_fail(GS_ENOMEM, "out of memory");
        if (s == GS_OK) s = gs_delight_save(d, o.out);
        gs_delight_free(d);
        return s == GS_OK ? 0 : srv_error("delight generate", s);
    }
    int is_show = !strcmp(sub, "show");
    if (strcmp(sub, "list") && !is_show && strcmp(sub, "export") && strcmp(sub, "plot")) {
        return srv_usage_error("delight", "'%s' is not a subcommand: expected list, show, export, import, "
                               "add, plot or generate", sub);
    }
    if (is_show && npos != 1) return srv_usage_error("delight show", "expected one bulb id");
    if (!strcmp(sub, "plot") && !o.out) return srv_usage_error("delight plot", "-o FILE.png is required");
    gs_delight *d = NULL;
    gs_status s = open_delight(&o, &d);
    if (s != GS_OK) {
        char cmd[16];   /* sub is one of the four above */
        snprintf(cmd, sizeof cmd, "delight %s", sub);
        return srv_error(cmd, s);
    }
    if (o.sensor && !has_sensor(d, gs_delight_count(d), o.sensor)) rc = sensor_hint(d, o.sensor);
    else if (!strcmp(sub, "list")) rc = cmd_list(d, &o);
    else if (is_show) rc = cmd_show(d, &o, pos[0]);
    else if (!strcmp(sub, "export")) rc = cmd_export(d, &o);
    else rc = cmd_plot(d, &o);
    gs_delight_free(d);
    return rc;
}
