/* numeric.c - the special functions and order statistics the tool shares: the chi-square tail
 * and its inverse (Eq. 7's unknown test, the phase-balance test), log Phi (Eq. 7's posterior
 * with the brightness marginalised), and the quickselect median (background meshes). */
#include "recognize/base/base.h"

#include <cblas.h>
#include <ctype.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define LOG_SQRT_2PI 0.91893853320467274178032973640562

/* Regularised upper incomplete gamma Q(a, x), a > 0, x > 0, with libm's lgamma (Numerical
 * Recipes 6.2): the series for P when x < a + 1, else the continued fraction for Q. Both in steps
 * of 8 terms without a division on the chain of terms: the series' 8 ratios x / (a + n) are
 * independent divisions, the fraction's convergents Q_n / P_n come from the three-term recurrences
 * of their numerators and denominators, rescaled (and tested) once per step. */
static double gamma_q(double a, double x)
{
    double lpre = a * log(x) - x - lgamma(a);
    if (x < a + 1.0) {
        double ap = a, del = 1.0 / a, sum = del;
        for (int n = 0; n < 100000; n += 8) {
            double r[8];
            for (int i = 0; i < 8; i++) r[i] = x / (ap + (i + 1));
            for (int i = 0; i < 8; i++) {
                del *= r[i];
                sum += del;
            }
            ap += 8.0;
            if (fabs(del) < fabs(sum) * 1e-17) break;
        }
        double p = sum * exp(lpre);
        return p >= 1.0 ? 0.0 : 1.0 - p;
    }
    if (!(exp(lpre) > 0.0)) return 0.0;   /* (and x^8 from one rescaling to the next could overflow) */
    /* h = 1 / (b0 + a1 / (b1 + a2 / (b2 + ...))), a_i = -i (i - a), b_i = x + 1 - a + 2 i: its
     * convergents are q_n / p_n, p_n = b_n p_(n-1) + a_n p_(n-2) (p_(-1) = 1, p_0 = b0) and
     * q_n likewise (q_(-1) = 0, q_0 = 1); all p_n > 0 here (x >= a + 1) */
    double b = x + 1.0 - a, p0 = 1.0, p1 = b, q0 = 0.0, q1 = 1.0;
    for (int i = 1; i < 100000;) {
        for (int k = 0; k < 8; k++, i++) {
            double an = -i * (i - a);
            b += 2.0;
            double p2 = b * p1 + an * p0, q2 = b * q1 + an * q0;
            p0 = p1, p1 = p2, q0 = q1, q1 = q2;
        }
        double r = 1.0 / p1;
        p0 *= r, q0 *= r, q1 *= r, p1 = 1.0;   /* now q1 = h_n, and h_(n-1) = q0 / p0 */
        if (fabs(q0 - q1 * p0) <= 1e-16 * fabs(q1 * p0)) break;
    }
    return exp(lpre) * q1;
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

/* Exact: fmod is exact, and r -+ 360 with |r| in [180, 360) is exact (Sterbenz), so a longitude
 * already in [-180, 180) comes back unchanged ((x + 180) - 180 moved 35.02 by an ulp, off the
 * edge of an area that covers it: stats --clip). */
double gs_wrap180(double a_deg)
{
    double r = fmod(a_deg, 360.0);
    if (r >= 180.0) r -= 360.0;
    else if (r < -180.0) r += 360.0;
    return r + 0.0;   /* (-0.0, of -0 or -360 k, as +0: exports would print "-0.0") */
}

const char *gs_number_prefix(const char *s, double *v)
{
    const char *p = s;
    while (isspace((unsigned char)*p)) p++;
    if (*p == '+' || *p == '-') p++;
    if (!(isdigit((unsigned char)*p) || (*p == '.' && isdigit((unsigned char)p[1])))) return NULL;
    if (p[0] == '0' && (p[1] == 'x' || p[1] == 'X')) return NULL;
    char *end;
    double x = strtod(s, &end);
    if (end == s || !isfinite(x)) return NULL;
    *v = x;
    return end;
}

int gs_parse_number(const char *s, double *v)
{
    double x;
    const char *end = gs_number_prefix(s, &x);
    if (!end || *end) return 0;
    *v = x;
    return 1;
}

int gs_blas_serial(void)
{
    int n = openblas_get_num_threads();
    if (n > 1) openblas_set_num_threads(1);
    return n;
}

void gs_blas_restore(int before)
{
    if (before > 1) openblas_set_num_threads(before);
}

int gs_cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

double gs_median_d(double *v, size_t n)
{
    if (n == 0) return NAN;
    qsort(v, n, sizeof *v, gs_cmp_double);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
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

/* (the eight partial sums as one vector: gcc's vectorizer made a poor loop of the array form) */
typedef double dot_v8 __attribute__((vector_size(8 * sizeof(double))));
/* The reduction of gs_dot's eight partial sums. */
static inline double dot_sum(const dot_v8 *v)
{
    const double *a = (const double *)v;
    return ((a[0] + a[1]) + (a[2] + a[3])) + ((a[4] + a[5]) + (a[6] + a[7]));
}

GS_VECTOR_CLONES
double gs_dot(const double *x, const double *t, size_t n)
{
    dot_v8 a = {0};
    size_t i = 0;
    for (; i + 8 <= n; i += 8) {
        dot_v8 xv, tv;
        memcpy(&xv, x + i, sizeof xv);
        memcpy(&tv, t + i, sizeof tv);
        a += xv * tv;
    }
    for (; i < n; i++) a[0] += x[i] * t[i];
    return dot_sum(&a);
}


GS_VECTOR_CLONES
void gs_dot_rows(const double *x, const double *t, size_t ld, size_t n, const size_t *idx, size_t count,
                 double scale, double *out)
{
    size_t i = 0;
    for (; i + 4 <= count; i += 4) {   /* four independent chains: gs_dot's operations on each */
        size_t r0 = idx ? idx[i] : i, r1 = idx ? idx[i + 1] : i + 1, r2 = idx ? idx[i + 2] : i + 2,
               r3 = idx ? idx[i + 3] : i + 3;
        const double *t0 = t + r0 * ld, *t1 = t + r1 * ld, *t2 = t + r2 * ld, *t3 = t + r3 * ld;
        dot_v8 a0 = {0}, a1 = {0}, a2 = {0}, a3 = {0};
        size_t k = 0;
        for (; k + 8 <= n; k += 8) {
            dot_v8 xv, v0, v1, v2, v3;
            memcpy(&xv, x + k, sizeof xv);
            memcpy(&v0, t0 + k, sizeof v0);
            memcpy(&v1, t1 + k, sizeof v1);
            memcpy(&v2, t2 + k, sizeof v2);
            memcpy(&v3, t3 + k, sizeof v3);
            a0 += xv * v0;
            a1 += xv * v1;
            a2 += xv * v2;
            a3 += xv * v3;
        }
        for (; k < n; k++) {
            a0[0] += x[k] * t0[k];
            a1[0] += x[k] * t1[k];
            a2[0] += x[k] * t2[k];
            a3[0] += x[k] * t3[k];
        }
        out[r0] = dot_sum(&a0) * scale;
        out[r1] = dot_sum(&a1) * scale;
        out[r2] = dot_sum(&a2) * scale;
        out[r3] = dot_sum(&a3) * scale;
    }
    for (; i < count; i++) {
        size_t r = idx ? idx[i] : i;
        out[r] = gs_dot(x, t + r * ld, n) * scale;
    }
}
