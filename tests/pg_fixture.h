/* pg_fixture.h - a throw-away PostgreSQL + PostGIS cluster for the tests of survey/pg*.c
 * (tests/pg_fixture.c, tests/pg_cluster.sh), prefix pg_fx_: one cluster per test run, started
 * by the first test that needs it (initdb under nobody when root, 127.0.0.1 only, a free port)
 * and stopped and removed when the runner exits; each test gets a database of its own. */
#ifndef GRIDSURVEY_TESTS_PG_FIXTURE_H
#define GRIDSURVEY_TESTS_PG_FIXTURE_H

#include <libpq-fe.h>

/* The conninfo of a new empty database `name` (a static buffer), or NULL when the Debian
 * packages postgresql / postgresql-15-postgis-3 are not installed: then a non-root run prints
 * "SKIP: ..." and makes one passing check, and a root run (CI, where make deps installs them)
 * fails. */
const char *pg_fx_database(const char *name);
/* A connection to conninfo (a test failure and NULL when it fails); PQfinish it. */
PGconn *pg_fx_connect(const char *conninfo);
/* The first column of sql's first row as a number (-1 and a test failure when none). */
long pg_fx_long(PGconn *c, const char *sql);
double pg_fx_double(PGconn *c, const char *sql);
/* Run sql (a test failure when it fails). */
void pg_fx_exec(PGconn *c, const char *sql);

#endif
