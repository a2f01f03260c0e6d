/*
 * recognize.h - the public interface of gridsurvey's recognize/ module (prefix rec_).
 *
 * Implements "Computational Imaging on the Electric Grid" (Sheinin, Schechner, Kutulakos,
 * CVPR 2017): the AC model (Eq. 1), bulb response functions (Eqs. 3-6), the DELIGHT bulb
 * database (Sec. 3; here a substitute generated from lamp physics, see docs/delight.md and
 * docs/delight-models.md).
 *
 * recognize/ is the lowest layer of the tool: it also owns the one status enum (gs_status)
 * that every module returns, with a thread-local detail string for one-line error messages.
 *
 * Conventions (docs/design.md): time t starts at a negative-to-positive zero crossing of the
 * reference outlet. A flicker cycle lasts Delta = 1/(2 f) (Eq. 1). Shifts are in cycles
 * (fractions of Delta), positive = delayed (the paper's shift() to the right).
 * Ownership: functions that return allocated memory say so; free it with the named function.
 * Every destructor accepts NULL.
 */
#ifndef GRIDSURVEY_RECOGNIZE_H
#define GRIDSURVEY_RECOGNIZE_H

#include <stddef.h>
#include <stdio.h>

/* ------------------------------------------------------------------ status */

typedef enum {
    GS_OK = 0,
    GS_EINVAL,      /* an argument outside its documented range */
    GS_EIO,         /* a file could not be opened, read or written */
    GS_EFORMAT,     /* a file's content does not follow its format */
    GS_ENOMEM,      /* allocation failed */
    GS_ESQL,        /* SQLite reported an error */
    GS_ENOTFOUND,   /* a named item (bulb id, file) does not exist */
    GS_ENUMERIC,    /* NaN, Inf or an ill-conditioned computation */
    GS_ELIMIT       /* a hardware or model limit would be exceeded */
} gs_status;

/* A static string naming the status. */
const char *gs_strerror(gs_status s);
/* The detail of the last failure on this thread ("file:line: field: expected ..."); never NULL. */
const char *gs_detail(void);
/* Record a printf-style detail for this thread and return s (for `return gs_fail(...)`). */
gs_status gs_fail(gs_status s, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/* ------------------------------------------------------------- AC (Eq. 1) */

/* Zero crossings of a uniformly sampled waveform x[0..n) at rate_hz, both directions, with
 * sub-sample times from a local cubic through the 4 samples around each sign change (exact for
 * cubics; at most 1.3e-3 of a sample period on a clean 50 Hz sine sampled at 400 Hz, ~1e-2
 * with a few % of 3rd harmonic, which 4 samples cannot resolve). The mean of x is removed
 * first. hysteresis (in units of x, >= 0) is a Schmitt trigger: a crossing counts only once x
 * has gone from below -hysteresis to above +hysteresis (or back), so noise-level sign changes
 * are rejected; when noise makes several sign changes in one transition, the crossing is the
 * midpoint of the first and last. Returns an allocated array of crossing times in seconds from
 * sample 0 (free(); NULL when there are none) and its length in *count; *rising_first is the
 * direction of the first crossing (+1 rising, -1 falling, 0 if none; they alternate).
 * A constant signal has no crossings (GS_OK, count 0). Non-finite samples are GS_ENUMERIC
 * naming the sample index. */
gs_status rec_zero_crossings(const double *x, size_t n, double rate_hz, double hysteresis,
                             double **t_s, size_t *count, int *rising_first);

/* Grid frequency from successive zero-crossing times t_s[0..n) (finite, increasing, n >= 3,
 * else GS_ENUMERIC / GS_EINVAL naming the index): per cycle f_i = 1/(2 Delta_i) with
 * Delta_i = t_{i+1} - t_i (Eq. 1), written to f_cycle_hz[0..n-1) unless NULL.
 * The robust mean uses full AC periods P_i = t_{i+2} - t_i (immune to the DC offset and even
 * harmonics that make half periods alternate), rejects periods whose frequency 1/P_i is more
 * than 5 robust sigmas (5 x 1.4826 MAD, at least 1e-9 of the median) from the median, and is
 * Eq. 1 on the mean accepted period: mean_hz = 1/mean(P_i) (a missing crossing rejects 2
 * periods, a spurious one up to 3). sigma_mean_hz is its standard error for independent errors in
 * the crossing times: the mean period telescopes to the crossings at the ends of each run of
 * accepted periods, and the crossing-time error is estimated from second differences
 * P_{i+2} - P_i, which cancel slow frequency wander. NaN when fewer than 2 such differences
 * exist (n < 7); std_hz is NaN for a single period. */
typedef struct {
    double mean_hz;         /* robust mean frequency */
    double sigma_mean_hz;   /* standard error of mean_hz */
    double median_hz;       /* median per-period frequency */
    double std_hz;          /* standard deviation of accepted per-period frequencies */
    size_t periods;         /* full AC periods used */
    size_t rejected;        /* periods rejected as outliers (glitches, missing crossings) */
} rec_freq_stats;
gs_status rec_grid_frequency(const double *t_s, size_t n, double *f_cycle_hz,
                             rec_freq_stats *stats);

/* Frequency wander of a long recording (see shared/data/README.md): the accepted full periods
 * of rec_grid_frequency, each assigned to the window of window_s seconds (0 < window_s <= 10;
 * 1 s is the usual ENF resolution) holding its midpoint, give one frequency per window (Eq. 1
 * on the window's mean period; a window without periods is skipped). Then the mean and
 * standard deviation of that series, the standard deviation of its window-to-window changes,
 * and its autocorrelation (Pearson correlation of the pairs w, w + lag) at lags of 10 s and
 * 60 s (rounded to whole windows). Needs crossings spanning at least 120 s (GS_EINVAL). */
typedef struct {
    double mean_hz;
    double sigma_hz;         /* std of the window-averaged frequency */
    double step_sigma_hz;    /* std of successive differences of that series */
    double corr_10s;         /* autocorrelation at lag 10 s */
    double corr_60s;         /* autocorrelation at lag 60 s */
    size_t windows;          /* complete windows in the span (including any skipped) */
} rec_wander;
gs_status rec_frequency_wander(const double *t_s, size_t n, double window_s, rec_wander *w);

/* Read a mono mains-voltage recording (WAV or any format libsndfile reads) as doubles (PCM is
 * scaled to [-1, 1), float samples are kept as they are). *x is allocated (free()).
 * GS_EIO if the file cannot be opened; GS_EFORMAT, with a detail naming the file and the field
 * or sample, for an empty file, an unrecognised header, a truncated WAV (declared RIFF or data
 * chunk size beyond the end of the file), a file with no samples, more than one channel, or a
 * non-finite sample. */
gs_status rec_mains_read(const char *path, double **x, size_t *n, double *rate_hz);

/* ------------------------------------------------------------ BRF (Eqs. 3-6) */

#define REC_MAX_BANDS 3
#define REC_BRF_N_DEFAULT 1024   /* high-resolution samples per flicker cycle */

/* A bulb response function: n samples over one flicker cycle per band, v[band * n + i] at
 * t = i/n * Delta, mean 1 per band (Eq. 4). The samples are those of a trigonometric
 * polynomial (band-limited to n/2 harmonics), which makes fractional shifts and window
 * integrals exact (rec_brf_shift, rec_brf_integrate). */
typedef struct {
    int n;        /* samples per cycle, >= 4 and even */
    int bands;    /* 1 (monochrome) or 3 (R, G, B) */
    double *v;    /* owned; bands * n values */
} rec_brf;

/* Allocate a zeroed BRF; release with rec_brf_release (which accepts a zeroed struct). */
gs_status rec_brf_init(rec_brf *b, int n, int bands);
void rec_brf_release(rec_brf *b);
/* Deep copy into an uninitialised *dst. */
gs_status rec_brf_copy(rec_brf *dst, const rec_brf *src);
/* Divide each band by its mean so the mean is 1 (Eq. 4); the means go to mean_out[] unless NULL.
 * A band whose mean is not finite and > 0 is GS_ENUMERIC. */
gs_status rec_brf_normalize(rec_brf *b, double *mean_out);
/* out = in delayed by shift_cycles (any real; 1 is the identity): out(t) = in(t - shift*Delta).
 * Exact on the trigonometric polynomial, so shifts compose. out must be initialised with the
 * same n and bands; out may equal in. */
gs_status rec_brf_shift(const rec_brf *in, double shift_cycles, rec_brf *out);
/* Eq. 5: the mean of the BRF (delayed by shift_cycles) over each of K windows
 * [k Delta/K, (k+1) Delta/K), k = 0..K-1, for every band: out[band * K + k]. Any K >= 2.
 * Exact integrals of the trigonometric polynomial; the mean over k stays 1. */
gs_status rec_brf_integrate(const rec_brf *b, double shift_cycles, int K, double *out);
/* Percent flicker of one band: 100 (max - min) / (max + min) over the samples. */
double rec_brf_percent_flicker(const rec_brf *b, int band);

/* The BRF shift (cycles, in [0,1)) of grid phase phase_deg: phi/pi cycles modulo 1
 * (docs/design.md: 0, 120, 240 deg -> 0, 2/3, 1/3). */
double rec_phase_to_shift(double phase_deg);
/* Inverse: the grid phase in [0,360) deg whose shift is shift_cycles. */
double rec_shift_to_phase(double shift_cycles);

/* Eq. 6: chromaticity Q[b] = mean[b] / sum(mean), and the brightness sum(mean) returned.
 * Returns NaN (and leaves Q untouched) when the sum is not finite and > 0. */
double rec_chromaticity(const double *mean, int bands, double *Q);

/* --------------------------------------------------------------- DELIGHT */

typedef enum {
    REC_TECH_INCANDESCENT,
    REC_TECH_HALOGEN,
    REC_TECH_FLUORESCENT_MAGNETIC,
    REC_TECH_FLUORESCENT_ELECTRONIC,
    REC_TECH_CFL,
    REC_TECH_LED_CAPACITOR,
    REC_TECH_LED_LINEAR,
    REC_TECH_LED_PWM,
    REC_TECH_SODIUM_HP,
    REC_TECH_SODIUM_LP,
    REC_TECH_METAL_HALIDE,
    REC_TECH_MERCURY,
    REC_TECH_UNKNOWN,           /* measured, technology not known */
    REC_TECH_COUNT
} rec_tech;

/* Stable lower-case names used in files ("incandescent", "sodium_hp", ...). */
const char *rec_tech_name(rec_tech t);
/* GS_ENOTFOUND if name is not one of rec_tech_name's. */
gs_status rec_tech_parse(const char *name, rec_tech *t);

/* What the template's time axis is referenced to. */
typedef enum {
    REC_REF_VOLTAGE,   /* relative to the outlet voltage (DELIGHT's convention): phase usable */
    REC_REF_NONE,      /* shape only, no voltage reference: never used for phase decisions */
    REC_REF_UNLOCKED   /* flicker not locked to the mains (PWM): never used by Eq. 7 */
} rec_ref;
const char *rec_ref_name(rec_ref r);   /* "voltage", "none", "unlocked" */

#define REC_ID_MAX 48
#define REC_NAME_MAX 96
#define REC_SENSOR_MAX 32

/* One DELIGHT entry: one bulb measured at one grid frequency with one sensor. */
typedef struct {
    char id[REC_ID_MAX];           /* bulb id, [A-Za-z0-9_.-]+; unique with grid_hz and sensor */
    rec_tech type;
    char name[REC_NAME_MAX];       /* human-readable; no commas or newlines */
    double watts;                  /* electrical power, W (> 0; 0 if unknown) */
    int grid_hz;                   /* 50 or 60 */
    char sensor[REC_SENSOR_MAX];   /* "photodiode" (mono) or "rgb" (3 bands), or a user name */
    rec_ref ref;
    double chroma[REC_MAX_BANDS];  /* Eq. 6 chromaticity per band, sums to 1 (mono: 1) */
    rec_brf brf;                   /* owned by the entry */
} rec_bulb;

/* Release the BRF of a bulb (the struct itself is the caller's). */
void rec_bulb_release(rec_bulb *b);

/* A DELIGHT database in memory: an ordered collection of bulbs (opaque handle). */
typedef struct rec_delight rec_delight;
rec_delight *rec_delight_new(void);
void rec_delight_free(rec_delight *d);
/* Add a deep copy of *b. GS_EINVAL if (id, grid_hz, sensor) is already present, or if the
 * entry is inconsistent (bands vs sensor, chroma not summing to 1, BRF mean not 1). */
gs_status rec_delight_add(rec_delight *d, const rec_bulb *b);
size_t rec_delight_count(const rec_delight *d);
/* Borrowed pointer, valid until d changes or is freed; NULL when i is out of range. */
const rec_bulb *rec_delight_get(const rec_delight *d, size_t i);
/* First entry with this id (and grid_hz, bands when they are > 0), or NULL. */
const rec_bulb *rec_delight_find(const rec_delight *d, const char *id, int grid_hz, int bands);

/* The built-in DELIGHT substitute: physical models of each technology (docs/delight.md), with
 * parameters drawn deterministically inside the ranges of shared/BULBS.md; every bulb at 50 and
 * 60 Hz, with a monochrome ("photodiode") and an RGB ("rgb") entry; n samples per cycle. */
gs_status rec_delight_generate(rec_delight *d, int n);

/* SQLite storage (versioned schema, docs/delight.md; tables delight_meta, delight_bulbs,
 * delight_brf_bands). save replaces the file's DELIGHT tables in one transaction and refuses a
 * file whose user_version belongs to another schema; load appends the file's bulbs to d, and on
 * any error (GS_EFORMAT for a file that is not a DELIGHT database) adds nothing. */
#define REC_DELIGHT_SCHEMA_VERSION 1
gs_status rec_delight_save(const rec_delight *d, const char *path);
gs_status rec_delight_load(rec_delight *d, const char *path);

/* CSV: header `bulb_id,type,name,watts,grid_hz,sensor,band,chromaticity,n,v0,...,v{n-1}`, one
 * row per bulb and band (band: mono, R, G, B); sensor is written "SENSOR/REF" (REF as in
 * rec_ref_name). Values are printed with %.17g, so a round trip is exact. The rows of one bulb
 * are consecutive; each row has its own n values (the header lists the largest n). import
 * appends to d; on any error nothing is added and the detail names file, line and field. */
gs_status rec_delight_export_csv(const rec_delight *d, FILE *out);
gs_status rec_delight_import_csv(rec_delight *d, const char *path);

/* ------------------------------------------------- measured bulbs (delight add) */

/* A photodiode recording turned into a BRF: the flicker period is found from the data, cycles
 * are folded and averaged into n bins and normalised. With a voltage column (1-based column
 * index > 0), time zero is the voltage's first negative-to-positive crossing and the BRF is
 * REC_REF_VOLTAGE; without, REC_REF_NONE (shape only). A flicker frequency that is not twice a
 * 50/60 Hz grid (+-3 %) gives REC_REF_UNLOCKED (e.g. PWM). */
typedef struct {
    size_t samples;            /* rows read */
    double sample_rate_hz;
    double flicker_hz;         /* measured flicker frequency */
    double cycles;             /* flicker cycles covered by the recording */
    double percent_flicker;    /* of the folded, averaged waveform */
    int grid_hz;               /* 50 or 60 inferred from flicker_hz, 0 if unlocked */
} rec_recording_info;
/* Reads `time,value[,voltage...]` CSV as oscilloscopes write it: UTF-8 BOM, `Key:value,`
 * metadata lines, a header that may run into the first sample, CRLF; uniform time steps.
 * Without a voltage column time zero is the first sample. The BRF keeps the harmonics that
 * stand above the fold's noise (band-limited); a waveform dipping below 0 (scope offset) is
 * raised to a minimum of 0. A lamp without flicker above the noise gets a flat BRF and
 * flicker_hz NaN. Fills *out (id and name from the file name; type unknown: the caller's to set
 * afterwards; grid_hz 0 when the recording cannot tell, i.e. unlocked without a voltage column:
 * set it before rec_delight_add) and *info unless NULL. */
gs_status rec_recording_to_bulb(const char *path, int voltage_column, int n, rec_bulb *out,
                                rec_recording_info *info);

/* ------------------------------------------------------------------ plots */

/* A PNG of the BRFs of bulbs[0..count) over one cycle, one panel per band (like the paper's
 * Fig. 2), with axes, labels and a legend (PLplot, cairo PNG driver). */
gs_status rec_plot_brfs(const rec_bulb *const *bulbs, size_t count, const char *png_path,
                        const char *title);

/* --------------------------------------------------------- capture directory */

/* A capture directory, format "gridsurvey-capture/1" (docs/formats.md is the specification):
 * capture.json plus K frames as 16-bit PNGs (grey for 1 band, RGB for 3), and optional 8-bit
 * grey HDR maps holding each pixel's halving count h (0..16): in that frame the pixel integrated
 * cycles / 2^h cycles, for all its bands (paper Sec. 6, the ACam's HDR loop). This is the one
 * reader and writer of the format; capture/ writes with it, recognize/ reads with it.
 *
 * Lifecycle: a rec_capture is a plain struct. Zero it, set the scalar fields, rec_capture_alloc
 * (and rec_capture_alloc_hdr for HDR maps), set frames[k].cycles and the pixels, then
 * rec_capture_write_frame for every k and rec_capture_write_json last. Or rec_capture_read.
 * Either way rec_capture_release frees everything (it accepts NULL and a zeroed struct). */
#define REC_CAPTURE_FORMAT "gridsurvey-capture/1"
#define REC_PATH_MAX 256
#define REC_MAX_HALVINGS 16

typedef struct {
    char file[REC_PATH_MAX];      /* frame PNG in the directory: [A-Za-z0-9._-]+ ending ".png" */
    int k;                        /* window index 0..K-1: [k Delta/K, (k+1) Delta/K) */
    double cycles;                /* C, flicker cycles integrated before any HDR halving (> 0) */
    char hdr_map[REC_PATH_MAX];   /* 8-bit PNG of halving counts, "" when the frame has none */
} rec_frame_info;

typedef struct {
    int grid_hz;                  /* 50 or 60 */
    int K;                        /* frames per cycle, 2..1024 */
    int bands;                    /* 1 or 3 (R, G, B) */
    int width, height;            /* pixels, 1..32768 each */
    double saturation_dn;         /* raw level at or above which a sample is saturated,
                                   * (black_level_dn, 65536]; 65536: nothing saturates */
    double black_level_dn;        /* raw pedestal, [0, 65536) (file default 0) */
    double gain_e_per_dn;         /* electrons per DN for shot noise, >= 0 (0 = unknown: read
                                   * noise only; file default 0) */
    double read_noise_dn;         /* read noise std per sample and frame, DN, >= 0 (file
                                   * default 1) */
    int locked;                   /* 1 if AC-locked, else 0 (file default 1) */
    char utc[40];                 /* acquisition time, ISO 8601 (YYYY-MM-DDThh:mm:ss[.f](Z|+hh:mm)),
                                   * "" if unknown */
    rec_frame_info *frames;       /* K entries, frames[k].k == k (owned, malloc) */
    /* Pixels (owned, malloc; NULL until allocated or read):
     * raw[((k * height + y) * width + x) * bands + band] in DN as stored (black level included);
     * halvings[(k * height + y) * width + x] (0..16), or NULL if no frame has an HDR map (then
     * h = 0 everywhere; a frame without a map reads as h = 0). */
    unsigned short *raw;
    unsigned char *halvings;
    char *station_json;           /* the optional "station" object as compact JSON text (owned,
                                   * malloc) or NULL. Kept semantically verbatim: Jansson
                                   * re-serialises it (key order kept, reals to 17 digits). */
} rec_capture;

/* Read dir/capture.json and every frame and HDR map into *cap (its previous content is ignored
 * and not freed; on failure *cap is left zeroed). Everything is validated: GS_ENOTFOUND for a
 * missing capture.json or frame file, GS_EFORMAT for bad JSON ("DIR/capture.json:LINE:COL: JSON
 * syntax: ..."), a bad field ("DIR/capture.json:LINE: field frames[3].k: expected ..."), a
 * frame PNG that is truncated, not 16-bit, of the wrong colour type or size (the detail names
 * the file and the capture.json line that names it). */
gs_status rec_capture_read(const char *dir, rec_capture *cap);
/* For a zeroed capture whose K, bands, width and height are set (GS_EINVAL otherwise, or if
 * frames, raw or halvings are already set): allocate frames (file "frame_NNN.png", k, cycles 0:
 * set them, hdr_map "") and zeroed raw pixels. */
gs_status rec_capture_alloc(rec_capture *cap);
/* After rec_capture_alloc: allocate zeroed halvings and name every frame's map "hdr_NNN.png"
 * (unless already named). */
gs_status rec_capture_alloc_hdr(rec_capture *cap);
/* Write frame k as dir/frames[k].file (and its HDR map as dir/frames[k].hdr_map when that is
 * not "") atomically: a temporary file in dir, fsync, rename. Creates dir (one level) if needed.
 * GS_EINVAL for a bad k or name, halvings > 16, or a halved pixel in a frame without a map. */
gs_status rec_capture_write_frame(const char *dir, const rec_capture *cap, int k);
/* Write dir/capture.json atomically, after validating every field with the reader's rules
 * (GS_EINVAL naming the field). Frames must have been written first (GS_ENOTFOUND naming the
 * missing file), so a capture.json never names a file that is not there. */
gs_status rec_capture_write_json(const char *dir, const rec_capture *cap);
/* Free frames, pixels and station_json and zero the struct. Accepts NULL. */
void rec_capture_release(rec_capture *cap);
/* The per-cycle intensity of one pixel sample, in DN per flicker cycle: black level removed,
 * divided by the cycles it integrated, (raw - black_level_dn) * (2^h / cycles). NaN when the
 * sample is saturated (raw >= saturation_dn), when an index is out of range or the capture has
 * no pixels. May be negative (noise below the black level). */
double rec_capture_value(const rec_capture *cap, int k, int y, int x, int band);

/* ------------------------------------------------------- blobs (per light) */

/* Lights as blobs of a capture, SEP-style (Barbary 2016, after SExtractor), with per-frame
 * photometry for Eq. 7. Steps (recognize/blobs.c):
 *  1. per-cycle values (rec_capture_value); the mean image M = mean over k of the sum over
 *     bands (saturated samples enter M clipped at the saturation level: they are bright);
 *  2. background of M: a mesh of boxes of background_px, each the median of its pixels after
 *     two 3-sigma clips, a 3x3 median over the mesh, bilinear interpolation (linear
 *     extrapolation at the borders, so a pedestal or linear gradient is removed exactly);
 *  3. noise of M per pixel from the capture's noise model: per sample
 *     var(DN) = read_noise_dn^2 + 1/12 (quantisation) + max(DN - black, 0) / gain_e_per_dn,
 *     var(value) = var(DN) / c_eff^2 with c_eff = cycles / 2^h, at the background level;
 *  4. detection: M - background > threshold_sigma noise sigmas, or saturated in any frame;
 *     8-connected components; components smaller than min_area_px are dropped, and so are
 *     components larger than 4 max_area_px (not deblended);
 *  5. deblending: local maxima of M (5x5) in a component, at most 32; each peak's temporal
 *     signal from its 3x3 neighbourhood, normalised by its mean over k (summed over bands);
 *     peaks are grouped (brightest first) while their normalised signals agree within
 *     deblend_sigma (chi-square over bands * K values, as a Gaussian sigma by Wilson-Hilferty);
 *     two or more groups split the component by a watershed on M from the groups' peaks
 *     (REC_BLOB_DEBLENDED). Lights whose footprint is outside [min_area_px, max_area_px] are
 *     dropped;
 *  6. photometry aperture: the footprint grown by grow_px pixels (8-connected, into pixels of
 *     no other light; the nearer light wins);
 *  7. per frame and band: the sum over the aperture's usable pixels (unsaturated in every frame
 *     and band, Eq. 17) of value - background, where the per-frame background is a mesh of the
 *     same boxes holding the mean of each box's pixels outside every detection (dilated by
 *     grow_px + 2) in that frame and band. sigma adds the pixels' noise (3.) and the variance of
 *     the mesh nodes used (each node's mean of its pixels' noise / n);
 *  8. position: the windowed centroid (SExtractor's XWIN_IMAGE): a Gaussian window whose sigma
 *     comes from the aperture's second moment, iterated from the aperture's intensity-weighted
 *     centroid; unbiased for any symmetric PSF (at most 0.013 px of pixel-sampling error for
 *     1-1.5 px Gaussian PSFs without noise, tests/test_blobs.c).
 * Works in O(K * bands * pixels), with OpenCV for components and morphology: 0.35 s for a
 * 1024 x 1024, K = 26, RGB capture (one core). */
enum {
    REC_BLOB_EDGE = 1u << 0,        /* aperture touches the image border: the light may be cut */
    REC_BLOB_SATURATED = 1u << 1,   /* some pixel saturated in some frame (excluded from sums) */
    REC_BLOB_DEBLENDED = 1u << 2,   /* split from touching lights with different signals */
    REC_BLOB_HDR = 1u << 3,         /* some aperture pixel was HDR-halved in some frame */
    REC_BLOB_NO_SIGNAL = 1u << 4    /* every aperture pixel saturated: signal 0, sigma +Inf */
};

typedef struct {
    double threshold_sigma;   /* detection threshold over the background, noise sigmas, > 0 (5) */
    int min_area_px;          /* smallest footprint kept, >= 1 (1) */
    int max_area_px;          /* largest footprint kept, >= min_area_px (5000) */
    int background_px;        /* background box side, pixels, 3..65535 (31) */
    double deblend_sigma;     /* signal difference, in noise sigmas, that splits a blob, > 0;
                               * INFINITY never splits (5) */
    int grow_px;              /* photometry aperture = footprint grown by this, 0..64 (2) */
    int labels;               /* 1: also return the aperture label image (0) */
} rec_blob_opts;
void rec_blob_opts_default(rec_blob_opts *o);

/* The light catalog, a struct of arrays (one entry per light, in raster order of each light's
 * first footprint pixel). signal and sigma hold count * bands * K values,
 * [(i * bands + band) * K + k]: the per-cycle flux of light i (DN per cycle) summed over its
 * aperture pixels that are unsaturated in every frame, background removed, and its noise std
 * (shot + read + quantisation + background estimate), always finite except sigma = +Inf for
 * REC_BLOB_NO_SIGNAL. Every array is a separate malloc (NULL when count is 0), owned by the
 * catalog; rec_catalog_release frees each and zeroes the struct (a hand-built catalog whose
 * arrays are malloc'd or NULL may be released too). */
typedef struct {
    size_t count;
    int bands, K;
    double *x_px, *y_px;      /* windowed centroid on M - background (pixel centres at integers,
                               * x right, y down); see step 8 */
    int *area_px;             /* footprint pixels (detected, after deblending) */
    double *peak_dn;          /* brightest raw sample of the footprint, DN as stored */
    int *saturated_px;        /* aperture pixels saturated in at least one frame */
    unsigned *flags;          /* REC_BLOB_* */
    double *signal, *sigma;
    int width, height;        /* of the capture */
    int *labels;              /* opts.labels: width * height, the light owning each aperture
                               * pixel, -1 elsewhere; else NULL */
} rec_catalog;
/* *cat is overwritten (not freed); on failure it is zeroed. GS_EINVAL for options outside
 * their ranges or a capture whose fields break docs/formats.md (NaN, Inf, negative noise,
 * cycles <= 0, halvings > 16), GS_ENOMEM. A scene with no light gives count 0 and GS_OK. */
gs_status rec_blobs_extract(const rec_capture *cap, const rec_blob_opts *o, rec_catalog *cat);
void rec_catalog_release(rec_catalog *cat);

#endif
