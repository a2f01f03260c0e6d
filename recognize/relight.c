/* relight.c - generalised relighting (paper Sec. 5.2, Eq. 20): the unmixed sources recombined
 * with other gains, bulbs and grid phases, and the result as a capture directory. */
#include "recognize/recognize.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

gs_status rec_relight(const rec_sources *src, const float *tq, int width, int height,
                      const gs_delight *d, int grid_hz, const rec_relight_set *set, float *frames)
{
    int S = src->S, B = src->bands, K = src->K;
    size_t P = (size_t)width * (size_t)height;
    double *qb = malloc(sizeof *qb * (size_t)S * B * (K + 1));
    if (!qb) return gs_fail(GS_ENOMEM, "relight: out of memory");
    /* per source and band: a_s Q'_s / Q_s and the BRF b'_s */
    double *fac = qb, *brf = qb + (size_t)S * B;
    for (int s = 0; s < S; s++) {
        const rec_relight_set *r = &set[s];
        if (!(r->gain >= 0) || !isfinite(r->gain)) {
            free(qb);
            return gs_fail(GS_EINVAL, "relight: source %02d: gain %g: expected a finite number >= 0", s, r->gain);
        }
        const char *bulb = r->bulb[0] ? r->bulb : src->bulb[s];
        double phase = r->set_phase ? r->phase_deg : src->phase_deg[s];
        /* (a phase and that phase + 180 deg are one flicker: its BRF is the half AC cycle's) */
        int same = !strcmp(bulb, src->bulb[s]) && (!r->set_phase || fabs(remainder(phase - src->phase_deg[s], 180.0)) < 1e-9);
        double q[GS_MAX_BANDS];
        double *b = brf + (size_t)s * B * K;
        if (same) {
            memcpy(q, src->q + (size_t)s * B, sizeof *q * (size_t)B);
            memcpy(b, src->b + (size_t)s * B * K, sizeof *b * (size_t)B * K);
        } else if (!strcmp(bulb, REC_DAYLIGHT)) {
            for (int c = 0; c < B; c++) q[c] = 1.0 / B;
            for (int i = 0; i < B * K; i++) b[i] = 1.0;
        } else {
            const gs_bulb *bu = d ? gs_delight_find(d, bulb, grid_hz, B) : NULL;
            if (!bu) {
                free(qb);
                return gs_fail(GS_ENOTFOUND, "relight: source %02d: bulb '%s': expected a DELIGHT bulb "
                               "id with a %d Hz, %d-band entry or \"%s\"", s, bulb, grid_hz, B, REC_DAYLIGHT);
            }
            for (int c = 0; c < B; c++) q[c] = bu->chroma[c];
            gs_status st = gs_brf_integrate(&bu->brf, gs_phase_to_shift(phase), K, b);
            if (st != GS_OK) {
                free(qb);
                return st;
            }
        }
        for (int c = 0; c < B; c++)
            fac[s * B + c] = src->q[s * B + c] > 0 ? r->gain * q[c] / src->q[s * B + c] : 0.0;
    }
    for (size_t p = 0; p < P; p++)
        for (int c = 0; c < B; c++) {
            double tau[REC_MAX_SOURCES];
            for (int s = 0; s < S; s++) {
                double v = tq[((size_t)s * P + p) * B + c];
                tau[s] = set[s].gain == 0 ? 0.0 : v * fac[s * B + c];
            }
            for (int k = 0; k < K; k++) {
                double v = 0;
                for (int s = 0; s < S; s++) v += tau[s] * brf[((size_t)s * B + c) * K + k];
                frames[((size_t)k * P + p) * B + c] = (float)v;
            }
        }
    free(qb);
    return GS_OK;
}

gs_status rec_frames_to_capture(const rec_capture_meta *m, const float *frames, gs_capture *cap)
{
    memset(cap, 0, sizeof *cap);
    cap->grid_hz = m->grid_hz;
    cap->K = m->K;
    cap->bands = m->bands;
    cap->width = m->width;
    cap->height = m->height;
    /* a sample written at 65535 must read back saturated */
    cap->saturation_dn = m->saturation_dn > 65535 ? 65535 : m->saturation_dn;
    cap->black_level_dn = m->black_level_dn;
    cap->gain_e_per_dn = m->gain_e_per_dn;
    cap->read_noise_dn = m->read_noise_dn;
    cap->locked = 1;   /* rendered with regular windows (Eq. 5), not exposed: none drifted */
    gs_status st = gs_capture_alloc(cap);
    if (st == GS_OK) st = gs_capture_alloc_hdr(cap);
    if (st != GS_OK) {
        gs_capture_release(cap);
        return st;
    }
    int B = m->bands;
    size_t P = (size_t)m->width * (size_t)m->height;
    /* the highest raw value that reads back unsaturated */
    double top = ceil(cap->saturation_dn) - 1.5;
    for (int k = 0; k < m->K; k++) {
        cap->frames[k].cycles = m->cycles;
        for (size_t p = 0; p < P; p++) {
            const float *v = frames + ((size_t)k * P + p) * B;
            double mx = 0;
            int bad = 0;
            for (int c = 0; c < B; c++) {
                if (!isfinite(v[c])) bad = 1;
                else if (v[c] > mx) mx = v[c];
            }
            int h = 0;
            while (!bad && m->black_level_dn + mx * m->cycles / (double)(1u << h) > top) {
                if (++h > GS_MAX_HALVINGS) bad = 1;
            }
            if (bad) h = 0;
            cap->halvings[(size_t)k * P + p] = (unsigned char)h;
            for (int c = 0; c < B; c++) {
                double raw = bad ? 65535.0
                                 : floor(m->black_level_dn + v[c] * m->cycles / (double)(1u << h) + 0.5);
                cap->raw[((size_t)k * P + p) * B + c] =
                    (unsigned short)(raw < 0 ? 0 : raw > 65535 ? 65535 : raw);
            }
        }
    }
    return GS_OK;
}
