/* test.h - a minimal test harness: TEST(name) registers a test; CHECK* count every check made
 * and record failures and continue; the runner (tests/main.c) prints one line per failure and
 * a final "N passed, N failed" summary, and exits non-zero on any failure. A test that makes no
 * check, dies of a signal or outlives its time limit fails too (tests/main.c says how).
 * Tests needing the shared data find it with test_shared_path() (GS_SHARED, default ../shared).
 * Helpers shared by several test files: tests/fixtures.h. */
#ifndef GRIDSURVEY_TEST_H
#define GRIDSURVEY_TEST_H

#include <math.h>
#include <stddef.h>

typedef void (*test_fn)(void);
/* timeout_s: the test's own time limit, used when longer than the default (0: the default). */
void test_register(const char *name, test_fn fn, double timeout_s);
/* Called by every CHECK* once per evaluation. */
void test_count_check(void);
void test_failed(const char *file, int line, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
/* "SHARED/rel" in a static buffer that the next call overwrites. */
const char *test_shared_path(const char *rel);
/* A fresh empty temporary directory for this test (removed by the runner at exit). */
const char *test_tmpdir(void);
/* Path of the gridsurvey binary (GS_BIN). */
const char *test_bin(void);
/* Run a shell command; returns its exit status (or -1), its stdout+stderr in out (may be NULL). */
int test_run(const char *cmd, char *out, size_t out_size);

#define TEST_REGISTERED_(name, label, timeout_s)                                           \
    static void name(void);                                                                \
    __attribute__((constructor)) static void register_##name(void)                         \
    {                                                                                      \
        test_register(label, name, timeout_s);                                             \
    }                                                                                      \
    static void name(void)
#define TEST(name) TEST_REGISTERED_(name, #name, 0)
/* A test that needs longer than the default limit (GS_TEST_TIMEOUT_S, 300 s). */
#define TEST_TIMEOUT(name, timeout_s) TEST_REGISTERED_(name, #name, timeout_s)
/* Registered as "_name": runs only when named exactly on the command line (the runner's
 * self-tests); timeout_s as for TEST_TIMEOUT, 0: the default. */
#define TEST_HIDDEN(name, timeout_s) TEST_REGISTERED_(name, "_" #name, timeout_s)

#define CHECK(cond)                                                                        \
    do {                                                                                   \
        test_count_check();                                                                \
        if (!(cond)) test_failed(__FILE__, __LINE__, "CHECK(%s)", #cond);                  \
    } while (0)
#define CHECK_MSG(cond, ...)                                                               \
    do {                                                                                   \
        test_count_check();                                                                \
        if (!(cond)) test_failed(__FILE__, __LINE__, __VA_ARGS__);                         \
    } while (0)
/* |a - b| <= tol, and both finite */
#define CHECK_NEAR(a, b, tol)                                                              \
    do {                                                                                   \
        test_count_check();                                                                \
        double check_a_ = (a), check_b_ = (b), check_t_ = (tol);                           \
        if (!(isfinite(check_a_) && isfinite(check_b_) && fabs(check_a_ - check_b_) <= check_t_)) \
            test_failed(__FILE__, __LINE__, "CHECK_NEAR(%s, %s, %s): %.17g vs %.17g",      \
                        #a, #b, #tol, check_a_, check_b_);                                 \
    } while (0)
#define CHECK_OK(expr)                                                                     \
    do {                                                                                   \
        test_count_check();                                                                \
        gs_status check_s_ = (expr);                                                       \
        if (check_s_ != GS_OK)                                                             \
            test_failed(__FILE__, __LINE__, "%s -> %s: %s", #expr, gs_strerror(check_s_),  \
                        gs_detail());                                                      \
    } while (0)

#endif
