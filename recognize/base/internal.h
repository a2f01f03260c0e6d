/* internal.h - recognize/base/ internals shared between its own files; other modules never
 * include it (tests may). */
#ifndef GRIDSURVEY_BASE_INTERNAL_H
#define GRIDSURVEY_BASE_INTERNAL_H

#include "recognize/base/base.h"

/* before <fftw3.h>: makes fftw_complex the C99 double complex */
#include <complex.h>

/* Consistency checks of one DELIGHT entry (id, ranges, BRF mean 1, chroma sums to 1). */
gs_status gs_bulb_validate(const gs_bulb *b);

#endif
