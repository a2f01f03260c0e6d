/* test.h - a minimal test harness: TEST(name) registers a test; CHECK* record failures and
 * continue; the runner (tests/main.c) prints one line per failure and a final
 * "N passed, N failed" summary, and exits non-zero on any failure.
 * Tests needing the shared data find it with test_shared_path() (GS_SHARED, default ../shared). */
#ifndef GRIDSURVEY_TEST_H
#define GRIDSURVEY_TEST_H

#include <math.h>
#include <stddef.h>

typedef void (*test_fn)(void);
void test_register(const char *name, test_fn fn);
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

#define TEST(name)                                                                         \
    static void name(void);                                                                \
    __attribute__((constructor)) static void register_##name(void)                         \
    {                                                                                      \
        test_register(#name, name);                                                        \
    }                                                                                      \
    static void name(void)

#define CHECK(cond)                                                                        \
    do {                                                                                   \
        if (!(cond)) test_failed(__FILE__, __LINE__, "CHECK(%s)", #cond);                  \
    } while (0)
#define CHECK_MSG(cond, ...)                                                               \
    do {                                                                                   \
        if (!(cond)) test_failed(__FILE__, __LINE__, __VA_ARGS__);                         \
    } while (0)
/* |a - b| <= tol, and both finite */
#define CHECK_NEAR(a, b, tol)                                                              \
    do {                                                                                   \
        double check_a_ = (a), check_b_ = (b), check_t_ = (tol);                           \
        if (!(isfinite(check_a_) && isfinite(check_b_) && fabs(check_a_ - check_b_) <= check_t_)) \
            test_failed(__FILE__, __LINE__, "CHECK_NEAR(%s, %s, %s): %.17g vs %.17g",      \
                        #a, #b, #tol, check_a_, check_b_);                                 \
    } while (0)
#define CHECK_OK(expr)                                                                     \
    do {                                                                                   \
        gs_status check_s_ = (expr);                                                       \
        if (check_s_ != GS_OK)                                                             \
            test_failed(__FILE__, __LINE__, "%s -> %s: %s", #expr, gs_strerror(check_s_),  \
                        gs_detail());                                                      \
    } while (0)

#endif
