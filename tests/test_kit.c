/* test_kit.c - the format kit of recognize/base (base.h): JSON positions, getters and the one
 * message shape, CSV (RFC 4180 through libcsv), atomic writes, paths, random numbers against
 * their published reference values, and the shared special functions against closed forms. */
#include "recognize/base/base.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <dirent.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* The parsed document of text (a test failure when it does not parse). */
static gs_json *doc_of(const char *text)
{
    gs_json *j = NULL;
    CHECK_OK(gs_json_parse(text, strlen(text), "t.json", &j));
    return j;
}

TEST(kit_json_lines_of_nested_members)
{
    const char *text = "{\n"
                       "  \"a\": 1,\n"
                       "  \"lights\": [\n"
                       "    {\"bulb\": \"x\"},\n"
                       "    {\"id\": 2,\n"
                       "     \"bulb\": \"y\"}\n"
                       "  ],\n"
                       "  \"esc\\\"aped\": {\"k\": [1,\n 2]}\n"
                       "}\n";
    gs_json *j = doc_of(text);
    if (!j) return;
    CHECK(gs_json_line(j, "a") == 2);
    CHECK(gs_json_line(j, "lights") == 3);
    CHECK(gs_json_line(j, "lights[0]") == 4 && gs_json_line(j, "lights[0].bulb") == 4);
    CHECK(gs_json_line(j, "lights[1]") == 5 && gs_json_line(j, "lights[1].bulb") == 6);
    /* an absent path: the nearest recorded ancestor's line */
    CHECK(gs_json_line(j, "lights[1].missing") == 5);
    CHECK(gs_json_line(j, "nothing.at.all") == 1);
    CHECK(gs_json_line(j, "esc\\\"aped.k[1]") == 9);
    gs_json_free(j);
}

TEST(kit_json_getters_one_message_shape)
{
    gs_json *j = doc_of("{\n \"n\": 5,\n \"s\": \"abc\",\n \"b\": 1,\n \"o\": {\"x\": 2.5}}\n");
    if (!j) return;
    json_t *root = gs_json_root(j);
    double d;
    long long i;
    char s[4];
    int b;
    CHECK(gs_json_get_num(j, root, "", "n", 1, 0, 0, 4, NULL, &d) == GS_EFORMAT);
    CHECK_MSG(!strcmp(gs_detail(), "t.json:2: field n: expected a number from 0 to 4 (got 5)"), "%s", gs_detail());
    CHECK(gs_json_get_int(j, root, "", "missing", 1, 0, 1, 9, NULL, &i) == GS_EFORMAT);
    CHECK_MSG(!strcmp(gs_detail(), "t.json:1: field missing: expected an integer from 1 to 9 (the "
                      "field is missing)"), "%s", gs_detail());
    CHECK_OK(gs_json_get_int(j, root, "", "missing", 0, 7, 1, 9, NULL, &i));
    CHECK(i == 7);
    CHECK(gs_json_get_str(j, root, "", "s", 1, NULL, s, sizeof s) == GS_OK && !strcmp(s, "abc"));
    CHECK(gs_json_get_str(j, root, "", "s", 1, NULL, s, 3) == GS_EFORMAT);
    CHECK(strstr(gs_detail(), "t.json:3: field s: expected a string of at most 2 characters"));
    CHECK(gs_json_get_bool(j, root, "", "b", 1, 0, &b) == GS_EFORMAT);
    CHECK(strstr(gs_detail(), "t.json:4: field b: expected true or false"));
    json_t *o;
    CHECK_OK(gs_json_get_obj(j, root, "", "o", 1, &o));
    CHECK(gs_json_get_num(j, o, "o", "x", 1, 0, 0, 1, "a fraction", &d) == GS_EFORMAT);
    CHECK_MSG(strstr(gs_detail(), "t.json:5: field o.x: expected a fraction (got 2.5)"), "%s", gs_detail());
    gs_json_free(j);
}

TEST(kit_json_unknown_key_rule)
{
    gs_json *j = doc_of("{\"a\": 1, \"comment\": \"c\", \"description\": \"d\", \"x_ext\": [],\n \"typo\": 2}");
    if (!j) return;
    static const char *const allowed[] = {"a", NULL};
    CHECK(gs_json_check_keys(j, gs_json_root(j), "", allowed) == GS_EFORMAT);
    CHECK_MSG(strstr(gs_detail(), "t.json:2: field typo: unknown field; expected one of: a"), "%s", gs_detail());
    gs_json_free(j);
    j = doc_of("{\"a\": 1, \"comment\": \"c\", \"x_ext\": {\"anything\": 1}}");
    if (j) CHECK_OK(gs_json_check_keys(j, gs_json_root(j), "", allowed));
    /* an object without keys of its own: the message lists the ones it takes all the same */
    static const char *const none[] = {NULL};
    if (j) CHECK(gs_json_check_keys(j, gs_json_root(j), "", none) == GS_EFORMAT);
    CHECK_MSG(strstr(gs_detail(), "t.json:1: field a: unknown field; expected one of: comment, description, or an "
                                  "extension named x_..."), "%s", gs_detail());
    gs_json_free(j);
}

TEST(kit_json_syntax_duplicates_and_nul)
{
    gs_json *j = NULL;
    const char *dup = "{\"a\": 1,\n \"a\": 2}";
    CHECK(gs_json_parse(dup, strlen(dup), "d.json", &j) == GS_EFORMAT && !j);
    CHECK(strstr(gs_detail(), "d.json:2:") && strstr(gs_detail(), "JSON syntax"));
    CHECK(gs_json_parse("{\"a\": 1\0}", 9, "z.json", &j) == GS_EFORMAT && !j);
    CHECK(strstr(gs_detail(), "z.json: contains a NUL byte"));
    CHECK(gs_json_load(fx_tmp("none.json"), 0, &j) == GS_ENOTFOUND && !j);
}

/* Every real prints in its shortest form that reads back exactly. */
TEST(kit_json_real_shortest_round_trip)
{
    static const double v[] = {0.1, 32.79, 1.0 / 3.0, 6.02214076e23, -0.0, 5e-324, 1.7976931348623157e308, 35.0};
    static const char *const want[] = {"0.1", "32.79", "0.3333333333333333", "6.02214076e+23", "-0", "5e-324", "1.7976931348623157e+308", "35"};
    for (size_t i = 0; i < sizeof v / sizeof *v; i++) {
        char buf[40];
        gs_json_real(buf, sizeof buf, v[i]);
        CHECK_MSG(strtod(buf, NULL) == v[i] && !strcmp(buf, want[i]), "%.17g -> %s", v[i], buf);
    }
}

typedef struct {
    char rows[8][4][32];
    size_t counts[8], lines[8];
    size_t n;
} csv_rows;

static gs_status keep_row(void *ctx, char **f, size_t count, size_t line)
{
    csv_rows *r = ctx;
    if (r->n == 8) return gs_fail(GS_ELIMIT, "too many rows");
    for (size_t i = 0; i < count && i < 4; i++) snprintf(r->rows[r->n][i], 32, "%s", f[i]);
    r->counts[r->n] = count;
    r->lines[r->n++] = line;
    return GS_OK;
}

TEST(kit_csv_quotes_bom_crlf_and_lines)
{
    const char *path = fx_tmp("q.csv");
    fx_write_text(path, "\xEF\xBB\xBFid,name\r\n"
                        "1,\"Philips, \"\"Master\"\" 70 W\"\r\n"
                        "\r\n"
                        "2,\"two\nlines\"\n"
                        "3, spaced \n"
                        "4,last");
    csv_rows r;
    memset(&r, 0, sizeof r);
    CHECK_OK(gs_csv_read(path, 0, keep_row, &r));
    CHECK(r.n == 5);
    CHECK(!strcmp(r.rows[0][0], "id") && r.lines[0] == 1);
    CHECK(!strcmp(r.rows[1][1], "Philips, \"Master\" 70 W") && r.lines[1] == 2);
    CHECK(!strcmp(r.rows[2][1], "two\nlines") && r.lines[2] == 5);   /* the line it ends on */
    CHECK(!strcmp(r.rows[3][1], "spaced") && r.lines[3] == 6);
    CHECK(!strcmp(r.rows[4][0], "4") && !strcmp(r.rows[4][1], "last") && r.counts[4] == 2);
    CHECK(gs_csv_read(fx_tmp("absent.csv"), 0, keep_row, &r) == GS_ENOTFOUND);
    CHECK(gs_csv_read(path, 10, keep_row, &r) == GS_ELIMIT);
}

/* A NUL byte is no CSV text: "12<NUL>0.5" was read as the field "12" (its C string), so a
 * corrupted pixel list or recording was read with a wrong value and exit 0. Every CSV reader
 * now refuses it in one line naming the file and the line. */
TEST(kit_csv_nul_byte_refused_with_its_line)
{
    const char *path = fx_tmp("nul.csv");
    fx_write_file(path, "id,x_px,y_px\nl1,12\0\060.5,300\n", 27);
    csv_rows r;
    memset(&r, 0, sizeof r);
    CHECK(gs_csv_read(path, 0, keep_row, &r) == GS_EFORMAT);
    CHECK_MSG(strstr(gs_detail(), "nul.csv:2: ") && strstr(gs_detail(), "NUL byte"), "%s", gs_detail());
    /* the command: one line, non-zero exit, no output */
    const char *st = fx_tmp("st.json");
    fx_write_text(st, "{\"format\": \"gridsurvey-station/1\", \"lat_deg\": 40.0, \"lon_deg\": -75.0,\n"
                      " \"height_m\": 120.0, \"heading_deg\": 30, \"pitch_deg\": -5, \"roll_deg\": 1,\n"
                      " \"focal_px\": 2000, \"cx_px\": 959.5, \"cy_px\": 539.5}\n");
    const char *located = fx_tmp("located.csv");
    char out[4096];
    CHECK(fx_run_bin(out, sizeof out, "%s locate --station %s --pixels %s -o %s", st, path, located) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "nul.csv:2: "), "%s", out);
    CHECK(!fx_exists(located));
}

/* A DELIGHT name may hold commas and quotes (quoted on export, read back exactly). */
TEST(kit_csv_delight_name_with_commas_round_trips)
{
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, 64));
    gs_bulb b = *gs_delight_get(d, 0);
    CHECK_OK(gs_brf_copy(&b.brf, &gs_delight_get(d, 0)->brf));
    snprintf(b.id, sizeof b.id, "named");
    snprintf(b.name, sizeof b.name, "Philips, \"Master\" SON-T, 70 W");
    gs_delight *one = gs_delight_new();
    CHECK_OK(gs_delight_add(one, &b));
    const char *path = fx_tmp("named.csv");
    FILE *f = fopen(path, "w");
    CHECK(f != NULL);
    if (f) {
        CHECK_OK(gs_delight_export_csv(one, f));
        fclose(f);
    }
    gs_delight *back = gs_delight_new();
    CHECK_OK(gs_delight_import_csv(back, path));
    const gs_bulb *r = gs_delight_find(back, "named", 0, 0);
    CHECK(r && !strcmp(r->name, b.name));
    b.name[3] = '\n';
    CHECK(gs_delight_add(one, &b) == GS_EINVAL);   /* control characters stay refused */
    gs_bulb_release(&b);
    gs_delight_free(back);
    gs_delight_free(one);
    gs_delight_free(d);
}

/* Files left in dir whose names contain ".tmp." (temporaries of gs_atomic). */
static int temporaries(const char *dir)
{
    DIR *dp = opendir(dir);
    int n = 0;
    for (struct dirent *e; dp && (e = readdir(dp));) n += strstr(e->d_name, ".tmp.") != NULL;
    if (dp) closedir(dp);
    return n;
}

TEST(kit_atomic_commit_replaces_abort_keeps)
{
    const char *path = fx_tmp("a.txt");
    fx_write_text(path, "old");
    gs_atomic a;
    CHECK_OK(gs_atomic_open(&a, path, 1));
    fputs("new", a.f);
    CHECK(temporaries(test_tmpdir()) == 1);
    gs_atomic_abort(&a);
    char *t = fx_read_file(path, NULL);
    CHECK(t && !strcmp(t, "old"));
    free(t);
    CHECK(temporaries(test_tmpdir()) == 0);
    CHECK_OK(gs_file_write_atomic(path, "new", 3));
    t = fx_read_file(path, NULL);
    CHECK(t && !strcmp(t, "new"));
    free(t);
    CHECK(temporaries(test_tmpdir()) == 0);
    CHECK(gs_file_write_atomic(fx_tmp("no/such/dir/x"), "y", 1) == GS_EIO);
}

TEST(kit_paths)
{
    char b[64];
    gs_path_dir("a/b/c.json", b, sizeof b);
    CHECK(!strcmp(b, "a/b"));
    gs_path_dir("c.json", b, sizeof b);
    CHECK(!strcmp(b, "."));
    gs_path_dir("/c", b, sizeof b);
    CHECK(!strcmp(b, "/"));
    gs_path_dir("a/b//", b, sizeof b);
    CHECK(!strcmp(b, "a"));
    gs_path_base("x/y/metro.json", 1, b, sizeof b);
    CHECK(!strcmp(b, "metro"));
    gs_path_base("x/y/cap/", 0, b, sizeof b);
    CHECK(!strcmp(b, "cap"));
    gs_path_base(".hidden", 1, b, sizeof b);
    CHECK(!strcmp(b, ".hidden"));
    CHECK(gs_path_join(b, sizeof b, "d", "f") && !strcmp(b, "d/f"));
    CHECK(!gs_path_join(b, 4, "dir", "file"));
}

/* splitmix64 from state 0: the first outputs of the reference implementation (Vigna,
 * splitmix64.c). */
TEST(kit_rng_reference_values)
{
    uint64_t s = 0;
    CHECK(gs_splitmix64(&s) == 0xe220a8397b1dcdafull);
    CHECK(gs_splitmix64(&s) == 0x6e789e6aa1b965f4ull);
    CHECK(gs_splitmix64(&s) == 0x06c45d188009454full);
    /* streams keyed by (seed, tag, a, b) differ, and repeat for the same key */
    gs_rng r1, r2, r3;
    gs_rng_init(&r1, 7, 1, 2, 3);
    gs_rng_init(&r2, 7, 1, 2, 3);
    gs_rng_init(&r3, 7, 1, 2, 4);
    uint64_t a = gs_rng_u64(&r1), c = gs_rng_u64(&r3);
    CHECK(a == gs_rng_u64(&r2) && a != c);
    /* the normal and Poisson draws have their moments (10^5 draws: 5 standard errors) */
    double m = 0, v = 0, pm = 0, pv = 0;
    const int N = 100000;
    for (int i = 0; i < N; i++) {
        double z = gs_rng_normal(&r1), k = gs_rng_poisson(&r1, 30.0);
        m += z;
        v += z * z;
        pm += k;
        pv += (k - 30.0) * (k - 30.0);
    }
    m /= N;
    v = v / N - m * m;
    CHECK_NEAR(m, 0.0, 5.0 / sqrt(N));
    CHECK_NEAR(v, 1.0, 5.0 * sqrt(2.0 / N));
    CHECK_NEAR(pm / N, 30.0, 5.0 * sqrt(30.0 / N));
    CHECK_NEAR(pv / N, 30.0, 5.0 * sqrt((2.0 * 900.0 + 30.0) / N));
}

TEST(kit_numeric_chi2_inverse_and_log_phi)
{
    CHECK_NEAR(gs_chi2_isf(0.05, 1), 3.841458820694124, 1e-9);
    CHECK_NEAR(gs_chi2_isf(0.05, 10), 18.307038, 1e-5);    /* tables: chi2_0.95(10) */
    CHECK_NEAR(gs_chi2_isf(0.01, 30), 50.892181, 1e-5);    /* chi2_0.99(30) */
    for (int dof = 1; dof <= 200; dof += 13)
        for (double p = 1e-12; p < 1; p *= 31) {
            double x = gs_chi2_isf(p, dof);
            CHECK_MSG(fabs(gs_chi2_sf(x, dof) - p) <= 1e-9 * p, "dof %d p %g: x %g", dof, p, x);
        }
    CHECK(isnan(gs_chi2_isf(0.5, 0)) && gs_chi2_isf(0, 3) == INFINITY && gs_chi2_isf(1, 3) == 0);
    /* log Phi: erfc where it is exact, and the asymptotic branch meets it at -20 */
    for (double z = -19.5; z < 8; z += 0.37)
        CHECK_NEAR(gs_log_phi(z), log(0.5 * erfc(-z / sqrt(2.0))), 1e-12 * (1 + fabs(log(0.5 * erfc(-z / sqrt(2.0))))));
    double below = gs_log_phi(-20.0000001), above = log(0.5 * erfc(20.0000001 / sqrt(2.0)));
    CHECK_NEAR(below, above, 1e-9 * fabs(above));
    CHECK(isfinite(gs_log_phi(-1e3)) && gs_log_phi(40) == 0.0);
}

TEST(kit_numeric_median_and_wraps)
{
    uint64_t s = 11;
    for (size_t n = 1; n < 60; n += 7) {
        float v[64], w[64];
        for (size_t i = 0; i < n; i++) v[i] = w[i] = (float)floor(10 * gs_splitmix_uniform(&s));
        /* oracle: insertion sort, upper median */
        for (size_t i = 1; i < n; i++)
            for (size_t k = i; k > 0 && w[k - 1] > w[k]; k--) {
                float t = w[k];
                w[k] = w[k - 1];
                w[k - 1] = t;
            }
        CHECK(gs_median_f(v, n) == w[n / 2]);
        /* the double one: the mean of the middle two for even n */
        double dv[64];
        for (size_t i = 0; i < n; i++) dv[i] = v[i];
        double want = n % 2 ? w[n / 2] : 0.5 * ((double)w[n / 2 - 1] + (double)w[n / 2]);
        CHECK(gs_median_d(dv, n) == want);
    }
    double two[2] = {3.0, 1.0};
    CHECK(gs_median_d(two, 2) == 2.0 && isnan(gs_median_d(two, 0)));
    CHECK(gs_wrap360(-1e-17) == 0.0 && gs_wrap360(725) == 5 && gs_wrap360(-90) == 270);
    CHECK(gs_wrap180(180) == -180 && gs_wrap180(-181) == 179 && gs_wrap180(359) == -1);
    /* zero without a sign (an export printed "-0.0000000000" for -0 and -360) */
    CHECK(!signbit(gs_wrap180(-0.0)) && !signbit(gs_wrap180(-360.0)) && !signbit(gs_wrap180(-720.0)));
    /* exact: a longitude already in [-180, 180) comes back unchanged (x + 180 - 180 moved 35.02 to
     * 35.02000000000001, off an area's edge), another one is x - 360 k to the bit (k/1024 degrees
     * plus multiples of 360 are exact doubles) */
    for (int i = 0; i < 100000; i++) {
        double x = -180.0 + 360.0 * (i + 0.5) / 100000.0 + 1e-9 * (i % 7);
        CHECK_MSG(gs_wrap180(x) == x, "gs_wrap180(%.17g) = %.17g", x, gs_wrap180(x));
    }
    for (int k = -3; k <= 3; k++)
        for (int j = -180 * 1024; j < 180 * 1024; j += 97) {
            double x = j / 1024.0;
            CHECK(gs_wrap180(x + 360.0 * k) == x);
        }
}

/* One parser of decimal numbers (CSV fields, options, lists): the values written out, and what
 * strtod alone took as numbers refused (hexadecimal: "0x10" was 16; inf, nan). */
TEST(kit_numeric_decimal_numbers_only)
{
    static const struct {
        const char *s;
        int ok;
        double v;
    } cases[] = {
        {"12.5", 1, 12.5}, {"-3e2", 1, -300.0}, {" 7", 1, 7.0}, {".5", 1, 0.5}, {"5.", 1, 5.0},
        {"+.25e1", 1, 2.5}, {"1e-3", 1, 0.001}, {"0", 1, 0.0}, {"007", 1, 7.0},
        {"0x10", 0, 0}, {"0X1p3", 0, 0}, {"-0x1", 0, 0}, {"inf", 0, 0}, {"-infinity", 0, 0}, {"nan", 0, 0},
        {"NAN(1)", 0, 0}, {"1e400", 0, 0}, {"", 0, 0}, {".", 0, 0}, {"-", 0, 0}, {"e5", 0, 0},
        {"1,2", 0, 0}, {"12 ", 0, 0}, {"1e", 0, 0},
    };
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        double v = -1.0;
        int ok = gs_parse_number(cases[i].s, &v);
        CHECK_MSG(ok == cases[i].ok && (!ok || v == cases[i].v), "'%s': %d %.17g", cases[i].s, ok, v);
    }
    double v = 0.0;
    const char *end = gs_number_prefix("1.5,-2e1m", &v);
    CHECK(end && *end == ',' && v == 1.5);
    end = end ? gs_number_prefix(end + 1, &v) : NULL;
    CHECK(end && !strcmp(end, "m") && v == -20.0);
    CHECK(!gs_number_prefix("0x1,2", &v) && !gs_number_prefix(",2", &v));
}

/* gs_dot against a long double sum (within its rounding), and gs_dot_rows against gs_dot bit for
 * bit: lengths 0 to 80 (tails of 0 to 7 after the 8-wide part), counts not a multiple of 4,
 * indices out of order and repeated, a scale. */
TEST(kit_numeric_dot_rows_same_bits_as_dot)
{
    uint64_t rs = 5;
    double x[80], t[40 * 80], out[40], ref[40];
    for (size_t i = 0; i < 80; i++) x[i] = gs_splitmix_normal(&rs) * exp(4.0 * gs_splitmix_normal(&rs));
    for (size_t i = 0; i < 40 * 80; i++) t[i] = gs_splitmix_normal(&rs);
    int differ = 0, far = 0;
    for (size_t n = 0; n <= 80; n++)
        for (size_t count = 0; count <= 11; count++) {
            size_t idx[11];
            for (size_t i = 0; i < count; i++) idx[i] = (size_t)(gs_splitmix_uniform(&rs) * 40.0) % 40;
            if (count > 2) idx[count - 1] = idx[0];
            for (size_t i = 0; i < count; i++) {
                ref[idx[i]] = gs_dot(x, t + idx[i] * 80, n) * 0.37;
                long double s = 0.0L, a = 0.0L;
                for (size_t k = 0; k < n; k++) {
                    s += (long double)x[k] * t[idx[i] * 80 + k];
                    a += fabsl((long double)x[k] * t[idx[i] * 80 + k]);
                }
                far += fabsl((long double)gs_dot(x, t + idx[i] * 80, n) - s) > 1e-14L * a;
            }
            gs_dot_rows(x, t, 80, n, idx, count, 0.37, out);
            for (size_t i = 0; i < count; i++) differ += memcmp(&out[idx[i]], &ref[idx[i]], sizeof *out) != 0;
            /* without idx: the rows 0..count-1 */
            gs_dot_rows(x, t, 80, n, NULL, count, 0.37, out);
            for (size_t i = 0; i < count; i++) {
                double r = gs_dot(x, t + i * 80, n) * 0.37;
                differ += memcmp(&out[i], &r, sizeof r) != 0;
            }
        }
    CHECK_MSG(differ == 0, "%d dot products differ from gs_dot", differ);
    CHECK_MSG(far == 0, "%d dot products off their sum", far);
}

/* A failure's detail is one line whatever its parts hold: a library's message ending in a
 * newline (OpenCV's), a file name with a newline or ESC in it. */
TEST(kit_status_detail_is_one_line)
{
    CHECK(gs_fail(GS_EFORMAT, "dilate: OpenCV: %s", "OpenCV(4.6.0) alloc.cpp:73: error\n\n") == GS_EFORMAT);
    CHECK_MSG(!strcmp(gs_detail(), "dilate: OpenCV: OpenCV(4.6.0) alloc.cpp:73: error"), "%s", gs_detail());
    gs_fail(GS_EIO, "%s: cannot open it", "a\nb\x1b[31m\tc\x7f");
    CHECK_MSG(!strcmp(gs_detail(), "a b [31m c : cannot open it"), "%s", gs_detail());
    /* context added to the last detail keeps it */
    gs_fail(GS_EIO, "run: %s", gs_detail());
    CHECK_MSG(!strcmp(gs_detail(), "run: a b [31m c : cannot open it"), "%s", gs_detail());
    gs_fail(GS_EIO, "%s", "");
    CHECK(!strcmp(gs_detail(), ""));
}

/* ------------------------------------------------------------------ gs_parallel_chunks */

/* Each index's visitor (part + 1) and each part's calls, so the test sees how the range was cut. */
typedef struct {
    int *owner;                           /* [n] the part that visited index i, + 1 */
    int *count;                           /* [n] visits of index i */
    size_t last_end[GS_MAX_THREADS];      /* a part's previous chunk's end */
    int calls[GS_MAX_THREADS], out_of_order, bad_part;
    size_t fail_at;                       /* a chunk holding this index fails (n: none) */
} chunk_probe;

static gs_status probe_range(void *ctx, int part, size_t b, size_t e)
{
    chunk_probe *p = ctx;
    if (part < 0 || part >= GS_MAX_THREADS) {
        p->bad_part = 1;
        return GS_OK;
    }
    if (p->calls[part]++ && b < p->last_end[part]) p->out_of_order = 1;
    p->last_end[part] = e;
    for (size_t i = b; i < e; i++) {
        p->owner[i] = part + 1;
        p->count[i]++;   /* each index is one part's: no two threads write one slot */
    }
    if (p->fail_at >= b && p->fail_at < e) return gs_fail(GS_EINVAL, "chunk [%zu, %zu) failed", b, e);
    return GS_OK;
}

/* Every index once, in chunks of the size asked (the last shorter; 0: about 64), a part's chunks in rising
 * order, parts numbered below the threads; one thread gets the whole range in one call; a
 * failing chunk's status and message come back. */
TEST(kit_parallel_chunks_every_index_once_and_failures_reported)
{
    enum { N = 1000 };
    static int owner[N], count[N];
    static const size_t chunks[] = {0, 1, 7, 64, 1000, 5000};   /* 0: the default, N / 64 + 1 */
    for (int threads = 1; threads <= 4; threads++)
        for (size_t c = 0; c < sizeof chunks / sizeof *chunks; c++) {
            chunk_probe p;
            memset(&p, 0, sizeof p);
            memset(owner, 0, sizeof owner);
            memset(count, 0, sizeof count);
            p.owner = owner;
            p.count = count;
            p.fail_at = N;
            CHECK_OK(gs_parallel_chunks(threads, N, chunks[c], probe_range, &p));
            int once = 1, parts = 0, calls = 0;
            for (size_t i = 0; i < N; i++) once &= count[i] == 1 && owner[i] >= 1 && owner[i] <= threads;
            for (int q = 0; q < GS_MAX_THREADS; q++) {
                parts += p.calls[q] > 0;
                calls += p.calls[q];
            }
            size_t size = chunks[c] ? chunks[c] : N / 64 + 1, want = threads == 1 ? 1 : (N + size - 1) / size;
            CHECK_MSG(once && !p.out_of_order && !p.bad_part && (size_t)calls == want && parts <= threads,
                      "threads %d chunk %zu: once %d order %d calls %d (want %zu) parts %d", threads, chunks[c],
                      once, !p.out_of_order, calls, want, parts);
        }
    chunk_probe p;
    memset(&p, 0, sizeof p);
    p.owner = owner;
    p.count = count;
    p.fail_at = 500;
    gs_status st = gs_parallel_chunks(2, N, 10, probe_range, &p);
    CHECK(st == GS_EINVAL && strstr(gs_detail(), "chunk [500, 510) failed"));
    CHECK_OK(gs_parallel_chunks(2, 0, 10, probe_range, &p));   /* an empty range: no call */
}
