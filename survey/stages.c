/* stages.c - the pipeline's stages on one capture (survey.h, srv_job): acquire (a scene through
 * the sim backend and the acquisition loop), read, extract (blobs), match (Eq. 7 over DELIGHT),
 * locate (one station) and store (one transaction). `run`, `recognize` and `bench accuracy`
 * call the same stages; srv_job_release frees whatever they built. */
#include "survey/internal.h"
#include "capture/capture.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

void srv_job_release(srv_job *j)
{
    if (!j) return;
    free(j->locs);
    free(j->lights);
    free(j->match);
    rec_matcher_free(j->matcher);
    gs_delight_free(j->delight_owned);
    rec_catalog_release(&j->cat);
    gs_capture_release(&j->cap);
    if (j->cap_locked) gs_capture_unlock(j->cap_lock_fd);
    memset(j, 0, sizeof *j);
}

gs_status srv_job_acquire(cap_backend *be, const char *capdir, int progress, int *frames_acquired,
                          int *frames_kept)
{
    cap_loop_opts lo;
    cap_loop_opts_default(&lo);
    lo.progress = progress ? 1 : 0;
    cap_loop_report lr;
    gs_status s = cap_loop_run(be, capdir, &lo, &lr);
    if (s == GS_OK && !lr.complete)
        s = gs_fail(GS_EIO, "%s: the acquisition stopped before the last frame", capdir);
    cap_sim *sim = cap_backend_sim_handle(be);
    if (s == GS_OK && sim) s = cap_sim_write_truth(sim, capdir);
    if (frames_acquired) *frames_acquired = lr.frames_acquired;
    if (frames_kept) *frames_kept = lr.frames_kept;
    return s;
}

gs_status srv_job_read(srv_job *j, const char *capdir)
{
    gs_capture_release(&j->cap);
    if (j->cap_locked) gs_capture_unlock(j->cap_lock_fd);
    j->cap_locked = 0;
    gs_status s = gs_capture_lock(capdir, 0, &j->cap_lock_fd);
    if (s != GS_OK) return s;
    j->cap_locked = 1;
    return gs_capture_read_held(capdir, &j->cap);
}

gs_status srv_job_matcher(srv_job *j, const gs_delight *d, const char *delight_path, int grid_hz,
                          int bands, int K, const rec_eq7_opts *eq7)
{
    if (j->matcher) return GS_OK;
    gs_status s = GS_OK;
    if (!d) {
        if ((s = gs_delight_open(delight_path, &j->delight_owned)) != GS_OK) return s;
        d = j->delight_owned;
    }
    j->delight = d;
    j->delight_path = delight_path;
    s = rec_matcher_new(d, grid_hz, bands, K, eq7, &j->matcher);
    if (s == GS_ENOTFOUND)
        s = gs_fail(GS_ENOTFOUND, "DELIGHT %s: no usable %s entry for the capture's %d Hz grid (%s)",
                    delight_path ? delight_path : "built-in", bands == 3 ? "RGB" : "monochrome",
                    grid_hz, gs_detail());
    return s;
}

gs_status srv_job_extract(srv_job *j, const rec_blob_opts *bo)
{
    rec_catalog_release(&j->cat);
    return rec_blobs_extract(&j->cap, bo, &j->cat);
}

gs_status srv_job_match(srv_job *j)
{
    if (!j->matcher) return gs_fail(GS_EINVAL, "srv_job_match: no matcher (srv_job_matcher first)");
    size_t n = j->cat.count;
    free(j->match);
    free(j->lights);
    j->match = calloc(n ? n : 1, sizeof *j->match);
    j->lights = calloc(n ? n : 1, sizeof *j->lights);
    if (!j->match || !j->lights) return gs_fail(GS_ENOMEM, "out of memory for %zu lights", n);
    gs_status s = rec_match_catalog(j->matcher, &j->cat, j->match, &j->noise);
    if (s != GS_OK) return s;
    j->with_bulb = j->with_phase = 0;
    for (size_t i = 0; i < n; i++) {
        srv_light_row_init(&j->lights[i]);
        srv_light_from_catalog(&j->lights[i], &j->cat, i);
        srv_light_from_match(&j->lights[i], &j->match[i], j->matcher);
        j->with_bulb += j->lights[i].bulb_id != NULL;
        j->with_phase += isfinite(j->lights[i].phase_deg);
    }
    return GS_OK;
}

void srv_drift_note(const gs_capture *cap, double max_drift_windows, char *buf, size_t n)
{
    int out = rec_frames_left_out(cap, max_drift_windows, NULL), unknown = 0, worst_k = -1;
    double worst = -1.0, limit = rec_drift_limit(max_drift_windows, cap->window_period);
    for (int k = 0; k < cap->K; k++) {
        double d = gs_capture_frame_drift(cap, k);
        unknown += isnan(d);
        if (d > worst) worst = d, worst_k = k;
    }
    if (cap->locked) {
        snprintf(buf, n, "%s", "");
    } else if (!out) {
        snprintf(buf, n, "; free running: the windows drifted at most %.4g windows over an exposure (frame %d)%s",
                 worst, worst_k, max_drift_windows == REC_DRIFT_AUTO && isinf(limit)
                                     ? ", every frame kept: the period was measured (--max-drift-windows auto)" : "");
    } else {
        int u = snprintf(buf, n, "; free running: %d of %d frames left out (flag drift):", out, cap->K);
        if (u > 0 && (size_t)u < n && out > unknown)
            u += snprintf(buf + u, n - (size_t)u, " %d drifted over %.4g windows (the most %.4g, frame %d)%s",
                          out - unknown, limit, worst, worst_k, unknown ? "," : "");
        if (u > 0 && (size_t)u < n && unknown)
            u += snprintf(buf + u, n - (size_t)u, " %d without the timing to tell (window_drift_windows, or "
                          "window_half_period_s and grid_hz_measured)", unknown);
        if (u > 0 && (size_t)u < n && max_drift_windows == REC_DRIFT_AUTO)
            snprintf(buf + u, n - (size_t)u, " (--max-drift-windows auto, the period %s)",
                     gs_period_name(cap->window_period) ? gs_period_name(cap->window_period)
                                                        : "not recorded: capture.json has no window_period");
    }
}

void srv_job_drop_pixels(srv_job *j)
{
    free(j->cap.raw);
    j->cap.raw = NULL;
    free(j->cap.halvings);
    j->cap.halvings = NULL;
}

/* The windowed centroid's noise (recognize/blobs_photometry.c: a Gaussian window of the PSF's
 * sigma s): for a Gaussian PSF, x = x0 + 2 sum(w I dx) / sum(w I) has variance 16 s^2 / (9 N)
 * for N photons and 8 pi b s^4 / N^2 on a background b per pixel, i.e. (4/3) s / SNR and
 * sqrt(2) s / SNR with the PSF-weighted SNR; sqrt(2) s / snr is the bound taken. Its floor is
 * the window's pixel-sampling bias (rec_centroid_bias_px, floor_px here): on the metro scene
 * (make demo, PSF 0.8 px) the plain lights' errors against the truth follow both (95 % inside
 * their 95 % circle); at a 1.1 px PSF the floor is 50x smaller. A deblended or crowded
 * footprint may hold an undetected neighbour (errors up to 1-2 px: 0.5 s covers 95 % of the
 * deblended ones); the multi-source PSF fit's lights share a neighbour's residual (0.012 s). */
double srv_centroid_sigma_px(double snr, unsigned blob_flags, int crowded, double psf_sigma_px, double floor_px)
{
    if (!(snr > 0.0) || !isfinite(snr) || !(psf_sigma_px >= 0.0) || !(floor_px >= 0.0)) return NAN;
    double s = sqrt(psf_sigma_px * psf_sigma_px + 1.0 / 12.0);
    double crowd = (blob_flags & REC_BLOB_PSF_FIT) ? 0.012 * s
                   : (crowded || (blob_flags & REC_BLOB_DEBLENDED)) ? 0.5 * s : 0.0;
    double noise = M_SQRT2 * s / snr;
    return sqrt(noise * noise + floor_px * floor_px + crowd * crowd);
}

gs_status srv_crowded_footprints(const srv_light_row *lights, size_t n, unsigned char *crowded)
{
    memset(crowded, 0, n);
    double *res = malloc((n ? n : 1) * sizeof *res);
    unsigned char *use = malloc(n ? n : 1);
    gs_status s = res && use ? GS_OK : GS_ENOMEM;
    if (s != GS_OK) goto done;
    size_t m = 0;
    for (size_t i = 0; i < n; i++) {
        use[i] = !lights[i].blob_flags && lights[i].snr > 1.0 && isfinite(lights[i].snr);
        m += use[i];
    }
    if (m < 10) goto done;
    double a = 0, b = 0, sigma = INFINITY;
    for (int round = 0; round < 4; round++) {
        double sx = 0, sy = 0, sxx = 0, sxy = 0;
        size_t k = 0;
        for (size_t i = 0; i < n; i++) {
            if (!use[i]) continue;
            double x = log(lights[i].snr), y = lights[i].area_px;
            if (round && fabs(y - a - b * x) > 3.0 * sigma) continue;
            sx += x, sy += y, sxx += x * x, sxy += x * y, k++;
        }
        double det = (double)k * sxx - sx * sx;
        if (k < 10 || !(det > 0)) goto done;
        b = ((double)k * sxy - sx * sy) / det;
        a = (sy - b * sx) / (double)k;
        k = 0;
        for (size_t i = 0; i < n; i++)
            if (use[i]) res[k++] = fabs(lights[i].area_px - a - b * log(lights[i].snr));
        /* at least half a pixel: areas are whole pixels, so a robust sigma below their rounding
         * (a line through equal SNRs fits that rounding) is no measure of a light's spread */
        sigma = fmax(1.4826 * gs_median_d(res, k), 0.5);
    }
    for (size_t i = 0; i < n; i++)
        crowded[i] = lights[i].snr > 0 && isfinite(lights[i].snr) &&
                     lights[i].area_px - a - b * log(lights[i].snr) > 4.0 * sigma;
done:
    free(res);
    free(use);
    return s;
}

gs_status srv_job_locate(srv_job *j, const gis_station *st, double height_m, double sigma_height_m)
{
    size_t n = j->cat.count;
    free(j->locs);
    j->locs = calloc(n ? n : 1, sizeof *j->locs);
    if (!j->locs) return gs_fail(GS_ENOMEM, "out of memory for %zu locations", n);
    j->located = 0;
    gis_locate_opts lo;
    gis_locate_opts_default(&lo);
    lo.sigma_height_m = sigma_height_m;
    unsigned char *crowded = malloc(n ? n : 1);
    if (!crowded || srv_crowded_footprints(j->lights, n, crowded) != GS_OK) {
        free(crowded);
        return gs_fail(GS_ENOMEM, "out of memory for %zu locations", n);
    }
    const double floor_px = st->psf_sigma_px > 0.0 ? rec_centroid_bias_px(st->psf_sigma_px) : 0.0;
    for (size_t i = 0; i < n; i++) {
        gis_fix fx;
        double c = srv_centroid_sigma_px(j->lights[i].snr, j->lights[i].blob_flags, crowded[i],
                                         st->psf_sigma_px, floor_px);
        double sig = isfinite(c) ? hypot(c, st->sigma_px) : st->sigma_px;
        /* a light of the PSF fit: its noise and its blend are in the fit's covariance (correlated,
         * larger across a blend), the window's bias floor and the station's sigma beside it */
        const double *pc = j->lights[i].pos_cov_px2;
        int fit = (j->lights[i].blob_flags & REC_BLOB_PSF_FIT) && isfinite(pc[0]) && isfinite(pc[1]) && isfinite(pc[2]);
        for (int k = 0; k < 3; k++) lo.pixel_cov_px2[k] = fit ? pc[k] : 0.0;
        if (fit) sig = hypot(floor_px, st->sigma_px);
        gs_status s = gis_locate(&st->cam, j->lights[i].x_px, j->lights[i].y_px, sig, height_m, &lo, &fx);
        if (s != GS_OK) {
            free(crowded);
            return s;
        }
        srv_location_row_init(&j->locs[i]);
        srv_location_from_fix(&j->locs[i], &fx);
        j->located += isfinite(fx.lat_deg);
    }
    free(crowded);
    return GS_OK;
}

gs_status srv_job_store(srv_job *j, srv_db *db, const srv_store_opts *o, int64_t *survey_id,
                        int64_t *capture_id, int *skipped)
{
    const gs_capture *cap = &j->cap;
    int K = cap->K;
    size_t n = j->cat.count;
    srv_frame_row *frames = calloc((size_t)K, sizeof *frames);
    srv_freq_row *freq = calloc((size_t)K, sizeof *freq);
    gs_status s = frames && freq ? GS_OK : gs_fail(GS_ENOMEM, "out of memory for %d frames", K);
    srv_delight_row dv;
    int64_t delight_id = 0, station_id = 0;
    /* one transaction for the DELIGHT version, survey, station and capture rows: a failure
     * (a full disk, an I/O error at commit) leaves the database as it was, not a survey without
     * its capture (#16, fault injection) */
    int own = 0;
    if (s == GS_OK) s = srv_dbi_auto_begin(db, &own);
    if (s == GS_OK) s = srv_delight_fingerprint(j->delight, j->delight_path, &dv);
    if (s == GS_OK) s = srv_db_add_delight(db, &dv, &delight_id);
    srv_survey_row sv = {.name = o->survey, .grid_hz = cap->grid_hz,
                         .started_utc = cap->utc[0] ? cap->utc : NULL};
    if (s == GS_OK) s = srv_db_add_survey(db, &sv, survey_id);
    if (s == GS_OK && o->station) {
        srv_station_row st;
        srv_station_row_init(&st);
        st.survey_id = *survey_id;
        st.name = o->station->id[0] ? o->station->id : "station";
        st.cam = o->station->cam;
        st.sigma_px = o->station->sigma_px;
        st.time_utc = o->station->time_utc[0] ? o->station->time_utc : (cap->utc[0] ? cap->utc : NULL);
        s = srv_db_add_station(db, &st, &station_id);
    }
    if (s != GS_OK) goto done;
    for (int k = 0; k < K; k++) {
        frames[k].k = cap->frames[k].k;
        frames[k].file = cap->frames[k].file;
        frames[k].hdr_map = cap->frames[k].hdr_map[0] ? cap->frames[k].hdr_map : NULL;
        frames[k].cycles = cap->frames[k].cycles;
    }
    /* the grid frequency log: one row per frame whose exposure's frequency and start are
     * known (capture.json), in time order; the capture's mean and std from them */
    size_t n_freq = 0;
    double f_sum = 0, f_sum2 = 0;
    for (int k = 0; k < K; k++) {
        const gs_frame_info *fi = &cap->frames[k];
        if (!isfinite(fi->grid_hz_measured) || !isfinite(fi->start_s)) continue;
        srv_freq_row fr = {fi->start_s, fi->cycles / (2.0 * fi->grid_hz_measured),
                           fi->grid_hz_measured, NAN};
        size_t q = n_freq++;
        for (; q > 0 && freq[q - 1].t_s > fr.t_s; q--) freq[q] = freq[q - 1];
        freq[q] = fr;
        f_sum += fr.frequency_hz;
    }
    double f_mean = n_freq ? f_sum / (double)n_freq : NAN;
    for (size_t q = 0; q < n_freq; q++)
        f_sum2 += (freq[q].frequency_hz - f_mean) * (freq[q].frequency_hz - f_mean);
    srv_capture_data cd;
    memset(&cd, 0, sizeof cd);
    srv_capture_row_init(&cd.capture);
    cd.capture.survey_id = *survey_id;
    cd.capture.station_id = station_id;
    cd.capture.delight_id = delight_id;
    cd.capture.key = o->key;
    cd.capture.path = o->path;
    cd.capture.utc = cap->utc[0] ? cap->utc : NULL;
    cd.capture.grid_hz = cap->grid_hz;
    cd.capture.K = K;
    cd.capture.bands = cap->bands;
    cd.capture.width_px = cap->width;
    cd.capture.height_px = cap->height;
    cd.capture.locked = cap->locked ? 1 : 0;
    cd.capture.mean_frequency_hz = f_mean;
    cd.capture.sigma_frequency_hz = n_freq >= 2 ? sqrt(f_sum2 / (double)(n_freq - 1)) : NAN;
    cd.capture.candidate_bulbs = j->matcher ? (long)rec_matcher_bulb_count(j->matcher) : 0;
    cd.frames = frames;
    cd.n_frames = (size_t)K;
    cd.frequency = n_freq ? freq : NULL;
    cd.n_frequency = n_freq;
    cd.lights = j->lights;
    cd.locations = o->station ? j->locs : NULL;
    cd.n_lights = n;
    if (o->before_commit) o->before_commit(o->ctx, n, K, n_freq);
    s = srv_db_add_capture(db, &cd, capture_id, skipped);
done:
    s = srv_dbi_auto_end(db, own, s);
    free(freq);
    free(frames);
    return s;
}
