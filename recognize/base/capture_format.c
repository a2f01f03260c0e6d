/* capture_format.c - the capture directory, format "gridsurvey-capture/1" (docs/formats.md has
 * the full specification; this file is its one reader and writer, capture_check.c its rules).
 *
 * A capture is the ACam's K-frame sequence of one flicker cycle (paper Sec. 6): frame k
 * integrates window [k Delta/K, (k+1) Delta/K) of each of C cycles, and a pixel the HDR loop
 * halved h times integrated C / 2^h cycles. The directory holds capture.json and one 16-bit PNG
 * per frame, plus optional 8-bit HDR maps of h.
 *
 * Reading checks everything before trusting it, through the format kit: JSON syntax and every
 * field's type and range (the detail names the file, the JSON line of the field, the field and
 * the expected value), k = 0..K-1 each once, and each PNG (png.c: chunk structure, CRCs, size,
 * bit depth and colour type). Writing validates with the same rules, so the writer never
 * produces a directory that the reader rejects, and replaces each file atomically. */
#include "recognize/base/internal.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#define CAPTURE_JSON "capture.json"
#define PATH_BUF 1024
/* capture.json is a few hundred bytes per frame: 64 MiB bounds a file that is not one */
#define JSON_MAX_BYTES ((size_t)64 << 20)

/* ------------------------------------------------------------------ reading */

typedef struct {
    const gs_json *doc;      /* DIR/capture.json */
    int *pos;                /* pos[k]: position of frame k in the frames array (owned) */
} reader;

static gs_status bad_field(const reader *r, const char *field, const char *expect)
{
    return gs_json_fail(r->doc, GS_EFORMAT, field, "expected %s", expect);
}

/* An integer member in [lo, hi] (the expected value named as expect) into an int. */
static gs_status get_int(const reader *r, json_t *obj, const char *path, const char *key,
                         int required, int dflt, long long lo, long long hi, const char *expect,
                         int *out)
{
    long long v;
    gs_status st = gs_json_get_int(r->doc, obj, path, key, required, dflt, lo, hi, expect, &v);
    if (st == GS_OK) *out = (int)v;
    return st;
}

/* A JSON number (integer or real); the range is checked by gs_capture_check_fields. */
static gs_status get_number(const reader *r, json_t *obj, const char *path, const char *key,
                            int required, double dflt, const char *expect, double *out)
{
    return gs_json_get_num(r->doc, obj, path, key, required, dflt, -HUGE_VAL, HUGE_VAL, expect, out);
}

static gs_status get_file_name(const reader *r, json_t *obj, const char *path, const char *key,
                               int required, char *out)
{
    const char *expect = required ? GS_CAPTURE_EXP_FILE : "\"\" (no map) or " GS_CAPTURE_EXP_FILE;
    char field[64];
    gs_json_path(field, sizeof field, path, key);
    json_t *v = json_object_get(obj, key);
    if (!v) {
        if (required) return gs_json_fail(r->doc, GS_EFORMAT, field, "expected %s (the field is missing)", expect);
        out[0] = '\0';
        return GS_OK;
    }
    if (!json_is_string(v)) return bad_field(r, field, expect);
    if (!required && json_string_value(v)[0] == '\0') {
        out[0] = '\0';
        return GS_OK;
    }
    if (!gs_capture_valid_name(json_string_value(v))) return bad_field(r, field, expect);
    snprintf(out, GS_PATH_MAX, "%s", json_string_value(v));
    return GS_OK;
}

static const char *const top_keys[] = {
    "format", "grid_hz", "K", "bands", "width", "height", "saturation", "black_level",
    "gain_e_per_dn", "read_noise_dn", "locked", "window_period", "utc", "station", "frames", NULL};
static const char *const frame_keys[] = {"file", "k", "cycles", "hdr_map", "grid_hz_measured",
                                         "start_s", "window_half_period_s", "window_drift_windows", NULL};

/* One frame object (array position i) into cap->frames[k], k its own field. */
static gs_status parse_frame(reader *r, json_t *f, int i, gs_capture *cap)
{
    char path[32], field[64], expect_k[64];
    snprintf(path, sizeof path, "frames[%d]", i);
    if (!json_is_object(f)) return bad_field(r, path, "an object with file, k and cycles");
    gs_status st = gs_json_check_keys(r->doc, f, path, frame_keys);
    if (st != GS_OK) return st;
    gs_frame_info info;
    memset(&info, 0, sizeof info);
    snprintf(expect_k, sizeof expect_k, "an integer from 0 to K-1 = %d", cap->K - 1);
    int k;
    if ((st = get_int(r, f, path, "k", 1, 0, 0, cap->K - 1, expect_k, &k)) != GS_OK) return st;
    if (r->pos[k] >= 0) {
        snprintf(field, sizeof field, "%s.k", path);
        return gs_json_fail(r->doc, GS_EFORMAT, field, "expected each k from 0 to %d exactly once "
                            "(k = %d is also frames[%d].k)", cap->K - 1, k, r->pos[k]);
    }
    r->pos[k] = i;
    info.k = k;
    if ((st = get_number(r, f, path, "cycles", 1, 0, GS_CAPTURE_EXP_CYCLES, &info.cycles)) != GS_OK)
        return st;
    if (!(isfinite(info.cycles) && info.cycles > 0)) {
        snprintf(field, sizeof field, "%s.cycles", path);
        return bad_field(r, field, GS_CAPTURE_EXP_CYCLES);
    }
    /* the optional ranges are checked by gs_capture_check_fields */
    if ((st = get_file_name(r, f, path, "file", 1, info.file)) != GS_OK ||
        (st = get_file_name(r, f, path, "hdr_map", 0, info.hdr_map)) != GS_OK ||
        (st = get_number(r, f, path, "grid_hz_measured", 0, NAN, GS_CAPTURE_EXP_HZ_MEASURED,
                         &info.grid_hz_measured)) != GS_OK ||
        (st = get_number(r, f, path, "start_s", 0, NAN, GS_CAPTURE_EXP_START, &info.start_s)) != GS_OK ||
        (st = get_number(r, f, path, "window_half_period_s", 0, NAN, GS_CAPTURE_EXP_WINDOW_PERIOD,
                         &info.window_half_period_s)) != GS_OK ||
        (st = get_number(r, f, path, "window_drift_windows", 0, NAN, GS_CAPTURE_EXP_WINDOW_DRIFT,
                         &info.window_drift_windows)) != GS_OK)
        return st;
    cap->frames[k] = info;
    return GS_OK;
}

/* Fill the scalar fields and the frames table of cap from the parsed document. */
static gs_status parse_capture(reader *r, gs_capture *cap)
{
    json_t *root = gs_json_root(r->doc);
    gs_status st;
    if (!json_is_object(root)) return bad_field(r, "(document)", "a JSON object");
    json_t *fmt = json_object_get(root, "format");
    if (!fmt) return bad_field(r, "format", GS_CAPTURE_EXP_FORMAT " (the field is missing)");
    if (!json_is_string(fmt) || strcmp(json_string_value(fmt), GS_CAPTURE_FORMAT) != 0)
        return bad_field(r, "format", GS_CAPTURE_EXP_FORMAT);
    if ((st = gs_json_check_keys(r->doc, root, "", top_keys)) != GS_OK) return st;
    if ((st = get_int(r, root, "", "grid_hz", 1, 0, 50, 60, GS_CAPTURE_EXP_GRID, &cap->grid_hz)) ||
        (st = get_int(r, root, "", "K", 1, 0, 2, GS_CAPTURE_MAX_K, GS_CAPTURE_EXP_K, &cap->K)) ||
        (st = get_int(r, root, "", "bands", 1, 0, 1, 3, GS_CAPTURE_EXP_BANDS, &cap->bands)) ||
        (st = get_int(r, root, "", "width", 1, 0, 1, GS_CAPTURE_MAX_SIDE, GS_CAPTURE_EXP_SIDE,
                      &cap->width)) ||
        (st = get_int(r, root, "", "height", 1, 0, 1, GS_CAPTURE_MAX_SIDE, GS_CAPTURE_EXP_SIDE,
                      &cap->height)) ||
        (st = get_number(r, root, "", "saturation", 1, 0, "a number > black_level and <= 65536",
                         &cap->saturation_dn)) ||
        (st = get_number(r, root, "", "black_level", 0, 0, "a number >= 0 and < 65536",
                         &cap->black_level_dn)) ||
        (st = get_number(r, root, "", "gain_e_per_dn", 0, 0, GS_CAPTURE_EXP_NONNEG,
                         &cap->gain_e_per_dn)) ||
        (st = get_number(r, root, "", "read_noise_dn", 0, 1, GS_CAPTURE_EXP_NONNEG,
                         &cap->read_noise_dn)) ||
        (st = gs_json_get_bool(r->doc, root, "", "locked", 0, 1, &cap->locked)))
        return st;
    json_t *v = json_object_get(root, "window_period");
    if (v) {   /* (only with locked false: gs_capture_check_fields) */
        const char *name = json_string_value(v);
        for (int p = GS_PERIOD_MEASURED; name && p <= GS_PERIOD_NOMINAL && !cap->window_period; p++)
            if (!strcmp(name, gs_period_name(p))) cap->window_period = p;
        if (!cap->window_period && name)
            return gs_json_fail(r->doc, GS_EFORMAT, "window_period", "expected " GS_CAPTURE_EXP_PERIOD_NAME
                                ", not \"%.40s\"", name);
        if (!cap->window_period) return bad_field(r, "window_period", GS_CAPTURE_EXP_PERIOD_NAME " (a string)");
    }
    v = json_object_get(root, "utc");
    if (v) {
        if (!json_is_string(v) || !gs_capture_valid_utc(json_string_value(v)))
            return bad_field(r, "utc", GS_CAPTURE_EXP_UTC);
        snprintf(cap->utc, sizeof cap->utc, "%s", json_string_value(v));
    }
    v = json_object_get(root, "station");
    if (v) {
        if (!json_is_object(v)) return bad_field(r, "station", "a JSON object");
        gs_text t = {0};
        gs_text_json(&t, v);
        if (t.oom) {
            free(t.s);
            return gs_fail(GS_ENOMEM, "%s: cannot copy the station object", gs_json_source(r->doc));
        }
        cap->station_json = t.s;
    }

    json_t *frames = json_object_get(root, "frames");
    if (!frames || !json_is_array(frames) || json_array_size(frames) != (size_t)cap->K)
        return gs_json_fail(r->doc, GS_EFORMAT, "frames", "expected an array of K = %d frame "
                            "objects (%s)", cap->K, !frames ? "the field is missing"
                            : !json_is_array(frames) ? "not an array" : "wrong length");
    cap->frames = calloc((size_t)cap->K, sizeof *cap->frames);
    r->pos = malloc((size_t)cap->K * sizeof *r->pos);
    if (!cap->frames || !r->pos)
        return gs_fail(GS_ENOMEM, "%s: cannot hold %d frames", gs_json_source(r->doc), cap->K);
    for (int k = 0; k < cap->K; k++) r->pos[k] = -1;
    for (int i = 0; i < cap->K; i++)
        if ((st = parse_frame(r, json_array_get(frames, (size_t)i), i, cap)) != GS_OK) return st;
    gs_capture_problem pr;
    if (gs_capture_check_fields(cap, &pr)) return GS_OK;
    /* the rules name frames by k; the file names them by array position */
    int idx;
    char field[64];
    if (sscanf(pr.field, "frames[%d]", &idx) == 1 && idx >= 0 && idx < cap->K)
        snprintf(field, sizeof field, "frames[%d]%s", r->pos[idx], strchr(pr.field, ']') + 1);
    else
        snprintf(field, sizeof field, "%s", pr.field);
    return bad_field(r, field, pr.expect);
}

/* The largest PNG file of that image we accept: twice its samples plus 1 MiB (deflate's
 * stored blocks, row filters and chunk headers add far less), so that a frame file cannot be
 * larger than any PNG of its declared size. */
static size_t png_max_bytes(int width, int height, int channels, int bits)
{
    return 2 * (size_t)width * (size_t)height * (size_t)channels * (size_t)(bits / 8) + ((size_t)1 << 20);
}

static void file_ref(const reader *r, char *ref, size_t cap, const char *fmt, int i);

/* Before anything is allocated: every file the capture names is a regular file no larger than
 * a PNG of the declared size, and the pixels plus recognition's working images fit the memory
 * budget (gs_mem_check). */
static gs_status check_before_reading(const char *dir, const reader *r, const gs_capture *cap,
                                      const char *json_path)
{
    char path[PATH_BUF], ref[160];
    int maps = 0;
    for (int k = 0; k < cap->K; k++)
        for (int m = 0; m < 2; m++) {
            const char *file = m ? cap->frames[k].hdr_map : cap->frames[k].file;
            if (!file[0]) continue;
            maps += m;
            file_ref(r, ref, sizeof ref, m ? "frames[%d].hdr_map" : "frames[%d].file", r->pos[k]);
            if (!gs_path_join(path, sizeof path, dir, file))
                return gs_fail(GS_EINVAL, "%s/%s: path too long", dir, file);
            gs_status st = gs_input_check(path);
            if (st != GS_OK) return gs_fail(st, "%s%s", gs_detail(), ref);
            struct stat sb;
            size_t max = m ? png_max_bytes(cap->width, cap->height, 1, 8)
                           : png_max_bytes(cap->width, cap->height, cap->bands, 16);
            if (stat(path, &sb) == 0 && (size_t)sb.st_size > max)
                return gs_fail(GS_EFORMAT, "%s: %lld bytes: larger than any PNG of %dx%d pixels "
                               "(at most %zu bytes)%s", path, (long long)sb.st_size, cap->width,
                               cap->height, max, ref);
        }
    return gs_capture_budget(json_path, cap->width, cap->height, cap->bands, cap->K, maps > 0);
}

gs_status gs_capture_budget(const char *source, int width, int height, int bands, int K, int hdr_maps)
{
    double plane = (double)width * (double)height;
    double samples = plane * K * bands;
    double bytes = samples * ((double)sizeof(unsigned short) + GS_WORK_BYTES_PER_SAMPLE) +
                   plane * K * (hdr_maps ? 1.0 : 0.0) + plane * GS_WORK_BYTES_PER_PIXEL;
    char what[PATH_BUF + 200];
    snprintf(what, sizeof what, "%.*s: %d frames of %dx%dx%d samples and the working images of "
             "their processing (%d B per pixel, %d per sample)", PATH_BUF, source, K, width, height,
             bands, GS_WORK_BYTES_PER_PIXEL, GS_WORK_BYTES_PER_SAMPLE);
    return gs_mem_check(bytes, what);
}

/* Read dir/file, which must be a width x height PNG of `channels` channels (grey or RGB) with
 * `bits` bits per sample, into out (R, G, B order). */
static gs_status read_png(const char *dir, const char *file, const char *ref, int width,
                          int height, int channels, int bits, void *out)
{
    char path[PATH_BUF];
    if (!gs_path_join(path, sizeof path, dir, file))
        return gs_fail(GS_EINVAL, "%s/%s: path too long", dir, file);
    char *buf;
    size_t n;
    gs_status st = gs_file_read(path, png_max_bytes(width, height, channels, bits), &buf, &n);
    if (st != GS_OK) return gs_fail(st, "%s%s", gs_detail(), ref);
    st = gs_png_decode((const unsigned char *)buf, n, path, ref, width, height, channels, bits, out);
    free(buf);
    return st;
}

/* " (capture.json:LINE: FIELD)" for the detail of a file that FIELD names. */
static void file_ref(const reader *r, char *ref, size_t cap, const char *fmt, int i)
{
    char field[64];
    snprintf(field, sizeof field, fmt, i);
    snprintf(ref, cap, " (%s:%d: %s)", CAPTURE_JSON, gs_json_line(r->doc, field), field);
}

/* Frames [k0, k1) of a capture whose sizes are checked and buffers allocated: each PNG and its
 * HDR map, the references of their fields made beforehand. */
typedef struct {
    const char *dir;
    gs_capture *cap;
    char (*ref)[2][160];   /* [K]: frames[k].file, frames[k].hdr_map */
} frame_refs;

static gs_status read_frames(void *ctx, int part, size_t k0, size_t k1)
{
    (void)part;
    const frame_refs *fr = ctx;
    const gs_capture *cap = fr->cap;
    size_t plane = (size_t)cap->width * (size_t)cap->height;
    gs_status st = GS_OK;
    for (size_t k = k0; st == GS_OK && k < k1; k++) {
        const gs_frame_info *f = &cap->frames[k];
        st = read_png(fr->dir, f->file, fr->ref[k][0], cap->width, cap->height, cap->bands, 16,
                      cap->raw + plane * (size_t)cap->bands * k);
        if (st != GS_OK || !f->hdr_map[0]) continue;
        unsigned char *h = cap->halvings + plane * k;
        st = read_png(fr->dir, f->hdr_map, fr->ref[k][1], cap->width, cap->height, 1, 8, h);
        for (size_t p = 0; st == GS_OK && p < plane; p++)
            if (h[p] > GS_MAX_HALVINGS)
                st = gs_fail(GS_EFORMAT, "%s/%s: pixel (x %zu, y %zu) holds %d halvings: expected 0 to "
                             "%d%s", fr->dir, f->hdr_map, p % (size_t)cap->width, p / (size_t)cap->width,
                             h[p], GS_MAX_HALVINGS, fr->ref[k][1]);
    }
    return st;
}

gs_status gs_capture_lock(const char *dir, int exclusive, int *fd)
{
    *fd = open(dir, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (*fd >= 0 && flock(*fd, (exclusive ? LOCK_EX : LOCK_SH) | LOCK_NB) == 0) return GS_OK;
    int e = errno;
    gs_capture_unlock(*fd);
    *fd = -1;
    if (e == EWOULDBLOCK)
        return gs_fail(GS_EIO, "%s: another process is acquiring into this capture directory%s: wait "
                       "for it to end%s", dir, exclusive ? " or reading it" : "",
                       exclusive ? ", or give another directory" : "");
    if (!exclusive) return GS_OK;   /* (a reader of a directory it cannot open, or without locks) */
    return gs_fail(GS_EIO, "%s: cannot lock the capture directory: %s", dir, strerror(e));
}

void gs_capture_unlock(int fd)
{
    if (fd >= 0) close(fd);
}

static gs_status read_locked(const char *dir, gs_capture *cap);

gs_status gs_capture_read(const char *dir, gs_capture *cap)
{
    if (!dir || !cap) return gs_fail(GS_EINVAL, "gs_capture_read: NULL argument");
    int fd = -1;
    gs_status st = gs_capture_lock(dir, 0, &fd);
    if (st == GS_OK) st = gs_capture_read_held(dir, cap);
    else memset(cap, 0, sizeof *cap);
    gs_capture_unlock(fd);
    return st;
}

gs_status gs_capture_read_held(const char *dir, gs_capture *cap)
{
    if (!dir || !cap) return gs_fail(GS_EINVAL, "gs_capture_read_held: NULL argument");
    memset(cap, 0, sizeof *cap);
    struct stat sb;
    int there = stat(dir, &sb) == 0;
    if (there && !S_ISDIR(sb.st_mode))
        return gs_fail(GS_EINVAL, "%s: not a directory: expected a capture directory (a scene file? "
                       "gridsurvey simulate SCENE --out-dir DIR renders one; docs/formats.md)", dir);
    if (!there && errno == ENOENT)
        return gs_fail(GS_ENOTFOUND, "%s: no such directory: expected a capture directory (gridsurvey "
                       "simulate SCENE --out-dir DIR renders one; docs/formats.md)", dir);
    return read_locked(dir, cap);
}

static gs_status read_locked(const char *dir, gs_capture *cap)
{
    reader r;
    memset(&r, 0, sizeof r);
    char json_path[PATH_BUF];
    if (!gs_path_join(json_path, sizeof json_path, dir, CAPTURE_JSON))
        return gs_fail(GS_EINVAL, "%s: path too long", dir);
    gs_json *doc;
    gs_status st = gs_json_load(json_path, JSON_MAX_BYTES, &doc);
    if (st != GS_OK) return st;
    r.doc = doc;
    st = parse_capture(&r, cap);
    if (st == GS_OK) st = check_before_reading(dir, &r, cap, json_path);

    /* the pixels: every frame and its HDR map, the frames split over the CPUs (each into its
     * own slice; the error is the first frame's in k order, as one after the other) */
    size_t plane = (size_t)cap->width * (size_t)cap->height;
    frame_refs fr = {dir, cap, NULL};
    int hdr_maps = 0;
    for (int k = 0; st == GS_OK && k < cap->K; k++) hdr_maps |= cap->frames[k].hdr_map[0] != '\0';
    if (st == GS_OK && cap->K > 0) {
        fr.ref = malloc(sizeof *fr.ref * (size_t)cap->K);
        cap->raw = calloc(plane * (size_t)cap->K * (size_t)cap->bands, sizeof *cap->raw);
        if (!fr.ref || !cap->raw)
            st = gs_fail(GS_ENOMEM, "%s: cannot hold %d frames of %dx%dx%d samples", json_path, cap->K,
                         cap->width, cap->height, cap->bands);
        if (st == GS_OK && hdr_maps && !(cap->halvings = calloc(plane * (size_t)cap->K, 1)))
            st = gs_fail(GS_ENOMEM, "%s: cannot hold the HDR maps", json_path);
        for (int k = 0; st == GS_OK && k < cap->K; k++) {   /* the JSON is not shared by threads */
            file_ref(&r, fr.ref[k][0], sizeof fr.ref[k][0], "frames[%d].file", r.pos[k]);
            file_ref(&r, fr.ref[k][1], sizeof fr.ref[k][1], "frames[%d].hdr_map", r.pos[k]);
        }
        if (st == GS_OK) st = gs_parallel_for(0, (size_t)cap->K, read_frames, &fr);
    }
    free(fr.ref);
    free(r.pos);
    gs_json_free(doc);
    if (st != GS_OK) gs_capture_release(cap);
    return st;
}

/* ------------------------------------------------------------------ writing */

gs_status gs_capture_alloc(gs_capture *cap)
{
    if (!cap) return gs_fail(GS_EINVAL, "gs_capture_alloc: NULL capture");
    gs_capture_problem pr;
    if (!gs_capture_check_geometry(cap, &pr))
        return gs_fail(GS_EINVAL, "gs_capture_alloc: field %s: expected %s", pr.field, pr.expect);
    if (cap->frames || cap->raw || cap->halvings)
        return gs_fail(GS_EINVAL, "gs_capture_alloc: the capture is already allocated "
                       "(gs_capture_release it first)");
    size_t plane = (size_t)cap->width * (size_t)cap->height;
    cap->frames = calloc((size_t)cap->K, sizeof *cap->frames);
    cap->raw = calloc(plane * (size_t)cap->K * (size_t)cap->bands, sizeof *cap->raw);
    if (!cap->frames || !cap->raw) {
        free(cap->frames);
        free(cap->raw);
        cap->frames = NULL;
        cap->raw = NULL;
        return gs_fail(GS_ENOMEM, "gs_capture_alloc: cannot hold %d frames of %dx%dx%d samples",
                       cap->K, cap->width, cap->height, cap->bands);
    }
    for (int k = 0; k < cap->K; k++) {
        snprintf(cap->frames[k].file, GS_PATH_MAX, "frame_%03d.png", k);
        cap->frames[k].k = k;
        cap->frames[k].grid_hz_measured = NAN;
        cap->frames[k].start_s = NAN;
        cap->frames[k].window_half_period_s = cap->frames[k].window_drift_windows = NAN;
    }
    return GS_OK;
}

gs_status gs_capture_alloc_hdr(gs_capture *cap)
{
    if (!cap || !cap->frames || !cap->raw)
        return gs_fail(GS_EINVAL, "gs_capture_alloc_hdr: call gs_capture_alloc first");
    if (cap->halvings) return gs_fail(GS_EINVAL, "gs_capture_alloc_hdr: already allocated");
    cap->halvings = calloc((size_t)cap->width * (size_t)cap->height * (size_t)cap->K, 1);
    if (!cap->halvings) return gs_fail(GS_ENOMEM, "gs_capture_alloc_hdr: cannot hold the maps");
    for (int k = 0; k < cap->K; k++)
        if (!cap->frames[k].hdr_map[0])
            snprintf(cap->frames[k].hdr_map, GS_PATH_MAX, "hdr_%03d.png", k);
    return GS_OK;
}

/* dir/name, atomically. */
static gs_status write_in(const char *dir, const char *name, const void *data, size_t size)
{
    char path[PATH_BUF];
    if (!gs_path_join(path, sizeof path, dir, name))
        return gs_fail(GS_EINVAL, "%s/%s: path too long", dir, name);
    return gs_file_write_atomic(path, data, size);
}

static gs_status write_png(const char *dir, const char *file, const void *pixels, int width,
                           int height, int channels, int depth16)
{
    unsigned char *png;
    size_t size;
    gs_status st = gs_png_encode(pixels, width, height, channels, depth16 ? 16 : 8, &png, &size);
    if (st != GS_OK) return gs_fail(st, "%s/%s: %s", dir, file, gs_detail());
    st = write_in(dir, file, png, size);
    free(png);
    return st;
}

gs_status gs_capture_write_frame(const char *dir, const gs_capture *cap, int k)
{
    if (!dir || !cap || !cap->frames || !cap->raw)
        return gs_fail(GS_EINVAL, "gs_capture_write_frame: NULL directory, capture or pixels");
    gs_capture_problem pr;
    if (!gs_capture_check_geometry(cap, &pr))
        return gs_fail(GS_EINVAL, "%s: gs_capture_write_frame: field %s: expected %s", dir,
                       pr.field, pr.expect);
    if (k < 0 || k >= cap->K)
        return gs_fail(GS_EINVAL, "%s: gs_capture_write_frame: k = %d: expected 0 to %d", dir, k,
                       cap->K - 1);
    const gs_frame_info *f = &cap->frames[k];
    if (!gs_capture_valid_name(f->file))
        return gs_fail(GS_EINVAL, "%s: field frames[%d].file: expected %s", dir, k, GS_CAPTURE_EXP_FILE);
    size_t plane = (size_t)cap->width * (size_t)cap->height;
    const unsigned char *h = cap->halvings ? cap->halvings + plane * (size_t)k : NULL;
    if (f->hdr_map[0]) {
        if (!gs_capture_valid_name(f->hdr_map) || strcmp(f->hdr_map, f->file) == 0)
            return gs_fail(GS_EINVAL, "%s: field frames[%d].hdr_map: expected %s, not the "
                           "frame's own", dir, k, GS_CAPTURE_EXP_FILE);
        if (!h)
            return gs_fail(GS_EINVAL, "%s: field frames[%d].hdr_map names a map but the capture "
                           "has no halvings (gs_capture_alloc_hdr)", dir, k);
        for (size_t p = 0; p < plane; p++)
            if (h[p] > GS_MAX_HALVINGS)
                return gs_fail(GS_EINVAL, "%s: frame %d pixel (x %zu, y %zu): %d halvings: "
                               "expected 0 to %d", dir, k, p % (size_t)cap->width,
                               p / (size_t)cap->width, h[p], GS_MAX_HALVINGS);
    } else if (h) {
        for (size_t p = 0; p < plane; p++)
            if (h[p])
                return gs_fail(GS_EINVAL, "%s: frame %d pixel (x %zu, y %zu) is halved but field "
                               "frames[%d].hdr_map is \"\" (the halvings would be lost)", dir, k,
                               p % (size_t)cap->width, p / (size_t)cap->width, k);
    }
    gs_status st = gs_dir_ensure(dir);
    if (st == GS_OK)
        st = write_png(dir, f->file, cap->raw + plane * (size_t)cap->bands * (size_t)k,
                       cap->width, cap->height, cap->bands, 1);
    if (st == GS_OK && f->hdr_map[0])
        st = write_png(dir, f->hdr_map, h, cap->width, cap->height, 1, 0);
    return st;
}

gs_status gs_capture_write_json(const char *dir, const gs_capture *cap)
{
    if (!dir || !cap || !cap->frames)
        return gs_fail(GS_EINVAL, "gs_capture_write_json: NULL directory, capture or frames");
    gs_capture_problem pr;
    if (!gs_capture_check_fields(cap, &pr))
        return gs_fail(GS_EINVAL, "%s/%s (writing): field %s: expected %s", dir, CAPTURE_JSON,
                       pr.field, pr.expect);
    char *station = NULL;
    if (cap->station_json) {
        json_error_t err;
        json_t *st_obj = json_loads(cap->station_json, JSON_REJECT_DUPLICATES, &err);
        if (!st_obj || !json_is_object(st_obj)) {
            json_decref(st_obj);
            return gs_fail(GS_EINVAL, "%s/%s (writing): field station: expected a JSON object "
                           "(%s)", dir, CAPTURE_JSON, st_obj ? "not an object" : err.text);
        }
        gs_text s = {0};
        gs_text_json(&s, st_obj);
        json_decref(st_obj);
        if (s.oom) {
            free(s.s);
            return gs_fail(GS_ENOMEM, "gs_capture_write_json: station");
        }
        station = s.s;
    }
    /* the frames must be there: a capture.json never names a missing file */
    for (int k = 0; k < cap->K; k++) {
        const char *names[2] = {cap->frames[k].file, cap->frames[k].hdr_map};
        for (int i = 0; i < 2; i++) {
            char path[PATH_BUF];
            struct stat sb;
            if (!names[i][0]) continue;
            if (!gs_path_join(path, sizeof path, dir, names[i]) || stat(path, &sb) != 0) {
                free(station);
                return gs_fail(GS_ENOTFOUND, "%s: missing: write every frame "
                               "(gs_capture_write_frame) before capture.json", path);
            }
        }
    }
    gs_text t = {0};
    char num[40];
    gs_text_printf(&t, "{\n  \"format\": \"%s\",\n  \"grid_hz\": %d,\n  \"K\": %d,\n  \"bands\": %d,\n"
              "  \"width\": %d,\n  \"height\": %d,\n", GS_CAPTURE_FORMAT, cap->grid_hz, cap->K,
              cap->bands, cap->width, cap->height);
    gs_json_real(num, sizeof num, cap->saturation_dn);
    gs_text_printf(&t, "  \"saturation\": %s,\n", num);
    gs_json_real(num, sizeof num, cap->black_level_dn);
    gs_text_printf(&t, "  \"black_level\": %s,\n", num);
    gs_json_real(num, sizeof num, cap->gain_e_per_dn);
    gs_text_printf(&t, "  \"gain_e_per_dn\": %s,\n", num);
    gs_json_real(num, sizeof num, cap->read_noise_dn);
    gs_text_printf(&t, "  \"read_noise_dn\": %s,\n", num);
    gs_text_printf(&t, "  \"locked\": %s,\n", cap->locked ? "true" : "false");
    if (gs_period_name(cap->window_period))
        gs_text_printf(&t, "  \"window_period\": \"%s\",\n", gs_period_name(cap->window_period));
    if (cap->utc[0]) {
        gs_text_printf(&t, "  \"utc\": ");
        gs_text_json_string(&t, cap->utc);
        gs_text_printf(&t, ",\n");
    }
    if (station) gs_text_printf(&t, "  \"station\": %s,\n", station);
    gs_text_printf(&t, "  \"frames\": [\n");
    for (int k = 0; k < cap->K; k++) {
        const gs_frame_info *f = &cap->frames[k];
        gs_text_printf(&t, "    {\"file\": ");
        gs_text_json_string(&t, f->file);
        gs_json_real(num, sizeof num, f->cycles);
        gs_text_printf(&t, ", \"k\": %d, \"cycles\": %s", f->k, num);
        if (f->hdr_map[0]) {
            gs_text_printf(&t, ", \"hdr_map\": ");
            gs_text_json_string(&t, f->hdr_map);
        }
        if (!isnan(f->grid_hz_measured)) {
            gs_json_real(num, sizeof num, f->grid_hz_measured);
            gs_text_printf(&t, ", \"grid_hz_measured\": %s", num);
        }
        if (!isnan(f->start_s)) {
            gs_json_real(num, sizeof num, f->start_s);
            gs_text_printf(&t, ", \"start_s\": %s", num);
        }
        if (!isnan(f->window_half_period_s)) {
            gs_json_real(num, sizeof num, f->window_half_period_s);
            gs_text_printf(&t, ", \"window_half_period_s\": %s", num);
        }
        if (!isnan(f->window_drift_windows)) {
            gs_json_real(num, sizeof num, f->window_drift_windows);
            gs_text_printf(&t, ", \"window_drift_windows\": %s", num);
        }
        gs_text_printf(&t, "}%s\n", k + 1 < cap->K ? "," : "");
    }
    gs_text_printf(&t, "  ]\n}\n");
    free(station);
    gs_status st;
    if (t.oom) st = gs_fail(GS_ENOMEM, "gs_capture_write_json: cannot build the text");
    else st = gs_dir_ensure(dir);
    if (st == GS_OK) st = write_in(dir, CAPTURE_JSON, t.s, t.n);
    free(t.s);
    return st;
}

void gs_capture_release(gs_capture *cap)
{
    if (!cap) return;
    free(cap->frames);
    free(cap->raw);
    free(cap->halvings);
    free(cap->station_json);
    memset(cap, 0, sizeof *cap);
}

void gs_capture_mean_image(const gs_capture *cap, int saturated_at_level, float *out)
{
    size_t P = (size_t)cap->width * (size_t)cap->height;
    for (size_t p = 0; p < P; p++)
        for (int b = 0; b < cap->bands; b++) {
            double sum = 0.0;
            for (int k = 0; k < cap->K; k++) {
                double v = gs_capture_value(cap, k, (int)(p / (size_t)cap->width), (int)(p % (size_t)cap->width), b);
                if (!isfinite(v) && saturated_at_level)
                    v = (cap->saturation_dn - cap->black_level_dn) / cap->frames[k].cycles;
                sum += v;
            }
            out[p * (size_t)cap->bands + (size_t)b] = (float)(sum / cap->K);
        }
}

double gs_capture_value(const gs_capture *cap, int k, int y, int x, int band)
{
    if (!cap || !cap->raw || !cap->frames || k < 0 || k >= cap->K || y < 0 ||
        y >= cap->height || x < 0 || x >= cap->width || band < 0 || band >= cap->bands)
        return NAN;
    size_t p = ((size_t)k * (size_t)cap->height + (size_t)y) * (size_t)cap->width + (size_t)x;
    double raw = cap->raw[p * (size_t)cap->bands + (size_t)band];
    double cycles = cap->frames[k].cycles;
    if (!(raw < cap->saturation_dn) || !(cycles > 0) || !isfinite(cycles)) return NAN;
    int h = cap->halvings ? cap->halvings[p] : 0;
    /* the same expression as blobs.c: (raw - black) * (2^h / cycles) */
    return (raw - cap->black_level_dn) * (ldexp(1.0, h) / cycles);
}

gs_noise gs_capture_noise(const gs_capture *cap)
{
    gs_noise n = {cap->read_noise_dn * cap->read_noise_dn + 1.0 / 12.0,
                  cap->gain_e_per_dn > 0.0 ? 1.0 / cap->gain_e_per_dn : 0.0, cap->black_level_dn};
    return n;
}
