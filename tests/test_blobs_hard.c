/* test_blobs_hard.c - rec_blobs_extract on hard cases (tests/blobs_fixture.h): area limits,
 * lights at the image edge, saturation in some frames, HDR halving, touching lights with
 * different and equal signals (deblending), NaN / Inf / negative input, lights near the
 * threshold, empty scenes and degenerate image sizes. */
#include "recognize/internal.h"
#include "tests/blobs_fixture.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Two lights 4.5 px apart (PSF sigma 1.3: their footprints merge into one component). */
static void touching_pair(blobfx_light *l, double phase2, double depth2)
{
    memset(l, 0, 2 * sizeof *l);
    l[0] = (blobfx_light){30.2, 24.4, 1.3, 20, 0.6, 0.0, {0.4, 0.35, 0.25}};
    l[1] = (blobfx_light){34.6, 25.3, 1.3, 14, depth2, phase2, {0.4, 0.35, 0.25}};
}

/* Cosine similarity of a catalog light's band-summed signal with light l's temporal signal
 * (both mean-removed). */
static double similarity(const rec_catalog *cat, size_t j, const blobfx_light *l)
{
    double dot = 0, na = 0, nb = 0, ma = 0, mb = 0, a[64], b[64];
    int K = cat->K;
    for (int k = 0; k < K; k++) {
        a[k] = 0;
        for (int band = 0; band < cat->bands; band++) a[k] += cat->signal[(j * cat->bands + band) * K + k];
        b[k] = 1 + l->depth * cos(2 * M_PI * ((double)k / K - l->phase));
        ma += a[k] / K;
        mb += b[k] / K;
    }
    for (int k = 0; k < K; k++) {
        dot += (a[k] - ma) * (b[k] - mb);
        na += (a[k] - ma) * (a[k] - ma);
        nb += (b[k] - mb) * (b[k] - mb);
    }
    return dot / sqrt(na * nb);
}

TEST(blobs_area_limits)
{
    blobfx_light l[3];
    memset(l, 0, sizeof l);
    l[0] = (blobfx_light){20.2, 20.7, 0.4, 2, 0, 0, {0}};   /* a few pixels */
    l[1] = (blobfx_light){60.5, 20.3, 1.3, 20, 0, 0, {0}};  /* tens of pixels */
    l[2] = (blobfx_light){40.1, 60.4, 4.0, 400, 0, 0, {0}}; /* hundreds */
    blobfx_scene sc = blobfx_base_scene(96, 96, l, 3, 5);
    sc.bg0 = 0.3;
    gs_capture cap;
    blobfx_render(&sc, &cap);
    rec_blob_opts o;
    rec_blob_opts_default(&o);
    o.background_px = 48;
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 3);
    int area[3] = {0};
    for (int i = 0; i < 3; i++) {
        int j = blobfx_find_light(&cat, l[i].x, l[i].y, 1);
        CHECK(j >= 0);
        if (j >= 0) area[i] = cat.area_px[j];
    }
    printf("    areas %d %d %d\n", area[0], area[1], area[2]);
    CHECK(area[0] < area[1] && area[1] < area[2]);
    rec_catalog_release(&cat);
    o.min_area_px = area[0] + 1;
    o.max_area_px = area[2] - 1;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 1 && blobfx_find_light(&cat, l[1].x, l[1].y, 1) == 0);
    for (size_t i = 0; i < cat.count; i++)
        CHECK(cat.area_px[i] >= o.min_area_px && cat.area_px[i] <= o.max_area_px);
    rec_catalog_release(&cat);
    o.min_area_px = area[2];
    o.max_area_px = area[2];
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 1 && cat.count && cat.area_px[0] == area[2]);
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
}

TEST(blobs_edge_touching)
{
    blobfx_light l[3];
    memset(l, 0, sizeof l);
    l[0] = (blobfx_light){0.3, 30.2, 1.2, 10, 0.3, 0, {0}};   /* half outside the left border */
    l[1] = (blobfx_light){62.8, 47.6, 1.2, 10, 0.3, 0, {0}};  /* in the bottom-right corner */
    l[2] = (blobfx_light){30.4, 20.6, 1.2, 10, 0.3, 0, {0}};  /* inside */
    blobfx_scene sc = blobfx_base_scene(64, 48, l, 3, 9);
    gs_capture cap;
    blobfx_render(&sc, &cap);
    rec_blob_opts o;
    rec_blob_opts_default(&o);
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 3);
    for (int i = 0; i < 3; i++) {
        int j = blobfx_find_light(&cat, l[i].x, l[i].y, 1.5);
        CHECK_MSG(j >= 0, "light %d not found", i);
        if (j >= 0) CHECK(((cat.flags[j] & REC_BLOB_EDGE) != 0) == (i < 2));
    }
    CHECK(blobfx_catalog_finite(&cat));
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
}

TEST(blobs_saturated_some_frames)
{
    /* a bright light whose core saturates only near the top of its flicker */
    blobfx_light l[2];
    memset(l, 0, sizeof l);
    l[0] = (blobfx_light){30.3, 25.6, 1.5, 200, 0.6, 0.25, {0}};
    l[1] = (blobfx_light){12.2, 10.7, 1.2, 3, 0.3, 0.5, {0}};
    blobfx_scene sc = blobfx_base_scene(64, 48, l, 2, 13);
    sc.sat = 3000;
    gs_capture cap;
    blobfx_render(&sc, &cap);
    /* which frames saturate: not all of them (the test is about "some frames") */
    int sat_frames = 0;
    size_t N = 64 * 48;
    for (int k = 0; k < sc.K; k++) {
        int any = 0;
        for (size_t p = 0; p < N * 3; p++) any |= cap.raw[(size_t)k * N * 3 + p] >= 3000;
        sat_frames += any;
    }
    CHECK_MSG(sat_frames > 0 && sat_frames < sc.K, "%d of %d frames saturate", sat_frames, sc.K);
    rec_blob_opts o = blobfx_opts_labels();
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 2);
    int j = blobfx_find_light(&cat, l[0].x, l[0].y, 1), j1 = blobfx_find_light(&cat, l[1].x, l[1].y, 1);
    CHECK(j >= 0 && j1 >= 0);
    if (j < 0 || j1 < 0) goto out;
    CHECK(cat.flags[j] & REC_BLOB_SATURATED);
    CHECK(!(cat.flags[j1] & REC_BLOB_SATURATED) && cat.saturated_px[j1] == 0);
    int nsat = 0;
    for (size_t p = 0; p < N; p++) nsat += cat.labels[p] == j && blobfx_saturated(&cap, p);
    CHECK(nsat > 0 && cat.saturated_px[j] == nsat);
    CHECK(cat.peak_dn[j] >= 3000);
    /* the sums are those of the pixels unsaturated in every frame, in every frame: both in
     * frames that saturate and in frames that do not */
    for (int k = 0; k < sc.K; k++)
        for (int b = 0; b < 3; b++) {
            size_t q = ((size_t)j * 3 + b) * sc.K + k;
            double t = blobfx_truth_sum(&sc, &cap, &cat, (size_t)j, k, b);
            CHECK_MSG(fabs(cat.signal[q] - t) < 5 * cat.sigma[q], "k %d band %d: %g vs %g (sigma %g)",
                      k, b, cat.signal[q], t, cat.sigma[q]);
            /* ... and not those of all the aperture's pixels */
            double all = 0;
            for (size_t p = 0; p < N; p++)
                if (cat.labels[p] == j) all += blobfx_lights_at(&sc, k, b, (int)(p % 64), (int)(p / 64));
            CHECK(all - t > 20 * cat.sigma[q]);
        }
out:
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
}

/* The ACam's HDR loop halves the exposure of pixels that saturate (paper Sec. 6): the same scene
 * without HDR saturates, with the core halved twice (4x fewer cycles) in the frames that would
 * saturate and once in the others it does not; per cycle, both give the same signal. */
TEST(blobs_hdr_halving)
{
    blobfx_light l[1];
    memset(l, 0, sizeof l);
    l[0] = (blobfx_light){30.3, 25.6, 1.5, 200, 0.6, 0.25, {0.4, 0.35, 0.25}};
    blobfx_scene sc = blobfx_base_scene(64, 48, l, 1, 17);
    sc.sat = 3000;
    gs_capture plain, hdr;
    blobfx_render(&sc, &plain);
    static unsigned char halv[8 * 64 * 48];
    size_t N = 64 * 48;
    for (int k = 0; k < 8; k++)
        for (size_t p = 0; p < N; p++) {
            int x = (int)(p % 64), y = (int)(p / 64);
            if (abs(x - 30) <= 3 && abs(y - 26) <= 3) halv[k * N + p] = (unsigned char)(k < 4 ? 2 : 1);
        }
    sc.halvings = halv;
    sc.seed = 18;
    blobfx_render(&sc, &hdr);
    rec_blob_opts o = blobfx_opts_labels();
    rec_catalog a, b;
    CHECK_OK(rec_blobs_extract(&plain, &o, &a));
    CHECK_OK(rec_blobs_extract(&hdr, &o, &b));
    CHECK(a.count == 1 && b.count == 1);
    if (a.count != 1 || b.count != 1) goto out;
    CHECK((a.flags[0] & REC_BLOB_SATURATED) && !(a.flags[0] & REC_BLOB_HDR));
    CHECK(!(b.flags[0] & REC_BLOB_SATURATED) && (b.flags[0] & REC_BLOB_HDR));
    /* HDR: the full light, per cycle, matches the truth (which has no halving in it) */
    for (int k = 0; k < 8; k++)
        for (int band = 0; band < 3; band++) {
            size_t q = (size_t)band * 8 + k;
            double t = blobfx_truth_sum(&sc, &hdr, &b, 0, k, band);
            CHECK_MSG(fabs(b.signal[q] - t) < 5 * b.sigma[q], "k %d band %d: %g vs %g (sigma %g)",
                      k, band, b.signal[q], t, b.sigma[q]);
            CHECK(b.signal[q] > a.signal[q]); /* the saturated core is back */
        }
    /* per cycle, the halved pixels agree with the same pixels unhalved where those did not
     * saturate: the light's normalised signals agree */
    double ma = 0, mb = 0;
    for (int q = 0; q < 24; q++) {
        ma += a.signal[q] / 8;
        mb += b.signal[q] / 8;
    }
    for (int q = 0; q < 24; q++) {
        double ua = a.signal[q] / ma, ub = b.signal[q] / mb;
        double su = hypot(a.sigma[q] / ma, b.sigma[q] / mb);
        CHECK_MSG(fabs(ua - ub) < 5 * su, "value %d: %g vs %g (sigma %g)", q, ua, ub, su);
    }
out:
    rec_catalog_release(&a);
    rec_catalog_release(&b);
    gs_capture_release(&plain);
    gs_capture_release(&hdr);
}

TEST(blobs_two_touching_different_phase)
{
    blobfx_light l[2];
    touching_pair(l, 1.0 / 3, 0.6); /* the second light 120 deg later (shift 1/3 cycle) */
    blobfx_scene sc = blobfx_base_scene(64, 48, l, 2, 31);
    sc.K = 12;
    gs_capture cap;
    blobfx_render(&sc, &cap);
    rec_blob_opts o = blobfx_opts_labels();
    rec_catalog cat;
    /* without deblending it is one blob: the test below is about the split */
    o.deblend_sigma = INFINITY;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 1);
    rec_catalog_release(&cat);
    o.deblend_sigma = 5;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 2);
    for (int i = 0; i < 2 && cat.count == 2; i++) {
        int j = blobfx_find_light(&cat, l[i].x, l[i].y, 1.0);
        CHECK_MSG(j >= 0, "light %d not found", i);
        if (j < 0) continue;
        CHECK(cat.flags[j] & REC_BLOB_DEBLENDED);
        /* the right signal: its own light's, not the neighbour's */
        double own = similarity(&cat, (size_t)j, &l[i]), other = similarity(&cat, (size_t)j, &l[1 - i]);
        CHECK_MSG(own > 0.97 && other < 0.2, "light %d: similarity %g to its own, %g to the other",
                  i, own, other);
        /* and the sums are the truth over its aperture (crosstalk included) */
        for (int k = 0; k < sc.K; k++)
            for (int b = 0; b < 3; b++) {
                size_t q = ((size_t)j * 3 + b) * sc.K + k;
                double t = blobfx_truth_sum(&sc, &cap, &cat, (size_t)j, k, b);
                CHECK_MSG(fabs(cat.signal[q] - t) < 5 * cat.sigma[q], "light %d k %d band %d: %g vs %g",
                          i, k, b, cat.signal[q], t);
            }
    }
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
}

TEST(blobs_two_touching_same_signal)
{
    /* same bulb, same phase, 0.7x the flux, 4.5 px (3.5 PSF sigma) apart: one signal, so only
     * space tells them apart (blobs_fit.c, spatial_split): two lights, each with that signal,
     * at their own positions, with their own fluxes */
    blobfx_light l[2];
    touching_pair(l, 0.0, 0.6);
    blobfx_scene sc = blobfx_base_scene(64, 48, l, 2, 37);
    sc.K = 12;
    gs_capture cap;
    blobfx_render(&sc, &cap);
    rec_blob_opts o = blobfx_opts_labels();
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 2);
    double mean[2] = {0, 0};
    for (int i = 0; i < 2 && cat.count == 2; i++) {
        int j = blobfx_find_light(&cat, l[i].x, l[i].y, 0.5);
        CHECK_MSG(j >= 0, "light %d not found within 0.5 px", i);
        if (j < 0) continue;
        CHECK(cat.flags[j] & REC_BLOB_PSF_FIT);
        CHECK_MSG(similarity(&cat, (size_t)j, &l[0]) > 0.99, "light %d: similarity %g", i,
                  similarity(&cat, (size_t)j, &l[0]));
        for (int q = 0; q < 3 * sc.K; q++) mean[i] += cat.signal[(size_t)j * 3 * sc.K + (size_t)q];
    }
    CHECK_MSG(fabs(mean[1] / mean[0] - l[1].flux / l[0].flux) < 0.05, "flux ratio %g, truth %g",
              mean[1] / mean[0], l[1].flux / l[0].flux);
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
    /* the same total flux in one light of the same signal: one light, not split */
    blobfx_light one[1] = {l[0]};
    one[0].flux = l[0].flux + l[1].flux;
    sc = blobfx_base_scene(64, 48, one, 1, 37);
    sc.K = 12;
    blobfx_render(&sc, &cap);
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 1);
    if (cat.count == 1) CHECK(!(cat.flags[0] & REC_BLOB_DEBLENDED));
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
}

/* The PSF fit's optimiser (blobs_fit.c, fit_positions) lands on chi2's minimum: without noise
 * (rounding only) the fixture renders exactly the fit's model (a pixel-integrated Gaussian), so
 * the minimum is the truth. Three lights on three phases 2-3 px apart, started from step 5's
 * peaks: each found within 0.01 px, its flux ratios those of the truth within 0.2 %. */
TEST(blobs_psf_fit_lands_on_the_noiseless_minimum)
{
    blobfx_light l[3];
    memset(l, 0, sizeof l);
    l[0] = (blobfx_light){30.27, 24.61, 1.3, 20, 0.6, 0.0, {0.4, 0.35, 0.25}};
    l[1] = (blobfx_light){32.74, 25.13, 1.3, 16, 0.6, 1.0 / 3, {0.4, 0.35, 0.25}};
    l[2] = (blobfx_light){31.18, 27.42, 1.3, 12, 0.6, 2.0 / 3, {0.4, 0.35, 0.25}};
    blobfx_scene sc = blobfx_base_scene(64, 48, l, 3, 43);
    sc.K = 12;
    sc.noise = 0;
    gs_capture cap;
    blobfx_render(&sc, &cap);
    rec_blob_opts o = blobfx_opts_labels();
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK_MSG(cat.count == 3, "%zu lights, expected 3", cat.count);
    double sum[3] = {0, 0, 0};
    for (int i = 0; i < 3 && cat.count == 3; i++) {
        int j = blobfx_find_light(&cat, l[i].x, l[i].y, 0.5);
        CHECK_MSG(j >= 0, "light %d not found within 0.5 px", i);
        if (j < 0) continue;
        CHECK(cat.flags[j] & REC_BLOB_PSF_FIT);
        double err = hypot(cat.x_px[j] - l[i].x, cat.y_px[j] - l[i].y);
        CHECK_MSG(err < 0.01, "light %d: %.4f px from the truth", i, err);
        for (int q = 0; q < 3 * sc.K; q++) sum[i] += cat.signal[(size_t)j * 3 * sc.K + (size_t)q];
    }
    for (int i = 1; i < 3 && sum[0] > 0; i++)
        CHECK_MSG(fabs(sum[i] / sum[0] / (l[i].flux / l[0].flux) - 1) < 0.002, "light %d: flux ratio %g, truth %g", i,
                  sum[i] / sum[0], l[i].flux / l[0].flux);
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
}

TEST(blobs_nan_inf_negative_input)
{
    blobfx_light l[1];
    memset(l, 0, sizeof l);
    l[0] = (blobfx_light){20.3, 15.6, 1.2, 5, 0.4, 0.1, {0}};
    blobfx_scene sc = blobfx_base_scene(40, 32, l, 1, 41);
    gs_capture cap;
    blobfx_render(&sc, &cap);
    rec_blob_opts o;
    rec_blob_opts_default(&o);
    rec_catalog cat;
    /* capture fields that docs/formats.md forbids */
    struct {
        double *field;
        double bad;
    } fields[] = {
        {&cap.black_level_dn, NAN}, {&cap.black_level_dn, -1},     {&cap.saturation_dn, INFINITY},
        {&cap.saturation_dn, NAN},  {&cap.saturation_dn, 10},      {&cap.gain_e_per_dn, NAN},
        {&cap.gain_e_per_dn, -2},   {&cap.gain_e_per_dn, INFINITY}, {&cap.read_noise_dn, NAN},
        {&cap.read_noise_dn, -3},   {&cap.frames[3].cycles, 0},    {&cap.frames[3].cycles, -500},
        {&cap.frames[3].cycles, NAN}, {&cap.frames[3].cycles, INFINITY},
    };
    for (size_t i = 0; i < sizeof fields / sizeof *fields; i++) {
        double keep = *fields[i].field;
        *fields[i].field = fields[i].bad;
        memset(&cat, 0x5a, sizeof cat);
        CHECK_MSG(rec_blobs_extract(&cap, &o, &cat) == GS_EINVAL, "field %zu = %g accepted", i,
                  fields[i].bad);
        CHECK(cat.count == 0 && cat.signal == NULL);
        CHECK(strstr(gs_detail(), "field") != NULL);
        *fields[i].field = keep;
    }
    /* options */
    rec_blob_opts bad[8];
    for (int i = 0; i < 8; i++) rec_blob_opts_default(&bad[i]);
    bad[0].threshold_sigma = NAN;
    bad[1].threshold_sigma = -1;
    bad[2].threshold_sigma = INFINITY;
    bad[3].deblend_sigma = NAN;
    bad[4].min_area_px = 0;
    bad[5].max_area_px = 0;
    bad[6].background_px = 2;
    bad[7].grow_px = -1;
    for (int i = 0; i < 8; i++) CHECK_MSG(rec_blobs_extract(&cap, &bad[i], &cat) == GS_EINVAL, "options %d", i);
    CHECK(rec_blobs_extract(NULL, &o, &cat) == GS_EINVAL);
    CHECK(rec_blobs_extract(&cap, NULL, &cat) == GS_EINVAL);
    CHECK(rec_blobs_extract(&cap, &o, NULL) == GS_EINVAL);
    /* HDR counts beyond the format's 16 */
    CHECK_OK(gs_capture_alloc_hdr(&cap));
    cap.halvings[5] = 17;
    cap.halvings[(size_t)cap.width * (size_t)cap.height + 3] = 18;   /* frame 1: the first bad one is named */
    CHECK(rec_blobs_extract(&cap, &o, &cat) == GS_EINVAL && strstr(gs_detail(), "frame 0 pixel (x 5, y 0): 17 halvings: expected 0 to 16"));
    cap.halvings[(size_t)cap.width * (size_t)cap.height + 3] = 0;
    cap.halvings[5] = 0;
    gs_capture_release(&cap);

    /* raw below the black level: negative per-cycle values everywhere around the light */
    sc.black = 1000;
    sc.bg0 = -0.5; /* the pedestal is under the black level: values ~ -0.5 per cycle */
    blobfx_render(&sc, &cap);
    CHECK(gs_capture_value(&cap, 0, 2, 2, 0) < 0);
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 1 && blobfx_catalog_finite(&cat));
    if (cat.count == 1) CHECK(hypot(cat.x_px[0] - 20.3, cat.y_px[0] - 15.6) < 0.5);
    rec_catalog_release(&cat);
    /* gain 0 (unknown) and read noise 0: quantisation noise alone, still finite */
    cap.gain_e_per_dn = 0;
    cap.read_noise_dn = 0;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count >= 1 && blobfx_catalog_finite(&cat));
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
}

TEST(blobs_dim_light_near_threshold)
{
    /* lights whose brightest pixel in M stands 12, 8 and 1.5 noise sigmas over the background */
    blobfx_light l[3];
    memset(l, 0, sizeof l);
    const double snr[3] = {12, 8, 1.5};
    blobfx_scene sc = blobfx_base_scene(96, 64, l, 3, 43);
    for (int i = 0; i < 3; i++) {
        l[i] = (blobfx_light){20.0 + 28 * i, 32.0, 1.2, 1, 0.3, 0.1 * i, {0}};
        double sigma_m = sqrt(blobfx_mean_image_var(&sc, (int)l[i].x, (int)l[i].y));
        l[i].flux = snr[i] * sigma_m / blobfx_psf_px(&l[i], (int)l[i].x, (int)l[i].y);
    }
    gs_capture cap;
    blobfx_render(&sc, &cap);
    rec_blob_opts o;
    rec_blob_opts_default(&o);
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(blobfx_find_light(&cat, l[0].x, l[0].y, 1.5) >= 0);
    CHECK(blobfx_find_light(&cat, l[1].x, l[1].y, 1.5) >= 0);
    CHECK(blobfx_find_light(&cat, l[2].x, l[2].y, 3) < 0);
    CHECK_MSG(cat.count == 2, "%zu lights", cat.count);
    rec_catalog_release(&cat);
    /* the threshold is in calibrated sigmas of the noise model: at 20 sigmas even the
     * 12-sigma light goes (a noise map 1.7 times too low would keep it; one 2 times too high
     * would have lost the 8-sigma light above, one 3.5 times too low found the 1.5-sigma one) */
    o.threshold_sigma = 20;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 0);
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
}

TEST(blobs_empty_scene)
{
    /* noise over a flat background: the expected number of 5-sigma pixels is 65536 * 2.9e-7 */
    blobfx_scene sc = blobfx_base_scene(256, 256, NULL, 0, 47);
    gs_capture cap;
    blobfx_render(&sc, &cap);
    rec_blob_opts o = blobfx_opts_labels();
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 0 && cat.x_px == NULL && cat.signal == NULL && cat.flags == NULL);
    CHECK(cat.labels != NULL && cat.width == 256);
    int any = 0;
    for (size_t p = 0; cat.labels && p < 256 * 256; p++) any |= cat.labels[p] != -1;
    CHECK(!any);
    rec_catalog_release(&cat);
    gs_capture_release(&cap);

    /* all zero (and black level 0): nothing */
    memset(&cap, 0, sizeof cap);
    cap.grid_hz = 60;
    cap.K = 4;
    cap.bands = 1;
    cap.width = 16;
    cap.height = 9;
    cap.saturation_dn = 65535;
    CHECK_OK(gs_capture_alloc(&cap));
    for (int k = 0; k < 4; k++) cap.frames[k].cycles = 100;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 0);
    rec_catalog_release(&cat);

    /* all saturated: one blob, no usable pixel: NO_SIGNAL, signal 0, sigma +Inf, no NaN */
    for (size_t i = 0; i < 4 * 16 * 9; i++) cap.raw[i] = 65535;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 1);
    if (cat.count == 1) {
        CHECK(cat.flags[0] & REC_BLOB_NO_SIGNAL);
        CHECK(cat.flags[0] & REC_BLOB_SATURATED);
        CHECK(cat.flags[0] & REC_BLOB_EDGE);
        CHECK(cat.saturated_px[0] == 16 * 9 && cat.area_px[0] == 16 * 9);
        CHECK(blobfx_catalog_finite(&cat));
        for (int k = 0; k < 4; k++) CHECK(cat.signal[k] == 0 && isinf(cat.sigma[k]));
    }
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
}

/* Degenerate geometries: one-pixel images, single rows and columns, a mesh of one box. */
TEST(blobs_tiny_images)
{
    static const int sizes[][2] = {{1, 1}, {1, 7}, {5, 1}, {3, 2}, {40, 1}};
    for (size_t i = 0; i < sizeof sizes / sizeof *sizes; i++)
        for (int bands = 1; bands <= 3; bands += 2) {
            gs_capture cap;
            memset(&cap, 0, sizeof cap);
            cap.grid_hz = 50;
            cap.K = 2;
            cap.bands = bands;
            cap.width = sizes[i][0];
            cap.height = sizes[i][1];
            cap.saturation_dn = 4095;
            cap.read_noise_dn = 1;
            CHECK_OK(gs_capture_alloc(&cap));
            cap.frames[0].cycles = cap.frames[1].cycles = 10;
            size_t n = (size_t)2 * cap.width * cap.height * bands;
            for (size_t q = 0; q < n; q++) cap.raw[q] = (unsigned short)(10 + q % 3);
            cap.raw[bands] = 3000; /* one bright pixel (the second, or the first of frame 1) */
            rec_blob_opts o = blobfx_opts_labels();
            o.background_px = 3;
            rec_catalog cat;
            CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
            CHECK(blobfx_catalog_finite(&cat));
            CHECK(cat.count <= 2);
            rec_catalog_release(&cat);
            gs_capture_release(&cap);
        }
}
