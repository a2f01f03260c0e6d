/* triangulate.c - two-station triangulation (gis.h Sec. 3): the intersection of two geodesics
 * given by a station and an azimuth each, by Karney's Gnomonic iteration (GeographicLib 2.1.2
 * has no Intersect class; see the "Geodesic intersections" example in the Gnomonic
 * documentation, and C. F. F. Karney, J. Geodesy 87, 43-55 (2013), Sec. 8): in a Gnomonic
 * projection centred on the intersection, geodesics through the centre are straight lines, so
 * intersecting the projected lines and re-centring converges to the exact intersection. */
#include "gis/internal.h"

#include <math.h>
#include <string.h>

#define MAX_ITER 20
#define CONVERGED_M 1e-8      /* the correction that ends the iteration */
#define NOISE_M 1e-6          /* below this, a correction that stops shrinking is round-off:
                                 one ulp of a latitude in degrees is 0.8 nm */
#define FAR_M 1.0e7           /* an estimate this far from the stations has diverged */

void gis_triangulate_opts_default(gis_triangulate_opts *o)
{
    o->min_angle_deg = 1.0;
    o->max_error_ratio = 0.25;
}

/* 2-D lines P1 + t (P2 - P1) and Q1 + u (Q2 - Q1): their intersection, or -1 if parallel. */
static int line_cross(const double p1[2], const double p2[2], const double q1[2], const double q2[2],
                      double out[2])
{
    double d1[2] = {p2[0] - p1[0], p2[1] - p1[1]}, d2[2] = {q2[0] - q1[0], q2[1] - q1[1]};
    double det = d1[0] * d2[1] - d1[1] * d2[0];
    double scale = hypot(d1[0], d1[1]) * hypot(d2[0], d2[1]);
    if (!(fabs(det) > 1e-14 * scale)) return -1;
    double w[2] = {q1[0] - p1[0], q1[1] - p1[1]};
    double t = (w[0] * d2[1] - w[1] * d2[0]) / det;
    out[0] = p1[0] + t * d1[0];
    out[1] = p1[1] + t * d1[1];
    return 0;
}

/* Two points on the geodesic of station b, near the centre (lat0, lon0): at the along-track
 * distance s of the centre and s + L; projected with the Gnomonic centred there. */
static int project_geodesic(const gis_bearing *b, double az, double lat0, double lon0,
                            double q1[2], double q2[2])
{
    double d, a1, a2, la, lo;
    if (gis_gl_inverse(b->lat_deg, b->lon_deg, lat0, lon0, &d, &a1, &a2)) return -1;
    double s = d * cos((a1 - az) * GIS_DEG), L = d > 1e5 ? 0.01 * d : 1000.0;
    if (gis_gl_direct(b->lat_deg, b->lon_deg, az, s, &la, &lo, NULL)) return -1;
    if (gis_gl_gnomonic_fwd(lat0, lon0, la, lo, &q1[0], &q1[1])) return -1;
    if (gis_gl_direct(b->lat_deg, b->lon_deg, az, s + L, &la, &lo, NULL)) return -1;
    if (gis_gl_gnomonic_fwd(lat0, lon0, la, lo, &q2[0], &q2[1])) return -1;
    return 0;
}

enum { T_OK = 0, T_PARALLEL = 1, T_NOCONV = 2 };

/* The iteration from (*lat, *lon); the result replaces them. */
static int intersect(const gis_bearing *a, double az_a, const gis_bearing *b, double az_b,
                     double *lat, double *lon, int *iterations)
{
    double la = *lat, lo = *lon, prev = INFINITY;
    for (int it = 1; it <= MAX_ITER; it++) {
        double p1[2], p2[2], q1[2], q2[2], x[2];
        if (project_geodesic(a, az_a, la, lo, p1, p2) || project_geodesic(b, az_b, la, lo, q1, q2))
            return T_PARALLEL;   /* a station beyond the projection's horizon: diverged */
        if (line_cross(p1, p2, q1, q2, x)) return T_PARALLEL;
        double nla, nlo;
        if (gis_gl_gnomonic_rev(la, lo, x[0], x[1], &nla, &nlo)) return T_PARALLEL;
        la = nla;
        lo = nlo;
        *iterations = it;
        double shift = hypot(x[0], x[1]);
        if (shift > FAR_M) return T_PARALLEL;
        if (shift <= CONVERGED_M || (shift < NOISE_M && shift >= prev)) {
            *lat = la;
            *lon = lo;
            return T_OK;
        }
        prev = shift;
    }
    *lat = la;
    *lon = lo;
    return T_NOCONV;
}

static gs_status check_bearing(const gis_bearing *b, const char *name)
{
    if (!b) return gs_fail(GS_EINVAL, "triangulate: bearing %s is NULL", name);
    if (!isfinite(b->lat_deg) || !isfinite(b->lon_deg) || !isfinite(b->azimuth_deg) || !isfinite(b->sigma_deg))
        return gs_fail(GS_ENUMERIC, "triangulate: station %s (%g, %g), azimuth %g, sigma %g: "
                       "expected finite values", name, b->lat_deg, b->lon_deg, b->azimuth_deg, b->sigma_deg);
    if (fabs(b->lat_deg) > 90.0)
        return gs_fail(GS_EINVAL, "triangulate: station %s latitude %g: expected [-90, 90]", name, b->lat_deg);
    if (b->sigma_deg < 0.0 || b->sigma_deg > 90.0)
        return gs_fail(GS_EINVAL, "triangulate: station %s sigma %g deg: expected [0, 90]", name, b->sigma_deg);
    return GS_OK;
}

gs_status gis_triangulate(const gis_bearing *a, const gis_bearing *b,
                          const gis_triangulate_opts *o, gis_intersection *out)
{
    gis_triangulate_opts def;
    if (!o) {
        gis_triangulate_opts_default(&def);
        o = &def;
    }
    memset(out, 0, sizeof *out);
    out->lat_deg = out->lon_deg = NAN;
    out->distance_m[0] = out->distance_m[1] = out->angle_deg = NAN;
    out->ellipse = gis_ellipse_nan();
    gs_status s = check_bearing(a, "a");
    if (s == GS_OK) s = check_bearing(b, "b");
    if (s != GS_OK) return s;
    if (!(o->min_angle_deg >= 0.0 && o->min_angle_deg < 90.0) || !(o->max_error_ratio > 0.0) ||
        !isfinite(o->max_error_ratio))
        return gs_fail(GS_EINVAL, "triangulate: options min_angle_deg %g, max_error_ratio %g: "
                       "expected [0, 90) and > 0", o->min_angle_deg, o->max_error_ratio);
    double base, az_ab, az_ba;
    if (gis_gl_inverse(a->lat_deg, a->lon_deg, b->lat_deg, b->lon_deg, &base, &az_ab, &az_ba))
        return GS_ENUMERIC;
    if (!(base > GIS_MIN_BASELINE_M))
        return gs_fail(GS_EINVAL, "triangulate: the stations are %g m apart: expected distinct stations", base);
    if (base > 9.0e6)
        return gs_fail(GS_EINVAL, "triangulate: the stations are %.0f km apart: expected < 9000 km", base / 1e3);

    /* Start at the midpoint of the baseline. */
    double lat, lon;
    if (gis_gl_direct(a->lat_deg, a->lon_deg, az_ab, 0.5 * base, &lat, &lon, NULL)) return GS_ENUMERIC;
    int r = intersect(a, a->azimuth_deg, b, b->azimuth_deg, &lat, &lon, &out->iterations);
    if (r == T_PARALLEL) {
        out->flags |= GIS_FIX_NEAR_PARALLEL;
        out->angle_deg = 0.0;
        out->ellipse.semi_major_m = out->ellipse.semi_minor_m = INFINITY;
        return GS_OK;
    }
    if (r == T_NOCONV) out->flags |= GIS_FIX_NO_CONVERGENCE;

    double d[2], azi1[2], azi2[2];
    const gis_bearing *st[2] = {a, b};
    for (int i = 0; i < 2; i++) {
        if (gis_gl_inverse(st[i]->lat_deg, st[i]->lon_deg, lat, lon, &d[i], &azi1[i], &azi2[i]))
            return GS_ENUMERIC;
        out->distance_m[i] = d[i];
        if (d[i] > 1e-6 && fabs(gs_wrap180(azi1[i] - st[i]->azimuth_deg)) > 90.0)
            out->flags |= GIS_FIX_BEHIND;
    }
    double g = fabs(gs_wrap180(azi2[0] - azi2[1]));
    out->angle_deg = g > 90.0 ? 180.0 - g : g;

    /* Ellipse: J = d(east, north)/d(azimuth) by central differences, in the local frame at the
     * intersection; C = sum sigma^2 J J^T. */
    const double step = 1e-5;
    double cee = 0.0, cen = 0.0, cnn = 0.0;
    int bad = 0;
    for (int j = 0; j < 2 && !bad; j++) {
        double sig = st[j]->sigma_deg;
        if (sig == 0.0) continue;
        double en[2][2];
        for (int sgn = 0; sgn < 2; sgn++) {
            double daz = sgn ? -step : step, pla = lat, plo = lon;
            int iters = 0;
            int r2 = intersect(a, a->azimuth_deg + (j == 0 ? daz : 0.0), b,
                               b->azimuth_deg + (j == 1 ? daz : 0.0), &pla, &plo, &iters);
            double enu[3];
            if (r2 != T_OK || gis_gl_local_fwd(lat, lon, 0.0, pla, plo, 0.0, enu)) {
                bad = 1;
                break;
            }
            en[sgn][0] = enu[0];
            en[sgn][1] = enu[1];
        }
        if (bad) break;
        double je = (en[0][0] - en[1][0]) / (2.0 * step);
        double jn = (en[0][1] - en[1][1]) / (2.0 * step);
        cee += sig * sig * je * je;
        cen += sig * sig * je * jn;
        cnn += sig * sig * jn * jn;
    }
    if (bad) {
        out->ellipse.semi_major_m = out->ellipse.semi_minor_m = INFINITY;
        out->ellipse.azimuth_deg = NAN;
    } else {
        out->ellipse = gis_ellipse_from_cov(cee, cen, cnn);
    }
    double dmax = d[0] > d[1] ? d[0] : d[1];
    if (out->angle_deg < o->min_angle_deg || !(out->ellipse.semi_major_m <= o->max_error_ratio * dmax))
        out->flags |= GIS_FIX_NEAR_PARALLEL;
    if (!(out->flags & (GIS_FIX_BEHIND | GIS_FIX_NEAR_PARALLEL | GIS_FIX_NO_CONVERGENCE))) {
        out->lat_deg = lat;
        out->lon_deg = gs_wrap180(lon);
    }
    return GS_OK;
}
