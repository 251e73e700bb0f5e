"""What limits back-stepping `--gnss` at a high dip: the aided levelling's error sources, removed one at a time.

    .venv/bin/python bench/backstepping_limits.py                         # 60° N, held-out seeds 4..8
    .venv/bin/python bench/backstepping_limits.py --sites default 60N     # both sites (~8 min: docs/magcal-vehicle.md)
    .venv/bin/python bench/backstepping_limits.py --sites default --seeds 1 2 3

The runs are bench/backstepping_gnss.py's boat in its `afix` case (the accelerometer calibrated and aligned to
the housing, the levelling told its bias is known to 2 mg). Each column changes one thing, levels again with the
aided filter smoothed over the run (calibration.backstepping_aided, with its fallback), fits back-stepping, and
prints the grid figure of that bench: true-heading RMS at other attitudes with the mean offset kept, and that
mean, in degrees (target ≤ 0.3).

- `as is`: the `afix` column of bench/backstepping_gnss.py.
- `no gyro noise`, `no accel noise`: the same sensor without the gyro's (accelerometer's) white noise: the angle
  (velocity) random walk. Everything else is the same draw: the simulator keeps a random stream per error source.
- `gyro cal`: the gyro's scale and misalignment removed from the data, as an exact rate-table calibration would
  (calibration/inertial/gyro.py), and the filter told they are known (0.05 %, 0.02°: `filter_overrides`).
- `bias 0.5mg`: the levelling told the accelerometer bias is known to 0.5 mg (`--accel-bias-sigma-mg 0.5`) instead
  of 2: a bias calibrated on the run's own power-up.
- `exact GNSS`: each fix's position and velocity are the truth (still weighted as 1.5 m and 0.05 m/s);
  `exact pos`, `exact vel`: only the position (only the velocity) the truth, to tell which of the two limits it.
- `vel 0.02`: a receiver whose velocity noise, and the accuracy it reports, is 0.02 m/s instead of 0.05 (a
  dual-frequency or RTK receiver's Doppler velocity); position as before.
- `GNSS 10 Hz`: the same receiver solving at 10 Hz instead of 5 (u-blox M8 and later do, GPS only or with fewer
  constellations).
- `ideal IMU`: no gyro or accelerometer error at all (noise, biases, scale, misalignment, temperature).
- `ideal+exact`: both.
- `arm untold`, `arm told`: the fixes of a receiver whose antenna is ARM_M from the IMU (1 m aft, 2 m up), with
  the levelling not told and told the lever arm (`calibrate mag --lever-arm-m`).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.backstepping_gnss import SITES, TARGET_DEG, BoatRun, _rms, grid_error_deg  # noqa: E402

HELD_OUT_SEEDS = (4, 5, 6, 7, 8)
ARM_M = (-1.0, 0.0, -2.0)
GYRO_CAL_OVERRIDES = {"init_gyro_scale_sigma": 5e-4, "init_gyro_misalignment_sigma_rad": math.radians(0.02)}
VARIANTS = ("as is", "no gyro noise", "no accel noise", "gyro cal", "bias 0.5mg", "exact GNSS", "exact pos",
            "exact vel", "vel 0.02", "GNSS 10 Hz", "ideal IMU", "ideal+exact", "arm untold", "arm told")
_Z3, _Z33 = np.zeros(3), np.zeros((3, 3))
IDEAL_IMU = dict(gyro_bias_rad_s=_Z3, gyro_scale=_Z3, gyro_misalignment_rad=_Z33, gyro_noise_density_rad_s_rthz=0.0,
                 gyro_bias_instability_rad_s=0.0, gyro_bias_temp_rad_s_per_c=_Z3, accel_bias_m_s2=_Z3,
                 accel_scale=_Z3, accel_misalignment_rad=_Z33, accel_noise_density_m_s2_rthz=0.0,
                 accel_bias_instability_m_s2=0.0, accel_bias_temp_m_s2_per_c=_Z3)


def _resimulated(run: BoatRun, site_text, seed: int, **error_changes):
    """The same run (trajectory, and every error source not changed: its own random stream) with these sensor
    errors changed: the block."""
    from ahrsd.simulation import DEFAULT_SITE, Site, open_stream

    from bench.backstepping_gnss import RATE_HZ, SECONDS

    site = Site.parse(site_text) if site_text else DEFAULT_SITE
    errors = dataclasses.replace(run.errors, **error_changes)     # run.errors already holds the vehicle iron
    b = open_stream("boat", rate_hz=RATE_HZ, seed=seed, site=site, errors=errors, vehicle_iron=None).next_block(
        len(run.block.t_s))
    if not np.array_equal(b.mag_ut, run.block.mag_ut):
        raise RuntimeError("the re-simulated run differs in its magnetometer: not the same draw")
    return b


def _exact(fixes, position: bool = True, velocity: bool = True):
    """The fixes with the truth in place of the measured position and/or velocity."""
    out = []
    for f in fixes:
        t = f.extra["truth"]
        if position:
            f = dataclasses.replace(f, lat_deg=t.lat_deg, lon_deg=t.lon_deg, alt_m=t.alt_m)
        if velocity:
            f = dataclasses.replace(f, vel_ned_m_s=np.array(t.vel_ned_m_s, dtype=float))
        out.append(f)
    return out


def variant_inputs(run: BoatRun, site_text, seed: int, name: str):
    """(data, fixes, accel-bias prior m/s², filter overrides) of one column."""
    from ahrsd.calibration.accel_trust import ACCEL_BIAS_SIGMA_CALIBRATED_M_S2
    from ahrsd.calibration.mag.fit_types import MagFitInput
    from ahrsd.core.angles import STANDARD_GRAVITY_M_S2
    from ahrsd.simulation import GnssErrors, simulate_gnss

    data, fixes, prior, overrides = run.data_afix, run.fixes, ACCEL_BIAS_SIGMA_CALIBRATED_M_S2, None

    def calibrated(b):
        return MagFitInput(b.t_s, b.mag_ut, np.ascontiguousarray(run.accel_model_afix.apply(b.accel_m_s2)),
                           b.gyro_rad_s)

    if name == "no gyro noise":
        data = calibrated(_resimulated(run, site_text, seed, gyro_noise_density_rad_s_rthz=0.0))
    elif name == "no accel noise":
        data = calibrated(_resimulated(run, site_text, seed, accel_noise_density_m_s2_rthz=0.0))
    elif name == "gyro cal":
        exact = np.linalg.inv(run.errors.gyro_matrix)
        data = dataclasses.replace(data, gyro_rad_s=np.ascontiguousarray(data.gyro_rad_s @ exact.T))
        overrides = GYRO_CAL_OVERRIDES
    elif name == "bias 0.5mg":
        prior = 0.5e-3 * STANDARD_GRAVITY_M_S2
    elif name in ("ideal IMU", "ideal+exact"):
        b = _resimulated(run, site_text, seed, **IDEAL_IMU)
        data = MagFitInput(b.t_s, b.mag_ut, b.accel_m_s2, b.gyro_rad_s)
    if name in ("exact GNSS", "ideal+exact"):
        fixes = _exact(fixes)
    if name in ("exact pos", "exact vel"):
        fixes = _exact(fixes, position=name == "exact pos", velocity=name == "exact vel")
    if name == "vel 0.02":
        fixes = simulate_gnss(run.block, rate_hz=5.0, seed=seed + 1000,
                              errors=dataclasses.replace(GnssErrors(), velocity_m_s=0.02))
    if name == "GNSS 10 Hz":
        fixes = simulate_gnss(run.block, rate_hz=10.0, seed=seed + 1000)
    if name in ("arm untold", "arm told"):
        fixes = simulate_gnss(run.block, rate_hz=5.0, seed=seed + 1000, lever_arm_m=ARM_M)
        overrides = {"lever_arm_m": ARM_M} if name == "arm told" else None
    return data, fixes, prior, overrides


def one_run(job):
    """Grid RMS and mean (deg) of every column for one (site, seed)."""
    from ahrsd.calibration.mag.backstepping_aided import fit_backstepping_aided

    label, site_text, seed = job
    logging.getLogger("ahrsd.estimator.ins").setLevel(logging.ERROR)
    run = BoatRun(seed, site_text)
    row = {}
    for name in VARIANTS:
        data, fixes, prior, overrides = variant_inputs(run, site_text, seed, name)
        res = fit_backstepping_aided(data, fixes, run.field, run.field.declination_rad, accel_bias_sigma_m_s2=prior,
                                     filter_overrides=overrides)
        err = grid_error_deg(run, res.model) if res.ok else np.array([math.nan])
        row[name] = (_rms(err), float(np.mean(err)))
    return label, seed, row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=list(HELD_OUT_SEEDS))
    ap.add_argument("--sites", nargs="+", default=["60N"], choices=list(SITES))
    ap.add_argument("--jobs", type=int, default=2, help="processes (default 2)")
    args = ap.parse_args(argv)
    jobs = [(label, SITES[label], seed) for label in args.sites for seed in args.seeds]
    print(f"# back-stepping --gnss on the boat (afix), grid true-heading RMS (mean) in degrees, target ≤ {TARGET_DEG}; "
          "one error source changed per column (see the docstring)")
    hdr = f"{'site':8s} {'seed':>4s} " + "".join(f"{n:>16s}" for n in VARIANTS)
    print(hdr)
    print("-" * len(hdr))
    t0 = time.perf_counter()
    table = []
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        for label, seed, row in pool.map(one_run, jobs):
            table.append([row[n] for n in VARIANTS])
            print(f"{label:8s} {seed:4d} " + "".join(f"{g:9.2f} ({m:+.2f})" for g, m in table[-1]), flush=True)
    print("-" * len(hdr))
    a = np.array(table)          # runs × variants × (rms, mean)
    for agg, fn in (("mean", np.nanmean), ("worst", np.nanmax)):
        print(f"{agg:13s} " + "".join(f"{v:16.2f}" for v in fn(a[:, :, 0], axis=0)))
    print(f"{'≤ target':13s} " + "".join(f"{int(np.sum(a[:, i, 0] <= TARGET_DEG)):>13d}/{len(a):<2d}"
                                          for i in range(len(VARIANTS))))
    print(f"({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
