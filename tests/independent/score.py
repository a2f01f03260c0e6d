#!/usr/bin/python3
"""Score `gridsurvey recognize` on a capture written by render.py, against its truth.json and
against a maximum-likelihood oracle that knows render.py's whole forward model.

1. Runs `BIN recognize CAPDIR --format json [extra options]` and, to recover the best-guess phase of
   lights whose phase is withheld (`phase_deg` is null when phase_ambiguous,
   docs/recognize-cli.md), the same command with `--ambiguous-below 0` (the option only sets the
   flags; the second run must report the same lights, bulbs and confidences, which is checked).
2. Matches reported lights to truth lights one-to-one, nearest pair first, within --radius px.
3. Best guess of a matched light: `bulb` and the phase (the --ambiguous-below 0 run's phase_deg
   when the first run's is null); for a light without an answer (`unknown`, `dim`: bulb null)
   the best fit within the database, `runner_up` (docs/recognition.md, "Flags"), with
   `runner_up.confidence` as its pair confidence.  A phase is right when it equals the truth
   modulo 180 deg (a flicker cannot tell phi from phi + 180, paper Sec. 2.2) within --phase-tol
   degrees (continuous phases: within 30 deg, the width of the recogniser's pair window).
4. The oracle: for every truth light (isolated, in the database) and every candidate (bulb,
   phase) template built from the same DELIGHT CSV (same grid_hz and bands, render.window_means,
   Eqs. 5-6), the likelihood of the raw pixel values within --oracle-radius px of the light's
   true position is maximised over its brightness (the signal budget a, e-).  It knows
   render.py's whole forward model (position, PSF, sky, gain, read noise, black level,
   extinction gains, the scintillation law):

       mu[p,k,b] = a * psf[p] * ext[b] Q[b] bwin[b,k] / K + sky       (electrons)
       raw = black + Poisson(mu)/gain + read N(0,1), rounded to an integer DN

   Exact per-sample likelihood, Poisson-Gaussian with the rounding:
       p(raw | mu) = sum_n Pois(n; mu) [Phi((raw + 1/2 - black - n/gain)/read) - Phi((raw - 1/2 - black - n/gain)/read)]
   summed over the n within +-7 read-noise sigmas of the sample (the bracket is < 1e-12
   beyond); saturated samples are dropped.  It is tabulated per distinct raw value on a fine
   grid of log mu and interpolated (ExactTable; checked against the direct sum and a
   brute-force sum over every n by --selftest).  The maximisation over a is Newton's method
   on this exact log-likelihood (its derivatives are the posterior mean and variance of n),
   started from the shifted-Poisson approximation raw*gain + r^2 ~ Poisson(mu + r^2)
   (r^2 = read^2 + 1/12 in e-^2), which also screens out templates more than 30 nats below
   the best (posterior < 1e-13).  Posterior: uniform prior over pairs (the renderer's), the
   brightness marginalised over a > 0 with a flat prior by Laplace's method
   (log L(a*) + log sqrt(2 pi / -L''(a*))); the oracle's answer is its posterior mode.
   With scintillation (render --scintillation s) the per-frame factor S_k = exp(s z - s^2/2)
   is integrated out by 20-node Gauss-Hermite quadrature per frame, with a Gaussian per-sample
   likelihood (variance mu + r^2) inside the quadrature and a golden-section search over a
   (an approximation: the exact Poisson-Gaussian times the quadrature is too slow in NumPy).
   Continuous phases: a uniform prior over the delay, integrated on a grid of max(4K, 64)
   delays per bulb, refined 16x over the +-2.5 cells around each plausible bulb's peak; the
   answer is the bulb and peak phase whose +-30 deg window holds the most posterior mass.
"""

import argparse
import json
import math
import os
import struct
import subprocess
import sys
import zlib
from concurrent.futures import ProcessPoolExecutor

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import render  # noqa: E402  (DELIGHT CSV reader, Eq. 5 window means, PSF)

# --------------------------------------------------------------------------------------------
# PNG reader (16-bit grey / RGB, non-interlaced, filters 0-4): what render.py writes, and any
# non-interlaced 16-bit PNG.
# --------------------------------------------------------------------------------------------


def read_png16(path):
    data = open(path, "rb").read()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError(f"{path}: not a PNG")
    pos, idat, hdr = 8, [], None
    while pos < len(data):
        ln, tag = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + ln]
        if tag == b"IHDR":
            hdr = struct.unpack(">IIBBBBB", body)
        elif tag == b"IDAT":
            idat.append(body)
        elif tag == b"IEND":
            break
        pos += 12 + ln
    w, h, depth, ctype, _, _, interlace = hdr
    if depth != 16 or ctype not in (0, 2) or interlace:
        raise ValueError(f"{path}: need 16-bit grey/RGB non-interlaced")
    ch = 1 if ctype == 0 else 3
    bpp = 2 * ch
    raw = np.frombuffer(zlib.decompress(b"".join(idat)), np.uint8).reshape(h, 1 + w * bpp)
    ftype, rows = raw[:, 0], raw[:, 1:].astype(np.int32)
    out = np.zeros_like(rows)
    prev = np.zeros(w * bpp, np.int32)
    for y in range(h):
        r, f = rows[y], ftype[y]
        if f == 0:
            cur = r
        elif f == 2:
            cur = (r + prev) & 255
        else:                                            # 1, 3, 4 need the left neighbour
            cur = np.zeros_like(r)
            for x in range(w * bpp):
                a = cur[x - bpp] if x >= bpp else 0
                b = prev[x]
                c = prev[x - bpp] if x >= bpp else 0
                if f == 1:
                    p = a
                elif f == 3:
                    p = (a + b) >> 1
                else:
                    pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                    p = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                cur[x] = (r[x] + p) & 255
        out[y] = cur
        prev = cur
    px = out.astype(np.uint8).reshape(h, w * ch, 2)
    img = (px[:, :, 0].astype(np.int64) << 8) | px[:, :, 1]
    return img.reshape(h, w, ch)


def read_capture(capdir):
    cap = json.load(open(os.path.join(capdir, "capture.json")))
    K, B = cap["K"], cap["bands"]
    cube = np.empty((K, cap["height"], cap["width"], B), np.int64)
    for fr in cap["frames"]:
        cube[fr["k"]] = read_png16(os.path.join(capdir, fr["file"]))
    return cap, cube


# --------------------------------------------------------------------------------------------
# Helpers: phases, matching, ECE
# --------------------------------------------------------------------------------------------

def phase_err_deg(a, b):
    """Signed circular difference a - b modulo 180 deg, in [-90, 90)."""
    return (a - b + 90.0) % 180.0 - 90.0


def match_lights(truth, reported, radius):
    """One-to-one, nearest pair first, within radius px.  Returns {truth index: reported index}."""
    tx = np.array([[t["x_px"], t["y_px"]] for t in truth]).reshape(-1, 2)
    rx = np.array([[r["x"], r["y"]] for r in reported]).reshape(-1, 2)
    if len(tx) == 0 or len(rx) == 0:
        return {}
    d = np.hypot(tx[:, None, 0] - rx[None, :, 0], tx[:, None, 1] - rx[None, :, 1])
    ti, ri = np.nonzero(d < radius)
    order = np.argsort(d[ti, ri], kind="stable")
    used_t, used_r, m = set(), set(), {}
    for o in order:
        t, r = int(ti[o]), int(ri[o])
        if t not in used_t and r not in used_r:
            m[t] = r
            used_t.add(t)
            used_r.add(r)
    return m


def ece(conf, right, bins=10):
    """Expected calibration error over 10 equal-width confidence bins; also the bin table."""
    conf, right = np.asarray(conf, float), np.asarray(right, float)
    if conf.size == 0:
        return float("nan"), []
    idx = np.minimum((conf * bins).astype(int), bins - 1)
    e, table = 0.0, []
    for b in range(bins):
        sel = idx == b
        if sel.any():
            e += sel.sum() / conf.size * abs(conf[sel].mean() - right[sel].mean())
            table.append((b / bins, (b + 1) / bins, int(sel.sum()), float(conf[sel].mean()), float(right[sel].mean())))
    return float(e), table


def ece_null(conf, observed, bins=10, draws=2000, seed=1):
    """The calibration test: the ECE of a perfectly calibrated predictor with the same confidences
    (outcomes drawn as Bernoulli(conf)), its 99th percentile and the share of draws at least as
    large as the observed ECE (the p-value: small when the confidences are miscalibrated beyond
    the sampling noise of that many lights)."""
    conf = np.asarray(conf, float)
    if conf.size == 0 or not np.isfinite(observed):
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    null = np.array([ece(conf, rng.random(conf.size) < conf, bins)[0] for _ in range(draws)])
    return float(np.quantile(null, 0.99)), float((null >= observed).mean())


# --------------------------------------------------------------------------------------------
# The oracle
# --------------------------------------------------------------------------------------------

_erfc = np.frompyfunc(math.erfc, 1, 1)


def _log_phi_diff(lo, hi):
    """log(Phi(hi) - Phi(lo)) for lo < hi, stable in both tails."""
    s = 1.0 / math.sqrt(2.0)
    up = lo > 0            # both in the upper tail: Q(lo) - Q(hi)
    a = np.where(up, lo, -hi)
    b = np.where(up, hi, -lo)
    ea = _erfc(a * s).astype(float)
    eb = _erfc(b * s).astype(float)
    with np.errstate(divide="ignore"):
        return np.log(np.maximum(0.5 * (ea - eb), 1e-300))


class SampleSet:
    """The usable raw samples of one light (pixels within the oracle radius x K x bands,
    flattened; saturated samples dropped), and for each the window of photo-electron counts n
    where the rounded read-noise kernel is non-negligible (the exact likelihood's sum)."""

    def __init__(self, raw, psf, cap, sky):
        self.shape = raw.shape                                        # (P, K, B)
        self.g = float(cap.get("gain_e_per_dn", 0) or 1.0)
        self.r = max(float(cap.get("read_noise_dn", 1.0)), 1e-3)
        self.b0 = float(cap.get("black_level", 0.0))
        sat = min(float(cap["saturation"]), 65535.0)
        self.sky = sky
        self.ok = (raw < sat).ravel()                                 # drop saturated samples
        x = raw.astype(float).ravel()[self.ok]
        self.x = x
        self.psf_full = np.broadcast_to(psf[:, None, None], raw.shape).ravel()
        self.frame = np.broadcast_to(np.arange(raw.shape[1])[None, :, None], raw.shape).ravel()[self.ok]
        # shifted-Poisson data: y' = (raw - black) gain + r_e^2 ~ Poisson(mu + r_e^2)
        self.re2 = (self.r * self.g) ** 2 + self.g ** 2 / 12.0
        self.yp = np.maximum((x - self.b0) * self.g + self.re2, 0.0)
        # exact: n window per sample (+-7 read sigmas around the sample, in electrons)
        half = 7.0 * self.r + 1.0          # Phi(-7) = 1e-12: the kernel beyond is negligible
        n_lo = np.maximum(np.floor(self.g * (x - self.b0 - half)), 0.0)
        J = int(math.ceil(self.g * 2 * half)) + 2
        self.n = n_lo[:, None] + np.arange(J)                         # (S, J)
        self.n2 = self.n ** 2
        m = self.n / self.g + self.b0
        lq = _log_phi_diff(((x[:, None] - 0.5) - m) / self.r, ((x[:, None] + 0.5) - m) / self.r)
        self.lq = lq - np.vectorize(math.lgamma)(self.n + 1.0)        # log q(x|n) - log n!

    def design(self, U):
        """Unit templates (T, K, B) -> per-sample expected electrons per e- of budget (T, S)."""
        return (self.psf_full[None] * np.broadcast_to(U[:, None], (U.shape[0],) + self.shape).reshape(U.shape[0], -1))[:, self.ok]

    def exact(self, mu):
        lp, d1, d2 = self.exact_each(mu)
        return lp.sum(axis=-1), d1, d2

    def exact_each(self, mu):
        """mu: (T, S) expected electrons.  Returns per sample the exact log p(raw | mu) and
        its d/dmu and d2/dmu2 (T, S): with the posterior moments of n given raw and mu,
        d/dmu = <n>/mu - 1 and d2/dmu2 = (var n - <n>)/mu^2."""
        mu = np.maximum(mu, 1e-12)        # a dark window of a linear LED with no sky: mu = 0
        w = self.n[None] * np.log(mu)[..., None] + self.lq[None]    # (T, S, J)
        wmax = w.max(axis=-1, keepdims=True)
        e = np.exp(w - wmax)
        s0 = e.sum(axis=-1)
        en = (e * self.n).sum(axis=-1) / s0
        en2 = (e * self.n2).sum(axis=-1) / s0
        logp = np.log(s0) + wmax[..., 0] - mu
        d1 = en / mu - 1.0
        d2 = (en2 - en ** 2 - en) / mu ** 2
        return logp, d1, d2


class ExactTable:
    """The exact per-sample log-likelihood tabulated for one light.  Raw values are integers,
    so a light has few distinct ones; for each, F(L) = log p(raw | mu = e^L) and dF/dL are
    computed exactly (SampleSet.exact_each) on a grid uniform in L = log mu with step H_L, and
    interpolated by cubic Hermite; d2F/dL2 linearly.  In L the sum over n is a log-sum-exp of
    linear functions, so F is smooth down to mu -> 0 (error ~ H_L^4/384 |d4F/dL4|, < 1e-7 nats
    per sample, checked by --selftest).  Makes the Newton iterations O(templates x samples)."""

    H_L = 0.02
    MU_MIN = 1e-6        # e-: a window that is dark in a template (linear LED, no sky)

    def __init__(self, ss, mu_max):
        xs, self.inv = np.unique(ss.x, return_inverse=True)
        self.L0 = math.log(self.MU_MIN)
        self.G = int(math.ceil((math.log(max(mu_max, 1.0)) - self.L0) / self.H_L)) + 3
        mu = np.exp(self.L0 + self.H_L * np.arange(self.G))
        first = np.zeros(len(xs), int)                               # one sample per raw value
        first[self.inv[::-1]] = np.arange(len(self.inv))[::-1]
        sub = object.__new__(SampleSet)
        sub.n, sub.n2, sub.lq = ss.n[first], ss.n2[first], ss.lq[first]
        F = np.empty((len(xs), self.G))
        dF = np.empty_like(F)
        d2F = np.empty_like(F)
        for c0 in range(0, self.G, 128):
            m = np.broadcast_to(mu[c0:c0 + 128, None], (min(128, self.G - c0), len(xs)))
            lp, d1, d2 = sub.exact_each(m)
            mm = m.T
            F[:, c0:c0 + 128] = lp.T
            dF[:, c0:c0 + 128] = d1.T * mm                            # dF/dL = mu dlogp/dmu
            d2F[:, c0:c0 + 128] = d2.T * mm ** 2 + d1.T * mm           # d2F/dL2
        self.F, self.dF, self.d2F = F, dF, d2F

    def __call__(self, mu):
        """mu (T, S) -> (sum of log p per template (T,), d log p/dmu (T, S), d2 log p/dmu2)."""
        mu = np.maximum(mu, self.MU_MIN)
        t = (np.log(mu) - self.L0) / self.H_L
        j = np.clip(np.floor(t).astype(int), 0, self.G - 2)
        f = t - j
        u = np.broadcast_to(self.inv, mu.shape)
        F0, F1 = self.F[u, j], self.F[u, j + 1]
        D0, D1 = self.dF[u, j] * self.H_L, self.dF[u, j + 1] * self.H_L
        f2, f3 = f * f, f * f * f
        lp = (2 * f3 - 3 * f2 + 1) * F0 + (f3 - 2 * f2 + f) * D0 + (-2 * f3 + 3 * f2) * F1 + (f3 - f2) * D1
        dFdt = (6 * f2 - 6 * f) * F0 + (3 * f2 - 4 * f + 1) * D0 + (-6 * f2 + 6 * f) * F1 + (3 * f2 - 2 * f) * D1
        dFdL = dFdt / self.H_L
        d2FdL2 = (1 - f) * self.d2F[u, j] + f * self.d2F[u, j + 1]
        d1 = dFdL / mu
        d2 = (d2FdL2 - dFdL) / mu ** 2
        return lp.sum(axis=-1), d1, d2


NEWTON_EXACT = 3     # Newton steps on the exact likelihood after the shifted-Poisson start
                     # (measured: the posteriors do not change in the 6th decimal with 6)


def oracle_light(ss, U, scint=0.0):
    """ss: SampleSet of one light; U: (T, K, B) unit templates (ext Q bwin / K per e- of
    budget).  Returns (log marginal likelihood (T,), brightness a* in e- (T,))."""
    T = U.shape[0]
    W = ss.design(U)                                                  # (T, S)
    # --- shifted-Poisson profile likelihood: start values and screening ------------------
    yp, c = ss.yp[None], ss.sky + ss.re2
    a = np.full(T, max(float((ss.yp - c).sum()), 1.0)) / np.maximum(W.sum(axis=1), 1e-12)
    a = np.maximum(a, 1.0)
    for _ in range(40):
        mu = a[:, None] * W + c
        g = (W * (yp / mu - 1)).sum(axis=1)
        h = -(W ** 2 * yp / mu ** 2).sum(axis=1)
        step = -g / np.minimum(h, -1e-300)
        a_new = np.maximum(a + step, 0.5 * a)
        done = np.all(np.abs(a_new - a) <= 1e-6 * a)
        a = a_new
        if done:
            break
    mu = a[:, None] * W + c
    lsp = (yp * np.log(mu) - mu).sum(axis=1)
    keep = np.nonzero(lsp >= lsp.max() - 30.0)[0]
    logm = np.full(T, -np.inf)
    ahat = a.copy()
    if scint > 0:
        logm[keep], ahat[keep] = _oracle_scint(ss, W[keep], a[keep], scint)
        return logm, ahat
    # --- exact Poisson-Gaussian: Newton from the shifted-Poisson estimate -----------------
    Wk, ak = W[keep], a[keep]
    a_lo, a_hi = 0.5 * ak, 2.0 * ak + 1.0            # the MLE is never this far from the start
    table = ExactTable(ss, float((a_hi[:, None] * Wk).max()) + ss.sky)
    for it in range(NEWTON_EXACT + 1):
        lp, d1, d2 = table(ak[:, None] * Wk + ss.sky)
        g = (d1 * Wk).sum(axis=1)
        h = (d2 * Wk ** 2).sum(axis=1)
        if it == NEWTON_EXACT:
            break
        step = np.where(h < 0, -g / np.minimum(h, -1e-300), 0.0)
        ak = np.clip(ak + step, a_lo, a_hi)
    # log of the flat-prior marginal over a > 0 (Laplace): L(a*) + log sqrt(2 pi / -L'')
    logm[keep] = lp + 0.5 * np.log(2 * np.pi / np.maximum(-h, 1e-300))
    ahat[keep] = ak
    return logm, ahat


_GH_X, _GH_W = np.polynomial.hermite_e.hermegauss(20)      # probabilists' Hermite: weight exp(-x^2/2)
_GH_W = _GH_W / _GH_W.sum()


def _oracle_scint(ss, W, a0, s):
    """Scintillation: the light's per-frame factor S_k = exp(s z - s^2/2) is integrated out by
    20-node Gauss-Hermite quadrature per frame; inside it a Gaussian per-sample likelihood with
    variance mu + r_e^2 (documented approximation); golden-section search over log a, and the
    Laplace term from a finite-difference curvature."""
    y = (ss.x - ss.b0) * ss.g                                          # (S,) electrons
    onehot = (ss.frame[:, None] == np.arange(ss.shape[1])[None]).astype(float)   # (S, K)
    fac = np.exp(s * _GH_X - 0.5 * s * s)                              # (Q,)
    lw = np.log(_GH_W)

    def L(a):
        mu = a[:, None, None] * fac[None, :, None] * W[:, None, :] + ss.sky   # (T, Q, S)
        var = mu + ss.re2
        lp = -0.5 * ((y - mu) ** 2 / var + np.log(2 * np.pi * var))
        per_frame = lp @ onehot + lw[None, :, None]                    # (T, Q, K)
        mx = per_frame.max(axis=1, keepdims=True)
        return (np.log(np.exp(per_frame - mx).sum(axis=1)) + mx[:, 0]).sum(axis=1)

    lo, hi = np.log(a0) - 1.0, np.log(a0) + 1.0
    gr = (math.sqrt(5) - 1) / 2
    x1, x2 = hi - gr * (hi - lo), lo + gr * (hi - lo)
    f1, f2 = L(np.exp(x1)), L(np.exp(x2))
    for _ in range(32):
        sel = f1 > f2                       # maximum in [lo, x2]
        hi = np.where(sel, x2, hi)
        lo = np.where(sel, lo, x1)
        nx1 = np.where(sel, hi - gr * (hi - lo), x2)
        nx2 = np.where(sel, x1, lo + gr * (hi - lo))
        nf = L(np.exp(np.where(sel, nx1, nx2)))
        f1, f2 = np.where(sel, nf, f2), np.where(sel, f1, nf)
        x1, x2 = nx1, nx2
    a = np.exp(0.5 * (lo + hi))
    eps = 1e-3
    Lc, Lp, Lm = L(a), L(a * math.exp(eps)), L(a * math.exp(-eps))
    h = (Lp - 2 * Lc + Lm) / eps ** 2 / a ** 2        # d2L/da2 at the maximum (dL/dlog a = 0)
    return Lc + 0.5 * np.log(2 * np.pi / np.maximum(-h, 1e-300)), a


def unit_templates(cands, K, shifts, ext):
    """(len(cands) * len(shifts), K, B) templates per e- of budget: ext Q bwin / K (Eqs. 5-6)."""
    U = []
    for b in cands:
        wm = np.maximum(render.window_means(b.brf, K, shifts), 0.0)     # (S, B, K)
        U.extend(((ext * b.chroma)[:, None] * wm / K).transpose(0, 2, 1))
    return np.asarray(U)


FINE = 16            # continuous phases: sub-cells per grid cell around each bulb's peak
FINE_HALF = 2.5      # ... over +-2.5 grid cells (the 5 cells nearest the peak are replaced)


def oracle_worker(job):
    capdir, truth_lights, csv, radius, idx = job
    cap, cube = read_capture(capdir)
    truth = json.load(open(os.path.join(capdir, "truth.json")))
    prm = truth["params"]
    K, B = cap["K"], cap["bands"]
    cands = render.candidate_bulbs(render.read_delight_csv(csv), cap["grid_hz"], B)
    nb = len(cands)
    ext = np.asarray(truth.get("extinction", [1.0] * B))
    phases = truth.get("phase_set_deg")
    if phases is None:                                    # continuous: a grid of delays
        G = max(4 * K, 64)
        shifts = np.arange(G) / G
    else:
        shifts = render.phase_to_shift(np.asarray(phases, float))
    U = unit_templates(cands, K, shifts, ext)
    sigma, sky, scint = prm["sigma_px"], prm["sky"], prm.get("scintillation", 0.0)
    rr = int(math.ceil(radius))
    out = []
    for i in idx:
        t = truth_lights[i]
        x0, y0 = t["x_px"], t["y_px"]
        cx, cy = int(round(x0)), int(round(y0))
        ys, xs = np.mgrid[cy - rr:cy + rr + 1, cx - rr:cx + rr + 1]
        sel = ((xs - x0) ** 2 + (ys - y0) ** 2 <= radius ** 2) & (xs >= 0) & (ys >= 0) & \
              (xs < cap["width"]) & (ys < cap["height"])
        xs, ys = xs[sel], ys[sel]
        # pixel-integrated Gaussian, as render.psf_stamp
        ix0, iy0, st = render.psf_stamp(x0, y0, sigma, int(math.ceil(5 * sigma)))
        psf = np.zeros(len(xs))
        inside = (xs - ix0 >= 0) & (xs - ix0 < st.shape[1]) & (ys - iy0 >= 0) & (ys - iy0 < st.shape[0])
        psf[inside] = st[ys[inside] - iy0, xs[inside] - ix0]
        raw = cube[:, ys, xs, :].transpose(1, 0, 2)                    # (P, K, B)
        ss = SampleSet(raw, psf, cap, sky)
        logm, ahat = oracle_light(ss, U, scint)
        # points of the posterior: (bulb index, delay in cycles, log mass, brightness)
        pb = np.repeat(np.arange(nb), len(shifts))
        ps = np.tile(shifts, nb)
        if phases is not None:                            # discrete: uniform prior over pairs
            pm, pa = logm, ahat
        else:
            # continuous: uniform density over the delay; each grid cell has mass exp(L)/G
            # (periodic trapezoid rule), but a peak narrower than a cell is integrated on a
            # FINE-times finer grid over the +-FINE_HALF cells around each plausible bulb's peak
            L2 = logm.reshape(nb, G)
            lw = np.full((nb, G), -math.log(G))
            fb, fs, fm, fa = [], [], [], []
            for b in np.nonzero(L2.max(axis=1) >= L2.max() - 30.0)[0]:
                g0 = int(np.argmax(L2[b]))
                u = (np.arange(int(2 * FINE_HALF * FINE)) - (FINE_HALF * FINE - 0.5)) / FINE
                sf = ((g0 + u) / G) % 1.0
                lf, af = oracle_light(ss, unit_templates([cands[b]], K, sf, ext), scint)
                lw[b, (g0 + np.arange(-2, 3)) % G] = -np.inf                # replaced by the fine cells
                fb += [b] * len(sf)
                fs += list(sf)
                fm += list(lf - math.log(G * FINE))
                fa += list(af)
            pb = np.concatenate([pb, np.array(fb, int)])
            ps = np.concatenate([ps, np.array(fs)])
            pm = np.concatenate([(L2 + lw).ravel(), np.array(fm)])
            pa = np.concatenate([ahat, np.array(fa)])
        post = np.exp(pm - pm.max())
        post /= post.sum()
        ph_all = ps * 180.0
        if phases is not None:                    # the posterior mode of the pairs
            j = int(np.argmax(post))
            bj, ph = int(pb[j]), float(ph_all[j])
            win = np.abs(phase_err_deg(ph_all, ph)) < 1e-6
        else:
            # the answer that maximises the posterior probability of being right: the bulb and
            # its peak phase whose +-30 deg window (the recogniser's pair) holds the most mass
            best = (-1.0, 0, 0.0, 0)
            for b in np.unique(pb[post > 1e-12 * post.max()]):
                jb = int(np.argmax(np.where(pb == b, post, -1.0)))
                mass = float(post[(pb == b) & (np.abs(phase_err_deg(ph_all, ph_all[jb])) <= 30.0)].sum())
                if mass > best[0]:
                    best = (mass, b, float(ph_all[jb]), jb)
            _, bj, ph, j = best
            win = np.abs(phase_err_deg(ph_all, ph)) <= 30.0
        same_b = pb == bj
        out.append(dict(i=i, bulb=cands[bj].id, technology=cands[bj].tech, phase_deg=ph,
                        confidence=float(post[same_b & win].sum()),
                        bulb_confidence=float(post[same_b].sum()),
                        phase_confidence=float(post[win].sum()),
                        brightness_e=float(pa[j]), templates_kept=int(np.isfinite(logm).sum())))
    return out


def run_oracle(capdir, truth_lights, which, csv, radius, jobs):
    chunks = [which[k::jobs] for k in range(jobs)] if jobs > 1 else [which]
    jobs_ = [(capdir, truth_lights, csv, radius, c) for c in chunks if c]
    res = []
    if jobs > 1:
        with ProcessPoolExecutor(jobs) as ex:
            for r in ex.map(oracle_worker, jobs_):
                res += r
    else:
        for j in jobs_:
            res += oracle_worker(j)
    return {r["i"]: r for r in res}


# --------------------------------------------------------------------------------------------
# Scoring
# --------------------------------------------------------------------------------------------

def run_recognize(binary, capdir, extra):
    cmd = [binary, "recognize", capdir, "--format", "json"] + extra
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)}: exit {p.returncode}: {p.stderr.strip()}")
    return json.loads(p.stdout), cmd


def with_min_conf_zero(extra):
    """The recogniser options with any --ambiguous-below replaced by 0."""
    out, it = [], iter(extra)
    for a in it:
        if a == "--ambiguous-below":
            next(it, None)
        elif not a.startswith("--ambiguous-below="):
            out.append(a)
    return out + ["--ambiguous-below", "0"]


def best_guess(l, l0):
    """(bulb, technology, phase, pair confidence, answered) of a reported light l; l0 is the
    same light from the --ambiguous-below 0 run (its phase for phase-ambiguous lights)."""
    if l["bulb"] is None:                                # unknown / dim: best fit within DELIGHT
        ru = l.get("runner_up") or {}
        return ru.get("bulb"), ru.get("technology"), ru.get("phase_deg"), float(ru.get("confidence", 0.0)), False
    ph = l["phase_deg"] if l["phase_deg"] is not None else l0["phase_deg"]
    answered = not ({"phase_ambiguous", "bulb_ambiguous"} & set(l["flags"]))
    return l["bulb"], l["technology"], ph, float(l["confidence"]), answered


def fmt(x, nd=3):
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    return f"{x:.{nd}f}" if isinstance(x, float) else str(x)


def selftest():
    """The oracle's exact likelihood against a brute-force sum over every n, its normalisation
    over all raw values, and its derivatives against finite differences."""
    cap = {"gain_e_per_dn": 1.7, "read_noise_dn": 1.3, "black_level": 20.0, "saturation": 65535}
    worst = worst_d = 0.0
    for mu0 in (0.3, 4.0, 40.0, 400.0):
        x = np.arange(0, int(20 + mu0 / 1.7 + 12 * math.sqrt(mu0 + 5) + 40))       # all raw values with mass
        ss = SampleSet(x[:, None, None], np.ones(len(x)), cap, 0.0)
        lp_each = []
        for xi in range(len(x)):                       # brute force: every n, full rounded kernel
            n = np.arange(0, int(mu0 + 40 * math.sqrt(mu0 + 1) + 60))
            lpois = n * math.log(mu0) - mu0 - np.vectorize(math.lgamma)(n + 1.0)
            m = n / 1.7 + 20.0
            lq = _log_phi_diff((x[xi] - 0.5 - m) / 1.3, (x[xi] + 0.5 - m) / 1.3)
            lp_each.append(np.logaddexp.reduce(lpois + lq))
        lp_each = np.array(lp_each)
        mu = np.full((1, len(x)), mu0)
        w = ss.n[None] * np.log(mu)[..., None] + ss.lq[None]
        mine = np.logaddexp.reduce(w, axis=-1)[0] - mu0
        sel = lp_each > -15                            # samples that matter (not far-off templates)
        worst = max(worst, float(np.abs(mine[sel] - lp_each[sel]).max()))
        tot = float(np.exp(lp_each).sum())
        worst = max(worst, abs(tot - 1.0))
        _, d1, d2 = ss.exact(mu)
        eps = 1e-4 * mu0
        lpp = np.logaddexp.reduce(ss.n[None] * np.log(mu + eps)[..., None] + ss.lq[None], axis=-1)[0] - (mu0 + eps)
        lpm = np.logaddexp.reduce(ss.n[None] * np.log(mu - eps)[..., None] + ss.lq[None], axis=-1)[0] - (mu0 - eps)
        fd1, fd2 = (lpp - lpm) / (2 * eps), (lpp - 2 * mine + lpm) / eps ** 2
        worst_d = max(worst_d, float(np.abs(fd1 - d1[0])[sel].max() / (1 + np.abs(d1[0][sel]).max())),
                      float(np.abs(fd2 - d2[0])[sel].max() / (1 + np.abs(d2[0][sel]).max()) * 1e-2))
    # the interpolated table against the direct sum, on a light-like sample set
    rng = np.random.default_rng(3)
    mu_t = np.concatenate([rng.uniform(0, 300, (5, 400)) * rng.uniform(0, 1, (1, 400)) ** 3,
                           np.full((1, 400), 1e-6), np.full((1, 400), 1e-3)])
    raw = np.rint(20 + rng.poisson(mu_t[0]) / 1.7 + 1.3 * rng.standard_normal(400))
    ss = SampleSet(raw[:, None, None], np.ones(400), cap, 0.0)
    tab = ExactTable(ss, float(mu_t.max()))
    lp_d, d1_d, _ = ss.exact(mu_t)
    lp_t, d1_t, _ = tab(mu_t)
    worst_t = float(np.abs(lp_t - lp_d).max() / 400)
    worst_t1 = float((np.abs(d1_t - d1_d) / (1 + np.abs(d1_d)))[:5].max())
    print(f"table vs direct: |log p| per sample {worst_t:.1e} nats, |d log p/dmu| (relative) {worst_t1:.1e}")
    print(f"exact Poisson-Gaussian: max |log p - brute force| and |sum p - 1|: {worst:.2e}; "
          f"derivatives vs finite differences: {worst_d:.2e}")
    ok = worst < 1e-6 and worst_d < 1e-4 and worst_t < 1e-6 and worst_t1 < 1e-4   # 3e-9 nats where log p ~ -30 (window edge)
    print("selftest", "ok" if ok else "FAILED")
    return 0 if ok else 1


def strict_json(x):
    """NaN and infinities as null: JSON has no such numbers (RFC 8259)."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: strict_json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [strict_json(v) for v in x]
    return x


def main(argv=None):
    if argv is None and sys.argv[1:2] == ["--selftest"]:
        return selftest()
    ap = argparse.ArgumentParser(
        description="Score `gridsurvey recognize` on a render.py capture: detection, accuracy, "
                    "calibration, and a maximum-likelihood oracle with render.py's forward model. "
                    "Unknown options (or everything after --) go to `gridsurvey recognize`.")
    ap.add_argument("capdir")
    ap.add_argument("--bin", default=os.path.join(os.path.dirname(__file__), "..", "..", "build", "gridsurvey"))
    ap.add_argument("--delight-csv", required=True, help="the CSV render.py used")
    ap.add_argument("--radius", type=float, default=2.0, help="matching radius, px")
    ap.add_argument("--phase-tol", type=float, default=1.0, help="discrete phase tolerance, deg")
    ap.add_argument("--no-oracle", action="store_true")
    ap.add_argument("--oracle-radius", type=float, default=3.5, help="oracle pixel disc radius, px")
    ap.add_argument("--oracle-max", type=int, default=0, help="oracle on at most this many lights (0 = all)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--json", metavar="FILE", help="also write the results as JSON ('-' = stdout only)")
    ap.add_argument("--label", default="")
    a, extra = ap.parse_known_args(argv)
    extra = [x for x in extra if x != "--"]

    truth = json.load(open(os.path.join(a.capdir, "truth.json")))
    tl = truth["lights"]
    continuous = truth.get("phase_set_deg") is None
    rep, cmd = run_recognize(a.bin, a.capdir, extra)
    rep0, _ = run_recognize(a.bin, a.capdir, with_min_conf_zero(extra))
    L, L0 = rep["lights"], rep0["lights"]
    assert len(L) == len(L0) and all(
        (x["id"], x["x"], x["y"], x["bulb"], x["confidence"]) == (y["id"], y["x"], y["y"], y["bulb"], y["confidence"])
        for x, y in zip(L, L0)), "--ambiguous-below 0 changed more than the flags"

    m = match_lights(tl, L, a.radius)
    cls = lambda t: "blend" if "blend" in t["flags"] else ("out_of_db" if t.get("out_of_db") else "isolated")
    res = {"capdir": a.capdir, "label": a.label, "command": " ".join(cmd),
           "params": truth["params"], "reported": len(L), "truth": len(tl)}
    res["false_detections"] = len(L) - len(m)
    res["detection"] = {c: (sum(1 for i, t in enumerate(tl) if cls(t) == c and i in m),
                            sum(1 for t in tl if cls(t) == c)) for c in ("isolated", "blend", "out_of_db")}

    # ---- isolated in-database lights ---------------------------------------------------------
    iso = [i for i, t in enumerate(tl) if cls(t) == "isolated" and i in m]
    rows = []
    for i in iso:
        t, l, l0 = tl[i], L[m[i]], L0[m[i]]
        bulb, tech, ph, conf, answered = best_guess(l, l0)
        ph_ok = ph is not None and (abs(phase_err_deg(ph, t["phase_deg"])) <= (30.0 if continuous else a.phase_tol))
        rows.append(dict(i=i, bulb=bulb, phase=ph, bulb_ok=bulb == t["bulb"], tech_ok=tech == t["technology"], phase_ok=bool(ph_ok),
                         conf=conf, bconf=float(l["bulb_confidence"]), pconf=float(l["phase_confidence"]),
                         has_bulb=l["bulb"] is not None, answered=answered, flags=l["flags"],
                         chi2dof=l["chi2"] / l["dof"] if l["dof"] > 0 else float("nan"),
                         perr=phase_err_deg(ph, t["phase_deg"]) if ph is not None else float("nan"),
                         psig=l0["phase_sigma_deg"] if l0["phase_sigma_deg"] is not None else float("nan")))
    n = len(rows)

    def R(key):
        """Column `key` of the matched lights as an array (float or bool)."""
        vals = [r[key] for r in rows]
        return np.array(vals, dtype=bool if isinstance(vals[0], (bool, np.bool_)) else float)

    if n:
        pair = R("bulb_ok") & R("phase_ok")
        hb, ans = R("has_bulb"), R("answered")
        conf = R("conf")
        flag = lambda f: np.array([f in r["flags"] for r in rows])
        res["matched"] = n
        res["pair_acc"] = float(pair.mean())
        res["bulb_acc"] = float(R("bulb_ok").mean())
        res["tech_acc"] = float(R("tech_ok").mean())
        res["phase_acc"] = float(R("phase_ok").mean())
        res["answered_share"] = float(ans.mean())
        res["answered_acc"] = float(pair[ans].mean()) if ans.any() else float("nan")
        res["unknown_share"] = float(flag("unknown").mean())
        res["dim_share"] = float(flag("dim").mean())
        res["phase_amb_share"] = float(flag("phase_ambiguous").mean())
        res["phase_amb_but_right"] = float((flag("phase_ambiguous") & R("phase_ok") & hb).mean())
        res["bulb_amb_share"] = float(flag("bulb_ambiguous").mean())
        res["ece_pair"], res["ece_pair_table"] = ece(conf[hb], pair[hb])
        res["ece_pair_null_p99"], res["ece_pair_p"] = ece_null(conf[hb], res["ece_pair"])
        res["ece_bulb"], _ = ece(R("bconf")[hb], R("bulb_ok")[hb])
        res["ece_phase"], _ = ece(R("pconf")[hb], R("phase_ok")[hb])
        res["mean_conf"] = float(conf[hb].mean()) if hb.any() else float("nan")
        hi = (conf > 0.9) & ans
        na = max(int(ans.sum()), 1)
        res["confident_wrong"] = {"bulb": float((hi & ~R("bulb_ok")).sum() / na),
                                  "technology": float((hi & ~R("tech_ok")).sum() / na),
                                  "phase": float((hi & ~R("phase_ok")).sum() / na),
                                  "any": float((hi & ~pair).sum() / na)}
        res["median_chi2_dof"] = float(np.nanmedian(R("chi2dof")))
        res["mean_chi2_dof"] = float(np.nanmean(R("chi2dof")))
        if continuous:
            z = R("perr") / R("psig")
            zz = z[np.isfinite(z) & R("bulb_ok")]
            res["phase_z_rms"] = float(np.sqrt(np.mean(zz ** 2))) if zz.size else float("nan")
            res["phase_err_rms_deg"] = float(np.sqrt(np.nanmean(R("perr")[R("bulb_ok")] ** 2)))

    # ---- oracle ---------------------------------------------------------------------------
    if not a.no_oracle and truth.get("free_running"):
        print("  (no oracle: its templates are Eq. 5's regular windows, not this free-running capture's)")
    elif not a.no_oracle:
        allidx = [i for i, t in enumerate(tl) if cls(t) == "isolated"]
        if a.oracle_max:
            allidx = allidx[:a.oracle_max]
        orc = run_oracle(a.capdir, tl, allidx, a.delight_csv, a.oracle_radius, a.jobs)

        def o_stats(idxs):
            if not idxs:
                return {}
            ok_b = np.array([orc[i]["bulb"] == tl[i]["bulb"] for i in idxs])
            ok_p = np.array([abs(phase_err_deg(orc[i]["phase_deg"], tl[i]["phase_deg"])) <= (30.0 if continuous else a.phase_tol) for i in idxs])
            pc = np.array([orc[i]["confidence"] for i in idxs])
            e, tab = ece(pc, ok_b & ok_p)
            return {"n": len(idxs), "pair_acc": float((ok_b & ok_p).mean()), "bulb_acc": float(ok_b.mean()),
                    "phase_acc": float(ok_p.mean()), "ece_pair": e,
                    "ece_bulb": ece([orc[i]["bulb_confidence"] for i in idxs], ok_b)[0],
                    "ece_phase": ece([orc[i]["phase_confidence"] for i in idxs], ok_p)[0],
                    "mean_conf": float(pc.mean()), "ece_pair_table": tab,
                    "templates_kept_mean": float(np.mean([orc[i]["templates_kept"] for i in idxs]))}
        res["oracle_all"] = o_stats(allidx)
        res["oracle_matched"] = o_stats([r["i"] for r in rows if r["i"] in orc])
        if rows and res["oracle_matched"]:
            sub = [r for r in rows if r["i"] in orc]
            rp = np.array([r["bulb_ok"] and r["phase_ok"] for r in sub])
            op = np.array([orc[r["i"]]["bulb"] == tl[r["i"]]["bulb"] and
                           abs(phase_err_deg(orc[r["i"]]["phase_deg"], tl[r["i"]]["phase_deg"])) <= (30.0 if continuous else a.phase_tol)
                           for r in sub])
            res["recognizer_pair_acc_on_oracle_set"] = float(rp.mean())
            res["disc"] = float((rp != op).mean())       # share where exactly one is right

    # ---- blends -----------------------------------------------------------------------------
    pairs = [(i, t["blend_partner"]) for i, t in enumerate(tl) if "blend" in t["flags"] and i < t["blend_partner"]]
    if pairs:
        sep = truth["params"]["blend_sep"]
        one_blob = conf_wrong_neither = conf_one_member = resolved = 0
        for i, j in pairs:
            mx = 0.5 * (tl[i]["x_px"] + tl[j]["x_px"])
            my = 0.5 * (tl[i]["y_px"] + tl[j]["y_px"])
            near = [r for r in L if math.hypot(r["x"] - mx, r["y"] - my) <= 0.5 * sep + a.radius]
            if len(near) >= 2:
                resolved += 1
            if len(near) == 1:
                one_blob += 1
                r = near[0]
                confident = r["bulb"] is not None and r["confidence"] > 0.9
                if confident and r["bulb"] not in (tl[i]["bulb"], tl[j]["bulb"]):
                    conf_wrong_neither += 1
                elif confident:
                    conf_one_member += 1
        res["blends"] = {"pairs": len(pairs), "one_blob": one_blob, "resolved_2plus": resolved,
                         "one_blob_confident_bulb_of_neither": conf_wrong_neither,
                         "one_blob_confident_bulb_of_one_member": conf_one_member}

    # ---- out-of-database lights -------------------------------------------------------------
    ood = [i for i, t in enumerate(tl) if t.get("out_of_db")]
    if ood:
        det = [i for i in ood if i in m]
        famt = lambda s: (s or "").split("_")[0]
        o = {"lights": len(ood), "detected": len(det)}
        o["unknown"] = sum("unknown" in L[m[i]]["flags"] for i in det)
        o["with_bulb"] = sum(L[m[i]]["bulb"] is not None for i in det)
        o["conf_gt_0.9_other_technology"] = sum(
            L[m[i]]["bulb"] is not None and L[m[i]]["confidence"] > 0.9 and L[m[i]]["technology"] != tl[i]["technology"] for i in det)
        o["conf_gt_0.9_other_family"] = sum(
            L[m[i]]["bulb"] is not None and L[m[i]]["confidence"] > 0.9 and famt(L[m[i]]["technology"]) != famt(tl[i]["technology"]) for i in det)
        o["bulb_conf_gt_0.9_other_technology"] = sum(
            L[m[i]]["bulb"] is not None and L[m[i]]["bulb_confidence"] > 0.9 and L[m[i]]["technology"] != tl[i]["technology"] for i in det)
        o["called"] = {}
        for i in det:
            k = L[m[i]]["technology"] or "none(" + ",".join(L[m[i]]["flags"]) + ")"
            o["called"][k] = o["called"].get(k, 0) + 1
        o["median_chi2_dof"] = float(np.median([L[m[i]]["chi2"] / max(L[m[i]]["dof"], 1) for i in det])) if det else float("nan")
        res["out_of_db"] = o

    # ---- per light (matched isolated lights), for drilling down -------------------------------
    orc_ = locals().get("orc", {})
    res["per_light"] = [dict(truth_id=r["i"], truth_bulb=tl[r["i"]]["bulb"], truth_phase=tl[r["i"]]["phase_deg"],
                             bulb=r["bulb"], phase=r["phase"], conf=r["conf"], flags=r["flags"],
                             chi2_dof=r["chi2dof"], phase_sigma=r["psig"],
                             oracle_bulb=orc_.get(r["i"], {}).get("bulb"),
                             oracle_phase=orc_.get(r["i"], {}).get("phase_deg"),
                             oracle_conf=orc_.get(r["i"], {}).get("confidence"))
                        for r in rows]
    print_table(res)
    if a.json:
        s = json.dumps(strict_json(res), indent=1, allow_nan=False)
        if a.json == "-":
            print(s)
        else:
            with open(a.json, "w") as f:
                f.write(s + "\n")
    return 0


def print_table(r):
    p = r["params"]
    print(f"# {r['label'] or r['capdir']}: {p['width']}x{p['height']} K={p['K']} {p['grid_hz']} Hz "
          f"bands={p['bands']} e-/light={p['electrons']} phases={p['phases']}")
    print(f"  command: {r['command']}")
    d = r["detection"]
    print("  detected: " + ", ".join(f"{c} {a}/{b}" for c, (a, b) in d.items() if b) +
          f"; false detections {r['false_detections']}")
    if "matched" in r:
        cw = r["confident_wrong"]
        print(f"  {'metric':42s} recognizer   oracle(matched)")
        o = r.get("oracle_matched", {})
        lines = [("pair accuracy (best guess)", r["pair_acc"], o.get("pair_acc")),
                 ("bulb accuracy", r["bulb_acc"], o.get("bulb_acc")),
                 ("phase accuracy", r["phase_acc"], o.get("phase_acc")),
                 ("technology accuracy", r["tech_acc"], None),
                 ("answered share", r["answered_share"], None),
                 ("accuracy of answered", r["answered_acc"], None),
                 ("phase_ambiguous share", r["phase_amb_share"], None),
                 ("phase_ambiguous but best phase right", r["phase_amb_but_right"], None),
                 ("bulb_ambiguous share", r["bulb_amb_share"], None),
                 ("unknown / dim share", r["unknown_share"] + r["dim_share"], None),
                 ("ECE pair", r["ece_pair"], o.get("ece_pair")),
                 ("ECE bulb", r["ece_bulb"], o.get("ece_bulb")),
                 ("ECE phase", r["ece_phase"], o.get("ece_phase")),
                 ("mean pair confidence", r["mean_conf"], o.get("mean_conf")),
                 ("confident (>0.9) wrong bulb / answered", cw["bulb"], None),
                 ("confident (>0.9) wrong technology / answered", cw["technology"], None),
                 ("confident (>0.9) wrong phase / answered", cw["phase"], None),
                 ("median chi2/dof", r["median_chi2_dof"], None)]
        if "phase_z_rms" in r:
            lines.append(("RMS phase error / reported sigma", r["phase_z_rms"], None))
            lines.append(("RMS phase error, deg", r["phase_err_rms_deg"], None))
        for name, x, y in lines:
            print(f"  {name:42s} {fmt(x):>10s}   {fmt(y):>10s}")
        if "oracle_all" in r and r["oracle_all"]:
            oa = r["oracle_all"]
            print(f"  oracle on all {oa['n']} isolated lights: pair {fmt(oa['pair_acc'])}, bulb {fmt(oa['bulb_acc'])}, "
                  f"phase {fmt(oa['phase_acc'])}, ECE {fmt(oa['ece_pair'])}; disc {fmt(r.get('disc'))}")
    if "blends" in r:
        print("  blends: " + ", ".join(f"{k} {v}" for k, v in r["blends"].items()))
    if "out_of_db" in r:
        print("  out of DB: " + ", ".join(f"{k} {v}" for k, v in r["out_of_db"].items()))


if __name__ == "__main__":
    sys.exit(main())
