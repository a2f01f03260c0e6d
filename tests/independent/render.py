#!/usr/bin/python3
"""Independent forward model of a coded-exposure AC capture (gridsurvey-capture/1).

Written from the paper (Sheinin, Schechner, Kutulakos, "Computational Imaging on the Electric
Grid", CVPR 2017, Sec. 2-4) and docs/formats.md only: nothing here comes from the repository's
simulator (capture/sim.c) or calls the C code, except that the bulb response functions (BRFs)
are *data* read from the CSV that `gridsurvey delight export -o FILE` writes (docs/delight.md).

Model, per light l, band sigma, frame k (paper Eqs. 3-6):

    I_l(t, sigma) = Ibar_l(sigma) B_l(t - s_l, sigma)                       (Eq. 4, delayed)
    s_l = phi_l / pi  cycles mod 1   (grid phase phi; 0/120/240 deg -> 0, 2/3, 1/3 cycle,
                                      positive = delayed; docs/design.md)
    b_l[sigma, k] = mean of B_l(t - s_l, sigma) over t in [k/K, (k+1)/K) cycles     (Eq. 5)
    i_l[sigma, k] = brightness * Q(sigma) * b_l[sigma, k]                   (Eq. 6)

Frame k integrates the window [k Delta/K, (k+1) Delta/K) of each of C flicker cycles
(Delta = 1/(2 f), Eq. 1).  The window means are computed here from the BRF's own DFT: the n
stored samples (sample j at t = j/n of a cycle, mean 1 per band) are read as the trigonometric
polynomial through them, and the window mean of each harmonic exp(2 pi i m t) delayed by s is
integrated in closed form.  `--selftest` checks this against a dense trapezoid rule on the
linearly interpolated samples.

Signal budget ("electrons per light"): E = the expected total photo-electrons of one light summed
over all K frames, all bands and all pixels of the capture, before extinction, scintillation and
noise.  The expected electrons of light l in frame k, band sigma, pixel p are then

    mu[p, k, sigma] = E * g_ext(sigma) * Q(sigma) * b[sigma, k] / K * S_k * psf(p)

with psf the pixel-integrated Gaussian (sums to 1 over the plane), g_ext the optional per-band
extinction gain (1 = none) and S_k the optional log-normal scintillation factor of the light in
frame k (exp(s z - s^2/2), z ~ N(0,1), mean 1, independent per light and frame, common to the
bands: not mains-locked).  Because each band's BRF has mean 1 over the cycle and sum Q = 1,
sum over k, sigma, p of mu = E exactly (without extinction / scintillation).  C only sets the
`cycles` of capture.json (the recogniser divides by it): the budget does not depend on it.

Noise (per pixel, per frame, per band): electrons n ~ Poisson(sky + sum_l mu_l), then
raw = black_level + n / gain + read_noise_dn * N(0, 1), rounded to the nearest integer and
clipped to [0, min(saturation, 65535)].

Outputs in OUTDIR: capture.json, frame_000.png ... (16-bit, colour type 0 for 1 band, 2 for RGB,
written here with zlib + struct), truth.json (every light; see `truth_doc` below).
"""

import argparse
import json
import math
import os
import re
import struct
import sys
import zlib

import numpy as np

FLICKER_DIR = "/work/shared/data/flicker"

# Technology of each real recording (shared/data/README.md table), as a DELIGHT type name
# (docs/delight.md) plus the README's wording.
RECORDING_TECH = {
    "Sylvania_60W": ("incandescent", "incandescent"),
    "Feit 60W": ("incandescent", "incandescent"),
    "CFL": ("cfl", "compact fluorescent, electronic ballast"),
    "GE_Align_PM": ("led_capacitor", "LED, capacitor-filtered driver"),
    "Old_IKEA_LED": ("led_capacitor", "LED, capacitor-filtered driver"),
    "Ecosmart_Candelabra_LED": ("led_capacitor", "LED, small capacitor (sawtooth)"),
    "Soraa_Healthy": ("led_capacitor", "LED, small capacitor (sawtooth)"),
    "GE_Classic_LED": ("led_capacitor", "LED, well filtered, multi-harmonic"),
    "IKEA_Lunnom": ("led_capacitor", "LED, essentially DC"),
    "Hue_Color_Day": ("led_pwm", "LED, PWM at ~1 kHz, not locked to the mains"),
}


# --------------------------------------------------------------------------------------------
# DELIGHT CSV (docs/delight.md): one row per bulb and band
# --------------------------------------------------------------------------------------------

class Bulb:
    """One DELIGHT entry: id, technology, grid_hz, sensor, reference, per-band BRF samples."""

    def __init__(self, bulb_id, tech, grid_hz, sensor, ref):
        self.id, self.tech, self.grid_hz, self.sensor, self.ref = bulb_id, tech, grid_hz, sensor, ref
        self.bands = []          # 'mono' or 'R', 'G', 'B'
        self.chroma = []         # Q(sigma), Eq. 6
        self.brf = []            # list of 1-D arrays, n samples per cycle, mean 1

    def finish(self):
        self.chroma = np.asarray(self.chroma, float)
        self.brf = np.vstack(self.brf)   # (bands, n); all bands of one entry share n here
        return self


def read_delight_csv(path):
    """Parse the export CSV; returns a list of Bulb (all entries, every grid and sensor)."""
    bulbs, cur, key = [], None, None
    with open(path, encoding="utf-8-sig") as f:
        header = f.readline().rstrip("\r\n").split(",")
        if header[:9] != ["bulb_id", "type", "name", "watts", "grid_hz", "sensor", "band",
                          "chromaticity", "n"]:
            raise SystemExit(f"{path}: not a DELIGHT export CSV (header {header[:9]})")
        for lineno, line in enumerate(f, 2):
            cells = line.rstrip("\r\n").split(",")
            if len(cells) < 9:
                continue
            bid, tech, _name, _w, ghz, sensor_ref, band, chroma, n = cells[:9]
            n = int(n)
            vals = np.array(cells[9:9 + n], float)
            if vals.size != n:
                raise SystemExit(f"{path}:{lineno}: expected {n} samples, got {vals.size}")
            sensor, _, ref = sensor_ref.partition("/")
            k = (bid, int(ghz), sensor)
            if k != key:
                cur = Bulb(bid, tech, int(ghz), sensor, ref or "voltage")
                bulbs.append(cur)
                key = k
            cur.bands.append(band)
            cur.chroma.append(float(chroma))
            cur.brf.append(vals)
    return [b.finish() for b in bulbs]


def candidate_bulbs(bulbs, grid_hz, nbands):
    """Entries Eq. 7 can use for this capture: same grid, 1 band = photodiode, 3 = rgb,
    mains-locked with a voltage reference (docs/recognize-cli.md, --delight)."""
    sensor = "photodiode" if nbands == 1 else "rgb"
    return [b for b in bulbs
            if b.grid_hz == grid_hz and b.sensor == sensor and len(b.bands) == nbands
            and b.ref == "voltage"]


# --------------------------------------------------------------------------------------------
# Eq. 5: window means of a delayed periodic BRF
# --------------------------------------------------------------------------------------------

def harmonics(brf):
    """DFT coefficients c (bands, M) and integer harmonics m (M) of B(t) = sum_m c_m exp(2 pi i m t),
    brf (bands, n) samples at t = j/n cycles read as the trigonometric polynomial through them
    (|m| < n/2; an even-n Nyquist term split symmetrically, i.e. read as a cosine)."""
    brf = np.atleast_2d(np.asarray(brf, float))
    n = brf.shape[1]
    c = np.fft.fft(brf, axis=1) / n
    m = np.fft.fftfreq(n, 1.0 / n)                        # integer harmonics, -n/2 .. n/2-1
    if n % 2 == 0:                                        # Nyquist: cos(pi n t) read as a cosine
        c[:, n // 2] *= 0.5
        c = np.concatenate([c, c[:, n // 2:n // 2 + 1]], axis=1)
        m = np.concatenate([m, [n / 2]])
    return c, m


def interval_means(m, a, b):
    """Mean of exp(2 pi i m u) over u in [a, b] (cycles), for harmonics m (M) and intervals a, b
    (arrays of one shape S): (S..., M)."""
    a, b = np.asarray(a, float)[..., None], np.asarray(b, float)[..., None]
    x = 2j * np.pi * m * (b - a)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(m == 0, 1.0, (np.exp(x) - 1.0) / np.where(m == 0, 1.0, x))
    return np.exp(2j * np.pi * m * a) * r


def window_means(brf, K, shift, frame_factors=None):
    """Mean of B(t - shift) over each window [k/K, (k+1)/K) of a cycle (Eq. 5).

    brf: (bands, n) samples (see harmonics).  shift: cycles (positive = delayed), scalar or 1-D
    array of S shifts.  frame_factors: None (Eq. 5's regular windows) or (M, K), each frame's
    mean over its exposure of its windows' interval_means (free running: free_running_factors).
    Returns (bands, K) for a scalar shift, else (S, bands, K)."""
    c, m = harmonics(brf)
    if frame_factors is None:
        k = np.arange(K)
        E = interval_means(m, k / K, (k + 1) / K).T                  # (M, K)
    else:
        E = frame_factors
    shifts = np.atleast_1d(np.asarray(shift, float))
    D = np.exp(-2j * np.pi * np.outer(shifts, m))                      # delay ramp (S, M)
    # out[s, b, k] = sum_m c[b, m] D[s, m] E[m, k]
    out = np.einsum("bm,sm,mk->sbk", c, D, E).real
    return out[0] if np.ndim(shift) == 0 else out


# --------------------------------------------------------------------------------------------
# Free running (paper Sec. 6; docs/formats.md window_half_period_s, window_drift_windows): the
# windows are timed with a fixed period P from the exposure's first crossing, on a real grid
# --------------------------------------------------------------------------------------------

MAINS_DIR = "/work/shared/data/mains"


def mains_crossings(name):
    """Zero crossings (s) of a mains WAV (shared/data/mains, 16-bit mono): each sign change of
    the waveform, linearly interpolated.  Crossing i is the start of flicker cycle i."""
    from mains_oracle import read_wav
    path = name if os.path.exists(name) else os.path.join(MAINS_DIR, name if name.endswith(".wav") else name + ".wav")
    if not os.path.exists(path):
        raise SystemExit(f"--free-running {name!r}: no such file (looked in {MAINS_DIR})")
    x, rate = read_wav(path)
    s = np.signbit(x)
    j = np.nonzero(s[1:] != s[:-1])[0]
    return (j + x[j] / (x[j] - x[j + 1])) / rate, os.path.basename(path)


def free_running_frames(tc, m, K, C, readout, period, first=64):
    """The K frames of a free-running capture on the grid whose crossings are tc: frame k starts
    at crossing s_k = first + k (C + readout); its window k opens at t0 + c P + k P / K for
    c = 0..C-1 and stays open P / K, P the nominal half period (period 'nominal', 1/(2 f) of
    the grid's nominal f, given as a number) or the mean of the 64 half periods before s_k
    ('measured', as the firmware does).  The flicker cycle u(t) runs linearly from crossing to
    crossing (u(tc[i]) = i).  Returns the factors (M, K) for window_means (each frame's mean over
    its C windows of interval_means) and per frame (P, the mean frequency C / (2 (t_C - t_0)),
    the range over even c and c = C of the window's offset c - (u(t0 + c P) - s_k), in windows).
    (Each window's mean is taken uniformly in u: a window that straddles a crossing, where the
    slope of u changes by the half periods' ratio, ~1e-3, is off by less than that.)"""
    n = len(tc)
    idx = np.arange(n, dtype=float)
    F = np.empty((len(m), K), complex)
    meta = []
    cyc = np.arange(C + 1)
    for k in range(K):
        s0 = first + k * (C + readout)
        if s0 + C + 1 >= n or s0 < 64:
            raise SystemExit(f"free running: the recording has {n} crossings, frame {k} needs {s0 + C + 2}")
        t0 = tc[s0]
        P = (tc[s0] - tc[s0 - 64]) / 64 if period == "measured" else float(period)
        ta = t0 + cyc[:C] * P + k * P / K
        ua, ub = np.interp(ta, tc, idx) - s0, np.interp(ta + P / K, tc, idx) - s0
        F[:, k] = interval_means(m, ua, ub).mean(axis=0)
        # the offset at the crossings of one polarity (even c) and the exposure's end, as
        # docs/formats.md defines window_drift_windows
        c1 = cyc[(cyc % 2 == 0) | (cyc == C)]
        off = c1 - (np.interp(t0 + c1 * P, tc, idx) - s0)
        meta.append((P, C / (2 * (tc[s0 + C] - t0)), K * float(off.max() - off.min())))
    return F, meta


def window_means_trapezoid(brf, K, shift, sub=4096):
    """Reference for the self-test: dense trapezoid rule on the linearly interpolated samples."""
    brf = np.atleast_2d(np.asarray(brf, float))
    n = brf.shape[1]
    out = np.empty((brf.shape[0], K))
    for k in range(K):
        t = np.linspace(k / K, (k + 1) / K, sub + 1)
        u = ((t - shift) % 1.0) * n                       # sample index of B(t - shift)
        j = np.floor(u).astype(int)
        f = u - j
        vals = brf[:, j % n] * (1 - f) + brf[:, (j + 1) % n] * f
        out[:, k] = np.trapz(vals, t, axis=1) * K
    return out


def phase_to_shift(phase_deg):
    """Grid phase (deg of AC) -> delay in flicker cycles: phi/pi mod 1 (docs/design.md)."""
    return (np.asarray(phase_deg, float) / 180.0) % 1.0


# --------------------------------------------------------------------------------------------
# Real recordings (shared/data/flicker, README format) folded into one cycle
# --------------------------------------------------------------------------------------------

_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_ROW = re.compile(rf"^\s*({_NUM})\s*,\s*({_NUM})\s*,?\s*$")


def read_recording(path):
    """time (s), value (V) rows of an oscilloscope CSV: optional UTF-8 BOM, `Key:value,`
    metadata lines, a `ch1_time(s),ch1_value(V)` header that may run into the first sample on
    the same line, CRLF line ends (shared/data/README.md)."""
    t, v = [], []
    with open(path, encoding="utf-8-sig", errors="replace") as f:
        for line in f:
            line = line.strip()
            mm = _ROW.match(line)
            if mm is None and "ch1_value(V)" in line:           # header + first sample
                mm = _ROW.match(line.split("ch1_value(V)", 1)[1])
            if mm is not None:
                t.append(float(mm.group(1)))
                v.append(float(mm.group(2)))
    if len(t) < 100:
        raise SystemExit(f"{path}: fewer than 100 time,value rows")
    t, v = np.array(t), np.array(v)
    o = np.argsort(t, kind="stable")
    return t[o], v[o]


def _fourier_fit(t, v, f, H):
    """Least-squares Fourier series of H harmonics at frequency f: (coefficients, rss)."""
    ph = 2 * np.pi * f * t
    cols = [np.ones_like(t)]
    for h in range(1, H + 1):
        cols += [np.cos(h * ph), np.sin(h * ph)]
    A = np.stack(cols, axis=1)
    coef, *_ = np.linalg.lstsq(A, v, rcond=None)
    r = v - A @ coef
    return coef, float(r @ r)


def fold_recording(path, n=1024, fmin=100.0, fmax=140.0, H=40):
    """Measure the flicker frequency near 120 Hz and fold the recording into one cycle.

    Frequency: minimum residual of a least-squares Fourier series (10 harmonics) over a 0.25 Hz
    grid in [fmin, fmax], refined by golden-section search (a phase-dispersion minimisation with
    a smooth model).  Fold: a least-squares Fourier series of H harmonics at that frequency;
    harmonics whose amplitude is below 4 standard errors are dropped (band-limited, no Nyquist
    term); evaluated at t = j/n, normalised to mean 1.  Returns (brf[n], f_hz, percent_flicker,
    explained) where explained is the share of the signal variance the fold explains."""
    t, v = read_recording(path)
    t = t - t[0]
    rss = lambda f: _fourier_fit(t, v, f, 10)[1]
    grid = np.arange(fmin, fmax + 1e-9, 0.25)
    r = np.array([rss(f) for f in grid])
    i = int(np.argmin(r))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    g = (math.sqrt(5) - 1) / 2
    x1, x2 = b - g * (b - a), a + g * (b - a)
    f1, f2 = rss(x1), rss(x2)
    while b - a > 1e-4:
        if f1 < f2:
            b, x2, f2 = x2, x1, f1
            x1 = b - g * (b - a)
            f1 = rss(x1)
        else:
            a, x1, f1 = x1, x2, f2
            x2 = a + g * (b - a)
            f2 = rss(x2)
    f = 0.5 * (a + b)
    coef, res = _fourier_fit(t, v, f, H)
    dof = max(len(t) - (2 * H + 1), 1)
    se = math.sqrt(res / dof) * math.sqrt(2.0 / len(t))     # std error of a cos/sin coefficient
    tt = np.arange(n) / n
    brf = np.full(n, coef[0])
    for h in range(1, min(H, n // 2 - 1) + 1):
        ca, sa = coef[2 * h - 1], coef[2 * h]
        if math.hypot(ca, sa) >= 4 * se:
            brf += ca * np.cos(2 * np.pi * h * tt) + sa * np.sin(2 * np.pi * h * tt)
    brf = brf / brf.mean()
    pf = 100.0 * (brf.max() - brf.min()) / (brf.max() + brf.min())
    var = float(np.var(v))
    explained = 1.0 - res / (var * len(v)) if var > 0 else 0.0
    return brf, f, pf, explained


def recording_path(name):
    if os.path.exists(name):
        return name
    p = os.path.join(FLICKER_DIR, name if name.endswith(".csv") else name + ".csv")
    if not os.path.exists(p):
        raise SystemExit(f"--ood-file {name!r}: no such file (looked in {FLICKER_DIR})")
    return p


# --------------------------------------------------------------------------------------------
# PNG writer (PNG spec: signature, IHDR, IDAT = zlib(filter byte 0 + big-endian rows), IEND)
# --------------------------------------------------------------------------------------------

def _chunk(tag, data):
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)


def write_png16(path, img, level=1):
    """img: uint16 (H, W) -> colour type 0, or (H, W, 3) -> colour type 2 (R, G, B)."""
    img = np.ascontiguousarray(img, dtype=">u2")
    h, w = img.shape[:2]
    ctype = 0 if img.ndim == 2 else 2
    rows = img.reshape(h, -1).view(np.uint8).reshape(h, -1)
    raw = np.concatenate([np.zeros((h, 1), np.uint8), rows], axis=1).tobytes()
    ihdr = struct.pack(">IIBBBBB", w, h, 16, ctype, 0, 0, 0)
    data = b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(raw, level)) + _chunk(b"IEND", b"")
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


# --------------------------------------------------------------------------------------------
# Geometry: pixel-integrated Gaussian PSF, positions
# --------------------------------------------------------------------------------------------

_erf = np.frompyfunc(math.erf, 1, 1)


def psf_stamp(x0, y0, sigma, radius):
    """Pixel-integrated Gaussian around (x0, y0) (pixel centres at integers): returns
    (ix0, iy0, stamp) with stamp[(2r+1), (2r+1)] covering pixels ix0.., iy0..."""
    cx, cy = int(round(x0)), int(round(y0))
    edges = np.arange(-radius, radius + 2) - 0.5
    s2 = sigma * math.sqrt(2.0)
    ex = _erf((cx + edges - x0) / s2).astype(float)
    ey = _erf((cy + edges - y0) / s2).astype(float)
    px, py = 0.5 * np.diff(ex), 0.5 * np.diff(ey)
    return cx - radius, cy - radius, np.outer(py, px)


def place_points(rng, n, width, height, margin, min_sep, existing=()):
    """n uniform positions at least min_sep from each other and from `existing` (rejection)."""
    pts = list(existing)
    out = []
    tries = 0
    while len(out) < n:
        tries += 1
        if tries > 200000 + 2000 * n:
            raise SystemExit(f"cannot place {n} lights {min_sep} px apart in {width}x{height}; "
                             "lower --lights or --min-spacing")
        x = rng.uniform(margin, width - 1 - margin)
        y = rng.uniform(margin, height - 1 - margin)
        if all((x - a) ** 2 + (y - b) ** 2 >= min_sep ** 2 for a, b in pts):
            pts.append((x, y))
            out.append((x, y))
    return out


# --------------------------------------------------------------------------------------------
# The renderer
# --------------------------------------------------------------------------------------------

def phase_set(kind, transformer_deg):
    if kind == "3":
        return [0.0, 120.0, 240.0]
    if kind == "6":
        return [0.0, 120.0, 240.0] + [(p + transformer_deg) % 360.0 for p in (0.0, 120.0, 240.0)]
    return None                                           # continuous


def select_bulbs(cands, spec):
    if spec in ("", "all"):
        return cands
    want = [w.strip() for w in spec.split(",") if w.strip()]
    out = [b for b in cands if b.id in want or b.tech in want]
    missing = [w for w in want if not any(b.id == w or b.tech == w for b in cands)]
    if missing or not out:
        raise SystemExit(f"--bulbs: {missing or want} match no candidate bulb for this grid/bands")
    return out


def parse_range(s):
    """'A' or 'A:B' (log-uniform between A and B)."""
    if ":" in s:
        a, b = (float(x) for x in s.split(":", 1))
        return a, b
    a = float(s)
    return a, a


def main(argv=None):
    ap = argparse.ArgumentParser(
        description="Independent NumPy renderer of gridsurvey-capture/1 directories (paper Eqs. "
                    "3-7, docs/formats.md): Gaussian-PSF lights from DELIGHT BRFs at grid phases, "
                    "Poisson + read noise; writes capture.json, 16-bit PNG frames and truth.json.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("outdir", nargs="?", help="capture directory to write (created)")
    ap.add_argument("--delight-csv", help="CSV from `gridsurvey delight export -o FILE`")
    ap.add_argument("--width", type=int, default=640, help="image width, px")
    ap.add_argument("--height", type=int, default=480, help="image height, px")
    ap.add_argument("-K", "--K", type=int, default=26, help="frames per flicker cycle (Eq. 5)")
    ap.add_argument("-C", "--cycles", type=float, default=500.0,
                    help="flicker cycles C integrated per frame (capture.json `cycles`; does not "
                         "change the electron budget)")
    ap.add_argument("--grid-hz", type=int, choices=(50, 60), default=50,
                    help="nominal mains frequency (flicker at twice it); selects the DELIGHT entries")
    ap.add_argument("--bands", type=int, choices=(1, 3), default=1,
                    help="1 = monochrome (photodiode entries), 3 = RGB (rgb entries, Eq. 6 chromaticity)")
    ap.add_argument("--lights", type=int, default=300, help="number of isolated in-DELIGHT lights")
    ap.add_argument("--electrons", default="10000",
                    help="signal budget of one light: its expected total photo-electrons summed over "
                         "all K frames, all bands and all pixels (before extinction, scintillation "
                         "and noise); 'A:B' draws each light log-uniformly in [A, B]")
    ap.add_argument("--sigma-px", type=float, default=1.2, help="Gaussian PSF sigma, pixels")
    ap.add_argument("--sky", type=float, default=0.0,
                    help="constant sky level, expected electrons per pixel per frame per band")
    ap.add_argument("--gain", type=float, default=1.0, help="gain_e_per_dn (e-/DN), > 0")
    ap.add_argument("--read-noise", type=float, default=2.0, help="read_noise_dn (DN rms)")
    ap.add_argument("--black-level", type=float, default=100.0, help="black_level (DN)")
    ap.add_argument("--saturation", type=float, default=65535.0, help="saturation (DN)")
    ap.add_argument("--phases", choices=("3", "6", "continuous"), default="3",
                    help="3 = 0/120/240 deg; 6 = those and +--transformer-deg; continuous = uniform")
    ap.add_argument("--transformer-deg", type=float, default=30.0,
                    help="AC phase shift of a delta-wye transformer (--phases 6), deg")
    ap.add_argument("--bulbs", default="all",
                    help="comma list of DELIGHT bulb ids and/or technologies (e.g. sodium_hp,cfl-11w)")
    ap.add_argument("--min-spacing", type=float, default=12.0, help="minimum distance between lights (px)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--extinction", default="",
                    help="per-band gains R,G,B (reddening), e.g. 1,0.8,0.6; off when empty")
    ap.add_argument("--scintillation", type=float, default=0.0,
                    help="log-normal sigma of the per-light, per-frame flux factor (0 = off)")
    ap.add_argument("--blend-pairs", type=int, default=0,
                    help="extra pairs of lights of different (bulb, phase) --blend-sep px apart")
    ap.add_argument("--blend-sep", type=float, default=3.0, help="distance between blend members, px")
    ap.add_argument("--blend-ratio", type=float, default=1.0, help="flux of the 2nd member / 1st")
    ap.add_argument("--ood-file", default="",
                    help="real recording (name in shared/data/flicker, e.g. Old_IKEA_LED, or a path) "
                         "for out-of-database lights")
    ap.add_argument("--ood-count", type=int, default=0, help="number of out-of-database lights")
    ap.add_argument("--free-running", default="",
                    help="free-running windows on the grid of this mains recording (name in "
                         "shared/data/mains, e.g. whu_001_ref, or a path); default: AC-locked")
    ap.add_argument("--free-period", default="measured",
                    help="free running: the windows' half period P, 'measured' (the mean of the 64 "
                         "half periods before each exposure, as the firmware does) or 'nominal'")
    ap.add_argument("--readout-cycles", type=int, default=10,
                    help="free running: flicker cycles between one exposure's end and the next's start")
    ap.add_argument("--png-level", type=int, default=1, help="zlib level of the PNGs")
    ap.add_argument("--selftest", action="store_true",
                    help="check the window integrals against a trapezoid rule and exit")
    ap.add_argument("--fold-table", action="store_true",
                    help="print frequency and percent flicker of every recording and exit")
    a = ap.parse_args(argv)

    if a.fold_table:
        for fn in sorted(os.listdir(FLICKER_DIR)):
            if fn.endswith(".csv") and fn != "info.csv":
                brf, f, pf, ex = fold_recording(os.path.join(FLICKER_DIR, fn))
                print(f"{fn[:-4]:26s} {f:9.3f} Hz  PF {pf:6.2f} %  fold explains {100 * ex:6.2f} % of the variance")
        return 0
    if not a.delight_csv:
        ap.error("--delight-csv is required")
    bulbs_all = read_delight_csv(a.delight_csv)
    if a.selftest:
        return selftest(bulbs_all)
    if not a.outdir:
        ap.error("OUTDIR is required")
    if a.gain <= 0 or a.read_noise < 0 or not (a.black_level < a.saturation <= 65536):
        ap.error("need gain > 0, read noise >= 0, black level < saturation <= 65536")

    rng = np.random.default_rng(a.seed)
    B, K = a.bands, a.K
    cands = select_bulbs(candidate_bulbs(bulbs_all, a.grid_hz, B), a.bulbs)
    phases = phase_set(a.phases, a.transformer_deg)
    ext = np.ones(B)
    if a.extinction:
        ext = np.array([float(x) for x in a.extinction.split(",")])
        if ext.size != B:
            ap.error(f"--extinction needs {B} gains")
    e_lo, e_hi = parse_range(a.electrons)

    def draw_flux():
        return e_lo if e_lo == e_hi else float(math.exp(rng.uniform(math.log(e_lo), math.log(e_hi))))

    def draw_phase():
        return float(rng.choice(phases)) if phases is not None else float(rng.uniform(0.0, 360.0))

    radius = int(math.ceil(5 * a.sigma_px))
    margin = radius + 3 + a.blend_sep
    lights = []   # dicts; the model arrays are built below

    def add_light(x, y, bulb, phase, flux, flags, **extra):
        d = dict(id=len(lights), x_px=x, y_px=y, bulb=bulb.id if bulb is not None else extra.pop("bulb_name"),
                 technology=bulb.tech if bulb is not None else extra.pop("tech"),
                 phase_deg=phase % 360.0, shift_cycles=float(phase_to_shift(phase)),
                 budget_e=flux, flags=flags)
        d.update(extra)
        lights.append(d)
        return d

    # isolated in-database lights
    pos = place_points(rng, a.lights, a.width, a.height, margin, a.min_spacing)
    for x, y in pos:
        add_light(x, y, cands[rng.integers(len(cands))], draw_phase(), draw_flux(), [])
    # blended pairs: two lights of different (bulb, phase) blend_sep px apart
    if a.blend_pairs:
        centres = place_points(rng, a.blend_pairs, a.width, a.height, margin, a.min_spacing + a.blend_sep, pos)
        pos = pos + centres
        for cx, cy in centres:
            ang = rng.uniform(0, 2 * math.pi)
            dx, dy = 0.5 * a.blend_sep * math.cos(ang), 0.5 * a.blend_sep * math.sin(ang)
            b1, p1 = cands[rng.integers(len(cands))], draw_phase()
            while True:
                b2, p2 = cands[rng.integers(len(cands))], draw_phase()
                if b2.id != b1.id or abs(((p2 - p1 + 90) % 180) - 90) > 1e-6:
                    break
            f1 = draw_flux()
            l1 = add_light(cx - dx, cy - dy, b1, p1, f1, ["blend"])
            l2 = add_light(cx + dx, cy + dy, b2, p2, f1 * a.blend_ratio, ["blend"])
            l1["blend_partner"], l2["blend_partner"] = l2["id"], l1["id"]
    # out-of-database lights from a real recording
    ood_brf = None
    if a.ood_count:
        if not a.ood_file:
            ap.error("--ood-count needs --ood-file")
        path = recording_path(a.ood_file)
        name = os.path.basename(path)[:-4]
        tech, desc = RECORDING_TECH.get(name, ("unknown", "unknown"))
        if tech == "led_pwm":
            raise SystemExit(f"{name}: PWM flicker not locked to the mains: no mains-cycle BRF to fold")
        ood_brf, ood_f, ood_pf, ood_ex = fold_recording(path)
        opos = place_points(rng, a.ood_count, a.width, a.height, margin, a.min_spacing, pos)
        for x, y in opos:
            # no voltage reference: a random delay, uniform over the cycle
            add_light(x, y, None, float(rng.uniform(0.0, 180.0)), draw_flux(), ["out_of_db"],
                      bulb_name="rec:" + name, tech=tech, out_of_db=True, recording=os.path.basename(path),
                      recording_technology=desc, recording_flicker_hz=ood_f,
                      recording_percent_flicker=ood_pf)

    # ---- free running: each frame's windows on the recording's grid ----------------------------
    factors, free_meta, mains_name = {}, None, None   # factors: per BRF length n
    if a.free_running:
        if a.free_period not in ("measured", "nominal"):
            ap.error("--free-period: expected measured or nominal")
        if a.cycles != int(a.cycles) or a.cycles < 1:
            ap.error("--free-running needs a whole number of --cycles")
        tc, mains_name = mains_crossings(a.free_running)
        period = a.free_period if a.free_period == "measured" else 1.0 / (2.0 * a.grid_hz)

    def frame_factors(brf):
        nonlocal free_meta
        n = np.shape(brf)[-1]
        if not a.free_running:
            return None
        if n not in factors:
            factors[n], free_meta = free_running_frames(tc, harmonics(np.ones((1, n)))[1], K, int(a.cycles),
                                                        a.readout_cycles, period)
        return factors[n]

    # ---- per-light mean electrons per frame and band (Eqs. 5-6) ------------------------------
    by_id = {b.id: b for b in cands}
    L = len(lights)
    mean_e = np.zeros((L, K, B))          # expected e- of the light in (frame, band), summed over pixels
    for i, d in enumerate(lights):
        if d.get("out_of_db"):
            brf = np.tile(ood_brf, (B, 1))
            Q = np.full(B, 1.0 / B)
        else:
            bulb = by_id[d["bulb"]]
            brf, Q = bulb.brf, bulb.chroma
        # (B, K), Eq. 5; a band-limited BRF may dip to ~-1e-9 in a dark gap (linear LED
        # drivers): a flux cannot be negative, so such window means are clipped to 0
        b = np.maximum(window_means(brf, K, d["shift_cycles"], frame_factors(brf)), 0.0)
        mean_e[i] = (d["budget_e"] * (ext * Q)[:, None] * b / K).T     # Eq. 6 with the budget
        d["flux_e"] = float(mean_e[i].sum())                           # after extinction
        d["chromaticity"] = [float(q) for q in Q]
    if a.scintillation > 0:
        s = a.scintillation
        scint = np.exp(s * rng.standard_normal((L, K)) - 0.5 * s * s)  # mean 1, per light & frame
        mean_e *= scint[:, :, None]

    # ---- expected image: stamps accumulated with bincount ----------------------------------
    W, H = a.width, a.height
    S = 2 * radius + 1
    idx = np.empty((L, S * S), np.int64)
    stamps = np.empty((L, S * S))
    valid = np.empty((L, S * S), bool)
    for i, d in enumerate(lights):
        ix0, iy0, st = psf_stamp(d["x_px"], d["y_px"], a.sigma_px, radius)
        xs, ys = np.meshgrid(np.arange(ix0, ix0 + S), np.arange(iy0, iy0 + S))
        ok = (xs >= 0) & (xs < W) & (ys >= 0) & (ys < H)
        idx[i] = np.where(ok, ys * W + xs, 0).ravel()
        stamps[i] = np.where(ok, st, 0.0).ravel()
        valid[i] = ok.ravel()
    os.makedirs(a.outdir, exist_ok=True)
    frames = []
    sat_clip = min(a.saturation, 65535.0)
    for k in range(K):
        img = np.empty((H, W, B))
        for bnd in range(B):
            mu = np.bincount(idx.ravel(), weights=(stamps * mean_e[:, k, bnd][:, None]).ravel(),
                             minlength=H * W).reshape(H, W) + a.sky
            ne = rng.poisson(mu).astype(float)                                  # photo-electrons
            raw = a.black_level + ne / a.gain + a.read_noise * rng.standard_normal((H, W))
            img[:, :, bnd] = np.clip(np.rint(raw), 0, sat_clip)
        fn = f"frame_{k:03d}.png"
        write_png16(os.path.join(a.outdir, fn), (img[:, :, 0] if B == 1 else img).astype(np.uint16), a.png_level)
        fr = {"file": fn, "k": k, "cycles": a.cycles}
        if free_meta is not None:
            fr.update(window_half_period_s=free_meta[k][0], grid_hz_measured=free_meta[k][1],
                      window_drift_windows=free_meta[k][2])
        frames.append(fr)

    cap = {"format": "gridsurvey-capture/1", "grid_hz": a.grid_hz, "K": K, "bands": B,
           "width": W, "height": H, "saturation": a.saturation, "black_level": a.black_level,
           "gain_e_per_dn": a.gain, "read_noise_dn": a.read_noise, "locked": free_meta is None,
           "x_generator": "tests/independent/render.py", "frames": frames}
    if free_meta is not None:   # how the windows' period was chosen (docs/formats.md)
        cap["window_period"] = a.free_period
    with open(os.path.join(a.outdir, "capture.json"), "w") as f:
        json.dump(cap, f, indent=1)
        f.write("\n")

    truth = {
        "format": "gridsurvey-independent-truth/1",
        "definitions": {
            "budget_e": "expected total photo-electrons of the light summed over all K frames, all "
                        "bands and all pixels, before extinction, scintillation and noise (--electrons)",
            "flux_e": "the same after the per-band extinction gains (= budget_e without extinction)",
            "phase_deg": "grid phase in [0, 360); the BRF is delayed by shift_cycles = phase/180 mod 1 "
                         "(0/120/240 -> 0, 2/3, 1/3); phase and phase+180 look the same",
            "x_px, y_px": "PSF centre, pixel centres at integers, x right, y down",
            "flags": "blend: one of a pair --blend-sep px apart (blend_partner = other id); "
                     "out_of_db: BRF folded from a real recording (random phase: no voltage reference)",
            "noise": "e- ~ Poisson(sky + sum mu); raw = black + e-/gain + read_noise_dn N(0,1), "
                     "rounded, clipped to [0, min(saturation, 65535)]",
            "psf": "pixel-integrated Gaussian of sigma_px, stamp radius ceil(5 sigma_px)",
        },
        "params": {k: v for k, v in vars(a).items() if k not in ("selftest", "fold_table")},
        "psf_radius_px": radius,
        "candidates": [b.id for b in cands],
        "phase_set_deg": phases,
        "extinction": [float(g) for g in ext],
        "lights": lights,
    }
    if free_meta is not None:
        truth["free_running"] = {"mains": mains_name, "period": a.free_period,
                                 "frames": [{"k": k, "window_half_period_s": p, "grid_hz_measured": f,
                                             "window_drift_windows": d} for k, (p, f, d) in enumerate(free_meta)]}
    if ood_brf is not None:
        truth["ood_brf"] = [float(v) for v in ood_brf]
    with open(os.path.join(a.outdir, "truth.json"), "w") as f:
        json.dump(truth, f, indent=1)
        f.write("\n")
    return 0


def selftest(bulbs):
    """Window integrals (DFT) against a dense trapezoid on linear interpolation, and the
    analytic case of a pure cosine; mean of the window means = 1."""
    worst = 0.0
    for b in bulbs[:: max(1, len(bulbs) // 25)]:
        for K in (13, 26):
            for s in (0.0, 1 / 3, 2 / 3, 0.123456):
                d = window_means(b.brf, K, s) - window_means_trapezoid(b.brf, K, s)
                worst = max(worst, float(np.abs(d).max()))
    n, K, s = 1024, 26, 0.3
    t = np.arange(n) / n
    cosb = 1 + 0.5 * np.cos(2 * np.pi * t)
    k = np.arange(K)
    exact = 1 + 0.5 * K / (2 * np.pi) * (np.sin(2 * np.pi * ((k + 1) / K - s)) - np.sin(2 * np.pi * (k / K - s)))
    err_cos = float(np.abs(window_means(cosb, K, s)[0] - exact).max())
    mean_err = float(abs(window_means(bulbs[0].brf, 26, 0.37).mean(axis=1) - 1).max())
    print(f"DFT vs trapezoid (linear interp): max |diff| {worst:.2e}; cosine vs closed form "
          f"{err_cos:.2e}; |mean - 1| {mean_err:.2e}")
    # free running on an ideal grid: P = Delta gives Eq. 5's windows, no drift; a grid slower by
    # eps slips the windows c eps cycles by cycle c (range K C eps / (1 + eps)), each cycle's
    # window mean of the cosine in closed form, averaged over the C cycles
    _, m = harmonics(np.ones((1, n)))
    tc = np.arange(14000) * 0.01
    F, meta = free_running_frames(tc, m, K, 512, 10, 0.01, first=64)
    err_locked = float(np.abs(window_means(cosb, K, s, F) - window_means(cosb, K, s)).max())
    eps, C = 2e-4, 100
    tc = np.arange(3000) * 0.01 * (1 + eps)
    F, meta2 = free_running_frames(tc, m, K, C, 10, 0.01, first=64)
    c = np.arange(C)[:, None]
    ua, ub = (c * 0.01 + k * 0.01 / K) / (0.01 * (1 + eps)) - c, (c * 0.01 + (k + 1) * 0.01 / K) / (0.01 * (1 + eps)) - c
    slip = 1 + 0.5 * ((np.sin(2 * np.pi * (ub - s)) - np.sin(2 * np.pi * (ua - s))) / (2 * np.pi * (ub - ua))).mean(axis=0)
    err_slip = float(np.abs(window_means(cosb, K, s, F)[0] - slip).max())
    err_range = max(abs(x[2] - K * C * eps / (1 + eps)) for x in meta2)
    # unequal half periods (the polarities 20 us apart) and a wandering grid, the period measured:
    # the drift range against docs/formats.md's formula (c P - (t_c - t_0)) / Delta_c, even c and C
    rng = np.random.default_rng(3)
    half = 0.01 + np.where(np.arange(20000) % 2 == 0, 1e-5, -1e-5) + np.cumsum(rng.normal(0, 2e-8, 20000))
    tc = np.concatenate([[0.0], np.cumsum(half)])
    F, meta3 = free_running_frames(tc, m, K, 300, 10, "measured", first=64)
    err_formula = 0.0
    for k, (P, f, d) in enumerate(meta3):
        s0 = 64 + k * 310
        offs = [(c * P - (tc[s0 + c] - tc[s0])) / (tc[s0 + min(c, 299) + 1] - tc[s0 + min(c, 299)])
                for c in range(0, 301) if c % 2 == 0 or c == 300]
        err_formula = max(err_formula, abs(d - K * (max(offs) - min(offs))))
    print(f"free running: ideal grid vs Eq. 5 {err_locked:.2e} (drift {max(x[2] for x in meta):.1e}); slipping "
          f"grid vs closed form {err_slip:.2e}, drift range error {err_range:.2e} windows; measured period on "
          f"unequal half periods: range vs the formula {err_formula:.2e} windows")
    ok = (worst < 2e-3 and err_cos < 1e-12 and mean_err < 1e-9 and err_locked < 1e-9 and err_slip < 1e-9 and
          err_range < 1e-6 and max(x[2] for x in meta) < 1e-9 and err_formula < 1e-3)
    print("selftest", "ok" if ok else "FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
