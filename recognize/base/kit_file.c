/* kit_file.c - the format kit's files: whole-file reads with a size cap, one-level directory
 * creation, path joins and atomic replacement (a temporary file beside the target, fsync,
 * rename), the one implementation every reader and writer of the tool uses. Unix filter rules:
 * "-" is stdin or stdout; inputs must be regular files; an output that exists and is not a
 * regular file (device, FIFO) is written through, a symlink's target is replaced, never the link. */
#include "recognize/base/base.h"

#include <errno.h>
#include <nettle/sha2.h>
#include <fcntl.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
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

/* The detail for a path that is not a regular file. */
static gs_status not_regular(const char *path, mode_t m)
{
    const char *what = S_ISDIR(m) ? "a directory" : S_ISFIFO(m) ? "a FIFO" : S_ISCHR(m) ? "a character device"
                       : S_ISBLK(m) ? "a block device" : S_ISSOCK(m) ? "a socket" : "not a regular file";
    return gs_fail(GS_EINVAL, "%s: %s: expected a regular file (or - for standard input)", path, what);
}

gs_status gs_input_check(const char *path)
{
    struct stat sb;
    if (!path || !*path) return gs_fail(GS_EINVAL, "empty input path");
    if (stat(path, &sb) != 0) {
        int e = errno;
        return gs_fail(e == ENOENT ? GS_ENOTFOUND : GS_EIO, "%s: cannot open: %s", path, strerror(e));
    }
    return S_ISREG(sb.st_mode) ? GS_OK : not_regular(path, sb.st_mode);
}

gs_status gs_input_open(const char *path, FILE **f, long long *size)
{
    *f = NULL;
    if (size) *size = -1;
    if (!path || !*path) return gs_fail(GS_EINVAL, "empty input path");
    if (!strcmp(path, "-")) {
        *f = stdin;
        return GS_OK;
    }
    /* O_NONBLOCK: opening a FIFO must not wait for a writer before it is refused */
    int fd = open(path, O_RDONLY | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0) {
        int e = errno;
        return gs_fail(e == ENOENT ? GS_ENOTFOUND : GS_EIO, "%s: cannot open: %s", path, strerror(e));
    }
    struct stat sb;
    int e = fstat(fd, &sb) != 0 ? errno : 0;
    if (e || !S_ISREG(sb.st_mode)) {
        gs_status st = e ? gs_fail(GS_EIO, "%s: cannot stat: %s", path, strerror(e))
                         : not_regular(path, sb.st_mode);
        close(fd);
        return st;
    }
    int fl = fcntl(fd, F_GETFL);
    if (fl < 0 || fcntl(fd, F_SETFL, fl & ~O_NONBLOCK) != 0 || !(*f = fdopen(fd, "rb"))) {
        e = errno;
        close(fd);
        return gs_fail(GS_EIO, "%s: cannot open: %s", path, strerror(e));
    }
    if (size) *size = (long long)sb.st_size;
    return GS_OK;
}

void gs_input_close(FILE *f)
{
    if (f && f != stdin) fclose(f);
}

gs_status gs_file_read(const char *path, size_t max_bytes, char **data, size_t *size)
{
    *data = NULL;
    if (size) *size = 0;
    if (!max_bytes) max_bytes = GS_FILE_MAX_DEFAULT;
    FILE *f;
    long long known;
    gs_status st = gs_input_open(path, &f, &known);
    if (st != GS_OK) return st;
    if (known > (long long)max_bytes) {
        gs_input_close(f);
        return gs_fail(GS_ELIMIT, "%s: larger than %zu bytes", path, max_bytes);
    }
    size_t cap = known >= 0 ? (size_t)known + 1 : (size_t)1 << 16, n = 0;
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
    gs_input_close(f);
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
    FILE *f;
    gs_status st = gs_input_open(path, &f, NULL);
    if (st != GS_OK) return st;
    struct sha256_ctx c;
    sha256_init(&c);
    unsigned char buf[1 << 16];
    size_t got;
    while ((got = fread(buf, 1, sizeof buf, f)) > 0) sha256_update(&c, got, buf);
    int bad = ferror(f);
    gs_input_close(f);
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

/* A scratch file for a by-name writer whose target is not a regular file (stdout, a device, a
 * FIFO): written by name, then copied to out_fd by gs_atomic_commit. */
static gs_status scratch_open(gs_atomic *a)
{
    const char *dir = getenv("TMPDIR");
    if (!dir || !*dir) dir = "/tmp";
    if (snprintf(a->tmp, sizeof a->tmp, "%s/gridsurvey-out.XXXXXX", dir) >= (int)sizeof a->tmp) {
        a->tmp[0] = '\0';
        return gs_fail(GS_EINVAL, "%s: TMPDIR too long", a->path);
    }
    int fd = mkstemp(a->tmp);
    if (fd < 0) {
        int e = errno;
        a->tmp[0] = '\0';
        return gs_fail(GS_EIO, "%s: cannot create a scratch file in %s: %s", a->path, dir, strerror(e));
    }
    close(fd);
    return GS_OK;
}

/* Write-through targets: "-" (stdout) and existing non-regular files (devices, FIFOs, and
 * symlinks that lead to one or to nothing). The target is opened as it is, never replaced. */
static gs_status direct_open(gs_atomic *a, int want_stream, int is_stdout)
{
    a->direct = 1;
    if (is_stdout) {
        a->out_fd = STDOUT_FILENO;
    } else {
        a->out_fd = open(a->path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
        if (a->out_fd < 0) {
            int e = errno;
            return gs_fail(GS_EIO, "%s: cannot open for writing: %s", a->path, strerror(e));
        }
    }
    if (!want_stream) {
        gs_status st = scratch_open(a);
        if (st != GS_OK) gs_atomic_abort(a);
        return st;
    }
    if (is_stdout) {
        a->f = stdout;
        return GS_OK;
    }
    a->f = fdopen(a->out_fd, "wb");
    if (!a->f) {
        int e = errno;
        gs_atomic_abort(a);
        return gs_fail(GS_EIO, "%s: %s", a->path, strerror(e));
    }
    a->out_fd = -1;   /* owned by f */
    return GS_OK;
}

gs_status gs_atomic_open(gs_atomic *a, const char *path, int want_stream)
{
    static atomic_uint seq;
    memset(a, 0, sizeof *a);
    a->out_fd = -1;
    if (!path || !*path) return gs_fail(GS_EINVAL, "empty output path");
    if (snprintf(a->path, sizeof a->path, "%s", path) >= (int)sizeof a->path)
        return gs_fail(GS_EINVAL, "%.200s...: path too long", path);
    if (!strcmp(path, "-")) return direct_open(a, want_stream, 1);
    struct stat lsb, sb;
    if (lstat(path, &lsb) == 0) {
        int to = stat(path, &sb) == 0;
        if (to && S_ISDIR(sb.st_mode))
            return gs_fail(GS_EIO, "%s: is a directory: expected a file to write", path);
        if (!to || !S_ISREG(sb.st_mode)) return direct_open(a, want_stream, 0);
        /* a symlink to a regular file: its target is replaced, the link stays */
        if (S_ISLNK(lsb.st_mode) && !realpath(path, a->path))
            return gs_fail(GS_EIO, "%s: cannot resolve the symlink: %s", path, strerror(errno));
        path = a->path;
    }
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
    if (a->f && a->f != stdout) fclose(a->f);
    else if (a->f) fflush(a->f);
    a->f = NULL;
    if (a->out_fd > STDERR_FILENO) close(a->out_fd);
    a->out_fd = -1;
    if (a->tmp[0]) {
        unlink(a->tmp);
        /* what an SQLite writer by name may leave beside it */
        static const char *const side[] = {"-journal", "-wal", "-shm"};
        for (int i = 0; i < 3; i++) {
            char p[sizeof a->tmp + 16];
            snprintf(p, sizeof p, "%s%s", a->tmp, side[i]);
            unlink(p);
        }
    }
    a->tmp[0] = '\0';
}

/* Copy the scratch file to the write-through target. */
static gs_status copy_out(gs_atomic *a)
{
    int in = open(a->tmp, O_RDONLY | O_CLOEXEC);
    if (in < 0) return gs_fail(GS_EIO, "%s: cannot read back %s: %s", a->path, a->tmp, strerror(errno));
    gs_status st = GS_OK;
    char buf[1 << 16];
    ssize_t got;
    while (st == GS_OK && (got = read(in, buf, sizeof buf)) != 0) {
        if (got < 0) {
            if (errno != EINTR) st = gs_fail(GS_EIO, "%s: read error: %s", a->tmp, strerror(errno));
            continue;
        }
        for (ssize_t off = 0; st == GS_OK && off < got;) {
            ssize_t w = write(a->out_fd, buf + off, (size_t)(got - off));
            if (w < 0 && errno != EINTR) st = gs_fail(GS_EIO, "%s: write failed: %s", a->path, strerror(errno));
            if (w > 0) off += w;
        }
    }
    close(in);
    return st;
}

gs_status gs_atomic_commit(gs_atomic *a)
{
    if (a->direct) {
        gs_status st = GS_OK;
        if (a->f) {
            if (ferror(a->f) || fflush(a->f) != 0)
                st = gs_fail(GS_EIO, "%s: write failed: %s", a->path, strerror(errno));
            if (a->f != stdout && fclose(a->f) != 0 && st == GS_OK)
                st = gs_fail(GS_EIO, "%s: write failed: %s", a->path, strerror(errno));
            a->f = NULL;
        } else {
            st = copy_out(a);
        }
        gs_atomic_abort(a);   /* closes the target, removes the scratch file */
        return st;
    }
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

gs_status gs_atomic_commit_new(gs_atomic *a, int *raced)
{
    *raced = 0;
    if (a->direct) return gs_atomic_commit(a);   /* written through (a symlink to nothing): no new file */
    char dir[sizeof a->path];
    const char *slash = strrchr(a->path, '/');
    if (slash) snprintf(dir, sizeof dir, "%.*s", slash == a->path ? 1 : (int)(slash - a->path), a->path);
    else snprintf(dir, sizeof dir, ".");
    int fd = open(dir, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (fd >= 0) flock(fd, LOCK_EX);   /* (without it, as gs_atomic_commit) */
    struct stat st;
    *raced = lstat(a->path, &st) == 0;
    gs_status s = GS_OK;
    if (*raced) gs_atomic_abort(a);
    else s = gs_atomic_commit(a);
    if (fd >= 0) close(fd);
    return s;
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
