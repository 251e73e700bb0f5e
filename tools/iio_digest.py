"""An md5 digest of what the kernel IIO path delivers (drivers.iio_source `decode`): the check that making the
IIO reader cheaper leaves the samples it delivers — values, time stamps, flags, sample indices — and its counts
bit-identical.

    .venv/bin/python tools/iio_digest.py              # one line per case and one over all of them

Run it in two checkouts (the same command in each worktree) and compare the lines. The source is started on the
simulated IIO device (drivers.simulated_iio: its sysfs tree, scales and record layout, as on hardware); its buffer is
not opened: the records are made here from a seeded generator with the simulated kernel's own `scan_record` and
decoded in blocks of drawn sizes (1 to 40 records, as reads of any interval give them). Hashed, sample by sample:
the time, the nine vector components (float64 bytes), temperature, supply, flags, DIAG_STAT and index; at the end
the source's counters. Cases: `clean` (new data in every record, the kernel's stamps one period apart with
jitter), `faults` (stale records, alarms, saturated and garbage words on each sensor, lost scans, a record
repeated and one stamped backwards).
"""

from __future__ import annotations

import argparse
import hashlib
import struct
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

SEED = 41
RECORDS = 20000
PERIOD_NS = 1e9 / 819.2


def _words(rng: np.random.Generator, faults: bool) -> list[int]:
    """The chip's 12 burst words: ND set, 14-bit readings (12-bit temperature and aux), and with `faults` the
    chip's alarm bit, a saturated or a garbage reading on one sensor word, a stale record (ND clear)."""
    lsb = [int(rng.integers(0, 1 << 14)) for _ in range(10)] + [int(rng.integers(0, 1 << 12)) for _ in range(2)]
    for axis in range(1, 10):                       # mostly small readings: the ranges are ±6000, ±8192, ±8192 LSB
        lsb[axis] = int(rng.integers(-2000, 2000)) & 0x3FFF
    words = [0x8000 | v for v in lsb]
    if faults:
        u = rng.random()
        axis = int(rng.integers(1, 10))
        if u < 0.02:
            words[axis] = 0x8000 | (7400 if axis <= 3 else 8191)              # at or beyond full scale
        elif u < 0.03:
            words[1] = 0x8000 | 8000                                        # gyro beyond 1.25 × its range
        elif u < 0.05:
            words[axis] |= 0x4000                                           # EA: the chip's alarm
        elif u < 0.06:
            words = [w & 0x7FFF for w in words]                             # ND clear: no new sample
    return words


def _stamps(rng: np.random.Generator, n: int, faults: bool) -> list[int]:
    t0 = 5_000_000_000
    out, k = [], 0
    for _ in range(n):
        jitter = int(rng.integers(-300_000, 300_000))        # the interrupt's stamp: ±0.3 ms of the grid
        out.append(int(t0 + k * PERIOD_NS) + jitter)
        u = rng.random()
        k += 1
        if faults and u < 0.01:
            k += int(rng.integers(1, 40))                   # scans the kernel lost
        elif faults and u < 0.012 and out:
            out.append(out[-1])                             # the same stamp again
        elif faults and u < 0.014 and out:
            out.append(out[-1] - 500_000)                   # a stamp before the last one
    return out[:n]


def digest_case(src, kind: str) -> str:
    from ahrsd.drivers.simulated_iio import SCAN_ELEMENTS, scan_record

    rng = np.random.default_rng([SEED, kind == "faults"])
    faults = kind == "faults"
    stamps = _stamps(rng, RECORDS, faults)
    data = b"".join(scan_record(_words(rng, faults), t, list(SCAN_ELEMENTS)) for t in stamps)
    size = src.record_bytes
    h = hashlib.md5()
    i = 0
    while i < len(stamps):
        n = int(rng.integers(1, 41))
        for s in src.decode(data[i * size:(i + n) * size]):
            h.update(struct.pack("<d", s.t_s))
            for v in (s.gyro_rad_s, s.accel_m_s2, s.mag_ut):
                h.update(np.asarray(v, dtype=np.float64).tobytes())
            h.update(struct.pack("<ddqqq", s.temp_c, s.supply_v, int(s.flags), s.diag_stat, s.counter))
        i += n
    h.update(repr(sorted(src.counters().items())).encode())
    return h.hexdigest()


def main() -> None:
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    from ahrsd.drivers.iio_source import IioSource
    from ahrsd.drivers.simulated_iio import SimulatedIioDevice

    total = hashlib.md5()
    for kind in ("clean", "faults"):
        with tempfile.TemporaryDirectory() as tmp:
            device = SimulatedIioDevice(tmp, scenario="static", seed=2)
            try:
                device.wait_ready()
                src = IioSource(str(device.sysfs))
                src.start()
                d = digest_case(src, kind)
            finally:
                device.close()
        total.update(d.encode())
        print(f"{kind:6s} {d}")
    print(f"all {total.hexdigest()}")


if __name__ == "__main__":
    main()
