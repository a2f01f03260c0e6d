/* fuzz_db.c - a survey database opened the way `stats` and `export` open it (srv_db_open
 * read-only), then the statistics by phase and by cell, the export's light query and its GeoJSON:
 * nothing crashes, and a file that is not SQLite (its 16-byte header) is refused with an error. */
#include "tests/fuzz/fuzz.h"
#include "survey/survey.h"

FUZZ_TARGET(db)
{
    char path[700], side[720];
    snprintf(path, sizeof path, "%s/fuzz.sqlite", fuzz_dir());
    static const char *const sides[] = {"-journal", "-wal", "-shm"};
    for (int i = 0; i < 3; i++) {   /* nothing of the previous input is replayed */
        snprintf(side, sizeof side, "%s%s", path, sides[i]);
        unlink(side);
    }
    fuzz_file("fuzz.sqlite", data, size);
    srv_db *db = NULL;
    gs_status s = srv_db_open(path, SRV_DB_READ, &db);
    if (s == GS_OK && (size < 100 || memcmp(data, "SQLite format 3", 16) != 0)) abort();
    if (s != GS_OK) {
        if (db) abort();
        return 0;
    }
    srv_stats_opts so;
    srv_stats_opts_default(&so);
    for (int by = 0; by < 2; by++) {
        srv_phase_stats *g = NULL;
        size_t n = 0;
        long ungrouped = 0;
        if (by && srv_stats_parse_by("cell:500", &so) != GS_OK) abort();
        if (srv_stats_compute(db, &so, &g, &n, &ungrouped) == GS_OK && n && !g) abort();
        free(g);
    }
    srv_export_opts eo;
    srv_export_opts_default(&eo);
    gis_light *lights = NULL;
    size_t count = 0;
    s = srv_db_read_lights(db, &eo, &lights, &count);
    srv_db_close(db);
    if (s == GS_OK) {   /* and what `export` writes of them */
        char out[720];
        snprintf(out, sizeof out, "%s/fuzz-export.geojson", fuzz_dir());
        gis_export(lights, count, GIS_FORMAT_GEOJSON, out);
        unlink(out);
    }
    free(lights);
    return 0;
}
