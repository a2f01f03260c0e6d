/* blobs_deblend.c - step 5 of the blob extraction (recognize.h, rec_blobs_extract): local
 * maxima of a component, their temporal signals, grouping by signal, watershed split. */
#include "recognize/internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Peaks per component considered for deblending (brightest first) and their spacing: local
 * maxima of M in a 5x5 window, no two within 2 pixels (Chebyshev). */
#define MAX_PEAKS 32
#define PEAK_RADIUS 2
/* A peak's signal comes from its 3x3 neighbourhood (grown to 7x7 when all of it saturated);
 * it is usable for deblending when its mean over k is at least PEAK_SNR sigmas. */
#define PEAK_WINDOW_MAX 3
#define PEAK_SNR 5.0
/* Components larger than this many max_area_px are dropped without deblending. */
#define DEBLEND_AREA_FACTOR 4
/* ------------------------------------------------------------- 5. deblend */

typedef struct {
    int p;            /* pixel index */
    float v;          /* M - background */
    int group;        /* -1: signal unusable */
} peak;

static int cmp_peak(const void *a, const void *b)
{
    const peak *x = a, *y = b;
    if (x->v != y->v) return x->v < y->v ? 1 : -1;
    return (x->p > y->p) - (x->p < y->p);
}

/* Temporal signal of a peak: sum over unsaturated pixels of the component in a window around
 * it of value - background, per (band, k), normalised by the mean over k of the band sum.
 * u and su hold bands * K values. 0 when unusable. */
static int peak_signal(const rec_blob_state *s, int label, int p, double *u, double *su)
{
    const gs_capture *c = s->cap;
    const int B = s->bands, K = s->K, HS = GS_MAX_HALVINGS + 1;
    const int px = (int)(p % (size_t)s->W), py = (int)(p / (size_t)s->W);
    int used = 0;
    for (int r = 1; r <= PEAK_WINDOW_MAX && !used; r++) {
        memset(u, 0, sizeof(double) * (size_t)(B * K));
        memset(su, 0, sizeof(double) * (size_t)(B * K));
        for (int y = py - r; y <= py + r; y++)
            for (int x = px - r; x <= px + r; x++) {
                if (x < 0 || y < 0 || x >= s->W || y >= s->H) continue;
                size_t q = (size_t)y * s->W + (size_t)x;
                if (s->comp[q] != label || s->sat[q]) continue;
                used++;
                for (int k = 0; k < K; k++) {
                    size_t qk = s->N * (size_t)k + q;
                    double f = s->scale[(size_t)k * HS + (c->halvings ? c->halvings[qk] : 0)];
                    for (int b = 0; b < B; b++) {
                        unsigned raw = c->raw[qk * (size_t)B + (size_t)b];
                        u[b * K + k] += ((double)raw - s->black) * f - rec_blob_frame_bg(s, k, b, x, y);
                        su[b * K + k] += rec_blob_sample_var(s, raw, f);
                    }
                }
            }
    }
    if (!used) return 0;
    double mean = 0, var_mean = 0;
    for (int i = 0; i < B * K; i++) {
        mean += u[i];
        var_mean += su[i];
    }
    mean /= K;
    var_mean /= (double)K * K;
    if (!(mean > PEAK_SNR * sqrt(var_mean))) return 0;
    for (int i = 0; i < B * K; i++) {
        u[i] /= mean;
        su[i] = sqrt(su[i]) / mean;
    }
    return 1;
}

/* How many Gaussian sigmas two normalised signals differ by: chi-square over the n values,
 * converted with Wilson & Hilferty (1931): z = ((chi2/nu)^(1/3) - (1 - 2/(9 nu))) /
 * sqrt(2/(9 nu)), nu = n - 1 (the normalisation takes one degree of freedom). */
double rec_signal_z(const double *u1, const double *s1, const double *u2, const double *s2,
                       int n)
{
    double chi2 = 0;
    for (int i = 0; i < n; i++) {
        double v = s1[i] * s1[i] + s2[i] * s2[i];
        double d = u1[i] - u2[i];
        chi2 += v > 0 ? d * d / v : (d != 0 ? INFINITY : 0);
    }
    double nu = n > 1 ? n - 1 : 1;
    if (!isfinite(chi2)) return INFINITY;
    double a = 2.0 / (9.0 * nu);
    return (cbrt(chi2 / nu) - (1 - a)) / sqrt(a);
}

/* A max-heap of pixels by M - background, for the watershed. */
typedef struct {
    float v;
    int p;
} heap_item;

static void heap_push(heap_item *h, size_t *n, heap_item it)
{
    size_t i = (*n)++;
    while (i > 0) {
        size_t parent = (i - 1) / 2;
        if (h[parent].v > it.v || (h[parent].v == it.v && h[parent].p < it.p)) break;
        h[i] = h[parent];
        i = parent;
    }
    h[i] = it;
}

static heap_item heap_pop(heap_item *h, size_t *n)
{
    heap_item top = h[0], last = h[--(*n)];
    size_t i = 0;
    for (;;) {
        size_t l = 2 * i + 1, r = l + 1, best = i;
        heap_item bv = last;
        if (l < *n && (h[l].v > bv.v || (h[l].v == bv.v && h[l].p < bv.p))) {
            best = l;
            bv = h[l];
        }
        if (r < *n && (h[r].v > bv.v || (h[r].v == bv.v && h[r].p < bv.p))) best = r;
        if (best == i) break;
        h[i] = h[best];
        i = best;
    }
    if (*n) h[i] = last;
    return top;
}

static gs_status add_light(rec_blob_state *s, unsigned flags, int *index)
{
    if (s->nlights == s->cap_lights) {
        int nc = s->cap_lights ? s->cap_lights * 2 : 64;
        unsigned *nf = realloc(s->lflags, sizeof *nf * (size_t)nc);
        if (!nf) return gs_fail(GS_ENOMEM, "blobs: cannot hold %d lights", nc);
        s->lflags = nf;
        s->cap_lights = nc;
    }
    s->lflags[s->nlights] = flags;
    *index = s->nlights++;
    return GS_OK;
}

/* Pixels of each component, grouped: pix[start[l] .. start[l + 1]) in raster order. */
static gs_status component_lists(const rec_blob_state *s, int **start_out, int **pix_out)
{
    int *start = calloc((size_t)s->ncomp + 2, sizeof *start);
    if (!start) return gs_fail(GS_ENOMEM, "blobs: cannot list the components' pixels");
    for (size_t p = 0; p < s->N; p++)
        if (s->comp[p]) start[s->comp[p] + 1]++;
    for (int l = 1; l <= s->ncomp + 1; l++) start[l] += start[l - 1];
    int *pix = malloc(sizeof(int) * (start[s->ncomp + 1] ? (size_t)start[s->ncomp + 1] : 1));
    if (!pix) {
        free(start);
        return gs_fail(GS_ENOMEM, "blobs: cannot list the components' pixels");
    }
    int *fill = malloc(sizeof(int) * ((size_t)s->ncomp + 1));
    if (!fill) {
        free(start);
        free(pix);
        return gs_fail(GS_ENOMEM, "blobs: cannot list the components' pixels");
    }
    memcpy(fill, start, sizeof(int) * ((size_t)s->ncomp + 1));
    for (size_t p = 0; p < s->N; p++)
        if (s->comp[p]) pix[fill[s->comp[p]]++] = (int)p;
    free(fill);
    *start_out = start;
    *pix_out = pix;
    return GS_OK;
}

/* Split the components into lights: every kept component becomes one light (footprint = its
 * pixels) or, when its peaks' signals differ, one light per group of peaks, by a watershed on
 * M from the peaks (priority flood: the brightest unassigned neighbour of an assigned pixel
 * takes that pixel's light). Writes s->fp and the lights' flags. */
gs_status rec_blob_deblend(rec_blob_state *s)
{
    const rec_blob_opts *o = s->o;
    const int BK = s->bands * s->K;
    int *start = NULL, *pix = NULL;
    gs_status st = component_lists(s, &start, &pix);
    if (st != GS_OK) return st;
    float *dil = malloc(sizeof(float) * s->N);
    double *u = malloc(sizeof(double) * (size_t)BK * MAX_PEAKS * 2);
    peak *pk = NULL;
    heap_item *heap = NULL;
    size_t pk_cap = 0, heap_cap = 0;
    if (!dil || !u) st = gs_fail(GS_ENOMEM, "blobs: cannot allocate the deblending buffers");
    const int try_split = isfinite(o->deblend_sigma);
    if (st == GS_OK && try_split) st = rec_cv_dilate_f32(s->M, dil, s->W, s->H, PEAK_RADIUS);
    double *su = u + (size_t)BK * MAX_PEAKS;

    for (int l = 1; st == GS_OK && l <= s->ncomp; l++) {
        const int area = start[l + 1] - start[l];
        const int *px = pix + start[l];
        if (area < o->min_area_px || area > (long long)DEBLEND_AREA_FACTOR * o->max_area_px)
            continue;
        int npk = 0, ngroups = 1;
        if (try_split && area >= 2) {
            if ((size_t)area > pk_cap) {
                peak *np = realloc(pk, sizeof *np * (size_t)area);
                if (!np) {
                    st = gs_fail(GS_ENOMEM, "blobs: cannot hold %d peaks", area);
                    break;
                }
                pk = np;
                pk_cap = (size_t)area;
            }
            int cand = 0;
            for (int i = 0; i < area; i++) {
                int p = px[i];
                if (s->M[p] >= dil[p]) pk[cand++] = (peak){p, s->M[p], -1};
            }
            qsort(pk, (size_t)cand, sizeof *pk, cmp_peak);
            for (int i = 0; i < cand && npk < MAX_PEAKS; i++) {
                int x = pk[i].p % s->W, y = pk[i].p / s->W, near = 0;
                for (int j = 0; j < npk && !near; j++) {
                    int dx = abs(pk[j].p % s->W - x), dy = abs(pk[j].p / s->W - y);
                    near = dx <= PEAK_RADIUS && dy <= PEAK_RADIUS;
                }
                if (!near) pk[npk++] = pk[i];
            }
        }
        if (npk >= 2) {
            int rep[MAX_PEAKS];
            ngroups = 0;
            for (int j = 0; j < npk; j++) {
                double *uj = u + (size_t)j * BK, *sj = su + (size_t)j * BK;
                if (!peak_signal(s, l, pk[j].p, uj, sj)) continue; /* group -1 */
                int best = -1;
                double best_z = INFINITY;
                for (int g = 0; g < ngroups; g++) {
                    int r = rep[g];
                    double z = rec_signal_z(uj, sj, u + (size_t)r * BK, su + (size_t)r * BK, BK);
                    if (z < best_z) {
                        best_z = z;
                        best = g;
                    }
                }
                if (best >= 0 && best_z <= o->deblend_sigma) {
                    pk[j].group = best;
                } else {
                    rep[ngroups] = j;
                    pk[j].group = ngroups++;
                }
            }
        }
        if (ngroups <= 1) {
            int idx;
            if ((st = add_light(s, 0, &idx)) != GS_OK) break;
            for (int i = 0; i < area; i++) s->fp[px[i]] = idx;
            continue;
        }
        int base = s->nlights, idx;
        for (int g = 0; g < ngroups && st == GS_OK; g++) st = add_light(s, REC_BLOB_DEBLENDED, &idx);
        if (st != GS_OK) break;
        if ((size_t)area > heap_cap) {
            heap_item *nh = realloc(heap, sizeof *nh * (size_t)area);
            if (!nh) {
                st = gs_fail(GS_ENOMEM, "blobs: cannot hold a %d-pixel watershed", area);
                break;
            }
            heap = nh;
            heap_cap = (size_t)area;
        }
        size_t hn = 0;
        for (int j = 0; j < npk; j++)
            if (pk[j].group >= 0) {
                s->fp[pk[j].p] = base + pk[j].group;
                heap_push(heap, &hn, (heap_item){pk[j].v, pk[j].p});
            }
        while (hn) {
            heap_item it = heap_pop(heap, &hn);
            int x = it.p % s->W, y = it.p / s->W;
            for (int dy = -1; dy <= 1; dy++)
                for (int dx = -1; dx <= 1; dx++) {
                    int xx = x + dx, yy = y + dy;
                    if ((!dx && !dy) || xx < 0 || yy < 0 || xx >= s->W || yy >= s->H) continue;
                    int q = yy * s->W + xx;
                    if (s->comp[q] != l || s->fp[q] >= 0) continue;
                    s->fp[q] = s->fp[it.p];
                    heap_push(heap, &hn, (heap_item){s->M[q], q});
                }
        }
    }
    free(start);
    free(pix);
    free(dil);
    free(u);
    free(pk);
    free(heap);
    return st;
}

