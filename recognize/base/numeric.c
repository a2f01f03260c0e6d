/* numeric.c - the special functions and order statistics the tool shares: the chi-square tail
 * and its inverse (Eq. 7's unknown test, the phase-balance test), log Phi (Eq. 7's posterior
 * with the brightness marginalised), and the quickselect median (background meshes). */
#include "recognize/base/base.h"

#include <math.h>

#define LOG_SQRT_2PI 0.91893853320467274178032973640562

/* Regularised upper incomplete gamma Q(a, x), a > 0, x > 0: the series for P when x < a + 1,
 * else the continued fraction for Q (modified Lentz), as in Numerical Recipes 6.2, with libm's
 * lgamma. */
static double gamma_q(double a, double x)
{
    double lpre = a * log(x) - x - lgamma(a);
    if (x < a + 1.0) {
        double ap = a, del = 1.0 / a, sum = del;
        for (int n = 0; n < 100000; n++) {
            ap += 1.0;
            del *= x / ap;
            sum += del;
            if (fabs(del) < fabs(sum) * 1e-17) break;
        }
        double p = sum * exp(lpre);
        return p >= 1.0 ? 0.0 : 1.0 - p;
    }
    double tiny = 1e-300;
    double b = x + 1.0 - a, c = 1.0 / tiny, d = 1.0 / b, h = d;
    for (int i = 1; i < 100000; i++) {
        double an = -i * (i - a);
        b += 2.0;
        d = an * d + b;
        if (fabs(d) < tiny) d = tiny;
        c = b + an / c;
        if (fabs(c) < tiny) c = tiny;
        d = 1.0 / d;
        double del = d * c;
        h *= del;
        if (fabs(del - 1.0) < 1e-16) break;
    }
    return exp(lpre) * h;
}

double gs_chi2_sf(double chi2, int dof)
{
    if (isnan(chi2) || dof < 1) return NAN;
    if (chi2 <= 0.0) return 1.0;
    if (isinf(chi2)) return 0.0;
    if (dof == 2) return exp(-0.5 * chi2);   /* Q(1, x/2) = exp(-x/2) exactly */
    return gamma_q(0.5 * dof, 0.5 * chi2);
}

double gs_chi2_isf(double p, int dof)
{
    if (isnan(p) || dof < 1) return NAN;
    if (p <= 0.0) return INFINITY;
    if (p >= 1.0) return 0.0;
    double lo = 0.0, hi = dof + 10.0 * sqrt(2.0 * dof) + 100.0;
    while (gs_chi2_sf(hi, dof) > p) hi *= 2.0;
    for (int i = 0; i < 200 && hi - lo > 1e-12 * hi; i++) {
        double mid = 0.5 * (lo + hi);
        if (gs_chi2_sf(mid, dof) > p) lo = mid;
        else hi = mid;
    }
    return hi;
}

double gs_log_phi(double z)
{
    if (z > 40.0) return -0.0;   /* erfc(z / sqrt 2) underflows to 0 from z = 38.6 */
    if (z > 0.0) return log1p(-0.5 * erfc(z * M_SQRT1_2));
    if (z > -20.0) return log(0.5 * erfc(-z * M_SQRT1_2));
    /* Mills ratio, asymptotic series */
    double r = 1.0 / (z * z);
    return -0.5 * z * z - log(-z) - LOG_SQRT_2PI + log1p(r * (-1.0 + r * (3.0 + r * (-15.0 + r * 105.0))));
}

double gs_wrap360(double a_deg)
{
    double r = fmod(a_deg, 360.0);
    if (r < 0.0) r += 360.0;
    return r >= 360.0 ? 0.0 : r;   /* fmod of tiny negatives can round to 360 */
}

double gs_wrap180(double a_deg)
{
    return gs_wrap360(a_deg + 180.0) - 180.0;
}

float gs_median_f(float *v, size_t n)
{
    size_t k = n / 2, lo = 0, hi = n - 1;
    while (lo < hi) {
        float pivot = v[lo + (hi - lo) / 2];
        size_t i = lo, j = hi;
        while (i <= j) {
            while (v[i] < pivot) i++;
            while (v[j] > pivot) j--;
            if (i <= j) {
                float t = v[i];
                v[i] = v[j];
                v[j] = t;
                i++;
                if (j == 0) break;
                j--;
            }
        }
        if (k <= j) hi = j;
        else if (k >= i) lo = i;
        else break;
    }
    return v[k];
}

GS_VECTOR_LOOP
double gs_dot(const double *x, const double *t, size_t n)
{
    double a[8] = {0, 0, 0, 0, 0, 0, 0, 0};
    size_t i = 0;
    for (; i + 8 <= n; i += 8)
        for (int k = 0; k < 8; k++) a[k] += x[i + k] * t[i + k];
    for (; i < n; i++) a[0] += x[i] * t[i];
    return ((a[0] + a[1]) + (a[2] + a[3])) + ((a[4] + a[5]) + (a[6] + a[7]));
}
