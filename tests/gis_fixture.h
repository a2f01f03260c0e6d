/* gis_fixture.h - what the gis/ tests (tests/test_gis.c, tests/test_gis_triangulate.c) share,
 * implemented in tests/gis_fixture.c, prefix gisfx_: a deterministic xorshift stream,
 * GeographicLib's command-line tools (GeodSolve, CartConvert) run in batches, and a camera
 * written independently of gis/ (the pose as extrinsic rotations about fixed ENU axes, not the
 * library's closed form). */
#ifndef GRIDSURVEY_TESTS_GIS_FIXTURE_H
#define GRIDSURVEY_TESTS_GIS_FIXTURE_H

#include "gis/gis.h"

#include <stddef.h>

#define PI 3.14159265358979323846
#define D2R (PI / 180.0)

/* xorshift64: gisfx_urand is uniform in [lo, hi) after gisfx_rng_seed (0 counts as 1). */
void gisfx_rng_seed(unsigned long long s);
double gisfx_urand(double lo, double hi);

/* A growing string (s malloc'd; free it). */
typedef struct {
    char *s;
    size_t n, cap;
} gisfx_sbuf;
void gisfx_sb_printf(gisfx_sbuf *b, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* Runs `tool` with the lines of input on stdin; returns its stdout (malloc'd) or NULL (a test
 * failure if the tool fails). */
char *gisfx_run_tool(const char *tool, const gisfx_sbuf *input);
/* The next number from *p (advances), NaN at the end. */
double gisfx_next_num(char **p);

/* Horizontal distance in metres between two nearby geodetic points (for small errors only). */
double gisfx_err_m(double lat1, double lon1, double lat2, double lon2);
/* ENU unit vectors at (lat, lon): rows e, n, u (the textbook formulas, not GeographicLib). */
void gisfx_enu_basis(double lat, double lon, double e[3], double n[3], double u[3]);
/* ENU vector -> pixel by the independent camera; 0 if behind or where the distortion folds
 * (derivative < 0.2). */
int gisfx_project(const gis_camera *c, const double v[3], double *x, double *y);
/* A 1920 x 1080 camera, focal 2000 px, at (45, 7) and 100 m, level and looking north. */
gis_camera gisfx_base_camera(void);
/* Covariance (ee, en, nn) of an ellipse. */
void gisfx_ellipse_cov(const gis_ellipse *e, double c[3]);

/* A latitude x longitude box for random stations, degrees. */
typedef struct {
    double lat_lo, lat_hi, lon_lo, lon_hi;
} gisfx_region;

/* The oracles' regions: the world between +-80 deg, a 0.1 deg cap at each pole, and a 0.1 deg
 * strip each side of the antimeridian (latitudes +-60). */
extern const gisfx_region gisfx_worldwide, gisfx_north_pole, gisfx_south_pole, gisfx_am_east,
    gisfx_am_west;

#endif
