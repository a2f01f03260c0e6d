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

#define PI 3.14159265358979323846
#define SQRT2 1.41421356237309504880
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

/* --------------------------------------------------------- camera model */

/* A generic Bayer colour camera behind its IR-cut filter (390-690 nm): Gaussian band
 * sensitivities plus a 0.3 % floor (every colour filter leaks a little; this is all the blue band
 * sees of low-pressure sodium light). */
static const double cam_peak_nm[3] = {620.0, 540.0, 455.0};
static const double cam_width_nm[3] = {35.0, 38.0, 22.0};
#define CAM_FLOOR 0.003
#define CAM_LO_NM 390.0
#define CAM_HI_NM 690.0

static double cam_sens(int band, double nm)
{
    if (nm < CAM_LO_NM || nm > CAM_HI_NM) return 0.0;
    double x = (nm - cam_peak_nm[band]) / cam_width_nm[band];
    return exp(-0.5 * x * x) + CAM_FLOOR;
}

/* Response of the three bands to a unit-power Gaussian emission line or band at nm (sigma_nm). */
static void line_response(double nm, double sigma_nm, double out[3])
{
    double step = sigma_nm / 8.0 < 0.5 ? sigma_nm / 8.0 : 0.5;
    out[0] = out[1] = out[2] = 0.0;
    double norm = 0.0;
    for (double x = nm - 6.0 * sigma_nm; x <= nm + 6.0 * sigma_nm; x += step) {
        double z = (x - nm) / sigma_nm, g = exp(-0.5 * z * z);
        norm += g;
        for (int b = 0; b < 3; b++) out[b] += g * cam_sens(b, x);
    }
    for (int b = 0; b < 3; b++) out[b] /= norm;
}

/* Planck radiation at colour temperature T through the camera: band responses resp[] and the
 * band-averaged logarithmic sensitivity m[b] = <d ln L / d ln T> = <x e^x / (e^x - 1)>,
 * x = c2 / (lambda T) ~ hc/(lambda k T). BULBS.md's "blue flickers ~1.45x red" [D] is 650/450 nm;
 * through this camera (Planck-weighted band centres ~625 and ~465 nm) the ratio is 1.33-1.34. */
static void planck_bands(double T, double resp[3], double m[3])
{
    const double c2 = 1.438777e7;   /* nm K */
    for (int b = 0; b < 3; b++) resp[b] = m[b] = 0.0;
    for (double nm = CAM_LO_NM; nm <= CAM_HI_NM; nm += 1.0) {
        double x = c2 / (nm * T);
        double L = pow(nm / 1000.0, -5.0) / expm1(x);
        double dlog = x * exp(x) / expm1(x);
        for (int b = 0; b < 3; b++) {
            double s = cam_sens(b, nm) * L;
            resp[b] += s;
            m[b] += s * dlog;
        }
    }
    for (int b = 0; b < 3; b++) m[b] /= resp[b];
}

/* ------------------------------------------------------ simulation grid */

typedef struct {
    double f;        /* grid frequency, Hz */
    int M;           /* samples per flicker cycle; sample j at t = j Delta / M */
    double dt;       /* Delta / M, s */
    double *band[3]; /* out: raw band intensities (any common scale) */
    double *tmp[5];  /* scratch, M each */
} sim;

static double mean_of(const double *x, int M)
{
    double s = 0.0;
    for (int j = 0; j < M; j++) s += x[j];
    return s / M;
}

/* Add one spectral component: weight is its share of the emitted power, shape its temporal
 * waveform (any scale; it is normalised to mean 1 here). */
static void add_light(sim *s, double nm, double sigma_nm, double weight, const double *shape)
{
    double resp[3];
    line_response(nm, sigma_nm, resp);
    double k = weight / mean_of(shape, s->M);
    for (int b = 0; b < 3; b++)
        for (int j = 0; j < s->M; j++) s->band[b][j] += k * resp[b] * shape[j];
}

/* First-order response tau y' = u - y (thermal inertia, phosphor or plasma afterglow) in its
 * exact periodic steady state: the input is linear between samples, the update is the exact
 * solution over one step, and y(0) solves y(0) = y(Delta). out may not alias in. */
static void lowpass_periodic(const double *in, double *out, int M, double dt, double tau)
{
    if (!(tau > 0.0)) {
        memcpy(out, in, sizeof *out * (size_t)M);
        return;
    }
    double x = dt / tau, a = exp(-x), b0, b1;
    if (x < 1e-4) {   /* series: avoids cancellation in 1 - (1 - a)/x */
        b1 = x / 2 - x * x / 6 + x * x * x / 24;
        b0 = x / 2 - x * x / 3 + x * x * x / 8;
    } else {
        double g = -expm1(-x) / x;
        b1 = 1.0 - g;
        b0 = g - a;
    }
    double y = 0.0;
    for (int j = 0; j < M; j++) y = a * y + b0 * in[j] + b1 * in[(j + 1) % M];
    y /= -expm1(-x * M);   /* y(0) = y(Delta) */
    for (int j = 0; j < M; j++) {
        out[j] = y;
        y = a * y + b0 * in[j] + b1 * in[(j + 1) % M];
    }
}

/* Illinois (modified regula falsi) root of f on [lo, hi]; f(lo) and f(hi) must differ in sign.
 * Stops when |f| <= ftol or the bracket is narrower than xtol. */
typedef double (*root_fn)(double x, void *ctx);
static int solve_root(root_fn f, void *ctx, double lo, double hi, double xtol, double ftol,
                      double *root)
{
    double flo = f(lo, ctx), fhi = f(hi, ctx);
    if (!isfinite(flo) || !isfinite(fhi) || flo * fhi > 0.0) return 0;
    int side = 0;
    for (int it = 0; it < 200; it++) {
        double x = (lo * fhi - hi * flo) / (fhi - flo);
        if (!(x > lo && x < hi)) x = 0.5 * (lo + hi);
        double fx = f(x, ctx);
        if (fabs(fx) <= ftol || hi - lo < xtol) {
            *root = x;
            return 1;
        }
        if (fx * fhi > 0.0) {
            hi = x;
            fhi = fx;
            if (side == -1) flo *= 0.5;
            side = -1;
        } else {
            lo = x;
            flo = fx;
            if (side == 1) fhi *= 0.5;
            side = 1;
        }
        if (hi - lo < xtol) {
            *root = 0.5 * (lo + hi);
            return 1;
        }
    }
    *root = 0.5 * (lo + hi);
    return 1;
}

/* ---------------------------------------- discharge lamp on a series choke */

/* A gas-discharge lamp behind a series choke (magnetic ballast), in per-unit form: time is the
 * AC phase th = 2 pi f t, voltage is in units of Vrms, current in Vrms/(2 pi f L):
 *     di/dth = sqrt(2) sin th - va sgn(i) - r i
 * with a square-wave arc voltage va, choke resistance r = R/(omega L). After each current zero
 * the arc is dark for gap_rad and re-ignites once the supply exceeds the arc voltage. The
 * steady state is anti-periodic (i(th + pi) = -i(th)), so the light |i|^gamma repeats every
 * flicker cycle. The simulation runs one half-cycle in a frame where the supply is positive
 * and flips the sign of the state at its end. */
typedef struct {
    double va, r, gap_rad;
} arc_model;

typedef struct {
    double i;        /* current */
    int s;           /* polarity of the conduction (+1/-1) */
    int dark;        /* 1 during the gap */
    double dark_end; /* phase of re-ignition while dark */
} arc_state;

static double arc_ip(const arc_model *a, int s, double th)
{
    return SQRT2 * (a->r * sin(th) - cos(th)) / (1.0 + a->r * a->r) - a->va * s / a->r;
}

/* Exact conduction from (th0, i0) to th1 (linear ODE with sinusoidal forcing). */
static double arc_advance(const arc_model *a, int s, double th0, double i0, double th1)
{
    return arc_ip(a, s, th1) + (i0 - arc_ip(a, s, th0)) * exp(-a->r * (th1 - th0));
}

/* Re-ignition phase for a gap ending at thc: the supply must exceed the arc voltage. */
static double arc_reignite(const arc_model *a, double thc)
{
    double th_on = asin(a->va / SQRT2) * (1.0 + 1e-9) + 1e-12;
    double k = floor(thc / PI), loc = thc - k * PI;
    if (loc < th_on) {
        loc = th_on;
    } else if (loc > PI - th_on) {
        loc = th_on;
        k += 1.0;
    }
    return k * PI + loc;
}

/* One half-cycle of M steps; i_out[j] = current at th = j pi / M (may be NULL); *th_ig = phase
 * of the re-ignition inside this half-cycle (unchanged if none). A[j] is the s-independent part
 * of arc_ip at th = j pi / M (j = 0..M), so that a step without events costs two products. */
static void arc_half_cycle(const arc_model *a, const double *A, arc_state *st, int M, double *i_out,
                           double *th_ig)
{
    const double h = PI / M, E = exp(-a->r * h);
    for (int j = 0; j < M; j++) {
        double th = j * h, th1 = (j + 1) * h;
        if (i_out) i_out[j] = st->i;
        if (!st->dark) {   /* fast path: a whole step of conduction */
            double c = a->va * st->s / a->r;
            double i1 = A[j + 1] - c + (st->i - A[j] + c) * E;
            if (i1 * st->s >= 0.0) {
                st->i = i1;
                continue;
            }
        }
        while (th < th1) {
            if (st->dark) {
                if (st->dark_end >= th1) break;
                if (st->dark_end > th) th = st->dark_end;
                st->dark = 0;
                st->s = +1;   /* the supply is positive in this frame */
                st->i = 0.0;
                if (th_ig) *th_ig = th;
            }
            double i1 = arc_advance(a, st->s, th, st->i, th1);
            if (i1 * st->s >= 0.0) {
                st->i = i1;
                break;
            }
            /* current zero inside the step: bisect the exact solution */
            double lo = th, hi = th1;
            for (int it = 0; it < 60; it++) {
                double mid = 0.5 * (lo + hi);
                if (arc_advance(a, st->s, th, st->i, mid) * st->s > 0.0) lo = mid;
                else hi = mid;
            }
            st->i = 0.0;
            st->dark = 1;
            st->dark_end = arc_reignite(a, hi + a->gap_rad);
            th = hi;
        }
    }
}

/* Steady state: i_out (M samples of one flicker cycle, signed, in the frame where the supply is
 * sqrt(2) sin(pi u), u = j/M), the re-ignition time u_ig in cycles, and the lag of the current's
 * fundamental behind the supply voltage in degrees of the AC cycle. */
static gs_status arc_run(const arc_model *a, int M, double *i_out, double *u_ig, double *lag_deg)
{
    double *A = malloc(sizeof *A * (size_t)(M + 1));
    if (!A) return gs_fail(GS_ENOMEM, "DELIGHT model: out of memory");
    for (int j = 0; j <= M; j++) A[j] = arc_ip(a, 0, PI * j / M);
    arc_state st = {0.0, +1, 1, arc_reignite(a, 0.0)};
    double th_ig = 0.0;
    int converged = 0;
    for (int it = 0; it < 2000 && !converged; it++) {
        arc_state start = st;
        arc_half_cycle(a, A, &st, M, i_out, &th_ig);
        st.i = -st.i;
        st.s = -st.s;
        if (st.dark) st.dark_end -= PI;
        converged = it > 2 && fabs(st.i - start.i) < 1e-12 && st.dark == start.dark &&
                    (!st.dark || fabs(st.dark_end - start.dark_end) < 1e-10);
    }
    free(A);
    if (!converged)
        return gs_fail(GS_ENUMERIC, "DELIGHT model: choke-arc circuit (va=%g, r=%g) did not reach a "
                       "steady state", a->va, a->r);
    if (u_ig) *u_ig = th_ig / PI;
    if (lag_deg) {
        double sa = 0.0, cb = 0.0;
        for (int j = 0; j < M; j++) {
            sa += i_out[j] * sin(PI * j / M);
            cb += i_out[j] * cos(PI * j / M);
        }
        *lag_deg = atan2(-cb, sa) * 180.0 / PI;   /* i ~ sin(th - lag) */
    }
    return GS_OK;
}

typedef struct {
    arc_model am;
    double target_deg;
    double *buf;
    int M;
    gs_status err;
} lag_ctx;

static double lag_error(double va, void *vctx)
{
    lag_ctx *c = vctx;
    c->am.va = va;
    double lag = NAN;
    gs_status s = arc_run(&c->am, c->M, c->buf, NULL, &lag);
    if (s != GS_OK) c->err = s;
    return lag - c->target_deg;
}

/* ------------------------------------------ rectifier + capacitor drivers */

/* A bridge rectifier charging a bulk capacitor through a source resistance, discharged by its
 * load (LED string of voltage vf through its series resistance, or a resistive inverter with
 * vf = 0). Per unit: v in units of the supply peak, th = 2 pi f t in [0, pi) (|V| = sin th):
 *     dv/dth = [ max(0, sin th - v) / rho - max(0, v - vf) ] / (2 pi f tau_d)
 * tau_d = R_load C is the discharge time constant, rho = R_source / R_load. */
typedef struct {
    double tau_rad, rho, vf;
} rectcap;

static double rc_deriv(const rectcap *c, double s, double v)
{
    double chg = s > v ? (s - v) / c->rho : 0.0;
    double dis = v > c->vf ? v - c->vf : 0.0;
    return (chg - dis) / c->tau_rad;
}

/* One flicker cycle (RK4, M steps) from v0; returns v at its end; v_out may be NULL.
 * sn[k] = sin(k pi / (2 M)), k = 0..2M (full and half steps). */
static double rc_cycle(const rectcap *c, const double *sn, int M, double v0, double *v_out)
{
    double h = PI / M, v = v0;
    for (int j = 0; j < M; j++) {
        if (v_out) v_out[j] = v;
        double s0 = sn[2 * j], sm = sn[2 * j + 1], s1 = sn[2 * j + 2];
        double k1 = rc_deriv(c, s0, v), k2 = rc_deriv(c, sm, v + 0.5 * h * k1);
        double k3 = rc_deriv(c, sm, v + 0.5 * h * k2), k4 = rc_deriv(c, s1, v + h * k3);
        v += h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
    }
    return v;
}

typedef struct {
    const rectcap *c;
    const double *sn;
    int M;
} rc_ctx;

static double rc_residual(double v0, void *vctx)
{
    rc_ctx *x = vctx;
    return rc_cycle(x->c, x->sn, x->M, v0, NULL) - v0;
}

/* Periodic steady state v(0) = v(Delta), found by shooting on v(0) in [vf, 1]. */
static gs_status rc_run(const rectcap *c, int M, double *v_out)
{
    double *sn = malloc(sizeof *sn * (size_t)(2 * M + 1));
    if (!sn) return gs_fail(GS_ENOMEM, "DELIGHT model: out of memory");
    for (int k = 0; k <= 2 * M; k++) sn[k] = sin(PI * k / (2.0 * M));
    rc_ctx x = {c, sn, M};
    double v0;
    int ok = solve_root(rc_residual, &x, c->vf, 1.0, 1e-15, 1e-14, &v0);
    if (ok) rc_cycle(c, sn, M, v0, v_out);
    free(sn);
    if (!ok)
        return gs_fail(GS_ENUMERIC, "DELIGHT model: rectifier (tau=%g rad, rho=%g, vf=%g) has no "
                       "steady state", c->tau_rad, c->rho, c->vf);
    return GS_OK;
}

/* ------------------------------------------------------------ bulb table */

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
    {"cfl-15w-m", "CFL spiral 15 W (8.9 % as measured)", GS_TECH_CFL, 15, 0, 50, 8.9, 8.9, V_TRI, 0},
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
        planck_bands(p->tcolor_k, p->planck_resp, p->planck_m);
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

/* ------------------------------------------------- one model per technology */

/* Incandescent and halogen (BULBS.md: thermal low-pass of V^2, tau 30-60 ms [D]). The filament's
 * relative temperature theta follows tau theta' = g (V^2 / <V^2> - 1) - theta (heat balance
 * linearised about its mean), and each band's light is exp(m_b theta) with m_b the band's
 * d ln L / d ln T from Planck's law (BULBS.md: blue ripple ~1.45x red [D]; 1.33 through this
 * camera). The lag of the flicker's fundamental is atan(4 pi f tau), 87-88.7 deg for tau in
 * 30-60 ms [D: ~85-89 deg]; g is solved for the PF target. */
static gs_status model_filament(const lamp *p, sim *s)
{
    double *u = s->tmp[0], *th = s->tmp[1];
    for (int j = 0; j < s->M; j++) u[j] = -cos(2.0 * PI * j / s->M);   /* 2 sin^2 - 1 */
    lowpass_periodic(u, th, s->M, s->dt, p->tau_th_s);
    for (int b = 0; b < 3; b++)
        for (int j = 0; j < s->M; j++)
            s->band[b][j] = p->planck_resp[b] * exp(p->coupling * p->planck_m[b] * th[j]);
    return GS_OK;
}

/* Run the choke-arc circuit of p at the grid of s: out = |i|^gamma normalised to peak 1, plus a
 * re-ignition spike of relative height spike_amp, an alpha pulse of width spike_s starting at
 * the re-ignition (0 if spike_amp is 0). */
static gs_status arc_drive(const lamp *p, sim *s, double gamma, double *out)
{
    arc_model am = {p->arc_va, p->r_choke, 2.0 * PI * s->f * p->gap_s};
    double u_ig = 0.0;
    gs_status st = arc_run(&am, s->M, out, &u_ig, NULL);
    if (st != GS_OK) return st;
    double peak = 0.0;
    for (int j = 0; j < s->M; j++) {
        out[j] = pow(fabs(out[j]), gamma);
        if (out[j] > peak) peak = out[j];
    }
    double w = p->spike_s * 2.0 * s->f;   /* cycles */
    for (int j = 0; j < s->M; j++) {
        out[j] /= peak;
        if (p->spike_amp > 0.0) {
            double x = fmod((double)j / s->M - u_ig + 2.0, 1.0) / w;
            out[j] += p->spike_amp * x * exp(1.0 - x);
        }
    }
    return GS_OK;
}

/* Fluorescent tube on a magnetic ballast (BULBS.md [L]/[D]): the UV output follows the lamp
 * current (lagging the voltage by 55-65 deg of the AC cycle), with a re-ignition bump and a
 * short dark gap after each current zero. Mercury lines are prompt and ~100 % modulated; each
 * phosphor is a first-order filter of the UV: blue fast, green (Tb) 2-5 ms, red (Eu) 1-1.5 ms.
 * Halophosphate: Sb3+ blue (fast) + Mn2+ orange with the green time range. */
static gs_status model_fluorescent_magnetic(const lamp *p, sim *s)
{
    double *e = s->tmp[0], *y = s->tmp[1];
    gs_status st = arc_drive(p, s, p->gamma, e);
    if (st != GS_OK) return st;
    add_light(s, 405, 1, 0.15 * p->w[0], e);
    add_light(s, 436, 1, 0.35 * p->w[0], e);
    add_light(s, 546, 1, 0.35 * p->w[0], e);
    add_light(s, 578, 1, 0.15 * p->w[0], e);
    if (p->spec->variant == V_HALO) {
        lowpass_periodic(e, y, s->M, s->dt, p->tau_blue_s);
        add_light(s, 480, 40, p->w[1], y);
        lowpass_periodic(e, y, s->M, s->dt, p->tau_green_s);
        add_light(s, 580, 35, p->w[2], y);
    } else {
        lowpass_periodic(e, y, s->M, s->dt, p->tau_blue_s);
        add_light(s, 450, 25, p->w[1], y);
        lowpass_periodic(e, y, s->M, s->dt, p->tau_green_s);
        add_light(s, 544, 6, p->w[2], y);
        lowpass_periodic(e, y, s->M, s->dt, p->tau_red_s);
        add_light(s, 611, 4, p->w[3], y);
    }
    return GS_OK;
}

/* The triphosphor light of a lamp whose UV output follows drive (mean-normalised inside). */
static void add_triphosphor(const lamp *p, sim *s, const double *drive, double *y)
{
    add_light(s, 436, 1, 0.5 * p->w[0], drive);
    add_light(s, 546, 1, 0.5 * p->w[0], drive);
    lowpass_periodic(drive, y, s->M, s->dt, p->tau_blue_s);
    add_light(s, 450, 25, p->w[1], y);
    lowpass_periodic(drive, y, s->M, s->dt, p->tau_green_s);
    add_light(s, 544, 6, p->w[2], y);
    lowpass_periodic(drive, y, s->M, s->dt, p->tau_red_s);
    add_light(s, 611, 4, p->w[3], y);
}

/* Fluorescent tube on an electronic ballast (BULBS.md: 1-10 %, bus ripple, sinusoid + harmonics
 * [L]). An active-PFC front end draws i_in ~ sin th + h3 sin 3th, so the bus capacitor integrates
 * p_in - P = V i_in - P; the lamp power follows the bus (linearised: 1 + delta). The kHz lamp
 * drive is not mains-locked and averages out. Phosphors filter the 2f ripple as in a tube. */
static gs_status model_fluorescent_electronic(const lamp *p, sim *s)
{
    double *d = s->tmp[0], *y = s->tmp[1];
    double acc = 0.0, h = PI / s->M;
    for (int j = 0; j < s->M; j++) {
        double th = (j + 0.5) * h, sn = sin(th);
        d[j] = acc;
        acc += h * (2.0 * sn * (sn + p->h3 * sin(3.0 * th)) - 1.0);   /* p_in / P - 1 */
    }
    double m = mean_of(d, s->M), amp = 0.0;
    for (int j = 0; j < s->M; j++) {
        d[j] -= m;
        if (fabs(d[j]) > amp) amp = fabs(d[j]);
    }
    for (int j = 0; j < s->M; j++) d[j] = 1.0 + 0.1 * d[j] / amp;   /* scaled later (depth) */
    add_triphosphor(p, s, d, y);
    return GS_OK;
}

/* CFL (BULBS.md: 5-30 % [L], sawtooth-like capacitor ripple, 2nd/1st ~0.24 [M]): bridge and
 * bulk capacitor feeding a half-bridge inverter (a resistive load, vf = 0); lamp power ~ v^2;
 * phosphors as in a tube. The capacitor (tau_d) is solved for the PF target. */
static gs_status model_cfl(const lamp *p, sim *s)
{
    double *v = s->tmp[0], *y = s->tmp[1];
    rectcap c = {2.0 * PI * s->f * p->tau_d_s, p->rho, 0.0};
    gs_status st = rc_run(&c, s->M, v);
    if (st != GS_OK) return st;
    for (int j = 0; j < s->M; j++) v[j] *= v[j];
    add_triphosphor(p, s, v, y);
    return GS_OK;
}

/* The white LED: blue die (450 nm) and YAG:Ce (fast, ~100 ns) follow the LED current; a KSF red
 * phosphor (tau ~8 ms [L/D]) smooths and lags its share. */
static void add_white_led(const lamp *p, sim *s, const double *cur, double *y)
{
    add_light(s, 450, 10, p->w[0], cur);
    add_light(s, 565, 50, 1.0 - p->w[0] - p->ksf_frac, cur);
    if (p->ksf_frac > 0.0) {
        lowpass_periodic(cur, y, s->M, s->dt, p->ksf_tau_s);
        add_light(s, 631, 3, p->ksf_frac, y);
    }
}

/* LED with a capacitor-filtered driver (BULBS.md: 1-40 % [M], asymmetric sawtooth, fast rise
 * near the voltage peak, slow decay, 2nd/1st 0.2-0.3 [M]): bridge and bulk capacitor feeding
 * an LED string of voltage vf through its resistance; light ~ LED current max(0, v - vf). */
static gs_status model_led_capacitor(const lamp *p, sim *s)
{
    double *v = s->tmp[0], *y = s->tmp[1];
    rectcap c = {2.0 * PI * s->f * p->tau_d_s, p->rho, p->vf};
    gs_status st = rc_run(&c, s->M, v);
    if (st != GS_OK) return st;
    for (int j = 0; j < s->M; j++) v[j] = v[j] > p->vf ? v[j] - p->vf : 0.0;
    add_white_led(p, s, v, y);
    return GS_OK;
}

/* LED on an unfiltered linear AC driver (BULBS.md [D]): dark while the rectified mains is below
 * the string voltage, i.e. for (2/pi) asin(Vf/Vpk) of the cycle (33/49/65 % for 0.5/0.7/0.85);
 * a k-tap driver lights segment t once |V| passes tap_v[t] (stair steps). The regulator's
 * headroom rounds each step over `edge` (in units of Vpk). */
static gs_status model_led_linear(const lamp *p, sim *s)
{
    double *L = s->tmp[0], *y = s->tmp[1];
    for (int j = 0; j < s->M; j++) {
        double x = sin(PI * j / s->M);
        L[j] = 0.0;
        for (int t = 0; t < p->spec->taps; t++)
            L[j] += p->tap_w[t] * 0.5 * erfc((p->tap_v[t] - x) / p->edge);
    }
    add_white_led(p, s, L, y);
    return GS_OK;
}

/* PWM-dimmed LED (BULBS.md: 100 % at 200 Hz-25 kHz, not mains-locked [M]; averages to a flat BRF
 * in an AC-locked capture [D]). The PWM averages to its duty cycle; what stays locked to the
 * mains is the driver's residual line ripple: its bulk-capacitor ripple (vf = 0) attenuated by
 * the current regulation, scaled to a PF of 0.15-0.5 %. Per-channel duty cycles set the colour of
 * RGBW fixtures; all channels share the ripple. */
static gs_status model_led_pwm(const lamp *p, sim *s)
{
    double *v = s->tmp[0];
    rectcap c = {2.0 * PI * s->f * p->tau_d_s, p->rho, 0.0};
    gs_status st = rc_run(&c, s->M, v);
    if (st != GS_OK) return st;
    if (p->spec->variant == V_RGBW) {
        add_light(s, 625, 9, p->w[1], v);
        add_light(s, 525, 15, p->w[2], v);
        add_light(s, 460, 10, p->w[3], v);
        add_light(s, 450, 10, p->w[4] * p->w[0], v);
        add_light(s, 565, 50, p->w[4] * (1.0 - p->w[0]), v);
    } else {
        add_light(s, 450, 10, p->w[0], v);
        add_light(s, 565, 50, 1.0 - p->w[0], v);
    }
    return GS_OK;
}

/* High-pressure sodium on a magnetic ballast (BULBS.md [L/D]): light ~ |i|^gamma (gamma
 * 1.2-1.5) with the ballast lag, a re-ignition spike and a 0.5-1.5 ms dark gap after each
 * current zero, filtered by a 0.1-0.5 ms afterglow. All lines share the shape; blue is weak. */
static gs_status model_sodium_hp(const lamp *p, sim *s)
{
    double *e = s->tmp[0], *y = s->tmp[1];
    gs_status st = arc_drive(p, s, p->gamma, e);
    if (st != GS_OK) return st;
    lowpass_periodic(e, y, s->M, s->dt, p->afterglow_s);
    add_light(s, 589, 15, p->w[0], y);
    add_light(s, 568, 3, p->w[1], y);
    add_light(s, 616, 3, p->w[2], y);
    add_light(s, 498, 3, p->w[3], y);
    add_light(s, 460, 30, p->w[4], y);
    return GS_OK;
}

/* Low-pressure sodium (BULBS.md: 80-100 %, re-ignition peaks [L]) on its high-reactance
 * (leakage) transformer, a series reactance like a choke: one 589 nm line, so every band has the
 * same shape and blue sees only its filter's leak (B ~ 0). */
static gs_status model_sodium_lp(const lamp *p, sim *s)
{
    double *e = s->tmp[0], *y = s->tmp[1];
    gs_status st = arc_drive(p, s, p->gamma, e);
    if (st != GS_OK) return st;
    lowpass_periodic(e, y, s->M, s->dt, p->afterglow_s);
    add_light(s, 589.3, 0.6, 1.0, y);
    return GS_OK;
}

/* Metal halide on a magnetic ballast (BULBS.md: 35-60 %, FI ~0.08, flux dips near current zero
 * but not to zero [L]; species respond differently [D]): each species s emits
 * LP_{tau_s}(|i|^gamma_s). The strong Na, Tl, In and Hg lines are optically thick and saturate
 * (gamma_s 0.3-0.8 < 1), so the flux stays up for most of the half-cycle and dips near current
 * zero; the continuum is linear (gamma 1) and slower. Short re-ignition gap, no spike. */
static gs_status model_metal_halide(const lamp *p, sim *s)
{
    double *cur = s->tmp[0], *e = s->tmp[1], *y = s->tmp[2];
    static const double nm[5] = {589, 535, 451, 0, 520}, sig[5] = {8, 2, 2, 0, 80};
    arc_model am = {p->arc_va, p->r_choke, 2.0 * PI * s->f * p->gap_s};
    gs_status st = arc_run(&am, s->M, cur, NULL, NULL);
    if (st != GS_OK) return st;
    for (int k = 0; k < 5; k++) {
        for (int j = 0; j < s->M; j++) e[j] = pow(fabs(cur[j]), p->sp_gamma[k]);
        lowpass_periodic(e, y, s->M, s->dt, p->sp_tau_s[k]);
        if (k == 3) {   /* mercury lines */
            add_light(s, 436, 1, 0.5 * p->w[3], y);
            add_light(s, 546, 1, 0.5 * p->w[3], y);
        } else {
            add_light(s, nm[k], sig[k], p->w[k], y);
        }
    }
    return GS_OK;
}

/* Mercury vapour on a magnetic ballast (BULBS.md: 50-65 % clear, 35-45 % coated [L]; blue/green
 * lines prompt and deep, red phosphor smoothed and lagged [D]): the lines follow the arc
 * (|i|^gamma, plasma afterglow); the coating's YVO4:Eu red phosphor filters the near-UV with the
 * Eu3+ time constant (1-1.5 ms, BULBS.md's fluorescent row). */
static gs_status model_mercury(const lamp *p, sim *s)
{
    double *e = s->tmp[0], *y = s->tmp[1], *z = s->tmp[2];
    gs_status st = arc_drive(p, s, p->gamma, e);
    if (st != GS_OK) return st;
    lowpass_periodic(e, y, s->M, s->dt, p->afterglow_s);
    add_light(s, 405, 1, p->w[0], y);
    add_light(s, 436, 1, p->w[1], y);
    add_light(s, 546, 1, p->w[2], y);
    add_light(s, 578, 1.5, p->w[3], y);
    add_light(s, 620, 40, p->w[4], y);
    if (p->w[5] > 0.0) {
        lowpass_periodic(y, z, s->M, s->dt, p->tau_red_s);
        add_light(s, 619, 4, p->w[5], z);
    }
    return GS_OK;
}

static gs_status run_model(const lamp *p, sim *s)
{
    for (int b = 0; b < 3; b++) memset(s->band[b], 0, sizeof(double) * (size_t)s->M);
    switch (p->spec->tech) {
    case GS_TECH_INCANDESCENT:
    case GS_TECH_HALOGEN: return model_filament(p, s);
    case GS_TECH_FLUORESCENT_MAGNETIC: return model_fluorescent_magnetic(p, s);
    case GS_TECH_FLUORESCENT_ELECTRONIC: return model_fluorescent_electronic(p, s);
    case GS_TECH_CFL: return model_cfl(p, s);
    case GS_TECH_LED_CAPACITOR: return model_led_capacitor(p, s);
    case GS_TECH_LED_LINEAR: return model_led_linear(p, s);
    case GS_TECH_LED_PWM: return model_led_pwm(p, s);
    case GS_TECH_SODIUM_HP: return model_sodium_hp(p, s);
    case GS_TECH_SODIUM_LP: return model_sodium_lp(p, s);
    case GS_TECH_METAL_HALIDE: return model_metal_halide(p, s);
    case GS_TECH_MERCURY: return model_mercury(p, s);
    default: break;
    }
    return gs_fail(GS_EINVAL, "DELIGHT model: bulb %s has no model", p->spec->id);
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
    gs_status st = run_model(c->p, c->s);
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
        if (!solve_root(lag_error, &c, 0.05, 1.30, 1e-12, 1e-9, &va) || c.err != GS_OK)
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
        if (!solve_root(knob_error, &c, lo, hi, 1e-12, 1e-9, &k) || c.err != GS_OK)
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
        mean[b] = mean_of(s->band[b], s->M);
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
            st = run_model(&p, &s);
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
