/* backend_sim.c - the `sim` backend: acquisitions rendered from a scene (sim.c). */
#include "capture/sim.h"

#include <jansson.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

typedef struct {
    cap_sim *sim;
    char *station_json;
    cap_acq_timing timing;      /* of the last acquisition */
} sim_backend;

static gs_status sim_info(void *self, cap_acq_info *info)
{
    sim_backend *b = self;
    const cap_sim *s = b->sim;
    const cap_scene *sc = &s->sc;
    memset(info, 0, sizeof *info);
    info->grid_hz = sc->grid_hz;
    info->K = s->K;
    info->bands = s->B;
    info->width = s->W;
    info->height = s->H;
    info->cycles = s->C;
    info->masks = s->M;
    info->max_halvings = s->hmax;
    info->hdr = sc->acam.hdr;
    info->hdr_max_rounds = s->hmax;
    info->hdr_max_saturated_px = sc->acam.hdr_max_saturated_px;
    info->saturation_dn = s->sat_dn;
    info->black_level_dn = sc->black_level_dn;
    info->gain_e_per_dn = (s->fx >> CAP_FX_SHOT_NOISE) & 1u ? sc->gain_e_per_dn : 0.0;
    info->read_noise_dn = s->read_dn;
    info->locked = sc->locked;
    info->window_period = sc->locked ? GS_PERIOD_UNKNOWN : sc->free_period_measured ? GS_PERIOD_MEASURED : GS_PERIOD_NOMINAL;
    snprintf(info->utc, sizeof info->utc, "%s", sc->utc);
    info->station_json = b->station_json;
    /* the scene text (and its GeoJSON files), the seed and the DELIGHT file */
    info->fingerprint = cap_fnv1a(sc->fingerprint, &sc->seed, sizeof sc->seed);
    info->fingerprint = cap_fnv1a(info->fingerprint, sc->delight, strlen(sc->delight));
    /* the lights rendered (a caller may drop some of the scene's) */
    info->fingerprint = cap_fnv1a(info->fingerprint, &sc->n_lights, sizeof sc->n_lights);
    for (size_t i = 0; i < sc->n_lights; i++)
        info->fingerprint = cap_fnv1a(info->fingerprint, sc->lights[i].id, strlen(sc->lights[i].id));
    return GS_OK;
}

static gs_status sim_acquire(void *self, const cap_acquisition *a, unsigned char *halvings,
                             unsigned short *raw, double *cycles)
{
    sim_backend *b = self;
    b->timing.grid_hz_measured = b->timing.start_s = b->timing.window_half_period_s = NAN;
    b->timing.window_drift_windows = NAN;
    b->timing.probed = 0;
    if (cycles) *cycles = (double)b->sim->C;
    gs_status st = cap_sim_render_hdr(b->sim, a->k, a->pass, a->index, halvings, raw, a->probe,
                                      a->max_saturated_px, &b->timing.probed);
    if (st != GS_OK) return st;
    /* the exposure's crossings on the sim's timeline: f = C / (2 (t_end - t_start)) (Eq. 1),
     * its start from the capture's first exposure (index 0) */
    double t0, t1, origin, unused;
    if ((st = cap_sim_exposure_span(b->sim, a->index, &t0, &t1)) != GS_OK ||
        (st = cap_sim_exposure_span(b->sim, 0, &origin, &unused)) != GS_OK ||
        (st = cap_sim_window_timing(b->sim, a->index, &b->timing.window_half_period_s,
                                    &b->timing.window_drift_windows)) != GS_OK)
        return st;
    if (t1 > t0) b->timing.grid_hz_measured = (double)b->sim->C / (2.0 * (t1 - t0));
    b->timing.start_s = t0 - origin;
    return GS_OK;
}

static gs_status sim_timing(void *self, cap_acq_timing *t)
{
    *t = ((sim_backend *)self)->timing;
    return GS_OK;
}

static void sim_free(void *self)
{
    sim_backend *b = self;
    if (!b) return;
    cap_sim_free(b->sim);
    free(b->station_json);
    free(b);
}

static const cap_backend_ops sim_ops = {"sim", sim_info, sim_acquire, sim_free,
                                         sim_timing};

/* The camera as a gridsurvey-station/1 object (docs/gis.md), for capture.json: its pose is
 * exact (no pose sigmas) and its PSF the psf effect's (0 without it: a point in one pixel). */
static char *station_text(const cap_sim *sim)
{
    const cap_scene *sc = &sim->sc;
    if (!sc->has_station) return NULL;
    const gis_camera *c = &sc->cam;
    json_t *o = json_object();
    if (!o) return NULL;
    json_object_set_new(o, "format", json_string(GIS_STATION_FORMAT));
    if (sc->name[0]) json_object_set_new(o, "id", json_string(sc->name));
    json_object_set_new(o, "lat_deg", json_real(c->lat_deg));
    json_object_set_new(o, "lon_deg", json_real(c->lon_deg));
    json_object_set_new(o, "height_m", json_real(c->height_m));
    json_object_set_new(o, "heading_deg", json_real(c->heading_deg));
    json_object_set_new(o, "pitch_deg", json_real(c->pitch_deg));
    json_object_set_new(o, "roll_deg", json_real(c->roll_deg));
    json_object_set_new(o, "focal_px", json_real(c->focal_px));
    json_object_set_new(o, "cx_px", json_real(c->cx_px));
    json_object_set_new(o, "cy_px", json_real(c->cy_px));
    json_object_set_new(o, "k1", json_real(c->k1));
    json_object_set_new(o, "k2", json_real(c->k2));
    json_object_set_new(o, "width_px", json_integer(c->width_px));
    json_object_set_new(o, "height_px", json_integer(c->height_px));
    json_object_set_new(o, "refraction_k", json_real(c->refraction_k));
    json_object_set_new(o, "psf_sigma_px", json_real((sim->fx >> CAP_FX_PSF) & 1u ? sc->fx.psf.sigma_px : 0.0));
    if (sc->utc[0]) json_object_set_new(o, "time_utc", json_string(sc->utc));
    char *t = json_dumps(o, JSON_COMPACT | JSON_PRESERVE_ORDER | JSON_REAL_PRECISION(17));
    json_decref(o);
    return t;
}

gs_status cap_backend_sim_new(const cap_scene *sc, const gs_delight *d, cap_backend **out)
{
    *out = NULL;
    sim_backend *b = calloc(1, sizeof *b);
    if (!b) return gs_fail(GS_ENOMEM, "sim backend: out of memory");
    gs_status s = cap_sim_new(sc, d, &b->sim);
    if (s != GS_OK) {
        sim_free(b);
        return s;
    }
    if (sc->has_station && !(b->station_json = station_text(b->sim))) {
        sim_free(b);
        return gs_fail(GS_ENOMEM, "sim backend: out of memory");
    }
    return cap_backend_wrap(&sim_ops, b, out);
}

cap_sim *cap_backend_sim_handle(cap_backend *be)
{
    sim_backend *b = cap_backend_self(be, &sim_ops);
    return b ? b->sim : NULL;
}
