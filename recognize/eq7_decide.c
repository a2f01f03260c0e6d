/* eq7_decide.c - Eq. 7's decision: the posterior over (bulb, phase) pairs from the candidates'
 * scores (docs/recognition.md), shared by the light and the pixel paths. */
#include "recognize/internal.h"

#include <cblas.h>
#include <fftw3.h>
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* mass[j] = exp(L[j] - Lmax) cellw[j] of the candidates j (0 where L is not finite). */
static void masses(const rec_matcher *m, rec_eq7_work *w, double Lmax)
{
    double *L = w->tmp, *e = w->tmp + m->M + 3 * m->nb;   /* ncand <= M + 3 nb */
    for (size_t i = 0; i < w->ncand; i++) L[i] = w->L[w->cand[i]];
    rec_eq7_exp_below(L, w->ncand, Lmax, e);
    for (size_t i = 0; i < w->ncand; i++) w->mass[w->cand[i]] = e[i] * m->cellw[w->cand[i]];
}

void rec_eq7_work_free(rec_eq7_work *w)
{
    free(w->L);
    free(w->mass);
    free(w->cand);
    free(w->mark);
    free(w->bmass);
    free(w->wmass);
    free(w->has_peak);
    free(w->peak_s);
    free(w->peak_L);
    free(w->peak_sig);
    free(w->peak_z);
    free(w->peak_gain);
    free(w->peak_cell);
    free(w->S_all);
    free(w->T_all);
    free(w->wf_all);
    free(w->wxf_all);
    free(w->Sf_all);
    free(w->Tf_all);
    free(w->fsw_all);
    free(w->fsx_all);
    free(w->wxn_all);
    free(w->have);
    free(w->w_all);
    free(w->wx_all);
    free(w->xs_all);
    free(w->prep);
    free(w->U);
    free(w->done);
    free(w->tight);
    free(w->tmp);
    free(w->tt);
    free(w->dt);
    free(w->r2);
    free(w->s2);
    free(w->m2);
    free(w->tr);
    free(w->t12);
    free(w->scratch);
    free(w->acc);
    free(w->rs);
    fftw_free(w->spec);
    fftw_free(w->grid);
    free(w->spec_v);
    free(w->bub);
    free(w->open);
    free(w->border);
    free(w->bs_y);
    free(w->bs_t);
    free(w->bs_z);
    free(w->bs_tmp);
    free(w->bs_ug);
    memset(w, 0, sizeof *w);
}

void rec_eq7_work_row(const rec_matcher *m, rec_eq7_work *w, size_t q)
{
    size_t D = (size_t)m->D, SM = (size_t)m->nfit * m->M;
    w->w = w->w_all + q * D;
    w->wx = w->wx_all + q * D;
    w->xs = w->xs_all + q * D;
    w->S = w->S_all + q * SM;
    w->T = w->T_all + q * SM;
    if (m->fsums) {
        w->Sf = w->Sf_all + q * m->M;
        w->Tf = w->Tf_all + q * m->M;
        w->fsw = w->fsw_all[q];
        w->fsx = w->fsx_all[q];
        w->wxn = w->wxn_all[q];
    }
}

gs_status rec_eq7_work_alloc_rows(const rec_matcher *m, rec_eq7_work *w, size_t rows)
{
    memset(w, 0, sizeof *w);
    size_t M = m->M, nb = m->nb, D = (size_t)m->D;
    size_t nr = rows;
    w->rows = rows;
    w->L = malloc(sizeof *w->L * M);
    w->mass = malloc(sizeof *w->mass * M);
    w->cand = malloc(sizeof *w->cand * (M + 3 * nb));
    w->mark = calloc(M, 1);
    w->bmass = malloc(sizeof *w->bmass * nb);
    w->wmass = malloc(sizeof *w->wmass * nb);
    w->has_peak = calloc(nb, 1);
    w->peak_s = malloc(sizeof *w->peak_s * nb);
    w->peak_L = malloc(sizeof *w->peak_L * nb);
    w->peak_sig = malloc(sizeof *w->peak_sig * nb);
    w->peak_z = malloc(sizeof *w->peak_z * nb);
    w->peak_gain = malloc(sizeof *w->peak_gain * nb);
    w->peak_cell = malloc(sizeof *w->peak_cell * nb);
    w->S_all = calloc(nr * M * (size_t)m->nfit, sizeof *w->S_all);
    w->T_all = calloc(nr * M * (size_t)m->nfit, sizeof *w->T_all);
    w->w_all = calloc(nr * D, sizeof *w->w_all);
    w->wx_all = calloc(nr * D, sizeof *w->wx_all);
    w->xs_all = calloc(nr * D, sizeof *w->xs_all);
    w->prep = calloc(nr, sizeof *w->prep);
    int fs = m->fsums;   /* (NULL and free() alike without the float sums) */
    w->wf_all = fs ? calloc(nr * D, sizeof *w->wf_all) : NULL;
    w->wxf_all = fs ? calloc(nr * D, sizeof *w->wxf_all) : NULL;
    w->Sf_all = fs ? calloc(nr * M, sizeof *w->Sf_all) : NULL;
    w->Tf_all = fs ? calloc(nr * M, sizeof *w->Tf_all) : NULL;
    w->fsw_all = fs ? calloc(nr, sizeof *w->fsw_all) : NULL;
    w->fsx_all = fs ? calloc(nr, sizeof *w->fsx_all) : NULL;
    w->wxn_all = fs ? calloc(nr, sizeof *w->wxn_all) : NULL;
    w->have = fs ? calloc(M, 1) : NULL;
    int part_bad = fs && (!w->wf_all || !w->wxf_all || !w->Sf_all || !w->Tf_all || !w->fsw_all || !w->fsx_all || !w->wxn_all || !w->have);
    w->U = malloc(sizeof *w->U * M);
    w->done = calloc(M, 1);
    w->tight = calloc(M, 1);
    w->tmp = malloc(sizeof *w->tmp * 2 * (M + 3 * nb));
    w->tt = malloc(sizeof *w->tt * D);
    w->dt = malloc(sizeof *w->dt * D);
    w->r2 = malloc(sizeof *w->r2 * D);
    w->s2 = malloc(sizeof *w->s2 * D);
    w->m2 = malloc(sizeof *w->m2 * D);
    w->tr = malloc(sizeof *w->tr * D);
    w->t12 = malloc(sizeof *w->t12 * M * (size_t)m->nfit * REC_NESTED_FIRST);
    w->scratch = malloc(sizeof *w->scratch * (size_t)(2 * 3 * GS_MAX_BANDS + 1) * D);
    w->acc = malloc(sizeof *w->acc * REC_TEMPLATE_ACC * (size_t)m->K);
    size_t nrs = rec_eq7_series_work_size(m);
    w->rs = nrs ? malloc(sizeof *w->rs * nrs) : NULL;
    /* (FFTW's alignment, as the arrays m->c2r was planned on: its SIMD codelets) */
    w->spec = fftw_malloc(sizeof *w->spec * ((size_t)m->G / 2 + 1) * (size_t)(1 + 2 * m->bands));
    w->grid = fftw_malloc(sizeof *w->grid * (size_t)m->G);
    w->spec_v = malloc(sizeof *w->spec_v * ((size_t)m->G / 2 + 1) * (size_t)m->bands);
    int bs = m->bs_on;   /* (NULL and free() alike without the screen of bulbs) */
    w->bub = bs ? malloc(sizeof *w->bub * nb) : NULL;
    w->open = bs ? calloc(nb, 1) : NULL;
    w->border = bs ? malloc(sizeof *w->border * nb) : NULL;
    w->bs_y = bs ? malloc(sizeof *w->bs_y * (4 * (size_t)m->bands * rec_eq7_harmonics_np(m) + 2 * D)) : NULL;
    w->bs_z = bs ? malloc(sizeof *w->bs_z * nb * (size_t)m->nfit * 4 * rec_eq7_harmonics_np(m)) : NULL;
    w->bs_t = bs ? malloc(sizeof *w->bs_t * nb * (size_t)m->nfit) : NULL;
    w->bs_tmp = bs ? malloc(sizeof *w->bs_tmp * 2 * nb * (size_t)m->nfit) : NULL;
    w->bs_ug = bs ? malloc(sizeof *w->bs_ug * nb * (1 + (size_t)m->nfit)) : NULL;
    part_bad = part_bad || (bs && (!w->bub || !w->open || !w->border || !w->bs_y || !w->bs_t || !w->bs_z || !w->bs_tmp || !w->bs_ug));
    if (!w->L || !w->mass || !w->cand || !w->mark || !w->bmass || !w->wmass || !w->has_peak ||
        !w->peak_s || !w->peak_L || !w->peak_sig || !w->peak_z || !w->peak_gain || !w->peak_cell || !w->S_all ||
        !w->T_all || !w->w_all || !w->wx_all || !w->xs_all || !w->prep || !w->U || !w->done || !w->tight || !w->tmp || !w->tt || !w->dt ||
        !w->r2 || !w->s2 || !w->m2 || !w->tr || !w->t12 || !w->scratch || !w->acc || (nrs && !w->rs) || !w->spec || !w->grid || !w->spec_v ||
        part_bad) {
        rec_eq7_work_free(w);
        return gs_fail(GS_ENOMEM, "Eq. 7: cannot allocate scratch for %zu templates", M);
    }
    rec_eq7_work_row(m, w, 0);
    return GS_OK;
}

gs_status rec_eq7_work_alloc(const rec_matcher *m, rec_eq7_work *w)
{
    return rec_eq7_work_alloc_rows(m, w, 1);
}


/* The phase (deg) to report for bulb b at shift s via template j. */
double rec_eq7_report_phase(const rec_matcher *m, int b, size_t j, double s)
{
    if (m->bulbs[b].ref == GS_REF_NONE) return 0.0;
    if (!m->cont[b]) return m->tphase[j];
    return gs_shift_to_phase(s);
}

void rec_eq7_add_cand(const rec_matcher *m, rec_eq7_work *w, size_t j)
{
    (void)m;
    if (!w->mark[j]) {
        w->mark[j] = 1;
        w->cand[w->ncand++] = j;
    }
}

/* mark[j] = v for every candidate j (the count and list in locals: a byte store may alias them). */
void rec_eq7_mark_cands(rec_eq7_work *w, unsigned char v)
{
    unsigned char *mark = w->mark;
    const size_t *cand = w->cand, n = w->ncand;
    for (size_t i = 0; i < n; i++) mark[cand[i]] = v;
}

/* rec_eq7_add_cand of every done template in [j, j1), in order: 8 flags at a time. */
static void add_done_range(const rec_matcher *m, rec_eq7_work *w, size_t j, size_t j1)
{
    for (; j + 8 <= j1; j += 8) {
        uint64_t any;
        memcpy(&any, w->done + j, sizeof any);
        for (size_t i = j; any && i < j + 8; i++)
            if (w->done[i]) rec_eq7_add_cand(m, w, i);
    }
    for (; j < j1; j++)
        if (w->done[j]) rec_eq7_add_cand(m, w, j);
}

/* Every template the screen made exact (w->done), in order. */
void rec_eq7_add_done(const rec_matcher *m, rec_eq7_work *w)
{
    if (!rec_eq7_bulb_screen(m)) {
        add_done_range(m, w, 0, m->M);
        return;
    }
    for (size_t b = 0; b < m->nb; b++)   /* the screen of bulbs scores only open bulbs' cells */
        if (w->open[b]) add_done_range(m, w, m->first[b], m->first[b] + m->count[b]);
}

/* A pair candidate for the best / runner-up: log of its mass relative to exp(Lmax). */
typedef struct {
    double lm;
    int bulb;
    size_t tmpl;
    double shift;
} pair_c;

static void consider(pair_c *best, pair_c *second, double lm, int bulb, size_t tmpl, double shift)
{
    if (!(lm > -INFINITY)) return;
    pair_c c = {lm, bulb, tmpl, shift};
    if (best->bulb < 0 || lm > best->lm) {
        *second = *best;
        *best = c;
    } else if (second->bulb < 0 || lm > second->lm) {
        *second = c;
    }
}

/* log of a summed mass, or the fallback when it underflowed (used for ranking only) */
static double log_mass(double mass, double fallback)
{
    return mass > 0.0 ? log(mass) : fallback;
}

/* Posterior over (bulb, phase) from w->L of the candidates (w->cand) and the refined peaks of
 * continuous bulbs. Lmax is the largest log likelihood (grid or peak). Pairs are ranked by
 * their log mass, so a runner-up exists even when its posterior underflows. */
void rec_eq7_decide(const rec_matcher *m, rec_eq7_work *w, double Lmax, rec_eq7_decision *dec)
{
    size_t nb = m->nb;
    double cell = 1.0 / m->G;
    dec->bulb = -1;
    dec->runner_bulb = -1;
    dec->conf = dec->bulb_conf = dec->phase_conf = dec->runner_conf = 0.0;
    dec->tmpl = dec->runner_tmpl = 0;
    dec->shift = dec->runner_shift = 0.0;
    if (!isfinite(Lmax)) goto done;
    masses(m, w, Lmax);
    /* Laplace correction of the cells around narrow peaks (narrower than a cell) */
    for (size_t b = 0; m->ncont && b < nb; b++) {
        if (!m->cont[b] || !w->has_peak[b] || !(w->peak_sig[b] < cell)) continue;
        size_t c0 = (size_t)m->tcell[w->peak_cell[b]];
        double d0 = w->peak_s[b] - (double)c0 / m->G;   /* peak relative to the cell centre */
        d0 -= floor(d0 + 0.5);
        double amp = exp(w->peak_L[b] - Lmax) * sqrt(2.0 * M_PI) * w->peak_sig[b];
        for (int dc = -1; dc <= 1; dc++) {
            size_t c = (c0 + (size_t)m->G + (size_t)(long)dc) % (size_t)m->G;
            size_t j = m->first[b] + c;
            double lo = (dc - 0.5) * cell - d0, hi = (dc + 0.5) * cell - d0;
            if (!w->mark[j]) {
                rec_eq7_add_cand(m, w, j);
                w->L[j] = -INFINITY;
            }
            w->mass[j] = amp * (phi_cdf(hi / w->peak_sig[b]) - phi_cdf(lo / w->peak_sig[b]));
        }
    }
    memset(w->bmass, 0, sizeof *w->bmass * nb);   /* (a bulb may have no candidate) */
    memset(w->wmass, 0, sizeof *w->wmass * nb);
    double Z = 0.0;
    for (size_t i = 0; i < w->ncand;) {   /* by runs of one bulb's candidates */
        int b = m->tbulb[w->cand[i]], win = m->cont[b] && w->has_peak[b];
        double ps = win ? w->peak_s[b] : 0.0, bm = w->bmass[b], wm = w->wmass[b];
        for (; i < w->ncand && m->tbulb[w->cand[i]] == b; i++) {
            double mj = w->mass[w->cand[i]];
            Z += mj;
            bm += mj;
            if (win) wm += circ_dist(m->shift[w->cand[i]], ps) <= PHASE_WINDOW ? mj : 0.0;   /* (a select) */
        }
        w->bmass[b] = bm;
        w->wmass[b] = wm;
    }
    if (!(Z > 0.0) || !isfinite(Z)) goto done;
    /* pairs: discrete (bulb, phase) templates; continuous voltage bulbs (bulb, +-30 deg around
     * the peak); shape-only bulbs as a whole */
    pair_c best = {-INFINITY, -1, 0, 0.0}, second = {-INFINITY, -1, 0, 0.0};
    for (size_t i = 0; i < w->ncand && (size_t)m->ncont < nb; i++) {
        size_t j = w->cand[i];
        int b = m->tbulb[j];
        if (m->cont[b]) continue;
        consider(&best, &second, w->L[j] - Lmax + m->logcellw[j], b, j, m->shift[j]);
    }
    for (size_t b = 0; m->ncont && b < nb; b++) {
        if (!m->cont[b] || !w->has_peak[b]) continue;
        double pm = m->bulbs[b].ref == GS_REF_NONE ? w->bmass[b] : w->wmass[b];
        double sg = w->peak_sig[b] < cell ? w->peak_sig[b] * sqrt(2.0 * M_PI) : cell;
        consider(&best, &second, log_mass(pm, w->peak_L[b] - Lmax + log(sg)), (int)b,
                 w->peak_cell[b], w->peak_s[b]);
    }
    if (best.bulb < 0) goto done;
    int bb = best.bulb;
    /* one pass over the candidates (by runs of one bulb's): the phase confidence's mass (the
     * voltage-referenced bulbs' within the winner's window, or at its cell), and a continuous
     * voltage winner's mass outside its window, a runner-up candidate; the window: whether each
     * grid cell (shift c/G, as the matcher's) lies within it, once (w->tmp: free after masses) */
    int volt = m->bulbs[bb].ref != GS_REF_NONE;
    unsigned char *inw = (unsigned char *)w->tmp;
    if (volt && m->cont[bb])
        for (int c = 0; c < m->G; c++) inw[c] = circ_dist((double)c / m->G, best.shift) <= PHASE_WINDOW;
    double pc = 0.0, out_mass = 0.0, top = -INFINITY;
    size_t jt = 0;
    for (size_t i = 0; volt && i < w->ncand;) {
        int b = m->tbulb[w->cand[i]], none = m->bulbs[b].ref == GS_REF_NONE;
        for (; i < w->ncand && m->tbulb[w->cand[i]] == b; i++) {
            size_t j = w->cand[i];
            if (none) continue;
            if (!m->cont[bb]) {
                if (m->tcell[j] == m->tcell[best.tmpl]) pc += w->mass[j];
            } else if (m->cont[b] ? inw[m->tcell[j]] : circ_dist(m->shift[j], best.shift) <= PHASE_WINDOW) {
                pc += w->mass[j];
            } else if (b == bb) {
                out_mass += w->mass[j];
                if (w->L[j] > top) {
                    top = w->L[j];
                    jt = j;
                }
            }
        }
    }
    if (volt && m->cont[bb]) {
        double lmo = log_mass(out_mass, top - Lmax + log(cell));
        if (top > -INFINITY && (second.bulb < 0 || lmo > second.lm)) {
            pair_c c = {lmo, bb, jt, m->shift[jt]};
            second = c;
        }
    }
    dec->bulb = bb;
    dec->tmpl = best.tmpl;
    dec->shift = best.shift;
    dec->conf = exp(best.lm) / Z;
    dec->bulb_conf = w->bmass[bb] / Z;
    if (second.bulb >= 0) {
        dec->runner_bulb = second.bulb;
        dec->runner_tmpl = second.tmpl;
        dec->runner_shift = second.shift;
        dec->runner_conf = exp(second.lm) / Z;
    }
    if (volt) dec->phase_conf = pc / Z;
    if (dec->conf > 1.0) dec->conf = 1.0;
    if (dec->bulb_conf > 1.0) dec->bulb_conf = 1.0;
    if (dec->phase_conf > 1.0) dec->phase_conf = 1.0;
    if (dec->runner_conf > 1.0) dec->runner_conf = 1.0;
done:
    rec_eq7_mark_cands(w, 0);
    w->ncand = 0;
}
