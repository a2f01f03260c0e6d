/* kit_rng.c - the format kit's random numbers: splitmix64 draws and the xoshiro256** streams
 * (normal by ziggurat, Poisson by inversion or Hormann's PTRS). */
#include "recognize/base/base.h"

#include <math.h>
#include <threads.h>

double gs_splitmix_uniform(uint64_t *x)
{
    return ((double)(gs_splitmix64(x) >> 11) + 0.5) * 0x1.0p-53;
}

double gs_splitmix_normal(uint64_t *x)
{
    double u1 = gs_splitmix_uniform(x);
    double u2 = gs_splitmix_uniform(x);
    return sqrt(-2.0 * log(u1)) * cos(6.283185307179586476925286766559 * u2);
}

void gs_rng_init(gs_rng *r, uint64_t seed, uint32_t tag, uint64_t a, uint64_t b)
{
    uint64_t x = seed;
    uint64_t h = gs_splitmix64(&x);
    x = h ^ ((uint64_t)tag * 0xd1b54a32d192ed03ull);
    h = gs_splitmix64(&x);
    x = h ^ (a * 0x8cb92ba72f3d8dd7ull);
    h = gs_splitmix64(&x);
    x = h ^ (b * 0x9fb21c651e98df25ull);
    for (int i = 0; i < 4; i++) r->s[i] = gs_splitmix64(&x);
    if (!(r->s[0] | r->s[1] | r->s[2] | r->s[3])) r->s[0] = 1;
}

/* Ziggurat tables (G. Marsaglia and W. W. Tsang, "The Ziggurat Method for Generating Random
 * Variables", J. Stat. Softw. 5(8), 2000; 128 layers), computed once. */
static uint32_t zig_k[128];
static double zig_w[128], zig_f[128];
static once_flag zig_once = ONCE_FLAG_INIT;

static void zig_init(void)
{
    const double m1 = 2147483648.0, vn = 9.91256303526217e-3;
    double dn = 3.442619855899, tn = dn;
    double q = vn / exp(-0.5 * dn * dn);
    zig_k[0] = (uint32_t)((dn / q) * m1);
    zig_k[1] = 0;
    zig_w[0] = q / m1;
    zig_w[127] = dn / m1;
    zig_f[0] = 1.0;
    zig_f[127] = exp(-0.5 * dn * dn);
    for (int i = 126; i >= 1; i--) {
        dn = sqrt(-2.0 * log(vn / dn + exp(-0.5 * dn * dn)));
        zig_k[i + 1] = (uint32_t)((dn / tn) * m1);
        tn = dn;
        zig_f[i] = exp(-0.5 * dn * dn);
        zig_w[i] = dn / m1;
    }
}

double gs_rng_normal(gs_rng *r)
{
    call_once(&zig_once, zig_init);
    for (;;) {
        uint64_t u = gs_rng_u64(r);
        int32_t hz = (int32_t)(uint32_t)(u >> 32);
        int iz = (int)(u & 127u);
        uint32_t ahz = hz < 0 ? (uint32_t)(-(int64_t)hz) : (uint32_t)hz;
        if (ahz < zig_k[iz]) return hz * zig_w[iz];
        /* the tail and the wedges */
        double x = hz * zig_w[iz];
        if (iz == 0) {
            const double rr = 3.442620;
            double y;
            do {
                x = -log(gs_rng_uniform(r)) / rr;
                y = -log(gs_rng_uniform(r));
            } while (y + y < x * x);
            return hz > 0 ? rr + x : -rr - x;
        }
        if (zig_f[iz] + gs_rng_uniform(r) * (zig_f[iz - 1] - zig_f[iz]) < exp(-0.5 * x * x))
            return x;
    }
}

double gs_rng_poisson(gs_rng *r, double lambda)
{
    if (!(lambda > 0.0)) return 0.0;
    if (lambda < 12.0) {
        /* inversion by sequential search */
        double p = exp(-lambda), F = p, u = gs_rng_uniform(r);
        double k = 0.0;
        while (u > F && k < 1000.0) {
            k += 1.0;
            p *= lambda / k;
            F += p;
        }
        return k;
    }
    /* W. Hormann, "The transformed rejection method for generating Poisson random variables",
     * Insurance: Mathematics and Economics 12 (1993) 39-45 (PTRS). */
    double slam = sqrt(lambda), loglam = log(lambda);
    double b = 0.931 + 2.53 * slam, a = -0.059 + 0.02483 * b;
    double invalpha = 1.1239 + 1.1328 / (b - 3.4), vr = 0.9277 - 3.6224 / (b - 2.0);
    for (;;) {
        double U = gs_rng_uniform(r) - 0.5, V = gs_rng_uniform(r);
        double us = 0.5 - fabs(U);
        double k = floor((2.0 * a / us + b) * U + lambda + 0.43);
        if (us >= 0.07 && V <= vr) return k;
        if (k < 0.0 || (us < 0.013 && V > us)) continue;
        if (log(V) + log(invalpha) - log(a / (us * us) + b) <=
            -lambda + k * loglam - lgamma(k + 1.0))
            return k;
    }
}
