/* scene.c - scene files, format gridsurvey-scene/1 (docs/scene.md), read through the format kit:
 * the grid, camera and ACam sections here, the lights in scene_lights.c, each effect's
 * parameters through the effects table (effects.c, effect_params.c). Every error names the
 * file, the line and the field ("FILE:LINE: field PATH: expected ..."). */
#include "capture/sim.h"

#include <jansson.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------------------ parse context */

gs_status cap_scene_bad(const cap_pctx *c, gs_status s, const char *path, const char *fmt, ...)
{
    char msg[768];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    return gs_json_fail(c->doc, s, path, "%s", msg);
}

gs_status cap_scene_get_long(const cap_pctx *c, json_t *obj, const char *ppath, const char *key,
                          int required, long def, long lo, long hi, long *out)
{
    long long v;
    gs_status s = gs_json_get_int(c->doc, obj, ppath, key, required, def, lo, hi, NULL, &v);
    if (s == GS_OK) *out = (long)v;
    return s;
}

gs_status cap_scene_get_int(const cap_pctx *c, json_t *obj, const char *ppath, const char *key,
                         int required, int def, int lo, int hi, int *out)
{
    long v;
    gs_status s = cap_scene_get_long(c, obj, ppath, key, required, def, lo, hi, &v);
    if (s == GS_OK) *out = (int)v;
    return s;
}

void cap_scene_resolve(const cap_pctx *c, const char *rel, char *out, size_t cap)
{
    if (rel[0] == '/' || !c->base_dir || !c->base_dir[0]) snprintf(out, cap, "%s", rel);
    else snprintf(out, cap, "%s/%s", c->base_dir, rel);
}

/* ------------------------------------------------------------------ the scene */

static gs_status parse_freq(const cap_pctx *c, cap_scene *sc, json_t *g)
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
        cap_scene_resolve(c, rel, full, sizeof full);
        if (strlen(full) >= sizeof f->wav) return cap_scene_bad(c, GS_EFORMAT, "grid.frequency.wav", "path too long");
        memcpy(f->wav, full, strlen(full) + 1);
        return GS_OK;
    }
    return cap_scene_bad(c, GS_EFORMAT, "grid.frequency.model", "\"%s\": expected \"constant\", "
               "\"random_walk\" or \"trace\"", model);
}

static gs_status parse_camera(const cap_pctx *c, cap_scene *sc, json_t *root)
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
        (s = cap_scene_get_int(c, cam, "camera", "width_px", 1, 0, 1, 32768, &g->width_px)) != GS_OK ||
        (s = cap_scene_get_int(c, cam, "camera", "height_px", 1, 0, 1, 32768, &g->height_px)) != GS_OK ||
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
    if ((s = cap_scene_get_int(c, sen, S, "bands", 0, 3, 1, 3, &sc->bands)) != GS_OK ||
        (s = cap_scene_get_int(c, sen, S, "bit_depth", 0, 12, 8, 16, &sc->bit_depth)) != GS_OK ||
        (s = gs_json_get_num(c->doc, sen, S, "full_well_e", 0, 20000, 1, 1e9, NULL, &sc->full_well_e)) != GS_OK ||
        (s = gs_json_get_num(c->doc, sen, S, "read_noise_e", 0, 3, 0, 1e6, NULL, &sc->read_noise_e)) != GS_OK ||
        (s = gs_json_get_num(c->doc, sen, S, "qe", 0, 0.6, 1e-6, 1, NULL, &sc->qe)) != GS_OK ||
        (s = gs_json_get_num(c->doc, sen, S, "gain_e_per_dn", 0, 5, 1e-3, 1e6, NULL, &sc->gain_e_per_dn)) != GS_OK ||
        (s = gs_json_get_num(c->doc, sen, S, "black_level_dn", 0, 0, 0, 60000, NULL, &sc->black_level_dn)) != GS_OK)
        return s;
    if (sc->bands == 2) return cap_scene_bad(c, GS_EFORMAT, "camera.sensor.bands", "2: expected 1 or 3");
    if (sc->black_level_dn >= (double)(1 << sc->bit_depth) - 1)
        return cap_scene_bad(c, GS_EFORMAT, "camera.sensor.black_level_dn", "%g: expected below the ADC's "
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
    if (s != GS_OK) return cap_scene_bad(c, GS_EFORMAT, "camera", "%s", gs_detail());
    return GS_OK;
}

static gs_status parse_acam(const cap_pctx *c, cap_scene *sc, json_t *root)
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
        (s = cap_scene_get_int(c, a, "acam", "K", 1, 0, 2, 1024, &q->K)) != GS_OK ||
        (s = cap_scene_get_long(c, a, "acam", "cycles", 1, 0, 1, CAP_MAX_CYCLES, &q->cycles)) != GS_OK ||
        (s = gs_json_get_bool(c->doc, a, "acam", "locked", 0, 1, &sc->locked)) != GS_OK ||
        (s = cap_scene_get_int(c, a, "acam", "masks", 0, 2, 2, 1000, &q->masks)) != GS_OK ||
        (s = gs_json_get_num(c->doc, a, "acam", "dmd_min_hold_us", 0, CAP_DMD_MIN_HOLD_US, 1, 1e5, NULL, &q->dmd_min_hold_us)) != GS_OK ||
        (s = gs_json_get_str(c->doc, a, "acam", "free_running_period", 0, "nominal", per, sizeof per)) != GS_OK ||
        (s = cap_scene_get_long(c, a, "acam", "readout_cycles", 0, 10, 0, 1000000, &sc->readout_cycles)) != GS_OK)
        return s;
    if (!strcmp(per, "measured")) sc->free_period_measured = 1;
    else if (strcmp(per, "nominal"))
        return cap_scene_bad(c, GS_EFORMAT, "acam.free_running_period", "\"%s\": expected \"nominal\" or "
                   "\"measured\"", per);
    if (sc->locked && json_object_get(a, "free_running_period"))
        return cap_scene_bad(c, GS_EFORMAT, "acam.free_running_period", "\"%s\" is the period of a "
                             "free-running ACam: expected acam.locked false (a locked one re-anchors "
                             "every window at its crossing)", per);
    json_t *h = json_object_get(a, "hdr");
    if (json_is_boolean(h)) q->hdr = json_is_true(h);
    else if (json_is_object(h)) {
        if ((s = gs_json_check_keys(c->doc, h, "acam.hdr", hkeys)) != GS_OK ||
            (s = gs_json_get_bool(c->doc, h, "acam.hdr", "enabled", 0, 1, &q->hdr)) != GS_OK ||
            (s = cap_scene_get_int(c, h, "acam.hdr", "max_rounds", 0, 0, 0, 16, &q->hdr_max_rounds)) != GS_OK ||
            (s = cap_scene_get_int(c, h, "acam.hdr", "max_saturated_px", 0, 0, 0, 1 << 30, &q->hdr_max_saturated_px)) != GS_OK)
            return s;
    } else if (h) {
        return cap_scene_bad(c, GS_EFORMAT, "acam.hdr", "expected true, false or {enabled, max_rounds, "
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
    cap_pctx c = {doc, base_dir};
    json_t *root = gs_json_root(doc);
    char fmt[64];
    long seed;
    json_t *grid, *effects;
    sc->fingerprint = cap_fnv1a(CAP_FNV_INIT, text, strlen(text));
    if (!json_is_object(root)) {
        s = cap_scene_bad(&c, GS_EFORMAT, "(top level)", "expected a JSON object");
        goto done;
    }
    if ((s = gs_json_check_keys(c.doc, root, "", keys)) != GS_OK ||
        (s = gs_json_get_str(c.doc, root, "", "format", 1, NULL, fmt, sizeof fmt)) != GS_OK)
        goto done;
    if (strcmp(fmt, CAP_SCENE_FORMAT)) {
        s = cap_scene_bad(&c, GS_EFORMAT, "format", "\"%s\": expected \"%s\"", fmt, CAP_SCENE_FORMAT);
        goto done;
    }
    if ((s = gs_json_get_str(c.doc, root, "", "name", 0, "", sc->name, sizeof sc->name)) != GS_OK ||
        (s = cap_scene_get_long(&c, root, "", "seed", 0, 1, 0, 0x7fffffffL, &seed)) != GS_OK ||
        (s = gs_json_get_str(c.doc, root, "", "utc", 0, "", sc->utc, sizeof sc->utc)) != GS_OK)
        goto done;
    sc->seed = (unsigned long long)seed;
    if (sc->utc[0] && !gs_capture_valid_utc(sc->utc)) {
        s = cap_scene_bad(&c, GS_EFORMAT, "utc", "\"%s\": expected " GS_CAPTURE_EXP_UTC, sc->utc);
        goto done;
    }
    if (json_object_get(root, "delight")) {
        char rel[CAP_PATH_MAX];
        if ((s = gs_json_get_str(c.doc, root, "", "delight", 1, NULL, rel, sizeof rel)) != GS_OK) goto done;
        char full[CAP_PATH_MAX * 2];
        cap_scene_resolve(&c, rel, full, sizeof full);
        if (strlen(full) >= sizeof sc->delight) {
            s = cap_scene_bad(&c, GS_EFORMAT, "delight", "path too long");
            goto done;
        }
        memcpy(sc->delight, full, strlen(full) + 1);
    }
    /* grid */
    if ((s = gs_json_get_obj(c.doc, root, "", "grid", 1, &grid)) != GS_OK ||
        (s = gs_json_check_keys(c.doc, grid, "grid", gkeys)) != GS_OK ||
        (s = cap_scene_get_int(&c, grid, "grid", "nominal_hz", 1, 0, 50, 60, &sc->grid_hz)) != GS_OK ||
        (s = gs_json_get_num(c.doc, grid, "grid", "transformer_deg", 0, 30, -180, 180, NULL, &sc->transformer_deg)) != GS_OK)
        goto done;
    if (sc->grid_hz != 50 && sc->grid_hz != 60) {
        s = cap_scene_bad(&c, GS_EFORMAT, "grid.nominal_hz", "%d: expected 50 or 60", sc->grid_hz);
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
                    snprintf(list + u, sizeof list - u, "%s%s", i ? ", " : "", cap_effect_name((cap_effect)i));
                }
                s = cap_scene_bad(&c, GS_EFORMAT, p, "unknown effect; expected one of: %s", list);
                goto done;
            }
            if (!json_is_object(v)) {
                s = cap_scene_bad(&c, GS_EFORMAT, p, "expected an object of parameters ({} for none)");
                goto done;
            }
            sc->fx.enabled |= 1u << e;
            if ((s = cap_effect_defs[e].parse(c.doc, sc, v, p)) != GS_OK) goto done;
        }
    }
    if (!(sc->fx.enabled & (1u << CAP_FX_READ_NOISE))) sc->fx.read_noise.sigma_e = 0;
    /* consistency between the grid, the ACam and the effects */
    int wander = (sc->fx.enabled >> CAP_FX_FREQUENCY_WANDER) & 1;
    if (!wander && (sc->freq.model != CAP_FREQ_CONSTANT || sc->freq.hz != sc->grid_hz)) {
        s = cap_scene_bad(&c, GS_EFORMAT, "grid.frequency", "a grid that deviates from nominal_hz is "
                "simulated only when effects lists frequency_wander (add it, or use model "
                "\"constant\" at the nominal frequency)");
        goto done;
    }
    if ((sc->fx.enabled >> CAP_FX_FREE_RUNNING_DRIFT) & 1 && sc->locked) {
        s = cap_scene_bad(&c, GS_EFORMAT, "effects.free_running_drift", "expected acam.locked false: a "
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
        s = cap_scene_bad(&c, s, acam_field(detail), "%s", detail);
        goto done;
    }
    s = cap_scene_parse_lights(&c, sc, json_object_get(root, "lights"));
done:
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
    free(sc->fx.transport.boxes);
    memset(sc, 0, sizeof *sc);
}
