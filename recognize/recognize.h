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
    double grid_hz_measured;      /* mean grid frequency during the exposure, Hz, 45..65 (NaN:
                                   * unknown; file field "grid_hz_measured", optional) */
    double start_s;               /* the exposure's start, s from the capture's first exposure,
                                   * >= 0 (NaN: unknown; file field "start_s", optional) */
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
 * set them, hdr_map "", grid_hz_measured and start_s NaN) and zeroed raw pixels. */
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

/* ------------------------------------------------------- Eq. 7 recognition */

/* Eq. 7 (paper Sec. 4) as a maximum-likelihood / Bayesian estimator; docs/recognition.md has the
 * derivation, the flags and the measured accuracy and calibration.
 * Model: sample d of a light is a * t(beta, phi)[d] + noise, noise Gaussian with the given std,
 * independent; t = Q_beta(sigma) shift(phi, b_beta(sigma)) integrated to the K windows (Eq. 5),
 * so a is the brightness (sum over bands of the mean per-cycle flux, Eq. 6). The paper's
 * normalisation by the mean brightness is the maximum-likelihood scale a* = S/T
 * (S = sum w x t, T = sum w t^2, w = 1/sigma^2), and Eq. 7's residual is
 * chi2 = sum w x^2 - S^2/T. The posterior over (bulb, phase) has uniform priors and the scale
 * marginalised over a > 0 (flat prior):
 *   log p(beta, phi | x) = -chi2/2 - log(T)/2 + log Phi(S/sqrt(T)) + const.
 * With band_gains (the default for 3 bands) each band b has its own brightness a_b and its
 * template is shift(phi, b_beta(b)) of mean 1 (no Q_beta), so a per-band gain such as extinction
 * reddening cancels: chi2 = sum w x^2 - sum_b S_b^2/T_b, the log posterior sums
 * -log(T_b)/2 + log Phi(S_b/sqrt(T_b)) over bands, the brightness is sum_b a_b and dof =
 * usable samples - bands - 1. model_error adds (model_error mu_b)^2 to every sample's variance
 * (docs/recognition.md, "Band gains and model error").
 * Thread safety: a matcher is read-only after rec_matcher_new; rec_match_* may run on several
 * threads with the same matcher (rec_match_pixels calls OpenBLAS, whose own threading applies;
 * rec_matcher_new plans FFTs, so do not create matchers concurrently with other FFTW planners). */
typedef enum {
    REC_PHASES_3,            /* {0, 120, 240} deg (default) */
    REC_PHASES_6,            /* those and the same + transformer_deg (a delta-wye transformer) */
    REC_PHASES_CONTINUOUS    /* any phase, sub-sample, with its uncertainty */
} rec_phase_set;

typedef struct {
    rec_phase_set phases;
    double transformer_deg;  /* AC phase shift of a delta-wye transformer, deg (30); with
                              * REC_PHASES_6 it must not be a multiple of 60 (its shift would
                              * repeat one of 0/120/240: GS_EINVAL) */
    double unknown_p;        /* chi-square p-value below which no bulb fits: unknown (1e-3);
                              * [0, 1), 0 disables the test */
    double ambiguous_conf;   /* bulb or phase posterior below which it is ambiguous (0.8), [0, 1] */
    double min_snr;          /* brightness / its std below which a light is too dim (3), >= 0 */
    int band_gains;          /* 1: one brightness per band (each band of the template mean 1,
                              * the chromaticity Q_beta not used), so a per-band gain (extinction
                              * reddening, white balance) cancels; 0: one brightness times Q_beta
                              * (the paper's Eq. 7). Ignored for 1 band. 0 or 1 (1) */
    double model_error;      /* fractional model error (scintillation, template mismatch): each
                              * sample's variance is sigma^2 + (model_error * mu_b)^2, mu_b the
                              * band's RMS signal level, mu_b^2 = mean over the band's usable
                              * samples of x^2 - sigma^2 (>= 0). [0, 1) (0.04) */
} rec_eq7_opts;
/* Fill *o with the defaults in parentheses above. */
void rec_eq7_opts_default(rec_eq7_opts *o);

enum {
    REC_MATCH_UNKNOWN = 1u << 0,          /* no bulb fits: p_value < unknown_p (bulb -1) */
    REC_MATCH_PHASE_AMBIGUOUS = 1u << 1,  /* phase_confidence < ambiguous_conf, or no phase */
    REC_MATCH_BULB_AMBIGUOUS = 1u << 2,   /* bulb_confidence < ambiguous_conf, or no bulb */
    REC_MATCH_DIM = 1u << 3,              /* brightness below min_snr of its std (bulb -1) */
    REC_MATCH_BAD_INPUT = 1u << 4         /* some sample non-finite / sigma <= 0 (dropped), or
                                           * no usable sample at all (bulb -1) */
};

/* The answer for one light. No field is ever NaN or infinite.
 * - bulb >= 0: the best (bulb, phase) pair by posterior. Pairs are (bulb, phase) for a
 *   discrete phase set; for REC_PHASES_CONTINUOUS (bulb, the +-30 deg of phase around the
 *   bulb's best phase); a REC_REF_NONE (shape-only) bulb is one pair whatever its shift, and
 *   when it wins phase_deg = 0, phase_confidence = 0 and PHASE_AMBIGUOUS is set.
 * - bulb = -1: BAD_INPUT without usable samples (every number 0), or DIM or UNKNOWN: then the
 *   best fit within the database is in runner_bulb / runner_phase_deg / runner_confidence
 *   (its posterior if the light were in the database), and brightness, chi2, dof, p_value
 *   describe that fit; confidence, bulb_confidence and phase_confidence are 0. */
typedef struct {
    int bulb;                 /* index into the matcher's bulbs, -1 when there is no answer */
    double phase_deg;         /* grid phase, [0, 360): the phase of the set (discrete), or
                               * rec_shift_to_phase of the fitted shift (continuous) */
    double phase_sigma_deg;   /* continuous: 1-sigma of the phase from the chi2 curvature
                               * (Delta chi2 = 1), at most 51.96 (uniform); discrete: 0 */
    double brightness;        /* fitted sum over bands of the mean per-cycle flux (a* >= 0; with
                               * band gains sum_b a_b*, each >= 0) */
    double chi2;              /* weighted residual of the best fit, sum w (x - a* t)^2 (w with
                               * the model error) */
    int dof;                  /* usable samples - 2 (scale and phase); with band gains usable
                               * samples - bands with a usable sample - 1; >= 0 */
    double p_value;           /* chi-square tail probability of chi2 at dof (1 when dof = 0) */
    double confidence;        /* posterior of the best pair */
    double bulb_confidence;   /* posterior of the best bulb, summed over phases */
    double phase_confidence;  /* posterior of the best phase, summed over voltage-referenced
                               * bulbs (continuous: of phases within +-30 deg of it) */
    int runner_bulb;          /* second most probable pair (different bulb or phase), -1 if none */
    double runner_phase_deg;
    double runner_confidence;
    unsigned flags;           /* REC_MATCH_* */
} rec_match;

/* Templates Q_b(sigma) shift(phi, b_b(sigma)) at K windows for the DELIGHT entries with this
 * grid frequency and band count (REC_REF_UNLOCKED entries excluded; REC_REF_NONE entries are
 * searched over every shift (max(8K, 96) per cycle) and take part in the bulb decision but
 * never decide a phase). REC_PHASES_CONTINUOUS uses the same grid for every bulb, refined to
 * sub-sample precision. 2 <= K <= 4096; o NULL = defaults. GS_ENOTFOUND when no entry fits,
 * GS_ELIMIT when the templates would exceed 64 Mi values. The matcher borrows nothing from d;
 * free it with rec_matcher_free. */
typedef struct rec_matcher rec_matcher;
gs_status rec_matcher_new(const rec_delight *d, int grid_hz, int bands, int K,
                          const rec_eq7_opts *o, rec_matcher **out);
void rec_matcher_free(rec_matcher *m);
size_t rec_matcher_bulb_count(const rec_matcher *m);
/* Borrowed: the i-th candidate bulb (a copy owned by the matcher), NULL if out of range. */
const rec_bulb *rec_matcher_bulb(const rec_matcher *m, size_t i);

/* Eq. 7 for one light: signal and sigma hold bands * K values ([band * K + k]), any units
 * (the same for both); negative signal values are legal (noise after background removal).
 * sigma = +INFINITY drops a sample silently (saturated, masked); a non-finite signal with a
 * finite sigma, or sigma NaN or <= 0, drops the sample and sets REC_MATCH_BAD_INPUT. The
 * brightness is fitted jointly (maximum likelihood under Gaussian noise of std sigma).
 * GS_EINVAL for NULL arguments; bad samples are reported in out->flags, not as an error. */
gs_status rec_match_light(const rec_matcher *m, const double *signal, const double *sigma,
                          rec_match *out);
/* Eq. 7 for every light of a catalog (bands and K must match the matcher's: GS_EINVAL); out
 * has cat->count entries. Lights flagged REC_BLOB_NO_SIGNAL get bulb -1 and BAD_INPUT. */
gs_status rec_match_catalog(const rec_matcher *m, const rec_catalog *cat, rec_match *out);

/* Eq. 7 per pixel, as matrix products (OpenBLAS SGEMMs per block of 1024 rows; a rigorous
 * prefilter first sets aside rows that are dim for every template): x holds P rows of
 * bands * K values, noise_sigma one std per row (uniform over the row; the model error adds per
 * band, as for one light). With band gains or a model error (3 bands) the scores are per band:
 * one SGEMM of K columns per band. Writes the best bulb,
 * the phase in degrees (0 for a REC_REF_NONE bulb) and the posterior of the best pair (same
 * model, pairs and posterior code as rec_match_light; float scores are rescored in double when
 * their rounding could exceed 1e-3 nats; continuous phases by parabolic refinement of the grid
 * scores, exact Newton refinement for bright rows). bulb is -1, phase 0 and confidence 0 for
 * rows with a non-finite value or a sigma that is not finite and > 0, and for dim (min_snr) or
 * unknown (unknown_p at dof = bands * K - 2, with band gains bands * K - bands - 1) rows.
 * phase_deg and confidence may be NULL.
 * docs/recognition.md gives the throughput (one core: ~3-5 Mpixel/s for 1 Mpixel RGB K = 26
 * with three phases when most pixels are dark). */
gs_status rec_match_pixels(const rec_matcher *m, const float *x, const float *noise_sigma,
                           size_t P, int *bulb, float *phase_deg, float *confidence);

/* Chi-square tail probability Q(dof/2, chi2/2) (regularised upper incomplete gamma: series or
 * continued fraction, relative error < 1e-12 where the result is > 1e-300). 1 for chi2 <= 0 or
 * dof < 1, 0 for chi2 = +inf, NaN for NaN. */
double rec_chi2_sf(double chi2, int dof);

/* Throughput of rec_match_pixels (for `make bench` / `gridsurvey bench`): synthesises `pixels`
 * rows (a fraction lit_fraction lit by a random template of m at mean sample snr noise sigmas,
 * the rest pure noise of std 1; deterministic for a seed), times one rec_match_pixels call and
 * checks the lit rows. Call openblas_set_num_threads(1) first for a one-core figure. */
typedef struct {
    size_t pixels, lit, templates;
    int values_per_pixel;     /* bands * K */
    int prefilter_dim;        /* R of the dark-row prefilter (docs/recognition.md), 0 = none */
    double seconds;           /* wall time of rec_match_pixels */
    double pixels_per_s;
    double cpu_seconds;       /* CPU time of the process during the call (all threads) */
    double pixels_per_cpu_s;  /* the one-core figure on a busy machine */
    double lit_accuracy;      /* lit rows with the true bulb and phase */
} rec_eq7_bench;
gs_status rec_bench_eq7(const rec_matcher *m, size_t pixels, double lit_fraction, double snr,
                        unsigned long seed, rec_eq7_bench *out);

/* ------------------------------------------------------------ maps and plots */

/* Per-pixel recognition maps like the paper's Fig. 1 and per-light signal plots like its Fig. 3
 * (recognize/maps.c; docs/recognize-cli.md shows them).
 *
 * rec_pixel_maps_compute: every pixel's per-cycle values (docs/formats.md: (raw - black_level)
 * 2^h / cycles) minus a background: per frame and band, a mesh of 64-pixel boxes (SExtractor's
 * default), each the median of (at most 256 evenly spaced of) its unsaturated values,
 * interpolated bilinearly between box centres (constant beyond the outer centres). The pixel's
 * brightness B is the sum over bands of the mean over k of those values; its noise comes from the
 * capture's noise model (docs/formats.md), per sample. A pixel is mapped when B exceeds
 * threshold_sigma times the std of B; a pixel with a saturated sample in any frame or band is
 * REC_PIX_SATURATED and not matched (Eq. 17). Mapped pixels go through rec_match_pixels (Eq. 7
 * as SGEMM blocks, 16384 pixels per call) with one noise std per pixel, the RMS over its samples
 * (exact when the read noise dominates). Cost: one pass over the samples (integer sums when the
 * capture has no HDR maps and no shot-noise gain), the mesh medians, and rec_match_pixels on the
 * mapped pixels only: a 1024 x 1024, K = 26, RGB capture with 5 % of its pixels lit takes about
 * 0.2 s on one core (docs/bench-recognize.md). */
enum {
    REC_PIX_DARK = 0,       /* B below the threshold: not matched */
    REC_PIX_MATCHED,        /* matched: bulb >= 0 */
    REC_PIX_NO_ANSWER,      /* above the threshold, but dim, unknown or bad input (bulb -1) */
    REC_PIX_SATURATED       /* some sample saturated: not matched */
};

typedef struct {
    double threshold_sigma;   /* mapping threshold on B in noise sigmas, finite and > 0 (5) */
    void (*progress)(void *ctx, double fraction);  /* after each block: fraction of the mapped
                                                    * pixels done; NULL = none (NULL) */
    void *progress_ctx;       /* passed to progress (NULL) */
} rec_map_opts;
/* Fill *o with the defaults in parentheses above. */
void rec_map_opts_default(rec_map_opts *o);

/* Per-pixel results, row-major width * height arrays, each a separate malloc owned by the struct;
 * rec_pixel_maps_release frees them and zeroes the struct (it accepts NULL and a zeroed struct). */
typedef struct {
    int width, height;
    rec_phase_set phases;     /* the phase set of the Eq. 7 options given (for the legend) */
    double transformer_deg;
    double ambiguous_conf;    /* matched pixels below this confidence are drawn as ambiguous */
    double threshold_sigma;
    size_t mapped;            /* pixels not REC_PIX_DARK */
    size_t matched;           /* REC_PIX_MATCHED pixels */
    unsigned char *state;     /* REC_PIX_* */
    int *bulb;                /* index into the matcher's bulbs; -1 unless REC_PIX_MATCHED */
    float *phase_deg;         /* grid phase in [0, 360) (0 for a REC_REF_NONE bulb); 0 unless
                               * matched */
    float *confidence;        /* posterior of the best (bulb, phase) pair; 0 unless matched */
    float *brightness;        /* B, DN per flicker cycle, background removed (every pixel) */
    float *snr;               /* B / its noise std (every pixel; 0 if the std is 0) */
} rec_pixel_maps;

/* Compute the maps of cap with matcher m (built for cap's grid_hz, bands and K). eq7 must be the
 * options m was built with (NULL = defaults): the maps keep its phase set and ambiguous_conf for
 * drawing. o NULL = defaults. *pm is overwritten (not freed); on failure it is zeroed.
 * GS_EINVAL for a capture that breaks docs/formats.md, a matcher of other bands, or a bad
 * threshold; GS_ENOMEM. Memory besides the capture: 21 bytes per pixel kept, 16 more while it
 * runs, and a block of 16384 x bands x K floats. */
gs_status rec_pixel_maps_compute(const rec_capture *cap, const rec_matcher *m,
                                 const rec_eq7_opts *eq7, const rec_map_opts *o,
                                 rec_pixel_maps *pm);
void rec_pixel_maps_release(rec_pixel_maps *pm);

/* The map PNGs: 8-bit RGB. The map is drawn at the integer scale s = rec_map_scale(width,
 * height) = clamp(floor(640 / max(width, height)), 1, 16): map pixel (x, y) fills the s x s block
 * with top-left corner (s x, s y). The image is max(s width, 480) pixels wide and s height + L
 * high, with a legend (title and colour key, white background, text by PLplot's memcairo driver)
 * in the L rows below the map; columns right of the map are legend background. Pixels below the
 * threshold are black, saturated pixels white, unknown/dim/bad-input pixels grey
 * (HSV value V/2, see below).
 * - Phase map (Fig. 1): hue = phase_deg on the HSV colour wheel (0 deg pure red, 120 pure green,
 *   240 pure blue; REC_PHASES_6 adds 0/120/240 + transformer_deg, continuous phases use the whole
 *   wheel), saturation 1, value V = 0.35 + 0.65 t, t = log(snr / threshold) / log(snr99 /
 *   threshold) clamped to [0, 1], snr99 the 99th percentile of the mapped pixels' snr (1 when
 *   that is not above the threshold). A matched pixel whose confidence is below ambiguous_conf
 *   is ambiguous: grey. Legend: a swatch per phase of the set (continuous: a hue bar with ticks
 *   every 60 deg), ambiguous/unknown, saturated, below threshold.
 * - Bulb map: the bulbs present, ranked by pixel count, take the colours of a fixed 20-colour
 *   palette in that order (cycled beyond 20), times V; the legend lists them (id, technology,
 *   pixel count), most pixels first.
 * - Confidence map: confidence on a viridis-like scale (0 dark violet .. 1 yellow), flat; the
 *   legend is a colour bar with ticks every 0.25.
 * GS_EIO when path cannot be written (nothing is left behind), GS_ELIMIT beyond 65535 pixels a
 * side, GS_ENOMEM. Not thread-safe (PLplot has global state). */
int rec_map_scale(int width, int height);
gs_status rec_map_write_phase_png(const rec_pixel_maps *pm, const char *path);
gs_status rec_map_write_bulb_png(const rec_pixel_maps *pm, const rec_matcher *m, const char *path);
gs_status rec_map_write_confidence_png(const rec_pixel_maps *pm, const char *path);

/* Fig. 3 as one PNG (PLplot, cairo PNG driver; 1500 x 620 pixels for 1 band, 1500 x 1500 for 3):
 * one row of two panels per band. Left: each drawn light's measured signal divided by its fitted
 * brightness (match[i].brightness), signal / brightness at the window centres (k + 1/2)/K with
 * error bars sigma / brightness, and its best template's curve: the chromaticity-scaled BRF of the
 * best bulb at the recognised phase, averaged over a window of Delta/K centred at each time (so
 * the curve passes through the template values of Eq. 7 at the window centres). Right: the same
 * samples shifted by minus the light's phase shift (onto grid phase 0), over the phase-0 curves
 * (lights without a voltage-referenced phase are left out). Colours by bulb (as the paper's
 * figure), one symbol per light; a legend names each light (catalog index), its bulb and phase.
 * Drawn: the recognised lights (bulb >= 0), at most max_lights (1..16) of them, highest
 * sum(signal) / sqrt(sum(sigma^2)) first; with none, empty axes and a note. cat and match are
 * rec_match_catalog's input and output for m. GS_EIO when png_path cannot be written, GS_EINVAL
 * for bad arguments or bands that differ from m's. Not thread-safe (PLplot). */
gs_status rec_plot_signals(const rec_matcher *m, const rec_catalog *cat, const rec_match *match,
                           int max_lights, const char *png_path, const char *title);

/* ---------------------------------------------- maximum-likelihood oracle (recognize/ml_oracle.c) */

/* The optimum that Eq. 7 is judged against (tests/test_eq7_accuracy.c, `gridsurvey bench
 * accuracy`): the maximum-likelihood (template, brightness) under the exact noise of a camera,
 * written without anything from eq7.c. A sample x (any linear unit: DN, DN per cycle, a sum over
 * an aperture) of a light of mean mu is
 *   x = (n - bg_e) / gain + read_dn * N(0, 1),   n ~ Poisson(gain * mu + bg_e),
 * i.e. Poisson photo-electrons of the light and a known background that was subtracted, plus
 * Gaussian read noise. */
typedef struct {
    double gain;       /* electrons per unit of x, finite and > 0 */
    double read_dn;    /* Gaussian read noise std, units of x, finite and > 0 */
    double bg_e;       /* background electrons in the sample (subtracted from x), >= 0 */
} rec_pg_noise;

/* log p(x | mu), exact: the sum over electron counts n of Pois(n; gain mu + bg_e) N(x - (n -
 * bg_e)/gain; 0, read_dn^2), from its mode outwards until the terms fall below 1e-17 of the
 * largest (mu < 0 counts as 0). Any electron count (log n! by lgamma). Thread-safe. */
double rec_pg_log_likelihood(const rec_pg_noise *c, double x, double mu);

/* The maximum-likelihood template for one light: for each of the M templates (templates[j * D
 * + d], d = band * K + k as Eq. 7's), the log-likelihood sum_d rec_pg_log_likelihood(x_d, a t_d)
 * maximised over the brightness a > 0 (golden-section search, 18 steps in a bracket of +-6
 * standard deviations around the least-squares a: ~1e-6 nats from the top; templates 30 nats
 * below the best at their least-squares a are not refined). noise: one entry for every sample
 * (per_sample 0) or D entries (per_sample 1). *best = the winning template's index, *loglik (may
 * be NULL) its log-likelihood. Cost: M x D likelihoods of a few to a few hundred terms each, plus
 * 20 D per refined template: milliseconds per light, for accuracy studies only.
 * GS_EINVAL for NULL arguments, M or D < 1, a non-finite x or bad noise; GS_ENOMEM. */
gs_status rec_ml_oracle(const rec_pg_noise *noise, int per_sample, const double *x,
                        const double *templates, int M, int D, int *best, double *loglik);

#endif
