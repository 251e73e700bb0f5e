"""How often does white noise alone read another Allan term? (issue 30 item 9: the rate behind
tests/test_allan_chip_filters.py's false-term test.)

White noise at the ADIS16405's 2 °/√h through the SENS_AVG window of setting N (two 2^N-tap averages) at 819.2 SPS,
one record of `--seconds` per seed (generator seed 1000 + seed, three gyro axes), analysed as `ahrsd calibrate
allan` does. Prints per axis that reads any term besides white noise, then the count of axes by terms read and the
white noise's error/σ (RMS, mean, share beyond 3σ). `--threshold-scale S` multiplies the significance thresholds
(allan_terms.DELTA_CHI2), to see what a looser test reads.

    .venv/bin/python bench/allan_false_terms.py --seeds 0 600       # N = 5, 120 s, 1800 axes (~15 min)
"""

from __future__ import annotations

import argparse
import collections
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import allan_noise as gen  # noqa: E402

from ahrsd.calibration.allan import terms as allan_terms  # noqa: E402
from ahrsd.calibration.allan.analysis import analyse_static  # noqa: E402

RATE_HZ = 819.2
DENSITY = 5.8e-4     # rad/s/√Hz, the ADIS16405's 2 °/√h


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--filter-taps", type=int, default=5, help="SENS_AVG N (window of two 2^N-tap averages)")
    ap.add_argument("--seconds", type=float, default=120.0)
    ap.add_argument("--seeds", type=int, nargs=2, default=[0, 200], metavar=("FIRST", "END"))
    ap.add_argument("--threshold-scale", type=float, default=1.0)
    args = ap.parse_args(argv)
    for k in allan_terms.DELTA_CHI2:
        allan_terms.DELTA_CHI2[k] *= args.threshold_scale
    box = np.ones(1 << args.filter_taps) / (1 << args.filter_taps)
    taps = np.convolve(box, box)
    samples = int(args.seconds * RATE_HZ)
    counts: collections.Counter = collections.Counter()
    z = []
    for seed in range(*args.seeds):
        rng = np.random.default_rng(1000 + seed)
        x = np.column_stack([np.convolve(gen.white(samples + len(taps), RATE_HZ, DENSITY, rng), taps, "valid")[:samples]
                             for _ in range(3)])
        for axis, p in analyse_static(np.arange(samples) / RATE_HZ, gyro_rad_s=x).parameters["gyro"].items():
            terms = ",".join(sorted(p.terms))
            counts[terms] += 1
            if terms != "white":
                print(f"seed {seed} {axis}: {terms}", flush=True)
            white = p.terms.get("white")
            if white is not None:
                z.append((white.value - DENSITY) / white.uncertainty)
    zs = np.array(z)
    n = sum(counts.values())
    print(f"N = {args.filter_taps}, {args.seconds:g} s, seeds {args.seeds[0]}…{args.seeds[1] - 1}, thresholds × "
          f"{args.threshold_scale:g}: {n} axes; " + ", ".join(f"{t or 'none'} {c}" for t, c in counts.most_common()))
    if len(zs):
        print(f"white error/σ: RMS {np.sqrt(np.mean(zs**2)):.2f}, mean {zs.mean():+.2f}, beyond 3σ "
              f"{np.mean(np.abs(zs) > 3):.1%} ({np.count_nonzero(np.abs(zs) > 3)} of {len(zs)})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
