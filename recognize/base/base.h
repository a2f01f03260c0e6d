/*
 * base.h - the lowest layer of gridsurvey (recognize/base/, prefix gs_): the vocabulary every
 * other module shares. Implements the physics half of "Computational Imaging on the Electric
 * Grid" (Sheinin, Schechner, Kutulakos, CVPR 2017) that does not depend on recognition: the AC
 * model (Eq. 1), bulb response functions (Eqs. 3-6), the DELIGHT bulb database (Sec. 3; here a
 * substitute generated from lamp physics, docs/delight.md, docs/delight-models.md) and the
 * capture-directory format (Sec. 6, docs/formats.md); plus the one status enum (gs_status) with a
 * thread-local detail string for one-line error messages.
 *
 * Conventions (docs/design.md): time t starts at a negative-to-positive zero crossing of the
 * reference outlet. A flicker cycle lasts Delta = 1/(2 f) (Eq. 1). Shifts are in cycles
 * (fractions of Delta), positive = delayed (the paper's shift() to the right).
 * Ownership: functions that return allocated memory say so; free it with the named function.
 * Every destructor accepts NULL.
 */
#ifndef GRIDSURVEY_BASE_H
#define GRIDSURVEY_BASE_H

#include <jansson.h>
#include <stddef.h>
#include <time.h>
#include <stdint.h>
#include <stdio.h>

/* ------------------------------------------------------------------ status */

typedef enum {
    GS_OK = 0,
    GS_EINVAL,      /* an argument outside its documented range */
    GS_EIO,         /* a file could not be opened, read or written */
    GS_EFORMAT,     /* a file's content does not follow its format */
    GS_ENOMEM,      /* allocation failed */
    GS_ESQL,        /* SQLite reported an error */
    GS_ENOTFOUND,   /* a named item (bulb id, file) does not exist */
    GS_ENUMERIC,    /* NaN, Inf or an ill-conditioned computation */
    GS_ELIMIT       /* a hardware or model limit would be exceeded */
} gs_status;

/* A static string naming the status. */
const char *gs_strerror(gs_status s);
/* The detail of the last failure on this thread ("file:line: field: expected ..."); never NULL. */
const char *gs_detail(void);
/* Record a printf-style detail for this thread and return s (for `return gs_fail(...)`); an
 * argument may be gs_detail() itself, to add context to the last failure. The detail is kept to
 * one line: trailing white space is dropped and other control bytes become spaces. */
gs_status gs_fail(gs_status s, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/* ------------------------------------------------------- format kit: files */

/* dir + "/" + name into out[0..cap); 0 if it does not fit. */
int gs_path_join(char *out, size_t cap, const char *dir, const char *name);

/* The directory part of path ("." when there is none, trailing slashes ignored); the last
 * component, without its extension when strip_ext. Cut to size. */
void gs_path_dir(const char *path, char *buf, size_t size);
void gs_path_base(const char *path, int strip_ext, char *buf, size_t size);

/* The whole file at path in a malloc'd buffer with a NUL appended (*data: free()), its length
 * in *size (may be NULL). GS_ENOTFOUND for a missing file, GS_EIO for one that cannot be read,
 * GS_ELIMIT beyond max_bytes (0: GS_FILE_MAX_DEFAULT); the detail names the file. */
#define GS_FILE_MAX_DEFAULT ((size_t)1 << 30)
gs_status gs_file_read(const char *path, size_t max_bytes, char **data, size_t *size);
/* Inputs: "-" is stdin; anything else must be a regular file (a symlink to one is fine): a
 * FIFO, device or directory is refused before anything is read (a FIFO without waiting for a
 * writer). gs_input_open sets *size to the file's size (-1 for stdin) unless NULL;
 * gs_input_close leaves stdin open. gs_input_check is for readers that open by name (SQLite,
 * libtiff, libsndfile), which cannot read stdin. */
gs_status gs_input_open(const char *path, FILE **f, long long *size);
void gs_input_close(FILE *f);
gs_status gs_input_check(const char *path);
/* SHA-256 (FIPS 180-4, nettle) of data[0..n), or of the file at path (streamed), as 64
 * lower-case hex digits + NUL. */
void gs_sha256_hex(const void *data, size_t n, char hex[65]);
gs_status gs_sha256_file(const char *path, char hex[65]);
/* Create dir if it does not exist (one level). */
gs_status gs_dir_ensure(const char *dir);

/* The memory budget (recognize/base/kit_mem.c): gs_mem_check fails with GS_ELIMIT, "WHAT need
 * N MiB: more than the memory budget of B MiB ...", when bytes exceed it; call it before an
 * allocation an input's declared size decides. What gs_mem_budget_set gave (the CLI's
 * --max-memory or GS_MAX_MEMORY), else (0) half the physical RAM (and at most half of
 * RLIMIT_AS). gs_mem_parse reads "4G", "512M", "1.5G", "1048576" (K, M, G, T: powers of 1024;
 * >= 1M); GS_EINVAL "WHAT 'TEXT': expected a size ..." otherwise (what: the option or variable). */
gs_status gs_mem_parse(const char *what, const char *text, size_t *bytes);
void gs_mem_budget_set(size_t bytes);
size_t gs_mem_budget(void);
gs_status gs_mem_check(double bytes, const char *what);

/* Atomic replacement of a file: gs_atomic_open creates ".NAME.tmp.PID.SEQ" beside path (with a
 * stdio stream in f when want_stream, else for writing by name through tmp), gs_atomic_commit
 * flushes, fsyncs and renames it over path, gs_atomic_abort (accepts NULL) removes it. Readers
 * see the old file or the new one, never a partial one. Unix filter rules: path "-" is stdout; a
 * symlink to a regular file has its target replaced (the link stays); an existing device, FIFO
 * or dangling symlink is written through (opened, never replaced; no atomicity); for by-name
 * writers those get a scratch file in $TMPDIR that commit copies to the target. */
typedef struct {
    char path[4096];
    char tmp[4200];
    FILE *f;
    int direct;   /* write-through target (internal) */
    int out_fd;   /* its descriptor while tmp is a scratch file (internal) */
} gs_atomic;
gs_status gs_atomic_open(gs_atomic *a, const char *path, int want_stream);
gs_status gs_atomic_commit(gs_atomic *a);
void gs_atomic_abort(gs_atomic *a);
/* gs_atomic_commit of a new file, unless another process made path meanwhile: then *raced = 1,
 * a is removed, GS_OK (a write-through target, e.g. a symlink to nothing, is committed). The creators of a path take turns under an flock of its directory, so
 * none replaces a file another has already opened and written. */
gs_status gs_atomic_commit_new(gs_atomic *a, int *raced);
/* data[0..size) as path, atomically. */
gs_status gs_file_write_atomic(const char *path, const void *data, size_t size);

/* draw(ctx, copy) in a child process on a shared copy of buf[0..bytes) (none when bytes is 0),
 * copied back when it succeeds (recognize/base/kit_isolate.c): for libraries that exit or crash
 * on a failure (PLplot). Nothing else draw changes reaches this process but the files it
 * writes. draw's own failure is returned with its detail; a crash or an exit is GS_EIO "WHAT:
 * the drawing process was killed by signal N (NAME): LAST LINE" (or "failed (exit status N)"),
 * LAST LINE the last of the child's standard error, in one line, buf unchanged. The child's
 * standard error is passed on after it ends when it succeeded, or when it holds a sanitizer's
 * report. A library's exit() in the child ends only the child. */
gs_status gs_isolated(const char *what, unsigned char *buf, size_t bytes,
                      gs_status (*draw)(void *ctx, unsigned char *buf), void *ctx);
/* For a library's error handler in draw (PLplot's plsexit): writes reason as the last line of
 * the child's standard error and ends the child with status 1. */
int gs_isolated_exit(const char *reason);

/* -------------------------------------------------------- format kit: JSON */

/* Every JSON format of the tool (scenes, capture.json, stations, truth files, progress files)
 * is read through a gs_json document: Jansson's parse (duplicate keys refused; syntax errors
 * "SOURCE:LINE:COL: JSON syntax: ...") plus the line of every member and element by its path
 * ("lights[3].bulb", "" is the document). Every field error has one shape,
 *   SOURCE:LINE: field PATH: expected EXPECTED[ (got VALUE)| (the field is missing)]
 * (LINE: the field's, else its nearest enclosing element's), and one rule for unknown keys: an
 * error, except "comment", "description" and extensions named "x_..." (ignored). */
typedef struct gs_json gs_json;
gs_status gs_json_parse(const char *text, size_t n, const char *source, gs_json **out);
gs_status gs_json_load(const char *path, size_t max_bytes, gs_json **out);   /* gs_file_read */
void gs_json_free(gs_json *j);
json_t *gs_json_root(const gs_json *j);          /* borrowed */
const char *gs_json_source(const gs_json *j);    /* borrowed */
const char *gs_json_text(const gs_json *j, size_t *n);   /* the document text, borrowed */
/* The line of path, or of its nearest recorded ancestor; 1 when none is. */
int gs_json_line(const gs_json *j, const char *path);
/* gs_fail(s, "SOURCE:LINE: field PATH: MESSAGE"). */
gs_status gs_json_fail(const gs_json *j, gs_status s, const char *path, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
/* parent + "." + key (or key at the top) into out. */
void gs_json_path(char *out, size_t cap, const char *parent, const char *key);
/* 1 for the keys every format ignores ("comment", "description", "x_..."). */
int gs_json_key_is_extension(const char *key);
/* GS_EFORMAT naming the first key of obj (at path) that is neither allowed (NULL-terminated,
 * maybe empty) nor an extension, with the list of allowed keys and the extensions. */
gs_status gs_json_check_keys(const gs_json *j, json_t *obj, const char *path,
                             const char *const *allowed);
/* Typed getters for member key of obj at path (obj NULL or not an object: absent). Absent and
 * not required: *out = def. A number must be finite and in [lo, hi]; expect (NULL: "a number
 * from LO to HI", "an integer from LO to HI") is the expected value the message names. */
gs_status gs_json_get_num(const gs_json *j, json_t *obj, const char *path, const char *key,
                          int required, double def, double lo, double hi, const char *expect,
                          double *out);
gs_status gs_json_get_int(const gs_json *j, json_t *obj, const char *path, const char *key,
                          int required, long long def, long long lo, long long hi,
                          const char *expect, long long *out);
gs_status gs_json_get_bool(const gs_json *j, json_t *obj, const char *path, const char *key,
                           int required, int def, int *out);
/* A string shorter than cap bytes copied into out (def, or "", when absent). */
gs_status gs_json_get_str(const gs_json *j, json_t *obj, const char *path, const char *key,
                          int required, const char *def, char *out, size_t cap);
gs_status gs_json_get_obj(const gs_json *j, json_t *obj, const char *path, const char *key,
                          int required, json_t **out);
/* An array of exactly n numbers (n > 0) or of 1..max (n = 0), each finite in [lo, hi]. */
gs_status gs_json_get_num_array(const gs_json *j, json_t *obj, const char *path, const char *key,
                                size_t n, size_t max, double lo, double hi, double *out,
                                size_t *count);

/* A growable text (zero it to start; free(t.s) when done). oom is set, and further output
 * dropped, when memory runs out. */
typedef struct {
    char *s;
    size_t n, cap;
    int oom;
} gs_text;
/* 1 if s is UTF-8 without control characters (C0, DEL): the one rule for names that reach a
 * terminal, a database and every export (survey names, light ids). */
int gs_text_clean(const char *s);
void gs_text_printf(gs_text *t, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* A JSON string literal of s. */
void gs_text_json_string(gs_text *t, const char *s);
/* Compact JSON of v, key order kept, every real in its shortest exact form (gs_json_real). */
void gs_text_json(gs_text *t, json_t *v);
/* The shortest %g form of v that reads back as exactly v (cap >= 32). */
void gs_json_real(char *buf, size_t cap, double v);

/* --------------------------------------------------------- format kit: CSV */

/* Read the CSV file at path (RFC 4180, libcsv: quoted fields may hold commas, quotes and line
 * breaks; a UTF-8 byte-order mark is skipped; blank lines are skipped; spaces around unquoted
 * fields are trimmed), calling fn once per row with its NUL-terminated fields (borrowed for the
 * call; fn may modify them) and the line the row ends on. The first status that is not GS_OK
 * (fn's, or GS_EFORMAT "PATH:LINE: CSV syntax: ..." or "PATH:LINE: a NUL byte: expected CSV
 * text", before any row), GS_ENOTFOUND, GS_EIO, GS_ELIMIT beyond
 * max_bytes, 0: GS_FILE_MAX_DEFAULT) stops the reading and is returned. */
typedef gs_status (*gs_csv_row_fn)(void *ctx, char **fields, size_t count, size_t line);
gs_status gs_csv_read(const char *path, size_t max_bytes, gs_csv_row_fn fn, void *ctx);
/* Write one field: as it is, or quoted (RFC 4180) when it holds a comma, quote or line break.
 * 0 on success, -1 on a write error. */
int gs_csv_write_field(FILE *out, const char *s);

/* ------------------------------------------------ format kit: random numbers */

/* splitmix64 (Steele, Lea, Flood 2014): a fixed, portable generator (never rand()); one step
 * of the state *x. The tool's deterministic draws (DELIGHT parameters, benches, tests) and the
 * seeding of gs_rng all come from it. */
static inline uint64_t gs_splitmix64(uint64_t *x)
{
    uint64_t z = (*x += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}
/* Uniform in (0, 1) (never 0 or 1) from 53 bits of splitmix64; a standard normal from two of
 * them by Box-Muller, drawn in that order. */
double gs_splitmix_uniform(uint64_t *x);
double gs_splitmix_normal(uint64_t *x);

/* xoshiro256** (Blackman and Vigna, 2018) seeded through splitmix64: the simulator's streams.
 * Every random process draws from its own stream keyed by (seed, tag, a, b), so enabling one
 * effect never changes another's numbers and a resumed capture re-renders a frame bit for bit. */
typedef struct {
    uint64_t s[4];
} gs_rng;
void gs_rng_init(gs_rng *r, uint64_t seed, uint32_t tag, uint64_t a, uint64_t b);
static inline uint64_t gs_rng_u64(gs_rng *r)
{
    uint64_t *s = r->s;
    uint64_t x = s[1] * 5u;
    uint64_t result = ((x << 7) | (x >> 57)) * 9u;
    uint64_t t = s[1] << 17;
    s[2] ^= s[0];
    s[3] ^= s[1];
    s[1] ^= s[2];
    s[0] ^= s[3];
    s[2] ^= t;
    s[3] = (s[3] << 45) | (s[3] >> 19);
    return result;
}
/* Uniform in (0, 1): never 0 or 1. */
static inline double gs_rng_uniform(gs_rng *r)
{
    return ((double)(gs_rng_u64(r) >> 11) + 0.5) * 0x1.0p-53;
}
/* Standard normal (Marsaglia and Tsang's ziggurat, 128 layers). */
double gs_rng_normal(gs_rng *r);
/* Poisson with mean lambda >= 0 (inversion below 12, Hormann's PTRS above: exact in law). */
double gs_rng_poisson(gs_rng *r, double lambda);

/* ------------------------------------------------------------------ numerics */

/* Chi-square tail probability P(X > chi2) for dof degrees of freedom: the regularised upper
 * incomplete gamma Q(dof/2, chi2/2) (series or continued fraction with libm's lgamma; relative
 * error < 1e-12 where the result is > 1e-300; exp(-chi2/2) exactly for dof = 2). 1 for
 * chi2 <= 0, 0 for +inf, NaN for NaN or dof < 1. */
double gs_chi2_sf(double chi2, int dof);
/* Its inverse: the chi2 whose tail probability is p (bisection to 1e-12 relative); +inf for
 * p <= 0, 0 for p >= 1, NaN for NaN or dof < 1. */
double gs_chi2_isf(double p, int dof);
/* log Phi(z), Phi the standard normal CDF, accurate for every z (asymptotic below -20). */
double gs_log_phi(double z);
/* Loops over every template, sample or pixel, in clones for the CPU's widest registers (a plain
 * clone, AVX2 and AVX-512; the same arithmetic in each, no contraction into fused multiply-adds;
 * where a loop calls log, erfc or exp, gcc's AVX-512 clone calls glibc's vector versions, which
 * round otherwise than the scalar ones: results may differ in the last bits from one CPU to
 * another, never from one split of the work to another on one CPU); GS_VECTOR_LOOP also lets
 * the vectorizer take loops of any length. The AVX2 clone by the CPU's features ("avx2"; gcc's
 * "arch=haswell" clone runs on Haswell models only). gcc (12) lowers a comparison of generic
 * vectors (vector_size types) in these clones for the plain target, to scalar code; the
 * vectorizer runs per clone. The light's preparation (eq7_light.c) compares in plain loops for
 * that; the screen's scans and the pixel rows' still compare generic vectors. gcc's only:
 * clang (14) cannot export such a function and names each resolver globally, so its build (the
 * sanitizers') runs the plain code. */
#if defined(__GNUC__) && !defined(__clang__)
#define GS_VECTOR_CLONES __attribute__((target_clones("avx512f", "avx2", "default")))
#define GS_VECTOR_LOOP __attribute__((target_clones("avx512f", "avx2", "default"), optimize("O3")))
#else   /* clang (the sanitizers' build): the plain code */
#define GS_VECTOR_CLONES
#define GS_VECTOR_LOOP
#endif
/* sum_i x_i t_i in eight interleaved partial sums (in clones, GS_VECTOR_LOOP: the same sums). */
double gs_dot(const double *x, const double *t, size_t n);
/* out[j] = gs_dot(x, t + j ld, n) * scale for the count indices j of idx, or j < count when idx
 * is NULL (the same bits as gs_dot, four rows at a time). */
void gs_dot_rows(const double *x, const double *t, size_t ld, size_t n, const size_t *idx, size_t count,
                 double scale, double *out);
/* An angle in degrees wrapped to [0, 360) and to [-180, 180). */
double gs_wrap360(double a_deg);
double gs_wrap180(double a_deg);
/* A decimal number at the start of s (leading blanks skipped, as strtod; a sign, digits, a
 * point, an exponent): its value in *v and the character after it, or NULL when s does not
 * start with one or it is not finite (hexadecimal, inf and nan are not decimal numbers). */
const char *gs_number_prefix(const char *s, double *v);
/* The whole of s is one finite decimal number (gs_number_prefix): 1 and *v, else 0. */
int gs_parse_number(const char *s, double *v);
/* qsort's comparison of doubles, ascending. */
int gs_cmp_double(const void *a, const void *b);
/* The median of v[0..n) (n >= 1; v is reordered): quickselect, the upper median for even n. */
float gs_median_f(float *v, size_t n);
/* The median of v[0..n) (v sorted in place), the mean of the middle two for even n; NaN for
 * n = 0. */
double gs_median_d(double *v, size_t n);

/* ------------------------------------------------------------------ threads */

#define GS_MAX_THREADS 64
/* OpenBLAS single-threaded while the program's own threads call it with small problems (its
 * threads gain nothing there and spin beside ours: the PSF fit's factorizations, a block of
 * pixels' SGEMMs): returns the thread count before, for gs_blas_restore. */
int gs_blas_serial(void);
void gs_blas_restore(int before);
/* threads > 0 as given, <= 0: the online CPUs; at most GS_MAX_THREADS. */
int gs_threads_resolve(int threads);
/* Part `part` of an index range: [begin, end). */
typedef gs_status (*gs_range_fn)(void *ctx, int part, size_t begin, size_t end);
/* fn over [0, n) split into P = min(gs_threads_resolve(threads), n) contiguous parts, part p
 * getting [n p / P, n (p + 1) / P), each on its own thread (part 0 on the caller's). The parts
 * must write disjoint outputs; the split depends only on n and P, and a caller whose result
 * does not depend on the split (per-row random streams, per-pixel sums in a fixed order) gets
 * the same bits on any number of threads. Returns the status of the lowest failing part with
 * its gs_detail() copied to the caller's thread. */
gs_status gs_parallel_for(int threads, size_t n, gs_range_fn fn, void *ctx);
/* fn over [0, n) in chunks of `chunk` indices (the last shorter; 0: n / 64 + 1, about 64
 * chunks) that P threads take in turn,
 * part = the thread's slot (0 on the caller's): a part gets any number of chunks, in rising
 * order, and on one thread (P = 1) the whole range in one call. For work that is uneven over
 * the range; a caller whose result does not depend on the split gets the same bits as with
 * gs_parallel_for. Returns the status of the lowest failing part (the others stop taking
 * chunks). */
gs_status gs_parallel_chunks(int threads, size_t n, size_t chunk, gs_range_fn fn, void *ctx);
/* The clock id's time in seconds (CLOCK_MONOTONIC for intervals, CLOCK_PROCESS_CPUTIME_ID for
 * CPU time). */
double gs_clock_s(clockid_t id);

/* ------------------------------------------------------------- AC (Eq. 1) */

/* Zero crossings of a uniformly sampled waveform x[0..n) at rate_hz, both directions. Each
 * sign change is first located by a local cubic through its 4 samples (exact for cubics), then,
 * when there are >= 3 crossings, refitted: a least-squares fit of a DC term and harmonics 1-3
 * of the local period (the median full period around the crossing, up to 25 either side) to
 * the ~one period of samples around it (at least 8), and the root of that fit. A cubic through
 * 4 samples at 400 Hz is off by ~1e-2 sample periods with a few % of 3rd harmonic, an error
 * that changes as slowly as the frequency; the fit's follows the noise. The mean of x is
 * removed first. hysteresis (in units of x, >= 0) is a Schmitt trigger: a crossing counts only once x
 * has gone from below -hysteresis to above +hysteresis (or back), so noise-level sign changes
 * are rejected; when noise makes several sign changes in one transition, the cubic's crossing is
 * the midpoint of the first and last (where the refit starts). Returns an allocated array of crossing times in seconds from
 * sample 0 (free(); NULL when there are none) and its length in *count; *rising_first is the
 * direction of the first crossing (+1 rising, -1 falling, 0 if none; they alternate).
 * A constant signal has no crossings (GS_OK, count 0). Non-finite samples are GS_ENUMERIC
 * naming the sample index. */
gs_status gs_zero_crossings(const double *x, size_t n, double rate_hz, double hysteresis,
                             double **t_s, size_t *count, int *rising_first);

/* Grid frequency from successive zero-crossing times t_s[0..n) (finite, increasing, n >= 3,
 * else GS_ENUMERIC / GS_EINVAL naming the index): per cycle f_i = 1/(2 Delta_i) with
 * Delta_i = t_{i+1} - t_i (Eq. 1), written to f_cycle_hz[0..n-1) unless NULL.
 * The robust mean uses full AC periods P_i = t_{i+2} - t_i (immune to the DC offset and even
 * harmonics that make half periods alternate), rejects periods whose frequency 1/P_i is more
 * than 5 robust sigmas (5 x 1.4826 MAD, at least 1e-9 of the median) from the median, and is
 * Eq. 1 on the mean accepted period: mean_hz = 1/mean(P_i) (a missing crossing rejects 2
 * periods, a spurious one up to 3). sigma_mean_hz is its standard error for independent errors in
 * the crossing times: the mean period telescopes to the crossings at the ends of each run of
 * accepted periods, and the crossing-time error is estimated from second differences
 * P_{i+2} - P_i, which cancel slow frequency wander. NaN when fewer than 2 such differences
 * exist (n < 6, or periods rejected); std_hz is NaN for a single period. The errors of neighbouring crossings may
 * correlate (gs_zero_crossings' fits share samples): their covariance, from successive second
 * differences (from at least 30 pairs, else 0; the correlation not below -1/2), is in the
 * standard error. On sampled mains-like waves with 1-3 % 2nd and 3rd
 * harmonics and noise, errors / sigma_mean_hz have an rms of 0.97-1.11 (0.64 with 16-bit
 * quantisation alone; eq1_sampled_harmonics_honest_error); on shared/data/mains mean_hz is
 * -1.9, 2.8 and -2.2 sigma_mean_hz from the fundamental's phase advance
 * (tests/independent/mains_oracle.py; ac_real_mains_*). */
typedef struct {
    double mean_hz;         /* robust mean frequency */
    double sigma_mean_hz;   /* standard error of mean_hz */
    double median_hz;       /* median per-period frequency */
    double std_hz;          /* standard deviation of accepted per-period frequencies */
    size_t periods;         /* full AC periods used */
    size_t rejected;        /* periods rejected as outliers (glitches, missing crossings) */
} gs_freq_stats;
gs_status gs_grid_frequency(const double *t_s, size_t n, double *f_cycle_hz,
                             gs_freq_stats *stats);

/* Frequency wander of a long recording (see shared/data/README.md): the accepted full periods
 * of gs_grid_frequency, each assigned to the window of window_s seconds (0 < window_s <= 10;
 * 1 s is the usual ENF resolution) holding its midpoint, give one frequency per window (Eq. 1
 * on the window's mean period; a window without periods is skipped). Then the mean and
 * standard deviation of that series, the standard deviation of its window-to-window changes,
 * and its autocorrelation (Pearson correlation of the pairs w, w + lag) at lags of 10 s and
 * 60 s (rounded to whole windows). Needs crossings spanning at least 120 s (GS_EINVAL).
 * On shared/data/mains step_sigma_hz is 1.57 / 1.62 / 1.61 mHz where the fundamental's phase
 * gives 1.56 / 1.60 / 1.61 (tests/independent/mains_oracle.py; sigma and the correlations
 * agree within 0.01 mHz and 0.001). */
typedef struct {
    double mean_hz;
    double sigma_hz;         /* std of the window-averaged frequency */
    double step_sigma_hz;    /* std of successive differences of that series */
    double corr_10s;         /* autocorrelation at lag 10 s */
    double corr_60s;         /* autocorrelation at lag 60 s */
    size_t windows;          /* complete windows in the span (including any skipped) */
} gs_wander;
gs_status gs_frequency_wander(const double *t_s, size_t n, double window_s, gs_wander *w);

/* Read a mono mains-voltage recording (WAV or any format libsndfile reads) as doubles (PCM is
 * scaled to [-1, 1), float samples are kept as they are). *x is allocated (free()).
 * GS_EIO if the file cannot be opened; GS_EFORMAT, with a detail naming the file and the field
 * or sample, for an empty file, an unrecognised header, a truncated WAV (declared RIFF or data
 * chunk size beyond the end of the file), a file with no samples, more than one channel, or a
 * non-finite sample. */
gs_status gs_mains_read(const char *path, double **x, size_t *n, double *rate_hz);

/* ------------------------------------------------------------ BRF (Eqs. 3-6) */

#define GS_MAX_BANDS 3
#define GS_BRF_N_DEFAULT 1024   /* high-resolution samples per flicker cycle */

/* A bulb response function: n samples over one flicker cycle per band, v[band * n + i] at
 * t = i/n * Delta, mean 1 per band (Eq. 4). The samples are those of a trigonometric
 * polynomial (band-limited to n/2 harmonics), which makes fractional shifts and window
 * integrals exact (gs_brf_shift, gs_brf_integrate). */
typedef struct {
    int n;        /* samples per cycle, >= 4 and even */
    int bands;    /* 1 (monochrome) or 3 (R, G, B) */
    double *v;    /* owned; bands * n values */
} gs_brf;

/* Allocate a zeroed BRF; release with gs_brf_release (which accepts a zeroed struct). */
gs_status gs_brf_init(gs_brf *b, int n, int bands);
void gs_brf_release(gs_brf *b);
/* Deep copy into an uninitialised *dst. */
gs_status gs_brf_copy(gs_brf *dst, const gs_brf *src);
/* Divide each band by its mean so the mean is 1 (Eq. 4); the means go to mean_out[] unless NULL.
 * A band whose mean is not finite and > 0 is GS_ENUMERIC. */
gs_status gs_brf_normalize(gs_brf *b, double *mean_out);
/* out = in delayed by shift_cycles (any real; 1 is the identity): out(t) = in(t - shift*Delta).
 * Exact on the trigonometric polynomial, so shifts compose. out must be initialised with the
 * same n and bands; out may equal in. */
gs_status gs_brf_shift(const gs_brf *in, double shift_cycles, gs_brf *out);
/* Eq. 5: the mean of the BRF (delayed by shift_cycles) over each of K windows
 * [k Delta/K, (k+1) Delta/K), k = 0..K-1, for every band: out[band * K + k]. Any K >= 2.
 * Exact integrals of the trigonometric polynomial; the mean over k stays 1. */
gs_status gs_brf_integrate(const gs_brf *b, double shift_cycles, int K, double *out);
/* DFT C[0..n/2] of x[0..n) (FFTW r2c convention: C_h = sum_j x_j e^{-2 pi i h j / n}).
 * (C only: C++ has no _Complex.) */
#ifndef __cplusplus
gs_status gs_brf_spectrum(const double *x, int n, _Complex double *C);
#endif
/* Percent flicker of one band: 100 (max - min) / (max + min) over the samples. */
double gs_brf_percent_flicker(const gs_brf *b, int band);

/* The BRF shift (cycles, in [0,1)) of grid phase phase_deg: phi/pi cycles modulo 1
 * (docs/design.md: 0, 120, 240 deg -> 0, 2/3, 1/3). */
double gs_phase_to_shift(double phase_deg);
/* Inverse: the grid phase in [0,360) deg whose shift is shift_cycles. */
double gs_shift_to_phase(double shift_cycles);
/* The phase class of a grid phase in degrees, the one rule of statistics, maps and exports:
 * 0, 1, 2 for 0/120/240 deg (within GS_PHASE_TOL_DEG, edges included), 3 for another finite
 * phase, -1 for NaN (unknown/ambiguous). The survey database's light_phase view repeats the
 * comparisons in SQL (tests/test_stats.c checks the two agree on every edge). */
#define GS_PHASE_TOL_DEG 20.0
int gs_phase_class(double phase_deg);

/* Eq. 6: chromaticity Q[b] = mean[b] / sum(mean), and the brightness sum(mean) returned.
 * Returns NaN (and leaves Q untouched) when the sum is not finite and > 0. */
double gs_chromaticity(const double *mean, int bands, double *Q);

/* --------------------------------------------------------------- DELIGHT */

typedef enum {
    GS_TECH_INCANDESCENT,
    GS_TECH_HALOGEN,
    GS_TECH_FLUORESCENT_MAGNETIC,
    GS_TECH_FLUORESCENT_ELECTRONIC,
    GS_TECH_CFL,
    GS_TECH_LED_CAPACITOR,
    GS_TECH_LED_LINEAR,
    GS_TECH_LED_PWM,
    GS_TECH_SODIUM_HP,
    GS_TECH_SODIUM_LP,
    GS_TECH_METAL_HALIDE,
    GS_TECH_MERCURY,
    GS_TECH_UNKNOWN,           /* measured, technology not known */
    GS_TECH_COUNT
} gs_tech;

/* Stable lower-case names used in files ("incandescent", "sodium_hp", ...). */
const char *gs_tech_name(gs_tech t);
/* GS_ENOTFOUND if name is not one of gs_tech_name's. */
gs_status gs_tech_parse(const char *name, gs_tech *t);

/* What the template's time axis is referenced to. */
typedef enum {
    GS_REF_VOLTAGE,   /* relative to the outlet voltage (DELIGHT's convention): phase usable */
    GS_REF_NONE,      /* shape only, no voltage reference: never used for phase decisions */
    GS_REF_UNLOCKED   /* flicker not locked to the mains (PWM): never used by Eq. 7 */
} gs_ref;
const char *gs_ref_name(gs_ref r);   /* "voltage", "none", "unlocked" */

#define GS_ID_MAX 48
#define GS_NAME_MAX 96
#define GS_SENSOR_MAX 32

#define GS_WATTS_MAX 1e5   /* a bulb's largest power, W (excluded) */
/* One DELIGHT entry: one bulb measured at one grid frequency with one sensor. */
typedef struct {
    char id[GS_ID_MAX];           /* bulb id, [A-Za-z0-9_.-]+; unique with grid_hz and sensor */
    gs_tech type;
    char name[GS_NAME_MAX];       /* human-readable; no control characters */
    double watts;                  /* electrical power, W (> 0 and < GS_WATTS_MAX; 0 if unknown) */
    int grid_hz;                   /* 50 or 60 */
    char sensor[GS_SENSOR_MAX];   /* "photodiode" (mono) or "rgb" (3 bands), or a user name */
    gs_ref ref;
    double chroma[GS_MAX_BANDS];  /* Eq. 6 chromaticity per band, sums to 1 (mono: 1) */
    gs_brf brf;                   /* owned by the entry */
} gs_bulb;

/* Release the BRF of a bulb (the struct itself is the caller's). */
void gs_bulb_release(gs_bulb *b);

/* A DELIGHT database in memory: an ordered collection of bulbs (opaque handle). */
typedef struct gs_delight gs_delight;
gs_delight *gs_delight_new(void);
void gs_delight_free(gs_delight *d);
/* Add a deep copy of *b. GS_EINVAL if (id, grid_hz, sensor) is already present, or if the
 * entry is inconsistent (bands vs sensor, chroma not summing to 1, BRF mean not 1). */
gs_status gs_delight_add(gs_delight *d, const gs_bulb *b);
size_t gs_delight_count(const gs_delight *d);
/* Borrowed pointer, valid until d changes or is freed; NULL when i is out of range. */
const gs_bulb *gs_delight_get(const gs_delight *d, size_t i);
/* First entry with this id (and grid_hz, bands when they are > 0), or NULL. */
const gs_bulb *gs_delight_find(const gs_delight *d, const char *id, int grid_hz, int bands);

/* The built-in DELIGHT substitute: physical models of each technology (docs/delight.md), with
 * parameters drawn deterministically inside the ranges of shared/BULBS.md; every bulb at 50 and
 * 60 Hz, with a monochrome ("photodiode") and an RGB ("rgb") entry; n samples per cycle. */
gs_status gs_delight_generate(gs_delight *d, int n);

/* SQLite storage (versioned schema, docs/delight.md; tables delight_meta, delight_bulbs,
 * delight_brf_bands). save replaces the file's DELIGHT tables in one transaction (a new file is
 * built under a temporary name and renamed into place) and refuses a file whose user_version
 * belongs to another schema; load appends the file's bulbs to d, and on
 * any error (GS_ENOTFOUND for a missing file, GS_EFORMAT for a file that is not a DELIGHT
 * database) adds nothing. */
#define GS_DELIGHT_SCHEMA_VERSION 1
gs_status gs_delight_save(const gs_delight *d, const char *path);
/* save into a new file only: when another process made path meanwhile, *raced = 1 and nothing
 * is written (GS_OK), for a caller that must then read that file first (gs_atomic_commit_new). */
gs_status gs_delight_save_new(const gs_delight *d, const char *path, int *raced);
gs_status gs_delight_load(gs_delight *d, const char *path);
/* The survey database's SQLite application_id ('GSDB', survey/survey.h): load names such a
 * file as one when it is given for a DELIGHT database. */
#define GS_SURVEY_DB_APPLICATION_ID 0x47534442
/* Both wait up to GS_DELIGHT_BUSY_MS for another process's transaction on the file. */
#define GS_DELIGHT_BUSY_MS 10000
/* SQLite's message for db's last failure into buf, with the system's error behind an I/O or
 * full-disk one ("disk I/O error (No space left on device)": a nearly full disk can fail as
 * either); "out of memory" for a NULL db. Returns buf. (The survey database's messages too.) */
struct sqlite3;
const char *gs_sqlite_errmsg(struct sqlite3 *db, char *buf, size_t size);
/* A new DELIGHT into *out (gs_delight_free; NULL on error): the file at path, or the built-in
 * database (gs_delight_generate, GS_BRF_N_DEFAULT samples) when path is NULL. */
gs_status gs_delight_open(const char *path, gs_delight **out);

/* CSV: header `bulb_id,type,name,watts,grid_hz,sensor,band,chromaticity,n,v0,...,v{n-1}`, one
 * row per bulb and band (band: mono, R, G, B); sensor is written "SENSOR/REF" (REF as in
 * gs_ref_name). Values are printed with %.17g, so a round trip is exact. The rows of one bulb
 * are consecutive; each row has its own n values (the header lists the largest n). import
 * appends to d; on any error nothing is added and the detail names file, line and field. */
gs_status gs_delight_export_csv(const gs_delight *d, FILE *out);
gs_status gs_delight_import_csv(gs_delight *d, const char *path);

/* ------------------------------------------------- measured bulbs (delight add) */

/* A photodiode recording turned into a BRF: the flicker period is found from the data, its
 * whole cycles are folded (each harmonic summed at the samples' exact phases, at any sample
 * rate) into n samples and normalised. With a voltage column (1-based column index > 0), time
 * zero is the voltage's first negative-to-positive crossing and the BRF is GS_REF_VOLTAGE;
 * without, GS_REF_NONE (shape only). A flicker frequency that is not twice a 50/60 Hz grid
 * (+-3 %) gives GS_REF_UNLOCKED (e.g. PWM). */
typedef struct {
    size_t samples;            /* rows read */
    double sample_rate_hz;
    double flicker_hz;         /* measured flicker frequency */
    double cycles;             /* flicker cycles covered by the recording */
    double percent_flicker;    /* of the folded, averaged waveform */
    int grid_hz;               /* 50 or 60 inferred from flicker_hz, 0 if unlocked */
    double clipped_share;      /* samples at the recording's largest value next to another there:
                                * a clipped light (its flicker then reads low); real recordings
                                * hold well under 1 % */
} gs_recording_info;
/* Reads `time,value[,voltage...]` CSV as oscilloscopes write it: UTF-8 BOM, `Key:value,`
 * metadata lines, a header that may run into the first sample, CRLF; uniform time steps.
 * Without a voltage column time zero is the first sample. The BRF keeps the harmonics that
 * its sample phases tell apart and that stand above the fold's noise (band-limited); a
 * waveform dipping below 0 (scope offset) is raised to a minimum of 0. A lamp without flicker above the noise gets a flat BRF and
 * flicker_hz NaN. Fills *out (id and name from the file name; type unknown: the caller's to set
 * afterwards; grid_hz 0 when the recording cannot tell, i.e. unlocked without a voltage column:
 * set it before gs_delight_add) and *info unless NULL. */
gs_status gs_recording_to_bulb(const char *path, int voltage_column, int n, gs_bulb *out,
                                gs_recording_info *info);

/* --------------------------------------------------------------------- PNG */

/* Decode the PNG held in buf[0..size) (libspng) into out: exactly width x height pixels of
 * `channels` (1 grey, 3 R G B interleaved) samples of `bits` (8: unsigned char, 16: unsigned
 * short, host-endian). A larger image is refused before anything is allocated. Every chunk's
 * length and CRC is checked and the file must reach IEND. name and ref (appended, may be "")
 * go into the detail: "NAME: truncated PNG: ...", "NAME: corrupt PNG: ...", "NAME: not a PNG
 * file ...", "NAME: PNG is 6x4 pixels: expected width x height = 5x4", "NAME: PNG has 8-bit
 * samples: expected 16-bit", "NAME: PNG colour type is RGB: expected grey (1 channel)", all
 * GS_EFORMAT. */
gs_status gs_png_decode(const unsigned char *buf, size_t size, const char *name, const char *ref,
                        int width, int height, int channels, int bits, void *out);
/* Encode width x height pixels of `channels` (1 or 3) samples of `bits` (8 or 16, host-endian)
 * as a PNG in memory: *png is malloc'd (the caller free()s it), *size its length. */
gs_status gs_png_encode(const void *pixels, int width, int height, int channels, int bits,
                        unsigned char **png, size_t *size);

/* ------------------------------------------------------------- float TIFF */

/* 32-bit IEEE float TIFF (libtiff), the light-transport images (docs/light-transport.md):
 * `pages` images of width x height pixels of `bands` (1 grey, 3 R G B in file order, i.e. file
 * band 1 is R) interleaved samples, pix[((page * height + y) * width + x) * bands + band];
 * uncompressed, one page per image (a multi-page file for pages > 1). NaN and Inf are stored as
 * they are. The write is atomic (gs_atomic_*); GS_EINVAL for sizes outside 1..65535 or other
 * band counts, GS_EIO when it cannot be written. */
gs_status gs_tiff_write_float(const char *path, const float *pix, int width, int height,
                              int bands, int pages);
/* Read such a file (any TIFF of 32-bit float samples, 1 or 3 per pixel, contiguous, every page
 * the same size): *pix is malloc'd (free()), laid out as above. GS_ENOTFOUND for a missing
 * file, GS_EFORMAT (naming the file, page and what was found) for anything else. */
gs_status gs_tiff_read_float(const char *path, int *width, int *height, int *bands, int *pages,
                             float **pix);

/* --------------------------------------------------------- capture directory */

/* A capture directory, format "gridsurvey-capture/1" (docs/formats.md is the specification):
 * capture.json plus K frames as 16-bit PNGs (grey for 1 band, RGB for 3), and optional 8-bit
 * grey HDR maps holding each pixel's halving count h (0..16): in that frame the pixel integrated
 * cycles / 2^h cycles, for all its bands (paper Sec. 6, the ACam's HDR loop). This is the one
 * reader and writer of the format; capture/ writes with it, recognize/ reads with it.
 *
 * Lifecycle: a gs_capture is a plain struct. Zero it, set the scalar fields, gs_capture_alloc
 * (and gs_capture_alloc_hdr for HDR maps), set frames[k].cycles and the pixels, then
 * gs_capture_write_frame for every k and gs_capture_write_json last. Or gs_capture_read.
 * Either way gs_capture_release frees everything (it accepts NULL and a zeroed struct). */
#define GS_CAPTURE_FORMAT "gridsurvey-capture/1"
/* The half periods of grids of 45 to 65 Hz (Eq. 1), what window_half_period_s may hold. */
#define GS_WINDOW_HALF_PERIOD_MIN_S (1.0 / 130.0)
#define GS_WINDOW_HALF_PERIOD_MAX_S (1.0 / 90.0)
#define GS_PATH_MAX 256
#define GS_MAX_HALVINGS 16

/* How a free-running capture's windows were timed (gs_capture.window_period). */
enum {
    GS_PERIOD_UNKNOWN = 0,   /* locked, or the capture does not say */
    GS_PERIOD_MEASURED,      /* the mean half period of the cycles before each exposure, as the
                              * firmware does: the windows move only with the grid's wander */
    GS_PERIOD_NOMINAL        /* the grid's nominal half period: the windows slip the same way
                              * in every frame */
};
/* "measured", "nominal", or NULL for GS_PERIOD_UNKNOWN (and any other value). */
const char *gs_period_name(int window_period);

typedef struct {
    char file[GS_PATH_MAX];      /* frame PNG in the directory: [A-Za-z0-9._-]+ ending ".png" */
    int k;                        /* window index 0..K-1: [k Delta/K, (k+1) Delta/K) */
    double cycles;                /* C, flicker cycles integrated before any HDR halving (> 0) */
    char hdr_map[GS_PATH_MAX];   /* 8-bit PNG of halving counts, "" when the frame has none */
    double grid_hz_measured;      /* mean grid frequency during the exposure, Hz, 45..65 (NaN:
                                   * unknown; file field "grid_hz_measured", optional) */
    double start_s;               /* the exposure's start, s from the capture's first exposure,
                                   * >= 0 (NaN: unknown; file field "start_s", optional) */
    double window_half_period_s;  /* free running: the fixed period the windows were timed with,
                                   * in the clock grid_hz_measured was measured with,
                                   * GS_WINDOW_HALF_PERIOD_MIN_S..MAX_S (NaN: unknown, or locked;
                                   * file field "window_half_period_s", optional, only with
                                   * locked false) */
    double window_drift_windows;  /* free running: how far the windows moved across the flicker
                                   * cycle during the exposure, the range of their offset from
                                   * each cycle's crossing over the C cycles, in windows (1/K
                                   * cycle), from the per-cycle crossings, >= 0 (NaN: unknown, or
                                   * locked; file field "window_drift_windows", optional, only
                                   * with locked false) */
} gs_frame_info;

typedef struct {
    int grid_hz;                  /* 50 or 60 */
    int K;                        /* frames per cycle, 2..1024 */
    int bands;                    /* 1 or 3 (R, G, B) */
    int width, height;            /* pixels, 1..32768 each */
    double saturation_dn;         /* raw level at or above which a sample is saturated,
                                   * (black_level_dn, 65536]; 65536: nothing saturates */
    double black_level_dn;        /* raw pedestal, [0, 65536) (file default 0) */
    double gain_e_per_dn;         /* electrons per DN for shot noise, >= 0 (0 = unknown: read
                                   * noise only; file default 0) */
    double read_noise_dn;         /* read noise std per sample and frame, DN, >= 0 (file
                                   * default 1) */
    int locked;                   /* 1 if AC-locked, else 0 (file default 1) */
    int window_period;            /* free running: how the windows' fixed period was chosen,
                                   * GS_PERIOD_* (file field "window_period": "measured" or
                                   * "nominal", optional, only with locked false; absent:
                                   * GS_PERIOD_UNKNOWN) */
    char utc[40];                 /* acquisition time, ISO 8601 (YYYY-MM-DDThh:mm:ss[.f](Z|+hh:mm)),
                                   * "" if unknown */
    gs_frame_info *frames;       /* K entries, frames[k].k == k (owned, malloc) */
    /* Pixels (owned, malloc; NULL until allocated or read):
     * raw[((k * height + y) * width + x) * bands + band] in DN as stored (black level included);
     * halvings[(k * height + y) * width + x] (0..16), or NULL if no frame has an HDR map (then
     * h = 0 everywhere; a frame without a map reads as h = 0). */
    unsigned short *raw;
    unsigned char *halvings;
    char *station_json;           /* the optional "station" object as compact JSON text (owned,
                                   * malloc) or NULL. Kept semantically verbatim: Jansson
                                   * re-serialises it (key order kept, reals to 17 digits). */
} gs_capture;

/* Read dir/capture.json and every frame and HDR map into *cap (its previous content is ignored
 * and not freed; on failure *cap is left zeroed). Everything is validated: GS_ENOTFOUND for a
 * missing capture.json or frame file, GS_EFORMAT for bad JSON ("DIR/capture.json:LINE:COL: JSON
 * syntax: ..."), a bad field ("DIR/capture.json:LINE: field frames[3].k: expected ..."), a
 * frame PNG that is truncated, not 16-bit, of the wrong colour type or size (the detail names
 * the file and the capture.json line that names it). */
gs_status gs_capture_read(const char *dir, gs_capture *cap);
/* How far the exposure windows of frame k moved across the flicker cycle over its exposure, in
 * windows (1/K cycle; against Eq. 5's): 0 for an AC-locked capture (its windows re-anchor at
 * every crossing); free running, the frame's window_drift_windows, else K C |2 P f - 1| from
 * its window_half_period_s P and grid_hz_measured f (Eq. 1: f = 1 / (2 Delta)), the net motion
 * from the first cycle to the last (a grid wandering within the exposure can take the windows
 * further and back: a lower bound); NaN when it lacks them. */
double gs_capture_frame_drift(const gs_capture *cap, int k);
/* The largest over the frames (*frame, may be NULL: which one; -1 when K is 0), NaN when a frame's
 * is (*frame: the first such). */
double gs_capture_window_drift(const gs_capture *cap, int *frame);
/* The same read, without taking the directory's lock: for a caller that holds it already (one
 * open and flock(2) less per read; srv_job_read, which holds it until the job ends). */
gs_status gs_capture_read_held(const char *dir, gs_capture *cap);
/* The capture directory's lock, an flock(2) of the directory (released by gs_capture_unlock, or
 * when the process ends, killed or not): exclusive for its one writer (capture/'s acquisition
 * loop), shared for readers (gs_capture_read takes one itself; hold one across a read, with
 * gs_capture_read_held, and anything else that reads the files, as `run` does through its
 * content key), so that no capture is read while another process acquires into it. It does not
 * wait: held by another, it fails (GS_EIO) in one line naming dir; *fd is the lock's
 * descriptor, -1 on failure. A shared lock that cannot be taken for another reason (a directory
 * without read permission, a file system without locks) is GS_OK with *fd = -1: the reader goes
 * on unlocked. */
gs_status gs_capture_lock(const char *dir, int exclusive, int *fd);
void gs_capture_unlock(int fd);
/* capture.json's utc (docs/formats.md), 1 if valid: ISO 8601 YYYY-MM-DDThh:mm:ss[.f+](Z|+hh:mm|
 * -hh:mm), shorter than 40 bytes; a scene's utc, written there, and a station's time_utc
 * (gis/station.c) are checked with it. */
int gs_capture_valid_utc(const char *s);
#define GS_CAPTURE_EXP_UTC "an ISO 8601 time like \"2017-07-21T22:05:00Z\" (at most 39 characters)"
/* Before allocating, gs_capture_read also checks that every named file is a regular file no
 * larger than a PNG of the declared size, and that the samples plus the working images of
 * recognition (these bytes per pixel and per sample, upper bounds of the peak resident memory
 * measured in docs/reliability.md) fit gs_mem_check's budget (GS_ELIMIT). */
#define GS_WORK_BYTES_PER_PIXEL 27
#define GS_WORK_BYTES_PER_SAMPLE 1
/* That check alone, for a capture of these sizes (hdr_maps: it has HDR maps): GS_ELIMIT in one
 * line naming source and the sizes. `run` asks it of a scene before rendering the capture. */
gs_status gs_capture_budget(const char *source, int width, int height, int bands, int K, int hdr_maps);
/* For a zeroed capture whose K, bands, width and height are set (GS_EINVAL otherwise, or if
 * frames, raw or halvings are already set): allocate frames (file "frame_NNN.png", k, cycles 0:
 * set them, hdr_map "", the timing fields NaN) and zeroed raw pixels. */
gs_status gs_capture_alloc(gs_capture *cap);
/* After gs_capture_alloc: allocate zeroed halvings and name every frame's map "hdr_NNN.png"
 * (unless already named). */
gs_status gs_capture_alloc_hdr(gs_capture *cap);
/* Write frame k as dir/frames[k].file (and its HDR map as dir/frames[k].hdr_map when that is
 * not "") atomically: a temporary file in dir, fsync, rename. Creates dir (one level) if needed.
 * GS_EINVAL for a bad k or name, halvings > 16, or a halved pixel in a frame without a map. */
gs_status gs_capture_write_frame(const char *dir, const gs_capture *cap, int k);
/* Write dir/capture.json atomically, after validating every field with the reader's rules
 * (GS_EINVAL naming the field). Frames must have been written first (GS_ENOTFOUND naming the
 * missing file), so a capture.json never names a file that is not there. */
gs_status gs_capture_write_json(const char *dir, const gs_capture *cap);
/* The camera noise model of docs/formats.md ("Meaning of a sample"), the one place every
 * estimator takes it from: a raw sample's variance, DN^2, is
 *   read_noise_dn^2 + 1/12 (quantisation of an integer sample) + max(raw - black, 0) / gain,
 * the last term absent when the gain is unknown (0); a per-cycle value (raw - black) 2^h / C
 * has that times (2^h / C)^2. */
typedef struct {
    double read_var_dn2;   /* read_noise_dn^2 + 1/12 */
    double inv_gain;       /* 1 / gain_e_per_dn, 0 when the gain is unknown */
    double black_dn;       /* black_level_dn */
} gs_noise;
gs_noise gs_capture_noise(const gs_capture *cap);
static inline double gs_noise_raw_var(const gs_noise *n, double raw_dn)
{
    double e = raw_dn - n->black_dn;
    return n->read_var_dn2 + (e > 0.0 ? e * n->inv_gain : 0.0);
}
/* GS_OK if every field of cap except the pixels follows docs/formats.md (frames must be set),
 * else GS_EINVAL with the detail "WHO: field F: expected E". */
gs_status gs_capture_check(const gs_capture *cap, const char *who);
/* Free frames, pixels and station_json and zero the struct. Accepts NULL. */
void gs_capture_release(gs_capture *cap);
/* The per-cycle intensity of one pixel sample, in DN per flicker cycle: black level removed,
 * divided by the cycles it integrated, (raw - black_level_dn) * (2^h / cycles). NaN when the
 * sample is saturated (raw >= saturation_dn), when an index is out of range or the capture has
 * no pixels. May be negative (noise below the black level). */
double gs_capture_value(const gs_capture *cap, int k, int y, int x, int band);
/* The mean over the K frames of every pixel's per-cycle value (gs_capture_value), bands
 * interleaved (out: width * height * bands). A saturated sample counts at the saturation level
 * when saturated_at_level, else makes its pixel's band NaN. */
void gs_capture_mean_image(const gs_capture *cap, int saturated_at_level, float *out);


#endif
