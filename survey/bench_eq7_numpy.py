#!/usr/bin/python3
"""bench_eq7_numpy.py - the paper's Eq. 7 per pixel in NumPy, for `gridsurvey bench recognize
--numpy` (survey/bench.c): the same search as its triple-loop reference (one brightness per
pixel, chromaticity templates, unit noise; L = -chi2/2 - log|t| + log Phi(z), z = x.t/|t|; no
answer when z < min_snr or chi2 > the unknown threshold), in its best NumPy form: float32 scores
of a block of rows against every unit template as one matrix product, the rest vectorised.

usage: bench_eq7_numpy.py DIR   (DIR holds t.f64 [M x D], x.f32 [P x D], params.txt
"M D P min_snr chi2_thr reps"; writes answers.i32 [P] (template index or -1) and seconds.txt,
the best of reps runs)
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


def main():
    if len(sys.argv) != 2 or sys.argv[1] in ("-h", "--help"):
        print(__doc__)
        return 0 if len(sys.argv) == 2 else 2
    d = sys.argv[1]
    with open(os.path.join(d, "params.txt")) as f:
        M, D, P, min_snr, chi2_thr, reps = f.read().split()
    M, D, P, reps = int(M), int(D), int(P), int(reps)
    min_snr, chi2_thr = float(min_snr), float(chi2_thr)
    t = np.fromfile(os.path.join(d, "t.f64"), dtype=np.float64).reshape(M, D)
    x = np.fromfile(os.path.join(d, "x.f32"), dtype=np.float32).reshape(P, D)
    norm = np.linalg.norm(t, axis=1)
    tn32 = (t / norm[:, None]).astype(np.float32)
    lognorm = np.log(norm)
    best_s = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        ans = search(x, tn32, lognorm, min_snr, chi2_thr)
        best_s = min(best_s, time.perf_counter() - t0)
    ans.tofile(os.path.join(d, "answers.i32"))
    with open(os.path.join(d, "seconds.txt"), "w") as f:
        f.write("%.9f\n" % best_s)
    return 0


if __name__ == "__main__":
    sys.exit(main())
