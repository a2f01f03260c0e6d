#!/usr/bin/python3
"""Independent mean grid frequency of a mains recording (16-bit PCM WAV), for checking Eq. 1 from
zero crossings (recognize/base/ac.c, gs_grid_frequency) on shared/data/mains.

The oracle does not use zero crossings for the frequency: the fundamental's phase is fitted by
linear least squares (DC, harmonics 1..3 at the block's own frequency, refined three times, and a
linear amplitude/phase drift) over 0.2 s around the time asked, and the mean frequency over
[ta, tb] is the phase advance / (2 pi (tb - ta)). Its span is that of gs_grid_frequency's mean
with no period rejected: from the midpoint of the first two crossings to that of the last two
(found here by linear interpolation; an error in ta or tb moves this estimate only to second
order). On synthetic 400 Hz recordings with a wandering frequency, a 3rd harmonic whose phase
drifts and 16-bit quantisation it recovers the exact mean within 1.1e-7 Hz (six records).

    /usr/bin/python3 tests/independent/mains_oracle.py ../shared/data/mains/whu_00*_ref.wav

With --frames FIRST STEP C K it prints instead, for acquisitions k = 0..K-1 spanning the C half
periods from crossing FIRST + k STEP of the recording (crossing 0 its first rising one, as
docs/scene.md's trace timeline), each one's start (s after acquisition 0's) and mean frequency
C / (2 (t_end - t_start)) (Eq. 1), on crossings of the fundamental: each crossing found by sign
change, then moved to where the fitted fundamental's phase crosses (its offset from the
waveform's own crossing, through the harmonics, cancels between crossings of one polarity).

    /usr/bin/python3 tests/independent/mains_oracle.py --frames 64 310 300 4 whu_001_ref.wav
"""
import sys, wave
import numpy as np


def read_wav(path):
    w = wave.open(path)
    if w.getsampwidth() != 2 or w.getnchannels() != 1:
        sys.exit(f"{path}: expected 16-bit mono PCM")
    x = np.frombuffer(w.readframes(w.getnframes()), dtype='<i2').astype(float) / 32768.0
    return x - x.mean(), float(w.getframerate())


def fundamental_phase(x, rate, t0, half_s=0.1, f_start=50.0):
    """Phase (rad, mod 2 pi) at time t0 of the cosine fitted to the fundamental."""
    i0, i1 = max(0, int((t0 - half_s) * rate)), min(len(x), int((t0 + half_s) * rate) + 1)
    u = np.arange(i0, i1) / rate - t0
    f = f_start
    for _ in range(3):
        w = 2 * np.pi * f
        cols = [np.ones_like(u)]
        for h in (1, 2, 3):
            cols += [np.cos(h * w * u), np.sin(h * w * u)]
        cols += [u * np.cos(w * u), u * np.sin(w * u)]
        c, *_ = np.linalg.lstsq(np.array(cols).T, x[i0:i1], rcond=None)
        a, b, da, db = c[1], c[2], c[7], c[8]
        f += (b * da - a * db) / (a * a + b * b) / (2 * np.pi)   # d/du of atan2(-(b + db u), a + da u)
    return np.arctan2(-b, a)


def frames(first, step, cycles, count, path):
    x, rate = read_wav(path)
    s = np.signbit(x)
    j = np.nonzero(s[1:] != s[:-1])[0]
    tc = (j + x[j] / (x[j] - x[j + 1])) / rate
    rising = ~s[j + 1]
    i0 = int(np.argmax(rising))
    f0 = (len(tc) - 1) / (2 * (tc[-1] - tc[0]))

    def crossing(i):   # the fundamental's: phase -pi/2 rising, +pi/2 falling (a cos(w u + phi))
        i += i0
        d = (-np.pi / 2 if rising[i] else np.pi / 2) - fundamental_phase(x, rate, tc[i], f_start=f0)
        return tc[i] + ((d + np.pi) % (2 * np.pi) - np.pi) / (2 * np.pi * f0)

    t_first = crossing(first)
    for k in range(count):
        t0, t1 = crossing(first + k * step), crossing(first + k * step + cycles)
        print(f"frame {k} {t0 - t_first:.9f} {cycles / (2 * (t1 - t0)):.9f}")


def main():
    if len(sys.argv) == 7 and sys.argv[1] == '--frames':
        frames(*(int(a) for a in sys.argv[2:6]), sys.argv[6])
        return
    for path in sys.argv[1:]:
        x, rate = read_wav(path)
        s = np.signbit(x)
        j = np.nonzero(s[1:] != s[:-1])[0]
        tc = (j + x[j] / (x[j] - x[j + 1])) / rate
        ta, tb = 0.5 * (tc[0] + tc[1]), 0.5 * (tc[-1] + tc[-2])
        f_cross = (len(tc) - 2) / (tc[-1] + tc[-2] - tc[1] - tc[0])   # whole cycles, to unwrap
        dphi = fundamental_phase(x, rate, tb) - fundamental_phase(x, rate, ta)
        k = np.round((2 * np.pi * f_cross * (tb - ta) - dphi) / (2 * np.pi))
        f = (dphi + 2 * np.pi * k) / (2 * np.pi * (tb - ta))
        # the 1-s windows of gs_frequency_wander, from the phase at whole seconds after ta
        edges = ta + np.arange(0.0, np.floor(tb - ta) + 0.5, 1.0)
        ph = np.unwrap([fundamental_phase(x, rate, e) - 2 * np.pi * 50.0 * (e - ta) for e in edges])
        fw = 50.0 + np.diff(ph) / (2 * np.pi)
        corr = lambda lag: np.corrcoef(fw[:-lag], fw[lag:])[0, 1]
        print(f"{path}: {len(tc)} crossings, mean over [{ta:.4f}, {tb:.4f}] s: {f:.9f} Hz; 1-s windows: "
              f"sigma {1e3 * fw.std(ddof=1):.2f} mHz, step {1e3 * np.diff(fw).std(ddof=1):.2f} mHz, "
              f"corr10 {corr(10):.3f}, corr60 {corr(60):.3f}")


if __name__ == '__main__':
    main()
