/* test_transport.c - AC light transport (paper Sec. 5): the NNLS solver against brute force,
 * float TIFFs read back by GDAL, the simulator's transport truth against its own renders and
 * against the analytic inverse-square law, unmixing (Eqs. 16-18) against a per-pixel weighted
 * least-squares oracle with the true BRFs, the B refinement, the hard cases (Eq. 15 merging,
 * Fig. 10 ill-posedness, saturated pixels, a near-flat BRF, K = 2), relighting (Eq. 20) and the
 * semi-reflection separation (Sec. 5.3). */
#include "tests/fixtures.h"
#include "tests/test.h"
#include "tests/transport_fixture.h"
#include "capture/sim.h"
#include "survey/internal.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static gs_delight *builtin(void)
{
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, GS_BRF_N_DEFAULT));
    return d;
}

/* The lab of capture/scenes/lab_transport.json at 64 x 48: five lamps of five technologies. */
static const trfx_lamp lab5[] = {
    {"inc25", "inc-a60-25w-230v", 0, 11.2, 8.9, 3.8, 6e6},
    {"cfl23", "cfl-23w", 120, 52.9, 7.2, 4.2, 6e6},
    {"ledfil", "led-fil-4w-lin", 240, 32.0, 4.9, 4.5, 5e6},
    {"fl36", "fl-t8-36w-tri", 0, 46.5, 27.2, 3.0, 4e6},
    {"mh70", "mh-70w", 240, 15.3, 25.7, 2.6, 8e6},
};

static void specs_of(const trfx_lamp *l, int n, rec_source_spec *sp)
{
    for (int i = 0; i < n; i++) {
        snprintf(sp[i].bulb, sizeof sp[i].bulb, "%s", l[i].bulb);
        sp[i].phase_deg = l[i].phase_deg;
    }
}

/* ------------------------------------------------------------------ NNLS */

TEST(nnls_matches_brute_force_over_active_sets)
{
    uint64_t seed = 14;
    double worst = 0;
    for (int trial = 0; trial < 400; trial++) {
        int n = 1 + trial % 8, m = n + 2 + trial % 5;
        double A[16 * 8], y[16], G[64], h[8], x[8];
        for (int i = 0; i < m * n; i++) A[i] = gs_splitmix_normal(&seed);
        for (int i = 0; i < m; i++) y[i] = gs_splitmix_normal(&seed);
        for (int i = 0; i < n; i++) {
            h[i] = 0;
            for (int k = 0; k < m; k++) h[i] += A[k * n + i] * y[k];
            for (int j = 0; j < n; j++) {
                G[i * n + j] = 0;
                for (int k = 0; k < m; k++) G[i * n + j] += A[k * n + i] * A[k * n + j];
            }
        }
        CHECK(rec_nnls(G, h, n, x) >= 0);
        /* the optimum's support solves the unconstrained problem on it: try every support */
        double best = INFINITY, bx[8] = {0};
        for (unsigned mask = 0; mask < (1u << n); mask++) {
            double Gs[64], hs[8], z[8] = {0};
            int idx[8], k = 0;
            for (int i = 0; i < n; i++)
                if (mask >> i & 1u) idx[k++] = i;
            for (int i = 0; i < k; i++) {
                hs[i] = h[idx[i]];
                for (int j = 0; j < k; j++) Gs[i * k + j] = G[idx[i] * n + idx[j]];
            }
            /* Gauss-Jordan on the subset */
            int ok = 1;
            for (int c = 0; c < k && ok; c++) {
                if (fabs(Gs[c * k + c]) < 1e-12) ok = 0;
                for (int r = 0; r < k && ok; r++) {
                    if (r == c) continue;
                    double f = Gs[r * k + c] / Gs[c * k + c];
                    for (int j = 0; j < k; j++) Gs[r * k + j] -= f * Gs[c * k + j];
                    hs[r] -= f * hs[c];
                }
            }
            if (!ok) continue;
            int feas = 1;
            for (int i = 0; i < k; i++) {
                z[idx[i]] = hs[i] / Gs[i * k + i];
                feas &= z[idx[i]] >= 0;
            }
            if (!feas) continue;
            double f = 0;
            for (int i = 0; i < n; i++) {
                f -= h[i] * z[i];
                for (int j = 0; j < n; j++) f += 0.5 * z[i] * G[i * n + j] * z[j];
            }
            if (f < best) {
                best = f;
                memcpy(bx, z, sizeof bx);
            }
        }
        for (int i = 0; i < n; i++) {
            CHECK(x[i] >= 0);
            double e = fabs(x[i] - bx[i]) / (1 + fabs(bx[i]));
            if (e > worst) worst = e;
        }
    }
    printf("    400 random problems, n = 1..8: worst difference from brute force %.2e\n", worst);
    CHECK(worst < 1e-8);
}

TEST(nnls_rejects_bad_sizes_and_singular_systems)
{
    double G[4] = {1, 1, 1, 1}, h[2] = {1, 1}, x[2];
    /* a dependent pair: the solver never returns garbage, either an optimum or -1 */
    int it = rec_nnls(G, h, 2, x);
    if (it >= 0) CHECK_NEAR(x[0] + x[1], 1.0, 1e-12);
    else CHECK(it == -1);
    CHECK(rec_nnls(G, h, 0, x) == -1);
    CHECK(rec_nnls(G, h, 33, x) == -1);
    double g1 = 2, h1 = -3, x1 = 7;
    CHECK(rec_nnls(&g1, &h1, 1, &x1) >= 0 && x1 == 0);   /* the bound is active */
}

/* ------------------------------------------------------------------ float TIFF */

/* `gdallocationinfo -valonly` of pixel (x, y) of path: the values of its bands. */
static int gdal_pixel(const char *path, int x, int y, double *v, int max)
{
    char out[1024];
    int rc = fx_run(out, sizeof out, "gdallocationinfo -valonly '%s' %d %d 2>&1", path, x, y);
    if (rc != 0) return 0;
    int n = 0;
    char *s = out, *end;
    while (n < max) {
        double d = strtod(s, &end);
        if (end == s) break;
        v[n++] = d;
        s = end;
    }
    return n;
}

TEST(tiff_float_round_trip_and_gdal_reads_float32_rgb_in_file_order)
{
    int W = 7, H = 5;
    float rgb[2 * 5 * 7 * 3], grey[5 * 7];
    uint64_t seed = 3;
    for (int i = 0; i < 2 * W * H * 3; i++) rgb[i] = (float)(1000 * gs_splitmix_normal(&seed));
    for (int i = 0; i < W * H; i++) grey[i] = (float)(i * 0.125);
    rgb[3 * (2 * W + 4) + 0] = 1.5f;   /* pixel (4, 2): R, G, B distinct */
    rgb[3 * (2 * W + 4) + 1] = 2.25f;
    rgb[3 * (2 * W + 4) + 2] = 3.125f;
    grey[W + 1] = NAN;
    const char *p3 = fx_tmp("rgb.tiff"), *p1 = fx_tmp("grey.tiff");
    CHECK_OK(gs_tiff_write_float(p3, rgb, W, H, 3, 2));
    CHECK_OK(gs_tiff_write_float(p1, grey, W, H, 1, 1));
    int w, h, b, pg;
    float *back;
    CHECK_OK(gs_tiff_read_float(p3, &w, &h, &b, &pg, &back));
    CHECK(w == W && h == H && b == 3 && pg == 2);
    if (back) CHECK(!memcmp(back, rgb, sizeof rgb));
    free(back);
    CHECK_OK(gs_tiff_read_float(p1, &w, &h, &b, &pg, &back));
    CHECK(b == 1 && pg == 1);
    if (back) CHECK(isnan(back[W + 1]) && back[3] == grey[3]);
    free(back);
    /* GDAL: Float32 bands, Red / Green / Blue, the values as written (file band 1 = R) */
    char out[8192];
    CHECK(fx_run(out, sizeof out, "gdalinfo '%s' 2>&1", p3) == 0);
    CHECK(fx_count_of(out, "Type=Float32") == 3);
    CHECK(fx_contains(out, "ColorInterp=Red") && fx_contains(out, "ColorInterp=Blue"));
    double v[3];
    CHECK(gdal_pixel(p3, 4, 2, v, 3) == 3);
    CHECK(v[0] == 1.5 && v[1] == 2.25 && v[2] == 3.125);
    CHECK(gdal_pixel(p1, 5, 0, v, 1) == 1 && v[0] == 0.625);
    /* bad input */
    CHECK(gs_tiff_write_float(p1, grey, W, H, 2, 1) == GS_EINVAL);
    CHECK(gs_tiff_read_float(fx_tmp("none.tiff"), &w, &h, &b, &pg, &back) == GS_ENOTFOUND);
    fx_write_text(fx_tmp("bad.tiff"), "not a tiff");
    CHECK(gs_tiff_read_float(fx_tmp("bad.tiff"), &w, &h, &b, &pg, &back) == GS_EFORMAT);
}

/* ------------------------------------------------------------------ the simulator */

TEST(scene_builtin_transport_scenes_parse_with_their_effects)
{
    cap_scene sc;
    CHECK_OK(cap_scene_read("capture/scenes/lab_transport.json", &sc));
    CHECK(sc.n_lights == 5 && (sc.fx.enabled >> CAP_FX_LIGHT_TRANSPORT & 1u));
    CHECK(!(sc.fx.enabled >> CAP_FX_SEMI_REFLECTION & 1u) && sc.fx.transport.n_boxes == 2);
    for (size_t i = 0; i < sc.n_lights; i++) CHECK(sc.lights[i].in_image && sc.lights[i].distance_m > 0);
    cap_scene_release(&sc);
    CHECK_OK(cap_scene_read("capture/scenes/window.json", &sc));
    CHECK(sc.n_lights == 1 && !sc.lights[0].in_image);
    CHECK(sc.fx.enabled >> CAP_FX_SEMI_REFLECTION & 1u);
    cap_scene_release(&sc);
    rec_source_spec *sp = NULL;
    int n = 0;
    CHECK_OK(rec_sources_read_specs("capture/scenes/lab_transport_sources.json", &sp, &n));
    CHECK(n == 5);
    free(sp);
}

TEST(scene_light_transport_bad_parameters_name_the_field)
{
    const char *bad[][2] = {
        {"\"light_transport\": {}", "field effects.light_transport.room"},
        {"\"light_transport\": {\"room\": {\"width_m\": 5, \"height_m\": 3}}", "depth_m"},
        {"\"light_transport\": {\"room\": {\"width_m\": 5, \"height_m\": 3, \"depth_m\": 4}, \"boxes\": [{\"min_m\": [0, 0, 1], \"max_m\": [1, 1, 0.5]}]}", "above min_m"},
        {"\"light_transport\": {\"room\": {\"width_m\": 5, \"height_m\": 3, \"depth_m\": 4, \"colour\": 1}}", "colour"},
        {"\"semi_reflection\": {\"reflectance\": 2, \"outdoor_e_per_px_cycle\": 1}", "reflectance"},
    };
    for (size_t i = 0; i < sizeof bad / sizeof *bad; i++) {
        char text[2048];
        snprintf(text, sizeof text,
                 "{\"format\": \"gridsurvey-scene/1\", \"grid\": {\"nominal_hz\": 50},\n"
                 " \"camera\": {\"width_px\": 8, \"height_px\": 6},\n \"acam\": {\"K\": 4, \"cycles\": 8},\n"
                 " \"lights\": [],\n \"effects\": {%s}}\n", bad[i][0]);
        cap_scene sc;
        gs_status st = cap_scene_parse(text, "bad.json", ".", &sc);
        CHECK_MSG(st == GS_EFORMAT && fx_contains(gs_detail(), "bad.json:5") &&
                  fx_contains(gs_detail(), bad[i][1]), "%s -> %s", bad[i][0], gs_detail());
        cap_scene_release(&sc);
    }
}

TEST(sim_transport_truth_is_the_cycle_mean_of_noise_free_renders)
{
    trfx_opts o = {0};
    char *text = trfx_scene(&o, lab5, 5);
    /* no sensor effect: the frames are exact */
    char *fx = strstr(text, ",\n  \"shot_noise\"");
    CHECK(fx != NULL);
    if (fx) strcpy(fx, "}}\n");
    cap_scene sc;
    CHECK_OK(cap_scene_parse(text, "t.json", ".", &sc));
    cap_sim *s = NULL;
    CHECK_OK(cap_sim_new(&sc, NULL, &s));
    if (!s) return;
    const char *dir = fx_tmp("truth");
    CHECK_OK(cap_sim_write_truth(s, dir));
    int W = 64, H = 48, K = 26;
    size_t n = (size_t)W * H * 3;
    double *dn = malloc(sizeof *dn * n), *mean = calloc(n, sizeof *mean);
    for (int k = 0; k < K; k++) {
        CHECK_OK(cap_sim_render(s, k, 0, k, NULL, NULL, dn));
        for (size_t i = 0; i < n; i++) mean[i] += (dn[i] - 64.0) / 256.0 / K;
    }
    /* the sum of every light's truth */
    srv_tr_truth t;
    CHECK_OK(srv_tr_truth_load(dir, &t));
    CHECK(t.n == 5);
    double worst = 0;
    for (size_t i = 0; i < n && t.n == 5; i++) {
        double sum = 0;
        for (int l = 0; l < 5; l++) sum += t.img[(size_t)l * n + i];
        double e = fabs(sum - mean[i]) / (fabs(mean[i]) + 1e-3);
        if (e > worst) worst = e;
    }
    printf("    truth vs the cycle mean of exact renders: worst relative difference %.2e\n", worst);
    CHECK(worst < 1e-5);
    srv_tr_truth_release(&t);
    free(dn);
    free(mean);
    cap_sim_free(s);
    cap_scene_release(&sc);
    free(text);
}

TEST(sim_light_transport_follows_inverse_square_and_cosine_law)
{
    /* one lamp, a plain room (no checker, no box): the back wall by the analytic formula */
    const char *text =
        "{\"format\": \"gridsurvey-scene/1\", \"grid\": {\"nominal_hz\": 50},\n"
        " \"camera\": {\"width_px\": 40, \"height_px\": 30, \"intrinsics\": {\"focal_px\": 40},\n"
        "   \"sensor\": {\"bands\": 1, \"gain_e_per_dn\": 2}},\n"
        " \"acam\": {\"K\": 8, \"cycles\": 64},\n"
        " \"lights\": [{\"id\": \"a\", \"bulb\": \"hps-150w\", \"x_px\": 8, \"y_px\": 6, \"distance_m\": 2, \"flux_e_per_cycle\": 1e7}],\n"
        " \"effects\": {\"light_transport\": {\"room\": {\"width_m\": 40, \"height_m\": 30, \"depth_m\": 5, \"albedo\": 0.6}}}}\n";
    cap_scene sc;
    CHECK_OK(cap_scene_parse(text, "a.json", ".", &sc));
    cap_sim *s = NULL;
    CHECK_OK(cap_sim_new(&sc, NULL, &s));
    if (!s) return;
    const char *dir = fx_tmp("analytic");
    CHECK_OK(cap_sim_write_truth(s, dir));
    int w, h, b, pg;
    float *img = NULL;
    char path[512];
    snprintf(path, sizeof path, "%s/truth_tau_00.tiff", dir);
    CHECK_OK(gs_tiff_read_float(path, &w, &h, &b, &pg, &img));
    if (!img) return;
    /* the lamp along its pixel's ray at 2 m */
    double cx = 19.5, cy = 14.5, f = 40, L[3] = {(8 - cx) / f, (6 - cy) / f, 1};
    double nl = sqrt(L[0] * L[0] + L[1] * L[1] + 1);
    for (int a = 0; a < 3; a++) L[a] *= 2.0 / nl;
    double worst = 0;
    int pts[][2] = {{20, 15}, {30, 25}, {5, 20}, {35, 3}};
    for (int i = 0; i < 4; i++) {
        int x = pts[i][0], y = pts[i][1];
        /* the back wall z = 5 (the room's side walls are far away) */
        double X[3] = {(x - cx) / f * 5, (y - cy) / f * 5, 5};
        double v[3] = {L[0] - X[0], L[1] - X[1], L[2] - X[2]};
        double r2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2], cosi = -v[2] / sqrt(r2);
        /* rho / pi * F d^2 cos / r^2 / f^2, per cycle and window: / (K gain) */
        double want = 0.6 / M_PI * 1e7 * 4.0 * cosi / r2 / (f * f) / (8 * 2.0);
        double got = img[y * 40 + x], e = fabs(got - want) / want;
        if (e > worst) worst = e;
    }
    printf("    back-wall transport vs the analytic Lambertian inverse-square law: %.2e\n", worst);
    CHECK(worst < 1e-5);
    free(img);
    cap_sim_free(s);
    cap_scene_release(&sc);
}

/* ------------------------------------------------------------------ unmixing */

/* Renders lamps into dir, unmixes them with specs (d: the DELIGHT unmix uses), returns the
 * status of rec_unmix; cap, src, r are the caller's to release. */
static gs_status unmix_scene(const char *dir, const trfx_opts *o, const trfx_lamp *lamps, int n,
                             const rec_source_spec *sp, int ns, int refine, const gs_delight *d,
                             gs_capture *cap, rec_sources *src, rec_unmix_result *r)
{
    char *text = trfx_scene(o, lamps, n);
    memset(r, 0, sizeof *r);
    memset(src, 0, sizeof *src);
    int ok = trfx_render(text, dir, cap);
    free(text);
    if (!ok) return GS_EIO;
    CHECK_OK(rec_sources_build(d, sp, ns, 50, cap->bands, cap->K, src, NULL));
    rec_unmix_opts uo;
    rec_unmix_opts_default(&uo);
    uo.refine = refine;
    return rec_unmix(cap, src, &uo, r);
}

static int cmp_float(const void *a, const void *b)
{
    float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

/* The mean residual of r's pixels with the most of a source's true light (top tenth of truth,
 * W x H x 3) over that of the pixels with the least (bottom half); *median r's median residual.
 * The ordering of the pixels is the truth's, not the code's. */
static double residual_contrast(const rec_unmix_result *r, const float *truth, size_t P, double *median)
{
    *median = NAN;
    float *t = malloc(sizeof *t * P), *res = malloc(sizeof *res * P);
    size_t n = 0;
    for (size_t p = 0; p < P; p++)
        if (isfinite(r->residual[p])) {
            t[n] = truth[p * 3] + truth[p * 3 + 1] + truth[p * 3 + 2];
            res[n++] = r->residual[p];
        }
    CHECK(n > 0);
    if (n == 0) {
        free(t), free(res);
        return NAN;
    }
    float *ts = malloc(sizeof *ts * n), *rs = malloc(sizeof *rs * n);
    memcpy(ts, t, sizeof *ts * n);
    memcpy(rs, res, sizeof *rs * n);
    qsort(ts, n, sizeof *ts, cmp_float);
    qsort(rs, n, sizeof *rs, cmp_float);
    float hi = ts[n - n / 10], lo = ts[n / 2];
    *median = rs[n / 2];
    double sh = 0, sl = 0;
    size_t nh = 0, nl = 0;
    for (size_t i = 0; i < n; i++) {
        if (t[i] >= hi) sh += res[i], nh++;
        if (t[i] <= lo) sl += res[i], nl++;
    }
    free(t), free(res), free(ts), free(rs);
    return (sh / (double)nh) / (sl / (double)nl);
}

TEST_TIMEOUT(eq16_unmix_within_1_25x_of_weighted_least_squares_with_true_brfs, 600)
{
    gs_delight *d = builtin();
    trfx_opts o = {0};
    o.hdr_rounds = 3;
    rec_source_spec sp[5];
    specs_of(lab5, 5, sp);
    gs_capture cap;
    rec_sources src;
    rec_unmix_result r;
    const char *dir = fx_tmp("lab5");
    CHECK_OK(unmix_scene(dir, &o, lab5, 5, sp, 5, 1, d, &cap, &src, &r));
    /* the hard parts are there: HDR-halved and saturated samples */
    size_t halved = 0, P = (size_t)cap.width * cap.height;
    for (size_t i = 0; cap.halvings && i < P * (size_t)cap.K; i++) halved += cap.halvings[i] > 0;
    printf("    %zu halved samples, %zu pixels partly saturated, %zu without an answer; weighted rms "
           "residual %.3f\n", halved, r.partial_px, r.unknown_px, r.rms_residual);
    CHECK(halved > 0 && r.partial_px > 0);
    /* the right sources and noise model: chi2 per degree of freedom (samples less the sources
     * fitted) is 1 up to its sampling noise and the BRFs' database-to-scene difference; per
     * sample it would be sqrt((K - S) / K) = 0.90 */
    CHECK_MSG(fabs(r.rms_residual - 1.0) < 0.05, "weighted rms residual %.3f", r.rms_residual);
    double oracle[5], ours[5];
    if (r.tq) {
        trfx_oracle_errors(dir, &cap, d, &src, &r, oracle, ours);
        for (int s = 0; s < 5; s++) {
            double all = trfx_error(dir, &r, &src, s);
            printf("    source %d %-18s: error %.4f (%.4f where the oracle has one), oracle %.4f, "
                   "ratio %.3f, predicted %.4f\n", s, src.bulb[s], all, ours[s], oracle[s],
                   ours[s] / oracle[s], r.predicted_error[s]);
            CHECK_MSG(ours[s] <= 1.25 * oracle[s], "source %d: %.4f vs the oracle's %.4f", s, ours[s], oracle[s]);
            CHECK(all < 0.5);
        }
        /* each value's sigma against its error from the truth (the simulator's tau Q): rms of
         * z = error / sigma over the complete pixels, 1 when the sigmas are right */
        for (int s = 0; s < 5; s++) {
            float *truth = trfx_truth(dir, src.bulb[s], src.phase_deg[s]);
            double z2 = 0;
            size_t nz = 0;
            for (size_t p = 0; truth && p < P; p++)
                for (int b = 0; b < 3 && r.state[p] == REC_UNMIX_OK; b++) {
                    size_t i = ((size_t)s * P + p) * 3 + b;
                    double z = (r.tq[i] - truth[p * 3 + b]) / r.sigma[i];
                    if (isfinite(z) && r.tq[i] > 3 * r.sigma[i]) z2 += z * z, nz++;   /* (away from T >= 0) */
                }
            double rz = nz ? sqrt(z2 / (double)nz) : NAN;
            printf("    source %d: rms error / sigma %.3f over %zu values\n", s, rz, nz);
            CHECK_MSG(nz > 1000 && rz > 0.85 && rz < 1.2, "source %d: rms z %.3f over %zu values", s, rz, nz);
            free(truth);
        }
        /* each pixel's residual shows where a source is missing from the list: with mh70 left
         * out it is high where mh70's true light is, about 1 elsewhere and everywhere with all five */
        float *mh = trfx_truth(dir, "mh-70w", 240);
        CHECK(mh != NULL && r.residual != NULL);
        if (mh && r.residual) {
            double med_all, c_all = residual_contrast(&r, mh, P, &med_all);
            rec_unmix_release(&r);
            rec_sources_release(&src);
            rec_unmix_opts uo;
            rec_unmix_opts_default(&uo);
            CHECK_OK(rec_sources_build(d, sp, 4, 50, cap.bands, cap.K, &src, NULL));   /* mh70 (the fifth) left out */
            CHECK_OK(rec_unmix(&cap, &src, &uo, &r));
            double med_four = NAN, c_four = r.residual ? residual_contrast(&r, mh, P, &med_four) : 0;
            printf("    residual where mh70 lights most / least: %.2f with all five sources (median %.3f), %.2f "
                   "with mh70 left out (median %.3f)\n", c_all, med_all, c_four, med_four);
            CHECK(fabs(med_all - 1.0) < 0.1 && c_all < 1.2);
            CHECK(c_four > 2.0);
        }
        free(mh);
    }
    rec_unmix_release(&r);
    rec_sources_release(&src);
    gs_capture_release(&cap);
    gs_delight_free(d);
}

/* A copy of d whose bulbs in ids have their BRF changed by a ripple of relative size `amount`
 * (3rd harmonic of the cycle, the mean kept at 1), saved as a DELIGHT file. */
static void save_perturbed(const gs_delight *d, const char *const *ids, int n, double amount,
                           const char *path)
{
    gs_delight *p = gs_delight_new();
    for (size_t i = 0; i < gs_delight_count(d); i++) {
        gs_bulb b = *gs_delight_get(d, i);
        CHECK_OK(gs_brf_copy(&b.brf, &gs_delight_get(d, i)->brf));
        for (int j = 0; j < n; j++)
            if (!strcmp(b.id, ids[j]))
                for (int c = 0; c < b.brf.bands; c++)
                    for (int s = 0; s < b.brf.n; s++)
                        b.brf.v[c * b.brf.n + s] *= 1 + amount * sin(2 * M_PI * (3.0 * s / b.brf.n + 0.1 * j));
        CHECK_OK(gs_brf_normalize(&b.brf, NULL));
        CHECK_OK(gs_delight_add(p, &b));
        gs_brf_release(&b.brf);
    }
    CHECK_OK(gs_delight_save(p, path));
    gs_delight_free(p);
}

TEST_TIMEOUT(eq18_refinement_helps_with_brf_mismatch_and_never_hurts_beyond_noise, 600)
{
    gs_delight *d = builtin();
    static const trfx_lamp l3[] = {
        {"inc25", "inc-a60-25w-230v", 0, 11.2, 8.9, 3.8, 6e6},
        {"cfl23", "cfl-23w", 120, 52.9, 7.2, 4.2, 6e6},
        {"ledfil", "led-fil-4w-lin", 240, 32.0, 4.9, 4.5, 5e6},
    };
    rec_source_spec sp[3];
    specs_of(l3, 3, sp);
    const char *ids[3] = {"inc-a60-25w-230v", "cfl-23w", "led-fil-4w-lin"};
    const char *db = fx_tmp("perturbed.sqlite");
    save_perturbed(d, ids, 3, 0.04, db);
    double e[2][2][3];   /* [mismatch][refine][source] */
    double db_err[3] = {0}, ref_err[3] = {0};   /* rms BRF error of the database, the refined */
    double e_true[3] = {0};                     /* error with the scene's own BRFs */
    for (int mm = 0; mm < 2; mm++) {
        trfx_opts o = {0};
        o.hdr_rounds = 3;
        o.delight = mm ? db : NULL;
        char *text = trfx_scene(&o, l3, 3);
        gs_capture cap;
        const char *dir = fx_tmp(mm ? "mismatch" : "matched");
        CHECK(trfx_render(text, dir, &cap));
        free(text);
        if (mm) {
            /* the floor: the mismatched scene unmixed with its own (true) BRFs */
            gs_delight *pd = gs_delight_new();
            CHECK_OK(gs_delight_load(pd, db));
            rec_sources src;
            rec_unmix_result r;
            CHECK_OK(rec_sources_build(pd, sp, 3, 50, 3, cap.K, &src, NULL));
            CHECK_OK(rec_unmix(&cap, &src, NULL, &r));
            for (int s = 0; s < 3; s++) e_true[s] = r.tq ? trfx_error(dir, &r, &src, s) : NAN;
            rec_unmix_release(&r);
            rec_sources_release(&src);
            gs_delight_free(pd);
        }
        for (int rf = 0; rf < 2; rf++) {
            rec_sources src;
            rec_unmix_result r;
            CHECK_OK(rec_sources_build(d, sp, 3, 50, 3, cap.K, &src, NULL));
            rec_unmix_opts uo;
            rec_unmix_opts_default(&uo);
            uo.refine = rf;
            CHECK_OK(rec_unmix(&cap, &src, &uo, &r));
            for (int s = 0; s < 3; s++) e[mm][rf][s] = r.tq ? trfx_error(dir, &r, &src, s) : NAN;
            if (mm && rf && r.b) {
                /* the refined BRFs against the scene's (the perturbed ones) */
                gs_delight *pd = gs_delight_new();
                CHECK_OK(gs_delight_load(pd, db));
                for (int s = 0; s < 3; s++) {
                    double bt[3 * 26], d0 = 0, d1 = 0;
                    const gs_bulb *bu = gs_delight_find(pd, ids[s], 50, 3);
                    CHECK_OK(gs_brf_integrate(&bu->brf, gs_phase_to_shift(l3[s].phase_deg), 26, bt));
                    for (int i = 0; i < 78; i++) {
                        d0 += (src.b[s * 78 + i] - bt[i]) * (src.b[s * 78 + i] - bt[i]);
                        d1 += (r.b[s * 78 + i] - bt[i]) * (r.b[s * 78 + i] - bt[i]);
                    }
                    db_err[s] = sqrt(d0 / 78);
                    ref_err[s] = sqrt(d1 / 78);
                }
                gs_delight_free(pd);
            }
            rec_unmix_release(&r);
            rec_sources_release(&src);
        }
        gs_capture_release(&cap);
    }
    double x0 = 0, x1 = 0;
    for (int s = 0; s < 3; s++) {
        printf("    %-18s matched: %.4f -> %.4f refined; 4 %% BRF ripple: %.4f -> %.4f, with the "
               "true BRFs %.4f (BRF rms error %.4f -> %.4f)\n", ids[s], e[0][0][s], e[0][1][s],
               e[1][0][s], e[1][1][s], e_true[s], db_err[s], ref_err[s]);
        /* matched BRFs: Eq. 18 costs at most noise (a few % of the error, or 0.005) */
        CHECK(e[0][1][s] <= 1.05 * e[0][0][s] + 0.005);
        /* mismatched: it brings the BRF towards the scene's */
        CHECK(ref_err[s] < 0.5 * db_err[s]);
        x0 += e[1][0][s] - e_true[s];
        x1 += e[1][1][s] - e_true[s];
    }
    /* and lowers the error the mismatch adds: most for the strongly flickering source, whose
     * BRF error Eq. 18 sees in the residual; for the others much of what remains lies in the
     * span of the other sources' BRFs, where I = T Q B cannot tell it from a change of T */
    printf("    error the mismatch adds: %.4f without Eq. 18, %.4f with it\n", x0 / 3, x1 / 3);
    CHECK_MSG(x1 < x0, "excess error %.4f refined vs %.4f", x1 / 3, x0 / 3);
    CHECK(e[1][1][2] - e_true[2] < 0.5 * (e[1][0][2] - e_true[2]));
    gs_delight_free(d);
}

TEST(eq15_same_bulb_and_phase_merged_not_split)
{
    gs_delight *d = builtin();
    /* phase 180 deg delays the BRF by a whole cycle: the same shift as 0 */
    rec_source_spec sp[4] = {{"inc-a60-25w-230v", 0}, {"cfl-23w", 120}, {"inc-a60-25w-230v", 180},
                             {"cfl-23w", 300}};
    rec_sources src;
    int into[4];
    CHECK_OK(rec_sources_build(d, sp, 4, 50, 3, 26, &src, into));
    CHECK(src.S == 2 && into[0] == into[2] && into[1] == into[3] && into[0] != into[1]);
    CHECK(src.merged[0] == 2 && src.merged[1] == 2);
    rec_sources_release(&src);
    /* two lamps of one bulb and phase in a scene: one source holding both */
    static const trfx_lamp l[] = {
        {"a", "inc-a60-25w-230v", 0, 11.2, 8.9, 3.8, 6e6},
        {"b", "inc-a60-25w-230v", 0, 46.5, 27.2, 3.0, 4e6},
        {"c", "led-fil-4w-lin", 240, 32.0, 4.9, 4.5, 5e6},
    };
    rec_source_spec s3[3];
    specs_of(l, 3, s3);
    trfx_opts o = {0};
    gs_capture cap;
    rec_unmix_result r;
    const char *dir = fx_tmp("merge");
    CHECK_OK(unmix_scene(dir, &o, l, 3, s3, 3, 1, d, &cap, &src, &r));
    CHECK(src.S == 2);
    double e = r.tq ? trfx_error(dir, &r, &src, 0) : NAN;
    printf("    two lamps of one bulb and phase: one source, error %.4f against their sum\n", e);
    CHECK(e < 0.1);
    rec_unmix_release(&r);
    rec_sources_release(&src);
    gs_capture_release(&cap);
    gs_delight_free(d);
}

/* Declares cap free running, every frame's windows drifting `drift` windows over the exposure
 * (P = 10 ms, grid_hz_measured to match), frame k5's `drift5`; and gives frame k5 frame src's
 * pixels. */
static void drift_frames(gs_capture *cap, double drift, double drift5, int k5, int src)
{
    cap->locked = 0;
    for (int k = 0; k < cap->K; k++) {
        double d = k == k5 ? drift5 : drift;
        cap->frames[k].window_half_period_s = 0.01;
        cap->frames[k].grid_hz_measured = (1.0 + d / (cap->K * cap->frames[k].cycles)) / (2.0 * 0.01);
    }
    size_t n = (size_t)cap->width * (size_t)cap->height * (size_t)cap->bands;
    memcpy(cap->raw + (size_t)k5 * n, cap->raw + (size_t)src * n, n * sizeof *cap->raw);
    if (cap->halvings) {
        size_t np = (size_t)cap->width * (size_t)cap->height;
        memcpy(cap->halvings + (size_t)k5 * np, cap->halvings + (size_t)src * np, np);
    }
}

/* A free-running frame whose windows drifted over half a window follows no BRF (docs/
 * recognition.md "Free-running captures"): Eq. 17 discards its samples, so unmixing (Eq. 16,
 * 18) and `--sources auto` do not depend on what it holds (frame 5 given frame 0's or frame 1's
 * pixels: the same bits), and stay near the locked capture's (the same auto sources, in order);
 * kept (drifting 0.45), the same pixels change them. With the threshold at 0.6
 * (rec_unmix_opts and rec_eq7_opts.max_drift_windows) the frame drifting 0.55 is kept: the same
 * bits as the one drifting 0.45 (neither raises a kept frame's noise), and so it is at
 * REC_DRIFT_AUTO when capture.json's window_period is measured; unmixing's default is not auto
 * but 0.5. */
TEST(eq17_drifted_frames_discarded_by_unmix_and_auto_sources)
{
    gs_delight *d = builtin();
    static const trfx_lamp l[] = {
        {"a", "inc-a60-25w-230v", 0, 11.2, 8.9, 3.8, 6e6},
        {"b", "cfl-23w", 120, 46.5, 27.2, 3.0, 4e6},
        {"c", "led-fil-4w-lin", 240, 32.0, 4.9, 4.5, 5e6},
    };
    rec_source_spec s3[3];
    specs_of(l, 3, s3);
    trfx_opts o = {0};
    gs_capture cap;
    rec_sources src;
    rec_unmix_result r0;
    const char *dir = fx_tmp("drift");
    CHECK_OK(unmix_scene(dir, &o, l, 3, s3, 3, 1, d, &cap, &src, &r0));
    rec_eq7_opts eo;
    rec_eq7_opts_default(&eo);
    eo.unknown_p = 0.0;
    rec_matcher *m = NULL;
    CHECK_OK(rec_matcher_new(d, 50, cap.bands, cap.K, &eo, &m));
    rec_unmix_opts uo;
    rec_unmix_opts_default(&uo);
    CHECK(uo.max_drift_windows == REC_MAX_DRIFT_WINDOWS && eo.max_drift_windows == REC_DRIFT_AUTO);
    size_t n = (size_t)cap.width * cap.height * cap.bands * (size_t)src.S;
    rec_unmix_result r[5];
    rec_source_spec *auto_sp[5] = {NULL, NULL, NULL, NULL, NULL};
    int n_auto[5] = {0, 0, 0, 0, 0};
    rec_matcher *m6 = NULL;   /* (threshold 0.6) */
    eo.max_drift_windows = 0.6;
    CHECK_OK(rec_matcher_new(d, 50, cap.bands, cap.K, &eo, &m6));
    for (int v = 0; v < 5 && m && m6; v++) {
        gs_capture c;
        CHECK_OK(gs_capture_read(dir, &c));
        drift_frames(&c, 0.45, v != 2 ? 0.55 : 0.45, 5, v == 1);
        rec_unmix_opts uv = uo;
        if (v == 3) uv.max_drift_windows = 0.6;
        if (v == 4) c.window_period = GS_PERIOD_MEASURED, uv.max_drift_windows = REC_DRIFT_AUTO;   /* (m: auto) */
        CHECK_OK(rec_unmix(&c, &src, &uv, &r[v]));
        CHECK_OK(rec_sources_auto(&c, v == 3 ? m6 : m, 20.0, 20, 8, &auto_sp[v], &n_auto[v], NULL, NULL));
        gs_capture_release(&c);
    }
    rec_source_spec *auto0 = NULL;
    int n0 = 0;
    if (m) CHECK_OK(rec_sources_auto(&cap, m, 20.0, 20, 8, &auto0, &n0, NULL, NULL));
    printf("    locked: %d auto sources:", n0);
    for (int i = 0; i < n0; i++) printf(" %s@%g", auto0[i].bulb, auto0[i].phase_deg);
    printf("\n");
    for (int v = 0; v < 3; v++) {
        printf("    case %d: %d auto sources:", v, n_auto[v]);
        for (int i = 0; i < n_auto[v]; i++) printf(" %s@%g", auto_sp[v][i].bulb, auto_sp[v][i].phase_deg);
        printf("\n");
    }
    if (m && m6 && r[0].tq && r[1].tq && r[2].tq && r[3].tq && r[4].tq && r0.tq) {
        CHECK(memcmp(r[0].tq, r[1].tq, n * sizeof *r[0].tq) == 0);
        for (int v = 3; v < 5; v++) {
            CHECK_MSG(memcmp(r[v].tq, r[2].tq, n * sizeof *r[2].tq) == 0, "case %d", v);
            CHECK(n_auto[v] == n_auto[2]);
            for (int i = 0; i < n_auto[v] && i < n_auto[2]; i++)
                CHECK(!strcmp(auto_sp[v][i].bulb, auto_sp[2][i].bulb) && auto_sp[v][i].phase_deg == auto_sp[2][i].phase_deg);
        }
        /* the sources auto finds: the locked capture's, in its order, frame 5 left out; not kept */
        int same[3] = {1, 1, 1};
        for (int v = 0; v < 3; v++) {
            same[v] = n_auto[v] == n0;
            for (int i = 0; same[v] && i < n0; i++)
                same[v] = !strcmp(auto_sp[v][i].bulb, auto0[i].bulb) && auto_sp[v][i].phase_deg == auto0[i].phase_deg;
        }
        CHECK(n0 >= 2 && same[0] && same[1] && !same[2]);
        double e_out = 0, e_in = 0, norm = 0;
        for (size_t i = 0; i < n; i++) {
            if (!isfinite(r0.tq[i]) || !isfinite(r[0].tq[i]) || !isfinite(r[2].tq[i])) continue;
            e_out += (r[0].tq[i] - r0.tq[i]) * (r[0].tq[i] - r0.tq[i]);
            e_in += (r[2].tq[i] - r0.tq[i]) * (r[2].tq[i] - r0.tq[i]);
            norm += r0.tq[i] * r0.tq[i];
        }
        printf("    against the locked capture's unmixing: frame 5 left out %.4f, kept %.4f (relative rms)\n",
               sqrt(e_out / norm), sqrt(e_in / norm));
        CHECK(sqrt(e_out / norm) < 0.05 && sqrt(e_in / norm) > 3 * sqrt(e_out / norm));
    }
    rec_unmix_opts bad = uo;
    bad.max_drift_windows = -0.5;   /* (-1 is REC_DRIFT_AUTO) */
    rec_unmix_result rb;
    CHECK(rec_unmix(&cap, &src, &bad, &rb) == GS_EINVAL);
    rec_unmix_release(&rb);
    for (int v = 0; v < 5; v++) {
        rec_unmix_release(&r[v]);
        free(auto_sp[v]);
    }
    free(auto0);
    rec_matcher_free(m);
    rec_matcher_free(m6);
    rec_unmix_release(&r0);
    rec_sources_release(&src);
    gs_capture_release(&cap);
    gs_delight_free(d);
}

TEST(fig10_more_sources_than_the_data_support_reported_ill_posed)
{
    gs_delight *d = builtin();
    static const trfx_lamp l2[] = {
        {"a", "inc-a60-25w-230v", 0, 11.2, 8.9, 3.8, 6e6},
        {"b", "led-fil-4w-lin", 240, 32.0, 4.9, 4.5, 5e6},
    };
    trfx_opts o = {0};
    o.K = 4;
    gs_capture cap;
    rec_sources src;
    rec_unmix_result r;
    /* S = 5 sources over K = 4 windows */
    rec_source_spec sp[5] = {{"inc-a60-25w-230v", 0}, {"led-fil-4w-lin", 240}, {"cfl-23w", 120},
                             {"mh-70w", 0}, {"hps-70w", 120}};
    gs_status st = unmix_scene(fx_tmp("k4"), &o, l2, 2, sp, 5, 1, d, &cap, &src, &r);
    CHECK(st == GS_ENUMERIC && r.ill_posed && !r.tq);
    CHECK(fx_contains(gs_detail(), "ill-posed") && fx_contains(gs_detail(), "at most 4 sources"));
    printf("    S = 5, K = 4: %s\n", gs_detail());
    rec_unmix_release(&r);
    rec_sources_release(&src);
    gs_capture_release(&cap);
    /* K = 26, but two incandescent models at one phase: their BRFs hardly differ */
    o.K = 0;
    rec_source_spec sp2[3] = {{"inc-a60-25w-230v", 0}, {"inc-a60-40w-230v", 0}, {"led-fil-4w-lin", 240}};
    st = unmix_scene(fx_tmp("collinear"), &o, l2, 2, sp2, 3, 1, d, &cap, &src, &r);
    CHECK(st == GS_ENUMERIC && r.ill_posed);
    CHECK(fx_contains(gs_detail(), "ill-posed") && fx_contains(gs_detail(), "noise"));
    printf("    two incandescent models at 0 deg: %s\n", gs_detail());
    CHECK(r.predicted_error[0] > 0.5 || r.predicted_error[1] > 0.5);
    /* the message tells them from a source without light: a fair share of the fitted energy
     * for the indistinct pair, next to none for a bulb the scene does not have */
    const char *h = strstr(gs_detail(), "its image holds ");
    double pair_share = h ? atof(h + 16) : -1;
    CHECK_MSG(pair_share > 0.0 && pair_share < 100.0, "%s", gs_detail());
    rec_unmix_release(&r);
    rec_sources_release(&src);
    rec_source_spec sp3[3] = {{"inc-a60-25w-230v", 0}, {"led-fil-4w-lin", 240}, {"hps-70w", 120}};
    rec_unmix_opts uo;
    rec_unmix_opts_default(&uo);
    CHECK_OK(rec_sources_build(d, sp3, 3, 50, cap.bands, cap.K, &src, NULL));
    CHECK(rec_unmix(&cap, &src, &uo, &r) == GS_ENUMERIC && r.ill_posed);
    printf("    a bulb the scene does not have: %s\n", gs_detail());
    h = strstr(gs_detail(), "source 02 (hps-70w") ? strstr(gs_detail(), "its image holds ") : NULL;
    double share = h ? atof(h + 16) : -1;
    CHECK_MSG(share >= 0.0 && share < 0.1 * pair_share, "%s (the pair's: %g %%)", gs_detail(), pair_share);
    rec_unmix_release(&r);
    rec_sources_release(&src);
    gs_capture_release(&cap);
    gs_delight_free(d);
}

TEST(eq17_all_saturated_pixels_get_no_value_partial_ones_are_recovered)
{
    gs_delight *d = builtin();
    trfx_opts o = {0};
    o.hdr_rounds = 1;
    o.shade = 0.3;    /* bright shades: their cores saturate in every frame, even halved */
    rec_source_spec sp[5];
    specs_of(lab5, 5, sp);
    gs_capture cap;
    rec_sources src;
    rec_unmix_result r;
    const char *dir = fx_tmp("saturated");
    CHECK_OK(unmix_scene(dir, &o, lab5, 5, sp, 5, 1, d, &cap, &src, &r));
    if (!r.tq) return;
    size_t P = (size_t)cap.width * cap.height, allsat = 0, nan_ok = 1, recovered = 0, above = 0;
    float *truth[5];
    for (int s = 0; s < 5; s++) truth[s] = trfx_truth(dir, src.bulb[s], src.phase_deg[s]);
    double e2 = 0, t2 = 0;
    for (size_t p = 0; p < P; p++) {
        int y = (int)(p / (size_t)cap.width), x = (int)(p % (size_t)cap.width), sat = 0;
        for (int k = 0; k < cap.K; k++) sat += !isfinite(gs_capture_value(&cap, k, y, x, 0)) ||
                                              !isfinite(gs_capture_value(&cap, k, y, x, 1)) ||
                                              !isfinite(gs_capture_value(&cap, k, y, x, 2));
        if (sat == cap.K) {
            allsat++;
            nan_ok &= r.state[p] == REC_UNMIX_UNKNOWN;
            for (int s = 0; s < 5; s++)
                for (int b = 0; b < 3; b++) nan_ok &= isnan(r.tq[((size_t)s * P + p) * 3 + b]);
        } else if (sat > 0 && truth[0]) {
            /* recovered from the unsaturated samples (HDR, Eq. 19) */
            for (int s = 0; s < 5; s++)
                for (int b = 0; b < 3; b++) {
                    float v = r.tq[((size_t)s * P + p) * 3 + b];
                    if (!isfinite(v)) continue;
                    double t = truth[s][p * 3 + b];
                    e2 += (v - t) * (v - t);
                    t2 += t * t;
                    recovered++;
                    /* brighter than the sensor could hold at its peak */
                    if (v * 2 > (cap.saturation_dn - cap.black_level_dn) / cap.frames[0].cycles) above++;
                }
        }
    }
    printf("    %zu pixels saturated in every frame (no value), %zu values recovered from partly "
           "saturated pixels (%zu above the sensor's range) with relative error %.4f\n", allsat,
           recovered, above, sqrt(e2 / t2));
    CHECK(allsat > 0 && nan_ok);
    CHECK(r.unknown_px >= allsat);
    CHECK(recovered > 0 && above > 0);
    /* as good as the weighted least-squares oracle with the true BRFs on the same samples */
    double oracle[5], ours[5];
    trfx_oracle_errors(dir, &cap, d, &src, &r, oracle, ours);
    for (int s = 0; s < 5; s++)
        CHECK_MSG(ours[s] <= 1.25 * oracle[s], "source %d: %.4f vs the oracle's %.4f", s, ours[s], oracle[s]);
    for (int s = 0; s < 5; s++) free(truth[s]);
    rec_unmix_release(&r);
    rec_sources_release(&src);
    gs_capture_release(&cap);
    gs_delight_free(d);
}

/* K = 9 with five sources: a pixel saturated in five or more frames has fewer usable samples
 * than sources. None of them may get a value (a fit without one of them gives its light to the
 * others: the given values were 2-12x off), and the values of partly saturated pixels are as
 * good as those of complete ones (the truth: the simulator's tau Q). */
TEST(eq17_fewer_usable_samples_than_sources_no_value_given)
{
    gs_delight *d = builtin();
    trfx_opts o = {0};
    o.K = 9;
    o.hdr_rounds = 1;
    o.shade = 0.3;
    rec_source_spec sp[5];
    specs_of(lab5, 5, sp);
    gs_capture cap;
    rec_sources src;
    rec_unmix_result r;
    const char *dir = fx_tmp("k7_saturated");
    CHECK_OK(unmix_scene(dir, &o, lab5, 5, sp, 5, 1, d, &cap, &src, &r));
    if (!r.tq) return;
    size_t P = (size_t)cap.width * cap.height, few = 0, given_few = 0;
    float *truth[5];
    for (int s = 0; s < 5; s++) truth[s] = trfx_truth(dir, src.bulb[s], src.phase_deg[s]);
    double e2[2] = {0, 0}, t2[2] = {0, 0};   /* complete pixels, partly saturated ones */
    for (size_t p = 0; p < P && truth[4]; p++) {
        int y = (int)(p / (size_t)cap.width), x = (int)(p % (size_t)cap.width), usable = 0;
        for (int k = 0; k < cap.K; k++)
            usable += isfinite(gs_capture_value(&cap, k, y, x, 0)) && isfinite(gs_capture_value(&cap, k, y, x, 1)) &&
                      isfinite(gs_capture_value(&cap, k, y, x, 2));
        few += usable > 0 && usable < 5;
        for (int s = 0; s < 5; s++)
            for (int b = 0; b < 3; b++) {
                float v = r.tq[((size_t)s * P + p) * 3 + b];
                if (!isfinite(v)) continue;
                given_few += usable < 5;
                double t = truth[s][p * 3 + b];
                e2[usable < cap.K] += (v - t) * (v - t);
                t2[usable < cap.K] += t * t;
            }
    }
    double err[2] = {sqrt(e2[0] / t2[0]), t2[1] > 0 ? sqrt(e2[1] / t2[1]) : 0};
    printf("    %zu pixels with 1-4 usable samples of %d (values given: %zu); relative error %.3f in "
           "complete pixels, %.3f in partly saturated ones\n", few, cap.K, given_few, err[0], err[1]);
    CHECK(few > 0 && given_few == 0);
    CHECK_MSG(err[1] <= 2.0 * err[0], "partly saturated pixels: error %.3f, complete ones %.3f", err[1], err[0]);
    for (int s = 0; s < 5; s++) free(truth[s]);
    rec_unmix_release(&r);
    rec_sources_release(&src);
    gs_capture_release(&cap);
    gs_delight_free(d);
}

TEST(near_flat_brf_source_unmixed_within_1_25x_of_the_oracle)
{
    gs_delight *d = builtin();
    /* led-a60-9w-cap flickers 3.2 %: almost the constant vector */
    static const trfx_lamp l[] = {
        {"flat", "led-a60-9w-cap", 0, 11.2, 8.9, 3.8, 6e6},
        {"cfl", "cfl-23w", 120, 52.9, 7.2, 4.2, 6e6},
        {"fil", "led-fil-4w-lin", 240, 32.0, 4.9, 4.5, 5e6},
    };
    rec_source_spec sp[3];
    specs_of(l, 3, sp);
    trfx_opts o = {0};
    gs_capture cap;
    rec_sources src;
    rec_unmix_result r;
    const char *dir = fx_tmp("flat");
    CHECK_OK(unmix_scene(dir, &o, l, 3, sp, 3, 1, d, &cap, &src, &r));
    double oracle[3], ours[3];
    if (r.tq) {
        trfx_oracle_errors(dir, &cap, d, &src, &r, oracle, ours);
        printf("    near-flat source: error %.4f, oracle %.4f\n", ours[0], oracle[0]);
        for (int s = 0; s < 3; s++) CHECK(ours[s] <= 1.25 * oracle[s]);
        CHECK(ours[0] < 0.2);
    }
    rec_unmix_release(&r);
    rec_sources_release(&src);
    gs_capture_release(&cap);
    gs_delight_free(d);
}

TEST(daylight_constant_source_unmixed_within_1_25x_of_the_oracle)
{
    gs_delight *d = builtin();
    static const trfx_lamp l[] = {
        {"cfl", "cfl-23w", 120, 52.9, 7.2, 4.2, 6e6},
        {"fil", "led-fil-4w-lin", 240, 32.0, 4.9, 4.5, 5e6},
    };
    rec_source_spec sp[3] = {{"cfl-23w", 120}, {"led-fil-4w-lin", 240}, {"daylight", 0}};
    trfx_opts o = {0};
    o.daylight_e = 300;
    gs_capture cap;
    rec_sources src;
    rec_unmix_result r;
    const char *dir = fx_tmp("daylight");
    CHECK_OK(unmix_scene(dir, &o, l, 2, sp, 3, 1, d, &cap, &src, &r));
    CHECK(src.fixed[2] && !src.fixed[0]);
    double oracle[3], ours[3];
    if (r.tq) {
        trfx_oracle_errors(dir, &cap, d, &src, &r, oracle, ours);
        printf("    daylight: error %.4f, oracle %.4f; its BRF stays all ones: %g\n", ours[2], oracle[2], r.b[2 * 3 * 26 + 7]);
        for (int s = 0; s < 3; s++) CHECK(ours[s] <= 1.25 * oracle[s]);
        for (int i = 0; i < 3 * 26; i++) CHECK(r.b[2 * 3 * 26 + i] == 1.0);
    }
    rec_unmix_release(&r);
    rec_sources_release(&src);
    gs_capture_release(&cap);
    gs_delight_free(d);
}

TEST(k2_two_sources_unmixed_three_ill_posed)
{
    gs_delight *d = builtin();
    static const trfx_lamp l[] = {
        {"fil", "led-fil-4w-lin", 120, 11.2, 8.9, 3.8, 6e6},
        {"hps", "hps-70w", 0, 52.9, 7.2, 4.2, 6e6},
    };
    rec_source_spec sp[3];
    specs_of(l, 2, sp);
    trfx_opts o = {0};
    o.K = 2;
    gs_capture cap;
    rec_sources src;
    rec_unmix_result r;
    const char *dir = fx_tmp("k2");
    CHECK_OK(unmix_scene(dir, &o, l, 2, sp, 2, 1, d, &cap, &src, &r));
    double oracle[2], ours[2];
    if (r.tq) {
        trfx_oracle_errors(dir, &cap, d, &src, &r, oracle, ours);
        printf("    K = 2: errors %.4f, %.4f; oracle %.4f, %.4f\n", ours[0], ours[1], oracle[0], oracle[1]);
        for (int s = 0; s < 2; s++) CHECK(ours[s] <= 1.25 * oracle[s]);
    }
    rec_unmix_release(&r);
    rec_sources_release(&src);
    rec_unmix_opts uo;
    rec_unmix_opts_default(&uo);
    snprintf(sp[2].bulb, sizeof sp[2].bulb, "cfl-23w");
    sp[2].phase_deg = 240;
    CHECK_OK(rec_sources_build(d, sp, 3, 50, 3, 2, &src, NULL));
    CHECK(rec_unmix(&cap, &src, &uo, &r) == GS_ENUMERIC && r.ill_posed);
    rec_unmix_release(&r);
    rec_sources_release(&src);
    gs_capture_release(&cap);
    gs_delight_free(d);
}

/* ------------------------------------------------------------------ relighting */


TEST_TIMEOUT(eq20_relight_source_off_matches_a_capture_without_it_within_5_percent, 600)
{
    gs_delight *d = builtin();
    trfx_opts o = {0};
    o.hdr_rounds = 3;
    rec_source_spec sp[5];
    specs_of(lab5, 5, sp);
    gs_capture cap, off;
    rec_sources src;
    rec_unmix_result r;
    CHECK_OK(unmix_scene(fx_tmp("full"), &o, lab5, 5, sp, 5, 1, d, &cap, &src, &r));
    char *text = trfx_scene(&o, lab5, 4);   /* without mh70, the last lamp */
    CHECK(trfx_render(text, fx_tmp("off"), &off));
    free(text);
    size_t n = (size_t)cap.width * cap.height * 3;
    float *fr = malloc(sizeof *fr * n * (size_t)cap.K), *mr = malloc(sizeof *mr * n), *mo = malloc(sizeof *mo * n);
    rec_relight_set set[5];
    memset(set, 0, sizeof set);
    for (int s = 0; s < 5; s++) set[s].gain = s == 4 ? 0 : 1;
    if (r.tq) {
        /* the refined BRFs, as unmix writes them to sources.json */
        memcpy(src.b, r.b, sizeof *src.b * (size_t)5 * 3 * cap.K);
        CHECK_OK(rec_relight(&src, r.tq, cap.width, cap.height, d, 50, set, fr));
        gs_capture rc;
        rec_capture_meta meta;
        rec_capture_meta_of(&cap, &meta);
        CHECK_OK(rec_frames_to_capture(&meta, fr, &rc));
        gs_capture_mean_image(&rc, 0, mr);
        gs_capture_mean_image(&off, 0, mo);
        for (size_t i = 0; i < n; i++)
            if (!isfinite(mo[i])) mr[i] = NAN;
        double e = srv_tr_rel_error(mr, mo, n / 3, 3);
        printf("    source mh70 switched off vs a capture without it: %.4f\n", e);
        CHECK(e < 0.05);
        /* and every source on reproduces the input */
        for (int s = 0; s < 5; s++) set[s].gain = 1;
        CHECK_OK(rec_relight(&src, r.tq, cap.width, cap.height, d, 50, set, fr));
        gs_capture_release(&rc);
        CHECK_OK(rec_frames_to_capture(&meta, fr, &rc));
        gs_capture_mean_image(&rc, 0, mr);
        gs_capture_mean_image(&cap, 0, mo);
        for (size_t i = 0; i < n; i++)
            if (!isfinite(mo[i])) mr[i] = NAN;
        double e1 = srv_tr_rel_error(mr, mo, n / 3, 3);
        printf("    all sources on vs the input: %.4f\n", e1);
        CHECK(e1 < 0.02);
        /* a phase change: that source's term takes DELIGHT's BRF shifted exactly (Eq. 14) */
        float *f2 = malloc(sizeof *f2 * n * (size_t)cap.K);
        set[2].set_phase = 1;
        set[2].phase_deg = 120;
        CHECK_OK(rec_relight(&src, r.tq, cap.width, cap.height, d, 50, set, f2));
        double want[3 * 26], worst = 0, scale = 0;
        const gs_bulb *fil = gs_delight_find(d, "led-fil-4w-lin", 50, 3);
        CHECK_OK(gs_brf_integrate(&fil->brf, gs_phase_to_shift(120), cap.K, want));
        size_t P = n / 3;
        for (size_t p = 0; p < P; p++)
            for (int b = 0; b < 3; b++) {
                float t = r.tq[(2 * P + p) * 3 + b];
                if (!isfinite(t)) continue;
                for (int k = 0; k < cap.K; k++) {
                    double ex = t * (want[b * cap.K + k] - r.b[(2 * 3 + b) * cap.K + k]);
                    double got = f2[((size_t)k * P + p) * 3 + b] - fr[((size_t)k * P + p) * 3 + b];
                    if (fabs(got - ex) > worst) worst = fabs(got - ex);
                    if (fabs(ex) > scale) scale = fabs(ex);
                }
            }
        CHECK_MSG(worst <= 1e-4 * scale + 1e-4, "phase change: %.3g off (scale %.3g)", worst, scale);
        /* its own phase given as itself + 360 deg is no change: the refined BRF stays (a phase
         * that is not a whole number too: fmod(240.3 + 360, 360) is 240.29999999999995) */
        set[2].phase_deg = src.phase_deg[2] + 360.0;
        CHECK_OK(rec_relight(&src, r.tq, cap.width, cap.height, d, 50, set, f2));
        CHECK(!memcmp(f2, fr, sizeof *f2 * n * (size_t)cap.K));
        double own = src.phase_deg[2];
        src.phase_deg[2] = 240.3;
        set[2].phase_deg = 240.3 + 360.0;
        CHECK_OK(rec_relight(&src, r.tq, cap.width, cap.height, d, 50, set, f2));
        CHECK(!memcmp(f2, fr, sizeof *f2 * n * (size_t)cap.K));
        src.phase_deg[2] = own;
        /* nor its phase + 180 deg, the same flicker (the BRF spans half an AC cycle): it took
         * DELIGHT's BRF for the refined one */
        set[2].phase_deg = own + 180.0;
        CHECK_OK(rec_relight(&src, r.tq, cap.width, cap.height, d, 50, set, f2));
        CHECK(!memcmp(f2, fr, sizeof *f2 * n * (size_t)cap.K));
        free(f2);
        set[2].set_phase = 0;
        gs_capture_release(&rc);
        /* bad gains and bulbs */
        set[1].gain = -1;
        CHECK(rec_relight(&src, r.tq, cap.width, cap.height, d, 50, set, fr) == GS_EINVAL);
        set[1].gain = 1;
        snprintf(set[1].bulb, sizeof set[1].bulb, "no-such-bulb");
        CHECK(rec_relight(&src, r.tq, cap.width, cap.height, d, 50, set, fr) == GS_ENOTFOUND);
    }
    free(fr);
    free(mr);
    free(mo);
    rec_unmix_release(&r);
    rec_sources_release(&src);
    gs_capture_release(&cap);
    gs_capture_release(&off);
    gs_delight_free(d);
}

TEST(relight_frames_to_capture_round_trip_with_hdr_and_nan)
{
    rec_capture_meta m = {50, 2, 1, 3, 1, 1, 100, 4095, 64, 5, 1};
    float fr[6] = {1.0f, 100.0f, NAN, 0.5f, 3000.0f, 0.0f};
    gs_capture cap;
    CHECK_OK(rec_frames_to_capture(&m, fr, &cap));
    const char *dir = fx_tmp("relit");
    for (int k = 0; k < 2; k++) CHECK_OK(gs_capture_write_frame(dir, &cap, k));
    CHECK_OK(gs_capture_write_json(dir, &cap));
    gs_capture back;
    CHECK_OK(gs_capture_read(dir, &back));
    for (int k = 0; k < 2; k++)
        for (int x = 0; x < 3; x++) {
            double v = gs_capture_value(&back, k, 0, x, 0), want = fr[k * 3 + x];
            if (isnan(want)) CHECK(isnan(v));
            else CHECK_MSG(fabs(v - want) <= 0.5 * (1 << back.halvings[k * 3 + x]) / 100.0 + 1e-9,
                           "frame %d pixel %d: %g vs %g", k, x, v, want);
        }
    /* 100 and 3000 DN per cycle exceed the 12-bit sensor at C = 100: halved, not clipped */
    CHECK(back.halvings[1] > 0 && back.halvings[4] > 0);
    gs_capture_release(&cap);
    gs_capture_release(&back);
}

/* ------------------------------------------------------------------ separation */

TEST(mutual_information_histogram_estimator_vs_gaussian_formula)
{
    size_t n = 65536;
    float *x = malloc(sizeof *x * n), *y = malloc(sizeof *y * n), *z = malloc(sizeof *z * n);
    uint64_t seed = 5;
    double rho = 0.8;
    for (size_t i = 0; i < n; i++) {
        x[i] = (float)gs_splitmix_normal(&seed);
        double e = gs_splitmix_normal(&seed);
        y[i] = (float)(rho * x[i] + sqrt(1 - rho * rho) * e);
        z[i] = (float)gs_splitmix_normal(&seed);
    }
    double mi = rec_mutual_information(x, y, n, 32), mi0 = rec_mutual_information(x, z, n, 32);
    double want = -0.5 * log(1 - rho * rho);
    printf("    rho 0.8: %.4f nats (Gaussian formula %.4f); independent: %.4f\n", mi, want, mi0);
    CHECK(fabs(mi - want) < 0.05 && mi0 < 0.02);
    CHECK(isnan(rec_mutual_information(x, y, n, 1)));
    free(x);
    free(y);
    free(z);
}

TEST(sec53_separation_ncc_at_least_0_97_with_the_true_components)
{
    /* capture/scenes/window.json at 160 x 120 */
    const char *text =
        "{\"format\": \"gridsurvey-scene/1\", \"seed\": 6, \"grid\": {\"nominal_hz\": 50},\n"
        " \"camera\": {\"width_px\": 160, \"height_px\": 120, \"intrinsics\": {\"focal_px\": 160},\n"
        "   \"sensor\": {\"bands\": 3, \"bit_depth\": 12, \"full_well_e\": 20000, \"read_noise_e\": 4, \"gain_e_per_dn\": 5, \"black_level_dn\": 64}},\n"
        " \"acam\": {\"K\": 26, \"cycles\": 1024, \"masks\": 64},\n"
        " \"lights\": [{\"id\": \"tube\", \"bulb\": \"fl-t8-36w-tri\", \"phase_deg\": 120, \"x_px\": -60, \"y_px\": 10, \"distance_m\": 2.5, \"flux_e_per_cycle\": 8e8}],\n"
        " \"effects\": {\"light_transport\": {\"room\": {\"width_m\": 5, \"height_m\": 3, \"depth_m\": 5, \"floor_m\": 1.5, \"albedo\": [0.8, 0.75, 0.7], \"checker_m\": 0.6, \"contrast\": 0.8},\n"
        "   \"boxes\": [{\"min_m\": [-1.6, 0.2, 2.4], \"max_m\": [-0.4, 1.5, 3.4], \"albedo\": [0.85, 0.35, 0.2]}]},\n"
        "  \"semi_reflection\": {\"reflectance\": 0.3, \"outdoor_e_per_px_cycle\": 250, \"chroma\": [0.3, 0.34, 0.36]},\n"
        "  \"shot_noise\": {}, \"saturation\": {}, \"read_noise\": {}, \"adc\": {}}}\n";
    const char *dir = fx_tmp("window");
    gs_capture cap;
    CHECK(trfx_render(text, dir, &cap));
    rec_separation sep;
    CHECK_OK(rec_separate(&cap, &sep));
    float *to = trfx_truth(dir, REC_DAYLIGHT, 0), *ta = trfx_truth(dir, "fl-t8-36w-tri", 120);
    size_t n = (size_t)cap.width * cap.height * 3;
    if (sep.transmitted && to && ta) {
        double nt = srv_tr_ncc(sep.transmitted, to, n), nr = srv_tr_ncc(sep.reflection, ta, n);
        printf("    NCC transmitted %.4f, reflection %.4f; A = %.3f %.3f %.3f\n", nt, nr, sep.A[0],
               sep.A[1], sep.A[2]);
        CHECK(nt >= 0.97 && nr >= 0.97);
        for (int b = 0; b < 3; b++) CHECK(sep.mi[b] <= sep.mi_a0[b]);
    }
    free(to);
    free(ta);
    rec_separation_release(&sep);
    gs_capture_release(&cap);
}

/* A lamp shade is a uniform disk carrying `transmission` of its light's flux (docs/scene.md):
 * with black walls (albedo 0: no transport) every frame holds exactly transmission x the frame
 * of the same light without the effect (flux conservation), for small and large disks anywhere
 * on the pixel grid. The disk's area came from 4 x 4 sub-samples per pixel but was divided by
 * pi R^2: a shade carried 0.955 of its transmission at R = 0.5 px, 1.035 at 1 and 2 px, 1.010 at
 * 4 px (capture/scenes/lab_transport.json); and a lone light's disk overran its weights' array
 * (sized for a (2r+1)^2 box, the disk's is (2r+2)^2: this test crashed). */
TEST(sim_lamp_shade_carries_its_transmission)
{
    static const char *fmt =
        "{\"format\": \"gridsurvey-scene/1\", \"grid\": {\"nominal_hz\": 50},\n"
        " \"camera\": {\"width_px\": 24, \"height_px\": 20, \"sensor\": {\"bands\": 1}},\n"
        " \"acam\": {\"K\": 4, \"cycles\": 8},\n"
        " \"lights\": [{\"bulb\": \"hps-150w\", \"x_px\": %g, \"y_px\": %g, \"distance_m\": 2, \"flux_e_per_cycle\": 1000}],\n"
        " \"effects\": {%s}}\n";
    const double radius[] = {0.5, 1, 2, 2.7, 4};
    /* the last: at x = 0.3 a disk of R = 2 px has the circular segment beyond the image's edge
     * (x = -0.5, 0.8 px from its centre) off the sensor: 1 - (4 acos(0.4) - 0.8 sqrt(3.36)) /
     * (4 pi) = 0.7477 of its flux reaches the image */
    const double pos[][2] = {{11, 9}, {11.3, 9.8}, {12.5, 10.5}, {0.3, 10}};
    gs_delight *d = builtin();
    double worst = 1, edge = 0;
    for (size_t i = 0; i < sizeof radius / sizeof *radius; i++)
        for (size_t j = 0; j < sizeof pos / sizeof *pos; j++) {
            if (j == 3 && radius[i] != 2) continue;
            double sum[2] = {0, 0};
            for (int e = 0; e < 2; e++) {
                char fx[256], text[1024];
                snprintf(fx, sizeof fx, "\"light_transport\": {\"room\": {\"width_m\": 6, \"height_m\": 4, "
                         "\"depth_m\": 8, \"albedo\": 0}, \"lamp_shade\": {\"radius_px\": %g, \"transmission\": 0.5}}",
                         radius[i]);
                snprintf(text, sizeof text, fmt, pos[j][0], pos[j][1], e ? fx : "");
                cap_scene sc;
                CHECK_OK(cap_scene_parse(text, "shade.json", ".", &sc));
                cap_sim *s = NULL;
                CHECK_OK(cap_sim_new(&sc, d, &s));
                double dn[24 * 20];
                for (int k = 0; s && k < 4; k++) {
                    CHECK_OK(cap_sim_render(s, k, 0, k, NULL, NULL, dn));
                    for (int p = 0; p < 24 * 20; p++) sum[e] += dn[p];
                }
                cap_sim_free(s);
                cap_scene_release(&sc);
            }
            double r = sum[1] / (0.5 * sum[0]);
            if (j == 3) edge = r;
            else if (fabs(r - 1) > fabs(worst - 1)) worst = r;
        }
    double edge_want = 1 - (4 * acos(0.4) - 0.8 * sqrt(3.36)) / (4 * M_PI);
    printf("    lamp shades, R 0.5 to 4 px: flux carried / transmission, worst %.12f; a disk cut by "
           "the image's edge %.4f (its area on the image %.4f)\n", worst, edge, edge_want);
    CHECK(fabs(worst - 1) < 1e-12);
    CHECK_NEAR(edge, edge_want, 0.02);
    gs_delight_free(d);
}

static int cmp_float_asc(const void *a, const void *b)
{
    float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

/* The white of a picture is the 99.5th percentile of all its samples, every band: a 400 x 300
 * RGB picture whose red is dim and green bright (the unmix demo's size, where a stride over the
 * interleaved samples that is a multiple of 3 reads only red) gets a white between the 99th and
 * 99.9th percentiles of every sample, sorted by brute force. */
TEST(png_white_is_a_percentile_of_every_band)
{
    int w = 400, h = 300;
    size_t n = (size_t)w * (size_t)h * 3;
    float *img = malloc(sizeof *img * n), *all = malloc(sizeof *all * n);
    CHECK(img && all);
    if (!img || !all) {
        free(img);
        free(all);
        return;
    }
    for (size_t p = 0; p < n / 3; p++) {
        double u = (double)((p * 7919) % 10007) / 10007.0;   /* spread over [0, 1) */
        img[3 * p] = (float)u;                              /* red: dim */
        img[3 * p + 1] = (float)(100.0 * u);                /* green: bright */
        img[3 * p + 2] = (float)(10.0 * u);
    }
    memcpy(all, img, sizeof *all * n);
    qsort(all, n, sizeof *all, cmp_float_asc);
    double lo = all[(size_t)(0.990 * (double)(n - 1))], hi = all[(size_t)(0.999 * (double)(n - 1))];
    double white = rec_png_white(img, w, h, 3);
    CHECK_MSG(white >= lo && white <= hi, "white %g: expected the 99.5th percentile of all samples, %g..%g",
              white, lo, hi);
    free(img);
    free(all);
}
