/* internal.h - survey/ internals: subcommands and CLI helpers. */
#ifndef GRIDSURVEY_SURVEY_INTERNAL_H
#define GRIDSURVEY_SURVEY_INTERNAL_H

#include "recognize/recognize.h"
#include "survey/survey.h"

/* Subcommands: argv[0] is the command name; return the exit status. */
int srv_cmd_delight(int argc, char **argv);
int srv_cmd_locate(int argc, char **argv);
int srv_cmd_simulate(int argc, char **argv);
int srv_cmd_capture(int argc, char **argv);
int srv_cmd_stats(int argc, char **argv);
int srv_cmd_export(int argc, char **argv);
int srv_cmd_db(int argc, char **argv);
int srv_cmd_recognize(int argc, char **argv);
int srv_cmd_bench(int argc, char **argv);

/* `gridsurvey bench render` (survey/bench_render.c). */
int srv_bench_render(int argc, char **argv);

/* Print "gridsurvey: STATUS: DETAIL" on stderr and return 1. */
int srv_error(gs_status s);

#endif
