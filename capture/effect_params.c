/* effect_params.c - each effect's parameters in a scene's "effects" object (docs/scene.md): one
 * parse function per effect, called through the effects table (effects.c) only for the effects
 * a scene lists. Ranges and defaults are those of docs/scene.md. */
#include "capture/sim.h"

#include <stdlib.h>
#include <string.h>

static const char *const no_keys[] = {NULL};

/* An optional "chroma" array of `bands` non-negative weights, normalised to sum 1 (default
 * equal). */
static gs_status parse_chroma(const gs_json *j, json_t *o, const char *path, int bands, double *q)
{
    for (int b = 0; b < 3; b++) q[b] = 1.0 / bands;
    if (!json_object_get(o, "chroma")) return GS_OK;
    double v[3];
    gs_status s = gs_json_get_num_array(j, o, path, "chroma", (size_t)bands, 3, 0, 1e6, v, NULL);
    if (s != GS_OK) return s;
    double sum = 0;
    for (int b = 0; b < bands; b++) sum += v[b];
    char p[560];
    snprintf(p, sizeof p, "%s.chroma", path);
    if (!(sum > 0)) return gs_json_fail(j, GS_EFORMAT, p, "expected a positive sum");
    for (int b = 0; b < bands; b++) q[b] = v[b] / sum;
    return GS_OK;
}

gs_status cap_fxp_none(const gs_json *j, cap_scene *sc, json_t *o, const char *path)
{
    (void)sc;
    return gs_json_check_keys(j, o, path, no_keys);
}

gs_status cap_fxp_free_running_drift(const gs_json *j, cap_scene *sc, json_t *o, const char *path)
{
    static const char *const k[] = {"clock_ppm", NULL};
    gs_status s = gs_json_check_keys(j, o, path, k);
    if (s != GS_OK) return s;
    return gs_json_get_num(j, o, path, "clock_ppm", 0, 0, -1000, 1000, NULL, &sc->fx.drift.clock_ppm);
}

gs_status cap_fxp_dmd_jitter(const gs_json *j, cap_scene *sc, json_t *o, const char *path)
{
    static const char *const k[] = {"sigma_us", NULL};
    gs_status s = gs_json_check_keys(j, o, path, k);
    if (s != GS_OK) return s;
    return gs_json_get_num(j, o, path, "sigma_us", 1, 0, 0, 1000, NULL, &sc->fx.jitter.sigma_us);
}

gs_status cap_fxp_extinction(const gs_json *j, cap_scene *sc, json_t *o, const char *path)
{
    static const char *const k[] = {"visibility_km", "angstrom_exponent", "wavelengths_nm", NULL};
    cap_effects *fx = &sc->fx;
    gs_status s;
    if ((s = gs_json_check_keys(j, o, path, k)) != GS_OK ||
        (s = gs_json_get_num(j, o, path, "visibility_km", 1, 0, 0.01, 1000, NULL,
                             &fx->extinction.visibility_km)) != GS_OK ||
        (s = gs_json_get_num(j, o, path, "angstrom_exponent", 0, 1.3, 0, 4, NULL,
                             &fx->extinction.angstrom)) != GS_OK)
        return s;
    if (sc->bands == 3) {
        fx->extinction.wavelength_nm[0] = 650;
        fx->extinction.wavelength_nm[1] = 550;
        fx->extinction.wavelength_nm[2] = 450;
    } else {
        fx->extinction.wavelength_nm[0] = 550;
    }
    if (json_object_get(o, "wavelengths_nm"))
        s = gs_json_get_num_array(j, o, path, "wavelengths_nm", (size_t)sc->bands, 3, 200, 2000,
                                  fx->extinction.wavelength_nm, NULL);
    return s;
}

gs_status cap_fxp_scintillation(const gs_json *j, cap_scene *sc, json_t *o, const char *path)
{
    static const char *const k[] = {"cn2", "wavelength_nm", "crosswind_m_s", "source_size_m",
                                    "aperture_averaging", "intensity_variance", NULL};
    cap_effects *fx = &sc->fx;
    gs_status s;
    if ((s = gs_json_check_keys(j, o, path, k)) != GS_OK ||
        (s = gs_json_get_num(j, o, path, "cn2", 0, 1e-14, 0, 1e-10, NULL, &fx->scint.cn2)) != GS_OK ||
        (s = gs_json_get_num(j, o, path, "wavelength_nm", 0, 550, 200, 2000, NULL,
                             &fx->scint.wavelength_nm)) != GS_OK ||
        (s = gs_json_get_num(j, o, path, "crosswind_m_s", 0, 2, 0.01, 100, NULL,
                             &fx->scint.crosswind_m_s)) != GS_OK ||
        (s = gs_json_get_num(j, o, path, "source_size_m", 0, 0, 0, 100, NULL,
                             &fx->scint.source_size_m)) != GS_OK ||
        (s = gs_json_get_bool(j, o, path, "aperture_averaging", 0, 1, &fx->scint.aperture)) != GS_OK ||
        (s = gs_json_get_num(j, o, path, "intensity_variance", 0, -1, 0, 100, NULL,
                             &fx->scint.sigma2)) != GS_OK)
        return s;
    return GS_OK;
}

gs_status cap_fxp_psf(const gs_json *j, cap_scene *sc, json_t *o, const char *path)
{
    static const char *const k[] = {"model", "sigma_px", "radius_sigma", NULL};
    cap_effects *fx = &sc->fx;
    char model[32];
    gs_status s;
    if ((s = gs_json_check_keys(j, o, path, k)) != GS_OK ||
        (s = gs_json_get_str(j, o, path, "model", 0, "gaussian", model, sizeof model)) != GS_OK ||
        (s = gs_json_get_num(j, o, path, "sigma_px", 1, 0, 0.05, 50, NULL, &fx->psf.sigma_px)) != GS_OK ||
        (s = gs_json_get_num(j, o, path, "radius_sigma", 0, 4, 2, 8, NULL, &fx->psf.radius_sigma)) != GS_OK)
        return s;
    if (strcmp(model, "gaussian")) {
        char p[560];
        snprintf(p, sizeof p, "%s.model", path);
        return gs_json_fail(j, GS_EFORMAT, p, "\"%s\": expected \"gaussian\"", model);
    }
    return GS_OK;
}

gs_status cap_fxp_skyglow(const gs_json *j, cap_scene *sc, json_t *o, const char *path)
{
    static const char *const k[] = {"fraction", "scale_px", "radius_scale", "flicker", NULL};
    cap_effects *fx = &sc->fx;
    char fl[16];
    gs_status s;
    if ((s = gs_json_check_keys(j, o, path, k)) != GS_OK ||
        (s = gs_json_get_num(j, o, path, "fraction", 1, 0, 0, 10, NULL, &fx->skyglow.fraction)) != GS_OK ||
        (s = gs_json_get_num(j, o, path, "scale_px", 1, 0, 0.2, 200, NULL, &fx->skyglow.scale_px)) != GS_OK ||
        (s = gs_json_get_num(j, o, path, "radius_scale", 0, 5, 1, 20, NULL,
                             &fx->skyglow.radius_scale)) != GS_OK ||
        (s = gs_json_get_str(j, o, path, "flicker", 0, "flat", fl, sizeof fl)) != GS_OK)
        return s;
    if (!strcmp(fl, "flat")) fx->skyglow.flicker = CAP_GLOW_FLAT;
    else if (!strcmp(fl, "same")) fx->skyglow.flicker = CAP_GLOW_SAME;
    else if (!strcmp(fl, "mixed")) fx->skyglow.flicker = CAP_GLOW_MIXED;
    else {
        char p[560];
        snprintf(p, sizeof p, "%s.flicker", path);
        return gs_json_fail(j, GS_EFORMAT, p, "\"%s\": expected \"flat\", \"same\" or \"mixed\"", fl);
    }
    return GS_OK;
}

/* The array member key of o holding 1 to 10000 objects, allocated as *items of `size` bytes
 * each (owned by the scene); its path in p. */
static gs_status object_array(const gs_json *j, json_t *o, const char *path, const char *key,
                              const char *what, size_t size, void **items, size_t *count,
                              char *p, size_t cap)
{
    json_t *arr = json_object_get(o, key);
    snprintf(p, cap, "%s.%s", path, key);
    if (!json_is_array(arr) || json_array_size(arr) < 1 || json_array_size(arr) > 10000)
        return gs_json_fail(j, GS_EFORMAT, p, "expected an array of 1 to 10000 %s", what);
    size_t n = json_array_size(arr);
    *items = calloc(n, size);
    if (!*items) return gs_fail(GS_ENOMEM, "scene: out of memory");
    *count = n;
    return GS_OK;
}

gs_status cap_fxp_blinking_sign(const gs_json *j, cap_scene *sc, json_t *o, const char *path)
{
    static const char *const k[] = {"signs", NULL};
    static const char *const sk[] = {"x_px", "y_px", "width_px", "height_px", "period_s",
                                     "duty", "phase_s", "flux_e_per_cycle", "chroma", NULL};
    cap_effects *fx = &sc->fx;
    char p[560];
    gs_status s = gs_json_check_keys(j, o, path, k);
    if (s != GS_OK ||
        (s = object_array(j, o, path, "signs", "signs", sizeof *fx->signs.items,
                          (void **)&fx->signs.items, &fx->signs.count, p, sizeof p)) != GS_OK)
        return s;
    json_t *arr = json_object_get(o, "signs");
    for (size_t i = 0; i < fx->signs.count; i++) {
        char ip[600];
        snprintf(ip, sizeof ip, "%s[%zu]", p, i);
        json_t *so = json_array_get(arr, i);
        cap_sign *g = &fx->signs.items[i];
        if (!json_is_object(so)) return gs_json_fail(j, GS_EFORMAT, ip, "expected an object");
        if ((s = gs_json_check_keys(j, so, ip, sk)) != GS_OK ||
            (s = gs_json_get_num(j, so, ip, "x_px", 1, 0, -1e5, 1e5, NULL, &g->x_px)) != GS_OK ||
            (s = gs_json_get_num(j, so, ip, "y_px", 1, 0, -1e5, 1e5, NULL, &g->y_px)) != GS_OK ||
            (s = gs_json_get_num(j, so, ip, "width_px", 0, 1, 1, 1e4, NULL, &g->width_px)) != GS_OK ||
            (s = gs_json_get_num(j, so, ip, "height_px", 0, 1, 1, 1e4, NULL, &g->height_px)) != GS_OK ||
            (s = gs_json_get_num(j, so, ip, "period_s", 1, 0, 1e-3, 1e5, NULL, &g->period_s)) != GS_OK ||
            (s = gs_json_get_num(j, so, ip, "duty", 0, 0.5, 0, 1, NULL, &g->duty)) != GS_OK ||
            (s = gs_json_get_num(j, so, ip, "phase_s", 0, 0, -1e6, 1e6, NULL, &g->phase_s)) != GS_OK ||
            (s = gs_json_get_num(j, so, ip, "flux_e_per_cycle", 1, 0, 0, 1e15, NULL,
                                 &g->flux_e_per_cycle)) != GS_OK ||
            (s = parse_chroma(j, so, ip, sc->bands, g->chroma)) != GS_OK)
            return s;
    }
    return GS_OK;
}

gs_status cap_fxp_headlights(const gs_json *j, cap_scene *sc, json_t *o, const char *path)
{
    static const char *const k[] = {"cars", NULL};
    static const char *const ck[] = {"from", "to", "speed_px_s", "period_s", "offset_s",
                                     "flux_e_per_cycle", "chroma", NULL};
    cap_effects *fx = &sc->fx;
    char p[560];
    gs_status s = gs_json_check_keys(j, o, path, k);
    if (s != GS_OK ||
        (s = object_array(j, o, path, "cars", "cars", sizeof *fx->cars.items,
                          (void **)&fx->cars.items, &fx->cars.count, p, sizeof p)) != GS_OK)
        return s;
    json_t *arr = json_object_get(o, "cars");
    for (size_t i = 0; i < fx->cars.count; i++) {
        char ip[600];
        snprintf(ip, sizeof ip, "%s[%zu]", p, i);
        json_t *co = json_array_get(arr, i);
        cap_car *g = &fx->cars.items[i];
        double from[2], to[2];
        if (!json_is_object(co)) return gs_json_fail(j, GS_EFORMAT, ip, "expected an object");
        if ((s = gs_json_check_keys(j, co, ip, ck)) != GS_OK ||
            (s = gs_json_get_num_array(j, co, ip, "from", 2, 2, -1e5, 1e5, from, NULL)) != GS_OK ||
            (s = gs_json_get_num_array(j, co, ip, "to", 2, 2, -1e5, 1e5, to, NULL)) != GS_OK ||
            (s = gs_json_get_num(j, co, ip, "speed_px_s", 1, 0, 1e-3, 1e6, NULL, &g->speed_px_s)) != GS_OK ||
            (s = gs_json_get_num(j, co, ip, "period_s", 1, 0, 1e-2, 1e5, NULL, &g->period_s)) != GS_OK ||
            (s = gs_json_get_num(j, co, ip, "offset_s", 0, 0, -1e6, 1e6, NULL, &g->offset_s)) != GS_OK ||
            (s = gs_json_get_num(j, co, ip, "flux_e_per_cycle", 1, 0, 0, 1e15, NULL,
                                 &g->flux_e_per_cycle)) != GS_OK ||
            (s = parse_chroma(j, co, ip, sc->bands, g->chroma)) != GS_OK)
            return s;
        g->x0_px = from[0];
        g->y0_px = from[1];
        g->x1_px = to[0];
        g->y1_px = to[1];
    }
    return GS_OK;
}

gs_status cap_fxp_ambient(const gs_json *j, cap_scene *sc, json_t *o, const char *path)
{
    static const char *const k[] = {"e_per_px_cycle", "top", "bottom", "chroma", NULL};
    cap_effects *fx = &sc->fx;
    gs_status s;
    if ((s = gs_json_check_keys(j, o, path, k)) != GS_OK ||
        (s = gs_json_get_num(j, o, path, "e_per_px_cycle", 1, 0, 0, 1e9, NULL,
                             &fx->ambient.e_per_px_cycle)) != GS_OK ||
        (s = gs_json_get_num(j, o, path, "top", 0, 1, 0, 1e3, NULL, &fx->ambient.top)) != GS_OK ||
        (s = gs_json_get_num(j, o, path, "bottom", 0, 1, 0, 1e3, NULL, &fx->ambient.bottom)) != GS_OK ||
        (s = parse_chroma(j, o, path, sc->bands, fx->ambient.chroma)) != GS_OK)
        return s;
    return GS_OK;
}

gs_status cap_fxp_read_noise(const gs_json *j, cap_scene *sc, json_t *o, const char *path)
{
    static const char *const k[] = {"sigma_e", NULL};
    gs_status s = gs_json_check_keys(j, o, path, k);
    if (s != GS_OK) return s;
    return gs_json_get_num(j, o, path, "sigma_e", 0, sc->read_noise_e, 0, 1e6, NULL,
                           &sc->fx.read_noise.sigma_e);
}

/* An array member key of o holding exactly 3 numbers in [lo, hi] into v (def when absent). */
static gs_status get3(const gs_json *j, json_t *o, const char *path, const char *key, double lo,
                      double hi, const double *def, double *v)
{
    if (!json_object_get(o, key)) {
        for (int i = 0; i < 3; i++) v[i] = def[i];
        return GS_OK;
    }
    return gs_json_get_num_array(j, o, path, key, 3, 3, lo, hi, v, NULL);
}

/* An albedo: 1 number (grey) or `bands` numbers in [0, 1]. */
static gs_status get_albedo(const gs_json *j, json_t *o, const char *path, int bands, double def,
                            double *v)
{
    for (int b = 0; b < 3; b++) v[b] = def;
    json_t *a = json_object_get(o, "albedo");
    if (!a) return GS_OK;
    if (json_is_number(a)) {
        double x;
        gs_status s = gs_json_get_num(j, o, path, "albedo", 1, 0, 0, 1, NULL, &x);
        for (int b = 0; b < 3; b++) v[b] = x;
        return s;
    }
    return gs_json_get_num_array(j, o, path, "albedo", (size_t)bands, 3, 0, 1, v, NULL);
}

gs_status cap_fxp_light_transport(const gs_json *j, cap_scene *sc, json_t *o, const char *path)
{
    static const char *const k[] = {"room", "boxes", "daylight", "lamp_shade", NULL};
    static const char *const sk[] = {"radius_px", "transmission", NULL};
    static const char *const rk[] = {"width_m", "height_m", "depth_m", "floor_m", "albedo",
                                     "checker_m", "contrast", NULL};
    static const char *const bk[] = {"min_m", "max_m", "albedo", NULL};
    static const char *const dk[] = {"e_per_px_cycle", "chroma", NULL};
    cap_effects *fx = &sc->fx;
    char p[560];
    json_t *room = NULL, *day = NULL;
    gs_status s = gs_json_check_keys(j, o, path, k);
    snprintf(p, sizeof p, "%s.room", path);
    if (s != GS_OK || (s = gs_json_get_obj(j, o, path, "room", 1, &room)) != GS_OK ||
        (s = gs_json_check_keys(j, room, p, rk)) != GS_OK ||
        (s = gs_json_get_num(j, room, p, "width_m", 1, 0, 0.1, 1e5, NULL, &fx->transport.width_m)) != GS_OK ||
        (s = gs_json_get_num(j, room, p, "height_m", 1, 0, 0.1, 1e5, NULL, &fx->transport.height_m)) != GS_OK ||
        (s = gs_json_get_num(j, room, p, "depth_m", 1, 0, 0.1, 1e5, NULL, &fx->transport.depth_m)) != GS_OK ||
        (s = gs_json_get_num(j, room, p, "floor_m", 0, 0.5 * fx->transport.height_m, 0,
                             fx->transport.height_m, NULL, &fx->transport.floor_m)) != GS_OK ||
        (s = get_albedo(j, room, p, sc->bands, 0.7, fx->transport.albedo)) != GS_OK ||
        (s = gs_json_get_num(j, room, p, "checker_m", 0, 0, 0, 100, NULL, &fx->transport.checker_m)) != GS_OK ||
        (s = gs_json_get_num(j, room, p, "contrast", 0, 0.5, 0, 1.9, NULL, &fx->transport.contrast)) != GS_OK)
        return s;
    if (sc->bands == 1)
        for (int b = 1; b < 3; b++) fx->transport.albedo[b] = fx->transport.albedo[0];
    if (json_object_get(o, "boxes")) {
        if ((s = object_array(j, o, path, "boxes", "boxes", sizeof *fx->transport.boxes,
                              (void **)&fx->transport.boxes, &fx->transport.n_boxes, p, sizeof p)) != GS_OK)
            return s;
        json_t *arr = json_object_get(o, "boxes");
        for (size_t i = 0; i < fx->transport.n_boxes; i++) {
            char ip[600];
            snprintf(ip, sizeof ip, "%s[%zu]", p, i);
            json_t *bo = json_array_get(arr, i);
            cap_box *bx = &fx->transport.boxes[i];
            static const double zero[3] = {0, 0, 0};
            if (!json_is_object(bo)) return gs_json_fail(j, GS_EFORMAT, ip, "expected an object");
            if ((s = gs_json_check_keys(j, bo, ip, bk)) != GS_OK ||
                (s = gs_json_get_num_array(j, bo, ip, "min_m", 3, 3, -1e5, 1e5, bx->min_m, NULL)) != GS_OK ||
                (s = get3(j, bo, ip, "max_m", -1e5, 1e5, zero, bx->max_m)) != GS_OK ||
                (s = get_albedo(j, bo, ip, sc->bands, 0.5, bx->albedo)) != GS_OK)
                return s;
            if (!json_object_get(bo, "max_m"))
                return gs_json_fail(j, GS_EFORMAT, ip, "field max_m: expected 3 numbers (the field is missing)");
            for (int a = 0; a < 3; a++)
                if (!(bx->max_m[a] > bx->min_m[a])) {
                    char mp[640];
                    snprintf(mp, sizeof mp, "%s.max_m", ip);
                    return gs_json_fail(j, GS_EFORMAT, mp, "expected each coordinate above min_m's");
                }
            if (sc->bands == 1) bx->albedo[1] = bx->albedo[2] = bx->albedo[0];
        }
    }
    json_t *shade = NULL;
    if ((s = gs_json_get_obj(j, o, path, "lamp_shade", 0, &shade)) != GS_OK) return s;
    if (shade) {
        snprintf(p, sizeof p, "%s.lamp_shade", path);
        if ((s = gs_json_check_keys(j, shade, p, sk)) != GS_OK ||
            (s = gs_json_get_num(j, shade, p, "radius_px", 1, 0, 0.5, 64, NULL,
                                 &fx->transport.shade_radius_px)) != GS_OK ||
            (s = gs_json_get_num(j, shade, p, "transmission", 1, 0, 0, 1, NULL,
                                 &fx->transport.shade_transmission)) != GS_OK)
            return s;
    }
    if ((s = gs_json_get_obj(j, o, path, "daylight", 0, &day)) != GS_OK || !day) return s;
    snprintf(p, sizeof p, "%s.daylight", path);
    if ((s = gs_json_check_keys(j, day, p, dk)) != GS_OK ||
        (s = gs_json_get_num(j, day, p, "e_per_px_cycle", 1, 0, 0, 1e9, NULL, &fx->transport.daylight_e)) != GS_OK ||
        (s = parse_chroma(j, day, p, sc->bands, fx->transport.daylight_chroma)) != GS_OK)
        return s;
    return GS_OK;
}

gs_status cap_fxp_semi_reflection(const gs_json *j, cap_scene *sc, json_t *o, const char *path)
{
    static const char *const k[] = {"reflectance", "outdoor_e_per_px_cycle", "chroma", NULL};
    cap_effects *fx = &sc->fx;
    gs_status s;
    if ((s = gs_json_check_keys(j, o, path, k)) != GS_OK ||
        (s = gs_json_get_num(j, o, path, "reflectance", 1, 0, 0, 1, NULL, &fx->window.reflectance)) != GS_OK ||
        (s = gs_json_get_num(j, o, path, "outdoor_e_per_px_cycle", 1, 0, 0, 1e9, NULL,
                             &fx->window.e_per_px_cycle)) != GS_OK ||
        (s = parse_chroma(j, o, path, sc->bands, fx->window.chroma)) != GS_OK)
        return s;
    return GS_OK;
}
