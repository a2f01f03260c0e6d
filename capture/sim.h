/* sim.h - the simulator's private state, shared by sim.c (construction, base stages, render
 * driver, truth), render.c (primitives), effects.c (one stage per effect, the effects table) and
 * effect_params.c (their scene parameters). Not included outside capture/ (tests may). */
#ifndef GRIDSURVEY_CAPTURE_SIM_H
#define GRIDSURVEY_CAPTURE_SIM_H

#include "capture/internal.h"

/* A (bulb, grid phase) pair: all lights of a species share their window integrals. */
typedef struct {
    int bulb;          /* index into cap_sim.bulbs */
    double shift;      /* BRF delay, cycles */
    double *i_k;       /* bands * K exact Eq. 5 window means (gs_brf_integrate) */
} cap_species;

/* The pixels a light deposits into: a rectangle clipped to the image, with weights. */
typedef struct {
    int x0, y0, w, h;  /* w = 0: nothing on the sensor */
    size_t off;        /* into cap_sim.fp_w */
} cap_footprint;

typedef struct cap_render cap_render;
typedef struct cap_stage cap_stage;
struct cap_stage {
    const char *name;
    int effect;        /* cap_effect or -1 */
    int noise;         /* shot noise and every stage after it: a probe runs them on its rows */
    gs_status (*run)(cap_sim *s, cap_render *r);   /* a whole-frame stage, or NULL and: */
    gs_range_fn rows;  /* a row stage (rows [y0, y1) of the image from the same rows; cap_par ctx) */
    unsigned long long calls, items;
    double seconds;
};

#define CAP_MAX_STAGES 32
#define CAP_MAX_LEVELS (GS_MAX_HALVINGS + 1)

/* Per-acquisition state. */
struct cap_render {
    int k, pass;
    long index, first_cycle;
    const unsigned char *halv;      /* NULL: all 0 */
    cap_window_config wcfg;         /* set by the timing stages */
    int timing;                     /* a timing stage ran: windows are computed */
    cap_windows win;
    double ex[CAP_MAX_LEVELS];      /* DC exposure per level, nominal cycles */
    long n_exposed[CAP_MAX_LEVELS]; /* cycles per level */
    unsigned char *lev;             /* [C] highest level exposed in cycle c (cap_cycle_level) */
    unsigned long long items;       /* set by the running stage: elements it processed */
    unsigned short *raw;            /* outputs (may be NULL) */
    double *dn;
    const unsigned char *rows;      /* a probe: the rows the noise stages render (NULL: all) */
    double probe_safe_e;            /* a probe: the largest mean that cannot saturate */
    int rows_keep;                  /* 1: the other rows' raw samples are left as they are (0: 0) */
};

struct cap_sim {
    cap_scene sc;                   /* deep copy */
    int W, H, B, K, M, L, hmax;
    long C;
    double half_s;                  /* nominal Delta */
    unsigned fx;                    /* enabled effects */
    int timing;                     /* any timing effect */
    int threads;                    /* cap_sim_set_threads (0: the online CPUs) */
    gs_bulb *bulbs;                /* copies of the DELIGHT entries used */
    size_t n_bulbs;
    cap_brf_table *tables;          /* per bulb, only with timing effects */
    cap_species *sp;
    size_t n_sp;
    /* lights */
    size_t n;                       /* scene lights */
    int *species;                   /* [n] */
    int *glow_sp;                   /* [n * 3] species of the 3 phases (skyglow mixed) */
    double *flux;                   /* [n * B] photo-electrons per cycle per band (Q_b flux) */
    double *trans;                  /* [n * B] extinction transmission (extinction stage) */
    double *scint_s2, *scint_rho;   /* [n] log-variance and cycle-to-cycle correlation */
    cap_footprint *fp;              /* [n] */
    double *fp_w;
    size_t fp_n;
    double *glow_k;                 /* skyglow kernel, (2R+1)^2 */
    int glow_r;
    cap_ac *ac;                     /* timeline (timing effects only) */
    /* pipeline */
    cap_stage stages[CAP_MAX_STAGES];
    size_t n_stages;
    unsigned long long fx_calls[CAP_FX_COUNT];
    double sat_dn, read_dn, adc_max;
    /* scratch */
    double *img;                    /* W * H * B, electrons then DN */
    double *E;                      /* [n * L * B] */
    double *Wsp;                    /* [n_sp * L * B] species sums (flux-per-cycle units) */
    double *wcyc;                   /* [n_sp * B * C] per-cycle window integrals (scintillation) */
    double *scin;                   /* [GS_MAX_THREADS * C], C per part */
    unsigned char *lev;             /* [C] cap_cycle_level of each cycle of an exposure */
    double *amb_row;                /* [H] ambient electrons per pixel and nominal cycle (ambient) */
    unsigned char *probe_rows;      /* [H] a probe's rows (cap_sim_render_hdr) */
    int probe_pending;              /* the last render was a probe, img holds its other rows' means */
    cap_render *probe_r;            /* its state (k, pass, halvings' copy in probe_halv) */
    unsigned char *probe_halv;      /* [W H] */
    struct cap_transport *tr;       /* light_transport / semi_reflection tables (effect_transport.c) */
};

/* Resolvability of the lights (truth_resolve.c, docs/formats.md): sigma_e = sqrt(psf sigma^2
 * + 1/12) px; lights closer than CAP_RESOLVE_SEPARATION sigma_e are close; a light is resolvable
 * when no close light has at least 1/CAP_RESOLVE_FLUX_RATIO of its received flux; close pairs
 * of comparable flux (that ratio either way) join blend groups of two or more lights.
 * resolvable[n] (0 for lights not in the image), group[n] (-1: none), *n_groups. */
#define CAP_RESOLVE_SEPARATION 2.0
#define CAP_RESOLVE_FLUX_RATIO 10.0
double cap_resolve_sigma_px(const cap_sim *s);
gs_status cap_resolve(const cap_sim *s, unsigned char *resolvable, int *group, int *n_groups);

/* Rendering primitives (render.c). */
/* A stage's parallel parts (cap_par_run): the sim, the acquisition, each part's items. */
typedef struct {
    cap_sim *s;
    cap_render *r;
    unsigned long long items[GS_MAX_THREADS];
} cap_par;
/* fn over [0, n) (rows, lights) on the sim's threads (gs_parallel_chunks with a cap_par as ctx:
 * fn adds to its part's items, once per chunk); r->items = the parts' items summed. The chunks
 * write disjoint outputs, so the frame is the same bits on any number of threads and any split
 * (tests/test_capture_sim.c). */
gs_status cap_par_run(cap_sim *s, cap_render *r, size_t n, gs_range_fn fn);
/* The n row stages stage[0 .. n) (consecutive in the pipeline) over the image's rows on the sim's
 * threads, together: every stage over a block of rows while it is in the cache, then the next
 * block. A row stage's rows depend only on the same rows, so the bits are those of the stages
 * run one after the other over the whole frame. Adds to each stage's calls, items and seconds
 * (the wall time, shared out in proportion to each stage's time on the threads). */
gs_status cap_rows_run(cap_sim *s, cap_render *r, cap_stage *stage, size_t n);
/* A row stage: rows [y0, y1) of every light's E through its footprint (point or PSF) into the
 * image; items: the pixels touched. */
gs_status cap_splat_rows(void *ctx, int part, size_t y0, size_t y1);
/* Timing of exposed cycle c in [0, C) of this acquisition: window [t0, t1) s. */
void cap_cycle_time(const cap_sim *s, const cap_render *r, long c, double *t0, double *t1);
/* Gaussian pixel-integrated weights of a point at (x, y) with sigma over a (2R+1)^2 box
 * centred on its nearest pixel; writes to w and returns the box's top-left corner. */
void cap_gauss_box(double x, double y, double sigma, int R, double *w, int *bx, int *by);

/* The effects (effects.c, effect_params.c): the one table the scene parser and the pipeline
 * read. parse reads the effect's object at path of the scene document into sc->fx; prepare
 * (NULL: none) runs once when a simulator is built; the per-acquisition stage is run (the whole
 * frame) or rows (a row stage: cap_stage). The pipeline counts each effect's stage calls in
 * s->fx_calls (once per acquisition it runs the stage in, a probe's completion included). */
typedef struct {
    const char *name;   /* in scene files: "shot_noise", ... */
    gs_status (*parse)(const gs_json *j, cap_scene *sc, json_t *o, const char *path);
    gs_status (*prepare)(cap_sim *s);
    gs_status (*run)(cap_sim *s, cap_render *r);
    gs_range_fn rows;
} cap_effect_def;
extern const cap_effect_def cap_effect_defs[CAP_FX_COUNT];

gs_status cap_fx_frequency_wander(cap_sim *s, cap_render *r);
gs_status cap_fx_free_running_drift(cap_sim *s, cap_render *r);
gs_status cap_fx_dmd_jitter(cap_sim *s, cap_render *r);
gs_status cap_fx_extinction(cap_sim *s, cap_render *r);
gs_status cap_fx_scintillation(cap_sim *s, cap_render *r);
gs_status cap_fx_blinking_sign(cap_sim *s, cap_render *r);
gs_status cap_fx_headlights(cap_sim *s, cap_render *r);
gs_status cap_fx_prepare_extinction(cap_sim *s);
gs_status cap_fx_prepare_scintillation(cap_sim *s);
gs_status cap_fx_prepare_psf(cap_sim *s);
gs_status cap_fx_prepare_skyglow(cap_sim *s);
/* Light transport and the window (effect_transport.c): prepare ray-casts the room once (each
 * light's transport image relative to its direct flux, the daylight and outdoor images). */
gs_status cap_fx_light_transport(cap_sim *s, cap_render *r);
gs_status cap_fx_semi_reflection(cap_sim *s, cap_render *r);
gs_status cap_fx_prepare_light_transport(cap_sim *s);
gs_status cap_fx_prepare_semi_reflection(cap_sim *s);
gs_status cap_fxp_light_transport(const gs_json *j, cap_scene *sc, json_t *o, const char *path);
gs_status cap_fxp_semi_reflection(const gs_json *j, cap_scene *sc, json_t *o, const char *path);
void cap_transport_free(cap_sim *s);
/* The truth of a transport scene: every light's tau Q (and the daylight's, the outdoor
 * scene's) as float TIFFs truth_tau_NN.tiff in dir, listed in the array *images (json). */
gs_status cap_transport_write_truth(const cap_sim *s, const char *dir, json_t **images);
/* Parameters (effect_params.c); cap_fxp_none: an effect without any ({} only). */
gs_status cap_fxp_none(const gs_json *j, cap_scene *sc, json_t *o, const char *path);
gs_status cap_fxp_free_running_drift(const gs_json *j, cap_scene *sc, json_t *o, const char *path);
gs_status cap_fxp_dmd_jitter(const gs_json *j, cap_scene *sc, json_t *o, const char *path);
gs_status cap_fxp_extinction(const gs_json *j, cap_scene *sc, json_t *o, const char *path);
gs_status cap_fxp_scintillation(const gs_json *j, cap_scene *sc, json_t *o, const char *path);
gs_status cap_fxp_psf(const gs_json *j, cap_scene *sc, json_t *o, const char *path);
gs_status cap_fxp_skyglow(const gs_json *j, cap_scene *sc, json_t *o, const char *path);
gs_status cap_fxp_blinking_sign(const gs_json *j, cap_scene *sc, json_t *o, const char *path);
gs_status cap_fxp_headlights(const gs_json *j, cap_scene *sc, json_t *o, const char *path);
gs_status cap_fxp_ambient(const gs_json *j, cap_scene *sc, json_t *o, const char *path);
gs_status cap_fxp_read_noise(const gs_json *j, cap_scene *sc, json_t *o, const char *path);
/* Intensity variance of scintillation of a point source at distance L (Andrews-Phillips,
 * spherical wave, with aperture averaging and source-size reduction): docs/capture.md. */
double cap_scintillation_index(const cap_effects *fx, double aperture_mm, double L_m);

#endif
