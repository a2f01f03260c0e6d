/* test_eq7_fourier.c - the fast paths of one light (recognize/eq7_light.c): the Fourier form
 * of the continuous-phase grids (every shift's sums S = sum w x t and T = sum w t^2 from one
 * inverse FFT of a cross-spectrum) and the reddened model's bound-based screen, against the
 * brute force they replace: the sums as plain double loops over the matcher's grid templates,
 * and every field of rec_match_light against the same matcher with both off (m->exhaustive:
 * the matrix-vector path and every template's exact likelihood; probabilities within 1e-9 for
 * 90 % of the lights, 1e-4 for all), for K = 13, 22, 26, K not divisible by 3 and a K whose
 * grid it does not divide (no Fourier form then), continuous and discrete phases.
 */
#include "recognize/internal.h"
#include "tests/eq7_fixture.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static rec_matcher *model_matcher(const gs_delight *d, int bands, int K, rec_band_model bg,
                                  rec_phase_set ps, double model_error, int nested)
{
    rec_eq7_opts o;
    rec_eq7_opts_default(&o);
    o.phases = ps;
    o.band_gains = bg;
    o.model_error = model_error;
    o.nested_tests = nested;
    o.threads = 1;
    rec_matcher *m = NULL;
    CHECK_OK(rec_matcher_new(d, 50, bands, K, &o, &m));
    return m;
}

static rec_matcher *phase_matcher(const gs_delight *d, int bands, int K, rec_band_model bg,
                                  rec_phase_set ps)
{
    return model_matcher(d, bands, K, bg, ps, 0.0, 1);
}

/* REC_CX4_MUL in a function cloned as the library's loops are (GS_VECTOR_LOOP: on this CPU its
 * widest clone runs), n a multiple of 4. */
GS_VECTOR_LOOP static void cx4_products(const double *a, const double *x, size_t n, double *p)
{
    for (size_t i = 0; i < n; i += 4) {
        rec_cx4 v;
        REC_CX4_MUL(v, a + 2 * i, x + 2 * i);
        memcpy(p + 2 * i, &v, sizeof v);
    }
}

/* The four complex products of REC_CX4_MUL (cross-spectra, the continuous template's harmonics)
 * are C's products bit for bit (unfused: a fused one differs in the last bits of most), for
 * values of every scale, signed zeros and subnormals among them. */
TEST(eq7_cx4_mul_is_the_complex_product)
{
    enum { N = 4096 };
    static double complex a[N], x[N], p[N];
    uint64_t rs = 29;
    for (size_t i = 0; i < N; i++) {
        double v[4];
        for (int q = 0; q < 4; q++) {
            double u = gs_splitmix_uniform(&rs);
            v[q] = u < 0.05 ? (u < 0.025 ? 0.0 : -0.0) : u < 0.1 ? 1e-310 * gs_splitmix_normal(&rs)
                                                                 : gs_splitmix_normal(&rs) * exp(20.0 * gs_splitmix_normal(&rs));
        }
        memcpy(&a[i], v, sizeof a[i]);   /* (a complex is its real and imaginary parts in order; */
        memcpy(&x[i], v + 2, sizeof x[i]);   /* clang has no CMPLX) */
    }
    cx4_products((const double *)a, (const double *)x, N, (double *)p);
    int differ = 0;
    for (size_t i = 0; i < N; i++) {
        double complex c = a[i] * x[i];
        differ += memcmp(&c, &p[i], sizeof c) != 0;
    }
    CHECK_MSG(differ == 0, "%d of %d products differ from C's", differ, (int)N);
}

/* frac1 (the continuous templates' and series' phase arguments) is fmod(x, 1.0) bit for bit:
 * random bit patterns of every exponent, shifts times harmonics as the series make them, and
 * zeros, integers, halves, huge and subnormal values of both signs. */
TEST(eq7_frac1_is_fmod)
{
    static const double special[] = {0.0, -0.0, 1.0, -1.0, 2.5, -2.5, 1e300, -1e300, 0x1p52, 0x1p53 + 2.0,
                                     3e-310, -3e-310, 0.999999999999, -0.999999999999};
    int differ = 0;
    for (size_t i = 0; i < sizeof special / sizeof *special; i++) {
        double a = fmod(special[i], 1.0), b = frac1(special[i]);
        differ += memcmp(&a, &b, sizeof a) != 0;
    }
    uint64_t rs = 31;
    for (int i = 0; i < 1000000; i++) {
        uint64_t u = gs_splitmix64(&rs);
        double x, y = (double)(i % 1024) * gs_splitmix_uniform(&rs);
        memcpy(&x, &u, sizeof x);
        if (!isfinite(x)) continue;
        double a = fmod(x, 1.0), b = frac1(x), c = fmod(y, 1.0), d = frac1(y);
        differ += memcmp(&a, &b, sizeof a) != 0;
        differ += memcmp(&c, &d, sizeof c) != 0;
    }
    CHECK_MSG(differ == 0, "%d values differ from fmod's", differ);
}

/* The sums of every grid template from the FFT against sum_d over the templates themselves,
 * for random positive weights, and any values' sums with the grids (rec_eq7_grid_dots, the
 * nested tests' cross sums): within 1e-12 of sum |w x t| (the rounding of either). */
TEST(eq7_fourier_sums_match_brute_force)
{
    static const int Ks[] = {4, 8, 13, 16, 22, 26};
    uint64_t rs = 17;
    for (int bands = 1; bands <= 3; bands += 2) {
        gs_delight *d = eq7fx_make_db(50, bands, 0, 0);
        for (int bg = 0; bg < (bands == 3 ? 2 : 1); bg++)
            for (size_t ki = 0; ki < sizeof Ks / sizeof *Ks; ki++) {
                int K = Ks[ki];
                rec_matcher *m = phase_matcher(d, bands, K, bg ? REC_BANDS_FREE : REC_BANDS_CHROMA, REC_PHASES_CONTINUOUS);
                if (!m) continue;
                CHECK_MSG(m->fourier, "K = %d, G = %d: expected the Fourier form", K, m->G);
                rec_eq7_work w;
                CHECK_OK(rec_eq7_work_alloc(m, &w));
                size_t D = (size_t)m->D, M = m->M, span = m->bg ? (size_t)K : D;
                for (size_t d0 = 0; d0 < D; d0++) {
                    w.w[d0] = 0.2 + gs_splitmix_uniform(&rs);
                    w.wx[d0] = w.w[d0] * (1.0 + 3.0 * gs_splitmix_normal(&rs));
                }
                rec_eq7_light_dfts(m, &w);
                double worst = 0.0;
                for (size_t b = 0; b < m->nb; b++) {
                    rec_eq7_grid_sums(m, &w, b);
                    for (size_t j = m->first[b]; j < m->first[b] + m->count[b]; j++) {
                        const double *t = rec_matcher_template(m, j, NULL, NULL);
                        for (int f = 0; f < m->nfit; f++) {
                            double S = 0, T = 0, Sa = 0, Ta = 0;
                            for (size_t q = (size_t)f * span; q < (size_t)(f + 1) * span; q++) {
                                S += w.wx[q] * t[q];
                                Sa += fabs(w.wx[q] * t[q]);
                                T += w.w[q] * t[q] * t[q];
                                Ta += w.w[q] * t[q] * t[q];
                            }
                            double eS = fabs(w.S[(size_t)f * M + j] - S) / Sa;
                            double eT = fabs(w.T[(size_t)f * M + j] - T) / Ta;
                            worst = fmax(worst, fmax(eS, eT));
                        }
                    }
                }
                CHECK_MSG(worst < 1e-12, "bands %d gains %d K %d: worst relative error %g", bands, bg, K, worst);
                /* any values' sums with the grids (the nested tests' cross sums): rec_eq7_grid_dots */
                double *v = malloc(sizeof *v * D), *g = malloc(sizeof *g * (size_t)m->G), wd = 0.0;
                for (size_t d0 = 0; d0 < D; d0++) v[d0] = gs_splitmix_normal(&rs);
                rec_eq7_band_dfts(m, v, w.spec_v);
                for (size_t b = 0; b < m->nb; b++)
                    for (int f = 0; f < m->nfit; f++) {
                        rec_eq7_grid_dots(m, &w, b, f, w.spec_v, g);
                        for (size_t c = 0; c < m->count[b]; c++) {
                            const double *t = rec_matcher_template(m, m->first[b] + c, NULL, NULL);
                            double S = 0, Sa = 0;
                            for (size_t q = (size_t)f * span; q < (size_t)(f + 1) * span; q++) {
                                S += v[q] * t[q];
                                Sa += fabs(v[q] * t[q]);
                            }
                            wd = fmax(wd, fabs(g[c] - S) / Sa);
                        }
                    }
                CHECK_MSG(wd < 1e-12, "bands %d gains %d K %d: grid dots' worst relative error %g", bands, bg, K, wd);
                free(v);
                free(g);
                rec_eq7_work_free(&w);
                rec_matcher_free(m);
            }
        gs_delight_free(d);
    }
    /* K = 10: the grid of 96 cells is not a multiple of K, no Fourier form */
    gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
    rec_matcher *m = phase_matcher(d, 3, 10, REC_BANDS_CHROMA, REC_PHASES_CONTINUOUS);
    CHECK(m && !m->fourier);
    rec_matcher_free(m);
    gs_delight_free(d);
}

/* The refinement's series (eq7_series.c: S, T and their first two derivatives at any shift from
 * the row's K-point DFTs and the tabulated harmonics of t and t^2) against the same sums over
 * rec_eq7_template_at's window means and derivatives (the harmonic fold and inverse DFTs, the
 * Nyquist term in closed form), for random weights and shifts: the built-in DELIGHT (sharp
 * waveforms: 500 harmonics and a Nyquist term) and the smooth test bulbs, K = 8, 13 (odd), 10
 * (no Fourier grid), 26, one band and RGB, one brightness and one per band. Each sum within
 * 1e-11 of its scale: the weights' absolute sum times the largest value the summed function
 * can take, from its harmonics' magnitudes (either method's rounding is relative to that). */
TEST(eq7_series_sums_match_templates)
{
    static const int Ks[] = {8, 10, 13, 26};
    uint64_t rs = 23;
    gs_delight *gen = gs_delight_new();
    CHECK_OK(gs_delight_generate(gen, GS_BRF_N_DEFAULT));
    double worst = 0.0;
    int sharp = 0;
    for (int db = 0; db < 2; db++)
        for (int bands = 1; bands <= 3; bands += 2) {
            gs_delight *d = db ? eq7fx_make_db(50, bands, 0, 0) : gen;
            for (int bg = 0; bg < (bands == 3 ? 2 : 1); bg++)
                for (size_t ki = 0; ki < sizeof Ks / sizeof *Ks; ki++) {
                    int K = Ks[ki];
                    rec_matcher *m = phase_matcher(d, bands, K, bg ? REC_BANDS_FREE : REC_BANDS_CHROMA,
                                                   REC_PHASES_CONTINUOUS);
                    if (!m) continue;
                    rec_eq7_work w;
                    CHECK_OK(rec_eq7_work_alloc(m, &w));
                    size_t D = (size_t)m->D, span = m->bg ? (size_t)K : D;
                    double *t = malloc(sizeof *t * 3 * D), *t1 = t + D, *t2 = t1 + D;
                    for (size_t b = 0; b < m->nb; b += db ? 1 : 7) {
                        sharp += m->rs_h[b] == m->nfine[b] / 2;
                        for (size_t q = 0; q < D; q++) {
                            w.w[q] = 0.2 + gs_splitmix_uniform(&rs);
                            w.wx[q] = w.w[q] * (1.0 + 3.0 * gs_splitmix_normal(&rs));
                        }
                        /* (the row's DFTs taken here, or from rec_eq7_light_dfts' as the light path) */
                        if (b % 2) rec_eq7_light_dfts(m, &w);
                        rec_eq7_series_row(m, &w, (int)(b % 2));
                        rec_eq7_series_bulb(m, &w, b);
                        for (int trial = 0; trial < 4; trial++) {
                            double sh = trial == 0 ? 0.0 : trial == 1 ? nextafter(1.0, 0.0) : gs_splitmix_uniform(&rs);
                            double v[6][GS_MAX_BANDS];
                            rec_eq7_series_at(m, &w, b, sh, v[0], v[1], v[2], v[3], v[4], v[5]);
                            rec_eq7_template_at(m, b, sh, t, t1, t2, w.acc);
                            for (int f = 0; f < m->nfit; f++) {
                                /* the scale of each sum: its weights' absolute sum times the largest
                                 * value of the function summed (t, its derivatives, t^2 and
                                 * its), from the harmonics' magnitudes M_i = sum (2 pi h)^i |A_h| */
                                double ref[6] = {0}, sw = 0.0, sx = 0.0, Mi[3] = {0};
                                for (size_t q = (size_t)f * span; q < (size_t)(f + 1) * span; q++) {
                                    double terms[6] = {w.wx[q] * t[q], w.wx[q] * t1[q], w.wx[q] * t2[q], w.w[q] * t[q] * t[q],
                                                       2.0 * w.w[q] * t[q] * t1[q], 2.0 * w.w[q] * (t1[q] * t1[q] + t[q] * t2[q])};
                                    for (int i = 0; i < 6; i++) ref[i] += terms[i];
                                    sw += w.w[q];
                                    sx += fabs(w.wx[q]);
                                }
                                int b0 = m->nfit == 1 ? 0 : f, b1 = m->nfit == 1 ? bands : f + 1;
                                for (int band = b0; band < b1; band++) {
                                    const double complex *F = m->F[b] + (size_t)band * (size_t)(m->H[b] + 1);
                                    double nyq = fabs(m->nyq[b * (size_t)bands + (size_t)band]) * 2.0 * K / (M_PI * m->nfine[b]);
                                    for (int h = 0; h <= m->H[b] + 1; h++) {
                                        double a = h <= m->H[b] ? cabs(F[h]) : nyq, wh = 2.0 * M_PI * (h <= m->H[b] ? h : m->nfine[b] / 2);
                                        Mi[0] += a, Mi[1] += wh * a, Mi[2] += wh * wh * a;
                                    }
                                }
                                double scale[6] = {sx * Mi[0], sx * Mi[1], sx * Mi[2], sw * Mi[0] * Mi[0], 2.0 * sw * Mi[0] * Mi[1],
                                                   2.0 * sw * (Mi[1] * Mi[1] + Mi[0] * Mi[2])};
                                for (int i = 0; i < 6; i++) {
                                    double e = fabs(v[i][f] - ref[i]) / scale[i];
                                    CHECK_MSG(e < 1e-11, "db %d bands %d gains %d K %d bulb %zu s %.17g sum %d: %.17g, "
                                              "templates %.17g (scale %g)", db, bands, bg, K, b, sh, i, v[i][f], ref[i], scale[i]);
                                    worst = fmax(worst, e);
                                }
                            }
                        }
                    }
                    free(t);
                    rec_eq7_work_free(&w);
                    rec_matcher_free(m);
                }
            if (db) gs_delight_free(d);
        }
    gs_delight_free(gen);
    CHECK_MSG(sharp > 0, "no bulb with a Nyquist harmonic");
    printf("    series against the templates' sums: worst relative error %.2g (%d bulbs with a Nyquist term)\n",
           worst, sharp);
}

static int close_to(double a, double b, double abs_tol, double rel_tol)
{
    return fabs(a - b) <= abs_tol + rel_tol * fmax(fabs(a), fabs(b));
}

/* Every answer of rec_match_light with the fast paths equals the exhaustive path's within the
 * stated tolerance: the same bulb, blend bulbs and flags, the same runner-up unless both give it
 * a posterior below 1e-9; phases within 1e-6 deg,
 * brightness and chi2 within 1e-9 relative; probabilities and the phase sigma within 1e-9 for
 * at least 90 % of the lights and 1e-4 for every light. Matchers: the three band models with
 * continuous phases; the reddened model with 3 and 6 phases; every band model with 3 phases and
 * an excess noise of 5 % (the scores tempered: the screen widens its cut), the nested tests on
 * and off. */
TEST(eq7_fourier_answers_match_slow_path)
{
    static const int Ks[] = {8, 13, 16, 22, 26};
    static const rec_band_model models[] = {REC_BANDS_CHROMA, REC_BANDS_FREE, REC_BANDS_REDDENED};
    uint64_t rs = 99;
    gs_delight *d = eq7fx_make_db(50, 3, 1, 0);
    int lights = 0, ntight = 0;
    /* models 0-2 continuous, 3-4 the reddened model with 3 and 6 discrete phases, 5-10 each band
     * model with 3 phases and an excess (5-7 the nested tests on, 8-10 off), 11-12 one brightness
     * and free band gains, continuous, with an excess (the screen of bulbs widens its cut) */
    const size_t NM = 13;
    for (size_t mi = 0; mi < NM; mi++)
        for (size_t ki = 0; ki < sizeof Ks / sizeof *Ks; ki++) {
            int K = Ks[ki];
            rec_phase_set ps = mi < 3 || mi > 10 ? REC_PHASES_CONTINUOUS : mi == 4 ? REC_PHASES_6 : REC_PHASES_3;
            rec_band_model bm = mi < 3 ? models[mi] : mi < 5 ? REC_BANDS_REDDENED : models[(mi - 5) % 3];
            rec_matcher *m = model_matcher(d, 3, K, bm, ps, mi < 5 ? 0.0 : 0.05, mi < 8);
            if (!m) continue;
            CHECK(m->fourier == (mi < 3 || mi > 10));
            size_t D = (size_t)m->D;
            double *x = malloc(sizeof *x * D), *sg = malloc(sizeof *sg * D);
            for (int i = 0; i < 12; i++) {
                size_t b = gs_splitmix64(&rs) % m->nb;
                double a = i < 4 ? 3.0 : i < 8 ? 30.0 : 400.0;   /* dim, medium, bright */
                eq7fx_render(rec_matcher_bulb(m, b), gs_splitmix_uniform(&rs), K, a, 1.0, &rs, x, sg);
                for (size_t q = 0; q < D; q++) sg[q] *= 0.5 + gs_splitmix_uniform(&rs);
                rec_match f, s;
                CHECK_OK(rec_match_light(m, x, sg, &f));
                m->exhaustive = 1;
                CHECK_OK(rec_match_light(m, x, sg, &s));
                m->exhaustive = 0;
                /* the screen may rank runner-ups of posterior < 1e-9 differently */
                int runner = f.runner_bulb == s.runner_bulb || (f.runner_confidence < 1e-9 && s.runner_confidence < 1e-9);
                int same = f.bulb == s.bulb && runner && f.flags == s.flags &&
                           f.blend_bulb[0] == s.blend_bulb[0] && f.blend_bulb[1] == s.blend_bulb[1];
                double dph = fabs(fmod(f.phase_deg - s.phase_deg + 540.0, 360.0) - 180.0);
                double drp = f.runner_bulb != s.runner_bulb ? 0.0 :
                             fabs(fmod(f.runner_phase_deg - s.runner_phase_deg + 540.0, 360.0) - 180.0);
                /* tight: 1e-9; loose: 1e-4 for the probabilities, when the best grid cell flips
                 * between two cells of equal likelihood (rounding decides; the posterior's cell
                 * integration differs by its own error) */
                int tight = 1, loose = 1;
                for (int tier = 0; tier < 2; tier++) {
                    double pt = tier ? 1e-4 : 1e-9;
                    int ok = dph < 1e-6 && drp < 1e-6 && close_to(f.phase_sigma_deg, s.phase_sigma_deg, 1e-12, pt) &&
                             close_to(f.confidence, s.confidence, pt, 0) &&
                             close_to(f.bulb_confidence, s.bulb_confidence, pt, 0) &&
                             close_to(f.phase_confidence, s.phase_confidence, pt, 0) &&
                             close_to(f.runner_confidence, s.runner_confidence, pt, 0) &&
                             close_to(f.p_value, s.p_value, 1e-9, 0) &&
                             close_to(f.shape_p_value, s.shape_p_value, 1e-9, 0) &&
                             close_to(f.blend_p_value, s.blend_p_value, pt, 0) &&
                             close_to(f.p_other, s.p_other, 1e-9, 0) && close_to(f.p_blend, s.p_blend, pt, 0) &&
                             close_to(f.brightness, s.brightness, 1e-12, 1e-9) && close_to(f.chi2, s.chi2, 1e-9, 1e-9);
                    if (tier) loose = ok;
                    else tight = ok;
                }
                CHECK_MSG(same && loose, "model %zu K %d light %d: bulb %d/%d phase %.9f/%.9f sigma %g/%g "
                          "conf %.12f/%.12f flags %u/%u", mi, K, i, f.bulb, s.bulb, f.phase_deg, s.phase_deg,
                          f.phase_sigma_deg, s.phase_sigma_deg, f.confidence, s.confidence, f.flags, s.flags);
                ntight += same && tight;
                lights++;
            }
            free(x);
            free(sg);
            rec_matcher_free(m);
        }
    CHECK(lights == (int)NM * 5 * 12);
    CHECK_MSG(ntight >= lights * 9 / 10, "%d of %d lights within 1e-9", ntight, lights);
    gs_delight_free(d);
}

/* The screen with an excess noise: the scores are tempered by kappa < 1 about the best, so a
 * template d nats below it comes kappa d below; every template that tempering brings within
 * the screen's cut must have its exact score (rec_eq7_screen_widen), as in the exhaustive path.
 * Bright lights of 5 bulbs at 3 phases with a 10 % excess (kappa about 0.3), the nested tests off
 * (their first templates would be the whole bank of 15): the fast path's tempered scores against
 * the exhaustive path's, template by template (it fails without the widened cut). */
TEST(eq7_screen_keeps_what_tempering_brings_within_the_cut)
{
    uint64_t rs = 7;
    gs_delight *d = eq7fx_make_db(50, 3, 0, 0);
    int widened = 0;
    for (int bm = 0; bm < 3; bm++) {
        rec_matcher *m = model_matcher(d, 3, 26, (rec_band_model)bm, REC_PHASES_3, 0.1, 0);
        size_t D = (size_t)m->D, M = m->M;
        double *x = malloc(sizeof *x * D), *sg = malloc(sizeof *sg * D), *Lf = malloc(sizeof *Lf * M);
        unsigned char *df = malloc(M);
        rec_eq7_work w;
        CHECK_OK(rec_eq7_work_alloc(m, &w));
        for (int i = 0; i < 40; i++) {
            size_t b = gs_splitmix64(&rs) % m->nb;
            eq7fx_render(rec_matcher_bulb(m, b), gs_phase_to_shift(eq7fx_p3[i % 3]), 26, 60.0 + 10.0 * i, 1.0, &rs, x, sg);
            rec_match f, s;
            CHECK_OK(rec_eq7_match_light_ws(m, &w, x, sg, 0.1, &f, NULL));
            memcpy(Lf, w.L, sizeof *Lf * M);
            memcpy(df, w.done, M);
            m->exhaustive = 1;
            CHECK_OK(rec_eq7_match_light_ws(m, &w, x, sg, 0.1, &s, NULL));
            m->exhaustive = 0;
            double Lmax = -INFINITY;
            for (size_t j = 0; j < M; j++) Lmax = fmax(Lmax, w.L[j]);
            for (size_t j = 0; j < M; j++) {
                if (!(w.L[j] >= Lmax - CUT_PIXEL)) continue;
                CHECK_MSG(df[j] && close_to(Lf[j], w.L[j], 1e-9, 1e-9), "model %d light %d template %zu: tempered "
                          "score %.9f, the fast path's %.9f (exact %d)", bm, i, j, w.L[j], Lf[j], df[j]);
                widened += Lmax - w.L[j] > 0.5 * CUT_PIXEL;
            }
        }
        rec_eq7_work_free(&w);
        free(x), free(sg), free(Lf), free(df);
        rec_matcher_free(m);
    }
    printf("    templates brought within the cut by tempering, beyond half of it: %d\n", widened);
    CHECK(widened > 0);
    gs_delight_free(d);
}

/* The screen's bounds are upper bounds of the exact scores: for every template the fast path
 * did not score, its bound is at least its exact score from the same sums (rec_eq7_loglik_fit),
 * and the answers are the exhaustive path's (bulb and flags; the confidence within 1e-9, or
 * 1e-4 for a continuous bank, whose Fourier sums round otherwise). Lights with samples
 * dropped (sigma = +inf: saturated frames, 2 to 13 of the 26 per band, or a whole band), whose
 * sums cover fewer samples than the templates' norms (the bound from the norms is not valid
 * there: it missed templates within the cut), every band model, 3 and continuous phases; and
 * noise alone with every sample (a mean below zero lowers a closed bulb's bound). A continuous
 * bulb the screen of bulbs left closed: every cell's exact L against the bulb's bound. */
TEST(eq7_screen_bounds_hold_with_dropped_samples)
{
    uint64_t rs = 41;
    gs_delight *d = eq7fx_make_db(50, 3, 1, 0);
    gs_delight *g = gs_delight_new();
    CHECK_OK(gs_delight_generate(g, 1024));
    int checked = 0, dropped_lights = 0, closed_bulbs = 0;
    for (int db = 0; db < 2; db++)
        for (int bm = 0; bm < 3; bm++)
            for (int cont = 0; cont < 2; cont++) {
                rec_matcher *m = model_matcher(db ? g : d, 3, 26, (rec_band_model)bm,
                                               cont ? REC_PHASES_CONTINUOUS : REC_PHASES_3, 0.0, 0);
                size_t D = (size_t)m->D, M = m->M;
                double *x = malloc(sizeof *x * D), *sg = malloc(sizeof *sg * D), *Uf = malloc(sizeof *Uf * M);
                unsigned char *df = malloc(M);
                rec_eq7_work w;
                CHECK_OK(rec_eq7_work_alloc(m, &w));
                for (int i = 0; i < 12; i++) {
                    size_t b = gs_splitmix64(&rs) % m->nb;
                    eq7fx_render(rec_matcher_bulb(m, b), gs_splitmix_uniform(&rs), 26, i < 2 ? 0.0 : i < 6 ? 20.0 : 300.0, 1.0,
                                 &rs, x, sg);
                    for (size_t q = 0; q < D; q++) sg[q] *= 0.5 + gs_splitmix_uniform(&rs);
                    /* a run of dropped frames in every band, or a whole band */
                    int run = 2 + (int)(gs_splitmix64(&rs) % 12), k0 = (int)(gs_splitmix64(&rs) % 26);
                    if (i < 2) run = 0;   /* noise alone: every sample */
                    for (int band = 0; band < 3; band++)
                        for (int k = 0; k < (i == 11 && band == 2 ? 26 : run); k++) sg[band * 26 + (k0 + k) % 26] = INFINITY;
                    dropped_lights += run > 0;
                    rec_match f, s;
                    CHECK_OK(rec_eq7_match_light_ws(m, &w, x, sg, 0.0, &f, NULL));
                    memcpy(Uf, w.U, sizeof *Uf * M);
                    memcpy(df, w.done, M);
                    /* a bulb the screen of bulbs left closed: its grids now, its cells against its
                     * bulb's bound */
                    int closed = 0;
                    if (m->bs_on) rec_eq7_light_dfts(m, &w);
                    for (size_t c = 0; m->bs_on && c < m->nb; c++) {
                        if (!m->cont[c] || w.open[c]) continue;
                        rec_eq7_grid_sums(m, &w, c);
                        for (size_t j = m->first[c]; j < m->first[c] + m->count[c]; j++) Uf[j] = w.bub[c];
                        closed++;
                    }
                    closed_bulbs += closed;
                    for (size_t j = 0; j < M; j++) {
                        if (df[j]) continue;
                        double L = rec_eq7_loglik_fit(m, &w, j, w.prep[0].Sxx);
                        if (!isfinite(L)) continue;
                        checked++;
                        CHECK_MSG(Uf[j] >= L, "db %d model %d cont %d light %d template %zu: bound %.9f below "
                                  "the exact score %.9f", db, bm, cont, i, j, Uf[j], L);
                    }
                    m->exhaustive = 1;
                    CHECK_OK(rec_eq7_match_light_ws(m, &w, x, sg, 0.0, &s, NULL));
                    m->exhaustive = 0;
                    CHECK_MSG(f.bulb == s.bulb && f.flags == s.flags && close_to(f.confidence, s.confidence, cont ? 1e-4 : 1e-9, 0),
                              "db %d model %d cont %d light %d: bulb %d/%d flags %u/%u confidence %.12f/%.12f", db,
                              bm, cont, i, f.bulb, s.bulb, f.flags, s.flags, f.confidence, s.confidence);
                }
                rec_eq7_work_free(&w);
                free(x), free(sg), free(Uf), free(df);
                rec_matcher_free(m);
            }
    printf("    %d lights with dropped samples, %d templates left unscored checked against their bounds (%d "
           "continuous bulbs' grids left closed)\n", dropped_lights, checked, closed_bulbs);
    CHECK(checked > 1000);
    CHECK(closed_bulbs > 0);
    gs_delight_free(g);
    gs_delight_free(d);
}

/* The coupled bound's search over mu (eq7_bulbscreen.c, rec_eq7_coupled_gain) against its own
 * function on a grid of 10,001 mu: at least the grid's largest value (a bound), and within 1e-4
 * of it when refined as far as it goes (the chords close in), or below a stop it proves. Random
 * cross-spectra (np 8 and 16; one in 10 beyond DBL_MAX once squared, one in 15 with T's
 * constant near DBL_MAX), signed constants and tails, T's bound from its harmonics or from
 * w_min |t|^2 alone (h then rises with mu) or both. Where h overflows only the bound's
 * validity is checked (its w_min |t|^2 term alone, or +inf). */
TEST(eq7_coupled_gain_bounds_its_function)
{
    uint64_t rs = 4242;
    int checked = 0, proved = 0, rising = 0, overflowed = 0;
    for (int trial = 0; trial < 1500; trial++) {
        size_t np = trial % 2 ? 16 : 8;
        double z[64], sum_s = 0.0, sum_t = 0.0;
        /* (one trial in 10 beyond DBL_MAX once squared: h overflows, only w_min |t|^2 bounds) */
        double scale = trial % 10 == 9 ? 1e160 : 1.0;
        for (size_t n = 0; n < 4 * np; n++) z[n] = scale * gs_splitmix_normal(&rs) * (n >= 2 * np ? 0.3 : 1.0);
        z[np] = z[3 * np] = 0.0;   /* the constant terms: real */
        for (size_t n = 1; n < np; n++) {
            sum_s += hypot(z[n], z[np + n]);
            sum_t += hypot(z[2 * np + n], z[3 * np + n]);
        }
        rec_eq7_bulb_terms t;
        t.tail_s = fabs(gs_splitmix_normal(&rs));
        t.tail_t = 0.3 * fabs(gs_splitmix_normal(&rs));
        t.cs = z[0] = 3.0 * gs_splitmix_normal(&rs);
        /* T's constant: its harmonic bound positive, or not (then only w_min |t|^2 bounds it) */
        int mode = trial % 3;
        t.ct = z[2 * np] = (mode == 1 ? 0.5 : 1.5 + gs_splitmix_uniform(&rs)) * (sum_t + t.tail_t);
        if (trial % 10 == 4 && mode != 1) t.ct = z[2 * np] = (0.5 + 0.3 * gs_splitmix_uniform(&rs)) * 1e308;   /* (T's constant near DBL_MAX) */
        t.es = fabs(t.cs) + sum_s + t.tail_s;
        t.et = fabs(t.ct) + sum_t + t.tail_t;
        t.sb = t.es - fabs(t.cs) + t.cs + 1e-9 * t.es;
        t.tb = t.ct - (t.et - fabs(t.ct)) - 1e-9 * t.et;
        t.tw = mode == 0 ? 0.0 : (0.2 + gs_splitmix_uniform(&rs)) * t.ct;
        t.tb = t.tw > t.tb ? t.tw : t.tb;
        if (!(t.sb > 0.0) || !(t.tb > 0.0)) continue;
        rising += mode == 1;
        /* the function searched: min(4 mu h(mu), 4 mu (sb - mu tw)) on [0, sb / (2 tb)] */
        double best = 0.0, mu_n = 0.5 * t.sb / t.tb;
        for (int i = 0; i <= 10000; i++) {
            double mu = mu_n * i / 10000.0, h = t.cs + t.tail_s - mu * (t.ct - t.tail_t) + 1e-9 * (t.es + mu * t.et);
            for (size_t n = 1; n < np; n++) h += hypot(z[n] - mu * z[2 * np + n], z[np + n] - mu * z[3 * np + n]);
            double v = 4.0 * mu * h, vw = t.tw > 0.0 ? 4.0 * mu * (t.sb - mu * t.tw) : INFINITY;
            v = vw < v ? vw : v;
            best = v > best ? v : best;
        }
        double tight = rec_eq7_coupled_gain(z, np, &t, NAN), stop = 1.5 * best + 1e-300;
        double early = rec_eq7_coupled_gain(z, np, &t, stop);
        CHECK_MSG(tight >= best * (1.0 - 1e-12) && early >= best * (1.0 - 1e-12),
                  "trial %d: bound %.17g (stopped at %g: %.17g) below the function's %.17g", trial, tight, stop, early, best);
        if (scale == 1.0) {   /* (where h overflows, its tw bound alone: no closer) */
            CHECK_MSG(tight <= best * (1.0 + 1e-4) + 1e-300, "trial %d: bound %.17g, function's largest %.17g", trial, tight, best);
            CHECK_MSG(early < stop, "trial %d: bound %.17g not below %.17g (tight %.17g)", trial, early, stop, tight);
        }
        proved += early > tight;
        overflowed += scale > 1.0 && isfinite(tight);
        checked++;
    }
    printf("    %d searches (%d with h rising), %d stopped early below their stop, %d finite where h overflows\n",
           checked, rising, proved, overflowed);
    CHECK(checked > 750 && rising > 250 && proved > 100 && overflowed > 50);
}

/* The screen of bulbs (eq7_bulbscreen.c): every continuous bulb's bound, open or closed, is at
 * least the exact L of each of its grid cells (from its grids, computed here for every bulb).
 * Lights: noise alone, its negative (a mean below zero: the signed constant term), dim, bright,
 * 1e6 sigma, a run of dropped samples, a whole band dropped, sigmas over 3 decades, a positive
 * and a negative offset, bright with sigmas over 3x (the coupled bound's case), 1e128 with
 * sigmas over 10 decades (sums beyond DBL_MAX: no coupled bound); equal sigmas otherwise (where
 * w_min |t|^2 is T's bound); K = 4 to 26, both databases, one brightness and free band gains.
 * (Noise and lights below zero close no bulb, every one within the cut, but their bounds are
 * checked all the same.) */
TEST(eq7_bulb_bounds_hold)
{
    static const int Ks[] = {4, 8, 13, 26};
    enum { KINDS = 12 };
    uint64_t rs = 12345;
    gs_delight *d = eq7fx_make_db(50, 3, 1, 0), *g = gs_delight_new();
    CHECK_OK(gs_delight_generate(g, 300));
    long checked = 0, closed[KINDS] = {0}, tighter[KINDS] = {0}, refined[KINDS] = {0}, bulbs[KINDS] = {0};
    for (int db = 0; db < 2; db++)
        for (int bm = 0; bm < 2; bm++)
            for (size_t ki = 0; ki < sizeof Ks / sizeof *Ks; ki++) {
                int K = Ks[ki];
                rec_matcher *m = model_matcher(db ? g : d, 3, K, bm ? REC_BANDS_FREE : REC_BANDS_CHROMA,
                                               REC_PHASES_CONTINUOUS, 0.0, 0);
                CHECK_MSG(m->bs_on, "K = %d: expected the screen of bulbs", K);
                size_t D = (size_t)m->D;
                double *x = malloc(sizeof *x * D), *sg = malloc(sizeof *sg * D);
                double *first = malloc(sizeof *first * m->nb), *tight = malloc(sizeof *tight * m->nb);
                rec_eq7_work w;
                CHECK_OK(rec_eq7_work_alloc(m, &w));
                for (int i = 0; i < 48; i++) {
                    int kind = i % KINDS;
                    double a = kind <= 1 ? 0.0 : kind == 3 || kind == 10 ? 3000.0 : kind == 9 ? 1e6 : kind == 11 ? 1e128 : 30.0;
                    eq7fx_render(rec_matcher_bulb(m, gs_splitmix64(&rs) % m->nb), gs_splitmix_uniform(&rs), K, a, 1.0,
                                 &rs, x, sg);
                    for (size_t q = 0; q < D; q++) {
                        x[q] = kind == 1 ? -x[q] - 0.5 : kind == 7 ? x[q] + 50.0 : kind == 8 ? x[q] - 50.0 - 0.2 * a : x[q];
                        if (kind == 6) sg[q] *= pow(10.0, 3.0 * gs_splitmix_uniform(&rs));
                        if (kind == 10) sg[q] *= 0.5 + gs_splitmix_uniform(&rs);   /* (the noise as drawn: 1) */
                        if (kind == 11) sg[q] *= pow(10.0, 10.0 * gs_splitmix_uniform(&rs));   /* sums beyond DBL_MAX */
                    }
                    int run = kind == 4 ? 1 + (int)(gs_splitmix64(&rs) % (uint64_t)(K - 1)) : 0, k0 = (int)(gs_splitmix64(&rs) % (uint64_t)K);
                    for (int band = 0; band < 3; band++)
                        for (int k = 0; k < (kind == 5 && band == 2 ? K : run); k++) sg[band * K + (k0 + k) % K] = INFINITY;
                    rec_match f;
                    CHECK_OK(rec_eq7_match_light_ws(m, &w, x, sg, 0.0, &f, NULL));
                    if (!w.prep[0].used) continue;
                    /* each bulb's first bound, and its coupled bound as tight as it gets */
                    double Sxx = w.prep[0].Sxx;
                    rec_eq7_light_dfts(m, &w);
                    rec_eq7_bulb_bounds(m, &w, &w.prep[0], Sxx, first);
                    for (size_t b = 0; b < m->nb; b++) {
                        closed[kind] += !w.open[b];
                        double screened = w.bub[b];
                        w.bub[b] = first[b];
                        tight[b] = rec_eq7_bulb_tighten(m, &w, &w.prep[0], Sxx, b, -INFINITY);
                        double chord = rec_eq7_bulb_tighten(m, &w, &w.prep[0], Sxx, b, INFINITY);
                        w.bub[b] = screened;
                        CHECK(tight[b] <= chord && chord <= first[b]);
                        tighter[kind] += tight[b] < first[b] - 1.0;
                        refined[kind] += tight[b] < chord - 1.0;
                        bulbs[kind]++;
                    }
                    for (size_t b = 0; b < m->nb; b++) {
                        rec_eq7_grid_sums(m, &w, b);
                        for (size_t j = m->first[b]; j < m->first[b] + m->count[b]; j++) {
                            double L = rec_eq7_loglik_fit(m, &w, j, Sxx);
                            if (!isfinite(L)) continue;
                            checked++;
                            CHECK_MSG(w.bub[b] >= L && tight[b] >= L, "db %d model %d K %d light %d (kind %d) bulb %zu "
                                      "cell %zu: bound %.12g (coupled %.12g) below the exact score %.12g", db, bm, K, i,
                                      kind, b, j - m->first[b], w.bub[b], tight[b], L);
                        }
                    }
                }
                rec_eq7_work_free(&w);
                free(x), free(sg), free(first), free(tight);
                rec_matcher_free(m);
            }
    long nclosed = 0;
    printf("    %ld cells checked against their bulbs' bounds; bulbs left closed per kind of light:", checked);
    for (int k = 0; k < KINDS; k++) printf(" %ld", closed[k]), nclosed += closed[k];
    printf("\n    coupled bounds more than 1 nat below the first (and below the first chord), per kind:");
    for (int k = 0; k < KINDS; k++) printf(" %ld/%ld (%ld)", tighter[k], bulbs[k], refined[k]);
    printf("\n");
    CHECK(nclosed > 1000);
    CHECK(tighter[10] > bulbs[10] / 4);   /* weights unequal: the coupled bound is the tighter */
    CHECK(refined[10] > bulbs[10] / 8);   /* and refined beyond its first chord */
    gs_delight_free(g);
    gs_delight_free(d);
}

/* The float sums' screen (eq7_sums.c, m->fsums: the paper's model, D >= 64): every template it
 * left unscored has a float bound at least its exact score from plain double sums of the
 * light's weights, and the answers are the exhaustive path's. Hard cases: noise alone (sums of
 * either sign), dim to very bright lights (Sxx to 1e33; with an excess noise their weights are
 * ~1e-30, whose absolute float error alone would make T's bound <= 0), sample sigmas over 6
 * decades, dropped samples (sigma = +inf, NaN signal), one sigma 1e9 and one 1e25 times below
 * the others (weights 1e50 apart: subnormal in float), a weight near DBL_MAX (the row's scale
 * clamped to 2^-1000); RGB K = 22 and 26, one band K = 64,
 * without and with an excess. */
TEST(eq7_float_sums_bounds_hold)
{
    uint64_t rs = 47;
    gs_delight *g = gs_delight_new();
    CHECK_OK(gs_delight_generate(g, 1024));
    static const int shapes[][2] = {{3, 22}, {3, 26}, {1, 64}};
    static const double amp[] = {0.0, 3.0, 30.0, 1e3, 1e6, 1e16};
    size_t checked = 0, exact_n = 0, total = 0;
    for (int si = 0; si < 3; si++)
        for (int ex = 0; ex < 2; ex++) {
            int bands = shapes[si][0], K = shapes[si][1];
            rec_matcher *m = model_matcher(g, bands, K, REC_BANDS_CHROMA, REC_PHASES_3, 0.0, 0);
            CHECK(m->fsums);
            size_t D = (size_t)m->D, M = m->M;
            double *x = malloc(sizeof *x * D), *sg = malloc(sizeof *sg * D);
            rec_eq7_work w;
            CHECK_OK(rec_eq7_work_alloc(m, &w));
            for (int i = 0; i < 18; i++) {
                size_t b = gs_splitmix64(&rs) % m->nb;
                eq7fx_render(rec_matcher_bulb(m, b), gs_splitmix_uniform(&rs), K, amp[i % 6], 0.0, &rs, x, sg);
                double spread = i % 3 == 0 ? 1e6 : 3.0;   /* sigmas over 6 decades, or a factor 3 */
                for (size_t q = 0; q < D; q++) {
                    sg[q] = exp(log(spread) * gs_splitmix_uniform(&rs));
                    x[q] += sg[q] * gs_splitmix_normal(&rs);
                }
                if (i % 4 == 1) sg[gs_splitmix64(&rs) % D] = INFINITY;   /* dropped samples */
                if (i % 4 == 2) x[gs_splitmix64(&rs) % D] = NAN;
                if (i == 16) sg[0] *= 1e-9;
                if (i == 17) sg[1] *= 1e-25;
                if (i == 12) {   /* a weight near DBL_MAX (its sample 0: the weighted sample finite) */
                    double top = 0.0;
                    for (size_t q = 0; q < D; q++) top = fmax(top, sg[q]);
                    sg[2] = top * 8.2e-155;
                    x[2] = 0.0;
                    sg[3] = INFINITY;   /* and a dropped sample: the bound takes log T itself */
                }
                rec_match f, s;
                double fe = ex ? 0.05 : 0.0;
                CHECK_OK(rec_eq7_match_light_ws(m, &w, x, sg, fe, &f, NULL));
                double Sxx = w.prep[0].Sxx;
                for (size_t j = 0; j < M; j++) {
                    total++;
                    exact_n += w.done[j];
                    if (w.done[j]) continue;
                    double S = 0.0, T = 0.0;
                    for (size_t d = 0; d < D; d++) {
                        S += w.wx[d] * m->t[j * D + d];
                        T += w.w[d] * m->t[j * D + d] * m->t[j * D + d];
                    }
                    double L = rec_eq7_loglik(Sxx, S, T);
                    if (!isfinite(L)) continue;
                    checked++;
                    CHECK_MSG(w.U[j] >= L - 1e-9 * (1.0 + fabs(L)), "D %zu excess %d light %d template %zu: float "
                              "bound %.9f below the exact score %.9f (Sxx %g)", D, ex, i, j, w.U[j], L, Sxx);
                }
                m->exhaustive = 1;
                CHECK_OK(rec_eq7_match_light_ws(m, &w, x, sg, fe, &s, NULL));
                m->exhaustive = 0;
                /* the probabilities where the rounding of Sxx - g (1e-16 Sxx) is below 0.1 nats: above,
                 * any two sums' last bits reorder templates (both paths' answers are rounding) */
                int sharp = Sxx < 1e15;
                CHECK_MSG(f.bulb == s.bulb && f.flags == s.flags &&
                              (!sharp || (close_to(f.confidence, s.confidence, 1e-9, 0) &&
                                          close_to(f.phase_confidence, s.phase_confidence, 1e-9, 0) &&
                                          close_to(f.runner_confidence, s.runner_confidence, 1e-9, 0))) &&
                              close_to(f.p_value, s.p_value, 1e-9, 0),
                          "D %zu excess %d light %d: bulb %d/%d flags %u/%u confidence %.12f/%.12f phase %.12f/%.12f "
                          "runner %.12f/%.12f p %.12g/%.12g", D, ex, i, f.bulb, s.bulb, f.flags, s.flags, f.confidence,
                          s.confidence, f.phase_confidence, s.phase_confidence, f.runner_confidence,
                          s.runner_confidence, f.p_value, s.p_value);
            }
            rec_eq7_work_free(&w);
            free(x), free(sg);
            rec_matcher_free(m);
        }
    CHECK(checked > 5000);
    printf("    %zu unscored templates checked against their float bounds; %zu of %zu scored exactly\n", checked,
           exact_n, total);
    gs_delight_free(g);
}

/* The reddened model's tight bounds (eq7_scores.c, red_tight_bound: the model's rounds without
 * its logarithms): every template the screen tightened but left unscored has a bound at least
 * its exact score, with a tau prior and a capture's chromaticity tolerance too; the bounds are
 * close (the median gap below 1 nat, where the chromaticity-blind bound is tens of nats off),
 * and the answers are the exhaustive path's. The built-in DELIGHT, RGB, K = 26, 3
 * phases and continuous, dim and bright lights. */
TEST(eq7_reddened_tight_bounds_hold)
{
    uint64_t rs = 43;
    gs_delight *g = gs_delight_new();
    CHECK_OK(gs_delight_generate(g, 1024));
    size_t checked = 0, exact_n = 0, total = 0;
    float *gaps = NULL;
    size_t ngap = 0;
    for (int cont = 0; cont < 2; cont++) {
        rec_matcher *m = model_matcher(g, 3, 26, REC_BANDS_REDDENED, cont ? REC_PHASES_CONTINUOUS : REC_PHASES_3, 0.0, 0);
        size_t D = (size_t)m->D, M = m->M;
        double *x = malloc(sizeof *x * D), *sg = malloc(sizeof *sg * D);
        gaps = realloc(gaps, sizeof *gaps * (ngap + 8 * M));
        rec_eq7_work w;
        CHECK_OK(rec_eq7_work_alloc(m, &w));
        for (int i = 0; i < 8; i++) {
            size_t b = gs_splitmix64(&rs) % m->nb;
            eq7fx_render(rec_matcher_bulb(m, b), gs_splitmix_uniform(&rs), 26, i < 4 ? 30.0 : 500.0, 1.0, &rs, x, sg);
            for (size_t q = 0; q < D; q++) sg[q] *= 0.5 + gs_splitmix_uniform(&rs);
            w.has_tau_prior = i % 2;
            for (int t = 0; t < REC_TAU_N; t++) w.tau_logprior[t] = -3.0 * gs_splitmix_uniform(&rs);
            w.chroma_tol = i % 4 < 2 ? 0.0 : 0.08;
            rec_match f, s;
            CHECK_OK(rec_eq7_match_light_ws(m, &w, x, sg, 0.0, &f, NULL));
            for (size_t j = 0; j < M; j++) {
                total++;
                exact_n += w.done[j];
                if (w.done[j] || !w.tight[j]) continue;
                double L = rec_eq7_loglik_fit(m, &w, j, w.prep[0].Sxx);
                if (!isfinite(L)) continue;
                checked++;
                CHECK_MSG(w.U[j] >= L, "cont %d light %d template %zu: tight bound %.9f below the exact score %.9f",
                          cont, i, j, w.U[j], L);
                gaps[ngap++] = (float)(w.U[j] - L);
            }
            m->exhaustive = 1;
            CHECK_OK(rec_eq7_match_light_ws(m, &w, x, sg, 0.0, &s, NULL));
            m->exhaustive = 0;
            CHECK_MSG(f.bulb == s.bulb && f.flags == s.flags && close_to(f.confidence, s.confidence, cont ? 1e-4 : 1e-9, 0),
                      "cont %d light %d: bulb %d/%d flags %u/%u confidence %.12f/%.12f", cont, i, f.bulb, s.bulb,
                      f.flags, s.flags, f.confidence, s.confidence);
        }
        rec_eq7_work_free(&w);
        free(x), free(sg);
        rec_matcher_free(m);
    }
    CHECK(checked > 1000);
    double med = ngap ? gs_median_f(gaps, ngap) : INFINITY;
    CHECK_MSG(med < 1.0, "median gap of the tight bounds %.2f nats", med);
    printf("    %zu tight bounds left unscored checked (median gap %.2f nats); %zu of %zu templates scored exactly\n",
           checked, med, exact_n, total);
    free(gaps);
    gs_delight_free(g);
}

/* Many exact scores at once (the screen's vectorized scores of the free model, in pieces of the
 * stack's scratch): K = 256, RGB, one brightness per band, 6 phases (300 templates), a light of
 * noise alone (every template within the cut) and a bright one: answers as the exhaustive
 * path's (the ASan passes check the scratch). */
TEST(eq7_free_model_many_scores_large_k)
{
    uint64_t rs = 5;
    gs_delight *g = gs_delight_new();
    CHECK_OK(gs_delight_generate(g, 1024));
    rec_matcher *m = model_matcher(g, 3, 256, REC_BANDS_FREE, REC_PHASES_6, 0.0, 1);
    size_t D = (size_t)m->D;
    double *x = malloc(sizeof *x * D), *sg = malloc(sizeof *sg * D);
    for (int i = 0; i < 2; i++) {
        eq7fx_render(rec_matcher_bulb(m, 3), 0.25, 256, i ? 300.0 : 0.0, 1.0, &rs, x, sg);
        rec_match f, s;
        CHECK_OK(rec_match_light(m, x, sg, &f));
        m->exhaustive = 1;
        CHECK_OK(rec_match_light(m, x, sg, &s));
        m->exhaustive = 0;
        CHECK(eq7fx_all_finite(&f));
        CHECK_MSG(f.bulb == s.bulb && f.flags == s.flags && close_to(f.confidence, s.confidence, 1e-9, 0) &&
                  close_to(f.runner_confidence, s.runner_confidence, 1e-9, 0),
                  "light %d: bulb %d/%d flags %u/%u confidence %.12f/%.12f", i, f.bulb, s.bulb, f.flags, s.flags,
                  f.confidence, s.confidence);
    }
    CHECK(rec_matcher_template_count(m) == 300);
    free(x), free(sg);
    rec_matcher_free(m);
    gs_delight_free(g);
}
