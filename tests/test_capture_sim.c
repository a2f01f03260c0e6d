/* test_capture_sim.c - the scene simulator (capture/sim.c, effects.c): without effects a frame
 * is the exact Eq. 5 integral through the masks (checked against brute-force numerical
 * integration of the BRF's trigonometric polynomial); an effect the scene does not list is never
 * executed (pipeline list and the effects' own call counters); the HDR loop recovers saturated
 * lights, its samples near full well the truncated normal; the effects' physics numbers (shared/BULBS.md); determinism. */
#include "tests/fixtures.h"
#include "tests/test.h"
#include "capture/sim.h"
#include "survey/internal.h"

#include <errno.h>
#include <fcntl.h>
#include <jansson.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

static gs_delight *delight(void)
{
    gs_delight *d = gs_delight_new();
    if (d && gs_delight_generate(d, GS_BRF_N_DEFAULT) != GS_OK) {
        gs_delight_free(d);
        return NULL;
    }
    return d;
}

/* The simulator of the scene text (name: the file name its messages give) into *sc, NULL after
 * a failed check; the caller frees both (cap_sim_free, cap_scene_release). */
static cap_sim *sim_of(const char *text, const char *name, const gs_delight *d, cap_scene *sc)
{
    CHECK_OK(cap_scene_parse(text, name, ".", sc));
    cap_sim *s = NULL;
    CHECK_OK(cap_sim_new(sc, d, &s));
    return s;
}

/* ------------------------------------------------------------ brute-force Eq. 5 */

/* The BRF band as its trigonometric polynomial (naive DFT, no FFTW), evaluated at any t. */
typedef struct {
    int n;
    double c0, nyq;
    double *re, *im;   /* C_h, h = 1 .. n/2 - 1 */
} trig;

static void trig_init(trig *t, const double *x, int n)
{
    t->n = n;
    t->re = calloc((size_t)n / 2, sizeof *t->re);
    t->im = calloc((size_t)n / 2, sizeof *t->im);
    t->c0 = 0;
    t->nyq = 0;
    for (int j = 0; j < n; j++) {
        t->c0 += x[j];
        t->nyq += (j % 2 ? -1.0 : 1.0) * x[j];
    }
    for (int h = 1; h < n / 2; h++)
        for (int j = 0; j < n; j++) {
            double a = -2.0 * M_PI * (double)((long)h * j % n) / n;
            t->re[h] += x[j] * cos(a);
            t->im[h] += x[j] * sin(a);
        }
}

static double trig_eval(const trig *t, double x)
{
    /* (C0 + 2 sum Re(C_h e^{2 pi i h x}) + C_{n/2} cos(pi n x)) / n, by rotation */
    double cr = cos(2 * M_PI * x), ci = sin(2 * M_PI * x), zr = 1, zi = 0, acc = 0;
    for (int h = 1; h < t->n / 2; h++) {
        double nr = zr * cr - zi * ci;
        zi = zr * ci + zi * cr;
        zr = nr;
        acc += t->re[h] * zr - t->im[h] * zi;
    }
    return (t->c0 + 2 * acc + t->nyq * cos(M_PI * t->n * x)) / t->n;
}

/* Mean of B(t - shift) over [a, b] by composite Simpson with m (even) intervals. */
static double brute_mean(const trig *t, double shift, double a, double b, int m)
{
    double h = (b - a) / m, s = 0;
    for (int i = 0; i <= m; i++) {
        double w = i == 0 || i == m ? 1 : (i % 2 ? 4 : 2);
        s += w * trig_eval(t, a + i * h - shift);
    }
    return s * h / 3 / (b - a);
}

static const char *exact_scene =
    "{\"format\": \"gridsurvey-scene/1\", \"seed\": 3,\n"
    " \"grid\": {\"nominal_hz\": 50},\n"
    " \"camera\": {\"width_px\": 40, \"height_px\": 30,\n"
    "   \"sensor\": {\"bands\": 3, \"gain_e_per_dn\": 2.5, \"black_level_dn\": 10}},\n"
    " \"acam\": {\"K\": 13, \"cycles\": 64, \"masks\": 16, \"hdr\": true},\n"
    " \"lights\": [\n"
    "  {\"bulb\": \"hps-150w\", \"phase_deg\": 0, \"x_px\": 5, \"y_px\": 5, \"flux_e_per_cycle\": 1500},\n"
    "  {\"bulb\": \"led-street-60w-lin3\", \"phase_deg\": 120, \"x_px\": 20, \"y_px\": 8, \"flux_e_per_cycle\": 2600},\n"
    "  {\"bulb\": \"fl-t8-36w-tri\", \"phase_deg\": 240, \"x_px\": 33, \"y_px\": 21, \"flux_e_per_cycle\": 900},\n"
    "  {\"bulb\": \"mh-250w\", \"phase_deg\": 47.5, \"x_px\": 12, \"y_px\": 25, \"flux_e_per_cycle\": 1234.5},\n"
    "  {\"bulb\": \"cfl-20w\", \"phase_deg\": 120, \"x_px\": 12, \"y_px\": 25, \"flux_e_per_cycle\": 321}\n"
    " ]}\n";

TEST(sim_no_effects_is_exact_eq5_vs_brute_force)
{
    gs_delight *d = delight();
    CHECK(d != NULL);
    cap_scene sc;
    cap_sim *s = sim_of(exact_scene, "exact.json", d, &sc);
    if (!s) return;
    int W = 40, H = 30, B = 3, K = 13;
    size_t n = (size_t)W * H * B;
    double *dn = malloc(n * sizeof *dn);
    unsigned short *raw = malloc(n * sizeof *raw);
    unsigned char *halv = calloc((size_t)W * H, 1);
    /* two lights halved (HDR rows), exposing C/2 and C/8 cycles */
    halv[5 * W + 5] = 1;
    halv[8 * W + 20] = 3;
    /* the brute-force model of every light */
    trig t[5][3];
    const gs_bulb *bulbs[5];
    for (size_t l = 0; l < 5; l++) {
        bulbs[l] = gs_delight_find(d, sc.lights[l].bulb, 50, 3);
        CHECK(bulbs[l] != NULL);
        for (int b = 0; b < B; b++)
            trig_init(&t[l][b], bulbs[l]->brf.v + (size_t)b * (size_t)bulbs[l]->brf.n, bulbs[l]->brf.n);
    }
    double worst = 0;
    int ks[3] = {0, 6, 12};
    for (int ki = 0; ki < (fx_sanitized() ? 1 : 3); ki++) {
        int k = ks[ki];
        CHECK_OK(cap_sim_render(s, k, 0, ki, halv, raw, dn));
        double expect[30][40][3];
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++)
                for (int b = 0; b < B; b++) expect[y][x][b] = 10.0;
        for (size_t l = 0; l < 5; l++) {
            int x = (int)sc.lights[l].x_px, y = (int)sc.lights[l].y_px;
            int h = halv[y * W + x];
            double cycles = 64.0 / (1 << h);   /* C / 2^h (Sec. 6) */
            double shift = gs_phase_to_shift(sc.lights[l].phase_deg);
            for (int b = 0; b < B; b++) {
                double m = brute_mean(&t[l][b], shift, (double)k / K, (double)(k + 1) / K, 600);
                expect[y][x][b] += sc.lights[l].flux_e_per_cycle * bulbs[l]->chroma[b] * cycles * m / K / 2.5;
            }
        }
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++)
                for (int b = 0; b < B; b++) {
                    size_t i = ((size_t)y * W + x) * B + b;
                    double e = expect[y][x][b], rel = fabs(dn[i] - e) / e;
                    if (rel > worst) worst = rel;
                    CHECK_MSG(rel < 1e-9, "k %d pixel (%d, %d) band %d: %.12g vs brute force %.12g", k, x, y, b, dn[i], e);
                    CHECK(raw[i] == (unsigned short)floor(e + 0.5) || fabs(e - floor(e) - 0.5) < 1e-6);
                }
    }
    printf("    no effects vs brute-force Eq. 5 (Simpson, 600 intervals): worst relative error %.2e\n", worst);
    /* no stage but the base ones */
    for (size_t i = 0; i < cap_sim_stage_count(s); i++) {
        cap_stage_info si;
        CHECK_OK(cap_sim_stage(s, i, &si));
        CHECK_MSG(si.effect < 0, "stage %s is an effect", si.name);
    }
    for (size_t l = 0; l < 5; l++)
        for (int b = 0; b < B; b++) {
            free(t[l][b].re);
            free(t[l][b].im);
        }
    free(dn);
    free(raw);
    free(halv);
    cap_sim_free(s);
    cap_scene_release(&sc);
    gs_delight_free(d);
}

/* ------------------------------------------------------------ skyglow */

/* A light's halo is centred on the light, not on its pixel: the frame with the skyglow minus
 * the frame without it (the halo alone) has its centroid at the light's position, to rounding,
 * for lights at several sub-pixel offsets (it sat on the nearest pixel centre: 0.3 and 0.4 px
 * off for the first). */
TEST(sim_skyglow_halo_centred_on_the_light)
{
    static const double pos[][2] = {{30.3, 25.6}, {30.5, 25.5}, {29.9, 26.2}, {31.0, 24.0}};
    gs_delight *d = delight();
    for (size_t t = 0; t < sizeof pos / sizeof *pos; t++) {
        double *dn[2] = {malloc(sizeof(double) * 64 * 48), malloc(sizeof(double) * 64 * 48)};
        for (int with = 0; with < 2; with++) {
            char text[1024];
            snprintf(text, sizeof text,
                     "{\"format\": \"gridsurvey-scene/1\", \"seed\": 5, \"grid\": {\"nominal_hz\": 50},\n"
                     " \"camera\": {\"width_px\": 64, \"height_px\": 48, \"sensor\": {\"bands\": 1}},\n"
                     " \"acam\": {\"K\": 8, \"cycles\": 40},\n"
                     " \"lights\": [{\"bulb\": \"hps-150w\", \"x_px\": %.3f, \"y_px\": %.3f, \"flux_e_per_cycle\": 900}],\n"
                     " \"effects\": {%s}}\n",
                     pos[t][0], pos[t][1], with ? "\"skyglow\": {\"fraction\": 0.05, \"scale_px\": 2}" : "");
            cap_scene sc;
            cap_sim *s = sim_of(text, "glow.json", d, &sc);
            if (s && dn[with]) CHECK_OK(cap_sim_render(s, 3, 0, 0, NULL, NULL, dn[with]));
            cap_sim_free(s);
            cap_scene_release(&sc);
        }
        double sum = 0, sx = 0, sy = 0;
        for (int y = 0; dn[0] && dn[1] && y < 48; y++)
            for (int x = 0; x < 64; x++) {
                double h = dn[1][y * 64 + x] - dn[0][y * 64 + x];
                sum += h;
                sx += h * x;
                sy += h * y;
            }
        CHECK_MSG(sum > 0, "light at (%g, %g): no halo", pos[t][0], pos[t][1]);
        if (sum > 0)
            CHECK_MSG(fabs(sx / sum - pos[t][0]) < 1e-9 && fabs(sy / sum - pos[t][1]) < 1e-9,
                      "light at (%g, %g): halo centroid (%.6f, %.6f)", pos[t][0], pos[t][1], sx / sum, sy / sum);
        free(dn[0]);
        free(dn[1]);
    }
    gs_delight_free(d);
}

/* ------------------------------------------------------------ disabled effects */

/* Parameters that make each effect valid on its own. */
static const char *const fx_params[CAP_FX_COUNT] = {
    "\"frequency_wander\": {}",
    "\"free_running_drift\": {\"clock_ppm\": 20}",
    "\"dmd_jitter\": {\"sigma_us\": 5}",
    "\"extinction\": {\"visibility_km\": 20}",
    "\"scintillation\": {\"intensity_variance\": 0.3}",
    "\"psf\": {\"sigma_px\": 1.0}",
    "\"light_transport\": {\"room\": {\"width_m\": 6, \"height_m\": 4, \"depth_m\": 8000}, \"boxes\": [{\"min_m\": [-1, 0, 2000], \"max_m\": [1, 1, 2500]}]}",
    "\"skyglow\": {\"fraction\": 0.05, \"scale_px\": 2}",
    "\"blinking_sign\": {\"signs\": [{\"x_px\": 3, \"y_px\": 3, \"width_px\": 2, \"height_px\": 2, \"period_s\": 0.7, \"flux_e_per_cycle\": 500}]}",
    "\"headlights\": {\"cars\": [{\"from\": [0, 20], \"to\": [39, 20], \"speed_px_s\": 20, \"period_s\": 3, \"flux_e_per_cycle\": 800}]}",
    "\"ambient\": {\"e_per_px_cycle\": 3}",
    "\"semi_reflection\": {\"reflectance\": 0.3, \"outdoor_e_per_px_cycle\": 40}",
    "\"shot_noise\": {}",
    "\"saturation\": {}",
    "\"read_noise\": {}",
    "\"adc\": {}",
};

static char *scene_with(unsigned mask)
{
    size_t cap = 8192;
    char *t = malloc(cap);
    int locked = !(mask & (1u << CAP_FX_FREE_RUNNING_DRIFT));
    int u = snprintf(t, cap,
                     "{\"format\": \"gridsurvey-scene/1\", \"seed\": 5,\n"
                     " \"grid\": {\"nominal_hz\": 50%s},\n"
                     " \"camera\": {\"width_px\": 40, \"height_px\": 30, \"sensor\": {\"bands\": 3}},\n"
                     " \"acam\": {\"K\": 10, \"cycles\": 40, \"locked\": %s},\n"
                     " \"lights\": [{\"bulb\": \"hps-150w\", \"x_px\": 10.3, \"y_px\": 12.6, \"distance_m\": 3000, \"flux_e_per_cycle\": 900},\n"
                     "            {\"bulb\": \"mh-250w\", \"phase_deg\": 120, \"x_px\": 30, \"y_px\": 5, \"distance_m\": 5000, \"flux_e_per_cycle\": 700}],\n"
                     " \"effects\": {",
                     mask & (1u << CAP_FX_FREQUENCY_WANDER) ? ", \"frequency\": {\"model\": \"random_walk\"}" : "",
                     locked ? "true" : "false");
    int first = 1;
    for (int e = 0; e < CAP_FX_COUNT; e++)
        if (mask & (1u << e)) {
            u += snprintf(t + u, cap - (size_t)u, "%s\n  %s", first ? "" : ",", fx_params[e]);
            first = 0;
        }
    snprintf(t + u, cap - (size_t)u, "}}\n");
    return t;
}

/* Renders `frames` acquisitions of the scene with exactly `mask` and checks the pipeline and
 * the counters: listed effects ran once per acquisition, the others never. */
static void check_mask(const gs_delight *d, unsigned mask, int frames)
{
    char *text = scene_with(mask);
    cap_scene sc;
    gs_status st = cap_scene_parse(text, "mask.json", ".", &sc);
    CHECK_MSG(st == GS_OK, "mask %#x: %s", mask, gs_detail());
    cap_sim *s = NULL;
    if (st == GS_OK) CHECK_OK(cap_sim_new(&sc, d, &s));
    if (s) {
        unsigned short *raw = malloc(40 * 30 * 3 * sizeof *raw);
        for (int i = 0; i < frames; i++) CHECK_OK(cap_sim_render(s, i % 10, 0, i, NULL, raw, NULL));
        unsigned in_pipeline = 0;
        for (size_t i = 0; i < cap_sim_stage_count(s); i++) {
            cap_stage_info si;
            CHECK_OK(cap_sim_stage(s, i, &si));
            CHECK(si.calls == (unsigned long long)frames);
            if (si.effect >= 0) {
                in_pipeline |= 1u << si.effect;
                CHECK(!strcmp(si.name, cap_effect_name((cap_effect)si.effect)));
            }
        }
        CHECK_MSG(in_pipeline == mask, "mask %#x: pipeline holds %#x", mask, in_pipeline);
        for (int e = 0; e < CAP_FX_COUNT; e++) {
            unsigned long long calls = cap_sim_effect_calls(s, (cap_effect)e);
            if (mask & (1u << e))
                CHECK_MSG(calls == (unsigned long long)frames, "%s listed: %llu calls for %d frames",
                          cap_effect_name((cap_effect)e), calls, frames);
            else
                CHECK_MSG(calls == 0, "%s not listed but ran %llu times", cap_effect_name((cap_effect)e), calls);
        }
        free(raw);
    }
    cap_sim_free(s);
    cap_scene_release(&sc);
    free(text);
}

TEST(sim_disabled_effect_never_runs)
{
    gs_delight *d = delight();
    CHECK(d != NULL);
    check_mask(d, 0, 3);                                   /* none */
    for (int e = 0; e < CAP_FX_COUNT; e++) check_mask(d, 1u << e, 2);   /* each alone */
    check_mask(d, (1u << CAP_FX_COUNT) - 1, 2);            /* all */
    /* all but one, for each */
    for (int e = 0; e < CAP_FX_COUNT; e++) check_mask(d, ((1u << CAP_FX_COUNT) - 1) & ~(1u << e), 1);
    gs_delight_free(d);
}

TEST(sim_bench_render_grows_only_with_enabled_effects)
{
    gs_delight *d = delight();
    char *text = scene_with((1u << CAP_FX_COUNT) - 1);
    cap_scene sc;
    CHECK_OK(cap_scene_parse(text, "bench.json", ".", &sc));
    srv_render_time_result none, one, all;
    CHECK_OK(srv_render_time(&sc, 0, 2, 1, &none));
    CHECK_OK(srv_render_time(&sc, 1u << CAP_FX_PSF, 2, 1, &one));
    CHECK_OK(srv_render_time(&sc, ~0u, 2, 1, &all));
    CHECK(none.effects == 0);
    CHECK(one.effects == 1u << CAP_FX_PSF);
    CHECK(all.effects == (1u << CAP_FX_COUNT) - 1);
    CHECK(none.lights == 2 && none.pixels == 1200);
    printf("    bench (40x30, 2 frames): none %.2e s, psf %.2e s, all %.2e s per frame\n",
           none.seconds_per_frame, one.seconds_per_frame, all.seconds_per_frame);
    cap_scene_release(&sc);
    free(text);
    gs_delight_free(d);
}

/* ------------------------------------------------------------ threads */

/* One acquisition of `text` on `threads` threads, with some pixels halved: dn, raw and the
 * stages' item counts. */
static void render_on(const gs_delight *d, const char *text, int threads, double *dn,
                      unsigned short *raw, unsigned long long *items, size_t *n_stages)
{
    cap_scene sc;
    cap_sim *s = sim_of(text, "threads.json", d, &sc);
    if (!s) {
        cap_scene_release(&sc);
        return;
    }
    cap_sim_set_threads(s, threads);
    unsigned char halv[40 * 30] = {0};
    for (int y = 10; y < 16; y++)
        for (int x = 6; x < 14; x++) halv[y * 40 + x] = (unsigned char)(1 + (x + y) % 2);
    CHECK_OK(cap_sim_render(s, 3, 1, 4, halv, raw, dn));
    *n_stages = cap_sim_stage_count(s);
    for (size_t i = 0; i < *n_stages && i < CAP_MAX_STAGES; i++) {
        cap_stage_info si;
        CHECK_OK(cap_sim_stage(s, i, &si));
        items[i] = si.items;
    }
    cap_sim_free(s);
    cap_scene_release(&sc);
}

/* Every stage splits rows or lights into disjoint parts (per-row and per-light random streams,
 * each pixel summing its lights in scene order): 2, 3 and 7 threads give the one-thread frame
 * bit for bit, and each stage touches the same number of items (the footprints and halos cut at
 * the parts' row boundaries add up to the whole ones). The row stages run together over blocks
 * of rows (cap_rows_run): one block of the whole 40 x 30 frame on one thread (each stage over the
 * frame, then the next), chunks of one row on more, so a row stage that read rows beyond
 * its own would fail here too. */
TEST(sim_threads_bit_identical_to_one_thread)
{
    gs_delight *d = delight();
    CHECK(d != NULL);
    unsigned all = (1u << CAP_FX_COUNT) - 1;
    /* the last without shot noise and ADC: dn keeps every last bit of the deposits (a Poisson
     * draw would hide a one-ulp difference in its mean) */
    unsigned masks[4] = {all, all & ~(1u << CAP_FX_FREE_RUNNING_DRIFT),
                         (1u << CAP_FX_PSF) | (1u << CAP_FX_SKYGLOW) | (1u << CAP_FX_SCINTILLATION) |
                             (1u << CAP_FX_SHOT_NOISE) | (1u << CAP_FX_READ_NOISE),
                         (1u << CAP_FX_PSF) | (1u << CAP_FX_SKYGLOW) | (1u << CAP_FX_SCINTILLATION) |
                             (1u << CAP_FX_AMBIENT) | (1u << CAP_FX_READ_NOISE)};
    size_t n = 40 * 30 * 3;
    double *dn1 = malloc(n * sizeof *dn1), *dn = malloc(n * sizeof *dn);
    unsigned short *raw1 = malloc(n * sizeof *raw1), *raw = malloc(n * sizeof *raw);
    for (int mi = 0; mi < 4; mi++) {
        /* with HDR masks, so pixels can be halved, and two more lights whose footprints and
         * halos overlap the first one's across the parts' row boundaries (each pixel then sums
         * several lights: their order decides the bits) */
        const char *more = "{\"bulb\": \"lps-90w\", \"phase_deg\": 240, \"x_px\": 11.2, \"y_px\": 11.4, "
                           "\"distance_m\": 4000, \"flux_e_per_cycle\": 1300},\n"
                           "            {\"bulb\": \"hps-250w\", \"x_px\": 9.6, \"y_px\": 13.3, "
                           "\"distance_m\": 2500, \"flux_e_per_cycle\": 1700},\n"
                           "            {\"bulb\": \"mh-250w\", \"phase_deg\": 120, \"x_px\": 10.9, \"y_px\": 12.2, "
                           "\"distance_m\": 3500, \"flux_e_per_cycle\": 1100.7},\n            ";
        char *plain = scene_with(masks[mi]);
        size_t cap = strlen(plain) + strlen(more) + 64;
        char *text = malloc(cap);
        const char *at = strstr(plain, "\"locked\""), *li = strstr(plain, "\"lights\": [");
        CHECK(at != NULL && li != NULL && at < li);
        if (!at || !li || at > li) at = li = plain;
        li += strlen("\"lights\": [");
        snprintf(text, cap, "%.*s\"masks\": 16, \"hdr\": true, %.*s%s%s", (int)(at - plain), plain,
                 (int)(li - at), at, more, li);
        free(plain);
        unsigned long long items1[CAP_MAX_STAGES] = {0}, items[CAP_MAX_STAGES] = {0};
        size_t ns1 = 0, ns = 0;
        render_on(d, text, 1, dn1, raw1, items1, &ns1);
        int threads[3] = {2, 3, 7};
        for (int ti = 0; ti < 3; ti++) {
            memset(dn, 0, n * sizeof *dn);
            render_on(d, text, threads[ti], dn, raw, items, &ns);
            CHECK_MSG(!memcmp(dn, dn1, n * sizeof *dn), "mask %#x, %d threads: dn differs", masks[mi],
                      threads[ti]);
            CHECK_MSG(!memcmp(raw, raw1, n * sizeof *raw), "mask %#x, %d threads: raw differs",
                      masks[mi], threads[ti]);
            CHECK(ns == ns1);
            for (size_t i = 0; i < ns && i < CAP_MAX_STAGES; i++)
                CHECK_MSG(items[i] == items1[i], "mask %#x, %d threads, stage %zu: %llu items, one "
                          "thread %llu", masks[mi], threads[ti], i, items[i], items1[i]);
        }
        /* the frame is not trivially the same: the lights and the noise are in it */
        double mn = dn1[0], mx = dn1[0];
        for (size_t i = 0; i < n; i++) {
            if (dn1[i] < mn) mn = dn1[i];
            if (dn1[i] > mx) mx = dn1[i];
        }
        CHECK_MSG(mx > mn + 10, "mask %#x: flat frame %g .. %g", masks[mi], mn, mx);
        free(text);
    }
    free(dn1);
    free(dn);
    free(raw1);
    free(raw);
    gs_delight_free(d);
}

/* ------------------------------------------------------------ HDR */

TEST(sim_hdr_recovers_saturated_lights_within_2_percent)
{
    const char *text =
        "{\"format\": \"gridsurvey-scene/1\", \"seed\": 11,\n"
        " \"grid\": {\"nominal_hz\": 50},\n"
        " \"camera\": {\"width_px\": 64, \"height_px\": 48,\n"
        "   \"sensor\": {\"bands\": 3, \"bit_depth\": 12, \"full_well_e\": 20000, \"read_noise_e\": 3, \"gain_e_per_dn\": 5, \"black_level_dn\": 64}},\n"
        " \"acam\": {\"K\": 8, \"cycles\": 256, \"masks\": 64, \"hdr\": {\"enabled\": true, \"max_saturated_px\": 0}},\n"
        " \"lights\": [\n"
        "  {\"id\": \"bright\", \"bulb\": \"hps-150w\", \"phase_deg\": 0, \"x_px\": 15.2, \"y_px\": 14.7, \"flux_e_per_cycle\": 30000},\n"
        "  {\"id\": \"brighter\", \"bulb\": \"mh-250w\", \"phase_deg\": 120, \"x_px\": 45.6, \"y_px\": 30.3, \"flux_e_per_cycle\": 90000},\n"
        "  {\"id\": \"dim\", \"bulb\": \"fl-t8-36w-tri\", \"phase_deg\": 240, \"x_px\": 40.1, \"y_px\": 10.9, \"flux_e_per_cycle\": 2000}\n"
        " ],\n"
        " \"effects\": {\"psf\": {\"sigma_px\": 1.2}, \"shot_noise\": {}, \"saturation\": {}, \"read_noise\": {}, \"adc\": {}}}\n";
    cap_scene sc;
    CHECK_OK(cap_scene_parse(text, "hdr.json", ".", &sc));
    cap_backend *be = NULL;
    CHECK_OK(cap_backend_sim_new(&sc, NULL, &be));
    if (!be) return;
    const char *dir = fx_tmp("hdr");
    cap_loop_opts o;
    cap_loop_opts_default(&o);
    o.progress = 0;
    cap_loop_report rep;
    CHECK_OK(cap_loop_run(be, dir, &o, &rep));
    CHECK(rep.complete);
    CHECK(rep.max_passes >= 3);
    CHECK(rep.saturated_px == 0);
    gs_capture cap;
    CHECK_OK(gs_capture_read(dir, &cap));
    gs_delight *d = delight();
    double worst = 0;
    int max_h = 0;
    for (size_t l = 0; l < sc.n_lights; l++) {
        const cap_light *li = &sc.lights[l];
        const gs_bulb *b = gs_delight_find(d, li->bulb, 50, 3);
        double i_k[3 * 8];
        CHECK_OK(gs_brf_integrate(&b->brf, gs_phase_to_shift(li->phase_deg), 8, i_k));
        int cx = (int)floor(li->x_px + 0.5), cy = (int)floor(li->y_px + 0.5);
        for (int k = 0; k < 8; k++) {
            double got = 0, truth = 0;
            for (int band = 0; band < 3; band++) {
                for (int y = cy - 5; y <= cy + 5; y++)
                    for (int x = cx - 5; x <= cx + 5; x++) {
                        double v = gs_capture_value(&cap, k, y, x, band);
                        CHECK_MSG(isfinite(v), "light %s frame %d pixel (%d, %d) saturated", li->id, k, x, y);
                        got += v;
                        int h = cap.halvings[((size_t)k * 48 + (size_t)y) * 64 + (size_t)x];
                        if (h > max_h) max_h = h;
                    }
                truth += li->flux_e_per_cycle * b->chroma[band] * i_k[band * 8 + k] / 8 / 5.0;
            }
            double rel = fabs(got - truth) / truth;
            if (rel > worst) worst = rel;
            CHECK_MSG(rel < 0.02, "light %s frame %d: %.2f DN/cycle vs truth %.2f (%.2f %%)", li->id, k,
                      got, truth, 100 * rel);
        }
    }
    printf("    HDR: %d passes at most, pixels halved up to %d times, worst light error %.2f %%\n",
           rep.max_passes, max_h, 100 * worst);
    CHECK(max_h >= 2);
    gs_capture_release(&cap);
    gs_delight_free(d);
    cap_backend_free(be);
    cap_scene_release(&sc);
}

/* ------------------------------------------------------------ physics of the effects */

TEST(sim_effect_physics_matches_bulbs_md)
{
    /* extinction (Koschmieder + Angstrom 1.3, shared/BULBS.md): 0.82 over 1 km, 0.38 over 5 km,
     * blue/red 0.82 over 2 km at 20 km visibility */
    double beta = 3.912 / 20.0;
    CHECK_NEAR(exp(-beta * 1), 0.82, 0.005);
    CHECK_NEAR(exp(-beta * 5), 0.38, 0.005);
    CHECK_NEAR(exp(-beta * pow(450 / 550.0, -1.3) * 2) / exp(-beta * pow(650 / 550.0, -1.3) * 2), 0.82, 0.01);
    /* ... and the same numbers through the simulator's extinction stage */
    gs_delight *d = delight();
    char *text = scene_with(1u << CAP_FX_EXTINCTION);
    cap_scene sc;
    cap_sim *s = sim_of(text, "ext.json", d, &sc);
    if (s) {
        CHECK_NEAR(s->trans[0 * 3 + 1], exp(-beta * 3), 1e-12);          /* 3 km, 550 nm */
        CHECK_NEAR(s->trans[1 * 3 + 1], exp(-beta * 5), 1e-12);          /* 5 km */
        CHECK(s->trans[2] < s->trans[1] && s->trans[1] < s->trans[0]);   /* blue < green < red */
    }
    cap_sim_free(s);
    cap_scene_release(&sc);
    free(text);
    /* scintillation index (Andrews-Phillips, point source, Cn2 = 1e-14): 0.27-0.30 at 1 km,
     * 0.84 at 2 km, ~1.6 at 5 km; a 25 mm aperture cuts 1 km to ~58-61 % */
    cap_effects fx;
    memset(&fx, 0, sizeof fx);
    fx.scint.cn2 = 1e-14;
    fx.scint.wavelength_nm = 550;
    fx.scint.sigma2 = -1;
    double s1 = cap_scintillation_index(&fx, 0, 1000), s2 = cap_scintillation_index(&fx, 0, 2000),
           s5 = cap_scintillation_index(&fx, 0, 5000);
    fx.scint.aperture = 1;
    double a1 = cap_scintillation_index(&fx, 25, 1000);
    printf("    scintillation index: 1 km %.3f, 2 km %.3f, 5 km %.3f; 25 mm aperture at 1 km: %.0f %%\n",
           s1, s2, s5, 100 * a1 / s1);
    CHECK(s1 > 0.26 && s1 < 0.31);
    CHECK_NEAR(s2, 0.84, 0.03);
    CHECK(s5 > 1.4 && s5 < 1.8);
    CHECK(a1 / s1 > 0.55 && a1 / s1 < 0.65);
    /* random-walk frequency: the statistics of shared/data/README.md */
    cap_freq_config f;
    memset(&f, 0, sizeof f);
    f.model = CAP_FREQ_RANDOM_WALK;
    f.hz = 50;
    f.sigma_hz = 0.02;
    f.corr_time_s = 18.8;
    f.fast_sigma_hz = 0.002;
    f.fast_corr_time_s = 1.0;
    f.seed = 7;
    cap_ac *ac = NULL;
    CHECK_OK(cap_ac_new(&f, 50, &ac));
    long n = fx_sanitized() ? 60000 : 360000;   /* 10 / 60 minutes */
    double *t = malloc(sizeof *t * (size_t)n);
    for (long c = 0; c < n; c++) CHECK_OK(cap_ac_time(ac, c, &t[c]));
    gs_wander w;
    CHECK_OK(gs_frequency_wander(t, (size_t)n, 1.0, &w));
    printf("    random walk (%ld s): mean %.4f Hz, sigma %.1f mHz, 1-s steps %.2f mHz, corr 10 s %.2f, 60 s %.2f\n",
           (long)t[n - 1], w.mean_hz, 1e3 * w.sigma_hz, 1e3 * w.step_sigma_hz, w.corr_10s, w.corr_60s);
    CHECK(w.sigma_hz > 0.008 && w.sigma_hz < 0.035);
    CHECK(w.step_sigma_hz > 0.0015 && w.step_sigma_hz < 0.0035);
    CHECK(w.corr_10s > 0.7);
    free(t);
    cap_ac_free(ac);
    gs_delight_free(d);
}

/* Shot noise is Poisson at every mean: an ambient pedestal of 2 to 5000 electrons per pixel
 * (the cached-CDF inversion below 40, Hormann's PTRS above) has the mean of the same scene
 * rendered without noise and the Poisson variance (the inversion's table once stopped at 159
 * electrons: every brighter pixel read 159, with no variance). */
TEST(sim_shot_noise_is_poisson_at_every_level)
{
    gs_delight *d = delight();
    const double level_e[] = {2, 30, 300, 5000};
    enum { W = 200, H = 100 };
    double *dn = malloc(sizeof *dn * W * H);
    unsigned short *raw = malloc(sizeof *raw * W * H);
    for (size_t i = 0; i < sizeof level_e / sizeof *level_e; i++) {
        double mean_e[2] = {0, 0}, var_e = 0;
        for (int noisy = 0; noisy < 2; noisy++) {
            char text[2048];
            /* 40 cycles, K = 10: a frame exposes 4 nominal cycles */
            snprintf(text, sizeof text,
                     "{\"format\": \"gridsurvey-scene/1\", \"seed\": 3, \"grid\": {\"nominal_hz\": 50},\n"
                     " \"camera\": {\"width_px\": %d, \"height_px\": %d, \"sensor\": {\"bands\": 1, "
                     "\"full_well_e\": 100000, \"gain_e_per_dn\": 1, \"black_level_dn\": 10}},\n"
                     " \"acam\": {\"K\": 10, \"cycles\": 40},\n"
                     " \"lights\": [{\"bulb\": \"hps-150w\", \"x_px\": -500, \"y_px\": -500, \"distance_m\": 3000, "
                     "\"flux_e_per_cycle\": 1}],\n"
                     " \"effects\": {\"ambient\": {\"e_per_px_cycle\": %.17g}%s}}\n",
                     W, H, level_e[i] / 4.0, noisy ? ", \"shot_noise\": {}" : "");
            cap_scene sc;
            cap_sim *s = sim_of(text, "shot.json", d, &sc);
            if (s) {
                CHECK_OK(cap_sim_render(s, 0, 0, 0, NULL, raw, dn));
                double sum = 0, sum2 = 0;
                for (int p = 0; p < W * H; p++) {
                    double e = dn[p] - 10.0;
                    sum += e;
                    sum2 += e * e;
                }
                mean_e[noisy] = sum / (W * H);
                if (noisy) var_e = sum2 / (W * H) - mean_e[1] * mean_e[1];
            }
            cap_sim_free(s);
            cap_scene_release(&sc);
        }
        double mu = mean_e[0], n = W * H;
        printf("    ambient %.0f e: mean %.3f e (noiseless %.3f), variance %.3f\n", level_e[i], mean_e[1],
               mu, var_e);
        CHECK_NEAR(mu, level_e[i], 1e-9 * level_e[i]);
        CHECK_MSG(fabs(mean_e[1] - mu) < 5.0 * sqrt(mu / n), "ambient %.0f e: mean %.3f", mu, mean_e[1]);
        CHECK_MSG(fabs(var_e - mu) < 6.0 * sqrt((mu + 2.0 * mu * mu) / n), "ambient %.0f e: variance %.3f",
                  mu, var_e);
    }
    free(dn);
    free(raw);
    gs_delight_free(d);
}

/* ------------------------------------------------------------ determinism */

TEST(sim_same_seed_identical_files)
{
    char cmd[8192], out[4096], scene[1024];
    const char *tmp = test_tmpdir();
    /* a small scene with every random effect and HDR */
    snprintf(scene, sizeof scene, "%s/det.json", tmp);
    char *text = scene_with(((1u << CAP_FX_COUNT) - 1) & ~(1u << CAP_FX_FREE_RUNNING_DRIFT));
    FILE *f = fopen(scene, "w");
    fputs(text, f);
    fclose(f);
    free(text);
    snprintf(cmd, sizeof cmd,
             "%s simulate %s --out-dir %s/a --no-progress && %s simulate %s --out-dir %s/b --no-progress && "
             "diff -r %s/a %s/b && echo SAME",
             test_bin(), scene, tmp, test_bin(), scene, tmp, tmp, tmp);
    int rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 0 && strstr(out, "SAME"), "rc %d: %s", rc, out);
    snprintf(cmd, sizeof cmd,
             "%s simulate %s --out-dir %s/c --seed 99 --no-progress >/dev/null && "
             "cmp -s %s/a/frame_003.png %s/c/frame_003.png || echo DIFFERENT",
             test_bin(), scene, tmp, tmp, tmp);
    rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(strstr(out, "DIFFERENT"), "another seed gave the same frame: %s", out);
}

/* truth.json's resolvability (docs/formats.md): PSF sigma 1 px, so sigma_e = sqrt(1 + 1/12) and
 * lights closer than 2 sigma_e = 2.082 px are close. a-b (1.5 px, fluxes 2x) and b-c (1.80 px)
 * chain into one group of three although a-c are 2.92 px apart; e is 1.9 px from d and 20x
 * fainter: hidden (no group), d stays resolvable; f-g at 2.2 px are both resolvable. */
TEST(sim_truth_resolvability_groups_and_hidden)
{
    const char *text =
        "{\"format\": \"gridsurvey-scene/1\", \"seed\": 3,\n"
        " \"grid\": {\"nominal_hz\": 50},\n"
        " \"camera\": {\"width_px\": 64, \"height_px\": 24,\n"
        "   \"sensor\": {\"bands\": 1, \"bit_depth\": 12, \"full_well_e\": 20000, \"read_noise_e\": 3, \"gain_e_per_dn\": 5, \"black_level_dn\": 64}},\n"
        " \"acam\": {\"K\": 4, \"cycles\": 16, \"masks\": 64},\n"
        " \"lights\": [\n"
        "  {\"id\": \"a\", \"bulb\": \"hps-150w\", \"phase_deg\": 0, \"x_px\": 10, \"y_px\": 10, \"flux_e_per_cycle\": 1000},\n"
        "  {\"id\": \"b\", \"bulb\": \"hps-150w\", \"phase_deg\": 120, \"x_px\": 11.5, \"y_px\": 10, \"flux_e_per_cycle\": 500},\n"
        "  {\"id\": \"c\", \"bulb\": \"mh-250w\", \"phase_deg\": 0, \"x_px\": 12.5, \"y_px\": 11.5, \"flux_e_per_cycle\": 300},\n"
        "  {\"id\": \"d\", \"bulb\": \"hps-150w\", \"phase_deg\": 0, \"x_px\": 30, \"y_px\": 10, \"flux_e_per_cycle\": 1000},\n"
        "  {\"id\": \"e\", \"bulb\": \"hps-150w\", \"phase_deg\": 240, \"x_px\": 31.9, \"y_px\": 10, \"flux_e_per_cycle\": 50},\n"
        "  {\"id\": \"f\", \"bulb\": \"hps-150w\", \"phase_deg\": 0, \"x_px\": 50, \"y_px\": 10, \"flux_e_per_cycle\": 1000},\n"
        "  {\"id\": \"g\", \"bulb\": \"hps-150w\", \"phase_deg\": 240, \"x_px\": 52.2, \"y_px\": 10, \"flux_e_per_cycle\": 900},\n"
        "  {\"id\": \"out\", \"bulb\": \"hps-150w\", \"phase_deg\": 0, \"x_px\": -40, \"y_px\": 10, \"flux_e_per_cycle\": 900}\n"
        " ],\n"
        " \"effects\": {\"psf\": {\"sigma_px\": 1.0}}}\n";
    gs_delight *d = delight();
    cap_scene sc;
    cap_sim *s = sim_of(text, "resolve.json", d, &sc);
    const char *dir = fx_tmp("resolve");
    CHECK(mkdir(dir, 0755) == 0 || errno == EEXIST);
    if (s) CHECK_OK(cap_sim_write_truth(s, dir));
    json_error_t err;
    json_t *root = json_load_file(fx_path(dir, "truth.json"), 0, &err);
    CHECK(root != NULL);
    if (root) {
        json_t *rs = json_object_get(root, "resolvability");
        CHECK_NEAR(json_real_value(json_object_get(rs, "sigma_px")), sqrt(1 + 1 / 12.0), 1e-12);
        CHECK(json_integer_value(json_object_get(rs, "blend_groups")) == 1);
        /* resolvable, group (-1: null) of a..g; "out" has neither field */
        const int want_res[7] = {0, 0, 0, 1, 0, 1, 1}, want_grp[7] = {0, 0, 0, -1, -1, -1, -1};
        json_t *arr = json_object_get(root, "lights");
        for (size_t i = 0; i < 7; i++) {
            json_t *o = json_array_get(arr, i), *g = json_object_get(o, "blend_group");
            CHECK_MSG(json_is_true(json_object_get(o, "resolvable")) == want_res[i], "light %zu", i);
            CHECK_MSG(want_grp[i] < 0 ? json_is_null(g) : json_integer_value(g) == want_grp[i], "light %zu", i);
        }
        json_t *out = json_array_get(arr, 7);
        CHECK(!json_object_get(out, "resolvable") && !json_object_get(out, "blend_group"));
    }
    json_decref(root);
    cap_sim_free(s);
    cap_scene_release(&sc);
    gs_delight_free(d);
}

/* The known bias near full well (docs/capture.md), against the analytic truncated normal. Every
 * HDR pass acquires the whole frame again, its halvings decided by the passes before (draws
 * independent of its own), and a sample that saturates is stored as such: so a stored sample of
 * a pixel halved h times, at mean mu_k with noise sigma_k, a_k = (T - mu_k) / sigma_k below the
 * level T (raw < saturation: T = saturation - 0.5 before the ADC's rounding), is a Gaussian draw
 * truncated at T, of mean mu_k - sigma_k phi(a_k) / Phi(a_k). (Whether the loop stopped because
 * no pixel saturated or because its rounds ran out, the condition on sample k is its own.)
 * 12,288 lights, one per pixel (no PSF), an incandescent lamp's flux spread so that the brightest
 * sample lies 0.5..3.5 sigma below the level, and a tenth of them far below (no bias: the oracle's
 * own check). */
TEST(sim_hdr_bias_near_full_well_is_the_truncated_normal)
{
    enum { W = 128, H = 96, K = 8, C = 256, NB = 6 };
    const double gain = 5.0, read_e = 3.0, black = 64.0, full_well = 20000.0;
    gs_delight *d = delight();
    const gs_bulb *b = d ? gs_delight_find(d, "inc-a19-60w-120v", 50, 1) : NULL;
    size_t cap_len = 160 * (size_t)W * H + 4096, len = 0;
    char *text = malloc(cap_len);
    double *flux = malloc(sizeof *flux * W * H), i_k[K], imax = 0;
    CHECK(b && text && flux);
    if (!b || !text || !flux) {
        free(text);
        free(flux);
        gs_delight_free(d);
        return;
    }
    CHECK_OK(gs_brf_integrate(&b->brf, gs_phase_to_shift(0.0), K, i_k));
    for (int k = 0; k < K; k++) imax = i_k[k] > imax ? i_k[k] : imax;
    /* the level in electrons, about: black + full well / gain - 4 read sigmas, in DN */
    double level_e = full_well - 4.0 * read_e, r2 = read_e * read_e;
    len += (size_t)snprintf(text + len, cap_len - len,
        "{\"format\": \"gridsurvey-scene/1\", \"seed\": 23, \"grid\": {\"nominal_hz\": 50},\n"
        " \"camera\": {\"width_px\": %d, \"height_px\": %d, \"sensor\": {\"bands\": 1, \"bit_depth\": 12,"
        " \"full_well_e\": %g, \"read_noise_e\": %g, \"gain_e_per_dn\": %g, \"black_level_dn\": %g}},\n"
        " \"acam\": {\"K\": %d, \"cycles\": %d, \"masks\": 64, \"hdr\": {\"enabled\": true, \"max_saturated_px\": 0}},\n"
        " \"effects\": {\"shot_noise\": {}, \"saturation\": {}, \"read_noise\": {}, \"adc\": {}},\n"
        " \"lights\": [", W, H, full_well, read_e, gain, black, K, C);
    for (int p = 0; p < W * H; p++) {
        /* the brightest sample's electrons mu, a sigmas below the level: mu + a sqrt(mu + r^2) */
        double a = p % 10 == 9 ? 40.0 : 0.5 + 3.0 * (p * 0.6180339887 - floor(p * 0.6180339887));
        double mu = level_e + a * a / 2.0 - a * sqrt(a * a / 4.0 + level_e + r2);
        flux[p] = mu / (imax / K * C);
        len += (size_t)snprintf(text + len, cap_len - len,
                                "%s{\"id\": \"l%d\", \"bulb\": \"inc-a19-60w-120v\", \"phase_deg\": 0, \"x_px\": %d.0,"
                                " \"y_px\": %d.0, \"flux_e_per_cycle\": %.6f}", p ? ",\n" : "", p, p % W, p / W, flux[p]);
    }
    snprintf(text + len, cap_len - len, "]}\n");
    cap_scene sc;
    CHECK_OK(cap_scene_parse(text, "bias.json", ".", &sc));
    free(text);
    cap_backend *be = NULL;
    CHECK_OK(cap_backend_sim_new(&sc, NULL, &be));
    cap_loop_opts o;
    cap_loop_opts_default(&o);
    o.progress = 0;
    cap_loop_report rep;
    gs_capture cap;
    memset(&cap, 0, sizeof cap);
    if (be) CHECK_OK(cap_loop_run(be, fx_tmp("hdr_bias"), &o, &rep));
    if (be) CHECK_OK(gs_capture_read(fx_tmp("hdr_bias"), &cap));
    /* per bin of a_k (below -1 and -1..0, 0..1, 1..2, 2..3, 3..10, far): the errors' sum in the
     * stored pass's sigmas, measured and predicted */
    double got[NB] = {0}, want[NB] = {0};
    long n[NB] = {0}, halved = 0, saturated = 0;
    for (size_t q = 0; cap.raw && q < (size_t)K * W * H; q++) {
        int k = (int)(q / (W * H)), p = (int)(q % (W * H)), h = cap.halvings[q];
        double e = flux[p] * i_k[k] / K * C / ldexp(1.0, h), sg = sqrt(e + r2) / gain;
        double a = (cap.saturation_dn - 0.5 - black - e / gain) / sg;
        double v = gs_capture_value(&cap, k, p / W, p % W, 0);
        halved += h > 0;
        if (!isfinite(v)) {   /* saturated: not a sample */
            saturated++;
            continue;
        }
        int bin = a < 0.0 ? 0 : a < 3.0 ? 1 + (int)a : a < 10.0 ? 4 : 5;
        double Phi = 0.5 * erfc(-a / sqrt(2.0)), phi = exp(-0.5 * a * a) / sqrt(2.0 * M_PI);
        got[bin] += (v * C / ldexp(1.0, h) - e / gain) / sg;
        want[bin] += -phi / Phi;
        n[bin]++;
    }
    printf("    %d passes, %ld of %d samples halved, %ld saturated; mean error in sigmas by the sample's "
           "distance a below the level:\n", rep.max_passes, halved, K * W * H, saturated);
    static const char *const name[NB] = {"< 0", "0..1", "1..2", "2..3", "3..10", "far"};
    for (int i = 0; i < NB; i++) {
        if (!n[i]) continue;
        /* the truncated normal's variance is below 1: 1 / sqrt(n) bounds the standard error */
        double se = 1.0 / sqrt((double)n[i]), g = got[i] / (double)n[i], w = want[i] / (double)n[i];
        printf("    a %-6s %6ld samples: measured %+.4f +- %.4f, truncated normal %+.4f\n", name[i], n[i], g, se, w);
        CHECK_MSG(fabs(g - w) < 4.0 * se, "a %s: measured %+.4f, predicted %+.4f (se %.4f)", name[i], g, w, se);
    }
    CHECK_MSG(n[1] > 300 && n[2] > 2000 && n[5] > 4000, "bins too thin: %ld %ld %ld", n[1], n[2], n[5]);
    CHECK(n[1] && got[1] / (double)n[1] < -0.2);   /* the bias is there, measured */
    gs_capture_release(&cap);
    cap_backend_free(be);
    cap_scene_release(&sc);
    free(flux);
    gs_delight_free(d);
}


/* A pixel halved h times keeps the cycles of pairs j with j mod 2^h = 0 (Sec. 6): all of one
 * mains polarity, whose half periods on a real recording differ from the other's by 10-30 us.
 * On whu_001 and whu_002 (the frequency_wander effect alone, locked), two equal lights, one
 * halved 1 to 4 times: the halved per-cycle values C / 2^h stay within 0.3 % of the unhalved
 * mean in every window, for a smooth BRF (cfl-20w) and the deepest flicker (led-fil-4w-lin,
 * dark in 15 of 26 windows) alike (docs/capture.md, HDR). */
TEST(sim_halved_pixels_match_unhalved_on_real_mains)
{
    gs_delight *d = delight();
    CHECK(d != NULL);
    static const char *wavs[2] = {"data/mains/whu_001_ref.wav", "data/mains/whu_002_ref.wav"};
    static const char *bulbs[2] = {"cfl-20w", "led-fil-4w-lin"};
    enum { W = 8, K = 26, C = 1024 };
    for (int wi = 0; wi < (fx_sanitized() ? 1 : 2) && d; wi++)
        for (int bi = 0; bi < 2; bi++) {
            char text[4096];
            snprintf(text, sizeof text,
                     "{\"format\": \"gridsurvey-scene/1\", \"seed\": 3,\n"
                     " \"grid\": {\"nominal_hz\": 50, \"frequency\": {\"model\": \"trace\", \"wav\": \"%s\"}},\n"
                     " \"camera\": {\"width_px\": 8, \"height_px\": 8, \"sensor\": {\"bands\": 1}},\n"
                     " \"acam\": {\"K\": 26, \"cycles\": 1024, \"masks\": 64, \"hdr\": true},\n"
                     " \"lights\": [{\"bulb\": \"%s\", \"x_px\": 1, \"y_px\": 1, \"flux_e_per_cycle\": 1000},\n"
                     "  {\"bulb\": \"%s\", \"x_px\": 5, \"y_px\": 5, \"flux_e_per_cycle\": 1000}],\n"
                     " \"effects\": {\"frequency_wander\": {}}}\n",
                     test_shared_path(wavs[wi]), bulbs[bi], bulbs[bi]);
            cap_scene sc;
            cap_sim *s = sim_of(text, "mains.json", d, &sc);
            if (!s) {
                cap_scene_release(&sc);
                continue;
            }
            double dn[W * W];
            unsigned short raw[W * W];
            unsigned char halv[W * W];
            for (int h = 1; h <= 4; h++) {
                memset(halv, 0, sizeof halv);
                halv[5 * W + 5] = (unsigned char)h;
                double plain[K], halved[K], mean = 0, worst = 0;
                for (int k = 0; k < K; k++) {
                    CHECK_OK(cap_sim_render(s, k, 0, k, halv, raw, dn));
                    plain[k] = dn[1 * W + 1] / C;
                    halved[k] = dn[5 * W + 5] / ((double)C / (1 << h));
                    mean += plain[k] / K;
                }
                for (int k = 0; k < K; k++) worst = fmax(worst, fabs(halved[k] - plain[k]) / mean);
                printf("    %s %s h %d: largest |halved - unhalved| %.3f %% of the mean\n", wavs[wi] + 11,
                       bulbs[bi], h, 100 * worst);
                CHECK_MSG(worst < 3e-3, "%s %s h %d: %.3f %%", wavs[wi], bulbs[bi], h, 100 * worst);
            }
            cap_sim_free(s);
            cap_scene_release(&sc);
        }
    gs_delight_free(d);
}

/* truth.json was written after the acquisition loop released the directory's lock: a writer
 * that took the lock meanwhile removed the truth's temporary file as a killed run's, and the
 * rename failed. It is now written under the shared lock, which keeps writers out: while a
 * writer holds the directory (here this process, through an open file description of its own)
 * the write fails in one line naming it and leaves nothing; once free, it writes truth.json. */
TEST(sim_truth_written_under_the_directory_lock)
{
    gs_delight *d = delight();
    CHECK(d != NULL);
    cap_scene sc;
    cap_sim *s = sim_of(exact_scene, "exact.json", d, &sc);
    const char *dir = fx_tmp("truth-lock");
    CHECK(mkdir(dir, 0777) == 0);
    int fd = open(dir, O_RDONLY | O_DIRECTORY);
    CHECK(fd >= 0 && flock(fd, LOCK_EX) == 0);
    if (s) {
        CHECK(cap_sim_write_truth(s, dir) == GS_EIO);
        CHECK_MSG(strstr(gs_detail(), dir) && strstr(gs_detail(), "another process"), "%s", gs_detail());
        char cmd[2048], out[256];
        snprintf(cmd, sizeof cmd, "ls -A %s | wc -l", dir);
        CHECK(test_run(cmd, out, sizeof out) == 0 && !strcmp(out, "0\n"));
        close(fd);
        CHECK_OK(cap_sim_write_truth(s, dir));
        char path[1100];
        snprintf(path, sizeof path, "%s/truth.json", dir);
        CHECK(fx_exists(path));
    }
    cap_sim_free(s);
    cap_scene_release(&sc);
    gs_delight_free(d);
}

/* A pixel light without distance_m (0, unknown) is skipped by scintillation (docs/scene.md),
 * even when the scene gives the intensity variance: its frames are those of the scene without
 * scintillation, bit for bit, and truth.json gives it no scintillation; a light with a distance
 * beside it scintillates. (It used to get the given variance, with a cycle-to-cycle correlation
 * from a made-up 1 m Fresnel scale.) */
TEST(sim_scintillation_skips_a_light_without_distance)
{
    static const char *fmt =
        "{\"format\": \"gridsurvey-scene/1\", \"seed\": 9, \"grid\": {\"nominal_hz\": 50},\n"
        " \"camera\": {\"width_px\": 8, \"height_px\": 4, \"sensor\": {\"bands\": 1}},\n"
        " \"acam\": {\"K\": 4, \"cycles\": 16},\n"
        " \"lights\": [{\"bulb\": \"hps-150w\", \"x_px\": 1, \"y_px\": 1, \"flux_e_per_cycle\": 900},\n"
        "            {\"bulb\": \"hps-150w\", \"x_px\": 5, \"y_px\": 2, \"distance_m\": 1000, \"flux_e_per_cycle\": 900}],\n"
        " \"effects\": {%s}}\n";
    const char *fx[2] = {"", "\"scintillation\": {\"intensity_variance\": 0.5}"};
    gs_delight *d = delight();
    double dn[2][4][8 * 4];
    cap_sim *s[2] = {NULL, NULL};
    cap_scene sc[2];
    for (int i = 0; i < 2; i++) {
        char text[2048];
        snprintf(text, sizeof text, fmt, fx[i]);
        s[i] = sim_of(text, "scint.json", d, &sc[i]);
        for (int k = 0; s[i] && k < 4; k++) CHECK_OK(cap_sim_render(s[i], k, 0, k, NULL, NULL, dn[i][k]));
    }
    if (s[0] && s[1]) {
        int same = 1, moved = 0;
        for (int k = 0; k < 4; k++) {
            same &= dn[1][k][1 * 8 + 1] == dn[0][k][1 * 8 + 1];
            moved += fabs(dn[1][k][2 * 8 + 5] / dn[0][k][2 * 8 + 5] - 1) > 1e-6;
        }
        CHECK_MSG(same, "the light without a distance scintillated: frame 0 %g, without the effect %g",
                  dn[1][0][1 * 8 + 1], dn[0][0][1 * 8 + 1]);
        CHECK(moved == 4);
        CHECK(s[1]->scint_s2[0] == 0 && s[1]->scint_s2[1] > 0);
    }
    for (int i = 0; i < 2; i++) {
        cap_sim_free(s[i]);
        cap_scene_release(&sc[i]);
    }
    gs_delight_free(d);
}
