/*
 * gis.h - the public interface of gridsurvey's gis/ module (prefix gis_): georeferencing with
 * GeographicLib (C. F. F. Karney, "Algorithms for geodesics", J. Geodesy 87, 43-55 (2013),
 * doi:10.1007/s00190-012-0578-z), one-station location of lights, two-station triangulation,
 * error ellipses, and exports (GeoJSON, KML, GeoPackage, CSV, PNG map). docs/gis.md has the math,
 * the accuracy measured by the tests and how to reproduce it.
 *
 * Datum: WGS84 everywhere. Heights are ellipsoidal (above the WGS84 ellipsoid, not above the
 * geoid or sea level). Angles are degrees, lengths metres, image coordinates pixels.
 *
 * Axis conventions
 *   Local frame: east, north, up (ENU) at the station, up along the ellipsoid normal
 *     (GeographicLib LocalCartesian).
 *   heading_deg: azimuth of the optical axis, clockwise from (geodetic) north, any value.
 *   pitch_deg:   elevation of the optical axis above the local horizontal plane, up positive,
 *                [-90, 90] (-90 looks straight down; the image's "up" is then toward heading).
 *   roll_deg:    rotation about the optical axis, positive = clockwise as seen from behind the
 *                camera (the right side of the image goes down, so the scene turns
 *                counter-clockwise in the image); any value.
 *   Image: x to the right, y down, pixel centres at integer coordinates (0,0 is the centre of
 *     the top-left pixel). Camera frame: X right, Y down, Z forward (along the optical axis).
 *   Pinhole with radial distortion (Brown): normalised (xn, yn) = (X/Z, Y/Z),
 *     r^2 = xn^2 + yn^2, s = 1 + k1 r^2 + k2 r^4, x = cx + f xn s, y = cy + f yn s.
 *     The model is used only where it is one-to-one: r < r_max, the first zero of
 *     d(r s)/dr = 1 + 3 k1 r^2 + 5 k2 r^4 (infinite when there is none).
 *
 * Refraction model (optional, refraction_k != 0): a sight line is an arc of a circle in the
 * vertical plane of the station, concave toward the Earth, of curvature k cos(e) / R, with
 * e the elevation of the sight line at the station and R = GIS_EARTH_RADIUS_M (the classical
 * coefficient of refraction k = R / rho of geodetic levelling for horizontal sight lines;
 * the cos(e) factor leaves vertical lines straight). The standard value is k = 0.13.
 * Projection and location both use it, so they stay exact inverses of each other.
 *
 * Errors: functions return a gs_status (recognize/base/base.h) and set gs_detail(). NaN or
 * infinite inputs are GS_ENUMERIC, finite values out of range GS_EINVAL. Geometric failures
 * (a ray above the horizon, near-parallel bearings) are not errors: the result carries a flag
 * and NaN coordinates instead of a made-up point.
 *
 * Ownership: every struct here is a plain value; nothing returned needs freeing.
 * Thread safety: all functions except gis_map_png (PLplot keeps global state) are reentrant.
 */
#ifndef GRIDSURVEY_GIS_H
#define GRIDSURVEY_GIS_H

#include "recognize/base/base.h"

#include <stddef.h>

/* The standard coefficient of atmospheric refraction (Gauss; used in geodetic levelling). */
#define GIS_REFRACTION_K_STANDARD 0.13
/* Radius used by the refraction model: the mean radius R1 = (2a + b)/3 of WGS84 (IUGG). */
#define GIS_EARTH_RADIUS_M 6371008.8
/* Longest sight line followed, metres: anything farther counts as missing the surface. */
#define GIS_MAX_PATH_M 2.0e6
/* Two stations closer than this have no baseline to triangulate from, metres. */
#define GIS_MIN_BASELINE_M 1e-3

/* Valid heights (station and lights), metres above the ellipsoid. */
#define GIS_MIN_HEIGHT_M (-1.2e4)
#define GIS_MAX_HEIGHT_M 1.0e5

/* ------------------------------------------------------------------ camera model */

typedef struct {
    /* station (WGS84) */
    double lat_deg;            /* [-90, 90] */
    double lon_deg;            /* any finite value */
    double height_m;           /* ellipsoidal, [GIS_MIN_HEIGHT_M, GIS_MAX_HEIGHT_M] */
    /* pose (see the axis conventions above) */
    double heading_deg, pitch_deg, roll_deg;
    /* pose 1-sigma uncertainties, degrees (>= 0; 0 = exact), used by gis_locate's ellipse */
    double sigma_heading_deg, sigma_pitch_deg, sigma_roll_deg;
    /* intrinsics */
    double focal_px;           /* > 0 */
    double cx_px, cy_px;       /* principal point */
    double k1, k2;             /* radial distortion (0 = none) */
    int width_px, height_px;   /* image size (>= 0; 0 = unknown): only gis_in_image uses it */
    double refraction_k;       /* [-1, 0.9]; 0 = straight sight lines (GIS_REFRACTION_K_STANDARD) */
} gis_camera;

/* GS_OK if every field is finite and in range (GS_ENUMERIC / GS_EINVAL naming the field). */
gs_status gis_camera_check(const gis_camera *cam);

/* The radius r_max (in normalised image coordinates) inside which the distortion model is
 * one-to-one; INFINITY when it is everywhere. */
double gis_distortion_limit(const gis_camera *cam);

/* Normalised undistorted image coordinates (xn, yn) -> pixel. GS_ELIMIT beyond r_max. */
gs_status gis_distort(const gis_camera *cam, double xn, double yn, double *x_px, double *y_px);
/* Pixel -> normalised undistorted coordinates: the inverse of gis_distort (safeguarded Newton
 * on the radius, converged to 1e-15 relative). GS_ELIMIT for a pixel beyond the image of
 * r_max (the distortion folds over there). */
gs_status gis_undistort(const gis_camera *cam, double x_px, double y_px, double *xn, double *yn);

/* Geodetic point -> pixel. *in_front = 1 when the point is in front of the camera (positive
 * depth along the sight line) and inside the one-to-one field of the distortion model; then
 * x_px, y_px are its pixel, which may lie outside the image (see gis_in_image). Otherwise
 * *in_front = 0 and x_px = y_px = NaN. With refraction the pixel is where the refracted
 * sight line arrives. Any output pointer may be NULL. */
gs_status gis_project(const gis_camera *cam, double lat_deg, double lon_deg, double h_m,
                      double *x_px, double *y_px, int *in_front);
/* 1 if (x_px, y_px) lies on the sensor: -0.5 <= x < width - 0.5 and likewise y (0 when the
 * camera's size is unknown). */
int gis_in_image(const gis_camera *cam, double x_px, double y_px);

/* Pixel -> unit direction of the sight line at the station, in the station's ENU frame
 * (the tangent of the refracted arc when refraction is on). */
gs_status gis_pixel_ray(const gis_camera *cam, double x_px, double y_px, double dir_enu[3]);
/* Pixel -> azimuth ([0, 360), clockwise from north) and elevation of the sight line at the
 * station. The azimuth is that of the sight line's vertical plane (a normal section through
 * the light): it differs from the geodesic azimuth to the light's foot point by the
 * skew-normal correction e^2 h cos^2(lat) sin(2 az) / (2 N) <= 5.3e-10 rad per metre of the
 * light's ellipsoidal height h (0.1 mm at 2 km for h = 100 m; tests/test_gis.c checks it), far
 * below any pixel error, so it can be fed to gis_triangulate. Either output may be NULL. */
gs_status gis_pixel_bearing(const gis_camera *cam, double x_px, double y_px,
                            double *azimuth_deg, double *elevation_deg);

/* ---------------------------------------------------------- results and ellipses */

/* A 2-D error ellipse in the local horizontal plane at the point, 1 sigma, metres. */
typedef struct {
    double semi_major_m, semi_minor_m;
    double azimuth_deg;          /* of the major axis, clockwise from north, [0, 180) */
} gis_ellipse;

enum {
    GIS_FIX_ABOVE_HORIZON = 1u << 0,   /* the sight line never reaches the light's height */
    GIS_FIX_GRAZING = 1u << 1,         /* ellipse unbounded (a 1-sigma perturbation misses the
                                          surface) or semi-major > max_error_ratio * range */
    GIS_FIX_BEHIND = 1u << 2,          /* triangulation: the bearings meet behind a station */
    GIS_FIX_NEAR_PARALLEL = 1u << 3,   /* triangulation: intersection angle < min_angle_deg,
                                          ellipse > max_error_ratio * distance, or no meeting */
    GIS_FIX_NO_CONVERGENCE = 1u << 4,  /* an iteration did not converge */
    GIS_FIX_BAD_PIXEL = 1u << 5        /* the pixel lies beyond the distortion model's field */
};
/* "above_horizon|grazing" etc. into buf ("" for 0); returns buf. */
const char *gis_flags_str(unsigned flags, char *buf, size_t size);

/* ----------------------------------------------------------- one station (Sec. 2) */

typedef struct {
    double max_error_ratio;  /* GIS_FIX_GRAZING when semi_major > ratio * range (0.25) */
    double sigma_height_m;   /* 1-sigma of the light's height (the height prior), >= 0 (0) */
    double pixel_cov_px2[3]; /* a pixel covariance (xx, xy, yy), px^2, added to sigma_px^2 I: e.g.
                                a deblended light's from its PSF fit, correlated and unequal in
                                x and y; positive semi-definite (0, 0, 0) */
} gis_locate_opts;
void gis_locate_opts_default(gis_locate_opts *o);

typedef struct {
    double lat_deg, lon_deg;   /* the located light; NaN when flagged */
    double height_m;           /* light_height_m (the crossing lies on it to 1e-9 m); NaN if flagged */
    double range_m;         /* straight-line (chord) distance station -> light; NaN if flagged */
    double distance_m;      /* geodesic distance on the ellipsoid; NaN if flagged */
    double bearing_deg;     /* azimuth at the station, [0, 360): the geodesic's when located,
                               the sight line's when flagged */
    double elevation_deg;   /* elevation of the sight line at the station (apparent) */
    gis_ellipse ellipse;    /* from sigma_px, the camera's pose sigmas and the height prior's
                               sigma (gis_locate_opts.sigma_height_m); semi-axes INFINITY
                               when unbounded, NaN when not computed (no intersection) */
    unsigned flags;         /* GIS_FIX_* */
} gis_fix;

/* Locate the light seen at pixel (x_px, y_px) by intersecting its sight line with the surface
 * at light_height_m above the ellipsoid: the first crossing, where the line descends through
 * it; a station below that surface takes the crossing where the line rises through it (a line
 * that dips below -500 m on the way, the lowest land, cannot see the light there:
 * ABOVE_HORIZON). Exact in Earth curvature: Newton on the geodetic height along the line
 * (Geocentric::Reverse), which converges monotonically because that height is a convex
 * function of the path length, to 1e-9 m in height. sigma_px (>= 0) is the 1-sigma error of
 * each pixel coordinate; the ellipse propagates it, the pose sigmas (small rotations about
 * the vertical, the camera's horizontal right axis and its optical axis, so pitch +-90 is
 * fine) and o->sigma_height_m (the light's height) through a central-difference Jacobian. Flags: ABOVE_HORIZON (no crossing within
 * GIS_MAX_PATH_M), GRAZING (a +-1-sigma change of one parameter loses the crossing, or the
 * semi-major axis exceeds o->max_error_ratio * range), BAD_PIXEL (beyond the distortion
 * model's field); flagged fixes have NaN position and range. o NULL = defaults. Returns an
 * error only for invalid input. */
gs_status gis_locate(const gis_camera *cam, double x_px, double y_px, double sigma_px,
                     double light_height_m, const gis_locate_opts *o, gis_fix *out);

/* --------------------------------------------------------- two stations (Sec. 3) */

typedef struct {
    double lat_deg, lon_deg;   /* station */
    double azimuth_deg;        /* geodesic azimuth toward the light at the station */
    double sigma_deg;          /* its 1-sigma error (>= 0) */
} gis_bearing;

typedef struct {
    double min_angle_deg;      /* GIS_FIX_NEAR_PARALLEL below this intersection angle (1) */
    double max_error_ratio;    /* ... or when semi_major > ratio * farther distance (0.25) */
} gis_triangulate_opts;
void gis_triangulate_opts_default(gis_triangulate_opts *o);

typedef struct {
    double lat_deg, lon_deg;   /* the intersection; NaN when flagged BEHIND / NEAR_PARALLEL */
    double distance_m[2];      /* geodesic distance from each station */
    double angle_deg;          /* angle between the geodesics at the intersection, [0, 90] */
    gis_ellipse ellipse;       /* from the bearing sigmas (kept when NEAR_PARALLEL; semi-axes
                                  INFINITY when the bearings do not meet) */
    int iterations;            /* Gnomonic iterations used */
    unsigned flags;            /* GIS_FIX_BEHIND, GIS_FIX_NEAR_PARALLEL, GIS_FIX_NO_CONVERGENCE */
} gis_intersection;

/* The intersection of the geodesics leaving a and b at their azimuths, by Karney's Gnomonic
 * iteration (GeographicLib's Gnomonic documentation): project both geodesics with a Gnomonic
 * projection centred on the current estimate, intersect the straight lines, re-centre, repeat
 * (2-3 steps to the round-off floor of ~1e-8 m; 4 where the floor needs one step to show).
 * The result is the intersection of the lines, so it is checked to lie ahead of both stations
 * (GIS_FIX_BEHIND otherwise). The stations must be distinct and less than 9000 km apart
 * (GS_EINVAL). o NULL = defaults. */
gs_status gis_triangulate(const gis_bearing *a, const gis_bearing *b,
                          const gis_triangulate_opts *o, gis_intersection *out);

/* ------------------------------------------------------------------- geodesics */

/* The geodesic between two points on the WGS84 ellipsoid (GeographicLib Geodesic::Inverse,
 * Karney 2013: accurate to 15 nm): its length s12_m (metres) and the azimuths at both ends
 * (degrees clockwise from north, [-180, 180]). Any output may be NULL. GS_ENUMERIC for a
 * non-finite coordinate, GS_EINVAL for a latitude outside [-90, 90]. */
gs_status gis_geodesic_inverse(double lat1_deg, double lon1_deg, double lat2_deg, double lon2_deg,
                               double *s12_m, double *azi1_deg, double *azi2_deg);
/* Metres per degree of latitude (*north_m, the meridional radius of curvature M x pi/180) and
 * of longitude (*east_m, N cos(lat) x pi/180, N the prime vertical's) at lat_deg on WGS84: the
 * local east/north metres of small offsets, those of gis_locate's ellipses. */
void gis_metres_per_deg(double lat_deg, double *north_m, double *east_m);
/* The straight-line (chord) distance, metres, between two points given by WGS84 latitude,
 * longitude (degrees) and ellipsoidal height (metres), through GeographicLib's Geocentric; NaN
 * for a latitude outside [-90, 90] or a non-finite input. */
double gis_chord_m(double lat1_deg, double lon1_deg, double h1_m, double lat2_deg,
                   double lon2_deg, double h2_m);

/* ------------------------------------------------------------ station files */

#define GIS_STATION_FORMAT "gridsurvey-station/1"
#define GIS_TEXT_MAX 64

/* A station file (JSON object, docs/gis.md): the camera plus the default pixel sigma. */
typedef struct {
    gis_camera cam;
    double sigma_px;                 /* without psf_sigma_px: every light's pixel 1-sigma (1);
                                        with it: the calibration residual added in quadrature
                                        to each light's centroid sigma (0) */
    double psf_sigma_px;             /* the optics' Gaussian PSF sigma, px; NaN = unknown */
    char id[GIS_TEXT_MAX];           /* "" when absent */
    char time_utc[40];               /* ISO 8601, "" when absent */
} gis_station;

/* Parse a station object from JSON text; source names it in errors ("file:line: field ...").
 * Unknown fields are errors (they are usually typos). */
gs_status gis_station_parse(const char *json_text, const char *source, gis_station *st);
/* Read and parse a station file. */
gs_status gis_station_read(const char *path, gis_station *st);

/* ------------------------------------------------------------------- exports */

/* A located (or not) light, as exported. Fixed-size strings: a plain value. */
typedef struct {
    char id[GIS_TEXT_MAX];           /* light id, e.g. from the pixels CSV */
    double lat_deg, lon_deg;         /* NaN: not located (null geometry / empty fields) */
    double height_m;                 /* ellipsoidal, NaN if unknown */
    gis_ellipse ellipse;             /* NaN fields if unknown */
    char bulb_id[GS_ID_MAX];        /* recognized DELIGHT bulb, "" if unknown */
    char technology[32];             /* gs_tech_name(), "" if unknown */
    double phase_deg;                /* grid phase [0, 360), NaN = unknown/ambiguous */
    double confidence;               /* [0, 1], NaN if unknown */
    char survey[GIS_TEXT_MAX];       /* survey name, "" if none */
    char time_utc[40];               /* ISO 8601 UTC, "" if unknown */
    unsigned flags;                  /* GIS_FIX_* */
    char site[GIS_TEXT_MAX];         /* the physical light it is a detection of (a survey
                                        database's light site id), "" if none */
} gis_light;

/* Empty strings, NaN numbers, no flags. */
void gis_light_init(gis_light *l);
/* Copy position, ellipse and flags from a one-station fix. */
void gis_light_set_fix(gis_light *l, const gis_fix *f);

typedef enum { GIS_FORMAT_GEOJSON, GIS_FORMAT_KML, GIS_FORMAT_GPKG, GIS_FORMAT_CSV } gis_format;
/* "geojson" | "kml" | "gpkg" | "csv" -> format; GS_EINVAL otherwise. */
gs_status gis_format_parse(const char *name, gis_format *f);
/* The format implied by a path's extension (.geojson/.json, .kml, .gpkg, .csv). */
gs_status gis_format_from_path(const char *path, gis_format *f);
/* An output's format: name's (--format) when given, else the path's extension's; GS_EINVAL when
 * the two name different formats (GeoJSON written to x.kml). A path without a known extension
 * takes any name. */
gs_status gis_format_choose(const char *name, const char *path, gis_format *f);

/* Each writer replaces path atomically (a temporary file in the same directory, then rename):
 * on failure path is untouched and no temporary file is left. Strings must not hold control
 * characters (GS_EINVAL). Every light is written; unlocated ones without a geometry.
 * Attributes (all formats): id, bulb, technology, phase (deg), confidence, survey, time,
 * height_m, err_major_m, err_minor_m, err_azimuth_deg, flags, site.
 *  GeoJSON: RFC 7946 FeatureCollection, [lon, lat, height] positions, null unknowns.
 *  KML 2.2: Placemarks (clampToGround lon,lat; the ellipsoidal height is an attribute, since
 *           KML altitudes are above sea level), coloured by phase, ExtendedData attributes.
 *  GeoPackage 1.3: table "lights", 2-D POINT geometry in EPSG:4326 (no spatial index).
 *  CSV: RFC 4180, header row, lat_deg/lon_deg columns, %.10f degrees. */
gs_status gis_export_geojson(const gis_light *lights, size_t n, const char *path);
/* GeoJSON with longitudes and latitudes rounded to `decimals` places (0..GIS_GEOJSON_DECIMALS_MAX;
 * heights to 3): gis_export_geojson uses GIS_GEOJSON_DECIMALS (7: 1.1 cm of latitude). The
 * writer's 15 significant digits hold 12 decimals of a longitude of three integer digits. */
#define GIS_GEOJSON_DECIMALS 7
#define GIS_GEOJSON_DECIMALS_MAX 12
gs_status gis_export_geojson_decimals(const gis_light *lights, size_t n, const char *path, int decimals);
gs_status gis_export_kml(const gis_light *lights, size_t n, const char *path);
gs_status gis_export_gpkg(const gis_light *lights, size_t n, const char *path);
gs_status gis_export_csv(const gis_light *lights, size_t n, const char *path);
gs_status gis_export(const gis_light *lights, size_t n, gis_format f, const char *path);

/* Phase classes used for colours: within 20 deg of 0/120/240, other, unknown (NaN). */
typedef enum { GIS_PHASE_0, GIS_PHASE_120, GIS_PHASE_240, GIS_PHASE_OTHER, GIS_PHASE_UNKNOWN } gis_phase_class;
gis_phase_class gis_phase_classify(double phase_deg);
/* The class's colour, 8-bit RGB (Okabe-Ito: vermillion, bluish green, blue, reddish purple,
 * grey). */
void gis_phase_rgb(gis_phase_class c, unsigned char rgb[3]);

typedef struct {
    const char *title;               /* NULL = "gridsurvey: located lights" */
    int width_px, height_px;         /* PNG size (1200 x 900) */
    int draw_ellipses;               /* draw 1-sigma ellipses (1) */
    const gis_camera *stations;      /* borrowed; drawn as triangles (may be NULL) */
    size_t n_stations;
} gis_map_opts;
void gis_map_opts_default(gis_map_opts *o);

/* A PNG map (PLplot, pngcairo) of the located lights in local east/north metres around their
 * centre (GeographicLib LocalCartesian), coloured by phase class, with a legend, a scale bar
 * and a north arrow. Written atomically. GS_EINVAL when nothing is located and no station is
 * given. Not thread-safe (PLplot). o NULL = defaults. */
gs_status gis_map_png(const gis_light *lights, size_t n, const gis_map_opts *o, const char *path);

/* GeographicLib's version string (gridsurvey --version). */
const char *gis_geographiclib_version(void);

#endif
