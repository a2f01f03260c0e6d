/* separate.c - semi-reflection separation under daylight plus one AC source (paper Sec. 5.3,
 * Eqs. 21-22): the AC component from frame differences, the transmitted one with the scalar A
 * that minimises the mutual information of the two (an ICA criterion, Hyvarinen and Oja,
 * Neural Networks 13, 2000). */
#include "recognize/recognize.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define MI_BINS 32
#define MI_MAX_PX 65536

void rec_separation_release(rec_separation *s)
{
    if (!s) return;
    free(s->transmitted);
    free(s->reflection);
    memset(s, 0, sizeof *s);
}

/* The range mean +- 3 std of the finite values, for binning. */
static void range3(const float *x, size_t n, double *lo, double *hi)
{
    double s = 0, s2 = 0;
    size_t m = 0;
    for (size_t i = 0; i < n; i++)
        if (isfinite(x[i])) {
            s += x[i];
            s2 += (double)x[i] * x[i];
            m++;
        }
    double mean = m ? s / m : 0, sd = m ? sqrt(fmax(s2 / m - mean * mean, 0)) : 0;
    if (!(sd > 0)) sd = fabs(mean) * 1e-6 + 1e-30;
    *lo = mean - 3 * sd;
    *hi = mean + 3 * sd;
}

double rec_mutual_information(const float *x, const float *y, size_t n, int bins)
{
    if (bins < 2 || bins > 256) return NAN;
    double xl, xh, yl, yh;
    range3(x, n, &xl, &xh);
    range3(y, n, &yl, &yh);
    double *h = calloc((size_t)bins * (bins + 2), sizeof *h);
    if (!h) return NAN;
    double *hx = h + (size_t)bins * bins, *hy = hx + bins, tot = 0;
    for (size_t i = 0; i < n; i++) {
        if (!isfinite(x[i]) || !isfinite(y[i])) continue;
        int a = (int)floor((x[i] - xl) / (xh - xl) * bins), b = (int)floor((y[i] - yl) / (yh - yl) * bins);
        a = a < 0 ? 0 : a >= bins ? bins - 1 : a;   /* the tails go to the edge bins */
        b = b < 0 ? 0 : b >= bins ? bins - 1 : b;
        h[a * bins + b] += 1;
        tot += 1;
    }
    double mi = 0;
    if (tot > 0) {
        for (int a = 0; a < bins; a++)
            for (int b = 0; b < bins; b++) {
                hx[a] += h[a * bins + b];
                hy[b] += h[a * bins + b];
            }
        for (int a = 0; a < bins; a++)
            for (int b = 0; b < bins; b++) {
                double p = h[a * bins + b];
                if (p > 0) mi += p / tot * log(p * tot / (hx[a] * hy[b]));
            }
    }
    free(h);
    return mi;
}


typedef struct {
    const float *D, *hi, *lo;
    float *R;
    size_t n;
} mi_ctx;

static double mi_at(mi_ctx *c, double A)
{
    for (size_t i = 0; i < c->n; i++) c->R[i] = (float)(c->lo[i] - A * c->hi[i]);
    return rec_mutual_information(c->D, c->R, c->n, MI_BINS);
}

gs_status rec_separate(const gs_capture *cap, rec_separation *o)
{
    memset(o, 0, sizeof *o);
    gs_status st = gs_capture_check(cap, "separate");
    if (st != GS_OK) return st;
    if (!cap->raw) return gs_fail(GS_EINVAL, "separate: the capture has no pixels");
    int W = cap->width, H = cap->height, B = cap->bands, K = cap->K;
    size_t P = (size_t)W * H;
    o->width = W;
    o->height = H;
    o->bands = B;
    o->transmitted = malloc(sizeof *o->transmitted * P * B);
    o->reflection = malloc(sizeof *o->reflection * P * B);
    float *v = malloc(sizeof *v * P * K), *hi = malloc(sizeof *hi * P), *lo = malloc(sizeof *lo * P);
    float *mean = malloc(sizeof *mean * P);
    size_t step = P / MI_MAX_PX + 1, ns = (P + step - 1) / step;
    float *sD = malloc(sizeof *sD * ns), *sH = malloc(sizeof *sH * ns), *sL = malloc(sizeof *sL * ns);
    float *sR = malloc(sizeof *sR * ns);
    int *order = malloc(sizeof *order * (size_t)K);
    double *fm = malloc(sizeof *fm * (size_t)K);
    if (!o->transmitted || !o->reflection || !v || !hi || !lo || !mean || !sD || !sH || !sL || !sR ||
        !order || !fm) {
        st = gs_fail(GS_ENOMEM, "separate: out of memory");
        goto done;
    }
    int third = K / 3 > 0 ? K / 3 : 1;
    for (int b = 0; b < B; b++) {
        for (int k = 0; k < K; k++)
            for (size_t p = 0; p < P; p++)
                v[(size_t)k * P + p] =
                    (float)gs_capture_value(cap, k, (int)(p / (size_t)W), (int)(p % (size_t)W), b);
        for (size_t p = 0; p < P; p++) {
            double s = 0;
            int ok = 1;
            for (int k = 0; k < K; k++) {
                ok &= isfinite(v[(size_t)k * P + p]);
                s += v[(size_t)k * P + p];
            }
            mean[p] = ok ? (float)(s / K) : NAN;
        }
        /* each frame's mean over the pixels unsaturated in every frame */
        for (int k = 0; k < K; k++) {
            double s = 0;
            for (size_t p = 0; p < P; p++)
                if (isfinite(mean[p])) s += v[(size_t)k * P + p];
            fm[k] = s;
            order[k] = k;
        }
        /* frames by mean, highest first: b_ac is highest there (Eqs. 21-22) */
        for (int i = 1; i < K; i++)
            for (int j = i; j > 0 && fm[order[j]] > fm[order[j - 1]]; j--) {
                int t = order[j];
                order[j] = order[j - 1];
                order[j - 1] = t;
            }
        for (size_t p = 0; p < P; p++) {
            double a = 0, c = 0;
            for (int i = 0; i < third; i++) {
                a += v[(size_t)order[i] * P + p];
                c += v[(size_t)order[K - 1 - i] * P + p];
            }
            hi[p] = isfinite(mean[p]) ? (float)(a / third) : NAN;
            lo[p] = isfinite(mean[p]) ? (float)(c / third) : NAN;
        }
        size_t n = 0;
        for (size_t p = 0; p < P; p += step) {
            sD[n] = hi[p] - lo[p];
            sH[n] = hi[p];
            sL[n] = lo[p];
            n++;
        }
        mi_ctx mc = {sD, sH, sL, sR, n};
        /* a grid over [0, 1), then golden section around its best */
        int G = 200;
        double best = INFINITY, bestA = 0;
        for (int g = 0; g < G; g++) {
            double A = (double)g / G, mi = mi_at(&mc, A);
            if (mi < best) {
                best = mi;
                bestA = A;
            }
        }
        double a = fmax(0, bestA - 1.0 / G), c = fmin(0.999999, bestA + 1.0 / G);
        const double gr = 0.5 * (sqrt(5.0) - 1);
        double x1 = c - gr * (c - a), x2 = a + gr * (c - a), f1 = mi_at(&mc, x1), f2 = mi_at(&mc, x2);
        for (int it = 0; it < 30; it++) {
            if (f1 < f2) {
                c = x2;
                x2 = x1;
                f2 = f1;
                x1 = c - gr * (c - a);
                f1 = mi_at(&mc, x1);
            } else {
                a = x1;
                x1 = x2;
                f1 = f2;
                x2 = a + gr * (c - a);
                f2 = mi_at(&mc, x2);
            }
        }
        double A = f1 < f2 ? x1 : x2, fA = fmin(f1, f2);
        if (best < fA) {
            A = bestA;
            fA = best;
        }
        o->A[b] = A;
        o->mi[b] = fA;
        o->mi_a0[b] = mi_at(&mc, 0);
        for (size_t p = 0; p < P; p++) {
            float t = (float)((lo[p] - A * hi[p]) / (1 - A));
            o->transmitted[p * B + b] = t;
            o->reflection[p * B + b] = mean[p] - t;
        }
    }
done:
    free(v);
    free(hi);
    free(lo);
    free(mean);
    free(sD);
    free(sH);
    free(sL);
    free(sR);
    free(order);
    free(fm);
    if (st != GS_OK) rec_separation_release(o);
    return st;
}
