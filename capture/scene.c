/* scene.c - scene files, format gridsurvey-scene/1 (docs/scene.md), parsed with Jansson.
 * Every error names the file, the line and the field ("FILE:LINE: field PATH: expected ...").
 * Lights come inline (pixel or geographic), from a GeoJSON file of points, or from a compact
 * "street_grid" block generated deterministically; geographic lights are projected with the
 * one shared camera model, gis_project (gis/gis.h). */
#include "capture/internal.h"

#include <jansson.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------------------ parse context */

/* A scene document (or a GeoJSON file it names) and the directory relative paths resolve in. */
typedef struct {
    const gs_json *doc;
    const char *base_dir;
} pctx;

static gs_status bad(const pctx *c, gs_status s, const char *path, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
static gs_status bad(const pctx *c, gs_status s, const char *path, const char *fmt, ...)
{
    char msg[768];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    return gs_json_fail(c->doc, s, path, "%s", msg);
}

static gs_status get_long(const pctx *c, json_t *obj, const char *ppath, const char *key,
                          int required, long def, long lo, long hi, long *out)
{
    long long v;
    gs_status s = gs_json_get_int(c->doc, obj, ppath, key, required, def, lo, hi, NULL, &v);
    if (s == GS_OK) *out = (long)v;
    return s;
}

static gs_status get_int(const pctx *c, json_t *obj, const char *ppath, const char *key,
                         int required, int def, int lo, int hi, int *out)
{
    long v;
    gs_status s = get_long(c, obj, ppath, key, required, def, lo, hi, &v);
    if (s == GS_OK) *out = (int)v;
    return s;
}

static void resolve(const pctx *c, const char *rel, char *out, size_t cap)
{
    if (rel[0] == '/' || !c->base_dir || !c->base_dir[0]) snprintf(out, cap, "%s", rel);
    else snprintf(out, cap, "%s/%s", c->base_dir, rel);
}

/* ------------------------------------------------------------------ geometry */

/* WGS84 geodetic -> Earth-centred Earth-fixed, metres. */
static void ecef(double lat_deg, double lon_deg, double h, double p[3])
{
    const double a = 6378137.0, f = 1.0 / 298.257223563, e2 = f * (2 - f);
    double la = lat_deg * M_PI / 180.0, lo = lon_deg * M_PI / 180.0;
    double N = a / sqrt(1 - e2 * sin(la) * sin(la));
    p[0] = (N + h) * cos(la) * cos(lo);
    p[1] = (N + h) * cos(la) * sin(lo);
    p[2] = (N * (1 - e2) + h) * sin(la);
}

static double chord_m(const gis_camera *cam, double lat, double lon, double h)
{
    double a[3], b[3];
    ecef(cam->lat_deg, cam->lon_deg, cam->height_m, a);
    ecef(lat, lon, h, b);
    return sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) +
                (a[2] - b[2]) * (a[2] - b[2]));
}

double cap_scene_flux_from_lumens(const cap_scene *sc, double lumens, double distance_m)
{
    if (!(distance_m > 0)) return NAN;
    double area = M_PI * 0.25 * (sc->aperture_mm * 1e-3) * (sc->aperture_mm * 1e-3);
    double half_s = 1.0 / (2.0 * sc->grid_hz);
    return lumens * CAP_PHOTONS_PER_LM_S * area / (4.0 * M_PI * distance_m * distance_m) *
           half_s * sc->transmission * sc->qe;
}

/* ------------------------------------------------------------------ lights */

typedef struct {
    cap_light *v;
    size_t n, cap;
} light_vec;

static gs_status push_light(light_vec *lv, const cap_light *l)
{
    if (lv->n == lv->cap) {
        size_t nc = lv->cap ? lv->cap * 2 : 64;
        cap_light *nv = realloc(lv->v, nc * sizeof *nv);
        if (!nv) return gs_fail(GS_ENOMEM, "scene: out of memory for lights");
        lv->v = nv;
        lv->cap = nc;
    }
    lv->v[lv->n++] = *l;
    return GS_OK;
}

/* Place a light: projection (geographic), distance, flux from lumens. path names it. */
static gs_status finish_light(const pctx *c, const cap_scene *sc, cap_light *l, const char *path,
                              int lumens_given)
{
    char p[560];
    if (l->geographic) {
        if (!sc->has_station) {
            snprintf(p, sizeof p, "%s.lat_deg", path);
            return bad(c, GS_EFORMAT, p, "a geographic light needs camera.station");
        }
        int in_front = 0;
        gs_status s = gis_project(&sc->cam, l->lat_deg, l->lon_deg, l->height_m, &l->x_px,
                                  &l->y_px, &in_front);
        if (s != GS_OK) return bad(c, GS_EFORMAT, path, "cannot project: %s", gs_detail());
        l->in_image = in_front && gis_in_image(&sc->cam, l->x_px, l->y_px);
        l->distance_m = chord_m(&sc->cam, l->lat_deg, l->lon_deg, l->height_m);
    } else {
        l->in_image = l->x_px >= -0.5 && l->x_px < sc->cam.width_px - 0.5 && l->y_px >= -0.5 &&
                      l->y_px < sc->cam.height_px - 0.5;
    }
    if (lumens_given) {
        if (!(l->distance_m > 0)) {
            snprintf(p, sizeof p, "%s.lumens", path);
            return bad(c, GS_EFORMAT, p, "a light given in lumens needs its distance (distance_m, "
                       "or a geographic position)");
        }
        l->flux_e_per_cycle = cap_scene_flux_from_lumens(sc, l->lumens, l->distance_m);
    }
    return GS_OK;
}

static const char *const light_keys[] = {"id", "bulb", "phase_deg", "x_px", "y_px", "lat_deg",
                                         "lon_deg", "height_m", "distance_m", "lumens",
                                         "flux_e_per_cycle", NULL};

static gs_status parse_light(const pctx *c, const cap_scene *sc, json_t *o, const char *path,
                             int index, cap_light *l)
{
    gs_status s;
    memset(l, 0, sizeof *l);
    if ((s = gs_json_check_keys(c->doc, o, path, light_keys)) != GS_OK) return s;
    char def_id[48];
    snprintf(def_id, sizeof def_id, "L%d", index);
    if ((s = gs_json_get_str(c->doc, o, path, "id", 0, def_id, l->id, sizeof l->id)) != GS_OK ||
        (s = gs_json_get_str(c->doc, o, path, "bulb", 1, NULL, l->bulb, sizeof l->bulb)) != GS_OK ||
        (s = gs_json_get_num(c->doc, o, path, "phase_deg", 0, 0, -360, 720, NULL, &l->phase_deg)) != GS_OK)
        return s;
    int has_px = json_object_get(o, "x_px") || json_object_get(o, "y_px");
    int has_geo = json_object_get(o, "lat_deg") || json_object_get(o, "lon_deg");
    char p[560];
    if (has_px == has_geo) {
        snprintf(p, sizeof p, "%s.x_px", path);
        return bad(c, GS_EFORMAT, p, "expected either x_px and y_px (a pixel) or lat_deg, "
                   "lon_deg and height_m (a geographic light)");
    }
    if (has_px) {
        if ((s = gs_json_get_num(c->doc, o, path, "x_px", 1, 0, -1e6, 1e6, NULL, &l->x_px)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "y_px", 1, 0, -1e6, 1e6, NULL, &l->y_px)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "distance_m", 0, 0, 0, 1e7, NULL, &l->distance_m)) != GS_OK)
            return s;
    } else {
        l->geographic = 1;
        if ((s = gs_json_get_num(c->doc, o, path, "lat_deg", 1, 0, -90, 90, NULL, &l->lat_deg)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "lon_deg", 1, 0, -540, 540, NULL, &l->lon_deg)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "height_m", 1, 0, GIS_MIN_HEIGHT_M, GIS_MAX_HEIGHT_M, NULL,
                         &l->height_m)) != GS_OK)
            return s;
        if (json_object_get(o, "distance_m")) {
            snprintf(p, sizeof p, "%s.distance_m", path);
            return bad(c, GS_EFORMAT, p, "a geographic light's distance comes from its position");
        }
    }
    int has_lm = json_object_get(o, "lumens") != NULL;
    if (has_lm == (json_object_get(o, "flux_e_per_cycle") != NULL)) {
        snprintf(p, sizeof p, "%s.lumens", path);
        return bad(c, GS_EFORMAT, p, "expected exactly one of lumens (luminous power, lm) and "
                   "flux_e_per_cycle (photo-electrons per cycle at the sensor)");
    }
    if (has_lm) s = gs_json_get_num(c->doc, o, path, "lumens", 1, 0, 0, 1e9, NULL, &l->lumens);
    else s = gs_json_get_num(c->doc, o, path, "flux_e_per_cycle", 1, 0, 0, 1e15, NULL, &l->flux_e_per_cycle);
    if (s != GS_OK) return s;
    return finish_light(c, sc, l, path, has_lm);
}

/* GeoJSON FeatureCollection of Points (RFC 7946: [lon, lat(, height)]). */
static gs_status parse_geojson(const pctx *c, cap_scene *sc, json_t *blk, const char *path,
                               light_vec *lv)
{
    static const char *const keys[] = {"type", "file", "defaults", NULL};
    static const char *const dkeys[] = {"bulb", "phase_deg", "lumens", "flux_e_per_cycle",
                                        "height_m", NULL};
    gs_status s = gs_json_check_keys(c->doc, blk, path, keys);
    if (s != GS_OK) return s;
    char rel[CAP_PATH_MAX], file[CAP_PATH_MAX * 2];
    if ((s = gs_json_get_str(c->doc, blk, path, "file", 1, NULL, rel, sizeof rel)) != GS_OK) return s;
    json_t *defs = NULL;
    if ((s = gs_json_get_obj(c->doc, blk, path, "defaults", 0, &defs)) != GS_OK) return s;
    char dpath[560];
    snprintf(dpath, sizeof dpath, "%s.defaults", path);
    if (defs && (s = gs_json_check_keys(c->doc, defs, dpath, dkeys)) != GS_OK) return s;
    resolve(c, rel, file, sizeof file);
    char *text = NULL;
    size_t n_text;
    if ((s = gs_file_read(file, 0, &text, &n_text)) != GS_OK) {
        char fp[560];
        snprintf(fp, sizeof fp, "%s.file", path);
        return bad(c, s, fp, "%s", gs_detail());
    }
    /* the file is part of the scene's identity (resume refuses a changed one) */
    sc->fingerprint = cap_fnv1a(sc->fingerprint, text, n_text);
    gs_json *gdoc;
    s = gs_json_parse(text, n_text, file, &gdoc);
    free(text);
    if (s != GS_OK) return s;
    pctx g = {gdoc, c->base_dir};
    json_t *root = gs_json_root(gdoc);
    json_t *feats = json_object_get(root, "features");
    const char *type = json_string_value(json_object_get(root, "type"));
    if (!type || strcmp(type, "FeatureCollection") || !json_is_array(feats)) {
        s = bad(&g, GS_EFORMAT, "type", "expected a GeoJSON FeatureCollection with features");
        goto done;
    }
    for (size_t i = 0; i < json_array_size(feats); i++) {
        json_t *f = json_array_get(feats, i);
        char fp[96], q[160];
        snprintf(fp, sizeof fp, "features[%zu]", i);
        json_t *geom = json_object_get(f, "geometry"), *props = json_object_get(f, "properties");
        json_t *coords = json_object_get(geom, "coordinates");
        const char *gt = json_string_value(json_object_get(geom, "type"));
        snprintf(q, sizeof q, "%s.geometry", fp);
        if (!gt || strcmp(gt, "Point") || !json_is_array(coords) || json_array_size(coords) < 2 ||
            json_array_size(coords) > 3) {
            s = bad(&g, GS_EFORMAT, q, "expected a Point with [lon, lat] or [lon, lat, height]");
            goto done;
        }
        cap_light l;
        memset(&l, 0, sizeof l);
        l.geographic = 1;
        double xyz[3] = {0, 0, NAN};
        for (size_t j = 0; j < json_array_size(coords); j++) {
            json_t *x = json_array_get(coords, j);
            xyz[j] = json_is_number(x) ? json_number_value(x) : NAN;
            if (!isfinite(xyz[j])) {
                snprintf(q, sizeof q, "%s.geometry.coordinates[%zu]", fp, j);
                s = bad(&g, GS_EFORMAT, q, "expected a number");
                goto done;
            }
        }
        l.lon_deg = xyz[0];
        l.lat_deg = xyz[1];
        if (fabs(l.lat_deg) > 90) {
            snprintf(q, sizeof q, "%s.geometry.coordinates[1]", fp);
            s = bad(&g, GS_EFORMAT, q, "latitude %g: expected -90 to 90", l.lat_deg);
            goto done;
        }
        snprintf(q, sizeof q, "%s.properties", fp);
        json_t *pid = json_object_get(props, "id");
        if (json_is_string(pid)) snprintf(l.id, sizeof l.id, "%s", json_string_value(pid));
        else if (json_is_integer(pid)) snprintf(l.id, sizeof l.id, "%lld", (long long)json_integer_value(pid));
        else snprintf(l.id, sizeof l.id, "G%zu", lv->n);
        json_t *bulb = json_object_get(props, "bulb");
        if (!bulb) bulb = json_object_get(props, "bulb_id");
        if (!bulb && defs) bulb = json_object_get(defs, "bulb");
        if (!json_is_string(bulb) || strlen(json_string_value(bulb)) >= sizeof l.bulb) {
            char q2[200];
            snprintf(q2, sizeof q2, "%s.bulb", q);
            s = bad(&g, GS_EFORMAT, q2, "expected a DELIGHT bulb id (or defaults.bulb in the scene)");
            goto done;
        }
        snprintf(l.bulb, sizeof l.bulb, "%s", json_string_value(bulb));
        /* numbers: the feature's property, else the scene block's default */
        struct { const char *key, *alt; double *dst; int required; double lo, hi; } nums[] = {
            {"phase_deg", "phase", &l.phase_deg, 0, -360, 720},
            {"height_m", NULL, &l.height_m, 0, GIS_MIN_HEIGHT_M, GIS_MAX_HEIGHT_M},
        };
        for (size_t j = 0; j < sizeof nums / sizeof *nums; j++) {
            json_t *x = json_object_get(props, nums[j].key);
            if (!x && nums[j].alt) x = json_object_get(props, nums[j].alt);
            const pctx *who = &g;
            char q2[640];
            snprintf(q2, sizeof q2, "%s.%s", q, nums[j].key);
            if (!x && defs) {
                x = json_object_get(defs, nums[j].key);
                who = c;
                snprintf(q2, sizeof q2, "%s.%s", dpath, nums[j].key);
            }
            if (!x) continue;
            double d = json_is_number(x) ? json_number_value(x) : NAN;
            if (!isfinite(d) || d < nums[j].lo || d > nums[j].hi) {
                s = bad(who, GS_EFORMAT, q2, "expected a number from %g to %g", nums[j].lo, nums[j].hi);
                goto done;
            }
            *nums[j].dst = d;
        }
        if (isfinite(xyz[2])) l.height_m = xyz[2];
        else if (!json_object_get(props, "height_m") && !(defs && json_object_get(defs, "height_m"))) {
            char q2[200];
            snprintf(q2, sizeof q2, "%s.height_m", q);
            s = bad(&g, GS_EFORMAT, q2, "expected the light's height (a third coordinate, "
                    "properties.height_m or defaults.height_m)");
            goto done;
        }
        json_t *lm = json_object_get(props, "lumens");
        if (!lm) lm = json_object_get(props, "luminous_power_lm");
        json_t *fl = json_object_get(props, "flux_e_per_cycle");
        if (!lm && !fl && defs) {
            lm = json_object_get(defs, "lumens");
            fl = json_object_get(defs, "flux_e_per_cycle");
        }
        if (!lm == !fl || !json_is_number(lm ? lm : fl) || json_number_value(lm ? lm : fl) < 0) {
            char q2[200];
            snprintf(q2, sizeof q2, "%s.lumens", q);
            s = bad(&g, GS_EFORMAT, q2, "expected exactly one of lumens (>= 0) and "
                    "flux_e_per_cycle, in the feature or in defaults");
            goto done;
        }
        if (lm) l.lumens = json_number_value(lm);
        else l.flux_e_per_cycle = json_number_value(fl);
        if ((s = finish_light(&g, sc, &l, fp, lm != NULL)) != GS_OK) goto done;
        if ((s = push_light(lv, &l)) != GS_OK) goto done;
    }
    s = GS_OK;
done:
    gs_json_free(gdoc);
    return s;
}

/* A street grid (docs/scene.md): streets every street_spacing_m in both directions of a
 * rotated rectangle, lights every light_spacing_m along them, technology per district, phase
 * per light, optionally behind a delta-wye transformer per district. */
static gs_status parse_street_grid(const pctx *c, const cap_scene *sc, json_t *b, const char *path,
                                   int index, light_vec *lv)
{
    static const char *const keys[] = {"type", "seed", "center", "size_m", "rotation_deg",
                                       "street_spacing_m", "light_spacing_m", "jitter_m",
                                       "ground_height_m", "pole_height_m", "min_range_m",
                                       "max_range_m", "district_m", "technologies",
                                       "phases_deg", "transformer_fraction", "lumens_spread",
                                       "only_in_image", NULL};
    static const char *const tkeys[] = {"bulb", "weight", "lumens", NULL};
    gs_status s = gs_json_check_keys(c->doc, b, path, keys);
    if (s != GS_OK) return s;
    long seed;
    double size[2], rot, street, spacing, jitter, ground, pole, rmin, rmax, district, tf, spread;
    double lat0, lon0, phases[12];
    size_t n_phases = 0;
    int only;
    json_t *center;
    char cp[560];
    snprintf(cp, sizeof cp, "%s.center", path);
    if ((s = get_long(c, b, path, "seed", 0, (long)((sc->seed + 1000003ull * (unsigned)index) & 0x7fffffff), 0, 0x7fffffffL, &seed)) != GS_OK ||
        (s = gs_json_get_obj(c->doc, b, path, "center", 1, &center)) != GS_OK ||
        (s = gs_json_get_num(c->doc, center, cp, "lat_deg", 1, 0, -89, 89, NULL, &lat0)) != GS_OK ||
        (s = gs_json_get_num(c->doc, center, cp, "lon_deg", 1, 0, -540, 540, NULL, &lon0)) != GS_OK ||
        (s = gs_json_get_num_array(c->doc, b, path, "size_m", 2, 2, 1, 1e5, size, NULL)) != GS_OK ||
        (s = gs_json_get_num(c->doc, b, path, "rotation_deg", 0, 0, -360, 360, NULL, &rot)) != GS_OK ||
        (s = gs_json_get_num(c->doc, b, path, "street_spacing_m", 1, 0, 10, 1e4, NULL, &street)) != GS_OK ||
        (s = gs_json_get_num(c->doc, b, path, "light_spacing_m", 1, 0, 5, 1e4, NULL, &spacing)) != GS_OK ||
        (s = gs_json_get_num(c->doc, b, path, "jitter_m", 0, 0, 0, 100, NULL, &jitter)) != GS_OK ||
        (s = gs_json_get_num(c->doc, b, path, "ground_height_m", 0, 0, GIS_MIN_HEIGHT_M, 1e4, NULL, &ground)) != GS_OK ||
        (s = gs_json_get_num(c->doc, b, path, "pole_height_m", 0, 8, 0, 300, NULL, &pole)) != GS_OK ||
        (s = gs_json_get_num(c->doc, b, path, "min_range_m", 0, 0, 0, 1e6, NULL, &rmin)) != GS_OK ||
        (s = gs_json_get_num(c->doc, b, path, "max_range_m", 0, 1e6, 1, 1e7, NULL, &rmax)) != GS_OK ||
        (s = gs_json_get_num(c->doc, b, path, "district_m", 0, 1000, 10, 1e5, NULL, &district)) != GS_OK ||
        (s = gs_json_get_num(c->doc, b, path, "transformer_fraction", 0, 0, 0, 1, NULL, &tf)) != GS_OK ||
        (s = gs_json_get_num(c->doc, b, path, "lumens_spread", 0, 0.1, 0, 1, NULL, &spread)) != GS_OK ||
        (s = gs_json_get_bool(c->doc, b, path, "only_in_image", 0, 1, &only)) != GS_OK)
        return s;
    if (json_object_get(b, "phases_deg")) {
        if ((s = gs_json_get_num_array(c->doc, b, path, "phases_deg", 0, 12, -360, 360, phases, &n_phases)) != GS_OK)
            return s;
    } else {
        n_phases = (size_t)sc->n_phases;
        memcpy(phases, sc->phases_deg, sizeof(double) * n_phases);
    }
    if (!sc->has_station) return bad(c, GS_EFORMAT, path, "a street grid needs camera.station");
    json_t *techs = json_object_get(b, "technologies");
    char tp[560];
    snprintf(tp, sizeof tp, "%s.technologies", path);
    if (!json_is_array(techs) || json_array_size(techs) < 1 || json_array_size(techs) > 64)
        return bad(c, GS_EFORMAT, tp, "expected an array of 1 to 64 {bulb, weight, lumens}");
    size_t nt = json_array_size(techs);
    char tbulb[64][GS_ID_MAX];
    double tw[64], tlm[64], wsum = 0;
    for (size_t i = 0; i < nt; i++) {
        char ip[600];
        snprintf(ip, sizeof ip, "%s[%zu]", tp, i);
        json_t *t = json_array_get(techs, i);
        if (!json_is_object(t)) return bad(c, GS_EFORMAT, ip, "expected an object {bulb, weight, lumens}");
        if ((s = gs_json_check_keys(c->doc, t, ip, tkeys)) != GS_OK ||
            (s = gs_json_get_str(c->doc, t, ip, "bulb", 1, NULL, tbulb[i], GS_ID_MAX)) != GS_OK ||
            (s = gs_json_get_num(c->doc, t, ip, "weight", 0, 1, 0, 1e9, NULL, &tw[i])) != GS_OK ||
            (s = gs_json_get_num(c->doc, t, ip, "lumens", 1, 0, 0, 1e9, NULL, &tlm[i])) != GS_OK)
            return s;
        wsum += tw[i];
    }
    if (!(wsum > 0)) return bad(c, GS_EFORMAT, tp, "expected weights with a positive sum");

    double sr = sin(rot * M_PI / 180), crot = cos(rot * M_PI / 180);
    const double a = 6378137.0, f = 1.0 / 298.257223563, e2 = f * (2 - f);
    double la = lat0 * M_PI / 180, sl = sin(la);
    double Nr = a / sqrt(1 - e2 * sl * sl), Mr = a * (1 - e2) / pow(1 - e2 * sl * sl, 1.5);
    long streets_u = (long)floor(size[0] / street), streets_v = (long)floor(size[1] / street);
    size_t before = lv->n;
    /* two families: direction 0 streets run along u (constant v), direction 1 along v */
    for (int dir = 0; dir < 2; dir++) {
        long n_streets = (dir == 0 ? streets_v : streets_u) + 1;
        double len = dir == 0 ? size[0] : size[1];
        long n_lights = (long)floor(len / spacing);
        for (long i = 0; i < n_streets; i++) {
            double across = -0.5 * (dir == 0 ? size[1] : size[0]) + (double)i * street;
            for (long j = 0; j < n_lights; j++) {
                double along = -0.5 * len + ((double)j + 0.5) * spacing;
                double u = dir == 0 ? along : across, v = dir == 0 ? across : along;
                gs_rng r;
                gs_rng_init(&r, (uint64_t)seed, CAP_TAG_GRID_GEN,
                             ((uint64_t)dir << 40) ^ ((uint64_t)i << 20) ^ (uint64_t)j, 1);
                u += jitter * gs_rng_normal(&r);
                v += jitter * gs_rng_normal(&r);
                /* the district decides technology and transformer */
                long du = (long)floor(u / district), dv = (long)floor(v / district);
                gs_rng rd;
                gs_rng_init(&rd, (uint64_t)seed, CAP_TAG_GRID_GEN,
                             ((uint64_t)(du + 100000) << 24) ^ (uint64_t)(dv + 100000), 2);
                double pick = gs_rng_uniform(&rd) * wsum, acc = 0;
                size_t ti = 0;
                for (ti = 0; ti < nt - 1; ti++) {
                    acc += tw[ti];
                    if (pick < acc) break;
                }
                int transformer = gs_rng_uniform(&rd) < tf;
                double e = u * crot + v * sr, nn = -u * sr + v * crot;
                cap_light l;
                memset(&l, 0, sizeof l);
                l.geographic = 1;
                l.lat_deg = lat0 + nn / Mr * 180 / M_PI;
                l.lon_deg = lon0 + e / (Nr * cos(la)) * 180 / M_PI;
                l.height_m = ground + pole;
                snprintf(l.bulb, sizeof l.bulb, "%s", tbulb[ti]);
                size_t pi = (size_t)(gs_rng_uniform(&r) * (double)n_phases);
                if (pi >= n_phases) pi = n_phases - 1;
                l.phase_deg = phases[pi] + (transformer ? sc->transformer_deg : 0.0);
                double g = 1.0 + spread * gs_rng_normal(&r);
                l.lumens = tlm[ti] * (g < 0.1 ? 0.1 : g);
                l.distance_m = chord_m(&sc->cam, l.lat_deg, l.lon_deg, l.height_m);
                if (l.distance_m < rmin || l.distance_m > rmax) continue;
                int in_front = 0;
                s = gis_project(&sc->cam, l.lat_deg, l.lon_deg, l.height_m, &l.x_px, &l.y_px,
                                &in_front);
                if (s != GS_OK) return bad(c, GS_EFORMAT, path, "cannot project a light: %s", gs_detail());
                l.in_image = in_front && gis_in_image(&sc->cam, l.x_px, l.y_px);
                if (only && !l.in_image) continue;
                l.flux_e_per_cycle = cap_scene_flux_from_lumens(sc, l.lumens, l.distance_m);
                snprintf(l.id, sizeof l.id, "S%d-%zu", index, lv->n - before);
                if ((s = push_light(lv, &l)) != GS_OK) return s;
            }
        }
    }
    return GS_OK;
}

/* ------------------------------------------------------------------ effects */

static gs_status parse_chroma(const pctx *c, json_t *o, const char *path, int bands, double *q)
{
    for (int b = 0; b < 3; b++) q[b] = 1.0 / bands;
    if (!json_object_get(o, "chroma")) return GS_OK;
    double v[3];
    gs_status s = gs_json_get_num_array(c->doc, o, path, "chroma", (size_t)bands, 3, 0, 1e6, v, NULL);
    if (s != GS_OK) return s;
    double sum = 0;
    for (int b = 0; b < bands; b++) sum += v[b];
    char p[560];
    snprintf(p, sizeof p, "%s.chroma", path);
    if (!(sum > 0)) return bad(c, GS_EFORMAT, p, "expected a positive sum");
    for (int b = 0; b < bands; b++) q[b] = v[b] / sum;
    return GS_OK;
}

static gs_status parse_effect(const pctx *c, cap_scene *sc, cap_effect e, json_t *o,
                              const char *path)
{
    cap_effects *fx = &sc->fx;
    gs_status s = GS_OK;
    static const char *const none[] = {NULL};
    switch (e) {
    case CAP_FX_FREQUENCY_WANDER:
    case CAP_FX_SHOT_NOISE:
    case CAP_FX_SATURATION:
    case CAP_FX_ADC:
        return gs_json_check_keys(c->doc, o, path, none);
    case CAP_FX_FREE_RUNNING_DRIFT: {
        static const char *const k[] = {"clock_ppm", NULL};
        if ((s = gs_json_check_keys(c->doc, o, path, k)) != GS_OK) return s;
        return gs_json_get_num(c->doc, o, path, "clock_ppm", 0, 0, -1000, 1000, NULL, &fx->drift.clock_ppm);
    }
    case CAP_FX_DMD_JITTER: {
        static const char *const k[] = {"sigma_us", NULL};
        if ((s = gs_json_check_keys(c->doc, o, path, k)) != GS_OK) return s;
        return gs_json_get_num(c->doc, o, path, "sigma_us", 1, 0, 0, 1000, NULL, &fx->jitter.sigma_us);
    }
    case CAP_FX_EXTINCTION: {
        static const char *const k[] = {"visibility_km", "angstrom_exponent", "wavelengths_nm", NULL};
        if ((s = gs_json_check_keys(c->doc, o, path, k)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "visibility_km", 1, 0, 0.01, 1000, NULL, &fx->extinction.visibility_km)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "angstrom_exponent", 0, 1.3, 0, 4, NULL, &fx->extinction.angstrom)) != GS_OK)
            return s;
        if (sc->bands == 3) {
            fx->extinction.wavelength_nm[0] = 650;
            fx->extinction.wavelength_nm[1] = 550;
            fx->extinction.wavelength_nm[2] = 450;
        } else {
            fx->extinction.wavelength_nm[0] = 550;
        }
        if (json_object_get(o, "wavelengths_nm"))
            s = gs_json_get_num_array(c->doc, o, path, "wavelengths_nm", (size_t)sc->bands, 3, 200, 2000,
                          fx->extinction.wavelength_nm, NULL);
        return s;
    }
    case CAP_FX_SCINTILLATION: {
        static const char *const k[] = {"cn2", "wavelength_nm", "crosswind_m_s", "source_size_m",
                                        "aperture_averaging", "intensity_variance", NULL};
        if ((s = gs_json_check_keys(c->doc, o, path, k)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "cn2", 0, 1e-14, 0, 1e-10, NULL, &fx->scint.cn2)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "wavelength_nm", 0, 550, 200, 2000, NULL, &fx->scint.wavelength_nm)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "crosswind_m_s", 0, 2, 0.01, 100, NULL, &fx->scint.crosswind_m_s)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "source_size_m", 0, 0, 0, 100, NULL, &fx->scint.source_size_m)) != GS_OK ||
            (s = gs_json_get_bool(c->doc, o, path, "aperture_averaging", 0, 1, &fx->scint.aperture)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "intensity_variance", 0, -1, 0, 100, NULL, &fx->scint.sigma2)) != GS_OK)
            return s;
        return GS_OK;
    }
    case CAP_FX_PSF: {
        static const char *const k[] = {"model", "sigma_px", "radius_sigma", NULL};
        char model[32];
        if ((s = gs_json_check_keys(c->doc, o, path, k)) != GS_OK ||
            (s = gs_json_get_str(c->doc, o, path, "model", 0, "gaussian", model, sizeof model)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "sigma_px", 1, 0, 0.05, 50, NULL, &fx->psf.sigma_px)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "radius_sigma", 0, 4, 2, 8, NULL, &fx->psf.radius_sigma)) != GS_OK)
            return s;
        if (strcmp(model, "gaussian")) {
            char p[560];
            snprintf(p, sizeof p, "%s.model", path);
            return bad(c, GS_EFORMAT, p, "\"%s\": expected \"gaussian\"", model);
        }
        return GS_OK;
    }
    case CAP_FX_SKYGLOW: {
        static const char *const k[] = {"fraction", "scale_px", "radius_scale", "flicker", NULL};
        char fl[16];
        if ((s = gs_json_check_keys(c->doc, o, path, k)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "fraction", 1, 0, 0, 10, NULL, &fx->skyglow.fraction)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "scale_px", 1, 0, 0.2, 200, NULL, &fx->skyglow.scale_px)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "radius_scale", 0, 5, 1, 20, NULL, &fx->skyglow.radius_scale)) != GS_OK ||
            (s = gs_json_get_str(c->doc, o, path, "flicker", 0, "flat", fl, sizeof fl)) != GS_OK)
            return s;
        if (!strcmp(fl, "flat")) fx->skyglow.flicker = CAP_GLOW_FLAT;
        else if (!strcmp(fl, "same")) fx->skyglow.flicker = CAP_GLOW_SAME;
        else if (!strcmp(fl, "mixed")) fx->skyglow.flicker = CAP_GLOW_MIXED;
        else {
            char p[560];
            snprintf(p, sizeof p, "%s.flicker", path);
            return bad(c, GS_EFORMAT, p, "\"%s\": expected \"flat\", \"same\" or \"mixed\"", fl);
        }
        return GS_OK;
    }
    case CAP_FX_BLINKING_SIGN: {
        static const char *const k[] = {"signs", NULL};
        static const char *const sk[] = {"x_px", "y_px", "width_px", "height_px", "period_s",
                                         "duty", "phase_s", "flux_e_per_cycle", "chroma", NULL};
        if ((s = gs_json_check_keys(c->doc, o, path, k)) != GS_OK) return s;
        json_t *arr = json_object_get(o, "signs");
        char p[560];
        snprintf(p, sizeof p, "%s.signs", path);
        if (!json_is_array(arr) || json_array_size(arr) < 1 || json_array_size(arr) > 10000)
            return bad(c, GS_EFORMAT, p, "expected an array of 1 to 10000 signs");
        size_t n = json_array_size(arr);
        fx->signs.items = calloc(n, sizeof *fx->signs.items);
        if (!fx->signs.items) return gs_fail(GS_ENOMEM, "scene: out of memory");
        fx->signs.count = n;
        for (size_t i = 0; i < n; i++) {
            char ip[600];
            snprintf(ip, sizeof ip, "%s[%zu]", p, i);
            json_t *so = json_array_get(arr, i);
            cap_sign *g = &fx->signs.items[i];
            if (!json_is_object(so)) return bad(c, GS_EFORMAT, ip, "expected an object");
            if ((s = gs_json_check_keys(c->doc, so, ip, sk)) != GS_OK ||
                (s = gs_json_get_num(c->doc, so, ip, "x_px", 1, 0, -1e5, 1e5, NULL, &g->x_px)) != GS_OK ||
                (s = gs_json_get_num(c->doc, so, ip, "y_px", 1, 0, -1e5, 1e5, NULL, &g->y_px)) != GS_OK ||
                (s = gs_json_get_num(c->doc, so, ip, "width_px", 0, 1, 1, 1e4, NULL, &g->width_px)) != GS_OK ||
                (s = gs_json_get_num(c->doc, so, ip, "height_px", 0, 1, 1, 1e4, NULL, &g->height_px)) != GS_OK ||
                (s = gs_json_get_num(c->doc, so, ip, "period_s", 1, 0, 1e-3, 1e5, NULL, &g->period_s)) != GS_OK ||
                (s = gs_json_get_num(c->doc, so, ip, "duty", 0, 0.5, 0, 1, NULL, &g->duty)) != GS_OK ||
                (s = gs_json_get_num(c->doc, so, ip, "phase_s", 0, 0, -1e6, 1e6, NULL, &g->phase_s)) != GS_OK ||
                (s = gs_json_get_num(c->doc, so, ip, "flux_e_per_cycle", 1, 0, 0, 1e15, NULL, &g->flux_e_per_cycle)) != GS_OK ||
                (s = parse_chroma(c, so, ip, sc->bands, g->chroma)) != GS_OK)
                return s;
        }
        return GS_OK;
    }
    case CAP_FX_HEADLIGHTS: {
        static const char *const k[] = {"cars", NULL};
        static const char *const ck[] = {"from", "to", "speed_px_s", "period_s", "offset_s",
                                         "flux_e_per_cycle", "chroma", NULL};
        if ((s = gs_json_check_keys(c->doc, o, path, k)) != GS_OK) return s;
        json_t *arr = json_object_get(o, "cars");
        char p[560];
        snprintf(p, sizeof p, "%s.cars", path);
        if (!json_is_array(arr) || json_array_size(arr) < 1 || json_array_size(arr) > 10000)
            return bad(c, GS_EFORMAT, p, "expected an array of 1 to 10000 cars");
        size_t n = json_array_size(arr);
        fx->cars.items = calloc(n, sizeof *fx->cars.items);
        if (!fx->cars.items) return gs_fail(GS_ENOMEM, "scene: out of memory");
        fx->cars.count = n;
        for (size_t i = 0; i < n; i++) {
            char ip[600];
            snprintf(ip, sizeof ip, "%s[%zu]", p, i);
            json_t *co = json_array_get(arr, i);
            cap_car *g = &fx->cars.items[i];
            double from[2], to[2];
            if (!json_is_object(co)) return bad(c, GS_EFORMAT, ip, "expected an object");
            if ((s = gs_json_check_keys(c->doc, co, ip, ck)) != GS_OK ||
                (s = gs_json_get_num_array(c->doc, co, ip, "from", 2, 2, -1e5, 1e5, from, NULL)) != GS_OK ||
                (s = gs_json_get_num_array(c->doc, co, ip, "to", 2, 2, -1e5, 1e5, to, NULL)) != GS_OK ||
                (s = gs_json_get_num(c->doc, co, ip, "speed_px_s", 1, 0, 1e-3, 1e6, NULL, &g->speed_px_s)) != GS_OK ||
                (s = gs_json_get_num(c->doc, co, ip, "period_s", 1, 0, 1e-2, 1e5, NULL, &g->period_s)) != GS_OK ||
                (s = gs_json_get_num(c->doc, co, ip, "offset_s", 0, 0, -1e6, 1e6, NULL, &g->offset_s)) != GS_OK ||
                (s = gs_json_get_num(c->doc, co, ip, "flux_e_per_cycle", 1, 0, 0, 1e15, NULL, &g->flux_e_per_cycle)) != GS_OK ||
                (s = parse_chroma(c, co, ip, sc->bands, g->chroma)) != GS_OK)
                return s;
            g->x0_px = from[0];
            g->y0_px = from[1];
            g->x1_px = to[0];
            g->y1_px = to[1];
        }
        return GS_OK;
    }
    case CAP_FX_AMBIENT: {
        static const char *const k[] = {"e_per_px_cycle", "top", "bottom", "chroma", NULL};
        if ((s = gs_json_check_keys(c->doc, o, path, k)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "e_per_px_cycle", 1, 0, 0, 1e9, NULL, &fx->ambient.e_per_px_cycle)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "top", 0, 1, 0, 1e3, NULL, &fx->ambient.top)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, path, "bottom", 0, 1, 0, 1e3, NULL, &fx->ambient.bottom)) != GS_OK ||
            (s = parse_chroma(c, o, path, sc->bands, fx->ambient.chroma)) != GS_OK)
            return s;
        return GS_OK;
    }
    case CAP_FX_READ_NOISE: {
        static const char *const k[] = {"sigma_e", NULL};
        if ((s = gs_json_check_keys(c->doc, o, path, k)) != GS_OK) return s;
        return gs_json_get_num(c->doc, o, path, "sigma_e", 0, sc->read_noise_e, 0, 1e6, NULL, &fx->read_noise.sigma_e);
    }
    case CAP_FX_COUNT:
        break;
    }
    return bad(c, GS_EFORMAT, path, "unknown effect");
}

static const char *const effect_names[CAP_FX_COUNT] = {
    "frequency_wander", "free_running_drift", "dmd_jitter", "extinction", "scintillation",
    "psf", "skyglow", "blinking_sign", "headlights", "ambient", "shot_noise", "saturation",
    "read_noise", "adc"};

const char *cap_effect_name(cap_effect e)
{
    return (int)e >= 0 && e < CAP_FX_COUNT ? effect_names[e] : NULL;
}

gs_status cap_effect_parse(const char *name, cap_effect *e)
{
    for (int i = 0; i < CAP_FX_COUNT; i++)
        if (!strcmp(name, effect_names[i])) {
            *e = (cap_effect)i;
            return GS_OK;
        }
    return gs_fail(GS_ENOTFOUND, "unknown effect '%s'", name);
}

/* ------------------------------------------------------------------ the scene */

static gs_status parse_freq(const pctx *c, cap_scene *sc, json_t *g)
{
    static const char *const keys[] = {"model", "hz", "mean_hz", "sigma_hz", "corr_time_s",
                                       "fast_sigma_hz", "fast_corr_time_s", "wav", "start_s",
                                       NULL};
    cap_freq_config *f = &sc->freq;
    memset(f, 0, sizeof *f);
    f->model = CAP_FREQ_CONSTANT;
    f->hz = sc->grid_hz;
    f->seed = sc->seed;
    json_t *o = NULL;
    gs_status s = gs_json_get_obj(c->doc, g, "grid", "frequency", 0, &o);
    if (s != GS_OK || !o) return s;
    const char *P = "grid.frequency";
    char model[32];
    if ((s = gs_json_check_keys(c->doc, o, P, keys)) != GS_OK ||
        (s = gs_json_get_str(c->doc, o, P, "model", 0, "constant", model, sizeof model)) != GS_OK)
        return s;
    double lo = 0.9 * sc->grid_hz, hi = 1.1 * sc->grid_hz;
    if (!strcmp(model, "constant")) {
        return gs_json_get_num(c->doc, o, P, "hz", 0, sc->grid_hz, lo, hi, NULL, &f->hz);
    } else if (!strcmp(model, "random_walk")) {
        f->model = CAP_FREQ_RANDOM_WALK;
        if ((s = gs_json_get_num(c->doc, o, P, "mean_hz", 0, sc->grid_hz, lo, hi, NULL, &f->hz)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, P, "sigma_hz", 0, 0.02, 0, 1, NULL, &f->sigma_hz)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, P, "corr_time_s", 0, 18.8, 0.01, 1e5, NULL, &f->corr_time_s)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, P, "fast_sigma_hz", 0, 0.002, 0, 1, NULL, &f->fast_sigma_hz)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, P, "fast_corr_time_s", 0, 1.0, 0.01, 1e5, NULL, &f->fast_corr_time_s)) != GS_OK)
            return s;
        return GS_OK;
    } else if (!strcmp(model, "trace")) {
        f->model = CAP_FREQ_TRACE;
        char rel[CAP_PATH_MAX];
        if ((s = gs_json_get_str(c->doc, o, P, "wav", 1, NULL, rel, sizeof rel)) != GS_OK ||
            (s = gs_json_get_num(c->doc, o, P, "start_s", 0, 0, 0, 1e7, NULL, &f->start_s)) != GS_OK)
            return s;
        char full[CAP_PATH_MAX * 2];
        resolve(c, rel, full, sizeof full);
        if (strlen(full) >= sizeof f->wav) return bad(c, GS_EFORMAT, "grid.frequency.wav", "path too long");
        memcpy(f->wav, full, strlen(full) + 1);
        return GS_OK;
    }
    return bad(c, GS_EFORMAT, "grid.frequency.model", "\"%s\": expected \"constant\", "
               "\"random_walk\" or \"trace\"", model);
}

static gs_status parse_camera(const pctx *c, cap_scene *sc, json_t *root)
{
    static const char *const keys[] = {"width_px", "height_px", "station", "pose", "intrinsics",
                                       "refraction_k", "sensor", "optics", NULL};
    static const char *const stkeys[] = {"lat_deg", "lon_deg", "height_m", NULL};
    static const char *const pkeys[] = {"heading_deg", "pitch_deg", "roll_deg", NULL};
    static const char *const ikeys[] = {"focal_px", "cx_px", "cy_px", "k1", "k2", NULL};
    static const char *const skeys[] = {"bands", "bit_depth", "full_well_e", "read_noise_e",
                                        "qe", "gain_e_per_dn", "black_level_dn", NULL};
    static const char *const okeys[] = {"aperture_mm", "transmission", NULL};
    json_t *cam, *st, *pose, *intr, *sen, *opt;
    gis_camera *g = &sc->cam;
    gs_status s;
    memset(g, 0, sizeof *g);
    if ((s = gs_json_get_obj(c->doc, root, "", "camera", 1, &cam)) != GS_OK ||
        (s = gs_json_check_keys(c->doc, cam, "camera", keys)) != GS_OK ||
        (s = get_int(c, cam, "camera", "width_px", 1, 0, 1, 32768, &g->width_px)) != GS_OK ||
        (s = get_int(c, cam, "camera", "height_px", 1, 0, 1, 32768, &g->height_px)) != GS_OK ||
        (s = gs_json_get_obj(c->doc, cam, "camera", "station", 0, &st)) != GS_OK ||
        (s = gs_json_get_obj(c->doc, cam, "camera", "pose", 0, &pose)) != GS_OK ||
        (s = gs_json_get_obj(c->doc, cam, "camera", "intrinsics", 0, &intr)) != GS_OK ||
        (s = gs_json_get_obj(c->doc, cam, "camera", "sensor", 0, &sen)) != GS_OK ||
        (s = gs_json_get_obj(c->doc, cam, "camera", "optics", 0, &opt)) != GS_OK ||
        (s = gs_json_get_num(c->doc, cam, "camera", "refraction_k", 0, 0, -1, 0.9, NULL, &g->refraction_k)) != GS_OK)
        return s;
    if (st) {
        sc->has_station = 1;
        if ((s = gs_json_check_keys(c->doc, st, "camera.station", stkeys)) != GS_OK ||
            (s = gs_json_get_num(c->doc, st, "camera.station", "lat_deg", 1, 0, -90, 90, NULL, &g->lat_deg)) != GS_OK ||
            (s = gs_json_get_num(c->doc, st, "camera.station", "lon_deg", 1, 0, -540, 540, NULL, &g->lon_deg)) != GS_OK ||
            (s = gs_json_get_num(c->doc, st, "camera.station", "height_m", 1, 0, GIS_MIN_HEIGHT_M, GIS_MAX_HEIGHT_M, NULL, &g->height_m)) != GS_OK)
            return s;
    }
    if (pose && (s = gs_json_check_keys(c->doc, pose, "camera.pose", pkeys)) != GS_OK) return s;
    if ((s = gs_json_get_num(c->doc, pose, "camera.pose", "heading_deg", 0, 0, -720, 720, NULL, &g->heading_deg)) != GS_OK ||
        (s = gs_json_get_num(c->doc, pose, "camera.pose", "pitch_deg", 0, 0, -90, 90, NULL, &g->pitch_deg)) != GS_OK ||
        (s = gs_json_get_num(c->doc, pose, "camera.pose", "roll_deg", 0, 0, -720, 720, NULL, &g->roll_deg)) != GS_OK)
        return s;
    if (intr && (s = gs_json_check_keys(c->doc, intr, "camera.intrinsics", ikeys)) != GS_OK) return s;
    if ((s = gs_json_get_num(c->doc, intr, "camera.intrinsics", "focal_px", 0, g->width_px, 1, 1e7, NULL, &g->focal_px)) != GS_OK ||
        (s = gs_json_get_num(c->doc, intr, "camera.intrinsics", "cx_px", 0, 0.5 * (g->width_px - 1), -1e5, 1e5, NULL, &g->cx_px)) != GS_OK ||
        (s = gs_json_get_num(c->doc, intr, "camera.intrinsics", "cy_px", 0, 0.5 * (g->height_px - 1), -1e5, 1e5, NULL, &g->cy_px)) != GS_OK ||
        (s = gs_json_get_num(c->doc, intr, "camera.intrinsics", "k1", 0, 0, -10, 10, NULL, &g->k1)) != GS_OK ||
        (s = gs_json_get_num(c->doc, intr, "camera.intrinsics", "k2", 0, 0, -10, 10, NULL, &g->k2)) != GS_OK)
        return s;
    if (sen && (s = gs_json_check_keys(c->doc, sen, "camera.sensor", skeys)) != GS_OK) return s;
    const char *S = "camera.sensor";
    if ((s = get_int(c, sen, S, "bands", 0, 3, 1, 3, &sc->bands)) != GS_OK ||
        (s = get_int(c, sen, S, "bit_depth", 0, 12, 8, 16, &sc->bit_depth)) != GS_OK ||
        (s = gs_json_get_num(c->doc, sen, S, "full_well_e", 0, 20000, 1, 1e9, NULL, &sc->full_well_e)) != GS_OK ||
        (s = gs_json_get_num(c->doc, sen, S, "read_noise_e", 0, 3, 0, 1e6, NULL, &sc->read_noise_e)) != GS_OK ||
        (s = gs_json_get_num(c->doc, sen, S, "qe", 0, 0.6, 1e-6, 1, NULL, &sc->qe)) != GS_OK ||
        (s = gs_json_get_num(c->doc, sen, S, "gain_e_per_dn", 0, 5, 1e-3, 1e6, NULL, &sc->gain_e_per_dn)) != GS_OK ||
        (s = gs_json_get_num(c->doc, sen, S, "black_level_dn", 0, 0, 0, 60000, NULL, &sc->black_level_dn)) != GS_OK)
        return s;
    if (sc->bands == 2) return bad(c, GS_EFORMAT, "camera.sensor.bands", "2: expected 1 or 3");
    if (sc->black_level_dn >= (double)(1 << sc->bit_depth) - 1)
        return bad(c, GS_EFORMAT, "camera.sensor.black_level_dn", "%g: expected below the ADC's "
                   "range 2^bit_depth - 1 = %d", sc->black_level_dn, (1 << sc->bit_depth) - 1);
    if (opt && (s = gs_json_check_keys(c->doc, opt, "camera.optics", okeys)) != GS_OK) return s;
    if ((s = gs_json_get_num(c->doc, opt, "camera.optics", "aperture_mm", 0, 2, 1e-3, 1e4, NULL, &sc->aperture_mm)) != GS_OK ||
        (s = gs_json_get_num(c->doc, opt, "camera.optics", "transmission", 0, 0.3, 1e-9, 1, NULL, &sc->transmission)) != GS_OK)
        return s;
    if (!sc->has_station) {
        /* a pixel-only scene: any valid pose (projection is never used) */
        g->lat_deg = 0;
        g->lon_deg = 0;
        g->height_m = 0;
    }
    s = gis_camera_check(g);
    if (s != GS_OK) return bad(c, GS_EFORMAT, "camera", "%s", gs_detail());
    return GS_OK;
}

static gs_status parse_acam(const pctx *c, cap_scene *sc, json_t *root)
{
    static const char *const keys[] = {"K", "cycles", "locked", "masks", "dmd_min_hold_us",
                                       "free_running_period", "readout_cycles", "hdr", NULL};
    static const char *const hkeys[] = {"enabled", "max_rounds", "max_saturated_px", NULL};
    json_t *a;
    cap_acam_config *q = &sc->acam;
    cap_acam_config_default(q);
    q->grid_hz = sc->grid_hz;
    gs_status s;
    char per[16];
    if ((s = gs_json_get_obj(c->doc, root, "", "acam", 1, &a)) != GS_OK ||
        (s = gs_json_check_keys(c->doc, a, "acam", keys)) != GS_OK ||
        (s = get_int(c, a, "acam", "K", 1, 0, 2, 1024, &q->K)) != GS_OK ||
        (s = get_long(c, a, "acam", "cycles", 1, 0, 1, CAP_MAX_CYCLES, &q->cycles)) != GS_OK ||
        (s = gs_json_get_bool(c->doc, a, "acam", "locked", 0, 1, &sc->locked)) != GS_OK ||
        (s = get_int(c, a, "acam", "masks", 0, 2, 2, 1000, &q->masks)) != GS_OK ||
        (s = gs_json_get_num(c->doc, a, "acam", "dmd_min_hold_us", 0, CAP_DMD_MIN_HOLD_US, 1, 1e5, NULL, &q->dmd_min_hold_us)) != GS_OK ||
        (s = gs_json_get_str(c->doc, a, "acam", "free_running_period", 0, "nominal", per, sizeof per)) != GS_OK ||
        (s = get_long(c, a, "acam", "readout_cycles", 0, 10, 0, 1000000, &sc->readout_cycles)) != GS_OK)
        return s;
    if (!strcmp(per, "measured")) sc->free_period_measured = 1;
    else if (strcmp(per, "nominal"))
        return bad(c, GS_EFORMAT, "acam.free_running_period", "\"%s\": expected \"nominal\" or "
                   "\"measured\"", per);
    json_t *h = json_object_get(a, "hdr");
    if (json_is_boolean(h)) q->hdr = json_is_true(h);
    else if (json_is_object(h)) {
        if ((s = gs_json_check_keys(c->doc, h, "acam.hdr", hkeys)) != GS_OK ||
            (s = gs_json_get_bool(c->doc, h, "acam.hdr", "enabled", 0, 1, &q->hdr)) != GS_OK ||
            (s = get_int(c, h, "acam.hdr", "max_rounds", 0, 0, 0, 16, &q->hdr_max_rounds)) != GS_OK ||
            (s = get_int(c, h, "acam.hdr", "max_saturated_px", 0, 0, 0, 1 << 30, &q->hdr_max_saturated_px)) != GS_OK)
            return s;
    } else if (h) {
        return bad(c, GS_EFORMAT, "acam.hdr", "expected true, false or {enabled, max_rounds, "
                   "max_saturated_px}");
    }
    return GS_OK;
}

/* The field of acam a cap_acam_check message is about. */
static const char *acam_field(const char *detail)
{
    if (!strncmp(detail, "K =", 3)) return "acam.K";
    if (!strncmp(detail, "M =", 3)) return "acam.masks";
    if (!strncmp(detail, "C =", 3)) return "acam.cycles";
    if (!strncmp(detail, "each mask", 9)) return "acam.dmd_min_hold_us";
    if (!strncmp(detail, "HDR", 3)) return "acam.hdr";
    if (!strncmp(detail, "highest", 7)) return "grid.frequency";
    return "acam";
}

gs_status cap_scene_parse(const char *text, const char *source, const char *base_dir,
                          cap_scene *sc)
{
    static const char *const keys[] = {"format", "name", "seed", "utc", "delight", "grid",
                                       "camera", "acam", "lights", "effects", NULL};
    static const char *const gkeys[] = {"nominal_hz", "frequency", "phases_deg", "transformer_deg",
                                        NULL};
    memset(sc, 0, sizeof *sc);
    if (!source) source = "<scene>";
    gs_json *doc;
    gs_status s = gs_json_parse(text, strlen(text), source, &doc);
    if (s != GS_OK) return s;
    pctx c = {doc, base_dir};
    json_t *root = gs_json_root(doc);
    light_vec lv = {NULL, 0, 0};
    char fmt[64];
    long seed;
    json_t *grid, *lights, *effects;
    sc->fingerprint = cap_fnv1a(CAP_FNV_INIT, text, strlen(text));
    if (!json_is_object(root)) {
        s = bad(&c, GS_EFORMAT, "(top level)", "expected a JSON object");
        goto done;
    }
    if ((s = gs_json_check_keys(c.doc, root, "", keys)) != GS_OK ||
        (s = gs_json_get_str(c.doc, root, "", "format", 1, NULL, fmt, sizeof fmt)) != GS_OK)
        goto done;
    if (strcmp(fmt, CAP_SCENE_FORMAT)) {
        s = bad(&c, GS_EFORMAT, "format", "\"%s\": expected \"%s\"", fmt, CAP_SCENE_FORMAT);
        goto done;
    }
    if ((s = gs_json_get_str(c.doc, root, "", "name", 0, "", sc->name, sizeof sc->name)) != GS_OK ||
        (s = get_long(&c, root, "", "seed", 0, 1, 0, 0x7fffffffL, &seed)) != GS_OK ||
        (s = gs_json_get_str(c.doc, root, "", "utc", 0, "", sc->utc, sizeof sc->utc)) != GS_OK)
        goto done;
    sc->seed = (unsigned long long)seed;
    if (sc->utc[0] && (strlen(sc->utc) < 20 || sc->utc[4] != '-' || sc->utc[10] != 'T')) {
        s = bad(&c, GS_EFORMAT, "utc", "\"%s\": expected ISO 8601 YYYY-MM-DDThh:mm:ssZ", sc->utc);
        goto done;
    }
    if (json_object_get(root, "delight")) {
        char rel[CAP_PATH_MAX];
        if ((s = gs_json_get_str(c.doc, root, "", "delight", 1, NULL, rel, sizeof rel)) != GS_OK) goto done;
        char full[CAP_PATH_MAX * 2];
        resolve(&c, rel, full, sizeof full);
        if (strlen(full) >= sizeof sc->delight) {
            s = bad(&c, GS_EFORMAT, "delight", "path too long");
            goto done;
        }
        memcpy(sc->delight, full, strlen(full) + 1);
    }
    /* grid */
    if ((s = gs_json_get_obj(c.doc, root, "", "grid", 1, &grid)) != GS_OK ||
        (s = gs_json_check_keys(c.doc, grid, "grid", gkeys)) != GS_OK ||
        (s = get_int(&c, grid, "grid", "nominal_hz", 1, 0, 50, 60, &sc->grid_hz)) != GS_OK ||
        (s = gs_json_get_num(c.doc, grid, "grid", "transformer_deg", 0, 30, -180, 180, NULL, &sc->transformer_deg)) != GS_OK)
        goto done;
    if (sc->grid_hz != 50 && sc->grid_hz != 60) {
        s = bad(&c, GS_EFORMAT, "grid.nominal_hz", "%d: expected 50 or 60", sc->grid_hz);
        goto done;
    }
    if ((s = parse_freq(&c, sc, grid)) != GS_OK) goto done;
    if (json_object_get(grid, "phases_deg")) {
        size_t np = 0;
        if ((s = gs_json_get_num_array(c.doc, grid, "grid", "phases_deg", 0, 12, 0, 360, sc->phases_deg, &np)) != GS_OK)
            goto done;
        sc->n_phases = (int)np;
    } else {
        sc->phases_deg[0] = 0;
        sc->phases_deg[1] = 120;
        sc->phases_deg[2] = 240;
        sc->n_phases = 3;
    }
    if ((s = parse_camera(&c, sc, root)) != GS_OK || (s = parse_acam(&c, sc, root)) != GS_OK)
        goto done;
    /* effects (before the checks that depend on them) */
    if ((s = gs_json_get_obj(c.doc, root, "", "effects", 0, &effects)) != GS_OK) goto done;
    if (effects) {
        const char *key;
        json_t *v;
        json_object_foreach(effects, key, v) {
            char p[512];
            snprintf(p, sizeof p, "effects.%s", key);
            cap_effect e;
            if (cap_effect_parse(key, &e) != GS_OK) {
                char list[512] = "";
                for (int i = 0; i < CAP_FX_COUNT; i++) {
                    size_t u = strlen(list);
                    snprintf(list + u, sizeof list - u, "%s%s", i ? ", " : "", effect_names[i]);
                }
                s = bad(&c, GS_EFORMAT, p, "unknown effect; expected one of: %s", list);
                goto done;
            }
            if (!json_is_object(v)) {
                s = bad(&c, GS_EFORMAT, p, "expected an object of parameters ({} for none)");
                goto done;
            }
            sc->fx.enabled |= 1u << e;
            if ((s = parse_effect(&c, sc, e, v, p)) != GS_OK) goto done;
        }
    }
    if (!(sc->fx.enabled & (1u << CAP_FX_READ_NOISE))) sc->fx.read_noise.sigma_e = 0;
    /* consistency between the grid, the ACam and the effects */
    int wander = (sc->fx.enabled >> CAP_FX_FREQUENCY_WANDER) & 1;
    if (!wander && (sc->freq.model != CAP_FREQ_CONSTANT || sc->freq.hz != sc->grid_hz)) {
        s = bad(&c, GS_EFORMAT, "grid.frequency", "a grid that deviates from nominal_hz is "
                "simulated only when effects lists frequency_wander (add it, or use model "
                "\"constant\" at the nominal frequency)");
        goto done;
    }
    if ((sc->fx.enabled >> CAP_FX_FREE_RUNNING_DRIFT) & 1 && sc->locked) {
        s = bad(&c, GS_EFORMAT, "effects.free_running_drift", "expected acam.locked false: a "
                "locked ACam re-anchors its windows at every zero crossing");
        goto done;
    }
    if (wander) {
        if (sc->freq.model == CAP_FREQ_CONSTANT) sc->acam.max_hz = sc->freq.hz;
        else if (sc->freq.model == CAP_FREQ_RANDOM_WALK)
            sc->acam.max_hz = sc->freq.hz + 5 * (sc->freq.sigma_hz + sc->freq.fast_sigma_hz);
        else sc->acam.max_hz = sc->grid_hz * 1.002;   /* checked on the trace when it is read */
    }
    s = cap_acam_check(&sc->acam);
    if (s != GS_OK) {
        char detail[512];
        snprintf(detail, sizeof detail, "%s", gs_detail());
        s = bad(&c, s, acam_field(detail), "%s", detail);
        goto done;
    }
    /* lights */
    lights = json_object_get(root, "lights");
    if (!json_is_array(lights)) {
        s = bad(&c, GS_EFORMAT, "lights", "expected an array of lights and light sources "
                "(required; [] for none)");
        goto done;
    }
    for (size_t i = 0; i < json_array_size(lights); i++) {
        char p[64];
        snprintf(p, sizeof p, "lights[%zu]", i);
        json_t *o = json_array_get(lights, i);
        if (!json_is_object(o)) {
            s = bad(&c, GS_EFORMAT, p, "expected an object");
            goto done;
        }
        json_t *type = json_object_get(o, "type");
        if (type) {
            const char *t = json_string_value(type);
            char tp[80];
            snprintf(tp, sizeof tp, "%s.type", p);
            if (t && !strcmp(t, "geojson")) s = parse_geojson(&c, sc, o, p, &lv);
            else if (t && !strcmp(t, "street_grid")) s = parse_street_grid(&c, sc, o, p, (int)i, &lv);
            else s = bad(&c, GS_EFORMAT, tp, "expected \"geojson\" or \"street_grid\" (a light "
                         "source block), or no type (one light)");
        } else {
            cap_light l;
            s = parse_light(&c, sc, o, p, (int)lv.n, &l);
            l.line = gs_json_line(c.doc, p);
            if (s == GS_OK) s = push_light(&lv, &l);
        }
        for (size_t j = 0; j < lv.n; j++)
            if (!lv.v[j].line) lv.v[j].line = gs_json_line(c.doc, p);
        if (s != GS_OK) goto done;
    }
    sc->lights = lv.v;
    sc->n_lights = lv.n;
    lv.v = NULL;
    s = GS_OK;
done:
    free(lv.v);
    gs_json_free(doc);
    return s;
}

gs_status cap_scene_read(const char *path, cap_scene *sc)
{
    memset(sc, 0, sizeof *sc);
    char *text = NULL;
    size_t n;
    gs_status s = gs_file_read(path, 0, &text, &n);
    if (s != GS_OK) return s;
    if (strlen(text) != n) {
        free(text);
        return gs_fail(GS_EFORMAT, "%s: contains a NUL byte: not JSON text", path);
    }
    char dir[CAP_PATH_MAX];
    snprintf(dir, sizeof dir, "%s", path);
    char *slash = strrchr(dir, '/');
    if (slash) *slash = '\0';
    else snprintf(dir, sizeof dir, ".");
    s = cap_scene_parse(text, path, dir, sc);
    free(text);
    if (s == GS_OK) snprintf(sc->path, sizeof sc->path, "%s", path);
    return s;
}

void cap_scene_release(cap_scene *sc)
{
    if (!sc) return;
    free(sc->lights);
    free(sc->fx.signs.items);
    free(sc->fx.cars.items);
    memset(sc, 0, sizeof *sc);
}
