/* bench_oracle.c - the ceiling of `gridsurvey bench accuracy` (docs/accuracy.md): the
 * maximum-likelihood oracle (rec_ml_oracle) on a subset of a point's extracted lights, knowing the
 * scene's whole forward model: the camera's Poisson-Gaussian noise of each aperture, each light's
 * extinction per band and its scintillation (the simulator's truth.json), the truth's phase set.
 * The subset's pipeline answers and the oracle's are stored as two captures of the point's
 * survey and scored by srv_evaluate. */
#include "survey/internal.h"

#include <jansson.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* What the oracle knows of one truth light's atmosphere. */
typedef struct {
    double x, y;
    double trans[GS_MAX_BANDS];   /* transmission per band (1: no extinction) */
    double s2, rho;               /* scintillation: log-variance per cycle, cycle-to-cycle correlation */
} atmo_light;

/* The in-image truth lights' atmosphere (truth.json, docs/formats.md); fields absent: none. */
static gs_status read_atmosphere(const char *truth, int bands, atmo_light **out, size_t *count)
{
    gs_json *doc;
    *out = NULL;
    *count = 0;
    gs_status s = gs_json_load(truth, 0, &doc);
    if (s != GS_OK) return s;
    json_t *arr = json_object_get(gs_json_root(doc), "lights");
    size_t n = json_array_size(arr), k = 0;
    atmo_light *a = calloc(n ? n : 1, sizeof *a);
    if (!a) {
        gs_json_free(doc);
        return gs_fail(GS_ENOMEM, "%s: out of memory", truth);
    }
    for (size_t i = 0; i < n; i++) {
        json_t *o = json_array_get(arr, i), *t = json_object_get(o, "transmission");
        if (!json_is_true(json_object_get(o, "in_image"))) continue;
        atmo_light *l = &a[k++];
        l->x = json_number_value(json_object_get(o, "x_px"));
        l->y = json_number_value(json_object_get(o, "y_px"));
        for (int b = 0; b < bands; b++)
            l->trans[b] = json_array_size(t) == (size_t)bands ? json_number_value(json_array_get(t, (size_t)b)) : 1.0;
        l->s2 = json_number_value(json_object_get(o, "scintillation_log_var"));
        l->rho = json_number_value(json_object_get(o, "scintillation_rho"));
    }
    gs_json_free(doc);
    *out = a;
    *count = k;
    return GS_OK;
}

/* The relative variance of the mean over C cycles of the simulator's scintillation factor
 * exp(x_c - s2/2), x an AR(1) process of variance s2 and lag-one correlation rho (capture/
 * effects.c): (1/C^2) sum_{c,c'} (exp(s2 rho^|c - c'|) - 1). */
static double frame_variance(double s2, double rho, long C)
{
    if (!(s2 > 0.0) || C < 1) return 0.0;
    double sum = (double)C * expm1(s2), r = 1.0;
    for (long l = 1; l < C; l++) {
        r *= rho;
        double term = expm1(s2 * r);
        sum += 2.0 * (double)(C - l) * term;
        if (term < 1e-16 * expm1(s2)) break;
    }
    return sum / ((double)C * (double)C);
}

static const atmo_light *nearest(const atmo_light *a, size_t n, double x, double y)
{
    const atmo_light *best = NULL;
    double d2 = INFINITY;
    for (size_t i = 0; i < n; i++) {
        double dx = a[i].x - x, dy = a[i].y - y;
        if (dx * dx + dy * dy < d2) {
            d2 = dx * dx + dy * dy;
            best = &a[i];
        }
    }
    return best;
}

gs_status srv_acc_oracle(srv_db *db, const srv_run_report *rr, const srv_job *j,
                         const srv_light_row *rows, double transformer, double max_drift_windows, int n_oracle,
                         srv_light_row *sub, srv_acc_point *p)
{
    p->ours_sub = p->oracle_sub = NAN;
    if (!(j->cap.gain_e_per_dn > 0) || n_oracle <= 0) return GS_OK;
    const rec_matcher *m = j->matcher;
    size_t n = j->cat.count, nb = rec_matcher_bulb_count(m);
    int K = j->cat.K, B = j->cat.bands, D = K * B, M = 0;
    /* templates of the matcher's voltage-referenced bulbs at the truth's phase set (0/120/240
     * and the same + the transformer's shift), chromaticity included */
    double phases[6] = {0, 120, 240, fmod(transformer + 360.0, 360.0), fmod(transformer + 480.0, 360.0),
                        fmod(transformer + 600.0, 360.0)};
    double *tab = malloc(sizeof *tab * nb * 6 * (size_t)D), *tl = malloc(sizeof *tl * nb * 6 * (size_t)D);
    double *x = calloc((size_t)D, sizeof *x), *fv = calloc((size_t)K, sizeof *fv), *tp = malloc(sizeof *tp * nb * 6);
    int *tb = malloc(sizeof *tb * nb * 6), *npix = calloc(n ? n : 1, sizeof *npix);
    unsigned char *kept = malloc((size_t)K);
    rec_pg_noise *nz = calloc((size_t)D, sizeof *nz);
    srv_light_row *orc = NULL;
    atmo_light *atmo = NULL;
    size_t natmo = 0;
    gs_status s = GS_OK;
    if (!tab || !tl || !x || !fv || !tp || !tb || !npix || !kept || !nz) {
        s = gs_fail(GS_ENOMEM, "bench accuracy: out of memory for the oracle");
        goto done;
    }
    rec_frames_left_out(&j->cap, max_drift_windows, kept);
    for (size_t b = 0; b < nb && s == GS_OK; b++) {
        const gs_bulb *bu = rec_matcher_bulb(m, b);
        if (bu->ref != GS_REF_VOLTAGE) continue;
        for (int ph = 0; ph < 6 && s == GS_OK; ph++) {
            double *t = tab + (size_t)M * (size_t)D;
            s = gs_brf_integrate(&bu->brf, gs_phase_to_shift(phases[ph]), K, t);
            for (int d = 0; d < D; d++) t[d] *= bu->chroma[d / K];
            tb[M] = (int)b;
            tp[M] = phases[ph];
            M++;
        }
    }
    if (s != GS_OK || (s = read_atmosphere(rr->truth_path, B, &atmo, &natmo)) != GS_OK) goto done;
    /* aperture sizes */
    for (size_t q = 0; q < (size_t)j->cat.width * (size_t)j->cat.height; q++)
        if (j->cat.labels[q] >= 0 && (size_t)j->cat.labels[q] < n) npix[j->cat.labels[q]]++;
    /* the subset: unflagged lights (no saturation, HDR, edge or deblending), evenly spaced */
    size_t eligible = 0;
    const unsigned bad = REC_BLOB_EDGE | REC_BLOB_SATURATED | REC_BLOB_DEBLENDED | REC_BLOB_HDR | REC_BLOB_NO_SIGNAL;
    for (size_t i = 0; i < n; i++) eligible += !(j->cat.flags[i] & bad) && npix[i] > 0;
    size_t want = eligible < (size_t)n_oracle ? eligible : (size_t)n_oracle, seen = 0, k = 0;
    orc = calloc(want ? want : 1, sizeof *orc);
    if (!orc) {
        s = gs_fail(GS_ENOMEM, "bench accuracy: out of memory");
        goto done;
    }
    double r2 = gs_capture_noise(&j->cap).read_var_dn2, ge = j->cap.gain_e_per_dn;
    for (size_t i = 0; i < n && k < want && s == GS_OK; i++) {
        if ((j->cat.flags[i] & bad) || npix[i] <= 0) continue;
        if (seen++ != k * eligible / want) continue;
        /* the camera's noise of an aperture sum of npix pixels, in DN per cycle: Poisson
         * electrons (gain_e_per_dn * cycles per unit), read + quantisation noise of npix
         * pixels, and the background's electrons: the shot part of the extractor's sigma
         * (which is shot + read + background estimate) less the light's own, per band */
        for (int band = 0; band < B; band++) {
            double bg = 0;
            for (int kk = 0; kk < K; kk++) {
                int d = band * K + kk;
                double c = j->cap.frames[kk].cycles, g = ge * c;
                double sig = j->cat.sigma[i * (size_t)D + (size_t)d];
                x[d] = j->cat.signal[i * (size_t)D + (size_t)d];
                double tot_e = (sig * sig * c * c - npix[i] * r2) * ge * ge;
                bg += (tot_e - x[d] * g) / K;
                nz[d].gain = g;
                nz[d].read_dn = sqrt(npix[i] * r2) / c;
            }
            for (int kk = 0; kk < K; kk++) nz[band * K + kk].bg_e = bg > 0 ? bg : 0;
        }
        /* the light's atmosphere: the templates reddened by its transmission, its frames'
         * scintillation variance */
        const atmo_light *al = nearest(atmo, natmo, j->cat.x_px[i], j->cat.y_px[i]);
        int scint = 0;
        for (int q = 0; q < M; q++)
            for (int d = 0; d < D; d++)
                tl[(size_t)q * D + d] = tab[(size_t)q * D + d] * (al ? al->trans[d / K] : 1.0);
        for (int kk = 0; kk < K; kk++) {
            fv[kk] = al ? frame_variance(al->s2, al->rho, lround(j->cap.frames[kk].cycles)) : 0.0;
            scint |= fv[kk] > 0.0;
        }
        /* the frames Eq. 7 leaves out (free running, rec_frame_kept): 0 in the data and every
         * template, a term the same for every candidate and brightness */
        for (int kk = 0; kk < K; kk++)
            if (!kept[kk])
                for (int d = kk; d < D; d += K) {
                    x[d] = 0.0;
                    for (int q = 0; q < M; q++) tl[(size_t)q * D + d] = 0.0;
                }
        rec_pg_excess ex = {K, fv};
        int best = 0;
        if ((s = rec_ml_oracle(nz, 1, scint ? &ex : NULL, x, tl, M, D, &best, NULL)) != GS_OK) break;
        const gs_bulb *bu = rec_matcher_bulb(m, (size_t)tb[best]);
        sub[k] = rows[i];
        sub[k].index = (int)k;
        orc[k] = rows[i];
        orc[k].index = (int)k;
        orc[k].bulb_id = bu->id;
        orc[k].technology = gs_tech_name(bu->type);
        orc[k].phase_deg = tp[best];
        orc[k].phase_fit_deg = tp[best];
        orc[k].confidence = orc[k].bulb_confidence = orc[k].phase_confidence = 1.0;
        orc[k].runner_bulb_id = NULL;
        orc[k].runner_phase_deg = NAN;
        orc[k].runner_confidence = 0;
        orc[k].match_flags = 0;
        k++;
    }
    srv_eval_report eo1, eo2;
    if (s == GS_OK && k) s = srv_acc_eval_subset(db, rr->survey_id, "oracle-subset-pipeline", sub, k, rr->truth_path, &eo1);
    if (s == GS_OK && k) s = srv_acc_eval_subset(db, rr->survey_id, "oracle-subset-oracle", orc, k, rr->truth_path, &eo2);
    if (s == GS_OK && k) {
        p->oracle_n = eo1.matched;
        p->ours_sub = eo1.matched ? (double)eo1.all_correct / (double)eo1.matched : NAN;
        p->oracle_sub = eo2.matched ? (double)eo2.all_correct / (double)eo2.matched : NAN;
    }
done:
    free(atmo);
    free(orc);
    free(nz);
    free(kept);
    free(npix);
    free(tb);
    free(tp);
    free(fv);
    free(x);
    free(tl);
    free(tab);
    return s;
}
