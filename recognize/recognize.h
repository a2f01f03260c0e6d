/*
 * recognize.h - the public interface of gridsurvey's recognize/ module (prefix rec_): lights as
 * blobs with per-frame photometry, Eq. 7 recognition of bulb and grid phase over DELIGHT (paper
 * Sec. 4), per-pixel maps and the paper's Fig. 2/3 plots, the maximum-likelihood oracle that
 * Eq. 7 is judged against, and AC light transport (Sec. 5: unmixing, rendering, relighting,
 * semi-reflection separation). Built on recognize/base/base.h (status, BRFs, DELIGHT, captures).
 * Ownership: functions that return allocated memory say so; free it with the named function.
 * Every destructor accepts NULL.
 */
#ifndef GRIDSURVEY_RECOGNIZE_H
#define GRIDSURVEY_RECOGNIZE_H

#include "recognize/base/base.h"

#include <math.h>
#include <stddef.h>
#include <stdio.h>

/* ------------------------------------------------------------------ plots */

/* A PNG of the BRFs of bulbs[0..count) over one cycle, one panel per band (like the paper's
 * Fig. 2), with axes, labels and a legend (PLplot, cairo PNG driver). */
gs_status rec_plot_brfs(const gs_bulb *const *bulbs, size_t count, const char *png_path,
                        const char *title);

/* ------------------------------------------------------- blobs (per light) */

/* Lights as blobs of a capture, SEP-style (Barbary 2016, after SExtractor), with per-frame
 * photometry for Eq. 7. Steps (recognize/blobs.c, blobs_deblend.c, blobs_photometry.c):
 *  1. per-cycle values (gs_capture_value); the mean image M = mean over k of the sum over
 *     bands (saturated samples enter M clipped at the saturation level: they are bright);
 *  2. background of M: a mesh of boxes of background_px, each the median of its pixels after
 *     two 3-sigma clips, a 3x3 median over the mesh, bilinear interpolation (linear
 *     extrapolation at the borders, so a pedestal or linear gradient is removed exactly);
 *  3. noise of M per pixel from the capture's noise model: per sample
 *     var(DN) = read_noise_dn^2 + 1/12 (quantisation) + max(DN - black, 0) / gain_e_per_dn,
 *     var(value) = var(DN) / c_eff^2 with c_eff = cycles / 2^h, at the background level;
 *  4. detection: M - background > threshold_sigma noise sigmas, or saturated in any frame,
 *     and (the halo cut) at least 1 % of the largest M - background within 8 pixels
 *     (Chebyshev): the threshold falls as sqrt(C) while a light's faint wide halo (scattering,
 *     skyglow) grows as C, so without the cut longer exposures join neighbours through their
 *     halos; with it a light's footprint is its core at any exposure;
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
 *     the mesh nodes used (each node's mean of its pixels' noise / n). With psf_weighted (the
 *     default) the sum is weighted (Horne 1986's optimal extraction): w_p = P_p / V_p, P_p the
 *     share of a Gaussian PSF at the light's centroid (8.) in pixel p, of the capture's PSF
 *     sigma (the median second moment of its brightest clean lights), V_p the pixel's variance
 *     averaged over the K windows; the same weights in every frame, the sum divided by
 *     sum_p w_p P_p: the light's flux when the PSF is that Gaussian, and for any PSF the flux
 *     times one factor per light (which Eq. 7's brightness absorbs), with less noise than the
 *     plain sum where read noise or the background matter;
 *  8. position: the windowed centroid (SExtractor's XWIN_IMAGE): a Gaussian window whose sigma
 *     comes from the aperture's second moment, iterated from the aperture's intensity-weighted
 *     centroid; unbiased for any symmetric PSF (at most 0.013 px of pixel-sampling error for
 *     1-1.5 px Gaussian PSFs without noise, tests/test_blobs.c).
 *     The position comes before the sums (step 8 is computed first).
 *  9. with psf_fit (the default), the multi-source PSF fit over the K frames (blobs_fit.c,
 *     docs/recognition.md "Detection at kilometre range"): a component that is not one
 *     spatial profile times one signal (a rank-1 test, PSF-free) is fitted as sources of a
 *     Gaussian PSF (positions and one sigma free, each source's per-frame fluxes free, by least
 *     squares), sources added at the residual's matched-filter peak while the chi-square drop
 *     is significant and the new source's signal is not a combination of the others'; with
 *     two or more sources its lights become the fit's (REC_BLOB_PSF_FIT: signal and sigma are
 *     the fitted fluxes and their noise; the catalog stays in raster order).
 * Works in O(K * bands * pixels), with OpenCV for components and morphology: 0.35 s for a
 * 1024 x 1024, K = 26, RGB capture (one core). */
enum {
    REC_BLOB_EDGE = 1u << 0,        /* aperture touches the image border: the light may be cut */
    REC_BLOB_SATURATED = 1u << 1,   /* some pixel saturated in some frame (excluded from sums) */
    REC_BLOB_DEBLENDED = 1u << 2,   /* split from touching lights with different signals */
    REC_BLOB_HDR = 1u << 3,         /* some aperture pixel was HDR-halved in some frame */
    REC_BLOB_NO_SIGNAL = 1u << 4,   /* every aperture pixel saturated: signal 0, sigma +Inf */
    REC_BLOB_PSF_FIT = 1u << 5      /* one of several sources of the multi-source PSF fit (9.):
                                     * signal and sigma are its fitted per-frame fluxes */
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
    int psf_weighted;         /* 1: PSF-weighted (optimal) photometry, 0: the aperture sum (1) */
    int psf_fit;              /* 1: the multi-source PSF fit over the K frames (9.), 0: off (1) */
    int threads;              /* threads of the PSF fit's groups, >= 0; 0 = the online CPUs (0);
                               * the catalog is the same bits on any number */
    int psf_fit_exhaustive;   /* 1: the fit's new-source search tries every candidate pixel
                               * instead of stopping at its Cauchy-Schwarz bound (the tests'
                               * slow path: the same catalog, bit for bit) (0) */
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
    double *pos_cov_px2;      /* 3 per light, (xx, xy, yy): the position's covariance from the
                               * PSF fit (9.: REC_BLOB_PSF_FIT lights), NaN for the others; NULL
                               * when the fit replaced no light */
    double *signal, *sigma;
    int width, height;        /* of the capture */
    double *drift_windows;    /* K values (even with no light), or NULL for a locked capture
                               * (every one 0): how far frame k's exposure windows moved across
                               * the flicker cycle, in windows (gs_capture_frame_drift; NaN:
                               * free running without the timing to tell); rec_match_catalog
                               * leaves out the frames not rec_frame_kept and raises the others'
                               * noise by their smear (REC_MATCH_DRIFT) */
    int window_period;        /* the capture's (GS_PERIOD_*: rec_drift_limit) */
    int *labels;              /* opts.labels: width * height, the light owning each aperture
                               * pixel, -1 elsewhere; else NULL */
} rec_catalog;
/* *cat is overwritten (not freed); on failure it is zeroed. GS_EINVAL for options outside
 * their ranges or a capture whose fields break docs/formats.md (NaN, Inf, negative noise,
 * cycles <= 0, halvings > 16), GS_ENOMEM. A scene with no light gives count 0 and GS_OK. */
gs_status rec_blobs_extract(const gs_capture *cap, const rec_blob_opts *o, rec_catalog *cat);
void rec_catalog_release(rec_catalog *cat);
/* The windowed centroid's (step 8) pixel-sampling bias for a Gaussian PSF of sigma
 * psf_sigma_px integrated over the pixels, without noise: its RMS over the light's sub-pixel
 * position, px per image axis (the window's rule of step 8 at the PSF's second moment). 0.0015 px
 * at 0.8 px, 3e-5 px at 1.1 px: a floor of the centroid's error only for sharp PSFs. NaN when
 * psf_sigma_px is not in (0, 64]. */
double rec_centroid_bias_px(double psf_sigma_px);

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
 * Bands (3): with REC_BANDS_REDDENED (the default) the band b brightness is a c_b(tau),
 * c_b = Q_beta(b) exp(-tau (f_b - 1)): the chromaticity reddened by extinction of optical depth
 * tau at 550 nm (Angstrom exponent 1.3, f_b = (lambda_b / 550 nm)^-1.3 at 650/550/450 nm), each
 * band free within chroma_tolerance of it (a Gaussian prior, marginalised), tau over a uniform
 * prior on [-0.3, 3]; so chromaticity stays information at low SNR while distant, reddened lights
 * still fit. REC_BANDS_FREE gives each band its own free brightness (chromaticity unused; the
 * log posterior sums -log(T_b)/2 + log Phi(S_b/sqrt(T_b)) over bands); REC_BANDS_CHROMA is the
 * paper's one brightness times Q_beta. The pixel path (rec_match_pixels) treats REDDENED as FREE.
 * Noise: each sample's variance is sigma^2 + (e mu_b)^2, mu_b the band's RMS signal level and e
 * the light's relative excess noise (scintillation): model_error when it is a number, else
 * measured per capture by rec_match_catalog (docs/recognition.md, "Noise").
 * Thread safety: a matcher is read-only after rec_matcher_new; rec_match_* may run on several
 * threads with the same matcher (rec_match_pixels calls OpenBLAS: on one thread its own
 * threading applies, on several it is set to one thread for the call, process-wide;
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
    int band_gains;          /* the band model, rec_band_model (REC_BANDS_REDDENED); ignored for
                              * 1 band */
    double chroma_tolerance; /* REC_BANDS_REDDENED: relative std of each band's gain around the
                              * reddened chromaticity (white balance, lamp-to-lamp spread),
                              * [0.001, 1] (0.05) */
    double model_error;      /* relative excess noise e of every light (scintillation): each
                              * sample's variance is sigma^2 + (e mu_b)^2, mu_b the band's RMS
                              * signal level, mu_b^2 = mean over the band's usable samples of
                              * x^2 - sigma^2 (>= 0). [0, 1), or NaN (default): measured per
                              * capture by rec_match_catalog; 0 for rec_match_light */
    double other_prior;      /* prior probability that a light's bulb is not in DELIGHT (its
                              * waveform a deformation of the best template's, eq7_nested.c):
                              * every confidence is of "in DELIGHT and this"; 0 = the paper's
                              * closed world, calibrated when DELIGHT covers the scene; 0.2 makes
                              * bulbs not in DELIGHT rarely confident (docs/recognition.md,
                              * "Bulbs not in DELIGHT"). [0, 1), or NaN (default): measured per
                              * capture by rec_match_catalog from its lights' evidence (EM of the
                              * share); 0 for rec_match_light */
    double flat_share;       /* the share of each light's flux that does not flicker (a halo of
                              * scattered light from many lamps, an unmodulated neighbour) and
                              * that the photometry takes for the light's, relative to its
                              * flickering flux phi: x = a (t + phi m), m the template's band
                              * means; each light's x minus phi/(1 + phi) of its band means
                              * before Eq. 7. [0, 0.5), or NaN (default): measured per capture
                              * by rec_match_catalog (the references' weighted median, 0 unless
                              * significant); 0 for rec_match_light */
    double blend_prior;      /* prior probability that a light is two lights in one aperture
                              * (eq7_nested.c): a blend more probable than not is flagged BLEND,
                              * and every confidence is of "one light and this". [0, 1) (0.1) */
    int nested_tests;        /* the nested-model tests of each light's best fit (eq7_nested.c: a
                              * second template, a smooth deformation, a bulb not in DELIGHT): 1
                              * (default), or 0 for Eq. 7 alone (never BLEND nor UNKNOWN by shape,
                              * p_other = p_blend = 0, other_prior and blend_prior unused) */
    int threads;             /* threads of rec_match_catalog and rec_match_pixels, >= 0; 0 = the
                              * online CPUs (0). The lights and rows are independent: the answers
                              * are the same on any number (rec_match_catalog's the same bits;
                              * rec_match_pixels' confidences within OpenBLAS's SGEMM rounding) */
    double max_drift_windows;   /* free running: a frame whose windows moved more than this many
                              * windows during its exposure (gs_capture_frame_drift) is left out
                              * of rec_match_catalog and rec_sources_auto; the maps answer no
                              * pixel once a frame is over it or over REC_MAX_DRIFT_WINDOWS (they
                              * cannot raise a smeared frame's noise); [0, inf] or
                              * REC_DRIFT_AUTO (rec_drift_limit) (REC_DRIFT_AUTO) */
} rec_eq7_opts;
typedef enum {
    REC_BANDS_CHROMA = 0,    /* one brightness times Q_beta (the paper's Eq. 7) */
    REC_BANDS_FREE = 1,      /* one free brightness per band */
    REC_BANDS_REDDENED = 2   /* one brightness times the reddened Q_beta, bands within a tolerance */
} rec_band_model;
/* Fill *o with the defaults in parentheses above. */
void rec_eq7_opts_default(rec_eq7_opts *o);

enum {
    REC_MATCH_UNKNOWN = 1u << 0,          /* no bulb fits: p_value < unknown_p (bulb -1) */
    REC_MATCH_PHASE_AMBIGUOUS = 1u << 1,  /* phase_confidence < ambiguous_conf, or no phase */
    REC_MATCH_BULB_AMBIGUOUS = 1u << 2,   /* bulb_confidence < ambiguous_conf, or no bulb */
    REC_MATCH_DIM = 1u << 3,              /* brightness below min_snr of its std (bulb -1) */
    REC_MATCH_BAD_INPUT = 1u << 4,        /* some sample non-finite / sigma <= 0 (dropped), or
                                           * no usable sample at all (bulb -1) */
    REC_MATCH_BLEND = 1u << 5,            /* two templates explain the light better than one
                                           * (two lights in one aperture): blend_* hold them
                                           * (bulb -1) */
    REC_MATCH_DRIFT = 1u << 6             /* the capture's windows drifted during the exposures
                                           * (free running, rec_catalog.drift_windows): frames
                                           * beyond rec_eq7_opts.max_drift_windows, or by an unknown
                                           * amount, left out, the others' noise raised by their
                                           * smear; the answer is theirs (every frame left out:
                                           * BAD_INPUT, bulb -1) */
};
/* Free running, a frame whose windows smear over at most this many windows is still a sample of
 * Eq. 5's window k; beyond, its samples follow no template and Eq. 7's answers were wrong and
 * confident (docs/recognition.md, "Free-running captures"; `gridsurvey bench accuracy
 * --drift-sweep` measures others): REC_DRIFT_AUTO's threshold unless the period was measured. */
#define REC_MAX_DRIFT_WINDOWS 0.5
/* The default of rec_eq7_opts.max_drift_windows (rec_unmix_opts.max_drift_windows takes it
 * too): the threshold follows how the capture's windows were timed (rec_drift_limit). */
#define REC_DRIFT_AUTO (-1.0)
/* The threshold max_drift_windows means for a capture timed window_period (GS_PERIOD_*): itself,
 * or for REC_DRIFT_AUTO +inf (every frame of known drift kept) when the period was measured
 * before each exposure, as the firmware does (the frames move with the grid's wander, both ways,
 * which their raised noise covers), else REC_MAX_DRIFT_WINDOWS (a nominal period slips every
 * frame the same way, which it does not: docs/recognition.md, "Free-running captures"). */
static inline double rec_drift_limit(double max_drift_windows, int window_period)
{
    if (max_drift_windows != REC_DRIFT_AUTO) return max_drift_windows;
    return window_period == GS_PERIOD_MEASURED ? INFINITY : REC_MAX_DRIFT_WINDOWS;
}
/* 1 when a frame whose windows drifted this much (gs_capture_frame_drift) is still a sample of
 * Eq. 5's window: at most max_drift_windows (NaN, unknown: 0). */
static inline int rec_frame_kept(double drift_windows, double max_drift_windows)
{
    return drift_windows <= max_drift_windows;
}
/* The frames of cap that are not rec_frame_kept (gs_capture_frame_drift) at
 * rec_drift_limit(max_drift_windows, cap->window_period); kept (may be NULL) gets K flags, 1 for
 * a kept frame. */
int rec_frames_left_out(const gs_capture *cap, double max_drift_windows, unsigned char *kept);

/* The answer for one light. No field is ever NaN or infinite.
 * - bulb >= 0: the best (bulb, phase) pair by posterior. Pairs are (bulb, phase) for a
 *   discrete phase set; for REC_PHASES_CONTINUOUS (bulb, the +-30 deg of phase around the
 *   bulb's best phase); a GS_REF_NONE (shape-only) bulb is one pair whatever its shift, and
 *   when it wins phase_deg = 0, phase_confidence = 0 and PHASE_AMBIGUOUS is set.
 * - bulb = -1: BAD_INPUT without usable samples (every number 0), or DIM or UNKNOWN, or a best
 *   fit whose template holds under 5 % of its energy on the usable samples (the light unseen
 *   where it was dropped; BULB_ and PHASE_AMBIGUOUS): then the
 *   best fit within the database is in runner_bulb / runner_phase_deg / runner_confidence
 *   (its posterior if the light were in the database), and brightness, chi2, dof, p_value
 *   describe that fit; confidence, bulb_confidence and phase_confidence are 0. */
typedef struct {
    int bulb;                 /* index into the matcher's bulbs, -1 when there is no answer */
    double phase_deg;         /* grid phase, [0, 360): the phase of the set (discrete), or
                               * gs_shift_to_phase of the fitted shift (continuous) */
    double phase_sigma_deg;   /* continuous: 1-sigma of the phase from the chi2 curvature
                               * (Delta chi2 = 1), at most 51.96 (uniform); discrete: 0 */
    double brightness;        /* fitted sum over bands of the mean per-cycle flux (a* >= 0; with
                               * band gains sum_b a_b*, each >= 0) */
    double band_brightness[GS_MAX_BANDS];   /* the fit's share of it in each band (a* Q_beta(b),
                               * or a_b* with band gains): the fit's model of band b's samples is
                               * band_flat[b] + band_brightness[b] t_b, t_b the best bulb's BRF
                               * window means (mean 1) at the fitted phase */
    double band_flat[GS_MAX_BANDS];   /* the flat part subtracted from band b's samples before
                               * the fit (rec_eq7_opts.flat_share; 0 without) */
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
    double model_error;       /* the relative excess noise e assumed for this light */
    double shape_p_value;     /* the smooth-deformation test of the best fit (1: not run) */
    double p_other;           /* posterior that the bulb is not in DELIGHT (other_prior); every
                               * confidence is of "in DELIGHT and this" (0: not run) */
    double blend_p_value;     /* the second-template test (1: not run or nothing found) */
    double p_blend;           /* posterior of two lights (blend_prior; 0: not run) */
    int blend_bulb[2];        /* REC_MATCH_BLEND: the two components (-1 otherwise), */
    double blend_phase_deg[2];   /* their phases (grid values for continuous bulbs) */
    double blend_share[2];       /* and their shares of the brightness */
    unsigned flags;           /* REC_MATCH_* */
} rec_match;

/* Templates Q_b(sigma) shift(phi, b_b(sigma)) at K windows for the DELIGHT entries with this
 * grid frequency and band count (GS_REF_UNLOCKED entries excluded; GS_REF_NONE entries are
 * searched over every shift (max(8K, 96) per cycle) and take part in the bulb decision but
 * never decide a phase). REC_PHASES_CONTINUOUS uses the same grid for every bulb, refined to
 * sub-sample precision. 2 <= K <= 4096; o NULL = defaults. GS_ENOTFOUND when no entry fits,
 * GS_ELIMIT when the templates would exceed 64 Mi values. The matcher borrows nothing from d;
 * free it with rec_matcher_free. */
typedef struct rec_matcher rec_matcher;
gs_status rec_matcher_new(const gs_delight *d, int grid_hz, int bands, int K,
                          const rec_eq7_opts *o, rec_matcher **out);
void rec_matcher_free(rec_matcher *m);
size_t rec_matcher_bulb_count(const rec_matcher *m);
/* Borrowed: the i-th candidate bulb (a copy owned by the matcher), NULL if out of range. */
const gs_bulb *rec_matcher_bulb(const rec_matcher *m, size_t i);
/* 1 when match mt (of m) reports a phase: a voltage-referenced bulb won, not PHASE_AMBIGUOUS. */
int rec_match_phase_known(const rec_matcher *m, const rec_match *mt);
/* The templates of Eq. 7: count, and template j's bands * K values (borrowed, [band * K + k],
 * NULL when j is out of range) with the index of its bulb and its BRF shift in cycles (either
 * may be NULL). */
size_t rec_matcher_template_count(const rec_matcher *m);
const double *rec_matcher_template(const rec_matcher *m, size_t j, int *bulb, double *shift_cycles);
/* The dimension R of the pixel path's dark-row prefilter (docs/recognition.md), 0 for none. */
int rec_matcher_prefilter_dim(const rec_matcher *m);

/* Eq. 7 for one light: signal and sigma hold bands * K values ([band * K + k]), any units
 * (the same for both); negative signal values are legal (noise after background removal).
 * sigma = +INFINITY drops a sample silently (saturated, masked); a non-finite signal with a
 * finite sigma, or sigma NaN or <= 0, drops the sample and sets REC_MATCH_BAD_INPUT. The
 * brightness is fitted jointly (maximum likelihood under Gaussian noise of std sigma).
 * GS_EINVAL for NULL arguments; bad samples are reported in out->flags, not as an error. */
gs_status rec_match_light(const rec_matcher *m, const double *signal, const double *sigma,
                          rec_match *out);
/* Eq. 7 for every light of a catalog (bands and K must match the matcher's: GS_EINVAL); out
 * has cat->count entries. Lights flagged REC_BLOB_NO_SIGNAL get bulb -1 and BAD_INPUT.
 * The excess noise (recognize/eq7_noise.c, docs/recognition.md "Noise"): a fixed model_error,
 * or measured: every light fitted with the camera noise, each light's excess e^2 from its
 * residuals, and for light i the weighted median of the OTHER clean lights' e^2 (weights their
 * precision times a kernel in image row and log brightness: a blend's or an unknown bulb's
 * misfit never raises its own noise), then the lights fitted again with it; out[i].model_error
 * is the e used. Fewer than 8 clean lights: the camera noise alone. noise (may be NULL) says
 * which. Free running (cat->drift_windows, any frame's not 0), a frame not rec_frame_kept is left
 * out of every light (its samples' sigma +inf), and a kept frame k that drifted d_k windows
 * gets d_k / 2 times the light's steepest step between adjacent kept windows of the band added
 * to its samples' sigma in quadrature (the smear's mean shift of the window, bounded by the
 * light's own samples); every light is flagged REC_MATCH_DRIFT. */
typedef enum {
    REC_NOISE_CAMERA,        /* the camera's noise model only (no population to measure from) */
    REC_NOISE_FIXED,         /* the options' model_error for every light */
    REC_NOISE_POPULATION     /* measured from the capture's other lights */
} rec_noise_source;
/* The lights' photometry kinds of the flat share: the aperture's or the PSF fit's
 * (REC_BLOB_PSF_FIT), with pixels saturated in some frame or not (REC_BLOB_SATURATED), which
 * take different shares of a halo: kind (psf_fit) + 2 (saturated). */
#define REC_FLAT_KINDS 4
#define REC_FLAT_KIND_NAMES {"aperture", "psf_fit", "aperture_saturated", "psf_fit_saturated"}
typedef struct {
    rec_noise_source source;
    size_t lights_used;           /* lights the measurement used */
    double median_model_error;    /* the capture's typical e (weighted median of all lights) */
    size_t reddening_lights;      /* REC_BANDS_REDDENED: the clean lights the population prior on
                                   * tau came from (eq7_population.c); 0: the uniform prior */
    double chroma_tolerance;      /* REC_BANDS_REDDENED: the band tolerance of the last pass,
                                   * measured from the bright lights (or the options') */
    size_t other_lights;          /* other_prior NaN: the lights its share came from (0: none) */
    double other_prior;           /* the share of bulbs not in DELIGHT used (measured or the
                                   * options') */
    size_t flat_lights;           /* flat_share NaN: the references it was measured on (0: none) */
    double flat_share;            /* the flat share subtracted (measured: the capture's phi0, each
                                   * light's shrunk to it or to its photometry kind's; or the
                                   * options') */
    double flat_spread;           /* measured: the spread of the lights' shares about phi0 */
    /* measured, per photometry kind (REC_FLAT_KIND_NAMES): the share its lights were shrunk to,
     * its own when significant (from kind_lights[k] of its lights), else the capture's
     * (kind_lights[k] 0) */
    double flat_kind_share[REC_FLAT_KINDS];
    size_t flat_kind_lights[REC_FLAT_KINDS];
} rec_noise_report;
/* "camera", "fixed", "population". */
const char *rec_noise_source_name(rec_noise_source s);
gs_status rec_match_catalog(const rec_matcher *m, const rec_catalog *cat, rec_match *out,
                            rec_noise_report *noise);

/* Eq. 7 per pixel, as matrix products (OpenBLAS SGEMMs per block of rows; a rigorous
 * prefilter first sets aside rows that are dim for every template, where it finds some): x holds P rows of
 * bands * K values, noise_sigma one std per row (uniform over the row; the model error adds per
 * band, as for one light). With band gains or a model error (3 bands) the scores are per band:
 * one SGEMM of K columns per band. Writes the best bulb,
 * the phase in degrees (0 for a GS_REF_NONE bulb) and the posterior of the best pair (same
 * model, pairs and posterior code as rec_match_light; float scores are rescored in double when
 * their rounding could exceed 1e-3 nats; continuous phases by parabolic refinement of the grid
 * scores, exact Newton refinement for bright rows). bulb is -1, phase 0 and confidence 0 for
 * rows with a non-finite value or a sigma that is not finite and > 0, and for dim (min_snr) or
 * unknown (unknown_p at dof = bands * K - 2, with band gains bands * K - bands - 1) rows.
 * phase_deg and confidence may be NULL. The blocks go over rec_eq7_opts.threads threads (the
 * same answers on any number; each thread holds a block of float scores: 512 rows x the
 * templates, fewer rows (down to 64) where that would pass 4 MiB, as with continuous phases).
 * docs/recognition.md gives the throughput (one core: ~3-5 Mpixel/s for 1 Mpixel RGB K = 26
 * with three phases when most pixels are dark). */
gs_status rec_match_pixels(const rec_matcher *m, const float *x, const float *noise_sigma,
                           size_t P, int *bulb, float *phase_deg, float *confidence);


/* ------------------------------------------------------------ maps and plots */

/* Per-pixel recognition maps like the paper's Fig. 1 and per-light signal plots like its Fig. 3
 * (recognize/maps.c, maps_draw.c, plot.c; docs/recognize-cli.md shows them).
 *
 * rec_pixel_maps_compute: every pixel's per-cycle values (docs/formats.md: (raw - black_level)
 * 2^h / cycles) minus a background: per frame and band, the background mesh of blobs (boxes
 * of about 64 pixels, SExtractor's default; recognize/background.c), each node the median of (at
 * most 256 evenly spaced of) its box's unsaturated values, interpolated bilinearly between box
 * centres (constant beyond the outer centres). The pixel's
 * brightness B is the sum over bands of the mean over k of those values; its noise comes from the
 * capture's noise model (docs/formats.md), per sample. A pixel is mapped when B exceeds
 * threshold_sigma times the std of B; a pixel with a saturated sample in any frame or band is
 * REC_PIX_SATURATED and not matched (Eq. 17). Mapped pixels go through rec_match_pixels (Eq. 7
 * as SGEMM blocks, 4096 pixels per call) with one noise std per pixel, the RMS over its samples
 * (exact when the read noise dominates). Cost: one pass over the samples (integer sums when the
 * capture has no HDR maps and no shot-noise gain), the mesh medians, and rec_match_pixels on the
 * mapped pixels only: a 1024 x 1024, K = 26, RGB capture with 5 % of its pixels lit takes about
 * 0.2 s on one core (docs/bench-recognize.md). */
enum {
    REC_PIX_DARK = 0,       /* B below the threshold: not matched */
    REC_PIX_MATCHED,        /* matched: bulb >= 0 */
    REC_PIX_NO_ANSWER,      /* above the threshold, but dim, unknown or bad input, or every
                             * pixel of a capture with a frame whose windows drifted beyond
                             * min(rec_drift_limit(rec_eq7_opts.max_drift_windows, its
                             * window_period), REC_MAX_DRIFT_WINDOWS): the
                             * pixel path cannot raise a smeared frame's noise (bulb -1) */
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
    double drift_limit_windows;   /* min(rec_drift_limit(...), REC_MAX_DRIFT_WINDOWS): the most a
                               * frame's windows may drift for the maps to answer */
    int drift_unanswered;     /* 1: no pixel answered because a frame's windows drifted beyond
                               * drift_limit_windows (REC_PIX_*) */
    unsigned char *state;     /* REC_PIX_* */
    int *bulb;                /* index into the matcher's bulbs; -1 unless REC_PIX_MATCHED */
    float *phase_deg;         /* grid phase in [0, 360) (0 for a GS_REF_NONE bulb); 0 unless
                               * matched */
    float *confidence;        /* posterior of the best (bulb, phase) pair; 0 unless matched */
    float *brightness;        /* B, DN per flicker cycle, background removed (every pixel) */
    float *snr;               /* B / its noise std (every pixel; 0 if the std is 0) */
} rec_pixel_maps;

/* Compute the maps of cap with matcher m (built for cap's grid_hz, bands and K). eq7 must be the
 * options m was built with (NULL = defaults): the maps keep its phase set and ambiguous_conf for
 * drawing. o NULL = defaults. *pm is overwritten (not freed); on failure it is zeroed.
 * GS_EINVAL for a capture that breaks docs/formats.md, a matcher of other bands, or a bad
 * threshold; GS_ENOMEM. Memory besides the capture and the matcher: 21 bytes per pixel kept,
 * with HDR maps or shot noise 4 more while it runs (then 4 per pixel to match), a block of 4096 x
 * bands x K floats and rec_match_pixels' scores. */
gs_status rec_pixel_maps_compute(const gs_capture *cap, const rec_matcher *m,
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
 * - Bulb map: a colour per bulb, times V; ambiguous pixels grey as in the phase map. The legend
 *   names the bulbs with at least 1 % of the coloured pixels, at most 12, most pixels first (id,
 *   technology, pixel count), each in a colour of its own; the other bulbs share one colour
 *   ("other": how many, their pixels) (internal.h: rec_bulb_legend).
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
 * error bars sigma / brightness (the frames the match used: free running, not those left out), and
 * the fit's model over the brightness: the best bulb's BRF at
 * the recognised phase, averaged over a window of Delta/K centred at each time, times the band's
 * band_brightness, plus its band_flat (so the curve passes through the fit's values at the window
 * centres; internal.h: rec_plot_template). Right: the same
 * samples shifted by minus the light's phase shift (onto grid phase 0), over the phase-0 curves
 * (lights without a voltage-referenced phase are left out). Drawn: at most max_lights (1..16)
 * recognised lights with a confident bulb, one per bulb first (the bulbs with the most such
 * lights, each's best: a known phase, then the highest sum(signal) / sqrt(sum(sigma^2))), then
 * each bulb's second best, ... (internal.h: rec_signal_lights); with none, empty axes and a note.
 * A colour per bulb (as the paper's figure), a symbol per light of the bulb, so no two lights
 * share both; a legend names each light (catalog index), its bulb and phase. cat and match are
 * rec_match_catalog's input and output for m. GS_EIO when png_path cannot be written, GS_EINVAL
 * for bad arguments or bands that differ from m's. Not thread-safe (PLplot). */
gs_status rec_plot_signals(const rec_matcher *m, const rec_catalog *cat, const rec_match *match,
                           int max_lights, const char *png_path, const char *title);

/* ------------------------------------------------- light transport (paper Sec. 5) */

/* AC light transport (recognize/nnls.c, unmix.c, sources.c, relight.c, separate.c,
 * transport_png.c; docs/light-transport.md). Per band sigma, the K-frame sequence of a scene
 * lit by S sources is I = T Q B (Eq. 13): T (P x S) the transport, Q = diag(Q_s) the sources'
 * chromaticities, B (S x K) their BRFs integrated to the K windows and shifted by their grid
 * phases (Eq. 14). Images are per band; "tau_s Q_s" is the cycle-mean image of source s alone
 * (Eq. 9), in DN per flicker cycle (docs/formats.md's per-cycle value). */

/* Non-negative least squares by Lawson and Hanson's active-set method (Solving Least Squares
 * Problems, 1974, ch. 23), on the normal equations: x = argmin_{x >= 0} x^T G x / 2 - h^T x,
 * G (n x n, row-major, symmetric positive semi-definite) and h as given; 1 <= n <= 32. The
 * passive set's systems are solved by Cholesky. Returns the iterations (>= 0), or -1 when a
 * passive system is singular (x is then the last feasible point) or n is out of range. */
int rec_nnls(const double *G, const double *h, int n, double *x);

#define REC_MAX_SOURCES 16
#define REC_SOURCES_FORMAT "gridsurvey-sources/1"
#define REC_DAYLIGHT "daylight"   /* the reserved bulb id of a constant source (BRF all ones) */

/* A source set (Eqs. 13-15): S sources of bands bands and K windows. Arrays owned (malloc),
 * freed by rec_sources_release (which accepts a zeroed struct). */
typedef struct {
    int S, bands, K;
    char (*bulb)[GS_ID_MAX];  /* [S] DELIGHT id, or REC_DAYLIGHT */
    double *phase_deg;        /* [S] grid phase (0 for daylight) */
    double *q;                /* [S * bands] chromaticity Q_s(band), sums to 1 over bands */
    double *b;                /* [(s * bands + band) * K + k] BRF window means, mean 1 */
    int *fixed;               /* [S] 1: B not refined by Eq. 18 (daylight: exactly ones) */
    int *merged;              /* [S] how many requested sources this one stands for (Eq. 15) */
} rec_sources;
void rec_sources_release(rec_sources *s);

/* One requested source: a DELIGHT bulb (or REC_DAYLIGHT) at a grid phase. */
typedef struct {
    char bulb[GS_ID_MAX];
    double phase_deg;
} rec_source_spec;

/* The source set of n specs (1..REC_MAX_SOURCES) at grid_hz, bands and K (2..1024): Q and B
 * from DELIGHT (gs_brf_integrate at gs_phase_to_shift(phase)), a daylight source with B = 1
 * and Q = 1/bands. Specs with the same bulb and the same BRF shift modulo one cycle (phi and
 * phi + 180 deg included) are inseparable (Eq. 15) and become one source; into[i] (may be NULL)
 * gets the source spec i went into. GS_ENOTFOUND naming the spec for a bulb DELIGHT lacks at
 * grid_hz with bands. */
gs_status rec_sources_build(const gs_delight *d, const rec_source_spec *specs, int n,
                            int grid_hz, int bands, int K, rec_sources *out, int *into);

/* The sources file, format gridsurvey-sources/1: {"format", "sources": [{"bulb", "phase_deg"},
 * ...]} (plus the keys rec_unmix's output adds, docs/light-transport.md), read through the
 * format kit (errors "FILE:LINE: field PATH: expected ..."). *specs is malloc'd (free()). */
gs_status rec_sources_read_specs(const char *path, rec_source_spec **specs, int *n);

/* `--sources auto` (Sec. 5.1 (a), (b)): sources from the pixels dominated by one source (bulbs
 * in view, nearby surfaces). Every pixel whose mean per-cycle value is at least min_snr noise
 * sigmas goes through Eq. 7 (rec_match_light with m, built for the capture; its per-cycle values
 * with the capture's noise model, saturated samples and drifted frames (rec_frame_kept)
 * dropped; the brightest 20000 of them); a
 * pixel is dominated when its best template fits to chi2/dof <= 3 with a phase posterior >=
 * 0.99 (m should be built with unknown_p 0: the fit decides). Each (bulb, phase) dominating at
 * least min_px pixels is a source, most pixels first; one at the BRF shift of a source already
 * taken with the same technology, or with a flicker (mean removed) within a cosine of 0.995 of
 * it, is that source seen through a similar model (Eq. 15); at most max_sources. *specs malloc'd (free()); *tested and *dominated
 * (either may be NULL) get the pixels tried and dominated. GS_ENOTFOUND when no source is. */
gs_status rec_sources_auto(const gs_capture *cap, const rec_matcher *m, double min_snr,
                           int min_px, int max_sources, rec_source_spec **specs, int *n,
                           size_t *tested, size_t *dominated);

typedef struct rec_unmix_result rec_unmix_result;

/* The capture numbers a sources file keeps for relighting (the input capture's). */
typedef struct {
    int grid_hz, K, bands, width, height, locked;
    double cycles;            /* C of frame 0 */
    double saturation_dn, black_level_dn, gain_e_per_dn, read_noise_dn;
} rec_capture_meta;
void rec_capture_meta_of(const gs_capture *cap, rec_capture_meta *m);

/* What `unmix` writes and `relight` reads: DIR/sources.json (gridsurvey-sources/1 with, per
 * source, "file" (its tau_s Q_s TIFF), "chromaticity", "brf" (the refined K samples per band),
 * "brf_database", "predicted_error", "merged", and "render" when written; at the top "capture"
 * (rec_capture_meta) and "unmix" (diagnostics)). write: atomic; files[s] and renders[s] (NULL
 * or "" = none) name each source's files in the directory. read: the sources (q and b from the
 * file), the meta and the file names (char[GS_PATH_MAX] each, malloc'd: free()). */
gs_status rec_sources_write(const char *path, const rec_sources *src, const rec_unmix_result *r,
                            const rec_capture_meta *meta, int refine, const char *const *files,
                            const char *const *renders, const double *brf_database);
gs_status rec_sources_read(const char *path, rec_sources *src, rec_capture_meta *meta,
                           char (**files)[GS_PATH_MAX]);

/* Eqs. 16-18. */
typedef struct {
    int refine;           /* rounds of Eq. 18 (B >= 0) then Eq. 16 again, 0..20 (1, the paper) */
    double max_error;     /* predicted relative error of a source above which the problem is
                           * ill-posed (Fig. 10), (0, inf) (0.5) */
    double max_inflation; /* a source whose variance at a pixel, from the usable samples only,
                           * exceeds this times its variance from all K samples is not
                           * determined there: fitted, but NaN (Eq. 17 discarded what measured
                           * it), > 1 (10) */
    double brf_sigma;     /* Eq. 18's freedom: B is the maximum a posteriori under a Gaussian
                           * prior of this std per window mean about the database's B (0.05:
                           * BRFs of one model agree to a few %), > 0 */
    double max_drift_windows;   /* free running: the frames left out (rec_frame_kept), [0, inf]
                           * or REC_DRIFT_AUTO (rec_drift_limit); the kept frames' noise is not
                           * raised by their smear as Eq. 7's is, so not auto by default
                           * (REC_MAX_DRIFT_WINDOWS) */
    void (*progress)(void *ctx, double fraction);   /* NULL = none */
    void *progress_ctx;
} rec_unmix_opts;
void rec_unmix_opts_default(rec_unmix_opts *o);

enum {
    REC_UNMIX_OK = 0,       /* every sample used */
    REC_UNMIX_PARTIAL,      /* some samples saturated (Eq. 17 discards them): recovered from the
                             * others (HDR, Eq. 19); a source they do not determine is NaN */
    REC_UNMIX_UNKNOWN       /* no source determined: NaN for all */
};

struct rec_unmix_result {
    int width, height, bands, S, K;
    float *tq;                /* [((s * height + y) * width + x) * bands + band]: tau_s Q_s, DN
                               * per cycle (>= 0), NaN where REC_UNMIX_UNKNOWN */
    float *sigma;             /* [as tq]: the 1-sigma of each value from the noise (Eq. 16's
                               * covariance of the unconstrained fit, of the last pass), NaN where
                               * tq is */
    double *b;                /* [(s * bands + band) * K + k]: the refined B (Eq. 18), mean 1 */
    unsigned char *state;     /* [height * width] REC_UNMIX_* */
    size_t partial_px, unknown_px;
    size_t unknown_values;    /* (pixel, source) pairs without a value (NaN), all bands */
    double cond[GS_MAX_BANDS];          /* condition number of the row-normalised QB per band */
    double predicted_error[REC_MAX_SOURCES];   /* of each source from the noise (Eq. 16's
                                         * covariance): sqrt(sum var) / ||tau_s Q_s||_F over
                                         * the pixels with every sample usable */
    double rms_residual;      /* weighted residual of the last Eq. 16 per degree of freedom
                               * (usable samples less the sources fitted; ~1 when the model fits
                               * to the noise) */
    float *residual;          /* [height * width]: the same of each pixel over its bands, where a
                               * missing source or a wrong BRF shows (Fig. 10's crosstalk); NaN
                               * without a fit or a degree of freedom */
    int ill_posed;            /* 1: rec_unmix returned GS_ENUMERIC for Fig. 10's reason */
};
void rec_unmix_release(rec_unmix_result *r);

/* Unmix cap with the sources src (bands and K as cap's): Eq. 16 per pixel and band, weights of
 * Eq. 17 (a sample with any band saturated discarded, and every sample of a free-running frame
 * whose windows drifted, rec_frame_kept; the others by their noise, the capture's
 * model at the pixel's level, so HDR-halved samples count with their exposure), T >= 0 by
 * rec_nnls; then `refine` rounds of Eq. 18 and Eq. 16 again. Eq. 18: each column of B by
 * rec_nnls over the pixels, from their linear Eq. 16 estimates with those estimates' noise
 * removed (errors in variables), samples within 10 % of the saturation left out (censored), a
 * Gaussian prior of std brf_sigma about the database's B, each source's change shrunk by
 * max(0, 1 - noise / change^2), rows renormalised to mean 1; fixed sources kept
 * (docs/light-transport.md). Ill-posed (GS_ENUMERIC, with
 * r->ill_posed = 1, cond and predicted_error filled, no images): S > K, QB of numerical rank
 * < S, or a source whose predicted error exceeds max_error. *r overwritten; release it also
 * after a failure. GS_EINVAL for mismatched arguments. */
gs_status rec_unmix(const gs_capture *cap, const rec_sources *src, const rec_unmix_opts *o,
                    rec_unmix_result *r);

/* The memory budget of the light-transport commands (gs_mem_check, GS_ELIMIT in one line
 * naming file, the declared sizes and the budget), checked before they allocate from their
 * inputs' declared sizes: unmix (after reading the capture; S sources, each source's K-frame
 * rendering when render), separate (after reading the capture) and relight (from a sources
 * file's declared capture, S sources). The bytes are the capture's samples and HDR maps, the
 * source images (12 B per source sample in unmix: values and sigmas; 4 in relight), the rendered or relit frames
 * (4 B per sample), REC_TRANSPORT_BYTES_PER_PIXEL for the rest (per-pixel state, image
 * writing) and REC_TRANSPORT_BASE_BYTES (the DELIGHT database and its tables): upper bounds of
 * the peak resident memory above the binary's baseline measured in docs/reliability.md. */
#define REC_TRANSPORT_BYTES_PER_PIXEL 96
#define REC_TRANSPORT_BASE_BYTES (16.0 * 1048576)
gs_status rec_unmix_budget(const char *capdir, const gs_capture *cap, int S, int render);
gs_status rec_separate_budget(const char *capdir, const gs_capture *cap);
gs_status rec_relight_budget(const char *sources_json, const rec_capture_meta *m, int S);

/* Eq. 19: the K-frame sequence of source s, out[((k * height + y) * width + x) * bands + band]
 * = tau_s Q_s * b_s[k] (DN per cycle; may exceed the sensor's saturation; NaN where unknown). */
gs_status rec_render_source(const rec_unmix_result *r, int s, float *out);

/* Eq. 20, generalised relighting: per source s, gain a_s (>= 0; 0 switches it off), and
 * optionally another bulb (its DELIGHT chromaticity and BRF, or REC_DAYLIGHT) and/or another
 * grid phase. */
typedef struct {
    double gain;
    char bulb[GS_ID_MAX];     /* "" = the source's own */
    int set_phase;            /* 1: phase_deg replaces the source's phase */
    double phase_deg;
} rec_relight_set;
/* frames[((k * height + y) * width + x) * bands + band] = sum_s a_s tau_s Q'_s b'_s[k] (DN per
 * cycle) from the sources src and their tau_s Q_s images tq ([s][p][band], as rec_unmix's),
 * with tau_s = (tau_s Q_s) / Q_s per band. A source whose bulb and phase are kept keeps its
 * refined BRF (src->b); one given another bulb or phase takes DELIGHT's (d, at grid_hz) shifted
 * exactly to its phase. A NaN tau Q stays NaN in the result unless the source is off. set has
 * src->S entries. GS_ENOTFOUND for a bulb DELIGHT lacks. */
gs_status rec_relight(const rec_sources *src, const float *tq, int width, int height,
                      const gs_delight *d, int grid_hz, const rec_relight_set *set, float *frames);
/* K frames of per-cycle values (rec_relight's layout) as a capture of meta's numbers: raw =
 * black + value * cycles / 2^h with each sample's pixel halved (HDR maps, h <= 16) just enough
 * to stay below the saturation; a NaN (or a value beyond 16 halvings) is written saturated, so
 * it reads back as no value. It is locked whatever meta's source was: its windows are regular
 * (rec_catalog.drift_windows). *cap is a complete capture (gs_capture_release it). */
gs_status rec_frames_to_capture(const rec_capture_meta *meta, const float *frames, gs_capture *cap);

/* Semi-reflection separation (Sec. 5.3, Eqs. 21-22): a window shows a daylit scene (constant
 * over the capture: BRF all ones) and the reflection of an indoor scene lit by one unknown AC
 * source. Per band, frames are ranked by their mean; I_hi and I_lo are the means of the top and
 * bottom thirds (at least one frame each: b_ac(hi) > b_ac(lo)), so by Eqs. 21-22
 * D = I_hi - I_lo = tau_ac (b_hi - b_lo) and I_lo - A I_hi = (1 - A) tau_out at A = b_lo / b_hi.
 * A in [0, 1) minimises the mutual information of D and I_lo - A I_hi (a 2-D histogram estimator
 * on at most 65536 evenly spaced pixels, 32 x 32 bins over mean +- 3 std of each, then a grid
 * of 200 values of A refined by golden section). Then transmitted = (I_lo - A I_hi) / (1 - A)
 * and reflection = mean_k I - transmitted: the cycle-mean images of the two (DN per cycle) when
 * the model holds. Pixels saturated in any frame are NaN. */
typedef struct {
    int width, height, bands;
    float *transmitted, *reflection;   /* width * height * bands each (owned) */
    double A[GS_MAX_BANDS];            /* the A of each band */
    double mi[GS_MAX_BANDS];           /* the mutual information at it, nats */
    double mi_a0[GS_MAX_BANDS];        /* and at A = 0 (no separation), for comparison */
} rec_separation;
gs_status rec_separate(const gs_capture *cap, rec_separation *out);
void rec_separation_release(rec_separation *s);
/* The mutual information (nats) of x and y (n pairs, NaN pairs skipped) by the histogram
 * estimator above with `bins` bins a side (2..256). */
double rec_mutual_information(const float *x, const float *y, size_t n, int bins);

/* The pictures of Figs. 4-6: img (width x height x bands, DN per cycle) as an 8-bit RGB PNG
 * (grey for 1 band), value / white clipped to [0, 1] with a 1/2.2 gamma; pixels with a NaN band
 * (unknown) magenta. white <= 0: rec_png_white. Atomic write. */
gs_status rec_write_image_png(const char *path, const float *img, int width, int height,
                              int bands, double white);
/* The 99.5th percentile of the finite samples (every band of evenly spaced pixels, at most
 * about 65536 samples), 1 if not positive: the white of a picture. */
double rec_png_white(const float *img, int width, int height, int bands);

/* ---------------------------------------------- maximum-likelihood oracle (recognize/ml_oracle.c) */

/* The optimum that Eq. 7 is judged against (tests/test_eq7_accuracy.c, `gridsurvey bench
 * accuracy`): the maximum-likelihood (template, brightness) under the exact noise of a camera,
 * written without anything from eq7_*.c. A sample x (any linear unit: DN, DN per cycle, a sum over
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

/* An excess the oracle knows (the simulator's scintillation): frame k's flux is multiplied by a
 * factor of mean 1 and relative variance frame_var[k], the same factor for the frame's samples of
 * every band (sample d is frame d % K). */
typedef struct {
    int K;
    const double *frame_var;   /* [K], finite, >= 0 */
} rec_pg_excess;

/* The maximum-likelihood template for one light: for each of the M templates (templates[j * D
 * + d], d = band * K + k as Eq. 7's), the log-likelihood sum_d rec_pg_log_likelihood(x_d, a t_d)
 * maximised over the brightness a > 0 (golden-section search, 18 steps in a bracket of +-6
 * standard deviations around the least-squares a: ~1e-6 nats from the top; templates 30 nats
 * below the best at their least-squares a are not refined). noise: one entry for every sample
 * (per_sample 0) or D entries (per_sample 1). *best = the winning template's index, *loglik (may
 * be NULL) its log-likelihood. ex (may be NULL): frames with an excess are Gaussian with the
 * Poisson-Gaussian variances plus the excess's rank-one covariance (exact in the limit of many
 * electrons, where the excess matters). Cost: M x D likelihoods of a few to a few hundred terms each, plus
 * 20 D per refined template: milliseconds per light, for accuracy studies only.
 * GS_EINVAL for NULL arguments, M or D < 1, a non-finite x or bad noise; GS_ENOMEM. */
gs_status rec_ml_oracle(const rec_pg_noise *noise, int per_sample, const rec_pg_excess *ex,
                        const double *x, const double *templates, int M, int D, int *best,
                        double *loglik);

/* OpenCV's version string (gridsurvey --version). */
const char *rec_opencv_version(void);

#endif
