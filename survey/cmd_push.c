/* cmd_push.c - `gridsurvey push`: a survey database into the shared PostGIS database
 * (survey/pg_push.c, docs/postgis.md). */
#include "survey/internal.h"

#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static const char push_usage[] =
    "usage: gridsurvey push --db DB --pg CONNINFO [--areas AREAS.geojson --field FIELD]\n"
    "                       [--batch N] [--progress | --no-progress | -q]\n"
    "\n"
    "Copy a survey database (surveys, stations, DELIGHT versions, captures with their frames\n"
    "and frequency log, lights, locations, light sites) into the schema gridsurvey of a\n"
    "PostgreSQL + PostGIS database, created or migrated on the way. Re-pushing adds nothing; an\n"
    "interrupted push resumes; several stations may push at once (docs/postgis.md).\n"
    "\n"
    "  --db DB         the survey database (read-only)\n"
    "  --pg CONNINFO   a libpq connection string, e.g. \"host=gis.example port=5432\n"
    "                  dbname=grid user=station1\" or postgresql://station1@gis.example/grid\n"
    "  --areas FILE    also load these GeoJSON (Multi)Polygon areas, e.g. feeders, as layer\n"
    "  --field FIELD   FIELD of table gridsurvey.areas, labelled by their property FIELD\n"
    "                  (for the view area_balance); a layer is replaced as a whole\n"
    "  --batch N       lights (whole captures) or sites per transaction (default 20000)\n"
    "  --progress      a line per 10 % of the captures on stderr (default: when stderr is a\n"
    "                  terminal)\n"
    "  -q, --no-progress  no progress\n"
    "  --help          this text\n"
    "\n"
    "Example:\n"
    "  gridsurvey push --db haifa.sqlite --pg \"host=127.0.0.1 dbname=grid\" \\\n"
    "      --areas feeders.geojson --field feeder\n";

int srv_cmd_push(int argc, char **argv)
{
    static const struct option longs[] = {
        {"db", required_argument, 0, 'd'},    {"pg", required_argument, 0, 'p'},
        {"areas", required_argument, 0, 'a'}, {"field", required_argument, 0, 'f'},
        {"batch", required_argument, 0, 'b'}, {"progress", no_argument, 0, 'P'},
        {"no-progress", no_argument, 0, 'q'}, {"help", no_argument, 0, 'h'},
        {0, 0, 0, 0},
    };
    const char *path = NULL, *conninfo = NULL;
    srv_push_opts o;
    srv_push_opts_default(&o);
    o.progress = isatty(2);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "hq", longs, NULL)) != -1) {
        switch (c) {
        case 'd': path = optarg; break;
        case 'p': conninfo = optarg; break;
        case 'a': o.areas = optarg; break;
        case 'f': o.areas_field = optarg; break;
        case 'b': {
            unsigned long long v;
            if (!srv_int_arg("push", "--batch", optarg, 1, 100000000, &v)) return 2;
            o.batch_lights = (size_t)v;
            break;
        }
        case 'P': o.progress = 1; break;
        case 'q': o.progress = 0; break;
        case 'h': fputs(push_usage, stdout); return 0;
        default: return srv_usage_hint("push", argv);
        }
    }
    if (optind < argc) return srv_usage_error("push", "unexpected argument '%s'", argv[optind]);
    if (!path || !conninfo) return srv_usage_error("push", "--db and --pg are required");
    if (!o.areas != !o.areas_field) return srv_usage_error("push", "--areas and --field go together");
    srv_push_report r;
    gs_status s = srv_pg_push(path, conninfo, &o, &r);
    if (s != GS_OK) return srv_error("push", s);
    fprintf(stderr, "push: %s: %zu captures (%zu new, %zu lights), %zu light sites (%zu written)%s",
            path, r.captures, r.captures_pushed, r.lights_pushed, r.sites, r.sites_written,
            r.retries ? "" : "\n");
    if (r.retries) fprintf(stderr, ", %d transactions retried after a deadlock\n", r.retries);
    if (o.areas) fprintf(stderr, "push: %zu areas in layer '%s'\n", r.areas, o.areas_field);
    return 0;
}
