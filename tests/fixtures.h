/* fixtures.h - helpers shared by the test files (tests/fixtures.c), prefix fx_: temporary paths,
 * whole-file reads and writes, string counts, printf-style commands (random numbers: the
 * format kit's gs_splitmix64, gs_splitmix_uniform, gs_splitmix_normal). A failure to write is a test
 * failure (a CHECK); the other helpers report through their results. */
#ifndef GRIDSURVEY_TESTS_FIXTURES_H
#define GRIDSURVEY_TESTS_FIXTURES_H

#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

/* ------------------------------------------------------------------ paths and files */

/* "dir/name" and "TMPDIR/name" (test_tmpdir()) in a ring of 64 static buffers shared by both:
 * a result stays valid for the next 63 calls (copy a path that must live longer). */
const char *fx_path(const char *dir, const char *name);
const char *fx_tmp(const char *name);
/* 1 if path exists (stat succeeds). */
int fx_exists(const char *path);
/* An exclusive lock on the file `path` (created), close-on-exec so that no child keeps it: the
 * descriptor to close() to release it, or -1 (a failed check). For what the tests of one
 * runner, running at once, make once and share. */
int fx_lock(const char *path);
/* The grid of a real mains recording under shared/ (data_path, e.g. "data/mains/whu_001_ref.wav")
 * as the scene's trace model gives it at grid_hz: a cap_ac (cap_ac_free), NULL after a failed
 * check. */
struct cap_ac;
struct cap_ac *fx_mains_ac(const char *data_path, int grid_hz);
/* Writes n bytes (or the text without its NUL) to path, replacing it. */
void fx_write_file(const char *path, const void *data, size_t n);
void fx_write_text(const char *path, const char *text);
/* The whole file, malloc'd with a NUL after its bytes (the caller frees); its size in *size
 * (may be NULL; 0 on failure). NULL when it cannot be opened. */
char *fx_read_file(const char *path, size_t *size);

/* ------------------------------------------------------------------ strings */

/* Newlines in s. */
int fx_count_lines(const char *s);
/* Occurrences of needle in hay (overlapping ones too). */
int fx_count_of(const char *hay, const char *needle);
/* 1 if needle occurs in hay. */
int fx_contains(const char *hay, const char *needle);

/* ------------------------------------------------------------------ commands */

/* 1 in a sanitizer pass (GS_SAN set and not "0": `make test-asan` sets 1, `make test-clang`
 * clang): tests that
 * scale their work down under ASan read it. */
int fx_sanitized(void);

/* test_run of a printf-style command; its stdout+stderr in out. */
int fx_run(char *out, size_t out_size, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
int fx_vrun(char *out, size_t out_size, const char *fmt, va_list ap);
/* fmt's conversions are four %s: the gridsurvey binary (test_bin()), then a, b, c (NULL: ""). */
int fx_run_bin(char *out, size_t out_size, const char *fmt, const char *a, const char *b,
               const char *c);

/* ------------------------------------------------------------------ processes */

/* fork() with a pipe from the child to the parent (stdout flushed first, so the child does not
 * print the parent's buffer again): 0 in the child, *fd the pipe's write end; the child's pid
 * in the parent, *fd the read end. -1 (a test failure) when the pipe or fork fails. */
int fx_fork_pipe(int *fd);

#endif
