/* faultinject.c - an LD_PRELOAD shim that makes the n-th call of one class fail, as SQLite's
 * test harness does for its own allocator and VFS (docs/reliability.md, "Fault injection").
 * Built as $(BUILD)/tests/faults/faultinject.so (tests/faults/module.mk), driven by
 * tests/test_faults.c. Calls are counted from main() until exit begins (the loader's and the
 * libraries' constructors and teardown are not counted: a failure there is not the tool's to
 * handle; OpenCV's teardown throws std::bad_alloc).
 *
 *   GS_FAULT_CLASS  malloc  malloc, calloc, realloc, posix_memalign, aligned_alloc, memalign
 *                   write   write, pwrite, pwrite64, writev, fwrite, fputs, fflush, fclose
 *                           (of a stream open for writing: where stdio's buffered writes reach
 *                           the file); not standard error, nor PLplot's driver table
 *                           (below)
 *                   fsync   fsync, fdatasync
 *                   rename  rename, renameat
 *   GS_FAULT_N      the call (1-based) that fails; 0 or unset: none (count only)
 *   GS_FAULT_ERRNO  ENOSPC (default), EIO or SHORT (write class: half the bytes are written and
 *                   the call reports that short count; stdio calls then fail with ENOSPC)
 *   GS_FAULT_OUT    a file to which the calls of each class are appended at exit, with "1" if
 *                   the fault was injected ("MALLOC WRITE FSYNC RENAME FIRED\n")
 *   GS_FAULT_SITES  (GS_FAULT_CLASS=malloc) a file to which every distinct stack an allocation
 *                   was made from is written at exit, in the order first seen, as
 *                   "SITE N MODULE\n": SITE the hash of the stack (each frame's module and offset
 *                   in it, so the same in every run), N the allocation (1-based) that first had
 *                   it, MODULE the file name of the module that asked for it (the innermost frame
 *                   outside this shim and libstdc++'s operator new; "exe" for the executable)
 *   GS_FAULT_SITE   (GS_FAULT_CLASS=malloc, instead of GS_FAULT_N) the first allocation whose
 *                   stack hashes to this SITE (hexadecimal) fails: the same call whatever the
 *                   order the threads allocate in
 *
 * A gcc ASan binary runs with it given ASAN_OPTIONS=verify_asan_link_order=0: the shim then
 * comes before libasan and forwards to ASan's allocator (dlsym RTLD_NEXT), so a leak after an
 * injected failure is still reported; so does a clang one linked with the shared runtime
 * (-shared-libsan, the Makefile's SAN=clang; a static one's malloc would win over any preload).
 * Not counted: C++ operator new under ASan
 * (ASan replaces it; without ASan libstdc++'s operator new calls malloc and is counted), and
 * FFTW's allocations, which FFTW by design does not survive (fftw_malloc asserts). */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <pthread.h>
#include <errno.h>
#include <execinfo.h>
#include <fcntl.h>
#include <link.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/uio.h>
#include <unistd.h>

enum { C_NONE, C_MALLOC, C_WRITE, C_FSYNC, C_RENAME };

static int fault_class = C_NONE;
static long fault_n;
static int fault_errno = ENOSPC, fault_short;
static int armed;                 /* counting: from main() on */
static long calls[C_RENAME + 1];  /* of each class, atomically */
static int fired;
static uint64_t fault_site;       /* GS_FAULT_SITE, 0 if none */

/* The distinct stacks seen (GS_FAULT_SITES): a hash set, and the list in the order first seen. */
enum { SITE_CAP = 1 << 16 };
static int record_sites, site_lock, sites_overflow;
static uint64_t site_set[2 * SITE_CAP];
static uint64_t site_list[SITE_CAP];
static long site_first[SITE_CAP];
static const char *site_module[SITE_CAP];
static long n_sites;

/* The next definitions, resolved once; an allocation dlsym makes before they are known comes
 * from a small static arena (never freed). */
static void *(*real_malloc)(size_t);
static void *(*real_calloc)(size_t, size_t);
static void *(*real_realloc)(void *, size_t);
static void (*real_free)(void *);
static int (*real_posix_memalign)(void **, size_t, size_t);
static void *(*real_aligned_alloc)(size_t, size_t);
static void *(*real_memalign)(size_t, size_t);
static ssize_t (*real_write)(int, const void *, size_t);
static ssize_t (*real_pwrite)(int, const void *, size_t, off_t);
static ssize_t (*real_pwrite64)(int, const void *, size_t, off_t);
static ssize_t (*real_writev)(int, const struct iovec *, int);
static size_t (*real_fwrite)(const void *, size_t, size_t, FILE *);
static int (*real_fputs)(const char *, FILE *);
static int (*real_fflush)(FILE *);
static int (*real_fclose)(FILE *);
static int (*real_fsync)(int);
static int (*real_fdatasync)(int);
static int (*real_rename)(const char *, const char *);
static int (*real_renameat)(int, const char *, int, const char *);

static _Alignas(16) char arena[1 << 16];
static size_t arena_used;
static int resolving;

static void *arena_alloc(size_t n)
{
    n = (n + 15) & ~(size_t)15;
    if (arena_used + n > sizeof arena) return NULL;
    void *p = arena + arena_used;
    arena_used += n;
    return p;
}
static int in_arena(const void *p)
{
    return (const char *)p >= arena && (const char *)p < arena + sizeof arena;
}

#define RESOLVE(name) real_##name = (__typeof__(real_##name))dlsym(RTLD_NEXT, #name)
static void resolve(void)
{
    if (real_malloc || resolving) return;
    resolving = 1;
    RESOLVE(calloc);
    RESOLVE(realloc);
    RESOLVE(free);
    RESOLVE(posix_memalign);
    RESOLVE(aligned_alloc);
    RESOLVE(memalign);
    RESOLVE(write);
    RESOLVE(pwrite);
    RESOLVE(pwrite64);
    RESOLVE(writev);
    RESOLVE(fwrite);
    RESOLVE(fputs);
    RESOLVE(fflush);
    RESOLVE(fclose);
    RESOLVE(fsync);
    RESOLVE(fdatasync);
    RESOLVE(rename);
    RESOLVE(renameat);
    RESOLVE(malloc);   /* last: its being set means all are */
    resolving = 0;
}

static void write_all(int fd, const char *b, size_t n)
{
    if (real_write(fd, b, n) != (ssize_t)n) { /* nothing to do about it */ }
}

static void report(void)
{
    const char *path = getenv("GS_FAULT_OUT"), *sites = getenv("GS_FAULT_SITES");
    if (!real_write) return;
    char line[512];
    int fd = path ? open(path, O_WRONLY | O_CREAT | O_APPEND, 0600) : -1;
    if (fd >= 0) {
        int n = snprintf(line, sizeof line, "%ld %ld %ld %ld %d\n", calls[C_MALLOC], calls[C_WRITE],
                         calls[C_FSYNC], calls[C_RENAME], fired);
        write_all(fd, line, (size_t)n);
        close(fd);
    }
    fd = record_sites && sites ? open(sites, O_WRONLY | O_CREAT | O_TRUNC, 0600) : -1;
    if (fd < 0) return;
    for (long i = 0; i < n_sites; i++) {
        const char *m = site_module[i] ? site_module[i] : "", *slash = strrchr(m, '/');
        int n = snprintf(line, sizeof line, "%016llx %ld %s\n", (unsigned long long)site_list[i], site_first[i],
                         slash ? slash + 1 : *m ? m : "exe");
        write_all(fd, line, (size_t)n);
    }
    if (sites_overflow) write_all(fd, "overflow\n", 9);   /* more stacks than SITE_CAP */
    close(fd);
}

/* 1 if call k of class c is the one to fail (and it is marked as fired). */
static int fails(int c, long k)
{
    if (c != fault_class || k != fault_n || fault_site) return 0;
    fired = 1;
    return 1;
}

/* Counts this call of class c; 1 if it is the one to fail. */
static int hit(int c)
{
    if (!armed) return 0;
    return fails(c, __atomic_add_fetch(&calls[c], 1, __ATOMIC_SEQ_CST));
}

/* Notes the stack site of allocation k, asked for by module (its name), if it is new. */
static void record_site(uint64_t site, long k, const char *module)
{
    while (__atomic_exchange_n(&site_lock, 1, __ATOMIC_ACQUIRE)) { /* spin: a few instructions */ }
    size_t i = (size_t)(site * 0x9E3779B97F4A7C15ull >> 47) & (2 * SITE_CAP - 1);
    while (site_set[i] && site_set[i] != site) i = (i + 1) & (2 * SITE_CAP - 1);
    if (!site_set[i]) {
        if (n_sites < SITE_CAP) {
            site_set[i] = site;
            site_list[n_sites] = site;
            site_module[n_sites] = module;
            site_first[n_sites++] = k;
        } else {
            sites_overflow = 1;
        }
    }
    __atomic_store_n(&site_lock, 0, __ATOMIC_RELEASE);
}

/* Libraries that do not survive a failed allocation. FFTW's allocator asserts (by design: it
 * has no error path). PLplot and the text stack it draws with exit (plexit, three lines on
 * stderr), abort (GLib by design; fontconfig's assertions) or crash (fontconfig passes a failed
 * strdup on: SIGSEGV in FcValueSave under FcConfigSubstituteWithPat and pango_layout_get_size,
 * found by the sweep), in the drawing thread and in the one pango loads fonts in
 * (docs/reliability.md). And the sanitizer runtime's own (gcc's libasan, clang's shared
 * libclang_rt.asan): ASan's setup of a new thread calls pthread_getattr_np, which allocates, and
 * aborts when that fails; those allocations, made as threads start, are not counted either. */
static const char *const unsurvivable[] = {"libfftw3", "libplplot", "plplot5", "libfontconfig", "libpango",
                                           "libglib-2", "libgobject-2", "libcairo", "libharfbuzz",
                                           "libfreetype", "libexpat", "libasan", "libubsan", "libclang_rt", NULL};

/* The loaded modules' address ranges (their PT_LOAD segments), each with its name's hash and
 * whether it is one of those: appended when a frame is in none of them (a module loaded since),
 * never changed once counted in n_modules, searched newest first. dladdr() would do, but it
 * searches each module's symbols too: most of the time of an allocation sweep. */
enum { MODULE_CAP = 4096 };   /* a power of two (page_cache keeps an index in 12 bits) */
static struct module {
    uintptr_t lo, hi, base;
    const char *name;   /* the loader's (valid while the module is loaded) */
    uint64_t name_hash;
    int unsurvivable, allocator;   /* allocator: this shim or libstdc++ (operator new) */
} modules[MODULE_CAP];
static int n_modules, module_lock;

static uint64_t fnv(uint64_t h, const void *p, size_t n)
{
    for (size_t i = 0; i < n; i++) h = (h ^ ((const unsigned char *)p)[i]) * 0x100000001b3ull;
    return h;
}

static int add_modules(struct dl_phdr_info *info, size_t size, void *ctx)
{
    (void)size;
    (void)ctx;
    const char *name = info->dlpi_name ? info->dlpi_name : "";
    for (int i = 0; i < info->dlpi_phnum; i++) {
        const ElfW(Phdr) *ph = &info->dlpi_phdr[i];
        if (ph->p_type != PT_LOAD) continue;
        uintptr_t lo = info->dlpi_addr + ph->p_vaddr, hi = lo + ph->p_memsz;
        int known = 0;
        for (int m = 0; m < n_modules && !known; m++)
            known = modules[m].lo == lo && modules[m].hi == hi && modules[m].base == info->dlpi_addr;
        if (known || n_modules == MODULE_CAP) continue;
        struct module *mo = &modules[n_modules];
        mo->lo = lo;
        mo->hi = hi;
        mo->base = info->dlpi_addr;
        mo->name = name;
        mo->name_hash = fnv(0xcbf29ce484222325ull, name, strlen(name));
        mo->unsurvivable = 0;
        mo->allocator = strstr(name, "libstdc++") != NULL ||
                        ((uintptr_t)&add_modules >= lo && (uintptr_t)&add_modules < hi);
        for (int j = 0; unsurvivable[j]; j++) mo->unsurvivable |= strstr(name, unsurvivable[j]) != NULL;
        __atomic_store_n(&n_modules, n_modules + 1, __ATOMIC_RELEASE);
    }
    return 0;
}

/* The module a code page was last found in, as (page << 12 | index): a hint, checked. */
enum { PAGE_CACHE = 1 << 14 };
static uint64_t page_cache[PAGE_CACHE];

/* The module pc is in (NULL if none, as for a JIT's code). */
static const struct module *module_of(uintptr_t pc)
{
    uint64_t page = pc >> 12, *slot = &page_cache[(page * 0x9E3779B97F4A7C15ull) >> 50];
    uint64_t e = __atomic_load_n(slot, __ATOMIC_RELAXED);
    const struct module *hint = &modules[e & (MODULE_CAP - 1)];
    if (e >> 12 == page && (int)(e & (MODULE_CAP - 1)) < __atomic_load_n(&n_modules, __ATOMIC_ACQUIRE) &&
        pc >= hint->lo && pc < hint->hi)
        return hint;
    for (int pass = 0; pass < 2; pass++) {
        for (int m = __atomic_load_n(&n_modules, __ATOMIC_ACQUIRE) - 1; m >= 0; m--)
            if (pc >= modules[m].lo && pc < modules[m].hi) {
                __atomic_store_n(slot, page << 12 | (uint64_t)m, __ATOMIC_RELAXED);
                return &modules[m];
            }
        if (pass) break;
        while (__atomic_exchange_n(&module_lock, 1, __ATOMIC_ACQUIRE)) { /* spin */ }
        dl_iterate_phdr(add_modules, NULL);
        __atomic_store_n(&module_lock, 0, __ATOMIC_RELEASE);
    }
    return NULL;
}

/* 1 if a frame of one of them is on the stack of the allocation being made; *site the hash
 * (FNV-1a) of that stack's frames, each as its module's name and its offset in the module (the
 * same in every run), *module the name of the module that asked for it. Allocations made by
 * backtrace() itself (only its first call, in setup) count as such. */
static __thread int unwinding;
static int for_unsurvivable(uint64_t *site, const char **module)
{
    *module = NULL;
    if (unwinding) return 1;
    unwinding = 1;
    void *pc[64];
    int n = backtrace(pc, 64), found = 0;
    uint64_t h = 0xcbf29ce484222325ull;
    for (int i = 1; i < n && !found; i++) {
        uintptr_t off = (uintptr_t)pc[i];
        const struct module *m = module_of(off);
        if (m) {
            found = m->unsurvivable;
            if (!*module && !m->allocator) *module = m->name;
            h = fnv(h, &m->name_hash, sizeof m->name_hash);
            off -= m->base;
        }
        h = fnv(h, &off, sizeof off);
    }
    unwinding = 0;
    *site = h ? h : 1;
    return found;
}

/* hit(C_MALLOC) for an allocation, unless for one of those libraries (only looked for when
 * allocations are the class counted: the stack is unwound for each); with GS_FAULT_SITE, the
 * first allocation from that site fails instead of the n-th. */
static int alloc_hit(void)
{
    if (!armed) return 0;
    if (fault_class != C_MALLOC) return hit(C_MALLOC);
    uint64_t site;
    const char *module;
    if (for_unsurvivable(&site, &module)) return 0;
    long k = __atomic_add_fetch(&calls[C_MALLOC], 1, __ATOMIC_SEQ_CST);
    if (record_sites) record_site(site, k, module);
    if (fault_site) return site == fault_site && !__atomic_exchange_n(&fired, 1, __ATOMIC_SEQ_CST);
    return fails(C_MALLOC, k);
}

__attribute__((constructor)) static void setup(void)
{
    resolve();
    void *pc[4];
    unwinding = 1;
    backtrace(pc, 4);   /* loads the unwinder (which allocates) before anything is counted */
    unwinding = 0;
    const char *c = getenv("GS_FAULT_CLASS"), *n = getenv("GS_FAULT_N"), *e = getenv("GS_FAULT_ERRNO");
    if (c) {
        fault_class = !strcmp(c, "malloc") ? C_MALLOC : !strcmp(c, "write") ? C_WRITE
                      : !strcmp(c, "fsync") ? C_FSYNC : !strcmp(c, "rename") ? C_RENAME : C_NONE;
    }
    fault_n = n ? atol(n) : 0;
    const char *site = getenv("GS_FAULT_SITE");
    if (fault_class == C_MALLOC && site && *site) fault_site = strtoull(site, NULL, 16);
    record_sites = fault_class == C_MALLOC && getenv("GS_FAULT_SITES") != NULL;
    if (e && !strcmp(e, "EIO")) fault_errno = EIO;
    if (e && !strcmp(e, "SHORT")) fault_short = 1;
    atexit(report);
}

/* main() is wrapped so that counting starts there. */
typedef int (*main_fn)(int, char **, char **);
static main_fn real_main;
static void disarm(void)
{
    armed = 0;
}
static int counted_main(int argc, char **argv, char **envp)
{
    /* not into the children: a sanitizer's symbolizer (clang's runs llvm-symbolizer to match
     * LSan's suppressions) would fail its own allocations and garble the report */
    unsetenv("LD_PRELOAD");
    armed = 1;
    atexit(disarm);   /* runs first at exit: the libraries' teardown is not counted */
    /* nor a forked child's (gs_isolated's drawing processes): its calls would reach neither the
     * report nor the site list, and fail the n-th call a second time */
    pthread_atfork(NULL, NULL, disarm);
    return real_main(argc, argv, envp);
}
int __libc_start_main(main_fn main, int argc, char **argv, void (*init)(void), void (*fini)(void),
                      void (*rtld_fini)(void), void *stack_end)
{
    int (*next)(main_fn, int, char **, void (*)(void), void (*)(void), void (*)(void), void *) =
        (__typeof__(next))dlsym(RTLD_NEXT, "__libc_start_main");
    real_main = main;
    return next(counted_main, argc, argv, init, fini, rtld_fini, stack_end);
}

/* ------------------------------------------------------------------ allocation */

void *malloc(size_t n)
{
    if (!real_malloc) {
        resolve();
        if (!real_malloc) return arena_alloc(n);
    }
    if (alloc_hit()) { errno = ENOMEM; return NULL; }
    return real_malloc(n);
}
void *calloc(size_t m, size_t n)
{
    if (!real_calloc) return arena_alloc(m * n);   /* zeroed: static */
    if (alloc_hit()) { errno = ENOMEM; return NULL; }
    return real_calloc(m, n);
}
void *realloc(void *p, size_t n)
{
    if (in_arena(p)) {   /* moved out of the arena */
        void *q = malloc(n);
        if (q) memcpy(q, p, n < (size_t)(arena + sizeof arena - (char *)p) ? n : (size_t)(arena + sizeof arena - (char *)p));
        return q;
    }
    if (alloc_hit()) { errno = ENOMEM; return NULL; }
    return real_realloc(p, n);
}
void free(void *p)
{
    if (!p || in_arena(p)) return;
    real_free(p);
}
int posix_memalign(void **p, size_t align, size_t n)
{
    if (alloc_hit()) return ENOMEM;
    return real_posix_memalign(p, align, n);
}
void *aligned_alloc(size_t align, size_t n)
{
    if (alloc_hit()) { errno = ENOMEM; return NULL; }
    return real_aligned_alloc(align, n);
}
void *memalign(size_t align, size_t n)
{
    if (alloc_hit()) { errno = ENOMEM; return NULL; }
    return real_memalign(align, n);
}

/* ------------------------------------------------------------------ writes */

/* Not failed (nor counted): standard error, and PLplot's driver table, which PLplot writes to
 * a temporary file (TMPDIR/plplot_XXXXXX, unlinked at once) and reads back without checking its
 * writes; a failed one leaves entries of the table uninitialised, which plend then frees (a
 * crash in PLplot: docs/reliability.md). */
static int exempt(int fd)
{
    if (fd == 2) return 1;
    char link[64], target[4096];
    snprintf(link, sizeof link, "/proc/self/fd/%d", fd);
    ssize_t n = readlink(link, target, sizeof target - 1);
    if (n <= 0) return 0;
    target[n] = '\0';
    const char *base = strrchr(target, '/');
    return base && !strncmp(base + 1, "plplot_", 7) && strstr(base, " (deleted)");
}

/* A failed write: SHORT writes half (at least one byte when there are two) and returns that. */
ssize_t write(int fd, const void *b, size_t n)
{
    if (!exempt(fd) && hit(C_WRITE)) {
        if (fault_short && n > 1) return real_write(fd, b, n / 2);
        errno = fault_errno;
        return -1;
    }
    return real_write(fd, b, n);
}
ssize_t pwrite(int fd, const void *b, size_t n, off_t off)
{
    if (hit(C_WRITE)) {
        if (fault_short && n > 1) return real_pwrite(fd, b, n / 2, off);
        errno = fault_errno;
        return -1;
    }
    return real_pwrite(fd, b, n, off);
}
ssize_t pwrite64(int fd, const void *b, size_t n, off_t off)
{
    if (hit(C_WRITE)) {
        if (fault_short && n > 1) return real_pwrite64(fd, b, n / 2, off);
        errno = fault_errno;
        return -1;
    }
    return real_pwrite64(fd, b, n, off);
}
ssize_t writev(int fd, const struct iovec *v, int cnt)
{
    if (!exempt(fd) && hit(C_WRITE)) {
        if (fault_short && cnt > 0 && v[0].iov_len > 1) return real_write(fd, v[0].iov_base, v[0].iov_len / 2);
        errno = fault_errno;
        return -1;
    }
    return real_writev(fd, v, cnt);
}

/* stdio: the stream's error flag is set, as a failed buffered write sets it (glibc's
 * _IO_ERR_SEEN). */
static int stdio_fail(FILE *f)
{
    f->_flags |= 0x0020;
    errno = fault_short ? ENOSPC : fault_errno;
    return EOF;
}
static int writing(FILE *f)
{
    if (f == stderr || exempt(fileno(f))) return 0;
    int fl = fcntl(fileno(f), F_GETFL);
    return fl >= 0 && (fl & O_ACCMODE) != O_RDONLY;
}
size_t fwrite(const void *b, size_t size, size_t n, FILE *f)
{
    if (writing(f) && hit(C_WRITE)) {
        size_t done = fault_short && n > 1 ? real_fwrite(b, size, n / 2, f) : 0;
        stdio_fail(f);
        return done;
    }
    return real_fwrite(b, size, n, f);
}
int fputs(const char *s, FILE *f)
{
    if (writing(f) && hit(C_WRITE)) return stdio_fail(f);
    return real_fputs(s, f);
}
int fflush(FILE *f)
{
    if (f && writing(f) && hit(C_WRITE)) return stdio_fail(f);
    return real_fflush(f);
}
int fclose(FILE *f)
{
    if (f && writing(f) && hit(C_WRITE)) {
        real_fclose(f);   /* closed all the same, as a failed fclose leaves it */
        errno = fault_short ? ENOSPC : fault_errno;
        return EOF;
    }
    return real_fclose(f);
}

/* ------------------------------------------------------------------ fsync, rename */

int fsync(int fd)
{
    if (hit(C_FSYNC)) { errno = fault_errno == ENOSPC ? EIO : fault_errno; return -1; }
    return real_fsync(fd);
}
int fdatasync(int fd)
{
    if (hit(C_FSYNC)) { errno = fault_errno == ENOSPC ? EIO : fault_errno; return -1; }
    return real_fdatasync(fd);
}
int rename(const char *a, const char *b)
{
    if (hit(C_RENAME)) { errno = fault_errno; return -1; }
    return real_rename(a, b);
}
int renameat(int da, const char *a, int db, const char *b)
{
    if (hit(C_RENAME)) { errno = fault_errno; return -1; }
    return real_renameat(da, a, db, b);
}
