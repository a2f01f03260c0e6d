/* blobs_fixture.c - synthetic captures with a known truth; the contract is in
 * tests/blobs_fixture.h. */
#include "tests/blobs_fixture.h"

#include "tests/fixtures.h"
#include "tests/test.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static uint64_t rng_state;   /* the renderer's splitmix64 stream */

/* Poisson: Knuth's product of uniforms, a rounded normal above a mean of 40. */
static double rng_poisson(double mean)
{
    if (mean <= 0) return 0;
    if (mean > 40) return fmax(0, floor(mean + sqrt(mean) * gs_splitmix_normal(&rng_state) + 0.5));
    double L = exp(-mean), p = 1;
    int k = 0;
    do {
        k++;
        p *= gs_splitmix_uniform(&rng_state);
    } while (p > L);
    return k - 1;
}

static double chroma(const blobfx_light *l, int b, int bands)
{
    if (bands == 1) return 1;
    if (l->chroma[0] + l->chroma[1] + l->chroma[2] == 0) return 1.0 / bands;
    return l->chroma[b];
}

double blobfx_light_flux(const blobfx_light *l, int K, int k, int b, int bands)
{
    return l->flux * chroma(l, b, bands) * (1 + l->depth * cos(2 * M_PI * ((double)k / K - l->phase)));
}

double blobfx_psf_px(const blobfx_light *l, int x, int y)
{
    double s = l->psf * M_SQRT2;
    double fx = 0.5 * (erf((x + 0.5 - l->x) / s) - erf((x - 0.5 - l->x) / s));
    double fy = 0.5 * (erf((y + 0.5 - l->y) / s) - erf((y - 0.5 - l->y) / s));
    return fx * fy;
}

static double background(const blobfx_scene *sc, int k, int b, int x, int y)
{
    (void)b; /* equal in every band */
    return (sc->bg0 + sc->bgx * x + sc->bgy * y) / sc->bands *
           (1 + sc->bg_flicker * cos(2 * M_PI * (double)k / sc->K + 0.3));
}

double blobfx_lights_at(const blobfx_scene *sc, int k, int b, int x, int y)
{
    double v = 0;
    for (int i = 0; i < sc->n; i++) {
        const blobfx_light *l = &sc->lights[i];
        if (fabs(x - l->x) > 8 * l->psf + 2 || fabs(y - l->y) > 8 * l->psf + 2) continue;
        v += blobfx_light_flux(l, sc->K, k, b, sc->bands) * blobfx_psf_px(l, x, y);
    }
    return v;
}

void blobfx_render(const blobfx_scene *sc, gs_capture *cap)
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
            const blobfx_light *l = &sc->lights[i];
            int r = (int)ceil(8 * l->psf + 2);
            for (int y = (int)l->y - r; y <= (int)l->y + r; y++)
                for (int x = (int)l->x - r; x <= (int)l->x + r; x++) {
                    if (x < 0 || y < 0 || x >= sc->W || y >= sc->H) continue;
                    double f = blobfx_psf_px(l, x, y);
                    for (int b = 0; b < sc->bands; b++)
                        img[((size_t)y * sc->W + x) * sc->bands + b] +=
                            blobfx_light_flux(l, sc->K, k, b, sc->bands) * f;
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
                    dn += sc->read * gs_splitmix_normal(&rng_state);
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

int blobfx_saturated(const gs_capture *cap, size_t p)
{
    size_t N = (size_t)cap->width * cap->height;
    for (int k = 0; k < cap->K; k++)
        for (int b = 0; b < cap->bands; b++)
            if (cap->raw[((size_t)k * N + p) * cap->bands + b] >= cap->saturation_dn) return 1;
    return 0;
}

double blobfx_truth_sum(const blobfx_scene *sc, const gs_capture *cap, const rec_catalog *cat, size_t i,
                        int k, int b)
{
    double s = 0;
    for (int y = 0; y < sc->H; y++)
        for (int x = 0; x < sc->W; x++) {
            size_t p = (size_t)y * sc->W + x;
            if (cat->labels[p] != (int)i || blobfx_saturated(cap, p)) continue;
            s += blobfx_lights_at(sc, k, b, x, y);
        }
    return s;
}

int blobfx_find_light(const rec_catalog *cat, double x, double y, double r)
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

rec_blob_opts blobfx_opts_labels(void)
{
    rec_blob_opts o;
    rec_blob_opts_default(&o);
    o.labels = 1;
    o.psf_weighted = 0;   /* the aperture sums the truth is summed over (PSF weighting: test_blobs_psf.c) */
    return o;
}

int blobfx_catalog_finite(const rec_catalog *cat)
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

blobfx_scene blobfx_base_scene(int W, int H, const blobfx_light *l, int n, uint64_t seed)
{
    blobfx_scene sc;
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

double blobfx_mean_image_var(const blobfx_scene *sc, int x, int y)
{
    double v = 0, c = sc->cycles;
    for (int k = 0; k < sc->K; k++)
        for (int b = 0; b < sc->bands; b++) {
            double dn = (background(sc, k, b, x, y) + blobfx_lights_at(sc, k, b, x, y)) * c;
            v += (sc->read * sc->read + 1.0 / 12 + (sc->gain > 0 ? dn / sc->gain : 0)) / (c * c);
        }
    return v / ((double)sc->K * sc->K);
}

cap_backend *blobfx_acquire(const char *text, const char *name, cap_scene *sc, const char **path)
{
    memset(sc, 0, sizeof *sc);
    *path = fx_tmp(name);
    CHECK_OK(cap_scene_parse(text, name, ".", sc));
    cap_backend *be = NULL;
    CHECK_OK(cap_backend_sim_new(sc, NULL, &be));
    if (!be) return NULL;
    cap_loop_opts o;
    cap_loop_opts_default(&o);
    o.progress = 0;
    cap_loop_report rep;
    CHECK_OK(cap_loop_run(be, *path, &o, &rep));
    CHECK(rep.complete);
    return be;
}
