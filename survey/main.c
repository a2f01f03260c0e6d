/* main.c - the gridsurvey command line (git-style subcommands). */
#include "survey/survey.h"

int main(int argc, char **argv)
{
    return srv_main(argc, argv);
}
