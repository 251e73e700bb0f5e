"""The daemon's heading without a magnetometer calibration, as issue 28 measures it: `ahrsd record --sim boat`
(its vehicle iron, no calibration stored), then `ahrsd run --replay REC --gnss-replay REC.gnss.csv
--replay-speed 5`; every VISION_POSITION_ESTIMATE against the recording's truth: the share whose yaw is within 3σ
of the VPE's own yaw variance after 30 s, and the yaw RMS from 180 s (targets ≥ 99 %, ≤ 1°).

`--site` / `--iron` as bench/heading_timeline.py's (vehicle_accuracy.honesty_site): a name ("held-out", "default")
or any place "LAT,LON[,ALT_M[,YYYY-MM-DD]]" (with the held-out iron), another iron ("unseen": never used for a
choice); they reach `ahrsd record --site/--iron` (the chip's field and gravity, the GNSS receiver's track).

`--replay` also replays the same recording in process order (`ahrsd replay REC --gnss REC.gnss.csv`, every fix
merged at its time) and prints its yaw error at the samples the VPEs carry, and the daemon's difference from it:
whether the daemon's pacing, fix hand-over and VPE stamping add anything to the estimator's own error.

    python bench/daemon_heading.py --seconds 600 --seed 11
    python bench/daemon_heading.py --seed 12 --site=-45.87,170.50 --iron unseen     # Dunedin ("=": a minus sign)
    python bench/daemon_heading.py --seed 17 --site=69.65,18.96 --replay            # the daemon against the replay
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from support.ahrsd_process import AHRSD, Daemon  # noqa: E402

from ahrsd.drivers.recording import read_recording  # noqa: E402
from bench.vehicle_accuracy import HONESTY_IRONS, honesty_site, honesty_site_arg  # noqa: E402


def record_boat(rec: Path, seconds: float, seed: int, site: str | None = None, iron: str | None = None) -> None:
    """The boat recording the daemon replays (and REC.gnss.csv beside it): `ahrsd record --sim boat` as a user
    runs it; a `site` or an `iron` (honesty_site's) goes to its `--site` / `--iron`, so the place's field and
    gravity and the receiver's latitude (the daemon's declination) agree."""
    argv = record_boat_argv(rec, seconds, seed, site, iron)
    done = subprocess.run([str(AHRSD), *argv], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"ahrsd {' '.join(argv)} failed ({done.returncode}): {done.stderr}")


def record_boat_argv(rec: Path, seconds: float, seed: int, site: str | None = None,
                     iron: str | None = None) -> list[str]:
    """record_boat's `ahrsd` arguments (for a caller that runs the command in its own process)."""
    argv = ["record", "--sim", "boat", "--seconds", str(seconds), "--seed", str(seed), "-o", str(rec), "--quiet"]
    if site is not None or iron is not None:
        site_text, iron_name = honesty_site("default" if site is None else site, iron)
        argv += ([f"--site={site_text}"] if site_text else []) + ["--iron", iron_name]
    return argv


def replay_heading(rec: Path) -> tuple[np.ndarray, np.ndarray]:
    """`ahrsd replay REC --gnss REC.gnss.csv` (the same estimator in one process, each fix merged at its time of
    validity): its true heading (rad) and published yaw σ (deg) per recorded sample, in the recording's order."""
    out = rec.with_name(rec.stem + ".replay.csv")
    argv = ["replay", str(rec), "--gnss", str(rec.with_name(rec.stem + ".gnss.csv")), "-o", str(out), "--quiet"]
    done = subprocess.run([str(AHRSD), *argv], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"ahrsd {' '.join(argv)} failed ({done.returncode}): {done.stderr}")
    with open(out) as f:
        header = f.readline().strip().split(",")
    cols = np.loadtxt(out, delimiter=",", skiprows=1, comments="#",
                      usecols=[header.index(c) for c in ("heading_true_deg", "sigma_yaw_deg")])
    out.unlink()
    return np.radians(cols[:, 0]), cols[:, 1]


def _wrap_deg(x: np.ndarray) -> np.ndarray:
    return (x + 180.0) % 360.0 - 180.0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--speed", type=float, default=5.0)
    ap.add_argument("--site", type=honesty_site_arg, default=None,
                    help='"held-out", "default" or a place "LAT,LON[,ALT_M[,YYYY-MM-DD]]" (default: `ahrsd record`\'s '
                         "own site and boat iron)")
    ap.add_argument("--iron", choices=HONESTY_IRONS, default=None,
                    help="the vehicle iron instead of the site's own (a place's own: held-out)")
    ap.add_argument("--replay", action="store_true",
                    help="also `ahrsd replay` the same recording and compare it with the VPEs at their samples")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        rec = tmp / "boat.csv"
        record_boat(rec, args.seconds, args.seed, args.site, args.iron)
        d = Daemon(tmp, "--gnss-replay", str(rec.with_name("boat.gnss.csv")), "--replay-speed", str(args.speed),
                   source=("--replay", str(rec)))
        got: dict = {}
        t0 = time.monotonic()
        try:
            while d.proc.poll() is None and time.monotonic() - t0 < args.seconds / args.speed * 4 + 300:
                for k, v in d.collect(1.0).items():
                    got.setdefault(k, []).extend(v)
            for k, v in d.collect(0.5).items():
                got.setdefault(k, []).extend(v)
        finally:
            d.stop()
        texts = [m.text for _, m in got.get("STATUSTEXT", [])]
        r = read_recording(rec)
        replayed = replay_heading(rec) if args.replay else None
    truth = Rotation.from_quat(np.column_stack([r.extra[c] for c in ("truth_qx", "truth_qy", "truth_qz", "truth_qw")]))
    index_us = {int(t * 1e6): i for i, t in enumerate(r.t_s)}
    all_vpe = [m for _, m in got.get("VISION_POSITION_ESTIMATE", [])]
    vpe = [m for m in all_vpe if int(m.usec) in index_us]      # stamped with the recording's t_s
    if not vpe:
        print("no VISION_POSITION_ESTIMATE received")
        return 1
    t = np.array([m.usec * 1e-6 for m in vpe]) - r.t_s[0]
    rows = np.array([index_us[int(m.usec)] for m in vpe])
    err = np.degrees(np.angle(np.exp(1j * (np.array([m.yaw for m in vpe]) - truth[rows].as_euler("ZYX")[:, 0]))))
    sigma = np.degrees(np.sqrt([m.covariance[20] for m in vpe]))
    after30, from180 = t >= 30.0, t >= 180.0
    where = "".join(f", {name} {value}" for name, value in (("site", args.site), ("iron", args.iron)) if value)
    print(f"boat seed {args.seed}{where}, {args.seconds:.0f} s at {args.speed:g}x, no magnetometer calibration: "
          f"{len(vpe)} VPE, first at {t[0]:.1f} s")
    print(f"  within 3σ of the VPE's yaw variance after 30 s: {np.mean(np.abs(err[after30]) <= 3 * sigma[after30]):.2%}")
    if from180.any():
        print(f"  yaw RMS from 180 s: {np.sqrt(np.mean(err[from180] ** 2)):.2f}° (median σ "
              f"{np.median(sigma[from180]):.2f}°)")
    if replayed is not None:
        if len(replayed[0]) != len(r.t_s):
            raise RuntimeError(f"the replay wrote {len(replayed[0])} rows for {len(r.t_s)} recorded samples")
        rep_yaw_rad, rep_sigma_deg = (a[rows] for a in replayed)
        rep_err = _wrap_deg(np.degrees(rep_yaw_rad - truth[rows].as_euler("ZYX")[:, 0]))
        diff = _wrap_deg(err - rep_err)
        print(f"  the replay of the same recording at these samples: within 3σ after 30 s "
              f"{np.mean(np.abs(rep_err[after30]) <= 3 * rep_sigma_deg[after30]):.2%}"
              + (f", yaw RMS from 180 s {np.sqrt(np.mean(rep_err[from180] ** 2)):.2f}°; daemon − replay from 180 s: "
                 f"mean {np.mean(diff[from180]):+.3f}°, RMS {np.sqrt(np.mean(diff[from180] ** 2)):.3f}°"
                 if from180.any() else ""))
    for start in range(0, int(args.seconds), 60):
        w = (t >= start) & (t < start + 60)
        if w.any():
            print(f"  {start:4d}–{start + 60:4d} s: RMS {np.sqrt(np.mean(err[w] ** 2)):5.2f}°, median σ "
                  f"{np.median(sigma[w]):5.2f}°, beyond 3σ {np.mean(np.abs(err[w]) > 3 * sigma[w]):6.2%}"
                  + ("" if replayed is None else f"; replay RMS {np.sqrt(np.mean(rep_err[w] ** 2)):5.2f}°, "
                     f"daemon − replay mean {np.mean(diff[w]):+.2f}°"))
    print("  STATUSTEXT:", " | ".join(dict.fromkeys(texts)))
    # every STATUSTEXT in order, at the recording time of the last VPE received before it (a heading state that
    # flips shows here as the same announcements repeated)
    vpe_wall = np.array([w for w, m in got.get("VISION_POSITION_ESTIMATE", []) if int(m.usec) in index_us])
    print(f"  STATUSTEXT in order ({len(texts)}):")
    for wall, m in got.get("STATUSTEXT", []):
        i = int(np.searchsorted(vpe_wall, wall)) - 1
        print(f"    {'≈%6.1f s' % t[i] if i >= 0 else '  before VPE'}  {m.text}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
