/* test_blobs_psf.c - PSF-weighted photometry (recognize.h, step 7, psf_weighted): the flux of
 * a Gaussian light whatever its aperture, one factor per light for another PSF, calibrated
 * noise, and less of it than the plain aperture sum where read noise dominates. */
#include "recognize/recognize.h"
#include "tests/blobs_fixture.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>

/* A grid of n x n isolated lights 24 px apart, flux f, PSF sigma psf. */
static void grid_lights(blobfx_light *l, int n, double f, double psf, uint64_t *rs)
{
    for (int i = 0; i < n * n; i++) {
        l[i].x = 14.0 + 24.0 * (i % n) + gs_splitmix_uniform(rs) - 0.5;
        l[i].y = 14.0 + 24.0 * (i / n) + gs_splitmix_uniform(rs) - 0.5;
        l[i].psf = psf;
        l[i].flux = f;
        l[i].depth = 0.4;
        l[i].phase = gs_splitmix_uniform(rs);
        for (int b = 0; b < 3; b++) l[i].chroma[b] = 0.0;
    }
}

TEST(blobs_psf_weighted_flux_of_a_gaussian_light)
{
    /* Noiseless Gaussian lights of sigma 1.3 px: the PSF-weighted signal is each light's whole
     * flux per frame and band (not the aperture's share of it), within 1 %, and the capture's
     * PSF sigma is recovered well enough for that. */
    blobfx_light l[16];
    uint64_t rs = 5;
    grid_lights(l, 4, 400.0, 1.3, &rs);
    blobfx_scene sc = blobfx_base_scene(110, 110, l, 16, 1);
    sc.noise = 0;
    gs_capture cap;
    blobfx_render(&sc, &cap);
    rec_blob_opts o;
    rec_blob_opts_default(&o);
    CHECK(o.psf_weighted == 1);
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 16);
    double worst = 0;
    for (int j = 0; j < 16; j++) {
        int i = blobfx_find_light(&cat, l[j].x, l[j].y, 1.0);
        CHECK(i >= 0);
        if (i < 0) continue;
        for (int b = 0; b < 3; b++)
            for (int k = 0; k < sc.K; k++) {
                double t = blobfx_light_flux(&l[j], sc.K, k, b, 3);
                double e = fabs(cat.signal[((size_t)i * 3 + b) * sc.K + k] / t - 1.0);
                if (e > worst) worst = e;
            }
    }
    printf("    worst relative error of the flux: %.4f\n", worst);
    CHECK_MSG(worst < 0.01, "worst relative error %g", worst);
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
}

/* Per light of a noisy capture: z = (signal - a truth) / sigma over its frames and bands, with
 * a the light's own least-squares factor (one per light), and the mean sigma / truth. */
static void score(const blobfx_scene *sc, const blobfx_light *l, int n, const rec_catalog *cat,
                  double *z_rms, double *rel_sigma)
{
    double z2 = 0, rs = 0;
    int nz = 0, nr = 0;
    for (int j = 0; j < n; j++) {
        int i = blobfx_find_light(cat, l[j].x, l[j].y, 1.5);
        CHECK(i >= 0);
        if (i < 0) continue;
        double st = 0, tt = 0;
        for (int b = 0; b < 3; b++)
            for (int k = 0; k < sc->K; k++) {
                double t = blobfx_light_flux(&l[j], sc->K, k, b, 3), sg = cat->sigma[((size_t)i * 3 + b) * sc->K + k];
                st += cat->signal[((size_t)i * 3 + b) * sc->K + k] * t / (sg * sg);
                tt += t * t / (sg * sg);
            }
        double a = st / tt;
        for (int b = 0; b < 3; b++)
            for (int k = 0; k < sc->K; k++) {
                size_t q = ((size_t)i * 3 + b) * sc->K + k;
                double t = blobfx_light_flux(&l[j], sc->K, k, b, 3);
                double z = (cat->signal[q] - a * t) / cat->sigma[q];
                z2 += z * z;
                nz++;
                rs += cat->sigma[q] / (a * t);
                nr++;
            }
    }
    /* one factor fitted per light out of 3 K samples */
    *z_rms = sqrt(z2 / (nz - (double)n));
    *rel_sigma = rs / nr;
}

TEST(blobs_psf_weighted_noise_calibrated_and_lower)
{
    /* Faint lights (read noise 3 DN, 60 DN per cycle, 50 cycles a frame) of PSF sigma 1.2 px:
     * the weighted signal is the truth times one factor per light with residuals of RMS 1 in
     * sigma units (calibrated), and its relative noise is below the plain aperture sum's. Then
     * lights of two PSFs (0.9 and 1.8 px: the capture's sigma fits neither): still calibrated,
     * one factor per light. */
    blobfx_light l[36];
    uint64_t rs = 9;
    grid_lights(l, 6, 60.0, 1.2, &rs);
    blobfx_scene sc = blobfx_base_scene(160, 160, l, 36, 3);
    sc.cycles = 50;
    gs_capture cap;
    blobfx_render(&sc, &cap);
    rec_blob_opts o;
    rec_blob_opts_default(&o);
    rec_catalog wcat, acat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &wcat));
    o.psf_weighted = 0;
    CHECK_OK(rec_blobs_extract(&cap, &o, &acat));
    double zw, sw, za, sa;
    score(&sc, l, 36, &wcat, &zw, &sw);
    score(&sc, l, 36, &acat, &za, &sa);
    printf("    Gaussian PSF: weighted z RMS %.3f, sigma/flux %.4f; aperture z RMS %.3f, sigma/flux %.4f\n",
           zw, sw, za, sa);
    CHECK_MSG(zw > 0.9 && zw < 1.1, "weighted z RMS %g", zw);
    CHECK_MSG(za > 0.9 && za < 1.1, "aperture z RMS %g", za);
    CHECK_MSG(sw < 0.9 * sa, "weighted relative noise %g, aperture %g", sw, sa);
    rec_catalog_release(&wcat);
    rec_catalog_release(&acat);
    gs_capture_release(&cap);
    for (int i = 0; i < 36; i++) l[i].psf = (i & 1) ? 1.8 : 0.9;
    blobfx_render(&sc, &cap);
    o.psf_weighted = 1;
    CHECK_OK(rec_blobs_extract(&cap, &o, &wcat));
    score(&sc, l, 36, &wcat, &zw, &sw);
    printf("    PSFs 0.9 and 1.8 px: weighted z RMS %.3f\n", zw);
    CHECK_MSG(zw > 0.9 && zw < 1.1, "weighted z RMS %g with mismatched PSFs", zw);
    rec_catalog_release(&wcat);
    gs_capture_release(&cap);
}
