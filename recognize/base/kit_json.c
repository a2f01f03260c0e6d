/* kit_json.c - the format kit's JSON: documents parsed by Jansson (duplicate keys refused) with
 * the line of every member and element, range-checked typed getters, one rule for unknown keys
 * and one message shape, "SOURCE:LINE: field PATH: ...", for every format of the tool.
 *
 * Jansson keeps no positions, so a small scanner walks the same (already valid) text once and
 * records the line of each member key and array element by its path ("lights[3].bulb"); the
 * paths live in one arena and are sorted on first lookup. */
#include "recognize/base/base.h"

#include <math.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

typedef struct {
    size_t path;   /* offset into the arena */
    int line;
} json_pos;

struct gs_json {
    char *source;          /* file name for messages (owned) */
    char *text;            /* the document text (owned) */
    size_t n;
    json_t *root;
    json_pos *pos;         /* every member and element, document order until sorted */
    size_t count, cap;
    char *arena;           /* NUL-terminated paths */
    size_t used, arena_cap;
    int sorted, oom;       /* oom: positions incomplete (messages then say the nearest known) */
};

/* ------------------------------------------------------------------ positions */

static void pos_add(gs_json *j, const char *path, int line)
{
    if (j->oom) return;
    size_t len = strlen(path) + 1;
    if (j->count == j->cap) {
        size_t nc = j->cap ? j->cap * 2 : 256;
        json_pos *np = realloc(j->pos, nc * sizeof *np);
        if (!np) {
            j->oom = 1;
            return;
        }
        j->pos = np;
        j->cap = nc;
    }
    if (j->used + len > j->arena_cap) {
        size_t nc = j->arena_cap ? j->arena_cap * 2 : 4096;
        while (nc < j->used + len) nc *= 2;
        char *na = realloc(j->arena, nc);
        if (!na) {
            j->oom = 1;
            return;
        }
        j->arena = na;
        j->arena_cap = nc;
    }
    memcpy(j->arena + j->used, path, len);
    j->pos[j->count].path = j->used;
    j->pos[j->count].line = line;
    j->count++;
    j->used += len;
}

typedef struct {
    gs_json *j;
    size_t i;
    int line;
} scanner;

static void scan_ws(scanner *s)
{
    while (s->i < s->j->n) {
        char c = s->j->text[s->i];
        if (c == '\n') s->line++;
        else if (c != ' ' && c != '\t' && c != '\r') break;
        s->i++;
    }
}

/* At a '"': skip the string; its raw content (escapes kept as written) into out if not NULL. */
static void scan_string(scanner *s, char *out, size_t cap)
{
    size_t o = 0;
    s->i++;
    while (s->i < s->j->n && s->j->text[s->i] != '"') {
        if (s->j->text[s->i] == '\\' && s->i + 1 < s->j->n) {
            if (out && o + 1 < cap) out[o++] = s->j->text[s->i];
            s->i++;
        }
        if (out && o + 1 < cap) out[o++] = s->j->text[s->i];
        s->i++;
    }
    if (out && cap) out[o] = '\0';
    s->i++;
}

static void scan_value(scanner *s, const char *path, int depth)
{
    scan_ws(s);
    if (s->i >= s->j->n || depth > 64) return;
    char c = s->j->text[s->i];
    if (c == '"') {
        scan_string(s, NULL, 0);
        return;
    }
    if (c != '{' && c != '[') {
        while (s->i < s->j->n && !strchr(",]} \t\r\n", s->j->text[s->i])) s->i++;
        return;
    }
    char close = c == '{' ? '}' : ']';
    size_t plen = strlen(path);
    char *child = malloc(plen + 280);
    if (!child) {
        s->j->oom = 1;
        return;
    }
    s->i++;
    for (int idx = 0;; idx++) {
        scan_ws(s);
        if (s->i >= s->j->n) break;
        if (s->j->text[s->i] == close) {
            s->i++;
            break;
        }
        size_t before = s->i;
        if (c == '{') {
            char key[256];
            int line = s->line;
            if (s->j->text[s->i] != '"') break;
            scan_string(s, key, sizeof key);
            snprintf(child, plen + 280, "%s%s%s", path, plen ? "." : "", key);
            pos_add(s->j, child, line);
            scan_ws(s);
            if (s->i < s->j->n && s->j->text[s->i] == ':') s->i++;
        } else {
            snprintf(child, plen + 280, "%s[%d]", path, idx);
            pos_add(s->j, child, s->line);
        }
        scan_value(s, child, depth + 1);
        scan_ws(s);
        if (s->i < s->j->n && s->j->text[s->i] == ',') s->i++;
        else if (s->i == before) break; /* no progress: not the JSON Jansson accepted */
    }
    free(child);
}

static const gs_json *sort_ctx; /* qsort has no context argument; lookups happen on one thread */

static int cmp_pos(const void *a, const void *b)
{
    const json_pos *x = a, *y = b;
    int c = strcmp(sort_ctx->arena + x->path, sort_ctx->arena + y->path);
    return c ? c : (x->path > y->path) - (x->path < y->path);   /* stable: first one wins */
}

static int find_line(gs_json *j, const char *path)
{
    if (!j->sorted) {
        sort_ctx = j;
        if (j->count) qsort(j->pos, j->count, sizeof *j->pos, cmp_pos);
        j->sorted = 1;
    }
    size_t lo = 0, hi = j->count;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (strcmp(j->arena + j->pos[mid].path, path) < 0) lo = mid + 1;
        else hi = mid;
    }
    return lo < j->count && !strcmp(j->arena + j->pos[lo].path, path) ? j->pos[lo].line : 0;
}

int gs_json_line(const gs_json *jc, const char *path)
{
    gs_json *j = (gs_json *)jc;   /* the lazy sort is not visible to the caller */
    if (!j || !path) return 1;
    char *p = strdup(path);
    if (!p) return 1;
    int line = 1;
    for (;;) {
        int l = find_line(j, p);
        if (l) {
            line = l;
            break;
        }
        char *dot = strrchr(p, '.'), *br = strrchr(p, '[');
        char *cut = dot > br ? dot : br;
        if (!cut) break;
        *cut = '\0';
    }
    free(p);
    return line;
}

/* ------------------------------------------------------------------ documents */

gs_status gs_json_parse(const char *text, size_t n, const char *source, gs_json **out)
{
    *out = NULL;
    if (!source) source = "JSON";
    gs_json *j = calloc(1, sizeof *j);
    if (j) {
        j->source = strdup(source);
        j->text = malloc(n + 1);
    }
    if (!j || !j->source || !j->text) {
        gs_json_free(j);
        return gs_fail(GS_ENOMEM, "%s: out of memory", source);
    }
    memcpy(j->text, text, n);
    j->text[n] = '\0';
    j->n = n;
    if (memchr(text, '\0', n)) {
        gs_json_free(j);
        return gs_fail(GS_EFORMAT, "%s: contains a NUL byte: not JSON text", source);
    }
    json_error_t err;
    j->root = json_loadb(text, n, JSON_REJECT_DUPLICATES, &err);
    if (!j->root) {
        gs_status st = gs_fail(GS_EFORMAT, "%s:%d:%d: JSON syntax: %s", source, err.line,
                               err.column, err.text);
        gs_json_free(j);
        return st;
    }
    scanner s = {j, 0, 1};
    scan_value(&s, "", 0);
    *out = j;
    return GS_OK;
}

gs_status gs_json_load(const char *path, size_t max_bytes, gs_json **out)
{
    *out = NULL;
    char *text;
    size_t n;
    gs_status st = gs_file_read(path, max_bytes, &text, &n);
    if (st != GS_OK) return st;
    st = gs_json_parse(text, n, path, out);
    free(text);
    return st;
}

void gs_json_free(gs_json *j)
{
    if (!j) return;
    json_decref(j->root);
    free(j->pos);
    free(j->arena);
    free(j->text);
    free(j->source);
    free(j);
}

json_t *gs_json_root(const gs_json *j)
{
    return j ? j->root : NULL;
}

const char *gs_json_source(const gs_json *j)
{
    return j ? j->source : "";
}

const char *gs_json_text(const gs_json *j, size_t *n)
{
    if (n) *n = j ? j->n : 0;
    return j ? j->text : "";
}

gs_status gs_json_fail(const gs_json *j, gs_status s, const char *path, const char *fmt, ...)
{
    char msg[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    return gs_fail(s, "%s:%d: field %s: %s", gs_json_source(j), gs_json_line(j, path), path, msg);
}

/* ------------------------------------------------------------------ getters */

void gs_json_path(char *out, size_t cap, const char *parent, const char *key)
{
    snprintf(out, cap, "%s%s%s", parent, parent && *parent ? "." : "", key);
}

int gs_json_key_is_extension(const char *key)
{
    return !strcmp(key, "comment") || !strcmp(key, "description") || !strncmp(key, "x_", 2);
}

gs_status gs_json_check_keys(const gs_json *j, json_t *obj, const char *path,
                             const char *const *allowed)
{
    const char *key;
    json_t *v;
    json_object_foreach(obj, key, v) {
        (void)v;
        int ok = gs_json_key_is_extension(key);
        for (const char *const *a = allowed; !ok && *a; a++) ok = !strcmp(key, *a);
        if (ok) continue;
        char p[512], list[1024] = "";
        gs_json_path(p, sizeof p, path, key);
        for (const char *const *a = allowed; *a; a++) {
            size_t u = strlen(list);
            snprintf(list + u, sizeof list - u, "%s%s", a == allowed ? "" : ", ", *a);
        }
        /* the extensions after the allowed keys, or alone when there are none */
        return gs_json_fail(j, GS_EFORMAT, p, "unknown field; expected one of: %s%scomment, "
                            "description, or an extension named x_...%s", list, *allowed ? " (or " : "",
                            *allowed ? ")" : "");
    }
    return GS_OK;
}

/* The member key of obj (NULL when obj is not an object or lacks it), its path in p. */
static json_t *member(json_t *obj, const char *parent, const char *key, char *p, size_t cap)
{
    gs_json_path(p, cap, parent, key);
    return json_is_object(obj) ? json_object_get(obj, key) : NULL;
}

static gs_status missing(const gs_json *j, const char *p, const char *expect)
{
    return gs_json_fail(j, GS_EFORMAT, p, "expected %s (the field is missing)", expect);
}

gs_status gs_json_get_num(const gs_json *j, json_t *obj, const char *path, const char *key,
                          int required, double def, double lo, double hi, const char *expect,
                          double *out)
{
    char p[512], range[128];
    snprintf(range, sizeof range, "a number from %g to %g", lo, hi);
    if (!expect) expect = range;
    json_t *v = member(obj, path, key, p, sizeof p);
    if (!v) {
        if (required) return missing(j, p, expect);
        *out = def;
        return GS_OK;
    }
    if (!json_is_number(v)) return gs_json_fail(j, GS_EFORMAT, p, "expected %s", expect);
    double x = json_number_value(v);
    if (!isfinite(x) || x < lo || x > hi)
        return gs_json_fail(j, GS_EFORMAT, p, "expected %s (got %g)", expect, x);
    *out = x;
    return GS_OK;
}

gs_status gs_json_get_int(const gs_json *j, json_t *obj, const char *path, const char *key,
                          int required, long long def, long long lo, long long hi,
                          const char *expect, long long *out)
{
    char p[512], range[128];
    snprintf(range, sizeof range, "an integer from %lld to %lld", lo, hi);
    if (!expect) expect = range;
    json_t *v = member(obj, path, key, p, sizeof p);
    if (!v) {
        if (required) return missing(j, p, expect);
        *out = def;
        return GS_OK;
    }
    if (!json_is_integer(v)) return gs_json_fail(j, GS_EFORMAT, p, "expected %s", expect);
    long long x = (long long)json_integer_value(v);
    if (x < lo || x > hi) return gs_json_fail(j, GS_EFORMAT, p, "expected %s (got %lld)", expect, x);
    *out = x;
    return GS_OK;
}

gs_status gs_json_get_bool(const gs_json *j, json_t *obj, const char *path, const char *key,
                           int required, int def, int *out)
{
    char p[512];
    json_t *v = member(obj, path, key, p, sizeof p);
    if (!v) {
        if (required) return missing(j, p, "true or false");
        *out = def;
        return GS_OK;
    }
    if (!json_is_boolean(v)) return gs_json_fail(j, GS_EFORMAT, p, "expected true or false");
    *out = json_is_true(v);
    return GS_OK;
}

gs_status gs_json_get_str(const gs_json *j, json_t *obj, const char *path, const char *key,
                          int required, const char *def, char *out, size_t cap)
{
    char p[512];
    json_t *v = member(obj, path, key, p, sizeof p);
    if (!v) {
        if (required) return missing(j, p, "a string");
        snprintf(out, cap, "%s", def ? def : "");
        return GS_OK;
    }
    if (!json_is_string(v)) return gs_json_fail(j, GS_EFORMAT, p, "expected a string");
    const char *s = json_string_value(v);
    if (strlen(s) >= cap)
        return gs_json_fail(j, GS_EFORMAT, p, "expected a string of at most %zu characters", cap - 1);
    snprintf(out, cap, "%s", s);
    return GS_OK;
}

gs_status gs_json_get_obj(const gs_json *j, json_t *obj, const char *path, const char *key,
                          int required, json_t **out)
{
    char p[512];
    json_t *v = member(obj, path, key, p, sizeof p);
    *out = NULL;
    if (!v) return required ? missing(j, p, "an object") : GS_OK;
    if (!json_is_object(v)) return gs_json_fail(j, GS_EFORMAT, p, "expected an object");
    *out = v;
    return GS_OK;
}

gs_status gs_json_get_num_array(const gs_json *j, json_t *obj, const char *path, const char *key,
                                size_t n, size_t max, double lo, double hi, double *out,
                                size_t *count)
{
    char p[512];
    json_t *v = member(obj, path, key, p, sizeof p);
    size_t len = json_is_array(v) ? json_array_size(v) : 0;
    if (!json_is_array(v) || (n && len != n) || (!n && (len < 1 || len > max))) {
        if (n) return gs_json_fail(j, GS_EFORMAT, p, "expected an array of %zu numbers from %g to %g", n, lo, hi);
        return gs_json_fail(j, GS_EFORMAT, p, "expected an array of 1 to %zu numbers from %g to %g", max, lo, hi);
    }
    for (size_t i = 0; i < len; i++) {
        json_t *x = json_array_get(v, i);
        double d = json_is_number(x) ? json_number_value(x) : NAN;
        if (!isfinite(d) || d < lo || d > hi) {
            char q[540];
            snprintf(q, sizeof q, "%s[%zu]", p, i);
            return gs_json_fail(j, GS_EFORMAT, q, "expected a number from %g to %g", lo, hi);
        }
        out[i] = d;
    }
    if (count) *count = len;
    return GS_OK;
}

/* ------------------------------------------------------------------ writing */

void gs_json_real(char *buf, size_t cap, double v)
{
    for (int prec = 1; prec <= 17; prec++) {
        snprintf(buf, cap, "%.*g", prec, v);
        if (strtod(buf, NULL) == v) return;
    }
}

void gs_text_printf(gs_text *t, const char *fmt, ...)
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
        size_t nc = t->cap ? t->cap : 1024;
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

void gs_text_json_string(gs_text *t, const char *s)
{
    gs_text_printf(t, "\"");
    for (; *s; s++) {
        unsigned char c = (unsigned char)*s;
        if (c == '"' || c == '\\') gs_text_printf(t, "\\%c", c);
        else if (c < 0x20) gs_text_printf(t, "\\u%04x", c);
        else gs_text_printf(t, "%c", c);
    }
    gs_text_printf(t, "\"");
}

static void text_json(gs_text *t, json_t *v, int depth)
{
    char num[40];
    if (depth > 64) { /* Jansson's parser stops at 2048; be bounded anyway */
        gs_text_printf(t, "null");
        return;
    }
    switch (json_typeof(v)) {
    case JSON_OBJECT: {
        const char *key;
        json_t *m;
        int first = 1;
        gs_text_printf(t, "{");
        json_object_foreach(v, key, m) {
            if (!first) gs_text_printf(t, ",");
            first = 0;
            gs_text_json_string(t, key);
            gs_text_printf(t, ":");
            text_json(t, m, depth + 1);
        }
        gs_text_printf(t, "}");
        break;
    }
    case JSON_ARRAY:
        gs_text_printf(t, "[");
        for (size_t i = 0; i < json_array_size(v); i++) {
            if (i) gs_text_printf(t, ",");
            text_json(t, json_array_get(v, i), depth + 1);
        }
        gs_text_printf(t, "]");
        break;
    case JSON_STRING: gs_text_json_string(t, json_string_value(v)); break;
    case JSON_INTEGER: gs_text_printf(t, "%" JSON_INTEGER_FORMAT, json_integer_value(v)); break;
    case JSON_REAL:
        gs_json_real(num, sizeof num, json_real_value(v));
        /* keep it a real: 35.0 stays 35.0, not the integer 35 */
        gs_text_printf(t, "%s%s", num, strpbrk(num, ".eE") ? "" : ".0");
        break;
    case JSON_TRUE: gs_text_printf(t, "true"); break;
    case JSON_FALSE: gs_text_printf(t, "false"); break;
    case JSON_NULL: gs_text_printf(t, "null"); break;
    }
}

void gs_text_json(gs_text *t, json_t *v)
{
    text_json(t, v, 0);
}

int gs_text_clean(const char *s)
{
    const unsigned char *p = (const unsigned char *)s;
    while (*p) {
        unsigned c = *p;
        int extra;
        if (c < 0x20 || c == 0x7f) return 0;
        if (c < 0x80) extra = 0;
        else if (c >= 0xc2 && c <= 0xdf) extra = 1;
        else if (c >= 0xe0 && c <= 0xef) extra = 2;
        else if (c >= 0xf0 && c <= 0xf4) extra = 3;
        else return 0;
        p++;
        for (int i = 0; i < extra; i++, p++)
            if ((*p & 0xc0) != 0x80) return 0;
    }
    return 1;
}
