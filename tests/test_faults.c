/* test_faults.c - fault injection as SQLite's harness does it (docs/reliability.md): the n-th
 * allocation, write, fsync or rename of `gridsurvey run`, `export` and `delight import` fails
 * (tests/faults/faultinject.c, preloaded), and each such run must either fail with one line on
 * stderr or succeed, and leave the database and every file in its directory either as they were
 * before or as an uninjected run leaves them. Under ASan (`make test-asan`) a leak or any other
 * report is a failure too (it makes stderr longer than one line).
 *
 * Oracles: the database as every table's rows read through a raw SQLite connection (after
 * PRAGMA integrity_check), and every other file's SHA-256 (sha256sum) with the directory's
 * listing, compared with the state before the run and after an uninjected run.
 *
 * Which points: a count-only run of each class gives the number of calls N; `make check` tries
 * a few of them (the scenario's `points`), evenly spread, `make faults`
 * (GS_FAULT_SWEEP=full) every one (every GS_FAULT_MALLOC_STEP-th allocation when that is set),
 * and appends the counts to $GS_FAULT_REPORT; GS_FAULT_POINTS=A-B runs only the points A..B. */
#include "tests/fixtures.h"
#include "tests/survey_fixture.h"
#include "tests/test.h"

#include <nettle/sha2.h>
#include <sqlite3.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

static char out[1 << 16];

/* ------------------------------------------------------------------ the state of a directory */

/* "SHA256  ./name" for every file under dir but the database (db, relative to dir, with its
 * -journal and -wal), sorted by name; for a GeoPackage the SHA-256 of its db_state (its bytes
 * differ from run to run). The caller frees. */
static char *files_state(const char *dir, const char *db)
{
    char cmd[4096];
    snprintf(cmd, sizeof cmd, "cd %s && find . -type f ! -name '%s' ! -name '%s-journal' ! -name '%s-wal' "
             "! -name '%s-shm' -print0 | LC_ALL=C sort -z | xargs -0 -r sha256sum", dir, db, db, db, db);
    static char listing[1 << 16];
    if (test_run(cmd, listing, sizeof listing) != 0) return strdup("unlistable");
    for (char *l = listing; *l;) {
        char *e = strchr(l, '\n');
        size_t n = e ? (size_t)(e - l) : strlen(l);
        if (n > 66 + 5 && !strncmp(l + n - 5, ".gpkg", 5)) {
            char path[2048];
            snprintf(path, sizeof path, "%s/%.*s", dir, (int)(n - 66), l + 66);
            char *st = survey_fx_db_state(path);
            struct sha256_ctx c;
            uint8_t d[SHA256_DIGEST_SIZE];
            sha256_init(&c);
            sha256_update(&c, strlen(st), (const uint8_t *)st);
            sha256_digest(&c, sizeof d, d);
            for (int i = 0; i < SHA256_DIGEST_SIZE; i++) {
                static const char hex[] = "0123456789abcdef";
                l[2 * i] = hex[d[i] >> 4];
                l[2 * i + 1] = hex[d[i] & 15];
            }
            free(st);
        }
        if (!e) break;
        l = e + 1;
    }
    return strdup(listing);
}

/* The hash of ./name in a files_state listing, or "" if it is not there. */
static const char *hash_of(const char *state, const char *name, char *hash, size_t size)
{
    hash[0] = '\0';
    for (const char *l = state; *l;) {
        const char *e = strchr(l, '\n');
        size_t n = e ? (size_t)(e - l) : strlen(l);
        if (n > 66 && strlen(name) == n - 66 && !strncmp(l + 66, name, n - 66)) {
            snprintf(hash, size, "%.64s", l);
            break;
        }
        if (!e) break;
        l = e + 1;
    }
    return hash;
}

/* Each file of after either as in before or as in ref (absent counting as a state); the first
 * that is neither in why. */
static int files_each_before_or_ref(const char *before, const char *ref, const char *after, char *why,
                                    size_t size)
{
    const char *lists[3] = {before, ref, after};
    for (int k = 0; k < 3; k++) {
        for (const char *l = lists[k]; *l;) {
            const char *e = strchr(l, '\n');
            size_t n = e ? (size_t)(e - l) : strlen(l);
            if (n > 66) {
                char name[1024], hb[80], hr[80], ha[80];
                snprintf(name, sizeof name, "%.*s", (int)(n - 66), l + 66);
                hash_of(before, name, hb, sizeof hb);
                hash_of(ref, name, hr, sizeof hr);
                hash_of(after, name, ha, sizeof ha);
                if (strcmp(ha, hb) && strcmp(ha, hr)) {
                    snprintf(why, size, "%s is %s", name, ha[0] ? "neither as before nor complete"
                                                                 : "gone (it was there before and after a run)");
                    return 0;
                }
            }
            if (!e) break;
            l = e + 1;
        }
    }
    return 1;
}

/* The first line where a and b differ, as "a-line | b-line", in a static buffer. */
static const char *first_difference(const char *a, const char *b)
{
    static char buf[600];
    while (*a && *a == *b) {
        const char *ea = strchr(a, '\n'), *eb = strchr(b, '\n');
        if (!ea || !eb || ea - a != eb - b || strncmp(a, b, (size_t)(ea - a))) break;
        a = ea + 1;
        b = eb + 1;
    }
    snprintf(buf, sizeof buf, "%.*s | %.*s", (int)strcspn(a, "\n") % 280, a, (int)strcspn(b, "\n") % 280, b);
    return buf;
}

/* ------------------------------------------------------------------ scenarios */

typedef struct {
    const char *name;
    int points;        /* of each kind in `make check` (the sweep: all) */
    const char *cmd;   /* a format of up to three %s: the binary, the assets' directory, and it
                        * again (it runs in the work directory) */
    const char *db;    /* the database's name in the work directory */
    /* makes the work directory's state before the command (it is emptied first) */
    void (*setup)(const char *work, const char *assets);
    /* when set, only allocations fail, by site, always, and only those of the sites whose module
     * (the shim's GS_FAULT_SITES) starts with it: `make check` spreads sc->points over them */
    const char *site_module;
} scenario;

static void setup_empty(const char *work, const char *assets)
{
    (void)work;
    (void)assets;
}
/* an existing survey database with a survey in it (the run adds a capture to it) */
static void setup_existing_survey(const char *work, const char *assets)
{
    char cmd[4096];
    snprintf(cmd, sizeof cmd, "cp %s/base.sqlite %s/survey.sqlite", assets, work);
    CHECK(test_run(cmd, out, sizeof out) == 0);
}
/* the export's source database, and an older output file to be replaced */
static void setup_export(const char *work, const char *assets)
{
    char cmd[4096];
    snprintf(cmd, sizeof cmd, "cp %s/exported.sqlite %s/survey.sqlite && echo old > %s/lights.geojson && "
             "echo old > %s/lights.gpkg", assets, work, work, work);
    CHECK(test_run(cmd, out, sizeof out) == 0);
}
static void setup_delight_existing(const char *work, const char *assets)
{
    char cmd[4096];
    snprintf(cmd, sizeof cmd, "cp %s/small-delight.sqlite %s/delight.sqlite", assets, work);
    CHECK(test_run(cmd, out, sizeof out) == 0);
}

/* The assets every scenario reads, made once: a capture directory of a small geographic scene
 * (160 x 120 pixels, three lights seen from a station, C = 64 cycles: every stage of `run`,
 * recognition, location, the store, the GeoJSON and the map, in about a second), a survey
 * database with it (to export) and one with only another survey, a DELIGHT CSV and a DELIGHT
 * database holding part of it. */
static const char *assets(void)
{
    /* beside the tests' own directories, so the tests of one runner share them; made by the
     * first test that needs them while the others (tests run at once) wait on the lock */
    static char dir[1024];
    const char *t = test_tmpdir(), *slash = strrchr(t, '/');
    snprintf(dir, sizeof dir, "%.*s/fault-assets", slash ? (int)(slash - t) : 1, slash ? t : ".");
    char lock_path[1100];
    snprintf(lock_path, sizeof lock_path, "%s.lock", dir);
    int lock = fx_lock(lock_path);
    if (fx_exists(fx_path(dir, "ready"))) {
        if (lock >= 0) close(lock);
        return dir;
    }
    mkdir(dir, 0777);
    char scene[1100], cmd[8192];
    snprintf(scene, sizeof scene, "%s/small.json", dir);
    survey_fx_geo_scene(scene, 0.5, 3, 64);
    char *b = realpath(test_bin(), NULL);
    CHECK_MSG(b != NULL, "%s: not found", test_bin());
    if (!b) {
        if (lock >= 0) close(lock);
        return dir;
    }
    snprintf(cmd, sizeof cmd,
             "cd %s && %s run small.json --db exported.sqlite --capture-dir cap --out-dir cap-out >/dev/null && "
             "%s db init --db base.sqlite >/dev/null && "
             "%s delight export -o all.csv && head -n 9 all.csv > some.csv && "
             "(head -n 1 all.csv; tail -n +10 all.csv | head -n 16) > more.csv && "
             "%s delight import some.csv --delight small-delight.sqlite >/dev/null",
             dir, b, b, b, b);
    free(b);
    if (test_run(cmd, out, sizeof out) == 0) fx_write_text(fx_path(dir, "ready"), "");
    else CHECK_MSG(0, "%s", out);
    if (lock >= 0) close(lock);
    return dir;
}

static const scenario scenarios[] = {
    /* (DELIGHT from a file: run-existing-db's sweep covers the built-in one's generation, this
     * one the reading of a DELIGHT database, in half the time a run) */
    {"run-new-db", 1, "%s run %s/cap --db survey.sqlite --survey night --light-height-m 10 --out-dir . "
     "--delight %s/small-delight.sqlite", "survey.sqlite", setup_empty, NULL},
    {"run-existing-db", 2, "%s run %s/cap --db survey.sqlite --survey night --light-height-m 10 --out-dir .",
     "survey.sqlite", setup_existing_survey, NULL},
    {"export-geojson", 2, "%s export --db survey.sqlite -o lights.geojson", "survey.sqlite", setup_export, NULL},
    {"export-gpkg", 2, "%s export --db survey.sqlite -o lights.gpkg", "survey.sqlite", setup_export, NULL},
    {"delight-import-new", 2, "%s delight import %s/some.csv --delight delight.sqlite", "delight.sqlite",
     setup_empty, NULL},
    {"delight-import-existing", 2, "%s delight import %s/more.csv --delight delight.sqlite",
     "delight.sqlite", setup_delight_existing, NULL},
    /* OpenCV's allocations (it throws cv::Exception StsNoMem, not std::bad_alloc) */
    {"recognize-opencv", 12, "%s recognize %s/cap --format json --delight %s/small-delight.sqlite",
     "none.sqlite", setup_empty, "libopencv"},
};

typedef struct {
    const char *cls, *err;
} fault_kind;
static const fault_kind kinds[] = {
    {"malloc", "ENOSPC"}, {"write", "ENOSPC"}, {"write", "EIO"}, {"write", "SHORT"},
    {"fsync", "EIO"},     {"rename", "EIO"},
};

/* A shim beside the binary's build: BUILD/tests/faults/NAME for BUILD/gridsurvey (a static
 * buffer). */
static const char *shim_path_of(const char *name)
{
    static char path[1100];
    const char *bin = test_bin(), *slash = strrchr(bin, '/');
    snprintf(path, sizeof path, "%.*s/tests/faults/%s", slash ? (int)(slash - bin) : 1,
             slash ? bin : ".", name);
    return path;
}

static const char *shim_path(void)
{
    return shim_path_of("faultinject.so");
}

enum { N_CLASSES = 4 };
static const char *const class_names[N_CLASSES] = {"malloc", "write", "fsync", "rename"};

/* Empties work, sets it up, runs the scenario with the n-th call of kind failing (n = 0: none),
 * or (site != 0, allocations) the first allocation from that stack; sites_out (or NULL): where
 * the shim writes the distinct stacks of the allocations (GS_FAULT_SITES). Its exit status,
 * stderr in out, the calls of each class (class_names) in calls[] and whether the fault fired
 * in *fired. */
static int run_injected_at(const scenario *sc, const char *work, const fault_kind *k, long n,
                           unsigned long long site, const char *sites_out, long *calls, int *fired)
{
    char cmd[8192], report[1100];
    snprintf(cmd, sizeof cmd, "rm -rf %s && mkdir -p %s", work, work);
    CHECK(test_run(cmd, NULL, 0) == 0);
    sc->setup(work, assets());
    snprintf(report, sizeof report, "%s.count", work);
    unlink(report);
    /* absolute paths: the command runs in work */
    char *bin = realpath(test_bin(), NULL), *shim = realpath(shim_path(), NULL);
    CHECK_MSG(bin && shim, "%s or %s: not found (make builds the shim with the test binary)", test_bin(),
              shim_path());
    if (!bin || !shim) {
        free(bin);
        free(shim);
        return -1;
    }
    char run[2048];
    snprintf(run, sizeof run, sc->cmd, bin, assets(), assets());
    char site_env[1300] = "";
    if (site) snprintf(site_env, sizeof site_env, "GS_FAULT_SITE=%llx ", site);
    else if (sites_out) snprintf(site_env, sizeof site_env, "GS_FAULT_SITES=%s ", sites_out);
    snprintf(cmd, sizeof cmd,
             "cd %s && timeout 300 env GS_FAULT_CLASS=%s GS_FAULT_N=%ld %sGS_FAULT_ERRNO=%s GS_FAULT_OUT=%s "
             "LD_PRELOAD=%s ASAN_OPTIONS=${ASAN_OPTIONS:+$ASAN_OPTIONS:}verify_asan_link_order=0 "
             "%s 2>&1 >/dev/null",
             work, k->cls, n, site_env, k->err, report, shim, run);
    free(bin);
    free(shim);
    int rc = test_run(cmd, out, sizeof out);
    for (int c = 0; c < N_CLASSES; c++) calls[c] = -1;
    *fired = 0;
    FILE *f = fopen(report, "r");
    if (f) {
        if (fscanf(f, "%ld %ld %ld %ld %d", &calls[0], &calls[1], &calls[2], &calls[3], fired) != 5) calls[0] = -1;
        fclose(f);
    }
    return rc;
}

static int run_injected(const scenario *sc, const char *work, const fault_kind *k, long n, long *calls,
                        int *fired)
{
    return run_injected_at(sc, work, k, n, 0, NULL, calls, fired);
}

/* Empties work and sets the scenario up in it; the state before the command in *db and *files
 * (db_state, files_state; the caller frees). */
static void set_up(const scenario *sc, const char *work, char **db, char **files)
{
    char cmd[4096], dbp[1200];
    snprintf(cmd, sizeof cmd, "rm -rf %s && mkdir -p %s", work, work);
    CHECK(test_run(cmd, NULL, 0) == 0);
    sc->setup(work, assets());
    snprintf(dbp, sizeof dbp, "%s/%s", work, sc->db);
    *db = survey_fx_db_state(dbp);
    *files = files_state(work, sc->db);
}

/* The distinct allocation stacks a run wrote (GS_FAULT_SITES: "SITE N MODULE" lines in the order
 * first seen), those of module (a prefix of MODULE; NULL: all) into a new array (*n of them; NULL
 * and 0 if none, *overflow if the shim ran out of room). */
typedef struct {
    unsigned long long site;
    long first;
    char module[64];
} alloc_site;
static alloc_site *read_sites(const char *path, const char *module, size_t *n, int *overflow)
{
    *n = 0;
    *overflow = 0;
    alloc_site *v = NULL;
    size_t cap = 0;
    FILE *f = fopen(path, "r");
    char line[256];
    while (f && fgets(line, sizeof line, f)) {
        alloc_site a;
        if (!strncmp(line, "overflow", 8)) *overflow = 1;
        if (sscanf(line, "%llx %ld %63s", &a.site, &a.first, a.module) != 3) continue;
        if (module && strncmp(a.module, module, strlen(module))) continue;
        if (*n == cap) {
            cap = cap ? 2 * cap : 1024;
            alloc_site *nv = realloc(v, cap * sizeof *nv);
            if (!nv) break;
            v = nv;
        }
        v[(*n)++] = a;
    }
    if (f) fclose(f);
    return v;
}

static int by_site(const void *a, const void *b)
{
    unsigned long long x = ((const alloc_site *)a)->site, y = ((const alloc_site *)b)->site;
    return (x > y) - (x < y);
}

/* How many of a's sites are not among b's (both sorted by site). */
static size_t sites_missing(const alloc_site *a, size_t na, const alloc_site *b, size_t nb)
{
    size_t missing = 0;
    for (size_t i = 0, j = 0; i < na; i++) {
        while (j < nb && b[j].site < a[i].site) j++;
        missing += j == nb || b[j].site != a[i].site;
    }
    return missing;
}

/* The outcome of one injected run: 0 bad, 1 failed cleanly, 2 succeeded complete; why (bad). */
typedef struct {
    int outcome;
    char why[4200];
} point_result;

/* The references one scenario's injected runs are judged against. */
typedef struct {
    const scenario *sc;
    const char *db_before, *files_before, *db_ref, *files_ref;
    long total[N_CLASSES];
} sweep_refs;

/* The n-th call of kind k failing (or the first allocation from site) in the work directory
 * work, judged against the references. */
static point_result try_point(const sweep_refs *rf, const char *work, size_t k, long n, unsigned long long site)
{
    point_result pr = {0, ""};
    const scenario *sc = rf->sc;
    char dbp[1400];
    snprintf(dbp, sizeof dbp, "%s/%s", work, sc->db);
    long calls[N_CLASSES];
    int fired, c = 0;
    while (strcmp(class_names[c], kinds[k].cls)) c++;
    int rc = run_injected_at(sc, work, &kinds[k], n, site, NULL, calls, &fired);
    char *dba = survey_fx_db_state(dbp), *fa = files_state(work, sc->db);
    char why[1200] = "";
    if (rc == 0) {
        pr.outcome = !strcmp(dba, rf->db_ref) && !strcmp(fa, rf->files_ref) ? 2 : 0;
        if (!pr.outcome)
            snprintf(why, sizeof why, "succeeded but its output is not complete: %s",
                     strcmp(dba, rf->db_ref) ? first_difference(rf->db_ref, dba) : first_difference(rf->files_ref, fa));
    } else {
        int one_line = rc == 1 && fx_count_lines(out) == 1 && !strncmp(out, "gridsurvey ", 11);
        int db_ok = !strcmp(dba, rf->db_before) || !strcmp(dba, rf->db_ref);
        int ok = one_line && db_ok && files_each_before_or_ref(rf->files_before, rf->files_ref, fa, why, sizeof why);
        if (!one_line) snprintf(why, sizeof why, "exit %d, not one line on stderr", rc);
        else if (!db_ok)
            snprintf(why, sizeof why, "the database is neither as before nor complete: %s",
                     first_difference(rf->db_ref, dba));
        pr.outcome = ok;
    }
    if (!pr.outcome)
        snprintf(pr.why, sizeof pr.why, "%s: %s %s at call %ld of %ld (site %llx, fired %d): %s: %.2000s",
                 sc->name, kinds[k].cls, kinds[k].err, n, rf->total[c], site, fired, why, out);
    free(dba);
    free(fa);
    return pr;
}

/* The step between the tried calls of class c: `make check` sc->points evenly spread, the
 * sweep every call, or every GS_FAULT_MALLOC_STEP-th allocation; in the run scenarios every
 * GS_FAULT_RUN_MALLOC_STEP-th allocation and GS_FAULT_RUN_WRITE_STEP-th write, when set. */
static long point_step(const scenario *sc, int c, long total, int full)
{
    long step = full || total <= sc->points ? 1 : (total + sc->points - 1) / sc->points;
    if (full && c <= 1) {
        const char *e = c == 0 ? getenv("GS_FAULT_MALLOC_STEP") : NULL,
                   *r = getenv(c == 0 ? "GS_FAULT_RUN_MALLOC_STEP" : "GS_FAULT_RUN_WRITE_STEP");
        if (r && *r && !strncmp(sc->name, "run-", 4)) e = r;
        if (e && *e) step = atol(e);
    }
    return step < 1 ? 1 : step;
}

/* One scenario through every kind of fault: `make check` at sc->points points of each,
 * GS_FAULT_SWEEP=full at every point, GS_FAULT_SWEEP=sites at every point but the allocations,
 * which fail once for each distinct stack they are made from (its first call); on
 * GS_FAULT_JOBS workers (each its own process and work directory; their outcomes come back
 * through a file each). */
static void sweep(const scenario *sc)
{
    const char *mode = getenv("GS_FAULT_SWEEP");
    int sites_mode = mode && !strcmp(mode, "sites"), full = sites_mode || (mode && !strcmp(mode, "full"));
    int by_sites = sites_mode || sc->site_module;
    int jobs = getenv("GS_FAULT_JOBS") ? atoi(getenv("GS_FAULT_JOBS")) : 1;
    if (jobs < 1 || jobs > 64) jobs = 1;
    char work[1100], dbp[1200];
    snprintf(work, sizeof work, "%s/%s", fx_tmp("fault-work"), sc->name);
    snprintf(dbp, sizeof dbp, "%s/%s", work, sc->db);
    /* before and after an uninjected run */
    int fired;
    sweep_refs rf = {sc, NULL, NULL, NULL, NULL, {0}};
    char *db_before, *files_before;
    set_up(sc, work, &db_before, &files_before);
    long again[N_CLASSES];
    /* two uninjected runs: the counts of calls, and the complete state (the same twice: the
     * oracle needs the command to be deterministic) */
    char sites_path[2][1200];
    for (int i = 0; i < 2; i++) snprintf(sites_path[i], sizeof sites_path[i], "%s.sites%d", work, i);
    int rc = run_injected_at(sc, work, &kinds[0], 0, 0, by_sites ? sites_path[0] : NULL, rf.total, &fired);
    CHECK_MSG(rc == 0 && rf.total[0] >= 0, "%s: the uninjected run: %d: %s", sc->name, rc, out);
    char *db_ref = survey_fx_db_state(dbp), *files_ref = files_state(work, sc->db);
    rc = run_injected_at(sc, work, &kinds[0], 0, 0, by_sites ? sites_path[1] : NULL, again, &fired);
    CHECK_MSG(rc == 0 && again[0] >= 0, "%s: the uninjected run: %d: %s", sc->name, rc, out);
    char *dbr = survey_fx_db_state(dbp), *fr = files_state(work, sc->db);
    CHECK_MSG(!strcmp(dbr, db_ref), "%s: two uninjected runs differ: %s", sc->name, first_difference(db_ref, dbr));
    CHECK_MSG(!strcmp(fr, files_ref), "%s: two uninjected runs differ: %s", sc->name, first_difference(files_ref, fr));
    free(dbr);
    free(fr);
    /* the allocation sites (by_sites): the same in both runs, each tried at its first call */
    size_t n_sites = 0, n_again = 0, unstable = 0;
    int overflow = 0, overflow_again = 0;
    alloc_site *sites = by_sites ? read_sites(sites_path[0], sc->site_module, &n_sites, &overflow) : NULL;
    if (by_sites) {
        alloc_site *sites_again = read_sites(sites_path[1], sc->site_module, &n_again, &overflow_again);
        CHECK_MSG(n_sites > 0 && !overflow && !overflow_again, "%s: %zu allocation sites (overflow %d %d)",
                  sc->name, n_sites, overflow, overflow_again);
        alloc_site *a = malloc((n_sites + 1) * sizeof *a);
        CHECK(a != NULL);
        if (a && sites_again) {
            memcpy(a, sites, n_sites * sizeof *a);
            qsort(a, n_sites, sizeof *a, by_site);
            qsort(sites_again, n_again, sizeof *sites_again, by_site);
            unstable = sites_missing(a, n_sites, sites_again, n_again) + sites_missing(sites_again, n_again, a, n_sites);
        }
        free(a);
        free(sites_again);
    }
    rf.db_before = db_before;
    rf.files_before = files_before;
    rf.db_ref = db_ref;
    rf.files_ref = files_ref;
    long tried = 0, failed_ok = 0, succeeded = 0, bad = 0, malloc_step = 1, write_step = 1;
    /* the points, in order: point i goes to worker i % jobs */
    size_t n_points = 0, cap_points = 0;
    struct point {
        size_t k;
        long n;
        unsigned long long site;
    } *points = NULL;
    /* (a scenario of one module's allocations tries only them) */
    for (size_t k = 0; k < (sc->site_module ? 1 : sizeof kinds / sizeof *kinds); k++) {
        int c = 0;
        while (strcmp(class_names[c], kinds[k].cls)) c++;
        int each_site = by_sites && c == 0;
        long end = each_site ? (long)n_sites : rf.total[c];
        long step = each_site && full ? 1 : point_step(sc, c, end, full);
        if (c == 0) malloc_step = step;
        if (c == 1) write_step = step;
        for (long n = 1 + (full ? 0 : (step - 1) / 2); n <= end; n += step) {
            if (n_points == cap_points) {
                cap_points = cap_points ? 2 * cap_points : 256;
                struct point *np = realloc(points, cap_points * sizeof *np);
                CHECK(np != NULL);
                if (!np) break;
                points = np;
            }
            points[n_points++] = each_site ? (struct point){k, 0, sites[n - 1].site} : (struct point){k, n, 0};
        }
    }
    free(sites);
    /* GS_FAULT_POINTS=A-B: only the points A..B (1-based, in the order above) of this list, so a
     * sweep too long for one sitting runs in parts with the same binaries */
    size_t lo = 0, hi = n_points;
    const char *range = getenv("GS_FAULT_POINTS");
    if (range && *range) {
        unsigned long a = 0, b = 0;
        int ok = sscanf(range, "%lu-%lu", &a, &b) == 2 && a >= 1 && a <= b;
        CHECK_MSG(ok, "GS_FAULT_POINTS=%s: expected A-B, 1 <= A <= B", range);
        lo = ok && a - 1 < n_points ? a - 1 : n_points;   /* (none when malformed) */
        hi = ok && b < n_points ? b : n_points;
    }
    pid_t pids[64];
    char res[64][1200];
    for (int w = 0; w < jobs; w++) {
        snprintf(res[w], sizeof res[w], "%s.worker%d", work, w);
        fflush(NULL);
        pids[w] = jobs > 1 ? fork() : 0;
        CHECK(pids[w] >= 0);
        if (pids[w] != 0) continue;
        /* a worker: its points, each outcome a line "OUTCOME WHY" (why without newlines) */
        char wwork[1200];
        snprintf(wwork, sizeof wwork, "%s-w%d", work, w);
        FILE *f = fopen(res[w], "w");
        for (size_t i = lo + (size_t)w; f && i < hi; i += (size_t)jobs) {
            point_result pr = try_point(&rf, jobs > 1 ? wwork : work, points[i].k, points[i].n, points[i].site);
            for (char *p = pr.why; *p; p++)
                if (*p == '\n') *p = ' ';
            fprintf(f, "%d %s\n", pr.outcome, pr.why);
            fflush(f);
        }
        if (f) fclose(f);
        if (jobs > 1) _exit(f ? 0 : 1);
    }
    for (int w = 0; w < jobs; w++) {
        if (jobs > 1) {
            int st = 0;
            CHECK(waitpid(pids[w], &st, 0) == pids[w] && WIFEXITED(st) && WEXITSTATUS(st) == 0);
        }
        FILE *f = fopen(res[w], "r");
        CHECK_MSG(f != NULL, "%s: no outcomes from worker %d", res[w], w);
        char line[4400];
        while (f && fgets(line, sizeof line, f)) {
            int outcome = line[0] - '0';
            tried++;
            failed_ok += outcome == 1;
            succeeded += outcome == 2;
            bad += outcome == 0;
            line[strcspn(line, "\n")] = '\0';
            CHECK_MSG(outcome != 0, "%s", line + 2);
        }
        if (f) fclose(f);
    }
    CHECK_MSG(tried == (long)(hi - lo), "%s: %ld of %zu points have an outcome", sc->name, tried, hi - lo);
    free(points);
    const char *rep = getenv("GS_FAULT_REPORT");
    FILE *r = rep && *rep ? fopen(rep, "a") : NULL;
    char malloc_tried[80];
    if (by_sites)
        snprintf(malloc_tried, sizeof malloc_tried, "%s %zu %s stacks (%zu unstable)", malloc_step > 1 ? "spread over" : "each of",
                 n_sites, sc->site_module ? sc->site_module : "", unstable);
    else snprintf(malloc_tried, sizeof malloc_tried, "every %ld", malloc_step);
    char label[160];
    if (lo > 0 || hi < n_points) snprintf(label, sizeof label, "`%s` (points %zu-%zu of %zu)", sc->name, lo + 1, hi, n_points);
    else snprintf(label, sizeof label, "`%s`", sc->name);
    if (r) {
        fprintf(r, "| %s | %ld | %s | %ld | every %ld | %ld | %ld | %ld | %ld | %ld | %ld |\n", label, rf.total[0],
                malloc_tried, rf.total[1], write_step, rf.total[2], rf.total[3], tried, failed_ok, succeeded, bad);
        fclose(r);
    }
    if (getenv("GS_TEST_VERBOSE"))
        printf("    %s: calls malloc %ld (%s tried), write %ld, fsync %ld, rename %ld; %ld tried: %ld "
               "failed cleanly, %ld succeeded, %ld bad\n", sc->name, rf.total[0], malloc_tried, rf.total[1],
               rf.total[2], rf.total[3], tried, failed_ok, succeeded, bad);
    free(db_before);
    free(files_before);
    free(db_ref);
    free(files_ref);
}

/* `delight import` took a DELIGHT database it could not open (fopen failing: out of memory here,
 * out of file descriptors or permissions elsewhere) for an absent one, started empty and saved
 * only the imported bulbs over it, exit 0 (found by the allocation-site sweep, at the 2nd
 * allocation). The first 12 allocations of an import into a database holding other bulbs fail
 * in turn: each run fails in one line leaving the database as it was, or succeeds complete. */
TEST(delight_import_failed_open_never_replaces_the_database)
{
    const scenario *sc = &scenarios[5];
    char work[1100], dbp[1200], *db_before, *files_before;
    snprintf(work, sizeof work, "%s/open", fx_tmp("fault-work"));
    snprintf(dbp, sizeof dbp, "%s/%s", work, sc->db);
    set_up(sc, work, &db_before, &files_before);
    sweep_refs rf = {sc, db_before, files_before, NULL, NULL, {0}};
    int fired;
    CHECK_MSG(run_injected(sc, work, &kinds[0], 0, rf.total, &fired) == 0 && rf.total[0] > 12, "%s", out);
    char *db_ref = survey_fx_db_state(dbp), *files_ref = files_state(work, sc->db);
    rf.db_ref = db_ref;
    rf.files_ref = files_ref;
    for (long n = 1; n <= 12; n++) {
        point_result pr = try_point(&rf, work, 0, n, 0);
        CHECK_MSG(pr.outcome != 0, "%s", pr.why);
    }
    free(db_before);
    free(files_before);
    free(db_ref);
    free(files_ref);
}

/* The shim's site mode (GS_FAULT_SWEEP=sites): a count-only run lists the distinct stacks the
 * allocations come from, each with its first call; failing the first allocation from a site must
 * be failing that call. Oracle: the n-th-call mode of the same shim, on a single-threaded command
 * (export): the same exit, the same stderr and the same number of allocations made. */
TEST(fault_site_is_the_allocation_of_its_first_call)
{
    const scenario *sc = &scenarios[2];
    char work[1100], sites_file[1200];
    snprintf(work, sizeof work, "%s/sites", fx_tmp("fault-work"));
    snprintf(sites_file, sizeof sites_file, "%s.sites", work);
    long total[N_CLASSES], calls[N_CLASSES];
    int fired;
    CHECK(run_injected_at(sc, work, &kinds[0], 0, 0, sites_file, total, &fired) == 0 && !fired);
    size_t n = 0;
    int overflow;
    alloc_site *sites = read_sites(sites_file, NULL, &n, &overflow);
    CHECK_MSG(n > 10 && (long)n < total[0] && !overflow, "%zu sites of %ld allocations", n, total[0]);
    if (n <= 10) {
        free(sites);
        return;
    }
    CHECK(sites[0].first == 1);   /* the first allocation is a new site, and so on in order */
    for (size_t i = 1; i < n; i++) CHECK(sites[i].first > sites[i - 1].first && sites[i].first <= total[0]);
    const size_t pick[] = {1, n / 2, n - 1};
    for (int j = 0; j < 3; j++) {
        const alloc_site *a = &sites[pick[j]];
        int rc_site = run_injected_at(sc, work, &kinds[0], 0, a->site, NULL, calls, &fired), fired_site = fired;
        long made_site = calls[0];
        char out_site[4096];
        snprintf(out_site, sizeof out_site, "%.4000s", out);
        int rc_n = run_injected(sc, work, &kinds[0], a->first, calls, &fired);
        CHECK_MSG(fired_site && fired, "site %llx (call %ld): fired %d and %d", a->site, a->first, fired_site, fired);
        CHECK_MSG(rc_site == rc_n && made_site == calls[0] && !strcmp(out_site, out),
                  "site %llx, its first call %ld: exit %d after %ld allocations (%s), and %d after %ld (%s)",
                  a->site, a->first, rc_site, made_site, out_site, rc_n, calls[0], out);
    }
    free(sites);
}

TEST(fault_injection_export_geojson) { sweep(&scenarios[2]); }
TEST(fault_injection_export_gpkg) { sweep(&scenarios[3]); }
TEST(fault_injection_delight_import_new) { sweep(&scenarios[4]); }
TEST(fault_injection_delight_import_existing) { sweep(&scenarios[5]); }
TEST(fault_injection_run_existing_database) { sweep(&scenarios[1]); }
TEST(fault_injection_recognize_opencv_out_of_memory_is_one_line) { sweep(&scenarios[6]); }
/* (only in `make faults`, last: `make check` has run_failed_leaves_no_new_database) */
TEST_HIDDEN(fault_injection_run_new_database, 0) { sweep(&scenarios[0]); }

/* ------------------------------------------------------------------ the defects it found */

/* `run` stored the DELIGHT version, the survey and the station each in a transaction of its
 * own before the capture's: a capture that failed to go in (a full disk at its commit) left a
 * survey without it. Now all are one transaction. The failure here is a trigger that refuses
 * the capture's row. */
TEST(run_failed_capture_insert_leaves_database_as_it_was)
{
    const char *dir = fx_tmp("trigger"), *a = assets();
    char *bin = realpath(test_bin(), NULL), cmd[8192];
    CHECK(bin != NULL);
    snprintf(cmd, sizeof cmd, "mkdir -p %s && cd %s && %s db init --db s.sqlite >/dev/null && sqlite3 s.sqlite "
             "\"CREATE TRIGGER refuse BEFORE INSERT ON captures BEGIN SELECT RAISE(ABORT, 'refused'); END\"",
             dir, dir, bin ? bin : "");
    CHECK(test_run(cmd, out, sizeof out) == 0);
    char db[1200];
    snprintf(db, sizeof db, "%s/s.sqlite", dir);
    char *before = survey_fx_db_state(db);
    snprintf(cmd, sizeof cmd, "cd %s && %s run %s/cap --db s.sqlite --survey night --light-height-m 10 --out-dir . "
             "2>&1 >/dev/null", dir,
             bin ? bin : "", a);
    CHECK(test_run(cmd, out, sizeof out) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "refused"), "%s", out);
    char *after = survey_fx_db_state(db);
    CHECK_MSG(!strcmp(before, after), "the database changed: %s", first_difference(before, after));
    free(before);
    free(after);
    free(bin);
}

/* `delight import` into a new file: a failed commit (here the first fsync) left a database file
 * behind that was neither absent nor complete. A new file is now built under a temporary name. */
TEST(delight_import_failed_commit_leaves_no_new_file)
{
    const scenario sc = {"delight-new", 0, "%s delight import %s/some.csv --delight delight.sqlite",
                         "delight.sqlite", setup_empty, NULL};
    char work[1100];
    snprintf(work, sizeof work, "%s/one", fx_tmp("fault-work"));
    const fault_kind k = {"fsync", "EIO"};
    long calls[N_CLASSES];
    int fired;
    CHECK(run_injected(&sc, work, &k, 1, calls, &fired) == 1 && fired);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "delight.sqlite"), "%s", out);
    char *files = files_state(work, "none");
    CHECK_MSG(!files[0], "left behind: %s", files);
    free(files);
}

/* A new survey database (`db init`, and `run` into a new file) is built under a temporary name
 * in WAL mode: a write that failed while closing it (folding the log into the file) left the
 * temporary -wal and -shm files behind and renamed an incomplete file into place. Every write
 * of `db init` fails in turn here (`make check`: the last 8, where the file is closed, and 6
 * more spread over the others): each either fails in one line leaving nothing, or succeeds
 * with a database `db check` accepts. */
TEST(db_init_write_failure_leaves_no_file)
{
    const scenario sc = {"db-init", 0, "%s db init --db survey.sqlite", "survey.sqlite", setup_empty, NULL};
    char work[1100], db[1200];
    snprintf(work, sizeof work, "%s/init", fx_tmp("fault-work"));
    snprintf(db, sizeof db, "%s/survey.sqlite", work);
    const fault_kind k = {"write", "ENOSPC"};
    long counts[N_CLASSES] = {0}, calls[N_CLASSES];
    int fired;
    int ok = run_injected(&sc, work, &k, 0, counts, &fired) == 0 && counts[1] > 0;
    CHECK(ok);
    if (!ok) return;   /* no count to sweep over */
    long total = counts[1];
    char *bin = realpath(test_bin(), NULL);
    int full = getenv("GS_FAULT_SWEEP") && !strcmp(getenv("GS_FAULT_SWEEP"), "full");
    long step = full ? 1 : total / 6 + 1;
    for (long n = 1; n <= total; n++) {
        if (!full && n <= total - 8 && (n - 1) % step) continue;
        int rc = run_injected(&sc, work, &k, n, calls, &fired);
        char *files = files_state(work, "none");
        if (rc == 0) {
            char cmd[4096];
            snprintf(cmd, sizeof cmd, "%s db check --db %s", bin ? bin : "", db);
            CHECK_MSG(test_run(cmd, out, sizeof out) == 0, "write %ld of %ld: succeeded, but: %s", n, total, out);
        } else {
            CHECK_MSG(rc == 1 && fx_count_lines(out) == 1, "write %ld of %ld: %d: %s", n, total, rc, out);
            CHECK_MSG(!files[0], "write %ld of %ld: failed and left: %s", n, total, files);
            /* the file the user named, not the temporary one it is built in */
            CHECK_MSG(strstr(out, "survey.sqlite") && !strstr(out, ".tmp."), "write %ld of %ld: %s", n, total, out);
        }
        free(files);
    }
    free(bin);
}

/* The map (`run`'s and `locate --map`'s) was written by PLplot's pngcairo driver, which ignores
 * a failed write of its file: the command exited 0 leaving a truncated map (0 to 52 KB of 60).
 * The map is now drawn by the memcairo driver into memory and written by the format kit. Every
 * write of `locate --map` fails in turn: each run exits 0 with the complete map and GeoJSON, or
 * 1 in one line with each of them absent or complete. */
static void setup_locate(const char *work, const char *assets_dir)
{
    (void)assets_dir;
    char path[1200];
    snprintf(path, sizeof path, "%s/st.json", work);
    fx_write_text(path, "{\"format\": \"gridsurvey-station/1\", \"lat_deg\": 40.0, \"lon_deg\": -75.0,\n"
                        " \"height_m\": 120.0, \"heading_deg\": 30, \"pitch_deg\": -5, \"roll_deg\": 1,\n"
                        " \"focal_px\": 2000, \"cx_px\": 959.5, \"cy_px\": 539.5}\n");
    snprintf(path, sizeof path, "%s/px.csv", work);
    fx_write_text(path, "id,x_px,y_px\nA,959.5,539.5\nB,100,800\n");
}

TEST(map_write_failure_never_leaves_a_partial_map)
{
    const scenario sc = {"locate-map", 0, "%s locate --station st.json --pixels px.csv --light-height-m 30 -o l.geojson "
                         "--map m.png", "none", setup_locate, NULL};
    char work[1100];
    snprintf(work, sizeof work, "%s/locate", fx_tmp("fault-work"));
    const fault_kind k = {"write", "EIO"};
    long counts[N_CLASSES] = {0}, calls[N_CLASSES];
    int fired;
    int ok = run_injected(&sc, work, &k, 0, counts, &fired) == 0 && counts[1] > 0;
    CHECK_MSG(ok, "%s", out);
    if (!ok) return;
    char *before = strdup(""), *ref = files_state(work, "none");
    CHECK(strstr(ref, "./m.png") != NULL);
    for (long n = 1; n <= counts[1]; n++) {
        int rc = run_injected(&sc, work, &k, n, calls, &fired);
        CHECK_MSG(rc == 0 || (rc == 1 && fx_count_lines(out) == 1), "write %ld of %ld: exit %d: %s", n,
                  counts[1], rc, out);
        char *after = files_state(work, "none"), why[1200] = "";
        /* the inputs are there before and after; the outputs each absent or complete */
        CHECK_MSG(files_each_before_or_ref(before, ref, after, why, sizeof why), "write %ld of %ld: %s", n,
                  counts[1], why);
        if (rc == 0) CHECK_MSG(!strcmp(after, ref), "write %ld: succeeded: %s", n, first_difference(ref, after));
        free(after);
    }
    free(before);
    free(ref);
}

/* Runs CMD (printf: the binary, assets twice) in an empty work set up by setup (or none), with
 * tests/faults/plcrash.so preloaded failing the at-th plinit the way how says (at 0: every one);
 * plinit calls are counted in work.plinit. Its exit status, stderr in out. */
static int run_plcrash(const char *work, const char *how, int at, const char *cmd_fmt,
                       void (*setup)(const char *, const char *))
{
    char cmd[8192], run[4096];
    const char *crash = shim_path_of("plcrash.so");
    char *bin = realpath(test_bin(), NULL), *shim = realpath(crash, NULL);
    CHECK_MSG(bin && shim, "%s or %s: not found", test_bin(), crash);
    int rc = -1;
    if (bin && shim) {
        snprintf(cmd, sizeof cmd, "rm -rf %s %s.plinit && mkdir -p %s", work, work, work);
        CHECK(test_run(cmd, NULL, 0) == 0);
        if (setup) setup(work, assets());
        snprintf(run, sizeof run, cmd_fmt, bin, assets(), assets());
        char at_env[64] = "";
        if (at > 0) snprintf(at_env, sizeof at_env, "GS_PLCRASH_AT=%d ", at);
        snprintf(cmd, sizeof cmd,
                 "cd %s && env GS_PLCRASH=%s %sGS_PLCRASH_COUNT=%s.plinit LD_PRELOAD=%s "
                 "ASAN_OPTIONS=${ASAN_OPTIONS:+$ASAN_OPTIONS:}verify_asan_link_order=0 %s 2>&1 >/dev/null",
                 work, how, at_env, work, shim, run);
        rc = test_run(cmd, out, sizeof out);
    }
    free(bin);
    free(shim);
    return rc;
}

/* plinit calls counted by run_plcrash. */
static int plinit_calls(const char *work)
{
    char path[1200];
    snprintf(path, sizeof path, "%s.plinit", work);
    FILE *f = fopen(path, "r");
    int n = 0;
    if (f) {
        if (fscanf(f, "%d", &n) != 1) n = 0;
        fclose(f);
    }
    return n;
}

/* PLplot and its text stack exit or crash when they fail (docs/reliability.md): every drawing
 * with PLplot runs in a child process (gs_isolated), so a crash there fails the command in one
 * line naming the drawing's file, every output absent or complete. Each drawing of `locate
 * --map`, `recognize --maps` (three maps and a signal plot), `delight plot` and `run` (its map)
 * is failed in turn by tests/faults/plcrash.c, which makes plinit crash (SIGSEGV, abort) or
 * exit through PLplot's plexit; the exit's reason must be the line's end. */
TEST(map_drawing_crash_fails_in_one_line)
{
    static const struct {
        const char *name, *cmd;
        void (*setup)(const char *, const char *);
        int drawings;   /* plinit calls of an uninjected run */
    } cmds[] = {
        {"locate", "%s locate --station st.json --pixels px.csv --light-height-m 30 -o l.geojson --map m.png",
         setup_locate, 1},
        {"recognize", "%s recognize %s/cap --format json --delight %s/small-delight.sqlite --maps mp", NULL, 4},
        {"delight plot", "%s delight plot --ids inc-a19-25w-120v,hps-150w -o brf.png", NULL, 1},
        {"run", "%s run %s/cap --db survey.sqlite --survey night --light-height-m 10 --out-dir .", setup_empty, 1},
    };
    static const char *const hows[] = {"segv", "abort", "exit"};
    char work[1100];
    snprintf(work, sizeof work, "%s/plcrash", fx_tmp("fault-work"));
    for (size_t c = 0; c < sizeof cmds / sizeof *cmds; c++) {
        int rc = run_plcrash(work, "none", 0, cmds[c].cmd, cmds[c].setup);   /* PLplot's own plinit */
        char *ref = files_state(work, "survey.sqlite");
        CHECK_MSG(rc == 0 && plinit_calls(work) == cmds[c].drawings, "%s: exit %d, %d drawings: %s", cmds[c].name,
                  rc, plinit_calls(work), out);
        char named[4][256] = {{0}};
        /* the first command: every way at its drawing; the others: a way per drawing */
        int tries = c == 0 ? 3 : cmds[c].drawings;
        for (int t = 0; t < tries; t++) {
            int at = c == 0 ? 1 : t + 1;
            const char *how = hows[c == 0 ? (size_t)t : ((size_t)t + c) % 3];
            rc = run_plcrash(work, how, at, cmds[c].cmd, cmds[c].setup);
            const char *what = strstr(out, ": the drawing process ");
            CHECK_MSG(rc == 1 && fx_count_lines(out) == 1 && what && strstr(out, ".png: the drawing process "),
                      "%s, %s at drawing %d: exit %d: %s", cmds[c].name, how, at, rc, out);
            if (!strcmp(how, "exit"))
                CHECK_MSG(strstr(out, "(exit status 1): plinit: out of memory\n"), "%s: %s", cmds[c].name, out);
            if (what && c > 0 && t < 4) {   /* the file it names: "gridsurvey CMD: FILE: the drawing ..." */
                const char *p = what;
                while (p > out && p[-1] != ' ') p--;
                snprintf(named[t], sizeof named[t], "%.*s", (int)(what - p), p);
                for (int u = 0; u < t; u++)
                    CHECK_MSG(strcmp(named[u], named[t]), "%s: drawing %d and %d both name %s", cmds[c].name,
                              u + 1, t + 1, named[t]);
            }
            char *after = files_state(work, "survey.sqlite"), why[1200] = "";
            CHECK_MSG(files_each_before_or_ref("", ref, after, why, sizeof why), "%s, %s at drawing %d: %s",
                      cmds[c].name, how, at, why);
            free(after);
        }
        free(ref);
    }
}

/* A nearly full disk could fail as "disk I/O error": SQLite reports a write that failed with
 * ENOSPC while it maps its WAL index as an I/O error, which says nothing of the disk. The
 * system's error is now named behind SQLite's. The first 12 writes of a new survey database's
 * ingest fail in turn with ENOSPC: every failure is one line, and each I/O error among them
 * (there are some) ends "(No space left on device)"; one EIO reads "(Input/output error)". */
TEST(survey_db_full_disk_names_the_system_error)
{
    const scenario sc = {"full-disk", 0, "%s db ingest-synthetic --db s.sqlite --survey s --captures 2 --lights 50",
                         "s.sqlite", setup_empty, NULL};
    char work[1100];
    snprintf(work, sizeof work, "%s/full", fx_tmp("fault-work"));
    long calls[N_CLASSES];
    int fired, io_errors = 0;
    for (long n = 1; n <= 12; n++) {
        const fault_kind k = {"write", "ENOSPC"};
        int rc = run_injected(&sc, work, &k, n, calls, &fired);
        if (rc == 0) continue;
        CHECK_MSG(rc == 1 && fx_count_lines(out) == 1, "write %ld: %d: %s", n, rc, out);
        if (!strstr(out, "disk I/O error")) continue;
        io_errors++;
        CHECK_MSG(strstr(out, "disk I/O error (No space left on device)"), "write %ld: %s", n, out);
    }
    CHECK_MSG(io_errors > 0, "no write failed as an I/O error");
    const fault_kind k = {"write", "EIO"};
    CHECK(run_injected(&sc, work, &k, 1, calls, &fired) == 1 && fired);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "disk I/O error (Input/output error)"), "%s", out);
}
