/* test_blobs.c - rec_blobs_extract against synthetic captures with a known truth
 * (tests/blobs_fixture.h): sums and centroids of isolated lights, noisy and noiseless, against
 * the truth and its noise model; sums against the format's values; a background with a pedestal,
 * a gradient and its own flicker; the ACam's largest capture. Hard cases:
 * tests/test_blobs_hard.c. */
#include "recognize/internal.h"
#include "tests/blobs_fixture.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* 1-sigma error of the windowed centroid of light l (blobs.c: x <- x + 2 sum w I dx / sum w I,
 * with a Gaussian window of the PSF's sigma): linearised at the truth,
 * var(x) = 4 sum w^2 (x_p - x)^2 var(M_p) / (sum w I_p)^2, I the light's mean-image flux. */
static double centroid_sigma(const blobfx_scene *sc, const blobfx_light *l)
{
    double num = 0, den = 0, inv2s2 = 1 / (2 * l->psf * l->psf);
    int r = (int)ceil(4 * l->psf) + 1;
    double mean_flux = 0;
    for (int k = 0; k < sc->K; k++)
        for (int b = 0; b < sc->bands; b++) mean_flux += blobfx_light_flux(l, sc->K, k, b, sc->bands);
    mean_flux /= sc->K;
    for (int y = (int)l->y - r; y <= (int)l->y + r; y++)
        for (int x = (int)l->x - r; x <= (int)l->x + r; x++) {
            if (x < 0 || y < 0 || x >= sc->W || y >= sc->H) continue;
            double dx = x - l->x, dy = y - l->y;
            double w = exp(-(dx * dx + dy * dy) * inv2s2);
            num += 4 * w * w * dx * dx * blobfx_mean_image_var(sc, x, y);
            den += w * mean_flux * blobfx_psf_px(l, x, y);
        }
    return sqrt(num) / den;
}

/* z = (signal - truth) / sigma of every frame and band of every matched light, the centroid
 * errors against centroid_sigma, and no catalog entry without a true light. Returns the
 * number of matched lights; the z statistics go to *mean, *std. */
static int check_against_truth(const blobfx_scene *sc, const gs_capture *cap, const rec_catalog *cat,
                               double min_flux, double *zmean, double *zstd)
{
    double zs = 0, zz = 0;
    long nz = 0;
    int found = 0;
    for (int i = 0; i < sc->n; i++) {
        const blobfx_light *l = &sc->lights[i];
        int j = blobfx_find_light(cat, l->x, l->y, 2);
        if (j < 0) {
            CHECK_MSG(l->flux < min_flux, "light %d (flux %g at %g, %g) not found", i, l->flux,
                      l->x, l->y);
            continue;
        }
        found++;
        /* centroid: 5 sigma of the noise plus 0.03 px of pixel-sampling bias (without noise
         * the largest error over these lights is 0.013 px: blobs_noiseless_lights). The
         * linearised sigma holds while it is small next to the window (the PSF): below 0.1 px.
         * Fainter lights are held to the match radius. */
        double cs = centroid_sigma(sc, l), tol = cs < 0.1 ? 5 * cs + 0.03 : 2;
        CHECK_MSG(fabs(cat->x_px[j] - l->x) <= tol && fabs(cat->y_px[j] - l->y) <= tol,
                  "light %d (flux %g): centroid (%g, %g), truth (%g, %g), tolerance %g", i,
                  l->flux, cat->x_px[j], cat->y_px[j], l->x, l->y, tol);
        for (int k = 0; k < sc->K; k++)
            for (int b = 0; b < sc->bands; b++) {
                size_t q = ((size_t)j * sc->bands + b) * sc->K + k;
                double z = (cat->signal[q] - blobfx_truth_sum(sc, cap, cat, (size_t)j, k, b)) / cat->sigma[q];
                zs += z;
                zz += z * z;
                nz++;
            }
    }
    for (size_t j = 0; j < cat->count; j++) {
        int matched = 0;
        for (int i = 0; i < sc->n && !matched; i++)
            matched = hypot(cat->x_px[j] - sc->lights[i].x, cat->y_px[j] - sc->lights[i].y) <= 2;
        CHECK_MSG(matched, "spurious light at (%g, %g), area %d", cat->x_px[j], cat->y_px[j],
                  cat->area_px[j]);
    }
    *zmean = nz ? zs / nz : NAN;
    *zstd = nz ? sqrt(zz / nz - *zmean * *zmean) : NAN;
    return found;
}

/* 64 lights on a grid, random sub-pixel positions, PSF sigma 1-1.5 px, fluxes over two decades
 * (peak SNR in M about 3 to 300), random signals. */
static void random_lights(blobfx_light *l, int n, double flux_lo, uint64_t seed)
{
    uint64_t rs = seed;
    for (int i = 0; i < n; i++) {
        memset(&l[i], 0, sizeof l[i]);
        l[i].x = 16 + 32 * (i % 8) + gs_splitmix_uniform(&rs) - 0.5;
        l[i].y = 16 + 32 * (i / 8) + gs_splitmix_uniform(&rs) - 0.5;
        l[i].psf = 1.0 + 0.5 * gs_splitmix_uniform(&rs);
        l[i].flux = flux_lo * pow(10, 2 * gs_splitmix_uniform(&rs));
        l[i].depth = 0.5 * gs_splitmix_uniform(&rs);
        l[i].phase = gs_splitmix_uniform(&rs);
        double c0 = 0.2 + gs_splitmix_uniform(&rs), c1 = 0.2 + gs_splitmix_uniform(&rs),
               c2 = 0.2 + gs_splitmix_uniform(&rs);
        l[i].chroma[0] = c0 / (c0 + c1 + c2);
        l[i].chroma[1] = c1 / (c0 + c1 + c2);
        l[i].chroma[2] = c2 / (c0 + c1 + c2);
    }
}

TEST(blobs_opts_default)
{
    rec_blob_opts o;
    rec_blob_opts_default(&o);
    CHECK(o.threshold_sigma == 5 && o.min_area_px == 1 && o.max_area_px == 5000);
    CHECK(o.background_px == 31 && o.deblend_sigma == 5 && o.grow_px == 2 && o.labels == 0 && o.threads == 0);
    rec_blob_opts_default(NULL); /* harmless */
    rec_catalog_release(NULL);
    rec_catalog cat;
    memset(&cat, 0, sizeof cat);
    rec_catalog_release(&cat);
}

TEST(blobs_isolated_lights_sums_and_centroids)
{
    enum { NL = 64 };
    blobfx_light l[NL];
    random_lights(l, NL, 0.3, 7);
    blobfx_scene sc = blobfx_base_scene(256, 256, l, NL, 11);
    gs_capture cap;
    blobfx_render(&sc, &cap);
    rec_blob_opts o = blobfx_opts_labels();
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.bands == 3 && cat.K == 8 && cat.width == 256 && cat.height == 256);
    CHECK(blobfx_catalog_finite(&cat));
    double zm, zsd;
    /* a light of flux 1 has a peak SNR of about 10 in M: every one from there up is found */
    int found = check_against_truth(&sc, &cap, &cat, 1.0, &zm, &zsd), bright = 0;
    for (int i = 0; i < NL; i++) bright += l[i].flux >= 1.0;
    CHECK(found >= bright && bright >= 25);
    /* honest sigmas: z over ~1500 sums has mean 0 and std 1 (sampling error of the std ~0.02) */
    CHECK_MSG(fabs(zm) < 0.1 && zsd > 0.9 && zsd < 1.1, "z mean %g std %g", zm, zsd);
    for (size_t i = 0; i < cat.count; i++) {
        int ap = 0;
        for (size_t p = 0; p < 256 * 256; p++) ap += cat.labels[p] == (int)i;
        CHECK(ap >= cat.area_px[i] && cat.area_px[i] >= 1);
        CHECK(cat.flags[i] == 0);
        CHECK(cat.saturated_px[i] == 0);
        CHECK(cat.peak_dn[i] > 64 && cat.peak_dn[i] < 65535);
    }
    /* catalog order: raster order of the first footprint pixel, so y grows (rows of 8) */
    for (size_t i = 1; i < cat.count; i++) CHECK(cat.y_px[i] > cat.y_px[i - 1] - 20);
    rec_catalog_release(&cat);
    CHECK(cat.count == 0 && cat.signal == NULL && cat.labels == NULL);
    gs_capture_release(&cap);
}

/* The same lights without noise (only the rounding of raw samples; the capture says read noise
 * 0 and gain 0, so sigma is the quantisation noise): centroids to the pixel-sampling accuracy of
 * the windowed centroid, sums to the quantisation noise. */
TEST(blobs_noiseless_lights)
{
    enum { NL = 64 };
    blobfx_light l[NL];
    random_lights(l, NL, 0.3, 7);
    blobfx_scene sc = blobfx_base_scene(256, 256, l, NL, 11);
    sc.noise = 0;
    sc.read = 0;
    sc.gain = 0;
    gs_capture cap;
    blobfx_render(&sc, &cap);
    rec_blob_opts o = blobfx_opts_labels();
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == NL);
    double worst = 0;
    for (int i = 0; i < NL; i++) {
        int j = blobfx_find_light(&cat, l[i].x, l[i].y, 1);
        CHECK_MSG(j >= 0, "light %d (flux %g) not found", i, l[i].flux);
        if (j < 0) continue;
        double e = fmax(fabs(cat.x_px[j] - l[i].x), fabs(cat.y_px[j] - l[i].y));
        /* 0.03 px: the Gaussian window on a pixel grid (0.013 px at worst here); the faintest
         * lights (a few pixels over the threshold) have a window wider than their PSF */
        CHECK_MSG(e <= (l[i].flux >= 1 ? 0.03 : 0.1), "light %d (flux %g): error %g px", i, l[i].flux, e);
        if (l[i].flux >= 1 && e > worst) worst = e;
        for (int k = 0; k < sc.K; k++)
            for (int b = 0; b < 3; b++) {
                size_t q = ((size_t)j * 3 + b) * sc.K + k;
                double t = blobfx_truth_sum(&sc, &cap, &cat, (size_t)j, k, b);
                CHECK_MSG(fabs(cat.signal[q] - t) <= 5 * cat.sigma[q], "light %d k %d b %d: %g vs %g (sigma %g)",
                          i, k, b, cat.signal[q], t, cat.sigma[q]);
            }
    }
    printf("    largest centroid error (flux >= 1): %.4f px\n", worst);
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
}

/* Without noise and on an exactly black background the per-frame background is exactly 0, so a
 * light's sum is exactly the sum of gs_capture_value over its usable aperture pixels: the
 * extractor and the format agree on black level, cycles and 2^h (HDR). */
TEST(blobs_sum_equals_capture_values)
{
    blobfx_light l[2];
    memset(l, 0, sizeof l);
    l[0] = (blobfx_light){40.3, 30.6, 1.2, 3, 0.4, 0.2, {0.5, 0.3, 0.2}};
    l[1] = (blobfx_light){20.8, 12.1, 1.0, 1, 0.7, 0.6, {0.2, 0.3, 0.5}};
    blobfx_scene sc = blobfx_base_scene(64, 48, l, 2, 3);
    sc.noise = 0;
    sc.bg0 = 0;
    sc.black = 100;
    static unsigned char halv[8 * 64 * 48];
    for (int k = 0; k < 8; k++)
        for (int y = 28; y < 34; y++)
            for (int x = 38; x < 43; x++) halv[(k * 48 + y) * 64 + x] = (unsigned char)(k % 3);
    sc.halvings = halv;
    gs_capture cap;
    blobfx_render(&sc, &cap);
    rec_blob_opts o = blobfx_opts_labels();
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 2);
    for (size_t i = 0; i < cat.count; i++) {
        int j = blobfx_find_light(&cat, l[i].x, l[i].y, 1);
        CHECK(j >= 0);
        if (j < 0) continue;
        CHECK(((cat.flags[j] & REC_BLOB_HDR) != 0) == (i == 0));
        for (int k = 0; k < 8; k++)
            for (int b = 0; b < 3; b++) {
                double want = 0;
                for (int y = 0; y < 48; y++)
                    for (int x = 0; x < 64; x++)
                        if (cat.labels[y * 64 + x] == j) want += gs_capture_value(&cap, k, y, x, b);
                CHECK_NEAR(cat.signal[((size_t)j * 3 + b) * 8 + k], want, 1e-9 * fabs(want) + 1e-12);
            }
    }
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
}

TEST(blobs_background_pedestal_gradient)
{
    enum { NL = 64 };
    blobfx_light l[NL];
    random_lights(l, NL, 1.0, 21);
    blobfx_scene sc = blobfx_base_scene(256, 256, l, NL, 22);
    sc.bg0 = 2.0;          /* a pedestal ~7 times the previous test's */
    sc.bgx = 0.01;         /* +2.5 per cycle across the image */
    sc.bgy = -0.006;
    sc.bg_flicker = 0.3;   /* the sky flickers too */
    gs_capture cap;
    blobfx_render(&sc, &cap);
    rec_blob_opts o = blobfx_opts_labels();
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    double zm, zsd;
    check_against_truth(&sc, &cap, &cat, 3.0, &zm, &zsd);
    /* an aperture of ~40 pixels over a background of ~1-4.5 per cycle: a residual of 1 % of
     * the background would shift z by several sigmas */
    CHECK_MSG(fabs(zm) < 0.15 && zsd > 0.85 && zsd < 1.15, "z mean %g std %g", zm, zsd);
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
}

/* The ACam's largest capture at 50 Hz (paper Fig. 7): 1 megapixel, K = 26, RGB, 400 lights of
 * 9 x 9 pixels (truncated Gaussians, each its own phase) on a 50-pixel grid over uniform noise.
 * Every light is found at its centre, unflagged, and its sums are the light's DN over its
 * aperture. (The extraction's time on this capture is for the bench, not for a test.) */
static double speed_light_dn(int l, int k, int dx, int dy)
{
    double amp = 200 + 50 * l % 1000, mod = 1 + 0.5 * cos(2 * M_PI * (k / 26.0 - l / 7.0));
    return (unsigned short)(amp * mod * exp(-(dx * dx + dy * dy) / 3.0));
}

TEST(blobs_speed_1mp_k26_rgb)
{
    gs_capture cap;
    memset(&cap, 0, sizeof cap);
    cap.grid_hz = 50;
    cap.K = 26;
    cap.bands = 3;
    cap.width = 1024;
    cap.height = 1024;
    cap.saturation_dn = 65535;
    cap.black_level_dn = 64;
    cap.gain_e_per_dn = 2;
    cap.read_noise_dn = 3;
    CHECK_OK(gs_capture_alloc(&cap));
    const size_t N = 1024 * 1024;
    uint32_t h = 12345;
    for (int k = 0; k < cap.K; k++) {
        cap.frames[k].cycles = 500;
        unsigned short *r = cap.raw + (size_t)k * N * 3;
        for (size_t i = 0; i < N * 3; i++) {
            h ^= h << 13;
            h ^= h >> 17;
            h ^= h << 5;
            r[i] = (unsigned short)(150 + (h & 15)); /* ~ uniform noise, std 4.6 DN */
        }
        for (int l = 0; l < 400; l++) {
            int cx = 20 + (l % 20) * 50, cy = 20 + (l / 20) * 50;
            for (int dy = -4; dy <= 4; dy++)
                for (int dx = -4; dx <= 4; dx++)
                    for (int b = 0; b < 3; b++)
                        r[((size_t)(cy + dy) * 1024 + cx + dx) * 3 + b] +=
                            (unsigned short)speed_light_dn(l, k, dx, dy);
        }
    }
    rec_blob_opts o = blobfx_opts_labels();
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 400);
    /* the light of each aperture pixel (the 9 x 9 boxes are 50 pixels apart) */
    double worst_z = 0;
    for (int l = 0; l < 400 && cat.labels; l++) {
        int cx = 20 + (l % 20) * 50, cy = 20 + (l / 20) * 50;
        int j = blobfx_find_light(&cat, cx, cy, 0.5);
        CHECK_MSG(j >= 0, "light %d at (%d, %d) not found", l, cx, cy);
        if (j < 0) continue;
        CHECK_MSG(cat.flags[j] == 0 && cat.saturated_px[j] == 0, "light %d: flags %#x", l,
                  cat.flags[j]);
        for (int k = 0; k < 26; k++) {
            double truth = 0;
            for (int y = cy - 12; y <= cy + 12; y++)
                for (int x = cx - 12; x <= cx + 12; x++)
                    if (cat.labels[(size_t)y * 1024 + x] == j && abs(x - cx) <= 4 && abs(y - cy) <= 4)
                        truth += speed_light_dn(l, k, x - cx, y - cy) / 500.0;
            for (int b = 0; b < 3; b++) {
                size_t q = ((size_t)j * 3 + b) * 26 + k;
                double z = (cat.signal[q] - truth) / cat.sigma[q];
                if (fabs(z) > worst_z) worst_z = fabs(z);
                CHECK_MSG(fabs(z) < 5, "light %d k %d band %d: %g vs %g (sigma %g)", l, k, b,
                          cat.signal[q], truth, cat.sigma[q]);
            }
        }
    }
    /* no aperture reaches past the 12-pixel window searched above */
    size_t far = 0;
    for (size_t p = 0; cat.labels && p < N; p++) {
        int x = (int)(p % 1024), y = (int)(p / 1024);
        int lx = (x + 5) / 50, ly = (y + 5) / 50;   /* the nearest light's column and row */
        lx = lx > 19 ? 19 : lx;
        ly = ly > 19 ? 19 : ly;
        far += cat.labels[p] >= 0 && (abs(x - 20 - 50 * lx) > 12 || abs(y - 20 - 50 * ly) > 12);
    }
    CHECK_MSG(far == 0, "%zu aperture pixels beyond 12 px of their light", far);
    printf("    1024x1024, K = 26, RGB: %zu lights, largest |sum - truth| %.2f sigma\n", cat.count,
           worst_z);
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
}

/* The windowed centroid's fixed point on a noise-free pixel-integrated 1-D Gaussian, found by
 * bisection on its condition sum_i w(i - x) g_i (i - x) = 0 (not step 8's iteration), window
 * sigma max(1, s): the oracle of rec_centroid_bias_px. */
static double bisect_centroid(double c, double psf)
{
    const double s = sqrt(psf * psf + 1.0 / 12.0), sw = s > 1 ? s : 1, k = 1 / (sqrt(2.0) * psf);
    double lo = c - 0.5, hi = c + 0.5;
    for (int it = 0; it < 80; it++) {
        double x = 0.5 * (lo + hi), f = 0;
        for (int i = -40; i <= 40; i++) {
            double g = 0.5 * (erf((i + 0.5 - c) * k) - erf((i - 0.5 - c) * k));
            f += exp(-(i - x) * (i - x) / (2 * sw * sw)) * g * (i - x);
        }
        if (f > 0) lo = x;
        else hi = x;
    }
    return 0.5 * (lo + hi);
}

/* rec_centroid_bias_px: the RMS over 40 sub-pixel phases of the bisection oracle's bias (to
 * 1e-4 relative), 0 at the symmetric phases, falling with the PSF's width; and it is a floor of
 * the extractor's own error: one noise-free bright light (black background, only the rounding
 * of the raw samples) at 20 sub-pixel positions has at least that RMS x error. */
TEST(blobs_centroid_bias_floor)
{
    const double psf[2] = {0.8, 1.1};
    for (int t = 0; t < 2; t++) {
        double sum2 = 0;
        for (int ph = 0; ph < 40; ph++) {
            double d = bisect_centroid(ph / 40.0, psf[t]) - ph / 40.0;
            sum2 += d * d;
            if (ph == 0 || ph == 20) CHECK_MSG(fabs(d) < 1e-9, "phase %d: bias %g", ph, d);
        }
        double oracle = sqrt(sum2 / 40), b = rec_centroid_bias_px(psf[t]);
        CHECK_MSG(fabs(b - oracle) <= 1e-4 * oracle, "PSF %g: %g against the oracle's %g", psf[t], b, oracle);
        double ext2 = 0;
        int n = 0;
        for (int ph = 0; ph < 20; ph++) {
            blobfx_light l[1];
            memset(l, 0, sizeof l);
            l[0] = (blobfx_light){20.0 + ph / 20.0, 16.0, psf[t], 4000, 0.3, 0.1, {0}};
            blobfx_scene sc = blobfx_base_scene(40, 32, l, 1, 3);
            sc.noise = 0;
            sc.read = 0;
            sc.gain = 0;
            sc.bg0 = sc.bgx = sc.bgy = 0;
            gs_capture cap;
            blobfx_render(&sc, &cap);
            rec_blob_opts o = blobfx_opts_labels();
            rec_catalog cat;
            CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
            CHECK(cat.count == 1);
            if (cat.count == 1) {
                ext2 += (cat.x_px[0] - l[0].x) * (cat.x_px[0] - l[0].x);
                n++;
            }
            rec_catalog_release(&cat);
            gs_capture_release(&cap);
        }
        double ext = n ? sqrt(ext2 / n) : NAN;
        printf("    PSF %.1f px: rec_centroid_bias_px %.5f px, the extractor's noise-free RMS x error %.5f px\n",
               psf[t], b, ext);
        CHECK_MSG(ext >= b, "PSF %g: extractor %g below the floor %g", psf[t], ext, b);
    }
    CHECK(rec_centroid_bias_px(1.1) < rec_centroid_bias_px(0.8) / 20);
    CHECK(isnan(rec_centroid_bias_px(0)) && isnan(rec_centroid_bias_px(NAN)) && isnan(rec_centroid_bias_px(100)));
}
