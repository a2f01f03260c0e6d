/* internal.h - gis/ internals: the C interface of the GeographicLib shim
 * (geographiclib_shim.cpp) and shared geometry helpers. Not included
 * outside gis/ (tests may include it). */
#ifndef GRIDSURVEY_GIS_INTERNAL_H
#define GRIDSURVEY_GIS_INTERNAL_H

#include "gis/gis.h"

#include <stdio.h>

/* ------------------------------------------------ GeographicLib 2.1.2 (WGS84), extern "C" */
/* Each returns 0, or -1 when GeographicLib threw or returned a non-finite value (the detail
 * is then in gs_detail()). Degrees, metres. Matrices are 3x3 row-major, GeographicLib's M:
 * M * (east, north, up) = geocentric (X, Y, Z) direction. */
#ifdef __cplusplus
extern "C" {
#endif
int gis_gl_geocentric_fwd(double lat, double lon, double h, double xyz[3], double M[9]);
int gis_gl_geocentric_rev(const double xyz[3], double *lat, double *lon, double *h, double M[9]);
int gis_gl_local_fwd(double lat0, double lon0, double h0, double lat, double lon, double h,
                     double enu[3]);
int gis_gl_local_rev(double lat0, double lon0, double h0, const double enu[3], double *lat,
                     double *lon, double *h);
int gis_gl_direct(double lat1, double lon1, double azi1, double s12, double *lat2, double *lon2,
                  double *azi2);
int gis_gl_inverse(double lat1, double lon1, double lat2, double lon2, double *s12, double *azi1,
                   double *azi2);
int gis_gl_gnomonic_fwd(double lat0, double lon0, double lat, double lon, double *x, double *y);
int gis_gl_gnomonic_rev(double lat0, double lon0, double x, double y, double *lat, double *lon);
#ifdef __cplusplus
}
#endif

#ifndef __cplusplus
#define GIS_DEG (3.14159265358979323846 / 180.0)

/* Ellipse from a 2x2 covariance (east, north), metres^2. */
gis_ellipse gis_ellipse_from_cov(double cee, double cen, double cnn);
/* A NaN ellipse. */
gis_ellipse gis_ellipse_nan(void);

/* Camera internals (camera.c). The camera's right, down and forward axes in station ENU. */
void gis_cam_axes(const gis_camera *cam, double right[3], double down[3], double fwd[3]);
/* The apparent (refracted) direction at the station toward ENU point c (unit vector). */
void gis_apparent_dir(const gis_camera *cam, const double c[3], double dir[3]);

/* A sight line: a straight line or, with refraction, a circular arc of curvature kappa in the
 * station's vertical plane. */
typedef struct {
    double t_enu[3], n_enu[3];  /* initial tangent; downward unit normal in the vertical plane */
    double kappa;               /* curvature, 1/m (0 = straight; n_enu is then 0) */
    double t[3], n[3];          /* the same in the frame gis_sight_point works in (set by caller) */
} gis_sight;
/* The sight line of a pixel (t, n left zero). */
gs_status gis_sight_from_pixel(const gis_camera *cam, double x_px, double y_px, gis_sight *out);
/* The same through given camera axes (right, down, forward in ENU, 3 doubles each), e.g. a
 * perturbed pose; cam supplies the intrinsics and refraction only (not checked). */
gs_status gis_sight_from_axes(const gis_camera *cam, const double axes[9], double x_px,
                              double y_px, gis_sight *out);
/* The point at path length s (relative to the station) and the unit tangent there (may be
 * NULL), in the frame of t and n. */
void gis_sight_point(const gis_sight *sg, double s, double p[3], double tan[3]);

#endif

#endif
