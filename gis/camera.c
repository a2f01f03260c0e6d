/* camera.c - the camera model of gis.h: pose (heading, pitch, roll in the station's ENU frame),
 * pinhole intrinsics with radial distortion (Brown: s = 1 + k1 r^2 + k2 r^4), the refracted
 * sight line (a circular arc of curvature k cos(e) / R), geodetic -> pixel projection
 * (GeographicLib LocalCartesian) and pixel -> sight line back-projection. */
#include "gis/internal.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

static gs_status check_num(double v, const char *name, double lo, double hi)
{
    if (!isfinite(v)) return gs_fail(GS_ENUMERIC, "camera: %s is %g: expected a finite number", name, v);
    if (v < lo || v > hi)
        return gs_fail(GS_EINVAL, "camera: %s = %g: expected a value in [%g, %g]", name, v, lo, hi);
    return GS_OK;
}

gs_status gis_camera_check(const gis_camera *cam)
{
    if (!cam) return gs_fail(GS_EINVAL, "camera: NULL");
    const double big = 1e300;
    const struct {
        double v;
        const char *name;
        double lo, hi;
    } f[] = {
        {cam->lat_deg, "lat_deg", -90.0, 90.0},
        {cam->lon_deg, "lon_deg", -big, big},
        {cam->height_m, "height_m", GIS_MIN_HEIGHT_M, GIS_MAX_HEIGHT_M},
        {cam->heading_deg, "heading_deg", -big, big},
        {cam->pitch_deg, "pitch_deg", -90.0, 90.0},
        {cam->roll_deg, "roll_deg", -big, big},
        {cam->sigma_heading_deg, "sigma_heading_deg", 0.0, 90.0},
        {cam->sigma_pitch_deg, "sigma_pitch_deg", 0.0, 90.0},
        {cam->sigma_roll_deg, "sigma_roll_deg", 0.0, 90.0},
        {cam->focal_px, "focal_px", 1e-6, 1e9},
        {cam->cx_px, "cx_px", -1e9, 1e9},
        {cam->cy_px, "cy_px", -1e9, 1e9},
        {cam->k1, "k1", -1e6, 1e6},
        {cam->k2, "k2", -1e6, 1e6},
        {cam->refraction_k, "refraction_k", -1.0, 0.9},
    };
    for (size_t i = 0; i < sizeof f / sizeof *f; i++) {
        gs_status s = check_num(f[i].v, f[i].name, f[i].lo, f[i].hi);
        if (s != GS_OK) return s;
    }
    if (cam->width_px < 0 || cam->height_px < 0)
        return gs_fail(GS_EINVAL, "camera: image size %d x %d: expected sizes >= 0 (0 = unknown)",
                       cam->width_px, cam->height_px);
    return GS_OK;
}

/* The camera's axes in the station's ENU frame: right, down, forward (rows of the rotation
 * ENU -> camera). forward = (sin H cos P, cos H cos P, sin P); before roll, right is
 * horizontal (cos H, -sin H, 0) and up = right x forward; roll turns right toward down. */
void gis_cam_axes(const gis_camera *cam, double right[3], double down[3], double fwd[3])
{
    double H = cam->heading_deg * GIS_DEG, P = cam->pitch_deg * GIS_DEG, R = cam->roll_deg * GIS_DEG;
    double sh = sin(H), ch = cos(H), sp = sin(P), cp = cos(P), sr = sin(R), cr = cos(R);
    if (cam->pitch_deg == 90.0 || cam->pitch_deg == -90.0) {   /* exact: cos(pi/2) != 0 */
        cp = 0.0;
        sp = cam->pitch_deg > 0 ? 1.0 : -1.0;
    }
    double f[3] = {sh * cp, ch * cp, sp};
    double r0[3] = {ch, -sh, 0.0};
    double u0[3] = {-sh * sp, -ch * sp, cp};
    for (int i = 0; i < 3; i++) {
        fwd[i] = f[i];
        right[i] = r0[i] * cr - u0[i] * sr;
        down[i] = -(u0[i] * cr + r0[i] * sr);
    }
}

double gis_distortion_limit(const gis_camera *cam)
{
    /* smallest t = r^2 > 0 with 1 + 3 k1 t + 5 k2 t^2 = 0 */
    double a = 5.0 * cam->k2, b = 3.0 * cam->k1, t = INFINITY;
    if (a == 0.0) {
        if (b < 0.0) t = -1.0 / b;
    } else {
        double disc = b * b - 4.0 * a;
        if (disc >= 0.0) {
            double q = -0.5 * (b + (b >= 0.0 ? 1.0 : -1.0) * sqrt(disc));
            double r1 = q / a, r2 = q != 0.0 ? 1.0 / q : INFINITY;   /* roots: q/a and c/q, c = 1 */
            if (r1 > 0.0 && r1 < t) t = r1;
            if (r2 > 0.0 && r2 < t) t = r2;
        }
    }
    return sqrt(t);
}

static double radial(const gis_camera *cam, double r)
{
    double r2 = r * r;
    return r * (1.0 + r2 * (cam->k1 + r2 * cam->k2));
}

gs_status gis_distort(const gis_camera *cam, double xn, double yn, double *x_px, double *y_px)
{
    if (!isfinite(xn) || !isfinite(yn))
        return gs_fail(GS_ENUMERIC, "distort: non-finite image coordinates (%g, %g)", xn, yn);
    double r2 = xn * xn + yn * yn, rmax = gis_distortion_limit(cam);
    if (r2 >= rmax * rmax)
        return gs_fail(GS_ELIMIT, "distort: radius %g beyond the distortion model's one-to-one "
                       "limit %g (k1 = %g, k2 = %g)", sqrt(r2), rmax, cam->k1, cam->k2);
    double s = 1.0 + r2 * (cam->k1 + r2 * cam->k2);
    *x_px = cam->cx_px + cam->focal_px * xn * s;
    *y_px = cam->cy_px + cam->focal_px * yn * s;
    return GS_OK;
}

gs_status gis_undistort(const gis_camera *cam, double x_px, double y_px, double *xn, double *yn)
{
    if (!isfinite(x_px) || !isfinite(y_px))
        return gs_fail(GS_ENUMERIC, "pixel (%g, %g): expected finite coordinates", x_px, y_px);
    double xd = (x_px - cam->cx_px) / cam->focal_px, yd = (y_px - cam->cy_px) / cam->focal_px;
    double rd = hypot(xd, yd);
    if (rd == 0.0 || (cam->k1 == 0.0 && cam->k2 == 0.0)) {
        *xn = xd;
        *yn = yd;
        return GS_OK;
    }
    /* Solve radial(r) = rd on [0, rmax), where radial() increases from 0. */
    double rmax = gis_distortion_limit(cam), lo = 0.0, hi;
    if (isfinite(rmax)) {
        if (rd >= radial(cam, rmax))
            return gs_fail(GS_ELIMIT, "pixel (%g, %g) lies beyond the image of the distortion "
                           "model's one-to-one field (k1 = %g, k2 = %g)", x_px, y_px, cam->k1, cam->k2);
        hi = rmax;
    } else {
        hi = rd > 1.0 ? rd : 1.0;
        while (radial(cam, hi) < rd) hi *= 2.0;   /* radial grows without bound here */
    }
    double r = rd;
    if (r >= hi) r = 0.5 * (lo + hi);
    for (int it = 0; it < 200; it++) {
        double r2 = r * r;
        double g = radial(cam, r) - rd;
        double dg = 1.0 + r2 * (3.0 * cam->k1 + 5.0 * cam->k2 * r2);
        if (g > 0.0) hi = r;
        else lo = r;
        double next = dg > 0.0 ? r - g / dg : 0.5 * (lo + hi);
        if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);   /* safeguard: bisect */
        double step = fabs(next - r);
        r = next;
        if (step <= 1e-15 * r || hi - lo <= 1e-16 * hi) break;
    }
    *xn = xd * (r / rd);
    *yn = yd * (r / rd);
    return GS_OK;
}

/* ENU direction -> pixel (no refraction here). */
static int dir_to_pixel(const gis_camera *cam, const double d[3], double *x, double *y)
{
    double right[3], down[3], fwd[3];
    gis_cam_axes(cam, right, down, fwd);
    double X = right[0] * d[0] + right[1] * d[1] + right[2] * d[2];
    double Y = down[0] * d[0] + down[1] * d[1] + down[2] * d[2];
    double Z = fwd[0] * d[0] + fwd[1] * d[1] + fwd[2] * d[2];
    if (!(Z > 0.0)) return 0;
    double xn = X / Z, yn = Y / Z, rmax = gis_distortion_limit(cam);
    if (xn * xn + yn * yn >= rmax * rmax) return 0;
    double s = 1.0 + (xn * xn + yn * yn) * (cam->k1 + (xn * xn + yn * yn) * cam->k2);
    *x = cam->cx_px + cam->focal_px * xn * s;
    *y = cam->cy_px + cam->focal_px * yn * s;
    return 1;
}

/* The apparent direction (tangent of the refracted arc) toward ENU point c: tangent elevation
 * e0 solves e0 = ec + asin(kappa(e0) d / 2), kappa = k cos(e0) / R (the tangent-chord angle of
 * a circle of curvature kappa over a chord of length d). */
void gis_apparent_dir(const gis_camera *cam, const double c[3], double dir[3])
{
    double d = sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
    double hl = hypot(c[0], c[1]);
    if (cam->refraction_k == 0.0 || hl == 0.0 || d == 0.0) {
        for (int i = 0; i < 3; i++) dir[i] = d > 0.0 ? c[i] / d : 0.0;
        return;
    }
    double ec = atan2(c[2], hl), e0 = ec;
    for (int it = 0; it < 50; it++) {
        double kappa = cam->refraction_k * cos(e0) / GIS_EARTH_RADIUS_M;
        double x = kappa * d / 2.0;
        if (x > 1.0) x = 1.0;
        if (x < -1.0) x = -1.0;
        double next = ec + asin(x);
        if (fabs(next - e0) <= 1e-17) {
            e0 = next;
            break;
        }
        e0 = next;
    }
    double ce = cos(e0);
    dir[0] = ce * c[0] / hl;
    dir[1] = ce * c[1] / hl;
    dir[2] = sin(e0);
}

gs_status gis_project(const gis_camera *cam, double lat_deg, double lon_deg, double h_m,
                      double *x_px, double *y_px, int *in_front)
{
    if (x_px) *x_px = NAN;
    if (y_px) *y_px = NAN;
    if (in_front) *in_front = 0;
    gs_status s = gis_camera_check(cam);
    if (s != GS_OK) return s;
    if (!isfinite(lat_deg) || !isfinite(lon_deg) || !isfinite(h_m))
        return gs_fail(GS_ENUMERIC, "project: point (%g, %g, %g): expected finite coordinates",
                       lat_deg, lon_deg, h_m);
    if (fabs(lat_deg) > 90.0)
        return gs_fail(GS_EINVAL, "project: latitude %g: expected [-90, 90]", lat_deg);
    double c[3], dir[3], x, y;
    if (gis_gl_local_fwd(cam->lat_deg, cam->lon_deg, cam->height_m, lat_deg, lon_deg, h_m, c))
        return GS_ENUMERIC;
    gis_apparent_dir(cam, c, dir);
    if (!(dir[0] != 0.0 || dir[1] != 0.0 || dir[2] != 0.0)) return GS_OK;   /* at the camera */
    if (!dir_to_pixel(cam, dir, &x, &y)) return GS_OK;
    if (x_px) *x_px = x;
    if (y_px) *y_px = y;
    if (in_front) *in_front = 1;
    return GS_OK;
}

int gis_in_image(const gis_camera *cam, double x_px, double y_px)
{
    return cam->width_px > 0 && cam->height_px > 0 && x_px >= -0.5 && y_px >= -0.5 &&
           x_px < cam->width_px - 0.5 && y_px < cam->height_px - 0.5;
}

/* Pixel -> unit ENU direction through the camera axes (rows: right, down, forward). */
static gs_status ray_from_axes(const gis_camera *cam, const double axes[9], double x_px,
                               double y_px, double dir_enu[3])
{
    double xn, yn, v[3];
    gs_status s = gis_undistort(cam, x_px, y_px, &xn, &yn);
    if (s != GS_OK) return s;
    for (int i = 0; i < 3; i++) v[i] = xn * axes[i] + yn * axes[3 + i] + axes[6 + i];
    double n = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    for (int i = 0; i < 3; i++) dir_enu[i] = v[i] / n;
    return GS_OK;
}

gs_status gis_pixel_ray(const gis_camera *cam, double x_px, double y_px, double dir_enu[3])
{
    gs_status s = gis_camera_check(cam);
    if (s != GS_OK) return s;
    double axes[9];
    gis_cam_axes(cam, axes, axes + 3, axes + 6);
    return ray_from_axes(cam, axes, x_px, y_px, dir_enu);
}

gs_status gis_pixel_bearing(const gis_camera *cam, double x_px, double y_px,
                            double *azimuth_deg, double *elevation_deg)
{
    double d[3];
    gs_status s = gis_pixel_ray(cam, x_px, y_px, d);
    if (s != GS_OK) return s;
    if (azimuth_deg) *azimuth_deg = gs_wrap360(atan2(d[0], d[1]) / GIS_DEG);
    if (elevation_deg) *elevation_deg = atan2(d[2], hypot(d[0], d[1])) / GIS_DEG;
    return GS_OK;
}

gs_status gis_sight_from_axes(const gis_camera *cam, const double axes[9], double x_px,
                              double y_px, gis_sight *out)
{
    memset(out, 0, sizeof *out);
    gs_status s = ray_from_axes(cam, axes, x_px, y_px, out->t_enu);
    if (s != GS_OK) return s;
    const double *t = out->t_enu;
    double hl = hypot(t[0], t[1]);
    if (cam->refraction_k != 0.0 && hl > 0.0) {
        out->kappa = cam->refraction_k * hl / GIS_EARTH_RADIUS_M;   /* cos(e) = hl */
        out->n_enu[0] = t[2] * t[0] / hl;
        out->n_enu[1] = t[2] * t[1] / hl;
        out->n_enu[2] = -hl;
    }
    return GS_OK;
}

gs_status gis_sight_from_pixel(const gis_camera *cam, double x_px, double y_px, gis_sight *out)
{
    memset(out, 0, sizeof *out);
    gs_status s = gis_camera_check(cam);
    if (s != GS_OK) return s;
    double axes[9];
    gis_cam_axes(cam, axes, axes + 3, axes + 6);
    return gis_sight_from_axes(cam, axes, x_px, y_px, out);
}

void gis_sight_point(const gis_sight *sg, double s, double p[3], double tan[3])
{
    /* p(s) = sin(kappa s)/kappa t + (1 - cos(kappa s))/kappa n, relative to the station */
    double a, b, ct, st;
    if (sg->kappa == 0.0) {
        a = s;
        b = 0.0;
        ct = 1.0;
        st = 0.0;
    } else {
        double th = sg->kappa * s, hs = sin(0.5 * th);
        a = sin(th) / sg->kappa;
        b = 2.0 * hs * hs / sg->kappa;
        ct = cos(th);
        st = sin(th);
    }
    for (int i = 0; i < 3; i++) {
        p[i] = a * sg->t[i] + b * sg->n[i];
        if (tan) tan[i] = ct * sg->t[i] + st * sg->n[i];
    }
}
