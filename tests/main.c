/* main.c - the test runner: runs every registered test (or those whose name contains one of
 * the arguments) in its own process and process group, so a crash or a hang fails only that
 * test, then prints "N passed, N failed". Exit status 1 if any test failed or none ran.
 *
 * A test FAILS when a CHECK fails, when it makes no check at all ("made no check"), when its
 * process dies of a signal ("killed by signal N"), exits before the test function returns, or
 * runs past its time limit ("timed out after N s": the whole process group is SIGKILLed).
 * The limit is GS_TEST_TIMEOUT_S (default 300 s), or a test's own TEST_TIMEOUT if longer.
 * Hidden tests (TEST_HIDDEN, names starting with '_') run only when named exactly. */
#include "tests/test.h"

#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#define MAX_TESTS 1024
#define DEFAULT_TIMEOUT_S 300.0

static struct {
    const char *name;
    test_fn fn;
    double timeout_s;   /* 0: the default */
} tests[MAX_TESTS];
static int n_tests;
static int failures;            /* in the current (child) process */
static unsigned long checks;    /* likewise */
static char tmp_root[256];
static char tmp_dir[512];
static volatile sig_atomic_t running_pgid;   /* the test's process group, 0 between tests */

void test_register(const char *name, test_fn fn, double timeout_s)
{
    if (n_tests == MAX_TESTS) {
        fprintf(stderr, "test runner: more than %d tests\n", MAX_TESTS);
        exit(2);
    }
    tests[n_tests].name = name;
    tests[n_tests].fn = fn;
    tests[n_tests].timeout_s = timeout_s;
    n_tests++;
}

void test_count_check(void)
{
    checks++;
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

/* Hidden tests only when named exactly; the others when their name contains an argument. */
static int selected(const char *name, int argc, char **argv)
{
    int hidden = name[0] == '_';
    if (argc < 2) return !hidden;
    for (int i = 1; i < argc; i++)
        if (hidden ? !strcmp(name, argv[i]) : strstr(name, argv[i]) != NULL) return 1;
    return 0;
}

/* GS_TEST_TIMEOUT_S, or the default; exits 2 on a value that is not a positive number. */
static double default_timeout_s(void)
{
    const char *e = getenv("GS_TEST_TIMEOUT_S");
    if (!e || !*e) return DEFAULT_TIMEOUT_S;
    char *end;
    double s = strtod(e, &end);
    if (*end || !(s > 0)) {
        fprintf(stderr, "test runner: GS_TEST_TIMEOUT_S=%s: expected a positive number of "
                        "seconds\n", e);
        exit(2);
    }
    return s;
}

/* SIGINT/SIGTERM/SIGHUP to the runner also end the running test's group (it is not in the
 * terminal's foreground group), then the runner dies of the same signal. */
static void on_signal(int sig)
{
    if (running_pgid > 0) kill(-(pid_t)running_pgid, SIGKILL);
    signal(sig, SIG_DFL);
    raise(sig);
}

static double seconds_since(const struct timespec *t0)
{
    struct timespec t1;
    clock_gettime(CLOCK_MONOTONIC, &t1);
    return (double)(t1.tv_sec - t0->tv_sec) + 1e-9 * (double)(t1.tv_nsec - t0->tv_nsec);
}

/* The child's report, written to a pipe when the test function has returned. */
typedef struct {
    int failures;
    unsigned long checks;
} report;

/* Runs test i in a child; prints its reason lines and returns 1 if it passed. */
static int run_one(int i, double limit_s, const sigset_t *old_mask, struct timespec *t0)
{
    int fds[2];
    if (pipe(fds) != 0) {
        perror("test runner: pipe");
        exit(2);
    }
    clock_gettime(CLOCK_MONOTONIC, t0);
    fflush(stdout);
    pid_t pid = fork();
    if (pid < 0) {
        perror("test runner: fork");
        exit(2);
    }
    if (pid == 0) {
        setpgid(0, 0);
        signal(SIGINT, SIG_DFL);
        signal(SIGTERM, SIG_DFL);
        signal(SIGHUP, SIG_DFL);
        sigprocmask(SIG_SETMASK, old_mask, NULL);
        close(fds[0]);
        fcntl(fds[1], F_SETFD, FD_CLOEXEC);
        if (mkdir(tmp_dir, 0700) != 0) _exit(3);
        tests[i].fn();
        fflush(stdout);
        report r = {failures, checks};
        if (write(fds[1], &r, sizeof r) != (ssize_t)sizeof r) _exit(3);
        _exit(failures ? 1 : 0);
    }
    close(fds[1]);
    setpgid(pid, pid);   /* also here: no race with the child's own call */
    running_pgid = pid;

    int st = 0, timed_out = 0;
    sigset_t chld;
    sigemptyset(&chld);
    sigaddset(&chld, SIGCHLD);
    for (;;) {
        pid_t w = waitpid(pid, &st, WNOHANG);
        if (w == pid) break;
        double left = limit_s - seconds_since(t0);
        if (left <= 0) {
            kill(-pid, SIGKILL);
            waitpid(pid, &st, 0);
            timed_out = 1;
            break;
        }
        struct timespec ts = {(time_t)left, (long)((left - (double)(time_t)left) * 1e9)};
        if (sigtimedwait(&chld, NULL, &ts) < 0 && errno != EAGAIN && errno != EINTR) {
            perror("test runner: sigtimedwait");
            exit(2);
        }
    }
    running_pgid = 0;

    /* the report is in the pipe by now, or never will be (grandchildren may hold it open) */
    report r = {0, 0};
    int have_report = 0;
    if (!timed_out) {
        fcntl(fds[0], F_SETFL, O_NONBLOCK);
        have_report = read(fds[0], &r, sizeof r) == (ssize_t)sizeof r;
    }
    close(fds[0]);

    if (timed_out) {
        printf("    timed out after %g s\n", limit_s);
        return 0;
    }
    if (WIFSIGNALED(st)) {
        printf("    killed by signal %d\n", WTERMSIG(st));
        return 0;
    }
    if (!have_report) {
        printf("    exited with status %d before the end of the test\n", WEXITSTATUS(st));
        return 0;
    }
    if (WEXITSTATUS(st) != 0) return 0;   /* the failed checks said why */
    if (r.checks == 0) {
        printf("    made no check\n");
        return 0;
    }
    return r.failures == 0;
}

int main(int argc, char **argv)
{
    double limit_default_s = default_timeout_s();
    snprintf(tmp_root, sizeof tmp_root, "/tmp/gridsurvey-tests.XXXXXX");
    if (!mkdtemp(tmp_root)) {
        perror("test runner: mkdtemp");
        return 2;
    }
    /* SIGCHLD stays blocked in the runner so that sigtimedwait can wait for it */
    sigset_t chld, old_mask;
    sigemptyset(&chld);
    sigaddset(&chld, SIGCHLD);
    sigprocmask(SIG_BLOCK, &chld, &old_mask);
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    signal(SIGHUP, on_signal);
    int passed = 0, failed = 0;
    for (int i = 0; i < n_tests; i++) {
        if (!selected(tests[i].name, argc, argv)) continue;
        snprintf(tmp_dir, sizeof tmp_dir, "%s/%s", tmp_root, tests[i].name);
        double limit_s = limit_default_s;
        if (tests[i].timeout_s > limit_s) limit_s = tests[i].timeout_s;
        struct timespec t0;
        int ok = run_one(i, limit_s, &old_mask, &t0);
        printf("%s %s (%.2f s)\n", ok ? "PASS" : "FAIL", tests[i].name, seconds_since(&t0));
        if (ok) passed++;
        else failed++;
    }
    sigprocmask(SIG_SETMASK, &old_mask, NULL);
    char rm[512];
    snprintf(rm, sizeof rm, "rm -rf '%s'", tmp_root);
    if (system(rm) != 0) fprintf(stderr, "test runner: could not remove %s\n", tmp_root);
    printf("%d passed, %d failed\n", passed, failed);
    return (failed || passed == 0) ? 1 : 0;
}
