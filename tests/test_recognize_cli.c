/* test_recognize_cli.c - `gridsurvey recognize` end to end (paper Sec. 4, Eq. 7; Figs. 1 and 3).
 *
 * The captures are written by an independent program: a Python script (numpy only, below) that
 * follows docs/formats.md by hand (16-bit PNGs chunk by chunk, capture.json) and renders lights whose
 * per-window signals it integrates itself from the DELIGHT BRFs exported as CSV by
 * `gridsurvey delight export` (Fourier series of each BRF, delayed by phi/pi cycles, averaged over
 * the K windows: docs/design.md, Eq. 5), plus Gaussian read noise matching capture.json. The
 * JSON output is parsed here with Jansson; the map PNGs are read back with the OpenCV shim.
 * Renders are cached in the runner's temporary root, so tests that share a scene render it once. */
#include "recognize/recognize.h"
#include "recognize/internal.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <jansson.h>
#include <libgen.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

static const char render_py[] =
    "# render.py - writes a gridsurvey-capture/1 directory (docs/formats.md) of Gaussian lights whose\n"
    "# per-window signals are DELIGHT BRFs (rows of `gridsurvey delight export`) integrated here with\n"
    "# numpy, independently of the C code; PNGs are written by hand (PNG spec: signature, IHDR, zlib\n"
    "# IDAT with filter 0 rows, IEND; 16-bit samples big-endian). usage: render.py OUTDIR CSV SPEC.json\n"
    "import json, math, os, struct, sys, zlib\n"
    "import numpy as np\n"
    "\n"
    "out, csv_path, spec = sys.argv[1], sys.argv[2], json.load(open(sys.argv[3]))\n"
    "grid, K, bands = spec[\"grid_hz\"], spec[\"K\"], spec[\"bands\"]\n"
    "W, H = spec[\"width\"], spec[\"height\"]\n"
    "black, read, cycles = spec[\"black_level\"], spec[\"read_noise_dn\"], spec[\"cycles\"]\n"
    "sensor = \"rgb\" if bands == 3 else \"photodiode\"\n"
    "need = {l[\"bulb\"] for l in spec[\"lights\"]}\n"
    "brf = {}\n"
    "with open(csv_path) as f:\n"
    "    f.readline()\n"
    "    for line in f:\n"
    "        p = line.rstrip(\"\\n\").split(\",\")\n"
    "        if p[0] not in need or int(p[4]) != grid or p[5].split(\"/\")[0] != sensor:\n"
    "            continue\n"
    "        band = {\"mono\": 0, \"R\": 0, \"G\": 1, \"B\": 2}[p[6]]\n"
    "        n = int(p[8])\n"
    "        brf.setdefault(p[0], [None] * bands)[band] = (float(p[7]), np.array(p[9:9 + n], float))\n"
    "if need - set(brf):\n"
    "    sys.exit(\"render.py: bulbs not in the export: %s\" % sorted(need - set(brf)))\n"
    "\n"
    "def window_means(v, shift):\n"
    "    # mean of v(t - shift) over [k/K, (k+1)/K), v a trigonometric polynomial of n samples/cycle:\n"
    "    # harmonic h contributes C_h e^{-2 pi i h shift} (e^{2 pi i h (k+1)/K} - e^{2 pi i h k/K}) K / (2 pi i h)\n"
    "    n = len(v)\n"
    "    C = np.fft.rfft(v) / n\n"
    "    h = np.arange(1, len(C))[:, None]\n"
    "    a = np.arange(K)[None, :] / K\n"
    "    seg = (np.exp(2j * math.pi * h * (a + 1.0 / K)) - np.exp(2j * math.pi * h * a)) * K / (2j * math.pi * h)\n"
    "    weight = np.where(2 * h == n, 1.0, 2.0)\n"
    "    terms = weight * (C[1:, None] * np.exp(-2j * math.pi * h * shift) * seg).real\n"
    "    return C[0].real + terms.sum(axis=0)\n"
    "\n"
    "def write_png16(path, img):\n"
    "    # img: uint16 array (H, W) grey or (H, W, 3) RGB\n"
    "    h, w = img.shape[:2]\n"
    "    ctype = 0 if img.ndim == 2 else 2\n"
    "    rows = img.astype(\">u2\").reshape(h, -1).view(np.uint8).reshape(h, -1)\n"
    "    data = np.hstack([np.zeros((h, 1), np.uint8), rows]).tobytes()\n"
    "    def chunk(tag, body):\n"
    "        return struct.pack(\">I\", len(body)) + tag + body + struct.pack(\">I\", zlib.crc32(tag + body))\n"
    "    with open(path, \"wb\") as f:\n"
    "        f.write(b\"\\x89PNG\\r\\n\\x1a\\n\" + chunk(b\"IHDR\", struct.pack(\">IIBBBBB\", w, h, 16, ctype, 0, 0, 0))\n"
    "                + chunk(b\"IDAT\", zlib.compress(data, 1)) + chunk(b\"IEND\", b\"\"))\n"
    "\n"
    "yy, xx = np.mgrid[0:H, 0:W].astype(float)\n"
    "value = np.zeros((K, H, W, bands)) + np.array(spec[\"sky\"][:bands])   # DN per flicker cycle\n"
    "for l in spec[\"lights\"]:\n"
    "    s = (l[\"phase_deg\"] / 180.0) % 1.0      # docs/design.md: phase phi delays by phi/pi cycles\n"
    "    psf = np.exp(-((xx - l[\"x\"]) ** 2 + (yy - l[\"y\"]) ** 2) / (2 * l[\"psf_px\"] ** 2))\n"
    "    psf /= 2 * math.pi * l[\"psf_px\"] ** 2\n"
    "    for b in range(bands):\n"
    "        q, v = brf[l[\"bulb\"]][b]\n"
    "        value[:, :, :, b] += l[\"flux\"] * q * window_means(v, s)[:, None, None] * psf[None]\n"
    "rng = np.random.default_rng(spec[\"seed\"])\n"
    "raw = black + value * cycles + rng.normal(0.0, read, value.shape)\n"
    "raw = np.clip(np.rint(raw), 0, 65535).astype(np.uint16)\n"
    "os.makedirs(out, exist_ok=True)\n"
    "frames = []\n"
    "for k in range(K):\n"
    "    name = \"frame_%03d.png\" % k\n"
    "    write_png16(os.path.join(out, name), raw[k, :, :, 0] if bands == 1 else raw[k])\n"
    "    frames.append({\"file\": name, \"k\": k, \"cycles\": cycles})\n"
    "frames.reverse()                             # frames may come in any order\n"
    "meta = {\"format\": \"gridsurvey-capture/1\", \"grid_hz\": grid, \"K\": K, \"bands\": bands,\n"
    "        \"width\": W, \"height\": H, \"saturation\": 65535, \"black_level\": black,\n"
    "        \"read_noise_dn\": read, \"gain_e_per_dn\": 0, \"utc\": \"2017-07-21T22:05:00Z\",\n"
    "        \"station\": {\"name\": \"test roof\", \"lat\": 32.79, \"lon\": 35.02},\n"
    "        \"x_renderer\": \"tests/test_recognize_cli.c\", \"frames\": frames}\n"
    "with open(os.path.join(out, \"capture.json\"), \"w\") as f:\n"
    "    json.dump(meta, f, indent=1)\n";

static char out[1 << 20];

typedef struct {
    double x, y, flux;
    const char *bulb;
    double phase_deg;
} light;

typedef struct {
    const char *key;        /* cache name */
    int grid_hz, K, bands, width, height;
    unsigned seed;
    const light *lights;
    int count;
} scene;

/* Scene A: RGB, 50 Hz, K = 26, six technologies on the three phases. */
static const light lights_a[] = {
    {30.3, 25.6, 400, "hps-150w", 0},          {80.7, 30.2, 300, "mh-250w", 120},
    {130.1, 22.9, 300, "cfl-23w", 240},        {40.4, 85.5, 300, "fl-t8-36w-tri", 120},
    {95.2, 90.1, 300, "led-gu10-5w-cap", 240}, {140.6, 80.8, 500, "inc-a60-25w-230v", 0},
};
static const scene scene_a = {"a", 50, 26, 3, 160, 120, 7, lights_a, 6};

/* Scene B: monochrome, 60 Hz, K = 22 (the ACam's 60 Hz K). */
static const light lights_b[] = {
    {20.6, 20.3, 400, "hps-150w", 0},   {90.2, 25.7, 300, "mh-250w", 240},
    {30.4, 70.1, 300, "cfl-23w", 120},  {100.8, 72.4, 300, "fl-t8-36w-tri", 0},
};
static const scene scene_b = {"b", 60, 22, 1, 128, 96, 5, lights_b, 4};

/* Scene C: phases off the 0/120/240 set (each nearer to the set than its +180 twin, which a
 * flicker cannot tell apart: docs/design.md). */
static const light lights_c[] = {
    {30.3, 25.6, 400, "hps-150w", 17},     {90.7, 30.2, 300, "mh-250w", 95},
    {40.4, 70.5, 300, "fl-t8-36w-tri", 225}, {95.2, 75.1, 300, "cfl-23w", 250},
};
static const scene scene_c = {"c", 50, 26, 3, 128, 96, 11, lights_c, 4};

/* Scene D: a delta-wye transformer's 30 deg shift. */
static const light lights_d[] = {
    {30.3, 25.6, 400, "hps-150w", 30},     {90.7, 30.2, 300, "mh-250w", 150},
    {40.4, 70.5, 300, "fl-t8-36w-tri", 270}, {95.2, 75.1, 300, "cfl-23w", 120},
};
static const scene scene_d = {"d", 50, 26, 3, 128, 96, 13, lights_d, 4};

/* Scene E: sky and noise only. */
static const scene scene_e = {"e", 50, 8, 1, 64, 48, 17, NULL, 0};

/* The runner's temporary root (parent of this test's directory), shared by the tests of a run. */
static const char *cache_root(void)
{
    static char root[512];
    snprintf(root, sizeof root, "%s", test_tmpdir());
    return dirname(root);
}

/* The built-in DELIGHT as a SQLite file, generated once per run; GRIDSURVEY_DELIGHT names it for
 * the commands this test runs (generating it in every command would cost 0.25 s each). */
static const char *cached_delight(void)
{
    static char db[1100];
    snprintf(db, sizeof db, "%s/delight.sqlite", cache_root());
    if (!fx_exists(db)) {
        char cmd[4096];
        snprintf(cmd, sizeof cmd, "%s delight generate -o %s.tmp && mv %s.tmp %s", test_bin(), db, db, db);
        CHECK_MSG(test_run(cmd, out, sizeof out) == 0, "delight generate: %s", out);
    }
    setenv("GRIDSURVEY_DELIGHT", db, 1);
    return db;
}

/* Render scene s (once per run) and return its capture directory. */
static const char *render(const scene *s)
{
    static char dir[1024];
    char path[1100], cmd[8192];
    const char *root = cache_root();
    snprintf(dir, sizeof dir, "%s/capture-%s", root, s->key);
    snprintf(path, sizeof path, "%s/capture.json", dir);
    if (fx_exists(path)) return dir;
    /* the DELIGHT export, once per run */
    char csv[1100];
    snprintf(csv, sizeof csv, "%s/delight-export.csv", root);
    if (!fx_exists(csv)) {
        char tmp[1200];
        snprintf(tmp, sizeof tmp, "%s.tmp", csv);
        snprintf(cmd, sizeof cmd, "%s delight export --delight %s -o %s && mv %s %s", test_bin(),
                 cached_delight(), tmp, tmp, csv);
        CHECK_MSG(test_run(cmd, out, sizeof out) == 0, "delight export: %s", out);
    }
    char script[1100];
    snprintf(script, sizeof script, "%s/render.py", root);
    FILE *f = fopen(script, "w");
    CHECK(f != NULL);
    if (!f) return dir;
    fputs(render_py, f);
    fclose(f);
    char spec[1200];
    snprintf(spec, sizeof spec, "%s/spec-%s.json", root, s->key);
    f = fopen(spec, "w");
    CHECK(f != NULL);
    if (!f) return dir;
    fprintf(f, "{\"grid_hz\": %d, \"K\": %d, \"bands\": %d, \"width\": %d, \"height\": %d, "
               "\"black_level\": 64, \"read_noise_dn\": 3, \"cycles\": 50, "
               "\"sky\": [0.5, 0.6, 0.8], \"seed\": %u, \"lights\": [",
            s->grid_hz, s->K, s->bands, s->width, s->height, s->seed);
    for (int i = 0; i < s->count; i++)
        fprintf(f, "%s{\"x\": %.17g, \"y\": %.17g, \"flux\": %.17g, \"psf_px\": 1.3, "
                   "\"bulb\": \"%s\", \"phase_deg\": %.17g}", i ? ", " : "", s->lights[i].x,
                s->lights[i].y, s->lights[i].flux, s->lights[i].bulb, s->lights[i].phase_deg);
    fputs("]}\n", f);
    fclose(f);
    snprintf(cmd, sizeof cmd, "/usr/bin/python3 %s %s %s %s", script, dir, csv, spec);
    int rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 0, "render.py (needs /usr/bin/python3 with python3-numpy, .ci/deps.sh) "
                       "failed: %s", out);
    return dir;
}

/* Run `gridsurvey recognize ARGS` with stderr to a file; parse stdout as JSON. NULL on failure. */
static json_t *recognize_json(const char *args, int *rc, char *err, size_t err_size)
{
    char errf[1100], cmd[4096];
    snprintf(errf, sizeof errf, "%s/stderr.txt", test_tmpdir());
    snprintf(cmd, sizeof cmd, "%s recognize %s --json 2>%s", test_bin(), args, errf);
    *rc = test_run(cmd, out, sizeof out);
    if (err) {
        err[0] = '\0';
        FILE *f = fopen(errf, "r");
        if (f) {
            size_t n = fread(err, 1, err_size - 1, f);
            err[n] = '\0';
            fclose(f);
        }
    }
    json_error_t je;
    json_t *root = json_loads(out, 0, &je);
    CHECK_MSG(root != NULL, "JSON output: %s at line %d: %.200s", je.text, je.line, out);
    return root;
}

/* Nothing on stderr (under the sanitizers, LeakSanitizer may list its suppressions there). */
static int quiet_stderr(const char *err)
{
    if (fx_sanitized())
        return !strstr(err, "gridsurvey") && !strstr(err, "PLPLOT") && !strstr(err, "ERROR") &&
               !strstr(err, "arning");
    return err[0] == '\0';
}

/* The JSON light within 1 px of (x, y), or NULL. */
static json_t *light_near(json_t *root, double x, double y)
{
    json_t *lights = json_object_get(root, "lights");
    size_t i;
    json_t *l;
    json_array_foreach(lights, i, l) {
        double lx = json_number_value(json_object_get(l, "x"));
        double ly = json_number_value(json_object_get(l, "y"));
        if (hypot(lx - x, ly - y) < 1.0) return l;
    }
    return NULL;
}

static int has_flag(json_t *l, const char *name)
{
    size_t i;
    json_t *f;
    json_array_foreach(json_object_get(l, "flags"), i, f)
        if (json_is_string(f) && !strcmp(json_string_value(f), name)) return 1;
    return 0;
}

static double circ_diff_deg(double a, double b)
{
    double d = fmod(a - b, 360.0);
    if (d > 180.0) d -= 360.0;
    if (d < -180.0) d += 360.0;
    return d;
}

/* Every light of the scene found at its position with its bulb and (discrete) phase. */
static void check_discrete(json_t *root, const scene *s)
{
    CHECK(!strcmp(json_string_value(json_object_get(root, "format")), "gridsurvey-lights/1"));
    CHECK(json_array_size(json_object_get(root, "lights")) == (size_t)s->count);
    for (int i = 0; i < s->count; i++) {
        const light *t = &s->lights[i];
        json_t *l = light_near(root, t->x, t->y);
        CHECK_MSG(l != NULL, "light %s at (%.1f, %.1f) not found", t->bulb, t->x, t->y);
        if (!l) continue;
        const char *bulb = json_string_value(json_object_get(l, "bulb"));
        CHECK_MSG(bulb && !strcmp(bulb, t->bulb), "light at (%.1f, %.1f): bulb %s, expected %s",
                  t->x, t->y, bulb ? bulb : "null", t->bulb);
        json_t *ph = json_object_get(l, "phase_deg");
        CHECK_MSG(json_is_number(ph) && fabs(circ_diff_deg(json_number_value(ph), t->phase_deg)) < 1e-9,
                  "light %s: phase %g, expected %g", t->bulb, json_number_value(ph), t->phase_deg);
        CHECK(json_number_value(json_object_get(l, "confidence")) >= 0.8);
        CHECK(json_number_value(json_object_get(l, "p_value")) >= 1e-3);
        CHECK(json_array_size(json_object_get(l, "flags")) == 0);
        CHECK(json_is_string(json_object_get(l, "technology")));
        CHECK(json_is_integer(json_object_get(l, "dof")) && json_integer_value(json_object_get(l, "dof")) > 0);
    }
}

TEST(recognize_cli_json_bulbs_and_phases)
{
    const char *dir = render(&scene_a);
    unsetenv("GRIDSURVEY_DELIGHT");   /* this one generates the built-in database itself */
    int rc;
    char err[4096];
    json_t *root = recognize_json(dir, &rc, err, sizeof err);
    CHECK_MSG(rc == 0, "exit %d: %s", rc, err);
    CHECK_MSG(quiet_stderr(err), "stderr not empty: %s", err);
    if (!root) return;
    check_discrete(root, &scene_a);
    json_t *cap = json_object_get(root, "capture");
    CHECK(json_integer_value(json_object_get(cap, "grid_hz")) == 50);
    CHECK(json_integer_value(json_object_get(cap, "K")) == 26);
    CHECK(json_integer_value(json_object_get(cap, "bands")) == 3);
    CHECK(json_integer_value(json_object_get(cap, "width")) == 160);
    CHECK(json_is_true(json_object_get(cap, "locked")));
    CHECK(!strcmp(json_string_value(json_object_get(cap, "utc")), "2017-07-21T22:05:00Z"));
    CHECK_NEAR(json_number_value(json_object_get(json_object_get(cap, "station"), "lat")), 32.79, 1e-12);
    json_t *rcg = json_object_get(root, "recognition");
    CHECK(!strcmp(json_string_value(json_object_get(rcg, "phases")), "3"));
    CHECK(!strcmp(json_string_value(json_object_get(rcg, "delight")), "built-in"));
    CHECK(json_integer_value(json_object_get(rcg, "candidates")) >= 30);
    json_t *sum = json_object_get(root, "summary");
    CHECK(json_integer_value(json_object_get(sum, "lights")) == 6);
    CHECK(json_integer_value(json_object_get(sum, "with_bulb")) == 6);
    CHECK(json_integer_value(json_object_get(sum, "with_phase")) == 6);
    /* brightness is the fitted flux: sum over bands of the mean per-cycle flux (Eq. 6) */
    for (int i = 0; i < scene_a.count; i++) {
        json_t *l = light_near(root, lights_a[i].x, lights_a[i].y);
        if (!l) continue;
        CHECK_NEAR(json_number_value(json_object_get(l, "brightness")), lights_a[i].flux, 0.03 * lights_a[i].flux);
        json_t *ru = json_object_get(l, "runner_up");
        CHECK(json_is_null(ru) || (json_is_string(json_object_get(ru, "bulb")) &&
                                   json_number_value(json_object_get(ru, "confidence")) < 0.2));
        CHECK(json_number_value(json_object_get(l, "phase_sigma_deg")) == 0.0);
    }
    json_decref(root);
}

/* --band-gains off --model-error 0 is the paper's Eq. 7: these unreddened lights are recognized
 * just the same, and the JSON says which model ran. */
TEST(recognize_cli_paper_model_flags)
{
    cached_delight();
    const char *dir = render(&scene_a);
    char args[1200];
    snprintf(args, sizeof args, "%s --band-gains off --model-error 0", dir);
    int rc;
    char err[4096];
    json_t *root = recognize_json(args, &rc, err, sizeof err);
    CHECK_MSG(rc == 0, "exit %d: %s", rc, err);
    if (!root) return;
    check_discrete(root, &scene_a);
    json_t *rcg = json_object_get(root, "recognition");
    CHECK(json_is_false(json_object_get(rcg, "band_gains")));
    CHECK(json_number_value(json_object_get(rcg, "model_error")) == 0.0);
    json_decref(root);
    snprintf(args, sizeof args, "%s --model-error 0.1", dir);
    root = recognize_json(args, &rc, err, sizeof err);
    CHECK_MSG(rc == 0, "exit %d: %s", rc, err);
    if (!root) return;
    rcg = json_object_get(root, "recognition");
    CHECK(json_is_true(json_object_get(rcg, "band_gains")));
    CHECK_NEAR(json_number_value(json_object_get(rcg, "model_error")), 0.1, 1e-15);
    json_decref(root);
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "%s recognize %s --band-gains maybe", test_bin(), dir);
    CHECK(test_run(cmd, out, sizeof out) == 2 && strstr(out, "--band-gains"));
    snprintf(cmd, sizeof cmd, "%s recognize %s --model-error 2", test_bin(), dir);
    CHECK(test_run(cmd, out, sizeof out) == 2 && strstr(out, "--model-error"));
}

TEST(recognize_cli_mono_60hz_table)
{
    cached_delight();
    const char *dir = render(&scene_b);
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "%s recognize %s", test_bin(), dir);
    int rc = test_run(cmd, out, sizeof out);
    CHECK_MSG(rc == 0, "exit %d: %s", rc, out);
    CHECK(strstr(out, "60 Hz grid, K = 22, 1 band,") != NULL);
    CHECK(strstr(out, "4 lights: 4 with a bulb, 4 with a phase") != NULL);
    for (int i = 0; i < scene_b.count; i++) {
        /* the light's row: its bulb, then its phase "P.0 +- 0.0" */
        char phase[32];
        snprintf(phase, sizeof phase, " %.1f +- 0.0 ", lights_b[i].phase_deg);
        const char *line = out;
        int found = 0;
        while (line && *line && !found) {
            const char *end = strchr(line, '\n');
            size_t len = end ? (size_t)(end - line) : strlen(line);
            char buf[512];
            snprintf(buf, sizeof buf, "%.*s", (int)(len < sizeof buf ? len : sizeof buf - 1), line);
            char id[64];
            snprintf(id, sizeof id, "  %s ", lights_b[i].bulb);
            found = strstr(buf, id) && strstr(buf, phase) && !strstr(buf, "unknown");
            line = end ? end + 1 : NULL;
        }
        CHECK_MSG(found, "no table row with %s at %s:\n%s", lights_b[i].bulb, phase, out);
    }
}

/* Hue in degrees of an RGB colour (NaN for grey). */
static double hue_deg(const unsigned char *p)
{
    double r = p[0], g = p[1], b = p[2];
    double mx = fmax(r, fmax(g, b)), mn = fmin(r, fmin(g, b)), c = mx - mn;
    if (c < 1.0) return NAN;
    double h = mx == r ? fmod((g - b) / c, 6.0) : mx == g ? (b - r) / c + 2.0 : (r - g) / c + 4.0;
    h *= 60.0;
    return h < 0 ? h + 360.0 : h;
}

/* Read a map PNG: checks the signature, reads the size from IHDR and decodes it as 8-bit RGB.
 * Returns the pixels (free()) or NULL. */
static unsigned char *read_png(const char *path, int *w, int *h)
{
    FILE *f = fopen(path, "rb");
    CHECK_MSG(f != NULL, "%s missing", path);
    if (!f) return NULL;
    fseek(f, 0, SEEK_END);
    long size = ftell(f);
    fseek(f, 0, SEEK_SET);
    unsigned char *buf = malloc((size_t)size);
    size_t got = buf ? fread(buf, 1, (size_t)size, f) : 0;
    fclose(f);
    CHECK(size > 33 && got == (size_t)size);
    if (!buf || size <= 33 || got != (size_t)size) {
        free(buf);
        return NULL;
    }
    CHECK_MSG(!memcmp(buf, "\x89PNG\r\n\x1a\n", 8) && !memcmp(buf + 12, "IHDR", 4), "%s: not a PNG", path);
    *w = (int)((unsigned)buf[16] << 24 | (unsigned)buf[17] << 16 | (unsigned)buf[18] << 8 | buf[19]);
    *h = (int)((unsigned)buf[20] << 24 | (unsigned)buf[21] << 16 | (unsigned)buf[22] << 8 | buf[23]);
    CHECK_MSG(buf[24] == 8 && buf[25] == 2, "%s: bit depth %d colour type %d, expected 8-bit RGB",
              path, buf[24], buf[25]);
    unsigned char *px = malloc((size_t)*w * (size_t)*h * 3);
    gs_status s = px ? gs_png_decode(buf, (size_t)size, path, "", *w, *h, 3, 8, px) : GS_ENOMEM;
    CHECK_OK(s);
    free(buf);
    if (s != GS_OK) {
        free(px);
        return NULL;
    }
    return px;
}

/* The map colour at the centre of capture pixel (x, y) (rounded), with the documented scale. */
static const unsigned char *map_at(const unsigned char *px, int png_w, int s, double x, double y)
{
    int xi = (int)lround(x), yi = (int)lround(y);
    return px + 3 * ((size_t)(s * yi + s / 2) * (size_t)png_w + (size_t)(s * xi + s / 2));
}

/* docs/recognize-cli.md: s = clamp(floor(640 / max(W, H)), 1, 16); image max(s W, 480) wide. */
static int doc_scale(int w, int h)
{
    int s = 640 / (w > h ? w : h);
    return s < 1 ? 1 : s > 16 ? 16 : s;
}

TEST(recognize_cli_continuous_phase_within_sigma)
{
    cached_delight();
    const char *dir = render(&scene_c);
    char args[2048];
    snprintf(args, sizeof args, "%s --phases continuous --maps %s/maps", dir, test_tmpdir());
    int rc;
    char err[4096];
    json_t *root = recognize_json(args, &rc, err, sizeof err);
    CHECK_MSG(rc == 0, "exit %d: %s", rc, err);
    if (!root) return;
    CHECK(!strcmp(json_string_value(json_object_get(json_object_get(root, "recognition"), "phases")),
                  "continuous"));
    CHECK(json_array_size(json_object_get(root, "lights")) == (size_t)scene_c.count);
    const char *path = fx_tmp("maps/phase_map.png");
    int w = 0, h = 0;
    unsigned char *px = read_png(path, &w, &h);
    int s = doc_scale(scene_c.width, scene_c.height);
    for (int i = 0; i < scene_c.count; i++) {
        const light *t = &lights_c[i];
        json_t *l = light_near(root, t->x, t->y);
        CHECK_MSG(l != NULL, "light %s not found", t->bulb);
        if (!l) continue;
        const char *bulb = json_string_value(json_object_get(l, "bulb"));
        CHECK_MSG(bulb && !strcmp(bulb, t->bulb), "bulb %s, expected %s", bulb ? bulb : "null", t->bulb);
        double phase = json_number_value(json_object_get(l, "phase_deg"));
        double sigma = json_number_value(json_object_get(l, "phase_sigma_deg"));
        /* within 3 reported sigmas, and the sigma is informative (not the uniform 51.96) */
        CHECK_MSG(sigma > 0.0 && sigma < 3.0, "light %s: sigma %g deg", t->bulb, sigma);
        CHECK_MSG(fabs(circ_diff_deg(phase, t->phase_deg)) <= 3.0 * sigma,
                  "light %s: phase %.4f +- %.4f, true %.1f", t->bulb, phase, sigma, t->phase_deg);
        /* Fig. 1 for continuous phases: the hue wheel (hue = phase) at the light's centre */
        if (px && w == (s * scene_c.width > 480 ? s * scene_c.width : 480)) {
            double hue = hue_deg(map_at(px, w, s, t->x, t->y));
            CHECK_MSG(isfinite(hue) && fabs(circ_diff_deg(hue, t->phase_deg)) < 6.0,
                      "light %s: map hue %.1f, phase %.1f", t->bulb, hue, t->phase_deg);
        }
    }
    CHECK(w == 640 && h > s * scene_c.height);
    free(px);
    json_decref(root);
}

TEST(recognize_cli_six_phases_transformer)
{
    cached_delight();
    const char *dir = render(&scene_d);
    char args[2048];
    snprintf(args, sizeof args, "%s --phases 6 --transformer-deg 30", dir);
    int rc;
    char err[4096];
    json_t *root = recognize_json(args, &rc, err, sizeof err);
    CHECK_MSG(rc == 0, "exit %d: %s", rc, err);
    if (!root) return;
    check_discrete(root, &scene_d);
    CHECK(!strcmp(json_string_value(json_object_get(json_object_get(root, "recognition"), "phases")), "6"));
    json_decref(root);
    /* the same lights with only 0/120/240 allowed: the 30/150/270 ones fit nothing (unknown) */
    root = recognize_json(dir, &rc, err, sizeof err);
    CHECK(rc == 0);
    if (!root) return;
    for (int i = 0; i < scene_d.count; i++) {
        json_t *l = light_near(root, lights_d[i].x, lights_d[i].y);
        CHECK(l != NULL);
        if (!l || lights_d[i].phase_deg == 120) continue;
        CHECK_MSG(json_is_null(json_object_get(l, "bulb")) && has_flag(l, "unknown") &&
                      json_is_null(json_object_get(l, "phase_deg")),
                  "light %s at %g deg with phases 3: expected unknown", lights_d[i].bulb, lights_d[i].phase_deg);
    }
    json_decref(root);
}

TEST(recognize_cli_delight_subset_unknown)
{
    const char *dir = render(&scene_a);
    char sub[1024], db[1024], cmd[4096];
    snprintf(sub, sizeof sub, "%s/sub.csv", test_tmpdir());
    snprintf(db, sizeof db, "%s/sub.sqlite", test_tmpdir());
    snprintf(cmd, sizeof cmd, "%s delight export | grep -E '^(bulb_id|hps-150w|mh-250w),' > %s && "
                              "%s delight import %s --delight %s",
             test_bin(), sub, test_bin(), sub, db);
    CHECK_MSG(test_run(cmd, out, sizeof out) == 0, "%s", out);
    for (int how = 0; how < 2; how++) {
        char args[3000];
        int rc;
        /* how 0: $GRIDSURVEY_DELIGHT; how 1: --delight wins over a bad $GRIDSURVEY_DELIGHT */
        if (how == 0) snprintf(args, sizeof args, "%s", dir);
        else snprintf(args, sizeof args, "%s --delight %s", dir, db);
        setenv("GRIDSURVEY_DELIGHT", how == 0 ? db : "/nonexistent/delight.sqlite", 1);
        json_t *root = recognize_json(args, &rc, NULL, 0);
        CHECK_MSG(rc == 0, "case %d: exit %d", how, rc);
        if (!root) continue;
        CHECK(json_integer_value(json_object_get(json_object_get(root, "recognition"), "candidates")) == 2);
        for (int i = 0; i < scene_a.count; i++) {
            json_t *l = light_near(root, lights_a[i].x, lights_a[i].y);
            CHECK(l != NULL);
            if (!l) continue;
            int known = !strcmp(lights_a[i].bulb, "hps-150w") || !strcmp(lights_a[i].bulb, "mh-250w");
            const char *bulb = json_string_value(json_object_get(l, "bulb"));
            if (known) {
                CHECK(bulb && !strcmp(bulb, lights_a[i].bulb));
                continue;
            }
            /* not in the database: unknown, not a confident wrong answer; the best fit is the
             * runner-up */
            CHECK_MSG(json_is_null(json_object_get(l, "bulb")) && has_flag(l, "unknown"),
                      "light %s: bulb %s, expected null and unknown", lights_a[i].bulb, bulb ? bulb : "null");
            CHECK(json_is_null(json_object_get(l, "technology")));
            CHECK(json_is_null(json_object_get(l, "phase_deg")));
            CHECK(json_number_value(json_object_get(l, "p_value")) < 1e-3);
            CHECK(json_is_object(json_object_get(l, "runner_up")));
        }
        json_decref(root);
    }
    unsetenv("GRIDSURVEY_DELIGHT");
}

static int run1(const char *args, const char *extra)
{
    char cmd[4096];
    snprintf(cmd, sizeof cmd, "%s recognize %s %s", test_bin(), args, extra ? extra : "");
    return test_run(cmd, out, sizeof out);
}

TEST(recognize_cli_bad_inputs_one_line_errors)
{
    cached_delight();
    const char *good = render(&scene_e);   /* the smallest capture: errors come fast */
    char cmd_buf[8192];
    char missing[1024], bad[1024], path[1100], file[1200];
    snprintf(missing, sizeof missing, "%s/no-such-capture", test_tmpdir());
    CHECK(run1(missing, NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "no-such-capture"), "%s", out);

    snprintf(bad, sizeof bad, "%s/bad", test_tmpdir());
    mkdir(bad, 0700);
    snprintf(path, sizeof path, "%s/capture.json", bad);
    FILE *f = fopen(path, "w");
    CHECK(f != NULL);
    if (f) {
        fputs("{\"format\": \"gridsurvey-capture/1\", \"grid_hz\": 50,\n \"K\": 26,\n", f);
        fclose(f);
    }
    CHECK(run1(bad, "--json") == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "capture.json"), "%s", out);

    CHECK(run1(good, "--phases 5") == 2);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "--phases"), "%s", out);
    CHECK(run1(good, "--phases") == 2);
    CHECK_MSG(fx_count_lines(out) == 1, "%s", out);
    CHECK(run1(good, "--min-confidence 1.5") == 2);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "--min-confidence"), "%s", out);
    CHECK(run1(good, "--threshold -1") == 2);
    CHECK_MSG(fx_count_lines(out) == 1, "%s", out);
    CHECK(run1(good, "--transformer-deg abc") == 2);
    CHECK_MSG(fx_count_lines(out) == 1, "%s", out);
    CHECK(run1(good, "--frobnicate") == 2);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "frobnicate"), "%s", out);
    CHECK(run1("", NULL) == 2);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "capture directory"), "%s", out);
    CHECK(run1(good, good) == 2);
    CHECK_MSG(fx_count_lines(out) == 1, "%s", out);
    /* a transformer shift that repeats 0/120/240 */
    CHECK(run1(good, "--phases 6 --transformer-deg 120") == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "transformer"), "%s", out);
    /* a DELIGHT file that is missing or not a database */
    CHECK(run1(good, "--delight /nonexistent/delight.sqlite") == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "delight.sqlite"), "%s", out);
    CHECK(run1(good, "--delight tests/test.h") == 1);
    CHECK_MSG(fx_count_lines(out) == 1, "%s", out);
    /* a DELIGHT without an entry for the capture's grid frequency (only 60 Hz rows) */
    const char *db60 = fx_tmp("only60.sqlite");
    snprintf(cmd_buf, sizeof cmd_buf, "grep -E '^(bulb_id|hps-150w,[^,]*,[^,]*,[^,]*,60),' "
             "%s/delight-export.csv > %s/only60.csv && %s delight import %s/only60.csv --delight %s",
             cache_root(), test_tmpdir(), test_bin(), test_tmpdir(), db60);
    CHECK_MSG(test_run(cmd_buf, out, sizeof out) == 0, "%s", out);
    snprintf(file, sizeof file, "--delight %s", db60);
    CHECK(run1(good, file) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "no usable monochrome entry") && strstr(out, "50 Hz"),
              "%s", out);
    /* --maps naming a regular file */
    snprintf(file, sizeof file, "--maps %s", path);
    CHECK(run1(good, file) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "capture.json"), "%s", out);
    /* a frame file gone missing after capture.json was written */
    char cmd[4096];
    snprintf(cmd, sizeof cmd, "cp -r %s %s/partial && rm %s/partial/frame_003.png", good,
             test_tmpdir(), test_tmpdir());
    CHECK(test_run(cmd, out, sizeof out) == 0);
    snprintf(path, sizeof path, "%s/partial", test_tmpdir());
    CHECK(run1(path, NULL) == 1);
    CHECK_MSG(fx_count_lines(out) == 1 && strstr(out, "frame_003.png"), "%s", out);
    /* and the maps directory of a failed run holds no partial pictures */
    char maps_arg[1300];
    snprintf(maps_arg, sizeof maps_arg, "--maps %s/failmaps", test_tmpdir());
    CHECK(run1(path, maps_arg) == 1);
    snprintf(cmd, sizeof cmd, "ls -A %s/failmaps", test_tmpdir());
    CHECK(test_run(cmd, out, sizeof out) == 0);
    CHECK_MSG(out[0] == '\0', "left behind: %s", out);
}

TEST(recognize_cli_help)
{
    CHECK(run1("--help", NULL) == 0);
    CHECK(strstr(out, "usage: gridsurvey recognize CAPDIR") && strstr(out, "--phases 3|6|continuous") &&
          strstr(out, "--maps DIR") && strstr(out, "--json") && strstr(out, "--min-confidence") &&
          strstr(out, "--transformer-deg") && strstr(out, "--delight"));
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "%s --help", test_bin());
    CHECK(test_run(cmd, out, sizeof out) == 0 && strstr(out, "recognize") && strstr(out, "bench"));
    snprintf(cmd, sizeof cmd, "%s bench --help", test_bin());
    CHECK(test_run(cmd, out, sizeof out) == 0 && strstr(out, "bench recognize"));
    snprintf(cmd, sizeof cmd, "%s bench frobnicate", test_bin());
    CHECK(test_run(cmd, out, sizeof out) == 2 && fx_count_lines(out) == 1);
}

/* The colour of a pure hue at phase 0/120/240: which channel dominates. */
static void check_phase_colour(const unsigned char *p, double phase, const char *what)
{
    int ch = phase == 0 ? 0 : phase == 120 ? 1 : 2;
    int o1 = (ch + 1) % 3, o2 = (ch + 2) % 3;
    CHECK_MSG(p[ch] >= 80 && p[o1] <= p[ch] / 5 && p[o2] <= p[ch] / 5,
              "%s: colour (%d, %d, %d) for phase %g", what, p[0], p[1], p[2], phase);
}

TEST(maps_png_valid_and_phase_hues)
{
    cached_delight();
    const char *dir = render(&scene_a);
    char args[2048];
    snprintf(args, sizeof args, "%s --maps %s/maps", dir, test_tmpdir());
    int rc;
    char err[4096];
    json_t *root = recognize_json(args, &rc, err, sizeof err);
    CHECK_MSG(rc == 0, "exit %d: %s", rc, err);
    CHECK_MSG(quiet_stderr(err), "stderr not empty: %s", err);
    json_decref(root);
    int s = doc_scale(scene_a.width, scene_a.height);
    int want_w = s * scene_a.width > 480 ? s * scene_a.width : 480;
    static const char *const names[3] = {"phase_map.png", "bulb_map.png", "confidence_map.png"};
    unsigned char *px[3] = {NULL, NULL, NULL};
    int w[3] = {0, 0, 0}, h[3] = {0, 0, 0};
    for (int m = 0; m < 3; m++) {
        char path[1200];
        snprintf(path, sizeof path, "%s/maps/%s", test_tmpdir(), names[m]);
        px[m] = read_png(path, &w[m], &h[m]);
        CHECK_MSG(w[m] == want_w && h[m] > s * scene_a.height + 40, "%s: %dx%d, expected %d wide and a legend",
                  names[m], w[m], h[m], want_w);
        if (!px[m] || w[m] != want_w) {
            for (int k = 0; k <= m; k++) free(px[k]);
            return;
        }
        /* far from every light: black (below the threshold) */
        const unsigned char *bg = map_at(px[m], w[m], s, 2, 60);
        CHECK_MSG(bg[0] == 0 && bg[1] == 0 && bg[2] == 0, "%s: background (%d, %d, %d)", names[m],
                  bg[0], bg[1], bg[2]);
        /* the legend band holds text (dark pixels on white) */
        size_t dark = 0;
        for (int y = s * scene_a.height; y < h[m]; y++)
            for (int x = 0; x < w[m]; x++) dark += px[m][3 * ((size_t)y * (size_t)w[m] + (size_t)x)] < 100;
        CHECK_MSG(dark > 500, "%s: legend has %zu dark pixels", names[m], dark);
    }
    for (int i = 0; i < scene_a.count; i++) {
        const light *t = &lights_a[i];
        check_phase_colour(map_at(px[0], w[0], s, t->x, t->y), t->phase_deg, t->bulb);
        const unsigned char *c = map_at(px[1], w[1], s, t->x, t->y);
        CHECK_MSG(!(c[0] == c[1] && c[1] == c[2]), "bulb map: %s grey", t->bulb);
        for (int j = 0; j < i; j++) {
            const unsigned char *d = map_at(px[1], w[1], s, lights_a[j].x, lights_a[j].y);
            /* distinct bulbs in distinct hues (brightness may differ) */
            double hc = hue_deg(c), hd = hue_deg(d);
            CHECK_MSG(!(fabs(circ_diff_deg(hc, hd)) < 1.0 && abs(c[0] - d[0]) < 8),
                      "bulb map: %s and %s share a colour", t->bulb, lights_a[j].bulb);
        }
        const unsigned char *q = map_at(px[2], w[2], s, t->x, t->y);   /* viridis near 1: yellow */
        CHECK_MSG(q[0] > 150 && q[1] > 150 && q[2] < 120, "confidence map: %s (%d, %d, %d)", t->bulb,
                  q[0], q[1], q[2]);
    }
    for (int m = 0; m < 3; m++) free(px[m]);
    const char *path = fx_tmp("maps/signals.png");
    int sw = 0, sh = 0;
    unsigned char *sp = read_png(path, &sw, &sh);
    CHECK(sw == 1500 && sh == 1500);
    if (sp) {
        /* curves and points in colour, not an empty canvas */
        size_t coloured = 0;
        for (size_t k = 0; k < (size_t)sw * (size_t)sh; k++) {
            const unsigned char *p = sp + 3 * k;
            coloured += abs(p[0] - p[1]) > 40 || abs(p[1] - p[2]) > 40;
        }
        CHECK_MSG(coloured > 20000, "signals.png: %zu coloured pixels", coloured);
    }
    free(sp);
}

TEST(maps_no_lights_still_written)
{
    cached_delight();
    const char *dir = render(&scene_e);
    char args[2048];
    snprintf(args, sizeof args, "%s --maps %s/maps", dir, test_tmpdir());
    int rc;
    char err[4096];
    json_t *root = recognize_json(args, &rc, err, sizeof err);
    CHECK_MSG(rc == 0, "exit %d: %s", rc, err);
    if (root) {
        CHECK(json_array_size(json_object_get(root, "lights")) == 0);
        CHECK(json_integer_value(json_object_get(json_object_get(root, "summary"), "lights")) == 0);
    }
    json_decref(root);
    const char *path = fx_tmp("maps/phase_map.png");
    int w = 0, h = 0;
    unsigned char *px = read_png(path, &w, &h);
    int s = doc_scale(scene_e.width, scene_e.height);
    CHECK(w == s * scene_e.width && h > s * scene_e.height);
    if (px) {
        size_t lit = 0;
        for (int y = 0; y < s * scene_e.height; y++)
            for (int x = 0; x < s * scene_e.width; x++) {
                const unsigned char *p = px + 3 * ((size_t)y * (size_t)w + (size_t)x);
                lit += p[0] || p[1] || p[2];
            }
        /* noise alone crosses 5 sigma in ~3e-7 of the pixels: nothing is drawn */
        CHECK_MSG(lit == 0, "%zu map pixels drawn in an empty scene", lit);
    }
    free(px);
    path = fx_tmp("maps/signals.png");
    int sw = 0, sh = 0;
    unsigned char *sp = read_png(path, &sw, &sh);
    CHECK(sw == 1500 && sh == 620);
    free(sp);
}

/* ------------------------------------------------------------ maps, in process */

/* A capture built in memory: sky 0.5 DN per cycle, read noise 2 DN at 40 cycles, three lights of
 * 3x3 pixels (weights 1, 0.5, 0.25) of known bulbs and phases. */
typedef struct {
    int x, y;
    const char *bulb;
    double phase_deg, flux;
} mem_light;

static const mem_light mem_lights[3] = {
    {12, 14, "hps-150w", 240, 60}, {40, 20, "mh-250w", 0, 50}, {25, 45, "cfl-23w", 120, 50}};

static gs_status mem_capture(const gs_delight *d, gs_capture *cap)
{
    memset(cap, 0, sizeof *cap);
    cap->grid_hz = 50;
    cap->K = 13;
    cap->bands = 3;
    cap->width = 64;
    cap->height = 56;
    cap->saturation_dn = 65536;
    cap->black_level_dn = 100;
    cap->read_noise_dn = 2;
    cap->locked = 1;
    gs_status s = gs_capture_alloc(cap);
    if (s != GS_OK) return s;
    const double cycles = 40.0;
    size_t np = (size_t)cap->width * (size_t)cap->height;
    double *v = calloc(np * 13 * 3, sizeof *v);
    if (!v) return GS_ENOMEM;
    for (int k = 0; k < 13; k++) cap->frames[k].cycles = cycles;
    for (int i = 0; i < 3; i++) {
        const gs_bulb *b = gs_delight_find(d, mem_lights[i].bulb, 50, 3);
        double t[3 * 13];
        if (!b || gs_brf_integrate(&b->brf, gs_phase_to_shift(mem_lights[i].phase_deg), 13, t) != GS_OK) {
            free(v);
            return GS_ENOTFOUND;
        }
        for (int dy = -1; dy <= 1; dy++)
            for (int dx = -1; dx <= 1; dx++) {
                double w = (dx ? 0.5 : 1.0) * (dy ? 0.5 : 1.0);
                size_t p = (size_t)(mem_lights[i].y + dy) * (size_t)cap->width + (size_t)(mem_lights[i].x + dx);
                for (int band = 0; band < 3; band++)
                    for (int k = 0; k < 13; k++)
                        v[((size_t)k * np + p) * 3 + (size_t)band] +=
                            w * mem_lights[i].flux * b->chroma[band] * t[band * 13 + k];
            }
    }
    uint64_t seed = 99;
    for (size_t q = 0; q < np * 13 * 3; q++) {
        /* Box-Muller on one splitmix64 draw: u1 from its top 53 bits, u2 from its low 11 */
        uint64_t z = fx_rng_next(&seed);
        double u1 = ((double)(z >> 11) + 0.5) * 0x1p-53, u2 = ((double)(z & 0x7ff) + 0.5) / 2048.0;
        double n = sqrt(-2.0 * log(u1)) * cos(6.283185307179586 * u2);
        double raw = 100.0 + cycles * (0.5 + v[q]) + 2.0 * n;
        cap->raw[q] = (unsigned short)(raw < 0 ? 0 : raw > 65535 ? 65535 : lround(raw));
    }
    free(v);
    return GS_OK;
}

static const char *matcher_bulb_id(const rec_matcher *m, int i)
{
    const gs_bulb *b = i >= 0 ? rec_matcher_bulb(m, (size_t)i) : NULL;
    return b ? b->id : "none";
}

TEST(maps_fast_path_matches_general)
{
    /* Without HDR maps and shot noise the per-pixel pass takes an integer fast path; with an
     * all-zero HDR map it takes the general one. Same capture, same maps. */
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, 512));
    rec_matcher *m = NULL;
    CHECK_OK(rec_matcher_new(d, 50, 3, 13, NULL, &m));
    gs_capture cap;
    CHECK_OK(mem_capture(d, &cap));
    rec_pixel_maps a, b;
    CHECK_OK(rec_pixel_maps_compute(&cap, m, NULL, NULL, &a));
    CHECK_OK(gs_capture_alloc_hdr(&cap));
    CHECK_OK(rec_pixel_maps_compute(&cap, m, NULL, NULL, &b));
    size_t np = (size_t)cap.width * (size_t)cap.height, differ = 0;
    for (size_t p = 0; p < np && a.state && b.state; p++)
        differ += a.state[p] != b.state[p] || a.bulb[p] != b.bulb[p] ||
                  fabsf(a.brightness[p] - b.brightness[p]) > 1e-4f * (1.0f + fabsf(a.brightness[p]));
    CHECK_MSG(differ == 0, "%zu pixels differ", differ);
    /* the light centres: the rendered bulb and phase (Eq. 7 per pixel) */
    for (int i = 0; i < 3 && a.state; i++) {
        size_t p = (size_t)mem_lights[i].y * (size_t)cap.width + (size_t)mem_lights[i].x;
        CHECK_MSG(a.state[p] == REC_PIX_MATCHED && !strcmp(matcher_bulb_id(m, a.bulb[p]), mem_lights[i].bulb) &&
                      fabs(circ_diff_deg(a.phase_deg[p], mem_lights[i].phase_deg)) < 1e-3 && a.confidence[p] > 0.8,
                  "light %s: state %d bulb %s phase %g conf %g", mem_lights[i].bulb, a.state[p],
                  matcher_bulb_id(m, a.bulb[p]), a.phase_deg[p], a.confidence[p]);
        /* brightness = the rendered flux at the centre pixel (weight 1), background removed */
        CHECK_NEAR(a.brightness[p], mem_lights[i].flux, 0.02 * mem_lights[i].flux);
    }
    CHECK(a.mapped >= 9 * 3 - 6 && a.mapped <= 9 * 3 + 3);   /* the lights' pixels, no sky */
    rec_pixel_maps_release(&a);
    rec_pixel_maps_release(&b);
    rec_pixel_maps_release(NULL);
    gs_capture_release(&cap);
    rec_matcher_free(m);
    gs_delight_free(d);
}

TEST(maps_saturated_core_white_and_bad_arguments)
{
    gs_delight *d = gs_delight_new();
    CHECK_OK(gs_delight_generate(d, 512));
    rec_matcher *m = NULL;
    CHECK_OK(rec_matcher_new(d, 50, 3, 13, NULL, &m));
    gs_capture cap;
    CHECK_OK(mem_capture(d, &cap));
    /* saturate the brightest light's centre: the level just below its peak sample */
    size_t np = (size_t)cap.width * (size_t)cap.height;
    size_t pc = (size_t)mem_lights[0].y * (size_t)cap.width + (size_t)mem_lights[0].x;
    unsigned peak = 0;
    for (int k = 0; k < 13; k++)
        for (int band = 0; band < 3; band++) {
            unsigned r = cap.raw[((size_t)k * np + pc) * 3 + (size_t)band];
            peak = r > peak ? r : peak;
        }
    cap.saturation_dn = peak - 1;   /* only that pixel reaches it */
    rec_pixel_maps pm;
    CHECK_OK(rec_pixel_maps_compute(&cap, m, NULL, NULL, &pm));
    if (pm.state) {
        CHECK(pm.state[pc] == REC_PIX_SATURATED && pm.bulb[pc] == -1);
        const char *path = fx_tmp("phase.png");
        CHECK_OK(rec_map_write_phase_png(&pm, path));
        int w = 0, h = 0;
        unsigned char *px = read_png(path, &w, &h);
        int s = rec_map_scale(cap.width, cap.height);
        CHECK(s == doc_scale(cap.width, cap.height) && w == s * cap.width);
        if (px) {
            const unsigned char *c = map_at(px, w, s, mem_lights[0].x, mem_lights[0].y);
            CHECK_MSG(c[0] == 255 && c[1] == 255 && c[2] == 255, "saturated pixel (%d, %d, %d)", c[0], c[1], c[2]);
            /* a neighbour, unsaturated: blue for 240 deg */
            check_phase_colour(map_at(px, w, s, mem_lights[0].x + 1, mem_lights[0].y), 240, "neighbour");
        }
        free(px);
        /* unwritable paths fail cleanly, leaving nothing behind */
        CHECK(rec_map_write_phase_png(&pm, "/nonexistent-dir/phase.png") == GS_EIO);
        CHECK(rec_map_write_bulb_png(&pm, m, "/nonexistent-dir/bulb.png") == GS_EIO);
        CHECK(rec_map_write_confidence_png(&pm, "/nonexistent-dir/c.png") == GS_EIO);
    }
    rec_pixel_maps_release(&pm);
    /* bad arguments */
    rec_map_opts o;
    rec_map_opts_default(&o);
    o.threshold_sigma = 0.0;
    CHECK(rec_pixel_maps_compute(&cap, m, NULL, &o, &pm) == GS_EINVAL && pm.state == NULL);
    o.threshold_sigma = NAN;
    CHECK(rec_pixel_maps_compute(&cap, m, NULL, &o, &pm) == GS_EINVAL);
    rec_matcher *mono = NULL;
    CHECK_OK(rec_matcher_new(d, 50, 1, 13, NULL, &mono));
    CHECK(rec_pixel_maps_compute(&cap, mono, NULL, NULL, &pm) == GS_EINVAL);
    rec_matcher *k26 = NULL;   /* a matcher for another K: refused, not read out of bounds */
    CHECK_OK(rec_matcher_new(d, 50, 3, 26, NULL, &k26));
    CHECK(rec_pixel_maps_compute(&cap, k26, NULL, NULL, &pm) == GS_EINVAL && strstr(gs_detail(), "K = 13"));
    rec_matcher_free(k26);
    CHECK(rec_pixel_maps_compute(NULL, m, NULL, NULL, &pm) == GS_EINVAL);
    rec_catalog cat;
    memset(&cat, 0, sizeof cat);
    CHECK(rec_plot_signals(m, &cat, NULL, 0, "/tmp/x.png", NULL) == GS_EINVAL);
    CHECK(rec_plot_signals(m, &cat, NULL, 4, "/nonexistent-dir/s.png", NULL) == GS_EIO);
    rec_matcher_free(mono);
    gs_capture_release(&cap);
    rec_matcher_free(m);
    gs_delight_free(d);
}
