/* test_runner.c - the runner's own guards (tests/main.c): a test that makes no check fails, a
 * test that hangs is killed with its whole process group and fails, a crash is reported, and a
 * test's own longer limit is honoured. The cases are hidden tests, run here by the test binary
 * itself (/proc/self/exe) with GS_TEST_TIMEOUT_S=1; a normal run never runs them. */
#include "tests/test.h"

#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/types.h>
#include <unistd.h>

/* ------------------------------------------------------------------ hidden cases */

TEST_HIDDEN(runner_case_no_check, 0)
{
}

/* Hangs, and so does a grandchild in its process group, whose pid it prints first. */
TEST_HIDDEN(runner_case_hangs, 0)
{
    pid_t pid = fork();
    if (pid == 0) {
        int null = open("/dev/null", O_WRONLY);   /* so it holds none of the caller's pipes */
        if (null < 0 || dup2(null, 1) < 0 || dup2(null, 2) < 0) _exit(1);
        for (;;) pause();
    }
    printf("    grandchild %ld\n", (long)pid);
    fflush(stdout);
    for (;;) pause();
}

TEST_HIDDEN(runner_case_killed_by_signal, 0)
{
    CHECK(1);
    fflush(stdout);
    raise(SIGTERM);
}

/* Sleeps past GS_TEST_TIMEOUT_S=1 but within its own limit. */
TEST_HIDDEN(runner_case_own_longer_limit, 60)
{
    sleep(2);
    CHECK(1);
}

/* Two tests that print while the other does (run at once with GS_TEST_JOBS=2). */
static void chatty(const char *who)
{
    for (int i = 0; i < 3; i++) {
        printf("    %s line %d\n", who, i);
        fflush(stdout);
        fprintf(stderr, "    %s err %d\n", who, i);
        usleep(100000);
    }
    CHECK(1);
}

TEST_HIDDEN(runner_case_chatty_a, 0)
{
    chatty("a");
}

TEST_HIDDEN(runner_case_chatty_b, 0)
{
    chatty("b");
}

/* ------------------------------------------------------------------ the test */

/* The test binary's own path into self (size bytes); 0 when it cannot be read (a failed check). */
static int self_exe(char *self, size_t size)
{
    ssize_t n = readlink("/proc/self/exe", self, size - 1);
    CHECK(n > 0);
    if (n <= 0) return 0;
    self[n] = '\0';
    return 1;
}

/* 1 once /proc/PID is gone or a zombie (waits up to 5 s for the kernel to finish the kill). */
static int process_gone(long pid)
{
    char path[64];
    snprintf(path, sizeof path, "/proc/%ld/stat", pid);
    for (int i = 0; i < 500; i++) {
        FILE *f = fopen(path, "r");
        if (!f) return 1;
        char state = '?';
        int got = fscanf(f, "%*d (%*[^)]) %c", &state);
        fclose(f);
        if (got == 1 && (state == 'Z' || state == 'X')) return 1;
        usleep(10000);
    }
    return 0;
}

TEST(runner_fails_test_without_checks_and_hanging_test)
{
    char self[4096];
    if (!self_exe(self, sizeof self)) return;
    static const struct {
        const char *name, *reason;
        int status;
    } cases[] = {
        {"_runner_case_no_check", "    made no check\nFAIL _runner_case_no_check (", 1},
        {"_runner_case_hangs", "    timed out after 1 s\nFAIL _runner_case_hangs (", 1},
        {"_runner_case_killed_by_signal",
         "    killed by signal 15\nFAIL _runner_case_killed_by_signal (", 1},
        {"_runner_case_own_longer_limit", "PASS _runner_case_own_longer_limit (", 0},
    };
    static char out[1 << 14];
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        char cmd[8192];
        snprintf(cmd, sizeof cmd, "GS_TEST_TIMEOUT_S=1 '%s' %s", self, cases[i].name);
        int rc = test_run(cmd, out, sizeof out);
        CHECK_MSG(rc == cases[i].status, "%s: exit %d\n%s", cases[i].name, rc, out);
        CHECK_MSG(strstr(out, cases[i].reason), "%s: no '%s' in\n%s", cases[i].name,
                  cases[i].reason, out);
        CHECK_MSG(strstr(out, cases[i].status ? "0 passed, 1 failed\n" : "1 passed, 0 failed\n"),
                  "%s:\n%s", cases[i].name, out);
        /* the hanging test's grandchild died with it */
        const char *g = strstr(out, "    grandchild ");
        if (i == 1) {
            CHECK_MSG(g != NULL, "%s", out);
            if (g) {
                long pid = atol(g + 15);
                int gone = pid > 0 && process_gone(pid);
                CHECK_MSG(gone, "grandchild %ld still runs", pid);
                if (pid > 0 && !gone) kill((pid_t)pid, SIGKILL);
            }
        }
    }
}

/* Tests run at once keep their output whole: each one's lines (stdout and stderr) come
 * together, right before its PASS line; a bad GS_TEST_JOBS is refused. */
TEST(runner_runs_tests_at_once_without_mixing_their_output)
{
    char self[4096];
    if (!self_exe(self, sizeof self)) return;
    static char out[1 << 14];
    char cmd[8192];
    snprintf(cmd, sizeof cmd, "GS_TEST_JOBS=2 '%s' _runner_case_chatty_a _runner_case_chatty_b", self);
    int rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 0 && strstr(out, "2 passed, 0 failed\n"), "exit %d\n%s", rc, out);
    static const char *const whole[] = {
        "    a line 0\n    a err 0\n    a line 1\n    a err 1\n    a line 2\n    a err 2\nPASS _runner_case_chatty_a (",
        "    b line 0\n    b err 0\n    b line 1\n    b err 1\n    b line 2\n    b err 2\nPASS _runner_case_chatty_b (",
    };
    for (int i = 0; i < 2; i++) CHECK_MSG(strstr(out, whole[i]), "not whole: %s in\n%s", whole[i], out);
    snprintf(cmd, sizeof cmd, "GS_TEST_JOBS=0 '%s' _runner_case_chatty_a", self);
    rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 2 && strstr(out, "GS_TEST_JOBS=0: expected a whole number from 1 to 64"), "exit %d\n%s", rc, out);
}
