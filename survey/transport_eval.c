/* transport_eval.c - what `unmix`, `relight` and `separate` share: the DELIGHT they use and the
 * evaluation against a simulated capture's truth (truth.json "transport": every source's tau Q,
 * docs/light-transport.md). */
#include "survey/internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

gs_status srv_tr_delight(const char *db, gs_delight **out)
{
    const char *env = getenv("GRIDSURVEY_DELIGHT");
    return gs_delight_open(db ? db : env && *env ? env : NULL, out);
}

void srv_tr_truth_release(srv_tr_truth *t)
{
    if (!t) return;
    free(t->light);
    free(t->bulb);
    free(t->phase_deg);
    free(t->img);
    memset(t, 0, sizeof *t);
}

gs_status srv_tr_truth_load(const char *capdir, srv_tr_truth *t)
{
    memset(t, 0, sizeof *t);
    char path[GS_PATH_MAX * 4];
    snprintf(path, sizeof path, "%s/truth.json", capdir);
    gs_json *doc = NULL;
    gs_status st = gs_json_load(path, 0, &doc);
    if (st != GS_OK) return st;
    json_t *tr = json_object_get(gs_json_root(doc), "transport");
    json_t *im = json_object_get(tr, "images");
    if (!json_is_array(im) || json_array_size(im) < 1) {
        gs_json_free(doc);
        return gs_fail(GS_ENOTFOUND, "%s: no transport truth", path);
    }
    int n = (int)json_array_size(im);
    t->n = n;
    t->light = calloc((size_t)n, sizeof *t->light);
    t->bulb = calloc((size_t)n, sizeof *t->bulb);
    t->phase_deg = calloc((size_t)n, sizeof *t->phase_deg);
    if (!t->light || !t->bulb || !t->phase_deg) st = gs_fail(GS_ENOMEM, "truth: out of memory");
    for (int i = 0; i < n && st == GS_OK; i++) {
        json_t *o = json_array_get(im, (size_t)i);
        const char *l = json_string_value(json_object_get(o, "light"));
        const char *b = json_string_value(json_object_get(o, "bulb"));
        const char *f = json_string_value(json_object_get(o, "file"));
        json_t *ph = json_object_get(o, "phase_deg");
        if (!l || !b || !f || !json_is_number(ph) || strchr(f, '/')) {
            st = gs_fail(GS_EFORMAT, "%s: transport.images[%d]: expected light, bulb, phase_deg and file", path, i);
            break;
        }
        snprintf(t->light[i], sizeof t->light[i], "%s", l);
        snprintf(t->bulb[i], sizeof t->bulb[i], "%s", b);
        t->phase_deg[i] = json_number_value(ph);
        char fp[GS_PATH_MAX * 4 + 300];
        snprintf(fp, sizeof fp, "%s/%s", capdir, f);
        int w, h, bands, pages;
        float *img;
        if ((st = gs_tiff_read_float(fp, &w, &h, &bands, &pages, &img)) != GS_OK) break;
        if (i == 0) {
            t->W = w;
            t->H = h;
            t->B = bands;
            t->img = malloc(sizeof *t->img * (size_t)n * w * h * bands);
            if (!t->img) st = gs_fail(GS_ENOMEM, "truth: out of memory");
        } else if (w != t->W || h != t->H || bands != t->B || pages != 1) {
            st = gs_fail(GS_EFORMAT, "%s: %dx%dx%d: expected %dx%dx%d as the first", fp, w, h, bands,
                         t->W, t->H, t->B);
        }
        if (st == GS_OK) memcpy(t->img + (size_t)i * w * h * bands, img, sizeof *img * (size_t)w * h * bands);
        free(img);
    }
    gs_json_free(doc);
    if (st != GS_OK) srv_tr_truth_release(t);
    return st;
}

int srv_tr_same_source(const char *bulb_a, double phase_a_deg, const char *bulb_b, double phase_b_deg)
{
    if (strcmp(bulb_a, bulb_b)) return 0;
    if (!strcmp(bulb_a, REC_DAYLIGHT)) return 1;
    double d = fmod(fabs(gs_phase_to_shift(phase_a_deg) - gs_phase_to_shift(phase_b_deg)), 1.0);
    return d < 1e-6 || d > 1 - 1e-6;
}

gs_status srv_tr_truth_of(const srv_tr_truth *t, const char *bulb, double phase_deg, float *out,
                          int *lights)
{
    size_t n = (size_t)t->W * t->H * t->B;
    memset(out, 0, sizeof *out * n);
    *lights = 0;
    for (int i = 0; i < t->n; i++) {
        if (!srv_tr_same_source(t->bulb[i], t->phase_deg[i], bulb, phase_deg)) continue;
        (*lights)++;
        const float *im = t->img + (size_t)i * n;
        for (size_t j = 0; j < n; j++) out[j] += im[j];
    }
    return GS_OK;
}

double srv_tr_rel_error(const float *est, const float *truth, size_t P, int bands)
{
    double e2 = 0, t2 = 0;
    for (size_t p = 0; p < P; p++) {
        int known = 1;
        for (int b = 0; b < bands; b++) known &= isfinite(est[p * bands + b]);
        if (!known) continue;
        for (int b = 0; b < bands; b++) {
            double d = est[p * bands + b] - truth[p * bands + b];
            e2 += d * d;
            t2 += (double)truth[p * bands + b] * truth[p * bands + b];
        }
    }
    return t2 > 0 ? sqrt(e2 / t2) : NAN;
}

const char *srv_tr_truth_match(const srv_tr_truth *t, const gs_delight *d, int grid_hz, int bands,
                               const char *bulb, double phase_deg)
{
    for (int i = 0; i < t->n; i++)
        if (srv_tr_same_source(t->bulb[i], t->phase_deg[i], bulb, phase_deg)) return bulb;
    const gs_bulb *b = gs_delight_find(d, bulb, grid_hz, bands);
    for (int i = 0; b && i < t->n; i++) {
        const gs_bulb *tb = gs_delight_find(d, t->bulb[i], grid_hz, bands);
        if (tb && tb->type == b->type && srv_tr_same_source(t->bulb[i], t->phase_deg[i], t->bulb[i], phase_deg))
            return t->bulb[i];
    }
    return NULL;
}

double srv_tr_ncc(const float *a, const float *b, size_t n)
{
    double sa = 0, sb = 0, saa = 0, sbb = 0, sab = 0, m = 0;
    for (size_t i = 0; i < n; i++) {
        if (!isfinite(a[i]) || !isfinite(b[i])) continue;
        sa += a[i];
        sb += b[i];
        saa += (double)a[i] * a[i];
        sbb += (double)b[i] * b[i];
        sab += (double)a[i] * b[i];
        m++;
    }
    if (m < 2) return NAN;
    double va = saa - sa * sa / m, vb = sbb - sb * sb / m;
    return va > 0 && vb > 0 ? (sab - sa * sb / m) / sqrt(va * vb) : NAN;
}
