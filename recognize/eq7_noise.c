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
 * Pass 2 fits again the lights whose excess is not zero. */
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
} light_fits;

static void keep_fit(const rec_eq7_work *w, size_t i, light_fits *fit)
{
    if (fit->tll) {
        memcpy(fit->tll + i * REC_TAU_N, w->tau_ll, sizeof w->tau_ll);
        fit->bulb[i] = w->fit_bulb;
        memcpy(fit->S + i * GS_MAX_BANDS, w->fit_S, sizeof w->fit_S);
        memcpy(fit->T + i * GS_MAX_BANDS, w->fit_T, sizeof w->fit_T);
        fit->z[i] = w->fit_z;
    }
    if (fit->lbf) fit->lbf[i] = w->other_lbf;
}

/* The last pass of rec_match_catalog (eq7_population.c): from the clean lights, the tau prior
 * and the band tolerance (reddened model) and the share of bulbs not in DELIGHT (other_prior
 * NaN); then every light with a signal fitted again under them, with its noise fe[i] (NULL: the
 * report's fixed or zero excess). */
static gs_status match_with_population(const rec_matcher *m, rec_eq7_work *w, const rec_catalog *cat,
                                       rec_match *out, const light_fits *fit, const double *fe,
                                       rec_noise_report *rep)
{
    size_t n = cat->count, D = (size_t)m->D;
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
    w->collect_tau = 0;
    w->has_tau_prior = used > 0;
    w->chroma_tol = tol;
    w->has_other_prior = isfinite(other);
    w->other_prior = isfinite(other) ? other : 0.0;
    for (size_t i = 0; i < n && s == GS_OK && (used > 0 || isfinite(other)); i++) {
        if (cat->flags && (cat->flags[i] & REC_BLOB_NO_SIGNAL)) continue;
        if (logprior) memcpy(w->tau_logprior, logprior + i * REC_TAU_N, sizeof w->tau_logprior);
        s = rec_eq7_match_light_ws(m, w, cat->signal + i * D, cat->sigma + i * D,
                                   fe ? fe[i] : rep->median_model_error, &out[i], NULL);
    }
    w->has_tau_prior = w->has_other_prior = 0;
    w->chroma_tol = 0.0;
    rep->reddening_lights = used;
    rep->chroma_tolerance = tol > 0.0 ? tol : m->o.chroma_tolerance;
    rep->other_lights = isfinite(other) ? other_used : 0;
    rep->other_prior = isfinite(other) ? other : isnan(m->o.other_prior) ? 0.0 : m->o.other_prior;
    free(logprior);
    free(is_ref);
    return s;
}

gs_status rec_match_catalog(const rec_matcher *m, const rec_catalog *cat, rec_match *out,
                            rec_noise_report *noise)
{
    if (!m || !cat) return gs_fail(GS_EINVAL, "Eq. 7: matcher and catalog must not be NULL");
    rec_noise_report rep = {isfinite(m->o.model_error) ? REC_NOISE_FIXED : REC_NOISE_CAMERA, 0,
                            isfinite(m->o.model_error) ? m->o.model_error : 0.0, 0, m->o.chroma_tolerance, 0,
                            isnan(m->o.other_prior) ? 0.0 : m->o.other_prior};
    if (noise) *noise = rep;
    if (cat->count == 0) return GS_OK;
    if (!out || !cat->signal || !cat->sigma)
        return gs_fail(GS_EINVAL, "Eq. 7: catalog of %zu lights without signal, sigma or output",
                       cat->count);
    if (cat->bands != m->bands || cat->K != m->K)
        return gs_fail(GS_EINVAL, "Eq. 7: catalog has %d bands x K=%d, the matcher %d bands x K=%d",
                       cat->bands, cat->K, m->bands, m->K);
    size_t n = cat->count, D = (size_t)m->D;
    int measured = !isfinite(m->o.model_error);
    rec_eq7_work w;
    gs_status s = rec_eq7_work_alloc(m, &w);
    if (s != GS_OK) return s;
    rec_eq7_excess *ex = measured ? calloc(n, sizeof *ex) : NULL;
    ref_light *ref = measured ? malloc(n * sizeof *ref) : NULL;
    double *wk = measured ? malloc(n * sizeof *wk) : NULL, *fe = measured ? malloc(n * sizeof *fe) : NULL;
    light_fits fit = {NULL, NULL, NULL, NULL, NULL, NULL};
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
    w.collect_tau = m->red;   /* for the last pass (match_with_population) */
    /* pass 1: the camera noise (or the fixed model error) */
    for (size_t i = 0; i < n && s == GS_OK; i++) {
        if (cat->flags && (cat->flags[i] & REC_BLOB_NO_SIGNAL)) {
            rec_eq7_no_answer(&out[i], REC_MATCH_BAD_INPUT);
            continue;
        }
        s = rec_eq7_match_light_ws(m, &w, cat->signal + i * D, cat->sigma + i * D, rep.median_model_error,
                                   &out[i], ex ? &ex[i] : NULL);
        keep_fit(&w, i, &fit);
    }
    if (s != GS_OK) goto done;
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
    for (size_t i = 0; i < n; i++) {
        double lb = log10(out[i].brightness > 0.0 ? out[i].brightness : 1e-300);
        double e2 = weighted_median(ref, nr, i, cat->y_px ? cat->y_px[i] : 0.0, lb, hy, KERNEL_DECADES,
                                    1, wk, &neff);
        if (neff < NOISE_MIN_EFFECTIVE) e2 = weighted_median(ref, nr, i, 0, 0, 1, 1, 0, wk, &neff);
        fe[i] = sqrt(e2);
    }
    rep.source = REC_NOISE_POPULATION;
    rep.lights_used = nr;
    rep.median_model_error = sqrt(global);
    /* pass 2: the lights whose excess is not zero */
    for (size_t i = 0; i < n && s == GS_OK; i++) {
        if (cat->flags && (cat->flags[i] & REC_BLOB_NO_SIGNAL)) continue;
        if (fe[i] > 0.0) {
            s = rec_eq7_match_light_ws(m, &w, cat->signal + i * D, cat->sigma + i * D, fe[i], &out[i], NULL);
            keep_fit(&w, i, &fit);
        }
    }
population:
    /* the last pass: every light again under what the population tells (eq7_population.c) */
    if (s == GS_OK && (fit.tll || fit.lbf))
        s = match_with_population(m, &w, cat, out, &fit, rep.source == REC_NOISE_POPULATION ? fe : NULL, &rep);
    if (noise && s == GS_OK) *noise = rep;
done:
    free(fit.tll), free(fit.bulb), free(fit.S), free(fit.T), free(fit.z), free(fit.lbf);
    free(fe);
    free(wk);
    free(ref);
    free(ex);
    rec_eq7_work_free(&w);
    return s;
}
