/* test_capture_acam.c - the ACam model (capture/acam.c, aclock.c): hardware limits rejected
 * with clear errors, the mask matrix and its HDR halvings, and AC locking against a real mains
 * recording (paper Fig. 9): free running blurs the windows over 1500 cycles, locking does not. */
#include "tests/fixtures.h"
#include "tests/test.h"
#include "capture/sim.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

TEST(acam_limits_rejected_with_clear_errors)
{
    cap_acam_config c;
    cap_acam_config_default(&c);
    CHECK_OK(cap_acam_check(&c));   /* K = 26 at 50 Hz: the limit itself is fine */
    c.K = 27;
    CHECK(cap_acam_check(&c) == GS_ELIMIT);
    CHECK_MSG(fx_contains(gs_detail(), "K = 27") && fx_contains(gs_detail(), "26") &&
              fx_contains(gs_detail(), "50 Hz"), "%s", gs_detail());
    c.grid_hz = 60;
    c.K = 22;
    CHECK_OK(cap_acam_check(&c));
    c.K = 23;
    CHECK(cap_acam_check(&c) == GS_ELIMIT);
    CHECK_MSG(fx_contains(gs_detail(), "K = 23") && fx_contains(gs_detail(), "22") &&
              fx_contains(gs_detail(), "60 Hz"), "%s", gs_detail());
    cap_acam_config_default(&c);
    c.masks = 96;
    CHECK_OK(cap_acam_check(&c));
    c.masks = 98;
    CHECK(cap_acam_check(&c) == GS_ELIMIT);
    CHECK_MSG(fx_contains(gs_detail(), "M = 98") && fx_contains(gs_detail(), "96"), "%s", gs_detail());
    c.masks = 7;
    CHECK(cap_acam_check(&c) == GS_EINVAL);
    /* masks held for Delta/K: too short for the DMD */
    cap_acam_config_default(&c);
    c.dmd_min_hold_us = 400;    /* K = 26 at 50 Hz holds 384.6 us */
    CHECK(cap_acam_check(&c) == GS_ELIMIT);
    CHECK_MSG(fx_contains(gs_detail(), "384.6 us") && fx_contains(gs_detail(), "400 us"), "%s", gs_detail());
    cap_acam_config_default(&c);
    c.max_hz = 52.5;            /* a grid this fast shortens the windows below 370 us */
    CHECK(cap_acam_check(&c) == GS_ELIMIT);
    /* HDR needs exact halvings */
    cap_acam_config_default(&c);
    c.hdr = 1;
    CHECK(cap_acam_check(&c) == GS_EINVAL);   /* M = 2 cannot be halved */
    c.masks = 64;
    c.cycles = 500;
    CHECK(cap_acam_check(&c) == GS_EINVAL);   /* 500 is not a multiple of 32 */
    CHECK_MSG(fx_contains(gs_detail(), "C = 500"), "%s", gs_detail());
    c.cycles = 512;
    CHECK_OK(cap_acam_check(&c));
    c.hdr_max_rounds = 6;
    CHECK(cap_acam_check(&c) == GS_ELIMIT);

    /* the same limits through a scene file name its file, line and field */
    static const struct {
        const char *acam, *grid, *field;
        gs_status st;
    } cases[] = {
        {"{\"K\": 27, \"cycles\": 100}", "50", "acam.K", GS_ELIMIT},
        {"{\"K\": 23, \"cycles\": 100}", "60", "acam.K", GS_ELIMIT},
        {"{\"K\": 20, \"cycles\": 100, \"masks\": 98}", "50", "acam.masks", GS_ELIMIT},
        {"{\"K\": 26, \"cycles\": 100, \"dmd_min_hold_us\": 390}", "50", "acam.dmd_min_hold_us", GS_ELIMIT},
    };
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        char text[1024];
        snprintf(text, sizeof text,
                 "{\"format\": \"gridsurvey-scene/1\",\n \"grid\": {\"nominal_hz\": %s},\n"
                 " \"camera\": {\"width_px\": 8, \"height_px\": 8},\n \"acam\": %s,\n \"lights\": []}\n",
                 cases[i].grid, cases[i].acam);
        cap_scene sc;
        gs_status st = cap_scene_parse(text, "limits.json", ".", &sc);
        char want[64];
        snprintf(want, sizeof want, "limits.json:4: field %s:", cases[i].field);
        CHECK_MSG(st == cases[i].st && fx_contains(gs_detail(), want), "case %zu: %s (wanted '%s')", i,
                  gs_detail(), want);
        cap_scene_release(&sc);
    }
    /* the hardware backend refuses them before touching any device */
    cap_hw_config hw;
    cap_hw_config_default(&hw);
    hw.K = 27;
    cap_backend *be = NULL;
    CHECK(cap_backend_hardware_new(&hw, &be) == GS_ELIMIT && be == NULL);
}

TEST(acam_mask_matrix_and_halvings)
{
    CHECK(cap_acam_max_halvings(2) == 0);
    CHECK(cap_acam_max_halvings(64) == 5);    /* floor(log2(32)) */
    CHECK(cap_acam_max_halvings(96) == 4);    /* 48 -> 24 -> 12 -> 6 -> 3: exact halvings */
    CHECK(cap_acam_max_halvings(4) == 1);
    int M = 64, N = 32;
    for (int h = 0; h <= 5; h++) {
        int ones = 0;
        for (int col = 0; col < M; col++) {
            int e = cap_mask_element(M, h, col);
            if (col % 2) CHECK(e == 0);   /* M = [m1 0 m2 0 ...] */
            ones += e;
        }
        CHECK(ones == N >> h);            /* each round zeroes half the non-zero elements */
        CHECK(cap_exposed_cycles(M, 0, 512, h) == 512 >> h);
        /* rows are nested: a pixel halved h times integrates a subset of h - 1's cycles */
        long both = 0;
        for (long c = 0; c < 512; c++) {
            int lev = cap_cycle_level(M, 5, c);
            if (lev >= h) both++;
            if (h && lev >= h) CHECK(cap_mask_element(M, h - 1, 2 * (int)(c % N)));
            CHECK(cap_mask_element(M, lev, 2 * (int)(c % N)));
        }
        CHECK(both == 512 >> h);
    }
    /* one HDR round */
    unsigned short raw[6] = {100, 4095, 4095, 10, 4095, 20};   /* 3 px x 2 bands */
    unsigned char h[3] = {0, 5, 2};
    size_t sat, halved;
    CHECK_OK(cap_hdr_update(raw, 3, 1, 2, 4095, 5, h, &sat, &halved));
    /* all three saturate in some band; the one already at the limit stays */
    CHECK(sat == 3 && halved == 2 && h[0] == 1 && h[1] == 5 && h[2] == 3);
    /* against the definition (a pixel saturates when a band's raw >= saturation_dn), pixel by
     * pixel: odd sizes, 1 to 4 bands, thresholds between integers, 0, above 65535, NaN */
    const double thr[] = {4094.5, 4095, 1, 0, -3, 65535, 65535.5, 70000, NAN};
    uint64_t x = 12345;
    for (int t = 0; t < 9; t++)
        for (int bands = 1; bands <= 4; bands++) {
            int W = 37 + bands, H = 5;
            size_t n = (size_t)W * H * (size_t)bands;
            unsigned short *r = malloc(n * sizeof *r);
            unsigned char *hv = malloc((size_t)W * H), *ref = malloc((size_t)W * H);
            for (size_t i = 0; i < n; i++) {
                uint64_t u = gs_splitmix64(&x);
                r[i] = u % 50 == 0 ? (unsigned short)(4094 + u % 3) : u % 97 == 0 ? 65535 : (unsigned short)(u % 4000);
            }
            size_t want_sat = 0, want_halved = 0;
            for (int p = 0; p < W * H; p++) {
                hv[p] = ref[p] = (unsigned char)(p % 3);
                int any = 0;
                for (int b = 0; b < bands; b++) any |= r[(size_t)p * (size_t)bands + (size_t)b] >= thr[t];
                want_sat += (size_t)any;
                if (any && ref[p] < 2) {
                    ref[p]++;
                    want_halved++;
                }
            }
            CHECK_OK(cap_hdr_update(r, W, H, bands, thr[t], 2, hv, &sat, &halved));
            CHECK_MSG(sat == want_sat && halved == want_halved && !memcmp(hv, ref, (size_t)W * H),
                      "threshold %g, %d bands: %zu/%zu saturated, %zu/%zu halved", thr[t], bands, sat,
                      want_sat, halved, want_halved);
            free(r);
            free(hv);
            free(ref);
        }
}

/* ------------------------------------------------------------ Fig. 9: lock vs free running */

typedef struct {
    double spread, range, rms, peak;   /* peak: brightest frame / mean */
} lock_result;

/* All K windows (acquired one after the other, as the loop does) of an LED with a 100 %
 * flicker, against its exact Eq. 5 template. */
static void run_lock(cap_ac *ac, const gs_brf *b, int K, long C, cap_lock_mode mode,
                     lock_result *out)
{
    double *i_k = malloc(sizeof *i_k * (size_t)K), *v = malloc(sizeof *v * (size_t)K);
    CHECK_OK(gs_brf_integrate(b, 0.0, K, i_k));
    double spread2 = 0, range = 0, mean = 0;
    for (int k = 0; k < K; k++) {
        cap_window_config w;
        memset(&w, 0, sizeof w);
        w.K = K;
        w.k = k;
        w.cycles = C;
        w.first_cycle = 64 + (long)k * (C + 10);
        w.mode = mode;
        cap_windows win;
        CHECK_OK(cap_ac_windows(ac, &w, &win));
        cap_blur bl;
        CHECK_OK(cap_windows_blur(&win, &bl));
        spread2 += bl.spread_cycles * bl.spread_cycles;
        if (bl.range_cycles > range) range = bl.range_cycles;
        CHECK_OK(cap_brf_expose(b, 0.0, &win, &v[k]));
        cap_windows_release(&win);
        mean += i_k[k] / K;
    }
    double err2 = 0, hi = -1e300;
    for (int k = 0; k < K; k++) {
        err2 += (v[k] - i_k[k]) * (v[k] - i_k[k]);
        if (v[k] > hi) hi = v[k];
    }
    out->spread = sqrt(spread2 / K);
    out->range = range;
    out->rms = sqrt(err2 / K) / mean;
    out->peak = hi / mean;
    free(i_k);
    free(v);
}

TEST(acam_lock_vs_free_running_real_mains_fig9)
{
    cap_ac *ac = fx_mains_ac("data/mains/whu_001_ref.wav", 50);
    if (!ac) return;
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, GS_BRF_N_DEFAULT));
    const gs_bulb *led = gs_delight_find(d, "led-a19-9w-lin2", 50, 1);   /* like LED2 */
    CHECK(led != NULL);
    int K = 26;
    long C = 1500;
    lock_result L, F;
    run_lock(ac, &led->brf, K, C, CAP_LOCKED, &L);
    run_lock(ac, &led->brf, K, C, CAP_FREE_RUNNING, &F);
    double i_k[26], hi = -1e300, t0, t1;
    CHECK_OK(gs_brf_integrate(&led->brf, 0.0, K, i_k));
    for (int k = 0; k < K; k++)
        if (i_k[k] > hi) hi = i_k[k];
    CHECK_OK(cap_ac_time(ac, 64, &t0));
    CHECK_OK(cap_ac_time(ac, 64 + 26 * 1510, &t1));
    printf("    whu_001 mains (mean %.4f Hz over the capture), K = %d, C = %ld cycles, LED with a "
           "two-tap linear driver:\n", 26 * 1510 / (2 * (t1 - t0)), K, C);
    printf("      locked:       window spread %.2e cycles (largest range %.2e), template rms error %.2e, peak/mean %.3f\n",
           L.spread, L.range, L.rms, L.peak);
    printf("      free running: window spread %.2e cycles (largest range %.2e), template rms error %.2e, peak/mean %.3f\n",
           F.spread, F.range, F.rms, F.peak);
    printf("      Eq. 5 (no blur): peak/mean %.3f\n", hi);
    /* locked: no temporal blur (the windows move by the cycle-to-cycle change of the period) */
    CHECK(L.spread < 1e-3);
    CHECK(L.rms < 2e-3);
    CHECK_NEAR(L.peak, hi, 0.01);
    /* free running: the windows drift by the grid's frequency offset over 1500 cycles */
    CHECK(F.range > 0.05);
    CHECK(F.rms > 0.05);
    CHECK(F.spread > 0.02);   /* the temporal blur: windows spread over a good part of a cycle */
    CHECK(F.rms > 20 * L.rms);

    /* the same through the simulator: a scene with the trace, frequency_wander and one light */
    char text[2048];
    for (int locked = 1; locked >= 0; locked--) {
        snprintf(text, sizeof text,
                 "{\"format\": \"gridsurvey-scene/1\",\n"
                 " \"grid\": {\"nominal_hz\": 50, \"frequency\": {\"model\": \"trace\", \"wav\": \"%s\"}},\n"
                 " \"camera\": {\"width_px\": 4, \"height_px\": 4, \"sensor\": {\"bands\": 1}},\n"
                 " \"acam\": {\"K\": 26, \"cycles\": 1500, \"locked\": %s},\n"
                 " \"lights\": [{\"bulb\": \"led-a19-9w-lin2\", \"x_px\": 1, \"y_px\": 1, \"flux_e_per_cycle\": 26000}],\n"
                 " \"effects\": {\"frequency_wander\": {}}}\n",
                 test_shared_path("data/mains/whu_001_ref.wav"), locked ? "true" : "false");
        cap_scene sc;
        CHECK_OK(cap_scene_parse(text, "fig9.json", ".", &sc));
        cap_sim *s = NULL;
        CHECK_OK(cap_sim_new(&sc, d, &s));
        if (!s) continue;
        double dn[16], err2 = 0, mean = 0;
        for (int k = 0; k < K; k++) {
            CHECK_OK(cap_sim_render(s, k, 0, k, NULL, NULL, dn));
            double value = dn[1 * 4 + 1] * 5.0 / 1500;   /* DN -> e per cycle (gain 5) */
            double exact = 26000 * i_k[k] / K;
            err2 += (value - exact) * (value - exact);
            mean += exact / K;
        }
        double rms = sqrt(err2 / K) / mean;
        printf("      simulator, %s: rms error of the 26 frames vs Eq. 5 %.2e\n",
               locked ? "locked" : "free running", rms);
        if (locked) CHECK(rms < 2e-3);
        else CHECK(rms > 0.05);
        cap_sim_free(s);
        cap_scene_release(&sc);
    }
    gs_delight_free(d);
    cap_ac_free(ac);
}

/* The antiderivative tables used for windows at any position agree with the exact Eq. 5
 * integrals (gs_brf_integrate) for every DELIGHT bulb, band and window. */
TEST(acam_brf_table_matches_exact_eq5)
{
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, GS_BRF_N_DEFAULT));
    double worst = 0;
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *b = gs_delight_get(d, i);
        if (b->grid_hz != 50 || b->brf.bands != 3) continue;
        cap_brf_table t;
        CHECK_OK(cap_brf_table_init(&t, &b->brf, 4096));
        double shift = 0.37 + 0.01 * (double)i, i_k[3 * 26];
        CHECK_OK(gs_brf_integrate(&b->brf, shift, 26, i_k));
        for (int band = 0; band < 3; band++)
            for (int k = 0; k < 26; k++) {
                double v = cap_brf_table_integral(&t, band, shift, 5.0 + k / 26.0, 5.0 + (k + 1) / 26.0) * 26;
                double err = fabs(v - i_k[band * 26 + k]);
                if (err > worst) worst = err;
            }
        cap_brf_table_release(&t);
    }
    printf("    BRF tables vs Eq. 5 (K = 26, every 50 Hz RGB bulb): worst absolute error %.2e (window means ~1)\n", worst);
    CHECK(worst < 1e-6);
    gs_delight_free(d);
}
