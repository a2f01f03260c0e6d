/* acam.c - the ACam's coded-exposure model (paper Sec. 6, Eq. 23, Fig. 7): limits, the mask
 * matrix M = [m1 0 m2 0 ... m_{M/2} 0], the exposure of a pixel whose row the HDR loop halved
 * h times, one HDR round, and the exact expected value of a light (Eq. 5 through the masks). */
#include "capture/internal.h"

#include <stdlib.h>
#include <string.h>

void cap_acam_config_default(cap_acam_config *c)
{
    memset(c, 0, sizeof *c);
    c->grid_hz = 50;
    c->K = 26;
    c->cycles = 500;
    c->masks = 2;
    c->dmd_min_hold_us = CAP_DMD_MIN_HOLD_US;
}

int cap_acam_max_halvings(int masks)
{
    if (masks < 2) return 0;
    int n = masks / 2, r = 0;
    while (n > 1 && n % 2 == 0) {
        n /= 2;
        r++;
    }
    return r;
}

gs_status cap_acam_check(const cap_acam_config *c)
{
    if (c->grid_hz != 50 && c->grid_hz != 60)
        return gs_fail(GS_EINVAL, "grid %d Hz: expected 50 or 60", c->grid_hz);
    int kmax = c->grid_hz == 50 ? CAP_MAX_K_50HZ : CAP_MAX_K_60HZ;
    if (c->K < 2)
        return gs_fail(GS_EINVAL, "K = %d: expected at least 2 windows per cycle", c->K);
    if (c->K > kmax)
        return gs_fail(GS_ELIMIT, "K = %d: the ACam reaches at most K = %d windows per cycle at "
                       "%d Hz (paper Fig. 7)", c->K, kmax, c->grid_hz);
    if (c->cycles < 1 || c->cycles > CAP_MAX_CYCLES)
        return gs_fail(GS_EINVAL, "C = %ld cycles: expected 1 to %ld", c->cycles, CAP_MAX_CYCLES);
    if (c->masks > CAP_MAX_MASKS)
        return gs_fail(GS_ELIMIT, "M = %d masks: the ACam's DMD holds at most %d (paper "
                       "footnote 5)", c->masks, CAP_MAX_MASKS);
    if (c->masks < 2 || c->masks % 2)
        return gs_fail(GS_EINVAL, "M = %d masks: expected an even number from 2 to %d "
                       "(M = [m1 0 m2 0 ...], Eq. 23)", c->masks, CAP_MAX_MASKS);
    if (!(c->dmd_min_hold_us > 0) || !isfinite(c->dmd_min_hold_us))
        return gs_fail(GS_EINVAL, "DMD minimum hold %g us: expected a positive time",
                       c->dmd_min_hold_us);
    double hz = c->max_hz > 0 ? c->max_hz : (double)c->grid_hz;
    if (!isfinite(hz) || hz < 0.5 * c->grid_hz || hz > 2.0 * c->grid_hz)
        return gs_fail(GS_EINVAL, "highest grid frequency %g Hz: expected near %d Hz", hz,
                       c->grid_hz);
    double hold_us = 1e6 / (2.0 * hz * c->K);
    if (hold_us < c->dmd_min_hold_us)
        return gs_fail(GS_ELIMIT, "each mask is held Delta/K = %.1f us (K = %d at %.3f Hz) but "
                       "the DMD needs at least %.0f us per mask (paper Fig. 7: masks must "
                       "persist for Delta/K)", hold_us, c->K, hz, c->dmd_min_hold_us);
    if (c->hdr) {
        int hmax = cap_acam_max_halvings(c->masks);
        if (hmax < 1)
            return gs_fail(GS_EINVAL, "HDR with M = %d masks: M/2 = %d non-zero masks cannot be "
                           "halved exactly (use M = 64 for 5 rounds)", c->masks, c->masks / 2);
        if (c->hdr_max_rounds < 0 || c->hdr_max_rounds > hmax)
            return gs_fail(GS_ELIMIT, "HDR rounds %d: M = %d masks allow at most %d exact "
                           "halvings (M/2 = %d)", c->hdr_max_rounds, c->masks, hmax,
                           c->masks / 2);
        int rounds = c->hdr_max_rounds ? c->hdr_max_rounds : hmax;
        long step = 1L << rounds;
        if (c->cycles % step)
            return gs_fail(GS_EINVAL, "HDR: C = %ld cycles is not a multiple of 2^%d = %ld, so "
                           "a halved row would not integrate exactly C/2^h cycles",
                           c->cycles, rounds, step);
        if (c->hdr_max_saturated_px < 0)
            return gs_fail(GS_EINVAL, "HDR: max_saturated_px %d: expected >= 0",
                           c->hdr_max_saturated_px);
    }
    return GS_OK;
}

int cap_mask_element(int masks, int halvings, int col)
{
    if (col < 0 || col >= masks || col % 2) return 0;
    int j = col / 2;
    return halvings <= 0 || j % (1 << halvings) == 0;
}

/* multiples of m in [lo, hi), lo >= 0 */
static long multiples(long lo, long hi, long m)
{
    if (hi <= lo) return 0;
    return (hi + m - 1) / m - (lo + m - 1) / m;
}

long cap_exposed_cycles(int masks, long first, long cycles, int halvings)
{
    if (cycles <= 0 || first < 0) return 0;
    if (halvings <= 0) return cycles;
    long n = masks / 2, m = 1L << halvings;
    if (n % m == 0) return multiples(first, first + cycles, m);
    /* not an exact halving: count pair by pair */
    long count = 0;
    for (long c = first; c < first + cycles; c++) count += (c % n) % m == 0;
    return count;
}

int cap_cycle_level(int masks, int max_h, long c)
{
    long j = c % (masks / 2 > 0 ? masks / 2 : 1);
    int h = 0;
    while (h < max_h && j % (1L << (h + 1)) == 0) h++;
    return h;
}

/* 1 when a sample of v[0 .. n) is at least thr (one vectorized pass: most rows have none). */
GS_VECTOR_LOOP static int any_at_least(const unsigned short *v, size_t n, unsigned thr)
{
    int any = 0;
    for (size_t i = 0; i < n; i++) any |= v[i] >= thr;
    return any;
}

gs_status cap_hdr_update(const unsigned short *raw, int width, int height, int bands,
                         double saturation_dn, int max_halvings, unsigned char *halvings,
                         size_t *saturated, size_t *halved)
{
    if (!raw || !halvings || width < 1 || height < 1 || bands < 1 || max_halvings < 0 ||
        max_halvings > GS_MAX_HALVINGS)
        return gs_fail(GS_EINVAL, "HDR update: bad arguments");
    size_t n_sat = 0, n_half = 0, row = (size_t)width * (size_t)bands;
    /* raw >= saturation_dn for an integer raw: raw >= the threshold rounded up (none above
     * 65535 or NaN) */
    unsigned thr = saturation_dn <= 0.0 ? 0u : saturation_dn <= 65535.0 ? (unsigned)ceil(saturation_dn) : 65536u;
    for (size_t y = 0; y < (size_t)height; y++) {
        const unsigned short *v = raw + y * row;
        if (!any_at_least(v, row, thr)) continue;
        for (size_t x = 0; x < (size_t)width; x++) {
            if (!any_at_least(v + x * (size_t)bands, (size_t)bands, thr)) continue;
            size_t p = y * (size_t)width + x;
            n_sat++;
            if (halvings[p] < max_halvings) {
                halvings[p]++;
                n_half++;
            }
        }
    }
    if (saturated) *saturated = n_sat;
    if (halved) *halved = n_half;
    return GS_OK;
}

gs_status cap_acam_expected(const gs_brf *b, double shift_cycles, const cap_acam_config *c,
                            int k, int halvings, double *out)
{
    if (k < 0 || k >= c->K) return gs_fail(GS_EINVAL, "window k = %d of K = %d", k, c->K);
    double *i_k = malloc(sizeof *i_k * (size_t)c->K * (size_t)b->bands);
    if (!i_k) return gs_fail(GS_ENOMEM, "out of memory");
    gs_status s = gs_brf_integrate(b, shift_cycles, c->K, i_k);
    if (s == GS_OK) {
        double n = (double)cap_exposed_cycles(c->masks, 0, c->cycles, halvings);
        for (int band = 0; band < b->bands; band++)
            out[band] = n * i_k[band * c->K + k] / c->K;
    }
    free(i_k);
    return s;
}
