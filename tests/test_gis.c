/* test_gis.c - gis/ geometry of one station against independent oracles (tests/gis_fixture.h):
 * GeographicLib's command-line tools (GeodSolve for geodesics, CartConvert for geocentric
 * coordinates, run in batches with -p 9), a camera written independently (the pose as
 * extrinsic rotations about fixed ENU axes, not the library's closed form), analytic error
 * ellipses and round trips. Hard cases are named tests: near-horizontal rays, pitch +-90,
 * poles, the antimeridian, distortion at image corners, NaN/Inf inputs. Station files too.
 * Two stations: tests/test_gis_triangulate.c. */
#include "gis/gis.h"
#include "gis/internal.h"
#include "tests/gis_fixture.h"
#include "tests/test.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------- one-station oracle */

/* n random stations in the region; each sees a light placed with GeodSolve (direct problem)
 * at a random azimuth and distance <= 20 km, below the station (and before the horizon of the
 * light's surface); ENU from CartConvert's geocentric coordinates; the pixel from the test
 * camera. gis_project must give that pixel, gis_locate the light. */
static void locate_oracle(int n, const gisfx_region *rg, unsigned long long seed, const char *label)
{
    gisfx_rng_seed(seed);
    double *P = calloc((size_t)n * 8, sizeof *P);   /* lat, lon, H, ht, az, s, lat_t, lon_t */
    gisfx_sbuf direct = {0}, cart = {0};
    for (int i = 0; i < n; i++) {
        double *p = P + 8 * i;
        p[0] = gisfx_urand(rg->lat_lo, rg->lat_hi);
        p[1] = gisfx_urand(rg->lon_lo, rg->lon_hi);
        p[2] = gisfx_urand(20.0, 600.0);
        double delta = gisfx_urand(10.0, 300.0);
        p[3] = p[2] - delta;
        if (p[3] < -100.0) p[3] = -100.0, delta = p[2] + 100.0;
        double smax = 0.8 * sqrt(2.0 * 6.36e6 * delta);
        p[4] = gisfx_urand(0.0, 360.0);
        p[5] = gisfx_urand(20.0, smax < 20000.0 ? smax : 20000.0);
        gisfx_sb_printf(&direct, "%.15g %.15g %.15g %.15g\n", p[0], p[1], p[4], p[5]);
    }
    char *out = gisfx_run_tool("GeodSolve -p 9", &direct);
    CHECK(out != NULL);
    if (!out) goto done;
    char *q = out;
    for (int i = 0; i < n; i++) {
        double *p = P + 8 * i;
        p[6] = gisfx_next_num(&q);
        p[7] = gisfx_next_num(&q);
        gisfx_next_num(&q);   /* azi2 */
        gisfx_sb_printf(&cart, "%.15g %.15g %.15g\n%.15g %.15g %.15g\n", p[0], p[1], p[2], p[6], p[7], p[3]);
    }
    free(out);
    out = gisfx_run_tool("CartConvert -p 9", &cart);
    CHECK(out != NULL);
    if (!out) goto done;
    q = out;
    double max_pos = 0, max_range = 0, max_dist = 0, max_px = 0, max_bear = 0;
    int checked = 0;
    for (int i = 0; i < n; i++) {
        double *p = P + 8 * i, xs[3], xt[3], e[3], nn[3], u[3], v[3], c[3];
        for (int k = 0; k < 3; k++) xs[k] = gisfx_next_num(&q);
        for (int k = 0; k < 3; k++) xt[k] = gisfx_next_num(&q);
        for (int k = 0; k < 3; k++) c[k] = xt[k] - xs[k];
        gisfx_enu_basis(p[0], p[1], e, nn, u);
        v[0] = e[0] * c[0] + e[1] * c[1] + e[2] * c[2];
        v[1] = nn[0] * c[0] + nn[1] * c[1] + nn[2] * c[2];
        v[2] = u[0] * c[0] + u[1] * c[1] + u[2] * c[2];
        double elev = atan2(v[2], hypot(v[0], v[1])) / D2R, range = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        gis_camera cam = gisfx_base_camera();
        cam.lat_deg = p[0];
        cam.lon_deg = p[1];
        cam.height_m = p[2];
        cam.focal_px = gisfx_urand(800.0, 4000.0);
        cam.cx_px = 959.5 + gisfx_urand(-30, 30);
        cam.cy_px = 539.5 + gisfx_urand(-30, 30);
        cam.k1 = gisfx_urand(-0.15, 0.05);
        cam.k2 = gisfx_urand(-0.01, 0.02);
        double x = NAN, y = NAN;
        int ok = 0;
        for (int tries = 0; tries < 20 && !ok; tries++) {
            double spread = tries < 19 ? 1.0 : 0.0;
            cam.heading_deg = p[4] + spread * gisfx_urand(-15, 15);
            cam.pitch_deg = elev + spread * gisfx_urand(-8, 8);
            if (cam.pitch_deg > 90) cam.pitch_deg = 90;
            if (cam.pitch_deg < -90) cam.pitch_deg = -90;
            cam.roll_deg = spread * gisfx_urand(-30, 30);
            ok = gisfx_project(&cam, v, &x, &y);
        }
        CHECK(ok);
        if (!ok) continue;
        double gx, gy;
        int front;
        CHECK_OK(gis_project(&cam, p[6], p[7], p[3], &gx, &gy, &front));
        CHECK(front == 1);
        double dpx = hypot(gx - x, gy - y);
        if (dpx > max_px) max_px = dpx;
        gis_fix fx;
        CHECK_OK(gis_locate(&cam, x, y, 0.0, p[3], NULL, &fx));
        CHECK_MSG(fx.flags == 0, "%s case %d: flags %#x", label, i, fx.flags);
        double ep = gisfx_err_m(fx.lat_deg, fx.lon_deg, p[6], p[7]);
        double er = fabs(fx.range_m - range), ed = fabs(fx.distance_m - p[5]), eh = fabs(fx.height_m - p[3]);
        double eb = fabs(gs_wrap180(fx.bearing_deg - p[4])) * D2R * p[5];
        double az_px, el_px;
        CHECK_OK(gis_pixel_bearing(&cam, x, y, &az_px, &el_px));
        /* The pixel's azimuth is that of the vertical plane through the elevated light: it
         * differs from the geodesic azimuth to the light's foot by the skew-normal correction
         * e^2 h cos^2(lat) sin(2 az) / (2 N) (h = the light's height), to 1e-8 rad (the
         * normal section's own departure from the geodesic is ~5e-9 rad at 20 km). */
        double e2 = 0.0066943799901413165, sl = sin(p[0] * D2R);
        double Nrad = 6378137.0 / sqrt(1.0 - e2 * sl * sl);
        double skew = e2 * p[3] * cos(p[0] * D2R) * cos(p[0] * D2R) * sin(2.0 * p[4] * D2R) / (2.0 * Nrad);
        double eb_px = fabs(gs_wrap180(az_px - p[4]));
        double eb_skew = fabs(fabs(eb_px * D2R) - fabs(skew));
        CHECK_MSG(ep <= 1e-3 && er <= 1e-3 && ed <= 1e-3 && eh <= 1e-6 && eb <= 1e-3,
                  "%s case %d (%.6f, %.6f, H %.1f, ht %.1f, az %.3f, s %.1f): position %.3g m, "
                  "range %.3g m, distance %.3g m, height %.3g m, bearing %.3g m", label, i, p[0],
                  p[1], p[2], p[3], p[4], p[5], ep, er, ed, eh, eb);
        CHECK_MSG(eb_skew <= 0.02 * fabs(skew) + 1e-8, "%s case %d: pixel bearing %.3g rad from "
                  "the geodesic's, skew-normal correction %.3g rad", label, i, eb_px * D2R, skew);
        CHECK_MSG(fabs(el_px - elev) <= 1e-7, "%s case %d: elevation %.12f vs %.12f", label, i, el_px, elev);
        CHECK_MSG(dpx <= 1e-6, "%s case %d: gis_project %.3g px from the test camera", label, i, dpx);
        if (ep > max_pos) max_pos = ep;
        if (er > max_range) max_range = er;
        if (ed > max_dist) max_dist = ed;
        if (eb_skew > max_bear) max_bear = eb_skew;
        checked++;
    }
    CHECK(checked == n);
    printf("    %s: %d cases, max errors: position %.2e m, range %.2e m, distance %.2e m, "
           "projection %.2e px, pixel bearing - skew-normal %.2e rad\n",
           label, checked, max_pos, max_range, max_dist, max_px, max_bear);
done:
    free(out);
    free(direct.s);
    free(cart.s);
    free(P);
}

TEST(gis_locate_oracle_random)
{
    locate_oracle(300, &gisfx_worldwide, 11, "worldwide");
}

TEST(gis_locate_oracle_poles)
{
    locate_oracle(40, &gisfx_north_pole, 12, "north pole");
    locate_oracle(40, &gisfx_south_pole, 13, "south pole");
}

TEST(gis_locate_oracle_antimeridian)
{
    locate_oracle(40, &gisfx_am_east, 14, "antimeridian east");
    locate_oracle(40, &gisfx_am_west, 15, "antimeridian west");
}

/* ------------------------------------------------------------- round trips */

/* geodetic -> pixel -> geodetic over a grid of stations, poses and ranges up to 20 km. */
static void round_trip_grid(double refraction_k, const char *label)
{
    const double lats[] = {0.0, 45.0, -60.0, 89.9}, heights[] = {100.0, 1500.0};
    const double dists[] = {10.0, 100.0, 1000.0, 5000.0, 20000.0}, rolls[] = {-25.0, 0.0, 40.0};
    double worst = 0.0;
    int cases = 0;
    for (size_t a = 0; a < 4; a++)
        for (size_t b = 0; b < 2; b++)
            for (int hd = 0; hd < 8; hd++)
                for (size_t d = 0; d < 5; d++)
                    for (size_t r = 0; r < 3; r++) {
                        gis_camera cam = gisfx_base_camera();
                        cam.lat_deg = lats[a];
                        cam.lon_deg = 179.0 + a;
                        cam.height_m = heights[b];
                        cam.k1 = -0.1;
                        cam.k2 = 0.02;
                        cam.refraction_k = refraction_k;
                        double az = hd * 45.0 + 7.0, lat, lon, ht = 12.0;
                        CHECK(gis_gl_direct(cam.lat_deg, cam.lon_deg, az, dists[d], &lat, &lon, NULL) == 0);
                        double enu[3], dir[3];
                        CHECK(gis_gl_local_fwd(cam.lat_deg, cam.lon_deg, cam.height_m, lat, lon, ht, enu) == 0);
                        gis_apparent_dir(&cam, enu, dir);
                        cam.heading_deg = az + 6.0 * (double)r - 6.0;
                        cam.pitch_deg = atan2(dir[2], hypot(dir[0], dir[1])) / D2R + 3.0;
                        cam.roll_deg = rolls[r];
                        double x, y;
                        int front;
                        CHECK_OK(gis_project(&cam, lat, lon, ht, &x, &y, &front));
                        CHECK(front == 1);
                        gis_fix fx;
                        CHECK_OK(gis_locate(&cam, x, y, 0.0, ht, NULL, &fx));
                        double s12 = NAN;
                        CHECK(fx.flags == 0);
                        if (fx.flags == 0)
                            CHECK(gis_gl_inverse(lat, lon, fx.lat_deg, fx.lon_deg, &s12, NULL, NULL) == 0);
                        CHECK_MSG(s12 <= 1e-3, "%s: lat %g, height %g, az %g, distance %g, roll %g: "
                                  "round trip %.3g m", label, lats[a], heights[b], az, dists[d], rolls[r], s12);
                        if (s12 > worst) worst = s12;
                        cases++;
                    }
    printf("    %s: %d round trips, worst %.2e m\n", label, cases, worst);
}

TEST(gis_round_trip_grid)
{
    round_trip_grid(0.0, "straight sight lines");
}

TEST(gis_round_trip_grid_refraction)
{
    round_trip_grid(GIS_REFRACTION_K_STANDARD, "refraction k = 0.13");
}

/* ------------------------------------------------------------ named hard cases */

TEST(gis_pitch_minus_90_nadir)
{
    gis_camera cam = gisfx_base_camera();
    cam.height_m = 500.0;
    cam.pitch_deg = -90.0;
    cam.heading_deg = 0.0;
    gis_fix fx;
    /* the principal point sees the foot of the ellipsoid normal */
    CHECK_OK(gis_locate(&cam, cam.cx_px, cam.cy_px, 0.0, 0.0, NULL, &fx));
    CHECK(fx.flags == 0);
    CHECK_NEAR(gisfx_err_m(fx.lat_deg, fx.lon_deg, cam.lat_deg, cam.lon_deg), 0.0, 1e-6);
    CHECK_NEAR(fx.range_m, 500.0, 1e-6);
    /* image right = east, image up = the heading (north) */
    CHECK_OK(gis_locate(&cam, cam.cx_px + 200.0, cam.cy_px, 0.0, 0.0, NULL, &fx));
    CHECK_NEAR(fx.bearing_deg, 90.0, 1e-6);
    CHECK_NEAR(fx.distance_m, 500.0 * 200.0 / 2000.0, 0.01);
    CHECK_OK(gis_locate(&cam, cam.cx_px, cam.cy_px - 200.0, 0.0, 0.0, NULL, &fx));
    CHECK(fabs(gs_wrap180(fx.bearing_deg)) < 1e-6);
    cam.heading_deg = 90.0;
    CHECK_OK(gis_locate(&cam, cam.cx_px, cam.cy_px - 200.0, 0.0, 0.0, NULL, &fx));
    CHECK_NEAR(fx.bearing_deg, 90.0, 1e-6);
    /* round trip over the whole image, with roll */
    cam.roll_deg = 33.0;
    cam.k1 = -0.1;
    for (int i = 0; i <= 8; i++)
        for (int j = 0; j <= 8; j++) {
            double x = i * 1919.0 / 8, y = j * 1079.0 / 8, gx, gy;
            int front;
            CHECK_OK(gis_locate(&cam, x, y, 0.0, 3.0, NULL, &fx));
            CHECK(fx.flags == 0);
            CHECK_OK(gis_project(&cam, fx.lat_deg, fx.lon_deg, 3.0, &gx, &gy, &front));
            CHECK(front == 1);
            CHECK_NEAR(hypot(gx - x, gy - y), 0.0, 1e-6);
        }
}

TEST(gis_pitch_plus_90_zenith)
{
    gis_camera cam = gisfx_base_camera();
    cam.pitch_deg = 90.0;
    gis_fix fx;
    CHECK_OK(gis_locate(&cam, cam.cx_px, cam.cy_px, 1.0, 0.0, NULL, &fx));
    CHECK(fx.flags & GIS_FIX_ABOVE_HORIZON);
    CHECK(isnan(fx.lat_deg) && isnan(fx.lon_deg) && isnan(fx.range_m));
    CHECK_NEAR(fx.elevation_deg, 90.0, 1e-9);
    double x, y;
    int front = -1;
    CHECK_OK(gis_project(&cam, 45.001, 7.0, 0.0, &x, &y, &front));   /* on the ground: behind */
    CHECK(front == 0 && isnan(x) && isnan(y));
    CHECK_OK(gis_project(&cam, 45.0, 7.0, 1100.0, &x, &y, &front));  /* straight above */
    CHECK(front == 1);
    CHECK_NEAR(x, cam.cx_px, 1e-6);
    CHECK_NEAR(y, cam.cy_px, 1e-6);
    /* looking up, a light above the station's height is found where the line rises through
     * its surface */
    cam.pitch_deg = 30.0;
    CHECK_OK(gis_locate(&cam, cam.cx_px, cam.cy_px, 0.0, 600.0, NULL, &fx));
    CHECK(fx.flags == 0);
    CHECK_NEAR(fx.range_m, 1000.0, 0.5);   /* 500 m rise at 30 deg, curvature adds ~0.07 m */
    CHECK_NEAR(fx.height_m, 600.0, 1e-6);
}

TEST(gis_near_horizontal_rays)
{
    /* Station 100 m above a light surface at 0 m: the geometric horizon dips by about
     * sqrt(2 h / R) = 0.32 deg. */
    gis_camera cam = gisfx_base_camera();
    cam.sigma_pitch_deg = 0.02;
    cam.sigma_heading_deg = 0.02;
    gis_fix fx;
    const double above[] = {10.0, 0.0, -0.1, -0.3};
    for (size_t i = 0; i < sizeof above / sizeof *above; i++) {
        cam.pitch_deg = above[i];
        CHECK_OK(gis_locate(&cam, cam.cx_px, cam.cy_px, 0.5, 0.0, NULL, &fx));
        CHECK_MSG(fx.flags == GIS_FIX_ABOVE_HORIZON, "pitch %g: flags %#x", above[i], fx.flags);
        CHECK(isnan(fx.lat_deg) && isnan(fx.lon_deg) && isnan(fx.height_m));
    }
    /* just below the horizon: a point exists but a 1-sigma pitch error loses it */
    cam.pitch_deg = -0.33;
    CHECK_OK(gis_locate(&cam, cam.cx_px, cam.cy_px, 0.5, 0.0, NULL, &fx));
    CHECK_MSG(fx.flags == GIS_FIX_GRAZING, "flags %#x", fx.flags);
    CHECK(isnan(fx.lat_deg) && isnan(fx.range_m));
    CHECK(isfinite(fx.bearing_deg));
    /* the same ray without uncertainty is located, exactly: Newton at a near-double root */
    gis_camera exact = cam;
    exact.sigma_pitch_deg = exact.sigma_heading_deg = 0.0;
    CHECK_OK(gis_locate(&exact, exact.cx_px, exact.cy_px, 0.0, 0.0, NULL, &fx));
    CHECK(fx.flags == 0);
    CHECK(fx.range_m > 25000.0 && fx.range_m < 40000.0);
    double x, y;
    int front;
    CHECK_OK(gis_project(&exact, fx.lat_deg, fx.lon_deg, 0.0, &x, &y, &front));
    CHECK_NEAR(hypot(x - exact.cx_px, y - exact.cy_px), 0.0, 1e-5);
    CHECK_NEAR(fx.height_m, 0.0, 1e-6);
    /* ellipses grow as the ray flattens, and are bounded well below the horizon */
    double prev = 0.0;
    const double pitches[] = {-30.0, -10.0, -5.0, -2.0};
    for (size_t i = 0; i < 4; i++) {
        cam.pitch_deg = pitches[i];
        CHECK_OK(gis_locate(&cam, cam.cx_px, cam.cy_px, 0.5, 0.0, NULL, &fx));
        CHECK_MSG(fx.flags == 0, "pitch %g: flags %#x", pitches[i], fx.flags);
        CHECK(fx.ellipse.semi_major_m > prev);
        CHECK(fx.ellipse.semi_major_m < 0.25 * fx.range_m);
        prev = fx.ellipse.semi_major_m;
    }
    /* along the line of sight at pitch -2 deg: d(distance)/d(elevation) ~ H / sin^2(2 deg), for
     * the pitch sigma and the y pixel sigma (0.5 px / f rad); curvature adds ~2.5 % */
    CHECK_NEAR(fabs(gs_wrap180(2.0 * fx.ellipse.azimuth_deg)) / 2.0, 0.0, 0.5);
    double sig_e = hypot(0.02 * D2R, 0.5 / cam.focal_px);
    double expect = 100.0 / (sin(2.0 * D2R) * sin(2.0 * D2R)) * sig_e;
    CHECK_NEAR(fx.ellipse.semi_major_m / expect, 1.0, 0.05);
}

TEST(gis_refraction_standard_coefficient)
{
    /* Over a horizontal sight line the surface drops by (1 - k) d^2 / (2 R): a light 10 m above
     * the station's height is met at d = sqrt(2 R 10 / (1 - k)), 1/sqrt(1 - k) = 1.0721 times
     * farther than with straight lines. */
    gis_camera cam = gisfx_base_camera();
    cam.pitch_deg = 0.0;
    gis_fix straight, bent;
    CHECK_OK(gis_locate(&cam, cam.cx_px, cam.cy_px, 0.0, 110.0, NULL, &straight));
    cam.refraction_k = GIS_REFRACTION_K_STANDARD;
    CHECK_OK(gis_locate(&cam, cam.cx_px, cam.cy_px, 0.0, 110.0, NULL, &bent));
    CHECK(straight.flags == 0 && bent.flags == 0);
    CHECK_NEAR(straight.distance_m, sqrt(2.0 * GIS_EARTH_RADIUS_M * 10.0), 0.005 * straight.distance_m);
    CHECK_NEAR(bent.distance_m / straight.distance_m, 1.0 / sqrt(1.0 - 0.13), 2e-3);
    /* A light at the station's height 10 km away appears depressed by (1 - k) d / (2 R)
     * (the textbook curvature-and-refraction correction), instead of d / (2 R). */
    double lat, lon, el;
    CHECK(gis_gl_direct(cam.lat_deg, cam.lon_deg, 60.0, 10000.0, &lat, &lon, NULL) == 0);
    for (int k = 0; k < 2; k++) {
        cam.refraction_k = k ? 0.13 : 0.0;
        cam.heading_deg = 60.0;
        double x, y;
        int front;
        CHECK_OK(gis_project(&cam, lat, lon, cam.height_m, &x, &y, &front));
        CHECK_OK(gis_pixel_bearing(&cam, x, y, NULL, &el));
        double expect = -(1.0 - cam.refraction_k) * 10000.0 / (2.0 * GIS_EARTH_RADIUS_M) / D2R;
        CHECK_NEAR(el / expect, 1.0, 0.005);
    }
}

TEST(gis_distortion_image_corners)
{
    gis_camera cam = gisfx_base_camera();
    cam.width_px = 4000;
    cam.height_px = 3000;
    cam.cx_px = 1999.5;
    cam.cy_px = 1499.5;
    cam.k1 = -0.25;
    cam.k2 = 0.05;
    CHECK(isinf(gis_distortion_limit(&cam)));   /* 1 - 0.75 t + 0.25 t^2 has no real root */
    /* corners, edge midpoints and a grid: undistort then distort gives the pixel back, and
     * agrees with an independent bisection on the radius */
    for (int i = 0; i <= 10; i++)
        for (int j = 0; j <= 10; j++) {
            double x = -0.5 + i * 4000.0 / 10, y = -0.5 + j * 3000.0 / 10, xn, yn, bx, by;
            CHECK_OK(gis_undistort(&cam, x, y, &xn, &yn));
            CHECK_OK(gis_distort(&cam, xn, yn, &bx, &by));
            CHECK_NEAR(hypot(bx - x, by - y), 0.0, 1e-9);
            double xd = (x - cam.cx_px) / cam.focal_px, yd = (y - cam.cy_px) / cam.focal_px;
            double rd = hypot(xd, yd), lo = 0.0, hi = 4.0;
            for (int it = 0; it < 200; it++) {
                double m = 0.5 * (lo + hi);
                if (m * (1.0 + cam.k1 * m * m + cam.k2 * m * m * m * m) < rd) lo = m;
                else hi = m;
            }
            CHECK_NEAR(hypot(xn, yn), 0.5 * (lo + hi), 1e-13);
        }
    /* strong barrel distortion folds over inside the image: r_max = 1/sqrt(1.2) */
    cam.k1 = -0.4;
    cam.k2 = 0.0;
    double rmax = gis_distortion_limit(&cam);
    CHECK_NEAR(rmax, 1.0 / sqrt(1.2), 1e-15);
    double xn, yn, x, y;
    CHECK(gis_undistort(&cam, -0.5, -0.5, &xn, &yn) == GS_ELIMIT);   /* corner: no preimage */
    gis_fix fx;
    cam.pitch_deg = -20.0;
    CHECK_OK(gis_locate(&cam, -0.5, -0.5, 1.0, 0.0, NULL, &fx));
    CHECK(fx.flags == GIS_FIX_BAD_PIXEL && isnan(fx.lat_deg));
    /* just inside the fold the safeguarded Newton still converges */
    double rd = 0.999 * rmax * (1.0 - 0.4 * rmax * rmax);
    CHECK_OK(gis_undistort(&cam, cam.cx_px + rd * cam.focal_px, cam.cy_px, &xn, &yn));
    CHECK(xn < rmax && xn > 0.9 * rmax);
    CHECK_OK(gis_distort(&cam, xn, yn, &x, &y));
    CHECK_NEAR(x, cam.cx_px + rd * cam.focal_px, 1e-6);
    /* a point beyond r_max is not projected (no fold-back into the image) */
    CHECK(gis_distort(&cam, 1.2 * rmax, 0.0, &x, &y) == GS_ELIMIT);
    double lat, lon;
    cam.heading_deg = 0.0;
    cam.pitch_deg = 0.0;
    CHECK(gis_gl_direct(cam.lat_deg, cam.lon_deg, 60.0, 1000.0, &lat, &lon, NULL) == 0);   /* 60 deg off axis */
    int front = 1;
    CHECK_OK(gis_project(&cam, lat, lon, cam.height_m, &x, &y, &front));
    CHECK(front == 0 && isnan(x));
}

TEST(gis_rejects_nan_inf)
{
    const double bad[] = {NAN, INFINITY, -INFINITY};
    size_t offs[] = {offsetof(gis_camera, lat_deg), offsetof(gis_camera, lon_deg),
                     offsetof(gis_camera, height_m), offsetof(gis_camera, heading_deg),
                     offsetof(gis_camera, pitch_deg), offsetof(gis_camera, roll_deg),
                     offsetof(gis_camera, sigma_heading_deg), offsetof(gis_camera, sigma_pitch_deg),
                     offsetof(gis_camera, sigma_roll_deg), offsetof(gis_camera, focal_px),
                     offsetof(gis_camera, cx_px), offsetof(gis_camera, cy_px),
                     offsetof(gis_camera, k1), offsetof(gis_camera, k2),
                     offsetof(gis_camera, refraction_k)};
    gis_fix fx;
    double x, y;
    int front;
    for (size_t i = 0; i < sizeof offs / sizeof *offs; i++)
        for (size_t b = 0; b < 3; b++) {
            gis_camera cam = gisfx_base_camera();
            cam.pitch_deg = -10.0;
            memcpy((char *)&cam + offs[i], &bad[b], sizeof(double));
            CHECK(gis_camera_check(&cam) == GS_ENUMERIC);
            CHECK(gis_locate(&cam, 100, 100, 1, 0, NULL, &fx) == GS_ENUMERIC);
            CHECK(isnan(fx.lat_deg) && isnan(fx.lon_deg));
            CHECK(gis_project(&cam, 45.01, 7.0, 0.0, &x, &y, &front) == GS_ENUMERIC);
            CHECK(isnan(x) && front == 0);
        }
    gis_camera cam = gisfx_base_camera();
    cam.pitch_deg = -10.0;
    for (size_t b = 0; b < 3; b++) {
        CHECK(gis_locate(&cam, bad[b], 100, 1, 0, NULL, &fx) == GS_ENUMERIC);
        CHECK(gis_locate(&cam, 100, bad[b], 1, 0, NULL, &fx) == GS_ENUMERIC);
        CHECK(gis_locate(&cam, 100, 100, bad[b], 0, NULL, &fx) == GS_ENUMERIC);
        CHECK(gis_locate(&cam, 100, 100, 1, bad[b], NULL, &fx) == GS_ENUMERIC);
        CHECK(gis_project(&cam, bad[b], 7, 0, &x, &y, &front) == GS_ENUMERIC);
        CHECK(gis_project(&cam, 45, 7, bad[b], &x, &y, &front) == GS_ENUMERIC);
        double xn, yn;
        CHECK(gis_undistort(&cam, bad[b], 0, &xn, &yn) == GS_ENUMERIC);
        gis_bearing a = {45, 7, 10, 0.1}, c = {45, 7.01, 350, 0.1};
        gis_intersection it;
        a.azimuth_deg = bad[b];
        CHECK(gis_triangulate(&a, &c, NULL, &it) == GS_ENUMERIC);
        CHECK(isnan(it.lat_deg));
        a.azimuth_deg = 10;
        c.lat_deg = bad[b];
        CHECK(gis_triangulate(&a, &c, NULL, &it) == GS_ENUMERIC);
    }
    /* finite but out of range */
    cam.lat_deg = 90.5;
    CHECK(gis_camera_check(&cam) == GS_EINVAL);
    cam = gisfx_base_camera();
    cam.pitch_deg = 91.0;
    CHECK(gis_camera_check(&cam) == GS_EINVAL);
    cam = gisfx_base_camera();
    cam.focal_px = 0.0;
    CHECK(gis_camera_check(&cam) == GS_EINVAL);
    cam = gisfx_base_camera();
    CHECK(gis_locate(&cam, 100, 100, -1.0, 0, NULL, &fx) == GS_EINVAL);
    CHECK(gis_locate(&cam, 100, 100, 1.0, 2e5, NULL, &fx) == GS_EINVAL);
    CHECK(gis_project(&cam, 95.0, 7, 0, &x, &y, &front) == GS_EINVAL);
    gis_bearing a = {45, 7, 10, 0.1};
    gis_intersection it;
    CHECK(gis_triangulate(&a, &a, NULL, &it) == GS_EINVAL);   /* same station */
}

TEST(gis_locate_ellipse_nadir_analytic)
{
    /* Looking straight down from 1000 m with f = 1000 px: 1 px is 1 m on the ground in each
     * axis; a pitch error moves the point along the heading by H sigma, a roll error across
     * it; a heading error does not move the centre pixel. */
    gis_camera cam = gisfx_base_camera();
    cam.height_m = 1000.0;
    cam.focal_px = 1000.0;
    cam.pitch_deg = -90.0;
    cam.heading_deg = 30.0;
    gis_fix fx;
    CHECK_OK(gis_locate(&cam, cam.cx_px, cam.cy_px, 1.0, 0.0, NULL, &fx));
    CHECK_NEAR(fx.ellipse.semi_major_m, 1.0, 2e-3);
    CHECK_NEAR(fx.ellipse.semi_minor_m, 1.0, 2e-3);
    cam.sigma_pitch_deg = 0.1;
    CHECK_OK(gis_locate(&cam, cam.cx_px, cam.cy_px, 0.0, 0.0, NULL, &fx));
    CHECK_NEAR(fx.ellipse.semi_major_m, 1000.0 * 0.1 * D2R, 2e-3);
    CHECK_NEAR(fx.ellipse.semi_minor_m, 0.0, 1e-6);
    CHECK_NEAR(fx.ellipse.azimuth_deg, 30.0, 1e-3);
    /* roll and heading both turn the image about the optical axis here (gimbal lock): the
     * centre does not move, a pixel 500 px right (500 m at azimuth 120) moves tangentially */
    cam.sigma_pitch_deg = 0.0;
    for (int k = 0; k < 2; k++) {
        cam.sigma_roll_deg = k ? 0.0 : 0.1;
        cam.sigma_heading_deg = k ? 0.1 : 0.0;
        CHECK_OK(gis_locate(&cam, cam.cx_px, cam.cy_px, 0.0, 0.0, NULL, &fx));
        CHECK_NEAR(fx.ellipse.semi_major_m, 0.0, 1e-6);
        CHECK_OK(gis_locate(&cam, cam.cx_px + 500.0, cam.cy_px, 0.0, 0.0, NULL, &fx));
        CHECK_NEAR(fx.bearing_deg, 120.0, 1e-6);
        CHECK_NEAR(fx.ellipse.semi_major_m, 500.0 * 0.1 * D2R, 2e-3);
        CHECK_NEAR(fx.ellipse.semi_minor_m, 0.0, 1e-6);
        CHECK_NEAR(fx.ellipse.azimuth_deg, 30.0, 0.01);   /* + meridian convergence 0.004 deg */
    }
    cam.sigma_roll_deg = cam.sigma_heading_deg = 0.0;
    /* max_error_ratio flags a too-large ellipse */
    cam.sigma_heading_deg = 0.0;
    gis_locate_opts o;
    gis_locate_opts_default(&o);
    o.max_error_ratio = 0.5 / 1000.0;
    CHECK_OK(gis_locate(&cam, cam.cx_px, cam.cy_px, 1.0, 0.0, &o, &fx));
    CHECK(fx.flags == GIS_FIX_GRAZING && isnan(fx.lat_deg));
    CHECK_NEAR(fx.ellipse.semi_major_m, 1.0, 2e-3);
}

TEST(gis_locate_ellipse_height_prior_analytic)
{
    /* 100 m above flat ground (the Earth's curvature drops it 0.08 m at 1 km), the centre
     * pixel at a depression of atan(0.1): the light is 1000 m away, and a height error dh
     * moves it along the sight line's azimuth by dh / tan(e) = 10 dh (to 1 %); across it,
     * nothing. */
    gis_camera cam = gisfx_base_camera();
    cam.height_m = 100.0;
    cam.focal_px = 1000.0;
    cam.heading_deg = 70.0;
    cam.pitch_deg = -atan(0.1) / D2R;
    gis_locate_opts o;
    gis_locate_opts_default(&o);
    o.sigma_height_m = 0.5;
    gis_fix fx;
    CHECK_OK(gis_locate(&cam, cam.cx_px, cam.cy_px, 0.0, 0.0, &o, &fx));
    CHECK_NEAR(fx.distance_m, 1000.0, 2.0);
    CHECK_NEAR(fx.ellipse.semi_major_m, 0.5 * 10.0, 0.05);
    CHECK_NEAR(fx.ellipse.semi_minor_m, 0.0, 1e-6);
    CHECK_NEAR(fx.ellipse.azimuth_deg, 70.0, 0.01);
    gis_fix f0;
    CHECK_OK(gis_locate(&cam, cam.cx_px, cam.cy_px, 0.0, 0.0, NULL, &f0));
    CHECK_NEAR(f0.ellipse.semi_major_m, 0.0, 1e-6);   /* no height prior, no sigma: a point */
    o.sigma_height_m = -1.0;
    CHECK(gis_locate(&cam, cam.cx_px, cam.cy_px, 0.0, 0.0, &o, &fx) == GS_EINVAL);
}

TEST(gis_locate_ellipse_pixel_covariance_monte_carlo)
{
    /* A correlated, unequal pixel covariance (a deblended light's, gis_locate_opts.pixel_cov_px2)
     * on a grazing sight line (200 m up, 5 km away: one pixel of y is ~30 m along the line): the
     * ellipse's covariance against the Monte-Carlo oracle of the forward model itself, 20,000
     * pixels drawn from N(0, sigma_px^2 I + C) and each located; the share inside the 95 %
     * ellipse is 95 %. Without the cross term, or with sigma_px alone, it is far off. */
    gis_camera cam = gisfx_base_camera();
    cam.height_m = 200.0;
    cam.focal_px = 4000.0;
    cam.heading_deg = 30.0;
    cam.pitch_deg = -atan(170.0 / 5000.0) / D2R;
    gis_locate_opts o;
    gis_locate_opts_default(&o);
    const double sp = 0.02, cxx = 0.09, cxy = -0.05, cyy = 0.04;   /* px, px^2 */
    o.pixel_cov_px2[0] = cxx, o.pixel_cov_px2[1] = cxy, o.pixel_cov_px2[2] = cyy;
    const double x0 = cam.cx_px + 150.0, y0 = cam.cy_px + 20.0;
    gis_fix fx;
    CHECK_OK(gis_locate(&cam, x0, y0, sp, 29.0, &o, &fx));
    CHECK(isfinite(fx.lat_deg) && fx.ellipse.semi_major_m > 5.0);
    /* the oracle: draws by the Cholesky factor of the total covariance */
    const double a = sp * sp + cxx, b = cxy, c = sp * sp + cyy;
    const double l11 = sqrt(a), l21 = b / l11, l22 = sqrt(c - l21 * l21);
    gs_rng r;
    gs_rng_init(&r, 7, 0, 0, 1);
    const int n = 20000;
    double see = 0, sen = 0, snn = 0;
    double *en = malloc(sizeof(double) * 2 * n);
    for (int i = 0; i < n; i++) {
        double z1 = gs_rng_normal(&r), z2 = gs_rng_normal(&r);
        gis_fix f;
        CHECK_OK(gis_locate(&cam, x0 + l11 * z1, y0 + l21 * z1 + l22 * z2, 0.0, 29.0, NULL, &f));
        double d, azi;
        CHECK_OK(gis_geodesic_inverse(fx.lat_deg, fx.lon_deg, f.lat_deg, f.lon_deg, &d, &azi, NULL));
        en[2 * i] = d * sin(azi * D2R);
        en[2 * i + 1] = d * cos(azi * D2R);
        see += en[2 * i] * en[2 * i], sen += en[2 * i] * en[2 * i + 1], snn += en[2 * i + 1] * en[2 * i + 1];
    }
    gis_ellipse mc = gis_ellipse_from_cov(see / n, sen / n, snn / n);
    CHECK_NEAR(fx.ellipse.semi_major_m, mc.semi_major_m, 0.03 * mc.semi_major_m);
    CHECK_NEAR(fx.ellipse.semi_minor_m, mc.semi_minor_m, 0.03 * mc.semi_minor_m);
    CHECK_NEAR(fx.ellipse.azimuth_deg, mc.azimuth_deg, 1.0);
    /* the share inside the stored 95 % ellipse (first order: the line is straight over +-3 sigma) */
    const double t = fx.ellipse.azimuth_deg * D2R, A = fx.ellipse.semi_major_m, B = fx.ellipse.semi_minor_m;
    int in = 0;
    for (int i = 0; i < n; i++) {
        double u = en[2 * i] * sin(t) + en[2 * i + 1] * cos(t), v = en[2 * i] * cos(t) - en[2 * i + 1] * sin(t);
        in += (u * u) / (A * A) + (v * v) / (B * B) <= -2.0 * log(0.05);
    }
    free(en);
    CHECK_MSG(fabs((double)in / n - 0.95) < 0.01, "%d of %d inside the 95 %% ellipse", in, n);
    /* not positive semi-definite: refused */
    o.pixel_cov_px2[1] = 0.07;
    CHECK(gis_locate(&cam, x0, y0, sp, 29.0, &o, &fx) == GS_EINVAL);
}

/* -------------------------------------------------------------- station files */

TEST(gis_station_parse_errors_name_line_and_field)
{
    gis_station st;
    const char *good = "{\n \"format\": \"gridsurvey-station/1\",\n \"lat\": 45, \"lon\": 7,\n"
                       " \"height\": 100, \"heading\": 10, \"pitch\": -5, \"roll\": 0,\n"
                       " \"focal_px\": 2000, \"cx\": 959.5, \"cy\": 539.5, \"k1\": -0.1, \"k2\": 0.01,\n"
                       " \"sigma_px\": 0.7, \"sigma_heading_deg\": 0.05, \"time_utc\": \"2024-05-01T21:00:00Z\"\n}\n";
    CHECK_OK(gis_station_parse(good, "st.json", &st));
    CHECK_NEAR(st.cam.lat_deg, 45.0, 0);
    CHECK_NEAR(st.cam.k1, -0.1, 0);
    CHECK_NEAR(st.sigma_px, 0.7, 0);
    CHECK_NEAR(st.cam.sigma_heading_deg, 0.05, 0);
    CHECK(!strcmp(st.time_utc, "2024-05-01T21:00:00Z"));
    CHECK(isnan(st.psf_sigma_px));
    /* sigma_px defaults to 1 px without a PSF, to 0 (a perfect calibration) with one */
    const char *psf = "{\"lat\": 45, \"lon\": 7, \"height\": 100, \"heading\": 10, \"pitch\": -5,\n"
                      " \"focal_px\": 2000, \"cx\": 959.5, \"cy\": 539.5, \"psf_sigma_px\": 0.8}";
    CHECK_OK(gis_station_parse(psf, "st.json", &st));
    CHECK_NEAR(st.psf_sigma_px, 0.8, 0);
    CHECK_NEAR(st.sigma_px, 0.0, 0);
    char nopsf[400];
    snprintf(nopsf, sizeof nopsf, "%.*s}", (int)(strstr(psf, ", \"psf") - psf), psf);
    CHECK_OK(gis_station_parse(nopsf, "st.json", &st));
    CHECK(isnan(st.psf_sigma_px) && st.sigma_px == 1.0);
    const char *offset = "{\"lat\": 45, \"lon\": 7, \"height\": 100, \"heading\": 10, \"pitch\": -5, \"focal_px\": 2000,"
                         " \"cx\": 1, \"cy\": 1, \"time_utc\": \"2024-05-01T23:00:00.5+02:00\"}";
    CHECK_OK(gis_station_parse(offset, "st.json", &st));
    const struct {
        const char *text, *expect;
        gs_status s;
    } bad[] = {
        {"{\n \"lat_deg\": 45,\n \"lon_deg\": 7,\n \"height_m\": 1, \"heading_deg\": 0,\n \"pitch_deg\": 95,\n"
         " \"focal_px\": 1, \"cx_px\": 0, \"cy_px\": 0}", "s.json:5: field pitch_deg: pitch_deg = 95", GS_EFORMAT},
        {"{\n \"lat_deg\": 45,\n \"lon_deg\": 7,\n \"heigth_m\": 1}", "s.json:4: field heigth_m: unknown field", GS_EFORMAT},
        {"{\n \"lat_deg\": 45,\n \"lon_deg\": \"7\"}", "s.json:3: field lon_deg: expected a number", GS_EFORMAT},
        {"{\n \"lat_deg\": 45, \"lat\": 46}", "s.json:2: field lat: lat_deg given twice", GS_EFORMAT},
        {"{\n \"lat_deg\": 45,\n \"lon_deg\": 7}", "s.json:1: field height_m: expected a number (the field is missing", GS_EFORMAT},
        {"{\n \"lat_deg\": 45,\n \"lon_deg\": 7,,}", "s.json:3:", GS_EFORMAT},
        {"{\"format\": \"gridsurvey-station/2\"}", "s.json:1: field format", GS_EFORMAT},
        {"[1, 2]", "s.json:1: expected a JSON object", GS_EFORMAT},
        {"{\"lat\": 45, \"lon\": 7, \"height\": 100, \"heading\": 10, \"pitch\": -5,\n \"focal_px\": 2000, "
         "\"cx\": 1, \"cy\": 1,\n \"psf_sigma_px\": -1}", "s.json:3: field psf_sigma_px: expected a value from 0 to 50", GS_EFORMAT},
        /* the acquisition time is copied to every light: not ISO 8601 is an error, as in a capture */
        {"{\"lat\": 45, \"lon\": 7, \"height\": 100, \"heading\": 10, \"pitch\": -5,\n \"focal_px\": 2000, "
         "\"cx\": 1, \"cy\": 1,\n \"time_utc\": \"yesterday\"}", "s.json:3: field time_utc: expected an ISO 8601 time", GS_EFORMAT},
        {"{\"lat\": 45, \"lon\": 7, \"height\": 100, \"heading\": 10, \"pitch\": -5,\n \"focal_px\": 2000, "
         "\"cx\": 1, \"cy\": 1,\n \"time_utc\": \"2024-05-01 21:00\"}", "s.json:3: field time_utc: expected an ISO 8601 time", GS_EFORMAT},
        /* the id too is copied to every light, whose exports refused a control character */
        {"{\"lat\": 45, \"lon\": 7, \"height\": 100, \"heading\": 10, \"pitch\": -5,\n \"focal_px\": 2000, "
         "\"cx\": 1, \"cy\": 1,\n \"id\": \"a\\nb\"}", "s.json:3: field id: expected text without control characters", GS_EFORMAT},
    };
    for (size_t i = 0; i < sizeof bad / sizeof *bad; i++) {
        gs_status s = gis_station_parse(bad[i].text, "s.json", &st);
        CHECK_MSG(s == bad[i].s && strstr(gs_detail(), bad[i].expect), "case %zu: %s: %s (expected '%s')",
                  i, gs_strerror(s), gs_detail(), bad[i].expect);
    }
    CHECK(gis_station_read("/nonexistent/station.json", &st) == GS_ENOTFOUND);
    CHECK(strstr(gs_detail(), "/nonexistent/station.json") != NULL);
}
