"""Attitude accuracy of ahrsd's estimators and the open peers, in one process, on the same data.

    .venv/bin/python bench/accuracy.py                 # simulated scenarios + all 15 BROAD trials
    .venv/bin/python bench/accuracy.py --quick         # short simulated runs, 3 BROAD trials
    .venv/bin/python bench/accuracy.py --trials 06 32 --no-sim --methods mekf vqf
    .venv/bin/python bench/accuracy.py --vehicles [--quick]  # only (c) and (d): ins with GNSS on boat, car, plane
    .venv/bin/python bench/accuracy.py --cv --no-sim --no-broad   # cross-validated tuning only (bench/cv.py)

(a) Simulated ADIS16405 (ahrsd.simulation, datasheet noise, 819.2 SPS) read through the byte-level chip
    `drivers.simulated.SimulatedAdis16405` and the real driver `drivers.adis16405.Adis16405` (quantised,
    flagged ImuSamples, exactly what the daemon sees). The magnetometer is corrected with the simulator's
    known hard/soft iron (a perfect calibration, as the daemon applies its calibration before the estimator);
    the accelerometer likewise (turn-on bias, scale, misalignment), the gyro for scale and misalignment only
    (the filters must learn the gyro bias). Roll/pitch/heading RMS after a
    10 s settling time against the thesis targets (static roll/pitch < 0.2°, heading < 0.4°; dynamic < 0.5°).
    Heading is compared as true heading (estimates are magnetic: the WMM declination of the simulator's site
    is added to every method alike).
(b) BROAD (Laidig et al., Data 6(7) 2021, doi:10.3390/data6070072, CC BY 4.0): BROAD's own metric (total,
    heading, inclination RMSE in movement phases), per trial and method, means per group, mekf/VQF ratio.
(c) Vehicles (bench/vehicle_accuracy.py): `ins` with simulated GNSS beside mekf and VQF on boat, car and plane
    at two sites, tilt and true-heading RMS, and a 30 s GNSS outage in a turn.

Peers (benchmark-only packages, never imported by ahrsd itself): `vqf` 9D defaults (causal) and
`offlineVQF` (acausal), `imufusion` defaults (x-io Fusion), `ahrs` Madgwick (β = 0.12, BROAD's tuned value)
and Mahony (BROAD-tuned Kp 0.74, Ki 0.0012). Output frames: VQF gives ENU (magnetic north), Fusion and
`ahrs` Madgwick give NWU whatever they are told, `ahrs` Mahony gives ENU (anchors/estimators.md pitfalls;
checked on BROAD); all are converted to NED here.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ahrsd.estimator.rotations import quat_multiply  # noqa: E402
from bench.broad import Q_NED_TO_ENU, broad_errors, load_trial, ned_to_enu, trial_paths  # noqa: E402

_S = 1.0 / math.sqrt(2.0)
Q_NWU_TO_ENU = np.array([_S, 0.0, 0.0, _S])  # +90° about up: (N, W, U) coordinates → (E, N, U)
Q_ENU_TO_NED = Q_NED_TO_ENU  # a 180° rotation: its own inverse


@dataclass
class ImuArrays:
    t_s: np.ndarray
    gyro_rad_s: np.ndarray
    accel_m_s2: np.ndarray
    mag_ut: np.ndarray
    rate_hz: float
    flags: np.ndarray | None = None


# ------------------------------------------------------------------------------------------ methods
def run_mekf(d: ImuArrays) -> np.ndarray:
    from ahrsd.estimator.mekf import Mekf

    q, _ = Mekf().run_batch(d.t_s, d.gyro_rad_s, d.accel_m_s2, d.mag_ut, d.flags)
    return q


def run_mekf_fixed_wing(d: ImuArrays) -> np.ndarray:
    from ahrsd.estimator.mekf import FIXED_WING_MEKF_PARAMS, Mekf

    q, _ = Mekf(params=FIXED_WING_MEKF_PARAMS).run_batch(d.t_s, d.gyro_rad_s, d.accel_m_s2, d.mag_ut, d.flags)
    return q


def run_thesis(d: ImuArrays) -> np.ndarray:
    from ahrsd.core.sample import ImuSample, SampleFlags
    from ahrsd.estimator import make_estimator

    est = make_estimator("thesis")
    n = len(d.t_s)
    q = np.empty((n, 4))
    fl = d.flags if d.flags is not None else np.zeros(n, dtype=np.int64)
    for i in range(n):
        s = ImuSample(float(d.t_s[i]), d.gyro_rad_s[i], d.accel_m_s2[i], d.mag_ut[i], flags=SampleFlags(int(fl[i])))
        q[i] = est.update(s).q_wxyz
    return q


def run_vqf(d: ImuArrays) -> np.ndarray:
    from vqf import VQF

    out = VQF(1.0 / d.rate_hz).updateBatch(d.gyro_rad_s, d.accel_m_s2, d.mag_ut)
    return quat_multiply(Q_ENU_TO_NED, out["quat9D"])


def run_offline_vqf(d: ImuArrays) -> np.ndarray:
    from vqf import offlineVQF

    out = offlineVQF(d.gyro_rad_s, d.accel_m_s2, d.mag_ut, 1.0 / d.rate_hz)
    return quat_multiply(Q_ENU_TO_NED, out["quat9D"])


def run_fusion(d: ImuArrays) -> np.ndarray:
    import imufusion

    ahrs = imufusion.Ahrs()  # defaults (gain 0.5, ...); output NWU whatever the convention setting says
    ahrs.set_sample_period(1.0 / d.rate_hz)
    gyro_dps = np.degrees(d.gyro_rad_s)
    acc_g = d.accel_m_s2 / 9.80665
    n = len(d.t_s)
    q = np.empty((n, 4))
    for i in range(n):
        ahrs.update(gyro_dps[i], acc_g[i], d.mag_ut[i])
        q[i] = ahrs.get_quaternion()
    return quat_multiply(Q_ENU_TO_NED, quat_multiply(Q_NWU_TO_ENU, q))


def run_madgwick(d: ImuArrays) -> np.ndarray:
    from ahrs.filters import Madgwick

    q = Madgwick(gyr=d.gyro_rad_s, acc=d.accel_m_s2, mag=d.mag_ut, frequency=d.rate_hz, beta=0.12).Q
    return quat_multiply(Q_ENU_TO_NED, quat_multiply(Q_NWU_TO_ENU, q))


def run_mahony(d: ImuArrays) -> np.ndarray:
    from ahrs.filters import Mahony

    q = Mahony(gyr=d.gyro_rad_s, acc=d.accel_m_s2, mag=d.mag_ut, frequency=d.rate_hz, k_P=0.74, k_I=0.0012).Q
    # ahrs 0.4.0's Mahony references ENU, unlike its Madgwick (NWU): checked on BROAD trial 01 — every other
    # frame/sign combination gives 57–180° errors
    return quat_multiply(Q_ENU_TO_NED, q)


METHODS = {
    "mekf": run_mekf,
    "mekf-fw": run_mekf_fixed_wing,
    "thesis": run_thesis,
    "vqf": run_vqf,
    "offline-vqf": run_offline_vqf,
    "fusion": run_fusion,
    "madgwick": run_madgwick,
    "mahony": run_mahony,
}
SLOW_METHODS = {"thesis", "madgwick", "mahony"}  # one Python call per sample: minutes on all of BROAD


def available_methods(names: list[str]) -> tuple[list[str], dict[str, str]]:
    """The methods that can run here, and a note for each one that cannot."""
    ok, notes = [], {}
    for name in names:
        try:
            if name == "thesis":
                from ahrsd.estimator import thesis_kf  # noqa: F401
            elif name in ("vqf", "offline-vqf"):
                import vqf  # noqa: F401
            elif name == "fusion":
                import imufusion  # noqa: F401
            elif name in ("madgwick", "mahony"):
                import ahrs  # noqa: F401
        except ImportError as exc:
            notes[name] = f"skipped ({exc})"
            continue
        ok.append(name)
    return ok, notes


# ------------------------------------------------------------------------------------------ simulation
SIM_SCENARIOS = {  # name: (seconds, dynamic?)
    "static": (60.0, False),
    "rate-table": (240.0, True),
    "level-turns": (120.0, True),
    "coordinated-turn": (156.0, True),
    "mag-disturbance": (60.0, False),
}
SETTLE_S = 10.0


def simulate_through_driver(scenario: str, seconds: float, seed: int = 0):
    """Samples of `scenario` read through the simulated chip and the ADIS16405 driver; returns
    (ImuArrays with the magnetometer perfectly calibrated, truth q (N, 4), declination rad)."""
    from ahrsd.drivers.adis16405 import Adis16405
    from ahrsd.drivers.simulated import SimulatedAdis16405
    from ahrsd.simulation import DEFAULT_SITE, open_stream

    stream = open_stream(scenario, rate_hz=819.2, seed=seed)
    chip = SimulatedAdis16405(stream, seed=seed)
    drv = Adis16405(chip)
    drv.start()
    n = int(seconds * drv.sample_rate_hz)
    t = np.empty(n)
    g = np.empty((n, 3))
    a = np.empty((n, 3))
    m = np.empty((n, 3))
    fl = np.empty(n, dtype=np.int64)
    truth = np.empty((n, 4))
    for i in range(n):
        s = drv.read_sample()
        t[i] = s.t_s
        g[i] = s.gyro_rad_s
        a[i] = s.accel_m_s2
        m[i] = s.mag_ut
        fl[i] = int(s.flags)
        truth[i] = chip.output_truth_q_wxyz
    # the calibration the daemon would apply: perfect for the magnetometer and the accelerometer (turn-on bias,
    # scale, misalignment: what a six-position / field calibration finds), gyro scale and misalignment only —
    # the gyro's turn-on bias changes at every power-on and is left for the filters to learn
    err = stream.errors
    m_cal = (np.linalg.inv(err.soft_iron) @ (m - err.hard_iron_ut).T).T
    a_cal = (np.linalg.inv(err.accel_matrix) @ (a - err.accel_bias_m_s2).T).T
    g_cal = (np.linalg.inv(err.gyro_matrix) @ g.T).T
    decl = DEFAULT_SITE.earth_field().declination_rad
    arrays = ImuArrays(*(np.ascontiguousarray(x) for x in (t, g_cal, a_cal, m_cal)), drv.sample_rate_hz, fl)
    return arrays, truth, decl


def rpy_errors_deg(q_est: np.ndarray, q_truth: np.ndarray, declination_rad: float, settle: np.ndarray):
    """RMS roll, pitch and (true) heading errors in degrees over the samples where `settle` is True.

    Computed from the error rotation q_est ⊗ q_truth* in NED (small angles): its down component is the
    heading error, its north/east components rotated into the truth's heading frame are the roll and pitch
    errors. Unlike differences of Euler angles this stays meaningful at ±90° pitch (the rate table's x-up
    and x-down positions), where roll and yaw are undefined. Truth maths via scipy, not ahrsd's rotations."""
    from scipy.spatial.transform import Rotation

    def rot(q):
        return Rotation.from_quat(np.concatenate([q[:, 1:], q[:, :1]], axis=1))

    ok = settle & np.all(np.isfinite(q_est), axis=1)
    qd = Rotation.from_rotvec([0.0, 0.0, declination_rad])
    r_true = rot(q_truth[ok])
    e = (qd * rot(q_est[ok]) * r_true.inv()).as_rotvec()
    c = r_true.as_matrix()
    yaw = np.arctan2(c[:, 1, 0], c[:, 0, 0])
    roll = np.cos(yaw) * e[:, 0] + np.sin(yaw) * e[:, 1]
    pitch = -np.sin(yaw) * e[:, 0] + np.cos(yaw) * e[:, 1]
    err = np.stack([roll, pitch, e[:, 2]], axis=1)
    return np.degrees(np.sqrt(np.mean(err**2, axis=0)))


def sim_section(methods: list[str], quick: bool) -> None:
    print("\n## (a) Simulated ADIS16405, 819.2 SPS, through SimulatedAdis16405 + Adis16405 driver")
    print(f"RMS error in degrees after {SETTLE_S:.0f} s (roll/pitch/heading components of the error rotation);")
    print("targets (thesis): static roll/pitch < 0.2, heading < 0.4; dynamic < 0.5")
    hdr = f"{'scenario':17s} {'method':12s} {'roll':>7s} {'pitch':>7s} {'heading':>8s}  target"
    print(hdr)
    print("-" * len(hdr))
    for scen, (seconds, dynamic) in SIM_SCENARIOS.items():
        if quick:
            seconds = min(seconds, 40.0)
        t0 = time.perf_counter()
        data, truth, decl = simulate_through_driver(scen, seconds)
        settle = data.t_s - data.t_s[0] >= SETTLE_S
        for name in methods:
            if name == "offline-vqf":
                continue
            q = METHODS[name](data)
            r, p, h = rpy_errors_deg(q, truth, decl, settle)
            if dynamic:
                ok = max(r, p, h) < 0.5
            else:
                ok = max(r, p) < 0.2 and h < 0.4
            print(f"{scen:17s} {name:12s} {r:7.3f} {p:7.3f} {h:8.3f}  {'meets' if ok else 'misses'}")
        print(f"{'':17s} ({len(data.t_s)} samples, {time.perf_counter() - t0:.0f} s)")


# ------------------------------------------------------------------------------------------ BROAD
def broad_section(methods: list[str], trial_names: list[str] | None, quick: bool, max_samples: int | None):
    paths = trial_paths(names=trial_names)
    if quick and not trial_names:
        paths = [p for p in paths if p.stem[:2] in ("01", "15", "32")]
    if not paths:
        print("\n## (b) BROAD: no trials found (needs ../shared/data/broad beside the checkout)")
        return
    print(f"\n## (b) BROAD, {len(paths)} trials: total RMSE (deg) in movement phases, BROAD's metric")
    res: dict[str, dict[str, object]] = {m: {} for m in methods}
    timing = {m: 0.0 for m in methods}
    names = []
    for p in paths:
        tr = load_trial(p, max_samples=max_samples)
        names.append(tr.name)
        d = ImuArrays(tr.t_s, tr.gyro_rad_s, tr.accel_m_s2, tr.mag_ut, tr.rate_hz)
        for m in methods:
            t0 = time.perf_counter()
            q_ned = METHODS[m](d)
            timing[m] += time.perf_counter() - t0
            res[m][tr.name] = broad_errors(ned_to_enu(q_ned), tr)
    col = 12
    print(f"{'trial':44s}" + "".join(f"{m:>{col}s}" for m in methods)
          + ("   mekf/vqf" if "mekf" in methods and "vqf" in methods else ""))
    for n in names:
        line = f"{n:44s}" + "".join(f"{res[m][n].total_deg:{col}.2f}" for m in methods)
        if "mekf" in methods and "vqf" in methods:
            line += f"   {res['mekf'][n].total_deg / res['vqf'][n].total_deg:8.2f}"
        print(line)
    groups = {
        "mean (all)": names,
        "mean (undisturbed)": [n for n in names if "_undisturbed_" in n],
        "mean (disturbed)": [n for n in names if "_disturbed_" in n],
    }
    print("-" * (44 + col * len(methods)))
    for g, members in groups.items():
        if not members:
            continue
        means = {m: float(np.mean([res[m][n].total_deg for n in members])) for m in methods}
        line = f"{g:44s}" + "".join(f"{means[m]:{col}.2f}" for m in methods)
        if "mekf" in methods and "vqf" in methods:
            line += f"   {means['mekf'] / means['vqf']:8.3f}"
        print(line)
    for kind in ("heading_deg", "inclination_deg"):
        line = f"{'mean ' + kind.split('_')[0] + ' RMSE':44s}"
        line += "".join(f"{np.mean([getattr(res[m][n], kind) for n in names]):{col}.2f}" for m in methods)
        print(line)
    print(f"{'run time (s)':44s}" + "".join(f"{timing[m]:{col}.1f}" for m in methods))
    if "mekf" in methods and "vqf" in methods:
        ratios = {n: res["mekf"][n].total_deg / res["vqf"][n].total_deg for n in names}
        worst = max(ratios, key=ratios.get)
        mean_ratio = np.mean([res["mekf"][n].total_deg for n in names]) / np.mean(
            [res["vqf"][n].total_deg for n in names])
        print(f"\nmekf / VQF: mean ratio {mean_ratio:.3f} (target ≤ 0.85); worst trial {worst} "
              f"{ratios[worst]:.2f} (target ≤ 1.20)")


def main(argv: list[str] | None = None) -> int:
    ap = _arguments()
    args = ap.parse_args(argv)
    unknown = set(args.methods) - set(METHODS)
    if unknown:
        ap.error(f"unknown method(s): {', '.join(sorted(unknown))}")
    methods, notes = available_methods(args.methods)
    print("# ahrsd attitude accuracy benchmark")
    for name, note in notes.items():
        print(f"note: {name} {note}")
    if not args.no_sim and not args.vehicles:
        sim_section(methods, args.quick)
    if not args.no_broad and not args.vehicles:
        broad_section(methods, args.trials, args.quick, args.max_samples)
    if not args.no_vehicles:
        _vehicle_sections(args)
    if args.cv:
        from bench.cv import print_report, run_grid

        print_report(run_grid(trial_names=args.trials, max_samples=args.max_samples))
    return 0


def _arguments() -> argparse.ArgumentParser:
    from bench.vehicle_accuracy import HONESTY_IRONS, honesty_site_arg

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", nargs="*", help="BROAD trial name prefixes or substrings (default: all)")
    ap.add_argument("--methods", nargs="*", default=list(METHODS), help=f"subset of {', '.join(METHODS)}")
    ap.add_argument("--quick", action="store_true", help="40 s simulated runs, BROAD trials 01, 15, 32 only")
    ap.add_argument("--no-sim", action="store_true", help="skip the simulated scenarios")
    ap.add_argument("--no-broad", action="store_true", help="skip BROAD")
    ap.add_argument("--max-samples", type=int, default=None, help="truncate each BROAD trial")
    ap.add_argument("--vehicles", action="store_true", help="only the vehicle section (c)")
    ap.add_argument("--no-vehicles", action="store_true",
                    help="skip the vehicle section (c) and with it the honest-heading section (d)")
    ap.add_argument("--vehicle-seeds", type=int, default=3, help="seeds per vehicle and site in (c)")
    ap.add_argument("--vehicle-scenarios", nargs="*", default=None, metavar="SCENARIO",
                    help="moving scenarios for (c) (default: boat car plane)")
    ap.add_argument("--lever-arm", action="store_true",
                    help="(c): the GNSS antenna away from the IMU on each vehicle, ins told (and ins-untold not)")
    ap.add_argument("--site", action="append", default=None, metavar="LAT,LON[,ALT_M[,YYYY-MM-DD]]",
                    help="site(s) for (c) instead of the default and 60°N (repeatable)")
    ap.add_argument("--honesty-seconds", type=float, default=600.0,
                    help="(d) honest heading: run length of the uncalibrated / iron-change vehicles, s")
    ap.add_argument("--honesty-seeds", type=int, nargs="*", default=None,
                    help="(d): seeds (default 1 at the default site and 11 at the held-out one; --quick: 11 only)")
    ap.add_argument("--honesty-site", type=honesty_site_arg, default=None,
                    help='(d) at this site only (seeds: --honesty-seeds, else 11): "held-out", "default" or a place '
                         '"LAT,LON[,ALT_M[,YYYY-MM-DD]]" (with the held-out iron), as heading_timeline\'s --site')
    ap.add_argument("--honesty-iron", choices=HONESTY_IRONS, default=None,
                    help="(d) at --honesty-site (default held-out) with this vehicle iron instead of the site's own")
    ap.add_argument("--no-honesty", action="store_true", help="skip the honest-heading section (d)")
    ap.add_argument("--cv", action="store_true",
                    help="cross-validated tuning of mekf on BROAD (leave-one-trial-out and leave-one-pair-out "
                         "over bench/cv.py's candidate grid, beside VQF)")
    return ap


def _vehicle_sections(args) -> None:
    """(c) the vehicles, then (d) the honest heading unless --no-honesty (default seeds: 1 at the default site
    and 11 at the held-out one; --quick: 11 only; with --honesty-site / --honesty-iron: there, 11 only)."""
    from bench.vehicle_accuracy import HONESTY_SITES, VEHICLE_SCENARIOS, honesty_section, honesty_site, vehicle_section

    sites = {f"site{i + 1}": s for i, s in enumerate(args.site)} if args.site else None
    vehicle_section(args.quick, args.vehicle_seeds, sites, args.vehicle_scenarios or VEHICLE_SCENARIOS,
                    lever_arm=args.lever_arm)
    if args.no_honesty:
        return
    scen = args.vehicle_scenarios or VEHICLE_SCENARIOS
    if args.honesty_site or args.honesty_iron:
        site = args.honesty_site or "held-out"
        honesty_section(args.honesty_seconds, tuple(args.honesty_seeds or (11,)),
                        {site: honesty_site(site, args.honesty_iron)}, scen)
    elif args.honesty_seeds:
        honesty_section(args.honesty_seconds, tuple(args.honesty_seeds), HONESTY_SITES, scen)
    else:
        if not args.quick:
            honesty_section(args.honesty_seconds, (1,), {"default": HONESTY_SITES["default"]}, scen)
        honesty_section(args.honesty_seconds, (11,), {"held-out": HONESTY_SITES["held-out"]}, scen)


if __name__ == "__main__":
    raise SystemExit(main())
