/* internal.h - capture/ internals shared between its own files; other modules never include it
 * (tests may). Random streams, the BRF integral tables, the backend vtable, the JSON line
 * locator of the scene parser and the videoio shim's C interface. */
#ifndef GRIDSURVEY_CAPTURE_INTERNAL_H
#define GRIDSURVEY_CAPTURE_INTERNAL_H

#include "capture/capture.h"

#include <math.h>
#include <stdint.h>

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

/* ------------------------------------------------------------------ scene parsing */

/* A scene document (or a GeoJSON file it names) and the directory relative paths resolve in. */
typedef struct {
    const gs_json *doc;
    const char *base_dir;
} cap_pctx;
/* gs_json_fail on c's document. */
gs_status cap_scene_bad(const cap_pctx *c, gs_status s, const char *path, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
/* gs_json_get_int into a long / an int (default expected text). */
gs_status cap_scene_get_long(const cap_pctx *c, json_t *obj, const char *ppath, const char *key,
                             int required, long def, long lo, long hi, long *out);
gs_status cap_scene_get_int(const cap_pctx *c, json_t *obj, const char *ppath, const char *key,
                            int required, int def, int lo, int hi, int *out);
/* rel against the scene's directory (absolute paths as they are). */
void cap_scene_resolve(const cap_pctx *c, const char *rel, char *out, size_t cap);
/* The "lights" array (scene_lights.c) into sc->lights / n_lights. */
gs_status cap_scene_parse_lights(const cap_pctx *c, cap_scene *sc, json_t *lights);

/* ------------------------------------------------------------------ random streams */

/* Stream tags (one per random process). */
enum {
    CAP_TAG_FREQ = 1,      /* random-walk grid frequency */
    CAP_TAG_JITTER,        /* DMD edge jitter, per acquisition */
    CAP_TAG_SCINT,         /* scintillation, per acquisition */
    CAP_TAG_SHOT,          /* photon shot noise, per acquisition */
    CAP_TAG_READ,          /* read noise, per acquisition */
    CAP_TAG_GRID_GEN,      /* street-grid light generator */
    CAP_TAG_HEADLIGHTS     /* car start offsets */
};

/* ------------------------------------------------------- BRF integral tables (Eq. 5) */

/* The antiderivative of a BRF band as a periodic table: the BRF is the trigonometric
 * polynomial of its samples (recognize.h), B(x) = 1 + sum_h ..., and
 *   F(x) = int_0^x B = x + G(x) - G(0),  G periodic with G' = B - 1,
 * tabulated with B at `n` points per cycle (zero-padded inverse DFT: exact at the nodes) and
 * evaluated between them by cubic Hermite interpolation (error <= h^4 max|B'''| / 384). */
typedef struct {
    int n;          /* table points per cycle */
    int bands;
    double *G, *B;  /* bands * n each, owned: G and B - mean at x = j / n */
    double mean[GS_MAX_BANDS];
} cap_brf_table;

gs_status cap_brf_table_init(cap_brf_table *t, const gs_brf *b, int n);
void cap_brf_table_release(cap_brf_table *t);
/* int_a^b B(x - shift) dx for one band (any real a <= b, in cycles). */
double cap_brf_table_integral(const cap_brf_table *t, int band, double shift, double a, double b);

/* ------------------------------------------------------------------ backends */

typedef struct {
    const char *name;
    gs_status (*info)(void *self, cap_acq_info *info);
    gs_status (*acquire)(void *self, const cap_acquisition *a, unsigned char *halvings,
                         unsigned short *raw, double *cycles);
    void (*free)(void *self);
    gs_status (*timing)(void *self, cap_acq_timing *t);   /* NULL: nothing known */
} cap_backend_ops;

/* Wraps self with ops into a backend handle (takes ownership of self, also on failure). */
gs_status cap_backend_wrap(const cap_backend_ops *ops, void *self, cap_backend **out);
/* The backend's self pointer when it was made with ops, else NULL. */
void *cap_backend_self(cap_backend *b, const cap_backend_ops *ops);

/* 64-bit FNV-1a (progress file checksums and configuration fingerprints). */
uint64_t cap_fnv1a(uint64_t h, const void *data, size_t n);
#define CAP_FNV_INIT 0xcbf29ce484222325ull

/* Write data to dir/name atomically (gs_file_write_atomic), creating dir (one level). */
gs_status cap_write_in(const char *dir, const char *name, const void *data, size_t size);

/* ------------------------------------------------------- the camera (videoio.c, plugin) */

/* A camera through OpenCV VideoCapture (opencv_videoio). Every C++ exception is caught at the
 * boundary. source: a device index ("0"), a device path or URL, or, with images = 1, an image
 * sequence pattern ("dir/img_%03d.png", CAP_IMAGES; 16-bit PNGs are read as they are).
 * opencv_videoio brings some 180 libraries that cost every process about 50 MB of memory and
 * 0.14 s at start, so it is in a plugin (capture/videoio/videoio_plugin.cpp, built as
 * gridsurvey-videoio.so beside the binary, installed as PREFIX/lib/gridsurvey/) that the first
 * cap_vio_open loads: GS_EIO in one line when it cannot (where it looked, dlerror). */
typedef struct cap_vio cap_vio;
#ifdef __cplusplus
extern "C" {
#endif
gs_status cap_vio_open(const char *source, int images, cap_vio **out);
void cap_vio_close(cap_vio *v);
/* Sets the exposure, exposure_s seconds, through CAP_PROP_EXPOSURE in the backend's unit, and
 * reads it back into *actual_s: for V4L2 (OpenCV passes the value to V4L2's
 * exposure_time_absolute, in 100 us: 5 s was 0.5 ms) both in seconds; a backend of unknown unit
 * gets the seconds as they are, *actual_s NaN (not read back). */
gs_status cap_vio_set_exposure(cap_vio *v, double exposure_s, double *actual_s);
/* The backend's CAP_PROP_EXPOSURE units in one second (OpenCV's backend name: V4L2 1e4), NaN
 * when unknown. */
double cap_vio_units_per_s(const char *backend);
/* Grabs the next frame as width x height x bands 16-bit samples (R, G, B order for 3 bands; an
 * 8-bit camera is scaled by 257). GS_EIO when no frame comes, GS_EFORMAT for another size or
 * channel count. */
gs_status cap_vio_read(cap_vio *v, int width, int height, int bands, unsigned short *out);
/* The plugin's entry points (cap_vio_plugin_*, named as the functions above) and its dlopen
 * handle. cap_vio_plugin_load looks in bin_dir, then in bin_dir/../lib/gridsurvey/ (the
 * installed layout); the first cap_vio_open calls it with the running binary's directory and
 * keeps the plugin loaded until exit. GS_EIO in one line naming both places and dlerror's
 * reasons, or the missing entry points. */
typedef struct {
    void *handle;
    gs_status (*open)(const char *, int, cap_vio **);
    void (*close)(cap_vio *);
    gs_status (*set_exposure)(cap_vio *, double, double *);
    gs_status (*read)(cap_vio *, int, int, int, unsigned short *);
    const char *(*backend)(cap_vio *);
} cap_vio_api;
gs_status cap_vio_plugin_load(const char *bin_dir, cap_vio_api *api);
/* The plugin's entry points, one for each of the above. */
gs_status cap_vio_plugin_open(const char *source, int images, cap_vio **out);
void cap_vio_plugin_close(cap_vio *v);
gs_status cap_vio_plugin_set_exposure(cap_vio *v, double exposure, double *actual);
gs_status cap_vio_plugin_read(cap_vio *v, int width, int height, int bands, unsigned short *out);
/* OpenCV's name of the camera's backend (VideoCapture::getBackendName; "" if it has none). */
const char *cap_vio_plugin_backend(cap_vio *v);
#ifdef __cplusplus
}
#endif

#endif
