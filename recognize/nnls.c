/* nnls.c - non-negative least squares (Lawson and Hanson, Solving Least Squares Problems,
 * Prentice-Hall 1974, ch. 23, algorithm NNLS) on the normal equations of a small problem: the
 * T >= 0 of Eq. 16 and the B >= 0 of Eq. 18 (paper Sec. 5.1). */
#include "recognize/recognize.h"

#include <math.h>
#include <string.h>

#define NNLS_MAX 32

/* Solve G_PP z_P = h_P on the passive set P (p[i] = 1) by Cholesky; z = 0 outside P.
 * 0 when G_PP is not numerically positive definite. */
static int solve_passive(const double *G, const double *h, int n, const int *p, double *z)
{
    int idx[NNLS_MAX], m = 0;
    for (int i = 0; i < n; i++) {
        z[i] = 0;
        if (p[i]) idx[m++] = i;
    }
    double L[NNLS_MAX * NNLS_MAX], y[NNLS_MAX];
    for (int i = 0; i < m; i++)
        for (int j = 0; j <= i; j++) {
            double s = G[idx[i] * n + idx[j]];
            for (int r = 0; r < j; r++) s -= L[i * m + r] * L[j * m + r];
            if (i == j) {
                /* a pivot that cancels to rounding level means a dependent column */
                if (!(s > 1e-13 * G[idx[i] * n + idx[i]]) || !(s > 0)) return 0;
                L[i * m + i] = sqrt(s);
            } else {
                L[i * m + j] = s / L[j * m + j];
            }
        }
    for (int i = 0; i < m; i++) {
        double s = h[idx[i]];
        for (int r = 0; r < i; r++) s -= L[i * m + r] * y[r];
        y[i] = s / L[i * m + i];
    }
    for (int i = m - 1; i >= 0; i--) {
        double s = y[i];
        for (int r = i + 1; r < m; r++) s -= L[r * m + i] * z[idx[r]];
        z[idx[i]] = s / L[i * m + i];
    }
    return 1;
}

int rec_nnls(const double *G, const double *h, int n, double *x)
{
    if (n < 1 || n > NNLS_MAX) return -1;
    int p[NNLS_MAX] = {0};
    double w[NNLS_MAX], z[NNLS_MAX];
    double scale = 0;
    for (int i = 0; i < n; i++) {
        x[i] = 0;
        if (fabs(h[i]) > scale) scale = fabs(h[i]);
    }
    /* the dual w = h - G x must be <= tol outside the passive set at the optimum */
    double tol = 1e-12 * scale * n;
    int it = 0;
    for (; it < 3 * n + 10; it++) {
        for (int i = 0; i < n; i++) {
            double s = h[i];
            for (int j = 0; j < n; j++) s -= G[i * n + j] * x[j];
            w[i] = s;
        }
        int jmax = -1;
        for (int i = 0; i < n; i++)
            if (!p[i] && w[i] > tol && (jmax < 0 || w[i] > w[jmax])) jmax = i;
        if (jmax < 0) return it;
        p[jmax] = 1;
        for (int inner = 0;; inner++) {
            if (!solve_passive(G, h, n, p, z)) {
                p[jmax] = 0;
                return -1;
            }
            int feasible = 1;
            for (int i = 0; i < n; i++)
                if (p[i] && z[i] <= 0) feasible = 0;
            if (feasible) {
                memcpy(x, z, sizeof *x * (size_t)n);
                break;
            }
            if (inner > n) return -1;
            /* step from x towards z until the first passive variable reaches 0 */
            double alpha = 1;
            int imin = -1;
            for (int i = 0; i < n; i++)
                if (p[i] && z[i] <= 0) {
                    double d = x[i] - z[i], a = d > 0 ? x[i] / d : 0.0;
                    if (imin < 0 || a < alpha) {
                        alpha = a;
                        imin = i;
                    }
                }
            for (int i = 0; i < n; i++) {
                if (!p[i]) continue;
                x[i] += alpha * (z[i] - x[i]);
                if (i == imin || x[i] <= 0) {
                    p[i] = 0;
                    x[i] = 0;
                }
            }
        }
    }
    return it;
}
