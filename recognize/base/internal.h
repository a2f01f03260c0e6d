/* internal.h - recognize/base/ internals shared between its own files; other modules never
 * include it (tests may). */
#ifndef GRIDSURVEY_BASE_INTERNAL_H
#define GRIDSURVEY_BASE_INTERNAL_H

#include "recognize/base/base.h"

/* before <fftw3.h>: makes fftw_complex the C99 double complex */
#include <complex.h>

/* Consistency checks of one DELIGHT entry (id, ranges, BRF mean 1, chroma sums to 1). */
gs_status gs_bulb_validate(const gs_bulb *b);

/* ----------------------------------------- capture format rules (capture_check.c) */

/* Ranges of the format (docs/formats.md). K: the ACam reaches 26 (paper Fig. 7); 1024 bounds
 * memory for a file that is wrong. Sides: 32768 pixels. Halvings: the ACam's DMD holds M = 96
 * masks, so at most floor(log2(M/2)) = 5..6 halvings (paper footnote 5); GS_MAX_HALVINGS = 16
 * leaves room. */
#define GS_CAPTURE_MAX_K 1024
#define GS_CAPTURE_MAX_SIDE 32768
#define GS_CAPTURE_MAX_SATURATION 65536.0
/* Expected values, in the words of docs/formats.md. */
#define GS_CAPTURE_EXP_FORMAT "the string \"" GS_CAPTURE_FORMAT "\""
#define GS_CAPTURE_EXP_GRID "50 or 60 (an integer)"
#define GS_CAPTURE_EXP_K "an integer from 2 to 1024"
#define GS_CAPTURE_EXP_BANDS "1 or 3 (an integer)"
#define GS_CAPTURE_EXP_SIDE "an integer from 1 to 32768"
#define GS_CAPTURE_EXP_NONNEG "a finite number >= 0"
#define GS_CAPTURE_EXP_LOCKED "true or false"
#define GS_CAPTURE_EXP_UTC "an ISO 8601 time like \"2017-07-21T22:05:00Z\" (at most 39 characters)"
#define GS_CAPTURE_EXP_FILE "a file name of letters, digits, '.', '_' or '-' that ends in \".png\", does not " \
                 "start with '.' and has at most 255 characters"
#define GS_CAPTURE_EXP_CYCLES "a finite number > 0"
#define GS_CAPTURE_EXP_HZ_MEASURED "a finite number from 45 to 65 (Hz)"
#define GS_CAPTURE_EXP_START "a finite number >= 0 (s)"

/* One problem of a capture: the field (e.g. "frames[3].cycles") and the expected value. */
typedef struct {
    char field[64];
    char expect[320];
} gs_capture_problem;
/* 1 if valid, else 0 with *pr set. The geometry fields (K, bands, width, height) size the
 * pixel arrays; the fields are every field but the pixels and station_json (frames must hold K
 * entries, in k order). */
int gs_capture_check_geometry(const gs_capture *c, gs_capture_problem *pr);
int gs_capture_check_fields(const gs_capture *c, gs_capture_problem *pr);
/* A frame or HDR-map file name; an ISO 8601 time (1 if valid). */
int gs_capture_valid_name(const char *s);
int gs_capture_valid_utc(const char *s);

#endif
