/* blobs_photometry.c - steps 6-8 of the blob extraction (recognize.h, rec_blobs_extract):
 * apertures grown from the footprints, per-frame sums with the per-frame background and their
 * noise, and the windowed centroid. */
#include "recognize/internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------- 6. aperture, 7. photometry */

/* Drop lights whose footprint area is outside the limits; grow the apertures. */
gs_status rec_blob_apertures(rec_blob_state *s, int *area)
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

/* The window of step 8 for a footprint's second moment r2 (px^2, both axes): sigma. */
static double window_sigma(double r2)
{
    double sw = sqrt(r2 / 2);
    if (!(sw >= 1)) sw = 1;
    return sw > 8 ? 8 : sw;
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
static void win_centroid(const rec_blob_state *s, int light, double r2, double *xc, double *yc)
{
    const double sw = window_sigma(r2);
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

double rec_centroid_bias_px(double psf_sigma_px)
{
    if (!(psf_sigma_px > 0 && psf_sigma_px <= 64)) return NAN;
    enum { PHASES = 40, ITER = 100 };
    const double sp = sqrt(psf_sigma_px * psf_sigma_px + 1.0 / 12.0), sw = window_sigma(2 * sp * sp);
    const int R = (int)ceil(4 * sw) + 1;
    const double k = 1.0 / (sqrt(2.0) * psf_sigma_px);
    double sum2 = 0;
    for (int ph = 0; ph < PHASES; ph++) {
        /* one axis (the PSF and the window are separable): pixel shares of a Gaussian at c */
        double c = (double)ph / PHASES, x = 0;
        for (int it = 0; it < ITER; it++) {
            double sw_sum = 0, sx = 0;
            for (int i = -R; i <= R; i++) {
                double g = 0.5 * (erf((i + 0.5 - c) * k) - erf((i - 0.5 - c) * k));
                double w = exp(-(i - x) * (i - x) / (2 * sw * sw)) * g;
                sw_sum += w;
                sx += w * (i - x);
            }
            double d = 2 * sx / sw_sum;
            x += d;
            if (fabs(d) < 1e-12) break;
        }
        sum2 += (x - c) * (x - c);
    }
    return sqrt(sum2 / PHASES);
}

/* Noise of pixel p's samples from the pixel's mean level over the K windows (shot + read),
 * var_k[b * K + k] in (DN per cycle)^2; level_k (NULL: not wanted) the samples' levels
 * (raw - black) x scale. The raw frames are read once. */
void rec_blob_pixel_var(const rec_blob_state *s, size_t p, double *var_k, double *level_k)
{
    const gs_capture *c = s->cap;
    const int B = s->bands, K = s->K, HS = GS_MAX_HALVINGS + 1;
    double mean_flux[GS_MAX_BANDS] = {0};
    for (int k = 0; k < K; k++) {
        double f = s->scale[(size_t)k * HS + (c->halvings ? c->halvings[s->N * (size_t)k + p] : 0)];
        const unsigned short *r = c->raw + (s->N * (size_t)k + p) * (size_t)B;
        for (int b = 0; b < B; b++) {
            double l = ((double)r[b] - s->black) * f;
            mean_flux[b] += l;
            if (level_k) level_k[b * K + k] = l;
        }
    }
    for (int b = 0; b < B; b++) mean_flux[b] /= K;
    for (int b = 0; b < B; b++)
        for (int k = 0; k < K; k++) {
            double f = s->scale[(size_t)k * HS + (c->halvings ? c->halvings[s->N * (size_t)k + p] : 0)];
            double dn = mean_flux[b] / f;   /* expected raw level above black */
            var_k[b * K + k] = (s->nz.read_var_dn2 + (dn > 0 ? dn * s->nz.inv_gain : 0)) * f * f;
        }
}

/* The share of a Gaussian PSF of sigma centred at (xc, yc) that falls in pixel (x, y). */
double rec_psf_share(int x, int y, double xc, double yc, double sigma)
{
    const double k = 1.0 / (sqrt(2.0) * sigma);
    double fx = 0.5 * (erf((x + 0.5 - xc) * k) - erf((x - 0.5 - xc) * k));
    double fy = 0.5 * (erf((y + 0.5 - yc) * k) - erf((y - 0.5 - yc) * k));
    return fx * fy;
}

/* The capture's PSF sigma (7.): the median of sqrt(r2 / 2) (the aperture's second moment on
 * M - background) over its brightest clean lights (no flag, footprint >= 9 px), at most
 * PSF_LIGHTS of them; 1 px when there is none. Clamped to [0.3, 8] px. */
#define PSF_LIGHTS 64
static double capture_psf_sigma(const rec_catalog *cat, const double *r2, const double *bright, size_t n)
{
    double br[PSF_LIGHTS], sg[PSF_LIGHTS];
    int idx[PSF_LIGHTS], m = 0;
    for (size_t i = 0; i < n; i++) {
        if (cat->flags[i] || cat->area_px[i] < 9 || !(r2[i] > 0) || !isfinite(bright[i])) continue;
        int slot = m < PSF_LIGHTS ? m++ : -1;
        if (slot < 0) {   /* replace the faintest kept one */
            int lo = 0;
            for (int q = 1; q < m; q++)
                if (br[q] < br[lo]) lo = q;
            if (!(bright[i] > br[lo])) continue;
            slot = lo;
        }
        br[slot] = bright[i];
        idx[slot] = (int)i;
    }
    if (m == 0) return 1.0;
    for (int q = 0; q < m; q++) sg[q] = sqrt(r2[idx[q]] / 2);
    qsort(sg, (size_t)m, sizeof *sg, gs_cmp_double);
    double med = (m & 1) ? sg[m / 2] : 0.5 * (sg[m / 2 - 1] + sg[m / 2]);
    return med < 0.3 ? 0.3 : med > 8 ? 8 : med;
}

/* The catalog: lights in raster order of their first footprint pixel. */
gs_status rec_blob_photometry(rec_blob_state *s, const int *area, rec_catalog *cat)
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
    double *wn = NULL, *acc = NULL, *r2s = NULL, *bright = NULL;
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
    wn = malloc(sizeof(double) * (size_t)nodes * (size_t)B);
    acc = malloc(sizeof(double) * (size_t)BK * 3);
    r2s = malloc(sizeof(double) * n);
    bright = malloc(sizeof(double) * n);
    if (!pix || !fill || !stamp || !touched || !wn || !acc || !r2s || !bright) {
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

    /* the positions first (8.), then the capture's PSF from its bright clean lights */
    for (size_t i = 0; i < n; i++) {
        const int *ap = pix + start[i];
        const int na = start[i + 1] - start[i];
        unsigned flags = s->lflags[ord[i].light];
        double sw = 0, sx = 0, sy = 0, sxx = 0, syy = 0, peak_raw = 0;
        int nsat = 0, nuse = 0;
        for (int a = 0; a < na; a++) {
            int p = ap[a], x = p % W, y = p / W;
            if (x == 0 || y == 0 || x == W - 1 || y == H - 1) flags |= REC_BLOB_EDGE;
            if (s->hdr[p]) flags |= REC_BLOB_HDR;
            double w = s->M[p];
            sw += w;
            sx += w * x;
            sy += w * y;
            sxx += w * x * x;
            syy += w * y * y;
            if (s->fp[p] == (int)i) {
                for (int k = 0; k < K; k++) {
                    const unsigned short *r = c->raw + (s->N * (size_t)k + (size_t)p) * (size_t)B;
                    for (int b = 0; b < B; b++)
                        if (r[b] > peak_raw) peak_raw = r[b];
                }
            }
            if (s->sat[p]) nsat++;
            else nuse++;
        }
        /* centroid on M - background over the footprint; its weights are above the
         * threshold, hence > 0, except where the footprint holds saturated pixels whose
         * clipped M is still positive: sw > 0 unless the data are degenerate */
        r2s[i] = NAN;
        bright[i] = sw;
        if (sw > 0 && isfinite(sw)) {
            cat->x_px[i] = sx / sw;
            cat->y_px[i] = sy / sw;
            double r2 = sxx / sw - cat->x_px[i] * cat->x_px[i] + syy / sw - cat->y_px[i] * cat->y_px[i];
            win_centroid(s, (int)i, r2, &cat->x_px[i], &cat->y_px[i]);
            r2s[i] = r2;
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
    }
    s->psf_sigma = capture_psf_sigma(cat, r2s, bright, n);
    double psf_sigma = s->o->psf_weighted ? s->psf_sigma : 0.0;

    for (size_t i = 0; i < n; i++) {
        const int *ap = pix + start[i];
        const int na = start[i + 1] - start[i];
        int ntouch = 0;
        double *sig = cat->signal + i * (size_t)BK, *sgm = cat->sigma + i * (size_t)BK;
        if (cat->flags[i] & REC_BLOB_NO_SIGNAL) {
            for (int q = 0; q < BK; q++) {
                sig[q] = 0;
                sgm[q] = INFINITY;
            }
            continue;
        }
        double *sv = acc, *vv = acc + BK, wsum[GS_MAX_BANDS] = {0};
        memset(acc, 0, sizeof(double) * (size_t)BK * 2);
        /* the PSF's share inside the usable aperture: a light whose centroid left it (a
         * degenerate one) keeps the plain sum */
        double psf = psf_sigma, mass = 0;
        for (int a = 0; a < na && psf > 0; a++)
            if (!s->sat[ap[a]]) mass += rec_psf_share(ap[a] % W, ap[a] / W, cat->x_px[i], cat->y_px[i], psf);
        if (!(mass > 0.05)) psf = 0;
        /* Shot noise from each pixel's mean level over the K windows, not from each sample's
         * own value: a sample's own value correlates its weight with its noise and biases
         * Eq. 7 at low photon counts (docs/recognition.md). The pixel's weight (7.): 1, or
         * its PSF share over its variance averaged over the windows, the same in every
         * frame. */
        for (int a = 0; a < na; a++) {
            int p = ap[a], x = p % W, y = p / W;
            if (s->sat[p]) continue;
            double *var_k = acc + 2 * BK, wpix[GS_MAX_BANDS];
            rec_blob_pixel_var(s, (size_t)p, var_k, NULL);
            double prof = psf > 0 ? rec_psf_share(x, y, cat->x_px[i], cat->y_px[i], psf) : 1.0;
            for (int b = 0; b < B; b++) {
                double vmean = 0;
                for (int k = 0; k < K; k++) vmean += var_k[b * K + k] / K;
                wpix[b] = psf > 0 ? (vmean > 0 && isfinite(vmean) ? prof / vmean : prof) : 1.0;
                wsum[b] += wpix[b] * prof;
            }
            for (int k = 0; k < K; k++) {
                double f = s->scale[(size_t)k * HS + (c->halvings ? c->halvings[s->N * (size_t)k + (size_t)p] : 0)];
                const unsigned short *r = c->raw + (s->N * (size_t)k + (size_t)p) * (size_t)B;
                for (int b = 0; b < B; b++) {
                    sv[b * K + k] += wpix[b] * ((double)r[b] - s->black) * f;
                    vv[b * K + k] += wpix[b] * wpix[b] * var_k[b * K + k];
                }
            }
            int node[4];
            double w[4];
            int m = rec_mesh_weights(&s->mesh, x, y, node, w);
            for (int t = 0; t < m; t++) {
                if (stamp[node[t]] != (int)i) {
                    stamp[node[t]] = (int)i;
                    for (int b = 0; b < B; b++) wn[(size_t)b * (size_t)nodes + (size_t)node[t]] = 0;
                    touched[ntouch++] = node[t];
                }
                for (int b = 0; b < B; b++) wn[(size_t)b * (size_t)nodes + (size_t)node[t]] += wpix[b] * w[t];
            }
        }
        for (int b = 0; b < B; b++) {
            /* the weighted sum estimates sum_p w_p P_p times the flux: divide it out */
            double norm = psf > 0 ? (wsum[b] > 0 ? 1.0 / wsum[b] : 0.0) : 1.0;
            for (int k = 0; k < K; k++) {
                const size_t plane = ((size_t)k * B + (size_t)b) * (size_t)nodes;
                double bsum = 0, bvar = 0;
                for (int t = 0; t < ntouch; t++) {
                    double wt = wn[(size_t)b * (size_t)nodes + (size_t)touched[t]];
                    bsum += wt * s->fval[plane + (size_t)touched[t]];
                    bvar += wt * wt * s->fvar[plane + (size_t)touched[t]];
                }
                sig[b * K + k] = (sv[b * K + k] - bsum) * norm;
                sgm[b * K + k] = sqrt(vv[b * K + k] + bvar) * norm;
            }
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
    free(r2s);
    free(bright);
    return st;
}

