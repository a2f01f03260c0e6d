/* test_cli_docs.c - the man page (docs/gridsurvey.1) and the bash completion
 * (docs/bash-completion/gridsurvey) against the binary under test: the commands are those that
 * `gridsurvey --help` lists and each command's flags those that `gridsurvey help CMD` names,
 * read here from the binary's own output; the page must have a section for every command with
 * every flag in it (as roff writes a minus, \-), and bash, sourcing the completion, must offer
 * every command and every flag of each. Then: groff renders the page without a warning, both
 * files are what docs/gen-cli-docs.sh makes of this binary (`make cli-docs` after a change to a
 * --help text), and `make install` puts the binary, its camera plugin, the page and the
 * completion under DESTDIR/PREFIX. Then the progress flags: the same three in every command that has them, with
 * the same effect. Last, every command's and subcommand's --help has an example of its own that
 * uses only flags its command names, and the flags that once meant different things in
 * different commands (-o, --out, --json, --min-confidence, --height-m) have one meaning each. */
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
    /* the binary under test and its camera plugin beside it as they are (-o: never rebuilt),
     * outside the calling make */
    char plugin[1100];
    const char *slash = strrchr(test_bin(), '/');
    snprintf(plugin, sizeof plugin, "%.*sgridsurvey-videoio.so", slash ? (int)(slash - test_bin() + 1) : 0,
             test_bin());
    snprintf(cmd, sizeof cmd,
             "env -u MAKEFLAGS -u MFLAGS -u MAKELEVEL make -s --no-print-directory -o %s -o %s install "
             "BIN=%s DESTDIR=%s PREFIX=/opt/gs", test_bin(), plugin, test_bin(), dest);
    CHECK_MSG(test_run(cmd, out, sizeof out) == 0, "%s: %s", cmd, out);
    const char *const pairs[][2] = {
        {"bin/gridsurvey", NULL},
        {"lib/gridsurvey/gridsurvey-videoio.so", plugin},
        {"share/man/man1/gridsurvey.1", "docs/gridsurvey.1"},
        {"share/bash-completion/completions/gridsurvey", "docs/bash-completion/gridsurvey"},
    };
    for (int i = 0; i < 4; i++) {
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
        snprintf(args, sizeof args, "simulate %s --out-dir %s/cap%d %s", scene, test_tmpdir(), m, modes[m]);
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

/* ------------------------------------------------------------------ examples and flag meanings */

#define MAX_EXAMPLES 16
#define EXAMPLE_LEN 512

typedef struct {
    char line[MAX_EXAMPLES][EXAMPLE_LEN];   /* "gridsurvey ...", continuations joined, no comment */
    int n;
} examples;

/* stdout of `gridsurvey CMD [SUB] --help`, which must exit 0. */
static void help_of(const char *cmd, const char *sub, char *out, size_t size)
{
    int rc = fx_run(out, size, "%s %s %s --help 2>/dev/null", test_bin(), cmd, sub ? sub : "");
    CHECK_MSG(rc == 0, "gridsurvey %s %s --help: exit status %d", cmd, sub ? sub : "", rc);
}

/* The --help texts a test has read (each command's and subcommand's once: each run of the
 * binary costs a fraction of a second). */
#define MAX_HELPS 64
static struct {
    char key[2 * WORD_LEN];
    char *text;
} helps[MAX_HELPS];
static int n_helps;

static const char *cached_help(const char *cmd, const char *sub)
{
    static char buf[65536];
    char key[2 * WORD_LEN];
    snprintf(key, sizeof key, "%s %s", cmd, sub ? sub : "");
    for (int i = 0; i < n_helps; i++)
        if (!strcmp(helps[i].key, key)) return helps[i].text;
    help_of(cmd, sub, buf, sizeof buf);
    if (n_helps == MAX_HELPS) return buf;
    snprintf(helps[n_helps].key, sizeof helps[n_helps].key, "%s", key);
    helps[n_helps].text = strdup(buf);
    return helps[n_helps].text ? helps[n_helps++].text : buf;
}

static void cached_helps_free(void)
{
    for (int i = 0; i < n_helps; i++) free(helps[i].text);
    n_helps = 0;
}

/* The text before a help's examples (its usage and options): the examples start at a line
 * beginning with "Example". Returns its length. */
static size_t before_examples(const char *help)
{
    for (const char *p = help; *p;) {
        if (!strncmp(p, "Example", 7)) return (size_t)(p - help);
        const char *nl = strchr(p, '\n');
        if (!nl) break;
        p = nl + 1;
    }
    return strlen(help);
}

/* The command lines of a help's examples: after the "Example..." heading, each line that
 * starts with "  gridsurvey ", with the lines it continues with a trailing backslash, up to a
 * blank line; a "# ..." comment is cut off. */
static void help_examples(const char *help, examples *ex)
{
    ex->n = 0;
    const char *p = help + before_examples(help);
    if (!*p) return;
    p = strchr(p, '\n');
    while (p && p[1] && p[1] != '\n') {
        p++;
        const char *nl = strchr(p, '\n');
        const char *s = p;
        while (*s == ' ') s++;
        if (!strncmp(s, "gridsurvey ", 11) && ex->n < MAX_EXAMPLES) {
            char *d = ex->line[ex->n++];
            size_t used = 0;
            for (;;) {
                size_t l = nl ? (size_t)(nl - s) : strlen(s);
                int more = l > 0 && s[l - 1] == '\\';
                if (more) l--;
                if (used + l >= EXAMPLE_LEN) l = EXAMPLE_LEN - 1 - used;
                memcpy(d + used, s, l);
                used += l;
                d[used] = '\0';
                if (!more || !nl) break;
                p = nl + 1;
                nl = strchr(p, '\n');
                for (s = p; *s == ' '; s++) {}
            }
            char *hash = strstr(d, " #");
            if (hash) *hash = '\0';
            for (size_t e = strlen(d); e > 0 && d[e - 1] == ' '; e--) d[e - 1] = '\0';
        }
        p = nl;
    }
}

/* A command's subcommands, found as docs/gen-cli-docs.sh finds them: with SUBCOMMAND in its
 * usage line, the first word of each two-space-indented line before the examples; and NAME in
 * every line "[usage:] gridsurvey CMD NAME ..." (bench's usage, the examples). */
static void help_subcommands(const char *cmd, const char *help, words *ws)
{
    ws->n = 0;
    size_t head = before_examples(help);
    char first[256];
    snprintf(first, sizeof first, "%.*s", (int)strcspn(help, "\n"), help);
    int listed = strstr(first, "SUBCOMMAND") != NULL;
    char prefix[64];
    snprintf(prefix, sizeof prefix, "gridsurvey %s ", cmd);
    for (const char *p = help; *p;) {
        const char *nl = strchr(p, '\n');
        if (listed && (size_t)(p - help) < head && !strncmp(p, "  ", 2) && islower((unsigned char)p[2]) &&
            strcspn(p + 2, " \n") < strcspn(p + 2, "\n"))
            words_add(ws, p + 2, strcspn(p + 2, " \n"));
        const char *s = p;
        if (!strncmp(s, "usage:", 6)) s += 6;
        while (*s == ' ') s++;
        if (!strncmp(s, prefix, strlen(prefix))) {
            const char *w = s + strlen(prefix);
            size_t len = 0;
            while (islower((unsigned char)w[len]) || (len && w[len] == '-')) len++;
            if (len && (w[len] == ' ' || w[len] == '\n' || !w[len])) words_add(ws, w, len);
        }
        if (!nl) break;
        p = nl + 1;
    }
}

static int has_word(const words *ws, const char *w)
{
    for (int i = 0; i < ws->n; i++)
        if (!strcmp(ws->w[i], w)) return 1;
    return 0;
}

/* An example line's command and subcommand ("gridsurvey CMD [SUB] ..."), and whether it has
 * one the help of CMD lists. */
static void example_command(const char *line, char *cmd, size_t cmd_size, char *sub, size_t sub_size)
{
    const char *c = line + 11;   /* after "gridsurvey " */
    size_t len = strcspn(c, " ");
    snprintf(cmd, cmd_size, "%.*s", (int)len, c);
    const char *s = c + len;
    while (*s == ' ') s++;
    len = strcspn(s, " ");
    snprintf(sub, sub_size, "%.*s", (int)len, s);
}

/* Every command and subcommand has an "Example" section in its --help with a command line of
 * its own, and every flag an example uses is one the help of that example's command names
 * (outside the examples): an example still written with a renamed flag fails here. */
TEST(every_help_has_an_example_of_its_command_with_its_own_flags)
{
    static char top[65536], other[65536];
    CHECK(fx_run_bin(top, sizeof top, "%s --help%s%s%s", NULL, NULL, NULL) == 0);
    words cmds, subs, fl, other_subs, named;
    help_commands(top, &cmds);
    CHECK_MSG(cmds.n >= 16, "%d commands in gridsurvey --help", cmds.n);
    int checked_subs = 0, checked_examples = 0;
    for (int c = 0; c < cmds.n; c++) {
        const char *name = cmds.w[c];
        help_subcommands(name, cached_help(name, NULL), &subs);
        for (int s = -1; s < subs.n; s++) {
            const char *sub = s < 0 ? NULL : subs.w[s];
            checked_subs += sub != NULL;
            examples ex;
            help_examples(cached_help(name, sub), &ex);
            char want[128];
            snprintf(want, sizeof want, "gridsurvey %s%s%s", name, sub ? " " : "", sub ? sub : "");
            size_t wl = strlen(want);
            int own = 0;
            for (int e = 0; e < ex.n; e++)
                own |= !strncmp(ex.line[e], want, wl) && (ex.line[e][wl] == ' ' || !ex.line[e][wl]);
            CHECK_MSG(own, "%s --help: no example line '%s ...' in an Example section", want, want);
            if (sub) continue;
            /* the flags of each example line against its command's help */
            for (int e = 0; e < ex.n; e++) {
                char ecmd[64], esub[64];
                example_command(ex.line[e], ecmd, sizeof ecmd, esub, sizeof esub);
                CHECK_MSG(has_word(&cmds, ecmd), "%s --help: example '%s': no command %s", name,
                          ex.line[e], ecmd);
                if (!has_word(&cmds, ecmd)) continue;
                help_subcommands(ecmd, cached_help(ecmd, NULL), &other_subs);
                int with_sub = has_word(&other_subs, esub);
                snprintf(other, sizeof other, "%s", cached_help(ecmd, with_sub ? esub : NULL));
                other[before_examples(other)] = '\0';
                help_flags(other, &named);
                help_flags(ex.line[e], &fl);
                for (int f = 0; f < fl.n; f++)
                    CHECK_MSG(has_word(&named, fl.w[f]), "%s --help: example '%s' uses %s, which "
                              "gridsurvey %s %s --help does not name", name, ex.line[e], fl.w[f], ecmd,
                              with_sub ? esub : "");
                checked_examples++;
            }
        }
    }
    CHECK_MSG(checked_subs >= 17, "%d subcommands checked (db 4, delight 7, bench 6)", checked_subs);
    CHECK_MSG(checked_examples >= 40, "%d example lines checked", checked_examples);
    cached_helps_free();
}

/* Whether WORD is in TEXT (up to LEN bytes) as a whole word (not inside a longer name). */
static int has_whole_word(const char *text, size_t len, const char *word)
{
    size_t wl = strlen(word);
    for (const char *p = text; p + wl <= text + len; p++)
        if (!strncmp(p, word, wl) && (p == text || !(isalnum((unsigned char)p[-1]) || p[-1] == '-')) &&
            !(isalnum((unsigned char)p[wl]) || p[wl] == '-'))
            return 1;
    return 0;
}

/* The summary `gridsurvey --help` gives a command with subcommands names every subcommand its
 * own help lists: bench's named only recognize and db of its seven. */
TEST(top_help_summaries_name_every_subcommand)
{
    static char top[65536];
    CHECK(fx_run_bin(top, sizeof top, "%s --help%s%s%s", NULL, NULL, NULL) == 0);
    words cmds, subs;
    help_commands(top, &cmds);
    int with_subs = 0;
    for (int c = 0; c < cmds.n; c++) {
        help_subcommands(cmds.w[c], cached_help(cmds.w[c], NULL), &subs);
        if (!subs.n) continue;
        with_subs++;
        char head[WORD_LEN + 4];
        snprintf(head, sizeof head, "\n  %s ", cmds.w[c]);
        const char *line = strstr(top, head);
        CHECK_MSG(line != NULL, "gridsurvey --help: no line for %s", cmds.w[c]);
        if (!line) continue;
        line += strlen(head);
        size_t len = strcspn(line, "\n");
        for (int s = 0; s < subs.n; s++)
            CHECK_MSG(has_whole_word(line, len, subs.w[s]), "gridsurvey --help: the %s line '%.*s' "
                      "does not name its subcommand %s", cmds.w[c], (int)len, line, subs.w[s]);
    }
    CHECK_MSG(with_subs >= 3, "%d commands with subcommands (db, delight, bench)", with_subs);
    cached_helps_free();
}

/* capture's --help lists its common options in a synopsis; each has a line of its own that
 * says what it does (--max-rounds 0 means as many rounds as the masks allow, not none). */
TEST(capture_help_describes_its_common_options)
{
    const char *help = cached_help("capture", NULL);
    const char *common = strstr(help, "common:");
    CHECK(common != NULL);
    if (!common) return;
    words fl;
    char syn[512];   /* the synopsis: up to the blank line */
    const char *end = strstr(common, "\n\n");
    snprintf(syn, sizeof syn, "%.*s", end ? (int)(end - common) : 0, common);
    help_flags(syn, &fl);
    CHECK_MSG(fl.n >= 8, "%d flags in '%s'", fl.n, syn);
    for (int f = 0; f < fl.n; f++) {
        if (!strcmp(fl.w[f], "--progress") || !strcmp(fl.w[f], "--no-progress") || !strcmp(fl.w[f], "-q"))
            continue;   /* one meaning in every command (progress_flags_mean_the_same_in_every_command) */
        /* an option line: "  --a, --b  text", the flag in its first column */
        int described = 0;
        for (const char *p = strstr(help, "\n  -"); p && !described; p = strstr(p + 1, "\n  -")) {
            const char *col = p + 3, *gap = strstr(col, "  ");
            described = has_whole_word(col, gap ? (size_t)(gap - col) : 0, fl.w[f]);
        }
        CHECK_MSG(described, "gridsurvey capture --help: %s has no line describing it", fl.w[f]);
    }
    cached_helps_free();
}

/* The words that follow FLAG (e.g. "-o") in a help's usage and options, each checked for containing "DIR" as
 * want_dir says: -o is always a file, --out-dir always a directory. Returns the count. */
static int placeholders_after(const char *text, const char *flag, int want_dir, const char *where)
{
    int n = 0;
    size_t fl = strlen(flag);
    for (const char *p = strstr(text, flag); p; p = strstr(p + 1, flag)) {
        if ((p > text && (isalnum((unsigned char)p[-1]) || p[-1] == '-')) || (p[fl] != ' ' && p[fl] != ','))
            continue;
        const char *w = p + fl + (p[fl] == ',');
        if (*w == ',') continue;
        while (*w == ' ') w++;
        size_t len = strcspn(w, " \n]|)");
        char word[64];
        snprintf(word, sizeof word, "%.*s", (int)(len < 63 ? len : 63), w);
        if (p[fl] == ',' || !strncmp(word, "--", 2)) continue;   /* "-o, --output" style */
        n++;
        CHECK_MSG(!!strstr(word, "DIR") == want_dir, "%s: '%s %s': %s names %s", where, flag, word,
                  flag, want_dir ? "a directory" : "a file");
    }
    return n;
}

/* One meaning per flag across commands (docs/reliability.md, "Command-line habits"), read from
 * every command's and subcommand's --help: -o FILE is always a file and the directory a
 * command writes is always --out-dir DIR; JSON output is --format json (no --json); the
 * lights' height is --light-height-m (no --height-m); a phase-confidence filter is
 * --min-phase-confidence, and --min-confidence is only export's overall-confidence filter;
 * no --output or --out. Then the directory commands refuse -o with a one-line error that
 * names --out-dir, writing nothing. */
TEST(flags_mean_the_same_in_every_command)
{
    static char top[65536], out[65536];
    CHECK(fx_run_bin(top, sizeof top, "%s --help%s%s%s", NULL, NULL, NULL) == 0);
    words cmds, subs, fl;
    help_commands(top, &cmds);
    static const char *const gone[] = {"--json", "--output", "--out", "--height-m"};
    int with_out_dir = 0, with_o = 0;
    for (int c = 0; c < cmds.n; c++) {
        const char *name = cmds.w[c];
        help_subcommands(name, cached_help(name, NULL), &subs);
        for (int s = -1; s < subs.n; s++) {
            const char *sub = s < 0 ? NULL : subs.w[s];
            const char *text = cached_help(name, sub);
            char where[128];
            snprintf(where, sizeof where, "gridsurvey %s%s%s --help", name, sub ? " " : "", sub ? sub : "");
            help_flags(text, &fl);
            for (size_t g = 0; g < sizeof gone / sizeof *gone; g++)
                CHECK_MSG(!has_word(&fl, gone[g]), "%s names %s", where, gone[g]);
            CHECK_MSG(!has_word(&fl, "--min-confidence") || !strcmp(name, "export"),
                      "%s: --min-confidence outside export", where);
            static char head[65536];   /* the usage and the options: placeholders, not paths */
            snprintf(head, sizeof head, "%.*s", (int)before_examples(text), text);
            with_o += placeholders_after(head, "-o", 0, where) > 0;
            with_out_dir += placeholders_after(head, "--out-dir", 1, where) > 0;
        }
    }
    CHECK_MSG(with_o >= 5 && with_out_dir >= 7, "-o FILE in %d help texts, --out-dir DIR in %d", with_o,
              with_out_dir);
    static const char *const has[][2] = {
        {"stats", "--min-phase-confidence"}, {"compare", "--min-phase-confidence"},
        {"export", "--min-confidence"},      {"recognize", "--ambiguous-below"},
        {"run", "--light-height-m"},         {"locate", "--light-height-m"},
        {"stats", "--format"},               {"evaluate", "--format"},
        {"recognize", "--format"},           {"run", "--out-dir"},
    };
    for (size_t i = 0; i < sizeof has / sizeof *has; i++) {
        help_flags(cached_help(has[i][0], NULL), &fl);
        CHECK_MSG(has_word(&fl, has[i][1]), "gridsurvey %s --help does not name %s", has[i][0], has[i][1]);
    }
    /* -o on a command that writes a directory: one line naming --out-dir, exit 2, nothing made */
    static const char *const dir_cmds[][2] = {
        {"simulate", "capture/scenes/lab.json"}, {"capture", "--backend replay --from ."},
        {"unmix", ". --sources auto"},            {"relight", ". --set 0=gain:1"},
        {"separate", "."},                        {"run", ". --db x.sqlite"},
    };
    const char *made = fx_tmp("by-o");
    for (size_t i = 0; i < sizeof dir_cmds / sizeof *dir_cmds; i++) {
        int rc = fx_run(out, sizeof out, "%s %s %s -o %s", test_bin(), dir_cmds[i][0], dir_cmds[i][1], made);
        CHECK_MSG(rc == 2 && fx_count_lines(out) == 1 && strstr(out, "--out-dir"), "%s -o: exit %d: %s",
                  dir_cmds[i][0], rc, out);
        CHECK_MSG(!fx_exists(made), "%s -o: %s was made", dir_cmds[i][0], made);
    }
    cached_helps_free();
}
