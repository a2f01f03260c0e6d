/* effects.c - the simulator's effects, one stage each (docs/capture.md has the physics and the
 * sources of every constant). A stage exists in a simulator's pipeline only when its scene lists
 * the effect (the pipeline counts its calls: cap_sim_effect_calls). The row stages (the image's
 * rows from the same rows) run together over cached blocks of rows (cap_rows_run). */
#include "capture/sim.h"

#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------------------ timing */

/* The grid follows the scene's frequency model: the timeline (cap_ac) was built from it when
 * the simulator was; windows re-anchor (locked) or drift (free running) against it. */
gs_status cap_fx_frequency_wander(cap_sim *s, cap_render *r)
{
    r->timing = 1;
    r->items = (unsigned long long)s->C;
    return GS_OK;
}

/* The free-running controller's clock error: its period is off by clock_ppm. */
gs_status cap_fx_free_running_drift(cap_sim *s, cap_render *r)
{
    r->timing = 1;
    r->wcfg.clock_ppm = s->sc.fx.drift.clock_ppm;
    r->items = (unsigned long long)s->C;
    return GS_OK;
}

/* Each window edge lands sigma_us (Gaussian) from where it should: DMD switching and the
 * controller's interrupt latency. */
gs_status cap_fx_dmd_jitter(cap_sim *s, cap_render *r)
{
    r->timing = 1;
    r->wcfg.jitter_us = s->sc.fx.jitter.sigma_us;
    r->items = (unsigned long long)s->C;
    return GS_OK;
}

/* ------------------------------------------------------------------ extinction */

/* Koschmieder: beta(550 nm) = 3.912 / visibility; Angstrom: beta(lambda) = beta(550)
 * (lambda / 550)^-alpha; transmission exp(-beta d) per band (shared/BULBS.md). */
gs_status cap_fx_prepare_extinction(cap_sim *s)
{
    s->trans = malloc(sizeof *s->trans * (s->n ? s->n : 1) * (size_t)s->B);
    if (!s->trans) return gs_fail(GS_ENOMEM, "extinction: out of memory");
    const cap_effects *fx = &s->sc.fx;
    double beta550 = 3.912 / fx->extinction.visibility_km;   /* per km */
    for (size_t l = 0; l < s->n; l++) {
        double d_km = s->sc.lights[l].distance_m * 1e-3;
        for (int b = 0; b < s->B; b++) {
            double beta = beta550 * pow(fx->extinction.wavelength_nm[b] / 550.0, -fx->extinction.angstrom);
            s->trans[l * (size_t)s->B + (size_t)b] = exp(-beta * d_km);
        }
    }
    return GS_OK;
}

gs_status cap_fx_extinction(cap_sim *s, cap_render *r)
{
    int B = s->B, L = s->L;
    for (size_t l = 0; l < s->n; l++)
        for (int h = 0; h < L; h++)
            for (int b = 0; b < B; b++)
                s->E[(l * (size_t)L + (size_t)h) * (size_t)B + (size_t)b] *= s->trans[l * (size_t)B + (size_t)b];
    r->items = s->n;
    return GS_OK;
}

/* ------------------------------------------------------------------ scintillation */

double cap_scintillation_index(const cap_effects *fx, double aperture_mm, double L)
{
    if (!(L > 0)) return 0.0;   /* distance unknown: the light is skipped (docs/scene.md) */
    if (fx->scint.sigma2 >= 0) return fx->scint.sigma2;
    if (!(fx->scint.cn2 > 0)) return 0.0;
    double lambda = fx->scint.wavelength_nm * 1e-9, k = 2.0 * M_PI / lambda;
    /* spherical-wave Rytov variance (Andrews and Phillips, Laser Beam Propagation through
     * Random Media, 2nd ed., SPIE 2005, Eq. 8.xx): beta0^2 = 0.5 Cn^2 k^(7/6) L^(11/6) */
    double b2 = 0.5 * fx->scint.cn2 * pow(k, 7.0 / 6.0) * pow(L, 11.0 / 6.0);
    double b125 = pow(b2, 1.2);
    /* weak to strong fluctuations (the same book, point source): saturates near 1.6 at 5 km */
    double s2 = exp(0.49 * b2 / pow(1.0 + 0.56 * b125, 7.0 / 6.0) +
                    0.51 * b2 / pow(1.0 + 0.69 * b125, 5.0 / 6.0)) - 1.0;
    if (fx->scint.aperture && aperture_mm > 0) {
        double D = aperture_mm * 1e-3;
        s2 /= 1.0 + 0.33 * pow(k * D * D / (4.0 * L), 7.0 / 6.0);
    }
    if (fx->scint.source_size_m > 0) {
        double rho_f = sqrt(lambda * L);   /* Fresnel scale: 2.3 cm at 1 km */
        double q = fx->scint.source_size_m / rho_f;
        s2 /= pow(1.0 + q * q, 7.0 / 6.0);
    }
    return s2;
}

gs_status cap_fx_prepare_scintillation(cap_sim *s)
{
    s->scint_s2 = malloc(sizeof *s->scint_s2 * (s->n ? s->n : 1));
    s->scint_rho = malloc(sizeof *s->scint_rho * (s->n ? s->n : 1));
    if (!s->scint_s2 || !s->scint_rho) return gs_fail(GS_ENOMEM, "scintillation: out of memory");
    const cap_effects *fx = &s->sc.fx;
    for (size_t l = 0; l < s->n; l++) {
        double L = s->sc.lights[l].distance_m;
        double si = cap_scintillation_index(fx, s->sc.aperture_mm, L);
        s->scint_s2[l] = log1p(si);   /* log-normal: var(I) / <I>^2 = e^{s2} - 1 */
        /* spectrum flat to v / rho_F, then falling: a first-order process with that corner,
         * sampled once per flicker cycle (the windows are far shorter than 1 / corner) */
        double rho_f = L > 0 ? sqrt(fx->scint.wavelength_nm * 1e-9 * L) : 1.0;
        double fc = fx->scint.crosswind_m_s / rho_f;
        s->scint_rho[l] = exp(-2.0 * M_PI * fc * s->half_s);
    }
    return GS_OK;
}

/* Lights [l0, l1), each with its own stream and its own rows of E. */
static gs_status scint_lights(void *ctx, int part, size_t l0, size_t l1)
{
    cap_par *par = ctx;
    cap_sim *s = par->s;
    const cap_render *r = par->r;
    int B = s->B, L = s->L;
    long C = s->C;
    double *scin = s->scin + (size_t)part * (size_t)C;
    unsigned long long items = 0;
    for (size_t l = l0; l < l1; l++) {
        double s2 = s->scint_s2[l];
        if (!(s2 > 0) || !s->fp[l].w) continue;
        gs_rng rng;
        gs_rng_init(&rng, s->sc.seed, CAP_TAG_SCINT, ((uint64_t)r->k << 32) | (uint64_t)r->pass, l);
        double sd = sqrt(s2), rho = s->scint_rho[l], innov = sd * sqrt(1.0 - rho * rho);
        double x = sd * gs_rng_normal(&rng);
        for (long c = 0; c < C; c++) {
            if (c) x = rho * x + innov * gs_rng_normal(&rng);
            scin[c] = exp(x - 0.5 * s2);
        }
        items += (unsigned long long)C;
        double *E = s->E + l * (size_t)L * (size_t)B;
        if (!s->wcyc) {
            /* exact windows: every cycle of a level weighs the same */
            double S[CAP_MAX_LEVELS] = {0};
            for (long c = 0; c < C; c++) S[r->lev[c]] += scin[c];
            for (int h = L - 2; h >= 0; h--) S[h] += S[h + 1];
            for (int h = 0; h < L; h++) {
                double f = r->n_exposed[h] ? S[h] / (double)r->n_exposed[h] : 0.0;
                for (int b = 0; b < B; b++) E[h * B + b] *= f;
            }
        } else {
            size_t sp = (size_t)s->species[l];
            for (int b = 0; b < B; b++) {
                const double *w = s->wcyc + (sp * (size_t)B + (size_t)b) * (size_t)C;
                double S[CAP_MAX_LEVELS] = {0};
                for (long c = 0; c < C; c++) S[r->lev[c]] += scin[c] * w[c];
                for (int h = L - 2; h >= 0; h--) S[h] += S[h + 1];
                for (int h = 0; h < L; h++) {
                    double Wt = s->Wsp[(sp * (size_t)L + (size_t)h) * (size_t)B + (size_t)b];
                    E[h * B + b] *= Wt != 0 ? S[h] / Wt : 0.0;
                }
            }
        }
    }
    par->items[part] += items;
    return GS_OK;
}

gs_status cap_fx_scintillation(cap_sim *s, cap_render *r)
{
    return cap_par_run(s, r, s->n, scint_lights);
}

/* ------------------------------------------------------------------ PSF */

/* A Gaussian integrated over each pixel, truncated at radius_sigma sigmas and renormalised so
 * the light's flux is kept (the psf stage, cap_splat_rows, deposits through it). */
gs_status cap_fx_prepare_psf(cap_sim *s)
{
    double sigma = s->sc.fx.psf.sigma_px;
    int R = (int)ceil(s->sc.fx.psf.radius_sigma * sigma);
    if (R > 64) R = 64;
    int n = 2 * R + 1;
    s->fp = calloc(s->n ? s->n : 1, sizeof *s->fp);
    s->fp_w = malloc(sizeof *s->fp_w * (s->n ? s->n : 1) * (size_t)n * (size_t)n);
    double *box = malloc(sizeof *box * (size_t)n * (size_t)n);
    if (!s->fp || !s->fp_w || !box) {
        free(box);
        return gs_fail(GS_ENOMEM, "psf: out of memory");
    }
    size_t off = 0;
    for (size_t l = 0; l < s->n; l++) {
        const cap_light *li = &s->sc.lights[l];
        if (!isfinite(li->x_px) || !isfinite(li->y_px) || li->x_px < -R - 1 ||
            li->y_px < -R - 1 || li->x_px > s->W + R || li->y_px > s->H + R)
            continue;
        int bx, by;
        cap_gauss_box(li->x_px, li->y_px, sigma, R, box, &bx, &by);
        int x0 = bx < 0 ? 0 : bx, y0 = by < 0 ? 0 : by;
        int x1 = bx + n > s->W ? s->W : bx + n, y1 = by + n > s->H ? s->H : by + n;
        if (x1 <= x0 || y1 <= y0) continue;
        cap_footprint *f = &s->fp[l];
        f->x0 = x0;
        f->y0 = y0;
        f->w = x1 - x0;
        f->h = y1 - y0;
        f->off = off;
        for (int y = y0; y < y1; y++)
            for (int x = x0; x < x1; x++) s->fp_w[off++] = box[(y - by) * n + (x - bx)];
    }
    free(box);
    s->fp_n = off;
    return GS_OK;
}

/* ------------------------------------------------------------------ skyglow */

/* Forward scattering and glare: a halo of `fraction` of each light's flux, exp(-r / scale),
 * truncated at radius_scale scales and normalised; flat (no flicker), the same flicker as the
 * light, or mixed (the light's bulb averaged over the three grid phases). */
gs_status cap_fx_prepare_skyglow(cap_sim *s)
{
    double scale = s->sc.fx.skyglow.scale_px;
    int R = (int)ceil(s->sc.fx.skyglow.radius_scale * scale);
    if (R > 256) R = 256;
    int n = 2 * R + 1;
    s->glow_r = R;
    s->glow_k = malloc(sizeof *s->glow_k * (size_t)n * (size_t)n);
    if (!s->glow_k) return gs_fail(GS_ENOMEM, "skyglow: out of memory");
    double sum = 0;
    for (int y = -R; y <= R; y++)
        for (int x = -R; x <= R; x++) {
            double r = sqrt((double)(x * x + y * y));
            double v = r <= R ? exp(-r / scale) : 0.0;
            s->glow_k[(y + R) * n + (x + R)] = v;
            sum += v;
        }
    for (int i = 0; i < n * n; i++) s->glow_k[i] /= sum;
    return GS_OK;
}

/* The halo kernel at offset (i, j) from its corner, 0 outside it. */
static double glow_at(const cap_sim *s, int n, int i, int j)
{
    return i >= 0 && i < n && j >= 0 && j < n ? s->glow_k[i * n + j] : 0.0;
}

/* Rows [ya, yb) of every light's halo, the lights in scene order. The kernel is centred on the
 * light's own position, not on its pixel: spread bilinearly over the four pixel centres around
 * it (pixel i's centre at coordinate i), which keeps its flux and puts its centroid exactly at
 * the light (a halo centred on the nearest pixel pulled the light's centroid by up to half a
 * pixel times the halo's fraction). */
static gs_status skyglow_rows(void *ctx, int part, size_t ya, size_t yb)
{
    cap_par *par = ctx;
    cap_sim *s = par->s;
    const cap_render *r = par->r;
    int B = s->B, L = s->L, R = s->glow_r, n = 2 * R + 1;
    double frac = s->sc.fx.skyglow.fraction;
    int mode = s->sc.fx.skyglow.flicker;
    unsigned long long items = 0;
    double g[CAP_MAX_LEVELS * GS_MAX_BANDS];
    for (size_t l = 0; l < s->n; l++) {
        const cap_light *li = &s->sc.lights[l];
        double bx = floor(li->x_px), by = floor(li->y_px);
        if (!isfinite(bx) || !isfinite(by) || bx < -R - 1 || by < -R - 1 || bx >= s->W + R || by >= s->H + R)
            continue;
        double fx = li->x_px - bx, fy = li->y_px - by;
        int x0 = (int)bx - R, y0 = (int)by - R;   /* the support: n + 1 pixels from x0, y0 */
        int y_lo = y0 < (int)ya ? (int)ya : y0, y_hi = y0 + n + 1 < (int)yb ? y0 + n + 1 : (int)yb;
        if (y_lo >= y_hi) continue;
        for (int h = 0; h < L; h++)
            for (int b = 0; b < B; b++) {
                double t = s->trans ? s->trans[l * (size_t)B + (size_t)b] : 1.0;
                double f = s->flux[l * (size_t)B + (size_t)b];
                double v;
                if (mode == CAP_GLOW_SAME) v = s->E[(l * (size_t)L + (size_t)h) * (size_t)B + (size_t)b];
                else if (mode == CAP_GLOW_MIXED) {
                    double w = 0;
                    for (int j = 0; j < 3; j++)
                        w += s->Wsp[((size_t)s->glow_sp[l * 3 + (size_t)j] * (size_t)L + (size_t)h) * (size_t)B + (size_t)b];
                    v = f * t * w / 3.0;
                } else v = f * t * r->ex[h];
                g[h * B + b] = frac * v;
            }
        for (int y = y_lo; y < y_hi; y++)
            for (int x = x0 < 0 ? 0 : x0; x < x0 + n + 1 && x < s->W; x++) {
                size_t p = (size_t)y * (size_t)s->W + (size_t)x;
                int i = y - y0, j = x - x0;
                double k = (1.0 - fy) * ((1.0 - fx) * glow_at(s, n, i, j) + fx * glow_at(s, n, i, j - 1)) +
                           fy * ((1.0 - fx) * glow_at(s, n, i - 1, j) + fx * glow_at(s, n, i - 1, j - 1));
                int h = r->halv ? r->halv[p] : 0;
                for (int b = 0; b < B; b++) s->img[p * (size_t)B + (size_t)b] += k * g[h * B + b];
                items++;
            }
    }
    par->items[part] += items;
    return GS_OK;
}

/* ------------------------------------------------------------------ distractors */

/* Signs blinking at their own period (not mains-locked): on during [phase, phase + duty P)
 * modulo P, sampled at the middle of each exposed window. */
gs_status cap_fx_blinking_sign(cap_sim *s, cap_render *r)
{
    int B = s->B, L = s->L;
    unsigned long long items = 0;
    for (size_t i = 0; i < s->sc.fx.signs.count; i++) {
        const cap_sign *g = &s->sc.fx.signs.items[i];
        double on[CAP_MAX_LEVELS] = {0};
        for (long c = 0; c < s->C; c++) {
            double t0, t1;
            cap_cycle_time(s, r, c, &t0, &t1);
            double ph = fmod(0.5 * (t0 + t1) - g->phase_s, g->period_s);
            if (ph < 0) ph += g->period_s;
            if (ph < g->duty * g->period_s) on[r->lev[c]] += (t1 - t0) / s->half_s;
        }
        for (int h = L - 2; h >= 0; h--) on[h] += on[h + 1];
        int x0 = (int)floor(g->x_px), y0 = (int)floor(g->y_px);
        int w = (int)ceil(g->width_px), hgt = (int)ceil(g->height_px);
        double per_px = g->flux_e_per_cycle / ((double)w * hgt);
        for (int y = y0 < 0 ? 0 : y0; y < y0 + hgt && y < s->H; y++)
            for (int x = x0 < 0 ? 0 : x0; x < x0 + w && x < s->W; x++) {
                size_t p = (size_t)y * (size_t)s->W + (size_t)x;
                int h = r->halv ? r->halv[p] : 0;
                for (int b = 0; b < B; b++)
                    s->img[p * (size_t)B + (size_t)b] += per_px * g->chroma[b] * on[h];
                items++;
            }
        items += (unsigned long long)s->C;
    }
    r->items = items;
    return GS_OK;
}

/* Cars driving along a path at constant speed, a new one every period_s: during each exposed
 * window a car is a point at its position then (through the PSF when the scene has one). */
gs_status cap_fx_headlights(cap_sim *s, cap_render *r)
{
    int B = s->B;
    int psf = (s->fx >> CAP_FX_PSF) & 1u;
    double sigma = psf ? s->sc.fx.psf.sigma_px : 0;
    int R = psf ? (int)ceil(s->sc.fx.psf.radius_sigma * sigma) : 0;
    if (R > 64) R = 64;
    int n = 2 * R + 1;
    double *box = malloc(sizeof *box * (size_t)n * (size_t)n);
    if (!box) return gs_fail(GS_ENOMEM, "headlights: out of memory");
    unsigned long long items = 0;
    for (size_t i = 0; i < s->sc.fx.cars.count; i++) {
        const cap_car *g = &s->sc.fx.cars.items[i];
        double dx = g->x1_px - g->x0_px, dy = g->y1_px - g->y0_px;
        double len = sqrt(dx * dx + dy * dy);
        for (long c = 0; c < s->C; c++) {
            double t0, t1;
            cap_cycle_time(s, r, c, &t0, &t1);
            double u = fmod(0.5 * (t0 + t1) - g->offset_s, g->period_s);
            if (u < 0) u += g->period_s;
            double pos = u * g->speed_px_s;
            if (pos > len) continue;
            double x = g->x0_px + (len > 0 ? dx * pos / len : 0);
            double y = g->y0_px + (len > 0 ? dy * pos / len : 0);
            double e = g->flux_e_per_cycle * (t1 - t0) / s->half_s;
            int lev = r->lev[c], bx, by;
            if (psf) cap_gauss_box(x, y, sigma, R, box, &bx, &by);
            else {
                bx = (int)floor(x + 0.5);
                by = (int)floor(y + 0.5);
                box[0] = 1.0;
            }
            for (int yy = 0; yy < n; yy++) {
                int py = by + yy;
                if (py < 0 || py >= s->H) continue;
                for (int xx = 0; xx < n; xx++) {
                    int px = bx + xx;
                    if (px < 0 || px >= s->W) continue;
                    size_t p = (size_t)py * (size_t)s->W + (size_t)px;
                    if (r->halv && r->halv[p] > lev) continue;
                    double wgt = box[yy * n + xx] * e;
                    for (int b = 0; b < B; b++) s->img[p * (size_t)B + (size_t)b] += wgt * g->chroma[b];
                    items++;
                }
            }
        }
    }
    free(box);
    r->items = items;
    return GS_OK;
}

/* ------------------------------------------------------------------ ambient */

/* Daylight or room light: a pedestal with BRF = 1 (paper Sec. 5.3), e_per_px_cycle per pixel
 * and flicker cycle, scaled linearly from `top` (row 0) to `bottom` (last row). */
static gs_status ambient_rows(void *ctx, int part, size_t y0, size_t y1)
{
    cap_par *par = ctx;
    cap_sim *s = par->s;
    const cap_render *r = par->r;
    const cap_effects *fx = &s->sc.fx;
    int B = s->B;
    for (int y = (int)y0; y < (int)y1; y++) {
        double g = s->H > 1 ? fx->ambient.top + (fx->ambient.bottom - fx->ambient.top) * y / (s->H - 1.0)
                            : fx->ambient.top;
        double lvl = fx->ambient.e_per_px_cycle * g;
        s->amb_row[y] = lvl;
        for (int x = 0; x < s->W; x++) {
            size_t p = (size_t)y * (size_t)s->W + (size_t)x;
            double e = lvl * r->ex[r->halv ? r->halv[p] : 0];
            for (int b = 0; b < B; b++) s->img[p * (size_t)B + (size_t)b] += e * fx->ambient.chroma[b];
        }
    }
    par->items[part] += (unsigned long long)s->W * (unsigned long long)(y1 - y0);
    return GS_OK;
}

/* ------------------------------------------------------------------ sensor */

/* Photo-electrons are Poisson (one stream per row, so a frame renders the same in any order).
 * A Poisson count of mean a + b is the sum of independent counts of means a and b, which this
 * uses for speed without leaving the law: the ambient pedestal (the same mean along a row, per
 * band and halving level) is drawn by inversion from a cached CDF, the rest (lights, halos,
 * distractors) separately; either below CAP_POISSON_INVERT by inversion (the rest with the bound
 * e^-x >= 1 - x deciding most zeros without an exponential), above by Hormann's PTRS. */
#define CAP_POISSON_INVERT 40.0
enum { CAP_POISSON_CDF = 160 };   /* reaches 1 - 1e-16 for means below CAP_POISSON_INVERT */

enum { CAP_POISSON_GUIDE = 128 };   /* about one CDF step per draw after the guide */

typedef struct {
    double lam;
    int n;
    double cdf[CAP_POISSON_CDF];
    int guide[CAP_POISSON_GUIDE];   /* the first k with cdf[k] >= g / CAP_POISSON_GUIDE (or n - 1) */
} poisson_cache;

static double poisson_cached(poisson_cache *pc, gs_rng *rng, double lam)
{
    if (lam >= CAP_POISSON_INVERT) return gs_rng_poisson(rng, lam);   /* beyond the table */
    if (lam != pc->lam) {
        double p = exp(-lam), F = p;
        int k = 0;
        for (; k < CAP_POISSON_CDF; k++) {
            pc->cdf[k] = F;
            if (F >= 1.0) break;
            p *= lam / (k + 1);
            F += p;
        }
        pc->n = k < CAP_POISSON_CDF ? k + 1 : CAP_POISSON_CDF;
        pc->lam = lam;
        for (int g = 0, j = 0; g < CAP_POISSON_GUIDE; g++) {
            while (j < pc->n - 1 && pc->cdf[j] < (double)g / CAP_POISSON_GUIDE) j++;
            pc->guide[g] = j;
        }
    }
    /* the first k with u <= cdf[k]: every k below the guide's has cdf[k] < g / GUIDE <= u */
    double u = gs_rng_uniform(rng);
    int k = pc->guide[(int)(u * CAP_POISSON_GUIDE)];
    while (k < pc->n - 1 && u > pc->cdf[k]) k++;
    return k;
}

static double poisson_rest(gs_rng *rng, double lam)
{
    if (!(lam > 0)) return 0;
    if (lam >= CAP_POISSON_INVERT) return gs_rng_poisson(rng, lam);
    double u = gs_rng_uniform(rng);
    if (u <= 1.0 - lam) return 0;   /* u <= 1 - lam <= e^-lam */
    double p = exp(-lam), F = p;
    int k = 0;
    while (u > F && k < 400) {
        k++;
        p *= lam / k;
        F += p;
    }
    return k;
}

/* The samples of rows [y0, y1) a stage renders: every row, or a probe's (cap_render.rows). */
static unsigned long long rendered(const cap_sim *s, const cap_render *r, size_t y0, size_t y1)
{
    size_t n = 0;
    for (size_t y = y0; y < y1; y++) n += !r->rows || r->rows[y];
    return (unsigned long long)n * (unsigned long long)s->W * (unsigned long long)s->B;
}

/* Rows [y0, y1); the CDF cache is the part's own (a pure memo of lam: any split draws the same). */
static gs_status shot_rows(void *ctx, int part, size_t y0, size_t y1)
{
    cap_par *par = ctx;
    cap_sim *s = par->s;
    const cap_render *r = par->r;
    int B = s->B, L = s->L;
    size_t row = (size_t)s->W * (size_t)B;
    poisson_cache *pc = malloc(sizeof *pc * (size_t)B * (size_t)L);
    if (!pc) return gs_fail(GS_ENOMEM, "shot noise: out of memory");
    for (int i = 0; i < B * L; i++) pc[i].lam = -1;
    int amb = (s->fx >> CAP_FX_AMBIENT) & 1u;
    for (int y = (int)y0; y < (int)y1; y++) {
        if (r->rows && !r->rows[y]) continue;   /* a probe's row that cannot saturate */
        gs_rng rng;
        gs_rng_init(&rng, s->sc.seed, CAP_TAG_SHOT, ((uint64_t)r->k << 32) | (uint64_t)r->pass, (uint64_t)y);
        double *v = s->img + (size_t)y * row;
        double base_row = amb ? s->amb_row[y] : 0.0;
        for (int x = 0; x < s->W; x++) {
            int h = r->halv ? r->halv[(size_t)y * (size_t)s->W + (size_t)x] : 0;
            for (int b = 0; b < B; b++) {
                double *px = &v[(size_t)x * (size_t)B + (size_t)b];
                double lam = *px;
                if (!(lam > 0)) continue;
                double base = base_row * s->sc.fx.ambient.chroma[b] * r->ex[h];
                if (base > lam) base = lam;
                double n = base > 0 ? poisson_cached(&pc[h * B + b], &rng, base) : 0.0;
                *px = n + poisson_rest(&rng, lam - base);
            }
        }
    }
    free(pc);
    par->items[part] += rendered(s, r, y0, y1);
    return GS_OK;
}

/* The pixel's well holds full_well_e electrons at most. */
GS_VECTOR_LOOP
static gs_status saturation_rows(void *ctx, int part, size_t y0, size_t y1)
{
    cap_par *par = ctx;
    cap_sim *s = par->s;
    const cap_render *r = par->r;
    size_t row = (size_t)s->W * (size_t)s->B;
    double fw = s->sc.full_well_e;
    for (size_t y = y0; y < y1; y++) {
        if (r->rows && !r->rows[y]) continue;
        double *v = s->img + y * row;
        for (size_t i = 0; i < row; i++) v[i] = v[i] > fw ? fw : v[i];
    }
    par->items[part] += rendered(s, r, y0, y1);
    return GS_OK;
}

/* Gaussian read noise, sigma_e / gain DN per sample (one stream per row). */
static gs_status read_rows(void *ctx, int part, size_t y0, size_t y1)
{
    cap_par *par = ctx;
    cap_sim *s = par->s;
    const cap_render *r = par->r;
    size_t row = (size_t)s->W * (size_t)s->B;
    double sd = s->read_dn;
    for (size_t y = y0; y < y1; y++) {
        if (r->rows && !r->rows[y]) continue;
        gs_rng rng;
        gs_rng_init(&rng, s->sc.seed, CAP_TAG_READ, ((uint64_t)r->k << 32) | (uint64_t)r->pass, (uint64_t)y);
        double *v = s->img + y * row;
        for (size_t i = 0; i < row; i++) v[i] += sd * gs_rng_normal(&rng);
    }
    par->items[part] += rendered(s, r, y0, y1);
    return GS_OK;
}

/* The ADC: integer DN (round half up), clipped to 0 .. 2^bit_depth - 1. */
GS_VECTOR_LOOP
static gs_status adc_rows(void *ctx, int part, size_t y0, size_t y1)
{
    cap_par *par = ctx;
    cap_sim *s = par->s;
    const cap_render *r = par->r;
    size_t row = (size_t)s->W * (size_t)s->B;
    double mx = s->adc_max;
    for (size_t y = y0; y < y1; y++) {
        if (r->rows && !r->rows[y]) continue;
        double *img = s->img + y * row;
        for (size_t i = 0; i < row; i++) {
            double v = floor(img[i] + 0.5);
            img[i] = v < 0 ? 0 : v > mx ? mx : v;
        }
    }
    par->items[part] += rendered(s, r, y0, y1);
    return GS_OK;
}

/* ------------------------------------------------------------------ the table */

/* The one list of effects, in pipeline order: name in scene files, parameters, once-per-sim
 * preparation, per-acquisition stage (the whole frame, or a row stage). */
const cap_effect_def cap_effect_defs[CAP_FX_COUNT] = {
    [CAP_FX_FREQUENCY_WANDER] = {"frequency_wander", cap_fxp_none, NULL, cap_fx_frequency_wander, NULL},
    [CAP_FX_FREE_RUNNING_DRIFT] = {"free_running_drift", cap_fxp_free_running_drift, NULL,
                                   cap_fx_free_running_drift, NULL},
    [CAP_FX_DMD_JITTER] = {"dmd_jitter", cap_fxp_dmd_jitter, NULL, cap_fx_dmd_jitter, NULL},
    [CAP_FX_EXTINCTION] = {"extinction", cap_fxp_extinction, cap_fx_prepare_extinction,
                           cap_fx_extinction, NULL},
    [CAP_FX_SCINTILLATION] = {"scintillation", cap_fxp_scintillation,
                              cap_fx_prepare_scintillation, cap_fx_scintillation, NULL},
    [CAP_FX_PSF] = {"psf", cap_fxp_psf, cap_fx_prepare_psf, NULL, cap_splat_rows},
    [CAP_FX_LIGHT_TRANSPORT] = {"light_transport", cap_fxp_light_transport,
                                cap_fx_prepare_light_transport, cap_fx_light_transport, NULL},
    [CAP_FX_SKYGLOW] = {"skyglow", cap_fxp_skyglow, cap_fx_prepare_skyglow, NULL, skyglow_rows},
    [CAP_FX_BLINKING_SIGN] = {"blinking_sign", cap_fxp_blinking_sign, NULL, cap_fx_blinking_sign, NULL},
    [CAP_FX_HEADLIGHTS] = {"headlights", cap_fxp_headlights, NULL, cap_fx_headlights, NULL},
    [CAP_FX_AMBIENT] = {"ambient", cap_fxp_ambient, NULL, NULL, ambient_rows},
    [CAP_FX_SEMI_REFLECTION] = {"semi_reflection", cap_fxp_semi_reflection,
                                cap_fx_prepare_semi_reflection, cap_fx_semi_reflection, NULL},
    [CAP_FX_SHOT_NOISE] = {"shot_noise", cap_fxp_none, NULL, NULL, shot_rows},
    [CAP_FX_SATURATION] = {"saturation", cap_fxp_none, NULL, NULL, saturation_rows},
    [CAP_FX_READ_NOISE] = {"read_noise", cap_fxp_read_noise, NULL, NULL, read_rows},
    [CAP_FX_ADC] = {"adc", cap_fxp_none, NULL, NULL, adc_rows},
};

const char *cap_effect_name(cap_effect e)
{
    return (int)e >= 0 && e < CAP_FX_COUNT ? cap_effect_defs[e].name : NULL;
}

gs_status cap_effect_parse(const char *name, cap_effect *e)
{
    for (int i = 0; i < CAP_FX_COUNT; i++)
        if (!strcmp(name, cap_effect_defs[i].name)) {
            *e = (cap_effect)i;
            return GS_OK;
        }
    return gs_fail(GS_ENOTFOUND, "unknown effect '%s'", name);
}
