"""The GNSS–inertial yaw between turns against the simulator's truth: how far the heading walks, what the vertical
gyro bias is off meanwhile, and what the magnetometer's turning (estimator/mag_rotation.py) tells of that bias
(docs/gnss.md "The uncalibrated boat's tail at Halifax: the bias the GNSS-only phase leaves (tail35)").

Runs `ins` as `bench/heading_timeline.py` does (same vehicle, site, iron and case) and prints, every `--every`
seconds from `--from` to `--to`: the published heading's true error, the filter's yaw 1σ, the vertical gyro bias's
error against the simulator's turn-on bias (the in-run Gauss–Markov part, 25 °/h over 100 s, is not in the truth)
and the filter's 1σ of it, the true heading rate, and whether the magnetometer is fused, its iron learned and the
monitor rejecting it; with `--start`, also the GNSS yaw bank's error against the truth, its 1σ and whether it is
valid, the vertical gyro's scale-factor error against the simulator's and its 1σ, and the yaw resets so far (the
start-up: docs/gnss.md "The uncalibrated boat at Tromsø seed 17: the start under the magnetometer (trom36)"). Then
each magnetometer-rotation window that gave a fit: its span, its b_z − b̂_z with its 1σ,
the truth's b_z − b̂_z at the window's end, and the share of that 1σ the filter's tilt term makes
(√2·tan|dip|·σ_tilt / T); with `--terms`, every term of the window's 1σ (MagRotationBias.terms: the scatter and its
check-to-check correlation r₁, the gyro scale, the soft iron, the start attitude with the filter's tilt 1σ at the
window's start, the gyro's white noise, the tilt).

    python bench/yaw_drift_trace.py --site=44.65,-63.57 --iron held-out --seeds 41 --seconds 330
    python bench/yaw_drift_trace.py --site=44.65,-63.57 --iron held-out --seeds 41 --params '{"iron_unmodelled_ut": 0.8}'
    python bench/yaw_drift_trace.py --site=69.65,18.96 --iron held-out --seeds 17 --seconds 130 --from 10 --every 4 --start
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.vehicle_accuracy import (HONESTY_IRONS, estimates_in_arrival_order, honesty_site,  # noqa: E402
                                    honesty_site_arg, simulate_vehicle, tilt_heading_errors_deg)

DEG_H = 180.0 / math.pi * 3600.0     # rad/s → °/h
EVERY = 8                            # the true tilt error is sampled every this many samples (heading_timeline's)


def true_heading_rate_deg_s(t_s: np.ndarray, q_wxyz: np.ndarray) -> np.ndarray:
    """The simulator's heading rate (ZYX yaw, unwrapped), °/s; scipy only."""
    from scipy.spatial.transform import Rotation

    yaw = np.unwrap(Rotation.from_quat(np.asarray(q_wxyz)[:, [1, 2, 3, 0]]).as_euler("ZYX")[:, 0])
    return np.degrees(np.gradient(yaw, t_s))


def tilt_about_magnetic_north_rad(q_mag_est, q_truth, declination_rad: float) -> float:
    """The estimate's attitude error about magnetic north (rad): the component of the error rotation (truth ∘
    estimate⁻¹, both body → magnetic NED; the truth is body → true NED) that turns the vertical field into the east,
    the heading error a magnetometer's field gets from it at tan|dip| (mag_rotation.py's tilt term)."""
    from scipy.spatial.transform import Rotation

    est = Rotation.from_quat(np.asarray(q_mag_est)[[1, 2, 3, 0]])
    tru = Rotation.from_euler("z", -declination_rad) * Rotation.from_quat(np.asarray(q_truth)[[1, 2, 3, 0]])
    return float((tru * est.inv()).as_rotvec()[0])


def _slope(t_s: list, y: list, t0_s: float, t1_s: float) -> float:
    """The least-squares slope of y over [t0, t1] (per s); 0 with fewer than 3 points."""
    t = np.asarray(t_s)
    keep = (t >= t0_s) & (t <= t1_s)
    if np.count_nonzero(keep) < 3:
        return 0.0
    tc = t[keep] - t[keep].mean()
    return float(tc @ (np.asarray(y)[keep] - np.mean(np.asarray(y)[keep]))) / float(tc @ tc)


def bank_error_deg(est, q_truth_wxyz) -> tuple[float, float, bool]:
    """The GNSS yaw bank's yaw error against the simulator's heading, its 1σ (°) and whether it is valid; NaN
    before it has a yaw. Both are true headings (the bank's is the filter's frame, body → true NED; so is the
    simulator's quaternion), ZYX yaw; scipy only for the truth."""
    from scipy.spatial.transform import Rotation

    yaw, var, valid = est._heading.gnss_yaw()
    if not (math.isfinite(yaw) and math.isfinite(var)):
        return math.nan, math.nan, False
    true_yaw = Rotation.from_quat(np.asarray(q_truth_wxyz)[[1, 2, 3, 0]]).as_euler("ZYX")[0]
    err = math.degrees(yaw - true_yaw)
    return (err + 180.0) % 360.0 - 180.0, math.degrees(math.sqrt(var)), bool(valid)


def trace(scenario: str, case: str, seed: int, site_label: str, iron_label: str | None, seconds: float,
          every_s: float, from_s: float, to_s: float, params: dict) -> tuple[list, list, tuple]:
    """(rows, windows, (reruns, CPU per sample)): the per-`every_s` rows and the fitted magnetometer-rotation windows,
    as printed; each row ends with the start-up columns (`--start`: the bank's error, σ and validity, the vertical
    gyro's scale-factor error and σ in %, the yaw resets so far); each start run again (InsParams.start_rerun_max_s)
    with the filter's time, the samples and fixes run again and its CPU seconds, and the run's mean CPU seconds a
    sample (the trace's own work included)."""
    from ahrsd.estimator import ins_core as core
    from ahrsd.estimator.ins import Ins
    from ahrsd.simulation import SensorErrors

    site, iron = honesty_site(site_label, iron_label)
    run = simulate_vehicle(scenario, seconds, seed, site, mag=case, iron=iron)
    est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad, **params)
    sensor = SensorErrors.adis16405(seed)                                # simulate_vehicle's sensor
    true_bz, true_sz = float(sensor.gyro_bias_rad_s[2]), float(sensor.gyro_scale[2])
    rate = true_heading_rate_deg_s(run.t_s, run.truth_q_wxyz)
    # what the vertical gyro adds to the body's turn, integrated (rad): its whole bias in force (turn-on, in-run
    # Gauss–Markov, temperature) and its scale factor's share s_z·ω_z; a window's slope of these is its truth
    dt_s = np.diff(run.t_s, prepend=run.t_s[0])
    turned_by_bias = np.cumsum(run.truth_gyro_bias_rad_s[:, 2] * dt_s)
    turned_by_scale = np.cumsum(true_sz * run.truth_gyro_rad_s[:, 2] * dt_s)
    windows = []
    tilt_t, tilt_n = [], []      # the true tilt error about magnetic north, rad, at the checks (heading_timeline's EVERY)

    def trace_windows():
        """Every window the filter's magnetometer-rotation part fits goes into `windows` (again after a start run
        again, which builds the part anew)."""
        rotation = est._heading._mag_rotation
        add = rotation.add

        def add_traced(t_s, *args):
            out = add(t_s, *args)
            if out is not None:
                record_window(rotation, t_s, out)
            return out

        rotation.add = add_traced
        fit = rotation._fit

        def fit_traced(*args):
            # the fitted window's bounds and turn, before a turn's new window replaces its samples
            out = fit(*args)
            if out is not None:
                rotation.traced = (rotation.t0_s, rotation.samples[-1][0], rotation.samples[-1][3])
            return out

        rotation._fit = fit_traced

    def record_window(rotation, t_s, out):
        if out is not None:
            b = rotation.b_ned_ut
            tan_dip = abs(float(b[2])) / max(math.hypot(float(b[0]), float(b[1])), 1e-6)
            tilt = math.sqrt(rotation.terms[5])     # the window's tilt term, as the fit counted it
            terms = tuple(math.sqrt(v) * DEG_H for v in rotation.terms[:6]) + (rotation.terms[6],
                                                                          math.degrees(rotation.terms[7]))
            bias_end = float(est._x["gyro_bias_rad_s"][2])
            t0, t1, turn = rotation.traced
            k0, k1 = np.searchsorted(run.t_s, [t0, t1])
            pooled = ((_slope(run.t_s[k0:k1 + 1], turned_by_bias[k0:k1 + 1], t0, t1) - bias_end) * DEG_H,
                      _slope(run.t_s[k0:k1 + 1], turned_by_scale[k0:k1 + 1], t0, t1) * DEG_H, math.degrees(turn))
            windows.append((rotation.span_s, t_s, out[0] * DEG_H, math.sqrt(out[1]) * DEG_H,
                            (true_bz - bias_end) * DEG_H, tilt * DEG_H,
                            tan_dip * abs(_slope(tilt_t, tilt_n, t_s - rotation.span_s, t_s)) * DEG_H, terms, pooled))

    trace_windows()
    run_again = est._run_start_again
    reruns = []     # (t s of the filter when run again, samples and fixes run again, CPU s)

    def run_again_timed():
        t0, n = time.process_time(), len(est._start_recording.events)
        run_again()
        reruns.append((float(est._x["t_last_s"]), n, time.process_time() - t0))
        trace_windows()

    est._run_start_again = run_again_timed
    rows = []
    next_s = from_s
    cpu0 = time.process_time()
    for k, e in estimates_in_arrival_order(est, run, run.fixes):
        t = float(run.t_s[k])
        if k % EVERY == 0 and est._initialised:
            tilt_t.append(t)
            tilt_n.append(tilt_about_magnetic_north_rad(e.q_wxyz, run.truth_q_wxyz[k], run.declination_rad))
        if t < next_s or t > to_s or not est._initialised:
            continue
        next_s += every_s
        _, hdg = tilt_heading_errors_deg(e.q_wxyz[None, :], run.truth_q_wxyz[k][None, :], run.declination_rad)
        i, j = core.E_BG + 2, core.E_SG + 2
        start = (*bank_error_deg(est, run.truth_q_wxyz[k]),
                 100.0 * (float(est._x["gyro_scale"][2]) - true_sz), 100.0 * math.sqrt(max(est._P[j, j], 0.0)),
                 est._heading.yaw_resets)
        rows.append((t, float(hdg[0]), math.degrees(math.sqrt(max(est._P[core.E_YAW, core.E_YAW], 0.0))),
                     (float(est._x["gyro_bias_rad_s"][2]) - true_bz) * DEG_H, math.sqrt(max(est._P[i, i], 0.0)) * DEG_H,
                     float(rate[k]), est._par["mag_use"] > 0.5, est._heading.monitor.learning,
                     est._heading.monitor.mag_rejected, start))
    cpu_per_sample = (time.process_time() - cpu0) / len(run.t_s)
    return rows, windows, (reruns, cpu_per_sample)


TURN_BINS_DEG = (3.0, 4.5)     # --pooled splits the windows by how far the vehicle turned in them
FULL_WINDOW_S = 29.9           # ... and into the windows that ran their whole 30 s and those a turn ended


def pooled_summary(windows: list) -> list[str]:
    """--pooled: for every truth (the turn-on bias as the rows print it; the whole bias in force; that and the gyro
    scale's share s_z·mean ω_z), the windows' normalised errors (fit − truth)/1σ pooled: how many, their RMS and the
    shares beyond 2σ and 3σ (a Gaussian: 1, 4.6 %, 0.27 %), by the window's turn and over all."""
    if not windows:
        return ["no windows"]
    fit = np.array([w[2] for w in windows])
    sig = np.array([w[3] for w in windows])
    turn_on = np.array([w[4] for w in windows])
    bias = np.array([w[8][0] for w in windows])
    scale = np.array([w[8][1] for w in windows])
    turn = np.abs([w[8][2] for w in windows])
    full = np.array([w[0] for w in windows]) >= FULL_WINDOW_S
    edges = (0.0, *TURN_BINS_DEG, math.inf)
    groups = [(f"turn {lo:g}–{hi:g}°" if hi < math.inf else f"turn ≥{lo:g}°", (turn >= lo) & (turn < hi))
              for lo, hi in zip(edges[:-1], edges[1:])]
    groups += [(f"span ≥{FULL_WINDOW_S:g} s", full), (f"span <{FULL_WINDOW_S:g} s", ~full),
               ("all", np.ones(len(windows), dtype=bool))]
    lines = []
    for label, truth in (("turn-on b_z", turn_on), ("b_z in force", bias), ("b_z in force + s_z·ω_z", bias + scale)):
        z = (fit - truth) / sig
        for span, keep in groups:
            n = int(np.count_nonzero(keep))
            if n == 0:
                continue
            zk = z[keep]
            lines.append(f"  {label:24s} {span:12s}: n {n:3d} | RMS z {math.sqrt(float(zk @ zk) / n):4.2f} | "
                         f"beyond 2σ {100.0 * np.mean(np.abs(zk) > 2.0):4.1f} % | beyond 3σ "
                         f"{100.0 * np.mean(np.abs(zk) > 3.0):4.1f} % | mean z {float(np.mean(zk)):+5.2f}")
    return lines


def _run_arg(text: str) -> tuple[str, list[int]]:
    """--runs: "LAT,LON[,…]:SEED[,SEED…]" (or a site's name) → (the site, its seeds)."""
    site, _, seeds = text.rpartition(":")
    if not site or not seeds:
        raise argparse.ArgumentTypeError(f"expected SITE:SEED[,SEED…], got {text!r}")
    return honesty_site_arg(site), [int(x) for x in seeds.split(",")]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="boat")
    ap.add_argument("--case", default="uncalibrated", choices=("uncalibrated", "calibrated", "iron-step"))
    ap.add_argument("--site", default="held-out", type=honesty_site_arg)
    ap.add_argument("--iron", default=None, choices=HONESTY_IRONS)
    ap.add_argument("--seeds", type=int, nargs="+", default=[41])
    ap.add_argument("--seconds", type=float, default=330.0)
    ap.add_argument("--every", type=float, default=5.0, help="print every this many seconds (default 5)")
    ap.add_argument("--from", dest="from_s", type=float, default=60.0, help="first row, s (default 60)")
    ap.add_argument("--to", dest="to_s", type=float, default=math.inf, help="last row, s (default: the end)")
    ap.add_argument("--params", default="{}", help="InsParams overrides as JSON")
    ap.add_argument("--start", action="store_true",
                    help="also the GNSS yaw bank's error, σ and validity, the vertical gyro scale-factor error and σ, "
                         "and the yaw resets so far")
    ap.add_argument("--terms", action="store_true", help="also every term of each fitted window's 1σ")
    ap.add_argument("--pooled", action="store_true",
                    help="also each window's truth as the whole bias in force and the gyro scale's share s_z·mean ω_z "
                         "and its turn, and at the end the normalised errors of all windows of all runs pooled")
    ap.add_argument("--runs", type=_run_arg, action="append", default=None, metavar="SITE:SEEDS",
                    help="a site with its seeds (\"--runs=-53.16,-70.91:91,92\"; again for more sites), instead of "
                         "--site and --seeds")
    args = ap.parse_args(argv)
    params = json.loads(args.params)
    runs = args.runs or [(args.site, args.seeds)]
    pooled = []
    for site, seed in [(site, seed) for site, seeds in runs for seed in seeds]:
        rows, windows, (reruns, cpu_per_sample) = trace(args.scenario, args.case, seed, site, args.iron, args.seconds, args.every,
                              args.from_s, args.to_s, params)
        pooled += windows
        print(f"{args.scenario} {args.case} seed {seed} at {site} ({args.iron or 'own'} iron) {params or ''}: "
              "t s | heading err ° | yaw σ ° | b_z err °/h (vs turn-on) | b_z σ °/h | true rate °/s | "
              "mag fused | learning | rejected" + (" | bank err ° | bank σ ° | bank valid | s_z err % | s_z σ % | "
                                                   "yaw resets" if args.start else ""))
        for t, h, sy, bz, sbz, r, fused, learning, rejected, start in rows:
            more = ""
            if args.start:
                be, bs, bv, sz, ssz, resets = start
                more = f" | {be:+7.2f} | {bs:6.2f} | {'yes' if bv else 'no '} | {sz:+6.3f} | {ssz:5.3f} | {resets}"
            print(f"{t:7.1f} | {h:+6.2f} | {sy:5.2f} | {bz:+6.0f} | {sbz:5.0f} | {r:+5.1f} | "
                  f"{'yes' if fused else 'no '} | {'yes' if learning else 'no '} | {'yes' if rejected else 'no'}{more}")
        for t, n, cpu in reruns:
            print(f"start run again at {t:.2f} s: {n} samples and fixes in {cpu:.3f} CPU-s "
                  f"({cpu / cpu_per_sample:.0f} samples' worth at this run's mean {cpu_per_sample * 1e6:.0f} µs a "
                  "sample, the trace's own work included)")
        print("magnetometer-rotation windows fitted: span s, ending at s | b_z − b̂_z ± 1σ °/h | truth °/h | "
              "tilt term of the 1σ °/h | the true tilt error's slope about magnetic north × tan|dip| °/h"
              + (" | terms °/h: scatter (r₁) scale soft-iron attitude (start tilt σ °) gyro-noise tilt" if args.terms else "")
              + (" | b_z in force − b̂_z °/h | s_z·mean ω_z °/h | turn °" if args.pooled else ""))
        for span, end, fit, sig, truth, tilt, true_tilt, terms, (in_force, scale_share, turn) in windows:
            more = ""
            if args.terms:
                sc, scale, soft, att, walk, tl, r1, att_deg = terms
                more = (f" | {sc:4.0f} ({r1:.2f}) {scale:4.0f} {soft:4.0f} {att:4.0f} ({att_deg:4.2f}) {walk:4.0f} "
                        f"{tl:4.0f}")
            if args.pooled:
                more += f" | {in_force:+6.0f} | {scale_share:+5.1f} | {turn:+5.1f}"
            print(f"  {span:5.1f} s to {end:6.1f} | {fit:+6.0f} ± {sig:5.0f} | {truth:+6.0f} | {tilt:5.0f} | "
                  f"{true_tilt:5.0f}{more}")
    if args.pooled:
        print(f"all windows of {sum(len(seeds) for _, seeds in runs)} runs: (fit − truth)/1σ")
        print("\n".join(pooled_summary(pooled)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
