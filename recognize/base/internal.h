/* internal.h - recognize/base/ internals shared between its own files; other modules never
 * include it (tests may). */
#ifndef GRIDSURVEY_BASE_INTERNAL_H
#define GRIDSURVEY_BASE_INTERNAL_H

#include "recognize/base/base.h"

/* before <fftw3.h>: makes fftw_complex the C99 double complex */
#include <complex.h>

/* Consistency checks of one DELIGHT entry (id, ranges, BRF mean 1, chroma sums to 1). */
gs_status gs_bulb_validate(const gs_bulb *b);

/* ----------------------------------------- capture format rules (capture_check.c) */

/* Ranges of the format (docs/formats.md). K: the ACam reaches 26 (paper Fig. 7); 1024 bounds
 * memory for a file that is wrong. Sides: 32768 pixels. Halvings: the ACam's DMD holds M = 96
 * masks, so at most floor(log2(M/2)) = 5..6 halvings (paper footnote 5); GS_MAX_HALVINGS = 16
 * leaves room. */
#define GS_CAPTURE_MAX_K 1024
#define GS_CAPTURE_MAX_SIDE 32768
#define GS_CAPTURE_MAX_SATURATION 65536.0
/* Expected values, in the words of docs/formats.md. */
#define GS_CAPTURE_EXP_FORMAT "the string \"" GS_CAPTURE_FORMAT "\""
#define GS_CAPTURE_EXP_GRID "50 or 60 (an integer)"
#define GS_CAPTURE_EXP_K "an integer from 2 to 1024"
#define GS_CAPTURE_EXP_BANDS "1 or 3 (an integer)"
#define GS_CAPTURE_EXP_SIDE "an integer from 1 to 32768"
#define GS_CAPTURE_EXP_NONNEG "a finite number >= 0"
#define GS_CAPTURE_EXP_LOCKED "true or false"
#define GS_CAPTURE_EXP_FILE "a file name of letters, digits, '.', '_' or '-' that ends in \".png\", does not " \
                 "start with '.' and has at most 255 characters"
#define GS_CAPTURE_EXP_CYCLES "a finite number > 0"
#define GS_CAPTURE_EXP_HZ_MEASURED "a finite number from 45 to 65 (Hz)"
#define GS_CAPTURE_EXP_START "a finite number >= 0 (s)"
#define GS_CAPTURE_EXP_WINDOW_PERIOD "a finite number from 1/130 to 1/90 (s), only when locked is false"
#define GS_CAPTURE_EXP_WINDOW_DRIFT "a finite number >= 0 (windows), only when locked is false"
#define GS_CAPTURE_EXP_PERIOD_NAME "\"measured\" or \"nominal\""
#define GS_CAPTURE_EXP_PERIOD_SOURCE GS_CAPTURE_EXP_PERIOD_NAME ", only when locked is false"

/* One problem of a capture: the field (e.g. "frames[3].cycles") and the expected value. */
typedef struct {
    char field[64];
    char expect[320];
} gs_capture_problem;
/* 1 if valid, else 0 with *pr set. The geometry fields (K, bands, width, height) size the
 * pixel arrays; the fields are every field but the pixels and station_json (frames must hold K
 * entries, in k order). */
int gs_capture_check_geometry(const gs_capture *c, gs_capture_problem *pr);
int gs_capture_check_fields(const gs_capture *c, gs_capture_problem *pr);
/* A frame or HDR-map file name (1 if valid). */
int gs_capture_valid_name(const char *s);

/* ======================== DELIGHT models (delight_model.c, delight_lamps.c), shared between them */

#define PI 3.14159265358979323846
#define SQRT2 1.41421356237309504880

typedef struct {
    double f;        /* grid frequency, Hz */
    int M;           /* samples per flicker cycle; sample j at t = j Delta / M */
    double dt;       /* Delta / M, s */
    double *band[3]; /* out: raw band intensities (any common scale) */
    double *tmp[5];  /* scratch, M each */
} sim;

static inline double dm_mean_of(const double *x, int M)
{
    double s = 0.0;
    for (int j = 0; j < M; j++) s += x[j];
    return s / M;
}

typedef double (*root_fn)(double x, void *ctx);

typedef struct {
    double va, r, gap_rad;
} arc_model;

typedef struct {
    arc_model am;
    double target_deg;
    double *buf;
    int M;
    gs_status err;
} lag_ctx;

enum variant {
    V_NONE,
    V_HALO,      /* halophosphate fluorescent */
    V_TRI,       /* triphosphor fluorescent */
    V_MAINS,     /* mains-voltage halogen */
    V_LOWV,      /* 12 V halogen on a magnetic transformer */
    V_CLEAR,     /* clear mercury */
    V_COATED,    /* phosphor-coated mercury */
    V_KSF,       /* LED with a KSF (K2SiF6:Mn4+) red phosphor */
    V_RGBW       /* PWM LED with separate R, G, B, W channels */
};

typedef struct {
    const char *id;
    const char *name;
    gs_tech tech;
    double watts;
    double volts;      /* rated voltage (filament lamps); 0 = any mains */
    int native_hz;     /* grid whose percent flicker hits the target */
    double pf_lo, pf_hi; /* monochrome PF target range at native_hz, % (BULBS.md, see table) */
    int variant;
    int taps;          /* LED linear: driver taps */
} bulb_spec;

/* How the modulation depth reaches the PF target at the native grid. */
enum knob {
    KNOB_COUPLING,   /* filament: thermal coupling g, solved */
    KNOB_CAPACITOR,  /* rectifier: discharge time constant tau_d (capacitor size), solved */
    KNOB_PEDESTAL,   /* B -> 1 + s (B - 1), s <= 1: a non-flickering share 1 - s of the light */
    KNOB_AMPLITUDE,  /* B -> 1 + s (B - 1), any s > 0: ripple amplitude of a regulated driver */
    KNOB_NONE        /* the shape fixes the depth (linear LED driver) */
};

typedef struct {
    const bulb_spec *spec;
    enum knob knob;
    double pf_target;           /* % at native_hz */
    /* filament (incandescent, halogen) */
    double tcolor_k, tau_th_s, coupling, planck_resp[3], planck_m[3];
    /* discharge on a choke */
    double lag_deg, r_choke, gap_s, gamma, afterglow_s, spike_amp, spike_s, arc_va;
    /* phosphors */
    double tau_blue_s, tau_green_s, tau_red_s;
    /* rectifier drivers */
    double rho, vf, tau_d_s, ksf_frac, ksf_tau_s;
    /* linear LED taps */
    double tap_v[4], tap_w[4], edge;
    /* electronic ballast PFC input-current third harmonic */
    double h3;
    /* spectral weights and per-species responses (metal halide) */
    double w[8], sp_gamma[5], sp_tau_s[5];
    /* depth s (KNOB_PEDESTAL / KNOB_AMPLITUDE), solved at native_hz */
    double depth;
} lamp;

/* delight_lamps.c: the lamp physics. */
/* Band responses of a blackbody at T kelvin: resp[b] its share per band, m[b] ln-derivative. */
void dm_planck_bands(double T, double resp[3], double m[3]);
/* A root of f in [lo, hi] to xtol / ftol (bracketing and secant steps); 0 if none. */
int dm_solve_root(root_fn f, void *ctx, double lo, double hi, double xtol, double ftol, double *root);
/* The ballast lag of a choke lamp at arc voltage va, minus its target (for dm_solve_root). */
double dm_lag_error(double va, void *vctx);
/* The lamp's band waveforms over one cycle into s->band[] (its technology's model). */
gs_status dm_run_model(const lamp *p, sim *s);
/* ====================================================================== end of DELIGHT models */

#endif
