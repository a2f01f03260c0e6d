/* kit_file.c - the format kit's files: whole-file reads with a size cap, one-level directory
 * creation, path joins and atomic replacement (a temporary file beside the target, fsync,
 * rename), the one implementation every writer of the tool uses. */
#include "recognize/base/base.h"

#include <errno.h>
#include <nettle/sha2.h>
#include <fcntl.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

int gs_path_join(char *out, size_t cap, const char *dir, const char *name)
{
    int n = snprintf(out, cap, "%s/%s", dir, name);
    return n > 0 && (size_t)n < cap;
}

void gs_path_dir(const char *path, char *buf, size_t size)
{
    snprintf(buf, size, "%s", path);
    size_t n = strlen(buf);
    while (n > 1 && buf[n - 1] == '/') buf[--n] = '\0';
    char *slash = strrchr(buf, '/');
    if (!slash) snprintf(buf, size, ".");
    else if (slash == buf) buf[1] = '\0';
    else *slash = '\0';
}

void gs_path_base(const char *path, int strip_ext, char *buf, size_t size)
{
    char tmp[4096];
    snprintf(tmp, sizeof tmp, "%s", path);
    size_t n = strlen(tmp);
    while (n > 1 && tmp[n - 1] == '/') tmp[--n] = '\0';
    const char *slash = strrchr(tmp, '/');
    snprintf(buf, size, "%s", slash ? slash + 1 : tmp);
    if (strip_ext) {
        char *dot = strrchr(buf, '.');
        if (dot && dot != buf) *dot = '\0';
    }
}

gs_status gs_file_read(const char *path, size_t max_bytes, char **data, size_t *size)
{
    *data = NULL;
    if (size) *size = 0;
    if (!max_bytes) max_bytes = GS_FILE_MAX_DEFAULT;
    FILE *f = fopen(path, "rb");
    if (!f) {
        int e = errno;
        return gs_fail(e == ENOENT ? GS_ENOTFOUND : GS_EIO, "%s: cannot open: %s", path,
                       strerror(e));
    }
    gs_status st = GS_OK;
    size_t cap = 1 << 16, n = 0;
    char *b = malloc(cap);
    if (!b) st = gs_fail(GS_ENOMEM, "%s: cannot allocate a read buffer", path);
    while (st == GS_OK) {
        if (n + 1 >= cap) {
            if (cap > max_bytes) {
                st = gs_fail(GS_ELIMIT, "%s: larger than %zu bytes", path, max_bytes);
                break;
            }
            char *nb = cap > SIZE_MAX / 2 ? NULL : realloc(b, cap * 2);
            if (!nb) {
                st = gs_fail(GS_ENOMEM, "%s: cannot hold %zu bytes", path, cap * 2);
                break;
            }
            b = nb;
            cap *= 2;
        }
        size_t got = fread(b + n, 1, cap - 1 - n, f);
        n += got;
        if (got == 0) {
            if (ferror(f)) st = gs_fail(GS_EIO, "%s: read error", path);
            break;
        }
    }
    if (st == GS_OK && n > max_bytes) st = gs_fail(GS_ELIMIT, "%s: larger than %zu bytes", path, max_bytes);
    fclose(f);
    if (st != GS_OK) {
        free(b);
        return st;
    }
    b[n] = '\0';
    *data = b;
    if (size) *size = n;
    return GS_OK;
}

static void sha256_hex_digest(struct sha256_ctx *c, char hex[65])
{
    uint8_t d[SHA256_DIGEST_SIZE];
    sha256_digest(c, sizeof d, d);
    for (int i = 0; i < SHA256_DIGEST_SIZE; i++) snprintf(hex + 2 * i, 3, "%02x", d[i]);
}

void gs_sha256_hex(const void *data, size_t n, char hex[65])
{
    struct sha256_ctx c;
    sha256_init(&c);
    sha256_update(&c, n, data);
    sha256_hex_digest(&c, hex);
}

gs_status gs_sha256_file(const char *path, char hex[65])
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        int e = errno;
        return gs_fail(e == ENOENT ? GS_ENOTFOUND : GS_EIO, "%s: cannot open: %s", path, strerror(e));
    }
    struct sha256_ctx c;
    sha256_init(&c);
    unsigned char buf[1 << 16];
    size_t got;
    while ((got = fread(buf, 1, sizeof buf, f)) > 0) sha256_update(&c, got, buf);
    int bad = ferror(f);
    fclose(f);
    if (bad) return gs_fail(GS_EIO, "%s: read error", path);
    sha256_hex_digest(&c, hex);
    return GS_OK;
}

gs_status gs_dir_ensure(const char *dir)
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

gs_status gs_atomic_open(gs_atomic *a, const char *path, int want_stream)
{
    static atomic_uint seq;
    memset(a, 0, sizeof *a);
    if (!path || !*path) return gs_fail(GS_EINVAL, "empty output path");
    if (snprintf(a->path, sizeof a->path, "%s", path) >= (int)sizeof a->path)
        return gs_fail(GS_EINVAL, "%.200s...: path too long", path);
    /* ".NAME.tmp.PID.SEQ" in the target's directory, so the rename cannot cross file systems;
     * O_EXCL makes sure it is ours; mode 0666 lets the umask apply as usual */
    const char *slash = strrchr(path, '/');
    int dir_len = slash ? (int)(slash - path + 1) : 0;
    int fd = -1;
    for (int tries = 0; tries < 100 && fd < 0; tries++) {
        int n = snprintf(a->tmp, sizeof a->tmp, "%.*s.%s.tmp.%ld.%u", dir_len, path,
                         slash ? slash + 1 : path, (long)getpid(), atomic_fetch_add(&seq, 1u));
        if (n < 0 || (size_t)n >= sizeof a->tmp) {
            a->tmp[0] = '\0';
            return gs_fail(GS_EINVAL, "%.200s...: path too long", path);
        }
        fd = open(a->tmp, O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
        if (fd < 0 && errno != EEXIST) break;
    }
    if (fd < 0) {
        int e = errno;
        a->tmp[0] = '\0';
        return gs_fail(GS_EIO, "%s: cannot create a temporary file beside it: %s", path, strerror(e));
    }
    if (!want_stream) {
        close(fd);
        return GS_OK;
    }
    a->f = fdopen(fd, "wb");
    if (!a->f) {
        int e = errno;
        close(fd);
        unlink(a->tmp);
        a->tmp[0] = '\0';
        return gs_fail(GS_EIO, "%s: %s", path, strerror(e));
    }
    return GS_OK;
}

void gs_atomic_abort(gs_atomic *a)
{
    if (!a) return;
    if (a->f) fclose(a->f);
    a->f = NULL;
    if (a->tmp[0]) unlink(a->tmp);
    a->tmp[0] = '\0';
}

gs_status gs_atomic_commit(gs_atomic *a)
{
    if (a->f) {
        int bad = ferror(a->f) || fflush(a->f) != 0 || fsync(fileno(a->f)) != 0;
        int e = errno;
        if (fclose(a->f) != 0 && !bad) {
            bad = 1;
            e = errno;
        }
        a->f = NULL;
        if (bad) {
            gs_atomic_abort(a);
            return gs_fail(GS_EIO, "%s: write failed: %s", a->path, strerror(e));
        }
    } else {
        /* written by name (SQLite, PLplot): make it durable before the rename */
        int fd = open(a->tmp, O_RDONLY | O_CLOEXEC);
        int bad = fd < 0 || fsync(fd) != 0;
        int e = errno;
        if (fd >= 0) close(fd);
        if (bad) {
            gs_atomic_abort(a);
            return gs_fail(GS_EIO, "%s: cannot sync: %s", a->path, strerror(e));
        }
    }
    if (rename(a->tmp, a->path) != 0) {
        int e = errno;
        gs_atomic_abort(a);
        return gs_fail(GS_EIO, "%s: cannot replace it: %s", a->path,
                       strerror(e));
    }
    a->tmp[0] = '\0';
    return GS_OK;
}

gs_status gs_file_write_atomic(const char *path, const void *data, size_t size)
{
    gs_atomic a;
    gs_status st = gs_atomic_open(&a, path, 1);
    if (st != GS_OK) return st;
    if (size && fwrite(data, 1, size, a.f) != size) {
        int e = errno;
        gs_atomic_abort(&a);
        return gs_fail(GS_EIO, "%s: write error: %s", path, strerror(e));
    }
    return gs_atomic_commit(&a);
}
