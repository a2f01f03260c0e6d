/* kit_isolate.c - gs_isolated (base.h): a drawing step run in a child process, so that a
 * library that exits or crashes when it fails (PLplot and its text stack under memory
 * exhaustion: plexit, GLib's aborts, fontconfig's SIGSEGV; docs/reliability.md) fails that
 * step in one line instead of ending the whole command. */
#include "recognize/base/base.h"

#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/wait.h>
#include <unistd.h>

/* The last non-empty line of text[0..n) (a library's reason comes after its banner), without
 * surrounding white space, into line. */
static void last_line(const char *text, size_t n, char *line, size_t size)
{
    size_t j = n;
    while (j > 0 && (text[j - 1] == '\n' || text[j - 1] == '\r' || text[j - 1] == ' ')) j--;
    size_t i = j;
    while (i > 0 && text[i - 1] != '\n') i--;
    while (i < j && text[i] == ' ') i++;
    snprintf(line, size, "%.*s", (int)(j - i), text + i);
}

/* A child whose draw failed exits with CHILD_FAILED + its status, its detail the last line. */
#define CHILD_FAILED 100

gs_status gs_isolated(const char *what, unsigned char *buf, size_t bytes,
                      gs_status (*draw)(void *ctx, unsigned char *buf), void *ctx)
{
    unsigned char *shared = mmap(NULL, bytes ? bytes : 1, PROT_READ | PROT_WRITE,
                                 MAP_SHARED | MAP_ANONYMOUS, -1, 0);
    if (shared == MAP_FAILED) return gs_fail(GS_ENOMEM, "%s: cannot map %zu bytes to draw in: %s", what, bytes, strerror(errno));
    if (bytes) memcpy(shared, buf, bytes);
    int fd[2];
    if (pipe(fd) != 0) {
        munmap(shared, bytes ? bytes : 1);
        return gs_fail(GS_EIO, "%s: cannot open a pipe to the drawing process: %s", what, strerror(errno));
    }
    fflush(stdout);   /* the child must not write the parent's buffered output again */
    fflush(stderr);
    pid_t pid = fork();
    if (pid == 0) {
        close(fd[0]);
        dup2(fd[1], STDERR_FILENO);
        gs_status ds = draw(ctx, shared);
        if (ds != GS_OK) {
            fprintf(stderr, "\n%s\n", gs_detail());
            _exit(CHILD_FAILED + (int)ds);
        }
        _exit(0);   /* no exit handlers: they are the parent's */
    }
    close(fd[1]);
    char err[4096];
    size_t n = 0;
    if (pid > 0)
        for (;;) {   /* the child's standard error, its last 4 KiB kept */
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
    if (pid < 0) s = gs_fail(GS_ENOMEM, "%s: cannot start the drawing process: %s", what, strerror(errno));
    else {
        while (waitpid(pid, &st, 0) < 0 && errno == EINTR) {}
        char line[300];
        last_line(err, n, line, sizeof line);
        const char *sep = line[0] ? ": " : "";
        if (WIFSIGNALED(st))
            s = gs_fail(GS_EIO, "%s: the drawing process was killed by signal %d (%s)%s%s", what,
                        WTERMSIG(st), strsignal(WTERMSIG(st)), sep, line);
        else if (WIFEXITED(st) && WEXITSTATUS(st) > CHILD_FAILED && WEXITSTATUS(st) <= CHILD_FAILED + GS_ELIMIT)
            s = gs_fail((gs_status)(WEXITSTATUS(st) - CHILD_FAILED), "%s", line);
        else if (!WIFEXITED(st) || WEXITSTATUS(st) != 0)
            s = gs_fail(GS_EIO, "%s: the drawing process failed (exit status %d)%s%s", what,
                        WIFEXITED(st) ? WEXITSTATUS(st) : -1, sep, line);
        else if (n) {   /* a library's warnings, as they were */
            size_t written = fwrite(err, 1, n, stderr);
            (void)written;
        }
    }
    if (s == GS_OK && bytes) memcpy(buf, shared, bytes);
    munmap(shared, bytes ? bytes : 1);
    return s;
}
