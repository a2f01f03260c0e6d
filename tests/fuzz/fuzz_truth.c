/* fuzz_truth.c - a simulator's truth.json as `gridsurvey evaluate` reads it (srv_evaluate, over
 * a small synthetic survey database made once per process, so that an accepted truth reaches the
 * matching). */
#include "tests/fuzz/fuzz.h"
#include "survey/survey.h"

/* The database, open read-only for the process: one synthetic capture of 20 lights (created on
 * the first call; the handle stays reachable from here). */
static srv_db *fuzz_truth_db(void)
{
    static srv_db *db;
    if (db) return db;
    char path[700];
    snprintf(path, sizeof path, "%s/fuzz-truth.sqlite", fuzz_dir());
    srv_synth_opts o;
    srv_synth_opts_default(&o);
    o.captures = 1;
    o.lights_per_capture = 20;
    if (srv_db_open(path, SRV_DB_CREATE, &db) != GS_OK || srv_synth_ingest(db, &o, NULL) != GS_OK)
        abort();
    srv_db_close(db);
    if (srv_db_open(path, SRV_DB_READ, &db) != GS_OK) abort();
    return db;
}

FUZZ_TARGET(truth)
{
    srv_eval_report r;
    srv_evaluate(fuzz_truth_db(), fuzz_file("truth.json", data, size), NULL, &r);
    return 0;
}
