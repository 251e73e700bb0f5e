"""CPU cost of decoding a GNSS receiver's bytes (drivers.gnss.stream), per epoch and for a garbage stream.

    .venv/bin/python bench/gnss_decode.py

Feeds the decoder whole epochs (one UBX NAV-PVT, or NMEA RMC+VTG+GGA) as the serial source does, and
garbage: what a reader sees of a receiver at the wrong baud rate (both ways, re-timed by the simulated
UART) and uniform random bytes, costed at a full 115200-baud line.
Best of 5 runs (the machine is shared: the minimum is the least disturbed). The share of a core at 10 Hz
is what the decoder adds to the daemon.
"""

from __future__ import annotations

import datetime as dt
import random
import time

from ahrsd.core.gnss import make_fix
from ahrsd.drivers.gnss.nmea import nmea_epoch_sentences
from ahrsd.drivers.gnss.simulated import uart_resample
from ahrsd.drivers.gnss.stream import GnssStreamDecoder
from ahrsd.drivers.gnss.ubx import nav_pvt_message

EPOCHS = 2000
REPEAT = 5


def _best(run) -> float:
    return min(run() for _ in range(REPEAT))


def main() -> None:
    fix = make_fix(0.0, 47.1, 8.2, 500.0, [1.0, 2.0, 0.1], h_acc_m=1.0, v_acc_m=2.0, s_acc_m_s=0.1, num_sats=12)
    ubx = nav_pvt_message(fix, 1000).serialize()
    nmea = b"".join(m.serialize() for m in nmea_epoch_sentences(fix, dt.datetime(2026, 1, 1, 12)))
    print(f"{'stream':28s} {'bytes':>7s} {'µs/epoch':>9s} {'% core at 10 Hz':>16s}")
    for name, frame, protocol in (("UBX NAV-PVT", ubx, "ubx"), ("NMEA RMC+VTG+GGA", nmea, "nmea")):
        def run():
            decoder = GnssStreamDecoder(protocol)
            t0 = time.perf_counter()
            for k in range(EPOCHS):
                decoder.feed(frame, float(k))
            assert decoder.counters.fixes >= EPOCHS - 1
            return (time.perf_counter() - t0) / EPOCHS
        per_epoch = _best(run)
        print(f"{name:28s} {len(frame):7d} {per_epoch * 1e6:9.1f} {per_epoch * 10 * 100:16.3f}")

    bytes_per_s = 115200 / 10                     # 8N1: 10 bits a byte, the line never idle (worst case)
    streams = (("9600-baud UBX read at 115200", uart_resample(ubx * 200, 9600, 115200)),
               ("115200-baud UBX read at 9600", uart_resample(ubx * 2000, 115200, 9600)),
               ("uniform random bytes", random.Random(1).randbytes(100_000)))
    for name, wire in streams:
        def run_garbage():
            decoder = GnssStreamDecoder("auto")
            t0 = time.perf_counter()
            for i in range(0, len(wire), 256):
                decoder.feed(wire[i:i + 256], 0.0)
            assert decoder.counters.fixes == 0
            return (time.perf_counter() - t0) / len(wire)
        per_byte = _best(run_garbage)
        print(f"{name:28s} {len(wire):7d} {per_byte * 1e6:9.3f} µs/B "
              f"{bytes_per_s * per_byte * 100:7.3f} % core at {bytes_per_s:.0f} B/s")


if __name__ == "__main__":
    main()
