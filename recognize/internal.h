/* internal.h - recognize/ internals shared between its own files; other modules never
 * include it. */
#ifndef GRIDSURVEY_RECOGNIZE_INTERNAL_H
#define GRIDSURVEY_RECOGNIZE_INTERNAL_H

#include "recognize/recognize.h"

/* The background mesh (background.c) of blobs.c and maps.c: nx x ny boxes of about box_px,
 * box i spanning [bx[i], bx[i+1]) with centre cx[i]; each caller computes one value per node
 * (node index j * nx + i) and interpolates bilinearly between centres, linearly extrapolated
 * beyond the outer ones (extrapolate = 1) or constant there (0). */
typedef struct {
    int nx, ny;
    int *bx, *by;          /* nx + 1, ny + 1 box edges */
    double *cx, *cy;       /* box centres */
    int *ix, *iy;          /* per column / row: the box holding it */
    int *i0, *j0;          /* per column / row: left / top node of its interpolation cell */
    double *tx, *ty;       /* per column / row: interpolation weight of the right / lower node */
} rec_mesh;
gs_status rec_mesh_init(rec_mesh *m, int W, int H, int box_px, int extrapolate);
void rec_mesh_free(rec_mesh *m);
/* The (up to) 4 nodes and weights interpolating pixel (x, y); weights sum to 1 (some negative
 * when extrapolating). Returns the count. */
int rec_mesh_weights(const rec_mesh *m, int x, int y, int *node, double *w);
/* The value at (x, y) of node values g (g[node * stride]); the same over a float plane. */
double rec_mesh_at(const rec_mesh *m, const double *g, size_t stride, int x, int y);
float rec_mesh_at_f(const rec_mesh *m, const float *g, int x, int y);

/* ====================================== blobs (blobs*.c), shared between its files */

/* The extraction state of one capture (blobs.c builds it; deblending and photometry read it). */
typedef struct {
    const gs_capture *cap;
    const rec_blob_opts *o;
    int W, H, K, bands;
    size_t N;
    int sat_level;           /* raw >= sat_level is saturated (integer form of saturation_dn) */
    float black;
    gs_noise nz;             /* the capture's noise model */
    double *scale;           /* [k * (GS_MAX_HALVINGS + 1) + h] = 2^h / cycles_k */

    float *M;                /* mean image, then M - background */
    unsigned char *sat;      /* saturated in some frame and band */
    unsigned char *hdr;      /* halved in some frame */
    float *sumA, *sumB;      /* HDR only: sum_k scale^2, sum_k scale */

    rec_mesh mesh;
    double *fval, *fvar;     /* per-frame mesh: [((k * bands + b) * nodes + n)] mean, var of mean */

    unsigned char *det;      /* detection mask */
    int *comp;               /* component labels (0 = none) */
    int ncomp;
    int *stats;              /* 5 per label */

    int *fp;                 /* footprint owner (light index) or -1 */
    int *ap;                 /* aperture owner or -1 */
    int nlights, cap_lights;
    unsigned *lflags;        /* per light: DEBLENDED */
    double psf_sigma;        /* the capture's PSF sigma (photometry, step 7), px */
} rec_blob_state;
/* The variance (DN^2 per cycle^2) of a raw sample that integrated 1/scale cycles. */
static inline double rec_blob_sample_var(const rec_blob_state *s, unsigned raw, double scale)
{
    return gs_noise_raw_var(&s->nz, (double)raw) * scale * scale;
}
/* Noise of pixel p's samples from its mean level over the K windows, var_k[b * K + k], and
 * (level_k not NULL) the samples' levels above black per cycle (blobs_photometry.c). */
void rec_blob_pixel_var(const rec_blob_state *s, size_t p, double *var_k, double *level_k);
/* The share of a Gaussian PSF of sigma centred at (xc, yc) that falls in pixel (x, y). */
double rec_psf_share(int x, int y, double xc, double yc, double sigma);
/* How many Gaussian sigmas two normalised signals of n values differ by (blobs_deblend.c). */
double rec_signal_z(const double *u1, const double *s1, const double *u2, const double *s2, int n);
/* Step 9, the multi-source PSF fit over the K frames (blobs_fit.c): rewrites cat. */
gs_status rec_blob_psf_fit(rec_blob_state *s, rec_catalog *cat);
/* Value of the per-frame background mesh of frame k, band b at (x, y) (blobs.c). */
double rec_blob_frame_bg(const rec_blob_state *s, int k, int b, int x, int y);
/* Step 5, deblending (blobs_deblend.c); steps 6-7, apertures and photometry
 * (blobs_photometry.c): area[] per light, then the catalog. */
gs_status rec_blob_deblend(rec_blob_state *s);
gs_status rec_blob_apertures(rec_blob_state *s, int *area);
gs_status rec_blob_photometry(rec_blob_state *s, const int *area, rec_catalog *cat);
/* ================================================================= end of blobs */

#define REC_BULB_LEGEND_MAX 12        /* bulbs named in the bulb map's legend, at most */
#define REC_BULB_LEGEND_SHARE 0.01    /* each with at least this share of the pixels */
#define REC_BULB_OTHER_COLOUR REC_BULB_LEGEND_MAX   /* the palette entry of the legend's "other" */
/* The bulb colours of the bulb map (maps_draw.c): the listed bulbs' in rank order, then the
 * other's; and the degree sign in UTF-8. */
extern const unsigned char rec_bulb_palette[REC_BULB_OTHER_COLOUR + 1][3];
/* maps_draw.c: the bulb map's legend from each bulb's coloured pixels px[0..nb): listed[0..n),
 * n returned, the bulbs named in it, most pixels first (then by index): those with at least
 * REC_BULB_LEGEND_SHARE of all px, at most REC_BULB_LEGEND_MAX; colour[b] bulb b's
 * rec_bulb_palette entry: a listed bulb's rank (distinct), REC_BULB_OTHER_COLOUR for the other
 * bulbs with pixels (*other_bulbs of them, *other_px pixels: the legend's "other"), -1 for a
 * bulb without. */
size_t rec_bulb_legend(const size_t *px, size_t nb, size_t *listed, int *colour, size_t *other_bulbs,
                       size_t *other_px);
#define REC_DEG "\xc2\xb0"

/* plot.c: the signal plot's template of light mt, its best bulb b, in band at the n times u
 * (cycles): the fit's model of the light's samples divided by its brightness, (band_flat +
 * band_brightness c(u)) / brightness, c(u) the mean of b's BRF (mean 1) delayed by shift cycles
 * over a window of 1/K centred at u: at the window centres (k + 1/2)/K exactly Eq. 5's template
 * values (a Nyquist component, which the built-in DELIGHT does not have, is left out). C holds
 * b->brf.n / 2 + 1 values of scratch. */
gs_status rec_plot_template(const gs_bulb *b, const rec_match *mt, double shift, int K, int band,
                            const double *u, size_t n, double *c, _Complex double *C);
/* plot.c: a light of the signal plot, its catalog index, colour and symbol (0-based). */
typedef struct {
    size_t light;
    int colour, symbol;
} rec_signal_pick;
#define REC_SIGNAL_SYMBOLS 8
/* The lights the signal plot draws, pick[0..*n), *n <= max: of the recognised lights with a
 * confident bulb (bulb >= 0 without REC_MATCH_BULB_AMBIGUOUS, brightness > 0, a finite noise
 * sum > 0), the bulbs ranked by how many they have (most first, then by index), at most max;
 * each bulb's best light (a known phase before none, then the highest SNR, sum(signal) /
 * sqrt(sum(sigma^2))), then each bulb's second best, ... (at most REC_SIGNAL_SYMBOLS a bulb),
 * until max; in order of colour, then symbol. colour: the bulb's rank; symbol: the light's rank
 * within its bulb (no two lights share both). GS_ENOMEM. */
gs_status rec_signal_lights(const rec_matcher *m, const rec_catalog *cat, const rec_match *match,
                            size_t max, rec_signal_pick *pick, size_t *n);

/* OpenCV shim (recognize/opencv_shim.cpp), the only C++ in recognize/: plain C functions over
 * OpenCV 4 (core, imgproc, imgcodecs).
 * Every OpenCV or C++ exception is caught at this boundary and returned as a gs_status with a
 * gs_fail detail. Pixel buffers are borrowed and row-major with interleaved channels. */

/* 8-connected components of mask (nonzero = foreground, width x height bytes):
 * labels[y * width + x] = 0 for background, 1..*count for the components (raster order of their
 * first pixel). stats (malloc'd, free()) holds 5 ints per label 0..*count: area (pixels),
 * left, top, width, height of its bounding box. */
gs_status rec_cv_components(const unsigned char *mask, int width, int height, int *labels,
                            int *count, int **stats);
/* dst = grey-level dilation of src (width x height floats) with a (2 radius + 1)^2 square;
 * pixels outside the image do not take part. dst must not alias src. */
gs_status rec_cv_dilate_f32(const float *src, float *dst, int width, int height, int radius);
/* In-place dilation of a 0/1 byte mask with a (2 radius + 1)^2 square. */
gs_status rec_cv_dilate_u8(unsigned char *mask, int width, int height, int radius);

/* ================================================= Eq. 7 (eq7_*.c), shared between its files */

/* complex.h before the matcher: its Fourier series are C99 double complex */
#include <complex.h>
#include <math.h>

#define EQ7_TWO_PI 6.283185307179586476925286766559
#define INV_SQRT12 0.28867513459481288225457439025098  /* std of a uniform shift, cycles */
#define CUT_PIXEL 30.0    /* nats: pairs this far below the best are < 1e-13 of it */
/* nats: continuous bulbs this far below the best keep their grid peak (not above CUT_PIXEL: the
 * screen of bulbs leaves closed, unrefined, bulbs whose every cell is below CUT_PIXEL) */
#define CUT_REFINE CUT_PIXEL
#define FLOAT_ERR 2e-6    /* error of z^2/2 from float scores, per unit |x|^2/sigma^2 */
/* a row's |x|^2 in double (eq7_pixels.c), and the pixel path's bound on that error for a row of
 * Sxx = |x|^2/sigma^2 (eq7_pixels.c, eq7_pixscreen.c) */
double rec_pix_sumsq(const float *x, size_t n);
static inline double rec_pix_float_err(double Sxx)
{
    return FLOAT_ERR * Sxx + 1e-6;
}
#define PHASE_WINDOW 0.16666666666666666  /* +-30 deg of phase = +-1/6 cycle of shift */
#define PIX_BLOCK 512    /* rows per SGEMM block (its band scores stay in L2) */
#define PIX_BLOCK_BYTES (4u << 20)   /* at most, for a block's float scores (continuous grids) */
/* The lights' kernel medians of the excess take at most this many references (every k-th by
 * excess: a sample stratified in e2; eq7_noise.c), so that their cost stays linear in the lights
 * (with every pair, 6 of the 14 s of 32,000 lights). Not fewer: a sample of a third of the demo's
 * ~5,000 references left 13 more of its lights unknown (a noisier excess). */
#define NOISE_MAX_REFS 8192
#define PIX_PREFILTER_REST 7   /* blocks without the prefilter after one it hardly filtered */
#define SUMS_ROWS 8       /* the light path's sums: lights and templates of one tile (eq7_sums.c) */
#define SUMS_COLS 16
#define SUMS_COLS_F 32    /* (in float) */
#define LANES 16          /* row loops in blocks of 16 floats (vectorised by the compiler) */
/* gcc vector types (eq7_light.c, eq7_pixels.c): a load from memory of any alignment, and a select
 * by a comparison's mask m of integer vector type IT (the same values as the scalar m ? a : b;
 * macros: a function returning a vector would take the ABI of the widest one) */
#define REC_VLOAD(v, p) memcpy(&(v), (p), sizeof(v))
#define REC_VSELECT(T, IT, m, a, b) ((T)(((IT)(a) & (m)) | ((IT)(b) & ~(m))))
/* p = four complex products a x ((re, im) pairs, 8 doubles from the pointers a and x): re =
 * ar xr - ai xi, im = ai xr + ar xi, the operations of C's product under -fcx-limited-range.
 * Written as scalar code, such a pair is fused into vfmaddsub by gcc 12's AVX-512 vectorizer
 * (despite -ffp-contract=off), and the clones' sums differ; so the vectors, a group of fewer
 * than four from zero-padded copies. */
typedef double rec_cx4 __attribute__((vector_size(8 * sizeof(double))));
#define REC_CX4_MUL(p, a, x)                                                                        \
    do {                                                                                            \
        rec_cx4 a_, x_, s_ = {-1.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0};                          \
        REC_VLOAD(a_, a);                                                                           \
        REC_VLOAD(x_, x);                                                                           \
        (p) = a_ * __builtin_shufflevector(x_, x_, 0, 0, 2, 2, 4, 4, 6, 6) +                        \
              s_ * (__builtin_shufflevector(a_, a_, 1, 0, 3, 2, 5, 4, 7, 6) *                       \
                    __builtin_shufflevector(x_, x_, 1, 1, 3, 3, 5, 5, 7, 7));                       \
    } while (0)
#define LOGPHI_ZMAX 12.0
#define LOGPHI_STEPS 32   /* table points per unit of z */

struct rec_matcher {
    int grid_hz, bands, K, D;           /* D = bands * K values per light */
    rec_eq7_opts o;
    size_t nb;                          /* candidate bulbs */
    gs_bulb *bulbs;                    /* owned copies */
    int np;                             /* discrete phases (3 or 6), 0 in continuous mode */
    double phase_deg[6];
    int G;                              /* grid cells per cycle for continuous bulbs */
    unsigned char *cont;                /* [nb] bulb searched over a continuous shift */
    size_t *first, *count;              /* [nb] its templates */
    size_t M;                           /* templates */
    double *t;                          /* [M * D] templates */
    double *tsq;                        /* [M * D] squared templates */
    size_t Mp;                          /* M rounded up to a multiple of LANES */
    float *tn;                          /* [Mp * D] templates / |t| (pixels), zero padded */
    float *lnf;                         /* [Mp] log |t| as float, 1e30 for padding */
    double *tnd;                        /* [M * D] templates / |t| in double */
    int pr;                             /* prefilter dimension R (0: no prefilter) */
    float *pe;                          /* [R * D] orthonormal basis of the prefilter */
    float *pc;                          /* [Mp * R] template coefficients in that basis */
    float *prho;                        /* [Mp] residual norms of the unit templates */
    int ncont;                          /* bulbs searched over a continuous shift */
    double *lognorm;                    /* [M] log |t| */
    double *cellw;                      /* [M] prior mass of the template within its bulb */
    double *logcellw;                   /* [M] its log */
    /* the light path's sums over a block of lights (eq7_sums.c): the templates and their squares
     * transposed, [D * ldtr] each (ldtr = M rounded up to SUMS_COLS, zero padded); NULL when
     * every template is a Fourier grid (fourier and all bulbs continuous) or the sums go in
     * float (fsums) */
    size_t ldtr;
    double *ttr, *tsqtr;
    /* and in float, when the block's sums go in float first (fsums: one brightness, no reddening,
     * no nested tests, discrete phases only): every template's score bounded from them with
     * their error bound, the double sums taken only for the templates scored exactly
     * (rec_eq7_exact_sums); ldtrf = M rounded up to SUMS_COLS_F, plus SUMS_COLS_F */
    int fsums;
    size_t ldtrf;
    float *ttrf, *tsqtrf;
    double *tnorm;                      /* [M] |t| as exp(lognorm) (the float sums' bound, the
                                         * pixel path's exact scores from a grid: no exp per row) */
    double *shift;                      /* [M] cycles */
    double *tphase;                     /* [M] grid phase, deg (0 for GS_REF_NONE bulbs) */
    int *tbulb, *tcell;                 /* [M] bulb, index among the bulb's templates */
    /* Fourier series of the window means, continuous bulbs only:
     * t_k(s) = F0 + sum_h Re(F_h e^{2 pi i h (k/K - s)}) + nyquist term. */
    int *H;                             /* [nb] harmonics kept */
    double complex **F;                 /* [nb] -> [bands * (H + 1)], F[band * (H+1) + h] */
    double *nyq;                        /* [nb * bands] Nyquist coefficient */
    /* The Fourier form of the continuous grids (fourier: K divides G, so window k is window 0
     * delayed by G/K cells, t_k(c) = t_0(c - k G/K)): per continuous bulb and band the DFT over
     * the G cells of t_0(c) and of t_0(c)^2, divided by G, bins 0..G/2 (eq7_matcher.c) */
    int fourier;
    double complex *ahat, *bhat;        /* [nb * bands * (G/2 + 1)] */
    int exhaustive;                     /* 1: neither the Fourier form, the block sums' kernel
                                         * nor the screen of the light path (eq7_sums.c,
                                         * eq7_scores.c; the pixel path ignores it): every
                                         * template's sums as matrix-vector products and its
                                         * exact L (the tests' slow path); 0 from rec_matcher_new */
    void *c2r;                          /* fftw_plan: G-point complex-to-real, on FFTW-aligned arrays
                                         * (w->spec, w->grid: fftw_malloc, its SIMD codelets) */
    int *nfine;                         /* [nb] BRF samples per cycle */
    double *dftc, *dfts;                /* [K * K] cos, sin of 2 pi q k / K ([k K + q]) */
    double *nyqs, *nyqc;                /* [nb * (K + 1)] sin, cos of pi nfine k / K (continuous) */
    /* the refinement's series (eq7_series.c), continuous bulbs: f(x) = Re sum A_h e^{2 pi i h x},
     * h <= rs_h (the Nyquist term as harmonic nfine / 2), and f^2 = Re sum B_g e^{2 pi i g x},
     * g <= 2 rs_h; per band the real parts, then the imaginary parts, each zero padded to 8 */
    int *rs_h;                          /* [nb] */
    int rs_hmax;                        /* their largest */
    double **rs_a, **rs_b;              /* [nb] -> A ([band][re, im]), B ([band][re, im]) */
    /* the pixel path's Fourier screen (eq7_pixscreen.c: fourier and the one-score path) */
    int fs_on;                          /* REC_FS_ON: rec_match_pixels uses it; _OFF: the matcher
                                         * has none (one SGEMM of every template); _ALL (tests):
                                         * the screen's kernel on every bulb of every row */
    double *fs_a;                       /* [nb * bands * 2 * np] f_n ahat_n / min |t| (re, im; np =
                                         * rec_eq7_harmonics_np) */
    double *fs_tail;                    /* [nb * bands * K] sum of |f_n ahat_n| / min |t| over the
                                         * harmonics n > K/2 with n mod K = q ([b][band][q]) */
    double *fs_lnfmin;                  /* [nb] least log |t| of the bulb's templates */
    /* the light path's screen of continuous bulbs (eq7_bulbscreen.c; bs_on: fourier, every bulb
     * continuous, not reddened, no nested tests): per bulb [bands][re, im rec_eq7_harmonics_np] f_n ahat_n and
     * f_n bhat_n, n <= K/2; [bands][K] the tails (sum of |f_n hat_n| over n > K/2, n mod K = q);
     * [nfit] the least |t|^2 of its cells over each brightness's samples */
    int bs_on;
    double *bs_a, *bs_b, *bs_at, *bs_bt, *bs_t2;
    size_t *fs_off;                     /* [nb] where each bulb's blocks start in fs_tb */
    float *fs_tb;                       /* the unit templates tn of each bulb in blocks of LANES
                                         * templates, [block][D][LANES] (zero past its last):
                                         * the screen's kernel reads them in order */
    double *harm;                       /* [2 REC_SHAPE_H K] the shape test's columns within a
                                         * band: cos, sin of 2 pi h k / K, h = 1..REC_SHAPE_H
                                         * ([(2 (h - 1) + q) K + k], q = 1 sin; eq7_nested.c) */
    double chi2_thr;                    /* pixels: chi2 at p = unknown_p, dof D - nfit - 1 */
    /* per-band brightness (band_gains) and model error */
    int bg;                             /* per-band sums and templates of mean 1 per band
                                         * (REC_BANDS_FREE or _REDDENED, bands > 1) */
    int red;                            /* light path: the reddened band model */
    double red_f[GS_MAX_BANDS];         /* its f_b - 1 (optical depth per band relative to 550 nm) */
    double *red_c;                      /* [nb * REC_TAU_N * bands] Q_b exp(-tau_i f_b) on the
                                         * tau grid (red only) */
    double *red_cmin;                   /* [nb * bands] its least value over the grid */
    double fe_pix;                      /* pixels: the relative excess noise (model_error or 0) */
    int nfit;                           /* brightness parameters: bands (bg) or 1 */
    int bandpath;                       /* pixels: per-band scores (bands > 1, bg or model error) */
    double *bnorm;                      /* [M * bands] |t_j| over band b's K values */
    double *lbnorm;                     /* [M * bands] its log */
    double *blog;                       /* [M] sum over bands of log |t_jb| */
    double *tbn;                        /* [M * D] templates, each band of unit norm (bandpath only) */
    float *tbnf;                        /* [Mp * D] the same in float, zero padded (bandpath only) */
    float *blnf;                        /* [Mp] blog as float, 1e30 for padding */
    float *bib, *bib2;                  /* [bands * Mp] 1/|t_jb|, 1/|t_jb|^2 (padding 0, 1) */
    double logphi_tab[2 * (int)LOGPHI_ZMAX * LOGPHI_STEPS + 2];
};

/* Phi(z) */
static inline double phi_cdf(double z)
{
    return 0.5 * erfc(-z * M_SQRT1_2);
}


/* exp(d) for d <= 0, without calling exp where it underflows to 0 (below -745.2). */
static inline double rec_exp_neg(double d)
{
    return d > -746.0 ? exp(d) : 0.0;
}

/* log(exp(a) + exp(b)), -inf aware. */
static inline double rec_log_add(double a, double b)
{
    if (a < b) {
        double t = a;
        a = b;
        b = t;
    }
    return isinf(a) && a < 0.0 ? a : a + log1p(rec_exp_neg(b - a));
}

/* The reddened band model's grid of optical depths at 550 nm (eq7_scores.c). */
#define REC_TAU_N 24
#define REC_TAU_LO -0.3
#define REC_TAU_HI 3.0
static inline double rec_eq7_tau(int i)
{
    return REC_TAU_LO + (REC_TAU_HI - REC_TAU_LO) * i / (REC_TAU_N - 1);
}

/* Circular distance of two shifts, cycles, in [0, 0.5]. */
/* (fmod only outside [0, 1), where it is not the identity: the same values, without its cost
 * in the decision's loops over candidates) */
static inline double circ_dist(double a, double b)
{
    double d = fabs(a - b);
    if (!(d < 1.0)) d = fmod(d, 1.0);
    return d > 0.5 ? 1.0 - d : d;
}

/* fmod(x, 1.0) of a finite x, exactly (x - trunc(x) is representable; the sign of x, as fmod's,
 * for a zero result), without fmod's cost: the phase factors' arguments in the continuous
 * templates and series. */
static inline double frac1(double x)
{
    return copysign(x - trunc(x), x);
}

static inline double wrap01(double s)
{
    if (s >= 0.0 && s < 1.0) return s;
    s = fmod(s, 1.0);
    if (s < 0.0) s += 1.0;
    return s >= 1.0 ? 0.0 : s;
}


/* One light's preparation (rec_eq7_light_prepare), kept until its answer. */
typedef struct {
    int used;               /* usable samples */
    unsigned flags;         /* REC_MATCH_BAD_INPUT so far */
    double c;               /* the unit of the weights: the largest usable sigma */
    double Sxx;             /* sum w x^2 */
    double mu2[GS_MAX_BANDS];   /* the band levels of the excess noise, units of c */
    double wmin[GS_MAX_BANDS];  /* the smallest weight of each brightness's samples (0: none) */
    int full[GS_MAX_BANDS];     /* every sample of the brightness has a weight (none dropped) */
    double flat[GS_MAX_BANDS];  /* the flat part subtracted from each band's samples, units of c */
} rec_eq7_prep;

/* A continuous bulb's brightness f against a light (eq7_bulbscreen.c): the constant terms of its
 * sums S and T (signed), their tails' magnitudes, the sums of their magnitudes (constant,
 * harmonics, tails), S <= sb and T >= tb at every cell (tb <= 0: no bound), and tw = w_min
 * min |t|^2 (0 when a sample is dropped), part of tb */
typedef struct {
    double cs, ct, tail_s, tail_t, es, et, sb, tb, tw;
} rec_eq7_bulb_terms;

/* Scratch for one light or pixel, or a block of lights (rec_eq7_work_alloc_rows). */
typedef struct {
    double *L;              /* [M] log likelihood (valid for candidates) */
    double *mass;           /* [M] posterior mass relative to the best */
    size_t *cand;           /* [M + 3 nb] candidate templates */
    size_t ncand;
    unsigned char *mark;    /* [M] in cand */
    double *bmass;          /* [nb] */
    double *wmass;          /* [nb] mass within +-1/6 cycle of the bulb's peak (continuous) */
    unsigned char *has_peak;/* [nb] */
    double *peak_s, *peak_L, *peak_sig;   /* [nb] refined peak: shift, log lik, std (cycles) */
    double *peak_z;                        /* [nb] brightness / its std at the peak */
    double *peak_gain;                     /* [nb] Sxx - chi2 at the peak */
    size_t *peak_cell;      /* [nb] template of the best grid cell */
    /* light path: the current light's rows of the block below (rec_eq7_work_row) */
    double *S, *T, *w, *wx, *xs;           /* [nfit * M] ([f * M + j]), [nfit * M], [D] x 3 */
    size_t rows;                           /* lights of the block */
    double *w_all, *wx_all, *xs_all;       /* [rows * D] */
    double *S_all, *T_all;                 /* [rows * nfit * M] */
    /* the float sums (m->fsums): the block's weights and weighted samples, each row scaled by a
     * power of two (fsw, fsx: its largest in [1/2, 1)), their sums and the scaled |wx| per row;
     * the current light's and which of its double sums are taken (have [M]) */
    float *wf_all, *wxf_all;               /* [rows * D] */
    float *Sf_all, *Tf_all;                /* [rows * M] */
    double *fsw_all, *fsx_all, *wxn_all;   /* [rows] */
    const float *Sf, *Tf;
    double fsw, fsx, wxn;
    unsigned char *have;                   /* [M] */
    rec_eq7_prep *prep;                    /* [rows] */
    double *U;                             /* [M] the screen's bounds of L (eq7_scores.c) */
    unsigned char *done;                   /* [M] L exact (1) or screened out (0, L = -inf) */
    unsigned char *tight;                  /* [M] its bound made tight (the reddened model) */
    double *tmp;                           /* [2 (M + 3 nb)] the decision's and blend search's scratch */
    double *tt, *dt;                       /* [D] */
    double *r2, *s2, *m2;                  /* [D] the excess noise's residuals, variances, levels */
    double *tr;                            /* [D] the runner-up's template */
    double *t12;                           /* [nfit * REC_NESTED_FIRST * M] cross sums of the first
                                            * templates and every template ([f][r][j], eq7_nested.c) */
    double *scratch;                       /* [(6 bands + 1) D] the nested tests' */
    double complex *acc;                   /* [REC_TEMPLATE_ACC K] */
    double *rs;                            /* [rec_eq7_series_work_size] the series' (eq7_series.c) */
    double complex *spec;                  /* [(G/2 + 1) (1 + 2 bands)] a cross-spectrum and the
                                            * light's band DFTs over the grid's bins
                                            * (rec_eq7_grid_sums) */
    double *grid;                          /* [G] its inverse */
    /* the light path's screen of continuous bulbs (m->bs_on): each bulb's bound, whether its
     * grids are computed (open), the bulbs by bound (border[0], then those within the cut, or
     * the runner-up: rec_eq7_screen); the light's harmonics (eq7_bulbscreen.c) */
    double *bub;                           /* [nb] */
    unsigned char *open;                   /* [nb] */
    size_t *border;                        /* [nb] */
    double *bs_y;                          /* [4 bands rec_eq7_harmonics_np + 2 D] */
    rec_eq7_bulb_terms *bs_t;              /* [nb nfit] each bulb's terms */
    double *bs_z;                          /* [nb nfit 4 rec_eq7_harmonics_np] its C_n, C'_n */
    double *bs_tmp;                        /* [nfit][S, T][nb] its tails' sums, then (once the
                                            * terms hold them) [nb][nfit] its log(tb_f) */
    double *bs_ug;                         /* [nb][1 + nfit] its bound's u and g_f */
    double complex *spec_v;                /* [(G/2 + 1) bands] the band DFTs of other values
                                            * (the nested tests' cross sums, rec_eq7_grid_dots) */
    /* the reddened model: the light's log prior per tau (has_tau_prior; else uniform) and, when
     * collect_tau, its log likelihood per tau with every bulb weighted alike (eq7_population.c) */
    int has_tau_prior, collect_tau;
    double tau_logprior[REC_TAU_N], tau_ll[REC_TAU_N];
    double chroma_tol;                     /* > 0: the band tolerance instead of the options' */
    int has_other_prior;                   /* other_prior instead of the options' */
    double other_prior, other_lbf;         /* and the last light's log Bayes factor (NaN: none) */
    int fit_bulb;                          /* the last light's answer: bulb (-1 none), its */
    double fit_S[GS_MAX_BANDS], fit_T[GS_MAX_BANDS], fit_z;   /* band sums and a / sigma_a */
    double flat;                           /* the flat share phi subtracted (rec_eq7_opts) */
    int want_flat;                         /* estimate the light's own flat share (fit_flat) */
    double fit_flat, fit_flat_var;         /* the last light's own estimate of the flat share
                                            * left after that, with the answer's template, and
                                            * its variance (inf: none) */
} rec_eq7_work;

/* eq7_population.c: the population prior on tau for each of n lights (logprior, n x REC_TAU_N)
 * from their tau log likelihoods (tau_ll, n x REC_TAU_N, as rec_eq7_work's) and which lights are
 * clean references; returns the references used, 0 (logprior untouched) below 8. */
/* eq7_scores.c: the reddened model's band misfit sum_b v_b (a_b - a c_b)^2 of bulb's band sums
 * at the best tau (uniform prior) with band tolerance tol: ~ chi2 with bands - 2 dof when tol is
 * the lamps' true spread. */
double rec_eq7_band_misfit(const rec_matcher *m, int bulb, const double *S, const double *T, double tol);
/* eq7_population.c: the capture's band tolerance from n lights' answers (bulb[i] >= 0, band sums
 * S, T [i * GS_MAX_BANDS + b], a/sigma_a z[i], is_ref): the tolerance at which the median band
 * misfit of the bright references is chi2's median; 0 when fewer than 8 bright references. */
double rec_eq7_chroma_tolerance(const rec_matcher *m, size_t n, const int *bulb, const double *S,
                                const double *T, const double *z, const unsigned char *is_ref);
/* eq7_population.c: the share of bulbs not in DELIGHT from the references' log Bayes factors
 * (rec_eq7_nested.lbf_other; NaN entries skipped), *used the lights it came from; NaN below 8. */
double rec_eq7_other_share(const double *lbf, const unsigned char *is_ref, size_t n, size_t *used);
/* eq7_population.c: the capture's flat share *share from n lights' own estimates phi[i]
 * (variance var[i], inf: none) over the references is_ref: their weighted median when
 * significant, else 0; NaN with fewer than 8 references with an estimate. *spread the std of the
 * lights' true shares about it (beyond their estimates' noise; 0 when *share is 0), *used the
 * references with an estimate. */
#define REC_FLAT_MAX 0.45   /* the largest flat share (rec_eq7_opts.flat_share below 0.5) */
gs_status rec_eq7_flat_share(const double *phi, const double *var, const unsigned char *is_ref,
                             size_t n, double *share, double *spread, size_t *used);
size_t rec_eq7_tau_prior(const double *tau_ll, const unsigned char *is_ref, const double *y_px,
                         size_t n, int height, double *logprior);

typedef struct {
    int bulb;               /* -1: nothing finite */
    size_t tmpl;            /* the fitted template (continuous: best grid cell) */
    double shift;           /* cycles */
    double conf, bulb_conf, phase_conf;
    int runner_bulb;
    double runner_shift, runner_conf;
    size_t runner_tmpl;
} rec_eq7_decision;

/* eq7_pixels.c: zz[j] = x . t_j / (|t_j| sigma) in double (inv = 1 / sigma, xd the row) for the
 * n candidates cand (rising order), the pixel path's exact rescoring: with grids, a run of at
 * least 32 cells of a continuous bulb from its grid's dots (m->fourier: the row's band DFTs once
 * into w->spec_v, then one G-point inverse FFT per bulb into gd [G], exact but for rounding,
 * ~1e-15 of |x| / sigma), the others four at a time (gs_dot_rows). */
void rec_eq7_exact_z(const rec_matcher *m, rec_eq7_work *w, double *gd, const double *xd, double inv,
                     const size_t *cand, size_t n, int grids, double *zz);

/* eq7_pixscreen.c: the pixel path's Fourier screen for continuous bulbs (rec_matcher.fs_on). */
enum { REC_FS_OFF = 0, REC_FS_ON = 1, REC_FS_ALL = 2 };
/* Per row of a block: */
typedef struct {
    double umax;            /* the largest float bound U of the scores so far (-inf: none) */
    double nmax;            /* the largest U of a score <= eps so far */
    double err;             /* pixel_row's error of z^2/2 from float scores */
    float smax, hf;         /* the largest score so far; 1 / (2 sigma^2) */
    float eps;              /* a bound on a float score's rounding error */
} rec_pixscreen_row;
typedef struct {
    double *bound;          /* [B * nb] bounds of the bulbs' normalised scores */
    unsigned char *state;   /* [B * nb] none, wanted, scored */
    rec_pixscreen_row *row; /* [B] */
    double *xd;             /* [D] one row in double */
    double *y;              /* [bands * 2K] its DFT ((re, im) pairs) */
    double *yx;             /* [bands * 2 np] one row's, at the kept harmonics */
    double *xa;             /* [bands * K] its magnitudes */
    double *tail;           /* [nb] each bulb's tail sum with them */
    float *xg, *og;         /* [(B + 3) * D] gathered rows, [(B + 3) * max count] their scores */
    size_t *idx;            /* [B] their rows */
} rec_pixscreen_work;
/* eq7_bulbscreen.c: bounds of a continuous bulb's grid sums from its cross-spectrum's magnitudes.
 * rec_eq7_harmonic_table: bulb b's f_n hat_n * scale, n <= K/2, into a ([bands][re, im np]), the
 * rest's magnitudes added into tail ([bands][K], by n mod K); rec_eq7_harmonic_row: a row's band
 * DFTs V (ld ldv) at those harmonics into y, their magnitudes |V_band,q| into ya.
 * rec_eq7_bulbscreen_setup (rec_matcher_new) and
 * rec_eq7_bulb_bounds: every continuous bulb's bound on the L of its cells into U ([nb]), after
 * rec_eq7_light_dfts. */
size_t rec_eq7_harmonics_np(const rec_matcher *m);
void rec_eq7_harmonic_table(const rec_matcher *m, const double complex *hat, size_t b, double scale, double *a,
                            double *tail);
void rec_eq7_harmonic_row(const rec_matcher *m, const double complex *V, size_t ldv, double *y, double *ya);
/* sum_n |sum_band a_n y_n| over np harmonics plus tail_sum, the tail's sum_band tail_q |y_q|
 * (gs_dot of the bulb's tail and the row's ya, [bands][K]; gs_dot_rows for every bulb at once):
 * the sum of a trigonometric sum's magnitudes; its constant term (real) into *c0, the complex
 * sums into z (re, im blocks of np) unless NULL */
double rec_eq7_harmonic_extent(const double *a, const double *y, int bands, size_t np, double tail_sum, double *c0,
                               double *z);
gs_status rec_eq7_bulbscreen_setup(rec_matcher *m);
void rec_eq7_bulb_bounds(const rec_matcher *m, rec_eq7_work *w, const rec_eq7_prep *p, double Sxx, double *U);
/* Bulb b's coupled bound (after rec_eq7_bulb_bounds, at most its bound w->bub[b]): refined until
 * it is below th or cannot get there (th = -inf: as tight as it gets; +inf: the first chord of
 * each brightness). rec_eq7_coupled_gain: one brightness's bound on S^2/T over the cells from its
 * terms and cross-spectra z (C then C', re and im blocks of np each), refined until below stop or
 * it cannot get there (stop NaN: as tight as it gets: within 1e-6 of the bound function's largest
 * value found, or 48 intervals). */
double rec_eq7_bulb_tighten(const rec_matcher *m, rec_eq7_work *w, const rec_eq7_prep *p, double Sxx, size_t b,
                            double th);
double rec_eq7_coupled_gain(const double *z, size_t np, const rec_eq7_bulb_terms *t, double stop);
/* Tables (rec_matcher_new; fs_on when m->fourier, every bulb continuous, not m->bandpath). */
gs_status rec_eq7_pixscreen_setup(rec_matcher *m);
gs_status rec_eq7_pixscreen_alloc(const rec_matcher *m, size_t B, rec_pixscreen_work *sw);
void rec_eq7_pixscreen_free(rec_pixscreen_work *sw);
/* The float scores sc[k * Mp + j] of the ns rows xs (rows[k]: their index into noise_sigma)
 * for every template that can matter; keep[k] = 0 for a row pixel_row would answer nothing
 * (dim, or not finite). A row's other scores are 0 where rec_eq7_pixscreen_ranges' ranges
 * reach them, else undefined. */
void rec_eq7_pixscreen(const rec_matcher *m, rec_pixscreen_work *sw, const float *xs, size_t ns,
                       const float *noise_sigma, const size_t *rows, float *sc, unsigned char *keep);
/* Row k's ranges of templates pixel_row reads, as pairs [lo, hi) in rising order: the scored
 * bulbs' templates widened to multiples of LANES (within Mp), adjacent ones merged. Returns
 * their number (at most nb). */
size_t rec_eq7_pixscreen_ranges(const rec_matcher *m, const rec_pixscreen_work *sw, size_t k, size_t *range);

/* eq7_matcher.c: the window means of continuous bulb b at shift s (and their first two
 * derivatives when dt, d2t are not NULL; acc is scratch of REC_TEMPLATE_ACC K). */
#define REC_TEMPLATE_ACC (3 * GS_MAX_BANDS + 3)
void rec_eq7_template_at(const rec_matcher *m, size_t b, double s, double *t, double *dt,
                         double *d2t, double complex *acc);
/* log Phi(z) from the matcher's table (error < 4e-5), for the pixel path (inline: it takes it
 * for every candidate of a row, all 10,400 grid cells for a dim row with continuous phases). */
static inline double rec_eq7_log_phi_fast(const rec_matcher *m, double z)
{
    if (z >= LOGPHI_ZMAX) return 0.0;
    if (z <= -LOGPHI_ZMAX) return gs_log_phi(z);
    double u = (z + LOGPHI_ZMAX) * LOGPHI_STEPS;
    int i = (int)u;
    double f = u - i;
    return m->logphi_tab[i] + f * (m->logphi_tab[i + 1] - m->logphi_tab[i]);
}
/* eq7_series.c: continuous bulb b's sums S_f, T_f per brightness f and their first two
 * derivatives at any shift s from Fourier series (the tables of rec_eq7_series_setup; freed by
 * rec_eq7_series_free): rec_eq7_series_row takes the K-point DFTs of the row's w->wx and w->w
 * (once per row), rec_eq7_series_bulb bulb b's products with them, into w->rs; then
 * rec_eq7_series_at evaluates any s. */
gs_status rec_eq7_series_setup(rec_matcher *m);
void rec_eq7_series_free(rec_matcher *m);
size_t rec_eq7_series_work_size(const rec_matcher *m);
void rec_eq7_series_row(const rec_matcher *m, rec_eq7_work *w, int have_dfts);
void rec_eq7_series_bulb(const rec_matcher *m, rec_eq7_work *w, size_t b);
void rec_eq7_series_at(const rec_matcher *m, rec_eq7_work *w, size_t b, double s, double *S, double *S1,
                       double *S2, double *T, double *T1, double *T2);
/* eq7_sums.c: the sums S, T (rec_eq7_work [f * M + j]) of continuous bulb b's grid from the
 * Fourier form (m->fourier): one G-point inverse FFT per sum, after rec_eq7_light_dfts has
 * taken the DFTs of the light's w->wx and w->w. */
void rec_eq7_light_dfts(const rec_matcher *m, rec_eq7_work *w);
void rec_eq7_grid_sums(const rec_matcher *m, rec_eq7_work *w, size_t b);
/* The same for any D values v: their band DFTs (X: bands * (G/2 + 1), e.g. w->spec_v), then
 * sum_d v_d t_j[d] of brightness f over bulb b's grid into dst (G values). */
void rec_eq7_band_dfts(const rec_matcher *m, const double *v, double complex *X);
/* The K-point DFT of v, x[q] = sum_k v_k e^{-2 pi i q k / K} as (re, im) pairs, q < K, from the
 * tables c, s (m->dftc, dfts: [k K + q]); the sums over k in order, every q at once. */
void rec_eq7_dft(const double *v, const double *c, const double *s, size_t K, double *x);
/* z[r] = sum_q a_q[r] x_q[r] over nq arrays (a_q at a + q ld, x_q at x + q ld, in doubles),
 * complex ((re, im) pairs), r < n, added from 0 in the order of q (REC_CX4_MUL; the last group
 * of fewer than four from zero-padded copies): the grids' cross-spectra (nq bands) and the
 * continuous template's harmonic terms (nq = 1). */
void rec_eq7_cross_sum(const double *a, const double *x, size_t ld, int nq, size_t n, double *z);
void rec_eq7_grid_dots(const rec_matcher *m, rec_eq7_work *w, size_t b, int f, const double complex *X, double *dst);
/* eq7_decide.c: scratch for one light or pixel (rec_eq7_work_alloc), or a block of rows lights
 * (the light path's); rec_eq7_work_row points w, wx, xs, S and T at light q's rows; and the
 * posterior over (bulb, phase) from the candidates' scores. */
gs_status rec_eq7_work_alloc(const rec_matcher *m, rec_eq7_work *w);
gs_status rec_eq7_work_alloc_rows(const rec_matcher *m, rec_eq7_work *w, size_t rows);
void rec_eq7_work_row(const rec_matcher *m, rec_eq7_work *w, size_t q);
void rec_eq7_work_free(rec_eq7_work *w);
double rec_eq7_report_phase(const rec_matcher *m, int b, size_t j, double s);
void rec_eq7_add_cand(const rec_matcher *m, rec_eq7_work *w, size_t j);
void rec_eq7_add_done(const rec_matcher *m, rec_eq7_work *w);
void rec_eq7_mark_cands(rec_eq7_work *w, unsigned char v);
void rec_eq7_decide(const rec_matcher *m, rec_eq7_work *w, double Lmax, rec_eq7_decision *dec);
/* eq7_scores.c: the log likelihood of one scale; eq7_light.c: Newton refinement of continuous
 * bulb b's peak from grid cell j0 (after rec_eq7_series_row of the row's weights). */
double rec_eq7_loglik(double Sxx, double S, double T);
/* eq7_scores.c: the first index of the largest of U[0..n) (0 when every one is -inf; NaN
 * entries are passed over). */
size_t rec_eq7_argmax(const double *U, size_t n);
/* An answer without a bulb (every number 0, runner-up none, both ambiguous flags). */
void rec_eq7_no_answer(rec_match *out, unsigned flags);
void rec_eq7_refine_peak(const rec_matcher *m, rec_eq7_work *w, size_t b, size_t j0, double Sxx);
/* Excess noise of one light's fit (eq7_light.c, for the population estimate of eq7_noise.c):
 * e2 solves sum_d r_d^2 / (sigma_d^2 + e2 mu_b^2) = dof for the best fit's residuals r (0 when
 * the camera noise explains them); per band b its usable samples n_b, their mean camera variance
 * s2_b and the level mu2_b, from which the estimate's expected variance at any e2 follows
 * (2 dof / I^2, I = sum_b n_b mu2_b / (s2_b + e2 mu2_b)); valid 0 when the light has no fit. */
typedef struct {
    double e2;
    int dof, valid;
    double n_b[GS_MAX_BANDS], s2_b[GS_MAX_BANDS], mu2_b[GS_MAX_BANDS];
} rec_eq7_excess;
/* Eq. 7 for one light in three steps, so that a block of lights shares the sums' pass over the
 * templates: rec_eq7_light_prepare puts the light's weights in row q of w's block (1: to be
 * finished; 0: answered in out, no usable sample, w's fit outputs none);
 * rec_eq7_block_sums (eq7_sums.c) the sums of rows 0..n-1; rec_eq7_light_finish the scores, the decision and the answer of row q
 * (sigma the light's). rec_eq7_match_light_ws is the three for one light (row 0). */
int rec_eq7_light_prepare(const rec_matcher *m, rec_eq7_work *w, size_t q, const double *signal,
                          const double *sigma, double fe, rec_match *out);
void rec_eq7_block_sums(const rec_matcher *m, rec_eq7_work *w, size_t n);
gs_status rec_eq7_light_finish(const rec_matcher *m, rec_eq7_work *w, size_t q, const double *sigma,
                               double fe, rec_match *out, rec_eq7_excess *excess);
gs_status rec_eq7_match_light_ws(const rec_matcher *m, rec_eq7_work *w, const double *signal,
                                 const double *sigma, double fe, rec_match *out,
                                 rec_eq7_excess *excess);
/* eq7_sums.c: the transposed templates of the block sums (rec_matcher ttr, tsqtr), at build. */
gs_status rec_eq7_sums_setup(rec_matcher *m);
/* eq7_scores.c: every template's L where it can matter (docs/recognition.md, "The screen"):
 * rec_eq7_screen scores the current light (prepared as p; w->L, exact where w->done; -inf elsewhere) and returns
 * the largest L; rec_eq7_screen_widen makes every template within cut of Lmax exact (before the
 * scores are tempered by kappa < 1: cut / kappa). rec_eq7_loglik_fit is a template's exact L
 * under the matcher's band model (its tau terms into w->tau_ll when collecting). */
double rec_eq7_screen(const rec_matcher *m, rec_eq7_work *w, const rec_eq7_prep *p, double Sxx);
/* The light path's screen of bulbs is on (m->bs_on, not the exhaustive path): a bulb's grid sums,
 * bounds U and scores L exist only once the screen opened it (w->open); a bulb is active when
 * they exist. */
static inline int rec_eq7_bulb_screen(const rec_matcher *m)
{
    return m->bs_on && !m->exhaustive;
}
static inline int rec_eq7_bulb_active(const rec_matcher *m, const rec_eq7_work *w, size_t b)
{
    return !rec_eq7_bulb_screen(m) || w->open[b];
}
/* eq7_light.c: continuous bulb b's peak at its best grid cell jb, unrefined (a bulb too far below
 * the best to refine). */
void rec_eq7_grid_peak(const rec_matcher *m, rec_eq7_work *w, size_t b, size_t jb);
void rec_eq7_screen_widen(const rec_matcher *m, rec_eq7_work *w, const rec_eq7_prep *p, double Sxx, double Lmax,
                          double cut);
double rec_eq7_loglik_fit(const rec_matcher *m, rec_eq7_work *w, size_t j, double Sxx);
/* eq7_scores.c: the band models' log likelihoods from a template's sums S, T (nfit values):
 * free or one brightness (rec_eq7_loglik_n), reddened (rec_eq7_loglik_red: with fit, the most
 * probable tau's numbers; ll_acc accumulates exp(L(tau) + ll_logw) per tau). */
typedef struct {
    double chi2;                 /* R + sum v (a_b - a c_b)^2 at the best tau */
    double a, tau, z;            /* the brightness, optical depth and a / sigma_a there */
    double band[GS_MAX_BANDS];   /* each band's brightness: the posterior mean of a_b */
} rec_red_fit;
double rec_eq7_loglik_n(int nf, double Sxx, const double *S, const double *T);
/* ex[i] = exp(L[i] - Lmax) where that is above -746, else 0 (rec_exp_neg), for n values, through
 * the vector math. */
void rec_eq7_exp_below(const double *L, size_t n, double Lmax, double *ex);
double rec_eq7_loglik_red(const rec_matcher *m, const rec_eq7_work *w, int bulb, double Sxx,
                          const double *S, const double *T, rec_red_fit *fit, double *ll_acc,
                          double ll_logw);
/* The double sums S, T of the current light's templates idx[0..n) where not yet taken (the
 * float sums' path, m->fsums; no-op otherwise). */
void rec_eq7_exact_sums(const rec_matcher *m, rec_eq7_work *w, const size_t *idx, size_t n);
/* Whether the block's sums go in float first (m->fsums and not the tests' slow path). */
static inline int rec_eq7_float_sums(const rec_matcher *m)
{
    return m->fsums && !m->exhaustive;
}
/* The sums of template j from the current light's S, T ([f * M + j]). */
static inline void rec_eq7_sums_of(const rec_matcher *m, const rec_eq7_work *w, size_t j, double *S, double *T)
{
    for (int f = 0; f < m->nfit; f++) {
        S[f] = w->S[(size_t)f * m->M + j];
        T[f] = w->T[(size_t)f * m->M + j];
    }
}
/* eq7_nested.c: the nested-model tests of the best fit tb (bulb, template or M for an exact
 * continuous one, shift), on the work arrays of rec_eq7_match_light_ws; phi the chi2 variance
 * inflation of a correlated excess. */
#define REC_NESTED_MAX_D (GS_MAX_BANDS * 64)
/* Second templates are searched against the best fit and the next REC_NESTED_FIRST - 1
 * templates by score (every template of a small bank). */
#define REC_NESTED_FIRST 16
typedef struct {
    double p_shape;       /* + smooth harmonics 1..3 per band: chi2(2 H bands) test */
    double p_blend;       /* + a second template: Bonferroni over the templates searched */
    double chi2_null, chi2_shape, chi2_blend;
    int extra_shape, extra_blend, found;
    size_t tmpl[2];       /* the blend's two templates; (size_t)-1: the best fit itself */
    double share[2];      /* their shares of the brightness */
    double p_other;       /* posterior that the bulb is not in DELIGHT (eq7_nested.c) */
    double lbf_other;     /* its log Bayes factor against the best template (NaN: not tested) */
    double p_blend_post;  /* posterior of two lights (blend_prior) */
} rec_eq7_nested;
/* "Not in DELIGHT": a bulb whose waveform is the best template deformed by harmonics 1..3 per
 * band of relative amplitude ~ N(0, tau^2), tau one of REC_OTHER_TAUS (equally likely), of prior
 * probability other_prior. */
#define REC_OTHER_TAUS {0.01, 0.03, 0.1}
/* The deformation: harmonics 1..REC_SHAPE_H of the flicker cycle per band (a smooth change of
 * the waveform; the template's own mean keeps the columns independent). */
#define REC_SHAPE_H 3
void rec_eq7_nested_tests(const rec_matcher *m, rec_eq7_work *w, const double *tb, int best_bulb,
                          size_t best_tmpl, double best_shift, double phi, rec_eq7_nested *out);
/* ============================================================================ end of Eq. 7 */

#endif
