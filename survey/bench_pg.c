/* bench_pg.c - `gridsurvey bench pg`: the shared PostGIS database next to the SQLite file
 * (docs/postgis.md, "Scale"): one synthetic survey grown through 1e4 .. 1e6 lights in SQLite
 * (as `bench db`), pushed at each size (the new captures), then the same statistics from both,
 * the statistics views, and a re-push that finds nothing to do. */
#include "survey/internal.h"

#include <errno.h>
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static const char bench_pg_usage[] =
    "usage: gridsurvey bench pg --pg CONNINFO [--min N] [--max N] [--dir DIR]\n"
    "\n"
    "Grows a synthetic survey (1000 lights per capture) in a SQLite file through the powers of\n"
    "ten from --min to --max lights (default 1e5 .. 1e6) and pushes it to the PostGIS database\n"
    "CONNINFO after each step (its schema gridsurvey must hold no other survey named 'bench'),\n"
    "timing the push (lights/s), a re-push (nothing new), `stats --by technology` and\n"
    "`--by cell:250` from each database, and the views phase_balance (both), site_balance and\n"
    "site_balance_cells(250) (PostGIS). Prints a Markdown table. make bench runs it on a\n"
    "throw-away cluster (tests/pg_cluster.sh, fsync on).\n"
    "\n"
    "Example:\n"
    "  gridsurvey bench pg --pg \"host=127.0.0.1 port=5432 dbname=bench\" --max 100000\n";

/* Read every row of sql on the PostGIS database. */
static gs_status time_pg_query(PGconn *c, const char *sql, double *sec)
{
    double t0 = gs_clock_s(CLOCK_MONOTONIC);
    PGresult *r = PQexec(c, sql);
    *sec = gs_clock_s(CLOCK_MONOTONIC) - t0;
    gs_status s = PQresultStatus(r) == PGRES_TUPLES_OK ? GS_OK : srv_pgi_fail(c, r, sql);
    PQclear(r);
    return s;
}

int srv_bench_pg(int argc, char **argv)
{
    static const struct option longs[] = {
        {"pg", required_argument, 0, 'p'},  {"min", required_argument, 0, 'n'},
        {"max", required_argument, 0, 'm'}, {"dir", required_argument, 0, 'd'},
        {"help", no_argument, 0, 'h'},      {0, 0, 0, 0},
    };
    long min = 100000, max = 1000000;
    unsigned long long v;
    const char *dir = NULL, *conninfo = NULL;
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "h", longs, NULL)) != -1) {
        switch (c) {
        case 'p': conninfo = optarg; break;
        case 'n':
            if (!srv_int_arg("bench pg", "--min", optarg, 10000, 100000000, &v)) return 2;
            min = (long)v;
            break;
        case 'm':
            if (!srv_int_arg("bench pg", "--max", optarg, 10000, 100000000, &v)) return 2;
            max = (long)v;
            break;
        case 'd': dir = optarg; break;
        case 'h': fputs(bench_pg_usage, stdout); return 0;
        default: return srv_usage_hint("bench pg", argv);
        }
    }
    if (!conninfo) return srv_usage_error("bench pg", "--pg CONNINFO is required");
    char tmp[256] = "", path[4096];
    if (!dir) {
        snprintf(tmp, sizeof tmp, "/tmp/gridsurvey-bench-pg.XXXXXX");
        if (!mkdtemp(tmp))
            return srv_error("bench pg", gs_fail(GS_EIO, "%s: cannot create a temporary directory: %s", tmp,
                                                 strerror(errno)));
        dir = tmp;
    }
    snprintf(path, sizeof path, "%s/bench.sqlite", dir);
    srv_db *db = NULL;
    PGconn *pg = NULL;
    gs_status s = srv_db_open(path, SRV_DB_CREATE, &db);
    if (s == GS_OK) s = srv_pgi_connect(conninfo, 1, &pg);
    srv_synth_opts o;
    srv_synth_opts_default(&o);
    o.survey = "bench";
    o.lights_per_capture = 1000;
    srv_push_opts po;
    srv_push_opts_default(&po);
    printf("# SQLite and PostGIS (`gridsurvey bench pg`)\n\n"
           "One synthetic survey (%zu lights per capture) grown in a SQLite file (srv_db_add_capture, "
           "light sites associated on ingest) and pushed to PostgreSQL %d + PostGIS after each step "
           "(push: the new captures and every site, %zu lights per transaction); then the same "
           "statistics from both. Wall-clock seconds on this machine.\n\n"
           "| lights | SQLite ingest lights/s | push s | push lights/s | re-push s | stats technology "
           "SQLite s | PostGIS s | stats cell:250m SQLite s | PostGIS s | view phase_balance SQLite s | "
           "PostGIS s | view site_balance s | site_balance_cells(250) s |\n"
           "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
           o.lights_per_capture, pg ? PQserverVersion(pg) / 10000 : 0, po.batch_lights);
    fflush(stdout);
    long have = 0;
    for (long size = min; size <= max && s == GS_OK; size *= 10) {
        o.captures = (size_t)(size / 1000);
        double t0 = gs_clock_s(CLOCK_MONOTONIC);
        if ((s = srv_synth_ingest(db, &o, NULL)) != GS_OK) break;
        double ingest = gs_clock_s(CLOCK_MONOTONIC) - t0;
        srv_push_report r;
        t0 = gs_clock_s(CLOCK_MONOTONIC);
        if ((s = srv_pg_push(path, conninfo, &po, &r)) != GS_OK) break;
        double push = gs_clock_s(CLOCK_MONOTONIC) - t0;
        t0 = gs_clock_s(CLOCK_MONOTONIC);
        if ((s = srv_pg_push(path, conninfo, &po, &r)) != GS_OK) break;
        double repush = gs_clock_s(CLOCK_MONOTONIC) - t0;
        if (r.captures_pushed || r.sites_written) {
            s = gs_fail(GS_EFORMAT, "bench pg: a re-push wrote %zu captures, %zu sites", r.captures_pushed,
                        r.sites_written);
            break;
        }
        double t[8];
        if ((s = srv_bench_time_stats(db, NULL, "technology", &t[0])) != GS_OK ||
            (s = srv_bench_time_stats(NULL, conninfo, "technology", &t[1])) != GS_OK ||
            (s = srv_bench_time_stats(db, NULL, "cell:250", &t[2])) != GS_OK ||
            (s = srv_bench_time_stats(NULL, conninfo, "cell:250", &t[3])) != GS_OK ||
            (s = srv_bench_time_view(db, "SELECT * FROM phase_balance", &t[4])) != GS_OK ||
            (s = time_pg_query(pg, "SELECT * FROM phase_balance", &t[5])) != GS_OK ||
            (s = time_pg_query(pg, "SELECT * FROM site_balance", &t[6])) != GS_OK ||
            (s = time_pg_query(pg, "SELECT * FROM site_balance_cells(250)", &t[7])) != GS_OK)
            break;
        printf("| %ld | %.0f | %.2f | %.0f | %.2f | %.3f | %.3f | %.3f | %.3f | %.3f | %.3f | %.3f | %.3f |\n",
               size, (double)(size - have) / ingest, push, (double)(size - have) / push, repush, t[0], t[1],
               t[2], t[3], t[4], t[5], t[6], t[7]);
        fflush(stdout);
        have = size;
    }
    if (pg) PQfinish(pg);
    srv_db_close(db);
    if (*tmp) {
        static const char *const suffix[] = {"", "-wal", "-shm"};
        for (int i = 0; i < 3; i++) {
            char p[4200];
            snprintf(p, sizeof p, "%s%s", path, suffix[i]);
            unlink(p);
        }
        rmdir(tmp);
    }
    if (s != GS_OK) return srv_error("bench pg", s);
    return 0;
}
