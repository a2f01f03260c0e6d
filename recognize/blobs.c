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

/* A mesh node needs this many usable pixels (and this fraction of its box) for the per-frame
 * background; others are filled from their neighbours. */
#define NODE_MIN_PX 8
#define NODE_MIN_FRACTION 0.1
/* Robust level of a box of M: median after this many 3-sigma clips (sigma = 1.4826 MAD). */
#define CLIP_ITER 2
#define CLIP_SIGMA 3.0
/* The per-frame background ignores pixels within grow_px + this of a detection. */
#define MASK_MARGIN 2
/* Halo cut (step 4): a pixel is detected only when it holds at least HALO_FRACTION of the
 * brightest M - background within HALO_RADIUS pixels (Chebyshev), so that the faint wide halos
 * around lights (scattering, skyglow) never join neighbours however long the exposure. */
#define HALO_FRACTION 0.01f
#define HALO_RADIUS 8

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
    o->psf_weighted = 1;
    o->psf_fit = 1;
    o->threads = 0;
    o->psf_fit_exhaustive = 0;
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
    free(cat->pos_cov_px2);
    free(cat->signal);
    free(cat->sigma);
    free(cat->labels);
    free(cat->drift_windows);
    memset(cat, 0, sizeof *cat);
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
            qsort(v, (size_t)n, sizeof *v, gs_cmp_double);
            g[j * nx + i] = v[n / 2];
        }
}

/* ------------------------------------------------------------------ rec_blob_state */


static void state_free(rec_blob_state *s)
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


/* ------------------------------------------------------- 1. mean image */

/* Pixels [p0, p1) of the mean image: each pixel's frames summed in frame order (the same
 * floats on any split). */
static gs_status mean_pixels(void *ctx, int part, size_t p0, size_t p1)
{
    (void)part;
    rec_blob_state *s = ctx;
    const gs_capture *c = s->cap;
    const int HS = GS_MAX_HALVINGS + 1;
    const int B = s->bands;
    for (int k = 0; k < s->K; k++) {
        const unsigned short *rk = c->raw + s->N * (size_t)B * (size_t)k;
        const unsigned char *hk = c->halvings ? c->halvings + s->N * (size_t)k : NULL;
        const double *sc = s->scale + (size_t)k * HS;
        const float sc0 = (float)sc[0];
        for (size_t p = p0; p < p1; p++) {
            float acc = 0;
            int satp = 0;
            for (int b = 0; b < B; b++) {
                unsigned r = rk[p * (size_t)B + (size_t)b];
                satp |= (int)r >= s->sat_level;
                acc += (float)r - s->black;
            }
            s->sat[p] |= (unsigned char)satp;
            if (hk) {
                unsigned h = hk[p];   /* <= GS_MAX_HALVINGS: mean_image checked */
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
    for (size_t p = p0; p < p1; p++) s->M[p] *= invK;
    return GS_OK;
}

static gs_status mean_image(rec_blob_state *s)
{
    const gs_capture *c = s->cap;
    for (int k = 0; c->halvings && k < s->K; k++)
        for (size_t p = 0; p < s->N; p++) {
            unsigned h = c->halvings[s->N * (size_t)k + p];
            if (h > GS_MAX_HALVINGS)
                return gs_fail(GS_EINVAL, "blobs: frame %d pixel (x %zu, y %zu): %u halvings: "
                               "expected 0 to %d", k, p % (size_t)s->W, p / (size_t)s->W, h,
                               GS_MAX_HALVINGS);
        }
    return gs_parallel_for(s->o->threads, s->N, mean_pixels, s);
}

/* ----------------------------------------- 2-4. background, noise, threshold */

static gs_status detect(rec_blob_state *s)
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
    /* the halo cut, on the local maximum of M - background (bg reused for it) */
    gs_status st = rec_cv_dilate_f32(s->M, bg, s->W, s->H, HALO_RADIUS);
    if (st == GS_OK)
        for (size_t p = 0; p < s->N; p++)
            if (!s->sat[p] && s->M[p] < HALO_FRACTION * bg[p]) s->det[p] = 0;
    free(buf);
    free(level);
    free(bg);
    return st;
}

/* ------------------------------------------------ per-frame background mesh */

/* Frames [k0, k1) of frame_mesh: each node's sums of its pixels' values and variances, each
 * frame into its own planes (the same sums on any split). */
typedef struct {
    rec_blob_state *s;
    const unsigned char *mask;   /* NULL: every unsaturated pixel */
} frame_sums;

static gs_status frame_sums_part(void *ctx, int part, size_t k0, size_t k1)
{
    (void)part;
    const frame_sums *fs = ctx;
    rec_blob_state *s = fs->s;
    const gs_capture *c = s->cap;
    const rec_mesh *m = &s->mesh;
    const int nodes = m->nx * m->ny, B = s->bands, HS = GS_MAX_HALVINGS + 1;
    for (size_t k = k0; k < k1; k++) {
        const unsigned short *rk = c->raw + s->N * (size_t)B * k;
        const unsigned char *hk = c->halvings ? c->halvings + s->N * k : NULL;
        const double *sc = s->scale + k * HS;
        double *val = s->fval + k * B * nodes, *var = s->fvar + k * B * nodes;
        for (int y = 0; y < s->H; y++) {
            const size_t row = (size_t)y * s->W;
            const int nrow = m->iy[y] * m->nx;
            for (int x = 0; x < s->W; x++) {
                size_t p = row + (size_t)x;
                if (s->sat[p] || (fs->mask && fs->mask[p])) continue;
                double f = sc[hk ? hk[p] : 0];
                int n = nrow + m->ix[x];
                for (int b = 0; b < B; b++) {
                    unsigned r = rk[p * (size_t)B + (size_t)b];
                    val[b * nodes + n] += ((float)r - s->black) * f;
                    var[b * nodes + n] += rec_blob_sample_var(s, r, f);
                }
            }
        }
    }
    return GS_OK;
}

/* For every frame and band, each node: the mean of the values of its box's pixels outside the
 * dilated detections (and unsaturated), and the variance of that mean. use_mask = 0 takes every
 * unsaturated pixel (the fallback when detections cover nearly everything). */
static gs_status frame_mesh(rec_blob_state *s, const unsigned char *mask, int use_mask)
{
    const rec_mesh *m = &s->mesh;
    const int nodes = m->nx * m->ny, B = s->bands;
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
    frame_sums fs = {s, use_mask ? mask : NULL};
    gs_status st = gs_parallel_for(s->o->threads, (size_t)s->K, frame_sums_part, &fs);
    if (st != GS_OK) {
        free(cnt);
        free(good);
        return st;
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
double rec_blob_frame_bg(const rec_blob_state *s, int k, int b, int x, int y)
{
    const int nodes = s->mesh.nx * s->mesh.ny;
    return rec_mesh_at(&s->mesh, s->fval + ((size_t)k * s->bands + (size_t)b) * nodes, 1, x, y);
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
    if (o->psf_weighted != 0 && o->psf_weighted != 1)
        return gs_fail(GS_EINVAL, "blobs: psf_weighted = %d: expected 0 or 1", o->psf_weighted);
    if (o->psf_fit != 0 && o->psf_fit != 1)
        return gs_fail(GS_EINVAL, "blobs: psf_fit = %d: expected 0 or 1", o->psf_fit);
    if (o->threads < 0) return gs_fail(GS_EINVAL, "blobs: threads = %d: expected >= 0 (0: the online CPUs)", o->threads);
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

    rec_blob_state s;
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
    free(mask);
    mask = NULL;

    if ((st = rec_blob_deblend(&s)) != GS_OK) goto done;
    area = calloc((size_t)(s.nlights ? s.nlights : 1), sizeof *area);
    if (!area) {
        st = gs_fail(GS_ENOMEM, "rec_blobs_extract: cannot hold %d lights", s.nlights);
        goto done;
    }
    if ((st = rec_blob_apertures(&s, area)) != GS_OK) goto done;
    if ((st = rec_blob_photometry(&s, area, cat)) != GS_OK) goto done;
    if ((st = rec_blob_psf_fit(&s, cat)) != GS_OK) goto done;
    if (!cap->locked) {
        if (!(cat->drift_windows = malloc(sizeof *cat->drift_windows * (size_t)s.K))) {
            st = gs_fail(GS_ENOMEM, "rec_blobs_extract: out of memory");
            goto done;
        }
        for (int k = 0; k < s.K; k++) cat->drift_windows[k] = gs_capture_frame_drift(cap, k);
        cat->window_period = cap->window_period;
    }
done:
    free(area);
    free(mask);
    state_free(&s);
    if (st != GS_OK) rec_catalog_release(cat);
    return st;
}
