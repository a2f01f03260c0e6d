/* test_cli_delight.c - `gridsurvey delight` end to end: the built-in database's coverage through
 * `export`, export -> import -> export identity, `add` of a real recording and of an unlocked
 * one (a one-line warning), `plot` writing a real PNG titled with every plotted bulb's grid,
 * --help everywhere, and bad input as one-line errors with a non-zero exit. */
#include "recognize/recognize.h"
#include "survey/internal.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static char out[1 << 20];

/* `gridsurvey ...`: fmt's first %s is the binary (tests/fixtures.h); output in out. */
static int run(const char *fmt, const char *a, const char *b)
{
    return fx_run_bin(out, sizeof out, fmt, a, b, NULL);
}

TEST(cli_delight_export_covers_30_bulbs_9_technologies)
{
    /* The export is parsed here independently of the library's CSV reader. */
    const char *path = fx_tmp("d.csv");
    CHECK(run("%s delight export -o %s", path, NULL) == 0);
    FILE *f = fopen(path, "r");
    CHECK(f != NULL);
    if (!f) return;
    char *line = NULL;
    size_t cap = 0;
    CHECK(getline(&line, &cap, f) > 0 && !strncmp(line, "bulb_id,type,name,watts,grid_hz,sensor,band,chromaticity,n,v0,v1,", 65));
    enum { MAXB = 512 };
    static char ids[2][MAXB][64], techs[2][MAXB][64];
    int nid[2] = {0, 0}, ntech[2] = {0, 0};
    while (getline(&line, &cap, f) > 0) {
        char id[64], type[64];
        int hz;
        if (sscanf(line, "%63[^,],%63[^,],%*[^,],%*[^,],%d,", id, type, &hz) != 3) continue;
        int g = hz == 60;
        int seen = 0;
        for (int i = 0; i < nid[g] && !seen; i++) seen = !strcmp(ids[g][i], id);
        if (!seen && nid[g] < MAXB) strcpy(ids[g][nid[g]++], id);
        seen = 0;
        for (int i = 0; i < ntech[g] && !seen; i++) seen = !strcmp(techs[g][i], type);
        if (!seen && ntech[g] < MAXB) strcpy(techs[g][ntech[g]++], type);
    }
    free(line);
    fclose(f);
    for (int g = 0; g < 2; g++) {
        CHECK_MSG(nid[g] >= 30, "%d Hz: %d bulbs, expected >= 30", g ? 60 : 50, nid[g]);
        CHECK_MSG(ntech[g] >= 9, "%d Hz: %d technologies, expected >= 9", g ? 60 : 50, ntech[g]);
    }
}

TEST(cli_delight_import_export_identity)
{
    const char *csv1 = fx_tmp("a.csv"), *csv2 = fx_tmp("b.csv"), *db = fx_tmp("d.sqlite");
    CHECK(run("%s delight export -o %s", csv1, NULL) == 0);
    CHECK(run("%s delight import %s --delight %s", csv1, db) == 0);
    CHECK(run("%s delight export --delight %s -o %s", db, csv2) == 0);
    char cmd[3000];
    snprintf(cmd, sizeof cmd, "cmp %s %s", csv1, csv2);
    CHECK(test_run(cmd, out, sizeof out) == 0);
    /* importing the same entries again is refused and leaves the database as it was */
    CHECK(run("%s delight import %s --delight %s", csv1, db) == 1);
    CHECK(strstr(out, "already in the database") != NULL);
    CHECK(run("%s delight export --delight %s -o %s", db, csv2) == 0);
    CHECK(test_run(cmd, out, sizeof out) == 0);
}

TEST(cli_delight_add_real_recording)
{
    const char *db = fx_tmp("m.sqlite");
    const char *rec = test_shared_path("data/flicker/Feit 60W.csv");
    char quoted[1100];
    snprintf(quoted, sizeof quoted, "'%s'", rec);
    CHECK(run("%s delight add --from-recording %s --id feit-60w --type incandescent --delight %s", quoted, db) == 0);
    CHECK(strstr(out, "reference none") != NULL);
    CHECK(run("%s delight list --delight %s", db, NULL) == 0);
    CHECK(strstr(out, "feit-60w") && strstr(out, "incandescent") && strstr(out, "1 entries"));
}

/* A 500 Hz driver filed with --grid 50: the percent flicker of 1 + 0.5 sin^2 (20 %, a rate of
 * 100 kHz: 200 samples a cycle) and a one-line warning that its flicker is not at twice the grid. */
TEST(cli_delight_add_unlocked_warns_and_keeps_percent_flicker)
{
    const char *rec = fx_tmp("driver500.csv"), *db = fx_tmp("u.sqlite");
    FILE *f = fopen(rec, "w");
    CHECK(f != NULL);
    if (!f) return;
    for (int i = 0; i < 20000; i++)
        fprintf(f, "%.9g,%.12g\n", i * 1e-5, 1 + 0.5 * pow(sin(M_PI * 500 * i * 1e-5), 2));
    fclose(f);
    CHECK(run("%s delight add --from-recording %s --grid 50 --delight %s", rec, db) == 0);
    CHECK_MSG(strstr(out, "percent flicker 20.0, reference unlocked") != NULL, "%s", out);
    /* the warning is one line of its own */
    const char *w = strstr(out, "warning: ");
    const char *hit = strstr(out, "driver500.csv: flicker at 500.00 Hz is not twice the 50 Hz grid");
    CHECK_MSG(w && hit && hit < strchr(w, '\n') && fx_count_lines(out) == 2, "%s", out);
    CHECK(run("%s delight show driver500 --delight %s", db, NULL) == 0);
    CHECK_MSG(strstr(out, "reference unlocked") && strstr(out, "percent flicker 20.00"), "%s", out);
    /* no --watts: the power is not given, not 0 W */
    CHECK_MSG(strstr(out, ", power not given, 50 Hz"), "%s", out);
    CHECK(run("%s delight list --delight %s", db, NULL) == 0);
    CHECK_MSG(strstr(out, " unlocked       -  20.0 "), "%s", out);   /* (ref, then watts in 7) */
}


/* A lamp without flicker (0.5 s of a constant at 10 kHz) filed with --grid 50: `add` names the
 * nominal 100 Hz and the cycles the recording spans at it, 0.5 s x 100 Hz = 50 (it printed
 * "over nan cycles": the measured flicker frequency, NaN, times the duration). */
TEST(cli_delight_add_flat_recording_counts_nominal_cycles)
{
    const char *rec = fx_tmp("flat.csv"), *db = fx_tmp("flat.sqlite");
    FILE *f = fopen(rec, "w");
    CHECK(f != NULL);
    if (!f) return;
    for (int i = 0; i < 5000; i++) fprintf(f, "%.9g,0.25\n", i * 1e-4);
    fclose(f);
    CHECK(run("%s delight add --from-recording %s --grid 50 --delight %s", rec, db) == 0);
    CHECK_MSG(strstr(out, "no flicker found, nominal 100.00 Hz over 50.0 cycles, grid 50 Hz, "
                          "percent flicker 0.0, reference none") != NULL, "%s", out);
}
/* A light clipped at the top of the recorder's range (a 100 Hz flicker of 19 % percent flicker,
 * its upper third cut flat: 13.5 %) was filed without a word; now a warning names the file
 * and the share of samples at its largest value. The same wave unclipped, with noise, and the
 * shared/data/flicker recordings (well under 1 % there) file without one. */
TEST(cli_delight_add_warns_of_a_clipped_recording)
{
    const char *rec = fx_tmp("clipped.csv");
    for (int clip = 1; clip >= 0; clip--) {
        const char *db = fx_tmp(clip ? "clipped.sqlite" : "unclipped.sqlite");
        FILE *f = fopen(rec, "w");
        CHECK(f != NULL);
        if (!f) return;
        uint64_t rs = 5;
        for (int i = 0; i < 20000; i++) {
            double v = 1.0 + 0.19 * cos(2 * M_PI * 100.0 * i * 1e-4);
            if (clip) v = fmin(v, 1.1);
            else v += 1e-3 * gs_splitmix_normal(&rs);
            fprintf(f, "%.9g,%.6f\n", i * 1e-4, v);
        }
        fclose(f);
        CHECK(run("%s delight add --from-recording %s --grid 50 --delight %s", rec, db) == 0);
        printf("    %s", out);
        CHECK_MSG(!strstr(out, "warning") == !clip, "clip %d: %s", clip, out);
        /* the flicker: 19 %, and clipped it reads low */
        const char *pf = strstr(out, "percent flicker ");
        double v = pf ? strtod(pf + 16, NULL) : NAN;
        CHECK_MSG(clip ? v < 17.0 : fabs(v - 19.0) < 0.5, "clip %d: percent flicker %g", clip, v);
        CHECK_MSG(!clip || (strstr(out, "clipped.csv: ") && strstr(out, " % of the samples sit at the recording's "
                                                                    "largest value, in runs: a clipped light?")),
                  "%s", out);
    }
    char path[1200];
    snprintf(path, sizeof path, "%s", test_shared_path("data/flicker/CFL.csv"));
    CHECK(run("%s delight add --from-recording %s --delight %s", path, fx_tmp("cfl.sqlite")) == 0);
    CHECK_MSG(!strstr(out, "warning"), "%s", out);
}

TEST(cli_delight_plot_writes_png)
{
    const char *png = fx_tmp("brf.png");
    CHECK(run("%s delight plot --grid 50 -o %s", png, NULL) == 0);
    FILE *f = fopen(png, "rb");
    CHECK(f != NULL);
    if (!f) return;
    unsigned char sig[8] = {0};
    CHECK(fread(sig, 1, 8, f) == 8);
    CHECK(!memcmp(sig, "\x89PNG\r\n\x1a\n", 8));
    fseek(f, 0, SEEK_END);
    CHECK(ftell(f) > 20000); /* axes, labels, legend and curves, not an empty canvas */
    fclose(f);
}

TEST(cli_help_everywhere)
{
    CHECK(run("%s --help", NULL, NULL) == 0 && strstr(out, "delight"));
    CHECK(run("%s delight --help", NULL, NULL) == 0 && strstr(out, "usage: gridsurvey delight"));
    CHECK(run("%s delight list --help", NULL, NULL) == 0 && strstr(out, "usage"));
}

TEST(cli_bad_input_one_line_errors)
{
    const char *bad = fx_tmp("bad.csv");
    fx_write_text(bad, "bulb_id,type,name\nx,y,z\n");
    const char *db = fx_tmp("d.sqlite");
    CHECK(run("%s delight import %s --delight %s", bad, db) == 1);
    CHECK(fx_count_lines(out) == 1 && strstr(out, "bad.csv"));
    FILE *exists = fopen(db, "r");
    CHECK(exists == NULL); /* nothing written */
    if (exists) fclose(exists);
    CHECK(run("%s delight show no-such-bulb", NULL, NULL) == 1);
    CHECK(fx_count_lines(out) == 1 && strstr(out, "no-such-bulb"));
    CHECK(run("%s delight list --delight %s", bad, NULL) == 1);
    CHECK(fx_count_lines(out) == 1 && strstr(out, "bad.csv"));
    CHECK(run("%s delight frobnicate", NULL, NULL) == 2);
    CHECK(run("%s frobnicate", NULL, NULL) == 2);
    CHECK(run("%s delight list --grid 55", NULL, NULL) == 2);
    /* a missing option or argument is a usage error (exit 2, not 1 with "invalid argument") */
    static const struct {
        const char *cmd, *names;
    } usage[] = {
        {"%s delight plot --ids hps-150w", "-o FILE.png"}, {"%s delight generate", "-o DB"},
        {"%s delight show", "bulb id"},                     {"env -u GRIDSURVEY_DELIGHT %s delight import x.csv", "--delight DB"},
        {"%s delight add --delight x.sqlite", "--from-recording"},
    };
    for (size_t i = 0; i < sizeof usage / sizeof *usage; i++)
        CHECK_MSG(run(usage[i].cmd, NULL, NULL) == 2 && fx_count_lines(out) == 1 &&
                  strstr(out, usage[i].names) && strstr(out, "see gridsurvey help delight"),
                  "%s: %s", usage[i].cmd, out);
    /* an unknown --type is a usage error before any work (it was "not found" after the recording) */
    CHECK(run("%s delight add --from-recording none.csv --type led --delight x.sqlite", NULL, NULL) == 2);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "--type: technology 'led': expected one of"), "%s", out);
    /* an unknown --sensor is a usage error naming the database's sensors, not an empty answer */
    CHECK(run("%s delight list --sensor foo", NULL, NULL) == 2);
    CHECK(fx_count_lines(out) == 1 && strstr(out, "--sensor 'foo'") && strstr(out, "photodiode") && strstr(out, "rgb"));
    CHECK(run("%s delight show hps-70w --sensor foo", NULL, NULL) == 2);
    CHECK(fx_count_lines(out) == 1 && strstr(out, "--sensor 'foo'"));
    CHECK(run("%s delight show hps-70w --sensor rgb", NULL, NULL) == 0 && strstr(out, "sensor rgb"));
}

/* Four `delight import`s at once of one bulb each, into a new file and into an existing one:
 * each new file was renamed over the one another process had built (its bulbs lost, exit 0),
 * and a process that found the file busy failed at once ("database is locked", no busy
 * timeout). Now each exits 0 and the database holds every imported row (the union of the CSVs,
 * compared sorted). */
TEST(cli_delight_concurrent_imports_keep_every_bulb)
{
    const char *dir = fx_tmp("concurrent");
    char bin[2048], cmd[8192];
    if (!realpath(test_bin(), bin)) snprintf(bin, sizeof bin, "%s", test_bin());
    snprintf(cmd, sizeof cmd, "mkdir -p %s && cd %s && %s delight export -o all.csv && "
             "for i in 1 2 3 4; do id=$(awk -F, 'NR > 1 {print $1}' all.csv | uniq | sed -n ${i}p); "
             "(head -1 all.csv; awk -F, -v id=$id 'NR > 1 && $1 == id' all.csv) > one$i.csv; done && "
             "tail -q -n +2 one1.csv one2.csv one3.csv one4.csv | sort > want.txt", dir, dir, bin);
    CHECK(test_run(cmd, out, sizeof out) == 0);
    for (int trial = 0; trial < 8; trial++) {
        int existing = trial >= 4;   /* one1's bulb imported first, the others at once */
        snprintf(cmd, sizeof cmd, "cd %s && rm -f d.sqlite && %s%s%s"
                 "for i in %s; do (%s delight import one$i.csv --delight d.sqlite > /dev/null || "
                 "echo \"one$i failed\") & done; wait; "
                 "%s delight export --delight d.sqlite -o - 2>/dev/null | tail -n +2 | sort | cmp - want.txt",
                 dir, existing ? bin : "", existing ? " delight import one1.csv --delight d.sqlite > /dev/null" : "",
                 existing ? " && " : "", existing ? "2 3 4" : "1 2 3 4", bin, bin);
        int rc = test_run(cmd, out, sizeof out);
        CHECK_MSG(rc == 0 && !out[0], "trial %d (%s file): %d: %s", trial, existing ? "existing" : "new", rc, out);
    }
}

/* `delight plot`'s title names the grid of every plotted bulb: bulbs of 60, 50 and 60 Hz (as
 * `--ids` may pick from a database) give both grids, once each; bulbs of one grid give it. */
TEST(cli_delight_plot_title_names_every_grid)
{
    static const int grids[2][3] = {{60, 50, 60}, {60, 60, 60}};
    for (int c = 0; c < 2; c++) {
        gs_bulb b[3];
        const gs_bulb *list[3];
        memset(b, 0, sizeof b);
        for (int i = 0; i < 3; i++) {
            b[i].grid_hz = grids[c][i];
            list[i] = &b[i];
        }
        char title[128];
        srv_delight_plot_title(list, 3, title, sizeof title);
        CHECK_MSG(!strcmp(title, c ? "DELIGHT BRFs, 60 Hz grid" : "DELIGHT BRFs, 50 and 60 Hz grids"), "%s",
                  title);
    }
}
