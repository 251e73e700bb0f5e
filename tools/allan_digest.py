"""An md5 digest of what the Allan analysis computes: the check that making it cheaper leaves its output
bit-identical.

    .venv/bin/python tools/allan_digest.py        # one line per part and one over all of them

Run it in two checkouts (the same command in each worktree) and compare the lines. Parts:
- `curve`: every field of the AllanCurve of records of 8 to 300 000 samples (1 to 4 axes, white, random-walk,
  flicker and Gauss–Markov noise on a bias), whole and fed to StreamingAllan in chunks of 1, 7, 1000 and 65 536
  samples, and at given cluster sizes (`allan_deviation(x, rate, m)`);
- `fit`: every field of the ModelFit of `terms._fit_fixed` (the IRLS fit) on the octave points of a record's three
  axes, without and with a sensor filter's white-noise deficit and its 1σ, for sets of terms, with a term held
  fixed (the deviance profile's fits) and over a grid of Gauss–Markov correlation times;
- `analysis`: every field of the AllanResult of `analyse_static` on records like the tests' (white with a rate
  random walk, with flicker, with a Gauss–Markov bias, with quantization; gyro, accelerometer and magnetometer).
The noise is tests/allan_noise.py's generators' (independent of the analysis), from fixed seeds.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path

import numpy as np

from sim_digest import feed   # tools/, beside this script: the same bits of every value as the simulator's digest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import allan_noise as gen  # noqa: E402


def _noise(n: int, rate_hz: float, seed: int, axes: int) -> np.ndarray:
    """(n, axes) rate samples: a bias of 0.3 with white, rate random walk, Gauss–Markov (from rest) and flicker noise
    on each axis; the flicker's filter cut to 4096 taps and convolved directly, as the digests were first made."""
    rng = np.random.default_rng(seed)
    white = gen.white((n, axes), rate_hz, 0.005, rng)
    walk = gen.rate_random_walk((n, axes), rate_hz, 2e-4, rng)
    gm = gen.gauss_markov((n, axes), rate_hz, 1e-3, 30.0, rng, from_rest=True)
    h = gen.kasdin_taps(min(n, 4096))
    flicker = np.stack([np.convolve(rng.standard_normal(n), h)[:n] * 1e-4 for _ in range(axes)], axis=1)
    return 0.3 + white + walk + gm + flicker


def curve_part() -> str:
    from ahrsd.calibration.allan.adev import StreamingAllan, allan_deviation

    h = hashlib.md5()
    for n, axes, seed in ((8, 1, 1), (29, 3, 2), (1000, 2, 3), (1000, 3, 7), (4099, 4, 8), (65_537, 3, 4),
                          (300_000, 3, 5), (100_003, 1, 6)):
        x = _noise(n, 100.0, seed, axes)
        feed(h, allan_deviation(x, 100.0))
        feed(h, allan_deviation(x, 100.0, m=np.array([1, 2, 3, 7, 20, max(1, n // 3)])))
        for chunk in (1, 7, 1000, 65_536):
            if chunk < 1000 and n > 5000:
                continue
            acc = StreamingAllan(100.0, axes)
            for start in range(0, n, chunk):
                acc.add(x[start:start + chunk])
            feed(h, acc.curve())
    return h.hexdigest()


def analysis_part() -> str:
    from ahrsd.calibration.allan.analysis import analyse_static

    h = hashlib.md5()
    for hours, rate, seed in ((0.25, 100.0, 11), (0.5, 50.0, 12)):
        n = int(hours * 3600 * rate)
        t = np.arange(n) / rate
        gyro = _noise(n, rate, seed, 3)
        rng = np.random.default_rng(seed + 100)
        accel = 9.81 * np.array([0.0, 0.0, 1.0]) + rng.standard_normal((n, 3)) * 0.02
        mag = np.round((np.array([20.0, 0.0, 45.0]) + rng.standard_normal((n, 3)) * 0.05) / 0.3) * 0.3
        feed(h, analyse_static(t, gyro, accel, mag))
    return h.hexdigest()


def fit_part() -> str:
    from ahrsd.calibration.allan.adev import allan_deviation
    from ahrsd.calibration.allan.terms import _fit_fixed, _Points, octave_points

    h = hashlib.md5()
    x = _noise(60_000, 100.0, 21, 3)
    for axis in range(3):
        base = octave_points(allan_deviation(x, 100.0), axis)
        for deficit_s, deficit_sd_s in ((0.0, 0.0), (0.05, 0.01), (0.02, 0.02)):
            pts = _Points(base.taus, base.avar, base.level_n, base.level_m, base.record_s, deficit_s, deficit_sd_s)
            for terms in (("white",), ("white", "rate_random_walk"), ("quantization", "white", "flicker"),
                          ("white", "rate_random_walk", "rate_ramp")):
                feed(h, _fit_fixed(pts, terms, None))
                feed(h, _fit_fixed(pts, terms, None, ("flicker" if "flicker" not in terms else "rate_ramp", 1e-9)))
            for tc in np.geomspace(0.05, 20.0, 25):
                feed(h, _fit_fixed(pts, ("white", "gauss_markov"), float(tc)))
                feed(h, _fit_fixed(pts, ("white", "flicker", "gauss_markov"), float(tc)))
    return h.hexdigest()


PARTS = {"curve": curve_part, "fit": fit_part, "analysis": analysis_part}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--parts", nargs="+", choices=tuple(PARTS), default=list(PARTS))
    args = parser.parse_args()
    total = hashlib.md5()
    for name in args.parts:
        digest = PARTS[name]()
        total.update(digest.encode())
        print(f"{name} {digest}")
    print(f"all {total.hexdigest()}")


if __name__ == "__main__":
    main()
