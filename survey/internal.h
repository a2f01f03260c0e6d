/* internal.h - survey/ internals: subcommands and CLI helpers. */
#ifndef GRIDSURVEY_SURVEY_INTERNAL_H
#define GRIDSURVEY_SURVEY_INTERNAL_H

#include "recognize/recognize.h"
#include "survey/survey.h"

#include <stdio.h>

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
int srv_cmd_run(int argc, char **argv);
int srv_cmd_evaluate(int argc, char **argv);

/* `gridsurvey bench accuracy` (survey/bench_accuracy.c); argv[0] is "accuracy". */
int srv_bench_accuracy(int argc, char **argv);
/* `gridsurvey bench render` (survey/bench_render.c). */
int srv_bench_render(int argc, char **argv);

/* Print "gridsurvey: STATUS: DETAIL" on stderr and return 1. */
int srv_error(gs_status s);

/* An evaluation (survey/evaluate.c) as Markdown tables or a gridsurvey-evaluation/1 JSON
 * document (json != 0) on f. GS_EIO when f cannot be written. */
gs_status srv_eval_print(const srv_eval_report *r, const char *truth_path, int json, FILE *f);

#endif
