"""ins without a magnetometer (`mag_enabled=False`: `calibrate mag --gnss`'s magnetometer-free levelling, and a user
without one) over a simulated vehicle with GNSS: the velocities its gate rejected, whether its yaw was set to the
GNSS yaw (`gnss_yaw_alignments`), and from `--from-s` on the RMS and largest error of its own yaw, of the published
true heading (`heading_true_rad`) and the tilt, each with the share beyond 3σ of the published σ.

    .venv/bin/python bench/ins_no_magnetometer.py --kind car --seeds 0 1 2 3 --rates 819.2 400
    PYTHONPATH=/tmp/old ...                       # the same against another checkout (before → after)

Data: the simulator's vehicle at the default site (ADIS16405 errors, its iron, `simulate_gnss` at 5 Hz with the
seed 1000 + N), fed as `calibrate mag --gnss`'s levelling feeds it (`GnssFixFeed`: each fix before the first sample
not earlier than it). Truth: scipy's ZYX angles of the simulator's body→NED attitude.
"""

from __future__ import annotations

import argparse
import logging
import math
import time

import numpy as np
from scipy.spatial.transform import Rotation

from ahrsd.core.sample import make_sample
from ahrsd.estimator import make_estimator
from ahrsd.estimator.fix_feed import GnssFixFeed
from ahrsd.simulation import DEFAULT_SITE, open_stream, simulate_gnss


def run(kind: str, seed: int, rate_hz: float, seconds: float, from_s: float) -> str:
    t0 = time.process_time()
    stream = open_stream(kind, rate_hz=rate_hz, seed=seed, site=DEFAULT_SITE)
    b = stream.next_block(int(seconds * rate_hz))
    fixes = simulate_gnss(b, rate_hz=5.0, seed=1000 + seed)
    est = make_estimator("ins", declination_rad=stream.earth_field.declination_rad, mag_enabled=False)
    feed = GnssFixFeed(est, fixes)
    q = b.truth_q_wxyz
    ypr = Rotation.from_quat(np.column_stack([q[:, 1:], q[:, :1]])).as_euler("ZYX")
    n = len(b.t_s)
    own, pub, roll, pitch = (np.full(n, np.nan) for _ in range(4))
    sig = np.full((n, 3), np.nan)
    for i in range(n):
        feed.offer_until(b.t_s[i])
        e = est.update(make_sample(b.t_s[i], b.gyro_rad_s[i], b.accel_m_s2[i], b.mag_ut[i]))
        if e.yaw_rad is None:
            continue
        w, x, y, z = est._x["q"]
        own[i] = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        pub[i], roll[i], pitch[i], sig[i] = e.heading_true_rad, e.roll_rad, e.pitch_rad, e.sigma_rpy_rad
    late = b.t_s >= from_s

    def wrap_deg(a):
        return np.degrees((a + np.pi) % (2.0 * np.pi) - np.pi)[late]

    e_own, e_pub = wrap_deg(own - ypr[:, 0]), wrap_deg(pub - ypr[:, 0])
    e_roll, e_pitch = wrap_deg(roll - ypr[:, 2]), wrap_deg(pitch - ypr[:, 1])
    s = np.degrees(sig[late])

    def rms(a):
        return float(np.sqrt(np.nanmean(np.square(a))))

    def beyond(a, sd):
        return 100.0 * float(np.mean(np.abs(a) > 3.0 * sd))

    c = est.gnss_counters
    return (f"{kind} seed {seed} {rate_hz:g} SPS: velocities rejected {c.rejected_velocity} of {len(fixes)} "
            f"(resets {c.reset_velocity}), aligned {est.gnss_yaw_alignments} | from {from_s:g} s: own yaw "
            f"{rms(e_own):.2f}° RMS (max {np.nanmax(np.abs(e_own)):.1f}°); published yaw {rms(e_pub):.2f}° RMS, "
            f"σ median {np.nanmedian(s[:, 2]):.2f}°, {beyond(e_pub, s[:, 2]):.1f} % beyond 3σ | tilt "
            f"{rms(np.hypot(e_roll, e_pitch)):.3f}° RMS, roll / pitch beyond 3σ {beyond(e_roll, s[:, 0]):.1f} / "
            f"{beyond(e_pitch, s[:, 1]):.1f} % ({time.process_time() - t0:.0f} CPU s)")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kind", default="car", choices=("boat", "car", "plane"))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    ap.add_argument("--rates", type=float, nargs="+", default=[819.2, 400.0])
    ap.add_argument("--seconds", type=float, default=150.0)
    ap.add_argument("--from-s", type=float, default=30.0)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    for rate in args.rates:
        for seed in args.seeds:
            print(run(args.kind, seed, rate, args.seconds, args.from_s), flush=True)


if __name__ == "__main__":
    main()
