"""How far a serial receiver's fix stamps are from the epochs' true times, with a reader that is held up.

    .venv/bin/python bench/gnss_stamps.py [--seconds 30] [--hold-share 0.1] [--protocol ubx|nmea]

The simulated receiver (drivers.gnss.simulated, 5 Hz, 0.05 s output latency) writes each epoch into a pty when
the monotonic clock reaches the epoch's time + its latency; `SerialGnssSource` (told the same latency) reads it
as the daemon does, waiting on the descriptor, but with `--hold-share` of its reads held up 0.2–1.0 s first (a
busy daemon). Truth: each epoch's own time. Prints the stamp − truth distribution, the non-increasing steps and
the source's time-stamp counters. Run the old code with PYTHONPATH=<an old checkout's parent> to compare.
"""

from __future__ import annotations

import argparse
import random
import select
import time

import numpy as np

from ahrsd.core.gnss import make_fix
from ahrsd.drivers.gnss.serial_port import SerialGnssSource
from ahrsd.drivers.gnss.simulated import SimulatedGnssReceiver

LATENCY_S = 0.05
RATE_HZ = 5.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--hold-share", type=float, default=0.1, help="share of reads held up 0.2-1.0 s first")
    ap.add_argument("--protocol", choices=("ubx", "nmea"), default="ubx")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    rng = random.Random(args.seed)
    n = int(args.seconds * RATE_HZ)
    t0 = time.monotonic() + 0.5
    # the epoch index rides in the latitude (1e-6 deg apart), so each stamp is matched to its own epoch
    fixes = [make_fix(t0 + k / RATE_HZ, 47.0 + 1e-6 * k, 8.0, 500.0, [1.0, 0.0, 0.0], h_acc_m=1.0, v_acc_m=1.0,
                      s_acc_m_s=0.1, num_sats=9) for k in range(n)]
    got = []
    with SimulatedGnssReceiver(fixes, protocol=args.protocol, latency_s=LATENCY_S) as rx, \
            SerialGnssSource(rx.device, 115200, args.protocol, latency_s=LATENCY_S) as src:
        rx.start()
        end = t0 + args.seconds + 2.0
        while time.monotonic() < end and len(got) < n:
            select.select([src.fileno()], [], [], 0.5)
            if rng.random() < args.hold_share:
                time.sleep(rng.uniform(0.2, 1.0))
            got += src.read_available()
        got += src.decoder.flush()
        counters = {k: src.counters.get(k) for k in ("fixes", "stamps_held", "receiver_clock_jumps")}
    k = np.array([round((f.lat_deg - 47.0) / 1e-6) for f in got])
    t = np.array([f.t_s for f in got])
    err_ms = 1e3 * (t - np.array([fixes[i].t_s for i in k]))
    with open("/proc/loadavg") as f:
        load = f.read().split()[0]
    print(f"{args.protocol}, {len(got)}/{n} epochs, hold-share {args.hold_share}, load {load}: stamp − truth ms "
          f"median {np.median(err_ms):.1f}, p95 {np.percentile(err_ms, 95):.1f}, max {err_ms.max():.1f}, "
          f"min {err_ms.min():.1f}; non-increasing steps {int(np.sum(np.diff(t) <= 0))}; counters {counters}")


if __name__ == "__main__":
    main()
