/* fuzz.h - the shared part of the libFuzzer targets (tests/fuzz/fuzz_*.c, docs/reliability.md).
 * FUZZ_TARGET(name) is LLVMFuzzerTestOneInput in a libFuzzer build (`make fuzz`), and a static
 * function fuzz_name when tests/test_fuzz_replay.c includes the targets (FUZZ_REPLAY) to replay
 * the corpora and past crash inputs in `make check`. Inputs that the parsers read by path go
 * through one scratch directory per process. */
#ifndef GRIDSURVEY_FUZZ_H
#define GRIDSURVEY_FUZZ_H

#include "recognize/base/base.h"

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#ifdef FUZZ_REPLAY
#define FUZZ_TARGET(name) static int fuzz_##name(const uint8_t *data, size_t size)
#else
#define FUZZ_TARGET(name)                                                                  \
    int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);                          \
    int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
#endif

/* The process's scratch directory (created once, under $TMPDIR or /tmp). */
static inline const char *fuzz_dir(void)
{
    static char dir[512];
    if (!dir[0]) {
        const char *t = getenv("TMPDIR");
        snprintf(dir, sizeof dir, "%s/gridsurvey-fuzz.XXXXXX", t && *t ? t : "/tmp");
        if (!mkdtemp(dir)) abort();
    }
    return dir;
}

/* dir/name holding data[0..size); returns the path (a static buffer per name slot). */
static inline const char *fuzz_file(const char *name, const void *data, size_t size)
{
    static char path[4][700];
    static int slot;
    char *p = path[slot++ & 3];
    snprintf(p, sizeof path[0], "%s/%s", fuzz_dir(), name);
    FILE *f = fopen(p, "wb");
    if (!f || (size && fwrite(data, 1, size, f) != size) || fclose(f) != 0) abort();
    return p;
}

/* A NUL-terminated copy (the caller frees). */
static inline char *fuzz_text(const uint8_t *data, size_t size)
{
    char *t = malloc(size + 1);
    if (!t) abort();
    if (size) memcpy(t, data, size);
    t[size] = '\0';
    return t;
}

#endif
