/* pipeline.c - the whole job on one capture (`gridsurvey run`; survey.h, docs/pipeline.md):
 * capture (a scene through the sim backend and the acquisition loop, or a capture directory
 * as it is) -> blobs -> Eq. 7 (paper Sec. 4) -> one-station location (gis_locate) -> the
 * survey database, one transaction per capture.
 *
 * Order of work, chosen so that bad input changes nothing on disk: every input (scene or
 * capture directory, station file, DELIGHT file, light height, capture-directory location) is
 * read and checked first; then the database is opened (srv_db_open removes what it created
 * when it fails); only then is anything written (the capture directory, the rows).
 * Crash safety comes from the parts: the acquisition loop keeps intact frames and resumes,
 * srv_db_add_capture commits a capture completely or not at all, and the resume key (a content
 * hash of the capture directory) makes a re-run skip what is committed. */
#include "survey/survey.h"
#include "capture/capture.h"

#include <errno.h>
#include <math.h>
#include <sqlite3.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#define KEY_FORMAT "gridsurvey-capture-key/1"

static const char *const stage_names[SRV_STAGE_COUNT] = {
    "capture", "read", "blobs", "match", "locate", "store",
};

const char *srv_stage_name(srv_stage s)
{
    return (int)s >= 0 && s < SRV_STAGE_COUNT ? stage_names[s] : NULL;
}

void srv_run_opts_default(srv_run_opts *o)
{
    memset(o, 0, sizeof *o);
    o->light_height_m = NAN;
    rec_eq7_opts_default(&o->eq7);
    o->threshold_sigma = 5.0;
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* ------------------------------------------------------------------ paths */

/* The directory part of path ("." when there is none), without a trailing slash. */
static void dir_of(const char *path, char *buf, size_t size)
{
    snprintf(buf, size, "%s", path);
    size_t n = strlen(buf);
    while (n > 1 && buf[n - 1] == '/') buf[--n] = '\0';
    char *slash = strrchr(buf, '/');
    if (!slash) snprintf(buf, size, ".");
    else if (slash == buf) buf[1] = '\0';
    else *slash = '\0';
}

/* The last component of path (trailing slashes ignored), and without its extension. */
static void base_of(const char *path, int strip_ext, char *buf, size_t size)
{
    char tmp[4096];
    snprintf(tmp, sizeof tmp, "%s", path);
    size_t n = strlen(tmp);
    while (n > 1 && tmp[n - 1] == '/') tmp[--n] = '\0';
    const char *slash = strrchr(tmp, '/');
    snprintf(buf, size, "%s", slash ? slash + 1 : tmp);
    if (strip_ext) {
        char *dot = strrchr(buf, '.');
        if (dot && dot != buf) *dot = '\0';
    }
}

/* A directory that exists and is writable, or can be created (its parent exists and is a
 * writable directory). Checked before anything is written; nothing is created here. */
static gs_status check_dir_creatable(const char *path, const char *what)
{
    struct stat sb;
    if (stat(path, &sb) == 0) {
        if (!S_ISDIR(sb.st_mode))
            return gs_fail(GS_EIO, "%s: %s exists and is not a directory", path, what);
        if (access(path, W_OK | X_OK) != 0)
            return gs_fail(GS_EIO, "%s: %s is not writable: %s", path, what, strerror(errno));
        return GS_OK;
    }
    if (errno != ENOENT)
        return gs_fail(GS_EIO, "%s: cannot use as the %s: %s", path, what, strerror(errno));
    char parent[4096];
    dir_of(path, parent, sizeof parent);
    if (stat(parent, &sb) != 0)
        return gs_fail(GS_EIO, "%s: cannot create the %s: %s: %s", path, what, parent, strerror(errno));
    if (!S_ISDIR(sb.st_mode))
        return gs_fail(GS_EIO, "%s: cannot create the %s: %s is not a directory", path, what, parent);
    if (access(parent, W_OK | X_OK) != 0)
        return gs_fail(GS_EIO, "%s: cannot create the %s: %s: %s", path, what, parent, strerror(errno));
    return GS_OK;
}

/* Copy a default survey name, cut to 63 bytes at a UTF-8 character boundary. */
static void set_name(char dst[64], const char *src)
{
    snprintf(dst, 64, "%s", src);
    size_t n = strlen(dst);
    /* cut inside a character (the first byte left out continues it): drop its start too */
    if (src[n])
        while (n > 0 && ((unsigned char)src[n] & 0xC0) == 0x80) dst[--n] = '\0';
}

/* ------------------------------------------------------------------ resume key */

static gs_status file_sha256(const char *dir, const char *name, char hex[65])
{
    char path[4352];
    if (!gs_path_join(path, sizeof path, dir, name))
        return gs_fail(GS_EINVAL, "%s/%s: path too long", dir, name);
    return gs_sha256_file(path, hex);
}

/* "sha256:" + SHA-256 of a manifest listing capture.json and every file it names (frames in
 * k order, then their HDR maps) with each file's SHA-256: the capture's identity, whatever the
 * directory is called or where it lies. */
static gs_status capture_key(const char *dir, const gs_capture *cap, char key[72])
{
    size_t size = 128 + (size_t)cap->K * 2 * (GS_PATH_MAX + 70), used = 0;
    char *man = malloc(size), hex[65];
    if (!man) return gs_fail(GS_ENOMEM, "capture key: out of memory");
    gs_status s = file_sha256(dir, "capture.json", hex);
    if (s == GS_OK) used += (size_t)snprintf(man + used, size - used, KEY_FORMAT "\ncapture.json %s\n", hex);
    for (int k = 0; s == GS_OK && k < cap->K; k++) {
        const gs_frame_info *fr = &cap->frames[k];
        if ((s = file_sha256(dir, fr->file, hex)) != GS_OK) break;
        used += (size_t)snprintf(man + used, size - used, "%s %s\n", fr->file, hex);
        if (fr->hdr_map[0]) {
            if ((s = file_sha256(dir, fr->hdr_map, hex)) != GS_OK) break;
            used += (size_t)snprintf(man + used, size - used, "%s %s\n", fr->hdr_map, hex);
        }
    }
    if (s == GS_OK) {
        gs_sha256_hex(man, used, hex);
        snprintf(key, 72, "sha256:%s", hex);
    }
    free(man);
    return s;
}

/* ------------------------------------------------------------------ helpers */

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* The median height of the scene's geographic lights; NaN when it has none. */
static double scene_median_height(const cap_scene *sc)
{
    double *h = malloc((sc->n_lights ? sc->n_lights : 1) * sizeof *h);
    size_t n = 0;
    if (!h) return NAN;
    for (size_t i = 0; i < sc->n_lights; i++)
        if (sc->lights[i].geographic && isfinite(sc->lights[i].height_m)) h[n++] = sc->lights[i].height_m;
    double med = NAN;
    if (n) {
        qsort(h, n, sizeof *h, cmp_double);
        med = n % 2 ? h[n / 2] : 0.5 * (h[n / 2 - 1] + h[n / 2]);
    }
    free(h);
    return med;
}

static void stage(const srv_run_opts *o, srv_stage s, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

static void stage(const srv_run_opts *o, srv_stage s, const char *fmt, ...)
{
    if (!o->progress) return;
    char detail[256];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(detail, sizeof detail, fmt, ap);
    va_end(ap);
    o->progress(o->progress_ctx, s, detail);
}

static gs_status check_opts(const srv_run_opts *o)
{
    if (!o->input || !*o->input) return gs_fail(GS_EINVAL, "run: no input (a scene or a capture directory)");
    if (!o->db_path || !*o->db_path) return gs_fail(GS_EINVAL, "run: no survey database (--db)");
    if (!(o->threshold_sigma > 0.0) || !isfinite(o->threshold_sigma))
        return gs_fail(GS_EINVAL, "run: threshold %g: expected a finite number of sigmas > 0", o->threshold_sigma);
    if (!isnan(o->light_height_m) &&
        !(o->light_height_m >= GIS_MIN_HEIGHT_M && o->light_height_m <= GIS_MAX_HEIGHT_M))
        return gs_fail(GS_EINVAL, "--light-height-m %g: expected a height above the WGS84 ellipsoid "
                       "from %g to %g m", o->light_height_m, GIS_MIN_HEIGHT_M, GIS_MAX_HEIGHT_M);
    if (o->survey && (!*o->survey || strlen(o->survey) > 63))
        return gs_fail(GS_EINVAL, "--survey '%s': expected a name of 1 to 63 bytes", o->survey);
    return GS_OK;
}

/* A skipped run reports what the committed capture holds. */
static gs_status committed_counts(srv_db *db, int64_t survey_id, srv_run_report *r)
{
    static const char sql[] =
        "SELECT c.id, count(l.id), count(l.bulb_id), count(l.phase_deg), count(loc.lat_deg), "
        "max(loc.height_m) FROM captures c LEFT JOIN lights l ON l.capture_id = c.id "
        "LEFT JOIN locations loc ON loc.light_id = l.id "
        "WHERE c.survey_id = ?1 AND c.capture_key = ?2 GROUP BY c.id";
    sqlite3 *h = srv_db_sqlite(db);
    sqlite3_stmt *q = NULL;
    if (sqlite3_prepare_v2(h, sql, -1, &q, NULL) != SQLITE_OK)
        return gs_fail(GS_ESQL, "%s: %s", srv_db_path(db), sqlite3_errmsg(h));
    sqlite3_bind_int64(q, 1, survey_id);
    sqlite3_bind_text(q, 2, r->key, -1, SQLITE_STATIC);
    gs_status s = GS_OK;
    int rc = sqlite3_step(q);
    if (rc == SQLITE_ROW) {
        r->capture_id = sqlite3_column_int64(q, 0);
        r->lights = (size_t)sqlite3_column_int64(q, 1);
        r->with_bulb = (size_t)sqlite3_column_int64(q, 2);
        r->with_phase = (size_t)sqlite3_column_int64(q, 3);
        r->located = (size_t)sqlite3_column_int64(q, 4);
        r->light_height_m = sqlite3_column_type(q, 5) == SQLITE_NULL ? NAN : sqlite3_column_double(q, 5);
        if (!isfinite(r->light_height_m)) r->height_source[0] = '\0';
        else snprintf(r->height_source, sizeof r->height_source, "stored");
    } else if (rc != SQLITE_DONE) {
        s = gs_fail(GS_ESQL, "%s: %s", srv_db_path(db), sqlite3_errmsg(h));
    }
    sqlite3_finalize(q);
    return s;
}

/* DELIGHT (the file, or the built-in database when path is NULL) and its Eq. 7 templates for
 * a capture of grid_hz, bands and K. */
static gs_status load_matcher(const char *path, int grid_hz, int bands, int K, const rec_eq7_opts *eq7,
                              gs_delight **d, rec_matcher **m)
{
    if (!(*d = gs_delight_new())) return gs_fail(GS_ENOMEM, "cannot allocate the DELIGHT database");
    gs_status s = path ? gs_delight_load(*d, path) : gs_delight_generate(*d, GS_BRF_N_DEFAULT);
    if (s != GS_OK) return s;
    s = rec_matcher_new(*d, grid_hz, bands, K, eq7, m);
    if (s == GS_ENOTFOUND) {
        char why[512];
        snprintf(why, sizeof why, "%s", gs_detail());
        s = gs_fail(GS_ENOTFOUND, "DELIGHT %s: no usable %s entry for the capture's %d Hz grid (%s)",
                    path ? path : "built-in", bands == 3 ? "RGB" : "monochrome", grid_hz, why);
    }
    return s;
}

/* ------------------------------------------------------------------ the run */

gs_status srv_run(const srv_run_opts *o, srv_run_report *r)
{
    if (!o || !r) return gs_fail(GS_EINVAL, "srv_run: NULL argument");
    memset(r, 0, sizeof *r);
    r->light_height_m = NAN;
    gs_status s = check_opts(o);
    if (s != GS_OK) return s;

    cap_scene sc;
    memset(&sc, 0, sizeof sc);
    int have_scene = 0;
    cap_backend *be = NULL;
    gs_capture cap;
    memset(&cap, 0, sizeof cap);
    rec_catalog cat;
    memset(&cat, 0, sizeof cat);
    gs_delight *d = NULL;
    rec_matcher *m = NULL;
    rec_match *mt = NULL;
    srv_db *db = NULL;
    srv_light_row *lights = NULL;
    srv_location_row *locs = NULL;
    srv_frame_row *frames = NULL;
    srv_freq_row *freq = NULL;
    const char *delight_path = o->delight_path;
    char delight_buf[CAP_PATH_MAX];
    int grid_hz = 0, bands = 0, K = 0, width = 0, height = 0;
    double t0;

    /* 1. the input, checked in full */
    struct stat sb;
    if (stat(o->input, &sb) != 0) {
        s = gs_fail(errno == ENOENT ? GS_ENOTFOUND : GS_EIO, "%s: %s (expected a scene file or a "
                    "capture directory)", o->input, strerror(errno));
        goto done;
    }
    r->scene = !S_ISDIR(sb.st_mode);
    if (r->scene) {
        s = cap_scene_read(o->input, &sc);
        have_scene = 1;
        if (s != GS_OK) goto done;
        if (!delight_path && sc.delight[0]) {
            snprintf(delight_buf, sizeof delight_buf, "%s", sc.delight);
            delight_path = delight_buf;
        }
        if ((s = cap_backend_sim_new(&sc, &be)) != GS_OK) goto done;
        cap_acq_info info;
        if ((s = cap_backend_info(be, &info)) != GS_OK) goto done;
        grid_hz = info.grid_hz;
        bands = info.bands;
        K = info.K;
        width = info.width;
        height = info.height;
        if (info.station_json && !o->station_path) {
            char src[4200];
            snprintf(src, sizeof src, "%s: camera.station", o->input);
            if ((s = gis_station_parse(info.station_json, src, &r->station)) != GS_OK) goto done;
            r->has_station = 1;
        }
        if (o->survey) set_name(r->survey, o->survey);
        else if (sc.name[0]) set_name(r->survey, sc.name);
        else {
            char stem[256];
            base_of(o->input, 1, stem, sizeof stem);
            set_name(r->survey, stem);
        }
        int len;
        if (o->capture_dir) {
            len = snprintf(r->capture_dir, sizeof r->capture_dir, "%s", o->capture_dir);
        } else {
            char dbdir[4096], stem[256];
            dir_of(o->db_path, dbdir, sizeof dbdir);
            base_of(o->input, 1, stem, sizeof stem);
            len = snprintf(r->capture_dir, sizeof r->capture_dir, "%.3800s/%.200s-capture", dbdir, stem);
        }
        if (len < 0 || (size_t)len >= sizeof r->capture_dir - 64) {
            s = gs_fail(GS_EINVAL, "%.200s...: capture directory path too long", r->capture_dir);
            goto done;
        }
        if ((s = check_dir_creatable(r->capture_dir, "capture directory")) != GS_OK) goto done;
    } else {
        if (o->capture_dir) {
            s = gs_fail(GS_EINVAL, "--capture-dir is for scene inputs: %s is already a capture "
                        "directory", o->input);
            goto done;
        }
        if (strlen(o->input) >= sizeof r->capture_dir - 64) {
            s = gs_fail(GS_EINVAL, "%.200s...: capture directory path too long", o->input);
            goto done;
        }
        snprintf(r->capture_dir, sizeof r->capture_dir, "%s", o->input);
        stage(o, SRV_STAGE_READ, "reading %s", o->input);
        t0 = now_s();
        if ((s = gs_capture_read(o->input, &cap)) != GS_OK) goto done;
        r->seconds[SRV_STAGE_READ] += now_s() - t0;
        grid_hz = cap.grid_hz;
        bands = cap.bands;
        K = cap.K;
        width = cap.width;
        height = cap.height;
        if (cap.station_json && !o->station_path) {
            char src[4200];
            snprintf(src, sizeof src, "%s/capture.json: station", o->input);
            if ((s = gis_station_parse(cap.station_json, src, &r->station)) != GS_OK) goto done;
            r->has_station = 1;
        }
        char base[256];
        base_of(o->input, 0, base, sizeof base);
        set_name(r->survey, o->survey ? o->survey : base);
    }

    /* 2. the station and the light height */
    if (o->station_path) {
        if ((s = gis_station_read(o->station_path, &r->station)) != GS_OK) goto done;
        r->has_station = 1;
    }
    if (r->has_station) {
        const gis_camera *c = &r->station.cam;
        if ((s = gis_camera_check(c)) != GS_OK) goto done;
        if ((c->width_px > 0 && c->width_px != width) || (c->height_px > 0 && c->height_px != height)) {
            s = gs_fail(GS_EINVAL, "%s: the station's image is %dx%d pixels but the capture's is "
                        "%dx%d", o->station_path ? o->station_path : o->input, c->width_px,
                        c->height_px, width, height);
            goto done;
        }
        if (isfinite(o->light_height_m)) {
            r->light_height_m = o->light_height_m;
            snprintf(r->height_source, sizeof r->height_source, "--light-height-m");
        } else if (have_scene && isfinite(r->light_height_m = scene_median_height(&sc))) {
            snprintf(r->height_source, sizeof r->height_source, "scene median");
        } else {
            s = gs_fail(GS_EINVAL, "%s: the lights' height is unknown (%s): give --light-height-m "
                        "H, metres above the WGS84 ellipsoid", o->input,
                        have_scene ? "the scene has no geographic light" : "a capture directory");
            goto done;
        }
    }
    if (have_scene) {
        cap_scene_release(&sc);
        have_scene = 0;
    }

    /* 3. a DELIGHT file and the Eq. 7 templates it gives for this capture: checked now (the
     * built-in database cannot be wrong, so it is generated only when it is needed, below) */
    if (delight_path && (s = load_matcher(delight_path, grid_hz, bands, K, &o->eq7, &d, &m)) != GS_OK)
        goto done;

    /* 4. the database: the last check, and the first write */
    if ((s = srv_db_open(o->db_path, SRV_DB_CREATE, &db)) != GS_OK) goto done;

    /* 5. capture (scene input) */
    if (be) {
        stage(o, SRV_STAGE_CAPTURE, "acquiring %d frames into %s", K, r->capture_dir);
        t0 = now_s();
        cap_loop_opts lo;
        cap_loop_opts_default(&lo);
        lo.progress = o->capture_progress ? 1 : 0;
        cap_loop_report lr;
        s = cap_loop_run(be, r->capture_dir, &lo, &lr);
        if (s == GS_OK && !lr.complete)
            s = gs_fail(GS_EIO, "%s: the acquisition stopped before the last frame", r->capture_dir);
        if (s == GS_OK) s = cap_sim_write_truth(cap_backend_sim_handle(be), r->capture_dir);
        r->frames_acquired = lr.frames_acquired;
        r->frames_kept = lr.frames_kept;
        cap_backend_free(be);
        be = NULL;
        r->seconds[SRV_STAGE_CAPTURE] = now_s() - t0;
        if (s != GS_OK) goto done;
        stage(o, SRV_STAGE_READ, "reading %s", r->capture_dir);
        t0 = now_s();
        if ((s = gs_capture_read(r->capture_dir, &cap)) != GS_OK) goto done;
        r->seconds[SRV_STAGE_READ] += now_s() - t0;
    }
    /* (capture_dir is at most sizeof - 64 bytes long: checked above, or by gs_capture_read) */
    if (snprintf(r->truth_path, sizeof r->truth_path, "%.4000s/truth.json", r->capture_dir) > 0 &&
        !(stat(r->truth_path, &sb) == 0 && S_ISREG(sb.st_mode)))
        r->truth_path[0] = '\0';

    /* 6. the resume key; a committed capture is skipped */
    stage(o, SRV_STAGE_READ, "hashing %s", r->capture_dir);
    t0 = now_s();
    s = capture_key(r->capture_dir, &cap, r->key);
    r->seconds[SRV_STAGE_READ] += now_s() - t0;
    if (s != GS_OK) goto done;
    int64_t survey_id = 0;
    s = srv_db_find_survey(db, r->survey, &survey_id);
    if (s == GS_OK) {
        int is_done = 0;
        if ((s = srv_db_capture_done(db, survey_id, r->key, &is_done)) != GS_OK) goto done;
        if (is_done) {
            r->skipped = 1;
            r->survey_id = survey_id;
            s = committed_counts(db, survey_id, r);
            goto done;
        }
    } else if (s != GS_ENOTFOUND) {
        goto done;
    }
    s = GS_OK;

    /* 7. blobs and Eq. 7 */
    stage(o, SRV_STAGE_BLOBS, "extracting lights");
    t0 = now_s();
    rec_blob_opts bo;
    rec_blob_opts_default(&bo);
    bo.threshold_sigma = o->threshold_sigma;
    s = rec_blobs_extract(&cap, &bo, &cat);
    r->seconds[SRV_STAGE_BLOBS] = now_s() - t0;
    if (s != GS_OK) goto done;
    stage(o, SRV_STAGE_MATCH, "Eq. 7 on %zu lights%s", cat.count, m ? "" : " (built-in DELIGHT)");
    t0 = now_s();
    if (!m && (s = load_matcher(NULL, grid_hz, bands, K, &o->eq7, &d, &m)) != GS_OK) goto done;
    size_t n = cat.count;
    mt = calloc(n ? n : 1, sizeof *mt);
    lights = calloc(n ? n : 1, sizeof *lights);
    locs = calloc(n ? n : 1, sizeof *locs);
    frames = calloc((size_t)K, sizeof *frames);
    freq = calloc((size_t)K, sizeof *freq);
    if (!mt || !lights || !locs || !frames || !freq) {
        s = gs_fail(GS_ENOMEM, "out of memory for %zu lights", n);
        goto done;
    }
    if ((s = rec_match_catalog(m, &cat, mt)) != GS_OK) goto done;
    for (size_t i = 0; i < n; i++) {
        srv_light_row_init(&lights[i]);
        srv_light_from_catalog(&lights[i], &cat, i);
        srv_light_from_match(&lights[i], &mt[i], m);
        r->with_bulb += lights[i].bulb_id != NULL;
        r->with_phase += isfinite(lights[i].phase_deg);
    }
    r->lights = n;
    /* the pixels are no longer needed: free them before the rest */
    free(cap.raw);
    cap.raw = NULL;
    free(cap.halvings);
    cap.halvings = NULL;
    r->seconds[SRV_STAGE_MATCH] = now_s() - t0;

    /* 8. locate */
    if (r->has_station) {
        stage(o, SRV_STAGE_LOCATE, "%zu lights at %.1f m", n, r->light_height_m);
        t0 = now_s();
        for (size_t i = 0; i < n; i++) {
            gis_fix fx;
            s = gis_locate(&r->station.cam, lights[i].x_px, lights[i].y_px, r->station.sigma_px,
                           r->light_height_m, NULL, &fx);
            if (s != GS_OK) goto done;
            srv_location_row_init(&locs[i]);
            srv_location_from_fix(&locs[i], &fx);
            r->located += isfinite(fx.lat_deg);
        }
        r->seconds[SRV_STAGE_LOCATE] = now_s() - t0;
    } else {
        r->light_height_m = NAN;
    }

    /* 9. store: the survey, DELIGHT and station rows (get or add), then the capture at once */
    stage(o, SRV_STAGE_STORE, "DELIGHT, survey and station rows");
    t0 = now_s();
    srv_delight_row dv;
    if ((s = srv_delight_fingerprint(d, delight_path, &dv)) != GS_OK) goto done;
    int64_t delight_id = 0, station_id = 0;
    if ((s = srv_db_add_delight(db, &dv, &delight_id)) != GS_OK) goto done;
    srv_survey_row sv = {.name = r->survey, .grid_hz = grid_hz, .started_utc = cap.utc[0] ? cap.utc : NULL};
    if ((s = srv_db_add_survey(db, &sv, &survey_id)) != GS_OK) goto done;
    r->survey_id = survey_id;
    if (r->has_station) {
        srv_station_row st;
        srv_station_row_init(&st);
        st.survey_id = survey_id;
        st.name = r->station.id[0] ? r->station.id : "station";
        st.cam = r->station.cam;
        st.sigma_px = r->station.sigma_px;
        st.time_utc = r->station.time_utc[0] ? r->station.time_utc : (cap.utc[0] ? cap.utc : NULL);
        if ((s = srv_db_add_station(db, &st, &station_id)) != GS_OK) goto done;
    }
    for (int k = 0; k < K; k++) {
        frames[k].k = cap.frames[k].k;
        frames[k].file = cap.frames[k].file;
        frames[k].hdr_map = cap.frames[k].hdr_map[0] ? cap.frames[k].hdr_map : NULL;
        frames[k].cycles = cap.frames[k].cycles;
    }
    /* the grid frequency log: one row per frame whose exposure's frequency and start are
     * known (capture.json), in time order; the capture's mean and std from them */
    size_t n_freq = 0;
    double f_sum = 0, f_sum2 = 0;
    for (int k = 0; k < K; k++) {
        const gs_frame_info *fi = &cap.frames[k];
        if (!isfinite(fi->grid_hz_measured) || !isfinite(fi->start_s)) continue;
        srv_freq_row fr = {fi->start_s, fi->cycles / (2.0 * fi->grid_hz_measured),
                           fi->grid_hz_measured, NAN};
        size_t j = n_freq++;
        for (; j > 0 && freq[j - 1].t_s > fr.t_s; j--) freq[j] = freq[j - 1];
        freq[j] = fr;
        f_sum += fr.frequency_hz;
    }
    double f_mean = n_freq ? f_sum / (double)n_freq : NAN;
    for (size_t j = 0; j < n_freq; j++)
        f_sum2 += (freq[j].frequency_hz - f_mean) * (freq[j].frequency_hz - f_mean);
    char abs_dir[4096];
    const char *path = realpath(r->capture_dir, abs_dir) ? abs_dir : r->capture_dir;
    srv_capture_data cd;
    memset(&cd, 0, sizeof cd);
    srv_capture_row_init(&cd.capture);
    cd.capture.survey_id = survey_id;
    cd.capture.station_id = station_id;
    cd.capture.delight_id = delight_id;
    cd.capture.key = r->key;
    cd.capture.path = path;
    cd.capture.utc = cap.utc[0] ? cap.utc : NULL;
    cd.capture.grid_hz = grid_hz;
    cd.capture.K = K;
    cd.capture.bands = bands;
    cd.capture.width_px = width;
    cd.capture.height_px = height;
    cd.capture.locked = cap.locked ? 1 : 0;
    cd.capture.mean_frequency_hz = f_mean;
    cd.capture.sigma_frequency_hz = n_freq >= 2 ? sqrt(f_sum2 / (double)(n_freq - 1)) : NAN;
    cd.frames = frames;
    cd.n_frames = (size_t)K;
    cd.frequency = n_freq ? freq : NULL;
    cd.n_frequency = n_freq;
    cd.lights = lights;
    cd.locations = r->has_station ? locs : NULL;
    cd.n_lights = n;
    int skipped = 0;
    stage(o, SRV_STAGE_STORE, "capture: %zu lights, %d frames, %zu frequency rows in one "
          "transaction", n, K, n_freq);
    s = srv_db_add_capture(db, &cd, &r->capture_id, &skipped);
    r->seconds[SRV_STAGE_STORE] = now_s() - t0;
    if (s != GS_OK) goto done;
    r->skipped = skipped;

done:
    free(freq);
    free(frames);
    free(locs);
    free(lights);
    free(mt);
    rec_matcher_free(m);
    gs_delight_free(d);
    srv_db_close(db);
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
    cap_backend_free(be);
    if (have_scene) cap_scene_release(&sc);
    return s;
}
