/* ml_oracle.c - the maximum-likelihood oracle for Eq. 7 (recognize.h, "maximum-likelihood
 * oracle"): brute force over every template, the exact Poisson-Gaussian likelihood of each
 * sample, the brightness profiled by golden-section search. Written without anything from
 * eq7.c, so it can judge it (tests/test_eq7_accuracy.c, `gridsurvey bench accuracy`). */
#include "recognize/recognize.h"

#include <math.h>
#include <stdlib.h>

/* log n! */
static double lfact(long n)
{
    return lgamma((double)n + 1.0);
}

/* log p(x | mean mu of the light) for one sample, exact: the sum over electron counts n of
 * Pois(n; g mu + bg) N(x - (n - bg)/g; 0, r^2), evaluated from its mode outwards until the terms
 * fall below 1e-17 of the largest (the summand is log-concave in n). Successive terms by their
 * ratio: e_{n+1}/e_n = lambda/(n+1) q_n, q_n = exp((2 xe - (2n+1)/g)/(2 g r^2)),
 * q_{n+1} = q_n exp(-1/(g r)^2). */
double rec_pg_log_likelihood(const rec_pg_noise *c, double x, double mu)
{
    double g = c->gain, r = c->read_dn;
    double lam = g * (mu > 0 ? mu : 0) + c->bg_e;
    double xe = x + c->bg_e / g;   /* units of x including the background */
    double inv2r2 = 1.0 / (2.0 * r * r);
    double loglam = lam > 0 ? log(lam) : 0;
#define TERM(n_) ((lam > 0 ? -lam + (double)(n_) * loglam - lfact(n_) : ((n_) == 0 ? 0.0 : -INFINITY)) - \
                  (xe - (double)(n_) / g) * (xe - (double)(n_) / g) * inv2r2)
    /* mode of the product of the Poisson and the Gaussian in n */
    double gr2 = g * g * r * r;
    double nstart = lam > 0 ? (lam * gr2 + g * xe * lam) / (lam + gr2) : 0;
    long n = nstart < 0 ? 0 : (long)floor(nstart + 0.5);
    double tn = TERM(n);
    while (TERM(n + 1) > tn) {
        n++;
        tn = TERM(n);
    }
    while (n > 0 && TERM(n - 1) > tn) {
        n--;
        tn = TERM(n);
    }
#undef TERM
    double sum = 1.0;
    if (lam > 0) {
        double cq = exp(-1.0 / gr2);
        double q0 = exp((2.0 * xe - (2.0 * (double)n + 1.0) / g) / g * inv2r2), q = q0, e = 1.0;
        for (long k = n;; k++) {   /* upwards: e_{k+1} = e_k lam/(k+1) q_k */
            e *= lam / (double)(k + 1) * q;
            q *= cq;
            sum += e;
            if (e < 1e-17) break;
        }
        q = q0 / cq;   /* q_{n-1} */
        e = 1.0;
        for (long k = n; k > 0; k--) {   /* downwards: e_{k-1} = e_k k / (lam q_{k-1}) */
            e *= (double)k / (lam * q);
            q /= cq;
            sum += e;
            if (e < 1e-17) break;
        }
    }
    return tn + log(sum) - log(r * sqrt(2.0 * M_PI));
}

static const rec_pg_noise *nz(const rec_pg_noise *noise, int per_sample, int k)
{
    return per_sample ? noise + k : noise;
}

/* The log likelihood of brightness a: per sample exactly (Poisson-Gaussian) where frame k has
 * no excess; where it has one (relative variance v, one flux factor for the frame's samples of
 * every band), the frame's samples are Gaussian with the Poisson-Gaussian variances d_b and
 * covariance diag(d) + v mu mu^T (mu_b = a t_b), by Sherman-Morrison and the determinant lemma. */
static double loglik(const rec_pg_noise *noise, int per_sample, const rec_pg_excess *ex,
                     const double *x, const double *t, int D, double a)
{
    double l = 0.0;
    int K = ex ? ex->K : D;
    for (int k = 0; k < K; k++) {
        double v = ex ? ex->frame_var[k] : 0.0;
        if (!(v > 0.0)) {
            for (int d = k; d < D; d += K) l += rec_pg_log_likelihood(nz(noise, per_sample, d), x[d], a * t[d]);
            continue;
        }
        double q = 0.0, uq = 0.0, uu = 0.0, ld = 0.0;
        for (int d = k; d < D; d += K) {
            const rec_pg_noise *c = nz(noise, per_sample, d);
            double mu = a * t[d], r = x[d] - mu;
            double var = c->read_dn * c->read_dn + (c->gain * (mu > 0 ? mu : 0) + c->bg_e) / (c->gain * c->gain);
            q += r * r / var;
            uq += mu * r / var;
            uu += mu * mu / var;
            ld += log(2.0 * M_PI * var);
        }
        l += -0.5 * (q - v * uq * uq / (1.0 + v * uu)) - 0.5 * (ld + log1p(v * uu));
    }
    return l;
}

gs_status rec_ml_oracle(const rec_pg_noise *noise, int per_sample, const rec_pg_excess *ex,
                        const double *x, const double *templates, int M, int D, int *best_out,
                        double *loglik_out)
{
    if (!noise || !x || !templates || !best_out || M < 1 || D < 1)
        return gs_fail(GS_EINVAL, "rec_ml_oracle: NULL argument or M = %d, D = %d", M, D);
    if (ex) {
        if (!ex->frame_var || ex->K < 1 || D % ex->K)
            return gs_fail(GS_EINVAL, "rec_ml_oracle: excess of K = %d frames for %d samples: "
                           "expected K dividing D and frame_var", ex->K, D);
        for (int k = 0; k < ex->K; k++)
            if (!(ex->frame_var[k] >= 0.0) || !isfinite(ex->frame_var[k]))
                return gs_fail(GS_EINVAL, "rec_ml_oracle: frame %d: excess variance %g: expected "
                               "finite and >= 0", k, ex->frame_var[k]);
    }
    for (int k = 0; k < (per_sample ? D : 1); k++) {
        const rec_pg_noise *c = nz(noise, per_sample, k);
        if (!(c->gain > 0) || !(c->read_dn > 0) || !(c->bg_e >= 0) || !isfinite(c->gain) ||
            !isfinite(c->read_dn) || !isfinite(c->bg_e))
            return gs_fail(GS_EINVAL, "rec_ml_oracle: sample %d: gain %g, read noise %g, "
                           "background %g: expected finite gain > 0, read noise > 0, "
                           "background >= 0", k, c->gain, c->read_dn, c->bg_e);
    }
    for (int k = 0; k < D; k++)
        if (!isfinite(x[k])) return gs_fail(GS_EINVAL, "rec_ml_oracle: sample %d is not finite", k);
    double *lb = malloc(sizeof *lb * 2 * (size_t)M);
    if (!lb) return gs_fail(GS_ENOMEM, "rec_ml_oracle: out of memory for %d templates", M);
    double *alsq = lb + M, best_lb = -INFINITY;
    for (int j = 0; j < M; j++) {
        const double *t = templates + (size_t)j * (size_t)D;
        double num = 0, den = 0;
        for (int k = 0; k < D; k++) {
            num += x[k] * t[k];
            den += t[k] * t[k];
        }
        double a = den > 0 ? num / den : 0;
        if (!(a > 1e-9)) a = 1e-9;
        alsq[j] = a;
        lb[j] = loglik(noise, per_sample, ex, x, t, D, a);
        if (lb[j] > best_lb) best_lb = lb[j];
    }
    int best = 0;
    double bestv = -INFINITY;
    const double gr = (sqrt(5.0) - 1.0) / 2.0;
    for (int j = 0; j < M; j++) {
        if (lb[j] < best_lb - 30.0) continue;
        const double *t = templates + (size_t)j * (size_t)D;
        /* bracket: +-6 standard deviations of a at the least-squares value */
        double a0 = alsq[j], den = 0, var = 0;
        for (int k = 0; k < D; k++) {
            const rec_pg_noise *c = nz(noise, per_sample, k);
            den += t[k] * t[k];
            var += t[k] * t[k] * (c->read_dn * c->read_dn + (a0 * t[k] * c->gain + c->bg_e) / (c->gain * c->gain));
        }
        for (int f = 0; ex && f < ex->K; f++) {   /* the excess: a^2 sum_k v_k (sum_{d in k} t_d^2)^2 */
            double tk = 0;
            for (int d = f; d < D; d += ex->K) tk += t[d] * t[d];
            var += ex->frame_var[f] * a0 * a0 * tk * tk;
        }
        double sa = den > 0 ? sqrt(var) / den : 0;
        double lo = a0 - 6 * sa, hi = a0 + 6 * sa;
        if (lo < 1e-9) lo = 1e-9;
        if (hi < lo) hi = lo;
        double p = hi - gr * (hi - lo), q = lo + gr * (hi - lo);
        double fp = loglik(noise, per_sample, ex, x, t, D, p), fq = loglik(noise, per_sample, ex, x, t, D, q);
        for (int it = 0; it < 18; it++) {   /* bracket / 5800: ~1e-6 nats from the top */
            if (fp > fq) {
                hi = q;
                q = p;
                fq = fp;
                p = hi - gr * (hi - lo);
                fp = loglik(noise, per_sample, ex, x, t, D, p);
            } else {
                lo = p;
                p = q;
                fp = fq;
                q = lo + gr * (hi - lo);
                fq = loglik(noise, per_sample, ex, x, t, D, q);
            }
        }
        double v = fp > fq ? fp : fq;
        if (lb[j] > v) v = lb[j];
        if (v > bestv) {
            bestv = v;
            best = j;
        }
    }
    free(lb);
    *best_out = best;
    if (loglik_out) *loglik_out = bestv;
    return GS_OK;
}
