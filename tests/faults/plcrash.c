/* plcrash.c - an LD_PRELOAD shim for tests/test_faults.c (map_drawing_crash_fails_in_one_line):
 * PLplot's plinit (c_plinit) fails the ways PLplot and its text stack do when memory runs out
 * (docs/reliability.md): GS_PLCRASH=segv raises SIGSEGV (fontconfig passing a failed strdup
 * on), abort calls abort() (GLib, fontconfig's assertions), exit prints PLplot's message and
 * exits 1 (plexit). Any other value, or none: PLplot's own plinit. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

void c_plinit(void) /* plplot.h: #define plinit c_plinit */
{
    const char *how = getenv("GS_PLCRASH");
    if (how && !strcmp(how, "segv")) raise(SIGSEGV);
    if (how && !strcmp(how, "abort")) abort();
    if (how && !strcmp(how, "exit")) {
        fprintf(stderr, "\n*** PLPLOT ERROR, ABORTING OPERATION ***\nplinit: out of memory, aborting operation\n");
        exit(1);
    }
    void (*real)(void) = NULL;
    *(void **)&real = dlsym(RTLD_NEXT, "c_plinit");
    if (real) real();
}
