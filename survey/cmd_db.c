/* cmd_db.c - `gridsurvey db`: create, migrate and check a survey database, and (a developer
 * tool) ingest a synthetic survey, which the crash tests kill at random points. */
#include "survey/internal.h"

#include <getopt.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char db_usage[] =
    "usage: gridsurvey db SUBCOMMAND --db DB [OPTIONS]\n"
    "\n"
    "  init      --db DB      create an empty survey database (an existing one is kept)\n"
    "  migrate   --db DB      bring an existing database to this gridsurvey's schema version and\n"
    "                         associate its lights with light sites (resumable)\n"
    "  check     --db DB      integrity_check, foreign_key_check, R*Tree vs locations, complete\n"
    "                         captures, every light in a light site; exit status 1 if anything\n"
    "                         is wrong\n"
    "  ingest-synthetic --db DB [--survey NAME] [--captures N] [--lights N] [--batch B]\n"
    "            [--seed S] [--weights W0,W120,W240] [--ambiguous F]\n"
    "                         developer tool: a deterministic synthetic survey (N captures of\n"
    "                         N lights, B captures per transaction); a re-run resumes\n"
    "\n"
    "The schema, migrations and crash safety are described in docs/survey-db.md.\n"
    "\n"
    "Examples:\n"
    "  gridsurvey db init --db city.sqlite\n"
    "  gridsurvey db migrate --db city.sqlite\n"
    "  gridsurvey db check --db city.sqlite\n"
    "  gridsurvey db ingest-synthetic --db synthetic.sqlite --captures 10 --lights 1000\n";

/* srv_int_arg into a size_t. */
static int parse_size(const char *cmd, const char *opt, const char *text, size_t lo, size_t hi, size_t *v)
{
    unsigned long long x;
    if (!srv_int_arg(cmd, opt, text, lo, hi, &x)) return 0;
    *v = (size_t)x;
    return 1;
}

int srv_cmd_db(int argc, char **argv)
{
    if (argc < 2) {
        fputs(db_usage, stderr);
        return 2;
    }
    const char *sub = argv[1];
    if (!strcmp(sub, "--help") || !strcmp(sub, "-h")) {
        fputs(db_usage, stdout);
        return 0;
    }
    int which = !strcmp(sub, "init") ? 0 : !strcmp(sub, "migrate") ? 1 : !strcmp(sub, "check") ? 2
              : !strcmp(sub, "ingest-synthetic") ? 3 : -1;
    if (which < 0)
        return srv_usage_error("db", "'%s' is not a subcommand: expected init, migrate, check or "
                               "ingest-synthetic", sub);
    char cmd[24];   /* "db SUB" in an error */
    snprintf(cmd, sizeof cmd, "db %s", sub);
    static const struct option longs[] = {
        {"db", required_argument, 0, 'd'},       {"survey", required_argument, 0, 'S'},
        {"captures", required_argument, 0, 'c'}, {"lights", required_argument, 0, 'l'},
        {"batch", required_argument, 0, 'b'},    {"seed", required_argument, 0, 's'},
        {"weights", required_argument, 0, 'w'},  {"ambiguous", required_argument, 0, 'a'},
        {"help", no_argument, 0, 'h'},           {0, 0, 0, 0},
    };
    const char *path = NULL;
    srv_synth_opts so;
    srv_synth_opts_default(&so);
    optind = 1;
    int c;
    while ((c = getopt_long(argc - 1, argv + 1, "h", longs, NULL)) != -1) {
        if (which != 3 && c != 'd' && c != 'h' && c != '?') return srv_usage_error(cmd, "only --db is accepted");
        switch (c) {
        case 'd': path = optarg; break;
        case 'S': so.survey = optarg; break;
        case 'c':
            if (!parse_size(cmd, "--captures", optarg, 0, 100000000, &so.captures)) return 2;
            break;
        case 'l':
            if (!parse_size(cmd, "--lights", optarg, 0, 1000000, &so.lights_per_capture)) return 2;
            break;
        case 'b':
            if (!parse_size(cmd, "--batch", optarg, 1, 1000000, &so.batch)) return 2;
            break;
        case 's':
            if (!srv_int_arg(cmd, "--seed", optarg, 0, ULLONG_MAX, &so.seed)) return 2;
            break;
        case 'w':
            if (sscanf(optarg, "%lf,%lf,%lf", &so.phase_weights[0], &so.phase_weights[1],
                       &so.phase_weights[2]) != 3 || !(so.phase_weights[0] >= 0) ||
                !(so.phase_weights[1] >= 0) || !(so.phase_weights[2] >= 0) ||
                !(so.phase_weights[0] + so.phase_weights[1] + so.phase_weights[2] > 0))
                return srv_usage_error(cmd, "--weights '%s': expected W0,W120,W240 >= 0 with a positive sum", optarg);
            break;
        case 'a':
            if (!srv_num_arg(cmd, "--ambiguous", optarg, 0.0, 1.0, &so.ambiguous_fraction)) return 2;
            break;
        case 'h': fputs(db_usage, stdout); return 0;
        default: return srv_usage_hint(cmd, argv + 1);
        }
    }
    if (optind < argc - 1) return srv_usage_error(cmd, "unexpected argument '%s'", argv[optind + 1]);
    if (!path) return srv_usage_error(cmd, "--db is required");
    srv_db *db;
    gs_status s = srv_db_open(path, which == 1 ? SRV_DB_WRITE : which == 2 ? SRV_DB_READ : which == 0 ? SRV_DB_INIT : SRV_DB_CREATE, &db);
    if (s != GS_OK) return srv_error(cmd, s);
    int rc = 0;
    if (which == 0 || which == 1) {
        long created = 0, joined = 0, merged = 0;
        if (which == 1) s = srv_db_associate(db, &created, &joined, &merged);
        printf("%s: survey database, schema version %d\n", path, SRV_DB_SCHEMA_VERSION);
        if (which == 1 && s == GS_OK)
            printf("%s: %ld lights associated: %ld new light sites, %ld joined existing ones; %ld sites "
                   "merged into others\n", path, created + joined, created, joined, merged);
    } else if (which == 2) {
        srv_db_report r;
        if ((s = srv_db_check(db, &r)) == GS_OK) {
            printf("%s: %ld surveys, %ld captures, %ld lights, %ld locations (%ld located, %ld in the "
                   "R*Tree), %ld frequency rows\n", path, r.surveys, r.captures, r.lights,
                   r.locations, r.located, r.rtree_rows, r.frequency_rows);
            printf("%ld light sites, %ld lights without a site, %ld stale sites, %ld site R*Tree "
                   "mismatches\n", r.sites, r.unassociated, r.stale_sites, r.site_rtree_mismatch);
            printf("integrity %s, %ld foreign-key violations, %ld R*Tree mismatches, %ld incomplete "
                   "captures, %ld numbers stored as text: %s\n", r.integrity_ok ? "ok" : "FAILED",
                   r.fk_violations, r.rtree_mismatch, r.incomplete_captures, r.wrong_types,
                   srv_db_report_ok(&r) ? "ok" : "FAILED");
            rc = srv_db_report_ok(&r) ? 0 : 1;
        }
    } else {
        size_t added = 0;
        if ((s = srv_synth_ingest(db, &so, &added)) == GS_OK)
            printf("%s: added %zu captures (%zu lights each)\n", path, added, so.lights_per_capture);
    }
    srv_db_close(db);
    if (s != GS_OK) return srv_error(cmd, s);
    return rc;
}
