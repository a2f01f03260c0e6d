/* render.c - the rendering primitives that the simulator's base stages (sim.c) and its effects
 * (effects.c) share: a stage's parts on the sim's threads, depositing each light through its
 * footprint (split by rows), pixel-integrated Gaussian weights, and the timing of an exposed
 * cycle. */
#include "capture/sim.h"

#include <math.h>
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

/* Rows [y0, y1) of every light's footprint, the lights in scene order (so every pixel sums its
 * lights in the same order whatever the split). */
static gs_status splat_rows(void *ctx, int part, size_t y0, size_t y1)
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

gs_status cap_splat(cap_sim *s, cap_render *r)
{
    return cap_par_run(s, r, (size_t)s->H, splat_rows);
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
