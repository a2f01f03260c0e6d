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

