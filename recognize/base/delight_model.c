/* delight_model.c - the built-in DELIGHT substitute (paper Sec. 3): gs_delight_generate().
 *
 * The paper's DELIGHT database is not public, so every bulb here is a physical model of its lamp
 * technology, calibrated to shared/BULBS.md (tags: [M] measured, [L] literature, [D] derived).
 * docs/delight-models.md gives each model's equations, its parameter ranges and their sources,
 * and the resulting percent-flicker table.
 *
 * One bulb at one grid frequency f goes through four steps:
 *  1. A time-domain model of the lamp, driven by the outlet voltage V(t) = sqrt(2) Vrms
 *     sin(2 pi f t) (t = 0 at its negative-to-positive zero crossing, docs/design.md), run to its
 *     periodic steady state on a fine grid of M >= 8192 samples per flicker cycle
 *     Delta = 1/(2 f) (Eq. 1). Ballast lag, thermal lag and phosphor lag all happen inside the
 *     model, so every template is referenced to the outlet voltage, as DELIGHT was.
 *  2. Its light as a sum of spectral components (mercury and sodium lines, phosphor bands, Planck
 *     radiation), each with its own temporal shape, seen through a three-band camera model:
 *     band intensities I(t, sigma) (Eq. 4), chromaticity Q(sigma) (Eq. 6) and per-band BRFs
 *     B*(t, sigma) = I(t, sigma) / mean I(sigma).
 *  3. Reduction to n samples: the DFT of the fine samples keeps the harmonics h < n/2 with a
 *     raised-cosine taper from n/4 to n/2. The result is a trigonometric polynomial without a
 *     Nyquist term (gs_brf_shift composes exactly) and with little Gibbs ringing at sharp edges.
 *  4. The monochrome ("photodiode") BRF is sum_sigma Q(sigma) B*(t, sigma), i.e. a sensor whose
 *     sensitivity is the sum of the three bands', so mono and RGB entries are consistent.
 *
 * Parameters are drawn with splitmix64 seeded from the bulb id (adding a bulb never changes
 * another), inside the ranges of BULBS.md or, where BULBS.md is silent, inside the model ranges
 * that docs/delight-models.md lists as model choices. Each bulb's modulation depth is set so that
 * its monochrome percent flicker at its native grid frequency equals a target drawn inside its
 * BULBS.md range: by solving one physical knob (filament coupling, capacitor size) or by scaling
 * the modulation around the mean (a non-flickering pedestal for discharge lamps, the ripple
 * amplitude for regulated drivers). The other grid's entry is the same physical bulb (time
 * constants in seconds, design ratios) at the other frequency, so it is not a resampled copy.
 */
#include "recognize/base/internal.h"

#include <fftw3.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define FINE_MIN 8192    /* fine samples per flicker cycle: 1.2 us steps at 50 Hz, 1.0 us at 60 Hz */
#define COARSE_M 1024    /* samples per cycle while solving a knob */

/* ------------------------------------------------------------------ PRNG */

/* Each bulb's own splitmix64 stream (gs_splitmix64). */
typedef struct {
    uint64_t s;
} rng;

static uint64_t rng_next(rng *r)
{
    return gs_splitmix64(&r->s);
}

/* Uniform in [lo, hi). */
static double draw(rng *r, double lo, double hi)
{
    return lo + (hi - lo) * (double)(rng_next(r) >> 11) * 0x1.0p-53;
}

/* The generator of one bulb: FNV-1a of its id, so each bulb's draws are its own. */
static rng rng_for(const char *id)
{
    uint64_t h = 0xcbf29ce484222325ull;
    for (const unsigned char *c = (const unsigned char *)id; *c; c++) h = (h ^ *c) * 0x100000001b3ull;
    rng r = {h ^ 0x44454c4947485431ull};   /* "DELIGHT1" */
    return r;
}

/* ------------------------------------------------------------ bulb table */



/* PF target ranges: BULBS.md's row for the technology, narrowed where needed so that the same
 * bulb at the other grid frequency (whose PF follows from the physics) stays inside the row. */
static const bulb_spec bulbs[] = {
    /* incandescent: 120 V 4-6 % (50-60 W), 10 % (25 W) [M]; 230 V 7-12 % (40-100 W),
     * 15-25 % (15-25 W) [D]. 40 W at 120 V interpolates; 100 W at 120 V takes the lower half. */
    {"inc-a19-25w-120v", "Incandescent A19 25 W 120 V", GS_TECH_INCANDESCENT, 25, 120, 60, 9.2, 10.8, V_NONE, 0},
    {"inc-a19-40w-120v", "Incandescent A19 40 W 120 V", GS_TECH_INCANDESCENT, 40, 120, 60, 6.5, 8.5, V_NONE, 0},
    {"inc-a19-60w-120v", "Incandescent A19 60 W 120 V", GS_TECH_INCANDESCENT, 60, 120, 60, 4.3, 5.7, V_NONE, 0},
    {"inc-a19-100w-120v", "Incandescent A19 100 W 120 V", GS_TECH_INCANDESCENT, 100, 120, 60, 4.1, 4.8, V_NONE, 0},
    {"inc-a60-25w-230v", "Incandescent A60 25 W 230 V", GS_TECH_INCANDESCENT, 25, 230, 50, 16.0, 23.0, V_NONE, 0},
    {"inc-a60-40w-230v", "Incandescent A60 40 W 230 V", GS_TECH_INCANDESCENT, 40, 230, 50, 10.0, 11.5, V_NONE, 0},
    {"inc-a60-60w-230v", "Incandescent A60 60 W 230 V", GS_TECH_INCANDESCENT, 60, 230, 50, 8.5, 10.0, V_NONE, 0},
    {"inc-a60-100w-230v", "Incandescent A60 100 W 230 V", GS_TECH_INCANDESCENT, 100, 230, 50, 7.3, 8.5, V_NONE, 0},
    /* halogen: mains 5-10 % [D/L]; 12 V on a magnetic transformer 1-3 % [D] */
    {"hal-a60-42w-230v", "Halogen A60 42 W 230 V", GS_TECH_HALOGEN, 42, 230, 50, 6.3, 8.0, V_MAINS, 0},
    {"hal-a19-72w-120v", "Halogen A19 72 W 120 V", GS_TECH_HALOGEN, 72, 120, 60, 6.3, 8.0, V_MAINS, 0},
    {"hal-mr16-35w-12v", "Halogen MR16 35 W 12 V magnetic transformer", GS_TECH_HALOGEN, 35, 12, 50, 1.4, 2.4, V_LOWV, 0},
    {"hal-mr16-50w-12v", "Halogen MR16 50 W 12 V magnetic transformer", GS_TECH_HALOGEN, 50, 12, 60, 1.4, 2.4, V_LOWV, 0},
    /* fluorescent, magnetic ballast: 25-40 % halophosphate, 15-25 % triphosphor [L] */
    {"fl-t12-40w-halo", "Fluorescent T12 40 W cool white magnetic ballast", GS_TECH_FLUORESCENT_MAGNETIC, 40, 0, 60, 29.0, 34.0, V_HALO, 0},
    {"fl-t8-18w-halo", "Fluorescent T8 18 W daylight magnetic ballast", GS_TECH_FLUORESCENT_MAGNETIC, 18, 0, 50, 29.0, 34.0, V_HALO, 0},
    {"fl-t8-36w-tri", "Fluorescent T8 36 W 840 magnetic ballast", GS_TECH_FLUORESCENT_MAGNETIC, 36, 0, 50, 18.0, 21.5, V_TRI, 0},
    {"fl-t8-58w-tri", "Fluorescent T8 58 W 830 magnetic ballast", GS_TECH_FLUORESCENT_MAGNETIC, 58, 0, 50, 18.0, 21.5, V_TRI, 0},
    /* fluorescent, electronic ballast: 1-10 % [L] */
    {"fle-t8-32w", "Fluorescent T8 32 W electronic ballast", GS_TECH_FLUORESCENT_ELECTRONIC, 32, 0, 60, 2.5, 7.5, V_TRI, 0},
    {"fle-t5-28w", "Fluorescent T5 28 W electronic ballast", GS_TECH_FLUORESCENT_ELECTRONIC, 28, 0, 50, 2.5, 7.5, V_TRI, 0},
    {"fle-t5-54w", "Fluorescent T5HO 54 W electronic ballast", GS_TECH_FLUORESCENT_ELECTRONIC, 54, 0, 50, 2.5, 7.5, V_TRI, 0},
    /* CFL: 5-30 % [L], 8.9 % measured [M] */
    {"cfl-15w-m", "CFL spiral 15 W (8.9 % as measured)", GS_TECH_CFL, 15, 0, 60, 8.9, 8.9, V_TRI, 0},
    {"cfl-11w", "CFL stick 11 W", GS_TECH_CFL, 11, 0, 50, 14.0, 22.0, V_TRI, 0},
    {"cfl-20w", "CFL spiral 20 W", GS_TECH_CFL, 20, 0, 60, 7.0, 14.0, V_TRI, 0},
    {"cfl-23w", "CFL spiral 23 W", GS_TECH_CFL, 23, 0, 60, 14.0, 22.0, V_TRI, 0},
    /* LED, capacitor-filtered driver: 1-40 % [M: 2.5-36 % over 9 lamps] */
    {"led-a60-9w-cap", "LED A60 9 W capacitor driver", GS_TECH_LED_CAPACITOR, 9, 0, 50, 3.0, 6.0, V_NONE, 0},
    {"led-gu10-5w-cap", "LED GU10 5 W capacitor driver", GS_TECH_LED_CAPACITOR, 5, 0, 50, 24.0, 30.0, V_NONE, 0},
    {"led-a19-8w-cap", "LED A19 8 W capacitor driver", GS_TECH_LED_CAPACITOR, 8, 0, 60, 8.0, 14.0, V_NONE, 0},
    {"led-a19-11w-ksf", "LED A19 11 W high-CRI KSF capacitor driver", GS_TECH_LED_CAPACITOR, 11, 0, 60, 15.0, 22.0, V_KSF, 0},
    {"led-br30-13w-ksf", "LED BR30 13 W KSF capacitor driver", GS_TECH_LED_CAPACITOR, 13, 0, 50, 8.0, 14.0, V_KSF, 0},
    /* LED, unfiltered linear AC driver: ~100 % [D] (no target: the dark interval sets it) */
    {"led-fil-4w-lin", "LED filament 4 W linear AC driver", GS_TECH_LED_LINEAR, 4, 0, 50, 0, 0, V_NONE, 1},
    {"led-a19-9w-lin2", "LED A19 9 W two-tap linear driver", GS_TECH_LED_LINEAR, 9, 0, 60, 0, 0, V_NONE, 2},
    {"led-street-60w-lin3", "LED street light 60 W three-tap linear driver", GS_TECH_LED_LINEAR, 60, 0, 50, 0, 0, V_NONE, 3},
    {"led-highbay-100w-lin4", "LED high bay 100 W four-tap linear driver", GS_TECH_LED_LINEAR, 100, 0, 60, 0, 0, V_NONE, 4},
    /* LED, PWM dimmed: 100 % at 200 Hz-25 kHz, not mains-locked [M]; the AC-locked BRF is the
     * driver's residual line ripple only (PF < 1 %, [D]) */
    {"led-pwm-12w-downlight", "LED downlight 12 W PWM dimmed", GS_TECH_LED_PWM, 12, 0, 50, 0.15, 0.5, V_NONE, 0},
    {"led-pwm-36w-panel", "LED panel 36 W PWM dimmed", GS_TECH_LED_PWM, 36, 0, 60, 0.15, 0.5, V_NONE, 0},
    {"led-pwm-10w-rgbw", "LED RGBW 10 W PWM colour mixing", GS_TECH_LED_PWM, 10, 0, 50, 0.15, 0.5, V_RGBW, 0},
    /* high-pressure sodium, magnetic ballast: 90-100 % (FI 0.20-0.26) [L] */
    {"hps-70w", "High-pressure sodium 70 W magnetic ballast", GS_TECH_SODIUM_HP, 70, 0, 50, 92.0, 98.0, V_NONE, 0},
    {"hps-150w", "High-pressure sodium 150 W magnetic ballast", GS_TECH_SODIUM_HP, 150, 0, 50, 92.0, 98.0, V_NONE, 0},
    {"hps-250w", "High-pressure sodium 250 W magnetic ballast", GS_TECH_SODIUM_HP, 250, 0, 60, 92.0, 98.0, V_NONE, 0},
    {"hps-400w", "High-pressure sodium 400 W magnetic ballast", GS_TECH_SODIUM_HP, 400, 0, 60, 92.0, 98.0, V_NONE, 0},
    /* low-pressure sodium: 80-100 % [L] */
    {"lps-35w", "Low-pressure sodium SOX 35 W", GS_TECH_SODIUM_LP, 35, 0, 50, 84.0, 95.0, V_NONE, 0},
    {"lps-90w", "Low-pressure sodium SOX 90 W", GS_TECH_SODIUM_LP, 90, 0, 50, 84.0, 95.0, V_NONE, 0},
    {"lps-180w", "Low-pressure sodium SOX 180 W", GS_TECH_SODIUM_LP, 180, 0, 60, 84.0, 95.0, V_NONE, 0},
    /* metal halide, magnetic ballast: 35-60 % (FI ~0.08) [L] */
    {"mh-70w", "Metal halide 70 W magnetic ballast", GS_TECH_METAL_HALIDE, 70, 0, 50, 40.0, 50.0, V_NONE, 0},
    {"mh-150w", "Metal halide 150 W magnetic ballast", GS_TECH_METAL_HALIDE, 150, 0, 60, 40.0, 50.0, V_NONE, 0},
    {"mh-250w", "Metal halide 250 W magnetic ballast", GS_TECH_METAL_HALIDE, 250, 0, 50, 40.0, 50.0, V_NONE, 0},
    {"mh-400w", "Metal halide 400 W magnetic ballast", GS_TECH_METAL_HALIDE, 400, 0, 60, 40.0, 50.0, V_NONE, 0},
    /* mercury vapour: 50-65 % clear, 35-45 % coated [L] */
    {"hg-125w-clear", "Mercury vapour 125 W clear", GS_TECH_MERCURY, 125, 0, 50, 54.0, 61.0, V_CLEAR, 0},
    {"hg-250w-clear", "Mercury vapour 250 W clear", GS_TECH_MERCURY, 250, 0, 60, 54.0, 61.0, V_CLEAR, 0},
    {"hg-125w-coated", "Mercury vapour 125 W phosphor coated", GS_TECH_MERCURY, 125, 0, 50, 38.0, 42.0, V_COATED, 0},
    {"hg-400w-coated", "Mercury vapour 400 W phosphor coated", GS_TECH_MERCURY, 400, 0, 60, 38.0, 42.0, V_COATED, 0},
};
#define N_BULBS (sizeof bulbs / sizeof *bulbs)

/* ------------------------------------------------------- drawn parameters */



/* Filament thermal time constant: tau grows with the filament diameter, which grows with its
 * current P/V (BULBS.md gives 30-60 ms [D]); mapped over the table's range of P/V. */
static double filament_tau(const bulb_spec *b, rng *r)
{
    double amps = b->watts / b->volts;
    double frac = log(amps / 0.1) / log(1.0 / 0.1);   /* 0.1 A (25 W 230 V) .. 1 A */
    if (frac < 0) frac = 0;
    if (frac > 1) frac = 1;
    double spread = draw(r, 0.9, 1.0);   /* separate statements: C leaves operand order open */
    double jitter = draw(r, 0.0, 1.0);
    double tau = 0.030 + 0.030 * frac * spread + 0.002 * jitter;
    return tau > 0.060 ? 0.060 : tau;
}

/* Draw one bulb's parameters (the order of draws is part of the database: do not reorder). */
static void draw_params(const bulb_spec *b, lamp *p)
{
    rng r = rng_for(b->id);
    memset(p, 0, sizeof *p);
    p->spec = b;
    p->pf_target = b->pf_lo == b->pf_hi ? b->pf_lo : draw(&r, b->pf_lo, b->pf_hi);
    p->depth = 1.0;
    switch (b->tech) {
    case GS_TECH_INCANDESCENT:
    case GS_TECH_HALOGEN:
        p->knob = KNOB_COUPLING;
        p->tcolor_k = b->tech == GS_TECH_HALOGEN ? draw(&r, 2900, 3100) : draw(&r, 2700, 2850);
        p->tau_th_s = filament_tau(b, &r);
        dm_planck_bands(p->tcolor_k, p->planck_resp, p->planck_m);
        break;
    case GS_TECH_FLUORESCENT_MAGNETIC:
        p->knob = KNOB_PEDESTAL;
        p->lag_deg = draw(&r, 55, 65);
        p->r_choke = draw(&r, 0.05, 0.15);
        p->gap_s = draw(&r, 0.1e-3, 0.3e-3);
        p->gamma = 1.0;
        p->spike_amp = draw(&r, 0.05, 0.2);
        p->spike_s = draw(&r, 0.1e-3, 0.3e-3);
        p->tau_blue_s = draw(&r, 1e-6, 10e-6);
        p->tau_green_s = draw(&r, 2e-3, 5e-3);
        p->tau_red_s = draw(&r, 1e-3, 1.5e-3);
        p->w[0] = draw(&r, 0.05, 0.10);     /* Hg visible lines */
        if (b->variant == V_HALO) {
            p->w[1] = draw(&r, 0.25, 0.40); /* Sb3+ blue band */
            p->w[2] = draw(&r, 0.55, 0.65); /* Mn2+ orange band */
        } else {
            p->w[1] = draw(&r, 0.08, 0.16); /* BAM blue */
            p->w[2] = draw(&r, 0.35, 0.45); /* LAP:Tb green */
            p->w[3] = draw(&r, 0.35, 0.45); /* YOX:Eu red */
        }
        break;
    case GS_TECH_FLUORESCENT_ELECTRONIC:
    case GS_TECH_CFL:
        p->knob = b->tech == GS_TECH_CFL ? KNOB_CAPACITOR : KNOB_AMPLITUDE;
        p->tau_blue_s = draw(&r, 1e-6, 10e-6);
        p->tau_green_s = draw(&r, 2e-3, 5e-3);
        p->tau_red_s = draw(&r, 1e-3, 1.5e-3);
        p->w[0] = draw(&r, 0.04, 0.08);
        p->w[1] = draw(&r, 0.05, 0.16);
        p->w[2] = draw(&r, 0.35, 0.45);
        p->w[3] = draw(&r, 0.35, 0.50);
        p->h3 = draw(&r, -0.08, 0.08);
        p->rho = draw(&r, 0.01, 0.04);
        break;
    case GS_TECH_LED_CAPACITOR:
        p->knob = KNOB_CAPACITOR;
        p->rho = draw(&r, 0.35, 0.6);
        p->vf = draw(&r, 0.55, 0.68);
        p->w[0] = draw(&r, 0.08, 0.22);     /* blue die share */
        p->ksf_frac = b->variant == V_KSF ? draw(&r, 0.12, 0.25) : 0.0;
        p->ksf_tau_s = draw(&r, 7.5e-3, 8.5e-3);
        break;
    case GS_TECH_LED_LINEAR: {
        p->knob = KNOB_NONE;
        int k = b->taps;
        p->tap_v[0] = k == 1 ? draw(&r, 0.5, 0.85) : draw(&r, 0.5, 0.7);
        double top = draw(&r, 0.88, 0.95);
        for (int t = 1; t < k; t++) p->tap_v[t] = p->tap_v[0] + t * (top - p->tap_v[0]) / (k - 1);
        for (int t = 0; t < k; t++) p->tap_w[t] = draw(&r, 0.6, 1.4);
        p->edge = draw(&r, 0.005, 0.015);
        p->w[0] = draw(&r, 0.08, 0.22);
        break;
    }
    case GS_TECH_LED_PWM:
        p->knob = KNOB_AMPLITUDE;
        p->rho = draw(&r, 0.01, 0.03);
        p->tau_d_s = draw(&r, 0.02, 0.06);
        p->w[0] = draw(&r, 0.08, 0.22);
        for (int c = 1; c < 5; c++) p->w[c] = draw(&r, 0.2, 0.9);   /* RGBW duty cycles */
        break;
    case GS_TECH_SODIUM_HP:
        p->knob = KNOB_PEDESTAL;
        p->lag_deg = draw(&r, 55, 65);
        p->r_choke = draw(&r, 0.05, 0.15);
        p->gap_s = draw(&r, 0.5e-3, 1.5e-3);
        p->gamma = draw(&r, 1.2, 1.5);
        p->afterglow_s = draw(&r, 0.1e-3, 0.5e-3);
        p->spike_amp = draw(&r, 0.1, 0.3);
        p->spike_s = draw(&r, 0.05e-3, 0.15e-3);
        p->w[0] = draw(&r, 0.75, 0.85);   /* self-reversed D lines, broad */
        p->w[1] = draw(&r, 0.05, 0.08);   /* 568 nm */
        p->w[2] = draw(&r, 0.04, 0.06);   /* 616 nm */
        p->w[3] = draw(&r, 0.01, 0.03);   /* 498 nm */
        p->w[4] = draw(&r, 0.005, 0.015); /* blue continuum */
        break;
    case GS_TECH_SODIUM_LP:
        p->knob = KNOB_PEDESTAL;
        p->lag_deg = draw(&r, 55, 65);
        p->r_choke = draw(&r, 0.05, 0.15);
        p->gap_s = draw(&r, 0.3e-3, 0.8e-3);
        p->gamma = draw(&r, 1.0, 1.2);
        p->afterglow_s = draw(&r, 0.1e-3, 0.3e-3);
        p->spike_amp = draw(&r, 0.3, 0.6);
        p->spike_s = draw(&r, 0.2e-3, 0.4e-3);
        break;
    case GS_TECH_METAL_HALIDE:
        p->knob = KNOB_PEDESTAL;
        p->lag_deg = draw(&r, 55, 65);
        p->r_choke = draw(&r, 0.05, 0.15);
        p->gap_s = draw(&r, 0.05e-3, 0.2e-3);
        /* species: Na 589, Tl 535, In 451, Hg 436/546 lines, broad (Sc/molecular) continuum */
        p->w[0] = draw(&r, 0.25, 0.35);
        p->w[1] = draw(&r, 0.20, 0.30);
        p->w[2] = draw(&r, 0.10, 0.20);
        p->w[3] = draw(&r, 0.05, 0.10);
        p->w[4] = draw(&r, 0.15, 0.25);
        p->sp_gamma[0] = draw(&r, 0.3, 0.5);
        p->sp_tau_s[0] = draw(&r, 0.3e-3, 0.6e-3);
        p->sp_gamma[1] = draw(&r, 0.4, 0.6);
        p->sp_tau_s[1] = draw(&r, 0.2e-3, 0.5e-3);
        p->sp_gamma[2] = draw(&r, 0.5, 0.7);
        p->sp_tau_s[2] = draw(&r, 0.1e-3, 0.3e-3);
        p->sp_gamma[3] = draw(&r, 0.6, 0.8);
        p->sp_tau_s[3] = draw(&r, 0.1e-3, 0.3e-3);
        p->sp_gamma[4] = 1.0;
        p->sp_tau_s[4] = draw(&r, 0.5e-3, 1.0e-3);
        break;
    case GS_TECH_MERCURY:
        p->knob = KNOB_PEDESTAL;
        p->lag_deg = draw(&r, 55, 65);
        p->r_choke = draw(&r, 0.05, 0.15);
        p->gap_s = draw(&r, 0.1e-3, 0.3e-3);
        p->gamma = draw(&r, 1.0, 1.4);
        p->afterglow_s = draw(&r, 0.2e-3, 0.6e-3);
        p->spike_amp = draw(&r, 0.05, 0.15);
        p->spike_s = draw(&r, 0.1e-3, 0.2e-3);
        p->tau_red_s = draw(&r, 1e-3, 1.5e-3);
        p->w[0] = draw(&r, 0.15, 0.20);   /* 405 nm */
        p->w[1] = draw(&r, 0.25, 0.30);   /* 436 nm */
        p->w[2] = draw(&r, 0.30, 0.35);   /* 546 nm */
        p->w[3] = draw(&r, 0.20, 0.25);   /* 577/579 nm */
        p->w[4] = draw(&r, 0.02, 0.05);   /* red continuum */
        p->w[5] = b->variant == V_COATED ? draw(&r, 0.25, 0.40) : 0.0; /* YVO4:Eu red */
        break;
    default:
        break;
    }
}

/* --------------------------------------------------------------- solving */

/* Monochrome percent flicker of the fine band intensities (sum of the bands, Eq. 6). */
static double fine_mono_pf(const sim *s)
{
    double lo = INFINITY, hi = -INFINITY;
    for (int j = 0; j < s->M; j++) {
        double v = s->band[0][j] + s->band[1][j] + s->band[2][j];
        if (v < lo) lo = v;
        if (v > hi) hi = v;
    }
    return 100.0 * (hi - lo) / (hi + lo);
}

typedef struct {
    lamp *p;
    sim *s;
    gs_status err;
} knob_ctx;

/* PF error as a function of log(knob). */
static double knob_error(double logk, void *vctx)
{
    knob_ctx *c = vctx;
    if (c->p->knob == KNOB_COUPLING) c->p->coupling = exp(logk);
    else c->p->tau_d_s = exp(logk);
    gs_status st = dm_run_model(c->p, c->s);
    if (st != GS_OK) {
        c->err = st;
        return NAN;
    }
    return fine_mono_pf(c->s) - c->p->pf_target;
}

/* Solve the bulb's physics at its native grid, on a coarse grid (s has M = COARSE_M): the
 * ballast's arc voltage for the drawn lag, then the coupling or capacitor for the PF target. */
static gs_status solve_bulb(lamp *p, sim *s)
{
    if (p->lag_deg > 0.0) {
        lag_ctx c = {{0.0, p->r_choke, 2.0 * PI * s->f * p->gap_s}, p->lag_deg, s->tmp[4], s->M, GS_OK};
        double va;
        if (!dm_solve_root(dm_lag_error, &c, 0.05, 1.30, 1e-12, 1e-9, &va) || c.err != GS_OK)
            return c.err != GS_OK ? c.err
                                  : gs_fail(GS_ENUMERIC, "DELIGHT model: bulb %s: ballast lag %.1f deg "
                                            "not reachable", p->spec->id, p->lag_deg);
        p->arc_va = va;
    }
    if (p->knob == KNOB_COUPLING || p->knob == KNOB_CAPACITOR) {
        knob_ctx c = {p, s, GS_OK};
        double lo = p->knob == KNOB_COUPLING ? log(1e-3) : log(0.3 / (2.0 * s->f));
        double hi = p->knob == KNOB_COUPLING ? log(10.0) : log(3000.0 / (2.0 * s->f));
        double k;
        if (!dm_solve_root(knob_error, &c, lo, hi, 1e-12, 1e-9, &k) || c.err != GS_OK)
            return c.err != GS_OK ? c.err
                                  : gs_fail(GS_ENUMERIC, "DELIGHT model: bulb %s: percent flicker "
                                            "%.2f not reachable", p->spec->id, p->pf_target);
        if (p->knob == KNOB_COUPLING) p->coupling = exp(k);
        else p->tau_d_s = exp(k);
    }
    return GS_OK;
}

/* ------------------------------------------------------------- reduction */

typedef struct {
    int n, M;
    double *fin;
    fftw_complex *spec;
    fftw_complex *cspec;
    double *cout;
    fftw_plan fwd, inv;
} reducer;

static gs_status reducer_init(reducer *r, int n, int M)
{
    memset(r, 0, sizeof *r);
    r->n = n;
    r->M = M;
    r->fin = fftw_malloc(sizeof(double) * (size_t)M);
    r->spec = fftw_malloc(sizeof(fftw_complex) * (size_t)(M / 2 + 1));
    r->cspec = fftw_malloc(sizeof(fftw_complex) * (size_t)(n / 2 + 1));
    r->cout = fftw_malloc(sizeof(double) * (size_t)n);
    if (!r->fin || !r->spec || !r->cspec || !r->cout)
        return gs_fail(GS_ENOMEM, "DELIGHT model: cannot allocate the %d-point reduction", M);
    r->fwd = fftw_plan_dft_r2c_1d(M, r->fin, r->spec, FFTW_ESTIMATE);
    r->inv = fftw_plan_dft_c2r_1d(n, r->cspec, r->cout, FFTW_ESTIMATE);
    if (!r->fwd || !r->inv) return gs_fail(GS_ENOMEM, "DELIGHT model: cannot plan a DFT");
    return GS_OK;
}

static void reducer_free(reducer *r)
{
    if (r->fwd) fftw_destroy_plan(r->fwd);
    if (r->inv) fftw_destroy_plan(r->inv);
    fftw_free(r->fin);
    fftw_free(r->spec);
    fftw_free(r->cspec);
    fftw_free(r->cout);
}

/* n samples of the trigonometric polynomial through fine[0..M): harmonics h < n/2 with a
 * raised-cosine taper from n/4 to n/2, the Nyquist term zero. */
static void reduce(reducer *r, const double *fine, double *out)
{
    int n = r->n, M = r->M;
    memcpy(r->fin, fine, sizeof(double) * (size_t)M);
    fftw_execute(r->fwd);
    double q = n / 4.0;
    for (int h = 0; h <= n / 2; h++) {
        double w = 0.0;
        if (h < n / 2) {
            double c = cos(0.5 * PI * (h - q) / (n / 2.0 - q));
            w = h <= q ? 1.0 : c * c;
        }
        r->cspec[h] = r->spec[h] * (w / M);   /* fftw_complex is double complex here */
    }
    fftw_execute(r->inv);
    memcpy(out, r->cout, sizeof(double) * (size_t)n);
}

/* ----------------------------------------------------------- generation */

/* Entry data of one bulb at one grid: chromaticity and the RGB and mono BRFs (n each). */
typedef struct {
    double q[3];
    double *rgb;    /* 3 n */
    double *mono;   /* n */
} grid_result;

/* Turn the fine band intensities of s into chroma and n-sample BRFs; for the native grid of a
 * depth-scaled technology, solve the depth s for the PF target first. The target applies to the
 * physical (fine) waveform; the n-sample BRF is its band-limited form, whose PF is the same at
 * n = 1024 to within ~0.1 % of the value (smaller n smooths sharp features and lowers it). */
static gs_status finish(lamp *p, sim *s, reducer *red, int solve_depth, grid_result *g)
{
    int n = red->n;
    double mean[3], sum = 0.0;
    for (int b = 0; b < 3; b++) {
        mean[b] = dm_mean_of(s->band[b], s->M);
        if (!(mean[b] > 0.0) || !isfinite(mean[b]))
            return gs_fail(GS_ENUMERIC, "DELIGHT model: bulb %s band %d has mean %g", p->spec->id, b,
                           mean[b]);
        sum += mean[b];
    }
    for (int b = 0; b < 3; b++) {
        g->q[b] = mean[b] / sum;
        for (int j = 0; j < s->M; j++) {
            s->band[b][j] /= mean[b];
            if (!(s->band[b][j] >= 0.0))   /* a physical model emits no negative light */
                return gs_fail(GS_ENUMERIC, "DELIGHT model: bulb %s band %d sample %d is %g",
                               p->spec->id, b, j, s->band[b][j]);
        }
    }
    if ((p->knob == KNOB_PEDESTAL || p->knob == KNOB_AMPLITUDE) && solve_depth) {
        /* PF(s) = s (a - c) / (2 + s (a + c)), a and c the extremes of mono - 1 (mono = sum Q B) */
        double a = -INFINITY, c = INFINITY, P = p->pf_target / 100.0;
        for (int j = 0; j < s->M; j++) {
            double m = g->q[0] * s->band[0][j] + g->q[1] * s->band[1][j] + g->q[2] * s->band[2][j];
            if (m - 1.0 > a) a = m - 1.0;
            if (m - 1.0 < c) c = m - 1.0;
        }
        double den = (a - c) - P * (a + c);
        p->depth = den > 0.0 ? 2.0 * P / den : -1.0;
        /* a pedestal adds light (s <= 1); an amplitude must keep the light positive */
        double smax = p->knob == KNOB_PEDESTAL ? 1.0 + 1e-12 : (c < 0.0 ? -1.0 / c : INFINITY);
        if (!(p->depth > 0.0) || p->depth > smax)
            return gs_fail(GS_ENUMERIC, "DELIGHT model: bulb %s: percent flicker %.2f not "
                           "reachable (depth %g)", p->spec->id, p->pf_target, p->depth);
    }
    for (int b = 0; b < 3; b++) reduce(red, s->band[b], g->rgb + (size_t)b * n);
    for (int j = 0; j < n; j++)
        g->mono[j] = g->q[0] * g->rgb[j] + g->q[1] * g->rgb[n + j] + g->q[2] * g->rgb[2 * n + j];
    if (p->knob == KNOB_PEDESTAL || p->knob == KNOB_AMPLITUDE) {
        for (int j = 0; j < 3 * n; j++) g->rgb[j] = 1.0 + p->depth * (g->rgb[j] - 1.0);
        for (int j = 0; j < n; j++) g->mono[j] = 1.0 + p->depth * (g->mono[j] - 1.0);
    }
    return GS_OK;
}

static gs_status add_entry(gs_delight *d, const lamp *p, int grid_hz, int bands, const double *q,
                           const double *v, int n)
{
    gs_bulb e;
    memset(&e, 0, sizeof e);
    snprintf(e.id, sizeof e.id, "%s", p->spec->id);
    snprintf(e.name, sizeof e.name, "%s", p->spec->name);
    snprintf(e.sensor, sizeof e.sensor, "%s", bands == 1 ? "photodiode" : "rgb");
    e.type = p->spec->tech;
    e.watts = p->spec->watts;
    e.grid_hz = grid_hz;
    e.ref = GS_REF_VOLTAGE;
    gs_status s = gs_brf_init(&e.brf, n, bands);
    if (s != GS_OK) return s;
    memcpy(e.brf.v, v, sizeof(double) * (size_t)n * (size_t)bands);
    s = gs_brf_normalize(&e.brf, NULL);
    if (s == GS_OK) {
        if (bands == 1) {
            e.chroma[0] = 1.0;
        } else {
            e.chroma[0] = q[0];
            e.chroma[1] = q[1];
            e.chroma[2] = 1.0 - q[0] - q[1];
        }
        s = gs_delight_add(d, &e);
    }
    gs_brf_release(&e.brf);
    return s;
}

static void sim_set(sim *s, double *mem, int M, double f)
{
    s->f = f;
    s->M = M;
    s->dt = 1.0 / (2.0 * f) / M;
    for (int b = 0; b < 3; b++) s->band[b] = mem + (size_t)b * M;
    for (int k = 0; k < 5; k++) s->tmp[k] = mem + (size_t)(3 + k) * M;
}

#ifdef DELIGHT_MODEL_TRACE
#include <stdio.h>
static void trace_lamp(const lamp *p)
{
    fprintf(stderr, "%-22s pf*=%6.2f Tc=%4.0f tau_th=%5.1fms g=%.4f lag=%4.1f va=%.4f r=%.3f "
            "gap=%.2fms gam=%.2f glow=%.2fms spike=%.2f/%.2fms tauB/G/R=%.3f/%.2f/%.2fms rho=%.3f "
            "vf=%.3f tau_d=%.2fms ksf=%.2f taps=%.2f..%.2f edge=%.3f h3=%.3f depth=%.4f\n",
            p->spec->id, p->pf_target, p->tcolor_k, p->tau_th_s * 1e3, p->coupling, p->lag_deg,
            p->arc_va, p->r_choke, p->gap_s * 1e3, p->gamma, p->afterglow_s * 1e3, p->spike_amp,
            p->spike_s * 1e3, p->tau_blue_s * 1e3, p->tau_green_s * 1e3, p->tau_red_s * 1e3, p->rho,
            p->vf, p->tau_d_s * 1e3, p->ksf_frac, p->tap_v[0],
            p->spec->taps > 0 ? p->tap_v[p->spec->taps - 1] : 0.0, p->edge, p->h3, p->depth);
}
#endif

gs_status gs_delight_generate(gs_delight *d, int n)
{
    if (!d) return gs_fail(GS_EINVAL, "DELIGHT generate: no database");
    if (n < 4 || n % 2 != 0 || n > (1 << 20))
        return gs_fail(GS_EINVAL, "DELIGHT generate: n=%d: expected an even number in [4, 2^20]", n);
    /* Refuse up front if any entry exists already. Everything is generated into a scratch
     * collection first, so that a failure adds nothing (except running out of memory while
     * copying the finished entries into d). */
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        const gs_bulb *o = gs_delight_get(d, i);
        for (size_t k = 0; k < N_BULBS; k++)
            if (!strcmp(o->id, bulbs[k].id) && (!strcmp(o->sensor, "photodiode") || !strcmp(o->sensor, "rgb")))
                return gs_fail(GS_EINVAL, "DELIGHT generate: bulb %s at %d Hz with sensor %s is "
                               "already in the database", o->id, o->grid_hz, o->sensor);
    }
    int M = n * 2 > FINE_MIN ? n * 2 : FINE_MIN;
    size_t per = (size_t)(M > COARSE_M ? M : COARSE_M);
    double *mem = malloc(sizeof(double) * 8 * per);
    double *out = malloc(sizeof(double) * 8 * (size_t)n);
    gs_delight *tmp = gs_delight_new();
    reducer red;
    gs_status st = reducer_init(&red, n, M);
    if (st == GS_OK && (!mem || !out || !tmp)) st = gs_fail(GS_ENOMEM, "DELIGHT generate: out of memory");
    for (size_t k = 0; k < N_BULBS && st == GS_OK; k++) {
        lamp p;
        draw_params(&bulbs[k], &p);
        sim s;
        sim_set(&s, mem, COARSE_M, bulbs[k].native_hz);
        st = solve_bulb(&p, &s);
        grid_result g[2] = {{{0}, out, out + 3 * n}, {{0}, out + 4 * n, out + 7 * n}};
        int order[2] = {p.spec->native_hz == 50 ? 0 : 1, p.spec->native_hz == 50 ? 1 : 0};
        for (int gi = 0; gi < 2 && st == GS_OK; gi++) {
            int which = order[gi];   /* 0: 50 Hz, 1: 60 Hz; native first (it sets the depth) */
            sim_set(&s, mem, M, which == 0 ? 50.0 : 60.0);
            st = dm_run_model(&p, &s);
            if (st == GS_OK) st = finish(&p, &s, &red, gi == 0, &g[which]);
        }
#ifdef DELIGHT_MODEL_TRACE
        trace_lamp(&p);
#endif
        for (int which = 0; which < 2 && st == GS_OK; which++) {
            int hz = which == 0 ? 50 : 60;
            st = add_entry(tmp, &p, hz, 1, NULL, g[which].mono, n);
            if (st == GS_OK) st = add_entry(tmp, &p, hz, 3, g[which].q, g[which].rgb, n);
        }
    }
    for (size_t i = 0; st == GS_OK && i < gs_delight_count(tmp); i++)
        st = gs_delight_add(d, gs_delight_get(tmp, i));
    gs_delight_free(tmp);
    reducer_free(&red);
    free(mem);
    free(out);
    return st;
}
