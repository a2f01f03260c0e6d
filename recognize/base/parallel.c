/* parallel.c - a static split of an index range over threads (gs_parallel_for): part p of P
 * always gets the same contiguous slice, so a computation whose parts write disjoint outputs
 * gives the same bits on any number of threads. */
#include "recognize/base/base.h"

#include <pthread.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

double gs_clock_s(clockid_t id)
{
    struct timespec ts;
    clock_gettime(id, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

int gs_threads_resolve(int threads)
{
    if (threads <= 0) {
        long n = sysconf(_SC_NPROCESSORS_ONLN);
        threads = n > 0 ? (int)n : 1;
    }
    return threads > GS_MAX_THREADS ? GS_MAX_THREADS : threads;
}

typedef struct {
    gs_range_fn fn;
    void *ctx;
    int part;
    size_t begin, end;
    gs_status st;
    char detail[512];   /* gs_detail() of a failing part (thread-local on its thread) */
} part_job;

static void run_part(part_job *j)
{
    j->st = j->fn(j->ctx, j->part, j->begin, j->end);
    if (j->st != GS_OK) snprintf(j->detail, sizeof j->detail, "%s", gs_detail());
}

static void *part_main(void *arg)
{
    run_part(arg);
    return NULL;
}

gs_status gs_parallel_for(int threads, size_t n, gs_range_fn fn, void *ctx)
{
    if (n == 0) return GS_OK;
    int P = gs_threads_resolve(threads);
    if ((size_t)P > n) P = (int)n;
    if (P == 1) return fn(ctx, 0, 0, n);
    part_job job[GS_MAX_THREADS];
    pthread_t tid[GS_MAX_THREADS];
    int started[GS_MAX_THREADS] = {0};
    for (int p = 0; p < P; p++)
        job[p] = (part_job){fn, ctx, p, n * (size_t)p / (size_t)P, n * (size_t)(p + 1) / (size_t)P,
                            GS_OK, ""};
    /* parts 1.. on new threads (inline when one cannot start), part 0 on this one */
    for (int p = 1; p < P; p++) {
        started[p] = pthread_create(&tid[p], NULL, part_main, &job[p]) == 0;
        if (!started[p]) run_part(&job[p]);
    }
    run_part(&job[0]);
    for (int p = 1; p < P; p++)
        if (started[p]) pthread_join(tid[p], NULL);
    for (int p = 0; p < P; p++)
        if (job[p].st != GS_OK) return gs_fail(job[p].st, "%s", job[p].detail);
    return GS_OK;
}
