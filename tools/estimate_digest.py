"""An md5 digest of everything `ins` hands out over simulated GNSS runs: the check that moving code inside the
filter (issue #29, "a filter you can read") leaves its output bit-identical.

    .venv/bin/python tools/estimate_digest.py                  # one digest per run and one over all of them
    .venv/bin/python tools/estimate_digest.py --seconds 300    # longer runs
    .venv/bin/python tools/estimate_digest.py --gap-s 3        # instead: the runs with a gap in the samples

Run it on two checkouts (the same command in each worktree) and compare the lines. Runs: the boat, the car and
the plane of `bench/vehicle_accuracy.simulate_vehicle` (seed 0, the default site, each fix offered where it
arrives), the magnetometer uncalibrated and calibrated, the antenna at the vehicle's arm (`lever_arm=True`) and
the filter told that arm; and the same three vehicles uncalibrated told (0, 0, 0): a wrong arm, for the lever-arm
check. With `--gap-s`: instead, the uncalibrated runs told the right arm with no samples for that long from 40 % of
the run (the fixes still offered: those ahead of the samples wait), so that the filter restarts after the gap
keeping what it had learned (InsParams.reinit_dt_s). Each run goes through both entry points:
- `update`: every field of every estimate (AttitudeEstimate with its NavState and HeadingIntegrity), bit by bit;
- `step`: the view's t_s, valid and flags at every sample, and its snapshot at every 20th (the daemon builds an
  estimate when a publisher asks; a fix in between must not change what the view shows);
and in both, after every fix offered: what `update_gnss` returned, `gnss_counters`, `heading_report()`,
`heading_state`, the yaw resets and alignments, the latest heading-check record and `lever_arm_fit()`.
The WMM field (simulator and estimator) is evaluated on FIELD_DATE, not today (`--field-date`): the field's
secular variation would otherwise move every digest at midnight.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as _dt
import enum
import hashlib
import logging
import math
import struct
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))

STEP_SNAPSHOT_EVERY = 20
VEHICLES = ("boat", "car", "plane")
# the WMM field's date (core/wmm.py evaluates it on today's date otherwise, and a digest would move at midnight):
# the date the digests quoted in the commit messages and docs were taken on
FIELD_DATE = _dt.date(2026, 12, 6)


def _feed(h, value) -> None:
    """Every bit of `value` into the hash: floats as their IEEE bytes, arrays with their shape, dataclasses field by
    field, enums by value; a type tag before each, so that None and 0 differ."""
    if value is None:
        h.update(b"N")
    elif isinstance(value, (bool, np.bool_)):
        h.update(b"B1" if value else b"B0")
    elif isinstance(value, enum.Enum):
        h.update(b"E")
        _feed(h, value.value)
    elif isinstance(value, (int, np.integer)):
        h.update(b"I" + str(int(value)).encode())
    elif isinstance(value, (float, np.floating)):
        h.update(b"F" + struct.pack("<d", float(value)))
    elif isinstance(value, np.ndarray):
        a = np.ascontiguousarray(value)
        h.update(b"A" + str(a.shape).encode() + a.dtype.str.encode() + a.tobytes())
    elif dataclasses.is_dataclass(value):
        h.update(b"D" + type(value).__name__.encode())
        for f in dataclasses.fields(value):
            h.update(f.name.encode())
            _feed(h, getattr(value, f.name))
    elif isinstance(value, dict):
        h.update(b"M")
        for k in sorted(value):
            h.update(str(k).encode())
            _feed(h, value[k])
    elif isinstance(value, (tuple, list)):
        h.update(b"T" + str(len(value)).encode())
        for v in value:
            _feed(h, v)
    elif isinstance(value, str):
        h.update(b"S" + value.encode())
    else:
        raise TypeError(f"no digest for {type(value).__name__}")


def _after_fix(h, est, res) -> None:
    _feed(h, res)
    _feed(h, est.gnss_counters.as_dict())
    _feed(h, est.heading_report())
    _feed(h, est.heading_state)
    _feed(h, (est.yaw_resets, est.gnss_yaw_alignments, est.heading_interventions))
    _feed(h, est.heading_checks[-1] if est.heading_checks else None)
    _feed(h, est.lever_arm_fit())


def digest_run(run, told_arm_m, path: str, gap_s: float = 0.0) -> str:
    """The md5 of one run through `path` ("update" or "step")."""
    from ahrsd.core.gnss import GnssFix
    from ahrsd.core.sample import SampleFlags, make_sample
    from ahrsd.estimator.ins import Ins
    from ahrsd.simulation import in_arrival_order

    est = Ins(declination_rad=run.declination_rad, lever_arm_m=told_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad)
    h = hashlib.md5()
    t, g, a, m = run.t_s, run.gyro_rad_s, run.accel_m_s2, run.mag_ut
    gap_from_s = t[0] + 0.4 * (t[-1] - t[0])
    kept = [k for k in range(len(t)) if not gap_from_s <= t[k] < gap_from_s + gap_s]
    samples = (make_sample(t[k], g[k], a[k], m[k], flags=SampleFlags.NEW_DATA) for k in kept)
    k = 0
    for item in in_arrival_order(samples, run.fixes):
        if isinstance(item, GnssFix):
            _after_fix(h, est, est.update_gnss(item))
            continue
        if path == "update":
            _feed(h, est.update(item))
        else:
            v = est.step(item)
            _feed(h, (v.t_s, v.valid, v.flags))
            if k % STEP_SNAPSHOT_EVERY == 0:
                _feed(h, v.snapshot())
        k += 1
    _feed(h, (est.covariance, est.gyro_bias_rad_s, est.accel_bias_m_s2, est.last_nis, est.learned_iron()))
    return h.hexdigest()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=120.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--vehicles", nargs="+", default=list(VEHICLES))
    ap.add_argument("--gap-s", type=float, default=0.0, help="instead: the runs with a gap this long (s)")
    ap.add_argument("--field-date", type=_dt.date.fromisoformat, default=FIELD_DATE,
                    help=f"the date the WMM field is evaluated on, simulator and estimator (default {FIELD_DATE})")
    args = ap.parse_args(argv)
    logging.disable(logging.WARNING)
    from vehicle_accuracy import simulate_vehicle

    from ahrsd.core.wmm import fixed_date

    with fixed_date(args.field_date):
        return _print_digests(args, simulate_vehicle)


def _print_digests(args, simulate_vehicle) -> int:
    total = hashlib.md5()
    for vehicle in args.vehicles:
        cases = (("uncalibrated", "right"),) if args.gap_s > 0.0 else (
            ("uncalibrated", "right"), ("calibrated", "right"), ("uncalibrated", "zero"))
        for mag, told in cases:
            run = simulate_vehicle(vehicle, args.seconds, args.seed, None, lever_arm=True, mag=mag)
            arm = run.lever_arm_m if told == "right" else (0.0, 0.0, 0.0)
            for path in ("update", "step"):
                d = digest_run(run, arm, path, args.gap_s)
                total.update(d.encode())
                gap = f" gap {args.gap_s:g} s" if args.gap_s > 0.0 else ""
                print(f"{vehicle:5s} {mag:12s} told {told:5s}{gap} {path:6s} {d}", flush=True)
    print(f"all {total.hexdigest()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
