/* test_blobs.c - rec_blobs_extract against synthetic captures with a known truth: Gaussian-PSF
 * lights (pixel-integrated, so the true flux in every pixel is known exactly) at sub-pixel
 * positions, each with a temporal signal 1 + depth cos(2 pi (k/K - phase)) and a chromaticity,
 * over a background that may have a pedestal, a gradient and its own flicker, rendered to DN
 * through the capture's model (black level, cycles / 2^h, Poisson shot noise in electrons,
 * Gaussian read noise, rounding, clipping) with a deterministic PRNG (splitmix64).
 *
 * The truth of a per-frame sum is the light flux (all lights: crosstalk included) over the
 * light's usable aperture pixels, which the catalog's label image names. */
#include "recognize/internal.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------------ the renderer */

typedef struct {
    double x, y;        /* centre, pixels (pixel centres at integers) */
    double psf;         /* Gaussian sigma, pixels */
    double flux;        /* mean per-cycle flux, summed over bands, DN per cycle */
    double depth;       /* modulation depth of the temporal signal */
    double phase;       /* cycles */
    double chroma[3];   /* fraction per band (sums to 1); all 0: equal */
} light;

typedef struct {
    int W, H, K, bands;
    double cycles;                  /* per frame */
    double black, gain, read, sat;  /* DN, e/DN, DN, DN */
    double bg0, bgx, bgy;           /* background per cycle summed over bands: bg0 + bgx x + bgy y */
    double bg_flicker;              /* background temporal modulation depth */
    int noise;                      /* 0: only rounding */
    uint64_t seed;
    const light *lights;
    int n;
    const unsigned char *halvings;  /* optional K * W * H */
} scene;

static uint64_t rng_state;   /* the renderer's splitmix64 stream (tests/fixtures.h) */

/* Poisson: Knuth's product of uniforms, a rounded normal above a mean of 40. */
static double rng_poisson(double mean)
{
    if (mean <= 0) return 0;
    if (mean > 40) return fmax(0, floor(mean + sqrt(mean) * fx_rng_gauss(&rng_state) + 0.5));
    double L = exp(-mean), p = 1;
    int k = 0;
    do {
        k++;
        p *= fx_rng_uniform(&rng_state);
    } while (p > L);
    return k - 1;
}

static double chroma(const light *l, int b, int bands)
{
    if (bands == 1) return 1;
    if (l->chroma[0] + l->chroma[1] + l->chroma[2] == 0) return 1.0 / bands;
    return l->chroma[b];
}

/* Per-cycle flux of light l in frame k, band b (all its pixels). */
static double light_flux(const light *l, int K, int k, int b, int bands)
{
    return l->flux * chroma(l, b, bands) * (1 + l->depth * cos(2 * M_PI * ((double)k / K - l->phase)));
}

/* Fraction of a Gaussian PSF in pixel (x, y). */
static double psf_px(const light *l, int x, int y)
{
    double s = l->psf * M_SQRT2;
    double fx = 0.5 * (erf((x + 0.5 - l->x) / s) - erf((x - 0.5 - l->x) / s));
    double fy = 0.5 * (erf((y + 0.5 - l->y) / s) - erf((y - 0.5 - l->y) / s));
    return fx * fy;
}

static double background(const scene *sc, int k, int b, int x, int y)
{
    (void)b; /* equal in every band */
    return (sc->bg0 + sc->bgx * x + sc->bgy * y) / sc->bands *
           (1 + sc->bg_flicker * cos(2 * M_PI * (double)k / sc->K + 0.3));
}

/* Light-only per-cycle flux of every light at pixel (x, y), frame k, band b. */
static double lights_at(const scene *sc, int k, int b, int x, int y)
{
    double v = 0;
    for (int i = 0; i < sc->n; i++) {
        const light *l = &sc->lights[i];
        if (fabs(x - l->x) > 8 * l->psf + 2 || fabs(y - l->y) > 8 * l->psf + 2) continue;
        v += light_flux(l, sc->K, k, b, sc->bands) * psf_px(l, x, y);
    }
    return v;
}

static void render(const scene *sc, gs_capture *cap)
{
    memset(cap, 0, sizeof *cap);
    cap->grid_hz = 50;
    cap->K = sc->K;
    cap->bands = sc->bands;
    cap->width = sc->W;
    cap->height = sc->H;
    cap->saturation_dn = sc->sat;
    cap->black_level_dn = sc->black;
    cap->gain_e_per_dn = sc->gain;
    cap->read_noise_dn = sc->read;
    cap->locked = 1;
    CHECK_OK(gs_capture_alloc(cap));
    if (sc->halvings) {
        CHECK_OK(gs_capture_alloc_hdr(cap));
        memcpy(cap->halvings, sc->halvings, (size_t)sc->K * sc->W * sc->H);
    }
    rng_state = sc->seed;
    size_t N = (size_t)sc->W * sc->H;
    double *img = malloc(sizeof(double) * N * sc->bands);
    for (int k = 0; k < sc->K; k++) {
        cap->frames[k].cycles = sc->cycles;
        for (int y = 0; y < sc->H; y++)
            for (int x = 0; x < sc->W; x++)
                for (int b = 0; b < sc->bands; b++)
                    img[((size_t)y * sc->W + x) * sc->bands + b] = background(sc, k, b, x, y);
        for (int i = 0; i < sc->n; i++) {
            const light *l = &sc->lights[i];
            int r = (int)ceil(8 * l->psf + 2);
            for (int y = (int)l->y - r; y <= (int)l->y + r; y++)
                for (int x = (int)l->x - r; x <= (int)l->x + r; x++) {
                    if (x < 0 || y < 0 || x >= sc->W || y >= sc->H) continue;
                    double f = psf_px(l, x, y);
                    for (int b = 0; b < sc->bands; b++)
                        img[((size_t)y * sc->W + x) * sc->bands + b] +=
                            light_flux(l, sc->K, k, b, sc->bands) * f;
                }
        }
        for (size_t p = 0; p < N; p++) {
            int h = sc->halvings ? sc->halvings[(size_t)k * N + p] : 0;
            double ceff = sc->cycles / ldexp(1.0, h);
            for (int b = 0; b < sc->bands; b++) {
                double dn = img[p * sc->bands + b] * ceff; /* signal DN */
                if (sc->noise) {
                    double pos = dn > 0 ? dn : 0; /* a negative pedestal has no shot noise */
                    if (sc->gain > 0) dn += rng_poisson(pos * sc->gain) / sc->gain - pos;
                    dn += sc->read * fx_rng_gauss(&rng_state);
                }
                double raw = floor(sc->black + dn + 0.5);
                if (raw < 0) raw = 0;
                if (raw > 65535) raw = 65535;
                cap->raw[((size_t)k * N + p) * sc->bands + b] = (unsigned short)raw;
            }
        }
    }
    free(img);
}

/* Pixel p saturated in some frame and band of cap. */
static int saturated(const gs_capture *cap, size_t p)
{
    size_t N = (size_t)cap->width * cap->height;
    for (int k = 0; k < cap->K; k++)
        for (int b = 0; b < cap->bands; b++)
            if (cap->raw[((size_t)k * N + p) * cap->bands + b] >= cap->saturation_dn) return 1;
    return 0;
}

/* The truth of light i's sum in frame k, band b: lights' flux over its usable aperture. */
static double truth_sum(const scene *sc, const gs_capture *cap, const rec_catalog *cat, size_t i,
                        int k, int b)
{
    double s = 0;
    for (int y = 0; y < sc->H; y++)
        for (int x = 0; x < sc->W; x++) {
            size_t p = (size_t)y * sc->W + x;
            if (cat->labels[p] != (int)i || saturated(cap, p)) continue;
            s += lights_at(sc, k, b, x, y);
        }
    return s;
}

/* The catalog light nearest to (x, y), within r pixels, or -1. */
static int find_light(const rec_catalog *cat, double x, double y, double r)
{
    int best = -1;
    double bd = r * r;
    for (size_t i = 0; i < cat->count; i++) {
        double d = (cat->x_px[i] - x) * (cat->x_px[i] - x) + (cat->y_px[i] - y) * (cat->y_px[i] - y);
        if (d <= bd) {
            bd = d;
            best = (int)i;
        }
    }
    return best;
}

static rec_blob_opts opts_labels(void)
{
    rec_blob_opts o;
    rec_blob_opts_default(&o);
    o.labels = 1;
    return o;
}

/* Every value of a catalog is finite (sigma may be +Inf only for NO_SIGNAL lights). */
static int catalog_finite(const rec_catalog *cat)
{
    size_t nbk = cat->count * (size_t)cat->bands * cat->K;
    for (size_t i = 0; i < cat->count; i++) {
        if (!isfinite(cat->x_px[i]) || !isfinite(cat->y_px[i]) || !isfinite(cat->peak_dn[i]))
            return 0;
        for (int q = 0; q < cat->bands * cat->K; q++) {
            size_t j = i * (size_t)cat->bands * cat->K + q;
            if (!isfinite(cat->signal[j])) return 0;
            if (!(cat->flags[i] & REC_BLOB_NO_SIGNAL) && !(isfinite(cat->sigma[j]) && cat->sigma[j] > 0))
                return 0;
            if (isnan(cat->sigma[j])) return 0;
        }
    }
    (void)nbk;
    return 1;
}

/* A default noisy scene: 3 bands, K = 8, 500 cycles a frame, gain 2 e/DN, read noise 3 DN. */
static scene base_scene(int W, int H, const light *l, int n, uint64_t seed)
{
    scene sc;
    memset(&sc, 0, sizeof sc);
    sc.W = W;
    sc.H = H;
    sc.K = 8;
    sc.bands = 3;
    sc.cycles = 500;
    sc.black = 64;
    sc.gain = 2;
    sc.read = 3;
    sc.sat = 65535;
    sc.bg0 = 0.3;
    sc.noise = 1;
    sc.seed = seed;
    sc.lights = l;
    sc.n = n;
    return sc;
}

/* -------------------------------------------------------------------- tests */

TEST(blobs_opts_default)
{
    rec_blob_opts o;
    rec_blob_opts_default(&o);
    CHECK(o.threshold_sigma == 5 && o.min_area_px == 1 && o.max_area_px == 5000);
    CHECK(o.background_px == 31 && o.deblend_sigma == 5 && o.grow_px == 2 && o.labels == 0);
    rec_blob_opts_default(NULL); /* harmless */
    rec_catalog_release(NULL);
    rec_catalog cat;
    memset(&cat, 0, sizeof cat);
    rec_catalog_release(&cat);
}

/* Noise variance of the mean image M (per cycle, sum of bands, mean over k) at pixel (x, y),
 * from the truth and the capture's noise model (recognize.h, step 3), without HDR. */
static double mean_image_var(const scene *sc, int x, int y)
{
    double v = 0, c = sc->cycles;
    for (int k = 0; k < sc->K; k++)
        for (int b = 0; b < sc->bands; b++) {
            double dn = (background(sc, k, b, x, y) + lights_at(sc, k, b, x, y)) * c;
            v += (sc->read * sc->read + 1.0 / 12 + (sc->gain > 0 ? dn / sc->gain : 0)) / (c * c);
        }
    return v / ((double)sc->K * sc->K);
}

/* 1-sigma error of the windowed centroid of light l (blobs.c: x <- x + 2 sum w I dx / sum w I,
 * with a Gaussian window of the PSF's sigma): linearised at the truth,
 * var(x) = 4 sum w^2 (x_p - x)^2 var(M_p) / (sum w I_p)^2, I the light's mean-image flux. */
static double centroid_sigma(const scene *sc, const light *l)
{
    double num = 0, den = 0, inv2s2 = 1 / (2 * l->psf * l->psf);
    int r = (int)ceil(4 * l->psf) + 1;
    double mean_flux = 0;
    for (int k = 0; k < sc->K; k++)
        for (int b = 0; b < sc->bands; b++) mean_flux += light_flux(l, sc->K, k, b, sc->bands);
    mean_flux /= sc->K;
    for (int y = (int)l->y - r; y <= (int)l->y + r; y++)
        for (int x = (int)l->x - r; x <= (int)l->x + r; x++) {
            if (x < 0 || y < 0 || x >= sc->W || y >= sc->H) continue;
            double dx = x - l->x, dy = y - l->y;
            double w = exp(-(dx * dx + dy * dy) * inv2s2);
            num += 4 * w * w * dx * dx * mean_image_var(sc, x, y);
            den += w * mean_flux * psf_px(l, x, y);
        }
    return sqrt(num) / den;
}

/* z = (signal - truth) / sigma of every frame and band of every matched light, the centroid
 * errors against centroid_sigma, and no catalog entry without a true light. Returns the
 * number of matched lights; the z statistics go to *mean, *std. */
static int check_against_truth(const scene *sc, const gs_capture *cap, const rec_catalog *cat,
                               double min_flux, double *zmean, double *zstd)
{
    double zs = 0, zz = 0;
    long nz = 0;
    int found = 0;
    for (int i = 0; i < sc->n; i++) {
        const light *l = &sc->lights[i];
        int j = find_light(cat, l->x, l->y, 2);
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
                double z = (cat->signal[q] - truth_sum(sc, cap, cat, (size_t)j, k, b)) / cat->sigma[q];
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
static void random_lights(light *l, int n, double flux_lo, uint64_t seed)
{
    rng_state = seed;
    for (int i = 0; i < n; i++) {
        memset(&l[i], 0, sizeof l[i]);
        l[i].x = 16 + 32 * (i % 8) + fx_rng_uniform(&rng_state) - 0.5;
        l[i].y = 16 + 32 * (i / 8) + fx_rng_uniform(&rng_state) - 0.5;
        l[i].psf = 1.0 + 0.5 * fx_rng_uniform(&rng_state);
        l[i].flux = flux_lo * pow(10, 2 * fx_rng_uniform(&rng_state));
        l[i].depth = 0.5 * fx_rng_uniform(&rng_state);
        l[i].phase = fx_rng_uniform(&rng_state);
        double c0 = 0.2 + fx_rng_uniform(&rng_state), c1 = 0.2 + fx_rng_uniform(&rng_state),
               c2 = 0.2 + fx_rng_uniform(&rng_state);
        l[i].chroma[0] = c0 / (c0 + c1 + c2);
        l[i].chroma[1] = c1 / (c0 + c1 + c2);
        l[i].chroma[2] = c2 / (c0 + c1 + c2);
    }
}

TEST(blobs_isolated_lights_sums_and_centroids)
{
    enum { NL = 64 };
    light l[NL];
    random_lights(l, NL, 0.3, 7);
    scene sc = base_scene(256, 256, l, NL, 11);
    gs_capture cap;
    render(&sc, &cap);
    rec_blob_opts o = opts_labels();
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.bands == 3 && cat.K == 8 && cat.width == 256 && cat.height == 256);
    CHECK(catalog_finite(&cat));
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
    light l[NL];
    random_lights(l, NL, 0.3, 7);
    scene sc = base_scene(256, 256, l, NL, 11);
    sc.noise = 0;
    sc.read = 0;
    sc.gain = 0;
    gs_capture cap;
    render(&sc, &cap);
    rec_blob_opts o = opts_labels();
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == NL);
    double worst = 0;
    for (int i = 0; i < NL; i++) {
        int j = find_light(&cat, l[i].x, l[i].y, 1);
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
                double t = truth_sum(&sc, &cap, &cat, (size_t)j, k, b);
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
    light l[2];
    memset(l, 0, sizeof l);
    l[0] = (light){40.3, 30.6, 1.2, 3, 0.4, 0.2, {0.5, 0.3, 0.2}};
    l[1] = (light){20.8, 12.1, 1.0, 1, 0.7, 0.6, {0.2, 0.3, 0.5}};
    scene sc = base_scene(64, 48, l, 2, 3);
    sc.noise = 0;
    sc.bg0 = 0;
    sc.black = 100;
    static unsigned char halv[8 * 64 * 48];
    for (int k = 0; k < 8; k++)
        for (int y = 28; y < 34; y++)
            for (int x = 38; x < 43; x++) halv[(k * 48 + y) * 64 + x] = (unsigned char)(k % 3);
    sc.halvings = halv;
    gs_capture cap;
    render(&sc, &cap);
    rec_blob_opts o = opts_labels();
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 2);
    for (size_t i = 0; i < cat.count; i++) {
        int j = find_light(&cat, l[i].x, l[i].y, 1);
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
    light l[NL];
    random_lights(l, NL, 1.0, 21);
    scene sc = base_scene(256, 256, l, NL, 22);
    sc.bg0 = 2.0;          /* a pedestal ~7 times the previous test's */
    sc.bgx = 0.01;         /* +2.5 per cycle across the image */
    sc.bgy = -0.006;
    sc.bg_flicker = 0.3;   /* the sky flickers too */
    gs_capture cap;
    render(&sc, &cap);
    rec_blob_opts o = opts_labels();
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

TEST(blobs_area_limits)
{
    light l[3];
    memset(l, 0, sizeof l);
    l[0] = (light){20.2, 20.7, 0.4, 2, 0, 0, {0}};   /* a few pixels */
    l[1] = (light){60.5, 20.3, 1.3, 20, 0, 0, {0}};  /* tens of pixels */
    l[2] = (light){40.1, 60.4, 4.0, 400, 0, 0, {0}}; /* hundreds */
    scene sc = base_scene(96, 96, l, 3, 5);
    sc.bg0 = 0.3;
    gs_capture cap;
    render(&sc, &cap);
    rec_blob_opts o;
    rec_blob_opts_default(&o);
    o.background_px = 48;
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 3);
    int area[3] = {0};
    for (int i = 0; i < 3; i++) {
        int j = find_light(&cat, l[i].x, l[i].y, 1);
        CHECK(j >= 0);
        if (j >= 0) area[i] = cat.area_px[j];
    }
    printf("    areas %d %d %d\n", area[0], area[1], area[2]);
    CHECK(area[0] < area[1] && area[1] < area[2]);
    rec_catalog_release(&cat);
    o.min_area_px = area[0] + 1;
    o.max_area_px = area[2] - 1;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 1 && find_light(&cat, l[1].x, l[1].y, 1) == 0);
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
    light l[3];
    memset(l, 0, sizeof l);
    l[0] = (light){0.3, 30.2, 1.2, 10, 0.3, 0, {0}};   /* half outside the left border */
    l[1] = (light){62.8, 47.6, 1.2, 10, 0.3, 0, {0}};  /* in the bottom-right corner */
    l[2] = (light){30.4, 20.6, 1.2, 10, 0.3, 0, {0}};  /* inside */
    scene sc = base_scene(64, 48, l, 3, 9);
    gs_capture cap;
    render(&sc, &cap);
    rec_blob_opts o;
    rec_blob_opts_default(&o);
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 3);
    for (int i = 0; i < 3; i++) {
        int j = find_light(&cat, l[i].x, l[i].y, 1.5);
        CHECK_MSG(j >= 0, "light %d not found", i);
        if (j >= 0) CHECK(((cat.flags[j] & REC_BLOB_EDGE) != 0) == (i < 2));
    }
    CHECK(catalog_finite(&cat));
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
}

TEST(blobs_saturated_some_frames)
{
    /* a bright light whose core saturates only near the top of its flicker */
    light l[2];
    memset(l, 0, sizeof l);
    l[0] = (light){30.3, 25.6, 1.5, 200, 0.6, 0.25, {0}};
    l[1] = (light){12.2, 10.7, 1.2, 3, 0.3, 0.5, {0}};
    scene sc = base_scene(64, 48, l, 2, 13);
    sc.sat = 3000;
    gs_capture cap;
    render(&sc, &cap);
    /* which frames saturate: not all of them (the test is about "some frames") */
    int sat_frames = 0;
    size_t N = 64 * 48;
    for (int k = 0; k < sc.K; k++) {
        int any = 0;
        for (size_t p = 0; p < N * 3; p++) any |= cap.raw[(size_t)k * N * 3 + p] >= 3000;
        sat_frames += any;
    }
    CHECK_MSG(sat_frames > 0 && sat_frames < sc.K, "%d of %d frames saturate", sat_frames, sc.K);
    rec_blob_opts o = opts_labels();
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 2);
    int j = find_light(&cat, l[0].x, l[0].y, 1), j1 = find_light(&cat, l[1].x, l[1].y, 1);
    CHECK(j >= 0 && j1 >= 0);
    if (j < 0 || j1 < 0) goto out;
    CHECK(cat.flags[j] & REC_BLOB_SATURATED);
    CHECK(!(cat.flags[j1] & REC_BLOB_SATURATED) && cat.saturated_px[j1] == 0);
    int nsat = 0;
    for (size_t p = 0; p < N; p++) nsat += cat.labels[p] == j && saturated(&cap, p);
    CHECK(nsat > 0 && cat.saturated_px[j] == nsat);
    CHECK(cat.peak_dn[j] >= 3000);
    /* the sums are those of the pixels unsaturated in every frame, in every frame: both in
     * frames that saturate and in frames that do not */
    for (int k = 0; k < sc.K; k++)
        for (int b = 0; b < 3; b++) {
            size_t q = ((size_t)j * 3 + b) * sc.K + k;
            double t = truth_sum(&sc, &cap, &cat, (size_t)j, k, b);
            CHECK_MSG(fabs(cat.signal[q] - t) < 5 * cat.sigma[q], "k %d band %d: %g vs %g (sigma %g)",
                      k, b, cat.signal[q], t, cat.sigma[q]);
            /* ... and not those of all the aperture's pixels */
            double all = 0;
            for (size_t p = 0; p < N; p++)
                if (cat.labels[p] == j) all += lights_at(&sc, k, b, (int)(p % 64), (int)(p / 64));
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
    light l[1];
    memset(l, 0, sizeof l);
    l[0] = (light){30.3, 25.6, 1.5, 200, 0.6, 0.25, {0.4, 0.35, 0.25}};
    scene sc = base_scene(64, 48, l, 1, 17);
    sc.sat = 3000;
    gs_capture plain, hdr;
    render(&sc, &plain);
    static unsigned char halv[8 * 64 * 48];
    size_t N = 64 * 48;
    for (int k = 0; k < 8; k++)
        for (size_t p = 0; p < N; p++) {
            int x = (int)(p % 64), y = (int)(p / 64);
            if (abs(x - 30) <= 3 && abs(y - 26) <= 3) halv[k * N + p] = (unsigned char)(k < 4 ? 2 : 1);
        }
    sc.halvings = halv;
    sc.seed = 18;
    render(&sc, &hdr);
    rec_blob_opts o = opts_labels();
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
            double t = truth_sum(&sc, &hdr, &b, 0, k, band);
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

/* Two lights 4.5 px apart (PSF sigma 1.3: their footprints merge into one component). */
static void touching_pair(light *l, double phase2, double depth2)
{
    memset(l, 0, 2 * sizeof *l);
    l[0] = (light){30.2, 24.4, 1.3, 20, 0.6, 0.0, {0.4, 0.35, 0.25}};
    l[1] = (light){34.6, 25.3, 1.3, 14, depth2, phase2, {0.4, 0.35, 0.25}};
}

/* Cosine similarity of a catalog light's band-summed signal with light l's temporal signal
 * (both mean-removed). */
static double similarity(const rec_catalog *cat, size_t j, const light *l)
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

TEST(blobs_two_touching_different_phase)
{
    light l[2];
    touching_pair(l, 1.0 / 3, 0.6); /* the second light 120 deg later (shift 1/3 cycle) */
    scene sc = base_scene(64, 48, l, 2, 31);
    sc.K = 12;
    gs_capture cap;
    render(&sc, &cap);
    rec_blob_opts o = opts_labels();
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
        int j = find_light(&cat, l[i].x, l[i].y, 1.0);
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
                double t = truth_sum(&sc, &cap, &cat, (size_t)j, k, b);
                CHECK_MSG(fabs(cat.signal[q] - t) < 5 * cat.sigma[q], "light %d k %d band %d: %g vs %g",
                          i, k, b, cat.signal[q], t);
            }
    }
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
}

TEST(blobs_two_touching_same_signal)
{
    light l[2];
    touching_pair(l, 0.0, 0.6); /* same bulb, same phase, different brightness */
    scene sc = base_scene(64, 48, l, 2, 37);
    sc.K = 12;
    gs_capture cap;
    render(&sc, &cap);
    rec_blob_opts o = opts_labels();
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 1);
    if (cat.count == 1) {
        CHECK(!(cat.flags[0] & REC_BLOB_DEBLENDED));
        CHECK(similarity(&cat, 0, &l[0]) > 0.99);
        for (int k = 0; k < sc.K; k++)
            for (int b = 0; b < 3; b++) {
                size_t q = (size_t)b * sc.K + k;
                double t = truth_sum(&sc, &cap, &cat, 0, k, b);
                CHECK(fabs(cat.signal[q] - t) < 5 * cat.sigma[q]);
            }
    }
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
}

TEST(blobs_nan_inf_negative_input)
{
    light l[1];
    memset(l, 0, sizeof l);
    l[0] = (light){20.3, 15.6, 1.2, 5, 0.4, 0.1, {0}};
    scene sc = base_scene(40, 32, l, 1, 41);
    gs_capture cap;
    render(&sc, &cap);
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
    CHECK(rec_blobs_extract(&cap, &o, &cat) == GS_EINVAL);
    cap.halvings[5] = 0;
    gs_capture_release(&cap);

    /* raw below the black level: negative per-cycle values everywhere around the light */
    sc.black = 1000;
    sc.bg0 = -0.5; /* the pedestal is under the black level: values ~ -0.5 per cycle */
    render(&sc, &cap);
    CHECK(gs_capture_value(&cap, 0, 2, 2, 0) < 0);
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 1 && catalog_finite(&cat));
    if (cat.count == 1) CHECK(hypot(cat.x_px[0] - 20.3, cat.y_px[0] - 15.6) < 0.5);
    rec_catalog_release(&cat);
    /* gain 0 (unknown) and read noise 0: quantisation noise alone, still finite */
    cap.gain_e_per_dn = 0;
    cap.read_noise_dn = 0;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count >= 1 && catalog_finite(&cat));
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
}

TEST(blobs_dim_light_near_threshold)
{
    /* lights whose brightest pixel in M stands 12, 8 and 1.5 noise sigmas over the background */
    light l[3];
    memset(l, 0, sizeof l);
    const double snr[3] = {12, 8, 1.5};
    scene sc = base_scene(96, 64, l, 3, 43);
    for (int i = 0; i < 3; i++) {
        l[i] = (light){20.0 + 28 * i, 32.0, 1.2, 1, 0.3, 0.1 * i, {0}};
        double sigma_m = sqrt(mean_image_var(&sc, (int)l[i].x, (int)l[i].y));
        l[i].flux = snr[i] * sigma_m / psf_px(&l[i], (int)l[i].x, (int)l[i].y);
    }
    gs_capture cap;
    render(&sc, &cap);
    rec_blob_opts o;
    rec_blob_opts_default(&o);
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(find_light(&cat, l[0].x, l[0].y, 1.5) >= 0);
    CHECK(find_light(&cat, l[1].x, l[1].y, 1.5) >= 0);
    CHECK(find_light(&cat, l[2].x, l[2].y, 3) < 0);
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
    scene sc = base_scene(256, 256, NULL, 0, 47);
    gs_capture cap;
    render(&sc, &cap);
    rec_blob_opts o = opts_labels();
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
        CHECK(catalog_finite(&cat));
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
            rec_blob_opts o = opts_labels();
            o.background_px = 3;
            rec_catalog cat;
            CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
            CHECK(catalog_finite(&cat));
            CHECK(cat.count <= 2);
            rec_catalog_release(&cat);
            gs_capture_release(&cap);
        }
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
    rec_blob_opts o = opts_labels();
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &o, &cat));
    CHECK(cat.count == 400);
    /* the light of each aperture pixel (the 9 x 9 boxes are 50 pixels apart) */
    double worst_z = 0;
    for (int l = 0; l < 400 && cat.labels; l++) {
        int cx = 20 + (l % 20) * 50, cy = 20 + (l / 20) * 50;
        int j = find_light(&cat, cx, cy, 0.5);
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
