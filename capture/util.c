/* util.c - capture/ helpers: BRF antiderivative tables for windows at any position (Eq. 5
 * generalised), FNV-1a, atomic writes into a capture directory. */
#include "capture/internal.h"

#include <fftw3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <threads.h>

/* ------------------------------------------------------------------ BRF tables */

gs_status cap_brf_table_init(cap_brf_table *t, const gs_brf *b, int n_min)
{
    memset(t, 0, sizeof *t);
    int n = b->n;
    if (n < 4 || n % 2 || b->bands < 1 || b->bands > GS_MAX_BANDS || !b->v)
        return gs_fail(GS_EINVAL, "BRF table: a BRF of %d x %d samples", b->bands, n);
    int T = n_min > 2 * n ? n_min : 2 * n;
    if (T % 2) T++;
    t->n = T;
    t->bands = b->bands;
    t->G = malloc(sizeof *t->G * (size_t)T * (size_t)b->bands);
    t->B = malloc(sizeof *t->B * (size_t)T * (size_t)b->bands);
    double *x = fftw_malloc(sizeof *x * (size_t)(n > T ? n : T));
    fftw_complex *C = fftw_malloc(sizeof *C * (size_t)(n / 2 + 1));
    fftw_complex *Y = fftw_malloc(sizeof *Y * (size_t)(T / 2 + 1));
    if (!t->G || !t->B || !x || !C || !Y) {
        fftw_free(x);
        fftw_free(C);
        fftw_free(Y);
        cap_brf_table_release(t);
        return gs_fail(GS_ENOMEM, "BRF table: out of memory");
    }
    fftw_plan fwd = fftw_plan_dft_r2c_1d(n, x, C, FFTW_ESTIMATE);
    fftw_plan inv = fftw_plan_dft_c2r_1d(T, Y, x, FFTW_ESTIMATE);
    for (int band = 0; band < b->bands; band++) {
        memcpy(x, b->v + (size_t)band * (size_t)n, sizeof *x * (size_t)n);
        fftw_execute(fwd);
        /* B: Y_h = C_h / n; the Nyquist term cos(pi n x) C_{n/2} / n splits into +-n/2 */
        memset(Y, 0, sizeof *Y * (size_t)(T / 2 + 1));
        for (int h = 0; h < n / 2; h++) {
            Y[h][0] = C[h][0] / n;
            Y[h][1] = C[h][1] / n;
        }
        Y[0][1] = 0.0;
        Y[n / 2][0] = C[n / 2][0] / (2.0 * n);
        Y[n / 2][1] = 0.0;
        fftw_execute(inv);
        memcpy(t->B + (size_t)band * (size_t)T, x, sizeof *x * (size_t)T);
        /* G: Y_h = C_h / (n 2 pi i h); Nyquist: C_{n/2} sin(pi n x) / (pi n^2) */
        memset(Y, 0, sizeof *Y * (size_t)(T / 2 + 1));
        for (int h = 1; h < n / 2; h++) {
            double w = 1.0 / (n * 2.0 * M_PI * h);
            /* (re + i im) / i = im - i re */
            Y[h][0] = C[h][1] * w;
            Y[h][1] = -C[h][0] * w;
        }
        Y[n / 2][0] = 0.0;
        Y[n / 2][1] = -C[n / 2][0] / (2.0 * M_PI * (double)n * (double)n);
        fftw_execute(inv);
        memcpy(t->G + (size_t)band * (size_t)T, x, sizeof *x * (size_t)T);
        /* the table keeps B - mean as G's derivative; the mean is B's C_0 / n */
        double mean = C[0][0] / n;
        double *Bb = t->B + (size_t)band * (size_t)T;
        for (int j = 0; j < T; j++) Bb[j] -= mean;
        t->mean[band] = mean;
    }
    fftw_destroy_plan(fwd);
    fftw_destroy_plan(inv);
    fftw_free(x);
    fftw_free(C);
    fftw_free(Y);
    return GS_OK;
}

void cap_brf_table_release(cap_brf_table *t)
{
    if (!t) return;
    free(t->G);
    free(t->B);
    memset(t, 0, sizeof *t);
}

/* G(x) by cubic Hermite interpolation on the periodic table. */
static double table_G(const cap_brf_table *t, int band, double x)
{
    double u = (x - floor(x)) * t->n;
    long j = (long)u;
    if (j >= t->n) j = t->n - 1;
    double f = u - (double)j;
    long j1 = j + 1 == t->n ? 0 : j + 1;
    const double *G = t->G + (size_t)band * (size_t)t->n;
    const double *D = t->B + (size_t)band * (size_t)t->n;
    double h = 1.0 / t->n;
    double f2 = f * f, f3 = f2 * f;
    double h00 = 2 * f3 - 3 * f2 + 1, h10 = f3 - 2 * f2 + f, h01 = -2 * f3 + 3 * f2,
           h11 = f3 - f2;
    return h00 * G[j] + h10 * h * D[j] + h01 * G[j1] + h11 * h * D[j1];
}

double cap_brf_table_integral(const cap_brf_table *t, int band, double shift, double a, double b)
{
    /* F(x) = mean x + G(x) - G(0); BRFs have mean 1 (Eq. 4) */
    return t->mean[band] * (b - a) + table_G(t, band, b - shift) - table_G(t, band, a - shift);
}

/* ------------------------------------------------------------------ files */

uint64_t cap_fnv1a(uint64_t h, const void *data, size_t n)
{
    const unsigned char *p = data;
    for (size_t i = 0; i < n; i++) {
        h ^= p[i];
        h *= 0x100000001b3ull;
    }
    return h;
}

gs_status cap_write_in(const char *dir, const char *name, const void *data, size_t size)
{
    char path[CAP_PATH_MAX + 64];
    if (!gs_path_join(path, sizeof path, dir, name))
        return gs_fail(GS_EINVAL, "%s/%s: path too long", dir, name);
    gs_status s = gs_dir_ensure(dir);
    return s == GS_OK ? gs_file_write_atomic(path, data, size) : s;
}
