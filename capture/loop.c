/* loop.c - the acquisition loop behind one backend interface (sim, replay, hardware): frames
 * 0..K-1, each with the ACam's HDR loop (paper Sec. 6: repeat with the rows of saturated pixels
 * halved until few pixels saturate or rows cannot be halved), written to the capture directory
 * as soon as it is acquired (gs_capture_write_frame: atomic; on a thread while the next frame
 * is acquired), then capture.json. Progress on a
 * TTY. acquisition.json makes an interrupted capture resumable: it holds the configuration's
 * fingerprint and each finished frame's files with sizes and FNV-1a checksums and the index of
 * its first acquisition on the capture's timeline, so a frame that is re-acquired comes out the
 * same as it would have (deterministic backends) and intact frames are never acquired again. */
#include "capture/internal.h"

#include <dirent.h>
#include <jansson.h>
#include <math.h>
#include <pthread.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#define PROGRESS_FILE "acquisition.json"
#define PROGRESS_FORMAT "gridsurvey-acquisition/1"

struct cap_backend {
    const cap_backend_ops *ops;
    void *self;
};

gs_status cap_backend_wrap(const cap_backend_ops *ops, void *self, cap_backend **out)
{
    *out = NULL;
    cap_backend *b = calloc(1, sizeof *b);
    if (!b) {
        ops->free(self);
        return gs_fail(GS_ENOMEM, "backend: out of memory");
    }
    b->ops = ops;
    b->self = self;
    *out = b;
    return GS_OK;
}

void *cap_backend_self(cap_backend *b, const cap_backend_ops *ops)
{
    return b && b->ops == ops ? b->self : NULL;
}

void cap_backend_free(cap_backend *b)
{
    if (!b) return;
    b->ops->free(b->self);
    free(b);
}

const char *cap_backend_name(const cap_backend *b)
{
    return b ? b->ops->name : "(none)";
}


gs_status cap_backend_info(cap_backend *b, cap_acq_info *info)
{
    return b->ops->info(b->self, info);
}

gs_status cap_backend_acquire(cap_backend *b, const cap_acquisition *a, unsigned char *halvings,
                              unsigned short *raw, double *cycles)
{
    return b->ops->acquire(b->self, a, halvings, raw, cycles);
}

gs_status cap_backend_timing(cap_backend *b, cap_acq_timing *t)
{
    t->grid_hz_measured = NAN;
    t->start_s = NAN;
    t->window_half_period_s = t->window_drift_windows = NAN;
    t->probed = 0;
    return b->ops->timing ? b->ops->timing(b->self, t) : GS_OK;
}

void cap_loop_opts_default(cap_loop_opts *o)
{
    o->progress = -1;
    o->stop_after = 0;
    o->force = 0;
    o->hdr = -1;
    o->hdr_max_rounds = -1;
    o->hdr_max_saturated_px = -1;
    o->hdr_whole_passes = 0;
}

/* ------------------------------------------------------------------ progress file */

typedef struct {
    int done;                  /* listed and its files intact */
    long index;                /* its first acquisition */
    long old_index;            /* listed but damaged: the index to acquire it at again (or -1) */
    int passes;
    gs_frame_info f;           /* its cycles and timing (copy_timing; the names are cap's) */
    long bytes, hdr_bytes;
    uint64_t fnv, hdr_fnv;
} frame_state;

/* A frame's optional timing numbers (gs_frame_info, docs/formats.md; NaN: unknown), as
 * acquisition.json carries them over a resume. */
static const struct {
    const char *name;
    size_t offset;
} timing_fields[] = {
    {"grid_hz_measured", offsetof(gs_frame_info, grid_hz_measured)},
    {"start_s", offsetof(gs_frame_info, start_s)},
    {"window_half_period_s", offsetof(gs_frame_info, window_half_period_s)},
    {"window_drift_windows", offsetof(gs_frame_info, window_drift_windows)},
};
#define N_TIMING (sizeof timing_fields / sizeof *timing_fields)
static double *timing(gs_frame_info *f, size_t i)
{
    return (double *)((char *)f + timing_fields[i].offset);
}
static double timing_of(const gs_frame_info *f, size_t i)
{
    return *(const double *)((const char *)f + timing_fields[i].offset);
}

/* dst's cycles and timing numbers from src's (its file names kept). */
static void copy_timing(gs_frame_info *dst, const gs_frame_info *src)
{
    dst->cycles = src->cycles;
    for (size_t i = 0; i < N_TIMING; i++) *timing(dst, i) = timing_of(src, i);
}

static void timing_unknown(gs_frame_info *f)
{
    for (size_t i = 0; i < N_TIMING; i++) *timing(f, i) = NAN;
}

/* Size and checksum of dir/name; -1 bytes when it cannot be read. */
static void file_sum(const char *dir, const char *name, long *bytes, uint64_t *fnv)
{
    char path[CAP_PATH_MAX + GS_PATH_MAX + 2], *text = NULL;
    size_t n = 0;
    *bytes = -1;
    *fnv = 0;
    snprintf(path, sizeof path, "%s/%s", dir, name);
    if (gs_file_read(path, 0, &text, &n) != GS_OK) return;
    *bytes = (long)n;
    *fnv = cap_fnv1a(CAP_FNV_INIT, text, n);
    free(text);
}

static gs_status write_progress(const char *dir, uint64_t fp, long acquisitions, int K,
                                const gs_capture *cap, const frame_state *fs, int complete)
{
    /* plain text, one frame a line, deterministic */
    size_t cap_n = 512 + (size_t)K * 640;
    char *t = malloc(cap_n);
    if (!t) return gs_fail(GS_ENOMEM, "progress: out of memory");
    size_t u = 0;
    u += (size_t)snprintf(t + u, cap_n - u,
                          "{\n  \"format\": \"%s\",\n  \"fingerprint\": \"%016llx\",\n"
                          "  \"acquisitions\": %ld,\n  \"complete\": %s,\n  \"frames\": [",
                          PROGRESS_FORMAT, (unsigned long long)fp, acquisitions,
                          complete ? "true" : "false");
    int first = 1;
    for (int k = 0; k < K; k++) {
        if (!fs[k].done) continue;
        u += (size_t)snprintf(t + u, cap_n - u,
                              "%s\n    {\"k\": %d, \"index\": %ld, \"passes\": %d, \"cycles\": %.17g, "
                              "\"file\": \"%s\", \"bytes\": %ld, \"fnv\": \"%016llx\"",
                              first ? "" : ",", k, fs[k].index, fs[k].passes, fs[k].f.cycles,
                              cap->frames[k].file, fs[k].bytes, (unsigned long long)fs[k].fnv);
        for (size_t i = 0; i < N_TIMING; i++)
            if (isfinite(timing_of(&fs[k].f, i)))
                u += (size_t)snprintf(t + u, cap_n - u, ", \"%s\": %.17g", timing_fields[i].name,
                                      timing_of(&fs[k].f, i));
        if (cap->frames[k].hdr_map[0])
            u += (size_t)snprintf(t + u, cap_n - u,
                                  ", \"hdr_map\": \"%s\", \"hdr_bytes\": %ld, \"hdr_fnv\": \"%016llx\"",
                                  cap->frames[k].hdr_map, fs[k].hdr_bytes,
                                  (unsigned long long)fs[k].hdr_fnv);
        u += (size_t)snprintf(t + u, cap_n - u, "}");
        first = 0;
    }
    u += (size_t)snprintf(t + u, cap_n - u, "\n  ]\n}\n");
    gs_status s = cap_write_in(dir, PROGRESS_FILE, t, u);
    free(t);
    return s;
}

/* Reads dir/acquisition.json: frames whose files are intact become done. *found = 0 when there
 * is none. */
static gs_status read_progress(const char *dir, uint64_t fp, int K, const gs_capture *cap,
                               frame_state *fs, long *acquisitions, int *complete, int *found)
{
    char path[CAP_PATH_MAX + 32];
    snprintf(path, sizeof path, "%s/%s", dir, PROGRESS_FILE);
    *found = 0;
    *complete = 0;
    gs_json *doc;
    gs_status s = gs_json_load(path, 0, &doc);
    if (s == GS_ENOTFOUND) return GS_OK;
    if (s != GS_OK) return s;
    /* read leniently: an entry that does not check out only means its frame is acquired again */
    json_t *root = json_incref(gs_json_root(doc));
    gs_json_free(doc);
    const char *f = json_string_value(json_object_get(root, "format"));
    const char *fps = json_string_value(json_object_get(root, "fingerprint"));
    json_t *frames = json_object_get(root, "frames");
    if (!f || strcmp(f, PROGRESS_FORMAT) || !fps || !json_is_array(frames)) {
        json_decref(root);
        return gs_fail(GS_EFORMAT, "%s: field format: expected \"%s\" with fingerprint and frames",
                       path, PROGRESS_FORMAT);
    }
    char want[20];
    snprintf(want, sizeof want, "%016llx", (unsigned long long)fp);
    if (strcmp(fps, want)) {
        char had[40];
        snprintf(had, sizeof had, "%s", fps);
        json_decref(root);
        return gs_fail(GS_EINVAL, "%s holds an acquisition of another configuration (%s: "
                       "fingerprint %s, this one %s): use another directory or --force to "
                       "start again", dir, PROGRESS_FILE, had, want);
    }
    *found = 1;
    *acquisitions = (long)json_integer_value(json_object_get(root, "acquisitions"));
    *complete = json_is_true(json_object_get(root, "complete"));
    for (size_t i = 0; i < json_array_size(frames); i++) {
        json_t *o = json_array_get(frames, i);
        json_int_t k = json_integer_value(json_object_get(o, "k"));
        if (k < 0 || k >= K) continue;
        frame_state *e = &fs[k];
        e->index = (long)json_integer_value(json_object_get(o, "index"));
        e->passes = (int)json_integer_value(json_object_get(o, "passes"));
        e->f.cycles = json_number_value(json_object_get(o, "cycles"));
        for (size_t t = 0; t < N_TIMING; t++) {
            json_t *jt = json_object_get(o, timing_fields[t].name);
            *timing(&e->f, t) = json_is_number(jt) ? json_number_value(jt) : NAN;
        }
        long bytes = (long)json_integer_value(json_object_get(o, "bytes"));
        const char *fnv = json_string_value(json_object_get(o, "fnv"));
        const char *file = json_string_value(json_object_get(o, "file"));
        uint64_t got;
        long got_bytes;
        int ok = file && fnv && !strcmp(file, cap->frames[k].file);
        if (ok) {
            file_sum(dir, file, &got_bytes, &got);
            char hex[20];
            snprintf(hex, sizeof hex, "%016llx", (unsigned long long)got);
            ok = got_bytes == bytes && !strcmp(hex, fnv);
            e->bytes = bytes;
            e->fnv = got;
        }
        if (ok && cap->frames[k].hdr_map[0]) {
            const char *hm = json_string_value(json_object_get(o, "hdr_map"));
            const char *hf = json_string_value(json_object_get(o, "hdr_fnv"));
            long hb = (long)json_integer_value(json_object_get(o, "hdr_bytes"));
            ok = hm && hf && !strcmp(hm, cap->frames[k].hdr_map);
            if (ok) {
                file_sum(dir, hm, &got_bytes, &got);
                char hex[20];
                snprintf(hex, sizeof hex, "%016llx", (unsigned long long)got);
                ok = got_bytes == hb && !strcmp(hex, hf);
                e->hdr_bytes = hb;
                e->hdr_fnv = got;
            }
        }
        e->done = ok && e->f.cycles > 0;
        e->old_index = e->done || e->index < 0 ? -1 : e->index;
    }
    json_decref(root);
    return GS_OK;
}

/* Temporary files a killed writer left behind (".NAME.<...>tmp<...>" for the files the loop
 * writes: frames, maps, capture.json, acquisition.json, truth.json). */
static void remove_stale_temporaries(const char *dir)
{
    DIR *d = opendir(dir);
    if (!d) return;
    struct dirent *e;
    while ((e = readdir(d))) {
        const char *n = e->d_name;
        if (n[0] != '.' || !strstr(n, "tmp")) continue;
        int ours = !strncmp(n + 1, "frame_", 6) || !strncmp(n + 1, "hdr_", 4) ||
                   !strncmp(n + 1, "capture.json.", 13) || !strncmp(n + 1, PROGRESS_FILE ".", 17) ||
                   !strncmp(n + 1, "truth.json.", 11);
        if (!ours) continue;
        char path[CAP_PATH_MAX + 300];
        snprintf(path, sizeof path, "%s/%s", dir, n);
        unlink(path);
    }
    closedir(d);
}

/* ------------------------------------------------------------------ the frame writer */

/* One frame's files written on a thread of their own while the next frame is acquired (the PNG
 * encoding is a third of a simulated capture's time): the frame's pixels in its own buffers
 * (two slots, used in turn), what its acquisition.json entry records kept with it. Only the
 * loop's thread writes acquisition.json, after the frame's files are complete, so the files a
 * killed run leaves are those of one frame after the other. */
typedef struct {
    unsigned short *raw;
    unsigned char *halv;
    gs_frame_info frames[2];      /* a 2-frame view: the frame, and an unused second one */
    gs_capture view;
    const char *dir;
    int k, passes, maps;
    int pending, threaded;        /* written or being written, not yet recorded; on a thread */
    long index, acquisitions;     /* its first acquisition; the timeline's length after it */
    size_t n_sat;
    pthread_t tid;
    gs_status st;                 /* the thread's outcome, its detail (thread-local there) */
    char detail[512];
    long bytes, hdr_bytes;
    uint64_t fnv, hdr_fnv;
} frame_write;

static void *write_frame_main(void *arg)
{
    frame_write *w = arg;
    w->st = gs_capture_write_frame(w->dir, &w->view, 0);
    if (w->st != GS_OK) {
        snprintf(w->detail, sizeof w->detail, "%s", gs_detail());
        return NULL;
    }
    file_sum(w->dir, w->frames[0].file, &w->bytes, &w->fnv);
    if (w->maps) file_sum(w->dir, w->frames[0].hdr_map, &w->hdr_bytes, &w->hdr_fnv);
    return NULL;
}

/* Start writing slot w (inline when no thread can start). */
static void write_frame_start(frame_write *w)
{
    w->pending = 1;
    w->threaded = pthread_create(&w->tid, NULL, write_frame_main, w) == 0;
    if (!w->threaded) write_frame_main(w);
}

/* Wait for slot w's files; their failure as this thread's. */
static gs_status write_frame_wait(frame_write *w)
{
    if (w->threaded) pthread_join(w->tid, NULL);
    w->threaded = 0;
    return w->st == GS_OK ? GS_OK : gs_fail(w->st, "%s", w->detail);
}

/* Slot w's frame, once its files are complete, into acquisition.json (the timeline as it was
 * after the frame) and the report. */
static gs_status record_frame(frame_write *w, uint64_t fp, int K, const gs_capture *cap, frame_state *fs,
                              cap_loop_report *rep, int progress, double t_start)
{
    w->pending = 0;
    gs_status s = write_frame_wait(w);
    if (s != GS_OK) return s;
    int k = w->k;
    fs[k].done = 1;
    fs[k].index = w->index;
    fs[k].passes = w->passes;
    copy_timing(&fs[k].f, &cap->frames[k]);
    fs[k].bytes = w->bytes;
    fs[k].fnv = w->fnv;
    fs[k].hdr_bytes = w->hdr_bytes;
    fs[k].hdr_fnv = w->hdr_fnv;
    s = write_progress(w->dir, fp, w->acquisitions, K, cap, fs, 0);
    if (s != GS_OK) return s;
    rep->frames_acquired++;
    if (progress)
        fprintf(stderr, "\rcapture: frame %d/%d written (%d pass%s, %zu saturated px)  %.1f s   ", k + 1, K,
                w->passes, w->passes > 1 ? "es" : "", w->n_sat, gs_clock_s(CLOCK_MONOTONIC) - t_start);
    return GS_OK;
}

/* ------------------------------------------------------------------ the loop */

/* The resume state of dir (nothing with force): each frame's, the acquisitions so far, the
 * frames kept (rep->frames_kept), and *complete when every frame is kept and capture.json is
 * written. */
static gs_status resume_state(const char *dir, uint64_t fp, int K, int force, gs_capture *cap, frame_state *fs,
                              cap_loop_report *rep, long *acquisitions, int *complete)
{
    int done = 0, found = 0;
    *complete = 0;
    *acquisitions = 0;
    if (!force) {
        gs_status s = read_progress(dir, fp, K, cap, fs, acquisitions, &done, &found);
        if (s != GS_OK) return s;
    }
    if (!found) {
        for (int k = 0; k < K; k++) {
            memset(&fs[k], 0, sizeof fs[k]);
            fs[k].index = fs[k].old_index = -1;
            timing_unknown(&fs[k].f);
        }
        *acquisitions = 0;
    }
    rep->frames_kept = 0;
    for (int k = 0; k < K; k++)
        if (fs[k].done) {
            copy_timing(&cap->frames[k], &fs[k].f);
            rep->frames_kept++;
        }
    char path[CAP_PATH_MAX + 32];
    struct stat sb;
    snprintf(path, sizeof path, "%s/capture.json", dir);
    *complete = found && done && rep->frames_kept == K && stat(path, &sb) == 0;
    return GS_OK;
}

gs_status cap_loop_run(cap_backend *b, const char *dir, const cap_loop_opts *o_in,
                       cap_loop_report *rep)
{
    cap_loop_opts o;
    if (o_in) o = *o_in;
    else cap_loop_opts_default(&o);
    cap_loop_report dummy;
    if (!rep) rep = &dummy;
    memset(rep, 0, sizeof *rep);
    double t_start = gs_clock_s(CLOCK_MONOTONIC);
    cap_acq_info info;
    gs_status s = cap_backend_info(b, &info);
    if (s != GS_OK) return s;
    int hdr = o.hdr < 0 ? info.hdr : o.hdr;
    if (info.fixed_halvings) hdr = 0;
    if (hdr && info.max_halvings < 1)
        return gs_fail(GS_EINVAL, "%s backend: HDR needs masks that can be halved (this "
                       "configuration allows %d rounds)", cap_backend_name(b), info.max_halvings);
    if (hdr && o.hdr_max_rounds > info.max_halvings)
        return gs_fail(GS_EINVAL, "HDR rounds (--max-rounds %d): expected at most %d, the exact "
                       "halvings of this %s configuration's masks and cycles (paper Sec. 6)",
                       o.hdr_max_rounds, info.max_halvings, cap_backend_name(b));
    int rounds = o.hdr_max_rounds >= 0 ? o.hdr_max_rounds : info.hdr_max_rounds;
    if (rounds <= 0 || rounds > info.max_halvings) rounds = info.max_halvings;
    int max_sat = o.hdr_max_saturated_px >= 0 ? o.hdr_max_saturated_px : info.hdr_max_saturated_px;
    if (!hdr) rounds = 0;
    uint64_t fp = info.fingerprint;
    int cfg[3] = {hdr, rounds, max_sat};
    fp = cap_fnv1a(fp, cfg, sizeof cfg);
    int progress = o.progress < 0 ? isatty(STDERR_FILENO) : o.progress;
    int K = info.K;
    size_t plane = (size_t)info.width * (size_t)info.height;
    size_t nraw = plane * (size_t)info.bands;

    gs_capture cap;
    memset(&cap, 0, sizeof cap);
    int lock_fd = -1, made_dir = 0;
    frame_write wr[2];   /* the frame being acquired and the one being written, in turn */
    memset(wr, 0, sizeof wr);
    int cur = 0;   /* the slot of the frame being acquired */
    cap.grid_hz = info.grid_hz;
    cap.K = K;
    cap.bands = info.bands;
    cap.width = info.width;
    cap.height = info.height;
    cap.saturation_dn = info.saturation_dn;
    cap.black_level_dn = info.black_level_dn;
    cap.gain_e_per_dn = info.gain_e_per_dn;
    cap.read_noise_dn = info.read_noise_dn;
    cap.locked = info.locked;
    cap.window_period = info.window_period;
    snprintf(cap.utc, sizeof cap.utc, "%s", info.utc);
    for (int i = 0; i < 2; i++) {
        wr[i].raw = malloc(nraw * sizeof *wr[i].raw);
        wr[i].halv = calloc(plane ? plane : 1, 1);
    }
    cap.frames = calloc((size_t)K, sizeof *cap.frames);
    frame_state *fs = calloc((size_t)K, sizeof *fs);
    if (info.station_json) cap.station_json = strdup(info.station_json);
    if (!wr[0].raw || !wr[0].halv || !wr[1].raw || !wr[1].halv || !cap.frames || !fs ||
        (info.station_json && !cap.station_json)) {
        s = gs_fail(GS_ENOMEM, "capture loop: cannot hold a %d x %d x %d frame", info.width,
                    info.height, info.bands);
        goto done;
    }
    int maps = hdr || info.fixed_halvings;
    for (int k = 0; k < K; k++) {
        snprintf(cap.frames[k].file, GS_PATH_MAX, "frame_%03d.png", k);
        cap.frames[k].k = k;
        cap.frames[k].cycles = (double)info.cycles;
        timing_unknown(&cap.frames[k]);
        if (maps) snprintf(cap.frames[k].hdr_map, GS_PATH_MAX, "hdr_%03d.png", k);
        fs[k].index = -1;
        fs[k].old_index = -1;
        timing_unknown(&fs[k].f);
    }
    /* (made by this process: its own mkdir succeeded; another's, made meanwhile, is not removed) */
    made_dir = mkdir(dir, 0777) == 0;
    if (!made_dir && (s = gs_dir_ensure(dir)) != GS_OK) goto done;
    /* a complete capture is found under the directory's shared lock, as its readers hold it; one
     * to acquire into under the exclusive one, one writer at a time (the lock goes with the
     * process, killed or not): another's temporaries are not stale, and each reads, then
     * rewrites, acquisition.json. The progress is read again once it is held. */
    long acquisitions = 0;
    for (int writer = 0; writer < 2; writer++) {
        gs_capture_unlock(lock_fd);
        if ((s = gs_capture_lock(dir, writer, &lock_fd)) != GS_OK) {
            made_dir = 0;   /* (the writer holding it, or a reader, may not be done) */
            if (!writer)    /* (the shared lock's refusal is a reader's; a writer may go elsewhere) */
                s = gs_fail(s, "%s, or give another directory", gs_detail());
            goto done;
        }
        if (writer) remove_stale_temporaries(dir);
        int complete = 0;
        if ((s = resume_state(dir, fp, K, o.force, &cap, fs, rep, &acquisitions, &complete)) != GS_OK) goto done;
        if (complete) {
            rep->complete = 1;
            rep->acquisitions = acquisitions;
            if (progress) fprintf(stderr, "capture: %s is complete (%d frames); nothing to do\n", dir, K);
            goto done;
        }
    }
    /* each slot's 2-frame view of the capture writes one frame from the slot's buffers */
    for (int i = 0; i < 2; i++) {
        wr[i].view = cap;
        wr[i].view.K = 2;
        wr[i].view.frames = wr[i].frames;
        wr[i].view.raw = wr[i].raw;
        wr[i].view.halvings = maps ? wr[i].halv : NULL;
        wr[i].view.station_json = NULL;
        wr[i].dir = dir;
        wr[i].maps = maps;
    }
    unsigned short *raw = wr[0].raw;
    unsigned char *halv = wr[0].halv;
    int stopped = 0;
    for (int k = 0; k < K; k++) {
        if (fs[k].done) continue;
        if (o.stop_after > 0 && rep->frames_acquired + wr[cur ^ 1].pending >= o.stop_after) {
            stopped = 1;
            break;
        }
        /* a frame listed but damaged keeps its place on the timeline */
        long index = fs[k].old_index >= 0 ? fs[k].old_index : acquisitions;
        memset(halv, 0, plane);
        int pass = 0;
        size_t n_sat = 0;
        double cycles = (double)info.cycles;
        cap_acq_timing tm;
        for (;;) {
            /* a pass that more rounds may follow: a probe will do (its saturated pixels) */
            cap_acquisition a = {k, pass, index + pass, hdr && pass < rounds && !o.hdr_whole_passes, max_sat};
            s = cap_backend_acquire(b, &a, halv, raw, &cycles);
            if (s != GS_OK) goto done;
            /* the timing of the exposure that is kept: the last one */
            if ((s = cap_backend_timing(b, &tm)) != GS_OK) goto done;
            rep->probes += tm.probed;
            if (!hdr) {
                if (progress) {
                    n_sat = 0;
                    for (size_t p = 0; p < plane; p++) {
                        int sat = 0;
                        for (int bd = 0; bd < info.bands; bd++)
                            sat |= raw[p * (size_t)info.bands + (size_t)bd] >= info.saturation_dn;
                        n_sat += (size_t)sat;
                    }
                }
                break;
            }
            size_t halved = 0;
            /* the HDR loop: halve the rows of saturated pixels (paper Sec. 6) */
            if (pass >= rounds) {
                s = cap_hdr_update(raw, info.width, info.height, info.bands, info.saturation_dn,
                                   0, halv, &n_sat, &halved);
                if (s != GS_OK) goto done;
                break;
            }
            unsigned char *trial = malloc(plane);
            if (!trial) {
                s = gs_fail(GS_ENOMEM, "capture loop: out of memory");
                goto done;
            }
            memcpy(trial, halv, plane);
            s = cap_hdr_update(raw, info.width, info.height, info.bands, info.saturation_dn,
                               rounds, trial, &n_sat, &halved);
            if (s != GS_OK || n_sat <= (size_t)max_sat || halved == 0) {
                free(trial);
                if (s != GS_OK) goto done;
                if (tm.probed) {   /* the probe is the frame's last pass: acquired again whole */
                    a.probe = 0;
                    rep->probes_kept++;
                    if ((s = cap_backend_acquire(b, &a, halv, raw, &cycles)) != GS_OK ||
                        (s = cap_backend_timing(b, &tm)) != GS_OK)
                        goto done;
                }
                break;
            }
            memcpy(halv, trial, plane);
            free(trial);
            pass++;
            if (progress)
                fprintf(stderr, "\rcapture: frame %d/%d  HDR round %d: %zu saturated px, %zu halved   ",
                        k + 1, K, pass, n_sat, halved);
        }
        rep->saturated_px += n_sat;
        if (pass + 1 > rep->max_passes) rep->max_passes = pass + 1;
        if (index + pass + 1 > acquisitions) acquisitions = index + pass + 1;
        cap.frames[k].cycles = cycles;
        /* only what capture.json accepts (docs/formats.md); anything else is unknown */
        cap.frames[k].grid_hz_measured =
            isfinite(tm.grid_hz_measured) && tm.grid_hz_measured >= 45 && tm.grid_hz_measured <= 65
                ? tm.grid_hz_measured : NAN;
        cap.frames[k].start_s = isfinite(tm.start_s) && tm.start_s >= 0 ? tm.start_s : NAN;
        cap.frames[k].window_half_period_s =
            !info.locked && tm.window_half_period_s >= GS_WINDOW_HALF_PERIOD_MIN_S &&
                    tm.window_half_period_s <= GS_WINDOW_HALF_PERIOD_MAX_S
                ? tm.window_half_period_s : NAN;
        cap.frames[k].window_drift_windows =
            !info.locked && tm.window_drift_windows >= 0 && isfinite(tm.window_drift_windows)
                ? tm.window_drift_windows : NAN;
        frame_write *w = &wr[cur];
        w->frames[0] = cap.frames[k];
        w->frames[1] = cap.frames[k];
        snprintf(w->frames[1].file, GS_PATH_MAX, "unused_%03d.png", k);
        w->frames[1].hdr_map[0] = '\0';
        w->k = k;
        w->index = index;
        w->passes = pass + 1;
        w->acquisitions = acquisitions;
        w->n_sat = n_sat;
        w->st = GS_OK;
        /* the previous frame recorded once its files are complete, then this one written while
         * the next is acquired */
        if (wr[cur ^ 1].pending && (s = record_frame(&wr[cur ^ 1], fp, K, &cap, fs, rep, progress, t_start)) != GS_OK)
            goto done;
        write_frame_start(w);
        cur ^= 1;
        raw = wr[cur].raw;
        halv = wr[cur].halv;
    }
    if (wr[cur ^ 1].pending && (s = record_frame(&wr[cur ^ 1], fp, K, &cap, fs, rep, progress, t_start)) != GS_OK)
        goto done;
    if (progress) fputc('\n', stderr);
    rep->acquisitions = acquisitions;
    if (stopped) {
        s = GS_OK;
        goto done;
    }
    s = gs_capture_write_json(dir, &cap);
    if (s != GS_OK) goto done;
    s = write_progress(dir, fp, acquisitions, K, &cap, fs, 1);
    if (s != GS_OK) goto done;
    rep->complete = 1;
done:
    if (wr[cur ^ 1].pending) {
        /* a frame written before the failure is recorded, as one after the other would have */
        char why[512];
        snprintf(why, sizeof why, "%s", gs_detail());
        gs_status s1 = record_frame(&wr[cur ^ 1], fp, K, &cap, fs, rep, progress, t_start);
        s = s1 != GS_OK ? s1 : gs_fail(s, "%s", why);
    }
    rep->seconds = gs_clock_s(CLOCK_MONOTONIC) - t_start;
    for (int i = 0; i < 2; i++) {
        free(wr[i].raw);
        free(wr[i].halv);
    }
    free(fs);
    gs_capture_release(&cap);
    gs_capture_unlock(lock_fd);
    if (made_dir && s != GS_OK) rmdir(dir);   /* (only if nothing was written to it) */
    return s;
}
