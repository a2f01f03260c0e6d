/* maps.c - per-pixel recognition maps like the paper's Fig. 1 (grid phase colour-coded, bulb type,
 * confidence) and per-light signal plots like its Fig. 3 (normalised measured signals with their
 * best-matching templates, and the same signals shifted onto grid phase 0).
 * Sheinin, Schechner, Kutulakos, "Computational Imaging on the Electric Grid", CVPR 2017, Sec. 4.
 *
 * Maps: the per-cycle values of every pixel (docs/formats.md), minus a mesh background, go through
 * rec_match_pixels (Eq. 7 as SGEMM blocks) when the pixel stands above the noise; the maps are
 * composed here pixel by pixel (exact colours, so a test can read them back) and the legend text is
 * drawn on top by PLplot's memcairo driver, then the image is encoded by the OpenCV shim.
 * Plots: PLplot's pngcairo driver, as recognize/plot.c. */
#include "recognize/recognize.h"
#include "recognize/internal.h"

#include <math.h>
#include <plplot.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define BG_BOX 64            /* background mesh box side, pixels (SExtractor's default) */
#define BG_SAMPLES 256       /* at most this many pixels per box enter its median */
#define MAP_BLOCK 16384      /* mapped pixels per rec_match_pixels call */
#define PASS1_TILE 4096      /* pixels whose sums stay in cache while the frames stream by */
#define MAP_TARGET_PX 640    /* the map is scaled up to about this many pixels on its long side */
#define MAP_MAX_SCALE 16
#define MAP_MIN_WIDTH 480    /* the legend needs this much width */
#define V_MIN 0.35           /* HSV value of the faintest mapped pixel */

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
    gs_status st = rec_match_catalog(m, &one, &r);
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
    double *var_sum = calloc(np, sizeof *var_sum);
    if (!pm->state || !pm->bulb || !pm->phase_deg || !pm->confidence || !pm->brightness ||
        !pm->snr || !inv_cycles || !var_sum) {
        free(inv_cycles);
        free(var_sum);
        rec_pixel_maps_release(pm);
        return gs_fail(GS_ENOMEM, "maps: cannot allocate maps of %dx%d pixels", W, H);
    }
    for (size_t p = 0; p < np; p++) pm->bulb[p] = -1;
    for (int k = 0; k < K; k++) inv_cycles[cap->frames[k].k] = 1.0 / cap->frames[k].cycles;

    mesh bg;
    st = mesh_build(cap, inv_cycles, &bg);
    if (st != GS_OK) {
        free(inv_cycles);
        free(var_sum);
        rec_pixel_maps_release(pm);
        return st;
    }

    /* pass 1: brightness B (sum over bands of the mean over k), its noise, saturation. Streams
     * the raw samples once in memory order; the background is linear in its mesh nodes, so its
     * contribution to B is one interpolation of the nodes summed over frames and bands. */
    double *sum = calloc(np, sizeof *sum);
    float *bg_mean = malloc(sizeof *bg_mean * (size_t)bg.g.nx * (size_t)bg.g.ny);
    if (!sum || !bg_mean) {
        free(sum);
        free(bg_mean);
        mesh_free(&bg);
        free(inv_cycles);
        free(var_sum);
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
    const gs_noise nz = gs_capture_noise(cap);
    const double v0 = nz.read_var_dn2, inv_gain = nz.inv_gain, black = nz.black_dn;
    const unsigned sat_dn = cap->saturation_dn > 65535.0 ? 65536u : (unsigned)ceil(cap->saturation_dn);
    /* Without HDR maps and shot noise every pixel has the same variance, and the black level
     * comes off as one constant: the inner loop only adds integers. Tiles of pixels keep the
     * accumulators in cache while the K frames stream by. */
    const int fast = !cap->halvings && inv_gain == 0.0;
    double csum = 0.0, c2sum = 0.0;
    for (int k = 0; k < K; k++) {
        csum += inv_cycles[k];
        c2sum += inv_cycles[k] * inv_cycles[k];
    }
    for (size_t p0 = 0; p0 < np; p0 += PASS1_TILE) {
        size_t n = np - p0 < PASS1_TILE ? np - p0 : PASS1_TILE;
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
                    sum[p0 + i] += c * (double)acc;
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
                sum[p0 + i] += e_sum * ci;
                var_sum[p0 + i] += (bands * v0 + e_pos * inv_gain) * ci * ci;
            }
        }
    }
    if (fast)
        for (size_t p = 0; p < np; p++) {
            sum[p] -= bands * black * csum;
            var_sum[p] = bands * v0 * c2sum;
        }
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            size_t p = (size_t)y * (size_t)W + (size_t)x;
            /* the background of the summed nodes */
            pm->brightness[p] = (float)(sum[p] / K - rec_mesh_at_f(&bg.g, bg_mean, x, y));
        }
    free(sum);
    free(bg_mean);
    size_t mapped = 0;
    for (size_t p = 0; p < np; p++) {
        if (pm->state[p] == REC_PIX_SATURATED) {
            mapped++;
            continue;
        }
        double sd = sqrt(var_sum[p]) / K;
        pm->snr[p] = sd > 0.0 ? (float)(pm->brightness[p] / sd) : 0.0f;
        if (pm->snr[p] > o->threshold_sigma) {
            pm->state[p] = REC_PIX_NO_ANSWER;   /* until matched */
            mapped++;
        }
    }
    pm->mapped = mapped;

    /* pass 2: Eq. 7 on the mapped, unsaturated pixels, in blocks */
    size_t cap_rows = MAP_BLOCK;
    size_t *idx = malloc(sizeof *idx * cap_rows);
    float *xb = malloc(sizeof *xb * cap_rows * D), *sg = malloc(sizeof *sg * cap_rows);
    float *ph = malloc(sizeof *ph * cap_rows), *cf = malloc(sizeof *cf * cap_rows);
    int *bb = malloc(sizeof *bb * cap_rows);
    if (!idx || !xb || !sg || !ph || !cf || !bb) st = gs_fail(GS_ENOMEM, "maps: cannot allocate a block of %zu pixels", cap_rows);
    size_t done = 0, p = 0;
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
            sg[r] = (float)sqrt(var_sum[q] / (double)D);   /* RMS noise of the row's samples */
        }
        st = rec_match_pixels(m, xb, sg, n, bb, ph, cf);
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
    free(sg);
    free(ph);
    free(cf);
    free(bb);
    mesh_free(&bg);
    free(inv_cycles);
    free(var_sum);
    if (st != GS_OK) rec_pixel_maps_release(pm);
    return st;
}

/* ------------------------------------------------------------ canvas and legend */

typedef struct {
    double x, y, size_mm, just;   /* just: 0 left-aligned at x, 1 right-aligned */
    char text[160];
} label;

typedef struct {
    int w, h;
    unsigned char *rgb;
    label *labels;
    size_t nlabels, cap_labels;
} canvas;

static void canvas_free(canvas *c)
{
    free(c->rgb);
    free(c->labels);
}

static void put_px(canvas *c, int x, int y, const unsigned char col[3])
{
    if (x < 0 || y < 0 || x >= c->w || y >= c->h) return;
    memcpy(c->rgb + 3 * ((size_t)y * (size_t)c->w + (size_t)x), col, 3);
}

static void fill_rect(canvas *c, int x0, int y0, int w, int h, const unsigned char col[3])
{
    for (int y = y0; y < y0 + h; y++)
        for (int x = x0; x < x0 + w; x++) put_px(c, x, y, col);
}

static const unsigned char ink[3] = {0, 0, 0},
                           grey_col[3] = {128, 128, 128}, white_col[3] = {255, 255, 255},
                           dark_col[3] = {0, 0, 0};

static void swatch(canvas *c, int x0, int y0, int side, const unsigned char col[3])
{
    fill_rect(c, x0, y0, side, side, ink);
    fill_rect(c, x0 + 1, y0 + 1, side - 2, side - 2, col);
}

static gs_status add_label(canvas *c, double x, double y, double size_mm, const char *fmt, ...)
    __attribute__((format(printf, 5, 6)));
static gs_status add_label(canvas *c, double x, double y, double size_mm, const char *fmt, ...)
{
    if (c->nlabels == c->cap_labels) {
        size_t n = c->cap_labels ? 2 * c->cap_labels : 32;
        label *l = realloc(c->labels, sizeof *l * n);
        if (!l) return gs_fail(GS_ENOMEM, "maps: cannot hold %zu legend labels", n);
        c->labels = l;
        c->cap_labels = n;
    }
    label *l = &c->labels[c->nlabels++];
    l->x = x;
    l->y = y;
    l->size_mm = size_mm;
    l->just = 0.0;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(l->text, sizeof l->text, fmt, ap);
    va_end(ap);
    return GS_OK;
}

/* Draw the queued labels with PLplot's memcairo driver onto the pixels, then encode the PNG. */
static gs_status canvas_write(canvas *c, const char *path)
{
    FILE *f = fopen(path, "wb");
    if (!f) return gs_fail(GS_EIO, "%s: cannot open for writing", path);
    if (c->nlabels) {
        plsdev("memcairo");
        plsmem(c->w, c->h, c->rgb);
        plinit();
        pladv(0);
        plvpor(0.0, 1.0, 0.0, 1.0);
        plwind(0.0, c->w, c->h, 0.0);   /* pixel coordinates, y down */
        plscol0(1, 0, 0, 0);
        plcol0(1);
        for (size_t i = 0; i < c->nlabels; i++) {
            plschr(c->labels[i].size_mm, 1.0);
            plptex(c->labels[i].x, c->labels[i].y, 1.0, 0.0, c->labels[i].just, c->labels[i].text);
        }
        plend();
    }
    unsigned char *png = NULL;
    size_t size = 0;
    gs_status st = gs_png_encode(c->rgb, c->w, c->h, 3, 8, &png, &size);
    if (st == GS_OK && fwrite(png, 1, size, f) != size) st = gs_fail(GS_EIO, "%s: write failed", path);
    if (fclose(f) != 0 && st == GS_OK) st = gs_fail(GS_EIO, "%s: write failed", path);
    free(png);
    if (st != GS_OK) remove(path);
    return st;
}

/* HSV (h in degrees, s and v in [0, 1]) to 8-bit RGB. */
static void hsv_rgb(double h, double s, double v, unsigned char out[3])
{
    h = fmod(h, 360.0);
    if (h < 0) h += 360.0;
    double c = v * s, hp = h / 60.0, x = c * (1.0 - fabs(fmod(hp, 2.0) - 1.0)), r = 0, g = 0, b = 0;
    switch ((int)hp) {
    case 0: r = c; g = x; break;
    case 1: r = x; g = c; break;
    case 2: g = c; b = x; break;
    case 3: g = x; b = c; break;
    case 4: r = x; b = c; break;
    default: r = c; b = x; break;
    }
    double mn = v - c;
    out[0] = (unsigned char)lround(255.0 * (r + mn));
    out[1] = (unsigned char)lround(255.0 * (g + mn));
    out[2] = (unsigned char)lround(255.0 * (b + mn));
}

/* Viridis at 5 control points, linearly interpolated (t in [0, 1]). */
static void conf_rgb(double t, unsigned char out[3])
{
    static const double cp[5][3] = {{68, 1, 84}, {59, 82, 139}, {33, 145, 140}, {94, 201, 98}, {253, 231, 37}};
    if (!(t >= 0.0)) t = 0.0;
    if (t > 1.0) t = 1.0;
    double u = t * 4.0;
    int i = (int)u;
    if (i > 3) i = 3;
    double f = u - i;
    for (int c = 0; c < 3; c++) out[c] = (unsigned char)lround(cp[i][c] + f * (cp[i + 1][c] - cp[i][c]));
}

/* 20 distinct colours for bulbs (Tableau 20 without its greys, plus two dark ones). */
static const unsigned char bulb_palette[20][3] = {
    {31, 119, 180},  {255, 127, 14},  {44, 160, 44},   {214, 39, 40},   {148, 103, 189},
    {140, 86, 75},   {227, 119, 194}, {188, 189, 34},  {23, 190, 207},  {174, 199, 232},
    {255, 187, 120}, {152, 223, 138}, {255, 152, 150}, {197, 176, 213}, {196, 156, 148},
    {247, 182, 210}, {219, 219, 141}, {158, 218, 229}, {0, 90, 60},     {120, 60, 0},
};

/* The HSV value of a mapped pixel from its SNR: V_MIN at the threshold, 1 at the 99th percentile
 * of the mapped pixels. */
typedef struct {
    double log_thr, log_span;
} vscale;

static int cmp_float(const void *a, const void *b)
{
    float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

static gs_status vscale_make(const rec_pixel_maps *pm, vscale *vs)
{
    size_t np = (size_t)pm->width * (size_t)pm->height, n = 0;
    for (size_t p = 0; p < np; p++) n += pm->state[p] == REC_PIX_MATCHED || pm->state[p] == REC_PIX_NO_ANSWER;
    vs->log_thr = log(pm->threshold_sigma);
    vs->log_span = 0.0;
    if (n == 0) return GS_OK;
    float *v = malloc(sizeof *v * n);
    if (!v) return gs_fail(GS_ENOMEM, "maps: cannot sort %zu pixels", n);
    n = 0;
    for (size_t p = 0; p < np; p++)
        if (pm->state[p] == REC_PIX_MATCHED || pm->state[p] == REC_PIX_NO_ANSWER) v[n++] = pm->snr[p];
    qsort(v, n, sizeof *v, cmp_float);
    double hi = v[(size_t)(0.99 * (double)(n - 1))];
    free(v);
    if (hi > pm->threshold_sigma * 1.0001) vs->log_span = log(hi) - vs->log_thr;
    return GS_OK;
}

static double vscale_at(const vscale *vs, double snr)
{
    if (vs->log_span <= 0.0) return 1.0;
    double t = snr > 0.0 ? (log(snr) - vs->log_thr) / vs->log_span : 0.0;
    if (!(t > 0.0)) t = 0.0;
    if (t > 1.0) t = 1.0;
    return V_MIN + (1.0 - V_MIN) * t;
}

/* A canvas holding the scaled map area and a legend band of legend_h rows below it. */
static gs_status canvas_new(canvas *c, const rec_pixel_maps *pm, int legend_h, int *scale)
{
    memset(c, 0, sizeof *c);
    int s = rec_map_scale(pm->width, pm->height);
    long w = (long)s * pm->width, h = (long)s * pm->height + legend_h;
    if (w < MAP_MIN_WIDTH) w = MAP_MIN_WIDTH;
    if (w > 65535 || h > 65535) return gs_fail(GS_ELIMIT, "maps: a %ldx%ld image is too large", w, h);
    c->w = (int)w;
    c->h = (int)h;
    c->rgb = malloc((size_t)c->w * (size_t)c->h * 3);
    if (!c->rgb) return gs_fail(GS_ENOMEM, "maps: cannot allocate a %dx%d image", c->w, c->h);
    memset(c->rgb, 255, (size_t)c->w * (size_t)c->h * 3);   /* legend paper */
    fill_rect(c, 0, 0, s * pm->width, s * pm->height, dark_col);
    *scale = s;
    return GS_OK;
}

static void map_px(canvas *c, int s, int x, int y, const unsigned char col[3])
{
    fill_rect(c, s * x, s * y, s, s, col);
}

/* Legend items in columns of col_w pixels: swatches of 16 px and their labels. */
typedef struct {
    unsigned char rgb[3];
    char text[120];
} key_item;

#define ROW_H 22
#define LEGEND_TOP 8
#define TITLE_H 26
#define TEXT_MM 3.4

static int legend_rows(int width, int col_w, size_t n)
{
    int cols = width / col_w;
    if (cols < 1) cols = 1;
    return (int)((n + (size_t)cols - 1) / (size_t)cols);
}

static gs_status draw_items(canvas *c, int y0, int col_w, const key_item *items, size_t n)
{
    int cols = c->w / col_w;
    if (cols < 1) cols = 1;
    int rows = legend_rows(c->w, col_w, n);
    for (size_t i = 0; i < n; i++) {
        int col = (int)(i / (size_t)rows), row = (int)(i % (size_t)rows);
        int x = 12 + col * col_w, y = y0 + row * ROW_H;
        swatch(c, x, y + 2, 16, items[i].rgb);
        gs_status st = add_label(c, x + 24, y + 10, TEXT_MM, "%s", items[i].text);
        if (st != GS_OK) return st;
    }
    return GS_OK;
}

#define DEG "\xc2\xb0"

/* ------------------------------------------------------------ phase map */

gs_status rec_map_write_phase_png(const rec_pixel_maps *pm, const char *path)
{
    if (!pm || !pm->state || !path) return gs_fail(GS_EINVAL, "phase map: no maps or no path");
    key_item items[10];
    size_t n = 0;
    double set[6] = {0.0, 120.0, 240.0, 0, 0, 0};
    int nset = 0;
    if (pm->phases != REC_PHASES_CONTINUOUS) {
        nset = pm->phases == REC_PHASES_6 ? 6 : 3;
        for (int i = 3; i < nset; i++) set[i] = fmod(set[i - 3] + pm->transformer_deg + 720.0, 360.0);
        for (int i = 0; i < nset; i++) {
            hsv_rgb(set[i], 1.0, 1.0, items[n].rgb);
            snprintf(items[n++].text, sizeof items[0].text, "%g" DEG "%s", set[i],
                     i >= 3 ? " (transformer)" : "");
        }
    }
    memcpy(items[n].rgb, grey_col, 3);
    snprintf(items[n++].text, sizeof items[0].text, "ambiguous (conf. < %.2g) or unknown",
             pm->ambiguous_conf);
    memcpy(items[n].rgb, white_col, 3);
    snprintf(items[n++].text, sizeof items[0].text, "saturated");
    memcpy(items[n].rgb, dark_col, 3);
    snprintf(items[n++].text, sizeof items[0].text, "below %g sigma", pm->threshold_sigma);

    int col_w = 320;
    int probe_w = rec_map_scale(pm->width, pm->height) * pm->width;
    if (probe_w < MAP_MIN_WIDTH) probe_w = MAP_MIN_WIDTH;
    int bar_h = pm->phases == REC_PHASES_CONTINUOUS ? 16 + 22 : 0;
    int legend_h = LEGEND_TOP + TITLE_H + bar_h + legend_rows(probe_w, col_w, n) * ROW_H + 8;
    canvas c;
    int s;
    gs_status st = canvas_new(&c, pm, legend_h, &s);
    if (st != GS_OK) return st;
    vscale vs;
    st = vscale_make(pm, &vs);
    for (int y = 0; y < pm->height && st == GS_OK; y++)
        for (int x = 0; x < pm->width; x++) {
            size_t p = (size_t)y * (size_t)pm->width + (size_t)x;
            unsigned char col[3];
            double v = vscale_at(&vs, pm->snr[p]);
            if (pm->state[p] == REC_PIX_SATURATED) memcpy(col, white_col, 3);
            else if (pm->state[p] == REC_PIX_MATCHED && pm->confidence[p] >= pm->ambiguous_conf)
                hsv_rgb(pm->phase_deg[p], 1.0, v, col);
            else if (pm->state[p] == REC_PIX_MATCHED || pm->state[p] == REC_PIX_NO_ANSWER)
                hsv_rgb(0.0, 0.0, 0.5 * v, col);   /* ambiguous or no answer */
            else continue;
            map_px(&c, s, x, y, col);
        }
    int y0 = s * pm->height + LEGEND_TOP;
    if (st == GS_OK)
        st = add_label(&c, 12, y0 + 10, 3.8, "grid phase per pixel (Eq. 7; hue = phase, brightness = signal)%s",
                       pm->phases == REC_PHASES_CONTINUOUS ? ", continuous" : "");
    y0 += TITLE_H;
    if (st == GS_OK && pm->phases == REC_PHASES_CONTINUOUS) {
        int bw = c.w - 24 < 720 ? c.w - 24 : 720;
        for (int i = 0; i < bw; i++) {
            unsigned char col[3];
            hsv_rgb(360.0 * i / bw, 1.0, 1.0, col);
            fill_rect(&c, 12 + i, y0, 1, 16, col);
        }
        for (int t = 0; t <= 360 && st == GS_OK; t += 60) {
            int xt = 12 + (int)lround((double)bw * t / 360.0);
            fill_rect(&c, xt, y0 + 16, 1, 4, ink);
            st = add_label(&c, xt - (t ? (t == 360 ? 0 : 10) : 0), y0 + 28, TEXT_MM, "%d" DEG, t);
            if (st == GS_OK && t == 360) c.labels[c.nlabels - 1].just = 1.0;
        }
        y0 += bar_h;
    }
    if (st == GS_OK) st = draw_items(&c, y0, col_w, items, n);
    if (st == GS_OK) st = canvas_write(&c, path);
    canvas_free(&c);
    return st;
}

/* ------------------------------------------------------------ bulb map */

typedef struct {
    int bulb;
    size_t pixels;
} bulb_count;

static int cmp_bulb_count(const void *a, const void *b)
{
    const bulb_count *x = a, *y = b;
    if (x->pixels != y->pixels) return x->pixels < y->pixels ? 1 : -1;
    return x->bulb - y->bulb;
}

gs_status rec_map_write_bulb_png(const rec_pixel_maps *pm, const rec_matcher *m, const char *path)
{
    if (!pm || !pm->state || !m || !path) return gs_fail(GS_EINVAL, "bulb map: no maps, matcher or path");
    size_t nb = rec_matcher_bulb_count(m), np = (size_t)pm->width * (size_t)pm->height;
    bulb_count *cnt = calloc(nb ? nb : 1, sizeof *cnt);
    key_item *items = calloc(nb + 3, sizeof *items);
    int *colour = calloc(nb ? nb : 1, sizeof *colour);
    if (!cnt || !items || !colour) {
        free(cnt);
        free(items);
        free(colour);
        return gs_fail(GS_ENOMEM, "bulb map: cannot allocate the legend");
    }
    for (size_t b = 0; b < nb; b++) cnt[b].bulb = (int)b;
    for (size_t p = 0; p < np; p++)
        if (pm->state[p] == REC_PIX_MATCHED && pm->bulb[p] >= 0 && (size_t)pm->bulb[p] < nb)
            cnt[pm->bulb[p]].pixels++;
    qsort(cnt, nb, sizeof *cnt, cmp_bulb_count);
    size_t n = 0;
    for (size_t i = 0; i < nb && cnt[i].pixels; i++) {
        const gs_bulb *b = rec_matcher_bulb(m, (size_t)cnt[i].bulb);
        colour[cnt[i].bulb] = (int)(i % 20);   /* by rank: the 20 commonest bulbs differ */
        memcpy(items[n].rgb, bulb_palette[colour[cnt[i].bulb]], 3);
        snprintf(items[n++].text, sizeof items[0].text, "%s (%s), %zu px", b->id,
                 gs_tech_name(b->type), cnt[i].pixels);
    }
    memcpy(items[n].rgb, grey_col, 3);
    snprintf(items[n++].text, sizeof items[0].text, "unknown, dim or bad input");
    memcpy(items[n].rgb, white_col, 3);
    snprintf(items[n++].text, sizeof items[0].text, "saturated");
    memcpy(items[n].rgb, dark_col, 3);
    snprintf(items[n++].text, sizeof items[0].text, "below %g sigma", pm->threshold_sigma);

    int col_w = 320;
    int probe_w = rec_map_scale(pm->width, pm->height) * pm->width;
    if (probe_w < MAP_MIN_WIDTH) probe_w = MAP_MIN_WIDTH;
    int legend_h = LEGEND_TOP + TITLE_H + legend_rows(probe_w, col_w, n) * ROW_H + 8;
    canvas c;
    int s;
    gs_status st = canvas_new(&c, pm, legend_h, &s);
    vscale vs;
    if (st == GS_OK) st = vscale_make(pm, &vs);
    for (int y = 0; y < pm->height && st == GS_OK; y++)
        for (int x = 0; x < pm->width; x++) {
            size_t p = (size_t)y * (size_t)pm->width + (size_t)x;
            unsigned char col[3];
            double v = vscale_at(&vs, pm->snr[p]);
            if (pm->state[p] == REC_PIX_SATURATED) memcpy(col, white_col, 3);
            else if (pm->state[p] == REC_PIX_MATCHED)
                for (int k = 0; k < 3; k++) col[k] = (unsigned char)lround(v * bulb_palette[colour[pm->bulb[p]]][k]);
            else if (pm->state[p] == REC_PIX_NO_ANSWER) hsv_rgb(0.0, 0.0, 0.5 * v, col);
            else continue;
            map_px(&c, s, x, y, col);
        }
    int y0 = s * pm->height + LEGEND_TOP;
    if (st == GS_OK)
        st = add_label(&c, 12, y0 + 10, 3.8, "bulb per pixel (Eq. 7 over DELIGHT; brightness = signal)");
    if (st == GS_OK) st = draw_items(&c, y0 + TITLE_H, col_w, items, n);
    if (st == GS_OK) st = canvas_write(&c, path);
    if (c.rgb) canvas_free(&c);
    free(cnt);
    free(items);
    free(colour);
    return st;
}

/* ------------------------------------------------------------ confidence map */

gs_status rec_map_write_confidence_png(const rec_pixel_maps *pm, const char *path)
{
    if (!pm || !pm->state || !path) return gs_fail(GS_EINVAL, "confidence map: no maps or no path");
    key_item items[3];
    memcpy(items[0].rgb, grey_col, 3);
    snprintf(items[0].text, sizeof items[0].text, "unknown, dim or bad input");
    memcpy(items[1].rgb, white_col, 3);
    snprintf(items[1].text, sizeof items[1].text, "saturated");
    memcpy(items[2].rgb, dark_col, 3);
    snprintf(items[2].text, sizeof items[2].text, "below %g sigma", pm->threshold_sigma);
    int col_w = 320, bar_h = 16 + 22;
    int probe_w = rec_map_scale(pm->width, pm->height) * pm->width;
    if (probe_w < MAP_MIN_WIDTH) probe_w = MAP_MIN_WIDTH;
    int legend_h = LEGEND_TOP + TITLE_H + bar_h + legend_rows(probe_w, col_w, 3) * ROW_H + 8;
    canvas c;
    int s;
    gs_status st = canvas_new(&c, pm, legend_h, &s);
    if (st != GS_OK) return st;
    for (int y = 0; y < pm->height; y++)
        for (int x = 0; x < pm->width; x++) {
            size_t p = (size_t)y * (size_t)pm->width + (size_t)x;
            unsigned char col[3];
            if (pm->state[p] == REC_PIX_SATURATED) memcpy(col, white_col, 3);
            else if (pm->state[p] == REC_PIX_MATCHED) conf_rgb(pm->confidence[p], col);
            else if (pm->state[p] == REC_PIX_NO_ANSWER) memcpy(col, grey_col, 3);
            else continue;
            map_px(&c, s, x, y, col);
        }
    int y0 = s * pm->height + LEGEND_TOP;
    st = add_label(&c, 12, y0 + 10, 3.8, "posterior of the best (bulb, phase) pair per pixel (Eq. 7)");
    y0 += TITLE_H;
    int bw = c.w - 24 < 600 ? c.w - 24 : 600;
    for (int i = 0; i < bw; i++) {
        unsigned char col[3];
        conf_rgb((double)i / (bw - 1), col);
        fill_rect(&c, 12 + i, y0, 1, 16, col);
    }
    for (int t = 0; t <= 4 && st == GS_OK; t++) {
        int xt = 12 + (int)lround((double)(bw - 1) * t / 4.0);
        fill_rect(&c, xt, y0 + 16, 1, 4, ink);
        st = add_label(&c, xt - (t && t < 4 ? 12 : 0), y0 + 28, TEXT_MM, "%.2f", t / 4.0);
        if (st == GS_OK && t == 4) c.labels[c.nlabels - 1].just = 1.0;
    }
    y0 += bar_h;
    if (st == GS_OK) st = draw_items(&c, y0, col_w, items, 3);
    if (st == GS_OK) st = canvas_write(&c, path);
    canvas_free(&c);
    return st;
}

/* ------------------------------------------------------------ signal plots (Fig. 3) */

#define CURVE_N 200
#define MAX_SIGNAL_LIGHTS 16

/* Window-mean curve of bulb b delayed by shift cycles, for band: c(u) = the mean of the delayed,
 * chromaticity-scaled BRF over a window of 1/K centred at u, at u = j / (CURVE_N - 1), from the
 * BRF's Fourier series (each harmonic h times sinc(h / K)); exactly the template value (Eq. 5) at
 * the window centres u = (k + 1/2) / K (a Nyquist component, which the built-in DELIGHT does not
 * have, is left out). C holds n/2 + 1 values of scratch. */
static gs_status template_curve(const gs_bulb *b, double shift, int K, int band, double *u,
                                double *c, double complex *C)
{
    int n = b->brf.n;
    gs_status st = gs_brf_spectrum(b->brf.v + (size_t)band * (size_t)n, n, C);
    if (st != GS_OK) return st;
    const double pi = 3.14159265358979323846;
    for (int h = 1; h < n / 2; h++) {
        double a = pi * h / K;
        C[h] *= 2.0 * sin(a) / a;
    }
    for (int j = 0; j < CURVE_N; j++) {
        u[j] = (double)j / (CURVE_N - 1);
        double turns = fmod(u[j] - shift, 1.0);
        double complex z = cexp(I * 2.0 * pi * turns), zh = 1.0;
        double acc = creal(C[0]);
        for (int h = 1; h < n / 2; h++) {
            zh *= z;
            acc += creal(C[h] * zh);
        }
        c[j] = b->chroma[band] * acc / n;
    }
    return GS_OK;
}

typedef struct {
    size_t light;
    double snr;
} light_rank;

static int cmp_rank(const void *a, const void *b)
{
    const light_rank *x = a, *y = b;
    if (x->snr != y->snr) return x->snr < y->snr ? 1 : -1;
    return x->light < y->light ? -1 : x->light > y->light;
}

static const char *const symbols[8] = {"\xe2\x97\x8f", "\xe2\x96\xa0", "\xe2\x96\xb2",
                                       "\xe2\x97\x86", "\xe2\x96\xbc", "\xe2\x98\x85",
                                       "\xe2\x9c\x9a", "\xe2\x9c\x96"};

gs_status rec_plot_signals(const rec_matcher *m, const rec_catalog *cat, const rec_match *match,
                           int max_lights, const char *png_path, const char *title)
{
    if (!m || !cat || (cat->count && !match) || !png_path)
        return gs_fail(GS_EINVAL, "signal plot: expected a matcher, a catalog, its matches and a path");
    if (max_lights < 1 || max_lights > MAX_SIGNAL_LIGHTS)
        return gs_fail(GS_EINVAL, "signal plot: max_lights %d: expected 1 to %d", max_lights,
                       MAX_SIGNAL_LIGHTS);
    const gs_bulb *first = rec_matcher_bulb(m, 0);
    int K = cat->K, bands = cat->bands;
    if (cat->count && (!first || first->brf.bands != bands))
        return gs_fail(GS_EINVAL, "signal plot: the catalog has %d bands, the matcher %d", bands,
                       first ? first->brf.bands : 0);
    if (bands < 1 || bands > GS_MAX_BANDS) bands = first ? first->brf.bands : 1;
    if (K < 2) K = 2;
    /* the lights to draw: recognised, highest SNR first */
    light_rank rank[MAX_SIGNAL_LIGHTS];
    size_t nl = 0;
    light_rank *all = calloc(cat->count ? cat->count : 1, sizeof *all);
    if (!all) return gs_fail(GS_ENOMEM, "signal plot: cannot rank %zu lights", cat->count);
    size_t na = 0;
    size_t D = (size_t)bands * (size_t)K;
    for (size_t i = 0; i < cat->count; i++) {
        if (match[i].bulb < 0 || !(match[i].brightness > 0.0)) continue;
        double s = 0.0, v = 0.0;
        for (size_t d = 0; d < D; d++) {
            s += cat->signal[i * D + d];
            v += cat->sigma[i * D + d] * cat->sigma[i * D + d];
        }
        if (!(v > 0.0) || !isfinite(v)) continue;
        all[na].light = i;
        all[na++].snr = s / sqrt(v);
    }
    qsort(all, na, sizeof *all, cmp_rank);
    for (size_t i = 0; i < na && nl < (size_t)max_lights; i++) rank[nl++] = all[i];
    free(all);

    FILE *probe = fopen(png_path, "wb");   /* PLplot exits the process on open failures */
    if (!probe) return gs_fail(GS_EIO, "%s: cannot write the plot", png_path);
    fclose(probe);

    double *u = malloc(sizeof *u * CURVE_N), *cv = malloc(sizeof *cv * CURVE_N);
    int nmax = 4;
    for (size_t i = 0; i < rec_matcher_bulb_count(m); i++)
        if (rec_matcher_bulb(m, i)->brf.n > nmax) nmax = rec_matcher_bulb(m, i)->brf.n;
    double complex *tmp = malloc(sizeof *tmp * (size_t)(nmax / 2 + 1));
    double *px = malloc(sizeof *px * (size_t)(K + 1)), *py = malloc(sizeof *py * (size_t)(K + 1));
    double *lo = malloc(sizeof *lo * (size_t)K), *hi = malloc(sizeof *hi * (size_t)K);
    if (!u || !cv || !tmp || !px || !py || !lo || !hi) {
        free(u); free(cv); free(tmp); free(px); free(py); free(lo); free(hi);
        return gs_fail(GS_ENOMEM, "signal plot: cannot allocate curves");
    }
    /* y range over every drawn value */
    double ymax = 0.0;
    for (size_t l = 0; l < nl; l++) {
        size_t i = rank[l].light;
        double a = match[i].brightness;
        for (size_t d = 0; d < D; d++) {
            double y = (cat->signal[i * D + d] + cat->sigma[i * D + d]) / a;
            if (y > ymax) ymax = y;
        }
    }
    gs_status st = GS_OK;
    for (size_t l = 0; l < nl && st == GS_OK; l++) {
        const gs_bulb *b = rec_matcher_bulb(m, (size_t)match[rank[l].light].bulb);
        for (int band = 0; band < bands && st == GS_OK; band++) {
            st = template_curve(b, 0.0, K, band, u, cv, tmp);
            for (int j = 0; j < CURVE_N && st == GS_OK; j++)
                if (cv[j] > ymax) ymax = cv[j];
        }
    }
    ymax = ymax > 0.0 ? ymax * 1.08 : 1.0;
    if (bands == 3 && ymax < 0.6) ymax = 0.6;
    if (bands == 1 && ymax < 1.5) ymax = 1.5;

    /* colours: one per distinct bulb (as the paper's Fig. 3) */
    int bulb_of_colour[MAX_SIGNAL_LIGHTS], ncol = 0, colour[MAX_SIGNAL_LIGHTS];
    for (size_t l = 0; l < nl; l++) {
        int bb = match[rank[l].light].bulb, c = -1;
        for (int k = 0; k < ncol; k++)
            if (bulb_of_colour[k] == bb) c = k;
        if (c < 0) {
            c = ncol;
            bulb_of_colour[ncol++] = bb;
        }
        colour[l] = c;
    }

    if (st == GS_OK) {
        plsdev("pngcairo");
        plsfnam(png_path);
        char geom[32];
        snprintf(geom, sizeof geom, "1500x%d", bands == 1 ? 620 : 1500);
        plsetopt("geometry", geom);
        plscmap0n(24);
        plscol0(0, 255, 255, 255);
        plscol0(1, 0, 0, 0);
        for (int c = 0; c < 20; c++)
            plscol0(c + 2, bulb_palette[c][0] * 4 / 5, bulb_palette[c][1] * 4 / 5, bulb_palette[c][2] * 4 / 5);
        plinit();
        pladv(0);
        static const char *const band_name[3] = {"red band", "green band", "blue band"};
        double top = 0.93, bottom = 0.05, gap = 0.09;
        double row_h = (top - bottom - gap * (bands - 1)) / bands;
        const char *labels[MAX_SIGNAL_LIGHTS], *syms[MAX_SIGNAL_LIGHTS];
        char text[MAX_SIGNAL_LIGHTS][120];
        PLINT opts[MAX_SIGNAL_LIGHTS], colors[MAX_SIGNAL_LIGHTS], styles[MAX_SIGNAL_LIGHTS];
        PLFLT widths[MAX_SIGNAL_LIGHTS], scales[MAX_SIGNAL_LIGHTS];
        PLINT numbers[MAX_SIGNAL_LIGHTS];
        for (int band = 0; band < bands && st == GS_OK; band++) {
            double y1 = top - band * (row_h + gap), y0 = y1 - row_h;
            for (int panel = 0; panel < 2 && st == GS_OK; panel++) {
                plvpor(panel ? 0.45 : 0.07, panel ? 0.76 : 0.38, y0, y1);
                plwind(0.0, 1.0, 0.0, ymax);
                plcol0(1);
                plwidth(1.0);
                plschr(0, 0.6);
                plbox("bcnstg", 0.2, 2, "bcnstvg", 0, 0);
                char lab[300];
                const char *bn = bands == 1 ? "monochrome" : band_name[band];
                if (panel == 0)
                    snprintf(lab, sizeof lab, "%s: measured/brightness, best template", bn);
                else
                    snprintf(lab, sizeof lab, "%s: shifted to grid phase 0", bn);
                pllab("time in the flicker cycle, t / #gD", "normalised signal", lab);
                if (band == 0 && panel == 0 && title && *title) {
                    plschr(0, 0.75);
                    plmtex("t", 3.2, 0.0, 0.0, title);
                    plschr(0, 0.6);
                }
                for (size_t l = 0; l < nl && st == GS_OK; l++) {
                    size_t i = rank[l].light;
                    const rec_match *mt = &match[i];
                    const gs_bulb *b = rec_matcher_bulb(m, (size_t)mt->bulb);
                    int phase_known = b->ref == GS_REF_VOLTAGE && !(mt->flags & REC_MATCH_PHASE_AMBIGUOUS);
                    double sh = gs_phase_to_shift(mt->phase_deg);
                    if (panel == 1 && !phase_known) continue;
                    /* the template (panel 0: at the light's phase; panel 1: at phase 0) */
                    st = template_curve(b, panel ? 0.0 : sh, K, band, u, cv, tmp);
                    if (st != GS_OK) break;
                    plcol0(colour[l] % 20 + 2);
                    plwidth(panel ? 1.0 : 2.0);
                    plline(CURVE_N, u, cv);
                    /* the measured samples at the window centres (panel 1: minus the shift) */
                    double a = mt->brightness;
                    for (int k = 0; k < K; k++) {
                        double t = (k + 0.5) / K - (panel ? sh : 0.0);
                        t -= floor(t);
                        size_t d = i * D + (size_t)band * (size_t)K + (size_t)k;
                        px[k] = t;
                        py[k] = cat->signal[d] / a;
                        lo[k] = (cat->signal[d] - cat->sigma[d]) / a;
                        hi[k] = (cat->signal[d] + cat->sigma[d]) / a;
                    }
                    plwidth(1.0);
                    plerry(K, px, lo, hi);
                    plschr(0, 0.45);
                    plstring(K, px, py, symbols[l % 8]);
                    plschr(0, 0.6);
                }
            }
            if (st != GS_OK) break;
            /* legend, right of the first row */
            if (band == 0) {
                for (size_t l = 0; l < nl; l++) {
                    const rec_match *mt = &match[rank[l].light];
                    const gs_bulb *b = rec_matcher_bulb(m, (size_t)mt->bulb);
                    if (b->ref == GS_REF_VOLTAGE && !(mt->flags & REC_MATCH_PHASE_AMBIGUOUS))
                        snprintf(text[l], sizeof text[l], "light %zu: %s, %.0f" DEG, rank[l].light, b->id,
                                 mt->phase_deg);
                    else
                        snprintf(text[l], sizeof text[l], "light %zu: %s, phase ?", rank[l].light, b->id);
                    labels[l] = text[l];
                    syms[l] = symbols[l % 8];
                    opts[l] = PL_LEGEND_LINE | PL_LEGEND_SYMBOL;
                    colors[l] = colour[l] % 20 + 2;
                    styles[l] = 1;
                    widths[l] = 2.0;
                    scales[l] = 0.5;
                    numbers[l] = 2;
                }
                plvpor(0.78, 0.998, y0, y1);
                plwind(0.0, 1.0, 0.0, 1.0);
                if (nl) {
                    PLFLT lw, lh;
                    pllegend(&lw, &lh, PL_LEGEND_BACKGROUND | PL_LEGEND_BOUNDING_BOX,
                             PL_POSITION_LEFT | PL_POSITION_INSIDE | PL_POSITION_TOP, 0.0, 0.0,
                             0.05, 0, 1, 1, (PLINT)nl, 1, (PLINT)nl, opts, 0.6, 0.45, 2.0, 0.0, colors,
                             (const char *const *)labels, NULL, NULL, NULL, NULL, colors, styles,
                             widths, colors, scales, numbers, (const char *const *)syms);
                } else {
                    plcol0(1);
                    plschr(0, 0.8);
                    plptex(0.5, 0.9, 1.0, 0.0, 0.5, "no recognised light");
                }
            }
        }
        plend();
    }
    free(u); free(cv); free(tmp); free(px); free(py); free(lo); free(hi);
    if (st != GS_OK) remove(png_path);
    return st;
}
