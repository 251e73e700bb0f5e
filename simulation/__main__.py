"""`python -m ahrsd.simulation`: list the scenarios, the site and the error defaults, and measure the speed.

    python -m ahrsd.simulation            # summary
    python -m ahrsd.simulation --speed    # also time next_block(82), next_block(1) and 60 s batches
"""

from __future__ import annotations

import argparse
import inspect
import math
import time

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ahrsd.simulation", description=__doc__.splitlines()[0])
    ap.add_argument("--speed", action="store_true", help="time the streams (a few seconds)")
    args = ap.parse_args(argv)

    from ahrsd.simulation import (DEFAULT_SITE, EXTRA_SCENARIOS, SCENARIOS, GnssErrors, SensorErrors, make_scenario,
                                  open_stream, simulate, simulate_gnss)

    f = DEFAULT_SITE.earth_field()
    print(f"site: lat {DEFAULT_SITE.lat_deg}° lon {DEFAULT_SITE.lon_deg}° alt {DEFAULT_SITE.alt_m} m "
          f"{DEFAULT_SITE.date}; g {DEFAULT_SITE.gravity_m_s2:.5f} m/s²; WMM2025 F {f.total_ut:.2f} µT, "
          f"dip {math.degrees(f.inclination_rad):.2f}°, declination {math.degrees(f.declination_rad):+.2f}°")
    e = SensorErrors.adis16405(0)
    std = e.noise_std(819.2)
    print(f"ADIS16405 @ 819.2 SPS: gyro {math.degrees(std['gyro_rad_s']):.3f} °/s rms, "
          f"accel {std['accel_m_s2'] / 9.80665 * 1e3:.2f} mg rms, mag {std['mag_ut'] * 10:.2f} mgauss rms; "
          f"bias instability {math.degrees(e.gyro_bias_instability_rad_s):.3f} °/s, "
          f"{e.accel_bias_instability_m_s2 / 9.80665 * 1e3:.2f} mg")
    g = GnssErrors()
    gnss_defaults = inspect.signature(simulate_gnss).parameters
    print(f"GNSS (simulate_gnss): {gnss_defaults['rate_hz'].default:g} Hz, position σ {g.horizontal_m} m N/E, "
          f"{g.vertical_m} m D ({g.wander_fraction:.0%} of the variance wandering, τ {g.wander_tau_s:.0f} s), velocity σ "
          f"{g.velocity_m_s} m/s, latency {gnss_defaults['latency_s'].default:g} s")
    for name in SCENARIOS + tuple(EXTRA_SCENARIOS):
        sc = make_scenario(name)
        iron = "vehicle iron" if sc.default_iron is not None else "no iron"
        extra = ", make_scenario only" if name in EXTRA_SCENARIOS else ""
        print(f"  {name:18s} {sc.description} ({iron}{extra})")
    if args.speed:
        print("speed (this machine):")
        for name in SCENARIOS:
            st = open_stream(name)
            st.next_block(819)
            t0 = time.perf_counter()
            for _ in range(100):
                st.next_block(82)
            per82 = (time.perf_counter() - t0) / 100
            t0 = time.perf_counter()
            for _ in range(2000):
                st.next_block(1)
            per1 = (time.perf_counter() - t0) / 2000
            t0 = time.perf_counter()
            simulate(name, 60.0)
            batch = (time.perf_counter() - t0) / 60.0
            print(f"  {name:18s} {per82 * 1e6:6.0f} µs per next_block(82), {per1 * 1e6:5.1f} µs per next_block(1), "
                  f"{batch * 1e3:4.1f} ms per simulated second at 819.2 Hz ({1 / batch:.0f}× real time)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
