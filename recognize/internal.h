/* internal.h - recognize/ internals shared between its own files; other modules never
 * include it. */
#ifndef GRIDSURVEY_RECOGNIZE_INTERNAL_H
#define GRIDSURVEY_RECOGNIZE_INTERNAL_H

#include "recognize/recognize.h"

#include <complex.h>

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
/* ====================== end of capture directory, blobs and OpenCV shim ====================== */

#endif
