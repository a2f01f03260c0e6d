/* kit_isolate.c - gs_isolated (base.h): a drawing step run in a child process, so that a
 * library that exits or crashes when it fails (PLplot and its text stack under memory
 * exhaustion: plexit, GLib's aborts, fontconfig's SIGSEGV; docs/reliability.md) fails that
 * step in one line instead of ending the whole command. */
#define _GNU_SOURCE   /* on_exit, pipe2 */
#include "recognize/base/base.h"

#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/wait.h>
#include <unistd.h>

/* The head of the shared mapping: draw's own failure, then the copy of the caller's buffer. */
typedef struct {
    int status;
    char detail[1024];
} child_report;

/* The last non-empty line of text[0..n), without surrounding white space, into line. */
static void last_line(const char *text, size_t n, char *line, size_t size)
{
    size_t j = n;
    while (j > 0 && (text[j - 1] == '\n' || text[j - 1] == '\r' || text[j - 1] == ' ')) j--;
    size_t i = j;
    while (i > 0 && text[i - 1] != '\n') i--;
    while (i < j && text[i] == ' ') i++;
    snprintf(line, size, "%.*s", (int)(j - i), text + i);
}

/* In the child, a library's exit(): out at once, without the parent's exit handlers. */
static void child_exit(int status, void *unused)
{
    (void)unused;
    _exit(status);
}

int gs_isolated_exit(const char *reason)
{
    fprintf(stderr, "\n%s\n", reason ? reason : "");
    _exit(1);
}

gs_status gs_isolated(const char *what, unsigned char *buf, size_t bytes,
                      gs_status (*draw)(void *ctx, unsigned char *buf), void *ctx)
{
    size_t map_bytes = sizeof(child_report) + bytes;
    child_report *rep = mmap(NULL, map_bytes, PROT_READ | PROT_WRITE, MAP_SHARED | MAP_ANONYMOUS, -1, 0);
    if (rep == MAP_FAILED)
        return gs_fail(GS_ENOMEM, "%s: cannot map %zu bytes to draw in: %s", what, bytes, strerror(errno));
    unsigned char *shared = (unsigned char *)(rep + 1);
    rep->status = GS_OK;
    if (bytes) memcpy(shared, buf, bytes);
    int fd[2];
    if (pipe2(fd, O_CLOEXEC) != 0) {
        int e = errno;
        munmap(rep, map_bytes);
        return gs_fail(GS_EIO, "%s: cannot open a pipe to the drawing process: %s", what, strerror(e));
    }
    fflush(NULL);   /* the child must not write the parent's buffered output again */
    pid_t pid = fork();
    int fork_errno = errno;
    if (pid == 0) {
        close(fd[0]);
        dup2(fd[1], STDERR_FILENO);
        on_exit(child_exit, NULL);   /* registered last: runs before the parent's handlers */
        gs_status ds = draw(ctx, shared);
        if (ds != GS_OK) {
            rep->status = ds;
            snprintf(rep->detail, sizeof rep->detail, "%s", gs_detail());
        }
        _exit(0);   /* no leak check: LeakSanitizer in a forked child takes the parent's
                     * threads for running ones and warns of false leaks */
    }
    close(fd[1]);
    char err[8192];
    size_t n = 0;
    for (; pid > 0;) {   /* the child's standard error, its last 8 KiB kept */
        char chunk[1024];
        ssize_t got = read(fd[0], chunk, sizeof chunk);
        if (got < 0 && errno == EINTR) continue;
        if (got <= 0) break;
        if (n + (size_t)got > sizeof err) {
            size_t drop = n + (size_t)got - sizeof err;
            memmove(err, err + drop, n - drop);
            n -= drop;
        }
        memcpy(err + n, chunk, (size_t)got);
        n += (size_t)got;
    }
    close(fd[0]);
    gs_status s = GS_OK;
    int st = 0;
    if (pid < 0) s = gs_fail(GS_EIO, "%s: cannot start the drawing process: %s", what, strerror(fork_errno));
    else {
        pid_t w;
        while ((w = waitpid(pid, &st, 0)) < 0 && errno == EINTR) {}
        char line[300];
        last_line(err, n, line, sizeof line);
        const char *sep = line[0] ? ": " : "";
        if (w != pid)
            s = gs_fail(GS_EIO, "%s: the drawing process's end is unknown (waitpid: %s)", what, strerror(errno));
        else if (WIFSIGNALED(st))
            s = gs_fail(GS_EIO, "%s: the drawing process was killed by signal %d (%s)%s%s", what,
                        WTERMSIG(st), strsignal(WTERMSIG(st)), sep, line);
        else if (WEXITSTATUS(st) != 0)
            s = gs_fail(GS_EIO, "%s: the drawing process failed (exit status %d)%s%s", what,
                        WEXITSTATUS(st), sep, line);
        else if (rep->status != GS_OK)
            s = gs_fail((gs_status)rep->status, "%s", rep->detail);
        /* a library's warnings as they were; on a failure, a sanitizer's report in full (the
         * one line would hide it) */
        if (n && (s == GS_OK || memmem(err, n, "Sanitizer", 9))) {
            size_t written = fwrite(err, 1, n, stderr);
            (void)written;
        }
    }
    if (s == GS_OK && bytes) memcpy(buf, shared, bytes);
    munmap(rep, map_bytes);
    return s;
}
