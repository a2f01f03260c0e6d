/* effect_transport.c - the light-transport effects (paper Sec. 5; docs/scene.md,
 * docs/light-transport.md):
 *  - light_transport: a room of Lambertian walls (a checker texture) and boxes around the
 *    camera, lit by the scene's lights (each placed at its distance along its pixel's ray) with
 *    inverse-square fall-off, cosine law and box shadows, and optionally by daylight (BRF = 1,
 *    uniform on the surfaces). Ray-cast once (prepare): each light's transport image relative
 *    to its direct flux; rendering adds tau * E for each light through its own flicker.
 *  - semi_reflection: the view through a window: everything indoors times the glass's
 *    reflectance, plus a daylit outdoor scene (a generated skyline, BRF = 1).
 * The truth is every source's tau Q (cap_transport_write_truth). */
#include "capture/sim.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

struct cap_transport {
    float *tau;     /* [l][p][b] pixel fraction of light l's direct flux (light_transport) */
    float *day;     /* [p][b] daylight electrons per nominal cycle (light_transport daylight) */
    float *out;     /* [p][b] outdoor electrons per nominal cycle (semi_reflection) */
};

static struct cap_transport *tr_of(cap_sim *s)
{
    if (!s->tr) s->tr = calloc(1, sizeof *s->tr);
    return s->tr;
}

void cap_transport_free(cap_sim *s)
{
    if (!s->tr) return;
    free(s->tr->tau);
    free(s->tr->day);
    free(s->tr->out);
    free(s->tr);
    s->tr = NULL;
}

/* ------------------------------------------------------------------ geometry */

/* The ray o + t d (t in (t0, t1)) against box bx: the entry t and the entry face's axis and
 * sign (the face normal is -sign(d[axis])); 0 if it misses. */
static int hit_box(const cap_box *bx, const double *o, const double *d, double t0, double t1,
                   double *t_hit, int *axis)
{
    double tn = t0, tf = t1;
    int ax = -1;
    for (int a = 0; a < 3; a++) {
        if (fabs(d[a]) < 1e-300) {
            if (o[a] < bx->min_m[a] || o[a] > bx->max_m[a]) return 0;
            continue;
        }
        double ta = (bx->min_m[a] - o[a]) / d[a], tb = (bx->max_m[a] - o[a]) / d[a];
        if (ta > tb) {
            double x = ta;
            ta = tb;
            tb = x;
        }
        if (ta > tn) {
            tn = ta;
            ax = a;
        }
        if (tb < tf) tf = tb;
        if (tn > tf) return 0;
    }
    if (ax < 0) return 0;   /* the origin is inside the box */
    *t_hit = tn;
    *axis = ax;
    return 1;
}

/* The surface a camera ray meets: point X, inward normal n, albedo per band. 0 if none. */
static int cast(const cap_effects *fx, const double *d, double *X, double *n, double *alb)
{
    const double w2 = 0.5 * fx->transport.width_m, fl = fx->transport.floor_m;
    const double ce = fl - fx->transport.height_m, dp = fx->transport.depth_m;
    double t = INFINITY;
    int wall = -1;
    /* the walls: x = -w/2, +w/2, floor y = floor_m (y down), ceiling, back z = depth */
    double cand[5] = {d[0] < 0 ? -w2 / d[0] : INFINITY, d[0] > 0 ? w2 / d[0] : INFINITY,
                      d[1] > 0 ? fl / d[1] : INFINITY, d[1] < 0 ? ce / d[1] : INFINITY,
                      d[2] > 0 ? dp / d[2] : INFINITY};
    for (int i = 0; i < 5; i++)
        if (cand[i] > 0 && cand[i] < t) {
            t = cand[i];
            wall = i;
        }
    if (wall < 0) return 0;
    static const double wn[5][3] = {{1, 0, 0}, {-1, 0, 0}, {0, -1, 0}, {0, 1, 0}, {0, 0, -1}};
    const double o[3] = {0, 0, 0};
    double tb;
    int axis, box = -1;
    for (size_t i = 0; i < fx->transport.n_boxes; i++)
        if (hit_box(&fx->transport.boxes[i], o, d, 0, t, &tb, &axis)) {
            t = tb;
            box = (int)i;
            for (int a = 0; a < 3; a++) n[a] = a == axis ? (d[a] > 0 ? -1.0 : 1.0) : 0.0;
        }
    for (int a = 0; a < 3; a++) X[a] = t * d[a];
    const double *base;
    if (box < 0) {
        for (int a = 0; a < 3; a++) n[a] = wn[wall][a];
        base = fx->transport.albedo;
    } else {
        base = fx->transport.boxes[box].albedo;
    }
    /* checker on the surface's two in-plane coordinates */
    double f = 1.0;
    if (fx->transport.checker_m > 0) {
        int ax = n[0] != 0 ? 0 : n[1] != 0 ? 1 : 2;
        int u = ax == 0 ? 1 : 0, v = ax == 2 ? 1 : 2;
        long cu = (long)floor(X[u] / fx->transport.checker_m);
        long cv = (long)floor(X[v] / fx->transport.checker_m);
        f = ((cu + cv) & 1) ? 1.0 + 0.5 * fx->transport.contrast : 1.0 - 0.5 * fx->transport.contrast;
    }
    for (int b = 0; b < 3; b++) {
        alb[b] = base[b] * f;
        if (alb[b] > 1) alb[b] = 1;
    }
    return 1;
}

/* 1 when a box blocks the segment from X to L. */
static int shadowed(const cap_effects *fx, const double *X, const double *L)
{
    double d[3] = {L[0] - X[0], L[1] - X[1], L[2] - X[2]};
    double t, o[3] = {X[0] + 1e-7 * d[0], X[1] + 1e-7 * d[1], X[2] + 1e-7 * d[2]};
    int axis;
    for (size_t i = 0; i < fx->transport.n_boxes; i++)
        if (hit_box(&fx->transport.boxes[i], o, d, 0, 1, &t, &axis)) return 1;
    return 0;
}

/* The camera ray of pixel (x, y) (pinhole; distortion not modelled), with z = 1. */
static void ray(const cap_sim *s, double x, double y, double *d)
{
    d[0] = (x - s->sc.cam.cx_px) / s->sc.cam.focal_px;
    d[1] = (y - s->sc.cam.cy_px) / s->sc.cam.focal_px;
    d[2] = 1.0;
}

/* ------------------------------------------------------------------ light_transport */

/* A light is a transport source when it has a distance (its 3-D position along its ray). */
static int is_source(const cap_light *li)
{
    return !li->geographic && li->distance_m > 0 && isfinite(li->x_px) && isfinite(li->y_px);
}

/* Lamp shades: the direct image of every source light becomes a uniform disk of radius_px
 * carrying `transmission` of its flux (a diffuser in front of the bulb); the footprints of the
 * other lights are kept. */
static gs_status shade_footprints(cap_sim *s)
{
    double R = s->sc.fx.transport.shade_radius_px, f = s->sc.fx.transport.shade_transmission;
    int r = (int)ceil(R);
    size_t per = (size_t)(2 * r + 2) * (size_t)(2 * r + 2), total = s->fp_n;   /* the disk's box */
    if (!total)
        for (size_t l = 0; l < s->n; l++) total += (size_t)s->fp[l].w * (size_t)s->fp[l].h;
    double *w = malloc(sizeof *w * (total + s->n * per + 1));
    if (!w) return gs_fail(GS_ENOMEM, "light transport: out of memory");
    size_t off = 0;
    for (size_t l = 0; l < s->n; l++) {
        cap_footprint *fp = &s->fp[l];
        const cap_light *li = &s->sc.lights[l];
        if (!is_source(li)) {
            size_t m = (size_t)fp->w * (size_t)fp->h;
            memcpy(w + off, s->fp_w + fp->off, sizeof *w * m);
            fp->off = off;
            off += m;
            continue;
        }
        double cx = li->x_px, cy = li->y_px;
        int x0 = (int)floor(cx) - r, y0 = (int)floor(cy) - r, n = 2 * r + 2;
        int xa = x0 < 0 ? 0 : x0, ya = y0 < 0 ? 0 : y0;
        int xb = x0 + n > s->W ? s->W : x0 + n, yb = y0 + n > s->H ? s->H : y0 + n;
        memset(fp, 0, sizeof *fp);
        if (xb <= xa || yb <= ya) continue;
        /* the disk's area in each pixel from a 4 x 4 grid of sub-samples; the whole disk's
         * (off the image too) carries the transmission: on the samples it is not pi R^2 */
        double sum = 0;
        size_t start = off;
        for (int y = y0; y < y0 + n; y++)
            for (int x = x0; x < x0 + n; x++) {
                int in = 0;
                for (int j = 0; j < 4; j++)
                    for (int i = 0; i < 4; i++) {
                        double dx = x - 0.375 + 0.25 * i - cx, dy = y - 0.375 + 0.25 * j - cy;
                        in += dx * dx + dy * dy <= R * R;
                    }
                sum += in / 16.0;
                if (x >= xa && x < xb && y >= ya && y < yb) w[off++] = in / 16.0;
            }
        for (size_t i = start; i < off; i++) w[i] *= sum > 0 ? f / sum : 0.0;
        *fp = (cap_footprint){xa, ya, xb - xa, yb - ya, start};
    }
    free(s->fp_w);
    s->fp_w = w;
    s->fp_n = off;
    return GS_OK;
}

gs_status cap_fx_prepare_light_transport(cap_sim *s)
{
    struct cap_transport *t = tr_of(s);
    size_t P = (size_t)s->W * (size_t)s->H, B = (size_t)s->B;
    if (!t) return gs_fail(GS_ENOMEM, "light transport: out of memory");
    t->tau = calloc((s->n ? s->n : 1) * P * B, sizeof *t->tau);
    if (s->sc.fx.transport.daylight_e > 0) t->day = calloc(P * B, sizeof *t->day);
    if (!t->tau || (s->sc.fx.transport.daylight_e > 0 && !t->day))
        return gs_fail(GS_ENOMEM, "light transport: cannot hold %zu transport images", s->n);
    const cap_effects *fx = &s->sc.fx;
    double (*Lp)[3] = malloc(sizeof *Lp * (s->n ? s->n : 1));
    if (!Lp) return gs_fail(GS_ENOMEM, "light transport: out of memory");
    for (size_t l = 0; l < s->n; l++) {
        const cap_light *li = &s->sc.lights[l];
        double d[3];
        ray(s, li->x_px, li->y_px, d);
        double nd = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        for (int a = 0; a < 3; a++) Lp[l][a] = d[a] / nd * li->distance_m;
    }
    /* a Lambertian patch of albedo rho under a point source of direct flux F at distance d_l
     * gives the pixel rho / pi * F d_l^2 cos(i) / r^2 * Omega, Omega = 1 / focal^2 sr */
    double omega = 1.0 / (s->sc.cam.focal_px * s->sc.cam.focal_px);
    for (int y = 0; y < s->H; y++)
        for (int x = 0; x < s->W; x++) {
            size_t p = (size_t)y * (size_t)s->W + (size_t)x;
            double d[3], X[3], n[3], alb[3];
            ray(s, x, y, d);
            if (!cast(fx, d, X, n, alb)) continue;
            for (size_t l = 0; l < s->n; l++) {
                if (!is_source(&s->sc.lights[l])) continue;
                double v[3] = {Lp[l][0] - X[0], Lp[l][1] - X[1], Lp[l][2] - X[2]};
                double r2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
                double cosi = (v[0] * n[0] + v[1] * n[1] + v[2] * n[2]) / sqrt(r2);
                if (!(cosi > 0) || shadowed(fx, X, Lp[l])) continue;
                double dl = s->sc.lights[l].distance_m;
                double g = dl * dl * cosi / r2 * omega / M_PI;
                for (size_t b = 0; b < B; b++) t->tau[(l * P + p) * B + b] = (float)(alb[b] * g);
            }
            if (t->day)
                for (size_t b = 0; b < B; b++)
                    t->day[p * B + b] = (float)(fx->transport.daylight_e *
                                                fx->transport.daylight_chroma[b] * alb[b]);
        }
    free(Lp);
    return fx->transport.shade_radius_px > 0 ? shade_footprints(s) : GS_OK;
}

gs_status cap_fx_light_transport(cap_sim *s, cap_render *r)
{
    const struct cap_transport *t = s->tr;
    int B = s->B, L = s->L;
    size_t P = (size_t)s->W * (size_t)s->H;
    unsigned long long items = 0;
    for (size_t l = 0; l < s->n; l++) {
        if (!is_source(&s->sc.lights[l])) continue;
        const float *tau = t->tau + l * P * (size_t)B;
        const double *E = s->E + l * (size_t)L * (size_t)B;
        for (size_t p = 0; p < P; p++) {
            int h = r->halv ? r->halv[p] : 0;
            for (int b = 0; b < B; b++) s->img[p * B + b] += tau[p * B + b] * E[h * B + b];
        }
        items += P;
    }
    if (t->day)
        for (size_t p = 0; p < P; p++) {
            double ex = r->ex[r->halv ? r->halv[p] : 0];
            for (int b = 0; b < B; b++) s->img[p * B + b] += t->day[p * B + b] * ex;
        }
    r->items = items;
    return GS_OK;
}

/* ------------------------------------------------------------------ semi_reflection */

/* A daylit skyline (deterministic in the seed): sky brightening upwards, buildings of random
 * widths, heights and facade reflectance with rows of windows, in [0.05, 1]. */
gs_status cap_fx_prepare_semi_reflection(cap_sim *s)
{
    struct cap_transport *t = tr_of(s);
    size_t P = (size_t)s->W * (size_t)s->H, B = (size_t)s->B;
    if (!t || !(t->out = malloc(sizeof *t->out * P * B)))
        return gs_fail(GS_ENOMEM, "semi_reflection: out of memory");
    uint64_t seed = s->sc.seed ^ 0x6a09e667f3bcc909ull;
    int W = s->W, H = s->H;
    double *top = malloc(sizeof *top * (size_t)W), *fac = malloc(sizeof *fac * (size_t)W);
    int *bw = malloc(sizeof *bw * (size_t)W);
    if (!top || !fac || !bw) {
        free(top);
        free(fac);
        free(bw);
        return gs_fail(GS_ENOMEM, "semi_reflection: out of memory");
    }
    for (int x = 0; x < W;) {
        int w = 8 + (int)(gs_splitmix_uniform(&seed) * W / 6.0);
        double h = 0.15 + 0.7 * gs_splitmix_uniform(&seed), f = 0.15 + 0.6 * gs_splitmix_uniform(&seed);
        for (int i = 0; i < w && x < W; i++, x++) {
            top[x] = (1.0 - h) * H;
            fac[x] = f;
            bw[x] = i;
        }
    }
    const cap_effects *fx = &s->sc.fx;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            double v;
            if (y < top[x]) {
                v = 0.55 + 0.45 * (1.0 - (double)y / H);   /* sky */
            } else {
                int row = (int)(y - top[x]);
                int win = (row % 9) >= 3 && (row % 9) < 7 && (bw[x] % 7) >= 2 && (bw[x] % 7) < 5;
                v = win ? 0.25 * fac[x] : fac[x];
            }
            if (v < 0.05) v = 0.05;
            for (size_t b = 0; b < B; b++)
                t->out[((size_t)y * W + x) * B + b] =
                    (float)(fx->window.e_per_px_cycle * fx->window.chroma[b] * v);
        }
    free(top);
    free(fac);
    free(bw);
    return GS_OK;
}

gs_status cap_fx_semi_reflection(cap_sim *s, cap_render *r)
{
    size_t P = (size_t)s->W * (size_t)s->H;
    int B = s->B;
    double R = s->sc.fx.window.reflectance;
    for (size_t p = 0; p < P; p++) {
        double ex = r->ex[r->halv ? r->halv[p] : 0];
        for (int b = 0; b < B; b++)
            s->img[p * B + b] = s->img[p * B + b] * R + s->tr->out[p * B + b] * ex;
    }
    r->items = P;
    return GS_OK;
}

/* ------------------------------------------------------------------ truth */

static gs_status truth_image(const cap_sim *s, const char *dir, int idx, const float *img,
                             json_t *arr, const char *light, const char *bulb, double phase_deg)
{
    char name[64], path[CAP_PATH_MAX + 64];
    snprintf(name, sizeof name, "truth_tau_%02d.tiff", idx);
    snprintf(path, sizeof path, "%s/%s", dir, name);
    gs_status st = gs_tiff_write_float(path, img, s->W, s->H, s->B, 1);
    if (st != GS_OK) return st;
    json_t *o = json_object();
    json_object_set_new(o, "light", json_string(light));
    json_object_set_new(o, "bulb", json_string(bulb));
    json_object_set_new(o, "phase_deg", json_real(phase_deg));
    json_object_set_new(o, "file", json_string(name));
    json_array_append_new(arr, o);
    return GS_OK;
}

gs_status cap_transport_write_truth(const cap_sim *s, const char *dir, json_t **images)
{
    *images = NULL;
    int lt = (s->fx >> CAP_FX_LIGHT_TRANSPORT) & 1u, win = (s->fx >> CAP_FX_SEMI_REFLECTION) & 1u;
    if (!lt && !win) return GS_OK;
    size_t P = (size_t)s->W * (size_t)s->H, B = (size_t)s->B;
    float *img = malloc(sizeof *img * P * B);
    json_t *arr = json_array();
    if (!img || !arr) {
        free(img);
        json_decref(arr);
        return gs_fail(GS_ENOMEM, "truth: out of memory");
    }
    /* per-cycle DN of the cycle mean: electrons per nominal cycle / (K gain) (Eq. 5: the
     * windows' mean is 1) */
    double R = win ? s->sc.fx.window.reflectance : 1.0;
    double k = R / (s->K * s->sc.gain_e_per_dn);
    gs_status st = gs_dir_ensure(dir);
    int idx = 0;
    for (size_t l = 0; l < s->n && st == GS_OK; l++) {
        const cap_light *li = &s->sc.lights[l];
        memset(img, 0, sizeof *img * P * B);
        const cap_footprint *f = &s->fp[l];
        for (int y = 0; y < f->h; y++)
            for (int x = 0; x < f->w; x++) {
                size_t p = (size_t)(f->y0 + y) * (size_t)s->W + (size_t)(f->x0 + x);
                for (size_t b = 0; b < B; b++) img[p * B + b] += (float)s->fp_w[f->off + (size_t)(y * f->w + x)];
            }
        if (lt && is_source(li))
            for (size_t i = 0; i < P * B; i++) img[i] += s->tr->tau[l * P * B + i];
        for (size_t p = 0; p < P; p++)
            for (size_t b = 0; b < B; b++) {
                double tr = s->trans ? s->trans[l * B + b] : 1.0;
                img[p * B + b] = (float)(img[p * B + b] * s->flux[l * B + b] * tr * k);
            }
        st = truth_image(s, dir, idx++, img, arr, li->id, li->bulb, li->phase_deg);
    }
    if (st == GS_OK && lt && s->tr->day) {
        for (size_t i = 0; i < P * B; i++) img[i] = (float)(s->tr->day[i] * k);
        st = truth_image(s, dir, idx++, img, arr, "daylight", "daylight", 0);
    }
    if (st == GS_OK && win) {
        double kk = 1.0 / (s->K * s->sc.gain_e_per_dn);
        for (size_t i = 0; i < P * B; i++) img[i] = (float)(s->tr->out[i] * kk);
        st = truth_image(s, dir, idx++, img, arr, "outdoor", "daylight", 0);
    }
    free(img);
    if (st != GS_OK) {
        json_decref(arr);
        return st;
    }
    *images = arr;
    return GS_OK;
}
