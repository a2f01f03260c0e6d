/* maps.c - per-pixel recognition maps like the paper's Fig. 1 (grid phase, bulb type,
 * confidence; Sheinin, Schechner, Kutulakos, CVPR 2017, Sec. 4): the per-cycle values of every
 * pixel (docs/formats.md), minus a mesh background, go through rec_match_pixels (Eq. 7 as SGEMM
 * blocks) when the pixel stands above the noise. The pictures are drawn by maps_draw.c. */
#include "recognize/recognize.h"
#include "recognize/internal.h"

#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define BG_BOX 64            /* background mesh box side, pixels (SExtractor's default) */
#define BG_SAMPLES 256       /* at most this many pixels per box enter its median */
#define MAP_BLOCK 4096       /* mapped pixels per rec_match_pixels call and thread */
#define PASS1_TILE 4096      /* pixels whose sums stay in cache while the frames stream by */
#define MAP_TARGET_PX 640    /* the map is scaled up to about this many pixels on its long side */
#define MAP_MAX_SCALE 16

/* ------------------------------------------------------------ options, release */

void rec_map_opts_default(rec_map_opts *o)
{
    if (!o) return;
    o->threshold_sigma = 5.0;
    o->progress = NULL;
    o->progress_ctx = NULL;
}

void rec_pixel_maps_release(rec_pixel_maps *pm)
{
    if (!pm) return;
    free(pm->state);
    free(pm->bulb);
    free(pm->phase_deg);
    free(pm->confidence);
    free(pm->brightness);
    free(pm->snr);
    memset(pm, 0, sizeof *pm);
}

int rec_map_scale(int width, int height)
{
    int side = width > height ? width : height;
    if (side < 1) return 1;
    int s = MAP_TARGET_PX / side;
    return s < 1 ? 1 : s > MAP_MAX_SCALE ? MAP_MAX_SCALE : s;
}

/* ------------------------------------------------------------ background mesh */

/* The RMS noise of one of a pixel's D samples, from the variance of its brightness sum. */
static inline float row_noise(double var_sum, size_t D)
{
    return (float)sqrt(var_sum / (double)D);
}

/* Sample (k, y, x, band) of the capture as per-cycle DN (docs/formats.md), NaN when saturated.
 * Reads cap->raw directly (the hot loop). */
static inline double sample_value(const gs_capture *cap, const double *inv_cycles, size_t k,
                                  size_t pix, int band)
{
    size_t np = (size_t)cap->width * (size_t)cap->height;
    double raw = cap->raw[(k * np + pix) * (size_t)cap->bands + (size_t)band];
    double c = inv_cycles[k];
    if (cap->halvings) c *= (double)(1u << cap->halvings[k * np + pix]);
    if (raw >= cap->saturation_dn) return NAN;
    return (raw - cap->black_level_dn) * c;
}

/* The per-frame background: node values over the shared mesh (constant beyond the outer box
 * centres). */
typedef struct {
    rec_mesh g;
    float *node;        /* [(k * bands + band) * nodes + node] box medians */
} mesh;

static void mesh_free(mesh *m)
{
    rec_mesh_free(&m->g);
    free(m->node);
    m->node = NULL;
}

static gs_status mesh_build(const gs_capture *cap, const double *inv_cycles, mesh *m)
{
    memset(m, 0, sizeof *m);
    int W = cap->width, H = cap->height, K = cap->K, bands = cap->bands;
    gs_status st = rec_mesh_init(&m->g, W, H, BG_BOX, 0);
    if (st != GS_OK) return st;
    size_t nodes = (size_t)m->g.nx * (size_t)m->g.ny;
    /* a box of the mesh is at most 3/2 BG_BOX on a side */
    size_t buf_n = BG_SAMPLES + 4 * BG_BOX;
    m->node = malloc(sizeof *m->node * nodes * (size_t)K * (size_t)bands);
    float *buf = malloc(sizeof *buf * buf_n);
    if (!m->node || !buf) {
        free(buf);
        mesh_free(m);
        return gs_fail(GS_ENOMEM, "maps: cannot allocate the background mesh");
    }
    for (int j = 0; j < m->g.ny; j++) {
        int y0 = m->g.by[j], y1 = m->g.by[j + 1];
        for (int i = 0; i < m->g.nx; i++) {
            int x0 = m->g.bx[i], x1 = m->g.bx[i + 1];
            int area = (x1 - x0) * (y1 - y0);
            int step = 1;
            while ((area + step * step - 1) / (step * step) > BG_SAMPLES) step++;
            for (int k = 0; k < K; k++)
                for (int band = 0; band < bands; band++) {
                    size_t n = 0;
                    for (int y = y0; y < y1; y += step)
                        for (int x = x0; x < x1; x += step) {
                            double v = sample_value(cap, inv_cycles, (size_t)k,
                                                    (size_t)y * (size_t)W + (size_t)x, band);
                            if (isfinite(v) && n < buf_n) buf[n++] = (float)v;
                        }
                    m->node[((size_t)k * (size_t)bands + (size_t)band) * nodes + (size_t)j * (size_t)m->g.nx + (size_t)i] =
                        n ? gs_median_f(buf, n) : 0.0f;
                }
        }
    }
    free(buf);
    return GS_OK;
}

static inline float mesh_at(const mesh *m, size_t plane, int x, int y)
{
    return rec_mesh_at_f(&m->g, m->node + plane * (size_t)m->g.nx * (size_t)m->g.ny, x, y);
}

/* ------------------------------------------------------------ per-pixel Eq. 7 */

/* GS_EINVAL unless m was built for this band count and K: rec_match_catalog checks both, so ask it
 * about a one-light catalog without signal (the matcher has no accessor for K). */
static gs_status check_matcher(const rec_matcher *m, int bands, int K)
{
    size_t D = (size_t)bands * (size_t)K;
    double *sig = calloc(2 * D, sizeof *sig);
    if (!sig) return gs_fail(GS_ENOMEM, "maps: cannot allocate %zu values", 2 * D);
    for (size_t d = 0; d < D; d++) sig[D + d] = INFINITY;
    double x = 0.0, y = 0.0, peak = 0.0;
    int area = 1, sat = 0;
    unsigned flags = REC_BLOB_NO_SIGNAL;
    rec_catalog one = {.count = 1, .bands = bands, .K = K, .x_px = &x, .y_px = &y,
                       .area_px = &area, .peak_dn = &peak, .saturated_px = &sat, .flags = &flags,
                       .signal = sig, .sigma = sig + D, .width = 1, .height = 1, .labels = NULL};
    rec_match r;
    gs_status st = rec_match_catalog(m, &one, &r, NULL);
    free(sig);
    if (st == GS_OK) return GS_OK;
    char why[512];
    snprintf(why, sizeof why, "%s", gs_detail());
    return gs_fail(GS_EINVAL, "maps: the matcher was not built for %d band(s) and K = %d (%s)",
                   bands, K, why);
}

gs_status rec_pixel_maps_compute(const gs_capture *cap, const rec_matcher *m,
                                 const rec_eq7_opts *eq7, const rec_map_opts *o,
                                 rec_pixel_maps *pm)
{
    if (!pm) return gs_fail(GS_EINVAL, "maps: no output");
    memset(pm, 0, sizeof *pm);
    rec_map_opts dflt;
    rec_map_opts_default(&dflt);
    if (!o) o = &dflt;
    rec_eq7_opts e7;
    rec_eq7_opts_default(&e7);
    if (eq7) e7 = *eq7;
    if (!cap || !m || !cap->raw || !cap->frames)
        return gs_fail(GS_EINVAL, "maps: expected a capture with pixels and a matcher");
    if (!(o->threshold_sigma > 0.0) || !isfinite(o->threshold_sigma))
        return gs_fail(GS_EINVAL, "maps: threshold_sigma %g: expected a finite number > 0",
                       o->threshold_sigma);
    gs_status st = gs_capture_check(cap, "maps: capture");
    if (st != GS_OK) return st;
    st = check_matcher(m, cap->bands, cap->K);
    if (st != GS_OK) return st;

    int W = cap->width, H = cap->height, K = cap->K, bands = cap->bands;
    size_t np = (size_t)W * (size_t)H, D = (size_t)bands * (size_t)K;
    pm->width = W;
    pm->height = H;
    pm->phases = e7.phases;
    pm->transformer_deg = e7.transformer_deg;
    pm->ambiguous_conf = e7.ambiguous_conf;
    pm->threshold_sigma = o->threshold_sigma;
    pm->state = calloc(np, 1);
    pm->bulb = malloc(sizeof *pm->bulb * np);
    pm->phase_deg = calloc(np, sizeof *pm->phase_deg);
    pm->confidence = calloc(np, sizeof *pm->confidence);
    pm->brightness = calloc(np, sizeof *pm->brightness);
    pm->snr = calloc(np, sizeof *pm->snr);
    double *inv_cycles = malloc(sizeof *inv_cycles * (size_t)K);
    if (!pm->state || !pm->bulb || !pm->phase_deg || !pm->confidence || !pm->brightness ||
        !pm->snr || !inv_cycles) {
        free(inv_cycles);
        rec_pixel_maps_release(pm);
        return gs_fail(GS_ENOMEM, "maps: cannot allocate maps of %dx%d pixels", W, H);
    }
    for (size_t p = 0; p < np; p++) pm->bulb[p] = -1;
    for (int k = 0; k < K; k++) inv_cycles[cap->frames[k].k] = 1.0 / cap->frames[k].cycles;

    mesh bg;
    st = mesh_build(cap, inv_cycles, &bg);
    if (st != GS_OK) {
        free(inv_cycles);
        rec_pixel_maps_release(pm);
        return st;
    }

    /* pass 1: brightness B (sum over bands of the mean over k), its noise, saturation, the SNR
     * and the threshold. Streams the raw samples once in memory order, in tiles of pixels whose
     * sums stay in cache while the K frames stream by; the background is linear in its mesh
     * nodes, so its contribution to B is one interpolation of the nodes summed over frames and
     * bands. Without HDR maps and shot noise every pixel has the same variance, and the black
     * level comes off as one constant: the inner loop only adds integers. */
    const gs_noise nz = gs_capture_noise(cap);
    const double v0 = nz.read_var_dn2, inv_gain = nz.inv_gain, black = nz.black_dn;
    const int fast = !cap->halvings && inv_gain == 0.0;
    double csum = 0.0, c2sum = 0.0;
    for (int k = 0; k < K; k++) {
        csum += inv_cycles[k];
        c2sum += inv_cycles[k] * inv_cycles[k];
    }
    const double var_fast = bands * v0 * c2sum;
    /* the RMS noise of a sample of each pixel to match, in the order pass 2 takes them (where
     * it varies; else one value) */
    float *row_sigma = fast ? NULL : malloc(sizeof *row_sigma * np);
    float *bg_mean = malloc(sizeof *bg_mean * (size_t)bg.g.nx * (size_t)bg.g.ny);
    double *sum = malloc(sizeof *sum * PASS1_TILE), *var = fast ? NULL : malloc(sizeof *var * PASS1_TILE);
    if (!bg_mean || !sum || (!fast && (!var || !row_sigma))) {
        free(row_sigma);
        free(bg_mean);
        free(sum);
        free(var);
        mesh_free(&bg);
        free(inv_cycles);
        rec_pixel_maps_release(pm);
        return gs_fail(GS_ENOMEM, "maps: cannot allocate maps of %dx%d pixels", W, H);
    }
    {
        size_t nodes = (size_t)bg.g.nx * (size_t)bg.g.ny;
        for (size_t q = 0; q < nodes; q++) {
            double acc = 0.0;
            for (size_t plane = 0; plane < (size_t)K * (size_t)bands; plane++) acc += bg.node[plane * nodes + q];
            bg_mean[q] = (float)(acc / K);
        }
    }
    const unsigned sat_dn = cap->saturation_dn > 65535.0 ? 65536u : (unsigned)ceil(cap->saturation_dn);
    size_t mapped = 0, to_match = 0;
    for (size_t p0 = 0; p0 < np; p0 += PASS1_TILE) {
        size_t n = np - p0 < PASS1_TILE ? np - p0 : PASS1_TILE;
        memset(sum, 0, sizeof *sum * n);
        if (var) memset(var, 0, sizeof *var * n);
        for (int k = 0; k < K; k++) {
            const unsigned short *rk = cap->raw + ((size_t)k * np + p0) * (size_t)bands;
            const double c = inv_cycles[k];
            if (fast) {
                for (size_t i = 0; i < n; i++) {
                    unsigned acc = 0, mx = 0;
                    for (int band = 0; band < bands; band++) {
                        unsigned r = rk[i * (size_t)bands + (size_t)band];
                        acc += r;
                        mx = r > mx ? r : mx;
                    }
                    sum[i] += c * (double)acc;
                    if (mx >= sat_dn) pm->state[p0 + i] = REC_PIX_SATURATED;
                }
                continue;
            }
            const unsigned char *hk = cap->halvings ? cap->halvings + (size_t)k * np + p0 : NULL;
            for (size_t i = 0; i < n; i++) {
                double ci = hk ? c * (double)(1u << hk[i]) : c;
                double e_sum = 0.0, e_pos = 0.0;
                unsigned mx = 0;
                for (int band = 0; band < bands; band++) {
                    unsigned r = rk[i * (size_t)bands + (size_t)band];
                    double e = (double)r - black;
                    mx = r > mx ? r : mx;
                    e_sum += e;
                    if (e > 0.0) e_pos += e;
                }
                if (mx >= sat_dn) pm->state[p0 + i] = REC_PIX_SATURATED;
                sum[i] += e_sum * ci;
                var[i] += (bands * v0 + e_pos * inv_gain) * ci * ci;
            }
        }
        for (size_t i = 0; i < n; i++) {
            size_t p = p0 + i;
            int x = (int)(p % (size_t)W), y = (int)(p / (size_t)W);
            if (fast) sum[i] -= bands * black * csum;
            /* the background of the summed nodes */
            pm->brightness[p] = (float)(sum[i] / K - rec_mesh_at_f(&bg.g, bg_mean, x, y));
            double v = fast ? var_fast : var[i];
            if (pm->state[p] == REC_PIX_SATURATED) {
                mapped++;
                continue;
            }
            double sd = sqrt(v) / K;
            pm->snr[p] = sd > 0.0 ? (float)(pm->brightness[p] / sd) : 0.0f;
            if (pm->snr[p] > o->threshold_sigma) {
                pm->state[p] = REC_PIX_NO_ANSWER;   /* until matched */
                mapped++;
                if (row_sigma) row_sigma[to_match] = row_noise(v, D);
                to_match++;
            }
        }
    }
    free(sum);
    free(var);
    free(bg_mean);
    pm->mapped = mapped;
    if (row_sigma && to_match) {   /* (the rest goes back before the matcher's blocks come) */
        float *shrunk = realloc(row_sigma, sizeof *row_sigma * to_match);
        if (shrunk) row_sigma = shrunk;
    }

    /* pass 2: Eq. 7 on the mapped, unsaturated pixels, in blocks */
    size_t cap_rows = MAP_BLOCK * (size_t)gs_threads_resolve(m->o.threads);   /* (rows are independent) */
    size_t *idx = malloc(sizeof *idx * cap_rows);
    float *xb = malloc(sizeof *xb * cap_rows * D);
    float *ph = malloc(sizeof *ph * cap_rows), *cf = malloc(sizeof *cf * cap_rows);
    float *sg = row_sigma ? NULL : malloc(sizeof *sg * cap_rows);   /* (every pixel's) */
    int *bb = malloc(sizeof *bb * cap_rows);
    if (!idx || !xb || !ph || !cf || !bb || (!row_sigma && !sg))
        st = gs_fail(GS_ENOMEM, "maps: cannot allocate a block of %zu pixels", cap_rows);
    for (size_t r = 0; sg && r < cap_rows; r++) sg[r] = row_noise(var_fast, D);
    size_t done = 0, p = 0;
    /* a frame whose windows smeared across the flicker: no pixel answered (the rows have one
     * sigma each, so its samples can neither be left out nor have their noise raised as
     * rec_match_catalog does: not beyond REC_MAX_DRIFT_WINDOWS whatever the option) */
    pm->drift_limit_windows = fmin(rec_drift_limit(m->o.max_drift_windows, cap->window_period), REC_MAX_DRIFT_WINDOWS);
    pm->drift_unanswered = !rec_frame_kept(gs_capture_window_drift(cap, NULL), pm->drift_limit_windows);
    if (pm->drift_unanswered) {
        p = np;
        if (o->progress) o->progress(o->progress_ctx, 1.0);
    }
    while (st == GS_OK) {
        size_t n = 0;
        for (; p < np && n < cap_rows; p++)
            if (pm->state[p] == REC_PIX_NO_ANSWER) idx[n++] = p;
        if (n == 0) break;
        for (size_t r = 0; r < n; r++) {
            size_t q = idx[r];
            int x = (int)(q % (size_t)W), y = (int)(q / (size_t)W);
            for (int k = 0; k < K; k++)
                for (int band = 0; band < bands; band++) {
                    double v = sample_value(cap, inv_cycles, (size_t)k, q, band);
                    xb[r * D + (size_t)band * (size_t)K + (size_t)k] =
                        (float)(v - mesh_at(&bg, (size_t)k * (size_t)bands + (size_t)band, x, y));
                }
        }
        st = rec_match_pixels(m, xb, row_sigma ? row_sigma + done : sg, n, bb, ph, cf);
        for (size_t r = 0; r < n && st == GS_OK; r++) {
            size_t q = idx[r];
            if (bb[r] < 0) continue;
            pm->state[q] = REC_PIX_MATCHED;
            pm->bulb[q] = bb[r];
            pm->phase_deg[q] = ph[r];
            pm->confidence[q] = cf[r];
            pm->matched++;
        }
        done += n;
        if (o->progress && mapped) o->progress(o->progress_ctx, (double)done / (double)mapped);
    }
    free(idx);
    free(xb);
    free(row_sigma);
    free(sg);
    free(ph);
    free(cf);
    free(bb);
    mesh_free(&bg);
    free(inv_cycles);
    if (st != GS_OK) rec_pixel_maps_release(pm);
    return st;
}

