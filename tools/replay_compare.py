"""Replay simulated recordings through `ahrsd replay` and compare two trees' outputs numerically: the check that a
kernel refactor leaves the estimate bit-identical or within a stated bound (issue #29: "bit-identical or within
1e-9 rad").

    python tools/replay_compare.py replay DIR/before        # with the tree to compare against checked out
    python tools/replay_compare.py replay DIR/after         # with the change
    python tools/replay_compare.py compare DIR/before DIR/after

`replay` records each scenario once (into DIR/../recordings, reused by the second run so both replay the same
bytes) and replays it with the installed `ahrsd` (the current tree for an editable install). The CSV prints the
quaternion to 1e-9 and angles to 1e-6°, which cannot show a 1e-9 rad difference, so `replay` also keeps the
same table at full float64 precision (NAME.npy: `estimator.replay.replay_attitude`, the loop `ahrsd replay`
runs). `compare` prints, per scenario, whether the CSVs are byte-identical and the float64 tables bit-identical,
else the largest attitude difference (the rotation angle between the two quaternions, rad), the largest
difference of each angle column converted to rad, and whether the flags agree; it exits 1 when any attitude or
σ difference exceeds --tolerance-rad.
"""

from __future__ import annotations

import argparse
import filecmp
import subprocess
import sys
from pathlib import Path

import numpy as np

SCENARIOS = {"static": 20.0, "level-turns": 60.0, "coordinated-turn": 60.0, "tumble": 30.0, "boat": 60.0}
SEED = 3


def _ahrsd() -> list[str]:
    return [sys.executable, "-c", "import sys; from ahrsd.cli.main import main; sys.exit(main())"]


def replay(out_dir: Path, seconds_scale: float) -> None:
    recordings = out_dir.parent / "recordings"
    recordings.mkdir(parents=True, exist_ok=True)
    out_dir.mkdir(parents=True, exist_ok=True)
    for name, seconds in SCENARIOS.items():
        rec = recordings / f"{name}.csv"
        if not rec.exists():
            subprocess.run([*_ahrsd(), "record", "--sim", name, "--seconds", str(seconds * seconds_scale),
                            "--seed", str(SEED), "--no-gnss", "--quiet", "--output", str(rec)], check=True)
        subprocess.run([*_ahrsd(), "replay", str(rec), "--estimator", "mekf", "--quiet",
                        "--output", str(out_dir / f"{name}.csv")], check=True)
        np.save(out_dir / f"{name}.npy", _full_precision_table(rec))
        print(f"{name}: {out_dir / name}.csv, .npy")


def _full_precision_table(recording: Path) -> np.ndarray:
    from ahrsd.drivers.recording import iter_samples
    from ahrsd.estimator import make_estimator
    from ahrsd.estimator.replay import replay_attitude

    return np.concatenate(list(replay_attitude(make_estimator("mekf"), iter_samples(str(recording)))))


def _rotation_angle_rad(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """Angle of the rotation between two unit quaternions (either sign): 2·acos(|qa·qb|), written with atan2 so
    it keeps its precision near zero."""
    dot = np.abs(np.sum(qa * qb, axis=1))
    cross = np.linalg.norm(qa[:, :1] * qb[:, 1:] - qb[:, :1] * qa[:, 1:] + np.cross(qa[:, 1:], qb[:, 1:]), axis=1)
    return 2.0 * np.arctan2(cross, dot)


def compare(a_dir: Path, b_dir: Path, tolerance_rad: float) -> int:
    from ahrsd.estimator.replay import ATTITUDE_COLUMNS

    worst = 0.0
    for a in sorted(a_dir.glob("*.csv")):
        b = b_dir / a.name
        csv_same = filecmp.cmp(a, b, shallow=False)
        xa = np.load(a.with_suffix(".npy"))
        xb = np.load(b.with_suffix(".npy"))
        if xa.shape != xb.shape:
            print(f"{a.stem}: different row count ({xa.shape} against {xb.shape})")
            return 1
        if np.array_equal(xa, xb, equal_nan=True):
            print(f"{a.stem}: float64 table bit-identical; CSV {'byte-identical' if csv_same else 'DIFFERS'}")
            if not csv_same:
                return 1
            continue
        print(f"{a.stem}: CSV {'byte-identical' if csv_same else 'differs'}; float64 table differs:")
        ha = list(ATTITUDE_COLUMNS)
        col = {n: i for i, n in enumerate(ha)}
        qa = xa[:, [col[n] for n in ("qw", "qx", "qy", "qz")]]
        qb = xb[:, [col[n] for n in ("qw", "qx", "qy", "qz")]]
        both = np.all(np.isfinite(qa), axis=1) & np.all(np.isfinite(qb), axis=1)
        att = float(np.max(_rotation_angle_rad(qa[both], qb[both]), initial=0.0))
        parts = [f"attitude {att:.3g} rad"]
        worst = max(worst, att)
        for n in ha:
            if n.endswith("_deg"):
                d = np.abs(xa[:, col[n]] - xb[:, col[n]])
                d = np.where(d > 180.0, 360.0 - d, d)   # a heading wrapping at ±180° on one side only
                dmax = float(np.radians(np.nanmax(d, initial=0.0)))
                worst = max(worst, dmax)
                parts.append(f"{n} {dmax:.3g} rad")
        others = [n for n in ha if not n.endswith("_deg") and n[0] != "q"
                  and not np.array_equal(xa[:, col[n]], xb[:, col[n]], equal_nan=True)]
        parts.append(f"other columns that differ: {', '.join(others) or 'none'}")
        nan_differs = int(np.sum(np.isnan(xa) != np.isnan(xb)))
        flags_equal = bool(np.array_equal(xa[:, col["flags"]], xb[:, col["flags"]]))
        print("  " + ", ".join(parts) + f"; flags {'equal' if flags_equal else 'DIFFER'}; "
              f"NaN placement differs in {nan_differs} cells")
        if not flags_equal or nan_differs:
            return 1
    print(f"largest difference: {worst:.3g} rad (tolerance {tolerance_rad:g} rad)")
    return 0 if worst <= tolerance_rad else 1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    r = sub.add_parser("replay", help="record (once) and replay every scenario with the installed ahrsd")
    r.add_argument("out_dir", type=Path)
    r.add_argument("--seconds-scale", type=float, default=1.0, help="scale every scenario's length")
    c = sub.add_parser("compare", help="compare two replay directories")
    c.add_argument("a_dir", type=Path)
    c.add_argument("b_dir", type=Path)
    c.add_argument("--tolerance-rad", type=float, default=1e-9)
    args = ap.parse_args(argv)
    if args.command == "replay":
        replay(args.out_dir, args.seconds_scale)
        return 0
    return compare(args.a_dir, args.b_dir, args.tolerance_rad)


if __name__ == "__main__":
    sys.exit(main())
