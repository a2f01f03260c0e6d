/* blobs.c - lights as blobs of a capture, with per-frame photometry for Eq. 7 (paper Sec. 4:
 * "point a camera at a bulb", i(sigma) per light; Eq. 17: saturated samples carry no weight).
 *
 * SEP-style source extraction (Barbary 2016, JOSS 1(6) 58; Bertin & Arnouts 1996, SExtractor):
 * background mesh, threshold over a noise map, 8-connected components, deblending, then sums.
 * The steps and their formulas are documented at rec_blobs_extract in recognize.h; the notes
 * here are about how.
 *
 * Units: every image here is per-cycle intensity (DN per flicker cycle, black removed):
 * v = (raw - black) * 2^h / cycles (gs_capture_value). Noise per sample (DN^2):
 * var(raw) = read^2 + 1/12 + max(raw - black, 0) / gain, so var(v) = var(raw) * (2^h/cycles)^2.
 * The 1/12 DN^2 is the quantisation of an integer sample (uniform over one DN); it also keeps
 * the noise map > 0 for noise-free data.
 *
 * Memory: a few float/int/byte images of width x height (about 30 bytes a pixel), nothing per
 * pixel or per light that is not in one array. Time: two passes over the K * bands samples
 * (the mean image, the per-frame background mesh) plus work proportional to the lights'
 * pixels. */
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
/* A mesh node needs this many usable pixels (and this fraction of its box) for the per-frame
 * background; others are filled from their neighbours. */
#define NODE_MIN_PX 8
#define NODE_MIN_FRACTION 0.1
/* Robust level of a box of M: median after this many 3-sigma clips (sigma = 1.4826 MAD). */
#define CLIP_ITER 2
#define CLIP_SIGMA 3.0
/* The per-frame background ignores pixels within grow_px + this of a detection. */
#define MASK_MARGIN 2

void rec_blob_opts_default(rec_blob_opts *o)
{
    if (!o) return;
    o->threshold_sigma = 5;
    o->min_area_px = 1;
    o->max_area_px = 5000;
    o->background_px = 31;
    o->deblend_sigma = 5;
    o->grow_px = 2;
    o->labels = 0;
}

void rec_catalog_release(rec_catalog *cat)
{
    if (!cat) return;
    free(cat->x_px);
    free(cat->y_px);
    free(cat->area_px);
    free(cat->peak_dn);
    free(cat->saturated_px);
    free(cat->flags);
    free(cat->signal);
    free(cat->sigma);
    free(cat->labels);
    memset(cat, 0, sizeof *cat);
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Robust level of a box: the median after CLIP_ITER clips at CLIP_SIGMA (1.4826 MAD). */
static float robust_level(float *v, float *tmp, size_t n)
{
    float med = gs_median_f(v, n);
    for (int it = 0; it < CLIP_ITER && n > 2; it++) {
        for (size_t i = 0; i < n; i++) tmp[i] = fabsf(v[i] - med);
        float sig = 1.4826f * gs_median_f(tmp, n);
        if (!(sig > 0)) break;
        size_t m = 0;
        for (size_t i = 0; i < n; i++)
            if (fabsf(v[i] - med) <= CLIP_SIGMA * sig) v[m++] = v[i];
        if (m == 0 || m == n) break;
        n = m;
        med = gs_median_f(v, n);
    }
    return med;
}

/* 3x3 median of a node grid, with the grid extended by linear extrapolation (2 f(0) - f(1)) so
 * that a linear background passes unchanged, edges included. */
static void mesh_median3(double *g, int nx, int ny, double *tmp)
{
    if (nx * ny < 2) return;
    memcpy(tmp, g, sizeof(double) * (size_t)(nx * ny));
    for (int j = 0; j < ny; j++)
        for (int i = 0; i < nx; i++) {
            double v[9];
            int n = 0;
            for (int b = -1; b <= 1; b++)
                for (int a = -1; a <= 1; a++) {
                    int ii = i + a, jj = j + b;
                    /* beyond the edge: f(-1) = 2 f(0) - f(1), per extrapolated axis */
                    int ei = ii < 0 ? 0 : ii >= nx ? nx - 1 : ii;
                    int ej = jj < 0 ? 0 : jj >= ny ? ny - 1 : jj;
                    int ri = ii < 0 ? 1 : nx - 2, rj = jj < 0 ? 1 : ny - 2;
                    double fe = tmp[ej * nx + ei], fx = fe;
                    if (ei != ii && nx > 1) fx += fe - tmp[ej * nx + ri];
                    if (ej != jj && ny > 1) fx += fe - tmp[rj * nx + ei];
                    v[n++] = fx;
                }
            qsort(v, (size_t)n, sizeof *v, cmp_double);
            g[j * nx + i] = v[n / 2];
        }
}

/* ------------------------------------------------------------------ state */

typedef struct {
    const gs_capture *cap;
    const rec_blob_opts *o;
    int W, H, K, bands;
    size_t N;
    int sat_level;           /* raw >= sat_level is saturated (integer form of saturation_dn) */
    float black;
    gs_noise nz;             /* the capture's noise model */
    double *scale;           /* [k * (GS_MAX_HALVINGS + 1) + h] = 2^h / cycles_k */

    float *M;                /* mean image, then M - background */
    unsigned char *sat;      /* saturated in some frame and band */
    unsigned char *hdr;      /* halved in some frame */
    float *sumA, *sumB;      /* HDR only: sum_k scale^2, sum_k scale */

    rec_mesh mesh;
    double *fval, *fvar;     /* per-frame mesh: [((k * bands + b) * nodes + n)] mean, var of mean */

    unsigned char *det;      /* detection mask */
    int *comp;               /* component labels (0 = none) */
    int ncomp;
    int *stats;              /* 5 per label */

    int *fp;                 /* footprint owner (light index) or -1 */
    int *ap;                 /* aperture owner or -1 */
    int nlights, cap_lights;
    unsigned *lflags;        /* per light: DEBLENDED */
} state;

static void state_free(state *s)
{
    free(s->scale);
    free(s->M);
    free(s->sat);
    free(s->hdr);
    free(s->sumA);
    free(s->sumB);
    rec_mesh_free(&s->mesh);
    free(s->fval);
    free(s->fvar);
    free(s->det);
    free(s->comp);
    free(s->stats);
    free(s->fp);
    free(s->ap);
    free(s->lflags);
}

static inline double sample_var(const state *s, unsigned raw, double scale)
{
    return gs_noise_raw_var(&s->nz, (double)raw) * scale * scale;
}

/* ------------------------------------------------------- 1. mean image */

static gs_status mean_image(state *s)
{
    const gs_capture *c = s->cap;
    const int HS = GS_MAX_HALVINGS + 1;
    const int B = s->bands;
    for (int k = 0; k < s->K; k++) {
        const unsigned short *rk = c->raw + s->N * (size_t)B * (size_t)k;
        const unsigned char *hk = c->halvings ? c->halvings + s->N * (size_t)k : NULL;
        const double *sc = s->scale + (size_t)k * HS;
        const float sc0 = (float)sc[0];
        for (size_t p = 0; p < s->N; p++) {
            float acc = 0;
            int satp = 0;
            for (int b = 0; b < B; b++) {
                unsigned r = rk[p * (size_t)B + (size_t)b];
                satp |= (int)r >= s->sat_level;
                acc += (float)r - s->black;
            }
            s->sat[p] |= (unsigned char)satp;
            if (hk) {
                unsigned h = hk[p];
                if (h > GS_MAX_HALVINGS)
                    return gs_fail(GS_EINVAL, "blobs: frame %d pixel (x %zu, y %zu): %u halvings: "
                                   "expected 0 to %d", k, p % (size_t)s->W, p / (size_t)s->W, h,
                                   GS_MAX_HALVINGS);
                float f = (float)sc[h];
                s->M[p] += acc * f;
                s->sumA[p] += f * f;
                s->sumB[p] += f;
                s->hdr[p] |= (unsigned char)(h > 0);
            } else {
                s->M[p] += acc * sc0;
            }
        }
    }
    const float invK = 1.0f / (float)s->K;
    for (size_t p = 0; p < s->N; p++) s->M[p] *= invK;
    return GS_OK;
}

/* ----------------------------------------- 2-4. background, noise, threshold */

static gs_status detect(state *s)
{
    const rec_mesh *m = &s->mesh;
    const int nodes = m->nx * m->ny;
    size_t box_max = 0;
    for (int j = 0; j < m->ny; j++)
        for (int i = 0; i < m->nx; i++) {
            size_t a = (size_t)(m->bx[i + 1] - m->bx[i]) * (size_t)(m->by[j + 1] - m->by[j]);
            if (a > box_max) box_max = a;
        }
    float *buf = malloc(sizeof(float) * box_max * 2);
    double *level = malloc(sizeof(double) * (size_t)nodes * 2);
    float *bg = malloc(sizeof(float) * s->N);
    if (!buf || !level || !bg) {
        free(buf);
        free(level);
        free(bg);
        return gs_fail(GS_ENOMEM, "blobs: cannot allocate the background of %dx%d pixels", s->W,
                       s->H);
    }
    for (int j = 0; j < m->ny; j++)
        for (int i = 0; i < m->nx; i++) {
            size_t n = 0;
            for (int y = m->by[j]; y < m->by[j + 1]; y++)
                for (int x = m->bx[i]; x < m->bx[i + 1]; x++) buf[n++] = s->M[(size_t)y * s->W + x];
            level[j * m->nx + i] = robust_level(buf, buf + box_max, n);
        }
    mesh_median3(level, m->nx, m->ny, level + nodes);
    /* background image, by rows */
    for (int y = 0; y < s->H; y++)
        for (int x = 0; x < s->W; x++) bg[(size_t)y * s->W + x] = (float)rec_mesh_at(m, level, 1, x, y);

    /* noise of M at the background level (recognize.h, step 3) and the threshold */
    double A = 0, Bq = 0;
    for (int k = 0; k < s->K; k++) {
        double sc = s->scale[(size_t)k * (GS_MAX_HALVINGS + 1)];
        A += sc * sc;
        Bq += sc;
    }
    const double thr = s->o->threshold_sigma, K2 = (double)s->K * s->K;
    for (size_t p = 0; p < s->N; p++) {
        double a = s->sumA ? s->sumA[p] : A, bq = s->sumB ? s->sumB[p] : Bq;
        double b = bg[p] > 0 ? bg[p] : 0;
        double var = (s->bands * s->nz.read_var_dn2 * a + b * s->nz.inv_gain * bq) / K2;
        float r = s->M[p] - bg[p];
        s->M[p] = r;
        s->det[p] = (unsigned char)(s->sat[p] || r > thr * sqrt(var));
    }
    free(buf);
    free(level);
    free(bg);
    return GS_OK;
}

/* ------------------------------------------------ per-frame background mesh */

/* For every frame and band, each node: the mean of the values of its box's pixels outside the
 * dilated detections (and unsaturated), and the variance of that mean. use_mask = 0 takes every
 * unsaturated pixel (the fallback when detections cover nearly everything). */
static gs_status frame_mesh(state *s, const unsigned char *mask, int use_mask)
{
    const gs_capture *c = s->cap;
    const rec_mesh *m = &s->mesh;
    const int nodes = m->nx * m->ny, B = s->bands, HS = GS_MAX_HALVINGS + 1;
    const size_t planes = (size_t)s->K * (size_t)B;
    int *cnt = calloc((size_t)nodes, sizeof *cnt);
    unsigned char *good = malloc((size_t)nodes);
    if (!cnt || !good) {
        free(cnt);
        free(good);
        return gs_fail(GS_ENOMEM, "blobs: cannot allocate the frame background");
    }
    memset(s->fval, 0, sizeof(double) * planes * (size_t)nodes);
    memset(s->fvar, 0, sizeof(double) * planes * (size_t)nodes);
    for (size_t p = 0; p < s->N; p++)
        if (!s->sat[p] && !(use_mask && mask[p]))
            cnt[m->iy[p / (size_t)s->W] * m->nx + m->ix[p % (size_t)s->W]]++;
    for (int k = 0; k < s->K; k++) {
        const unsigned short *rk = c->raw + s->N * (size_t)B * (size_t)k;
        const unsigned char *hk = c->halvings ? c->halvings + s->N * (size_t)k : NULL;
        const double *sc = s->scale + (size_t)k * HS;
        double *val = s->fval + (size_t)k * B * nodes, *var = s->fvar + (size_t)k * B * nodes;
        for (int y = 0; y < s->H; y++) {
            const size_t row = (size_t)y * s->W;
            const int nrow = m->iy[y] * m->nx;
            for (int x = 0; x < s->W; x++) {
                size_t p = row + (size_t)x;
                if (s->sat[p] || (use_mask && mask[p])) continue;
                double f = sc[hk ? hk[p] : 0];
                int n = nrow + m->ix[x];
                for (int b = 0; b < B; b++) {
                    unsigned r = rk[p * (size_t)B + (size_t)b];
                    val[b * nodes + n] += ((float)r - s->black) * f;
                    var[b * nodes + n] += sample_var(s, r, f);
                }
            }
        }
    }
    int any = 0;
    for (int n = 0; n < nodes; n++) {
        int j = n / m->nx, i = n % m->nx;
        size_t area = (size_t)(m->bx[i + 1] - m->bx[i]) * (size_t)(m->by[j + 1] - m->by[j]);
        good[n] = cnt[n] >= NODE_MIN_PX && cnt[n] >= NODE_MIN_FRACTION * (double)area;
        any |= good[n];
    }
    if (!any) {
        free(cnt);
        free(good);
        if (use_mask) return frame_mesh(s, mask, 0);
        return GS_OK; /* every pixel saturated: background 0, variance 0 */
    }
    for (size_t q = 0; q < planes; q++) {
        double *val = s->fval + q * nodes, *var = s->fvar + q * nodes;
        for (int n = 0; n < nodes; n++)
            if (good[n]) {
                val[n] /= cnt[n];
                var[n] /= (double)cnt[n] * cnt[n];
            }
    }
    /* fill bad nodes from good (or filled) 8-neighbours, ring by ring */
    unsigned char *done = malloc((size_t)nodes);
    if (!done) {
        free(cnt);
        free(good);
        return gs_fail(GS_ENOMEM, "blobs: cannot allocate the frame background");
    }
    memcpy(done, good, (size_t)nodes);
    for (int pending = 1; pending;) {
        pending = 0;
        unsigned char *now = good; /* reuse: nodes filled in this ring */
        memset(now, 0, (size_t)nodes);
        for (int n = 0; n < nodes; n++) {
            if (done[n]) continue;
            int j = n / m->nx, i = n % m->nx, nn = 0;
            int nb[8];
            for (int b = -1; b <= 1; b++)
                for (int a = -1; a <= 1; a++) {
                    int ii = i + a, jj = j + b;
                    if ((a || b) && ii >= 0 && jj >= 0 && ii < m->nx && jj < m->ny &&
                        done[jj * m->nx + ii])
                        nb[nn++] = jj * m->nx + ii;
                }
            if (!nn) {
                pending = 1;
                continue;
            }
            for (size_t q = 0; q < planes; q++) {
                double *val = s->fval + q * nodes, *var = s->fvar + q * nodes;
                double sv = 0, sw = 0;
                for (int t = 0; t < nn; t++) {
                    sv += val[nb[t]];
                    sw += var[nb[t]];
                }
                val[n] = sv / nn;
                var[n] = sw / nn; /* as uncertain as a neighbour: conservative */
            }
            now[n] = 1;
        }
        for (int n = 0; n < nodes; n++) done[n] |= now[n];
    }
    free(done);
    free(cnt);
    free(good);
    return GS_OK;
}

/* Background of frame k, band b at (x, y), per cycle. */
static double frame_bg(const state *s, int k, int b, int x, int y)
{
    const int nodes = s->mesh.nx * s->mesh.ny;
    return rec_mesh_at(&s->mesh, s->fval + ((size_t)k * s->bands + (size_t)b) * nodes, 1, x, y);
}

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
static int peak_signal(const state *s, int label, int p, double *u, double *su)
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
                        u[b * K + k] += ((double)raw - s->black) * f - frame_bg(s, k, b, x, y);
                        su[b * K + k] += sample_var(s, raw, f);
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
static double signal_z(const double *u1, const double *s1, const double *u2, const double *s2,
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

static gs_status add_light(state *s, unsigned flags, int *index)
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
static gs_status component_lists(const state *s, int **start_out, int **pix_out)
{
    int *start = calloc((size_t)s->ncomp + 2, sizeof *start);
    int *pix = malloc(sizeof(int) * (s->N ? s->N : 1));
    if (!start || !pix) {
        free(start);
        free(pix);
        return gs_fail(GS_ENOMEM, "blobs: cannot list the components' pixels");
    }
    for (size_t p = 0; p < s->N; p++)
        if (s->comp[p]) start[s->comp[p] + 1]++;
    for (int l = 1; l <= s->ncomp + 1; l++) start[l] += start[l - 1];
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
static gs_status deblend(state *s)
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
                    double z = signal_z(uj, sj, u + (size_t)r * BK, su + (size_t)r * BK, BK);
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

/* ------------------------------------------------- 6. aperture, 7. photometry */

/* Drop lights whose footprint area is outside the limits; grow the apertures. */
static gs_status apertures(state *s, int *area)
{
    const rec_blob_opts *o = s->o;
    for (size_t p = 0; p < s->N; p++)
        if (s->fp[p] >= 0) area[s->fp[p]]++;
    for (size_t p = 0; p < s->N; p++) {
        int i = s->fp[p];
        if (i >= 0 && (area[i] < o->min_area_px || area[i] > o->max_area_px)) s->fp[p] = -1;
    }
    memcpy(s->ap, s->fp, sizeof(int) * s->N);
    if (o->grow_px == 0) return GS_OK;
    int *cur = malloc(sizeof(int) * s->N), *next = malloc(sizeof(int) * s->N);
    if (!cur || !next) {
        free(cur);
        free(next);
        return gs_fail(GS_ENOMEM, "blobs: cannot allocate the aperture growth");
    }
    size_t nc = 0;
    for (size_t p = 0; p < s->N; p++)
        if (s->fp[p] >= 0) cur[nc++] = (int)p;
    for (int r = 0; r < o->grow_px && nc; r++) {
        size_t nn = 0;
        for (size_t i = 0; i < nc; i++) {
            int p = cur[i], x = p % s->W, y = p / s->W;
            for (int dy = -1; dy <= 1; dy++)
                for (int dx = -1; dx <= 1; dx++) {
                    int xx = x + dx, yy = y + dy;
                    if (xx < 0 || yy < 0 || xx >= s->W || yy >= s->H) continue;
                    int q = yy * s->W + xx;
                    if (s->ap[q] >= 0) continue;
                    s->ap[q] = s->ap[p];
                    next[nn++] = q;
                }
        }
        int *t = cur;
        cur = next;
        next = t;
        nc = nn;
    }
    free(cur);
    free(next);
    return GS_OK;
}

typedef struct {
    int first, light;
} order_item;

static int cmp_order(const void *a, const void *b)
{
    const order_item *x = a, *y = b;
    return (x->first > y->first) - (x->first < y->first);
}

static gs_status alloc_catalog(rec_catalog *cat, size_t n, int bands, int K)
{
    cat->count = n;
    cat->bands = bands;
    cat->K = K;
    if (n == 0) return GS_OK;
    size_t nbk = n * (size_t)bands * (size_t)K;
    cat->x_px = malloc(sizeof(double) * n);
    cat->y_px = malloc(sizeof(double) * n);
    cat->area_px = malloc(sizeof(int) * n);
    cat->peak_dn = malloc(sizeof(double) * n);
    cat->saturated_px = malloc(sizeof(int) * n);
    cat->flags = malloc(sizeof(unsigned) * n);
    cat->signal = malloc(sizeof(double) * nbk);
    cat->sigma = malloc(sizeof(double) * nbk);
    if (!cat->x_px || !cat->y_px || !cat->area_px || !cat->peak_dn || !cat->saturated_px ||
        !cat->flags || !cat->signal || !cat->sigma)
        return gs_fail(GS_ENOMEM, "blobs: cannot hold a catalog of %zu lights", n);
    return GS_OK;
}

/* Windowed centroid (SExtractor's XWIN_IMAGE, Bertin 2010; SEP's winpos): iterate
 * x <- x + 2 sum(w I (x_p - x)) / sum(w I) with a Gaussian window w of sigma_w, which converges to
 * the centre of any symmetric profile (where sum w I (x_p - x) = 0) and, for a Gaussian PSF
 * with sigma_w = its sigma, in one step with near-optimal (PSF-weighted) noise. I = M -
 * background over pixels within 4 sigma_w that no other light's aperture owns. sigma_w comes
 * from the aperture's second moment (2 sigma^2 for a Gaussian), clamped to [1, 8] pixels (a
 * window wider than the PSF costs a little noise, a narrower one much more; the moment of a dim
 * light's aperture is mostly noise).
 * Starts from (x, y); keeps it when the iteration fails or leaves 2 sigma_w. */
static void win_centroid(const state *s, int light, double r2, double *xc, double *yc)
{
    double sw = sqrt(r2 / 2);
    if (!(sw >= 1)) sw = 1;
    if (sw > 8) sw = 8;
    const double x0 = *xc, y0 = *yc, inv2s2 = 1 / (2 * sw * sw);
    const int R = (int)ceil(4 * sw);
    double x = x0, y = y0;
    for (int it = 0; it < 16; it++) {
        double swi = 0, sx = 0, sy = 0;
        int cx = (int)lround(x), cy = (int)lround(y);
        for (int yy = cy - R; yy <= cy + R; yy++) {
            if (yy < 0 || yy >= s->H) continue;
            for (int xx = cx - R; xx <= cx + R; xx++) {
                if (xx < 0 || xx >= s->W) continue;
                size_t q = (size_t)yy * s->W + (size_t)xx;
                if (s->ap[q] >= 0 && s->ap[q] != light) continue;
                double dx = xx - x, dy = yy - y;
                double w = exp(-(dx * dx + dy * dy) * inv2s2) * s->M[q];
                swi += w;
                sx += w * dx;
                sy += w * dy;
            }
        }
        if (!(swi > 0)) return;
        double ddx = 2 * sx / swi, ddy = 2 * sy / swi;
        x += ddx;
        y += ddy;
        if (!isfinite(x) || !isfinite(y) || fabs(x - x0) > 2 * sw || fabs(y - y0) > 2 * sw) return;
        if (ddx * ddx + ddy * ddy < 1e-10) break;
    }
    *xc = x;
    *yc = y;
}

/* The catalog: lights in raster order of their first footprint pixel. */
static gs_status photometry(state *s, const int *area, rec_catalog *cat)
{
    const gs_capture *c = s->cap;
    const int B = s->bands, K = s->K, HS = GS_MAX_HALVINGS + 1, BK = B * K;
    const int nodes = s->mesh.nx * s->mesh.ny;
    const int W = s->W, H = s->H;
    gs_status st = GS_OK;

    /* order and new indices */
    order_item *ord = malloc(sizeof *ord * (size_t)(s->nlights ? s->nlights : 1));
    int *newi = malloc(sizeof(int) * (size_t)(s->nlights ? s->nlights : 1));
    int *start = calloc((size_t)s->nlights + 2, sizeof(int));
    int *pix = NULL, *fill = NULL, *stamp = NULL, *touched = NULL;
    double *wn = NULL, *acc = NULL;
    if (!ord || !newi || !start) {
        st = gs_fail(GS_ENOMEM, "blobs: cannot order the lights");
        goto done;
    }
    for (int i = 0; i < s->nlights; i++) {
        ord[i].first = -1;
        ord[i].light = i;
    }
    for (size_t p = 0; p < s->N; p++) {
        int i = s->fp[p];
        if (i >= 0 && ord[i].first < 0) ord[i].first = (int)p;
    }
    size_t n = 0;
    for (int i = 0; i < s->nlights; i++)
        if (ord[i].first >= 0) ord[n++] = ord[i];
    qsort(ord, n, sizeof *ord, cmp_order);
    for (int i = 0; i < s->nlights; i++) newi[i] = -1;
    for (size_t j = 0; j < n; j++) newi[ord[j].light] = (int)j;
    for (size_t p = 0; p < s->N; p++) {
        if (s->ap[p] >= 0) s->ap[p] = newi[s->ap[p]];
        if (s->fp[p] >= 0) s->fp[p] = newi[s->fp[p]];
    }

    if ((st = alloc_catalog(cat, n, B, K)) != GS_OK) goto done;
    cat->width = W;
    cat->height = H;
    if (s->o->labels) {
        cat->labels = malloc(sizeof(int) * s->N);
        if (!cat->labels) {
            st = gs_fail(GS_ENOMEM, "blobs: cannot hold the label image");
            goto done;
        }
        memcpy(cat->labels, s->ap, sizeof(int) * s->N);
    }
    if (n == 0) goto done;

    /* aperture pixel lists */
    pix = malloc(sizeof(int) * s->N);
    fill = malloc(sizeof(int) * (n + 1));
    stamp = malloc(sizeof(int) * (size_t)nodes);
    touched = malloc(sizeof(int) * (size_t)nodes);
    wn = malloc(sizeof(double) * (size_t)nodes);
    acc = malloc(sizeof(double) * (size_t)BK * 2);
    if (!pix || !fill || !stamp || !touched || !wn || !acc) {
        st = gs_fail(GS_ENOMEM, "blobs: cannot allocate the photometry buffers");
        goto done;
    }
    for (size_t p = 0; p < s->N; p++)
        if (s->ap[p] >= 0) start[s->ap[p] + 1]++;
    for (size_t i = 1; i <= n; i++) start[i] += start[i - 1];
    memcpy(fill, start, sizeof(int) * n);
    for (size_t p = 0; p < s->N; p++)
        if (s->ap[p] >= 0) pix[fill[s->ap[p]]++] = (int)p;
    for (int t = 0; t < nodes; t++) stamp[t] = -1;

    for (size_t i = 0; i < n; i++) {
        const int *ap = pix + start[i];
        const int na = start[i + 1] - start[i];
        unsigned flags = s->lflags[ord[i].light];
        double sw = 0, sx = 0, sy = 0, sxx = 0, syy = 0, peak_raw = 0;
        int nsat = 0, nuse = 0, ntouch = 0;
        for (int a = 0; a < na; a++) {
            int p = ap[a], x = p % W, y = p / W;
            if (x == 0 || y == 0 || x == W - 1 || y == H - 1) flags |= REC_BLOB_EDGE;
            if (s->hdr[p]) flags |= REC_BLOB_HDR;
            {
                double w = s->M[p];
                sw += w;
                sx += w * x;
                sy += w * y;
                sxx += w * x * x;
                syy += w * y * y;
            }
            if (s->fp[p] == (int)i) {
                for (int k = 0; k < K; k++) {
                    const unsigned short *r = c->raw + (s->N * (size_t)k + (size_t)p) * (size_t)B;
                    for (int b = 0; b < B; b++)
                        if (r[b] > peak_raw) peak_raw = r[b];
                }
            }
            if (s->sat[p]) {
                nsat++;
                continue;
            }
            nuse++;
            int node[4];
            double w[4];
            int m = rec_mesh_weights(&s->mesh, x, y, node, w);
            for (int t = 0; t < m; t++) {
                if (stamp[node[t]] != (int)i) {
                    stamp[node[t]] = (int)i;
                    wn[node[t]] = 0;
                    touched[ntouch++] = node[t];
                }
                wn[node[t]] += w[t];
            }
        }
        /* centroid on M - background over the footprint; its weights are above the
         * threshold, hence > 0, except where the footprint holds saturated pixels whose
         * clipped M is still positive: sw > 0 unless the data are degenerate */
        if (sw > 0 && isfinite(sw)) {
            cat->x_px[i] = sx / sw;
            cat->y_px[i] = sy / sw;
            double r2 = sxx / sw - cat->x_px[i] * cat->x_px[i] + syy / sw - cat->y_px[i] * cat->y_px[i];
            win_centroid(s, (int)i, r2, &cat->x_px[i], &cat->y_px[i]);
        } else {
            double gx = 0, gy = 0;
            int nf = 0;
            for (int a = 0; a < na; a++)
                if (s->fp[ap[a]] == (int)i) {
                    gx += ap[a] % W;
                    gy += ap[a] / W;
                    nf++;
                }
            cat->x_px[i] = nf ? gx / nf : 0;
            cat->y_px[i] = nf ? gy / nf : 0;
        }
        cat->area_px[i] = area[ord[i].light];
        cat->peak_dn[i] = peak_raw;
        cat->saturated_px[i] = nsat;
        if (nsat) flags |= REC_BLOB_SATURATED;
        if (!nuse) flags |= REC_BLOB_NO_SIGNAL;
        cat->flags[i] = flags;

        double *sig = cat->signal + i * (size_t)BK, *sgm = cat->sigma + i * (size_t)BK;
        if (!nuse) {
            for (int q = 0; q < BK; q++) {
                sig[q] = 0;
                sgm[q] = INFINITY;
            }
            continue;
        }
        double *sv = acc, *vv = acc + BK;
        memset(acc, 0, sizeof(double) * (size_t)BK * 2);
        /* Shot noise from each pixel's mean level over the K windows, not from each sample's
         * own value: a sample's own value correlates its weight with its noise and biases
         * Eq. 7 at low photon counts (docs/recognition.md). */
        for (int a = 0; a < na; a++) {
            int p = ap[a];
            if (s->sat[p]) continue;
            double mean_flux[GS_MAX_BANDS] = {0};
            for (int k = 0; k < K; k++) {
                double f = s->scale[(size_t)k * HS + (c->halvings ? c->halvings[s->N * (size_t)k + (size_t)p] : 0)];
                const unsigned short *r = c->raw + (s->N * (size_t)k + (size_t)p) * (size_t)B;
                for (int b = 0; b < B; b++) {
                    double v = ((double)r[b] - s->black) * f;
                    sv[b * K + k] += v;
                    mean_flux[b] += v / K;
                }
            }
            for (int k = 0; k < K; k++) {
                double f = s->scale[(size_t)k * HS + (c->halvings ? c->halvings[s->N * (size_t)k + (size_t)p] : 0)];
                for (int b = 0; b < B; b++) {
                    double dn = mean_flux[b] / f;   /* expected raw level above black */
                    vv[b * K + k] += (s->nz.read_var_dn2 + (dn > 0 ? dn * s->nz.inv_gain : 0)) * f * f;
                }
            }
        }
        for (int k = 0; k < K; k++)
            for (int b = 0; b < B; b++) {
                const size_t plane = ((size_t)k * B + (size_t)b) * (size_t)nodes;
                double bsum = 0, bvar = 0;
                for (int t = 0; t < ntouch; t++) {
                    int nd = touched[t];
                    bsum += wn[nd] * s->fval[plane + (size_t)nd];
                    bvar += wn[nd] * wn[nd] * s->fvar[plane + (size_t)nd];
                }
                sig[b * K + k] = sv[b * K + k] - bsum;
                sgm[b * K + k] = sqrt(vv[b * K + k] + bvar);
            }
    }
done:
    free(ord);
    free(newi);
    free(start);
    free(pix);
    free(fill);
    free(stamp);
    free(touched);
    free(wn);
    free(acc);
    return st;
}

/* ------------------------------------------------------------------- entry */

static gs_status check_opts(const rec_blob_opts *o)
{
    if (!(isfinite(o->threshold_sigma) && o->threshold_sigma > 0))
        return gs_fail(GS_EINVAL, "blobs: threshold_sigma = %g: expected a finite number > 0",
                       o->threshold_sigma);
    if (o->min_area_px < 1 || o->max_area_px < o->min_area_px)
        return gs_fail(GS_EINVAL, "blobs: min_area_px = %d, max_area_px = %d: expected "
                       "1 <= min_area_px <= max_area_px", o->min_area_px, o->max_area_px);
    if (o->background_px < 3 || o->background_px > 65535)
        return gs_fail(GS_EINVAL, "blobs: background_px = %d: expected 3 to 65535",
                       o->background_px);
    if (!(o->deblend_sigma > 0)) /* NaN fails too; +Inf disables deblending */
        return gs_fail(GS_EINVAL, "blobs: deblend_sigma = %g: expected a number > 0 (INFINITY: "
                       "never split)", o->deblend_sigma);
    if (o->grow_px < 0 || o->grow_px > 64)
        return gs_fail(GS_EINVAL, "blobs: grow_px = %d: expected 0 to 64", o->grow_px);
    if (o->labels != 0 && o->labels != 1)
        return gs_fail(GS_EINVAL, "blobs: labels = %d: expected 0 or 1", o->labels);
    return GS_OK;
}

gs_status rec_blobs_extract(const gs_capture *cap, const rec_blob_opts *o, rec_catalog *cat)
{
    if (!cat) return gs_fail(GS_EINVAL, "rec_blobs_extract: NULL catalog");
    memset(cat, 0, sizeof *cat);
    if (!cap || !o) return gs_fail(GS_EINVAL, "rec_blobs_extract: NULL capture or options");
    gs_status st = check_opts(o);
    if (st != GS_OK) return st;
    if ((st = gs_capture_check(cap, "rec_blobs_extract")) != GS_OK) return st;
    if (!cap->raw) return gs_fail(GS_EINVAL, "rec_blobs_extract: the capture has no pixels");

    state s;
    memset(&s, 0, sizeof s);
    s.cap = cap;
    s.o = o;
    s.W = cap->width;
    s.H = cap->height;
    s.K = cap->K;
    s.bands = cap->bands;
    s.N = (size_t)s.W * (size_t)s.H;
    s.sat_level = (int)ceil(cap->saturation_dn);
    s.black = (float)cap->black_level_dn;
    s.nz = gs_capture_noise(cap);
    const int HS = GS_MAX_HALVINGS + 1;
    s.scale = malloc(sizeof(double) * (size_t)s.K * HS);
    s.M = calloc(s.N, sizeof(float));
    s.sat = calloc(s.N, 1);
    s.hdr = calloc(s.N, 1);
    s.det = malloc(s.N);
    s.comp = malloc(sizeof(int) * s.N);
    s.fp = malloc(sizeof(int) * s.N);
    s.ap = malloc(sizeof(int) * s.N);
    if (cap->halvings) {
        s.sumA = calloc(s.N, sizeof(float));
        s.sumB = calloc(s.N, sizeof(float));
    }
    int *area = NULL;
    unsigned char *mask = NULL;
    if (!s.scale || !s.M || !s.sat || !s.hdr || !s.det || !s.comp || !s.fp || !s.ap ||
        (cap->halvings && (!s.sumA || !s.sumB))) {
        st = gs_fail(GS_ENOMEM, "rec_blobs_extract: cannot allocate images of %dx%d pixels", s.W,
                     s.H);
        goto done;
    }
    for (int k = 0; k < s.K; k++)
        for (int h = 0; h < HS; h++)
            s.scale[(size_t)k * HS + h] = ldexp(1.0, h) / cap->frames[k].cycles;
    for (size_t p = 0; p < s.N; p++) s.fp[p] = -1;

    if ((st = mean_image(&s)) != GS_OK) goto done;
    if ((st = rec_mesh_init(&s.mesh, s.W, s.H, o->background_px, 1)) != GS_OK) goto done;
    if ((st = detect(&s)) != GS_OK) goto done;
    if ((st = rec_cv_components(s.det, s.W, s.H, s.comp, &s.ncomp, &s.stats)) != GS_OK) goto done;

    /* the per-frame background, away from every detection */
    mask = malloc(s.N);
    const size_t fsize = (size_t)s.K * s.bands * (size_t)(s.mesh.nx * s.mesh.ny);
    s.fval = malloc(sizeof(double) * fsize);
    s.fvar = malloc(sizeof(double) * fsize);
    if (!mask || !s.fval || !s.fvar) {
        st = gs_fail(GS_ENOMEM, "rec_blobs_extract: cannot allocate the frame background");
        goto done;
    }
    memcpy(mask, s.det, s.N);
    if ((st = rec_cv_dilate_u8(mask, s.W, s.H, o->grow_px + MASK_MARGIN)) != GS_OK) goto done;
    if ((st = frame_mesh(&s, mask, 1)) != GS_OK) goto done;

    if ((st = deblend(&s)) != GS_OK) goto done;
    area = calloc((size_t)(s.nlights ? s.nlights : 1), sizeof *area);
    if (!area) {
        st = gs_fail(GS_ENOMEM, "rec_blobs_extract: cannot hold %d lights", s.nlights);
        goto done;
    }
    if ((st = apertures(&s, area)) != GS_OK) goto done;
    st = photometry(&s, area, cat);
done:
    free(area);
    free(mask);
    state_free(&s);
    if (st != GS_OK) rec_catalog_release(cat);
    return st;
}
