/* gis_fixture.c - what the gis/ tests share; the contract is in tests/gis_fixture.h. */
#include "tests/gis_fixture.h"

#include "tests/fixtures.h"
#include "tests/test.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static unsigned long long rng_state = 88172645463325252ull;

const gisfx_region gisfx_worldwide = {-80.0, 80.0, -180.0, 180.0},
                   gisfx_north_pole = {89.9, 90.0, -180.0, 180.0},
                   gisfx_south_pole = {-90.0, -89.9, -180.0, 180.0},
                   gisfx_am_east = {-60.0, 60.0, 179.9, 180.0},
                   gisfx_am_west = {-60.0, 60.0, -180.0, -179.9};

void gisfx_rng_seed(unsigned long long s)
{
    rng_state = s ? s : 1;
}

double gisfx_urand(double lo, double hi)
{
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    return lo + (hi - lo) * ((double)(rng_state >> 11) / 9007199254740992.0);
}

void gisfx_sb_printf(gisfx_sbuf *b, const char *fmt, ...)
{
    for (;;) {
        va_list ap;
        va_start(ap, fmt);
        int w = vsnprintf(b->s ? b->s + b->n : NULL, b->s ? b->cap - b->n : 0, fmt, ap);
        va_end(ap);
        if (w >= 0 && b->s && b->n + (size_t)w < b->cap) {
            b->n += (size_t)w;
            return;
        }
        size_t nc = b->cap ? b->cap * 2 : 4096;
        while (nc < b->n + (size_t)w + 1) nc *= 2;
        b->s = realloc(b->s, nc);
        b->cap = nc;
    }
}

char *gisfx_run_tool(const char *tool, const gisfx_sbuf *input)
{
    static int seq;
    char in[600], outp[600], cmd[2000], msg[2000];
    snprintf(in, sizeof in, "%s/tool_in_%d.txt", test_tmpdir(), seq);
    snprintf(outp, sizeof outp, "%s/tool_out_%d.txt", test_tmpdir(), seq);
    seq++;
    fx_write_file(in, input->s, input->n);
    snprintf(cmd, sizeof cmd, "%s < '%s' > '%s'", tool, in, outp);
    int rc = test_run(cmd, msg, sizeof msg);
    CHECK_MSG(rc == 0, "%s failed (%d): %s", tool, rc, msg);
    return rc == 0 ? fx_read_file(outp, NULL) : NULL;
}

double gisfx_next_num(char **p)
{
    char *end;
    double v = strtod(*p, &end);
    if (end == *p) return NAN;
    *p = end;
    return v;
}

double gisfx_err_m(double lat1, double lon1, double lat2, double lon2)
{
    double dlat = lat1 - lat2, dlon = lon1 - lon2;
    dlon -= 360.0 * floor(dlon / 360.0 + 0.5);
    return hypot(dlat * 111132.954, dlon * 111319.491 * cos(0.5 * (lat1 + lat2) * D2R));
}

void gisfx_enu_basis(double lat, double lon, double e[3], double n[3], double u[3])
{
    double sf = sin(lat * D2R), cf = cos(lat * D2R), sl = sin(lon * D2R), cl = cos(lon * D2R);
    e[0] = -sl, e[1] = cl, e[2] = 0.0;
    n[0] = -sf * cl, n[1] = -sf * sl, n[2] = cf;
    u[0] = cf * cl, u[1] = cf * sl, u[2] = sf;
}

/* Rotate v about a unit axis by angle (right-handed), Rodrigues. */
static void rotate(double v[3], const double ax[3], double ang)
{
    double c = cos(ang), s = sin(ang), d = ax[0] * v[0] + ax[1] * v[1] + ax[2] * v[2];
    double x[3] = {ax[1] * v[2] - ax[2] * v[1], ax[2] * v[0] - ax[0] * v[2], ax[0] * v[1] - ax[1] * v[0]};
    for (int i = 0; i < 3; i++) v[i] = v[i] * c + x[i] * s + ax[i] * d * (1.0 - c);
}

/* Camera axes by extrinsic rotations of the level, north-looking camera (right = E,
 * down = -U, forward = N): roll about N, then pitch about E (up positive), then heading
 * about U (clockwise from north = negative about U). */
static void test_axes(const gis_camera *c, double right[3], double down[3], double fwd[3])
{
    double r[3] = {1, 0, 0}, d[3] = {0, 0, -1}, f[3] = {0, 1, 0};
    const double E[3] = {1, 0, 0}, N[3] = {0, 1, 0}, U[3] = {0, 0, 1};
    double *v[3] = {r, d, f};
    for (int i = 0; i < 3; i++) {
        rotate(v[i], N, c->roll_deg * D2R);
        rotate(v[i], E, c->pitch_deg * D2R);
        rotate(v[i], U, -c->heading_deg * D2R);
    }
    memcpy(right, r, sizeof r);
    memcpy(down, d, sizeof d);
    memcpy(fwd, f, sizeof f);
}

int gisfx_project(const gis_camera *c, const double v[3], double *x, double *y)
{
    double r[3], d[3], f[3];
    test_axes(c, r, d, f);
    double X = r[0] * v[0] + r[1] * v[1] + r[2] * v[2];
    double Y = d[0] * v[0] + d[1] * v[1] + d[2] * v[2];
    double Z = f[0] * v[0] + f[1] * v[1] + f[2] * v[2];
    if (Z <= 0.0) return 0;
    double xn = X / Z, yn = Y / Z, r2 = xn * xn + yn * yn;
    if (1.0 + 3.0 * c->k1 * r2 + 5.0 * c->k2 * r2 * r2 < 0.2) return 0;
    double s = 1.0 + c->k1 * r2 + c->k2 * r2 * r2;
    *x = c->cx_px + c->focal_px * xn * s;
    *y = c->cy_px + c->focal_px * yn * s;
    return 1;
}

gis_camera gisfx_base_camera(void)
{
    gis_camera c;
    memset(&c, 0, sizeof c);
    c.lat_deg = 45.0;
    c.lon_deg = 7.0;
    c.height_m = 100.0;
    c.focal_px = 2000.0;
    c.cx_px = 959.5;
    c.cy_px = 539.5;
    c.width_px = 1920;
    c.height_px = 1080;
    return c;
}

void gisfx_ellipse_cov(const gis_ellipse *e, double c[3])
{
    double az = e->azimuth_deg * D2R, u[2] = {sin(az), cos(az)}, v[2] = {cos(az), -sin(az)};
    double a2 = e->semi_major_m * e->semi_major_m, b2 = e->semi_minor_m * e->semi_minor_m;
    c[0] = a2 * u[0] * u[0] + b2 * v[0] * v[0];
    c[1] = a2 * u[0] * u[1] + b2 * v[0] * v[1];
    c[2] = a2 * u[1] * u[1] + b2 * v[1] * v[1];
}
