/* test_two_stations_sigma.c - srv_triangulate_sites (survey/sites_triangulate.c) on a database
 * written by hand: the pixels' bearings through a distorting lens, the bearing sigmas (the
 * one-station ellipse across the sight line at the light, over its distance) and the choice of
 * two different stations. Oracles: GeodSolve (GeographicLib's program) places the stations from
 * the light and gives the sight lines' azimuths at both ends and their lengths; the pixel of a
 * bearing from the Brown model written here (a level camera: azimuth = heading + atan(xn)); the
 * variance across the sight line u^T C u with C the ellipse's covariance (tests/gis_fixture.c). */
#include "survey/survey.h"
#include "tests/fixtures.h"
#include "tests/gis_fixture.h"
#include "tests/survey_fixture.h"
#include "tests/test.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The light P at 75 deg north (meridians converge: a 20 km sight line turns by 0.6 deg) seen
 * from station "sw" 20 km away (azimuth 250 deg from P) on two nights and from "se" 15 km away
 * (130 deg), 20 deg right of each camera's axis through a lens of k1 = -0.15 (the undistorted
 * pixel is 0.3 deg off). The stored one-station ellipses: 100 x 2 m along sw's sight line, and
 * 40 x 3 m at 30 deg to se's. Expected: one site from sw's first night and se (not sw's two
 * nights), intersected at P (1 mm), each sigma sqrt(u^T C u) / s12 with u across the sight line
 * at P. */
TEST(two_stations_bearing_sigma_distortion_stations)
{
    const double P[2] = {75.0, 20.0}, alpha[2] = {250.0, 130.0}, dist[2] = {20000.0, 15000.0};
    const double xn = tan(20.0 * D2R), yn = 0.05, k1 = -0.15, f = 1000.0, cx = 960.0, cy = 540.0;
    gisfx_sbuf in = {0};
    for (int k = 0; k < 2; k++) gisfx_sb_printf(&in, "%.15g %.15g %.15g %.15g\n", P[0], P[1], alpha[k], dist[k]);
    char *out = gisfx_run_tool("GeodSolve -p 9", &in), *q = out;
    free(in.s);
    if (!out) return;
    double st[2][3];   /* station lat, lon, azimuth toward P */
    for (int k = 0; k < 2; k++) {
        st[k][0] = gisfx_next_num(&q);
        st[k][1] = gisfx_next_num(&q);
        st[k][2] = gisfx_next_num(&q) + 180.0;
    }
    free(out);
    int64_t sid;
    srv_db *db = survey_fx_create(fx_tmp("tri.sqlite"), "t", &sid);
    if (!db) return;
    const gis_ellipse e[2] = {{100.0, 2.0, fmod(alpha[0] + 180.0, 180.0)},
                              {40.0, 3.0, fmod(alpha[1] + 180.0 + 30.0, 180.0)}};
    /* "sw-july": sw's roof stored again under another name (the same position): not a second
     * station (a pair of them has no baseline to triangulate) */
    static const char *const names[3] = {"sw", "se", "sw-july"};
    static const int place[3] = {0, 1, 0};
    int64_t stid[3], cid[3], light[3];
    for (int k = 0; k < 3; k++) {
        srv_station_row r;
        srv_station_row_init(&r);
        r.survey_id = sid;
        r.name = names[k];
        gis_camera *c = &r.cam;
        c->lat_deg = st[place[k]][0];
        c->lon_deg = st[place[k]][1];
        c->height_m = 50.0;
        c->heading_deg = st[place[k]][2] - 20.0;
        c->pitch_deg = c->roll_deg = 0.0;
        c->sigma_heading_deg = c->sigma_pitch_deg = c->sigma_roll_deg = 0.0;
        c->focal_px = f;
        c->cx_px = cx;
        c->cy_px = cy;
        c->k1 = k1;
        c->k2 = c->refraction_k = 0.0;
        r.sigma_px = 0.5;
        CHECK_OK(srv_db_add_station(db, &r, &stid[k]));
    }
    /* captures in id order: sw, sw-july (another night from sw's roof), se */
    static const int station_of[3] = {0, 2, 1};
    double s = 1.0 + k1 * (xn * xn + yn * yn);
    for (int c = 0; c < 3; c++) {
        int k = place[station_of[c]];
        srv_light_row l = survey_fx_light(0, cx + f * xn * s, cy + f * yn * s, 0.0, 0.9);
        srv_location_row loc;
        srv_location_row_init(&loc);
        loc.method = SRV_LOC_ONE_STATION;
        loc.lat_deg = P[0];
        loc.lon_deg = P[1];
        loc.height_m = 0.0;
        loc.ellipse = e[k];
        loc.range_m = dist[k];
        char key[16];
        snprintf(key, sizeof key, "c%d", c);
        srv_capture_data cd = survey_fx_capture(sid, key, &l, &loc, 1);
        cd.capture.station_id = stid[station_of[c]];
        CHECK_OK(srv_db_add_capture(db, &cd, &cid[c], NULL));
        char sql[96];
        snprintf(sql, sizeof sql, "SELECT id FROM lights WHERE capture_id = %lld", (long long)cid[c]);
        light[c] = survey_fx_query_long(srv_db_sqlite(db), sql);
    }
    CHECK(survey_fx_query_long(srv_db_sqlite(db), "SELECT count(*) FROM light_sites WHERE detections = 3") == 1);
    srv_tri_site *t = NULL;
    size_t n = 0;
    CHECK_OK(srv_triangulate_sites(db, cid, 3, &t, &n));
    CHECK_MSG(n == 1, "%zu sites", n);
    if (n == 1) {
        CHECK_MSG(t->light_id[0] == light[0] && t->light_id[1] == light[2] && !strcmp(t->station[0], "sw") &&
                      !strcmp(t->station[1], "se"),
                  "lights %lld (%s) and %lld (%s), expected %lld (sw) and %lld (se)", (long long)t->light_id[0],
                  t->station[0], (long long)t->light_id[1], t->station[1], (long long)light[0], (long long)light[2]);
        CHECK_MSG(t->fix.flags == 0 && gisfx_err_m(t->fix.lat_deg, t->fix.lon_deg, P[0], P[1]) < 1e-3,
                  "flags %#x, %.3f m from the light", t->fix.flags,
                  gisfx_err_m(t->fix.lat_deg, t->fix.lon_deg, P[0], P[1]));
        for (int k = 0; k < 2; k++) {
            double C[3], beta = (alpha[k] + 180.0 + 90.0) * D2R, u[2] = {sin(beta), cos(beta)};
            gisfx_ellipse_cov(&e[k], C);
            double var = C[0] * u[0] * u[0] + 2.0 * C[1] * u[0] * u[1] + C[2] * u[1] * u[1];
            double want = sqrt(var) / dist[k] / D2R;
            CHECK_MSG(fabs(t->sigma_bearing_deg[k] / want - 1.0) < 1e-6, "%s: bearing sigma %.9g deg, expected %.9g",
                      names[k], t->sigma_bearing_deg[k], want);
        }
    }
    free(t);
    /* a site that cannot be intersected (light Q seen from sw and from a station 9,500 km
     * away, which gis_triangulate refuses) is kept with its reason; the others are not lost */
    srv_station_row far;
    srv_station_row_init(&far);
    far.survey_id = sid;
    far.name = "far";
    far.cam = (gis_camera){.lat_deg = -10.0, .lon_deg = 100.0, .height_m = 50.0, .heading_deg = 0.0,
                           .focal_px = f, .cx_px = cx, .cy_px = cy};
    int64_t far_id, cq[2];
    CHECK_OK(srv_db_add_station(db, &far, &far_id));
    for (int c = 0; c < 2; c++) {
        srv_light_row l = survey_fx_light(0, cx, cy, 0.0, 0.9);
        srv_location_row loc;
        srv_location_row_init(&loc);
        loc.method = SRV_LOC_ONE_STATION;
        loc.lat_deg = P[0] + 0.05;
        loc.lon_deg = P[1];
        loc.height_m = 0.0;
        loc.ellipse = e[0];
        loc.range_m = 20000.0;
        char key[16];
        snprintf(key, sizeof key, "q%d", c);
        srv_capture_data cd = survey_fx_capture(sid, key, &l, &loc, 1);
        cd.capture.station_id = c ? far_id : stid[0];
        CHECK_OK(srv_db_add_capture(db, &cd, &cq[c], NULL));
    }
    int64_t all[5] = {cid[0], cid[1], cid[2], cq[0], cq[1]};
    CHECK_OK(srv_triangulate_sites(db, all, 5, &t, &n));
    int fixed = 0, refused = 0;
    for (size_t i = 0; i < n; i++) {
        fixed += isfinite(t[i].fix.lat_deg) && !t[i].error[0];
        refused += !isfinite(t[i].fix.lat_deg) && strstr(t[i].error, "km apart") != NULL;
    }
    CHECK_MSG(n == 2 && fixed == 1 && refused == 1, "%zu sites, %d intersected, %d refused (%s)", n, fixed, refused,
              n == 2 ? t[1].error : "");
    free(t);
    srv_db_close(db);
}
