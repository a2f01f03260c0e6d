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
#include "survey/internal.h"
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
    o->light_height_sigma_m = NAN;
    rec_eq7_opts_default(&o->eq7);
    o->threshold_sigma = 5.0;
}

/* ------------------------------------------------------------------ paths */

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
    gs_path_dir(path, parent, sizeof parent);
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

/* The SHA-256 of frames [k0, k1) and their HDR maps (hex[2k], hex[2k + 1]). */
typedef struct {
    const char *dir;
    const gs_capture *cap;
    char (*hex)[65];
} frame_hashes;

static gs_status hash_frames(void *ctx, int part, size_t k0, size_t k1)
{
    (void)part;
    const frame_hashes *h = ctx;
    gs_status s = GS_OK;
    for (size_t k = k0; s == GS_OK && k < k1; k++) {
        const gs_frame_info *fr = &h->cap->frames[k];
        s = file_sha256(h->dir, fr->file, h->hex[2 * k]);
        if (s == GS_OK && fr->hdr_map[0]) s = file_sha256(h->dir, fr->hdr_map, h->hex[2 * k + 1]);
    }
    return s;
}

/* "sha256:" + SHA-256 of a manifest listing capture.json and every file it names (frames in
 * k order, then their HDR maps) with each file's SHA-256: the capture's identity, whatever the
 * directory is called or where it lies. The files are hashed on every CPU (an error is the
 * first file's in that order, as one after the other). */
static gs_status capture_key(const char *dir, const gs_capture *cap, char key[72])
{
    size_t size = 128 + (size_t)cap->K * 2 * (GS_PATH_MAX + 70), used = 0;
    char *man = malloc(size), hex[65];
    frame_hashes fh = {dir, cap, malloc(sizeof *fh.hex * 2 * (size_t)(cap->K > 0 ? cap->K : 1))};
    gs_status s = man && fh.hex ? file_sha256(dir, "capture.json", hex) : gs_fail(GS_ENOMEM, "capture key: out of memory");
    if (s == GS_OK) s = gs_parallel_for(0, (size_t)cap->K, hash_frames, &fh);
    if (s == GS_OK) {
        used += (size_t)snprintf(man + used, size - used, KEY_FORMAT "\ncapture.json %s\n", hex);
        for (int k = 0; k < cap->K; k++) {
            const gs_frame_info *fr = &cap->frames[k];
            used += (size_t)snprintf(man + used, size - used, "%s %s\n", fr->file, fh.hex[2 * k]);
            if (fr->hdr_map[0])
                used += (size_t)snprintf(man + used, size - used, "%s %s\n", fr->hdr_map, fh.hex[2 * k + 1]);
        }
        gs_sha256_hex(man, used, hex);
        snprintf(key, 72, "sha256:%s", hex);
    }
    free(fh.hex);
    free(man);
    return s;
}

/* ------------------------------------------------------------------ helpers */

/* The median height of the scene's geographic lights (NaN when it has none) and their
 * standard deviation. */
static double scene_median_height(const cap_scene *sc, double *sd_m)
{
    double *h = malloc((sc->n_lights ? sc->n_lights : 1) * sizeof *h);
    size_t n = 0;
    if (!h) return NAN;
    for (size_t i = 0; i < sc->n_lights; i++)
        if (sc->lights[i].geographic && isfinite(sc->lights[i].height_m)) h[n++] = sc->lights[i].height_m;
    double sum = 0, sum2 = 0;
    for (size_t i = 0; i < n; i++) sum += h[i];
    for (size_t i = 0; i < n; i++) sum2 += (h[i] - sum / (double)n) * (h[i] - sum / (double)n);
    *sd_m = n > 1 ? sqrt(sum2 / (double)(n - 1)) : 0.0;
    double med = gs_median_d(h, n);   /* (NaN without a geographic light) */
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
    if (!isnan(o->light_height_sigma_m) && !(o->light_height_sigma_m >= 0.0 && o->light_height_sigma_m <= 1000.0))
        return gs_fail(GS_EINVAL, "--light-height-sigma-m %g: expected metres from 0 to 1000",
                       o->light_height_sigma_m);
    if (o->survey && (!*o->survey || strlen(o->survey) > 63 || !gs_text_clean(o->survey)))
        return gs_fail(GS_EINVAL, "--survey: expected a name of 1 to 63 bytes of UTF-8 without "
                       "control characters");
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
        r->light_height_m = srv_dbi_col_real(q, 5);
        if (!isfinite(r->light_height_m)) r->height_source[0] = '\0';
        else snprintf(r->height_source, sizeof r->height_source, "stored");
    } else if (rc != SQLITE_DONE) {
        s = gs_fail(GS_ESQL, "%s: %s", srv_db_path(db), sqlite3_errmsg(h));
    }
    sqlite3_finalize(q);
    return s;
}

/* ------------------------------------------------------------------ the run */

/* store's progress report right before the capture's transaction */
static void before_commit(void *ctx, size_t lights, int frames, size_t frequency_rows)
{
    const srv_run_opts *o = ctx;
    stage(o, SRV_STAGE_STORE, "capture: %zu lights, %d frames, %zu frequency rows in one "
          "transaction", lights, frames, frequency_rows);
}

/* 1. The input, checked in full: a scene (its sim backend, station, survey name and capture
 * directory) or a capture directory (read into j). grid_hz, bands, K, width, height set. */
static gs_status open_input(const srv_run_opts *o, srv_run_report *r, cap_scene *sc, int *have_scene,
                            cap_backend **be, srv_job *j, int dims[5])
{
    struct stat sb;
    if (stat(o->input, &sb) != 0)
        return gs_fail(errno == ENOENT ? GS_ENOTFOUND : GS_EIO, "%s: %s (expected a scene file or a "
                       "capture directory)", o->input, strerror(errno));
    r->scene = !S_ISDIR(sb.st_mode);
    gs_status s;
    const char *station_json = NULL;
    char src[4200];
    if (r->scene) {
        *have_scene = 1;
        if ((s = cap_scene_read(o->input, sc)) != GS_OK) return s;
        /* without --delight the render's DELIGHT is also Eq. 7's: read or generated once */
        if (!o->delight_path &&
            (s = gs_delight_open(sc->delight[0] ? sc->delight : NULL, &j->delight_owned)) != GS_OK)
            return s;
        if ((s = cap_backend_sim_new(sc, j->delight_owned, be)) != GS_OK) return s;
        cap_acq_info info;
        if ((s = cap_backend_info(*be, &info)) != GS_OK) return s;
        int d[5] = {info.grid_hz, info.bands, info.K, info.width, info.height};
        memcpy(dims, d, sizeof d);
        /* recognition's memory, checked before the capture is rendered (the render's own is
         * checked by cap_backend_sim_new) */
        if ((s = gs_capture_budget(o->input, info.width, info.height, info.bands, info.K, info.hdr)) != GS_OK)
            return s;
        station_json = info.station_json;
        snprintf(src, sizeof src, "%s: camera.station", o->input);
        if (o->survey) set_name(r->survey, o->survey);
        else if (sc->name[0]) set_name(r->survey, sc->name);
        else {
            char stem[256];
            gs_path_base(o->input, 1, stem, sizeof stem);
            set_name(r->survey, stem);
        }
        int len;
        if (o->capture_dir) {
            len = snprintf(r->capture_dir, sizeof r->capture_dir, "%s", o->capture_dir);
        } else {
            char dbdir[4096], stem[256];
            gs_path_dir(o->db_path, dbdir, sizeof dbdir);
            gs_path_base(o->input, 1, stem, sizeof stem);
            len = snprintf(r->capture_dir, sizeof r->capture_dir, "%.3800s/%.200s-capture", dbdir, stem);
        }
        if (len < 0 || (size_t)len >= sizeof r->capture_dir - 64)
            return gs_fail(GS_EINVAL, "%.200s...: capture directory path too long", r->capture_dir);
        if ((s = check_dir_creatable(r->capture_dir, "capture directory")) != GS_OK) return s;
    } else {
        if (o->capture_dir)
            return gs_fail(GS_EINVAL, "--capture-dir is for scene inputs: %s is already a capture "
                           "directory", o->input);
        if (strlen(o->input) >= sizeof r->capture_dir - 64)
            return gs_fail(GS_EINVAL, "%.200s...: capture directory path too long", o->input);
        snprintf(r->capture_dir, sizeof r->capture_dir, "%s", o->input);
        stage(o, SRV_STAGE_READ, "reading %s", o->input);
        double t0 = gs_clock_s(CLOCK_MONOTONIC);
        if ((s = srv_job_read(j, o->input)) != GS_OK) return s;
        r->seconds[SRV_STAGE_READ] += gs_clock_s(CLOCK_MONOTONIC) - t0;
        int d[5] = {j->cap.grid_hz, j->cap.bands, j->cap.K, j->cap.width, j->cap.height};
        memcpy(dims, d, sizeof d);
        station_json = j->cap.station_json;
        snprintf(src, sizeof src, "%s/capture.json: station", o->input);
        char base[256];
        gs_path_base(o->input, 0, base, sizeof base);
        set_name(r->survey, o->survey ? o->survey : base);
    }
    /* the one rule of every export, checked once here (the name is not echoed: it may hold
     * terminal escapes) */
    if (!gs_text_clean(r->survey))
        return gs_fail(GS_EFORMAT, "%s: the survey name (%s) is not UTF-8 text without control "
                       "characters: give --survey NAME", o->input,
                       o->survey ? "--survey" : r->scene && sc->name[0] ? "the scene's name"
                       : r->scene ? "the scene file's name" : "the capture directory's name");
    if (station_json && !o->station_path) {
        if ((s = gis_station_parse(station_json, src, &r->station)) != GS_OK) return s;
        r->has_station = 1;
    }
    return GS_OK;
}

/* 2. The station (a file overrides the capture's) and the lights' height. */
static gs_status station_and_height(const srv_run_opts *o, srv_run_report *r, const cap_scene *sc,
                                    int have_scene, const int dims[5])
{
    gs_status s;
    double sd = 0.0;
    if (o->station_path) {
        if ((s = gis_station_read(o->station_path, &r->station)) != GS_OK) return s;
        r->has_station = 1;
    }
    if (!r->has_station) return GS_OK;
    const gis_camera *c = &r->station.cam;
    if ((s = gis_camera_check(c)) != GS_OK) return s;
    if ((c->width_px > 0 && c->width_px != dims[3]) || (c->height_px > 0 && c->height_px != dims[4]))
        return gs_fail(GS_EINVAL, "%s: the station's image is %dx%d pixels but the capture's is "
                       "%dx%d", o->station_path ? o->station_path : o->input, c->width_px,
                       c->height_px, dims[3], dims[4]);
    if (isfinite(o->light_height_m)) {
        r->light_height_m = o->light_height_m;
        snprintf(r->height_source, sizeof r->height_source, "--light-height-m");
    } else if (have_scene && isfinite(r->light_height_m = scene_median_height(sc, &sd))) {
        snprintf(r->height_source, sizeof r->height_source, "scene median");
        r->light_height_sigma_m = sd;
    } else {
        return gs_fail(GS_EINVAL, "%s: the lights' height is unknown (%s): give --light-height-m "
                       "H, metres above the WGS84 ellipsoid", o->input,
                       have_scene ? "the scene has no geographic light" : "a capture directory");
    }
    if (!isnan(o->light_height_sigma_m)) r->light_height_sigma_m = o->light_height_sigma_m;
    return GS_OK;
}

gs_status srv_run(const srv_run_opts *o, srv_run_report *r)
{
    if (!o || !r) return gs_fail(GS_EINVAL, "srv_run: NULL argument");
    memset(r, 0, sizeof *r);
    r->light_height_m = NAN;
    gs_status s = check_opts(o);
    if (s != GS_OK) return s;

    cap_scene sc;
    memset(&sc, 0, sizeof sc);
    int have_scene = 0, dims[5] = {0};   /* grid_hz, bands, K, width, height */
    cap_backend *be = NULL;
    srv_job j;
    memset(&j, 0, sizeof j);
    srv_db *db = NULL;
    const char *delight_path = o->delight_path;
    char delight_buf[CAP_PATH_MAX];
    double t0;

    /* 1-2. every input, checked in full */
    if ((s = open_input(o, r, &sc, &have_scene, &be, &j, dims)) != GS_OK) goto done;
    if (have_scene && !delight_path && sc.delight[0]) {
        snprintf(delight_buf, sizeof delight_buf, "%s", sc.delight);
        delight_path = delight_buf;
    }
    if ((s = station_and_height(o, r, &sc, have_scene, dims)) != GS_OK) goto done;
    if (have_scene) {
        cap_scene_release(&sc);
        have_scene = 0;
    }
    /* 3. a DELIGHT file and the Eq. 7 templates it gives for this capture: checked now (the
     * built-in database cannot be wrong: for a capture directory it is generated only when it
     * is needed, below; a scene's render has it already) */
    if (delight_path && (s = srv_job_matcher(&j, j.delight_owned, delight_path, dims[0], dims[1], dims[2], &o->eq7)) != GS_OK)
        goto done;

    /* 4. the database: the last check, and the first write */
    if ((s = srv_db_open(o->db_path, SRV_DB_CREATE, &db)) != GS_OK) goto done;

    /* 5. acquire (scene input) */
    if (be) {
        stage(o, SRV_STAGE_CAPTURE, "acquiring %d frames into %s", dims[2], r->capture_dir);
        t0 = gs_clock_s(CLOCK_MONOTONIC);
        s = srv_job_acquire(be, r->capture_dir, o->capture_progress, &r->frames_acquired, &r->frames_kept);
        cap_backend_free(be);
        be = NULL;
        r->seconds[SRV_STAGE_CAPTURE] = gs_clock_s(CLOCK_MONOTONIC) - t0;
        if (s != GS_OK) goto done;
        stage(o, SRV_STAGE_READ, "reading %s", r->capture_dir);
        t0 = gs_clock_s(CLOCK_MONOTONIC);
        if ((s = srv_job_read(&j, r->capture_dir)) != GS_OK) goto done;
        r->seconds[SRV_STAGE_READ] += gs_clock_s(CLOCK_MONOTONIC) - t0;
    }
    /* (capture_dir is at most sizeof - 64 bytes long: checked above, or by gs_capture_read) */
    struct stat sb;
    if (snprintf(r->truth_path, sizeof r->truth_path, "%.4000s/truth.json", r->capture_dir) > 0 &&
        !(stat(r->truth_path, &sb) == 0 && S_ISREG(sb.st_mode)))
        r->truth_path[0] = '\0';

    /* 6. the resume key; a committed capture is skipped */
    stage(o, SRV_STAGE_READ, "hashing %s", r->capture_dir);
    t0 = gs_clock_s(CLOCK_MONOTONIC);
    s = capture_key(r->capture_dir, &j.cap, r->key);
    r->seconds[SRV_STAGE_READ] += gs_clock_s(CLOCK_MONOTONIC) - t0;
    if (s != GS_OK) goto done;
    int64_t survey_id = 0;
    int is_done = 0;
    if (o->survey) {   /* the named survey's; another survey's copy is said (r->also_in) */
        s = srv_db_find_survey(db, r->survey, &survey_id);
        if (s == GS_OK) s = srv_db_capture_done(db, survey_id, r->key, &is_done);
        int64_t other_id;
        char other[64] = "";   /* (no preferred name: any other survey's) */
        if ((s == GS_OK || s == GS_ENOTFOUND) && !is_done) {
            gs_status so = srv_db_capture_survey(db, r->key, &other_id, other);
            if (so == GS_OK) snprintf(r->also_in, sizeof r->also_in, "%s", other);
            else if (so != GS_ENOTFOUND) s = so;
        }
    } else {
        /* any survey's (its default name's first): a scene run names its survey after the
         * scene, a run on its capture directory after the directory */
        s = srv_db_capture_survey(db, r->key, &survey_id, r->survey);
        is_done = s == GS_OK;
    }
    if (s != GS_OK && s != GS_ENOTFOUND) goto done;
    if (is_done) {
        r->skipped = 1;
        r->survey_id = survey_id;
        s = committed_counts(db, survey_id, r);
        goto done;
    }

    /* 7. extract and match */
    stage(o, SRV_STAGE_BLOBS, "extracting lights");
    t0 = gs_clock_s(CLOCK_MONOTONIC);
    rec_blob_opts bo;
    rec_blob_opts_default(&bo);
    bo.threshold_sigma = o->threshold_sigma;
    s = srv_job_extract(&j, &bo);
    r->seconds[SRV_STAGE_BLOBS] = gs_clock_s(CLOCK_MONOTONIC) - t0;
    if (s != GS_OK) goto done;
    stage(o, SRV_STAGE_MATCH, "Eq. 7 on %zu lights%s", j.cat.count, j.matcher ? "" : " (built-in DELIGHT)");
    t0 = gs_clock_s(CLOCK_MONOTONIC);
    if ((s = srv_job_matcher(&j, j.delight_owned, NULL, dims[0], dims[1], dims[2], &o->eq7)) != GS_OK ||
        (s = srv_job_match(&j)) != GS_OK)
        goto done;
    r->lights = j.cat.count;
    r->with_bulb = j.with_bulb;
    srv_drift_note(&j.cap, o->eq7.max_drift_windows, r->drift_note, sizeof r->drift_note);
    r->with_phase = j.with_phase;
    srv_job_drop_pixels(&j);   /* not needed by the rest */
    r->seconds[SRV_STAGE_MATCH] = gs_clock_s(CLOCK_MONOTONIC) - t0;

    /* 8. locate */
    if (r->has_station) {
        stage(o, SRV_STAGE_LOCATE, "%zu lights at %.1f m", j.cat.count, r->light_height_m);
        t0 = gs_clock_s(CLOCK_MONOTONIC);
        if ((s = srv_job_locate(&j, &r->station, r->light_height_m, r->light_height_sigma_m)) != GS_OK) goto done;
        r->located = j.located;
        r->seconds[SRV_STAGE_LOCATE] = gs_clock_s(CLOCK_MONOTONIC) - t0;
    } else {
        r->light_height_m = NAN;
    }

    /* 9. store */
    stage(o, SRV_STAGE_STORE, "DELIGHT, survey and station rows");
    t0 = gs_clock_s(CLOCK_MONOTONIC);
    char abs_dir[4096];
    srv_store_opts so = {.survey = r->survey,
                         .station = r->has_station ? &r->station : NULL,
                         .key = r->key,
                         .path = realpath(r->capture_dir, abs_dir) ? abs_dir : r->capture_dir,
                         .before_commit = before_commit,
                         .ctx = (void *)o};
    s = srv_job_store(&j, db, &so, &r->survey_id, &r->capture_id, &r->skipped);
    r->seconds[SRV_STAGE_STORE] = gs_clock_s(CLOCK_MONOTONIC) - t0;

done:
    srv_job_release(&j);
    if (s == GS_OK) srv_db_close(db);
    else srv_db_close_discard(db);   /* a database this failed run created goes again */
    cap_backend_free(be);
    if (have_scene) cap_scene_release(&sc);
    return s;
}
