"""Held-out check of allan_resolution.MIN_NOISE_LSB: the white noise read through a coarse output, by its σ in LSB.

White noise through the ADIS16405's SENS_AVG window N (two 2^N-tap averages, 819.2 SPS), rounded to an LSB chosen
so the filtered noise is `--noise-lsb` LSB per sample, plus an offset of `--offset` LSB; the analysis is run with
the threshold off (MIN_NOISE_LSB = 0) and the white noise read is compared with the density put in. The threshold
was chosen on the simulated chip at N = 3…7 (bench/allan_filters.py, offsets of the simulator, 300 s); these cases
differ in window, noise level, offset and seeds.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import allan_noise as gen  # noqa: E402

from ahrsd.calibration.allan import analysis as allan  # noqa: E402

RATE_HZ = 819.2
DENSITY = 5.8e-4


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--filter-taps", type=int, nargs="+", default=[3, 4, 6])
    ap.add_argument("--noise-lsb", type=float, nargs="+", default=[0.4, 0.5, 0.6, 0.7, 0.9])
    ap.add_argument("--offset", type=float, nargs="+", default=[0.3, 7.5])
    ap.add_argument("--seconds", type=float, default=150.0)
    ap.add_argument("--seed", type=int, default=500)
    args = ap.parse_args(argv)
    allan.MIN_NOISE_LSB = 0.0
    print("N  noise_lsb offset  read σ/LSB   white error per axis (± 1σ), other terms")
    for n in args.filter_taps:
        box = np.ones(1 << n) / (1 << n)
        taps = np.convolve(box, box)
        samples = int(args.seconds * RATE_HZ)
        rng = np.random.default_rng(args.seed + n)
        clean = np.column_stack([np.convolve(gen.white(samples + len(taps), RATE_HZ, DENSITY, rng), taps, "valid")[:samples]
                                 for _ in range(3)])
        filtered_sd = DENSITY * np.sqrt(RATE_HZ) * np.sqrt(np.sum(taps**2))
        for level in args.noise_lsb:
            for offset in args.offset:
                lsb = filtered_sd / level
                x = np.round(clean / lsb + offset) * lsb
                res = allan.analyse_static(np.arange(samples) / RATE_HZ, gyro_rad_s=x)
                cells, read = [], []
                for p in res.parameters["gyro"].values():
                    read.append(p.noise_lsb if p.noise_lsb is not None else float(np.std(x[:, 0]) / lsb))
                    w = p.terms.get("white")
                    extra = ",".join(sorted(t for t in p.terms if t != "white"))
                    cells.append((f"{w.value / DENSITY - 1:+6.1%} (±{w.uncertainty / DENSITY:.1%})" if w else "   none      ")
                                 + (f" +{extra}" if extra else ""))
                print(f"{n}  {level:8.2f} {offset:6.1f}  {min(read):.2f}–{max(read):.2f}   " + "  ".join(cells), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
