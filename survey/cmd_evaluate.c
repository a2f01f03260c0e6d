/* cmd_evaluate.c - `gridsurvey evaluate`: a survey database against a simulator's truth.json
 * (survey/evaluate.c; the metrics are defined in docs/pipeline.md). */
#include "survey/internal.h"

#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char evaluate_usage[] =
    "usage: gridsurvey evaluate --db DB --truth truth.json [--survey NAME] [--match-px R]\n"
    "                           [--format table|json]\n"
    "\n"
    "Matches the stored lights of one capture to the simulator's truth (gridsurvey-truth/1) by\n"
    "pixel position, one-to-one, nearest pairs first, within R pixels, and reports with their\n"
    "counts: the detection rate (truth lights in the image that were detected), false\n"
    "detections, bulb, technology and phase accuracy (among matched lights with an answer;\n"
    "a phase is right within 20 deg), the share left unknown or ambiguous, a phase confusion\n"
    "matrix and the location error (WGS84 geodesic distance: median, 95th percentile, max).\n"
    "\n"
    "  --db DB          the survey database (read-only)\n"
    "  --truth FILE     the capture directory's truth.json\n"
    "  --survey NAME    only captures of this survey\n"
    "  --match-px R     match radius, pixels, > 0 and <= 64 (default 2)\n"
    "  --format F       table (Markdown, default) or json (gridsurvey-evaluation/1)\n"
    "  --help           this text\n"
    "\n"
    "The capture is the one whose directory holds the truth file (or the only one).\n"
    "\n"
    "Example (a database of `gridsurvey run build/lab --db build/lab.sqlite`):\n"
    "  gridsurvey evaluate --db build/lab.sqlite --truth build/lab/truth.json --format json\n"
    "\n"
    "Exit status: 0 done, 1 failure (one line on stderr), 2 usage error.\n";

int srv_cmd_evaluate(int argc, char **argv)
{
    static const struct option longs[] = {
        {"db", required_argument, 0, 'd'},       {"truth", required_argument, 0, 't'},
        {"survey", required_argument, 0, 'S'},   {"match-px", required_argument, 0, 'm'},
        {"format", required_argument, 0, 'f'},   {"help", no_argument, 0, 'h'},
        {0, 0, 0, 0},
    };
    const char *path = NULL, *truth = NULL;
    int json = 0;
    srv_eval_opts o;
    srv_eval_opts_default(&o);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, ":h", longs, NULL)) != -1) {
        switch (c) {
        case 'd': path = optarg; break;
        case 't': truth = optarg; break;
        case 'S': o.survey = optarg; break;
        case 'm':
            if (!srv_num_arg_open("evaluate", "--match-px", optarg, 0.0, SRV_MATCH_PX_MAX, SRV_OPEN_LO, &o.match_px))
                return 2;
            break;
        case 'f':
            if (!strcmp(optarg, "table")) json = 0;
            else if (!strcmp(optarg, "json")) json = 1;
            else return srv_usage_error("evaluate", "--format '%s': expected table or json", optarg);
            break;
        case 'h': fputs(evaluate_usage, stdout); return 0;
        case ':': return srv_usage_error("evaluate", "option '%s' needs a value", argv[optind - 1]);
        default: return srv_usage_error("evaluate", "unknown option '%s'", argv[optind - 1]);
        }
    }
    if (optind < argc) return srv_usage_error("evaluate", "unexpected argument '%s'", argv[optind]);
    if (!path || !truth) return srv_usage_error("evaluate", "--db and --truth are required");
    srv_db *db = NULL;
    gs_status s = srv_db_open(path, SRV_DB_READ, &db);
    if (s != GS_OK) return srv_error("evaluate", s);
    srv_eval_report r;
    s = srv_evaluate(db, truth, &o, &r);
    srv_db_close(db);
    if (s == GS_OK) s = srv_eval_print(&r, truth, json, stdout);
    if (s == GS_OK && fflush(stdout) != 0) s = gs_fail(GS_EIO, "stdout: write failed");
    return s == GS_OK ? 0 : srv_error("evaluate", s);
}
