/*
 * capture.h - the public interface of gridsurvey's capture/ module (prefix cap_).
 *
 * ACam acquisition (paper Sec. 6): the host side of the ACam controller link (the `hardware`
 * backend drives the controller through it), the coded-exposure model (C flicker cycles, mask
 * matrix M, HDR halving, AC-locked mask switching), the AC lock model, scene files and the
 * effect-by-effect simulator, the backends (sim, replay, hardware) and the acquisition loop.
 * docs/capture.md and docs/scene.md.
 *
 * Conventions: as recognize/base/base.h (gs_status, thread-local gs_detail(), destructors accept
 * NULL, ownership stated per function). A flicker cycle lasts Delta = 1/(2 f) (Eq. 1).
 */
#ifndef GRIDSURVEY_CAPTURE_H
#define GRIDSURVEY_CAPTURE_H

#include "recognize/base/base.h"

#include <stddef.h>

/* ------------------------------------ ACam controller link (firmware/ over a serial port) */

/* The host side of the serial protocol of the ACam controller firmware (firmware/,
 * docs/firmware.md): an Arduino Uno that tracks the mains zero crossings and emits the DMD
 * mask-switch trigger at the start and end of window k of every flicker cycle, AC-locked (paper
 * Sec. 6) or free running, for C cycles, and reports the measured half period of every cycle.
 * Lines are ASCII, "*HH"-checksummed (XOR, as NMEA 0183) in both directions. One link is used
 * from one thread. */
typedef struct cap_link cap_link;

typedef enum {
    CAP_LOCKED = 0,      /* windows re-anchored on every detected crossing (the paper's mode) */
    CAP_FREE_RUNNING = 1 /* windows at the period measured before the start, never re-anchored */
} cap_lock_mode;

typedef struct {
    int K;               /* windows per flicker cycle: 2..26 at 50 Hz, 2..22 at 60 Hz (Fig. 7) */
    int k;               /* the window exposed, 0..K-1: [k Delta/K, (k+1) Delta/K) */
    long cycles;         /* C, flicker cycles: 1..1000000 (the paper uses 100..1500) */
    cap_lock_mode mode;
} cap_link_config;

/* Opens a serial device (raw, 115200 8N1) holding the controller. GS_EIO (naming the path and
 * errno) if it cannot be opened or configured. Free with cap_link_close. */
gs_status cap_link_open(const char *path, cap_link **out);
/* Wraps an open descriptor (a tty is set raw 115200 8N1; a pipe or socket is used as is). The
 * link owns fd from then on, also on failure. */
gs_status cap_link_open_fd(int fd, cap_link **out);
/* Closes the descriptor and frees the link (NULL: nothing). Does not stop an exposure. */
void cap_link_close(cap_link *l);
/* Longest wait for a reply or for the next per-cycle line, ms (default 1000; >= 1). */
void cap_link_set_timeout_ms(cap_link *l, int timeout_ms);

/* The commands. Errors: GS_EIO for a timeout, an I/O error, a line the firmware reports as
 * corrupted (ERR SYNTAX, CHECKSUM, LONG) or no lock on the mains (ERR NOLOCK); GS_EFORMAT for a
 * reply with a bad checksum or an unexpected form; GS_EINVAL for a configuration out of range
 * (ERR RANGE, or checked here first), a command while an exposure runs (ERR BUSY) or START
 * before a configuration (ERR NOCFG); GS_ELIMIT for ERR LIMIT (K above the grid's limit, or
 * windows shorter than the DMD's 370 us). The detail names the command and the reply. */
gs_status cap_link_ping(cap_link *l);
gs_status cap_link_configure(cap_link *l, const cap_link_config *c);
gs_status cap_link_start(cap_link *l);
/* Stops a running exposure (no-op otherwise); cycles_done (may be NULL) gets its count. */
gs_status cap_link_stop(cap_link *l, long *cycles_done);

typedef struct {
    char state[12];       /* IDLE, ARMED, EXPOSING, DONE or FAULT */
    int locked;           /* the firmware has 64 consistent half periods */
    int grid_hz;          /* 50 or 60 when locked, else 0 */
    long cycles_done;     /* of the current or last exposure */
    long cycles;          /* C configured */
    int K, k;
    cap_lock_mode mode;
    double half_period_s; /* the last measured half period (0 if none) */
    char fault[12];       /* what stopped the last exposure: OK, SPURIOUS, MISSING, FREQ, LIMIT,
                           * LATE, OVERFLOW, STOPPED */
    char last_event[12];  /* the last crossing the tracker rejected (OK if none) */
} cap_link_status;
gs_status cap_link_get_status(cap_link *l, cap_link_status *st);
gs_status cap_link_cycle_count(cap_link *l, long *cycles_done);

/* The per-cycle log of one exposure: the grid frequency during it is 1 / (2 half_period_s[n])
 * (Eq. 1; successive half periods alternate by the detector's asymmetry, so average pairs). */
typedef struct {
    size_t cycles;               /* cycles logged: C when the exposure completed */
    double *half_period_s;       /* [cycles], owned: the measured Delta_n (0.5 us resolution,
                                  * and the Uno's clock tolerance, docs/firmware.md) */
    int grid_hz;                 /* 50 or 60 */
    double start_half_period_s;  /* locked: the prediction for cycle 0; free: Delta_0 */
    char fault[12];              /* "" when complete, else the firmware's fault name */
} cap_exposure_log;

/* Runs one exposure: CFG, START (repeated every 50 ms for up to 2 s while the firmware answers
 * ERR NOLOCK, i.e. right after power-up or a glitch), then collects one line per cycle until
 * EV DONE. *log is overwritten (release it with cap_exposure_log_release, also on failure).
 * Returns GS_OK with log->cycles == C. An EV FAULT returns GS_ELIMIT for FREQ and LIMIT, else
 * GS_EIO, with the cycles logged before it and log->fault set; silence for longer than the
 * link timeout returns GS_EIO (the exposure may still run: call cap_link_stop). */
gs_status cap_link_expose(cap_link *l, const cap_link_config *c, cap_exposure_log *log);
void cap_exposure_log_release(cap_exposure_log *log);

/* ==================================================================================== */
#include "gis/gis.h"

#include <stdint.h>

/* ------------------------------------------------ coded exposure (paper Sec. 6, Eq. 23) */

/* Hardware limits of the ACam (paper Sec. 6, Fig. 7 and footnote 5). */
#define CAP_MAX_MASKS 96           /* DMD mask memory: M <= 96 */
#define CAP_MAX_K_50HZ 26          /* windows per flicker cycle at 50 Hz (Fig. 7) */
#define CAP_MAX_K_60HZ 22          /* ... at 60 Hz */
#define CAP_DMD_MIN_HOLD_US 370.0  /* shortest mask display of the DMD (firmware's ERR LIMIT) */
#define CAP_MAX_CYCLES 1000000L    /* C, as the firmware accepts */

/* The acquisition of one frame: the shutter stays open for C cycles while the DMD steps
 * through the mask matrix M = [m1 0 m2 0 ... m_{M/2} 0] (Eq. 23), one pair per flicker cycle:
 * m_j exposes window k, [k Delta/K, (k+1) Delta/K), and is held for Delta/K; 0 blocks the rest
 * of the cycle. Cycle c uses pair j = c mod (M/2). Without HDR every m_j is all ones. The HDR
 * loop zeroes half of the non-zero elements of the row of each saturated pixel and acquires
 * the frame again: a row halved h times keeps the pairs j with j mod 2^h == 0, so the pixel
 * integrates exactly C / 2^h cycles when M/2 and C are multiples of 2^h. */
typedef struct {
    int grid_hz;               /* 50 or 60 */
    int K;                     /* windows per cycle: 2..26 at 50 Hz, 2..22 at 60 Hz */
    long cycles;               /* C: 1..CAP_MAX_CYCLES */
    int masks;                 /* M: even, 2..96 (M/2 exposing masks, each followed by 0) */
    double dmd_min_hold_us;    /* shortest mask display of the DMD, us (> 0; 370) */
    double max_hz;             /* highest grid frequency during the exposure (0: nominal):
                                * the windows Delta/K are shortest then */
    int hdr;                   /* 1: the HDR loop may halve rows */
    int hdr_max_rounds;        /* halving rounds allowed, 0..cap_acam_max_halvings (0: that) */
    int hdr_max_saturated_px;  /* the loop stops when at most this many pixels saturate (0) */
} cap_acam_config;

/* 50 Hz, K = 26, C = 500, M = 2, 370 us, no HDR. */
void cap_acam_config_default(cap_acam_config *c);
/* GS_ELIMIT for a hardware limit (K above 26 / 22, M above 96, a window Delta/K shorter than
 * dmd_min_hold_us, HDR rounds above the maximum), GS_EINVAL for values out of range or an HDR
 * configuration that cannot halve exactly (M/2 or C not a multiple of 2^rounds); the detail
 * names the field, the value, the limit and where it comes from. */
gs_status cap_acam_check(const cap_acam_config *c);
/* Halving rounds the masks allow: the times M/2 can be halved exactly, at most
 * floor(log2(M/2)) (paper: "until rows have one non-zero element"; 5 for M = 64, 4 for 96). */
int cap_acam_max_halvings(int masks);
/* Element M[p, col] (0 or 1) of the row of a pixel halved h times; col in 0..M-1 (odd columns
 * are the zero masks). */
int cap_mask_element(int masks, int halvings, int col);
/* Cycles in [first, first + C) that a pixel halved h times integrates (pair j = c mod (M/2)
 * exposed when M[p, 2 j] = 1). */
long cap_exposed_cycles(int masks, long first, long cycles, int halvings);
/* The highest halving count h <= max_h whose row exposes cycle c (a pixel halved h' <= that
 * integrates cycle c). */
int cap_cycle_level(int masks, int max_h, long c);

/* One round of the HDR loop on a frame of width x height x bands raw samples: every pixel with
 * a sample >= saturation_dn is saturated; saturated pixels with h < max_halvings get h + 1.
 * *saturated (may be NULL) gets the saturated pixels, *halved the pixels halved. */
gs_status cap_hdr_update(const unsigned short *raw, int width, int height, int bands,
                         double saturation_dn, int max_halvings, unsigned char *halvings,
                         size_t *saturated, size_t *halved);

/* The exact model value of one light in frame k (Eq. 5 through the masks): the BRF b delayed
 * by shift_cycles, its mean over window k of each of the cycles a pixel halved h times
 * integrates, summed: out[band] = exposed_cycles * i_k / K in units of "flux per cycle", with
 * i_k the Eq. 5 window mean (gs_brf_integrate). */
gs_status cap_acam_expected(const gs_brf *b, double shift_cycles, const cap_acam_config *c,
                            int k, int halvings, double *out);

/* ------------------------------------------------------------ AC lock (paper Fig. 9) */

/* Grid frequency models (docs/scene.md): the reference outlet's zero crossings over the
 * whole capture, crossing 0 at t = 0. */
typedef enum {
    CAP_FREQ_CONSTANT = 0,   /* hz, exactly */
    CAP_FREQ_RANDOM_WALK,    /* mean_hz + a smooth (2nd-order) and a fast (1st-order)
                              * Gauss-Markov process: statistics of shared/data/README.md */
    CAP_FREQ_TRACE           /* the crossings of a real mains recording (gs_mains_read) */
} cap_freq_model;

#define CAP_PATH_MAX 1024

typedef struct {
    cap_freq_model model;
    double hz;                /* constant: the frequency; random walk: the mean (Hz) */
    double sigma_hz;          /* random walk: std of the smooth part (0.02) */
    double corr_time_s;       /* ... its time constant: corr (1 + t/T) e^{-t/T} (18.8 s) */
    double fast_sigma_hz;     /* random walk: std of the fast part (0.002) */
    double fast_corr_time_s;  /* ... its time constant: corr e^{-t/T} (1 s) */
    char wav[CAP_PATH_MAX];   /* trace: the recording */
    double start_s;           /* trace: where the capture starts in it (first rising
                               * crossing at or after start_s) */
    unsigned long long seed;  /* random walk */
} cap_freq_config;

/* The timeline of one capture (opaque): zero-crossing times of the reference outlet, computed
 * lazily and deterministically as far as they are asked for. */
typedef struct cap_ac cap_ac;
/* grid_hz is the nominal 50 or 60. GS_EIO / GS_EFORMAT for an unreadable trace; a trace whose
 * crossings are fewer than 100 is GS_EFORMAT. */
gs_status cap_ac_new(const cap_freq_config *f, int grid_hz, cap_ac **out);
void cap_ac_free(cap_ac *ac);
/* Time of crossing c >= 0 (s); GS_ELIMIT beyond the end of a trace (detail: how far it goes). */
gs_status cap_ac_time(cap_ac *ac, long c, double *t_s);
/* Crossings a trace provides (LONG_MAX for the generated models). */
long cap_ac_available(const cap_ac *ac);

/* The C exposure windows of one frame acquisition. */
typedef struct {
    int K, k;                 /* window k of K */
    long cycles;              /* C */
    long first_cycle;         /* the crossing that starts the exposure */
    cap_lock_mode mode;       /* CAP_LOCKED: each window re-anchored at its cycle's crossing,
                               * timed with the predicted half period (the mean of the last
                               * two); CAP_FREE_RUNNING: a fixed period from the first one */
    int free_period_measured; /* free running: 1 = the mean half period of the 64 cycles before
                               * the start (as the firmware does), 0 = nominal 1/(2 grid_hz) */
    double clock_ppm;         /* free running: the controller clock's error (parts per million),
                               * which moves a nominal period (a measured one is timed with the
                               * clock it was measured with: the error cancels) */
    double jitter_us;         /* std of each window edge (DMD switching), us (0: none) */
    unsigned long long jitter_seed;
} cap_window_config;

/* Per cycle c of the exposure: the window in seconds and in reference phase (crossing index +
 * fraction of its half period; the BRF of a light at grid phase phi is B(phase - shift(phi))). */
typedef struct {
    long cycles, first_cycle;
    int K, k;
    double *t0_s, *t1_s;        /* owned, [cycles] */
    double *phase0, *phase1;    /* owned, [cycles] */
} cap_windows;

gs_status cap_ac_windows(cap_ac *ac, const cap_window_config *w, cap_windows *out);
/* The fixed half period that free-running windows are timed with (s), NaN when locked. */
gs_status cap_ac_window_period(cap_ac *ac, const cap_window_config *w, double *half_period_s);
/* How far free-running windows of period P (s) move across the flicker cycle during an
 * exposure of cycles half periods delta[0..cycles) (s, in P's clock): the range over the cycles
 * c of the window's offset from its cycle's crossing, (c P - sum_{i<c} delta_i) / delta_c
 * cycles, times K: in windows. At even c (crossings of one polarity: a zero-crossing detector's
 * asymmetry alternates the half periods) and the exposure's end, c = cycles (over delta of the
 * last cycle; an odd end is off by the asymmetry), so it holds the net motion. */
double cap_window_drift(const double *delta, long cycles, double P, int K);
void cap_windows_release(cap_windows *w);

/* Temporal blur of an exposure's windows relative to the ideal windows
 * [first + c + k/K, first + c + (k+1)/K) of its cycles c. */
typedef struct {
    double mean_offset_cycles;  /* mean offset of the window centres from the ideal, cycles */
    double spread_cycles;       /* std of that offset over the cycles (0 = no blur) */
    double range_cycles;        /* max - min of the offset */
    double length_rel_std;      /* relative std of the window lengths in phase */
} cap_blur;
gs_status cap_windows_blur(const cap_windows *w, cap_blur *out);
/* The BRF (delayed by shift_cycles) averaged over all the exposure's windows, per band
 * (integral over the windows / their total length): the Eq. 5 value i_k of window k when
 * nothing blurs. */
gs_status cap_brf_expose(const gs_brf *b, double shift_cycles, const cap_windows *w,
                         double *out);

/* ------------------------------------------------------------------ scenes */

#define CAP_SCENE_FORMAT "gridsurvey-scene/1"
#define CAP_TRUTH_FORMAT "gridsurvey-truth/1"

/* The simulator's effects, in pipeline order (docs/capture.md). A scene lists the ones it
 * wants in "effects"; the others are not computed at all. */
typedef enum {
    CAP_FX_FREQUENCY_WANDER = 0,  /* the grid follows grid.frequency instead of the nominal */
    CAP_FX_FREE_RUNNING_DRIFT,    /* the free-running controller clock's error (acam.locked false) */
    CAP_FX_DMD_JITTER,            /* random timing of each window edge */
    CAP_FX_EXTINCTION,            /* Koschmieder + Angstrom, per band, with distance */
    CAP_FX_SCINTILLATION,         /* log-normal, per light and cycle, not mains-locked */
    CAP_FX_PSF,                   /* Gaussian point spread, pixel-integrated */
    CAP_FX_LIGHT_TRANSPORT,       /* extended surfaces lit by the lights (and daylight), Sec. 5 */
    CAP_FX_SKYGLOW,               /* a halo around each light */
    CAP_FX_BLINKING_SIGN,         /* non-AC sources blinking at their own period */
    CAP_FX_HEADLIGHTS,            /* non-AC moving sources */
    CAP_FX_AMBIENT,               /* daylight / ambient pedestal (BRF = 1) */
    CAP_FX_SEMI_REFLECTION,       /* the view through a window: the indoor scene as a reflection
                                   * plus a daylit outdoor scene (Sec. 5.3) */
    CAP_FX_SHOT_NOISE,            /* Poisson photo-electrons */
    CAP_FX_SATURATION,            /* full-well clipping */
    CAP_FX_READ_NOISE,            /* Gaussian read noise */
    CAP_FX_ADC,                   /* quantisation to integer DN, clipped to the ADC range */
    CAP_FX_COUNT
} cap_effect;
/* The effect's name in scene files ("shot_noise", ...); NULL out of range. */
const char *cap_effect_name(cap_effect e);
/* GS_ENOTFOUND for an unknown name. */
gs_status cap_effect_parse(const char *name, cap_effect *e);

typedef struct {
    double x_px, y_px, width_px, height_px;   /* rectangle (top-left corner, size) */
    double period_s, duty, phase_s;           /* on during [phase, phase + duty period) mod period */
    double flux_e_per_cycle;                  /* total over the rectangle and bands, when on */
    double chroma[3];
} cap_sign;

typedef struct {
    double x0_px, y0_px, x1_px, y1_px;        /* path */
    double speed_px_s;                        /* along the path */
    double period_s;                          /* a new car every period_s */
    double offset_s;
    double flux_e_per_cycle;                  /* total over bands */
    double chroma[3];
} cap_car;

enum { CAP_GLOW_FLAT = 0, CAP_GLOW_SAME, CAP_GLOW_MIXED };

/* An object of a light-transport room: an axis-aligned box in camera coordinates (m; x right,
 * y down, z along the optical axis) that reflects and casts shadows. */
typedef struct {
    double min_m[3], max_m[3];
    double albedo[3];
} cap_box;

/* The effects' parameters, as parsed (meaning, units and defaults: docs/scene.md, "effects";
 * sigma2 < 0: computed from cn2; aperture: aperture averaging on). */
typedef struct {
    unsigned enabled;                 /* bit 1u << CAP_FX_* for each listed effect */
    struct { double clock_ppm; } drift;
    struct { double sigma_us; } jitter;
    struct { double visibility_km, angstrom, wavelength_nm[3]; } extinction;
    struct { double cn2, wavelength_nm, crosswind_m_s, source_size_m, sigma2; int aperture; } scint;
    struct { double sigma_px, radius_sigma; } psf;
    struct { double fraction, scale_px, radius_scale; int flicker; } skyglow;
    struct { cap_sign *items; size_t count; } signs;     /* owned */
    struct { cap_car *items; size_t count; } cars;       /* owned */
    struct { double e_per_px_cycle, top, bottom, chroma[3]; } ambient;
    struct { double sigma_e; } read_noise;
    struct {                                           /* light_transport (docs/scene.md) */
        double width_m, height_m, depth_m, floor_m;    /* the room around the camera */
        double albedo[3], checker_m, contrast;          /* its walls' reflectance and checker */
        cap_box *boxes;                                  /* owned */
        size_t n_boxes;
        double daylight_e, daylight_chroma[3];          /* daylight on the surfaces (0: none) */
        double shade_radius_px, shade_transmission;     /* lamp shades (radius 0: none) */
    } transport;
    struct { double reflectance, e_per_px_cycle, chroma[3]; } window;   /* semi_reflection */
} cap_effects;

/* One AC light of a scene (inline, from a GeoJSON file, or generated). */
typedef struct {
    char id[48];
    char bulb[GS_ID_MAX];        /* DELIGHT bulb id */
    double phase_deg;             /* grid phase (shift = gs_phase_to_shift) */
    double x_px, y_px;            /* image position (projected with gis_project if geographic) */
    int geographic;               /* 1: lat/lon/height given */
    double lat_deg, lon_deg, height_m;
    double distance_m;            /* station -> light (chord), 0 if unknown */
    double lumens;                /* luminous power (0 when flux is given directly) */
    double flux_e_per_cycle;      /* photo-electrons per flicker cycle at the sensor over all
                                   * bands, before extinction and the masks */
    int in_image;                 /* on the sensor */
    int line;                     /* line of the scene file that defines it (for messages) */
} cap_light;

typedef struct {
    char path[CAP_PATH_MAX];          /* the scene file ("" when parsed from text) */
    char name[64];
    unsigned long long seed;
    char utc[40];
    char delight[CAP_PATH_MAX];       /* DELIGHT SQLite file, "" = built-in */
    uint64_t fingerprint;             /* of the scene text (configuration identity) */
    /* grid */
    int grid_hz;
    cap_freq_config freq;
    double phases_deg[12];            /* the grid's phase set (default 0, 120, 240) */
    int n_phases;
    double transformer_deg;
    /* camera */
    gis_camera cam;                   /* pose and intrinsics (width/height = image size) */
    int has_station;
    int bands, bit_depth;
    double full_well_e, read_noise_e, qe, gain_e_per_dn, black_level_dn;
    double aperture_mm, transmission;
    /* ACam */
    cap_acam_config acam;
    int locked;
    int free_period_measured;
    long readout_cycles;              /* cycles between two acquisitions (readout, reload) */
    /* lights and effects */
    cap_light *lights;                /* owned */
    size_t n_lights;
    cap_effects fx;
} cap_scene;

/* Parse a scene (docs/scene.md). Errors are GS_EFORMAT (or GS_ELIMIT for an ACam limit, GS_EIO
 * / GS_ENOTFOUND for a file it names) with "FILE:LINE: field PATH: expected ..." (JSON syntax:
 * "FILE:LINE:COLUMN: JSON syntax: ..."). Relative paths inside resolve against base_dir.
 * *sc is overwritten; release it with cap_scene_release (also after a failure). */
gs_status cap_scene_parse(const char *text, const char *source, const char *base_dir,
                          cap_scene *sc);
gs_status cap_scene_read(const char *path, cap_scene *sc);
void cap_scene_release(cap_scene *sc);
/* Photo-electrons per flicker cycle (all bands) of a light of `lumens` at distance_m: isotropic
 * emission, CAP_PHOTONS_PER_LM_S photons per lumen-second, the aperture's area, the optics'
 * transmission and the quantum efficiency (docs/scene.md). */
#define CAP_PHOTONS_PER_LM_S 8.0e15
double cap_scene_flux_from_lumens(const cap_scene *sc, double lumens, double distance_m);

/* ------------------------------------------------------------------ simulator */

/* The scene renderer (opaque). Built once from a scene: the DELIGHT entries of its lights, the
 * per-light tables and the effect pipeline (one stage per listed effect; nothing else). */
typedef struct cap_sim cap_sim;

/* d: the DELIGHT database to draw bulbs from (borrowed during the call only); NULL = the scene's
 * "delight" file or the built-in database. GS_ENOTFOUND naming the light for an unknown bulb. */
gs_status cap_sim_new(const cap_scene *sc, const gs_delight *d, cap_sim **out);
/* Before it allocates anything, cap_sim_new checks that the render fits the memory budget
 * (gs_mem_check, GS_ELIMIT naming the scene, the frame and the lights): the bytes
 * cap_sim_bytes gives, the DELIGHT database and the tables built once (base), the frame and
 * the capture loop's buffers (these bytes per sample and per pixel, with the HDR maps), every
 * light's tables and footprint (per light), the light transport's images and the per-cycle
 * tables, upper bounds of the peak resident memory above the binary's baseline measured in
 * docs/reliability.md. */
#define CAP_RENDER_BASE_BYTES (16.0 * 1048576)
#define CAP_RENDER_BYTES_PER_SAMPLE 14
#define CAP_RENDER_BYTES_PER_PIXEL 4
#define CAP_RENDER_BYTES_PER_LIGHT 3072
double cap_sim_bytes(const cap_scene *sc);
void cap_sim_free(cap_sim *s);
const cap_scene *cap_sim_scene(const cap_sim *s);   /* borrowed copy held by the sim */
/* Threads to render on (default 0: the online CPUs; 1: the caller's only). A frame is the same
 * bits on any number: every stage splits rows or lights whose outputs are disjoint, random
 * streams are per row or per light, and each pixel sums its lights in scene order. */
void cap_sim_set_threads(cap_sim *s, int threads);

/* Render one acquisition of frame k: pass (HDR round, 0 first), index (acquisitions before it
 * in this capture: places it on the grid's timeline), halvings (per pixel, NULL = none).
 * raw (width x height x bands, may be NULL) gets the stored samples; dn (may be NULL) the
 * same before rounding to integers (double). Deterministic in (scene, k, pass, index,
 * halvings). */
gs_status cap_sim_render(cap_sim *s, int k, int pass, long index, const unsigned char *halvings,
                         unsigned short *raw, double *dn);
/* cap_sim_render into raw for the HDR loop (cap_acquisition). probe 1 (its decision only):
 * when more than max_saturated_px pixels could saturate, the noise stages run only on the rows
 * that hold one and every other sample is 0 (*probed 1); a sample cannot saturate when its mean
 * is at most half the electrons the saturation level needs (less 40 read-noise sigmas):
 * Poisson's Chernoff bound, P < e^-80. So the saturated pixels are those of the whole frame,
 * unless an event of that probability happens; else the whole frame (*probed 0). probe 0 right
 * after a probe of the same k, pass, index and halvings, with raw as the probe left it: the
 * probe's other rows rendered from the means it kept, so raw is the whole frame, the same bits
 * as cap_sim_render's; else cap_sim_render. */
gs_status cap_sim_render_hdr(cap_sim *s, int k, int pass, long index, const unsigned char *halvings,
                             unsigned short *raw, int probe, long max_saturated_px, int *probed);
/* Times (s, on the sim's grid timeline: the cap_ac crossings with timing effects, else
 * nominal half periods) of the crossings that start and end the C cycles of acquisition index:
 * crossings first_cycle and first_cycle + C. Index 0 starts the capture. */
gs_status cap_sim_exposure_span(cap_sim *s, long index, double *t_start_s, double *t_end_s);
/* The half period the free-running windows of acquisition index are timed with (s, on that
 * timeline; cap_ac_window_period) and how far they move during its exposure (cap_window_drift
 * of the timeline's half periods), NaN both when the ACam is locked. */
gs_status cap_sim_window_timing(cap_sim *s, long index, double *half_period_s, double *drift_windows);
/* The capture-level numbers of the simulated camera. */
double cap_sim_saturation_dn(const cap_sim *s);
double cap_sim_read_noise_dn(const cap_sim *s);

/* The pipeline, as built: stages in execution order (base stages have effect -1). */
typedef struct {
    const char *name;
    int effect;                  /* cap_effect, or -1 for a base stage */
    unsigned long long calls;    /* times run */
    unsigned long long items;    /* elements processed (pixels, lights, cycles) */
    double seconds;              /* wall time spent */
} cap_stage_info;
size_t cap_sim_stage_count(const cap_sim *s);
gs_status cap_sim_stage(const cap_sim *s, size_t i, cap_stage_info *info);
/* Calls of each effect's stage, counted where the pipeline runs it (a probe's completion runs
 * the noise stages again): 0 for an effect the scene does not list. */
unsigned long long cap_sim_effect_calls(const cap_sim *s, cap_effect e);

/* truth.json (CAP_TRUTH_FORMAT): every light (id, pixel, in_image, lat/lon/height when
 * geographic, distance, bulb id, technology, phase, flux) and the non-AC distractors; written
 * under the directory's shared lock (gs_capture_lock: it fails in one line while another
 * process acquires into the directory). */
gs_status cap_sim_write_truth(const cap_sim *s, const char *dir);


/* ------------------------------------------------------------------ backends */

/* What a backend acquires: the capture's fixed numbers. */
typedef struct {
    int grid_hz, K, bands, width, height;
    long cycles;                  /* C */
    int masks;                    /* M */
    int max_halvings;             /* HDR rounds it can do (0: none; replay serves stored maps) */
    int fixed_halvings;           /* 1: acquire() sets the halvings (replay) */
    int hdr;                      /* the HDR loop by default (scene / configuration) */
    int hdr_max_rounds, hdr_max_saturated_px;
    double saturation_dn, black_level_dn, gain_e_per_dn, read_noise_dn;
    int locked;
    int window_period;            /* free running: GS_PERIOD_* (capture.json window_period) */
    char utc[40];
    const char *station_json;     /* borrowed (NULL: none) */
    uint64_t fingerprint;         /* identity of the configuration (resume refuses others) */
} cap_acq_info;

/* One acquisition request. */
typedef struct {
    int k;                        /* window */
    int pass;                     /* HDR round, 0 first */
    long index;                   /* acquisitions before this one in the capture */
    int probe;                    /* 1: only the HDR loop's decision needs this one (more rounds
                                   * may follow): the backend may return a probe, every sample that
                                   * cannot reach the saturation level 0, when more than
                                   * max_saturated_px pixels could (cap_acq_timing.probed) */
    long max_saturated_px;
} cap_acquisition;

typedef struct cap_backend cap_backend;
void cap_backend_free(cap_backend *b);
const char *cap_backend_name(const cap_backend *b);
gs_status cap_backend_info(cap_backend *b, cap_acq_info *info);
/* Acquire into raw (width x height x bands) with the pixels' halvings (width x height; the
 * mask rows the DMD uses). A backend with fixed_halvings writes them instead. *cycles (may be
 * NULL) gets the frame's C (info.cycles unless the backend knows better, e.g. replay). */
gs_status cap_backend_acquire(cap_backend *b, const cap_acquisition *a, unsigned char *halvings,
                              unsigned short *raw, double *cycles);

/* The timing of the exposure of the backend's last successful acquisition (NaN: unknown). */
typedef struct {
    double grid_hz_measured;      /* mean grid frequency during the exposure, Hz */
    double start_s;               /* its start, s from the capture's first exposure (index 0) */
    double window_half_period_s;  /* free running: the fixed period of its windows, in the clock
                                   * of grid_hz_measured (NaN: locked or unknown) */
    double window_drift_windows;  /* free running: the range of the windows' offset from each
                                   * cycle's crossing over the exposure, in windows
                                   * (cap_window_drift; NaN: locked or unknown) */
    int probed;                   /* it was a probe (cap_acquisition.probe) */
} cap_acq_timing;
/* After cap_backend_acquire: sim from its timeline (C / (2 (t_end - t_start)) between the
 * exposure's first and last crossings, Eq. 1), hardware from the controller's per-cycle log
 * (1 / (2 mean half period); start_s from the capture's first acquisition in this process,
 * else NaN), replay what the source capture.json holds. Always GS_OK for a valid backend. */
gs_status cap_backend_timing(cap_backend *b, cap_acq_timing *t);

/* sim: renders sc (copied) with the bulbs of d (read during the call only; NULL: the scene's
 * DELIGHT file, else the built-in database; as cap_sim_new). cap_backend_sim_handle gives its
 * simulator (borrowed). */
gs_status cap_backend_sim_new(const cap_scene *sc, const gs_delight *d, cap_backend **out);
cap_sim *cap_backend_sim_handle(cap_backend *b);
/* replay: serves the frames (and HDR maps) of a capture directory. */
gs_status cap_backend_replay_new(const char *dir, cap_backend **out);

/* hardware: a camera through OpenCV VideoCapture, the mains zero crossings and the shutter and
 * trigger outputs through libgpiod (v1.6), and the ACam controller over its serial link.
 * Per acquisition: DMD masks (callback), wait for a crossing, shutter high, cap_link_expose
 * (C cycles of window k, locked or free running), shutter low, a trigger pulse, read the frame;
 * the crossings seen meanwhile are logged. */
typedef struct {
    const char *camera;           /* VideoCapture source (device index, path) */
    int camera_images;            /* 1: camera is an image-sequence pattern (CAP_IMAGES) */
    double exposure_margin_s;     /* added to the camera's exposure (cap_hw_exposure_s; 0.05) */
    const char *serial;           /* controller tty; NULL: use serial_fd */
    int serial_fd;                /* an open descriptor (the link owns it), -1: none */
    int link_timeout_ms;          /* per-line timeout of the link (1000) */
    const char *gpio_chip;        /* e.g. "gpiochip0"; NULL: no GPIO */
    int zc_line, shutter_line, trigger_line;   /* offsets; -1: not wired */
    int zc_timeout_ms;            /* longest wait for a crossing before an exposure (1000) */
    int grid_hz, K, bands, width, height;
    long cycles;
    int masks;
    int locked;
    int hdr;
    double saturation_dn, black_level_dn, gain_e_per_dn, read_noise_dn;
    /* DMD loading (the DMD is programmed by its own tool): called before each acquisition with
     * the mask matrix as per-pixel halvings; NULL: not wired. Returns non-zero on failure. */
    int (*load_masks)(void *user, int masks, const unsigned char *halvings, int width,
                      int height);
    void *load_masks_user;
} cap_hw_config;
void cap_hw_config_default(cap_hw_config *c);
gs_status cap_backend_hardware_new(const cap_hw_config *c, cap_backend **out);
/* The controller's START is retried while it reports NOLOCK, up to this long (capture/acam_link.c). */
#define CAP_LINK_LOCK_WAIT_MS 2000
/* The grid frequencies the controller accepts: nominal +- this (firmware/schedule.h; outside,
 * its FREQ fault ends the exposure). */
#define CAP_GRID_BAND_HZ 3.0
/* The camera exposure that spans the shutter's opening: the wait for the controller's lock,
 * C half periods at the lowest grid frequency the controller accepts, and the margin. */
double cap_hw_exposure_s(long cycles, int grid_hz, double margin_s);
/* The exposure the camera reports back (actual_s, NaN: not read back) against the one asked:
 * GS_ELIMIT in one line naming both when it is more than 2 % shorter (the camera clamped it to
 * its range: its frames would not span the C cycles; a longer one still does). */
gs_status cap_hw_exposure_check(const char *camera, double asked_s, double actual_s);

/* Per-acquisition log of the hardware backend (for tests and diagnostics). */
typedef struct {
    size_t crossings;             /* zero-crossing events read from the GPIO line */
    double mean_half_period_s;    /* from their timestamps (NaN if < 2) */
    size_t link_cycles;           /* cycles the controller logged */
    double link_mean_half_period_s;
} cap_hw_log;
gs_status cap_backend_hardware_log(cap_backend *b, cap_hw_log *log);

/* ------------------------------------------------------------------ acquisition loop */

/* Acquires frames 0..K-1 into a capture directory (docs/formats.md), each frame written as
 * soon as it is acquired (gs_capture_write_frame, atomic), with the HDR loop when enabled,
 * then capture.json. The directory's acquisition.json records the configuration fingerprint
 * and each finished frame's files with their sizes and FNV-1a checksums: a later run with the
 * same configuration keeps the frames that are present and intact, acquires the rest and
 * produces the same files as an uninterrupted run. */
typedef struct {
    int progress;                 /* -1: when stderr is a TTY (default); 0 off; 1 on */
    int stop_after;               /* stop after acquiring this many frames (0: never) */
    int force;                    /* 1: ignore earlier progress and start again */
    int hdr;                      /* -1: the backend's default; 0 off; 1 on */
    int hdr_max_rounds;           /* -1: the backend's default; above its max_halvings: GS_EINVAL */
    int hdr_max_saturated_px;     /* -1: the backend's default */
    int hdr_whole_passes;         /* 1: no probes, every HDR pass acquired whole (the same frames) */
} cap_loop_opts;
void cap_loop_opts_default(cap_loop_opts *o);

typedef struct {
    int frames_acquired;          /* in this run */
    int frames_kept;              /* found complete from an earlier run */
    long acquisitions;            /* in the whole capture (HDR passes included) */
    int max_passes;
    size_t saturated_px;          /* saturated pixels left over all frames */
    long probes, probes_kept;     /* HDR passes acquired as probes; of them the frame's last,
                                   * acquired again whole */
    int complete;                 /* capture.json written */
    double seconds;
} cap_loop_report;
gs_status cap_loop_run(cap_backend *b, const char *dir, const cap_loop_opts *o,
                       cap_loop_report *r);

#endif
