/* test_eq7_pixels.c - Eq. 7 on catalogs and pixel rows (rec_match_catalog, rec_match_pixels):
 * every row answers as rec_match_light does, across SGEMM blocks and through the dark-row
 * prefilter of the generated DELIGHT; and the bench's smoke test. */
#include "recognize/internal.h"
#include "recognize/recognize.h"
#include "tests/eq7_fixture.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <cblas.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

TEST(eq7_catalog_equals_lights)
{
    gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
    rec_matcher *m = eq7fx_new_matcher(d, 50, 3, 26, REC_PHASES_3);
    rec_catalog cat;
    memset(&cat, 0, sizeof cat);
    cat.count = 12;
    cat.bands = 3;
    cat.K = 26;
    cat.signal = malloc(sizeof(double) * 12 * 78);
    cat.sigma = malloc(sizeof(double) * 12 * 78);
    cat.flags = calloc(12, sizeof(unsigned));
    uint64_t rs = 16;
    for (int i = 0; i < 12; i++)
        eq7fx_render(rec_matcher_bulb(m, (size_t)i % 5), gs_phase_to_shift(eq7fx_p3[i % 3]), 26, 200.0 + 50 * i,
                     2.0, &rs, cat.signal + i * 78, cat.sigma + i * 78);
    cat.flags[7] = REC_BLOB_NO_SIGNAL;
    cat.flags[8] = REC_BLOB_SATURATED;
    rec_match out[12];
    CHECK_OK(rec_match_catalog(m, &cat, out, NULL));
    for (int i = 0; i < 12; i++) {
        rec_match r;
        CHECK_OK(rec_match_light(m, cat.signal + i * 78, cat.sigma + i * 78, &r));
        if (i == 7) {
            CHECK(out[i].bulb == -1 && (out[i].flags & REC_MATCH_BAD_INPUT) && eq7fx_all_finite(&out[i]));
            continue;
        }
        CHECK(memcmp(&r, &out[i], sizeof r) == 0);
    }
    cat.K = 13;
    CHECK(rec_match_catalog(m, &cat, out, NULL) == GS_EINVAL);
    cat.K = 26;
    cat.count = 0;
    CHECK_OK(rec_match_catalog(m, &cat, NULL, NULL));
    free(cat.signal);
    free(cat.sigma);
    free(cat.flags);
    rec_matcher_free(m);
    gs_delight_free(d);
}

/* The light path matches a catalog in blocks of lights whose sums share one pass over the
 * templates (recognize/eq7_sums.c): a light's answer must not depend on which lights share its
 * block. 300 lights of the generated DELIGHT (several blocks), one brightness and one per band
 * (the reddened model measures a prior from the catalog's other lights), a fixed excess and share
 * of bulbs not in DELIGHT (one pass): the catalog in reverse order, every other light flagged
 * without signal, and on 3 threads, each light's answer the same bits as in order on one thread,
 * and as rec_match_light's. */
TEST(eq7_catalog_answers_do_not_depend_on_the_block)
{
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, 1024));
    size_t n = 300, D = 78;
    rec_catalog cat = {.count = n, .bands = 3, .K = 26}, rev = cat;
    cat.signal = malloc(sizeof *cat.signal * n * D);
    cat.sigma = malloc(sizeof *cat.sigma * n * D);
    cat.flags = calloc(n, sizeof *cat.flags);
    rev.signal = malloc(sizeof *rev.signal * n * D);
    rev.sigma = malloc(sizeof *rev.sigma * n * D);
    rev.flags = calloc(n, sizeof *rev.flags);
    rec_match *a = malloc(sizeof *a * n), *b = malloc(sizeof *b * n);
    uint64_t rs = 31;
    for (int bm = REC_BANDS_CHROMA; bm <= REC_BANDS_FREE; bm++) {
        rec_eq7_opts o;
        rec_eq7_opts_default(&o);
        o.band_gains = bm;
        o.model_error = 0.02;
        o.other_prior = 0.05;
        o.flat_share = 0.0;
        o.threads = 1;
        rec_matcher *m = NULL, *m3 = NULL;
        CHECK_OK(rec_matcher_new(d, 50, 3, 26, &o, &m));
        o.threads = 3;
        CHECK_OK(rec_matcher_new(d, 50, 3, 26, &o, &m3));
        size_t nb = rec_matcher_bulb_count(m);
        for (size_t i = 0; i < n; i++) {
            double amp = i % 5 == 0 ? 2.0 : 50.0 + 400.0 * gs_splitmix_uniform(&rs);
            eq7fx_render(rec_matcher_bulb(m, i % nb), gs_phase_to_shift(eq7fx_p3[i % 3]), 26, amp, 1.0, &rs,
                         cat.signal + i * D, cat.sigma + i * D);
            memcpy(rev.signal + (n - 1 - i) * D, cat.signal + i * D, sizeof *cat.signal * D);
            memcpy(rev.sigma + (n - 1 - i) * D, cat.sigma + i * D, sizeof *cat.sigma * D);
        }
        CHECK_OK(rec_match_catalog(m, &cat, a, NULL));
        CHECK_OK(rec_match_catalog(m, &rev, b, NULL));
        int same = 0;
        for (size_t i = 0; i < n; i++) same += !memcmp(&a[i], &b[n - 1 - i], sizeof *a);
        CHECK_MSG(same == (int)n, "band model %d, reversed: %d of %zu answers the same bits", bm, same, n);
        for (size_t i = 0; i < n; i++) rev.flags[i] = i % 2 ? REC_BLOB_NO_SIGNAL : 0;
        CHECK_OK(rec_match_catalog(m, &rev, b, NULL));
        same = 0;
        for (size_t i = 0; i < n; i += 2) same += !memcmp(&a[n - 1 - i], &b[i], sizeof *a);
        CHECK_MSG(same == (int)n / 2, "band model %d, every other light without signal: %d of %zu", bm, same, n / 2);
        memset(rev.flags, 0, sizeof *rev.flags * n);
        CHECK_OK(rec_match_catalog(m3, &cat, b, NULL));
        CHECK_MSG(!memcmp(a, b, sizeof *a * n), "band model %d: 3 threads differ", bm);
        for (size_t i = 0; i < n; i += 37) {
            rec_match r;
            CHECK_OK(rec_match_light(m, cat.signal + i * D, cat.sigma + i * D, &r));
            CHECK_MSG(!memcmp(&r, &a[i], sizeof r), "band model %d light %zu: rec_match_light differs", bm, i);
        }
        rec_matcher_free(m);
        rec_matcher_free(m3);
    }
    free(a), free(b);
    rec_catalog_release(&cat);
    rec_catalog_release(&rev);
    gs_delight_free(d);
}

TEST(eq7_pixels_many_blocks)
{
    /* more rows than one SGEMM block, mixed lit / dark / bad rows: every row as rec_match_light */
    gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
    rec_matcher *m = eq7fx_new_matcher(d, 50, 3, 26, REC_PHASES_3);
    eq7fx_rows px;
    eq7fx_rows_alloc(&px, 9000);
    double x[78], sg[78];
    eq7fx_ttab tb;
    eq7fx_ttab_init(&tb, d, 50, 3, 26, eq7fx_p3, 3);
    uint64_t rs = 17;
    for (size_t i = 0; i < px.n; i++) {
        double a = (i % 3 == 0) ? 0.0 : 300.0;
        eq7fx_render_t(eq7fx_ttab_row(&tb, (int)(i % 5), (int)(i / 5) % 3), 78, a, 1.0, &rs, x, sg);
        for (int k = 0; k < 78; k++) px.x[i * 78 + k] = (float)x[k];
    }
    CHECK_OK(rec_match_pixels(m, px.x, px.sigma, px.n, px.bulb, px.phase, px.conf));
    int mism = eq7fx_rows_vs_lights(m, &px, 7, 0, NULL);
    CHECK_MSG(mism == 0, "%d rows differ from rec_match_light", mism);
    free(tb.t);
    eq7fx_rows_free(&px);
    rec_matcher_free(m);
    gs_delight_free(d);
}

/* Two answers of one row agree: the same bulb and phase (bits), the confidences within 1e-4
 * (*worst: the largest difference of agreeing answers so far). Not the same bits: OpenBLAS's
 * AVX2 SGEMM kernel (its "Haswell" core, also picked on AMD Zen) rounds a row's dot products
 * differently with its place in the block (the tests print the largest difference); its
 * SkylakeX and Sandybridge kernels, and the continuous phases' Fourier screen, give the same
 * bits. */
static int same_answer(int b0, float p0, float c0, int b1, float p1, float c1, float *worst)
{
    int same = b0 == b1 && !memcmp(&p0, &p1, sizeof p0) && fabsf(c0 - c1) <= 1e-4f;
    if (same) *worst = fmaxf(*worst, fabsf(c0 - c1));
    return same;
}

/* The prefilter rests after blocks it hardly filtered (all-lit regions): runs of bright rows,
 * then dark, dim (around the threshold) and broken rows (NaN, Inf, sigma 0 or NaN), twice, in
 * one call give every row the same answer (same_answer) as calls of one block each (PIX_BLOCK rows, every one
 * prefiltered); with the paper's model (the one-score path) and with band gains, without and
 * with a model error (the band path). The first block's bright rows must all pass the
 * prefilter, which is what makes the next blocks go without it. */
TEST(eq7_pixels_prefilter_rest_same_answers_as_block_by_block)
{
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, 1024));
    eq7fx_ttab tb;
    eq7fx_ttab_init(&tb, d, 50, 3, 26, eq7fx_p3, 3);
    size_t run = 3000;
    eq7fx_rows px;
    eq7fx_rows_alloc(&px, 4 * run);
    int b[PIX_BLOCK];
    float ph[PIX_BLOCK], cf[PIX_BLOCK];
    for (int model = 0; model < 3; model++) {
        rec_matcher *m = NULL;
        if (model == 0) {
            m = eq7fx_new_matcher(d, 50, 3, 26, REC_PHASES_3);
        } else {
            rec_eq7_opts o;
            rec_eq7_opts_default(&o);
            o.phases = REC_PHASES_3;
            o.threads = 1;
            o.model_error = model == 2 ? 0.02 : o.model_error;
            CHECK_OK(rec_matcher_new(d, 50, 3, 26, &o, &m));
        }
        CHECK(m && rec_matcher_prefilter_dim(m) > 0);
        if (!m) continue;
        size_t nb = rec_matcher_bulb_count(m);
        double x[78], sg[78];
        uint64_t rs = 41;
        for (size_t i = 0; i < px.n; i++) {
            int lit_run = (i / run) % 2 == 0;
            double a = lit_run ? 5.0 + 50.0 * gs_splitmix_uniform(&rs)
                               : (i % 3 == 0) ? 0.0 : 0.5 + 1.5 * gs_splitmix_uniform(&rs);
            eq7fx_render_t(eq7fx_ttab_row(&tb, (int)(i % nb), (int)(i / nb) % 3), 78, a, 1.0, &rs, x, sg);
            for (int k = 0; k < 78; k++) px.x[i * 78 + k] = (float)x[k];
            px.sigma[i] = 1.0f;
            if (!lit_run && i % 97 == 1) px.x[i * 78 + i % 78] = NAN;
            if (!lit_run && i % 97 == 2) px.x[i * 78 + i % 78] = INFINITY;
            if (!lit_run && i % 89 == 3) px.sigma[i] = (i % 2) ? 0.0f : NAN;
        }
        CHECK_OK(rec_match_pixels(m, px.x, px.sigma, px.n, px.bulb, px.phase, px.conf));
        int differ = 0, answered = 0, first_block = 0;
        float worst = 0.0f;
        for (size_t i0 = 0; i0 < px.n; i0 += PIX_BLOCK) {
            size_t n = px.n - i0 < PIX_BLOCK ? px.n - i0 : PIX_BLOCK;
            CHECK_OK(rec_match_pixels(m, px.x + i0 * 78, px.sigma + i0, n, b, ph, cf));
            for (size_t k = 0, i = i0; k < n; k++, i++) {
                answered += b[k] >= 0;
                first_block += i0 == 0 && b[k] >= 0;
                if (!same_answer(b[k], ph[k], cf[k], px.bulb[i], px.phase[i], px.conf[i], &worst)) {
                    if (differ++ < 5)
                        printf("    model %d, row %zu: by blocks %d %g %g, in one call %d %g %g\n", model, i,
                               b[k], ph[k], cf[k], px.bulb[i], px.phase[i], px.conf[i]);
                }
            }
        }
        CHECK_MSG(differ == 0, "model %d: %d of %zu rows differ", model, differ, px.n);
        printf("    model %d: confidences by blocks and in one call differ by at most %.2g\n", model, worst);
        CHECK_MSG(4 * first_block > 3 * PIX_BLOCK, "model %d: %d of the first block's rows answered", model,
                  first_block);
        CHECK(answered > (int)px.n / 3);
        rec_matcher_free(m);
    }
    free(tb.t);
    eq7fx_rows_free(&px);
    gs_delight_free(d);
}

/* rec_match_pixels splits its blocks of rows over rec_eq7_opts.threads: 1, 2 and 3 threads give
 * every row the same answer (same_answer) for the paper's model with three phases (the
 * prefilter, resting after the bright runs on each thread), the survey's defaults (the band path)
 * and continuous phases (the Fourier screen); rows bright, dim, dark and broken, in runs of
 * 1.5 PIX_BLOCK rows (a block and a half with three phases; continuous matchers' blocks are
 * smaller, PIX_BLOCK_BYTES of scores), and a last block shorter than the others. OpenBLAS's threads are as before
 * each call (set to one within a call on several). */
TEST(eq7_pixels_threads_same_answers_as_one_thread)
{
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, 1024));
    eq7fx_ttab tb;
    eq7fx_ttab_init(&tb, d, 50, 3, 26, eq7fx_p3, 3);
    size_t n = 6 * PIX_BLOCK + 77, run = 3 * PIX_BLOCK / 2;
    eq7fx_rows px[3];
    for (int t = 0; t < 3; t++) eq7fx_rows_alloc(&px[t], n);
    for (int model = 0; model < 3; model++) {
        rec_matcher *m[3] = {NULL, NULL, NULL};
        for (int t = 0; t < 3; t++) {
            rec_eq7_opts o;
            rec_eq7_opts_default(&o);
            o.phases = model == 2 ? REC_PHASES_CONTINUOUS : REC_PHASES_3;
            if (model != 1) {   /* the paper's model */
                o.band_gains = 0;
                o.model_error = 0.0;
                o.other_prior = o.blend_prior = o.flat_share = 0.0;
            }
            o.threads = t + 1;
            CHECK_OK(rec_matcher_new(d, 50, 3, 26, &o, &m[t]));
        }
        if (!m[0] || !m[1] || !m[2]) break;
        size_t nb = rec_matcher_bulb_count(m[0]);
        double x[78], sg[78];
        uint64_t rs = 59;
        for (size_t i = 0; i < n; i++) {
            int lit_run = (i / run) % 2 == 0;
            double a = lit_run ? 5.0 + 50.0 * gs_splitmix_uniform(&rs)
                               : (i % 3 == 0) ? 0.0 : 0.5 + 1.5 * gs_splitmix_uniform(&rs);
            eq7fx_render_t(eq7fx_ttab_row(&tb, (int)(i % nb), (int)(i / nb) % 3), 78, a, 1.0, &rs, x, sg);
            for (int t = 0; t < 3; t++) {
                for (int k = 0; k < 78; k++) px[t].x[i * 78 + k] = (float)x[k];
                px[t].sigma[i] = 1.0f;
                if (i % 97 == 1) px[t].x[i * 78 + i % 78] = NAN;
                if (i % 89 == 3) px[t].sigma[i] = 0.0f;
            }
        }
        int blas = openblas_get_num_threads();
        openblas_set_num_threads(2);   /* (restored by every call on several threads) */
        for (int t = 0; t < 3; t++) {
            CHECK_OK(rec_match_pixels(m[t], px[t].x, px[t].sigma, n, px[t].bulb, px[t].phase, px[t].conf));
            CHECK_MSG(openblas_get_num_threads() == 2, "%d threads: OpenBLAS left on %d", t + 1, openblas_get_num_threads());
        }
        openblas_set_num_threads(blas);
        int answered = 0;
        for (size_t i = 0; i < n; i++) answered += px[0].bulb[i] >= 0;
        CHECK_MSG(answered > (int)n / 3, "model %d: %d of %zu rows answered", model, answered, n);
        for (int t = 1; t < 3; t++) {
            int differ = 0;
            float worst = 0.0f;
            for (size_t i = 0; i < n; i++)
                differ += !same_answer(px[t].bulb[i], px[t].phase[i], px[t].conf[i], px[0].bulb[i], px[0].phase[i],
                                       px[0].conf[i], &worst);
            CHECK_MSG(differ == 0, "model %d, %d threads: %d of %zu rows differ from one thread", model, t + 1,
                      differ, n);
            printf("    model %d, %d threads: confidences differ from one thread's by at most %.2g\n", model, t + 1,
                   worst);
        }
        for (int t = 0; t < 3; t++) rec_matcher_free(m[t]);
    }
    for (int t = 0; t < 3; t++) eq7fx_rows_free(&px[t]);
    free(tb.t);
    gs_delight_free(d);
}

/* Rows of every brightness, including just around the dim threshold (z ~ 3), through the
 * generated DELIGHT (150 templates, where the dark-row prefilter is active): every row as
 * rec_match_light says. */
TEST(eq7_pixels_prefilter_generated_delight)
{
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, 1024));
    rec_matcher *m = eq7fx_new_matcher(d, 50, 3, 26, REC_PHASES_3);
    CHECK_MSG(rec_matcher_prefilter_dim(m) > 0, "prefilter dimension %d", rec_matcher_prefilter_dim(m));
    eq7fx_ttab tb;
    eq7fx_ttab_init(&tb, d, 50, 3, 26, eq7fx_p3, 3);
    size_t nb = rec_matcher_bulb_count(m);
    eq7fx_rows px;
    eq7fx_rows_alloc(&px, 4000);   /* each of the 150 x 3 templates about 9 times */
    double x[78], sg[78];
    uint64_t rs = 23;
    for (size_t i = 0; i < px.n; i++) {
        /* |t| ~ 2.9 for a unit brightness: a in [0.5, 2] puts z around 1.5 - 6 */
        double a = (i % 4 == 0) ? 0.0 : (i % 4 == 3) ? 50.0 * gs_splitmix_uniform(&rs) : 0.5 + 1.5 * gs_splitmix_uniform(&rs);
        eq7fx_render_t(eq7fx_ttab_row(&tb, (int)(i % nb), (int)(i / nb) % 3), 78, a, 1.0, &rs, x, sg);
        for (int k = 0; k < 78; k++) px.x[i * 78 + k] = (float)x[k];
    }
    CHECK_OK(rec_match_pixels(m, px.x, px.sigma, px.n, px.bulb, px.phase, px.conf));
    int answered = 0, mism = eq7fx_rows_vs_lights(m, &px, 1, 0, &answered);
    CHECK_MSG(mism == 0, "%d of %zu rows differ from rec_match_light", mism, px.n);
    CHECK(answered > (int)px.n / 4);
    free(tb.t);
    eq7fx_rows_free(&px);
    rec_matcher_free(m);
    gs_delight_free(d);
}


/* The screen on the first PIX_BLOCK finite rows of x with a valid sigma (row i of kind i % 6:
 * dark, dim, lit, bright): every bulb's bound against the float scores of its templates (the
 * screen's kernel on every bulb, REC_FS_ALL) and against double dot products; what it leaves
 * out. */
static void screen_block_checks(rec_matcher *m, const float *x, const float *sg, size_t n)
{
    size_t D = (size_t)m->D, nb = m->nb, Mp = m->Mp, rows[PIX_BLOCK], ns = 0;
    float *xs = malloc(sizeof *xs * PIX_BLOCK * D), *sc = malloc(sizeof *sc * PIX_BLOCK * Mp);
    double *bound = malloc(sizeof *bound * PIX_BLOCK * nb);
    unsigned char keep[PIX_BLOCK], *state = malloc(PIX_BLOCK * nb);
    rec_pixscreen_work sw;
    CHECK_OK(rec_eq7_pixscreen_alloc(m, PIX_BLOCK, &sw));
    for (size_t i = 0; i < n && ns < PIX_BLOCK; i++) {
        int ok = sg[i] > 0.0f && i % 6 < 4;
        for (size_t d = 0; d < D; d++) ok = ok && isfinite(x[i * D + d]);
        if (!ok) continue;
        memcpy(xs + ns * D, x + i * D, sizeof *xs * D);
        rows[ns++] = i;
    }
    rec_eq7_pixscreen(m, &sw, xs, ns, sg, rows, sc, keep);
    memcpy(bound, sw.bound, sizeof *bound * ns * nb);
    memcpy(state, sw.state, ns * nb);
    int dark = 0, dark_out = 0;
    size_t lit_pairs = 0, lit_scored = 0;
    for (size_t k = 0; k < ns; k++) {
        int kind = (int)(rows[k] % 6);
        dark += kind == 0;
        dark_out += kind == 0 && !keep[k];
        for (size_t b = 0; b < nb && kind >= 2 && keep[k]; b++) {
            lit_pairs++;
            lit_scored += state[k * nb + b] != 0;
        }
    }
    m->fs_on = REC_FS_ALL;   /* every score, for the bounds */
    rec_eq7_pixscreen(m, &sw, xs, ns, sg, rows, sc, keep);
    m->fs_on = REC_FS_ON;
    int below = 0;
    for (size_t k = 0; k < ns; k++)
        for (size_t b = 0; b < nb; b++) {
            double best = -INFINITY, bestf = -INFINITY;
            for (size_t c = 0; c < m->count[b]; c++) {
                size_t j = m->first[b] + c;
                double v = 0.0;
                for (size_t d = 0; d < D; d++) v += (double)xs[k * D + d] * m->tnd[j * D + d];
                best = v > best ? v : best;
                bestf = sc[k * Mp + j] > bestf ? sc[k * Mp + j] : bestf;
            }
            if (!(bound[k * nb + b] >= best && bound[k * nb + b] >= bestf) && below++ < 5)
                printf("    row %zu bulb %zu: bound %.9g below the best score %.9g (float %.9g)\n", rows[k], b,
                       bound[k * nb + b], best, bestf);
        }
    printf("    screen: %d of %d dark rows left out; %zu of %zu (lit row, bulb) pairs scored\n", dark_out, dark,
           lit_scored, lit_pairs);
    CHECK_MSG(below == 0, "%d bounds below their bulb's best score", below);
    CHECK_MSG(2 * dark_out > dark, "%d of %d dark rows left out", dark_out, dark);
    CHECK_MSG(lit_pairs > 0 && 2 * lit_scored < lit_pairs, "%zu of %zu lit pairs scored", lit_scored, lit_pairs);
    rec_eq7_pixscreen_free(&sw);
    free(xs);
    free(sc);
    free(bound);
    free(state);
}

/* The pixel path's exact rescoring (rec_eq7_exact_z) against long double dot products with the
 * templates: continuous grids (RGB at K = 26 and 13, photodiode at K = 8; runs of whole bulbs and
 * of 72 cells with a gap through the grid's inverse FFT, of 31 and 3 cells four at a time; and
 * without grids, every run four at a time, as beyond Sxx = 1e12) and a
 * discrete matcher, rows of noise and of a template, 1e-2 to 1e6: within 1e-12 of |x| / sigma. */
TEST(eq7_pixels_exact_scores_equal_dot_products)
{
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, 1024));
    static const struct { int bands, K; rec_phase_set ps; } cases[] = {
        {3, 26, REC_PHASES_CONTINUOUS}, {3, 13, REC_PHASES_CONTINUOUS}, {1, 8, REC_PHASES_CONTINUOUS}, {3, 26, REC_PHASES_3}};
    uint64_t rs = 211;
    for (size_t ci = 0; ci < sizeof cases / sizeof *cases; ci++) {
        rec_matcher *m = eq7fx_new_matcher(d, 50, cases[ci].bands, cases[ci].K, cases[ci].ps);
        if (!m) continue;
        size_t D = (size_t)m->D, M = m->M, n = 0, *cand = malloc(sizeof *cand * M);
        double *xd = malloc(sizeof *xd * D), *zz = malloc(sizeof *zz * M), *gd = malloc(sizeof *gd * (size_t)(m->G > 0 ? m->G : 1));
        rec_eq7_work w;
        CHECK_OK(rec_eq7_work_alloc(m, &w));
        /* bulb 0 whole, bulb 1's cells 0..39 and 50..81 (one run), bulb 2's 0..30, bulb 3's 5..7,
         * the last bulb whole */
        size_t nb = m->nb, lo[5] = {0, 0, 50, 0, 5}, hi[5] = {M, 40, 82, 31, 8}, bu[5] = {0, 1, 1, 2, 3};
        for (int r = 0; r < 6; r++) {
            size_t b = r < 5 ? bu[r] : nb - 1;
            size_t a = r < 5 ? lo[r] : 0, e = r < 5 ? hi[r] : M;
            for (size_t c = a; c < e && c < m->count[b]; c++) cand[n++] = m->first[b] + c;
        }
        int far = 0;
        for (int trial = 0; trial < 20; trial++) {
            double scale = pow(10.0, 8.0 * gs_splitmix_uniform(&rs) - 2.0), xx = 0.0, inv = 1.0 / (0.5 + gs_splitmix_uniform(&rs));
            for (size_t q = 0; q < D; q++) {
                xd[q] = scale * (gs_splitmix_normal(&rs) + (trial % 2 ? m->t[(n / 2) * D + q] : 0.0));
                xx += xd[q] * xd[q];
            }
            for (int grids = 1; grids >= 0; grids--) {   /* (0: every run four at a time) */
                for (size_t i = 0; i < n; i++) zz[cand[i]] = NAN;
                rec_eq7_exact_z(m, &w, gd, xd, inv, cand, n, grids, zz);
                for (size_t i = 0; i < n; i++) {
                    size_t j = cand[i];
                    long double s = 0.0L;
                    for (size_t q = 0; q < D; q++) s += (long double)xd[q] * m->t[j * D + q];
                    double ref = (double)(s / sqrtl((long double)exp(2.0 * m->lognorm[j])) * inv);
                    if (!(fabs(zz[j] - ref) <= 1e-12 * sqrt(xx) * inv) && far++ < 5)
                        printf("    K = %d, %d bands, grids %d, template %zu (bulb %d, cell %d): %.17g, dot product "
                               "%.17g\n", m->K, m->bands, grids, j, m->tbulb[j], m->tcell[j], zz[j], ref);
                }
            }
        }
        CHECK_MSG(far == 0, "K = %d, %d bands: %d exact scores off their dot products", m->K, m->bands, far);
        rec_eq7_work_free(&w);
        free(cand);
        free(xd);
        free(zz);
        free(gd);
        rec_matcher_free(m);
    }
    gs_delight_free(d);
}

/* What pixel_row reads behind the screen, on the first PIX_BLOCK rows of x with a valid sigma (score buffer filled
 * with NaN first): each kept row's ranges (rec_eq7_pixscreen_ranges) are whole vectors in rising
 * order within Mp, hold every template of the bulbs it scored (their scores written), and 0 at
 * every other template and the padding they reach. */
static void screen_ranges_checks(rec_matcher *m, const float *x, const float *sg, size_t n)
{
    size_t D = (size_t)m->D, nb = m->nb, Mp = m->Mp, rows[PIX_BLOCK], ns = 0;
    float *xs = malloc(sizeof *xs * PIX_BLOCK * D), *sc = malloc(sizeof *sc * PIX_BLOCK * Mp);
    size_t *range = malloc(sizeof *range * 2 * nb);
    unsigned char keep[PIX_BLOCK], *scored = malloc(Mp);
    rec_pixscreen_work sw;
    CHECK_OK(rec_eq7_pixscreen_alloc(m, PIX_BLOCK, &sw));
    for (size_t i = 0; i < PIX_BLOCK * Mp; i++) sc[i] = NAN;
    for (size_t i = 0; i < n && ns < PIX_BLOCK; i++) {   /* rows as rec_match_pixels passes them */
        if (!(sg[i] > 0.0f) || !isfinite(sg[i])) continue;
        memcpy(xs + ns * D, x + i * D, sizeof *xs * D);
        rows[ns++] = i;
    }
    rec_eq7_pixscreen(m, &sw, xs, ns, sg, rows, sc, keep);
    int bad = 0, kept = 0, partial = 0;
    for (size_t k = 0; k < ns; k++) {
        if (!keep[k]) continue;
        kept++;
        memset(scored, 0, Mp);
        size_t nr = rec_eq7_pixscreen_ranges(m, &sw, k, range), reached = 0, nscored = 0;
        for (size_t b = 0; b < nb; b++)
            if (sw.state[k * nb + b] == 2) {   /* ST_DONE */
                memset(scored + m->first[b], 1, m->count[b]);
                nscored += m->count[b];
            }
        partial += nscored < m->M;
        for (size_t i = 0; i < nr; i++) {
            size_t lo = range[2 * i], hi = range[2 * i + 1];
            if (lo % LANES || hi % LANES || hi <= lo || hi > Mp || (i > 0 && lo <= range[2 * i - 1])) {
                if (bad++ < 5) printf("    row %zu: range [%zu, %zu) of Mp %zu\n", k, lo, hi, Mp);
                continue;
            }
            for (size_t j = lo; j < hi; j++) {
                reached += scored[j];
                int ok = scored[j] ? !isnan(sc[k * Mp + j]) : sc[k * Mp + j] == 0.0f;
                if (!ok && bad++ < 5) printf("    row %zu: template %zu (scored %d) reads %g\n", k, j, scored[j], sc[k * Mp + j]);
            }
        }
        if (reached != nscored && bad++ < 5) printf("    row %zu: %zu of %zu scored templates in its ranges\n", k, reached, nscored);
    }
    CHECK_MSG(bad == 0, "K = %d: %d faults in the ranges pixel_row reads", m->K, bad);
    CHECK_MSG(kept > 0 && partial > 0, "K = %d: %d rows kept, %d with bulbs left out", m->K, kept, partial);
    rec_eq7_pixscreen_free(&sw);
    free(xs);
    free(sc);
    free(range);
    free(scored);
}

/* The Fourier screen of continuous grids (recognize/eq7_pixscreen.c) gives full scores only to
 * the bulbs that can matter: every row gets the bits it gets with the screen's kernel on every
 * bulb (REC_FS_ALL): dark rows, dim ones around the threshold, lit and bright ones (the exact
 * rescoring and the Newton refinement), rows near float overflow (|x| / sigma ~ 1e21 and
 * entries ~ 1e37), rows of zero mean (scores around 0), zero and broken rows (NaN, Inf, sigma 0
 * or NaN), several blocks; RGB at K = 26 (G = 208), a photodiode at K = 8 and RGB at K = 12
 * (G = 96), and RGB at K = 13 (G = 104, not a multiple of the 16-score vectors) with min_snr 0
 * and no unknown test (every row answered, extreme ones too). SGEMM's float scores differ from
 * that kernel's in the last bits (its kernels depend on the shapes): against one SGEMM of every
 * template (REC_FS_OFF), at K = 26, the same bulb wherever a pair has confidence >= 0.1, phases
 * within 1 deg (dim rows' parabolas), confidences within 5e-3. And the screen itself on one
 * block of the K = 26 rows: every bulb's bound is at least its largest float and double score,
 * and it leaves out most dark rows and most (lit row, bulb) pairs (else the first part could
 * pass with a screen that scores everything). In every case, what pixel_row reads of a block's
 * scores (screen_ranges_checks). A discrete matcher with a shape-only bulb
 * (searched over every shift) keeps its dark-row prefilter and has no screen. */
TEST(eq7_pixels_fourier_screen_same_answers_as_every_score)
{
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, 1024));
    static const struct { int bands, K; double min_snr, unknown_p; } cases[] = {
        {3, 26, 3.0, -1}, {1, 8, 3.0, -1}, {3, 12, 3.0, -1}, {3, 13, 0.0, 0.0}};
    for (size_t ci = 0; ci < sizeof cases / sizeof *cases; ci++) {
        int bands = cases[ci].bands, K = cases[ci].K, D = bands * K;
        rec_eq7_opts o;
        rec_eq7_opts_default(&o);
        o.phases = REC_PHASES_CONTINUOUS;
        o.band_gains = 0;
        o.model_error = 0.0;
        o.other_prior = o.blend_prior = o.flat_share = 0.0;
        o.min_snr = cases[ci].min_snr;
        if (cases[ci].unknown_p >= 0.0) o.unknown_p = cases[ci].unknown_p;
        rec_matcher *m = NULL;
        CHECK_OK(rec_matcher_new(d, 50, bands, K, &o, &m));
        CHECK_MSG(m && m->fs_on == REC_FS_ON, "K = %d, %d bands: the screen is on", K, bands);
        if (!m || m->fs_on != REC_FS_ON) {
            rec_matcher_free(m);
            continue;
        }
        size_t n = 1500, M = rec_matcher_template_count(m);
        float *x = malloc(sizeof *x * n * (size_t)D), *sg = malloc(sizeof *sg * n);
        float *ph[2] = {malloc(sizeof(float) * n), malloc(sizeof(float) * n)};
        float *cf[2] = {malloc(sizeof(float) * n), malloc(sizeof(float) * n)};
        int *bu[2] = {malloc(sizeof(int) * n), malloc(sizeof(int) * n)};
        uint64_t rs = 97 + ci;
        for (size_t i = 0; i < n; i++) {
            size_t j = (size_t)(gs_splitmix_uniform(&rs) * (double)M) % M;
            const double *t = rec_matcher_template(m, j, NULL, NULL);
            double tt = 0.0, mean = 0.0;
            for (int k = 0; k < D; k++) tt += t[k] * t[k], mean += t[k] / D;
            /* a |t| = z: dark (or below zero), dim (0.5 - 6), lit (6 - 60), bright (100 - 3000), extreme,
             * zero mean */
            int kind = (int)(i % 6);
            double u = gs_splitmix_uniform(&rs);
            double z = kind == 0 ? 0.0 : kind == 1 ? 0.5 + 5.5 * u : kind == 2 ? 6.0 + 54.0 * u
                     : kind == 3 ? 100.0 + 2900.0 * u : kind == 4 ? (i % 12 < 6 ? 1e21 : 1.5e37 * sqrt(tt) / t[0])
                     : 3.0 * u;
            double a = z / sqrt(tt);
            /* (every other dark row 10 sigma below zero: every score negative) */
            double off = kind == 0 && i % 12 == 6 ? -10.0 : 0.0;
            for (int k = 0; k < D; k++)
                x[i * (size_t)D + (size_t)k] = (float)(a * (kind == 5 ? t[k] - mean : t[k]) + off + gs_splitmix_normal(&rs));
            sg[i] = 1.0f;
            if (i % 61 == 5) x[i * (size_t)D + i % (size_t)D] = NAN;
            if (i % 61 == 6) x[i * (size_t)D + i % (size_t)D] = INFINITY;
            if (i % 67 == 7) sg[i] = (i % 2) ? 0.0f : NAN;
            if (i % 71 == 8) memset(x + i * (size_t)D, 0, sizeof *x * (size_t)D);
        }
        for (int on = 0; on < 2; on++) {
            m->fs_on = on ? REC_FS_ON : REC_FS_ALL;
            CHECK_OK(rec_match_pixels(m, x, sg, n, bu[on], ph[on], cf[on]));
        }
        m->fs_on = REC_FS_ON;
        int differ = 0, answered = 0, extreme = 0;
        for (size_t i = 0; i < n; i++) {
            answered += bu[1][i] >= 0;
            extreme += i % 6 == 4 && bu[1][i] >= 0;
            if (bu[0][i] != bu[1][i] || memcmp(&ph[0][i], &ph[1][i], sizeof(float)) ||
                memcmp(&cf[0][i], &cf[1][i], sizeof(float))) {
                if (differ++ < 5)
                    printf("    K = %d, %d bands, row %zu: screened %d %g %g, every score %d %g %g\n", K, bands, i,
                           bu[1][i], ph[1][i], cf[1][i], bu[0][i], ph[0][i], cf[0][i]);
            }
        }
        CHECK_MSG(differ == 0, "K = %d, %d bands: %d of %zu rows differ", K, bands, differ, n);
        CHECK_MSG(answered > (int)n / 3, "K = %d: %d rows answered", K, answered);
        if (cases[ci].unknown_p == 0.0) CHECK_MSG(extreme > (int)n / 12, "K = %d: %d extreme rows answered", K, extreme);
        if (ci == 0) {
            /* against one SGEMM of every template (REC_FS_OFF): the same bulbs where a pair has
             * confidence >= 0.1; phases and confidences within the float scores' rounding (dim
             * rows' parabolas) */
            m->fs_on = REC_FS_OFF;
            CHECK_OK(rec_match_pixels(m, x, sg, n, bu[0], ph[0], cf[0]));
            m->fs_on = REC_FS_ON;
            int other = 0;
            double dph = 0.0, dcf = 0.0;
            for (size_t i = 0; i < n; i++) {
                /* a bulb may flip only between near-tied pairs of a row no pair dominates */
                if (bu[0][i] != bu[1][i] && (cf[0][i] >= 0.1f || cf[1][i] >= 0.1f) && other++ < 3)
                    printf("    row %zu (kind %zu): SGEMM %d %g %g, screened %d %g %g\n", i, i % 6, bu[0][i], ph[0][i],
                           cf[0][i], bu[1][i], ph[1][i], cf[1][i]);
                if (bu[0][i] < 0 || bu[0][i] != bu[1][i]) continue;
                double e = fabs((double)ph[0][i] - ph[1][i]);
                e = e > 180.0 ? 360.0 - e : e;
                dph = e > dph ? e : dph;
                dcf = fabs((double)cf[0][i] - cf[1][i]) > dcf ? fabs((double)cf[0][i] - cf[1][i]) : dcf;
            }
            printf("    against SGEMM: %d confident bulbs differ, phases within %.3g deg, confidences within %.2g\n", other,
                   dph, dcf);
            CHECK_MSG(other == 0 && dph < 1.0 && dcf < 5e-3, "against SGEMM: %d bulbs, %g deg, %g", other, dph, dcf);
            screen_block_checks(m, x, sg, n);
        }
        screen_ranges_checks(m, x, sg, n);
        rec_matcher_free(m);
        free(x);
        free(sg);
        for (int on = 0; on < 2; on++) {
            free(ph[on]);
            free(cf[on]);
            free(bu[on]);
        }
    }
    /* discrete phases with a shape-only bulb: no screen, the prefilter kept */
    gs_delight *d2 = gs_delight_new();
    size_t nv = 0;
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        gs_bulb b = *gs_delight_get(d, i);
        if (b.grid_hz != 50 || strcmp(b.sensor, "rgb") || b.ref != GS_REF_VOLTAGE) continue;
        if (nv++ == 0) {
            CHECK_OK(gs_delight_add(d2, &b));
            snprintf(b.id, sizeof b.id, "shape-only-copy");
            b.ref = GS_REF_NONE;
        }
        CHECK_OK(gs_delight_add(d2, &b));
    }
    rec_matcher *m3 = eq7fx_new_matcher(d2, 50, 3, 26, REC_PHASES_3);
    CHECK(m3 && m3->ncont == 1 && m3->fs_on == REC_FS_OFF && rec_matcher_prefilter_dim(m3) > 0);
    rec_matcher_free(m3);
    gs_delight_free(d2);
    gs_delight_free(d);
}


/* One file of n items of size sz in dir (CHECKed). */
static void write_file(const char *dir, const char *name, const void *p, size_t sz, size_t n)
{
    char path[1200];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "wb");
    CHECK(f && fwrite(p, sz, n, f) == n);
    if (f) fclose(f);
}

/* rec_match_pixels against an independent implementation of the same search: the NumPy one of
 * `bench recognize --numpy` (survey/bench_eq7_numpy.py, written from the models' description,
 * sharing no code with recognize/), on the same rows, with the paper's model and with the
 * survey's defaults per pixel (free band gains). Rows: a random template of the generated
 * DELIGHT's voltage-referenced 50 Hz RGB bulbs at 0/120/240 deg, 2 to 40 noise sigmas per
 * sample, and dark rows. Oracle: the same answer (bulb and phase, or none) for >= 99.5 % of the
 * rows (float scores leave near-ties to either side), under 95 % with the other model's search
 * (the comparison tells the models apart), and most lit rows answered. */
TEST(eq7_pixels_agree_with_numpy_search)
{
    gs_delight *all = gs_delight_new(), *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(all, 1024));
    for (size_t i = 0; i < gs_delight_count(all); i++) {
        const gs_bulb *b = gs_delight_get(all, i);
        if (b->grid_hz == 50 && b->brf.bands == 3 && b->ref == GS_REF_VOLTAGE) CHECK_OK(gs_delight_add(d, b));
    }
    size_t nb = gs_delight_count(d), M = 3 * nb, D = 78, P = 3000;
    double *t = malloc(sizeof *t * M * D);
    float *x = malloc(sizeof *x * P * D), *sg = malloc(sizeof *sg * P), *ph = malloc(sizeof *ph * P);
    int *bulb = malloc(sizeof *bulb * P), *ans = malloc(sizeof *ans * 2 * P);
    CHECK(nb > 10 && t && x && sg && ph && bulb && ans);
    for (size_t j = 0; j < M; j++) eq7fx_template(gs_delight_get(d, j / 3), gs_phase_to_shift(120.0 * (double)(j % 3)), 26, t + j * D);
    uint64_t rs = 77;
    size_t lit = 0;
    for (size_t p = 0; p < P; p++) {
        int on = p % 3 != 0;
        size_t j = (size_t)gs_splitmix64(&rs) % M;
        double a = on ? 2.0 + 38.0 * gs_splitmix_uniform(&rs) : 0.0;   /* templates' mean ~1/3 per band */
        for (size_t k = 0; k < D; k++) x[p * D + k] = (float)(3.0 * a * t[j * D + k] + gs_splitmix_normal(&rs));
        sg[p] = 1.0f;
        lit += on;
    }
    char dir[1100];
    snprintf(dir, sizeof dir, "%s", fx_tmp("numpy-search"));
    CHECK(mkdir(dir, 0700) == 0);
    write_file(dir, "t.f64", t, sizeof *t, M * D);
    write_file(dir, "x.f32", x, sizeof *x, P * D);
    rec_eq7_opts o;
    rec_eq7_opts_default(&o);
    o.phases = REC_PHASES_3;
    o.threads = 1;
    /* NumPy's answers with each model (ans + model * P); the unknown test at the matcher's dof:
     * D - 2 (one brightness), D - 4 (three gains) */
    int got[2];
    for (int model = 0; model < 2; model++) {
        double thr = gs_chi2_isf(o.unknown_p, model == 0 ? (int)D - 2 : (int)D - 4);
        char params[256], path[1200], out[4096];
        int n = snprintf(params, sizeof params, "%zu %zu %zu %.17g %.17g 1 %s 3\n", M, D, P, o.min_snr, thr,
                         model == 0 ? "chroma" : "free");
        write_file(dir, "params.txt", params, 1, (size_t)n);
        CHECK_MSG(fx_run(out, sizeof out, "OPENBLAS_NUM_THREADS=1 /usr/bin/python3 survey/bench_eq7_numpy.py %s",
                         dir) == 0, "%s", out);
        snprintf(path, sizeof path, "%s/answers.i32", dir);
        FILE *f = fopen(path, "rb");
        got[model] = f && fread(ans + (size_t)model * P, sizeof *ans, P, f) == P;
        if (f) fclose(f);
        CHECK(got[model]);
    }
    for (int model = 0; model < 2 && got[0] && got[1]; model++) {
        rec_matcher *m = NULL;
        if (model == 0) m = eq7fx_new_matcher(d, 50, 3, 26, REC_PHASES_3);
        else CHECK_OK(rec_matcher_new(d, 50, 3, 26, &o, &m));
        CHECK(m != NULL);
        if (!m) continue;
        CHECK_OK(rec_match_pixels(m, x, sg, P, bulb, ph, NULL));
        size_t same[2] = {0, 0}, answered = 0;   /* alike with NumPy's chroma and free searches */
        for (size_t p = 0; p < P; p++) {
            answered += p % 3 != 0 && bulb[p] >= 0;
            for (int nm = 0; nm < 2; nm++) {
                int a = ans[(size_t)nm * P + p];
                if (a < 0 || bulb[p] < 0) {
                    same[nm] += a < 0 && bulb[p] < 0;
                    continue;
                }
                const gs_bulb *mine = rec_matcher_bulb(m, (size_t)bulb[p]), *theirs = gs_delight_get(d, (size_t)a / 3);
                same[nm] += !strcmp(mine->id, theirs->id) && fabs(ph[p] - 120.0 * (a % 3)) < 1e-3;
            }
        }
        printf("    %s: %zu of %zu rows alike with NumPy's search of the same model, %zu with the other's\n",
               model == 0 ? "paper's model" : "survey's defaults", same[model], P, same[1 - model]);
        CHECK_MSG(same[model] >= P - P / 200, "model %d: %zu of %zu rows answered alike", model, same[model], P);
        /* the oracle tells the models apart */
        CHECK_MSG(same[1 - model] < P - P / 20, "model %d: %zu of %zu rows alike with the other model", model,
                  same[1 - model], P);
        CHECK_MSG(answered > lit / 2, "model %d: %zu of %zu lit rows answered", model, answered, lit);
        rec_matcher_free(m);
    }
    free(t);
    free(x);
    free(sg);
    free(ph);
    free(bulb);
    free(ans);
    gs_delight_free(d);
    gs_delight_free(all);
}

/* Continuous phases per pixel against rec_match_light on the same rows (noise sigma 1, every
 * sample kept): the parabolic refinement of the grid and the candidates' cut make the pixel's
 * confidence an approximation. The built-in DELIGHT (RGB, 50 Hz), the paper's model, 2,000 rows
 * (400 under the sanitizers)
 * of random grid templates at a mean sample of 1, 3 and 10 sigma, K = 10 (not dividing the grid:
 * the matrix path) and 13 (the Fourier screen): the same bulb on all but 1 % of the rows, and
 * where both answer the confidence within 0.003 rms and 0.06 at most (docs/recognition.md). */
TEST(eq7_pixels_continuous_confidence_near_the_light_path)
{
    gs_delight *all = NULL, *s = gs_delight_new();
    CHECK_OK(gs_delight_open(NULL, &all));
    for (size_t i = 0; all && i < gs_delight_count(all); i++) {
        const gs_bulb *b = gs_delight_get(all, i);
        if (b->grid_hz == 50 && !strcmp(b->sensor, "rgb") && b->ref == GS_REF_VOLTAGE) CHECK_OK(gs_delight_add(s, b));
    }
    rec_eq7_opts eo;
    rec_eq7_opts_default(&eo);
    eo.band_gains = REC_BANDS_CHROMA;
    eo.model_error = eo.other_prior = eo.flat_share = eo.blend_prior = 0.0;
    eo.nested_tests = 0;
    eo.phases = REC_PHASES_CONTINUOUS;
    static const int Ks[2] = {10, 13};
    static const double snrs[3] = {1, 3, 10};
    enum { PMAX = 2000 };
    const int P = fx_sanitized() ? 400 : PMAX;
    for (int ki = 0; ki < 2; ki++) {
        int K = Ks[ki], D = 3 * K;
        rec_matcher *m = NULL;
        CHECK_OK(rec_matcher_new(s, 50, 3, K, &eo, &m));
        if (!m) continue;
        float *x = malloc(sizeof *x * PMAX * (size_t)D), sg[PMAX], ph[PMAX], cf[PMAX];
        int bulb[PMAX];
        double xd[39], sd[39];
        size_t nt = rec_matcher_template_count(m);
        uint64_t rs = 5;
        for (int si = 0; si < 3 && x; si++) {
            for (int p = 0; p < P; p++) {
                sg[p] = 1.0f;
                const double *t = rec_matcher_template(m, gs_splitmix64(&rs) % nt, NULL, NULL);
                double mean = 0;
                for (int d = 0; d < D; d++) mean += t[d] / D;
                for (int d = 0; d < D; d++) x[(size_t)p * D + d] = (float)(snrs[si] * t[d] / mean + gs_splitmix_normal(&rs));
            }
            CHECK_OK(rec_match_pixels(m, x, sg, (size_t)P, bulb, ph, cf));
            double ss = 0, worst = 0;
            int n = 0, differ = 0;
            for (int p = 0; p < P; p++) {
                for (int d = 0; d < D; d++) {
                    xd[d] = x[(size_t)p * D + d];
                    sd[d] = 1.0;
                }
                rec_match r;
                CHECK_OK(rec_match_light(m, xd, sd, &r));
                if (r.bulb < 0 && bulb[p] < 0) continue;
                if (r.bulb != bulb[p]) {
                    differ++;
                    continue;
                }
                double e = cf[p] - r.confidence;
                ss += e * e;
                worst = fmax(worst, fabs(e));
                n++;
            }
            double rms = sqrt(ss / (n ? n : 1));
            printf("    K %d, mean sample %g sigma: %d answered alike, %d other bulbs, confidence %.5f rms, %.4f at most\n",
                   K, snrs[si], n, differ, rms, worst);
            CHECK_MSG(differ <= P / 100 && rms < 0.003 && worst < 0.06, "K %d, %g sigma: %d differ, %.5f rms, %.4f", K,
                      snrs[si], differ, rms, worst);
        }
        free(x);
        rec_matcher_free(m);
    }
    gs_delight_free(s);
    gs_delight_free(all);
}
