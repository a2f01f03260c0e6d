/* transport_fixture.c - light-transport scenes and the weighted least-squares oracle
 * (transport_fixture.h). */
#include "tests/transport_fixture.h"
#include "tests/fixtures.h"
#include "tests/test.h"
#include "capture/capture.h"
#include "survey/internal.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

char *trfx_scene(const trfx_opts *o, const trfx_lamp *lamps, int n)
{
    int W = o->W ? o->W : 64, H = o->H ? o->H : 48, K = o->K ? o->K : 26;
    long C = o->cycles ? o->cycles : 256;
    size_t cap = 8192 + (size_t)n * 256;
    char *t = malloc(cap);
    int u = snprintf(t, cap,
        "{\"format\": \"gridsurvey-scene/1\", \"seed\": %u,%s%s%s\n"
        " \"grid\": {\"nominal_hz\": 50},\n"
        " \"camera\": {\"width_px\": %d, \"height_px\": %d, \"intrinsics\": {\"focal_px\": %d},\n"
        "   \"sensor\": {\"bands\": 3, \"bit_depth\": 12, \"full_well_e\": 20000, \"read_noise_e\": 4, \"gain_e_per_dn\": 5, \"black_level_dn\": 64}},\n"
        " \"acam\": {\"K\": %d, \"cycles\": %ld, \"masks\": 64, \"hdr\": %s},\n"
        " \"lights\": [\n",
        o->seed ? o->seed : 1u, o->delight ? " \"delight\": \"" : "", o->delight ? o->delight : "",
        o->delight ? "\"," : "", W, H, W, K, C,
        o->hdr_rounds ? "{\"enabled\": true, \"max_rounds\": 0, \"max_saturated_px\": 0}" : "false");
    if (o->hdr_rounds) {
        char *p = strstr(t, "\"max_rounds\": 0");
        if (p) p[14] = (char)('0' + o->hdr_rounds);
    }
    for (int i = 0; i < n; i++)
        u += snprintf(t + u, cap - (size_t)u,
                      "  {\"id\": \"%s\", \"bulb\": \"%s\", \"phase_deg\": %g, \"x_px\": %g, \"y_px\": %g, "
                      "\"distance_m\": %g, \"flux_e_per_cycle\": %g}%s\n",
                      lamps[i].id, lamps[i].bulb, lamps[i].phase_deg, lamps[i].x_px, lamps[i].y_px,
                      lamps[i].distance_m, lamps[i].flux > 0 ? lamps[i].flux : 5e6, i + 1 < n ? "," : "");
    char day[128] = "";
    if (o->daylight_e > 0) snprintf(day, sizeof day, ", \"daylight\": {\"e_per_px_cycle\": %g}", o->daylight_e);
    snprintf(t + u, cap - (size_t)u,
             " ],\n \"effects\": {\"psf\": {\"sigma_px\": 1.0},\n"
             "  \"light_transport\": {\"room\": {\"width_m\": 5, \"height_m\": 3, \"depth_m\": 6, \"floor_m\": 1.4, "
             "\"albedo\": [0.75, 0.7, 0.62], \"checker_m\": 0.5, \"contrast\": 0.4},\n"
             "    \"boxes\": [{\"min_m\": [-1.3, 0.5, 3.2], \"max_m\": [-0.3, 1.4, 4.2], \"albedo\": [0.8, 0.3, 0.2]}],\n"
             "    \"lamp_shade\": {\"radius_px\": 2, \"transmission\": %g}%s},\n"
             "  \"shot_noise\": {}, \"saturation\": {}, \"read_noise\": {}, \"adc\": {}}}\n",
             o->shade > 0 ? o->shade : 0.01, day);
    return t;
}

int trfx_render(const char *text, const char *dir, gs_capture *cap)
{
    memset(cap, 0, sizeof *cap);
    cap_scene sc;
    gs_status st = cap_scene_parse(text, "transport.json", ".", &sc);
    CHECK_MSG(st == GS_OK, "scene: %s", gs_detail());
    cap_backend *be = NULL;
    if (st == GS_OK) {
        st = cap_backend_sim_new(&sc, NULL, &be);
        CHECK_MSG(st == GS_OK, "sim: %s", gs_detail());
    }
    cap_scene_release(&sc);
    if (st != GS_OK) return 0;
    cap_loop_opts lo;
    cap_loop_opts_default(&lo);
    lo.progress = 0;
    cap_loop_report rep;
    CHECK_OK(st = cap_loop_run(be, dir, &lo, &rep));
    if (st == GS_OK) CHECK_OK(st = cap_sim_write_truth(cap_backend_sim_handle(be), dir));
    cap_backend_free(be);
    if (st == GS_OK) CHECK_OK(st = gs_capture_read(dir, cap));
    return st == GS_OK;
}

float *trfx_truth(const char *dir, const char *bulb, double phase_deg)
{
    srv_tr_truth t;
    gs_status st = srv_tr_truth_load(dir, &t);
    CHECK_MSG(st == GS_OK, "truth: %s", gs_detail());
    if (st != GS_OK) return NULL;
    float *out = malloc(sizeof *out * (size_t)t.W * t.H * t.B);
    int lights = 0;
    srv_tr_truth_of(&t, bulb, phase_deg, out, &lights);
    srv_tr_truth_release(&t);
    CHECK_MSG(lights > 0, "no light of %s at %g deg in %s", bulb, phase_deg, dir);
    if (!lights) {
        free(out);
        return NULL;
    }
    return out;
}

double trfx_error(const char *dir, const rec_unmix_result *r, const rec_sources *src, int s)
{
    float *t = trfx_truth(dir, src->bulb[s], src->phase_deg[s]);
    if (!t) return NAN;
    size_t P = (size_t)r->width * r->height;
    double e = srv_tr_rel_error(r->tq + (size_t)s * P * r->bands, t, P, r->bands);
    free(t);
    return e;
}

/* Solve the n x n system G x = h by Gaussian elimination with partial pivoting; 0 if singular. */
static int solve(double *G, double *h, int n, double *x)
{
    for (int c = 0; c < n; c++) {
        int piv = c;
        for (int r = c + 1; r < n; r++)
            if (fabs(G[r * n + c]) > fabs(G[piv * n + c])) piv = r;
        if (!(fabs(G[piv * n + c]) > 0)) return 0;
        for (int j = 0; j < n; j++) {
            double t = G[c * n + j];
            G[c * n + j] = G[piv * n + j];
            G[piv * n + j] = t;
        }
        double t = h[c];
        h[c] = h[piv];
        h[piv] = t;
        for (int r = c + 1; r < n; r++) {
            double f = G[r * n + c] / G[c * n + c];
            for (int j = c; j < n; j++) G[r * n + j] -= f * G[c * n + j];
            h[r] -= f * h[c];
        }
    }
    for (int r = n - 1; r >= 0; r--) {
        double s = h[r];
        for (int j = r + 1; j < n; j++) s -= G[r * n + j] * x[j];
        x[r] = s / G[r * n + r];
    }
    return 1;
}

void trfx_oracle_errors(const char *dir, const gs_capture *cap, const gs_delight *d,
                        const rec_sources *src, const rec_unmix_result *r, double *err,
                        double *ours)
{
    int S = src->S, B = cap->bands, K = cap->K;
    size_t P = (size_t)cap->width * cap->height;
    float **tr = calloc((size_t)S, sizeof *tr);
    double *bt = malloc(sizeof *bt * (size_t)S * B * K);
    double e2[16] = {0}, o2[16] = {0}, t2[16] = {0};
    double q[16][3];
    for (int s = 0; s < S; s++) {
        tr[s] = trfx_truth(dir, src->bulb[s], src->phase_deg[s]);
        if (!strcmp(src->bulb[s], REC_DAYLIGHT)) {
            /* constant: B all ones (its Q only scales t) */
            for (int i = 0; i < B * K; i++) bt[(size_t)s * B * K + i] = 1;
            for (int c = 0; c < B; c++) q[s][c] = 1.0 / B;
            CHECK(tr[s] != NULL);
            if (!tr[s]) goto done;
            continue;
        }
        const gs_bulb *b = gs_delight_find(d, src->bulb[s], cap->grid_hz, B);
        CHECK(b != NULL && tr[s] != NULL);
        if (!b || !tr[s]) goto done;
        for (int c = 0; c < B; c++) q[s][c] = b->chroma[c];
        CHECK_OK(gs_brf_integrate(&b->brf, gs_phase_to_shift(src->phase_deg[s]), K, bt + (size_t)s * B * K));
    }
    gs_noise nz = gs_capture_noise(cap);
    for (size_t p = 0; p < P; p++) {
        int known = 1;
        for (int s = 0; s < S; s++) known &= isfinite(r->tq[((size_t)s * P + p) * B]);
        if (!known) continue;
        int y = (int)(p / (size_t)cap->width), x = (int)(p % (size_t)cap->width);
        for (int b = 0; b < B; b++) {
            double G[256] = {0}, h[16] = {0}, t[16];
            int used = 0;
            for (int k = 0; k < K; k++) {
                int sat = 0;
                for (int c = 0; c < B; c++) sat |= !isfinite(gs_capture_value(cap, k, y, x, c));
                if (sat) continue;
                int hv = cap->halvings ? cap->halvings[(size_t)k * P + p] : 0;
                double cyc = cap->frames[k].cycles / (double)(1u << hv), mu = 0, a[16];
                for (int s = 0; s < S; s++) {
                    a[s] = q[s][b] * bt[((size_t)s * B + b) * K + k];
                    mu += tr[s][p * B + b] * bt[((size_t)s * B + b) * K + k];
                }
                double var = (nz.read_var_dn2 + fmax(mu * cyc, 0) * nz.inv_gain) / (cyc * cyc);
                double v = gs_capture_value(cap, k, y, x, b);
                for (int i = 0; i < S; i++) {
                    h[i] += v * a[i] / var;
                    for (int j = 0; j < S; j++) G[i * S + j] += a[i] * a[j] / var;
                }
                used++;
            }
            if (used < S || !solve(G, h, S, t)) continue;
            for (int s = 0; s < S; s++) {
                double tv = tr[s][p * B + b], est = t[s] * q[s][b];
                double mine = r->tq[((size_t)s * P + p) * B + b];
                e2[s] += (est - tv) * (est - tv);
                o2[s] += (mine - tv) * (mine - tv);
                t2[s] += tv * tv;
            }
        }
    }
    for (int s = 0; s < S; s++) {
        err[s] = t2[s] > 0 ? sqrt(e2[s] / t2[s]) : NAN;
        ours[s] = t2[s] > 0 ? sqrt(o2[s] / t2[s]) : NAN;
    }
done:
    for (int s = 0; s < S; s++) free(tr[s]);
    free(tr);
    free(bt);
}
