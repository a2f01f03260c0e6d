/* main.c - the test runner: runs every registered test (or those whose name contains one of
 * the arguments) in its own process and process group, so a crash or a hang fails only that
 * test, then prints "N passed, N failed". Exit status 1 if any test failed or none ran.
 *
 * A test FAILS when a CHECK fails, when it makes no check at all ("made no check"), when its
 * process dies of a signal ("killed by signal N"), exits before the test function returns, or
 * runs past its time limit ("timed out after N s": the whole process group is SIGKILLed).
 * The limit is GS_TEST_TIMEOUT_S (default 300 s), or a test's own TEST_TIMEOUT if longer.
 * Hidden tests (TEST_HIDDEN, names starting with '_') run only when named exactly.
 * GS_TEST_JOBS tests (default: the online CPUs) run at once; each one's stdout and stderr go to
 * a file of its own, printed with its PASS/FAIL line when it ends (in the order they end); one
 * test at a time (one job or one test selected) writes straight to the runner's output. */
#include "tests/test.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
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

/* A test the runner has started: its process (group), report pipe, output file, clock. */
typedef struct {
    int test;            /* index into tests[] */
    pid_t pid;           /* 0: the slot is free */
    int report_fd, out_fd;
    double limit_s;
    struct timespec t0;
} running;

enum { MAX_JOBS = 64 };
static running slots[MAX_JOBS];

/* SIGINT/SIGTERM/SIGHUP to the runner also end the running tests' groups (they are not in the
 * terminal's foreground group), then the runner dies of the same signal. */
static void on_signal(int sig)
{
    for (int i = 0; i < MAX_JOBS; i++)
        if (slots[i].pid > 0) kill(-slots[i].pid, SIGKILL);
    signal(sig, SIG_DFL);
    raise(sig);
}

/* GS_TEST_JOBS, or the online CPUs: how many tests run at once; exits 2 on a bad value. */
static int jobs_wanted(void)
{
    const char *e = getenv("GS_TEST_JOBS");
    if (!e || !*e) {
        long n = sysconf(_SC_NPROCESSORS_ONLN);
        return n < 1 ? 1 : n > MAX_JOBS ? MAX_JOBS : (int)n;
    }
    char *end;
    long n = strtol(e, &end, 10);
    if (*end || n < 1 || n > MAX_JOBS) {
        fprintf(stderr, "test runner: GS_TEST_JOBS=%s: expected a whole number from 1 to %d\n", e,
                MAX_JOBS);
        exit(2);
    }
    return (int)n;
}

/* Starts test i in slot r: a child in its own process group; when tests run at once (kept),
 * its stdout and stderr into a file of its own, printed when it ends so that they do not
 * interleave; else straight to the runner's (a long test shows its progress). */
static void start(running *r, int i, double limit_s, int kept, const sigset_t *old_mask)
{
    char out_path[600];
    snprintf(out_path, sizeof out_path, "%s/%s.out", tmp_root, tests[i].name);
    int fds[2], out = kept ? open(out_path, O_RDWR | O_CREAT | O_TRUNC | O_CLOEXEC, 0600) : -1;
    if ((kept && out < 0) || pipe(fds) != 0) {
        perror("test runner: output file or pipe");
        exit(2);
    }
    if (kept) unlink(out_path);   /* the runner reads it through out; nothing else needs its name */
    snprintf(tmp_dir, sizeof tmp_dir, "%s/%s", tmp_root, tests[i].name);
    fflush(stdout);
    fflush(stderr);
    clock_gettime(CLOCK_MONOTONIC, &r->t0);
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
        if (kept && (dup2(out, 1) < 0 || dup2(out, 2) < 0)) _exit(3);
        if (mkdir(tmp_dir, 0700) != 0) _exit(3);
        tests[i].fn();
        fflush(stdout);
        report rep = {failures, checks};
        if (write(fds[1], &rep, sizeof rep) != (ssize_t)sizeof rep) _exit(3);
        _exit(failures ? 1 : 0);
    }
    close(fds[1]);
    setpgid(pid, pid);   /* also here: no race with the child's own call */
    r->test = i;
    r->pid = pid;
    r->report_fd = fds[0];
    r->out_fd = out;
    r->limit_s = limit_s;
}

/* The verdict on a test that has ended (status st) or timed out: its reason line into why
 * (empty when the failed checks said why, or it passed); 1 if it passed. */
static int verdict(running *r, int st, int timed_out, char *why, size_t why_size)
{
    /* the report is in the pipe by now, or never will be (grandchildren may hold it open) */
    report rep = {0, 0};
    int have_report = 0;
    if (!timed_out) {
        fcntl(r->report_fd, F_SETFL, O_NONBLOCK);
        have_report = read(r->report_fd, &rep, sizeof rep) == (ssize_t)sizeof rep;
    }
    close(r->report_fd);
    why[0] = '\0';
    if (timed_out) {
        snprintf(why, why_size, "    timed out after %g s\n", r->limit_s);
        return 0;
    }
    if (WIFSIGNALED(st)) {
        snprintf(why, why_size, "    killed by signal %d\n", WTERMSIG(st));
        return 0;
    }
    if (!have_report) {
        snprintf(why, why_size, "    exited with status %d before the end of the test\n", WEXITSTATUS(st));
        return 0;
    }
    if (WEXITSTATUS(st) != 0) return 0;   /* the failed checks said why */
    if (rep.checks == 0) {
        snprintf(why, why_size, "    made no check\n");
        return 0;
    }
    return rep.failures == 0;
}

/* The output of a test that has ended, its reason line and its PASS/FAIL line, to stdout. */
static void print_result(running *r, int ok, const char *why)
{
    char buf[1 << 14];
    ssize_t got;
    fflush(stdout);
    if (r->out_fd >= 0) {
        lseek(r->out_fd, 0, SEEK_SET);
        while ((got = read(r->out_fd, buf, sizeof buf)) > 0) fwrite(buf, 1, (size_t)got, stdout);
        close(r->out_fd);
    }
    fputs(why, stdout);
    printf("%s %s (%.2f s)\n", ok ? "PASS" : "FAIL", tests[r->test].name, seconds_since(&r->t0));
    fflush(stdout);
    r->pid = 0;
}

/* Waits until a running test ends or the first one's limit passes; finishes that test. */
static int wait_one(int njobs, int *passed, int *failed)
{
    sigset_t chld;
    sigemptyset(&chld);
    sigaddset(&chld, SIGCHLD);
    for (;;) {
        double left = INFINITY;
        for (int s = 0; s < njobs; s++) {
            running *r = &slots[s];
            if (!r->pid) continue;
            int st = 0;
            pid_t w = waitpid(r->pid, &st, WNOHANG);
            double l = r->limit_s - seconds_since(&r->t0);
            int timed_out = w != r->pid && l <= 0;
            if (timed_out) {
                kill(-r->pid, SIGKILL);
                waitpid(r->pid, &st, 0);
            }
            if (w == r->pid || timed_out) {
                char why[128];
                int ok = verdict(r, st, timed_out, why, sizeof why);
                print_result(r, ok, why);
                ++*(ok ? passed : failed);
                return s;
            }
            if (l < left) left = l;
        }
        if (!isfinite(left)) return -1;
        struct timespec ts = {(time_t)left, (long)((left - (double)(time_t)left) * 1e9)};
        if (sigtimedwait(&chld, NULL, &ts) < 0 && errno != EAGAIN && errno != EINTR) {
            perror("test runner: sigtimedwait");
            exit(2);
        }
    }
}

int main(int argc, char **argv)
{
    double limit_default_s = default_timeout_s();
    int njobs = jobs_wanted();
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
    int passed = 0, failed = 0, busy = 0, nsel = 0;
    for (int i = 0; i < n_tests; i++) nsel += selected(tests[i].name, argc, argv);
    int kept = njobs > 1 && nsel > 1;   /* tests run at once: their output kept apart */
    for (int i = 0; i < n_tests || busy > 0;) {
        if (i < n_tests && !selected(tests[i].name, argc, argv)) {
            i++;
            continue;
        }
        if (i < n_tests && busy < njobs) {
            int s = 0;
            while (slots[s].pid) s++;
            double limit_s = limit_default_s;
            if (tests[i].timeout_s > limit_s) limit_s = tests[i].timeout_s;
            start(&slots[s], i++, limit_s, kept, &old_mask);
            busy++;
            continue;
        }
        if (wait_one(njobs, &passed, &failed) >= 0) busy--;
    }
    sigprocmask(SIG_SETMASK, &old_mask, NULL);
    char rm[512];
    snprintf(rm, sizeof rm, "rm -rf '%s'", tmp_root);
    if (system(rm) != 0) fprintf(stderr, "test runner: could not remove %s\n", tmp_root);
    printf("%d passed, %d failed\n", passed, failed);
    return (failed || passed == 0) ? 1 : 0;
}
