/* kit_csv.c - the format kit's CSV (RFC 4180 through libcsv): rows of NUL-terminated fields
 * with the line number each row ends on, quoted fields (commas, quotes, line breaks inside),
 * a UTF-8 byte-order mark skipped, CRLF or LF, blank lines skipped; and the writing of one
 * field, quoted only when it has to be. */
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
    if (!max_bytes) max_bytes = GS_FILE_MAX_DEFAULT;
    FILE *in = fopen(path, "rb");
    if (!in) {
        int e = errno;
        return gs_fail(e == ENOENT ? GS_ENOTFOUND : GS_EIO, "%s: cannot open: %s", path, strerror(e));
    }
    struct csv_parser p;
    if (csv_init(&p, CSV_APPEND_NULL) != 0) {
        fclose(in);
        return gs_fail(GS_ENOMEM, "%s: cannot start a CSV parser", path);
    }
    csv_reader r = {.path = path, .fn = fn, .ctx = ctx};
    char *line = NULL;
    size_t line_cap = 0, total = 0;
    ssize_t len;
    while (r.st == GS_OK && (len = getline(&line, &line_cap, in)) >= 0) {
        r.line++;
        total += (size_t)len;
        if (total > max_bytes) {
            r.st = gs_fail(GS_ELIMIT, "%s: larger than %zu bytes", path, max_bytes);
            break;
        }
        const char *s = line;
        if (r.line == 1 && len >= 3 && !memcmp(s, "\xEF\xBB\xBF", 3)) {
            s += 3;
            len -= 3;
        }
        if (csv_parse(&p, s, (size_t)len, on_field, on_row, &r) != (size_t)len && r.st == GS_OK)
            r.st = gs_fail(GS_EFORMAT, "%s:%zu: CSV syntax: %s", path, r.line,
                           csv_strerror(csv_error(&p)));
    }
    if (r.st == GS_OK && ferror(in)) r.st = gs_fail(GS_EIO, "%s: read error", path);
    if (r.st == GS_OK) csv_fini(&p, on_field, on_row, &r);   /* a last row without a newline */
    clear_row(&r);
    free(r.f);
    free(line);
    csv_free(&p);
    fclose(in);
    return r.st;
}

int gs_csv_write_field(FILE *out, const char *s)
{
    if (!strpbrk(s, ",\"\r\n")) return fputs(s, out) < 0 ? -1 : 0;
    return csv_fwrite(out, s, strlen(s)) == 0 ? 0 : -1;
}
