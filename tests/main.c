/* main.c - the test runner: runs every registered test (or those whose name contains one of
 * the arguments) in its own process, so a crash fails only that test, then prints
 * "N passed, N failed". Exit status 1 if any test failed or none ran. */
#include "tests/test.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#define MAX_TESTS 1024

static struct {
    const char *name;
    test_fn fn;
} tests[MAX_TESTS];
static int n_tests;
static int failures;            /* in the current (child) process */
static char tmp_root[256];
static char tmp_dir[512];

void test_register(const char *name, test_fn fn)
{
    if (n_tests == MAX_TESTS) {
        fprintf(stderr, "test runner: more than %d tests\n", MAX_TESTS);
        exit(2);
    }
    tests[n_tests].name = name;
    tests[n_tests].fn = fn;
    n_tests++;
}

void test_failed(const char *file, int line, const char *fmt, ...)
{
    va_list ap;
    fprintf(stdout, "    %s:%d: ", file, line);
    va_start(ap, fmt);
    vfprintf(stdout, fmt, ap);
    va_end(ap);
    fputc('\n', stdout);
    fflush(stdout);
    failures++;
}

const char *test_shared_path(const char *rel)
{
    static char buf[1024];
    const char *root = getenv("GS_SHARED");
    snprintf(buf, sizeof buf, "%s/%s", root && *root ? root : "../shared", rel);
    return buf;
}

const char *test_tmpdir(void)
{
    return tmp_dir;
}

const char *test_bin(void)
{
    const char *bin = getenv("GS_BIN");
    return bin && *bin ? bin : "build/gridsurvey";
}

int test_run(const char *cmd, char *out, size_t out_size)
{
    char full[4096];
    snprintf(full, sizeof full, "(%s) 2>&1", cmd);
    FILE *p = popen(full, "r");
    if (!p) return -1;
    size_t used = 0;
    char chunk[4096];
    size_t got;
    while ((got = fread(chunk, 1, sizeof chunk, p)) > 0) {
        if (out && used + 1 < out_size) {
            size_t take = got < out_size - 1 - used ? got : out_size - 1 - used;
            memcpy(out + used, chunk, take);
            used += take;
        }
    }
    if (out && out_size) out[used] = '\0';
    int st = pclose(p);
    return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

static int selected(const char *name, int argc, char **argv)
{
    if (argc < 2) return 1;
    for (int i = 1; i < argc; i++)
        if (strstr(name, argv[i])) return 1;
    return 0;
}

int main(int argc, char **argv)
{
    snprintf(tmp_root, sizeof tmp_root, "/tmp/gridsurvey-tests.XXXXXX");
    if (!mkdtemp(tmp_root)) {
        perror("test runner: mkdtemp");
        return 2;
    }
    int passed = 0, failed = 0;
    for (int i = 0; i < n_tests; i++) {
        if (!selected(tests[i].name, argc, argv)) continue;
        snprintf(tmp_dir, sizeof tmp_dir, "%s/%s", tmp_root, tests[i].name);
        struct timespec t0, t1;
        clock_gettime(CLOCK_MONOTONIC, &t0);
        fflush(stdout);
        pid_t pid = fork();
        if (pid == 0) {
            if (mkdir(tmp_dir, 0700) != 0) _exit(3);
            tests[i].fn();
            fflush(stdout);
            _exit(failures ? 1 : 0);
        }
        int st = 0;
        waitpid(pid, &st, 0);
        clock_gettime(CLOCK_MONOTONIC, &t1);
        double s = (double)(t1.tv_sec - t0.tv_sec) + 1e-9 * (double)(t1.tv_nsec - t0.tv_nsec);
        int ok = WIFEXITED(st) && WEXITSTATUS(st) == 0;
        if (!ok && WIFSIGNALED(st)) printf("    killed by signal %d\n", WTERMSIG(st));
        printf("%s %s (%.2f s)\n", ok ? "PASS" : "FAIL", tests[i].name, s);
        if (ok) passed++;
        else failed++;
    }
    char rm[512];
    snprintf(rm, sizeof rm, "rm -rf '%s'", tmp_root);
    if (system(rm) != 0) fprintf(stderr, "test runner: could not remove %s\n", tmp_root);
    printf("%d passed, %d failed\n", passed, failed);
    return (failed || passed == 0) ? 1 : 0;
}
