"""ins with its GNSS antenna somewhere else than told: the lever-arm check (estimator/lever_arm_fit.py) against the
simulator's truth. Per run: the velocities the gate rejected, when the told arm was found wrong, the arm the filter
fuses at in the end (told + adopted), and from `--from-s` on the published true heading: the share of samples
published known (σ below `heading_unknown_sigma_rad`), their RMS error, the share of them beyond 3σ and the median σ.

    .venv/bin/python bench/lever_arm_heading.py                                # the mast boat, told none / told right
    .venv/bin/python bench/lever_arm_heading.py --adopt                        # ins adopting the fitted arm
    .venv/bin/python bench/lever_arm_heading.py --kinds boat car --seeds 0 1 2 3 --seconds 300 --cases right
    PYTHONPATH=/tmp/old ...                                                    # the same against another checkout

    .venv/bin/python bench/lever_arm_heading.py --kinds car --seeds 61 62 63 --seconds 600 \
        --site 64.15,-21.94                                                    # held back: Reykjavik
    .venv/bin/python bench/lever_arm_heading.py --kinds car --params '{"lever_arm_sigma_m": 0}'   # the arm as exact

Data: the simulator's vehicle at the default site or `--site` (ADIS16405 errors, its iron, the magnetometer uncalibrated),
`simulate_gnss` at 5 Hz with the seed 1000 + N and the antenna at `--antenna-m` (body FRD, m), fed as
`calibrate mag --gnss` feeds fixes (`GnssFixFeed`). Cases: `none` (the filter told (0, 0, 0): the antenna on a mast
it does not know of), `right` (told the true arm) and `told` (told `--told-m`). `--errors ideal`: an IMU without
errors, so that the fit sees only the arm, the receiver and the filter's own errors; `fitted antenna` is the mean of
where the check puts the antenna (told + its error as best known), once a second from `--from-s`; `arm term` what
the told arm's error makes of the velocity, |ω × δr| at the fixes (the gyro's rate).

    .venv/bin/python bench/lever_arm_heading.py --kinds car --errors ideal --seconds 300 --from-s 60 \
        --cases told --told-m -1 0 0                                               # the car told a height 2 m wrong Truth: scipy's ZYX yaw of the simulator's body→NED attitude.
"""

from __future__ import annotations

import argparse
import json
import logging
import math

import numpy as np
from scipy.spatial.transform import Rotation

from ahrsd.core.sample import make_sample
from ahrsd.estimator import make_estimator
from ahrsd.estimator.fix_feed import GnssFixFeed
from ahrsd.simulation import DEFAULT_SITE, Site, open_stream, simulate_gnss

MAST_M = (-1.0, 0.0, -2.0)       # 1 m aft, 2 m up (body FRD): a boat's receiver on its mast


def run(kind: str, seed: int, rate_hz: float, seconds: float, from_s: float, antenna_m, told_m,
        show_fit_every_s: float = 0.0, adopt: bool = False, errors: str = "adis16405", site: Site = DEFAULT_SITE,
        params: dict | None = None) -> str:
    stream = open_stream(kind, rate_hz=rate_hz, seed=seed, site=site, errors=errors)
    b = stream.next_block(int(seconds * rate_hz))
    fixes = simulate_gnss(b, rate_hz=5.0, seed=1000 + seed, lever_arm_m=antenna_m)
    est = make_estimator("ins", declination_rad=stream.earth_field.declination_rad, lever_arm_m=told_m,
                         lever_arm_adopt=adopt, **(params or {}))
    feed = GnssFixFeed(est, fixes)
    # the told arm's error seen in the velocity: |ω × δr| (C keeps the length) at the fixes, the gyro's rate
    step = max(int(round(rate_hz / 5.0)), 1)
    arm_term = np.linalg.norm(np.cross(b.gyro_rad_s[::step], np.asarray(antenna_m) - np.asarray(told_m)), axis=1)
    q = b.truth_q_wxyz
    true_yaw = Rotation.from_quat(np.column_stack([q[:, 1:], q[:, :1]])).as_euler("ZYX")[:, 0]
    unknown_rad = est.params.heading_unknown_sigma_rad
    errors_deg, sigmas_deg, late, found_at_s, antennas = [], [], 0, math.nan, []
    next_show_s = show_fit_every_s if show_fit_every_s > 0.0 else math.inf
    for i in range(len(b.t_s)):
        feed.offer_until(b.t_s[i])
        e = est.update(make_sample(b.t_s[i], b.gyro_rad_s[i], b.accel_m_s2[i], b.mag_ut[i]))
        fit = est.lever_arm_fit()
        if math.isnan(found_at_s) and fit is not None and fit.arm_wrong:
            found_at_s = float(b.t_s[i])
        if b.t_s[i] >= from_s and fit is not None and i % int(rate_hz) == 0 and np.all(np.isfinite(fit.offset_m)):
            antennas.append(fit.antenna_m(told_m))      # once a second: where the check puts the antenna
        if b.t_s[i] >= next_show_s and fit is not None:
            next_show_s += show_fit_every_s
            print(f"  {b.t_s[i]:6.1f} s  fit δr {np.round(fit.offset_m, 2)} m  1σ {np.round(fit.sigma_m, 2)} m  "
                  f"χ² {fit.chi2:5.1f}  explained {fit.explained_share:.2f}  explains {fit.explains}  "
                  f"rejected {est.gnss_counters.rejected_velocity}")
        if b.t_s[i] < from_s or e.yaw_rad is None:
            continue
        late += 1
        if e.sigma_rpy_rad[2] >= unknown_rad:
            continue                     # published unknown: claims nothing, so it is neither right nor wrong
        d = (e.heading_true_rad - true_yaw[i] + math.pi) % (2.0 * math.pi) - math.pi
        errors_deg.append(math.degrees(d))
        sigmas_deg.append(math.degrees(e.sigma_rpy_rad[2]))
    fit = est.lever_arm_fit()
    in_use = np.asarray(told_m, dtype=float) + (fit.adopted_m if fit is not None and fit.adopted_m is not None else 0.0)
    c = est.gnss_counters
    found = "never" if math.isnan(found_at_s) else f"{found_at_s:5.1f} s"
    arm = ",".join(f"{v:+.2f}" for v in in_use)
    fitted = ",".join(f"{v:+.2f}" for v in np.mean(antennas, axis=0)) if antennas else "none"
    head = (f"{kind:5s} {seed:4d} {rate_hz:6.1f}  told {','.join(f'{v:g}' for v in told_m):>9s}  rejected {c.rejected_velocity:4d}/{c.offered:4d}  found wrong {found:>7s}  arm in use {arm}"
            f"  fitted antenna (mean from {from_s:g} s) {fitted}  arm term |ω×δr| median/95 %/max "
            f"{np.median(arm_term):.2f}/{np.percentile(arm_term, 95):.2f}/{arm_term.max():.2f} m/s")
    if not errors_deg:
        return f"{head}  from {from_s:g} s: unknown on all {late} samples"
    err, sig = np.asarray(errors_deg), np.asarray(sigmas_deg)
    return (f"{head}  from {from_s:g} s: known {100.0 * len(err) / max(late, 1):5.1f} %  RMS {math.sqrt(np.mean(err ** 2)):5.2f}°"
            f"  beyond 3σ {100.0 * np.mean(np.abs(err) > 3.0 * sig):5.2f} %  σ median {np.median(sig):5.2f}°")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", nargs="+", default=["boat"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--rates", nargs="+", type=float, default=[100.0], help="IMU rate(s), Hz")
    ap.add_argument("--seconds", type=float, default=240.0)
    ap.add_argument("--from-s", type=float, default=120.0, help="score the heading from this time on")
    ap.add_argument("--antenna-m", type=float, nargs=3, default=MAST_M, help="the true antenna arm, body FRD, m")
    ap.add_argument("--cases", nargs="+", choices=("none", "right", "told"), default=["none", "right"])
    ap.add_argument("--told-m", type=float, nargs=3, default=(0.0, 0.0, 0.0),
                    help="the arm the filter is told in the case `told`, body FRD, m")
    ap.add_argument("--errors", choices=("adis16405", "ideal"), default="adis16405",
                    help="the simulated IMU's errors (open_stream): `ideal` leaves only the arm and the receiver")
    ap.add_argument("--adopt", action="store_true",
                    help="let ins adopt the fitted arm once sure of it (InsParams.lever_arm_adopt, off by default)")
    ap.add_argument("--show-fit-every-s", type=float, default=0.0,
                    help="print the lever-arm fit (δr, its 1σ, χ², explained share) this often, s (0: never)")
    ap.add_argument("--site", type=Site.parse, default=DEFAULT_SITE,
                    help="the place, LAT,LON[,ALT_M[,YYYY-MM-DD]] (default: the simulator's DEFAULT_SITE)")
    ap.add_argument("--params", type=json.loads, default={},
                    help="ins parameters as JSON, e.g. '{\"lever_arm_sigma_m\": 0}' (the arm fused as exact)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    for kind in args.kinds:
        for seed in args.seeds:
            for rate in args.rates:
                for case in args.cases:
                    told = {"none": (0.0, 0.0, 0.0), "right": tuple(args.antenna_m), "told": tuple(args.told_m)}[case]
                    print(run(kind, seed, rate, args.seconds, args.from_s, tuple(args.antenna_m), told,
                              args.show_fit_every_s, args.adopt, args.errors, args.site, args.params), flush=True)


if __name__ == "__main__":
    main()
