/* transport_png.c - the pictures of light transport (paper Figs. 4-6): a float image (DN per
 * cycle) tone-mapped to an 8-bit RGB PNG. */
#include "recognize/recognize.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static int cmp_float(const void *a, const void *b)
{
    float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

double rec_png_white(const float *img, int width, int height, int bands)
{
    /* every band of evenly spaced pixels (a stride over the interleaved samples that is a
     * multiple of bands would read one band only) */
    size_t P = (size_t)width * (size_t)height, m = 0, step = P * (size_t)bands / 65536 + 1;
    float *v = malloc(sizeof *v * (P / step + 1) * (size_t)bands);
    if (!v) return NAN;
    for (size_t p = 0; p < P; p += step)
        for (int c = 0; c < bands; c++)
            if (isfinite(img[p * (size_t)bands + (size_t)c])) v[m++] = img[p * (size_t)bands + (size_t)c];
    double w = NAN;
    if (m) {
        qsort(v, m, sizeof *v, cmp_float);
        w = v[(size_t)(0.995 * (double)(m - 1))];
    }
    free(v);
    return w > 0 ? w : 1.0;
}

gs_status rec_write_image_png(const char *path, const float *img, int width, int height,
                              int bands, double white)
{
    if (!(white > 0)) white = rec_png_white(img, width, height, bands);
    size_t P = (size_t)width * (size_t)height;
    unsigned char *rgb = malloc(P * 3);
    if (!rgb) return gs_fail(GS_ENOMEM, "%s: out of memory", path);
    for (size_t p = 0; p < P; p++)
        for (int c = 0; c < 3; c++) {
            float x = img[p * (size_t)bands + (size_t)(bands == 3 ? c : 0)];
            int any_nan = 0;
            for (int b = 0; b < bands; b++) any_nan |= !isfinite(img[p * (size_t)bands + (size_t)b]);
            double t = x / white;
            t = t < 0 ? 0 : t > 1 ? 1 : t;
            /* sRGB-like gamma; unknown pixels (NaN) magenta */
            rgb[p * 3 + (size_t)c] = any_nan ? (unsigned char)(c == 1 ? 0 : 255)
                                             : (unsigned char)floor(255.0 * pow(t, 1 / 2.2) + 0.5);
        }
    unsigned char *png = NULL;
    size_t size = 0;
    gs_status st = gs_png_encode(rgb, width, height, 3, 8, &png, &size);
    free(rgb);
    if (st == GS_OK) st = gs_file_write_atomic(path, png, size);
    free(png);
    return st;
}
