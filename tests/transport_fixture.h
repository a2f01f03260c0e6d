/* transport_fixture.h - light-transport scenes for tests/test_transport*.c (implemented in
 * tests/transport_fixture.c, prefix trfx_): a small room (light_transport effect) with lamps at
 * given bulbs and phases, rendered through the real simulator and acquisition loop into a
 * capture directory with its truth (every light's tau Q), and an independent per-pixel weighted
 * least-squares unmixing with the true BRFs to judge rec_unmix against. */
#ifndef GRIDSURVEY_TESTS_TRANSPORT_FIXTURE_H
#define GRIDSURVEY_TESTS_TRANSPORT_FIXTURE_H

#include "recognize/recognize.h"

typedef struct {
    const char *id, *bulb;
    double phase_deg;
    double x_px, y_px, distance_m, flux;   /* flux: photo-electrons per cycle (0: 5e6) */
} trfx_lamp;

typedef struct {
    int W, H, K;             /* 0: 64 x 48, K = 26 */
    long cycles;             /* 0: 256 */
    int hdr_rounds;          /* HDR rounds (0: no HDR) */
    double shade;            /* lamp-shade transmission (0: 0.01) */
    double daylight_e;       /* daylight on the surfaces, e per pixel and cycle (0: none) */
    const char *delight;     /* DELIGHT file the scene renders with (NULL: built-in) */
    unsigned seed;           /* 0: 1 */
} trfx_opts;

/* The scene text (malloc'd: free()) of n lamps in the fixture's room. */
char *trfx_scene(const trfx_opts *o, const trfx_lamp *lamps, int n);
/* Renders text into dir (a capture with truth.json) and reads it into *cap. 1 on success (a
 * failure is a failed CHECK). */
int trfx_render(const char *text, const char *dir, gs_capture *cap);
/* The true tau Q of the lights of the source (bulb, phase) (summed, Eq. 15), W * H * B floats
 * malloc'd (free()), from dir's truth; NULL (a failed CHECK) when none. */
float *trfx_truth(const char *dir, const char *bulb, double phase_deg);
/* The relative Frobenius error of source s of r against the truth of its (bulb, phase) in
 * dir, over the pixels where r has a value. */
double trfx_error(const char *dir, const rec_unmix_result *r, const rec_sources *src, int s);
/* The oracle: per pixel and band, the weighted least-squares T (unconstrained) from the
 * unsaturated samples with the sources' true B (Q B of the lights' own bulbs from d, exactly
 * as the simulator renders them) and weights 1/var from the capture's noise model at the true
 * expected value. err[s] gets its relative Frobenius error per source, over the pixels where
 * both it and r have a value. */
void trfx_oracle_errors(const char *dir, const gs_capture *cap, const gs_delight *d,
                        const rec_sources *src, const rec_unmix_result *r, double *err,
                        double *ours);

#endif
