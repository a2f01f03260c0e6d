// geographiclib_shim.cpp - the only C++ in gis/: plain C functions over GeographicLib 2.1.2
// (WGS84 Geocentric, LocalCartesian, Geodesic, Gnomonic). Exceptions are caught here and
// non-finite results are reported, so no C++ exception or NaN escapes silently.
extern "C" {
#include "gis/internal.h"
}

#include <GeographicLib/Ellipsoid.hpp>
#include <GeographicLib/Geocentric.hpp>
#include <GeographicLib/Geodesic.hpp>
#include <GeographicLib/Gnomonic.hpp>
#include <GeographicLib/LocalCartesian.hpp>

#include <cmath>
#include <exception>
#include <vector>

using GeographicLib::Geocentric;
using GeographicLib::Geodesic;
using GeographicLib::Gnomonic;
using GeographicLib::LocalCartesian;

namespace {

bool finite_all(std::initializer_list<double> v)
{
    for (double x : v)
        if (!std::isfinite(x)) return false;
    return true;
}

int fail_nonfinite(const char *what)
{
    gs_fail(GS_ENUMERIC, "GeographicLib %s: non-finite result (input out of range)", what);
    return -1;
}

int fail_exception(const char *what, const std::exception &e)
{
    gs_fail(GS_ENUMERIC, "GeographicLib %s: %s", what, e.what());
    return -1;
}

int fail_unknown(const char *what)
{
    gs_fail(GS_ENUMERIC, "GeographicLib %s: unknown exception", what);
    return -1;
}

} // namespace

extern "C" int gis_gl_geocentric_fwd(double lat, double lon, double h, double xyz[3], double M[9])
{
    try {
        // without M, the overload that takes none (an empty vector makes GeographicLib's
        // header add an offset to a null pointer)
        if (M) {
            std::vector<double> m(9);
            Geocentric::WGS84().Forward(lat, lon, h, xyz[0], xyz[1], xyz[2], m);
            for (int i = 0; i < 9; i++) M[i] = m[i];
        } else {
            Geocentric::WGS84().Forward(lat, lon, h, xyz[0], xyz[1], xyz[2]);
        }
        if (!finite_all({xyz[0], xyz[1], xyz[2]})) return fail_nonfinite("Geocentric::Forward");
        return 0;
    } catch (const std::exception &e) {
        return fail_exception("Geocentric::Forward", e);
    } catch (...) {
        return fail_unknown("Geocentric::Forward");
    }
}

extern "C" int gis_gl_geocentric_rev(const double xyz[3], double *lat, double *lon, double *h,
                                     double M[9])
{
    try {
        if (M) {
            std::vector<double> m(9);
            Geocentric::WGS84().Reverse(xyz[0], xyz[1], xyz[2], *lat, *lon, *h, m);
            for (int i = 0; i < 9; i++) M[i] = m[i];
        } else {
            Geocentric::WGS84().Reverse(xyz[0], xyz[1], xyz[2], *lat, *lon, *h);
        }
        if (!finite_all({*lat, *lon, *h})) return fail_nonfinite("Geocentric::Reverse");
        return 0;
    } catch (const std::exception &e) {
        return fail_exception("Geocentric::Reverse", e);
    } catch (...) {
        return fail_unknown("Geocentric::Reverse");
    }
}

extern "C" int gis_gl_local_fwd(double lat0, double lon0, double h0, double lat, double lon,
                                double h, double enu[3])
{
    try {
        LocalCartesian lc(lat0, lon0, h0, Geocentric::WGS84());
        lc.Forward(lat, lon, h, enu[0], enu[1], enu[2]);
        if (!finite_all({enu[0], enu[1], enu[2]})) return fail_nonfinite("LocalCartesian::Forward");
        return 0;
    } catch (const std::exception &e) {
        return fail_exception("LocalCartesian::Forward", e);
    } catch (...) {
        return fail_unknown("LocalCartesian::Forward");
    }
}

extern "C" int gis_gl_local_rev(double lat0, double lon0, double h0, const double enu[3],
                                double *lat, double *lon, double *h)
{
    try {
        LocalCartesian lc(lat0, lon0, h0, Geocentric::WGS84());
        lc.Reverse(enu[0], enu[1], enu[2], *lat, *lon, *h);
        if (!finite_all({*lat, *lon, *h})) return fail_nonfinite("LocalCartesian::Reverse");
        return 0;
    } catch (const std::exception &e) {
        return fail_exception("LocalCartesian::Reverse", e);
    } catch (...) {
        return fail_unknown("LocalCartesian::Reverse");
    }
}

extern "C" int gis_gl_direct(double lat1, double lon1, double azi1, double s12, double *lat2,
                             double *lon2, double *azi2)
{
    try {
        double a2 = 0.0;
        Geodesic::WGS84().Direct(lat1, lon1, azi1, s12, *lat2, *lon2, a2);
        if (azi2) *azi2 = a2;
        if (!finite_all({*lat2, *lon2, a2})) return fail_nonfinite("Geodesic::Direct");
        return 0;
    } catch (const std::exception &e) {
        return fail_exception("Geodesic::Direct", e);
    } catch (...) {
        return fail_unknown("Geodesic::Direct");
    }
}

extern "C" int gis_gl_inverse(double lat1, double lon1, double lat2, double lon2, double *s12,
                              double *azi1, double *azi2)
{
    try {
        double s = 0.0, a1 = 0.0, a2 = 0.0;
        Geodesic::WGS84().Inverse(lat1, lon1, lat2, lon2, s, a1, a2);
        if (s12) *s12 = s;
        if (azi1) *azi1 = a1;
        if (azi2) *azi2 = a2;
        if (!finite_all({s, a1, a2})) return fail_nonfinite("Geodesic::Inverse");
        return 0;
    } catch (const std::exception &e) {
        return fail_exception("Geodesic::Inverse", e);
    } catch (...) {
        return fail_unknown("Geodesic::Inverse");
    }
}

// The public straight-line distance (gis.h): two geocentric points.
extern "C" double gis_chord_m(double lat1_deg, double lon1_deg, double h1_m, double lat2_deg,
                              double lon2_deg, double h2_m)
{
    double a[3], b[3];
    if (std::fabs(lat1_deg) > 90.0 || std::fabs(lat2_deg) > 90.0 ||
        gis_gl_geocentric_fwd(lat1_deg, lon1_deg, h1_m, a, nullptr) ||
        gis_gl_geocentric_fwd(lat2_deg, lon2_deg, h2_m, b, nullptr))
        return NAN;
    return std::sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) +
                     (a[2] - b[2]) * (a[2] - b[2]));
}

// The public metres per degree (gis.h): WGS84's radii of curvature at lat_deg.
extern "C" void gis_metres_per_deg(double lat_deg, double *north_m, double *east_m)
{
    const GeographicLib::Ellipsoid &e = GeographicLib::Ellipsoid::WGS84();
    const double deg = GeographicLib::Math::degree();
    *north_m = e.MeridionalCurvatureRadius(lat_deg) * deg;
    *east_m = e.CircleRadius(lat_deg) * deg;
}

// The public geodesic distance (gis.h): argument checks, then gis_gl_inverse.
extern "C" gs_status gis_geodesic_inverse(double lat1_deg, double lon1_deg, double lat2_deg,
                                          double lon2_deg, double *s12_m, double *azi1_deg,
                                          double *azi2_deg)
{
    if (!finite_all({lat1_deg, lon1_deg, lat2_deg, lon2_deg}))
        return gs_fail(GS_ENUMERIC, "gis_geodesic_inverse: non-finite coordinate");
    if (std::fabs(lat1_deg) > 90.0 || std::fabs(lat2_deg) > 90.0)
        return gs_fail(GS_EINVAL, "gis_geodesic_inverse: latitude %g / %g: expected [-90, 90]",
                       lat1_deg, lat2_deg);
    double s = 0.0, a1 = 0.0, a2 = 0.0;
    if (gis_gl_inverse(lat1_deg, lon1_deg, lat2_deg, lon2_deg, &s, &a1, &a2)) return GS_ENUMERIC;
    if (s12_m) *s12_m = s;
    if (azi1_deg) *azi1_deg = a1;
    if (azi2_deg) *azi2_deg = a2;
    return GS_OK;
}

extern "C" int gis_gl_gnomonic_fwd(double lat0, double lon0, double lat, double lon, double *x,
                                   double *y)
{
    try {
        static const Gnomonic gn(Geodesic::WGS84());
        gn.Forward(lat0, lon0, lat, lon, *x, *y);
        if (!finite_all({*x, *y})) return fail_nonfinite("Gnomonic::Forward (beyond the horizon)");
        return 0;
    } catch (const std::exception &e) {
        return fail_exception("Gnomonic::Forward", e);
    } catch (...) {
        return fail_unknown("Gnomonic::Forward");
    }
}

extern "C" int gis_gl_gnomonic_rev(double lat0, double lon0, double x, double y, double *lat,
                                   double *lon)
{
    try {
        static const Gnomonic gn(Geodesic::WGS84());
        gn.Reverse(lat0, lon0, x, y, *lat, *lon);
        if (!finite_all({*lat, *lon})) return fail_nonfinite("Gnomonic::Reverse");
        return 0;
    } catch (const std::exception &e) {
        return fail_exception("Gnomonic::Reverse", e);
    } catch (...) {
        return fail_unknown("Gnomonic::Reverse");
    }
}

extern "C" const char *gis_geographiclib_version(void)
{
    return GEOGRAPHICLIB_VERSION_STRING;
}
