/* locate.c - one-station location (gis.h Sec. 2): a light's sight line intersected with the
 * surface at the light's height above the WGS84 ellipsoid, with the error ellipse propagated
 * from the pixel and pose sigmas by a finite-difference Jacobian. */
#include "gis/internal.h"

#include <math.h>
#include <string.h>

/* The Dead Sea shore, the lowest land, is about -410 m above the ellipsoid (-430 m orthometric,
 * geoid +20 m): a sight line that passes below this cannot reach a light behind. */
#define LOWEST_GROUND_M (-500.0)
/* Newton tolerances: geodetic height within 1e-9 m, or a step below 1e-10 m. */
#define H_TOL_M 1e-9
#define S_TOL_M 1e-10
#define MAX_NEWTON 300

void gis_locate_opts_default(gis_locate_opts *o)
{
    o->max_error_ratio = 0.25;
    o->sigma_height_m = 0.0;
    o->pixel_cov_px2[0] = o->pixel_cov_px2[1] = o->pixel_cov_px2[2] = 0.0;
}

const char *gis_flags_str(unsigned flags, char *buf, size_t size)
{
    static const char *const names[] = {"above_horizon", "grazing", "behind", "near_parallel",
                                        "no_convergence", "bad_pixel"};
    size_t used = 0;
    if (size) buf[0] = '\0';
    for (unsigned i = 0; i < sizeof names / sizeof *names; i++) {
        if (!(flags & (1u << i))) continue;
        int w = snprintf(buf + used, size > used ? size - used : 0, "%s%s", used ? "|" : "", names[i]);
        if (w < 0) break;
        used += (size_t)w;
        if (used >= size) {
            used = size ? size - 1 : 0;
            break;
        }
    }
    return buf;
}

gis_ellipse gis_ellipse_nan(void)
{
    gis_ellipse e = {NAN, NAN, NAN};
    return e;
}

gis_ellipse gis_ellipse_from_cov(double cee, double cen, double cnn)
{
    gis_ellipse e;
    if (!isfinite(cee) || !isfinite(cen) || !isfinite(cnn)) return gis_ellipse_nan();
    double m = 0.5 * (cee + cnn), d = hypot(0.5 * (cee - cnn), cen);
    double l1 = m + d, l2 = m - d;
    e.semi_major_m = sqrt(l1 > 0.0 ? l1 : 0.0);
    e.semi_minor_m = sqrt(l2 > 0.0 ? l2 : 0.0);
    /* major axis direction (east, north) = (cen, l1 - cee) or (l1 - cnn, cen) */
    double ve, vn;
    if (cee >= cnn) {
        ve = l1 - cnn;
        vn = cen;
    } else {
        ve = cen;
        vn = l1 - cee;
    }
    double az = (ve == 0.0 && vn == 0.0) ? 0.0 : atan2(ve, vn) / GIS_DEG;
    az = fmod(az, 180.0);
    if (az < 0.0) az += 180.0;
    if (az >= 180.0) az = 0.0;
    e.azimuth_deg = az;
    return e;
}

/* Rotate v about the unit axis by ang radians (right-handed; Rodrigues). */
static void rotate(double v[3], const double ax[3], double ang)
{
    double c = cos(ang), sn = sin(ang), d = ax[0] * v[0] + ax[1] * v[1] + ax[2] * v[2];
    double x[3] = {ax[1] * v[2] - ax[2] * v[1], ax[2] * v[0] - ax[0] * v[2], ax[0] * v[1] - ax[1] * v[0]};
    for (int i = 0; i < 3; i++) v[i] = v[i] * c + x[i] * sn + ax[i] * d * (1.0 - c);
}

/* The path of a pixel's sight line in geocentric coordinates. */
typedef struct {
    double p0[3];       /* station, ECEF */
    gis_sight sg;       /* t, n in ECEF */
} path;

static gs_status path_init(const gis_camera *cam, const double axes[9], double x_px,
                           double y_px, path *p)
{
    gs_status s = gis_sight_from_axes(cam, axes, x_px, y_px, &p->sg);
    if (s != GS_OK) return s;
    double M[9];
    if (gis_gl_geocentric_fwd(cam->lat_deg, cam->lon_deg, cam->height_m, p->p0, M)) return GS_ENUMERIC;
    for (int i = 0; i < 3; i++) {
        p->sg.t[i] = M[3 * i] * p->sg.t_enu[0] + M[3 * i + 1] * p->sg.t_enu[1] + M[3 * i + 2] * p->sg.t_enu[2];
        p->sg.n[i] = M[3 * i] * p->sg.n_enu[0] + M[3 * i + 1] * p->sg.n_enu[1] + M[3 * i + 2] * p->sg.n_enu[2];
    }
    return GS_OK;
}

/* Geodetic height at path length s and its derivative dh/ds = up . tangent. */
static int height_at(const path *p, double s, double *h, double *dh, double *lat, double *lon)
{
    double q[3], tan[3], la, lo;
    gis_sight_point(&p->sg, s, q, tan);
    for (int i = 0; i < 3; i++) q[i] += p->p0[i];
    if (gis_gl_geocentric_rev(q, &la, &lo, h, NULL)) return -1;
    double cl = cos(la * GIS_DEG), up[3] = {cl * cos(lo * GIS_DEG), cl * sin(lo * GIS_DEG), sin(la * GIS_DEG)};
    *dh = up[0] * tan[0] + up[1] * tan[1] + up[2] * tan[2];
    if (lat) *lat = la;
    if (lon) *lon = lo;
    return 0;
}

enum { HIT = 0, MISS_ABOVE = 1, MISS_NOCONV = 2, MISS_GROUND = 3, MISS_ERROR = 4 };

/* The path length of the crossing with height ht. The geodetic height along the path is convex
 * in s (the height above a convex body along a line, and the arc bends less than the Earth), so
 * Newton from the side where g = h - ht > 0 moves monotonically toward the crossing and never
 * past it: from s = 0 when the station is above ht (the first, descending crossing; a slope
 * >= 0 before reaching it proves there is none), from beyond the crossing when the station is
 * below ht (the ascending crossing). */
static int intersect(const path *p, double h0, double ht, double *s_out)
{
    double g = INFINITY, dg, h;
    if (h0 - ht > 0.0) {
        double s = 0.0;
        for (int it = 0; it < MAX_NEWTON; it++) {
            if (height_at(p, s, &h, &dg, NULL, NULL)) return MISS_ERROR;
            g = h - ht;
            if (g <= H_TOL_M) {
                *s_out = s;
                return HIT;
            }
            if (dg >= 0.0) return MISS_ABOVE;   /* past the lowest point, still above ht */
            double step = -g / dg;
            s += step;
            if (s > GIS_MAX_PATH_M) return MISS_ABOVE;
            if (step <= S_TOL_M) {
                *s_out = s;
                return HIT;
            }
        }
        return MISS_NOCONV;
    }
    /* Station at or below ht: bracket the ascending crossing, then Newton from the right. */
    double hi = 1000.0 > 2.0 * (ht - h0) ? 1000.0 : 2.0 * (ht - h0);
    for (;;) {
        if (height_at(p, hi, &h, &dg, NULL, NULL)) return MISS_ERROR;
        if (h - ht > 0.0) break;
        hi *= 2.0;
        if (hi > GIS_MAX_PATH_M) return MISS_ABOVE;
    }
    double s = hi;
    int hit = 0;
    for (int it = 0; it < MAX_NEWTON && !hit; it++) {
        if (height_at(p, s, &h, &dg, NULL, NULL)) return MISS_ERROR;
        g = h - ht;
        if (g <= H_TOL_M) break;
        if (dg <= 0.0) return MISS_NOCONV;   /* cannot happen for a convex height */
        double step = g / dg;
        s -= step;
        if (step <= S_TOL_M) hit = 1;
        if (s < 0.0) s = 0.0;
    }
    if (!hit && fabs(g) > 1e-6) return MISS_NOCONV;
    /* A line that starts descending dips to its lowest point before rising through ht: it must
     * not pass below the lowest land on the way. The lowest point is where dh/ds = 0; dh/ds
     * increases along the path, so bisect. */
    double dg0;
    if (height_at(p, 0.0, &h, &dg0, NULL, NULL)) return MISS_ERROR;
    if (dg0 < 0.0) {
        double lo = 0.0, up = s;
        for (int it = 0; it < 80; it++) {
            double mid = 0.5 * (lo + up);
            if (height_at(p, mid, &h, &dg, NULL, NULL)) return MISS_ERROR;
            if (dg < 0.0) lo = mid;
            else up = mid;
        }
        if (height_at(p, 0.5 * (lo + up), &h, &dg, NULL, NULL)) return MISS_ERROR;
        if (h < LOWEST_GROUND_M) return MISS_GROUND;
    }
    *s_out = s;
    return HIT;
}

/* Locate without the ellipse, through the given camera axes. On HIT fills lat, lon, h and the
 * chord range. */
static int locate_point(const gis_camera *cam, const double axes[9], double x, double y,
                        double ht, double *lat, double *lon, double *h, double *range, gs_status *err)
{
    path p;
    *err = path_init(cam, axes, x, y, &p);
    if (*err != GS_OK) return MISS_ERROR;
    double s;
    int r = intersect(&p, cam->height_m, ht, &s);
    if (r != HIT) {
        if (r == MISS_ERROR) *err = GS_ENUMERIC;
        return r;
    }
    double q[3], dg;
    gis_sight_point(&p.sg, s, q, NULL);
    if (range) *range = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
    if (height_at(&p, s, h, &dg, lat, lon)) {
        *err = GS_ENUMERIC;
        return MISS_ERROR;
    }
    return HIT;
}

static void fix_clear_point(gis_fix *out)
{
    out->lat_deg = out->lon_deg = out->height_m = NAN;
    out->range_m = out->distance_m = NAN;
}

gs_status gis_locate(const gis_camera *cam, double x_px, double y_px, double sigma_px,
                     double light_height_m, const gis_locate_opts *o, gis_fix *out)
{
    gis_locate_opts def;
    if (!o) {
        gis_locate_opts_default(&def);
        o = &def;
    }
    memset(out, 0, sizeof *out);
    fix_clear_point(out);
    out->bearing_deg = out->elevation_deg = NAN;
    out->ellipse = gis_ellipse_nan();
    gs_status s = gis_camera_check(cam);
    if (s != GS_OK) return s;
    if (!isfinite(x_px) || !isfinite(y_px) || !isfinite(sigma_px) || !isfinite(light_height_m))
        return gs_fail(GS_ENUMERIC, "locate: pixel (%g, %g), sigma %g px, light height %g m: "
                       "expected finite values", x_px, y_px, sigma_px, light_height_m);
    if (sigma_px < 0.0) return gs_fail(GS_EINVAL, "locate: sigma_px = %g: expected >= 0", sigma_px);
    if (light_height_m < GIS_MIN_HEIGHT_M || light_height_m > GIS_MAX_HEIGHT_M)
        return gs_fail(GS_EINVAL, "locate: light height %g m: expected [%g, %g]", light_height_m,
                       GIS_MIN_HEIGHT_M, GIS_MAX_HEIGHT_M);
    if (!isfinite(o->max_error_ratio) || o->max_error_ratio <= 0.0)
        return gs_fail(GS_EINVAL, "locate: max_error_ratio = %g: expected > 0", o->max_error_ratio);
    if (!(o->sigma_height_m >= 0.0) || !isfinite(o->sigma_height_m))
        return gs_fail(GS_EINVAL, "locate: sigma_height_m = %g: expected a finite value >= 0", o->sigma_height_m);
    const double *pc = o->pixel_cov_px2;
    if (!(pc[0] >= 0.0 && pc[2] >= 0.0 && isfinite(pc[0]) && isfinite(pc[1]) && isfinite(pc[2]) &&
          pc[1] * pc[1] <= pc[0] * pc[2] * (1.0 + 1e-9)))
        return gs_fail(GS_EINVAL, "locate: pixel covariance (%g, %g, %g) px^2: expected a positive "
                       "semi-definite (xx, xy, yy)", pc[0], pc[1], pc[2]);

    if (gis_pixel_bearing(cam, x_px, y_px, &out->bearing_deg, &out->elevation_deg) != GS_OK) {
        out->flags |= GIS_FIX_BAD_PIXEL;   /* beyond the distortion model's field */
        return GS_OK;
    }
    double axes[9];
    gis_cam_axes(cam, axes, axes + 3, axes + 6);
    double lat, lon, h, range;
    int r = locate_point(cam, axes, x_px, y_px, light_height_m, &lat, &lon, &h, &range, &s);
    if (r == MISS_ERROR) return s;
    if (r == MISS_ABOVE || r == MISS_GROUND) {
        out->flags |= GIS_FIX_ABOVE_HORIZON;
        return GS_OK;
    }
    if (r == MISS_NOCONV) {
        out->flags |= GIS_FIX_NO_CONVERGENCE | GIS_FIX_GRAZING;
        return GS_OK;
    }
    double dist, azi1, azi2;
    if (gis_gl_inverse(cam->lat_deg, cam->lon_deg, lat, lon, &dist, &azi1, &azi2)) return GS_ENUMERIC;

    /* Error ellipse: J = d(east, north)/d(param) by central differences, in the local frame
     * at the light; C = sum sigma^2 J J^T. A pose error is a small rotation of the camera:
     * heading about the vertical (clockwise), pitch about the horizontal right axis
     * (cos H, -sin H, 0), roll about the optical axis; these are the partial derivatives of
     * the heading/pitch/roll parametrisation, and stay defined at pitch +-90 deg, where the
     * angles themselves lock. The light's height (the prior's sigma) moves the surface the
     * sight line meets. Each parameter is also moved by +-1 sigma: when that sight line misses
     * the surface the ellipse is unbounded. The pixel's x and y have the covariance
     * sigma_px^2 I + pixel_cov_px2: their terms, with the cross term Cxy (Jx Jy^T + Jy Jx^T). */
    const double var_x = sigma_px * sigma_px + pc[0], var_y = sigma_px * sigma_px + pc[2];
    const double sig[6] = {sqrt(var_x), sqrt(var_y), cam->sigma_heading_deg, cam->sigma_pitch_deg,
                           cam->sigma_roll_deg, o->sigma_height_m};
    const double step[6] = {1e-3, 1e-3, 1e-5, 1e-5, 1e-5, 1e-3};
    const double up[3] = {0.0, 0.0, 1.0};
    const double pitch_axis[3] = {cos(cam->heading_deg * GIS_DEG), -sin(cam->heading_deg * GIS_DEG), 0.0};
    double cee = 0.0, cen = 0.0, cnn = 0.0, jpx[2][2] = {{0.0, 0.0}, {0.0, 0.0}};
    int unbounded = 0;
    for (int j = 0; j < 6 && !unbounded; j++) {
        if (sig[j] == 0.0) continue;
        double en[2][2];
        for (int pass = 0; pass < 2 && !unbounded; pass++) {
            for (int sgn = 0; sgn < 2; sgn++) {
                double delta = (sgn ? -1.0 : 1.0) * (pass == 0 ? step[j] : sig[j]);
                double x = x_px, y = y_px, ht = light_height_m, ax[9];
                memcpy(ax, axes, sizeof ax);
                if (j == 0) x += delta;
                else if (j == 1) y += delta;
                else if (j == 5) ht += delta;
                else {
                    const double *about = j == 2 ? up : j == 3 ? pitch_axis : axes + 6;
                    double ang = (j == 2 ? -delta : delta) * GIS_DEG;
                    for (int k = 0; k < 3; k++) rotate(ax + 3 * k, about, ang);
                }
                double la, lo, hh, rr;
                gs_status e2;
                int r2 = locate_point(cam, ax, x, y, ht, &la, &lo, &hh, &rr, &e2);
                if (r2 != HIT) {
                    unbounded = 1;
                    break;
                }
                if (pass == 0) {
                    double enu[3];
                    if (gis_gl_local_fwd(lat, lon, h, la, lo, hh, enu)) return GS_ENUMERIC;
                    en[sgn][0] = enu[0];
                    en[sgn][1] = enu[1];
                }
            }
            if (pass == 0 && !unbounded) {
                double je = (en[0][0] - en[1][0]) / (2.0 * step[j]);
                double jn = (en[0][1] - en[1][1]) / (2.0 * step[j]);
                double v = j == 0 ? var_x : j == 1 ? var_y : sig[j] * sig[j];
                cee += v * je * je;
                cen += v * je * jn;
                cnn += v * jn * jn;
                if (j < 2) jpx[j][0] = je, jpx[j][1] = jn;
            }
        }
    }
    if (pc[1] != 0.0) {
        cee += 2.0 * pc[1] * jpx[0][0] * jpx[1][0];
        cen += pc[1] * (jpx[0][0] * jpx[1][1] + jpx[1][0] * jpx[0][1]);
        cnn += 2.0 * pc[1] * jpx[0][1] * jpx[1][1];
    }
    if (unbounded) {
        out->ellipse.semi_major_m = out->ellipse.semi_minor_m = INFINITY;
        out->ellipse.azimuth_deg = NAN;
    } else {
        out->ellipse = gis_ellipse_from_cov(cee, cen, cnn);
    }
    if (unbounded || !(out->ellipse.semi_major_m <= o->max_error_ratio * range)) {
        out->flags |= GIS_FIX_GRAZING;
        return GS_OK;
    }
    out->lat_deg = lat;
    out->lon_deg = gs_wrap180(lon);
    out->height_m = light_height_m;   /* the crossing is on that surface to 1e-9 m (h) */
    out->range_m = range;
    out->distance_m = dist;
    out->bearing_deg = gs_wrap360(azi1);
    return GS_OK;
}
