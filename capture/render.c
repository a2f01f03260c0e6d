/* render.c - the rendering primitives that the simulator's base stages (sim.c) and its effects
 * (effects.c) share: a stage's parts on the sim's threads, consecutive row stages together over
 * cached blocks of rows, depositing each light through its footprint (split by rows),
 * pixel-integrated Gaussian weights, and the timing of an exposed cycle. */
#include "capture/sim.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

gs_status cap_par_run(cap_sim *s, cap_render *r, size_t n, gs_range_fn fn)
{
    cap_par par;
    memset(&par, 0, sizeof par);
    par.s = s;
    par.r = r;
    /* about 64 chunks taken in turn: a frame's rows (or lights) are uneven work (the city below
     * the sky), and every stage's result is the same for any split */
    gs_status st = gs_parallel_chunks(s->threads, n, 0, fn, &par);
    r->items = 0;
    for (int p = 0; p < GS_MAX_THREADS; p++) r->items += par.items[p];
    return st;
}

/* Row stages run together (cap_rows_run): each over a block of rows, then the next, the block
 * about this many bytes of the image (within the core's L2 cache: it is read and written by
 * every stage, not streamed from memory once per stage). */
#define ROW_BLOCK_BYTES (512u * 1024u)

typedef struct {
    cap_stage *stage;
    size_t n;
    size_t block_rows;
    cap_par *par;                   /* [n] */
    double (*busy_s)[GS_MAX_THREADS]; /* [n]: each stage's time on each part */
} row_group;

static gs_status group_rows(void *ctx, int part, size_t y0, size_t y1)
{
    row_group *g = ctx;
    for (size_t a = y0; a < y1; a += g->block_rows) {
        size_t b = y1 - a > g->block_rows ? a + g->block_rows : y1;
        for (size_t i = 0; i < g->n; i++) {
            double t0 = gs_clock_s(CLOCK_MONOTONIC);
            gs_status st = g->stage[i].rows(&g->par[i], part, a, b);
            g->busy_s[i][part] += gs_clock_s(CLOCK_MONOTONIC) - t0;
            if (st != GS_OK) return st;
        }
    }
    return GS_OK;
}

gs_status cap_rows_run(cap_sim *s, cap_render *r, cap_stage *stage, size_t n)
{
    cap_par *par = calloc(n, sizeof *par);
    double (*busy_s)[GS_MAX_THREADS] = calloc(n, sizeof *busy_s);
    if (!par || !busy_s) {
        free(par);
        free(busy_s);
        return gs_fail(GS_ENOMEM, "simulator: out of memory");
    }
    size_t row_bytes = (size_t)s->W * (size_t)s->B * sizeof *s->img;
    row_group g = {stage, n, row_bytes < ROW_BLOCK_BYTES ? ROW_BLOCK_BYTES / row_bytes : 1, par,
                   busy_s};
    for (size_t i = 0; i < n; i++) {
        par[i].s = s;
        par[i].r = r;
    }
    /* chunks of at most a block (about 64 of them), so that a chunk is one block */
    size_t chunk = (size_t)s->H / 64 + 1;
    double t0 = gs_clock_s(CLOCK_MONOTONIC);
    gs_status st = gs_parallel_chunks(s->threads, (size_t)s->H, chunk < g.block_rows ? chunk : g.block_rows,
                                      group_rows, &g);
    double wall_s = gs_clock_s(CLOCK_MONOTONIC) - t0, busy_all = 0;
    for (size_t i = 0; i < n; i++)
        for (int p = 0; p < GS_MAX_THREADS; p++) busy_all += busy_s[i][p];
    for (size_t i = 0; i < n; i++) {   /* the wall time shared out as the stages kept the threads */
        double busy = 0;
        for (int p = 0; p < GS_MAX_THREADS; p++) {
            busy += busy_s[i][p];
            stage[i].items += par[i].items[p];
        }
        stage[i].seconds += busy_all > 0 ? wall_s * busy / busy_all : 0.0;
        stage[i].calls++;
    }
    free(par);
    free(busy_s);
    return st;
}

/* Rows [y0, y1) of every light's footprint, the lights in scene order (so every pixel sums its
 * lights in the same order whatever the split). */
gs_status cap_splat_rows(void *ctx, int part, size_t y0, size_t y1)
{
    cap_par *par = ctx;
    cap_sim *s = par->s;
    const cap_render *r = par->r;
    int B = s->B, L = s->L;
    unsigned long long items = 0;
    for (size_t l = 0; l < s->n; l++) {
        const cap_footprint *f = &s->fp[l];
        if (!f->w) continue;
        int ya = f->y0 > (int)y0 ? f->y0 : (int)y0, yb = f->y0 + f->h < (int)y1 ? f->y0 + f->h : (int)y1;
        if (ya >= yb) continue;
        const double *w = s->fp_w + f->off;
        const double *E = s->E + l * (size_t)L * (size_t)B;
        for (int y = ya; y < yb; y++) {
            size_t row = (size_t)y * (size_t)s->W + (size_t)f->x0;
            const double *wr = w + (size_t)(y - f->y0) * (size_t)f->w;
            for (int x = 0; x < f->w; x++) {
                size_t p = row + (size_t)x;
                int h = r->halv ? r->halv[p] : 0;
                for (int b = 0; b < B; b++) s->img[p * (size_t)B + (size_t)b] += wr[x] * E[h * B + b];
            }
        }
        items += (unsigned long long)f->w * (unsigned long long)(yb - ya);
    }
    par->items[part] += items;
    return GS_OK;
}

void cap_gauss_box(double x, double y, double sigma, int R, double *w, int *bx, int *by)
{
    double cx = floor(x + 0.5), cy = floor(y + 0.5);
    *bx = (int)cx - R;
    *by = (int)cy - R;
    int n = 2 * R + 1;
    double wx[2 * 64 + 1], wy[2 * 64 + 1], sx = 0, sy = 0;
    double k = 1.0 / (sigma * sqrt(2.0));
    for (int i = 0; i < n; i++) {
        double px = cx - R + i, py = cy - R + i;
        wx[i] = 0.5 * (erf((px + 0.5 - x) * k) - erf((px - 0.5 - x) * k));
        wy[i] = 0.5 * (erf((py + 0.5 - y) * k) - erf((py - 0.5 - y) * k));
        sx += wx[i];
        sy += wy[i];
    }
    for (int j = 0; j < n; j++)
        for (int i = 0; i < n; i++) w[j * n + i] = wx[i] * wy[j] / (sx * sy);
}

void cap_cycle_time(const cap_sim *s, const cap_render *r, long c, double *t0, double *t1)
{
    if (r->timing) {
        *t0 = r->win.t0_s[c];
        *t1 = r->win.t1_s[c];
        return;
    }
    double base = (double)(r->first_cycle + c) * s->half_s;
    *t0 = base + r->k * s->half_s / s->K;
    *t1 = base + (r->k + 1) * s->half_s / s->K;
}
