"""µs per Adis16405.read_sample() through the simulated chip (driver only, chip + driver, stream generation,
fault plan armed) and the CPU share that is at 819.2 SPS.

    .venv/bin/python bench/driver_read.py [--samples 20000] [--repeat 3] [--scenario level-turns]
"""

from __future__ import annotations

import argparse
import time

from ahrsd.drivers import registers as R
from ahrsd.drivers.adis16405 import Adis16405
from ahrsd.drivers.faults import FaultPlan
from ahrsd.drivers.simulated import SimulatedAdis16405
from ahrsd.simulation import open_stream


def ideal_static():
    """A stream without physics or noise cost to speak of: the static scenario with ideal sensors."""
    return open_stream("static", rate_hz=R.sample_rate_hz(R.SMPL_PRD_DEFAULT), seed=0, errors="ideal")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--samples", type=int, default=20_000)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--scenario", default="level-turns")
    args = p.parse_args(argv)
    rate = R.sample_rate_hz(R.SMPL_PRD_DEFAULT)
    cases = [("ideal static stream (chip + driver only)", lambda: ideal_static(), None),
             (f"{args.scenario} (stream generation included)", lambda: args.scenario, None),
             ("ideal static stream, fault plan armed (slow path)", lambda: ideal_static(), "armed")]
    cases.insert(0, ("driver only (canned burst frame, no chip)", None, "canned"))
    print(f"{'case':48s} {'µs/read_sample':>15s} {'CPU at 819.2 SPS':>17s}   (best of {args.repeat})")
    for name, source, mode in cases:
        if mode == "canned":
            frame = SimulatedAdis16405(ideal_static()).transfer(R.BURST_COMMAND + bytes(24), R.SPI_BURST_HZ)

            class CannedBus:
                def transfer(self, tx, speed_hz, delay_us=0, _frame=frame):
                    return _frame

                def sleep(self, seconds):
                    time.sleep(seconds)

                def close(self):
                    pass

            imu = Adis16405(CannedBus())
        else:
            plan = FaultPlan()
            if mode == "armed":
                plan.add("alarm", start_sample=10**12)      # enabled but never due: every check runs
            chip = SimulatedAdis16405(source(), faults=plan)
            imu = Adis16405(chip)
            imu.start()
        for _ in range(2000):
            imu.read_sample()
        runs = []
        for _ in range(args.repeat):                        # best of N: the machine may be shared
            t0 = time.perf_counter()
            for _ in range(args.samples):
                imu.read_sample()
            runs.append((time.perf_counter() - t0) / args.samples * 1e6)
        us = min(runs)
        print(f"{name:48s} {us:15.1f} {us * rate / 1e4:16.2f}%")


if __name__ == "__main__":
    main()
