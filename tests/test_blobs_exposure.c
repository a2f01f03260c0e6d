/* test_blobs_exposure.c - detection does not fall as the exposure grows (issue 13): a window of
 * the built-in metro scene (PSF, skyglow halos, ambient light, shot and read noise, HDR), without
 * extinction and scintillation, acquired through the HDR loop at C = 64, 256 and 1024 cycles a
 * frame; rec_blobs_extract's lights are matched one-to-one (nearest first, brute force) within
 * 2 px to the simulator's resolvable lights (capture/truth_resolve.c). Longer exposures only
 * raise the SNR, so the resolvable lights found may not drop by more than one light from one C
 * to the next, nor the false detections rise by more than one. */
#include "capture/sim.h"
#include "recognize/recognize.h"
#include "tests/blobs_fixture.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <jansson.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The metro scene cropped to w x h at (x0, y0) with K windows and C cycles (as bench accuracy's
 * metro_clear). Returns the scene text (free()). */
static char *clear_window(int x0, int y0, int w, int h, int K, long C)
{
    json_error_t je;
    json_t *root = json_load_file("capture/scenes/metro.json", 0, &je);
    if (!root) return NULL;
    json_t *cam = json_object_get(root, "camera"), *acam = json_object_get(root, "acam");
    json_t *in = json_object_get(cam, "intrinsics"), *fx = json_object_get(root, "effects");
    double W = (double)json_integer_value(json_object_get(cam, "width_px"));
    double H = (double)json_integer_value(json_object_get(cam, "height_px"));
    json_object_set_new(in, "cx_px", json_real(W / 2 - x0));
    json_object_set_new(in, "cy_px", json_real(H / 2 - y0));
    json_object_set_new(cam, "width_px", json_integer(w));
    json_object_set_new(cam, "height_px", json_integer(h));
    json_object_set_new(acam, "K", json_integer(K));
    json_object_set_new(acam, "cycles", json_integer(C));
    json_t *hdr = json_object();
    json_object_set_new(hdr, "enabled", json_true());
    json_object_set_new(hdr, "max_saturated_px", json_integer(10));
    json_object_set_new(acam, "hdr", hdr);
    json_object_del(fx, "extinction");
    json_object_del(fx, "scintillation");
    char *text = json_dumps(root, 0);
    json_decref(root);
    return text;
}

typedef struct {
    int resolvable, found, stored, false_det;
} exposure_score;

/* Acquire the window at C cycles and score its blobs against the truth. */
static exposure_score score_at(long C)
{
    exposure_score r = {0, 0, 0, 0};
    char *text = clear_window(700, 380, 240, 135, 8, C);
    CHECK(text != NULL);
    if (!text) return r;
    char name[64];
    snprintf(name, sizeof name, "exposure-%ld", C);
    cap_scene sc;
    const char *path;
    cap_backend *be = blobfx_acquire(text, name, &sc, &path);
    free(text);
    if (!be) {
        cap_scene_release(&sc);
        return r;
    }
    const cap_sim *s = cap_backend_sim_handle(be);
    size_t n = s->n;
    unsigned char *res = malloc(n ? n : 1), *used = calloc(n ? n : 1, 1);
    int *grp = malloc((n ? n : 1) * sizeof *grp), ng = 0;
    CHECK_OK(cap_resolve(s, res, grp, &ng));
    gs_capture cap;
    CHECK_OK(gs_capture_read(path, &cap));
    rec_blob_opts bo;
    rec_blob_opts_default(&bo);
    rec_catalog cat;
    CHECK_OK(rec_blobs_extract(&cap, &bo, &cat));
    /* one-to-one, nearest first: repeatedly the closest unused (stored, truth) pair */
    unsigned char *taken = calloc(cat.count ? cat.count : 1, 1);
    for (;;) {
        double best = 2.0;
        size_t bi = 0, bj = 0;
        int any = 0;
        for (size_t i = 0; i < cat.count; i++) {
            if (taken[i]) continue;
            for (size_t j = 0; j < n; j++) {
                if (used[j] || !sc.lights[j].in_image) continue;
                double dd = hypot(cat.x_px[i] - sc.lights[j].x_px, cat.y_px[i] - sc.lights[j].y_px);
                if (dd <= best) {
                    best = dd;
                    bi = i;
                    bj = j;
                    any = 1;
                }
            }
        }
        if (!any) break;
        taken[bi] = used[bj] = 1;
    }
    for (size_t j = 0; j < n; j++) {
        r.resolvable += res[j];
        r.found += res[j] && used[j];
    }
    r.stored = (int)cat.count;
    for (size_t i = 0; i < cat.count; i++) r.false_det += !taken[i];
    free(taken);
    free(res);
    free(used);
    free(grp);
    rec_catalog_release(&cat);
    gs_capture_release(&cap);
    cap_backend_free(be);
    cap_scene_release(&sc);
    return r;
}

TEST(blobs_detection_does_not_fall_with_exposure)
{
    const long C[3] = {64, 256, 1024};
    exposure_score sc[3];
    for (int i = 0; i < 3; i++) {
        sc[i] = score_at(C[i]);
        printf("    C = %4ld: %d / %d resolvable lights found, %d stored, %d false\n", C[i], sc[i].found,
               sc[i].resolvable, sc[i].stored, sc[i].false_det);
    }
    CHECK(sc[0].resolvable >= 50);
    for (int i = 1; i < 3; i++) {
        CHECK_MSG(sc[i].found >= sc[i - 1].found - 1, "C = %ld: %d found, C = %ld: %d", C[i], sc[i].found,
                  C[i - 1], sc[i - 1].found);
        CHECK_MSG(sc[i].false_det <= sc[i - 1].false_det + 1, "C = %ld: %d false, C = %ld: %d", C[i],
                  sc[i].false_det, C[i - 1], sc[i - 1].false_det);
    }
    /* and the window is mostly found: detection is not monotone by finding nothing */
    CHECK(sc[0].found >= 0.9 * sc[0].resolvable);
}
