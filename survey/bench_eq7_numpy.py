#!/usr/bin/python3
"""bench_eq7_numpy.py - Eq. 7 per pixel in NumPy, for `gridsurvey bench recognize --numpy`
(survey/bench.c), in its best NumPy form: float32 scores of a block of rows against every unit
template as matrix products, the rest vectorised. Unit noise. Two searches:

  chroma  the paper's model, the search of bench.c's triple-loop reference: one brightness per
          pixel times the chromaticity; L = -chi2/2 - log|t| + log Phi(z), z = x.t/|t|; no answer
          when z < min_snr or chi2 = |x|^2 - z^2 > the unknown threshold
  free    the survey's defaults per pixel (free band gains, docs/recognition.md): a brightness
          per band, each band of a template at mean 1;
          L = sum_b [log Phi(z_b) - log|t_b|] - (|x|^2 - sum_b z_b^2)/2,
          z_b = x_b.t_b/|t_b|; no answer when the summed brightness's SNR
          (sum_b z_b/|t_b|) / sqrt(sum_b 1/|t_b|^2) < min_snr or chi2 = |x|^2 - sum_b max(z_b, 0)^2
          > the unknown threshold

usage: bench_eq7_numpy.py DIR   (DIR holds t.f64 [M x D], x.f32 [P x D], params.txt
"M D P min_snr chi2_thr reps [chroma|free bands]"; writes answers.i32 [P] (template index or
-1) and seconds.txt, the best of reps runs)
example: OPENBLAS_NUM_THREADS=1 bench_eq7_numpy.py /tmp/bench-numpy
"""
import os
import sys
import time

import numpy as np

BLOCK = 1 << 15   # rows per matrix product


def log_phi(z):
    """log Phi(z) from erfc in log form (Numerical Recipes' erfcc, relative error < 1.2e-7)."""
    x = np.abs(z) / np.sqrt(2.0)
    t = 1.0 / (1.0 + 0.5 * x)
    poly = (-x * x - 1.26551223 + t * (1.00002368 + t * (0.37409196 + t * (0.09678418 + t * (
        -0.18628806 + t * (0.27886807 + t * (-1.13520398 + t * (1.48851587 + t * (
            -0.82215223 + t * 0.17087277)))))))))
    log_erfc = np.log(t) + poly                      # log erfc(|z| / sqrt 2)
    return np.where(z < 0.0, np.log(0.5) + log_erfc, np.log1p(-0.5 * np.exp(log_erfc)))


def search(x, tn32, lognorm, min_snr, chi2_thr):
    out = np.empty(x.shape[0], dtype=np.int32)
    for r0 in range(0, x.shape[0], BLOCK):
        xb = x[r0:r0 + BLOCK]
        z = xb @ tn32.T                                  # [rows x M] normalised scores
        sxx = np.einsum("ij,ij->i", xb, xb, dtype=np.float64)
        z64 = z.astype(np.float64)
        L = 0.5 * z64 * z64 - lognorm + log_phi(z64)     # + -Sxx/2, the same for every template
        best = np.argmax(L, axis=1)
        zb = z64[np.arange(len(best)), best]
        ok = (zb >= min_snr) & (sxx - zb * zb <= chi2_thr)
        out[r0:r0 + BLOCK] = np.where(ok, best, -1)
    return out


def prepare_free(t, bands):
    """The free model's per-band unit templates (float32), sum_b log|t_b|, 1/|t_b| and the
    summed brightness's SNR denominator, each band of a template at mean 1."""
    M, D = t.shape
    tb = t.reshape(M, bands, D // bands)
    tb = tb / tb.mean(axis=2, keepdims=True)     # each band at mean 1 (its gain is free)
    bn = np.linalg.norm(tb, axis=2)                                  # [M x bands]
    ub32 = [(tb[:, b, :] / bn[:, b:b + 1]).astype(np.float32) for b in range(bands)]
    ibn = 1.0 / bn
    return ub32, np.log(bn).sum(axis=1), ibn, np.sqrt((ibn * ibn).sum(axis=1))


def search_free(x, prep, min_snr, chi2_thr):
    ub32, blog, ibn, snr_den = prep
    bands, M, K = len(ub32), len(blog), ub32[0].shape[1]
    out = np.empty(x.shape[0], dtype=np.int32)
    for r0 in range(0, x.shape[0], BLOCK):
        xb = x[r0:r0 + BLOCK]
        sxx = np.einsum("ij,ij->i", xb, xb, dtype=np.float64)
        n = xb.shape[0]
        L = np.empty((n, M))
        L[:] = -blog
        num = np.zeros((n, M))
        gain = np.zeros((n, M))
        for b in range(bands):
            z = (xb[:, b * K:(b + 1) * K] @ ub32[b].T).astype(np.float64)   # [rows x M]
            L += 0.5 * z * z
            L += log_phi(z)
            num += z * ibn[:, b]
            zp = np.maximum(z, 0.0)
            gain += zp * zp
        best = np.argmax(L, axis=1)
        rows = np.arange(len(best))
        snr = num[rows, best] / snr_den[best]
        ok = (snr >= min_snr) & (sxx - gain[rows, best] <= chi2_thr)
        out[r0:r0 + BLOCK] = np.where(ok, best, -1)
    return out


def main():
    if len(sys.argv) != 2 or sys.argv[1] in ("-h", "--help"):
        print(__doc__)
        return 0 if len(sys.argv) == 2 else 2
    d = sys.argv[1]
    with open(os.path.join(d, "params.txt")) as f:
        fields = f.read().split()
    M, D, P, min_snr, chi2_thr, reps = fields[:6]
    model, bands = (fields[6], int(fields[7])) if len(fields) > 6 else ("chroma", 1)
    M, D, P, reps = int(M), int(D), int(P), int(reps)
    min_snr, chi2_thr = float(min_snr), float(chi2_thr)
    t = np.fromfile(os.path.join(d, "t.f64"), dtype=np.float64).reshape(M, D)
    x = np.fromfile(os.path.join(d, "x.f32"), dtype=np.float32).reshape(P, D)
    norm = np.linalg.norm(t, axis=1)
    tn32 = (t / norm[:, None]).astype(np.float32)
    lognorm = np.log(norm)
    prep = prepare_free(t, bands) if model == "free" else None
    best_s = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        if model == "free":
            ans = search_free(x, prep, min_snr, chi2_thr)
        else:
            ans = search(x, tn32, lognorm, min_snr, chi2_thr)
        best_s = min(best_s, time.perf_counter() - t0)
    ans.tofile(os.path.join(d, "answers.i32"))
    with open(os.path.join(d, "seconds.txt"), "w") as f:
        f.write("%.9f\n" % best_s)
    return 0


if __name__ == "__main__":
    sys.exit(main())
