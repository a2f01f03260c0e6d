/* internal.h - recognize/ internals shared between its own files; other modules never
 * include it. */
#ifndef GRIDSURVEY_RECOGNIZE_INTERNAL_H
#define GRIDSURVEY_RECOGNIZE_INTERNAL_H

#include "recognize/recognize.h"

#include <complex.h>

/* DFT C[0..n/2] of x[0..n) (FFTW r2c convention: C_h = sum_j x_j e^{-2 pi i h j / n}). */
gs_status rec_brf_spectrum(const double *x, int n, double complex *C);

/* Consistency checks of one DELIGHT entry (id, ranges, BRF mean 1, chroma sums to 1). */
gs_status rec_bulb_validate(const rec_bulb *b);

/* ============ capture directory and blobs (capture_format.c, blobs.c, opencv_shim.cpp) ============ */

/* GS_OK if every field of cap except the pixels follows docs/formats.md (frames must be set),
 * else GS_EINVAL with the detail "WHO: field F: expected E". */
gs_status rec_capture_check(const rec_capture *cap, const char *who);

/* OpenCV shim (recognize/opencv_shim.cpp), the only C++ in recognize/: plain C functions over
 * OpenCV 4 (core, imgproc, imgcodecs).
 * Every OpenCV or C++ exception is caught at this boundary and returned as a gs_status with a
 * gs_fail detail. Pixel buffers are borrowed and row-major with interleaved channels. */

/* Decode the PNG held in buf[0..size) into out: exactly width x height pixels of `channels`
 * (1 or 3) channels of 16 bits (depth16 = 1, out is unsigned short) or 8 bits (depth16 = 0,
 * out is unsigned char). A 3-channel image comes out in R, G, B order (OpenCV decodes BGR).
 * name is only used in the detail. GS_EFORMAT when libpng cannot decode the data or the decoded
 * image differs from what was expected. */
gs_status rec_cv_png_decode(const unsigned char *buf, size_t size, const char *name, int width,
                            int height, int channels, int depth16, void *out);
/* Encode width x height pixels of `channels` (1 or 3, R G B order) channels of 16 bits
 * (depth16 = 1, unsigned short) or 8 bits as a PNG in memory: *png is malloc'd (the caller
 * free()s it), *size its length. */
gs_status rec_cv_png_encode(const void *pixels, int width, int height, int channels, int depth16,
                            unsigned char **png, size_t *size);
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
/* ====================== end of capture directory, blobs and OpenCV shim ====================== */

#endif
