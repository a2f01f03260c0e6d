/* survey.h - the public interface of gridsurvey's survey/ module (prefix srv_): the command
 * line and, later, the survey database, statistics and pipeline. */
#ifndef GRIDSURVEY_SURVEY_H
#define GRIDSURVEY_SURVEY_H

/* Run the gridsurvey command line; returns the process exit status (0 ok, 1 failure with a
 * one-line message on stderr, 2 usage error). */
int srv_main(int argc, char **argv);

#endif
