/* cli.c - gridsurvey's git-style subcommand dispatch and shared option helpers. */
#include "survey/internal.h"

#include <stdio.h>
#include <string.h>

static const struct {
    const char *name;
    int (*run)(int argc, char **argv);
    const char *summary;
} commands[] = {
    {"delight", srv_cmd_delight, "the DELIGHT bulb database: list, show, export, import, add, plot, generate"},
    {"locate", srv_cmd_locate, "locate lights from one station's pixels; GeoJSON, KML, GeoPackage, CSV, map"},
    {"simulate", srv_cmd_simulate, "render a scene into a capture directory and truth.json (ACam simulator)"},
    {"capture", srv_cmd_capture, "run the ACam acquisition loop: --backend sim, replay or hardware"},
    {"stats", srv_cmd_stats, "phase-balance statistics of a survey database (shares, Wilson CIs, chi-square)"},
    {"export", srv_cmd_export, "export a survey database's lights as GeoJSON, KML, GeoPackage or CSV"},
    {"db", srv_cmd_db, "survey database tools: init, migrate, check, ingest-synthetic"},
    {"recognize", srv_cmd_recognize, "bulb type and grid phase of every light in a capture (Eq. 7); maps, plots"},
    {"run", srv_cmd_run, "the whole job: capture (or a capture directory), recognize, locate, store; stats, maps"},
    {"compare", srv_cmd_compare, "changes between two surveys: rephased or replaced lights, appeared, vanished"},
    {"evaluate", srv_cmd_evaluate, "compare a survey database with a simulator's truth.json (rates, errors)"},
    {"unmix", srv_cmd_unmix, "light transport: unmix a capture into one image per source (Eqs. 16-19)"},
    {"relight", srv_cmd_relight, "relight unmixed sources: gain, off, other bulb or phase (Eq. 20)"},
    {"separate", srv_cmd_separate, "separate a window's reflection from the daylit scene behind it (Sec. 5.3)"},
    {"bench", srv_cmd_bench, "performance tables: bench recognize (Eq. 7 throughput), bench db"},
};

static void usage(FILE *f)
{
    fprintf(f, "usage: gridsurvey COMMAND [ARGS]   (gridsurvey COMMAND --help for details)\n\n"
               "Surveys a city's electric grid from its lights at night (bulb type and grid phase\n"
               "of every light, from an AC-locked coded-exposure camera).\n\ncommands:\n");
    for (size_t i = 0; i < sizeof commands / sizeof *commands; i++)
        fprintf(f, "  %-10s %s\n", commands[i].name, commands[i].summary);
}

int srv_main(int argc, char **argv)
{
    if (argc < 2) {
        usage(stderr);
        return 2;
    }
    if (!strcmp(argv[1], "--help") || !strcmp(argv[1], "-h") || !strcmp(argv[1], "help")) {
        usage(stdout);
        return 0;
    }
    for (size_t i = 0; i < sizeof commands / sizeof *commands; i++)
        if (!strcmp(argv[1], commands[i].name)) return commands[i].run(argc - 1, argv + 1);
    fprintf(stderr, "gridsurvey: '%s' is not a command: expected one of", argv[1]);
    for (size_t i = 0; i < sizeof commands / sizeof *commands; i++)
        fprintf(stderr, " %s", commands[i].name);
    fprintf(stderr, " (see gridsurvey --help)\n");
    return 2;
}

int srv_error(gs_status s)
{
    fprintf(stderr, "gridsurvey: %s: %s\n", gs_strerror(s), gs_detail());
    return 1;
}
