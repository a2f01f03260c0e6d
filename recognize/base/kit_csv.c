/* kit_csv.c - the format kit's CSV (RFC 4180 through libcsv): rows of NUL-terminated fields
 * with the line number each row ends on, quoted fields (commas, quotes, line breaks inside),
 * a UTF-8 byte-order mark skipped, CRLF or LF, blank lines skipped, a NUL byte refused; and
 * the writing of one field, quoted only when it has to be. */
#include "recognize/base/base.h"

#include <csv.h>
#include <errno.h>
#include <stdlib.h>
#include <string.h>

typedef struct {
    const char *path;
    gs_csv_row_fn fn;
    void *ctx;
    char **f;             /* the row's fields, each malloc'd */
    size_t count, cap;
    size_t line;          /* the line being parsed */
    gs_status st;         /* the first failure (the row function's or ours) */
} csv_reader;

static void on_field(void *s, size_t len, void *data)
{
    csv_reader *r = data;
    if (r->st != GS_OK) return;
    if (r->count == r->cap) {
        size_t nc = r->cap ? 2 * r->cap : 64;
        char **nf = realloc(r->f, nc * sizeof *nf);
        if (!nf) {
            r->st = gs_fail(GS_ENOMEM, "%s:%zu: cannot hold a row of %zu fields", r->path, r->line, nc);
            return;
        }
        r->f = nf;
        r->cap = nc;
    }
    char *v = malloc(len + 1);
    if (!v) {
        r->st = gs_fail(GS_ENOMEM, "%s:%zu: cannot hold a field of %zu bytes", r->path, r->line, len);
        return;
    }
    if (len) memcpy(v, s, len);
    v[len] = '\0';
    r->f[r->count++] = v;
}

static void clear_row(csv_reader *r)
{
    for (size_t i = 0; i < r->count; i++) free(r->f[i]);
    r->count = 0;
}

static void on_row(int term, void *data)
{
    (void)term;
    csv_reader *r = data;
    if (r->st == GS_OK) r->st = r->fn(r->ctx, r->f, r->count, r->line);
    clear_row(r);
}

gs_status gs_csv_read(const char *path, size_t max_bytes, gs_csv_row_fn fn, void *ctx)
{
    /* the whole file first (gs_file_read: "-" is stdin, the size cap holds before a line is
     * parsed, so a file without newlines cannot grow a line without bound) */
    char *text;
    size_t size;
    gs_status st = gs_file_read(path, max_bytes, &text, &size);
    if (st != GS_OK) return st;
    /* a field is a C string: a NUL byte would end it early ("12<NUL>0.5" read as 12) */
    const char *nul = memchr(text, '\0', size);
    if (nul) {
        size_t line = 1;
        for (const char *c = text; c < nul; c++) line += *c == '\n';
        free(text);
        return gs_fail(GS_EFORMAT, "%s:%zu: a NUL byte: expected CSV text", path, line);
    }
    struct csv_parser p;
    if (csv_init(&p, CSV_APPEND_NULL) != 0) {
        free(text);
        return gs_fail(GS_ENOMEM, "%s: cannot start a CSV parser", path);
    }
    csv_reader r = {.path = path, .fn = fn, .ctx = ctx};
    const char *s = text, *end = text + size;
    if (size >= 3 && !memcmp(s, "\xEF\xBB\xBF", 3)) s += 3;
    while (r.st == GS_OK && s < end) {
        const char *nl = memchr(s, '\n', (size_t)(end - s));
        size_t len = nl ? (size_t)(nl - s) + 1 : (size_t)(end - s);
        r.line++;
        if (csv_parse(&p, s, len, on_field, on_row, &r) != len && r.st == GS_OK)
            r.st = gs_fail(GS_EFORMAT, "%s:%zu: CSV syntax: %s", path, r.line,
                           csv_strerror(csv_error(&p)));
        s += len;
    }
    if (r.st == GS_OK) csv_fini(&p, on_field, on_row, &r);   /* a last row without a newline */
    clear_row(&r);
    free(r.f);
    free(text);
    csv_free(&p);
    return r.st;
}

int gs_csv_write_field(FILE *out, const char *s)
{
    if (!strpbrk(s, ",\"\r\n")) return fputs(s, out) < 0 ? -1 : 0;
    return csv_fwrite(out, s, strlen(s)) == 0 ? 0 : -1;
}
