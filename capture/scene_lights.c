/* scene_lights.c - the lights of a scene (docs/scene.md, "lights"): inline lights (pixel or
 * geographic), GeoJSON files of points, and compact "street_grid" blocks generated
 * deterministically; geographic lights are projected with the one shared camera model,
 * gis_project (gis/gis.h). */
#include "capture/internal.h"

#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------------------ geometry */

static double chord_m(const gis_camera *cam, double lat, double lon, double h)
{
    return gis_chord_m(cam->lat_deg, cam->lon_deg, cam->height_m, lat, lon, h);
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

/* Appends l (of the block at path); the lights must fit the memory budget as the simulator
 * will hold them (CAP_RENDER_BYTES_PER_LIGHT each), checked before the vector grows: a street
 * grid of a few lines can declare 10^8 lights. */
static gs_status push_light(const cap_pctx *c, const char *path, light_vec *lv, const cap_light *l)
{
    if (lv->n == lv->cap) {
        size_t nc = lv->cap ? lv->cap * 2 : 64;
        char what[160];
        snprintf(what, sizeof what, "%zu lights (%d B each when rendered)", nc,
                 CAP_RENDER_BYTES_PER_LIGHT + (int)sizeof(cap_light));
        if (lv->cap && gs_mem_check((double)nc * (CAP_RENDER_BYTES_PER_LIGHT + sizeof(cap_light)), what) != GS_OK)
            return cap_scene_bad(c, GS_ELIMIT, path, "%s", gs_detail());
        cap_light *nv = realloc(lv->v, nc * sizeof *nv);
        if (!nv) return gs_fail(GS_ENOMEM, "scene: out of memory for lights");
        lv->v = nv;
        lv->cap = nc;
    }
    lv->v[lv->n++] = *l;
    return GS_OK;
}

/* The range of every numeric light field, whichever block gives it (an inline light, a GeoJSON
 * feature or its block's defaults), so that no path lets through what another refuses. */
static const struct {
    const char *key;
    double lo, hi;
} light_range[] = {
    {"phase_deg", -360, 720},
    {"x_px", -1e6, 1e6},
    {"y_px", -1e6, 1e6},
    {"distance_m", 0, 1e7},
    {"lat_deg", -90, 90},
    {"lon_deg", -540, 540},
    {"height_m", GIS_MIN_HEIGHT_M, GIS_MAX_HEIGHT_M},
    {"lumens", 0, 1e9},
    {"flux_e_per_cycle", 0, 1e15},
};

static void range_of(const char *key, double *lo, double *hi)
{
    for (size_t i = 0; i < sizeof light_range / sizeof *light_range; i++)
        if (!strcmp(light_range[i].key, key)) {
            *lo = light_range[i].lo;
            *hi = light_range[i].hi;
            return;
        }
    *lo = *hi = NAN;   /* not a light field: every comparison fails, nothing passes */
}

/* gs_json_get_num of a light field, with its range. */
static gs_status get_light_num(const cap_pctx *c, json_t *o, const char *path, const char *key,
                               int required, double def, double *out)
{
    double lo, hi;
    range_of(key, &lo, &hi);
    return gs_json_get_num(c->doc, o, path, key, required, def, lo, hi, NULL, out);
}

/* Place a light: projection (geographic), distance, flux from lumens. path names it. */
static gs_status finish_light(const cap_pctx *c, const cap_scene *sc, cap_light *l, const char *path,
                              int lumens_given)
{
    char p[560];
    if (l->geographic) {
        if (!sc->has_station) {
            snprintf(p, sizeof p, "%s.lat_deg", path);
            return cap_scene_bad(c, GS_EFORMAT, p, "a geographic light needs camera.station");
        }
        int in_front = 0;
        gs_status s = gis_project(&sc->cam, l->lat_deg, l->lon_deg, l->height_m, &l->x_px,
                                  &l->y_px, &in_front);
        if (s != GS_OK) return cap_scene_bad(c, GS_EFORMAT, path, "cannot project: %s", gs_detail());
        l->in_image = in_front && gis_in_image(&sc->cam, l->x_px, l->y_px);
        l->distance_m = chord_m(&sc->cam, l->lat_deg, l->lon_deg, l->height_m);
    } else {
        l->in_image = l->x_px >= -0.5 && l->x_px < sc->cam.width_px - 0.5 && l->y_px >= -0.5 &&
                      l->y_px < sc->cam.height_px - 0.5;
    }
    if (lumens_given) {
        if (!(l->distance_m > 0)) {
            snprintf(p, sizeof p, "%s.lumens", path);
            return cap_scene_bad(c, GS_EFORMAT, p, "a light given in lumens needs its distance (distance_m, "
                       "or a geographic position)");
        }
        l->flux_e_per_cycle = cap_scene_flux_from_lumens(sc, l->lumens, l->distance_m);
    }
    double lo, hi;
    range_of("flux_e_per_cycle", &lo, &hi);
    if (!(l->flux_e_per_cycle >= lo && l->flux_e_per_cycle <= hi)) {
        snprintf(p, sizeof p, "%s.%s", path, lumens_given ? "lumens" : "flux_e_per_cycle");
        return cap_scene_bad(c, GS_EFORMAT, p, "gives %g photo-electrons per cycle at the sensor: "
                             "expected %g to %g", l->flux_e_per_cycle, lo, hi);
    }
    return GS_OK;
}

static const char *const light_keys[] = {"id", "bulb", "phase_deg", "x_px", "y_px", "lat_deg",
                                         "lon_deg", "height_m", "distance_m", "lumens",
                                         "flux_e_per_cycle", NULL};

static gs_status parse_light(const cap_pctx *c, const cap_scene *sc, json_t *o, const char *path,
                             int index, cap_light *l)
{
    gs_status s;
    memset(l, 0, sizeof *l);
    if ((s = gs_json_check_keys(c->doc, o, path, light_keys)) != GS_OK) return s;
    char def_id[48];
    snprintf(def_id, sizeof def_id, "L%d", index);
    if ((s = gs_json_get_str(c->doc, o, path, "id", 0, def_id, l->id, sizeof l->id)) != GS_OK ||
        (s = gs_json_get_str(c->doc, o, path, "bulb", 1, NULL, l->bulb, sizeof l->bulb)) != GS_OK ||
        (s = get_light_num(c, o, path, "phase_deg", 0, 0, &l->phase_deg)) != GS_OK)
        return s;
    int has_px = json_object_get(o, "x_px") || json_object_get(o, "y_px");
    int has_geo = json_object_get(o, "lat_deg") || json_object_get(o, "lon_deg");
    char p[560];
    if (has_px == has_geo) {
        snprintf(p, sizeof p, "%s.x_px", path);
        return cap_scene_bad(c, GS_EFORMAT, p, "expected either x_px and y_px (a pixel) or lat_deg, "
                   "lon_deg and height_m (a geographic light)");
    }
    if (has_px) {
        if ((s = get_light_num(c, o, path, "x_px", 1, 0, &l->x_px)) != GS_OK ||
            (s = get_light_num(c, o, path, "y_px", 1, 0, &l->y_px)) != GS_OK ||
            (s = get_light_num(c, o, path, "distance_m", 0, 0, &l->distance_m)) != GS_OK)
            return s;
    } else {
        l->geographic = 1;
        if ((s = get_light_num(c, o, path, "lat_deg", 1, 0, &l->lat_deg)) != GS_OK ||
            (s = get_light_num(c, o, path, "lon_deg", 1, 0, &l->lon_deg)) != GS_OK ||
            (s = get_light_num(c, o, path, "height_m", 1, 0, &l->height_m)) != GS_OK)
            return s;
        if (json_object_get(o, "distance_m")) {
            snprintf(p, sizeof p, "%s.distance_m", path);
            return cap_scene_bad(c, GS_EFORMAT, p, "a geographic light's distance comes from its position");
        }
    }
    int has_lm = json_object_get(o, "lumens") != NULL;
    if (has_lm == (json_object_get(o, "flux_e_per_cycle") != NULL)) {
        snprintf(p, sizeof p, "%s.lumens", path);
        return cap_scene_bad(c, GS_EFORMAT, p, "expected exactly one of lumens (luminous power, lm) and "
                   "flux_e_per_cycle (photo-electrons per cycle at the sensor)");
    }
    if (has_lm) s = get_light_num(c, o, path, "lumens", 1, 0, &l->lumens);
    else s = get_light_num(c, o, path, "flux_e_per_cycle", 1, 0, &l->flux_e_per_cycle);
    if (s != GS_OK) return s;
    return finish_light(c, sc, l, path, has_lm);
}

/* GeoJSON FeatureCollection of Points (RFC 7946: [lon, lat(, height)]). */
static gs_status parse_geojson(const cap_pctx *c, cap_scene *sc, json_t *blk, const char *path,
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
    cap_scene_resolve(c, rel, file, sizeof file);
    char *text = NULL;
    size_t n_text;
    if ((s = gs_file_read(file, 0, &text, &n_text)) != GS_OK) {
        char fp[560];
        snprintf(fp, sizeof fp, "%s.file", path);
        return cap_scene_bad(c, s, fp, "%s", gs_detail());
    }
    /* the file is part of the scene's identity (resume refuses a changed one) */
    sc->fingerprint = cap_fnv1a(sc->fingerprint, text, n_text);
    gs_json *gdoc;
    s = gs_json_parse(text, n_text, file, &gdoc);
    free(text);
    if (s != GS_OK) return s;
    cap_pctx g = {gdoc, c->base_dir};
    json_t *root = gs_json_root(gdoc);
    json_t *feats = json_object_get(root, "features");
    const char *type = json_string_value(json_object_get(root, "type"));
    if (!type || strcmp(type, "FeatureCollection") || !json_is_array(feats)) {
        s = cap_scene_bad(&g, GS_EFORMAT, "type", "expected a GeoJSON FeatureCollection with features");
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
            s = cap_scene_bad(&g, GS_EFORMAT, q, "expected a Point with [lon, lat] or [lon, lat, height]");
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
                s = cap_scene_bad(&g, GS_EFORMAT, q, "expected a number");
                goto done;
            }
        }
        l.lon_deg = xyz[0];
        l.lat_deg = xyz[1];
        static const char *const coord_key[3] = {"lon_deg", "lat_deg", "height_m"};
        for (size_t j = 0; j < json_array_size(coords); j++) {
            double lo, hi;
            range_of(coord_key[j], &lo, &hi);
            if (!(xyz[j] >= lo && xyz[j] <= hi)) {
                snprintf(q, sizeof q, "%s.geometry.coordinates[%zu]", fp, j);
                s = cap_scene_bad(&g, GS_EFORMAT, q, "%s %g: expected %g to %g", coord_key[j], xyz[j], lo, hi);
                goto done;
            }
        }
        snprintf(q, sizeof q, "%s.properties", fp);
        json_t *pid = json_object_get(props, "id");
        if (json_is_string(pid) && strlen(json_string_value(pid)) >= sizeof l.id) {
            char q2[200];
            snprintf(q2, sizeof q2, "%s.id", q);
            s = cap_scene_bad(&g, GS_EFORMAT, q2, "expected an id shorter than %zu bytes", sizeof l.id);
            goto done;
        }
        if (json_is_string(pid)) snprintf(l.id, sizeof l.id, "%s", json_string_value(pid));
        else if (json_is_integer(pid)) snprintf(l.id, sizeof l.id, "%lld", (long long)json_integer_value(pid));
        else snprintf(l.id, sizeof l.id, "G%zu", lv->n);
        json_t *bulb = json_object_get(props, "bulb");
        if (!bulb) bulb = json_object_get(props, "bulb_id");
        if (!bulb && defs) bulb = json_object_get(defs, "bulb");
        if (!json_is_string(bulb) || strlen(json_string_value(bulb)) >= sizeof l.bulb) {
            char q2[200];
            snprintf(q2, sizeof q2, "%s.bulb", q);
            s = cap_scene_bad(&g, GS_EFORMAT, q2, "expected a DELIGHT bulb id (or defaults.bulb in the scene)");
            goto done;
        }
        snprintf(l.bulb, sizeof l.bulb, "%s", json_string_value(bulb));
        /* numbers: the feature's property, else the scene block's default */
        struct { const char *key, *alt; double *dst; } nums[] = {
            {"phase_deg", "phase", &l.phase_deg},
            {"height_m", NULL, &l.height_m},
            {"lumens", "luminous_power_lm", &l.lumens},
            {"flux_e_per_cycle", NULL, &l.flux_e_per_cycle},
        };
        json_t *given[4] = {NULL};
        /* the feature's own lumens or flux overrides both defaults */
        int own_flux = json_object_get(props, "lumens") || json_object_get(props, "luminous_power_lm") ||
                       json_object_get(props, "flux_e_per_cycle");
        for (size_t j = 0; j < sizeof nums / sizeof *nums; j++) {
            json_t *x = json_object_get(props, nums[j].key);
            if (!x && nums[j].alt) x = json_object_get(props, nums[j].alt);
            const cap_pctx *who = &g;
            char q2[640];
            snprintf(q2, sizeof q2, "%s.%s", q, nums[j].key);
            if (!x && defs && !(j >= 2 && own_flux)) {
                x = json_object_get(defs, nums[j].key);
                who = c;
                snprintf(q2, sizeof q2, "%s.%s", dpath, nums[j].key);
            }
            if (!x) continue;
            double d = json_is_number(x) ? json_number_value(x) : NAN, lo, hi;
            range_of(nums[j].key, &lo, &hi);
            if (!(d >= lo && d <= hi)) {
                s = cap_scene_bad(who, GS_EFORMAT, q2, "expected a number from %g to %g", lo, hi);
                goto done;
            }
            *nums[j].dst = d;
            given[j] = x;
        }
        if (isfinite(xyz[2])) l.height_m = xyz[2];
        else if (!json_object_get(props, "height_m") && !(defs && json_object_get(defs, "height_m"))) {
            char q2[200];
            snprintf(q2, sizeof q2, "%s.height_m", q);
            s = cap_scene_bad(&g, GS_EFORMAT, q2, "expected the light's height (a third coordinate, "
                    "properties.height_m or defaults.height_m)");
            goto done;
        }
        /* lumens or flux: the feature's, else the defaults' (read and range-checked above) */
        json_t *lm = given[2], *fl = given[3];
        if (!lm == !fl) {
            char q2[200];
            snprintf(q2, sizeof q2, "%s.lumens", q);
            s = cap_scene_bad(&g, GS_EFORMAT, q2, "expected exactly one of lumens and "
                    "flux_e_per_cycle, in the feature or in defaults");
            goto done;
        }
        if ((s = finish_light(&g, sc, &l, fp, lm != NULL)) != GS_OK) goto done;
        if ((s = push_light(c, path, lv, &l)) != GS_OK) goto done;
    }
    s = GS_OK;
done:
    gs_json_free(gdoc);
    return s;
}

/* A street grid (docs/scene.md): streets every street_spacing_m in both directions of a
 * rotated rectangle, lights every light_spacing_m along them, technology per district, phase
 * per light, optionally behind a delta-wye transformer per district. */
static gs_status parse_street_grid(const cap_pctx *c, const cap_scene *sc, json_t *b, const char *path,
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
    if ((s = cap_scene_get_long(c, b, path, "seed", 0, (long)((sc->seed + 1000003ull * (unsigned)index) & 0x7fffffff), 0, 0x7fffffffL, &seed)) != GS_OK ||
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
    if (rmin >= rmax) {   /* (no light would be in range) */
        char rp[560];
        snprintf(rp, sizeof rp, "%s.min_range_m", path);
        return cap_scene_bad(c, GS_EFORMAT, rp, "%g: expected below max_range_m = %g", rmin, rmax);
    }
    if (json_object_get(b, "phases_deg")) {
        if ((s = gs_json_get_num_array(c->doc, b, path, "phases_deg", 0, 12, -360, 360, phases, &n_phases)) != GS_OK)
            return s;
    } else {
        n_phases = (size_t)sc->n_phases;
        memcpy(phases, sc->phases_deg, sizeof(double) * n_phases);
    }
    if (!sc->has_station) return cap_scene_bad(c, GS_EFORMAT, path, "a street grid needs camera.station");
    json_t *techs = json_object_get(b, "technologies");
    char tp[560];
    snprintf(tp, sizeof tp, "%s.technologies", path);
    if (!json_is_array(techs) || json_array_size(techs) < 1 || json_array_size(techs) > 64)
        return cap_scene_bad(c, GS_EFORMAT, tp, "expected an array of 1 to 64 {bulb, weight, lumens}");
    size_t nt = json_array_size(techs);
    char tbulb[64][GS_ID_MAX];
    double tw[64], tlm[64], wsum = 0;
    for (size_t i = 0; i < nt; i++) {
        char ip[600];
        snprintf(ip, sizeof ip, "%s[%zu]", tp, i);
        json_t *t = json_array_get(techs, i);
        if (!json_is_object(t)) return cap_scene_bad(c, GS_EFORMAT, ip, "expected an object {bulb, weight, lumens}");
        if ((s = gs_json_check_keys(c->doc, t, ip, tkeys)) != GS_OK ||
            (s = gs_json_get_str(c->doc, t, ip, "bulb", 1, NULL, tbulb[i], GS_ID_MAX)) != GS_OK ||
            (s = gs_json_get_num(c->doc, t, ip, "weight", 0, 1, 0, 1e9, NULL, &tw[i])) != GS_OK ||
            (s = get_light_num(c, t, ip, "lumens", 1, 0, &tlm[i])) != GS_OK)
            return s;
        wsum += tw[i];
    }
    if (!(wsum > 0)) return cap_scene_bad(c, GS_EFORMAT, tp, "expected weights with a positive sum");

    double sr = sin(rot * M_PI / 180), crot = cos(rot * M_PI / 180);
    const double a = 6378137.0, f = 1.0 / 298.257223563, e2 = f * (2 - f);
    double la = lat0 * M_PI / 180, sl = sin(la);
    double Nr = a / sqrt(1 - e2 * sl * sl), Mr = a * (1 - e2) / pow(1 - e2 * sl * sl, 1.5);
    /* two families: direction 0 streets run along u (constant v), direction 1 along v */
    const long n_streets[2] = {(long)floor(size[1] / street) + 1, (long)floor(size[0] / street) + 1};
    const long n_lights[2] = {(long)floor(size[0] / spacing), (long)floor(size[1] / spacing)};
    /* every position is computed (and, in range, projected) before it is kept or dropped: the
     * positions, each a light if all are in range, must fit the budget as the lights would,
     * which bounds the time too (not only the lights kept) */
    double positions = (double)n_streets[0] * n_lights[0] + (double)n_streets[1] * n_lights[1];
    char what[200];
    snprintf(what, sizeof what, "a street grid of %.0f positions (size_m over street_spacing_m and "
             "light_spacing_m, both directions; %d B each when rendered)", positions,
             CAP_RENDER_BYTES_PER_LIGHT + (int)sizeof(cap_light));
    if (gs_mem_check(positions * (CAP_RENDER_BYTES_PER_LIGHT + sizeof(cap_light)), what) != GS_OK)
        return cap_scene_bad(c, GS_ELIMIT, path, "%s", gs_detail());
    size_t before = lv->n;
    for (int dir = 0; dir < 2; dir++) {
        double len = dir == 0 ? size[0] : size[1];
        for (long i = 0; i < n_streets[dir]; i++) {
            double across = -0.5 * (dir == 0 ? size[1] : size[0]) + (double)i * street;
            for (long j = 0; j < n_lights[dir]; j++) {
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
                if (s != GS_OK) return cap_scene_bad(c, GS_EFORMAT, path, "cannot project a light: %s", gs_detail());
                l.in_image = in_front && gis_in_image(&sc->cam, l.x_px, l.y_px);
                if (only && !l.in_image) continue;
                l.flux_e_per_cycle = cap_scene_flux_from_lumens(sc, l.lumens, l.distance_m);
                snprintf(l.id, sizeof l.id, "S%d-%zu", index, lv->n - before);
                if ((s = push_light(c, path, lv, &l)) != GS_OK) return s;
            }
        }
    }
    return GS_OK;
}

/* ------------------------------------------------------------------ unique ids */

typedef struct {
    const char *id;
    size_t n;   /* the light's index */
} light_id;

static int cmp_light_id(const void *a, const void *b)
{
    const light_id *x = a, *y = b;
    int c = strcmp(x->id, y->id);
    return c ? c : (x->n > y->n) - (x->n < y->n);
}

/* The item of lights that gives light n (first[i]: the index of item i's first light). */
static size_t item_of(const size_t *first, size_t n)
{
    size_t i = 0;
    while (first[i + 1] <= n) i++;
    return i;
}

static int is_block(json_t *lights, size_t i)
{
    return json_object_get(json_array_get(lights, i), "type") != NULL;
}

/* Light ids are unique in a scene (--drop-light, truth.json and the evaluation name a light by
 * its id): the first light whose id an earlier one has is refused, at its item of lights (the
 * id of an inline light, or the block that gives it). */
static gs_status check_unique_ids(const cap_pctx *c, json_t *lights, const light_vec *lv, const size_t *first)
{
    if (lv->n < 2) return GS_OK;
    light_id *r = malloc(lv->n * sizeof *r);
    if (!r) return gs_fail(GS_ENOMEM, "scene: out of memory for light ids");
    for (size_t k = 0; k < lv->n; k++) r[k] = (light_id){lv->v[k].id, k};
    qsort(r, lv->n, sizeof *r, cmp_light_id);
    size_t dup = SIZE_MAX, twin = 0;
    for (size_t k = 1, run = 0; k < lv->n; k++) {
        if (strcmp(r[k].id, r[run].id)) {
            run = k;
        } else if (r[k].n < dup) {
            dup = r[k].n;
            twin = r[run].n;
        }
    }
    free(r);
    if (dup == SIZE_MAX) return GS_OK;
    size_t i = item_of(first, dup), j = item_of(first, twin);
    char p[64], which[64] = "", other[80];
    snprintf(p, sizeof p, "lights[%zu]%s", i, is_block(lights, i) ? "" : ".id");
    if (is_block(lights, i)) snprintf(which, sizeof which, "light %zu's id ", dup - first[i]);
    if (is_block(lights, j)) snprintf(other, sizeof other, "light %zu of lights[%zu]", twin - first[j], j);
    else snprintf(other, sizeof other, "lights[%zu]", j);
    return cap_scene_bad(c, GS_EFORMAT, p, "%s\"%s\" is already the id of %s: expected an id that no "
                         "other light of the scene has", which, lv->v[dup].id, other);
}

gs_status cap_scene_parse_lights(const cap_pctx *c, cap_scene *sc, json_t *lights)
{
    if (!json_is_array(lights))
        return cap_scene_bad(c, GS_EFORMAT, "lights", "expected an array of lights and light sources "
                   "(required; [] for none)");
    light_vec lv = {NULL, 0, 0};
    size_t *first = malloc((json_array_size(lights) + 1) * sizeof *first);
    if (!first) return gs_fail(GS_ENOMEM, "scene: out of memory for lights");
    gs_status s = GS_OK;
    for (size_t i = 0; i < json_array_size(lights) && s == GS_OK; i++) {
        first[i] = lv.n;
        char p[64];
        snprintf(p, sizeof p, "lights[%zu]", i);
        json_t *o = json_array_get(lights, i);
        if (!json_is_object(o)) {
            s = cap_scene_bad(c, GS_EFORMAT, p, "expected an object");
            break;
        }
        json_t *type = json_object_get(o, "type");
        if (type) {
            const char *t = json_string_value(type);
            char tp[80];
            snprintf(tp, sizeof tp, "%s.type", p);
            if (t && !strcmp(t, "geojson")) s = parse_geojson(c, sc, o, p, &lv);
            else if (t && !strcmp(t, "street_grid")) s = parse_street_grid(c, sc, o, p, (int)i, &lv);
            else s = cap_scene_bad(c, GS_EFORMAT, tp, "expected \"geojson\" or \"street_grid\" (a light "
                         "source block), or no type (one light)");
        } else {
            cap_light l;
            s = parse_light(c, sc, o, p, (int)lv.n, &l);
            l.line = gs_json_line(c->doc, p);
            if (s == GS_OK) s = push_light(c, p, &lv, &l);
        }
        for (size_t j = 0; j < lv.n; j++)
            if (!lv.v[j].line) lv.v[j].line = gs_json_line(c->doc, p);
    }
    first[json_array_size(lights)] = lv.n;
    if (s == GS_OK) s = check_unique_ids(c, lights, &lv, first);
    free(first);
    if (s != GS_OK) {
        free(lv.v);
        return s;
    }
    sc->lights = lv.v;
    sc->n_lights = lv.n;
    return GS_OK;
}
