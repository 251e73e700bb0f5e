"""Does a short-Tc Gauss–Markov bias beside the chip's filtered white noise read as Gauss–Markov (issue 30 item 9)?

White noise through the ADIS16405's default SENS_AVG window (7-tap Bartlett, 819.2 SPS) plus a first-order
Gauss–Markov bias of correlation time Tc = f × τ_min, τ_min = 8 of the window's correlation lengths as read from
the data (the fit's start in allan_correlation until session 20, which starts it at 2; kept as the unit so rows
compare across fit rules), σ_GM set so the bump's
Allan variance at its peak is `--ratio` × the white noise's there. Per case: which terms
are read, σ_GM and Tc against the generator's, and the bias-driving density w_b that allan_kalman proposes against
the truth σ_GM·√(2/Tc). `--seeds`, `--factors` and `--ratio` choose the cases (in-sample: seeds 1-3, Tc factors
5 10 20 50 100, ratio 10; held out: seeds 4-6, other factors and ratios). `--without-alternatives`: the selection
as it was before the non-nested comparison.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import allan_noise as gen  # noqa: E402

from ahrsd.calibration.allan.analysis import analyse_static  # noqa: E402
from ahrsd.calibration.allan.kalman import bias_drive  # noqa: E402
from ahrsd.calibration.allan.correlation import SampleCorrelation  # noqa: E402
from ahrsd.calibration.allan import terms as allan_terms  # noqa: E402
from ahrsd.calibration.allan.terms import gauss_markov_avar  # noqa: E402

RATE_HZ = 819.2
DENSITY = 5.8e-4
TC_UNIT_LENGTHS = 8


def window(n: int) -> np.ndarray:
    box = np.ones(1 << n) / (1 << n)
    return np.convolve(box, box)


def record(seed: int, tc_s: float, ratio: float, seconds: float, taps: np.ndarray):
    rng = np.random.default_rng(seed)
    samples = int(seconds * RATE_HZ)
    peak_tau = 1.89 * tc_s
    sigma = math.sqrt(ratio * DENSITY**2 / peak_tau / float(gauss_markov_avar(np.array([peak_tau]), tc_s)[0]))
    cols = []
    for _ in range(3):
        w = np.convolve(gen.white(samples + len(taps), RATE_HZ, DENSITY, rng), taps, "valid")[:samples]
        cols.append(w + gen.gauss_markov(samples, RATE_HZ, sigma, tc_s, rng))
    return np.column_stack(cols), sigma


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--factors", type=float, nargs="+", default=[5, 10, 20, 50, 100, 300, 1000])
    ap.add_argument("--ratio", type=float, nargs="+", default=[10.0])
    ap.add_argument("--filter-taps", type=int, default=2, help="SENS_AVG N (window of two 2^N-tap averages)")
    ap.add_argument("--min-seconds", type=float, default=320.0)
    ap.add_argument("--without-alternatives", action="store_true",
                    help="the selection before the non-nested comparison (allan_terms.ALTERNATIVES emptied)")
    args = ap.parse_args(argv)
    if args.without_alternatives:
        allan_terms.ALTERNATIVES = ()
    taps = window(args.filter_taps)
    print(f"{'f':>6} {'Tc s':>7} {'ratio':>5} {'seed':>4} {'axis':>4}  {'terms':<34} {'σ/σ0':>6} {'z_σ':>6} "
          f"{'Tc/Tc0':>6} {'w_b/w0':>7}")
    counts: dict = {}
    for ratio in args.ratio:
        for f in args.factors:
            for seed in args.seeds:
                _one_run(counts, seed, f, ratio, taps, args.min_seconds)
    _print_summary(counts)
    return 0


def _one_run(counts: dict, seed: int, f: float, ratio: float, taps: np.ndarray, min_seconds: float) -> None:
    """One recording with Tc = f·τ_min, analysed: a row per gyro axis, and its counts added to `counts`."""
    x0, _ = record(seed, 1.0, ratio, 4.0, taps)   # to learn the window's length from the data
    correlation = SampleCorrelation()
    correlation.add(x0)
    # the unit of Tc: 8 of the window's correlation lengths, read as the analysis reads them (module doc), whatever
    # the fit's start
    tau_min = TC_UNIT_LENGTHS * int(correlation.lengths().max()) / RATE_HZ
    tc = f * tau_min
    seconds = max(min_seconds, 30.0 * tc)
    x, sigma = record(1000 * seed + int(f), tc, ratio, seconds, taps)
    res = analyse_static(np.arange(len(x)) / RATE_HZ, gyro_rad_s=x)
    w_true = sigma * math.sqrt(2.0 / tc)
    for axis, p in res.parameters["gyro"].items():
        terms = ",".join(sorted(p.terms))
        w_b, _ = bias_drive(p)
        gm = p.terms.get("gauss_markov")
        s = f"{gm.value / sigma:6.2f} {(gm.value - sigma) / gm.uncertainty:6.1f} {gm.corr_time_s / tc:6.2f}" \
            if gm else f"{'-':>6} {'-':>6} {'-':>6}"
        wb = f"{w_b / w_true:7.2f}" if w_b else f"{'-':>7}"
        print(f"{f:6g} {tc:7.3g} {ratio:5g} {seed:4d} {axis:>4}  {terms:<34} {s} {wb}", flush=True)
        c = counts.setdefault((ratio, f), {"gm": 0, "flicker": 0, "n": 0, "wb": [], "z": [], "tc": []})
        c["n"] += 1
        c["gm"] += gm is not None
        c["flicker"] += "flicker" in p.terms
        if w_b:
            c["wb"].append(w_b / w_true)
        if gm:
            c["z"].append((gm.value - sigma) / gm.uncertainty)
            c["tc"].append(gm.corr_time_s / tc)


def _print_summary(counts: dict) -> None:
    print("\nsummary: ratio, f (Tc/τ_min): GM read, flicker read, of n; w_b/truth median (min … max); where GM is "
          "read: σ_GM error/σ RMS and share beyond 3σ, fitted Tc/truth (min … max)")
    for (ratio, f), c in counts.items():
        wb = np.array(c["wb"]) if c["wb"] else np.array([math.nan])
        z = np.array(c["z"]) if c["z"] else np.array([math.nan])
        tcr = np.array(c["tc"]) if c["tc"] else np.array([math.nan])
        print(f"  {ratio:g} {f:6g}: GM {c['gm']}/{c['n']}, flicker {c['flicker']}/{c['n']}; "
              f"w_b {np.median(wb):.2f} ({wb.min():.2f} … {wb.max():.2f}); "
              f"z RMS {np.sqrt(np.mean(z**2)):.2f}, {np.mean(np.abs(z) > 3):.0%} > 3σ; Tc {tcr.min():.2f} … {tcr.max():.2f}")


if __name__ == "__main__":
    raise SystemExit(main())
