/* test_eq7_pixels.c - Eq. 7 on catalogs and pixel rows (rec_match_catalog, rec_match_pixels):
 * every row answers as rec_match_light does, across SGEMM blocks and through the dark-row
 * prefilter of the generated DELIGHT; and the bench's smoke test. */
#include "recognize/recognize.h"
#include "tests/eq7_fixture.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

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

