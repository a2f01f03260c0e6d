/* test_recognize_maps.c - the maps of `gridsurvey recognize --maps` (Fig. 1): valid PNGs with
 * the documented scale, phase hues, bulb colours and the confidence scale on rendered captures
 * (tests/recognize_fixture.h), an empty scene, and in process the per-pixel pass's fast and
 * general paths, a saturated core and bad arguments; the bulb map's legend and the signal plot's
 * (Fig. 3) lights and template curves; the BRF plot's (Fig. 2) levels inside its frame. */
#include "recognize/recognize.h"
#include "recognize/internal.h"
#include "tests/fixtures.h"
#include "tests/recognize_fixture.h"
#include "tests/test.h"

#include <jansson.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

TEST(maps_png_valid_and_phase_hues)
{
    json_t *root = recfx_recognize_scene(&recfx_scene_a, "", 1, 1);
    json_decref(root);
    int s = recfx_doc_scale(recfx_scene_a.width, recfx_scene_a.height);
    int want_w = s * recfx_scene_a.width > 480 ? s * recfx_scene_a.width : 480;
    static const char *const names[3] = {"phase_map.png", "bulb_map.png", "confidence_map.png"};
    unsigned char *px[3] = {NULL, NULL, NULL};
    int w[3] = {0, 0, 0}, h[3] = {0, 0, 0};
    for (int m = 0; m < 3; m++) {
        char path[1200];
        snprintf(path, sizeof path, "%s/maps/%s", test_tmpdir(), names[m]);
        px[m] = recfx_read_png(path, &w[m], &h[m]);
        CHECK_MSG(w[m] == want_w && h[m] > s * recfx_scene_a.height + 40, "%s: %dx%d, expected %d wide and a legend",
                  names[m], w[m], h[m], want_w);
        if (!px[m] || w[m] != want_w) {
            for (int k = 0; k <= m; k++) free(px[k]);
            return;
        }
        /* far from every light: black (below the threshold) */
        const unsigned char *bg = recfx_map_at(px[m], w[m], s, 2, 60);
        CHECK_MSG(bg[0] == 0 && bg[1] == 0 && bg[2] == 0, "%s: background (%d, %d, %d)", names[m],
                  bg[0], bg[1], bg[2]);
        /* the legend band holds text (dark pixels on white) */
        size_t dark = 0;
        for (int y = s * recfx_scene_a.height; y < h[m]; y++)
            for (int x = 0; x < w[m]; x++) dark += px[m][3 * ((size_t)y * (size_t)w[m] + (size_t)x)] < 100;
        CHECK_MSG(dark > 500, "%s: legend has %zu dark pixels", names[m], dark);
    }
    for (int i = 0; i < recfx_scene_a.count; i++) {
        const recfx_light *t = &recfx_lights_a[i];
        recfx_check_phase_colour(recfx_map_at(px[0], w[0], s, t->x, t->y), t->phase_deg, t->bulb);
        const unsigned char *c = recfx_map_at(px[1], w[1], s, t->x, t->y);
        CHECK_MSG(!(c[0] == c[1] && c[1] == c[2]), "bulb map: %s grey", t->bulb);
        for (int j = 0; j < i; j++) {
            const unsigned char *d = recfx_map_at(px[1], w[1], s, recfx_lights_a[j].x, recfx_lights_a[j].y);
            /* distinct bulbs in distinct hues (brightness may differ) */
            double hc = recfx_hue_deg(c), hd = recfx_hue_deg(d);
            CHECK_MSG(!(fabs(recfx_circ_diff_deg(hc, hd)) < 1.0 && abs(c[0] - d[0]) < 8),
                      "bulb map: %s and %s share a colour", t->bulb, recfx_lights_a[j].bulb);
        }
        const unsigned char *q = recfx_map_at(px[2], w[2], s, t->x, t->y);   /* viridis near 1: yellow */
        CHECK_MSG(q[0] > 150 && q[1] > 150 && q[2] < 120, "confidence map: %s (%d, %d, %d)", t->bulb,
                  q[0], q[1], q[2]);
    }
    for (int m = 0; m < 3; m++) free(px[m]);
    const char *path = fx_tmp("maps/signals.png");
    int sw = 0, sh = 0;
    unsigned char *sp = recfx_read_png(path, &sw, &sh);
    CHECK(sw == 1500 && sh == 1500);
    if (sp) {
        /* curves and points in colour, not an empty canvas */
        size_t coloured = 0;
        for (size_t k = 0; k < (size_t)sw * (size_t)sh; k++) {
            const unsigned char *p = sp + 3 * k;
            coloured += abs(p[0] - p[1]) > 40 || abs(p[1] - p[2]) > 40;
        }
        CHECK_MSG(coloured > 20000, "signals.png: %zu coloured pixels", coloured);
    }
    free(sp);
}

TEST(maps_no_lights_still_written)
{
    json_t *root = recfx_recognize_scene(&recfx_scene_e, "", 1, 0);
    if (root) {
        CHECK(json_array_size(json_object_get(root, "lights")) == 0);
        CHECK(json_integer_value(json_object_get(json_object_get(root, "summary"), "lights")) == 0);
    }
    json_decref(root);
    const char *path = fx_tmp("maps/phase_map.png");
    int w = 0, h = 0;
    unsigned char *px = recfx_read_png(path, &w, &h);
    int s = recfx_doc_scale(recfx_scene_e.width, recfx_scene_e.height);
    CHECK(w == s * recfx_scene_e.width && h > s * recfx_scene_e.height);
    if (px) {
        size_t lit = 0;
        for (int y = 0; y < s * recfx_scene_e.height; y++)
            for (int x = 0; x < s * recfx_scene_e.width; x++) {
                const unsigned char *p = px + 3 * ((size_t)y * (size_t)w + (size_t)x);
                lit += p[0] || p[1] || p[2];
            }
        /* noise alone crosses 5 sigma in ~3e-7 of the pixels: nothing is drawn */
        CHECK_MSG(lit == 0, "%zu map pixels drawn in an empty scene", lit);
    }
    free(px);
    path = fx_tmp("maps/signals.png");
    int sw = 0, sh = 0;
    unsigned char *sp = recfx_read_png(path, &sw, &sh);
    CHECK(sw == 1500 && sh == 620);
    free(sp);
}

/* ------------------------------------------------------------ maps, in process */

/* A capture built in memory: sky 0.5 DN per cycle, read noise 2 DN at 40 cycles, three lights of
 * 3x3 pixels (weights 1, 0.5, 0.25) of known bulbs and phases. */
typedef struct {
    int x, y;
    const char *bulb;
    double phase_deg, flux;
} mem_light;

static const mem_light mem_lights[3] = {
    {12, 14, "hps-150w", 240, 60}, {40, 20, "mh-250w", 0, 50}, {25, 45, "cfl-23w", 120, 50}};

static gs_status mem_capture(const gs_delight *d, gs_capture *cap)
{
    memset(cap, 0, sizeof *cap);
    cap->grid_hz = 50;
    cap->K = 13;
    cap->bands = 3;
    cap->width = 64;
    cap->height = 56;
    cap->saturation_dn = 65536;
    cap->black_level_dn = 100;
    cap->read_noise_dn = 2;
    cap->locked = 1;
    gs_status s = gs_capture_alloc(cap);
    if (s != GS_OK) return s;
    const double cycles = 40.0;
    size_t np = (size_t)cap->width * (size_t)cap->height;
    double *v = calloc(np * 13 * 3, sizeof *v);
    if (!v) return GS_ENOMEM;
    for (int k = 0; k < 13; k++) cap->frames[k].cycles = cycles;
    for (int i = 0; i < 3; i++) {
        const gs_bulb *b = gs_delight_find(d, mem_lights[i].bulb, 50, 3);
        double t[3 * 13];
        if (!b || gs_brf_integrate(&b->brf, gs_phase_to_shift(mem_lights[i].phase_deg), 13, t) != GS_OK) {
            free(v);
            return GS_ENOTFOUND;
        }
        for (int dy = -1; dy <= 1; dy++)
            for (int dx = -1; dx <= 1; dx++) {
                double w = (dx ? 0.5 : 1.0) * (dy ? 0.5 : 1.0);
                size_t p = (size_t)(mem_lights[i].y + dy) * (size_t)cap->width + (size_t)(mem_lights[i].x + dx);
                for (int band = 0; band < 3; band++)
                    for (int k = 0; k < 13; k++)
                        v[((size_t)k * np + p) * 3 + (size_t)band] +=
                            w * mem_lights[i].flux * b->chroma[band] * t[band * 13 + k];
            }
    }
    uint64_t seed = 99;
    for (size_t q = 0; q < np * 13 * 3; q++) {
        /* Box-Muller on one splitmix64 draw: u1 from its top 53 bits, u2 from its low 11 */
        uint64_t z = gs_splitmix64(&seed);
        double u1 = ((double)(z >> 11) + 0.5) * 0x1p-53, u2 = ((double)(z & 0x7ff) + 0.5) / 2048.0;
        double n = sqrt(-2.0 * log(u1)) * cos(6.283185307179586 * u2);
        double raw = 100.0 + cycles * (0.5 + v[q]) + 2.0 * n;
        cap->raw[q] = (unsigned short)(raw < 0 ? 0 : raw > 65535 ? 65535 : lround(raw));
    }
    free(v);
    return GS_OK;
}

static const char *matcher_bulb_id(const rec_matcher *m, int i)
{
    const gs_bulb *b = i >= 0 ? rec_matcher_bulb(m, (size_t)i) : NULL;
    return b ? b->id : "none";
}

/* The generated DELIGHT (in *d), mem_capture's capture and a 50 Hz RGB K = 13 matcher. */
static rec_matcher *mem_setup(gs_delight **d, gs_capture *cap)
{
    *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(*d, 512));
    rec_matcher *m = NULL;
    CHECK_OK(rec_matcher_new(*d, 50, 3, 13, NULL, &m));
    CHECK_OK(mem_capture(*d, cap));
    return m;
}

TEST(maps_fast_path_matches_general)
{
    /* Without HDR maps and shot noise the per-pixel pass takes an integer fast path; with an
     * all-zero HDR map it takes the general one. Same capture, same maps. */
    gs_delight *d = NULL;
    gs_capture cap;
    rec_matcher *m = mem_setup(&d, &cap);
    rec_pixel_maps a, b;
    CHECK_OK(rec_pixel_maps_compute(&cap, m, NULL, NULL, &a));
    CHECK_OK(gs_capture_alloc_hdr(&cap));
    CHECK_OK(rec_pixel_maps_compute(&cap, m, NULL, NULL, &b));
    size_t np = (size_t)cap.width * (size_t)cap.height, differ = 0;
    for (size_t p = 0; p < np && a.state && b.state; p++)
        differ += a.state[p] != b.state[p] || a.bulb[p] != b.bulb[p] ||
                  fabsf(a.brightness[p] - b.brightness[p]) > 1e-4f * (1.0f + fabsf(a.brightness[p]));
    CHECK_MSG(differ == 0, "%zu pixels differ", differ);
    /* the light centres: the rendered bulb and phase (Eq. 7 per pixel) */
    for (int i = 0; i < 3 && a.state; i++) {
        size_t p = (size_t)mem_lights[i].y * (size_t)cap.width + (size_t)mem_lights[i].x;
        CHECK_MSG(a.state[p] == REC_PIX_MATCHED && !strcmp(matcher_bulb_id(m, a.bulb[p]), mem_lights[i].bulb) &&
                      fabs(recfx_circ_diff_deg(a.phase_deg[p], mem_lights[i].phase_deg)) < 1e-3 && a.confidence[p] > 0.8,
                  "light %s: state %d bulb %s phase %g conf %g", mem_lights[i].bulb, a.state[p],
                  matcher_bulb_id(m, a.bulb[p]), a.phase_deg[p], a.confidence[p]);
        /* brightness = the rendered flux at the centre pixel (weight 1), background removed */
        CHECK_NEAR(a.brightness[p], mem_lights[i].flux, 0.02 * mem_lights[i].flux);
    }
    CHECK(a.mapped >= 9 * 3 - 6 && a.mapped <= 9 * 3 + 3);   /* the lights' pixels, no sky */
    rec_pixel_maps_release(&a);
    rec_pixel_maps_release(&b);
    rec_pixel_maps_release(NULL);
    gs_capture_release(&cap);
    rec_matcher_free(m);
    gs_delight_free(d);
}

TEST(maps_saturated_core_white_and_bad_arguments)
{
    gs_delight *d = NULL;
    gs_capture cap;
    rec_matcher *m = mem_setup(&d, &cap);
    /* saturate the brightest light's centre: the level just below its peak sample */
    size_t np = (size_t)cap.width * (size_t)cap.height;
    size_t pc = (size_t)mem_lights[0].y * (size_t)cap.width + (size_t)mem_lights[0].x;
    unsigned peak = 0;
    for (int k = 0; k < 13; k++)
        for (int band = 0; band < 3; band++) {
            unsigned r = cap.raw[((size_t)k * np + pc) * 3 + (size_t)band];
            peak = r > peak ? r : peak;
        }
    cap.saturation_dn = peak - 1;   /* only that pixel reaches it */
    rec_pixel_maps pm;
    CHECK_OK(rec_pixel_maps_compute(&cap, m, NULL, NULL, &pm));
    if (pm.state) {
        CHECK(pm.state[pc] == REC_PIX_SATURATED && pm.bulb[pc] == -1);
        const char *path = fx_tmp("phase.png");
        CHECK_OK(rec_map_write_phase_png(&pm, path));
        int w = 0, h = 0;
        unsigned char *px = recfx_read_png(path, &w, &h);
        int s = rec_map_scale(cap.width, cap.height);
        CHECK(s == recfx_doc_scale(cap.width, cap.height) && w == s * cap.width);
        if (px) {
            const unsigned char *c = recfx_map_at(px, w, s, mem_lights[0].x, mem_lights[0].y);
            CHECK_MSG(c[0] == 255 && c[1] == 255 && c[2] == 255, "saturated pixel (%d, %d, %d)", c[0], c[1], c[2]);
            /* a neighbour, unsaturated: blue for 240 deg */
            recfx_check_phase_colour(recfx_map_at(px, w, s, mem_lights[0].x + 1, mem_lights[0].y), 240, "neighbour");
        }
        free(px);
        /* unwritable paths fail cleanly, leaving nothing behind */
        CHECK(rec_map_write_phase_png(&pm, "/nonexistent-dir/phase.png") == GS_EIO);
        CHECK(rec_map_write_bulb_png(&pm, m, "/nonexistent-dir/bulb.png") == GS_EIO);
        CHECK(rec_map_write_confidence_png(&pm, "/nonexistent-dir/c.png") == GS_EIO);
    }
    rec_pixel_maps_release(&pm);
    /* bad arguments */
    rec_map_opts o;
    rec_map_opts_default(&o);
    o.threshold_sigma = 0.0;
    CHECK(rec_pixel_maps_compute(&cap, m, NULL, &o, &pm) == GS_EINVAL && pm.state == NULL);
    o.threshold_sigma = NAN;
    CHECK(rec_pixel_maps_compute(&cap, m, NULL, &o, &pm) == GS_EINVAL);
    rec_matcher *mono = NULL;
    CHECK_OK(rec_matcher_new(d, 50, 1, 13, NULL, &mono));
    CHECK(rec_pixel_maps_compute(&cap, mono, NULL, NULL, &pm) == GS_EINVAL);
    rec_matcher *k26 = NULL;   /* a matcher for another K: refused, not read out of bounds */
    CHECK_OK(rec_matcher_new(d, 50, 3, 26, NULL, &k26));
    CHECK(rec_pixel_maps_compute(&cap, k26, NULL, NULL, &pm) == GS_EINVAL && strstr(gs_detail(), "K = 13"));
    rec_matcher_free(k26);
    CHECK(rec_pixel_maps_compute(NULL, m, NULL, NULL, &pm) == GS_EINVAL);
    rec_catalog cat;
    memset(&cat, 0, sizeof cat);
    CHECK(rec_plot_signals(m, &cat, NULL, 0, "/tmp/x.png", NULL) == GS_EINVAL);
    CHECK(rec_plot_signals(m, &cat, NULL, 4, "/nonexistent-dir/s.png", NULL) == GS_EIO);
    rec_matcher_free(mono);
    gs_capture_release(&cap);
    rec_matcher_free(m);
    gs_delight_free(d);
}

/* ------------------------------------------------------------ the signal plot (Fig. 3) */

static int matcher_bulb_index(const rec_matcher *m, const char *id)
{
    for (size_t i = 0; i < rec_matcher_bulb_count(m); i++)
        if (!strcmp(rec_matcher_bulb(m, i)->id, id)) return (int)i;
    return -1;
}

TEST(signals_template_is_the_fits_model)
{
    /* A noise-free mh-250w light reddened by extinction (optical depth 0.4 at 650/550/450 nm,
     * Angstrom exponent 1.3: its bands' shares are not the chromaticity's) with a flat share of
     * 5 % of its flicker, x_b = g_b (t_b + 0.05), fitted under the default (reddened) band model:
     * the plotted template times the brightness passes through its samples at the window centres. */
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, 512));
    rec_eq7_opts o;
    rec_eq7_opts_default(&o);
    o.flat_share = 0.05;
    rec_matcher *m = NULL;
    CHECK_OK(rec_matcher_new(d, 50, 3, 13, &o, &m));
    int bi = m ? matcher_bulb_index(m, "mh-250w") : -1;
    CHECK(bi >= 0);
    if (bi >= 0) {
        enum { K = 13 };
        const gs_bulb *b = rec_matcher_bulb(m, (size_t)bi);
        static const double lambda_nm[3] = {650.0, 550.0, 450.0};
        double t[3 * K], x[3 * K], sg[3 * K], u[K], c[K], g[3];
        CHECK_OK(gs_brf_integrate(&b->brf, gs_phase_to_shift(120.0), K, t));
        for (int band = 0; band < 3; band++) {
            g[band] = 500.0 * b->chroma[band] * exp(-0.4 * (pow(lambda_nm[band] / 550.0, -1.3) - 1.0));
            for (int k = 0; k < K; k++) {
                x[band * K + k] = g[band] * (t[band * K + k] + 0.05);
                sg[band * K + k] = 1e-3 * g[band];
            }
        }
        rec_match mt;
        CHECK_OK(rec_match_light(m, x, sg, &mt));
        CHECK_MSG(mt.bulb == bi && fabs(mt.phase_deg - 120.0) < 1e-9, "bulb %d phase %g", mt.bulb, mt.phase_deg);
        double complex *C = malloc(sizeof *C * (size_t)(b->brf.n / 2 + 1));
        for (int k = 0; k < K; k++) u[k] = (k + 0.5) / K;
        for (int band = 0; band < 3 && C; band++) {
            CHECK_OK(rec_plot_template(b, &mt, gs_phase_to_shift(mt.phase_deg), K, band, u, K, c, C));
            for (int k = 0; k < K; k++)
                CHECK_MSG(fabs(c[k] * mt.brightness - x[band * K + k]) < 1e-4 * g[band],
                          "band %d window %d: template %g x brightness %g, sample %g", band, k, c[k],
                          mt.brightness, x[band * K + k]);
        }
        free(C);
    }
    rec_matcher_free(m);
    gs_delight_free(d);
}

TEST(signals_lights_one_per_bulb_first)
{
    /* 14 lights, K = 4 mono, sigma 1, SNR = 2 x their level: bulb 5 has six lights (the five
     * brightest and light 12; the brightest, light 0, with an ambiguous phase: drawn after the
     * others of its bulb), bulb 2 four, bulb 7 two (one of them bulb-ambiguous, which is never
     * drawn) and bulb 1 one; light 13 has no answer. By count: 5, 2, then 1 and 7 (one light
     * each, by index). */
    static const int bulb[14] = {5, 5, 5, 5, 5, 2, 2, 2, 7, 7, 1, 2, 5, -1};
    static const double level[14] = {90, 80, 70, 60, 50, 40, 30, 20, 45, 15, 10, 25, 55, 100};
    enum { N = 14, K = 4 };
    double signal[N * K], sigma[N * K];
    rec_match match[N];
    memset(match, 0, sizeof match);
    for (int i = 0; i < N; i++) {
        for (int k = 0; k < K; k++) signal[i * K + k] = level[i], sigma[i * K + k] = 1.0;
        match[i].bulb = bulb[i];
        match[i].brightness = level[i];
        match[i].flags = i == 8 ? REC_MATCH_BULB_AMBIGUOUS : i == 0 ? REC_MATCH_PHASE_AMBIGUOUS : 0u;
    }
    rec_catalog cat;
    memset(&cat, 0, sizeof cat);
    cat.count = N, cat.bands = 1, cat.K = K, cat.signal = signal, cat.sigma = sigma;
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, 512));
    rec_matcher *m = NULL;
    CHECK_OK(rec_matcher_new(d, 50, 1, K, NULL, &m));
    /* a light's phase is known when its bulb is voltage-referenced and its phase not ambiguous */
    int known[14];
    for (int i = 0; i < N && m; i++)
        known[i] = bulb[i] >= 0 && rec_matcher_bulb(m, (size_t)bulb[i])->ref == GS_REF_VOLTAGE && i != 0;
    CHECK(m && rec_matcher_bulb(m, 5)->ref == GS_REF_VOLTAGE);   /* (light 0's ambiguity matters) */
    for (size_t max = 1; max <= 16 && m; max++) {
        rec_signal_pick pick[16];
        size_t n = 99;
        CHECK_OK(rec_signal_lights(m, &cat, match, max, pick, &n));
        /* the eligible lights: 12 (not 8, not 13) */
        CHECK_MSG(n == (max < 12 ? max : 12), "max %zu: %zu lights", max, n);
        int first_of[4] = {-1, -1, -1, -1};   /* the best light of colour 0..3 */
        static const int want_bulb[4] = {5, 2, 1, 7}, want_first[4] = {1, 5, 10, 9};
        for (size_t a = 0; a < n && a < 16; a++) {
            const rec_signal_pick *p = &pick[a];
            CHECK_MSG(p->light != 8 && p->light != 13, "max %zu: light %zu drawn", max, p->light);
            CHECK(p->colour >= 0 && p->colour < 4 && p->symbol >= 0 && p->symbol < REC_SIGNAL_SYMBOLS);
            if (p->colour < 0 || p->colour >= 4) continue;
            CHECK_MSG(bulb[p->light] == want_bulb[p->colour], "max %zu: colour %d is bulb %d", max, p->colour,
                      bulb[p->light]);
            if (p->symbol == 0) first_of[p->colour] = (int)p->light;
            for (size_t b = 0; b < a; b++) {
                CHECK_MSG(pick[b].light != p->light, "max %zu: light %zu twice", max, p->light);
                CHECK_MSG(pick[b].colour != p->colour || pick[b].symbol != p->symbol,
                          "max %zu: lights %zu and %zu share colour %d and symbol %d", max, pick[b].light,
                          p->light, p->colour, p->symbol);
                /* ordered by colour, then symbol; within a bulb a known phase first, then by SNR */
                size_t u = pick[b].light, v = p->light;
                CHECK(pick[b].colour < p->colour ||
                      (pick[b].colour == p->colour && pick[b].symbol < p->symbol &&
                       (known[u] > known[v] || (known[u] == known[v] && level[u] > level[v]))));
            }
        }
        /* every bulb drawn (up to max) with its best light */
        for (int c = 0; c < 4; c++)
            CHECK_MSG(first_of[c] == ((size_t)c < max ? want_first[c] : -1), "max %zu: colour %d's first light %d",
                      max, c, first_of[c]);
    }
    rec_matcher_free(m);
    gs_delight_free(d);
}

/* ------------------------------------------------------------ the bulb map's legend */

TEST(maps_bulb_legend_top_bulbs_and_other)
{
    /* 40 bulbs: 25 with pixels (two large, a tail down to 1 px, a tie), 15 without */
    enum { NB = 40 };
    size_t px[NB] = {0}, listed[NB], total = 0, with = 0;
    int colour[NB];
    for (int b = 0; b < 25; b++) px[(b * 7) % NB] = b == 0 ? 20000 : b == 1 ? 9000 : (size_t)(2400 / b);
    px[33] = px[(3 * 7) % NB];   /* a tie with bulb 21's 800 px */
    for (int b = 0; b < NB; b++) total += px[b], with += px[b] > 0;
    size_t other_bulbs = 99, other_px = 99;
    size_t n = rec_bulb_legend(px, NB, listed, colour, &other_bulbs, &other_px);
    CHECK_MSG(n >= 2 && n <= REC_BULB_LEGEND_MAX, "%zu bulbs listed", n);
    /* the counts add up: the listed bulbs and "other" cover every bulb with pixels */
    size_t listed_px = 0;
    for (size_t i = 0; i < n && i < NB; i++) listed_px += px[listed[i]];
    CHECK_MSG(n + other_bulbs == with && listed_px + other_px == total, "%zu + %zu bulbs of %zu, %zu + %zu px of %zu",
              n, other_bulbs, with, listed_px, other_px, total);
    for (size_t i = 0; i < n && i < NB; i++) {
        size_t b = listed[i];
        CHECK_MSG(px[b] >= REC_BULB_LEGEND_SHARE * (double)total, "bulb %zu listed with %zu px", b, px[b]);
        CHECK(colour[b] == (int)i);
        if (i) CHECK(px[listed[i - 1]] > px[b] || (px[listed[i - 1]] == px[b] && listed[i - 1] < b));
        /* distinct colours within the legend, "other" one of its own */
        const unsigned char *c = rec_bulb_palette[colour[b] >= 0 && colour[b] <= REC_BULB_OTHER_COLOUR ? colour[b] : 0];
        CHECK(memcmp(c, rec_bulb_palette[REC_BULB_OTHER_COLOUR], 3) != 0);
        for (size_t j = 0; j < i; j++)
            CHECK_MSG(memcmp(c, rec_bulb_palette[colour[listed[j]]], 3) != 0, "bulbs %zu and %zu share a colour", b,
                      listed[j]);
    }
    /* an unlisted bulb: "other" (fewer pixels than every listed one, or below the share) or none */
    for (size_t b = 0; b < NB; b++) {
        int is_listed = 0;
        for (size_t i = 0; i < n && i < NB; i++) is_listed |= listed[i] == b;
        if (is_listed) continue;
        CHECK_MSG(colour[b] == (px[b] ? REC_BULB_OTHER_COLOUR : -1), "bulb %zu (%zu px): colour %d", b, px[b], colour[b]);
        if (px[b] && n)
            CHECK(px[b] < REC_BULB_LEGEND_SHARE * (double)total ||
                  (n == REC_BULB_LEGEND_MAX && px[b] <= px[listed[n - 1]]));
    }
    /* 20 bulbs of 5 % each: the first REC_BULB_LEGEND_MAX by index listed, the rest "other" */
    size_t even[20];
    for (int b = 0; b < 20; b++) even[b] = 100;
    CHECK(rec_bulb_legend(even, 20, listed, colour, &other_bulbs, &other_px) == REC_BULB_LEGEND_MAX &&
          listed[REC_BULB_LEGEND_MAX - 1] == REC_BULB_LEGEND_MAX - 1 && other_bulbs == 20 - REC_BULB_LEGEND_MAX &&
          other_px == 100 * (20 - REC_BULB_LEGEND_MAX) && colour[19] == REC_BULB_OTHER_COLOUR);
    /* every pixel one bulb: listed alone */
    size_t one[3] = {0, 5, 0};
    CHECK(rec_bulb_legend(one, 3, listed, colour, &other_bulbs, &other_px) == 1 && listed[0] == 1 &&
          other_bulbs == 0 && other_px == 0 && colour[0] == -1 && colour[1] == 0);
}

TEST(maps_bulb_map_greys_ambiguous_pixels)
{
    /* As the phase map: a matched pixel below the ambiguity threshold is grey, a confident one in
     * its bulb's colour (the legend counts those). Every second matched pixel made ambiguous. */
    gs_delight *d = NULL;
    gs_capture cap;
    rec_matcher *m = mem_setup(&d, &cap);
    rec_pixel_maps pm;
    CHECK_OK(rec_pixel_maps_compute(&cap, m, NULL, NULL, &pm));
    size_t np = (size_t)cap.width * (size_t)cap.height, nm = 0;
    for (size_t p = 0; p < np && pm.state; p++)
        if (pm.state[p] == REC_PIX_MATCHED && nm++ % 2) pm.confidence[p] = (float)(0.5 * pm.ambiguous_conf);
    CHECK_MSG(nm >= 8, "%zu matched pixels", nm);
    if (nm >= 8) {
        const char *path = fx_tmp("bulb.png");
        CHECK_OK(rec_map_write_bulb_png(&pm, m, path));
        int w = 0, h = 0, s = rec_map_scale(cap.width, cap.height);
        unsigned char *px = recfx_read_png(path, &w, &h);
        size_t grey = 0, coloured = 0;
        for (int y = 0; y < cap.height && px; y++)
            for (int x = 0; x < cap.width; x++) {
                size_t p = (size_t)y * (size_t)cap.width + (size_t)x;
                if (pm.state[p] != REC_PIX_MATCHED) continue;
                const unsigned char *c = recfx_map_at(px, w, s, x, y);
                int is_grey = c[0] == c[1] && c[1] == c[2];
                int ambiguous = pm.confidence[p] < pm.ambiguous_conf;
                CHECK_MSG(is_grey == ambiguous, "pixel (%d, %d), confidence %g: (%d, %d, %d)", x, y,
                          pm.confidence[p], c[0], c[1], c[2]);
                grey += is_grey;
                coloured += !is_grey;
            }
        CHECK(grey > 0 && coloured > 0);
        free(px);
    }
    rec_pixel_maps_release(&pm);
    gs_capture_release(&cap);
    rec_matcher_free(m);
    gs_delight_free(d);
}

/* A plot's rows (PNG at path): the frame's top and bottom, the highest and lowest rows inked
 * across 2/5 of the width; the first and last rows holding more than fill x the width in pixels
 * of the first curve's colour (230, 159, 0). 0, or -1 if the PNG does not read. */
static int plot_rows(const char *path, double fill, int *top, int *bottom, int *first, int *last)
{
    int w = 0, h = 0;
    unsigned char *px = recfx_read_png(path, &w, &h);
    if (!px) return -1;
    *top = *bottom = *first = *last = -1;
    for (int y = 0; y < h; y++) {
        int ink = 0, mine = 0;
        for (int x = 0; x < w; x++) {
            const unsigned char *p = px + 3 * ((size_t)y * (size_t)w + (size_t)x);
            ink += p[0] < 200 || p[1] < 200 || p[2] < 200;
            mine += abs(p[0] - 230) < 40 && abs(p[1] - 159) < 40 && p[2] < 60;
        }
        if (ink > 2 * w / 5) {
            if (*top < 0) *top = y;
            *bottom = y;
        }
        if (mine > fill * w) {
            if (*first < 0) *first = y;
            *last = y;
        }
    }
    free(px);
    CHECK_MSG(*top >= 0 && *first >= 0 && *bottom - *top > h / 3, "frame rows %d..%d, curve rows %d..%d", *top,
              *bottom, *first, *last);
    return 0;
}

/* The BRF plot (rec_plot_brfs, `delight plot`): a bulb dark for half its cycle (value 0) and at
 * 2 the other half draws both levels inside the frame, clear of its lines: each level is the
 * row its colour fills along most of half the plot (~ w / 4 wide). */
TEST(brf_plot_zero_and_peak_inside_the_frame)
{
    gs_bulb b;
    memset(&b, 0, sizeof b);
    snprintf(b.id, sizeof b.id, "dark-half");
    b.type = GS_TECH_LED_PWM;
    b.grid_hz = 50;
    CHECK_OK(gs_brf_init(&b.brf, 64, 1));
    for (int j = 0; j < 64; j++) b.brf.v[j] = j >= 16 && j < 48 ? 0.0 : 2.0;   /* mean 1 */
    const gs_bulb *list[1] = {&b};
    const char *path = fx_tmp("brf_zero.png");
    CHECK_OK(rec_plot_brfs(list, 1, path, "dark half"));
    gs_bulb_release(&b);
    int top, bottom, peak, zero;
    if (plot_rows(path, 1.0 / 8, &top, &bottom, &peak, &zero)) return;
    CHECK_MSG(zero < bottom - 3, "the zero level (row %d) on the frame's bottom (row %d)", zero, bottom);
    CHECK_MSG(peak > top + 3, "the peak level (row %d) on the frame's top (row %d)", peak, top);
}

/* The signal plot (rec_plot_signals, Fig. 3): a dim sample's error bar reaching below 0 is drawn
 * whole, inside the frame (the axis used to start at 0, cutting it at the frame's bottom). One
 * mono light, K = 4, samples 1, 1, 0, 1 of sigma 0.3: the bar of the third spans -0.3..0.3. */
TEST(signal_plot_error_bar_below_zero_inside_the_frame)
{
    enum { K = 4 };
    double signal[K] = {1.0, 1.0, 0.0, 1.0}, sigma[K] = {0.3, 0.3, 0.3, 0.3};
    rec_match match;
    memset(&match, 0, sizeof match);
    match.brightness = 1.0;
    rec_catalog cat;
    memset(&cat, 0, sizeof cat);
    cat.count = 1, cat.bands = 1, cat.K = K, cat.signal = signal, cat.sigma = sigma;
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, 512));
    rec_matcher *m = NULL;
    CHECK_OK(rec_matcher_new(d, 50, 1, K, NULL, &m));
    const char *path = fx_tmp("signal_below_zero.png");
    if (m) CHECK_OK(rec_plot_signals(m, &cat, &match, 1, path, "dim sample"));
    rec_matcher_free(m);
    gs_delight_free(d);
    int top, bottom, first, last;
    if (!m || plot_rows(path, 0, &top, &bottom, &first, &last)) return;
    CHECK_MSG(last < bottom - 3, "the error bar's lowest row %d on the frame's bottom (row %d)", last, bottom);
}

/* The signal plot draws only the samples rec_match_catalog used: a free-running frame left out
 * (its windows drifted 0.9 windows, over the 0.5 of a capture without window_period) holding
 * 40 times the light's level gives the same PNG as the same frame holding its level; locked,
 * the same frame is drawn (a different PNG: the comparison can fail). */
TEST(signal_plot_leaves_out_the_frames_left_out)
{
    enum { K = 4 };
    double drift[K] = {0.2, 0.9, 0.2, 0.2}, sigma[K] = {0.1, 0.1, 0.1, 0.1};
    double quiet[K] = {1.0, 1.0, 0.5, 1.0}, loud[K] = {1.0, 40.0, 0.5, 1.0};
    rec_match match;
    memset(&match, 0, sizeof match);
    match.brightness = 1.0;
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, 512));
    rec_matcher *m = NULL;
    CHECK_OK(rec_matcher_new(d, 50, 1, K, NULL, &m));
    char *png[3] = {NULL, NULL, NULL};
    size_t len[3] = {0, 0, 0};
    for (int v = 0; v < 3 && m; v++) {   /* free quiet, free loud, locked loud */
        rec_catalog cat;
        memset(&cat, 0, sizeof cat);
        cat.count = 1, cat.bands = 1, cat.K = K, cat.signal = v ? loud : quiet, cat.sigma = sigma;
        cat.drift_windows = v < 2 ? drift : NULL;
        char name[64];
        snprintf(name, sizeof name, "signal_left_out_%d.png", v);
        const char *path = fx_tmp(name);
        CHECK_OK(rec_plot_signals(m, &cat, &match, 1, path, "left out"));
        png[v] = fx_read_file(path, &len[v]);
    }
    CHECK(png[0] && png[1] && png[2]);
    if (png[0] && png[1] && png[2]) {
        CHECK_MSG(len[0] == len[1] && !memcmp(png[0], png[1], len[0]), "the left-out frame changed the plot");
        CHECK_MSG(len[1] != len[2] || memcmp(png[1], png[2], len[1]), "locked, the loud frame did not change it");
    }
    for (int v = 0; v < 3; v++) free(png[v]);
    rec_matcher_free(m);
    gs_delight_free(d);
}
