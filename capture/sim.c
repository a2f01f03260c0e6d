/* sim.c - the scene simulator: builds, once per scene, the per-light tables and a pipeline of
 * stages holding exactly the effects the scene lists (docs/capture.md), then renders each
 * acquisition through it. Without effects a frame is the exact Eq. 5 integral through the
 * mask matrix (acam.c): value = C/2^h * Q(sigma) * i_k(sigma) * flux / K per light. */
#include "capture/sim.h"

#include <jansson.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static gs_status scene_copy(cap_scene *dst, const cap_scene *src)
{
    *dst = *src;
    dst->lights = NULL;
    dst->fx.signs.items = NULL;
    dst->fx.cars.items = NULL;
    dst->fx.transport.boxes = NULL;
    if (src->fx.transport.n_boxes) {
        size_t nb = src->fx.transport.n_boxes * sizeof *dst->fx.transport.boxes;
        dst->fx.transport.boxes = malloc(nb);
        if (!dst->fx.transport.boxes) return gs_fail(GS_ENOMEM, "simulator: out of memory");
        memcpy(dst->fx.transport.boxes, src->fx.transport.boxes, nb);
    }
    if (src->n_lights) {
        dst->lights = malloc(src->n_lights * sizeof *dst->lights);
        if (!dst->lights) return gs_fail(GS_ENOMEM, "simulator: out of memory");
        memcpy(dst->lights, src->lights, src->n_lights * sizeof *dst->lights);
    }
    if (src->fx.signs.count) {
        dst->fx.signs.items = malloc(src->fx.signs.count * sizeof *dst->fx.signs.items);
        if (!dst->fx.signs.items) return gs_fail(GS_ENOMEM, "simulator: out of memory");
        memcpy(dst->fx.signs.items, src->fx.signs.items,
               src->fx.signs.count * sizeof *dst->fx.signs.items);
    }
    if (src->fx.cars.count) {
        dst->fx.cars.items = malloc(src->fx.cars.count * sizeof *dst->fx.cars.items);
        if (!dst->fx.cars.items) return gs_fail(GS_ENOMEM, "simulator: out of memory");
        memcpy(dst->fx.cars.items, src->fx.cars.items,
               src->fx.cars.count * sizeof *dst->fx.cars.items);
    }
    return GS_OK;
}

/* ------------------------------------------------------------------ base stages */

static gs_status st_windows(cap_sim *s, cap_render *r)
{
    if (!r->timing) return GS_OK;
    r->items = (unsigned long long)s->C;
    return cap_ac_windows(s->ac, &r->wcfg, &r->win);
}

static gs_status st_eq5(cap_sim *s, cap_render *r)
{
    int B = s->B, L = s->L, K = s->K;
    for (int h = 0; h < L; h++) r->n_exposed[h] = cap_exposed_cycles(s->M, 0, s->C, h);
    if (!r->timing) {
        for (int h = 0; h < L; h++) r->ex[h] = (double)r->n_exposed[h] / K;
        for (size_t i = 0; i < s->n_sp; i++)
            for (int h = 0; h < L; h++)
                for (int b = 0; b < B; b++)
                    s->Wsp[(i * (size_t)L + (size_t)h) * (size_t)B + (size_t)b] =
                        (double)r->n_exposed[h] * s->sp[i].i_k[b * K + r->k] / K;
        return GS_OK;
    }
    memset(s->Wsp, 0, sizeof *s->Wsp * s->n_sp * (size_t)L * (size_t)B);
    for (int h = 0; h < L; h++) r->ex[h] = 0;
    for (long c = 0; c < s->C; c++) {
        int lev = r->lev[c];
        double t0 = r->win.t0_s[c], t1 = r->win.t1_s[c];
        double p0 = r->win.phase0[c], p1 = r->win.phase1[c];
        double dur = (t1 - t0) / s->half_s;
        for (int h = 0; h <= lev; h++) r->ex[h] += dur;
        double scale = (t1 - t0) / ((p1 - p0) * s->half_s);
        for (size_t i = 0; i < s->n_sp; i++) {
            const cap_brf_table *t = &s->tables[s->sp[i].bulb];
            for (int b = 0; b < B; b++) {
                double w = scale * cap_brf_table_integral(t, b, s->sp[i].shift, p0, p1);
                if (s->wcyc) s->wcyc[(i * (size_t)B + (size_t)b) * (size_t)s->C + (size_t)c] = w;
                for (int h = 0; h <= lev; h++)
                    s->Wsp[(i * (size_t)L + (size_t)h) * (size_t)B + (size_t)b] += w;
            }
        }
    }
    return GS_OK;
}

static gs_status st_lights(cap_sim *s, cap_render *r)
{
    (void)r;
    int B = s->B, L = s->L;
    for (size_t l = 0; l < s->n; l++) {
        size_t sp = (size_t)s->species[l];
        for (int h = 0; h < L; h++)
            for (int b = 0; b < B; b++)
                s->E[(l * (size_t)L + (size_t)h) * (size_t)B + (size_t)b] =
                    s->flux[l * (size_t)B + (size_t)b] *
                    s->Wsp[(sp * (size_t)L + (size_t)h) * (size_t)B + (size_t)b];
    }
    return GS_OK;
}

/* The image's rows at 0 before the first stage that deposits into them (with the next row
 * stages, while the rows are in the cache). */
static gs_status clear_rows(void *ctx, int part, size_t y0, size_t y1)
{
    (void)part;   /* no items */
    cap_par *par = ctx;
    cap_sim *s = par->s;
    size_t row = (size_t)s->W * (size_t)s->B;
    memset(s->img + y0 * row, 0, (y1 - y0) * row * sizeof *s->img);
    return GS_OK;
}

GS_VECTOR_LOOP
static gs_status to_dn_rows(void *ctx, int part, size_t y0, size_t y1)
{
    (void)part;   /* no items */
    cap_par *par = ctx;
    cap_sim *s = par->s;
    size_t row = (size_t)s->W * (size_t)s->B;
    const cap_render *r = par->r;
    double g = 1.0 / s->sc.gain_e_per_dn, black = s->sc.black_level_dn;
    for (size_t y = y0; y < y1; y++) {
        if (r->rows && !r->rows[y]) continue;
        double *v = s->img + y * row;
        for (size_t i = 0; i < row; i++) v[i] = v[i] * g + black;
    }
    return GS_OK;
}

GS_VECTOR_LOOP
static gs_status store_rows(void *ctx, int part, size_t y0, size_t y1)
{
    (void)part;   /* no items */
    cap_par *par = ctx;
    cap_sim *s = par->s;
    const cap_render *r = par->r;
    size_t row = (size_t)s->W * (size_t)s->B, a = y0 * row, b = y1 * row;
    if (r->dn) memcpy(r->dn + a, s->img + a, (b - a) * sizeof *r->dn);
    for (size_t y = y0; r->raw && y < y1; y++) {
        if (r->rows && !r->rows[y]) {   /* a probe's row without noise, or a completed one */
            if (!r->rows_keep) memset(r->raw + y * row, 0, row * sizeof *r->raw);
            continue;
        }
        const double *img = s->img + y * row;
        unsigned short *raw = r->raw + y * row;
        for (size_t i = 0; i < row; i++) {
            double v = floor(img[i] + 0.5);
            /* written so that NaN clamps to 0 rather than reaching the cast */
            raw[i] = (unsigned short)(v > 0 ? (v < 65535 ? v : 65535) : 0);
        }
    }
    return GS_OK;
}

/* ------------------------------------------------------------------ construction */

/* A stage at pipeline position `at` (the effect it is, or runs before): from shot noise on, a
 * noise stage. */
static void add_stage(cap_sim *s, const char *name, int effect, int at,
                      gs_status (*run)(cap_sim *, cap_render *), gs_range_fn rows)
{
    cap_stage *st = &s->stages[s->n_stages++];
    memset(st, 0, sizeof *st);
    st->name = name;
    st->effect = effect;
    st->noise = at >= CAP_FX_SHOT_NOISE;
    st->run = run;
    st->rows = rows;
}

static int has(const cap_sim *s, cap_effect e)
{
    return (s->fx >> e) & 1u;
}

static gs_status find_species(cap_sim *s, int bulb, double shift, int *out)
{
    for (size_t i = 0; i < s->n_sp; i++)
        if (s->sp[i].bulb == bulb && fabs(s->sp[i].shift - shift) < 1e-12) {
            *out = (int)i;
            return GS_OK;
        }
    cap_species *ns = realloc(s->sp, (s->n_sp + 1) * sizeof *ns);
    if (!ns) return gs_fail(GS_ENOMEM, "simulator: out of memory");
    s->sp = ns;
    cap_species *p = &s->sp[s->n_sp];
    p->bulb = bulb;
    p->shift = shift;
    p->i_k = malloc(sizeof *p->i_k * (size_t)s->K * (size_t)s->B);
    if (!p->i_k) return gs_fail(GS_ENOMEM, "simulator: out of memory");
    s->n_sp++;
    *out = (int)(s->n_sp - 1);
    return gs_brf_integrate(&s->bulbs[bulb].brf, shift, s->K, p->i_k);
}

static gs_status load_bulbs(cap_sim *s, const gs_delight *d)
{
    const cap_scene *sc = &s->sc;
    s->species = calloc(s->n ? s->n : 1, sizeof *s->species);
    s->flux = calloc(s->n ? s->n * (size_t)s->B : 1, sizeof *s->flux);
    s->bulbs = calloc(s->n ? s->n : 1, sizeof *s->bulbs);
    if (!s->species || !s->flux || !s->bulbs) return gs_fail(GS_ENOMEM, "simulator: out of memory");
    for (size_t l = 0; l < s->n; l++) {
        const cap_light *li = &sc->lights[l];
        const gs_bulb *b = gs_delight_find(d, li->bulb, sc->grid_hz, s->B);
        if (!b)
            return gs_fail(GS_ENOTFOUND, "%s:%d: field lights (light %s): bulb '%s': expected a "
                           "DELIGHT bulb id with a %d Hz, %d-band entry (gridsurvey delight list)",
                           sc->path[0] ? sc->path : "<scene>", li->line, li->id, li->bulb,
                           sc->grid_hz, s->B);
        size_t bi = 0;
        while (bi < s->n_bulbs && strcmp(s->bulbs[bi].id, b->id)) bi++;
        if (bi == s->n_bulbs) {
            gs_bulb *nb = &s->bulbs[s->n_bulbs];
            *nb = *b;
            memset(&nb->brf, 0, sizeof nb->brf);
            gs_status st = gs_brf_copy(&nb->brf, &b->brf);
            if (st != GS_OK) return st;
            s->n_bulbs++;
        }
        int sp;
        gs_status st = find_species(s, (int)bi, gs_phase_to_shift(li->phase_deg), &sp);
        if (st != GS_OK) return st;
        s->species[l] = sp;
        for (int band = 0; band < s->B; band++)
            s->flux[l * (size_t)s->B + (size_t)band] = li->flux_e_per_cycle * s->bulbs[bi].chroma[band];
    }
    if (has(s, CAP_FX_SKYGLOW) && s->sc.fx.skyglow.flicker == CAP_GLOW_MIXED) {
        s->glow_sp = malloc(sizeof *s->glow_sp * (s->n ? s->n : 1) * 3);
        if (!s->glow_sp) return gs_fail(GS_ENOMEM, "simulator: out of memory");
        for (size_t l = 0; l < s->n; l++) {
            int bulb = s->sp[s->species[l]].bulb;
            double sh = s->sp[s->species[l]].shift;
            for (int j = 0; j < 3; j++) {
                int sp;
                gs_status st = find_species(s, bulb, fmod(sh + j / 3.0, 1.0), &sp);
                if (st != GS_OK) return st;
                s->glow_sp[l * 3 + (size_t)j] = sp;
            }
        }
    }
    return GS_OK;
}

/* Point footprints: the nearest pixel. */
static gs_status point_footprints(cap_sim *s)
{
    s->fp = calloc(s->n ? s->n : 1, sizeof *s->fp);
    s->fp_w = malloc(sizeof *s->fp_w * (s->n ? s->n : 1));
    if (!s->fp || !s->fp_w) return gs_fail(GS_ENOMEM, "simulator: out of memory");
    for (size_t l = 0; l < s->n; l++) {
        const cap_light *li = &s->sc.lights[l];
        double x = floor(li->x_px + 0.5), y = floor(li->y_px + 0.5);
        s->fp_w[l] = 1.0;
        if (x < 0 || y < 0 || x >= s->W || y >= s->H) continue;
        s->fp[l] = (cap_footprint){(int)x, (int)y, 1, 1, l};
    }
    return GS_OK;
}

void cap_sim_free(cap_sim *s)
{
    if (!s) return;
    for (size_t i = 0; i < s->n_bulbs; i++) gs_bulb_release(&s->bulbs[i]);
    free(s->bulbs);
    if (s->tables)
        for (size_t i = 0; i < s->n_bulbs; i++) cap_brf_table_release(&s->tables[i]);
    free(s->tables);
    for (size_t i = 0; i < s->n_sp; i++) free(s->sp[i].i_k);
    free(s->sp);
    free(s->species);
    free(s->glow_sp);
    free(s->flux);
    free(s->trans);
    free(s->scint_s2);
    free(s->scint_rho);
    free(s->fp);
    free(s->fp_w);
    free(s->glow_k);
    cap_ac_free(s->ac);
    free(s->img);
    free(s->E);
    free(s->Wsp);
    free(s->wcyc);
    free(s->scin);
    free(s->lev);
    free(s->amb_row);
    free(s->probe_rows);
    free(s->probe_r);
    free(s->probe_halv);
    cap_transport_free(s);
    cap_scene_release(&s->sc);
    free(s);
}

static int timing_wanted(const cap_sim *s)
{
    return s->timing;
}

static int no_psf(const cap_sim *s)
{
    return !has(s, CAP_FX_PSF);
}

/* The base stages and the effect each runs before (CAP_FX_COUNT: at the end), in order; wanted
 * NULL = always. */
static const struct {
    const char *name;
    gs_status (*run)(cap_sim *, cap_render *);
    gs_range_fn rows;
    cap_effect before;
    int (*wanted)(const cap_sim *);
} base_stages[] = {
    {"windows", st_windows, NULL, CAP_FX_EXTINCTION, timing_wanted},
    {"eq5", st_eq5, NULL, CAP_FX_EXTINCTION, NULL},
    {"lights", st_lights, NULL, CAP_FX_EXTINCTION, NULL},
    {"clear", NULL, clear_rows, CAP_FX_PSF, NULL},
    {"splat", NULL, cap_splat_rows, CAP_FX_SKYGLOW, no_psf},
    {"to_dn", NULL, to_dn_rows, CAP_FX_READ_NOISE, NULL},
    {"store", NULL, store_rows, CAP_FX_COUNT, NULL},
};

double cap_sim_bytes(const cap_scene *sc)
{
    unsigned fx = sc->fx.enabled;
    double P = (double)sc->cam.width_px * (double)sc->cam.height_px, N = P * sc->bands;
    double n = (double)sc->n_lights, C = (double)sc->acam.cycles, B = sc->bands;
    double bytes = CAP_RENDER_BASE_BYTES + N * CAP_RENDER_BYTES_PER_SAMPLE + P * CAP_RENDER_BYTES_PER_PIXEL +
                   n * (CAP_RENDER_BYTES_PER_LIGHT + sizeof(cap_light) + 8.0 * CAP_MAX_LEVELS * B);
    if ((fx >> CAP_FX_PSF) & 1u) {
        /* each light's footprint: a (2R + 1)^2 box of weights (cap_fx_prepare_psf) */
        double R = fmin(64.0, ceil(sc->fx.psf.radius_sigma * sc->fx.psf.sigma_px));
        bytes += n * 8.0 * (2 * R + 1) * (2 * R + 1);
    }
    if ((fx >> CAP_FX_SKYGLOW) & 1u) bytes += 8.0 * 513 * 513;   /* the kernel, R <= 256 */
    if ((fx >> CAP_FX_LIGHT_TRANSPORT) & 1u) {
        /* a float image per light (tau), the daylight's, the truth's; lamp shades' disks */
        double r = ceil(sc->fx.transport.shade_radius_px);
        bytes += (n + 2) * N * 4.0 + n * 8.0 * (2 * r + 2) * (2 * r + 2);
    }
    if ((fx >> CAP_FX_SEMI_REFLECTION) & 1u) bytes += 2 * N * 4.0;   /* the outdoor image, the truth's */
    /* per cycle: the mask levels, each thread's scintillation row, and with a timing effect
     * the species' per-cycle windows (at most one species per light) */
    bytes += C * (1.0 + 8.0 * GS_MAX_THREADS);
    int timing = (fx >> CAP_FX_FREQUENCY_WANDER) & 1u || (fx >> CAP_FX_FREE_RUNNING_DRIFT) & 1u ||
                 (fx >> CAP_FX_DMD_JITTER) & 1u;
    if (timing && (fx >> CAP_FX_SCINTILLATION) & 1u) bytes += n * B * C * 8.0;
    return bytes;
}

/* cap_sim_bytes against the memory budget, in one line naming the scene's sizes. */
static gs_status render_budget(const cap_scene *sc)
{
    char what[CAP_PATH_MAX + 400];
    snprintf(what, sizeof what, "%s: camera.width_px x height_px x sensor.bands = %dx%dx%d samples and %zu "
             "lights, rendered (%.0f MiB, %d B per sample, %d per pixel, %d per light, the light transport's "
             "images and %ld acam.cycles)", sc->path[0] ? sc->path : "scene", sc->cam.width_px, sc->cam.height_px,
             sc->bands, sc->n_lights, CAP_RENDER_BASE_BYTES / 1048576, CAP_RENDER_BYTES_PER_SAMPLE, CAP_RENDER_BYTES_PER_PIXEL,
             CAP_RENDER_BYTES_PER_LIGHT, sc->acam.cycles);
    return gs_mem_check(cap_sim_bytes(sc), what);
}

gs_status cap_sim_new(const cap_scene *sc, const gs_delight *d_in, cap_sim **out)
{
    *out = NULL;
    gs_status budget = render_budget(sc);
    if (budget != GS_OK) return budget;
    cap_sim *s = calloc(1, sizeof *s);
    if (!s) return gs_fail(GS_ENOMEM, "simulator: out of memory");
    gs_delight *own = NULL;
    gs_status st = scene_copy(&s->sc, sc);
    if (st != GS_OK) goto fail;
    s->W = sc->cam.width_px;
    s->H = sc->cam.height_px;
    s->B = sc->bands;
    s->K = sc->acam.K;
    s->C = sc->acam.cycles;
    s->M = sc->acam.masks;
    s->hmax = sc->acam.hdr ? (sc->acam.hdr_max_rounds ? sc->acam.hdr_max_rounds
                                                      : cap_acam_max_halvings(s->M))
                           : 0;
    s->L = s->hmax + 1;
    s->half_s = 1.0 / (2.0 * sc->grid_hz);
    s->fx = sc->fx.enabled;
    s->n = sc->n_lights;
    s->timing = has(s, CAP_FX_FREQUENCY_WANDER) || has(s, CAP_FX_FREE_RUNNING_DRIFT) ||
                has(s, CAP_FX_DMD_JITTER);
    if ((st = cap_acam_check(&sc->acam)) != GS_OK) goto fail;
    /* DELIGHT */
    const gs_delight *d = d_in;
    if (!d) {
        if ((st = gs_delight_open(sc->delight[0] ? sc->delight : NULL, &own)) != GS_OK) goto fail;
        d = own;
    }
    if ((st = load_bulbs(s, d)) != GS_OK) goto fail;
    gs_delight_free(own);
    own = NULL;
    /* cycle levels of the mask rows */
    s->lev = malloc((size_t)s->C);
    if (!s->lev) {
        st = gs_fail(GS_ENOMEM, "simulator: out of memory");
        goto fail;
    }
    for (long c = 0; c < s->C; c++) s->lev[c] = (unsigned char)cap_cycle_level(s->M, s->hmax, c);
    /* timing machinery, only for the timing effects */
    if (s->timing) {
        s->tables = calloc(s->n_bulbs ? s->n_bulbs : 1, sizeof *s->tables);
        if (!s->tables) {
            st = gs_fail(GS_ENOMEM, "simulator: out of memory");
            goto fail;
        }
        for (size_t i = 0; i < s->n_bulbs; i++)
            if ((st = cap_brf_table_init(&s->tables[i], &s->bulbs[i].brf, 4096)) != GS_OK) goto fail;
        cap_freq_config f = sc->freq;
        if (!has(s, CAP_FX_FREQUENCY_WANDER)) {
            memset(&f, 0, sizeof f);
            f.model = CAP_FREQ_CONSTANT;
            f.hz = sc->grid_hz;
        }
        if ((st = cap_ac_new(&f, sc->grid_hz, &s->ac)) != GS_OK) goto fail;
        if (has(s, CAP_FX_SCINTILLATION)) {
            s->wcyc = malloc(sizeof *s->wcyc * (s->n_sp ? s->n_sp : 1) * (size_t)s->B * (size_t)s->C);
            if (!s->wcyc) {
                st = gs_fail(GS_ENOMEM, "simulator: out of memory");
                goto fail;
            }
        }
    }
    /* effects that prepare once (without a PSF every light is a point) */
    if (!has(s, CAP_FX_PSF) && (st = point_footprints(s)) != GS_OK) goto fail;
    for (int e = 0; e < CAP_FX_COUNT; e++)
        if (has(s, (cap_effect)e) && cap_effect_defs[e].prepare &&
            (st = cap_effect_defs[e].prepare(s)) != GS_OK)
            goto fail;
    /* capture-level numbers */
    double adc_max = has(s, CAP_FX_ADC) ? (double)((1 << sc->bit_depth) - 1) : 65535.0;
    s->adc_max = adc_max;
    s->read_dn = has(s, CAP_FX_READ_NOISE) ? sc->fx.read_noise.sigma_e / sc->gain_e_per_dn : 0.0;
    s->sat_dn = adc_max;
    if (has(s, CAP_FX_SATURATION)) {
        /* clipped pixels sit at the full well, then get read noise: flag from 4 sigma below */
        double fw = sc->black_level_dn + sc->full_well_e / sc->gain_e_per_dn - 4.0 * s->read_dn;
        if (fw < s->sat_dn) s->sat_dn = floor(fw);
    }
    if (!(s->sat_dn > sc->black_level_dn + 1)) {
        st = gs_fail(GS_EINVAL, "%s: the saturation level %.1f DN is not above the black level "
                     "%.1f DN (full well, gain and read noise)", sc->path, s->sat_dn,
                     sc->black_level_dn);
        goto fail;
    }
    /* scratch */
    size_t npx = (size_t)s->W * (size_t)s->H * (size_t)s->B;
    s->img = malloc(sizeof *s->img * npx);
    s->E = malloc(sizeof *s->E * (s->n ? s->n : 1) * (size_t)s->L * (size_t)s->B);
    s->Wsp = malloc(sizeof *s->Wsp * (s->n_sp ? s->n_sp : 1) * (size_t)s->L * (size_t)s->B);
    s->scin = malloc(sizeof *s->scin * GS_MAX_THREADS * (size_t)s->C);
    s->amb_row = calloc((size_t)s->H, sizeof *s->amb_row);
    s->probe_rows = malloc((size_t)s->H);
    s->probe_r = malloc(sizeof *s->probe_r);
    s->probe_halv = malloc((size_t)s->W * (size_t)s->H);
    if (!s->img || !s->E || !s->Wsp || !s->scin || !s->amb_row || !s->probe_rows || !s->probe_r ||
        !s->probe_halv) {
        st = gs_fail(GS_ENOMEM, "simulator: cannot hold a %d x %d x %d frame", s->W, s->H, s->B);
        goto fail;
    }
    /* the pipeline: exactly the listed effects, in physical order, with the base stages */
    for (int e = 0; e <= CAP_FX_COUNT; e++) {
        for (size_t b = 0; b < sizeof base_stages / sizeof *base_stages; b++)
            if ((int)base_stages[b].before == e && (!base_stages[b].wanted || base_stages[b].wanted(s)))
                add_stage(s, base_stages[b].name, -1, e, base_stages[b].run, base_stages[b].rows);
        if (e < CAP_FX_COUNT && has(s, (cap_effect)e))
            add_stage(s, cap_effect_defs[e].name, e, e, cap_effect_defs[e].run, cap_effect_defs[e].rows);
    }
    *out = s;
    return GS_OK;
fail:
    gs_delight_free(own);
    cap_sim_free(s);
    return st;
}

void cap_sim_set_threads(cap_sim *s, int threads)
{
    s->threads = threads;
}

const cap_scene *cap_sim_scene(const cap_sim *s)
{
    return &s->sc;
}

double cap_sim_saturation_dn(const cap_sim *s)
{
    return s->sat_dn;
}

double cap_sim_read_noise_dn(const cap_sim *s)
{
    return s->read_dn;
}

size_t cap_sim_stage_count(const cap_sim *s)
{
    return s->n_stages;
}

gs_status cap_sim_stage(const cap_sim *s, size_t i, cap_stage_info *info)
{
    if (i >= s->n_stages) return gs_fail(GS_EINVAL, "stage %zu of %zu", i, s->n_stages);
    const cap_stage *st = &s->stages[i];
    info->name = st->name;
    info->effect = st->effect;
    info->calls = st->calls;
    info->items = st->items;
    info->seconds = st->seconds;
    return GS_OK;
}

unsigned long long cap_sim_effect_calls(const cap_sim *s, cap_effect e)
{
    return (int)e >= 0 && e < CAP_FX_COUNT ? s->fx_calls[e] : 0;
}

/* The crossing that starts acquisition index; the timeline starts 64 crossings in, so a
 * measured free-running period has a history. */
static long first_cycle_of(const cap_sim *s, long index)
{
    return 64 + index * (s->C + s->sc.readout_cycles);
}

gs_status cap_sim_exposure_span(cap_sim *s, long index, double *t_start_s, double *t_end_s)
{
    if (index < 0) return gs_fail(GS_EINVAL, "exposure span: index %ld", index);
    long c0 = first_cycle_of(s, index), c1 = c0 + s->C;
    if (!s->ac) {
        /* no timing effect: the nominal timeline of cap_sim_cycle_time */
        *t_start_s = (double)c0 * s->half_s;
        *t_end_s = (double)c1 * s->half_s;
        return GS_OK;
    }
    gs_status st = cap_ac_time(s->ac, c0, t_start_s);
    if (st == GS_OK) st = cap_ac_time(s->ac, c1, t_end_s);
    return st;
}

gs_status cap_sim_window_timing(cap_sim *s, long index, double *half_period_s, double *drift_windows)
{
    *half_period_s = *drift_windows = NAN;
    if (index < 0) return gs_fail(GS_EINVAL, "window timing: index %ld", index);
    if (s->sc.locked) return GS_OK;
    if (!s->ac) {   /* no timing effect: every period nominal */
        *half_period_s = s->half_s;
        *drift_windows = 0.0;
        return GS_OK;
    }
    /* the windows' configuration as cap_sim_render and the free-running drift effect set it */
    cap_window_config w = {.K = s->K, .cycles = s->C, .first_cycle = first_cycle_of(s, index),
                           .mode = CAP_FREE_RUNNING, .free_period_measured = s->sc.free_period_measured,
                           .clock_ppm = has(s, CAP_FX_FREE_RUNNING_DRIFT) ? s->sc.fx.drift.clock_ppm : 0.0};
    gs_status st = cap_ac_window_period(s->ac, &w, half_period_s);
    double *delta = st == GS_OK ? malloc(sizeof *delta * (size_t)s->C) : NULL;
    if (st == GS_OK && !delta) st = gs_fail(GS_ENOMEM, "window timing: out of memory");
    double t0 = 0.0, t1;
    for (long c = 0; st == GS_OK && c <= s->C; c++) {
        if ((st = cap_ac_time(s->ac, w.first_cycle + c, &t1)) == GS_OK && c > 0) delta[c - 1] = t1 - t0;
        t0 = t1;
    }
    if (st == GS_OK) *drift_windows = cap_window_drift(delta, s->C, *half_period_s, s->K);
    free(delta);
    return st;
}

/* The electrons a sample's mean may have and still certainly not read the saturation level
 * (cap_sim_render_probe), or NaN when no bound is tight enough: it needs n = (sat_dn - 0.5 -
 * black - 40 read sigmas) x gain electrons; with shot noise, a mean lam <= n/2 reaches n with
 * P <= e^-lam (e lam / n)^n <= e^(-n (ln 2 - 1/2)) (Chernoff), which must be below e^-80. */
static double probe_safe_e(const cap_sim *s)
{
    double n = (s->sat_dn - 0.5 - s->sc.black_level_dn - 40.0 * s->read_dn) * s->sc.gain_e_per_dn;
    if (!(n > 0.0) || !isfinite(n)) return NAN;
    if (!has(s, CAP_FX_SHOT_NOISE)) return n * (1.0 - 1e-9);
    return n * (M_LN2 - 0.5) >= 80.0 ? 0.5 * n : NAN;
}

/* 1 when a sample of v[0 .. n) is above safe or NaN (one vectorized pass: most rows have none). */
GS_VECTOR_LOOP static int any_above(const double *v, size_t n, double safe)
{
    int any = 0;
    for (size_t i = 0; i < n; i++) any |= !(v[i] <= safe);
    return any;
}

/* Rows [y0, y1) of a probe: s->probe_rows[y] = 1 for a row with a sample above the safe mean
 * (par->r->probe_safe_e), the part's items the pixels with one. */
static gs_status probe_rows_part(void *ctx, int part, size_t y0, size_t y1)
{
    cap_par *par = ctx;
    cap_sim *s = par->s;
    double safe = par->r->probe_safe_e;
    size_t row = (size_t)s->W * (size_t)s->B;
    for (size_t y = y0; y < y1; y++) {
        const double *v = s->img + y * row;
        s->probe_rows[y] = (unsigned char)any_above(v, row, safe);
        if (!s->probe_rows[y]) continue;
        for (size_t x = 0; x < (size_t)s->W; x++)
            par->items[part] += (unsigned long long)any_above(v + x * (size_t)s->B, (size_t)s->B, safe);
    }
    return GS_OK;
}

/* A probe's rows: those with a sample whose mean (s->img before the noise stages) could
 * saturate; NULL (a whole frame) when no more than max_px pixels could. */
static const unsigned char *probe_rows_of(cap_sim *s, cap_render *r, long max_px, gs_status *st)
{
    r->probe_safe_e = probe_safe_e(s);
    if (isnan(r->probe_safe_e)) return NULL;
    *st = cap_par_run(s, r, (size_t)s->H, probe_rows_part);
    return *st == GS_OK && r->items > (unsigned long long)max_px ? s->probe_rows : NULL;
}

/* Stages [i0, i1) of the pipeline on one acquisition, consecutive row stages together
 * (cap_rows_run); each effect's calls counted. */
static gs_status run_stages(cap_sim *s, cap_render *r, size_t i0, size_t i1)
{
    gs_status st = GS_OK;
    for (size_t i = i0, j; i < i1 && st == GS_OK; i = j) {
        j = i + 1;
        if (s->stages[i].rows)
            while (j < i1 && s->stages[j].rows) j++;
        for (size_t e = i; e < j; e++)
            if (s->stages[e].effect >= 0) s->fx_calls[s->stages[e].effect]++;
        if (s->stages[i].rows) {
            st = cap_rows_run(s, r, &s->stages[i], j - i);
            continue;
        }
        cap_stage *sg = &s->stages[i];
        double t0 = gs_clock_s(CLOCK_MONOTONIC);
        r->items = 0;
        st = sg->run(s, r);
        sg->seconds += gs_clock_s(CLOCK_MONOTONIC) - t0;
        sg->calls++;
        sg->items += r->items;
    }
    return st;
}

static gs_status render(cap_sim *s, int k, int pass, long index, const unsigned char *halvings,
                        unsigned short *raw, double *dn, long probe_max_px, int *probed)
{
    if (k < 0 || k >= s->K || pass < 0 || index < 0)
        return gs_fail(GS_EINVAL, "render: k %d of K %d, pass %d, index %ld", k, s->K, pass, index);
    size_t plane = (size_t)s->W * (size_t)s->H;
    if (halvings)
        for (size_t p = 0; p < plane; p++)
            if (halvings[p] > s->hmax)
                return gs_fail(GS_EINVAL, "render: pixel (%zu, %zu) halved %d times: the masks "
                               "allow %d", p % (size_t)s->W, p / (size_t)s->W, halvings[p], s->hmax);
    cap_render r;
    memset(&r, 0, sizeof r);
    r.k = k;
    r.pass = pass;
    r.index = index;
    r.first_cycle = first_cycle_of(s, index);
    r.halv = halvings;
    r.lev = s->lev;
    r.raw = raw;
    r.dn = dn;
    r.wcfg.K = s->K;
    r.wcfg.k = k;
    r.wcfg.cycles = s->C;
    r.wcfg.first_cycle = r.first_cycle;
    r.wcfg.mode = s->sc.locked ? CAP_LOCKED : CAP_FREE_RUNNING;
    r.wcfg.free_period_measured = s->sc.free_period_measured;
    r.wcfg.jitter_seed = s->sc.seed ^ (0x5851f42d4c957f2dull * (unsigned long long)(pass + 1));
    s->probe_pending = 0;
    size_t noise = 0;   /* a probe decides its rows when the means are complete */
    while (probe_max_px >= 0 && noise < s->n_stages && !s->stages[noise].noise) noise++;
    gs_status st = run_stages(s, &r, 0, probe_max_px >= 0 ? noise : s->n_stages);
    if (st == GS_OK && probe_max_px >= 0) {   /* which rows can saturate */
        r.rows = probe_rows_of(s, &r, probe_max_px, &st);
        if (st == GS_OK) st = run_stages(s, &r, noise, s->n_stages);
    }
    cap_windows_release(&r.win);
    if (probed) *probed = st == GS_OK && r.rows;
    if (st == GS_OK && r.rows) {   /* what completing it needs */
        s->probe_pending = 1;
        *s->probe_r = r;
        memset(&s->probe_r->win, 0, sizeof s->probe_r->win);   /* released: the noise stages do not use it */
        if (halvings) memcpy(s->probe_halv, halvings, plane);
        s->probe_r->halv = halvings ? s->probe_halv : NULL;
    }
    return st;
}

/* The rows the last probe left without noise, into raw (its other rows already there). */
static gs_status complete_probe(cap_sim *s, unsigned short *raw)
{
    s->probe_pending = 0;
    for (int y = 0; y < s->H; y++) s->probe_rows[y] = !s->probe_rows[y];
    cap_render r = *s->probe_r;
    r.raw = raw;
    r.rows = s->probe_rows;
    r.rows_keep = 1;
    size_t i = 0;
    while (i < s->n_stages && !s->stages[i].noise) i++;
    return run_stages(s, &r, i, s->n_stages);
}

gs_status cap_sim_render(cap_sim *s, int k, int pass, long index, const unsigned char *halvings,
                         unsigned short *raw, double *dn)
{
    return render(s, k, pass, index, halvings, raw, dn, -1, NULL);
}

gs_status cap_sim_render_hdr(cap_sim *s, int k, int pass, long index, const unsigned char *halvings,
                             unsigned short *raw, int probe, long max_saturated_px, int *probed)
{
    *probed = 0;
    if (!raw) return render(s, k, pass, index, halvings, NULL, NULL, -1, NULL);
    const cap_render *p = s->probe_r;
    size_t plane = (size_t)s->W * (size_t)s->H;
    if (!probe && s->probe_pending && p->k == k && p->pass == pass && p->index == index &&
        (halvings ? p->halv && !memcmp(halvings, p->halv, plane) : !p->halv))
        return complete_probe(s, raw);
    return render(s, k, pass, index, halvings, raw, NULL, probe ? (max_saturated_px < 0 ? 0 : max_saturated_px) : -1,
                  probed);
}

/* ------------------------------------------------------------------ truth */

static json_t *jnum(double v)
{
    return isfinite(v) ? json_real(v) : json_null();
}

static gs_status write_truth(const cap_sim *s, const char *dir)
{
    const cap_scene *sc = &s->sc;
    json_t *root = json_object(), *lights = json_array();
    if (!root || !lights) {
        json_decref(root);
        json_decref(lights);
        return gs_fail(GS_ENOMEM, "truth: out of memory");
    }
    json_object_set_new(root, "format", json_string(CAP_TRUTH_FORMAT));
    json_object_set_new(root, "scene", json_string(sc->name));
    json_object_set_new(root, "seed", json_integer((json_int_t)sc->seed));
    json_object_set_new(root, "grid_hz", json_integer(sc->grid_hz));
    json_object_set_new(root, "K", json_integer(s->K));
    json_object_set_new(root, "bands", json_integer(s->B));
    json_object_set_new(root, "width", json_integer(s->W));
    json_object_set_new(root, "height", json_integer(s->H));
    unsigned char *res = malloc(s->n ? s->n : 1);
    int *grp = malloc((s->n ? s->n : 1) * sizeof *grp), n_groups = 0;
    gs_status rst = res && grp ? cap_resolve(s, res, grp, &n_groups)
                               : gs_fail(GS_ENOMEM, "truth: out of memory");
    if (rst != GS_OK) {
        free(res);
        free(grp);
        json_decref(root);
        json_decref(lights);
        return rst;
    }
    json_t *rs = json_object();
    json_object_set_new(rs, "sigma_px", jnum(cap_resolve_sigma_px(s)));
    json_object_set_new(rs, "separation_sigma", jnum(CAP_RESOLVE_SEPARATION));
    json_object_set_new(rs, "flux_ratio", jnum(CAP_RESOLVE_FLUX_RATIO));
    json_object_set_new(rs, "blend_groups", json_integer(n_groups));
    json_object_set_new(root, "resolvability", rs);
    size_t in_image = 0;
    for (size_t l = 0; l < s->n; l++) {
        const cap_light *li = &sc->lights[l];
        const gs_bulb *b = &s->bulbs[s->sp[s->species[l]].bulb];
        json_t *o = json_object();
        json_object_set_new(o, "id", json_string(li->id));
        json_object_set_new(o, "x_px", jnum(li->x_px));
        json_object_set_new(o, "y_px", jnum(li->y_px));
        json_object_set_new(o, "in_image", json_boolean(li->in_image));
        if (li->geographic) {
            json_object_set_new(o, "lat_deg", jnum(li->lat_deg));
            json_object_set_new(o, "lon_deg", jnum(li->lon_deg));
            json_object_set_new(o, "height_m", jnum(li->height_m));
        }
        if (li->distance_m > 0) json_object_set_new(o, "distance_m", jnum(li->distance_m));
        json_object_set_new(o, "bulb", json_string(li->bulb));
        json_object_set_new(o, "technology", json_string(gs_tech_name(b->type)));
        json_object_set_new(o, "phase_deg", jnum(li->phase_deg));
        json_object_set_new(o, "shift_cycles", jnum(gs_phase_to_shift(li->phase_deg)));
        json_object_set_new(o, "flux_e_per_cycle", jnum(li->flux_e_per_cycle));
        if (li->in_image) {
            json_object_set_new(o, "resolvable", json_boolean(res[l]));
            json_object_set_new(o, "blend_group", grp[l] >= 0 ? json_integer(grp[l]) : json_null());
        }
        if (li->lumens > 0) json_object_set_new(o, "lumens", jnum(li->lumens));
        /* what a maximum-likelihood oracle must know of the atmosphere (docs/formats.md) */
        if (has(s, CAP_FX_EXTINCTION) && s->trans) {
            json_t *t = json_array();
            for (int band = 0; band < s->B; band++) json_array_append_new(t, jnum(s->trans[l * (size_t)s->B + (size_t)band]));
            json_object_set_new(o, "transmission", t);
        }
        if (has(s, CAP_FX_SCINTILLATION) && s->scint_s2 && s->scint_s2[l] > 0) {
            json_object_set_new(o, "scintillation_log_var", jnum(s->scint_s2[l]));
            json_object_set_new(o, "scintillation_rho", jnum(s->scint_rho[l]));
        }
        json_array_append_new(lights, o);
        in_image += li->in_image != 0;
    }
    free(res);
    free(grp);
    json_object_set_new(root, "lights_in_image", json_integer((json_int_t)in_image));
    json_object_set_new(root, "lights", lights);
    json_t *dis = json_object();
    if (has(s, CAP_FX_BLINKING_SIGN)) {
        json_t *a = json_array();
        for (size_t i = 0; i < sc->fx.signs.count; i++) {
            const cap_sign *g = &sc->fx.signs.items[i];
            json_t *o = json_object();
            json_object_set_new(o, "x_px", jnum(g->x_px));
            json_object_set_new(o, "y_px", jnum(g->y_px));
            json_object_set_new(o, "width_px", jnum(g->width_px));
            json_object_set_new(o, "height_px", jnum(g->height_px));
            json_object_set_new(o, "period_s", jnum(g->period_s));
            json_array_append_new(a, o);
        }
        json_object_set_new(dis, "blinking_signs", a);
    }
    if (has(s, CAP_FX_HEADLIGHTS)) {
        json_t *a = json_array();
        for (size_t i = 0; i < sc->fx.cars.count; i++) {
            const cap_car *g = &sc->fx.cars.items[i];
            json_t *o = json_object(), *from = json_array(), *to = json_array();
            json_array_append_new(from, jnum(g->x0_px));
            json_array_append_new(from, jnum(g->y0_px));
            json_array_append_new(to, jnum(g->x1_px));
            json_array_append_new(to, jnum(g->y1_px));
            json_object_set_new(o, "from", from);
            json_object_set_new(o, "to", to);
            json_array_append_new(a, o);
        }
        json_object_set_new(dis, "headlights", a);
    }
    json_object_set_new(root, "distractors", dis);
    json_t *images = NULL;
    gs_status tst = cap_transport_write_truth(s, dir, &images);
    if (tst != GS_OK) {
        json_decref(root);
        return tst;
    }
    if (images) {
        json_t *tr = json_object();
        json_object_set_new(tr, "units", json_string("DN per flicker cycle: each source's cycle-mean "
                                                      "image tau_s Q_s (Eq. 9), float TIFF"));
        json_object_set_new(tr, "images", images);
        json_object_set_new(root, "transport", tr);
    }
    char *text = json_dumps(root, JSON_INDENT(1) | JSON_PRESERVE_ORDER | JSON_REAL_PRECISION(15));
    json_decref(root);
    if (!text) return gs_fail(GS_ENOMEM, "truth: cannot serialise");
    size_t len = strlen(text);
    char *withnl = realloc(text, len + 2);
    if (!withnl) {
        free(text);
        return gs_fail(GS_ENOMEM, "truth: out of memory");
    }
    withnl[len] = '\n';
    withnl[len + 1] = '\0';
    gs_status st = cap_write_in(dir, "truth.json", withnl, len + 1);
    free(withnl);
    return st;
}

/* (under the directory's shared lock: a writer, which takes it exclusive, took the truth's
 * temporaries for a killed run's and removed them when it came after the acquisition loop had
 * released the lock) */
gs_status cap_sim_write_truth(const cap_sim *s, const char *dir)
{
    int fd;
    gs_status st = gs_capture_lock(dir, 0, &fd);
    if (st != GS_OK) return st;
    st = write_truth(s, dir);
    gs_capture_unlock(fd);
    return st;
}

/* ------------------------------------------------------------------ bench */

