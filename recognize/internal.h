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


#endif
