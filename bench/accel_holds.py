"""`ahrsd calibrate accel` on ordinary bench recordings: 24 positions at 100 Hz, held H s each and joined by 1-s
slews (the simulated ADIS16405 with its injected bias, scale and misalignment), calibrated with default options
and with --min-still-s 1; prints the bias error against the injected bias and the norm residual.

    .venv/bin/python bench/accel_holds.py [--holds 3 2 1.5] [--seeds 5 6 7] [--keep DIR]

--keep DIR writes the recordings there (holds-3s-seed5.csv, ...) to run `ahrsd calibrate accel` on by hand.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from support.accel_positions import holds_recording  # noqa: E402

from ahrsd.cli.main import main as ahrsd  # noqa: E402
from ahrsd.simulation import DEFAULT_SITE  # noqa: E402

MG = 9.80665e-3


def calibrate(path: Path, *extra: str) -> dict:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        ahrsd(["calibrate", "accel", str(path), "--json", "--dry-run", "--lat", str(DEFAULT_SITE.lat_deg),
               "--alt-m", str(DEFAULT_SITE.alt_m), *extra])
    return json.loads(out.getvalue())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--holds", type=float, nargs="+", default=[3.0, 2.0, 1.5])
    ap.add_argument("--seeds", type=int, nargs="+", default=[5, 6, 7])
    ap.add_argument("--keep", metavar="DIR", default=None)
    args = ap.parse_args()
    d = Path(args.keep or tempfile.mkdtemp())
    d.mkdir(parents=True, exist_ok=True)
    print(f"{'hold':>5} {'seed':>4} | {'default options':^36} | {'--min-still-s 1':^36}")
    print(f"{'s':>5} {'':>4} | {'positions':>9} {'bias err mg':>12} {'resid mg':>9}  | "
          f"{'positions':>9} {'bias err mg':>12} {'resid mg':>9}")
    for hold in args.holds:
        for seed in args.seeds:
            path = d / f"holds-{hold:g}s-seed{seed}.csv"
            bias = holds_recording(path, hold, seed)[2].accel_bias_m_s2
            cells = []
            for extra in ((), ("--min-still-s", "1")):
                r = calibrate(path, *extra)
                if r.get("refused") or "error" in r:
                    cells.append(f"{'refused':>9} {'':>12} {'':>9} ")
                    continue
                err = np.max(np.abs(np.array(r["bias_m_s2"]) - bias)) / MG
                cells.append(f"{r['quality']['positions']:>9} {err:>12.2f} {r['residual_rms_m_s2'] / MG:>9.2f} ")
            print(f"{hold:>5g} {seed:>4} | {cells[0]} | {cells[1]}")
    if args.keep:
        print(f"recordings in {d}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
