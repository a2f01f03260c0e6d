/* test_gis_triangulate.c - gis_triangulate (two stations) against independent oracles
 * (tests/gis_fixture.h): light positions and azimuths from GeodSolve, the error ellipse
 * against the first-order one from the reduced lengths m12 (GeodSolve -f), near-parallel and
 * behind bearings, and triangulation from pixels. */
#include "gis/gis.h"
#include "gis/internal.h"
#include "tests/gis_fixture.h"
#include "tests/test.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------ two-station oracle */

/* n random light positions P at <= 20 km from a station A (GeodSolve direct), a second station
 * B at <= 20 km from P at an intersection angle of 10..170 deg; the azimuths toward P and the
 * reduced lengths m12 from GeodSolve -i -f. gis_triangulate must return P, and its ellipse
 * must equal the first-order one: an azimuth error at A moves the geodesic by m12_A dphi at
 * P, which slides the intersection along B's geodesic by m12_A dphi / sin(gamma). */
static void triangulate_oracle(int n, const gisfx_region *rg, unsigned long long seed, const char *label)
{
    gisfx_rng_seed(seed);
    double *P = calloc((size_t)n * 12, sizeof *P);
    gisfx_sbuf b1 = {0}, b2 = {0}, b3 = {0};
    char *out = NULL, *q;
    for (int i = 0; i < n; i++) {
        double *p = P + 12 * i;   /* latA lonA az1 s1 gamma s2 ... */
        p[0] = gisfx_urand(rg->lat_lo, rg->lat_hi);
        p[1] = gisfx_urand(rg->lon_lo, rg->lon_hi);
        p[2] = gisfx_urand(0.0, 360.0);
        p[3] = gisfx_urand(100.0, 20000.0);
        p[4] = gisfx_urand(10.0, 170.0) * (gisfx_urand(0, 1) < 0.5 ? -1.0 : 1.0);
        p[5] = gisfx_urand(100.0, 20000.0);
        gisfx_sb_printf(&b1, "%.15g %.15g %.15g %.15g\n", p[0], p[1], p[2], p[3]);
    }
    out = gisfx_run_tool("GeodSolve -p 9", &b1);
    if (!out) goto done;
    q = out;
    for (int i = 0; i < n; i++) {
        double *p = P + 12 * i;   /* p[6], p[7] = P; p[8] = azi2 at P of A's geodesic */
        p[6] = gisfx_next_num(&q);
        p[7] = gisfx_next_num(&q);
        p[8] = gisfx_next_num(&q);
        gisfx_sb_printf(&b2, "%.15g %.15g %.15g %.15g\n", p[6], p[7], p[8] + 180.0 + p[4], p[5]);
    }
    free(out);
    out = gisfx_run_tool("GeodSolve -p 9", &b2);
    if (!out) goto done;
    q = out;
    for (int i = 0; i < n; i++) {
        double *p = P + 12 * i;   /* p[9], p[10] = B */
        p[9] = gisfx_next_num(&q);
        p[10] = gisfx_next_num(&q);
        gisfx_next_num(&q);
        gisfx_sb_printf(&b3, "%.15g %.15g %.15g %.15g\n%.15g %.15g %.15g %.15g\n", p[0], p[1], p[6],
                        p[7], p[9], p[10], p[6], p[7]);
    }
    free(out);
    out = gisfx_run_tool("GeodSolve -i -f -p 9", &b3);
    if (!out) goto done;
    q = out;
    double max_pos = 0, max_dist = 0, max_cov = 0;
    int max_it = 0, checked = 0;
    for (int i = 0; i < n; i++) {
        double *p = P + 12 * i, f[2][12];
        for (int r = 0; r < 2; r++)
            for (int k = 0; k < 12; k++) f[r][k] = gisfx_next_num(&q);
        /* fields: lat1 lon1 azi1 lat2 lon2 azi2 s12 a12 m12 M12 M21 S12 */
        gis_bearing a = {p[0], p[1], f[0][2], 0.01}, b = {p[9], p[10], f[1][2], 0.02};
        gis_intersection it;
        CHECK_OK(gis_triangulate(&a, &b, NULL, &it));
        CHECK_MSG(it.flags == 0, "%s case %d: flags %#x", label, i, it.flags);
        double ep = gisfx_err_m(it.lat_deg, it.lon_deg, p[6], p[7]);
        double ed = fmax(fabs(it.distance_m[0] - f[0][6]), fabs(it.distance_m[1] - f[1][6]));
        double g = fabs(gs_wrap180(f[0][5] - f[1][5]));
        double gamma = g > 90.0 ? 180.0 - g : g;
        /* first-order covariance */
        double sg = sin(gamma * D2R), ua[2] = {sin(f[0][5] * D2R), cos(f[0][5] * D2R)},
               ub[2] = {sin(f[1][5] * D2R), cos(f[1][5] * D2R)};
        double ka = f[0][8] * a.sigma_deg * D2R / sg, kb = f[1][8] * b.sigma_deg * D2R / sg;
        double C[3] = {ka * ka * ub[0] * ub[0] + kb * kb * ua[0] * ua[0],
                       ka * ka * ub[0] * ub[1] + kb * kb * ua[0] * ua[1],
                       ka * ka * ub[1] * ub[1] + kb * kb * ua[1] * ua[1]};
        double G[3];
        gisfx_ellipse_cov(&it.ellipse, G);
        double scale = C[0] + C[2], ec = 0.0;
        for (int k = 0; k < 3; k++) ec = fmax(ec, fabs(G[k] - C[k]) / scale);
        CHECK_MSG(ep <= 1e-3 && ed <= 1e-3, "%s case %d: position %.3g m, distances %.3g m",
                  label, i, ep, ed);
        CHECK_MSG(fabs(it.angle_deg - gamma) <= 1e-6, "%s case %d: angle %.9f vs %.9f", label, i,
                  it.angle_deg, gamma);
        CHECK_MSG(ec <= 1e-4, "%s case %d: covariance differs by %.3g (relative)", label, i, ec);
        CHECK_MSG(it.iterations <= 5, "%s case %d: %d iterations", label, i, it.iterations);
        if (ep > max_pos) max_pos = ep;
        if (ed > max_dist) max_dist = ed;
        if (ec > max_cov) max_cov = ec;
        if (it.iterations > max_it) max_it = it.iterations;
        checked++;
    }
    CHECK(checked == n);
    printf("    %s: %d cases, max errors: position %.2e m, distance %.2e m, covariance %.2e "
           "(relative), max %d iterations\n", label, checked, max_pos, max_dist, max_cov, max_it);
done:
    free(out);
    free(b1.s);
    free(b2.s);
    free(b3.s);
    free(P);
}

TEST(gis_triangulate_oracle_random)
{
    triangulate_oracle(300, &gisfx_worldwide, 21, "worldwide");
}

TEST(gis_triangulate_oracle_poles)
{
    triangulate_oracle(40, &gisfx_north_pole, 22, "north pole");
    triangulate_oracle(40, &gisfx_south_pole, 23, "south pole");
}

TEST(gis_triangulate_oracle_antimeridian)
{
    triangulate_oracle(40, &gisfx_am_east, 24, "antimeridian east");
    triangulate_oracle(40, &gisfx_am_west, 25, "antimeridian west");
}

TEST(gis_triangulate_near_parallel)
{
    /* Stations 1 km apart on an east-west baseline; a light ~114.6 km north: the bearings
     * meet at 0.5 deg. Flagged, no point, and the ellipse is the first-order one (m12 from
     * GeodSolve -f), about sqrt(2) m12 sigma / sin(0.5 deg) = 16 km for sigma = 0.05 deg. */
    double lat0 = 45.0, lon0 = 7.0, latB, lonB, latP, lonP, mid_lat, mid_lon;
    CHECK(gis_gl_direct(lat0, lon0, 90.0, 1000.0, &latB, &lonB, NULL) == 0);
    CHECK(gis_gl_direct(lat0, lon0, 90.0, 500.0, &mid_lat, &mid_lon, NULL) == 0);
    CHECK(gis_gl_direct(mid_lat, mid_lon, 0.0, 500.0 / tan(0.25 * D2R), &latP, &lonP, NULL) == 0);
    gisfx_sbuf in = {0};
    gisfx_sb_printf(&in, "%.15g %.15g %.15g %.15g\n%.15g %.15g %.15g %.15g\n", lat0, lon0, latP, lonP,
                    latB, lonB, latP, lonP);
    char *out = gisfx_run_tool("GeodSolve -i -f -p 9", &in), *q = out;
    free(in.s);
    CHECK(out != NULL);
    if (!out) return;
    double f[2][12];
    for (int r = 0; r < 2; r++)
        for (int k = 0; k < 12; k++) f[r][k] = gisfx_next_num(&q);
    free(out);
    gis_bearing a = {lat0, lon0, f[0][2], 0.05}, b = {latB, lonB, f[1][2], 0.05};
    gis_intersection it;
    CHECK_OK(gis_triangulate(&a, &b, NULL, &it));
    CHECK(it.flags == GIS_FIX_NEAR_PARALLEL);
    CHECK(isnan(it.lat_deg) && isnan(it.lon_deg));
    double g = fabs(gs_wrap180(f[0][5] - f[1][5]));
    CHECK_NEAR(it.angle_deg, g, 1e-6);
    CHECK_NEAR(it.angle_deg, 0.5, 0.01);
    CHECK_NEAR(it.distance_m[0], f[0][6], 1e-3);
    double sg = sin(g * D2R), ua[2] = {sin(f[0][5] * D2R), cos(f[0][5] * D2R)},
           ub[2] = {sin(f[1][5] * D2R), cos(f[1][5] * D2R)};
    double ka = f[0][8] * 0.05 * D2R / sg, kb = f[1][8] * 0.05 * D2R / sg;
    double C[3] = {ka * ka * ub[0] * ub[0] + kb * kb * ua[0] * ua[0],
                   ka * ka * ub[0] * ub[1] + kb * kb * ua[0] * ua[1],
                   ka * ka * ub[1] * ub[1] + kb * kb * ua[1] * ua[1]};
    double G[3];
    gisfx_ellipse_cov(&it.ellipse, G);
    for (int k = 0; k < 3; k++) CHECK_NEAR(G[k], C[k], 1e-3 * (C[0] + C[2]));
    CHECK(it.ellipse.semi_major_m > 15000.0 && it.ellipse.semi_major_m < 17000.0);
    CHECK_NEAR(it.ellipse.azimuth_deg, 0.0, 0.5);
    /* the same geometry with a tiny sigma is still flagged by the angle alone */
    a.sigma_deg = b.sigma_deg = 1e-6;
    CHECK_OK(gis_triangulate(&a, &b, NULL, &it));
    CHECK(it.flags == GIS_FIX_NEAR_PARALLEL);
    /* and accepted when the caller lowers the angle limit */
    gis_triangulate_opts o;
    gis_triangulate_opts_default(&o);
    o.min_angle_deg = 0.1;
    CHECK_OK(gis_triangulate(&a, &b, &o, &it));
    CHECK(it.flags == 0);
    CHECK_NEAR(gisfx_err_m(it.lat_deg, it.lon_deg, latP, lonP), 0.0, 1e-3);
    /* parallel meridians meet at the pole, at a 0.01 deg angle: flagged */
    gis_bearing m1 = {45.0, 7.0, 0.0, 0.01}, m2 = {45.0, 7.01, 0.0, 0.01};
    CHECK_OK(gis_triangulate(&m1, &m2, NULL, &it));
    CHECK(it.flags & GIS_FIX_NEAR_PARALLEL);
    CHECK(isnan(it.lat_deg));
    /* two stations looking at each other: the lines coincide */
    double az_ab, az_ba, s;
    CHECK(gis_gl_inverse(lat0, lon0, latB, lonB, &s, &az_ab, &az_ba) == 0);
    gis_bearing c1 = {lat0, lon0, az_ab, 0.01}, c2 = {latB, lonB, az_ba + 180.0, 0.01};
    CHECK_OK(gis_triangulate(&c1, &c2, NULL, &it));
    CHECK(it.flags & GIS_FIX_NEAR_PARALLEL);
    CHECK(isnan(it.lat_deg));
}

TEST(gis_triangulate_behind)
{
    double latB, lonB, latP, lonP, s, a1, a2, b1, b2;
    CHECK(gis_gl_direct(45.0, 7.0, 90.0, 1000.0, &latB, &lonB, NULL) == 0);
    CHECK(gis_gl_direct(45.0, 7.0, 20.0, 5000.0, &latP, &lonP, NULL) == 0);
    CHECK(gis_gl_inverse(45.0, 7.0, latP, lonP, &s, &a1, &a2) == 0);
    CHECK(gis_gl_inverse(latB, lonB, latP, lonP, &s, &b1, &b2) == 0);
    gis_bearing a = {45.0, 7.0, a1, 0.01}, b = {latB, lonB, b1, 0.01};
    gis_intersection it;
    CHECK_OK(gis_triangulate(&a, &b, NULL, &it));
    CHECK(it.flags == 0);
    CHECK_NEAR(gisfx_err_m(it.lat_deg, it.lon_deg, latP, lonP), 0.0, 1e-3);
    /* both reversed: the lines still meet at P, behind both stations */
    a.azimuth_deg += 180.0;
    b.azimuth_deg += 180.0;
    CHECK_OK(gis_triangulate(&a, &b, NULL, &it));
    CHECK(it.flags & GIS_FIX_BEHIND);
    CHECK(isnan(it.lat_deg) && isnan(it.lon_deg));
    CHECK_NEAR(it.distance_m[0], 5000.0, 1e-3);   /* the meeting point is still reported as distances */
    /* one reversed */
    b.azimuth_deg -= 180.0;
    CHECK_OK(gis_triangulate(&a, &b, NULL, &it));
    CHECK(it.flags == GIS_FIX_BEHIND);
}

TEST(gis_triangulate_from_pixels)
{
    /* Two cameras see the same light; bearings from pixels (gis_pixel_bearing) triangulate to
     * the light within 1 mm at 3 km (the normal-section azimuth differs from the geodesic's by
     * far less). */
    double latP, lonP, latB, lonB;
    CHECK(gis_gl_direct(45.0, 7.0, 30.0, 3000.0, &latP, &lonP, NULL) == 0);
    CHECK(gis_gl_direct(45.0, 7.0, 100.0, 800.0, &latB, &lonB, NULL) == 0);
    gis_camera ca = gisfx_base_camera(), cb = gisfx_base_camera();
    cb.lat_deg = latB;
    cb.lon_deg = lonB;
    cb.height_m = 140.0;
    ca.heading_deg = 25.0;
    cb.heading_deg = 10.0;
    ca.pitch_deg = cb.pitch_deg = -2.0;
    ca.k1 = cb.k1 = -0.1;
    double xa, ya, xb, yb, aza, azb;
    int fa, fb;
    CHECK_OK(gis_project(&ca, latP, lonP, 20.0, &xa, &ya, &fa));
    CHECK_OK(gis_project(&cb, latP, lonP, 20.0, &xb, &yb, &fb));
    CHECK(fa && fb && gis_in_image(&ca, xa, ya) && gis_in_image(&cb, xb, yb));
    CHECK_OK(gis_pixel_bearing(&ca, xa, ya, &aza, NULL));
    CHECK_OK(gis_pixel_bearing(&cb, xb, yb, &azb, NULL));
    gis_bearing a = {ca.lat_deg, ca.lon_deg, aza, 0.01}, b = {cb.lat_deg, cb.lon_deg, azb, 0.01};
    gis_intersection it;
    CHECK_OK(gis_triangulate(&a, &b, NULL, &it));
    CHECK(it.flags == 0);
    CHECK_NEAR(gisfx_err_m(it.lat_deg, it.lon_deg, latP, lonP), 0.0, 1e-3);
}
