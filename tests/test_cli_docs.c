/* test_cli_docs.c - the man page (docs/gridsurvey.1) and the bash completion
 * (docs/bash-completion/gridsurvey) against the binary under test: the commands are those that
 * `gridsurvey --help` lists and each command's flags those that `gridsurvey help CMD` names,
 * read here from the binary's own output; the page must have a section for every command with
 * every flag in it (as roff writes a minus, \-), and bash, sourcing the completion, must offer
 * every command and every flag of each. Then: groff renders the page without a warning, both
 * files are what docs/gen-cli-docs.sh makes of this binary (`make cli-docs` after a change to a
 * --help text), and `make install` puts the binary, the page and the completion under
 * DESTDIR/PREFIX. Last, the progress flags: the same three in every command that has them, with
 * the same effect. */
#include "tests/fixtures.h"
#include "tests/survey_fixture.h"
#include "tests/test.h"

#include <ctype.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define MAX_WORDS 128
#define WORD_LEN 48

typedef struct {
    char w[MAX_WORDS][WORD_LEN];
    int n;
} words;

static void words_add(words *ws, const char *s, size_t len)
{
    if (len == 0 || len >= WORD_LEN) return;
    for (int i = 0; i < ws->n; i++)
        if (strlen(ws->w[i]) == len && !strncmp(ws->w[i], s, len)) return;
    CHECK_MSG(ws->n < MAX_WORDS, "more than %d words", MAX_WORDS);
    if (ws->n >= MAX_WORDS) return;
    memcpy(ws->w[ws->n], s, len);
    ws->w[ws->n++][len] = '\0';
}

/* The commands of `gridsurvey --help`: the first word of each two-space-indented line after
 * "commands:". */
static void help_commands(const char *help, words *ws)
{
    ws->n = 0;
    const char *p = strstr(help, "\ncommands:\n");
    if (!p) return;
    for (p = strchr(p + 1, '\n') + 1; !strncmp(p, "  ", 2) && islower((unsigned char)p[2]);) {
        size_t len = strcspn(p + 2, " \n");
        words_add(ws, p + 2, len);
        const char *nl = strchr(p, '\n');
        if (!nl) break;
        p = nl + 1;
    }
}

/* The flags named in a help text: "--word" and "-x..." not preceded by a letter, digit, '_' or
 * '-', running over letters, digits and '-'. */
static void help_flags(const char *text, words *ws)
{
    ws->n = 0;
    for (const char *p = text; *p; p++) {
        if (*p != '-' || (p > text && (isalnum((unsigned char)p[-1]) || p[-1] == '_' || p[-1] == '-')))
            continue;
        const char *q = p + 1 + (p[1] == '-');
        if (!isalpha((unsigned char)*q)) continue;
        while (isalnum((unsigned char)*q) || *q == '-') q++;
        words_add(ws, p, (size_t)(q - p));
        p = q - 1;
    }
}

/* The output of the completion function for the words given (the last is being completed),
 * one candidate a line, with a newline before the first. */
static void complete(const char *line, char *out, size_t size)
{
    char cmd[1024], buf[65536];
    snprintf(cmd, sizeof cmd,
             "bash -c 'source docs/bash-completion/gridsurvey; COMP_WORDS=(%s); "
             "COMP_CWORD=$((${#COMP_WORDS[@]} - 1)); _gridsurvey; printf \"%%s\\n\" \"${COMPREPLY[@]}\"'",
             line);
    CHECK_MSG(test_run(cmd, buf, sizeof buf) == 0, "%s: %s", cmd, buf);
    out[0] = '\n';
    memcpy(out + 1, buf, size - 1 < sizeof buf ? size - 1 : sizeof buf);
    out[size - 1] = '\0';
}

static int offered(const char *out, const char *word)
{
    char needle[WORD_LEN + 2];
    snprintf(needle, sizeof needle, "\n%s\n", word);
    return fx_contains(out, needle);
}

TEST(man_page_and_completion_cover_every_command_and_flag_of_the_help)
{
    static char help[65536], sub[65536], top[65536], reply[65536];
    CHECK(fx_run_bin(help, sizeof help, "%s --help%s%s%s", NULL, NULL, NULL) == 0);
    words cmds;
    help_commands(help, &cmds);
    CHECK_MSG(cmds.n >= 10, "%d commands in gridsurvey --help", cmds.n);
    char *man = fx_read_file("docs/gridsurvey.1", NULL);
    CHECK_MSG(man != NULL, "docs/gridsurvey.1 missing");
    if (!man) return;
    complete("gridsurvey \"\"", top, sizeof top);
    for (int c = 0; c < cmds.n; c++) {
        const char *name = cmds.w[c];
        CHECK_MSG(offered(top, name), "completion of 'gridsurvey ' does not offer %s", name);
        char head[WORD_LEN + 8];
        snprintf(head, sizeof head, "\n.SS %s\n", name);
        const char *sec = strstr(man, head);
        CHECK_MSG(sec != NULL, "docs/gridsurvey.1: no section for the command %s", name);
        /* the section runs to the next .SS or .SH */
        size_t sec_len = 0;
        if (sec) {
            const char *ss = strstr(sec + 1, "\n.SS "), *sh = strstr(sec + 1, "\n.SH ");
            const char *end = ss && (!sh || ss < sh) ? ss : sh;
            sec_len = end ? (size_t)(end - sec) : strlen(sec);
        }
        CHECK(fx_run_bin(sub, sizeof sub, "%s help %s%s%s", name, NULL, NULL) == 0);
        words fl;
        help_flags(sub, &fl);
        char line[128];
        snprintf(line, sizeof line, "gridsurvey %s -", name);
        complete(line, reply, sizeof reply);
        for (int f = 0; f < fl.n; f++) {
            CHECK_MSG(offered(reply, fl.w[f]), "completion of '%s' does not offer %s", line, fl.w[f]);
            char esc[2 * WORD_LEN], *e = esc;
            for (const char *s = fl.w[f]; *s; s++) {
                if (*s == '-') *e++ = '\\';
                *e++ = *s;
            }
            *e = '\0';
            const char *at = sec ? strstr(sec, esc) : NULL;   /* the first after the heading */
            CHECK_MSG(at && at < sec + sec_len, "docs/gridsurvey.1: section %s does not name %s", name,
                      fl.w[f]);
        }
    }
    free(man);
}

TEST(man_page_renders_and_cli_docs_are_those_of_the_binary)
{
    static char out[65536];
    CHECK_MSG(test_run("groff -man -Tutf8 -ww -z docs/gridsurvey.1", out, sizeof out) == 0 && !out[0],
              "groff: %s", out);
    const char *dir = fx_tmp("cli-docs");
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "sh docs/gen-cli-docs.sh %s %s", test_bin(), dir);
    CHECK_MSG(test_run(cmd, out, sizeof out) == 0, "%s: %s", cmd, out);
    static const char *const files[] = {"gridsurvey.1", "bash-completion/gridsurvey"};
    for (int i = 0; i < 2; i++) {
        char fresh[600], kept[600];
        snprintf(fresh, sizeof fresh, "%s/%s", dir, files[i]);
        snprintf(kept, sizeof kept, "docs/%s", files[i]);
        snprintf(cmd, sizeof cmd, "cmp %s %s", kept, fresh);
        CHECK_MSG(test_run(cmd, out, sizeof out) == 0, "%s differs from the --help texts of %s "
                  "(run make cli-docs): %s", kept, test_bin(), out);
    }
}

TEST(make_install_puts_binary_page_and_completion_under_destdir)
{
    static char out[65536];
    const char *dest = fx_tmp("destdir");
    char cmd[2048];
    /* the binary under test as it is (-o: never rebuilt), outside the calling make */
    snprintf(cmd, sizeof cmd,
             "env -u MAKEFLAGS -u MFLAGS -u MAKELEVEL make -s --no-print-directory -o %s install "
             "BIN=%s DESTDIR=%s PREFIX=/opt/gs", test_bin(), test_bin(), dest);
    CHECK_MSG(test_run(cmd, out, sizeof out) == 0, "%s: %s", cmd, out);
    static const char *const pairs[][2] = {
        {"bin/gridsurvey", NULL},
        {"share/man/man1/gridsurvey.1", "docs/gridsurvey.1"},
        {"share/bash-completion/completions/gridsurvey", "docs/bash-completion/gridsurvey"},
    };
    for (int i = 0; i < 3; i++) {
        snprintf(cmd, sizeof cmd, "cmp %s %s/opt/gs/%s", pairs[i][1] ? pairs[i][1] : test_bin(), dest,
                 pairs[i][0]);
        CHECK_MSG(test_run(cmd, out, sizeof out) == 0, "%s: %s", cmd, out);
    }
    snprintf(cmd, sizeof cmd, "%s/opt/gs/bin/gridsurvey --version", dest);
    CHECK_MSG(test_run(cmd, out, sizeof out) == 0 && !strncmp(out, "gridsurvey ", 11), "%s: %s", cmd, out);
    snprintf(cmd, sizeof cmd,
             "env -u MAKEFLAGS -u MFLAGS -u MAKELEVEL make -s --no-print-directory uninstall "
             "DESTDIR=%s PREFIX=/opt/gs && test -z \"$(find %s -type f)\"", dest, dest);
    CHECK_MSG(test_run(cmd, out, sizeof out) == 0, "%s: %s", cmd, out);
}

/* stderr of `BIN ARGS`, stdout dropped; the exit status must be 0. */
static void run_stderr(const char *args, char *err, size_t size)
{
    char cmd[4096];
    snprintf(cmd, sizeof cmd, "%s %s 2>&1 >/dev/null", test_bin(), args);
    CHECK_MSG(test_run(cmd, err, size) == 0, "%s: %s", cmd, err);
}

/* One meaning of the progress flags: every command that prints progress takes --progress,
 * --no-progress and -q; on a stderr that is not a terminal (the default there: none),
 * --progress adds progress lines and a later -q takes them away again. */
TEST(progress_flags_mean_the_same_in_every_command)
{
    static char help[65536], sub[65536];
    CHECK(fx_run_bin(help, sizeof help, "%s --help%s%s%s", NULL, NULL, NULL) == 0);
    words cmds, fl;
    help_commands(help, &cmds);
    int with_progress = 0;
    for (int c = 0; c < cmds.n; c++) {
        CHECK(fx_run_bin(sub, sizeof sub, "%s help %s%s%s", cmds.w[c], NULL, NULL) == 0);
        help_flags(sub, &fl);
        int has[3] = {0, 0, 0};
        for (int f = 0; f < fl.n; f++) {
            has[0] |= !strcmp(fl.w[f], "--progress");
            has[1] |= !strcmp(fl.w[f], "--no-progress");
            has[2] |= !strcmp(fl.w[f], "-q");
        }
        if (!has[0]) continue;
        with_progress++;
        CHECK_MSG(has[1] && has[2], "%s: --progress without --no-progress and -q", cmds.w[c]);
    }
    CHECK_MSG(with_progress >= 5, "%d commands with --progress", with_progress);

    survey_lab_spec spec = survey_fx_lab_spec();
    char scene[600], args[2048];
    snprintf(scene, sizeof scene, "%s", fx_tmp("lab.json"));
    survey_fx_small_lab(scene, 0.25, &spec);
    static const char *const modes[3] = {"", "--progress", "--progress -q"};
    static char err[3][65536];
    for (int m = 0; m < 3; m++) {
        snprintf(args, sizeof args, "simulate %s -o %s/cap%d %s", scene, test_tmpdir(), m, modes[m]);
        run_stderr(args, err[m], sizeof err[m]);
    }
    char cap0[600];
    snprintf(cap0, sizeof cap0, "%s/cap0", test_tmpdir());
    for (int step = 0; step < 2; step++) {   /* the capture loop's progress, then recognize's */
        const char *what = step == 0 ? "simulate" : "recognize";
        if (step > 0)
            for (int m = 0; m < 3; m++) {
                snprintf(args, sizeof args, "recognize %s %s", cap0, modes[m]);
                run_stderr(args, err[m], sizeof err[m]);
            }
        CHECK_MSG(strlen(err[1]) > strlen(err[0]), "%s --progress printed no progress", what);
        CHECK_MSG(!strcmp(err[2], err[0]), "%s --progress -q: stderr '%s', without the flags '%s'",
                  what, err[2], err[0]);
    }
}
