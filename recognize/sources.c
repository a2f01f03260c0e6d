/* sources.c - the sources of AC light transport (paper Sec. 5.1): Q and B from DELIGHT for a
 * list of (bulb, phase), merging inseparable ones (Eq. 15); the lights in view as sources
 * (Sec. 5.1 (a), (b): blobs, then Eq. 7); the gridsurvey-sources/1 file. */
#include "recognize/recognize.h"
#include "recognize/internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

void rec_sources_release(rec_sources *s)
{
    if (!s) return;
    free(s->bulb);
    free(s->phase_deg);
    free(s->q);
    free(s->b);
    free(s->fixed);
    free(s->merged);
    memset(s, 0, sizeof *s);
}

static gs_status sources_alloc(rec_sources *o, int S, int bands, int K)
{
    memset(o, 0, sizeof *o);
    o->S = S;
    o->bands = bands;
    o->K = K;
    o->bulb = calloc((size_t)S, sizeof *o->bulb);
    o->phase_deg = calloc((size_t)S, sizeof *o->phase_deg);
    o->q = calloc((size_t)S * bands, sizeof *o->q);
    o->b = calloc((size_t)S * bands * K, sizeof *o->b);
    o->fixed = calloc((size_t)S, sizeof *o->fixed);
    o->merged = calloc((size_t)S, sizeof *o->merged);
    if (!o->bulb || !o->phase_deg || !o->q || !o->b || !o->fixed || !o->merged) {
        rec_sources_release(o);
        return gs_fail(GS_ENOMEM, "sources: out of memory");
    }
    return GS_OK;
}

/* Shift of a phase modulo one cycle, in [0, 1): phi and phi + 180 deg delay the BRF alike. */
static double shift_of(double phase_deg)
{
    double s = fmod(gs_phase_to_shift(phase_deg), 1.0);
    return s < 0 ? s + 1.0 : s;
}

static int same_shift(double a_deg, double b_deg)
{
    double d = fabs(shift_of(a_deg) - shift_of(b_deg));
    return d < 1e-9 || d > 1.0 - 1e-9;
}

gs_status rec_sources_build(const gs_delight *d, const rec_source_spec *specs, int n,
                            int grid_hz, int bands, int K, rec_sources *out, int *into)
{
    memset(out, 0, sizeof *out);
    if (n < 1 || n > REC_MAX_SOURCES || K < 2 || K > 1024 || (bands != 1 && bands != 3))
        return gs_fail(GS_EINVAL, "sources: %d sources (expected 1..%d), K = %d (2..1024), %d "
                       "bands (1 or 3)", n, REC_MAX_SOURCES, K, bands);
    /* Eq. 15: the same bulb at the same BRF shift is one source */
    int map[REC_MAX_SOURCES], S = 0, first[REC_MAX_SOURCES];
    for (int i = 0; i < n; i++) {
        map[i] = -1;
        for (int j = 0; j < S; j++)
            if (!strcmp(specs[first[j]].bulb, specs[i].bulb) &&
                (!strcmp(specs[i].bulb, REC_DAYLIGHT) ||
                 same_shift(specs[first[j]].phase_deg, specs[i].phase_deg)))
                map[i] = j;
        if (map[i] < 0) {
            first[S] = i;
            map[i] = S++;
        }
    }
    gs_status st = sources_alloc(out, S, bands, K);
    if (st != GS_OK) return st;
    for (int i = 0; i < n; i++) {
        out->merged[map[i]]++;
        if (into) into[i] = map[i];
    }
    for (int s = 0; s < S; s++) {
        const rec_source_spec *sp = &specs[first[s]];
        snprintf(out->bulb[s], GS_ID_MAX, "%s", sp->bulb);
        double *b = out->b + (size_t)s * bands * K;
        if (!strcmp(sp->bulb, REC_DAYLIGHT)) {
            /* daylight: constant over the few thousand cycles of a capture (Sec. 5.3) */
            out->phase_deg[s] = 0;
            out->fixed[s] = 1;
            for (int c = 0; c < bands; c++) out->q[s * bands + c] = 1.0 / bands;
            for (int i = 0; i < bands * K; i++) b[i] = 1.0;
            continue;
        }
        out->phase_deg[s] = sp->phase_deg;
        const gs_bulb *bu = d ? gs_delight_find(d, sp->bulb, grid_hz, bands) : NULL;
        if (!bu) {
            rec_sources_release(out);
            return gs_fail(GS_ENOTFOUND, "source %d: bulb '%s': expected a DELIGHT bulb id with a %d "
                           "Hz, %d-band entry (gridsurvey delight list) or \"%s\"", first[s],
                           sp->bulb, grid_hz, bands, REC_DAYLIGHT);
        }
        for (int c = 0; c < bands; c++) out->q[s * bands + c] = bu->chroma[c];
        if ((st = gs_brf_integrate(&bu->brf, gs_phase_to_shift(sp->phase_deg), K, b)) != GS_OK) {
            rec_sources_release(out);
            return st;
        }
    }
    return GS_OK;
}

/* ------------------------------------------------------------------ --sources auto */

#define REC_AUTO_MAX_PX 20000   /* pixels tried by Eq. 7, brightest first */
/* A pixel is dominated by one source when one template fits it to this chi-square per degree
 * of freedom (Eq. 7's model error included): the lab scene's bulbs fit to 1.4-2.5, the walls
 * they light together to 5 and far more. */
#define REC_AUTO_MAX_CHI2_DOF 3.0

struct cand {
    size_t p;
    double snr;
};

static int by_snr_desc(const void *a, const void *b)
{
    double x = ((const struct cand *)a)->snr, y = ((const struct cand *)b)->snr;
    return (x < y) - (x > y);
}

/* The cosine between the flicker (mean removed per band) of two bands x K templates. */
static double flicker_cos(const double *a, const double *b, int B, int K)
{
    double ab = 0, aa = 0, bb = 0;
    for (int c = 0; c < B; c++) {
        double ma = 0, mb = 0;
        for (int k = 0; k < K; k++) {
            ma += a[c * K + k] / K;
            mb += b[c * K + k] / K;
        }
        for (int k = 0; k < K; k++) {
            double x = a[c * K + k] - ma, y = b[c * K + k] - mb;
            ab += x * y;
            aa += x * x;
            bb += y * y;
        }
    }
    return aa > 0 && bb > 0 ? ab / sqrt(aa * bb) : 1.0;
}

gs_status rec_sources_auto(const gs_capture *cap, const rec_matcher *m, double min_snr,
                           int min_px, int max_sources, rec_source_spec **specs, int *n,
                           size_t *tested, size_t *dominated)
{
    *specs = NULL;
    *n = 0;
    if (tested) *tested = 0;
    if (dominated) *dominated = 0;
    if (max_sources < 1 || max_sources > REC_MAX_SOURCES || min_px < 1 || !(min_snr >= 0))
        return gs_fail(GS_EINVAL, "sources auto: max_sources %d (expected 1..%d), min_px %d (>= 1), "
                       "min_snr %g (>= 0)", max_sources, REC_MAX_SOURCES, min_px, min_snr);
    gs_status st = gs_capture_check(cap, "sources auto");
    if (st != GS_OK) return st;
    int B = cap->bands, K = cap->K;
    size_t D = (size_t)B * K, P = (size_t)cap->width * cap->height;
    size_t nb = rec_matcher_bulb_count(m);
    double *tpl = NULL;
    struct cand *cand = NULL;
    double *x = malloc(sizeof *x * D), *sg = malloc(sizeof *sg * D);
    /* votes per (bulb, phase): the phase set's phases found so far */
    size_t cap_v = nb * 8 + 8, nv = 0;
    struct vote { int bulb; double phase_deg; size_t px; } *v = malloc(sizeof *v * cap_v);
    rec_source_spec *out = calloc((size_t)max_sources, sizeof *out);
    cand = malloc(sizeof *cand * (P ? P : 1));
    tpl = malloc(sizeof *tpl * D * (size_t)(max_sources + 1));
    unsigned char *kept = malloc((size_t)K);   /* (as rec_match_catalog) */
    if (kept) rec_frames_left_out(cap, m->o.max_drift_windows, kept);
    if (!x || !sg || !v || !out || !cand || !tpl || !kept) {
        st = gs_fail(GS_ENOMEM, "sources auto: out of memory");
        goto done;
    }
    gs_noise nz = gs_capture_noise(cap);
    /* the pixels to try: SNR of the mean at least min_snr, the brightest REC_AUTO_MAX_PX */
    size_t ncand = 0;
    for (size_t p = 0; p < P; p++) {
        double sum = 0, var = 0;
        for (int k = 0; k < K; k++) {
            int h = cap->halvings ? cap->halvings[(size_t)k * P + p] : 0;
            double c = cap->frames[k].cycles / (double)(1u << h);
            for (int b = 0; b < B; b++) {
                /* saturated samples count at the saturation level: they are bright */
                double raw = cap->raw[((size_t)k * P + p) * B + b];
                if (raw > cap->saturation_dn) raw = cap->saturation_dn;
                sum += (raw - cap->black_level_dn) / c;
                var += gs_noise_raw_var(&nz, raw) / (c * c);
            }
        }
        if (var > 0 && sum > min_snr * sqrt(var)) {
            cand[ncand].p = p;
            cand[ncand++].snr = sum;   /* brightest first: bulbs in view */
        }
    }
    qsort(cand, ncand, sizeof *cand, by_snr_desc);
    if (ncand > REC_AUTO_MAX_PX) ncand = REC_AUTO_MAX_PX;
    size_t ntested = 0, ndom = 0;
    for (size_t ci = 0; ci < ncand && st == GS_OK; ci++) {
        size_t p = cand[ci].p;
        for (int k = 0; k < K; k++) {
            int h = cap->halvings ? cap->halvings[(size_t)k * P + p] : 0;
            double c = cap->frames[k].cycles / (double)(1u << h);
            for (int b = 0; b < B; b++) {
                unsigned short raw = cap->raw[((size_t)k * P + p) * B + b];
                size_t d = (size_t)b * K + k;
                x[d] = ((double)raw - cap->black_level_dn) / c;
                sg[d] = raw >= cap->saturation_dn || !kept[k] ? INFINITY : sqrt(gs_noise_raw_var(&nz, raw)) / c;
            }
        }
        ntested++;
        rec_match r;
        st = rec_match_light(m, x, sg, &r);
        /* the phase must be certain; a bulb ambiguous between near-identical models still
         * names the source (the same BRF: see the merge below) */
        if (st != GS_OK || r.bulb < 0 || r.phase_confidence < 0.99 ||
            (r.flags & (REC_MATCH_UNKNOWN | REC_MATCH_PHASE_AMBIGUOUS)) ||
            !(r.chi2 <= REC_AUTO_MAX_CHI2_DOF * (r.dof > 0 ? r.dof : 1)))
            continue;

        ndom++;
        size_t i = 0;
        for (; i < nv; i++)
            if (v[i].bulb == r.bulb && same_shift(v[i].phase_deg, r.phase_deg)) break;
        if (i == nv) {
            if (nv == cap_v) continue;
            v[nv++] = (struct vote){r.bulb, r.phase_deg, 0};
        }
        v[i].px++;
    }
    if (st != GS_OK) goto done;
    if (tested) *tested = ntested;
    if (dominated) *dominated = ndom;
    /* most pixels first */
    for (size_t i = 1; i < nv; i++)
        for (size_t j = i; j > 0 && v[j].px > v[j - 1].px; j--) {
            struct vote t = v[j];
            v[j] = v[j - 1];
            v[j - 1] = t;
        }
    int S = 0, taken[REC_MAX_SOURCES];
    for (size_t i = 0; i < nv && S < max_sources && st == GS_OK; i++) {
        if (v[i].px < (size_t)min_px) break;
        const gs_bulb *bu = rec_matcher_bulb(m, (size_t)v[i].bulb);
        double *t = tpl + (size_t)S * D;
        if ((st = gs_brf_integrate(&bu->brf, gs_phase_to_shift(v[i].phase_deg), K, t)) != GS_OK) break;
        /* a near-identical BRF to a source already taken (a similar model of the same bulb
         * at the same phase) is the same source: Eq. 15 */
        int dup = 0;
        for (int j = 0; j < S && !dup; j++) {
            const gs_bulb *bj = rec_matcher_bulb(m, (size_t)taken[j]);
            dup = same_shift(out[j].phase_deg, v[i].phase_deg) &&
                  (bj->type == bu->type || flicker_cos(t, tpl + (size_t)j * D, B, K) > 0.995);
        }
        if (dup) continue;
        snprintf(out[S].bulb, GS_ID_MAX, "%s", bu->id);
        out[S].phase_deg = v[i].phase_deg;
        taken[S] = v[i].bulb;
        S++;
    }
    if (st != GS_OK) goto done;
    if (S == 0) {
        st = gs_fail(GS_ENOTFOUND, "sources auto: no pixel of %zu tried is dominated by one source "
                     "recognised with Eq. 7 (at least %d pixels each): give the sources with "
                     "--sources FILE", ntested, min_px);
        goto done;
    }
    *specs = out;
    *n = S;
    out = NULL;
done:
    free(out);
    free(cand);
    free(tpl);
    free(v);
    free(x);
    free(sg);
    free(kept);
    return st;
}

/* ------------------------------------------------------------------ the file */

static const char *const top_keys[] = {"format", "sources", "capture", "unmix", NULL};
static const char *const src_keys[] = {"bulb", "phase_deg", "file", "chromaticity", "brf",
                                       "brf_database", "predicted_error", "merged", "render",
                                       NULL};

/* The document's "sources" array, checked: n, and its json. */
static gs_status open_doc(const char *path, gs_json **doc, json_t **arr)
{
    gs_status st = gs_json_load(path, 1u << 26, doc);
    if (st != GS_OK) return st;
    json_t *root = gs_json_root(*doc);
    char fmt[64];
    if (!json_is_object(root)) return gs_json_fail(*doc, GS_EFORMAT, "", "expected a JSON object");
    if ((st = gs_json_check_keys(*doc, root, "", top_keys)) != GS_OK ||
        (st = gs_json_get_str(*doc, root, "", "format", 1, NULL, fmt, sizeof fmt)) != GS_OK)
        return st;
    if (strcmp(fmt, REC_SOURCES_FORMAT))
        return gs_json_fail(*doc, GS_EFORMAT, "format", "expected \"%s\" (got \"%s\")",
                            REC_SOURCES_FORMAT, fmt);
    *arr = json_object_get(root, "sources");
    if (!json_is_array(*arr) || json_array_size(*arr) < 1 || json_array_size(*arr) > REC_MAX_SOURCES)
        return gs_json_fail(*doc, GS_EFORMAT, "sources", "expected an array of 1 to %d sources",
                            REC_MAX_SOURCES);
    return GS_OK;
}

static gs_status read_spec(const gs_json *doc, json_t *o, const char *p, rec_source_spec *sp)
{
    if (!json_is_object(o)) return gs_json_fail(doc, GS_EFORMAT, p, "expected an object {bulb, phase_deg}");
    gs_status st;
    if ((st = gs_json_check_keys(doc, o, p, src_keys)) != GS_OK ||
        (st = gs_json_get_str(doc, o, p, "bulb", 1, NULL, sp->bulb, sizeof sp->bulb)) != GS_OK ||
        (st = gs_json_get_num(doc, o, p, "phase_deg", strcmp(sp->bulb, REC_DAYLIGHT) != 0, 0,
                              -720, 720, NULL, &sp->phase_deg)) != GS_OK)
        return st;
    return GS_OK;
}

gs_status rec_sources_read_specs(const char *path, rec_source_spec **specs, int *n)
{
    *specs = NULL;
    *n = 0;
    gs_json *doc = NULL;
    json_t *arr;
    gs_status st = open_doc(path, &doc, &arr);
    rec_source_spec *out = NULL;
    if (st == GS_OK) {
        size_t m = json_array_size(arr);
        out = calloc(m, sizeof *out);
        if (!out) st = gs_fail(GS_ENOMEM, "%s: out of memory", path);
        for (size_t i = 0; i < m && st == GS_OK; i++) {
            char p[32];
            snprintf(p, sizeof p, "sources[%zu]", i);
            st = read_spec(doc, json_array_get(arr, i), p, &out[i]);
        }
        if (st == GS_OK) {
            *specs = out;
            *n = (int)m;
            out = NULL;
        }
    }
    free(out);
    gs_json_free(doc);
    return st;
}

void rec_capture_meta_of(const gs_capture *cap, rec_capture_meta *m)
{
    memset(m, 0, sizeof *m);
    m->grid_hz = cap->grid_hz;
    m->K = cap->K;
    m->bands = cap->bands;
    m->width = cap->width;
    m->height = cap->height;
    m->locked = cap->locked;
    m->cycles = cap->frames ? cap->frames[0].cycles : 0;
    m->saturation_dn = cap->saturation_dn;
    m->black_level_dn = cap->black_level_dn;
    m->gain_e_per_dn = cap->gain_e_per_dn;
    m->read_noise_dn = cap->read_noise_dn;
}

static void real(gs_text *t, double v)
{
    char b[40];
    if (!isfinite(v)) {
        gs_text_printf(t, "null");
        return;
    }
    gs_json_real(b, sizeof b, v);
    gs_text_printf(t, "%s", b);
}

static void rows(gs_text *t, const double *b, int bands, int K)
{
    gs_text_printf(t, "[");
    for (int c = 0; c < bands; c++) {
        gs_text_printf(t, "%s[", c ? ", " : "");
        for (int k = 0; k < K; k++) {
            if (k) gs_text_printf(t, ", ");
            real(t, b[c * K + k]);
        }
        gs_text_printf(t, "]");
    }
    gs_text_printf(t, "]");
}

gs_status rec_sources_write(const char *path, const rec_sources *src, const rec_unmix_result *r,
                            const rec_capture_meta *m, int refine, const char *const *files,
                            const char *const *renders, const double *brf_database)
{
    gs_text t = {0};
    int B = src->bands, K = src->K;
    gs_text_printf(&t, "{\n  \"format\": \"%s\",\n", REC_SOURCES_FORMAT);
    gs_text_printf(&t, "  \"capture\": {\"grid_hz\": %d, \"K\": %d, \"bands\": %d, \"width\": %d, "
                   "\"height\": %d, \"locked\": %s, \"cycles\": ", m->grid_hz, m->K, m->bands,
                   m->width, m->height, m->locked ? "true" : "false");
    real(&t, m->cycles);
    gs_text_printf(&t, ", \"saturation\": ");
    real(&t, m->saturation_dn);
    gs_text_printf(&t, ", \"black_level\": ");
    real(&t, m->black_level_dn);
    gs_text_printf(&t, ", \"gain_e_per_dn\": ");
    real(&t, m->gain_e_per_dn);
    gs_text_printf(&t, ", \"read_noise_dn\": ");
    real(&t, m->read_noise_dn);
    gs_text_printf(&t, "},\n");
    if (r) {
        gs_text_printf(&t, "  \"unmix\": {\"refine\": %d, \"cond\": [", refine);
        for (int c = 0; c < B; c++) {
            if (c) gs_text_printf(&t, ", ");
            real(&t, r->cond[c]);
        }
        gs_text_printf(&t, "], \"partial_px\": %zu, \"unknown_px\": %zu, \"rms_residual\": ",
                       r->partial_px, r->unknown_px);
        real(&t, r->rms_residual);
        gs_text_printf(&t, "},\n");
    }
    gs_text_printf(&t, "  \"sources\": [\n");
    for (int s = 0; s < src->S; s++) {
        gs_text_printf(&t, "    {\"bulb\": ");
        gs_text_json_string(&t, src->bulb[s]);
        gs_text_printf(&t, ", \"phase_deg\": ");
        real(&t, src->phase_deg[s]);
        if (files && files[s] && files[s][0]) {
            gs_text_printf(&t, ", \"file\": ");
            gs_text_json_string(&t, files[s]);
        }
        if (renders && renders[s] && renders[s][0]) {
            gs_text_printf(&t, ", \"render\": ");
            gs_text_json_string(&t, renders[s]);
        }
        gs_text_printf(&t, ", \"merged\": %d, \"chromaticity\": [", src->merged[s]);
        for (int c = 0; c < B; c++) {
            if (c) gs_text_printf(&t, ", ");
            real(&t, src->q[s * B + c]);
        }
        gs_text_printf(&t, "]");
        if (r) {
            gs_text_printf(&t, ", \"predicted_error\": ");
            real(&t, r->predicted_error[s]);
        }
        gs_text_printf(&t, ",\n     \"brf\": ");
        rows(&t, (r ? r->b : src->b) + (size_t)s * B * K, B, K);
        if (brf_database) {
            gs_text_printf(&t, ",\n     \"brf_database\": ");
            rows(&t, brf_database + (size_t)s * B * K, B, K);
        }
        gs_text_printf(&t, "}%s\n", s + 1 < src->S ? "," : "");
    }
    gs_text_printf(&t, "  ]\n}\n");
    if (t.oom) {
        free(t.s);
        return gs_fail(GS_ENOMEM, "%s: out of memory", path);
    }
    gs_status st = gs_file_write_atomic(path, t.s, t.n);
    free(t.s);
    return st;
}

/* A "brf" member: bands arrays of K numbers >= 0. */
static gs_status read_rows(const gs_json *doc, json_t *o, const char *p, int bands, int K, double *b)
{
    json_t *a = json_object_get(o, "brf");
    char q[64];
    snprintf(q, sizeof q, "%s.brf", p);
    if (!json_is_array(a) || (int)json_array_size(a) != bands)
        return gs_json_fail(doc, GS_EFORMAT, q, "expected %d arrays of K = %d numbers", bands, K);
    for (int c = 0; c < bands; c++) {
        json_t *row = json_array_get(a, (size_t)c);
        if (!json_is_array(row) || (int)json_array_size(row) != K)
            return gs_json_fail(doc, GS_EFORMAT, q, "band %d: expected an array of K = %d numbers", c, K);
        for (int k = 0; k < K; k++) {
            json_t *v = json_array_get(row, (size_t)k);
            double x = json_is_number(v) ? json_number_value(v) : NAN;
            /* window means of a trigonometric polynomial may dip below 0 by rounding */
            if (!(x >= -1e-6 && x < 1e6))
                return gs_json_fail(doc, GS_EFORMAT, q, "band %d sample %d: expected a number "
                                    "from 0 to 1e6", c, k);
            b[c * K + k] = x;
        }
    }
    return GS_OK;
}

gs_status rec_sources_read(const char *path, rec_sources *src, rec_capture_meta *m,
                           char (**files)[GS_PATH_MAX])
{
    memset(src, 0, sizeof *src);
    memset(m, 0, sizeof *m);
    *files = NULL;
    gs_json *doc = NULL;
    json_t *arr, *cap = NULL;
    gs_status st = open_doc(path, &doc, &arr);
    static const char *const ckeys[] = {"grid_hz", "K", "bands", "width", "height", "locked",
                                        "cycles", "saturation", "black_level", "gain_e_per_dn",
                                        "read_noise_dn", NULL};
    long long g, K, B, w, h;
    if (st == GS_OK) st = gs_json_get_obj(doc, gs_json_root(doc), "", "capture", 1, &cap);
    if (st == GS_OK &&
        ((st = gs_json_check_keys(doc, cap, "capture", ckeys)) != GS_OK ||
         (st = gs_json_get_int(doc, cap, "capture", "grid_hz", 1, 0, 50, 60, NULL, &g)) != GS_OK ||
         (st = gs_json_get_int(doc, cap, "capture", "K", 1, 0, 2, 1024, NULL, &K)) != GS_OK ||
         (st = gs_json_get_int(doc, cap, "capture", "bands", 1, 0, 1, 3, NULL, &B)) != GS_OK ||
         (st = gs_json_get_int(doc, cap, "capture", "width", 1, 0, 1, 32768, NULL, &w)) != GS_OK ||
         (st = gs_json_get_int(doc, cap, "capture", "height", 1, 0, 1, 32768, NULL, &h)) != GS_OK ||
         (st = gs_json_get_bool(doc, cap, "capture", "locked", 0, 1, &m->locked)) != GS_OK ||
         (st = gs_json_get_num(doc, cap, "capture", "cycles", 1, 0, 1e-9, 1e12, NULL, &m->cycles)) != GS_OK ||
         (st = gs_json_get_num(doc, cap, "capture", "saturation", 1, 0, 1, 65536, NULL, &m->saturation_dn)) != GS_OK ||
         (st = gs_json_get_num(doc, cap, "capture", "black_level", 0, 0, 0, 65535, NULL, &m->black_level_dn)) != GS_OK ||
         (st = gs_json_get_num(doc, cap, "capture", "gain_e_per_dn", 0, 0, 0, 1e9, NULL, &m->gain_e_per_dn)) != GS_OK ||
         (st = gs_json_get_num(doc, cap, "capture", "read_noise_dn", 0, 1, 0, 1e9, NULL, &m->read_noise_dn)) != GS_OK)) {
        /* st names the field */
    }
    if (st == GS_OK && B == 2) st = gs_json_fail(doc, GS_EFORMAT, "capture.bands", "expected 1 or 3 (got 2)");
    if (st == GS_OK) {
        m->grid_hz = (int)g;
        m->K = (int)K;
        m->bands = (int)B;
        m->width = (int)w;
        m->height = (int)h;
        int S = (int)json_array_size(arr);
        st = sources_alloc(src, S, (int)B, (int)K);
        if (st == GS_OK && !(*files = calloc((size_t)S, sizeof **files)))
            st = gs_fail(GS_ENOMEM, "%s: out of memory", path);
        for (int s = 0; s < S && st == GS_OK; s++) {
            char p[32];
            snprintf(p, sizeof p, "sources[%d]", s);
            json_t *o = json_array_get(arr, (size_t)s);
            rec_source_spec sp;
            long long mg;
            double q[3];
            if ((st = read_spec(doc, o, p, &sp)) != GS_OK ||
                (st = gs_json_get_str(doc, o, p, "file", 1, NULL, (*files)[s], GS_PATH_MAX)) != GS_OK ||
                (st = gs_json_get_num_array(doc, o, p, "chromaticity", (size_t)B, 3, 0, 1, q, NULL)) != GS_OK ||
                (st = gs_json_get_int(doc, o, p, "merged", 0, 1, 1, 1000000, NULL, &mg)) != GS_OK ||
                (st = read_rows(doc, o, p, (int)B, (int)K, src->b + (size_t)s * B * K)) != GS_OK)
                break;
            if (strchr((*files)[s], '/') || (*files)[s][0] == '.') {
                char fp[48];
                snprintf(fp, sizeof fp, "%s.file", p);
                st = gs_json_fail(doc, GS_EFORMAT, fp, "expected a file name in the directory (got \"%s\")", (*files)[s]);
                break;
            }
            snprintf(src->bulb[s], GS_ID_MAX, "%s", sp.bulb);
            src->phase_deg[s] = sp.phase_deg;
            src->fixed[s] = !strcmp(sp.bulb, REC_DAYLIGHT);
            src->merged[s] = (int)mg;
            for (int c = 0; c < B; c++) src->q[s * B + c] = q[c];
        }
    }
    if (st != GS_OK) {
        rec_sources_release(src);
        free(*files);
        *files = NULL;
    }
    gs_json_free(doc);
    return st;
}
