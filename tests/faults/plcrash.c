/* plcrash.c - an LD_PRELOAD shim for tests/test_faults.c (map_drawing_crash_fails_in_one_line):
 * PLplot's plinit (c_plinit; plstar calls it too) fails the ways PLplot and its text stack do
 * when memory runs out (docs/reliability.md):
 *   GS_PLCRASH=segv   SIGSEGV with its default action (fontconfig passing a failed strdup on;
 *                     a sanitizer's handler, which would report it, is bypassed)
 *   GS_PLCRASH=abort  abort() (GLib, fontconfig's assertions)
 *   GS_PLCRASH=exit   PLplot's own plexit("plinit: out of memory") (its banner, the reason,
 *                     "Program aborted", exit(1); or the program's plsexit handler)
 *   other, or unset   PLplot's own plinit
 * GS_PLCRASH_COUNT=FILE, GS_PLCRASH_AT=N: only the N-th plinit of the command fails, counted in
 * FILE across its processes (each drawing is a process of its own). */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* This call's number (1-based) in the count file, which it updates; 0 without one. */
static long call_number(void)
{
    const char *path = getenv("GS_PLCRASH_COUNT");
    if (!path) return 0;
    long n = 0;
    FILE *f = fopen(path, "r");
    if (f) {
        if (fscanf(f, "%ld", &n) != 1) n = 0;
        fclose(f);
    }
    f = fopen(path, "w");
    if (f) {
        fprintf(f, "%ld\n", n + 1);
        fclose(f);
    }
    return n + 1;
}

void c_plinit(void)   /* plplot.h: #define plinit c_plinit */
{
    const char *how = getenv("GS_PLCRASH"), *at = getenv("GS_PLCRASH_AT");
    long n = call_number();
    int fail = how && (!at || n == atol(at));
    if (fail && !strcmp(how, "segv")) {
        signal(SIGSEGV, SIG_DFL);
        raise(SIGSEGV);
    }
    if (fail && !strcmp(how, "abort")) abort();
    if (fail && !strcmp(how, "exit")) {
        void (*plexit)(const char *) = NULL;
        *(void **)&plexit = dlsym(RTLD_DEFAULT, "plexit");
        if (plexit) plexit("plinit: out of memory");
        exit(1);
    }
    void (*real)(void) = NULL;
    *(void **)&real = dlsym(RTLD_NEXT, "c_plinit");
    if (real) real();
}
