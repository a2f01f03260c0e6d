/* background.c - the background mesh of blobs.c and maps.c (SExtractor's, Bertin & Arnouts
 * 1996): nx x ny boxes of about box_px pixels (n = round(len / box_px) per axis, box i spans
 * [i len / n, (i + 1) len / n)), one value per box (each caller's statistic), bilinear
 * interpolation between box centres; beyond the outer centres either linear extrapolation
 * (exact for a linear background) or the outer value. */
#include "recognize/internal.h"

#include <stdlib.h>
#include <string.h>

void rec_mesh_free(rec_mesh *m)
{
    if (!m) return;
    free(m->bx);
    free(m->by);
    free(m->cx);
    free(m->cy);
    free(m->ix);
    free(m->iy);
    free(m->i0);
    free(m->j0);
    free(m->tx);
    free(m->ty);
    memset(m, 0, sizeof *m);
}

/* One axis: n boxes over len pixels. */
static void mesh_axis(int len, int n, int extrapolate, int *b, double *c, int *idx, int *i0,
                      double *t)
{
    for (int i = 0; i <= n; i++) b[i] = (int)((long long)i * len / n);
    for (int i = 0; i < n; i++) {
        c[i] = 0.5 * (b[i] + b[i + 1] - 1);
        for (int x = b[i]; x < b[i + 1]; x++) idx[x] = i;
    }
    for (int x = 0; x < len; x++) {
        if (n == 1) {
            i0[x] = 0;
            t[x] = 0;
            continue;
        }
        int i = idx[x];
        if (x < c[i]) i--;
        if (i < 0) i = 0;
        if (i > n - 2) i = n - 2;
        i0[x] = i;
        t[x] = (x - c[i]) / (c[i + 1] - c[i]);
        if (!extrapolate) t[x] = t[x] < 0.0 ? 0.0 : t[x] > 1.0 ? 1.0 : t[x];
    }
}

gs_status rec_mesh_init(rec_mesh *m, int W, int H, int box_px, int extrapolate)
{
    memset(m, 0, sizeof *m);
    if (W < 1 || H < 1 || box_px < 1) return gs_fail(GS_EINVAL, "background mesh: %dx%d, box %d", W, H, box_px);
    m->nx = (W + box_px / 2) / box_px;
    m->ny = (H + box_px / 2) / box_px;
    if (m->nx < 1) m->nx = 1;
    if (m->ny < 1) m->ny = 1;
    m->bx = malloc(sizeof(int) * (size_t)(m->nx + 1));
    m->by = malloc(sizeof(int) * (size_t)(m->ny + 1));
    m->cx = malloc(sizeof(double) * (size_t)m->nx);
    m->cy = malloc(sizeof(double) * (size_t)m->ny);
    m->ix = malloc(sizeof(int) * (size_t)W);
    m->iy = malloc(sizeof(int) * (size_t)H);
    m->i0 = malloc(sizeof(int) * (size_t)W);
    m->j0 = malloc(sizeof(int) * (size_t)H);
    m->tx = malloc(sizeof(double) * (size_t)W);
    m->ty = malloc(sizeof(double) * (size_t)H);
    if (!m->bx || !m->by || !m->cx || !m->cy || !m->ix || !m->iy || !m->i0 || !m->j0 || !m->tx ||
        !m->ty) {
        rec_mesh_free(m);
        return gs_fail(GS_ENOMEM, "cannot allocate a %dx%d background mesh", W, H);
    }
    mesh_axis(W, m->nx, extrapolate, m->bx, m->cx, m->ix, m->i0, m->tx);
    mesh_axis(H, m->ny, extrapolate, m->by, m->cy, m->iy, m->j0, m->ty);
    return GS_OK;
}

int rec_mesh_weights(const rec_mesh *m, int x, int y, int *node, double *w)
{
    int i = m->i0[x], j = m->j0[y];
    double tx = m->tx[x], ty = m->ty[y];
    int n = 0;
    int ni = m->nx > 1 ? 2 : 1, nj = m->ny > 1 ? 2 : 1;
    for (int b = 0; b < nj; b++)
        for (int a = 0; a < ni; a++) {
            double wx = ni == 1 ? 1 : (a ? tx : 1 - tx);
            double wy = nj == 1 ? 1 : (b ? ty : 1 - ty);
            node[n] = (j + b) * m->nx + (i + a);
            w[n] = wx * wy;
            n++;
        }
    return n;
}

double rec_mesh_at(const rec_mesh *m, const double *g, size_t stride, int x, int y)
{
    int node[4];
    double w[4], s = 0;
    int n = rec_mesh_weights(m, x, y, node, w);
    for (int i = 0; i < n; i++) s += w[i] * g[(size_t)node[i] * stride];
    return s;
}

float rec_mesh_at_f(const rec_mesh *m, const float *g, int x, int y)
{
    int node[4];
    double w[4], s = 0;
    int n = rec_mesh_weights(m, x, y, node, w);
    for (int i = 0; i < n; i++) s += w[i] * g[node[i]];
    return (float)s;
}
