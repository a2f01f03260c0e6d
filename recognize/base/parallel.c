/* parallel.c - an index range over threads: a static split (gs_parallel_for: part p of P
 * always gets the same contiguous slice, so a computation whose parts write disjoint outputs
 * gives the same bits on any number of threads), or chunks taken in turn (gs_parallel_chunks:
 * the threads stay busy when the work per index is uneven). */
#include "recognize/base/base.h"

#include <pthread.h>
#include <stdatomic.h>
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

/* The chunks of gs_parallel_chunks: the next chunk's first index; set once a part failed. */
typedef struct {
    atomic_size_t next;
    atomic_int failed;
    size_t n, chunk;
} chunk_queue;

typedef struct {
    gs_range_fn fn;
    void *ctx;
    int part;
    size_t begin, end;   /* without a queue */
    chunk_queue *q;      /* NULL: [begin, end) */
    gs_status st;
    char detail[1024];   /* gs_detail() of a failing part (thread-local on its thread) */
} part_job;

static void run_part(part_job *j)
{
    if (!j->q) {
        j->st = j->fn(j->ctx, j->part, j->begin, j->end);
    } else {
        j->st = GS_OK;
        for (;;) {
            size_t b = atomic_fetch_add(&j->q->next, j->q->chunk);
            if (b >= j->q->n || atomic_load(&j->q->failed)) break;
            size_t e = j->q->n - b < j->q->chunk ? j->q->n : b + j->q->chunk;
            j->st = j->fn(j->ctx, j->part, b, e);
            if (j->st != GS_OK) {
                atomic_store(&j->q->failed, 1);
                break;
            }
        }
    }
    if (j->st != GS_OK) snprintf(j->detail, sizeof j->detail, "%s", gs_detail());
}

static void *part_main(void *arg)
{
    run_part(arg);
    return NULL;
}

/* P parts (P > 1) of [0, n): static slices, or chunks from q. */
static gs_status run_parts(int P, size_t n, chunk_queue *q, gs_range_fn fn, void *ctx)
{
    part_job job[GS_MAX_THREADS];
    pthread_t tid[GS_MAX_THREADS];
    int started[GS_MAX_THREADS] = {0};
    for (int p = 0; p < P; p++)
        job[p] = (part_job){fn, ctx, p, n * (size_t)p / (size_t)P, n * (size_t)(p + 1) / (size_t)P,
                            q, GS_OK, ""};
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

gs_status gs_parallel_for(int threads, size_t n, gs_range_fn fn, void *ctx)
{
    if (n == 0) return GS_OK;
    int P = gs_threads_resolve(threads);
    if ((size_t)P > n) P = (int)n;
    if (P == 1) return fn(ctx, 0, 0, n);
    return run_parts(P, n, NULL, fn, ctx);
}

gs_status gs_parallel_chunks(int threads, size_t n, size_t chunk, gs_range_fn fn, void *ctx)
{
    if (n == 0) return GS_OK;
    if (chunk == 0) chunk = n / 64 + 1;
    size_t nchunks = (n + chunk - 1) / chunk;
    int P = gs_threads_resolve(threads);
    if ((size_t)P > nchunks) P = (int)nchunks;
    if (P == 1) return fn(ctx, 0, 0, n);
    chunk_queue q = {0, 0, n, chunk};
    return run_parts(P, n, &q, fn, ctx);
}
