/* blobs_fixture.h - synthetic captures with a known truth for the blob tests
 * (tests/test_blobs*.c), implemented in tests/blobs_fixture.c, prefix blobfx_.
 *
 * Gaussian-PSF lights (pixel-integrated, so the true flux in every pixel is known exactly) at
 * sub-pixel positions, each with a temporal signal 1 + depth cos(2 pi (k/K - phase)) and a
 * chromaticity, over a background that may have a pedestal, a gradient and its own flicker,
 * rendered to DN through the capture's model (black level, cycles / 2^h, Poisson shot noise in
 * electrons, Gaussian read noise, rounding, clipping) with a deterministic PRNG (splitmix64,
 * tests/fixtures.h). The truth of a per-frame sum is the light flux (all lights: crosstalk
 * included) over the light's usable aperture pixels, which the catalog's label image names. */
#ifndef GRIDSURVEY_TESTS_BLOBS_FIXTURE_H
#define GRIDSURVEY_TESTS_BLOBS_FIXTURE_H

#include "capture/capture.h"
#include "recognize/recognize.h"

#include <stddef.h>
#include <stdint.h>

typedef struct {
    double x, y;        /* centre, pixels (pixel centres at integers) */
    double psf;         /* Gaussian sigma, pixels */
    double flux;        /* mean per-cycle flux, summed over bands, DN per cycle */
    double depth;       /* modulation depth of the temporal signal */
    double phase;       /* cycles */
    double chroma[3];   /* fraction per band (sums to 1); all 0: equal */
} blobfx_light;

typedef struct {
    int W, H, K, bands;
    double cycles;                  /* per frame */
    double black, gain, read, sat;  /* DN, e/DN, DN, DN */
    double bg0, bgx, bgy;           /* background per cycle summed over bands: bg0 + bgx x + bgy y */
    double bg_flicker;              /* background temporal modulation depth */
    int noise;                      /* 0: only rounding */
    uint64_t seed;
    const blobfx_light *lights;
    int n;
    const unsigned char *halvings;  /* optional K * W * H */
} blobfx_scene;

/* The scene rendered into cap (allocated here; gs_capture_release frees it), noise from the
 * scene's seed. */
void blobfx_render(const blobfx_scene *sc, gs_capture *cap);
/* A default noisy scene of n lights (borrowed): 3 bands, K = 8, 500 cycles a frame, black 64,
 * gain 2 e/DN, read noise 3 DN, saturation 65535, background 0.3 per cycle. */
blobfx_scene blobfx_base_scene(int W, int H, const blobfx_light *l, int n, uint64_t seed);

/* Per-cycle flux of light l in frame k, band b (all its pixels). */
double blobfx_light_flux(const blobfx_light *l, int K, int k, int b, int bands);
/* Fraction of l's Gaussian PSF in pixel (x, y). */
double blobfx_psf_px(const blobfx_light *l, int x, int y);
/* Light-only per-cycle flux of every light at pixel (x, y), frame k, band b. */
double blobfx_lights_at(const blobfx_scene *sc, int k, int b, int x, int y);
/* Noise variance of the mean image M (per cycle, sum of bands, mean over k) at pixel (x, y),
 * from the truth and the capture's noise model (recognize.h, step 3), without HDR. */
double blobfx_mean_image_var(const blobfx_scene *sc, int x, int y);

/* Pixel p saturated in some frame and band of cap. */
int blobfx_saturated(const gs_capture *cap, size_t p);
/* The truth of catalog light i's sum in frame k, band b: the lights' flux over its usable
 * aperture (cat->labels needed). */
double blobfx_truth_sum(const blobfx_scene *sc, const gs_capture *cap, const rec_catalog *cat,
                        size_t i, int k, int b);
/* The catalog light nearest to (x, y), within r pixels, or -1. */
int blobfx_find_light(const rec_catalog *cat, double x, double y, double r);
/* The default options with the label image. */
rec_blob_opts blobfx_opts_labels(void);
/* Every value of a catalog is finite (sigma may be +Inf only for NO_SIGNAL lights). */
int blobfx_catalog_finite(const rec_catalog *cat);

/* A scene (text) acquired through the simulator backend and the acquisition loop (HDR as the
 * scene says, no progress) into fx_tmp(name), which *path names. Returns the backend (its
 * simulator: cap_backend_sim_handle; free it with cap_backend_free), NULL on failure (CHECKs
 * fail); *sc is the parsed scene (cap_scene_release it). */
cap_backend *blobfx_acquire(const char *text, const char *name, cap_scene *sc, const char **path);

#endif
