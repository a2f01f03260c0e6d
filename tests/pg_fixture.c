/* pg_fixture.c - the tests' PostgreSQL + PostGIS cluster (pg_fixture.h). */
#include "tests/pg_fixture.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

const char *pg_fx_database(const char *name)
{
    static char conninfo[256];
    char dir[128], path[192], out[4096] = "";
    /* the runner is the test's parent: one cluster per run, started by the first test that
     * needs it while the others (tests run at once, tests/main.c) wait on the lock */
    snprintf(dir, sizeof dir, "/tmp/gridsurvey-pg.%ld", (long)getppid());
    snprintf(path, sizeof path, "%s.lock", dir);
    int lock = fx_lock(path);   /* close-on-exec: the cluster's watchdog does not hold it */
    if (lock < 0) return NULL;
    snprintf(path, sizeof path, "%s/port", dir);
    int port = 0;
    FILE *f = fopen(path, "r");
    if (f) {
        if (fscanf(f, "%d", &port) != 1) port = 0;
        fclose(f);
    }
    char cmd[512];
    snprintf(conninfo, sizeof conninfo, "host=127.0.0.1 port=%d user=gs dbname=postgres", port);
    if (!port || PQping(conninfo) != PQPING_OK) {
        snprintf(cmd, sizeof cmd, "sh tests/pg_cluster.sh start %s %ld", dir, (long)getppid());
        int rc = test_run(cmd, out, sizeof out);
        if (rc == 77 && getuid() != 0) {
            printf("    SKIP: %s", out);
            CHECK(1);
            close(lock);
            return NULL;
        }
        CHECK_MSG(rc == 0 && sscanf(out, "%d", &port) == 1, "pg_cluster.sh start: status %d: %s", rc, out);
        if (rc != 0) {
            close(lock);
            return NULL;
        }
    }
    close(lock);
    snprintf(conninfo, sizeof conninfo, "host=127.0.0.1 port=%d user=gs dbname=postgres", port);
    PGconn *c = pg_fx_connect(conninfo);
    if (!c) return NULL;
    char sql[256];
    snprintf(sql, sizeof sql, "DROP DATABASE IF EXISTS %s", name);
    pg_fx_exec(c, sql);
    snprintf(sql, sizeof sql, "CREATE DATABASE %s", name);
    pg_fx_exec(c, sql);
    PQfinish(c);
    snprintf(conninfo, sizeof conninfo, "host=127.0.0.1 port=%d user=gs dbname=%s", port, name);
    return conninfo;
}

PGconn *pg_fx_connect(const char *conninfo)
{
    PGconn *c = PQconnectdb(conninfo);
    CHECK_MSG(PQstatus(c) == CONNECTION_OK, "connect %s: %s", conninfo, PQerrorMessage(c));
    if (PQstatus(c) != CONNECTION_OK) {
        PQfinish(c);
        return NULL;
    }
    PQclear(PQexec(c, "SET client_min_messages = warning"));
    return c;
}

static PGresult *one_row(PGconn *c, const char *sql)
{
    PGresult *r = PQexec(c, sql);
    int ok = PQresultStatus(r) == PGRES_TUPLES_OK && PQntuples(r) >= 1 && !PQgetisnull(r, 0, 0);
    CHECK_MSG(ok, "%s: %s", sql, PQresultErrorMessage(r));
    if (ok) return r;
    PQclear(r);
    return NULL;
}

long pg_fx_long(PGconn *c, const char *sql)
{
    PGresult *r = one_row(c, sql);
    long v = r ? strtol(PQgetvalue(r, 0, 0), NULL, 10) : -1;
    PQclear(r);
    return v;
}

double pg_fx_double(PGconn *c, const char *sql)
{
    PGresult *r = one_row(c, sql);
    double v = r ? strtod(PQgetvalue(r, 0, 0), NULL) : -1;
    PQclear(r);
    return v;
}

void pg_fx_exec(PGconn *c, const char *sql)
{
    PGresult *r = PQexec(c, sql);
    ExecStatusType st = PQresultStatus(r);
    CHECK_MSG(st == PGRES_COMMAND_OK || st == PGRES_TUPLES_OK, "%s: %s", sql, PQresultErrorMessage(r));
    PQclear(r);
}
