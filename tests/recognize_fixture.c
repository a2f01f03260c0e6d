/* recognize_fixture.c - captures for the tests of `gridsurvey recognize`; the contract is in
 * tests/recognize_fixture.h. */
#include "tests/recognize_fixture.h"

#include "recognize/internal.h"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <libgen.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

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

/* Scene A: RGB, 50 Hz, K = 26, six technologies on the three phases. */
const recfx_light recfx_lights_a[] = {
    {30.3, 25.6, 400, "hps-150w", 0},          {80.7, 30.2, 300, "mh-250w", 120},
    {130.1, 22.9, 300, "cfl-23w", 240},        {40.4, 85.5, 300, "fl-t8-36w-tri", 120},
    {95.2, 90.1, 300, "led-gu10-5w-cap", 240}, {140.6, 80.8, 500, "inc-a60-25w-230v", 0},
};
const recfx_scene recfx_scene_a = {"a", 50, 26, 3, 160, 120, 7, recfx_lights_a, 6};

/* Scene B: monochrome, 60 Hz, K = 22 (the ACam's 60 Hz K). */
const recfx_light recfx_lights_b[] = {
    {20.6, 20.3, 400, "hps-150w", 0},   {90.2, 25.7, 300, "mh-250w", 240},
    {30.4, 70.1, 300, "cfl-23w", 120},  {100.8, 72.4, 300, "fl-t8-36w-tri", 0},
};
const recfx_scene recfx_scene_b = {"b", 60, 22, 1, 128, 96, 5, recfx_lights_b, 4};

/* Scene C: phases off the 0/120/240 set (each nearer to the set than its +180 twin, which a
 * flicker cannot tell apart: docs/design.md). */
const recfx_light recfx_lights_c[] = {
    {30.3, 25.6, 400, "hps-150w", 17},     {90.7, 30.2, 300, "mh-250w", 95},
    {40.4, 70.5, 300, "fl-t8-36w-tri", 225}, {95.2, 75.1, 300, "cfl-23w", 250},
};
const recfx_scene recfx_scene_c = {"c", 50, 26, 3, 128, 96, 11, recfx_lights_c, 4};

/* Scene D: a delta-wye transformer's 30 deg shift. */
const recfx_light recfx_lights_d[] = {
    {30.3, 25.6, 400, "hps-150w", 30},     {90.7, 30.2, 300, "mh-250w", 150},
    {40.4, 70.5, 300, "fl-t8-36w-tri", 270}, {95.2, 75.1, 300, "cfl-23w", 120},
};
const recfx_scene recfx_scene_d = {"d", 50, 26, 3, 128, 96, 13, recfx_lights_d, 4};

/* Scene E: sky and noise only. */
const recfx_scene recfx_scene_e = {"e", 50, 8, 1, 64, 48, 17, NULL, 0};

const char *recfx_cache_root(void)
{
    static char root[512];
    snprintf(root, sizeof root, "%s", test_tmpdir());
    return dirname(root);
}

const char *recfx_cached_delight(void)
{
    static char db[1100];
    char lock_path[1200];
    snprintf(db, sizeof db, "%s/delight.sqlite", recfx_cache_root());
    snprintf(lock_path, sizeof lock_path, "%s.lock", db);
    int lock = fx_lock(lock_path);   /* tests that run at once make it once */
    if (!fx_exists(db)) {
        char cmd[4096];
        snprintf(cmd, sizeof cmd, "%s delight generate -o %s.tmp && mv %s.tmp %s", test_bin(), db, db, db);
        CHECK_MSG(test_run(cmd, out, sizeof out) == 0, "delight generate: %s", out);
    }
    if (lock >= 0) close(lock);
    setenv("GRIDSURVEY_DELIGHT", db, 1);
    return db;
}

const char *recfx_render(const recfx_scene *s)
{
    static char dir[1024];
    char path[1100], cmd[8192];
    const char *root = recfx_cache_root();
    snprintf(dir, sizeof dir, "%s/capture-%s", root, s->key);
    snprintf(path, sizeof path, "%s/capture.json", dir);
    /* tests that run at once render each capture once, and none reads one being rendered (a
     * frame being rewritten was read short) */
    snprintf(cmd, sizeof cmd, "%s/render.lock", root);
    int lock = fx_lock(cmd);
    if (fx_exists(path)) {
        if (lock >= 0) close(lock);
        return dir;
    }
    /* the DELIGHT export, once per run */
    char csv[1100];
    snprintf(csv, sizeof csv, "%s/delight-export.csv", root);
    if (!fx_exists(csv)) {
        char tmp[1200];
        snprintf(tmp, sizeof tmp, "%s.tmp", csv);
        snprintf(cmd, sizeof cmd, "%s delight export --delight %s -o %s && mv %s %s", test_bin(),
                 recfx_cached_delight(), tmp, tmp, csv);
        CHECK_MSG(test_run(cmd, out, sizeof out) == 0, "delight export: %s", out);
    }
    char script[1100];
    snprintf(script, sizeof script, "%s/render.py", root);
    fx_write_text(script, render_py);
    char spec[1200];
    snprintf(spec, sizeof spec, "%s/spec-%s.json", root, s->key);
    FILE *f = fopen(spec, "w");
    CHECK(f != NULL);
    if (!f) {
        if (lock >= 0) close(lock);
        return dir;
    }
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
    if (lock >= 0) close(lock);
    return dir;
}

/* The run and the JSON, with the exit status in *rc and stderr in err (may be NULL). */
static json_t *recognize_json(const char *args, int *rc, char *err, size_t err_size)
{
    char errf[1100], cmd[4096];
    snprintf(errf, sizeof errf, "%s/stderr.txt", test_tmpdir());
    snprintf(cmd, sizeof cmd, "%s recognize %s --format json 2>%s", test_bin(), args, errf);
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

json_t *recfx_recognize_ok(const char *args, int quiet)
{
    int rc;
    char err[4096];
    json_t *root = recognize_json(args, &rc, err, sizeof err);
    CHECK_MSG(rc == 0, "exit %d: %s", rc, err);
    if (quiet) CHECK_MSG(recfx_quiet_stderr(err), "stderr not empty: %s", err);
    return root;
}

json_t *recfx_recognize_scene(const recfx_scene *s, const char *flags, int maps, int quiet)
{
    recfx_cached_delight();
    const char *dir = recfx_render(s);
    char args[3000];
    snprintf(args, sizeof args, "%s %s%s%s%s", dir, flags, maps ? " --maps " : "",
             maps ? test_tmpdir() : "", maps ? "/maps" : "");
    return recfx_recognize_ok(args, quiet);
}

int recfx_quiet_stderr(const char *err)
{
    if (fx_sanitized())
        return !strstr(err, "gridsurvey") && !strstr(err, "PLPLOT") && !strstr(err, "ERROR") &&
               !strstr(err, "arning");
    return err[0] == '\0';
}

json_t *recfx_light_near(json_t *root, double x, double y)
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

int recfx_has_flag(json_t *l, const char *name)
{
    size_t i;
    json_t *f;
    json_array_foreach(json_object_get(l, "flags"), i, f)
        if (json_is_string(f) && !strcmp(json_string_value(f), name)) return 1;
    return 0;
}

double recfx_circ_diff_deg(double a, double b)
{
    double d = fmod(a - b, 360.0);
    if (d > 180.0) d -= 360.0;
    if (d < -180.0) d += 360.0;
    return d;
}

double recfx_hue_deg(const unsigned char *p)
{
    double r = p[0], g = p[1], b = p[2];
    double mx = fmax(r, fmax(g, b)), mn = fmin(r, fmin(g, b)), c = mx - mn;
    if (c < 1.0) return NAN;
    double h = mx == r ? fmod((g - b) / c, 6.0) : mx == g ? (b - r) / c + 2.0 : (r - g) / c + 4.0;
    h *= 60.0;
    return h < 0 ? h + 360.0 : h;
}

unsigned char *recfx_read_png(const char *path, int *w, int *h)
{
    size_t size = 0;
    unsigned char *buf = (unsigned char *)fx_read_file(path, &size);
    CHECK_MSG(buf != NULL, "%s missing", path);
    CHECK(size > 33);
    if (!buf || size <= 33) {
        free(buf);
        return NULL;
    }
    CHECK_MSG(!memcmp(buf, "\x89PNG\r\n\x1a\n", 8) && !memcmp(buf + 12, "IHDR", 4), "%s: not a PNG", path);
    *w = (int)((unsigned)buf[16] << 24 | (unsigned)buf[17] << 16 | (unsigned)buf[18] << 8 | buf[19]);
    *h = (int)((unsigned)buf[20] << 24 | (unsigned)buf[21] << 16 | (unsigned)buf[22] << 8 | buf[23]);
    CHECK_MSG(buf[24] == 8 && buf[25] == 2, "%s: bit depth %d colour type %d, expected 8-bit RGB",
              path, buf[24], buf[25]);
    unsigned char *px = malloc((size_t)*w * (size_t)*h * 3);
    gs_status s = px ? gs_png_decode(buf, size, path, "", *w, *h, 3, 8, px) : GS_ENOMEM;
    CHECK_OK(s);
    free(buf);
    if (s != GS_OK) {
        free(px);
        return NULL;
    }
    return px;
}

const unsigned char *recfx_map_at(const unsigned char *px, int png_w, int s, double x, double y)
{
    int xi = (int)lround(x), yi = (int)lround(y);
    return px + 3 * ((size_t)(s * yi + s / 2) * (size_t)png_w + (size_t)(s * xi + s / 2));
}

int recfx_doc_scale(int w, int h)
{
    int s = 640 / (w > h ? w : h);
    return s < 1 ? 1 : s > 16 ? 16 : s;
}

void recfx_check_phase_colour(const unsigned char *p, double phase, const char *what)
{
    int ch = phase == 0 ? 0 : phase == 120 ? 1 : 2;
    int o1 = (ch + 1) % 3, o2 = (ch + 2) % 3;
    CHECK_MSG(p[ch] >= 80 && p[o1] <= p[ch] / 5 && p[o2] <= p[ch] / 5,
              "%s: colour (%d, %d, %d) for phase %g", what, p[0], p[1], p[2], phase);
}
