"""An md5 digest of what the simulator and the simulated chip hand out: the check that making them cheaper leaves
their output bit-identical.

    .venv/bin/python tools/sim_digest.py              # one line per part and one over all of them
    .venv/bin/python tools/sim_digest.py --seconds 5  # shorter runs (a quick look; the default is the check)

Run it in two checkouts (the same command in each worktree) and compare the lines. Parts:
- `stream`: every field of every SensorBlock of each scenario (seed 3), the stream cut into blocks of 1, 82 and
  1000 samples (the chunked buffer of SensorStream.next_block), and `truth_at` at times between samples;
- `samples`: every field of every ImuSample of `SensorBlock.samples()`;
- `gnss`: every field of every fix `simulate_gnss` makes from a block and from a stream, with a lever arm, an
  outage and glitches, and the order `in_arrival_order` merges them in;
- `record`: the bytes of the CSV files `ahrsd record --sim boat` writes (samples with truth, and GNSS), unpaced;
- `replay`: every field of every sample `iter_samples` reads back from that recording, and `read_recording`'s
  arrays.
The WMM field is evaluated on FIELD_DATE (core.wmm.fixed_date), as tools/estimate_digest.py does.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as _dt
import hashlib
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

FIELD_DATE = _dt.date(2026, 12, 6)
SCENARIOS = ("static", "rate-table", "level-turns", "coordinated-turn", "tumble", "auv-out-and-back",
             "mag-disturbance", "boat", "car", "plane")


def feed(h, value) -> None:
    """Every bit of `value` into the hash (arrays by dtype, shape and bytes; floats by their IEEE bits)."""
    if isinstance(value, np.ndarray):
        h.update(f"{value.dtype}{value.shape}".encode())
        h.update(np.ascontiguousarray(value).tobytes())
    elif isinstance(value, float):
        h.update(np.float64(value).tobytes())
    elif isinstance(value, (list, tuple)):
        h.update(b"[")
        for v in value:
            feed(h, v)
        h.update(b"]")
    elif isinstance(value, dict):
        for k in sorted(value):
            h.update(repr(k).encode())
            feed(h, value[k])
    elif dataclasses.is_dataclass(value):
        h.update(type(value).__name__.encode())
        for f in dataclasses.fields(value):
            feed(h, getattr(value, f.name))
    else:
        h.update(f"{type(value).__name__}:{value!r}".encode())


def stream_part(seconds: float) -> str:
    from ahrsd.simulation.stream import open_stream

    h = hashlib.md5()
    for name in SCENARIOS:
        for cut in (1, 82, 1000):
            s = open_stream(name, seed=3)
            n_total = int(seconds * 819.2) if cut > 1 else 600
            n = 0
            while n < n_total:
                b = s.next_block(min(cut, n_total - n))
                n += len(b)
                feed(h, b)
            feed(h, s.truth_at(np.linspace(0.0, n_total / 819.2, 97) + 1e-4))
    return h.hexdigest()


def samples_part(seconds: float) -> str:
    from ahrsd.simulation.stream import simulate

    h = hashlib.md5()
    for name in ("boat", "tumble"):
        for s in simulate(name, seconds, seed=5).samples(first_counter=7):
            feed(h, s)
    return h.hexdigest()


def gnss_part(seconds: float) -> str:
    from ahrsd.simulation.gnss import GnssGlitch, GnssOutage, in_arrival_order, simulate_gnss
    from ahrsd.simulation.stream import open_stream, simulate

    h = hashlib.md5()
    glitches = (GnssGlitch(0.3 * seconds, "position_jump", 20.0, 1.0, 30.0),
                GnssGlitch(0.5 * seconds, "velocity_spike", 3.0, 0.4, 100.0),
                GnssGlitch(0.6 * seconds, "time_backwards", 0.5, 0.2),
                GnssGlitch(0.7 * seconds, "nan", None, 0.2))
    outage = (GnssOutage(0.4 * seconds, 0.45 * seconds), GnssOutage(0.8 * seconds, 0.85 * seconds, True))
    for name in ("boat", "car", "plane"):
        block = simulate(name, seconds, rate_hz=100.0, seed=2)
        fixes = simulate_gnss(block, seed=4, lever_arm_m=(0.5, -0.2, -1.0), outages=outage, glitches=glitches,
                              jitter_s=0.05)
        feed(h, fixes)
        feed(h, [x.t_s if hasattr(x, "counter") else -x.t_s for x in in_arrival_order(block, fixes)])
        stream = open_stream(name, rate_hz=100.0, seed=2)
        stream.next_block(int(seconds * 100))
        feed(h, simulate_gnss(stream, seed=6, rate_hz=10.0))
    return h.hexdigest()


def record_part(seconds: float, out_dir: Path) -> tuple[str, str]:
    from ahrsd.cli.main import main
    from ahrsd.drivers.recording import iter_samples, read_recording

    rec = out_dir / "boat.csv"
    if main(["record", "--sim", "boat", "--seconds", str(seconds), "--seed", "4", "-o", str(rec), "-q"]) != 0:
        raise SystemExit("ahrsd record failed")
    h = hashlib.md5()
    for path in sorted(out_dir.iterdir()):
        h.update(path.name.encode())
        h.update(path.read_bytes())
    r = hashlib.md5()
    for s in iter_samples(rec, chunk_rows=1000):
        feed(r, s)
    feed(r, read_recording(rec).__dict__ | {"path": None})
    return h.hexdigest(), r.hexdigest()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=20.0, help="seconds simulated per run (default 20)")
    args = p.parse_args(argv)
    from ahrsd.core import wmm

    with wmm.fixed_date(FIELD_DATE), tempfile.TemporaryDirectory() as tmp:
        parts = {"stream": stream_part(args.seconds), "samples": samples_part(args.seconds),
                 "gnss": gnss_part(args.seconds * 5)}
        parts["record"], parts["replay"] = record_part(args.seconds, Path(tmp))
    for name, digest in parts.items():
        print(name, digest)
    print("all", hashlib.md5("".join(parts.values()).encode()).hexdigest())
    return 0


if __name__ == "__main__":
    sys.exit(main())
