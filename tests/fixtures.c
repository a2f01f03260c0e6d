/* fixtures.c - helpers shared by the test files; the contract is in tests/fixtures.h. */
#include "tests/fixtures.h"
#include "capture/capture.h"

#include "tests/test.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#define FX_RING 64

const char *fx_path(const char *dir, const char *name)
{
    static char buf[FX_RING][1024];
    static int k;
    k = (k + 1) % FX_RING;
    snprintf(buf[k], sizeof buf[k], "%s/%s", dir, name);
    return buf[k];
}

const char *fx_tmp(const char *name)
{
    return fx_path(test_tmpdir(), name);
}

int fx_exists(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0;
}

void fx_write_file(const char *path, const void *data, size_t n)
{
    FILE *f = fopen(path, "wb");
    CHECK_MSG(f != NULL, "%s: %s", path, strerror(errno));
    if (!f) return;
    CHECK_MSG(fwrite(data, 1, n, f) == n, "%s: short write", path);
    fclose(f);
}

void fx_write_text(const char *path, const char *text)
{
    fx_write_file(path, text, strlen(text));
}

char *fx_read_file(const char *path, size_t *size)
{
    FILE *f = fopen(path, "rb");
    if (size) *size = 0;
    if (!f) return NULL;
    size_t cap = 1 << 16, n = 0, got;
    char *buf = malloc(cap + 1);
    while (buf && (got = fread(buf + n, 1, cap - n, f)) > 0) {
        n += got;
        if (n == cap) {
            char *nb = realloc(buf, 2 * cap + 1);
            if (!nb) {
                free(buf);
                buf = NULL;
                break;
            }
            buf = nb;
            cap *= 2;
        }
    }
    fclose(f);
    if (!buf) return NULL;
    buf[n] = '\0';
    if (size) *size = n;
    return buf;
}

int fx_count_lines(const char *s)
{
    int n = 0;
    for (; *s; s++) n += *s == '\n';
    return n;
}

int fx_count_of(const char *hay, const char *needle)
{
    int n = 0;
    for (const char *p = strstr(hay, needle); p; p = strstr(p + 1, needle)) n++;
    return n;
}

int fx_contains(const char *hay, const char *needle)
{
    return strstr(hay, needle) != NULL;
}

int fx_sanitized(void)
{
    const char *san = getenv("GS_SAN");
    return san && *san && strcmp(san, "0");
}

int fx_vrun(char *out, size_t out_size, const char *fmt, va_list ap)
{
    char cmd[8192];
    vsnprintf(cmd, sizeof cmd, fmt, ap);
    return test_run(cmd, out, out_size);
}

int fx_run(char *out, size_t out_size, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    int rc = fx_vrun(out, out_size, fmt, ap);
    va_end(ap);
    return rc;
}

int fx_run_bin(char *out, size_t out_size, const char *fmt, const char *a, const char *b,
               const char *c)
{
    char cmd[8192];
    snprintf(cmd, sizeof cmd, fmt, test_bin(), a ? a : "", b ? b : "", c ? c : "");
    return test_run(cmd, out, out_size);
}

int fx_fork_pipe(int *fd)
{
    int fds[2];
    *fd = -1;
    CHECK(pipe(fds) == 0);
    fflush(stdout);
    pid_t pid = fork();
    CHECK(pid >= 0);
    if (pid == 0) {
        close(fds[0]);
        *fd = fds[1];
        return 0;
    }
    close(fds[1]);
    *fd = fds[0];
    return (int)pid;
}

int fx_lock(const char *path)
{
    int fd = open(path, O_WRONLY | O_CREAT | O_CLOEXEC, 0600);
    int ok = fd >= 0 && flock(fd, LOCK_EX) == 0;
    CHECK_MSG(ok, "%s: cannot lock", path);
    if (!ok && fd >= 0) close(fd);
    return ok ? fd : -1;
}

struct cap_ac *fx_mains_ac(const char *data_path, int grid_hz)
{
    cap_freq_config f;
    memset(&f, 0, sizeof f);
    f.model = CAP_FREQ_TRACE;
    snprintf(f.wav, sizeof f.wav, "%s", test_shared_path(data_path));
    cap_ac *ac = NULL;
    CHECK_OK(cap_ac_new(&f, grid_hz, &ac));
    return ac;
}
