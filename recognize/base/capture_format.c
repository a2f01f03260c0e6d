/* capture_format.c - the capture directory, format "gridsurvey-capture/1" (docs/formats.md has
 * the full specification; this file is its one reader and writer).
 *
 * A capture is the ACam's K-frame sequence of one flicker cycle (paper Sec. 6): frame k
 * integrates window [k Delta/K, (k+1) Delta/K) of each of C cycles, and a pixel the HDR loop
 * halved h times integrated C / 2^h cycles. The directory holds capture.json (Jansson) and one
 * 16-bit PNG per frame (OpenCV through opencv_shim.cpp), plus optional 8-bit HDR maps of h.
 *
 * Reading checks everything before trusting it: JSON syntax (Jansson's line and column), every
 * field's type and range (the detail names the file, the JSON line of the field, the field and
 * the expected value; lines come from a small scanner over the same text, since Jansson keeps no
 * positions), k = 0..K-1 each once, and each PNG's structure (signature, chunk lengths within the
 * file, IHDR first, IEND present: a truncated file is named as such) and IHDR (size, bit depth,
 * colour type) before it is decoded. Writing validates with the same rules, so the writer never
 * produces a directory that the reader rejects, and replaces each file atomically (a temporary
 * name in the same directory, fsync, rename). */
#include "recognize/base/internal.h"

#include <errno.h>
#include <fcntl.h>
#include <jansson.h>
#include <math.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define CAPTURE_JSON "capture.json"
/* Ranges of the format (docs/formats.md). K: the ACam reaches 26 (paper Fig. 7); 1024 bounds
 * memory for a file that is wrong. Sides: 32768 pixels. Halvings: the ACam's DMD holds M = 96
 * masks, so at most floor(log2(M/2)) = 5..6 halvings (paper footnote 5); GS_MAX_HALVINGS = 16
 * leaves room. */
#define MAX_K 1024
#define MAX_SIDE 32768
#define MAX_SATURATION 65536.0
#define PATH_BUF 1024

/* ---------------------------------------------------------------- helpers */

/* dir + "/" + name into out; 0 if it does not fit. */
static int join(char *out, size_t cap, const char *dir, const char *name)
{
    int n = snprintf(out, cap, "%s/%s", dir, name);
    return n > 0 && (size_t)n < cap;
}

/* A frame or HDR-map file name: [A-Za-z0-9._-]+ ending in ".png", not starting with '.',
 * shorter than GS_PATH_MAX. No directories: the capture is one flat folder. */
static int valid_file_name(const char *s)
{
    size_t n = strnlen(s, GS_PATH_MAX);
    if (n < 5 || n >= GS_PATH_MAX || s[0] == '.' || strcmp(s + n - 4, ".png") != 0) return 0;
    for (size_t i = 0; i < n; i++) {
        char c = s[i];
        if (!((c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
              c == '.' || c == '_' || c == '-'))
            return 0;
    }
    return 1;
}

/* `count` decimal digits at s, as an int in [lo, hi]; 0 on failure. */
static int digits(const char *s, int count, int lo, int hi, int *out)
{
    int v = 0;
    for (int i = 0; i < count; i++) {
        if (s[i] < '0' || s[i] > '9') return 0;
        v = v * 10 + (s[i] - '0');
    }
    if (v < lo || v > hi) return 0;
    if (out) *out = v;
    return 1;
}

/* ISO 8601 date-time: YYYY-MM-DDThh:mm:ss[.f+](Z|+hh:mm|-hh:mm), shorter than 40 bytes. */
static int valid_utc(const char *s)
{
    size_t n = strnlen(s, 40);
    if (n >= 40 || n < 20) return 0;
    if (!digits(s, 4, 0, 9999, NULL) || s[4] != '-' || !digits(s + 5, 2, 1, 12, NULL) ||
        s[7] != '-' || !digits(s + 8, 2, 1, 31, NULL) || s[10] != 'T' ||
        !digits(s + 11, 2, 0, 23, NULL) || s[13] != ':' || !digits(s + 14, 2, 0, 59, NULL) ||
        s[16] != ':' || !digits(s + 17, 2, 0, 60, NULL))
        return 0;
    size_t i = 19;
    if (s[i] == '.') {
        i++;
        size_t start = i;
        while (s[i] >= '0' && s[i] <= '9') i++;
        if (i == start) return 0;
    }
    if (s[i] == 'Z') return s[i + 1] == '\0';
    if (s[i] != '+' && s[i] != '-') return 0;
    return digits(s + i + 1, 2, 0, 23, NULL) && s[i + 3] == ':' &&
           digits(s + i + 4, 2, 0, 59, NULL) && s[i + 6] == '\0';
}

/* The whole of a file into a malloc'd buffer. A missing file is GS_ENOTFOUND. `ref` (may be
 * "") is appended to the detail, e.g. " (capture.json:12: frames[3].file)". */
static gs_status slurp(const char *path, const char *ref, unsigned char **buf, size_t *size)
{
    *buf = NULL;
    *size = 0;
    FILE *f = fopen(path, "rb");
    if (!f) {
        int e = errno;
        return gs_fail(e == ENOENT ? GS_ENOTFOUND : GS_EIO, "%s: cannot open: %s%s", path,
                       strerror(e), ref);
    }
    gs_status st = GS_OK;
    size_t cap = 1 << 16, n = 0;
    unsigned char *b = malloc(cap);
    if (!b) st = gs_fail(GS_ENOMEM, "%s: cannot allocate a read buffer", path);
    while (st == GS_OK) {
        if (n == cap) {
            unsigned char *nb = cap > SIZE_MAX / 2 ? NULL : realloc(b, cap * 2);
            if (!nb) {
                st = gs_fail(GS_ENOMEM, "%s: cannot hold %zu bytes", path, cap * 2);
                break;
            }
            b = nb;
            cap *= 2;
        }
        size_t got = fread(b + n, 1, cap - n, f);
        n += got;
        if (got == 0) {
            if (ferror(f)) st = gs_fail(GS_EIO, "%s: read error%s", path, ref);
            break;
        }
    }
    fclose(f);
    if (st != GS_OK) {
        free(b);
        return st;
    }
    *buf = b;
    *size = n;
    return GS_OK;
}

/* Create dir if it does not exist (one level). */
static gs_status ensure_dir(const char *dir)
{
    struct stat sb;
    if (stat(dir, &sb) == 0) {
        if (S_ISDIR(sb.st_mode)) return GS_OK;
        return gs_fail(GS_EIO, "%s: exists and is not a directory", dir);
    }
    if (mkdir(dir, 0777) != 0 && errno != EEXIST)
        return gs_fail(GS_EIO, "%s: cannot create the directory: %s", dir, strerror(errno));
    return GS_OK;
}

/* Write data to dir/name atomically: a temporary file in the same directory (so rename cannot
 * cross file systems), fsync'd, then renamed over the target. Readers see the old file or the
 * new one, never a partial one; on failure the temporary file is removed. */
static gs_status write_atomic(const char *dir, const char *name, const void *data, size_t size)
{
    static atomic_uint seq;
    char path[PATH_BUF], tmp[PATH_BUF + 64];
    if (!join(path, sizeof path, dir, name))
        return gs_fail(GS_EINVAL, "%s/%s: path too long", dir, name);
    snprintf(tmp, sizeof tmp, "%s/.%s.tmp.%ld.%u", dir, name, (long)getpid(),
             atomic_fetch_add(&seq, 1u));
    int fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
    if (fd < 0) return gs_fail(GS_EIO, "%s: cannot create: %s", tmp, strerror(errno));
    const unsigned char *p = data;
    size_t left = size;
    gs_status st = GS_OK;
    while (left > 0) {
        ssize_t w = write(fd, p, left);
        if (w < 0) {
            if (errno == EINTR) continue;
            st = gs_fail(GS_EIO, "%s: write error: %s", tmp, strerror(errno));
            break;
        }
        p += w;
        left -= (size_t)w;
    }
    if (st == GS_OK && fsync(fd) != 0)
        st = gs_fail(GS_EIO, "%s: fsync: %s", tmp, strerror(errno));
    if (close(fd) != 0 && st == GS_OK) st = gs_fail(GS_EIO, "%s: close: %s", tmp, strerror(errno));
    if (st == GS_OK && rename(tmp, path) != 0)
        st = gs_fail(GS_EIO, "%s: cannot rename to %s: %s", tmp, path, strerror(errno));
    if (st != GS_OK) unlink(tmp);
    return st;
}

/* ------------------------------------------------------- capture validation */

/* Expected values, in the words of docs/formats.md. */
#define EXP_FORMAT "the string \"" GS_CAPTURE_FORMAT "\""
#define EXP_GRID "50 or 60 (an integer)"
#define EXP_K "an integer from 2 to 1024"
#define EXP_BANDS "1 or 3 (an integer)"
#define EXP_SIDE "an integer from 1 to 32768"
#define EXP_NONNEG "a finite number >= 0"
#define EXP_LOCKED "true or false"
#define EXP_UTC "an ISO 8601 time like \"2017-07-21T22:05:00Z\" (at most 39 characters)"
#define EXP_FILE "a file name of letters, digits, '.', '_' or '-' that ends in \".png\", does not " \
                 "start with '.' and has at most 255 characters"
#define EXP_CYCLES "a finite number > 0"
#define EXP_HZ_MEASURED "a finite number from 45 to 65 (Hz)"
#define EXP_START "a finite number >= 0 (s)"

/* One problem of a capture: the field (e.g. "frames[3].cycles") and the expected value. */
typedef struct {
    char field[64];
    char expect[320];
} problem;

static int set_problem(problem *pr, const char *field, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
static int set_problem(problem *pr, const char *field, const char *fmt, ...)
{
    snprintf(pr->field, sizeof pr->field, "%s", field);
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(pr->expect, sizeof pr->expect, fmt, ap);
    va_end(ap);
    return 0;
}

/* The geometry fields, which size the pixel arrays. 1 if valid. */
static int check_geometry(const gs_capture *c, problem *pr)
{
    if (c->K < 2 || c->K > MAX_K) return set_problem(pr, "K", EXP_K);
    if (c->bands != 1 && c->bands != 3) return set_problem(pr, "bands", EXP_BANDS);
    if (c->width < 1 || c->width > MAX_SIDE) return set_problem(pr, "width", EXP_SIDE);
    if (c->height < 1 || c->height > MAX_SIDE) return set_problem(pr, "height", EXP_SIDE);
    return 1;
}

/* Every field except the pixels and station_json: the rules of docs/formats.md. frames must hold
 * K entries. 1 if valid. */
static int check_capture(const gs_capture *c, problem *pr)
{
    if (c->grid_hz != 50 && c->grid_hz != 60) return set_problem(pr, "grid_hz", EXP_GRID);
    if (!check_geometry(c, pr)) return 0;
    if (!(c->black_level_dn >= 0 && c->black_level_dn < MAX_SATURATION))
        return set_problem(pr, "black_level", "a number >= 0 and < 65536");
    if (!(c->saturation_dn > c->black_level_dn && c->saturation_dn <= MAX_SATURATION))
        return set_problem(pr, "saturation", "a number > black_level (%.17g) and <= 65536",
                           c->black_level_dn);
    if (!(isfinite(c->gain_e_per_dn) && c->gain_e_per_dn >= 0))
        return set_problem(pr, "gain_e_per_dn", EXP_NONNEG);
    if (!(isfinite(c->read_noise_dn) && c->read_noise_dn >= 0))
        return set_problem(pr, "read_noise_dn", EXP_NONNEG);
    if (c->locked != 0 && c->locked != 1) return set_problem(pr, "locked", EXP_LOCKED);
    if (memchr(c->utc, '\0', sizeof c->utc) == NULL || (c->utc[0] && !valid_utc(c->utc)))
        return set_problem(pr, "utc", EXP_UTC);
    for (int k = 0; k < c->K; k++) {
        const gs_frame_info *f = &c->frames[k];
        char field[64];
        snprintf(field, sizeof field, "frames[%d].k", k);
        if (f->k != k) return set_problem(pr, field, "%d (frames are held in k order)", k);
        snprintf(field, sizeof field, "frames[%d].cycles", k);
        if (!(isfinite(f->cycles) && f->cycles > 0)) return set_problem(pr, field, EXP_CYCLES);
        snprintf(field, sizeof field, "frames[%d].grid_hz_measured", k);
        if (!isnan(f->grid_hz_measured) &&
            !(isfinite(f->grid_hz_measured) && f->grid_hz_measured >= 45 &&
              f->grid_hz_measured <= 65))
            return set_problem(pr, field, EXP_HZ_MEASURED);
        snprintf(field, sizeof field, "frames[%d].start_s", k);
        if (!isnan(f->start_s) && !(isfinite(f->start_s) && f->start_s >= 0))
            return set_problem(pr, field, EXP_START);
        snprintf(field, sizeof field, "frames[%d].file", k);
        if (!valid_file_name(f->file)) return set_problem(pr, field, EXP_FILE);
        snprintf(field, sizeof field, "frames[%d].hdr_map", k);
        if (memchr(f->hdr_map, '\0', sizeof f->hdr_map) == NULL ||
            (f->hdr_map[0] && !valid_file_name(f->hdr_map)))
            return set_problem(pr, field, "\"\" (no map) or " EXP_FILE);
        /* every file of the directory is named once */
        for (int j = 0; j < k; j++) {
            const gs_frame_info *g = &c->frames[j];
            if (strcmp(f->file, g->file) == 0 || strcmp(f->file, g->hdr_map) == 0 ||
                (f->hdr_map[0] && (strcmp(f->hdr_map, g->file) == 0 ||
                                   strcmp(f->hdr_map, g->hdr_map) == 0))) {
                snprintf(field, sizeof field, "frames[%d]", k);
                return set_problem(pr, field, "file names used by no other frame (frames[%d] "
                                   "names the same file)", j);
            }
        }
        if (f->hdr_map[0] && strcmp(f->file, f->hdr_map) == 0) {
            snprintf(field, sizeof field, "frames[%d].hdr_map", k);
            return set_problem(pr, field, "a file other than the frame's own");
        }
    }
    return 1;
}

gs_status gs_capture_check(const gs_capture *cap, const char *who)
{
    problem pr;
    if (!cap || !cap->frames) return gs_fail(GS_EINVAL, "%s: no capture or no frames table", who);
    if (!check_capture(cap, &pr))
        return gs_fail(GS_EINVAL, "%s: field %s: expected %s", who, pr.field, pr.expect);
    return GS_OK;
}

/* ------------------------------------------------- JSON line locator */

/* Jansson keeps no positions, so a scanner over the same (already valid) text records the line
 * of every member key and array element, by path: "K", "frames", "frames[3]", "frames[3].k". */
typedef struct {
    char path[64];
    int line;
} json_loc;

typedef struct {
    const char *s;
    size_t n, i;
    int line;
    json_loc *v;
    size_t count, cap;
} json_scan;

static void loc_add(json_scan *sc, const char *path, int line)
{
    if (sc->count == sc->cap) {
        size_t nc = sc->cap ? sc->cap * 2 : 64;
        json_loc *nv = realloc(sc->v, nc * sizeof *nv);
        if (!nv) return; /* lines are a convenience: without memory, errors say line 1 */
        sc->v = nv;
        sc->cap = nc;
    }
    snprintf(sc->v[sc->count].path, sizeof sc->v[sc->count].path, "%s", path);
    sc->v[sc->count].line = line;
    sc->count++;
}

static void scan_ws(json_scan *sc)
{
    while (sc->i < sc->n) {
        char c = sc->s[sc->i];
        if (c == '\n') sc->line++;
        else if (c != ' ' && c != '\t' && c != '\r') break;
        sc->i++;
    }
}

/* At a '"': skip the string, copying its raw content (escapes as written) into out. */
static void scan_string(json_scan *sc, char *out, size_t cap)
{
    size_t o = 0;
    sc->i++;
    while (sc->i < sc->n && sc->s[sc->i] != '"') {
        if (sc->s[sc->i] == '\\' && sc->i + 1 < sc->n) {
            if (out && o + 1 < cap) out[o++] = sc->s[sc->i];
            sc->i++;
        }
        if (out && o + 1 < cap) out[o++] = sc->s[sc->i];
        sc->i++;
    }
    if (out && cap) out[o] = '\0';
    sc->i++;
}

static void scan_value(json_scan *sc, const char *path, int depth)
{
    scan_ws(sc);
    if (sc->i >= sc->n || depth > 64) return;
    char c = sc->s[sc->i];
    if (c == '{' || c == '[') {
        char close = c == '{' ? '}' : ']';
        sc->i++;
        for (int idx = 0;; idx++) {
            scan_ws(sc);
            if (sc->i >= sc->n) return;
            if (sc->s[sc->i] == close) {
                sc->i++;
                return;
            }
            char child[64];
            if (c == '{') {
                char key[48];
                int line = sc->line;
                if (sc->s[sc->i] != '"') return;
                scan_string(sc, key, sizeof key);
                snprintf(child, sizeof child, "%s%s%s", path, *path ? "." : "", key);
                loc_add(sc, child, line);
                scan_ws(sc);
                if (sc->i < sc->n && sc->s[sc->i] == ':') sc->i++;
            } else {
                snprintf(child, sizeof child, "%s[%d]", path, idx);
                scan_ws(sc);
                loc_add(sc, child, sc->line);
            }
            size_t before = sc->i;
            scan_value(sc, child, depth + 1);
            scan_ws(sc);
            if (sc->i < sc->n && sc->s[sc->i] == ',') sc->i++;
            else if (sc->i == before) return; /* no progress: not the JSON Jansson accepted */
        }
    }
    if (c == '"') {
        scan_string(sc, NULL, 0);
        return;
    }
    while (sc->i < sc->n && !strchr(",]} \t\r\n", sc->s[sc->i])) sc->i++;
}

/* The line of a path, or of its nearest enclosing element; 1 for the document. */
static int loc_line(const json_scan *sc, const char *path)
{
    char p[64];
    snprintf(p, sizeof p, "%s", path);
    for (;;) {
        for (size_t i = 0; i < sc->count; i++)
            if (strcmp(sc->v[i].path, p) == 0) return sc->v[i].line;
        char *dot = strrchr(p, '.'), *br = strrchr(p, '[');
        char *cut = dot > br ? dot : br;
        if (!cut) return 1;
        *cut = '\0';
    }
}

/* A growable text buffer. */
typedef struct {
    char *s;
    size_t n, cap;
    int oom;
} text_buf;

static void tb_printf(text_buf *t, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void tb_printf(text_buf *t, const char *fmt, ...)
{
    if (t->oom) return;
    for (;;) {
        va_list ap;
        va_start(ap, fmt);
        int need = vsnprintf(t->s ? t->s + t->n : NULL, t->s ? t->cap - t->n : 0, fmt, ap);
        va_end(ap);
        if (need < 0) {
            t->oom = 1;
            return;
        }
        if (t->s && (size_t)need < t->cap - t->n) {
            t->n += (size_t)need;
            return;
        }
        size_t nc = (t->cap ? t->cap : 1024);
        while (nc < t->n + (size_t)need + 1) nc *= 2;
        char *ns = realloc(t->s, nc);
        if (!ns) {
            t->oom = 1;
            return;
        }
        t->s = ns;
        t->cap = nc;
    }
}

/* The shortest %g form of v that reads back as exactly v. */
static void fmt_real(char *buf, size_t cap, double v)
{
    for (int prec = 1; prec <= 17; prec++) {
        snprintf(buf, cap, "%.*g", prec, v);
        if (strtod(buf, NULL) == v) return;
    }
}

/* A JSON string literal (the names here are restricted, but escape anyway). */
static void tb_string(text_buf *t, const char *s)
{
    tb_printf(t, "\"");
    for (; *s; s++) {
        unsigned char c = (unsigned char)*s;
        if (c == '"' || c == '\\') tb_printf(t, "\\%c", c);
        else if (c < 0x20) tb_printf(t, "\\u%04x", c);
        else tb_printf(t, "%c", c);
    }
    tb_printf(t, "\"");
}

/* Compact JSON text of a Jansson value with the shortest round-trip form of every real (Jansson
 * itself prints 17 digits: 32.79 would come back as 32.789999999999999). Key order is kept. */
static void tb_json(text_buf *t, json_t *v, int depth)
{
    char num[40];
    if (depth > 64) { /* Jansson's parser stops at 2048; be bounded anyway */
        tb_printf(t, "null");
        return;
    }
    switch (json_typeof(v)) {
    case JSON_OBJECT: {
        const char *key;
        json_t *m;
        int first = 1;
        tb_printf(t, "{");
        json_object_foreach(v, key, m) {
            if (!first) tb_printf(t, ",");
            first = 0;
            tb_string(t, key);
            tb_printf(t, ":");
            tb_json(t, m, depth + 1);
        }
        tb_printf(t, "}");
        break;
    }
    case JSON_ARRAY:
        tb_printf(t, "[");
        for (size_t i = 0; i < json_array_size(v); i++) {
            if (i) tb_printf(t, ",");
            tb_json(t, json_array_get(v, i), depth + 1);
        }
        tb_printf(t, "]");
        break;
    case JSON_STRING: tb_string(t, json_string_value(v)); break;
    case JSON_INTEGER: tb_printf(t, "%" JSON_INTEGER_FORMAT, json_integer_value(v)); break;
    case JSON_REAL:
        fmt_real(num, sizeof num, json_real_value(v));
        /* keep it a real: 35.0 stays 35.0, not the integer 35 */
        tb_printf(t, "%s%s", num, strpbrk(num, ".eE") ? "" : ".0");
        break;
    case JSON_TRUE: tb_printf(t, "true"); break;
    case JSON_FALSE: tb_printf(t, "false"); break;
    case JSON_NULL: tb_printf(t, "null"); break;
    }
}

/* The station object as compact JSON (malloc'd), or NULL when out of memory. */
static char *station_text(json_t *obj)
{
    text_buf t = {0};
    tb_json(&t, obj, 0);
    if (t.oom) {
        free(t.s);
        return NULL;
    }
    return t.s;
}

/* ------------------------------------------------------------------ reading */

typedef struct {
    const char *json_path;   /* DIR/capture.json */
    json_scan sc;
    int *pos;                /* pos[k]: position of frame k in the frames array (owned) */
} reader;

/* "FILE:LINE: field F: expected E" */
static gs_status bad_field(const reader *r, const char *field, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
static gs_status bad_field(const reader *r, const char *field, const char *fmt, ...)
{
    char expect[400];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(expect, sizeof expect, fmt, ap);
    va_end(ap);
    return gs_fail(GS_EFORMAT, "%s:%d: field %s: expected %s", r->json_path,
                   loc_line(&r->sc, field), field, expect);
}

static gs_status get_int(const reader *r, json_t *obj, const char *key, const char *field,
                         int required, int dflt, long long lo, long long hi, const char *expect,
                         int *out)
{
    json_t *v = json_object_get(obj, key);
    if (!v) {
        if (required) return bad_field(r, field, "%s (the field is missing)", expect);
        *out = dflt;
        return GS_OK;
    }
    if (!json_is_integer(v) || json_integer_value(v) < lo || json_integer_value(v) > hi)
        return bad_field(r, field, "%s", expect);
    *out = (int)json_integer_value(v);
    return GS_OK;
}

/* A JSON number (integer or real); the range is checked by check_capture. */
static gs_status get_number(const reader *r, json_t *obj, const char *key, const char *field,
                            int required, double dflt, const char *expect, double *out)
{
    json_t *v = json_object_get(obj, key);
    if (!v) {
        if (required) return bad_field(r, field, "%s (the field is missing)", expect);
        *out = dflt;
        return GS_OK;
    }
    if (!json_is_number(v)) return bad_field(r, field, "%s", expect);
    *out = json_number_value(v);
    return GS_OK;
}

static gs_status get_file_name(const reader *r, json_t *obj, const char *key, const char *field,
                               int required, char *out)
{
    json_t *v = json_object_get(obj, key);
    if (!v) {
        if (required) return bad_field(r, field, EXP_FILE " (the field is missing)");
        out[0] = '\0';
        return GS_OK;
    }
    if (!json_is_string(v) || !valid_file_name(json_string_value(v)))
        return bad_field(r, field, required ? EXP_FILE : "\"\" (no map) or " EXP_FILE);
    snprintf(out, GS_PATH_MAX, "%s", json_string_value(v));
    return GS_OK;
}

/* Only the format's keys, and "x_..." extensions (ignored). */
static gs_status check_keys(const reader *r, json_t *obj, const char *prefix,
                            const char *const *keys)
{
    const char *key;
    json_t *v;
    json_object_foreach(obj, key, v) {
        (void)v;
        int known = strncmp(key, "x_", 2) == 0;
        for (int i = 0; keys[i] && !known; i++) known = strcmp(key, keys[i]) == 0;
        if (!known) {
            char field[64];
            snprintf(field, sizeof field, "%s%s", prefix, key);
            return bad_field(r, field, "no such field (a field of " GS_CAPTURE_FORMAT
                             ", or an extension named x_...)");
        }
    }
    return GS_OK;
}

static const char *const top_keys[] = {
    "format", "grid_hz", "K", "bands", "width", "height", "saturation", "black_level",
    "gain_e_per_dn", "read_noise_dn", "locked", "utc", "station", "frames", NULL};
static const char *const frame_keys[] = {"file", "k", "cycles", "hdr_map", "grid_hz_measured",
                                         "start_s", NULL};

/* Fill the scalar fields and the frames table of cap from the parsed document. */
static gs_status parse_capture(reader *r, json_t *root, gs_capture *cap)
{
    gs_status st;
    if (!json_is_object(root)) return bad_field(r, "(document)", "a JSON object");
    json_t *fmt = json_object_get(root, "format");
    if (!fmt) return bad_field(r, "format", EXP_FORMAT " (the field is missing)");
    if (!json_is_string(fmt) || strcmp(json_string_value(fmt), GS_CAPTURE_FORMAT) != 0)
        return bad_field(r, "format", EXP_FORMAT);
    if ((st = check_keys(r, root, "", top_keys)) != GS_OK) return st;
    if ((st = get_int(r, root, "grid_hz", "grid_hz", 1, 0, 50, 60, EXP_GRID, &cap->grid_hz)) ||
        (st = get_int(r, root, "K", "K", 1, 0, 2, MAX_K, EXP_K, &cap->K)) ||
        (st = get_int(r, root, "bands", "bands", 1, 0, 1, 3, EXP_BANDS, &cap->bands)) ||
        (st = get_int(r, root, "width", "width", 1, 0, 1, MAX_SIDE, EXP_SIDE, &cap->width)) ||
        (st = get_int(r, root, "height", "height", 1, 0, 1, MAX_SIDE, EXP_SIDE, &cap->height)) ||
        (st = get_number(r, root, "saturation", "saturation", 1, 0,
                         "a number > black_level and <= 65536", &cap->saturation_dn)) ||
        (st = get_number(r, root, "black_level", "black_level", 0, 0, "a number >= 0 and < 65536",
                         &cap->black_level_dn)) ||
        (st = get_number(r, root, "gain_e_per_dn", "gain_e_per_dn", 0, 0, EXP_NONNEG,
                         &cap->gain_e_per_dn)) ||
        (st = get_number(r, root, "read_noise_dn", "read_noise_dn", 0, 1, EXP_NONNEG,
                         &cap->read_noise_dn)))
        return st;
    json_t *v = json_object_get(root, "locked");
    if (v && !json_is_boolean(v)) return bad_field(r, "locked", EXP_LOCKED);
    cap->locked = v ? json_is_true(v) : 1;
    v = json_object_get(root, "utc");
    if (v) {
        if (!json_is_string(v) || !valid_utc(json_string_value(v)))
            return bad_field(r, "utc", EXP_UTC);
        snprintf(cap->utc, sizeof cap->utc, "%s", json_string_value(v));
    }
    v = json_object_get(root, "station");
    if (v) {
        if (!json_is_object(v)) return bad_field(r, "station", "a JSON object");
        cap->station_json = station_text(v);
        if (!cap->station_json)
            return gs_fail(GS_ENOMEM, "%s: cannot copy the station object", r->json_path);
    }

    json_t *frames = json_object_get(root, "frames");
    if (!frames || !json_is_array(frames) || json_array_size(frames) != (size_t)cap->K)
        return bad_field(r, "frames", "an array of K = %d frame objects (%s)", cap->K,
                         !frames ? "the field is missing"
                         : !json_is_array(frames) ? "not an array" : "wrong length");
    cap->frames = calloc((size_t)cap->K, sizeof *cap->frames);
    int *seen = r->pos = malloc((size_t)cap->K * sizeof *seen);
    if (!cap->frames || !seen)
        return gs_fail(GS_ENOMEM, "%s: cannot hold %d frames", r->json_path, cap->K);
    for (int k = 0; k < cap->K; k++) seen[k] = -1;
    for (int i = 0; i < cap->K && st == GS_OK; i++) {
        json_t *f = json_array_get(frames, (size_t)i);
        char field[64], prefix[32];
        snprintf(prefix, sizeof prefix, "frames[%d].", i);
        snprintf(field, sizeof field, "frames[%d]", i);
        if (!json_is_object(f)) {
            st = bad_field(r, field, "an object with file, k and cycles");
            break;
        }
        if ((st = check_keys(r, f, prefix, frame_keys)) != GS_OK) break;
        int k;
        gs_frame_info info;
        memset(&info, 0, sizeof info);
        snprintf(field, sizeof field, "frames[%d].k", i);
        char expect_k[64];
        snprintf(expect_k, sizeof expect_k, "an integer from 0 to K-1 = %d", cap->K - 1);
        if ((st = get_int(r, f, "k", field, 1, 0, 0, cap->K - 1, expect_k, &k)) != GS_OK) break;
        if (seen[k] >= 0) {
            st = bad_field(r, field, "each k from 0 to %d exactly once (k = %d is also "
                           "frames[%d].k)", cap->K - 1, k, seen[k]);
            break;
        }
        seen[k] = i;
        info.k = k;
        snprintf(field, sizeof field, "frames[%d].cycles", i);
        if ((st = get_number(r, f, "cycles", field, 1, 0, EXP_CYCLES, &info.cycles)) != GS_OK)
            break;
        if (!(isfinite(info.cycles) && info.cycles > 0)) {
            st = bad_field(r, field, EXP_CYCLES);
            break;
        }
        snprintf(field, sizeof field, "frames[%d].file", i);
        if ((st = get_file_name(r, f, "file", field, 1, info.file)) != GS_OK) break;
        snprintf(field, sizeof field, "frames[%d].hdr_map", i);
        json_t *hm = json_object_get(f, "hdr_map");
        if (hm && json_is_string(hm) && json_string_value(hm)[0] == '\0') info.hdr_map[0] = '\0';
        else if ((st = get_file_name(r, f, "hdr_map", field, 0, info.hdr_map)) != GS_OK) break;
        /* optional; the ranges are checked by check_capture */
        snprintf(field, sizeof field, "frames[%d].grid_hz_measured", i);
        if ((st = get_number(r, f, "grid_hz_measured", field, 0, NAN, EXP_HZ_MEASURED,
                             &info.grid_hz_measured)) != GS_OK)
            break;
        snprintf(field, sizeof field, "frames[%d].start_s", i);
        if ((st = get_number(r, f, "start_s", field, 0, NAN, EXP_START, &info.start_s)) != GS_OK)
            break;
        cap->frames[k] = info;
    }
    if (st == GS_OK) {
        problem pr;
        if (!check_capture(cap, &pr)) {
            /* check_capture names frames by k; the file names them by array position */
            int idx;
            char field[64];
            if (sscanf(pr.field, "frames[%d]", &idx) == 1 && idx >= 0 && idx < cap->K) {
                const char *rest = strchr(pr.field, ']') + 1;
                snprintf(field, sizeof field, "frames[%d]%s", seen[idx], rest);
            } else {
                snprintf(field, sizeof field, "%s", pr.field);
            }
            st = bad_field(r, field, "%s", pr.expect);
        }
    }
    return st;
}

/* ------------------------------------------------------------------- PNG */

/* Read dir/file, which must be a width x height PNG of `channels` channels (grey or RGB) with
 * `bits` bits per sample, into out (R, G, B order). */
static gs_status read_png(const char *dir, const char *file, const char *ref, int width,
                          int height, int channels, int bits, void *out)
{
    char path[PATH_BUF];
    if (!join(path, sizeof path, dir, file)) return gs_fail(GS_EINVAL, "%s/%s: path too long", dir, file);
    unsigned char *buf;
    size_t n;
    gs_status st = slurp(path, ref, &buf, &n);
    if (st != GS_OK) return st;
    st = gs_png_decode(buf, n, path, ref, width, height, channels, bits, out);
    free(buf);
    return st;
}

gs_status gs_capture_read(const char *dir, gs_capture *cap)
{
    if (!dir || !cap) return gs_fail(GS_EINVAL, "gs_capture_read: NULL argument");
    memset(cap, 0, sizeof *cap);
    reader r;
    memset(&r, 0, sizeof r);
    char json_path[PATH_BUF];
    if (!join(json_path, sizeof json_path, dir, CAPTURE_JSON))
        return gs_fail(GS_EINVAL, "%s: path too long", dir);
    r.json_path = json_path;

    unsigned char *text;
    size_t n;
    gs_status st = slurp(json_path, "", &text, &n);
    if (st != GS_OK) return st;
    json_error_t err;
    json_t *root = json_loadb((const char *)text, n, JSON_REJECT_DUPLICATES, &err);
    if (!root) {
        free(text);
        return gs_fail(GS_EFORMAT, "%s:%d:%d: JSON syntax: %s", json_path, err.line, err.column,
                       err.text);
    }
    r.sc.s = (const char *)text;
    r.sc.n = n;
    r.sc.line = 1;
    scan_value(&r.sc, "", 0);

    st = parse_capture(&r, root, cap);
    json_decref(root);

    /* the pixels: frames in k order, then the HDR maps */
    size_t plane = (size_t)cap->width * (size_t)cap->height;
    for (int k = 0; st == GS_OK && k < cap->K; k++) {
        char ref[160], field[64];
        snprintf(field, sizeof field, "frames[%d].file", r.pos[k]);
        snprintf(ref, sizeof ref, " (%s:%d: %s)", CAPTURE_JSON, loc_line(&r.sc, field), field);
        if (!cap->raw) {
            cap->raw = calloc(plane * (size_t)cap->K * (size_t)cap->bands, sizeof *cap->raw);
            if (!cap->raw) {
                st = gs_fail(GS_ENOMEM, "%s: cannot hold %d frames of %dx%dx%d samples",
                             json_path, cap->K, cap->width, cap->height, cap->bands);
                break;
            }
        }
        st = read_png(dir, cap->frames[k].file, ref, cap->width, cap->height, cap->bands, 16,
                      cap->raw + plane * (size_t)cap->bands * (size_t)k);
        if (st == GS_OK && cap->frames[k].hdr_map[0]) {
            if (!cap->halvings) {
                cap->halvings = calloc(plane * (size_t)cap->K, 1);
                if (!cap->halvings) {
                    st = gs_fail(GS_ENOMEM, "%s: cannot hold the HDR maps", json_path);
                    break;
                }
            }
            unsigned char *h = cap->halvings + plane * (size_t)k;
            snprintf(field, sizeof field, "frames[%d].hdr_map", r.pos[k]);
            snprintf(ref, sizeof ref, " (%s:%d: %s)", CAPTURE_JSON, loc_line(&r.sc, field), field);
            st = read_png(dir, cap->frames[k].hdr_map, ref, cap->width, cap->height, 1, 8, h);
            for (size_t p = 0; st == GS_OK && p < plane; p++)
                if (h[p] > GS_MAX_HALVINGS)
                    st = gs_fail(GS_EFORMAT, "%s/%s: pixel (x %zu, y %zu) holds %d halvings: "
                                 "expected 0 to %d%s", dir, cap->frames[k].hdr_map,
                                 p % (size_t)cap->width, p / (size_t)cap->width, h[p],
                                 GS_MAX_HALVINGS, ref);
        }
    }
    free(r.sc.v);
    free(r.pos);
    free(text);
    if (st != GS_OK) gs_capture_release(cap);
    return st;
}

/* ------------------------------------------------------------------ writing */

gs_status gs_capture_alloc(gs_capture *cap)
{
    if (!cap) return gs_fail(GS_EINVAL, "gs_capture_alloc: NULL capture");
    problem pr;
    if (!check_geometry(cap, &pr))
        return gs_fail(GS_EINVAL, "gs_capture_alloc: field %s: expected %s", pr.field, pr.expect);
    if (cap->frames || cap->raw || cap->halvings)
        return gs_fail(GS_EINVAL, "gs_capture_alloc: the capture is already allocated "
                       "(gs_capture_release it first)");
    size_t plane = (size_t)cap->width * (size_t)cap->height;
    cap->frames = calloc((size_t)cap->K, sizeof *cap->frames);
    cap->raw = calloc(plane * (size_t)cap->K * (size_t)cap->bands, sizeof *cap->raw);
    if (!cap->frames || !cap->raw) {
        free(cap->frames);
        free(cap->raw);
        cap->frames = NULL;
        cap->raw = NULL;
        return gs_fail(GS_ENOMEM, "gs_capture_alloc: cannot hold %d frames of %dx%dx%d samples",
                       cap->K, cap->width, cap->height, cap->bands);
    }
    for (int k = 0; k < cap->K; k++) {
        snprintf(cap->frames[k].file, GS_PATH_MAX, "frame_%03d.png", k);
        cap->frames[k].k = k;
        cap->frames[k].grid_hz_measured = NAN;
        cap->frames[k].start_s = NAN;
    }
    return GS_OK;
}

gs_status gs_capture_alloc_hdr(gs_capture *cap)
{
    if (!cap || !cap->frames || !cap->raw)
        return gs_fail(GS_EINVAL, "gs_capture_alloc_hdr: call gs_capture_alloc first");
    if (cap->halvings) return gs_fail(GS_EINVAL, "gs_capture_alloc_hdr: already allocated");
    cap->halvings = calloc((size_t)cap->width * (size_t)cap->height * (size_t)cap->K, 1);
    if (!cap->halvings) return gs_fail(GS_ENOMEM, "gs_capture_alloc_hdr: cannot hold the maps");
    for (int k = 0; k < cap->K; k++)
        if (!cap->frames[k].hdr_map[0])
            snprintf(cap->frames[k].hdr_map, GS_PATH_MAX, "hdr_%03d.png", k);
    return GS_OK;
}

static gs_status write_png(const char *dir, const char *file, const void *pixels, int width,
                           int height, int channels, int depth16)
{
    unsigned char *png;
    size_t size;
    gs_status st = gs_png_encode(pixels, width, height, channels, depth16 ? 16 : 8, &png, &size);
    if (st != GS_OK) return gs_fail(st, "%s/%s: %s", dir, file, gs_detail());
    st = write_atomic(dir, file, png, size);
    free(png);
    return st;
}

gs_status gs_capture_write_frame(const char *dir, const gs_capture *cap, int k)
{
    if (!dir || !cap || !cap->frames || !cap->raw)
        return gs_fail(GS_EINVAL, "gs_capture_write_frame: NULL directory, capture or pixels");
    problem pr;
    if (!check_geometry(cap, &pr))
        return gs_fail(GS_EINVAL, "%s: gs_capture_write_frame: field %s: expected %s", dir,
                       pr.field, pr.expect);
    if (k < 0 || k >= cap->K)
        return gs_fail(GS_EINVAL, "%s: gs_capture_write_frame: k = %d: expected 0 to %d", dir, k,
                       cap->K - 1);
    const gs_frame_info *f = &cap->frames[k];
    if (!valid_file_name(f->file))
        return gs_fail(GS_EINVAL, "%s: field frames[%d].file: expected %s", dir, k, EXP_FILE);
    size_t plane = (size_t)cap->width * (size_t)cap->height;
    const unsigned char *h = cap->halvings ? cap->halvings + plane * (size_t)k : NULL;
    if (f->hdr_map[0]) {
        if (!valid_file_name(f->hdr_map) || strcmp(f->hdr_map, f->file) == 0)
            return gs_fail(GS_EINVAL, "%s: field frames[%d].hdr_map: expected %s, not the "
                           "frame's own", dir, k, EXP_FILE);
        if (!h)
            return gs_fail(GS_EINVAL, "%s: field frames[%d].hdr_map names a map but the capture "
                           "has no halvings (gs_capture_alloc_hdr)", dir, k);
        for (size_t p = 0; p < plane; p++)
            if (h[p] > GS_MAX_HALVINGS)
                return gs_fail(GS_EINVAL, "%s: frame %d pixel (x %zu, y %zu): %d halvings: "
                               "expected 0 to %d", dir, k, p % (size_t)cap->width,
                               p / (size_t)cap->width, h[p], GS_MAX_HALVINGS);
    } else if (h) {
        for (size_t p = 0; p < plane; p++)
            if (h[p])
                return gs_fail(GS_EINVAL, "%s: frame %d pixel (x %zu, y %zu) is halved but field "
                               "frames[%d].hdr_map is \"\" (the halvings would be lost)", dir, k,
                               p % (size_t)cap->width, p / (size_t)cap->width, k);
    }
    gs_status st = ensure_dir(dir);
    if (st == GS_OK)
        st = write_png(dir, f->file, cap->raw + plane * (size_t)cap->bands * (size_t)k,
                       cap->width, cap->height, cap->bands, 1);
    if (st == GS_OK && f->hdr_map[0])
        st = write_png(dir, f->hdr_map, h, cap->width, cap->height, 1, 0);
    return st;
}

gs_status gs_capture_write_json(const char *dir, const gs_capture *cap)
{
    if (!dir || !cap || !cap->frames)
        return gs_fail(GS_EINVAL, "gs_capture_write_json: NULL directory, capture or frames");
    problem pr;
    if (!check_capture(cap, &pr))
        return gs_fail(GS_EINVAL, "%s/%s (writing): field %s: expected %s", dir, CAPTURE_JSON,
                       pr.field, pr.expect);
    char *station = NULL;
    if (cap->station_json) {
        json_error_t err;
        json_t *st_obj = json_loads(cap->station_json, JSON_REJECT_DUPLICATES, &err);
        if (!st_obj || !json_is_object(st_obj)) {
            json_decref(st_obj);
            return gs_fail(GS_EINVAL, "%s/%s (writing): field station: expected a JSON object "
                           "(%s)", dir, CAPTURE_JSON, st_obj ? "not an object" : err.text);
        }
        station = station_text(st_obj);
        json_decref(st_obj);
        if (!station) return gs_fail(GS_ENOMEM, "gs_capture_write_json: station");
    }
    /* the frames must be there: a capture.json never names a missing file */
    for (int k = 0; k < cap->K; k++) {
        const char *names[2] = {cap->frames[k].file, cap->frames[k].hdr_map};
        for (int i = 0; i < 2; i++) {
            char path[PATH_BUF];
            struct stat sb;
            if (!names[i][0]) continue;
            if (!join(path, sizeof path, dir, names[i]) || stat(path, &sb) != 0) {
                free(station);
                return gs_fail(GS_ENOTFOUND, "%s: missing: write every frame "
                               "(gs_capture_write_frame) before capture.json", path);
            }
        }
    }
    text_buf t = {0};
    char num[40];
    tb_printf(&t, "{\n  \"format\": \"%s\",\n  \"grid_hz\": %d,\n  \"K\": %d,\n  \"bands\": %d,\n"
              "  \"width\": %d,\n  \"height\": %d,\n", GS_CAPTURE_FORMAT, cap->grid_hz, cap->K,
              cap->bands, cap->width, cap->height);
    fmt_real(num, sizeof num, cap->saturation_dn);
    tb_printf(&t, "  \"saturation\": %s,\n", num);
    fmt_real(num, sizeof num, cap->black_level_dn);
    tb_printf(&t, "  \"black_level\": %s,\n", num);
    fmt_real(num, sizeof num, cap->gain_e_per_dn);
    tb_printf(&t, "  \"gain_e_per_dn\": %s,\n", num);
    fmt_real(num, sizeof num, cap->read_noise_dn);
    tb_printf(&t, "  \"read_noise_dn\": %s,\n", num);
    tb_printf(&t, "  \"locked\": %s,\n", cap->locked ? "true" : "false");
    if (cap->utc[0]) {
        tb_printf(&t, "  \"utc\": ");
        tb_string(&t, cap->utc);
        tb_printf(&t, ",\n");
    }
    if (station) tb_printf(&t, "  \"station\": %s,\n", station);
    tb_printf(&t, "  \"frames\": [\n");
    for (int k = 0; k < cap->K; k++) {
        const gs_frame_info *f = &cap->frames[k];
        tb_printf(&t, "    {\"file\": ");
        tb_string(&t, f->file);
        fmt_real(num, sizeof num, f->cycles);
        tb_printf(&t, ", \"k\": %d, \"cycles\": %s", f->k, num);
        if (f->hdr_map[0]) {
            tb_printf(&t, ", \"hdr_map\": ");
            tb_string(&t, f->hdr_map);
        }
        if (!isnan(f->grid_hz_measured)) {
            fmt_real(num, sizeof num, f->grid_hz_measured);
            tb_printf(&t, ", \"grid_hz_measured\": %s", num);
        }
        if (!isnan(f->start_s)) {
            fmt_real(num, sizeof num, f->start_s);
            tb_printf(&t, ", \"start_s\": %s", num);
        }
        tb_printf(&t, "}%s\n", k + 1 < cap->K ? "," : "");
    }
    tb_printf(&t, "  ]\n}\n");
    free(station);
    gs_status st;
    if (t.oom) st = gs_fail(GS_ENOMEM, "gs_capture_write_json: cannot build the text");
    else st = ensure_dir(dir);
    if (st == GS_OK) st = write_atomic(dir, CAPTURE_JSON, t.s, t.n);
    free(t.s);
    return st;
}

void gs_capture_release(gs_capture *cap)
{
    if (!cap) return;
    free(cap->frames);
    free(cap->raw);
    free(cap->halvings);
    free(cap->station_json);
    memset(cap, 0, sizeof *cap);
}

double gs_capture_value(const gs_capture *cap, int k, int y, int x, int band)
{
    if (!cap || !cap->raw || !cap->frames || k < 0 || k >= cap->K || y < 0 ||
        y >= cap->height || x < 0 || x >= cap->width || band < 0 || band >= cap->bands)
        return NAN;
    size_t p = ((size_t)k * (size_t)cap->height + (size_t)y) * (size_t)cap->width + (size_t)x;
    double raw = cap->raw[p * (size_t)cap->bands + (size_t)band];
    double cycles = cap->frames[k].cycles;
    if (!(raw < cap->saturation_dn) || !(cycles > 0) || !isfinite(cycles)) return NAN;
    int h = cap->halvings ? cap->halvings[p] : 0;
    /* the same expression as blobs.c: (raw - black) * (2^h / cycles) */
    return (raw - cap->black_level_dn) * (ldexp(1.0, h) / cycles);
}
