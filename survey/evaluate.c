/* evaluate.c - a survey database against a simulator's truth.json (gridsurvey-truth/1,
 * capture/sim.c): the stored lights of one capture are matched one-to-one to the truth's
 * lights by pixel position, then detection, false detections, bulb, technology and phase
 * accuracy, the share left unknown or ambiguous, and the location error (geodesic distance on
 * WGS84, gis_geodesic_inverse). Definitions: survey.h (srv_eval_report) and docs/pipeline.md. */
#include "survey/internal.h"
#include "capture/capture.h"

#include <limits.h>
#include <math.h>
#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define EVAL_FORMAT "gridsurvey-evaluation/1"

void srv_eval_opts_default(srv_eval_opts *o)
{
    memset(o, 0, sizeof *o);
    o->match_px = 2.0;
}

/* One light, stored or true. */
typedef struct {
    double x, y;
    char bulb[GS_ID_MAX];      /* "" = none */
    char tech[32];              /* "" = none */
    double phase_deg;           /* NaN = none */
    double lat, lon;            /* NaN = none */
    double a_m, b_m, az_deg;    /* stored: the 1-sigma ellipse (NaN = none or unbounded) */
    unsigned flags;             /* stored: match_flags */
    unsigned blob_flags;        /* stored: REC_BLOB_* */
    int resolvable;             /* truth: resolvable (1 when the truth does not say) */
    long group;                 /* truth: blend group, -1 none */
    int partner;                /* index of the matched light on the other side, -1 */
} ev_light;

/* ------------------------------------------------------------------ truth.json */

/* Member key of light i: a string copied to dst, "" when absent or null (unless required). */
static gs_status truth_text(const gs_json *doc, json_t *o, const char *key, size_t i, int required,
                            char *dst, size_t size)
{
    char path[64];
    snprintf(path, sizeof path, "lights[%zu]", i);
    json_t *v = json_object_get(o, key);
    dst[0] = '\0';
    if ((!v || json_is_null(v)) && !required) return GS_OK;
    return gs_json_get_str(doc, o, path, key, 1, NULL, dst, size);
}

/* A number of light i, or NaN when absent or null (optional fields). */
static gs_status truth_number(const gs_json *doc, json_t *o, const char *key, size_t i, double *out)
{
    char path[64];
    snprintf(path, sizeof path, "lights[%zu]", i);
    json_t *v = json_object_get(o, key);
    *out = NAN;
    if (!v || json_is_null(v)) return GS_OK;
    return gs_json_get_num(doc, o, path, key, 1, 0, -HUGE_VAL, HUGE_VAL,
                           "a finite number or null", out);
}

/* The capture's dimensions a truth file names, in the captures table's order. */
static const char *const truth_dims[5] = {"grid_hz", "K", "bands", "width", "height"};

/* The in-image lights of truth_path into *out (allocated); *total counts every light; dims the
 * capture's dimensions (truth_dims, -1 when absent). */
static gs_status read_truth(const char *path, ev_light **out, size_t *count, long *total,
                            long long dims[5])
{
    *out = NULL;
    *count = 0;
    *total = 0;
    gs_json *doc;
    gs_status s = gs_json_load(path, 0, &doc);
    if (s != GS_OK) return s;
    json_t *root = gs_json_root(doc);
    json_t *fmt = json_object_get(root, "format"), *arr = json_object_get(root, "lights");
    ev_light *v = NULL;
    size_t n = 0;
    if (!json_is_object(root) || !json_is_string(fmt) || strcmp(json_string_value(fmt), CAP_TRUTH_FORMAT)) {
        s = gs_json_fail(doc, GS_EFORMAT, "format", "expected \"%s\" (a simulator's truth.json)",
                         CAP_TRUTH_FORMAT);
        goto done;
    }
    if (!json_is_array(arr)) {
        s = gs_json_fail(doc, GS_EFORMAT, "lights", "expected an array");
        goto done;
    }
    for (int d = 0; d < 5; d++)
        if ((s = gs_json_get_int(doc, root, "", truth_dims[d], 0, -1, 1, 1 << 30, NULL, &dims[d])) != GS_OK)
            goto done;
    size_t total_n = json_array_size(arr);
    v = calloc(total_n ? total_n : 1, sizeof *v);
    if (!v) {
        s = gs_fail(GS_ENOMEM, "%s: out of memory for %zu lights", path, total_n);
        goto done;
    }
    for (size_t i = 0; i < total_n; i++) {
        json_t *o = json_array_get(arr, i);
        char lp[64];
        snprintf(lp, sizeof lp, "lights[%zu]", i);
        if (!json_is_object(o)) {
            s = gs_json_fail(doc, GS_EFORMAT, lp, "expected an object");
            goto done;
        }
        ev_light *l = &v[n];
        memset(l, 0, sizeof *l);
        l->partner = -1;
        int in_image;
        double group;
        if ((s = gs_json_get_bool(doc, o, lp, "in_image", 1, 0, &in_image)) != GS_OK ||
            (s = truth_number(doc, o, "x_px", i, &l->x)) != GS_OK ||
            (s = truth_number(doc, o, "y_px", i, &l->y)) != GS_OK ||
            (s = truth_number(doc, o, "phase_deg", i, &l->phase_deg)) != GS_OK ||
            (s = truth_number(doc, o, "lat_deg", i, &l->lat)) != GS_OK ||
            (s = truth_number(doc, o, "lon_deg", i, &l->lon)) != GS_OK ||
            (s = truth_text(doc, o, "bulb", i, 1, l->bulb, sizeof l->bulb)) != GS_OK ||
            (s = truth_text(doc, o, "technology", i, 0, l->tech, sizeof l->tech)) != GS_OK ||
            (s = gs_json_get_bool(doc, o, lp, "resolvable", 0, 1, &l->resolvable)) != GS_OK ||
            (s = truth_number(doc, o, "blend_group", i, &group)) != GS_OK)
            goto done;
        if (!isnan(group) && !(group >= 0 && group == floor(group) && group < (double)total_n)) {
            s = gs_json_fail(doc, GS_EFORMAT, lp, "blend_group %g: expected an integer 0 to %zu or "
                             "null", group, total_n - 1);
            goto done;
        }
        l->group = isnan(group) ? -1 : (long)group;
        if (!in_image) continue;
        if (!isfinite(l->x) || !isfinite(l->y)) {
            s = gs_json_fail(doc, GS_EFORMAT, lp, "in_image but x_px/y_px not numbers");
            goto done;
        }
        if (isnan(l->lat) != isnan(l->lon)) {
            s = gs_json_fail(doc, GS_EFORMAT, lp, "lat_deg without lon_deg or the reverse");
            goto done;
        }
        n++;
    }
    *total = (long)total_n;
done:
    gs_json_free(doc);
    if (s != GS_OK) {
        free(v);
        return s;
    }
    *out = v;
    *count = n;
    return GS_OK;
}

/* ------------------------------------------------------------------ the capture */

/* Which capture the truth describes (see srv_eval_opts), and its recorded grid_hz, K, bands,
 * width and height (cap_dims, the order of truth_dims). */
static gs_status find_capture(srv_db *db, const char *truth_path, const srv_eval_opts *o,
                              srv_eval_report *r, long long cap_dims[5])
{
    sqlite3 *h = srv_db_sqlite(db);
    if (o->survey) {
        int64_t sid;
        gs_status s = srv_db_find_survey(db, o->survey, &sid);
        if (s != GS_OK) return s;
    }
    char dir[4096], abs_dir[PATH_MAX];
    gs_path_dir(truth_path, dir, sizeof dir);
    const char *path = realpath(dir, abs_dir) ? abs_dir : dir;
    static const char base[] =
        "SELECT c.id, s.name, c.capture_key, c.grid_hz, c.K, c.bands, c.width_px, c.height_px "
        "FROM captures c JOIN surveys s ON s.id = c.survey_id "
        "WHERE (?1 IS NULL OR s.name = ?1) ";
    const char *const where[3] = {"AND c.capture_key = ?2 ORDER BY c.id", "AND c.path = ?2 ORDER BY c.id",
                                  "ORDER BY c.id"};
    /* by key when one is given; else by the truth's directory, then the only capture */
    int first = o->capture_key ? 0 : 1, last = o->capture_key ? 0 : 2;
    for (int w = first; w <= last; w++) {
        char sql[512];
        snprintf(sql, sizeof sql, "%s%s", base, where[w]);
        sqlite3_stmt *q = NULL;
        if (sqlite3_prepare_v2(h, sql, -1, &q, NULL) != SQLITE_OK)
            return gs_fail(GS_ESQL, "%s: %s", srv_db_path(db), sqlite3_errmsg(h));
        if (o->survey) sqlite3_bind_text(q, 1, o->survey, -1, SQLITE_STATIC);
        if (w == 0) sqlite3_bind_text(q, 2, o->capture_key, -1, SQLITE_STATIC);
        if (w == 1) sqlite3_bind_text(q, 2, path, -1, SQLITE_STATIC);
        int found = 0, rc;
        char list[1024] = "";
        while ((rc = sqlite3_step(q)) == SQLITE_ROW) {
            if (!found) {
                r->capture_id = sqlite3_column_int64(q, 0);
                snprintf(r->survey, sizeof r->survey, "%s", (const char *)sqlite3_column_text(q, 1));
                snprintf(r->capture_key, sizeof r->capture_key, "%s", (const char *)sqlite3_column_text(q, 2));
                for (int d = 0; d < 5; d++) cap_dims[d] = sqlite3_column_int64(q, 3 + d);
            }
            size_t used = strlen(list);
            if (found < 4)
                snprintf(list + used, sizeof list - used, "%s%s/%.15s", found ? ", " : "",
                         (const char *)sqlite3_column_text(q, 1), (const char *)sqlite3_column_text(q, 2));
            found++;
        }
        sqlite3_finalize(q);
        if (rc != SQLITE_DONE) return gs_fail(GS_ESQL, "%s: %s", srv_db_path(db), sqlite3_errmsg(h));
        if (found == 1) return GS_OK;
        if (found > 1)
            return gs_fail(GS_EINVAL, "%s: %d captures could be the one %s describes (%s%s): give "
                           "--survey", srv_db_path(db), found, truth_path, list, found > 4 ? ", ..." : "");
    }
    if (o->capture_key)
        return gs_fail(GS_ENOTFOUND, "%s: no capture with key %s%s%s", srv_db_path(db), o->capture_key,
                       o->survey ? " in survey " : "", o->survey ? o->survey : "");
    return gs_fail(GS_ENOTFOUND, "%s: no capture%s%s to evaluate", srv_db_path(db),
                   o->survey ? " in survey " : "", o->survey ? o->survey : "");
}

/* The truth's dimensions against those the capture records: a truth file of another capture is
 * refused. */
static gs_status check_dims(const char *truth_path, const srv_eval_report *r, const long long dims[5],
                            const long long cap_dims[5])
{
    for (int d = 0; d < 5; d++)
        if (dims[d] >= 0 && cap_dims[d] > 0 && dims[d] != cap_dims[d])   /* (0: not recorded, as bench accuracy's subsets) */
            return gs_fail(GS_EINVAL, "%s: %s %lld: expected %lld, the capture's (survey %s, key "
                           "%.19s...): a truth file of another capture?", truth_path, truth_dims[d],
                           dims[d], cap_dims[d], r->survey, r->capture_key);
    return GS_OK;
}

static gs_status read_stored(srv_db *db, int64_t capture_id, ev_light **out, size_t *count)
{
    static const char sql[] =
        "SELECT l.x_px, l.y_px, l.bulb_id, l.technology, l.phase_deg, l.match_flags, loc.lat_deg, "
        "loc.lon_deg, loc.semi_major_m, loc.semi_minor_m, loc.azimuth_deg, l.blob_flags FROM lights l "
        "LEFT JOIN locations loc ON loc.light_id = l.id "
        "WHERE l.capture_id = ?1 ORDER BY l.light_index";
    sqlite3 *h = srv_db_sqlite(db);
    sqlite3_stmt *q = NULL;
    *out = NULL;
    *count = 0;
    if (sqlite3_prepare_v2(h, sql, -1, &q, NULL) != SQLITE_OK)
        return gs_fail(GS_ESQL, "%s: %s", srv_db_path(db), sqlite3_errmsg(h));
    sqlite3_bind_int64(q, 1, capture_id);
    ev_light *v = NULL;
    size_t n = 0, cap = 0;
    gs_status s = GS_OK;
    int rc;
    while ((rc = sqlite3_step(q)) == SQLITE_ROW) {
        if (n == cap) {
            size_t nc = cap ? 2 * cap : 256;
            ev_light *nv = realloc(v, nc * sizeof *nv);
            if (!nv) {
                s = gs_fail(GS_ENOMEM, "evaluate: out of memory for %zu lights", nc);
                break;
            }
            v = nv;
            cap = nc;
        }
        ev_light *l = &v[n++];
        memset(l, 0, sizeof *l);
        l->partner = -1;
        l->x = sqlite3_column_double(q, 0);
        l->y = sqlite3_column_double(q, 1);
        const char *b = (const char *)sqlite3_column_text(q, 2);
        snprintf(l->bulb, sizeof l->bulb, "%s", b ? b : "");
        const char *t = (const char *)sqlite3_column_text(q, 3);
        snprintf(l->tech, sizeof l->tech, "%s", t ? t : "");
        l->phase_deg = srv_dbi_col_real(q, 4);
        l->flags = (unsigned)sqlite3_column_int64(q, 5);
        l->lat = srv_dbi_col_real(q, 6);
        l->lon = srv_dbi_col_real(q, 7);
        double *e[3] = {&l->a_m, &l->b_m, &l->az_deg};
        for (int k = 0; k < 3; k++)
            *e[k] = srv_dbi_col_real(q, 8 + k);
        l->blob_flags = (unsigned)sqlite3_column_int64(q, 11);
    }
    if (s == GS_OK && rc != SQLITE_DONE) s = gs_fail(GS_ESQL, "%s: %s", srv_db_path(db), sqlite3_errmsg(h));
    sqlite3_finalize(q);
    if (s != GS_OK) {
        free(v);
        return s;
    }
    *out = v;
    *count = n;
    return GS_OK;
}

/* ------------------------------------------------------------------ matching */

typedef struct {
    double d;
    size_t a, b;   /* stored, truth */
} ev_pair;

static int cmp_pair(const void *p, const void *q)
{
    const ev_pair *x = p, *y = q;
    if (x->d != y->d) return x->d < y->d ? -1 : 1;
    if (x->a != y->a) return x->a < y->a ? -1 : 1;
    return (x->b > y->b) - (x->b < y->b);
}

typedef struct {
    double x;
    size_t j;
} ev_key;

static int cmp_key(const void *p, const void *q)
{
    const ev_key *a = p, *b = q;
    if (a->x != b->x) return a->x < b->x ? -1 : 1;
    return (a->j > b->j) - (a->j < b->j);
}

static gs_status add_pair(ev_pair **pairs, size_t *np, size_t *cap, ev_pair p)
{
    if (*np == *cap) {
        size_t nc = *cap ? 2 * *cap : 1024;
        ev_pair *n2 = realloc(*pairs, nc * sizeof *n2);
        if (!n2) return gs_fail(GS_ENOMEM, "evaluate: out of memory for %zu pairs", nc);
        *pairs = n2;
        *cap = nc;
    }
    (*pairs)[(*np)++] = p;
    return GS_OK;
}

/* One-to-one: all pairs within R (truth sorted by x, a window of +-R per stored light), in
 * increasing distance, each light taken once. */
static gs_status match(ev_light *st, size_t ns, ev_light *tr, size_t nt, double R, long *matched)
{
    *matched = 0;
    ev_key *order = malloc((nt ? nt : 1) * sizeof *order);
    ev_pair *pairs = NULL;
    size_t np = 0, cap = 0;
    if (!order) return gs_fail(GS_ENOMEM, "evaluate: out of memory");
    for (size_t j = 0; j < nt; j++) order[j] = (ev_key){tr[j].x, j};
    qsort(order, nt, sizeof *order, cmp_key);
    gs_status s = GS_OK;
    for (size_t i = 0; i < ns && s == GS_OK; i++) {
        size_t lo = 0, hi = nt;   /* the first truth light with x >= st.x - R */
        while (lo < hi) {
            size_t mid = lo + (hi - lo) / 2;
            if (order[mid].x < st[i].x - R) lo = mid + 1;
            else hi = mid;
        }
        for (size_t k = lo; k < nt && order[k].x <= st[i].x + R && s == GS_OK; k++) {
            size_t j = order[k].j;
            double d = hypot(st[i].x - tr[j].x, st[i].y - tr[j].y);
            if (d <= R) s = add_pair(&pairs, &np, &cap, (ev_pair){d, i, j});
        }
    }
    if (s == GS_OK) {
        if (np) qsort(pairs, np, sizeof *pairs, cmp_pair);
        for (size_t p = 0; p < np; p++) {
            ev_light *a = &st[pairs[p].a], *b = &tr[pairs[p].b];
            if (a->partner >= 0 || b->partner >= 0) continue;
            a->partner = (int)pairs[p].b;
            b->partner = (int)pairs[p].a;
            (*matched)++;
        }
    }
    free(order);
    free(pairs);
    return s;
}

/* Linear interpolation between order statistics at position (n - 1) q of sorted v. */
static double quantile(const double *v, size_t n, double q)
{
    if (n == 0) return NAN;
    double pos = (double)(n - 1) * q;
    size_t i = (size_t)floor(pos);
    if (i + 1 >= n) return v[n - 1];
    return v[i] + (pos - (double)i) * (v[i + 1] - v[i]);
}

static double rate(long k, long n)
{
    return n > 0 ? (double)k / (double)n : NAN;
}

static double phase_diff_deg(double a, double b)
{
    double d = fmod(fabs(a - b), 360.0);
    return d > 180.0 ? 360.0 - d : d;
}

/* Resolvable and hidden lights found, and the outcome of each blend group (survey.h). */
static gs_status score_groups(const ev_light *st, const ev_light *tr, size_t nt, srv_eval_report *r)
{
    long ng = 0;
    for (size_t j = 0; j < nt; j++) {
        const ev_light *t = &tr[j];
        if (t->resolvable) {
            r->resolvable++;
            r->resolvable_matched += t->partner >= 0;
        } else if (t->group < 0) {
            r->hidden++;
            r->hidden_matched += t->partner >= 0;
        }
        if (t->group >= ng) ng = t->group + 1;
    }
    if (ng == 0) return GS_OK;
    /* per group: members, members matched, matched lights flagged blend, confident, members
     * whose signal differs from the first one's, confident answers other than that signal, and
     * the first member + 1 */
    enum { NG = 7 };
    long *c = calloc((size_t)ng * NG, sizeof *c);
    if (!c) return gs_fail(GS_ENOMEM, "evaluate: out of memory for %ld blend groups", ng);
    for (size_t j = 0; j < nt; j++) {
        const ev_light *t = &tr[j];
        if (t->group < 0) continue;
        long *g = c + NG * t->group;
        if (!g[6]) g[6] = (long)j + 1;
        const ev_light *t0 = &tr[g[6] - 1];
        g[0]++;
        g[4] += strcmp(t->bulb, t0->bulb) != 0 || !(phase_diff_deg(t->phase_deg, t0->phase_deg) <= GS_PHASE_TOL_DEG);
        if (t->partner < 0) continue;
        const ev_light *a = &st[t->partner];
        g[1]++;
        g[2] += (a->flags & REC_MATCH_BLEND) != 0;
        int confident = a->bulb[0] && !(a->flags & (REC_MATCH_BLEND | REC_MATCH_BULB_AMBIGUOUS));
        g[3] += confident;
        g[5] += confident && (strcmp(a->bulb, t0->bulb) != 0 ||
                              !(phase_diff_deg(a->phase_deg, t0->phase_deg) <= GS_PHASE_TOL_DEG));
    }
    for (long k = 0; k < ng; k++) {
        const long *g = c + NG * k;
        if (g[0] < 2) continue; /* ids the truth skipped */
        r->groups++;
        r->group_lights += g[0];
        if (g[1] == g[0]) r->groups_resolved++;
        else if (g[2] > 0) r->groups_flagged++;
        else if (g[3] > 0) {
            r->groups_confident++;
            r->groups_one_signal += g[4] == 0 && g[5] == 0;
        } else if (g[1] > 0) r->groups_unsure++;
        else r->groups_missed++;
    }
    free(c);
    return GS_OK;
}

/* Class 0..3 of a phase (0, 120, 240, other), 4 for NaN. */
static int phase_col(double phase_deg)
{
    int c = gs_phase_class(phase_deg);
    return c < 0 ? 4 : c;
}

gs_status srv_evaluate(srv_db *db, const char *truth_path, const srv_eval_opts *o,
                       srv_eval_report *r)
{
    if (!db || !truth_path || !r) return gs_fail(GS_EINVAL, "srv_evaluate: NULL argument");
    srv_eval_opts def;
    if (!o) {
        srv_eval_opts_default(&def);
        o = &def;
    }
    memset(r, 0, sizeof *r);
    r->match_px = o->match_px;
    r->loc_median_m = r->loc_p95_m = r->loc_max_m = NAN;
    if (!(o->match_px > 0.0 && o->match_px <= SRV_MATCH_PX_MAX))
        return gs_fail(GS_EINVAL, "--match-px %g: expected a radius > 0 and <= %g pixels", o->match_px,
                       SRV_MATCH_PX_MAX);
    ev_light *tr = NULL, *st = NULL;
    size_t nt = 0, ns = 0;
    double *err = NULL;
    long long dims[5];
    gs_status s = read_truth(truth_path, &tr, &nt, &r->truth_lights, dims);
    long long cap_dims[5];
    if (s == GS_OK) s = find_capture(db, truth_path, o, r, cap_dims);
    if (s == GS_OK) s = check_dims(truth_path, r, dims, cap_dims);
    if (s == GS_OK) s = read_stored(db, r->capture_id, &st, &ns);
    if (s == GS_OK) s = match(st, ns, tr, nt, o->match_px, &r->matched);
    if (s == GS_OK && !(err = malloc((ns ? ns : 1) * sizeof *err)))
        s = gs_fail(GS_ENOMEM, "evaluate: out of memory");
    if (s != GS_OK) goto done;
    r->truth_in_image = (long)nt;
    r->stored = (long)ns;
    r->false_detections = r->stored - r->matched;
    for (size_t i = 0; i < ns; i++) {
        const ev_light *a = &st[i];
        if (a->partner < 0) continue;
        const ev_light *t = &tr[a->partner];
        int bulb_ok = 0, phase_ok = 0;
        if (a->bulb[0]) {
            r->bulb_answered++;
            bulb_ok = !strcmp(a->bulb, t->bulb);
            r->bulb_correct += bulb_ok;
            r->bulb_ambiguous += (a->flags & REC_MATCH_BULB_AMBIGUOUS) != 0;
        }
        if (a->tech[0]) {
            r->tech_answered++;
            r->tech_correct += !strcmp(a->tech, t->tech);
        }
        if (isfinite(a->phase_deg)) {
            r->phase_answered++;
            phase_ok = isfinite(t->phase_deg) && phase_diff_deg(a->phase_deg, t->phase_deg) <= GS_PHASE_TOL_DEG;
            r->phase_correct += phase_ok;
        }
        r->all_correct += bulb_ok && phase_ok;
        int tc = phase_col(t->phase_deg);
        if (tc < 4) r->confusion[tc][phase_col(a->phase_deg)]++;
        if (isfinite(a->lat) && isfinite(t->lat)) {
            double d, azi;
            if ((s = gis_geodesic_inverse(a->lat, a->lon, t->lat, t->lon, &d, &azi, NULL)) != GS_OK) goto done;
            err[r->loc_pairs++] = d;
            /* the truth inside the stored 95 % ellipse: d2 = x^T C^-1 x <= -2 ln 0.05 */
            if (a->a_m > 0.0 && isfinite(a->a_m) && a->b_m > 0.0 && isfinite(a->b_m)) {
                double d2 = srv_ellipse_maha2(a->a_m, a->b_m, isfinite(a->az_deg) ? a->az_deg : 0.0,
                                              d * sin(azi * M_PI / 180.0), d * cos(azi * M_PI / 180.0));
                r->ellipse_pairs++;
                r->ellipse_in95 += d2 <= SRV_CHI2_2DOF_95;
                int ec = t->group >= 0                     ? SRV_ELLIPSE_BLEND_GROUP
                         : !a->blob_flags                  ? SRV_ELLIPSE_PLAIN
                         : a->blob_flags & REC_BLOB_PSF_FIT ? SRV_ELLIPSE_PSF_FIT
                                                            : -1;
                if (ec >= 0) {
                    r->ellipse_class_pairs[ec]++;
                    r->ellipse_class_in95[ec] += d2 <= SRV_CHI2_2DOF_95;
                }
            }
        } else if (!isfinite(a->lat)) {
            r->loc_unlocated++;
        }
    }
    if (r->loc_pairs > 0) {
        qsort(err, (size_t)r->loc_pairs, sizeof *err, gs_cmp_double);
        r->loc_median_m = quantile(err, (size_t)r->loc_pairs, 0.5);
        r->loc_p95_m = quantile(err, (size_t)r->loc_pairs, 0.95);
        r->loc_max_m = err[r->loc_pairs - 1];
    }
    r->ellipse_coverage95 = rate(r->ellipse_in95, r->ellipse_pairs);
    if ((s = score_groups(st, tr, nt, r)) != GS_OK) goto done;
    r->detection_rate = rate(r->matched, r->truth_in_image);
    r->resolvable_rate = rate(r->resolvable_matched, r->resolvable);
    r->false_rate = rate(r->false_detections, r->stored);
    r->bulb_accuracy = rate(r->bulb_correct, r->bulb_answered);
    r->tech_accuracy = rate(r->tech_correct, r->tech_answered);
    r->phase_accuracy = rate(r->phase_correct, r->phase_answered);
    r->bulb_unknown_rate = rate(r->matched - r->bulb_answered, r->matched);
    r->phase_unknown_rate = rate(r->matched - r->phase_answered, r->matched);
    r->all_correct_rate = rate(r->all_correct, r->truth_in_image);
done:
    free(err);
    free(st);
    free(tr);
    return s;
}

/* ------------------------------------------------------------------ printing */

/* 100 v with one decimal, or as many more (up to 4) as keep a share that is not all from
 * reading 100.0 and one that is not none from reading 0.0 */
static const char *pct_text(double v, char *buf, size_t size)
{
    for (int d = 1; d <= 4; d++) {
        snprintf(buf, size, "%.*f", d, 100.0 * v);
        double shown = atof(buf);
        if (!((v < 1.0 && shown >= 100.0) || (v > 0.0 && shown <= 0.0))) break;
    }
    return buf;
}

static void pct_row(FILE *f, const char *metric, double v, long k, long n, const char *of)
{
    char b[32];
    if (isnan(v)) fprintf(f, "| %s | - | %ld / %ld %s |\n", metric, k, n, of);
    else fprintf(f, "| %s | %s %% | %ld / %ld %s |\n", metric, pct_text(v, b, sizeof b), k, n, of);
}

static json_t *jnum(double v)
{
    return isfinite(v) ? json_real(v) : json_null();
}

static json_t *jrate(double v, long k, long n)
{
    json_t *o = json_object();
    json_object_set_new(o, "rate", jnum(v));
    json_object_set_new(o, "count", json_integer(k));
    json_object_set_new(o, "of", json_integer(n));
    return o;
}

static const char *const class_names[SRV_EVAL_PHASE_CLASSES] = {"0", "120", "240", "other", "none"};
/* the ellipse classes (SRV_ELLIPSE_*): JSON keys and table rows */
static const char *const ellipse_keys[SRV_ELLIPSE_CLASSES] = {"plain", "psf_fit", "blend_group"};
static const char *const ellipse_rows[SRV_ELLIPSE_CLASSES] = {
    "plain lights (no blob flag)", "PSF-fit lights outside blend groups", "lights in blend groups"};

gs_status srv_eval_print(const srv_eval_report *r, const char *truth_path, int json, FILE *f)
{
    if (json) {
        json_t *root = json_object();
        json_object_set_new(root, "format", json_string(EVAL_FORMAT));
        json_object_set_new(root, "truth", json_string(truth_path));
        json_object_set_new(root, "survey", json_string(r->survey));
        json_object_set_new(root, "capture_key", json_string(r->capture_key));
        json_object_set_new(root, "match_px", jnum(r->match_px));
        json_object_set_new(root, "truth_lights", json_integer(r->truth_lights));
        json_object_set_new(root, "truth_in_image", json_integer(r->truth_in_image));
        json_object_set_new(root, "stored", json_integer(r->stored));
        json_object_set_new(root, "matched", json_integer(r->matched));
        json_object_set_new(root, "detection", jrate(r->detection_rate, r->matched, r->truth_in_image));
        json_object_set_new(root, "false_detections", jrate(r->false_rate, r->false_detections, r->stored));
        json_object_set_new(root, "resolvable_detection",
                            jrate(r->resolvable_rate, r->resolvable_matched, r->resolvable));
        json_object_set_new(root, "hidden_detection",
                            jrate(rate(r->hidden_matched, r->hidden), r->hidden_matched, r->hidden));
        json_t *bg = json_object();
        json_object_set_new(bg, "groups", json_integer(r->groups));
        json_object_set_new(bg, "lights", json_integer(r->group_lights));
        json_object_set_new(bg, "resolved", json_integer(r->groups_resolved));
        json_object_set_new(bg, "flagged_blend", json_integer(r->groups_flagged));
        json_object_set_new(bg, "confident_single", json_integer(r->groups_confident));
        json_object_set_new(bg, "confident_single_one_signal", json_integer(r->groups_one_signal));
        json_object_set_new(bg, "unsure", json_integer(r->groups_unsure));
        json_object_set_new(bg, "missed", json_integer(r->groups_missed));
        json_object_set_new(root, "blend_groups", bg);
        json_object_set_new(root, "bulb", jrate(r->bulb_accuracy, r->bulb_correct, r->bulb_answered));
        json_object_set_new(root, "bulb_ambiguous", json_integer(r->bulb_ambiguous));
        json_object_set_new(root, "technology", jrate(r->tech_accuracy, r->tech_correct, r->tech_answered));
        json_object_set_new(root, "phase", jrate(r->phase_accuracy, r->phase_correct, r->phase_answered));
        json_object_set_new(root, "bulb_unknown",
                            jrate(r->bulb_unknown_rate, r->matched - r->bulb_answered, r->matched));
        json_object_set_new(root, "phase_unknown",
                            jrate(r->phase_unknown_rate, r->matched - r->phase_answered, r->matched));
        json_object_set_new(root, "bulb_and_phase", jrate(r->all_correct_rate, r->all_correct, r->truth_in_image));
        json_t *conf = json_object();
        for (int t = 0; t < 4; t++) {
            json_t *row = json_object();
            for (int c = 0; c < SRV_EVAL_PHASE_CLASSES; c++)
                json_object_set_new(row, class_names[c], json_integer(r->confusion[t][c]));
            json_object_set_new(conf, class_names[t], row);
        }
        json_object_set_new(root, "phase_confusion", conf);
        json_t *loc = json_object();
        json_object_set_new(loc, "pairs", json_integer(r->loc_pairs));
        json_object_set_new(loc, "unlocated", json_integer(r->loc_unlocated));
        json_object_set_new(loc, "median_m", jnum(r->loc_median_m));
        json_object_set_new(loc, "p95_m", jnum(r->loc_p95_m));
        json_object_set_new(loc, "max_m", jnum(r->loc_max_m));
        json_object_set_new(loc, "ellipse_pairs", json_integer(r->ellipse_pairs));
        json_object_set_new(loc, "ellipse95_coverage", jnum(r->ellipse_coverage95));
        json_t *byc = json_object();
        for (int c = 0; c < SRV_ELLIPSE_CLASSES; c++)
            json_object_set_new(byc, ellipse_keys[c],
                                jrate(rate(r->ellipse_class_in95[c], r->ellipse_class_pairs[c]),
                                      r->ellipse_class_in95[c], r->ellipse_class_pairs[c]));
        json_object_set_new(loc, "ellipse95_by_class", byc);
        json_object_set_new(root, "location_error", loc);
        int rc = json_dumpf(root, f, JSON_INDENT(2) | JSON_PRESERVE_ORDER | JSON_REAL_PRECISION(10));
        json_decref(root);
        if (rc != 0 || fputc('\n', f) == EOF) return gs_fail(GS_EIO, "cannot write the evaluation");
        return GS_OK;
    }
    fprintf(f, "Evaluation against %s: survey %s, capture %.19s%s, stored lights matched to the "
               "truth's lights in the image within %g px (one-to-one, nearest first)\n\n",
            truth_path, r->survey, r->capture_key, strlen(r->capture_key) > 19 ? "..." : "", r->match_px);
    fprintf(f, "| metric | value | counts |\n|---|---:|---|\n");
    pct_row(f, "detection rate", r->detection_rate, r->matched, r->truth_in_image, "truth lights in the image");
    pct_row(f, "false detections", r->false_rate, r->false_detections, r->stored, "stored lights");
    pct_row(f, "detection of resolvable lights", r->resolvable_rate, r->resolvable_matched, r->resolvable,
            "resolvable truth lights");
    pct_row(f, "detection of hidden lights", rate(r->hidden_matched, r->hidden), r->hidden_matched, r->hidden,
            "lights next to a 10x brighter one");
    pct_row(f, "bulb accuracy", r->bulb_accuracy, r->bulb_correct, r->bulb_answered, "matched lights with a bulb");
    pct_row(f, "technology accuracy", r->tech_accuracy, r->tech_correct, r->tech_answered,
            "matched lights with a technology");
    pct_row(f, "phase accuracy", r->phase_accuracy, r->phase_correct, r->phase_answered,
            "matched lights with a phase");
    pct_row(f, "bulb unknown", r->bulb_unknown_rate, r->matched - r->bulb_answered, r->matched, "matched lights");
    pct_row(f, "phase ambiguous or unknown", r->phase_unknown_rate, r->matched - r->phase_answered,
            r->matched, "matched lights");
    pct_row(f, "bulb and phase right", r->all_correct_rate, r->all_correct, r->truth_in_image,
            "truth lights in the image");
    if (r->loc_pairs > 0) {
        fprintf(f, "| location error, median | %.2f m | %ld located matched lights (%ld not located) |\n",
                r->loc_median_m, r->loc_pairs, r->loc_unlocated);
        fprintf(f, "| location error, 95th percentile | %.2f m | max %.2f m |\n", r->loc_p95_m, r->loc_max_m);
        char b[32];
        if (r->ellipse_pairs > 0)
            fprintf(f, "| 95 %% ellipse coverage | %s %% | %ld of %ld truth lights inside their stored "
                    "95 %% error ellipse (calibrated: 95 %%) |\n", pct_text(r->ellipse_coverage95, b, sizeof b),
                    r->ellipse_in95, r->ellipse_pairs);
        for (int c = 0; c < SRV_ELLIPSE_CLASSES; c++)
            if (r->ellipse_class_pairs[c] > 0)
                fprintf(f, "| 95 %% ellipse coverage, %s | %s %% | %ld of %ld |\n", ellipse_rows[c],
                        pct_text(rate(r->ellipse_class_in95[c], r->ellipse_class_pairs[c]), b, sizeof b),
                        r->ellipse_class_in95[c], r->ellipse_class_pairs[c]);
    } else {
        fprintf(f, "| location error | - | no located matched light with a true position (%ld not located) |\n",
                r->loc_unlocated);
    }
    if (r->groups > 0)
        fprintf(f, "\nUnresolvable groups (lights closer than 2 PSF sigma, fluxes within 10x; truth.json "
                   "resolvability): %ld groups of %ld lights: %ld resolved (every light matched), %ld "
                   "flagged blend, %ld a confident single bulb (%ld of them one bulb and phase, answered "
                   "right: their sum is one template), %ld unsure (bulb unknown or ambiguous), %ld missed.\n",
                r->groups, r->group_lights, r->groups_resolved, r->groups_flagged, r->groups_confident,
                r->groups_one_signal, r->groups_unsure, r->groups_missed);
    fprintf(f, "\nbulb accuracy counts %ld bulbs flagged ambiguous (posterior < the ambiguity threshold) "
               "as answers. Phase of matched lights, truth (rows) against stored (columns; none = "
               "ambiguous or unknown):\n\n", r->bulb_ambiguous);
    fprintf(f, "| truth \\ stored | 0 | 120 | 240 | other | none |\n|---|---:|---:|---:|---:|---:|\n");
    for (int t = 0; t < 4; t++) {
        fprintf(f, "| %s |", class_names[t]);
        for (int c = 0; c < SRV_EVAL_PHASE_CLASSES; c++) fprintf(f, " %ld |", r->confusion[t][c]);
        fputc('\n', f);
    }
    if (ferror(f)) return gs_fail(GS_EIO, "cannot write the evaluation");
    return GS_OK;
}
