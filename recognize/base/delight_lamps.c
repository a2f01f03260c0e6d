/* delight_lamps.c - the lamp physics behind the DELIGHT substitute (docs/delight-models.md,
 * shared/BULBS.md): the camera's band responses, the per-cycle simulation grid, the discharge lamp
 * on a series choke, rectifier + capacitor drivers, and one model per technology. delight_model.c
 * draws each bulb's parameters, solves its depth and reduces the result to a BRF. */
#include "recognize/base/internal.h"
#include <fftw3.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

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
void dm_planck_bands(double T, double resp[3], double m[3])
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



/* Add one spectral component: weight is its share of the emitted power, shape its temporal
 * waveform (any scale; it is normalised to mean 1 here). */
static void add_light(sim *s, double nm, double sigma_nm, double weight, const double *shape)
{
    double resp[3];
    line_response(nm, sigma_nm, resp);
    double k = weight / dm_mean_of(shape, s->M);
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
int dm_solve_root(root_fn f, void *ctx, double lo, double hi, double xtol, double ftol,
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


double dm_lag_error(double va, void *vctx)
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
    int ok = dm_solve_root(rc_residual, &x, c->vf, 1.0, 1e-15, 1e-14, &v0);
    if (ok) rc_cycle(c, sn, M, v0, v_out);
    free(sn);
    if (!ok)
        return gs_fail(GS_ENUMERIC, "DELIGHT model: rectifier (tau=%g rad, rho=%g, vf=%g) has no "
                       "steady state", c->tau_rad, c->rho, c->vf);
    return GS_OK;
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
    double m = dm_mean_of(d, s->M), amp = 0.0;
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

gs_status dm_run_model(const lamp *p, sim *s)
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

