/* eq7_noise.c - Eq. 7 for every light of a catalog, with the excess noise (scintillation: the
 * light's flux fluctuating from frame to frame, not locked to the mains) measured from the
 * capture itself rather than assumed (docs/recognition.md, "Noise").
 *
 * Pass 1 fits every light with the camera noise alone and measures, from its residuals, the
 * relative excess e^2 that would bring its chi2 to its dof (rec_eq7_excess, with its variance).
 * A light's own misfit (a blend, a bulb not in DELIGHT) must not hide itself, so the e^2 used
 * for light i is a weighted median over the OTHER clean lights j (leave-one-out), weights
 * 1/var(e^2_j) times a Gaussian kernel in image row (range, for a camera looking down on a city)
 * and in log brightness: the excess is a smooth property of the atmosphere along the lines of
 * sight, not of one lamp. var(e^2_j) is the expected one at the capture's typical excess (not
 * the light's own estimate, which would favour the lights whose noise happened to be low).
 * Over more than NOISE_MAX_REFS references, each light's median takes a sample of them
 * stratified in e^2 (every k-th), so that this step stays linear in the lights.
 * Pass 2 fits again the lights whose excess is not zero; the last pass (eq7_population.c) every
 * light under what the population tells of tau, the band tolerance and bulbs not in DELIGHT.
 * The lights of each pass run on the matcher's threads, in chunks taken in turn (their costs are
 * uneven; the answers are bit-identical to one thread's). */
#include "recognize/internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Fewer clean lights than this: no population, the camera noise (REC_NOISE_CAMERA). */
#define NOISE_MIN_LIGHTS 8
/* Kernel widths: a third of the image height, a decade of brightness. */
#define KERNEL_ROWS 3.0
#define KERNEL_DECADES 1.0
/* A light whose kernel weights amount to fewer than this many lights uses the global median. */
#define NOISE_MIN_EFFECTIVE 3.0
/* (The lights' kernel medians take at most NOISE_MAX_REFS references: internal.h.) */

typedef struct {
    const rec_eq7_excess *ex;
    double e2, wt;       /* excess estimate and inverse variance */
    double y, lb;        /* row, log10 brightness */
    size_t light;
} ref_light;

/* The expected inverse variance of a light's e2 estimate at the excess e2 (rec_eq7_excess). */
static double excess_weight(const rec_eq7_excess *ex, int bands, double e2)
{
    double info = 0.0;
    for (int b = 0; b < bands; b++)
        if (ex->n_b[b] > 0.0) info += ex->n_b[b] * ex->mu2_b[b] / (ex->s2_b[b] + e2 * ex->mu2_b[b]);
    return info * info / (2.0 * ex->dof);
}

static int cmp_e2(const void *a, const void *b)
{
    double x = ((const ref_light *)a)->e2, y = ((const ref_light *)b)->e2;
    return (x > y) - (x < y);
}

/* The weighted median of the references sorted by e2, with weights from kernel k (skipping the
 * light itself); *neff the effective count (sum w)^2 / sum w^2. */
static double weighted_median(const ref_light *r, size_t n, size_t self, double y, double lb,
                              double hy, double hb, int use_kernel, double *wk, double *neff)
{
    double sum = 0.0, sum2 = 0.0;
    for (size_t j = 0; j < n; j++) {
        double w = r[j].light == self ? 0.0 : r[j].wt;
        if (use_kernel && w > 0.0) {
            double dy = (r[j].y - y) / hy, db = (r[j].lb - lb) / hb;
            w *= exp(-0.5 * (dy * dy + db * db));
        }
        wk[j] = w;
        sum += w;
        sum2 += w * w;
    }
    *neff = sum2 > 0.0 ? sum * sum / sum2 : 0.0;
    if (!(sum > 0.0)) return 0.0;
    double acc = 0.0;
    for (size_t j = 0; j < n; j++) {
        acc += wk[j];
        if (acc >= 0.5 * sum) return r[j].e2;
    }
    return r[n - 1].e2;
}

const char *rec_noise_source_name(rec_noise_source s)
{
    switch (s) {
    case REC_NOISE_CAMERA: return "camera";
    case REC_NOISE_FIXED: return "fixed";
    case REC_NOISE_POPULATION: return "population";
    }
    return "unknown";
}

/* What the last pass needs of each light's answer (rec_eq7_work's): the reddened model's tau
 * likelihoods and band fit (tll not NULL), the log Bayes factor of "not in DELIGHT" (lbf not
 * NULL). */
typedef struct {
    double *tll;         /* [i * REC_TAU_N + t] */
    int *bulb;
    double *S, *T, *z;   /* [i * GS_MAX_BANDS + b], [i] */
    double *lbf;         /* [i] */
    double *flat, *flat_var;   /* [i]: the light's own flat share (flat_share measured) */
} light_fits;

static void keep_fit(const rec_eq7_work *w, size_t i, const light_fits *fit)
{
    if (fit->tll) {
        memcpy(fit->tll + i * REC_TAU_N, w->tau_ll, sizeof w->tau_ll);
        fit->bulb[i] = w->fit_bulb;
        memcpy(fit->S + i * GS_MAX_BANDS, w->fit_S, sizeof w->fit_S);
        memcpy(fit->T + i * GS_MAX_BANDS, w->fit_T, sizeof w->fit_T);
        fit->z[i] = w->fit_z;
    }
    if (fit->lbf) fit->lbf[i] = w->other_lbf;
    if (fit->flat) {
        fit->flat[i] = w->fit_flat;
        fit->flat_var[i] = w->fit_flat_var;
    }
}

/* Each part's (thread's) scratch, allocated on its first chunk and kept for every chunk and
 * pass of one rec_match_catalog. */
typedef struct {
    rec_eq7_work w[GS_MAX_THREADS];
    size_t *light[GS_MAX_THREADS];
    size_t cap[GS_MAX_THREADS];   /* lights per block; 0: not allocated yet */
} catalog_scratch;

static void catalog_scratch_free(catalog_scratch *cs)
{
    for (int q = 0; cs && q < GS_MAX_THREADS; q++) {
        if (cs->cap[q]) rec_eq7_work_free(&cs->w[q]);
        free(cs->light[q]);
    }
    free(cs);
}

/* One pass of rec_match_catalog over a range of lights, each part with its own scratch:
 * pass 1 (fe NULL: every light with fe1), pass 2 (the lights with fe[i] > 0), the last pass
 * (last: every light with fe[i], or fe1 when fe is NULL, under the population's priors). */
typedef struct {
    catalog_scratch *scratch;
    const rec_matcher *m;
    const rec_catalog *cat;
    rec_match *out;
    rec_eq7_excess *ex;       /* pass 1 (may be NULL) */
    const double *fe;         /* each light's excess; NULL: fe1 */
    double fe1;
    const light_fits *keep;   /* passes 1 and 2: what the last pass needs */
    int last;
    const double *logprior;   /* the last pass: each light's tau prior (NULL: uniform) */
    double tol, other;        /* and the band tolerance (0: the options'), other share (NaN: */
                              /* the options') */
    double flat;              /* every pass: the flat share subtracted, or */
    const double *flat_i;     /* each light's (not NULL) */
} catalog_pass;

/* The lights of a pass go in blocks of this many (rec_eq7_block_sums), fewer when their sums
 * would exceed about 1 MiB. */
#define CATALOG_BLOCK 64

static gs_status catalog_part(void *ctx, int part, size_t i0, size_t i1)
{
    const catalog_pass *p = ctx;
    const rec_matcher *m = p->m;
    const rec_catalog *cat = p->cat;
    size_t D = (size_t)m->D, cap = p->scratch->cap[part];
    gs_status s = GS_OK;
    if (!cap) {   /* this part's first chunk */
        cap = ((size_t)1 << 20) / (16 * (size_t)m->nfit * m->M);
        cap = cap < 1 ? 1 : cap > CATALOG_BLOCK ? CATALOG_BLOCK : cap;
        if (cap > cat->count) cap = cat->count;
        if ((s = rec_eq7_work_alloc_rows(m, &p->scratch->w[part], cap)) != GS_OK) return s;
        if (!(p->scratch->light[part] = malloc(cap * sizeof *p->scratch->light[part]))) {
            rec_eq7_work_free(&p->scratch->w[part]);
            return gs_fail(GS_ENOMEM, "Eq. 7: out of memory for %zu lights", cap);
        }
        p->scratch->cap[part] = cap;
    }
    rec_eq7_work *w = &p->scratch->w[part];   /* (the pass's settings below) */
    size_t *light = p->scratch->light[part];
    w->collect_tau = p->keep && p->keep->tll;
    w->want_flat = p->keep && p->keep->flat;
    w->has_tau_prior = p->last && p->logprior;
    w->chroma_tol = p->last ? p->tol : 0.0;
    w->has_other_prior = p->last && isfinite(p->other);
    w->other_prior = w->has_other_prior ? p->other : 0.0;
    w->flat = p->flat;
    int first = !p->fe && !p->last;   /* pass 1 answers every light */
    for (size_t i = i0; i < i1 && s == GS_OK;) {
        /* a block of the lights this pass matches, one row each; those without a usable sample
         * are answered at once */
        size_t n = 0;
        for (; i < i1 && n < cap; i++) {
            int no_signal = cat->flags && (cat->flags[i] & REC_BLOB_NO_SIGNAL);
            double fe = p->fe ? p->fe[i] : p->fe1;
            if (first && no_signal) {
                rec_eq7_no_answer(&p->out[i], REC_MATCH_BAD_INPUT);
                continue;
            }
            if (!first && (no_signal || !(p->last || fe > 0.0))) continue;
            if (p->flat_i) w->flat = p->flat_i[i];
            if (rec_eq7_light_prepare(m, w, n, cat->signal + i * D, cat->sigma + i * D, fe, &p->out[i])) {
                light[n++] = i;
                continue;
            }
            if (p->ex && first) p->ex[i].valid = 0;
            if (p->keep) keep_fit(w, i, p->keep);   /* (none: prepare said so) */
        }
        rec_eq7_block_sums(m, w, n);
        for (size_t q = 0; q < n && s == GS_OK; q++) {
            size_t l = light[q];
            double fe = p->fe ? p->fe[l] : p->fe1;
            if (w->has_tau_prior) memcpy(w->tau_logprior, p->logprior + l * REC_TAU_N, sizeof w->tau_logprior);
            s = rec_eq7_light_finish(m, w, q, cat->sigma + l * D, fe, &p->out[l], p->ex && first ? &p->ex[l] : NULL);
            if (s == GS_OK && p->keep) keep_fit(w, l, p->keep);
        }
    }
    return s;
}

/* Each light's excess from the others (the kernel-weighted median), over a range of lights. */
typedef struct {
    const ref_light *ref;
    size_t nr;
    const rec_catalog *cat;
    const rec_match *out;
    double hy;
    double *fe;
    size_t k;        /* the references are every k-th of all (NOISE_MAX_REFS) */
    double global;   /* all references' weighted median */
} excess_pass;

static gs_status excess_part(void *ctx, int part, size_t i0, size_t i1)
{
    (void)part;
    const excess_pass *p = ctx;
    double *wk = malloc((p->nr ? p->nr : 1) * sizeof *wk), neff;
    if (!wk) return gs_fail(GS_ENOMEM, "Eq. 7: out of memory for %zu lights", p->nr);
    for (size_t i = i0; i < i1; i++) {
        double lb = log10(p->out[i].brightness > 0.0 ? p->out[i].brightness : 1e-300);
        double e2 = weighted_median(p->ref, p->nr, i, p->cat->y_px ? p->cat->y_px[i] : 0.0, lb, p->hy,
                                    KERNEL_DECADES, 1, wk, &neff);
        /* (over a sample, its own effective count says whether its median can be trusted, and
         * the fallback is the global median of all references: one light left out of thousands
         * would not move it) */
        if (neff < NOISE_MIN_EFFECTIVE)
            e2 = p->k == 1 ? weighted_median(p->ref, p->nr, i, 0, 0, 1, 1, 0, wk, &neff) : p->global;
        p->fe[i] = sqrt(e2);
    }
    free(wk);
    return GS_OK;
}

/* The last pass of rec_match_catalog (eq7_population.c): from the clean lights, the tau prior
 * and the band tolerance (reddened model) and the share of bulbs not in DELIGHT (other_prior
 * NaN); then every light with a signal fitted again under them (pass: the noise of pass 2). */
static gs_status match_with_population(const rec_matcher *m, catalog_pass *pass, const light_fits *fit,
                                       rec_noise_report *rep)
{
    const rec_catalog *cat = pass->cat;
    const rec_match *out = pass->out;
    size_t n = cat->count;
    const unsigned disturbed = REC_BLOB_EDGE | REC_BLOB_SATURATED | REC_BLOB_DEBLENDED | REC_BLOB_NO_SIGNAL;
    const unsigned misfit = REC_MATCH_DIM | REC_MATCH_BAD_INPUT | REC_MATCH_UNKNOWN | REC_MATCH_BLEND;
    unsigned char *is_ref = calloc(n, 1);
    double *logprior = fit->tll ? malloc(n * REC_TAU_N * sizeof *logprior) : NULL;
    gs_status s = GS_OK;
    if (!is_ref || (fit->tll && !logprior)) s = gs_fail(GS_ENOMEM, "Eq. 7: out of memory for %zu lights", n);
    for (size_t i = 0; i < n && s == GS_OK; i++)
        is_ref[i] = !(cat->flags && (cat->flags[i] & disturbed)) && !(out[i].flags & misfit);
    size_t used = s == GS_OK && fit->tll ? rec_eq7_tau_prior(fit->tll, is_ref, cat->y_px, n, cat->height, logprior) : 0;
    double tol = used > 0 ? rec_eq7_chroma_tolerance(m, n, fit->bulb, fit->S, fit->T, fit->z, is_ref) : 0.0;
    /* bulbs not in DELIGHT are the evidence for their share: unknown lights count too */
    double other = NAN;
    size_t other_used = 0;
    if (s == GS_OK && fit->lbf) {
        for (size_t i = 0; i < n; i++)
            is_ref[i] = !(cat->flags && (cat->flags[i] & disturbed)) &&
                        !(out[i].flags & (REC_MATCH_DIM | REC_MATCH_BAD_INPUT | REC_MATCH_BLEND));
        other = rec_eq7_other_share(fit->lbf, is_ref, n, &other_used);
    }
    if (s == GS_OK && (used > 0 || isfinite(other))) {
        pass->ex = NULL;
        pass->keep = NULL;
        pass->last = 1;
        pass->logprior = used > 0 ? logprior : NULL;
        pass->tol = tol;
        pass->other = other;
        s = gs_parallel_chunks(m->o.threads, n, 0, catalog_part, pass);
    }
    rep->reddening_lights = used;
    rep->chroma_tolerance = tol > 0.0 ? tol : m->o.chroma_tolerance;
    rep->other_lights = isfinite(other) ? other_used : 0;
    rep->other_prior = isfinite(other) ? other : isnan(m->o.other_prior) ? 0.0 : m->o.other_prior;
    free(logprior);
    free(is_ref);
    return s;
}

/* The flat share from pass 1's answers: the capture's (rep) and each light's flat_i. Unknown
 * lights and blends count (a flat share is what makes a bright light unknown, or better fitted by
 * two phases of its bulb, whose sum flickers less), so do the PSF fit's sources; the weighted
 * median is robust to the minority of true blends. The capture's: not lights cut by the border
 * or saturated. The lights' shares differ (how much of a halo the photometry takes depends on the
 * light): each light's is its own estimate shrunk under the prior N(phi0, spread^2) (the
 * posterior mean), kept within FLAT_PRIOR_Z spreads of phi0 so that a blend's or an unknown
 * bulb's misfit cannot hide in it; phi0 for a light without an estimate. phi0 and spread are
 * those of the lights measured alike (flat_kind) when theirs is significant, else the capture's. */
#define FLAT_PRIOR_Z 3.0
/* Photometry kinds that take different shares of a halo (REC_FLAT_KINDS): the aperture's or the
 * PSF fit's, with or without pixels saturated in some frame (a fit on the ring around a saturated
 * core extrapolates the ring's halo into the core). On metro_clear at K = 26, C = 1024 the kinds' shares
 * are 0.011 (aperture), 0.020 (PSF fit), 0.014 (aperture, saturated) and 0.038 (PSF fit,
 * saturated); held within 3 spreads of the capture's (0.0124 + 3 x 0.0031), the brightest HPS
 * lights were unknown (docs/recognition.md, "Per photometry kind"). */
static int flat_kind(const rec_catalog *cat, size_t i)
{
    const unsigned f = cat->flags ? cat->flags[i] : 0u;
    return (f & REC_BLOB_PSF_FIT ? 1 : 0) + (f & REC_BLOB_SATURATED ? 2 : 0);
}

/* Light i is a reference of the flat share: an answer that is not dim or bad, nothing of flags
 * cut. */
static int flat_ref_light(const rec_catalog *cat, const rec_match *out, size_t i, unsigned cut)
{
    return !(cat->flags && (cat->flags[i] & cut)) && !(out[i].flags & (REC_MATCH_DIM | REC_MATCH_BAD_INPUT));
}

static gs_status measure_flat(const rec_catalog *cat, const rec_match *out, const light_fits *fit,
                              double *flat_i, rec_noise_report *rep, int *any)
{
    size_t n = cat->count, used;
    const unsigned cut = REC_BLOB_EDGE | REC_BLOB_NO_SIGNAL;
    unsigned char *is_ref = malloc(n);
    if (!is_ref) return gs_fail(GS_ENOMEM, "Eq. 7: out of memory for %zu lights", n);
    for (size_t i = 0; i < n; i++) is_ref[i] = flat_ref_light(cat, out, i, cut | REC_BLOB_SATURATED);
    double share, spread, *kshare = rep->flat_kind_share, kspread[REC_FLAT_KINDS];
    gs_status s = rec_eq7_flat_share(fit->flat, fit->flat_var, is_ref, n, &share, &spread, &rep->flat_lights);
    rep->flat_share = isfinite(share) ? share : 0.0;
    rep->flat_spread = isfinite(share) ? spread : 0.0;
    if (!isfinite(share)) rep->flat_lights = 0;
    *any = rep->flat_share > 0.0;
    for (int k = 0; k < REC_FLAT_KINDS && s == GS_OK; k++) {
        for (size_t i = 0; i < n; i++) is_ref[i] = flat_kind(cat, i) == k && flat_ref_light(cat, out, i, cut);
        s = rec_eq7_flat_share(fit->flat, fit->flat_var, is_ref, n, &kshare[k], &kspread[k], &used);
        rep->flat_kind_lights[k] = kshare[k] > 0.0 ? used : 0;
        if (kshare[k] > 0.0) *any = 1;
        else {
            kshare[k] = rep->flat_share;
            kspread[k] = rep->flat_spread;
        }
    }
    free(is_ref);
    for (size_t i = 0; i < n && s == GS_OK; i++) {
        const int k = flat_kind(cat, i);
        double phi0 = kshare[k], t2 = kspread[k] * kspread[k], v = fit->flat_var[i];
        double f = phi0;
        if (phi0 > 0.0 && t2 > 0.0 && v > 0.0 && isfinite(v) && isfinite(fit->flat[i])) {
            f = (fit->flat[i] / v + phi0 / t2) / (1.0 / v + 1.0 / t2);
            double lo = phi0 - FLAT_PRIOR_Z * kspread[k], hi = phi0 + FLAT_PRIOR_Z * kspread[k];
            f = f < lo ? lo : f > hi ? hi : f;
        }
        flat_i[i] = f < 0.0 ? 0.0 : f > REC_FLAT_MAX ? REC_FLAT_MAX : f;
    }
    return s;
}

static gs_status match_catalog(const rec_matcher *m, const rec_catalog *cat, rec_match *out,
                               rec_noise_report *noise)
{
    if (!m || !cat) return gs_fail(GS_EINVAL, "Eq. 7: matcher and catalog must not be NULL");
    rec_noise_report rep = {isfinite(m->o.model_error) ? REC_NOISE_FIXED : REC_NOISE_CAMERA, 0,
                            isfinite(m->o.model_error) ? m->o.model_error : 0.0, 0, m->o.chroma_tolerance, 0,
                            isnan(m->o.other_prior) ? 0.0 : m->o.other_prior, 0,
                            isnan(m->o.flat_share) ? 0.0 : m->o.flat_share, 0.0, {0}, {0}};
    for (int k = 0; k < REC_FLAT_KINDS; k++) rep.flat_kind_share[k] = rep.flat_share;
    if (noise) *noise = rep;
    if (cat->count == 0) return GS_OK;
    if (!out || !cat->signal || !cat->sigma)
        return gs_fail(GS_EINVAL, "Eq. 7: catalog of %zu lights without signal, sigma or output",
                       cat->count);
    if (cat->bands != m->bands || cat->K != m->K)
        return gs_fail(GS_EINVAL, "Eq. 7: catalog has %d bands x K=%d, the matcher %d bands x K=%d",
                       cat->bands, cat->K, m->bands, m->K);
    size_t n = cat->count;
    int measured = !isfinite(m->o.model_error);
    gs_status s = GS_OK;
    rec_eq7_excess *ex = measured ? calloc(n, sizeof *ex) : NULL;
    ref_light *ref = measured ? malloc(n * sizeof *ref) : NULL;
    double *wk = measured ? malloc(n * sizeof *wk) : NULL, *fe = measured ? malloc(n * sizeof *fe) : NULL;
    light_fits fit = {NULL, NULL, NULL, NULL, NULL, NULL, NULL, NULL};
    int flat_measured = isnan(m->o.flat_share);
    double *flat_i = NULL;
    if (flat_measured) {
        fit.flat = calloc(n, sizeof *fit.flat);
        fit.flat_var = calloc(n, sizeof *fit.flat_var);
        flat_i = malloc(n * sizeof *flat_i);
    }
    if (m->red) {
        fit.tll = malloc(n * REC_TAU_N * sizeof *fit.tll);
        fit.bulb = malloc(n * sizeof *fit.bulb);
        fit.S = malloc(n * GS_MAX_BANDS * sizeof *fit.S);
        fit.T = malloc(n * GS_MAX_BANDS * sizeof *fit.T);
        fit.z = malloc(n * sizeof *fit.z);
    }
    if (isnan(m->o.other_prior)) fit.lbf = malloc(n * sizeof *fit.lbf);
    if (measured && (!ex || !ref || !wk || !fe)) s = gs_fail(GS_ENOMEM, "Eq. 7: out of memory for %zu lights", n);
    if ((m->red && (!fit.tll || !fit.bulb || !fit.S || !fit.T || !fit.z)) || (isnan(m->o.other_prior) && !fit.lbf))
        s = gs_fail(GS_ENOMEM, "Eq. 7: out of memory for %zu lights", n);
    if (flat_measured && (!fit.flat || !fit.flat_var || !flat_i)) s = gs_fail(GS_ENOMEM, "Eq. 7: out of memory for %zu lights", n);
    int population = fit.tll || fit.lbf;
    /* pass 1: the camera noise (or the fixed model error); the lights on the matcher's threads */
    catalog_scratch *scratch = calloc(1, sizeof *scratch);
    if (!scratch) s = gs_fail(GS_ENOMEM, "Eq. 7: out of memory for the lights' scratch");
    catalog_pass pass = {scratch, m, cat, out, ex, NULL, rep.median_model_error, population || flat_measured ? &fit : NULL,
                         0, NULL, 0.0, NAN, rep.flat_share, NULL};
    if (s == GS_OK) s = gs_parallel_chunks(m->o.threads, n, 0, catalog_part, &pass);
    if (s != GS_OK) goto done;
    /* the flat share measured on pass 1's answers; when there is one, pass 1 again without it,
     * so that neither the excess noise nor the last pass's priors absorb its misfit */
    int any_flat = 0;
    if (flat_measured && (s = measure_flat(cat, out, &fit, flat_i, &rep, &any_flat)) != GS_OK) goto done;
    if (any_flat) {
        pass.flat_i = flat_i;
        if ((s = gs_parallel_chunks(m->o.threads, n, 0, catalog_part, &pass)) != GS_OK) goto done;
    }
    if (!measured) goto population;
    /* the clean references: a fit, an informative estimate, an aperture nothing disturbed */
    const unsigned disturbed = REC_BLOB_EDGE | REC_BLOB_SATURATED | REC_BLOB_DEBLENDED | REC_BLOB_NO_SIGNAL;
    size_t nr = 0;
    for (size_t i = 0; i < n; i++) {
        if (!ex[i].valid) continue;
        if (cat->flags && (cat->flags[i] & disturbed)) continue;
        if (out[i].flags & (REC_MATCH_DIM | REC_MATCH_BAD_INPUT)) continue;
        ref[nr].ex = &ex[i];
        ref[nr].e2 = ex[i].e2;
        ref[nr].wt = 1.0;
        ref[nr].y = cat->y_px ? cat->y_px[i] : 0.0;
        ref[nr].lb = log10(out[i].brightness > 0.0 ? out[i].brightness : 1e-300);
        ref[nr].light = i;
        nr++;
    }
    if (nr < NOISE_MIN_LIGHTS) goto population;   /* no population: the camera noise, said so */
    qsort(ref, nr, sizeof *ref, cmp_e2);
    /* the typical excess: the median, then twice the weighted median at the previous value */
    double hy = (cat->height > 0 ? cat->height : 1) / KERNEL_ROWS, neff;
    double global = weighted_median(ref, nr, (size_t)-1, 0, 0, 1, 1, 0, wk, &neff);
    for (int it = 0; it < 2; it++) {
        for (size_t j = 0; j < nr; j++) ref[j].wt = excess_weight(ref[j].ex, m->bands, global);
        global = weighted_median(ref, nr, (size_t)-1, 0, 0, 1, 1, 0, wk, &neff);
    }
    /* the lights' references: all, or every k-th by e2, the middle of each stratum (the
     * kernel's weights and the scan of the median keep the order) */
    size_t k = (nr + NOISE_MAX_REFS - 1) / NOISE_MAX_REFS, ns = 0;
    for (size_t j = k / 2; j < nr; j += k) ref[ns++] = ref[j];
    excess_pass ep = {ref, ns, cat, out, hy, fe, k, global};
    if ((s = gs_parallel_chunks(m->o.threads, n, 0, excess_part, &ep)) != GS_OK) goto done;
    rep.source = REC_NOISE_POPULATION;
    rep.lights_used = nr;
    rep.median_model_error = sqrt(global);
    /* pass 2: the lights whose excess is not zero */
    pass.ex = NULL;
    pass.fe = fe;
    if ((s = gs_parallel_chunks(m->o.threads, n, 0, catalog_part, &pass)) != GS_OK) goto done;
population:
    /* the last pass: every light again under what the population tells (eq7_population.c) */
    if (population) {
        pass.fe = rep.source == REC_NOISE_POPULATION ? fe : NULL;
        pass.fe1 = rep.median_model_error;
        s = match_with_population(m, &pass, &fit, &rep);
    }
    if (noise && s == GS_OK) *noise = rep;
done:
    catalog_scratch_free(scratch);
    free(fit.tll), free(fit.bulb), free(fit.S), free(fit.T), free(fit.z), free(fit.lbf);
    free(fit.flat), free(fit.flat_var), free(flat_i);
    free(fe);
    free(wk);
    free(ref);
    free(ex);
    return s;
}

int rec_frames_left_out(const gs_capture *cap, double max_drift_windows, unsigned char *kept)
{
    int out = 0;
    double limit = rec_drift_limit(max_drift_windows, cap->window_period);
    for (int k = 0; k < cap->K; k++) {
        int keep = rec_frame_kept(gs_capture_frame_drift(cap, k), limit);
        if (kept) kept[k] = (unsigned char)keep;
        out += !keep;
    }
    return out;
}

/* A free-running capture's samples (cat->drift_windows, kept[k]: rec_frame_kept): a frame not
 * kept is left out (sigma = +inf); a kept frame k whose windows moved d_k windows is Eq. 5's
 * window shifted by up to d_k / 2 windows on average (the smear's mean), so its samples' noise
 * gets d_k / 2 times the light's steepest step between adjacent kept windows in the band added
 * in quadrature (a bound of the template's change, from the light's own samples). */
static void drift_sigma(const rec_catalog *cat, const unsigned char *kept, size_t i, double *sigma)
{
    size_t K = (size_t)cat->K;
    const double *dr = cat->drift_windows;
    for (int band = 0; band < cat->bands; band++) {
        size_t o = (i * (size_t)cat->bands + (size_t)band) * K;
        const double *x = cat->signal + o;
        double step = 0.0;
        for (size_t k = 0; k < K; k++) {
            size_t k2 = (k + 1) % K;
            if (kept[k] && kept[k2] && isfinite(x[k]) && isfinite(x[k2])) step = fmax(step, fabs(x[k2] - x[k]));
        }
        for (size_t k = 0; k < K; k++) sigma[o + k] = kept[k] ? hypot(sigma[o + k], 0.5 * dr[k] * step) : INFINITY;
    }
}

gs_status rec_match_catalog(const rec_matcher *m, const rec_catalog *cat, rec_match *out,
                            rec_noise_report *noise)
{
    size_t drifted = 0, K = cat ? (size_t)cat->K : 0, D = cat ? (size_t)cat->bands * K : 0;
    for (size_t k = 0; cat && cat->drift_windows && k < K; k++) drifted += !(cat->drift_windows[k] == 0.0);
    if (!drifted || !cat->count || !cat->sigma || !cat->signal) return match_catalog(m, cat, out, noise);
    rec_catalog kept = *cat;
    double *sigma = malloc(sizeof *sigma * cat->count * D);
    unsigned char *frame_kept = malloc(K);
    if (!sigma || !frame_kept) {
        free(sigma), free(frame_kept);
        return gs_fail(GS_ENOMEM, "Eq. 7: out of memory for %zu lights", cat->count);
    }
    double limit = rec_drift_limit(m->o.max_drift_windows, cat->window_period);
    for (size_t k = 0; k < K; k++) frame_kept[k] = (unsigned char)rec_frame_kept(cat->drift_windows[k], limit);
    memcpy(sigma, cat->sigma, sizeof *sigma * cat->count * D);
    for (size_t i = 0; i < cat->count; i++) drift_sigma(cat, frame_kept, i, sigma);
    kept.sigma = sigma;
    gs_status s = match_catalog(m, &kept, out, noise);
    free(sigma), free(frame_kept);
    for (size_t i = 0; s == GS_OK && i < cat->count; i++) out[i].flags |= REC_MATCH_DRIFT;
    return s;
}
